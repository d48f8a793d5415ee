"""What running jobs reports: a FileResult per job, a BatchReport per run."""
from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import one_line


@dataclass
class FileResult:
    path: str
    output: str | None = None
    status: str = "failed"            # ok | failed | skipped | cancelled
    error: str | None = None
    texels: int = 0
    seconds: float = 0.0
    invalid: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)       # e.g. channels left out
    colour: str | None = None                       # its colour path (ColourPath.describe)
    values: dict = field(default_factory=dict)      # a constant material's coefficients
    info: object = None                             # a blur's BlurInfo (None: not a blur)
    companion: bool = False       # a file beside the outputs (a layer's, materials): counted
    #                               apart from the jobs, by its first note (its kind)

    @property
    def mtexel_per_s(self):
        return self.texels / self.seconds / 1e6 if self.seconds > 0 else 0.0


@dataclass
class BatchReport:
    results: list

    @property
    def ok(self):
        return all(r.status in ("ok", "skipped") for r in self.results)

    @property
    def exit_code(self):
        return 0 if self.ok else 1

    def summary(self):
        rows = [("file", "status", "texels", "Mtexel/s", "invalid values", "output / reason")]
        for r in self.results:
            inv = ", ".join(f"{k} {v}" for k, v in r.invalid.items() if v) or "0"
            rows.append((r.path, r.status, f"{r.texels}", f"{r.mtexel_per_s:.3g}", inv,
                         one_line(r.error) if r.status in ("failed", "cancelled") else
                         (r.output or "") + "".join(f" ({n})" for n in r.notes)))
        widths = [max(len(row[i]) for row in rows) for i in range(5)]
        lines = []
        for row, r in zip(rows, [None] + self.results):
            lines.append("  ".join(c.ljust(w) for c, w in zip(row[:5], widths)) + "  " + row[5])
            if r is not None and r.colour:
                lines.append(f"  colour: {r.colour}")
        done = sum(r.status == "ok" and not r.companion for r in self.results)
        beside = [r for r in self.results if r.status == "ok" and r.companion]
        kinds = list(dict.fromkeys(r.notes[0] for r in beside if r.notes))
        failed = sum(r.status == "failed" and not r.companion for r in self.results)
        beside_failed = sum(r.status == "failed" and r.companion for r in self.results)
        skipped = sum(r.status == "skipped" for r in self.results)
        cancelled = sum(r.status == "cancelled" for r in self.results)
        lines.append(f"{done} done, {failed} failed, {skipped} skipped"
                     + (f", {cancelled} cancelled" if cancelled else "")
                     + (f"; {len(beside)} files beside them ({', '.join(kinds)})"
                        if beside else "")
                     + (f"; {beside_failed} failed beside them" if beside_failed else ""))
        return "\n".join(lines)
