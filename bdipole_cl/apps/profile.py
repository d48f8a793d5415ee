"""``bdipole-cl profile``: the Better Dipole profile R(r) of a material, per channel, and
Rd(alpha') with its albedo range.

Left: R(r) (docs/model.md, ``physics.reference.profile``) per channel on log axes, for the
albedo and mfp given (or a scene material's mean over its albedo texture, the range over its
texels shaded), with the blur's truncation radius at ``tol`` (energy beyond it <= tol * Rd,
``ops.blur.weights.truncation_radius``) marked on each curve and the mfp marked. Right: Rd as
a function of alpha' (``reference.rd``) with the albedo range shaded and each channel's
(alpha', Rd) marked. Everything drawn is returned (``ProfilePlot``): the curves' data as the
artists hold it, so tests check the picture against R(r).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.colour import resolve_working_space
from ..io.images import read_parameter_texture
from ..io.patterns import companion_path, expand_inputs
from ..jobs.scene import load
from ..jobs.scene_stats import read_albedo
from ..ops.blur.weights import truncation_radius
from ..physics import reference as ref

#: line colours by channel name (anything else: grey)
CHANNEL_COLOURS = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
#: a texture's albedos are kept within these for the profile (Rd = 1 is an infinitely dense
#: medium, invalid for the coefficients; the largest float32 below 1 is what the bake takes)
RD_MIN, RD_MAX = 1e-6, float(np.nextafter(np.float32(1.0), np.float32(0.0)))
#: the blur's usual truncation tol, for a material no blur of the scene uses
DEFAULT_BLUR_TOL = 1e-3
#: points of each R(r) curve (geometric in r), plus the marked radii themselves
CURVE_POINTS = 400


@dataclass(frozen=True)
class ChannelSpec:
    """One channel's material: albedo (Rd, its mean over a texture) and its range, mfp, eta."""

    name: str
    albedo: float
    mfp: float                       # the material's mfp, its mfp_scale applied
    eta: float
    albedo_range: tuple | None = None
    mfp_kind: str = "diffuse"        # as the material's bake reads the mfp
    model: str = "better"            # the inversion's model, as the bake's


@dataclass(frozen=True)
class ChannelProfile:
    """One channel as drawn: its parameters, the curve and the marked truncation radius."""

    spec: ChannelSpec
    alpha: float                     # alpha'
    sigma_t: float                   # sigma_t', 1/unit
    truncation_radius: float         # unit
    r: np.ndarray                    # the curve as drawn: r (unit) ...
    R: np.ndarray                    # ... and R(r) (1/unit^2)
    mark: tuple                      # the marker as drawn: (r, R)
    band: tuple | None = None        # R(r) at the albedo range's ends, as drawn


@dataclass(frozen=True)
class ProfilePlot:
    title: str
    unit: str
    tol: float
    channels: tuple
    alpha: np.ndarray                # Rd(alpha') as drawn
    rd: dict                         # eta -> Rd over ``alpha``
    shaded: tuple | None             # the albedo range shaded on the Rd axis
    size: tuple                      # pixels
    path: str | None = None


def coefficients(albedo, mfp, eta, mfp_kind="diffuse", model="better"):
    """(alpha', sigma_t') of an albedo (Rd) and mfp, as the bake computes them: the model's
    inversion, sigma_t' = 1/mfp for an extinction mfp, 1/(mfp mu_tr/sigma_t') for a diffuse
    one (docs/model.md "Mean free path")."""
    alpha, rho = ref.invert_rd_rho(albedo, eta, False, model)
    sigma_t = (1.0 / mfp if mfp_kind == "extinction"
               else 1.0 / (mfp * ref.mu_tr_over_sigma_t(rho, model)))
    return float(alpha), float(sigma_t)


def spec_coefficients(spec: ChannelSpec, albedo=None):
    """``coefficients`` of a channel (at ``albedo`` instead of its own, where given)."""
    return coefficients(spec.albedo if albedo is None else albedo, spec.mfp, spec.eta,
                        spec.mfp_kind, spec.model)


def channel_profile(spec: ChannelSpec, tol):
    """(alpha', sigma_t', truncation radius) of one channel."""
    alpha, sigma_t = spec_coefficients(spec)
    return alpha, sigma_t, truncation_radius(alpha, sigma_t, spec.eta, tol)


def radii(specs, tol, extra):
    lo = 0.01 * min(s.mfp for s in specs)
    hi = 1.5 * max(channel_profile(s, tol)[2] for s in specs)
    return np.unique(np.concatenate([np.geomspace(lo, hi, CURVE_POINTS), extra]))


def draw_profiles(ax, specs, unit, tol, band=True):
    """R(r) of every channel in ``ax`` (log axes), each with its truncation radius marked and
    the mfp dashed; the albedo range shaded when known. Returns the ChannelProfiles."""
    params = [channel_profile(s, tol) for s in specs]
    marks = np.array([p[2] for p in params] + [s.mfp for s in specs])
    r = radii(specs, tol, marks)
    out = []
    for s, (alpha, sigma_t, r_t) in zip(specs, params):
        colour = CHANNEL_COLOURS.get(s.name, "0.35")
        (line,) = ax.plot(r, ref.profile(r, alpha, sigma_t, s.eta), color=colour, lw=1.6,
                          label=f"{s.name}: albedo {s.albedo:.3g}, mfp {s.mfp:.3g} {unit}")
        drawn_band = None
        if band and s.albedo_range is not None and s.albedo_range[0] < s.albedo_range[1]:
            ends = [ref.profile(r, *spec_coefficients(s, a), s.eta) for a in s.albedo_range]
            ax.fill_between(r, ends[0], ends[1], color=colour, alpha=0.15, lw=0)
            drawn_band = tuple(ends)
        (mark,) = ax.plot([r_t], [ref.profile(r_t, alpha, sigma_t, s.eta)], "o", color=colour,
                          mfc="white", ms=6, mew=1.5)
        ax.axvline(s.mfp, color=colour, ls="--", lw=0.8)
        out.append(ChannelProfile(s, alpha, sigma_t, r_t, np.asarray(line.get_xdata()),
                                  np.asarray(line.get_ydata()),
                                  (float(mark.get_xdata()[0]), float(mark.get_ydata()[0])),
                                  drawn_band))
    ax.set_xscale("log")
    ax.set_yscale("log")
    # down to a decade below the lowest mark: the tail past the truncation radius is cut off
    low = min(p.mark[1] for p in out) * 0.1
    ax.set_ylim(low, max(float(p.R.max()) for p in out) * 2.0)
    ax.set_xlim(r[0], r[-1])
    ax.set_xlabel(f"r ({unit})")
    ax.set_ylabel(f"R(r) (1/{unit}$^2$)")
    ax.grid(True, which="major", alpha=0.3)
    ax.plot([], [], "o", color="0.3", mfc="white", label=f"truncation radius (tol {tol:g})")
    ax.plot([], [], "--", color="0.3", lw=0.8, label="mfp")
    if any(p.band is not None for p in out):
        ax.fill_between([], [], [], color="0.3", alpha=0.15, lw=0,
                        label="R(r) over the albedo range of the texture")
    ax.legend(fontsize=7, loc="lower left")
    return out


def draw_rd(ax, specs, profiles):
    """Rd(alpha') per distinct eta, the albedo range shaded, the channels marked; returns
    (alpha grid, {eta: Rd}, shaded range)."""
    # dense near alpha' = 1, where Rd rises steeply
    alpha = np.unique(np.concatenate([np.linspace(0.0, 1.0, 401),
                                      1.0 - np.geomspace(1e-7, 0.5, 400)]))
    curves, etas = {}, sorted({s.eta for s in specs})
    for eta in etas:
        users = [s for s in specs if s.eta == eta]     # a curve in its channel's colour
        colour = CHANNEL_COLOURS.get(users[0].name, "0.2") if len(users) == 1 else "0.2"
        curves[eta] = ref.rd(alpha, eta, model=users[0].model)
        which = f" ({', '.join(u.name for u in users)})" if len(etas) > 1 else ""
        ax.plot(alpha, curves[eta], color=colour, lw=1.4,
                label=f"Rd($\\alpha'$), eta {eta:g}{which}")
    ranges = [s.albedo_range for s in specs if s.albedo_range is not None]
    lo = min(r[0] for r in ranges) if ranges else min(s.albedo for s in specs)
    hi = max(r[1] for r in ranges) if ranges else max(s.albedo for s in specs)
    shaded = None
    if hi > lo:
        ax.axhspan(lo, hi, color="tab:orange", alpha=0.18, lw=0,
                   label="albedo range" + ("" if ranges else " of the channels"))
        shaded = (float(lo), float(hi))
        ends = [min(spec_coefficients(c, v)[0] for c in specs) if k == 0 else
                max(spec_coefficients(c, v)[0] for c in specs) for k, v in enumerate((lo, hi))]
        ax.axvspan(*ends, color="tab:orange", alpha=0.10, lw=0)
    for s, p in zip(specs, profiles):
        ax.plot([p.alpha], [s.albedo], "o",
                color=CHANNEL_COLOURS.get(s.name, "0.35"), ms=6,
                label=f"{s.name}: $\\alpha'$ {p.alpha:.4g}, Rd {s.albedo:.3g}")
    # Rd rises steeply near alpha' = 1: from a margin below the lowest alpha' of the range
    a_lo = min([p.alpha for p in profiles] + [spec_coefficients(c, max(lo, 1e-4))[0]
                                              for c in specs])
    ax.set_xlim(max(0.0, 1.0 - 2.0 * (1.0 - a_lo)), 1.0)
    ax.set_ylim(0, 1)
    ax.set_xlabel("$\\alpha'$ (reduced albedo, dimensionless)")
    ax.set_ylabel("Rd (diffuse albedo, dimensionless)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    return alpha, curves, shaded


def profile_plot(specs, output, *, unit="mm", tol=1e-3, title=None, force=False,
                 inputs=()) -> ProfilePlot:
    """Draw and save (PNG or SVG by extension) the profile page of ``specs`` (replacing no
    file this tool did not write unless ``force``, and never one of ``inputs``)."""
    from .preview import check_picture_output, require_matplotlib, save_figure
    require_matplotlib()
    check_picture_output(output, inputs, force)         # before any work
    from matplotlib.figure import Figure
    fig = Figure(figsize=(11.0, 4.6), dpi=100, layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=(1.35, 1.0))
    profiles = draw_profiles(left, specs, unit, tol)
    left.set_title("Better Dipole profile R(r) per channel", fontsize=10)
    alpha, curves, shaded = draw_rd(right, specs, profiles)
    right.set_title("Rd($\\alpha'$): the albedo the inversion matches", fontsize=10)
    title = title or "profile"
    fig.suptitle(title, fontsize=11, weight="bold")
    save_figure(fig, output, inputs, force)
    size = (int(round(fig.get_figwidth() * fig.dpi)), int(round(fig.get_figheight() * fig.dpi)))
    return ProfilePlot(title, unit, tol, tuple(profiles), alpha, curves, shaded, size,
                       str(output))


def constant_specs(albedo, mfp, eta) -> list:
    """Channels of constants (one value or one per channel each)."""
    n = max(len(albedo), len(mfp), len(eta))
    names = ("R", "G", "B") if n == 3 else tuple(f"c{i}" for i in range(n)) if n > 1 else ("Y",)
    pick = [v if len(v) == n else v * n for v in (albedo, mfp, eta)]
    for what, v in zip(("albedo", "mfp", "eta"), (albedo, mfp, eta)):
        if len(v) not in (1, n):
            raise ValueError(f"--{what} has {len(v)} values for {n} channels")
    return [ChannelSpec(names[i], pick[0][i], pick[1][i], pick[2][i]) for i in range(n)]


def _material(scene, name):
    names = [m.name for m in scene.materials]
    if name not in names:
        raise ValueError(f"{scene.path}: no material {name!r} (materials: "
                         f"{', '.join(names) or 'none'})")
    return scene.materials[names.index(name)]


def material_specs(scene, name, inputs=None):
    """(ChannelSpecs, unit, tol) of a scene material: per channel the mean albedo over the
    unmasked, finite texels of all its tiles and their range, the mean mfp (its mfp_scale
    applied, read as its mfp_kind), eta and model, as its bake takes them; tol is its blur's
    (else DEFAULT_BLUR_TOL). ``inputs``: a list that gets the files read (a picture never
    replaces one)."""
    scene = load(scene) if isinstance(scene, (str, Path)) else scene
    m = _material(scene, name)
    inputs = [] if inputs is None else inputs
    albedos, mfps, names = [], [], None
    for path, tile in expand_inputs([m.albedo]):
        if not Path(path).is_file():
            continue
        mask_path = companion_path(m.mask, path, tile) if m.mask not in (None, "alpha") else None
        px, keep, names, *_ = read_albedo(path, m.mask, mask_path, m.colorspace,
                                          resolve_working_space(m.working_space),
                                          m.albedo_layer)
        inputs += [p for p in (path, mask_path) if p]
        keep = np.ones(px.shape[:2], bool) if keep is None else keep
        albedos.append(px[keep])
        if isinstance(m.mfp, str):
            inputs.append(companion_path(m.mfp, path, tile))
            mfp = read_parameter_texture(inputs[-1], "mfp", role="mfp", layer=m.mfp_layer)
            mfps.append(np.broadcast_to(mfp, px.shape[:2] + (mfp.shape[-1],))[keep])
    if not albedos:
        raise ValueError(f"material {name!r}: no albedo file matches {m.albedo}")
    vals = np.concatenate(albedos)
    finite = np.all(np.isfinite(vals), axis=-1)
    if not finite.any():
        raise ValueError(f"material {name!r}: no albedo texel to plot (every one is masked "
                         f"out or not finite)")
    vals = np.clip(vals[finite], RD_MIN, RD_MAX)
    mfp = np.concatenate(mfps)[finite].mean(axis=0) if mfps else np.asarray(m.mfp)
    n = vals.shape[-1]
    mfp = np.broadcast_to(mfp, (n,)) if mfp.size in (1, n) else mfp[:n]
    scale = np.broadcast_to(np.asarray(m.mfp_scale, np.float64), (n,))
    eta = np.broadcast_to(np.asarray(m.eta), (n,))
    specs = [ChannelSpec(names[c], float(vals[:, c].mean()), float(mfp[c] * scale[c]),
                         float(eta[c]), (float(vals[:, c].min()), float(vals[:, c].max())),
                         m.mfp_kind, m.model)
             for c in range(n)]
    tol = next((b.tol for b in scene.blurs if b.material.name == name), DEFAULT_BLUR_TOL)
    return specs, m.unit, tol


def add_command(command):
    """Add the command to the CLI (``command``: the subparsers' add_parser)."""
    from .cli_types import constants, floats, fraction, length_unit
    p = command("profile", help="plot R(r) per channel and Rd(alpha') (PNG or SVG)")
    p.add_argument("--albedo", type=constants("albedo"),
                   help="Rd in (0, 1): one value or per channel 'r,g,b'")
    p.add_argument("--mfp", type=constants("mfp"),
                   help="mean free path ld = 1/mu_tr, per channel")
    p.add_argument("--eta", type=floats, default=(1.4,), help="one or per channel")
    p.add_argument("--unit", default="mm", type=length_unit,
                   help="length unit of the mfp (default mm)")
    p.add_argument("--tol", type=fraction,
                   help="the blur's truncation tol: energy left out beyond the marked radius "
                        f"(default: the material's blur's, else {DEFAULT_BLUR_TOL:g})")
    p.add_argument("--scene", help="a scene file: plot one of its materials (--material)")
    p.add_argument("--material", help="the material's name: its mean albedo and mfp over "
                                      "its textures, their range shaded")
    p.add_argument("-o", "--output", help="PNG or SVG (default: profile.png, or "
                                          "MATERIAL.profile.png)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing -o file that bdipole-cl did not write")
    p.set_defaults(func=_cmd_profile)


def _cmd_profile(args) -> int:
    if args.scene:
        if not args.material:
            raise ValueError("--scene needs --material NAME")
        inputs = [args.scene]
        specs, unit, tol = material_specs(args.scene, args.material, inputs)
        tol = args.tol or tol
        # the default beside the command, named after the material: a name is no path
        output = args.output or f"{re.sub(r'[^A-Za-z0-9_.-]', '_', args.material)}.profile.png"
        title = f"{args.material} ({args.scene})"
    else:
        if args.albedo is None or args.mfp is None:
            raise ValueError("give --albedo and --mfp (or --scene and --material)")
        specs, unit = constant_specs(args.albedo, args.mfp, args.eta), args.unit
        tol = args.tol or DEFAULT_BLUR_TOL
        output = args.output or "profile.png"
        title, inputs = None, []
    plot = profile_plot(specs, output, unit=unit, tol=tol, title=title, force=args.force,
                        inputs=inputs)
    for c in plot.channels:
        print(f"channel {c.spec.name}: albedo {c.spec.albedo:.4g}, mfp {c.spec.mfp:.4g} {unit}: "
              f"alpha' {c.alpha:.4g}, sigma_t' {c.sigma_t:.4g} 1/{unit}, truncation radius "
              f"{c.truncation_radius:.4g} {unit} (tol {tol:g})")
    print(f"wrote {plot.path}")
    return 0
