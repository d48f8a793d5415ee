"""MaterialX documents (``.mtlx``) as scenes: every material node's surface shader read
through ``shaders`` (I/O; needs ``MaterialX``, the ``usd`` extra).

MaterialX's reader upgrades older documents on read, so 1.37's ``<material>`` /
``<shaderref>`` / ``<bindinput>`` arrive as 1.38+ shader nodes and ``surfacematerial``s. An
input's value is its ``value`` attribute; a connected input (``nodename``, or ``nodegraph`` +
``output``) must come from an ``image`` or ``tiledimage`` node, whose ``file`` (with
``fileprefix`` applied, ``<UDIM>`` kept, relative to the document that authored it: an
``xi:include``d one's own folder; through node graphs' interface inputs) is the texture and
whose active colour space (its ``colorspace`` attribute, else the enclosing elements', else
the document's) goes to colour management (a ``float`` image, one channel of the file, is
refused where its texels are baked, but as a distance from a one-channel file; a ``layer``
is read where it is the file's layer a bake reads, else refused: ``shaders``), or through a
``convert`` that only casts it (``vector3`` to ``color3``: a data image, as this tool's own
documents read one). Any other node is a procedural network: the material
is named as not bakeable. A distance input's ``unit`` (``unittype="distance"``) converts it to
the scene unit: metres, MaterialX's default target distance unit (``GenOptions``), which a
scene file's ``unit`` may change. A material's name is a valid USD prim and file name
(``valid_identifier``: an included document's namespace ``lib:skin`` is ``lib_skin``), unique.
"""
from __future__ import annotations

import os

import MaterialX as mx

from . import tiles
from .networks import identifier as valid_identifier
from .scene_file import SceneError
from .shaders import (TEXTURE_NODES, Input, Texture, imported_material, one_channel,
                      shader_mapping, unique_names)

#: metres per scene unit of a MaterialX document (MaterialX's default target distance unit)
DOCUMENT_UNIT_M = 1.0
#: where UsdMtlx puts a document's materials when a stage references it
USD_MATERIALS_SCOPE = "/MaterialX/Materials"


def _values(inp) -> tuple | None:
    """An input's numbers as written in the document (its value string: 1.45, not the
    float32 1.4500000477); a value that is no number (value="red") a SceneError naming the
    input, never its default in silence."""
    text = inp.getValueString()
    try:
        return tuple(float(v) for v in text.split(",")) if text else None
    except ValueError:
        raise SceneError(f"{inp.getNamePath()} = {text!r}: expected a number or a colour "
                         f"(its type is {inp.getType()})") from None


def _interface_source(inp):
    """The input that gives ``inp`` its value or connection: ``inp`` itself, or, through its
    ``interfacename``, the enclosing node graph's input (and on through theirs)."""
    seen = set()
    while inp is not None and inp.getInterfaceName() and inp.getNamePath() not in seen:
        seen.add(inp.getNamePath())
        inp = inp.getInterfaceInput()
    return inp


def _relative_file(element, path: str, base: str) -> str:
    """A relative ``path`` authored on ``element``: relative to the document that authored it
    (an ``xi:include``d one's folder, which MaterialX names relative to the root document's,
    ``base``), else, where nothing is there and the root document's folder has it, relative
    to that (MaterialX's own viewer searches every source document's folder)."""
    uri = element.getActiveSourceUri()
    own = os.path.normpath(os.path.join(base, os.path.dirname(uri), path)) if uri else None
    root = os.path.normpath(os.path.join(base, path))
    if own is None or own == root or _exists(own) or not _exists(root):
        return own or root
    return root


def _exists(path: str) -> bool:
    """Whether a file, or a tile of a tile pattern, is there (a refused token: no; the job
    says why)."""
    if os.path.exists(path) or not tiles.is_pattern(path):
        return os.path.exists(path)
    try:
        return bool(tiles.expand(path))
    except tiles.TileError:
        return False


def _texture(node, base: str) -> Texture | str:
    """The texture an image node reads: its ``file`` (through interface inputs) relative to
    the document that authored the value, or why it cannot be baked."""
    file_input = _interface_source(node.getInput("file"))
    if file_input is None or not file_input.getValueString():
        return f"{node.getCategory()} {node.getNamePath()} has no file"
    path = file_input.getResolvedValueString()
    if not os.path.isabs(path):
        path = _relative_file(file_input, path, base)
    layer = _interface_source(node.getInput("layer"))
    channel = one_channel(node.getType())
    return Texture(path, file_input.getActiveColorSpace() or "auto", node.getNamePath(),
                   channel=channel, channel_index=0 if channel else None,
                   layer=(layer.getValueString() or None) if layer is not None else None)


def read_input(shader, name: str, base: str) -> Input | None:
    """One input of the shader node (None: not authored)."""
    own = shader.getInput(name)
    if own is None:
        return None
    inp = _interface_source(own) or own          # a shader in a node graph: its interface
    unit = inp.getUnit() if inp.getUnitType() == "distance" and inp.hasUnit() else None
    node = inp.getConnectedNode()
    if node is None and (inp.getNodeName() or inp.getNodeGraphString()
                         or inp.getInterfaceName()):
        return Input(name, refused=f"{name} is connected to nothing that gives a value")
    if node is None:
        value = _values(inp)
        return None if value is None else Input(name, value=value, unit=unit)
    node = _through_cast(node)
    if node.getCategory() in TEXTURE_NODES:
        texture = _texture(node, base)
        return Input(name, refused=f"{name}: {texture}") if isinstance(texture, str) else \
            Input(name, texture=texture, unit=unit)
    return Input(name, refused=f"{name} comes from {node.getCategory()} "
                               f"({node.getNamePath()}), a procedural network")


#: the ``convert`` node's casts that keep every value (three channels as three): a data
#: image read as ``vector3`` for a ``color3`` input, as this tool writes it
VALUE_CASTS = {("vector3", "color3"), ("color3", "vector3")}


def _through_cast(node):
    """The image a ``convert`` node only casts (VALUE_CASTS), else ``node`` itself."""
    if node.getCategory() != "convert" or node.getInput("in") is None:
        return node
    source = node.getInput("in").getConnectedNode()
    if source is None or (source.getType(), node.getType()) not in VALUE_CASTS or \
            source.getCategory() not in TEXTURE_NODES:
        return node
    return source


def surface_shader(material):
    """The material node's surface shader with a subsurface mapping, else its first."""
    shaders = mx.getShaderNodes(material, "surfaceshader")
    for shader in shaders:
        if shader_mapping(shader.getCategory()) is not None:
            return shader
    return shaders[0] if shaders else None


def read_document(path):
    """[ImportedMaterial] of every material node of the document at ``path``."""
    doc = mx.createDocument()
    try:
        mx.readFromXmlFile(doc, os.path.abspath(path))
    except (mx.ExceptionFileMissing, mx.ExceptionParseError) as exc:
        raise SceneError(f"{path}: cannot read the MaterialX document: {exc}") from None
    base = os.path.dirname(os.path.abspath(path))
    out_dir = os.path.join(base, "bdipole")
    materials = doc.getMaterialNodes()
    paths = [f"{USD_MATERIALS_SCOPE}/{valid_identifier(m.getName())}" for m in materials]
    names = unique_names(paths)
    result = []
    for material, prim_path in zip(materials, paths):
        shader = surface_shader(material)
        result.append(imported_material(
            names[prim_path], prim_path, shader.getCategory() if shader else None,
            (lambda n, s=shader: read_input(s, n, base)) if shader else (lambda n: None),
            unit_m=DOCUMENT_UNIT_M, out_dir=out_dir, bound=None))
    return result
