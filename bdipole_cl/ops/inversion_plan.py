"""The inversion plan: made once from what an inversion is (model, resolved method, etas,
outputs, mfp kind, precision, specialisation, runtime), holding its prepared kernel and that
kernel's device buffers, and applied to any number of arrays (bands of a file, files of a
batch) with ``apply``, into preallocated outputs where given. ``invert_albedo`` and
``albedo_to_coefficients`` (``bdipole_cl.ops.invert``) are a plan and one ``apply``.

Two validity rules, as docs/model.md "Input policy" gives them: without an mfp (``mfp_kind``
None: ``invert_albedo``) Rd = 1 is valid (alpha' = 1); with one (the coefficients) Rd >= 1 is
invalid, since sigma_t' -> infinity there.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from ..device import Runtime, get_runtime
from ..errors import InvalidInputError, check_policy, find_invalid, plain_array
from ..methods.choice import DeviceKey, resolve_method
from ..methods.registry import MFP_KIND, MFP_KINDS, OUTPUTS, MethodConfig
from ..physics.models import MODEL
from .host_arrays import (apart_from, channel_values, check_out_shapes, shared_channels,
                          texel_broadcast)
from ..device.transfer import is_device_array
from .inversion_device import apply_on_device, send_to, shares_memory
from .inversion_kernel import (CHECK_ALBEDO, CHECK_COEFFICIENTS, MFP_MIN, InversionKernel,
                               inversion_kernel, output_array)

#: largest float32 below 1: where ``on_invalid="clamp"`` puts Rd >= 1 for coefficients.
RD_CLAMP_MAX = float(np.nextafter(np.float32(1.0), np.float32(0.0)))

#: where ``on_invalid="clamp"`` puts mfp values that are NaN, below MFP_MIN or infinite.
MFP_CLAMP_RANGE = (MFP_MIN, 1e20)


def valid_mfp(mfp):
    """The coefficients' mfp rule: finite and >= MFP_MIN (a smaller one's coefficients could
    overflow float32)."""
    return (mfp >= MFP_MIN) & np.isfinite(mfp)


def check_outputs(outputs):
    """``outputs`` as a tuple: some of OUTPUTS, each at most once (a channel is written once),
    else ValueError."""
    outputs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
    unknown = [o for o in outputs if o not in OUTPUTS]
    if not outputs or unknown:
        raise ValueError(f"unknown outputs {unknown or 'none'}: expected some of {OUTPUTS}")
    twice = sorted({o for o in outputs if outputs.count(o) > 1})
    if twice:
        raise ValueError(f"outputs {', '.join(twice)} given more than once: each output is one "
                         f"set of channels")
    return outputs


def check_mfp_kind(mfp_kind):
    return MFP_KIND.canonical(mfp_kind)


def kernel_outputs(outputs, mfp_kind):
    """What the kernel computes for ``outputs``: with an extinction mfp the coefficients are
    alpha' and rho over the mfp (the host divides), so the kernel gives alpha' and rho."""
    wanted = set(outputs)
    if "sigma_t" in wanted:
        wanted |= {"sigma_a", "sigma_s"}
    if mfp_kind == "extinction":
        wanted |= {"rho"} if "sigma_a" in wanted else set()
        wanted |= {"alpha"} if "sigma_s" in wanted else set()
        wanted -= {"sigma_a", "sigma_s"}
    return tuple(k for k in ("alpha", "rho", "sigma_a", "sigma_s") if k in wanted)


def extinction_coefficients(outs, mfp, outputs, out=None):
    """sigma_a = rho / mfp and sigma_s' = alpha' / mfp (sigma_t' = 1/mfp, docs/model.md
    "Mean free path"), added to ``outs`` in its precision (into ``out``'s arrays if given)."""
    wanted = set(outputs) | ({"sigma_a", "sigma_s"} if "sigma_t" in outputs else set())
    for sigma, base in (("sigma_a", "rho"), ("sigma_s", "alpha")):
        if sigma in wanted:
            dtype = outs[base].dtype
            outs[sigma] = np.divide(outs[base], mfp.astype(dtype, copy=False),
                                    out=output_array(out, sigma, mfp.size, dtype))


def as_kernel_dtype(values, dtype):
    """``values`` rounded to the kernel's precision: what it will see, and so what is checked
    (a float64 Rd = 1 - 1e-8 < 1 is 1.0 in float32; an mfp of 1e-50 is 0)."""
    with np.errstate(over="ignore", under="ignore"):
        return np.asarray(values).astype(dtype, copy=False)


def invalid_albedo_count(rd, on_invalid) -> int:
    """The invalid count of ``rd`` under invert_albedo's rule (NaN, infinite or > 1; raise:
    the first named)."""
    return find_invalid("albedo", rd, ~(rd <= 1.0) | (rd == -np.inf), "NaN, infinite or > 1",
                        on_invalid)


def checked_albedo(rd, on_invalid):
    """``rd`` and its invalid count under invert_albedo's rule: NaN, infinite or > 1 raise
    (count, first index) or, with "clamp", NaN and -inf become 0 and > 1 becomes 1."""
    n = invalid_albedo_count(rd, on_invalid)
    if n:
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0, np.minimum(rd, 1.0))
    return rd, n


def invalid_coefficient_albedos(rd):
    """Where ``rd`` (in the kernel's precision) breaks the coefficients' rule: NaN, infinite
    or >= 1."""
    return ~(rd < 1.0) | (rd == -np.inf)


def checked_albedo_for_coefficients(rd, on_invalid, dtype=np.float32):
    """``rd`` in the kernel's precision and its invalid count under the coefficients' rule
    (``invalid_coefficient_albedos``); clamped: NaN, -inf -> 0 and >= 1 -> RD_CLAMP_MAX."""
    given, rd = rd, as_kernel_dtype(rd, dtype)
    n = find_invalid("albedo", given, invalid_coefficient_albedos(rd),
                     f"NaN, infinite or >= 1 as {np.dtype(dtype).name}", on_invalid)
    if n:
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0,
                      np.minimum(rd, RD_CLAMP_MAX)).astype(dtype)
    return rd, n


def checked_mfp(mfp, on_invalid, dtype=np.float32):
    """``mfp`` in the kernel's precision and its invalid count (``valid_mfp`` there); clamped
    into MFP_CLAMP_RANGE (NaN and +inf to its top)."""
    given, mfp = mfp, as_kernel_dtype(mfp, dtype)
    n = find_invalid("mfp", given, ~valid_mfp(mfp),
                     f"NaN, below {MFP_MIN:g} (its coefficients would overflow) or infinite "
                     f"as {np.dtype(dtype).name}", on_invalid)
    if n:
        lo, hi = MFP_CLAMP_RANGE
        mfp = np.clip(np.nan_to_num(mfp, nan=hi, posinf=hi, neginf=lo), lo, hi).astype(dtype)
    return mfp, n


def as_float(values, name="albedo"):
    """``values`` as an array, floating point (integers become float64); a masked, complex or
    non-numeric array a ValueError naming it (``errors.plain_array``)."""
    values = plain_array(values, name)
    return values if values.dtype.kind == "f" else values.astype(np.float64)


def invalid_map_values(mfp_map, keep, dtype) -> int:
    """Invalid values (``valid_mfp`` in ``dtype``) of a per-texel mfp map (its last axis 1)
    at texels some channel of which ``keep`` keeps (None: all): each value once, not once
    per channel it serves."""
    bad = ~valid_mfp(as_kernel_dtype(mfp_map, dtype))
    if keep is not None:
        bad &= keep.any(axis=-1, keepdims=True)
    return int(np.count_nonzero(bad))


@dataclass(frozen=True)
class Inverted:
    """One ``InversionPlan.apply``: the outputs (the plan's, in its order, each of the input's
    broadcast shape) and how many albedo and mfp values broke the plan's rule (clamped with
    ``on_invalid="clamp"``; with "raise" apply raised instead)."""

    arrays: dict
    invalid_albedo: int = 0
    invalid_mfp: int = 0


@dataclass(eq=False)
class InversionPlan:
    """An inversion made once and applied per band, per file (``apply``).

    etas : one relative index of refraction per channel (the last axis of the inputs; one eta
        serves every channel). config : the method, resolved for the precision (``plan_
        inversion`` resolves a name or "auto"). outputs : some of OUTPUTS, returned in that
        order. mfp_kind : None (no mfp: invert_albedo's rule, outputs alpha and rho only) or
        one of ``MFP_KINDS`` (the coefficients' rule). double : float64 on the device.
        specialise : compile this job's constants into the kernel (``InversionKernel``), and
        ``mfp_const`` (a valid mfp per channel) when given. runtime : where it runs (None,
        a device spec or a Runtime; resolved on construction).

    The plan holds its kernel (its program built once, its table, parameter, flag and mfp
    buffers on the device, kept for every apply). One apply runs at a time (a lock)."""

    etas: tuple
    config: MethodConfig = MethodConfig()
    outputs: tuple = ("alpha",)
    mfp_kind: str | None = None
    model: str = "better"
    exact: bool = False
    double: bool = False
    on_invalid: str = "raise"
    specialise: bool = False
    mfp_const: tuple | None = None
    runtime: Runtime | None = None
    kernel: InversionKernel = field(init=False, repr=False)
    kernel_outputs: tuple = field(init=False, repr=False)

    def __post_init__(self):
        self.etas = tuple(float(e) for e in self.etas)
        self.model = MODEL.canonical(self.model)
        self.config = self.config.resolved(self.double)
        self.outputs = check_outputs(self.outputs)
        check_policy(self.on_invalid)
        self.runtime = get_runtime(self.runtime)
        if self.mfp_kind is None:
            extra = [o for o in self.outputs if o not in ("alpha", "rho")]
            if extra or self.mfp_const is not None:
                raise ValueError(f"outputs {extra or ''} and mfp_const need an mfp: give "
                                 f"mfp_kind (one of {', '.join(MFP_KINDS)})")
        else:
            check_mfp_kind(self.mfp_kind)
        self.kernel_outputs = (self.outputs if self.mfp_kind is None
                               else kernel_outputs(self.outputs, self.mfp_kind))
        if self.mfp_const is not None:
            const = np.broadcast_to(np.asarray(self.mfp_const, np.float64), (len(self.etas),))
            checked_mfp(const, "raise", self.dtype)          # compiled in: must be valid
            self.mfp_const = tuple(float(v) for v in const)
        compiled_mfp = None if self.extinction else self.mfp_const
        if self.specialise:
            self.kernel = InversionKernel(self.etas, self.config, exact=self.exact,
                                          model=self.model, double=self.double,
                                          runtime=self.runtime, specialise=True,
                                          mfp_const=compiled_mfp, outputs=self.kernel_outputs)
        else:
            self.kernel = inversion_kernel(self.etas, self.config, exact=self.exact,
                                           model=self.model, double=self.double,
                                           runtime=self.runtime)
        self._lock = threading.Lock()

    @property
    def dtype(self):
        return np.dtype(np.float64 if self.double else np.float32)

    @property
    def extinction(self) -> bool:
        return self.mfp_kind == "extinction"

    def apply(self, rd, mfp=None, mask=None, out=None) -> Inverted:
        """Invert ``rd`` (any shape; the channels on its last axis when there are several
        etas), with ``mfp`` (broadcast against it; None for a plan without mfp, or to use
        ``mfp_const``).

        ``mask`` (broadcast against ``rd``): texels where it is 0 are left out, neither
        validated nor inverted, and come out as 0. ``out``: where to write the outputs, a
        {name: array} dict, a sequence in ``outputs`` order, or one array (the first output);
        each C-contiguous, writeable, of the input's shape (or flat, of its size) and the
        plan's dtype (on a device that shares host memory the kernel writes into them in
        place); outputs not given are new arrays.

        Device arrays (``pyopencl.array.Array``) in, device arrays out, on the plan's device
        (``inversion_device``)."""
        if is_device_array(rd) or is_device_array(mfp):
            with self._lock:
                outs, redo = apply_on_device(self, rd, mfp, mask, self._out_dict(out))
            if redo is None:
                return Inverted(outs)
            done = self._apply_host(redo.rd, redo.mfp)      # an input broke its rule
            send_to(outs, done.arrays)
            return Inverted(outs, done.invalid_albedo, done.invalid_mfp)
        return self._apply_host(rd, mfp, mask, out)

    def _apply_host(self, rd, mfp=None, mask=None, out=None) -> Inverted:
        out = self._out_dict(out)
        with self._lock:
            mfp_map, shared = None, 1
            if self.mfp_kind is None:
                if mfp is not None:
                    raise ValueError("this plan has no mfp (mfp_kind=None): apply(rd) only")
                rd, mfp = as_float(rd), None
            else:
                if mfp is None:
                    if self.mfp_const is None:
                        raise ValueError("this plan needs an mfp: apply(rd, mfp)")
                    mfp = np.asarray(self.mfp_const, np.float64)
                elif self.kernel.mfp_compiled and not self._is_compiled_mfp(mfp):
                    raise ValueError(
                        f"this plan compiled mfp_const={np.asarray(self.mfp_const).tolist()} "
                        f"into its kernel, which reads no other mfp: apply(rd) uses it; "
                        f"another mfp needs a plan without mfp_const (or specialise=False)")
                rd, mfp_map = texel_broadcast(as_float(rd), as_float(mfp, "mfp"))
                shared = shared_channels(rd, mfp_map)
                rd, mfp = np.broadcast_arrays(rd, mfp_map)
            self._check_channels(rd.shape)
            check_out_shapes(out, rd.shape)
            rd, mfp = apart_from(out, rd, mfp, mfp_after=self.mfp_kind == "extinction")
            keep = None if mask is None else self._keep(mask, rd.shape)
            if keep is not None:
                if not keep.any():                 # nothing to invert: no device call at all
                    return Inverted(self._zeros(rd.shape, out))
                rd = np.where(keep, rd, 0.0).astype(rd.dtype, copy=False)
                mfp = None if mfp is None else np.where(keep, mfp, 1.0).astype(mfp.dtype,
                                                                               copy=False)
            if self.mfp_kind is None:
                outs, n_rd = self._albedo(rd, out)
                n_mfp = 0
            else:
                try:
                    outs, n_rd, n_mfp, mfp = self._coefficients(rd, mfp, out)
                except InvalidInputError as exc:
                    if exc.name != "mfp" or shared == 1:
                        raise
                    raise exc.with_(                # counted once per value given
                        count=invalid_map_values(mfp_map, keep, self.dtype)) from None
                if n_mfp and shared > 1:
                    n_mfp = invalid_map_values(mfp_map, keep, self.dtype)
                if self.extinction:
                    extinction_coefficients(outs, mfp.reshape(-1), self.outputs, out)
            if keep is not None:
                flat = keep.reshape(-1)
                for k in outs:
                    outs[k][~flat] = 0
            if "sigma_t" in self.outputs:
                outs["sigma_t"] = np.add(outs["sigma_a"], outs["sigma_s"],
                                         out=output_array(out, "sigma_t", rd.size, self.dtype))
            return Inverted({k: outs[k].reshape(rd.shape) for k in self.outputs}, n_rd, n_mfp)

    def _check_channels(self, shape):
        """Several etas are one per channel of the input's last axis (ValueError if not)."""
        n = len(self.etas)
        if n > 1 and (len(shape) == 0 or shape[-1] != n):
            raise ValueError(f"eta has {n} values but the input's last axis has "
                             f"{shape[-1] if shape else 'no'} channels")

    def _keep(self, mask, shape):
        """The mask as booleans of the input's shape: an HxW mask of an HxWxC input masks
        every channel of its texels."""
        values = np.asarray(mask)
        if values.dtype.kind == "f" and np.isnan(values).any():
            first = tuple(int(i) for i in np.argwhere(np.isnan(values))[0])
            raise ValueError(f"mask: NaN at index {first}: a mask is 0 (left out) or > 0 (kept)")
        keep = values > 0
        if len(self.etas) > 1 and keep.ndim == len(shape) - 1:
            keep = keep[..., None]
        try:
            return np.broadcast_to(keep, shape)
        except ValueError:
            raise ValueError(f"mask of shape {np.shape(mask)} does not fit albedo of shape "
                             f"{tuple(shape)}: give one of its shape, or without its channel "
                             f"axis") from None

    def __reduce__(self):
        """Pickled as its settings: unpickled, it builds its kernel on the default device
        of the process that receives it."""
        return (InversionPlan, (self.etas, self.config, self.outputs, self.mfp_kind,
                                self.model, self.exact, self.double, self.on_invalid,
                                self.specialise, self.mfp_const))

    def _out_dict(self, out):
        if out is None:
            return out
        if isinstance(out, dict):
            arrays = out
        else:
            seq = (out,) if isinstance(out, np.ndarray) or is_device_array(out) else tuple(out)
            if len(seq) > len(self.outputs):
                raise ValueError(f"out: {len(seq)} arrays for the {len(self.outputs)} "
                                 f"outputs {', '.join(self.outputs)}")
            arrays = dict(zip(self.outputs, seq))
        names = list(arrays)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                if shares_memory(arrays[a], arrays[b]):
                    raise ValueError(f"out: the arrays for {a} and {b} overlap; give each "
                                     f"output its own memory")
        return arrays

    def _zeros(self, shape, out):
        n = int(np.prod(shape))
        arrays = {}
        for k in self.outputs:
            arrays[k] = output_array(out, k, n, self.dtype).reshape(shape)
            arrays[k][...] = 0
        return arrays

    def _albedo(self, rd, out):
        """invert_albedo's rule: the kernel's outputs (1-D) and the invalid count. float32 is
        tested by the kernel as it reads it; the host looks again only when it saw one."""
        k = self.kernel
        in_kernel = k.checks_inputs(rd)
        n_rd = 0
        if not in_kernel:
            rd, n_rd = checked_albedo(rd, self.on_invalid)
        outs, flagged = k.run_checked(rd, None, self.kernel_outputs, out=out,
                                      check=CHECK_ALBEDO if in_kernel else 0)
        if flagged:
            # the first invalid value named (raise); with "clamp" the kernel's results already
            # are those of the clamped input: NaN, -inf -> (0, 1) as Rd = 0, > 1 -> (1, 0)
            n_rd = invalid_albedo_count(rd, self.on_invalid)
        return outs, n_rd

    def _is_compiled_mfp(self, mfp) -> bool:
        """Whether ``mfp`` is the plan's ``mfp_const`` at every texel and channel."""
        try:
            return bool(np.all(np.asarray(mfp, np.float64)
                               == np.asarray(self.mfp_const, np.float64)))
        except (ValueError, TypeError):                # does not broadcast: a map
            return False

    def _coefficients(self, rd, mfp, out):
        """The kernel's outputs (1-D), the invalid albedo and mfp counts, and the mfp (checked,
        for the host's share of the work: an extinction mfp's division). An mfp constant
        per channel goes to the kernel as one value per channel (no per-texel mfp array), and
        float32 inputs are tested by the kernel as it reads them: the host looks at them again
        only when it saw an invalid one."""
        k, policy = self.kernel, self.on_invalid
        reads_mfp = not (k.mfp_compiled or self.extinction)
        per_channel = channel_values(mfp, k.nchan) if reads_mfp and k.width else None
        as_kernel = None if per_channel is None else as_kernel_dtype(per_channel, k.dtype)
        if as_kernel is not None and not np.all(valid_mfp(as_kernel)):
            per_channel = None            # the texels named (or clamped) one by one, below
        n_mfp, host_mfp = 0, mfp
        if not reads_mfp:                 # compiled in, or divided by on the host: checked here
            host_mfp, n_mfp = checked_mfp(mfp, policy, k.dtype)
        if per_channel is not None or not reads_mfp:
            mfp = None
        def host_checked(rd, mfp, n_mfp):
            """The kernel's inputs tested on the host: (rd, its count, mfp, its count)."""
            rd, n_rd = checked_albedo_for_coefficients(rd, policy, k.dtype)
            if mfp is not None:
                mfp, n_mfp = checked_mfp(mfp, policy, k.dtype)
            return rd, n_rd, mfp, n_mfp

        in_kernel = k.checks_inputs(rd, *([] if mfp is None else [mfp]))
        n_rd = 0
        if not in_kernel:
            rd, n_rd, mfp, n_mfp = host_checked(rd, mfp, n_mfp)
        outs, flagged = k.run_checked(rd, mfp, self.kernel_outputs, mfp_channels=per_channel,
                                      check=CHECK_COEFFICIENTS if in_kernel else 0, out=out)
        if flagged and policy == "raise":          # the first named
            host_checked(rd, mfp, n_mfp)
        elif flagged:                               # the invalid texels clamped and mapped again
            n_rd, n_mfp = self._clamped_texels(rd, mfp, per_channel, outs, n_mfp)
        return outs, n_rd, n_mfp, host_mfp if mfp is None else mfp

    def _clamped_texels(self, rd, mfp, per_channel, outs, n_mfp):
        """The texels (all their channels, so that each element keeps its channel) with an
        invalid albedo or mfp, clamped (``checked_albedo_for_coefficients``, ``checked_mfp``)
        and mapped again into ``outs``: one pass to find them, not a clamped copy of the whole
        input mapped again. Returns the invalid albedo and mfp counts."""
        k, nchan = self.kernel, self.kernel.nchan
        rd = rd.reshape(-1)
        mfp = None if mfp is None else mfp.reshape(-1)
        bad = invalid_coefficient_albedos(rd)
        if mfp is not None:
            bad |= ~valid_mfp(mfp)
        texels = np.unique(np.flatnonzero(bad) // nchan)
        elements = (texels[:, None] * nchan + np.arange(nchan)).reshape(-1)
        sub_rd, n_rd = checked_albedo_for_coefficients(rd[elements], "clamp", k.dtype)
        sub_mfp = None
        if mfp is not None:
            sub_mfp, n_mfp = checked_mfp(mfp[elements], "clamp", k.dtype)
        fixed = k.run(sub_rd, sub_mfp, self.kernel_outputs, mfp_channels=per_channel)
        for name, values in fixed.items():
            outs[name][elements] = values
        return n_rd, n_mfp


def plan_inversion(etas, method="table", *, outputs=("alpha",), mfp_kind=None,
                   model="better", exact=False, double=False, on_invalid="raise",
                   specialise=False, mfp_const=None, device=None, **knobs) -> InversionPlan:
    """An InversionPlan from a method name (or MethodConfig, or "auto": resolved on the
    device's choice data, ``resolve_method``) and its knobs (``iterations``, ``tol``,
    ``table_size``, ``polish``, ``seed_size``; None keeps the defaults)."""
    rt = get_runtime(device)
    config = resolve_method(method, double=double, device_key=DeviceKey.of(rt.device),
                            **knobs)
    etas = tuple(float(e) for e in np.atleast_1d(np.asarray(etas, np.float64)))
    return InversionPlan(etas, config, outputs=outputs, mfp_kind=mfp_kind, model=model,
                         exact=exact, double=double, on_invalid=on_invalid,
                         specialise=specialise, mfp_const=mfp_const, runtime=rt)
