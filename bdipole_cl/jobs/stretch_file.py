"""Stretch jobs: one UDIM tile's stretch maps from a scene's meshes (``job.StretchWork``),
written as every output is (temporary file, read back, rename) with the up-to-date key in its
header; ``run_stretch`` is their runner (``runner.run_job``). And how a scene blur reads the
maps back, in its material's unit (docs/scenes.md "Stretch")."""
from __future__ import annotations

import time
from dataclasses import replace

from ..errors import one_line
from ..io.freshness import InputChanged, InputGuard
from ..io.images import TextureError
from ..io.mesh_sets import read_mesh_set, time_words
from ..io.scene_keys import UNIT_METERS
from ..io.stretch_maps import read_stretch, write_tile
from ..ops.stretch import stretch_tiles
from ..signals import Stopped
from .results import FileResult


def run_stretch(job, runtime, *, cancel=None, lock=None, progress=None) -> FileResult:
    """Run one stretch job: read its meshes, check they are the geometry the plan read (else
    nothing is written), rasterize its tile and write it. A FileResult, never a raise."""
    w = job.work
    result = FileResult(job.source, job.output)
    t0 = time.perf_counter()
    guard = InputGuard(job.inputs, job.identities)
    try:
        meshes = read_mesh_set(w.source, w.material, w.mesh_unit)
        if meshes.digest != w.digest:
            raise InputChanged(f"{w.source}: the meshes' geometry differs from the plan's "
                               f"(changed since): nothing written; run it again")
        (tile,) = stretch_tiles(meshes.meshes, w.size, UNIT_METERS[w.unit], w.unit,
                                tiles=[w.tile])
        if cancel is not None and cancel.is_set():
            raise Stopped()
        when = "" if meshes.time is None else time_words(meshes.time)
        header = w.header | {"stretch_meshes": ", ".join(meshes.prims), "stretch_time": when}
        write_tile(tile, job.output, w.source, meshes.meters_per_unit, header, guard.check)
        result.status = "ok"
        result.texels = int(w.size[0]) * int(w.size[1])
        result.notes = [f"stretch u {tile.su.min():.4g}..{tile.su.max():.4g}, v "
                        f"{tile.sv.min():.4g}..{tile.sv.max():.4g} {w.unit} a texel"]
    except Stopped:
        result.status, result.error = "cancelled", f"{job.output}: interrupted; nothing written"
    except (TextureError, OSError, ValueError, RuntimeError) as exc:   # MeshError,
        result.error = one_line(exc)          # StretchError, SceneError; pxr's Tf errors
    result.seconds = time.perf_counter() - t0
    return result


def scene_stretch(path, unit):
    """The ``ops.blur.stretched.Stretch`` of a stretch map file (``io.stretch_maps``) with its
    lengths in ``unit`` (a scene material's): converted from the unit its header records; a
    TextureError naming the file where it records none this tool knows."""
    s = read_stretch(path)
    if s.unit == unit:
        return s
    if s.unit not in UNIT_METERS:
        raise TextureError(f"{path}: stretch maps with lengths in {s.unit or 'no unit'!r} "
                           f"(bdipole:stretch_unit); a scene needs one of "
                           f"{', '.join(UNIT_METERS)} to convert them into {unit}")
    factor = UNIT_METERS[s.unit] / UNIT_METERS[unit]
    return replace(s, su=s.su * factor, sv=s.sv * factor, unit=unit)
