"""Inversions of device-resident arrays (the operations layer): ``InversionPlan.apply`` of
``pyopencl.array.Array`` inputs, on their device, into Arrays, so that chains (invert, then
blur) never come back to the host.

The albedos (and an mfp map) are read where they are: C-contiguous Arrays of the plan's
precision on the plan's context (a view with an offset is copied on the device first). An mfp
may also be one value or one per channel (a host value). The outputs are new Arrays on the
plan's queue, or the ``out`` Arrays given; each carries the event that writes it (pyopencl's
``Array.events``), and the inputs' events are waited for, so that work on other queues of the
context orders itself. What goes over the bus is one int: whether an input broke its rule
(tested by the float32 table kernel as it reads, else by kernels/array_ops.cl).

Where an input did break its rule, that call is done on the host instead (the inputs brought
back, ``InversionPlan.apply`` on them, the outputs sent to their Arrays): the error names the
first invalid texel as the host's does, and ``on_invalid="clamp"`` gives the host's results.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..device import build_options, get_program
from ..device.launch import enqueue_items
from ..device.transfer import is_device_array, ready_array
from .host_arrays import check_out_shapes
from .inversion_kernel import CHECK_ALBEDO, CHECK_COEFFICIENTS, MFP_MIN

#: kernels/array_ops.cl's rules (``breaks_rule``)
RULE_ALBEDO, RULE_COEFFICIENT_ALBEDO, RULE_MFP = 1, 2, 3


def shares_memory(a, b) -> bool:
    """Whether two outputs (host or device arrays) may overlap: host arrays by NumPy, device
    arrays when they are views of one buffer."""
    if is_device_array(a) or is_device_array(b):
        return (is_device_array(a) and is_device_array(b)
                and a.base_data.int_ptr == b.base_data.int_ptr)
    return bool(np.shares_memory(a, b))


def _checked_array(a, name, rt, dtype) -> cla.Array:
    """``a`` as a C-contiguous Array of ``dtype`` on ``rt``'s context (copied on the device
    when it is a view with an offset), else a ValueError naming ``name`` and what to give."""
    a = ready_array(a, rt, name)
    if a.dtype != dtype:
        raise ValueError(f"{name}: a {a.dtype} device array; this call computes in "
                         f"{np.dtype(dtype).name} (convert it on the device first, or pass "
                         f"double={dtype == np.float32})")
    return a.copy(queue=rt.queue) if a.offset else a


def _array_ops(rt, dtype, name):
    opts = build_options({"BD_MFP_MIN": repr(MFP_MIN) + ("" if dtype == np.float64 else "f")},
                         double=dtype == np.float64)
    return cl.Kernel(get_program(rt, "array_ops", opts), name)


def _broken(rt, arrays_rules, dtype, wait_for) -> bool:
    """Whether some element of an (Array, rule) pair breaks its rule (kernels/array_ops.cl),
    tested on the device: one int read back."""
    flag = np.zeros(1, np.int32)
    buf = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=flag)
    knl = _array_ops(rt, dtype, "flag_invalid")
    for a, rule in arrays_rules:
        enqueue_items(knl, rt.queue, a.size, a.data, np.uint64(a.size), np.int32(rule), buf,
                      wait_for=wait_for)
    cl.enqueue_copy(rt.queue, flag, buf)
    return bool(flag[0])


def _outputs(plan, out, shape, rt) -> dict:
    """{output: Array}: those of ``out`` ({name: array}, checked), new ones for the rest."""
    arrays = {}
    for name in plan.outputs:
        a = (out or {}).get(name)
        if a is None:
            arrays[name] = cla.empty(rt.queue, shape, plan.dtype)
            continue
        if not is_device_array(a):
            raise ValueError(f"out[{name!r}]: the inputs are device arrays, so are the outputs "
                             f"(a pyopencl.array.Array); got {type(a).__name__}")
        n = int(np.prod(shape))
        if a.size != n or a.offset or not a.flags.c_contiguous:
            raise ValueError(f"out[{name!r}]: a C-contiguous device array of {n} elements "
                             f"without an offset; got shape {a.shape}")
        arrays[name] = _checked_array(a, f"out[{name!r}]", rt, plan.dtype)
    return arrays


@dataclass(frozen=True)
class DeviceInputs:
    """The inputs of a device call that broke their rule, brought back for the host to redo:
    albedos, and the mfp (a map, one value per channel, or None)."""

    rd: np.ndarray
    mfp: object


def apply_on_device(plan, rd, mfp, mask, out):
    """``plan.apply`` of device arrays (the module docstring), ``out`` a {name: Array} dict or
    None: ({output: Array}, None), or (the output Arrays, DeviceInputs) where an input broke
    its rule and the host must redo the call (``send_to`` then fills the Arrays)."""
    rt = plan.runtime
    check_out_shapes(out, np.shape(rd))
    if mask is not None:
        raise ValueError("mask: not taken with device arrays (invert the whole array, or "
                         "give host arrays)")
    if not is_device_array(rd):
        raise ValueError("albedo: a host array with a device-array mfp; give both on the "
                         "device (pyopencl.array.to_device) or both on the host")
    rd = _checked_array(rd, "albedo", rt, plan.dtype)
    k = plan.kernel
    if k.nchan > 1 and (rd.ndim == 0 or rd.shape[-1] != k.nchan):
        raise ValueError(f"eta has {k.nchan} values but the albedos' last axis has "
                         f"{rd.shape[-1] if rd.ndim else 'no'} channels")
    mfp_map = mfp_channels = None
    if plan.mfp_kind is None:
        if mfp is not None:
            raise ValueError("this plan has no mfp (mfp_kind=None): apply(rd) only")
    elif is_device_array(mfp):
        if mfp.shape != rd.shape:
            raise ValueError(f"mfp: a device array of shape {mfp.shape} beside albedos of shape "
                             f"{rd.shape}: give one of the albedos' shape (or one value, or "
                             f"one per channel)")
        mfp_map = _checked_array(mfp, "mfp", rt, plan.dtype)
    else:
        if mfp is None and plan.mfp_const is None:
            raise ValueError("this plan needs an mfp: apply(rd, mfp)")
        try:
            mfp_channels = np.broadcast_to(np.asarray(plan.mfp_const if mfp is None else mfp,
                                                      np.float64), (k.nchan,)).copy()
        except ValueError:
            raise ValueError(f"mfp of shape {np.shape(mfp)} beside device albedos: give one "
                             f"value, one per channel, or a device array of the albedos' "
                             f"shape") from None
        if not k.width:                 # a kernel of one value per element: a map of them
            mfp_map = constant_map(rt, mfp_channels, rd.shape, plan.dtype)
            mfp_channels = None
    outs = _outputs(plan, out, rd.shape, rt)
    wait = [e for a in (rd, mfp_map, *outs.values()) if a is not None for e in a.events]
    if _run(plan, rd, mfp_map, mfp_channels, outs, wait):
        return outs, DeviceInputs(rd.get(), None if plan.mfp_kind is None else
                                  mfp_map.get() if mfp_map is not None else mfp_channels)
    return outs, None


def send_to(outs: dict, arrays: dict) -> None:
    """The host's results into the output Arrays."""
    for name, a in outs.items():
        a.set(np.ascontiguousarray(arrays[name]).reshape(a.shape))


def constant_map(rt, per_channel, shape, dtype) -> cla.Array:
    """A device array of ``shape`` holding ``per_channel`` along its last axis."""
    return cla.to_device(rt.queue, np.ascontiguousarray(np.broadcast_to(
        np.asarray(per_channel).astype(dtype), shape)))


def _run(plan, rd, mfp_map, mfp_channels, outs, wait) -> bool:
    """The plan's kernel over the arrays, the extinction division and sigma_t's sum after it;
    whether an input broke its rule (then the outputs are not the answer)."""
    rt, k, n = plan.runtime, plan.kernel, rd.size
    coefficients = plan.mfp_kind is not None
    if mfp_channels is not None and not np.all((mfp_channels >= MFP_MIN)
                                               & np.isfinite(mfp_channels)):
        return True
    in_kernel = bool(k.width)            # the float32 table tests what it reads
    rules = [] if in_kernel else [(rd, RULE_COEFFICIENT_ALBEDO if coefficients
                                   else RULE_ALBEDO)]
    if mfp_map is not None and (plan.extinction or not in_kernel):    # read by no kernel
        rules.append((mfp_map, RULE_MFP))
    if rules and _broken(rt, rules, plan.dtype, wait):
        return True
    reads_mfp = coefficients and not plan.extinction
    scratch = {name: (outs[name] if name in outs else cla.empty(rt.queue, rd.shape, plan.dtype))
               for name in plan.kernel_outputs}
    check = 0 if not in_kernel else CHECK_COEFFICIENTS if coefficients else CHECK_ALBEDO
    event, flagged = k.run_buffers(
        n, rd.data, mfp_map.data if reads_mfp and mfp_map is not None else None,
        {name: a.data for name, a in scratch.items()}, check=check,
        mfp_channels=mfp_channels if reads_mfp and mfp_map is None else None,
        wait_for=wait or None)
    if flagged:
        return True
    if plan.extinction:
        event = _extinction(plan, scratch, outs, mfp_map, mfp_channels, rd.shape, event)
    if "sigma_t" in plan.outputs:
        event = enqueue_items(_array_ops(rt, plan.dtype, "add"), rt.queue, n,
                              outs["sigma_t"].data, scratch["sigma_a"].data,
                              scratch["sigma_s"].data, np.uint64(n), wait_for=[event])
    for a in outs.values():
        a.add_event(event)
    return False


def _extinction(plan, scratch, outs, mfp_map, mfp_channels, shape, event):
    """sigma_a = rho / mfp and sigma_s' = alpha' / mfp (docs/model.md "Mean free path")."""
    rt, n = plan.runtime, int(np.prod(shape))
    if mfp_map is None:
        mfp_map = constant_map(rt, mfp_channels, shape, plan.dtype)
    wanted = set(plan.outputs) | ({"sigma_a", "sigma_s"} if "sigma_t" in plan.outputs
                                  else set())
    divide = _array_ops(rt, plan.dtype, "divide")
    for sigma, base in (("sigma_a", "rho"), ("sigma_s", "alpha")):
        if sigma in wanted:
            scratch[sigma] = (outs[sigma] if sigma in outs
                              else cla.empty(rt.queue, shape, plan.dtype))
            event = enqueue_items(divide, rt.queue, n, scratch[sigma].data,
                                  scratch[base].data, mfp_map.data, np.uint64(n),
                                  wait_for=[event])
    return event
