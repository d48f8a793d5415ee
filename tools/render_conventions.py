"""Render the conventions' check in real renderers at high sample counts (docs/conventions.md
"Checked in real renderers"): Mitsuba 3 and Blender's Cycles, from PyPI (the ``renderers``
extra).

1. Mitsuba: the walk reference's media (alpha -> walk_reflectance with the dielectric)
   against Mitsuba's dielectric-bounded slab, per eta.
2. Mitsuba: a PxrSurface texture set (better-dipole colours) converted to OpenPBR
   (van-de-hulst) two ways: with the boundary (``van-de-hulst``: the converted colour's
   medium walked inside the dielectric) and as the OpenPBR spec reads its albedo
   (``van-de-hulst-matched``: boundary ignored); both media rendered in Mitsuba with the
   dielectric, against the painted albedo.
3. Cycles: painted colours rendered by each subsurface method, against the formula
   (``rendered_rd``), and PxrSurface colours converted to Cycles' Random Walk against the
   painted albedo.

    PYTHONPATH=. python tools/render_conventions.py [--spp 4096] [--batches 8] [--quick]

Prints Markdown tables (pasted into docs/conventions.md).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from bdipole_cl.apps import render_check
from bdipole_cl.physics import transport
from bdipole_cl.physics.conventions import CONVENTION, colour_for, rendered_rd

PAINTED = np.array([0.35, 0.6, 0.85])


def fmt(measured, k):
    return f"{measured.value[k]:.4f} ± {measured.error[k]:.4f}"


def mitsuba_reference(spp, batches, etas):
    print("| eta | alpha | walk reference | Mitsuba (diffuse) | (M - ref)/err | specular ref "
          "| Mitsuba specular |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    alpha = np.array([0.5, 0.9, 0.99])
    for eta in etas:
        diffuse, spec = render_check.mitsuba_reflectance(alpha, eta, spp=spp, batches=batches)
        ref = transport.walk_reflectance(alpha, g=0.0, eta=eta)
        s_ref = transport.specular_reflectance(eta)
        for k, a in enumerate(alpha):
            z = (diffuse.value[k] - ref[k]) / diffuse.error[k]
            print(f"| {eta:g} | {a:g} | {ref[k]:.4f} | {fmt(diffuse, k)} | {z:+.1f} | "
                  f"{s_ref:.4f} | {fmt(spec, 0)} |")


def pxrsurface_to_openpbr(spp, batches, eta=1.4):
    print("| target | painted | converted colour | medium alpha | Mitsuba (diffuse) | "
          "rel. error |")
    print("|---|---:|---:|---:|---:|---:|")
    for target in ("van-de-hulst", "van-de-hulst-matched"):
        conv = CONVENTION[target]
        colour = colour_for(target, PAINTED, eta)
        alpha = np.clip(conv.alpha_fit(colour, 0.0), 0.0, conv.alpha_max)
        diffuse, _ = render_check.mitsuba_reflectance(alpha, eta, spp=spp, batches=batches)
        for k, p in enumerate(PAINTED):
            print(f"| {target} | {p:g} | {colour[k]:.4f} | {alpha[k]:.6f} | {fmt(diffuse, k)} "
                  f"| {diffuse.value[k] / p - 1:+.2%} |")


def cycles_methods(spp, batches, eta=1.4):
    print("| Cycles method (convention) | colour | formula (rendered_rd) | Cycles (diffuse) | "
          "rel. difference |")
    print("|---|---:|---:|---:|---:|")
    colour = np.array([0.3, 0.6, 0.9])
    for name, method in render_check.CYCLES_METHODS.items():
        diffuse, _ = render_check.cycles_reflectance(colour, (1, 1, 1), eta, method, spp=spp,
                                                     batches=batches)
        want = rendered_rd(name, colour, eta)
        for k, c in enumerate(colour):
            print(f"| {method} ({name}) | {c:g} | {want[k]:.4f} | {fmt(diffuse, k)} | "
                  f"{diffuse.value[k] / want[k] - 1:+.2%} |")
    print()
    print("| PxrSurface painted | Cycles Random Walk colour | Cycles (diffuse) | rel. error |")
    print("|---:|---:|---:|---:|")
    painted = np.array([0.35, 0.6, 0.75])
    for chunk in (painted, np.array([0.8, 0.85, 0.9])):
        ok = chunk <= rendered_rd("cycles-random-walk", 1.0, eta)
        colour = np.where(ok, colour_for("cycles-random-walk", np.where(ok, chunk, 0.5), eta),
                          1.0)
        diffuse, _ = render_check.cycles_reflectance(colour, (1, 1, 1), eta, "RANDOM_WALK",
                                                     spp=spp, batches=batches)
        for k, p in enumerate(chunk):
            note = "" if ok[k] else " (beyond reach: colour 1)"
            print(f"| {p:g} | {colour[k]:.4f}{note} | {fmt(diffuse, k)} | "
                  f"{diffuse.value[k] / p - 1:+.2%} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096, help="Mitsuba paths per batch")
    ap.add_argument("--batches", type=int, default=8)
    ap.add_argument("--cycles-spp", type=int, default=256)
    ap.add_argument("--quick", action="store_true", help="small counts (a smoke run)")
    ap.add_argument("--only", choices=("mitsuba", "openpbr", "cycles"), default=None)
    args = ap.parse_args()
    spp, cspp = (256, 16) if args.quick else (args.spp, args.cycles_spp)
    t0 = time.perf_counter()
    if args.only in (None, "mitsuba"):
        mitsuba_reference(spp, args.batches, (1.33, 1.4, 1.5))
        print()
    if args.only in (None, "openpbr"):
        pxrsurface_to_openpbr(spp, args.batches)
        print()
    if args.only in (None, "cycles"):
        cycles_methods(cspp, args.batches)
    print(f"\n({time.perf_counter() - t0:.0f} s; Mitsuba {spp} x {args.batches} paths, Cycles "
          f"{cspp} spp x {args.batches} seeds on a 64x32 panorama)")


if __name__ == "__main__":
    main()
