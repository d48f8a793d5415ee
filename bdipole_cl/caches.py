"""Caches bounded in bytes, and ``clear_caches()`` for all of them (the foundation layer).

Every cache of the package is a ``ByteCache``: least recently used out once its entries' bytes
pass ``max_bytes`` (arrays count their ``nbytes``; tuples, lists, dicts and dataclasses the sum of
their parts). ``clear_caches()`` empties every one (the device layer's compiled programs among
them)."""
from __future__ import annotations

import dataclasses
import functools
import os
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

_caches: list = []

#: the folder of this user's files that outlive a process (calibrations, the OpenCL runtime
#: registrations): it overrides $XDG_CACHE_HOME/bdipole_cl (tests set it)
CACHE_DIR_VARIABLE = "BDIPOLE_CL_CACHE_DIR"


def cache_home() -> Path:
    """$XDG_CACHE_HOME, else ~/.cache (as pyopencl, pytools and bdipole_cl read it)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")


def user_cache_dir() -> Path:
    """$BDIPOLE_CL_CACHE_DIR, $XDG_CACHE_HOME/bdipole_cl or ~/.cache/bdipole_cl."""
    named = os.environ.get(CACHE_DIR_VARIABLE)
    if named:
        return Path(named)
    return cache_home() / "bdipole_cl"


def nbytes_of(value) -> int:
    """Approximate memory of a cached value: arrays exactly, containers by their parts."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return 64 + sum(nbytes_of(getattr(value, f.name)) for f in dataclasses.fields(value))
    if isinstance(value, (tuple, list)):
        return 56 + sum(nbytes_of(v) for v in value)
    if isinstance(value, dict):
        return 64 + sum(nbytes_of(k) + nbytes_of(v) for k, v in value.items())
    return 32


class ByteCache:
    """A thread-safe LRU cache bounded in bytes; ``memoize`` wraps a function with it."""

    def __init__(self, name: str, max_bytes: int):
        self.name, self.max_bytes = name, int(max_bytes)
        self._data: OrderedDict = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        _caches.append(self)

    @property
    def nbytes(self) -> int:
        return self._bytes

    def __len__(self):
        return len(self._data)

    def get(self, key, default=None):
        with self._lock:
            hit = self._data.get(key)
            if hit is None:
                return default
            self._data.move_to_end(key)
            return hit[0]

    def put(self, key, value, nbytes=None):
        size = nbytes_of(value) if nbytes is None else int(nbytes)
        if size > self.max_bytes:
            return value                    # larger than the whole budget: not kept
        with self._lock:
            old = self._data.pop(key, None)
            if old is not None:
                self._bytes -= old[1]
            self._data[key] = (value, size)
            self._bytes += size
            while self._bytes > self.max_bytes:
                _, (_, freed) = self._data.popitem(last=False)
                self._bytes -= freed
        return value

    def clear(self):
        with self._lock:
            self._data.clear()
            self._bytes = 0

    def memoize(self, fn):
        """Cache ``fn``'s results by its arguments (hashable), like functools.lru_cache."""
        missing = object()

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            key = (args, tuple(sorted(kwargs.items()))) if kwargs else args
            hit = self.get(key, missing)
            if hit is not missing:
                return hit
            return self.put(key, fn(*args, **kwargs))
        wrapper.cache = self
        return wrapper


def all_caches() -> list:
    return list(_caches)


def clear_caches():
    """Empty every cache of the package (kernels, tables, plans, spectra, programs)."""
    for cache in _caches:
        cache.clear()
