"""What an image file declares of its colour (I/O layer), in the words of OpenColorIO's
built-in config (interop IDs such as ``srgb_p3d65_scene``), for ``colour`` to follow into the
active config. Each declaration decides the space or fails the file, named; none is ignored
(docs/colour.md):

* an embedded ICC profile, in any format and at any bit depth (``icc.identify``: primaries
  and tone curve);
* a PNG's ``sRGB``, ``gAMA`` and ``cHRM`` chunks (``iCCP`` is the ICC profile): OpenImageIO
  reads ``sRGB`` and ``gAMA`` but not ``cHRM``, so P3 primaries passed as Rec.709;
* EXIF ``ColorSpace`` (JPEG, TIFF): 1 is sRGB, 2 Adobe RGB; 65535 (uncalibrated) with no ICC
  profile says nothing usable and fails the file.

An EXR's ``colorInteropID`` and ``chromaticities`` and other formats' ``oiio:ColorSpace`` are
read by ``colour`` itself, as OpenImageIO reports them.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import OpenImageIO as oiio

from . import icc

#: OpenColorIO's built-in config (OpenImageIO's default): the vocabulary of declarations
BUILTIN_CONFIG = "ocio://default"
#: a PNG gAMA's gamma (1 / stored value) within this of a built-in space's is that space's:
#: gAMA holds 1e-5 (45455 is 2.19998)
GAMMA_TOL = 0.01
#: gamma -> the transfer part of a built-in interop ID
GAMMAS = {1.0: "lin", 1.8: "g18", 2.2: "g22", 2.4: "g24"}
#: primaries xy within this are the same (cHRM holds 1e-5; see colour.CHROMATICITY_TOL)
XY_TOL = 1e-3


class DeclarationError(ValueError):
    """A colour declaration that names no space this tool can follow (one line)."""


@dataclass(frozen=True)
class Declared:
    """One declaration: the space (a built-in config interop ID) and where the file says it."""

    space: str
    how: str


def file_kind(path) -> str:
    """"png", "jpeg", "tiff", "exr" or "" by the file's first bytes."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return ""
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if head.startswith(b"\xff\xd8"):
        return "jpeg"
    if head[:4] in (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+"):
        return "tiff"
    if head.startswith(b"v/1\x01"):
        return "exr"
    return ""


def png_chunks(path, wanted=(b"sRGB", b"gAMA", b"cHRM", b"iCCP")) -> dict:
    """{type: data} of the first of each ``wanted`` chunk before a PNG's image data."""
    found = {}
    with open(path, "rb") as f:
        f.read(8)
        while True:
            head = f.read(8)
            if len(head) < 8:
                break
            size, kind = struct.unpack(">I4s", head)
            if kind in (b"IDAT", b"IEND"):
                break
            data = f.read(size)
            f.read(4)                                   # CRC
            if kind in wanted and kind not in found:
                found[kind] = data
    return found


def _builtin():
    cfg = oiio.ColorConfig(BUILTIN_CONFIG)
    return cfg


def builtin_primaries(xy) -> str | None:
    """The built-in config's name for primaries and white ``xy`` (xR, yR, xG, yG, xB, yB,
    xW, yW): ``p3d65`` where its linear space ``lin_p3d65_scene`` has them, else None."""
    cfg = _builtin()
    for name in cfg.getColorSpaceNames():
        interop = cfg.get_color_interop_id(name) or ""
        if not (interop.startswith("lin_") and interop.endswith("_scene")):
            continue
        own = cfg.get_chromaticities(name)
        if own and max(abs(float(a) - b) for a, b in zip(own, xy)) <= XY_TOL:
            return interop[4:-6]
    return None


def _gamma_key(gamma, how) -> str:
    for g, key in GAMMAS.items():
        if abs(gamma - g) <= GAMMA_TOL:
            return key
    raise DeclarationError(f"{how} declares gamma {gamma:.4g}, which no colour space of "
                           f"OpenColorIO's built-in config has ({', '.join(map(str, GAMMAS))})")


def png_declarations(path) -> list:
    """The PNG's own declarations (sRGB, gAMA, cHRM; iCCP is read as the ICC profile): the
    transfer from sRGB (the sRGB curve) or gAMA, else the sRGB curve, PNG's default; the
    primaries from cHRM, else Rec.709. sRGB with cHRM primaries other than Rec.709's is a
    contradiction, named."""
    chunks = png_chunks(path)
    if b"iCCP" in chunks or not any(k in chunks for k in (b"sRGB", b"gAMA", b"cHRM")):
        return []                      # PNG 1.2, 4.2.2: with iCCP the others are fallbacks
    if b"sRGB" in chunks:
        transfer, said = "srgb", "sRGB chunk"
    elif b"gAMA" in chunks:
        gamma = 100000.0 / max(1, struct.unpack(">I", chunks[b"gAMA"][:4])[0])
        transfer, said = _gamma_key(gamma, "its gAMA chunk"), f"gAMA {gamma:.4g}"
    else:
        transfer, said = "srgb", "no gAMA (the sRGB curve)"
    primaries = "rec709"
    if b"cHRM" in chunks:
        w = [v / 100000.0 for v in struct.unpack(">8I", chunks[b"cHRM"][:32])]
        xy = (*w[2:8], *w[0:2])                        # cHRM: white, R, G, B
        primaries = builtin_primaries(xy)
        if primaries is None:
            raise DeclarationError(f"its cHRM chunk declares primaries "
                                   f"{', '.join(f'{v:.4f}' for v in xy)}, which no colour "
                                   f"space of OpenColorIO's built-in config has")
        said += f" and cHRM ({primaries} primaries)"
        if b"sRGB" in chunks and primaries != "rec709":
            raise DeclarationError(f"its sRGB chunk says sRGB but its cHRM chunk declares "
                                   f"{primaries} primaries")
    return [Declared(f"{transfer}_{primaries}_scene", f"PNG {said}")]


def png_icc(path) -> bytes | None:
    """A PNG's iCCP profile (name, 0, compression 0, zlib data), or None."""
    data = png_chunks(path, (b"iCCP",)).get(b"iCCP")
    if not data or b"\0" not in data[:80]:
        return None
    try:
        return zlib.decompress(data[data.index(b"\0") + 2:])
    except zlib.error:
        raise DeclarationError("its iCCP chunk cannot be read") from None


def icc_declaration(spec, path=None) -> Declared | None:
    """The space an embedded ICC profile declares (``icc.identify``), or None without one (a
    PNG's iCCP read here where OpenImageIO did not report it)."""
    data = spec.getattribute("ICCProfile")
    if (data is None or not len(data)) and path is not None and file_kind(path) == "png":
        data = png_icc(path)
    if data is None or not len(data):
        return None
    try:
        profile = icc.parse(data)
    except (ValueError, struct.error) as exc:
        raise DeclarationError(f"embeds an ICC profile that cannot be read ({exc})") from None
    found = icc.identify(profile)
    name = profile.description or "(unnamed)"
    if found is None:
        raise DeclarationError(f"embeds the ICC profile {name!r}, whose primaries and tone "
                               f"curves are no colour space of OpenColorIO's built-in config")
    transfer, primaries = found
    return Declared(f"{transfer}_{primaries}_scene", f"ICC profile {name!r}")


#: EXIF ColorSpace values (EXIF 2.3 and DCF 2.0's Adobe RGB option)
EXIF_SPACES = {1: "srgb_rec709_scene", 2: "g22_adobergb_scene"}


def exif_declaration(spec, has_icc: bool) -> Declared | None:
    value = spec.getattribute("Exif:ColorSpace")
    if value is None:
        return None
    if int(value) in EXIF_SPACES:
        return Declared(EXIF_SPACES[int(value)], f"EXIF ColorSpace {int(value)}")
    if has_icc:                                     # uncalibrated: the ICC profile says
        return None
    raise DeclarationError(f"declares EXIF ColorSpace {int(value)} (uncalibrated: often Adobe "
                           f"RGB) and embeds no ICC profile")


def declarations(spec, path) -> list:
    """Every declaration of the file's own (ICC profile, PNG chunks, EXIF), in that order;
    a DeclarationError (without the path) for one that cannot be followed."""
    out = []
    found = icc_declaration(spec, path)
    if found is not None:
        out.append(found)
    if file_kind(path) == "png":
        out += png_declarations(path)
    found = exif_declaration(spec, out and out[0].how.startswith("ICC"))
    if found is not None:
        out.append(found)
    return out
