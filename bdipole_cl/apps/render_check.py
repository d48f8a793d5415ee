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


# {{{ Cycles (bpy)

#: Cycles' Principled BSDF subsurface methods, by the conventions that describe them
#: (Blender 5.0 has no Random Walk (Legacy) any more: BURLEY, RANDOM_WALK, RANDOM_WALK_SKIN)
CYCLES_METHODS = {"cycles-random-walk": "RANDOM_WALK", "cycles-skin": "RANDOM_WALK_SKIN"}
#: the panorama's resolution (longitude x latitude), each row weighted by its exact share of
#: the cosine-weighted hemisphere
CYCLES_PANORAMA = (64, 32)


def _bpy():
    try:
        import bpy
    except ImportError as exc:
        raise ImportError("Blender's bpy is not installed: pip install bpy (it pins "
                          "numpy<2; docs/conventions.md says how to install it beside this "
                          "package)") from exc
    return bpy


def cycles_scene(colour, radius, ior, method="RANDOM_WALK", spp=64, anisotropy=0.0):
    """A Principled BSDF slab (subsurface weight 1, roughness 0) lit by a constant world of
    radiance 1, seen by an equirectangular camera 0.05 above it (clip 1e-4): the panorama's
    lower half is the exitance."""
    bpy = _bpy()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = "CPU", int(spp), False, False
    for bounces in ("max_bounces", "diffuse_bounces", "glossy_bounces",
                    "transmission_bounces"):
        setattr(c, bounces, 1024)
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.min_light_bounces, c.blur_glossy = 0, 0.0
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_x, scene.render.resolution_y = CYCLES_PANORAMA
    scene.render.resolution_percentage = 100
    world = bpy.data.worlds.new("constant")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[0].default_value = (1.0, 1.0, 1.0, 1.0)
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    slab = bpy.context.object
    slab.scale, slab.location = (SLAB_HALF,) * 3, (0.0, 0.0, -SLAB_HALF)
    material = bpy.data.materials.new("subsurface")
    material.use_nodes = True
    p = material.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*[float(v) for v in colour], 1.0)
    p.inputs["Subsurface Weight"].default_value = 1.0
    p.inputs["Subsurface Radius"].default_value = [float(v) for v in radius]
    p.inputs["Subsurface Scale"].default_value = 1.0
    p.inputs["Subsurface Anisotropy"].default_value = float(anisotropy)
    p.inputs["Roughness"].default_value = 0.0
    p.inputs["IOR"].default_value = float(ior)
    if "Subsurface IOR" in p.inputs:
        p.inputs["Subsurface IOR"].default_value = float(ior)
    p.subsurface_method = method
    slab.data.materials.append(material)
    cam = bpy.data.cameras.new("meter")
    cam.type, cam.clip_start = "PANO", 1e-4
    cam.panorama_type = "EQUIRECTANGULAR"
    meter = bpy.data.objects.new("meter", cam)
    scene.collection.objects.link(meter)
    scene.camera = meter
    meter.location = (0.0, 0.0, METER_HEIGHT)
    meter.rotation_euler = (0.5 * np.pi, 0.0, 0.0)   # horizontal axis: rows are latitudes
    return scene


def _panorama_exitance(path):
    import OpenImageIO as oiio
    px = oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT)[..., :3].astype(np.float64)
    h, w = px.shape[:2]
    # each row's exact weight Int cos(lat) sin(-lat) dlat over its band of latitudes (the
    # midpoint rule read a white plane 0.28% high), lower half only, 2 pi / w per column
    edges = (0.5 - np.arange(h + 1) / h) * np.pi
    weight = 0.5 * np.abs(np.diff(np.cos(np.minimum(edges, 0.0)) ** 2)) * (2 * np.pi / w)
    return np.einsum("h,hwc->c", weight, px) / np.pi


def cycles_exitance(colour, radius, ior, method="RANDOM_WALK", spp=64, batches=4,
                    workdir=None, anisotropy=0.0) -> Measured:
    """Exitance / pi of the Principled slab per channel over ``batches`` seeds."""
    import tempfile
    from pathlib import Path
    scene = cycles_scene(colour, radius, ior, method, spp, anisotropy)
    bpy = _bpy()
    runs = []
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        for k in range(batches):
            scene.cycles.seed = k
            scene.render.filepath = str(Path(tmp) / f"run{k}.exr")
            scene.render.image_settings.file_format = "OPEN_EXR"
            scene.render.image_settings.color_depth = "32"
            bpy.ops.render.render(write_still=True)
            runs.append(_panorama_exitance(scene.render.filepath))
    runs = np.array(runs)
    return Measured(runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(batches),
                    spp * batches)


def cycles_reflectance(colour, radius, ior, method="RANDOM_WALK", spp=64, batches=4,
                       anisotropy=0.0):
    """(diffuse, specular) Cycles renders: the slab's exitance less the same slab with a
    black base colour (the specular layer alone); ``anisotropy``: the Subsurface Anisotropy
    (HG g of the walk)."""
    total = cycles_exitance(colour, radius, ior, method, spp, batches, anisotropy=anisotropy)
    spec = cycles_exitance((0.0, 0.0, 0.0), radius, ior, method, spp, batches,
                           anisotropy=anisotropy)
    return (Measured(total.value - spec.value, np.hypot(total.error, spec.error),
                     total.samples), spec)

# }}}
