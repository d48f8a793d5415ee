"""``bdipole-cl bake --preview``: a contact sheet per job beside its output, and one page for
the bake with every material's thumbnails and profile (``preview`` and ``profile`` draw)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import one_line
from ..io.collisions import Claim, collisions
from ..io.images import TextureError
from ..signals import check_stop

from .preview import (ContactSheet, contact_sheet, displayed_colour, draw_group, read_image,
                      require_matplotlib, save_figure)
from .profile import draw_profiles, material_specs

#: inches per thumbnail on the bake page, and for the profile panel
THUMB_IN, PROFILE_IN, ROW_IN = 2.4, 4.6, 2.9


@dataclass(frozen=True)
class BakePreview:
    sheets: tuple                    # ContactSheet per job output
    page: str                        # the bake's page (PNG)
    materials: tuple                 # the materials on it, in order
    failed: tuple = ()               # (output, why) of the sheets that could not be drawn

    def describe(self) -> str:
        return (f"previews: {len(self.sheets)} contact sheet(s) beside the outputs "
                f"(*.preview.png); the bake's page: {self.page}"
                + "".join(f"\ncontact sheet of {out} not drawn: {why}"
                          for out, why in self.failed))


def sheet_path(output) -> Path:
    """Where a job's contact sheet goes: beside its output, ``out.1001.exr`` ->
    ``out.1001.preview.png``."""
    return Path(output).with_suffix(".preview.png")


def page_path(plan, page=None) -> Path:
    """The bake's page: ``page``, else ``scene.preview.png`` beside the scene file."""
    return Path(page) if page is not None else Path(plan.scene.path).with_suffix(".preview.png")


def preview_clashes(plan, page=None, force=False):
    """Where a contact sheet or the page of ``plan``'s bake would land on any input or output
    of any of its jobs (never allowed, ``force`` or not), or replace a file this tool did not
    write (unless ``force``): the run's collision check (``io.collisions.collisions``) with
    the pictures as outputs of their own. ({job index: its sheet's one-line clash}, the
    page's clash or None)."""
    drawn = [i for i, j in enumerate(plan.jobs)          # a constant's output: the records
             if j.output and j.kind != "constant"]
    jobs = [Claim(plan.jobs[i].source, plan.jobs[i].output, plan.jobs[i].inputs) for i in drawn]
    pictures = [Claim(f"contact sheet of {plan.jobs[i].output}",
                      str(sheet_path(plan.jobs[i].output)), {}) for i in drawn]
    pictures.append(Claim("the bake's page", str(page_path(plan, page)), {}))
    found = collisions(jobs + pictures, force)[len(jobs):]
    sheets = {i: f"--preview: {clash}" for i, clash in zip(drawn, found[:-1]) if clash}
    return sheets, (f"--preview: {found[-1]}" if found[-1] else None)


def check_preview_outputs(plan, page=None, force=False):
    """ValueError (one line) naming the first picture of ``plan``'s bake that would land on a
    file of the run or replace a file this tool did not write (``preview_clashes``)."""
    sheets, page_clash = preview_clashes(plan, page, force)
    first = next(iter(sheets.values()), None) or page_clash
    if first:
        raise ValueError(first)


def bake_preview(plan, report, page=None, force=False) -> BakePreview:
    """Contact sheets of every output the bake left (made now or up to date), and the page
    (default: beside the scene file, ``scene.preview.png``); none lands on a file of the run
    (``preview_clashes``: a job's sheet that would is not drawn, a page that would is a
    ValueError), nor replaces a file this tool did not write unless ``force``."""
    clashes, page_clash = preview_clashes(plan, page, force)
    if page_clash:
        raise ValueError(page_clash)
    done = {r.output for r in report.results if r.status in ("ok", "skipped")}
    sheets, failed = [], []
    for i, j in enumerate(plan.jobs):     # a stop request ends the pictures between two
        if (j.kind != "constant" and i not in clashes and j.output in done  # of them (whole)
                and Path(j.output).is_file()):
            check_stop()
            try:                          # one sheet that cannot be drawn is that sheet's
                sheets.append(contact_sheet(j.output, sheet_path(j.output),
                                            title=_job_title(j), force=force))
            except (ValueError, OSError, TextureError) as exc:
                failed.append((j.output, one_line(exc)))
    scene = plan.scene
    page = page_path(plan, page)
    materials = tuple(m.name for m in scene.materials)
    check_stop()
    _bake_page(scene, plan, sheets, page, force)
    return BakePreview(tuple(sheets), str(page), materials, tuple(failed))


def _job_title(job):
    return f"{job.kind} {job.name}" + (f" [{job.udim}]" if job.udim else "")


def _material_of(scene, job):
    if job.kind == "invert":
        return job.name
    return next(b.material.name for b in scene.blurs if b.name == job.name)


def _page_rows(scene, plan, sheets: list):
    """Per material: (name, [(job title, file, group)] of its first tile's outputs)."""
    by_output = {s.source: s for s in sheets}
    rows = []
    for m in scene.materials:
        groups, tiles_seen = [], set()
        for j in plan.jobs:
            sheet: ContactSheet | None = by_output.get(j.output)
            if sheet is None or _material_of(scene, j) != m.name:
                continue
            if (j.kind, j.name) in tiles_seen:        # the first tile of each job stands in
                continue
            tiles_seen.add((j.kind, j.name))
            groups += [(_job_title(j), j.output, t.group) for t in sheet.tiles]
        rows.append((m.name, groups))
    return rows


def _bake_page(scene, plan, sheets, page, force=False):
    require_matplotlib()
    from matplotlib.figure import Figure
    rows = _page_rows(scene, plan, sheets)
    cols = max([len(g) for _, g in rows] + [1])
    width = cols * THUMB_IN + PROFILE_IN + 0.4
    fig = Figure(figsize=(width, ROW_IN * len(rows) + 0.5), dpi=100)
    height = fig.get_figheight()
    fig.text(0.5, 1 - 0.25 / height, f"bake of {Path(scene.path).name}: every material's "
             f"outputs (first tile) and profile", ha="center", va="center", fontsize=11,
             weight="bold")
    cache = {}
    for k, (name, groups) in enumerate(rows):
        y0 = 1 - (0.5 + ROW_IN * (k + 1)) / height
        cell_h = ROW_IN / height
        for c, (title, path, group) in enumerate(groups):
            if path not in cache:           # its colour as the contact sheet shows it
                px, names, alpha, header = read_image(path)
                cache[path] = (displayed_colour(path, px, names, alpha, header)[0], header)
            px, header = cache[path]
            x0 = (0.2 + c * THUMB_IN) / width
            ax = fig.add_axes((x0 + 0.05 * THUMB_IN / width, y0 + 0.36 * cell_h,
                               0.9 * THUMB_IN / width, 0.5 * cell_h))
            cax = fig.add_axes((x0 + 0.12 * THUMB_IN / width, y0 + 0.15 * cell_h,
                                0.76 * THUMB_IN / width, 0.035 * cell_h))
            draw_group(fig, ax, cax, px, group, header)
            ax.set_title(f"{title}\n{ax.get_title()}", fontsize=8)
        pax = fig.add_axes(((0.2 + cols * THUMB_IN + 0.75) / width, y0 + 0.16 * cell_h,
                            (PROFILE_IN - 0.95) / width, 0.7 * cell_h))
        try:
            specs, unit, tol = material_specs(scene, name)
            draw_profiles(pax, specs, unit, tol)
            pax.set_title(f"{name}: R(r) at the mean albedo, its range shaded\n"
                          f"o truncation radius (tol {tol:g}), dashed: mfp", fontsize=8)
            pax.legend().set_visible(False)
            pax.tick_params(labelsize=7)
            pax.xaxis.label.set_fontsize(8)
            pax.yaxis.label.set_fontsize(8)
        except ValueError as exc:              # a material without albedo files: say so
            pax.set_axis_off()
            pax.text(0.5, 0.5, str(exc), ha="center", va="center", fontsize=7, wrap=True)
        if not groups:
            fig.text((0.2 + 0.5 * cols * THUMB_IN) / width, y0 + 0.5 * cell_h,
                     f"{name}: no output", ha="center", fontsize=9)
    save_figure(fig, page, [scene.path], force)

