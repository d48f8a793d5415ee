"""``bdipole-cl demo``: a small built-in example, made procedurally, the main jobs on it, two
pictures of the results, and the commands a user runs next on their own files."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from ..io.oiio_text import oiio_error
from ..signals import signals_deferred

W, H = 256, 128


def write_exr(path, pixels, channels, half=False):
    """Write (H, W, C) float pixels as an EXR with named channels (helper for demo and tests)."""
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2],
                          "half" if half else "float")
    spec.channelnames = tuple(channels)
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec) or not out.write_image(pixels):
        raise OSError(f"cannot write {path}: {oiio_error()}")
    out.close()


def make_inputs(folder):
    """Albedo with a full 0..1 ramp (per channel), an mfp texture (mm) and an irradiance map."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    x = np.linspace(0.0, 1.0, W, dtype=np.float32)[None, :].repeat(H, 0)
    y = np.linspace(0.0, 1.0, H, dtype=np.float32)[:, None].repeat(W, 1)
    albedo = np.stack([x, x ** 1.2, x ** 1.5], axis=-1)            # skin-like: red scatters most
    mfp = (0.5 + 3.5 * y)[..., None]                                # 0.5 .. 4 mm down the image
    irradiance = np.zeros((H, W, 3), np.float32)
    irradiance[H // 2 - 2:H // 2 + 2, :] = 1.0                      # a bright horizontal line
    irradiance[:, W // 2 - 1:W // 2 + 1] = 4.0                      # and a vertical one
    paths = {"albedo": folder / "albedo.exr", "mfp": folder / "mfp.exr",
             "irradiance": folder / "irradiance.exr"}
    write_exr(paths["albedo"], albedo, ("R", "G", "B"))
    write_exr(paths["mfp"], mfp, ("Y",))
    write_exr(paths["irradiance"], irradiance, ("R", "G", "B"))
    return paths


#: the file that marks a folder as made by ``demo`` (which may then rewrite it): a JSON record of
#: the files it wrote and their digests (``record_folder``)
MARKER = ".bdipole_demo"


def folder_digests(folder) -> dict:
    """{path relative to ``folder``: sha256} of every regular file below it but the MARKER."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != MARKER}


def recorded_files(folder):
    """The files and digests the demo recorded in ``folder`` (None: no complete record, a
    marker of an earlier version or of a run that did not finish)."""
    try:
        record = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return record.get("files") if isinstance(record, dict) and record.get("complete") else None


def record_folder(folder, complete):
    """The MARKER: the folder is the demo's, and (``complete``) the files it holds now are
    what the demo wrote."""
    record = {"made by": "bdipole-cl demo: it may rewrite the files it made here",
              "complete": bool(complete), "files": folder_digests(folder) if complete else {}}
    (Path(folder) / MARKER).write_text(json.dumps(record, indent=1))


def claim_folder(folder):
    """Make ``folder`` the demo's: refused (ValueError) if it holds files the demo did not
    make, or files changed since it made them (a user's edit or addition in a demo folder), or
    files of a demo that did not finish (whose files were not recorded), so a user's file is
    never overwritten."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"--dir {folder}: exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not (folder / MARKER).exists():
        raise ValueError(f"--dir {folder}: the folder holds files the demo did not make; give "
                         f"a new or empty folder (nothing was written)")
    entries = list(folder.rglob("*")) if folder.is_dir() else []
    links = [p for p in entries if p.is_symlink()]
    if links:                     # a linked folder would take the demo's writes elsewhere
        raise ValueError(f"--dir {folder}: {links[0]} is a symbolic link; the demo writes only "
                         f"into a folder of its own (nothing was written)")
    odd = [p for p in entries if not (p.is_file() or p.is_dir())]
    if odd:                       # a FIFO or socket: not the demo's, and never read
        raise ValueError(f"--dir {folder}: {odd[0]} is not a regular file or folder; the demo "
                         f"made none (nothing was written)")
    present = folder_digests(folder) if folder.is_dir() else {}
    recorded = recorded_files(folder) if folder.is_dir() else None
    if present and recorded is None:
        raise ValueError(f"--dir {folder}: an earlier demo there did not finish (or an older "
                         f"version made it), so its files cannot be told from yours; give a new "
                         f"folder or remove this one (nothing was written)")
    if recorded is not None:
        changed = [name for name, digest in present.items() if recorded.get(name) != digest]
        if changed:
            shown = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more"
                                              if len(changed) > 3 else "")
            raise ValueError(f"--dir {folder}: {shown} changed or added since the demo made "
                             f"the folder; move them or give a new folder (nothing was "
                             f"written)")
    folder.mkdir(parents=True, exist_ok=True)
    record_folder(folder, complete=False)


def run_demo(folder="bdipole_demo", progress=True) -> int:
    claim_folder(folder)
    try:
        return _run_demo(folder, progress)
    finally:                # what the folder holds now is the demo's, an interrupted run's too
        with signals_deferred():               # (its writers removed their temporaries); a
            record_folder(folder, complete=True)   # second signal waits for the record


#: the demo's pictures: (file name in the demo folder, what it shows)
PICTURES = (("coefficients.preview.png", "contact sheet of step 1's coefficients"),
            ("profile.png", "R(r) per channel and Rd(alpha') of step 2's material"))

#: what a user runs next on their own files, printed last (each line: command, what it does)
NEXT_STEPS = (
    ("bdipole-cl invert 'albedo.<UDIM>.exr' --mfp 1.2,0.6,0.3 -o 'out/{stem}_sss.exr'",
     "your albedo tiles -> sigma_a, sigma_s' (mfp in mm, per channel)"),
    ("bdipole-cl preview out/albedo.1001_sss.exr",
     "a contact sheet of one output, beside it"),
    ("bdipole-cl bake scene.toml --preview",
     "a whole scene: copy {scene} beside your textures, edit its paths"),
)

#: the blur step's material: Rd and mfp (mm) per channel, eta; its texel (mm) and tol
BLUR_ALBEDO, BLUR_MFP, BLUR_ETA = (0.8, 0.6, 0.4), (4.0, 2.0, 1.0), 1.4
BLUR_TEXEL, BLUR_TOL = 0.5, 1e-3


def shown(path) -> str:
    """``path`` as the user typed it: relative to the working folder when below it."""
    path = Path(path)
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def tally(report) -> str:
    """The last line of a report's summary: 'N done, N failed, N skipped'."""
    return report.summary().splitlines()[-1]


def _run_demo(folder, progress) -> int:
    from ..device import get_runtime
    from ..jobs.batch import process_textures
    from ..jobs.blur_file import blur_file
    from .preview import contact_sheet
    from .profile import constant_specs, profile_plot
    folder = Path(folder)
    rt = get_runtime()
    print(f"bdipole-cl demo: a small made-up example in {shown(folder)}/")
    print(f"device: {rt.describe()}")
    paths = make_inputs(folder)

    print(f"\n1. invert: albedo ramp 0..1 + mfp 0.5..4 mm ({W}x{H}) -> sigma_a, sigma_s'")
    report = process_textures(paths["albedo"], mfp=str(paths["mfp"]), eta=1.4,
                              output=str(folder / "coefficients.exr"),
                              outputs=("alpha", "rho", "sigma_a", "sigma_s"),
                              on_invalid="clamp", progress=progress)
    if report.exit_code:                       # the full table only where something failed
        print(report.summary())
    else:
        clamped = sum(report.results[0].invalid.values())
        print(f"   {tally(report)}: wrote {shown(report.results[0].output)}")
        print(f"   {clamped} albedo texels are 1 (no finite medium has Rd = 1): "
              f"--on-invalid clamp clamped and counted them")

    out = folder / "exitance.exr"
    print(f"\n2. blur: irradiance lines -> exitance with R(r), albedo {BLUR_ALBEDO}, "
          f"mfp {BLUR_MFP} mm, texel {BLUR_TEXEL} mm")
    info = blur_file(paths["irradiance"], out, albedo=BLUR_ALBEDO, mfp=BLUR_MFP, eta=BLUR_ETA,
                     texel_size=BLUR_TEXEL, tol=BLUR_TOL)
    methods = ", ".join(f"{'RGB'[c.channel]}: {c.method} r={c.radius}" for c in info.channels)
    print(f"   wrote {shown(out)} ({methods} texels)")

    print("\n3. bake: a scene file, two materials on UDIM tiles with masks, and a blur")
    scene_rc = run_scene(folder / "scene")

    print("\npictures:")
    sheet = contact_sheet(folder / "coefficients.exr", folder / PICTURES[0][0],
                          title="bdipole-cl demo: coefficients.exr")
    plot = profile_plot(constant_specs(BLUR_ALBEDO, BLUR_MFP, (BLUR_ETA,)),
                        folder / PICTURES[1][0], unit="mm", tol=BLUR_TOL,
                        title="bdipole-cl demo: the blur's material")
    for path, (_, what) in zip((sheet.path, plot.path), PICTURES):
        print(f"   {shown(path):<40} {what}")
    print("   (no throughput: these textures are tiny, so the time is start-up and kernel "
          "compiles; `bdipole-cl report` measures it)")

    scene = shown(folder / "scene" / "scene.toml")
    print("\nnext, on your own files:")
    for cmd, what in NEXT_STEPS:
        print(f"   {cmd}\n      # {what.format(scene=scene)}")
    return max(report.exit_code, scene_rc)


SCENE_TOML = """# bdipole-cl demo scene: `bdipole-cl plan scene.toml`, `bdipole-cl bake scene.toml`
[defaults]
eta = 1.4
unit = "mm"
tol = 1e-4

[[material]]
name = "skin"
albedo = "tex/skin_albedo.<UDIM>.exr"
mfp = [1.2, 0.6, 0.3]
outputs = ["sigma_a", "sigma_s"]
output = "out/skin_sss.<UDIM>.exr"
mask = "alpha"
half = true

[[material]]
name = "marble"
albedo = "tex/marble_albedo.<UDIM>.exr"
mfp = 2.0
outputs = ["rho", "sigma_t"]
output = "out/marble_sss.<UDIM>.exr"

[[blur]]
name = "skin_tsd"
material = "skin"
irradiance = "light/skin_irr.<UDIM>.exr"
texel_size = 0.1
output = "out/skin_exitance.<UDIM>.exr"
"""


def make_scene(folder, size=64):
    """scene.toml and its textures: skin (RGB + alpha: UV islands on a white background, two
    UDIM tiles), marble (grey, one tile) and skin's irradiance."""
    folder = Path(folder)
    (folder / "tex").mkdir(parents=True, exist_ok=True)
    (folder / "light").mkdir(parents=True, exist_ok=True)
    yy, xx = np.mgrid[0:size, 0:size] / size
    for k, tile in enumerate(("1001", "1002")):
        island = ((xx - 0.5) ** 2 + (yy - 0.5) ** 2 < 0.12 + 0.05 * k).astype(np.float32)
        rgb = np.stack([0.55 + 0.3 * xx, 0.35 + 0.2 * yy, 0.25 + 0.1 * xx], -1)
        rgb = np.where(island[..., None] > 0, rgb, 1.0)     # painted white outside the islands
        write_exr(folder / "tex" / f"skin_albedo.{tile}.exr",
                  np.concatenate([rgb, island[..., None]], -1), ("R", "G", "B", "A"))
        light = np.zeros((size, size, 3), np.float32)
        light[size // 3:size // 3 + 3] = 5.0
        write_exr(folder / "light" / f"skin_irr.{tile}.exr", light, ("R", "G", "B"))
    write_exr(folder / "tex" / "marble_albedo.1001.exr", 0.6 + 0.3 * yy, ("Y",))
    path = folder / "scene.toml"
    path.write_text(SCENE_TOML)
    return path


def run_scene(folder) -> int:
    """Plan, bake and plan again the demo scene in ``folder``; its exit code."""
    from ..jobs.scene import load
    path = make_scene(folder)
    plan = load(path).plan()
    print(f"   plan: {len(plan.jobs)} jobs (`bdipole-cl plan {shown(path)}` says what each "
          f"computes and leaves out)")
    report = plan.run()
    if report.exit_code:
        print(report.summary())
    else:
        print(f"   {tally(report)}: wrote {shown(Path(folder) / 'out')}/ "
              f"({len(report.results)} EXRs)")
    again = load(path).plan()
    fresh = sum(j.up_to_date for j in again.jobs)
    print(f"   baked again: {fresh} of {len(again.jobs)} jobs up to date"
          + (" (nothing to do: a bake reruns only what changed)"
             if fresh == len(again.jobs) else ""))
    return report.exit_code
