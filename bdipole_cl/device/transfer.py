"""Host arrays in and out of element-wise kernels, with as little copying as the device allows
(the device layer).

``run_elementwise`` runs a kernel over 1-D host arrays (inputs read, outputs written) in chunks:

- on a device that shares host memory (a CPU device, or one reporting host-unified memory) the
  arrays themselves become the buffers (``CL_MEM_USE_HOST_PTR``): no copy in or out, only a map
  of each output afterwards, which synchronises it and costs nothing when the runtime used the
  pointer directly (outputs from ``aligned_empty`` are aligned for that);
- on a discrete device (a GPU) each chunk goes through pinned host staging buffers
  (``CL_MEM_ALLOC_HOST_PTR``, mapped once) into device buffers, both kept across calls in
  ``DEVICE_BUFFERS`` (bounded in bytes), so repeated calls allocate no device memory.
"""
from __future__ import annotations

import threading

import numpy as np
import pyopencl as cl

from ..caches import ByteCache
from .runtime import Runtime, device_kind

#: alignment of outputs (bytes): a cache line and more than any runtime here asks for zero copy
ALIGNMENT = 4096
#: elements per launch on a discrete device (bounds its memory and the staging buffers)
DEVICE_CHUNK = 1 << 22
#: device and pinned staging buffers kept across calls (discrete devices), least recent out
DEVICE_BUFFERS = ByteCache("device buffers", 1 << 30)
_lock = threading.Lock()


def shares_host_memory(rt: Runtime) -> bool:
    """Whether ``rt``'s device works in host memory (a CPU device, or host-unified memory):
    then host arrays are used as buffers directly."""
    if device_kind(rt.device) == "cpu":
        return True
    try:
        return bool(rt.device.host_unified_memory)
    except (cl.LogicError, AttributeError):      # removed from OpenCL 3.0 headers' devices
        return False


def aligned_empty(n: int, dtype) -> np.ndarray:
    """An uninitialised 1-D array of ``n`` elements starting on an ALIGNMENT boundary."""
    dtype = np.dtype(dtype)
    raw = np.empty(n * dtype.itemsize + ALIGNMENT, np.uint8)
    start = -raw.ctypes.data % ALIGNMENT
    return raw[start:start + n * dtype.itemsize].view(dtype)


def _max_chunk(rt: Runtime, itemsize: int) -> int:
    """Elements per launch in host memory: the device's largest allocation, a multiple of 1024
    elements (which keeps every chunk of an aligned array aligned)."""
    return max(1024, min(int(rt.device.max_mem_alloc_size) // itemsize, 1 << 28) // 1024 * 1024)


def _cached(rt: Runtime, role: str, nbytes: int, flags):
    """A buffer of ``nbytes`` for ``role`` on ``rt``, kept across calls; pinned staging buffers
    (ALLOC_HOST_PTR) come with their host view, mapped once."""
    key = (id(rt.context), role, nbytes)
    hit = DEVICE_BUFFERS.get(key)
    if hit is None:
        buf = cl.Buffer(rt.context, flags, nbytes)
        view = None
        if flags & cl.mem_flags.ALLOC_HOST_PTR:
            view, _ = cl.enqueue_map_buffer(rt.queue, buf, cl.map_flags.READ | cl.map_flags.WRITE,
                                            0, (nbytes,), np.uint8, is_blocking=True)
        hit = DEVICE_BUFFERS.put(key, (rt.context, buf, view), nbytes * (2 if view is None else 1))
    return hit[1], hit[2]


def run_elementwise(rt: Runtime, launch, inputs: dict, outputs: dict, multiple: int = 1):
    """``launch(n, {name: buffer})`` (enqueues a kernel over ``n`` elements, returns its event)
    over the 1-D arrays ``inputs`` (read) and ``outputs`` (written), equal lengths, in chunks
    of a multiple of ``multiple`` elements (a channel count). Returns when the outputs hold
    the results."""
    arrays = {**inputs, **outputs}
    n = next(iter(arrays.values())).size
    itemsize = max(a.itemsize for a in arrays.values())
    if n == 0:
        return
    if shares_host_memory(rt):
        _run_in_host_memory(rt, launch, inputs, outputs, n, itemsize, multiple)
    else:
        _run_staged(rt, launch, inputs, outputs, n, itemsize, multiple)


def _run_in_host_memory(rt, launch, inputs, outputs, n, itemsize, multiple):
    mf = cl.mem_flags
    chunk = _max_chunk(rt, itemsize) // multiple * multiple
    for start in range(0, n, chunk):
        stop = min(start + chunk, n)
        bufs = {k: cl.Buffer(rt.context, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=a[start:stop])
                for k, a in inputs.items()}
        bufs.update({k: cl.Buffer(rt.context, mf.WRITE_ONLY | mf.USE_HOST_PTR,
                                  hostbuf=a[start:stop]) for k, a in outputs.items()})
        event = launch(stop - start, bufs)
        for k in outputs:                 # the map makes the host array current (zero copy:
            mapped, _ = cl.enqueue_map_buffer(    # nothing moves)
                rt.queue, bufs[k], cl.map_flags.READ, 0, (stop - start,),
                outputs[k].dtype, wait_for=[event], is_blocking=True)
            mapped.base.release(rt.queue)
        for b in bufs.values():
            b.release()
    rt.queue.finish()


def _run_staged(rt, launch, inputs, outputs, n, itemsize, multiple):
    mf = cl.mem_flags
    chunk = DEVICE_CHUNK // multiple * multiple
    nbytes = min(chunk, n) * itemsize
    with _lock:                           # one caller at a time uses the cached buffers
        bufs, stage = {}, {}
        for k in (*inputs, *outputs):
            flags = mf.READ_ONLY if k in inputs else mf.WRITE_ONLY
            bufs[k] = _cached(rt, f"device {k}", nbytes, flags)[0]
            stage[k] = _cached(rt, f"pinned {k}", nbytes, mf.READ_WRITE | mf.ALLOC_HOST_PTR)[1]
        for start in range(0, n, chunk):
            stop = min(start + chunk, n)
            for k, a in inputs.items():   # host -> pinned -> device (DMA from pinned memory)
                view = stage[k][:(stop - start) * a.itemsize].view(a.dtype)
                np.copyto(view, a[start:stop])
                cl.enqueue_copy(rt.queue, bufs[k], view)
            launch(stop - start, bufs)
            for k, a in outputs.items():
                view = stage[k][:(stop - start) * a.itemsize].view(a.dtype)
                cl.enqueue_copy(rt.queue, view, bufs[k])
                rt.queue.finish()
                a[start:stop] = view
        rt.queue.finish()
