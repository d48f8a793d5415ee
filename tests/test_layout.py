"""The host/kernel parameter layout (bdipole_cl/device/layout.py) read back through a kernel,
and the package's caches (bdipole_cl/caches.py)."""
import numpy as np
import pyopencl as cl
import pytest

import bdipole_cl
from bdipole_cl.caches import all_caches
from bdipole_cl.device import programs
from bdipole_cl.device.layout import (P, PARAM_FIELDS, PARAM_STRIDE, channel_params, header,
                                      struct_members)

#: bdipole.h's bd_params members, by layout field, written out here so that a generated name
#: that drifts from what the kernels use fails the read-back below
STRUCT_MEMBERS = {"CPHI": "cphi", "CE": "ce", "A_COEF": "a_coef", "RD_SPLIT": "rd_split",
                  "X_SPLIT": "x_split", "G_SPLIT": "g_split", "SCALE0": "scale0",
                  "SCALE1": "scale1", "SCALE2": "scale2", "SLOPE0": "slope0"}

READ_BACK = "\n".join(
    ["__kernel void read_params(__constant const real *params, __global real *out, int c)",
     "{", "    bd_params p = bd_load_params(params, c);"]
    + [f"    out[{i}] = p.{STRUCT_MEMBERS[f]};" for i, f in enumerate(PARAM_FIELDS)] + ["}"])


def test_every_field_is_a_struct_member_and_the_header_matches():
    assert set(STRUCT_MEMBERS) == set(PARAM_FIELDS)
    text = header()
    for i, name in enumerate(PARAM_FIELDS):
        assert f"#define BD_P_{name} {i}\n" in text
    assert f"#define BD_PARAM_STRIDE {PARAM_STRIDE}\n" in text
    assert struct_members() == tuple(STRUCT_MEMBERS[f] for f in PARAM_FIELDS)
    assert f"#define BD_PARAM_MEMBERS real {', '.join(struct_members())};\n" in text


def test_bdipole_h_writes_no_member_list_by_hand():
    """The struct and its load come from the generated macros, not a hand-kept copy."""
    source = (programs.kernel_dir() / programs.HEADER).read_text()
    assert "BD_PARAM_MEMBERS" in source and "BD_PARAM_LOAD(p)" in source
    assert "real cphi" not in source


@pytest.mark.parametrize("double", [False, True], ids=["f32", "f64"])
def test_kernel_reads_each_field_where_the_host_wrote_it(runtime, double):
    if double and not runtime.has_fp64:
        pytest.skip("no cl_khr_fp64")
    dtype = np.float64 if double else np.float32
    # two channels of different eta and a table: channel 1 starts one stride in, and every
    # field differs between the channels
    record = channel_params((1.3, 2.0), table_n=64, dtype=dtype)
    assert record.size == 2 * PARAM_STRIDE
    opts = programs.build_options(double=double)
    prg = programs.build_quietly(runtime.context,
                                 programs.kernel_source("layout_check", READ_BACK), opts)
    mf = cl.mem_flags
    params = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=record)
    out_buf = cl.Buffer(runtime.context, mf.WRITE_ONLY, len(PARAM_FIELDS) * record.itemsize)
    read = cl.Kernel(prg, "read_params")
    for c in (0, 1):
        read(runtime.queue, (1,), None, params, out_buf, np.int32(c))
        out = np.empty(len(PARAM_FIELDS), dtype)
        cl.enqueue_copy(runtime.queue, out, out_buf)
        runtime.queue.finish()
        for i, name in enumerate(PARAM_FIELDS):
            assert out[i] == record[c * PARAM_STRIDE + P[name]], (name, c, out[i])


def test_clear_caches_empties_every_cache(runtime):
    rd = np.float32([0.2, 0.7])
    bdipole_cl.invert_albedo(rd, 1.4, device=runtime)                    # a table, a program
    e = np.ones((12, 12, 1), np.float32)
    bdipole_cl.blur(e, albedo=0.5, mfp=1.0, method="gaussians", device=runtime)   # kernel, fit
    filled = [c.name for c in all_caches() if c.nbytes > 0]
    assert {"inversion tables", "channel kernels", "gaussian fits"} <= set(filled), filled
    assert programs.program_count() > 0
    bdipole_cl.clear_caches()
    assert all(c.nbytes == 0 and len(c) == 0 for c in all_caches())
    assert programs.program_count() == 0
    # and everything still works, rebuilt
    np.testing.assert_array_equal(bdipole_cl.invert_albedo(rd, 1.4, device=runtime),
                                  bdipole_cl.invert_albedo(rd, 1.4, device=runtime))


def test_byte_cache_keeps_to_its_budget():
    from bdipole_cl.caches import ByteCache
    cache = ByteCache("test", 3 * 800)
    for i in range(5):
        cache.put(i, np.zeros(100))                # 800 bytes each
    assert len(cache) == 3 and cache.nbytes == 2400
    assert cache.get(0) is None and cache.get(4) is not None
    cache.put("huge", np.zeros(1000))             # larger than the budget: not kept
    assert cache.get("huge") is None and len(cache) == 3


def test_the_program_cache_is_bounded_in_bytes(runtime, monkeypatch):
    """Built programs count their binaries' bytes; past the budget the least recent goes."""
    bdipole_cl.clear_caches()
    first = programs.get_program(runtime, "copy", ())
    size = programs.program_bytes(first)
    assert 0 < size < programs.PROGRAM_CACHE_BYTES
    monkeypatch.setattr(programs.PROGRAM_CACHE, "max_bytes", size + size // 2)
    programs.get_program(runtime, "copy", programs.build_options(double=False,
                                                                 defines={"BD_UNUSED": 1}))
    assert programs.program_count() == 1, programs.program_count()
    assert programs.PROGRAM_CACHE.nbytes <= programs.PROGRAM_CACHE.max_bytes
