"""Render targets of a bake's materials (I/O): the one registry of the shader conventions a
bake writes a material for (``--target``, a scene file's ``targets``), each with the shader
it writes, the UsdShade render context its surface output is in, and the convention its
subsurface inputs are in (the names of ``physics.conventions``; docs/materials.md).

=================  =====================================  =======  ========================
target             shader                                 context  subsurface inputs
=================  =====================================  =======  ========================
preview            UsdPreviewSurface                      (all)    none: the albedo as the
                                                                   diffuse colour, for
                                                                   viewers
pxrsurface         RenderMan PxrSurface + PxrTexture      ri       colour + dmfp, Better
                                                                   Dipole (this library's)
openpbr            ND_open_pbr_surface_surfaceshader      mtlx     colour + radius, van de
                                                                   Hulst
standard-surface   ND_standard_surface_surfaceshader      mtlx     colour + radius, van de
                                                                   Hulst
=================  =====================================  =======  ========================
"""
from __future__ import annotations

from dataclasses import dataclass

from ..vocabulary import Option, Registry


@dataclass(frozen=True)
class Target(Option):
    """A render target: ``shader_id`` (USD ``info:id``), ``context`` (UsdShade render
    context of the material's surface output; "" is the universal one), ``convention``
    (the conventions registry's name its colour and distance are in; None: no subsurface),
    ``mtlx``: whether MaterialX's standard libraries define its nodes (it goes into the
    bake's ``.mtlx`` document too)."""

    shader_id: str = ""
    context: str = ""
    convention: str | None = None
    mtlx: bool = False


TARGET = Registry("target", (
    Target("preview", "UsdPreviewSurface for viewers: the albedo texture as its diffuse "
           "colour (it has no subsurface inputs)", ("usdpreviewsurface", "UsdPreviewSurface"),
           "UsdPreviewSurface", "", None, True),
    Target("pxrsurface", "RenderMan PxrSurface: subsurfaceColor and the diffuse mean free path "
           "(dmfp) through PxrTexture, in this library's (Better Dipole) convention",
           ("PxrSurface",), "PxrSurface", "ri", "better-dipole", False),
    Target("openpbr", "OpenPBR Surface (MaterialX): subsurface_color and subsurface_radius in "
           "the van de Hulst convention", ("open_pbr_surface",),
           "ND_open_pbr_surface_surfaceshader", "mtlx", "van-de-hulst", True),
    Target("standard-surface", "Autodesk Standard Surface (MaterialX): subsurface_color and "
           "subsurface_radius in the van de Hulst convention", ("standard_surface",),
           "ND_standard_surface_surfaceshader", "mtlx", "van-de-hulst", True),
))

#: what a bake writes when neither ``--target`` nor ``targets`` says
#: (the viewers' preview only: a target in another convention than the painted one makes maps
#: per texel, which ``--target`` asks for)
DEFAULT_TARGETS = ("preview",)


def parse_targets(spellings) -> tuple:
    """The canonical names of ``spellings`` (a comma list or a sequence), each once, in the
    registry's order; ValueError naming an unknown one or two that share a render context
    (one material has one surface per context)."""
    if isinstance(spellings, str):
        spellings = [s.strip() for s in spellings.split(",") if s.strip()]
    names = {TARGET.canonical(s) for s in spellings}
    chosen = tuple(t for t in TARGET if t.name in names)
    contexts = {}
    for t in chosen:
        if t.context in contexts:
            raise ValueError(f"target={contexts[t.context]},{t.name}: both write the "
                             f"{t.context or 'universal'} render context's surface; choose one")
        contexts[t.context] = t.name
    return tuple(t.name for t in chosen)
