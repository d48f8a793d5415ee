"""The job layer (bdipole_cl/jobs): one plan per blur, one runner for every path.

A banded file blur plans once (not once per band), and the CLI batches, the scene bake and a
Dask bake all run their jobs through ``jobs.runner.run_job``."""
import numpy as np
import pytest
from test_scene import SCENE, make_files

from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.jobs import blur_file as blur_file_mod
from bdipole_cl.jobs import runner
from bdipole_cl.jobs.blur_file import blur_file
from bdipole_cl.ops.blur import plan as plan_mod
from bdipole_cl.ops.blur import planning


@pytest.fixture
def calls(monkeypatch):
    """Every ``run_job`` call, by job kind (the real runner still runs them)."""
    seen = []
    real = runner.run_job

    def spy(job, *args, **kwargs):
        seen.append(job.kind)
        return real(job, *args, **kwargs)
    monkeypatch.setattr(runner, "run_job", spy)
    return seen


def count_calls(monkeypatch, module, name):
    counter = {"n": 0}
    real = getattr(module, name)

    def counted(*args, **kwargs):
        counter["n"] += 1
        return real(*args, **kwargs)
    monkeypatch.setattr(module, name, counted)
    return counter


@pytest.mark.parametrize("textured", [False, True])
def test_a_banded_file_blur_plans_once(tmp_path, monkeypatch, runtime, textured):
    """48 rows in bands of a few rows: the channel plans (each channel's method and kernel,
    ``auto``'s choice) are made once for the file, and applied to every band."""
    h, w = 48, 40
    e = np.zeros((h, w, 3), np.float32)
    e[::7, ::5] = 1.0
    write_exr(tmp_path / "e.exr", e, ("R", "G", "B"))
    plans = count_calls(monkeypatch, plan_mod, "channel_plans")
    textured_plans = count_calls(monkeypatch, plan_mod, "textured_plans")
    chosen = count_calls(monkeypatch, planning, "plan_channel")
    bands = count_calls(monkeypatch, plan_mod.BlurPlan, "apply_band")
    albedo = (np.linspace(0.3, 0.7, h * w, dtype=np.float32).reshape(h, w) if textured
              else 0.5)
    info = blur_file(tmp_path / "e.exr", tmp_path / "m.exr", albedo=albedo, mfp=1.5,
                     max_memory=40 * 3 * 4 * 10 * 8, device=runtime)
    assert info is not None
    if textured:
        assert textured_plans["n"] == 1 and plans["n"] == 0
    else:
        assert plans["n"] == 1 and chosen["n"] == 3       # one plan of 3 channels
        assert bands["n"] > 1, "the test means nothing unless the file is blurred in bands"
    whole = blur_file_mod.plan_blur((h, w, 3), plan_mod.Scattering(albedo, 1.5),
                                    device=runtime).apply(e)[0]
    from test_dask import read
    # bands change the FFT's transform sizes, so its float32 round-off (a few ulps of the
    # image's maximum exitance, docs/model.md "Blur error bound") differs from one piece's
    np.testing.assert_allclose(read(tmp_path / "m.exr"), whole, rtol=0,
                               atol=16 * np.finfo(np.float32).eps * whole.max())


@pytest.fixture
def scene_files(tmp_path):
    make_files(tmp_path, tiles=("1001",))
    (tmp_path / "scene.toml").write_text(SCENE.replace("METHOD", ""))
    return tmp_path / "scene.toml"


def test_the_cli_batches_and_the_scene_bake_call_the_one_runner(tmp_path, scene_files, calls,
                                                                 on_device):
    root = scene_files.parent
    assert cli_main(["invert", str(root / "tex" / "grey.1001.exr"), "--mfp", "2",
                     "-o", str(tmp_path / "g.exr"), "--no-progress"]) == 0
    assert calls == ["invert"]
    assert cli_main(["blur", str(root / "light" / "irr.1001.exr"), "--albedo", "0.5",
                     "--mfp", "1", "-o", str(tmp_path / "b.exr"), "--no-progress"]) == 0
    assert calls == ["invert", "blur"]
    del calls[:]
    report = scenes.load(scene_files).plan().run()
    assert report.exit_code == 0, report.summary()
    assert sorted(calls) == ["blur", "invert", "invert"]


def test_a_dask_bake_calls_the_one_runner(scene_files, calls, on_device):
    """Dask maps the runner over the jobs (threads here, so the spy sees the calls)."""
    distributed = pytest.importorskip("distributed")
    from bdipole_cl import dask as bdask
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1,
                            dashboard_address=":0") as client:
        report = bdask.bake_on_cluster(scenes.load(scene_files).plan(), client,
                                       progress=False)
    assert report.exit_code == 0, report.summary()
    assert sorted(calls) == ["blur", "invert", "invert"]


def test_blur_refuses_a_mixed_parameter_pair(tmp_path, capsys):
    """--sigma-t belongs to --alpha-prime: with --albedo and --mfp it is a usage error, not
    silently dropped."""
    e = np.ones((8, 8, 3), np.float32)
    write_exr(tmp_path / "e.exr", e, ("R", "G", "B"))
    rc = cli_main(["blur", str(tmp_path / "e.exr"), "--albedo", "0.8", "--mfp", "2",
                   "--sigma-t", "1", "-o", str(tmp_path / "m.exr"), "--no-progress"])
    assert rc == 2 and "not both pairs" in capsys.readouterr().err
    assert not (tmp_path / "m.exr").exists()


def test_the_output_names_the_planned_methods_whatever_the_bands(tmp_path, runtime):
    """bdipole:methods comes from the plan, so a dark first band does not drop it."""
    import OpenImageIO as oiio
    e = np.zeros((64, 16, 1), np.float32)
    e[48:] = 1.0                                   # the first bands get no light
    write_exr(tmp_path / "e.exr", e, ("Y",))
    blur_file(tmp_path / "e.exr", tmp_path / "m.exr", albedo=0.5, mfp=1.0,
              max_memory=16 * 4 * 10 * 8, device=runtime)
    spec = oiio.ImageInput.open(str(tmp_path / "m.exr")).spec()
    assert "(r=" in spec.get_string_attribute("bdipole:methods")
