"""The end of a bake (the jobs layer): each job's row named by its material or blur, the
records written (``scene_records.write_records``), and a failed row for each material of the
stage or document that has a subsurface but could not be baked (``ImportedMaterial.left_out``
of a subsurface material): a bake that leaves one unbaked has failed, it is no success."""
from __future__ import annotations

from .results import BatchReport, FileResult
from .scene_records import DROPPED, LAYERED, MAPPED, REMOVED, write_records


def unbaked_materials(scene) -> list:
    """A failed row for each imported subsurface material left out (not bakeable)."""
    return [FileResult(f"material {imp.name} ({imp.path})", error=f"not baked: {imp.left_out}")
            for imp in scene.imports if imp.left_out and imp.subsurface]


def finish_bake(plan, results: list) -> BatchReport:
    """The records of a bake of ``plan`` (a scene Plan), each file written added to the report;
    each job's row names its material or blur (jobs may share an input file)."""
    for job, result in zip(plan.jobs, results):
        if job.kind != "constant":
            result.path = f"{job.name}: {job.source}"
    # each a file beside the outputs (``companion``: the summary counts them apart)
    records = [FileResult(p, p, status="ok", notes=["records"], companion=True) if why is None
               else FileResult(p, f"removed {p}: an earlier bake's output that no input makes "
                                  f"now", status="ok", notes=["removed"], companion=True)
               if why == REMOVED else
               FileResult("records", p, status="ok", notes=[DROPPED], companion=True)
               if why == DROPPED else
               FileResult(p, p, status="ok", notes=[why], companion=True)
               if why in (MAPPED, LAYERED) else
               FileResult(p, p, error=why, companion=True)
               for p, why in write_records(plan, results)]
    return BatchReport(results + records + unbaked_materials(plan.scene))
