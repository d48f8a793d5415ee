"""Every invalid input value is named (raise) or clamped and counted (clamp), on every path, and
the counts match what is in the files: one unit (channel values), a NaN never hiding another
bad value, and a masked texel never checked nor counted (it is not inverted nor lit)."""
import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import blur
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.io import scene as scenes
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.channels import classify_channels
from test_bad_inputs import write_exr as write  # (float EXR, channel names)


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    px = np.asarray(inp.read_image(oiio.FLOAT))
    inp.close()
    return dict(zip(spec.channelnames, np.moveaxis(px, -1, 0)))


# {{{ inversion: a NaN in a band, and the mask

def test_a_nan_does_not_hide_a_negative_albedo_in_its_band(tmp_path):
    a = np.full((4, 4, 3), 0.5, np.float32)
    a[1, 3, 0] = -0.1                    # below 0: invalid in a file
    a[1, 0, 2] = np.nan                  # and a NaN in the same band, read first
    write(tmp_path / "a.exr", a)
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1.0, output=str(tmp_path / "o.exr"))
    error = rep.results[0].error      # both counted, the first in array order named
    assert rep.exit_code == 1 and "2 invalid albedo value(s) (below 0" in error, rep.summary()
    assert "x=0, y=1, channel B: nan" in error
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1.0, output=str(tmp_path / "o.exr"),
                           on_invalid="clamp")
    assert rep.exit_code == 0 and counted(rep.results[0]) == {"albedo": 2}, rep.summary()


def counted(row):
    return {k: n for k, n in row.invalid.items() if n}


def mask_scene(tmp_path, albedo, policy):
    write(tmp_path / "a.exr", albedo, ["R", "G", "B", "A"])
    path = tmp_path / "scene.toml"
    path.write_text(f'[defaults]\nmfp = 1.0\nmask = "alpha"\non_invalid = "{policy}"\n'
                    f'[[material]]\nname = "m"\nalbedo = "a.exr"\noutput = "out/m.exr"\n')
    return scenes.load(path).plan().run()


@pytest.mark.parametrize("policy", ["raise", "clamp"])
def test_masked_albedo_is_neither_checked_nor_counted(tmp_path, policy):
    """Below 0 and NaN under the mask (alpha 0): no error, nothing counted, 0 written."""
    a = np.full((8, 8, 4), 0.5, np.float32)
    a[:4, :, 3] = 0                      # rows 0-3 masked
    a[0, 0, 0] = -0.2
    a[1, 1, 1] = np.nan
    rep = mask_scene(tmp_path, a, policy)
    row = rep.results[0]
    assert row.status == "ok" and not any(row.invalid.values()), rep.summary()
    out = read(tmp_path / "out" / "m.exr")
    assert all(np.all(v[:4] == 0) for k, v in out.items() if k != "A")


@pytest.mark.parametrize("policy", ["raise", "clamp"])
def test_a_masked_nan_does_not_hide_a_visible_negative_albedo(tmp_path, policy):
    a = np.full((8, 8, 4), 0.5, np.float32)
    a[:4, :, 3] = 0
    a[0, 0, 0] = np.nan                  # masked: not checked
    a[6, 3, 1] = -0.2                    # visible: invalid
    row = mask_scene(tmp_path, a, policy).results[0]
    if policy == "raise":
        assert row.status == "failed" and "x=3, y=6, channel G" in row.error, row.error
    else:
        assert row.status == "ok" and counted(row) == {"albedo": 1}

# }}}


# {{{ blur: what clamp clamps is counted, on the API, the CLI and a scene's row

def bad_blur_inputs(tmp_path):
    e = np.ones((16, 16, 3), np.float32)
    e[2, 3, 0], e[5, 5, 2] = np.nan, np.inf            # 2 irradiance values
    alb = np.full((16, 16, 3), 0.5, np.float32)
    alb[7, 7, 1], alb[8, 2, 0] = np.nan, 1.5            # 2 albedo values
    mfp = np.full((16, 16, 1), 2.0, np.float32)
    mfp[9, 9, 0] = -2.0                                 # 1 mfp value (one map, 3 channels)
    for name, px in (("irr", e), ("alb", alb), ("mfp", mfp)):
        write(tmp_path / f"{name}.exr", px, ["Y"] if px.shape[2] == 1 else None)
    return e, alb, mfp


def test_blur_api_counts_what_it_clamps(tmp_path):
    e, alb, mfp = bad_blur_inputs(tmp_path)
    out, info = blur(e, albedo=alb, mfp=mfp[..., 0], on_invalid="clamp", return_info=True)
    assert info.invalid == {"irradiance": 2, "albedo": 2, "mfp": 1}
    assert np.all(np.isfinite(out))
    _, info = blur(np.ones((8, 8, 3), np.float32), albedo=0.5, mfp=1.0, return_info=True)
    assert info.invalid == {}


def test_blur_cli_and_scene_count_what_they_clamp(tmp_path, capsys):
    bad_blur_inputs(tmp_path)
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", str(tmp_path / "alb.exr"),
                     "--mfp", str(tmp_path / "mfp.exr"), "--on-invalid", "clamp",
                     "--no-progress", "-o", str(tmp_path / "b.exr")]) == 0
    out = capsys.readouterr().out
    assert "invalid values clamped: " in out, out
    for part in ("irradiance 2", "albedo 2", "mfp 1"):
        assert part in out, out
    # constant parameters: the irradiance's count alone
    assert cli_main(["blur", str(tmp_path / "irr.exr"), "--albedo", "0.5", "--mfp", "2",
                     "--on-invalid", "clamp", "--no-progress",
                     "-o", str(tmp_path / "c.exr")]) == 0
    assert "invalid values clamped: irradiance 2" in capsys.readouterr().out
    path = tmp_path / "scene.toml"
    path.write_text('[[material]]\nname = "m"\nalbedo = "alb.exr"\nmfp = "mfp.exr"\n'
                    'on_invalid = "clamp"\noutput = "m_out.exr"\n'
                    '[[blur]]\nname = "b"\nmaterial = "m"\nirradiance = "irr.exr"\n'
                    'texel_size = 1.0\non_invalid = "clamp"\noutput = "b_out.exr"\n')
    report = scenes.load(path).plan().run()
    rows = {r.output.rsplit("/", 1)[-1]: r for r in report.results}
    assert counted(rows["m_out.exr"]) == {"albedo": 2, "mfp": 1}, report.summary()
    assert rows["b_out.exr"].invalid == {"irradiance": 2, "albedo": 2, "mfp": 1}, \
        report.summary()
    assert "invalid values" in report.summary()


def test_a_masked_nan_irradiance_is_unlit_not_an_error(tmp_path):
    """A scene blur's mask (its material's alpha) makes masked texels unlit, whatever they
    hold: NaN * 0 is NaN, so they are set to 0, not multiplied."""
    e = np.ones((16, 16, 3), np.float32)
    e[3, 3, 1] = np.nan                                 # under the mask
    write(tmp_path / "irr.exr", e)
    a = np.full((16, 16, 4), 0.5, np.float32)
    a[:8, :, 3] = 0                                     # rows 0-7 masked
    write(tmp_path / "alb.exr", a, ["R", "G", "B", "A"])
    path = tmp_path / "scene.toml"
    path.write_text('[[material]]\nname = "m"\nalbedo = "alb.exr"\nmfp = 1.0\nmask = "alpha"\n'
                    'output = "m_out.exr"\n[[blur]]\nname = "b"\nmaterial = "m"\n'
                    'irradiance = "irr.exr"\ntexel_size = 1.0\noutput = "b_out.exr"\n')
    report = scenes.load(path).plan().run()
    row = next(r for r in report.results if r.output.endswith("b_out.exr"))
    assert row.status == "ok" and not row.invalid, report.summary()
    out = read(tmp_path / "b_out.exr")
    assert all(np.all(out[c][:8] == 0) and np.all(np.isfinite(out[c])) for c in "RGB")

# }}}


# {{{ channels: an unlayered X, Y, Z is no luminance

@pytest.mark.parametrize("names", [("X", "Y", "Z"), ("X", "Y"), ("X", "Y", "Z", "A")])
def test_unlayered_xyz_has_no_colour_channel(tmp_path, names):
    assert classify_channels(names)[0] == []
    write(tmp_path / "v.exr", np.full((4, 4, len(names)), 0.5), names)
    rep = process_textures(str(tmp_path / "v.exr"), mfp=1.0, output=str(tmp_path / "o.exr"))
    assert rep.exit_code == 1 and "no colour channel" in rep.results[0].error
    assert not (tmp_path / "o.exr").exists()


def test_unlayered_y_beside_depth_z_is_still_a_luminance():
    assert classify_channels(("Y", "Z")) == ([0], -1, [1])
    assert classify_channels(("R", "G", "B", "A", "X"))[:2] == ([0, 1, 2], 3)

# }}}


# {{{ the API: a mask or an imaginary part is never dropped in silence

@pytest.mark.parametrize("call", [
    lambda rd: __import__("bdipole_cl").invert_albedo(rd, 1.4),
    lambda rd: __import__("bdipole_cl").albedo_to_coefficients(rd, 1.0, 1.4),
    lambda rd: blur(rd, albedo=0.5, mfp=1.0)])
def test_masked_and_complex_arrays_are_refused_by_every_function(call):
    masked = np.ma.array(np.full((4, 4, 3), 0.5), mask=np.zeros((4, 4, 3), bool))
    masked.mask[1, 1, 0] = True
    with pytest.raises(ValueError, match="masked array with 1 masked value"):
        call(masked)
    with pytest.raises(ValueError, match="dtype complex128: expected real numbers"):
        call(np.full((4, 4, 3), 0.5 + 0.1j))
    call(np.ma.array(np.full((4, 4, 3), 0.5)))     # nothing masked: as the plain array

# }}}


def test_a_convert_colour_count_says_each_rule_it_covers(tmp_path, capsys):
    # one colour outside [0, 1] and two out of Cycles' walk's reach (~0.91 at eta 1.4): the
    # count (3) was given the first rule's reason alone, "(NaN, infinite or outside [0, 1])"
    a = np.full((2, 3, 3), 0.5, np.float32)
    a[0, 0, 0], a[0, 1, 1], a[1, 1, 2] = 1.5, 0.95, 0.97
    write(tmp_path / "c.exr", a, ("R", "G", "B"))
    assert cli_main(["convert", str(tmp_path / "c.exr"), "--radius", "1", "--target",
                     "cycles-random-walk"]) == 1
    out = capsys.readouterr().out
    assert ("3 invalid colour value(s) (1 NaN, infinite or outside [0, 1], 2 a reflectance "
            "cycles-random-walk does not render)") in out, out
