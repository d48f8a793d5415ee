"""The device FFTs (bdipole_cl/ops/device_fft.py, kernels/fft.cl) against numpy.fft in float64,
on every device under test: forward (rfft2) and inverse (irfft2, whole or row-pruned), every
radix, mixed and non-square sizes, batches of 1-4 planes, float32 and float64, the one-pass
rows and (with a small local-memory budget) the multi-pass ones, and adversarial inputs.

Error bound (docs/device_fft.md "Accuracy"). Higham, Accuracy and Stability of Numerical
Algorithms, 2nd ed., Thm. 24.2: the radix-2 FFT computed in floating point has a normwise
relative error ||y^ - y||_2 / ||y||_2 <= log2(n) eta / (1 - log2(n) eta), eta = mu + gamma_4
(sqrt 2 + mu), mu the twiddles' relative error. The same argument a stage at a time, each
stage a twiddle product (error <= mu + sqrt 2 gamma_2 = 3.83 u, mu = u: our twiddles are
float64 values rounded once) and an r-point butterfly whose outputs take at most k_r roundings
(normwise <= sqrt(2 r) gamma_(k_r) of its output), bounds every stage's error by ETA_LEVEL u
per log2 of its radix: radix 2 (k = 1) 5.8 u, 4 (k = 2) 4.7 u, 8 (k = 5 with its W_8
products) 7.9 u, 3 (k = 4) 8.6 u, 5 (k = 6) 9.8 u, 7 (k = 7) 10.7 u, and the real twist (a
2-point stage with a twiddle product, both of its outputs from one pair) 12 u. The stages' log2
radices add up to log2(N0 N1), so a 2D real transform's relative error is at most
ETA_LEVEL u log2(N0 N1) to first order (2160 x 4320 in float32: 1.7e-5; measured: 1.8e-7).
"""
import math

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from bdipole_cl.device import programs
from bdipole_cl.ops import device_fft
from bdipole_cl.ops.device_fft import DeviceFFT, device_fft_len
from bdipole_cl.ops.fft_passes import (PRIMES, axis_passes, pack_stages, split_radices,
                                       stage_radices, unit_roots)

#: unit round-off of float32 and float64
U = {False: 2.0 ** -24, True: 2.0 ** -53}
#: the largest stage error per log2 of a stage's radix, in u (the module docstring derives it:
#: 12 u for the real twist, 10.7 u for radix 7, at most 9.8 u for the others)
ETA_LEVEL = 12
#: a small local-memory budget (bytes): 128 float32 points a tile (beyond the runtime's
#: reserve), so that rows past 256 reals take several passes and columns passes of radix <= 16,
#: the paths a GPU takes for long rows
SMALL_LOCAL = 2048 + device_fft.LOCAL_RESERVE_BYTES


def bound(shape, double, inverse=False):
    """The normwise relative error bound of a forward or inverse 2D real FFT: ETA_LEVEL u per
    log2 level; the inverse adds its scale's rounding (u) and a factor sqrt 2 (the half
    spectrum it reads holds between 1/2 and all of the full spectrum's squared norm, so its
    errors, relative to the half spectrum, are at most sqrt 2 times those relative to the
    output by Parseval)."""
    levels = math.log2(shape[0] * shape[1])
    b = ETA_LEVEL * levels * U[double]
    return math.sqrt(2) * (b + U[double]) if inverse else b


def plane_errors(got, want):
    """Each plane's ||got - want||_2 / ||want||_2 (planes do not mix: each is held to its own
    norm, however different the batch's magnitudes)."""
    got, want = np.asarray(got, np.complex128), np.asarray(want, np.complex128)
    assert np.isfinite(want).all(), "the reference overflowed: a test input out of range"
    errors = []
    for g, w in zip(got, want):
        top = np.abs(w).max()          # norms of the scaled planes: no square overflows
        errors.append(float(np.linalg.norm((g - w) / top) / np.linalg.norm(w / top)))
    assert np.isfinite(errors).all(), errors
    return errors


def real_dtype(double):
    return np.dtype(np.float64 if double else np.float32)


def forward(rt, x, double):
    """(device rfft2 of the planes x, the plan)."""
    plan = DeviceFFT(rt, x.shape[1:], x.shape[0], double)
    src = cla.to_device(rt.queue, np.ascontiguousarray(x, real_dtype(double)))
    spec = cla.empty(rt.queue, plan.spectrum_shape, plan.complex_dtype)
    plan.forward(src, spec).wait()
    return spec.get(), plan


def inverse(rt, spec, shape, double, rows=None):
    plan = DeviceFFT(rt, shape, spec.shape[0], double)
    r0, r1 = rows or (0, shape[0])
    src = cla.to_device(rt.queue, np.ascontiguousarray(spec, plan.complex_dtype))
    out = cla.empty(rt.queue, (spec.shape[0], r1 - r0, shape[1]), real_dtype(double))
    plan.inverse(src, out, rows=rows).wait()
    return out.get()


def skip_without_fp64(rt, double):
    if double and not rt.has_fp64:
        pytest.skip(f"{rt.describe()} has no cl_khr_fp64")


# {{{ sizes, radices, twiddles (host only)

def smooth_even(limit):
    """Every even 7-smooth number below ``limit``, built as products (not by factoring)."""
    out = {1}
    for p in PRIMES:
        out |= {v * p ** e for v in list(out) for e in range(1, 40) if v * p ** e < limit}
    return sorted(v for v in out if v % 2 == 0)


def test_device_fft_len_is_the_next_even_7_smooth_length():
    lengths = smooth_even(1 << 14)
    for n in range(0, 10000):
        want = next(m for m in lengths if m >= n)
        assert device_fft_len(n) == want, (n, device_fft_len(n), want)


@pytest.mark.parametrize("shape", [(9, 8), (8, 9), (22, 8), (8, 26), (0, 8), (1, 8),
                                   (8, 8, 8)], ids=str)
def test_unsupported_shapes_are_refused_by_name(runtime, shape):
    with pytest.raises(ValueError, match="device FFT"):
        DeviceFFT(runtime, shape)


def test_bad_batch_is_refused(runtime):
    with pytest.raises(ValueError, match="batch"):
        DeviceFFT(runtime, (8, 8), 0)


@pytest.mark.parametrize("n", [2, 6, 7 * 16, 2160, 4320, 8192, 2 * 3 * 5 * 7 * 8, 7 ** 5],
                         ids=str)
@pytest.mark.parametrize("max_radix", [7, 8, 16, 192, 4096], ids=lambda r: f"max{r}")
def test_passes_cover_the_length_within_the_tile(n, max_radix):
    radices = split_radices(n, max_radix)
    assert math.prod(radices) == n and max(radices) <= max_radix, radices
    if max_radix >= 8:                 # every prime fits a pass of 8 with another factor
        fewest = math.ceil(math.log(n) / math.log(max_radix) - 1e-9)
        assert len(radices) <= fewest + 1, (radices, fewest)
    for r in radices:
        stages = stage_radices(r)
        assert math.prod(stages) == r and set(stages) <= {2, 3, 4, 5, 7, 8}, (r, stages)
        packed = pack_stages(stages)
        assert [(packed >> (4 * s)) & 15 for s in range(len(stages))] == list(stages)


def test_laned_passes_span_the_axis():
    passes = axis_passes(4320, 2161, 4096, 8)
    spans = [p.span for p in passes]
    assert spans == [math.prod(p.radix for p in passes[:i]) for i in range(len(passes))]
    assert all(p.tile <= 4096 for p in passes), [p.tile for p in passes]


@pytest.mark.parametrize("n", [2, 4, 6, 8, 10, 12, 14, 96, 2160, 4320], ids=str)
def test_unit_roots_are_exact_where_they_can_be_and_accurate_elsewhere(n):
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.prec = 80
    w = unit_roots(n, np.float64)
    exact = np.array([[float(mpmath.cospi(mpmath.mpf(2 * m) / n)),
                       -float(mpmath.sinpi(mpmath.mpf(2 * m) / n))] for m in range(n)])
    ulps = np.abs(w - exact) / np.spacing(1.0)          # absolute, in ulps of 1
    assert ulps.max() <= 2, (n, ulps.max(), int(ulps.argmax()))
    for m, want in ((0, (1, 0)), (n // 2, (-1, 0))) + (((n // 4, (0, -1)),) if n % 4 == 0
                                                        else ()):
        assert tuple(w[m]) == want, (n, m, w[m])
    # conjugate symmetry W^(n - m) = conj W^m, exactly
    np.testing.assert_array_equal(w[1:, 0], w[:0:-1, 0])
    np.testing.assert_array_equal(w[1:, 1], -w[:0:-1, 1])
    w32 = unit_roots(n, np.float32)
    np.testing.assert_array_equal(w32, exact.astype(np.float32))   # rounded once, correctly

# }}}


# {{{ forward, inverse, round trip against numpy

#: (N0, N1), one per radix and mixed: 2 and 4 (4 x 8: radix 4 and 2), 8, 3, 5, 7, mixed
#: non-square ones, and a column of each radix in 2160 x 96
SHAPES = [(2, 2), (4, 8), (6, 10), (16, 8), (8, 32), (12, 6), (10, 20), (14, 28), (30, 42),
          (126, 70), (250, 24), (96, 160), (2160, 96), (64, 1458)]


@pytest.mark.parametrize("local_bytes", [None, SMALL_LOCAL], ids=["local", "small_local"])
@pytest.mark.parametrize("double", [False, True], ids=["f32", "f64"])
@pytest.mark.parametrize("case", list(enumerate(SHAPES)), ids=lambda c: "x".join(map(str, c[1])))
def test_forward_inverse_and_round_trip_match_numpy(runtime, case, double, local_bytes,
                                                    monkeypatch):
    skip_without_fp64(runtime, double)
    if local_bytes:
        monkeypatch.setattr(device_fft, "LOCAL_BYTES_CAP", local_bytes)
    k, shape = case
    batch = 1 + k % 4
    rng = np.random.default_rng(k)
    x = rng.standard_normal((batch, *shape)).astype(real_dtype(double))
    spec, plan = forward(runtime, x, double)
    want = np.fft.rfft2(x.astype(np.float64))
    err = plane_errors(spec, want)
    paths = f"rows {[p.radix for p in plan.row_passes] or 'one pass'}, columns " \
            f"{[p.radix for p in plan.col_passes]}"
    assert max(err) <= bound(shape, double), (err, bound(shape, double), paths)

    # the inverse of an arbitrary half spectrum (not the spectrum of a real plane: irfft2
    # drops the imaginary parts of columns 0 and N1/2 and the rest of its anti-Hermitian
    # part, about half its norm), against irfft2 of the same numbers
    spec_in = (rng.standard_normal(plan.spectrum_shape)
               + 1j * rng.standard_normal(plan.spectrum_shape)).astype(plan.complex_dtype)
    back = inverse(runtime, spec_in, shape, double)
    want_back = np.fft.irfft2(spec_in.astype(np.complex128), shape)
    err = plane_errors(back, want_back)
    assert max(err) <= bound(shape, double, inverse=True), (err, paths)

    # round trip: the device's own spectrum back to x
    trip = inverse(runtime, spec, shape, double)
    err = plane_errors(trip, x)
    assert max(err) <= bound(shape, double) + bound(shape, double, inverse=True), (err, paths)


@pytest.mark.parametrize("local_bytes", [None, SMALL_LOCAL], ids=["local", "small_local"])
@pytest.mark.parametrize("shape", [(12, 20), (96, 560)], ids=str)
def test_pruned_inverse_is_the_full_inverse_rows_written_at_an_offset(runtime, shape,
                                                                       local_bytes, monkeypatch):
    """Rows [r0, r1) of each plane, written at an offset of a larger buffer, bit for bit those
    of the whole inverse; nothing around them written."""
    if local_bytes:
        monkeypatch.setattr(device_fft, "LOCAL_BYTES_CAP", local_bytes)
    batch, (n0, n1) = 3, shape
    x = np.random.default_rng(1).standard_normal((batch, n0, n1)).astype(np.float32)
    spec, plan = forward(runtime, x, False)
    full = inverse(runtime, spec, shape, False)
    src = cla.to_device(runtime.queue, spec)
    for r0, r1 in ((0, n0), (n0 // 3, n0 // 3 + n0 // 2), (n0 - 1, n0), (0, 1)):
        sentinel = np.float32(-7.25)
        before, size = 6, batch * (r1 - r0) * n1
        out = cla.to_device(runtime.queue, np.full(before + size + 5, sentinel, np.float32))
        plan.inverse(src, out, rows=(r0, r1), dst_offset=before).wait()
        got = out.get()
        np.testing.assert_array_equal(got[before:before + size].reshape(batch, r1 - r0, n1),
                                      full[:, r0:r1], err_msg=f"rows [{r0}, {r1})")
        assert (got[:before] == sentinel).all() and (got[before + size:] == sentinel).all()


def test_large_plane_forward_and_pruned_inverse(runtime):
    """2160 x 4320 (a UHD map padded): rows of 2160 complex points in one work-group, columns
    of 2160 in passes."""
    shape = (2160, 4320)
    x = np.random.default_rng(2).standard_normal((1, *shape)).astype(np.float32)
    spec, plan = forward(runtime, x, False)
    want = np.fft.rfft2(x.astype(np.float64))
    err = plane_errors(spec, want)
    assert max(err) <= bound(shape, False), (err, bound(shape, False))
    back = inverse(runtime, spec, shape, False, rows=(100, 2100))
    err = plane_errors(back, x[:, 100:2100])
    assert max(err) <= bound(shape, False) + bound(shape, False, True), err

# }}}


# {{{ adversarial inputs

def adversarial(kind, shape, double, rng):
    n0, n1 = shape
    i, j = np.indices(shape)
    if kind == "impulse_origin":
        x = (i == 0) & (j == 0)
    elif kind == "impulse_inside":
        x = (i == n0 // 3) & (j == n1 - 3)
    elif kind == "constant":
        x = np.full(shape, 3.0)
    elif kind == "alternating":          # all of its energy at the Nyquist corner
        x = (-1.0) ** (i + j)
    elif kind == "alternating_rows":
        x = (-1.0) ** i * np.ones(shape)
    elif kind == "dynamic_range":        # |x| from 1e-30 to 1e30 (1e-200..1e200 in float64)
        span = 200 if double else 30
        x = rng.choice([-1.0, 1.0], shape) * 10.0 ** rng.uniform(-span, span, shape)
    else:
        raise AssertionError(kind)
    return np.asarray(x, np.float64)


KINDS = ["impulse_origin", "impulse_inside", "constant", "alternating", "alternating_rows",
         "dynamic_range"]


@pytest.mark.parametrize("double", [False, True], ids=["f32", "f64"])
@pytest.mark.parametrize("shape", [(6, 10), (120, 84), (256, 250)], ids=str)
def test_adversarial_inputs_stay_within_the_bound(runtime, shape, double):
    """Every kind in one batch, the others' planes scaled 1e-20 .. 1e20 apart (float32:
    1e-10 .. 1e10) beside the dynamic range's: each plane held to its own norm, forward and
    inverse."""
    skip_without_fp64(runtime, double)
    rng = np.random.default_rng(3)
    top = 1e20 if double else 1e10
    scales = list(np.geomspace(1 / top, top, len(KINDS) - 1)) + [1.0]   # dynamic_range: 1
    x = np.stack([s * adversarial(k, shape, double, rng) for k, s in zip(KINDS, scales)])
    x = x.astype(real_dtype(double))
    spec, plan = forward(runtime, x, double)
    want = np.fft.rfft2(x.astype(np.float64))
    err = plane_errors(spec, want)
    assert max(err) <= bound(shape, double), dict(zip(KINDS, err))
    spec_in = want.astype(plan.complex_dtype)
    back = inverse(runtime, spec_in, shape, double)
    err = plane_errors(back, np.fft.irfft2(spec_in.astype(np.complex128), shape))
    assert max(err) <= bound(shape, double, inverse=True), dict(zip(KINDS, err))

# }}}


# {{{ the plan: buffers, offsets, builds

def test_plans_share_one_program_and_keep_their_scratch(runtime):
    """One program per precision serves every size (a new size builds nothing), and a plan's
    scratch buffers are made once and reused by each call."""
    DeviceFFT(runtime, (8, 8))
    built = programs.program_count()
    plan = DeviceFFT(runtime, (30, 42), 2)
    assert programs.program_count() == built
    x = cla.to_device(runtime.queue, np.ones((2, 30, 42), np.float32))
    spec = cla.empty(runtime.queue, plan.spectrum_shape, plan.complex_dtype)
    plan.forward(x, spec)
    plan.inverse(spec, x)
    scratch = list(plan.scratch)
    for _ in range(2):
        plan.forward(x, spec)
        plan.inverse(spec, x).wait()
    assert plan.scratch == scratch
    np.testing.assert_allclose(x.get(), 1.0, atol=1e-5)


def test_buffers_at_offsets_and_bad_offsets(runtime):
    shape, batch = (10, 12), 2
    plan = DeviceFFT(runtime, shape, batch)
    x = np.random.default_rng(4).standard_normal((batch, *shape)).astype(np.float32)
    padded = np.concatenate([np.zeros(4, np.float32), x.ravel()])
    src = cl.Buffer(runtime.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                    hostbuf=padded)
    spec = cla.empty(runtime.queue, 3 + int(np.prod(plan.spectrum_shape)), np.complex64)
    plan.forward(src, spec, src_offset=4, dst_offset=3).wait()
    got = spec.get()[3:].reshape(plan.spectrum_shape)
    assert max(plane_errors(got, np.fft.rfft2(x.astype(np.float64)))) <= bound(shape, False)
    with pytest.raises(ValueError, match="odd"):
        plan.forward(src, spec, src_offset=3)
    with pytest.raises(ValueError, match="bytes"):
        plan.forward(src, spec, src_offset=6)
    out = cla.empty(runtime.queue, (batch, 4, shape[1]), np.float32)
    with pytest.raises(ValueError, match="bytes"):
        plan.inverse(spec, out)                           # 4 rows' room for all 10
    for rows in ((3, 3), (-1, 4), (5, 11)):
        with pytest.raises(ValueError, match="rows"):
            plan.inverse(spec, out, rows=rows)

# }}}


def test_arrays_of_another_dtype_or_layout_are_refused(runtime):
    """An Array says what it holds: a float64 or strided source, a complex128 spectrum of a
    float32 plan, are ValueErrors, never silently read as float32 bytes."""
    plan = DeviceFFT(runtime, (40, 30), batch=2)
    q = runtime.queue
    x = np.random.default_rng(0).standard_normal((2, 40, 30))
    spectrum = cla.empty(q, plan.spectrum_shape, plan.complex_dtype)
    with pytest.raises(ValueError, match="float64 array; this plan takes float32"):
        plan.forward(cla.to_device(q, x), spectrum)
    wide = cla.to_device(q, np.zeros((2, 40, 60), np.float32))
    with pytest.raises(ValueError, match="strided"):
        plan.forward(wide[:, :, ::2], spectrum)
    with pytest.raises(ValueError, match="complex128 array; this plan takes complex64"):
        plan.forward(cla.to_device(q, x.astype(np.float32)),
                     cla.empty(q, plan.spectrum_shape, np.complex128))


@pytest.mark.parametrize("double", [False, True], ids=["f32", "f64"])
@pytest.mark.parametrize("shape", [(384, 216), (2160, 96), (64, 1458)], ids=str)
def test_tiles_leave_the_runtimes_reserve_free(runtime, shape, double):
    """Every pass's two tile buffers, with the kernels' own local memory, leave
    LOCAL_RESERVE_BYTES of the device's local memory free: NVIDIA's runtime keeps 1 KiB of a
    block's shared memory, and a float64 column pass of 384 points x 4 lanes (48 KiB, all of
    an H200's) failed to launch there (OUT_OF_RESOURCES)."""
    skip_without_fp64(runtime, double)
    plan = DeviceFFT(runtime, shape, 1, double)
    dev = runtime.device
    own = max(k.get_work_group_info(cl.kernel_work_group_info.LOCAL_MEM_SIZE, dev)
              for k in plan.kernels.values())
    room = min(dev.local_mem_size, device_fft.LOCAL_BYTES_CAP) - device_fft.LOCAL_RESERVE_BYTES
    tiles = [p.tile for p in (*plan.row_passes, *plan.col_passes)]
    if not plan.row_passes:                       # the fused row kernels' tile
        tiles.append(plan.m * plan.rows_tile)
    assert 2 * max(tiles) * plan.point_bytes + own <= room, (tiles, own, room)
