"""Records a consumer can use (bdipole_cl/jobs/scene_records.py): every ``bdipole:`` record of
a bake resolves through USD's own API (``UsdShade.UdimUtils``, plain asset resolution) to the
files it means, and names the channels (the EXR layer) each output is in, for every tile
convention of the inputs and outputs."""
import json
import shutil

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf, Usd, UsdShade  # noqa: E402

from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.io.images import image_header  # noqa: E402
from test_usd_scene import write_stage  # noqa: E402

pytestmark = pytest.mark.usefixtures("on_device")


def composed(stage_path, layer_path):
    """The stage with the bake's layer over it, as docs/materials.md says: a root whose
    sublayers are the bake's layer, then the stage (the first is the stronger)."""
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(layer_path), str(stage_path)]
    return Usd.Stage.Open(root)


def output_files(prim, output) -> list:
    """The files a baked material's record of ``output`` names, through USD's own API: a
    ``<UDIM>`` asset by ``UsdShade.UdimUtils``, a tile list or a plain file by asset
    resolution; a record nothing resolves is an empty list."""
    attr = prim.GetAttribute(f"bdipole:{output}")
    if attr and attr.HasAuthoredValue():
        asset = attr.Get()
        if UsdShade.UdimUtils.IsUdimIdentifier(asset.path):
            layer = attr.GetPropertyStack(Usd.TimeCode.Default())[0].layer
            return [p for p, _ in UsdShade.UdimUtils.ResolveUdimTilePaths(asset.path, layer)]
        return [asset.resolvedPath] if asset.resolvedPath else []
    tiles = prim.GetAttribute(f"bdipole:{output}:tiles")
    return [a.resolvedPath for a in tiles.Get()] if tiles and tiles.HasAuthoredValue() else []


def check_record(prim, output, want_tiles):
    """Each file the record names exists, holds the channels the record says (``:layer``,
    ``:channels``) and its ``:firstChannel`` is where that layer starts as the file is read,
    and those are the output's channels, not another's."""
    files = output_files(prim, output)
    assert len(files) == want_tiles and all(files), (prim.GetPath(), output, files)
    layer = prim.GetAttribute(f"bdipole:{output}:layer").Get()
    channels = list(prim.GetAttribute(f"bdipole:{output}:channels").Get())
    first = prim.GetAttribute(f"bdipole:{output}:firstChannel").Get()
    assert layer == output and channels and all(c.startswith(f"{output}.") for c in channels)
    for f in files:
        names = list(image_header(f).channelnames)
        assert names[first:first + len(channels)] == channels, (f, names, first, channels)
    return files


def test_each_output_names_its_files_and_its_own_channels(tmp_path):
    """sigma_a and sigma_s share a file: each record says which channels are its own (a reader
    of the file's colour channels got sigma_a for sigma_s)."""
    stage_path = write_stage(tmp_path)
    report = scenes.load(stage_path).plan().run()
    assert report.exit_code == 0, report.summary()
    stage = composed(stage_path, tmp_path / "bdipole" / "bdipole.usda")
    skin, marble = (stage.GetPrimAtPath(p) for p in ("/Looks/skin", "/Looks/marble"))
    a = check_record(skin, "sigma_a", 2)
    s = check_record(skin, "sigma_s", 2)
    assert a == s                                     # one file per tile, two layers
    first_a = skin.GetAttribute("bdipole:sigma_a:firstChannel").Get()
    first_s = skin.GetAttribute("bdipole:sigma_s:firstChannel").Get()
    assert first_a != first_s
    check_record(marble, "sigma_a", 1)
    manifest = json.loads((tmp_path / "bdipole" / "bdipole_materials.json").read_text())
    entry = next(e for e in manifest["materials"] if e["name"] == "skin")
    assert entry["channels"]["sigma_s"] == list(
        skin.GetAttribute("bdipole:sigma_s:channels").Get())


def uvtile_stage(tmp_path):
    """write_stage with the skin's albedo tiles renamed to 1-based UVTILE (u1_v1, u2_v1)."""
    stage_path = write_stage(tmp_path)
    for udim, uv in (("1001", "u1_v1"), ("1002", "u2_v1")):
        shutil.move(tmp_path / "tex" / f"skin.{udim}.exr", tmp_path / "tex" / f"skin.{uv}.exr")
    layer = Sdf.Layer.FindOrOpen(str(stage_path))
    attr = layer.GetAttributeAtPath("/Looks/skin/graph/image.inputs:file")
    attr.default = Sdf.AssetPath("tex/skin.<UVTILE>.exr")
    layer.Save()
    return stage_path


def test_a_uvtile_albedo_bakes_to_a_record_usd_resolves(tmp_path):
    """A <UVTILE> albedo's record was written as <UVTILE>, which UdimUtils cannot resolve."""
    stage_path = uvtile_stage(tmp_path)
    report = scenes.load(stage_path).plan().run()
    assert report.exit_code == 0, report.summary()
    stage = composed(stage_path, tmp_path / "bdipole" / "bdipole.usda")
    files = check_record(stage.GetPrimAtPath("/Looks/skin"), "sigma_a", 2)
    assert sorted(f.rsplit("/", 1)[-1] for f in files) == ["skin.1001.exr", "skin.1002.exr"]


@pytest.mark.parametrize("pattern, names", [
    ("out/{material}.%(UDIM)d.exr", ["skin.1001.exr", "skin.1002.exr"]),
    ("out/{material}_<UVTILE>.exr", ["skin_u1_v1.exr", "skin_u2_v1.exr"]),
    ("out/{material}_<UVTILE0>.exr", ["skin_u0_v0.exr", "skin_u1_v0.exr"]),
    ("out/{stem}.sss.exr", ["skin.1001.sss.exr", "skin.1002.sss.exr"]),
    ("out/{material}_{udim}.exr", ["skin_1001.exr", "skin_1002.exr"]),
], ids=["houdini-udim", "uvtile", "uvtile0", "stem-field", "udim-field"])
def test_every_output_tile_convention_gives_a_record_usd_resolves(tmp_path, pattern, names):
    """A scene file's output in any tile convention: the record resolves to the tiles written
    (the Houdini token and the UV tiles were recorded verbatim, resolving to nothing)."""
    write_stage(tmp_path)
    (tmp_path / "scene.toml").write_text(
        f'materials_from = "asset.usda"\n[defaults]\noutput = "{pattern}"\n'
        f'[[material]]\nname = "marble"\noutput = "out/marble.exr"\n')
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    stage = composed(tmp_path / "asset.usda", tmp_path / "out" / "bdipole.usda")
    files = check_record(stage.GetPrimAtPath("/Looks/skin"), "sigma_s", 2)
    assert sorted(f.rsplit("/", 1)[-1] for f in files) == names
    check_record(stage.GetPrimAtPath("/Looks/marble"), "sigma_a", 1)


def test_records_are_the_same_bytes_when_nothing_changed(tmp_path):
    stage_path = write_stage(tmp_path)
    scenes.load(stage_path).plan().run()
    folder = tmp_path / "bdipole"
    before = {p.name: p.read_bytes() for p in folder.iterdir() if not p.name.endswith(".exr")}
    again = scenes.load(stage_path).plan().run()
    assert [r for r in again.results if r.notes == ["records"]] == []
    assert {p.name: p.read_bytes() for p in folder.iterdir()
            if not p.name.endswith(".exr")} == before
    assert np.all([len(v) for v in before.values()])


def test_a_material_whose_inputs_vanished_loses_its_records_with_a_line(tmp_path):
    """The skin's albedo tiles deleted: its over (and its outputs' records) leave the layer,
    and the bake says so in a row naming the material (it vanished in silence)."""
    stage_path = write_stage(tmp_path)
    scenes.load(stage_path).plan().run()
    for tile in ("1001", "1002"):
        (tmp_path / "tex" / f"skin.{tile}.exr").unlink()
    report = scenes.load(stage_path).plan().run()
    rows = [r for r in report.results if "records removed" in r.notes]
    assert len(rows) == 1 and "skin" in rows[0].output and "/Looks/skin" in rows[0].output, \
        report.summary()
    stage = composed(stage_path, tmp_path / "bdipole" / "bdipole.usda")
    assert not stage.GetPrimAtPath("/Looks/skin").HasAttribute("bdipole:sigma_a")
    assert stage.GetPrimAtPath("/Looks/marble").HasAttribute("bdipole:sigma_a")
    # said once: the next bake has nothing more to remove
    again = scenes.load(stage_path).plan().run()
    assert not [r for r in again.results if "records removed" in r.notes]


def test_a_materialx_documents_records_resolve_where_usdmtlx_puts_its_materials(tmp_path):
    """A document's bake: its records are on /MaterialX/Materials/{name}, where a stage
    referencing the document finds the materials, and resolve to the tiles."""
    pytest.importorskip("MaterialX")
    from test_mtlx_scene import DOC_139, write_doc
    doc = write_doc(tmp_path, DOC_139)
    report = scenes.load(doc).plan().run()
    assert report.exit_code == 0, report.summary()
    stage = Usd.Stage.Open(str(tmp_path / "bdipole" / "bdipole.usda"))
    files = check_record(stage.GetPrimAtPath("/MaterialX/Materials/skin"), "sigma_a", 2)
    assert sorted(f.rsplit("/", 1)[-1] for f in files) == ["skin.1001.exr", "skin.1002.exr"]


def test_a_texture_node_reading_an_exr_layer_is_refused_not_read_as_its_first_channels(
        tmp_path):
    """An image node's ``layer`` (USD ND_image_*, MaterialX image) names other texels than the
    file's R, G, B, which a bake reads: it was ignored, and the material baked from the
    wrong channels, exit 0."""
    from pxr import UsdGeom
    from test_usd_scene import C3, F, albedo_texture, shader, texture_node
    albedo_texture(tmp_path / "tex" / "skin.exr")
    stage = Usd.Stage.CreateNew(str(tmp_path / "asset.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    skin = UsdShade.Material.Define(stage, "/Looks/skin")
    s = shader(stage, skin, "/Looks/skin/pbr", "ND_open_pbr_surface_surfaceshader", "mtlx",
               {"subsurface_weight": (F, 1.0)})
    out = texture_node(stage, "/Looks/skin/image", "ND_image_color3", "tex/skin.exr", "out")
    UsdShade.Shader(out.GetPrim()).CreateInput("layer", Sdf.ValueTypeNames.String).Set(
        "diffuse")
    s.CreateInput("subsurface_color", C3).ConnectToSource(out)
    stage.GetRootLayer().Save()
    imp = {m.name: m for m in scenes.load(tmp_path / "asset.usda").imports}["skin"]
    assert imp.left_out and "layer 'diffuse'" in imp.left_out, imp.left_out
    pytest.importorskip("MaterialX")
    (tmp_path / "look.mtlx").write_text(
        '<?xml version="1.0"?>\n<materialx version="1.39">\n'
        '  <image name="alb" type="color3">\n'
        '    <input name="file" type="filename" value="tex/skin.exr" />\n'
        '    <input name="layer" type="string" value="diffuse" />\n  </image>\n'
        '  <open_pbr_surface name="pbr" type="surfaceshader">\n'
        '    <input name="subsurface_weight" type="float" value="1" />\n'
        '    <input name="subsurface_color" type="color3" nodename="alb" />\n'
        '  </open_pbr_surface>\n  <surfacematerial name="skin" type="material">\n'
        '    <input name="surfaceshader" type="surfaceshader" nodename="pbr" />\n'
        '  </surfacematerial>\n</materialx>\n')
    imp = {m.name: m for m in scenes.load(tmp_path / "look.mtlx").imports}["skin"]
    assert imp.left_out and "layer 'diffuse'" in imp.left_out, imp.left_out


def test_a_glob_albedo_is_never_a_texture_nodes_file(tmp_path):
    """A scene file's albedo given as a glob (tex/skin.*.exr) bakes per file; a texture node
    naming the glob resolves to nothing (it was written so): the network is not written,
    said, and the records name each output file."""
    from test_scene import make_files
    make_files(tmp_path)
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "skin"\nalbedo = "tex/skin.*.exr"\nmfp = 1.0\n'
        'output = "out/{stem}_sss.exr"\nmask = "alpha"\ntargets = ["preview"]\n')
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    manifest = json.loads((tmp_path / "out" / "bdipole_materials.json").read_text())
    entry = manifest["materials"][0]
    assert entry["targets"]["preview"].startswith("not written: "), entry["targets"]
    assert "glob" in entry["targets"]["preview"]
    stage = Usd.Stage.Open(str(tmp_path / "out" / "bdipole.usda"))
    prim = stage.GetPrimAtPath("/bdipole_materials/skin")
    files = check_record(prim, "sigma_a", 2)
    assert sorted(f.rsplit("/", 1)[-1] for f in files) == ["skin.1001_sss.exr",
                                                           "skin.1002_sss.exr"]


def test_a_packaged_texture_is_named_in_its_package_not_in_the_users_cache(tmp_path):
    """A .usdz's texture is baked from a copy in the user's cache; a texture node naming that
    copy breaks when the cache is cleaned or the asset moves: it names the package's member
    (``asset.usdz[.../skin.<UDIM>.exr]``), which USD resolves (UdimUtils inside packages)."""
    from pxr import UsdUtils
    from test_bake_materials import check_connections, check_tiles
    stage_path = write_stage(tmp_path)
    usdz = tmp_path / "asset.usdz"
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(stage_path)), str(usdz))
    report = scenes.load(usdz, targets="preview").plan().run()
    assert report.exit_code == 0, report.summary()
    stage = composed(usdz, tmp_path / "bdipole" / "bdipole.usda")
    skin = UsdShade.Material(stage.GetPrimAtPath("/Looks/skin"))
    tex = skin.GetPrim().GetChild("bdipole_preview_albedo")
    asset = tex.GetAttribute("inputs:file").Get()
    assert asset.path.startswith("./../asset.usdz[") and asset.path.endswith(
        "skin.<UDIM>.exr]"), asset.path
    check_connections(skin)
    check_tiles(skin, 2)
