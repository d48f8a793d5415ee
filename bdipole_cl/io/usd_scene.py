"""USD stages (``.usda``, ``.usd``, ``.usdc``, ``.usdz``) as scenes: every UsdShade Material's
surface shader read through ``shaders`` (I/O; needs ``pxr``, the ``usd`` extra).

A material's surface is looked for in the ``mtlx``, ``ri``, ``arnold`` and universal render
contexts, in that order, then any other; the first shader with a subsurface mapping is used. An input's value comes from
``UsdShadeInput.GetValueProducingAttributes`` (so through node graphs and interface inputs):
an authored value, or the output of a texture node (``UsdUVTexture``, MaterialX ``image`` /
``tiledimage``, RenderMan ``PxrTexture``, Arnold ``image``) whose ``inputs:file`` (the
latter two: ``inputs:filename``; a PxrTexture's ``_MAPID_`` the tile token of its
``atlasStyle``) is the texture (``<UDIM>`` kept; one packaged in a
``.usdz`` read from its copy in the cache, ``usdz``; a UsdUVTexture's
output channel and ``inputs:scale`` / ``inputs:bias`` kept: ``shaders`` applies or refuses
them; the file, ``sourceColorSpace``, ``scale`` and ``bias`` may come through interface
inputs too). Its colour space is the file attribute's ``colorSpace`` metadata, else the one a
``ColorSpaceAPI`` on its prim or an ancestor declares, else ``inputs:sourceColorSpace``
(``raw`` is linear, ``sRGB``; ``auto`` leaves it to the file), a PxrTexture's
``linearize`` (1: sRGB, else raw) or an Arnold image's ``color_space``. Values are read at the stage's
start time code (``bake_time``; without a time range, an input's first time sample or
spline knot): an
animated input is baked at that time and noted, never replaced by its shader's default. Any
other node feeding an input is a procedural network: the material is named as not bakeable.
Distances are in the stage's unit (``metersPerUnit``). A stage using a ``.mtlx`` document
as a layer needs USD's MaterialX plugin, which the usd-core wheel lacks: refused, saying so.
"""
from __future__ import annotations

import math
import os
import re
import sys
import tempfile
import zipfile
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from ..errors import one_line
from . import usdz
from .scene_file import SceneError
from .shaders import (TEXTURE_NODES, Input, Texture, imported_material, layer_at,
                      one_channel, shader_mapping, unique_names)

#: render contexts searched for a material's surface, in order (then any other one)
CONTEXTS = ("mtlx", "ri", "arnold", "")


def shader_id_of(shader) -> str:
    """A shader's identifier: its ``info:id``, else, for one implemented by a source asset
    (``info:implementationSource = "sourceAsset"``, as a MaterialX library's node), the
    asset's sub-identifier (``info:mtlx:sourceAsset:subIdentifier``: the nodedef's name);
    "" if neither."""
    found = shader.GetShaderId()
    if found:
        return found
    for source_type in shader.GetSourceTypes():
        sub = shader.GetSourceAssetSubIdentifier(source_type)
        if sub:
            return sub
    return ""


def _node_kind(shader_id: str) -> str:
    """'UsdUVTexture', 'image', 'tiledimage', 'PxrTexture' or 'arnold:image' for texture
    nodes (MaterialX ids are ND_<node>_<type>), else the id."""
    if shader_id and shader_id.startswith("ND_"):
        for kind in ("tiledimage", "image"):
            if shader_id.startswith(f"ND_{kind}_"):
                return kind
    return shader_id


#: each texture node's file input; the channel (0 R ... 3 A) its one-channel outputs read
FILE_INPUT = {"PxrTexture": "filename", "arnold:image": "filename"}
CHANNEL_OUTPUTS = {"r": 0, "g": 1, "b": 2, "a": 3, "resultR": 0, "resultG": 1, "resultB": 2,
                   "resultA": 3}
#: a PxrTexture's atlasStyle: the tile token its ``_MAPID_`` stands for (docs: RenderMan)
PXR_ATLAS = {1: "<UDIM>", 2: "<UVTILE>", 3: "<UVTILE0>"}
#: Arnold image ``color_space`` names that are not OCIO's ("linear": linear Rec.709)
ARNOLD_SPACES = {"": "auto", "auto": "auto", "linear": "lin_rec709", "Raw": "raw",
                 "raw": "raw"}


def _decimal(v) -> float:
    """A float32 value (USD's float, color3f) as the decimal it was authored as: 1.4f is
    1.4, not 1.399999976; other values as they are."""
    v = float(v)
    return float(str(np.float32(v))) if float(np.float32(v)) == v else v


def _values(value, where="") -> tuple:
    """An authored number or vector as floats; anything else (a string, a token, a bool) a
    SceneError naming ``where`` (the attribute) and the value."""
    if isinstance(value, (str, bytes, bool)):
        raise SceneError(f"{where} = {value!r}: expected a number or a colour "
                         f"(a {type(value).__name__} is neither)")
    try:
        return tuple(_decimal(v) for v in (value if np.iterable(value) else (value,)))
    except (TypeError, ValueError):
        raise SceneError(f"{where} = {value!r}: expected a number or a colour") from None


def bake_time(stage) -> Usd.TimeCode:
    """The time a bake reads inputs at: the stage's start time code where it has a time range,
    else each attribute's earliest time sample (USD's ``EarliestTime``). A value that is not
    animated is the same at any time; an animated one is noted (``Input.animated``), never
    replaced by its shader's default."""
    return (Usd.TimeCode(stage.GetStartTimeCode()) if stage.HasAuthoredTimeCodeRange()
            else Usd.TimeCode.EarliestTime())


def _animated(attr, time) -> str | None:
    """Where an attribute's value is animated (time samples or a spline), the time it is read
    at, in words; else None. Without a time range that is its first sample or knot."""
    if not attr.ValueMightBeTimeVarying() and attr.GetNumTimeSamples() == 0:
        return None
    if not time.IsEarliestTime():
        return f"time code {time.GetValue():g}"
    times = list(attr.GetTimeSamples())
    if not times and getattr(attr, "HasSpline", None) and attr.HasSpline():   # USD 25.05+
        times = sorted(attr.GetSpline().GetKnots().keys())
    return f"time code {times[0]:g}" if times else "its earliest time"


def _value_attr(shader, name):
    """The attribute that gives input ``name`` of ``shader`` its value: its own, or the
    interface input it is connected to (``GetValueProducingAttributes``); None if neither
    gives one."""
    inp = shader.GetInput(name)
    if not inp:
        return None
    return next((a for a in inp.GetValueProducingAttributes() if UsdShade.Input.IsInput(a)),
                None)


def _asset_file(attr, time) -> str:
    """The absolute path (or <UDIM> pattern) of an asset-valued attribute at ``time``,
    relative to the layer that authored it."""
    asset = attr.Get(time)
    if asset is None:
        return ""
    if not isinstance(asset, Sdf.AssetPath):
        raise SceneError(f"{attr.GetPath()} = {asset!r}: a texture file is an asset path "
                         f"(asset inputs:file = @path@), not a {type(asset).__name__}")
    if asset.resolvedPath:
        return asset.resolvedPath
    path = asset.path
    for spec in attr.GetPropertyStack(time):
        if spec.HasDefaultValue() or spec.HasInfo("timeSamples"):
            layer_path = spec.layer.realPath
            if layer_path and not os.path.isabs(path) and usdz.in_package(layer_path):
                return usdz.anchored(layer_path, path)
            if layer_path and not os.path.isabs(path):
                return os.path.normpath(os.path.join(os.path.dirname(layer_path), path))
            break
    return path


def _scale_bias(shader, time, keys=("scale", "bias")) -> tuple:
    """A UsdUVTexture's per-channel (scale, bias) of its rgb (None: the default 1 or 0); an
    Arnold image's are ``multiply`` and ``offset``."""
    found = []
    for key, default in zip(keys, (1, 0)):
        attr = _value_attr(shader, key)
        raw = attr.Get(time) if attr else None
        value = _values(raw, str(attr.GetPath())) if raw is not None else None
        found.append(None if value is None or all(v == default for v in value[:3])
                     else value[:3])
    return tuple(found)


#: USD colour space names that are no OCIO space's: Gf's ``identity`` is no conversion
USD_SPACES = {"identity": "raw"}


def _declared_space(attr) -> str:
    """The colour space USD declares for an attribute's texture: its own ``colorSpace``, else
    the one a ``ColorSpaceAPI`` on its prim or an ancestor gives (inherited); "" if none
    (``USD_SPACES`` as their OCIO names)."""
    name = _declared_name(attr)
    return USD_SPACES.get(name, name)


def _declared_name(attr) -> str:
    if attr.HasColorSpace():
        return attr.GetColorSpace()
    api = getattr(Usd, "ColorSpaceAPI", None)          # USD 25.05 and later
    prim = attr.GetPrim()
    while api is not None and prim and not prim.IsPseudoRoot():
        if prim.HasAPI(api):
            return api.ComputeColorSpaceName(attr, Usd.ColorSpaceHashCache())
        prim = prim.GetParent()
    return ""


def _token(shader, name, time, default):
    """A texture node's setting ``name`` at ``time`` (through interface inputs), else
    ``default``."""
    attr = _value_attr(shader, name)
    value = attr.Get(time) if attr else None
    return default if value is None else value


def _space(shader, node_kind, attr, time) -> str:
    """The colour space of a texture node's file: as USD declares it (``_declared_space``),
    else the node's own setting: UsdUVTexture ``sourceColorSpace``, PxrTexture
    ``linearize`` (1: sRGB; 0: the texels as they are), Arnold ``color_space``."""
    space = _declared_space(attr)
    if space:
        return space
    if node_kind == "PxrTexture":
        return "sRGB" if _token(shader, "linearize", time, 0) else "raw"
    if node_kind == "arnold:image":
        name = str(_token(shader, "color_space", time, "auto"))
        return ARNOLD_SPACES.get(name, name)
    token = str(_token(shader, "sourceColorSpace", time, "auto"))
    return {"raw": "raw", "sRGB": "sRGB"}.get(token, "auto")


def _atlas_file(shader, path, time) -> str:
    """A PxrTexture's file with its ``_MAPID_`` as the tile token of its ``atlasStyle``."""
    style = int(_token(shader, "atlasStyle", time, 0))
    return path.replace("_MAPID_", PXR_ATLAS[style]) if style in PXR_ATLAS else path


def _texture(shader, node_kind: str, output: str = "rgb",
             time=Usd.TimeCode.EarliestTime()) -> Texture | str:
    """The texture a texture node reads (through its ``output``) at ``time``, or why it
    cannot be baked. Its file and settings may come through interface inputs."""
    attr = _value_attr(shader, FILE_INPUT.get(node_kind, "file"))
    if attr is None or attr.Get(time) is None:
        return f"{node_kind} {shader.GetPath()} has no file"
    path = _asset_file(attr, time)
    if node_kind == "PxrTexture":
        path = _atlas_file(shader, path, time)
    if node_kind == "arnold:image":                 # Arnold's tile token is lower case
        path = path.replace("<udim>", "<UDIM>")
    if usdz.is_packaged(path):         # read from its copy in the cache
        try:
            path = usdz.extracted(path)
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            return f"{node_kind} {shader.GetPath()}: {one_line(exc)}"
    space = _space(shader, node_kind, attr, time)
    where = str(shader.GetPath())
    if node_kind in ("image", "tiledimage"):        # ND_image_<type>
        channel = one_channel(shader_id_of(shader).split("_")[2])
        layer = str(_token(shader, "layer", time, "")) or None
        return Texture(path, space, where, channel=channel,
                       channel_index=0 if channel else None, layer=layer)
    scale, bias = _scale_bias(shader, time, ("multiply", "offset")
                              if node_kind == "arnold:image" else ("scale", "bias"))
    index = CHANNEL_OUTPUTS.get(output)
    channel = None if index is None else f"outputs:{output}"
    first = int(_token(shader, "firstChannel", time, 0)) if node_kind == "PxrTexture" else 0
    layer = layer_at(path, first) if first and index is None else None
    if layer is not None:       # its rgb from the first channel of a layer: that layer
        return Texture(path, space, where, scale, bias, layer=layer)
    if first:                   # from another channel than a layer's first: refused
        index = first + (index or 0)
        channel = f"outputs:{output} from firstChannel {first}"
    return Texture(path, space, where, scale, bias, channel, index)


def read_input(shader, name: str, time=Usd.TimeCode.EarliestTime()) -> Input | None:
    """One input of ``shader`` at ``time`` (None: not authored anywhere)."""
    inp = shader.GetInput(name)
    if not inp:
        return None
    attrs = inp.GetValueProducingAttributes()
    if not attrs:
        return None if not inp.HasConnectedSource() else \
            Input(name, refused=f"{name} is connected to nothing that gives a value")
    attr = attrs[0]
    if UsdShade.Input.IsInput(attr):
        value = attr.Get(time)
        return None if value is None else Input(name, value=_values(value, str(attr.GetPath())),
                                                animated=_animated(attr, time))
    source = UsdShade.Shader(attr.GetPrim())
    shader_id = shader_id_of(source)
    kind = _node_kind(shader_id)
    if kind in TEXTURE_NODES:
        texture = _texture(source, kind, attr.GetBaseName(), time)
        if isinstance(texture, str):
            return Input(name, refused=f"{name}: {texture}")
        file_attr = _value_attr(source, FILE_INPUT.get(kind, "file"))
        return Input(name, texture=texture, animated=_animated(file_attr, time))
    return Input(name, refused=f"{name} comes from {shader_id or 'a node'} "
                               f"({source.GetPath()}), a procedural network")


def _surface_outputs(material):
    """The material's surface outputs: those of ``CONTEXTS`` in order, then any other
    render context's (``outputs:<context>:surface``)."""
    known = [material.GetSurfaceOutput(c) for c in CONTEXTS]
    names = {o.GetFullName() for o in known if o}
    others = [o for o in material.GetSurfaceOutputs() if o.GetFullName() not in names]
    return [o for o in known if o] + sorted(others, key=lambda o: o.GetFullName())


def surface_shader(material):
    """(shader, id) of the material's surface: the first render context with a subsurface
    mapping, else the first surface found, else (None, None)."""
    found = []
    for output in _surface_outputs(material):
        if not output.HasConnectedSource():
            continue
        for attr in output.GetValueProducingAttributes():
            if UsdShade.Output.IsOutput(attr):
                shader = UsdShade.Shader(attr.GetPrim())
                found.append((shader, shader_id_of(shader)))
    for shader, shader_id in found:
        if shader_mapping(shader_id) is not None:
            return shader, shader_id
    return found[0] if found else (None, None)


#: the prims a scene reads: every active, loaded, defined prim, inside instances too (a
#: material of an instanced asset is a prim of its prototype, seen through each instance)
PRIMS = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)


def bound_materials(stage) -> set:
    """Paths of the materials some prim binds, directly or by a collection (any purpose), as the
    material prims are read (``stage_materials``: one of an instance's prototype by its
    prototype's path)."""
    bound = set()
    for prim in stage.Traverse(PRIMS):
        if not prim.HasAPI(UsdShade.MaterialBindingAPI):
            continue
        api = UsdShade.MaterialBindingAPI(prim)
        for purpose in (UsdShade.Tokens.allPurpose, UsdShade.Tokens.full,
                        UsdShade.Tokens.preview):
            paths = [api.GetDirectBinding(purpose).GetMaterialPath()] + [
                b.GetMaterialPath() for b in api.GetCollectionBindings(purpose)]
            for path in (p for p in paths if not p.isEmpty):
                bound.add(str(path))
                target = stage.GetPrimAtPath(path)
                if target and target.IsInstanceProxy():
                    bound.add(str(target.GetPrimInPrototype().GetPath()))
    return bound


def stage_materials(stage) -> list:
    """The Material prims of ``stage``, inside instances too; a material of an instanced
    asset once (its first instance's), however many instances show it: they are one prim,
    its prototype's, with one set of inputs. (UsdShade.Material, the prototype's path or its
    own) pairs, in traversal order."""
    seen, found = set(), []
    for prim in stage.Traverse(PRIMS):
        if not prim.IsA(UsdShade.Material):
            continue
        key = str(prim.GetPrimInPrototype().GetPath() if prim.IsInstanceProxy()
                  else prim.GetPath())
        if key not in seen:
            seen.add(key)
            found.append((UsdShade.Material(prim), key))
    return found


@contextmanager
def usd_diagnostics_kept(sink):
    """USD's own warnings and errors (written by its C++ to the process's stderr, several lines
    each) go to ``sink`` (a list that gets the text) instead: the scene reports what matters
    in its one line. Outside the main thread, nothing is redirected."""
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            sink.append(tmp.read().decode("utf-8", "replace"))


def open_stage(path):
    """The USD stage at ``path``, composed whole: a SceneError (one line, naming the file and
    the first problem) if it cannot be opened or any of its layers, references or payloads
    cannot (USD would compose the rest and go on: a missing sublayer would bake nothing, or
    less, as a success)."""
    said = []
    try:
        with usd_diagnostics_kept(said):
            stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Exception as exc:            # pxr raises Tf.ErrorException
        raise SceneError(f"{path}: cannot open the USD stage: {one_line(exc)}") from None
    if stage is None:
        raise SceneError(f"{path}: cannot open the USD stage"
                         + (f": {one_line(said[0])}" if said and said[0].strip() else ""))
    errors = stage.GetCompositionErrors()
    if errors:
        raise SceneError(f"{path}: the stage does not compose whole ({len(errors)} error(s)): "
                         f"{one_line(errors[0])}{_no_mtlx_plugin(errors)}")
    return stage


def _no_mtlx_plugin(errors) -> str:
    """Why a stage that references, sublayers or payloads a ``.mtlx`` document cannot compose
    here, and what to do instead (``; ...``), where this USD has no MaterialX file format (the
    usd-core wheel has none: usdMtlx is not in it); else ""."""
    mtlx = next((m for e in errors for m in re.findall(r"@([^@]*\.mtlx)@", str(e),
                                                        re.IGNORECASE)), None)
    if mtlx is None or Sdf.FileFormat.FindByExtension("mtlx") is not None:
        return ""
    return (f"; this USD (the usd-core wheel) has no MaterialX file-format plugin (usdMtlx), "
            f"so no stage can use {os.path.basename(mtlx)} as a layer: bake the document "
            f"itself (bdipole_cl bake {mtlx}, or materials_from = \"{mtlx}\" in a scene "
            f"file), or convert it with a USD built with MaterialX (usdcat {mtlx} -o "
            f"{os.path.splitext(mtlx)[0]}.usda) and reference that")


def read_stage(path):
    """[ImportedMaterial] of every Material prim of the stage at ``path`` (``stage_materials``:
    inside instances too)."""
    stage = open_stage(path)
    unit_m = UsdGeom.GetStageMetersPerUnit(stage)
    if not (math.isfinite(unit_m) and unit_m > 0):
        raise SceneError(f"{path}: metersPerUnit = {unit_m:g}: the stage's unit must be a "
                         f"positive, finite number of metres")
    out_dir = os.path.join(os.path.dirname(os.path.abspath(path)), "bdipole")
    materials = stage_materials(stage)
    names = unique_names([str(m.GetPath()) for m, _ in materials])
    bound = bound_materials(stage)
    time = bake_time(stage)
    result = []
    for material, key in materials:
        prim_path = str(material.GetPath())
        shader, shader_id = surface_shader(material)
        result.append(replace(imported_material(
            names[prim_path], prim_path, shader_id,
            (lambda n, s=shader: read_input(s, n, time)) if shader else (lambda n: None),
            unit_m=unit_m, out_dir=out_dir, bound=prim_path in bound or key in bound),
            instanced=material.GetPrim().IsInstanceProxy()))
    return result

