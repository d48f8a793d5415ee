"""What an earlier bake left that this one does not make (the jobs layer; ``scene_records``
calls them): its outputs no job makes now, removed, and the materials whose records are gone,
said."""
from __future__ import annotations

import os

from ..io.images import is_regular_file


def dropped_records(old: dict, records: dict) -> list:
    """One line per material the last bake recorded as baked (``old``: its manifest) that
    these ``records`` do not: its inputs vanished, it failed, or it left the scene; its
    ``over`` (and so its records and material networks) is gone from the layer, which a
    pipeline reading the layer would otherwise not know."""
    now = {e["name"]: e for e in records["materials"]}
    lines = []
    for name, entry in sorted(old.items()):
        new = now.get(name)
        if not entry.get("baked") or (new is not None and new.get("baked")):
            continue
        why = ("no longer in the scene" if new is None else
               new.get("not_baked") or new.get("left_out") or "not baked")
        lines.append(f"material {name} ({entry.get('prim') or 'scene file'}): its records "
                     f"are removed: {why}")
    return lines


def remove_stale_outputs(old, jobs, folder, inputs) -> list:
    """Remove, and return, the output files an earlier bake in ``folder`` wrote for a material
    this bake makes again (its manifest ``old``'s ``files``) that no job of this bake makes: a
    tile whose albedo tile is gone, say, which the records' <UDIM> pattern would still give a
    renderer. Only regular files in the folder that this bake does not read."""
    making = {os.path.normpath(j.output) for j in jobs if j.output}
    names = {j.name for j in jobs if j.kind == "invert"}
    root = os.path.realpath(folder)
    removed = []
    for name, entry in old.items():
        for f in (entry.get("files") or []) if name in names else []:
            path = os.path.normpath(os.path.join(folder, str(f)))
            real = os.path.realpath(path)
            if (path in making or real in inputs or not real.startswith(root + os.sep)
                    or not is_regular_file(path)):
                continue
            os.unlink(path)
            removed.append(path)
    return removed
