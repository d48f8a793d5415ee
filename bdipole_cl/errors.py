"""The invalid-input error family and the one policy vocabulary (the foundation layer).

Every operation that meets input the model cannot take (an albedo >= 1, a NaN mfp, an infinite
irradiance) raises ``InvalidInputError`` or, under ``on_invalid="clamp"``, replaces the values
by the nearest valid ones and counts them. The words are the same everywhere: the Python
``on_invalid=`` argument and the CLI's ``--on-invalid`` both take ``raise`` or ``clamp``. What
"nearest valid" means is each quantity's own rule, stated where it is applied (albedo: into
[0, 1); mfp: into [1e-20, 1e20]; irradiance, which has no upper bound: non-finite texels are
unlit, 0).
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
import warnings

import numpy as np

from .vocabulary import Option, Registry

#: what ``on_invalid`` takes, everywhere (the CLI's ``--on-invalid``, scene files' on_invalid)
POLICY = Registry("on_invalid", (
    Option("raise", "fail, naming the count and the first invalid value (the default)"),
    Option("clamp", "replace invalid values by the nearest valid ones and count them"),
))
POLICIES = POLICY.names


def check_numbers(value, name: str):
    """``value`` (a number, a sequence of them or a numeric array) as given, or a ValueError
    naming ``name`` where an entry is not a real number: a bool, a string or None would
    otherwise pass as 1.0, a parsed float or NaN."""
    if isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in "iuf":
        return value                   # (a list's bools would pass as a float array's 1.0)
    for e in np.ravel(np.asarray(value, dtype=object)):
        if isinstance(e, (bool, np.bool_)) or not isinstance(e, (int, float, np.integer,
                                                                np.floating)):
            raise ValueError(f"{name}={e!r}: expected a number (one, or one per channel)")
    return value


def plain_array(value, name):
    """``value`` as a NumPy array of real numbers; a masked array (numpy.ma) with masked
    values, or a complex, object or string array, is a ValueError naming it (its mask, or
    imaginary part, would be dropped silently)."""
    if isinstance(value, np.ma.MaskedArray) and np.ma.getmaskarray(value).any():
        raise ValueError(f"{name} is a masked array with {int(np.ma.count_masked(value))} "
                         f"masked value(s): fill them (numpy.ma.filled) first (texels left out "
                         f"are a mask: InversionPlan.apply's mask=, a scene's alpha or mask "
                         f"texture)")
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":   # complex (its imaginary part would be dropped),
        raise ValueError(f"{name} has dtype {array.dtype}: expected real numbers (float, "
                         f"int or bool)")  # objects, strings: refused, named
    return array


def check_policy(on_invalid: str) -> str:
    return POLICY.canonical(on_invalid)


def shortest(value) -> str:
    """``value`` in the fewest digits that still tell it apart in its own precision
    (1.0000001, not 1: a message saying "> 1: 1" is no help); ``g`` when that is as exact."""
    v = np.asarray(value)
    if v.dtype.kind != "f":
        return f"{float(v):g}"
    short = f"{float(v):g}"
    if not np.isfinite(v) or v.dtype.type(short) == v:
        return short
    return str(v[()])                  # NumPy's shortest repr that round-trips in its dtype


class InvalidInputError(ValueError):
    """Input values the model cannot take.

    ``name`` (albedo, mfp, irradiance, alpha, sigma_t), ``count``, the first bad element's
    ``first_index`` (a tuple; for HxWxC texel data ``(y, x, c)``) and ``first_value``, and
    ``why`` (the rule they break). The message names the first element as a texel (x, y,
    channel) when ``texels`` is true, else by its index."""

    def __init__(self, name, count, first_index, first_value, why, texels=False):
        self.name, self.count, self.first_index = name, count, tuple(first_index)
        self.first_value, self.why, self.texels = first_value, why, texels
        if texels and len(self.first_index) == 3:
            y, x, c = self.first_index
            where = f"x={x}, y={y}, channel {c}"
        else:
            where = f"index {self.first_index}"
        super().__init__(f"{count} invalid {name} value(s) ({why}); first at {where}: "
                         f"{shortest(first_value)} (on_invalid='clamp' / --on-invalid clamp "
                         f"clamps them)")

    def with_(self, *, count=None, first_index=None, why=None) -> "InvalidInputError":
        """This error with another count, first index or reason (the rest as it is): one
        counted over more than the check saw (and more rules), or named where it is in a
        larger image."""
        return InvalidInputError(self.name, self.count if count is None else count,
                                 self.first_index if first_index is None else first_index,
                                 self.first_value, self.why if why is None else why,
                                 self.texels)


def find_invalid(name, values, bad, why, on_invalid, texels=False, channel=None) -> int:
    """The count of ``bad`` elements of ``values``; with ``on_invalid="raise"`` and any bad,
    an InvalidInputError naming the first. ``texels``: the data are HxWxC texels (or HxW of
    channel ``channel``), named by x, y and channel."""
    check_policy(on_invalid)
    count = int(np.count_nonzero(bad))
    if count and on_invalid == "raise":
        first = np.unravel_index(int(np.flatnonzero(np.reshape(bad, -1))[0]), np.shape(bad))
        first = tuple(int(i) for i in first)
        value = np.asarray(values)[first].item()
        if channel is not None:
            first += (int(channel),)
        raise InvalidInputError(name, count, first, value, why, texels)
    return count


def moved_by(exc: InvalidInputError, origin) -> InvalidInputError:
    """``exc`` of a block of a larger array, its first index moved by the block's ``origin``
    (its first element's index in the array, per leading axis): named where it is in the
    array. The count stays the block's."""
    return exc.with_(first_index=tuple(int(i) + int(o) for i, o in zip(exc.first_index, origin))
                     + exc.first_index[len(origin):])


def one_line(text) -> str:
    """A message as one line: its lines (a library's error may hold several, some repeating
    an earlier one) joined by "; ", each once, white space folded."""
    seen = []
    for line in str(text).splitlines():
        line = " ".join(line.split())
        if line and not any(line in kept for kept in seen):
            seen.append(line)
    return "; ".join(seen)


#: the frames a warning is not attributed to: this package's and ``contextlib``'s (a context
#: manager of ours that warns on leaving is called by contextlib's ``__exit__``)
_SKIPPED = (os.path.dirname(os.path.abspath(__file__)) + os.sep,
            os.path.abspath(contextlib.__file__))
#: per thread, the (prefix, category) of the ``warnings_naming`` contexts it is within
_NAMING = threading.local()


def warn_caller(message, category=None):
    """``warnings.warn`` attributed to the first frame outside this package: the user's line
    that called the library (however deep in it the warning arose), not a line of ours. (On a
    thread of a pool, as Dask's workers, the user's line is not on the stack: the first frame
    outside the package is the pool's.) Within ``warnings_naming``, the message begins with
    its prefix."""
    kind = category or (type(message) if isinstance(message, Warning) else UserWarning)
    for prefix, named in reversed(getattr(_NAMING, "stack", ())):
        if issubclass(kind, named):
            message = kind(f"{prefix}: {message}")
            break
    depth, frame = 1, sys._getframe(1)
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(_SKIPPED):
        depth, frame = depth + 1, frame.f_back
    warnings.warn(message, kind, stacklevel=depth + 1)


@contextlib.contextmanager
def warnings_naming(prefix, category):
    """Within it, on this thread, the warnings of ``category`` that ``warn_caller`` says begin
    with ``prefix`` (the innermost context's): a file's warnings name the file, each tile of a
    set its own. Thread-local, where ``warnings.catch_warnings`` (process-wide) lost and
    mixed up the warnings of files blurred at once."""
    stack = _NAMING.__dict__.setdefault("stack", [])
    stack.append((prefix, category))
    try:
        yield
    finally:
        stack.pop()
