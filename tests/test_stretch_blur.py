"""The stretched blur (bdipole_cl/ops/blur/stretched*.py, kernels/blur_stretched.cl;
docs/stretch.md): against the isotropic blur resampled, against R(r) in surface distance on a
mesh, chart borders, the shear's bound, and the CLI."""
import subprocess
import sys
import warnings

import numpy as np
import pytest
from scipy import integrate

import bdipole_cl as bd
from bdipole_cl.io.stretch_maps import read_stretch, stretch_maps
from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
from bdipole_cl.physics import reference as ref
from conftest import short_id
from stretch_meshes import (CYL_U0, CYL_U1, CYL_V0, CYL_V1, affine_plane, cylinder_lengths,
                            cylinder_stage)

#: the reference blur's tol: its own bound adds to the stretched blur's in the comparisons
REF_TOL = 1e-4


@pytest.mark.parametrize("axis", [1, 0], ids=["u-long", "v-long"])
def test_plane_impulse_is_isotropic_blur_resampled(on_device, axis):
    """Texels 3t long along one axis and t along the other: the stretched blur of an impulse
    equals the isotropic blur (texel t) of the irradiance upsampled 3x along that axis, read
    at the middle fine texel of each coarse one (both are the exact texel-integrated
    convolution of the same irradiance at the same points), within the two bounds."""
    t, h, w = 0.25, 48, 40
    e = np.zeros((h, w), np.float32)
    e[20, 17] = 1.0
    e[30, 25] = 0.5
    s = [np.full((h, w), t, np.float32), np.full((h, w), t, np.float32)]   # (su, sv)
    s[0 if axis == 1 else 1][...] = 3 * t      # u-long: columns (axis 1) 3t; v-long: rows
    out, info = bd.blur(e, albedo=0.6, mfp=1.0, stretch=tuple(s), tol=1e-3, return_info=True)
    fine = np.repeat(e, 3, axis=1 if axis == 1 else 0)
    want, winfo = bd.blur(fine, albedo=0.6, mfp=1.0, texel_size=t, tol=REF_TOL, method="fft",
                          return_info=True)
    want = want[:, 1::3] if axis == 1 else want[1::3]
    rd = 0.6
    err = float(np.max(np.abs(out - want))) / (1.0 * rd)
    bound = info.channels[0].error_bound + winfo.channels[0].error_bound
    assert err <= bound, (err, bound, info.channels[0])
    # energy: Rd x sum E, but for the tail values the float32 FFT's settle floor (16 eps32 x
    # max E x Rd a texel) writes as 0
    floor = h * w * 16 * 2.0 ** -23 * rd
    assert 0 <= rd * 1.5 - float(out.sum()) <= floor, out.sum()


def surface_reference(x, y, cell, rd, mfp, eta=1.4):
    """Exitance at surface point (x, y) (mm, the cylinder unrolled) of a unit irradiance on
    the surface rectangle ``cell`` = (x0, x1, y0, y1): R integrated over it (scipy dblquad)."""
    sa, ss = ref.albedo_to_coefficients(rd, mfp, eta)
    st = float(sa + ss)
    alpha = float(ss / st)
    x0, x1, y0, y1 = cell
    val, _ = integrate.dblquad(
        lambda yy, xx: float(ref.profile(np.hypot(xx - x, yy - y), alpha, st, eta)),
        x0, x1, y0, y1, epsabs=1e-12, epsrel=1e-10)
    return val


def test_cylinder_follows_profile_in_surface_distance(on_device, tmp_path):
    """A USD cylinder whose two UV charts have different stretch (0.245 and 0.49 mm/texel
    along u, 0.195 along v): an impulse in each chart, blurred with its stretch map, equals
    R integrated over the impulse texel's surface rectangle at the surface distance of the
    polygon unrolled (the mesh is developable), at texels along u, v and the diagonal, within
    the reported bound (relative to max E x Rd)."""
    size, rd, mfp = 256, 0.7, 1.0
    (tile, _), = stretch_maps(cylinder_stage(tmp_path / "cyl.usda"), size=size)
    lengths = cylinder_lengths(size=size)
    e = np.zeros((size, size), np.float32)
    spots = [(128, 76), (128, 185)]            # (row, column): chart 0 and chart 1
    for r, c in spots:
        e[r, c] = 1.0
    out, info = bd.blur(e, albedo=rd, mfp=mfp, stretch=tile, tol=1e-3, return_info=True)
    bound = info.channels[0].error_bound
    assert bound < 2e-3, info
    for side, (r0, c0) in enumerate(spots):
        su, sv = lengths[side]
        assert abs(tile.su[r0, c0] / su - 1) < 1e-5 and abs(tile.sv[r0, c0] / sv - 1) < 1e-5
        cell = (-su / 2, su / 2, -sv / 2, sv / 2)
        for dr, dc in [(0, 0), (0, 1), (0, 3), (0, 6), (2, 0), (5, 0), (3, 3), (-4, 2)]:
            x, y = dc * su, -dr * sv               # rows run down, v up: the sign is immaterial
            want = surface_reference(x, y, cell, rd, mfp)
            got = float(out[r0 + dr, c0 + dc])
            assert abs(got - want) <= bound * rd, (side, dr, dc, got, want, bound)


def test_chart_borders(on_device, tmp_path):
    """An impulse 4 texels from chart 0's edge, 13 texels of gutter from chart 1: with charts
    kept apart ("clamp", "zero") no light reaches chart 1's texels; with "none" it does. With
    "clamp" the chart's light near its edge is what the edge continued gives (more than
    "zero", which has nothing beyond)."""
    size = 256
    (tile, _), = stretch_maps(cylinder_stage(tmp_path / "cyl.usda"), size=size)
    e = np.zeros((size, size), np.float32)
    col = int(CYL_U1[0] * size) - 4
    e[128, col] = 1.0
    outs = {mode: bd.blur(e, albedo=0.8, mfp=1.5, stretch=tile, charts=mode)
            for mode in ("clamp", "zero", "none")}
    other = tile.chart == tile.chart[128, int(CYL_U0[1] * size) + 4]
    assert not np.any(outs["clamp"][other]) and not np.any(outs["zero"][other])
    assert np.any(outs["none"][other] > 0)
    own = tile.chart == tile.chart[128, col]
    assert outs["clamp"][own].sum() >= outs["zero"][own].sum()
    np.testing.assert_array_equal(outs["clamp"][128, col - 2:col + 3] > 0, True)


def test_shear_is_bounded_and_reported(on_device, tmp_path):
    """A sheared UV map (u and v at 72 degrees on the surface): the axis-aligned kernel's
    error is measured and added to the bound, and warned of when it exceeds tol, naming the
    layout's most sheared texel."""
    jac = [(0.3, 0.1), (0.0, 0.3), (0.0, 0.0)]
    (tile, _), = stretch_maps(affine_plane(tmp_path / "shear.obj", jac), size=64)
    assert tile.max_shear > 0.3
    e = np.zeros((64, 64), np.float32)
    e[32, 32] = 1.0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, info = bd.blur(e, albedo=0.6, mfp=20.0, stretch=tile, return_info=True)
    assert "shear" in info.channels[0].method and info.channels[0].error_bound > 2e-3
    x, y = tile.max_shear_texel
    assert any(issubclass(w.category, BlurAccuracyWarning) and "shear" in str(w.message)
               and f"at texel x={x}, y={y}" in str(w.message) for w in caught)
    unsheared = (tile.su, tile.sv)                           # the same lengths, no shear known
    _, plain = bd.blur(e, albedo=0.6, mfp=20.0, stretch=unsheared, return_info=True)
    assert plain.channels[0].error_bound < info.channels[0].error_bound


def test_bad_stretch_named(on_device):
    """A texel length that is 0, negative or not finite: one line naming the texel."""
    e = np.ones((8, 8), np.float32)
    su = np.ones((8, 8), np.float32)
    su[3, 5] = 0.0
    with pytest.raises(ValueError, match=r"stretch su at x=5, y=3: .*finite and > 0"):
        bd.blur(e, albedo=0.5, mfp=1.0, stretch=(su, np.ones((8, 8), np.float32)))
    with pytest.raises(ValueError, match=r"shape \(4, 4\); expected \(8, 8\)"):
        bd.blur(e, albedo=0.5, mfp=1.0, stretch=np.ones((4, 4, 2), np.float32))


def test_cli_blur_with_stretch(on_device, tmp_path):
    """``bdipole-cl blur --stretch`` over UDIM tiles: each tile blurred with its own map, the
    same as the API with the map read back; the output records the stretch."""
    import OpenImageIO as oiio
    stage = cylinder_stage(tmp_path / "cyl.usda", tile2=True)
    stretch_maps(stage, str(tmp_path / "st.<UDIM>.exr"), size=64)
    for udim in (1001, 1002):
        e = np.zeros((64, 64, 3), np.float32)
        e[32, 28 if udim == 1001 else 45] = 1.0
        out = oiio.ImageOutput.create(str(tmp_path / f"irr.{udim}.exr"))
        out.open(str(tmp_path / f"irr.{udim}.exr"), oiio.ImageSpec(64, 64, 3, "float"))
        out.write_image(e)
        out.close()
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "blur",
                          str(tmp_path / "irr.<UDIM>.exr"), "--stretch",
                          str(tmp_path / "st.<UDIM>.exr"), "--albedo", "0.8,0.6,0.4",
                          "--mfp", "1.2,0.6,0.3", "-o", str(tmp_path / "out.<UDIM>.exr"),
                          "--device", short_id(on_device), "--no-progress", "--colorspace",
                          "lin_rec709_scene"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    for udim in (1001, 1002):
        inp = oiio.ImageInput.open(str(tmp_path / f"out.{udim}.exr"))
        got = inp.read_image("float")
        spec = inp.spec()
        inp.close()
        assert spec.get_string_attribute("bdipole:texel_size") == "stretch map"
        e = np.zeros((64, 64, 3), np.float32)
        e[32, 28 if udim == 1001 else 45] = 1.0
        want = bd.blur(e, albedo=(0.8, 0.6, 0.4), mfp=(1.2, 0.6, 0.3),
                       stretch=read_stretch(tmp_path / f"st.{udim}.exr"))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)
        assert got[..., 0].sum() > 0


def test_cli_blur_with_stretch_on_a_scheduler_says_why_not(tmp_path, capsys):
    """``blur --stretch --scheduler``: a usage error (exit 2) before any cluster starts, that
    says why (the cluster blurs bands; a stretched blur reads the whole image) and what to do
    instead; it had said the parameters were textures."""
    from bdipole_cl.apps.cli import main
    from bdipole_cl.apps.demo import write_exr
    (tile, _), = stretch_maps(affine_plane(tmp_path / "p.obj", [[0.04, 0], [0, 0.02], [0, 0]]),
                              str(tmp_path / "st.exr"), size=16)
    write_exr(tmp_path / "irr.exr", np.ones((16, 16, 3), np.float32), ("R", "G", "B"))
    code = main(["blur", str(tmp_path / "irr.exr"), "--stretch", str(tmp_path / "st.exr"),
                 "--albedo", "0.5", "--mfp", "1", "-o", str(tmp_path / "out.exr"),
                 "--scheduler", "local:1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "a stretched blur reads the whole image" in err, err
    assert "bake a scene on the cluster" in err and not (tmp_path / "out.exr").exists()


def test_cli_stretch_errors_name_the_stretch_file_and_options(tmp_path, capsys):
    """A stretch map with a NaN length is refused naming that file, its channel and texel
    (not the irradiance); --texel-size beside --stretch, and one tile's stretch map for a tile
    pattern of several, are usage errors (exit 2); nothing is written."""
    import OpenImageIO as oiio
    from bdipole_cl.apps.cli import main
    from bdipole_cl.apps.demo import write_exr
    stage = cylinder_stage(tmp_path / "cyl.usda", tile2=True)
    stretch_maps(stage, str(tmp_path / "st.<UDIM>.exr"), size=32)
    for udim in (1001, 1002):
        write_exr(tmp_path / f"irr.{udim}.exr", np.ones((32, 32, 3), np.float32),
                  ("R", "G", "B"))
    px = oiio.ImageBuf(str(tmp_path / "st.1001.exr"))
    spec = px.spec()
    bad = px.get_pixels(oiio.FLOAT)
    bad[5, 7, spec.channelnames.index("stretch.u")] = np.nan
    out = oiio.ImageOutput.create(str(tmp_path / "nan.exr"))
    out.open(str(tmp_path / "nan.exr"), spec)
    out.write_image(bad)
    out.close()
    common = ["--albedo", "0.5", "--mfp", "1", "--no-progress"]
    code = main(["blur", str(tmp_path / "irr.1001.exr"), "--stretch", str(tmp_path / "nan.exr"),
                 "-o", str(tmp_path / "o.exr"), *common])
    err = capsys.readouterr().err
    assert code == 1 and "nan.exr: stretch.u at x=7, y=5: nan" in err, err
    assert "irr.1001.exr" not in err
    code = main(["blur", str(tmp_path / "irr.1001.exr"), "--stretch",
                 str(tmp_path / "st.1001.exr"), "--texel-size", "0.1",
                 "-o", str(tmp_path / "o.exr"), *common])
    err = capsys.readouterr().err
    assert code == 2 and "--texel-size 0.1 with --stretch" in err, err
    code = main(["blur", str(tmp_path / "irr.<UDIM>.exr"), "--stretch",
                 str(tmp_path / "st.1001.exr"), "-o", str(tmp_path / "o.<UDIM>.exr"), *common])
    err = capsys.readouterr().err
    assert code == 2 and "is one tile's map" in err and "names 2 tiles" in err, err
    assert not list(tmp_path.glob("o*.exr"))


def test_cli_blur_names_the_tile_its_shear_warning_is_of(on_device, tmp_path):
    """``bdipole-cl blur`` of UDIM tiles whose stretch is sheared: the accuracy warning names
    the tile's irradiance file and the most sheared texel (it named neither tile nor file)."""
    import OpenImageIO as oiio
    jac = [(0.3, 0.1), (0.0, 0.3), (0.0, 0.0)]
    (tile, _), = stretch_maps(affine_plane(tmp_path / "shear.obj", jac),
                              str(tmp_path / "st.1001.exr"), size=32)
    e = np.zeros((32, 32, 3), np.float32)
    e[16, 16] = 1.0
    out = oiio.ImageOutput.create(str(tmp_path / "irr.1001.exr"))
    out.open(str(tmp_path / "irr.1001.exr"), oiio.ImageSpec(32, 32, 3, "float"))
    out.write_image(e)
    out.close()
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "blur",
                          str(tmp_path / "irr.<UDIM>.exr"), "--stretch",
                          str(tmp_path / "st.<UDIM>.exr"), "--albedo", "0.6", "--mfp", "20",
                          "-o", str(tmp_path / "out.<UDIM>.exr"), "--device",
                          short_id(on_device), "--no-progress", "--colorspace",
                          "lin_rec709_scene"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    x, y = tile.max_shear_texel
    lines = [ln for ln in run.stderr.splitlines() if "shear" in ln]
    assert lines and all("irr.1001.exr: channel " in ln and "stretched blur error bound" in ln
                         and f"at texel x={x}, y={y}" in ln for ln in lines), run.stderr
