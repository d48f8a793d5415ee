"""Meshes with texture coordinates, read from a USD stage (usd-core's UsdGeom) or a Wavefront
OBJ file, as the triangles the stretch maps are rasterized from (``ops.stretch``).

Each mesh becomes a ``UVMesh``: triangle corners' positions (metres: a stage's points times its
metersPerUnit, an OBJ's in the unit ``meters_per_unit`` says), their texture coordinates, and
per corner a *UV vertex* id: two corners share one where they are the same point with the same
texture coordinate, so triangles that share a UV edge share its two UV vertices (what makes
them one chart, ``ops.stretch.chart_ids``). Polygons are fanned into triangles. A vertex
``st`` primvar and a faceVarying one (indexed or not) are both read; faceVarying seams become
separate UV vertices there.

usd-core has no OBJ file format plugin and OpenImageIO reads no meshes, so OBJ's ``v``, ``vt``
and ``f`` records are read here (``read_obj``), nothing else of the format.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


class MeshError(ValueError):
    """A mesh that cannot give stretch maps: one line naming the file, prim and what."""


@dataclass(frozen=True)
class UVMesh:
    """Triangles with texture coordinates (``corners`` (T, 3, 3) float64 metres, ``uv``
    (T, 3, 2) float64, ``uv_vertex`` (T, 3) int64 UV vertex ids), named ``name``, with
    ``faces`` (T,) the source face each triangle comes from (for messages)."""

    name: str
    corners: np.ndarray
    uv: np.ndarray
    uv_vertex: np.ndarray
    faces: np.ndarray
    meters_per_unit: float = 1.0     # of the source's positions (recorded with the maps)


def fan_triangles(counts, indices):
    """(T, 3) corner indices into ``indices``' positions and (T,) face numbers of polygons of
    ``counts`` vertices each, fanned from each polygon's first vertex (polygons of fewer than
    3 vertices give none)."""
    counts = np.asarray(counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    first = starts[face]
    return np.stack([first, first + k + 1, first + k + 2], axis=1), face


def uv_vertex_ids(point_ids, uv):
    """Per corner an id shared by corners of one point with one texture coordinate (bit for
    bit): the UV vertices. ``point_ids`` (T, 3), ``uv`` (T, 3, 2)."""
    keys = np.concatenate([np.asarray(point_ids, np.float64).reshape(-1, 1),
                           np.asarray(uv, np.float64).reshape(-1, 2)], axis=1)
    _, ids = np.unique(keys, axis=0, return_inverse=True)
    return ids.reshape(np.shape(point_ids))


def make_mesh(name, points, counts, indices, uv, uv_per_corner, meters):
    """A UVMesh from a polygon mesh: ``points`` (N, 3) in a unit of ``meters`` metres,
    ``counts`` and ``indices`` (face vertex counts and point indices), ``uv`` (N, 2) per point
    or (len(indices), 2) per face corner (``uv_per_corner``)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    indices = np.asarray(indices, np.int64)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    if len(indices) != int(np.sum(counts)):
        raise MeshError(f"{name}: {len(indices)} face vertex indices for face vertex counts "
                        f"summing to {int(np.sum(counts))}")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(points)):
        raise MeshError(f"{name}: a face vertex index is outside its {len(points)} points")
    expected = len(indices) if uv_per_corner else len(points)
    if len(uv) != expected:
        raise MeshError(f"{name}: {len(uv)} texture coordinates for {expected} "
                        f"{'face corners' if uv_per_corner else 'points'}")
    if not np.all(np.isfinite(uv)) or not np.all(np.isfinite(points)):
        raise MeshError(f"{name}: a point or texture coordinate is not finite")
    tri, face = fan_triangles(counts, indices)
    pid = indices[tri]
    tuv = uv[tri] if uv_per_corner else uv[pid]
    return UVMesh(name, points[pid] * float(meters), tuv, uv_vertex_ids(pid, tuv), face,
                  float(meters))


# {{{ USD

#: primvar names taken as the texture coordinates, in order (USD's convention is ``st``)
UV_PRIMVARS = ("st", "st0", "uv", "UVMap", "map1")


def usd_uv(mesh, time, name):
    """(values, per corner?) of a mesh's texture coordinates at ``time``: the first of
    UV_PRIMVARS it has, vertex/varying (per point) or faceVarying (per face corner),
    indexed primvars flattened."""
    from pxr import UsdGeom
    api = UsdGeom.PrimvarsAPI(mesh.GetPrim())
    for pv_name in UV_PRIMVARS:
        pv = api.GetPrimvar(pv_name)
        if not pv or not pv.HasValue():
            continue
        values = pv.ComputeFlattened(time)
        if values is None:
            continue
        interp = pv.GetInterpolation()
        if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
            return np.asarray(values, np.float64), False
        if interp == UsdGeom.Tokens.faceVarying:
            return np.asarray(values, np.float64), True
        raise MeshError(f"{name}: primvar {pv_name} is {interp}: texture coordinates must "
                        f"be vertex or faceVarying")
    raise MeshError(f"{name}: no texture coordinates (a primvar named one of "
                    f"{', '.join(UV_PRIMVARS)})")


def usd_mesh(prim, time=None, meters=None) -> UVMesh:
    """The UVMesh of a UsdGeom.Mesh prim at ``time`` (a time code, a ``Usd.TimeCode``; None:
    the default), in world space (its local-to-world transform at that time), in metres
    (``meters``: the stage's metersPerUnit when None)."""
    from pxr import Usd, UsdGeom
    code = (time if isinstance(time, Usd.TimeCode) else
            Usd.TimeCode.Default() if time is None else Usd.TimeCode(float(time)))
    mesh = UsdGeom.Mesh(prim)
    name = f"{prim.GetStage().GetRootLayer().identifier}:{prim.GetPath()}"
    if meters is None:
        meters = UsdGeom.GetStageMetersPerUnit(prim.GetStage())
    points = mesh.GetPointsAttr().Get(code)
    counts = mesh.GetFaceVertexCountsAttr().Get(code)
    indices = mesh.GetFaceVertexIndicesAttr().Get(code)
    if points is None or counts is None or indices is None:
        raise MeshError(f"{name}: no points or faces at time {time if time is not None else 'default'}")
    xform = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(code), np.float64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    world = pts @ xform[:3, :3] + xform[3, :3]         # USD's row vectors
    uv, per_corner = usd_uv(mesh, code, name)
    return make_mesh(name, world, np.asarray(counts), np.asarray(indices), uv, per_corner,
                     meters)


def usd_meshes(path, time=None, prim_path=None) -> list:
    """The UVMeshes of a stage's meshes (or of the one at ``prim_path``) at ``time``."""
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise MeshError(f"{path}: cannot open the stage")
    if prim_path is not None:
        prim = stage.GetPrimAtPath(str(prim_path))
        if not prim or not prim.IsA(UsdGeom.Mesh):
            raise MeshError(f"{path}: no mesh at {prim_path}")
        return [usd_mesh(prim, time)]
    prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    if not prims:
        raise MeshError(f"{path}: the stage has no UsdGeom.Mesh")
    return [usd_mesh(p, time) for p in prims]

# }}}


def mesh_faces(mesh: UVMesh, faces) -> UVMesh:
    """The triangles of ``mesh`` that come from the source faces ``faces`` (a USD GeomSubset's
    indices); ``faces`` None: the whole mesh."""
    if faces is None:
        return mesh
    keep = np.isin(mesh.faces, np.asarray(faces, np.int64))
    return UVMesh(mesh.name, mesh.corners[keep], mesh.uv[keep], mesh.uv_vertex[keep],
                  mesh.faces[keep], mesh.meters_per_unit)


def geometry_digest(meshes) -> str:
    """A digest of what stretch maps are made of: each mesh's triangle corners (metres),
    texture coordinates and source faces, bit for bit (not its name: a moved file is the same
    geometry). Equal digests, equal maps."""
    import hashlib
    h = hashlib.blake2b(digest_size=16)
    for mesh in meshes:
        for a in (mesh.corners, mesh.uv, mesh.faces):
            h.update(np.ascontiguousarray(a).tobytes())
            h.update(str(a.shape).encode())
    return h.hexdigest()

# {{{ OBJ


def obj_index(text, count, path, line):
    """A 1-based (or negative, from the end) OBJ index as 0-based."""
    i = int(text)
    if i == 0 or abs(i) > count:
        raise MeshError(f"{path}:{line}: index {i} outside the {count} defined so far")
    return i - 1 if i > 0 else count + i


def read_obj(path, meters_per_unit=1.0) -> UVMesh:
    """The UVMesh of a Wavefront OBJ file (its ``v``, ``vt`` and ``f`` records; every face
    needs texture coordinates), positions times ``meters_per_unit``."""
    points, uvs, counts, pidx, tidx = [], [], [], [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line_no, line in enumerate(f, 1):
            parts = line.split()
            if not parts:
                continue
            try:
                if parts[0] == "v":
                    points.append([float(v) for v in parts[1:4]])
                elif parts[0] == "vt":
                    uvs.append([float(v) for v in parts[1:3]])
                elif parts[0] == "f":
                    corners = [c.split("/") for c in parts[1:]]
                    if any(len(c) < 2 or not c[1] for c in corners):
                        raise MeshError(f"{path}:{line_no}: a face without texture "
                                        f"coordinates (v/vt needed)")
                    counts.append(len(corners))
                    pidx += [obj_index(c[0], len(points), path, line_no) for c in corners]
                    tidx += [obj_index(c[1], len(uvs), path, line_no) for c in corners]
            except (ValueError, IndexError) as exc:
                if isinstance(exc, MeshError):
                    raise
                raise MeshError(f"{path}:{line_no}: cannot read {parts[0]!r} record: "
                                f"{line.strip()[:60]}") from None
    if not counts:
        raise MeshError(f"{path}: no faces")
    uv = np.asarray(uvs, np.float64)[np.asarray(tidx, np.int64)]
    return make_mesh(str(path), points, counts, pidx, uv, True, meters_per_unit)

# }}}


def read_meshes(path, time=None, prim_path=None, meters_per_unit=None) -> list:
    """The UVMeshes of a USD stage (.usd, .usda, .usdc, .usdz) or an OBJ file."""
    suffix = Path(path).suffix.lower()
    if not Path(path).is_file():
        raise MeshError(f"{path}: no such file")
    if suffix == ".obj":
        return [read_obj(path, 1.0 if meters_per_unit is None else meters_per_unit)]
    if suffix in (".usd", ".usda", ".usdc", ".usdz"):
        return usd_meshes(path, time, prim_path)
    raise MeshError(f"{path}: not a mesh this tool reads (.usd, .usda, .usdc, .usdz, .obj)")
