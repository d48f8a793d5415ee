"""Stretch in scenes (bdipole_cl/io/mesh_sets.py, scene_keys.py, jobs/scene_stretch.py,
stretch_file.py; docs/scenes.md "Stretch"): a blur of a stage's material bound to a mesh
computes its stretch maps from that mesh, records them and blurs with them, on every path
(the Python API, the CLI's plan and bake; Dask in tests/test_dask.py); which meshes a
material is bound to (direct, collection and GeomSubset bindings, instances); meshes that
share a tile; the scene file's keys and their one-line errors; up to date and changed
meshes; what the records say, read back through USD and OpenImageIO."""
import json

import numpy as np
import OpenImageIO as oiio
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt  # noqa: E402

import bdipole_cl as bd  # noqa: E402
from bdipole_cl import scene as scenes  # noqa: E402
from bdipole_cl.apps.cli import main as cli_main  # noqa: E402
from bdipole_cl.io.mesh_sets import bound_prims, read_mesh_set  # noqa: E402
from bdipole_cl.io.stretch_maps import read_stretch, stretch_maps  # noqa: E402
from bdipole_cl.ops.stretch import StretchError, stretch_tiles  # noqa: E402
from stretch_meshes import cylinder_lengths  # noqa: E402
from stretch_scenes import DMFP, SIZE, albedo, bind_material, irradiance, stretch_scene  # noqa: E402,E501

pytestmark = pytest.mark.usefixtures("on_device")

UDIMS = (1001, 1002)


def read_exr(path):
    """(pixels, channel names, spec) as OpenImageIO reads the file."""
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        return inp.read_image("float"), list(inp.spec().channelnames), inp.spec()
    finally:
        inp.close()


def expected_blur(udim, stretch_file, charts="clamp"):
    """The scene blur's exitance computed apart: ``bd.blur`` of the tile's irradiance with the
    material's albedo texture, its dmfp and eta and the stretch maps read back."""
    return bd.blur(irradiance(udim), albedo=albedo(udim), mfp=DMFP, eta=1.4,
                   stretch=read_stretch(stretch_file), charts=charts)


def check_maps_equal(made, want_stage, udim):
    """A stretch map file the bake made equals ``bdipole-cl stretch``'s (``stretch_maps``) of
    the stage, channel by channel, bit for bit: both rasterize the same triangles."""
    px, names, spec = read_exr(made)
    assert sorted(names) == ["chart", "stretch.u", "stretch.v"], names
    assert spec.get_string_attribute("bdipole:stretch_unit") == "mm"
    tile = next(t for t, _ in stretch_maps(want_stage, size=SIZE, unit="mm") if t.udim == udim)
    np.testing.assert_array_equal(px[..., names.index("stretch.u")], tile.su, str(made))
    np.testing.assert_array_equal(px[..., names.index("stretch.v")], tile.sv, str(made))


@pytest.fixture
def bound_scene(tmp_path):
    return stretch_scene(tmp_path / "s")


def test_a_bound_mesh_gives_the_blur_its_stretch_through_the_api(bound_scene):
    """plan().run(): one stretch job per irradiance tile before its blur; the maps equal the
    stage's as ``bdipole-cl stretch`` makes them (the cylinder's two charts, 1:2 along u:
    tests/test_stretch.py checks those against the analytic lengths); each tile's exitance is
    ``bd.blur`` with those maps; a second plan has nothing to do."""
    root = bound_scene.parent
    plan = scenes.load(bound_scene).plan()
    kinds = [(j.kind, j.udim) for j in plan.jobs if j.kind in ("stretch", "blur")]
    assert kinds == [("stretch", "1001"), ("blur", "1001"), ("stretch", "1002"),
                     ("blur", "1002")], kinds
    text = plan.describe()
    assert "stretch maps of UDIM 1001 at 64x64 texels from the mesh(es) bound to " \
           "/Looks/skin: /cyl" in text, text
    assert "in surface distance with the stretch maps" in text, text
    report = plan.run()
    assert report.exit_code == 0, report.summary()
    for k, udim in enumerate(UDIMS):
        made = root / "out" / f"skin_sss.{udim}.stretch.exr"
        check_maps_equal(made, root / "asset.usda", udim)
        s = read_stretch(made)
        su, sv = cylinder_lengths(size=SIZE)[k]
        assert np.allclose(s.su[s.covered], su, rtol=1e-5), (udim, su)
        got, names, spec = read_exr(root / "out" / f"skin_sss.{udim}.exr")
        assert spec.get_string_attribute("bdipole:texel_size") == "stretch map"
        assert spec.get_string_attribute("bdipole:stretch_unit") == "mm"
        want = expected_blur(udim, made)
        # the same plan, inputs and device: float32 round-off of the file's read and write
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * float(want.max()))
        assert got[..., 0].sum() > 0
    again = scenes.load(bound_scene).plan()
    assert all(j.up_to_date for j in again.jobs), again.describe()


def test_a_changed_mesh_rebakes_its_stretch_and_blurs_an_unchanged_one_does_not(bound_scene):
    """The maps' key is the bound meshes' geometry: another prim of the stage changed leaves
    every job up to date; the cylinder's points moved (radius x 1.5) remakes both tiles' maps
    and blurs, and the new maps are the new stage's."""
    root = bound_scene.parent
    assert scenes.load(bound_scene).plan().run().exit_code == 0
    stage = Usd.Stage.Open(str(root / "asset.usda"))
    UsdGeom.Xform.Define(stage, "/elsewhere").AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
    stage.GetRootLayer().Save()
    plan = scenes.load(bound_scene).plan()
    assert all(j.up_to_date for j in plan.jobs), plan.describe()
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/cyl")).GetPointsAttr()
    pts = np.array(points.Get())
    pts[:, :2] *= 1.5
    points.Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    stage.GetRootLayer().Save()
    plan = scenes.load(bound_scene).plan()
    todo = sorted((j.kind, j.udim) for j in plan.jobs if not j.up_to_date)
    assert todo == [("blur", "1001"), ("blur", "1002"), ("stretch", "1001"),
                    ("stretch", "1002")], plan.describe()
    assert plan.run().exit_code == 0
    for k, udim in enumerate(UDIMS):
        made = root / "out" / f"skin_sss.{udim}.stretch.exr"
        check_maps_equal(made, root / "asset.usda", udim)
        assert np.allclose(read_stretch(made).su[read_stretch(made).covered],
                           1.5 * cylinder_lengths(size=SIZE)[k][0], rtol=1e-5)
        got, _, _ = read_exr(root / "out" / f"skin_sss.{udim}.exr")
        np.testing.assert_allclose(got, expected_blur(udim, made), rtol=0,
                                   atol=1e-6 * float(got.max()))


def composed(stage_path, layer_path):
    """The stage with the bake's layer sublayered over it (docs/materials.md)."""
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths = [str(layer_path), str(stage_path)]
    return Usd.Stage.Open(root)


def test_the_records_list_the_stretch_maps_as_usd_and_oiio_read_them(bound_scene):
    """bdipole_materials.json: the blur's stretch under its material (pattern, files, prims,
    time code, unit, channels); bdipole.usda over the stage: bdipole:stretch:skin_tsd, a
    <UDIM> asset that UsdShade.UdimUtils resolves to both tiles, whose files OpenImageIO
    reads with the channels the record names, the unit, and a relationship to the mesh."""
    root = bound_scene.parent
    assert scenes.load(bound_scene).plan().run().exit_code == 0
    entry = next(e for e in json.loads((root / "out" / "bdipole_materials.json").read_text())
                 ["materials"] if e["name"] == "skin")
    record = entry["stretch"]["skin_tsd"]
    assert record["from"] == "bound" and record["prims"] == ["/cyl"], record
    assert record["maps"] == "./skin_sss.<UDIM>.stretch.exr" and record["unit"] == "mm"
    assert record["files"] == ["skin_sss.1001.stretch.exr", "skin_sss.1002.stretch.exr"]
    assert record["time_code"] == "earliest" and "errors" not in record
    stage = composed(root / "asset.usda", root / "out" / "bdipole.usda")
    prim = stage.GetPrimAtPath("/Looks/skin")
    asset = prim.GetAttribute("bdipole:stretch:skin_tsd").Get()
    assert UsdShade.UdimUtils.IsUdimIdentifier(asset.path), asset
    layer = prim.GetAttribute("bdipole:stretch:skin_tsd").GetPropertyStack(
        Usd.TimeCode.Default())[0].layer
    files = sorted(p for p, _ in UsdShade.UdimUtils.ResolveUdimTilePaths(asset.path, layer))
    assert [f.rsplit("/", 1)[-1] for f in files] == record["files"], files
    channels = list(prim.GetAttribute("bdipole:stretch:skin_tsd:channels").Get())
    for f in files:
        _, names, spec = read_exr(f)
        assert names == channels and spec.get_string_attribute("bdipole:stretch_unit") == \
            prim.GetAttribute("bdipole:stretch:skin_tsd:unit").Get() == "mm"
    rel = prim.GetRelationship("bdipole:stretch:skin_tsd:meshes")
    assert [str(p) for p in rel.GetTargets()] == ["/cyl"]
    assert stage.GetPrimAtPath("/cyl").IsA(UsdGeom.Mesh)
    # a tile gone: its maps, which the <UDIM> record would still give, are removed, said
    (root / "light" / "irr.1002.exr").unlink()
    report = scenes.load(bound_scene).plan().run()
    assert any(r.notes == ["removed"] and "skin_sss.1002.stretch.exr" in r.output
               for r in report.results), report.summary()
    assert not (root / "out" / "skin_sss.1002.stretch.exr").exists()
    stage = composed(root / "asset.usda", root / "out" / "bdipole.usda")
    attr = stage.GetPrimAtPath("/Looks/skin").GetAttribute("bdipole:stretch:skin_tsd")
    layer = attr.GetPropertyStack(Usd.TimeCode.Default())[0].layer
    assert [p.rsplit("/", 1)[-1] for p, _ in UsdShade.UdimUtils.ResolveUdimTilePaths(
        attr.Get().path, layer)] == ["skin_sss.1001.stretch.exr"]


def test_the_cli_plans_and_bakes_the_stretch(bound_scene, capsys):
    """``bdipole-cl plan`` names each tile's stretch job; ``bdipole-cl bake`` makes the maps
    and the blurs (exit 0); a second bake skips every job."""
    root = bound_scene.parent
    assert cli_main(["plan", str(bound_scene), "--device", "intel"]) == 0
    out = capsys.readouterr().out
    assert "stretch skin_tsd [1002]:" in out and "stretch maps of UDIM 1002" in out, out
    assert cli_main(["bake", str(bound_scene), "--device", "intel", "--no-progress"]) == 0
    out = capsys.readouterr().out
    for udim in UDIMS:
        check_maps_equal(root / "out" / f"skin_sss.{udim}.stretch.exr", root / "asset.usda",
                         udim)
        assert (root / "out" / f"skin_sss.{udim}.exr").is_file()
    assert cli_main(["bake", str(bound_scene), "--device", "intel", "--no-progress"]) == 0
    assert "6 skipped" in capsys.readouterr().out


def test_maps_that_cannot_be_made_fail_their_blur_named_and_the_others_bake(bound_scene):
    """The mesh changed between the plan and the bake: the stretch jobs fail (the geometry is
    not the plan's; nothing written), and each blur that reads their maps fails naming them,
    reading nothing; the inversions bake."""
    root = bound_scene.parent
    plan = scenes.load(bound_scene).plan()
    stage = Usd.Stage.Open(str(root / "asset.usda"))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/cyl")).GetPointsAttr()
    points.Set(Vt.Vec3fArray.FromNumpy(np.asarray(points.Get()) * np.float32(2)))
    stage.GetRootLayer().Save()
    report = plan.run()
    rows = {(r.path.split(":")[0], r.output.rsplit("/", 1)[-1]): r for r in report.results}
    for udim in UDIMS:
        made = rows[("skin_tsd", f"skin_sss.{udim}.stretch.exr")]
        assert made.status == "failed" and "differs from the plan's" in made.error, made
        blur = rows[("skin_tsd", f"skin_sss.{udim}.exr")]
        assert "its stretch maps" in blur.error and "were not made" in blur.error, blur
        assert not (root / "out" / f"skin_sss.{udim}.exr").exists()
        assert not (root / "out" / f"skin_sss.{udim}.stretch.exr").exists()
        assert rows[("skin", f"skin.{udim}.exr")].status == "ok"
    record = next(e for e in json.loads((root / "out" / "bdipole_materials.json").read_text())
                  ["materials"] if e["name"] == "skin")["stretch"]["skin_tsd"]
    assert record["files"] == [] and len(record["errors"]) == 2, record


# {{{ which meshes, and meshes that share a tile

def plane(stage, path, uv0, uv_size, size_m, subsets=None):
    """A 2 x 1 quad mesh at ``path``: world size ``size_m`` (x, y), texture coordinates the
    rectangle ``uv0`` + [0, uv_size], two faces (left, right half)."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    (w, h), (u0, v0), (du, dv) = size_m, uv0, uv_size
    xs = [0, w / 2, w]
    pts = [(x, y, 0) for y in (0, h) for x in xs]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr([4, 4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 4, 3, 1, 2, 5, 4])
    st = [(u0 + du * x / w, v0 + dv * y / h) for x, y, _ in pts]
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.vertex)
    pv.Set(Vt.Vec2fArray([Gf.Vec2f(*p) for p in st]))
    return mesh


def binding_stage(path):
    """A stage in metres: /Looks/skin and /Looks/other; /World/a bound to skin directly,
    /World/group/b by a collection binding on /World/group, /World/c bound to other with a
    GeomSubset (its right face) bound to skin, /World/d bound to other only."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    skin = UsdShade.Material.Define(stage, "/Looks/skin")
    other = UsdShade.Material.Define(stage, "/Looks/other")
    a = plane(stage, "/World/a", (0.05, 0.05), (0.4, 0.2), (0.04, 0.02))
    UsdShade.MaterialBindingAPI.Apply(a.GetPrim()).Bind(skin)
    group = UsdGeom.Xform.Define(stage, "/World/group").GetPrim()
    plane(stage, "/World/group/b", (0.55, 0.05), (0.4, 0.4), (0.02, 0.02))
    coll = Usd.CollectionAPI.Apply(group, "skinned")
    coll.CreateIncludesRel().AddTarget("/World/group/b")
    UsdShade.MaterialBindingAPI.Apply(group).Bind(coll, skin, "skinned")
    c = plane(stage, "/World/c", (0.05, 0.55), (0.4, 0.4), (0.08, 0.04))
    api = UsdShade.MaterialBindingAPI.Apply(c.GetPrim())
    api.Bind(other)
    subset = api.CreateMaterialBindSubset("right", Vt.IntArray([1]))
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(skin)
    d = plane(stage, "/World/d", (0.55, 0.55), (0.4, 0.4), (0.04, 0.04))
    UsdShade.MaterialBindingAPI.Apply(d.GetPrim()).Bind(other)
    stage.GetRootLayer().Save()
    return stage


def test_bound_meshes_follow_usds_computed_binding(tmp_path):
    """Direct, collection and GeomSubset bindings: the meshes (and faces) bound to skin are
    a, b and c's right face, not d; their maps are their analytic lengths (texel steps
    |dP/du| / W, |dP/dv| / H in mm), c's left half left to the gutters."""
    stage = binding_stage(tmp_path / "bind.usda")
    found = {str(p.GetPath()): f for p, f in bound_prims(stage, "/Looks/skin",
                                                          Usd.TimeCode.Default())}
    assert found == {"/World/a": None, "/World/group/b": None, "/World/c": (1,)}, found
    meshes = read_mesh_set(tmp_path / "bind.usda", "/Looks/skin")
    assert meshes.prims == ("/World/a", "/World/group/b", "/World/c")
    assert meshes.faces == (None, None, 1)
    (tile,) = stretch_tiles(meshes.meshes, 128, 1e-3, "mm")
    # each plane: (metres per unit u, per unit v) = (size_x / du, size_y / dv)
    for (u, v), (mx, my) in (((0.25, 0.15), (0.04 / 0.4, 0.02 / 0.2)),
                             ((0.75, 0.25), (0.02 / 0.4, 0.02 / 0.4)),
                             ((0.40, 0.75), (0.08 / 0.4, 0.04 / 0.4))):
        x, y = int(u * 128), int((1 - v) * 128)
        assert tile.covered[y, x], (u, v)
        np.testing.assert_allclose([tile.su[y, x], tile.sv[y, x]],
                                   [mx / 128 * 1e3, my / 128 * 1e3], rtol=1e-6)
    x, y = int(0.1 * 128), int((1 - 0.75) * 128)      # c's left face: other's, not covered
    assert not tile.covered[y, x]
    with pytest.raises(ValueError, match=r"bind.usda: no material at /Looks/none$"):
        read_mesh_set(tmp_path / "bind.usda", "/Looks/none")


def test_meshes_that_share_texels_agree_or_are_refused_naming_both(tmp_path):
    """Two meshes bound to one material whose UVs overlap: instances of one mesh placed
    rigidly (the same lengths) give one map, the same as either alone; a second mesh of
    another size over the same UVs is one line naming both prims and the texel."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "two.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    skin = UsdShade.Material.Define(stage, "/Looks/skin")
    proto = plane(stage, "/Proto/geo", (0.1, 0.1), (0.8, 0.4), (0.04, 0.02))
    UsdShade.MaterialBindingAPI.Apply(proto.GetPrim()).Bind(skin)
    stage.GetPrimAtPath("/Proto").SetSpecifier(Sdf.SpecifierClass)
    for k, name in enumerate(("left", "right")):
        inst = UsdGeom.Xform.Define(stage, f"/World/{name}")
        inst.AddRotateZOp().Set(90.0 * k)
        inst.AddTranslateOp().Set(Gf.Vec3d(5.0 * k, 0, 0))
        inst.GetPrim().GetReferences().AddInternalReference("/Proto")
        inst.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    both = read_mesh_set(tmp_path / "two.usda", "/Looks/skin")
    assert both.prims == ("/World/left/geo", "/World/right/geo"), both.prims
    (union,) = stretch_tiles(both.meshes, 64, 1e-3, "mm")
    (one,) = stretch_tiles(both.meshes[:1], 64, 1e-3, "mm")
    np.testing.assert_allclose(union.su, one.su, rtol=1e-6)
    np.testing.assert_allclose(union.sv, one.sv, rtol=1e-6)
    big = plane(stage, "/World/big", (0.1, 0.1), (0.8, 0.4), (0.08, 0.02))
    UsdShade.MaterialBindingAPI.Apply(big.GetPrim()).Bind(skin)
    stage.GetRootLayer().Save()
    meshes = read_mesh_set(tmp_path / "two.usda", "/Looks/skin")
    with pytest.raises(StretchError) as err:
        stretch_tiles(meshes.meshes, 64, 1e-3, "mm")
    text = str(err.value)
    assert "\n" not in text and "/World/left/geo and" in text and "/World/big" in text, text
    assert "UDIM 1001" in text and "one stretch map cannot hold both" in text, text

# }}}


# {{{ the scene file's stretch keys

def test_a_mesh_file_and_given_maps_in_another_unit(tmp_path):
    """stretch = a stage (every mesh of it) gives the bound mesh's maps, and charts = "zero"
    is the blur's; stretch = maps in cm (``bdipole-cl stretch --unit cm``) blurs as the same
    maps in mm: converted into the material's unit, not read as mm."""
    scene = stretch_scene(tmp_path / "f", stretch='"asset.usda"', extra='charts = "zero"')
    root = scene.parent
    assert scenes.load(scene).plan().run().exit_code == 0
    for udim in UDIMS:
        made = root / "out" / f"skin_sss.{udim}.stretch.exr"
        check_maps_equal(made, root / "asset.usda", udim)
        got, _, _ = read_exr(root / "out" / f"skin_sss.{udim}.exr")
        want = expected_blur(udim, made, "zero")
        assert np.abs(want - expected_blur(udim, made)).max() > 1e-3 * want.max()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * float(want.max()))
    stretch_maps(root / "asset.usda", str(root / "cm.<UDIM>.exr"), size=SIZE, unit="cm")
    given = stretch_scene(tmp_path / "g", stretch='"../f/cm.<UDIM>.exr"')
    plan = scenes.load(given).plan()
    assert not [j for j in plan.jobs if j.kind == "stretch"]
    assert "in surface distance with the stretch maps" in plan.describe()
    assert plan.run().exit_code == 0
    for udim in UDIMS:
        got, _, _ = read_exr(given.parent / "out" / f"skin_sss.{udim}.exr")
        want = expected_blur(udim, root / "out" / f"skin_sss.{udim}.stretch.exr")
        # the cm lengths x 10 round in float32: the blur moves by far less than its bound
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * float(want.max()))
    record = next(e for e in json.loads((given.parent / "out" / "bdipole_materials.json")
                                        .read_text())["materials"]
                  if e["name"] == "skin")["stretch"]["skin_tsd"]
    assert record["from"] == "maps" and len(record["files"]) == 2, record


def test_an_obj_in_its_own_unit_gives_the_analytic_lengths(tmp_path):
    """stretch = an OBJ with mesh_unit: a plane 40 x 20 (cm) over the UV square, the
    material in mm: each texel step is 400/64 mm along u and 200/64 mm along v, and the
    blur of a single irradiance file (no tile token: the one tile the mesh covers) uses
    them."""
    from bdipole_cl.apps.demo import write_exr
    from stretch_meshes import affine_plane
    root = tmp_path / "obj"
    (root / "tex").mkdir(parents=True)
    affine_plane(root / "plane.obj", [[40.0, 0], [0, 20.0], [0, 0]], offset=(0, 0),
                 extent=(1, 1))
    write_exr(root / "tex" / "a.exr", albedo(1001), ("R", "G", "B"))
    write_exr(root / "irr.exr", irradiance(1001), ("R", "G", "B"))
    (root / "scene.toml").write_text(
        '[[material]]\nname = "m"\nalbedo = "tex/a.exr"\ncolorspace = "raw"\n'
        'mfp = [1.5, 0.8, 0.4]\noutput = "out/m.exr"\n\n[[blur]]\nname = "b"\n'
        'material = "m"\nirradiance = "irr.exr"\ncolorspace = "raw"\n'
        'stretch = "plane.obj"\nmesh_unit = "cm"\noutput = "out/b.exr"\n')
    plan = scenes.load(root / "scene.toml").plan()
    assert [j.kind for j in plan.jobs] == ["invert", "stretch", "blur"], plan.describe()
    assert plan.run().exit_code == 0
    s = read_stretch(root / "out" / "b.stretch.exr")
    assert s.unit == "mm" and s.covered.all()
    np.testing.assert_allclose(s.su, 400.0 / SIZE, rtol=1e-6)
    np.testing.assert_allclose(s.sv, 200.0 / SIZE, rtol=1e-6)
    got, _, _ = read_exr(root / "out" / "b.exr")
    want = bd.blur(irradiance(1001), albedo=albedo(1001), mfp=DMFP, eta=1.4, stretch=s)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * float(want.max()))


@pytest.mark.parametrize("keys, where, words", [
    ('stretch = "bound"\ntexel_size = 0.1', "stretch", "texel_size and stretch: give one"),
    ('stretch = "geo.obj"', "stretch", "an OBJ has no unit; give mesh_unit"),
    ('stretch = "geo.abc"', "stretch", "expected \"bound\""),
    ('stretch = "asset.usda"\nmesh_unit = "cm"', "mesh_unit", "mesh_unit is for an OBJ"),
    ('texel_size = 0.1\ncharts = "zero"', "charts", "charts is for a blur with stretch"),
    ('stretch = "bound"\ncharts = "fold"', "charts", "expected"),
], ids=["both", "obj-no-unit", "not-a-mesh", "mesh-unit-usd", "charts-no-stretch",
        "bad-charts"])
def test_scene_file_stretch_keys_are_checked_in_one_line(tmp_path, keys, where, words):
    """Each wrong use of stretch, charts and mesh_unit: a SceneError naming the file, the
    line of the key and what is allowed."""
    scene = stretch_scene(tmp_path / "k", stretch='"bound"')
    text = scene.read_text().replace('stretch = "bound"\n', keys + "\n")
    scene.write_text(text)
    line = next(n for n, t in enumerate(text.splitlines(), 1) if t.startswith(where))
    with pytest.raises(scenes.SceneError) as err:
        scenes.load(scene)
    assert f"scene.toml:{line}:" in str(err.value) and words in str(err.value), err.value
    assert "\n" not in str(err.value)


def test_bound_needs_a_stages_material(tmp_path):
    """stretch = "bound" on a scene file's own material: refused, saying what to name."""
    scene = stretch_scene(tmp_path / "o")
    scene.write_text(scene.read_text().replace('material = "skin"', 'material = "mine"')
                     + '\n[[material]]\nname = "mine"\nalbedo = "tex/skin.<UDIM>.exr"\n'
                       'output = "out/mine.<UDIM>.exr"\n')
    with pytest.raises(scenes.SceneError, match=r"material 'mine' is not a USD stage's "
                                                r"\(materials_from\); name a mesh file"):
        scenes.load(scene)


def test_a_material_bound_to_no_mesh_or_a_tile_no_mesh_reaches_cannot_run(tmp_path):
    """An unbound material's blur, and an irradiance tile (1003) the meshes do not reach:
    jobs that cannot run, named in the plan before any work; the others bake."""
    scene = stretch_scene(tmp_path / "u")
    root = scene.parent
    from bdipole_cl.apps.demo import write_exr
    write_exr(root / "light" / "irr.1003.exr", irradiance(1001), ("R", "G", "B"))
    write_exr(root / "tex" / "skin.1003.exr", albedo(1001), ("R", "G", "B"))
    plan = scenes.load(scene).plan()
    stuck = [j for j in plan.jobs if j.problem]
    assert [(j.kind, j.udim) for j in stuck] == [("stretch", "1003"), ("blur", "1003")]
    assert "no triangle of the meshes reaches UDIM 1003 (they cover 1001, 1002)" in \
        stuck[1].problem, stuck[1].problem
    report = plan.run()
    assert report.exit_code == 1 and (root / "out" / "skin_sss.1001.exr").is_file()
    bind_material(root / "asset.usda", mesh=None, name="loose")
    for udim in (1001, 1002, 1003):
        write_exr(root / "tex" / f"loose.{udim}.exr", albedo(1001), ("R", "G", "B"))
    scene.write_text(scene.read_text().replace('material = "skin"', 'material = "loose"'))
    plan = scenes.load(scene).plan()
    problems = {j.problem for j in plan.jobs if j.kind == "blur"}
    assert problems == {"stretch maps: " + str(root / "asset.usda") + ": material "
                        "/Looks/loose is bound to no mesh (UsdShade's computed binding, "
                        "purpose full, GeomSubsets included)"}, problems

# }}}
