"""Scenes from MaterialX documents (bdipole_cl/io/mtlx_scene.py): documents written here, in
the 1.38+ syntax (shader nodes, surfacematerial) and the 1.37 one (shaderref, bindinput)."""
import json

import numpy as np
import pytest

pytest.importorskip("MaterialX")

import bdipole_cl as bd  # noqa: E402
from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.io.scene_import import import_materials  # noqa: E402
from test_scene import read  # noqa: E402
from test_usd_scene import albedo_texture, check_texture_bake  # noqa: E402

pytestmark = pytest.mark.usefixtures("on_device")

#: 1.39: an OpenPBR skin whose colour comes from a tiled <UDIM> image through a node graph
#: (the graph's colour space from the document default), radius in millimetres; a Standard
#: Surface with constants; a UsdPreviewSurface (DOC_139_NOISY: and a noise-fed one)
DOC_139 = """<?xml version="1.0"?>
<materialx version="1.39" colorspace="srgb_texture" fileprefix="tex/">
  <nodegraph name="skin_graph">
    <tiledimage name="albedo" type="color3">
      <input name="file" type="filename" value="skin.<UDIM>.exr" colorspace="lin_rec709" />
    </tiledimage>
    <output name="out" type="color3" nodename="albedo" />
  </nodegraph>
  <open_pbr_surface name="skin_pbr" type="surfaceshader">
    <input name="subsurface_weight" type="float" value="1" />
    <input name="subsurface_color" type="color3" nodegraph="skin_graph" output="out" />
    <input name="subsurface_radius" type="float" value="RADIUS" unittype="distance"
           unit="millimeter" />
    <input name="subsurface_radius_scale" type="color3" value="1, 0.5, 0.25" />
    <input name="specular_ior" type="float" value="1.4" />
  </open_pbr_surface>
  <surfacematerial name="skin" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="skin_pbr" />
  </surfacematerial>
  <standard_surface name="jade_std" type="surfaceshader">
    <input name="subsurface" type="float" value="1" />
    <input name="subsurface_color" type="color3" value="0.7, 0.5, 0.3" />
    <input name="subsurface_radius" type="color3" value="1, 0.6, 0.3" />
    <input name="subsurface_scale" type="float" value="0.5" />
  </standard_surface>
  <surfacematerial name="jade" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="jade_std" />
  </surfacematerial>
  <UsdPreviewSurface name="plastic_preview" type="surfaceshader" />
  <surfacematerial name="plastic" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="plastic_preview" />
  </surfacematerial>
</materialx>
"""

#: DOC_139 with a subsurface material no bake can bake (its colour a noise)
DOC_139_NOISY = DOC_139.replace("</materialx>", """  <fractal3d name="fbm" type="color3" />
  <open_pbr_surface name="noisy_pbr" type="surfaceshader">
    <input name="subsurface_weight" type="float" value="1" />
    <input name="subsurface_color" type="color3" nodename="fbm" />
  </open_pbr_surface>
  <surfacematerial name="noisy" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="noisy_pbr" />
  </surfacematerial>
</materialx>""")

#: 1.37: material / shaderref / bindinput, the image's file a parameter; no colorspace on
#: the image, so the document's (srgb_texture) is the texture's
DOC_137 = """<?xml version="1.0"?>
<materialx version="1.37" colorspace="srgb_texture">
  <nodegraph name="wax_graph">
    <image name="albedo" type="color3">
      <parameter name="file" type="filename" value="tex/wax.exr" />
    </image>
    <output name="out" type="color3" nodename="albedo" />
  </nodegraph>
  <material name="wax">
    <shaderref name="wax_std" node="standard_surface">
      <bindinput name="subsurface" type="float" value="0.8" />
      <bindinput name="subsurface_color" type="color3" nodegraph="wax_graph" output="out" />
      <bindinput name="subsurface_radius" type="color3" value="2, 1, 0.5" />
      <bindinput name="subsurface_scale" type="float" value="0.1" />
      <bindinput name="specular_IOR" type="float" value="1.45" />
    </shaderref>
  </material>
  <material name="glass">
    <shaderref name="glass_std" node="standard_surface">
      <bindinput name="subsurface" type="float" value="0" />
    </shaderref>
  </material>
</materialx>
"""


def write_doc(root, text, name="look.mtlx", radius="0.5"):
    for k, tile in enumerate(("1001", "1002")):
        albedo_texture(root / "tex" / f"skin.{tile}.exr", k)
    albedo_texture(root / "tex" / "wax.exr", 4)
    path = root / name
    path.write_text(text.replace("RADIUS", radius))
    return path


def test_materialx_139_shaders_textures_units_and_refusals(tmp_path):
    path = write_doc(tmp_path, DOC_139_NOISY)
    imports = {m.name: m for m in import_materials(path)}
    skin = imports["skin"]
    assert skin.shader == "OpenPBR Surface" and skin.path == "/MaterialX/Materials/skin"
    assert skin.facts["albedo"] == str(tmp_path / "tex" / "skin.<UDIM>.exr")   # fileprefix
    assert skin.facts["colorspace"] == "lin_rec709"
    # 0.5 mm in the document's unit (m): the radius x radius_scale product in metres
    np.testing.assert_allclose(skin.facts["mfp"], [5e-4, 2.5e-4, 1.25e-4])
    assert skin.facts["unit"] == "m"
    assert imports["jade"].shader == "Standard Surface"
    assert imports["jade"].facts["eta"] == [1.5]                  # specular_IOR's default
    assert imports["noisy"].left_out == ("not bakeable: subsurface_color comes from fractal3d "
                                         "(fbm), a procedural network")
    assert imports["plastic"].left_out == "no subsurface (UsdPreviewSurface shader): left out"


def test_materialx_bake_in_millimetres_equals_albedo_to_coefficients(tmp_path):
    write_doc(tmp_path, DOC_139_NOISY)
    scene = tmp_path / "scene.toml"
    scene.write_text('materials_from = "look.mtlx"\n[defaults]\nunit = "mm"\n')
    report = scenes.load(scene).plan().run()
    # the noise-fed material is not baked: the bake fails it, named; the others bake
    assert report.exit_code == 1, report.summary()
    assert [r.path for r in report.results if r.status != "ok"] == [
        "material noisy (/MaterialX/Materials/noisy)"], report.summary()
    for k, tile in enumerate(("1001", "1002")):
        albedo = albedo_texture(tmp_path / "probe" / "a.exr", k)
        check_texture_bake(tmp_path / "bdipole" / f"skin.{tile}.exr", albedo,
                           0.5 * np.array([1, 0.5, 0.25]), 1.4, "extinction")
    records = json.loads((tmp_path / "bdipole" / "bdipole_materials.json").read_text())
    entries = {e["name"]: e for e in records["materials"]}
    assert entries["skin"]["unit"] == "mm" and entries["jade"]["mfp_kind"] == "extinction"
    assert entries["noisy"]["baked"] is False
    from pxr import Sdf
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "bdipole" / "bdipole.usda"))
    prim = layer.GetPrimAtPath("/MaterialX/Materials/skin")
    assert prim.attributes["bdipole:sigma_s"].default.path == "./skin.<UDIM>.exr"


def test_materialx_137_is_upgraded_and_read(tmp_path):
    path = write_doc(tmp_path, DOC_137)
    imports = {m.name: m for m in import_materials(path)}
    wax = imports["wax"]
    assert wax.shader == "Standard Surface" and wax.left_out is None
    assert wax.facts["albedo"] == str(tmp_path / "tex" / "wax.exr")
    assert wax.facts["colorspace"] == "srgb_texture"        # the document's default
    np.testing.assert_allclose(wax.facts["mfp"], [0.2, 0.1, 0.05])
    assert wax.facts["eta"] == [1.45]
    assert imports["glass"].left_out == "no subsurface (subsurface = 0): left out"
    report = scenes.load(path).plan().run()
    assert report.exit_code == 0, report.summary()
    # the document's colour space reaches colour management: the texels are decoded from
    # sRGB into the working space before the inversion
    from bdipole_cl.io.colour import active_config, resolve_working_space
    texels = albedo_texture(tmp_path / "probe" / "w.exr", 4).astype(np.float32)
    decoded = active_config().convert(texels, "srgb_texture", resolve_working_space().name)
    check_texture_bake(tmp_path / "bdipole" / "wax.exr", decoded,
                       np.array([0.2, 0.1, 0.05]), 1.45, "extinction")


def test_a_changed_value_in_the_document_rebakes_that_material_only(tmp_path):
    path = write_doc(tmp_path, DOC_139)
    assert scenes.load(path).plan().run().exit_code == 0
    again = scenes.load(path).plan().run()
    assert [r.status for r in again.results] == ["skipped"] * len(again.results)
    path.write_text(DOC_139.replace("RADIUS", "0.6"))
    todo = sorted((j.name, j.udim) for j in scenes.load(path).plan().jobs if not j.up_to_date)
    assert todo == [("skin", "1001"), ("skin", "1002")]


def test_a_float_image_of_a_baked_input_is_refused_as_one_channel(tmp_path):
    doc = """<?xml version="1.0"?>
<materialx version="1.39">
  <image name="rad" type="float"><input name="file" type="filename" value="tex/wax.exr" />
  </image>
  <image name="alb" type="color3"><input name="file" type="filename" value="tex/wax.exr" />
  </image>
  <open_pbr_surface name="s" type="surfaceshader">
    <input name="subsurface_weight" type="float" value="1" />
    <input name="subsurface_color" type="color3" nodename="alb" />
    <input name="subsurface_radius" type="float" nodename="rad" />
  </open_pbr_surface>
  <surfacematerial name="m" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="s" />
  </surfacematerial>
</materialx>
"""
    (imp,) = import_materials(write_doc(tmp_path, doc))
    assert "subsurface_radius reads out (a float image: the file's first channel) of rad, " \
        "one channel" in imp.left_out


@pytest.mark.parametrize("edit, why", [
    (('unit="millimeter"', 'unit="parsec"'), "unit 'parsec' is not a distance unit"),
    (('value="1.4"', 'value="nan"'), "eta = [nan]"),
    (('value="1.4"', 'value="9"'), "eta=9.0 is outside"),
    (('value="RADIUS"', 'value="0"'), "mfp = "),
    (('value="1.4"', 'value="glass"'), "= 'glass': expected a number"),
], ids=["unit", "nan eta", "eta out of range", "zero radius", "no number"])
def test_a_bad_value_in_the_document_leaves_that_material_out_and_the_rest_bake(tmp_path,
                                                                                edit, why):
    """A value of one material that cannot be baked (a unit that is not a distance, a NaN or
    out-of-range eta, a radius of 0) leaves that material out, named with the value, as
    other not-bakeable materials are: the document still loads and the others bake; the
    bake fails that material (exit 1), named."""
    path = write_doc(tmp_path, DOC_139.replace(*edit))
    scene = scenes.load(path)
    left = {m.name: m.left_out for m in scene.imports}
    assert left["skin"] and left["skin"].startswith("not bakeable") and why in left["skin"], left
    assert "jade" in {m.name for m in scene.materials}
    assert "skin" not in {m.name for m in scene.materials}
    report = scene.plan().run()
    assert report.exit_code == 1, report.summary()
    assert [r.path for r in report.results if r.status != "ok"] == [
        "material skin (/MaterialX/Materials/skin)"], report.summary()
    records = json.loads((tmp_path / "bdipole" / "bdipole_materials.json").read_text())
    by_name = {e["name"]: e for e in records["materials"]}
    assert by_name["jade"]["baked"] and why in by_name["skin"]["left_out"]


#: an included document with a namespace and a texture beside it, an image whose file comes
#: through its node graph's interface, and a shader inside a node graph whose radius does
LIBRARY = """<?xml version="1.0"?>
<materialx version="1.39" namespace="lib">
  <image name="img" type="color3"><input name="file" type="filename" value="tex/wax.exr" />
  </image>
  <open_pbr_surface name="pbr" type="surfaceshader">
    <input name="subsurface_weight" type="float" value="1" />
    <input name="subsurface_color" type="color3" nodename="lib:img" />
  </open_pbr_surface>
  <surfacematerial name="skin" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="lib:pbr" />
  </surfacematerial>
</materialx>
"""
INCLUDING = """<?xml version="1.0"?>
<materialx version="1.39">
  <xi:include href="lib/library.mtlx" />
  <nodegraph name="graph">
    <input name="albedo_file" type="filename" value="tex/skin.<UDIM>.exr" />
    <input name="radius" type="float" value="0.25" />
    <image name="img" type="color3">
      <input name="file" type="filename" interfacename="albedo_file" />
    </image>
    <open_pbr_surface name="pbr" type="surfaceshader">
      <input name="subsurface_weight" type="float" value="1" />
      <input name="subsurface_color" type="color3" nodename="img" />
      <input name="subsurface_radius" type="float" interfacename="radius" />
    </open_pbr_surface>
    <output name="surface" type="surfaceshader" nodename="pbr" />
  </nodegraph>
  <surfacematerial name="skin" type="material">
    <input name="surfaceshader" type="surfaceshader" nodegraph="graph" output="surface" />
  </surfacematerial>
</materialx>
"""


def test_includes_namespaces_and_interface_inputs(tmp_path):
    """An included document's texture is relative to that document; its namespaced material
    (lib:skin) is a valid prim and file name beside the root's skin, and both bake; a file and
    a radius through a node graph's interface inputs are read."""
    path = write_doc(tmp_path, INCLUDING)
    albedo_texture(tmp_path / "lib" / "tex" / "wax.exr", 2)
    (tmp_path / "lib" / "library.mtlx").write_text(LIBRARY)
    imports = {m.name: m for m in import_materials(path)}
    assert set(imports) == {"skin", "lib_skin"}
    lib = imports["lib_skin"]
    assert lib.path == "/MaterialX/Materials/lib_skin"
    assert lib.facts["albedo"] == str(tmp_path / "lib" / "tex" / "wax.exr")
    skin = imports["skin"]
    assert skin.facts["albedo"] == str(tmp_path / "tex" / "skin.<UDIM>.exr")
    np.testing.assert_allclose(skin.facts["mfp"], [0.25, 0.125, 0.0625])
    report = scenes.load(path).plan().run()
    assert report.exit_code == 0
    assert (tmp_path / "bdipole" / "lib_skin.exr").is_file()
    assert "lib_skin" in (tmp_path / "bdipole" / "bdipole.usda").read_text()


def image_doc(path, layer=None, node_type="color3", target="subsurface_color",
              shader="open_pbr_surface", version=None, file="tex/wax.exr", albedo=None):
    """A document authored with MaterialX's own API: one material whose ``target`` input
    comes from an image node (of ``layer``), its colour from an image of ``albedo`` where
    ``target`` is not the colour."""
    import MaterialX as mx
    doc = mx.createDocument()
    img = doc.addNode("image", "img", node_type)
    img.setInputValue("file", file, "filename")
    if layer is not None:
        img.setInputValue("layer", layer, "string")
    s = doc.addNode(shader, "s", "surfaceshader")
    if version:
        s.setVersionString(version)
    weight = "subsurface_weight" if shader == "open_pbr_surface" else "subsurface"
    s.setInputValue(weight, 1.0)
    s.addInput(target, node_type).setNodeName("img")
    if albedo:
        alb = doc.addNode("image", "alb", "color3")
        alb.setInputValue("file", albedo, "filename")
        s.addInput("subsurface_color", "color3").setNodeName("alb")
    doc.addMaterialNode("m", s)
    mx.writeToXmlFile(doc, str(path))
    return path


def layered_exr(path, layers):
    """An EXR of R, G, B per layer name ('' unlayered): {layer: (r, g, b)}."""
    from bdipole_cl.apps.demo import write_exr
    names = [f"{lay}.{c}" if lay else c for lay in layers for c in "RGB"]
    px = np.concatenate([np.broadcast_to(np.float32(v), (4, 4, 3)) for v in layers.values()],
                        -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_exr(path, px, names)


def test_an_image_layer_is_baked_from_that_layer_or_the_material_fails(tmp_path):
    """An image's ``layer`` names the file's layer to read, and the bake reads that layer
    (OpenImageIO reads it by its channels' names): where the file also has unlayered R, G, B
    the layer's texels are baked, never the file's first ones (it was refused with an
    oiiotool command, and the bake said "done", exit 0, having baked nothing). A layer the
    file lacks leaves the material out, and the bake fails it, named."""
    layers = {"both": {"": (0.2, 0.2, 0.2), "diffuse": (0.8, 0.6, 0.4)},
              "only": {"diffuse": (0.8, 0.6, 0.4)}, "none": {"diffuse": (0.8, 0.6, 0.4)}}
    for name, found in layers.items():       # each document in a folder of its own
        layered_exr(tmp_path / name / "tex" / "a.exr", found)
    want_a, _ = bd.albedo_to_coefficients(np.float32([0.8, 0.6, 0.4]), np.float32([1, 0.5, 0.25]),
                                          1.5, mfp_kind="extinction")
    for name in ("both", "only"):
        path = image_doc(tmp_path / name / "m.mtlx", "diffuse", file="tex/a.exr")
        (imp,) = import_materials(path)
        assert imp.left_out is None and imp.facts["albedo_layer"] == "diffuse", imp.left_out
        report = scenes.load(path).plan().run()
        assert report.exit_code == 0, report.summary()
        px, names = read(tmp_path / name / "bdipole" / "m.exr")
        assert names == [f"{o}.{ch}" for o in ("sigma_a", "sigma_s") for ch in "RGB"], names
        # the scene's accuracy contract: 1e-4 relative (tests/test_usd_scene.py TOL)
        np.testing.assert_allclose(px[..., :3], np.broadcast_to(want_a, (4, 4, 3)), rtol=1e-4,
                                   err_msg=name)
    path = image_doc(tmp_path / "none" / "m.mtlx", "spec", file="tex/a.exr")
    (imp,) = import_materials(path)
    assert imp.left_out and "which has no colour channel in that layer" in imp.left_out
    report = scenes.load(path).plan().run()
    assert report.exit_code == 1, report.summary()
    assert [r.path for r in report.results if r.status != "ok"] == [
        "material m (/MaterialX/Materials/m)"]


def test_a_one_channel_radius_map_on_openpbrs_float_radius_bakes(tmp_path):
    """OpenPBR's subsurface_radius is a float: a float image of a one-channel file is the mfp
    texture, times subsurface_radius_scale per channel (it was refused, with advice to use a
    color3 image, which a float input cannot take). A float image of an RGB file reads its
    first channel: refused with a command that makes that channel a file."""
    from bdipole_cl.apps.demo import write_exr
    albedo = albedo_texture(tmp_path / "tex" / "wax.exr", 4)
    radius = np.linspace(0.5, 2.0, 64, dtype=np.float32).reshape(8, 8)
    write_exr(tmp_path / "tex" / "radius.exr", radius, ("Y",))
    layered_exr(tmp_path / "tex" / "rgb.exr", {"": (1.0, 2.0, 3.0)})
    path = image_doc(tmp_path / "one.mtlx", None, "float", "subsurface_radius",
                     file="tex/radius.exr", albedo="tex/wax.exr")
    (imp,) = import_materials(path)
    assert imp.left_out is None, imp.left_out
    report = scenes.load(path).plan().run()
    assert report.exit_code == 0, report.summary()
    mfp = radius[..., None] * np.float32([1.0, 0.5, 0.25])    # OpenPBR's radius_scale
    check_texture_bake(tmp_path / "bdipole" / "m.exr", albedo, mfp, 1.5, "extinction")
    path = image_doc(tmp_path / "rgb.mtlx", None, "float", "subsurface_radius",
                     file="tex/rgb.exr", albedo="tex/wax.exr")
    (imp,) = import_materials(path)
    assert imp.left_out and "whose colour is R, G, B" in imp.left_out \
        and "--ch R -o" in imp.left_out, imp.left_out


def test_standard_surface_1_0_0_is_standard_surface(tmp_path):
    """A document pinning Standard Surface 1.0.0 (version="1.0.0": its nodedef
    ND_standard_surface_surfaceshader_100) is read as Standard Surface, as 1.0.1 is."""
    albedo_texture(tmp_path / "tex" / "wax.exr", 4)
    path = image_doc(tmp_path / "old.mtlx", shader="standard_surface", version="1.0.0")
    (imp,) = import_materials(path)
    assert imp.shader == "Standard Surface" and imp.left_out is None, imp.left_out
