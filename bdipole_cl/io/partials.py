"""What a writer killed mid-write leaves beside its output (I/O): the ``images.Writer``'s
temporary file (``.{stem}.partial-{pid}-{thread}{suffix}``) and, for a texture, OpenImageIO's
build files beside that (``....tx`` and its own ``{stem}.{hex}.temp{ext}``). A writer removes
those of dead processes before it starts: a stopped or killed run's leftovers do not pile up,
and a live process's are never touched."""
from __future__ import annotations

import glob
import os
import re
from pathlib import Path


def partial_files(path) -> list:
    """Temporary files writers of ``path`` leave only if stopped or killed mid-write, matched
    literally (an output named ``m[1]`` or ``*`` never matches another output's)."""
    path = Path(path)
    name = re.compile(rf"\.{re.escape(path.stem)}\.partial-\d+(-\d+)?(\.[^/]+)?"
                      rf"{re.escape(path.suffix)}")
    candidates = path.parent.glob(f".{glob.escape(path.stem)}.partial-*")
    return sorted(p for p in candidates if name.fullmatch(p.name))


def writer_pid(partial) -> int | None:
    """The process id in a partial file's name."""
    match = re.search(r"\.partial-(\d+)", Path(partial).name)
    return int(match[1]) if match else None


def alive(pid) -> bool:
    """Whether process ``pid`` is running (another user's counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def remove_partial_files(path) -> int:
    """Remove what stopped or killed writers of ``path`` left, but for a running process's
    (this one's own earlier writes of ``path`` are over: outputs never collide in a run)."""
    n = 0
    for p in partial_files(path):
        pid = writer_pid(p)
        if pid is not None and pid != os.getpid() and alive(pid):
            continue
        try:
            p.unlink()
            n += 1
        except FileNotFoundError:
            pass
    return n
