"""Device discovery, probing and choice (bdipole_cl/device.py, bdipole_cl/icd.py)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bdipole_cl
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.device import icd
from bdipole_cl.device import runtime as device

ZEN5_POCL = "error: unknown target CPU 'generic'"


def state(index, platform, kind="cpu", reason=""):
    return device.DeviceState(index, platform, f"dev {index}", kind, "OpenCL 3.0", True,
                              not reason, reason)


# {{{ the choice, as pure logic

def test_choice_skips_a_broken_device():
    states = [state("0:0", "Portable Computing Language", reason=ZEN5_POCL),
              state("1:0", "Some Vendor OpenCL")]
    assert device.choose(states).index == "1:0"


def test_choice_ranks_gpu_then_intel_then_pocl():
    states = [state("0:0", "Portable Computing Language"), state("1:0", "Intel(R) OpenCL"),
              state("2:0", "NVIDIA CUDA", kind="gpu")]
    assert device.choose(states).index == "2:0"
    assert device.choose(states[:2]).index == "1:0"


def test_choice_probes_lazily_in_rank_order():
    probed = []

    def probe(s):
        probed.append(s.index)
        return "" if s.index == "0:0" else "broken"
    states = [state("0:0", "Portable Computing Language", reason="?"),
              state("1:0", "Intel(R) OpenCL", reason="?")]
    assert device.choose(states, probe_fn=probe).index == "0:0"
    assert probed == ["1:0", "0:0"]           # Intel first; nothing after the first that works


def test_no_working_device_names_each_failure_and_the_remedies():
    states = [state("0:0", "Portable Computing Language", reason=ZEN5_POCL),
              state("1:0", "Intel(R) OpenCL", reason="clCreateContext failed: OUT_OF_HOST_MEMORY")]
    with pytest.raises(device.DeviceError) as err:
        device.choose(states)
    text = str(err.value)
    assert "\n" not in text
    assert ZEN5_POCL in text and "OUT_OF_HOST_MEMORY" in text
    assert "[0:0]" in text and "[1:0]" in text
    assert "intel-opencl-rt" in text and "pocl-opencl-icd" in text


def test_no_device_at_all():
    with pytest.raises(device.DeviceError, match="no OpenCL device found"):
        device.choose([])

# }}}


# {{{ the choice on this machine's devices, one made broken

@pytest.fixture
def fresh_default(monkeypatch):
    """Forget the process default (and restore it afterwards)."""
    monkeypatch.setattr(device, "_default", None)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)


def test_automatic_choice_skips_a_device_whose_build_fails(monkeypatch, fresh_default):
    states = device.survey()
    best = device.choose(states)
    monkeypatch.setitem(device._probes, best.device.int_ptr, ZEN5_POCL)
    others = [s for s in states if s.works and s.device.int_ptr != best.device.int_ptr]
    if others:
        assert device.get_runtime().device.int_ptr == device.choose(others).device.int_ptr
    else:
        with pytest.raises(device.DeviceError, match="unknown target CPU"):
            device.get_runtime()


def test_devices_command_shows_broken_state_and_reason(monkeypatch, fresh_default, capsys):
    states = device.survey()
    victim = states[0]
    monkeypatch.setitem(device._probes, victim.device.int_ptr, ZEN5_POCL)
    rc = cli_main(["devices"])
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if f"[{victim.index}]" in ln)
    assert f"broken: {ZEN5_POCL}" in line and not line.startswith("*")
    assert rc == (0 if len(states) > 1 else 1)


def test_all_devices_broken_is_one_clear_error(monkeypatch, fresh_default, capsys):
    for s in device.survey():
        monkeypatch.setitem(device._probes, s.device.int_ptr, ZEN5_POCL)
    assert cli_main(["crosscheck", "--n", "10"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("bdipole-cl crosscheck: error: no working OpenCL device:")
    assert ZEN5_POCL in err
    assert "Traceback" not in err and "remedies" in err


def test_pyopencl_ctx_naming_nothing_is_one_clear_error(monkeypatch, fresh_default, capsys):
    monkeypatch.setenv("PYOPENCL_CTX", "9")
    assert cli_main(["devices"]) == 1
    err = capsys.readouterr().err
    assert "PYOPENCL_CTX='9' selects no device" in err and "Traceback" not in err

# }}}


# {{{ explicit devices

def test_every_entry_point_takes_an_explicit_device(runtime):
    rd = np.float32([1e-4, 0.3, 0.9, 0.999])
    want = bdipole_cl.invert_albedo(rd, 1.4, device=runtime)
    for spec in (runtime, runtime.device, f"{_index_of(runtime)}"):
        np.testing.assert_array_equal(bdipole_cl.invert_albedo(rd, 1.4, device=spec), want)
    sa, ss = bdipole_cl.albedo_to_coefficients(rd, 1.0, 1.4, device=runtime)
    assert np.all(sa > 0) and np.all(ss > 0)
    from bdipole_cl import blur
    e = np.zeros((9, 9, 1), np.float32)
    e[4, 4] = 1
    out = blur(e, albedo=0.5, mfp=0.5, method="direct", border="zero", device=runtime)
    assert abs(out.sum() - 0.5) < 1e-3


def _index_of(rt):
    return next(s.index for s in device.survey() if s.device.int_ptr == rt.device.int_ptr)


def test_unknown_device_string_lists_what_is_there():
    with pytest.raises(device.DeviceError, match="matches no OpenCL device .*seen:"):
        device.get_runtime("no-such-vendor")


def test_device_of_wrong_type():
    with pytest.raises(TypeError, match="expected None, a Runtime"):
        bdipole_cl.invert_albedo([0.5], 1.4, device=3)

# }}}


# {{{ environment runtimes (ICD registration)

def test_existing_entries_from_a_user_directory_file_or_library(tmp_path):
    (tmp_path / "a.icd").write_text("/opt/a/libA.so\n")
    (tmp_path / "notes.txt").write_text("ignored")
    assert icd.existing_icd_entries(str(tmp_path)) == {"a.icd": "/opt/a/libA.so\n"}
    assert icd.existing_icd_entries(str(tmp_path / "a.icd")) == {"a.icd": "/opt/a/libA.so\n"}
    assert icd.existing_icd_entries("/opt/b/libB.so") == {"user-libB.so.icd": "/opt/b/libB.so\n"}


def test_vendors_directory_holds_exactly_the_entries(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    entries = {"a.icd": "/opt/a/libA.so\n", "b.icd": "/opt/b/libB.so\n"}
    d = icd.vendors_directory(entries)
    assert {p.name: p.read_text() for p in d.iterdir()} == entries
    assert icd.vendors_directory(dict(entries)) == d          # same set, same directory


def test_find_intel_runtime_in_a_lib_dir(tmp_path):
    assert icd.find_intel_runtime([tmp_path]) is None
    (tmp_path / icd.INTEL_ICD_LIBRARY).write_bytes(b"")
    assert icd.find_intel_runtime([tmp_path]) == (tmp_path / icd.INTEL_ICD_LIBRARY).resolve()


def _fresh_process(env_updates, code, *args):
    env = {k: v for k, v in os.environ.items()
           if k not in ("OCL_ICD_VENDORS", "PYOPENCL_CTX", icd.SWITCH, icd.BEFORE)}
    env.update(env_updates)
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


LISTING = ("import json, os, bdipole_cl.device as d, pyopencl as cl; "
           "print(json.dumps({'vendors': os.environ.get('OCL_ICD_VENDORS'), "
           "'platforms': [p.name for p in cl.get_platforms()]}))")


@pytest.mark.skipif(icd.find_intel_runtime() is None,
                    reason="intel-opencl-rt is not installed here (not an x86-64 Linux env)")
def test_intel_runtime_found_without_any_variable_and_user_vendors_kept(tmp_path):
    got = _fresh_process({}, LISTING)
    assert any("Intel" in p for p in got["platforms"]), got
    # the user's own OCL_ICD_VENDORS still counts: its entries are kept beside Intel's
    user = tmp_path / "vendors"
    user.mkdir()
    (user / "mine.icd").write_text("/nonexistent/libmine.so\n")
    got = _fresh_process({"OCL_ICD_VENDORS": str(user), "XDG_CACHE_HOME": str(tmp_path)},
                         LISTING)
    merged = Path(got["vendors"])
    assert (merged / "mine.icd").read_text() == "/nonexistent/libmine.so\n"
    assert any("Intel" in p for p in got["platforms"]), got
    # and the switch leaves the loader exactly as configured
    got = _fresh_process({icd.SWITCH: "0", "OCL_ICD_VENDORS": str(user)}, LISTING)
    assert got["vendors"] == str(user) and not any("Intel" in p for p in got["platforms"])



def test_a_temporary_root_not_private_is_passed_over(tmp_path, monkeypatch):
    """The registration's fallback in the temporary folder has a known name: one another user
    made first (here: writable by all) would have its .icd files loaded, so it is not used."""
    (tmp_path / "file").write_text("x")
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(tmp_path / "file"))   # cannot be written
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)
    fallback = tmp_path / f"bdipole_cl-{os.getuid()}"
    fallback.mkdir()
    fallback.chmod(0o777)
    with pytest.raises(OSError, match="no writable directory"):
        icd.vendors_directory({"a.icd": "/opt/a/libA.so\n"})
    fallback.chmod(0o700)
    assert icd.vendors_directory({"a.icd": "/opt/a/libA.so\n"}).parent == fallback


SWITCHED_OFF_CHILD = """
import json, os, subprocess, sys
import bdipole_cl.device
env = dict(os.environ, BDIPOLE_CL_ENV_RUNTIMES="0")
child = subprocess.run([sys.executable, "-c", sys.argv[1]], env=env, capture_output=True,
                       text=True)
print(child.stdout.strip().splitlines()[-1])
"""


@pytest.mark.skipif(icd.find_intel_runtime() is None,
                    reason="intel-opencl-rt is not installed here (not an x86-64 Linux env)")
def test_the_switch_off_in_a_child_is_the_users_own_loader(tmp_path):
    """A process started with BDIPOLE_CL_ENV_RUNTIMES=0 by one that registered sees the
    loader as the user set it up, not the registration it inherited."""
    user = tmp_path / "vendors"
    user.mkdir()
    (user / "mine.icd").write_text("/nonexistent/libmine.so\n")
    got = _fresh_process({"OCL_ICD_VENDORS": str(user), "BDIPOLE_CL_CACHE_DIR":
                          str(tmp_path / "cache")}, SWITCHED_OFF_CHILD, LISTING)
    assert got["vendors"] == str(user) and not any("Intel" in p for p in got["platforms"])
    got = _fresh_process({"BDIPOLE_CL_CACHE_DIR": str(tmp_path / "cache")},
                         SWITCHED_OFF_CHILD, LISTING)
    assert got["vendors"] is None and not any("Intel" in p for p in got["platforms"]), got


#: a process whose registration folder is removed before its first platform query (another
#: shell's `bdipole-cl cache --clear`), then a child of it, as Dask's workers and the probes are
CLEARED = """
import json, os, shutil, subprocess, sys
import bdipole_cl.device as d
shutil.rmtree(os.environ["OCL_ICD_VENDORS"])
child = subprocess.run([sys.executable, "-c", sys.argv[1]], capture_output=True, text=True)
import pyopencl as cl
print(json.dumps({"platforms": [p.name for p in cl.get_platforms()],
                  "child": json.loads(child.stdout.strip().splitlines()[-1])}))
"""


@pytest.mark.skipif(icd.find_intel_runtime() is None,
                    reason="intel-opencl-rt is not installed here (not an x86-64 Linux env)")
def test_a_registration_removed_while_in_use_is_written_again(tmp_path):
    """ocl-icd reads a missing folder as one library and then finds no platform at all (every
    Dask worker of a CI run failed so, after a test cleared the shared fallback folder). The
    process writes its folder again before its first query; its children register from the
    user's own setting, not from the folder they inherited."""
    user = tmp_path / "vendors"
    user.mkdir()
    (user / "mine.icd").write_text("/nonexistent/libmine.so\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("OCL_ICD_VENDORS", "PYOPENCL_CTX", icd.SWITCH, icd.BEFORE)}
    env.update(OCL_ICD_VENDORS=str(user), BDIPOLE_CL_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run([sys.executable, "-c", CLEARED, LISTING], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert any("Intel" in p for p in got["platforms"]), got
    child = got["child"]
    assert any("Intel" in p for p in child["platforms"]), child
    held = sorted(p.name for p in Path(child["vendors"]).iterdir())
    assert held == ["bdipole_cl-intel-cpu.icd", "mine.icd"], held

# }}}


FORK_SCRIPT = """
import os, signal, sys
import numpy as np
import bdipole_cl as bd
from bdipole_cl.device import runtime as device
pocl = next(s for s in device.survey() if s.works and device.POCL_PLATFORM in s.platform.lower())
others = [s for s in device.survey() if s.works and s.index != pocl.index
          and device.POCL_PLATFORM not in s.platform.lower()]
bd.use_device(pocl.index)
bd.invert_albedo(np.full(10, 0.5, np.float32), 1.4)
pid = os.fork()
if pid == 0:
    signal.alarm(60)                          # a hang is a failure, not a stuck test run
    try:
        bd.invert_albedo(np.full(1000, 0.5, np.float32), 1.4)
        os._exit(10)
    except bd.DeviceError as exc:
        print(exc, flush=True)
    if others:                                # another runtime still serves the child
        got = bd.invert_albedo(np.float32([0.5]), 1.4, device=others[0].index)
        assert np.isfinite(got).all()
    os._exit(3)
_, status = os.waitpid(pid, 0)
sys.exit(os.waitstatus_to_exitcode(status))
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork() here")
def test_pocl_in_a_forked_child_is_a_clear_error_not_a_hang():
    """PoCL's threads do not survive fork(): a child of a process that had started PoCL would
    hang on its first PoCL call (multiprocessing's default start method on Linux). It gets a
    one-line DeviceError with the remedy instead; other runtimes still work there."""
    if not any(s.works and device.POCL_PLATFORM in s.platform.lower() for s in device.survey()):
        pytest.skip("no working PoCL device")
    proc = subprocess.run([sys.executable, "-c", FORK_SCRIPT], capture_output=True, text=True,
                          timeout=180)
    assert proc.returncode == 3, proc
    assert "forked" in proc.stdout and "'spawn'" in proc.stdout, proc.stdout
