"""What the tests of plans on disk share (tests/test_plan_files.py, the stretched blur's;
tests/test_textured_plan_files.py, the texture-varying blur's): a fresh cache folder whose
plans made are counted, and plan files rewritten with damage."""
import numpy as np

from bdipole_cl.ops.blur import plan_files as pf


def counted_plans(tmp_path, monkeypatch, module, make_name, memory, folder):
    """(the plans' folder in a fresh cache folder, a list that gets an entry each time
    ``module.make_name`` makes a plan, not read), the in-memory plans ``memory`` cleared."""
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(tmp_path / "cache"))
    memory.clear()
    made = []
    real = getattr(module, make_name)
    monkeypatch.setattr(module, make_name, lambda *a: made.append(a) or real(*a))
    return tmp_path / "cache" / folder, made


def rewritten(path, fmt, first, change, digest_anew):
    """The plan file at ``path`` rewritten by np.savez (a whole zip, its CRCs right) with
    ``change`` applied to ``first``'s arrays (``fmt``'s): with its digest made anew (what the
    plan's whole-check must find), or the digest of the arrays as written (any change)."""
    with np.load(path) as data:
        key = str(data["key"])
    arrays = {k: np.array(v) for k, v in pf.file_arrays(fmt, first, key).items()}
    change(arrays)
    if digest_anew:
        arrays["digest"] = np.array(pf.content_digest(arrays))
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def set_at(name, index, value):
    """A change setting array ``name``'s element ``index`` to ``value``."""
    def change(arrays):
        arrays[name][index] = value
    return change
