"""The meshes a scene's stretch maps are made of (I/O): those a USD stage binds a material to,
or every mesh of a mesh file (USD or OBJ), read at the bake's time code, with a digest of
their geometry, which is the stretch maps' up-to-date key (docs/scenes.md "Stretch").

A mesh is bound to a material by UsdShade's *computed* binding (``ComputeBoundMaterial``,
purpose ``full``, which falls back to ``allPurpose``): a direct binding on the mesh or an
ancestor, a collection binding that includes it, the stronger of them as UsdShade resolves
them. A mesh whose ``materialBind`` GeomSubsets bind other materials contributes only the
faces bound to this one (a subset's faces take the subset's computed binding, the others the
mesh's). Meshes inside instances are read per instance (each with its own transform).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from .mesh import MeshError, geometry_digest, mesh_faces, read_obj
from .scene_keys import MESH_SUFFIXES, UNIT_METERS

#: the material purpose a bake's stretch follows: what a final render binds
PURPOSE = "full"


@dataclass(frozen=True)
class MeshSet:
    """Meshes read for stretch maps: ``source`` (stage or mesh file), ``material`` (the prim
    path whose bound meshes they are; None: every mesh of the file), ``prims`` (each mesh's
    prim path, an OBJ's file), ``faces`` (per prim, None or how many of its faces a
    GeomSubset gives), ``time`` (the USD time code's value, None for an OBJ), the source's
    ``meters_per_unit``, the ``io.mesh.UVMesh`` es and their ``digest``."""

    source: str
    material: str | None
    prims: tuple
    faces: tuple
    time: float | None
    meters_per_unit: float
    meshes: tuple
    digest: str

    def describe(self) -> str:
        """The meshes in words, for a plan (the first four named)."""
        names = [p if n is None else f"{p} ({n} faces of its GeomSubsets)"
                 for p, n in zip(self.prims, self.faces)]
        more = f" and {len(names) - 4} more" if len(names) > 4 else ""
        when = "" if self.time is None else f", {time_words(self.time)}"
        whose = f"bound to {self.material}" if self.material else "of the file"
        return (f"mesh(es) {whose}: {', '.join(names[:4])}{more}{when}, "
                f"{self.meters_per_unit:g} m a unit")


def is_earliest(value: float) -> bool:
    """Whether a time code's value is USD's EarliestTime (the lowest double: a stage without
    a time range is read at each attribute's first time sample)."""
    return value == -sys.float_info.max


def time_words(value: float) -> str:
    """A time code's value in words."""
    return "the earliest time sample" if is_earliest(value) else f"time code {value:g}"


def material_key(prim) -> str:
    """A material prim's identity: its prototype's path inside an instance (every instance
    shows the one prim), else its own."""
    return str(prim.GetPrimInPrototype().GetPath() if prim.IsInstanceProxy()
               else prim.GetPath())


def bound_prims(stage, material_path, time) -> list:
    """[(UsdGeom.Mesh prim, faces or None: all)] of the meshes ``material_path`` is bound to
    (UsdShade's computed binding, GeomSubsets included: the module docstring)."""
    from pxr import UsdGeom, UsdShade

    from .usd_scene import PRIMS
    target = stage.GetPrimAtPath(str(material_path))
    if not target or not target.IsA(UsdShade.Material):
        raise MeshError(f"{stage.GetRootLayer().realPath}: no material at {material_path}")
    key = material_key(target)

    def binds(prim) -> bool:
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(PURPOSE)
        return bool(material) and material_key(material.GetPrim()) == key
    found = []
    for prim in stage.Traverse(PRIMS):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        if not subsets:
            if binds(prim):
                found.append((prim, None))
            continue
        faces, in_subsets = set(), set()
        for subset in subsets:
            indices = {int(i) for i in (subset.GetIndicesAttr().Get(time) or [])}
            in_subsets |= indices
            if binds(subset.GetPrim()):
                faces |= indices
        count = len(UsdGeom.Mesh(prim).GetFaceVertexCountsAttr().Get(time) or [])
        if binds(prim):
            faces |= set(range(count)) - in_subsets
        if faces:
            found.append((prim, None if faces >= set(range(count)) else tuple(sorted(faces))))
    return found


def stage_set(path, material=None) -> MeshSet:
    """The MeshSet of a stage: the meshes bound to ``material`` (a prim path), or every mesh
    (None), at the bake's time code (``usd_scene.bake_time``) in world space and metres."""
    from pxr import UsdGeom

    from .mesh import usd_mesh
    from .usd_scene import PRIMS, bake_time, open_stage
    stage = open_stage(path)
    time = bake_time(stage)
    if material is not None:
        found = bound_prims(stage, material, time)
        if not found:
            raise MeshError(f"{path}: material {material} is bound to no mesh (UsdShade's "
                            f"computed binding, purpose {PURPOSE}, GeomSubsets included)")
    else:
        found = [(p, None) for p in stage.Traverse(PRIMS) if p.IsA(UsdGeom.Mesh)]
        if not found:
            raise MeshError(f"{path}: the stage has no UsdGeom.Mesh")
    meters = UsdGeom.GetStageMetersPerUnit(stage)
    meshes = tuple(mesh_faces(usd_mesh(prim, time, meters), faces) for prim, faces in found)
    return MeshSet(str(path), material, tuple(str(p.GetPath()) for p, _ in found),
                   tuple(None if f is None else len(f) for _, f in found),
                   float(time.GetValue()), float(meters), meshes, geometry_digest(meshes))


def read_mesh_set(path, material=None, mesh_unit=None) -> MeshSet:
    """The MeshSet of a stage's meshes bound to ``material`` (a prim path), or of every mesh
    of a mesh file: a USD stage, or an OBJ whose positions are in ``mesh_unit`` (a name of
    ``scene_keys.UNIT_METERS``). MeshError (one line) where there is none to read."""
    suffix = str(path).lower().rsplit(".", 1)[-1]
    if not Path(path).is_file():
        raise MeshError(f"{path}: no such mesh file")
    if f".{suffix}" not in MESH_SUFFIXES:
        raise MeshError(f"{path}: not a mesh this tool reads ({', '.join(MESH_SUFFIXES)})")
    if suffix != "obj":
        return stage_set(path, material)
    if mesh_unit not in UNIT_METERS:
        raise MeshError(f"{path}: an OBJ has no unit: give its positions' unit (mesh_unit, one "
                        f"of {', '.join(UNIT_METERS)})")
    mesh = read_obj(path, UNIT_METERS[mesh_unit])
    return MeshSet(str(path), None, (str(path),), (None,), None, UNIT_METERS[mesh_unit],
                   (mesh,), geometry_digest([mesh]))
