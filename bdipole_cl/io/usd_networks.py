"""A bake's material networks as UsdShade prims (I/O; needs ``pxr``): ``author`` writes each
``networks.Network`` under its material's prim of the bake's own layer (``bdipole.usda``) and
connects the material's surface output of the target's render context to it, so that a stage
with that layer sublayered binds its geometry to the same material, now wired to the bake.

=================  ===========================================  ==========================
target             shader prim                                  texture nodes
=================  ===========================================  ==========================
preview            ``bdipole_preview`` (UsdPreviewSurface)      UsdUVTexture + primvar
                                                                reader ``st``
pxrsurface         ``bdipole_pxrsurface`` (PxrSurface)          PxrTexture (atlasStyle 1:
                                                                UDIM)
(every bake)       ``bdipole_coefficients`` (NodeGraph)         ND_image_vector3 (data)
                                                                per output, its own file
=================  ===========================================  ==========================

Inputs are authored with the types their shader declares: USD's own Sdr definitions for the
UsdPreviewSurface nodes, MaterialX's nodedefs for ``ND_*`` ones, RenderMan's PxrSurface and
PxrTexture argument files (``RENDERMAN_TYPES``: no Sdr definition ships with usd-core).
"""
from __future__ import annotations

from pxr import Gf, Sdf, Sdr, UsdShade

from .networks import USD_SPACES, Network, TextureRead, mtlx_address, space_name

#: RenderMan's declared types of the PxrSurface and PxrTexture parameters a network uses
#: (PxrSurface.args, PxrTexture.args)
RENDERMAN_TYPES = {
    "PxrSurface": {"subsurfaceGain": "float", "subsurfaceColor": "color3f",
                   "subsurfaceDmfp": "float", "subsurfaceDmfpColor": "color3f",
                   "subsurfaceIor": "float", "unitLength": "float", "out": "token"},
    "PxrTexture": {"filename": "asset", "firstChannel": "int", "atlasStyle": "int",
                   "linearize": "int", "resultRGB": "color3f"},
}
#: MaterialX types as Sdf value types
MTLX_TYPES = {"color3": "color3f", "float": "float", "filename": "asset", "string": "string",
              "vector2": "float2", "vector3": "float3", "integer": "int", "color4": "color4f",
              "surfaceshader": "token"}
#: RenderMan's atlasStyle of a <UDIM> (Mari) texture set; 0: one file
ATLAS_UDIM = 1
#: USD's sourceColorSpace of a texture: sRGB-encoded colour, else raw (linear: the declared
#: space, in the file attribute's colorSpace, says which), auto where nothing is declared
SRGB_NAMES = ("srgb_texture", "srgb", "srgb encoded rec.709 (srgb)", "sRGB - Texture")


def sdf_type(shader_id: str, name: str):
    """The Sdf value type ``name`` (an input or output) of shader ``shader_id`` declares."""
    if shader_id in RENDERMAN_TYPES:
        return Sdf.ValueTypeNames.Find(RENDERMAN_TYPES[shader_id][name])
    if shader_id.startswith("ND_"):
        return Sdf.ValueTypeNames.Find(MTLX_TYPES[_mtlx_type(shader_id, name)])
    node = Sdr.Registry().GetShaderNodeByIdentifier(shader_id)
    prop = node.GetShaderInput(name) or node.GetShaderOutput(name)
    return prop.GetTypeAsSdfType().GetSdfType()


_LIBRARY = []


def _mtlx_type(shader_id: str, name: str) -> str:
    """A MaterialX nodedef's declared type of its input or output ``name``."""
    import MaterialX as mx
    if not _LIBRARY:
        lib = mx.createDocument()
        mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
        _LIBRARY.append(lib)
    nodedef = _LIBRARY[0].getNodeDef(shader_id)
    port = nodedef.getActiveInput(name) or nodedef.getActiveOutput(name)
    return port.getType()


def is_srgb(space: str) -> bool:
    return space.casefold() in {s.casefold() for s in SRGB_NAMES}


def _value(type_name, values):
    """A constant as the Sdf type wants it."""
    if type_name in (Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float3):
        return Gf.Vec3f(*values)
    if type_name == Sdf.ValueTypeNames.Int:
        return int(values[0])
    return float(values[0])


def _shader(stage, path, shader_id):
    shader = UsdShade.Shader.Define(stage, path)
    shader.CreateIdAttr(shader_id)
    return shader


def _input(shader, shader_id, name, value=None):
    inp = shader.CreateInput(name, sdf_type(shader_id, name))
    if value is not None:
        inp.Set(value)
    return inp


def _file_input(shader, shader_id, name, read: TextureRead):
    """The texture's file (its <UDIM> pattern) with its colour space as USD declares one."""
    inp = _input(shader, shader_id, name, Sdf.AssetPath(read.file))
    if read.colorspace != "auto":
        inp.GetAttr().SetColorSpace(space_name(read.colorspace, USD_SPACES))
    return inp


def _address_modes(shader, shader_id, read: TextureRead):
    """A MaterialX image's ``uaddressmode`` and ``vaddressmode``: the file's wrap (MaterialX's
    default, periodic, would read across a tile's edge)."""
    for axis in ("uaddressmode", "vaddressmode"):
        _input(shader, shader_id, axis, mtlx_address(read))


def _output(shader, shader_id, name):
    return shader.CreateOutput(name, sdf_type(shader_id, name))


def preview_texture(stage, base, read: TextureRead):
    """UsdUVTexture (with its st reader) of ``read``: its rgb output."""
    reader = _shader(stage, f"{base}_st", "UsdPrimvarReader_float2")
    _input(reader, "UsdPrimvarReader_float2", "varname", "st")
    tex = _shader(stage, f"{base}_{read.role}", "UsdUVTexture")
    _file_input(tex, "UsdUVTexture", "file", read)
    _input(tex, "UsdUVTexture", "sourceColorSpace",
           "raw" if read.is_data else "sRGB" if is_srgb(read.colorspace) else
           "auto" if read.colorspace == "auto" else "raw")
    _input(tex, "UsdUVTexture", "st").ConnectToSource(
        _output(reader, "UsdPrimvarReader_float2", "result"))
    return _output(tex, "UsdUVTexture", "rgb")


def pxr_texture(stage, base, read: TextureRead):
    """PxrTexture of ``read``: its resultRGB output (atlasStyle UDIM for a tile set; sRGB
    decoded by ``linearize``; ``firstChannel`` the layer's first channel)."""
    tex = _shader(stage, f"{base}_{read.role}", "PxrTexture")
    _file_input(tex, "PxrTexture", "filename", read)
    _input(tex, "PxrTexture", "atlasStyle", ATLAS_UDIM if read.tiled else 0)
    _input(tex, "PxrTexture", "linearize", int(is_srgb(read.colorspace)))
    _input(tex, "PxrTexture", "firstChannel", read.first_channel)
    return _output(tex, "PxrTexture", "resultRGB")


def mtlx_texture(stage, base, read: TextureRead):
    """MaterialX ``image`` (ND_image_color3) of ``read``: its file and colour space (raw for
    data, which MaterialX does not convert), its address modes the file's wrap; the file's
    first channels, never a ``layer`` (MaterialX's generators do not read one:
    ``mtlx_networks``)."""
    tex = _shader(stage, f"{base}_{read.role}", "ND_image_color3")
    _file_input(tex, "ND_image_color3", "file", read)
    _address_modes(tex, "ND_image_color3", read)
    return _output(tex, "ND_image_color3", "out")


#: per target: (the shader's name under the material, its surface output, the texture node)
SHADERS = {"preview": ("bdipole_preview", "surface", preview_texture),
           "pxrsurface": ("bdipole_pxrsurface", "out", pxr_texture),
           "openpbr": ("bdipole_openpbr", "out", mtlx_texture),
           "standard-surface": ("bdipole_standard_surface", "out", mtlx_texture)}


def author(stage, material_path: str, network: Network):
    """Write ``network`` under the material prim at ``material_path`` of ``stage`` (the bake's
    layer) and connect the material's surface output of the target's context to it."""
    name, out, texture = SHADERS[network.target.name]
    shader_id = network.target.shader_id
    base = f"{material_path}/{name}"
    shader = _shader(stage, base, shader_id)
    for key, value in network.inputs.items():
        inp = _input(shader, shader_id, key)
        if isinstance(value, TextureRead):
            inp.ConnectToSource(texture(stage, base, value))
        else:
            inp.Set(_value(inp.GetTypeName(), value))
    material = UsdShade.Material(stage.GetPrimAtPath(material_path))
    material.CreateSurfaceOutput(network.target.context).ConnectToSource(
        _output(shader, shader_id, out))


def author_coefficients(stage, material_path: str, reads) -> None:
    """A NodeGraph ``bdipole_coefficients`` under the material: one MaterialX image node per
    output (its own file, ``networks.layer_path``, raw colour space), each an output of the
    graph, for a shader of one's own to connect."""
    if not reads:
        return
    graph = UsdShade.NodeGraph.Define(stage, f"{material_path}/bdipole_coefficients")
    for read in reads:
        shader_id = "ND_image_vector3" if read.channels >= 3 else "ND_image_float"
        node = _shader(stage, f"{graph.GetPath()}/{read.role}", shader_id)
        _file_input(node, shader_id, "file", read)
        _address_modes(node, shader_id, read)
        graph.CreateOutput(read.role, sdf_type(shader_id, "out")).ConnectToSource(
            _output(node, shader_id, "out"))
