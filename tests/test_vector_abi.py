"""No crash on any CPU (bdipole_cl/device/guard.py, isolation.py, ops/kernel_checks.py).

PoCL 3.0's LLVM 14 calls a Zen 4 (family 25 model 17, AVX-512) 'znver3', without AVX-512: its
front end passes float16 arguments of built-ins (sqrt, vload16, select) through memory, while
the built-in library PoCL loads (chosen from the CPU's flags) takes them in registers. The
build log holds only a warning ("... without 'avx512f' enabled changes the ABI"); the program
then aborts in LLVM, or a warm cache gives it no kernels and the process aborts at exit. The
same mismatch is made on any AVX-512 CPU by handing PoCL's front end ``-target-feature
-avx512f`` (``runtime.TARGET_FEATURE_VARIABLE``); on such a Zen 4 it is the runtime's own.

Here: the reproduction fails as reported, the probe sees the mismatch and builds nothing
16 floats wide on that device (widths and record chunks capped at 8), jobs there run right, and
every stage of a width (build, binary, run, timing) that kills the probe's child rejects it.
Programs the probe never built go through the guard's child first: a crash there costs the
program (a narrower width is used, in one line), never the process."""
import json
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import bdipole_cl
from bdipole_cl.caches import CACHE_DIR_VARIABLE
from bdipole_cl.device import guard, isolation
from bdipole_cl.device import runtime as device
from bdipole_cl.device.children import child_env
from bdipole_cl.device.programs import kernels_digest
from bdipole_cl.device.runtime import TARGET_FEATURE_VARIABLE
from bdipole_cl.methods.choice import TABLE_WIDTHS_ALLOWED
from bdipole_cl.ops import inversion_kernel
from bdipole_cl.ops.blur.dispatch import record_chunk

from conftest import RUNTIMES


def _pocl():
    rt = next((rt for rt in RUNTIMES if device.is_pocl(rt.device)), None)
    if rt is None:
        pytest.skip("PoCL is not among the devices under test")
    return rt


def _intel_or_first():
    return next((rt for rt in RUNTIMES if "intel" in rt.device.platform.name.lower()),
                RUNTIMES[0])


def _cpu_has_avx512f() -> bool:
    try:
        return " avx512f" in open("/proc/cpuinfo").read()
    except OSError:
        return False


def _mismatch_env(tmp_path) -> dict:
    """A process with fresh caches (ours and PoCL's) and PoCL's float16 ABI mismatch: made
    with -avx512f on an AVX-512 CPU (a no-op where PoCL already misnames it)."""
    if not _cpu_has_avx512f():
        pytest.skip("the mismatch is simulated on AVX-512 CPUs only (on others, -avx512f "
                    "changes nothing and +avx512f gives no warning to detect)")
    env = dict(child_env(), **{CACHE_DIR_VARIABLE: str(tmp_path / "cache"),
                               "POCL_CACHE_DIR": str(tmp_path / "pocl"),
                               TARGET_FEATURE_VARIABLE: "-avx512f"})
    env.pop(isolation.FAULT_VARIABLE, None)
    env.pop(inversion_kernel.TABLE_WIDTH_VARIABLE, None)
    return env


def _run(code, env, timeout=600):
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, text=True,
                          capture_output=True, timeout=timeout)


#: the issue's reproduction: a[i] = sqrt(a[i]) on float16, built and run by hand (no probe)
RAW_FLOAT16 = """
    import numpy as np, pyopencl as cl
    from bdipole_cl.device.runtime import build_quietly, get_runtime, runtime_at, device_index
    rt = runtime_at(device_index(get_runtime("pocl").device))
    prg = build_quietly(rt.context, "__kernel void k(__global float16 *a) "
                        "{ const size_t i = get_global_id(0); a[i] = sqrt(a[i]); }")
    a = np.arange(64, dtype=np.float32)
    buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    prg.k(rt.queue, (4,), None, buf)
    cl.enqueue_copy(rt.queue, a, buf)
    print("RIGHT" if np.allclose(a, np.sqrt(np.arange(64))) else "WRONG")
"""


def test_the_reproduction_fails_unguarded_and_the_vector_abi_check_sees_it(tmp_path):
    """Built twice from a fresh PoCL cache by hand, the float16 kernel fails (an abort in LLVM,
    no kernel from the warm cache, or a wrong result): the hazard the probe must see. Its
    check (a build only, in a child: the probe's) flags float16 and passes float8."""
    _pocl()
    env = _mismatch_env(tmp_path)
    env[device.PROBE_CHILD_VARIABLE] = "1"          # no probe, no guard: the raw build
    runs = [_run(RAW_FLOAT16, env, timeout=400) for _ in range(2)]
    assert any(r.returncode != 0 or "RIGHT" not in r.stdout for r in runs), runs
    check = _run("""
        import json
        from bdipole_cl.device.runtime import get_runtime, runtime_at, device_index
        from bdipole_cl.ops.kernel_checks import vector_abi_reason
        rt = runtime_at(device_index(get_runtime("pocl").device))
        print(json.dumps([vector_abi_reason(rt, 16), vector_abi_reason(rt, 8)]))
    """, env)
    assert check.returncode == 0, check.stderr
    wide, eight = json.loads(check.stdout.strip().splitlines()[-1])
    assert "changes the ABI" in wide and "float16" in wide, wide
    assert eight == "", eight


#: a job on PoCL in a process of its own: the probe's verdict and choices, an inversion and a
#: texture-varying blur (their results saved for the parent), a forced width 16
JOB_ON_POCL = """
    import json, sys, numpy as np, bdipole_cl as bd
    from bdipole_cl.device import runtime as d
    from bdipole_cl.ops.inversion_kernel import table_width_choice
    from bdipole_cl.ops.blur.dispatch import gather_width, record_chunk
    from bdipole_cl.ops.widths import device_vector_cap
    rt = bd.get_runtime("pocl")
    v = d.verdict(rt.device)
    rd = np.random.default_rng(0).uniform(0, 1, 4099).astype(np.float32)
    _, rho = bd.invert_albedo(rd, 1.4, return_rho=True, device=rt)
    e = np.random.default_rng(1).random((96, 80, 2), np.float32)
    y, x = np.mgrid[0:96, 0:80]
    albedo = (0.4 + 0.4 * x / 79).astype(np.float32)
    exitance = bd.blur(e, albedo=albedo, mfp=(2.0 + y / 40).astype(np.float32), method="fft",
                       device=rt)
    np.save(sys.argv[1] + "/rho.npy", rho); np.save(sys.argv[1] + "/exitance.npy", exitance)
    width = table_width_choice(rt).width
    try:
        import os; os.environ["BDIPOLE_CL_TABLE_WIDTH"] = "16"; bd.clear_caches()
        bd.invert_albedo(rd, 1.3, device=rt); forced = "built"
    except bd.DeviceError as exc:
        forced = str(exc)
    print(json.dumps({"cap": v.vector_cap, "width": width,
                      "gather": gather_width(rt, 4096),
                      "chunk": record_chunk(23, device_vector_cap(rt)), "forced": forced,
                      "rejected": {r.name: r.reason for r in v.rejected()}}))
"""


def test_pocl_with_the_mismatch_keeps_within_8_floats_and_computes_right(tmp_path,
                                                                         tmp_path_factory):
    """On a device with the mismatch: the vector ABI check fails at 16, nothing 16 floats wide
    is built (each such configuration rejected unbuilt), the widths and record chunks stay
    within 8, forcing width 16 is one line, and an inversion and a texture-varying blur are
    right (the float64 reference; the device under test without the mismatch). Twice: the
    second process meets the PoCL cache the first one filled, as the issue's reproduction."""
    pocl = _pocl()
    env = dict(_mismatch_env(tmp_path), **{CACHE_DIR_VARIABLE: str(     # as the user kernel's
        tmp_path_factory.getbasetemp() / "mismatch-cache")})
    for attempt in range(2):
        out = tmp_path / f"run{attempt}"
        out.mkdir()
        r = subprocess.run([sys.executable, "-c", textwrap.dedent(JOB_ON_POCL), str(out)],
                           env=env, text=True, capture_output=True, timeout=900)
        assert r.returncode == 0, r.stderr[-3000:]
        assert "Traceback" not in r.stderr and "references to IRs" not in r.stderr, r.stderr
        said = json.loads(r.stdout.strip().splitlines()[-1])
        assert said["cap"] == 8, said
        assert said["width"] <= 8 and said["gather"] <= 8 and said["chunk"] == 8, said
        # those three and nothing else: every other family (the stretched gather, the FFTs,
        # the program's teardown) builds within the cap, in the probe's child too
        assert set(said["rejected"]) == {"vector_abi/w16", "invert_table/w16",
                                         "blur_textured/w16"}, said
        assert "not built" in said["rejected"]["invert_table/w16"], said
        assert "invert_table/w16 failed this device's probe" in said["forced"], said
        assert "\n" not in said["forced"], said
        rd = np.random.default_rng(0).uniform(0, 1, 4099).astype(np.float32)
        want = bdipole_cl.reference.invert_rd_rho(rd.astype(np.float64), 1.4)[1]
        rho = np.load(out / "rho.npy")
        # as the probe's and the crosscheck's table bound: a few float32 ulps relative
        np.testing.assert_allclose(rho, want, rtol=2e-5)
        e = np.random.default_rng(1).random((96, 80, 2), np.float32)
        y, x = np.mgrid[0:96, 0:80]
        here = bdipole_cl.blur(e, albedo=(0.4 + 0.4 * x / 79).astype(np.float32),
                               mfp=(2.0 + y / 40).astype(np.float32), method="fft",
                               device=_intel_or_first() if RUNTIMES[0] is not pocl
                               else RUNTIMES[0])
        # the same plan on two devices: their log and exp differ by ulps, which move the fine
        # table's coordinates (a logit and a log) and the interpolated weights, and float32
        # sums run in other orders (measured: 3.5e-5 of the peak); a miscompiled gather, the
        # hazard here, is off by orders of magnitude more (the probe's own check holds 30%)
        got = np.load(out / "exitance.npy")
        assert np.max(np.abs(got - here)) <= 1e-4 * np.max(np.abs(here))


def test_record_chunks_stay_within_the_devices_vector_cap():
    assert [record_chunk(n) for n in (1, 4, 5, 8, 9, 16, 17)] == [4, 4, 8, 8, 16, 16, 16]
    assert [record_chunk(n, 8) for n in (1, 4, 5, 8, 9, 16, 17)] == [4, 4, 8, 8, 8, 8, 8]
    assert [record_chunk(n, 4) for n in (3, 9)] == [4, 4]


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache folder, this process's verdicts and build records forgotten."""
    monkeypatch.setenv(CACHE_DIR_VARIABLE, str(tmp_path))
    saved = dict(isolation._verdicts)
    isolation.forget_verdicts()
    guard.forget_outcomes()
    bdipole_cl.clear_caches()
    yield tmp_path
    isolation.forget_verdicts()
    isolation._verdicts.update(saved)
    guard.forget_outcomes()
    bdipole_cl.clear_caches()


@pytest.fixture
def verdict_kept(fresh_cache):
    """``fresh_cache`` holding the current verdict of the Intel (or first) device: its probe
    is not run again, its guarded builds start from none."""
    rt = _intel_or_first()
    old = os.environ.pop(CACHE_DIR_VARIABLE)
    try:
        path = isolation.verdict_path(rt.device, kernels_digest())
        device.verdict(rt.device)
    finally:
        os.environ[CACHE_DIR_VARIABLE] = old
    isolation.forget_verdicts()
    fresh = isolation.verdict_path(rt.device, kernels_digest())
    fresh.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(path, fresh)
    return rt


def test_a_death_while_timing_a_width_rejects_that_width(monkeypatch, fresh_cache):
    """A width that passed its check but kills the child while it is timed is rejected (it
    had cost only the timings), and the other timings are kept."""
    rt = _intel_or_first()
    monkeypatch.setenv(isolation.FAULT_VARIABLE, "time:invert_table/w8=segv")
    verdict = device.verdict(rt.device)
    bad = verdict.result("invert_table/w8")
    assert not bad.ok and "SIGSEGV" in bad.reason and "timing it" in bad.reason, bad
    assert verdict.works and verdict.result("invert_table/w4").seconds is not None, verdict
    assert any(r.name.startswith("blur-timing/") and r.seconds for r in verdict.results)
    assert inversion_kernel.table_width_choice(rt).width != 8


def test_a_child_dying_at_its_teardown_is_said_not_fatal(monkeypatch, fresh_cache):
    rt = _intel_or_first()
    monkeypatch.setenv(isolation.FAULT_VARIABLE, "exit=abort:still have references to IRs")
    verdict = device.verdict(rt.device)
    assert verdict.works and not verdict.transient, verdict
    assert "references to IRs" in verdict.result(isolation.EXIT).reason
    assert verdict.passed("invert_table/w16") and verdict.passed("blur_textured/w8")


def test_a_failed_vector_abi_check_builds_nothing_that_wide(monkeypatch, fresh_cache):
    """A child that dies checking float16 rejects it as the ABI warning does: every
    configuration of 16 floats is rejected unbuilt, the cap is 8."""
    rt = _intel_or_first()
    monkeypatch.setenv(isolation.FAULT_VARIABLE, "vector_abi/w16=segv")
    verdict = device.verdict(rt.device)
    assert verdict.vector_cap == 8 and verdict.works
    for name in ("invert_table/w16", "blur_textured/w16"):
        assert "not built" in verdict.result(name).reason, verdict
    assert verdict.passed("invert_table/w8") and verdict.passed("vector_abi/w8")
    assert inversion_kernel.table_width_choice(rt).width <= 8


def test_each_forced_width_builds_its_own_kernel(runtime, monkeypatch):
    """Prepared kernels are kept per width (the probe's checks of widths 2-16 all ran the
    first width's kernel when the width was not in the key)."""
    from bdipole_cl.methods.registry import MethodConfig
    from bdipole_cl.ops.widths import passes
    rd = np.float32([1e-4, 0.3, 0.9, 0.5, 0.7])
    want = bdipole_cl.reference.invert_rd(rd.astype(np.float64), 1.4)
    for width in TABLE_WIDTHS_ALLOWED:
        if not passes(runtime, "invert_table", width):
            continue
        monkeypatch.setenv(inversion_kernel.TABLE_WIDTH_VARIABLE, str(width))
        kernel = inversion_kernel.inversion_kernel((1.4,), MethodConfig(), runtime=runtime)
        assert kernel.width == width
        np.testing.assert_allclose(bdipole_cl.invert_albedo(rd, 1.4, device=runtime), want,
                                   rtol=1e-4)


def test_a_program_that_crashes_its_guarded_build_costs_a_width(monkeypatch, verdict_kept,
                                                                 caplog):
    """The guard's child dies building the chosen width's program: a narrower width is used
    (said in one line), the refusal is kept on disk, and another process reads it (no new
    child) and falls back alike."""
    rt = verdict_kept
    width = inversion_kernel.table_width_choice(rt).width
    if width == 1:
        monkeypatch.setenv(inversion_kernel.TABLE_WIDTH_VARIABLE, "2")
        width = 2
    monkeypatch.setenv(isolation.FAULT_VARIABLE, f"build:BD_WIDTH={width} =segv;"
                       f"build:BD_WIDTH={width}=segv")
    rd = np.float32([1e-4, 0.3, 0.9])
    want = bdipole_cl.reference.invert_rd(rd.astype(np.float64), 1.4)
    with caplog.at_level("WARNING", logger="bdipole_cl"):
        got = bdipole_cl.invert_albedo(rd, 1.4, device=rt)
    np.testing.assert_allclose(got, want, rtol=1e-4)
    said = [r.getMessage() for r in caplog.records if "guard" not in r.getMessage()
            and "child process" in r.getMessage()]
    assert len(said) == 1 and f"-DBD_WIDTH={width}" in said[0] and "SIGSEGV" in said[0], said
    assert "narrower width" in said[0] and "\n" not in said[0]
    folder = guard.records_dir(rt.device, kernels_digest())
    assert [p.suffix for p in folder.iterdir()].count(".bad") == 1

    env = dict(child_env())
    env.pop(isolation.FAULT_VARIABLE, None)              # no fault: the record refuses it
    r = _run(f"""
        import numpy as np, bdipole_cl as bd
        rt = bd.get_runtime({_spec(rt)!r})
        print(bd.invert_albedo(np.float32([1e-4, 0.3, 0.9]), 1.4, device=rt).tolist())
    """, env)
    assert r.returncode == 0, r.stderr
    assert "SIGSEGV" in r.stderr and "narrower width" in r.stderr, r.stderr
    np.testing.assert_allclose(eval(r.stdout), want, rtol=1e-4)


def _spec(rt):
    return "intel" if "intel" in rt.device.platform.name.lower() else device.device_index(
        rt.device)


def test_a_kernel_without_a_narrower_width_is_refused_in_one_line(monkeypatch, verdict_kept,
                                                                   tmp_path):
    """The direct blur's program crashes its guarded build: the blur fails with one line
    naming the program and the crash (the API's DeviceError; the command's exit 1), and the
    process goes on."""
    from bdipole_cl.apps.cli import main as cli_main
    rt = verdict_kept
    monkeypatch.setenv(isolation.FAULT_VARIABLE, "build:BD_TILE=segv")
    e = np.zeros((40, 40, 1), np.float32)
    e[20, 20] = 1
    with pytest.raises(bdipole_cl.DeviceError, match=r"blur_direct.cl with .*crashed this "
                                                     r"device's runtime in a child process "
                                                     r"\(crashed \(SIGSEGV\)"):
        bdipole_cl.blur(e, albedo=0.6, mfp=2.0, method="direct", device=rt)
    assert bdipole_cl.blur(e, albedo=0.6, mfp=2.0, method="fft", device=rt).sum() > 0.5
    import OpenImageIO as oiio
    src = str(tmp_path / "e.exr")
    assert oiio.ImageBuf(e).write(src)
    monkeypatch.setattr(device, "_default", None)
    rc = cli_main(["--device", device.device_index(rt.device), "blur", src, "--albedo", "0.6",
                   "--mfp", "2", "--method", "direct", "-o", str(tmp_path / "out.exr")])
    assert rc != 0 and not (tmp_path / "out.exr").exists()


def test_a_python_error_in_the_guarded_build_is_no_crash(monkeypatch, verdict_kept):
    """A Python error in the guarded build's child (pyopencl's cache folder unwritable raised
    a KeyError there) is no crash of the runtime: nothing is recorded as one, and the
    program is built here (it was refused as "crashed" until the cache was cleared)."""
    rt = verdict_kept
    monkeypatch.setenv(isolation.FAULT_VARIABLE, "build:BD_TILE=raise:no cache folder")
    e = np.zeros((40, 40, 1), np.float32)
    e[20, 20] = 1
    assert bdipole_cl.blur(e, albedo=0.6, mfp=2.0, method="direct", device=rt).sum() > 0.5
    folder = guard.records_dir(rt.device, kernels_digest())
    assert not [p for p in folder.iterdir() if p.suffix == ".bad"]


def test_cache_clear_removes_the_guarded_builds_records(verdict_kept):
    from bdipole_cl.apps.cache import clear, own_entries
    rt = verdict_kept
    bdipole_cl.invert_albedo(np.float32([0.5]), 1.37, device=rt)
    folder = guard.records_dir(rt.device, kernels_digest())
    assert any(p.suffix == ".ok" for p in folder.iterdir())
    assert folder in [e.path for e in own_entries()]
    clear()
    assert not folder.exists()


def test_a_width_past_the_vector_cap_is_never_chosen(monkeypatch):
    """``widths.choose_width`` on a device whose vector cap is 8 (the probe's child, which
    has no verdict yet, sets it after its vector ABI check) never picks 16, whatever the
    default or calibration says."""
    from bdipole_cl.ops.widths import VECTOR_CAP_VARIABLE, choose_width
    monkeypatch.setenv(VECTOR_CAP_VARIABLE, "8")
    rt = RUNTIMES[0]
    assert choose_width(rt, "blur_stretched", (1, 2, 4, 8, 16), None, 16).width <= 8
    assert choose_width(rt, "blur_stretched", (1, 2, 4, 8, 16), 16, 16).width <= 8


#: a user's function with 16-float vectors (crosscheck --user-kernel --against rd)
USER_FLOAT16 = """\
float rdf(float a, float two_c1, float three_c2)
{
    float16 v = (float16)(a);
    v = sqrt(v * v);
    float s = v.s0, t = sqrt(3.0f * (1.0f - s));
    return 0.5f * s * (1.0f + exp(-(4.0f / 3.0f) * (1.0f + two_c1) / (1.0f - three_c2) * t))
           * exp(-t);
}
"""


def test_a_user_kernel_the_mismatch_breaks_fails_naming_it_both_times(tmp_path,
                                                                      tmp_path_factory):
    """A user's kernel with 16-float vectors on PoCL with the mismatch: its run dies in the
    child (cold PoCL cache), then builds to a program without its kernel (warm cache); both
    times a failed run (exit 1) naming the file and function, never a usage error (2)."""
    _pocl()
    # the probe's verdict under the mismatch: made once for the module's tests (a cold probe
    # of PoCL takes a minute); PoCL's own cache is this test's, cold for the user's program
    env = dict(_mismatch_env(tmp_path), **{CACHE_DIR_VARIABLE: str(
        tmp_path_factory.getbasetemp() / "mismatch-cache")})
    src = tmp_path / "f16.cl"
    src.write_text(USER_FLOAT16)
    for attempt in range(2):
        r = subprocess.run([sys.executable, "-m", "bdipole_cl.apps.cli", "--device", "pocl",
                            "crosscheck", "--user-kernel", str(src), "--function", "rdf",
                            "--against", "rd", "--n", "20"],
                           env=env, text=True, capture_output=True, timeout=600)
        last = r.stderr.strip().splitlines()[-1]
        assert r.returncode == 1, (attempt, r.stderr[-2000:])
        assert str(src) in last and "rdf" in last and "Traceback" not in r.stderr, last
