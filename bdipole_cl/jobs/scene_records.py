"""What a bake of an imported scene writes beside its outputs (the jobs layer): constant materials'
coefficients, ``bdipole_materials.json`` (every material: its mapped inputs, convention, eta,
unit, output files, and a constant one's coefficients) and ``bdipole.usda`` (an ``over`` on
each baked material prim with ``bdipole:`` attributes: the output files as asset paths with
``<UDIM>``, a constant material's coefficients), so that a pipeline finds them by sublayering
it. Both are rewritten only when their content changes (temporary file + rename), with the
mode any file the process creates gets (0666 less the umask), as the images have.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time

import numpy as np

from ..durable import durable_replace
from ..io.images import is_regular_file
from ..io.networks import networks
from ..io.scene_import import source_files
from ..io.shaders import SHADERS
from ..methods.choice import resolve_method
from ..methods.registry import MethodConfig
from ..ops.invert import albedo_to_coefficients
from .results import FileResult
from .layer_files import coefficient_layers
from .scene_maps import maps_entry, remove_stale_maps, target_maps
from .scene_stale import dropped_records, remove_stale_outputs
from .scene_stretch import made_files, stretch_records
from .scene_layer import (LAYER_MARK, baked_material, layer_unit, mtlx_text,
                          output_channels, target_lines, usd_layer_text)

#: where each shader's distance convention is defined
SOURCES = {s.name: s.source for s in SHADERS}

MANIFEST = "bdipole_materials.json"
LAYER = "bdipole.usda"
DOCUMENT = "bdipole.mtlx"
#: what a scene's mfp_kind means, for the plan
MFP_MEANING = {"diffuse": "mfp = ld = 1/mu_tr", "extinction": "sigma_t' = 1/mfp"}


def records_dir(scene) -> str | None:
    """The folder of the records: beside the first material's outputs (None: a scene with
    neither imported nor constant materials writes none)."""
    if scene.source is None and not any(m.constant or m.targets for m in scene.materials):
        return None
    if scene.materials:
        return os.path.dirname(scene.materials[0].output)
    return os.path.join(os.path.dirname(str(scene.path)), "bdipole")


def constant_coefficients(m, config: MethodConfig, runtime) -> dict:
    """{output: per-channel floats} of a material whose albedo and mfp are constants."""
    n = max(len(m.albedo), len(m.mfp), len(m.mfp_scale), len(m.eta))
    rd = np.broadcast_to(np.asarray(m.albedo, np.float64), (n,))
    mfp = np.broadcast_to(np.asarray(m.mfp, np.float64) * np.asarray(m.mfp_scale), (n,))
    eta = m.eta if len(m.eta) > 1 else m.eta[0]
    outs = albedo_to_coefficients(rd, mfp, eta, config, model=m.model, exact=m.exact,
                                  double=m.double, on_invalid=m.on_invalid, outputs=m.outputs,
                                  mfp_kind=m.mfp_kind, device=runtime)
    outs = outs if len(m.outputs) > 1 else (outs,)
    return {o: [float(v) for v in vals] for o, vals in zip(m.outputs, outs)}


def mfp_text(m) -> str:
    """What a job's mfp is, for the plan."""
    scale = m.mfp_scale != (1.0,)
    return (f"mfp as {m.mfp_kind} ({MFP_MEANING[m.mfp_kind]})"
            + (f", scaled by {', '.join(f'{v:g}' for v in m.mfp_scale)}" if scale else ""))


def constant_text(m, config) -> str:
    """What a constant material's job computes, for the plan."""
    mfp = np.asarray(m.mfp) * np.asarray(m.mfp_scale)
    return (f"{', '.join(m.outputs)} of albedo {', '.join(f'{v:g}' for v in m.albedo)}, mfp "
            f"{', '.join(f'{v:g}' for v in mfp)} {m.unit} as {m.mfp_kind} "
            f"({MFP_MEANING[m.mfp_kind]}) with {config.describe(m.double)}")


def constant_config(m) -> MethodConfig:
    return resolve_method(m.method, double=m.double, tol=m.tol)


def coefficients_digest(values) -> str:
    """A digest of a constant material's recorded coefficients: an edit of them in the
    manifest is seen (the job is computed again), never passed on as up to date."""
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:32]


def manifest_record(folder):
    """The manifest in ``folder`` as this tool wrote it (a JSON object with its scene and a
    list of materials), else None: none there, not a regular file (a FIFO is never opened:
    it would block), or not this tool's (``records_refusal`` then says so)."""
    path = os.path.join(folder, MANIFEST)
    if not is_regular_file(path):
        return None
    try:
        with open(path) as f:
            record = json.load(f)
    except (OSError, ValueError):
        return None
    ours = (isinstance(record, dict) and isinstance(record.get("scene"), str)
            and isinstance(record.get("materials"), list))
    return record if ours else None


def read_manifest(folder) -> dict:
    """{material name: its entry} of an existing manifest of this tool's ({} when none)."""
    record = manifest_record(folder)
    entries = record["materials"] if record else []
    return {e["name"]: e for e in entries if isinstance(e, dict) and isinstance(e.get("name"), str)}


def record_paths(scene, folder) -> list:
    """The records' paths in ``folder``: the manifest, and for a stage or document the layer."""
    return [os.path.join(folder, MANIFEST)] + (
        [os.path.join(folder, LAYER), os.path.join(folder, DOCUMENT)]
        if writes_materials(scene) else [])


def writes_materials(scene) -> bool:
    """Whether a bake writes the USD layer and MaterialX document: a stage's or document's
    (its records), or a scene file's with targets."""
    return scene.source is not None or any(m.targets for m in scene.materials)


def records_refusal(scene, folder, inputs, force=False) -> str | None:
    """Why the records cannot be written in ``folder`` (one line), else None: something not
    a regular file at one of their paths (a directory, a FIFO: always), or a file this tool
    did not write there (its manifest, or its layer by LAYER_MARK) unless ``force``. An
    input there (``inputs``: ``record_inputs``; the stage's own layer) is not refused here:
    the images bake, and that record alone is not written (``records_over_input``, named in
    the plan)."""
    if folder is None:
        return None
    for path in record_paths(scene, folder):
        if not os.path.lexists(path) or os.path.realpath(path) in inputs:
            continue
        if not is_regular_file(path):
            return (f"{path} is not a regular file (a directory, FIFO or link to none); the "
                    f"bake's records go there: move it")
        ours = (manifest_record(folder) is not None if path.endswith(MANIFEST) else
                own_document(path) if path.endswith(DOCUMENT) else bool(own_layers(folder)))
        if not ours and not force:
            return (f"{path} exists and was not written by bdipole-cl (or was changed since); "
                    f"the bake's records go there: move it, or pass --force to replace it")
    return None


def records_owner(folder) -> str | None:
    """The scene file whose bake wrote the manifest in ``folder``, where it is now: by its
    path relative to the folder (so a copied or moved asset folder is still its own), else as
    recorded; None where there is no readable manifest, or that file is gone (renamed or
    removed: no other scene to protect)."""
    record = manifest_record(folder)
    if record is None:
        return None
    relative, recorded = record.get("scene_relative"), record.get("scene")
    for candidate in (os.path.join(folder, relative) if isinstance(relative, str) else None,
                      recorded if isinstance(recorded, str) else None):
        if candidate and os.path.isfile(candidate):
            return candidate
    return None


def foreign_records(scene, folder) -> str | None:
    """Why ``folder``'s records belong to the bake of another scene file (one line), else
    None: two stages (or scene files) beside one another share ``bdipole/``, and a bake of
    one would replace the other's records and the outputs of its materials of the same
    names, all of them this tool's files."""
    owner = None if folder is None else records_owner(folder)
    if owner is None or os.path.samefile(owner, str(scene.path)):
        return None
    return (f"{os.path.join(folder, MANIFEST)} records the bake of {owner}: a bake of "
            f"{scene.path} there would replace its records and the outputs of its materials "
            f"of the same names; give this scene its own output folder (a scene file with "
            f"materials_from and `output`), or --force")


def _relative(path, folder):
    return "./" + os.path.relpath(path, folder).replace(os.sep, "/")


def manifest(scene, jobs, coefficients, folder, results=None, maps=None) -> dict:
    """The manifest's content: every material of the scene (imported ones first, left-out
    ones with their reason); a material is baked when every one of its jobs wrote its
    output or found it up to date (``results``, in the order of ``jobs``; None: all did)."""
    by_name = {m.name: m for m in scene.materials}
    entries, seen = [], set()
    for imp in scene.imports:
        seen.add(imp.name)
        entry = {"name": imp.name, "prim": imp.path, "shader": imp.shader,
                 "inputs": imp.inputs, "baked": False}
        if imp.shader in SOURCES:
            entry["convention"] = f"{imp.mfp_kind}: {SOURCES[imp.shader]}"
        if imp.left_out:
            entry["left_out"] = imp.left_out
        if imp.notes:
            entry["notes"] = list(imp.notes)
        if imp.name in by_name:
            entry.update(_baked(by_name[imp.name], jobs, results, coefficients, folder,
                                imp.unit_m, (maps or {}).get(imp.name)))
        entries.append(entry)
    for m in scene.materials:
        if m.name not in seen:
            entries.append({"name": m.name} | _baked(m, jobs, results, coefficients, folder,
                                                     layer_unit(scene),
                                                     (maps or {}).get(m.name)))
    return {"source": scene.source, "scene": str(scene.path),
            "scene_relative": os.path.relpath(str(scene.path), folder), "materials": entries}


def _outcome(m, jobs, results) -> tuple:
    """([output files written or up to date], [why each other job of ``m`` is not])."""
    files, failed = [], []
    for j, r in zip(jobs, results if results is not None else [None] * len(jobs)):
        if j.name != m.name or j.kind not in ("invert", "constant"):
            continue
        done = r is None or r.status in ("ok", "skipped")
        if j.kind == "invert" and done and j.output and os.path.isfile(j.output):
            files.append(j.output)
        elif j.kind == "invert" or not done:
            why = (r.error if r is not None and r.error else
                   "its output is missing" if done else r.status)
            failed.append(f"{j.source}" + (f" [{j.udim}]" if j.udim else "") + f": {why}")
    return files, failed


def _baked(m, jobs, results, coefficients, folder, stage_unit_m, maps=None) -> dict:
    written, failed = _outcome(m, jobs, results)
    if m.constant and not coefficients.get(m.name) and not failed:
        failed.append("no coefficients computed")
    files = sorted(os.path.relpath(f, folder) for f in written)
    entry = {"baked": not failed, **({"not_baked": "; ".join(failed)} if failed else {}),"mfp_kind": m.mfp_kind, "eta": list(m.eta), "unit": m.unit,
             "coefficient_unit": f"1/{m.unit}", "outputs": list(m.outputs),
             "albedo": m.albedo if isinstance(m.albedo, str) else list(m.albedo),
             "mfp": m.mfp if isinstance(m.mfp, str) else list(m.mfp),
             "mfp_scale": list(m.mfp_scale), "colorspace": m.colorspace}
    if m.constant:
        entry["coefficients"] = coefficients.get(m.name)
        entry["coefficients_digest"] = coefficients_digest(entry["coefficients"])
        entry["params_digest"] = next((j.params_digest for j in jobs if j.name == m.name
                                       and j.kind == "constant"), "")
    else:
        entry["output"] = _relative(m.output, folder)
        entry["files"] = files
        entry["channels"], entry["first_channel"] = output_channels(written, m.outputs)
    entry["stage_unit_m"] = stage_unit_m
    if maps:
        entry["maps"] = maps_entry(maps, folder)
    if not failed:
        written_networks, why = networks(baked_material(m, entry, stage_unit_m), folder)
        entry["targets"] = {n.target.name: "written" for n in written_networks} | {
            t: f"not written: {w}" for t, w in why.items()}
    return entry


def default_mode() -> int:
    """The mode a plain ``open(path, "w")`` gives a new file: 0o666 less the process umask
    (read from /proc where it can be, so the umask is never changed, even for a moment)."""
    try:
        with open("/proc/self/status") as f:
            umask = next(int(line.split()[1], 8) for line in f if line.startswith("Umask:"))
    except (OSError, StopIteration, ValueError, IndexError):
        umask = os.umask(0o022)
        os.umask(umask)
    return 0o666 & ~umask


def write_if_changed(path, text: str) -> bool:
    """Write ``text`` to ``path`` (temporary file + rename) unless it already holds it (read
    only where it is a regular file: a FIFO would block)."""
    try:
        if is_regular_file(path):
            with open(path) as f:
                if f.read() == text:
                    return False
    except (OSError, UnicodeDecodeError):
        pass
    folder = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(path), dir=folder)
    try:
        os.chmod(tmp, default_mode())       # mkstemp's 0600 is for the temporary name only
        with os.fdopen(fd, "w") as f:
            f.write(text)
        with open(tmp) as f:
            if f.read() != text:
                raise OSError(f"{tmp}: written content differs from what was written")
        durable_replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return True


def record_inputs(scene, folder, jobs) -> set:
    """The real paths the records must never replace: the scene file, every layer its stage
    is made of (but the records layer itself, sublayered over it) and every job's inputs."""
    inputs = {os.path.realpath(str(scene.path))}
    if scene.source:
        inputs |= source_files(scene.source) - own_layers(folder)
    return inputs | {os.path.realpath(p) for j in jobs for p in (j.source, *j.inputs.values())
                     if p}


def records_over_input(scene, folder, inputs) -> str | None:
    """Why the records cannot be written (one of them would replace one of ``inputs``,
    ``record_inputs``: a stage's own layer named bdipole.usda beside it), known before any
    work; else None."""
    if folder is None:
        return None
    for path in record_paths(scene, folder):
        if os.path.realpath(path) in inputs:
            return (f"{path}: the bake's record would overwrite an input (a layer of the "
                    f"stage, or a file a job reads); put the outputs in another folder (a "
                    f"scene file with materials_from and `output`)")
    return None


def own_document(path) -> bool:
    """Whether the MaterialX document at ``path`` is this tool's (its first comment carries
    LAYER_MARK)."""
    try:
        with open(path, errors="replace") as f:
            return f"<!--{LAYER_MARK}" in f.read(400).replace("<!-- ", "<!--")
    except OSError:
        return False


def own_layers(folder) -> set:
    """{the records layer's real path} where the file there is this tool's (its comment
    carries LAYER_MARK: docs/scenes.md's way to use it is to sublayer it over the stage, which
    makes it one of the stage's layers), else {} (a user's layer there is an input)."""
    path = os.path.join(folder, LAYER)
    try:
        from pxr import Sdf
        layer = Sdf.Layer.OpenAsAnonymous(path) if is_regular_file(path) else None
    except Exception:                    # pxr raises Tf.ErrorException on a bad layer
        return set()
    return {os.path.realpath(path)} if layer is not None and \
        layer.comment.startswith(LAYER_MARK) else set()


def write_records(plan, results) -> list:
    """Write the manifest (and, for an imported scene, the USD layer) of a bake, never over
    an input; [(path, None) written or (path, why not)] ([] when nothing changed)."""
    scene = plan.scene
    folder = records_dir(scene)
    if folder is None:
        return []
    if plan.records_problem:                   # another scene's records: never replaced
        return [(os.path.join(folder, MANIFEST), plan.records_problem)]
    old = read_manifest(folder)
    coefficients = {}
    for job, result in zip(plan.jobs, results):
        if job.kind != "constant":
            continue
        if result.values:
            coefficients[job.name] = result.values
        elif job.up_to_date and old.get(job.name, {}).get("coefficients"):
            coefficients[job.name] = old[job.name]["coefficients"]
    maps = target_maps(scene, plan.jobs, results, coefficients, _outcome)
    records = manifest(scene, plan.jobs, coefficients, folder, results, maps)
    layered, layer_rows = coefficient_layers(
        scene.materials if writes_materials(scene) else (),
        lambda m: _outcome(m, plan.jobs, results), plan.record_inputs)
    for entry in records["materials"]:
        if entry.get("baked") and entry["name"] in layered:
            entry["layer_files"] = sorted(os.path.relpath(f, folder)
                                          for f in layered[entry["name"]])
    stretch = stretch_records(scene, plan.jobs, results, folder)
    for entry in records["materials"]:        # each blur's stretch, under its material
        entry.update({"stretch": stretch[entry["name"]]} if entry["name"] in stretch else {})
    texts = {os.path.join(folder, MANIFEST): json.dumps(records, indent=1, sort_keys=True)
             + "\n"}
    if writes_materials(scene):
        texts[os.path.join(folder, LAYER)] = usd_layer_text(scene, records, folder)
        texts[os.path.join(folder, DOCUMENT)] = mtlx_text(scene, records, folder)
    inputs = plan.record_inputs              # taken by the plan (the stage opened once)
    written = [(path, REMOVED) for path in remove_stale_outputs(old, plan.jobs, folder, inputs)]
    written += [(path, REMOVED) for path in remove_stale_maps(
        [f for e in old.values() for m in (e.get("maps") or {}).values()
         if isinstance(m, dict) for f in m.get("files") or []],
        [f for ms in maps.values() for m in ms.values() for f in m.files], folder, inputs)]
    written += [(path, REMOVED) for path in remove_stale_maps(
        [f for e in old.values() for f in e.get("layer_files") or []],
        [f for fs in layered.values() for f in fs], folder, inputs)]
    written += [(path, REMOVED) for path in remove_stale_maps(
        made_files(old.values()), made_files(records["materials"]), folder, inputs)]
    written += [(path, why or LAYERED) for path, why in layer_rows]
    written += [(line, DROPPED) for line in dropped_records(old, records)]
    written += [(path, MAPPED) for ms in maps.values() for mp in ms.values()
                for path in mp.written]
    for path, text in texts.items():
        if os.path.realpath(path) in inputs:
            written.append((path, f"{path}: the bake's record would overwrite an input; "
                                  f"put the outputs in another folder"))
        elif write_if_changed(path, text):
            written.append((path, None))
    return written


def imported_lines(scene) -> list:
    """What the plan says about each material of a stage or document: its shader, the
    mapped inputs and convention, or why it is left out."""
    if scene.source is None:
        return []
    lines = [f"materials from {scene.source}:"]
    baked = {m.name: m for m in scene.materials}
    for imp in scene.imports:
        head = f"material {imp.name} ({imp.path}, {imp.shader})"
        if imp.bound is False:
            head += ", bound to no geometry"
        if imp.left_out:
            lines.append(f"{head}: {imp.left_out}")
            lines += [f"  input {d}" for d in imp.inputs.values()] if "bakeable" in \
                imp.left_out else []
            continue
        m = baked[imp.name]
        lines.append(f"{head}: mfp_kind {m.mfp_kind} ({MFP_MEANING[m.mfp_kind]}), eta "
                     f"{', '.join(f'{e:g}' for e in m.eta)}, coefficients in 1/{m.unit}")
        lines += [f"  input {d}" for d in imp.inputs.values()]
        lines += [f"  note: {n}" for n in imp.notes]
        lines += target_lines(m, imp.unit_m, records_dir(scene))
    return lines


def run_constant(job, runtime, *, cancel=None, lock=None, progress=None):
    """A constant material's coefficients (in the result's ``values`` and notes): the runner
    of "constant" jobs (``runner.run_job``; ``job.work`` a ConstantWork)."""
    m = job.work.material
    result = FileResult(f"{m.name} (constants)", job.output)
    t0 = time.perf_counter()
    try:
        result.values = constant_coefficients(m, job.work.config, runtime)
        result.notes = [f"{o} {' '.join(f'{v:.6g}' for v in vals)} 1/{m.unit}"
                        for o, vals in result.values.items()]
        result.status = "ok"
    except ValueError as exc:
        result.error = f"{m.name}: {exc}"
    result.seconds = time.perf_counter() - t0
    return result


#: write_records' mark of an earlier bake's output it removed (``remove_stale_outputs``)
REMOVED = "removed"
#: write_records' mark of a material whose records the new ones no longer hold
DROPPED = "records removed"
#: write_records' mark of a map of colour and radius in a target's convention it wrote
MAPPED = "maps"
#: write_records' mark of an output's layer it wrote as a file of its own (``layer_files``)
LAYERED = "layer file"

