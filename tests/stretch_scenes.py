"""Scenes whose blurs take their texel lengths from meshes (tests/test_stretch_scene.py,
test_dask.py): the USD cylinder of ``stretch_meshes`` (two UDIM tiles, faceVarying seams)
bound to a PxrSurface material whose albedo is a <UDIM> texture, irradiance impulses per
tile, and a scene file that takes the stage's materials and blurs with ``stretch``."""
import numpy as np

from bdipole_cl.apps.demo import write_exr
from stretch_meshes import cylinder_stage

#: texels a tile side (the irradiance's, so the stretch maps')
SIZE = 64
#: the material's diffuse mean free path per channel, in the stage's unit (mm)
DMFP = (1.5, 0.8, 0.4)


def albedo(udim) -> np.ndarray:
    yy, xx = np.mgrid[0:SIZE, 0:SIZE] / SIZE
    k = udim - 1001
    return np.stack([0.6 + 0.2 * xx, 0.4 + 0.1 * yy, 0.3 + 0.05 * k + 0 * xx],
                    -1).astype(np.float32)


def irradiance(udim) -> np.ndarray:
    """Impulses on the cylinder's chart of the tile over a uniform 0.05 (which reaches the
    charts' borders: where the chart border rules differ)."""
    e = np.full((SIZE, SIZE, 3), 0.05, np.float32)
    e[32, 20 if udim == 1001 else 45] = 1.0
    e[20, 30 if udim == 1001 else 50] = 0.5
    return e


def bind_material(stage_path, mesh="/cyl", name="skin"):
    """A PxrSurface material /Looks/{name} (albedo tex/{name}.<UDIM>.exr, raw; dmfp DMFP,
    unitLength 1: in the stage's unit), bound to ``mesh`` (None: unbound)."""
    from pxr import Gf, Sdf, Usd, UsdShade
    stage = Usd.Stage.Open(str(stage_path))
    material = UsdShade.Material.Define(stage, f"/Looks/{name}")
    s = UsdShade.Shader.Define(stage, f"/Looks/{name}/pxr")
    s.CreateIdAttr("PxrSurface")
    for key, value in (("subsurfaceGain", 1.0), ("subsurfaceDmfp", 1.0),
                       ("subsurfaceIor", 1.4), ("unitLength", 1.0)):
        s.CreateInput(key, Sdf.ValueTypeNames.Float).Set(value)
    s.CreateInput("subsurfaceDmfpColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*DMFP))
    material.CreateSurfaceOutput("ri").ConnectToSource(s.ConnectableAPI(), "out")
    t = UsdShade.Shader.Define(stage, f"/Looks/{name}/tex")
    t.CreateIdAttr("UsdUVTexture")
    t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"tex/{name}.<UDIM>.exr")
    t.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    s.CreateInput("subsurfaceColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        t.CreateOutput("rgb", Sdf.ValueTypeNames.Color3f))
    if mesh is not None:
        UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath(mesh)).Bind(material)
    stage.GetRootLayer().Save()
    return material


def stretch_scene(root, stretch='"bound"', extra=""):
    """The cylinder stage (root/asset.usda, tiles 1001 and 1002) with /Looks/skin bound to it,
    its textures and irradiance, and root/scene.toml: the stage's materials, one blur with
    ``stretch`` (TOML text). Returns the scene file's path."""
    root.mkdir(parents=True, exist_ok=True)
    cylinder_stage(root / "asset.usda", tile2=True)
    bind_material(root / "asset.usda")
    (root / "tex").mkdir(exist_ok=True)
    (root / "light").mkdir(exist_ok=True)
    for udim in (1001, 1002):
        write_exr(root / "tex" / f"skin.{udim}.exr", albedo(udim), ("R", "G", "B"))
        write_exr(root / "light" / f"irr.{udim}.exr", irradiance(udim), ("R", "G", "B"))
    (root / "scene.toml").write_text(f'''materials_from = "asset.usda"
[defaults]
output = "out/{{material}}.<UDIM>.exr"

[[blur]]
name = "skin_tsd"
material = "skin"
irradiance = "light/irr.<UDIM>.exr"
colorspace = "raw"
stretch = {stretch}
output = "out/skin_sss.<UDIM>.exr"
{extra}''')
    return root / "scene.toml"
