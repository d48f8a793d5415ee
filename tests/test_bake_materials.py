"""Material networks a bake writes (bdipole_cl/io/networks.py, usd_networks.py,
mtlx_networks.py, targets.py), loaded with their consumers' own APIs: UsdShade's binding and
surface resolution per render context, every connection to a declared input of its type,
UsdShade.UdimUtils finding every tile, USD's validators (usdchecker's), and the library's own
reader giving back the material that was baked."""
import json
import re

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Sdr, Usd, UsdGeom, UsdShade, UsdValidation  # noqa: E402

import bdipole_cl as bd  # noqa: E402
from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.io.targets import TARGET, parse_targets  # noqa: E402
from bdipole_cl.io.usd_networks import RENDERMAN_TYPES, sdf_type  # noqa: E402
from test_bake_records import composed  # noqa: E402
from test_scene import read  # noqa: E402
from test_usd_scene import C3, F, albedo_texture, shader, texture_node, write_stage  # noqa: E402

pytestmark = pytest.mark.usefixtures("on_device")


def baked(tmp_path, targets=None):
    stage_path = write_stage(tmp_path)
    report = scenes.load(stage_path, targets=targets).plan().run()
    assert report.exit_code == 0, report.summary()
    return stage_path, composed(stage_path, tmp_path / "bdipole" / "bdipole.usda")


def ours(material):
    """The shader and node-graph prims the bake wrote under a material."""
    return [p for p in Usd.PrimRange(material.GetPrim()) if p.GetName().startswith("bdipole_")
            or p.GetParent().GetName() == "bdipole_coefficients"]


def declared(shader_id, name):
    """The type a shader declares for ``name``: Sdr's (USD's own nodes), MaterialX's nodedefs,
    RenderMan's argument files."""
    if shader_id in RENDERMAN_TYPES or shader_id.startswith("ND_"):
        return sdf_type(shader_id, name)
    node = Sdr.Registry().GetShaderNodeByIdentifier(shader_id)
    assert node is not None, shader_id
    prop = node.GetShaderInput(name) or node.GetShaderOutput(name)
    assert prop is not None, (shader_id, name)
    return prop.GetTypeAsSdfType().GetSdfType()


def check_connections(material):
    """Every input of the bake's shaders has its shader's declared type, and every connection
    resolves to an existing output, of the same value type, of a shader under the material."""
    n = 0
    for prim in ours(material):
        if not prim.IsA(UsdShade.Shader):
            continue
        s = UsdShade.Shader(prim)
        sid = s.GetShaderId()
        for inp in s.GetInputs():
            assert inp.GetTypeName() == declared(sid, inp.GetBaseName()), (prim.GetPath(), inp)
            for source in inp.GetConnectedSources()[0]:
                out = source.source.GetOutput(source.sourceName)
                assert out, (inp.GetAttr().GetPath(), source.sourceName)
                assert out.GetTypeName().type == inp.GetTypeName().type, (inp, out)
                assert out.GetPrim().GetPath().HasPrefix(material.GetPath())
                n += 1
    return n


def check_tiles(material, want):
    """Every asset input of the bake's shaders resolves, through UdimUtils for <UDIM>, to
    ``want[its file name's stem]`` files."""
    for prim in ours(material):
        for attr in prim.GetAttributes():
            if attr.GetTypeName() != Sdf.ValueTypeNames.Asset:
                continue
            asset = attr.Get()
            if UsdShade.UdimUtils.IsUdimIdentifier(asset.path):
                layer = attr.GetPropertyStack(Usd.TimeCode.Default())[0].layer
                files = UsdShade.UdimUtils.ResolveUdimTilePaths(asset.path, layer)
                assert len(files) == want, (attr.GetPath(), asset.path, files)
            else:
                assert asset.resolvedPath, (attr.GetPath(), asset.path)


def same_as_layer(own, layered, layer):
    """The file ``own`` a texture node names holds, as its first channels (all MaterialX's
    generators read: GLSL ignores an image's ``layer``, OSL takes it for a subimage), the
    ``layer`` of the output ``layered``, bit for bit, named R, G, B."""
    px, names = read(own)
    want, want_names = read(layered)
    idx = [i for i, n in enumerate(want_names) if n.startswith(f"{layer}.")]
    assert names == [n.rsplit(".", 1)[1] for n in (want_names[i] for i in idx)], (own, names)
    np.testing.assert_array_equal(px, want[..., idx], err_msg=str(own))


def test_geometry_binds_the_bakes_networks_per_render_context(tmp_path):
    stage_path, stage = baked(tmp_path, targets="preview,pxrsurface")
    bound = {}
    for geom in ("head", "table"):
        prim = stage.GetPrimAtPath(f"/World/{geom}")
        bound[geom], _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    skin, marble = bound["head"], bound["table"]
    assert str(skin.GetPath()) == "/Looks/skin" and str(marble.GetPath()) == "/Looks/marble"
    surface = {ctx: marble.ComputeSurfaceSource(ctx)[0] for ctx in ("ri", "")}
    assert surface["ri"].GetShaderId() == "PxrSurface"
    assert surface["ri"].GetPath().name == "bdipole_pxrsurface"
    assert surface[""].GetShaderId() == "UsdPreviewSurface"
    # the user's own OpenPBR network is kept (no openpbr target); the skin's PxrSurface
    # reads maps (its radius is an extinction mean free path: test below)
    assert skin.ComputeSurfaceSource("mtlx")[0].GetShaderId() == \
        "ND_open_pbr_surface_surfaceshader"
    assert skin.ComputeSurfaceSource("")[0].GetPath().name == "bdipole_preview"
    assert skin.ComputeSurfaceSource("ri")[0].GetPath().name == "bdipole_pxrsurface"
    # the PxrSurface reads the painted colour and the dmfp in the stage's unit (cm), all of
    # the distance in the colour (unitLength 1: RenderMan's default 0.1 would scale it)
    pxr_surface = surface["ri"]
    np.testing.assert_allclose(pxr_surface.GetInput("subsurfaceDmfpColor").Get(),
                               2.0 * np.array([1, 0.8, 0.6]) * 0.1, rtol=1e-6)
    assert pxr_surface.GetInput("unitLength").Get() == 1.0
    assert pxr_surface.GetInput("subsurfaceIor").Get() == pytest.approx(1.33)
    tex = pxr_surface.GetInput("subsurfaceColor").GetConnectedSources()[0][0].source
    assert UsdShade.Shader(tex.GetPrim()).GetShaderId() == "PxrTexture"
    assert tex.GetInput("filename").Get().resolvedPath == str(tmp_path / "tex" / "marble.exr")
    # the coefficient graph's image nodes read each output's own file (its first channels:
    # no MaterialX generator reads a layer), as data
    graph = UsdShade.NodeGraph(skin.GetPrim().GetChild("bdipole_coefficients"))
    for output in ("sigma_a", "sigma_s"):
        node = graph.GetOutput(output).GetConnectedSources()[0][0].source
        assert not node.GetInput("layer")
        assert node.GetInput("file").Get().path == f"./skin.<UDIM>.{output}.exr"
        assert node.GetInput("file").GetAttr().GetColorSpace() == "raw"
        for tile in ("1001", "1002"):
            same_as_layer(tmp_path / "bdipole" / f"skin.{tile}.{output}.exr",
                          tmp_path / "bdipole" / f"skin.{tile}.exr", output)
    for material in (skin, marble):
        assert check_connections(material) >= 2
    check_tiles(skin, 2)
    check_tiles(marble, 1)


def test_usd_validators_find_nothing_the_bake_added(tmp_path):
    """usdchecker's validators (UsdValidation; usd-core ships no usdchecker binary) on the
    stage with and without the bake's layer: the layer adds no error."""
    stage_path, stage = baked(tmp_path)
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()

    def errors(s):
        return sorted(f"{e.GetName()}: {e.GetMessage()}" for e in
                      UsdValidation.ValidationContext(validators).Validate(s)
                      if "anon:" not in e.GetMessage())

    before = errors(Usd.Stage.Open(str(stage_path)))
    after = errors(stage)
    added = [e for e in after if e not in before]
    # usd-core ships no Sdr definitions of MaterialX's nodes (usdMtlx) nor RenderMan's: their
    # ids are "not found" here (the user's own ND_ nodes too); check_connections checks those
    # against MaterialX's nodedefs and RenderMan's argument files instead
    unknown = [e for e in added if e.startswith("MissingShaderIdInRegistry: shaderId 'ND_")
               or any(f"shaderId '{i}'" in e for i in RENDERMAN_TYPES)]
    assert [e for e in added if e not in unknown] == [], after
    assert any("Looks/skin/bdipole_preview" in e for e in after) is False


@pytest.mark.parametrize("spelling, names", [
    ("preview", ("preview",)), ("PxrSurface,preview", ("preview", "pxrsurface")),
    (["openpbr", "pxrsurface"], ("pxrsurface", "openpbr"))])
def test_targets_are_one_registry(spelling, names):
    assert parse_targets(spelling) == names
    assert set(names) <= set(TARGET.names)


def test_two_targets_of_one_render_context_are_refused():
    with pytest.raises(ValueError, match="openpbr,standard-surface: both write the mtlx"):
        parse_targets("openpbr,standard-surface")
    with pytest.raises(ValueError, match="target='arnold'"):
        parse_targets("arnold")


def test_only_the_chosen_targets_are_written_and_said(tmp_path):
    import json
    stage_path, stage = baked(tmp_path, targets="preview")
    marble = UsdShade.Material(stage.GetPrimAtPath("/Looks/marble"))
    assert not marble.GetPrim().GetChild("bdipole_pxrsurface")
    assert marble.ComputeSurfaceSource("ri")[0].GetPath().name != "bdipole_pxrsurface"
    records = json.loads((tmp_path / "bdipole" / "bdipole_materials.json").read_text())
    entries = {e["name"]: e for e in records["materials"]}
    assert entries["marble"]["targets"] == {"preview": "written"}
    stage_path, stage = baked(tmp_path / "both", targets="pxrsurface,openpbr")
    records = json.loads((tmp_path / "both" / "bdipole" / "bdipole_materials.json").read_text())
    entries = {e["name"]: e for e in records["materials"]}
    assert entries["skin"]["targets"]["pxrsurface"] == "written"
    # openpbr: its colour and radius maps converted to van de Hulst (physics.transport)
    assert entries["skin"]["targets"]["openpbr"] == "written", entries["skin"]["targets"]


def painted_pxr_stage(root):
    """A PxrSurface whose colour and dmfp colour are painted <UDIM> textures (UsdUVTexture),
    dmfp 0.5 and unitLength 0.1 (a dmfp in mm on a stage in cm)."""
    for k, tile in enumerate(("1001", "1002")):
        albedo_texture(root / "tex" / f"wax.{tile}.exr", k)
        albedo_texture(root / "tex" / f"wax_mfp.{tile}.exr", k + 5)
    stage = Usd.Stage.CreateNew(str(root / "wax.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    wax = UsdShade.Material.Define(stage, "/Looks/wax")
    s = shader(stage, wax, "/Looks/wax/pxr", "PxrSurface", "ri",
               {"subsurfaceGain": (F, 1.0), "subsurfaceDmfp": (F, 0.5),
                "subsurfaceIor": (F, 1.45)})
    s.CreateInput("subsurfaceColor", C3).ConnectToSource(texture_node(
        stage, "/Looks/wax/albedo", "UsdUVTexture", "tex/wax.<UDIM>.exr", "rgb", source="raw"))
    s.CreateInput("subsurfaceDmfpColor", C3).ConnectToSource(texture_node(
        stage, "/Looks/wax/mfp", "UsdUVTexture", "tex/wax_mfp.<UDIM>.exr", "rgb",
        source="raw"))
    mesh = UsdGeom.Mesh.Define(stage, "/World/candle")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(wax)
    stage.GetRootLayer().Save()
    return root / "wax.usda"


def test_the_written_pxrsurface_reads_back_as_the_material_that_was_baked(tmp_path):
    """Round trip: bake a painted PxrSurface; a stage with the bake's layer over it, read by
    the library's own reader from the written network (PxrTexture nodes now), is the same
    material, and its bake gives the same coefficients, bit for bit."""
    path = painted_pxr_stage(tmp_path)
    report = scenes.load(path, targets="pxrsurface").plan().run()
    assert report.exit_code == 0, report.summary()
    over = tmp_path / "wax_baked.usda"
    over.write_text('#usda 1.0\n(\n    subLayers = [@bdipole/bdipole.usda@, @wax.usda@]\n)\n')
    first = {m.name: m for m in scenes.load(path).materials}["wax"]
    imports = {m.name: m for m in scenes.load(over).imports}
    assert imports["wax"].inputs["subsurfaceColor"].startswith(
        "subsurfaceColor <- " + str(tmp_path / "tex" / "wax.<UDIM>.exr"))
    assert imports["wax"].inputs["subsurfaceColor"].endswith("(raw)")
    (tmp_path / "again.toml").write_text('materials_from = "wax_baked.usda"\n[defaults]\n'
                                         'output = "again/{material}.<UDIM>.exr"\n')
    second = {m.name: m for m in scenes.load(tmp_path / "again.toml").materials}["wax"]
    for key in ("albedo", "mfp", "mfp_scale", "eta", "mfp_kind", "colorspace", "unit"):
        assert getattr(second, key) == getattr(first, key), key
    report = scenes.load(tmp_path / "again.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    for tile in ("1001", "1002"):
        a, names_a = read(tmp_path / "bdipole" / f"wax.{tile}.exr")
        b, names_b = read(tmp_path / "again" / f"wax.{tile}.exr")
        assert names_a == names_b
        np.testing.assert_array_equal(a, b)


def generated(doc, element):
    """GLSL, OSL and (where MaterialX has it) MDL source MaterialX's own generators write for
    ``element``."""
    import MaterialX as mx
    import MaterialX.PyMaterialXGenGlsl as glsl
    import MaterialX.PyMaterialXGenOsl as osl
    import MaterialX.PyMaterialXGenShader as gen_shader
    from bdipole_cl.io.mtlx_networks import library
    generators = [("glsl", glsl.GlslShaderGenerator), ("osl", osl.OslShaderGenerator)]
    try:
        import MaterialX.PyMaterialXGenMdl as mdl
        generators.append(("mdl", mdl.MdlShaderGenerator))
    except ImportError:
        pass
    out = {}
    for lang, cls, stage in ((lang, cls, gen_shader.PIXEL_STAGE) for lang, cls in generators):
        gen = cls.create()
        context = gen_shader.GenContext(gen)
        context.registerSourceCodeSearchPath(mx.getDefaultDataSearchPath())
        cms = gen_shader.DefaultColorManagementSystem.create(gen.getTarget())
        cms.loadLibrary(library())
        gen.setColorManagementSystem(cms)
        out[lang] = gen.generate(element.getName(), element, context).getSourceCode(stage)
    return out


def test_the_materialx_document_validates_and_generates_glsl_and_osl(tmp_path):
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.io.mtlx_networks import library
    baked(tmp_path)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(tmp_path / "bdipole" / "bdipole.mtlx"))
    assert not [e.getNamePath() for e in doc.traverseTree() if e.getCategory() == "input"
                and e.getName() == "layer"]           # (before the libraries' own nodes)
    doc.importLibrary(library())
    ok, message = doc.validate()
    assert ok, message
    materials = {m.getName(): m for m in doc.getMaterialNodes()}
    assert set(materials) == {"skin", "jade", "marble"}
    for name, material in materials.items():
        code = generated(doc, material)
        assert all(len(c) > 1000 for c in code.values()), name
    # the skin's albedo file, and each coefficient's own file, as written: no image names a
    # layer (GLSL ignores it: every image read the file's first channels, the sigma_a; OSL
    # took it for a subimage: "Unknown subimage"), the generated code has none, and each file's
    # first channels are what its node reads
    skin = mx.getShaderNodes(materials["skin"])[0]
    image = skin.getInput("diffuseColor").getConnectedNode()
    assert image.getInputValue("file") == "./../tex/skin.<UDIM>.exr"
    assert image.getInput("file").getColorSpace() == "lin_rec709"
    graph = doc.getNodeGraph("skin_coefficients")
    for output in ("sigma_a", "sigma_s"):
        node = graph.getOutput(output).getConnectedNode()
        assert node.getType() == "vector3"
        assert node.getInputValue("file") == f"./skin.<UDIM>.{output}.exr"
        code = generated(doc, graph.getOutput(output))
        assert all("texture" in c for c in code.values())
        # OSL hands an image's layer to OpenImageIO as "subimage" (MDL has it too): empty,
        # the file's own
        for lang in {"osl", "mdl"} & set(code):
            layers = set(re.findall(r'string \w+_layer = "([^"]*)"', code[lang]))
            assert layers == {""}, (lang, output, layers)
        for tile in ("1001", "1002"):
            same_as_layer(tmp_path / "bdipole" / f"skin.{tile}.{output}.exr",
                          tmp_path / "bdipole" / f"skin.{tile}.exr", output)


@pytest.mark.parametrize("targets", ["preview,pxrsurface,openpbr", "preview,standard-surface",
                                     "openpbr,preview"])
def test_a_preview_beside_a_materialx_target_has_names_of_its_own(tmp_path, targets):
    """A preview with OpenPBR or Standard Surface: the preview's material and the preview's
    shader node shared a name (LookupError: "Child name is not unique: skin_preview", the
    bake stopped). Every element has a name of its own; each material's shader generates."""
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.io.mtlx_networks import library
    baked(tmp_path, targets=targets)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(tmp_path / "bdipole" / "bdipole.mtlx"))
    doc.importLibrary(library())
    ok, message = doc.validate()
    assert ok, message
    materials = {m.getName(): m for m in doc.getMaterialNodes()}
    assert set(materials) == {f"{m}{k}" for m in ("skin", "jade", "marble")
                              for k in ("", "_preview")}
    main = "standard_surface" if "standard" in targets else "open_pbr_surface"
    for name, material in materials.items():
        (shader,) = mx.getShaderNodes(material)
        assert shader.getCategory() == ("UsdPreviewSurface" if name.endswith("_preview")
                                        else main), name
        assert all(len(c) > 1000 for c in generated(doc, material).values()), name


def test_a_material_named_as_anothers_preview_keeps_its_name(tmp_path):
    """Materials take their names first: one named ``skin_preview`` beside ``skin`` (both
    with a preview and OpenPBR) is that material; skin's preview takes the next free name."""
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.io.mtlx_networks import document_text, library
    from bdipole_cl.io.networks import networks
    b = converted_material(tmp_path, ("preview", "openpbr"))
    written, why = networks(b, str(tmp_path))
    assert why == {}
    text = document_text([("skin", written, (), 0.01), ("skin_preview", written, (), 0.01)],
                         "test")
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    doc.importLibrary(library())
    assert doc.validate()[0]
    shaders = {m.getName(): mx.getShaderNodes(m)[0].getCategory()
               for m in doc.getMaterialNodes()}
    assert shaders == {"skin": "open_pbr_surface", "skin_preview": "open_pbr_surface",
                       "skin_preview2": "UsdPreviewSurface",
                       "skin_preview_preview": "UsdPreviewSurface"}


def test_the_cli_and_scene_files_choose_targets_in_one_vocabulary(tmp_path, capsys):
    from bdipole_cl.apps.cli import main as cli_main
    stage_path = write_stage(tmp_path)
    assert cli_main(["plan", str(stage_path), "--target", "PxrSurface"]) == 0
    out = capsys.readouterr().out
    assert "  targets: pxrsurface (bdipole.usda)" in out
    assert "target preview" not in out
    with pytest.raises(SystemExit) as exit_:
        cli_main(["plan", str(stage_path), "--target", "openpbr,standard_surface"])
    assert exit_.value.code == 2
    assert "both write the mtlx render context" in capsys.readouterr().err
    (tmp_path / "scene.toml").write_text('materials_from = "asset.usda"\n[[material]]\n'
                                         'name = "marble"\ntargets = ["usdpreviewsurface"]\n')
    materials = {m.name: m for m in scenes.load(tmp_path / "scene.toml").materials}
    assert materials["marble"].targets == ("preview",)
    assert materials["skin"].targets == ("preview",)                     # the default
    (tmp_path / "bad.toml").write_text('materials_from = "asset.usda"\n[[material]]\n'
                                       'name = "marble"\ntargets = ["arnold"]\n')
    with pytest.raises(scenes.SceneError, match=r"bad.toml:4: targets = .*\"preview\", "):
        scenes.load(tmp_path / "bad.toml")


def test_pxrsurface_of_an_extinction_material_reads_maps_that_invert_to_its_coefficients(
        tmp_path):
    """The skin (OpenPBR: its radius is 1/sigma_t') for PxrSurface: the bake writes its colour
    and diffuse mean free path in the Better Dipole's convention, and those maps, inverted as
    a diffuse mfp (a second, independent route through albedo_to_coefficients), give back
    the baked coefficients. The jade (constants) gets the same as numbers."""
    import bdipole_cl as bd
    _, stage = baked(tmp_path, targets="pxrsurface")
    skin = UsdShade.Material(stage.GetPrimAtPath("/Looks/skin"))
    surface = skin.ComputeSurfaceSource("ri")[0]
    assert surface.GetPath().name == "bdipole_pxrsurface"
    for name, layer in (("subsurfaceColor", "colour"), ("subsurfaceDmfpColor", "radius")):
        tex = UsdShade.Shader(surface.GetInput(name).GetConnectedSources()[0][0].source
                              .GetPrim())
        asset = tex.GetInput("filename").Get()
        assert asset.path == f"./skin.<UDIM>.better-dipole.{layer}.exr"
        assert tex.GetInput("firstChannel").Get() == 0      # a plain R, G, B file
    assert surface.GetInput("subsurfaceDmfp").Get() == pytest.approx(1.0)   # cm on a cm stage
    check_connections(skin)
    check_tiles(skin, 2)
    for tile in ("1001", "1002"):
        col, names = read(tmp_path / "bdipole" / f"skin.{tile}.better-dipole.colour.exr")
        radius, rnames = read(tmp_path / "bdipole" / f"skin.{tile}.better-dipole.radius.exr")
        coef, cnames = read(tmp_path / "bdipole" / f"skin.{tile}.exr")
        assert names == rnames == ["R", "G", "B"]
        sa, ss = bd.albedo_to_coefficients(col.astype(np.float64), radius.astype(np.float64),
                                           1.4, mfp_kind="diffuse", double=True)
        # two inversions at tol 1e-4 in rho (the bake's and this one), float32 maps
        np.testing.assert_allclose(sa, coef[..., :3], rtol=3e-4)
        np.testing.assert_allclose(ss, coef[..., 3:], rtol=3e-4)
    jade = UsdShade.Material(stage.GetPrimAtPath("/Looks/jade")).ComputeSurfaceSource("ri")[0]
    np.testing.assert_allclose(jade.GetInput("subsurfaceColor").Get(), (0.7, 0.5, 0.3),
                               rtol=1e-6)
    want = bd.albedo_to_coefficients((0.7, 0.5, 0.3), 0.5 * np.array([1, 0.6, 0.3]), 1.5,
                                     mfp_kind="extinction", double=True)
    back = bd.albedo_to_coefficients((0.7, 0.5, 0.3),
                                     np.asarray(jade.GetInput("subsurfaceDmfpColor").Get()),
                                     1.5, mfp_kind="diffuse", double=True)
    np.testing.assert_allclose(back, want, rtol=3e-4)


def converted_material(tmp_path, targets):
    """A BakedMaterial whose maps are given (the networks need no conversion to be built)."""
    from bdipole_cl.io.networks import BakedMaterial
    maps = {"van-de-hulst": {layer: f"./wax.<UDIM>.van-de-hulst.{layer}.exr"
                             for layer in ("colour", "radius")}}
    for tile in ("1001", "1002"):
        for layer in ("colour", "radius"):
            albedo_texture(tmp_path / f"wax.{tile}.van-de-hulst.{layer}.exr")
    return BakedMaterial("wax", str(tmp_path / "tex" / "wax.<UDIM>.exr"), "lin_rec709", (1.0,),
                         (1.0,), "diffuse", "better", (1.4,), "mm", 0.01, targets,
                         str(tmp_path / "wax.<UDIM>.exr"), ("sigma_a",),
                         {"sigma_a": ["sigma_a.R", "sigma_a.G", "sigma_a.B"]},
                         {"sigma_a": 0}, maps, "Linear Rec.709 (sRGB)")


@pytest.mark.parametrize("target, colour, radius", [
    ("openpbr", "subsurface_color", "subsurface_radius_scale"),
    ("standard-surface", "subsurface_color", "subsurface_radius")])
def test_openpbr_and_standard_surface_networks_read_the_converted_maps(tmp_path, target,
                                                                       colour, radius):
    """The MaterialX targets' networks (given maps: the conversion itself is conventions'):
    declared types, a colour map in its space and a radius map as data, the mm radius on a cm
    stage scaled by 0.1; the .mtlx validates and generates GLSL and OSL."""
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.io import usd_networks
    from bdipole_cl.io.mtlx_networks import document_text, library
    from bdipole_cl.io.networks import networks
    b = converted_material(tmp_path, (target,))
    written, why = networks(b, str(tmp_path))
    assert why == {} and [n.target.name for n in written] == [target]
    stage = Usd.Stage.CreateInMemory()
    UsdShade.Material.Define(stage, "/wax")
    usd_networks.author(stage, "/wax", written[0])
    material = UsdShade.Material(stage.GetPrimAtPath("/wax"))
    surface = material.ComputeSurfaceSource("mtlx")[0]
    assert surface.GetShaderId() == TARGET[target].shader_id
    check_connections(material)
    scale = [i for i in surface.GetInputs() if i.GetBaseName() in (
        "subsurface_radius", "subsurface_scale") and not i.HasConnectedSource()][0]
    assert scale.Get() == pytest.approx(0.1)                 # mm maps on a cm stage
    files = {}
    for name in (colour, radius):
        node = UsdShade.Shader(surface.GetInput(name).GetConnectedSources()[0][0].source
                               .GetPrim())
        files[name] = (node.GetInput("file").Get().path,
                       node.GetInput("file").GetAttr().GetColorSpace())
    assert files == {colour: ("./wax.<UDIM>.van-de-hulst.colour.exr", "lin_rec709_scene"),
                     radius: ("./wax.<UDIM>.van-de-hulst.radius.exr", "raw")}
    path = tmp_path / "wax.mtlx"
    path.write_text(document_text([("wax", written, (), 0.01)], "test"))
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(path))
    doc.importLibrary(library())
    ok, message = doc.validate()
    assert ok, message
    node = doc.getNode("wax")
    code = generated(doc, node)
    assert all(len(c) > 1000 for c in code.values())
    shader = mx.getShaderNodes(node)[0]
    image = shader.getInput(colour).getConnectedNode()
    assert image.getInput("file").getColorSpace() == "lin_rec709"
    assert image.getInputValue("file") == "./wax.<UDIM>.van-de-hulst.colour.exr"
    # the radius map is data: a vector3 image MaterialX never colour-converts
    data = shader.getInput(radius).getConnectedNode()
    data = data.getInput("in").getConnectedNode() if data.getCategory() == "convert" else data
    assert data.getType() == "vector3"
    assert data.getInputValue("file") == "./wax.<UDIM>.van-de-hulst.radius.exr"
    # the distance says its unit (the stage's, cm): a reader without one takes MaterialX's
    # default, metres (100x too large)
    distance = shader.getInput("subsurface_radius" if target == "openpbr" else
                               "subsurface_scale")
    assert (distance.getUnitType(), distance.getUnit()) == ("distance", "centimeter")
    assert distance.getValue() == pytest.approx(0.1)
    layer = Sdf.Layer.CreateNew(str(tmp_path / "wax.usda"))
    layer.TransferContent(stage.GetRootLayer())
    layer.Save()
    saved = Usd.Stage.Open(str(tmp_path / "wax.usda"))
    check_tiles(UsdShade.Material(saved.GetPrimAtPath("/wax")), 2)


def test_a_scene_file_with_targets_writes_its_materials_as_new_ones(tmp_path):
    """A TOML scene's materials (no prim of a stage): with targets, each is a Material of its
    own in the bake's layer (/bdipole_materials/{name}) and document, reading its files; a
    grey albedo's coefficients are one channel (ND_image_float); without targets, no layer."""
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.io.mtlx_networks import library
    from test_scene import SCENE, make_files
    make_files(tmp_path)
    text = SCENE.replace("METHOD", 'method = "table"')
    (tmp_path / "plain.toml").write_text(text)
    assert scenes.load(tmp_path / "plain.toml").plan().run().exit_code == 0
    assert not (tmp_path / "out" / "bdipole.usda").exists()
    (tmp_path / "scene.toml").write_text(text.replace(
        'mfp = [1.2, 0.6, 0.3]', 'mfp = [1.2, 0.6, 0.3]\ntargets = ["preview", "pxrsurface"]')
        .replace('mfp = 2.0', 'mfp = 2.0\ntargets = ["preview"]'))
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    stage = Usd.Stage.Open(str(tmp_path / "out" / "bdipole.usda"))
    # its materials' distances in mm, and the layer says so (USD's default would be cm)
    assert stage.GetRootLayer().pseudoRoot.GetInfo("metersPerUnit") == 1e-3
    skin = UsdShade.Material(stage.GetPrimAtPath("/bdipole_materials/skin"))
    assert skin and skin.ComputeSurfaceSource("ri")[0].GetShaderId() == "PxrSurface"
    pxr_surface = skin.ComputeSurfaceSource("ri")[0]
    # a scene file's mm on its own mm stage: the dmfp as given
    np.testing.assert_allclose(pxr_surface.GetInput("subsurfaceDmfpColor").Get(),
                               (1.2, 0.6, 0.3), rtol=1e-6)
    assert skin.ComputeSurfaceSource("")[0].GetShaderId() == "UsdPreviewSurface"
    check_connections(skin)
    check_tiles(skin, 2)
    grey = UsdShade.Material(stage.GetPrimAtPath("/bdipole_materials/grey"))
    check_tiles(grey, 1)
    graph = grey.GetPrim().GetChild("bdipole_coefficients")
    ids = sorted(UsdShade.Shader(p).GetShaderId() for p in graph.GetChildren())
    assert ids == ["ND_image_float", "ND_image_float"]
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(tmp_path / "out" / "bdipole.mtlx"))
    doc.importLibrary(library())
    assert doc.validate()[0]
    assert {m.getName() for m in doc.getMaterialNodes()} == {"skin", "grey"}


def test_maps_are_reported_once_and_rebuilt_only_when_their_coefficients_change(tmp_path):
    """Re-baking is idempotent (the same bytes, no row); a changed tile rebuilds its map only;
    a tile gone takes its map with it."""
    stage_path, _ = baked(tmp_path, targets="pxrsurface")
    folder = tmp_path / "bdipole"
    maps = sorted(p.name for p in folder.glob("*.better-dipole.*.exr"))
    assert maps == [f"skin.{t}.better-dipole.{layer}.exr" for t in ("1001", "1002")
                    for layer in ("colour", "radius")]
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    again = scenes.load(stage_path, targets="pxrsurface").plan().run()
    assert not [r for r in again.results if r.notes and r.notes[0] in ("maps", "records")]
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    albedo_texture(tmp_path / "tex" / "skin.1002.exr", 7)
    third = scenes.load(stage_path, targets="pxrsurface").plan().run()
    rows = [r.path for r in third.results if r.notes == ["maps"]]
    assert rows == [str(folder / f"skin.1002.better-dipole.{layer}.exr")
                    for layer in ("colour", "radius")], third.summary()
    (tmp_path / "tex" / "skin.1002.exr").unlink()
    fourth = scenes.load(stage_path, targets="pxrsurface").plan().run()
    assert not list(folder.glob("skin.1002.better-dipole.*")), fourth.summary()
    assert (folder / "skin.1001.better-dipole.colour.exr").exists()


def test_blenders_usd_importer_puts_the_textures_on_the_materials_inputs(tmp_path):
    """Blender's own USD importer (bpy, where installed) reads the bake's preview network:
    the painted albedo arrives on the Principled BSDF's Base Color through an Image Texture
    (a tiled image of both UDIM tiles for the skin)."""
    bpy = pytest.importorskip("bpy")
    stage_path, _ = baked(tmp_path, targets="preview")
    quad = ("point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]\n"
            "        int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n"
            "        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] "
            "(interpolation = \"vertex\")\n")
    root = tmp_path / "shot.usda"
    root.write_text("#usda 1.0\n(\n    subLayers = [@bdipole/bdipole.usda@, @asset.usda@]\n)\n"
                    "over \"World\"\n{\n" + "".join(
                        f"    over \"{g}\"\n    {{\n        {quad}    }}\n"
                        for g in ("head", "table")) + "}\n")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert "FINISHED" in bpy.ops.wm.usd_import(filepath=str(root))
    for name, tiles_wanted, file in (("skin", 2, "skin.<UDIM>.exr"),
                                     ("marble", 1, "marble.exr")):
        material = bpy.data.materials[name]
        bsdf = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        links = bsdf.inputs["Base Color"].links
        assert links and links[0].from_node.type == "TEX_IMAGE", name
        image = links[0].from_node.image
        assert image is not None and bpy.path.abspath(image.filepath).replace(
            "1001", "<UDIM>").endswith(file), (name, image.filepath)
        if tiles_wanted > 1:
            assert image.source == "TILED" and len(image.tiles) == tiles_wanted


def test_an_openpbr_stage_baked_reads_back_from_the_written_material_as_the_same_medium(
        tmp_path):
    """Round trip: the stage's OpenPBR skin (painted <UDIM> colour, an extinction radius)
    baked for PxrSurface; the stage with the bake's layer over it and the user's own OpenPBR
    surface disconnected, read by the library's own reader from the written material (its
    PxrSurface and PxrTexture maps), bakes the same coefficients."""
    import bdipole_cl as bd  # noqa: F401  (the device fixture's default)
    stage_path, _ = baked(tmp_path, targets="pxrsurface")
    root = tmp_path / "shot.usda"
    root.write_text('#usda 1.0\n(\n    subLayers = [@bdipole/bdipole.usda@, @asset.usda@]\n)\n'
                    'over "Looks"\n{\n    over "skin"\n    {\n'
                    '        token outputs:mtlx:surface.connect = None\n    }\n}\n')
    imports = {m.name: m for m in scenes.load(root).imports}
    skin = imports["skin"]
    assert skin.shader == "PxrSurface" and skin.mfp_kind == "diffuse", skin
    assert "better-dipole.colour.exr" in skin.inputs["subsurfaceColor"]
    assert "better-dipole.radius.exr" in skin.inputs["subsurfaceDmfpColor"]
    (tmp_path / "again.toml").write_text('materials_from = "shot.usda"\n[defaults]\n'
                                         'output = "again/{material}.<UDIM>.exr"\n'
                                         '[[material]]\nname = "marble"\n'
                                         'output = "again/marble.exr"\n')
    report = scenes.load(tmp_path / "again.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    for tile in ("1001", "1002"):
        first, names = read(tmp_path / "bdipole" / f"skin.{tile}.exr")
        second, names2 = read(tmp_path / "again" / f"skin.{tile}.exr")
        assert names == names2
        # two inversions at tol 1e-4 in rho and float32 maps between them
        np.testing.assert_allclose(second, first, rtol=3e-4)


def test_a_material_of_an_instanced_asset_gets_a_material_of_its_own(tmp_path):
    """USD ignores an over on an instance proxy: the networks of a material inside an instance
    are on its records prim, a Material (/bdipole_instanced/{name}) whose preview reads the
    asset's texture; its relationship names the material it stands for."""
    from test_usd_import_faults import material, new_stage, texture
    texture(tmp_path / "tex" / "skin.exr")
    asset = Usd.Stage.CreateNew(str(tmp_path / "char.usda"))
    material(asset, "skin", "tex/skin.exr")
    asset.SetDefaultPrim(asset.GetPrimAtPath("/Mat"))
    asset.GetRootLayer().Save()
    shot = new_stage(tmp_path)
    for k in range(2):
        prim = shot.DefinePrim(f"/set/char{k}")
        prim.GetReferences().AddReference("char.usda")
        prim.SetInstanceable(True)
    shot.GetRootLayer().Save()
    report = scenes.load(tmp_path / "asset.usda").plan().run()
    assert report.exit_code == 0, report.summary()
    stage = composed(tmp_path / "asset.usda", tmp_path / "bdipole" / "bdipole.usda")
    record = UsdShade.Material(stage.GetPrimAtPath("/bdipole_instanced/skin"))
    assert record, "the records prim is a Material"
    surface = record.ComputeSurfaceSource("")[0]
    assert surface.GetShaderId() == "UsdPreviewSurface"
    check_connections(record)
    check_tiles(record, 1)
    target, = record.GetPrim().GetRelationship("bdipole:material").GetTargets()
    assert stage.GetPrimAtPath(target).IsInstanceProxy()


def test_convert_writes_the_materials_of_its_outputs(tmp_path, capsys):
    """``bdipole-cl convert`` to a convention a render target reads (Jensen's dipole to the
    Better Dipole: PxrSurface): a Material per texture set reading the converted file's
    colour and radius, each from a file of its own (its first channels), every tile
    resolving, in a layer that states the run's unit; again: the same bytes."""
    from bdipole_cl.apps.cli import main as cli_main
    for k, tile in enumerate(("1001", "1002")):
        albedo_texture(tmp_path / "tex" / f"skin.{tile}.exr", k)
    args = ["convert", str(tmp_path / "tex" / "skin.<UDIM>.exr"), "--radius", "1.2,0.6,0.3",
            "--source", "dipole", "--target", "pxrsurface", "--eta", "1.4", "--unit", "cm"]
    assert cli_main(args) == 0, capsys.readouterr()
    layer = tmp_path / "tex" / "bdipole_convert.usda"
    stage = Usd.Stage.Open(str(layer))
    # the radius is in cm: a renderer reading the layer takes its metersPerUnit (USD's default
    # when none is authored is cm: a mm run read 10x too large)
    assert stage.GetRootLayer().pseudoRoot.GetInfo("metersPerUnit") == 0.01
    assert UsdGeom.GetStageUpAxis(stage) == "Y"
    skin = UsdShade.Material(stage.GetPrimAtPath("/bdipole_materials/skin"))
    surface = skin.ComputeSurfaceSource("ri")[0]
    assert surface.GetShaderId() == "PxrSurface"
    for name, layer_name in (("subsurfaceColor", "colour"), ("subsurfaceDmfpColor", "radius")):
        tex = UsdShade.Shader(surface.GetInput(name).GetConnectedSources()[0][0].source
                              .GetPrim())
        assert tex.GetInput("filename").Get().path == \
            f"./skin.<UDIM>.better-dipole.{layer_name}.exr"
        assert tex.GetInput("firstChannel").Get() == 0
        for tile in ("1001", "1002"):
            same_as_layer(tmp_path / "tex" / f"skin.{tile}.better-dipole.{layer_name}.exr",
                          tmp_path / "tex" / f"skin.{tile}.better-dipole.exr", layer_name)
    check_connections(skin)
    check_tiles(skin, 2)
    before = layer.read_bytes()
    assert cli_main(args) == 0
    assert layer.read_bytes() == before
    assert (tmp_path / "tex" / "bdipole_convert.mtlx").is_file()


def test_convert_runs_into_one_folder_share_its_materials(tmp_path, capsys):
    """A second ``convert`` into the folder (another set, in mm where the first was cm;
    another target for the first set) joins the earlier runs' materials: nothing is
    dropped (the second run rewrote the files with only its own). The layer keeps the first
    run's unit and the second's radius is scaled into it; the .mtlx validates, and its
    images read each layer's own file (what MaterialX's generators read)."""
    mx = pytest.importorskip("MaterialX")
    from bdipole_cl.apps.cli import main as cli_main
    from bdipole_cl.io.mtlx_networks import library
    for name, k in (("skin", 0), ("eyes", 1)):
        albedo_texture(tmp_path / f"{name}.exr", k)
    runs = [("skin", "openpbr", "cm"), ("eyes", "openpbr", "mm"), ("skin", "pxrsurface", "cm")]
    for name, target, unit in runs:
        assert cli_main(["convert", str(tmp_path / f"{name}.exr"), "--radius", "1",
                         "--target", target, "--unit", unit]) == 0, capsys.readouterr()
    stage = Usd.Stage.Open(str(tmp_path / "bdipole_convert.usda"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    skin = UsdShade.Material(stage.GetPrimAtPath("/bdipole_materials/skin"))
    eyes = UsdShade.Material(stage.GetPrimAtPath("/bdipole_materials/eyes"))
    assert skin.ComputeSurfaceSource("mtlx")[0].GetShaderId() == TARGET["openpbr"].shader_id
    assert skin.ComputeSurfaceSource("ri")[0].GetShaderId() == "PxrSurface"
    pbr = eyes.ComputeSurfaceSource("mtlx")[0]
    assert pbr.GetInput("subsurface_radius").Get() == pytest.approx(0.1)   # mm on a cm layer
    for material in (skin, eyes):
        check_connections(material)
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(tmp_path / "bdipole_convert.mtlx"))
    doc.importLibrary(library())
    ok, message = doc.validate()
    assert ok, message
    assert {m.getName() for m in doc.getMaterialNodes()} == {"skin", "eyes"}
    for name in ("skin", "eyes"):
        material = doc.getNode(name)
        assert all(len(c) > 1000 for c in generated(doc, material).values()), name
        shader = mx.getShaderNodes(material)[0]
        for inp, layer_name in (("subsurface_color", "colour"),
                                ("subsurface_radius_scale", "radius")):
            node = shader.getInput(inp).getConnectedNode()
            node = node.getInput("in").getConnectedNode() if node.getCategory() == "convert" \
                else node
            assert node.getInput("layer") is None
            assert node.getInputValue("file") == f"./{name}.van-de-hulst.{layer_name}.exr"
            same_as_layer(tmp_path / f"{name}.van-de-hulst.{layer_name}.exr",
                          tmp_path / f"{name}.van-de-hulst.exr", layer_name)


def test_every_targets_convention_is_one_of_the_conventions_registry():
    from bdipole_cl.physics.conventions import CONVENTION
    for target in TARGET:
        assert target.convention is None or target.convention in CONVENTION.names, target
        # a target's own name, where the conventions registry knows it, means the same
        if target.name in CONVENTION:
            assert CONVENTION.canonical(target.name) == target.convention, target


def test_a_layer_of_a_painted_texture_bakes_and_reads_back_from_the_written_network(
        tmp_path):
    """A PxrSurface whose colour is a MaterialX image of layer ``diffuse`` of an EXR that also
    has unlayered R, G, B: the bake reads that layer (it was refused with an oiiotool
    command, and the bake said "done"); the written PxrSurface reads it through PxrTexture's
    firstChannel, and the stage read back through that network bakes the same coefficients,
    bit for bit. UsdPreviewSurface's texture node reads a file's first channels: its preview
    is not written, and the plan and manifest say why."""
    from test_mtlx_scene import layered_exr
    layered_exr(tmp_path / "tex" / "wax.exr", {"": (0.2, 0.2, 0.2), "diffuse": (0.8, 0.6, 0.4)})
    stage = Usd.Stage.CreateNew(str(tmp_path / "wax.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    wax = UsdShade.Material.Define(stage, "/Looks/wax")
    s = shader(stage, wax, "/Looks/wax/pxr", "PxrSurface", "ri",
               {"subsurfaceGain": (F, 1.0), "subsurfaceDmfp": (F, 0.5),
                "subsurfaceDmfpColor": (C3, Gf.Vec3f(1, 0.5, 0.25)),
                "subsurfaceIor": (F, 1.4), "unitLength": (F, 1.0)})
    out = texture_node(stage, "/Looks/wax/img", "ND_image_color3", "tex/wax.exr", "out",
                       colorspace="lin_rec709")
    UsdShade.Shader(out.GetPrim()).CreateInput("layer", Sdf.ValueTypeNames.String).Set(
        "diffuse")
    s.CreateInput("subsurfaceColor", C3).ConnectToSource(out)
    stage.GetRootLayer().Save()
    report = scenes.load(tmp_path / "wax.usda", targets="preview,pxrsurface").plan().run()
    assert report.exit_code == 0, report.summary()
    px, names = read(tmp_path / "bdipole" / "wax.exr")
    want_a, _ = bd.albedo_to_coefficients(np.float32([0.8, 0.6, 0.4]),
                                          0.5 * np.float32([1, 0.5, 0.25]), 1.4)
    # the scene's accuracy contract: 1e-4 relative (tests/test_usd_scene.py TOL)
    np.testing.assert_allclose(px[..., :3], np.broadcast_to(want_a, (4, 4, 3)), rtol=1e-4)
    entry = json.loads((tmp_path / "bdipole" / "bdipole_materials.json").read_text())
    targets = entry["materials"][0]["targets"]
    assert targets["pxrsurface"] == "written" and "layer 'diffuse'" in targets["preview"]
    composed_stage = composed(tmp_path / "wax.usda", tmp_path / "bdipole" / "bdipole.usda")
    surface = UsdShade.Material(composed_stage.GetPrimAtPath("/Looks/wax")) \
        .ComputeSurfaceSource("ri")[0]
    tex = UsdShade.Shader(surface.GetInput("subsurfaceColor").GetConnectedSources()[0][0]
                          .source.GetPrim())
    assert tex.GetInput("firstChannel").Get() == 3
    over = tmp_path / "wax_baked.usda"
    over.write_text('#usda 1.0\n(\n    subLayers = [@bdipole/bdipole.usda@, @wax.usda@]\n)\n')
    (tmp_path / "again.toml").write_text('materials_from = "wax_baked.usda"\n[defaults]\n'
                                         'output = "again/{material}.exr"\n')
    again = scenes.load(tmp_path / "again.toml")
    assert {m.name: m.albedo_layer for m in again.materials} == {"wax": "diffuse"}
    assert again.plan().run().exit_code == 0
    np.testing.assert_array_equal(read(tmp_path / "again" / "wax.exr")[0], px)


@pytest.mark.parametrize("meters_per_unit, up_axis", [(0.01, "Y"), (1.0, "Z")])
def test_the_records_layer_states_the_stages_unit_and_up_axis(tmp_path, meters_per_unit,
                                                               up_axis):
    """bdipole.usda states the metersPerUnit and upAxis its networks' distances are in (the
    stage's): a reader of the layer alone takes USD's defaults (cm, Y) otherwise."""
    stage_path = write_stage(tmp_path, meters_per_unit=meters_per_unit)
    stage = Usd.Stage.Open(str(stage_path))
    UsdGeom.SetStageUpAxis(stage, up_axis)
    stage.GetRootLayer().Save()
    assert scenes.load(stage_path, targets="pxrsurface").plan().run().exit_code == 0
    layer = Usd.Stage.Open(str(tmp_path / "bdipole" / "bdipole.usda"))
    assert UsdGeom.GetStageMetersPerUnit(layer) == meters_per_unit
    assert UsdGeom.GetStageUpAxis(layer) == up_axis
    assert layer.GetRootLayer().pseudoRoot.HasInfo("metersPerUnit")
