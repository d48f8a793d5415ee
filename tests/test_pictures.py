"""Pictures: ``bdipole-cl preview`` (contact sheets), ``bdipole-cl profile`` and ``bake
--preview``, checked against the files and the physics they were drawn from."""
import os

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import reference as ref
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import make_scene
from bdipole_cl.apps.preview import DPI, TILE_IN, contact_sheet
from bdipole_cl.apps.profile import constant_specs, profile_plot

matplotlib = pytest.importorskip("matplotlib")
from matplotlib import image as mpimg  # noqa: E402


def write_with_header(path, px, names, header):
    spec = oiio.ImageSpec(px.shape[1], px.shape[0], px.shape[2], "float")
    spec.channelnames = tuple(names)
    if "A" in names:
        spec.alpha_channel = names.index("A")
    for k, v in header.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(px, np.float32))
    out.close()


def bdipole_like(path):
    """A bdipole-like output: sigma_a over four decades, rho varying, a constant alpha'
    group and an alpha channel; (channel names, pixels)."""
    h, w = 48, 80
    x = np.linspace(0.0, 1.0, w)[None, :].repeat(h, 0)
    y = np.linspace(0.0, 1.0, h)[:, None].repeat(w, 1)
    sigma_a = np.stack([1e-3 * 10 ** (4 * x), 1e-2 * 10 ** (2 * y), 0.05 + 0 * x], -1)
    rho = (0.2 + 0.5 * x * y)[..., None]
    alpha = np.full((h, w, 1), 0.75)
    a = (x < 0.8)[..., None].astype(float)
    names = ["sigma_a.R", "sigma_a.G", "sigma_a.B", "rho.Y", "alpha.Y", "A"]
    px = np.concatenate([sigma_a, rho, alpha, a], -1)
    write_with_header(path, px, names, {
        "bdipole:model": "better", "bdipole:eta": "1.4", "bdipole:mfp": "1.2,0.6,0.3",
        "bdipole:unit": "mm", "bdipole:coefficient_unit": "1/mm",
        "bdipole:method": "table(size=8, polish=0)", "bdipole:tol": "0.0001",
        "oiio:ColorSpace": "lin_rec709_scene"})
    return names, px.astype(np.float32)


def read_exr(path):
    buf = oiio.ImageBuf(str(path))
    return list(buf.spec().channelnames), buf.get_pixels(oiio.FLOAT)


def read_png(path):
    img = mpimg.imread(str(path))
    return img[..., :3]


def test_contact_sheet_size_tiles_and_scales(tmp_path):
    bdipole_like(tmp_path / "out.exr")
    names, px = read_exr(tmp_path / "out.exr")        # in the file's (sorted) order
    sheet = contact_sheet(tmp_path / "out.exr", tmp_path / "sheet.png")
    img = read_png(tmp_path / "sheet.png")
    # four groups on a 3-column grid: 2 rows; each tile TILE_IN inches at DPI, + 0.9 in of
    # title and caption
    want = (round(3 * TILE_IN[0] * DPI), round((2 * TILE_IN[1] + 0.9) * DPI))
    assert sheet.size == want and img.shape[:2] == (want[1], want[0]), (sheet.size, img.shape)
    by_name = {t.group.name: t for t in sheet.tiles}
    assert set(by_name) == {"sigma_a", "rho", "alpha", "alpha channel"}
    for t in sheet.tiles:
        x0, y0, x1, y1 = t.bbox
        inner = img[y0 + 3:y1 - 3, x0 + 3:x1 - 3]          # inside the frame
        data = px[..., list(t.group.channels)]
        varies = bool(np.ptp(data) > 0)
        assert t.varies == varies, t.group.name
        if varies:
            assert inner.std() > 0.05, (t.group.name, inner.std())
        else:
            assert np.ptp(inner) == 0, (t.group.name, np.ptp(inner))
    sa = by_name["sigma_a"]
    assert sa.group.names == ("sigma_a.R", "sigma_a.G", "sigma_a.B")   # shown as R, G, B
    values = px[..., [names.index(n) for n in sa.group.names]]
    assert sa.log and sa.bar_scale == "log"
    assert sa.bar_limits == pytest.approx((values.min(), values.max()), rel=1e-6)
    assert by_name["rho"].bar_scale == "linear" and not by_name["rho"].log
    rho = px[..., names.index("rho.Y")]
    assert by_name["rho"].bar_limits == pytest.approx((rho.min(), rho.max()), rel=1e-6)
    for text in ("model better", "eta 1.4", "mfp 1.2,0.6,0.3 mm",
                 "working space lin_rec709_scene", "method table(size=8, polish=0)",
                 "tol 0.0001"):
        assert text in sheet.caption, (text, sheet.caption)


def test_any_exr_is_grouped_by_its_channel_names(tmp_path, capsys):
    px = np.random.default_rng(0).uniform(0.0, 1.0, (20, 30, 5))
    write_with_header(tmp_path / "any.exr", px, ["diffuse.R", "diffuse.G", "diffuse.B", "Z",
                                                 "A"], {})
    assert cli_main(["preview", str(tmp_path / "any.exr")]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "any.preview.png").is_file()
    sheet = contact_sheet(tmp_path / "any.exr", tmp_path / "any.png")
    assert sorted(t.group.name for t in sheet.tiles) == ["Z", "alpha channel", "diffuse"], out
    assert not any(t.log for t in sheet.tiles), out       # values in [0, 1]: linear
    assert sheet.caption == "(no bdipole parameters in the header)"


def test_preview_of_a_missing_file_is_one_line(tmp_path, capsys):
    assert cli_main(["preview", str(tmp_path / "none.exr")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "none.exr" in err and "no such file" in err


@pytest.mark.parametrize("tol", [1e-3, 1e-5])
def test_profile_curve_passes_through_R_at_the_marked_radius(tmp_path, tol):
    specs = constant_specs((0.8, 0.5, 0.2), (1.2, 0.6, 0.3), (1.4,))
    plot = profile_plot(specs, tmp_path / "p.png", tol=tol)
    assert read_png(tmp_path / "p.png").shape[:2] == (plot.size[1], plot.size[0]) == (460, 1100)
    for c, (rd, mfp) in zip(plot.channels, ((0.8, 1.2), (0.5, 0.6), (0.2, 0.3))):
        # independently of the plot: the coefficients the inversion gives this albedo and mfp
        sa, ss = ref.albedo_to_coefficients(rd, mfp, 1.4)
        alpha, sigma_t = ss / (sa + ss), sa + ss
        r_mark, R_mark = c.mark
        want = float(ref.profile(r_mark, alpha, sigma_t, 1.4))
        # the drawn curve, read at the marked radius (log-log interpolation of its points)
        on_curve = np.exp(np.interp(np.log(r_mark), np.log(c.r), np.log(c.R)))
        assert on_curve == pytest.approx(want, rel=1e-9), (c.spec.name, on_curve, want)
        assert R_mark == pytest.approx(want, rel=1e-12)
        # the mark is the truncation radius: the energy beyond it is tol of Rd (bisection
        # to 60 halvings: the tail lands on tol within 1e-6 relative)
        tail = ref.profile_tail(r_mark, alpha, sigma_t, 1.4) / ref.profile_tail(0.0, alpha,
                                                                               sigma_t, 1.4)
        assert tol * (1 - 1e-6) <= tail <= tol, (c.spec.name, tail)
        assert r_mark > mfp                                # R(r) is drawn past the mfp
        assert c.r.min() < mfp < c.r.max()
    assert plot.shaded == pytest.approx((0.2, 0.8))
    assert plot.rd[1.4] == pytest.approx(ref.rd(plot.alpha, 1.4))


def test_profile_of_a_scene_material_and_svg(tmp_path, capsys, on_device):
    scene = make_scene(tmp_path / "scene", size=32)
    rc = cli_main(["profile", "--scene", str(scene), "--material", "skin",
                   "-o", str(tmp_path / "skin.svg")])
    assert rc == 0, capsys.readouterr()
    text = (tmp_path / "skin.svg").read_text()
    assert text.lstrip().startswith("<?xml") and "<svg" in text
    from bdipole_cl.apps.profile import material_specs
    specs, unit, tol = material_specs(scene, "skin")
    assert unit == "mm" and tol == 1e-4 and [s.name for s in specs] == ["R", "G", "B"]
    for s in specs:            # mean inside the range of the unmasked (island) texels
        lo, hi = s.albedo_range
        assert 0.2 < lo < s.albedo < hi < 0.9, s
    rc = cli_main(["profile", "--scene", str(scene), "--material", "nope"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "skin, marble" in err


def test_bake_preview_writes_a_sheet_per_job_and_a_page(tmp_path, capsys, on_device):
    scene = make_scene(tmp_path / "scene", size=32)
    assert cli_main(["bake", str(scene), "--preview", "--no-progress"]) == 0
    out = capsys.readouterr().out
    sheets = sorted(p.name for p in (tmp_path / "scene" / "out").glob("*.preview.png"))
    exrs = sorted(p.name for p in (tmp_path / "scene" / "out").glob("*.exr"))
    assert sheets == [e.replace(".exr", ".preview.png") for e in exrs] and len(exrs) == 5, out
    page = read_png(tmp_path / "scene" / "scene.preview.png")
    # two materials (rows); skin's row holds 4 thumbnails: alpha, sigma_a, sigma_s, exitance
    assert page.shape[:2] == (round((2 * 2.9 + 0.5) * 100), round((4 * 2.4 + 5.0) * 100))
    assert page.std() > 0.05


def test_without_matplotlib_the_pictures_say_which_install(tmp_path, capsys, monkeypatch):
    import sys
    write_with_header(tmp_path / "a.exr", np.ones((4, 4, 1)), ["Y"], {})
    monkeypatch.setitem(sys.modules, "matplotlib", None)     # import matplotlib fails
    assert cli_main(["preview", str(tmp_path / "a.exr")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'matplotlib" in err, err


def test_preview_of_a_texture_output_reads_level_0(tmp_path, on_device):
    from bdipole_cl.io.batch import process_textures
    write_with_header(tmp_path / "a.exr", np.random.default_rng(2).uniform(
        0.1, 0.9, (40, 70, 3)), ["R", "G", "B"], {})
    rep = process_textures(str(tmp_path / "a.exr"), mfp=1.0, output=str(tmp_path / "t.exr"),
                           outputs=("rho",), texture=True)
    assert rep.exit_code == 0, rep.summary()
    sheet = contact_sheet(tmp_path / "t.exr", tmp_path / "t.png")
    (tile,) = sheet.tiles
    _, px = read_exr(tmp_path / "a.exr")
    rho = ref.invert_rd_rho(px.astype(np.float64), 1.4)[1]
    # the range drawn is level 0's (a coarser mip level's box averages would narrow it)
    assert (tile.vmin, tile.vmax) == pytest.approx((rho.min(), rho.max()), rel=2e-4)


@pytest.mark.parametrize("option, value", [("--albedo", "1.5"), ("--albedo", "1"),
                                           ("--albedo", "0"), ("--albedo", "-1"),
                                           ("--albedo", "0.5,nan,0.5"), ("--mfp", "0")])
def test_profile_constants_out_of_range_are_usage_errors(tmp_path, capsys, option, value):
    """profile takes the constants blur takes (an albedo in (0, 1), an mfp the kernels can
    take): another is a one-line usage error naming the option and value, never clamped
    into a plot of something else, nor an error of NumPy's."""
    args = {"--albedo": "0.5", "--mfp": "1", option: value}
    with pytest.raises(SystemExit) as usage:
        cli_main(["profile", *[x for kv in args.items() for x in kv],
                  "-o", str(tmp_path / "p.png")])
    err = capsys.readouterr().err
    assert usage.value.code == 2 and option in err and repr(value) in err, err
    assert not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("shape, names", [((300, 1, 3), ("R", "G", "B")),
                                          ((3, 4097, 3), ("R", "G", "B")),
                                          ((40, 30, 4), ("P.x", "P.y", "P.z", "P.w")),
                                          ((20, 20, 3), ("R", "G", "B"))])
def test_strips_wide_groups_and_dollar_names_are_drawn(tmp_path, shape, names):
    """A 300 x 1 or 3 x 4097 strip (a reshape of size 0 failed it), a group of 4 channels (its
    first three drawn, the fourth named: a negative pad failed it), a name with '$' pairs
    (parsed as mathtext: it failed) all draw; their edge texels are kept."""
    px = np.linspace(0.1, 0.9, int(np.prod(shape)), dtype=np.float32).reshape(shape)
    path = tmp_path / ("cost$_{x$.exr" if shape == (20, 20, 3) else "in.exr")
    write_with_header(path, px, names, {})
    sheet = contact_sheet(path, tmp_path / "in.png")
    tile, = sheet.tiles
    assert tile.vmin == pytest.approx(px[..., :len(tile.group.channels)].min(), rel=1e-6)
    assert tile.vmax == pytest.approx(px[..., :len(tile.group.channels)].max(), rel=1e-6)
    assert read_png(tmp_path / "in.png").shape[2] in (3, 4)


def test_texels_that_are_not_finite_are_shown_and_counted(tmp_path):
    """One NaN and one inf texel in a 1500^2 map: drawn magenta and counted in the caption
    (they vanished into a caption of 'constant 0.5')."""
    from bdipole_cl.apps.preview import NOT_FINITE_RGB
    px = np.full((1500, 1500, 3), 0.5, np.float32)
    px[10, 10, 0], px[1400, 700, 1] = np.nan, np.inf
    write_with_header(tmp_path / "in.exr", px, ("R", "G", "B"), {})
    sheet = contact_sheet(tmp_path / "in.exr", tmp_path / "in.png")
    tile, = sheet.tiles
    assert (tile.image == NOT_FINITE_RGB).all(axis=-1).sum() == 2
    assert "2 texels not finite (magenta)" in tile.label


def test_a_scene_materials_profile_is_its_bake_and_never_replaces_its_input(tmp_path, capsys,
                                                                          monkeypatch, on_device):
    """profile --scene draws the material as its bake reads it: mfp_scale applied, an
    extinction mfp as 1/sigma_t', Jensen's dipole inverted as such (all four plotted the plain
    material's sigma_t'); -o on its own albedo is refused, --force or not (it was replaced); a
    material name that is a path is no path for the default output."""
    from bdipole_cl.apps.profile import material_specs
    from bdipole_cl.ops.invert import albedo_to_coefficients
    px = np.full((8, 8, 3), 0.5, np.float32)
    write_with_header(tmp_path / "a.exr", px, ("R", "G", "B"), {})
    (tmp_path / "s.toml").write_text("".join(
        f'[[material]]\nname = "{n}"\nalbedo = "a.exr"\nmfp = 1.0\n{extra}\n'
        f'output = "out/{n}.exr"\n' for n, extra in (
            ("plain", ""), ("scaled", "mfp_scale = 10"),
            ("ext", 'mfp_kind = "extinction"'), ("jensen", 'model = "dipole"'))))
    for name, kind, model, scale in (("plain", "diffuse", "better", 1), ("scaled", "diffuse",
                                     "better", 10), ("ext", "extinction", "better", 1),
                                     ("jensen", "diffuse", "dipole", 1)):
        specs, _, _ = material_specs(tmp_path / "s.toml", name)
        plot = profile_plot(specs, tmp_path / f"{name}.png")
        sa, ss = albedo_to_coefficients(np.float32(0.5), 1.0 * scale, 1.4, mfp_kind=kind,
                                        model=model)
        assert plot.channels[0].sigma_t == pytest.approx(float(sa + ss), rel=1e-4), name
    from PIL import Image
    Image.fromarray(np.full((8, 8, 3), 128, np.uint8)).save(tmp_path / "albedo.png")
    before = (tmp_path / "albedo.png").read_bytes()
    (tmp_path / "t.toml").write_text('[[material]]\nname = "../m"\nalbedo = "albedo.png"\n'
                                     'mfp = 1.0\noutput = "out/m.exr"\n')
    for extra in ([], ["--force"]):
        rc = cli_main(["profile", "--scene", str(tmp_path / "t.toml"), "--material", "../m",
                       "-o", str(tmp_path / "albedo.png")] + extra)
        assert rc == 2 and "would overwrite an input" in capsys.readouterr().err
    assert (tmp_path / "albedo.png").read_bytes() == before
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    assert cli_main(["profile", "--scene", str(tmp_path / "t.toml"), "--material", "../m"]) == 0
    assert os.listdir(tmp_path / "cwd") == [".._m.profile.png"]


def test_lab_channels_are_one_colour_group_not_alpha_and_blue(tmp_path):
    """L, a, b (and Y, RY, BY) are one colour model: one group in that order (a was drawn as
    the alpha channel and b as blue, the misreading the inverter refuses)."""
    from bdipole_cl.apps.preview import channel_groups
    groups = channel_groups(("L", "a", "b"))
    assert [(g.name, g.names) for g in groups] == [("L/a/b", ("L", "a", "b"))]
    groups = channel_groups(("BY", "RY", "Y"))
    assert [(g.name, g.names) for g in groups] == [("Y/RY/BY", ("Y", "RY", "BY"))]
    assert [g.names for g in channel_groups(("B", "G", "R", "A"), 3)] == [("R", "G", "B"),
                                                                          ("A",)]


#: four 8x8 blocks of codes 0, 64, 128, 255 (constant blocks: a JPEG keeps them)
CODES = np.kron(np.array([[0, 64], [128, 255]]), np.ones((8, 8)))


def srgb_encoded(linear):
    """IEC 61966-2-1's encoding, written here (an independent check of the preview's)."""
    linear = np.asarray(linear, np.float64)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(np.maximum(linear, 0), 1 / 2.4) - 0.055)


@pytest.mark.parametrize("name, fmt, attribs, encoded", [
    ("a.png", "uint8", {}, True),                     # 8-bit PNG (declared sRGB by its reader)
    ("a.tif", "uint8", {}, True),                     # 8-bit TIFF, undeclared: sRGB
    ("a.jpg", "uint8", {}, True),                     # 8-bit JPEG
    ("b.png", "uint16", {}, True),                    # 16-bit PNG: declared sRGB
    ("b.tif", "uint16", {}, False),                   # 16-bit TIFF, undeclared: linear
    ("a.exr", "half", {}, False),                     # EXR, undeclared: linear
    ("s.exr", "float", {"oiio:ColorSpace": "srgb_rec709_scene"}, True),   # EXR declared sRGB
    ("l.png", "uint8", {"oiio:ColorSpace": "lin_rec709_scene"}, False),   # 8-bit declared linear
], ids=["png8", "tif8", "jpg8", "png16", "tif16", "exr", "exr-srgb", "png8-linear"])
def test_a_colour_is_shown_with_its_encoding_once(tmp_path, name, fmt, attribs, encoded):
    """Each texel of a file's colour is shown as its encoded value, once: an sRGB file's
    code 128 as 128 (it was shown as 0.737: decoded as linear, then encoded for display), a
    linear file's value sRGB-encoded; as the tools read the file (its declaration, else the
    8-bit rule)."""
    path = tmp_path / name
    spec = oiio.ImageSpec(16, 16, 3, fmt)
    for k, v in attribs.items():
        spec.attribute(k, v)
    scale = {"uint8": 255, "uint16": 65535}.get(fmt)
    stored = CODES / 255.0
    data = np.repeat((np.round(stored * scale) if scale else stored)[..., None], 3, -1)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(data.astype({"uint8": np.uint8, "uint16": np.uint16}.get(
        fmt, np.float32)))
    out.close()
    back = oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)       # as stored (a JPEG's own)
    sheet = contact_sheet(path, tmp_path / "sheet.png")
    tile, = sheet.tiles
    assert not tile.log and tile.vmin == pytest.approx(0, abs=2e-3), tile
    want = back if encoded else srgb_encoded(back)
    # one float32 decode (OpenColorIO) and encode (the preview's) of 8-bit steps: 1e-4
    np.testing.assert_allclose(tile.image, want, atol=1e-4, err_msg=name)
    mid = tile.image[12, 4]                     # the 128 block
    assert abs(mid[0] - (128 / 255 if encoded else srgb_encoded(128 / 255))) < 2e-3, mid
