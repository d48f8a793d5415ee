"""Real renderers as witnesses (the ``renderers`` extra: ``pip install 'bdipole-cl[renderers]'``;
docs/conventions.md "Checked in real renderers"). Small sample counts: each test takes
seconds; tools/render_conventions.py renders the documented table at high counts.

Tolerances: a rendered value is a Monte Carlo mean with standard error e (the spread of
independent batches); it must lie within 4.5 e of the reference (a 1-in-150000 chance to
fail by noise alone) plus 2e-3 absolute for what the scene cannot make exact (a slab 200
mean free paths thick and wide, a meter 0.05 above it)."""
import numpy as np
import pytest

from test_conventions import half_space_albedo

SIGMAS = 4.5
SCENE_SLACK = 2e-3


def _within(measured, expected, what):
    err = np.abs(measured.value - expected)
    bound = SIGMAS * measured.error + SCENE_SLACK
    assert np.all(err <= bound), (what, measured.value, expected, measured.error)


@pytest.fixture(scope="module")
def render_check():
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the 'renderers' "
                                          "extra: pip install 'bdipole-cl[renderers]')")
    from bdipole_cl.apps import render_check
    return render_check


def test_mitsuba_index_matched_slab_renders_the_exact_half_space(render_check):
    # independent of physics.transport: at eta = 1 the slab's reflectance is Chandrasekhar's
    # exact isotropic half-space albedo (H-function), and there is no specular part
    alpha = (0.3, 0.6, 0.9)
    diffuse, specular = render_check.mitsuba_reflectance(alpha, 1.0, spp=1024, batches=4)
    _within(diffuse, np.array([half_space_albedo(a) for a in alpha]), "eta 1")
    assert np.all(specular.value == 0.0)


def test_mitsuba_dielectric_slab_renders_the_walk_reference(render_check):
    # the reference's medium, boundary included, against Mitsuba's volpath with a dielectric
    transport = pytest.importorskip("bdipole_cl.physics.transport",
                                    reason="physics.transport (the walk reference) not there")
    alpha, eta = (0.3, 0.7, 0.9), 1.4
    diffuse, specular = render_check.mitsuba_reflectance(alpha, eta, spp=1024, batches=4)
    _within(diffuse, transport.walk_reflectance(np.array(alpha), g=0.0, eta=eta), "eta 1.4")
    _within(specular, transport.specular_reflectance(eta, incidence="diffuse"), "specular")


@pytest.fixture(scope="module")
def cycles():
    pytest.importorskip("bpy", reason="Blender's bpy is not installed (the 'renderers' extra; "
                                      "bpy pins numpy<2: docs/conventions.md)")
    from bdipole_cl.apps import render_check
    return render_check


def test_cycles_random_walk_is_refracted_in_and_never_reflected_back(cycles):
    # Cycles' Random Walk: van de Hulst's albedo, refracted in through the dielectric, then an
    # index-matched walk that leaves at its first crossing (physics.half_space, exact for
    # g = 0). The dielectric-bounded walk (internal reflection) would render far less
    from bdipole_cl.physics import half_space, renderer_fits
    from bdipole_cl.physics.conventions import rendered_rd
    colour = np.array([0.3, 0.6, 0.9])
    diffuse, _ = cycles.cycles_reflectance(colour, (1, 1, 1), 1.4, "RANDOM_WALK", spp=16,
                                           batches=4)
    _within(diffuse, rendered_rd("cycles-random-walk", colour, 1.4), "cycles random walk")
    matched = half_space.matched_reflectance(renderer_fits.van_de_hulst_alpha(colour))
    assert np.all(diffuse.value < 0.95 * matched), (diffuse.value, matched)


def test_converted_pxrsurface_textures_render_the_painted_albedo_in_cycles(cycles):
    # better-dipole (PxrSurface) colours converted to Cycles' Random Walk render the painted
    # albedo there, within 1% (+ the Monte Carlo error bar); measured at high counts +0.37%,
    # +0.66% at 0.35, 0.6. Up to 0.65 here: at 0.75 it renders +1.06%, and above 0.8 Cycles'
    # walk stops at 256 bounces (BSSRDF_MAX_BOUNCES) and loses energy (painted 0.85 renders
    # 0.833; docs/conventions.md "Where Cycles differs")
    from bdipole_cl.physics.conventions import colour_for
    painted = np.array([0.35, 0.5, 0.65])
    colour = colour_for("cycles-random-walk", painted, 1.4)
    diffuse, _ = cycles.cycles_reflectance(colour, (1, 1, 1), 1.4, "RANDOM_WALK", spp=16,
                                           batches=4)
    err = np.abs(diffuse.value - painted)
    assert np.all(err <= 0.01 * painted + SIGMAS * diffuse.error), (diffuse.value, painted)


def test_cycles_random_walk_with_anisotropy(cycles):
    # Subsurface Anisotropy: a negative one is clamped to 0 (renders as g = 0, within 1%); at
    # g = 0.5 Cycles renders 1.4-1.8% above the HG walk of the documented formula (measured
    # at 16 x 4 spp: +1.7%, +1.4%, +1.8% at 0.3, 0.6, 0.9; not its switch to the similar
    # isotropic medium after 10 flights, which the Monte Carlo puts within 0.6%):
    # docs/conventions.md "Where Cycles differs"
    from bdipole_cl.physics.conventions import rendered_rd
    colour = np.array([0.3, 0.6, 0.9])
    for g, bound in ((-0.3, 0.01), (0.5, 0.025)):
        diffuse, _ = cycles.cycles_reflectance(colour, (1, 1, 1), 1.4, "RANDOM_WALK", spp=16,
                                               batches=4, anisotropy=g)
        want = rendered_rd("cycles-random-walk", colour, 1.4, g=g)
        err = np.abs(diffuse.value / want - 1)
        assert np.all(err <= bound + SIGMAS * diffuse.error / want), (g, diffuse.value, want)
    # and the model with g differs from the one without by more than that at 0.3
    assert abs(rendered_rd("cycles-random-walk", 0.3, 1.4, g=0.5) /
               rendered_rd("cycles-random-walk", 0.3, 1.4) - 1) > 0.05


def test_cycles_skin_enters_as_a_cosine_bounce(cycles):
    # Skin's formula with the cosine_entry boundary, (1 - F_dr) R_matched(alpha): measured
    # -1.8%, -1.2%, -3.9% at 0.3, 0.6, 0.9 (its rough half, the 256-bounce limit at 0.9); the
    # refracted-entry formula of Random Walk would be 11% off at 0.3
    from bdipole_cl.physics.conventions import rendered_rd
    colour = np.array([0.3, 0.6, 0.9])
    diffuse, _ = cycles.cycles_reflectance(colour, (1, 1, 1), 1.4, "RANDOM_WALK_SKIN", spp=16,
                                           batches=4)
    want = rendered_rd("cycles-skin", colour, 1.4)
    assert np.all(np.abs(diffuse.value / want - 1) < 0.05), (diffuse.value, want)
    from bdipole_cl.physics import half_space, renderer_fits
    refracted = half_space.entry_reflectance(renderer_fits.wvh_alpha(0.3), 1.4)   # 0.2468
    assert diffuse.value[0] > 1.08 * refracted, (diffuse.value[0], refracted)
