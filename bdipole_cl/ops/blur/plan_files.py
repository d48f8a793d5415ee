"""Blur plans kept on disk across processes (docs/stretch.md "Plans on disk"): a plan of one
set of arguments (the stretched blur's ranges, eta, tol, ...; the texture-varying blur's) is made
once per version of the code that makes it, not once per process (a 64-chart head's three
stretched plans: 15 s; a texture-varying blur at mfp 16 texels: 8 s; each read back in ~0.1 s),
so that a tile blurred by its own command, or on a cluster's fresh worker, starts warm.

Each kind of plan has a PlanFormat: its folder and its arrays both ways. A plan's file is named
by a digest of the sources of the packages plans are made by (``source_digest``: any change
there is a new name) and of its key, and holds the key itself (checked on reading: a file of
another key is not read as this one). Written as every cache file of the package (temp file,
read back and compared, durable rename), with a digest of its arrays; a file that cannot be
read as a whole plan of its key, its arrays as written, is made anew and replaced; a cache that
cannot be written is only a cache. Each folder keeps at most PLANS_MAX_BYTES, the least
recently used out first; ``bdipole-cl cache`` lists and clears them."""
from __future__ import annotations

import hashlib
import os
import re
import stat
import tempfile
import time
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable
from pathlib import Path

import numpy as np

from ...caches import user_cache_dir
from ...durable import fsync_path

#: the folders of the plans' files in the user cache folder, and their names:
#: plan-{source digest}-{key digest}.npz, and their writers' temp files (.{random}.tmp)
STRETCHED_FOLDER = "stretched-plans"
TEXTURED_FOLDER = "textured-plans"
PLANS_NAME = re.compile(r"^plan-[0-9a-f]{16}-[0-9a-f]{32}(\.npz|\.[a-z0-9_]{8}\.tmp)$")
#: a writer's temp file older than this is left over (its writer killed): pruned
STALE_TEMP_SECONDS = 3600
#: bytes of plans each folder keeps (a head's stretched plan is ~60 MB, the smooth
#: benchmark's ~20 MB; a texture-varying plan 1-10 MB)
PLANS_MAX_BYTES = 2 << 30


@dataclass(frozen=True)
class PlanFormat:
    """How one kind of plan is kept: its folder, ``arrays(plan)`` (named arrays, no object
    arrays: what ``np.savez`` writes) and ``plan(arrays)`` (the plan again, its arrays
    read-only; anything it raises is a file that is not a plan)."""

    folder: str
    arrays: Callable[[object], dict]
    plan: Callable[[dict], object]


def axes_arrays(axes) -> dict:
    """Lattice axes (``textured_plan.Axis``) as arrays: (origin, step, nodes) rows, values."""
    out = {"axes": np.array([(a.origin, a.step, len(a.values)) for a in axes], np.float64)}
    for i, a in enumerate(axes):
        out[f"axis{i}"] = np.asarray(a.values, np.float64)
    return out


def axes_of(arrays, make_axis) -> tuple:
    """The axes ``axes_arrays`` wrote, by ``make_axis(values, origin, step)``."""
    return tuple(make_axis(tuple(arrays[f"axis{i}"].tolist()), float(o), float(s))
                 for i, (o, s, _) in enumerate(arrays["axes"]))


def kernels_array(kernels, radius) -> np.ndarray:
    """A plan's (K+1)^2 kernel quadrants as one array (none: 0 of that shape)."""
    k = radius + 1
    return np.stack(kernels) if kernels else np.zeros((0, k, k))


def scalars_array(plan, names) -> np.ndarray:
    """The plan's fields ``names`` as the ``scalars`` array (``scalars_of`` reads it)."""
    return np.array([float(getattr(plan, name)) for name in names])


def scalars_of(arrays, names) -> dict:
    """The ``scalars`` array as {name: float}, ValueError where it is not one finite value a
    name."""
    values = arrays["scalars"]
    if values.shape != (len(names),) or not np.all(np.isfinite(values)):
        raise ValueError("scalars")
    return dict(zip(names, values.tolist()))


@lru_cache(maxsize=1)
def source_digest() -> str:
    """A digest of the sources of the packages a plan is made by (the blur's and the
    physics'), in path order, and of NumPy's version (its SVD's last bits): 16 hex digits."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256(f"numpy {np.__version__}\0".encode())
    for folder in ("ops/blur", "physics"):
        for path in sorted((root / folder).glob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def plan_path(fmt: PlanFormat, key: str) -> Path:
    """The file of the plan of ``key`` (the repr of its arguments)."""
    name = hashlib.sha256(key.encode()).hexdigest()[:32]
    return user_cache_dir() / fmt.folder / f"plan-{source_digest()}-{name}.npz"


def file_arrays(fmt: PlanFormat, plan, key: str) -> dict:
    """A plan's file's arrays: its key, its format's arrays, and the ``content_digest`` of
    them as ``digest``."""
    out = {"key": np.array(key), **fmt.arrays(plan)}
    out["digest"] = np.array(content_digest(out))
    return out


def content_digest(arrays) -> str:
    """A digest of named arrays (each name, dtype, shape and bytes, in name order; not the
    ``digest`` entry): a file's arrays as written, so that any array changed, cut or
    retyped since (by anything that did not also make this digest anew) is not read."""
    digest = hashlib.blake2b(digest_size=20)
    for name in sorted(n for n in arrays if n != "digest"):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


#: the members of a plan's file, as ``file_arrays`` writes them: no more, and stored (np.savez
#: does not compress; a compressed member, whose size unpacked is not the file's, is not ours)
MAX_MEMBERS = 16


def stored_within(path: Path, max_bytes: int) -> bool:
    """Whether the zip at ``path`` has at most MAX_MEMBERS members, every one stored (not
    compressed), their sizes within ``max_bytes`` in all: what reading it may take."""
    with zipfile.ZipFile(path) as z:
        infos = z.infolist()
    return (len(infos) <= MAX_MEMBERS and all(i.compress_type == zipfile.ZIP_STORED
                                              for i in infos)
            and sum(i.file_size for i in infos) <= max_bytes)


def kept_plan(fmt: PlanFormat, key: str, whole, make):
    """The plan of ``key``: its file's where that is a whole plan (``read_plan``), else
    ``make()``'s, written for the next process (``write_plan``)."""
    plan = read_plan(fmt, key, whole)
    if plan is None:
        plan = make()
        write_plan(fmt, key, plan, whole)
    return plan


def read_plan(fmt: PlanFormat, key: str, whole):
    """The plan of ``key`` from its file, or None where there is none, or it is not a whole
    plan of this key (``read_plan_at``); a file read is touched (the last to be pruned)."""
    path = plan_path(fmt, key)
    plan = read_plan_at(fmt, path, key, whole)
    if plan is not None:
        try:
            os.utime(path)
        except OSError:
            pass
    return plan


def read_plan_at(fmt: PlanFormat, path: Path, key: str, whole):
    """The plan of ``key`` in the regular file at ``path`` (rebuilt by ``fmt.plan``,
    read-only), or None where it is not one: not a regular file (a FIFO would block the
    read), not a zip of these arrays, another key, arrays not as written, or a plan
    ``whole(plan)`` finds not to be one its arguments make (shapes, lattice, radius, finite
    values)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode) or not stored_within(path, PLANS_MAX_BYTES):
            return None
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            arrays = {name: np.array(data[name]) for name in data.files}
        if str(arrays.pop("digest")) != content_digest(arrays):
            return None
        for a in arrays.values():
            a.setflags(write=False)
        plan = fmt.plan(arrays)
        return plan if whole(plan) else None
    except Exception:                  # anything a damaged file holds: not a plan
        return None


def write_plan(fmt: PlanFormat, key: str, plan, whole) -> None:
    """The plan's file: temp file, read back and compared array by array, durable rename;
    then the folder pruned to PLANS_MAX_BYTES. Nothing raised where it cannot be written."""
    path = plan_path(fmt, key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **file_arrays(fmt, plan, key))
            back = read_plan_at(fmt, Path(tmp), key, whole)
            if back is None or not same_plan(fmt, back, plan):
                return
            # not ``durable_replace``: a cache file takes no access from the file it replaces
            # (a plan file of mode 000 would make its successor unreadable, for good)
            fsync_path(tmp)
            os.replace(tmp, path)
            fsync_path(str(path.parent), directory=True)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        prune(path.parent, PLANS_MAX_BYTES)
    except OSError:
        return


def same_plan(fmt: PlanFormat, a, b) -> bool:
    """Whether two plans hold the same values: their arrays (``fmt.arrays``) of the same
    names, dtypes and shapes, bit for bit."""
    x, y = fmt.arrays(a), fmt.arrays(b)
    return x.keys() == y.keys() and all(
        x[n].dtype == y[n].dtype and x[n].shape == y[n].shape
        and np.asarray(x[n]).tobytes() == np.asarray(y[n]).tobytes() for n in x)


def prune(folder: Path, max_bytes: int) -> None:
    """The plans' files of ``folder`` beyond ``max_bytes`` removed, least recently used
    first (by modification time: a read touches its file), and writers' temp files left
    over (older than STALE_TEMP_SECONDS)."""
    files, now = [], time.time()
    for p in folder.iterdir():
        if PLANS_NAME.match(p.name) and p.is_file() and not p.is_symlink():
            try:
                st = p.stat()
                if p.suffix == ".tmp":             # a writer's: removed only when left over
                    if now - st.st_mtime > STALE_TEMP_SECONDS:
                        p.unlink()
                    continue
            except OSError:
                continue
            files.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in files)
    for _, size, p in sorted(files, key=lambda f: f[0]):
        if total <= max_bytes:
            break
        try:
            p.unlink()
            total -= size
        except OSError:
            continue
