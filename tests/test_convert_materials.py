"""The files a ``convert`` or a bake writes for its materials to read (jobs/convert_materials.py,
layer_files.py, scene_maps.py), checked as their consumers read them: every converted file's
material in the folder its output is in, whatever named it (paths in several folders, a glob
the shell did not expand); records matched with the layer's prims; an unwritten material a
failed row; each file a network reads a texture when the run's outputs are, and a file of
numbers that are not colour declared as data (OpenColorIO's data space), shown as stored."""
import numpy as np
import OpenImageIO as oiio
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdShade  # noqa: E402

from bdipole_cl.apps.cli import main  # noqa: E402


def _write(path, pixels):
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], "float")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.ascontiguousarray(pixels, np.float32))
    out.close()


def _colour(path, seed, size=9):
    path.parent.mkdir(parents=True, exist_ok=True)
    _write(path, np.random.default_rng(seed).uniform(0.05, 0.9, (size, size, 3)))


def _materials(folder) -> set:
    stage = Usd.Stage.Open(str(folder / "bdipole_convert.usda"))
    return {p.GetName() for p in stage.GetPrimAtPath("/bdipole_materials").GetChildren()
            if UsdShade.Material(p)}


def test_inputs_in_two_folders_each_get_their_material(tmp_path, capsys):
    # the second folder got its converted file but no layer files and no material, "ok"
    _colour(tmp_path / "d1" / "a.exr", 1)
    _colour(tmp_path / "d2" / "b.exr", 2)
    rc = main(["convert", str(tmp_path / "d1" / "a.exr"), str(tmp_path / "d2" / "b.exr"),
               "--radius", "1", "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    for folder, name in (("d1", "a"), ("d2", "b")):
        assert _materials(tmp_path / folder) == {name}, folder
        for layer in ("colour", "radius"):
            assert (tmp_path / folder / f"{name}.van-de-hulst.{layer}.exr").is_file()


def test_a_glob_the_shell_did_not_expand_writes_the_material_of_each_file(tmp_path, capsys):
    # the output was named from the glob's text (a*.van-de-hulst.exr): no file, no material,
    # an empty layer; a later run into the folder added no network
    for name, seed in (("a", 1), ("b", 2)):
        _colour(tmp_path / f"{name}.exr", seed)
    rc = main(["convert", str(tmp_path / "a*.exr"), str(tmp_path / "b*.exr"), "--radius", "1",
               "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    assert _materials(tmp_path) == {"a", "b"}
    rc = main(["convert", str(tmp_path / "*.exr"), "--radius", "1", "--source", "openpbr",
               "--target", "pxrsurface"])
    assert rc == 0, capsys.readouterr()
    stage = Usd.Stage.Open(str(tmp_path / "bdipole_convert.usda"))
    for name in ("a", "b"):
        material = UsdShade.Material(stage.GetPrimAtPath(f"/bdipole_materials/{name}"))
        assert material.ComputeSurfaceSource("ri")[0].GetShaderId() == "PxrSurface", name
        assert material.ComputeSurfaceSource("mtlx")[0], name


def test_a_set_whose_name_is_no_identifier_is_kept_without_a_warning(tmp_path, capsys):
    # skin.b's prim is skin_b; its record was keyed skin.b, so every later run said it was
    # "not kept" (it was)
    _colour(tmp_path / "skin.b.exr", 1)
    _colour(tmp_path / "other.exr", 2)
    for name in ("skin.b", "other"):
        rc = main(["convert", str(tmp_path / f"{name}.exr"), "--radius", "1",
                   "--target", "openpbr"])
        out = capsys.readouterr().out
        assert rc == 0 and "not kept" not in out, out
    assert _materials(tmp_path) == {"skin_b", "other"}


def test_a_material_not_written_is_a_failed_row(tmp_path, capsys):
    # a user's file where a layer file goes: kept, and the material not written is a
    # failure (it was "ok ... no material", exit 0)
    _colour(tmp_path / "a.exr", 1)
    _colour(tmp_path / "a.van-de-hulst.colour.exr", 2)
    before = (tmp_path / "a.van-de-hulst.colour.exr").read_bytes()
    rc = main(["convert", str(tmp_path / "a.exr"), "--radius", "1", "--target", "openpbr"])
    out = capsys.readouterr().out
    assert rc == 1 and "a: no material:" in out and "1 done, 0 failed" in out \
        and "1 failed beside them" in out, out
    assert (tmp_path / "a.van-de-hulst.colour.exr").read_bytes() == before


def test_the_summary_counts_the_converted_files_apart_from_the_files_beside_them(tmp_path,
                                                                                capsys):
    # "5 done" for one converted file: its two layer files and two materials files counted
    _colour(tmp_path / "a.exr", 1)
    assert main(["convert", str(tmp_path / "a.exr"), "--radius", "1", "--target",
                 "openpbr"]) == 0
    out = capsys.readouterr().out
    assert "1 done, 0 failed, 0 skipped; 4 files beside them" in out, out


def _spec(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    levels = 1
    while inp.seek_subimage(0, levels):
        levels += 1
    inp.close()
    return spec, levels


def _read_files(mtlx_path) -> list:
    """The files a MaterialX document's image nodes read, as paths."""
    mx = pytest.importorskip("MaterialX")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(mtlx_path))
    files = {n.getInputValue("file") for n in doc.traverseTree()
             if isinstance(n, mx.Node) and n.getInput("file") is not None}
    return sorted(mtlx_path.parent / f for f in files)


def _check_read_files(mtlx_path, want):
    """Every file the document reads is a tiled, mip-mapped texture; colour is tagged with
    the working space, every other layer as data (the radius in [0.039, 3.49] was shown as
    colour -2.26 .. 5.81: ACEScg converted)."""
    files = _read_files(mtlx_path)
    assert len(files) == want, files
    for f in files:
        spec, levels = _spec(str(f).replace("<UDIM>", "1001"))
        assert spec.tile_width == 64 and levels > 1, (f, spec.tile_width, levels)
        data = not str(f).endswith(".colour.exr")
        space = spec.get_string_attribute("colorInteropID")
        assert (space == "data") if data else (space == "lin_ap1_scene"), (f, space)


def test_every_file_a_converted_material_reads_is_a_texture_and_data_is_data(tmp_path,
                                                                              capsys):
    _colour(tmp_path / "a.exr", 1, 65)
    rc = main(["convert", str(tmp_path / "a.exr"), "--radius", "1", "--target", "openpbr",
               "--half", "--texture", "--working-space", "ACEScg"])
    assert rc == 0, capsys.readouterr()
    _check_read_files(tmp_path / "bdipole_convert.mtlx", 2)
    # a preview shows a data file as stored (its caption's range is the file's)
    capsys.readouterr()
    assert main(["preview", str(tmp_path / "a.van-de-hulst.radius.exr")]) == 0
    out = capsys.readouterr().out
    px = oiio.ImageBuf(str(tmp_path / "a.van-de-hulst.radius.exr")).get_pixels(oiio.FLOAT)
    assert f"radius: R, G, B  {px.min():.4g} .. {px.max():.4g}" in out, (out, px.min())


@pytest.mark.usefixtures("on_device")
def test_every_file_a_baked_material_reads_is_a_texture_and_data_is_data(tmp_path):
    from bdipole_cl import scene as scenes
    from test_scene import SCENE, make_files
    make_files(tmp_path, ("1001",))
    text = SCENE.split("[[material]]\nname = \"grey\"")[0].replace("METHOD", "") \
        .replace('mfp = [1.2, 0.6, 0.3]', 'mfp = [1.2, 0.6, 0.3]\ntargets = ["openpbr"]\n'
                 'texture = true\nworking_space = "ACEScg"')
    (tmp_path / "scene.toml").write_text(text)
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    # the coefficients' own files (sigma_a, sigma_s) and the OpenPBR maps (colour, radius)
    _check_read_files(tmp_path / "out" / "bdipole.mtlx", 4)


@pytest.mark.usefixtures("on_device")
def test_a_bake_reads_converts_mtlx_back_in_its_unit(tmp_path, capsys):
    # the .mtlx stated no unit for its distance (a reader takes MaterialX's metres: a cm run
    # 100x off) and the bake refused its radius image's vector3 -> color3 cast as "a
    # procedural network"
    _colour(tmp_path / "skin.exr", 1)
    assert main(["convert", str(tmp_path / "skin.exr"), "--radius", "1.2,0.6,0.3",
                 "--source", "pxrsurface", "--target", "openpbr", "--unit", "cm"]) == 0
    rc = main(["bake", str(tmp_path / "bdipole_convert.mtlx"), "--device", "intel",
               "--no-progress"])
    assert rc == 0, capsys.readouterr()
    coef = oiio.ImageBuf(str(tmp_path / "bdipole" / "skin.exr")).get_pixels(oiio.FLOAT)
    radius = oiio.ImageBuf(str(tmp_path / "skin.van-de-hulst.radius.exr")).get_pixels(
        oiio.FLOAT)
    # OpenPBR's radius is the medium's mean free path: sigma_a + sigma_s = 1 / (radius in m),
    # the coefficients in 1/m (the document's unit); float32 sum and product, 4 u = 4.8e-7
    np.testing.assert_allclose((coef[..., :3] + coef[..., 3:]) * radius * 0.01, 1.0,
                               rtol=4.8e-7)


#: the wrap a file declares (OpenImageIO's wrapmodes) as MaterialX's image address mode
_ADDRESS = {"clamp": "clamp", "black": "constant", "periodic": "periodic", "mirror": "mirror"}


def _declared_address(path) -> str:
    """The address mode the file's header declares (clamp where it declares none)."""
    spec, _ = _spec(str(path).replace("<UDIM>", "1001"))
    wrap = spec.get_string_attribute("wrapmodes") or "clamp,clamp"
    u, v = wrap.split(",")
    assert u == v, wrap
    return _ADDRESS[u]


def _check_address_modes(folder, mtlx_name, usda_name, want):
    """Every image node of the .mtlx and every ND_image_* shader of the .usda reads its file
    with the file's own wrap in u and v (MaterialX's default is periodic: a tile's edge
    sampled across it)."""
    mx = pytest.importorskip("MaterialX")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(folder / mtlx_name))
    images = [n for n in doc.traverseTree() if isinstance(n, mx.Node)
              and n.getCategory() == "image"]
    assert images
    for node in images:
        mode = _declared_address(folder / node.getInputValue("file"))
        assert mode == want
        for axis in ("uaddressmode", "vaddressmode"):
            assert node.getInputValue(axis) == mode, (node.getName(), axis)
    stage = Usd.Stage.Open(str(folder / usda_name))
    shaders = [UsdShade.Shader(p) for p in stage.Traverse() if UsdShade.Shader(p)
               and str(UsdShade.Shader(p).GetIdAttr().Get()).startswith("ND_image_")]
    assert shaders
    for shader in shaders:
        file = shader.GetInput("file").Get().path
        mode = _declared_address(folder / file)
        for axis in ("uaddressmode", "vaddressmode"):
            assert shader.GetInput(axis).Get() == mode, (shader.GetPath(), axis)


@pytest.mark.parametrize("options, want", [((), "clamp"), (("--texture",), "clamp"),
                                           (("--texture-wrap", "mirror"), "mirror"),
                                           (("--texture-wrap", "black"), "constant")])
def test_converted_materials_read_each_file_with_its_declared_wrap(tmp_path, capsys, options,
                                                                   want):
    # no image node set an address mode: MaterialX's default, periodic, read across the
    # edge of textures that declare clamp (or mirror)
    _colour(tmp_path / "a.exr", 1)
    rc = main(["convert", str(tmp_path / "a.exr"), "--radius", "1", "--target", "openpbr",
               *options])
    assert rc == 0, capsys.readouterr()
    _check_address_modes(tmp_path, "bdipole_convert.mtlx", "bdipole_convert.usda", want)


@pytest.mark.usefixtures("on_device")
def test_baked_materials_read_each_file_with_its_declared_wrap(tmp_path):
    from bdipole_cl import scene as scenes
    from test_scene import SCENE, make_files
    make_files(tmp_path, ("1001",))
    text = SCENE.split("[[material]]\nname = \"grey\"")[0].replace("METHOD", "") \
        .replace('mfp = [1.2, 0.6, 0.3]', 'mfp = [1.2, 0.6, 0.3]\ntargets = ["openpbr"]\n'
                 'texture_wrap = "mirror"')
    (tmp_path / "scene.toml").write_text(text)
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    _check_address_modes(tmp_path / "out", "bdipole.mtlx", "bdipole.usda", "mirror")


def _mtlx_materials(folder) -> set:
    mx = pytest.importorskip("MaterialX")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(folder / "bdipole_convert.mtlx"))
    return {m.getName() for m in doc.getMaterialNodes()}


def _reads(folder) -> dict:
    """{material: the colour file its OpenPBR network reads} of the .usda."""
    stage = Usd.Stage.Open(str(folder / "bdipole_convert.usda"))
    out = {}
    for prim in stage.GetPrimAtPath("/bdipole_materials").GetChildren():
        tex = stage.GetPrimAtPath(prim.GetPath().AppendPath(
            "bdipole_openpbr_colour"))
        out[prim.GetName()] = UsdShade.Shader(tex).GetInput("file").Get().path
    return out


def test_a_material_keeps_its_name_when_another_set_of_that_name_comes(tmp_path, capsys):
    # skin_b read "skin b"'s files after the second run (the first set moved to skin_b_2):
    # a binding to skin_b rendered another texture set, exit 0
    _colour(tmp_path / "skin.b.exr", 1)
    _colour(tmp_path / "skin b.exr", 2)
    _colour(tmp_path / "skin_b.exr", 3)
    for name in ("skin.b.exr", "skin b.exr", "skin_b.exr"):
        rc = main(["convert", str(tmp_path / name), "--radius", "1", "--target", "openpbr"])
        assert rc == 0, capsys.readouterr()
    assert _reads(tmp_path) == {"skin_b": "./skin.b.van-de-hulst.colour.exr",
                                "skin_b_2": "./skin b.van-de-hulst.colour.exr",
                                "skin_b_3": "./skin_b.van-de-hulst.colour.exr"}
    # a set converted again keeps its own
    rc = main(["convert", str(tmp_path / "skin b.exr"), "--radius", "2", "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    assert _reads(tmp_path)["skin_b_2"] == "./skin b.van-de-hulst.colour.exr"


@pytest.mark.parametrize("stem, ident", [("1skin", "_1skin"), ("peau_é", "peau__"),
                                         ("皮膚", "__")])
def test_usd_and_materialx_name_a_material_alike(tmp_path, capsys, stem, ident):
    # 1skin was _skin in the .usda (its digit lost), _1skin in the .mtlx; peau_é peau___ and
    # peau__ (USD replaced each byte of é)
    _colour(tmp_path / f"{stem}.exr", 1)
    rc = main(["convert", str(tmp_path / f"{stem}.exr"), "--radius", "1", "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    assert _materials(tmp_path) == _mtlx_materials(tmp_path) == {ident}


@pytest.mark.parametrize("order", [("skin.<UDIM>.exr", "skin.exr"),
                                   ("skin.exr", "skin.<UDIM>.exr")])
@pytest.mark.parametrize("runs", [1, 2])
def test_a_tile_set_and_a_texture_of_one_stem_each_keep_their_material(tmp_path, capsys,
                                                                       order, runs):
    # one material, skin, read skin.van-de-hulst.*; the tile set's was dropped, "2 done"
    _colour(tmp_path / "skin.1001.exr", 1)
    _colour(tmp_path / "skin.exr", 2)
    names = [[str(tmp_path / n) for n in order]] if runs == 1 else \
        [[str(tmp_path / n)] for n in order]
    for run in names:
        rc = main(["convert", *run, "--radius", "1", "--target", "openpbr"])
        assert rc == 0, capsys.readouterr()
    reads = _reads(tmp_path)
    assert sorted(reads.values()) == ["./skin.<UDIM>.van-de-hulst.colour.exr",
                                      "./skin.van-de-hulst.colour.exr"], reads
    assert set(reads) == {"skin", "skin_2"} == _mtlx_materials(tmp_path)


@pytest.mark.usefixtures("on_device")
def test_a_bakes_usda_and_mtlx_name_a_material_alike(tmp_path):
    # a scene file's 1skin was the .usda's _skin (its digit lost) and the .mtlx's _1skin
    from bdipole_cl import scene as scenes
    from test_scene import SCENE, make_files
    make_files(tmp_path, ("1001",))
    text = SCENE.split("[[material]]\nname = \"grey\"")[0].replace("METHOD", "") \
        .replace('name = "skin"', 'name = "1skin"') \
        .replace('mfp = [1.2, 0.6, 0.3]', 'mfp = [1.2, 0.6, 0.3]\ntargets = ["openpbr"]')
    (tmp_path / "scene.toml").write_text(text)
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 0, report.summary()
    mx = pytest.importorskip("MaterialX")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(tmp_path / "out" / "bdipole.mtlx"))
    stage = Usd.Stage.Open(str(tmp_path / "out" / "bdipole.usda"))
    prims = {p.GetName() for p in stage.Traverse() if UsdShade.Material(p)}
    assert prims == {m.getName() for m in doc.getMaterialNodes()} == {"_1skin"}


def _network_files(folder) -> dict:
    """{shader prim path: the file it reads} of every texture node of the .usda."""
    stage = Usd.Stage.Open(str(folder / "bdipole_convert.usda"))
    out = {}
    for prim in stage.Traverse():
        shader = UsdShade.Shader(prim)
        for name in ("file", "filename"):
            if shader and shader.GetInput(name):
                out[str(prim.GetPath())] = shader.GetInput(name).Get().path
    return out


def test_a_kept_network_never_reads_files_another_convention_rewrote(tmp_path, capsys):
    # both runs wrote outs/s.colour.exr: the OpenPBR network kept from the first read the
    # second's better-dipole colour and radius, exit 0
    import hashlib
    _colour(tmp_path / "in1" / "s.exr", 1)
    out = str(tmp_path / "outs" / "{stem}.exr")
    assert main(["convert", str(tmp_path / "in1" / "s.exr"), "--radius", "1", "--target",
                 "openpbr", "-o", out]) == 0, capsys.readouterr()
    reads = _network_files(tmp_path / "outs")
    digest = {f: hashlib.md5((tmp_path / "outs" / f).read_bytes()).hexdigest()
              for f in reads.values()}
    assert main(["convert", str(tmp_path / "in1" / "s.exr"), "--radius", "1", "--source",
                 "openpbr", "--target", "pxrsurface", "-o", out]) == 0, capsys.readouterr()
    after = _network_files(tmp_path / "outs")
    assert {k: v for k, v in after.items() if "openpbr" in k} == reads
    for f, d in digest.items():
        assert hashlib.md5((tmp_path / "outs" / f).read_bytes()).hexdigest() == d, f
    pxr_files = {v for k, v in after.items() if "pxrsurface" in k}
    assert pxr_files and not pxr_files & set(reads.values()), (pxr_files, reads)


def test_a_layer_file_never_overwrites_an_input_of_the_run(tmp_path, capsys):
    import hashlib
    _colour(tmp_path / "a.exr", 1)
    _colour(tmp_path / "a.van-de-hulst.colour.exr", 2)
    before = hashlib.md5((tmp_path / "a.van-de-hulst.colour.exr").read_bytes()).hexdigest()
    rc = main(["convert", str(tmp_path / "a.exr"), str(tmp_path / "a.van-de-hulst.colour.exr"),
               "--radius", "1", "--target", "openpbr"])
    out = capsys.readouterr().out
    assert rc == 1 and "would overwrite an input of this run" in out, out
    after = hashlib.md5((tmp_path / "a.van-de-hulst.colour.exr").read_bytes()).hexdigest()
    assert after == before


def test_inputs_of_one_name_in_two_folders_are_told_to_use_dir(tmp_path, capsys):
    # the advice was "put <UDIM>, {udim}, {stem} or {name} in -o" to an -o with {stem}
    _colour(tmp_path / "in1" / "s.exr", 1)
    _colour(tmp_path / "in2" / "s.exr", 2)
    rc = main(["convert", str(tmp_path / "in1" / "s.exr"), str(tmp_path / "in2" / "s.exr"),
               "--radius", "1", "--target", "openpbr", "-o",
               str(tmp_path / "outs" / "{stem}.exr")])
    out = "".join(capsys.readouterr())
    assert rc != 0 and "put {dir} (the inputs share their file name" in out, out


@pytest.mark.parametrize("command", [["convert", "--radius", "1"], ["invert", "--mfp", "1"]])
def test_an_unknown_field_in_o_is_a_usage_error(tmp_path, capsys, command):
    # convert -o '{bogus}/x.exr' made a folder named {bogus}, exit 0
    _colour(tmp_path / "a.exr", 1)
    with pytest.raises(SystemExit) as exit_:     # argparse's usage error
        main([command[0], str(tmp_path / "a.exr"), *command[1:], "-o",
              str(tmp_path / "{bogus}" / "x.exr")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "{bogus} is no field" in err, err
    assert not (tmp_path / "{bogus}").exists()


def test_a_file_beside_the_outputs_that_failed_is_counted_apart_from_the_jobs(tmp_path,
                                                                             capsys):
    # "1 done, 1 failed" for one input when only bdipole_convert.mtlx failed, and the note
    # named maps and records, which convert never writes
    _colour(tmp_path / "a.exr", 1)
    (tmp_path / "bdipole_convert.mtlx").write_text("<materialx/>\n")
    rc = main(["convert", str(tmp_path / "a.exr"), "--radius", "1", "--target", "openpbr"])
    out = capsys.readouterr().out
    assert rc == 1, out
    assert out.rstrip().endswith("1 done, 0 failed, 0 skipped; 3 files beside them (layer "
                                 "file, materials); 1 failed beside them"), out


def test_a_material_whose_files_are_gone_is_dropped_and_said(tmp_path, capsys):
    # the s material was kept pointing at the deleted files, no message
    _colour(tmp_path / "s.exr", 1)
    _colour(tmp_path / "t.exr", 2)
    assert main(["convert", str(tmp_path / "s.exr"), "--radius", "1", "--target",
                 "openpbr"]) == 0, capsys.readouterr()
    for f in tmp_path.glob("s.van-de-hulst.*"):
        f.unlink()
    capsys.readouterr()
    assert main(["convert", str(tmp_path / "t.exr"), "--radius", "1", "--target",
                 "openpbr"]) == 0
    out = capsys.readouterr().out
    assert "s (openpbr: ./s.van-de-hulst.colour.exr, ./s.van-de-hulst.radius.exr gone): " \
           "not kept" in out, out
    assert _materials(tmp_path) == _mtlx_materials(tmp_path) == {"t"}


def test_a_material_of_a_layer_without_sources_keeps_its_name(tmp_path, capsys):
    # a layer written before the sources were kept names its prims as USD's
    # TfMakeValidIdentifier did (1skin: _skin): they stay as they were, none "not kept"
    import json
    from pxr import Sdf
    _colour(tmp_path / "1skin.exr", 1)
    _colour(tmp_path / "t.exr", 2)
    assert main(["convert", str(tmp_path / "1skin.exr"), "--radius", "1", "--target",
                 "openpbr"]) == 0, capsys.readouterr()
    path = str(tmp_path / "bdipole_convert.usda")
    layer = Sdf.Layer.FindOrOpen(path)
    data = dict(layer.customLayerData)
    data.pop("bdipole_convert_sources")
    records = json.loads(data["bdipole_convert"])
    data["bdipole_convert"] = json.dumps({"1skin": records["_1skin"]})
    layer.customLayerData = data
    layer.GetPrimAtPath("/bdipole_materials/_1skin").name = "_skin"
    layer.Save()
    del layer                        # out of USD's layer registry: the stage reads the file
    capsys.readouterr()
    assert main(["convert", str(tmp_path / "t.exr"), "--radius", "1", "--target",
                 "openpbr"]) == 0
    out = capsys.readouterr().out
    assert "not kept" not in out, out
    assert _materials(tmp_path) == _mtlx_materials(tmp_path) == {"_skin", "t"}

