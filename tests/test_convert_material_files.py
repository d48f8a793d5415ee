"""Which material reads which files across inputs and runs of ``convert``
(jobs/convert_materials.py, io/collisions.py): no two inputs of a run share a file their
materials read, and a run that rewrites the files a kept material reads takes that material
over, said, so two materials never read one set of files."""
import json

import pytest

pxr = pytest.importorskip("pxr")

from bdipole_cl.apps.cli import main  # noqa: E402
from test_convert_materials import _colour, _materials, _mtlx_materials, _reads  # noqa: E402


@pytest.mark.parametrize("second", ["s.van-de-hulst.exr", "s.van-de-hulst.colour.exr"])
def test_two_inputs_whose_files_land_on_one_path_are_both_refused(tmp_path, capsys, second):
    # s and s.van-de-hulst both read o/s.van-de-hulst.colour.exr (the second's name already
    # ends with the convention), and s.van-de-hulst.colour.exr's output was s's layer file:
    # exit 0, one material reading the other's data
    _colour(tmp_path / "s.exr", 1)
    _colour(tmp_path / second, 2)
    rc = main(["convert", str(tmp_path / "s.exr"), str(tmp_path / second), "--radius", "1",
               "--target", "openpbr", "-o", str(tmp_path / "o" / "{stem}.exr")])
    out = capsys.readouterr().out
    assert rc == 1 and out.count("is also written by") == 2, out
    assert "0 done, 2 failed" in out, out
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").iterdir())


def _sources(folder) -> dict:
    from pxr import Sdf
    layer = Sdf.Layer.OpenAsAnonymous(str(folder / "bdipole_convert.usda"))
    return json.loads(layer.customLayerData["bdipole_convert_sources"])


def test_a_run_that_rewrites_a_kept_materials_files_takes_it_over(tmp_path, capsys):
    # s (in1) and s_2 (in2) both read ./s.van-de-hulst.*, which held in2's data, exit 0
    for d, seed in (("in1", 1), ("in2", 2)):
        _colour(tmp_path / d / "s.exr", seed)
    out = str(tmp_path / "outs" / "{stem}.exr")
    for d in ("in1", "in2"):
        capsys.readouterr()
        assert main(["convert", str(tmp_path / d / "s.exr"), "--radius", "1", "--target",
                     "openpbr", "-o", out]) == 0, capsys.readouterr()
    said = capsys.readouterr().out
    assert "s: now converts ../in2/s.exr (was ../in1/s.exr" in said, said
    assert _reads(tmp_path / "outs") == {"s": "./s.van-de-hulst.colour.exr"}
    assert _mtlx_materials(tmp_path / "outs") == {"s"}
    assert _sources(tmp_path / "outs") == {"s": "../in2/s.exr"}


def test_a_material_without_a_source_is_matched_by_its_files_not_its_name(tmp_path, capsys):
    # a layer written before sources were kept: in2/s.exr, into other files, took s by its
    # name (s read s.in2.*; s.van-de-hulst.* read by none)
    from pxr import Sdf
    for d, seed in (("in1", 1), ("in2", 2)):
        _colour(tmp_path / d / "s.exr", seed)
    outs = tmp_path / "outs"
    assert main(["convert", str(tmp_path / "in1" / "s.exr"), "--radius", "1", "--target",
                 "openpbr", "-o", str(outs / "{stem}.exr")]) == 0, capsys.readouterr()
    layer = Sdf.Layer.FindOrOpen(str(outs / "bdipole_convert.usda"))
    data = dict(layer.customLayerData)
    data.pop("bdipole_convert_sources")
    layer.customLayerData = data
    layer.Save()
    del layer                        # out of USD's layer registry: the stage reads the file
    assert main(["convert", str(tmp_path / "in2" / "s.exr"), "--radius", "1", "--target",
                 "openpbr", "-o", str(outs / "{stem}.in2.exr")]) == 0, capsys.readouterr()
    assert _reads(outs) == {"s": "./s.van-de-hulst.colour.exr",
                            "s_2": "./s.in2.van-de-hulst.colour.exr"}
    # converted again into its files, the legacy material is its source's, with no line
    capsys.readouterr()
    assert main(["convert", str(tmp_path / "in1" / "s.exr"), "--radius", "2", "--target",
                 "openpbr", "-o", str(outs / "{stem}.exr")]) == 0
    said = capsys.readouterr().out
    assert "now converts" not in said, said
    assert _sources(outs) == {"s": "../in1/s.exr", "s_2": "../in2/s.exr"}
    assert _materials(outs) == {"s", "s_2"}


@pytest.mark.parametrize("stems, named", [
    (("_skin", "skin"), {"_skin": "./_skin", "skin": "./skin"}),
    (("skin.<UDIM>", "-skin"), {"skin": "./skin.<UDIM>", "_skin": "./-skin"})])
def test_a_materials_name_keeps_every_character_of_its_files(tmp_path, capsys, stems, named):
    # _skin.exr's material was skin (its leading _ stripped) and skin.exr's skin_2
    for k, stem in enumerate(stems):
        _colour(tmp_path / f"{stem.replace('<UDIM>', '1001')}.exr", k)
    rc = main(["convert", *(str(tmp_path / f"{s}.exr") for s in stems), "--radius", "1",
               "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    assert _reads(tmp_path) == {m: f"{s}.van-de-hulst.colour.exr" for m, s in named.items()}
    assert _mtlx_materials(tmp_path) == set(named)
