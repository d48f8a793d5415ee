"""Inputs that change while a run reads them (bdipole_cl/io/freshness.py ``InputGuard``, the
jobs' and Dask's commits): a job whose input was re-exported in place or overwritten between
its first and last read fails, named, and writes nothing, on every path. The change is made
deterministically, by the test, between two band reads (a patched ``Reader.read_band``)."""
import os

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.io import images
from bdipole_cl.io.freshness import InputChanged, input_identities

pytestmark = pytest.mark.usefixtures("on_device")

H, W = 64, 16
#: a band budget of a few rows, so that a file is read in several bands
SMALL = str(W * 4 * 3 * 40 * 4)


def write_plain(path, value):
    """An uncompressed float EXR (its rows at fixed offsets: an in-place overwrite keeps its
    size) of one RGB ``value`` per row, rising with y."""
    rows = np.linspace(0.3, 0.7, H, dtype=np.float32)[:, None, None]
    px = np.ascontiguousarray(np.broadcast_to(rows * np.float32(value), (H, W, 3)))
    spec = oiio.ImageSpec(W, H, 3, "float")
    spec.channelnames = ("R", "G", "B")
    spec.attribute("compression", "none")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(px), oiio.geterror()
    out.close()


def change_during_read(monkeypatch, path, how, after=1):
    """Change ``path`` once, after ``after`` band reads of it: "re-export" writes a new file
    and renames it onto the name (a new inode: the reader holds the old one), "overwrite"
    writes the new content into the same file in place (the rows read after it are new)."""
    real, seen = images.Reader.read_band, {"n": 0}

    def read_band(self, y0, y1):
        px = real(self, y0, y1)
        if os.path.samefile(self.path, path) and seen["n"] >= 0:
            seen["n"] += 1
            if seen["n"] == after:
                seen["n"] = -1
                new = path.with_name("new_" + path.name)
                write_plain(new, 0.5)
                if how == "re-export":
                    os.replace(new, path)
                else:
                    data = new.read_bytes()
                    with open(path, "r+b") as f:
                        f.write(data)
                    new.unlink()
        return px
    monkeypatch.setattr(images.Reader, "read_band", read_band)
    return seen


@pytest.mark.parametrize("how", ["re-export", "overwrite"])
def test_cli_invert_fails_an_input_changed_during_its_read_and_skip_existing_redoes_it(
        tmp_path, monkeypatch, capsys, how):
    """Re-exported in place, the albedo gave an 'ok' output of the old content whose time is
    newer than the input's, so --skip-existing kept it for ever; overwritten in place, rows of
    both versions. Now the job fails, naming the file, nothing is written, and the next run
    makes the output of the new content."""
    a, out = tmp_path / "a.exr", tmp_path / "o" / "a.exr"
    write_plain(a, 1.0)
    argv = ["invert", str(a), "-o", str(out), "--skip-existing", "--no-progress",
            "--max-memory", SMALL]
    seen = change_during_read(monkeypatch, a, how)
    assert cli_main(argv) == 1
    assert seen["n"] == -1                       # the change was made mid-read
    err = capsys.readouterr()
    assert f"{a}: the albedo changed while the job read it" in err.out + err.err
    assert not out.exists()
    monkeypatch.undo()
    assert cli_main(argv) == 0
    write_plain(tmp_path / "b.exr", 0.5)        # the new content, inverted on its own
    assert cli_main(["invert", str(tmp_path / "b.exr"), "-o", str(tmp_path / "b_out.exr"),
                     "--no-progress"]) == 0
    got, want = (images.read_whole(p, "check")[1] for p in (out, tmp_path / "b_out.exr"))
    assert np.array_equal(got, want)


def test_cli_invert_fails_when_its_mfp_texture_changes_between_bands(tmp_path, monkeypatch,
                                                                    capsys):
    """Every input of a job is watched, not only the file it is named by: an mfp texture
    overwritten between two of its band reads fails the job, named as the mfp."""
    a, mfp, out = tmp_path / "a.exr", tmp_path / "mfp.exr", tmp_path / "o.exr"
    write_plain(a, 1.0)
    write_plain(mfp, 2.0)
    change_during_read(monkeypatch, mfp, "overwrite")
    assert cli_main(["invert", str(a), "--mfp", str(mfp), "-o", str(out), "--no-progress",
                     "--max-memory", SMALL]) == 1
    captured = capsys.readouterr()
    assert f"{mfp}: the mfp changed while the job read it (it was rewritten)" in \
        captured.out + captured.err
    assert not out.exists()


def test_a_texture_output_is_not_put_in_place_over_a_changed_input(tmp_path, monkeypatch,
                                                                   capsys):
    """--texture builds the mip-mapped file after the bands: the check runs after that build,
    just before the rename, so that path is guarded too."""
    a, out = tmp_path / "a.exr", tmp_path / "o.exr"
    write_plain(a, 1.0)
    change_during_read(monkeypatch, a, "re-export")
    assert cli_main(["invert", str(a), "-o", str(out), "--texture", "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert f"{a}: the albedo changed while the job read it" in captured.out + captured.err
    assert not out.exists() and not list(tmp_path.glob(".o.partial-*"))


def test_cli_blur_fails_when_its_irradiance_or_a_parameter_texture_changes(
        tmp_path, monkeypatch, capsys):
    """The irradiance overwritten between two bands, or the albedo texture re-exported after
    the CLI read it (before the irradiance's bands were blurred): the blur fails, named,
    nothing written."""
    e, alb, out = tmp_path / "e.exr", tmp_path / "alb.exr", tmp_path / "m.exr"
    write_plain(e, 1.0)
    write_plain(alb, 1.0)
    change_during_read(monkeypatch, e, "overwrite")
    argv = ["blur", str(e), "-o", str(out), "--albedo", "0.5", "--mfp", "2", "--no-progress",
            "--max-memory", SMALL]
    assert cli_main(argv) == 1
    assert f"{e}: the irradiance changed while the job read it" in capsys.readouterr().err
    assert not out.exists()
    monkeypatch.undo()
    real = images.read_parameter_texture

    def read_then_reexport(path, *args, **kwargs):
        px = real(path, *args, **kwargs)
        write_plain(tmp_path / "new.exr", 0.5)
        os.replace(tmp_path / "new.exr", path)
        return px
    monkeypatch.setattr(images, "read_parameter_texture", read_then_reexport)
    argv[5] = str(alb)                           # --albedo alb.exr
    assert cli_main(argv) == 1
    assert f"{alb}: the albedo changed while the job read it (it was replaced by another " \
        f"file" in capsys.readouterr().err
    assert not out.exists()


SCENE = """
[defaults]
eta = 1.4
tol = 1e-3

[[material]]
name = "skin"
albedo = "tex/a.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
output = "out/skin.<UDIM>.exr"
"""


def test_a_scene_job_whose_albedo_changed_since_the_plan_read_it_fails_alone(tmp_path):
    """The plan reads each albedo (its statistics choose the method); re-exported before the
    bake reaches it, that tile's job fails, named, nothing written, and the other tile
    bakes; the next bake makes it."""
    (tmp_path / "tex").mkdir()
    for tile in ("1001", "1002"):
        write_plain(tmp_path / "tex" / f"a.{tile}.exr", 1.0)
    (tmp_path / "scene.toml").write_text(SCENE)
    plan = scenes.load(tmp_path / "scene.toml").plan()
    write_plain(tmp_path / "tex" / "new.exr", 0.5)
    os.replace(tmp_path / "tex" / "new.exr", tmp_path / "tex" / "a.1001.exr")
    report = plan.run()
    by_tile = {r.output.rsplit(".", 2)[-2]: r for r in report.results}
    assert by_tile["1001"].status == "failed" and "the albedo changed while the job read " \
        "it" in by_tile["1001"].error, report.summary()
    assert by_tile["1002"].status == "ok"
    assert not (tmp_path / "out" / "skin.1001.exr").exists()
    again = scenes.load(tmp_path / "scene.toml").plan().run()
    assert again.exit_code == 0 and (tmp_path / "out" / "skin.1001.exr").exists()


def test_dask_tasks_check_the_identity_the_client_first_read(tmp_path):
    """On a cluster the client reads first: a scene job sent with the plan's identities, and a
    blur band with the client's, fail when the file on the worker is another (no cluster
    started: the worker functions are called here)."""
    from bdipole_cl.dask import blur_band_task, run_on_worker
    from bdipole_cl.jobs.blur_file import file_plan
    from bdipole_cl.jobs.scene import scene_job
    from bdipole_cl.ops.blur import Scattering
    (tmp_path / "tex").mkdir()
    write_plain(tmp_path / "tex" / "a.1001.exr", 1.0)
    (tmp_path / "scene.toml").write_text(SCENE)
    plan = scenes.load(tmp_path / "scene.toml").plan()
    old = input_identities({"irradiance": tmp_path / "tex" / "a.1001.exr"})["irradiance"]
    write_plain(tmp_path / "tex" / "new.exr", 0.5)
    os.replace(tmp_path / "tex" / "new.exr", tmp_path / "tex" / "a.1001.exr")
    result = run_on_worker(scene_job(plan.jobs[0], plan.scene))
    assert result.status == "failed" and "changed while the job read it" in result.error
    spec = images.image_header(tmp_path / "tex" / "a.1001.exr")
    blur_plan = file_plan("a", spec, ["R", "G", "B"], Scattering(0.5, 2.0, 1.4, 1.0), {}, {})
    band = blur_band_task(str(tmp_path / "tex" / "a.1001.exr"), str(tmp_path / "b.exr"), 0, 8,
                          blur_plan, "auto", None, identity=old)
    assert isinstance(band, InputChanged) and "it was replaced by another file" in str(band)
    assert not (tmp_path / "b.exr").exists()


def test_cli_convert_fails_an_input_changed_during_its_read(tmp_path, monkeypatch, capsys):
    """The conversion (bdipole-cl convert) is a path of its own: an albedo overwritten between
    its band reads fails the job, named, nothing written."""
    a, out = tmp_path / "a.exr", tmp_path / "o" / "a.exr"
    write_plain(a, 1.0)
    seen = change_during_read(monkeypatch, a, "overwrite")
    assert cli_main(["convert", str(a), "--radius", "1", "--source", "pxrsurface", "--target",
                     "openpbr", "-o", str(out), "--max-memory", SMALL]) == 1
    assert seen["n"] == -1
    err = capsys.readouterr()
    assert f"{a}: the albedo changed while the job read it" in err.out + err.err
    assert not out.exists()
