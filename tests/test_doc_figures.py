"""Every figure the docs state from the code (a threshold, a constant, a measurement the code
ships) carries a marker naming it, ``9.64e-7<!--figure:auto_float32_floor-->`` (invisible
in the rendered page), and equals the code's value to the digits written; every threshold
stated on tol (``tol >= N``, ``| >= N |``) carries one. So no page can state a figure the
code no longer has (docs/performance.md kept the float32 ``auto`` floor at 8.4e-7, the bare
measurement, after docs/numerics.md and the code had 9.64e-7)."""
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
#: a number and the marker after it (the number possibly in bold or code)
MARKED = re.compile(r"([0-9][0-9.]*(?:e[-+]?[0-9]+)?)(?:\*\*|`)?<!--figure:([a-z0-9_]+)-->")
#: a threshold on tol, or a row of a table of them: the number must be marked
THRESHOLD = re.compile(r"(?:\btol\s*(?:>=|<=|>|<)|^\|\s*(?:>=|<)|qualifies from(?: tol >=)?"
                       r"|\bfrom tol >=)\s*(~?)([0-9][0-9.]*(?:e[-+]?[0-9]+)?)"
                       r"((?:\*\*|`)?<!--figure:)?")


def _auto_f32(size=None):
    from bdipole_cl.methods.choice import choice_for
    data, _ = choice_for(None)
    return min(c.max_rho_error for c in data.inversion if c.precision == "f32" and c.monotone
               and (size is None or (c.config.method == "table"
                                     and c.config.table_size == size)))


def _figures() -> dict:
    """{name: the code's value} of every figure the docs state."""
    from bdipole_cl.methods import choice
    from bdipole_cl.ops.blur.weights import channel_kernel
    return {
        "auto_margin": choice.AUTO_MARGIN,
        "auto_default_tol": choice.AUTO_DEFAULT_TOL,
        "auto_float32_floor": choice.auto_inversion_floor(False),
        "auto_float32_error": _auto_f32(),
        "auto_float32_table128_from": _auto_f32(128) * choice.AUTO_MARGIN,
        "auto_float32_table64_from": _auto_f32(64) * choice.AUTO_MARGIN,
        "auto_float64_error": choice.auto_inversion_floor(True) / choice.AUTO_MARGIN,
        "blur_max_radius": inspect.signature(channel_kernel).parameters["max_radius"].default,
    }


def _digits(text: str) -> int:
    """Significant digits written in a number ("9.64e-7": 3, "2048": 4, "1e-4": 1)."""
    mantissa = text.split("e")[0].replace(".", "").lstrip("0")
    return max(len(mantissa), 1)


def test_every_marked_figure_is_the_codes():
    figures = _figures()
    seen, wrong = set(), []
    for page in PAGES:
        for n, line in enumerate(page.read_text().splitlines(), 1):
            for number, name in MARKED.findall(line):
                assert name in figures, f"{page.name}:{n}: no figure named {name!r}"
                seen.add(name)
                want = float(f"{figures[name]:.{_digits(number)}g}")
                if float(number) != want:
                    wrong.append(f"{page.name}:{n}: {number} ({name}); the code's: {want:g}")
    assert not wrong, wrong
    assert seen == set(figures), f"figures no page states: {sorted(set(figures) - seen)}"


def test_every_threshold_on_tol_is_a_marked_figure():
    """A threshold on tol written without its marker (approximations, ``tol >= ~1e-4``,
    aside) fails: it would drift from the code unseen."""
    unmarked = []
    for page in PAGES:
        for n, line in enumerate(page.read_text().splitlines(), 1):
            for approx, number, marker in THRESHOLD.findall(line):
                if not approx and not marker:
                    unmarked.append(f"{page.name}:{n}: {number}: {line.strip()[:90]}")
    assert not unmarked, unmarked


@pytest.mark.parametrize("line, stale", [
    ("- float32, any tol >= 8.4e-7: table(256)", True),
    ("- float32, any tol >= 8.4e-7<!--figure:auto_float32_floor-->: table(256)", True),
    ("- float32, any tol >= 9.64e-7<!--figure:auto_float32_floor-->: table(256)", False),
])
def test_the_checks_catch_the_drift_they_are_for(line, stale):
    # the performance page's stale line, unmarked or marked, is caught; the right one passes
    figures = _figures()
    unmarked = [m for m in THRESHOLD.findall(line) if not m[0] and not m[2]]
    wrong = [(number, name) for number, name in MARKED.findall(line)
             if float(number) != float(f"{figures[name]:.{_digits(number)}g}")]
    assert bool(unmarked or wrong) == stale, (unmarked, wrong)
