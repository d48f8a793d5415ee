"""Scenes: ``bdipole-cl plan/bake scene.toml`` compute what a scene needs and leave out the
rest (the jobs layer; the file format is ``io.scene_file``).

Per job (one UDIM tile of a material's inversion, or of a blur), the plan says what is
computed and what is left out, and why:

- **outputs and channels**: only the outputs asked for; as many channels as the albedo has
  colour channels (a grey albedo is one), alpha carried, other channels left out;
- **kernel specialisation**: the job's eta constants, model, outputs and a constant mfp are
  compiled into the inversion kernel (``InversionPlan(specialise=True)``), which then reads only
  the albedo (and an mfp texture if there is one); each distinct build is cached;
- **table size**: with ``method = "auto"`` (float32), a statistics pass finds the albedo
  range present (unmasked texels), and the smallest monotone table that meets tol there is
  used; the table still covers every albedo, so a texel outside the range is still right;
- **masks**: texels where the mask is 0 are neither inverted nor validated (a white
  background is no error) and are written as 0, the albedo's alpha kept; bands with no
  unmasked texel are not sent to the device. Blurs: masked texels give no light and get no
  exitance; bands with no light are not blurred. The boundary convention: light from unmasked
  texels spreads over masked ones and is lost there (the islands are cut surfaces: no energy
  is invented at their edges), and texels of another island within the kernel's radius in
  texture space do exchange light, as in any texture-space diffusion (keep islands a kernel
  radius apart, or accept the bleed);
- **colour**: each colour input's path into the job's working space; mfp and masks as is;
- **stretch**: a blur whose ``stretch`` is meshes has, per tile, a stretch job before it
  that makes its maps (``scene_stretch``; up to date while the meshes' geometry is);
- **up to date**: an output whose ``bdipole:*`` header records the same parameters digest
  (which includes the working space and the OCIO config), library version and input files
  (size and modification time, else their content digest) is not rebuilt.
"""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, replace

import numpy as np

from ..device import get_runtime
from ..io.collisions import Claim, collisions
from ..io.colour import resolve_working_space
from ..io.freshness import header_fields, input_identities, is_up_to_date, params_digest
from ..io.images import TextureError, check_same_window, image_header
from ..io.mipmaps import texture_options
from ..io.patterns import companion_path, expand_inputs, unmatched_pattern
from ..io.scene_file import SceneData, SceneError, load_imported
from ..io.scene_file import load as load_scene_file
from ..io.scene_import import import_materials, is_imported
from ..io.scene_values import number
from ..io.targets import parse_targets
from ..io.tiles import TileError, is_pattern
from ..methods.choice import DeviceKey, device_auto_note, resolve_method
from ..methods.registry import OUTPUTS, MethodConfig
from ..signals import check_stop
from . import runner
from .blur_file import colour_of
from .invert_file import per_channel
from .job import BlurWork, ConstantWork, InvertWork, Job
from .planned import PlannedJob
from .scene_stretch import blocked, plan_stretch
from .results import BatchReport, FileResult
from .scene_finish import finish_bake
from .scene_records import (LAYER, MANIFEST, coefficients_digest, constant_config,
                            constant_text, foreign_records, imported_lines, mfp_text,
                            read_manifest, record_inputs, records_dir, records_over_input,
                            records_refusal)
from .scene_stats import DEFAULT_MEMORY, albedo_stats, table_for_range

#: compile each job's constants into its kernel (tools/bench_scene.py turns it off to measure
#: what it saves)
SPECIALISE = True


@dataclass(frozen=True)
class Scene(SceneData):
    """A scene, ready to plan: ``load(path).plan().run()``."""

    def plan(self, force=False, device=None, max_memory=DEFAULT_MEMORY) -> Plan:
        """What a bake computes and leaves out, per job."""
        return plan(self, force=force, device=device, max_memory=max_memory)


@dataclass
class Plan:
    scene: Scene
    jobs: list
    records_problem: str | None = None   # the records folder holds another scene's bake
    records_note: str | None = None      # a record that would replace an input (not written)
    record_inputs: frozenset = frozenset()   # what the records never replace (record_inputs)

    @property
    def missing(self):
        return [j.problem for j in self.jobs if j.problem]

    def describe(self) -> str:
        todo = sum(not j.up_to_date and not j.problem for j in self.jobs)
        jobs = f"{len(self.jobs)} job" + ("" if len(self.jobs) == 1 else "s")
        note = [f"records: cannot write {self.records_note}"] if self.records_note else []
        return "\n".join(imported_lines(self.scene) + [j.describe() for j in self.jobs] + note
                         + [f"{jobs}: {todo} to run, "
                            f"{sum(j.up_to_date for j in self.jobs)} up to date, "
                            f"{len(self.missing)} that cannot run"])

    def to_json(self) -> str:
        return json.dumps([{k: v for k, v in asdict(j).items()
                            if k not in ("config", "working", "identities", "work")}
                           | {"config": j.config.describe() if j.config else None,
                              "working_space": j.working.describe() if j.working else None}
                           for j in self.jobs], indent=1)

    def run(self, *, cancel=None, device=None, progress=None,
            max_memory=DEFAULT_MEMORY) -> BatchReport:
        """Bake every job that is not up to date; a failing job does not stop the others."""
        return bake(self, cancel=cancel, device=device, progress=progress,
                    max_memory=max_memory)


# {{{ the plan

#: material keys that are not a job's parameters: the networks a bake writes for its targets
#: change no texel (a new target rewrites the records, never an image)
NOT_PARAMETERS = ("name", "albedo", "output", "targets")


def _material_fields(m) -> dict:
    return {k: v for k, v in asdict(m).items() if k not in NOT_PARAMETERS}


def _exists(role, path, problems):
    if path and not os.path.isfile(path):
        problems.append(f"{role} {path} " + ("is not a regular file" if os.path.exists(path)
                                             else "is missing"))


def _same_window(role, path, albedo, problems):
    """A problem where the headers of texture ``path`` (mfp or mask) and of ``albedo`` cover
    different texels (the bake would fail the job: the plan says so first)."""
    if problems or not os.path.isfile(path):
        return
    mine, theirs = image_header(albedo), image_header(path)
    if mine is not None and theirs is not None:
        try:
            check_same_window(mine, theirs, albedo, role, path)
        except TextureError as exc:
            problems.append(str(exc))


def _textures(inputs, material, mask, path, tile, problems):
    """Add the job's mfp and mask textures (companions of ``path`` by tile) to ``inputs``."""
    if isinstance(material.mfp, str):
        inputs["mfp"] = companion_path(material.mfp, path, tile)
        _exists("mfp texture", inputs["mfp"], problems)
        _same_window("mfp texture", inputs["mfp"], path, problems)
    if mask and mask != "alpha":
        inputs["mask"] = companion_path(mask, path, tile)
        _exists("mask", inputs["mask"], problems)
        _same_window("mask", inputs["mask"], path, problems)


def _new_job(kind, name, path, udim, out, inputs, fields, working_space, problems, force,
             problems_all):
    """The job, its parameters digest (``fields``, the working space, kind and tile) and
    working space set, and whether it still needs planning (not broken, not up to date)."""
    working = resolve_working_space(working_space)
    digest = params_digest(fields | working.key | {"kind": kind, "udim": udim})
    job = PlannedJob(kind, name, path, udim, out, inputs, params_digest=digest,
                     working=working, identities=input_identities(inputs))
    if problems:
        job.problem = "; ".join(problems)
        problems_all += problems
    elif not force and is_up_to_date(out, inputs, digest):
        job.up_to_date = True
        job.left_out.append("everything: up to date (inputs, parameters and version unchanged)")
    return job, not (job.problem or job.up_to_date)


def _cannot_run(job, problem, problems_all):
    job.problem = problem
    problems_all.append(problem)
    return job


def _plan_invert(m, path, tile, force, device, problems_all, max_memory):
    udim = tile.label if tile else None
    out = companion_path(m.output, path, tile)
    inputs = {"albedo": path}
    problems = []
    _exists("albedo", path, problems)
    _textures(inputs, m, m.mask, path, tile, problems)
    job, todo = _new_job("invert", m.name, path, udim, out, inputs, _material_fields(m),
                         m.working_space, problems, force, problems_all)
    working = job.working
    if not todo:
        return job
    try:
        names, alpha, other, rd_range, masked, route = albedo_stats(
            path, m.mask, inputs.get("mask"), m.colorspace, working, max_memory, m.albedo_layer)
    except TextureError as exc:          # this job cannot run (unreadable, or a colour space
        return _cannot_run(job, str(exc), problems_all)   # the config cannot follow); others do
    try:                                 # what the bake would refuse, refused now
        etas = per_channel(m.eta, len(names), "eta", path)
        if not isinstance(m.mfp, str):
            per_channel(tuple(m.mfp), len(names), "mfp", path)
    except TextureError as exc:
        return _cannot_run(job, str(exc), problems_all)
    job.computes.append(f"colour: albedo {route.describe()}")
    job.left_out.append(_not_converted(m.mask))
    if len(set(etas)) == 1:
        etas = etas[:1]
    key = DeviceKey.of(get_runtime(device).device)
    config = resolve_method(m.method, double=m.double, tol=m.tol, device_key=key)
    if m.method == "auto" and (m.double or rd_range is None):
        job.computes.append(f"method auto from {device_auto_note(key)}")
    if m.method == "auto" and not m.double and rd_range is not None:
        size, err = table_for_range(etas, rd_range, m.tol, m.model, m.exact, device)
        config = MethodConfig("table", table_size=size)
        job.computes.append(f"table of {size} intervals: the smallest monotone one meeting tol "
                            f"{m.tol:g} on the albedos present [{rd_range[0]:.4g}, "
                            f"{rd_range[1]:.4g}] (measured {err:.2e})")
    job.config = config
    left = [o for o in OUTPUTS if o not in m.outputs]
    job.computes.append(f"{', '.join(m.outputs)} of {len(names)} channel(s) "
                        f"({', '.join(names)}) with {config.describe(m.double)}")
    job.left_out.append(f"outputs {', '.join(left)}: not asked for")
    if alpha:
        job.left_out.append(f"channel {alpha}: alpha, carried to the output, not inverted")
    if other:
        job.left_out.append(f"channels {', '.join(other)}: not colour")
    job.computes.append(mfp_text(m))
    baked = ["eta's Fresnel terms", f"the model ({m.model})", "the outputs"]
    if not isinstance(m.mfp, str) and m.mfp_kind == "diffuse":
        mfp = np.asarray(m.mfp) * np.asarray(m.mfp_scale)
        baked.append(f"the mfp {', '.join(f'{v:g}' for v in mfp)} {m.unit}")
    job.left_out.append(f"per-texel constant reads: {', '.join(baked)} compiled into the "
                        f"kernel, which reads only the albedo"
                        + (" and the mfp texture" if isinstance(m.mfp, str) else ""))
    if m.mask:
        job.left_out.append(f"{masked:.0%} of texels, masked by "
                            f"{'the albedo alpha' if m.mask == 'alpha' else inputs['mask']}: "
                            f"not inverted nor validated, written as 0")
    return job


def _not_converted(mask) -> str:
    return ("colour conversion of the mfp (lengths per channel of the working space)"
            + (", the mask" if mask else "") + " and alpha (data)")


def _plan_blur(b, path, tile, force, problems_all, scene, meshes) -> list:
    """The blur job of one irradiance tile, after the stretch job that makes its maps if
    there is one (``scene_stretch``; ``meshes``: the plan's cache of meshes read)."""
    m = b.material
    udim = tile.label if tile else None
    out = companion_path(b.output, path, tile)
    inputs = {"irradiance": path, "albedo": companion_path(m.albedo, path, tile)}
    problems = []
    _exists("irradiance", path, problems)
    _exists("albedo", inputs["albedo"], problems)
    _textures(inputs, m, b.mask, path, tile, problems)
    lengths = plan_stretch(scene, b, path, tile, out, force, meshes) if b.stretch else None
    if lengths is not None:
        inputs["stretch"] = lengths.file
        if lengths.problem:
            problems.append(lengths.problem)
        elif lengths.job is None:             # the user's maps: read, so they must be there
            _exists("stretch maps", lengths.file, problems)
            _same_window("stretch maps", lengths.file, path, problems)
    fields = {k: v for k, v in asdict(b).items() if k not in ("name", "irradiance", "output")}
    fields["material"].pop("targets", None)
    job, todo = _new_job("blur", b.name, path, udim, out, inputs, fields, b.working_space,
                         problems, force or (lengths is not None and lengths.runs),
                         problems_all)
    made = [lengths.job] if lengths is not None and lengths.job is not None else []
    if made and job.identities:       # read once its job wrote it: identity taken then
        job.identities.pop("stretch", None)
    working = job.working
    if not todo:
        return made + [job]
    try:
        for role, file, space, layer in (("irradiance", path, b.colorspace, None),
                                         ("albedo", inputs["albedo"], m.colorspace,
                                          m.albedo_layer)):
            job.computes.append(f"colour: {role} {colour_of(file, role, space, working, layer)}")
    except TextureError as exc:                # e.g. a space the config does not know
        return made + [_cannot_run(job, str(exc), problems_all)]
    job.left_out.append(_not_converted(b.mask))
    size = (f"texel {b.texel_size:g} {m.unit}" if lengths is None else
            f"in surface distance with {lengths.words}, chart borders {b.charts}")
    job.computes.append(f"exitance with the exit texel's profile from {m.name}'s albedo "
                        f"and mfp, {size}, tol {b.tol:g} ({b.method}, border {b.border})")
    if b.mask:
        job.left_out.append("masked texels: no light from them, no exitance for them (0); "
                            "bands without light are not blurred")
    return made + [job]


def usable_coefficients(values, outputs) -> bool:
    """Whether a manifest's recorded coefficients can stand for a constant material's job: a
    list of finite, non-negative floats for each of its outputs (a hand-edited or broken
    record is computed again, never passed on)."""
    return isinstance(values, dict) and all(
        isinstance(values.get(o), list) and values[o]
        and all(number(v) and v >= 0 for v in values[o]) for o in outputs)


def _plan_constant(m, folder, old, force, scene_source):
    """A material without textures: its coefficients are computed, not written as an image
    (up to date when the manifest holds them for the same parameters)."""
    digest = params_digest(_material_fields(m) | {"kind": "constant", "albedo": m.albedo})
    job = PlannedJob("constant", m.name, "constants", None, os.path.join(folder, MANIFEST),
                     {}, params_digest=digest)
    entry = old.get(m.name, {})
    if not force and entry.get("params_digest") == digest and \
            usable_coefficients(entry.get("coefficients"), m.outputs) and \
            entry.get("coefficients_digest") == coefficients_digest(entry.get("coefficients")):
        job.up_to_date = True
        job.left_out.append("everything: up to date (parameters and version unchanged)")
        return job
    job.config = constant_config(m)
    job.computes.append(constant_text(m, job.config))
    job.left_out.append(f"an image: no texture; the coefficients go to the bake summary, "
                        f"{MANIFEST}" + (f" and {LAYER}" if scene_source else ""))
    return job


def plan(scene: Scene, *, force=False, device=None, max_memory=DEFAULT_MEMORY) -> Plan:
    """Every job of the scene, checked and described; missing inputs, unreadable files,
    patterns that cannot name a job's tile and collisions make jobs that cannot run (all are
    listed before any work; the others run). The statistics pass reads albedos in bands
    within ``max_memory`` bytes. A material without textures is one "constant" job (its
    coefficients, no image). A stop request (SIGINT/SIGTERM) raises ``Stopped`` between
    files."""
    rt = get_runtime(device)
    jobs, problems, meshes = [], [], {}
    textured = [m for m in scene.materials if not m.constant]
    for kind, entries in (("invert", textured), ("blur", scene.blurs)):
        for e in entries:
            for path, tile in expand_inputs([e.albedo if kind == "invert" else e.irradiance]):
                check_stop()
                try:
                    jobs += ([_plan_invert(e, path, tile, force, rt, problems, max_memory)]
                             if kind == "invert" else
                             _plan_blur(e, path, tile, force, problems, scene, meshes))
                except (TextureError, TileError) as exc:   # a pattern this file cannot fill
                    role = "albedo" if kind == "invert" else "irradiance"
                    problem = (f"{role} {unmatched_pattern(path)}"
                               if is_pattern(path) and not os.path.exists(path) else str(exc))
                    jobs.append(PlannedJob(kind, e.name, path, tile.label if tile else None, "",
                                           {"source": path}, problem=problem))
                    problems.append(problem)
    made = {j.output for j in jobs if j.kind == "stretch"}   # a blur reads what they write
    for j, clash in zip(jobs, collisions((Claim(j.source, j.output, {
            r: p for r, p in j.inputs.items() if not (r == "stretch" and p in made)})
            for j in jobs), force)):
        if clash:
            j.problem, j.up_to_date = clash, False
    folder = records_dir(scene)
    old = read_manifest(folder) if folder else {}
    jobs += [_plan_constant(m, folder, old, force, scene.source) for m in scene.materials
             if m.constant]
    inputs = frozenset(record_inputs(scene, folder, jobs)) if folder else frozenset()
    taken = records_refusal(scene, folder, inputs, force) or (
        None if force else foreign_records(scene, folder))
    for j in jobs if taken else ():
        if not j.problem:
            j.problem, j.up_to_date = taken, False
    return Plan(scene, jobs, taken, records_over_input(scene, folder, inputs), inputs)

# }}}


# {{{ the bake

def layers_of(m) -> dict:
    """{input role: the EXR layer read} of a material (its albedo_layer, mfp_layer)."""
    return {role: layer for role, layer in (("albedo", m.albedo_layer), ("mfp", m.mfp_layer))
            if layer is not None}


def scene_job(job: PlannedJob, scene: Scene, max_memory=DEFAULT_MEMORY, pending=()) -> Job:
    """The runnable ``job.Job`` of a planned job (``runner.run_job`` runs it; so do Dask's
    workers): the material's or blur's fields as the typed work. ``pending``: files a job of
    this bake has yet to write (stretch maps): a blur reading one gets its output header's
    record of its inputs where it runs, after them (``scene_stretch.with_maps_header``)."""
    header = ({} if job.inputs.get("stretch") in pending else
              header_fields(job.inputs, job.params_digest))
    if job.kind == "invert":
        m = next(x for x in scene.materials if x.name == job.name)
        work = InvertWork(
            eta=m.eta, mfp=None if isinstance(m.mfp, str) else m.mfp, mfp_scale=m.mfp_scale,
            config=job.config, mfp_kind=m.mfp_kind, model=m.model, exact=m.exact,
            half=m.half, colorspace=m.colorspace, alpha_channel="keep",
            on_invalid=m.on_invalid, max_memory=max_memory, outputs=m.outputs, unit=m.unit,
            double=m.double, mask=None if not m.mask else "alpha" if m.mask == "alpha"
            else "texture", specialise=SPECIALISE, header=header | {"tol": m.tol},
            working=job.working, texture=texture_options(m.texture), layers=layers_of(m))
    elif job.kind == "blur":
        b = next(x for x in scene.blurs if x.name == job.name)
        work = BlurWork(tol=b.tol, method=b.method, border=b.border, exact=b.material.exact,
                        on_invalid=b.on_invalid, half=b.half, texture=b.texture,
                        colorspace=b.colorspace, working=job.working, max_memory=max_memory,
                        header=header, material=b.material, texel_size=b.texel_size,
                        mask=b.mask, charts=b.charts)
    elif job.kind == "stretch":
        work = job.work                      # the plan made it (scene_stretch.plan_stretch)
    else:
        work = ConstantWork(next(x for x in scene.materials if x.name == job.name), job.config)
    return Job(job.kind, job.source, job.output, job.inputs, work, job.udim, job.params_digest,
               job.name, job.identities)


def not_run(job: PlannedJob) -> FileResult | None:
    """The result of a planned job that is not run (it cannot, or it is up to date)."""
    source = f"{job.name} (constants)" if job.kind == "constant" else job.source
    if job.problem:
        return FileResult(source, job.output, error=job.problem)
    if job.up_to_date:
        return FileResult(source, job.output, status="skipped")
    return None


def bake(plan: Plan, *, cancel=None, device=None, progress=None,
         max_memory=DEFAULT_MEMORY) -> BatchReport:
    runtime = get_runtime(device)
    results, made = [], {}
    for job in plan.jobs:
        result = not_run(job) or blocked(job, made)
        if result is None:
            result = runner.run_job(scene_job(job, plan.scene, max_memory), runtime,
                                    cancel=cancel)
        if job.kind == "stretch":
            made[job.output] = result
        results.append(result)
        if progress is not None:
            progress(job, result)
    return finish_bake(plan, results)


def load(path, working_space=None, targets=None) -> Scene:
    """Read and check a scene file, USD stage or MaterialX document (``SceneError``: one
    line with the file, line and key); ``working_space``: that of the entries that give none
    (None: the default); ``targets``: the render targets of every material (``io.targets``;
    None: each material's own, else the default)."""
    if is_imported(path):
        data = load_imported(path, import_materials, working_space)
    else:
        data = load_scene_file(path, import_materials, working_space)
    materials = data.materials
    if targets is not None:
        chosen = parse_targets(targets)
        materials = tuple(replace(m, targets=chosen) for m in materials)
    return Scene(data.path, materials, data.blurs, data.source, data.imports)


__all__ = ["Plan", "PlannedJob", "Scene", "SceneError", "bake", "load", "plan"]

# }}}
