"""Outputs never land on inputs: the one collision check of every run (I/O layer).

A run (a texture batch, a scene's plan, a file blur, on this machine or a cluster) is a list
of ``Claim``: one job's output and its inputs by role (albedo, mfp, mask, irradiance, parameter
textures). ``collisions`` compares them all, jobs that will be skipped as up to date included
(their inputs are still the user's files), with every path resolved through links
(``os.path.realpath``; an existing file is also compared by device and inode, which catches
hard links). An output that is any input of any job, or the output of two jobs, is refused, and
the message names the job that owns the output and the job and role whose file it would
overwrite. An output path that already holds a file this tool did not write (``foreign``:
a painted texture, a maketx'd one, anything without the ``bdipole:version`` header or the
preview's mark) is refused too, unless the run is forced (``force``): an output replaces only
what bdipole-cl made, or what the user said it may.
"""
from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field

from .images import SOFTWARE, image_header

#: the mark a contact sheet carries (PNG text "Software", SVG creator), so that a later
#: ``preview`` may replace it
PICTURE_MARK = "bdipole_cl preview"
#: an SVG sheet's mark: the creator element matplotlib writes for it (the words alone, in a
#: comment of a hand-made SVG, are not the mark)
SVG_MARK = f"<dc:creator>\n     <cc:Agent>\n      <dc:title>{PICTURE_MARK}</dc:title>"


@dataclass(frozen=True)
class Claim:
    """What one job writes and reads: ``inputs`` is {role: path} (None paths ignored);
    ``companions``: the files it writes beside ``output`` (a conversion's layer files), each
    checked as its output is against every input and every other file the run writes."""

    job: str                       # how messages name the job (its source file)
    output: str
    inputs: dict = field(default_factory=dict)
    companions: tuple = ()

    def written(self) -> tuple:
        """Every file the job writes: its output, then its companions."""
        return ((self.output,) if self.output else ()) + tuple(self.companions)


def file_key(path) -> tuple:
    """Where ``path`` lands: its real path, and for an existing file (device, inode)."""
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
        return real, (st.st_dev, st.st_ino)
    except OSError:
        return real, None


def ours(path) -> bool:
    """``path`` (an existing regular file) is one of this tool's outputs: an image whose header
    has ``bdipole:version`` (every output has it; an unrelated ``bdipole:`` attribute is not
    the mark) whose Software, if any, is this tool's, and, if it is a texture
    (``textureformat``, maketx's mark), ``bdipole:texture``
    (this tool's texture outputs have it: a texture another tool made from one of its outputs
    copies the rest of the header and is the user's), or a contact sheet with PICTURE_MARK."""
    if str(path).lower().endswith(".svg"):
        with open(path, "rb") as f:
            return SVG_MARK.encode() in f.read(1 << 16)
    spec = image_header(path)
    if spec is None:
        return False
    software = spec.getattribute("Software")
    if spec.getattribute("bdipole:version"):
        # an edit by another tool keeps the header but writes its own Software (outputs
        # written before this tool wrote Software have none)
        return ((software is None or str(software).startswith(SOFTWARE))
                and (spec.getattribute("textureformat") is None
                     or spec.getattribute("bdipole:texture") is not None))
    return PICTURE_MARK in str(software or "")


def foreign(path, is_ours=ours):
    """None if writing ``path`` replaces nothing but this tool's own output (nothing there,
    or ``is_ours``: ``ours`` for images and pictures), else the one-line reason. A symbolic
    link is judged by its target (the write replaces the link with the file); a directory,
    FIFO or device is never replaced."""
    try:
        mode = os.stat(path).st_mode
    except NotADirectoryError:               # a file where its folder would be
        return f"output {path}: {blocking_file(path)} is a file, not a folder; give a file path"
    except OSError:
        return None                          # nothing there (or a dangling link)
    if not stat.S_ISREG(mode):
        kind = "a directory, " if stat.S_ISDIR(mode) else ""
        return f"output {path} is {kind}not a regular file; give a file path"
    if is_ours(path):
        return None
    return (f"output {path} exists and was not written by bdipole-cl (or was changed since); "
            f"move it, choose another output, or pass --force (force=True) to replace it")


def blocking_file(path) -> str:
    """The nearest existing ancestor of ``path`` that is not a folder (why it cannot be made)."""
    parent = os.path.dirname(os.path.abspath(path))
    while parent and not os.path.exists(parent):
        parent = os.path.dirname(parent)
    return parent


def refusal(path, force=False, is_ours=ours):
    """``foreign``'s reason where it stands: a directory or other non-regular file always, a
    file this tool did not write unless ``force``; else None."""
    why = foreign(path, is_ours)
    return why if why and (not force or why.endswith("file path")) else None


def telling_apart(jobs) -> str:
    """The -o fields that tell ``jobs`` (their input files) apart: ``{dir}`` where they
    share a file name in several folders, else the name's fields and the tile's."""
    names = {os.path.basename(str(j)) for j in jobs}
    if len(names) == 1 and len({os.path.dirname(str(j)) for j in jobs}) > 1:
        return "{dir} (the inputs share their file name, in several folders)"
    return "<UDIM>, {udim}, {stem} or {name}"


def collisions(claims, force=False) -> list:
    """For each claim, in order: None if its output is safe to write, else the one-line
    reason (its output is an input of some job of the run, or two jobs share it, or it holds
    a file this tool did not write and the run is not ``force``d: ``foreign``)."""
    claims = list(claims)
    readers_by_path, readers_by_inode = {}, {}
    for c in claims:
        for role, p in c.inputs.items():
            if not p:
                continue
            real, inode = file_key(p)
            readers_by_path.setdefault(real, (c.job, role, p))
            if inode is not None:
                readers_by_inode.setdefault(inode, (c.job, role, p))
    writers = {}
    for c in claims:                                   # a job without an output only reads
        for p in c.written():
            writers.setdefault(file_key(p)[0], []).append((c.job, p == c.output))
    bad = [None] * len(claims)
    for n, c in enumerate(claims):
        for p in c.written():
            bad[n] = written_clash(c, p, readers_by_path, readers_by_inode, writers)
            if bad[n]:
                break
        if not bad[n] and c.output:
            why = refusal(c.output, force)
            bad[n] = f"{c.job}: {why}" if why else None
    return bad


def written_clash(c: Claim, path, readers_by_path, readers_by_inode, writers):
    """Why ``c`` may not write ``path`` (its output or a companion): an input of the run is
    there, or another job writes it too (as its output or a companion); else None.
    ``writers``: {real path: [(job, whether it is that job's output)]}."""
    own = path == c.output
    what = "output" if own else "layer file"
    real, inode = file_key(path)
    hit = readers_by_path.get(real) or (readers_by_inode.get(inode) if inode else None)
    if hit:
        job, role, p = hit
        whose = "its own" if job == c.job else f"{job}'s"
        return (f"{c.job}: {what} {path} would overwrite an input{'' if own else ' of this run'}"
                f" ({whose} {role} {p}); choose another -o (a scene: its output key)")
    if len(writers[real]) > 1:
        others = ", ".join(j for j, _ in writers[real] if j != c.job)
        whose = "the output of" if all(o for _, o in writers[real]) else "written by"
        return (f"{c.job}: {what} {path} is also {whose} {others}: put "
                f"{telling_apart([j for j, _ in writers[real]])} in -o (a scene: its output "
                f"key) so each input has its own")
    return None


def check_claim(claim: Claim, force=False):
    """The single-job run (a file blur, a preview): ValueError naming the input it would
    overwrite, or the file not of this tool's making it would replace (unless ``force``)."""
    bad = collisions([claim], force)[0]
    if bad:
        raise ValueError(bad)
