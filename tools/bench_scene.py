#!/usr/bin/env python3
"""Benchmark a scene bake against the same work as separate commands, and what each leave-out
saves on its own, in one run on the current device.

The scene: two materials on UDIM tiles of SIZE^2 (skin: RGB + alpha, the alpha masking ~60% of
texels whose albedo is painted white; marble: grey), and one blur of one skin tile. Each row
is a fresh bake (outputs removed first) unless it says re-bake.

    python tools/bench_scene.py                  # 2 tiles a material, 2048^2
    python tools/bench_scene.py --size 512 --tiles 1
"""
import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bdipole_cl import get_runtime, use_device
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io import scene as scene_mod
from bdipole_cl.io.batch import process_textures
from bdipole_cl.io.blur_file import blur_file
from bdipole_cl.io.images import read_parameter_texture

SCENE = """
[defaults]
eta = 1.4
tol = 1e-4

[[material]]
name = "skin"
albedo = "tex/skin.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
outputs = OUTPUTS
output = "out/skin.<UDIM>.exr"
MASK
METHOD

[[material]]
name = "marble"
albedo = "tex/marble.<UDIM>.exr"
mfp = 2.0
outputs = OUTPUTS
output = "out/marble.<UDIM>.exr"
METHOD

[[blur]]
name = "tsd"
material = "skin"
irradiance = "light/irr.<UDIM>.exr"
texel_size = 0.1
tol = 1e-3
output = "out/exitance.<UDIM>.exr"
MASK
"""


def make(root, size, tiles):
    rng = np.random.default_rng(0)
    (root / "tex").mkdir(parents=True)
    (root / "light").mkdir()
    yy, xx = np.mgrid[0:size, 0:size] / size
    for k in range(tiles):
        tile = str(1001 + k)
        # UV islands: discs covering ~40% of the tile, white outside
        mask = np.zeros((size, size), bool)
        for cx, cy, r in rng.uniform([0.15, 0.15, 0.12], [0.85, 0.85, 0.22], (6, 3)):
            mask |= (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        rgb = np.stack([0.5 + 0.3 * xx, 0.3 + 0.2 * yy, 0.2 + 0.1 * xx], -1)
        rgb = np.where(mask[..., None], rgb, 1.0)
        write_exr(root / "tex" / f"skin.{tile}.exr",
                  np.concatenate([rgb, mask[..., None]], -1), ("R", "G", "B", "A"))
        write_exr(root / "tex" / f"marble.{tile}.exr", 0.5 + 0.4 * yy, ("Y",))
    light = np.zeros((size, size, 3), np.float32)
    light[size // 3:size // 3 + 8] = 4.0
    write_exr(root / "light" / "irr.1001.exr", light, ("R", "G", "B"))
    return mask.mean()


def write_scene(root, outputs='["sigma_a", "sigma_s"]', mask=True, method="auto"):
    text = (SCENE.replace("OUTPUTS", outputs)
            .replace("MASK", 'mask = "alpha"' if mask else 'on_invalid = "clamp"')
            .replace("METHOD", f'method = "{method}"'))
    (root / "scene.toml").write_text(text)


def timed_bake(root, force=True):
    out = root / "out"
    if force and out.exists():
        shutil.rmtree(out)
    t0 = time.perf_counter()
    report = scene_mod.load(root / "scene.toml").plan(force=force).run()
    assert report.exit_code == 0, report.summary()
    return time.perf_counter() - t0


def separate_commands(root, tiles):
    """The same outputs the way one would without a scene: `bdipole-cl invert` per material
    (the white background must be clamped) and `bdipole-cl blur` with the albedo texture."""
    out = root / "sep"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    for name, mfp in (("skin", (1.2, 0.6, 0.3)), ("marble", 2.0)):
        rep = process_textures(str(root / "tex" / f"{name}.<UDIM>.exr"), mfp=mfp, eta=1.4,
                               outputs=("sigma_a", "sigma_s"), on_invalid="clamp",
                               output=str(out / "{stem}.exr"))
        assert rep.exit_code == 0, rep.summary()
    albedo = read_parameter_texture(root / "tex" / "skin.1001.exr", "albedo", colour=True)
    albedo = np.minimum(albedo, np.float32(0.999))
    blur_file(root / "light" / "irr.1001.exr", out / "exitance.exr", albedo=albedo,
              mfp=(1.2, 0.6, 0.3), eta=1.4, texel_size=0.1, tol=1e-3)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--tiles", type=int, default=2, help="UDIM tiles per material")
    ap.add_argument("--device", help="OpenCL device (as `bdipole-cl --device`)")
    args = ap.parse_args(argv)
    if args.device:
        use_device(args.device)
    print(f"device: {get_runtime().describe()}")
    root = Path(tempfile.mkdtemp(prefix="bdipole_scene_"))
    try:
        masked = 1 - make(root, args.size, args.tiles)
        print(f"scene: 2 materials x {args.tiles} tiles of {args.size}^2 (skin RGB + alpha, "
              f"{masked:.0%} masked; marble grey), 1 blur of one skin tile")
        write_scene(root)
        timed_bake(root)                          # warm: kernels built, plans cached
        rows = [("separate invert + blur commands", separate_commands(root, args.tiles))]
        rows.append(("scene bake (every leave-out on)", timed_bake(root)))
        base = rows[-1][1]
        write_scene(root, outputs='["alpha", "rho", "sigma_a", "sigma_s", "sigma_t"]')
        rows.append(("  without the outputs subset (all 5)", timed_bake(root)))
        write_scene(root, mask=False)
        rows.append(("  without masks (white clamped, every texel)", timed_bake(root)))
        write_scene(root)
        scene_mod.SPECIALISE = False
        rows.append(("  without baked constants (generic kernel)", timed_bake(root)))
        scene_mod.SPECIALISE = True
        write_scene(root, method="table")
        rows.append(("  without the table range (table 256)", timed_bake(root)))
        write_scene(root)
        timed_bake(root)
        before = {p.name: p.stat().st_mtime_ns for p in (root / "out").iterdir()}
        rows.append(("re-bake, nothing changed", timed_bake(root, force=False)))
        after = {p.name: p.stat().st_mtime_ns for p in (root / "out").iterdir()}
        written = sorted(n for n in after if after[n] != before.get(n))
        print(f"\n{'':46s} {'s':>8s} {'x bake':>8s}")
        for name, s in rows:
            print(f"{name:46s} {s:8.2f} {s / base:8.2f}")
        print(f"files written by the re-bake: {written or 'none'}")
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
