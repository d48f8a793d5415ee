// blur_stretched.cl -- the stretched blur's gather (bdipole_cl/ops/blur/stretched.py): per texel the
// weights of the shared eigen-kernel basis, trilinear in the fine table over (logit Rd, ln l_u,
// ln l_v) (stretched_plan.fine_table3: the node weights' cubic interpolation, REFINE points per
// lattice step), times the basis blurs there, times Rd, settled as fft.settled does.
//
// One texel per work-item (Intel's CPU runtime vectorizes across work-items). An axis on which
// the maps are constant has one node: its second tap reads the first with weight 0.
//
// Specialized by -DBD_NBASIS=G (the basis kernels, the table's weights per node) so the loops
// unroll.

#ifndef BD_NBASIS
#error "build with -DBD_NBASIS=<basis size>"
#endif

// node index and fraction along one axis at fine coordinate c (0, 0 on a one-node axis)
inline int stretched_base(const float c, const int nodes, float *frac)
{
    if (nodes == 1) {
        *frac = 0.0f;
        return 0;
    }
    const float base = clamp(floor(c), 0.0f, (float)(nodes - 2));
    *frac = c - base;
    return (int)base;
}

// out[y * w + x] = settled(rd * sum_j w_j(x, y) planes[j][y][x0 + x]) for the w x h window; the
// planes `plane` floats apart with rows `pitch` floats apart; table (n0, n1, n2, BD_NBASIS)
__kernel void gather_stretched(__global const float *rd, __global const float *lu,
                               __global const float *lv, __global const float *table,
                               __global const float *planes, __global float *out,
                               const int w, const int h, const int pitch, const int plane,
                               const int x0, const int n0, const int n1, const int n2,
                               const float rd_lo, const float rd_hi,
                               const float s0, const float o0, const float s1, const float o1,
                               const float s2, const float o2,
                               const float scale, const int nonneg)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const size_t p = (size_t)y * w + x;
    const float r = rd[p];
    const float q = clamp(r, rd_lo, rd_hi);
    float f0, f1, f2;
    const int i0 = stretched_base(log(q / (1.0f - q)) * s0 - o0, n0, &f0);
    const int i1 = stretched_base(log(lu[p]) * s1 - o1, n1, &f1);
    const int i2 = stretched_base(log(lv[p]) * s2 - o2, n2, &f2);
    const int d0 = (n0 > 1) ? n1 * n2 * BD_NBASIS : 0;
    const int d1 = (n1 > 1) ? n2 * BD_NBASIS : 0;
    const int d2 = (n2 > 1) ? BD_NBASIS : 0;
    __global const float *t = table + ((size_t)(i0 * n1 + i1) * n2 + i2) * BD_NBASIS;
    const float w000 = (1.0f - f0) * (1.0f - f1) * (1.0f - f2), w001 = (1.0f - f0) * (1.0f - f1) * f2;
    const float w010 = (1.0f - f0) * f1 * (1.0f - f2), w011 = (1.0f - f0) * f1 * f2;
    const float w100 = f0 * (1.0f - f1) * (1.0f - f2), w101 = f0 * (1.0f - f1) * f2;
    const float w110 = f0 * f1 * (1.0f - f2), w111 = f0 * f1 * f2;
    __global const float *b = planes + (size_t)y * pitch + x0 + x;
    float sum = 0.0f;
    for (int j = 0; j < BD_NBASIS; ++j) {
        const float wj = w000 * t[j] + w001 * t[d2 + j] + w010 * t[d1 + j] + w011 * t[d1 + d2 + j]
            + w100 * t[d0 + j] + w101 * t[d0 + d2 + j] + w110 * t[d0 + d1 + j]
            + w111 * t[d0 + d1 + d2 + j];
        sum += wj * b[(size_t)j * plane];
    }
    const float m = r * sum;
    const float floor_ = r * scale;
    out[p] = (nonneg ? m <= floor_ : fabs(m) <= floor_) ? 0.0f : m;
}
