"""Outputs of one tool read as inputs of another (docs/cli.md "Outputs as inputs"): every
reader takes the channels of an output of ours by their role's layer (``colour.*`` for an
albedo, ``radius.*`` for an mfp, ``alpha.*`` and ``sigma_t.*`` for the blur's alpha' and
sigma_t'), never by their order, refuses one that lacks it, and writes each output channel as
``{its layer}.{R, G, B}``, never ``colour.colour.R``."""
import numpy as np
import OpenImageIO as oiio
import pytest

import bdipole_cl
from bdipole_cl.apps.cli import main


def _write(path, pixels, names=None):
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], "float")
    if names:
        spec.channelnames = tuple(names)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.ascontiguousarray(pixels, np.float32))
    out.close()


def _read(path):
    buf = oiio.ImageBuf(str(path))
    return buf.spec().channelnames, buf.get_pixels(oiio.FLOAT)


def _channels(names, px, layer):
    return px[..., [i for i, n in enumerate(names) if n.startswith(f"{layer}.")]]


@pytest.fixture
def converted(tmp_path, capsys):
    """A PxrSurface set converted to burley: one file of colour.* and radius.* layers."""
    colour = np.random.default_rng(1).uniform(0.1, 0.8, (3, 4, 3)).astype(np.float32)
    _write(tmp_path / "skin.exr", colour)
    assert main(["convert", str(tmp_path / "skin.exr"), "--radius", "1.2,0.6,0.3",
                 "--source", "pxrsurface", "--target", "burley"]) == 0, capsys.readouterr()
    capsys.readouterr()
    return tmp_path / "skin.burley.exr", colour


def test_a_converted_file_is_its_own_colour_and_radius(converted, tmp_path, capsys):
    # convert's output given back to convert as colour and as --radius: the radius is read
    # from radius.* (it was read from colour.*: 14.7x off, exit 0) and the channels are
    # named once (colour.R, not colour.colour.R)
    path, colour = converted
    rc = main(["convert", str(path), "--radius", str(path), "--source", "burley",
               "--target", "dipole", "-o", str(tmp_path / "{stem}.again.exr")])
    assert rc == 0, capsys.readouterr()
    names, px = _read(tmp_path / "skin.burley.again.exr")
    assert names == ("colour.R", "colour.G", "colour.B", "radius.R", "radius.G", "radius.B")
    there = bdipole_cl.convert(colour, np.float32([1.2, 0.6, 0.3]), "better-dipole", "burley",
                               eta=1.4)
    again = bdipole_cl.convert(there.colour.astype(np.float32),
                               there.radius.astype(np.float32), "burley", "dipole", eta=1.4)
    np.testing.assert_allclose(px[..., :3], again.colour, rtol=3e-7)   # float32 in, out
    np.testing.assert_allclose(px[..., 3:], again.radius, rtol=3e-7)


def test_invert_reads_a_converted_file_by_its_layers(converted, tmp_path, capsys):
    # a conversion to this library's convention is an albedo and an mfp for invert
    path, colour = converted
    assert main(["convert", str(path), "--radius", str(path), "--source", "burley",
                 "--target", "pxrsurface", "-o", str(tmp_path / "{stem}.pxr.exr")]) == 0
    pxr = tmp_path / "skin.burley.pxr.exr"
    rc = main(["invert", str(pxr), "--mfp", str(pxr), "--outputs", "sigma_a,sigma_s",
               "-o", str(tmp_path / "{stem}_sss.exr"), "--device", "intel", "--no-progress"])
    assert rc == 0, capsys.readouterr()
    names, px = _read(tmp_path / "skin.burley.pxr_sss.exr")
    assert names == ("sigma_a.R", "sigma_a.G", "sigma_a.B", "sigma_s.R", "sigma_s.G",
                     "sigma_s.B")
    cnames, cpx = _read(pxr)
    sa, ss = bdipole_cl.reference.albedo_to_coefficients(
        _channels(cnames, cpx, "colour").astype(np.float64),
        _channels(cnames, cpx, "radius").astype(np.float64), 1.4)
    np.testing.assert_allclose(px[..., :3], sa, rtol=1e-4)      # the table method's tol
    np.testing.assert_allclose(px[..., 3:], ss, rtol=1e-4)


def test_blur_reads_alpha_and_sigma_t_from_an_inversion(tmp_path, capsys):
    # one inversion's alpha.* and sigma_t.* given as --alpha-prime and --sigma-t: the same
    # blur as the constants (sigma_t was read from alpha.*, the first layer)
    _write(tmp_path / "albedo.exr", np.full((8, 8, 3), 0.6))
    assert main(["invert", str(tmp_path / "albedo.exr"), "--mfp", "0.5", "--outputs",
                 "alpha,sigma_t", "-o", str(tmp_path / "coef.exr"), "--device", "intel",
                 "--no-progress"]) == 0, capsys.readouterr()
    names, coef = _read(tmp_path / "coef.exr")
    alpha, sigma_t = (float(_channels(names, coef, k)[0, 0, 0]) for k in ("alpha", "sigma_t"))
    irradiance = np.zeros((8, 8, 3), np.float32)
    irradiance[3:5, 3:5] = 1.0
    _write(tmp_path / "irr.exr", irradiance)
    common = ["--texel-size", "0.1", "--device", "intel", "--no-progress"]
    assert main(["blur", str(tmp_path / "irr.exr"), "--alpha-prime", str(tmp_path / "coef.exr"),
                 "--sigma-t", str(tmp_path / "coef.exr"), "-o", str(tmp_path / "a.exr"),
                 *common]) == 0, capsys.readouterr()
    assert main(["blur", str(tmp_path / "irr.exr"), "--alpha-prime", repr(alpha),
                 "--sigma-t", repr(sigma_t), "-o", str(tmp_path / "b.exr"),
                 *common]) == 0, capsys.readouterr()
    np.testing.assert_allclose(_read(tmp_path / "a.exr")[1], _read(tmp_path / "b.exr")[1],
                               rtol=1e-3, atol=1e-6)        # the blur's tol, both ways


@pytest.mark.parametrize("what", ["inversion", "medium"])
def test_an_output_without_the_roles_layer_is_refused_by_name(what, tmp_path, capsys):
    # an inversion's sigma_a/sigma_s, or a random-walk conversion's medium, holds no radius:
    # refused, named, never read as one by position
    layers = ("alpha", "rho") if what == "inversion" else ("sigma_a", "sigma_s")
    names = [f"{layer}.{c}" for layer in layers for c in "RGB"]
    _write(tmp_path / "other.exr", np.full((2, 2, 6), 0.5), names)
    _write(tmp_path / "skin.exr", np.full((2, 2, 3), 0.5))
    rc = main(["convert", str(tmp_path / "skin.exr"), "--radius", str(tmp_path / "other.exr"),
               "--target", "burley"])
    out = capsys.readouterr().out
    assert rc == 1 and "radius.* layer" in out and "other.exr" in out, out
    assert not (tmp_path / "skin.burley.exr").exists()


@pytest.fixture
def layer_files(tmp_path, capsys):
    """One-layer files of ours (plain R, G, B; only the header's ``bdipole:layer`` says what
    they hold): convert's colour and radius beside an OpenPBR set, and an inversion's
    sigma_a and alpha as a bake writes them beside its coefficients (``layer_files``)."""
    from bdipole_cl.io.colour import resolve_working_space
    from bdipole_cl.jobs.layer_files import layer_files as write_layers
    _write(tmp_path / "skin.exr", np.random.default_rng(2).uniform(0.1, 0.8, (4, 4, 3)))
    assert main(["convert", str(tmp_path / "skin.exr"), "--radius", "1.2,0.6,0.3",
                 "--source", "pxrsurface", "--target", "openpbr"]) == 0, capsys.readouterr()
    assert main(["invert", str(tmp_path / "skin.exr"), "--mfp", "0.5", "--outputs",
                 "sigma_a,alpha", "-o", str(tmp_path / "coef.exr"), "--device", "intel",
                 "--no-progress"]) == 0, capsys.readouterr()
    write_layers(str(tmp_path / "coef.exr"), ("sigma_a", "alpha"),
                 resolve_working_space(None), [])
    assert main(["blur", str(tmp_path / "skin.exr"), "--albedo", "0.5", "--mfp", "1",
                 "--texel-size", "1", "-o", str(tmp_path / "blurred.exitance.exr"),
                 "--device", "intel", "--no-progress"]) == 0, capsys.readouterr()
    capsys.readouterr()
    return {k: tmp_path / f"{k}.exr" for k in ("skin.van-de-hulst.colour",
                                                "skin.van-de-hulst.radius", "coef.sigma_a",
                                                "coef.alpha", "blurred.exitance")}


@pytest.mark.parametrize("given, args", [
    ("skin.van-de-hulst.colour", ["convert", "{skin}", "--radius", "{file}", "--source",
                                  "openpbr", "--target", "pxrsurface", "-o", "{tmp}/x.exr"]),
    ("skin.van-de-hulst.radius", ["convert", "{file}", "--radius", "1", "--source",
                                  "openpbr", "--target", "pxrsurface", "-o", "{tmp}/x.exr"]),
    ("coef.sigma_a", ["invert", "{skin}", "--mfp", "{file}", "-o", "{tmp}/x.exr"]),
    ("skin.van-de-hulst.radius", ["invert", "{file}", "--mfp", "1", "-o", "{tmp}/x.exr"]),
    ("coef.alpha", ["blur", "{skin}", "--alpha-prime", "0.5", "--sigma-t", "{file}",
                    "--texel-size", "5", "-o", "{tmp}/x.exr"]),
    ("coef.alpha", ["blur", "{file}", "--alpha-prime", "0.5", "--sigma-t", "1",
                    "--texel-size", "5", "-o", "{tmp}/x.exr"]),
    ("skin.van-de-hulst.radius", ["blur", "{skin}", "--albedo", "{file}", "--mfp", "1",
                                  "--texel-size", "5", "-o", "{tmp}/x.exr"]),
    ("blurred.exitance", ["invert", "{file}", "--mfp", "1", "-o", "{tmp}/x.exr"]),
    ("blurred.exitance", ["convert", "{skin}", "--radius", "{file}", "-o", "{tmp}/x.exr"]),
], ids=["convert-radius", "convert-colour", "invert-mfp", "invert-albedo", "blur-sigma-t",
        "blur-irradiance", "blur-albedo", "exitance-albedo", "exitance-radius"])
def test_a_layer_file_read_as_another_role_is_refused_by_name(layer_files, tmp_path, capsys,
                                                             given, args):
    # a one-layer file's R, G, B were read as whatever it was given as (a colour as the
    # radius, sigma_a as the mfp, alpha as sigma_t), exit 0: its header's layer decides
    fill = {"skin": str(tmp_path / "skin.exr"), "file": str(layer_files[given]),
            "tmp": str(tmp_path)}
    argv = [a.format(**fill) for a in args]
    argv += ["--device", "intel"] if argv[0] != "convert" else []
    rc = main(argv + (["--no-progress"] if argv[0] != "convert" else []))
    out = "".join(capsys.readouterr())
    held = given.rsplit(".", 1)[1]
    assert rc != 0 and f"{layer_files[given]}: holds a bdipole-cl output's {held} layer" in out, \
        (rc, out)
    assert not (tmp_path / "x.exr").exists()


def test_a_layer_file_as_its_own_role_is_read(layer_files, tmp_path, capsys):
    # convert's colour and radius files are a colour and a radius again; a blur's exitance
    # is light, blurred again
    rc = main(["convert", str(layer_files["skin.van-de-hulst.colour"]), "--radius",
               str(layer_files["skin.van-de-hulst.radius"]), "--source", "openpbr",
               "--target", "pxrsurface", "-o", str(tmp_path / "x.exr")])
    assert rc == 0, capsys.readouterr()
    rc = main(["blur", str(layer_files["blurred.exitance"]), "--albedo", "0.5", "--mfp", "1",
               "--texel-size", "1", "-o", str(tmp_path / "y.exr"), "--device", "intel",
               "--no-progress"])
    assert rc == 0, capsys.readouterr()


def test_scenes_and_dask_refuse_a_layer_file_of_another_role(layer_files, tmp_path):
    from bdipole_cl import dask as bdask
    from bdipole_cl import scene as scenes
    from bdipole_cl.io.images import TextureError
    with pytest.raises(TextureError, match="holds a bdipole-cl output's sigma_a layer"):
        bdask.blur_file_on_cluster(str(layer_files["coef.sigma_a"]), str(tmp_path / "x.exr"),
                                   None, albedo=0.5, mfp=1.0)
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "skin"\nalbedo = "skin.exr"\nmfp = "coef.sigma_a.exr"\n'
        'output = "out/skin.exr"\n')
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code == 1 and "holds a bdipole-cl output's sigma_a layer" in \
        report.summary(), report.summary()


@pytest.fixture
def old_exitance(layer_files, tmp_path):
    """A blur's output as blur wrote it before it named its layer: no ``bdipole:layer``, its
    methods, source and texel size in the header."""
    buf = oiio.ImageBuf(str(layer_files["blurred.exitance"]))
    buf.specmod().erase_attribute("bdipole:layer")
    assert buf.spec().getattribute("bdipole:methods") is not None
    path = tmp_path / "exit_old.exr"
    assert buf.write(str(path)), buf.geterror()
    return path


@pytest.mark.parametrize("args", [
    ["invert", "{skin}", "--mfp", "{file}", "-o", "{tmp}/x.exr"],
    ["convert", "{skin}", "--radius", "{file}", "--target", "openpbr", "-o", "{tmp}/x.exr"],
    ["invert", "{file}", "--mfp", "1", "-o", "{tmp}/x.exr"],
], ids=["invert-mfp", "convert-radius", "invert-albedo"])
def test_a_blur_output_without_its_layer_is_refused_as_another_role(old_exitance, tmp_path,
                                                                   capsys, args):
    # read as the mfp / radius (exit 0): the role check knew files only by bdipole:layer
    fill = {"skin": str(tmp_path / "skin.exr"), "file": str(old_exitance),
            "tmp": str(tmp_path)}
    argv = [a.format(**fill) for a in args]
    argv += ["--device", "intel", "--no-progress"] if argv[0] != "convert" else []
    rc = main(argv)
    out = "".join(capsys.readouterr())
    assert rc != 0 and f"{old_exitance}: holds a bdipole-cl output's exitance layer " \
                       f"(bdipole:methods)" in out, (rc, out)
    assert not (tmp_path / "x.exr").exists()


def test_a_scene_refuses_a_blur_output_without_its_layer_as_an_mfp(old_exitance, tmp_path):
    from bdipole_cl import scene as scenes
    (tmp_path / "scene.toml").write_text(
        '[[material]]\nname = "skin"\nalbedo = "skin.exr"\nmfp = "exit_old.exr"\n'
        'output = "out/skin.exr"\n')
    report = scenes.load(tmp_path / "scene.toml").plan().run()
    assert report.exit_code != 0 and "holds a bdipole-cl output's exitance layer" in \
        report.summary(), report.summary()
