"""Tile conventions of texture sets (I/O layer): the one registry of the tokens that stand for
a tile in input and output patterns, how each names a tile, and the pattern expansion that
batches and scenes share.

=============  =========================  =======================================
token          convention                 tile (u, v) 0-based, as written
=============  =========================  =======================================
``<UDIM>``     Mari, most renderers       ``1001 + u + 10 v`` (u < 10): ``1012``
``%(UDIM)d``   Houdini                    the same number
``<UVTILE>``   Mudbox, Cycles (1-based)   ``u{u+1}_v{v+1}``: ``u2_v2``
``%(UVTILE)d`` Houdini                    the same, 1-based
``<UVTILE0>``  ZBrush (0-based)           ``u{u}_v{v}``: ``u1_v1``
=============  =========================  =======================================

So ``u1_v1`` (1-based) is UDIM 1001, ``u10_v1`` is 1010 and ``u1_v2`` is 1011. An output
pattern's token may differ from its input's: each tile is converted (read ``u1_v1``, write
``<UDIM>``). A tile a token cannot express (UDIM holds ten tiles along u) is a one-line error.
"""
from __future__ import annotations

import glob
import re
from dataclasses import dataclass


class TileError(ValueError):
    """A pattern whose tile token cannot be used: one line naming the pattern and the tile."""


@dataclass(frozen=True)
class Tile:
    """One tile of a texture set, 0-based: u across, v up (UDIM 1001 is (0, 0))."""

    u: int
    v: int

    @property
    def udim(self) -> int | None:
        """The UDIM number, or None when the tile has none: beyond UDIM's ten columns
        (u >= 10) or its four digits (past 9999)."""
        n = 1001 + self.u + 10 * self.v
        return n if 0 <= self.u < 10 and self.v >= 0 and n <= 9999 else None

    @property
    def label(self) -> str:
        """How plans and summaries name the tile: its UDIM, else 1-based ``u11_v1``."""
        return str(self.udim) if self.udim is not None else f"u{self.u + 1}_v{self.v + 1}"


@dataclass(frozen=True)
class TileConvention:
    """A tile token: the name of its convention, the text it matches in a file name (regex,
    glob) and how a tile is written and read back."""

    token: str
    convention: str
    regex: str                       # groups: the number(s) in the name
    glob: str
    base: int                        # 1 or 0 for u/v names; None for UDIM numbers

    def is_udim(self) -> bool:
        return self.base is None

    def parse(self, match: re.Match) -> Tile | None:
        """The tile a regex match names, or None when the text is no tile of this convention
        (``1000``, ``u0_v1`` for a 1-based token)."""
        if self.is_udim():
            n = int(match.group(1))
            return Tile((n - 1001) % 10, (n - 1001) // 10) if n >= 1001 else None
        u, v = int(match.group(1)) - self.base, int(match.group(2)) - self.base
        return Tile(u, v) if u >= 0 and v >= 0 else None

    def format(self, tile: Tile, pattern: str) -> str:
        if not self.is_udim():
            return f"u{tile.u + self.base}_v{tile.v + self.base}"
        if tile.udim is None:
            raise TileError(f"pattern {pattern!r}: {self.token} cannot name tile {tile.label} "
                            f"(UDIM names u 1..10, up to 9999); use <UVTILE> or <UVTILE0> here")
        return str(tile.udim)


_UDIM = dict(regex=r"(\d{4})", glob="[1-9][0-9][0-9][0-9]", base=None)
_UV = dict(regex=r"u(\d+)_v(\d+)", glob="u[0-9]*_v[0-9]*")

#: every tile token a pattern may hold (one per pattern)
CONVENTIONS = (
    TileConvention("<UDIM>", "UDIM (Mari)", **_UDIM),
    TileConvention("%(UDIM)d", "UDIM (Houdini)", **_UDIM),
    TileConvention("<UVTILE>", "1-based u1_v1 (Mudbox, Cycles)", base=1, **_UV),
    TileConvention("%(UVTILE)d", "1-based u1_v1 (Houdini)", base=1, **_UV),
    TileConvention("<UVTILE0>", "0-based u0_v0 (ZBrush)", base=0, **_UV),
)
TOKENS = tuple(c.token for c in CONVENTIONS)


def token_of(pattern) -> TileConvention | None:
    """The tile convention of a pattern, or None; two different tokens are a TileError."""
    text = str(pattern)
    found = [c for c in CONVENTIONS if c.token in text]
    if len(found) > 1:
        raise TileError(f"pattern {text!r} holds {' and '.join(c.token for c in found)}: one "
                        f"tile token per pattern")
    return found[0] if found else None


def is_pattern(path) -> bool:
    """Whether ``path`` is a glob or tile pattern rather than one file's name."""
    return token_of(path) is not None or glob.has_magic(str(path))


def _glob_regex(text: str) -> str:
    """A glob's literal parts and wildcards (``*``, ``?``, ``[...]``) as a regex."""
    out, i = [], 0
    while i < len(text):
        ch = text[i]
        close = text.find("]", i + 2) if ch == "[" else -1
        if ch == "*":
            out.append(r"[^/]*")
        elif ch == "?":
            out.append(r"[^/]")
        elif close > 0:
            body = text[i + 1:close]
            out.append("[" + ("^" + body[1:] if body.startswith("!") else body) + "]")
            i = close
        else:
            out.append(re.escape(ch))
        i += 1
    return "".join(out)


def expand(pattern) -> list:
    """``[(path, Tile or None)]`` for a path, glob or tile pattern, sorted by tile then path;
    an empty list when a glob or tile pattern matches nothing. In a tile pattern the rest of
    the text is taken literally first (``tex[v2]/a.<UDIM>.exr``), else as a glob
    (``tex/*.<UDIM>.exr``)."""
    text = str(pattern)
    conv = token_of(text)
    if conv is None:
        if glob.has_magic(text):
            return [(h, None) for h in sorted(glob.glob(text))]
        return [(text, None)]
    parts = text.split(conv.token)
    hits = _tiles(conv, [re.escape(p) for p in parts], [glob.escape(p) for p in parts])
    if not hits and glob.has_magic(text.replace(conv.token, "")):
        hits = _tiles(conv, [_glob_regex(p) for p in parts], parts)
    return [(h, tile) for _, h, tile in sorted(hits)]


def _tiles(conv, regex_parts, glob_parts):
    rx = re.compile(conv.regex.join(regex_parts) + r"\Z")
    hits = []
    for h in glob.glob(conv.glob.join(glob_parts)):
        m = rx.match(h)
        tile = conv.parse(m) if m else None
        if tile is not None:
            hits.append(((tile.v, tile.u, h), h, tile))
    return hits


def fill(pattern, tile: Tile | None, source) -> str:
    """``pattern`` with its tile token (if any) written for ``tile``, the tile of ``source``
    (named in the error when it has none)."""
    text = str(pattern)
    conv = token_of(text)
    if conv is None:
        return text
    if tile is None:
        raise TileError(f"{source}: pattern {text!r} needs a tile ({conv.token}) but the input "
                        f"has none")
    return text.replace(conv.token, conv.format(tile, text))


def describe() -> str:
    """The tokens, for help texts: ``<UDIM> (UDIM (Mari)), ...``."""
    return ", ".join(f"{c.token} ({c.convention})" for c in CONVENTIONS)
