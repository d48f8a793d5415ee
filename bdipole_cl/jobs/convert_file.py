"""Texture sets from one renderer's subsurface convention to another's (``bdipole-cl
convert``; docs/conventions.md "Conversion"): a colour texture (+ a radius texture or
constants) in, one EXR out with the target's ``colour.*`` and ``radius.*`` channels.

The machinery is the inversion batch's (``batch``, ``invert_file``): the same inputs (globs,
UDIM and UV-tile patterns, ``{stem}`` companions), colour management, bands of rows, collision
checks and verified atomic writes; only the per-band computation differs
(``physics.conversion.convert``, per colour channel).
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace
from typing import ClassVar
from pathlib import Path

import numpy as np

from ..errors import InvalidInputError, check_policy
from ..io import tiles
from ..io.channels import COLOUR_LAYERS, MEDIUM_LAYERS, short_name
from ..io.collisions import Claim, collisions
from ..io.colour import WorkingSpace, check_colorspace, resolve_working_space
from ..io.freshness import InputGuard, params_digest
from ..io.images import (Cancelled, TextureError, Writer, check_output_format,
                         classify_channels, invalid_texels, output_spec)
from ..io.mipmaps import TextureOptions, texture_options
from ..io.networks import layer_path
from ..io.patterns import companion_path, expand_inputs, unmatched_pattern
from ..ops.bands import band_rows
from ..physics.conventions import CONVENTION
from ..io.scene_keys import UNIT_METERS
from ..physics.conversion import RADIUS_RANGE, convert
from ..version import __version__
from .batch import parse_constant
from .convert_materials import convention_targets
from .invert_file import JobFiles, open_inputs, per_channel
from .pipeline import stream_bands
from .results import BatchReport, FileResult

DEFAULT_OUTPUT = "{dir}/{stem}.{target}.exr"


@dataclass(frozen=True)
class ConvertJob:
    """One file's conversion: its colour texture (``source``), output, every input by role
    ("albedo", "mfp": the radius texture) and the batch's work."""

    source: str
    output: str
    inputs: dict
    work: "ConvertWork"
    udim: str | None = None


@dataclass(frozen=True)
class ConvertWork:
    """What a conversion job computes, the same for every file of a batch. ``mfp`` and
    ``mfp_scale`` are the radius (named as the inversion's readers name them), ``mask``
    and ``alpha_channel`` as there."""

    source: str
    target: str
    eta: tuple
    g: float
    mfp: tuple | None             # radius constants per channel, or None: the job's texture
    mfp_scale: float
    half: bool
    colorspace: str
    on_invalid: str
    max_memory: int
    unit: str
    alpha_channel: str = "keep"
    mask: str | None = None
    working: WorkingSpace | None = None
    texture: TextureOptions | None = None
    header: dict = field(default_factory=dict)
    layers: dict = field(default_factory=dict)    # as InvertWork's (none for convert)
    #: what each input role is called in messages (``invert_file.open_inputs``)
    input_names: ClassVar[dict] = {"albedo": "colour texture", "mfp": "radius (--radius)"}


def convert_textures(inputs, *, radius=1.0, source="better-dipole", target="van-de-hulst",
                     eta=1.4, g=0.0, output=DEFAULT_OUTPUT, half=False, colorspace="auto",
                     working_space=None, alpha="keep", on_invalid="raise",
                     max_memory=256 << 20, jobs=1, unit="mm", radius_scale=1.0,
                     texture=False, force=False, cancel=None) -> BatchReport:
    """Convert colour textures (+ radius) from ``source``'s convention to ``target``'s.

    ``inputs``: colour files, globs or tile patterns; ``radius``: constants (one or per
    channel, or ``"1,0.5,0.25"``) or a texture path/pattern (``{stem}``, ``<UDIM>``), times
    ``radius_scale``; ``output``: a path pattern (``{dir}``, ``{stem}``, ``{target}``, a tile
    token). The rest as ``batch.process_textures``. A failing file is reported and the batch
    goes on."""
    check_output_format(output.replace("{target}", "x"))
    working = resolve_working_space(working_space)
    check_colorspace(colorspace, working.config)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    src, tgt = CONVENTION[source], CONVENTION[target]
    constant = parse_constant(radius, "radius")
    check_before_work(constant, radius_scale, unit)
    work = ConvertWork(src.name, tgt.name,
                       tuple(np.atleast_1d(np.asarray(eta, np.float64)).tolist()), float(g),
                       constant, float(radius_scale), bool(half), colorspace,
                       check_policy(on_invalid), int(max_memory), unit, alpha,
                       working=working, texture=texture_options(texture))
    digest = params_digest({f.name: getattr(work, f.name) for f in fields(work)
                            if f.name not in ("max_memory", "header")})
    work = replace(work, header={"params_digest": digest})
    convert(0.5, 1.0, src.name, tgt.name, work.eta[0], work.g)   # fail fast on bad settings
    jobs_list, results = [], []
    for path, tile in expand_inputs(inputs):
        if tiles.is_pattern(path) and not os.path.exists(path):
            results.append(FileResult(path, error=unmatched_pattern(path)))
            continue
        try:
            out = companion_path(output.replace("{target}", tgt.name), path, tile)
            radius_path = None if constant is not None else companion_path(radius, path, tile)
        except (TextureError, tiles.TileError) as exc:
            results.append(FileResult(path, error=str(exc)))
            continue
        inputs_by_role = {"albedo": path} | ({"mfp": radius_path} if radius_path else {})
        jobs_list.append(ConvertJob(path, out, inputs_by_role, work,
                                    tile.label if tile else None))
    clashes = collisions(convert_claims(jobs_list, tgt.name), force)
    results += [FileResult(j.source, j.output, error=c) for j, c in zip(jobs_list, clashes) if c]
    todo = [j for j, c in zip(jobs_list, clashes) if not c]
    with ThreadPoolExecutor(max(1, int(jobs))) as pool:
        results += list(pool.map(lambda j: run_convert(j, cancel=cancel), todo))
    return BatchReport(results)


def convert_claims(jobs, convention: str) -> list:
    """The ``collisions.Claim`` of each job: its output, and where ``convention`` has render
    targets the layer files its material reads beside it (``networks.layer_path``), so that
    no two inputs of a run share a file one of their materials reads."""
    layers = COLOUR_LAYERS if convention_targets(convention) else ()
    return [Claim(j.source, j.output, j.inputs,
                  tuple(layer_path(j.output, layer, convention) for layer in layers))
            for j in jobs]


def check_before_work(constant, radius_scale, unit):
    """ValueError (a usage error, exit 2) before any file is written: a unit that is no
    length (the materials' metersPerUnit), a constant radius times ``radius_scale`` outside
    the range every convention takes (as its texels are checked: ``RADIUS_RANGE``)."""
    if unit not in UNIT_METERS:
        raise ValueError(f"unit={unit!r}: expected a length unit, one of "
                         f"{', '.join(UNIT_METERS)}")
    lo, hi = RADIUS_RANGE
    for v in (constant or ()):
        scaled = float(v) * float(radius_scale)
        if not lo <= scaled <= hi:
            raise ValueError(f"radius {float(v):g} x radius_scale {float(radius_scale):g} = "
                             f"{scaled:g}: expected a radius in [{lo:g}, {hi:g}]")


#: what an output holds: the target's colour and radius, or for ``random-walk`` the medium's
#: sigma_a and sigma_s (1/unit; its g is the header's): the layers ``channels`` reads by role
COLOUR_GROUPS, MEDIUM_GROUPS = COLOUR_LAYERS, MEDIUM_LAYERS


def output_groups(target) -> tuple:
    return MEDIUM_GROUPS if target == "random-walk" else COLOUR_GROUPS


def convert_band(work, inp, route, colour_in, radius, etas, job, y0):
    """One band's target colour and radius (for ``random-walk``: sigma_a and sigma_s), HxWxC
    each, and the invalid counts, per channel. ``convert`` is the one check of a colour
    (below 0 after the colour conversion is outside [0, 1] there): each invalid value is
    counted once."""
    colour = route.convert(colour_in, inp.names)
    radius = np.broadcast_to(radius, colour.shape)
    out_c, out_r = np.empty(colour.shape, np.float32), np.empty(colour.shape, np.float32)
    invalid = {"colour": 0, "radius": 0}
    raised = []                     # (y, x, channel, error): every channel is seen first
    for c, eta in enumerate(etas):
        def done_with(policy, c=c, eta=eta):
            return convert(colour[..., c], radius[..., c], work.source, work.target, eta,
                           work.g, on_invalid=policy, texels=True)
        try:
            done = done_with(work.on_invalid)
        except InvalidInputError as exc:
            raised.append((*exc.first_index[:2], c, exc))
            done = done_with("clamp")                  # to count them all
        if output_groups(work.target) == MEDIUM_GROUPS:
            # in float64 before the cast: 1 - alpha of a float32 alpha near 1 keeps few digits
            medium = done.medium()
            out_c[..., c], out_r[..., c] = medium.sigma_a, medium.sigma_s
        else:
            out_c[..., c], out_r[..., c] = done.colour, done.radius
        for key, n in done.invalid.items():
            invalid[key] += n
    if raised:                      # the first in the image's order, counted over channels
        yy, xx, c, exc = min(raised, key=lambda r: r[:3])
        where = job.inputs.get("mfp", job.source) if exc.name == "radius" else job.source
        spec = inp.albedo.spec
        raise invalid_texels(exc.with_(first_index=(yy, xx, c), count=invalid[exc.name],
                                       why=counted_why(exc, colour, invalid, work.target)),
                             where, spec.x + xx, spec.y + y0 + yy, inp.names[c],
                             f" in rows {y0}..{y0 + colour.shape[0] - 1}") from None
    return out_c, out_r, invalid


def counted_why(exc, colour, invalid, target) -> str:
    """The reason of an invalid count that covers every rule a colour breaks: the first
    rule's (``exc``) where it is all of them, else each rule's share (a colour outside [0, 1]
    and one out of the target's reach are both counted)."""
    if exc.name != "colour":
        return exc.why
    outside = int(np.count_nonzero(~((colour >= 0.0) & (colour <= 1.0))))
    if outside in (0, invalid["colour"]):
        return exc.why
    return (f"{outside} NaN, infinite or outside [0, 1], {invalid['colour'] - outside} a "
            f"reflectance {target} does not render")


def run_convert(job, *, cancel=None) -> FileResult:
    """Run one conversion job: its FileResult (the output verified and renamed into place,
    or nothing written)."""
    work = job.work
    result = FileResult(job.source, job.output)
    guard = InputGuard(job.inputs)               # before the first read
    with JobFiles(job, result) as files:
        inp = open_inputs(job, work, files.readers)
        spec = inp.albedo.spec
        _, _, other = classify_channels(spec.channelnames, spec.alpha_channel, "albedo")
        if other:
            result.notes.append("not colour, left out: "
                                + ", ".join(spec.channelnames[c] for c in other))
        etas = per_channel(work.eta, len(inp.names), "eta", job.source)
        route = inp.albedo.colour(work.colorspace, work.working)
        result.colour = route.describe()
        groups = output_groups(work.target)
        names = [f"{g}.{short_name(n)}" for g in groups for n in inp.names]
        if inp.keep_alpha:
            names.append(spec.channelnames[inp.alpha])
        header = {"version": __version__, "source": work.source, "target": work.target,
                  "eta": ",".join(f"{e:g}" for e in etas), "g": f"{work.g:g}",
                  "unit": work.unit, "albedo": job.source,
                  "radius": job.inputs.get("mfp") or ",".join(f"{m:g}" for m in inp.mfp_const),
                  **route.header("albedo"), **work.header}
        out_spec = output_spec(spec, names, len(names) - 1 if inp.keep_alpha else -1,
                               work.half, header, working=route.working)
        Path(job.output).parent.mkdir(parents=True, exist_ok=True)
        files.writer = writer = Writer(job.output, out_spec, work.on_invalid,
                                       texture=work.texture, cancel=cancel)
        per_texel = 8 * 6 * (spec.nchannels + 4 * len(inp.names))
        rows = band_rows(spec.height, spec.width * per_texel, work.max_memory,
                         tile_height=spec.tile_height if spec.tile_width else 0)

        def compute(band, data):
            (y0, _), (a, m, _) = band, data
            radius = (inp.mfp_const if m is None
                      else m[..., inp.mfp_channels] * np.float32(work.mfp_scale))
            out_c, out_r, invalid = convert_band(work, inp, route, a[..., inp.colour],
                                                 radius, etas, job, y0)
            for key, n in invalid.items():
                result.invalid[key] = result.invalid.get(key, 0) + n
            parts = [out_c, out_r] + ([a[..., inp.alpha:inp.alpha + 1]] if inp.keep_alpha
                                      else [])
            if cancel is not None and cancel.is_set():
                raise Cancelled(f"{job.source}: interrupted; nothing written")
            return np.concatenate(parts, axis=-1)

        stream_bands([(y, min(y + rows, spec.height)) for y in range(0, spec.height, rows)],
                     lambda band: inp.read(band, work), compute,
                     lambda band, block: writer.write_band(*band, block))
        writer.commit(check=guard.check)          # an input changed meanwhile: nothing written
        files.writer = None
        result.status = "ok"
        result.texels = spec.width * spec.height
    return result
