"""Tile tokens of texture sets (I/O layer): the one registry of the tokens that DCCs and
renderers write for a tile in a file name, how each names a tile, the tokens that are known but
refused (frames, export names), and the pattern expansion that batches, scenes, Dask and
``preview`` share. The table, with the tools that write each token, is in docs/tiles.md.

A pattern holds either whole-tile tokens (``<UDIM>``, ``<UVTILE>``, ``<tile>``, ...; one kind,
which may repeat: ``<UDIM>/alb.<UDIM>.exr``) or one u and one v token (``u<U>_v<V>``,
``$U_$V``, ``<u><v>``). Any other token-like text (``<f>``, ``$textureSet``, ``%04d``,
``####``, ``<Udim>``) is refused, named: never taken as part of a file name. Tiles are 0-based
(u across, v up; UDIM 1001 is (0, 0)); ``u1_v1`` (1-based) is UDIM 1001, ``u10_v1`` is 1010
and ``u1_v2`` is 1011. An output's tokens may differ from its input's: each tile is converted.
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
class Token:
    """One tile token: how it is spelt, who writes it, what of the tile it names (``udim``,
    ``uv`` both axes, ``u`` or ``v``), its numbering base and how the tile is written
    (``str.format`` fields ``udim``, ``u``, ``v`` already based, ``w`` the field width)."""

    text: str
    tools: str
    part: str
    base: int
    form: str

    def write(self, tile: Tile, width: int, pattern: str) -> str:
        """The text this token stands for in ``tile``'s file name; a TileError where the
        token cannot name the tile."""
        if self.part == "udim":
            if tile.udim is None:
                raise TileError(f"pattern {pattern!r}: {self.text} cannot name tile "
                                f"{tile.label} (UDIM names u 1..10, up to 9999); use <UVTILE> "
                                f"or <UVTILE0> here")
            return self.form.format(udim=tile.udim)
        u, v = tile.u + self.base, tile.v + self.base
        text = self.form.format(u=u, v=v, w=width)
        if "##" in self.text and (u > 99 or v > 99):
            raise TileError(f"pattern {pattern!r}: {self.text} cannot name tile {tile.label} "
                            f"(two digits per axis)")
        return text

    @property
    def rx(self) -> str:
        """A regex of what the token writes (numbers as digit runs, a UDIM as four digits)."""
        pieces = _FIELDS.split(self.form)
        return "".join(re.escape(p) if k % 2 == 0 else (r"\d{4}" if p == "{udim}" else r"\d+")
                       for k, p in enumerate(pieces))


_FIELDS = re.compile(r"(\{(?:udim|u|v)(?::0(?:\{w\}|\d+)d)?\})")


def _uv(text, tools, base, form):
    return Token(text, tools, "uv", base, form)


#: every tile token a pattern may hold. Number-only u/v tokens (``%(U)d``, ``$U``) take a
#: width (``%(U)02d``, ``$2U``: zero-padded); ``u<U>`` is Maya's spelling (``u`` then the
#: number), ``<U>`` alone OpenImageIO's (it writes the ``u`` itself): both give ``u1``.
TOKENS = (
    Token("<UDIM>", "Mari, RenderMan, Houdini, Blender, USD, MaterialX, OpenImageIO, V-Ray",
          "udim", 0, "{udim}"),
    Token("<udim>", "Arnold", "udim", 0, "{udim}"),
    Token("$UDIM", "Mari and Substance Painter export templates", "udim", 0, "{udim}"),
    Token("%(UDIM)d", "Houdini, OpenImageIO", "udim", 0, "{udim}"),
    _uv("<UVTILE>", "Mudbox, Blender, MaterialX, OpenImageIO, V-Ray (1-based)", 1,
        "u{u}_v{v}"),
    _uv("<uvtile>", "OpenImageIO, V-Ray (0-based)", 0, "u{u}_v{v}"),
    _uv("<UVTILE0>", "ZBrush (0-based)", 0, "u{u}_v{v}"),
    _uv("%(UVTILE)d", "Houdini (1-based)", 1, "u{u:0{w}d}_v{v:0{w}d}"),
    _uv("<tile>", "Arnold (Mudbox, with its underscore)", 1, "_u{u}_v{v}"),
    _uv("_u##v##", "OpenImageIO (0-based, two digits)", 0, "_u{u:02d}v{v:02d}"),
    Token("u<U>", "Maya (1-based)", "u", 1, "u{u}"),
    Token("v<V>", "Maya (1-based)", "v", 1, "v{v}"),
    Token("u<u>", "Maya (0-based)", "u", 0, "u{u}"),
    Token("v<v>", "Maya (0-based)", "v", 0, "v{v}"),
    Token("<U>", "OpenImageIO (1-based, writes u1)", "u", 1, "u{u}"),
    Token("<V>", "OpenImageIO (1-based, writes v1)", "v", 1, "v{v}"),
    Token("<u>", "OpenImageIO (0-based, writes u0)", "u", 0, "u{u}"),
    Token("<v>", "OpenImageIO (0-based, writes v0)", "v", 0, "v{v}"),
    Token("%(U)d", "Houdini (1-based number)", "u", 1, "{u:0{w}d}"),
    Token("%(V)d", "Houdini (1-based number)", "v", 1, "{v:0{w}d}"),
    Token("$U", "V-Ray (1-based number)", "u", 1, "{u:0{w}d}"),
    Token("$V", "V-Ray (1-based number)", "v", 1, "{v:0{w}d}"),
    Token("$u", "V-Ray (0-based number)", "u", 0, "{u:0{w}d}"),
    Token("$v", "V-Ray (0-based number)", "v", 0, "{v:0{w}d}"),
)
_BY_TEXT = {t.text: t for t in TOKENS}

_FRAME = "not a tile: name one frame's files (this tool reads no image sequences)"
_EXPORT = ("filled by {tool} when it exports, not by this tool: name the files as they were "
           "written")
_SHAPE = ("filled by the renderer for each shape as it renders, not a tile: name the files "
          "one shape reads")
#: tokens that tools write but that name no tile: refused with why
REFUSED = {
    "<f>": f"Maya's frame token, {_FRAME}", "<frame>": f"a frame token, {_FRAME}",
    "<frameNum>": f"V-Ray's frame token, {_FRAME}", "$F": f"Houdini's frame token, {_FRAME}",
    "$FF": f"Houdini's frame token, {_FRAME}", "$FRAME": f"Mari's frame token, {_FRAME}",
    "_MAPID_": ("RenderMan's atlas token, whose numbering depends on the shader's atlas "
                "style: write <UDIM>, <UVTILE> (1-based) or <UVTILE0> (0-based)"),
    **{t: f"Arnold's per-shape token, {_SHAPE}" for t in ("<attr>", "<shapeName>",
                                                          "<shapePath>")},
    **{f"${n}": f"a Substance Painter export token, {_EXPORT.format(tool='Substance Painter')}"
       for n in ("textureSet", "mesh", "project", "colorSpace", "sceneName")},
    **{f"${n}": f"a Mari export token, {_EXPORT.format(tool='Mari')}"
       for n in ("CHANNEL", "ENTITY", "LAYER", "NUMBER", "NODE")},
}

#: what looks like a token in a file name: <...>, $NAME, ${...}, $(...), %(NAME)Nd, %Nd,
#: #-runs and RenderMan's _MAPID_; Maya's u<U>-style spellings and _u##v## first (longest)
_TOKENLIKE = re.compile(
    r"u<[Uu]>|v<[Vv]>|_u##v##|_MAPID_|<[^<>/\\]*>|%\(\w+\)\d*d|%0?\d*d(?![A-Za-z])"
    r"|\$\{[^}]*\}|\$\([^)]*\)|\$\d*[A-Za-z][A-Za-z0-9]*|#+")
_WIDTH = re.compile(r"%\((\w+)\)(\d*)d\Z|\$(\d*)([A-Za-z][A-Za-z0-9]*)\Z")


def _token(found: str, pattern: str) -> tuple:
    """(Token, width) for token-like text ``found`` of ``pattern``; a TileError naming it
    where it is refused or unknown."""
    m = _WIDTH.match(found)
    if m and m.group(1) is not None:                    # %(NAME)Nd
        key, width = f"%({m.group(1)})d", m.group(2)
    elif m:                                             # $NAME, $NNAME
        key, width = f"${m.group(4)}", m.group(3)
    else:
        key, width = found, ""
    token = _BY_TEXT.get(key)
    if token is not None and (not width or "{w}" in token.form):
        return token, int(width or 1)
    name = key.split(":")[0] + ">" if key.startswith("<") and ":" in key else key
    why = REFUSED.get(name) or REFUSED.get(found)
    if why is None and re.fullmatch(r"\$F\d", found):                # Houdini's $F4
        why = REFUSED["$F"]
    if why is None and (found.startswith("#") or re.fullmatch(r"%0?\d*d", found)):
        why = f"frame-number padding, {_FRAME}"
    if why is None:
        close = [t.text for t in TOKENS if t.text.casefold() == key.casefold()]
        why = (f"not a tile token (did you mean {' or '.join(close)}?)" if close else
               f"not a tile token this tool knows; tile tokens: {', '.join(_BY_TEXT)} "
               "(docs/tiles.md)")
    raise TileError(f"pattern {pattern!r}: {found} is {why}")


@dataclass(frozen=True)
class TilePattern:
    """A pattern's text cut at its tile tokens: literal ``parts`` around ``tokens`` ((Token,
    width) each), checked to name one tile."""

    text: str
    parts: tuple
    tokens: tuple

    @property
    def token(self) -> str:
        """The tokens as written, for messages: ``<UDIM>``, ``u<U> v<V>``."""
        return " ".join(dict.fromkeys(found for found in self.spelt))

    @property
    def spelt(self) -> tuple:
        return tuple(_spelling(t, w) for t, w in self.tokens)

    @property
    def convention(self) -> str:
        return "; ".join(dict.fromkeys(t.tools for t, _ in self.tokens))

    @property
    def output_token(self) -> str:
        """One registry token that writes the same tiles: the pattern's own where it is one
        whole-tile token, else ``<UDIM>`` or ``<UVTILE>``."""
        kinds = set(self.tokens)
        (token, width), = kinds if len(kinds) == 1 else ((TOKENS[0], 0),)
        if width == 1 and token.part in ("udim", "uv"):
            return token.text
        return "<UDIM>" if self.is_udim() else "<UVTILE>"

    def is_udim(self) -> bool:
        return all(t.part == "udim" for t, _ in self.tokens)

    def write(self, tile: Tile) -> str:
        """The file name of ``tile``."""
        out = [self.parts[0]]
        for (token, width), part in zip(self.tokens, self.parts[1:]):
            out += [token.write(tile, width, self.text), part]
        return "".join(out)

    def regex(self, literal) -> re.Pattern:
        """A regex of the pattern, each token a group, the parts through ``literal``."""
        out = [literal(self.parts[0])]
        for (token, _), part in zip(self.tokens, self.parts[1:]):
            out += [f"({token.rx})", literal(part)]
        return re.compile("".join(out) + r"\Z")

    def tile_of(self, match: re.Match) -> Tile | None:
        """The tile a regex match names, or None where the text is no tile of this pattern:
        each token's text must be exactly what the token writes for that tile (``1000``,
        ``u0_v1`` for a 1-based token, ``01`` for an unpadded number are not)."""
        u = v = None
        for (token, _), text in zip(self.tokens, match.groups()):
            got = _read(token, text)
            if got is None:
                return None
            u = got[0] if u is None and got[0] is not None else u
            v = got[1] if v is None and got[1] is not None else v
        if u is None or v is None or u < 0 or v < 0:
            return None
        tile = Tile(u, v)
        try:
            same = all(token.write(tile, width, self.text) == text
                       for (token, width), text in zip(self.tokens, match.groups()))
        except TileError:
            return None
        return tile if same else None


def _spelling(token: Token, width: int) -> str:
    if width == 1:
        return token.text
    return token.text.replace(")d", f"){width:02d}d") if token.text.startswith("%") \
        else f"${width}{token.text[1:]}"


def _read(token: Token, text: str):
    """(u, v) 0-based that a token's text gives (None for an axis it does not name), or None
    where the text holds no number for it."""
    nums = [int(n) for n in re.findall(r"\d+", text)]
    if token.part == "udim":
        return ((nums[0] - 1001) % 10, (nums[0] - 1001) // 10) if len(nums) == 1 \
            and nums[0] >= 1001 else None
    if token.part == "uv":
        return (nums[0] - token.base, nums[1] - token.base) if len(nums) == 2 else None
    if len(nums) != 1:
        return None
    return (nums[0] - token.base, None) if token.part == "u" else (None, nums[0] - token.base)


def token_of(pattern) -> TilePattern | None:
    """The tile tokens of a pattern, or None where it has none; a TileError (one line, naming
    the pattern and the token) for a refused or unknown token, or tokens that do not name one
    tile (two kinds of whole-tile token, a u without a v, a whole-tile token with a u)."""
    text = str(pattern)
    parts, tokens, at = [], [], 0
    for m in _TOKENLIKE.finditer(text):
        tokens.append(_token(m.group(0), text))
        parts.append(text[at:m.start()])
        at = m.end()
    if not tokens:
        return None
    parts.append(text[at:])
    whole = list(dict.fromkeys(t.text for t, _ in tokens if t.part in ("udim", "uv")))
    axes = {t.part for t, _ in tokens if t.part in ("u", "v")}
    if len(whole) > 1 or (whole and axes):
        spelt = list(dict.fromkeys(m.group(0) for m in _TOKENLIKE.finditer(text)))
        raise TileError(f"pattern {text!r} holds {' and '.join(spelt)}: one tile token per "
                        f"pattern (or one u and one v token)")
    if not whole and axes != {"u", "v"}:
        have, lack = ("u", "v") if "u" in axes else ("v", "u")
        raise TileError(f"pattern {text!r} names the tile's {have} but not its {lack}: add a "
                        f"{lack} token (e.g. u<U>_v<V>)")
    return TilePattern(text, tuple(parts), tuple(tokens))


def has_tokens(path) -> bool:
    """Whether ``path`` holds token-like text (known, refused or unknown)."""
    return _TOKENLIKE.search(str(path)) is not None


def is_pattern(path) -> bool:
    """Whether ``path`` is a glob or tile pattern rather than one file's name (also where its
    token is refused: ``token_of`` says why)."""
    return has_tokens(path) or glob.has_magic(str(path))


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
    an empty list when a glob or tile pattern matches nothing; a TileError for a refused or
    unknown token. In a tile pattern the rest of the text is taken literally first
    (``tex[v2]/a.<UDIM>.exr``), else as a glob (``tex/*.<UDIM>.exr``)."""
    text = str(pattern)
    pat = token_of(text)
    if pat is None:
        if glob.has_magic(text):
            return [(h, None) for h in sorted(glob.glob(text))]
        return [(text, None)]
    hits = _tiles(pat, re.escape, glob.escape)
    if not hits and glob.has_magic("".join(pat.parts)):
        hits = _tiles(pat, _glob_regex, lambda p: p)
    return [(h, tile) for _, h, tile in sorted(hits)]


def _tiles(pat: TilePattern, regex_literal, glob_literal):
    rx = pat.regex(regex_literal)
    hits = []
    for h in glob.glob("*".join(glob_literal(p) for p in pat.parts)):
        m = rx.match(h)
        tile = pat.tile_of(m) if m else None
        if tile is not None:
            hits.append(((tile.v, tile.u, h), h, tile))
    return hits


def match(pattern, name) -> Tile | None:
    """The tile ``name`` is in tile pattern ``pattern`` (its text literal), or None."""
    pat = token_of(pattern)
    m = pat.regex(re.escape).match(str(name)) if pat is not None else None
    return pat.tile_of(m) if m else None


def fill(pattern, tile: Tile | None, source) -> str:
    """``pattern`` with its tile tokens (if any) written for ``tile``, the tile of ``source``
    (named in the error when it has none)."""
    text = str(pattern)
    pat = token_of(text)
    if pat is None:
        return text
    if tile is None:
        raise TileError(f"{source}: pattern {text!r} needs a tile ({pat.token}) but the input "
                        f"has none")
    return pat.write(tile)


def describe() -> str:
    """The tokens, for help texts: ``<UDIM> (Mari, ...), ...``."""
    return ", ".join(f"{t.text} ({t.tools})" for t in TOKENS)
