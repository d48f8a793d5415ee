"""Outputs never land on inputs: the one collision check of every run (I/O layer).

A run (a texture batch, a scene's plan, a file blur, on this machine or a cluster) is a list
of ``Claim``: one job's output and its inputs by role (albedo, mfp, mask, irradiance, parameter
textures). ``collisions`` compares them all, jobs that will be skipped as up to date included
(their inputs are still the user's files), with every path resolved through links
(``os.path.realpath``; an existing file is also compared by device and inode, which catches
hard links). An output that is any input of any job, or the output of two jobs, is refused, and
the message names the job that owns the output and the job and role whose file it would
overwrite.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Claim:
    """What one job writes and reads: ``inputs`` is {role: path} (None paths ignored)."""

    job: str                       # how messages name the job (its source file)
    output: str
    inputs: dict = field(default_factory=dict)


def file_key(path) -> tuple:
    """Where ``path`` lands: its real path, and for an existing file (device, inode)."""
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
        return real, (st.st_dev, st.st_ino)
    except OSError:
        return real, None


def collisions(claims) -> list:
    """For each claim, in order: None if its output is safe to write, else the one-line
    reason (its output is an input of some job of the run, or two jobs share it)."""
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
    for c in claims:
        if c.output:                                   # a job without an output only reads
            writers.setdefault(file_key(c.output)[0], []).append(c.job)
    bad = [None] * len(claims)
    for n, c in enumerate(claims):
        if not c.output:
            continue
        real, inode = file_key(c.output)
        hit = readers_by_path.get(real) or (readers_by_inode.get(inode) if inode else None)
        if hit:
            job, role, p = hit
            whose = "its own" if job == c.job else f"{job}'s"
            bad[n] = (f"{c.job}: output {c.output} would overwrite an input ({whose} {role} "
                      f"{p}); choose another -o / output")
        elif len(writers[real]) > 1:
            others = ", ".join(j for j in writers[real] if j != c.job)
            bad[n] = (f"{c.job}: output {c.output} is also the output of {others}: put "
                      f"<UDIM>, {{udim}}, {{stem}} or {{name}} in -o so each input has its own")
    return bad


def check_claim(claim: Claim):
    """The single-job run (a file blur): ValueError naming the input it would overwrite."""
    bad = collisions([claim])[0]
    if bad:
        raise ValueError(bad)
