"""Input patterns and output paths of texture batches and scenes (I/O layer): which files a
path, glob or tile pattern names (``expand_inputs``; tile conventions: ``tiles``), and the
output or companion (mfp, mask) path of each (``companion_path``)."""
from __future__ import annotations

import os
import re
from pathlib import Path

from . import tiles
from .images import TextureError, image_header


#: the header mark of a texture this tool writes for others to read as painted (a target's
#: colour and radius maps, jobs.scene_maps): an input like any other when a pattern names it
PAINTED_MARK = "bdipole:painted"


def written_by_us(path) -> bool:
    """An EXR whose header says bdipole-cl wrote it (``bdipole:version``): one of this tool's
    own outputs, never picked up again by a glob; but a painted map (PAINTED_MARK), which a
    stage's material reads as its textures."""
    spec = image_header(path) if str(path).lower().endswith(".exr") else None
    return spec is not None and bool(spec.getattribute("bdipole:version")) and \
        not spec.getattribute(PAINTED_MARK)


def expand_inputs(patterns, ours=False):
    """Files named by paths, globs (``textures/*.tif``) or tile patterns (``a.<UDIM>.exr``,
    ``a_<UVTILE>.exr``, ...: ``tiles``), as ``(path, Tile or None)``, in order, without
    duplicates (one file named twice, ``a.exr`` and ``./a.exr`` or through a link, is one
    job: compared by real path). A pattern matching nothing is kept as a path, so that it is
    reported as missing rather than silently skipped. A path that exists is taken as it is
    (``tex[v2]/a.exr`` is a file name, not a glob); the files a pattern matches leave out this
    tool's own outputs (``written_by_us``) unless ``ours`` (``preview`` draws them)."""
    out, seen = [], set()
    for pattern in patterns:
        pattern = str(pattern)
        if os.path.exists(pattern):
            found = [(pattern, None)]
        elif tiles.is_pattern(pattern):
            try:
                found = [(h, t) for h, t in tiles.expand(pattern)
                         if ours or not written_by_us(h)]
            except tiles.TileError:     # a refused or unknown token: unmatched_pattern says
                found = []
        else:
            found = [(pattern, None)]
        if not found:
            found = [(pattern, None)]
        for path, tile in found:
            key = os.path.realpath(path) if os.path.exists(path) else path
            if key not in seen:
                seen.add(key)
                out.append((path, tile))
    return out


def unmatched_pattern(pattern) -> str:
    """Why a pattern named no file (``expand_inputs`` kept it as a path): nothing matches it,
    or what matches is only this tool's own outputs, which a pattern leaves out, or its token
    is refused (``tiles``: never a file name)."""
    try:
        ours = [h for h, _ in tiles.expand(str(pattern)) if written_by_us(h)]
    except tiles.TileError as exc:
        return str(exc)
    if ours:
        return (f"{pattern}: matches only this tool's own outputs ({len(ours)}, e.g. "
                f"{ours[0]}), which a pattern leaves out; name such a file as a path to use it")
    conv = tiles.token_of(str(pattern))
    return (f"{pattern}: no file matches this pattern"
            + (f" ({conv.token}: {conv.convention}; tile 1001 would be "
               f"{os.path.basename(conv.write(tiles.Tile(0, 0)))})" if conv else ""))


def stem(path):
    """The file name without its extension: ``diffuse.1001.exr`` -> ``diffuse.1001``, so that
    the tiles of a UDIM set keep distinct names."""
    name = Path(path).name
    return name.rsplit(".", 1)[0] if "." in name else name


#: the fields of an output or companion pattern; any other text in braces is literal
PATTERN_FIELDS = ("stem", "dir", "name", "udim")
_FIELD = re.compile(r"\{(" + "|".join(PATTERN_FIELDS) + r")\}")


def companion_path(pattern, path, tile):
    """Fill ``{stem}``, ``{dir}``, ``{name}``, ``{udim}`` (the tile's label) and the tile
    token (``tiles``, written in the pattern's own convention) for one input file; other braces
    are part of the name (``proj{v2}/``). A tile token or ``{udim}`` with an input that has no
    tile is an error (it would write ``s..exr``)."""
    p = Path(path)
    text = str(pattern)
    if tile is None and "{udim}" in text:
        raise TextureError(f"{path}: pattern {pattern!r} needs a UDIM but the input has none "
                           f"(a tiled input is named with a tile token, e.g. a.<UDIM>.exr)")
    text = tiles.fill(text, tile, path)
    fields = {"stem": stem(path), "dir": str(p.parent), "name": p.name,
              "udim": tile.label if tile is not None else ""}
    return _FIELD.sub(lambda m: fields[m.group(1)], text)


def outputs_of(inputs, output, default, what="output") -> list:
    """``[(file, Tile or None, output path or None, error or None)]`` for the files that
    ``inputs`` (paths, globs, tile patterns; this tool's outputs too) name: ``output`` filled
    for each file's tile and name (``sheet.<UDIM>.png``, ``{stem}.png``), else
    ``default(file)``. A pattern that names no file, a token that cannot name a tile, or one
    output for several files is that file's error (one line)."""
    out = []
    for path, tile in expand_inputs([str(p) for p in inputs], ours=True):
        try:
            if tiles.is_pattern(path) and not os.path.exists(path):
                raise TextureError(unmatched_pattern(path))
            out.append((path, tile, str(companion_path(output, path, tile)
                                        if output is not None else default(path)), None))
        except (TextureError, tiles.TileError) as exc:
            out.append((path, tile, None, str(exc)))
    named = [p for _, _, p, e in out if e is None]
    one = "a tile token or {stem}"
    return [(path, t, None, f"-o {output}: names one {what} ({p}) for {named.count(p)} files; "
                            f"put {one} in it") if e is None and named.count(p) > 1
            else (path, t, p, e) for path, t, p, e in out]
