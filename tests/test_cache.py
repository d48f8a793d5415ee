"""``bdipole-cl cache``: every folder the tool writes outside the user's outputs is listed with
the variable that moves it, and ``--clear`` removes bdipole_cl's own entries and nothing else.
The demo, run with an empty home folder, is the measurement: whatever appears there must be a
listed folder (a new cache in the code, unlisted, fails it)."""
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from bdipole_cl.apps import cache
from bdipole_cl.apps.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]

#: the variables that move the folders: cleared, so that a test sees only what it sets
MOVING = ("BDIPOLE_CL_CACHE_DIR", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "POCL_CACHE_DIR",
          "MPLCONFIGDIR", "DASK_TEMPORARY_DIRECTORY")


@pytest.fixture
def home(tmp_path, monkeypatch):
    """An empty home folder, every moving variable unset, the temporary folder inside it."""
    folder = tmp_path / "home"
    folder.mkdir()
    monkeypatch.setenv("HOME", str(folder))
    for name in MOVING:
        monkeypatch.delenv(name, raising=False)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))
    monkeypatch.setattr("tempfile.tempdir", None)      # gettempdir() reads TMPDIR again
    return folder


def make_own_entries(root: Path):
    """One entry of each kind bdipole_cl makes in its cache folder, as the code names them."""
    (root / "icd-0123456789abcdef").mkdir(parents=True)
    (root / "icd-0123456789abcdef" / "bdipole_cl-intel-cpu.icd").write_text("/x/libintelocl.so\n")
    (root / "choice-intel-cpu-0123456789ab.json").write_text("{}")     # DeviceKey.slug's shape
    (root / "probes").mkdir()
    (root / "probes" / "0123456789abcdef0123.json").write_text("{}")  # a probe's verdict
    (root / "usdz" / "0123456789abcdef0123").mkdir(parents=True)
    (root / "usdz" / "0123456789abcdef0123" / "a.exr").write_bytes(b"x" * 100)


def test_every_folder_names_the_variable_that_moves_it(home, monkeypatch, tmp_path):
    moved = {name: tmp_path / name.lower() for name in
             ("BDIPOLE_CL_CACHE_DIR", "POCL_CACHE_DIR", "MPLCONFIGDIR",
              "XDG_CACHE_HOME")}
    for name, path in moved.items():
        monkeypatch.setenv(name, str(path))
    folders = {f.path: f for f in cache.cache_folders()}
    # each variable set moves its folder there (the XDG one: pyopencl's and pytools')
    assert moved["BDIPOLE_CL_CACHE_DIR"] in folders
    assert moved["POCL_CACHE_DIR"] in folders
    assert moved["MPLCONFIGDIR"] in folders
    assert moved["XDG_CACHE_HOME"] / "pyopencl" in folders
    assert moved["XDG_CACHE_HOME"] / "pytools" in folders
    for f in folders.values():
        assert f.moved_by and f.what, f


def test_clear_removes_only_the_tools_own_entries(home, tmp_path, capsys):
    root = home / ".cache" / "bdipole_cl"
    make_own_entries(root)
    mine = [root / "notes.txt", root / "choice.json", root / "usdz" / "my_textures" / "a.exr",
            root / "icd-mine" / "x.icd", root / "choice-my-notes.json", root / "choice-.json",
            root / "probes" / "README.json"]
    for path in mine:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("the user's")
    elsewhere = tmp_path / "precious"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("the user's")
    (root / "icd-fedcba9876543210").symlink_to(elsewhere)     # a link: never followed
    pocl = home / ".cache" / "pocl" / "kcache" / "k.bin"
    pocl.parent.mkdir(parents=True)
    pocl.write_bytes(b"shared")
    assert cli_main(["cache", "--clear"]) == 0
    out = capsys.readouterr().out
    for gone in ("icd-0123456789abcdef", "choice-intel-cpu-0123456789ab.json",
                 "usdz/0123456789abcdef0123", "probes/0123456789abcdef0123.json"):
        assert not (root / gone).exists(), (gone, out)
        assert gone.split("/")[-1] in out, (gone, out)
    for path in mine + [elsewhere / "keep.txt", pocl]:
        assert path.read_text(errors="replace") in ("the user's", "shared"), path
    assert (root / "icd-fedcba9876543210").is_symlink()
    assert cli_main(["cache", "--info"]) == 0
    info = capsys.readouterr().out
    assert "~/.cache/pocl/kcache" in info and "PoCL's, shared" in info, info


def test_the_readme_and_the_install_page_name_every_folders_variable(home):
    """The README's and docs/install.md's tables of folders name each variable that moves one
    (a folder added to ``cache_folders`` without its line in the docs fails here)."""
    for page in (ROOT / "README.md", ROOT / "docs" / "install.md"):
        text = page.read_text()
        for f in cache.cache_folders():
            variable = f.moved_by.split()[0]
            assert f"`{variable}`" in text, (page.name, f.what, variable)


def test_info_and_help_name_every_kind_of_entry(capsys):
    """``cache --info``'s own folder and ``--clear``'s help name every kind of entry the tool
    makes (both left out the texture-varying plans, the help the stretched ones too)."""
    from bdipole_cl.apps.cli import main as cli_main
    with pytest.raises(SystemExit):
        cli_main(["cache", "--help"])
    helped = " ".join(capsys.readouterr().out.split())
    own = cache.cache_folders()[0].what
    for kind in cache.OWN_KINDS:
        assert kind.what in own and kind.what in helped, kind.what


def test_the_readme_and_the_install_page_name_every_entry_the_tool_makes():
    """Each kind of entry bdipole_cl makes in its cache folder (``cache.OWN_KINDS``) is named
    in the README's and docs/install.md's "Where it writes" tables (a walk's reflectance
    curves were in neither)."""
    for page in (ROOT / "README.md", ROOT / "docs" / "install.md"):
        text = page.read_text()
        table = text[text.index("Where it writes"):]
        for kind in cache.OWN_KINDS:
            assert kind.shown in table, (page.name, kind.what, kind.shown)


@pytest.mark.slow
def test_demo_in_an_empty_home_writes_only_listed_folders(home, tmp_path):
    """A fresh user's demo: it ends with its pictures and the next steps, and every folder that
    appears in the empty home or temporary folder is one ``cache --info`` lists."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    work = tmp_path / "work"
    work.mkdir()
    done = subprocess.run([sys.executable, "-m", "bdipole_cl", "demo", "--no-progress"],
                          cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    out = done.stdout
    from bdipole_cl.apps.demo import NEXT_STEPS, PICTURES
    for name, _ in PICTURES:
        picture = work / "bdipole_demo" / name
        assert picture.stat().st_size > 10_000, picture      # a drawn page, not an empty file
        assert f"bdipole_demo/{name}" in out, (name, out)
    assert out.rstrip().splitlines()[-2].strip() == NEXT_STEPS[-1][0], out[-800:]
    assert "Mtexel/s" not in out, out                  # no start-up-dominated throughput
    listed = [f.path for f in cache.cache_folders()]
    written = [p for top in (home, Path(os.environ["TMPDIR"]))
               for p in top.rglob("*") if p.is_file()]
    assert written, "the demo wrote no cache at all: the check would be empty"
    unlisted = [p for p in written if not any(p.is_relative_to(f) for f in listed)]
    assert not unlisted, unlisted[:5]


#: every writer of bdipole_cl's cache folder, run in a fresh one: a device used (its runtime
#: registration and its probe), a short calibration, a walk's reflectance curves for a (g,
#: eta) first met, a .usdz stage baked (its textures extracted)
WRITERS = """
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, sys.argv[2])
from bdipole_cl import get_runtime, invert_albedo, scene
from bdipole_cl.apps.report import calibrate
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.physics import transport
from pxr import Sdf, UsdUtils
from test_usd_scene import write_stage
runtime = get_runtime("intel")
invert_albedo(np.float32([0.5]), 1.4, device=runtime)
calibrate(n=4096, blur_size=24, repeats=1, progress=lambda *a: None,
          sweep=[MethodConfig("table", table_size=64)], sweep_f64=[],
          blur_sweep=[("direct", 1e-4)], gather_size=48)
transport.reflectance_curves(0.125, 1.3125)
work = Path(sys.argv[1])
stage = write_stage(work)
usdz = stage.with_suffix(".usdz")
assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(stage)), str(usdz))
assert scene.load(usdz).plan().run().exit_code == 0
"""


def test_every_entry_a_writer_makes_is_listed_and_cleared(tmp_path):
    """Every writer of bdipole_cl's cache folder, in a fresh one (a process of its own: no
    memory of an earlier one): each file it then holds lies in an entry ``cache --info``
    lists, and ``cache --clear`` leaves none (a walk's reflectance curves, written by
    ``convert``, were neither listed nor removed)."""
    from conftest import RUNTIMES
    if not any("intel" in r.describe().lower() for r in RUNTIMES):
        pytest.skip("Intel's runtime is not among the test devices")
    root = tmp_path / "cache"
    work = tmp_path / "work"
    work.mkdir()
    env = {**os.environ, "BDIPOLE_CL_CACHE_DIR": str(root),
           "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, "-c", WRITERS, str(work), str(ROOT / "tests")],
                          cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    # the temporary folder too: `clear` empties the registration's fallback there, which the
    # other test processes (and their Dask workers) may be using
    (tmp_path / "tmp").mkdir()
    env_here = {"BDIPOLE_CL_CACHE_DIR": str(root), "TMPDIR": str(tmp_path / "tmp")}
    files = [p for p in root.rglob("*") if p.is_file() or p.is_symlink()]
    kinds = {"icd-": "registration", "probes": "probe", "choice-": "calibration",
             "usdz": "usdz", "transport": "curves", "textured-plans": "textured plans"}
    made = {kinds[k] for p in files for k in kinds if k in str(p.relative_to(root))}
    # (the registration: where this process's runtime was registered already, none)
    assert made >= set(kinds.values()) - {"registration"}, sorted(
        str(p.relative_to(root)) for p in files)
    old = {k: os.environ.get(k) for k in env_here}
    os.environ.update(env_here)
    tempfile.tempdir = None                     # gettempdir() reads TMPDIR again
    try:
        entries = [e.path for e in cache.own_entries()]
        unlisted = [p for p in files if not any(p == e or e in p.parents for e in entries)]
        assert not unlisted, unlisted
        assert "walk reflectance curves" in "\n".join(cache.info_lines())
        cache.clear()
        left = [p for p in root.rglob("*") if p.is_file()]
        assert not left, left
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        tempfile.tempdir = None


def test_the_cache_home_fallback_is_listed_and_cleared(home, capsys):
    """A process whose home could not be written kept its caches in $TMPDIR's fallback
    (``device.cache_home``); once the home is writable again, ``cache --info`` still shows
    that folder and ``--clear`` removes bdipole_cl's entries there."""
    from bdipole_cl.device.cache_home import FALLBACK_NAME
    fallback = Path(tempfile.gettempdir()) / FALLBACK_NAME.format(uid=os.getuid())
    make_own_entries(fallback / "bdipole_cl")
    assert cli_main(["cache", "--info"]) == 0
    assert str(fallback) in capsys.readouterr().out
    assert cli_main(["cache", "--clear"]) == 0
    assert not (fallback / "bdipole_cl" / "probes" / "0123456789abcdef0123.json").exists()
    assert not (fallback / "bdipole_cl" / "usdz" / "0123456789abcdef0123").exists()
    assert not (fallback / "bdipole_cl" / "icd-0123456789abcdef").exists()   # registrations too


def test_a_fallback_not_this_users_alone_is_neither_used_nor_cleared(home, capsys):
    from bdipole_cl.device.cache_home import FALLBACK_NAME
    fallback = Path(tempfile.gettempdir()) / FALLBACK_NAME.format(uid=os.getuid())
    make_own_entries(fallback / "bdipole_cl")
    fallback.chmod(0o777)
    assert cli_main(["cache", "--clear"]) == 0
    assert (fallback / "bdipole_cl" / "probes" / "0123456789abcdef0123.json").exists()
    assert cli_main(["cache", "--info"]) == 0
    assert "not used: not this user's alone" in capsys.readouterr().out


def test_no_temporary_folder_at_all_lists_and_clears_the_rest(home, monkeypatch, capsys):
    def none():
        raise FileNotFoundError("No usable temporary directory found")
    monkeypatch.setattr("tempfile.gettempdir", none)
    make_own_entries(home / ".cache" / "bdipole_cl")
    assert cli_main(["cache", "--info"]) == 0
    assert cli_main(["cache", "--clear"]) == 0
    assert not (home / ".cache" / "bdipole_cl" / "probes" / "0123456789abcdef0123.json").exists()



def test_a_registration_fallback_not_this_users_alone_is_not_cleared(home, capsys):
    fallback = Path(tempfile.gettempdir()) / f"bdipole_cl-{os.getuid()}"
    (fallback / "icd-aaaaaaaaaaaaaaaa").mkdir(parents=True)
    (fallback / "icd-aaaaaaaaaaaaaaaa" / "a.icd").write_text("/x/liba.so\n")
    fallback.chmod(0o777)
    assert cli_main(["cache", "--clear"]) == 0
    assert (fallback / "icd-aaaaaaaaaaaaaaaa" / "a.icd").exists()
    assert cli_main(["cache", "--info"]) == 0
    assert "registration where the cache folder is not writable; not used" in \
        capsys.readouterr().out
