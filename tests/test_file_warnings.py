"""A file blur's accuracy warnings (bdipole_cl/errors.py ``warn_caller``, ``warnings_naming``):
each names the file it is of, planned or applied, whether files are blurred one after another
or at once on threads, and points at the user's line; a band after another says nothing new."""
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from bdipole_cl.jobs.blur_file import blur_file
from bdipole_cl.ops.blur.planning import BlurAccuracyWarning
from bdipole_cl.ops.blur.stretched import Stretch
from test_bad_inputs import write_exr


def caught_of(call):
    """The BlurAccuracyWarnings ``call()`` raises, every one (``"always"``)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        call()
    return [w for w in caught if issubclass(w.category, BlurAccuracyWarning)]


def sheared(tmp_path, name, shear):
    """A 32x32 RGB irradiance file, and a stretch of ``shear`` (its bound is warned of)."""
    path = tmp_path / f"{name}.exr"
    write_exr(path, np.random.default_rng(len(name)).random((32, 32, 3)))
    one = np.full((32, 32), 0.3, np.float32)
    return path, Stretch(one, one, max_shear=shear)


def test_a_planned_blurs_warning_names_its_file_and_the_callers_line(tmp_path):
    """The stretched blur's shear warning (made when the file's plan is) begins with the
    file's path and points at this line, not at contextlib's or the library's."""
    path, stretch = sheared(tmp_path, "irr", 0.6)
    got = caught_of(lambda: blur_file(path, tmp_path / "out.exr", albedo=0.6, mfp=0.5,
                                      stretch=stretch))
    assert got and all(str(w.message).startswith(f"{path}: ") and w.filename == __file__
                       for w in got), [(str(w.message)[:60], w.filename) for w in got]


def test_an_applied_blurs_warning_names_its_file(tmp_path):
    """A warning made as the plan is applied to the file's bands (the Gaussians fit's bound
    past tol) names the file too (it named none); under the default filter, a file of
    several bands says it once, not once a band."""
    path = tmp_path / "impulses.exr"
    e = np.zeros((128, 128, 1), np.float32)
    e[::16, ::16] = 1.0
    write_exr(path, e)

    def run():
        blur_file(path, tmp_path / "out.exr", albedo=0.99, mfp=0.3, method="gaussians",
                  border="zero", max_memory=1 << 16, force=True)
    got = caught_of(run)
    assert got and all(str(w.message).startswith(f"{path}: ") for w in got), [
        str(w.message)[:80] for w in got]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        run()
    said = [str(w.message) for w in caught if issubclass(w.category, BlurAccuracyWarning)]
    assert len(said) == len(set(said)) >= 1, said


def test_files_blurred_at_once_name_their_own_warnings(tmp_path):
    """Four files blurred on four threads at once: each gets its own warnings, each naming
    it, as when blurred one after another (process-wide ``catch_warnings`` kept 1-4 of 12,
    some without a file)."""
    files = [sheared(tmp_path, f"thr{i}", 0.1 * (i + 3)) for i in range(4)]

    def one(i):
        path, stretch = files[i]
        blur_file(path, tmp_path / f"out{i}.exr", albedo=0.6, mfp=0.5, stretch=stretch)

    serial = caught_of(lambda: [one(i) for i in range(4)])
    for i in range(4):
        (tmp_path / f"out{i}.exr").unlink()

    def at_once():
        with ThreadPoolExecutor(4) as pool:
            list(pool.map(one, range(4)))
    threaded = caught_of(at_once)
    assert len(threaded) == len(serial) >= 4
    assert sorted(str(w.message) for w in threaded) == sorted(str(w.message) for w in serial)
    for path, _ in files:
        assert sum(str(w.message).startswith(f"{path}: ") for w in threaded) == len(serial) // 4
