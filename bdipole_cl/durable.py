"""A finished temporary file put in place durably (the foundation layer): its data flushed to
the disk, then renamed over the path, then the rename itself flushed (the folder's entry), so
that after a power loss the path holds either the old file or the whole new one, never an
empty or partial one (a rename alone can reach the disk before the data it names)."""
from __future__ import annotations

import os
import stat


def fsync_path(path, directory=False):
    """Flush ``path``'s data (or a folder's entries) to the disk; where the platform cannot
    open a folder for that (Windows), nothing."""
    flags = os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not directory:            # some file systems refuse a folder's fsync: its entry
            raise                    # then is as durable as they make it
    finally:
        os.close(fd)


def durable_replace(tmp, path):
    """``os.replace(tmp, path)`` with ``tmp``'s data on the disk first and the rename after; a
    file replaced keeps its permission bits and group (``keep_access``)."""
    keep_access(tmp, path)
    fsync_path(tmp)
    os.replace(tmp, path)
    fsync_path(os.path.dirname(os.path.abspath(path)) or ".", directory=True)


def keep_access(tmp, path):
    """Give ``tmp`` the permission bits and group of the regular file at ``path`` it replaces
    (a group-writable texture in a shared folder stays so, and its group: a new file has the
    process's umask and primary group); the group only where this user may set it."""
    try:
        st = os.stat(path)
    except OSError:
        return
    if not stat.S_ISREG(st.st_mode):
        return
    os.chmod(tmp, stat.S_IMODE(st.st_mode))
    try:
        os.chown(tmp, -1, st.st_gid)
    except OSError:                  # not a group of this user's: the new file keeps its own
        pass
