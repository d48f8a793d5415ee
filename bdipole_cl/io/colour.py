"""Colour management (I/O layer): every albedo and irradiance texel is converted into one
working space through OpenColorIO before any computation; what is not a colour is never
converted (docs/model.md "Colour").

* **The config** (``active_config``): the one named by ``$OCIO`` when it is set, else the
  built-in ``ocio://default``. Conversions are that config's OpenColorIO processors (what
  OpenImageIO's ``colorconvert`` applies); no colour matrix is written here.
* **The working space** (``resolve_working_space``): any scene-linear colour space of the config, by
  name or alias. Default: the config's ``scene_linear`` role under ``$OCIO`` (a studio's
  pipeline), else ``lin_rec709_scene``.
* **An input's space** (``colour_path``): the one given (``colorspace``), else what the file
  declares (``declared``: an ICC profile at any bit depth, a PNG's sRGB/gAMA/cHRM chunks,
  EXIF ColorSpace; an EXR's ``colorInteropID`` and other formats' ``oiio:ColorSpace``; EXR
  ``chromaticities``), each in OpenColorIO's built-in config's words followed into the active
  config (``ColourConfig.builtin_space``: its name, alias or interop ID, else OpenColorIO's
  ``IdentifyBuiltinColorSpace`` through its interchange roles, else for sRGB textures its
  ``texture_paint`` or ``color_picking`` role), else: 8-bit is the config's ``texture_paint``
  role (sRGB in the built-in config), as is any undeclared PNG (sRGB is PNG's default at
  every bit depth); other 16-bit and float files are already in the working space.
  Declarations that disagree, or that the config cannot follow, fail the file, named.
* **Never converted**: mfp textures and constants (lengths per channel of the working space),
  masks and alpha (data).
* **Outputs** (``tag_output``): ``oiio:ColorSpace`` is the working space (its interop ID when
  the config has one), the EXR ``chromaticities`` are its primaries and white point.

OpenColorIO's default CPU processors evaluate powers with a fast approximation (2.4e-5 off at
sRGB white); ``OCIO_OPTIMIZATION_FLAGS`` is set to its lossless level unless the user set it,
so the decoding is exact to float32 (docs/colour.md).
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import OpenImageIO as oiio
import PyOpenColorIO as ocio

from . import declared
from .ocio_configs import ocio_config, oiio_config, processor, reset_config_cache


#: the config when $OCIO is not set: OpenImageIO's built-in (OpenColorIO's CG config)
BUILTIN_CONFIG = "ocio://default"
#: the working space when $OCIO is not set (linear Rec.709, sRGB primaries, D65)
DEFAULT_WORKING_SPACE = "lin_rec709_scene"
#: what an undeclared 8-bit file is encoded in (the first name the config knows)
SRGB_NAMES = ("srgb_rec709_scene", "sRGB", "srgb_tx", "srgb_texture")
#: primaries and white point xy (x, y of R, G, B, W) match a space within this: writers round
#: them to 4-5 digits (D65 is 0.3127, 0.3290 or 0.31271, 0.32902); the nearest distinct common
#: spaces differ by more than 0.005 (D60 vs D65 white, P3 vs Rec.709 green)
CHROMATICITY_TOL = 1e-3


def _short(name) -> str:
    return str(name).rsplit(".", 1)[-1].strip().lower()


_RGB = {"r": 0, "red": 0, "g": 1, "green": 1, "b": 2, "blue": 2}


# {{{ the config

@dataclass(frozen=True)
class ColourConfig:
    """An OpenColorIO config by name (picklable: the loaded config is cached per process)."""

    name: str          # "ocio://default", a built-in URI or a file path
    source: str        # "$OCIO" or "built-in"

    @property
    def _cfg(self):
        return oiio_config(self.name)

    def space(self, name) -> str | None:
        """The config's own name for the colour space, role or alias ``name``, or None."""
        resolved = self._cfg.resolve(str(name))
        return resolved if self._cfg.getColorSpaceIndex(resolved) >= 0 else None

    def names(self) -> tuple:
        return tuple(self._cfg.getColorSpaceNames())

    def alias_in(self, space, vocabulary) -> str | None:
        """The first of the colour space's own name and aliases that ``vocabulary`` (another
        system's names: MaterialX's, USD's) holds, or None."""
        resolved = self.space(space)
        if resolved is None:
            return None
        names = (resolved, *self._cfg.getAliases(resolved))
        return next((n for n in names if n in vocabulary), None)

    def is_data(self, space) -> bool:
        return bool(self._cfg.isData(space))

    def is_scene_linear(self, space) -> bool:
        return bool(self._cfg.isColorSpaceLinear(space)) and not self.is_data(space)

    def working_names(self) -> tuple:
        return tuple(n for n in self.names() if self.is_scene_linear(n))

    def chromaticities(self, space) -> tuple | None:
        """Primaries and white point (xR, yR, xG, yG, xB, yB, xW, yW), when the config knows."""
        xy = self._cfg.get_chromaticities(space)
        return tuple(float(v) for v in xy) if xy else None

    def interop_id(self, space) -> str:
        return self._cfg.get_color_interop_id(space) or ""

    def role(self, role) -> str | None:
        """The space the config's role ``role`` names (texture_paint, ...), or None."""
        space = ocio_config(self.name).getRoleColorSpace(role)
        return self.space(space) if space else None

    def builtin_space(self, name) -> str | None:
        """This config's space for the built-in config's space ``name`` (an interop ID such as
        srgb_rec709_scene): its name or alias, else the space with that interop ID, else the
        one OpenColorIO identifies as the same through the config's interchange roles
        (``Config.IdentifyBuiltinColorSpace``), else None."""
        own = self.space(name)
        if own is not None or self.name == BUILTIN_CONFIG:
            return own
        canon = ColourConfig(BUILTIN_CONFIG, "built-in").space(name)
        if canon is None:
            return None
        interop = ColourConfig(BUILTIN_CONFIG, "built-in").interop_id(canon) or canon
        own = self.space(canon) or self.space(interop)
        same = [n for n in self.names() if self.interop_id(n) in (name, interop)]
        if own or same:
            return own or same[0]
        try:
            found = ocio.Config.IdentifyBuiltinColorSpace(ocio_config(self.name),
                                                          ocio_config(BUILTIN_CONFIG), canon)
        except Exception:       # no interchange roles, none matches, or a space that cannot
            return None         # be built (OCIO's ExceptionMissingFile is no ocio.Exception)
        return self.space(found) if found else None

    def match_chromaticities(self, xy) -> str | None:
        """The first scene-linear space whose primaries and white are ``xy`` (CHROMATICITY_TOL)."""
        for n in self.working_names():
            ch = self.chromaticities(n)
            if ch and max(abs(a - b) for a, b in zip(ch, xy)) <= CHROMATICITY_TOL:
                return n
        return None

    def convert(self, rgb, source, target):
        """(rows, width, 3) float32 texels from ``source`` to ``target`` by this config's
        OpenColorIO CPU processor (the one OpenImageIO's colorconvert applies, bit for bit;
        unpremultiplied: only colour channels are passed)."""
        out = np.array(rgb, np.float32, order="C")
        try:           # names as OpenImageIO resolves them ("sRGB", "linear": its aliases)
            processor(self.name, self.space(source) or source,
                       self.space(target) or target).applyRGB(out)
        except Exception as exc:   # a space the config lacks, a LUT missing (ExceptionMissingFile)
            raise ValueError(f"colour conversion {source} -> {target} (OCIO config "
                             f"{self.name}) failed: {' '.join(str(exc).split())}") from None
        return out


def active_config() -> ColourConfig:
    """The config named by ``$OCIO`` when set, else the built-in one (ValueError if unusable)."""
    env = os.environ.get("OCIO", "").strip()
    if env and "://" not in env:          # a file: by its absolute path (a chdir is another)
        env = os.path.abspath(env)
    config = ColourConfig(env, "$OCIO") if env else ColourConfig(BUILTIN_CONFIG, "built-in")
    oiio_config(config.name)
    return config


def _unknown(what, name, config, known) -> ValueError:
    return ValueError(f"{what} {name!r} is unknown to OCIO config {config.name}; known: "
                      f"{', '.join(known)} (or an alias or role of one)")


def resolve_colorspace(name, config=None) -> str:
    """The config's name for an input colour space ``name`` (ValueError listing the known):
    its own name or alias, else a space of the built-in config followed into it
    (``followed``: a scene's ``srgb_texture`` or ``srgb_rec709_scene`` under a studio's
    config)."""
    config = config or active_config()
    space = config.space(name) or followed(config, name)
    if space is None:
        raise _unknown("colorspace", name, config, ("auto",) + config.names())
    return space


def check_colorspace(colorspace, config=None) -> None:
    """A ``colorspace`` option: "auto" or a space of the config, else ValueError."""
    if colorspace not in (None, "", "auto"):
        resolve_colorspace(colorspace, config)

# }}}


# {{{ the working space

@dataclass(frozen=True)
class WorkingSpace:
    """The space every colour is inverted and blurred in (the renderer's rendering space)."""

    name: str                      # the config's name for it
    config: ColourConfig

    def describe(self) -> str:
        return f"{self.name}, config {self.config.name}"

    @property
    def key(self) -> dict:
        """What an output's up-to-date check compares."""
        return {"working_space": self.name, "ocio_config": self.config.name}


def resolve_working_space(name=None, config=None) -> WorkingSpace:
    """The working space ``name`` (a space, alias or role of the config), or the default: the
    ``scene_linear`` role under ``$OCIO``, else lin_rec709_scene. It must be scene-linear: an
    albedo is a reflectance, inverted per channel (ValueError listing the ones there are)."""
    if isinstance(name, WorkingSpace):
        return name
    config = config or active_config()
    if not name:
        name = "scene_linear" if config.source == "$OCIO" else DEFAULT_WORKING_SPACE
    space = config.space(name)
    if space is None:
        raise _unknown("working space", name, config, config.working_names())
    if not config.is_scene_linear(space):
        raise ValueError(f"working space {name!r} ({space}) is not scene-linear: an albedo is "
                         f"inverted as a linear reflectance; choose one of "
                         f"{', '.join(config.working_names())}")
    return WorkingSpace(space, config)

# }}}


# {{{ an input's colour path

def encoding(spec) -> str:
    """How a file stores its texels: 8-bit, 16-bit, 32-bit (integers), half or float."""
    base = spec.format.basetype
    if base == oiio.HALF:
        return "half"
    if base in (oiio.FLOAT, oiio.DOUBLE):
        return "float"
    return f"{8 * spec.format.size()}-bit"


def _declared_chromaticities(spec):
    attr = next((a for a in spec.extra_attribs if a.name == "chromaticities"), None)
    if attr is None:
        return None
    values = np.ravel(attr.value)
    return tuple(float(v) for v in values) if values.size == 8 else None


@dataclass(frozen=True)
class ColourPath:
    """Where one file's colour texels come from and go: ``source`` -> the working space."""

    source: str                # the config's name of the space the file's texels are in
    how: str                   # given | declared | chromaticities | default
    encoding: str              # 8-bit | 16-bit | half | float ...
    working: WorkingSpace

    @property
    def identity(self) -> bool:
        return self.source == self.working.name or self.working.config.is_data(self.source)

    def describe(self) -> str:
        return f"{self.source} ({self.encoding}, {self.how}) -> {self.working.describe()}"

    def header(self, role) -> dict:
        """``bdipole:*`` attributes recording this input's path (``role``: albedo, ...)."""
        return {f"{role}_colorspace": self.source, f"{role}_colour": self.describe(),
                **self.working.key}

    def convert(self, pixels, names):
        """(rows, width, C) colour texels, channels ``names``, into the working space: RGB by
        name in any order, or one grey channel as (y, y, y), kept as the mean of the result
        (the three agree: chromatic adaptation maps white to white)."""
        if self.identity:
            return pixels
        if pixels.shape[-1] == 1:
            return self.working.config.convert(np.repeat(pixels, 3, axis=-1), self.source,
                                               self.working.name).mean(axis=-1, keepdims=True)
        order = _rgb_order(names)
        if order is None:
            raise ValueError(_layout_error(names, self.source))
        rgb = self.working.config.convert(pixels[..., np.argsort(order)], self.source,
                                          self.working.name)
        return rgb[..., order]


def _rgb_order(names):
    """Each channel's index in R, G, B, when ``names`` are those three in any order."""
    order = [_RGB.get(_short(n), -1) for n in names]
    return order if sorted(order) == [0, 1, 2] else None


def _layout_error(names, source) -> str:
    return (f"channels {', '.join(names)}: a colour conversion from {source} needs R, G and "
            f"B or one grey channel (give the working space as colorspace to take them as "
            f"they are)")


def colour_path(spec, path, colorspace="auto", working=None, names=None) -> ColourPath:
    """The colour path of a file (``spec`` as read; ``names``: its colour channels) into
    ``working`` (see the module docstring for the order of the rules). ValueError naming the
    file when its declaration is unknown to the config or contradicts its chromaticities, or
    when its channels cannot be converted."""
    route = _colour_path(spec, path, colorspace, resolve_working_space(working))
    if names and len(names) != 1 and not route.identity and _rgb_order(names) is None:
        raise ValueError(f"{path}: {_layout_error(names, route.source)}")
    return route


#: roles that name the space of painted (8-bit) textures, in the order consulted
PAINT_ROLES = ("texture_paint", "color_picking")
#: the built-in config's space of an sRGB texture
SRGB = "srgb_rec709_scene"


def _given_up(path, what) -> ValueError:
    return ValueError(f"{path}: {what}: give its space (--colorspace / colorspace =)")


def followed(config, name) -> str | None:
    """The active config's space for the built-in config's space ``name``
    (``ColourConfig.builtin_space``; an sRGB texture also by the config's paint roles)."""
    builtin = ColourConfig(BUILTIN_CONFIG, "built-in")
    if builtin.space(name) is None:
        return None
    space = config.builtin_space(name)
    if space is None and builtin.space(name) == builtin.space(SRGB):
        space = next((s for s in map(config.role, PAINT_ROLES) if s), None)
    return space


def _follow(config, declared_space, how, path) -> str:
    """The active config's space for a declaration (its own name or alias, else
    ``followed``), else ValueError naming the file and what the config lacks."""
    own = config.space(declared_space)          # the active config's own name or alias
    if own is not None:
        return own
    if ColourConfig(BUILTIN_CONFIG, "built-in").space(declared_space) is None:
        raise _given_up(path, f"{how} declares {declared_space}, which OpenColorIO's built-in "
                              f"config has no space for")
    space = followed(config, declared_space)
    if space is None:
        raise _given_up(path, f"{how} declares {declared_space}, which OCIO config "
                              f"{config.name} has no space for (by name, alias, interop ID, "
                              f"its interchange roles or its {'/'.join(PAINT_ROLES)} roles)")
    return space


def _declared(spec, path, config) -> tuple:
    """(the config's space, how it was declared) of the file's own declarations, or
    (None, None); ValueError where one cannot be followed or two disagree."""
    try:
        found = declared.declarations(spec, path)
    except declared.DeclarationError as exc:
        raise _given_up(path, str(exc)) from None
    kind = declared.file_kind(path)
    tag = spec.getattribute("oiio:ColorSpace")
    if tag and kind not in ("png", "jpeg"):  # there OpenImageIO's tag is its own default, or
        found.append(declared.Declared(str(tag), "oiio:ColorSpace"))    # the chunks' reading
    spaces = {}
    for d in found:
        spaces.setdefault(_follow(config, d.space, d.how, path), []).append(d)
    if len(spaces) > 1:
        raise _given_up(path, "declares " + " but ".join(
            f"{s} ({', '.join(d.how for d in ds)})" for s, ds in spaces.items()))
    space, ds = next(iter(spaces.items()), (None, [None]))
    return space, ds[0]


def _colour_path(spec, path, colorspace, working) -> ColourPath:
    config = working.config
    enc = encoding(spec)
    if colorspace not in (None, "", "auto"):
        return ColourPath(resolve_colorspace(colorspace, config), "given", enc, working)
    xy = _declared_chromaticities(spec)
    space, first = _declared(spec, path, config)
    if space is not None:
        own = config.chromaticities(space)
        if xy and own and max(abs(a - b) for a, b in zip(own, xy)) > CHROMATICITY_TOL:
            raise _given_up(path, f"declares {first.space!r} but its chromaticities "
                                  f"{', '.join(f'{v:.4f}' for v in xy)} are not that space's")
        return ColourPath(space, "declared", enc, working)
    if xy and enc in ("half", "float"):
        space = config.match_chromaticities(xy)
        if space is None:
            raise _given_up(path, f"its chromaticities {', '.join(f'{v:.4f}' for v in xy)} "
                                  f"match no linear colour space of OCIO config {config.name}")
        return ColourPath(space, "chromaticities", enc, working)
    if enc == "8-bit" or declared.file_kind(path) in ("png", "jpeg"):  # PNG's own default
        space = (next((s for s in map(config.role, PAINT_ROLES) if s), None)
                 or config.builtin_space(SRGB)
                 or next((s for s in map(config.space, SRGB_NAMES) if s), None))
        if space is None:
            raise _given_up(path, f"an undeclared 8-bit file or PNG is taken as the config's "
                                  f"{'/'.join(PAINT_ROLES)} role or sRGB, which OCIO config "
                                  f"{config.name} has not")
        return ColourPath(space, "default", enc, working)
    return ColourPath(working.name, "default", enc, working)

# }}}


# {{{ outputs

#: input attributes that describe the input's colour, never copied to an output
COLOUR_ATTRIBS = ("oiio:ColorSpace", "colorInteropID", "chromaticities", "ICCProfile",
                  "adoptedNeutral", "oiio:Gamma")


def data_space(config=None) -> str:
    """The config's data colour space (its ``data`` role, else its first ``isdata`` space,
    else "Raw"): what a file of numbers that are not colour (coefficients, a radius, alpha)
    declares, so that no reader converts them as colour."""
    config = config or active_config()
    return config.role("data") or next((n for n in config.names() if config.is_data(n)),
                                       "Raw")


def tag_data(spec, config) -> None:
    """Tag an output ImageSpec as data: ``oiio:ColorSpace`` the config's data space and the
    EXR ``colorInteropID`` its interop ID ("data" in OpenColorIO's built-in config); no
    chromaticities (the numbers have no primaries to convert)."""
    space = data_space(config)
    spec.attribute("oiio:ColorSpace", space)
    spec.attribute("colorInteropID", config.interop_id(space) or "data")


def tag_output(spec, working) -> None:
    """Tag an output ImageSpec as being in ``working``: ``oiio:ColorSpace`` and the EXR
    ``colorInteropID`` (its interop ID in the config, e.g. lin_ap1_scene for ACEScg, else its
    name; set here, not left to OpenImageIO's writer, which looks names up in its own default
    config), and the ``chromaticities`` of its primaries and white point when the config
    knows them."""
    spec.attribute("oiio:ColorSpace", working.name)
    spec.attribute("colorInteropID", working.config.interop_id(working.name) or working.name)
    xy = working.config.chromaticities(working.name)
    if xy:
        spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), xy)

# }}}


__all__ = ["BUILTIN_CONFIG", "DEFAULT_WORKING_SPACE", "ColourConfig", "ColourPath",
           "WorkingSpace", "active_config", "check_colorspace", "colour_path", "encoding",
           "reset_config_cache", "resolve_colorspace", "resolve_working_space", "tag_output",
           "data_space", "tag_data"]
