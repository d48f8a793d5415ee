"""Scenes (bdipole_cl/io/scene.py, scene_file.py; ``bdipole-cl plan/bake``)."""
import json
import os

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import reference as ref
from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.blur_file import blur_file

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

N = 24


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    px = np.asarray(inp.read_image(oiio.FLOAT))
    names = list(inp.spec().channelnames)
    inp.close()
    return px, names


def channel(px, names, name):
    return px[..., names.index(name)]


def make_files(root, tiles=("1001", "1002")):
    """RGB + alpha skin tiles (white outside a disc), a grey tile, and irradiance tiles."""
    (root / "tex").mkdir(parents=True, exist_ok=True)
    (root / "light").mkdir(exist_ok=True)
    yy, xx = np.mgrid[0:N, 0:N] / N
    for k, tile in enumerate(tiles):
        disc = ((xx - 0.5) ** 2 + (yy - 0.5) ** 2 < 0.1 + 0.02 * k).astype(np.float32)
        rgb = np.stack([0.5 + 0.3 * xx, 0.3 + 0.2 * yy, 0.2 + 0.1 * xx + 0.01 * k], -1)
        rgb = np.where(disc[..., None] > 0, rgb, 1.0)
        write_exr(root / "tex" / f"skin.{tile}.exr", np.concatenate([rgb, disc[..., None]], -1),
                  ("R", "G", "B", "A"))
        light = np.zeros((N, N, 3), np.float32)
        light[N // 3:N // 3 + 2] = 3.0
        write_exr(root / "light" / f"irr.{tile}.exr", light, ("R", "G", "B"))
    write_exr(root / "tex" / "grey.1001.exr", 0.4 + 0.4 * yy, ("Y",))


SCENE = """
[defaults]
eta = 1.4
tol = 1e-4

[[material]]
name = "skin"
albedo = "tex/skin.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
outputs = ["sigma_a", "sigma_s"]
output = "out/skin.<UDIM>.exr"
mask = "alpha"
METHOD

[[material]]
name = "grey"
albedo = "tex/grey.<UDIM>.exr"
mfp = 2.0
outputs = ["rho", "sigma_t"]
output = "out/grey.<UDIM>.exr"

[[blur]]
name = "tsd"
material = "skin"
irradiance = "light/irr.<UDIM>.exr"
texel_size = 0.2
tol = 1e-3
output = "out/exitance.<UDIM>.exr"
"""


@pytest.fixture
def scene_dir(tmp_path):
    make_files(tmp_path)
    (tmp_path / "scene.toml").write_text(SCENE.replace("METHOD", 'method = "table"'))
    return tmp_path


def bake(path, **kw):
    return scenes.load(path).plan(**kw).run()


def test_outputs_equal_the_single_file_commands(scene_dir):
    report = bake(scene_dir / "scene.toml")
    assert report.exit_code == 0, report.summary()
    # the inversion: bit for bit what `bdipole-cl invert` writes for the same parameters (the
    # scene's specialised kernel computes the same float operations), masked texels 0
    single = process_textures(str(scene_dir / "tex" / "skin.1001.exr"), mfp=(1.2, 0.6, 0.3),
                              eta=1.4, method="table", on_invalid="clamp",
                              output=str(scene_dir / "single" / "{stem}.exr"))
    assert single.exit_code == 0
    got, names = read(scene_dir / "out" / "skin.1001.exr")
    want, wnames = read(scene_dir / "single" / "skin.1001.exr")
    disc = channel(got, names, "A") > 0
    for name in ("sigma_a.R", "sigma_s.G", "sigma_a.B"):
        np.testing.assert_array_equal(channel(got, names, name)[disc],
                                      channel(want, wnames, name)[disc])
        assert np.all(channel(got, names, name)[~disc] == 0)
    # the blur: what blur_file gives with the material's albedo and mfp, within round-off
    src, _ = read(scene_dir / "tex" / "skin.1001.exr")
    albedo = np.where(disc[..., None], src[..., :3], src[..., :3][disc].min(axis=0))
    blur_file(scene_dir / "light" / "irr.1001.exr", scene_dir / "single" / "e.exr",
              albedo=albedo, mfp=(1.2, 0.6, 0.3), eta=1.4, texel_size=0.2, tol=1e-3,
              mask=disc)
    got_e, _ = read(scene_dir / "out" / "exitance.1001.exr")
    want_e, _ = read(scene_dir / "single" / "e.exr")
    np.testing.assert_allclose(got_e, want_e, rtol=1e-5, atol=1e-7)
    assert np.all(got_e[~disc] == 0) and got_e[disc].max() > 0


def test_grey_and_rgb_and_only_the_outputs_asked_for(scene_dir):
    assert bake(scene_dir / "scene.toml").exit_code == 0
    _, names = read(scene_dir / "out" / "grey.1001.exr")
    assert sorted(names) == ["rho.Y", "sigma_t.Y"]
    _, names = read(scene_dir / "out" / "skin.1002.exr")
    assert sorted(names) == ["A"] + sorted(f"{o}.{c}" for o in ("sigma_a", "sigma_s")
                                           for c in "RGB")


def test_auto_picks_a_table_for_the_albedos_present_and_meets_tol(tmp_path):
    make_files(tmp_path)
    (tmp_path / "scene.toml").write_text(SCENE.replace("METHOD", ""))
    plan = scenes.load(tmp_path / "scene.toml").plan()
    job = next(j for j in plan.jobs if j.name == "grey")
    assert job.config.method == "table" and job.config.table_size < 256
    assert any("albedos present" in c for c in job.computes)
    assert plan.run().exit_code == 0
    px, names = read(tmp_path / "out" / "grey.1001.exr")
    rd = read(tmp_path / "tex" / "grey.1001.exr")[0][..., 0].astype(np.float64)
    want = ref.invert_rd_rho(rd, 1.4)[1]
    assert np.max(np.abs(channel(px, names, "rho.Y") / want - 1)) <= 1e-4


def test_masked_white_background_is_no_error_and_is_written_as_zero(scene_dir):
    # the skin tiles are 1.0 (an invalid albedo) outside the disc: masked, so no error
    report = bake(scene_dir / "scene.toml")
    assert report.exit_code == 0, report.summary()
    px, names = read(scene_dir / "out" / "skin.1002.exr")
    alpha = channel(px, names, "A")
    assert set(np.unique(alpha)) == {0.0, 1.0}               # the mask's alpha is kept
    assert np.all(px[alpha == 0][:, [i for i, n in enumerate(names) if n != "A"]] == 0)
    plan = scenes.load(scene_dir / "scene.toml").plan(force=True)
    skin = next(j for j in plan.jobs if j.name == "skin")
    assert any("masked by the albedo alpha" in x for x in skin.left_out)


def test_a_second_bake_rewrites_nothing_and_a_changed_tile_only_its_outputs(scene_dir):
    path = scene_dir / "scene.toml"
    assert bake(path).exit_code == 0
    outs = sorted((scene_dir / "out").iterdir())
    before = {p.name: p.stat().st_mtime_ns for p in outs}
    report = bake(path)
    assert [r.status for r in report.results] == ["skipped"] * len(report.results)
    assert {p.name: p.stat().st_mtime_ns for p in outs} == before
    # touched but unchanged: still up to date (the content decides)
    os.utime(scene_dir / "tex" / "skin.1002.exr")
    assert all(j.up_to_date for j in scenes.load(path).plan().jobs)
    # tile 1002 of the albedo changes: its inversion and its blur rebuild, nothing else
    px, _ = read(scene_dir / "tex" / "skin.1002.exr")
    px[..., 0] *= 0.9
    write_exr(scene_dir / "tex" / "skin.1002.exr", px, ("R", "G", "B", "A"))
    plan = scenes.load(path).plan()
    todo = sorted((j.kind, j.udim) for j in plan.jobs if not j.up_to_date)
    assert todo == [("blur", "1002"), ("invert", "1002")]
    plan.run()
    after = {p.name: p.stat().st_mtime_ns for p in outs}
    changed = sorted(n for n in after if after[n] != before[n])
    assert changed == ["exitance.1002.exr", "skin.1002.exr"]
    # and a changed parameter rebuilds that material's outputs
    path.write_text(path.read_text().replace("mfp = 2.0", "mfp = 2.5"))
    todo = [(j.name, j.udim) for j in scenes.load(path).plan().jobs if not j.up_to_date]
    assert todo == [("grey", "1001")]


BAD = [
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\ncolour = 1\n",
     r":5: unknown key 'colour' in \[material\]: allowed keys are"),
    ("[defaults]\neta = \"high\"\n", r":2: eta = 'high': expected a number or one per channel"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\n",
     r":1: \[\[material\]\] #1 needs 'output'"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.png\"\n",
     r":4: output = 'o.png': expected an .exr path"),
    ("[[blur]]\nname = \"b\"\nmaterial = \"nope\"\nirradiance = \"i.exr\"\ntexel_size = 1\n"
     "output = \"o.exr\"\n", r":3: material 'nope' is not in the scene"),
    ("[[material]]\nname = \"a\"\noutputs = [\"sigma_x\"]\n",
     r":3: outputs = \['sigma_x'\]: expected a list from alpha, rho"),
    ("[[material]\nname = 1\n", r"not valid TOML"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\nmfp = -1\n",
     r":5: mfp = -1: expected a number in \[1e-20, 3.4e\+38\]"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\nmfp = [1, 0, 1]\n",
     r":5: mfp = \[1, 0, 1\]: expected a number in"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\n"
     "outputs = [\"sigma_a\", \"sigma_a\"]\n", r":5: outputs = .*each once"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\neta = 9\n",
     r":5: eta = 9: eta=9.0 is outside \[0.5, 2.8\]"),
    ("[defaults]\neta = 9\n[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\n",
     r":2: eta = 9: eta=9.0 is outside"),
    ("[[material]]\nname = \"a\"\nalbedo = \"x.exr\"\noutput = \"o.exr\"\nmfp = 1e38\n"
     "mfp_scale = 100\n", r":6: mfp 1e\+38 x mfp_scale 100 = 1e\+40: expected mfp in"),
    ("[[material]]\nname = \"a\"\nalbedo = 0.5\noutput = \"o.exr\"\nmfp = 1e-19\n"
     "mfp_scale = 1e-5\n", r":6: mfp 1e-19 x mfp_scale 1e-05 = 1e-24"),
]


@pytest.mark.parametrize("text, message", BAD, ids=["unknown key", "bad value", "missing key",
                                                    "not exr", "unknown material",
                                                    "bad outputs", "syntax", "negative mfp",
                                                    "zero mfp channel", "output twice",
                                                    "eta out of range",
                                                    "eta out of range in defaults",
                                                    "mfp x scale too large",
                                                    "mfp x scale too small"])
def test_bad_scene_files_are_one_line_with_file_line_and_key(tmp_path, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(scenes.SceneError, match=message):
        scenes.load(path)
    assert cli_main(["plan", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "Traceback" not in err


def test_missing_inputs_are_listed_before_work_and_the_rest_still_runs(scene_dir, capsys):
    os.remove(scene_dir / "light" / "irr.1002.exr")
    text = (scene_dir / "scene.toml").read_text()
    text += ('\n[[material]]\nname = "ghost"\nalbedo = "tex/ghost.1001.exr"\nmfp = '
             '"tex/ghost_mfp.1001.exr"\noutput = "out/ghost.exr"\n')
    (scene_dir / "scene.toml").write_text(text)
    (scene_dir / "tex" / "ghost.1001.exr").write_bytes(b"")        # there, but its mfp is not
    rc = cli_main(["bake", str(scene_dir / "scene.toml"), "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 1
    assert "cannot run:" in captured.err and "ghost_mfp.1001.exr is missing" in captured.err
    assert "done" in captured.out and (scene_dir / "out" / "skin.1001.exr").exists()


def test_plan_json_lists_every_job(scene_dir, capsys):
    assert cli_main(["plan", str(scene_dir / "scene.toml"), "--json"]) == 0
    jobs = json.loads(capsys.readouterr().out)
    assert {(j["kind"], j["name"], j["udim"]) for j in jobs} == {
        ("invert", "skin", "1001"), ("invert", "skin", "1002"), ("invert", "grey", "1001"),
        ("blur", "tsd", "1001"), ("blur", "tsd", "1002")}
    assert all(j["computes"] and j["left_out"] for j in jobs)


def test_a_constant_material_gets_its_coefficients_in_the_summary_and_the_manifest(tmp_path):
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "jade"\nalbedo = [0.7, 0.5, 0.3]\nmfp = [1.0, 0.6, 0.3]\n'
        'output = "out/jade.exr"\noutputs = ["sigma_a", "sigma_s"]\n')
    plan = scenes.load(tmp_path / "scene.toml").plan()
    assert [j.kind for j in plan.jobs] == ["constant"]
    report = plan.run()
    assert report.exit_code == 0, report.summary()
    want = bd_coefficients((0.7, 0.5, 0.3), (1.0, 0.6, 0.3), 1.4)
    records = json.loads((tmp_path / "out" / "bdipole_materials.json").read_text())
    got = records["materials"][0]["coefficients"]
    np.testing.assert_allclose(got["sigma_a"], want[0], rtol=1e-4)
    np.testing.assert_allclose(got["sigma_s"], want[1], rtol=1e-4)
    assert f"sigma_a {want[0][0]:.6g}"[:12] in report.summary()
    assert not (tmp_path / "out" / "jade.exr").exists()             # no image
    assert not (tmp_path / "out" / "bdipole.usda").exists()         # no stage to layer over
    again = scenes.load(tmp_path / "scene.toml").plan()
    assert again.jobs[0].up_to_date and again.run().results[0].status == "skipped"
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "jade"\nalbedo = 0.7\nmfp = "mfp.exr"\noutput = "o.exr"\n')
    with pytest.raises(scenes.SceneError, match=r":3: albedo = 0.7 is constant and mfp a "
                                                r"texture"):
        scenes.load(tmp_path / "scene.toml")


def bd_coefficients(rd, mfp, eta):
    from bdipole_cl import albedo_to_coefficients
    return albedo_to_coefficients(np.asarray(rd), np.asarray(mfp), eta)


def test_plan_refuses_what_the_bake_would_refuse_per_channel_counts(tmp_path, capsys):
    """eta or mfp with a count that is neither one nor the albedo's channels cannot run, said
    by plan (not only by bake); equal values are one value (USD's mfp x colour of a grey
    albedo)."""
    write_exr(tmp_path / "rgb.exr", np.full((8, 8, 3), 0.5, np.float32), ("R", "G", "B"))
    write_exr(tmp_path / "grey.exr", np.full((8, 8, 1), 0.5, np.float32), ("Y",))
    path = tmp_path / "s.toml"
    path.write_text('[[material]]\nname = "a"\nalbedo = "rgb.exr"\nmfp = 1.0\n'
                    'eta = [1.3, 1.4]\noutput = "out/a.exr"\n'
                    '[[material]]\nname = "b"\nalbedo = "grey.exr"\nmfp = [1.0, 2.0, 3.0]\n'
                    'output = "out/b.exr"\n'
                    '[[material]]\nname = "c"\nalbedo = "grey.exr"\nmfp = [0.5, 0.5, 0.5]\n'
                    'output = "out/c.exr"\n')
    plan = scenes.load(path).plan()
    by_name = {j.name: j for j in plan.jobs}
    assert "eta has 2 values but the albedo has 3" in by_name["a"].problem
    assert "mfp has 3 values but the albedo has 1" in by_name["b"].problem
    assert not by_name["c"].problem
    report = plan.run()
    assert [r.status for r in report.results].count("ok") == 1
