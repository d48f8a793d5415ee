"""The stretched blur's per-call work (bdipole_cl/ops/blur/stretched.py, stretched_windows.py;
docs/stretch.md "Chart borders", "The near field"): chart windows made once per contents of the
maps and never stale, ranges over a window's own texels, and the near field's classes exact."""
import itertools

import numpy as np
import pytest

import bdipole_cl as bd
from bdipole_cl.ops.blur import stretched_windows as sw
from bdipole_cl.ops.blur.near_field import class_values, near_classes
from bdipole_cl.ops.blur.stretched import Stretch, map_ranges
from bdipole_cl.ops.blur import stretched as st
from bdipole_cl.ops.blur.stretched_plan import (MAX_NODES, kernel_at, lattice_nodes,
                                                lattice_variables, range_steps,
                                                shared_ranges, stretched_plan)
from bdipole_cl.ops.blur.textured_plan import REFINE


@pytest.mark.parametrize("ids", [[3, 7, 7, 9], [-5, 0, 2, -5], [0, 1 << 40, 5, 1 << 40],
                                 [2, 2, 2, 2]], ids=["gaps", "negative", "huge-span", "one"])
def test_chart_labels_are_the_ids_ranks(ids):
    """Labels 1..n in the ids' order, as np.unique's inverse: by lookup over a small span of
    ids, by sorting over a huge one."""
    chart = np.resize(np.array(ids, np.int64), (6, 5))
    _, inverse = np.unique(chart, return_inverse=True)
    np.testing.assert_array_equal(sw.chart_labels(chart), inverse.reshape(chart.shape) + 1)


def two_charts(h=40, w=48, split=20, gutter=3):
    """A Stretch of two charts side by side (columns [0, split) and [split + gutter, w)), the
    gutter between them given to the nearer chart and not covered."""
    chart = np.zeros((h, w), np.int32)
    chart[:, split + gutter // 2:] = 1
    covered = np.ones((h, w), bool)
    covered[:, split:split + gutter] = False
    su = np.full((h, w), 0.5, np.float32)
    sv = np.where(chart == 0, 0.5, 1.0).astype(np.float32)
    return Stretch(su, sv, chart, covered)


def test_windows_are_made_once_and_follow_the_maps_contents(on_device, monkeypatch):
    """A second blur over the same maps reuses the chart windows (one distance transform per
    layout, not per call); maps changed in place since are windowed anew: the result is that of
    a fresh process (no cache), not the old layout's."""
    made = []
    real = sw._chart_windows
    monkeypatch.setattr(sw, "_chart_windows", lambda *a: made.append(1) or real(*a))
    sw.WINDOWS.clear()
    s = two_charts()
    rng = np.random.default_rng(3)
    e = rng.random((40, 48)).astype(np.float32)

    def run():
        return bd.blur(e, albedo=0.5, mfp=2.0, stretch=s, tol=1e-3)
    first = run()
    assert np.array_equal(run(), first) and len(made) == 1
    s.chart[:, 30:] = 2                   # a third chart, in place: same arrays, new contents
    s.covered[:, 29:31] = False
    moved = run()
    assert len(made) == 2
    sw.WINDOWS.clear()
    np.testing.assert_array_equal(moved, run())
    assert not np.array_equal(moved, first)


def test_ranges_over_a_windows_own_texels():
    """``map_ranges`` over the texels where ``own`` holds equals the ranges of those texels
    taken one by one in float64 (Rd's lit texels' minimum where some are dark); the texels
    outside, however extreme, do not widen them."""
    rng = np.random.default_rng(5)
    h, w = 300, 70                        # more rows than a thread's piece: several pieces
    rd = rng.uniform(0.05, 0.9, (h, w)).astype(np.float32)
    rd[rng.random((h, w)) < 0.1] = 0.0
    lu = np.exp(rng.uniform(-1, 2, (h, w))).astype(np.float32)
    lv = np.exp(rng.uniform(-1, 2, (h, w))).astype(np.float32)
    own = rng.random((h, w)) < 0.6
    lu[~own] = 1e30                       # extremes outside the window's own texels
    rd[~own] = 0.999
    got = map_ranges(rd, lu, lv, own)
    r, u, v = (m[own].astype(np.float64) for m in (rd, lu, lv))
    lit = r[r > 0]
    t_rd = lattice_variables([lit.min(), r.max()], 1.0, 1.0)[0]
    want = ((t_rd[0], t_rd[1]), (0.5 * np.log((u * v).min()), 0.5 * np.log((u * v).max())),
            (np.log((u / v).min()), np.log((u / v).max())))
    # float64 throughout on both sides, from the same float32 texels: equal to rounding
    np.testing.assert_allclose(np.array(got), np.array(want), rtol=1e-12, atol=1e-12)
    whole = map_ranges(rd, lu, lv)
    assert whole[1][1] > got[1][1]        # without the mask the outside texels count


def test_charts_of_overlapping_ranges_share_a_plan():
    """Windows whose ranges overlap share the plan of their union (a UV layout's many charts:
    one plan, not one each); windows of distinct single aspects (one node of s each, as a
    cylinder's charts) keep their own; no union passes MAX_NODES."""
    tol = 1e-3
    near = [((0.5, 1.5), (1.0, 1.4), (-0.15, 0.1)), ((0.7, 1.9), (1.1, 1.5), (-0.1, 0.2)),
            ((0.6, 1.2), (0.9, 1.2), (-0.05, 0.05))]
    assert shared_ranges(near, [10, 30, 20], tol) == [((0.5, 1.9), (0.9, 1.5),
                                                       (-0.15, 0.2))] * 3
    aspects = [((0.5, 1.5), (1.0, 1.4), (0.26, 0.2601)), ((0.5, 1.5), (1.0, 1.4), (0.92, 0.92))]
    assert shared_ranges(aspects, [5, 5], tol) == aspects
    # a chain of single aspects 0.95 steps apart: no group grows past one step by links
    chain = [((0.5, 1.5), (1.0, 1.4), (0.19 * i, 0.19 * i)) for i in range(8)]
    groups = set(shared_ranges(chain, [1] * 8, tol))
    assert 4 <= len(groups) and all(hi - lo <= 0.2 for _, _, (lo, hi) in groups), groups
    # within MERGE_STEPS of the wider, but past MAX_NODES together
    wide = [((0.0, 1.2), (0.0, 1.0), (-1.0, 13.21)), ((0.0, 1.2), (0.0, 1.0), (-1.1, 13.16))]
    assert max(lattice_nodes(w, tol) for w in wide) <= MAX_NODES < lattice_nodes(
        ((0.0, 1.2), (0.0, 1.0), (-1.1, 13.21)), tol)
    assert shared_ranges(wide, [5, 5], tol) == wide


def test_a_wide_window_does_not_widen_the_plan_of_narrow_ones():
    """A head's sliver chart (aspects over 4 steps of s, among charts of about one aspect)
    plans alone, not widening the plan of every other chart (whose rank it would raise: 9-12
    eigen-kernels a channel for all 64 charts instead of 6-8); a window that fits into both
    groups joins the narrower."""
    tol = 1e-3
    big = ((0.5, 1.5), (1.0, 1.4), (-0.1, 0.1))
    sliver = ((0.6, 1.4), (0.8, 1.6), (-0.3, 0.45))
    small = ((0.7, 1.2), (1.1, 1.3), (-0.05, 0.05))
    got = shared_ranges([big, sliver, small], [300, 100, 10], tol)
    assert got == [big, sliver, big]
    # nested slivers, each a step wider and smaller than the last: no group grows by them
    # past its first window by more than a step (they chained to 8 steps with 2-step windows)
    nested = [((0.0, 0.0), (0.0, 0.0), (-0.1 * k, 0.1 * k)) for k in range(1, 9)]
    widths = [range_steps(g, tol)[2] for g in shared_ranges(nested, [100 - k for k in range(8)],
                                                            tol)]
    own = [range_steps(w, tol)[2] for w in nested]
    assert all(w <= o + 1 + 1e-9 for w, o in zip(widths, own)), widths
    # exactly a step wider joins, whatever the rounding of the widths (0.6 / 0.2 < 3)
    for a in range(1, 6):
        pair = [((0.0, 0.0), (0.0, 0.0), (0.0, 0.2 * a)),
                ((0.0, 0.0), (0.0, 0.0), (0.0, 0.2 * (a + 1)))]
        assert len(set(shared_ranges(pair, [2, 1], tol))) == 1, a


def many_charts(n=4, side=24, gutter=2):
    """A Stretch of n x n square charts (``side`` texels, ``gutter`` apart, not covered) of
    nearly one stretch (1 mm +- 4%, varying within and between charts) and a small shear."""
    size = n * (side + gutter)
    yy, xx = np.mgrid[0:size, 0:size]
    chart = (yy // (side + gutter)) * n + xx // (side + gutter)
    covered = ((yy % (side + gutter)) < side) & ((xx % (side + gutter)) < side)
    su = (1.0 + 0.04 * np.sin(0.3 * xx + 0.2 * yy)).astype(np.float32)
    sv = (1.0 + 0.04 * np.cos(0.25 * xx - 0.1 * yy)).astype(np.float32)
    return Stretch(su, sv, chart.astype(np.int32), covered, max_shear=0.05)


def test_a_layout_of_many_charts_plans_once(on_device, monkeypatch):
    """A layout of 16 charts of overlapping ranges makes one plan a channel, named once in
    the method, and its shear's error is integrated once: a second blur over the same maps
    makes no kernel (before: a plan a chart, and the shear's 8 kernels each call, 60x the
    blur on a 64-chart head)."""
    s = many_charts()
    e = np.random.default_rng(4).random((*s.su.shape, 2)).astype(np.float32)
    made = []
    real = st.sheared_kernel
    monkeypatch.setattr(st, "sheared_kernel", lambda *a: made.append(1) or real(*a))
    st.SHEAR_ERRORS.clear()

    def run():
        return bd.blur(e, albedo=(0.5, 0.8), mfp=(2.0, 3.0), stretch=s, tol=1e-3,
                       return_info=True)
    first, info = run()
    for c in info.channels:
        assert c.method.startswith("fft (stretched, 16 charts: ") and c.method.count(
            "eigen-kernel") == 1, c.method
    assert 0 < len(made) <= 2 * 8
    made.clear()
    again, _ = run()
    assert not made
    np.testing.assert_array_equal(again, first)


def test_near_field_is_exact_at_the_nodes():
    """The stretched plan's near kernels are its classes: at every lattice node the gather's
    table gives each near class the node kernel's own value (float32 rounding only; a
    projection on fewer near kernels would be off by up to its share of tol), and the far
    weights follow."""
    ranges = ((0.0, 1.0), (np.log(2.0), np.log(4.0)), (-0.3, 0.3))
    plan = stretched_plan(ranges, 1.4, 1e-3)
    assert plan.near >= 0 and plan.near_direct
    classes = near_classes(plan.near, mirrored=False)
    assert plan.near_values.shape == (len(classes), len(classes))
    g = len(plan.kernels)
    for idx in itertools.product(*(range(len(a.values)) for a in plan.axes)):
        t = [a.values[i] for a, i in zip(plan.axes, idx)]
        fine = plan.fine[tuple(REFINE * i for i in idx)]
        exact = class_values(kernel_at(t, 1.4, plan.radius), classes)
        # the cubic reproduces its node values; float32 tables: 2 ulps of the largest value
        np.testing.assert_allclose(fine[g:], exact, rtol=0, atol=2 * 2.0 ** -23 * exact.max())


# {{{ what a stretch is checked for, before any work

def test_stretch_inputs_are_checked_by_name(on_device):
    """A covered map of another shape, a length that is not finite and > 0 in float32 (as
    given: 1e-50 is not 0), chart ids that are not whole numbers and a texel size beside the
    stretch: each a one-line ValueError naming the map, texel or option; a covered map of the
    right bytes but another shape is refused after a blur cached its windows too."""
    h, w = 24, 30
    e = np.random.default_rng(3).random((h, w)).astype(np.float32)
    s = two_charts(h, w, split=13)

    def blur(stretch, **kw):
        return bd.blur(e, albedo=0.6, mfp=1.0, stretch=stretch, **kw)
    blur(s)                                                    # its windows cached
    for covered in (s.covered.ravel(), s.covered[:, :-1].copy()):
        with pytest.raises(ValueError, match=r"stretch covered map has shape \(\d+,? ?\d*\); "
                                             r"expected \(24, 30\)"):
            blur(Stretch(s.su, s.sv, s.chart, covered))
    tiny = s.su.astype(np.float64)
    tiny[3, 4] = 1e-50
    with pytest.raises(ValueError, match=r"stretch su at x=4, y=3: 1e-50 is below float32's"):
        blur((tiny, s.sv))
    chart = np.where(s.chart == 0, 0.5, 0.7)
    with pytest.raises(ValueError, match=r"chart map at x=0, y=0: 0\.5: chart ids are whole"):
        blur(Stretch(s.su, s.sv, chart, s.covered))
    with pytest.raises(ValueError, match=r"texel_size=0\.1 with stretch=.*leave texel_size"):
        blur(s, texel_size=0.1)


def test_stretch_maps_on_the_device_are_the_hosts(on_device):
    """pyopencl arrays as the stretch maps, as the irradiance and parameters may be: read
    back, the same blur."""
    import pyopencl.array as cla
    s = two_charts()
    e = np.random.default_rng(4).random(s.su.shape).astype(np.float32)
    q = on_device.queue
    got = bd.blur(e, albedo=0.6, mfp=1.0, stretch=(cla.to_device(q, s.su),
                                                   cla.to_device(q, s.sv)))
    np.testing.assert_array_equal(got, bd.blur(e, albedo=0.6, mfp=1.0, stretch=(s.su, s.sv)))

# }}}


def test_a_tables_records_are_kept_within_the_caches_budget(monkeypatch):
    """A gather table's records are made once across calls wherever the records alone fit
    the cache: the table they are made from is its plan's, not counted again (counting both
    made a 64-chart head's three 55 MB tables anew every call), nor held (a table whose plan
    is gone would be held and counted nowhere)."""
    from bdipole_cl.ops.blur import stretched_gather as sg
    fine = np.random.default_rng(2).random((9, 9, 9, 30)).astype(np.float32)
    made = []
    real = sg.node_records
    monkeypatch.setattr(sg, "node_records", lambda *a: made.append(1) or real(*a))
    records = real(fine.reshape(81, 9, 30), 16)
    assert records.nbytes + fine.nbytes > 1.5 * records.nbytes
    monkeypatch.setattr(sg.TABLE_RECORDS, "max_bytes", int(1.5 * records.nbytes))
    sg.TABLE_RECORDS.clear()
    first = sg.table_records(fine, 16)
    assert sg.table_records(fine, 16) is first and len(made) == 1
    np.testing.assert_array_equal(first, records)
    held = [entry for entry, _ in sg.TABLE_RECORDS._data.values()]
    del fine                           # the plan gone: its table is not kept by the records
    import gc
    gc.collect()
    assert all(ref() is None for ref, _ in held)


def test_a_union_past_the_planning_limits_plans_each_window_alone(on_device, monkeypatch):
    """Two charts, each within the planning memory alone, whose union (one aspect each, 0.9
    lattice steps apart: four nodes of s, not one) is past it: each chart gets its own plan and
    the blur is made (before: refused naming ranges neither chart has)."""
    from bdipole_cl.ops.blur import stretched_plan as sp
    from bdipole_cl.ops.blur.params import MapRanges
    h, w = 12, 24
    chart = np.zeros((h, w), np.int32)
    chart[:, 12:] = 1
    su = np.where(chart == 0, 1.0, 0.91).astype(np.float32)     # s = ln(1.09 / 0.91) = 0.18:
    sv = np.where(chart == 0, 1.0, 1.09).astype(np.float32)     # 0.9 lattice steps from 0
    albedo = np.tile(np.linspace(0.5, 0.7, h, dtype=np.float32)[:, None], (1, w))
    s = Stretch(su, sv, chart, np.ones((h, w), bool))
    shape = (h, w, 1)
    maps = st.channel_maps(shape, 0, st.as_stretch(s, shape), {"albedo": albedo, "mfp": 2.0},
                           1.4, False, "raise", {}, MapRanges())
    own = [st.window_maps(maps, win)[1] for win in sw.chart_windows(chart, s.covered, shape,
                                                                     "clamp")]
    union, = set(shared_ranges(own, [1, 1], 1e-3))

    def peak(r):
        return sp.plan_peak_bytes(lattice_nodes(r, 1e-3), sp.plan_radius(r, 1.4, 1e-3))
    limit = max(peak(r) for r in own)
    assert peak(union) > limit
    monkeypatch.setattr(sp, "PLAN_PEAK_BYTES", limit)
    sp.STRETCHED_PLANS.clear()
    e = np.random.default_rng(1).random((h, w)).astype(np.float32)
    out, info = bd.blur(e, albedo=albedo, mfp=2.0, stretch=s, return_info=True)
    assert np.all(np.isfinite(out)) and info.channels[0].method.count("eigen-kernel") == 2
    sp.STRETCHED_PLANS.clear()
