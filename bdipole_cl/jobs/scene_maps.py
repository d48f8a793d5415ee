"""Colour and radius in a render target's convention, from a bake's coefficients (the jobs
layer; written by ``scene_records`` before the networks that read them).

A target whose subsurface inputs are in another convention than the painted ones (OpenPBR,
Standard Surface: van de Hulst; PxrSurface when the material's distance is an extinction mean
free path or its model Jensen's dipole) reads maps the bake writes beside the coefficients:
``{output}.{convention}.colour.exr`` and ``.radius.exr`` per tile (plain R, G, B: every
texture node reads them as they are). Per texel: the
medium the bake found (rho = sigma_a/sigma_t', sigma_t') is the painted colour and diffuse
mean free path of the material's own model (``Rd = rd_of_rho``, ``ld = 1/(sigma_t'
mu_tr/sigma_t')``: the Better Dipole's, or Jensen's dipole's), and ``convert`` (the
conventions registry) takes them to the target's colour and radius (docs/materials.md). A
constant material's are numbers in the manifest. Maps are rebuilt only when their
coefficients or parameters change (their header records both: ``io.freshness``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import one_line
from ..io.colour import resolve_working_space
from ..io.freshness import header_fields, is_up_to_date, params_digest
from ..io.patterns import PAINTED_MARK
from ..io.images import TextureError, Writer, is_regular_file, output_spec, read_whole
from ..io.mipmaps import texture_options
from ..io.targets import TARGET
from ..physics.conventions import CONVENTION
from ..physics.reference import mu_tr_over_sigma_t, rd_of_rho
from .layer_files import write_whole

#: what a map's layers hold
LAYERS = ("colour", "radius")


@dataclass
class Maps:
    """A material's maps of one convention: each layer's pattern and the files; or
    ``constants`` {layer: floats} for a constant material; ``error``: why none are there."""

    convention: str
    patterns: dict = field(default_factory=dict)    # {layer: its files' pattern}
    files: list = field(default_factory=list)
    constants: dict | None = None
    error: str | None = None
    written: list = field(default_factory=list)   # the files this bake wrote (not up to date)


def painted_convention(model: str) -> str:
    """The convention a model's painted colour and diffuse mean free path are in (the
    conventions registry names each model: better-dipole, dipole)."""
    return CONVENTION.canonical(model)


def conventions_needed(m) -> list:
    """The conventions of ``m``'s targets that its painted inputs are not already in (a
    diffuse mean free path in its own model's convention is read as painted)."""
    own = painted_convention(m.model) if m.mfp_kind == "diffuse" else None
    wanted = [TARGET[t].convention for t in m.targets if TARGET[t].convention]
    return sorted({c for c in wanted if c != own})


def medium(values: dict) -> tuple | None:
    """(rho, sigma_t') of the coefficients ``values`` ({output: array}), else None (the
    outputs give no scale: alpha and rho alone)."""
    sa, ss, st = values.get("sigma_a"), values.get("sigma_s"), values.get("sigma_t")
    rho = values.get("rho")
    if rho is None and values.get("alpha") is not None:
        rho = 1.0 - values["alpha"]
    if st is None and sa is not None and ss is not None:
        st = sa + ss
    if st is None and rho is not None and sa is not None:
        st = sa / rho
    if st is None and rho is not None and ss is not None:
        st = ss / (1.0 - rho)
    if rho is None and st is not None and (sa is not None or ss is not None):
        rho = sa / st if sa is not None else 1.0 - ss / st
    return None if rho is None or st is None else (rho, st)


def converted(values: dict, etas, model: str, convention: str) -> tuple:
    """(colour, radius) arrays (..., C) of ``convention`` for coefficients ``values`` (each
    (..., C) float64; ``etas`` one per channel); texels with no medium (masked: 0) are 0."""
    from ..physics.conversion import convert
    found = medium(values)
    if found is None:
        raise ValueError("its outputs give no scale (alpha and rho alone): add sigma_a and "
                         "sigma_s (or sigma_t) to outputs")
    rho, st = (np.asarray(v, np.float64) for v in found)
    colour, radius = np.zeros_like(st), np.zeros_like(st)
    for c in range(st.shape[-1]):
        ok = np.isfinite(rho[..., c]) & np.isfinite(st[..., c]) & (st[..., c] > 0)
        r, s = rho[..., c][ok], st[..., c][ok]
        rd = rd_of_rho(r, etas[c], model=model)        # the painted colour of this medium
        ld = 1.0 / (s * mu_tr_over_sigma_t(r, model))   # and its diffuse mean free path
        out = convert(rd, ld, source=painted_convention(model), target=convention, eta=etas[c],
                      on_invalid="clamp")
        colour[..., c][ok], radius[..., c][ok] = out.colour, out.radius
    return colour, radius


def map_path(coefficients: str, convention: str, layer: str) -> str:
    """The ``layer`` (colour, radius) map of ``convention`` beside a coefficients file or
    pattern: one plain file per layer (R, G, B), which every texture node reads as it is."""
    return f"{coefficients[:-4]}.{convention}.{layer}.exr"


def _etas(m, n):
    return list(m.eta) * n if len(m.eta) == 1 else list(m.eta)


def write_maps(m, coefficients: str, convention: str, written: list) -> dict:
    """{layer: its map} of one coefficients file (written unless both are up to date: then
    added to ``written``); TextureError, ValueError on failure."""
    outs = {layer: map_path(coefficients, convention, layer) for layer in LAYERS}
    inputs = {"coefficients": coefficients}
    texture = texture_options(m.texture)      # every file a network reads is a texture
    digest = params_digest({"kind": "map", "convention": convention, "model": m.model,
                            "eta": list(m.eta), "source": painted_convention(m.model),
                            "texture": texture.describe() if texture else None})
    if all(is_up_to_date(out, inputs, digest) for out in outs.values()):
        return outs
    spec, px = read_whole(coefficients, "coefficients")
    names = list(spec.channelnames)
    values = {}
    for o in m.outputs:
        idx = [i for i, n in enumerate(names) if n.startswith(f"{o}.")]
        values[o] = px[..., idx].astype(np.float64)
    suffixes = [n.split(".", 1)[1] for n in names if n.startswith(f"{m.outputs[0]}.")]
    maps = dict(zip(LAYERS, converted(values, _etas(m, len(suffixes)), m.model, convention)))
    working = resolve_working_space(m.working_space)
    for layer, out in outs.items():
        header = header_fields(inputs, digest) | {PAINTED_MARK.split(":")[1]: f"{convention} "
                                                  f"{layer}"}
        write_whole(Writer(out, output_spec(spec, suffixes, -1, False, header, working=working,
                                            data=layer != "colour"), texture=texture),
                    maps[layer])
        written.append(out)
    return outs


def conversion_problem(model: str, convention: str, eta: float) -> str | None:
    """Why this build cannot convert ``model``'s painted inputs to ``convention`` at ``eta``
    (one value tried, as ``convert`` itself fails fast), else None: the plan says it before
    any texel is converted."""
    from ..physics.conversion import convert
    try:
        convert(0.5, 1.0, source=painted_convention(model), target=convention, eta=eta)
    except ImportError as exc:
        return (f"converting to {convention} needs {exc.name or 'a module'}, which this "
                f"build lacks")
    except (ValueError, NotImplementedError) as exc:
        return f"converting to {convention}: {one_line(exc)}"
    return None


def material_maps(m, files: list, coefficients: dict | None) -> dict:
    """{convention: Maps} of a baked material: its coefficient ``files``' maps, or a constant
    material's ``coefficients`` converted."""
    found = {}
    for convention in conventions_needed(m):
        maps = Maps(convention)
        problem = conversion_problem(m.model, convention, m.eta[0])
        if problem:
            maps.error = f"its {convention} maps: {problem}"
            found[convention] = maps
            continue
        try:
            if m.constant:
                values = {o: np.asarray(v, np.float64)[None] for o, v in
                          (coefficients or {}).items()}
                colour, radius = converted(values, _etas(m, len(next(iter(values.values()))
                                                                [0])), m.model, convention)
                maps.constants = {"colour": [float(v) for v in colour[0]],
                                  "radius": [float(v) for v in radius[0]]}
            else:
                maps.patterns = {layer: map_path(m.output, convention, layer)
                                 for layer in LAYERS}
                for f in files:
                    maps.files += list(write_maps(m, f, convention, maps.written).values())
        except ImportError as exc:       # a convention whose conversion this build lacks
            maps.error = (f"its {convention} maps: converting to {convention} needs "
                          f"{exc.name or 'a module'}, which this build lacks")
        except (TextureError, ValueError, OSError, NotImplementedError) as exc:
            maps.error = f"its {convention} maps: {one_line(exc)}"   # (a conversion not built)
        found[convention] = maps
    return found


def remove_stale_maps(old_files, kept, folder, inputs) -> list:
    """Remove the maps an earlier bake wrote (``old_files``, relative to ``folder``) that this
    one did not (``kept``): a tile gone, a target dropped; only regular files in the folder
    that no job reads."""
    root = os.path.realpath(folder)
    kept = {os.path.realpath(k) for k in kept}
    removed = []
    for f in old_files or []:
        path = os.path.normpath(os.path.join(folder, str(f)))
        real = os.path.realpath(path)
        if real in kept or real in inputs or not real.startswith(root + os.sep) or \
                not is_regular_file(path):
            continue
        os.unlink(path)
        removed.append(path)
    return removed


def target_maps(scene, jobs, results, coefficients, outcome) -> dict:
    """{material: {convention: scene_maps.Maps}} of every baked material whose targets read
    its colour and radius in another convention (written beside its coefficients;
    ``outcome``: scene_records' (files written, failures) of a material's jobs)."""
    found = {}
    for m in scene.materials:
        files, failed = outcome(m, jobs, results)
        if not failed and conventions_needed(m):
            found[m.name] = material_maps(m, files, coefficients.get(m.name))
    return found


def maps_entry(maps, folder) -> dict:
    """A material's maps as the manifest records them (paths relative to ``folder``)."""
    out = {}
    for conv, mp in (maps or {}).items():
        entry = {"error": mp.error} if mp.error else {}
        if mp.constants is not None:
            entry["constants"] = mp.constants
        elif not mp.error:
            entry |= {layer: "./" + os.path.relpath(p, folder).replace(os.sep, "/")
                      for layer, p in mp.patterns.items()}
            entry["files"] = sorted(os.path.relpath(f, folder) for f in mp.files)
        out[conv] = entry
    return out
