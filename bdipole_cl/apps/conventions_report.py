"""``bdipole-cl conventions``: what each renderer's convention means, and what each renders
from one painted texture set (docs/conventions.md "What renderer X makes of these textures").

The table is the diffuse reflectance (specular excluded) each convention's renderer produces
when the painted albedo is used as its colour, against the albedo painted: for the diffusion
profiles, the colour itself; for the walks, the walk reference under their boundary
(``physics.conventions.rendered_rd``).
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..io.collisions import refusal
from ..physics.conventions import CONVENTION, rendered_rd
from .preview import replaced_together

#: the painted albedos and etas of the table
ALBEDOS = (0.2, 0.35, 0.5, 0.65, 0.8, 0.95)
ETAS = (1.33, 1.4, 1.5)
REPORT_FILES = ("conventions.md", "conventions.csv", "conventions.png")
MARK = "bdipole_cl conventions"


def rendered_table(albedos=ALBEDOS, etas=ETAS, g=0.0):
    """{(convention, eta): rendered reflectance per albedo} for every convention."""
    a = np.asarray(albedos, np.float64)
    return {(c.name, eta): np.asarray(rendered_rd(c, a, eta, g), np.float64)
            for eta in etas for c in CONVENTION}


def markdown(table, albedos=ALBEDOS, etas=ETAS) -> str:
    """The table as Markdown: one block per eta, a row per convention."""
    lines = []
    for eta in etas:
        lines += [f"eta {eta:g}: rendered diffuse reflectance (specular excluded) for a painted "
                  f"albedo", "",
                  "| convention | boundary | " + " | ".join(f"{a:g}" for a in albedos) + " |",
                  "|---|---|" + "---:|" * len(albedos)]
        for c in CONVENTION:
            rd = table[(c.name, eta)]
            lines.append(f"| {c.name} | {c.boundary} | "
                         + " | ".join(f"{v:.4f}" for v in rd) + " |")
        lines.append("")
    return "\n".join(lines)


def write_report(folder, force=False, albedos=ALBEDOS, etas=ETAS):
    """conventions.md, .csv and .png in ``folder``, replaced together; a ValueError before
    anything is computed where one would replace a file this tool did not write."""
    folder = Path(folder)
    for name in REPORT_FILES:
        why = refusal(folder / name, force, _is_ours)
        if why:
            raise ValueError(why)
    table = rendered_table(albedos, etas)
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(["convention", "boundary", "eta", *[f"painted {a:g}" for a in albedos]])
    for (name, eta), rd in table.items():
        w.writerow([name, CONVENTION[name].boundary, f"{eta:g}", *[f"{v:.6f}" for v in rd]])
    picture = io.BytesIO()
    _plot(table, albedos, etas, picture)
    md = f"<!-- {MARK} -->\n" + markdown(table, albedos, etas)
    folder.mkdir(parents=True, exist_ok=True)
    replaced_together([
        (folder / "conventions.csv", lambda tmp: tmp.write_bytes(text.getvalue().encode())),
        (folder / "conventions.md", lambda tmp: tmp.write_bytes(md.encode())),
        (folder / "conventions.png", lambda tmp: tmp.write_bytes(picture.getvalue()))])
    return table


def _is_ours(path) -> bool:
    path = Path(path)
    try:
        md = (path.parent / "conventions.md").read_text(errors="replace")
    except OSError:
        return False
    return md.startswith(f"<!-- {MARK} -->")


def _plot(table, albedos, etas, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(etas), figsize=(5.2 * len(etas), 4.8), squeeze=False)
    for ax, eta in zip(axes[0], etas):
        ax.plot(albedos, albedos, "k:", lw=1, label="painted")
        for c in CONVENTION:
            if c.walk:
                ax.plot(albedos, table[(c.name, eta)], "o-", ms=3, label=c.name)
        ax.set_xlabel("painted albedo")
        ax.set_ylabel("rendered diffuse reflectance")
        ax.set_title(f"eta {eta:g} (profiles render the painted albedo)", fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out, dpi=100, format="png", metadata={"Software": MARK})
    plt.close(fig)


def listing() -> str:
    """Every convention: name, aliases, kind, boundary, what colour and radius mean."""
    out = []
    for c in CONVENTION:
        alias = f" (also {', '.join(c.aliases)})" if c.aliases else ""
        out += [f"{c.name}{alias}: {c.summary}",
                f"    renderers: {c.renderers}",
                f"    colour: {c.colour}; radius: {c.radius} [{c.unit}]",
                f"    {'walk' if c.walk else 'profile'}, boundary {c.boundary}: "
                f"{_boundary_words(c.boundary)}",
                f"    source: {c.source}"]
    return "\n".join(out)


def _boundary_words(name):
    from ..physics.conventions import BOUNDARIES
    return BOUNDARIES[name]


def add_command(command):
    """Add ``conventions`` to the CLI (``command``: the subparsers' add_parser)."""
    p = command("conventions", help="renderers' subsurface conventions: what each means, and "
                                    "what each renders from a painted albedo")
    p.add_argument("--report", metavar="DIR",
                   help="write conventions.md/.csv/.png: the reflectance each renders for "
                        "painted albedos 0.2..0.95 at eta 1.33, 1.4, 1.5")
    p.add_argument("--force", action="store_true",
                   help="replace report files bdipole-cl did not write")
    p.set_defaults(func=_cmd_conventions)


def _cmd_conventions(args) -> int:
    if not args.report:
        print(listing())
        return 0
    table = write_report(args.report, force=args.force)
    print(markdown(table))
    print(f"wrote {Path(args.report) / 'conventions.md'} (.csv, .png)")
    return 0
