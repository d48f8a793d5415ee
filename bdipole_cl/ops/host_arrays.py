"""How an inversion's host arrays relate (the operations layer): an mfp's broadcasting against
the albedos, the ``out`` arrays' shapes, and their overlap with the inputs."""
from __future__ import annotations

import numpy as np


def texel_broadcast(rd, mfp):
    """(rd, mfp) for broadcasting: an mfp map shaped as rd without its last axis (an HxW map
    beside HxWxC albedos) is one value per texel, for every channel (as a mask is), also
    where NumPy would broadcast it otherwise (a map 3 texels wide beside RGB albedos); else
    NumPy's rule (one value, one per channel, rd's shape; a 1-D mfp beside 2-D albedos whose
    last axis matches it is one per channel, as a tuple is)."""
    try:
        np.broadcast_shapes(rd.shape, mfp.shape)
        broadcasts = True
    except ValueError:
        broadcasts = False
    if rd.ndim >= 2 and mfp.shape == rd.shape[:-1] and (mfp.ndim >= 2 or not broadcasts):
        return rd, mfp[..., None]
    if not broadcasts:
        raise ValueError(f"mfp of shape {mfp.shape} does not fit albedo of shape {rd.shape}: "
                         f"give one value, one per channel, an albedo-shaped map, or one map "
                         f"of shape {rd.shape[:-1]} for every channel")
    return rd, mfp


def check_out_shapes(out, shape):
    """Each ``out`` array ({name: array}) shaped as the input (``shape``) or flat: one of the
    input's size in another shape (a transposed image, say) would be filled in the input's
    layout, which is not what its shape says (a ValueError naming it; another size is
    ``inversion_kernel.output_array``'s to name)."""
    for name, a in (out or {}).items():
        if (getattr(a, "ndim", 1) != 1 and tuple(a.shape) != tuple(shape)
                and a.size == int(np.prod(shape))):        # host and device arrays alike
            raise ValueError(f"out[{name!r}]: shape {a.shape} is not the input's "
                             f"{tuple(shape)} (give it the input's shape, or a flat array of "
                             f"its size)")


def apart_from(out, rd, mfp, mfp_after=False):
    """(rd, mfp), each copied where an ``out`` array overlaps it other than as the very same
    elements (out=rd is safe: each element is read before it is written; a shifted view is
    not, as the kernel would read texels it has already overwritten). ``mfp_after``: the host
    reads the mfp again after the kernel has written (an extinction mfp's division), so an
    output on any of its memory, the very same elements too, copies it."""
    def same(a, b):
        return (a.__array_interface__["data"][0] == b.__array_interface__["data"][0]
                and a.strides == b.strides and a.size == b.size)
    for arr in (out or {}).values():
        arr = np.asarray(arr)
        if np.may_share_memory(arr, rd) and not same(arr, rd):
            rd = rd.copy()
        if mfp is not None and np.may_share_memory(arr, mfp) and (mfp_after
                                                                  or not same(arr, mfp)):
            mfp = mfp.copy()
    return rd, mfp


def channel_values(values, nchan):
    """``values`` (broadcast to the input's shape) as one float per channel when it holds no
    more than that (a scalar or a per-channel tuple broadcast: zero strides), else None."""
    v = np.asarray(values)
    if v.ndim == 0 or all(st == 0 for st in v.strides):
        return np.full(nchan, v.reshape(-1)[0] if v.size else 0.0, np.float64)
    if any(st != 0 for st in v.strides[:-1]) or v.shape[-1] != nchan:
        return None
    return np.array(v[(0,) * (v.ndim - 1)], np.float64)


def shared_channels(rd, mfp) -> int:
    """How many channels each value of ``mfp`` serves (``texel_broadcast``'s operands): C for
    a map of one value per texel beside C-channel albedos, else 1 (a map of rd's shape; one
    value, or one per channel, is a constant, not a map)."""
    if mfp.ndim == rd.ndim >= 2 and mfp.shape[-1] == 1 < rd.shape[-1] and mfp.size > 1:
        return rd.shape[-1]
    return 1
