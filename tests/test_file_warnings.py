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


def faint(tmp_path):
    """A 64x64 RGB file of irradiance near 1e-42 (its exitance below float32's normal range:
    the bound takes float32's floor, past tol)."""
    path = tmp_path / "faint.exr"
    rows = 1 + np.arange(64)[:, None, None] / 16
    write_exr(path, np.ones((64, 64, 3)) * 1e-43 * rows)
    return path


def test_a_faint_files_floor_is_warned_of_once_a_channel_not_once_a_band(tmp_path):
    """The float32 floor's warning said the band's own peak and bound: a file of 56 bands
    said it 168 times under the default filter. Once a channel now."""
    path = faint(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        info = blur_file(path, tmp_path / "o.exr", albedo=0.8, mfp=2.0, max_memory=16384)
    said = [w for w in caught if issubclass(w.category, BlurAccuracyWarning)]
    assert max(c.error_bound for c in info.channels) > 1e-3
    assert len(said) == 3 and all(str(w.message).startswith(f"{path}: channel ")
                                  for w in said), [str(w.message) for w in said]


def test_a_texture_varying_blurs_floor_is_warned_of(tmp_path):
    """A texture-varying bound is tol plus its kernel error, above tol without the floor: the
    floor added to it (1e-3 past tol here) was silent. A floor past a tenth of tol is said."""
    path = faint(tmp_path)
    albedo = np.full((64, 64, 3), 0.8, np.float32)
    got = caught_of(lambda: blur_file(path, tmp_path / "o.exr", albedo=albedo, mfp=2.0))
    assert any("float32's normal range" in str(w.message) for w in got), [
        str(w.message) for w in got]


def test_a_warning_made_an_error_fails_its_tile_only(tmp_path, capsys):
    """Under a filter that makes accuracy warnings errors (``-W error``), a UDIM set's tile
    whose bound is past tol fails alone, named, as a bad file does; the others are written
    (the whole run stopped, "an unexpected error")."""
    from bdipole_cl.apps.cli import main as cli_main
    e = np.random.default_rng(1).random((32, 32, 3)) - 0.5          # both signs: warned
    write_exr(tmp_path / "n.1001.exr", e)
    write_exr(tmp_path / "n.1002.exr", np.random.default_rng(2).random((32, 32, 3)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", BlurAccuracyWarning)
        rc = cli_main(["blur", str(tmp_path / "n.<UDIM>.exr"), "--albedo", "0.8", "--mfp",
                       "2", "-o", str(tmp_path / "{stem}_b.exr"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1 and "unexpected" not in err, err
    assert f"{tmp_path / 'n.1001.exr'}: channel" in err and "both signs" in err, err
    assert (tmp_path / "n.1002_b.exr").exists() and not (tmp_path / "n.1001_b.exr").exists()
