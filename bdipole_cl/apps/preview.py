"""``bdipole-cl preview FILE.exr``: a contact sheet of an EXR, one thumbnail per channel group.

A bdipole output's groups are its outputs (alpha', rho, sigma_a, sigma_s', sigma_t', the
blur's exitance) and the alpha it carries; any other EXR's are the prefixes of its channel names
(``diffuse.R`` -> ``diffuse``), its unprefixed colour channels and its alpha. Each group is
drawn as a thumbnail of its (up to three) channels as R, G, B (one channel: grey), on a scale
shared by its channels: logarithmic when the middle 90% of its positive values spans more
than ``LOG_DECADES`` decades (coefficients often do), else linear and sRGB-encoded for
display. A file's colour is first decoded as the tools read it (its colour path into linear
Rec.709, ``io.colour``: an 8-bit sRGB texture's 128 is 0.216, shown as 128 again, never
encoded twice); data (coefficients, alpha, an output's other layers) is shown as stored.
Each has a colour bar of
that scale and its range in the caption; texels at 0 (masked) or below the log range are
black. The header's parameters (model, eta, mfp, working space, method, tol) are the sheet's
caption. Everything drawn is returned (``ContactSheet``), so tests read the picture back.

matplotlib draws (a dependency: ``pip install .`` is enough for the demo's pictures);
OpenImageIO reads.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..durable import durable_replace
from ..errors import one_line
from ..io.channels import COLOUR_HELD, COLOUR_LAYERS, NOT_RGB, held_layer, layer_of
from ..io.collisions import PICTURE_MARK, Claim, check_claim
from ..io.images import Reader, TextureError, classify_channels, read_whole
from ..io.patterns import outputs_of
from .thumbnails import (LOG_DECADES, NOT_FINITE_RGB, THUMB, finite_spread,  # noqa: F401
                         group_scale, normalise, shrink, srgb_encode)

#: inches per tile of the sheet and its resolution
TILE_IN, DPI = (3.0, 3.1), 100

#: display names of bdipole's outputs (mathtext) and what their values are
GROUP_LABELS = {"alpha": r"$\alpha'$ (reduced albedo)",
                "rho": r"$\rho = 1 - \alpha'$ (absorption)",
                "sigma_a": r"$\sigma_a$ (absorption)", "sigma_s": r"$\sigma_s'$ (scattering)",
                "sigma_t": r"$\sigma_t'$ (extinction)", "exitance": "exitance M",
                "alpha channel": "alpha channel"}
#: the order of a group's channels on the thumbnail's R, G, B
RGB_ORDER = {"r": 0, "red": 0, "g": 1, "green": 1, "b": 2, "blue": 2}
#: groups with a unit of 1/length
COEFFICIENTS = ("sigma_a", "sigma_s", "sigma_t")
#: caption entries: (label, header keys tried in order)
CAPTION_KEYS = (("model", ("bdipole:model",)), ("eta", ("bdipole:eta",)),
                ("mfp", ("bdipole:mfp",)),
                ("working space", ("bdipole:working_space", "oiio:ColorSpace")),
                ("method", ("bdipole:method", "bdipole:methods")),
                ("tol", ("bdipole:tol",)), ("texel", ("bdipole:texel_size",)))


@dataclass(frozen=True)
class ChannelGroup:
    """Channels shown together: ``name`` (``sigma_a``) and indices into the file's channels."""

    name: str
    channels: tuple
    names: tuple


@dataclass(frozen=True)
class GroupTile:
    """One drawn thumbnail: its group, scale and range, the pixels shown, where it lies in the
    saved PNG (x0, y0, x1, y1 from the top left) and the colour bar as drawn."""

    group: ChannelGroup
    log: bool
    vmin: float
    vmax: float
    varies: bool                     # whether any of its channels is not constant
    image: np.ndarray                # the thumbnail as shown, HxWx3 in [0, 1]
    bbox: tuple
    bar_scale: str                   # "log" or "linear", read from the drawn bar
    bar_limits: tuple
    label: str = ""                  # the caption under it, as drawn


@dataclass(frozen=True)
class ContactSheet:
    source: str
    tiles: tuple
    caption: str
    size: tuple                      # PNG (width, height), pixels
    path: str | None = None


def require_matplotlib():
    """matplotlib, or an ImportError saying how to bring it back (it is a dependency, so only a
    broken or hand-pruned environment lacks it)."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError("the pictures need matplotlib: pip install 'matplotlib>=3.6'") \
            from None
    return matplotlib


#: the order of the channels of the colour models that are not RGB (``NOT_RGB``) in a group
MODEL_ORDER = {"L": 0, "a": 1, "b": 2, "Y": 0, "RY": 1, "BY": 2}


def channel_groups(names, alpha_channel=-1, header=None) -> list:
    """The groups of an image's channels, in file order of first appearance: prefixes before
    the last '.', the unprefixed colour channels (``exitance`` in a bdipole blur output, else
    ``colour``), the alpha channel, then any other unprefixed channel on its own."""
    colour, alpha, _ = classify_channels(names, alpha_channel)
    blur = header is not None and header.get("bdipole:source") is not None
    held = held_layer(header) if header is not None else None    # a layer's own file
    model = next((m for m in NOT_RGB if m <= {n.rsplit(".", 1)[-1] for n in names}), None)
    groups = {}
    for i, n in enumerate(names):
        if model and n.rsplit(".", 1)[-1] in model:    # L, a, b: one colour, not alpha + blue
            key = "/".join(sorted(model, key=MODEL_ORDER.get))
        elif i == alpha:
            key = "alpha channel"
        elif "." in n:
            key = n.rsplit(".", 1)[0]
        elif i in colour:
            key = "exitance" if blur else held[0] if held else "colour"
        else:
            key = n
        groups.setdefault(key, []).append(i)
    out = []
    for k, v in groups.items():                 # R, G, B in that order (EXR sorts by name)
        v = sorted(v, key=lambda i: (MODEL_ORDER.get(names[i].rsplit(".", 1)[-1],
                                                     RGB_ORDER.get(names[i].rsplit(".", 1)[-1]
                                                                   .lower(), 3)), i))
        out.append(ChannelGroup(k, tuple(v), tuple(names[i] for i in v)))
    return out


def read_image(path):
    """(pixels HxWxC float32, channel names, alpha index, header dict) of an image file (level
    0 of a texture), read afresh (no image cache)."""
    spec, px = read_whole(path, "preview")
    header = {a.name: a.value for a in spec.extra_attribs}
    return px, tuple(spec.channelnames), spec.alpha_channel, header


#: the space a preview shows colour in: linear Rec.709, sRGB-encoded for the display
DISPLAY_LINEAR = "lin_rec709_scene"


def displayed_colour(path, px, names, alpha, header) -> tuple:
    """(pixels whose colour channels are decoded into DISPLAY_LINEAR as the tools read them,
    what was done for the caption or None): a file's colour channels (``classify_channels``;
    of an output of ours only its colour, convert's ``colour`` layer or a blur's exitance,
    never its coefficients); a declaration the config cannot follow is shown as stored and
    said."""
    colour, _, _ = classify_channels(names, alpha)
    if header.get("bdipole:version") is not None:
        colour = [i for i in colour if layer_of(names[i]) in ("", COLOUR_LAYERS[0])]
        if held_layer(header) is not None and held_layer(header)[0] not in COLOUR_HELD:
            colour = []               # a one-layer file of data (radius, sigma_a): as stored
    if not colour:
        return px, None
    reader = Reader(path, "preview")
    try:
        route = reader.colour("auto", DISPLAY_LINEAR)
    except TextureError as exc:
        return px, f"colour shown as stored: {exc}"
    finally:
        reader.close()
    if route.identity:
        return px, None
    out = px.copy()
    out[..., colour] = route.convert(px[..., colour], [names[i] for i in colour])
    return out, f"colour {route.describe()}"


def thumbnail(px, group):
    """(image HxWx3 in [0, 1] as displayed, log?, vmin, vmax, varies, texels not finite) of
    one group (its channels taken out of the image once: a copy of the whole image each)."""
    group_px = px[..., list(group.channels)]
    values = shrink(group_px.astype(np.float64))
    log, vmin, vmax = group_scale(group_px, may_log=group.name != "alpha channel")
    t = normalise(values, log, vmin, vmax)
    if not log:
        t = srgb_encode(t)
    t = t[..., :3]                              # a group of 4 or more: its first three shown
    rgb = np.repeat(t[..., :1], 3, axis=-1) if t.shape[-1] == 1 else np.concatenate(
        [t, np.zeros(t.shape[:2] + (3 - t.shape[-1],))], -1)
    rgb[~np.all(np.isfinite(values), axis=-1)] = NOT_FINITE_RGB
    varies = any(finite_spread(ch) for ch in np.moveaxis(group_px, -1, 0))
    not_finite = int(np.count_nonzero(~np.all(np.isfinite(group_px), axis=-1)))
    return rgb, log, vmin, vmax, varies, not_finite


def plain(text: str) -> str:
    """``text`` as matplotlib draws it verbatim: a file or channel name with ``$`` pairs is no
    mathtext (it was parsed as one, and failed)."""
    return text.replace("$", r"\$")


def span_text(vmin, vmax, digits=3) -> str:
    """A group's range as words: "a .. b", "constant a", or "no finite value"."""
    if not np.isfinite(vmin):
        return "no finite value"
    return f"{vmin:.{digits}g} .. {vmax:.{digits}g}" if vmax > vmin else \
        f"constant {vmin:.{digits + 1}g}"


def group_unit(name, header):
    if name in COEFFICIENTS:
        return header.get("bdipole:coefficient_unit", "")
    return ""


def caption_text(header) -> str:
    parts = []
    for label, keys in CAPTION_KEYS:
        value = next((header[k] for k in keys if header.get(k) not in (None, "")), None)
        if value is not None:
            unit = header.get("bdipole:unit", "") if label in ("mfp", "texel") else ""
            numeric = all(_is_float(v) for v in str(value).split(","))
            parts.append(f"{label} {value}" + (f" {unit}" if unit and numeric else
                                                f" ({unit})" if unit else ""))
    return "   ".join(parts) if parts else "(no bdipole parameters in the header)"


def _is_float(text):
    try:
        float(text)
        return True
    except ValueError:
        return False


def draw_group(fig, ax, cax, px, group, header):
    """Draw one group's thumbnail in ``ax`` and its colour bar in ``cax``; returns the
    pieces of a GroupTile (all but bbox)."""
    from matplotlib import cm, colors
    image, log, vmin, vmax, varies, bad = thumbnail(px, group)
    ax.imshow(image, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    unit = group_unit(group.name, header)
    ax.set_title(GROUP_LABELS.get(group.name, plain(group.name)), fontsize=10)
    span = span_text(vmin, vmax) + (f" {unit}" if unit else "")
    shown = group.names[:3] + ((f"(+{len(group.names) - 3} not shown)",)
                               if len(group.names) > 3 else ())
    ax.set_xlabel(plain(f"{', '.join(n.rsplit('.', 1)[-1] for n in shown)}: {span}"
                        + (" (log)" if log else "")
                        + (f"; {bad} texels not finite (magenta)" if bad else "")), fontsize=8)
    if log:
        norm, cmap = colors.LogNorm(vmin, vmax), "gray"
    else:
        low = vmin if np.isfinite(vmin) else 0.0
        # a constant group is drawn mid-grey: its value at the bar's middle
        half = 0.5 * abs(low) if low != 0 else 0.5
        norm = colors.Normalize(*((low, vmax) if vmax > low else (low - half, low + half)))
        cmap = colors.ListedColormap(np.repeat(srgb_encode(np.linspace(0, 1, 256))[:, None],
                                               3, 1))
    bar = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax,
                       orientation="horizontal")
    bar.ax.tick_params(labelsize=7)
    if unit:
        bar.set_label(unit, fontsize=7, labelpad=1)
    return (group, log, vmin, vmax, varies, image, bar.ax.get_xscale(),
            tuple(float(v) for v in bar.ax.get_xlim()))


def hug_colour_bar(fig, ax, cax, cell_w):
    """Move a colour bar to just below its image as laid out (its aspect kept), under the
    image's label: at least 55% of the cell wide."""
    pos = ax.get_position()
    height = fig.get_figheight()
    width = max(0.9 * pos.width, 0.55 * cell_w)
    bar_h = 0.11 / height
    cax.set_position((pos.x0 + 0.5 * pos.width - 0.5 * width, pos.y0 - 0.42 / height - bar_h,
                      width, bar_h))


def pixel_bbox(fig, ax):
    """Where ``ax`` lies in the saved PNG: (x0, y0, x1, y1) in pixels from the top left."""
    x0, y0, x1, y1 = ax.get_window_extent().extents
    height = fig.get_figheight() * fig.dpi
    return (int(np.ceil(x0)), int(np.ceil(height - y1)), int(np.floor(x1)),
            int(np.floor(height - y0)))


#: the picture formats a sheet or page is saved as
PICTURE_FORMATS = (".png", ".svg")


def check_picture_output(path, inputs=(), force=False):
    """ValueError (one line, naming the option and file) unless ``path`` is a PNG or SVG that
    lands on none of ``inputs`` and replaces no file this tool did not write (``force``:
    replace it; ``io.collisions.foreign``)."""
    suffix = Path(path).suffix.lower()
    if suffix not in PICTURE_FORMATS:
        raise ValueError(f"-o {path}: a picture is PNG or SVG (.png, .svg), got "
                         f"'{suffix or 'no extension'}'")
    job = str(next(iter(inputs))) if inputs else "picture"
    check_claim(Claim(job, str(path), {f"input {k + 1}": str(p) for k, p in enumerate(inputs)}),
                force)                    # every input by a role of its own (one key kept one)


def replaced(path, write):
    """``write(tmp)`` to a temporary file beside ``path`` (its folder made), then renamed over
    it: a picture or report is whole or not there, never half-written."""
    replaced_together([(path, write)])


def replaced_together(writes):
    """Each ``write(tmp)`` of ``writes`` ((path, write) pairs) to a temporary file beside its
    path, then all renamed over their paths: where one write fails (a full disk), no file is
    changed and no temporary file is left."""
    done = []
    try:
        for path, write in writes:
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
            done.append((tmp, path))
            write(tmp)
        for tmp, path in done:
            durable_replace(tmp, path)
    finally:
        for tmp, _ in done:
            if tmp.exists():
                tmp.unlink()


def save_figure(fig, path, inputs=(), force=False):
    """Save a figure (PNG or SVG by extension, marked as this tool's: PICTURE_MARK) through a
    temporary file beside it, renamed (``replaced``); ``check_picture_output`` first."""
    check_picture_output(path, inputs, force)
    fmt = Path(path).suffix.lstrip(".").lower()
    mark = {"Software": PICTURE_MARK} if fmt == "png" else {"Creator": PICTURE_MARK}
    replaced(path, lambda tmp: fig.savefig(tmp, dpi=fig.dpi, format=fmt, metadata=mark))


def sheet_axes(fig, rows, cols, top, bottom):
    """Per tile, (image axes, colour bar axes) on a rows x cols grid between ``bottom`` and
    ``top`` (figure fractions)."""
    cell_w, cell_h = 1.0 / cols, (top - bottom) / rows
    out = []
    for k in range(rows * cols):
        r, c = divmod(k, cols)
        x0 = c * cell_w + 0.06 * cell_w
        y0 = top - (r + 1) * cell_h
        ax = fig.add_axes((x0, y0 + 0.30 * cell_h, 0.88 * cell_w, 0.60 * cell_h))
        cax = fig.add_axes((x0 + 0.08 * cell_w, y0 + 0.11 * cell_h, 0.72 * cell_w,
                            0.035 * cell_h))
        out.append((ax, cax))
    return out


def contact_sheet(path, output=None, *, title=None, force=False) -> ContactSheet:
    """The contact sheet of ``path`` (an EXR, or any image OpenImageIO reads), saved to
    ``output`` (PNG or SVG by extension; default: beside the file, ``.preview.png``), which
    is never ``path`` itself and replaces no file this tool did not write unless ``force``."""
    require_matplotlib()
    output = Path(output) if output is not None else Path(path).with_suffix(".preview.png")
    check_picture_output(output, [path], force)         # before any work
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    px, names, alpha, header = read_image(path)
    px, decoded = displayed_colour(path, px, names, alpha, header)
    groups = channel_groups(names, alpha, header)
    cols = min(len(groups), 3)
    rows = -(-len(groups) // cols)
    fig = Figure(figsize=(TILE_IN[0] * cols, TILE_IN[1] * rows + 0.9), dpi=DPI)
    top = 1.0 - 0.45 / fig.get_figheight()
    bottom = 0.45 / fig.get_figheight()
    fig.text(0.5, 1.0 - 0.22 / fig.get_figheight(), plain(title or Path(path).name), ha="center",
             va="center", fontsize=11, weight="bold")
    caption = caption_text(header) + (f"   {decoded}" if decoded else "")
    fig.text(0.5, 0.22 / fig.get_figheight(), plain(_wrap(caption, 40 * cols)), ha="center",
             va="center", fontsize=8)
    drawn = []
    cells = sheet_axes(fig, rows, cols, top, bottom)
    for (ax, cax), group in zip(cells, groups):
        drawn.append((ax, draw_group(fig, ax, cax, px, group, header)))
    for ax, cax in cells[len(groups):]:
        fig.delaxes(ax)
        fig.delaxes(cax)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()                              # lays out (image aspect) as the PNG will be
    for (ax, cax), _ in zip(cells, groups):
        hug_colour_bar(fig, ax, cax, 1.0 / cols)
    canvas.draw()
    tiles = tuple(GroupTile(g, log, lo, hi, var, im, pixel_bbox(fig, ax), scale, lim,
                            ax.get_xlabel())
                  for ax, (g, log, lo, hi, var, im, scale, lim) in drawn)
    size = (int(round(fig.get_figwidth() * DPI)), int(round(fig.get_figheight() * DPI)))
    save_figure(fig, output, [path], force)
    return ContactSheet(str(path), tiles, caption, size, str(output))


def _wrap(text, width):
    """Break a caption of '   '-separated entries into lines of about ``width`` characters."""
    import textwrap
    lines, line = [], ""
    parts = [p for entry in text.split("   ")           # an entry longer than a line wraps
             for p in (textwrap.wrap(entry, width) or [entry])]
    for part in parts:
        if line and len(line) + len(part) + 3 > width:
            lines.append(line)
            line = part
        else:
            line = f"{line}   {part}" if line else part
    return "\n".join(lines + [line])


def add_command(command):
    """Add the command to the CLI (``command``: the subparsers' add_parser)."""
    p = command("preview", help="contact sheet of an EXR: a thumbnail per channel group")
    p.add_argument("input", nargs="+",
                   help="EXRs (a bdipole output, or any): files, globs or tile patterns "
                        "(alb.<UDIM>.exr, <udim>, $UDIM, u<U>_v<V>, ...: docs/tiles.md)")
    p.add_argument("-o", "--output",
                   help="PNG or SVG, a pattern for several files (sheet.<UDIM>.png, "
                        "{stem}.png; default: FILE.preview.png beside each)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing -o file that bdipole-cl did not write")
    p.set_defaults(func=_cmd_preview)


def _cmd_preview(args) -> int:
    """One sheet per file named; a lone file's error is the command's (exit 1 or 2, as
    before), each of several files' is its own line and the others are drawn (exit 1)."""
    entries = outputs_of(args.input, args.output, lambda p: Path(p).with_suffix('.preview.png'),
                         what="picture")
    if len(entries) == 1 and entries[0][3] is not None:
        raise TextureError(entries[0][3])
    failed = 0
    for path, _, picture, err in entries:
        if err is None:
            try:
                sheet = contact_sheet(path, picture, force=args.force)
            except (OSError, ValueError, ImportError) as exc:
                if len(entries) == 1:
                    raise
                err = one_line(str(exc) if str(path) in str(exc) else f"{path}: {exc}")
        if err is not None:                       # a bad file never stops the others
            failed += 1
            print(f"bdipole-cl preview: error: {err}", file=sys.stderr)
            continue
        for t in sheet.tiles:
            scale = "log" if t.log else "linear"
            print(f"{t.group.name}: {', '.join(t.group.names)}  "
                  f"{span_text(t.vmin, t.vmax, 4)} ({scale})")
        print(f"wrote {sheet.path} ({sheet.size[0]}x{sheet.size[1]})")
    return 1 if failed else 0
