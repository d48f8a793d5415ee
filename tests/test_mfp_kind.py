"""The two mean free path conventions (docs/model.md "Mean free path"): mfp_kind = "diffuse"
(ld = 1/mu_tr) or "extinction" (sigma_t' = 1/mfp), in albedo_to_coefficients, texture
batches, the CLI and scene files."""
import numpy as np
import OpenImageIO as oiio
import pytest

from bdipole_cl import albedo_to_coefficients, invert_albedo
from bdipole_cl import reference as ref
from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.blur_file import blur_file
from conftest import f32, rel_err

pytestmark = pytest.mark.usefixtures("on_device")

#: the inversion's accuracy contract in rho (tests/test_invert.py); sigma_a = rho/mfp and
#: sigma_s' = alpha'/mfp add one float32 division (half an ulp), far below it
RHO_TOL = 1e-4
#: alpha' is within ~8 float32 ulps (tests/test_invert.py), and sigma_s' adds half an ulp
ALPHA_TOL = 1e-6


def read(path):
    inp = oiio.ImageInput.open(str(path))
    px = np.asarray(inp.read_image(oiio.FLOAT))
    spec = inp.spec()
    inp.close()
    return px, list(spec.channelnames), spec


@pytest.mark.parametrize("eta", [1.0, 1.4, 2.5])
def test_extinction_coefficients_against_the_float64_reference(eta):
    rd = f32(np.concatenate([np.geomspace(1e-6, 0.5, 500), 1 - np.geomspace(1e-4, 0.5, 500)]))
    mfp = f32(np.geomspace(0.01, 100, rd.size))
    sa, ss, st = albedo_to_coefficients(rd, mfp, eta, outputs=("sigma_a", "sigma_s", "sigma_t"),
                                        mfp_kind="extinction")
    alpha, rho = ref.invert_rd_rho(rd.astype(np.float64), eta)
    assert rel_err(sa, rho / mfp).max() <= RHO_TOL
    assert rel_err(ss, alpha / mfp).max() <= ALPHA_TOL
    # sigma_t' = 1/mfp, whatever the albedo (rho + alpha' = 1): a few float32 roundings
    assert rel_err(st, 1.0 / mfp.astype(np.float64)).max() <= 1e-6
    # independently, the forward model gives the input back from the coefficients times mfp:
    # below Rd = 1/2 from alpha' = sigma_s' mfp, within alpha's error (ALPHA_TOL and the
    # product's roundings: 2 ALPHA_TOL) times the condition number alpha' Rd'/Rd; above it
    # from rho = sigma_a mfp, where 1 - Rd ~ sqrt(rho) carries half of rho's error
    low = rd < 0.5
    a = np.minimum(ss[low].astype(np.float64) * mfp[low], 1.0)
    back = ref.rd(a, eta)
    cond = a * ref.rd_derivative(a, eta) / back
    assert np.all(rel_err(back, rd[low]) <= 2 * ALPHA_TOL * np.maximum(cond, 1.0))
    back = ref.one_minus_rd_of_rho(sa[~low].astype(np.float64) * mfp[~low], eta)
    assert rel_err(back, 1.0 - rd[~low].astype(np.float64)).max() <= RHO_TOL


def test_diffuse_is_the_default_and_unchanged():
    rd, mfp = f32(np.linspace(0.05, 0.95, 64)), f32(np.linspace(0.5, 3, 64))
    default = albedo_to_coefficients(rd, mfp, 1.4)
    diffuse = albedo_to_coefficients(rd, mfp, 1.4, mfp_kind="diffuse")
    for a, b in zip(default, diffuse):
        np.testing.assert_array_equal(a, b)
    # the two kinds differ by mu_tr/sigma_t' = sqrt(3 rho/(1 + rho)) (docs/model.md)
    ext = albedo_to_coefficients(rd, mfp, 1.4, mfp_kind="extinction")
    rho = ref.invert_rd_rho(rd.astype(np.float64), 1.4)[1]
    ratio = np.sqrt(3 * rho / (1 + rho))
    assert rel_err(default[0] * ratio, ext[0]).max() <= RHO_TOL
    with pytest.raises(ValueError, match="mfp_kind='optical': expected one of diffuse, "
                                         "extinction"):
        albedo_to_coefficients(rd, mfp, 1.4, mfp_kind="optical")


def test_texture_batch_and_cli_take_the_kind(tmp_path):
    yy, xx = np.mgrid[0:6, 0:6] / 6
    rgb = np.stack([0.2 + 0.6 * xx, 0.3 + 0.5 * yy, 0.1 + 0.3 * xx], -1).astype(np.float32)
    write_exr(tmp_path / "albedo.exr", rgb, ("R", "G", "B"))
    report = process_textures(str(tmp_path / "albedo.exr"), mfp=(1.0, 0.5, 0.25), eta=1.4,
                              mfp_kind="extinction", output=str(tmp_path / "api.exr"))
    assert report.exit_code == 0, report.summary()
    assert cli_main(["invert", str(tmp_path / "albedo.exr"), "--mfp", "1,0.5,0.25",
                     "--mfp-kind", "extinction", "-o", str(tmp_path / "cli.exr"),
                     "--no-progress"]) == 0
    want = albedo_to_coefficients(rgb, np.array([1.0, 0.5, 0.25]), 1.4, mfp_kind="extinction")
    for name in ("api.exr", "cli.exr"):
        px, names, spec = read(tmp_path / name)
        for c, ch in enumerate("RGB"):
            np.testing.assert_array_equal(px[..., names.index(f"sigma_a.{ch}")],
                                          want[0][..., c])
        assert spec.getattribute("bdipole:mfp_convention").startswith("1/sigma_t'")
    with pytest.raises(SystemExit):
        cli_main(["invert", str(tmp_path / "albedo.exr"), "--mfp-kind", "optical"])


SCENE = """
[[material]]
name = "wax"
albedo = "albedo.exr"
mfp = [0.1, 0.05, 0.025]
mfp_kind = "extinction"
mfp_scale = 2.0
output = "out/wax.exr"

[[blur]]
name = "light"
material = "wax"
irradiance = "irr.exr"
texel_size = 1.0
output = "out/light.exr"
"""


def test_scene_files_take_the_kind_and_the_blur_uses_it(tmp_path):
    yy, xx = np.mgrid[0:12, 0:12] / 12
    rgb = np.stack([0.3 + 0.5 * xx, 0.4 + 0.3 * yy, 0.2 + 0.2 * xx], -1).astype(np.float32)
    write_exr(tmp_path / "albedo.exr", rgb, ("R", "G", "B"))
    light = np.zeros((12, 12, 3), np.float32)
    light[5:7] = 2.0
    write_exr(tmp_path / "irr.exr", light, ("R", "G", "B"))
    (tmp_path / "scene.toml").write_text(SCENE)
    plan = scenes.load(tmp_path / "scene.toml").plan()
    assert any("mfp as extinction (sigma_t' = 1/mfp), scaled by 2" in c
               for c in plan.jobs[0].computes)
    assert plan.run().exit_code == 0
    # an extinction mfp is short: ld = mfp / sqrt(3 rho/(1 + rho)) is ~20 mfp at these albedos
    mfp = 2.0 * np.array([0.1, 0.05, 0.025])
    px, names, _ = read(tmp_path / "out" / "wax.exr")
    want = albedo_to_coefficients(rgb, mfp, 1.4, mfp_kind="extinction")
    np.testing.assert_allclose(px[..., names.index("sigma_s.G")], want[1][..., 1],
                               rtol=RHO_TOL)
    # the blur's medium: alpha' of the albedo and sigma_t' = 1/mfp
    blur_file(tmp_path / "irr.exr", tmp_path / "want.exr", alpha=invert_albedo(rgb, 1.4),
              sigma_t=np.broadcast_to(1.0 / mfp, rgb.shape), eta=1.4, texel_size=1.0,
              tol=1e-3)
    got, _, _ = read(tmp_path / "out" / "light.exr")
    expect, _, _ = read(tmp_path / "want.exr")
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-7)
    (tmp_path / "scene.toml").write_text(SCENE.replace('"extinction"', '"optical"'))
    with pytest.raises(scenes.SceneError, match=r":6: mfp_kind = 'optical': expected "
                                                r"\"diffuse\" or \"extinction\""):
        scenes.load(tmp_path / "scene.toml")
