"""The typed job record, and the work each kind of job does.

A ``Job`` is what a runner needs and nothing it must look up elsewhere: its kind, the file it
is named by (``source``), its output, every file it reads by role (``inputs``: the collision
check and the up-to-date check read these), the work (``InvertWork``, ``BlurWork``,
``ConstantWork`` or ``StretchWork``) and the up-to-date key (a scene job's parameters
digest). Jobs and their work are plain data (paths, numbers, dataclasses), so a Dask worker
can be sent one; the runtime and the stop request are the runner's arguments, never part of
a job.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..io.colour import WorkingSpace
from ..io.mipmaps import TextureOptions
from ..methods.registry import MethodConfig
from ..ops.blur import Scattering

#: the kinds of job: an albedo texture inverted into coefficient maps, an irradiance map
#: blurred into exitance, a material with constant albedo and mfp (its coefficients), and a
#: mesh's stretch maps of one UDIM tile (a scene blur's lengths in surface distance)
JOB_KINDS = ("invert", "blur", "constant", "stretch")
#: where an inversion's mask comes from: the albedo's alpha, or a mask texture (``inputs``)
MASK_SOURCES = ("alpha", "texture")


@dataclass(frozen=True)
class InvertWork:
    """What an inversion job computes, the same for every file of a batch (the arguments of
    ``batch.process_textures``; a scene material's fields)."""

    eta: tuple
    mfp: tuple | None            # constants per channel, or None: the job's "mfp" texture
    mfp_scale: float | tuple     # one factor, or one per channel
    config: MethodConfig
    model: str
    exact: bool
    half: bool
    colorspace: str
    alpha_channel: str           # methods.registry.ALPHA_CHANNEL: keep or drop the alpha
    on_invalid: str              # errors.POLICIES
    max_memory: int
    outputs: tuple
    unit: str
    double: bool = False
    mask: str | None = None      # None or MASK_SOURCES ("texture": the job's "mask" input)
    specialise: bool = False     # a kernel with the constants compiled in (not a scene bake)
    header: dict = field(default_factory=dict)   # more bdipole:* attributes for the outputs
    working: WorkingSpace | None = None          # None: the default working space
    mfp_kind: str = "diffuse"    # methods.registry.MFP_KINDS: ld = 1/mu_tr, or 1/sigma_t'
    texture: TextureOptions | None = None        # tiled, mip-mapped outputs (images.Writer)
    layers: dict = field(default_factory=dict)   # {input role: its EXR layer read} (a scene
    #                                              material's albedo_layer, mfp_layer)


@dataclass(frozen=True)
class BlurWork:
    """What a blur job computes. The parameters are ``scattering`` (constants, or maps in
    memory), or, for a scene's blur, those of ``material`` (a ``scene_file.Material``: its
    albedo and mfp files are the job's "albedo" and "mfp" inputs, read when it runs)."""

    scattering: Scattering | None = None
    tol: float = 1e-3
    method: str = "auto"
    border: str = "clamp"
    exact: bool = False                    # a scene blur: its material's
    on_invalid: str = "raise"
    half: bool = False
    texture: TextureOptions | bool | None = False
    colorspace: str = "auto"               # the irradiance's
    working: WorkingSpace | str | None = None
    max_memory: int = 256 << 20
    header: dict = field(default_factory=dict)
    material: object = None                # scene blurs: the material whose profile blurs
    texel_size: float | None = 1.0         # scene blurs: the texel's size in the mfp's unit
    #                                        (None: the job's "stretch" maps give lengths)
    mask: str | None = None                # scene blurs: None, "alpha" or a mask texture
    charts: str = "clamp"                  # with a stretch: methods.registry.CHART_BORDER


@dataclass(frozen=True)
class ConstantWork:
    """A material without textures: its coefficients (``material`` a scene_file.Material)."""

    material: object
    config: MethodConfig


@dataclass(frozen=True)
class StretchWork:
    """One UDIM tile's stretch maps (``io.stretch_maps``) from meshes (``io.mesh_sets``): those
    the stage ``source`` binds ``material`` to (a prim path), or every mesh of the mesh file
    ``source`` (``material`` None; an OBJ's positions in ``mesh_unit``), ``size`` (H, W)
    texels, lengths in ``unit``; ``digest`` the meshes' geometry as the plan read it (the
    job fails, nothing written, where it reads other geometry)."""

    source: str
    material: str | None
    mesh_unit: str | None
    tile: tuple                    # (u, v), 0-based: UDIM 1001 + u + 10 v
    size: tuple                    # (H, W)
    unit: str                      # io.scene_keys.UNIT_METERS
    digest: str
    header: dict = field(default_factory=dict)   # more bdipole:* attributes (up-to-date key)
    prims: tuple = ()              # the meshes' prim paths as planned (for the records)
    time: float | None = None      # the USD time code's value they are read at (None: OBJ)


@dataclass(frozen=True)
class Job:
    """One unit of work (see the module docstring)."""

    kind: str                      # JOB_KINDS
    source: str                    # the albedo, irradiance, or the material's name
    output: str
    inputs: dict                   # role -> file: every file the job reads
    work: InvertWork | BlurWork | ConstantWork | StretchWork
    udim: str | None = None        # the tile's label (tiles.Tile.label), or None
    key: str = ""                  # the up-to-date key (a parameters digest; "": none)
    name: str = ""                 # a scene's material or blur the job is of ("": none)
    #: role -> ``freshness.input_identity`` of each input as of its first read (a scene's
    #: plan, the CLI's parameter reads); None: taken when the job starts
    identities: dict | None = None

    def __post_init__(self):
        if self.kind not in JOB_KINDS:
            raise ValueError(f"job kind {self.kind!r}: expected one of {JOB_KINDS}")
