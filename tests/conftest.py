import numpy as np
import pytest

import bdipole_cl
from bdipole_cl import reference as ref

#: float32 unit roundoff (half an ulp of 1); tolerances below are multiples of it.
EPS32 = 2.0**-24
EPS64 = 2.0**-53


@pytest.fixture(scope="session")
def runtime():
    return bdipole_cl.get_runtime()


@pytest.fixture(scope="session")
def has_fp64(runtime):
    return runtime.has_fp64


def f32(x):
    """Round to float32 and back, so the float64 reference sees exactly the kernel's input."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def stiff_albedos(n=2000):
    """Rd sweeping both stiff ends geometrically plus the middle, as float32 values."""
    return f32(np.concatenate([np.geomspace(1e-6, 0.5, n), 1.0 - np.geomspace(1e-3, 0.5, n),
                               np.linspace(1e-6, 0.999, n)]))


def rel_err(got, want):
    got = np.asarray(got, np.float64)
    want = np.asarray(want, np.float64)
    return np.abs(got - want) / np.abs(want)


__all__ = ["EPS32", "EPS64", "f32", "stiff_albedos", "rel_err", "ref"]
