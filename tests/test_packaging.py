"""A non-editable install (a built wheel) carries the kernels and data and works on its own."""
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_ships_kernels_and_runs_outside_the_source_tree(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(wheels),
                    str(ROOT)], check=True)
    (wheel,) = wheels.glob("bdipole_cl-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    kernels = {p.name for p in (ROOT / "kernels").iterdir()}
    for k in kernels:
        assert f"bdipole_cl/kernels/{k}" in names, k
    assert "bdipole_cl/data/choice.json" in names
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(target), str(wheel)], check=True)
    code = ("import bdipole_cl, bdipole_cl.device.programs as d; "
            "assert str(d.kernel_dir()).startswith(%r), d.kernel_dir(); "
            "a = bdipole_cl.invert_albedo([0.5], 1.4, 'auto'); "
            "print(bdipole_cl.__file__, float(a[0]))" % str(target))
    env = dict(os.environ, PYTHONPATH=str(target))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True).stdout
    assert str(target) in out and 0.9 < float(out.split()[-1]) < 1.0
