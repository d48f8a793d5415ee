"""Albedo inversion on an OpenCL device: Rd -> alpha', rho and (with a mean free path)
sigma_a, sigma_s' (kernels/invert.cl). The methods and their knobs are in
``bdipole_cl.methods.registry``; ``method="auto"`` is resolved by ``bdipole_cl.methods.choice``.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import build_options, get_program, get_runtime, real_dtype
from ..device.layout import channel_params
from ..errors import check_policy, find_invalid
from ..methods.choice import resolve_method
from ..methods.registry import MFP_KINDS, MethodConfig
from ..physics import reference as ref
from ..physics import tables


#: largest float32 below 1: where ``on_invalid="clamp"`` puts Rd >= 1 for coefficients.
RD_CLAMP_MAX = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


#: where ``on_invalid="clamp"`` puts mfp values that are NaN, <= 0 or infinite.
MFP_CLAMP_RANGE = (1e-20, 1e20)


#: elements per kernel launch (bounds device memory for huge arrays).
CHUNK = 1 << 22


def channel_etas(eta, shape):
    """Etas per channel: one eta (also when all are equal), or one per channel along the last
    axis of ``shape``."""
    etas = np.atleast_1d(np.asarray(eta, dtype=np.float64))
    if etas.ndim != 1:
        raise ValueError(f"eta must be a scalar or one value per channel, got shape {etas.shape}")
    if etas.size == 1 or np.all(etas == etas[0]):
        return (float(etas[0]),)
    if len(shape) == 0 or shape[-1] != etas.size:
        raise ValueError(f"eta has {etas.size} values but the input's last axis has "
                         f"{shape[-1] if shape else 'no'} channels")
    return tuple(float(e) for e in etas)


#: kernels/invert.cl's output bits (BD_OUTPUTS)
OUTPUT_BITS = {"alpha": 1, "rho": 2, "sigma_a": 4, "sigma_s": 8}


def _literals(values, double):
    """C literals of the kernel's precision, comma-separated (a -D initializer list)."""
    return ",".join(repr(float(v)) + ("" if double else "f") for v in values)


class InversionKernel:
    """kernels/invert.cl built for one configuration, precision, model and tuple of etas, with
    its constant buffers on the device; call it on device buffers (benchmarks do).

    ``bake``: specialise the build for one job (a scene's): the channels' constant records are
    compiled in, and so are ``mfp_const`` (a constant mfp per channel: no mfp buffer is read)
    and ``outputs`` (only those are computed). Each distinct specialisation is built once."""

    def __init__(self, etas, config: MethodConfig, *, exact=False, model="better",
                 double=False, runtime=None, bake=False, mfp_const=None, outputs=None):
        self.rt = get_runtime(runtime)
        config = config.resolved(double)
        self.config, self.etas, self.exact, self.model = config, tuple(etas), exact, model
        self.dtype = real_dtype(double)
        self.nchan = len(etas)
        for e in etas:
            ref.check_eta(e, exact, model)
        self.table_n = config.table_n
        params = channel_params(etas, exact=exact, model=model, table_n=self.table_n,
                                dtype=self.dtype)
        defines = config.defines(double)
        self.mfp_baked = bake and mfp_const is not None
        if bake:
            defines["BD_BAKED_PARAMS"] = _literals(params, double)
            if mfp_const is not None:
                mfp_const = np.broadcast_to(np.asarray(mfp_const, np.float64), (self.nchan,))
                defines["BD_MFP_CONST"] = _literals(mfp_const, double)
            if outputs is not None:
                defines["BD_OUTPUTS"] = sum(OUTPUT_BITS[k] for k in outputs)
        opts = build_options(defines, double=double, model=model)
        self.kernel = cl.Kernel(get_program(self.rt, "invert", opts), "invert_albedo")
        tab = (tables.channel_tables(etas, self.table_n, exact=exact, model=model)
               if self.table_n else np.zeros((1, 4), np.float32))
        mf = cl.mem_flags
        self.params = cl.Buffer(self.rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=params)
        self.tables = cl.Buffer(self.rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=tab)

    @property
    def monotone(self) -> bool:
        """Whether alpha' is non-decreasing in Rd over every float32 Rd by construction
        (docs/model.md "Monotone inverse"): bisection always; the table without polish when
        every interval of every channel's table meets the margin; secant, memo and Newton
        polish are not (their last steps round in either direction)."""
        c = self.config
        if c.method == "bisection":
            return True
        if c.method != "table" or c.polish:
            return False
        return all(tables.table_is_monotone(e, c.table_size, self.exact, self.model)
                   for e in self.etas)

    def __call__(self, n, rd, mfp=None, *, alpha=None, rho=None, sigma_a=None, sigma_s=None,
                 wait_for=None):
        """Enqueue over ``n`` elements (a multiple of nchan); returns the kernel's event."""
        return self.kernel(self.rt.queue, (n,), None, rd, mfp, alpha, rho, sigma_a, sigma_s,
                           self.params, self.tables, np.int32(self.nchan),
                           np.int32(tables.entries_per_channel(self.table_n)), np.uint32(n),
                           wait_for=wait_for)

    def run(self, rd, mfp=None, want=("alpha",)):
        """Host arrays in, host arrays out, in chunks of at most CHUNK elements."""
        rt, dtype = self.rt, self.dtype
        rd = np.ascontiguousarray(rd, dtype=dtype).reshape(-1)
        mfp = None if mfp is None else np.ascontiguousarray(mfp, dtype=dtype).reshape(-1)
        n = rd.size
        outs = {k: np.empty(n, dtype) for k in want}
        chunk = CHUNK - CHUNK % self.nchan
        nbytes = min(chunk, max(n, 1)) * dtype.itemsize
        mf = cl.mem_flags
        bufs = {k: cl.Buffer(rt.context, mf.WRITE_ONLY, nbytes) for k in want}
        rd_buf = cl.Buffer(rt.context, mf.READ_ONLY, nbytes)
        mfp_buf = None if mfp is None else cl.Buffer(rt.context, mf.READ_ONLY, nbytes)
        for start in range(0, n, chunk):
            stop = min(start + chunk, n)
            cl.enqueue_copy(rt.queue, rd_buf, rd[start:stop])
            if mfp is not None:
                cl.enqueue_copy(rt.queue, mfp_buf, mfp[start:stop])
            self(stop - start, rd_buf, mfp_buf, **bufs)
            for k, b in bufs.items():
                cl.enqueue_copy(rt.queue, outs[k][start:stop], b)
        rt.queue.finish()
        return outs


def invert_albedo(rd, eta, method="table", *, return_rho=False, model="better", exact=False,
                  double=False, on_invalid="raise", iterations=None, tol=None, table_size=None,
                  polish=None, seed_size=None, device=None):
    """Invert memo eq. 3 on the device: reduced albedo alpha' (and rho = 1 - alpha') of ``rd``.

    Parameters
    ----------
    rd : array_like, any shape, float32 or float64
        Diffuse reflectance ("albedo"), linear. Rd <= 0 gives alpha' = 0, Rd = 1 gives 1.
    eta : float or sequence of float
        Relative index of refraction; one per channel (the last axis of ``rd``) allowed.
    method : {"table", "secant", "bisection", "memo", "auto"} or MethodConfig
        See the module docstring; knobs ``iterations``, ``tol``, ``table_size``, ``polish``,
        ``seed_size`` (None keeps each method's default). ``"auto"`` picks the cheapest
        measured configuration whose max relative rho error is <= ``tol`` (see
        ``resolve_method``).
    return_rho : bool
        Also return rho = 1 - alpha', computed without cancellation (use it, not 1 - alpha').
    model : {"better", "dipole"}
        Better Dipole (memo) or Jensen's classical dipole.
    exact : bool
        Exact Fresnel moments by quadrature instead of d'Eon's fits (wider eta range).
    double : bool
        Compute in float64 on the device (needs cl_khr_fp64).
    on_invalid : {"raise", "clamp"}
        Rd that is NaN, infinite or > 1: raise InvalidInputError (count, first index), or clamp
        (NaN and -inf -> 0, > 1 -> 1).
    device : None, str, pyopencl.Device or Runtime
        Where to run (``bdipole_cl.device``): None is the automatic choice.

    Returns
    -------
    alpha or (alpha, rho) : ndarray, shape of ``rd``, float32 (float64 with ``double``)
    """
    config = resolve_method(method, double=double, iterations=iterations, tol=tol,
                            table_size=table_size, polish=polish, seed_size=seed_size)
    rd = np.asarray(rd)
    if rd.dtype.kind != "f":
        rd = rd.astype(np.float64)
    etas = channel_etas(eta, rd.shape)
    bad = ~(rd <= 1.0) | np.isinf(rd)
    if find_invalid("albedo", rd, bad, "NaN, infinite or > 1", on_invalid):
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0, np.minimum(rd, 1.0))
    kernel = InversionKernel(etas, config, exact=exact, model=model, double=double,
                             runtime=device)
    outs = kernel.run(rd, None, ("alpha", "rho") if return_rho else ("alpha",))
    alpha = outs["alpha"].reshape(rd.shape)
    return (alpha, outs["rho"].reshape(rd.shape)) if return_rho else alpha


OUTPUTS = ("alpha", "rho", "sigma_a", "sigma_s", "sigma_t")


def check_mfp_kind(mfp_kind):
    if mfp_kind not in MFP_KINDS:
        raise ValueError(f"mfp_kind={mfp_kind!r}: expected one of {', '.join(MFP_KINDS)}")
    return mfp_kind


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


def extinction_coefficients(outs, mfp, outputs):
    """sigma_a = rho / mfp and sigma_s' = alpha' / mfp (sigma_t' = 1/mfp, docs/model.md
    "Mean free path"), added to ``outs`` in its precision."""
    wanted = set(outputs) | ({"sigma_a", "sigma_s"} if "sigma_t" in outputs else set())
    for sigma, base in (("sigma_a", "rho"), ("sigma_s", "alpha")):
        if sigma in wanted:
            outs[sigma] = outs[base] / mfp.astype(outs[base].dtype, copy=False)


def _sanitize_albedo_for_coefficients(rd, on_invalid):
    n = find_invalid("albedo", rd, ~(rd < 1.0) | np.isneginf(rd), "NaN, infinite or >= 1",
                     on_invalid)
    if n:
        rd = np.where(np.isnan(rd) | np.isneginf(rd), 0.0, np.minimum(rd, RD_CLAMP_MAX))
    return rd, n


def _sanitize_mfp(mfp, on_invalid):
    n = find_invalid("mfp", mfp, ~((mfp > 0.0) & np.isfinite(mfp)), "NaN, <= 0 or infinite",
                     on_invalid)
    if n:
        lo, hi = MFP_CLAMP_RANGE
        mfp = np.clip(np.nan_to_num(mfp, nan=hi, posinf=hi, neginf=lo), lo, hi)
    return mfp, n


class CoefficientMapper:
    """(albedo, mfp) arrays -> the requested outputs, with one prepared kernel; the engine of
    ``albedo_to_coefficients`` and of the texture pipeline (called once per band).

    ``bake``: a kernel specialised for this job (``InversionKernel``), with ``mfp_const`` (a
    constant mfp per channel, valid) compiled in when given. ``mfp_kind``: what the mfp is
    (``MFP_KINDS``)."""

    def __init__(self, etas, config: MethodConfig, *, outputs=("sigma_a", "sigma_s"),
                 model="better", exact=False, double=False, on_invalid="raise", device=None,
                 bake=False, mfp_const=None, mfp_kind="diffuse"):
        unknown = set(outputs) - set(OUTPUTS)
        if unknown:
            raise ValueError(f"unknown outputs {sorted(unknown)}: expected some of {OUTPUTS}")
        self.outputs = tuple(outputs)
        self.on_invalid = check_policy(on_invalid)
        self.extinction = check_mfp_kind(mfp_kind) == "extinction"
        self.kernel_wants = kernel_outputs(outputs, mfp_kind)
        if mfp_const is not None:
            _sanitize_mfp(np.asarray(mfp_const, np.float64), "raise")   # baked: must be valid
        self.kernel = InversionKernel(etas, config, exact=exact, model=model, double=double,
                                      runtime=device, bake=bake,
                                      mfp_const=None if self.extinction else mfp_const,
                                      outputs=self.kernel_wants)

    def __call__(self, rd, mfp, mask=None):
        """Returns ({output: array of rd's broadcast shape}, {"albedo": n, "mfp": n} invalid).

        ``mask`` (broadcast against ``rd``): texels where it is 0 are left out, neither
        validated nor inverted, and come out as 0."""
        rd, mfp = np.broadcast_arrays(np.asarray(rd), np.asarray(mfp))
        keep = None if mask is None else np.broadcast_to(np.asarray(mask) > 0, rd.shape)
        if keep is not None:
            if not keep.any():                 # nothing to invert: no device call at all
                zeros = np.zeros(rd.shape, self.kernel.dtype)
                return {k: zeros for k in self.outputs}, {"albedo": 0, "mfp": 0}
            rd = np.where(keep, rd, 0.0).astype(rd.dtype, copy=False)
            mfp = np.where(keep, mfp, 1.0).astype(mfp.dtype, copy=False)
        rd, n_rd = _sanitize_albedo_for_coefficients(rd, self.on_invalid)
        mfp, n_mfp = _sanitize_mfp(mfp, self.on_invalid)
        reads_mfp = not (self.kernel.mfp_baked or self.extinction)
        outs = self.kernel.run(rd, mfp if reads_mfp else None, self.kernel_wants)
        if self.extinction:
            extinction_coefficients(outs, mfp.reshape(-1), self.outputs)
        if keep is not None:
            flat = keep.reshape(-1)
            for k in outs:
                outs[k][~flat] = 0
        if "sigma_t" in self.outputs:
            outs["sigma_t"] = outs["sigma_a"] + outs["sigma_s"]
        return ({k: outs[k].reshape(rd.shape) for k in self.outputs},
                {"albedo": n_rd, "mfp": n_mfp})


def albedo_to_coefficients(rd, mfp, eta, method="table", *, model="better", exact=False,
                           double=False, on_invalid="raise", outputs=("sigma_a", "sigma_s"),
                           mfp_kind="diffuse", device=None, **knobs):
    """The memo's drop-in mapping: (albedo Rd, mean free path ld, eta) -> (sigma_a, sigma_s').

    ``mfp_kind="diffuse"`` (default): ``mfp = ld = 1/mu_tr`` (Jensen/Hery skin convention,
    docs/model.md "Mean free path"):
    ``sigma_t' = 1/(ld * mu_tr/sigma_t')`` with ``mu_tr/sigma_t' = sqrt(3 rho/(1 + rho))``
    (``sqrt(3 rho)`` for ``model="dipole"``),
    ``sigma_a = sigma_t' rho``, ``sigma_s' = sigma_t' alpha'``, in 1/(unit of mfp).
    ``mfp_kind="extinction"``: mfp is the medium's mean free path, ``sigma_t' = 1/mfp`` (OpenPBR,
    Standard Surface; exact for isotropic scattering, docs/model.md says what anisotropy means).

    ``rd`` and ``mfp`` are scalars, per-channel tuples or arrays, broadcast against each other;
    ``eta`` a scalar or one per channel. Rd -> 1 drives sigma_t' -> infinity for a fixed ld, so
    here Rd >= 1 is invalid (as are NaN/inf albedo and mfp that is NaN, <= 0 or infinite);
    ``on_invalid="clamp"`` maps Rd >= 1 to the largest float32 below 1 (finite, very large
    sigma_t'), NaN albedo to 0, and mfp into ``MFP_CLAMP_RANGE`` (NaN -> its top).

    ``outputs`` picks what is returned, in order, from alpha, rho, sigma_a, sigma_s, sigma_t.
    ``device``: where to run, as for ``invert_albedo``.
    """
    config = resolve_method(method, double=double, **knobs)
    rd, mfp = np.broadcast_arrays(np.asarray(rd), np.asarray(mfp))
    rd = rd.astype(np.float64) if rd.dtype.kind != "f" else rd
    mfp = mfp.astype(np.float64) if mfp.dtype.kind != "f" else mfp
    etas = channel_etas(eta, rd.shape)
    mapper = CoefficientMapper(etas, config, outputs=outputs, model=model, exact=exact,
                               double=double, on_invalid=on_invalid, device=device,
                               mfp_kind=mfp_kind)
    outs, _ = mapper(rd, mfp)
    result = tuple(outs[k] for k in outputs)
    return result if len(result) > 1 else result[0]
