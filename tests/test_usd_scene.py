"""Scenes from USD stages (bdipole_cl/io/usd_scene.py, shaders.py, scene_records.py):
stages written here, one material of each shader type."""
import json
import os

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade  # noqa: E402

import bdipole_cl as bd  # noqa: E402
from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.apps.cli import main as cli_main  # noqa: E402
from bdipole_cl.apps.demo import write_exr  # noqa: E402
from bdipole_cl.io.scene_import import EXTRA, import_materials  # noqa: E402
from bdipole_cl.io.shaders import SHADERS  # noqa: E402
from test_scene import read  # noqa: E402  (an image's pixels and channel names)

pytestmark = pytest.mark.usefixtures("on_device")

N = 8
#: the scene's accuracy contract (tol = 1e-4 in rho, as in tests/test_scene.py): sigma_a and
#: sigma_s' are rho and alpha' over the same sigma_t', so they carry the same relative error
TOL = 1e-4
F, C3 = Sdf.ValueTypeNames.Float, Sdf.ValueTypeNames.Color3f


def albedo_texture(path, k=0):
    yy, xx = np.mgrid[0:N, 0:N] / N
    rgb = np.stack([0.5 + 0.3 * xx, 0.3 + 0.2 * yy, 0.2 + 0.1 * xx + 0.02 * k], -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, rgb.astype(np.float32), ("R", "G", "B"))
    return rgb


def shader(stage, material, path, shader_id, context, inputs):
    s = UsdShade.Shader.Define(stage, path)
    s.CreateIdAttr(shader_id)
    for name, (type_name, value) in inputs.items():
        s.CreateInput(name, type_name).Set(value)
    material.CreateSurfaceOutput(context).ConnectToSource(s.ConnectableAPI(), "out")
    return s


def texture_node(stage, path, shader_id, file, out, **meta):
    t = UsdShade.Shader.Define(stage, path)
    t.CreateIdAttr(shader_id)
    f = t.CreateInput("file", Sdf.ValueTypeNames.Asset)
    f.Set(file)
    if "colorspace" in meta:
        f.GetAttr().SetColorSpace(meta["colorspace"])
    if "source" in meta:
        t.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(meta["source"])
    return t.CreateOutput(out, C3)


def write_stage(root, meters_per_unit=0.01, radius=0.5, procedural=False):
    """/Looks: skin (OpenPBR, a <UDIM> albedo through a node graph), jade (Standard Surface,
    constants, unbound), marble (PxrSurface, a UsdUVTexture), plastic (UsdPreviewSurface),
    empty (no surface shader); with ``procedural`` noisy (OpenPBR fed by a noise: a
    subsurface material no bake can bake, so a bake of the stage fails it)."""
    for k, tile in enumerate(("1001", "1002")):
        albedo_texture(root / "tex" / f"skin.{tile}.exr", k)
    albedo_texture(root / "tex" / "marble.exr", 3)
    stage = Usd.Stage.CreateNew(str(root / "asset.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    UsdGeom.Scope.Define(stage, "/Looks")
    skin = UsdShade.Material.Define(stage, "/Looks/skin")
    s = shader(stage, skin, "/Looks/skin/pbr", "ND_open_pbr_surface_surfaceshader", "mtlx",
               {"subsurface_weight": (F, 1.0), "subsurface_radius": (F, radius),
                "subsurface_radius_scale": (C3, Gf.Vec3f(1, 0.5, 0.25)),
                "specular_ior": (F, 1.4)})
    graph = UsdShade.NodeGraph.Define(stage, "/Looks/skin/graph")
    out = texture_node(stage, "/Looks/skin/graph/image", "ND_image_color3",
                       "tex/skin.<UDIM>.exr", "out", colorspace="lin_rec709")
    graph_out = graph.CreateOutput("albedo", C3)
    graph_out.ConnectToSource(out)
    s.CreateInput("subsurface_color", C3).ConnectToSource(graph_out)
    jade = UsdShade.Material.Define(stage, "/Looks/jade")
    shader(stage, jade, "/Looks/jade/std", "ND_standard_surface_surfaceshader", "mtlx",
           {"subsurface": (F, 1.0), "subsurface_color": (C3, Gf.Vec3f(0.7, 0.5, 0.3)),
            "subsurface_radius": (C3, Gf.Vec3f(1, 0.6, 0.3)), "subsurface_scale": (F, 0.5),
            "specular_IOR": (F, 1.5)})
    marble = UsdShade.Material.Define(stage, "/Looks/marble")
    s = shader(stage, marble, "/Looks/marble/pxr", "PxrSurface", "ri",
               {"subsurfaceGain": (F, 1.0), "subsurfaceDmfp": (F, 2.0),
                "subsurfaceDmfpColor": (C3, Gf.Vec3f(1, 0.8, 0.6)), "subsurfaceIor": (F, 1.33)})
    out = texture_node(stage, "/Looks/marble/tex", "UsdUVTexture", "tex/marble.exr", "rgb",
                       source="raw")
    s.CreateInput("subsurfaceColor", C3).ConnectToSource(out)
    plastic = UsdShade.Material.Define(stage, "/Looks/plastic")
    shader(stage, plastic, "/Looks/plastic/preview", "UsdPreviewSurface", "",
           {"diffuseColor": (C3, Gf.Vec3f(0.2, 0.3, 0.4))})
    if procedural:
        noisy = UsdShade.Material.Define(stage, "/Looks/noisy")
        s = shader(stage, noisy, "/Looks/noisy/pbr", "ND_open_pbr_surface_surfaceshader",
                   "mtlx", {"subsurface_weight": (F, 1.0)})
        noise = UsdShade.Shader.Define(stage, "/Looks/noisy/noise")
        noise.CreateIdAttr("ND_noise3d_color3")
        s.CreateInput("subsurface_color", C3).ConnectToSource(noise.CreateOutput("out", C3))
    UsdShade.Material.Define(stage, "/Looks/empty")
    for name, material in (("head", skin), ("table", marble), ("cup", plastic)):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()
    return root / "asset.usda"


def check_texture_bake(out, albedo, mfp, eta, mfp_kind):
    px, names = read(out)
    want_a, want_s = bd.albedo_to_coefficients(albedo, np.asarray(mfp), eta, mfp_kind=mfp_kind)
    for c, ch in enumerate("RGB"):
        np.testing.assert_allclose(px[..., names.index(f"sigma_a.{ch}")], want_a[..., c],
                                   rtol=TOL)
        np.testing.assert_allclose(px[..., names.index(f"sigma_s.{ch}")], want_s[..., c],
                                   rtol=TOL)


@pytest.fixture
def stage_path(tmp_path):
    return write_stage(tmp_path)


def test_each_shader_maps_and_the_rest_are_left_out_by_name(tmp_path):
    stage_path = write_stage(tmp_path, procedural=True)
    imports = {m.name: m for m in import_materials(stage_path)}
    assert imports["skin"].shader == "OpenPBR Surface" and imports["skin"].mfp_kind == \
        "extinction"
    assert imports["jade"].shader == "Standard Surface" and imports["jade"].bound is False
    assert imports["marble"].shader == "PxrSurface" and imports["marble"].mfp_kind == "diffuse"
    assert imports["plastic"].left_out == "no subsurface (UsdPreviewSurface shader): left out"
    assert imports["noisy"].left_out == ("not bakeable: subsurface_color comes from "
                                         "ND_noise3d_color3 (/Looks/noisy/noise), a "
                                         "procedural network")
    assert imports["empty"].left_out.startswith("no subsurface (no surface")
    skin = imports["skin"].facts
    assert skin["albedo"] == str(stage_path.parent / "tex" / "skin.<UDIM>.exr")
    assert skin["colorspace"] == "lin_rec709" and skin["unit"] == "cm"
    assert imports["marble"].facts["colorspace"] == "raw"
    plan = scenes.load(stage_path).plan()
    text = plan.describe()
    assert "material plastic (/Looks/plastic, UsdPreviewSurface): no subsurface" in text
    assert "material jade (/Looks/jade, Standard Surface), bound to no geometry" in text
    assert "mfp_kind extinction (sigma_t' = 1/mfp)" in text
    assert sorted((j.kind, j.name, j.udim) for j in plan.jobs) == [
        ("constant", "jade", None), ("invert", "marble", None), ("invert", "skin", "1001"),
        ("invert", "skin", "1002")]
    # the others bake; the subsurface material left unbaked fails the bake, named (it was a
    # success: "done", exit 0, having baked nothing of it)
    report = plan.run()
    failed = [r for r in report.results if r.status != "ok"]
    assert report.exit_code == 1, report.summary()
    assert [(r.path, r.error) for r in failed] == [
        ("material noisy (/Looks/noisy)", "not baked: " + imports["noisy"].left_out)]


def test_baked_values_equal_albedo_to_coefficients_and_the_layer_reads_them_back(stage_path):
    root = stage_path.parent
    report = scenes.load(stage_path).plan().run()
    assert report.exit_code == 0, report.summary()
    for k, tile in enumerate(("1001", "1002")):
        albedo = albedo_texture(root / "probe" / "a.exr", k)
        check_texture_bake(root / "bdipole" / f"skin.{tile}.exr", albedo,
                           0.5 * np.array([1, 0.5, 0.25]), 1.4, "extinction")
    check_texture_bake(root / "bdipole" / "marble.exr", albedo_texture(root / "probe" / "m.exr", 3),
                       2.0 * np.array([1, 0.8, 0.6]) * 0.1, 1.33, "diffuse")  # unitLength
    want = bd.albedo_to_coefficients((0.7, 0.5, 0.3), 0.5 * np.array([1, 0.6, 0.3]), 1.5,
                                     mfp_kind="extinction")
    records = json.loads((root / "bdipole" / "bdipole_materials.json").read_text())
    entries = {e["name"]: e for e in records["materials"]}
    jade = entries["jade"]["coefficients"]
    np.testing.assert_allclose(jade["sigma_a"], want[0], rtol=TOL)
    np.testing.assert_allclose(jade["sigma_s"], want[1], rtol=TOL)
    assert entries["skin"]["files"] == ["skin.1001.exr", "skin.1002.exr"]
    assert entries["skin"]["mfp_kind"] == "extinction" and entries["skin"]["unit"] == "cm"
    assert entries["plastic"]["baked"] is False and "left_out" in entries["plastic"]
    assert "sigma_a" in report.summary() and "jade (constants)" in report.summary()
    # the layer, sublayered over the stage, finds every file and the constants
    layer = Sdf.Layer.FindOrOpen(str(root / "bdipole" / "bdipole.usda"))
    stage = Usd.Stage.Open(str(stage_path))
    stage.GetRootLayer().subLayerPaths.append(layer.identifier)
    sa = stage.GetPrimAtPath("/Looks/skin").GetAttribute("bdipole:sigma_a").Get()
    assert sa.path == "./skin.<UDIM>.exr"
    for tile in ("1001", "1002"):
        pattern = os.path.join(os.path.dirname(layer.realPath), sa.path)
        assert os.path.isfile(pattern.replace("<UDIM>", tile))
    jade_sa = stage.GetPrimAtPath("/Looks/jade").GetAttribute("bdipole:sigma_a").Get()
    np.testing.assert_allclose(list(jade_sa), want[0], rtol=TOL)
    assert stage.GetPrimAtPath("/Looks/jade").GetAttribute("bdipole:mfp_kind").Get() == \
        "extinction"
    assert not stage.GetPrimAtPath("/Looks/plastic").HasAttribute("bdipole:sigma_a")


def test_meters_per_unit_and_a_named_unit(tmp_path):
    path = write_stage(tmp_path, meters_per_unit=0.01)
    (tmp_path / "scene.toml").write_text(
        'materials_from = "asset.usda"\n[defaults]\nunit = "mm"\n')
    by_unit = {m.name: m for m in scenes.load(tmp_path / "scene.toml").materials}
    native = {m.name: m for m in scenes.load(path).materials}
    assert native["jade"].unit == "cm" and by_unit["jade"].unit == "mm"
    # 0.5 cm radii are 5 mm: the constants' coefficients are per mm, ten times smaller
    np.testing.assert_allclose(np.asarray(by_unit["jade"].mfp_scale), 10.0 * np.asarray(
        native["jade"].mfp_scale))
    assert by_unit["skin"].mfp_scale == tuple(10.0 * v for v in native["skin"].mfp_scale)


def test_materials_from_with_an_override_and_an_up_to_date_rebake(tmp_path):
    write_stage(tmp_path)
    scene = tmp_path / "scene.toml"
    scene.write_text('materials_from = "asset.usda"\n[defaults]\noutput = '
                     '"out/{material}.<UDIM>.exr"\n\n[[material]]\nname = "marble"\neta = 1.5\n'
                     'output = "out/marble.exr"\noutputs = ["rho", "sigma_t"]\n')
    materials = {m.name: m for m in scenes.load(scene).materials}
    assert materials["marble"].eta == (1.5,) and materials["marble"].outputs == ("rho",
                                                                                 "sigma_t")
    assert materials["skin"].output == str(tmp_path / "out" / "skin.<UDIM>.exr")
    assert materials["skin"].eta == (1.4,)                      # the stage's, not overridden
    report = scenes.load(scene).plan().run()
    assert report.exit_code == 0, report.summary()
    _, names = read(tmp_path / "out" / "marble.exr")
    assert sorted(names) == sorted(f"{o}.{c}" for o in ("rho", "sigma_t") for c in "RGB")
    files = sorted((tmp_path / "out").iterdir())
    before = {p.name: p.stat().st_mtime_ns for p in files}
    again = scenes.load(scene).plan().run()
    assert [r.status for r in again.results] == ["skipped"] * len(again.results)
    assert {p.name: p.stat().st_mtime_ns for p in files} == before
    # a changed input value in the stage rebakes that material only
    stage = Usd.Stage.Open(str(tmp_path / "asset.usda"))
    stage.GetPrimAtPath("/Looks/skin/pbr").GetAttribute("inputs:subsurface_radius").Set(0.7)
    stage.GetRootLayer().Save()
    todo = sorted((j.name, j.udim) for j in scenes.load(scene).plan().jobs if not j.up_to_date)
    assert todo == [("skin", "1001"), ("skin", "1002")]
    scenes.load(scene).plan().run()
    after = {p.name: p.stat().st_mtime_ns for p in files}
    # the manifest records the new radius; the layer holds only paths and constants: as it
    # was; each output's own file (the networks' texture nodes read) follows its output
    assert sorted(n for n in after if after[n] != before[n]) == [
        "bdipole_materials.json", "skin.1001.exr", "skin.1001.sigma_a.exr",
        "skin.1001.sigma_s.exr", "skin.1002.exr", "skin.1002.sigma_a.exr",
        "skin.1002.sigma_s.exr"]


def test_an_override_of_a_left_out_material_is_refused(tmp_path):
    write_stage(tmp_path)
    (tmp_path / "scene.toml").write_text(
        'materials_from = "asset.usda"\n\n[[material]]\nname = "plastic"\neta = 1.5\n')
    with pytest.raises(scenes.SceneError, match=r"scene.toml:4: material 'plastic' of .* is "
                                                r"left out \(no subsurface"):
        scenes.load(tmp_path / "scene.toml")


def test_the_cli_plans_and_bakes_a_stage(stage_path, capsys):
    assert cli_main(["plan", str(stage_path)]) == 0
    out = capsys.readouterr().out
    assert "materials from" in out and "constant jade" in out
    assert cli_main(["bake", str(stage_path), "--no-progress"]) == 0
    assert (stage_path.parent / "bdipole" / "bdipole.usda").is_file()


def test_without_pxr_a_stage_is_one_line_naming_the_extra(stage_path, monkeypatch):
    import builtins
    real = builtins.__import__

    def no_pxr(name, *args, **kw):
        if name == "pxr" or name.startswith("pxr."):
            raise ImportError("No module named 'pxr'", name="pxr")
        return real(name, *args, **kw)

    monkeypatch.delitem(__import__("sys").modules, "bdipole_cl.io.usd_scene", raising=False)
    monkeypatch.setattr(builtins, "__import__", no_pxr)
    with pytest.raises(scenes.SceneError) as err:
        scenes.load(stage_path)
    assert EXTRA in str(err.value) and "\n" not in str(err.value)


def test_the_default_table_matches_materialx_nodedefs():
    mx = pytest.importorskip("MaterialX")
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    for mapping in SHADERS[:2]:
        nodedef = lib.getNodeDef(mapping.ids[0])
        for name, value in mapping.defaults.items():
            got = nodedef.getActiveInput(name).getValue()
            got = tuple(got) if not isinstance(got, float) else (got,)
            assert np.allclose(got, value), (mapping.name, name)


def write_png(path, rgb8):
    import OpenImageIO as oiio
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(rgb8.shape[1], rgb8.shape[0], 3, "uint8"))
    out.write_image(rgb8)
    out.close()


def srgb_to_linear(c):
    """The sRGB transfer function (IEC 61966-2-1), independent of OpenImageIO."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_colour_spaces_a_distance_texture_and_notes(tmp_path):
    """8-bit albedo declared sRGB or raw; the radius scale a texture (an mfp texture times
    the radius); an anisotropy and a textured weight, noted in the plan."""
    (tmp_path / "tex").mkdir()
    rng = np.random.default_rng(3)
    rgb8 = rng.integers(40, 220, (N, N, 3)).astype(np.uint8)
    write_png(tmp_path / "tex" / "wax.png", rgb8)
    scale = albedo_texture(tmp_path / "tex" / "radius.exr", 1)     # positive, per channel
    stage = Usd.Stage.CreateNew(str(tmp_path / "wax.usda"))
    for name, space in (("srgb", "sRGB"), ("raw", "raw")):
        m = UsdShade.Material.Define(stage, f"/Looks/{name}")
        s = shader(stage, m, f"/Looks/{name}/pbr", "ND_open_pbr_surface_surfaceshader", "mtlx",
                   {"subsurface_weight": (F, 1.0), "subsurface_radius": (F, 0.2),
                    "subsurface_scatter_anisotropy": (F, 0.5)})
        s.CreateInput("subsurface_color", C3).ConnectToSource(texture_node(
            stage, f"/Looks/{name}/albedo", "UsdUVTexture", "tex/wax.png", "rgb", source=space))
        s.CreateInput("subsurface_radius_scale", C3).ConnectToSource(texture_node(
            stage, f"/Looks/{name}/radius", "UsdUVTexture", "tex/radius.exr", "rgb",
            source="sRGB"))
    weight = texture_node(stage, "/Looks/raw/weight", "UsdUVTexture", "tex/radius.exr", "r")
    stage.GetPrimAtPath("/Looks/raw/pbr").GetAttribute(
        "inputs:subsurface_weight").Clear()
    UsdShade.Shader(stage.GetPrimAtPath("/Looks/raw/pbr")).GetInput(
        "subsurface_weight").ConnectToSource(weight)
    stage.GetRootLayer().Save()
    path = tmp_path / "wax.usda"
    text = scenes.load(path).plan().describe()
    assert "note: subsurface_scatter_anisotropy = 0.5: the distance is read as 1/sigma_t'" in text
    assert "note: the distance texture declares sRGB: read as data" in text
    assert "scaled by 0.2" in text
    assert "note: subsurface_weight is a texture" in text
    report = scenes.load(path).plan().run()
    assert report.exit_code == 0, report.summary()
    mfp = 0.2 * scale
    # the bake decodes sRGB with OCIO (float32) into the working space (linear Rec.709): the
    # sRGB curve within 5e-5 relative,
    # and that decode's error is amplified by the inversion, so the coefficients are compared
    # on the decoded albedo
    from bdipole_cl.io.colour import active_config, resolve_working_space
    decoded = active_config().convert((rgb8 / 255.0).astype(np.float32), "sRGB",
                                      resolve_working_space().name)
    np.testing.assert_allclose(decoded, srgb_to_linear(rgb8 / 255.0), rtol=5e-5)
    for name, albedo in (("srgb", decoded), ("raw", rgb8 / 255.0)):
        check_texture_bake(tmp_path / "bdipole" / f"{name}.exr", albedo, mfp, 1.5,
                           "extinction")


def test_usdc_and_usdz_stages(stage_path):
    stage = Usd.Stage.Open(str(stage_path))
    stage.Export(str(stage_path.with_suffix(".usdc")))
    jobs = sorted((j.kind, j.name, j.udim) for j in
                  scenes.load(stage_path.with_suffix(".usdc")).plan().jobs)
    assert jobs == sorted((j.kind, j.name, j.udim) for j in scenes.load(stage_path).plan().jobs)
    from pxr import UsdUtils
    usdz = stage_path.with_suffix(".usdz")
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(stage_path)), str(usdz))
    # the packaged textures are read from a copy in the cache (the package is a zip): the
    # package's bake equals the stage's, <UDIM> sets too, and the package is left as it was
    before = usdz.read_bytes()
    packaged = {m.name: m for m in import_materials(usdz)}
    plain = {m.name: m for m in import_materials(stage_path)}
    assert packaged.keys() == plain.keys()
    for name, m in packaged.items():
        assert m.left_out == plain[name].left_out, name
        if isinstance(m.facts.get("albedo"), str):
            assert os.path.basename(m.facts["albedo"]) == os.path.basename(plain[name].facts[
                "albedo"])
            assert ".usdz[" not in m.facts["albedo"]
    report = scenes.load(usdz).plan().run()
    assert report.exit_code == 0, report.summary()
    assert usdz.read_bytes() == before
    first = scenes.load(usdz).plan()
    assert all(j.up_to_date for j in first.jobs if j.kind != "records"), first.describe()


def test_materials_from_a_missing_stage_names_the_scene_line(tmp_path):
    (tmp_path / "scene.toml").write_text('materials_from = "no.usda"\n[defaults]\neta = 1.4\n')
    with pytest.raises(scenes.SceneError, match=r"scene.toml:1: .*no.usda: no such stage"):
        scenes.load(tmp_path / "scene.toml")
    (tmp_path / "scene.toml").write_text('[defaults]\neta = 1.4\nmaterials_from = "a.usda"\n')
    with pytest.raises(scenes.SceneError, match=r"scene.toml:3: materials_from is in "
                                                r"\[defaults\]: it is a top-level key"):
        scenes.load(tmp_path / "scene.toml")


def test_a_unit_that_cannot_convert_the_stage_is_named(tmp_path):
    write_stage(tmp_path)
    (tmp_path / "scene.toml").write_text(
        'materials_from = "asset.usda"\n[defaults]\nunit = "furlong"\n')
    with pytest.raises(scenes.SceneError, match=r"scene.toml:3: unit = 'furlong': converting "
                                                r"\w+'s distances from the stage's unit"):
        scenes.load(tmp_path / "scene.toml")


def test_the_records_never_overwrite_an_input(tmp_path):
    """A stage named bdipole.usda with the outputs beside it: its layer is not written."""
    stage_path = tmp_path / "bdipole.usda"
    os.replace(write_stage(tmp_path), stage_path)
    before = stage_path.read_bytes()
    scene = tmp_path / "scene.toml"
    scene.write_text('materials_from = "bdipole.usda"\n[defaults]\n'
                     'output = "{material}_{stem}.exr"\n')
    report = scenes.load(scene).plan().run()
    assert report.exit_code == 1
    assert "bdipole.usda: the bake's record would overwrite an input" in report.summary()
    assert stage_path.read_bytes() == before
    assert (tmp_path / "bdipole_materials.json").is_file()      # the other record is written
    assert (tmp_path / "skin_skin.1001.exr").is_file()


def test_the_records_never_overwrite_a_layer_the_stage_is_made_of(tmp_path):
    """The materials in a sublayer at bdipole/bdipole.usda, beside where the records go: that
    layer is an input of the bake too, never replaced (the root layer alone was checked)."""
    (tmp_path / "bdipole").mkdir()
    layer = tmp_path / "bdipole" / "bdipole.usda"
    os.replace(write_stage(tmp_path), layer)
    layer.write_text(layer.read_text().replace("@tex/", "@../tex/").replace("@./tex/",
                                                                          "@../tex/"))
    before = layer.read_bytes()
    root = tmp_path / "asset.usda"
    root.write_text('#usda 1.0\n(\n    subLayers = [@bdipole/bdipole.usda@]\n'
                    '    metersPerUnit = 0.01\n)\n')
    assert {m.name for m in scenes.load(root).materials} >= {"skin", "jade"}
    report = scenes.load(root).plan().run()
    assert report.exit_code == 1
    assert "bdipole.usda: the bake's record would overwrite an input" in report.summary()
    assert layer.read_bytes() == before
    assert {m.name for m in scenes.load(root).materials} >= {"skin", "jade"}


@pytest.mark.parametrize("thing", ["fifo", "directory", "users file", "not ours json"])
@pytest.mark.parametrize("name", ["bdipole_materials.json", "bdipole.usda"])
def test_what_stands_at_a_records_path_is_never_opened_blindly_nor_replaced(tmp_path, thing,
                                                                            name):
    """A FIFO at a record's path hung the bake for ever (opened to compare); a directory
    aborted it with a raw errno; a user's file there was replaced. Each is refused before any
    work, named, in the plan; a user's file is replaced only with --force."""
    stage = write_stage(tmp_path)
    folder = tmp_path / "bdipole"
    folder.mkdir()
    path = folder / name
    if thing == "fifo":
        os.mkfifo(path)
    elif thing == "directory":
        path.mkdir()
    elif thing == "users file":
        path.write_text("#usda 1.0\n(\n    doc = \"my notes\"\n)\n" if name.endswith("usda")
                        else "my notes\n")
    else:
        path.write_text('["a list, not this tool\'s record"]\n')
    plan = scenes.load(stage).plan()
    assert plan.jobs and all(str(path) in (j.problem or "") for j in plan.jobs), plan.describe()
    before = path.read_bytes() if path.is_file() else None
    assert plan.run().exit_code == 1
    assert (path.read_bytes() if path.is_file() else None) == before
    forced = scenes.load(stage).plan(force=True)
    if thing in ("users file", "not ours json"):
        assert forced.run().exit_code == 0
        assert path.read_bytes() != before
    else:
        assert all(str(path) in (j.problem or "") for j in forced.jobs)


def test_recorded_coefficients_are_used_only_as_written(tmp_path, capsys):
    """A constant material's coefficients in the manifest, edited (NaN, another value, not a
    list), are computed again, never passed on as up to date; bake --preview of a stage with
    a constant material draws the images' sheets and exits 0 (it tried to read the
    manifest as an image)."""
    stage = write_stage(tmp_path)
    assert cli_main(["bake", str(stage), "--preview", "--no-progress"]) == 0, \
        capsys.readouterr().err
    manifest = tmp_path / "bdipole" / "bdipole_materials.json"
    record = json.loads(manifest.read_text())
    jade = next(e for e in record["materials"] if e["name"] == "jade")
    want = jade["coefficients"]
    for edit in ({"sigma_a": [float("nan")] * 3, "sigma_s": want["sigma_s"]},
                 {"sigma_a": [v * 1.1 for v in want["sigma_a"]], "sigma_s": want["sigma_s"]},
                 "garbage"):
        jade["coefficients"] = edit
        manifest.write_text(json.dumps(record))
        plan = scenes.load(stage).plan()
        job = next(j for j in plan.jobs if j.name == "jade")
        assert not job.up_to_date and not job.problem, job.describe()
        assert plan.run().exit_code == 0
        fresh = next(e for e in json.loads(manifest.read_text())["materials"]
                     if e["name"] == "jade")
        assert fresh["coefficients"] == want
