"""OpenCL dispatch of the blur kernels on one device (kernels/blur_direct.cl,
kernels/blur_separable.cl, kernels/blur_textured.cl). Every function takes the Runtime it runs
on; nothing here chooses a device."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ...device import build_options, get_program
from ...signals import check_stop
from .fit import gaussian_1d
from .textured_plan import texel_coords

#: work-group side of blur_direct.cl (its local-memory tiles are BD_TILE x BD_TILE outputs)
TILE = 16
#: taps one direct launch evaluates at most (~0.1-0.5 s on a CPU device): how soon it stops
LAUNCH_TAPS = 2e8


class DeviceBlur:
    """Device buffers and programs for one image."""

    def __init__(self, e, border, rt):
        self.rt = rt
        self.h, self.w, self.c = e.shape
        border_opt = {f"BD_BORDER_{border.upper()}": None}
        self.direct = cl.Kernel(get_program(rt, "blur_direct",
                                            build_options({**border_opt, "BD_TILE": TILE})),
                                "blur_direct")
        sep = get_program(rt, "blur_separable", build_options(border_opt))
        self.rows, self.cols = cl.Kernel(sep, "blur_rows"), cl.Kernel(sep, "blur_cols_add")
        self.cols_textured = cl.Kernel(get_program(
            rt, "blur_separable", build_options({**border_opt, "BD_PER_TEXEL_WEIGHT": None})),
            "blur_cols_add")
        mf = cl.mem_flags
        self.src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=e)
        self.dst = cl.Buffer(rt.context, mf.READ_WRITE, max(e.nbytes, 4))
        self.tmp = cl.Buffer(rt.context, mf.READ_WRITE, max(self.h * self.w * 4, 4))
        cl.enqueue_fill_buffer(rt.queue, self.dst, np.float32(0), 0, max(e.nbytes, 4))

    def _buf(self, array):
        return cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(array, np.float32))

    def run_direct(self, c, ck):
        """Channel c gathered with the ChannelKernel's exact weights, in launches of about
        LAUNCH_TAPS taps (bands of rows), a stop request checked between them."""
        gx = -(-self.w // TILE) * TILE
        gy = -(-self.h // TILE) * TILE
        taps = (2 * ck.radius + 1) ** 2
        step = TILE * max(1, int(LAUNCH_TAPS // (gx * TILE * taps)))
        weights = self._buf(ck.weights)
        for y in range(0, gy, step):
            check_stop()
            self.direct(self.rt.queue, (gx, min(step, gy - y)), (TILE, TILE), self.src,
                        self.dst, weights, np.int32(self.w), np.int32(self.h),
                        np.int32(self.c), np.int32(c), np.int32(ck.radius),
                        global_offset=(0, y))
            self.rt.queue.finish()

    def run_gaussians(self, c, fit):
        """Channel c blurred by the GaussianFit's separable Gaussians."""
        for sigma, weight, radius in zip(fit.sigmas, fit.weights, fit.radii):
            check_stop()
            taps = self._buf(gaussian_1d(sigma, radius))
            args = (np.int32(self.w), np.int32(self.h), np.int32(self.c), np.int32(c),
                    np.int32(radius))
            self.rows(self.rt.queue, (self.w, self.h), None, self.src, self.tmp, taps, *args)
            self.cols(self.rt.queue, (self.w, self.h), None, self.tmp, self.dst, taps, *args,
                      np.float32(weight))

    def run_textured(self, c, plan, weights):
        """Texture-varying parameters: each basis Gaussian of the TexturedPlan blurred by the
        separable kernels and added with its per-texel weight plane (w_j(x) * Rd(x))."""
        for taps, plane in zip(plan.kernels, weights):
            check_stop()
            self.rt.queue.finish()
            radius = (len(taps) - 1) // 2
            args = (np.int32(self.w), np.int32(self.h), np.int32(self.c), np.int32(c),
                    np.int32(radius))
            self.rows(self.rt.queue, (self.w, self.h), None, self.src, self.tmp,
                      self._buf(taps), *args)
            self.cols_textured(self.rt.queue, (self.w, self.h), None, self.tmp, self.dst,
                              self._buf(taps), *args, self._buf(plane))

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


def lattice_args(plan):
    """Program options and the lattice arguments of kernels/blur_textured.cl for a plan."""
    nu, nv, nbasis = plan.fine.shape
    opts = build_options({"BD_NBASIS": nbasis, "BD_NU_TAPS": 1 if nu == 1 else 2,
                          "BD_NV_TAPS": 1 if nv == 1 else 2})
    return opts, (np.int32(nu), np.int32(nv))


def weight_planes(plan, rd, ld, rt):
    """w_j(x) * Rd(x), (G, H, W) float32, computed on ``rt``'s device (kernels/blur_textured.cl)."""
    h, w = rd.shape
    mf = cl.mem_flags
    opts, axis_args = lattice_args(plan)
    out = np.empty((plan.fine.shape[2], h, w), np.float32)
    bufs = [host_buffer(rt, a, mf.READ_ONLY) for a in (rd, *texel_coords(plan, rd, ld),
                                                         plan.fine)]
    dst = host_buffer(rt, out, mf.WRITE_ONLY)
    cl.Kernel(get_program(rt, "blur_textured", opts), "lattice_weights")(
        rt.queue, (h * w,), None, *bufs, dst, np.int32(h * w), *axis_args)
    read_back(rt, dst, out)
    return out


def gather_exitance(out, c, plan, rd, ld, planes, x0, rt):
    """out[..., c] = Rd(x) sum_j w_j(x) planes[j, y, x0 + x], on ``rt``'s device."""
    h, w, nch = out.shape
    mf = cl.mem_flags
    opts, axis_args = lattice_args(plan)
    bufs = [host_buffer(rt, a, mf.READ_ONLY) for a in (rd, *texel_coords(plan, rd, ld),
                                                         plan.fine, planes)]
    dst = host_buffer(rt, out, mf.READ_WRITE)
    cl.Kernel(get_program(rt, "blur_textured", opts), "gather_exitance")(
        rt.queue, (w, h), None, *bufs, dst, np.int32(w), np.int32(h),
        np.int32(planes.shape[2]), np.int32(planes.shape[1] * planes.shape[2]), np.int32(x0),
        np.int32(nch), np.int32(c), *axis_args)
    read_back(rt, dst, out)
