"""Error-vs-runtime report (bdipole_cl/apps/report.py) and method='auto'."""
import logging
import os
from pathlib import Path

import numpy as np
import pytest

from bdipole_cl import invert_albedo
from bdipole_cl import reference as ref
from bdipole_cl.apps.report import Point, mark_pareto, read_csv, run_report
from bdipole_cl.methods.choice import (AUTO_MARGIN, auto_inversion_config, load_choice_data,
                                       resolve_method)


#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")


@pytest.mark.parametrize("tol", [1e-3, 1e-5, 1e-6])
def test_auto_picks_the_cheapest_measured_config_meeting_tol(tol, caplog):
    data = [c for c in load_choice_data().inversion if c.precision == "f32"]
    choice = auto_inversion_config(tol)
    assert choice.max_rho_error <= tol
    cheaper = [c for c in data if c.median_s < choice.median_s]
    assert all(c.max_rho_error * AUTO_MARGIN > tol for c in cheaper)   # nothing cheaper qualifies
    # and the choice really meets tol on a fresh stiff sweep
    rd = np.float32(np.concatenate([np.geomspace(1e-6, 0.5, 2000), 1 - np.geomspace(1e-3, 0.5, 2000)]))
    with caplog.at_level(logging.INFO, logger="bdipole_cl"):
        a, rho = invert_albedo(rd, 1.4, "auto", tol=tol, return_rho=True)
    assert "picked" in caplog.text
    want = ref.invert_rd_rho(rd.astype(np.float64), 1.4)[1]
    assert np.max(np.abs(rho / want - 1)) <= tol


def test_auto_without_a_reachable_tol_is_a_clear_error():
    with pytest.raises(ValueError, match="no monotone f32 configuration reaches it over eta"):
        resolve_method("auto", tol=1e-12)


def test_pareto_marking():
    pts = [Point("inversion", "a", "a1", "f32", 1.0, 1e-3, 0), Point("inversion", "a", "a2", "f32", 2.0, 1e-6, 0),
           Point("inversion", "b", "b1", "f32", 3.0, 1e-3, 0), Point("blur", "c", "c1", "f32", 9.0, 1.0, 0)]
    mark_pareto(pts)
    assert [p.pareto for p in pts] == [True, True, False, True]


def test_small_report_run_writes_table_csv_plot(tmp_path):
    """The report's table, CSV and plot (on the first device: tests/conftest.py's
    ONE_DEVICE_MODULES; every kernel it times is checked on every device elsewhere)."""
    points = run_report(tmp_path, n=4096, blur_size=32, repeats=1, progress=lambda *_: None)
    methods = {p.method.split()[0] for p in points}
    assert {"memo", "bisection", "secant", "table", "direct", "gaussians", "fft"} <= methods
    assert all(np.isfinite(p.max_error) and p.seconds > 0 for p in points)
    md = (tmp_path / "report.md").read_text()
    assert "| inversion config |" in md and "| blur mfp 0.5 config |" in md and "Device:" in md
    assert len(read_csv(tmp_path / "report.csv")) == len(points)
    assert (tmp_path / "report.png").stat().st_size > 10_000
    assert any(p.pareto for p in points if p.kind == "inversion")


@pytest.mark.parametrize("tol", [2e-3, 2e-4, 3e-5])
def test_blur_auto_picks_a_measured_config_meeting_tol(tol):
    from bdipole_cl.ops.blur import blur, channel_kernel, channel_parameters
    from bdipole_cl.ops.blur.fft import fft_blur_channel
    from bdipole_cl.ops.blur.planning import auto_data
    e = np.random.default_rng(4).uniform(0, 1, (40, 40, 1)).astype(np.float32)
    out, info = blur(e, albedo=0.8, mfp=3.0, tol=tol, method="auto", return_info=True)
    picked = info.channels[0].auto
    data = auto_data().data.blur      # the timings auto decides from on this device
    # only truncations no looser than tol are candidates (docs/model.md "Blur error bound"):
    # below every measured truncation, the radius rule at truncation tol
    assert picked.truncation_tol <= tol and info.channels[0].error_bound <= tol, picked
    if picked.rule == "radius":
        assert tol < min(d.tol for d in data) and picked.truncation_tol == tol, picked
    else:
        assert picked.measured_error <= tol, picked
        same = [d for d in data if d.radius == picked.workload_radius and d.tol <= tol
                and d.max_error <= tol]
        assert picked.measured_ms == pytest.approx(min(d.median_s for d in same) * 1e3)
    # and it holds here: error vs the exact discrete convolution relative to max(E) * Rd
    p = channel_parameters(1, albedo=0.8, mfp=3.0, eta=1.4)[0]
    exact_k = channel_kernel(*p, 1e-9)
    exact = fft_blur_channel(e[..., 0], exact_k.weights, "clamp")
    assert np.abs(out[..., 0] - exact).max() / (e.max() * exact_k.rd) <= tol
    # banded with halos, the same answer (the halo follows the picked truncation)
    banded = blur(e, albedo=0.8, mfp=3.0, tol=tol, method="auto", max_memory=40 * 4 * 8 * 30)
    np.testing.assert_allclose(banded, out, rtol=1e-5, atol=1e-6)


def test_copy_kernel_floor_copies_and_times():
    # kernels/copy.cl: the memory-bound floor the benchmarks compare against
    import pyopencl as cl

    from bdipole_cl.apps.benchmark import time_copy
    from bdipole_cl.device import build_options, get_program, get_runtime
    rt = get_runtime()
    knl = cl.Kernel(get_program(rt, "copy", build_options()), "copy")
    src = np.arange(1000, dtype=np.float32)
    mf = cl.mem_flags
    a = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=src)
    b = cl.Buffer(rt.context, mf.WRITE_ONLY, src.nbytes)
    knl(rt.queue, (src.size,), None, a, b, np.uint64(src.size))
    dst = np.empty_like(src)
    cl.enqueue_copy(rt.queue, dst, b)
    rt.queue.finish()
    np.testing.assert_array_equal(dst, src)
    assert time_copy(1 << 16, repeats=2) > 0


def test_a_report_into_a_place_it_cannot_write_is_refused_before_measuring(tmp_path,
                                                                           monkeypatch, capsys):
    """-o in a read-only place (a read-only mount: os.access says so, for root too) is a usage
    error before anything is measured (it measured ~25 s, then failed writing, exit 1)."""
    from bdipole_cl.apps import report
    from bdipole_cl.apps.cli import main as cli_main
    ro = tmp_path / "ro"
    ro.mkdir()
    real_access = os.access
    monkeypatch.setattr(report.os, "access",
                        lambda p, mode: False if Path(p) == ro else real_access(p, mode))
    monkeypatch.setattr(report, "run_report", lambda *a, **k: pytest.fail("measured"))
    assert cli_main(["report", "-o", str(ro / "sub")]) == 2
    assert f"-o {ro / 'sub'}: {ro} cannot be written" in capsys.readouterr().err
