"""A home folder that cannot be written (a render node's): pyopencl's and pytools' caches live
under it, and without the fallback of ``bdipole_cl.device.cache_home`` no kernel builds or
runs (pyopencl raised a KeyError on each build, pytools an OSError on each call)."""
import json
import os
import subprocess
import sys

import pytest

from bdipole_cl.caches import user_cache_dir
from bdipole_cl.device import cache_home

BLUR_AND_INVERT = """
import json, warnings
warnings.simplefilter("always")
with warnings.catch_warnings(record=True) as seen:
    import numpy as np, bdipole_cl
    bdipole_cl.use_device("intel" if "intel" in bdipole_cl.device.get_runtime().describe().lower()
                          else None)
    e = np.zeros((24, 24), np.float32); e[12, 12] = 1.0
    blurred = bdipole_cl.blur(e, albedo=0.5, mfp=2.0)
    alpha = bdipole_cl.invert_albedo(np.full(16, 0.3, np.float32), 1.4)
print(json.dumps({"sum": float(blurred.sum()), "alpha": float(alpha[0]),
                  "warnings": [str(w.message) for w in seen if "cannot be written" in str(w.message)]}))
"""


def test_writable_folder_or_not(tmp_path):
    assert cache_home.writable(tmp_path / "a" / "b")
    (tmp_path / "file").write_text("x")
    assert not cache_home.writable(tmp_path / "file" / ".cache")


def test_a_fallback_must_be_private(tmp_path):
    """Another user's folder at the fallback's known name in /tmp would have its .icd files
    loaded and its pickles read: only a folder of this user's that no one else can write."""
    mine = tmp_path / "mine"
    assert cache_home.private_folder(mine) and (mine.stat().st_mode & 0o777) == 0o700
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    assert not cache_home.private_folder(shared)
    link = tmp_path / "link"
    link.symlink_to(mine)
    assert not cache_home.private(link)
    if os.getuid() == 0:                # root can give a folder away: someone else's
        other = tmp_path / "other"
        other.mkdir(mode=0o700)
        os.chown(other, 65534, 65534)
        assert not cache_home.private_folder(other)


@pytest.fixture
def unwritable_home(tmp_path, monkeypatch):
    home = tmp_path / "home"
    home.write_text("a file: no folder can be made in it")
    monkeypatch.setenv("HOME", str(home))
    for name in ("XDG_CACHE_HOME", cache_home.NO_CACHE, "BDIPOLE_CL_CACHE_DIR"):
        monkeypatch.setenv(name, "")      # so that the value the code sets is undone too
        monkeypatch.delenv(name)
    monkeypatch.setattr(cache_home, "_note", None)
    return home


def test_without_a_private_fallback_pyopencls_caches_are_turned_off(unwritable_home, tmp_path,
                                                                     monkeypatch):
    tmp = tmp_path / "tmp"
    planted = tmp / cache_home.FALLBACK_NAME.format(uid=os.getuid())
    planted.mkdir(parents=True)
    planted.chmod(0o777)
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr("tempfile.tempdir", None)
    cache_home.ensure_writable_cache_home()
    assert os.environ[cache_home.NO_CACHE] == "1" and "XDG_CACHE_HOME" not in os.environ
    with pytest.warns(RuntimeWarning, match="built anew in each process"):
        cache_home.say_once()
    cache_home.say_once()                # once


def test_no_temporary_folder_at_all_is_no_crash(unwritable_home, monkeypatch):
    def none():
        raise FileNotFoundError("No usable temporary directory found")
    monkeypatch.setattr("tempfile.gettempdir", none)
    cache_home.ensure_writable_cache_home()
    assert os.environ[cache_home.NO_CACHE] == "1"


def test_the_note_names_only_the_caches_it_moved(unwritable_home, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr("tempfile.tempdir", None)
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(tmp_path / "own"))
    cache_home.ensure_writable_cache_home()
    assert "bdipole_cl's" not in cache_home._note, cache_home._note


def test_a_home_that_cannot_be_written_still_builds_and_runs_kernels(tmp_path):
    home = tmp_path / "home"
    home.write_text("a file: no folder can be made in it")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "XDG_CACHE_HOME"}
    # this run's probe verdicts, where they are (a probe of every device would take minutes)
    env.update(HOME=str(home), TMPDIR=str(tmp), BDIPOLE_CL_CACHE_DIR=str(user_cache_dir()))
    out = subprocess.run([sys.executable, "-c", BLUR_AND_INVERT], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert 0.0 < got["sum"] < 1.0 and 0.0 < got["alpha"] < 1.0, got
    fallback = tmp / cache_home.FALLBACK_NAME.format(uid=os.getuid())
    assert len(got["warnings"]) == 1 and str(fallback) in got["warnings"][0], got
    assert (fallback / "pyopencl").is_dir() or (fallback / "pytools").is_dir()
    # the command says it in one line, as its other warnings (it was Python's two lines,
    # said at import before the command set its format up)
    out = subprocess.run([sys.executable, "-m", "bdipole_cl.apps.cli", "devices"], env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    said = [ln for ln in out.stderr.splitlines() if ln.strip()]
    folders = "pyopencl, pytools" + ("" if env.get("POCL_CACHE_DIR") else ", pocl")
    assert said == [f"bdipole-cl: warning: RuntimeWarning: the cache folder {home}/.cache (or "
                    f"its {folders} folder) cannot be written: the OpenCL compilers' "
                    f"caches are kept in {fallback} (set XDG_CACHE_HOME to keep them "
                    f"elsewhere)"], out.stderr


def test_pyopencls_own_words_for_its_switch(unwritable_home, tmp_path, monkeypatch):
    """PYOPENCL_NO_CACHE=0 (or false, no, off) leaves pyopencl's caches on, as pyopencl reads
    it: with nowhere to keep them they are turned off (it was taken as "set", and every build
    failed)."""
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(tmp_path / "file"))
    (tmp_path / "file").write_text("x")
    for off in ("0", "false", "No", "off"):
        monkeypatch.setenv(cache_home.NO_CACHE, off)
        cache_home.ensure_writable_cache_home()
        assert os.environ[cache_home.NO_CACHE] == "1", off
    assert cache_home.turned_on("TRUE") and not cache_home.turned_on(None)


@pytest.mark.parametrize("folder", ["pyopencl", "pytools", "pocl"])
def test_a_library_folder_that_cannot_be_written_moves_the_caches(folder, tmp_path,
                                                                   monkeypatch):
    """The cache home writable, but pyopencl's, pytools' or PoCL's folder a file: pyopencl
    fails there as in an unwritable home, and PoCL lists no device (the check looked at the
    home only); bdipole_cl's own folder there is still listed and cleared."""
    home = tmp_path / "cache-home"
    home.mkdir()
    (home / folder).write_text("a file")
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.delenv("POCL_CACHE_DIR", raising=False)
    monkeypatch.delenv("BDIPOLE_CL_CACHE_DIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)
    monkeypatch.setattr(cache_home, "_note", None)
    monkeypatch.setattr(cache_home, "_moved_from", None)
    cache_home.ensure_writable_cache_home()
    assert os.environ["XDG_CACHE_HOME"] == str(cache_home.fallback_path())
    from bdipole_cl.apps.cache import own_roots
    assert home / "bdipole_cl" in own_roots()


def test_a_child_without_a_temporary_folder_still_starts(monkeypatch):
    """The children (probes, guarded builds) kept their stderr in a temporary file: with no
    temporary folder none could start, and no device was probed."""
    from bdipole_cl.device import children
    from conftest import RUNTIMES
    from bdipole_cl.device.runtime import device_index

    def none(*args, **kwargs):
        raise FileNotFoundError("No usable temporary directory found")
    monkeypatch.setattr("tempfile.TemporaryFile", none)
    child = children.Child("bdipole_cl.device.build_child",
                           ["--device", device_index(RUNTIMES[0].device)], requests=True)
    try:
        assert child.line(120) == {"ready": True}
    finally:
        child.finish(kill=True)
