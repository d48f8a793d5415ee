"""Faults in a USD stage's materials (bdipole_cl/io/usd_scene.py, shaders.py,
scene_records.py): each one is that material's job or refusal, named; the rest bake and the
records name only what was written."""
import json
import os
import stat

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade  # noqa: E402

from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.apps.demo import write_exr  # noqa: E402

pytestmark = pytest.mark.usefixtures("on_device")

N = 4
F, C3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f
OPENPBR = "ND_open_pbr_surface_surfaceshader"


def texture(path, rgb=(0.5, 0.4, 0.3)):
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, np.broadcast_to(np.float32(rgb), (N, N, 3)).copy(), ("R", "G", "B"))


def material(stage, name, file, sid=OPENPBR, weight="subsurface_weight",
             albedo="subsurface_color"):
    """A subsurface material whose albedo is a UsdUVTexture of ``file``: (shader, texture)."""
    m = UsdShade.Material.Define(stage, f"/Mat/{name}")
    s = UsdShade.Shader.Define(stage, f"/Mat/{name}/s")
    s.CreateIdAttr(sid)
    m.CreateSurfaceOutput("ri" if sid == "PxrSurface" else "mtlx").ConnectToSource(
        s.ConnectableAPI(), "out")
    s.CreateInput(weight, F).Set(1.0)
    t = UsdShade.Shader.Define(stage, f"/Mat/{name}/t")
    t.CreateIdAttr("UsdUVTexture")
    t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    s.CreateInput(albedo, C3).ConnectToSource(t.CreateOutput("rgb", Sdf.ValueTypeNames.Float3))
    return s, t


def new_stage(root, meters_per_unit=None):
    stage = Usd.Stage.CreateNew(str(root / "asset.usda"))
    if meters_per_unit is not None:
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    return stage


def records(folder):
    with open(folder / "bdipole_materials.json") as f:
        by_name = {e["name"]: e for e in json.load(f)["materials"]}
    return by_name, Sdf.Layer.OpenAsAnonymous(str(folder / "bdipole.usda"))


def baked_prims(layer):
    """{prim path: its bdipole: asset attributes' paths} of the records layer."""
    out = {}

    def visit(path):
        spec = layer.GetPrimAtPath(path)
        assets = {a.name: a.default.path for a in spec.attributes
                  if isinstance(a.default, Sdf.AssetPath) and a.name.startswith("bdipole:")}
        if any(a.name.startswith("bdipole:") for a in spec.attributes):   # the records, not
            #                                                   the material networks' shaders
            out[str(path)] = assets
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: visit(p) if p.IsPrimPath() else None)
    return out


def test_a_failed_material_is_not_recorded_as_baked(tmp_path):
    texture(tmp_path / "tex" / "jade.exr")
    stage = new_stage(tmp_path)
    material(stage, "jade", "tex/jade.exr")
    material(stage, "missing", "tex/nothere.exr")
    stage.GetRootLayer().Save()
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    assert report.exit_code != 0
    by_name, layer = records(tmp_path / "bdipole")
    assert by_name["jade"]["baked"] and by_name["jade"]["files"] == ["jade.exr"]
    miss = by_name["missing"]
    assert miss["baked"] is False and miss["files"] == []
    assert "nothere.exr is missing" in miss["not_baked"]
    assert baked_prims(layer) == {"/Mat/jade": {f"bdipole:{o}": "./jade.exr"
                                                for o in ("sigma_a", "sigma_s")}}
    assert not (tmp_path / "bdipole" / "missing.exr").exists()


def test_a_udim_material_with_one_failed_tile_names_only_the_tile_written(tmp_path):
    texture(tmp_path / "tex" / "skin.1001.exr")
    (tmp_path / "tex" / "skin.1002.exr").write_bytes(b"not an image")
    stage = new_stage(tmp_path)
    material(stage, "skin", "tex/skin.<UDIM>.exr")
    stage.GetRootLayer().Save()
    scenes.load(tmp_path / "asset.usda").plan().run()
    by_name, layer = records(tmp_path / "bdipole")
    skin = by_name["skin"]
    assert skin["baked"] is False and skin["files"] == ["skin.1001.exr"]
    assert "skin.1002.exr [1002]" in skin["not_baked"] and "1001" not in skin["not_baked"]
    assert baked_prims(layer) == {}


def test_a_job_without_an_output_fails_alone_and_the_records_are_written(tmp_path):
    texture(tmp_path / "tex" / "skin.1001.exr")
    texture(tmp_path / "tex" / "jade.exr")
    stage = new_stage(tmp_path)
    material(stage, "skin", "tex/skin.<UDIM>.exr")
    material(stage, "jade", "tex/jade.exr")
    stage.GetRootLayer().Save()
    (tmp_path / "scene.toml").write_text(
        'materials_from = "asset.usda"\n[defaults]\noutput = "out/{material}.<UDIM>.exr"\n')
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    failed = [r for r in report.results if r.status == "failed"]
    assert len(failed) == 1 and "jade" in failed[0].path, report.summary()
    by_name, layer = records(tmp_path / "out")
    assert by_name["skin"]["baked"] and by_name["skin"]["files"] == ["skin.1001.exr"]
    assert by_name["jade"]["baked"] is False and by_name["jade"]["files"] == []
    assert baked_prims(layer) == {"/Mat/skin": {f"bdipole:{o}": "./skin.<UDIM>.exr"
                                                for o in ("sigma_a", "sigma_s")}}


def test_the_records_have_the_umask_mode_of_the_images(tmp_path):
    texture(tmp_path / "tex" / "jade.exr")
    stage = new_stage(tmp_path)
    material(stage, "jade", "tex/jade.exr")
    stage.GetRootLayer().Save()
    old = os.umask(0o027)
    try:
        scenes.load(tmp_path / "asset.usda").plan().run()
    finally:
        os.umask(old)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in (tmp_path / "bdipole").iterdir()}
    assert modes == {"jade.exr": 0o640, "bdipole.usda": 0o640, "bdipole.mtlx": 0o640,
                     "bdipole_materials.json": 0o640, "jade.sigma_a.exr": 0o640,
                     "jade.sigma_s.exr": 0o640}


def test_an_unknown_colour_space_is_that_materials_job_only(tmp_path):
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    _, t = material(stage, "bad", "tex/a.exr")
    t.GetInput("file").GetAttr().SetColorSpace("NotASpace")
    material(stage, "good", "tex/a.exr")
    stage.GetRootLayer().Save()
    plan = scenes.load(tmp_path / "asset.usda").plan()
    jobs = {j.name: j for j in plan.jobs}
    assert "'NotASpace' is unknown" in jobs["bad"].problem and jobs["good"].problem is None
    assert "invert bad" in plan.describe()
    plan.run()
    by_name, _ = records(tmp_path / "bdipole")
    assert by_name["good"]["baked"] and (tmp_path / "bdipole" / "good.exr").is_file()
    assert by_name["bad"]["baked"] is False and "NotASpace" in by_name["bad"]["not_baked"]
    # a name the user writes in a scene file still fails on its line
    (tmp_path / "s.toml").write_text('materials_from = "asset.usda"\n[[material]]\n'
                                     'name = "good"\ncolorspace = "AlsoNot"\n')
    with pytest.raises(scenes.SceneError, match="s.toml:4: .*'AlsoNot'"):
        scenes.load(tmp_path / "s.toml")


def test_rows_of_materials_sharing_one_texture_name_the_material(tmp_path):
    texture(tmp_path / "tex" / "alb.exr")
    stage = new_stage(tmp_path)
    for name in ("a", "b", "c"):
        material(stage, name, "tex/alb.exr")
    stage.GetRootLayer().Save()
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    alb = str(tmp_path / "tex" / "alb.exr")
    assert [r.path for r in report.results][:3] == [f"{n}: {alb}" for n in "abc"]
    assert f"b: {alb}" in report.summary()


@pytest.mark.parametrize("meters", [0.0, -1.0, float("inf"), float("nan")])
def test_a_meters_per_unit_that_is_no_length_is_one_line(tmp_path, meters):
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path, meters_per_unit=meters)
    material(stage, "a", "tex/a.exr")
    stage.GetRootLayer().Save()
    with pytest.raises(scenes.SceneError, match=rf"asset.usda: metersPerUnit = {meters:g}: "
                                                r"the stage's unit must be a positive"):
        scenes.load(tmp_path / "asset.usda")


def radius_texture(stage, s, name, output="rgb", scale=None, bias=None):
    """subsurface_radius of shader ``s`` from a UsdUVTexture of tex/rad.exr."""
    t = UsdShade.Shader.Define(stage, f"/Mat/{name}/r")
    t.CreateIdAttr("UsdUVTexture")
    t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("tex/rad.exr")
    for key, value in (("scale", scale), ("bias", bias)):
        if value is not None:
            t.CreateInput(key, Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*value))
    out = t.CreateOutput(output, Sdf.ValueTypeNames.Float3 if output == "rgb" else F)
    s.CreateInput("subsurface_radius", F).ConnectToSource(out)
    return t


def test_texture_channels_scale_and_bias_are_honoured_or_refused_by_name(tmp_path):
    texture(tmp_path / "tex" / "alb.exr")
    texture(tmp_path / "tex" / "rad.exr", (0.5, 0.9, 0.1))
    stage = new_stage(tmp_path)
    radius_texture(stage, material(stage, "red", "tex/alb.exr")[0], "red", output="r")
    s, t = material(stage, "biased", "tex/alb.exr")
    t.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.1, 0, 0, 0))
    radius_texture(stage, s, "biased", output="g")         # both refusals are named
    s, t = material(stage, "dimmed", "tex/alb.exr")
    t.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0.5, 0.5, 0.5, 1))
    radius_texture(stage, material(stage, "rbias", "tex/alb.exr")[0], "rbias", bias=(0, 0, 1, 0))
    s, _ = material(stage, "scaled", "tex/alb.exr")
    scaled = radius_texture(stage, s, "scaled", scale=(2, 4, 8, 1))
    s, _ = material(stage, "mxfloat", "tex/alb.exr")
    radius_texture(stage, s, "mxfloat", output="out").GetIdAttr().Set("ND_image_float")
    stage.GetRootLayer().Save()
    scene = scenes.load(tmp_path / "asset.usda")
    left = {i.name: i.left_out for i in scene.imports}
    assert "subsurface_radius reads outputs:r of /Mat/red/r, one channel" in left["red"]
    assert "reads out (a float image: the file's first channel) of /Mat/mxfloat/r" in \
        left["mxfloat"]
    assert ("subsurface_color: UsdUVTexture scale/bias not supported (/Mat/biased/t has bias "
            "0.1, 0, 0); subsurface_radius reads outputs:g of /Mat/biased/r") in left["biased"]
    assert "(/Mat/dimmed/t has scale 0.5, 0.5, 0.5, on the albedo)" in left["dimmed"]
    assert "subsurface_radius: UsdUVTexture scale/bias not supported (/Mat/rbias/r has bias " \
        "0, 0, 1)" in left["rbias"]
    m = next(m for m in scene.materials if m.name == "scaled")
    # the radius texture times OpenPBR's default radius_scale (1, 0.5, 0.25) times the scale
    assert [m.name for m in scene.materials] == ["scaled"] and m.mfp_scale == (2.0, 2.0, 2.0)
    plan = scene.plan()
    plan.run()
    assert all(j.up_to_date for j in scenes.load(tmp_path / "asset.usda").plan().jobs)
    scaled.GetInput("scale").Set(Gf.Vec4f(2, 4, 4, 1))
    stage.GetRootLayer().Save()
    again = scenes.load(tmp_path / "asset.usda").plan().jobs
    assert [j.up_to_date for j in again if j.name == "scaled"] == [False]


def test_pxr_surface_unit_length_multiplies_the_dmfp(tmp_path):
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    for name, length in (("default", None), ("mm", 1.0), ("zero", 0.0)):
        s, _ = material(stage, name, "tex/a.exr", "PxrSurface", "subsurfaceGain",
                        "subsurfaceColor")
        s.CreateInput("subsurfaceDmfp", F).Set(5.0)
        s.CreateInput("subsurfaceDmfpColor", C3).Set(Gf.Vec3f(1, 0.5, 0.25))
        if length is not None:
            s.CreateInput("unitLength", F).Set(length)
    stage.GetRootLayer().Save()
    scene = scenes.load(tmp_path / "asset.usda")
    scale = {m.name: np.asarray(m.mfp) * m.mfp_scale for m in scene.materials}
    # RenderMan's default unitLength 0.1 (a dmfp in mm on a stage in cm)
    np.testing.assert_allclose(scale["default"], [0.5, 0.25, 0.125], rtol=1e-12)
    np.testing.assert_allclose(scale["mm"], [5.0, 2.5, 1.25], rtol=1e-12)
    left = {i.name: i.left_out for i in scene.imports}
    assert "unitLength must be a positive constant" in left["zero"]
    assert any("unitLength 0.1 (default)" in d for i in scene.imports if i.name == "default"
               for d in i.inputs.values())


def test_a_second_stage_beside_the_first_never_replaces_its_bake(tmp_path):
    """Two stages in one folder share bdipole/: the second's bake (a material of the same
    name, its own records) is refused, named, while the first's files stay as they were; the
    first bakes again as usual, and --force (``force=True``) lets the second replace them."""
    texture(tmp_path / "tex" / "paint.exr")
    texture(tmp_path / "tex" / "other.exr", (0.2, 0.3, 0.4))
    first = new_stage(tmp_path)
    material(first, "paint", "tex/paint.exr")
    first.GetRootLayer().Save()
    second = Usd.Stage.CreateNew(str(tmp_path / "look.usda"))
    material(second, "paint", "tex/other.exr")
    second.GetRootLayer().Save()
    assert scenes.load(tmp_path / "asset.usda").plan().run().exit_code == 0
    out = tmp_path / "bdipole"
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    plan = scenes.load(tmp_path / "look.usda").plan()
    assert plan.jobs and all("records the bake of" in j.problem and "asset.usda" in j.problem
                             for j in plan.jobs)
    assert plan.run().exit_code != 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    again = scenes.load(tmp_path / "asset.usda").plan()
    assert not any(j.problem for j in again.jobs)
    assert scenes.load(tmp_path / "look.usda").plan(force=True).run().exit_code == 0
    assert records(out)[0]["paint"]["albedo"].endswith("other.exr")


def test_a_copied_or_renamed_asset_folder_bakes_as_its_own(tmp_path):
    """The records name their stage relative to their folder: a copy of the whole asset folder
    bakes as its own (it was refused as another scene's), and so does a renamed stage (the
    recorded one is gone: no other scene to protect)."""
    import shutil
    src = tmp_path / "a"
    texture(src / "tex" / "paint.exr")
    stage = new_stage(src)
    material(stage, "paint", "tex/paint.exr")
    stage.GetRootLayer().Save()
    assert scenes.load(src / "asset.usda").plan().run().exit_code == 0
    shutil.copytree(src, tmp_path / "b")
    plan = scenes.load(tmp_path / "b" / "asset.usda").plan()
    assert not any(j.problem for j in plan.jobs) and plan.run().exit_code == 0
    os.replace(src / "asset.usda", src / "asset_v2.usda")
    plan = scenes.load(src / "asset_v2.usda").plan()
    assert not any(j.problem for j in plan.jobs), plan.describe()


def test_the_records_layer_sublayered_over_its_stage_is_rewritten(tmp_path):
    """docs/scenes.md's use of bdipole.usda: sublayer it over the stage. It is then one of the
    stage's layers, but the tool's own: a rebake after a change rewrites it (it was refused
    as an input, and left stale beside a new manifest)."""
    texture(tmp_path / "tex" / "paint.exr")
    stage = new_stage(tmp_path)
    material(stage, "paint", "tex/paint.exr")
    stage.GetRootLayer().Save()
    assert scenes.load(tmp_path / "asset.usda").plan().run().exit_code == 0
    stage.GetRootLayer().subLayerPaths.append("bdipole/bdipole.usda")
    stage.GetRootLayer().Save()
    texture(tmp_path / "tex" / "paint.exr", (0.2, 0.6, 0.3))
    plan = scenes.load(tmp_path / "asset.usda").plan()
    assert plan.records_note is None, plan.describe()
    report = plan.run()
    assert report.exit_code == 0, report.summary()
    by_name, layer = records(tmp_path / "bdipole")
    assert by_name["paint"]["baked"] and "/Mat/paint" in baked_prims(layer)


@pytest.mark.parametrize("arc", ["sublayer", "reference"])
def test_a_layer_that_cannot_be_opened_refuses_the_stage_in_one_line(tmp_path, capsys, arc):
    """USD composes what it can and warns (several lines, on stderr): a missing sublayer would
    bake nothing as a success and rewrite the records empty. The stage is refused, naming the
    layer, and an earlier bake's records are left as they are."""
    from bdipole_cl.apps.cli import main as cli_main
    texture(tmp_path / "tex" / "jade.exr")
    looks = Usd.Stage.CreateNew(str(tmp_path / "looks.usda"))
    material(looks, "jade", "tex/jade.exr")
    looks.GetRootLayer().Save()
    shot = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    if arc == "sublayer":
        shot.GetRootLayer().subLayerPaths.append("looks.usda")
    else:
        shot.DefinePrim("/Mat").GetReferences().AddReference("looks.usda", "/Mat")
    shot.GetRootLayer().Save()
    assert cli_main(["bake", str(tmp_path / "shot.usda"), "--no-progress"]) == 0
    capsys.readouterr()
    before = (tmp_path / "bdipole" / "bdipole_materials.json").read_bytes()
    (tmp_path / "looks.usda").rename(tmp_path / "looks_moved.usda")
    for command in ("plan", "bake"):
        rc = cli_main([command, str(tmp_path / "shot.usda"), "--no-progress"][
            :3 if command == "bake" else 2])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1, err
        assert "shot.usda: the stage does not compose whole" in err and "looks.usda" in err
    assert (tmp_path / "bdipole" / "bdipole_materials.json").read_bytes() == before


def test_a_material_of_an_instanced_asset_is_baked_once(tmp_path):
    """Set dressing instances its assets: their materials are prims of a prototype, which a
    plain traversal does not enter. Each is found, once however many instances show it."""
    texture(tmp_path / "tex" / "skin.exr")
    asset = Usd.Stage.CreateNew(str(tmp_path / "char.usda"))
    material(asset, "skin", "tex/skin.exr")
    asset.SetDefaultPrim(asset.GetPrimAtPath("/Mat"))
    asset.GetRootLayer().Save()
    shot = new_stage(tmp_path)
    for k in range(3):
        prim = shot.DefinePrim(f"/set/char{k}")
        prim.GetReferences().AddReference("char.usda")
        prim.SetInstanceable(True)
    shot.GetRootLayer().Save()
    plan = scenes.load(tmp_path / "asset.usda").plan()
    assert [j.name for j in plan.jobs] == ["skin"], plan.describe()
    report = plan.run()
    assert report.exit_code == 0 and (tmp_path / "bdipole" / "skin.exr").is_file()
    # USD ignores an over on an instance proxy: the records are a prim of their own, found
    # through the composed stage, whose relationship names the material
    composed = Usd.Stage.CreateInMemory()
    composed.GetRootLayer().subLayerPaths = [str(tmp_path / "bdipole" / "bdipole.usda"),
                                             str(tmp_path / "asset.usda")]
    record = composed.GetPrimAtPath("/bdipole_instanced/skin")
    target, = record.GetRelationship("bdipole:material").GetTargets()
    assert composed.GetPrimAtPath(target).IsInstanceProxy()
    assert record.GetAttribute("bdipole:sigma_a").Get().path == "./skin.exr"


def test_materials_whose_paths_join_to_one_name_get_their_own(tmp_path):
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    for path in ("/A/skin", "/A_skin", "/B/skin"):
        m = UsdShade.Material.Define(stage, path)
        s = UsdShade.Shader.Define(stage, f"{path}/s")
        s.CreateIdAttr(OPENPBR)
        m.CreateSurfaceOutput("mtlx").ConnectToSource(s.ConnectableAPI(), "out")
        s.CreateInput("subsurface_weight", F).Set(1.0)
        s.CreateInput("subsurface_color", C3).Set(Gf.Vec3f(0.5, 0.4, 0.3))
    stage.GetRootLayer().Save()
    plan = scenes.load(tmp_path / "asset.usda").plan()
    names = sorted(j.name for j in plan.jobs)
    assert len(set(names)) == 3 and not plan.missing, names


def test_names_that_differ_only_in_case_get_their_own_and_a_stray_override_is_named(
        tmp_path):
    """/A/Skin2 and /B/skin2 would be one file on a case-insensitive share: their names differ
    in more than case; a [[material]] override whose name is none of the stage's (a renamed
    one) says so, listing them (it said the material 'needs albedo')."""
    from bdipole_cl.io.shaders import unique_names
    names = unique_names(["/A/Skin2", "/B/skin2", "/Looks/Wax", "/Looks/wax"])
    assert len({n.casefold() for n in names.values()}) == 4, names
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    material(stage, "skin", "tex/a.exr")
    stage.GetRootLayer().Save()
    (tmp_path / "scene.toml").write_text('materials_from = "asset.usda"\n'
                                         '[[material]]\nname = "Skin"\nhalf = true\n')
    with pytest.raises(scenes.SceneError, match=r"material 'Skin' is not a material of .*"
                                                r"\(its materials: skin\)"):
        scenes.load(tmp_path / "scene.toml")


def test_a_wrongly_typed_input_leaves_its_material_out_by_name(tmp_path):
    """A texture file authored as a string, a colour as a string: that material is named as
    not bakeable (its attribute, its value, what was expected); the others bake."""
    texture(tmp_path / "tex" / "good.exr")
    texture(tmp_path / "tex" / "b.exr")
    stage = new_stage(tmp_path)
    material(stage, "good", "tex/good.exr")
    _, t = material(stage, "stringfile", "tex/b.exr")
    t.GetPrim().RemoveProperty("inputs:file")
    t.CreateInput("file", Sdf.ValueTypeNames.String).Set("tex/b.exr")
    m = UsdShade.Material.Define(stage, "/Mat/red")
    s = UsdShade.Shader.Define(stage, "/Mat/red/s")
    s.CreateIdAttr(OPENPBR)
    m.CreateSurfaceOutput("mtlx").ConnectToSource(s.ConnectableAPI(), "out")
    s.CreateInput("subsurface_weight", F).Set(1.0)
    s.CreateInput("subsurface_color", Sdf.ValueTypeNames.String).Set("red")
    stage.GetRootLayer().Save()
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    assert report.exit_code == 1 and (tmp_path / "bdipole" / "good.exr").is_file()
    assert sorted(r.path for r in report.results if r.status != "ok") == [
        "material red (/Mat/red)", "material stringfile (/Mat/stringfile)"], report.summary()
    by_name, _ = records(tmp_path / "bdipole")
    assert "a texture file is an asset path" in by_name["stringfile"]["left_out"]
    assert "'red': expected a number or a colour" in by_name["red"]["left_out"]


ANIMATED_STAGE = """#usda 1.0
(
    startTimeCode = 5
    endTimeCode = 10
)
def Material "anim" {
    token outputs:mtlx:surface.connect = </anim/pbr.outputs:out>
    def Shader "pbr" {
        uniform token info:id = "ND_open_pbr_surface_surfaceshader"
        float inputs:subsurface_weight = 1
        float inputs:subsurface_radius.timeSamples = { 1: 9, 5: 0.2, 10: 0.4 }
        color3f inputs:subsurface_color.connect = </anim/img.outputs:out>
        token outputs:out
    }
    def Shader "img" {
        uniform token info:id = "ND_image_color3"
        asset inputs:file.timeSamples = { 5: @tex/a.exr@ }
        color3f outputs:out
    }
}
def Material "iface" (
    prepend apiSchemas = ["ColorSpaceAPI"]
) {
    uniform token colorSpace:name = "lin_ap1_scene"
    asset inputs:albedo_file = @tex/a.exr@
    token outputs:mtlx:surface.connect = </iface/pbr.outputs:out>
    def Shader "pbr" {
        uniform token info:id = "ND_open_pbr_surface_surfaceshader"
        float inputs:subsurface_weight = 1
        color3f inputs:subsurface_color.connect = </iface/img.outputs:rgb>
        token outputs:out
    }
    def Shader "img" {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file.connect = </iface.inputs:albedo_file>
        float3 outputs:rgb
    }
}
"""


def test_animated_inputs_interface_files_and_inherited_colour_spaces(tmp_path):
    """An input authored only as time samples is read at the stage's start time code and noted
    (never its shader's default); a texture file that comes through the material's interface
    input is read; a colour space a ColorSpaceAPI on an ancestor declares is the texture's."""
    texture(tmp_path / "tex" / "a.exr")
    (tmp_path / "asset.usda").write_text(ANIMATED_STAGE)
    imports = {m.name: m for m in scenes.load(tmp_path / "asset.usda").imports}
    anim = imports["anim"]
    assert anim.left_out is None
    assert anim.inputs["subsurface_radius"] == "subsurface_radius 0.2 (animated: at time " \
                                                  "code 5)"
    assert anim.facts["albedo"] == str(tmp_path / "tex" / "a.exr")
    assert "subsurface_radius is animated: baked with its value at time code 5" in anim.notes
    iface = imports["iface"]
    assert iface.left_out is None and iface.facts["albedo"] == str(tmp_path / "tex" / "a.exr")
    assert iface.facts["colorspace"] == "lin_ap1_scene"


COLLECTION_STAGE = """#usda 1.0
def Material "skin" {
    token outputs:mtlx:surface.connect = </skin/pbr.outputs:out>
    def Shader "pbr" {
        uniform token info:id = "ND_open_pbr_surface_surfaceshader"
        float inputs:subsurface_weight = 1
        color3f inputs:subsurface_color.connect = </skin/img.outputs:out>
        token outputs:out
    }
    def Shader "img" {
        uniform token info:id = "ND_image_color3"
        asset inputs:file = @tex/a.exr@ ( colorSpace = "identity" )
        color3f outputs:out
    }
}
def "World" (
    prepend apiSchemas = ["CollectionAPI:skinGeo", "MaterialBindingAPI"]
) {
    prepend rel collection:skinGeo:includes = </World/head>
    rel material:binding:collection:skinGeo = [</World.collection:skinGeo>, </skin>]
    def Mesh "head" {}
}
"""


def test_a_collection_binding_binds_and_usds_identity_space_is_raw(tmp_path):
    """A material bound by a collection is bound to geometry (the plan said 'bound to no
    geometry'); USD's ``identity`` colour space (no conversion) is read as raw, not refused as
    a space OCIO does not know."""
    texture(tmp_path / "tex" / "a.exr")
    (tmp_path / "asset.usda").write_text(COLLECTION_STAGE)
    skin, = scenes.load(tmp_path / "asset.usda").imports
    assert skin.bound is True and skin.left_out is None
    assert skin.facts["colorspace"] == "raw"
    assert scenes.load(tmp_path / "asset.usda").plan().run().exit_code == 0


def test_an_output_whose_input_tile_is_gone_is_removed_at_the_next_bake(tmp_path):
    """An albedo tile deleted since the last bake: its output tile, which the records' <UDIM>
    pattern would still give a renderer, is removed (named in the report); the other tiles,
    and every file the bake did not write, stay."""
    for tile in ("1001", "1002"):
        texture(tmp_path / "tex" / f"skin.{tile}.exr")
    stage = new_stage(tmp_path)
    material(stage, "skin", "tex/skin.<UDIM>.exr")
    stage.GetRootLayer().Save()
    out = tmp_path / "bdipole"
    assert scenes.load(tmp_path / "asset.usda").plan().run().exit_code == 0
    assert (out / "skin.1002.exr").is_file()
    (out / "notes.txt").write_text("mine")
    (tmp_path / "tex" / "skin.1002.exr").unlink()
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    assert report.exit_code == 0
    assert not (out / "skin.1002.exr").exists()
    assert (out / "skin.1001.exr").is_file() and (out / "notes.txt").read_text() == "mine"
    assert any("removed" in r.notes and r.path == str(out / "skin.1002.exr")
               for r in report.results), report.summary()
    by_name, _ = records(out)
    assert by_name["skin"]["files"] == ["skin.1001.exr"]


def surface(stage, name, sid, context, **values):
    """A material whose surface (render context ``context``) is shader ``sid`` with float
    ``values``: the shader."""
    m = UsdShade.Material.Define(stage, f"/Mat/{name}")
    s = UsdShade.Shader.Define(stage, f"/Mat/{name}/s")
    s.CreateIdAttr(sid)
    m.CreateSurfaceOutput(context).ConnectToSource(s.ConnectableAPI(), "out")
    for key, value in values.items():
        s.CreateInput(key, F).Set(value)
    return s


def file_node(stage, path, sid, file_input, file, output, type_name=C3, **inputs):
    """A texture node ``sid`` reading ``file`` through ``file_input``: its ``output``."""
    t = UsdShade.Shader.Define(stage, path)
    t.CreateIdAttr(sid)
    t.CreateInput(file_input, Sdf.ValueTypeNames.Asset).Set(file)
    for key, (value_type, value) in inputs.items():
        t.CreateInput(key, value_type).Set(value)
    return t.CreateOutput(output, type_name)


def test_production_shader_ids_contexts_and_texture_nodes_are_read(tmp_path):
    """As productions author them: MaterialX's Standard Surface 1.0.0 nodedef
    (ND_standard_surface_surfaceshader_100) was 'no subsurface'; the arnold render context was
    not read ('no surface shader'); a PxrTexture feeding PxrSurface was 'a procedural
    network', as was an Arnold image. Each is read: a PxrTexture's file (its _MAPID_ the
    <UDIM> of atlasStyle 1) and linearize, an Arnold image's filename (its <udim> token),
    color_space and multiply (a scale: refused on the albedo, as UsdUVTexture's)."""
    for tile in ("1001", "1002"):
        texture(tmp_path / "tex" / f"skin.{tile}.exr")
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    surface(stage, "old", "ND_standard_surface_surfaceshader_100", "mtlx", subsurface=1.0
            ).CreateInput("subsurface_color", C3).Set(Gf.Vec3f(0.6, 0.5, 0.4))
    s = surface(stage, "pxr", "PxrSurface", "ri", subsurfaceGain=1.0)
    s.CreateInput("subsurfaceColor", C3).ConnectToSource(file_node(
        stage, "/Mat/pxr/tex", "PxrTexture", "filename", "tex/skin._MAPID_.exr", "resultRGB",
        atlasStyle=(Sdf.ValueTypeNames.Int, 1), linearize=(Sdf.ValueTypeNames.Int, 1)))
    s = surface(stage, "arn", "arnold:standard_surface", "arnold", subsurface=1.0)
    s.CreateInput("subsurface_color", C3).ConnectToSource(file_node(
        stage, "/Mat/arn/img", "arnold:image", "filename", "tex/a.exr", "out",
        color_space=(Sdf.ValueTypeNames.String, "linear")))
    s = surface(stage, "arnu", "arnold:standard_surface", "arnold", subsurface=1.0)
    s.CreateInput("subsurface_color", C3).ConnectToSource(file_node(
        stage, "/Mat/arnu/img", "arnold:image", "filename", "tex/skin.<udim>.exr", "out"))
    s = surface(stage, "arnx", "arnold:standard_surface", "arnold", subsurface=1.0)
    s.CreateInput("subsurface_color", C3).ConnectToSource(file_node(
        stage, "/Mat/arnx/img", "arnold:image", "filename", "tex/a.exr", "out",
        multiply=(C3, Gf.Vec3f(0.5, 0.5, 0.5))))
    stage.GetRootLayer().Save()
    imports = {m.name: m for m in scenes.load(tmp_path / "asset.usda").imports}
    assert imports["old"].shader == "Standard Surface" and imports["old"].left_out is None
    pxr_facts = imports["pxr"].facts
    assert imports["pxr"].left_out is None and pxr_facts["colorspace"] == "sRGB"
    assert pxr_facts["albedo"] == str(tmp_path / "tex" / "skin.<UDIM>.exr")
    assert imports["arn"].left_out is None and imports["arn"].shader == "Standard Surface"
    assert imports["arn"].facts["colorspace"] == "lin_rec709"
    assert imports["arnu"].facts["albedo"] == str(tmp_path / "tex" / "skin.<UDIM>.exr")
    assert "/Mat/arnx/img has scale 0.5, 0.5, 0.5, on the albedo" in imports["arnx"].left_out
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    # every other material bakes; the one left unbaked fails the bake, named
    assert report.exit_code == 1, report.summary()
    assert [r.path for r in report.results if r.status != "ok"] == ["material arnx (/Mat/arnx)"]


def test_a_spline_animated_input_without_a_time_range_is_read_at_its_first_knot(tmp_path):
    """USD splines have no time samples: on a stage with no time range the first sample of an
    empty list was an IndexError that stopped the whole plan, other materials included. The
    input is read at its first knot and noted, and the other material is read too."""
    from pxr import Ts
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    s, _ = material(stage, "anim", "tex/a.exr")
    spline = Ts.Spline("float")
    for time, value in ((3.0, 0.25), (10.0, 1.0)):
        knot = Ts.Knot("float")
        knot.SetTime(time)
        knot.SetValue(value)
        spline.SetKnot(knot)
    assert s.CreateInput("subsurface_radius", F).GetAttr().SetSpline(spline)
    material(stage, "still", "tex/a.exr")
    stage.GetRootLayer().Save()
    imports = {m.name: m for m in scenes.load(tmp_path / "asset.usda").imports}
    anim = imports["anim"]
    assert anim.left_out is None and imports["still"].left_out is None
    assert anim.inputs["subsurface_radius"] == \
        "subsurface_radius 0.25 (animated: at time code 3)"
    np.testing.assert_allclose(anim.facts["mfp"], [0.25, 0.125, 0.0625], rtol=1e-7)


def test_a_reader_fault_in_one_material_leaves_only_that_one_out(tmp_path, monkeypatch):
    """Whatever a stage's reader trips on in one material's inputs (a value USD cannot give)
    is that material's refusal, named; the others are read."""
    from bdipole_cl.io import usd_scene
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    material(stage, "bad", "tex/a.exr")
    material(stage, "good", "tex/a.exr")
    stage.GetRootLayer().Save()
    real = usd_scene.read_input

    def faulty(shader, name, time=None):
        time = Usd.TimeCode.EarliestTime() if time is None else time
        if "/bad/" in str(shader.GetPath()) and name == "specular_ior":
            raise IndexError("list index out of range")
        return real(shader, name, time)
    monkeypatch.setattr(usd_scene, "read_input", faulty)
    imports = {m.name: m for m in scenes.load(tmp_path / "asset.usda").imports}
    assert imports["bad"].left_out == ("not bakeable: specular_ior cannot be read: IndexError: "
                                       "list index out of range")
    assert imports["good"].left_out is None


def test_a_one_channel_radius_map_and_an_image_layer_in_a_stage(tmp_path):
    """OpenPBR's float subsurface_radius from a float image of a one-channel file bakes (the
    mfp texture times radius_scale); a MaterialX image's ``layer`` that is not what a bake
    reads of the file is refused, named (it was read from the file's R, G, B, exit 0)."""
    from bdipole_cl.apps.demo import write_exr
    texture(tmp_path / "tex" / "a.exr")
    radius = np.linspace(0.5, 2.0, N * N, dtype=np.float32).reshape(N, N)
    write_exr(tmp_path / "tex" / "radius.exr", radius, ("Y",))
    stage = new_stage(tmp_path)
    s, _ = material(stage, "mapped", "tex/a.exr")
    s.CreateInput("subsurface_radius", F).ConnectToSource(file_node(
        stage, "/Mat/mapped/r", "ND_image_float", "file", "tex/radius.exr", "out", F))
    s, t = material(stage, "layered", "tex/a.exr")
    t.GetIdAttr().Set("ND_image_color3")
    t.CreateInput("layer", Sdf.ValueTypeNames.String).Set("diffuse")
    stage.GetRootLayer().Save()
    scene = scenes.load(tmp_path / "asset.usda")
    left = {m.name: m.left_out for m in scene.imports}
    assert left["mapped"] is None
    assert "subsurface_color reads layer 'diffuse' of" in left["layered"], left
    m, = scene.materials
    assert m.mfp == str(tmp_path / "tex" / "radius.exr")
    np.testing.assert_allclose(m.mfp_scale, [1.0, 0.5, 0.25], rtol=1e-7)   # radius_scale


def test_a_stage_referencing_a_materialx_document_says_why_and_what_to_do(tmp_path, capsys):
    """The usd-core wheel has no MaterialX file-format plugin: a stage referencing look.mtlx
    failed with 'Could not open asset', no word of why. The refusal says so and names the
    ways that work (bake the document itself)."""
    from bdipole_cl.apps.cli import main as cli_main
    (tmp_path / "look.mtlx").write_text('<?xml version="1.0"?>\n<materialx version="1.39" />\n')
    shot = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    shot.DefinePrim("/MaterialX").GetReferences().AddReference("look.mtlx", "/MaterialX")
    shot.GetRootLayer().Save()
    if Sdf.FileFormat.FindByExtension("mtlx") is not None:
        pytest.skip("this USD reads .mtlx layers")
    assert cli_main(["plan", str(tmp_path / "shot.usda")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "no MaterialX file-format plugin" in err and \
        f"bdipole_cl bake {tmp_path / 'look.mtlx'}" in err, err


def test_a_shader_implemented_by_a_source_asset_is_known_by_its_sub_identifier(tmp_path):
    """A shader authored as a MaterialX library node (info:implementationSource sourceAsset,
    info:mtlx:sourceAsset:subIdentifier = the nodedef) has no info:id: it was 'no surface
    shader'. Its sub-identifier names it, for the surface and for an image node."""
    texture(tmp_path / "tex" / "a.exr")
    stage = new_stage(tmp_path)
    s, t = material(stage, "skin", "tex/a.exr")
    for shader, nodedef in ((s, "ND_standard_surface_surfaceshader_100"),
                            (t, "ND_image_color3")):
        shader.GetImplementationSourceAttr().Set(UsdShade.Tokens.sourceAsset)
        shader.SetSourceAsset(Sdf.AssetPath("stdlib_defs.mtlx"), "mtlx")
        shader.SetSourceAssetSubIdentifier(nodedef, "mtlx")
    s.CreateInput("subsurface", F).Set(1.0)
    stage.GetRootLayer().Save()
    (skin,) = scenes.load(tmp_path / "asset.usda").imports
    assert skin.shader == "Standard Surface" and skin.left_out is None, skin.left_out
    assert skin.facts["albedo"] == str(tmp_path / "tex" / "a.exr")
