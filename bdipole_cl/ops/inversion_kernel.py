"""The inversion kernels prepared on a device: kernels/invert.cl for every method, and
kernels/invert_table.cl, the default (the float32 table without polish) on several elements a
work-item; host arrays in and out through ``bdipole_cl.device.transfer``.
"""
from __future__ import annotations

import threading

import numpy as np
import pyopencl as cl

from ..caches import ByteCache
from ..device import build_options, get_program, get_runtime, real_dtype
from ..device.programs import kernels_digest
from ..device.launch import enqueue_items
from ..device.layout import channel_params
from ..device.runtime import device_kind, forced_width, platform_entry
from ..device.transfer import aligned_empty, run_elementwise
from .widths import WidthChoice, built_at_width, choose_width
from ..methods.choice import TABLE_WIDTHS_ALLOWED, DeviceKey, device_tuning
from ..methods.registry import MethodConfig
from ..physics import reference as ref
from ..physics import tables


#: kernels/invert_table.cl's validity tests (BD_CHECK): invert_albedo's rule (Rd NaN, infinite
#: or > 1) and the coefficients' (Rd NaN, infinite or >= 1; mfp NaN, below MFP_MIN or infinite)
CHECK_ALBEDO, CHECK_COEFFICIENTS = 1, 2

#: the least valid mfp: below it sigma' = f(Rd) / mfp can pass float32's 3.4e38 (f reaches
#: ~1e4 at the largest float32 albedo below 1), so 1e-20 keeps every coefficient finite
MFP_MIN = 1e-20

#: kernels/invert.cl's output bits (BD_OUTPUTS)
OUTPUT_BITS = {"alpha": 1, "rho": 2, "sigma_a": 4, "sigma_s": 8}


def vectorised(config: MethodConfig, double: bool) -> bool:
    """Whether ``config`` runs as kernels/invert_table.cl (the float32 table without polish:
    the default), BD_WIDTH elements a work-item, rather than kernels/invert.cl."""
    c = config.resolved(double)
    return c.method == "table" and not c.polish and not double


#: elements per work-item of kernels/invert_table.cl by OpenCL platform (a case-insensitive
#: part of its name), then by the device's native float vector lanes (None: any other),
#: measured at 32M texels (tools/bench_invert.py with BDIPOLE_CL_TABLE_WIDTH): Intel's CPU
#: runtime is fastest at 16 on an AVX CPU (8 lanes: the AMD EPYC VM; 8 was 25% slower) and at
#: 1 on an AVX-512 one (16 lanes: the Xeon VM, where it vectorises the one-element kernel
#: itself with gather instructions: 1.4x width 8 at one channel, 2.9x at three), PoCL at 8 on
#: the AVX CPU and 16 on the AVX-512 one (1.3x width 8 there); devices not listed (GPUs) get
#: one element per item. ``report --calibrate`` measures the device's own.
TABLE_WIDTHS = {"intel(r) opencl": {16: 1, None: 16},
                "portable computing language": {16: 16, None: 8}}
#: ``BDIPOLE_CL_TABLE_WIDTH`` overrides the width (1, 2, 4, 8 or 16), for measuring
TABLE_WIDTH_VARIABLE = "BDIPOLE_CL_TABLE_WIDTH"


def kernel_tuning(rt):
    """The KernelTuning ``report --calibrate`` measured on ``rt``'s device for these kernels
    (``methods.choice.device_tuning``), or None."""
    return device_tuning(DeviceKey.of(rt.device), kernels_digest())


def table_width(rt) -> int:
    """Elements per work-item of kernels/invert_table.cl on ``rt``'s device
    (``table_width_choice``)."""
    return table_width_choice(rt).width


def table_width_choice(rt) -> WidthChoice:
    """The width of kernels/invert_table.cl on ``rt``'s device and what decided it: forced by
    TABLE_WIDTH_VARIABLE, else the device's calibration (``report --calibrate``), else the
    fastest width its probe timed (``device.isolation``), else TABLE_WIDTHS; a width the probe
    rejected is never chosen."""
    forced = forced_width(TABLE_WIDTH_VARIABLE, TABLE_WIDTHS_ALLOWED)
    if forced:
        return WidthChoice(forced, f"forced by {TABLE_WIDTH_VARIABLE}")
    tuned = kernel_tuning(rt)
    widths = platform_entry(rt.device, TABLE_WIDTHS, {None: 8})
    default = widths.get(rt.device.native_vector_width_float, widths[None])
    if device_kind(rt.device) != "cpu":
        default = 1
    return choose_width(rt, "invert_table", TABLE_WIDTHS_ALLOWED,
                        tuned.table_width if tuned is not None else None, default)


def _literals(values, double):
    """C literals of the kernel's precision, comma-separated (a -D initializer list)."""
    return ",".join(repr(float(v)) + ("" if double else "f") for v in values)


def interval_records(rows):
    """The table's rows ((m, 4) float32: each interval's c0..c3, a segment's end node after its
    intervals) as kernels/invert_table.cl reads them: (m, 4), c0, c1, c2, then the interval's
    end node (the next row's c0: the same float as kernels/invert.cl reads); the kernel derives
    c3 from them, as the rows hold it (``tables.derived_c3``)."""
    records = np.zeros((rows.shape[0], 4), np.float32)
    records[:, :3] = rows[:, :3]
    records[:-1, 3] = rows[1:, 0]
    return records


class InversionKernel:
    """kernels/invert.cl built for one configuration, precision, model and tuple of etas, with
    its constant buffers on the device; call it on device buffers (benchmarks do), or on host
    arrays with ``run`` / ``run_checked`` (one call at a time: a lock serialises them, as a
    pyopencl Kernel's arguments are set per call).

    ``specialise`` (``bake`` is its old name): compile constants of one job into the build:
    the channels' constant records, ``mfp_const`` (a constant mfp per channel: no mfp buffer is
    read) and ``outputs`` (only those are computed). Each distinct specialisation is built
    once (``bdipole_cl.device.programs``' cache)."""

    def __init__(self, etas, config: MethodConfig, *, exact=False, model="better",
                 double=False, runtime=None, specialise=False, mfp_const=None, outputs=None,
                 bake=None):
        specialise = bool(specialise or bake)
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
        self.mfp_compiled = specialise and mfp_const is not None
        if specialise:
            defines["BD_CONST_PARAMS"] = _literals(params, double)
            if mfp_const is not None:
                mfp_const = np.broadcast_to(np.asarray(mfp_const, np.float64), (self.nchan,))
                defines["BD_MFP_CONST"] = _literals(mfp_const, double)
            if outputs is not None:
                defines["BD_OUTPUTS"] = sum(OUTPUT_BITS[k] for k in outputs)
        self.width = table_width(self.rt) if vectorised(config, double) else 0
        self._table_kernels = {}
        if self.width:
            # kernels/invert_table.cl: built per set of outputs (on the first call)
            self._table_defines = {"BD_TABLE_N": config.table_size, "BD_NCHAN": self.nchan}
            if specialise:
                self._table_defines["BD_CONST_PARAMS"] = defines["BD_CONST_PARAMS"]
            if self.mfp_compiled:
                self._table_defines["BD_MFP_CONST"] = defines["BD_MFP_CONST"]
            self.kernel = None
        else:
            opts = build_options(defines, double=double, model=model)
            self.kernel = cl.Kernel(get_program(self.rt, "invert", opts), "invert_albedo")
        tab = (tables.channel_tables(etas, self.table_n, exact=exact, model=model)
               if self.table_n else np.zeros((1, 4), np.float32))
        if self.width:
            tab = interval_records(tab)
        mf = cl.mem_flags
        self.params = cl.Buffer(self.rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=params)
        self.tables = cl.Buffer(self.rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=tab)
        # kept across calls: the invalid flag, the last per-channel mfp (values, buffer)
        self._flag = np.zeros(1, np.int32)
        self._flag_buf = cl.Buffer(self.rt.context, mf.READ_WRITE, self._flag.nbytes)
        self._mfp_channels = (None, None)
        self._lock = threading.Lock()

    @property
    def mfp_baked(self) -> bool:
        """The older name of ``mfp_compiled``."""
        return self.mfp_compiled

    def _table_kernel(self, bits: int, check: int = 0, mfp_channels: bool = False):
        """(width, kernel) of kernels/invert_table.cl for the outputs ``bits`` (OUTPUT_BITS),
        the validity test ``check`` (0, CHECK_ALBEDO, CHECK_COEFFICIENTS) and the mfp layout,
        built once each at ``width``, or narrower where that build was refused
        (``widths.built_at_width``)."""
        key = (bits, check, mfp_channels)
        hit = self._table_kernels.get(key)
        if hit is None:
            defines = {**self._table_defines, "BD_OUTPUTS": bits, "BD_CHECK": check,
                       "BD_MFP_MIN": f"{MFP_MIN:g}f"}
            if mfp_channels:
                defines["BD_MFP_CHANNELS"] = None

            def build(width):
                opts = build_options({**defines, "BD_WIDTH": width}, model=self.model)
                return cl.Kernel(get_program(self.rt, "invert_table", opts), "invert_table")
            hit = self._table_kernels[key] = built_at_width(
                self.rt, "invert_table", self.width, TABLE_WIDTHS_ALLOWED, build)
        return hit

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
                 wait_for=None, invalid=None, check=0, mfp_channels=False):
        """Enqueue over ``n`` elements (a multiple of nchan); returns the (last) launch's
        event (``device.launch.enqueue_items``).
        With the vectorised kernel (``width``): ``check`` and the 1-int buffer ``invalid``
        (set when some input breaks the rule), ``mfp_channels`` (``mfp`` holds one value per
        channel)."""
        if self.width:
            given = {"alpha": alpha, "rho": rho, "sigma_a": sigma_a, "sigma_s": sigma_s}
            bits = sum(OUTPUT_BITS[k] for k, b in given.items() if b is not None)
            width, knl = self._table_kernel(bits, check, mfp_channels)
            return enqueue_items(
                knl, self.rt.queue, -(-n // width), rd, mfp, alpha, rho, sigma_a, sigma_s, self.params,
                self.tables, np.int32(tables.entries_per_channel(self.table_n)), np.uint32(n),
                invalid, wait_for=wait_for)
        return enqueue_items(self.kernel, self.rt.queue, n, rd, mfp, alpha, rho, sigma_a,
                             sigma_s, self.params, self.tables, np.int32(self.nchan),
                             np.int32(tables.entries_per_channel(self.table_n)), np.uint32(n),
                             wait_for=wait_for)

    def checks_inputs(self, *arrays) -> bool:
        """Whether the kernel itself can test these inputs (the vectorised kernel on float32
        arrays; a float64 value may round to a valid float32 one, so those are tested on the
        host)."""
        return bool(self.width) and all(np.asarray(a).dtype == np.float32 for a in arrays)

    def run(self, rd, mfp=None, want=("alpha",), *, out=None, mfp_channels=None):
        """``run_checked`` without a test: {output: 1-D array}."""
        return self.run_checked(rd, mfp, want, out=out, mfp_channels=mfp_channels)[0]

    def run_checked(self, rd, mfp=None, want=("alpha",), *, out=None, check=0,
                    mfp_channels=None):
        """Host arrays in, host arrays out (``bdipole_cl.device.transfer``: host memory used
        directly where the device shares it, else pinned staging), into ``out`` ({name:
        array}, contiguous, rd's size and the kernel's dtype) where given, else into new
        arrays. ``mfp_channels``: one mfp per channel instead of ``mfp`` per element.

        Returns ({output: 1-D array}, flagged): with ``check`` (the vectorised kernel only),
        whether some input broke the rule (None: not tested)."""
        with self._lock:
            return self._run_checked(rd, mfp, want, out, check, mfp_channels)

    def run_buffers(self, n, rd, mfp=None, outputs=None, *, check=0, mfp_channels=None,
                    wait_for=None):
        """The kernel over ``n`` elements of device buffers (device-resident arrays:
        ``inversion_device``): ``outputs`` {name: buffer}, ``mfp`` a buffer of one value per
        element or ``mfp_channels`` one value per channel. Returns (its event, whether an input
        broke the rule ``check`` tests: None without a test; one int read back). One call at a
        time, as ``run_checked``."""
        with self._lock:
            flag_buf = self._flag_buf if check else None
            if check:
                self._flag[0] = 0
                cl.enqueue_copy(self.rt.queue, flag_buf, self._flag)
            const = None if mfp_channels is None else self._mfp_channels_buffer(mfp_channels)
            event = self(n, rd, mfp if const is None else const, **(outputs or {}),
                         invalid=flag_buf, check=check, mfp_channels=const is not None,
                         wait_for=wait_for)
            if check:
                cl.enqueue_copy(self.rt.queue, self._flag, flag_buf)
            return event, (bool(self._flag[0]) if check else None)

    def _mfp_channels_buffer(self, values):
        """A constant buffer of the per-channel mfp ``values``, the last one kept."""
        values = np.ascontiguousarray(values, self.dtype)
        held, buf = self._mfp_channels
        if held is None or not np.array_equal(held, values):
            buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                            hostbuf=values)
            self._mfp_channels = (values, buf)
        return buf

    def _run_checked(self, rd, mfp, want, out, check, mfp_channels):
        rt, dtype = self.rt, self.dtype
        with np.errstate(over="ignore"):   # float64 beyond float32's range is +-inf there,
            rd = np.ascontiguousarray(rd, dtype=dtype).reshape(-1)  # which the rules judge
            mfp = None if mfp is None else np.ascontiguousarray(mfp, dtype=dtype).reshape(-1)
        n = rd.size
        outs = {k: output_array(out, k, n, dtype, like=rd) for k in want}
        inputs = {"rd": rd}
        if mfp is not None:
            inputs["mfp"] = mfp
        const_mfp = None if mfp_channels is None else self._mfp_channels_buffer(mfp_channels)
        flag_buf = self._flag_buf if check else None
        if check:
            self._flag[0] = 0
            cl.enqueue_copy(rt.queue, flag_buf, self._flag)

        def launch(count, bufs, wait_for=None):
            return self(count, bufs["rd"], bufs.get("mfp", const_mfp),
                        **{k: bufs[k] for k in want}, invalid=flag_buf, check=check,
                        mfp_channels=const_mfp is not None, wait_for=wait_for)

        run_elementwise(rt, launch, inputs, outs, multiple=self.nchan * max(self.width, 1),
                        nchan=self.nchan)
        if check:
            cl.enqueue_copy(rt.queue, self._flag, flag_buf)
        return outs, (bool(self._flag[0]) if check else None)


def output_array(out, name, n, dtype, like=None):
    """``out[name]`` checked (1-D view of n elements of dtype, contiguous), or a new array
    aligned as ``like`` (an input: ``bdipole_cl.device.transfer.aligned_empty``)."""
    if out is None or name not in out:
        return aligned_empty(n, dtype, like=like)
    a = out[name]
    wrong = ("not a NumPy array" if not isinstance(a, np.ndarray) else
             f"its dtype is {a.dtype}" if a.dtype != dtype else
             f"it has {a.size} elements" if a.size != n else
             "it is not C-contiguous (a strided view)" if not a.flags.c_contiguous else
             "it is read-only" if not a.flags.writeable else None)
    if wrong:
        raise ValueError(f"out[{name!r}]: expected a writeable C-contiguous {np.dtype(dtype)} "
                         f"array of {n} elements (the input's shape, or flat); {wrong} (got "
                         f"{getattr(a, 'dtype', type(a).__name__)} shape {np.shape(a)})")
    return a.view(np.ndarray).reshape(-1)      # a subclass (np.matrix) stays 2-D reshaped


#: prepared kernels kept across calls (each holds its small constant buffers), per thread
#: (a pyopencl Kernel's arguments are set per call)
KERNEL_CACHE = ByteCache("inversion kernels", 16 << 20)


def inversion_kernel(etas, config, *, exact=False, model="better", double=False,
                     runtime=None) -> InversionKernel:
    """The InversionKernel for these arguments, from KERNEL_CACHE when it has it."""
    rt = get_runtime(runtime)
    width = table_width(rt) if vectorised(config, double) else 0     # forced ones differ
    key = (id(rt.context), rt.numerics.name, threading.get_ident(), tuple(etas),
           config.resolved(double), exact, model, double, width)
    hit = KERNEL_CACHE.get(key)
    if hit is None or hit[0] is not rt.context:    # the entry holds its context: ids are its own
        kernel = InversionKernel(etas, config, exact=exact, model=model, double=double,
                                 runtime=rt)
        hit = KERNEL_CACHE.put(key, (rt.context, kernel),
                               4096 + len(etas) * 48 * (config.table_n + 1))
    return hit[1]
