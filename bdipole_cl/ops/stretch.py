"""Stretch maps: per texel, the surface length of one texel step along u and along v (d'Eon,
Luebke and Enderton 2007's stretch map; docs/stretch.md "Stretch maps"), rasterized from a
mesh's UV triangles per UDIM tile with each triangle's exact Jacobian, and the UV charts the
chart-aware blur keeps apart.

On a triangle the surface point P(u, v) is affine in (u, v), so its Jacobian
``[dP/du dP/dv] = [p1 - p0, p2 - p0] [uv1 - uv0, uv2 - uv0]^-1`` is exact and constant there:
a texel step along u (1/W of a tile) is ``|dP/du| / W`` long on the surface, along v
``|dP/dv| / H``. The shear (the cosine of the angle between dP/du and dP/dv) is what an
axis-aligned stretch cannot say; it is kept per texel for the bound (docs/stretch.md "Shear").

Texels are the tile's: row 0 at the top (v = tile's v + 1), texel centres at half-integers. A
texel whose centre lies in a triangle takes its values (``covered``); every other texel (the
gutters) takes those of its nearest covered texel (Euclidean, ``scipy.ndimage``), so that a
lookup near a chart border reads defined values.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..signals import check_stop

#: a triangle whose UV area (in texels^2) is below this, or whose surface area is below this
#: fraction of its edges' squared length, has no Jacobian: it is left out (counted), and its
#: texels are filled from their neighbours as gutters are
DEGENERATE_UV_AREA = 1e-9
DEGENERATE_SURFACE = 1e-12
#: candidate texels per rasterization chunk (memory: ~100 bytes each)
CHUNK_TEXELS = 1 << 22
#: where two meshes cover one texel, the largest relative difference of their lengths that is
#: still one surface: an instance placed rigidly gives the same lengths up to the rounding of
#: float32 points through a float64 transform (~1e-7); a mesh scaled otherwise differs by far
#: more than this
AGREE = 1e-4


#: |cos| of a texel's shear at or below this is rounding, not a shear (the Jacobian of a
#: plane's triangles from float32 positions is good to ~1e-7): no texel is named for it
SHEAR_ROUNDING = 1e-6


class StretchError(ValueError):
    """Texture coordinates a stretch map cannot hold: one line naming the mesh and face."""


@dataclass(frozen=True)
class StretchTile:
    """One UDIM tile's stretch maps (H x W float32, the unit's lengths per texel step), its
    chart ids (int32, per texel: the covering or, in gutters, the nearest triangle's chart),
    which texels a triangle covers, and its shear (cosine of the angle between the surface's
    u and v directions, float32)."""

    tile: tuple                  # (u, v), 0-based; UDIM 1001 + u + 10 v
    su: np.ndarray
    sv: np.ndarray
    chart: np.ndarray
    covered: np.ndarray
    shear: np.ndarray
    unit: str = "mm"
    degenerate: int = 0          # triangles left out (no Jacobian)
    flipped: int = 0             # triangles whose UV orientation is reversed (used as they are)

    @property
    def udim(self) -> int:
        return 1001 + self.tile[0] + 10 * self.tile[1]

    @property
    def max_shear(self) -> float:
        """The largest |shear| over the covered texels (0 where none is covered)."""
        vals = np.abs(self.shear[self.covered])
        return float(vals.max()) if vals.size else 0.0

    @property
    def max_shear_texel(self):
        """(x, y) of the covered texel of the largest |shear| (the first in row order), or
        None where no covered texel is sheared beyond SHEAR_ROUNDING: where the layout's
        shear, and the blur's bound with it, is worst (docs/stretch.md "Shear")."""
        vals = np.where(self.covered, np.abs(self.shear), 0.0)
        if not vals.size or vals.max() <= SHEAR_ROUNDING:
            return None
        y, x = np.unravel_index(int(np.argmax(vals)), vals.shape)
        return int(x), int(y)


@dataclass(frozen=True)
class TriangleFrames:
    """Per triangle: texel lengths along u and v (metres per unit UV / per tile side), shear,
    chart id, and whether it is usable (``ok``) and flipped."""

    du: np.ndarray               # |dP/du| (metres per unit u)
    dv: np.ndarray               # |dP/dv|
    shear: np.ndarray
    chart: np.ndarray
    ok: np.ndarray
    flipped: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


def jacobians(corners, uv):
    """(dP/du, dP/dv) (T, 3) each and the UV determinant (T,) of triangles with corners
    ``corners`` (T, 3, 3) and texture coordinates ``uv`` (T, 3, 2): exact on each triangle."""
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    a, b = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        # [e1 e2] = [Pu Pv] [[a0 b0], [a1 b1]]  ->  [Pu Pv] = [e1 e2] [[b1 -b0], [-a1 a0]] / det
        pu = (e1 * b[:, 1:2] - e2 * a[:, 1:2]) * inv[:, None]
        pv = (e2 * a[:, 0:1] - e1 * b[:, 0:1]) * inv[:, None]
    return pu, pv, det


def chart_ids(uv_vertex):
    """Per triangle the id (0..n-1) of its chart: triangles joined by shared UV vertices
    (``io.mesh.uv_vertex_ids``), connected components."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    t = len(uv_vertex)
    if t == 0:
        return np.zeros(0, np.int64)
    n = int(uv_vertex.max()) + 1
    rows = np.repeat(np.arange(t), 3)
    graph = coo_matrix((np.ones(3 * t), (rows, uv_vertex.ravel() + t)), shape=(t + n, t + n))
    _, labels = connected_components(graph, directed=False)
    _, chart = np.unique(labels[:t], return_inverse=True)
    return chart


def triangle_frames(mesh, chart_offset=0) -> TriangleFrames:
    """The TriangleFrames of a ``io.mesh.UVMesh`` (chart ids from ``chart_offset`` on)."""
    pu, pv, det = jacobians(mesh.corners, mesh.uv)
    lu, lv = np.linalg.norm(pu, axis=1), np.linalg.norm(pv, axis=1)
    cross = np.linalg.norm(np.cross(mesh.corners[:, 1] - mesh.corners[:, 0],
                                    mesh.corners[:, 2] - mesh.corners[:, 0]), axis=1)
    edges = max(float(np.max(np.abs(mesh.corners))) if mesh.corners.size else 1.0, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        shear = np.einsum("ij,ij->i", pu, pv) / (lu * lv)
    ok = (np.abs(det) > 0) & np.isfinite(lu) & np.isfinite(lv) & (lu > 0) & (lv > 0) \
        & (cross > DEGENERATE_SURFACE * edges ** 2)
    chart = chart_ids(mesh.uv_vertex) + chart_offset
    return TriangleFrames(lu, lv, np.where(ok, shear, 0.0), chart, ok, det < 0)


def check_tiles(mesh):
    """StretchError naming the first triangle with a texture coordinate in no UDIM tile (u
    outside [0, 10), v < 0)."""
    u, v = mesh.uv[..., 0], mesh.uv[..., 1]
    bad = (u < 0) | (u >= 10) | (v < 0)
    if bad.any():
        t, k = np.unravel_index(int(np.flatnonzero(bad)[0]), bad.shape)
        raise StretchError(f"{mesh.name}: face {int(mesh.faces[t])}: texture coordinate "
                           f"({u[t, k]:.6g}, {v[t, k]:.6g}) is in no UDIM tile (u in [0, 10), "
                           f"v >= 0); {int(bad.any(axis=1).sum())} triangle(s) so")


def mesh_tiles(mesh) -> set:
    """The UDIM tiles (u, v) the mesh's triangles reach (each triangle's UV bounding box)."""
    lo = np.floor(mesh.uv.min(axis=1)).astype(np.int64)
    hi = np.floor(np.nextafter(mesh.uv.max(axis=1), -np.inf)).astype(np.int64)
    hi = np.maximum(hi, lo)
    tiles = set()
    for (u0, v0), (u1, v1) in zip(lo, hi):
        tiles.update((a, b) for a in range(u0, u1 + 1) for b in range(v0, v1 + 1))
    return tiles


def rasterize_tile(meshes, frames, tile, size, metres_per_unit_length):
    """(su, sv, shear, chart, covered, filled) maps of ``tile`` (u, v) at ``size`` (H, W) from
    every mesh's triangles (``frames``: their TriangleFrames), lengths in a unit of
    ``metres_per_unit_length`` metres; ``filled`` says which texels a triangle covered before
    dilation."""
    h, w = size
    su = np.zeros((h, w), np.float64)
    sv = np.zeros((h, w), np.float64)
    shear = np.zeros((h, w), np.float64)
    chart = np.full((h, w), -1, np.int64)
    for mesh, fr in zip(meshes, frames):
        # texel coordinates: x = (u - tu) W, y = (tv + 1 - v) H (row 0 at the top)
        x = (mesh.uv[..., 0] - tile[0]) * w
        y = (tile[1] + 1 - mesh.uv[..., 1]) * h
        x0 = np.maximum(np.ceil(x.min(axis=1) - 0.5), 0).astype(np.int64)
        x1 = np.minimum(np.floor(x.max(axis=1) - 0.5), w - 1).astype(np.int64)
        y0 = np.maximum(np.ceil(y.min(axis=1) - 0.5), 0).astype(np.int64)
        y1 = np.minimum(np.floor(y.max(axis=1) - 0.5), h - 1).astype(np.int64)
        live = np.flatnonzero(fr.ok & (x1 >= x0) & (y1 >= y0))
        bw = (x1 - x0 + 1)[live]
        count = bw * (y1 - y0 + 1)[live]
        values = (fr.du / (w * metres_per_unit_length), fr.dv / (h * metres_per_unit_length),
                  fr.shear, fr.chart)
        for part in np.array_split(live, max(1, int(count.sum() // CHUNK_TEXELS) + 1)):
            check_stop()
            if part.size == 0:
                continue
            covered_texels(x[part], y[part], x0[part], y0[part], (x1 - x0 + 1)[part],
                           (y1 - y0 + 1)[part], part, values, (su, sv, shear, chart))
    covered = chart >= 0
    return su, sv, shear, chart, covered


def covered_texels(x, y, x0, y0, bw, bh, tri, values, maps):
    """Write ``values`` (per triangle) of triangles ``tri`` (texel-space corners x, y (n, 3),
    bounding boxes from (x0, y0), bw x bh texels) into ``maps`` at the texels whose centres
    lie inside them (edge functions of one sign, either orientation)."""
    n = bw * bh
    which = np.repeat(np.arange(len(tri)), n)
    k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
    px = x0[which] + k % bw[which] + 0.5
    py = y0[which] + k // bw[which] + 0.5
    xs, ys = x[which], y[which]
    e = [(xs[:, (i + 1) % 3] - xs[:, i]) * (py - ys[:, i])
         - (ys[:, (i + 1) % 3] - ys[:, i]) * (px - xs[:, i]) for i in range(3)]
    inside = ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0)
                                                          & (e[2] <= 0))
    iy = (py[inside] - 0.5).astype(np.int64)
    ix = (px[inside] - 0.5).astype(np.int64)
    t = tri[which[inside]]
    for m, v in zip(maps, values):
        m[iy, ix] = v[t]


def dilated(maps, covered):
    """Each map with every uncovered texel given its nearest covered texel's value."""
    from scipy.ndimage import distance_transform_edt
    if covered.all():
        return maps
    iy, ix = distance_transform_edt(~covered, return_distances=False, return_indices=True)
    return [m[iy, ix] for m in maps]


def union_tile(meshes, frames, tile, size, metres_per_unit_length):
    """``rasterize_tile`` of each mesh on its own, merged: where two meshes cover one texel
    their lengths must agree within AGREE (the same surface, as instances of one mesh are),
    else a StretchError naming both meshes, the tile and the texel (one stretch map cannot
    hold two surfaces' lengths at one texel). The first mesh's chart keeps a texel."""
    merged, covered, owner = None, None, None
    for i, (mesh, fr) in enumerate(zip(meshes, frames)):
        maps = rasterize_tile([mesh], [fr], tile, size, metres_per_unit_length)
        mine = maps[4]
        if merged is None:
            merged, covered = list(maps[:4]), mine.copy()
            owner = np.where(mine, i, -1)
            continue
        both = mine & covered
        if both.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                diff = np.maximum(np.abs(maps[0] - merged[0]) / merged[0],
                                  np.abs(maps[1] - merged[1]) / merged[1])
            bad = both & ~(diff <= AGREE)
            if bad.any():
                y, x = np.unravel_index(int(np.flatnonzero(bad)[0]), bad.shape)
                udim = 1001 + tile[0] + 10 * tile[1]
                raise StretchError(
                    f"{meshes[owner[y, x]].name} and {mesh.name}: both cover texel x={x}, "
                    f"y={y} of UDIM {udim} with different lengths ({merged[0][y, x]:.6g}, "
                    f"{merged[1][y, x]:.6g} against {maps[0][y, x]:.6g}, {maps[1][y, x]:.6g}"
                    f"; {int(bad.sum())} texel(s) so): one stretch map cannot hold both; "
                    f"give them UVs of their own, or take one mesh")
        new = mine & ~covered
        for dst, src in zip(merged, maps[:4]):
            dst[new] = src[new]
        # two surfaces at one texel (lengths agreeing): the larger |shear| is the bound's
        more = both & (np.abs(maps[2]) > np.abs(merged[2]))
        merged[2][more] = maps[2][more]
        owner[new] = i
        covered |= mine
    return (*merged, covered)


def stretch_tiles(meshes, size=(1024, 1024), unit_metres=1e-3, unit="mm", tiles=None) -> list:
    """The StretchTile of every UDIM tile the meshes' triangles cover (or of those of them in
    ``tiles``, (u, v) pairs), at ``size`` (H, W) texels a tile, lengths in ``unit``
    (``unit_metres`` metres). The meshes share the tiles: where two cover one texel they must
    agree (``union_tile``). A texture coordinate in no tile is a StretchError
    (``check_tiles``); degenerate triangles are left out and counted."""
    h, w = (int(size), int(size)) if np.ndim(size) == 0 else (int(size[0]), int(size[1]))
    if h < 1 or w < 1:
        raise ValueError(f"size {size!r}: expected a positive tile size in texels")
    frames, offset, found = [], 0, set()
    for mesh in meshes:
        check_tiles(mesh)
        fr = triangle_frames(mesh, offset)
        offset = int(fr.chart.max()) + 1 if len(fr.chart) else offset
        frames.append(fr)
        found |= mesh_tiles(mesh)
    if tiles is not None:
        found &= {tuple(t) for t in tiles}
    degenerate = sum(int((~fr.ok).sum()) for fr in frames)
    flipped = sum(int((fr.flipped & fr.ok).sum()) for fr in frames)
    out = []
    for tile in sorted(found, key=lambda t: (t[1], t[0])):
        su, sv, shear, chart, covered = union_tile(meshes, frames, tile, (h, w), unit_metres)
        if not covered.any():
            continue
        su, sv, shear, chart = dilated([su, sv, shear, chart], covered)
        out.append(StretchTile(tile, su.astype(np.float32), sv.astype(np.float32),
                               chart.astype(np.int32), covered, shear.astype(np.float32),
                               unit, degenerate, flipped))
    if not out:
        where = "" if tiles is None else (" of UDIM " + ", ".join(
            str(1001 + u + 10 * v) for u, v in sorted(tiles, key=lambda t: (t[1], t[0]))))
        raise StretchError(f"{', '.join(m.name for m in meshes)}: no triangle covers a texel "
                           f"centre{where} at {w}x{h} texels a tile")
    return out
