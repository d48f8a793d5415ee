"""The default inversion at the memory floor: kernels/invert_table.cl against kernels/invert.cl's
table path, and host arrays through ``bdipole_cl.device.transfer`` (zero copy, ``out=``, pinned
staging, cached kernels), once per working OpenCL device.

The vectorised kernel does the same operations on the same float32 values as the scalar one, so
the two must agree bit for bit (no tolerance): that is what keeps the accuracy bounds of
tests/test_invert.py and the monotone sweep's result (bdipole_cl/apps/monotone.py) its own.
"""
import numpy as np
import pyopencl as cl
import pytest

from bdipole_cl import InvalidInputError, albedo_to_coefficients, invert_albedo
from bdipole_cl.device import build_options, get_program, transfer
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.ops import inversion_kernel as ik
from bdipole_cl.ops.inversion_kernel import InversionKernel, TABLE_WIDTH_VARIABLE
from bdipole_cl.physics import tables
from conftest import skip_if_rejected

WANT = ("alpha", "rho", "sigma_a", "sigma_s")


def albedos(n):
    """Uniform and stiff-end albedos plus the kernel's special values, in float32."""
    rng = np.random.default_rng(3)
    special = [0.0, -1.0, 1.0, 1e-30, 1e-45, 0.5, np.nextafter(np.float32(0.5), 0),
               np.nextafter(np.float32(1), 0)]
    return np.float32(np.concatenate([rng.uniform(1e-6, 0.999, n), np.geomspace(1e-7, 0.5, 500),
                                      1 - np.geomspace(6e-8, 0.5, 500), special]))


def scalar_table_kernel(etas, model, runtime):
    """kernels/invert.cl's BD_METHOD_TABLE path for the default config (the reference here)."""
    k = InversionKernel(etas, MethodConfig(), model=model, runtime=runtime)
    k.width = 0
    k.kernel = cl.Kernel(get_program(runtime, "invert", build_options(
        k.config.defines(False), model=model)), "invert_albedo")
    k.tables = cl.Buffer(runtime.context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                         hostbuf=tables.channel_tables(etas, k.table_n, model=model))  # its rows
    return k


@pytest.mark.parametrize("width", ["1", "2", "4", "8", "16"])
@pytest.mark.parametrize("etas", [(1.4,), (1.3, 1.4, 2.0)], ids=["1ch", "3ch"])
@pytest.mark.parametrize("model", ["better", "dipole"])
@pytest.mark.parametrize("specialise", [False, True], ids=["generic", "specialised"])
def test_vector_kernel_is_bitwise_the_scalar_one(runtime, monkeypatch, width, etas, model,
                                                 specialise):
    """Every width, channel count and model, generic or with the constants compiled in
    (``specialise``), a length that leaves a partial last work-item, mfp per element and per
    channel: the same bits as kernels/invert.cl."""
    skip_if_rejected(runtime, "invert_table", width)
    monkeypatch.setenv(TABLE_WIDTH_VARIABLE, width)
    rd = albedos(20011)
    rd = rd[:rd.size - rd.size % len(etas)]
    mfp = np.random.default_rng(4).uniform(0.1, 10.0, rd.size).astype(np.float32)
    want = scalar_table_kernel(etas, model, runtime).run(rd, mfp, WANT)
    fast = InversionKernel(etas, MethodConfig(), model=model, runtime=runtime,
                           specialise=specialise)
    assert fast.width == int(width)
    got = fast.run(rd, mfp, WANT)
    for k in WANT:
        np.testing.assert_array_equal(got[k], want[k], err_msg=f"{k}, width {width}")
    per_channel = np.float32([2.0, 0.5, 7.0][:len(etas)])
    want_c = scalar_table_kernel(etas, model, runtime).run(
        rd, np.tile(per_channel, rd.size // len(etas)), WANT)
    got_c = fast.run(rd, None, WANT, mfp_channels=per_channel)
    for k in WANT:
        np.testing.assert_array_equal(got_c[k], want_c[k], err_msg=f"{k} per channel")


def test_default_is_vectorised_on_cpus(runtime):
    """The default configuration runs kernels/invert_table.cl (at the device's elements per
    work-item); float64 and polished or other methods keep kernels/invert.cl."""
    k = InversionKernel((1.4,), MethodConfig(), runtime=runtime)
    assert k.width == ik.table_width(runtime) >= 1
    assert not InversionKernel((1.4,), MethodConfig("table", polish=1), runtime=runtime).width
    assert not InversionKernel((1.4,), MethodConfig("bisection"), runtime=runtime).width


@pytest.mark.parametrize("n", [4, 256, 4096])
@pytest.mark.parametrize("eta, model", [(1.4, "better"), (1.0, "better"), (2.8, "dipole")])
def test_rows_hold_the_c3_the_vector_kernel_derives(n, eta, model):
    """invert_table.cl gathers c0, c1, c2 and the end node and forms c3 = ((end - c0) - c1) - c2
    in float32: every cubic row of every segment must hold exactly that float (else the two
    kernels differ), and the records it reads must be those four values of the rows."""
    rows = tables.inversion_table(eta, n, model=model)[0]
    records = ik.interval_records(rows)
    for seg in rows.reshape(tables.SEGMENTS, n + 1, 4):
        c0, c1, c2, c3 = seg[:-1].T
        end = seg[1:, 0]
        assert c3.dtype == np.float32
        np.testing.assert_array_equal(c3, ((end - c0) - c1) - c2)
    np.testing.assert_array_equal(records[:, :3], rows[:, :3])
    np.testing.assert_array_equal(records[:-1, 3], rows[1:, 0])
    if n >= 64:       # the margin holds from 64 intervals at every eta (docs/model.md)
        assert tables.table_is_monotone(eta, n, model=model)


class _FakeCpu:
    """What table_width reads of a device: its type, platform, native float lanes and key."""

    def __init__(self, platform, lanes):
        self.type = cl.device_type.CPU
        self.platform = type("P", (), {"name": platform, "version": "OpenCL 3.0"})()
        self.native_vector_width_float = lanes
        self.vendor, self.name, self.driver_version = "fake", f"cpu {lanes}", "0"
        self.version = "OpenCL 3.0"                 # no verdict cached for it: the defaults


@pytest.mark.parametrize("platform, lanes, width", [
    ("Intel(R) OpenCL", 16, 1), ("Intel(R) OpenCL", 8, 16), ("Intel(R) OpenCL", 4, 16),
    ("Portable Computing Language", 16, 16), ("Portable Computing Language", 8, 8),
    ("Some Other CPU Runtime", 16, 8)])
def test_table_width_by_platform_and_native_lanes(monkeypatch, tmp_path, platform, lanes, width):
    """The measured defaults (``TABLE_WIDTHS``): Intel's runtime 1 on an AVX-512 CPU (16
    native float lanes), 16 on others; PoCL 16 on an AVX-512 CPU, 8 on others; an unlisted CPU
    runtime 8."""
    monkeypatch.delenv(TABLE_WIDTH_VARIABLE, raising=False)
    monkeypatch.delenv("BDIPOLE_CL_CHOICE_DATA", raising=False)
    monkeypatch.setenv("BDIPOLE_CL_CACHE_DIR", str(tmp_path))     # no calibration there
    rt = type("Rt", (), {"device": _FakeCpu(platform, lanes)})()
    assert ik.table_width(rt) == width


@pytest.mark.parametrize("n", [1, 15, 16, 17, 4099])
@pytest.mark.parametrize("where", [0, -1])
def test_kernel_finds_invalid_albedo(on_device, n, where):
    """float32 input is tested by the kernel: an invalid value anywhere, the partial last
    work-item included, is named with its index, as the host test names it."""
    rd = np.full(n, 0.3, np.float32)
    rd[where] = np.nan
    with pytest.raises(InvalidInputError, match=rf"first at index \({n - 1 if where else 0},\)"):
        invert_albedo(rd, 1.4)
    got = invert_albedo(rd, 1.4, on_invalid="clamp", return_rho=True)
    want = invert_albedo(np.where(np.isnan(rd), 0, rd), 1.4, return_rho=True)
    np.testing.assert_array_equal(got, want)
    mfp = np.ones(n, np.float32)
    mfp[where] = -1.0
    with pytest.raises(InvalidInputError, match="mfp"):
        albedo_to_coefficients(np.full(n, 0.3, np.float32), mfp, 1.4)


def test_out_arrays_are_written_in_place(on_device):
    """``out=``: the results are the given arrays (reshaped views of them), bit for bit those
    of a call without ``out``."""
    rd = albedos(3000).reshape(-1, 2)[:1500]
    alpha, rho = np.empty(rd.shape, np.float32), np.empty(rd.shape, np.float32)
    got = invert_albedo(rd, 1.4, return_rho=True, out=(alpha, rho))
    assert got[0].ctypes.data == alpha.ctypes.data and got[1].ctypes.data == rho.ctypes.data
    want = invert_albedo(rd, 1.4, return_rho=True)
    np.testing.assert_array_equal(alpha, want[0])
    np.testing.assert_array_equal(rho, want[1])
    sa, st = np.empty(rd.shape, np.float32), np.empty(rd.shape, np.float32)
    res = albedo_to_coefficients(rd, 2.0, 1.4, outputs=("sigma_a", "sigma_t"), out=(sa, st))
    assert res[0].ctypes.data == sa.ctypes.data and res[1].ctypes.data == st.ctypes.data
    with pytest.raises(ValueError, match="out"):
        invert_albedo(rd, 1.4, out=np.empty(rd.shape, np.float64))


@pytest.mark.parametrize("offset", [-40, -1, 1, 3, 40])
def test_out_overlapping_the_input_gives_what_separate_arrays_give(on_device, offset):
    """An out= view shifted against the input (as NumPy ufuncs allow) is written as if they
    were apart (the input copied first); the very same array (out=rd) is in place."""
    rd = np.random.default_rng(0).uniform(0.01, 0.99, 4096).astype(np.float32)
    mfp = np.full(4096, 2.0, np.float32)
    want = invert_albedo(rd, 1.4)
    want_sa, _ = albedo_to_coefficients(rd, mfp, 1.4)
    big = np.zeros(4400, np.float32)
    big[100:4196] = rd
    invert_albedo(big[100:4196], 1.4, out=big[100 + offset:4196 + offset])
    np.testing.assert_array_equal(big[100 + offset:4196 + offset], want)
    big[100:4196] = mfp
    sa = big[100 + offset:4196 + offset]
    albedo_to_coefficients(rd, big[100:4196], 1.4, out=(sa, np.empty_like(rd)))
    np.testing.assert_array_equal(sa, want_sa)
    same = rd.copy()
    invert_albedo(same, 1.4, out=same)
    np.testing.assert_array_equal(same, want)


def test_out_arrays_that_overlap_each_other_are_refused(on_device):
    rd = np.linspace(0.05, 0.95, 12, dtype=np.float32)
    o = np.empty(24, np.float32)
    for pair in ((o[:12], o[:12]), (o[:12], o[6:18])):
        with pytest.raises(ValueError, match="alpha and rho overlap"):
            invert_albedo(rd, 1.4, return_rho=True, out=pair)


def test_host_memory_is_used_without_copies_where_the_device_shares_it(runtime):
    """On a device that shares host memory (a CPU device) the kernel's buffers are the host
    arrays themselves: mapping an output buffer gives back the array's own memory (in each
    launch). On a discrete one (a GPU) they are device buffers, filled from pinned staging
    (``CL_MEM_ALLOC_HOST_PTR``) kept across calls."""
    k = InversionKernel((1.4,), MethodConfig(), runtime=runtime)
    out = transfer.aligned_empty(4096, np.float32)
    rd = albedos(4000)[:4096]
    pointers, flags = [], []

    def launch(n, bufs, wait_for=None):
        event = k(n, bufs["rd"], alpha=bufs["alpha"], wait_for=wait_for)
        flags.append(bufs["alpha"].flags)
        mapped, _ = cl.enqueue_map_buffer(runtime.queue, bufs["alpha"], cl.map_flags.READ, 0,
                                          (n,), np.float32, wait_for=[event], is_blocking=True)
        pointers.append(mapped.ctypes.data)
        mapped.base.release(runtime.queue)
        return event

    transfer.run_elementwise(runtime, launch, {"rd": rd}, {"alpha": out})
    np.testing.assert_array_equal(out, k.run(rd)["alpha"])
    if transfer.shares_host_memory(runtime):
        # rd (a slice of NumPy's array) is not aligned: its head is a launch of its own
        head = transfer.aligned_head(rd, transfer.base_alignment(runtime))
        assert pointers == [out.ctypes.data] + ([out.ctypes.data + 4 * head] if head else [])
        assert all(f & cl.mem_flags.USE_HOST_PTR for f in flags)
    else:
        assert not any(f & cl.mem_flags.USE_HOST_PTR for f in flags)
        pinned = [key for key in transfer.DEVICE_BUFFERS._data if "pinned" in str(key)]
        assert pinned, "no pinned staging buffer was made"


def test_staged_path_reuses_its_buffers(runtime, monkeypatch):
    """The discrete-device path (pinned staging into device buffers, chunks in a pipeline of
    STAGES on three queues; forced here on a CPU device) gives the same bits, over many
    chunks, and allocates nothing on a second call."""
    monkeypatch.setattr(transfer, "shares_host_memory", lambda rt: False)
    monkeypatch.setattr(transfer, "DEVICE_CHUNK", 1 << 12)
    transfer.DEVICE_BUFFERS.clear()
    rd = albedos(30000)                             # 8 chunks: every slot used again
    k = InversionKernel((1.4,), MethodConfig(), runtime=runtime)
    got = k.run(rd, None, ("alpha", "rho"))
    held = len(transfer.DEVICE_BUFFERS)
    again = k.run(rd, None, ("alpha", "rho"))
    # rd, alpha, rho: a device and a pinned buffer each per stage, and the two extra queues
    assert held == 3 * 2 * transfer.STAGES + 1 and len(transfer.DEVICE_BUFFERS) == held
    monkeypatch.undo()
    want = k.run(rd, None, ("alpha", "rho"))
    for key in ("alpha", "rho"):
        np.testing.assert_array_equal(got[key], want[key])
        np.testing.assert_array_equal(again[key], want[key])


def test_kernels_are_kept_across_calls(on_device):
    """A second call with the same arguments builds nothing and makes no new kernel."""
    ik.KERNEL_CACHE.clear()
    rd = albedos(100)
    invert_albedo(rd, 1.7, return_rho=True)
    first = dict(ik.KERNEL_CACHE._data)
    invert_albedo(rd, 1.7, return_rho=True)
    assert len(first) == 1 and dict(ik.KERNEL_CACHE._data).keys() == first.keys()
    assert next(iter(ik.KERNEL_CACHE._data.values()))[0][1] is next(iter(first.values()))[0][1]


@pytest.mark.parametrize("make, why", [
    (lambda: np.empty((3, 8), np.float32)[:, ::2], "not C-contiguous"),
    (lambda: np.empty((3, 4), np.float64), "its dtype is float64"),
    (lambda: np.empty((3, 5), np.float32), "it has 15 elements"),
    (lambda: np.frombuffer(bytes(48), np.float32).reshape(3, 4), "read-only")])
def test_a_wrong_out_array_is_named_with_its_fault(make, why):
    """out= arrays refused for each reason by that reason (they all read the same before)."""
    with pytest.raises(ValueError, match=why):
        invert_albedo(np.full((3, 4), 0.5, np.float32), 1.4, out=make())


@pytest.mark.parametrize("items", [0, 1, 1023, 1024, 1025, 4099, 33554393])
def test_launches_cover_every_work_item_once(items):
    """``launch_ranges``: consecutive launches from 0 that cover the work-items exactly once,
    all but the last a multiple of LAUNCH_MULTIPLE (a prime count gets a bulk launch too)."""
    from bdipole_cl.device.launch import LAUNCH_MULTIPLE, launch_ranges
    ranges = launch_ranges(items)
    assert sum(count for _, count in ranges) == items
    assert all(first == sum(c for _, c in ranges[:i]) for i, (first, _) in enumerate(ranges))
    assert all(count > 0 for _, count in ranges)
    assert all(count % LAUNCH_MULTIPLE == 0 for _, count in ranges[:-1])
    assert len(ranges) <= 2 and (items < LAUNCH_MULTIPLE or ranges[0][1] % LAUNCH_MULTIPLE == 0)


def test_prime_length_inverts_as_the_composite_one(runtime):
    """A prime number of albedos (one launch of a multiple of 1024 work-items, then the rest,
    numbered on by the global offset) gives each albedo the value it has in a longer array."""
    rd = albedos(70000)[:65537]                      # 65537 is prime
    whole = invert_albedo(albedos(70000), 1.4, return_rho=True, device=runtime)
    part = invert_albedo(rd, 1.4, return_rho=True, device=runtime)
    for got, want in zip(part, whole):              # alpha', rho
        np.testing.assert_array_equal(got, want[:rd.size])


@pytest.mark.parametrize("multiple, nchan", [(48, 3), (24, 3), (16, 1), (1, 1), (5, 5)])
def test_every_host_chunk_starts_aligned(runtime, monkeypatch, multiple, nchan):
    """In host memory, after the head every launch starts on the runtime's base alignment
    and on a channel boundary, and all but the last hold a multiple of ``multiple`` elements
    (chunks of a multiple of 48, a 3-channel width-16 kernel's, moved the second chunk off
    the alignment: the runtime then copies it whole)."""
    monkeypatch.setattr(transfer, "_max_chunk", lambda rt, itemsize: 5000)   # several chunks
    align = transfer.base_alignment(runtime)
    base = transfer.aligned_empty(60000, np.float32)
    rd = base[5:5 + 3 * 17000]                        # an unaligned start: a head first
    chunks = transfer._host_chunks(runtime, [rd], rd.size, 4, multiple, nchan)
    assert chunks[0][0] == 0 and chunks[-1][1] == rd.size
    assert all(a[1] == b[0] for a, b in zip(chunks, chunks[1:]))          # no gap, no overlap
    head = transfer.aligned_head(rd, align, nchan)
    body = chunks[1:] if head else chunks
    assert len(body) > 2
    for start, stop in body:
        assert (rd.ctypes.data + 4 * start) % align == 0 and start % nchan == 0, (start, stop)
    assert all((stop - start) % multiple == 0 for start, stop in body[:-1])
