"""Host arrays in and out of element-wise kernels, with as little copying as the device allows
(the device layer).

``run_elementwise`` runs a kernel over 1-D host arrays (inputs read, outputs written) in chunks:

- on a device that shares host memory (a CPU device, or one reporting host-unified memory) the
  arrays themselves become the buffers (``CL_MEM_USE_HOST_PTR``): no copy in or out, only a map
  of each output afterwards, which synchronises it and costs nothing when the runtime used the
  pointer directly. A runtime uses a pointer in place only when it is aligned to the device's
  base address alignment (``CL_DEVICE_MEM_BASE_ADDR_ALIGN``, 128 bytes on the CPU runtimes
  here), else it copies the whole array: NumPy's arrays start 16 bytes past a page, so the
  first few elements (``aligned_head``) of the inputs go in a launch of their own and the rest
  starts on the boundary (outputs made for an input, ``aligned_empty(..., like=input)``, share
  its offset from it);
- on a discrete device (a GPU) each chunk goes through pinned host staging buffers
  (``CL_MEM_ALLOC_HOST_PTR``, mapped once: the bus moves 55 GB/s each way from pinned memory,
  9.6 from pageable, on the H200 measured) into device buffers, both kept across calls in
  ``DEVICE_BUFFERS`` (bounded in bytes), so repeated calls allocate no device memory. The
  chunks run as a pipeline (``_run_staged``): one uploading, one in the kernel, one
  downloading, on three queues ordered by events, the host's copies into and out of pinned
  memory on several threads.
"""
from __future__ import annotations

import functools
import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

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


def aligned_empty(n: int, dtype, like: np.ndarray | None = None) -> np.ndarray:
    """An uninitialised 1-D array of ``n`` elements starting on an ALIGNMENT boundary, or with
    ``like``'s offset from one (so that both reach a boundary after the same elements)."""
    dtype = np.dtype(dtype)
    raw = np.empty(n * dtype.itemsize + ALIGNMENT, np.uint8)
    start = (-raw.ctypes.data + (0 if like is None else like.ctypes.data)) % ALIGNMENT
    return raw[start:start + n * dtype.itemsize].view(dtype)


def base_alignment(rt: Runtime) -> int:
    """Bytes a host pointer must be aligned to for ``rt``'s device to use it in place."""
    return max(1, int(rt.device.mem_base_addr_align) // 8)


def aligned_head(array: np.ndarray, alignment: int, multiple: int = 1) -> int:
    """Elements of the 1-D ``array`` before the first one on an ``alignment``-byte boundary,
    a multiple of ``multiple`` (the channel count, so the rest starts on channel 0): 0 when it
    is aligned, too short, or no such count exists (elements not aligned to their size)."""
    itemsize, address = array.itemsize, array.ctypes.data
    for head in range(0, multiple * alignment // itemsize + 1, multiple):
        if (address + head * itemsize) % alignment == 0:
            return head if head < array.size else 0
    return 0


#: elements per step of a chunk in host memory: 1024 keeps every chunk of an aligned array
#: aligned (4 KiB of float32)
ALIGNED_ELEMENTS = 1024


def _max_chunk(rt: Runtime, itemsize: int) -> int:
    """Elements per launch in host memory: the device's largest allocation, a multiple of
    ALIGNED_ELEMENTS."""
    return max(ALIGNED_ELEMENTS, min(int(rt.device.max_mem_alloc_size) // itemsize, 1 << 28)
               // ALIGNED_ELEMENTS * ALIGNED_ELEMENTS)


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


def run_elementwise(rt: Runtime, launch, inputs: dict, outputs: dict, multiple: int = 1,
                    nchan: int | None = None):
    """``launch(n, {name: buffer}, wait_for=None)`` (enqueues a kernel over ``n`` elements after
    the events ``wait_for``, returns its event)
    over the 1-D arrays ``inputs`` (read) and ``outputs`` (written), equal lengths, in chunks
    that start on a multiple of ``nchan`` (the channel count; default ``multiple``) and are
    multiples of ``multiple`` (but the first and the last). Returns when the outputs hold the
    results."""
    arrays = {**inputs, **outputs}
    n = next(iter(arrays.values())).size
    itemsize = max(a.itemsize for a in arrays.values())
    if n == 0:
        return
    if shares_host_memory(rt):
        _run_in_host_memory(rt, launch, inputs, outputs, n, itemsize, multiple,
                            multiple if nchan is None else nchan)
    else:
        _run_staged(rt, launch, inputs, outputs, n, itemsize, multiple)


def _host_chunks(rt, inputs, n, itemsize, multiple, nchan):
    """(start, stop) of each launch in host memory: a head of elements, then chunks of a
    multiple of ``multiple`` from there on. The head is the one after which most ``inputs``
    are aligned (the fewest elements of those that tie). Inputs only: a runtime copies an
    unaligned input whole when the buffer is made (Intel's CPU runtime: 130 ms for 128 MiB
    on this project's 2-core machine), where an unaligned output cost nothing measurable."""
    alignment = base_alignment(rt)
    heads = [aligned_head(a, alignment, nchan) for a in inputs] or [0]
    head = min(heads, key=lambda h: (-heads.count(h), h))
    # a multiple of both ``multiple`` and 1024 elements, so every chunk starts aligned as the
    # first (a 3-channel width-16 kernel's 48 alone moved the second chunk off alignment)
    step = math.lcm(multiple, ALIGNED_ELEMENTS)
    chunk = max(step, _max_chunk(rt, itemsize) // step * step)
    return ([(0, head)] if head else []) + [(start, min(start + chunk, n))
                                            for start in range(head, n, chunk)]


def _run_in_host_memory(rt, launch, inputs, outputs, n, itemsize, multiple, nchan):
    mf = cl.mem_flags
    for start, stop in _host_chunks(rt, list(inputs.values()), n, itemsize, multiple, nchan):
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


#: chunks in flight on a discrete device: one uploading, one in the kernel, one downloading
STAGES = 3
#: host threads copying between the user's arrays and the pinned staging buffers: one host
#: thread moves ~10 GB/s, the bus 55 GB/s each way from pinned memory (docs/runtimes.md)
COPY_THREADS = max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                          else os.cpu_count() or 1))
#: bytes below which a host copy runs in one thread (a thread's start costs more)
THREADED_COPY_BYTES = 1 << 20


@functools.lru_cache(maxsize=1)
def _copy_threads():
    return ThreadPoolExecutor(COPY_THREADS, thread_name_prefix="bdipole-stage")


def parallel_copy(dst: np.ndarray, src: np.ndarray) -> None:
    """dst[...] = src (1-D, equal sizes) in pieces on the copy threads (NumPy releases the
    GIL in copies)."""
    if dst.nbytes < THREADED_COPY_BYTES or COPY_THREADS == 1:
        np.copyto(dst, src)
        return
    edges = np.linspace(0, dst.size, COPY_THREADS + 1).astype(int)
    list(_copy_threads().map(lambda ab: np.copyto(dst[ab[0]:ab[1]], src[ab[0]:ab[1]]),
                             zip(edges[:-1], edges[1:])))


@dataclass
class _Slot:
    """One stage of the pipeline: its device and pinned buffers, and the chunk in it (the
    download's event and where its outputs go)."""

    device: dict
    pinned: dict
    pending: tuple | None = None          # (download events, start, stop)


def _staging_queues(rt: Runtime):
    """(upload, download) queues beside ``rt``'s own (kernels): separate in-order queues, so
    that a chunk's upload, another's kernel and a third's download overlap (one per context)."""
    key = (id(rt.context), "queues")
    hit = DEVICE_BUFFERS.get(key)
    if hit is None or hit[0] is not rt.context:
        hit = DEVICE_BUFFERS.put(key, (rt.context, (cl.CommandQueue(rt.context, rt.device),
                                                    cl.CommandQueue(rt.context, rt.device))), 0)
    return hit[1]


def _run_staged(rt, launch, inputs, outputs, n, itemsize, multiple):
    """Chunks through pinned staging buffers in a pipeline of STAGES: chunk i's upload (host
    copy into pinned memory, then DMA), chunk i - 1's kernel and chunk i - 2's download run
    at once, each on its own queue, ordered by events; buffers kept across calls."""
    mf = cl.mem_flags
    chunk = max(multiple, DEVICE_CHUNK // multiple * multiple)
    count = min(chunk, n)
    up, down = _staging_queues(rt)
    with _lock:                           # one caller at a time uses the cached buffers
        slots = []
        for s in range(min(STAGES, -(-n // chunk))):
            device, pinned = {}, {}
            for k, a in (*inputs.items(), *outputs.items()):
                nbytes = count * a.itemsize
                flags = mf.READ_ONLY if k in inputs else mf.WRITE_ONLY
                device[k] = _cached(rt, f"device {k} {s}", nbytes, flags)[0]
                pinned[k] = _cached(rt, f"pinned {k} {s}", nbytes,
                                    mf.READ_WRITE | mf.ALLOC_HOST_PTR)[1][:nbytes].view(a.dtype)
            slots.append(_Slot(device, pinned))
        try:
            for i, start in enumerate(range(0, n, chunk)):
                stop = min(start + chunk, n)
                slot = slots[i % len(slots)]
                _drain(slot, outputs)         # its last chunk's outputs out, its buffers free
                uploads = []
                for k, a in inputs.items():
                    view = slot.pinned[k][:stop - start]
                    parallel_copy(view, a[start:stop])
                    uploads.append(cl.enqueue_copy(up, slot.device[k], view, is_blocking=False))
                done = launch(stop - start, slot.device, wait_for=uploads)
                slot.pending = ([cl.enqueue_copy(down, slot.pinned[k][:stop - start],
                                                 slot.device[k], wait_for=[done],
                                                 is_blocking=False) for k in outputs],
                                start, stop)
                up.flush()
                rt.queue.flush()
                down.flush()
            for slot in slots:
                _drain(slot, outputs)
        finally:                              # an error: nothing left reading the buffers
            for q in (up, rt.queue, down):
                q.finish()


def _drain(slot: _Slot, outputs: dict) -> None:
    """Wait for the slot's chunk to come down and copy it into the outputs."""
    if slot.pending is None:
        return
    events, start, stop = slot.pending
    cl.wait_for_events(events)
    for k, a in outputs.items():
        parallel_copy(a[start:stop], slot.pinned[k][:stop - start])
    slot.pending = None


# {{{ whole arrays on the device (the blur's images)

def is_device_array(value) -> bool:
    """Whether ``value`` is a device-resident array (``pyopencl.array.Array``)."""
    import pyopencl.array as cla
    return isinstance(value, cla.Array)


def ready_array(a, rt: Runtime, name: str):
    """A caller's device array ``a`` checked and ordered for ``rt``'s queue: on ``rt``'s
    context and C-contiguous (else a ValueError naming ``name`` and what to give), bound to
    ``rt``'s queue where it has none, and after everything enqueued so far on a queue of its
    own (a marker there joins its events: pyopencl records in ``Array.events`` only what its
    own operations enqueue, so a user's kernel writing it may be in no event)."""
    if a.context != rt.context:
        raise ValueError(f"{name}: a device array of another OpenCL context than the one this "
                         f"call runs on ({rt.describe()}): pass device= its runtime, or arrays "
                         f"made on it")
    if not a.flags.c_contiguous:
        raise ValueError(f"{name}: a strided device array view; give a C-contiguous one "
                         f"(its .copy())")
    if a.queue is None:
        return a.with_queue(rt.queue)
    if a.queue != rt.queue:
        a.add_event(cl.enqueue_marker(a.queue))
        a.queue.flush()                 # submitted, so that rt's queue can wait for it
    return a


def device_image(rt: Runtime, host: np.ndarray):
    """``host`` (C-contiguous) as a ``pyopencl.array.Array`` on ``rt``: the host memory itself
    where the device shares it and it is aligned (``CL_MEM_USE_HOST_PTR``: no copy), else a
    device buffer filled through a pinned staging buffer (kept across calls)."""
    import pyopencl.array as cla
    mf = cl.mem_flags
    if shares_host_memory(rt) and host.ctypes.data % base_alignment(rt) == 0:
        buf = cl.Buffer(rt.context, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=host)
        return cla.Array(rt.queue, host.shape, host.dtype, data=buf)
    out = cla.empty(rt.queue, host.shape, host.dtype)
    if shares_host_memory(rt):
        cl.enqueue_copy(rt.queue, out.data, host, is_blocking=False)
        return out
    with _lock:
        pinned = _cached(rt, "pinned upload", host.nbytes,
                         mf.READ_WRITE | mf.ALLOC_HOST_PTR)[1].view(host.dtype)
        parallel_copy(pinned, host.reshape(-1))
        cl.enqueue_copy(rt.queue, out.data, pinned).wait()
    return out


def host_copy(rt: Runtime, array, out: np.ndarray) -> np.ndarray:
    """``out`` (C-contiguous, the array's size and dtype) holding the device array ``array``:
    through a pinned staging buffer on a discrete device (kept across calls), a plain read
    where the device shares host memory (a map where ``out`` is the array's own memory)."""
    if shares_host_memory(rt) or out.nbytes == 0:
        if array.base_data.flags & cl.mem_flags.USE_HOST_PTR and array.offset == 0:
            mapped, _ = cl.enqueue_map_buffer(rt.queue, array.base_data, cl.map_flags.READ, 0,
                                              out.shape, out.dtype, wait_for=array.events,
                                              is_blocking=True)
            if mapped.ctypes.data != out.ctypes.data:
                np.copyto(out, mapped)
            mapped.base.release(rt.queue)
            rt.queue.finish()
            return out
        cl.enqueue_copy(rt.queue, out, array.base_data, src_offset=array.offset,
                        wait_for=array.events)
        return out
    with _lock:
        pinned = _cached(rt, "pinned download", out.nbytes,
                         cl.mem_flags.READ_WRITE | cl.mem_flags.ALLOC_HOST_PTR)[1]
        view = pinned.view(out.dtype)
        cl.enqueue_copy(rt.queue, view, array.base_data, src_offset=array.offset,
                        wait_for=array.events)
        parallel_copy(out.reshape(-1), view)
    return out

# }}}
