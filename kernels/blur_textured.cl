// blur_textured.cl -- texture-varying blur parameters (bdipole_cl/ops/blur/textured.py): per-texel weights
// of the shared basis, w_j(x) = sum_{a,b = 0,1} lu[a] lv[b] table[iu + a][iv + b][j], the
// bilinear interpolation (2 nodes per axis) of the fine weight table (textured_plan.fine_table: the
// node weights' cubic interpolation, REFINE points per lattice step) at the texel's fine-table
// coordinates (cu, cv) (logit Rd and ln ld, ``fine_coords`` below). An axis on which the texture is
// constant has one node.
//
// The FFT path's gather adds a near field: the cells within BD_NEAR (Chebyshev) of the texel, in
// classes of equal weight (textured_plan.near_classes), each class's weight interpolated from
// the table like the basis weights (after them) and applied to the irradiance there.
//
// Specialized by -DBD_NBASIS=G (blurred basis kernels), -DBD_NEAR (near field radius, -1: none),
// -DBD_NU_TAPS, -DBD_NV_TAPS (2, or 1 for a constant axis), so the loops unroll.

#ifndef BD_NBASIS
#error "build with -DBD_NBASIS=<basis size>"
#endif
#ifndef BD_NU_TAPS
#define BD_NU_TAPS 2
#endif
#ifndef BD_NV_TAPS
#define BD_NV_TAPS 2
#endif
#ifndef BD_NEAR
#define BD_NEAR (-1)
#endif
// weights per table node: the basis kernels', then the near classes' ((n + 1)(n + 2) / 2)
#define BD_NWEIGHTS (BD_NBASIS + (BD_NEAR + 1) * (BD_NEAR + 2) / 2)

// offset (floats) of the second node along v: 0 on a constant axis, whose second "node" is
// the first with weight 0 (so every read stays in the table)
#define DV ((BD_NV_TAPS == 2) ? BD_NWEIGHTS : 0)

// a texel's bilinear taps: the offset of its first node (iu, iv) in the table, the offset du
// of the second node along u (0 on a constant axis, as DV), and the tap weights of nodes
// (iu, iv), (iu, iv + 1), (iu + 1, iv), (iu + 1, iv + 1)
typedef struct {
    int node, du;
    float t00, t01, t10, t11;
} taps_t;

// node index and fraction of one axis at fine-table coordinate coord (0, 0 on a constant axis)
inline int axis_base(const float coord, const int nodes, const int ntaps, float *frac)
{
    if (ntaps == 1) {
        *frac = 0.0f;
        return 0;
    }
    const int base = clamp((int)floor(coord), 0, nodes - 2);
    *frac = coord - (float)base;
    return base;
}

// the taps at fine-table coordinates c = (cu, cv) (``fine_coords``)
inline taps_t texel_taps(const float2 c, const int nu, const int nv)
{
    float fu, fv;
    const int iu = axis_base(c.x, nu, BD_NU_TAPS, &fu);
    const int iv = axis_base(c.y, nv, BD_NV_TAPS, &fv);
    taps_t r;
    r.node = (iu * nv + iv) * BD_NWEIGHTS;
    r.du = (BD_NU_TAPS == 2) ? nv * BD_NWEIGHTS : 0;
    r.t00 = (1.0f - fu) * (1.0f - fv);
    r.t01 = (1.0f - fu) * fv;
    r.t10 = fu * (1.0f - fv);
    r.t11 = fu * fv;
    return r;
}

// a texel's fine-table coordinates (cu, cv) from its Rd and ld (textured_plan.texel_coords,
// the host's float32 version, which the tests compare): cu = logit(Rd clamped to [rd_lo, rd_hi])
// * su - ou, cv = ln(ld) * sv - ov; on a constant axis its scale and offset are 0 (the clamp
// keeps logit finite and ld > 0 is checked, so the coordinate is then 0)
inline float2 fine_coords(const float rd, const float ld, const float rd_lo, const float rd_hi,
                          const float su, const float ou, const float sv, const float ov)
{
    const float p = clamp(rd, rd_lo, rd_hi);
    return (float2)(log(p / (1.0f - p)) * su - ou, log(ld) * sv - ov);
}

// the coordinate arguments every kernel below takes after its own
#define BD_COORD_ARGS const float rd_lo, const float rd_hi, const float su, const float ou, \
    const float sv, const float ov
#define BD_TEXEL_TAPS(p) \
    texel_taps(fine_coords(rd[p], ld[p], rd_lo, rd_hi, su, ou, sv, ov), nu, nv)

// weight w_j of basis kernel j (without the Rd factor) from the texel's taps (scalar code, no
// per-texel arrays: PoCL keeps it in registers)
inline float texel_weight(__global const float *table, const taps_t tp, const int j)
{
    __global const float *n = table + tp.node + j;
    return tp.t00 * n[0] + tp.t01 * n[DV] + tp.t10 * n[tp.du] + tp.t11 * n[tp.du + DV];
}

// the weight planes: w[j * npix + p] = rd[p] * w_j(p), every weight of the table (the
// separable-Gaussian path's, which has no near field; the tests read the others)
__kernel void lattice_weights(__global const float *rd, __global const float *ld,
                              __global const float *table, __global float *w, const int npix,
                              const int nu, const int nv, BD_COORD_ARGS)
{
    const int p = get_global_id(0);
    if (p >= npix) return;
    const taps_t tp = BD_TEXEL_TAPS(p);
    const float scale = rd[p];
    for (int j = 0; j < BD_NWEIGHTS; ++j)
        w[(size_t)j * npix + p] = scale * texel_weight(table, tp, j);
}

// a gathered exitance m with the round-off of a zero result removed (fft.settled, the host's
// rule, which the tests compare): |m| below floor = rd * scale is 0, and so is every m < 0 where
// the irradiance is non-negative (nonneg)
inline float settle(const float m, const float rd, const float scale, const int nonneg)
{
    const float floor = rd * scale;
    return (nonneg ? m < floor : fabs(m) < floor) ? 0.0f : m;
}

// the irradiance summed over the cells of near class (a, b) (cells (+-a, +-b), (+-b, +-a), each
// once) around the texel at e, rows `pitch` floats apart
inline float class_sum(__global const float *e, const int pitch, const int a, const int b)
{
    float s = e[a * pitch + b];
    if (a) s += e[-a * pitch + b];
    if (b) {
        s += e[a * pitch - b];
        if (a) s += e[-a * pitch - b];
    }
    if (a != b) {
        s += e[b * pitch + a];
        if (b) s += e[-b * pitch + a];
        if (a) {
            s += e[b * pitch - a];
            if (b) s += e[-b * pitch - a];
        }
    }
    return s;
}

// the exitance of channel c at texel (x, y) of a w x h image (the FFT path), gathered from
// the basis blurs and the near field, and settled: out[(y * w + x) * nch + c] = rd * (sum_j w_j *
// planes[j][y][x0 + x] + sum_classes w_class * class_sum), the planes `plane` floats apart with
// rows `pitch` floats apart; e: the channel's irradiance, padded by x0 texels on every side by the
// border rule, rows `epitch` floats apart
__kernel void gather_exitance(__global const float *rd, __global const float *ld,
                              __global const float *table, __global const float *planes,
                              __global const float *e, __global float *out, const int w,
                              const int h, const int pitch, const int plane, const int epitch,
                              const int x0, const int nch, const int c,
                              const float scale, const int nonneg,
                              const int nu, const int nv, BD_COORD_ARGS)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const size_t p = (size_t)y * w + x;
    const taps_t tp = BD_TEXEL_TAPS(p);
    __global const float *blurred = planes + (size_t)y * pitch + x0 + x;
    float sum = 0.0f;
    for (int j = 0; j < BD_NBASIS; ++j)
        sum += texel_weight(table, tp, j) * blurred[(size_t)j * plane];
#if BD_NEAR >= 0
    __global const float *here = e + (size_t)(y + x0) * epitch + x0 + x;
    int j = BD_NBASIS;
    for (int a = 0; a <= BD_NEAR; ++a)
        for (int b = 0; b <= a; ++b, ++j)
            sum += texel_weight(table, tp, j) * class_sum(here, epitch, a, b);
#endif
    out[p * nch + c] = settle(rd[p] * sum, rd[p], scale, nonneg);
}
