"""The kernel probe in a child process (bdipole_cl/device/isolation.py,
bdipole_cl/ops/kernel_checks.py): a runtime whose compiler crashes on one configuration costs
that configuration, never the process; the verdict is cached and `bdipole-cl devices` says it.

The crashes are simulated in the probe's real child (``isolation.FAULT_VARIABLE``): killed by
SIGSEGV, or exiting with the runtime's INVALID_KERNEL_NAME message, as PoCL's LLVM does on a
Zen 4 building kernels/invert_table.cl at 16 lanes."""
import os
import subprocess
import sys

import numpy as np
import pytest

import bdipole_cl
from bdipole_cl.caches import CACHE_DIR_VARIABLE
from bdipole_cl.device import guard, isolation
from bdipole_cl.device.children import child_env
from bdipole_cl.device import runtime as device
from bdipole_cl.device.programs import kernels_digest
from bdipole_cl.ops import inversion_kernel

from conftest import RUNTIMES

INVALID_KERNEL_NAME = ("pyopencl._cl.LogicError: clCreateKernel failed: INVALID_KERNEL_NAME\n"
                       "still have references to IRs - refcount: 1")


def _pick(platform_part):
    """A device under test whose platform names ``platform_part``, else the first one."""
    return next((rt for rt in RUNTIMES if platform_part in rt.device.platform.name.lower()),
                RUNTIMES[0])


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty verdict cache, this process's verdicts forgotten (and restored after), and its
    programs built under them dropped (a program built before is not refused again)."""
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path))
    saved = dict(isolation._verdicts)
    isolation.forget_verdicts()
    bdipole_cl.clear_caches()
    yield tmp_path
    isolation.forget_verdicts()
    isolation._verdicts.update(saved)
    bdipole_cl.clear_caches()


def _index(rt):
    return next(s.index for s in device.survey() if s.device.int_ptr == rt.device.int_ptr)


def _probe_with_fault(monkeypatch, rt, fault):
    monkeypatch.setenv(isolation.FAULT_VARIABLE, fault)
    return device.verdict(rt.device)


def test_a_crashing_compiler_costs_one_configuration(monkeypatch, fresh_cache):
    rt = _pick("intel")
    verdict = _probe_with_fault(monkeypatch, rt, "invert_table/w16=segv")
    bad = verdict.result("invert_table/w16")
    assert bad is not None and not bad.ok and "SIGSEGV" in bad.reason, verdict
    # the child that died was replaced: every other configuration was probed, and passed
    assert verdict.works and [r.name for r in verdict.rejected()] == ["invert_table/w16"]
    assert verdict.passed("invert_table/w8") and verdict.passed("blur_direct"), verdict
    # cached on disk: a new process reads it (no probe), under the same key
    path = isolation.verdict_path(rt.device, kernels_digest())
    assert path.is_file() and isolation.read_verdict(path).rejected()[0].name == bad.name

    # the library never picks the rejected width, and still computes right (kernels that
    # earlier tests prepared under the verdict without the fault are dropped first)
    bdipole_cl.clear_caches()
    choice = inversion_kernel.table_width_choice(rt)
    assert choice.width != 16, choice
    rd = np.float32([1e-4, 0.3, 0.9])
    want = bdipole_cl.reference.invert_rd(rd.astype(np.float64), 1.4)
    np.testing.assert_allclose(bdipole_cl.invert_albedo(rd, 1.4, device=rt), want, rtol=1e-4)
    # forcing it is a one-line DeviceError naming the reason, not a crash
    monkeypatch.setenv(inversion_kernel.TABLE_WIDTH_VARIABLE, "16")
    bdipole_cl.clear_caches()
    with pytest.raises(bdipole_cl.DeviceError, match="invert_table/w16 failed this device's "
                                                     "probe.*SIGSEGV"):
        bdipole_cl.invert_albedo(np.float32([0.5, 0.6]), 1.3, device=rt)
    monkeypatch.delenv(inversion_kernel.TABLE_WIDTH_VARIABLE)
    bdipole_cl.clear_caches()

    # `bdipole-cl devices` (a new process, reading the cached verdict) names the reason
    env = dict(os.environ)
    out = subprocess.run([sys.executable, "-m", "bdipole_cl", "devices"], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    line = next(ln for ln in out.stdout.splitlines() if rt.device.name.strip() in ln
                and rt.device.platform.name.strip() in ln)
    assert "works (1 configuration rejected: invert_table/w16 (crashed (SIGSEGV)" in line, line
    described = f"{rt.device.name.strip()} ({rt.device.platform.name.strip()})"
    assert f"probing {described}" not in out.stderr, out.stderr   # its cached verdict read


def test_invalid_kernel_name_and_exit_is_rejected_with_the_runtimes_words(monkeypatch,
                                                                          fresh_cache):
    rt = _pick("portable")
    verdict = _probe_with_fault(monkeypatch, rt, f"invert_table/w8=abort:{INVALID_KERNEL_NAME}")
    bad = verdict.result("invert_table/w8")
    assert not bad.ok and "INVALID_KERNEL_NAME" in bad.reason, bad
    assert "exited with status 1" in bad.reason, bad
    assert verdict.works and verdict.passed("invert_table/w4"), verdict
    assert inversion_kernel.table_width_choice(rt).width != 8


def test_a_hanging_build_times_out(monkeypatch, fresh_cache):
    rt = _pick("intel")
    monkeypatch.setattr(isolation, "CONFIG_TIMEOUT_S", 3.0)
    verdict = _probe_with_fault(monkeypatch, rt, "blur_direct=hang")
    bad = verdict.result("blur_direct")
    assert not bad.ok and "timed out after 3 s" in bad.reason, bad
    assert verdict.passed("blur_separable"), verdict


def test_a_device_whose_child_cannot_start_is_broken_with_the_reason(monkeypatch, fresh_cache):
    rt = _pick("intel")
    monkeypatch.setattr(isolation, "PROBE_MODULE", "bdipole_cl.no_such_module")
    verdict = device.verdict(rt.device)
    assert not verdict.works
    assert "failed outside any kernel" in verdict.reason and "No module named" in verdict.reason


def test_a_probes_child_leaves_no_file_open(monkeypatch, fresh_cache):
    """The probe's child's output pipe is closed when it ends, not left to the collector (a
    ResourceWarning where a user shows every warning)."""
    import gc
    import time
    import warnings
    rt = _pick("intel")
    monkeypatch.setattr(isolation, "PROBE_MODULE", "bdipole_cl.no_such_module")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert not device.verdict(rt.device).works
        time.sleep(0.2)                 # the reader thread's last step, after the end
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)], [
        str(w.message) for w in caught]


def test_verdict_key_follows_driver_and_kernels(fresh_cache):
    rt = RUNTIMES[0]
    a = isolation.verdict_key(rt.device, "digest-a")
    assert a == isolation.verdict_key(rt.device, "digest-a")
    assert a != isolation.verdict_key(rt.device, "digest-b")


def test_pyopencls_build_options_are_in_the_verdicts_key(monkeypatch, fresh_cache):
    """A verdict reached with PYOPENCL_BUILD_OPTIONS (refused options: the device "broken";
    -cl-fast-relaxed-math: checks failed) served runs without them, and the other way round
    (a run with -cl-fast-relaxed-math used kernels its probe would have rejected)."""
    rt = _pick("intel")
    plain = isolation.verdict_key(rt.device, kernels_digest())
    monkeypatch.setenv(isolation.BUILD_OPTIONS_VARIABLE, "-cl-fast-relaxed-math")
    assert isolation.verdict_key(rt.device, kernels_digest()) != plain


def test_a_verdict_and_builds_made_under_a_simulated_target_serve_only_it(monkeypatch,
                                                                        fresh_cache):
    """The simulated target feature (tests) is in the verdict's key, so neither that verdict
    nor the guarded builds' records beside it (a 16-float program that built under +avx512f)
    serve a process without it."""
    rt = RUNTIMES[0]
    plain = isolation.verdict_key(rt.device, "digest-a")
    monkeypatch.setenv(isolation.TARGET_FEATURE_VARIABLE, "+avx512f")
    simulated = isolation.verdict_key(rt.device, "digest-a")
    assert simulated != plain
    assert guard.records_dir(rt.device, "digest-a").name == f"{simulated}.builds"


def test_config_names_match_what_get_program_builds():
    assert isolation.config_name("invert_table", ("-DBD_NCHAN=3", "-DBD_WIDTH=16")) \
        == "invert_table/w16"
    assert isolation.config_name("invert", ("-DBD_DOUBLE", "-DBD_METHOD_TABLE")) == "invert/f64"
    assert isolation.config_name("blur_direct", ("-DBD_TILE=16",)) == "blur_direct"


def test_every_device_under_test_passed_its_own_probe():
    """The machine at hand: each device's verdict, with what it rejected (none expected on a
    CPU whose runtimes work; a rejection here is printed, not failed, as the library copes)."""
    for rt in RUNTIMES:
        v = device.verdict(rt.device)
        assert v.works, v.reason
        print(rt.describe(), v.describe_rejected() or "nothing rejected")


def test_blur_crossovers_follow_this_devices_timings():
    """The shipped blur timings are another CPU's: rescaled by what each (method, radius) took
    on this device, ``auto`` picks by this device's costs (errors unchanged)."""
    from bdipole_cl.methods import choice
    data = choice.load_choice_data(choice.PACKAGED_CHOICE_DATA)
    refs = choice.timing_references(data)
    assert {(r.method, r.radius) for r in refs} == {(b.method, b.radius) for b in data.blur}
    assert choice.rescaled_blur(data, {}) is None                 # nothing timed: unchanged
    radius = max(r.radius for r in refs)
    for fast in ("direct", "fft"):
        # a device where ``fast`` costs a thousandth of the others at every radius
        seconds = {(r.method, r.radius): (1e-6 if r.method == fast else 1e-3) for r in refs}
        scaled = choice.rescaled_blur(data, seconds)
        assert [b.max_error for b in scaled.blur] == [b.max_error for b in data.blur]
        pick = choice.auto_blur_config(radius, 1e-2, scaled)
        assert pick.method == fast, (fast, pick)


def test_auto_says_its_timings_are_this_devices(runtime):
    from bdipole_cl.ops.blur.planning import auto_data
    auto = auto_data(runtime)
    if "calibrated" not in auto.source:
        assert "rescaled by this device's probe" in auto.source, auto.source
        assert auto.methods is None


def test_a_kill_from_outside_is_not_cached(monkeypatch, fresh_cache):
    rt = _pick("intel")
    verdict = _probe_with_fault(monkeypatch, rt, "blur_direct=kill")
    assert not verdict.passed("blur_direct") and "SIGKILL" in verdict.result("blur_direct").reason
    assert verdict.works and verdict.transient
    assert not isolation.verdict_path(rt.device, kernels_digest()).exists()


def _process_env(cache):
    """Another process's environment: this checkout first on its path (the probe child's
    own, ``children.child_env``), the verdict cache ``cache``, no simulated fault."""
    env = dict(child_env(), **{CACHE_DIR_VARIABLE: str(cache)})
    env.pop(isolation.FAULT_VARIABLE, None)
    return env


def _spec(rt):
    """A device spec that names ``rt`` in a new process."""
    return "intel" if "intel" in rt.device.platform.name.lower() else "0:0"


def test_processes_starting_together_probe_a_device_once(fresh_cache):
    """Two processes (a test run's workers, a farm's tasks) meeting a cold cache: one probes,
    the other waits for its verdict and reads it (cached=True), nothing probed twice."""
    rt = _pick("intel")
    spec = _spec(rt)
    code = (f"import bdipole_cl; from bdipole_cl.device import runtime as d; "
            f"rt = bdipole_cl.get_runtime({spec!r}); print('cached', d.verdict(rt.device).cached)")
    env = _process_env(fresh_cache)
    children = [subprocess.Popen([sys.executable, "-c", code], env=env, text=True,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                for _ in range(2)]
    runs = [(c.communicate(timeout=600), c.returncode) for c in children]
    assert all(rc == 0 for _, rc in runs), runs
    probing = sum(err.count("bdipole-cl: probing") for (_, err), _ in runs)
    assert probing == 1, runs
    assert sorted(out.split()[-1] for (out, _), _ in runs) == ["False", "True"], runs


def test_a_process_waiting_for_a_probe_says_so_and_its_lock_is_kept(fresh_cache):
    """While another process holds a device's probe lock, a new one says it waits (it does not
    probe beside it), and `cache --clear` leaves a held lock alone; released, it probes."""
    import fcntl
    import time
    from bdipole_cl.apps.cache import own_entries
    rt = _pick("intel")
    spec = _spec(rt)
    lock = isolation.verdict_path(rt.device, kernels_digest()).with_suffix(".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    env = _process_env(fresh_cache)
    with open(lock, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, "-c", f"import bdipole_cl; "
                                  f"bdipole_cl.get_runtime({spec!r})"], env=env, text=True,
                                 stderr=subprocess.PIPE)
        first = child.stderr.readline()         # the child's first word, while it waits
        assert "waiting for another process probing" in first, first
        assert lock not in [e.path for e in own_entries()]      # cache --clear keeps it
        time.sleep(0.2)
        assert child.poll() is None
    _, rest = child.communicate(timeout=600)
    assert child.returncode == 0, rest
    assert "bdipole-cl: probing" in rest, rest
    assert lock in [e.path for e in own_entries()]              # free again: clearable


def test_a_device_whose_default_inversion_fails_at_every_width_is_broken(monkeypatch,
                                                                        fresh_cache):
    from bdipole_cl.methods.choice import TABLE_WIDTHS_ALLOWED
    rt = _pick("intel")
    fault = ";".join(f"invert_table/w{w}=abort:INVALID_KERNEL_NAME" for w in TABLE_WIDTHS_ALLOWED)
    verdict = _probe_with_fault(monkeypatch, rt, fault)
    assert verdict.passed("blur_direct") and not verdict.works
    assert "the default inversion kernel fails at every width" in verdict.reason, verdict.reason


def test_intel_names_intels_runtime_not_pocl_on_an_intel_cpu():
    platforms = {rt.device.platform.name.strip() for rt in RUNTIMES}
    if not any("Intel(R) OpenCL" in p for p in platforms):
        pytest.skip("Intel's runtime is not among the devices under test")
    assert "Intel(R) OpenCL" in bdipole_cl.get_runtime("intel").device.platform.name


def test_a_runtime_made_by_hand_is_probed_too(monkeypatch):
    import pyopencl as cl
    rt = RUNTIMES[0]
    mine = bdipole_cl.Runtime(rt.context, cl.CommandQueue(rt.context))
    monkeypatch.setitem(device._probes, rt.device.int_ptr, "crashed (SIGSEGV)")
    with pytest.raises(bdipole_cl.DeviceError, match="is broken: crashed"):
        bdipole_cl.invert_albedo(np.float32([0.5]), 1.4, device=mine)


def test_a_killed_caller_leaves_no_probe_running(tmp_path):
    """A process killed while its device is probed (SIGKILL: no handler runs) takes its probe
    child with it, instead of leaving it building for ever."""
    import signal
    import time
    env = dict(os.environ, BDIPOLE_CL_CACHE_DIR=str(tmp_path),
               **{isolation.FAULT_VARIABLE: "invert_table/w1=hang"})
    parent = subprocess.Popen([sys.executable, "-c", "import bdipole_cl as b; b.get_runtime()"],
                              env=env, stderr=subprocess.DEVNULL)

    def children():
        found = []
        for proc in os.listdir("/proc"):
            try:
                cmd = open(f"/proc/{proc}/cmdline", "rb").read().split(b"\0")
            except OSError:
                continue
            if b"bdipole_cl.ops.kernel_checks" in cmd and str(parent.pid).encode() in cmd:
                found.append(int(proc))
        return found
    deadline = time.monotonic() + 120
    while not children() and time.monotonic() < deadline:
        time.sleep(0.5)
    assert children(), "the probe's child never started"
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 10
    while children() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not children(), "the probe's child outlived its killed parent"


def test_crosscheck_fails_when_no_device_works_and_goes_on_past_a_rejection(monkeypatch,
                                                                            fresh_cache,
                                                                            capsys):
    from bdipole_cl.apps.cli import main as cli_main
    monkeypatch.setattr(device, "_default", None)
    rt = _pick("intel")
    assert not _probe_with_fault(monkeypatch, rt, "physics_eval=segv").passed("physics_eval")
    assert cli_main(["--device", _index(rt), "crosscheck", "--n", "20"]) == 0
    out = capsys.readouterr().out
    assert "physics f32: rejected by the device's probe, skipped" in out, out
    assert "invert table" in out and "blur direct" in out          # the rest was checked
    for s in device.survey():
        monkeypatch.setitem(device._probes, s.device.int_ptr, "crashed (SIGSEGV)")
    assert cli_main(["crosscheck", "--all-devices", "--n", "20"]) == 1
    err = capsys.readouterr().err
    assert "no working OpenCL device" in err and "Traceback" not in err


def test_a_fault_of_the_processs_folders_is_not_the_devices_verdict(monkeypatch, fresh_cache):
    """A check that fails on the process's folders (pyopencl's cache unwritable: a KeyError
    from pyopencl, an OSError) says nothing of the device: the verdict names it and serves this
    process only; it was cached as the device's, refusing it until `cache --clear`."""
    rt = _pick("intel")
    verdict = _probe_with_fault(monkeypatch, rt, "invert_table/w1=raise:no cache folder")
    assert not verdict.works and verdict.transient, verdict
    assert "no cache folder" in verdict.reason and "not of the device" in verdict.reason
    assert not isolation.verdict_path(rt.device, kernels_digest()).exists()
    monkeypatch.delenv(isolation.FAULT_VARIABLE)
    isolation.forget_verdicts()
    assert device.verdict(rt.device).works                      # probed again, and cached
    assert isolation.verdict_path(rt.device, kernels_digest()).is_file()


def test_pyopencls_cache_failure_is_a_fault_of_the_folders(tmp_path):
    """pyopencl 2026.1, its cache folder unwritable, raises a KeyError from its cache module
    (it reads PYOPENCL_CACHE_FAILURE_FATAL unguarded): the probe reads that as the folders'."""
    import pyopencl as cl
    from bdipole_cl.device.faults import environment_fault
    rt = _pick("intel")
    (tmp_path / "file").write_text("x")
    try:
        cl.Program(rt.context, "kernel void f(global float *a) { a[0] = 3.0f; }").build(
            cache_dir=str(tmp_path / "file" / "cache"))
    except Exception as exc:               # noqa: BLE001 - whatever pyopencl raises there
        assert environment_fault(exc), repr(exc)
    assert environment_fault(OSError("read-only file system"))
    assert not environment_fault(ValueError("a wrong result"))
    # pytools' sqlite errors name no file: the words name its folder
    import sqlite3
    from bdipole_cl.device.faults import fault_words
    from pytools.persistent_dict import WriteOncePersistentDict
    version = ".".join(str(i) for i in sys.version_info)
    (tmp_path / "db" / f"pdict-v5-t-{version}.sqlite").mkdir(parents=True)   # not a file
    with pytest.raises(sqlite3.Error) as caught:
        WriteOncePersistentDict("t", container_dir=str(tmp_path / "db"))
    assert environment_fault(caught.value)
    assert "pytools' cache folder" in fault_words(caught.value), fault_words(caught.value)
    # build options the runtime refuses come out of pyopencl's cache as the same KeyError:
    # a fault of the device (or the options), not of the folders
    try:
        cl.Program(rt.context, "kernel void f(global float *a) { a[0] = 3.0f; }").build(
            options=["-bogus-option"])
    except Exception as exc:               # noqa: BLE001
        assert not environment_fault(exc), repr(exc)
    else:
        pytest.fail("the runtime built with -bogus-option")
