"""A scene's planned job (the jobs layer): what the plan found for one job, what it computes
and leaves out, and why it is up to date or cannot run (``scene.plan`` makes them)."""
from __future__ import annotations

from dataclasses import dataclass, field

from ..io.colour import WorkingSpace
from ..methods.registry import MethodConfig


@dataclass
class PlannedJob:
    kind: str                        # job.JOB_KINDS: "invert", "blur", "stretch" or "constant"
    name: str                        # the material's or blur's name
    source: str                      # the albedo (invert), irradiance (blur) or mesh (stretch)
    udim: str | None
    output: str
    inputs: dict                     # role -> file
    computes: list = field(default_factory=list)
    left_out: list = field(default_factory=list)
    up_to_date: bool = False
    problem: str | None = None       # a missing input or a collision: the job cannot run
    params_digest: str = ""
    config: MethodConfig | None = None
    working: WorkingSpace | None = None   # the space its colours are converted into
    #: role -> ``freshness.input_identity`` of each input as the plan first read it (the
    #: bake fails the job if one differs when its output would be put in place)
    identities: dict | None = None
    #: the typed work where the plan made it (a "stretch" job's ``job.StretchWork``)
    work: object = None

    def describe(self) -> str:
        head = f"{self.kind} {self.name}" + (f" [{self.udim}]" if self.udim else "")
        lines = [f"{head}: {self.source} -> {self.output}"]
        if self.problem:
            return "\n".join(lines + [f"  cannot run: {self.problem}"])
        lines += [f"  computes: {c}" for c in self.computes]
        lines += [f"  leaves out: {x}" for x in self.left_out]
        return "\n".join(lines)
