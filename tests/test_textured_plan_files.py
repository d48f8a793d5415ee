"""Texture-varying plans on disk (bdipole_cl/ops/blur/textured_plan_files.py; docs/model.md
"What planning costs"): made once per version of the code, read back in another process bit
for bit and giving the same blur, never read under other near field radii, made anew where a
file is damaged, and the Gaussians basis never written."""
import os
import subprocess
import sys

import numpy as np
import pytest

from bdipole_cl.ops.blur import near_field
from bdipole_cl.ops.blur import plan_files as pf
from bdipole_cl.ops.blur import textured_plan as tp
from bdipole_cl.ops.blur import textured_plan_files as tpf
from plan_file_helpers import counted_plans, set_at
from plan_file_helpers import rewritten as rewritten_as

#: a small plan's ranges (logit Rd, ln ld texels): a few nodes, planned in ~0.5 s
RANGES = ((0.5, 1.5), (1.0, 1.6))


@pytest.fixture
def plans(tmp_path, monkeypatch):
    """The plans' folder in a fresh cache folder, the in-memory plans cleared, and a list
    that gets an entry each time a plan is made (not read)."""
    yield counted_plans(tmp_path, monkeypatch, tpf, "make_plan_for_ranges", tp.PLAN_CACHE,
                        pf.TEXTURED_FOLDER)
    tp.PLAN_CACHE.clear()


def plan_again(**kw):
    tp.PLAN_CACHE.clear()
    return tpf.plan_for_ranges(*RANGES, 1.4, 1e-3, **kw)


def maps(n=24):
    """An irradiance and albedo, mfp maps whose ranges need a few lattice nodes."""
    yy, xx = np.mgrid[0:n, 0:n]
    e = np.random.default_rng(3).random((n, n, 1)).astype(np.float32)
    albedo = (0.4 + 0.3 * xx / n)[..., None].astype(np.float32)
    mfp = (2.0 + 1.5 * yy / n).astype(np.float32)
    return e, albedo, mfp


#: a process's blur of the maps in argv[1] into argv[2]; with argv[3] == "read", a plan it
#: would make raises (it must read every one)
BLUR_SCRIPT = """import sys, numpy as np
from bdipole_cl.ops.blur import blur
from bdipole_cl.ops.blur import textured_plan_files as tpf
if sys.argv[3] == "read":
    tpf.make_plan_for_ranges = None
e, albedo, mfp = (np.load(sys.argv[1])[k] for k in ("e", "albedo", "mfp"))
np.save(sys.argv[2], blur(e, albedo=albedo, mfp=mfp, eta=1.4))
"""


def test_a_plan_is_made_once_and_read_back_in_another_process(plans):
    """The blur of a new process reads the plans an earlier process made: none made, the
    image bit for bit (both processes of this cache folder: the same device verdict, so the
    same gather costs in the plans' keys)."""
    folder, made = plans
    e, albedo, mfp = maps()
    work = folder.parent.parent
    np.savez(work / "maps.npz", e=e, albedo=albedo, mfp=mfp)
    for mode in ("make", "read"):
        run = subprocess.run([sys.executable, "-c", BLUR_SCRIPT, str(work / "maps.npz"),
                              str(work / f"{mode}.npy"), mode], capture_output=True,
                             text=True, env={**os.environ}, timeout=300)
        assert run.returncode == 0, (mode, run.stderr[-2000:])
        if mode == "make":             # (a fresh cache folder's probe plans some too)
            files = sorted(folder.iterdir())
            assert files and all(pf.PLANS_NAME.match(f.name) for f in files), files
    np.testing.assert_array_equal(np.load(work / "read.npy"), np.load(work / "make.npy"))
    assert not made


def test_a_plan_read_is_read_only(plans):
    folder, made = plans
    plan_again()
    again = plan_again()
    assert len(made) == 1 and not again.fine.flags.writeable and not again.table.flags.writeable


def test_other_near_field_radii_or_basis_are_not_read(plans, monkeypatch):
    """A plan made under other near field radii (a calibration's, one radius at a time) is a
    file of its own: the default's is not read as it, nor it as the default's. The Gaussians
    basis is made in every process, never written."""
    folder, made = plans
    default = plan_again()
    monkeypatch.setattr(near_field, "NEAR_RADII", (1,))
    one = plan_again()
    assert one.near == 1 and len(made) == 2 and len(list(folder.iterdir())) == 2
    monkeypatch.undo()
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(folder.parent))
    assert plan_again().near == default.near
    plan_again(basis="gaussians")
    assert len(list(folder.iterdir())) == 2


def rewritten(path, first, change, digest_anew=True):
    """The plan file at ``path`` rewritten by np.savez (a whole zip) with ``change`` applied:
    with its digest made anew (what ``plan_is_whole`` must find: shapes, lattice, radius,
    values not finite, a fine table not its table's), or the digest of the arrays as written
    (any change at all)."""
    rewritten_as(path, tpf.PLAN_FORMAT, first, change, digest_anew)


def near_cut(arrays):                  # one near kernel fewer, the tables cut to match
    arrays["near_values"] = arrays["near_values"][:-1]
    arrays["table"] = arrays["table"][..., :-1]
    arrays["fine"] = arrays["fine"][..., :-1]


DAMAGE = {
    "truncated": lambda path, first: path.write_bytes(path.read_bytes()[:path.stat().st_size
                                                                      // 2]),
    "not a zip": lambda path, first: path.write_bytes(b"x" * 4096),
    "a table value changed": lambda path, first: rewritten(path, first,
                                                           set_at("table", (0, 0, 0), 0.5)),
    "nan in a kernel": lambda path, first: rewritten(path, first,
                                                     set_at("kernels", (0, 0, 0), np.nan)),
    "another near radius": lambda path, first: rewritten(path, first, set_at("scalars", 5, 2)),
    # a near rank is any from 1 to the classes: cut consistently, only the digest tells
    "a near kernel cut, consistently": lambda path, first: rewritten(path, first, near_cut,
                                                                     digest_anew=False),
    "another radius": lambda path, first: rewritten(path, first, set_at("scalars", 0, 7)),
    "an axis moved": lambda path, first: rewritten(path, first, set_at("axes", (0, 0), -5)),
    "a negative error": lambda path, first: rewritten(path, first, set_at("scalars", 2, -1)),
    "float16 table": lambda path, first: rewritten(
        path, first, lambda a: a.__setitem__("table", a["table"].astype(np.float16))),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_a_damaged_file_is_planned_anew_and_replaced(plans, damage):
    """A file that is not a whole plan of its key (truncated, not a zip, its fine table not
    the one its table makes, a value not finite, shapes that do not fit each other, the
    lattice or the radius its key makes) is planned anew, the same plan, and replaced."""
    folder, made = plans
    first = plan_again()
    assert first.near >= 1 and first.kernels   # there is a near field and a basis to damage
    (path,) = folder.iterdir()
    DAMAGE[damage](path, first)
    again = plan_again()
    assert len(made) == 2 and pf.same_plan(tpf.PLAN_FORMAT, again, first)
    plan_again()                       # the file was replaced by a whole one
    assert len(made) == 2


def test_a_plan_of_exact_moments_is_read_without_integrating_them_again(plans, monkeypatch):
    """Reading a plan checks its radius, whose kernels ask for one eta's exact Fresnel
    moments hundreds of times: integrated once per eta (each a Gauss-Legendre sum of
    ``fresnel_reflectance``), a warm exact plan is read in a fraction of a second, as a new
    process reads it (it took 3 s a channel, 30x the blur)."""
    from bdipole_cl.physics import fresnel
    folder, made = plans
    plan_again(exact=True)
    sums = []
    real = fresnel.fresnel_reflectance
    monkeypatch.setattr(fresnel, "fresnel_reflectance", lambda *a: sums.append(1) or real(*a))
    if hasattr(fresnel, "_moments_exact_at"):
        fresnel._moments_exact_at.cache_clear()
    tp.NODE_CACHE.clear()                  # as in a new process: the radius found anew
    plan_again(exact=True)
    assert len(made) == 1 and 1 <= len(sums) <= 2, (len(made), len(sums))
