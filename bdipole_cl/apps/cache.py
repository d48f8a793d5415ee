"""``bdipole-cl cache``: the folders the tool writes outside the user's outputs, their sizes and
the variable that moves each (``--info``), and ``--clear`` of the entries bdipole_cl itself made.

bdipole_cl's own entries (docs/guide.md, "Where it writes") live in its cache folder
(``caches.user_cache_dir``): the OpenCL runtime registration (``icd-*``, else in a folder of the
temporary directory), the device probes' verdicts (``probes/<digest>.json``:
``device.isolation``), the device calibrations (``choice-*.json``), the textures extracted
from ``.usdz`` packages (``usdz/<digest>``) and the walks' reflectance curves
(``transport/curves-*.npz``: ``physics.transport``) and the guarded builds' records
(``probes/<digest>.builds/``: ``device.guard``), each kind named as its writer names it
(``OWN_KINDS``, imported, never retyped). The other folders belong to the libraries it runs
(PoCL, pyopencl, pytools, matplotlib, Dask) and are shared with every other program using them:
they are shown, never removed. A clear removes only names the tool makes, by their exact shape,
so a user's file in a folder they pointed a variable at is never touched.
"""
from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from ..caches import CACHE_DIR_VARIABLE, cache_home, user_cache_dir
from ..device.cache_home import fallback_path, moved_from, private, temporary_folder
from ..device.icd import ICD_NAME, vendors_roots
from ..device.isolation import BUILDS_NAME, VERDICT_FOLDER, VERDICT_NAME, lock_in_use
from ..io.usdz import EXTRACTED_FOLDER, EXTRACTED_NAME
from ..methods.choice import CALIBRATION_NAME
from ..ops.blur.plan_files import PLANS_NAME, STRETCHED_FOLDER, TEXTURED_FOLDER
from ..physics.transport_tables import CURVES_FOLDER, CURVES_NAME


@dataclass(frozen=True)
class OwnKind:
    """A kind of entry bdipole_cl makes in its cache folder: under ``folder`` ('' the folder
    itself), named exactly as ``name`` matches, a folder (``is_dir``) or a file; ``shown``
    as the README's and docs/install.md's "Where it writes" tables name it."""

    what: str
    folder: str
    name: re.Pattern
    is_dir: bool
    shown: str


#: every kind of entry bdipole_cl makes in its cache folder but the runtime registrations
#: (which have a second root): ``--info`` lists them, ``--clear`` removes them
OWN_KINDS = (
    OwnKind("calibration", "", CALIBRATION_NAME, False, "choice-*.json"),
    OwnKind("device probe", VERDICT_FOLDER, VERDICT_NAME, False, f"{VERDICT_FOLDER}/"),
    OwnKind("guarded builds' records", VERDICT_FOLDER, BUILDS_NAME, True, f"{VERDICT_FOLDER}/"),
    OwnKind("extracted .usdz textures", EXTRACTED_FOLDER, EXTRACTED_NAME, True,
            f"{EXTRACTED_FOLDER}/"),
    OwnKind("walk reflectance curves", CURVES_FOLDER, CURVES_NAME, False, f"{CURVES_FOLDER}/"),
    OwnKind("stretched blur plans", STRETCHED_FOLDER, PLANS_NAME, False,
            f"{STRETCHED_FOLDER}/"),
    OwnKind("texture-varying blur plans", TEXTURED_FOLDER, PLANS_NAME, False,
            f"{TEXTURED_FOLDER}/"),
)


@dataclass(frozen=True)
class CacheFolder:
    """One folder the tool (or a library it runs) writes outside the user's outputs."""

    what: str                 # what it holds
    path: Path
    moved_by: str             # the variable that moves it (or turns it off)
    owner: str                # "bdipole_cl", or the library whose folder it is (shared)

    @property
    def ours(self) -> bool:
        return self.owner == "bdipole_cl"


@dataclass(frozen=True)
class OwnEntry:
    """A file or folder that bdipole_cl made in its own folders, which ``--clear`` removes."""

    what: str
    path: Path


def xdg(variable: str, default: str) -> Path:
    """$variable, else ~/default (the XDG base folders)."""
    return Path(os.environ.get(variable) or Path.home() / default)


def pyopencl_cache() -> Path:
    """pyopencl's compiler cache folder, found as pyopencl finds it."""
    named = os.environ.get("XDG_CACHE_HOME")
    if named:
        return Path(named) / "pyopencl"
    try:
        import platformdirs
        return Path(platformdirs.user_cache_dir("pyopencl", "pyopencl"))
    except ImportError:               # pyopencl's dependency: absent only in odd installs
        return cache_home() / "pyopencl"


def nvidia_compute_cache() -> Path:
    """Where NVIDIA's driver keeps the GPU code it compiles ($CUDA_CACHE_PATH, else
    ~/.nv/ComputeCache)."""
    named = os.environ.get("CUDA_CACHE_PATH")
    return Path(named) if named else Path.home() / ".nv" / "ComputeCache"


def matplotlib_folders() -> tuple[Path, Path]:
    """matplotlib's (cache, configuration) folders, found without creating them."""
    named = os.environ.get("MPLCONFIGDIR")
    if named:
        return Path(named), Path(named)
    return (cache_home() / "matplotlib",
            xdg("XDG_CONFIG_HOME", ".config") / "matplotlib")


def own_words() -> str:
    """What bdipole_cl's own cache folder holds, in words: the registration and every kind
    of OWN_KINDS (so that a new kind is never left unsaid)."""
    return ", ".join(["runtime registration"] + [kind.what for kind in OWN_KINDS])


#: said of a fallback folder in the temporary folder that bdipole_cl does not use
NOT_USED = "; not used: not this user's alone"


def kept(folder: Path | None) -> bool:
    """Whether a fallback in the temporary folder is this user's alone (bdipole_cl uses it)."""
    return folder is not None and private(folder)


def refused(folder: Path | None) -> bool:
    """Whether a fallback in the temporary folder is there but not this user's alone."""
    return folder is not None and os.path.lexists(folder) and not private(folder)


def cache_folders() -> list[CacheFolder]:
    """Every folder written outside the user's outputs, bdipole_cl's own first (those in the
    temporary folder only where there is one)."""
    own, fallback = vendors_roots()
    home_fallback, temporary = fallback_path(), temporary_folder()
    mpl_cache, mpl_config = matplotlib_folders()
    home = cache_home()
    folders = [
        CacheFolder(own_words(), own,
                    f"{CACHE_DIR_VARIABLE} (else XDG_CACHE_HOME)", "bdipole_cl"),
        CacheFolder("runtime registration where the cache folder is not writable"
                    + (NOT_USED if refused(fallback) else ""), fallback,
                    "TMPDIR", "bdipole_cl"),
        CacheFolder("the cache home where ~/.cache is not writable (pyopencl's, pytools' and "
                    "bdipole_cl's folders)" + (NOT_USED if refused(home_fallback) else ""),
                    home_fallback, "TMPDIR", "bdipole_cl"),
        CacheFolder("PoCL's compiled kernels", Path(os.environ.get("POCL_CACHE_DIR")
                                                    or home / "pocl" / "kcache"),
                    "POCL_CACHE_DIR", "PoCL"),
        CacheFolder("pyopencl's compiled programs", pyopencl_cache(),
                    "XDG_CACHE_HOME (PYOPENCL_NO_CACHE=1: none)", "pyopencl"),
        CacheFolder("pyopencl's kernel invokers", home / "pytools",
                    "XDG_CACHE_HOME (PYOPENCL_NO_CACHE=1: none)", "pytools"),
        CacheFolder("matplotlib's font list (pictures)", mpl_cache, "MPLCONFIGDIR", "matplotlib"),
        CacheFolder("matplotlib's settings folder (made empty)", mpl_config, "MPLCONFIGDIR",
                    "matplotlib"),
        CacheFolder("NVIDIA's compiled GPU kernels (its OpenCL driver's JIT cache; only on "
                    "an NVIDIA GPU)", nvidia_compute_cache(),
                    "CUDA_CACHE_PATH (CUDA_CACHE_DISABLE=1: none)", "NVIDIA's driver"),
        CacheFolder("Dask's scratch space (--scheduler local:N)",
                    temporary and temporary / "dask-scratch-space",
                    "DASK_TEMPORARY_DIRECTORY", "Dask"),
    ]
    return [f for f in folders if f.path is not None]


def own_roots() -> list[Path]:
    """bdipole_cl's cache folder, and the cache-home fallback's where a process whose cache
    home could not be written kept it there (``device.cache_home``; only a private one)."""
    fallback, before = fallback_path(), moved_from()
    return list(dict.fromkeys([user_cache_dir()]
                              + ([fallback / "bdipole_cl"] if kept(fallback) else [])
                              + ([before / "bdipole_cl"] if before else [])))


def own_entries() -> list[OwnEntry]:
    """The entries bdipole_cl made in its folders, recognised by their exact names; a link is
    never one (it would lead out of the folder)."""
    entries = []
    roots = own_roots()
    own, temporary = vendors_roots()
    for root in dict.fromkeys(roots + [own] + ([temporary] if kept(temporary) else [])):
        if root.is_dir():
            entries += [OwnEntry("runtime registration", p) for p in sorted(root.iterdir())
                        if ICD_NAME.match(p.name) and p.is_dir() and not p.is_symlink()]
    for root, kind in ((root, kind) for root in roots for kind in OWN_KINDS):
        folder = root / kind.folder
        if not folder.is_dir() or folder.is_symlink():
            continue
        entries += [OwnEntry(entry_what(kind, p), p) for p in sorted(folder.iterdir())
                    if kind.name.match(p.name) and not p.is_symlink()
                    and (p.is_dir() if kind.is_dir else p.is_file())
                    and not (p.suffix == ".lock" and lock_in_use(p))]   # a probe's own
    return entries


def entry_what(kind: OwnKind, path: Path) -> str:
    """What one entry is (a probe's verdict or its lock file; the guarded builds' records
    are a folder of their own kind)."""
    if kind.folder == VERDICT_FOLDER and not kind.is_dir:
        return f"{kind.what} {'lock' if path.suffix == '.lock' else 'verdict'}"
    return kind.what


def size_of(path: Path) -> tuple[int, int]:
    """(bytes, files) below ``path`` (a file: itself), links not followed; (0, 0) if absent."""
    if path.is_symlink() or path.is_file():
        return (path.lstat().st_size, 1) if path.exists() else (0, 0)
    total = files = 0
    for folder, _, names in os.walk(path):
        for name in names:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
                files += 1
            except OSError:           # removed while we walked: not there
                continue
    return total, files


def human(nbytes: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if nbytes < 1024 or unit == "GB":
            return f"{nbytes:.0f} {unit}" if unit == "B" else f"{nbytes:.1f} {unit}"
        nbytes /= 1024
    return ""                                          # pragma: no cover


def shown(path: Path) -> str:
    """``path`` with the home folder as ``~``."""
    home = str(Path.home())
    text = str(path)
    return "~" + text[len(home):] if home != "/" and text.startswith(home + os.sep) else text


def info_lines() -> list[str]:
    """``--info``: each folder, its size (or absent), the variable that moves it, whose it is;
    then bdipole_cl's own entries."""
    lines = ["folders written outside your outputs (set the variable to move one):"]
    for f in cache_folders():
        nbytes, files = size_of(f.path)
        size = (f"{human(nbytes)} in {files} file{'s' * (files != 1)}" if f.path.is_dir()
                else "absent")
        whose = "bdipole_cl's" if f.ours else f"{f.owner}'s, shared"
        lines.append(f"  {shown(f.path)}  ({size}; {whose})")
        lines.append(f"      {f.what}; moved by {f.moved_by}")
    entries = own_entries()
    lines.append(f"bdipole_cl's own entries ({len(entries)}), removed by `bdipole-cl cache "
                 f"--clear`:")
    for e in entries:
        nbytes, files = size_of(e.path)
        lines.append(f"  {e.what}: {shown(e.path)} ({human(nbytes)})")
    lines.append("the shared folders are the libraries' own: other programs use them too, so "
                 "--clear leaves them (remove one yourself while nothing runs)")
    return lines


def clear() -> list[str]:
    """Remove bdipole_cl's own entries (never a shared folder, never a file it did not name);
    one line per entry removed or not, and a total."""
    lines, freed, removed = [], 0, 0
    for e in own_entries():
        nbytes, _ = size_of(e.path)
        try:
            if e.path.is_dir():
                shutil.rmtree(e.path)
            else:
                e.path.unlink()
        except OSError as exc:
            lines.append(f"  not removed: {e.what}: {shown(e.path)}: {exc.strerror or exc}")
            continue
        freed, removed = freed + nbytes, removed + 1
        lines.append(f"  removed {e.what}: {shown(e.path)} ({human(nbytes)})")
    lines.append(f"removed {removed} entries ({human(freed)}); every command makes its runtime "
                 f"registration again as it starts, `bdipole-cl report --calibrate` a "
                 f"calibration"
                 if removed else "nothing to remove: bdipole_cl's folders hold none of its "
                                 "entries")
    return lines


def add_command(command):
    """Add the command to the CLI (``command``: the subparsers' add_parser)."""
    p = command("cache", help="show (--info) or clear (--clear) the folders the tool writes "
                              "outside your outputs")
    action = p.add_mutually_exclusive_group()
    action.add_argument("--info", action="store_true",
                        help="every folder, its size, whose it is and the variable that moves "
                             "it (the default)")
    action.add_argument("--clear", action="store_true",
                        help=f"remove bdipole_cl's own entries ({own_words()}); shared "
                             "library caches are left")
    p.set_defaults(func=_cmd_cache)


def _cmd_cache(args) -> int:
    print("\n".join(clear() if args.clear else info_lines()))
    return 0
