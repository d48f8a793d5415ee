"""One file per layer of an output of ours that holds several (the jobs layer): the texture
nodes a material network names read a file's first channels, so each reads a file of its
own (docs/materials.md "Texture nodes").

MaterialX's ``image`` node has a ``layer`` input, but its GLSL generator ignores it (every
image reads the file's first channels) and its OSL generator passes it to OpenImageIO as a
subimage's name (``Unknown subimage``); UsdUVTexture has none. So beside a coefficients file
``skin.1001.exr`` (``sigma_a.*``, ``sigma_s.*``) a bake that writes networks writes
``skin.1001.sigma_a.exr`` and ``skin.1001.sigma_s.exr``, and ``convert`` writes
``skin.van-de-hulst.colour.exr`` and ``.radius.exr`` beside its output: the layer's
channels as R, G, B, the same values, tagged as the output is (``networks.layer_path``
names them). Each is rewritten only when its output changes (its header records the
output's identity: ``io.freshness``).
"""
from __future__ import annotations

import os

from ..io.channels import COLOUR_LAYERS, short_name
from ..io.collisions import foreign
from ..io.freshness import header_fields, is_up_to_date, params_digest
from ..io.images import TextureError, Writer, output_spec, read_whole
from ..io.mipmaps import texture_options
from ..io.networks import layer_path


def layer_files(path: str, layers, working, written: list, inputs=frozenset(),
                texture=None, convention=None) -> dict:
    """{layer: its file} of the output ``path`` (written unless all are up to date; each one
    written added to ``written``); ``working``: the WorkingSpace the output is in (a colour
    layer's tag; every other layer is data: ``output_spec``); ``inputs``: the real paths of
    the run's inputs; ``texture``: the run's TextureOptions (each file a tiled, mip-mapped
    texture as the output is: every file a network reads), or None; ``convention``: a
    conversion's, named in each file (``networks.layer_path``). TextureError, OSError
    on failure: a layer the output does not hold, a file there that is an input or not this
    tool's."""
    outs = {layer: layer_path(path, layer, convention) for layer in layers}
    for out in outs.values():
        why = (f"{out}: a layer's file would overwrite an input of this run" if
               os.path.realpath(out) in inputs else foreign(out))
        if why:
            raise TextureError(why)
    inputs = {"layered": path}
    texture = texture_options(texture)
    digest = params_digest({"kind": "layer", "layers": sorted(outs),
                            "texture": texture.describe() if texture else None})
    if all(is_up_to_date(out, inputs, digest) for out in outs.values()):
        return outs
    spec, px = read_whole(path, "layered output")
    names = [str(n) for n in spec.channelnames]
    for layer, out in outs.items():
        idx = [i for i, n in enumerate(names) if n.startswith(f"{layer}.")]
        if not idx:
            raise TextureError(f"{path}: no {layer}.* channels (its channels: "
                               f"{', '.join(names)})")
        header = header_fields(inputs, digest) | {"layer": layer}
        half = all(str(f) == "half" for f in (list(spec.channelformats) or [spec.format]))
        write_whole(Writer(out, output_spec(spec, [short_name(names[i]) for i in idx], -1, half,
                                            header, working=working,
                                            data=layer != COLOUR_LAYERS[0]), texture=texture),
                    px[..., idx])
        written.append(out)
    return outs


def write_whole(writer: Writer, pixels) -> None:
    """``pixels`` (H x W x C) as the whole of ``writer``'s file, committed (temp file, verified,
    renamed), or the temp file removed on any failure or stop."""
    try:
        writer.write_band(0, pixels.shape[0], pixels)
        writer.commit()
    except BaseException:
        writer.abort()
        raise


def coefficient_layers(materials, outcome, inputs) -> tuple:
    """({material name: [its layer files]}, [(path, None) written or (path, why not)]) of a
    bake's textured materials (``outcome(m)``: its coefficient files and failures, as the
    manifest takes them; ``inputs``: the real paths the bake reads): each output's own file
    beside each coefficients file."""
    from ..io.colour import resolve_working_space
    found, rows = {}, []
    for m in materials:
        files, failed = outcome(m)
        if failed or m.constant:
            continue
        written, found[m.name] = [], []
        for f in files:
            try:
                found[m.name] += layer_files(f, m.outputs, resolve_working_space(
                    m.working_space), written, inputs, m.texture).values()
            except (TextureError, OSError) as exc:
                rows.append((layer_path(f, m.outputs[0]), str(exc)))
        rows += [(p, None) for p in written]
    return found, rows
