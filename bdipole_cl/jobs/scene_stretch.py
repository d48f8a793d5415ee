"""A scene blur's stretch (the jobs layer; docs/scenes.md "Stretch"): the stretch job of each
tile whose maps the bake makes from meshes (those a stage binds the blur's material to, or a
mesh file's), planned with their geometry's digest as the up-to-date key; the blur that reads
them waits for them (``blocked``); and what the records say of them.

The maps of a blur's tile are ``{its output without .exr}.stretch.exr`` at the irradiance
tile's size, lengths in the material's unit. They are rebuilt only when the meshes' geometry
(points in world space at the bake's time code, texture coordinates, faces bound), the size or
the unit change: not when another part of the stage does. A blur whose maps are rebuilt is
blurred again; one whose maps are unchanged is up to date as before.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, replace

from ..errors import one_line
from ..io.freshness import header_fields, input_identities, is_up_to_date, params_digest
from ..io.images import TextureError, image_header
from ..io.mesh_sets import is_earliest, read_mesh_set
from ..io.patterns import companion_path
from ..io.scene_keys import BOUND, UNIT_METERS
from ..io.stretch_maps import CHANNELS
from ..io.tiles import TileError
from ..ops.stretch import check_tiles, mesh_tiles
from .job import StretchWork
from .planned import PlannedJob
from .results import FileResult


@dataclass
class BlurStretch:
    """Where a blur tile's stretch maps come from: ``file``, made by ``job`` (a "stretch"
    PlannedJob; None: the user's maps, read), or why there are none (``problem``), and the
    words the blur's plan says of them."""

    file: str | None
    job: PlannedJob | None = None
    problem: str | None = None
    words: str = ""

    @property
    def runs(self) -> bool:
        """Whether the bake makes the maps anew (so the blur that reads them runs too)."""
        return self.job is not None and not (self.job.up_to_date or self.job.problem)


def stretch_output(blur_output: str) -> str:
    """The stretch maps' file (or pattern) of a blur's output (file or pattern)."""
    return f"{blur_output[:-4]}.stretch.exr"


def mesh_source(scene, b) -> tuple:
    """(mesh file, material prim path or None) of a blur whose stretch is made from meshes."""
    if b.stretch != BOUND:
        return b.stretch, None
    imp = next(i for i in scene.imports if i.name == b.material.name)
    return scene.source, imp.path


def read_cached(cache, source, material, mesh_unit):
    """``io.mesh_sets.read_mesh_set`` once per plan (``cache``: a dict), or the one-line
    reason it cannot be read (a str)."""
    key = (source, material, mesh_unit)
    if key not in cache:
        try:
            cache[key] = read_mesh_set(source, material, mesh_unit)
            for mesh in cache[key].meshes:
                check_tiles(mesh)
        except (OSError, ValueError, RuntimeError) as exc:   # MeshError, StretchError,
            cache[key] = one_line(exc)                      # SceneError; pxr's Tf errors
    return cache[key]


def stretch_tile(meshes, tile, irradiance) -> tuple:
    """(u, v) of the UDIM tile whose stretch a blur of ``irradiance`` (its ``tile``, None
    without a tile token) needs; a ValueError where the meshes cover none, or several and the
    irradiance names no tile."""
    covered = set().union(*(mesh_tiles(m) for m in meshes.meshes))
    names = ", ".join(str(1001 + u + 10 * v) for u, v in sorted(covered, key=lambda t: t[::-1]))
    if tile is None:
        if len(covered) != 1:
            raise ValueError(f"irradiance {irradiance} has no tile token and the meshes cover "
                             f"UDIM {names}: name the irradiance with <UDIM>")
        return next(iter(covered))
    if (tile.u, tile.v) not in covered:
        raise ValueError(f"no triangle of the meshes reaches UDIM {tile.label} (they cover "
                         f"{names})")
    return tile.u, tile.v


def plan_stretch(scene, b, irradiance, tile, blur_out, force, cache) -> BlurStretch:
    """The BlurStretch of one tile of blur ``b`` (its ``irradiance`` file and ``tile``, its
    output ``blur_out``): the user's maps, or a stretch job (up to date, to run, or that cannot
    run, with its reason)."""
    if b.stretch != BOUND and b.stretch.lower().endswith(".exr"):
        try:
            file = companion_path(b.stretch, irradiance, tile)
        except (TextureError, TileError) as exc:
            return BlurStretch(None, problem=f"stretch maps: {exc}")
        return BlurStretch(file, words=f"the stretch maps {file}")
    source, material = mesh_source(scene, b)
    out = stretch_output(blur_out)
    job = PlannedJob("stretch", b.name, source, tile.label if tile else None, out,
                     {"mesh": source}, identities=input_identities({"mesh": source}))
    meshes = read_cached(cache, source, material, b.mesh_unit)
    header = image_header(irradiance)
    try:
        if isinstance(meshes, str):
            raise ValueError(meshes)
        if header is None:
            raise ValueError(f"irradiance {irradiance} cannot be read for its size")
        where = stretch_tile(meshes, tile, irradiance)
    except ValueError as exc:
        job.problem = f"stretch maps: {exc}"
        return BlurStretch(out, job, job.problem)
    size, unit = (header.height, header.width), b.material.unit
    job.params_digest = params_digest({"kind": "stretch", "geometry": meshes.digest,
                                       "tile": where, "size": size, "unit": unit})
    job.work = StretchWork(source, material, b.mesh_unit, where, size, unit, meshes.digest,
                           header_fields({}, job.params_digest), meshes.prims, meshes.time)
    if not force and is_up_to_date(out, {}, job.params_digest):
        job.up_to_date = True
        job.left_out.append("everything: up to date (the meshes' geometry, size and unit "
                            "unchanged)")
    else:
        job.computes.append(f"stretch maps of UDIM {1001 + where[0] + 10 * where[1]} at "
                            f"{size[1]}x{size[0]} texels from the {meshes.describe()}, lengths "
                            f"in {unit} ({UNIT_METERS[unit]:g} m)")
    return BlurStretch(out, job, words=f"the stretch maps {out}, made from the "
                                       f"{meshes.describe()}")


def blocked(job, made: dict) -> FileResult | None:
    """The result of a blur whose stretch maps a job of this bake was to make and did not
    (``made``: {stretch output: its FileResult}); None where it can run."""
    needs = job.inputs.get("stretch") if job.kind == "blur" else None
    done = made.get(needs)
    if done is None or done.status in ("ok", "skipped"):
        return None
    return FileResult(job.source, job.output, error=f"its stretch maps {needs} were not made: "
                                                    f"{done.error or done.status}")


def with_maps_header(job):
    """A blur ``job`` (``job.Job``) that reads stretch maps a job of this bake made, with its
    output header's record of its inputs (``freshness.header_fields``: their stat and content
    digest) taken now, once they are written."""
    return replace(job, work=replace(job.work, header=job.work.header
                                     | header_fields(job.inputs, job.key)))


# {{{ records

def _relative(path, folder) -> str:
    return "./" + os.path.relpath(path, folder).replace(os.sep, "/")


def stretch_records(scene, jobs, results, folder) -> dict:
    """{material: {blur: its stretch record}} of every blur with a stretch (the manifest's
    ``stretch``; paths relative to ``folder``): where the maps come from, their pattern, the
    files made or up to date (or read), the meshes and time code, the unit and channels, and
    why any tile's maps are missing."""
    found = {}
    for b in scene.blurs:
        if b.stretch is None:
            continue
        given = b.stretch != BOUND and b.stretch.lower().endswith(".exr")
        record = {"from": "maps" if given else b.stretch if b.stretch == BOUND else "mesh file",
                  "maps": _relative(b.stretch if given else stretch_output(b.output), folder),
                  "unit": b.material.unit, "charts": b.charts, "channels": list(CHANNELS)}
        files, errors = [], []
        for j, r in zip(jobs, results):
            if j.name != b.name or j.kind != ("blur" if given else "stretch"):
                continue
            path = j.inputs.get("stretch") if given else j.output
            if r is not None and r.status not in ("ok", "skipped") and not given:
                errors.append(f"{j.output}: {r.error or r.status}")
            elif path and os.path.isfile(path):
                files.append(os.path.relpath(path, folder))
            if j.kind == "stretch" and isinstance(j.work, StretchWork):
                record["source"] = os.path.relpath(j.source, folder)
                record["prims"] = list(j.work.prims) if j.work.material else []
                record["time_code"] = time_record(j.work.time)
        record["files"] = sorted(set(files))
        header = image_header(os.path.join(folder, files[0])) if files else None
        if header is not None:           # as a reader finds them (EXR sorts its channels)
            record["channels"] = list(header.channelnames)
        if errors:
            record["errors"] = errors
        found.setdefault(b.material.name, {})[b.name] = record
    return found


def time_record(value):
    """A time code's value as the manifest records it: a number, "earliest" (USD's
    EarliestTime: a stage without a time range) or None (an OBJ)."""
    return None if value is None else "earliest" if is_earliest(value) else value


def made_files(entries) -> list:
    """The stretch map files a manifest's material ``entries`` record as made by the bake
    (never the user's: those are inputs), relative to its folder."""
    return [f for e in entries for r in (e.get("stretch") or {}).values()
            if isinstance(r, dict) and r.get("from") != "maps" for f in r.get("files") or []]

# }}}
