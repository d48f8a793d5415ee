"""The independent Monte Carlo against the transport reference (docs/transport.md).

Two jobs:

* ``compare``: the reference (``physics.transport``) and the Monte Carlo
  (``physics.montecarlo``) at the table's (alpha, g, eta, incidence) points, at --paths each:
  prints the Markdown table of docs/transport.md "Monte Carlo check".
* ``spread``: the radii holding given fractions of the reflected energy (normal pencil) on
  the grid of docs/transport.md "Spread", written to bdipole_cl/data/walk_spread.npz.

Examples::

    python tools/walk_montecarlo.py compare --paths 1000000
    python tools/walk_montecarlo.py spread --paths 20000 --out bdipole_cl/data/walk_spread.npz
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bdipole_cl.physics import montecarlo as mc
from bdipole_cl.physics import transport as tr


def van_de_hulst_alpha(c: float, g: float = 0.0) -> float:
    """van de Hulst's inverse: s = 4.09712 + 4.20863 C - sqrt(9.59217 + 41.6808 C +
    17.7126 C^2), alpha = (1 - s^2)/(1 - g s^2)."""
    s = 4.09712 + 4.20863 * c - np.sqrt(9.59217 + 41.6808 * c + 17.7126 * c * c)
    return float((1.0 - s * s) / (1.0 - g * s * s))


#: (alpha, g, eta, incidence): eta = 1, the van de Hulst / Mitsuba points, eta < 1 and up to
#: 2.5, g from -0.5 to 0.9, both incidences
POINTS = [
    (0.3, 0.0, 1.0, "diffuse"), (0.6, 0.0, 1.0, "normal"), (0.9, 0.0, 1.0, "diffuse"),
    (0.99, 0.0, 1.0, "diffuse"), (van_de_hulst_alpha(0.6), 0.0, 1.0, "diffuse"),
    (van_de_hulst_alpha(0.6), 0.0, 1.4, "diffuse"), (0.8, 0.0, 1.33, "normal"),
    (0.95, 0.0, 1.6, "diffuse"), (0.5, 0.0, 2.0, "diffuse"), (0.9, 0.0, 2.5, "normal"),
    (0.9, 0.0, 0.7, "diffuse"), (0.99, 0.0, 0.5, "normal"), (0.8, 0.5, 1.0, "diffuse"),
    (0.95, 0.5, 1.4, "diffuse"), (0.9, 0.5, 1.33, "normal"), (0.6, 0.8, 1.4, "diffuse"),
    (0.98, 0.8, 1.4, "diffuse"), (0.9, 0.8, 1.0, "normal"), (0.95, -0.3, 1.4, "diffuse"),
    (0.8, -0.5, 2.0, "normal"), (0.99, 0.3, 1.6, "diffuse"), (0.7, 0.9, 1.33, "diffuse"),
    (0.95, 0.9, 1.4, "normal"), (0.9, 0.0, 1.4, "normal"),
]

#: the spread table's grid: similarity parameter s, g, eta, and the fractions tabulated
SPREAD_S = (0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 0.95)
SPREAD_G = (0.0, 0.4, 0.8)
SPREAD_ETA = (1.0, 1.2, 1.4, 1.7, 2.0)
SPREAD_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95)


def compare(paths: int, seed: int):
    print("| alpha | g | eta | incidence | reference | Monte Carlo | std. error | "
          "(MC - ref)/se | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for k, (alpha, g, eta, incidence) in enumerate(POINTS):
        ref = float(tr.walk_reflectance(alpha, g, eta, incidence))
        start = time.perf_counter()
        got = mc.walk(alpha, g, eta, incidence, paths=paths, seed=seed + k)
        z = (got.reflectance - ref) / got.stderr
        worst = max(worst, abs(z))
        print(f"| {alpha:.6g} | {g:g} | {eta:g} | {incidence} | {ref:.6f} | "
              f"{got.reflectance:.6f} | {got.stderr:.1e} | {z:+.2f} | "
              f"{time.perf_counter() - start:.0f} |", flush=True)
    print(f"\nlargest |MC - ref| / se: {worst:.2f} over {len(POINTS)} points, {paths} paths each")


def spread(paths: int, seed: int, out: Path):
    shape = (len(SPREAD_S), len(SPREAD_G), len(SPREAD_ETA), len(SPREAD_FRACTIONS))
    radius, error = np.empty(shape), np.empty(shape)
    for i, s in enumerate(SPREAD_S):
        for j, g in enumerate(SPREAD_G):
            alpha = float(tr.alpha_of_s(s, g))
            for k, eta in enumerate(SPREAD_ETA):
                start = time.perf_counter()
                got = mc.walk(alpha, g, eta, "normal", paths=paths, seed=seed + 1000 * i
                              + 100 * j + k, batches=20)
                for m, f in enumerate(SPREAD_FRACTIONS):
                    radius[i, j, k, m], error[i, j, k, m] = mc.spread(got, f)
                print(f"s={s} g={g} eta={eta}: r50={radius[i, j, k, 4]:.4g} "
                      f"+- {error[i, j, k, 4]:.2g} ({time.perf_counter() - start:.0f} s)",
                      flush=True)
    np.savez(out, s=np.array(SPREAD_S), g=np.array(SPREAD_G), eta=np.array(SPREAD_ETA),
             fraction=np.array(SPREAD_FRACTIONS), radius=radius, stderr=error,
             paths=np.array(paths))
    print(f"wrote {out}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("Examples::")[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("job", choices=("compare", "spread"))
    parser.add_argument("--paths", type=int, default=1_000_000)
    parser.add_argument("--seed", type=int, default=20260)
    parser.add_argument("--out", type=Path, default=Path("bdipole_cl/data/walk_spread.npz"))
    args = parser.parse_args(argv)
    if args.job == "compare":
        compare(args.paths, args.seed)
    else:
        spread(args.paths, args.seed, args.out)


if __name__ == "__main__":
    main()
