"""Inversions of device-resident arrays (bdipole_cl/ops/inversion_device.py,
kernels/array_ops.cl) on every device under test: pyopencl arrays in, pyopencl arrays out,
the host's results (the same kernels; the extinction division within OpenCL's float32
division bound), the host's errors and clamps where an input breaks its rule."""
import numpy as np
import pyopencl.array as cla
import pytest

import bdipole_cl as bd


def _albedos(shape, seed=4):
    return np.random.default_rng(seed).uniform(0, 0.999, shape).astype(np.float32)


def test_inversions_of_device_arrays_stay_on_the_device(runtime):
    rd = _albedos((33, 17, 3))
    dev = cla.to_device(runtime.queue, rd)
    alpha, rho = bd.invert_albedo(dev, (1.3, 1.4, 1.5), return_rho=True)
    assert isinstance(alpha, cla.Array) and alpha.shape == rd.shape
    want = bd.invert_albedo(rd, (1.3, 1.4, 1.5), return_rho=True, device=runtime)
    np.testing.assert_array_equal(alpha.get(), want[0])
    np.testing.assert_array_equal(rho.get(), want[1])
    mfp = cla.to_device(runtime.queue, np.full(rd.shape, 1.5, np.float32))
    for kind in ("diffuse", "extinction"):
        for m_dev, m_host in ((mfp, 1.5), ((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))):
            got = bd.albedo_to_coefficients(dev, m_dev, 1.4, mfp_kind=kind,
                                            outputs=("sigma_a", "sigma_s", "sigma_t"))
            host = bd.albedo_to_coefficients(rd, m_host, 1.4, mfp_kind=kind,
                                             outputs=("sigma_a", "sigma_s", "sigma_t"),
                                             device=runtime)
            for g, h in zip(got, host):
                # OpenCL's float32 division is within 2.5 ulp (the host's is exact)
                np.testing.assert_allclose(g.get(), h, rtol=3 * 2.0 ** -23)


def test_device_outputs_given_are_written(runtime):
    rd = _albedos((64,))
    dev = cla.to_device(runtime.queue, rd)
    alpha, rho = (cla.empty(runtime.queue, rd.shape, np.float32) for _ in range(2))
    got = bd.invert_albedo(dev, 1.4, return_rho=True, out=(alpha, rho))
    assert got[0] is alpha and got[1] is rho
    np.testing.assert_array_equal(alpha.get(), bd.invert_albedo(rd, 1.4, device=runtime))
    with pytest.raises(ValueError, match="out\\['alpha'\\]: the inputs are device arrays"):
        bd.invert_albedo(dev, 1.4, out=np.empty(64, np.float32))
    with pytest.raises(ValueError, match="alpha and rho overlap"):
        bd.invert_albedo(dev, 1.4, return_rho=True, out=(alpha, alpha))


def test_device_inputs_that_break_the_rule_are_named_or_clamped_as_on_the_host(runtime):
    rd = _albedos((10, 12, 3))
    rd[4, 7, 2], rd[1, 1, 0] = np.nan, 1.5
    dev = cla.to_device(runtime.queue, rd)
    with pytest.raises(bd.InvalidInputError, match=r"first at index \(1, 1, 0\)"):
        bd.invert_albedo(dev, 1.4)
    got = bd.invert_albedo(dev, 1.4, on_invalid="clamp")
    np.testing.assert_array_equal(got.get(), bd.invert_albedo(rd, 1.4, on_invalid="clamp",
                                                              device=runtime))
    mfp = np.full(rd.shape, 2.0, np.float32)
    mfp[2, 3, 1] = -1.0
    got = bd.albedo_to_coefficients(dev, cla.to_device(runtime.queue, mfp), 1.4,
                                    on_invalid="clamp")
    want = bd.albedo_to_coefficients(rd, mfp, 1.4, on_invalid="clamp", device=runtime)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.get(), w)


def test_float64_and_other_methods_on_device_arrays(runtime, has_fp64):
    rd = _albedos((500,))
    for method in ("bisection", "secant"):
        got = bd.invert_albedo(cla.to_device(runtime.queue, rd), 1.4, method=method)
        np.testing.assert_array_equal(got.get(), bd.invert_albedo(rd, 1.4, method=method,
                                                                  device=runtime))
    if has_fp64:
        rd64 = rd.astype(np.float64)
        got = bd.invert_albedo(cla.to_device(runtime.queue, rd64), 1.4, double=True)
        np.testing.assert_array_equal(got.get(), bd.invert_albedo(rd64, 1.4, double=True,
                                                                  device=runtime))
        bad = rd64.copy()
        bad[9] = 2.0
        with pytest.raises(bd.InvalidInputError, match=r"index \(9,\)"):
            bd.invert_albedo(cla.to_device(runtime.queue, bad), 1.4, double=True)


def test_device_arrays_that_do_not_fit_are_refused_in_one_line(runtime):
    dev = cla.to_device(runtime.queue, _albedos((8, 3)))
    with pytest.raises(ValueError, match="a float64 device array; this call computes in "
                                         "float32"):
        bd.invert_albedo(cla.to_device(runtime.queue, _albedos((8,)).astype(np.float64)), 1.4)
    with pytest.raises(ValueError, match="mask: not taken with device arrays"):
        bd.ops.invert.plan_inversion((1.4,), device=runtime).apply(dev, mask=np.ones((8, 3)))
    with pytest.raises(ValueError, match="mfp: a device array of shape \\(8,\\)"):
        bd.albedo_to_coefficients(dev, cla.to_device(runtime.queue, np.ones(8, np.float32)),
                                  1.4)


#: a user's slow kernel writing 0.25 (a fixed point after ~30 steps) into its array: its
#: writes, enqueued on the user's own queue, are recorded in no pyopencl event
SLOW_FILL = ("float *x, int m",
             "float v = 0; for (int k = 0; k < m; ++k) v = v * 0.5f + 0.125f; x[i] = v;")


def _written_on_another_queue(runtime, shape):
    """A device array whose fill is still running on a queue of the user's (not the
    runtime's), when the call that reads it is made."""
    import pyopencl as cl
    from pyopencl.elementwise import ElementwiseKernel
    q2 = cl.CommandQueue(runtime.context)
    fill = ElementwiseKernel(runtime.context, *SLOW_FILL, "bd_test_slow_fill")
    d = cla.zeros(q2, shape, np.float32)
    d.finish()
    fill(d, np.int32(20000), queue=q2)
    return d


def test_a_device_array_still_written_on_its_own_queue_is_read_after_that(runtime):
    """The inversion and the blur wait for the work enqueued on a device array's own queue
    (pyopencl's Array.events hold only its own operations': the user's kernel is in none)."""
    shape = (512, 512)
    want = bd.invert_albedo(np.full(shape, 0.25, np.float32), 1.4, device=runtime)
    got = bd.invert_albedo(_written_on_another_queue(runtime, shape), 1.4, device=runtime)
    np.testing.assert_array_equal(got.get(), want)
    want = bd.blur(np.full(shape, 0.25, np.float32), albedo=0.5, mfp=2.0, device=runtime)
    got = bd.blur(_written_on_another_queue(runtime, shape), albedo=0.5, mfp=2.0,
                  device=runtime)
    np.testing.assert_array_equal(got.get(), want)


def test_device_arrays_of_every_layout_in_the_blur_and_inversion(runtime):
    """Queue-less device arrays are taken (on the call's queue); strided views, outputs of
    another shape and a host albedo beside a device mfp are one-line ValueErrors."""
    q = runtime.queue
    e = np.random.default_rng(3).random((30, 20)).astype(np.float32)
    want = bd.blur(e, albedo=0.5, mfp=2.0, device=runtime)
    got = bd.blur(cla.to_device(q, e).with_queue(None), albedo=0.5, mfp=2.0, device=runtime)
    np.testing.assert_array_equal(got.get(), want)
    albedo = cla.to_device(q, np.full(e.shape, 0.5, np.float32)).with_queue(None)
    np.testing.assert_array_equal(bd.blur(e, albedo=albedo, mfp=2.0, device=runtime),
                                  bd.blur(e, albedo=np.full(e.shape, 0.5, np.float32),
                                          mfp=2.0, device=runtime))
    wide = cla.to_device(q, np.random.default_rng(4).random((30, 40)).astype(np.float32))
    with pytest.raises(ValueError, match="irradiance: a strided device array view"):
        bd.blur(wide[:, ::2], albedo=0.5, mfp=2.0, device=runtime)
    with pytest.raises(ValueError, match="albedo: a strided device array view"):
        bd.blur(e[:, :10], albedo=wide[:, ::4], mfp=2.0, device=runtime)
    rd = cla.to_device(q, _albedos((64, 48)))
    with pytest.raises(ValueError, match=r"out\['alpha'\]: shape \(48, 64\) is not the "
                                         r"input's \(64, 48\)"):
        bd.invert_albedo(rd, 1.4, out=cla.empty(q, (48, 64), np.float32))
    with pytest.raises(ValueError, match="albedo: a host array with a device-array mfp"):
        bd.albedo_to_coefficients(0.5, cla.to_device(q, np.ones((4, 4), np.float32)), 1.4)
