"""Stretched plans on disk (bdipole_cl/ops/blur/plan_files.py; docs/stretch.md "Plans on
disk"): made once per version of the code, read back in another process bit for bit, never
read for another key or another version of the code, made anew where a file is damaged, and
never in the way where the cache folder cannot be written."""
import subprocess
import sys

import numpy as np
import pytest

from bdipole_cl.ops.blur import plan_files as pf
from bdipole_cl.ops.blur import stretched_plan as sp
from plan_file_helpers import counted_plans, set_at
from plan_file_helpers import rewritten as rewritten_as

#: a small plan's ranges (logit Rd, ln l, s): one aspect, a few nodes, planned in ~0.3 s
RANGES = ((0.2, 0.9), (0.9, 1.2), (0.1, 0.1))


@pytest.fixture
def plans(tmp_path, monkeypatch):
    """The plans' folder in a fresh cache folder, the in-memory plans cleared, and a list
    that gets an entry each time a plan is made (not read)."""
    yield counted_plans(tmp_path, monkeypatch, sp, "make_stretched_plan", sp.STRETCHED_PLANS,
                        pf.STRETCHED_FOLDER)
    sp.STRETCHED_PLANS.clear()


def plan_again():
    sp.STRETCHED_PLANS.clear()
    return sp.stretched_plan(RANGES, 1.4, 1e-3)


def test_a_plan_is_made_once_and_read_back_in_another_process(plans):
    folder, made = plans
    first = sp.stretched_plan(RANGES, 1.4, 1e-3)
    files = sorted(folder.iterdir())
    assert len(made) == 1 and len(files) == 1 and pf.PLANS_NAME.match(files[0].name)
    again = plan_again()
    assert len(made) == 1 and again is not first and pf.same_plan(sp.PLAN_FORMAT, again, first)
    assert not again.fine.flags.writeable
    script = ("import sys\nfrom bdipole_cl.ops.blur import stretched_plan as sp\n"
              "sp.make_stretched_plan = None  # a plan made here would fail\n"
              f"p = sp.stretched_plan({RANGES!r}, 1.4, 1e-3)\n"
              "print(len(p.kernels), p.near, float(p.fine.sum()).hex())")
    env_run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                             env={**__import__("os").environ}, timeout=120)
    assert env_run.returncode == 0, env_run.stderr[-2000:]
    assert env_run.stdout.split() == [str(len(first.kernels)), str(first.near),
                                      float(first.fine.sum()).hex()]


def test_another_key_or_version_of_the_code_is_not_read(plans, monkeypatch):
    """A plan of another tol is a file of its own; a file holding another key under this
    key's name is not read as this one (made anew, and replaced); a plan made by other sources
    of the blur or the physics is a file of its own."""
    folder, made = plans
    sp.stretched_plan(RANGES, 1.4, 1e-3)
    sp.stretched_plan(RANGES, 1.4, 2e-3)
    assert len(made) == 2 and len(list(folder.iterdir())) == 2

    def path(tol):
        return pf.plan_path(sp.PLAN_FORMAT, repr(("stretched", RANGES, 1.4, tol, False, 2048,
                                                  sp.DEFAULT_GATHER_COSTS, sp.NEAR_RADII)))
    assert path(1e-3).exists() and path(2e-3).exists()
    path(2e-3).replace(path(1e-3))     # another key's plan under this key's name
    assert plan_again().truncation_tol == 1e-3 and len(made) == 3
    plan_again()
    assert len(made) == 3
    monkeypatch.setattr(pf, "source_digest", lambda: "0" * 16)
    plan_again()
    assert len(made) == 4 and len(list(folder.iterdir())) == 2


def rewritten(path, first, change):
    """The plan file at ``path`` rewritten with ``change`` applied to ``first``'s arrays, its
    digest the arrays' as written: consistent-looking damage."""
    rewritten_as(path, sp.PLAN_FORMAT, first, change, digest_anew=False)


def near_cut(arrays):                  # 5 of the near classes, the table cut to match
    g = len(arrays["kernels"])
    arrays["near_values"] = arrays["near_values"][:5, :5]
    arrays["fine"] = arrays["fine"][..., :g + 5]


def near_zero(arrays):                 # near field 0: one class, the table cut to match
    g = len(arrays["kernels"])
    arrays["scalars"][6] = 0
    arrays["near_values"] = arrays["near_values"][:1, :1]
    arrays["fine"] = arrays["fine"][..., :g + 1]


def kernel_dropped(arrays):            # the last eigen-kernel and its table column gone
    g = len(arrays["kernels"])
    arrays["kernels"] = arrays["kernels"][:g - 1]
    arrays["fine"] = np.delete(arrays["fine"], g - 1, axis=-1)


def compressed(path, first):
    """The plan's own arrays, its digest right, in a compressed zip (not as written: its
    unpacked size is not the file's)."""
    with np.load(path) as data:
        key = str(data["key"])
    with open(path, "wb") as f:
        np.savez_compressed(f, **pf.file_arrays(sp.PLAN_FORMAT, first, key))


DAMAGE = {
    "truncated": lambda path, first: path.write_bytes(path.read_bytes()[:path.stat().st_size
                                                                      // 2]),
    "empty": lambda path, first: path.write_bytes(b""),
    "not a zip": lambda path, first: path.write_bytes(b"x" * 4096),
    "nan in the table": lambda path, first: rewritten(path, first,
                                                      set_at("fine", (0, 0, 0, 0), np.nan)),
    "nan in a kernel": lambda path, first: rewritten(path, first,
                                                     set_at("kernels", (0, 0, 0), np.nan)),
    "inf in an axis": lambda path, first: rewritten(path, first, set_at("axes", (0, 1), np.inf)),
    "inf error": lambda path, first: rewritten(path, first, set_at("scalars", 3, np.inf)),
    "nan near value": lambda path, first: rewritten(path, first,
                                                    set_at("near_values", (0, 0), np.nan)),
    "nan radius": lambda path, first: rewritten(path, first, set_at("scalars", 0, np.nan)),
    "another near radius": lambda path, first: rewritten(path, first, set_at("scalars", 6, 5)),
    "near classes cut": lambda path, first: rewritten(path, first, near_cut),
    "table cut": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("fine", a["fine"][:, :5])),
    "kernels of another radius": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("kernels", a["kernels"][:, :-1, :-1])),
    "scalars cut": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("scalars", a["scalars"][:4])),
    "near field 0, consistently": lambda path, first: rewritten(path, first, near_zero),
    "an eigen-kernel dropped, consistently": lambda path, first: rewritten(path, first,
                                                                          kernel_dropped),
    "errors of 0": lambda path, first: rewritten(
        path, first, lambda a: a["scalars"].__setitem__(slice(2, 4), 0.0)),
    "compressed": lambda path, first: compressed(path, first),
    "a complex table": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("fine", a["fine"].astype(np.complex64))),
    "float16 kernels": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("kernels", a["kernels"].astype(np.float16))),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_file_is_planned_anew_and_replaced(plans, damage):
    """A file that is not a whole plan of its key (truncated, not a zip, a value not finite
    anywhere, arrays whose shapes do not fit each other or the lattice and radius its key
    makes) is not trusted: planned anew, the same plan, and the file replaced."""
    folder, made = plans
    first = sp.stretched_plan(RANGES, 1.4, 1e-3)
    assert first.near >= 1                 # the near field's damage has classes to cut
    (path,) = folder.iterdir()
    DAMAGE[damage](path, first)
    again = plan_again()
    assert len(made) == 2 and pf.same_plan(sp.PLAN_FORMAT, again, first)
    plan_again()                       # the file was replaced by a whole one
    assert len(made) == 2


def test_a_plan_file_replaced_takes_no_access_from_the_one_before(plans):
    """A damaged plan file of mode 000 is replaced by one its owner can read (a cache file
    does not keep the access of the file it replaces: the replacement would be unreadable,
    and made anew by every process)."""
    import os
    import stat
    folder, made = plans
    sp.stretched_plan(RANGES, 1.4, 1e-3)
    (path,) = folder.iterdir()
    path.write_bytes(b"")
    os.chmod(path, 0)
    plan_again()
    assert len(made) == 2 and stat.S_IMODE(path.stat().st_mode) & stat.S_IRUSR


def test_a_fifo_where_a_plan_file_is_does_not_block(plans):
    """A FIFO (or any file that is not a regular one) at a plan's path is not opened (the
    read would block, and no signal ends a blocked open): planned anew, and the FIFO
    replaced by the plan's file."""
    import os
    folder, made = plans
    sp.stretched_plan(RANGES, 1.4, 1e-3)
    (path,) = folder.iterdir()
    path.unlink()
    os.mkfifo(path)
    plan_again()
    assert len(made) == 2 and path.is_file()


def test_a_cache_folder_that_cannot_be_written_is_only_no_cache(tmp_path, monkeypatch):
    """The cache folder's place is a file: the plan is made, nothing is raised, and it is
    made again in a new process (here: with the in-memory plans cleared)."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a user's file")
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(blocker))
    sp.STRETCHED_PLANS.clear()
    plan = plan_again()
    assert len(plan.kernels) >= 1 and blocker.read_text() == "a user's file"
    sp.STRETCHED_PLANS.clear()


def test_the_folder_keeps_its_bytes_least_recently_used_out(plans, monkeypatch):
    """Past PLANS_MAX_BYTES the least recently used plans go (a read counts as a use); a
    writer's temp file goes once it is left over (an hour old), never while fresh; a file of
    another name in the folder is never touched."""
    folder, made = plans
    sp.stretched_plan(RANGES, 1.4, 1e-3)
    (first,) = folder.iterdir()
    keep = folder / "notes.txt"
    keep.write_text("mine")
    monkeypatch.setattr(pf, "PLANS_MAX_BYTES", int(first.stat().st_size * 1.5))
    import os
    os.utime(first, (1, 1))            # long unused
    stale, fresh = (folder / f"{first.stem}.{tag}.tmp" for tag in ("abcd1234", "efgh5678"))
    stale.write_bytes(b"x")
    fresh.write_bytes(b"y")
    os.utime(stale, (1, 1))
    assert pf.PLANS_NAME.match(stale.name)
    sp.stretched_plan(RANGES, 1.4, 2e-3)
    names = {p.name for p in folder.iterdir()}
    assert first.name not in names and stale.name not in names and fresh.name in names
    assert len(names) == 3 and keep.read_text() == "mine"


def test_the_plans_names_follow_numpys_version(monkeypatch):
    """A plan is made by NumPy's SVD, whose last bits are its version's: a plan of another
    NumPy is a file of its own (read, it was valid, but not the plan this one makes)."""
    pf.source_digest.cache_clear()
    here = pf.source_digest()
    monkeypatch.setattr(np, "__version__", "0.0.1")
    pf.source_digest.cache_clear()
    try:
        assert pf.source_digest() != here
    finally:
        monkeypatch.undo()
        pf.source_digest.cache_clear()
