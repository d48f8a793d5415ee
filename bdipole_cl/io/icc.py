"""ICC profiles embedded in images (I/O): enough of one read (its description, colorants and
tone curves; ICC.1:2010 sections 7 and 10) to tell whether its texels are sRGB.

OpenImageIO tags every 8-bit PNG and JPEG ``oiio:ColorSpace`` sRGB whatever profile it
embeds, and a TIFF not at all, so an Adobe RGB or Display P3 texture would be converted as if
it were sRGB, in silence. ``colour.colour_path`` asks ``is_srgb`` of a file's profile; one
that is not sRGB (or cannot be read) is named, and the file's space must be given.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

#: sRGB's colorants as ICC profiles carry them: its primaries' XYZ adapted to the D50 PCS
#: (Bradford), rows R, G, B (IEC 61966-2-1's profile; littleCMS's built-in gives the same)
SRGB_COLORANTS = ((0.4361, 0.2225, 0.0139), (0.3851, 0.7169, 0.0971),
                  (0.1431, 0.0606, 0.7141))
#: the colorants (D50 PCS, Bradford, as ICC profiles carry them) of the primaries of
#: OpenColorIO's built-in config that profiles use, keyed as its interop IDs name them
#: (``srgb_p3d65_scene``); tests/test_colour.py derives each from the config's chromaticities
COLORANTS = {
    "rec709": SRGB_COLORANTS,
    "p3d65": ((0.5151, 0.2412, -0.0011), (0.2920, 0.6922, 0.0419), (0.1571, 0.0666, 0.7841)),
    "adobergb": ((0.6097, 0.3111, 0.0195), (0.2053, 0.6257, 0.0609),
                 (0.1492, 0.0632, 0.7446)),
    "rec2020": ((0.6735, 0.2790, -0.0019), (0.1657, 0.6753, 0.0300),
                (0.1250, 0.0456, 0.7969)),
}
#: tone curves (code value -> linear) keyed as the built-in config's interop IDs name them
CURVES = {"srgb": lambda x: srgb_decode(x), "lin": lambda x: x, "g18": lambda x: x ** 1.8,
          "g22": lambda x: x ** 2.2, "g24": lambda x: x ** 2.4}
#: colorants within this of sRGB's are sRGB's: s15Fixed16 holds them to 1.5e-5, and Bradford
#: matrices of different authors differ by <= 5e-4; the nearest other spaces (P3, Adobe RGB)
#: differ by > 0.05
COLORANT_TOL = 2e-3
#: a tone curve within this of sRGB's at every code value is sRGB's: half of an 8-bit step
CURVE_TOL = 0.5 / 255


@dataclass(frozen=True)
class Profile:
    description: str
    colorants: tuple | None          # ((X, Y, Z) of R, G, B) or None (a grey profile)
    curves: tuple                    # tone curves (callables on [0, 1]) of the channels

    @property
    def is_srgb(self) -> bool:
        """sRGB's colorants (an RGB profile) and sRGB's tone curve on every channel."""
        if self.colorants is not None and not np.allclose(self.colorants, SRGB_COLORANTS,
                                                          rtol=0, atol=COLORANT_TOL):
            return False
        x = np.linspace(0.0, 1.0, 256)
        return bool(self.curves) and all(
            np.max(np.abs(curve(x) - srgb_decode(x))) <= CURVE_TOL for curve in self.curves)


def identify(profile: Profile) -> tuple | None:
    """(transfer, primaries) of a profile, as the built-in config's interop IDs name them
    (``("srgb", "p3d65")``), or None: colorants within COLORANT_TOL of a COLORANTS entry (a
    grey profile: Rec.709's), the same curve on every channel within CURVE_TOL of a CURVES
    entry."""
    if profile.colorants is None:
        primaries = "rec709"
    else:
        primaries = next((k for k, c in COLORANTS.items()
                          if np.allclose(profile.colorants, c, rtol=0, atol=COLORANT_TOL)), None)
    if primaries is None or not profile.curves:
        return None
    x = np.linspace(0.0, 1.0, 256)
    for key, ideal in CURVES.items():
        if all(np.max(np.abs(curve(x) - ideal(x))) <= CURVE_TOL for curve in profile.curves):
            return key, primaries
    return None


def srgb_decode(v):
    """IEC 61966-2-1's decoding: code value to linear."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def parse(data) -> Profile:
    """The Profile of an ICC profile's bytes; ValueError if it is not one."""
    data = bytes(np.asarray(data, np.uint8)) if not isinstance(data, bytes) else data
    if len(data) < 132 or data[36:40] != b"acsp":
        raise ValueError("not an ICC profile")
    found = tags(data)
    rgb = all(k in found for k in (b"rXYZ", b"gXYZ", b"bXYZ"))
    colorants = tuple(xyz(found[k]) for k in (b"rXYZ", b"gXYZ", b"bXYZ")) if rgb else None
    names = (b"rTRC", b"gTRC", b"bTRC") if rgb else (b"kTRC",)
    curves = tuple(curve(found[k]) for k in names if k in found)
    return Profile(text(found.get(b"desc", b"")), colorants,
                   curves if len(curves) == len(names) else ())


def tags(data: bytes) -> dict:
    """{signature: the tag's bytes} of a profile's tag table."""
    (count,) = struct.unpack_from(">I", data, 128)
    out = {}
    for i in range(min(count, (len(data) - 132) // 12)):
        sig, offset, size = struct.unpack_from(">4sII", data, 132 + 12 * i)
        if offset + size <= len(data):
            out[sig] = data[offset:offset + size]
    return out


def text(tag: bytes) -> str:
    """A 'desc' (v2: ASCII) or 'mluc' (v4: its first UTF-16BE record) tag's text."""
    try:
        if tag[:4] == b"desc":
            (n,) = struct.unpack_from(">I", tag, 8)
            return tag[12:12 + n].split(b"\0")[0].decode("latin-1")
        if tag[:4] == b"mluc":
            size, offset = struct.unpack_from(">II", tag, 20)
            return tag[offset:offset + size].decode("utf-16-be", "replace")
    except (struct.error, ValueError):
        pass
    return ""


def xyz(tag: bytes) -> tuple:
    """An 'XYZ ' tag's first value, s15Fixed16."""
    return tuple(v / 65536.0 for v in struct.unpack_from(">3i", tag, 8))


def curve(tag: bytes):
    """A 'curv' or 'para' tag as a function on [0, 1] (ValueError for another type)."""
    kind = tag[:4]
    if kind == b"curv":
        (n,) = struct.unpack_from(">I", tag, 8)
        if n == 0:
            return lambda x: np.asarray(x, np.float64)
        if n == 1:
            gamma = struct.unpack_from(">H", tag, 12)[0] / 256.0
            return lambda x: np.asarray(x, np.float64) ** gamma
        table = np.array(struct.unpack_from(f">{n}H", tag, 12), np.float64) / 65535.0
        return lambda x: np.interp(x, np.linspace(0.0, 1.0, n), table)
    if kind == b"para":
        (function,) = struct.unpack_from(">H", tag, 8)
        counts = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}
        if function not in counts:
            raise ValueError(f"parametric curve type {function}")
        p = [v / 65536.0 for v in struct.unpack_from(f">{counts[function]}i", tag, 12)]
        return lambda x: parametric(np.asarray(x, np.float64), function, p)
    raise ValueError(f"tone curve of type {kind!r}")


def parametric(x, function, p):
    """ICC's parametric curve of type ``function`` (ICC.1:2010 Table 65) with parameters p."""
    g, a, b, c, d, e, f = (p + [0.0] * 7)[:7]
    if function == 0:
        return x ** g
    if function == 1:
        return np.where(x >= -b / a, np.maximum(a * x + b, 0) ** g, 0.0)
    if function == 2:
        return np.where(x >= -b / a, np.maximum(a * x + b, 0) ** g + c, c)
    if function == 3:
        return np.where(x >= d, np.maximum(a * x + b, 0) ** g, c * x)
    return np.where(x >= d, np.maximum(a * x + b, 0) ** g + e, c * x + f)
