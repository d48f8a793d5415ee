"""A home folder that cannot be written (a render node's): pyopencl's and pytools' caches live
under it, and without the fallback of ``bdipole_cl.device.cache_home`` no kernel builds or
runs (pyopencl raised a KeyError on each build, pytools an OSError on each call)."""
import json
import os
import subprocess
import sys

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
