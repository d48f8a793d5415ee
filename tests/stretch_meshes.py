"""Meshes for the stretch tests (tests/test_stretch.py, test_stretch_blur.py): OBJ planes with
affine texture coordinates, and a USD cylinder whose two halves are UV charts of different
scale (a faceVarying seam between them at theta = 0 and pi)."""
import numpy as np

#: the cylinder's charts: theta in [0, pi) -> u in [U0[0], U1[0]], [pi, 2 pi) -> [U0[1], U1[1]]
CYL_U0, CYL_U1 = (0.05, 0.6), (0.55, 0.85)
CYL_V0, CYL_V1 = 0.1, 0.9


def write_obj(path, points, uvs, faces):
    """An OBJ of ``points`` (N, 3), ``uvs`` (M, 2) and ``faces``: lists of (v, vt), 0-based."""
    with open(path, "w") as f:
        f.writelines(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in points)
        f.writelines(f"vt {float(u)!r} {float(v)!r}\n" for u, v in uvs)
        for face in faces:
            f.write("f " + " ".join(f"{a + 1}/{b + 1}" for a, b in face) + "\n")
    return path


def affine_plane(path, jac, offset=(0.1, 0.1), extent=(0.8, 0.8), flip=False):
    """An OBJ plane whose surface point is P(u, v) = jac @ (u, v) (jac 3x2, metres per unit
    UV) over the UV rectangle [offset, offset + extent] (u mirrored with ``flip``)."""
    (u0, v0), (du, dv) = offset, extent
    uvs = np.array([[u0, v0], [u0 + du, v0], [u0 + du, v0 + dv], [u0, v0 + dv]])
    points = uvs @ np.asarray(jac, float).T
    if flip:
        uvs = uvs.copy()
        uvs[:, 0] = 2 * u0 + du - uvs[:, 0]
    return write_obj(path, points, uvs, [[(0, 0), (1, 1), (2, 2), (3, 3)]])


def cylinder_stage(path, radius=10.0, height=40.0, n=64, rows=16, meters=0.001, tile2=False):
    """A USD cylinder (stage in mm: metersPerUnit 0.001) of n facets and ``rows`` rows, its
    halves the charts CYL_U0..CYL_U1 (``tile2``: the second half in UDIM 1002), v in
    [CYL_V0, CYL_V1]: faceVarying st."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, meters)
    mesh = UsdGeom.Mesh.Define(stage, "/cyl")
    th = np.arange(n) * 2 * np.pi / n
    z = np.linspace(0, height, rows + 1)
    pts = [(radius * np.cos(t), radius * np.sin(t), zz) for zz in z for t in th]
    half = n // 2

    def u_of(k, side):                 # k = 0..half along the side's chart
        return CYL_U0[side] + (CYL_U1[side] - CYL_U0[side]) * k / half + (side if tile2 else 0)

    def v_of(j):
        return CYL_V0 + (CYL_V1 - CYL_V0) * j / rows
    counts, idx, st = [], [], []
    for j in range(rows):
        for k in range(n):
            side, kk = divmod(k, half)
            a, b = j * n + k, j * n + (k + 1) % n
            counts.append(4)
            idx += [a, b, b + n, a + n]
            st += [(u_of(kk, side), v_of(j)), (u_of(kk + 1, side), v_of(j)),
                   (u_of(kk + 1, side), v_of(j + 1)), (u_of(kk, side), v_of(j + 1))]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(idx)
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                 UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray([Gf.Vec2f(*p) for p in st]))
    stage.GetRootLayer().Save()
    return path


def cylinder_lengths(radius=10.0, height=40.0, n=64, size=256):
    """The cylinder's analytic texel lengths (mm) per chart (su, sv): the facets' chord
    length times the facets per texel (the polygon unrolled is flat)."""
    chord = 2 * radius * np.sin(np.pi / n)
    return [((n // 2) * chord / ((CYL_U1[s] - CYL_U0[s]) * size),
             height / ((CYL_V1 - CYL_V0) * size)) for s in (0, 1)]
