"""``bdipole-cl stretch``: a mesh's stretch maps (USD or OBJ) as one EXR per UDIM tile
(``io.stretch_maps``; docs/stretch.md). Errors are one line; exit 1 when the mesh cannot give
maps, 2 for usage errors."""
from __future__ import annotations

import sys

from .cli_types import length_unit


def add_command(command):
    p = command("stretch", help="stretch maps (surface length of a texel step along u and v, "
                                "UV charts) of a USD or OBJ mesh, one EXR per UDIM tile")
    p.add_argument("mesh", help="a USD stage (.usd, .usda, .usdc, .usdz) or an OBJ file")
    p.add_argument("-o", "--output", required=True,
                   help="output EXR, with a tile token for several tiles: stretch.<UDIM>.exr")
    p.add_argument("--size", type=int, default=1024,
                   help="texels per tile side (the irradiance maps' resolution)")
    p.add_argument("--unit", default="mm", type=length_unit,
                   help="unit of the lengths written: the mfp's unit (mm, cm, m, in, ...; "
                        "default mm)")
    p.add_argument("--time", type=float, default=None,
                   help="USD time code of the points (default: the default time)")
    p.add_argument("--prim", default=None, help="USD: only the mesh at this prim path")
    p.add_argument("--meters-per-unit", type=float, default=None,
                   help="OBJ: metres per unit of its positions (default 1); USD: the stage's")
    p.set_defaults(func=cmd_stretch)


def cmd_stretch(args) -> int:
    from ..io.images import TextureError
    from ..io.mesh import MeshError
    from ..io.stretch_maps import stretch_maps
    from ..io.tiles import TileError
    from ..ops.blur.stretched import shear_words
    from ..ops.stretch import StretchError
    if args.size < 1:
        print(f"bdipole-cl stretch: error: --size {args.size}: expected >= 1", file=sys.stderr)
        return 2
    try:
        done = stretch_maps(args.mesh, args.output, size=args.size, unit=args.unit,
                            time=args.time, prim=args.prim,
                            meters_per_unit=args.meters_per_unit)
    except (MeshError, StretchError, TextureError, TileError, ValueError, OSError) as exc:
        print(f"bdipole-cl stretch: error: {exc}", file=sys.stderr)
        return 1
    for tile, path in done:
        print(f"{path}: UDIM {tile.udim}, stretch u {tile.su.min():.4g}..{tile.su.max():.4g}, "
              f"v {tile.sv.min():.4g}..{tile.sv.max():.4g} {tile.unit}/texel, max shear "
              f"{shear_words(tile.max_shear, tile.max_shear_texel)}"
              + (f", {tile.degenerate} degenerate triangle(s) left out" if tile.degenerate
                 else ""))
    return 0
