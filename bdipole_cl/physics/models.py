"""The diffusion models (``model=``): one registry, the same names in Python, the CLI's
``--model`` and scene files' ``model`` (docs/model.md "Model").

Both have the form ``Rd = alpha'^n exp(K(q))``, q = sqrt(1 - alpha') (``physics.reference``);
what differs is n, K and where the boundary constants come from.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..vocabulary import Option, Registry


@dataclass(frozen=True)
class Model(Option):
    """One model: ``power`` n of ``Rd = alpha'^n exp(K)``; ``define``, the build option of
    kernels/bdipole.h that selects it (None: the kernels' default); ``fresnel_moments``: its
    boundary constants come from the Fresnel moments, so ``exact=True`` (quadrature moments)
    applies to it."""

    power: int = 2
    define: str | None = None
    fresnel_moments: bool = True


#: canonical names first; "better-dipole" is the scene files' historical spelling
MODEL = Registry("model", (
    Model("better", "the Better Dipole (d'Eon 2012; Hery TM 12-11, memo eqs. 1-4)",
          aliases=("better-dipole",), power=2, define=None, fresnel_moments=True),
    Model("dipole", "Jensen et al. 2001's classical dipole (Egan-Hilgeman Fdr fit)",
          power=1, define="BD_MODEL_DIPOLE", fresnel_moments=False),
))
#: the canonical model names
MODELS = MODEL.names
BETTER, DIPOLE = MODEL["better"], MODEL["dipole"]
