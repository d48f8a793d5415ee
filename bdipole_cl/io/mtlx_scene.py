"""MaterialX documents (``.mtlx``) as scenes: every material node's surface shader read
through ``shaders`` (I/O; needs ``MaterialX``, the ``usd`` extra).

MaterialX's reader upgrades older documents on read, so 1.37's ``<material>`` /
``<shaderref>`` / ``<bindinput>`` arrive as 1.38+ shader nodes and ``surfacematerial``s. An
input's value is its ``value`` attribute; a connected input (``nodename``, or ``nodegraph`` +
``output``) must come from an ``image`` or ``tiledimage`` node, whose ``file`` (with
``fileprefix`` applied, ``<UDIM>`` kept, relative to the document) is the texture and whose
active colour space (its ``colorspace`` attribute, else the enclosing elements', else the
document's) goes to colour management (a ``float`` image, one channel of the file, is
refused where its texels are baked). Any other node is a procedural network: the material
is named as not bakeable. A distance input's ``unit`` (``unittype="distance"``) converts it to
the scene unit: metres, MaterialX's default target distance unit (``GenOptions``), which a
scene file's ``unit`` may change.
"""
from __future__ import annotations

import os

import MaterialX as mx

from .scene_file import SceneError
from .shaders import BY_ID, TEXTURE_NODES, Input, Texture, imported_material, one_channel

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


def _texture(node, base: str) -> Texture | str:
    file_input = node.getInput("file")
    if file_input is None or not file_input.getValueString():
        return f"{node.getCategory()} {node.getNamePath()} has no file"
    path = file_input.getResolvedValueString()
    if not os.path.isabs(path):
        path = os.path.normpath(os.path.join(base, path))
    return Texture(path, file_input.getActiveColorSpace() or "auto", node.getNamePath(),
                   channel=one_channel(node.getType()))


def read_input(shader, name: str, base: str) -> Input | None:
    """One input of the shader node (None: not authored)."""
    inp = shader.getInput(name)
    if inp is None:
        return None
    unit = inp.getUnit() if inp.getUnitType() == "distance" and inp.hasUnit() else None
    node = inp.getConnectedNode()
    if node is None and (inp.getNodeName() or inp.getNodeGraphString()
                         or inp.getInterfaceName()):
        return Input(name, refused=f"{name} is connected to nothing that gives a value")
    if node is None:
        value = _values(inp)
        return None if value is None else Input(name, value=value, unit=unit)
    if node.getCategory() in TEXTURE_NODES:
        texture = _texture(node, base)
        return Input(name, refused=f"{name}: {texture}") if isinstance(texture, str) else \
            Input(name, texture=texture, unit=unit)
    return Input(name, refused=f"{name} comes from {node.getCategory()} "
                               f"({node.getNamePath()}), a procedural network")


def surface_shader(material):
    """The material node's surface shader with a subsurface mapping, else its first."""
    shaders = mx.getShaderNodes(material, "surfaceshader")
    for shader in shaders:
        if shader.getCategory() in BY_ID:
            return shader
    return shaders[0] if shaders else None


def read_document(path):
    """[ImportedMaterial] of every material node of the document at ``path``."""
    doc = mx.createDocument()
    try:
        mx.readFromXmlFile(doc, str(path))
    except (mx.ExceptionFileMissing, mx.ExceptionParseError) as exc:
        raise SceneError(f"{path}: cannot read the MaterialX document: {exc}") from None
    base = os.path.dirname(os.path.abspath(path))
    out_dir = os.path.join(base, "bdipole")
    result = []
    for material in doc.getMaterialNodes():
        shader = surface_shader(material)
        name = material.getName()
        result.append(imported_material(
            name, f"{USD_MATERIALS_SCOPE}/{name}", shader.getCategory() if shader else None,
            (lambda n, s=shader: read_input(s, n, base)) if shader else (lambda n: None),
            unit_m=DOCUMENT_UNIT_M, out_dir=out_dir, bound=None))
    return result
