"""OpenCL dispatch of the blur kernels on one device (kernels/blur_direct.cl,
kernels/blur_separable.cl, kernels/blur_textured.cl). Every function takes the Runtime it runs
on; nothing here chooses a device."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ...device import build_options, get_program
from ...device.launch import enqueue_items
from ...device.runtime import forced_width, platform_entry
from ...device.transfer import aligned_empty, is_device_array
from ...methods.choice import GATHER_WIDTHS_ALLOWED
from ..widths import built_at_width, choose_width, device_vector_cap
from ...signals import check_stop
from ..inversion_kernel import kernel_tuning
from .fit import gaussian_1d
from .near_field import DEFAULT_GATHER_COSTS, GatherCosts
from .textured_plan import RD_MAX, RD_MIN, fine_axis_map

#: work-group side of blur_direct.cl (its local-memory tiles are BD_TILE x BD_TILE outputs)
TILE = 16
#: taps one direct launch evaluates at most (~0.1-0.5 s on a CPU device): how soon it stops
LAUNCH_TAPS = 2e8


class BlurKernels:
    """The blur's programs on one device for one border rule, built on first use and kept for
    the plan's life (``plan.BlurPlan``), with the tap and weight buffers it uploads, each once
    (keyed by content: a channel's weights are the same on every band)."""

    def __init__(self, rt, border):
        self.rt = rt
        self.border = border
        self._kernels = {}
        self._buffers = {}

    def kernel(self, program, name, double=False, **options):
        """Kernel ``name`` of kernels/<program>.cl, with the border and ``options`` defined
        (``double``: its ``real`` is double)."""
        key = (program, name, double, tuple(sorted(options.items())))
        if key not in self._kernels:
            opts = {f"BD_BORDER_{self.border.upper()}": None, **options}
            self._kernels[key] = cl.Kernel(get_program(self.rt, program,
                                                       build_options(opts, double=double)),
                                           name)
        return self._kernels[key]

    def uploaded(self, array):
        """A read-only device buffer holding ``array`` (float32), uploaded once."""
        a = np.ascontiguousarray(array, np.float32)
        key = (a.shape, a.tobytes())
        if key not in self._buffers:
            self._buffers[key] = cl.Buffer(self.rt.context,
                                           cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                                           hostbuf=a)
        return self._buffers[key]


class DeviceBlur:
    """The image buffers of one image (or band) on the plan's device: the irradiance ``e``
    uploaded, or ``src`` and ``dst`` given (device buffers of its shape: the device path)."""

    def __init__(self, e, kernels: BlurKernels, src=None, dst=None):
        self.kernels = kernels
        self.rt = rt = kernels.rt
        self.h, self.w, self.c = e.shape
        nbytes = max(self.h * self.w * self.c * 4, 4)
        mf = cl.mem_flags
        self.src = (cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=e)
                    if src is None else src)
        self.dst = cl.Buffer(rt.context, mf.READ_WRITE, nbytes) if dst is None else dst
        self.tmp = cl.Buffer(rt.context, mf.READ_WRITE, max(self.h * self.w * 4, 4))
        if dst is None:
            cl.enqueue_fill_buffer(rt.queue, self.dst, np.float32(0), 0, nbytes)

    def run_direct(self, c, ck):
        """Channel c gathered with the ChannelKernel's exact weights, in launches of about
        LAUNCH_TAPS taps (bands of rows), a stop request checked between them."""
        gx = -(-self.w // TILE) * TILE
        gy = -(-self.h // TILE) * TILE
        taps = (2 * ck.radius + 1) ** 2
        # work-group tiles per launch: whole rows of tiles where they fit, else a row's tiles
        # in parts (a wide kernel: one row of tiles can be 1e10 taps, a minute between checks)
        tiles = max(1, int(LAUNCH_TAPS // (TILE * TILE * taps)))
        step_x = min(gx, TILE * tiles)
        step_y = TILE * max(1, tiles // (gx // TILE))
        weights = self.kernels.uploaded(ck.weights)
        direct = self.kernels.kernel("blur_direct", "blur_direct", BD_TILE=TILE)
        for y in range(0, gy, step_y):
            for x in range(0, gx, step_x):
                check_stop()
                direct(self.rt.queue, (min(step_x, gx - x), min(step_y, gy - y)), (TILE, TILE),
                       self.src, self.dst, weights, np.int32(self.w), np.int32(self.h),
                       np.int32(self.c), np.int32(c), np.int32(ck.radius),
                       global_offset=(x, y))
                self.rt.queue.finish()

    def _separable(self, c, taps, column_pass, *weight_args):
        """Rows then columns of one separable kernel (1D ``taps``) into channel c."""
        radius = (len(taps) - 1) // 2
        g = self.kernels.uploaded(taps)
        args = (np.int32(self.w), np.int32(self.h), np.int32(self.c), np.int32(c),
                np.int32(radius))
        rows = self.kernels.kernel("blur_separable", "blur_rows")
        rows(self.rt.queue, (self.w, self.h), None, self.src, self.tmp, g, *args)
        column_pass(self.rt.queue, (self.w, self.h), None, self.tmp, self.dst, g, *args,
                    *weight_args)

    def run_gaussians(self, c, fit):
        """Channel c blurred by the GaussianFit's separable Gaussians."""
        cols = self.kernels.kernel("blur_separable", "blur_cols_add")
        for sigma, weight, radius in zip(fit.sigmas, fit.weights, fit.radii):
            check_stop()
            self._separable(c, gaussian_1d(sigma, radius), cols, np.float32(weight))

    def run_textured(self, c, plan, planes):
        """Texture-varying parameters: each basis Gaussian of the TexturedPlan blurred by the
        separable kernels and added with its per-texel weight plane (w_j(x) * Rd(x)), the
        planes the device buffer ``weight_planes`` left on the device."""
        cols = self.kernels.kernel("blur_separable", "blur_cols_add", BD_PER_TEXEL_WEIGHT=None)
        for j, taps in enumerate(plan.kernels):
            check_stop()
            self._separable(c, taps, cols, planes, np.int32(j))
            self.rt.queue.finish()

    def result(self):
        out = np.empty((self.h, self.w, self.c), np.float32)
        cl.enqueue_copy(self.rt.queue, out, self.dst)
        self.rt.queue.finish()
        return out


def host_buffer(rt, array, flags):
    """A device buffer over a host array (zero-copy on CPU devices)."""
    return cl.Buffer(rt.context, flags | cl.mem_flags.USE_HOST_PTR,
                     hostbuf=np.ascontiguousarray(array))


def read_back(rt, buf, array):
    """Make the device's writes to a USE_HOST_PTR buffer visible in ``array``."""
    mapped, _ = cl.enqueue_map_buffer(rt.queue, buf, cl.map_flags.READ, 0, array.shape,
                                      array.dtype)
    mapped.base.release(rt.queue)
    rt.queue.finish()


#: texels per work-item of kernels/blur_textured.cl by OpenCL platform (a case-insensitive part
#: of its name), and its costs (``near_field.GatherCosts``), measured at 2048^2 on the 2-core
#: AVX-512 CPU (tools/bench_blur.py --gather): Intel's runtime vectorizes the one-texel kernel
#: across work-items itself (8 lanes a work-item: 2x slower there); PoCL leaves a one-texel
#: kernel scalar (its logs and taps ~5x slower than in explicit vectors), 16 lanes its best.
#: Devices not listed (GPUs) get one texel per work-item and the default costs
GATHER_WIDTHS = {"intel(r) opencl": 1, "portable computing language": 16}
GATHER_COSTS = {"intel(r) opencl": DEFAULT_GATHER_COSTS,
                "portable computing language": GatherCosts(cell=0.01, term=0.0, weight=0.045)}


#: forces the gather's texels per work-item (``GATHER_WIDTHS_ALLOWED``), for measuring
GATHER_WIDTH_VARIABLE = "BDIPOLE_CL_GATHER_WIDTH"


def gather_width(rt, n) -> int:
    """Texels per work-item of kernels/blur_textured.cl on ``rt``'s device for rows of n
    texels (a work-item's texels lie in one row: 1 for rows narrower than the width): forced
    by GATHER_WIDTH_VARIABLE, else the device's calibration, else the fastest width its probe
    timed, else GATHER_WIDTHS; never one the probe rejected (``ops.widths``)."""
    width = forced_width(GATHER_WIDTH_VARIABLE, GATHER_WIDTHS_ALLOWED)
    if not width:
        tuned = kernel_tuning(rt)
        width = choose_width(rt, "blur_textured", GATHER_WIDTHS_ALLOWED,
                             tuned.gather_width if tuned is not None else None,
                             platform_entry(rt.device, GATHER_WIDTHS, 1)).width
    return width if n >= width else 1


def gather_costs(rt) -> GatherCosts:
    """The gather's costs on ``rt``'s device: its calibration's, else GATHER_COSTS' (what
    chooses its near field)."""
    tuned = kernel_tuning(rt)
    if tuned is not None and tuned.gather_costs:
        return GatherCosts(*tuned.gather_costs)
    return platform_entry(rt.device, GATHER_COSTS, DEFAULT_GATHER_COSTS)


def record_chunk(nweights, cap=16) -> int:
    """Floats per load of a table node's record (kernels/blur_textured.cl ``BD_CHUNK``): the
    smallest vector of 4, 8 or 16 floats that holds ``nweights`` weights, else the widest
    (records of several chunks); none wider than ``cap`` (the device's vector cap,
    ``widths.device_vector_cap``)."""
    sizes = [n for n in (4, 8, 16) if n <= max(cap, 4)]
    return next((n for n in sizes if nweights <= n), sizes[-1])


def node_records(fine, chunk):
    """The fine table (nu, nv, weights) as kernels/blur_textured.cl reads it: each node's
    weights padded with zeros to a whole number of ``chunk`` floats (``record_chunk``),
    float32, on the device-alignment boundary (so every chunk load is aligned; a CPU runtime
    reads it in place)."""
    nu, nv, nweights = fine.shape
    records = aligned_empty(nu * nv * chunk * -(-nweights // chunk), np.float32).reshape(
        (nu, nv, -1))
    records[..., nweights:] = 0
    records[..., :nweights] = fine
    return records


def lattice_args(plan, width, chunk):
    """Program options and the lattice arguments of kernels/blur_textured.cl for a plan, at
    ``width`` texels per work-item and records read ``chunk`` floats at a time: the fine
    table's size, then its coordinates' (``fine_coords``: the Rd clamp, and per axis the scale
    and offset of ``textured_plan.texel_coords``)."""
    nu, nv, nweights = plan.fine.shape
    opts = build_options({"BD_NBASIS": len(plan.kernels), "BD_NEAR": plan.near,
                          "BD_NEAR_RANK": len(plan.near_basis),
                          "BD_NU_TAPS": 1 if nu == 1 else 2, "BD_NV_TAPS": 1 if nv == 1 else 2,
                          "BD_WIDTH": width, "BD_CHUNK": chunk})
    coords = [np.float32(v) for v in (RD_MIN, RD_MAX, *fine_axis_map(plan.axes[0]),
                                      *fine_axis_map(plan.axes[1]))]
    return opts, (np.int32(nu), np.int32(nv), *coords)


def textured_kernel(rt, plan, n, name):
    """(width, chunk, kernel, lattice arguments) of kernel ``name`` of kernels/blur_textured.cl
    for a plan over rows of n texels: at ``gather_width``, or narrower where that build was
    refused (``widths.built_at_width``), its records read in chunks within the device's vector
    cap."""
    chunk = record_chunk(plan.fine.shape[2], device_vector_cap(rt))

    def build(width):
        return cl.Kernel(get_program(rt, "blur_textured", lattice_args(plan, width, chunk)[0]),
                         name)
    width, knl = built_at_width(rt, "blur_textured", gather_width(rt, n), GATHER_WIDTHS_ALLOWED,
                                build)
    return width, chunk, knl, lattice_args(plan, width, chunk)[1]


def weight_planes(plan, rd, ld, rt):
    """w_j(x) * Rd(x), (G, H, W) float32 on the host (``device_weight_planes`` read back)."""
    out = np.empty((plan.fine.shape[2], *rd.shape), np.float32)
    cl.enqueue_copy(rt.queue, out, device_weight_planes(plan, rd, ld, rt))
    rt.queue.finish()
    return out


def device_weight_planes(plan, rd, ld, rt):
    """w_j(x) * Rd(x), (G, H, W) float32, computed on ``rt``'s device and left there (the
    buffer the separable column pass reads: kernels/blur_textured.cl, blur_separable.cl); the
    Rd and ld maps host arrays or device arrays."""
    h, w = rd.shape
    mf = cl.mem_flags
    width, chunk, knl, axis_args = textured_kernel(rt, plan, h * w, "lattice_weights")
    bufs = [a.data if is_device_array(a) else host_buffer(rt, a, mf.READ_ONLY)
            for a in (rd, ld, node_records(plan.fine, chunk))]
    planes = cl.Buffer(rt.context, mf.READ_WRITE, max(plan.fine.shape[2] * h * w * 4, 4))
    enqueue_items(knl, rt.queue, -(-h * w // width), *bufs, planes, np.int32(h * w),
                  *axis_args)
    rt.queue.finish()                  # the host arrays under ``bufs`` are then free to go
    return planes


def gather_exitance(out, c, plan, rd, ld, planes, padded, x0, rt, settle=(0.0, True)):
    """out[..., c] = Rd(x) (sum_j w_j(x) planes[j, y, x0 + x] + the near kernels' weights
    times their convolution with the irradiance there, from ``padded``: the channel padded by
    x0 texels by the border rule), on ``rt``'s device, settled by ``settle`` = (scale,
    non-negative) (``fft.settle_floor``; the default settles nothing but the negative
    round-off of a non-negative irradiance)."""
    h, w, nch = out.shape
    mf = cl.mem_flags
    width, chunk, knl, axis_args = textured_kernel(rt, plan, w, "gather_exitance")
    bufs = [host_buffer(rt, a if a.size else np.zeros(1, np.float32), mf.READ_ONLY)
            for a in (rd, ld, node_records(plan.fine, chunk), planes, padded,
                      plan.near_basis)]                                     # none: 1 float
    dst = host_buffer(rt, out, mf.READ_WRITE)
    scale, nonneg = settle
    knl(
        rt.queue, (-(-w // width), h), None, *bufs, dst, np.int32(w), np.int32(h),
        np.int32(planes.shape[2]), np.int32(planes.shape[1] * planes.shape[2]),
        np.int32(padded.shape[1]), np.int32(x0), np.int32(nch), np.int32(c),
        np.float32(scale), np.int32(bool(nonneg)), *axis_args)
    read_back(rt, dst, out)
