"""The typed records a scene file is read into (I/O): ``Material``, ``ImportedMaterial`` (a
material of a USD stage or MaterialX document, baked or left out), ``Blur`` and ``SceneData``
(``scene_file`` reads them; its names import them from there too)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .mipmaps import TextureOptions


@dataclass(frozen=True)
class Material:
    name: str
    albedo: str | tuple              # absolute pattern, or constants (imported materials)
    mfp: tuple | str                 # constants per channel, or an absolute texture pattern
    eta: tuple
    outputs: tuple
    output: str
    mask: str | None                 # None, "alpha" or an absolute texture pattern
    half: bool
    unit: str
    tol: float
    model: str                       # physics.models.MODEL's canonical name
    method: str
    exact: bool
    double: bool
    on_invalid: str
    colorspace: str                  # the albedo's: "auto" or the config's name of a space
    working_space: str | None = None  # the config's name; None: the default working space
    mfp_kind: str = "diffuse"        # methods.registry.MFP_KIND
    mfp_scale: tuple = (1.0,)        # multiplies the mfp (one or per channel)
    texture: TextureOptions | None = None    # tiled, mip-mapped EXR outputs (texture_options)
    targets: tuple = ()               # io.targets.TARGET: the material networks a bake writes
    #                                   (a stage's or document's materials: DEFAULT_TARGETS)
    albedo_layer: str | None = None   # the EXR layer of the albedo texture read (None: the
    mfp_layer: str | None = None      # channels' rule, io.channels), of the mfp texture

    @property
    def constant(self) -> bool:
        """No texture: the coefficients are numbers (no image is written)."""
        return not isinstance(self.albedo, str) and not isinstance(self.mfp, str)


@dataclass(frozen=True)
class ImportedMaterial:
    """A material as read from a USD stage or MaterialX document (``shaders``): where it is,
    which shader, the scene keys it gives (``facts``; ``suggestions`` yield to [defaults]),
    each mapped input described, and why it is left out (None: it is baked)."""

    name: str
    path: str                        # the prim path (MaterialX: UsdMtlx's path for it)
    shader: str
    mfp_kind: str | None
    facts: dict
    suggestions: dict
    inputs: dict                     # input name -> description
    unit_m: float                    # metres per scene unit
    left_out: str | None = None
    notes: tuple = ()
    bound: bool | None = None        # bound to geometry (None: the source cannot say)
    instanced: bool = False          # a prim of an instance's prototype (USD): no over of a
    #                                  layer above reaches it
    subsurface: bool = True          # it has a subsurface to bake: left out, a bake failed it
    #                                  (False: no subsurface shader, or its weight 0)


@dataclass(frozen=True)
class Blur:
    name: str
    material: Material
    irradiance: str
    texel_size: float | None         # None: the blur's lengths are ``stretch``'s
    output: str
    mask: str | None
    half: bool
    tol: float
    method: str
    border: str
    on_invalid: str
    colorspace: str                  # the irradiance's
    working_space: str | None = None  # irradiance, albedo and mfp: the material's unless given
    texture: TextureOptions | None = None
    stretch: str | None = None        # scene_keys.BOUND, or a mesh file's or stretch maps' path
    charts: str = "clamp"             # methods.registry.CHART_BORDER (with a stretch)
    mesh_unit: str | None = None      # an OBJ stretch mesh's positions' unit


@dataclass(frozen=True)
class SceneData:
    """A checked scene file: its path, materials and blurs (``bdipole_cl.jobs.scene.Scene``
    adds planning)."""

    path: Path
    materials: tuple
    blurs: tuple
    source: str | None = None        # the stage or document materials come from
    imports: tuple = ()              # ImportedMaterial, baked or left out
