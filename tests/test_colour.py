"""Colour management (bdipole_cl/io/colour.py): the albedo inverted is the file's colour in the
working space, as an independent colour library (colour-science) converts it, and every output
is tagged with the working space. docs/colour.md; docs/model.md "Colour"."""
import os
import subprocess
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import reference as ref
from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.io import colour as cm
from bdipole_cl.io import icc
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.blur_file import blur_file

from conftest import short_id

with warnings.catch_warnings():
    warnings.simplefilter("ignore")      # colour-science warns about optional packages
    import colour as colour_science

W, H = 8, 6
ETA = 1.4
#: |albedo inverted - independent conversion|. What it covers: OpenColorIO (float32, lossless
#: optimisation) against colour-science (float64): matrices ~2e-7 (measured), and the sRGB
#: curve's linear segment, which OCIO joins continuously (slope 12.9232, break 0.0392857)
#: where IEC 61966-2-1 and colour-science use the rounded 12.92 and 0.04045: 7.5e-7 at the
#: 8-bit level 10 (derived: (1/12.92 - 1/12.9232) * 10/255). The inversion is float64
#: (double=True, 1e-12) and the rho written as float32 moves Rd(rho) by < 1e-8 (measured).
TOL = 1e-6
#: the colour-science names of the spaces of the tests (the config's names are the keys)
SCIENCE = {"lin_rec709_scene": "ITU-R BT.709", "ACEScg": "ACEScg",
           "lin_rec2020_scene": "ITU-R BT.2020"}
#: the config's own names (ocio://default) of the test spaces
CANONICAL = {"lin_rec709_scene": "Linear Rec.709 (sRGB)", "ACEScg": "ACEScg",
             "lin_rec2020_scene": "Linear Rec.2020", "srgb": "sRGB Encoded Rec.709 (sRGB)"}


@pytest.fixture(autouse=True)
def _built_in_config(monkeypatch):
    """Every test starts from the built-in config (no $OCIO), and leaves none cached."""
    monkeypatch.delenv("OCIO", raising=False)
    cm.reset_config_cache()
    yield
    cm.reset_config_cache()


def chromaticities_of(space):
    """(xR, yR, xG, yG, xB, yB, xW, yW) of a space, from colour-science."""
    cs = colour_science.RGB_COLOURSPACES[SCIENCE[space]]
    return tuple(np.concatenate([cs.primaries.ravel(), cs.whitepoint]).tolist())


def independent(rgb, source, target):
    """``rgb`` (linear, float64) from ``source`` to ``target`` by colour-science (Bradford
    adaptation between white points, as the ACES configs do)."""
    if source == target:
        return rgb
    return colour_science.RGB_to_RGB(rgb, colour_science.RGB_COLOURSPACES[SCIENCE[source]],
                                     colour_science.RGB_COLOURSPACES[SCIENCE[target]],
                                     chromatic_adaptation_transform="Bradford")


def albedo_in(seed=0, lo=0.001):
    """Linear albedos, near-neutral (grey lo-0.6, log-uniform, channels +-20%), so that they
    stay valid (0 < Rd < 1) in every space of the tests; lo = 0.001 reaches the sRGB curve's
    linear segment (8-bit levels below 10)."""
    rng = np.random.default_rng(seed)
    grey = np.exp(rng.uniform(np.log(lo), np.log(0.6), (H, W, 1)))
    return grey * rng.uniform(0.8, 1.2, (H, W, 3))


def write(path, pixels, fmt, channels=("R", "G", "B"), attrs=()):
    spec = oiio.ImageSpec(W, H, len(channels), fmt)
    spec.channelnames = tuple(channels)
    if "A" in channels:
        spec.alpha_channel = channels.index("A")
    for name, value in attrs:
        if name == "chromaticities":
            spec.attribute(name, oiio.TypeDesc("float[8]"), value)
        else:
            spec.attribute(name, value)
    data = {"uint8": lambda p: np.round(p * 255).astype(np.uint8),
            "uint16": lambda p: np.round(p * 65535).astype(np.uint16)}.get(
        fmt, lambda p: np.asarray(p, np.float32))(pixels)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.ascontiguousarray(data)), out.geterror()
    out.close()


def read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    px = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT), np.float64)
    inp.close()
    return spec, px.reshape(spec.height, spec.width, spec.nchannels)


def rho_channels(spec, px, names=("R", "G", "B")):
    return np.stack([px[..., list(spec.channelnames).index(f"rho.{c}")] for c in names], -1)


@dataclass(frozen=True)
class Case:
    ext: str
    fmt: str                      # how the file stores texels
    space: str                    # the space its texels are written in (a key of SCIENCE)
    srgb: bool                    # encoded with the sRGB curve (8-bit)
    attrs: tuple                  # how the file declares it
    working: str | None           # working_space= (None: the default, lin_rec709_scene)
    colorspace: str = "auto"
    how: str = "declared"         # what the colour path says
    encoding: str = ""

    @property
    def source(self):             # the config's name of the space the file is read as
        if self.how == "default" and not self.srgb:
            return CANONICAL[self.working or "lin_rec709_scene"]
        return CANONICAL["srgb" if self.srgb else self.space]


def by_name(space):
    return (("oiio:ColorSpace", space),)


def by_chromaticities(space):
    return (("chromaticities", chromaticities_of(space)),)


CASES = [
    pytest.param(Case("png", "uint8", "lin_rec709_scene", True, (), "ACEScg",
                      encoding="8-bit"), id="png-8bit-srgb-to-acescg"),
    pytest.param(Case("png", "uint8", "lin_rec709_scene", True, (), None, encoding="8-bit"),
                 id="png-8bit-srgb-to-default"),
    pytest.param(Case("tif", "uint16", "ACEScg", False, (), "ACEScg", how="default",
                      encoding="16-bit"), id="tif-16bit-untagged-is-working"),
    pytest.param(Case("tif", "uint16", "lin_rec2020_scene", False, (), "ACEScg",
                      colorspace="lin_rec2020_scene", how="given", encoding="16-bit"),
                 id="tif-16bit-given-rec2020"),
    pytest.param(Case("exr", "half", "ACEScg", False, by_name("ACEScg"), None,
                      encoding="half"), id="exr-half-acescg-by-name"),
    pytest.param(Case("exr", "float", "ACEScg", False, by_name("ACEScg"), "lin_rec2020_scene",
                      encoding="float"), id="exr-float-acescg-by-name"),
    pytest.param(Case("exr", "half", "ACEScg", False, by_chromaticities("ACEScg"), None,
                      how="chromaticities", encoding="half"),
                 id="exr-half-acescg-by-chromaticities"),
    pytest.param(Case("exr", "float", "lin_rec709_scene", False, by_name("lin_rec709_scene"),
                      "ACEScg", encoding="float"), id="exr-float-rec709-by-name"),
    pytest.param(Case("exr", "half", "lin_rec709_scene", False,
                      by_chromaticities("lin_rec709_scene"), "ACEScg", how="chromaticities",
                      encoding="half"), id="exr-half-rec709-by-chromaticities"),
    pytest.param(Case("exr", "half", "lin_rec2020_scene", False,
                      by_name("lin_rec2020_scene"), "ACEScg", encoding="half"),
                 id="exr-half-rec2020-by-name"),
    pytest.param(Case("exr", "float", "lin_rec2020_scene", False,
                      by_chromaticities("lin_rec2020_scene"), "ACEScg", how="chromaticities",
                      encoding="float"), id="exr-float-rec2020-by-chromaticities"),
    pytest.param(Case("exr", "float", "ACEScg", False, (), "ACEScg", how="default",
                      encoding="float"), id="exr-float-untagged-is-working"),
]


def stored_linear(case, stored):
    """The file's texels as linear values of ``case.space`` (independently of OCIO)."""
    if case.srgb:
        return colour_science.cctf_decoding(stored, function="sRGB")
    return stored


def check_tags(spec, working):
    """The output says it is in ``working`` (oiio:ColorSpace, chromaticities, bdipole:*)."""
    ws = cm.resolve_working_space(working)
    assert ws.config.space(spec.getattribute("oiio:ColorSpace")) == ws.name, \
        (spec.getattribute("oiio:ColorSpace"), ws.name)
    assert spec.getattribute("bdipole:working_space") == ws.name
    assert spec.getattribute("bdipole:ocio_config") == ws.config.name
    return ws


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("case", CASES)
def test_albedo_inverted_in_the_working_space(tmp_path, case):
    lin = albedo_in()
    enc = colour_science.cctf_encoding(lin, function="sRGB") if case.srgb else lin
    path = tmp_path / f"albedo.{case.ext}"
    write(path, enc, case.fmt, attrs=case.attrs)
    _, stored = read(path)                          # the texels as stored (quantised)
    report = process_textures(path, mfp=1.0, eta=ETA, outputs=("rho",), double=True,
                              working_space=case.working, colorspace=case.colorspace,
                              output=str(tmp_path / "{stem}_out.exr"))
    assert report.ok, report.summary()
    spec, px = read(tmp_path / "albedo_out.exr")
    inverted = ref.rd_of_rho(rho_channels(spec, px), ETA)
    target = case.working or "lin_rec709_scene"
    want = independent(stored_linear(case, stored), case.space, target)
    err = float(np.max(np.abs(inverted - want)))
    print(f"{case.encoding} {case.space} {case.how} -> {target}: max |albedo - colour-science| "
          f"= {err:.2e}")
    assert err <= TOL, (err, case)
    ws = check_tags(spec, case.working)
    assert spec.getattribute("chromaticities") == pytest.approx(chromaticities_of(target),
                                                                abs=1e-7)
    assert spec.getattribute("bdipole:albedo_colorspace") == case.source
    path_text = f"{case.source} ({case.encoding}, {case.how}) -> {ws.name}, config ocio://default"
    assert report.results[0].colour == path_text and path_text in report.summary()


def test_default_working_space_and_config():
    ws = cm.resolve_working_space()
    assert (ws.name, ws.config.name, ws.config.source) == ("Linear Rec.709 (sRGB)",
                                                          "ocio://default", "built-in")
    for alias in ("lin_rec709_scene", "lin_rec709", "Linear Rec.709 (sRGB)", "linear"):
        assert cm.resolve_working_space(alias) == ws, alias
    assert cm.resolve_working_space("lin_ap1_scene").name == "ACEScg"
    assert cm.resolve_working_space("scene_linear").name == "ACEScg"   # the config's role
    # docs/colour.md's example: one sRGB texel in two working spaces (and colour-science agrees)
    texel = np.array([[[0.8, 0.2, 0.1]]], np.float32)
    spec = oiio.ImageSpec(1, 1, 3, "uint8")
    for space, want in (("lin_rec709_scene", (0.604, 0.033, 0.010)),
                        ("ACEScg", (0.382, 0.073, 0.025))):
        got = cm.colour_path(spec, "texel.png", working=space).convert(texel, ("R", "G", "B"))
        lin = colour_science.cctf_decoding(texel.astype(np.float64), function="sRGB")
        assert np.max(np.abs(got - independent(lin, "lin_rec709_scene", space))) < 1e-6
        np.testing.assert_allclose(got.ravel(), want, atol=5e-4)


@pytest.mark.parametrize("argv,message", [
    (["--working-space", "foo", "devices"], "working space 'foo' is unknown to OCIO config "
                                            "ocio://default; known: CIE XYZ-D65"),
    (["devices", "--working-space", "sRGB"], "working space 'sRGB' (sRGB Encoded Rec.709 (sRGB)) "
                                             "is not scene-linear"),
    (["invert", "x.exr", "--colorspace", "bogus"], "colorspace 'bogus' is unknown to OCIO "
                                                  "config ocio://default; known: auto, "),
    (["blur", "x.exr", "-o", "y.exr", "--colorspace", "nope"], "colorspace 'nope' is unknown "
                                                               "to OCIO config ocio://default"),
    (["plan", "scene.toml", "--working-space", "nope"], "working space 'nope' is unknown"),
    (["--working-space", "", "devices"], "an empty name; give a colour space of the config, "
                                         "e.g. ACEScg"),
], ids=["unknown-working-space", "non-linear-working-space", "unknown-colorspace",
        "blur-unknown-colorspace", "plan-unknown-working-space", "empty-working-space"])
def test_unknown_names_are_one_line_usage_errors(capsys, argv, message):
    try:
        code = cli_main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and "ACEScg" in err and err.count("\n") == 1, err


CONFIG = """ocio_profile_version: 2

roles:
  default: lin_rec709
  scene_linear: studio_wide
  data: raw

file_rules:
  - !<Rule> {{name: Default, colorspace: default}}

colorspaces:
  - !<ColorSpace>
    name: lin_rec709
    aliases: [lin_rec709_scene]
    isdata: false

  - !<ColorSpace>
    name: studio_wide
    isdata: false
    to_scene_reference: !<MatrixTransform> {{matrix: [{m}]}}

  - !<ColorSpace>
    name: srgb_texture
    aliases: [srgb_rec709_scene]
    isdata: false
    from_scene_reference: !<ExponentWithLinearTransform>
      gamma: 2.4
      offset: 0.055
      direction: inverse

  - !<ColorSpace>
    name: raw
    isdata: true
"""
#: the custom config's studio_wide -> lin_rec709 matrix (rows sum to 1: white stays white);
#: its inverse's rows have absolute sums <= 1.2, so the sRGB curves' 7.5e-7 stays within TOL
WIDE_TO_709 = np.array([[0.9, 0.07, 0.03], [0.05, 0.9, 0.05], [0.02, 0.05, 0.93]])


def write_config(folder):
    m4 = np.eye(4)
    m4[:3, :3] = WIDE_TO_709
    path = Path(folder) / "studio.ocio"
    path.write_text(CONFIG.format(m=", ".join(f"{v:g}" for v in m4.ravel())))
    return path


def to_wide(lin709):
    """Linear Rec.709 into studio_wide, independently: the inverse of the config's matrix."""
    return lin709 @ np.linalg.inv(WIDE_TO_709).T


@pytest.mark.usefixtures("on_device")
def test_custom_config_from_env(tmp_path, monkeypatch):
    """$OCIO names a studio config: its scene_linear role is the default working space, its
    aliases name the spaces of the files; outputs carry its space by name (no chromaticities:
    the config does not give primaries)."""
    monkeypatch.setenv("OCIO", str(write_config(tmp_path)))
    cm.reset_config_cache()
    ws = cm.resolve_working_space()
    assert (ws.name, ws.config.name, ws.config.source) == ("studio_wide", os.environ["OCIO"],
                                                          "$OCIO")
    lin = albedo_in(1)
    write(tmp_path / "albedo.png", colour_science.cctf_encoding(lin, function="sRGB"), "uint8")
    _, stored = read(tmp_path / "albedo.png")
    report = process_textures(tmp_path / "albedo.png", mfp=1.0, eta=ETA, outputs=("rho",),
                              double=True, output=str(tmp_path / "{stem}_out.exr"))
    assert report.ok, report.summary()
    spec, px = read(tmp_path / "albedo_out.exr")
    want = to_wide(colour_science.cctf_decoding(stored, function="sRGB"))
    inverted = ref.rd_of_rho(rho_channels(spec, px), ETA)
    err = float(np.max(np.abs(inverted - want)))
    # and the opencolorio package's own processor of the same file, without optimisation
    import PyOpenColorIO as ocio
    cpu = ocio.Config.CreateFromFile(os.environ["OCIO"]).getProcessor(
        "srgb_texture", "studio_wide").getOptimizedCPUProcessor(ocio.OPTIMIZATION_NONE)
    by_ocio = np.ascontiguousarray(stored, np.float32)
    cpu.applyRGB(by_ocio)
    err_ocio = float(np.max(np.abs(inverted - by_ocio)))
    print(f"custom config (monkeypatched $OCIO) 8-bit sRGB -> studio_wide: {err:.2e} "
          f"(colour-science), {err_ocio:.2e} (opencolorio)")
    assert err <= TOL and err_ocio <= TOL, (err, err_ocio)
    check_tags(spec, None)
    assert spec.getattribute("chromaticities") is None
    assert report.results[0].colour == (f"srgb_texture (8-bit, declared) -> studio_wide, "
                                        f"config {os.environ['OCIO']}")


def test_custom_config_in_a_fresh_process(tmp_path, runtime):
    """The CLI with $OCIO set before it starts (OpenImageIO's own default config), the
    working space and the device given after the command: a float EXR declared lin_rec709."""
    lin = albedo_in(2)
    write(tmp_path / "albedo.exr", lin, "float", attrs=by_name("lin_rec709_scene"))
    env = dict(os.environ, OCIO=str(write_config(tmp_path)),
               PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[1]),
                                           os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-m", "bdipole_cl", "invert",
                          str(tmp_path / "albedo.exr"), "--outputs", "rho", "--double",
                          "--no-progress", "-o", str(tmp_path / "out.exr"),
                          "--working-space", "studio_wide", "--device", short_id(runtime)],
                         env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert (f"colour: lin_rec709 (float, declared) -> studio_wide, config {env['OCIO']}"
            in run.stdout), run.stdout
    spec, px = read(tmp_path / "out.exr")
    err = float(np.max(np.abs(ref.rd_of_rho(rho_channels(spec, px), ETA) - to_wide(lin))))
    print(f"custom config ($OCIO of a new process) float lin_rec709 -> studio_wide: {err:.2e}")
    assert err <= TOL, err
    assert spec.getattribute("oiio:ColorSpace") == "studio_wide"
    assert spec.getattribute("bdipole:ocio_config") == env["OCIO"]


@pytest.mark.parametrize("source, target", [("sRGB", "linear"), ("ACEScg", "lin_rec709_scene"),
                                            ("srgb_rec709_scene", "ACEScg"),
                                            ("Linear Rec.2020", "scene_linear")])
def test_conversions_are_openimageios_colorconvert_bit_for_bit(source, target):
    """The config's processor, by OpenImageIO's names and aliases too: equal to
    ImageBufAlgo.colorconvert with the same config to the last bit (HDR and negative texels
    included)."""
    rgb = np.random.default_rng(1).uniform(-0.5, 40.0, (7, 5, 3)).astype(np.float32)
    buf = oiio.ImageBuf(oiio.ImageSpec(5, 7, 3, "float"))
    buf.set_pixels(oiio.ROI(), rgb)
    want = oiio.ImageBufAlgo.colorconvert(buf, source, target, False, "", "",
                                          cm.BUILTIN_CONFIG).get_pixels(oiio.FLOAT)
    got = cm.active_config().convert(rgb, source, target)
    assert np.array_equal(got.view(np.uint32), want.reshape(got.shape).view(np.uint32))


def test_conversions_leave_openimageios_default_config_alone(tmp_path, monkeypatch):
    """OpenImageIO names the spaces of the files it writes through a process-wide default
    config; a conversion must leave it alone. Reading it from Python (OpenImageIO 3.2) moved
    it out, so that after a conversion under a studio $OCIO, files written in the built-in
    config's words lost their declaration (found as an order-dependent 19% error in
    test_blur_irradiance_converted_like_a_pre_converted_file)."""
    rgb = np.full((1, 1, 3), 0.5, np.float32)
    with monkeypatch.context() as studio:
        studio.setenv("OCIO", str(write_config(tmp_path)))
        cm.active_config().convert(rgb, "srgb_texture", "studio_wide")
    cm.active_config().convert(rgb, "ACEScg", "lin_rec709_scene")
    write(tmp_path / "a.exr", np.zeros((H, W, 3)), "float", attrs=by_name("ACEScg"))
    spec, _ = read(tmp_path / "a.exr")
    assert spec.getattribute("colorInteropID") == "lin_ap1_scene"


SHOT_CONFIG = """ocio_profile_version: 2
search_path: luts
environment:
  SHOT: A
roles:
  default: lin709
  scene_linear: lin709
file_rules:
  - !<Rule> {name: Default, colorspace: default}
colorspaces:
  - !<ColorSpace>
    name: lin709
    isdata: false
  - !<ColorSpace>
    name: shotlut
    isdata: false
    to_scene_reference: !<FileTransform> {src: $SHOT/lut.spi1d, interpolation: linear}
  - !<ColorSpace>
    name: broken
    isdata: false
    to_scene_reference: !<FileTransform> {src: nothere.spi1d}
"""


def shot_config(folder):
    """A studio config whose 'shotlut' scales by 1/2 (SHOT=A) or 1/4 (SHOT=B), and a
    'broken' space whose LUT is missing."""
    for shot, top in (("A", 0.5), ("B", 0.25)):
        (folder / "luts" / shot).mkdir(parents=True)
        (folder / "luts" / shot / "lut.spi1d").write_text(
            f"Version 1\nFrom 0.0 1.0\nLength 2\nComponents 1\n{{\n 0.0\n {top}\n}}\n")
    (folder / "config.ocio").write_text(SHOT_CONFIG)
    return folder / "config.ocio"


def test_an_empty_optimization_flags_variable_still_decodes_exactly():
    """OpenColorIO reads an empty OCIO_OPTIMIZATION_FLAGS as unset (its fast pow, 2.4e-5 off at
    sRGB white): the library's lossless level replaces it, as when it is not set at all."""
    code = ("import numpy as np; from bdipole_cl.io import colour as cm; "
            "v = np.arange(256, dtype=np.float32) / 255; "
            "x = np.repeat(v[None, :, None], 3, axis=2); "
            "y = cm.active_config().convert(x, 'srgb_rec709_scene', 'lin_rec709_scene'); "
            "want = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4); "
            "print(float(np.max(np.abs(y[0, :, 0] - want))))")
    env = {k: v for k, v in os.environ.items() if k != "OCIO"}
    env.update(OCIO_OPTIMIZATION_FLAGS="", PYTHONPATH=os.pathsep.join(
        [str(Path(__file__).parents[1]), env.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert float(run.stdout.split()[-1]) < 2e-6, run.stdout     # float32 decode (7.5e-7)


def test_a_studio_configs_context_and_broken_spaces(tmp_path, monkeypatch):
    """Context variables are read at each conversion ($SHOT changed in the process is
    followed, as OpenImageIO's colorconvert by name does); a relative $OCIO is the file in the
    folder it was named in; a space whose LUT is missing costs only what uses it, named in one
    line (OpenColorIO's ExceptionMissingFile is no PyOpenColorIO.Exception)."""
    # written first: OpenImageIO's writer names spaces through the config of its first use
    write(tmp_path / "acescg.exr", albedo_in(), "float",
          attrs=by_name("ACEScg") + (("colorInteropID", "lin_ap1_scene"),))
    config = shot_config(tmp_path / "studio")
    monkeypatch.chdir(config.parent)
    monkeypatch.setenv("OCIO", "config.ocio")
    monkeypatch.setenv("SHOT", "A")
    cfg = cm.active_config()
    assert cfg.name == str(config)
    texel = np.full((1, 1, 3), 0.8, np.float32)
    # with its environment: section (SHOT declared, default A) and without one (every
    # variable of the environment): A, B, A again, and unset (the default, or an error)
    bare = config.parent / "bare.ocio"
    bare.write_text(SHOT_CONFIG.replace("environment:\n  SHOT: A\n", ""))
    for studio, unset in ((cfg, 0.4), (cm.ColourConfig(str(bare), "$OCIO"), None)):
        for shot, want in (("A", 0.4), ("B", 0.2), ("A", 0.4), (None, unset)):
            if shot is None:
                monkeypatch.delenv("SHOT")
            else:
                monkeypatch.setenv("SHOT", shot)
            if want is None:
                with pytest.raises(ValueError, match="shotlut -> lin709"):
                    studio.convert(texel, "shotlut", "lin709")
                continue
            got = float(studio.convert(texel, "shotlut", "lin709")[0, 0, 0])
            assert got == pytest.approx(want), (studio.name, shot, got)
    with pytest.raises(ValueError, match="broken -> lin709.*nothere.spi1d"):
        cfg.convert(texel, "broken", "lin709")
    # an ACEScg file under this config (no interchange roles to follow it by) fails in one
    # named line, not as an unexpected error, and the broken space is not what it is about
    monkeypatch.chdir(tmp_path)     # the relative $OCIO now names another (absent) file
    with pytest.raises(ValueError, match="cannot be used"):
        cm.active_config()
    monkeypatch.setenv("OCIO", str(config))
    report = process_textures(tmp_path / "acescg.exr", mfp=1.0, eta=ETA,
                              output=str(tmp_path / "{stem}_out.exr"))
    r = report.results[0]
    assert r.status == "failed" and "has no space for" in r.error, (r.error, r.colour)
    assert "\n" not in r.error and "acescg.exr" in r.error


@pytest.mark.usefixtures("on_device")
def test_mfp_and_alpha_are_not_converted(tmp_path):
    """The albedo (declared lin_rec709) is converted into ACEScg; the mfp texture, declared
    lin_rec709 too, is a length per ACEScg channel and is used as it is, and alpha is copied."""
    lin = albedo_in(3, lo=0.02)
    alpha = np.linspace(0.2, 1.0, W)[None, :, None] * np.ones((H, 1, 1))
    write(tmp_path / "albedo.exr", np.concatenate([lin, alpha], -1), "float",
          ("R", "G", "B", "A"), by_name("lin_rec709_scene"))
    mfp = np.stack([np.full((H, W), v) for v in (2.0, 1.0, 0.25)], -1)
    write(tmp_path / "mfp.exr", mfp, "float", attrs=by_name("lin_rec709_scene"))
    report = process_textures(tmp_path / "albedo.exr", mfp=str(tmp_path / "mfp.exr"), eta=ETA,
                              outputs=("sigma_a", "sigma_s"), double=True,
                              working_space="ACEScg", output=str(tmp_path / "out.exr"))
    assert report.ok, report.summary()
    spec, px = read(tmp_path / "out.exr")
    names = list(spec.channelnames)
    albedo = independent(lin, "lin_rec709_scene", "ACEScg")
    want_sa, want_ss = ref.albedo_to_coefficients(albedo, mfp, ETA)
    got_sa = np.stack([px[..., names.index(f"sigma_a.{c}")] for c in "RGB"], -1)
    got_ss = np.stack([px[..., names.index(f"sigma_s.{c}")] for c in "RGB"], -1)
    # float32 outputs of a float64 inversion; 1e-5 relative also covers the albedo's 1e-6
    # absolute through d(sigma)/d(Rd) at the darkest texels (Rd ~ 0.016)
    np.testing.assert_allclose(got_sa, want_sa, rtol=1e-5)
    np.testing.assert_allclose(got_ss, want_ss, rtol=1e-5)
    # converting the mfp as a colour would have changed it: the test can tell
    converted = independent(mfp, "lin_rec709_scene", "ACEScg")
    assert np.max(np.abs(converted / mfp - 1)) > 0.1
    np.testing.assert_array_equal(px[..., names.index("A")], alpha[..., 0].astype(np.float32))
    assert spec.getattribute("bdipole:mfp") == str(tmp_path / "mfp.exr")


@pytest.mark.usefixtures("on_device")
def test_blur_irradiance_converted_like_a_pre_converted_file(tmp_path):
    """An irradiance declared ACEScg blurred in lin_rec709 equals the blur of the same light
    converted beforehand by colour-science and given untagged (taken as in the working
    space): the irradiance is converted first, the albedo and mfp constants are in it."""
    rng = np.random.default_rng(4)
    light = rng.uniform(0.1, 2.0, (H, W, 1)) * rng.uniform(0.8, 1.2, (H, W, 3))
    write(tmp_path / "irr_acescg.exr", light, "float", attrs=by_name("ACEScg"))
    write(tmp_path / "irr_709.exr", independent(light, "ACEScg", "lin_rec709_scene"), "float")
    kw = dict(albedo=(0.8, 0.5, 0.3), mfp=(1.0, 0.5, 0.25), eta=ETA, texel_size=0.5,
              method="direct", working_space="lin_rec709_scene")
    blur_file(tmp_path / "irr_acescg.exr", tmp_path / "a.exr", **kw)
    blur_file(tmp_path / "irr_709.exr", tmp_path / "b.exr", **kw)
    spec, a = read(tmp_path / "a.exr")
    _, b = read(tmp_path / "b.exr")
    # the same blur of inputs within 2e-7 of each other (float32 conversion): 1e-6 relative
    err = float(np.max(np.abs(a - b) / np.abs(b)))
    assert err <= 1e-6, err
    check_tags(spec, "lin_rec709_scene")
    assert spec.getattribute("bdipole:irradiance_colorspace") == "ACEScg"


def test_declarations_the_config_cannot_follow(tmp_path):
    lin = albedo_in()
    write(tmp_path / "lies.exr", lin, "float",
          attrs=by_name("ACEScg") + by_chromaticities("lin_rec709_scene"))
    odd = (0.69, 0.3, 0.2, 0.7, 0.14, 0.05, 0.3127, 0.329)
    write(tmp_path / "odd.exr", lin, "float", attrs=(("chromaticities", odd),))
    for name, message in (("lies", "declares 'lin_ap1_scene' but its chromaticities"),
                          ("odd", "match no linear colour space of OCIO config")):
        report = process_textures(tmp_path / f"{name}.exr", output=str(tmp_path / "o_{stem}.exr"))
        r = report.results[0]
        assert r.status == "failed" and message in r.error and "--colorspace" in r.error, r.error
        assert r.error.count(f"{name}.exr") == 1, r.error
        assert not (tmp_path / f"o_{name}.exr").exists()


SCENE = """
[defaults]
working_space = "{ws}"

[[material]]
name = "skin"
albedo = "albedo.png"
mfp = [1.0, 0.5, 0.25]
outputs = ["sigma_a", "sigma_s"]
output = "out/skin.exr"

[[blur]]
name = "skin_light"
material = "skin"
irradiance = "irr.exr"
texel_size = 0.5
output = "out/exitance.exr"
"""


@pytest.mark.usefixtures("on_device")
def test_scene_rebaked_when_the_working_space_or_config_changes(tmp_path, monkeypatch):
    write(tmp_path / "albedo.png", colour_science.cctf_encoding(albedo_in(5), function="sRGB"),
          "uint8")
    write(tmp_path / "irr.exr", np.full((H, W, 3), 2.0), "float",
          attrs=by_name("lin_rec709_scene"))          # a name both configs know
    scene_file = tmp_path / "scene.toml"

    def bake(ws, want):
        scene_file.write_text(SCENE.format(ws=ws) if ws else
                              SCENE.replace('working_space = "{ws}"', ""))
        plan = scenes.load(scene_file).plan()
        statuses = [r.status for r in plan.run().results]
        assert statuses == [want, want], (ws, statuses, plan.describe())
        return plan

    plan = bake("ACEScg", "ok")
    assert ("colour: albedo sRGB Encoded Rec.709 (sRGB) (8-bit, declared) -> ACEScg, config "
            "ocio://default") in plan.describe()
    bake("lin_ap1_scene", "skipped")            # another name of the same space
    bake("lin_rec2020_scene", "ok")
    for out in ("skin", "exitance"):
        spec, _ = read(tmp_path / "out" / f"{out}.exr")
        check_tags(spec, "lin_rec2020_scene")
    assert spec.getattribute("bdipole:irradiance_colorspace") == CANONICAL["lin_rec709_scene"]
    assert spec.getattribute("bdipole:albedo_colorspace") == CANONICAL["srgb"]
    bake("lin_rec2020_scene", "skipped")
    bake(None, "ok")                            # the default: lin_rec709_scene
    bake(None, "skipped")
    monkeypatch.setenv("OCIO", str(write_config(tmp_path)))   # a studio config: rebaked
    cm.reset_config_cache()
    bake(None, "ok")
    spec, _ = read(tmp_path / "out" / "skin.exr")
    assert spec.getattribute("bdipole:working_space") == "studio_wide"


def test_scene_colour_keys(tmp_path):
    """working_space: [defaults], else the CLI's/load()'s, else the default; a blur takes its
    material's unless it gives its own. Names are stored as the config names them."""
    scene_file = tmp_path / "scene.toml"
    body = SCENE.replace('working_space = "{ws}"', "")
    scene_file.write_text(body)
    s = scenes.load(scene_file)
    assert (s.materials[0].working_space, s.blurs[0].working_space) == (None, None)
    s = scenes.load(scene_file, "lin_ap1_scene")
    assert (s.materials[0].working_space, s.blurs[0].working_space) == ("ACEScg", "ACEScg")
    scene_file.write_text(body.replace('texel_size = 0.5', 'texel_size = 0.5\n'
                                       'working_space = "lin_rec2020_scene"\n'
                                       'colorspace = "srgb_tx"'))
    s = scenes.load(scene_file, "ACEScg")
    assert (s.materials[0].working_space, s.blurs[0].working_space) == ("ACEScg",
                                                                        "Linear Rec.2020")
    assert (s.materials[0].colorspace, s.blurs[0].colorspace) == ("auto", CANONICAL["srgb"])


def test_scene_colour_names_are_checked_on_their_line(tmp_path):
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text(SCENE.format(ws="ACEScg").replace(
        'albedo = "albedo.png"', 'albedo = "albedo.png"\ncolorspace = "nope"'))
    with pytest.raises(scenes.SceneError, match=r"scene.toml:8: colorspace = 'nope': "
                                                r"colorspace 'nope' is unknown to OCIO"):
        scenes.load(scene_file)
    scene_file.write_text(SCENE.format(ws="sRGB"))
    with pytest.raises(scenes.SceneError, match=r"scene.toml:3: working_space = 'sRGB'.*not "
                                                r"scene-linear"):
        scenes.load(scene_file)


@pytest.mark.usefixtures("on_device")
def test_grey_converted_as_neutral_and_two_channels_refused(tmp_path):
    """A grey 8-bit PNG into ACEScg is the grey (y, y, y) converted (white stays white under
    chromatic adaptation, so the three agree); two colour channels cannot be converted."""
    y = albedo_in(6)[..., :1]
    write(tmp_path / "grey.png", colour_science.cctf_encoding(y, function="sRGB"), "uint8",
          ("Y",))
    _, stored = read(tmp_path / "grey.png")
    report = process_textures(tmp_path / "grey.png", outputs=("rho",), double=True,
                              working_space="ACEScg", output=str(tmp_path / "grey_out.exr"))
    assert report.ok, report.summary()
    spec, px = read(tmp_path / "grey_out.exr")
    rgb = independent(np.repeat(colour_science.cctf_decoding(stored, function="sRGB"), 3, -1),
                      "lin_rec709_scene", "ACEScg")
    assert np.max(np.ptp(rgb, axis=-1)) < 1e-6           # neutral stays neutral
    inverted = ref.rd_of_rho(px[..., list(spec.channelnames).index("rho.Y")], ETA)
    err = float(np.max(np.abs(inverted - rgb.mean(axis=-1))))
    assert err <= TOL, err
    write(tmp_path / "rg.tif", albedo_in(6)[..., :2], "uint8", ("R", "G"))
    report = process_textures(tmp_path / "rg.tif", working_space="ACEScg",
                              output=str(tmp_path / "rg_out.exr"))
    assert "channels R, G: a colour conversion from sRGB Encoded Rec.709 (sRGB) needs R, G " \
           "and B" in report.results[0].error, report.summary()


def icc_profile(colorants, curve, description):
    """A minimal ICC v2 matrix/TRC profile (ICC.1:2010 7.2, 10.2 'curv', 10.27 'XYZ '):
    ``curve`` a gamma (one u8.8 value) or a table of code values (uint16)."""
    import struct

    def s15(v):
        return struct.pack(">i", int(round(v * 65536)))

    def xyz(v):
        return b"XYZ " + b"\0" * 4 + b"".join(s15(c) for c in v)

    def trc():
        if np.ndim(curve) == 0:
            return b"curv" + b"\0" * 4 + struct.pack(">IH", 1, int(round(curve * 256)))
        table = np.round(np.asarray(curve) * 65535).astype(">u2").tobytes()
        return b"curv" + b"\0" * 4 + struct.pack(">I", len(curve)) + table

    text = description.encode() + b"\0"
    desc = b"desc" + b"\0" * 4 + struct.pack(">I", len(text)) + text + b"\0" * 79
    tags = [(b"desc", desc), (b"wtpt", xyz((0.9642, 1.0, 0.8249)))] + [
        (k, xyz(v)) for k, v in zip((b"rXYZ", b"gXYZ", b"bXYZ"), colorants)] + [
        (k, trc()) for k in (b"rTRC", b"gTRC", b"bTRC")]
    table, data, offset = b"", b"", 128 + 4 + 12 * len(tags)
    for sig, body in tags:
        body += b"\0" * (-len(body) % 4)
        table += sig + struct.pack(">II", offset + len(data), len(body))
        data += body
    body = struct.pack(">I", len(tags)) + table + data
    head = (struct.pack(">I", 128 + len(body)) + b"none" + bytes([2, 0x10, 0, 0]) + b"mntr"
            + b"RGB XYZ " + b"\0" * 12 + b"acsp" + b"\0" * 28 + s15(0.9642) + s15(1.0)
            + s15(0.8249) + b"\0" * 48)
    return head + body


SRGB_TABLE = [float(v) for v in np.where(np.linspace(0, 1, 1024) <= 0.04045,
                                         np.linspace(0, 1, 1024) / 12.92,
                                         ((np.linspace(0, 1, 1024) + 0.055) / 1.055) ** 2.4)]
ADOBE_RGB = ((0.6097, 0.3111, 0.0195), (0.2053, 0.6257, 0.0609), (0.1492, 0.0632, 0.7446))
DISPLAY_P3 = ((0.5151, 0.2412, -0.0011), (0.2920, 0.6922, 0.0419), (0.1571, 0.0666, 0.7841))


#: (colorants, curve, description, the built-in space it declares, or None: refused)
PROFILES = [
    (None, None, "sRGB (littleCMS, parametric)", "srgb_rec709_scene"),
    (icc.SRGB_COLORANTS, SRGB_TABLE, "sRGB IEC61966-2.1 (a 1024-entry table)",
     "srgb_rec709_scene"),
    (ADOBE_RGB, 563 / 256, "Adobe RGB (1998)", "g22_adobergb_scene"),
    (DISPLAY_P3, SRGB_TABLE, "Display P3", "srgb_p3d65_scene"),
    (icc.SRGB_COLORANTS, 1.0, "linear sRGB", "lin_rec709_scene"),
    (DISPLAY_P3, 1.5, "P3 gamma 1.5", None),
    (((0.45, 0.25, 0.02), (0.35, 0.70, 0.10), (0.16, 0.05, 0.70)), 2.2, "odd primaries", None)]


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("colorants, curve, name, space", PROFILES,
                         ids=[p[2].split(" (")[0] for p in PROFILES])
@pytest.mark.parametrize("suffix, depth", [(".png", 8), (".tif", 8), (".jpg", 8), (".tif", 16),
                                           (".png", 16)], ids=["png", "tif", "jpg", "tif16",
                                                               "png16"])
def test_an_embedded_icc_profile_decides_the_space_at_every_bit_depth(
        tmp_path, colorants, curve, name, space, suffix, depth):
    """An ICC profile decides the file's space, in every format and at every bit depth: its
    output equals the one with that space given. A 16-bit TIFF with an sRGB profile was taken
    as linear (painted 0.5 inverted as albedo 0.5, not 0.214); Adobe RGB, P3 and linear
    profiles failed. A profile no built-in space matches fails its file, named."""
    from PIL import Image, ImageCms
    profile = (ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
               if colorants is None else icc_profile(colorants, curve, name))
    ramp = np.linspace(0.1, 0.9, 8 * 8 * 3).reshape(8, 8, 3)
    path = tmp_path / f"albedo{suffix}"
    if depth == 8:
        Image.fromarray((ramp * 255).astype(np.uint8), "RGB").save(path, icc_profile=profile)
    else:                                   # PIL writes no 16-bit RGB: OpenImageIO does
        out = oiio.ImageOutput.create(str(path))
        spec = oiio.ImageSpec(8, 8, 3, "uint16")
        spec.attribute("ICCProfile", oiio.TypeDesc(f"uint8[{len(profile)}]"),
                       np.frombuffer(profile, np.uint8))
        assert out.open(str(path), spec) and out.write_image((ramp * 65535).astype(np.uint16))
        out.close()
    report = process_textures(str(path), output=str(tmp_path / "o" / "{stem}.exr"),
                              outputs=("rho",))
    row, = report.results
    if space is None:
        assert row.status == "failed" and name in row.error and "--colorspace" in row.error, row
        return
    assert row.status == "ok", row
    given = process_textures(str(path), output=str(tmp_path / "g" / "{stem}.exr"),
                             colorspace=space, outputs=("rho",))
    assert given.exit_code == 0, given.summary()
    auto, want = (read(tmp_path / d / "albedo.exr")[1] for d in ("o", "g"))
    assert np.array_equal(auto, want), (name, suffix, depth)


def test_the_icc_colorants_are_the_built_in_configs_primaries():
    """icc.COLORANTS (D50, as profiles carry them) derived independently: the built-in config's
    primaries and white (xy) to XYZ, Bradford-adapted to ICC's D50 (ICC.1:2010 Annex E)."""
    bradford = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367],
                         [0.0389, -0.0685, 1.0296]])

    def xyz(x, y):
        return np.array([x / y, 1.0, (1 - x - y) / y])

    d50 = np.array([0.9642, 1.0, 0.8249])
    cfg = cm.ColourConfig(cm.BUILTIN_CONFIG, "built-in")
    for key, colorants in icc.COLORANTS.items():
        xy = cfg.chromaticities(cfg.space(f"lin_{key}_scene"))
        prim = np.stack([xyz(*xy[2 * k:2 * k + 2]) for k in range(3)], 1)
        white = xyz(*xy[6:8])
        m = prim * np.linalg.solve(prim, white)
        adapt = np.linalg.inv(bradford) @ np.diag((bradford @ d50) / (bradford @ white)) @ bradford
        got = (adapt @ m).T
        assert np.allclose(got, colorants, atol=icc.COLORANT_TOL / 4), (key, got)


def png_chunk(kind, data):
    import struct
    import zlib
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff))


def png_with(path, px8, chunks):
    """An 8-bit RGB PNG of ``px8`` (None: the PNG already at ``path``) whose only colour
    chunks are ``chunks`` (OpenImageIO's own sRGB, gAMA, cHRM, iCCP are taken out)."""
    import struct
    if px8 is not None:
        out = oiio.ImageOutput.create(str(path))
        assert out.open(str(path), oiio.ImageSpec(px8.shape[1], px8.shape[0], 3, "uint8"))
        out.write_image(px8)
        out.close()
    data, keep, i = path.read_bytes(), [], 8
    while i < len(data):
        (n,) = struct.unpack(">I", data[i:i + 4])
        kind = data[i + 4:i + 8]
        if kind == b"IDAT" and chunks is not None:
            keep += chunks
            chunks = None
        if kind not in (b"sRGB", b"gAMA", b"cHRM", b"iCCP"):
            keep.append(data[i:i + 12 + n])
        i += 12 + n
    path.write_bytes(data[:8] + b"".join(keep))


def chrm(xy):
    """A cHRM chunk of (xR, yR, xG, yG, xB, yB, xW, yW) (white first, as PNG stores it)."""
    import struct
    return png_chunk(b"cHRM", struct.pack(">8I", *(round(v * 100000)
                                                   for v in (*xy[6:8], *xy[:6]))))


#: published primaries and white (xR, yR, xG, yG, xB, yB, xW, yW): SMPTE EG 432-1 (P3-D65),
#: Adobe RGB (1998)
P3_XY = (0.680, 0.320, 0.265, 0.690, 0.150, 0.060, 0.3127, 0.3290)
ADOBE_XY = (0.64, 0.33, 0.21, 0.71, 0.15, 0.06, 0.3127, 0.3290)


def gama(gamma):
    import struct
    return png_chunk(b"gAMA", struct.pack(">I", round(100000 / gamma)))


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("chunks, space", [
    ((png_chunk(b"sRGB", b"\0"),), "srgb_rec709_scene"),
    ((chrm(P3_XY),), "srgb_p3d65_scene"),
    ((chrm(P3_XY), gama(1.0)), "lin_p3d65_scene"),
    ((chrm(ADOBE_XY), gama(2.2)), "g22_adobergb_scene"),
    ((gama(1.0),), "lin_rec709_scene"),
    ((gama(1.8),), "g18_rec709_scene"),
    ((gama(2.5),), None),
    ((png_chunk(b"sRGB", b"\0"), chrm(P3_XY)), None),
    ((chrm((0.69, 0.3, 0.2, 0.7, 0.14, 0.05, 0.3127, 0.329)),), None),
], ids=["sRGB", "cHRM-P3", "cHRM-P3-gAMA1", "cHRM-Adobe-gAMA2.2", "gAMA1", "gAMA1.8",
        "gAMA2.5", "sRGB-with-P3", "cHRM-odd"])
def test_png_colour_chunks_decide_the_space(tmp_path, chunks, space):
    """A PNG's sRGB, gAMA and cHRM chunks decide its space (cHRM was ignored: P3 primaries
    gave Rec.709's coefficients, unsaid); what no space matches, or chunks that contradict
    each other, fail the file, named."""
    px8 = (np.linspace(0.1, 0.9, 6 * 4 * 3).reshape(4, 6, 3) * 255).astype(np.uint8)
    png_with(tmp_path / "a.png", px8, list(chunks))
    report = process_textures(str(tmp_path / "a.png"), output=str(tmp_path / "o.exr"),
                              outputs=("rho",))
    row, = report.results
    if space is None:
        assert row.status == "failed" and "a.png" in row.error and "--colorspace" in row.error
        return
    assert row.status == "ok" and row.colour.startswith(
        cm.ColourConfig(cm.BUILTIN_CONFIG, "b").space(space)), (row.colour, space)
    given = process_textures(str(tmp_path / "a.png"), output=str(tmp_path / "g.exr"),
                             outputs=("rho",), colorspace=space)
    assert given.exit_code == 0
    assert np.array_equal(read(tmp_path / "o.exr")[1], read(tmp_path / "g.exr")[1])


STUDIO = """ocio_profile_version: 2.1

roles:
  default: linear
  scene_linear: linear
  texture_paint: {paint}
  data: raw
  {interchange}

file_rules:
  - !<Rule> {{name: Default, colorspace: default}}

colorspaces:
  - !<ColorSpace>
    name: linear
    isdata: false

  - !<ColorSpace>
    name: ACES2065-1 (studio)
    isdata: false
    to_scene_reference: !<MatrixTransform> {{matrix: [{ap0_to_709}]}}

  - !<ColorSpace>
    name: studio paint
    isdata: false
    from_scene_reference: !<ExponentWithLinearTransform>
      gamma: 2.4
      offset: 0.055
      direction: inverse

  - !<ColorSpace>
    name: raw
    isdata: true
"""


def studio_config(folder, interchange):
    """A studio config whose names are none of the CG config's: 'linear' (Rec.709), 'studio
    paint' (sRGB) as its texture_paint role; with ``interchange`` an aces_interchange role
    (its AP0 -> Rec.709 matrix taken from the built-in config through OpenColorIO)."""
    import PyOpenColorIO as ocio
    builtin = ocio.Config.CreateFromFile("ocio://default")
    cpu = builtin.getProcessor("ACES2065-1", "lin_rec709_scene").getDefaultCPUProcessor()
    m = np.eye(4)
    for k in range(3):
        v = np.eye(3, dtype=np.float32)[k].copy()
        cpu.applyRGB(v)
        m[:3, k] = v
    path = Path(folder) / "studio.ocio"
    path.write_text(STUDIO.format(
        paint="studio paint" if not interchange else "linear",
        interchange="aces_interchange: ACES2065-1 (studio)" if interchange else "",
        ap0_to_709=", ".join(f"{v:.9g}" for v in m.ravel())))
    return path


@pytest.mark.usefixtures("on_device")
@pytest.mark.parametrize("interchange", [False, True], ids=["roles", "interchange"])
def test_a_studio_config_with_its_own_names_reads_every_png(tmp_path, monkeypatch, interchange):
    """$OCIO names a config with none of the CG config's names: an 8-bit PNG declared sRGB
    (OpenImageIO: srgb_rec709_scene) is followed to the config's own sRGB, found through its
    interchange role (OpenColorIO identifies 'studio paint'), else its texture_paint role (it
    failed: "srgb_rec709_scene unknown"); an undeclared one takes texture_paint."""
    monkeypatch.setenv("OCIO", str(studio_config(tmp_path, interchange)))
    cm.reset_config_cache()
    px8 = (np.linspace(0.1, 0.9, 6 * 4 * 3).reshape(4, 6, 3) * 255).astype(np.uint8)
    png_with(tmp_path / "srgb.png", px8, [png_chunk(b"sRGB", b"\0")])
    png_with(tmp_path / "plain.png", px8, [])
    for name, space in (("srgb", "studio paint"),
                        ("plain", "linear" if interchange else "studio paint")):
        report = process_textures(str(tmp_path / f"{name}.png"),
                                  output=str(tmp_path / f"o_{name}.exr"), outputs=("rho",))
        row, = report.results
        assert row.status == "ok" and row.colour.startswith(space), (name, row)
    cm.reset_config_cache()


@pytest.mark.usefixtures("on_device")
def test_exif_colorspace_decides_or_fails_and_an_undeclared_16bit_png_is_srgb(tmp_path):
    """EXIF ColorSpace 1 is sRGB; 65535 (uncalibrated, often Adobe RGB) without an ICC
    profile fails its file, named. A 16-bit PNG with no colour chunk is sRGB, PNG's default
    (OpenImageIO's tag said so; it is not taken as linear)."""
    from PIL import Image
    px8 = (np.linspace(0.1, 0.9, 8 * 8 * 3).reshape(8, 8, 3) * 255).astype(np.uint8)
    for value in (1, 65535):
        exif = Image.Exif()
        exif[0xA001] = value
        Image.fromarray(px8, "RGB").save(tmp_path / f"e{value}.jpg", exif=exif.tobytes())
    ok, bad = (process_textures(str(tmp_path / f"e{v}.jpg"), output=str(tmp_path / f"o{v}.exr"),
                                outputs=("rho",)).results[0] for v in (1, 65535))
    assert ok.status == "ok" and "sRGB" in ok.colour, ok
    assert bad.status == "failed" and "EXIF ColorSpace 65535" in bad.error, bad
    out = oiio.ImageOutput.create(str(tmp_path / "p16.png"))
    assert out.open(str(tmp_path / "p16.png"), oiio.ImageSpec(8, 8, 3, "uint16"))
    out.write_image(px8.astype(np.uint16) * 257)
    out.close()
    png_with(tmp_path / "p16.png", None, [])             # no colour chunks at all
    row, = process_textures(str(tmp_path / "p16.png"), output=str(tmp_path / "p16.exr"),
                            outputs=("rho",)).results
    assert row.status == "ok" and row.colour.startswith("sRGB Encoded Rec.709 (sRGB) (16-bit, "
                                                        "default)"), row


@pytest.mark.usefixtures("on_device")
def test_a_space_named_in_the_built_in_configs_words_is_followed_into_a_studio_config(
        tmp_path, monkeypatch):
    """--colorspace (or a scene's, a USD stage's) srgb_rec709_scene / srgb_texture under a
    studio config that has neither name: its sRGB space through its interchange role, or its
    texture_paint role (was: "unknown to OCIO config")."""
    for interchange in (True, False):
        monkeypatch.setenv("OCIO", str(studio_config(tmp_path, interchange)))
        cm.reset_config_cache()
        want = "studio paint"
        for name in ("srgb_rec709_scene", "srgb_texture", "sRGB Encoded Rec.709 (sRGB)"):
            if not interchange and name != "srgb_rec709_scene":
                continue
            assert cm.resolve_colorspace(name) == want, (interchange, name)
        with pytest.raises(ValueError, match="unknown to OCIO config"):
            cm.resolve_colorspace("lin_p3d65_scene" if not interchange else "bogus")
    cm.reset_config_cache()
