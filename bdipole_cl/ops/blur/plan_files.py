"""Stretched plans kept on disk across processes (docs/stretch.md "Plans on disk"): a plan of
one (ranges, eta, tol, exact, max_radius, gather costs) is made once per version of the code
that makes it, not once per process (a 64-chart head's three plans: 15 s, read back in
~0.1 s), so that a tile blurred by its own command, or on a cluster's fresh worker, starts warm.

A plan's file is named by a digest of the sources of the packages plans are made by
(``source_digest``: any change there is a new name) and of its key, and holds the key itself
(checked on reading: a file of another key is not read as this one). Written as every cache
file of the package (temp file, read back and compared, durable rename), with a digest of its
arrays; a file that cannot be read as a whole plan of its key, its arrays as written, is made
anew and replaced; a cache that cannot be written is only a cache.
The folder keeps at most PLANS_MAX_BYTES, the least recently used out first; ``bdipole-cl
cache`` lists and clears it."""
from __future__ import annotations

import hashlib
import os
import re
import stat
import tempfile
import time
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from ...caches import user_cache_dir
from ...durable import fsync_path

#: the folder of the plans' files in the user cache folder, and their names:
#: plan-{source digest}-{key digest}.npz, and their writers' temp files (.{random}.tmp)
PLANS_FOLDER = "stretched-plans"
PLANS_NAME = re.compile(r"^plan-[0-9a-f]{16}-[0-9a-f]{32}(\.npz|\.[a-z0-9_]{8}\.tmp)$")
#: a writer's temp file older than this is left over (its writer killed): pruned
STALE_TEMP_SECONDS = 3600
#: bytes of plans the folder keeps (a head's plan is ~60 MB, the smooth benchmark's ~20 MB)
PLANS_MAX_BYTES = 2 << 30
#: the scalar fields of a StretchedPlan, in their file's ``scalars`` order
SCALARS = ("radius", "eta", "fit_error", "interp_error", "truncation_tol", "nodes", "near",
           "near_direct")


@lru_cache(maxsize=1)
def source_digest() -> str:
    """A digest of the sources of the packages a plan is made by (the blur's and the
    physics'), in path order: 16 hex digits."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for folder in ("ops/blur", "physics"):
        for path in sorted((root / folder).glob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def plan_path(key: str) -> Path:
    """The file of the plan of ``key`` (the repr of its arguments)."""
    name = hashlib.sha256(key.encode()).hexdigest()[:32]
    return user_cache_dir() / PLANS_FOLDER / f"plan-{source_digest()}-{name}.npz"


def plan_arrays(plan, key: str) -> dict:
    """A StretchedPlan as the arrays of its file (``np.savez``; no object arrays), with the
    ``content_digest`` of the others as ``digest``."""
    k = plan.radius + 1
    out = {"key": np.array(key), "fine": plan.fine, "near_values": plan.near_values,
           "kernels": (np.stack(plan.kernels) if plan.kernels else np.zeros((0, k, k))),
           "scalars": np.array([float(getattr(plan, f)) for f in SCALARS]),
           "axes": np.array([(a.origin, a.step, len(a.values)) for a in plan.axes])}
    for i, a in enumerate(plan.axes):
        out[f"axis{i}"] = np.asarray(a.values, np.float64)
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


#: the members of a plan's file, as ``plan_arrays`` writes them: no more, and stored (np.savez
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


def read_plan(key: str, make_axis, make_plan, whole):
    """The plan of ``key`` from its file, or None where there is none, or it is not a whole
    plan of this key (``read_plan_at``); a file read is touched (the last to be pruned)."""
    path = plan_path(key)
    plan = read_plan_at(path, key, make_axis, make_plan, whole)
    if plan is not None:
        try:
            os.utime(path)
        except OSError:
            pass
    return plan


def read_plan_at(path: Path, key: str, make_axis, make_plan, whole):
    """The plan of ``key`` in the regular file at ``path`` (``make_axis(values, origin,
    step)`` and ``make_plan(**fields)`` rebuild it, read-only), or None where it is not one:
    not a regular file (a FIFO would block the read), not a zip of these arrays, another key,
    or a plan ``whole(plan)`` finds not to be one its arguments make (shapes, lattice, radius,
    finite values)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode) or not stored_within(path, PLANS_MAX_BYTES):
            return None
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            arrays = {name: np.array(data[name]) for name in data.files}
        if str(arrays.pop("digest")) != content_digest(arrays):
            return None
        values = arrays["scalars"]
        if values.shape != (len(SCALARS),) or not np.all(np.isfinite(values)):
            return None
        scalars = dict(zip(SCALARS, values.tolist()))
        axes = tuple(make_axis(tuple(arrays[f"axis{i}"].tolist()), float(o), float(s))
                     for i, (o, s, _) in enumerate(arrays["axes"]))
        for a in arrays.values():
            a.setflags(write=False)
        plan = make_plan(axes=axes, fine=arrays["fine"], near_values=arrays["near_values"],
                         kernels=tuple(arrays["kernels"]), radius=int(scalars["radius"]),
                         nodes=int(scalars["nodes"]), near=int(scalars["near"]),
                         near_direct=bool(scalars["near_direct"]),
                         **{f: scalars[f] for f in ("eta", "fit_error", "interp_error",
                                                    "truncation_tol")})
        return plan if whole(plan) else None
    except Exception:                  # anything a damaged file holds: not a plan
        return None


def write_plan(key: str, plan, make_axis, make_plan, whole) -> None:
    """The plan's file: temp file, read back and compared field by field, durable rename;
    then the folder pruned to PLANS_MAX_BYTES. Nothing raised where it cannot be written."""
    path = plan_path(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **plan_arrays(plan, key))
            back = read_plan_at(Path(tmp), key, make_axis, make_plan, whole)
            if back is None or not same_plan(back, plan):
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


def same_plan(a, b) -> bool:
    """Whether two StretchedPlans hold the same values (arrays bit for bit)."""
    return (all(getattr(a, f) == getattr(b, f) for f in SCALARS) and a.axes == b.axes
            and len(a.kernels) == len(b.kernels)
            and all(np.array_equal(x, y) for x, y in zip(a.kernels, b.kernels))
            and np.array_equal(a.fine, b.fine) and np.array_equal(a.near_values, b.near_values))


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
