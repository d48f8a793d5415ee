"""The inversion plan (``bdipole_cl.ops.inversion_plan``): made once, applied per band, its
program built once, its outputs written where the caller says; and host arrays reaching the
kernel in place whatever their offset from the device's alignment (``device.transfer``).

The plan does the same operations on the same values as one call on the whole array, so the
comparisons are exact (no tolerance)."""
import re

import numpy as np
import pyopencl as cl
import pytest

from bdipole_cl import InvalidInputError, albedo_to_coefficients, clear_caches, invert_albedo
from bdipole_cl.device import programs, transfer
from bdipole_cl.methods.registry import MethodConfig
from bdipole_cl.ops import inversion_kernel as ik
from bdipole_cl.ops.invert import CoefficientMapper, InversionPlan, Inverted, plan_inversion

ETAS = (1.3, 1.4, 2.0)


def albedo_map(h=37, w=29, seed=5):
    """An h x w RGB float32 albedo map (odd sizes: bands end mid work-item), stiff ends too."""
    rng = np.random.default_rng(seed)
    rd = rng.uniform(1e-6, 0.999, (h, w, 3)).astype(np.float32)
    rd[0, :3] = [[1e-7, 0.5, 0.9999]] * 3
    return rd


def bands(height, rows):
    return [(y, min(y + rows, height)) for y in range(0, height, rows)]


@pytest.fixture
def build_count(monkeypatch):
    """How many times kernels/invert*.cl programs are asked for (``get_program`` calls from
    the inversion kernels), with the inversion kernel cache emptied first."""
    ik.KERNEL_CACHE.clear()
    calls = []
    real = ik.get_program

    def counting(rt, name, options=()):
        calls.append((name, options))
        return real(rt, name, options)

    monkeypatch.setattr(ik, "get_program", counting)
    return calls


@pytest.mark.parametrize("kind", ["albedo", "diffuse", "extinction"])
@pytest.mark.parametrize("specialise", [False, True], ids=["generic", "specialised"])
def test_plan_per_band_is_one_call_and_builds_once(on_device, build_count, kind, specialise):
    """One plan applied band by band (uneven bands, an mfp map) gives the bits of one call on
    the whole map, and asks for its program once, not once per band."""
    rd = albedo_map()
    mfp = np.random.default_rng(6).uniform(0.1, 9.0, rd.shape).astype(np.float32)
    if kind == "albedo":
        outputs, mfp_kind, args = ("alpha", "rho"), None, (rd,)
        want = invert_albedo(rd, ETAS, return_rho=True)
    else:
        outputs, mfp_kind, args = ("sigma_a", "sigma_s", "sigma_t"), kind, (rd, mfp)
        want = albedo_to_coefficients(rd, mfp, ETAS, outputs=outputs, mfp_kind=kind)
    built_by_calls = len(build_count)
    plan = plan_inversion(ETAS, outputs=outputs, mfp_kind=mfp_kind, specialise=specialise)
    got = {k: np.empty(rd.shape, np.float32) for k in outputs}
    before = len(build_count)
    for y0, y1 in bands(rd.shape[0], 8):
        band = plan.apply(rd[y0:y1], None if mfp_kind is None else mfp[y0:y1])
        assert isinstance(band, Inverted) and tuple(band.arrays) == outputs
        for k in outputs:
            got[k][y0:y1] = band.arrays[k]
    assert len(build_count) - before <= 1, build_count[before:]     # built by the first band
    assert built_by_calls >= 1                                       # (the spy sees builds)
    for k, w in zip(outputs, want):
        np.testing.assert_array_equal(got[k], w, err_msg=f"{k}, {kind}")


def test_plan_builds_one_program_in_the_cache(on_device):
    """Counted in the built-program cache itself: the first apply builds one program, five
    more bands build none."""
    clear_caches()
    plan = plan_inversion((1.4,), outputs=("alpha", "rho"))
    rd = albedo_map()[..., 0]
    start = programs.program_count()
    plan.apply(rd[:5])
    assert programs.program_count() == start + 1
    for y in range(5, 30, 5):
        plan.apply(rd[y:y + 5])
    assert programs.program_count() == start + 1


def test_plan_fills_given_outputs(on_device):
    """``out=`` as a dict, a sequence in outputs order, or one array: the results are those
    arrays (views of the same memory), bit for bit those of a plan without ``out``."""
    rd = albedo_map()
    plan = plan_inversion(ETAS, outputs=("rho", "sigma_s"), mfp_kind="diffuse")
    want = plan.apply(rd, 2.0).arrays
    rho, ss = np.empty(rd.shape, np.float32), np.empty(rd.shape, np.float32)
    for out in ({"rho": rho, "sigma_s": ss}, (rho, ss)):
        rho[...] = ss[...] = np.nan
        got = plan.apply(rd, 2.0, out=out).arrays
        assert got["rho"].ctypes.data == rho.ctypes.data
        assert got["sigma_s"].ctypes.data == ss.ctypes.data
        np.testing.assert_array_equal(rho, want["rho"])
        np.testing.assert_array_equal(ss, want["sigma_s"])
    alpha = np.empty(rd.shape[:2] + (1,), np.float32)
    one = plan_inversion((1.4,)).apply(rd[..., :1], out=alpha).arrays["alpha"]
    assert one.ctypes.data == alpha.ctypes.data
    with pytest.raises(ValueError, match="3 arrays for the 2 outputs"):
        plan.apply(rd, 2.0, out=(rho, ss, ss))


def test_plan_masks_and_counts_invalid_texels(on_device):
    """A mask leaves texels out (0 out, not validated); with "clamp" the counts of invalid
    albedo and mfp values are returned; with "raise" the first is named."""
    rd = albedo_map(6, 5)
    rd[1, 2, 0], rd[2, 3, 1] = np.nan, 1.0
    mfp = np.full(rd.shape, 2.0, np.float32)
    mfp[4, 4, 2] = -1.0
    mask = np.ones(rd.shape[:2] + (1,), np.float32)
    mask[2, 3] = 0
    plan = plan_inversion(ETAS, outputs=("sigma_a",), mfp_kind="diffuse", on_invalid="clamp")
    done = plan.apply(rd, mfp, mask)
    assert (done.invalid_albedo, done.invalid_mfp) == (1, 1)
    assert np.all(done.arrays["sigma_a"][2, 3] == 0)
    with pytest.raises(InvalidInputError, match="albedo"):
        plan_inversion(ETAS, outputs=("sigma_a",), mfp_kind="diffuse").apply(rd, mfp)
    albedo_plan = plan_inversion(ETAS, on_invalid="clamp")
    assert albedo_plan.apply(rd).invalid_albedo == 1        # Rd = 1 is valid here, NaN not
    with pytest.raises(ValueError, match="no mfp"):
        albedo_plan.apply(rd, mfp)
    with pytest.raises(ValueError, match="need an mfp"):
        InversionPlan(ETAS, outputs=("sigma_a",))


def test_coefficient_mapper_is_the_plan(on_device):
    """The older ``CoefficientMapper`` (``bake=`` the older name of ``specialise=``) returns
    (outputs, counts) from the plan it holds, the same bits as ``albedo_to_coefficients``."""
    rd = albedo_map()
    mapper = CoefficientMapper(ETAS, MethodConfig(), outputs=("sigma_a", "sigma_s"), bake=True,
                               mfp_const=(1.0, 2.0, 3.0))
    assert isinstance(mapper.plan, InversionPlan) and mapper.plan.specialise
    assert mapper.kernel.mfp_compiled and mapper.outputs == ("sigma_a", "sigma_s")
    mfp = np.broadcast_to(np.float32([1.0, 2.0, 3.0]), rd.shape)
    outs, counts = mapper(rd, mfp, None)
    assert counts == {"albedo": 0, "mfp": 0}
    want = albedo_to_coefficients(rd, np.array(mfp), ETAS)
    for k, w in zip(("sigma_a", "sigma_s"), want):
        np.testing.assert_array_equal(outs[k], w, err_msg=k)


@pytest.mark.parametrize("offset", [0, 4, 12, 16, 64, 124])
@pytest.mark.parametrize("nchan", [1, 3])
def test_unaligned_inputs_are_used_in_place(runtime, monkeypatch, offset, nchan):
    """An input that starts ``offset`` bytes past the device's alignment (NumPy's arrays start
    16 bytes past a page) goes, on a device that shares host memory, in two launches: its
    head, then the rest from the boundary, whose buffer is the array itself (aligned, so the
    runtime need not copy it); on a discrete one through pinned staging. The channel
    phase is kept (the head is a whole number of texels), so the results are those of an
    aligned copy of the input."""
    align = transfer.base_alignment(runtime)
    n = 3 * 1000 + 7 if nchan == 1 else 3 * 1000
    raw = transfer.aligned_empty(n + align, np.float32)
    rd = raw[offset // 4:offset // 4 + n]
    rd[...] = albedo_map(40, 26).reshape(-1)[:n]
    etas = ETAS if nchan == 3 else (1.4,)
    k = ik.InversionKernel(etas, MethodConfig(), runtime=runtime)
    want = k.run(np.array(rd), None, ("alpha", "rho"))
    made = []
    real = cl.Buffer

    def spy(context, flags, size=0, hostbuf=None):
        if hostbuf is not None and flags & cl.mem_flags.READ_ONLY:
            made.append((hostbuf.ctypes.data, hostbuf.size))
        return real(context, flags, size, hostbuf)

    monkeypatch.setattr(transfer.cl, "Buffer", spy)
    got = k.run(rd, None, ("alpha", "rho"))
    monkeypatch.undo()
    head = transfer.aligned_head(rd, align, nchan)
    assert head % nchan == 0 and (rd.ctypes.data + 4 * head) % align == 0
    if transfer.shares_host_memory(runtime):
        assert made[-1][0] % align == 0, (offset, made)
        assert sum(size for _, size in made) == n and (len(made) == 2) == (head > 0), made
    else:                     # a discrete device: through pinned staging, no buffer on the array
        assert not made, made
    for key in ("alpha", "rho"):
        np.testing.assert_array_equal(got[key], want[key], err_msg=f"{key}, offset {offset}")


def test_plan_refuses_a_channel_count_that_is_not_its_etas(runtime):
    """Three etas are one per channel: a two-channel input is an error, not etas cycled over
    the texels."""
    import bdipole_cl as bd
    plan = bd.plan_inversion((1.3, 1.4, 1.5), device=runtime)
    with pytest.raises(ValueError, match="eta has 3 values but the input's last axis has 2"):
        plan.apply(np.full((4, 4, 2), 0.5, np.float32))
    one = bd.plan_inversion(1.4, device=runtime)          # a scalar eta, as elsewhere
    assert one.apply(np.full(5, 0.5, np.float32)).arrays["alpha"].shape == (5,)


def test_plan_pickles_and_masks_by_texel(runtime):
    """A plan pickles as its settings (for clusters); an HxW mask masks every channel."""
    import pickle

    import bdipole_cl as bd
    plan = bd.plan_inversion((1.3, 1.4, 1.5), outputs=("sigma_a",), mfp_kind="diffuse",
                             device=runtime)
    again = pickle.loads(pickle.dumps(plan))
    rd = np.full((4, 4, 3), 0.5, np.float32)
    mask = np.ones((4, 4))
    mask[0] = 0
    got = again.apply(rd, 1.0, mask=mask).arrays["sigma_a"]
    want = plan.apply(rd, 1.0).arrays["sigma_a"]
    assert np.all(got[0] == 0)
    np.testing.assert_array_equal(got[1:], want[1:])


def test_out_of_the_inputs_size_in_another_shape_is_refused():
    """out= arrays take the input's shape or are flat: a transposed image of the same size
    would be filled in the input's layout (its rows would not be the image's rows)."""
    rd = np.random.default_rng(5).uniform(0.05, 0.95, (11, 13, 3)).astype(np.float32)
    want = invert_albedo(rd, (1.3, 1.4, 1.5))
    for bad in ((13, 11, 3), (1, 11, 13, 3), (11, 39)):
        with pytest.raises(ValueError, match=r"out\['alpha'\]: shape .* is not the input's"):
            invert_albedo(rd, (1.3, 1.4, 1.5), out=np.zeros(bad, np.float32))
    for good in (rd.shape, (rd.size,)):
        got = np.zeros(good, np.float32)
        invert_albedo(rd, (1.3, 1.4, 1.5), out=got)
        np.testing.assert_array_equal(got.reshape(rd.shape), want)


def test_an_hxw_mfp_map_serves_every_channel():
    """An HxW mfp map beside HxWx3 albedos is one mfp per texel for every channel (as a mask
    is); where NumPy's own broadcasting applies (one mfp per channel) it is kept; a shape that
    fits neither is one ValueError naming both shapes."""
    rng = np.random.default_rng(6)
    rd = rng.uniform(0.05, 0.95, (5, 7, 3)).astype(np.float32)
    mfp = rng.uniform(0.5, 4.0, (5, 7)).astype(np.float32)
    got = albedo_to_coefficients(rd, mfp, 1.4)
    want = albedo_to_coefficients(rd, np.repeat(mfp[..., None], 3, axis=-1), 1.4)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    for h, w in ((3, 3), (1, 3), (3, 1)):    # where NumPy alone would read it per channel
        small_rd, small_mfp = rd[:h, :w], mfp[:h, :w].copy()
        got = albedo_to_coefficients(small_rd, small_mfp, 1.4)
        want = albedo_to_coefficients(small_rd, np.repeat(small_mfp[..., None], 3, -1), 1.4)
        for g, x in zip(got, want):
            assert g.shape == small_rd.shape
            np.testing.assert_array_equal(g, x)
    square = rng.uniform(0.05, 0.95, (3, 3)).astype(np.float32)
    per_column = np.float32([1.0, 2.0, 4.0])              # NumPy's rule: one per last-axis entry
    got = albedo_to_coefficients(square, per_column, 1.4)
    want = albedo_to_coefficients(square, np.tile(per_column, (3, 1)), 1.4)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    with pytest.raises(ValueError, match=r"mfp of shape \(7, 5\) does not fit albedo of shape"):
        albedo_to_coefficients(rd, mfp.T, 1.4)


@pytest.mark.parametrize("bad", [None, True, "1.4", (1.3, None, 1.5), [True, 1.4, 1.4]])
def test_eta_must_be_numbers(bad):
    """eta (and the blur's constant parameters) are real numbers: None, a bool or a string
    is one ValueError naming it, not NaN's range error or a silent 1.0 or parsed float."""
    from bdipole_cl import blur
    rd = np.full((2, 3), 0.5, np.float32)
    shown = repr(bad if not isinstance(bad, (tuple, list)) else next(
        e for e in bad if not isinstance(e, float)))
    with pytest.raises(ValueError, match=rf"eta={re.escape(shown)}: expected a number"):
        invert_albedo(rd, bad)
    with pytest.raises(ValueError, match=rf"eta={re.escape(shown)}: expected a number"):
        blur(np.ones((4, 4, 3), np.float32), albedo=0.5, mfp=1.0, eta=bad)
    if bad is not None:                  # (albedo=None: not given, an error of its own)
        with pytest.raises(ValueError, match=rf"albedo={re.escape(shown)}: expected a number"):
            blur(np.ones((4, 4, 3), np.float32), albedo=bad, mfp=1.0)


@pytest.mark.parametrize("mfp_form", ["per texel", "per channel", "hxw"])
def test_clamped_coefficients_are_those_of_the_clamped_inputs(mfp_form):
    """With on_invalid="clamp", the texels with an invalid albedo or mfp (mapped again on
    their own, all their channels) come out as the clamped inputs' coefficients, bit for bit,
    and the others untouched; the counts are the invalid values'."""
    from bdipole_cl.ops.inversion_plan import MFP_CLAMP_RANGE, RD_CLAMP_MAX
    rng = np.random.default_rng(8)
    rd = rng.uniform(0.05, 0.95, (7, 9, 3)).astype(np.float32)
    mfp = {"per texel": rng.uniform(0.5, 4.0, (7, 9, 3)).astype(np.float32),
           "per channel": np.float32([1.0, 2.0, 0.5]),
           "hxw": rng.uniform(0.5, 4.0, (7, 9)).astype(np.float32)}[mfp_form]
    rd[0, 0, 1], rd[3, 4, 2], rd[6, 8, 0], rd[2, 2, 0] = np.nan, 1.0, -np.inf, 7.0
    fixed_rd = np.where(np.isnan(rd) | np.isneginf(rd), 0, np.minimum(rd, RD_CLAMP_MAX))
    fixed_mfp = mfp
    if mfp_form != "per channel":
        mfp = mfp.copy()
        mfp[(1, 1, 0) if mfp.ndim == 3 else (1, 1)] = 0.0
        mfp[(5, 2, 2) if mfp.ndim == 3 else (5, 2)] = np.inf
        lo, hi = MFP_CLAMP_RANGE
        fixed_mfp = np.clip(np.nan_to_num(mfp, nan=hi, posinf=hi, neginf=lo), lo, hi)
    got = albedo_to_coefficients(rd, mfp, (1.3, 1.4, 1.5), on_invalid="clamp",
                                 outputs=("alpha", "sigma_a", "sigma_s"))
    want = albedo_to_coefficients(fixed_rd.astype(np.float32), fixed_mfp.astype(np.float32),
                                  (1.3, 1.4, 1.5), outputs=("alpha", "sigma_a", "sigma_s"))
    for g, w in zip(got, want):
        assert np.all(np.isfinite(g))
        np.testing.assert_array_equal(g, w)
    plan = plan_inversion((1.3, 1.4, 1.5), outputs=("sigma_a",), mfp_kind="diffuse",
                          on_invalid="clamp")
    done = plan.apply(rd, mfp)
    assert done.invalid_albedo == 4
    # an HxW map's bad value counts once, though every channel reads it (values given)
    assert done.invalid_mfp == {"per channel": 0, "per texel": 2, "hxw": 2}[mfp_form]


@pytest.mark.parametrize("outputs, alias", [(("sigma_a", "sigma_s"), 0),
                                            (("sigma_a", "sigma_s"), 1), (("rho", "sigma_a"), 0)])
def test_an_output_on_the_extinction_mfp_itself_gives_the_same_values(runtime, outputs, alias):
    """out= on the mfp's own elements: an extinction mfp is read again after the kernel (the
    division sigma = base / mfp), so it is copied first; the values are those of separate
    arrays (they were 1.0, or base over an overwritten mfp)."""
    rd = np.array([0.2, 0.5, 0.8, 0.95], np.float32)
    mfp = np.array([0.5, 1.0, 2.0, 4.0], np.float32)
    want = albedo_to_coefficients(rd, mfp, 1.4, outputs=outputs, mfp_kind="extinction",
                                  device=runtime)
    out = [np.empty_like(rd) for _ in outputs]
    out[alias] = mfp
    got = albedo_to_coefficients(rd, mfp, 1.4, outputs=outputs, mfp_kind="extinction",
                                 out=tuple(out), device=runtime)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)


def test_a_plan_with_its_mfp_compiled_in_refuses_another(runtime):
    """specialise=True with mfp_const: the kernel reads no mfp, so another one passed to apply
    is a ValueError, not the compiled one used in silence; the compiled value itself is fine."""
    rd = np.array([0.2, 0.5, 0.8], np.float32)
    plan = plan_inversion(1.4, outputs=("sigma_a",), mfp_kind="diffuse", specialise=True,
                          mfp_const=1.0, device=runtime)
    want = plan.apply(rd).arrays["sigma_a"]
    np.testing.assert_array_equal(plan.apply(rd, np.float32(1.0)).arrays["sigma_a"], want)
    for other in (3.0, np.full(3, 3.0, np.float32)):
        with pytest.raises(ValueError, match=r"compiled mfp_const=\[1\.0\]"):
            plan.apply(rd, other)


def test_a_one_channel_mfp_map_counts_each_value_once_and_matrix_outputs_fill(runtime):
    """albedo_to_coefficients with an HxW mfp map beside HxWx3 albedos: 2 bad values are 2,
    as plan.apply counts them (not 6, one per channel after a broadcast); an np.matrix out is
    filled (a subclass's flat view is taken as an ndarray's)."""
    rd = np.full((4, 5, 3), 0.5, np.float32)
    mfp = np.ones((4, 5), np.float32)
    mfp[1, 1] = mfp[2, 3] = np.nan
    with pytest.raises(InvalidInputError, match=r"^2 invalid mfp value"):
        albedo_to_coefficients(rd, mfp, 1.4, device=runtime)
    rd2 = np.linspace(0.1, 0.9, 12, dtype=np.float32).reshape(3, 4)
    sa = np.asmatrix(np.zeros((3, 4), np.float32))
    ss = np.asmatrix(np.zeros((3, 4), np.float32))
    want = albedo_to_coefficients(rd2, 1.0, 1.4, device=runtime)
    albedo_to_coefficients(rd2, 1.0, 1.4, out=(sa, ss), device=runtime)
    np.testing.assert_array_equal(np.asarray(sa), want[0])
    np.testing.assert_array_equal(np.asarray(ss), want[1])


def test_a_mask_that_does_not_fit_or_holds_nan_is_named(runtime):
    """A mask of another shape is a ValueError naming both shapes (it was NumPy's broadcast
    message); a NaN in a mask is neither 'left out' nor 'kept': named, not taken as 0."""
    plan = plan_inversion(ETAS, device=runtime)
    rd = albedo_map(4, 5)
    with pytest.raises(ValueError, match=r"mask of shape \(3, 5\) does not fit albedo of shape "
                                         r"\(4, 5, 3\)"):
        plan.apply(rd, mask=np.ones((3, 5)))
    mask = np.ones((4, 5))
    mask[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"mask: NaN at index \(2, 1\)"):
        plan.apply(rd, mask=mask)
