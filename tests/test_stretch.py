"""Stretch maps from meshes (bdipole_cl/io/mesh.py, ops/stretch.py, io/stretch_maps.py,
``bdipole-cl stretch``; docs/stretch.md): analytic planes, a USD cylinder over UDIM tiles with
faceVarying seams, degenerate and flipped triangles, UVs in no tile."""
import subprocess
import sys

import numpy as np
import pytest

from bdipole_cl.io.mesh import MeshError, read_meshes
from bdipole_cl.io.stretch_maps import read_stretch, stretch_maps
from bdipole_cl.ops.stretch import StretchError, stretch_tiles
from stretch_meshes import affine_plane, cylinder_lengths, cylinder_stage, write_obj

#: float32 unit round-off: the maps are float64 Jacobians rounded once to float32 (u), from
#: positions and UVs exact in binary or within a few float64 ulps (negligible)
U32 = 2.0 ** -24


@pytest.mark.parametrize("jac,shear", [
    (((0.3, 0.0), (0.0, 0.12), (0.0, 0.0)), 0.0),                  # u along x, v along y
    (((0.2, 0.0), (0.0, 0.1), (0.15, 0.05)), None),                 # tilted in 3D
    (((0.3, 0.1), (0.0, 0.2), (0.0, 0.0)), None),                   # sheared
], ids=["axes", "tilted", "sheared"])
def test_affine_plane_exact(tmp_path, jac, shear):
    """An affine UV map's stretch is constant: |dP/du| / W and |dP/dv| / H (metres to mm),
    equal to the analytic values within float32's rounding, the shear the cosine between the
    columns; every texel of the tile (gutters too, by dilation) holds it."""
    jac = np.asarray(jac)
    path = affine_plane(tmp_path / "plane.obj", jac)
    (tile,) = stretch_tiles(read_meshes(path), (64, 128), 1e-3)
    su = np.linalg.norm(jac[:, 0]) / 128 / 1e-3
    sv = np.linalg.norm(jac[:, 1]) / 64 / 1e-3
    cos = jac[:, 0] @ jac[:, 1] / (np.linalg.norm(jac[:, 0]) * np.linalg.norm(jac[:, 1]))
    assert tile.tile == (0, 0) and tile.covered.mean() > 0.5
    assert np.max(np.abs(tile.su / su - 1)) <= 2 * U32, (tile.su.min(), tile.su.max(), su)
    assert np.max(np.abs(tile.sv / sv - 1)) <= 2 * U32, (tile.sv.min(), tile.sv.max(), sv)
    assert abs(tile.max_shear - abs(cos)) <= 4 * U32, (tile.max_shear, cos)
    if shear is not None:
        assert tile.max_shear == shear


def test_flipped_triangles_same_map(tmp_path):
    """A mirrored UV layout (negative UV orientation) gives the same lengths, counted."""
    jac = [(0.3, 0.0), (0.0, 0.12), (0.0, 0.0)]
    (a,) = stretch_tiles(read_meshes(affine_plane(tmp_path / "a.obj", jac)), 64)
    (b,) = stretch_tiles(read_meshes(affine_plane(tmp_path / "b.obj", jac, flip=True)), 64)
    assert b.flipped == 2 and a.flipped == 0
    np.testing.assert_array_equal(a.su, b.su)
    np.testing.assert_array_equal(a.sv, b.sv)


def test_degenerate_triangles_left_out(tmp_path):
    """Triangles of zero UV area or zero surface area have no Jacobian: left out and counted;
    their texels take their neighbours' (right) values."""
    pts = [(0, 0, 0), (0.1, 0, 0), (0.1, 0.1, 0), (0, 0.1, 0), (0.05, 0.05, 0), (0.2, 0.2, 0)]
    uvs = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9), (0.5, 0.5), (0.5, 0.5)]
    faces = [[(0, 0), (1, 1), (2, 2)], [(0, 0), (2, 2), (3, 3)],
             [(4, 0), (4, 1), (4, 2)],                 # zero surface area, full UV area
             [(0, 4), (1, 5), (5, 4)]]                 # zero UV area
    path = write_obj(tmp_path / "deg.obj", pts, uvs, faces)
    (tile,) = stretch_tiles(read_meshes(path), 32)
    assert tile.degenerate == 2
    want = 0.1 / 0.8 / 32 / 1e-3
    assert np.max(np.abs(tile.su / want - 1)) <= 2 * U32
    assert np.max(np.abs(tile.sv / want - 1)) <= 2 * U32


@pytest.mark.parametrize("uv,where", [((-0.2, 0.5), "-0.2"), ((10.5, 0.5), "10.5"),
                                      ((0.5, -1.0), "-1")], ids=["u<0", "u>=10", "v<0"])
def test_uv_in_no_tile_one_line(tmp_path, uv, where):
    """A texture coordinate in no UDIM tile: one line naming the mesh, the face and the UV
    (API: StretchError; CLI: exit 1, that line)."""
    pts = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    path = write_obj(tmp_path / "out.obj", pts, [(0.1, 0.1), (0.2, 0.1), uv],
                     [[(0, 0), (1, 1), (2, 2)]])
    with pytest.raises(StretchError, match=rf"face 0: texture coordinate .*{where}.* no UDIM"):
        stretch_tiles(read_meshes(path), 16)
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "stretch", str(path), "-o",
                          str(tmp_path / "s.<UDIM>.exr"), "--size", "16"],
                         capture_output=True, text=True)
    assert run.returncode == 1, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "no UDIM tile" in lines[0], run.stderr
    assert not list(tmp_path.glob("s.*"))


def test_obj_errors_named(tmp_path):
    """An OBJ face without texture coordinates, or an index past the vertices: named."""
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"bad.obj:4: a face without texture coordinates"):
        read_meshes(bad)
    bad.write_text("v 0 0 0\nvt 0 0\nf 1/1 2/1 3/1\n")
    with pytest.raises(MeshError, match=r"bad.obj:3: index 2 outside the 1"):
        read_meshes(bad)


def test_cylinder_udim_facevarying(tmp_path):
    """A USD cylinder (metersPerUnit 0.001: mm) with faceVarying st, its halves two charts in
    UDIM 1001 and 1002: one EXR per tile, declared as data, with the unit, each chart's
    lengths the polygon's (chord x facets per texel), the seam making two charts."""
    from OpenImageIO import ImageInput
    stage = cylinder_stage(tmp_path / "cyl.usda", tile2=True)
    done = stretch_maps(stage, str(tmp_path / "st.<UDIM>.exr"), size=256)
    assert [t.udim for t, _ in done] == [1001, 1002]
    want = cylinder_lengths()
    for side, (tile, path) in enumerate(done):
        s = read_stretch(path)
        su, sv = want[side]
        cov = s.covered
        # the stage's points are float32: each coordinate within u x 10 mm, so a 0.98 mm
        # chord within ~2 x 10 / 0.98 u = 20 u relative, and the map's own rounding (u)
        assert np.max(np.abs(s.su[cov] / su - 1)) <= 24 * U32, (s.su[cov].min(), su)
        assert np.max(np.abs(s.sv[cov] / sv - 1)) <= 24 * U32, (s.sv[cov].min(), sv)
        assert len(np.unique(s.chart)) == 1 and s.unit == "mm"
        inp = ImageInput.open(path)
        spec = inp.spec()
        inp.close()
        assert spec.get_string_attribute("oiio:ColorSpace") in ("data", "Raw", "raw")
        assert spec.get_string_attribute("bdipole:stretch_unit") == "mm"
        assert spec.get_string_attribute("bdipole:stretch_meters_per_unit") == "0.001"
    (one, _), = stretch_maps(cylinder_stage(tmp_path / "one.usda"), None, size=256)
    charts = np.unique(one.chart[one.covered])
    assert len(charts) == 2                # the faceVarying seams split the two halves


def test_usd_time_samples(tmp_path):
    """Points time-sampled: the map at the time asked (a plane scaled 2x at time 10)."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(tmp_path / "t.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)                     # cm
    mesh = UsdGeom.Mesh.Define(stage, "/p")
    quad = np.array([(0, 0, 0), (8, 0, 0), (8, 8, 0), (0, 8, 0)], float)
    for t, k in ((1.0, 1.0), (10.0, 2.0)):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*(k * p)) for p in quad]), t)
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        Vt.Vec2fArray([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)]))
    stage.GetRootLayer().Save()
    for t, k in ((1.0, 1.0), (10.0, 2.0)):
        (tile, _), = stretch_maps(tmp_path / "t.usda", size=32, time=t)
        want = k * 80.0 / 32                                       # mm per texel
        assert np.max(np.abs(tile.su / want - 1)) <= 2 * U32, (t, tile.su.max(), want)


def test_cli_stretch_writes_tiles(tmp_path):
    """``bdipole-cl stretch`` writes the tiles and says what each holds."""
    stage = cylinder_stage(tmp_path / "cyl.usda", tile2=True)
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "stretch", str(stage), "-o",
                          str(tmp_path / "s.<UDIM>.exr"), "--size", "64", "--unit", "cm"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "s.1001.exr").exists() and (tmp_path / "s.1002.exr").exists()
    assert "UDIM 1002" in run.stdout and "cm/texel" in run.stdout
    assert read_stretch(tmp_path / "s.1001.exr").unit == "cm"


def test_cli_stretch_of_meshes_that_share_texels(tmp_path):
    """``bdipole-cl stretch`` of a stage whose two meshes cover the same UVs with different
    lengths: exit 1, one line naming both prims and the texel (it had written the second
    mesh's lengths over the first's, silently); ``--prim`` takes one of them; two copies of
    one plane (the same lengths) give the one plane's map."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(tmp_path / "two.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    for name, width, x in (("a", 0.04, 0.0), ("copy", 0.04, 1.0), ("b", 0.08, 2.0)):
        mesh = UsdGeom.Mesh.Define(stage, f"/{name}")
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(x + px * width, py * 0.02, 0) for px,
                                             py in ((0, 0), (1, 0), (1, 1), (0, 1))]))
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
            Vt.Vec2fArray([Gf.Vec2f(*p) for p in ((0.1, 0.1), (0.9, 0.1), (0.9, 0.9),
                                                  (0.1, 0.9))]))
    stage.GetRootLayer().Save()
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "stretch", str(tmp_path /
                          "two.usda"), "-o", str(tmp_path / "s.exr"), "--size", "32"],
                         capture_output=True, text=True)
    assert run.returncode == 1 and not (tmp_path / "s.exr").exists(), run.stderr
    line = run.stderr.strip()
    assert "\n" not in line and ":/a and " in line and ":/b: both cover texel" in line, line
    assert "one stretch map cannot hold both" in line, line
    (b, _), = stretch_maps(tmp_path / "two.usda", size=32, prim="/b")
    np.testing.assert_allclose(b.su[b.covered], 80.0 / 0.8 / 32, rtol=1e-6)
    stage.RemovePrim("/b")
    stage.GetRootLayer().Save()
    (both, _), = stretch_maps(tmp_path / "two.usda", size=32)
    (one, _), = stretch_maps(tmp_path / "two.usda", size=32, prim="/a")
    np.testing.assert_array_equal(both.su, one.su)
    np.testing.assert_array_equal(both.sv, one.sv)


def test_stretch_into_a_missing_folder_makes_it(tmp_path):
    # exit 1 naming the temp file (Could not open "st/.quad.partial-....exr"); invert and
    # preview make their output's folder
    pts = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    path = write_obj(tmp_path / "quad.obj", pts, [(0.1, 0.1), (0.9, 0.1), (0.1, 0.9)],
                     [[(0, 0), (1, 1), (2, 2)]])
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "stretch", str(path), "-o",
                          str(tmp_path / "st" / "quad.exr"), "--size", "16"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "st" / "quad.exr").is_file()


def test_the_most_sheared_texel_is_named_and_recorded(tmp_path):
    """Two charts, the left one's u and v orthogonal on the surface, the right one's sheared:
    the tile names the first covered texel of the largest |shear| (in the right chart), the
    stretch map records it (``bdipole:stretch_max_shear_texel``) and reads it back, and a map
    without the record (written before it) reads as not known."""
    import OpenImageIO as oiio
    left = np.array([[0.05, 0.1], [0.45, 0.1], [0.45, 0.9], [0.05, 0.9]])
    right = left + [0.5, 0.0]
    straight = np.array([(0.3, 0.0), (0.0, 0.2), (0.0, 0.0)])
    sheared = np.array([(0.3, 0.1), (0.0, 0.2), (0.0, 0.0)])
    points = np.vstack([left @ straight.T, right @ sheared.T + [0.0, 0.0, 1.0]])
    path = write_obj(tmp_path / "two.obj", points, np.vstack([left, right]),
                     [[(i, i) for i in range(4)], [(i, i) for i in range(4, 8)]])
    (tile, out), = stretch_maps(path, tmp_path / "s.exr", size=64)
    x, y = tile.max_shear_texel
    assert x >= 0.5 * 64 and tile.covered[y, x]
    assert abs(tile.shear[y, x]) == tile.max_shear > 0.3
    assert not (np.abs(np.where(tile.covered, tile.shear, 0))[:y] == tile.max_shear).any()
    assert read_stretch(out).max_shear_at == (x, y)
    spec = oiio.ImageInput.open(str(out)).spec()
    old = oiio.ImageBuf(str(out))
    old.specmod().erase_attribute("bdipole:stretch_max_shear_texel")
    old.write(str(tmp_path / "old.exr"))
    assert spec.get_string_attribute("bdipole:stretch_max_shear_texel") == f"{x} {y}"
    assert read_stretch(tmp_path / "old.exr").max_shear_at is None
    assert read_stretch(tmp_path / "old.exr").max_shear == pytest.approx(tile.max_shear)


def test_a_rotated_planes_rounding_names_no_texel(tmp_path):
    """A plane whose u and v are orthogonal, rotated in 3D: its shear is rounding (~1e-16),
    not a shear, and no texel is named for it."""
    a, b, c = 0.3, 0.7, 1.1
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    jac = rz @ ry @ rx @ np.array([[0.3, 0.0], [0.0, 0.12], [0.0, 0.0]])
    (tile,) = stretch_tiles(read_meshes(affine_plane(tmp_path / "p.obj", jac)), (64, 64), 1e-3)
    assert 0 < tile.max_shear <= 1e-6 and tile.max_shear_texel is None


@pytest.mark.parametrize("sheared_first", [False, True])
def test_two_surfaces_at_one_texel_keep_the_larger_shear(tmp_path, sheared_first):
    """Two meshes on the same UVs with equal lengths (instances, as far as the lengths go),
    one square and one sheared at 60 degrees: the tile's shear is the larger, whichever mesh
    comes first (it was the first mesh's)."""
    square = affine_plane(tmp_path / "square.obj", [(0.2, 0.0), (0.0, 0.2), (0.0, 0.0)])
    c = np.cos(np.pi / 3)
    sheared = affine_plane(tmp_path / "sheared.obj",
                           [(0.2, 0.2 * c), (0.0, 0.2 * np.sin(np.pi / 3)), (0.0, 0.0)])
    paths = [sheared, square] if sheared_first else [square, sheared]
    meshes = [m for p in paths for m in read_meshes(p)]
    (tile,) = stretch_tiles(meshes, (32, 32), 1e-3)
    assert tile.max_shear == pytest.approx(0.5, abs=1e-6) and tile.max_shear_texel is not None


@pytest.mark.parametrize("text", ["999 999", "3 64", "\uff13 \uff14", "3 4 5", "-1 5", ""])
def test_a_recorded_texel_outside_the_map_or_malformed_reads_as_not_known(tmp_path, text):
    """``bdipole:stretch_max_shear_texel`` is read only as two ASCII numbers of a texel of
    the map; anything else (off the 64x64 map, full-width digits, three numbers) is not
    known."""
    import OpenImageIO as oiio
    path = affine_plane(tmp_path / "p.obj", [(0.3, 0.1), (0.0, 0.2), (0.0, 0.0)])
    (_, out), = stretch_maps(path, tmp_path / "s.exr", size=64)
    buf = oiio.ImageBuf(str(out))
    buf.specmod().attribute("bdipole:stretch_max_shear_texel", text)
    buf.write(str(tmp_path / "edited.exr"))
    assert read_stretch(tmp_path / "edited.exr").max_shear_at is None
    assert read_stretch(out).max_shear_at is not None
