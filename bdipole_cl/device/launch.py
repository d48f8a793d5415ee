"""One-dimensional kernel launches over any number of work-items, at full speed.

With no local size, a runtime picks a work-group size that divides the launch's, so for a
prime count of work-items it can only pick 1; Intel's CPU runtime, which vectorises a kernel
across a group's work-items, then ran the one-element inversion kernel 11x slower (32M - 39
texels against 32M). So a launch is split: the largest multiple of LAUNCH_MULTIPLE, then the
rest, its work-items numbered on from there (``global_offset``)."""
from __future__ import annotations

#: work-items per launch are a multiple of this, the rest in a launch of their own
LAUNCH_MULTIPLE = 1024


def launch_ranges(items):
    """(first work-item, count) of the launches over ``items`` work-items."""
    bulk = items - items % LAUNCH_MULTIPLE
    return [r for r in ((0, bulk), (bulk, items - bulk)) if r[1]]


def enqueue_items(kernel, queue, items, *args, wait_for=None):
    """``kernel(*args)`` over work-items 0 .. items - 1 (get_global_id(0)) on the in-order
    ``queue``, in ``launch_ranges``; returns the last launch's event (None for no items)."""
    event = None
    for first, count in launch_ranges(items):
        event = kernel(queue, (count,), None, *args, global_offset=(first,),
                       wait_for=wait_for if first == 0 else None)
    return event
