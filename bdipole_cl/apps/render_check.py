"""Real renderers from PyPI as witnesses (the ``renderers`` extra; docs/conventions.md
"Checked in real renderers"): the diffuse reflectance Mitsuba 3 and Blender's Cycles render
for a medium or a painted colour, with its Monte Carlo error bar.

Mitsuba 3 (``scalar_rgb``, ``volpath``): a slab far thicker and wider than the mean free
path (sigma_t = 1) bounded by a ``dielectric`` at eta, holding a ``homogeneous`` medium, lit
by a constant environment of radiance 1. A tiny ``irradiancemeter`` disk just above the
slab, facing it, measures the exitance: irradiance / pi is the white-sky (diffuse-incidence)
reflectance, specular included; the specular part is measured apart (the same slab with an
absorbing medium) and subtracted. Each of the three RGB channels carries its own albedo, so
one render measures three media. The error bar is the spread of independent batches.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: slab half-size and meter placement, in mean free paths (float32 scenes: a much larger
#: slab puts the intersections' rounding at the meter's height; measured: a 1e6-wide slab
#: read a white diffuse plane 15% low, this one within 1e-3)
SLAB_HALF = 200.0
METER_HEIGHT = 0.05
METER_RADIUS = 1e-3


@dataclass(frozen=True)
class Measured:
    """A rendered reflectance per channel: ``value`` and its standard error ``error``
    (batches' spread / sqrt(batches)); ``samples``: paths per channel in all."""

    value: np.ndarray
    error: np.ndarray
    samples: int


def _mitsuba():
    try:
        import mitsuba as mi
    except ImportError as exc:     # the extra is optional
        raise ImportError("Mitsuba 3 is not installed: pip install 'bdipole-cl[renderers]' "
                          "(or pip install mitsuba)") from exc
    mi.set_variant("scalar_rgb")
    return mi


def mitsuba_scene(alpha, eta, g=0.0, spp=1024):
    """The slab scene of the module docstring for per-channel single-scattering albedos
    ``alpha`` (3 values), relative index ``eta``, HG ``g``, ``spp`` paths per render."""
    mi = _mitsuba()
    t = mi.ScalarTransform4f
    phase = {"type": "hg", "g": float(g)} if g else {"type": "isotropic"}
    medium = {"type": "homogeneous", "sigma_t": 1.0, "phase": phase,
              "albedo": {"type": "rgb", "value": [float(a) for a in alpha]}}
    slab = {"type": "cube", "interior": medium,
            "to_world": t().translate([0, 0, -SLAB_HALF]).scale([SLAB_HALF] * 3),
            "bsdf": {"type": "dielectric", "int_ior": float(eta), "ext_ior": 1.0}}
    film = {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
            "pixel_format": "rgb"}
    meter = {"type": "disk", "sensor": {
        "type": "irradiancemeter", "film": film,
        "sampler": {"type": "independent", "sample_count": int(spp)}},
        "to_world": (t().translate([0, 0, METER_HEIGHT]) @ t().rotate([1, 0, 0], 180)
                     @ t().scale([METER_RADIUS] * 3))}
    return mi.load_dict({
        "type": "scene", "slab": slab, "meter": meter,
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1 << 20},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}})


def mitsuba_exitance(alpha, eta, g=0.0, spp=1024, batches=8, seed=0) -> Measured:
    """Exitance / pi of the slab (diffuse and specular) per channel, ``batches`` renders."""
    mi = _mitsuba()
    scene = mitsuba_scene(alpha, eta, g, spp)
    runs = np.array([np.asarray(mi.render(scene, seed=seed + k), np.float64).reshape(-1)[:3]
                     for k in range(batches)]) / np.pi
    return Measured(runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(batches),
                    spp * batches)


def mitsuba_reflectance(alpha, eta, g=0.0, spp=1024, batches=8, seed=0):
    """(diffuse reflectance, specular) Mitsuba renders for single-scattering ``alpha`` (up to
    3 values): the slab's exitance less the specular part measured apart (the same slab,
    albedo 0). Errors add in quadrature."""
    alpha = np.resize(np.asarray(alpha, np.float64), 3)
    total = mitsuba_exitance(alpha, eta, g, spp, batches, seed)
    specular = mitsuba_exitance((0.0, 0.0, 0.0), eta, g, spp, batches, seed + batches)
    # one medium in all three channels: the same paths, so channel 0 is the measurement
    spec = Measured(np.full(3, specular.value[0]), np.full(3, specular.error[0]),
                    specular.samples)
    diffuse = Measured(total.value - spec.value, np.hypot(total.error, spec.error),
                       total.samples)
    return diffuse, spec
