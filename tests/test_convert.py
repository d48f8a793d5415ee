"""``convert`` (docs/conventions.md "Conversion"): round trips and monotone sweeps for every
pair of conventions, what both sides render, invalid texels, and the CLI on a small texture
set. Pairs that involve a random walk need physics.transport (the walk reference)."""
import itertools

import numpy as np
import pytest

import bdipole_cl
from bdipole_cl.errors import InvalidInputError
from bdipole_cl.physics.conventions import CONVENTION, rendered

PROFILES = [c.name for c in CONVENTION if not c.walk]
ALL = [c.name for c in CONVENTION]
#: round trips A -> B -> A: the brief's 1e-5 (each inverse is a 64-step float64 bisection,
#: ~1e-16; the walk reference's own inverse sets the floor for walks)
ROUND_TRIP = 1e-5
#: colours of the sweeps: inside every convention's range at eta 1.33 and 1.4 (MoonRay's walk
#: renders at most 0.845 at 1.4, Cycles' 0.870: higher colours are out of their reach)
COLOURS = np.linspace(0.05, 0.8, 16)


def _needs_walk(*names):
    """Skip unless the walk reference, its spread table included, is there."""
    if any(CONVENTION[n].walk for n in names):
        transport = pytest.importorskip("bdipole_cl.physics.transport",
                                        reason="physics.transport (the walk reference) not "
                                               "there")
        try:
            transport.walk_spread(0.5)
        except (ImportError, OSError) as exc:
            pytest.skip(f"physics.transport.walk_spread not available: {exc}")


def _pairs(names):
    return [pytest.param(a, b, id=f"{a}->{b}") for a, b in itertools.permutations(names, 2)]


@pytest.mark.parametrize("source,target", _pairs(ALL))
def test_round_trip_and_monotone(source, target):
    _needs_walk(source, target)
    radius = np.linspace(0.5, 2.0, COLOURS.size)
    there = bdipole_cl.convert(COLOURS, radius, source, target, eta=1.4)
    back = bdipole_cl.convert(there.colour, there.radius, target, source, eta=1.4)
    assert np.max(np.abs(back.colour - COLOURS)) <= ROUND_TRIP, (source, target)
    assert np.max(np.abs(back.radius / radius - 1.0)) <= ROUND_TRIP, (source, target)
    # the target's colour increases with the source's (a reflectance map is monotone)
    assert np.all(np.diff(there.colour) > 0.0), (source, target, there.colour)


@pytest.mark.parametrize("source,target", _pairs(["better-dipole", "burley", "van-de-hulst",
                                                   "cycles-skin", "random-walk"]))
def test_both_sides_render_the_same(source, target):
    # what the target renders from the converted values (computed afresh) is what the source
    # renders: reflectance to 1e-9 (bisection), median radius to 1e-7 (a bisection in log r)
    _needs_walk(source, target)
    there = bdipole_cl.convert(COLOURS, 1.3, source, target, eta=1.33)
    a = rendered(source, COLOURS, 1.3, eta=1.33)
    b = rendered(target, there.colour, there.radius, eta=1.33)
    assert np.max(np.abs(a.rd - b.rd)) < 1e-9
    assert np.max(np.abs(b.median / a.median - 1.0)) < 1e-7


@pytest.mark.parametrize("target", ["cycles-random-walk", "cycles-skin", "van-de-hulst",
                                    "cycles-legacy"])
def test_anisotropic_walks_render_the_painted_albedo(target):
    # Cycles' Random Walk with its anisotropy: the walk that leaves at its first crossing is
    # modelled for g != 0 (physics.transport, against a separate Monte Carlo in
    # test_transport); a PxrSurface texture converted at g = 0.6 renders its own reflectance,
    # and comes back within the round trip's bound
    _needs_walk(target)
    colours = np.linspace(0.05, 0.75, 12)
    there = bdipole_cl.convert(colours, 1.3, "better-dipole", target, eta=1.4, g=0.6)
    a = rendered("better-dipole", colours, 1.3, eta=1.4, g=0.6)
    b = rendered(target, there.colour, there.radius, eta=1.4, g=0.6)
    assert np.max(np.abs(a.rd - b.rd)) < 1e-9
    assert np.max(np.abs(b.median / a.median - 1.0)) < 1e-7
    back = bdipole_cl.convert(there.colour, there.radius, target, "better-dipole", eta=1.4,
                              g=0.6)
    assert np.max(np.abs(back.colour - colours)) <= ROUND_TRIP
    assert np.all(np.diff(there.colour) > 0.0)


def test_profile_conventions_keep_the_colour():
    # a diffusion profile's total is its colour: only the radius changes between them
    there = bdipole_cl.convert(COLOURS, 1.0, "better-dipole", "burley", eta=1.4)
    np.testing.assert_array_equal(there.colour, COLOURS)
    assert np.all(there.radius > 0)


def test_shapes_broadcast_and_invalid_values_named():
    colour = np.full((2, 3, 3), 0.5)
    colour[1, 2, 0] = 1.5
    with pytest.raises(InvalidInputError) as info:
        bdipole_cl.convert(colour, 1.0, "better-dipole", "burley", texels=True)
    assert info.value.first_index == (1, 2, 0) and info.value.count == 1
    done = bdipole_cl.convert(colour, np.ones(3), "better-dipole", "burley",
                              on_invalid="clamp")
    assert done.colour.shape == (2, 3, 3) and done.invalid["colour"] == 1
    assert done.colour[1, 2, 0] == 1.0
    with pytest.raises(InvalidInputError):
        bdipole_cl.convert(0.5, -1.0, "better-dipole", "burley")
    with pytest.raises(ValueError, match="convention"):
        bdipole_cl.convert(0.5, 1.0, "better-dipole", "no-such")


@pytest.mark.parametrize("value,target", [(1.5, "cycles-random-walk"), (np.nan, "moonray-walk"),
                                          (-0.25, "moonray-walk"), (0.95, "cycles-legacy")])
def test_a_value_breaking_several_rules_is_one_invalid_value(value, target):
    # 1.5 is outside [0, 1] and, clamped to 1, beyond Cycles' reach; -0.25 and NaN, clamped to
    # 0, are below MoonRay's colour floor: each is one invalid value, not one per rule
    _needs_walk(target)
    colour = np.array([[[0.5, value, 0.4]]])
    done = bdipole_cl.convert(colour, 1.0, "better-dipole", target, eta=1.4,
                              on_invalid="clamp", texels=True)
    assert done.invalid == {"colour": 1, "radius": 0}, (value, target, done.invalid)


def test_cli_counts_a_value_breaking_several_rules_once(tmp_path, capsys):
    _needs_walk("cycles-random-walk", "moonray-walk")
    from bdipole_cl.apps.cli import main
    colour = np.full((2, 3, 3), 0.5)
    colour[1, 2, 1] = 1.5
    _write(tmp_path / "hot.exr", colour)
    colour[1, 2, 1] = -0.25
    _write(tmp_path / "cold.exr", colour)
    for name, target in (("hot", "cycles-random-walk"), ("cold", "moonray-walk")):
        rc = main(["convert", str(tmp_path / f"{name}.exr"), "--radius", "1", "--target",
                   target, "--on-invalid", "clamp"])
        out = capsys.readouterr().out
        assert rc == 0 and "colour 1" in out and "colour 2" not in out, (target, out)


def test_cycles_cannot_render_a_high_albedo_at_ior_1_4():
    # the walk loses the entry's Fresnel part: a painted 0.95 is beyond Cycles' reach
    _needs_walk("cycles-random-walk")
    with pytest.raises(InvalidInputError, match="above"):
        bdipole_cl.convert(0.95, 1.0, "better-dipole", "cycles-random-walk", eta=1.4)


def test_random_walk_target_gives_the_medium():
    _needs_walk("random-walk")
    from bdipole_cl.physics import transport  # noqa: F811
    done = bdipole_cl.convert(np.array([0.3, 0.6, 0.9]), 1.0, "better-dipole", "random-walk",
                              eta=1.4)
    m = done.medium()
    alpha = m.sigma_s / (m.sigma_a + m.sigma_s)
    rd = transport.walk_reflectance(alpha, g=0.0, eta=1.4)
    assert np.max(np.abs(rd - [0.3, 0.6, 0.9])) < 1e-8


def _write(path, pixels):
    import OpenImageIO as oiio
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], "float")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(pixels.astype(np.float32))
    out.close()


def _read(path):
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(str(path))
    return buf.spec().channelnames, buf.get_pixels(oiio.FLOAT)


def test_cli_converts_a_texture_set(tmp_path, capsys):
    from bdipole_cl.apps.cli import main
    rng = np.random.default_rng(3)
    colour = rng.uniform(0.1, 0.9, (4, 5, 3))
    for udim in (1001, 1002):
        _write(tmp_path / f"skin.{udim}.exr", colour)
        _write(tmp_path / f"skin.{udim}_dmfp.exr", np.full((4, 5, 1), 0.7))
    rc = main(["convert", str(tmp_path / "skin.<UDIM>.exr"), "--radius",
               str(tmp_path / "skin.<UDIM>_dmfp.exr"), "--source", "pxrsurface",
               "--target", "burley", "--eta", "1.4"])
    assert rc == 0, capsys.readouterr()
    names, px = _read(tmp_path / "skin.1002.burley.exr")
    assert names == ("colour.R", "colour.G", "colour.B", "radius.R", "radius.G", "radius.B")
    want = bdipole_cl.convert(colour.astype(np.float32), np.float32(0.7), "better-dipole",
                              "burley", eta=1.4)
    # written as float32: a float32 ulp of each value
    np.testing.assert_allclose(px[..., :3], want.colour, rtol=1.2e-7)
    np.testing.assert_allclose(px[..., 3:], want.radius, rtol=1.2e-7)


def test_cli_names_an_invalid_texel(tmp_path, capsys):
    from bdipole_cl.apps.cli import main
    colour = np.full((3, 4, 3), 0.5)
    colour[2, 1, 1] = 1.25
    _write(tmp_path / "bad.exr", colour)
    _write(tmp_path / "good.exr", np.full((3, 4, 3), 0.5))
    rc = main(["convert", str(tmp_path / "bad.exr"), str(tmp_path / "good.exr"),
               "--radius", "1", "--target", "burley"])
    out = capsys.readouterr().out
    assert rc == 1
    assert "x=1, y=2, channel G" in out, out
    assert (tmp_path / "good.burley.exr").exists() and not (tmp_path / "bad.burley.exr").exists()


def test_cli_counts_invalid_texels_over_every_channel_and_names_the_first(tmp_path, capsys):
    # MoonRay renders nothing darker than its colour floor: a dark G at (1, 1) and a black
    # texel at (3, 2) are 4 invalid values, the first (in the image's order) at x=1, y=1, G
    from bdipole_cl.apps.cli import main
    colour = np.full((4, 5, 3), 0.5)
    colour[1, 1, 1] = 5e-4
    colour[2, 3] = 0.0
    _write(tmp_path / "dark.exr", colour)
    rc = main(["convert", str(tmp_path / "dark.exr"), "--radius", "1",
               "--target", "moonray-walk"])
    out = capsys.readouterr().out
    assert rc == 1 and "4 invalid colour value(s)" in out, out
    assert "x=1, y=1, channel G" in out and "in rows 0..3" in out, out
    assert not (tmp_path / "dark.moonray-walk.exr").exists()


@pytest.mark.parametrize("name", [c.name for c in CONVENTION if c.name != "random-walk"])
def test_round_trip_through_the_medium_for_any_spread_curve(name, monkeypatch):
    # the conversion's algebra (reflectance matched through the real walk reference, radius
    # through the ratio of medians) round-trips whatever the spread curve: checked with a
    # smooth stand-in for walk_spread, so that it runs before the spread table exists
    transport = pytest.importorskip("bdipole_cl.physics.transport")
    monkeypatch.setattr(transport, "walk_spread", lambda alpha, g=0.0, eta=1.0, fraction=0.5:
                        0.7 + (1 + 0.1 * (eta - 1)) / np.sqrt(3 * (1 - np.asarray(alpha))
                                                              + 1e-3))
    radius = np.linspace(0.5, 2.0, COLOURS.size)
    there = bdipole_cl.convert(COLOURS, radius, name, "random-walk", eta=1.4)
    back = bdipole_cl.convert(there.colour, there.radius, "random-walk", name, eta=1.4)
    assert np.max(np.abs(back.colour - COLOURS)) <= ROUND_TRIP, name
    assert np.max(np.abs(back.radius / radius - 1.0)) <= ROUND_TRIP, name
    assert np.all(np.diff(there.colour) > 0.0), name


def test_cli_pxrsurface_to_openpbr_matches_the_arrays(tmp_path, capsys):
    # the brief's case: a PxrSurface set (colour + dmfp constants) to OpenPBR, as the API does
    _needs_walk("van-de-hulst")
    from bdipole_cl.apps.cli import main
    colour = np.random.default_rng(5).uniform(0.1, 0.8, (3, 4, 3))
    _write(tmp_path / "skin.exr", colour)
    rc = main(["convert", str(tmp_path / "skin.exr"), "--radius", "1.2,0.6,0.3",
               "--source", "pxrsurface", "--target", "openpbr", "--eta", "1.4"])
    assert rc == 0, capsys.readouterr()
    _, px = _read(tmp_path / "skin.van-de-hulst.exr")
    c32 = colour.astype(np.float32)
    for k, dmfp in enumerate((1.2, 0.6, 0.3)):
        want = bdipole_cl.convert(c32[..., k], np.float32(dmfp), "better-dipole",
                                  "van-de-hulst", eta=1.4)
        np.testing.assert_allclose(px[..., k], want.colour, rtol=1.2e-7)
        np.testing.assert_allclose(px[..., 3 + k], want.radius, rtol=1.2e-7)


@pytest.mark.parametrize("source,target", [("better-dipole", "burley"),
                                           ("burley-perpendicular", "dipole"),
                                           ("better-dipole", "van-de-hulst"),
                                           ("random-walk", "better-dipole"),
                                           ("cycles-random-walk", "hyperion-2018")])
def test_a_colour_converts_to_the_same_bits_among_any_number_of_others(source, target):
    # every distinct colour is converted exactly (docs/conventions.md "Conversion"): a
    # texture's texel (over 4096 distinct colours: it went through an interpolated grid, 2e-4
    # off with the real spread table) is bit for bit the exact maps of that colour alone
    from bdipole_cl.physics import conversion
    _needs_walk(source, target)
    colour = np.random.default_rng(2).uniform(0.02, 0.8, 6000).astype(np.float32)
    done = conversion.convert(colour, 1.0, source, target, eta=1.4)
    exact = conversion.colour_maps(CONVENTION[source], CONVENTION[target],
                                   colour[:300].astype(np.float64), 1.4, 0.0)
    np.testing.assert_array_equal(done.colour[:300], exact[0], err_msg=f"{source}->{target}")
    np.testing.assert_array_equal(done.radius[:300], exact[1], err_msg=f"{source}->{target}")
    for n in (1, 7, 4097):
        few = conversion.convert(colour[:n], 1.0, source, target, eta=1.4)
        np.testing.assert_array_equal(few.colour, done.colour[:n], err_msg=f"{n} colours")
        np.testing.assert_array_equal(few.radius, done.radius[:n], err_msg=f"{n} colours")


def test_cli_texels_do_not_depend_on_the_image_size(tmp_path, capsys):
    # a 64x64 and a 65x65 texture (4096 and 4225 distinct colours per channel) give the same
    # bits for the texels they share, and those are the array API's
    _needs_walk("van-de-hulst")
    from bdipole_cl.apps.cli import main
    colour = np.random.default_rng(8).uniform(0.05, 0.8, (65, 65, 3)).astype(np.float32)
    _write(tmp_path / "big.exr", colour)
    _write(tmp_path / "small.exr", colour[:64, :64])
    rc = main(["convert", str(tmp_path / "big.exr"), str(tmp_path / "small.exr"),
               "--radius", "1.2,0.6,0.3", "--source", "pxrsurface", "--target", "openpbr"])
    assert rc == 0, capsys.readouterr()
    _, big = _read(tmp_path / "big.van-de-hulst.exr")
    _, small = _read(tmp_path / "small.van-de-hulst.exr")
    np.testing.assert_array_equal(big[:64, :64], small)
    want = bdipole_cl.convert(colour[:64, :64, 0], np.float32(1.2), "better-dipole",
                              "van-de-hulst", eta=1.4)
    np.testing.assert_array_equal(small[..., 0], want.colour.astype(np.float32))
    np.testing.assert_array_equal(small[..., 3], want.radius.astype(np.float32))


def test_cli_random_walk_target_writes_the_medium(tmp_path, capsys):
    _needs_walk("random-walk")
    from bdipole_cl.apps.cli import main
    colour = np.random.default_rng(6).uniform(0.1, 0.8, (2, 3, 3))
    _write(tmp_path / "skin.exr", colour)
    assert main(["convert", str(tmp_path / "skin.exr"), "--radius", "0.5",
                 "--target", "random-walk"]) == 0, capsys.readouterr()
    names, px = _read(tmp_path / "skin.random-walk.exr")
    assert names[:3] == ("sigma_a.R", "sigma_a.G", "sigma_a.B") and names[3] == "sigma_s.R"
    want = bdipole_cl.convert(colour.astype(np.float32), 0.5, "better-dipole", "random-walk",
                              eta=1.4).medium()
    # sigma_a from float64 alpha (a float32 alpha near 1 would leave 1 - alpha 2e-5 off)
    np.testing.assert_allclose(px[..., :3], want.sigma_a, rtol=1.2e-7)
    np.testing.assert_allclose(px[..., 3:], want.sigma_s, rtol=1.2e-7)


def test_a_nearly_black_texel_round_trips_within_its_documented_bound():
    """Below a reflectance of 1e-4 the spread is taken at that bound (docs/conventions.md): the
    colour comes back within 1e-6 (absolute), the radius within the documented 1%."""
    import bdipole_cl
    colour = np.geomspace(1e-7, 1e-3, 40)
    radius = np.ones_like(colour)
    colour_bound = {"openpbr": 1e-6, "random-walk": 1e-6, "cycles-random-walk": 1e-6,
                    "moonray-walk": 7.5e-4}       # docs/conventions.md: each one's floor
    # MoonRay renders no less than its colour floor's reflectance: texels below it are
    # invalid, named, and clamped to the floor on request
    with pytest.raises(InvalidInputError, match="below 0.00073.*colour floor"):
        bdipole_cl.convert(colour, radius, source="pxrsurface", target="moonray-walk", eta=1.4)
    for target, bound in colour_bound.items():
        policy = "clamp" if target == "moonray-walk" else "raise"
        there = bdipole_cl.convert(colour, radius, source="pxrsurface", target=target, eta=1.4,
                                   on_invalid=policy)
        back = bdipole_cl.convert(there.colour, there.radius, source=target,
                                  target="pxrsurface", eta=1.4)
        assert np.max(np.abs(back.colour - colour)) <= bound, target
        assert np.max(np.abs(back.radius - 1)) <= 1e-2, target
