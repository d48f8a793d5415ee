"""Texture batches (bdipole_cl/io/batch.py, ``bdipole-cl invert``) on generated files."""
import os
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import reference as ref
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io.batch import expand_inputs, process_textures

#: every test here runs once per working OpenCL device (tests/conftest.py)
pytestmark = pytest.mark.usefixtures("on_device")

W, H = 24, 16


def albedo_image(nch, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.02, 0.97, (H, W, nch)).astype(np.float32)


def write_image(path, pixels, fmt, channels, tile=None):
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], fmt)
    spec.channelnames = tuple(channels)
    if "A" in channels:
        spec.alpha_channel = channels.index("A")
    if tile:
        spec.tile_width = spec.tile_height = tile
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    if fmt == "uint8":
        data = np.round(pixels * 255).astype(np.uint8)
    elif fmt == "uint16":
        data = np.round(pixels * 65535).astype(np.uint16)
    else:
        data = pixels
    assert out.write_image(data), out.geterror()
    out.close()


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    px = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    inp.close()
    return spec, np.asarray(px).reshape(spec.height, spec.width, spec.nchannels)


def srgb_to_linear(v):
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def channel(spec, px, name):
    return px[..., list(spec.channelnames).index(name)]


def no_partials(*folders):
    return not [p for f in folders for p in Path(f).iterdir() if ".partial-" in p.name]


CASES = [
    # (extension, format, channels, expected decode)
    pytest.param("png", "uint8", ("R", "G", "B"), "srgb", id="png-8bit-srgb-rgb"),
    pytest.param("png", "uint8", ("Y",), "srgb", id="png-8bit-srgb-grey"),
    pytest.param("tif", "uint16", ("R", "G", "B", "A"), "linear", id="tif-16bit-rgba"),
    pytest.param("exr", "half", ("R", "G", "B"), "linear", id="exr-half-rgb"),
    pytest.param("exr", "float", ("R", "G", "B", "A"), "linear", id="exr-float-rgba"),
    pytest.param("tif", "float", ("Y",), "linear", id="tif-float-grey"),
]


@pytest.mark.parametrize("ext,fmt,channels,decode", CASES)
def test_formats_values_and_headers(tmp_path, ext, fmt, channels, decode):
    src = albedo_image(len(channels))
    if "A" in channels:
        src[..., channels.index("A")] = np.linspace(0, 1, W)[None, :]
    path = tmp_path / f"diffuse.{ext}"
    write_image(path, src, fmt, channels)
    report = process_textures(path, mfp=(2.0,), eta=1.4, outputs=("rho", "sigma_a", "sigma_s"),
                              output=str(tmp_path / "{stem}_out.exr"))
    assert report.ok, report.summary()
    spec, px = read(tmp_path / "diffuse_out.exr")
    colour = [c for c in channels if c != "A"]
    want_names = [f"{o}.{c}" for o in ("rho", "sigma_a", "sigma_s") for c in colour]
    want_names += ["A"] if "A" in channels else []
    assert sorted(spec.channelnames) == sorted(want_names)  # EXR stores channels by name
    assert (spec.width, spec.height) == (W, H) and spec.format == oiio.FLOAT
    assert spec.getattribute("bdipole:eta").startswith("1.4")
    assert spec.getattribute("bdipole:albedo_colorspace") == (
        "Linear Rec.709 (sRGB)" if decode == "linear" else "sRGB Encoded Rec.709 (sRGB)")
    # expected linear albedo, decoded independently of OpenImageIO
    _, stored = read(path)
    for c in colour:
        enc = stored[..., channels.index(c)].astype(np.float64)
        albedo = srgb_to_linear(enc) if decode == "srgb" else enc
        rho = channel(spec, px, f"rho.{c}").astype(np.float64)
        # forward model of the written rho gives back the albedo: 2e-6 absolute covers the
        # table inversion's rho error seen through Rd(rho) and float32 rounding (OpenColorIO
        # decodes sRGB without its fast-pow approximation: io/colour.py)
        np.testing.assert_allclose(ref.rd_of_rho(rho, 1.4), albedo, atol=2e-6, rtol=0)
        want_sa, want_ss = ref.albedo_to_coefficients(ref.rd_of_rho(rho, 1.4), 2.0, 1.4)
        np.testing.assert_allclose(channel(spec, px, f"sigma_a.{c}"), want_sa, rtol=2e-5)
        np.testing.assert_allclose(channel(spec, px, f"sigma_s.{c}"), want_ss, rtol=2e-5)
    if "A" in channels:
        np.testing.assert_array_equal(channel(spec, px, "A"), stored[..., channels.index("A")])


def test_udim_set_with_mfp_textures_tiling_and_half(tmp_path):
    for k, udim in enumerate(("1001", "1002")):
        write_image(tmp_path / f"diffuse.{udim}.exr", albedo_image(3, seed=k), "float",
                    ("R", "G", "B"), tile=8)
        write_exr(tmp_path / f"mfp.{udim}.exr", np.full((H, W, 1), 0.5 + k, np.float32), ("Y",))
    assert [t.label for _, t in expand_inputs([str(tmp_path / "diffuse.<UDIM>.exr")])] == ["1001", "1002"]
    rc = cli_main(["invert", str(tmp_path / "diffuse.<UDIM>.exr"),
                   "--mfp", str(tmp_path / "mfp.<UDIM>.exr"),
                   "-o", str(tmp_path / "out" / "coeffs.<UDIM>.exr"),
                   "--half", "--eta", "1.3,1.4,1.5", "--no-progress"])
    assert rc == 0
    for k, udim in enumerate(("1001", "1002")):
        spec, px = read(tmp_path / "out" / f"coeffs.{udim}.exr")
        assert spec.format == oiio.HALF and spec.tile_width == 8
        albedo = albedo_image(3, seed=k)
        for ci, (c, eta) in enumerate(zip("RGB", (1.3, 1.4, 1.5))):
            want = ref.albedo_to_coefficients(albedo[..., ci], 0.5 + k, eta)[0]
            # half output: 2^-11 relative rounding
            np.testing.assert_allclose(channel(spec, px, f"sigma_a.{c}"), want, rtol=1e-3)


def test_streaming_in_bands_matches_one_band(tmp_path):
    write_image(tmp_path / "a.exr", albedo_image(3), "float", ("R", "G", "B"))
    one = process_textures(tmp_path / "a.exr", mfp=1.0, output=str(tmp_path / "one.exr"))
    many = process_textures(tmp_path / "a.exr", mfp=1.0, output=str(tmp_path / "many.exr"),
                            max_memory=1)   # forces one scanline per band
    assert one.ok and many.ok
    np.testing.assert_array_equal(read(tmp_path / "one.exr")[1], read(tmp_path / "many.exr")[1])


def test_bad_inputs_are_reported_and_the_others_finish(tmp_path, capsys):
    good = tmp_path / "good.exr"
    write_image(good, albedo_image(3), "float", ("R", "G", "B"))
    (tmp_path / "corrupt.exr").write_bytes(b"not an image" * 20)
    nan = albedo_image(3)
    nan[9, 5, 1] = np.nan
    write_image(tmp_path / "nan.exr", nan, "float", ("R", "G", "B"))
    write_image(tmp_path / "small.exr", albedo_image(3)[:8], "float", ("R", "G", "B"))
    write_exr(tmp_path / "mfp_small.exr", np.ones((8, W, 1)), ("Y",))
    write_exr(tmp_path / "mfp_good.exr", np.ones((H, W, 1)), ("Y",))
    out = tmp_path / "out"
    rc = cli_main(["invert", str(tmp_path / "missing.exr"), str(tmp_path / "corrupt.exr"),
                   str(tmp_path / "nan.exr"), str(good), "--mfp", str(tmp_path / "mfp_good.exr"),
                   "-o", str(out / "{stem}.exr"), "--no-progress"])
    text = capsys.readouterr().out
    assert rc == 1
    assert (out / "good.exr").exists()
    assert not (out / "nan.exr").exists() and not (out / "corrupt.exr").exists()
    assert "missing.exr: no such file (albedo)" in text
    assert "corrupt.exr: cannot read albedo" in text
    assert "x=5, y=9, channel G: nan" in text
    assert "1 done, 3 failed" in text
    assert no_partials(out)
    # mismatched mfp resolution
    rep = process_textures(tmp_path / "small.exr", mfp=str(tmp_path / "mfp_good.exr"),
                           output=str(out / "{stem}.exr"))
    assert not rep.ok and "resolutions must match" in rep.results[0].error
    # unwritable output folder (a path under a regular file: fails even as root)
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    rep = process_textures(good, mfp=1.0, output=str(blocker / "sub" / "{stem}.exr"))
    assert not rep.ok and "good.exr" in rep.results[0].error
    # NaN under clamp is counted, not fatal
    rep = process_textures(tmp_path / "nan.exr", mfp=1.0, output=str(out / "{stem}.exr"),
                           on_invalid="clamp")
    assert rep.ok and rep.results[0].invalid["albedo"] == 1


def test_failure_in_a_late_band_leaves_no_file(tmp_path):
    img = albedo_image(3)
    img[-1, -1, 0] = np.inf         # the last band fails after earlier bands were written
    write_image(tmp_path / "late.exr", img, "float", ("R", "G", "B"))
    rep = process_textures(tmp_path / "late.exr", mfp=1.0, output=str(tmp_path / "o.exr"),
                           max_memory=1)
    assert not rep.ok and f"y={H - 1}" in rep.results[0].error
    assert not (tmp_path / "o.exr").exists() and no_partials(tmp_path)


def test_wrong_channel_count_and_alpha_drop(tmp_path):
    write_image(tmp_path / "rgba.exr", albedo_image(4), "float", ("R", "G", "B", "A"))
    rep = process_textures(tmp_path / "rgba.exr", mfp=(1.0, 2.0), output=str(tmp_path / "o.exr"))
    assert not rep.ok and "mfp has 2 values but the albedo has 3 colour channels" in rep.results[0].error
    rep = process_textures(tmp_path / "rgba.exr", mfp=1.0, output=str(tmp_path / "o.exr"),
                           alpha="drop")
    assert rep.ok and "A" not in read(tmp_path / "o.exr")[0].channelnames


def test_skip_existing(tmp_path):
    write_image(tmp_path / "a.exr", albedo_image(3), "float", ("R", "G", "B"))
    kw = dict(mfp=1.0, output=str(tmp_path / "o.exr"), skip_existing=True)
    assert process_textures(tmp_path / "a.exr", **kw).results[0].status == "ok"
    assert process_textures(tmp_path / "a.exr", **kw).results[0].status == "skipped"
    os.utime(tmp_path / "a.exr", (2e9, 2e9))   # input newer than the output
    assert process_textures(tmp_path / "a.exr", **kw).results[0].status == "ok"
    # other settings make another output: rebuilt, never kept as "skipped"
    os.utime(tmp_path / "a.exr", (1e9, 1e9))
    for change in ({"eta": 1.3}, {"mfp": 5.0}, {"outputs": ("rho",)}, {"half": True},
                   {"working_space": "ACEScg"}):
        assert process_textures(tmp_path / "a.exr", **(kw | change)).results[0].status == \
            "ok", change
        assert process_textures(tmp_path / "a.exr", **(kw | change)).results[0].status == \
            "skipped", change


def test_demo_runs(tmp_path, capsys):
    assert cli_main(["demo", "--dir", str(tmp_path / "demo"), "--no-progress"]) == 0
    spec, px = read(tmp_path / "demo" / "coefficients.exr")
    assert "sigma_a.R" in spec.channelnames and np.all(np.isfinite(px))
    assert "1 done, 0 failed" in capsys.readouterr().out
