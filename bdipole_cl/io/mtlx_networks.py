"""A bake's material networks as a MaterialX document, ``bdipole.mtlx`` beside its USD layer
(I/O; needs ``MaterialX``): the same networks as ``usd_networks`` writes, for the targets
MaterialX's standard libraries define (``Target.mtlx``: UsdPreviewSurface, OpenPBR,
Standard Surface; RenderMan's PxrSurface has no standard nodedef and stays in USD only).

Per material: a ``surfacematerial`` named as the material (its shader: the first of its
MaterialX targets that is not ``preview``, else the preview; each other target a
``surfacematerial`` ``{material}_{target}``), ``image`` nodes that name the file with
``<UDIM>`` and the colour space (``colorspace`` on a colour file; data is read through
``vector3`` / ``float`` images, which MaterialX never colour-converts), and a node graph
``{material}_coefficients`` with one output per baked coefficient. Every image reads a file's
first channels, never a ``layer``: MaterialX's GLSL generator ignores ``layer`` and its OSL
one passes it to OpenImageIO as a subimage's name, so each file an image names holds the one
thing it reads (``networks.layer_path``). Every element has a name of its own in the document
(materials first, as named; a node whose name is taken gets the next free one).
"""
from __future__ import annotations

import MaterialX as mx

from .networks import (MTLX_INPUTS, MTLX_SPACES, Network, TextureRead, identifier,
                       mtlx_address, space_name)

#: MaterialX's nodes of each target's shader
CATEGORY = {"preview": "UsdPreviewSurface", "openpbr": "open_pbr_surface",
            "standard-surface": "standard_surface"}

_LIBRARY = []


def library():
    """MaterialX's standard data libraries (loaded once)."""
    if not _LIBRARY:
        lib = mx.createDocument()
        mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
        _LIBRARY.append(lib)
    return _LIBRARY[0]


def input_type(category: str, name: str) -> str:
    """The type the node's nodedef gives its input ``name``."""
    nodedef = library().getNodeDef(f"ND_{category}_surfaceshader")
    return nodedef.getActiveInput(name).getType()


def _image(parent, name: str, read: TextureRead, type_name: str):
    """An ``image`` node reading ``read`` (a file whose first channels it reads: ValueError
    for a layer further in, which no generator reads): colour files of a colour input as
    ``color3`` with their ``colorspace``; data as ``vector3`` (or ``float``): never
    colour-converted; its address modes the file's wrap (``networks.mtlx_address``)."""
    if read.first_channel:
        raise ValueError(f"{read.file}: an image node reads a file's first channels, not "
                         f"layer {read.layer!r} from channel {read.first_channel}")
    if read.is_data and type_name == "color3":
        type_name = "vector3"
    node = parent.addNode("image", parent.createValidChildName(name), type_name)
    file = node.addInput("file", "filename")
    file.setValueString(read.file)
    if type_name.startswith("color") and read.colorspace not in ("auto", "raw"):
        file.setColorSpace(space_name(read.colorspace, MTLX_SPACES))
    for axis in ("uaddressmode", "vaddressmode"):
        node.addInput(axis, "string").setValueString(mtlx_address(read))
    return node


def _connect(inp, node, want: str):
    """Connect ``inp`` to ``node``, through a ``convert`` where a data image (vector3) feeds a
    colour input."""
    if node.getType() != want:
        parent = node.getParent()
        conv = parent.addNode("convert", parent.createValidChildName(
            f"{node.getName()}_{want}"), want)
        conv.addInput("in", node.getType()).setConnectedNode(node)
        node = conv
    inp.setConnectedNode(node)


def distance_unit(unit_m: float) -> tuple:
    """(MaterialX's name of the distance unit of ``unit_m`` metres, the factor from that unit
    to it): the standard library's ``UD_stdlib_distance`` unit of that scale (a relative
    1e-9: its scales are decimal text), else metres with the factor ``unit_m``."""
    for unit in library().getUnitDef("UD_stdlib_distance").getUnits():
        scale = float(unit.getAttribute("scale"))
        if abs(scale - unit_m) <= 1e-9 * unit_m:
            return unit.getName(), 1.0
    return "meter", unit_m


def add_network(doc, name: str, network: Network, material, unit_m: float):
    """The target's shader node for one material, connected to its ``material`` node; its
    distances are in ``unit_m`` metres, which the distance input states (``unittype``
    "distance", ``unit``): MaterialX converts it into a renderer's unit, and a document
    without one is read in its default, metres."""
    category = CATEGORY[network.target.name]
    distance = MTLX_INPUTS.get(network.target.name, (None,) * 3)[2]
    shader = doc.addNode(category, doc.createValidChildName(
        f"{name}_{network.target.name.replace('-', '_')}"), "surfaceshader")
    for key, value in network.inputs.items():
        type_name = input_type(category, key)
        inp = shader.addInput(key, type_name)
        if isinstance(value, TextureRead):
            _connect(inp, _image(doc, f"{shader.getName()}_{value.role}", value, type_name),
                     type_name)
        elif type_name == "color3":
            inp.setValue(mx.Color3(*value))
        elif type_name == "integer":
            inp.setValue(int(value[0]))
        elif key == distance:
            unit, factor = distance_unit(unit_m)
            inp.setValue(float(value[0]) * factor)
            inp.setUnitType("distance")
            inp.setUnit(unit)
        else:
            inp.setValue(float(value[0]))
    material.addInput("surfaceshader", "surfaceshader").setConnectedNode(shader)


def add_coefficients(doc, name: str, reads):
    """``{name}_coefficients``: one output per baked coefficient, each an image of its layer."""
    if not reads:
        return
    graph = doc.addNodeGraph(doc.createValidChildName(f"{name}_coefficients"))
    for read in reads:
        type_name = "vector3" if read.channels >= 3 else "float"
        node = _image(graph, f"{read.role}_image", read, type_name)
        graph.addOutput(read.role, type_name).setConnectedNode(node)


def document_text(materials, comment: str) -> str:
    """The document of ``materials`` ([(name, [Network], [coefficient TextureRead], metres
    per unit of its distances)]): each MaterialX target's material and the coefficients
    graph; ``comment`` its first line."""
    doc = mx.createDocument()
    doc.addChildOfCategory("comment").setDocString(comment)
    # the materials' names first: each its material's own, before any node could take it
    chosen = []                     # per material: (ident, [(network, is its main)])
    units = {}
    for name, networks, _, unit_m in materials:
        mtlx = [n for n in networks if n.target.mtlx]
        main = next((i for i, n in enumerate(mtlx) if n.target.name != "preview"), 0)
        chosen.append((identifier(name), [(n, i == main) for i, n in enumerate(mtlx)]))
        units[identifier(name)] = unit_m
    wired = [(ident, n, doc.addMaterialNode(doc.createValidChildName(ident)))
             for ident, nets in chosen for n, main in nets if main]
    wired += [(ident, n, doc.addMaterialNode(doc.createValidChildName(
        f"{ident}_{n.target.name.replace('-', '_')}")))
        for ident, nets in chosen for n, main in nets if not main]
    for ident, network, material in wired:
        add_network(doc, ident, network, material, units[ident])
    for name, _, reads, _ in materials:
        add_coefficients(doc, identifier(name), reads)
    return mx.writeToXmlString(doc)
