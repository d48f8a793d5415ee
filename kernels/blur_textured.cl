// blur_textured.cl -- texture-varying blur parameters (bdipole_cl/ops/blur/textured.py): per-texel weights
// of the shared basis, w_j(x) = sum_{a,b = 0,1} lu[a] lv[b] table[iu + a][iv + b][j], the
// bilinear interpolation (2 nodes per axis) of the fine weight table (textured_plan.fine_table: the
// node weights' cubic interpolation, REFINE points per lattice step) at the texel's fine-table
// coordinates (cu, cv) (logit Rd and ln ld, ``fine_coords`` below). An axis on which the texture is
// constant has one node.
//
// The FFT path's gather adds a near field: the cells within BD_NEAR (Chebyshev) of the texel. Its
// kernels are BD_NEAR_RANK fixed kernels of the near cells (near_field.near_field_basis: values per
// class of symmetric cells, near_field.near_classes), each convolved here with the irradiance
// (the class sums, shared by all of them) and weighted per texel from the table like the FFT
// basis kernels (after them).
//
// Every work-item takes BD_WIDTH (1, 4, 8 or 16) neighbouring texels of one row in explicit
// vectors: CPU runtimes compile them to SIMD directly (PoCL leaves a scalar kernel scalar, and
// its scalar log and loads cost ~10x Intel's vectorized ones here); the table's entries are
// gathered per lane. Rows hold at least BD_WIDTH texels (the host builds a narrower kernel for
// a narrower image), and the last work-item of a row takes the row's last BD_WIDTH texels
// (``first_texel``), overlapping the one before: every load is a whole vector, and the texels
// computed twice are written twice with the same value.
//
// Specialized by -DBD_NBASIS=G (blurred basis kernels), -DBD_NEAR (near field radius, -1: none),
// -DBD_NEAR_RANK (near kernels), -DBD_NU_TAPS, -DBD_NV_TAPS (2, or 1 for a constant axis),
// -DBD_WIDTH, so the loops unroll.

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
#ifndef BD_NEAR_RANK
#define BD_NEAR_RANK 0
#endif
#ifndef BD_WIDTH
#error "build with -DBD_WIDTH=<texels per work-item> (kernels/lanes.h, before this file, needs it)"
#endif
// near classes (near_field.near_classes) and weights per table node: the basis kernels', then
// the near kernels'
#define BD_NCLASSES ((BD_NEAR + 1) * (BD_NEAR + 2) / 2)
#define BD_NWEIGHTS (BD_NBASIS + BD_NEAR_RANK)

// offset (floats) of the second node along v: 0 on a constant axis, whose second "node" is
// the first with weight 0 (so every read stays in the table)
#define DV ((BD_NV_TAPS == 2) ? BD_NWEIGHTS : 0)

// {{{ lane helpers (the lane types, vec, ivec, VLOAD, VSTORE, TO_INT, FOR_LANES: kernels/lanes.h)

// lanes of p[idx + j], per lane (a gather)
inline vec gather(__global const float *p, const ivec idx, const int j)
{
    vec v;
#define BD_GATHER_LANE(s, i) v s = p[idx s + j];
    FOR_LANES(BD_GATHER_LANE)
#undef BD_GATHER_LANE
    return v;
}

// the first of work-item g's BD_WIDTH texels in a row of n >= BD_WIDTH: the last work-item
// takes the row's last BD_WIDTH
inline int first_texel(const int g, const int n)
{
    return min(g * BD_WIDTH, n - BD_WIDTH);
}

// }}}

// a texel's bilinear taps: the offsets of its first node (iu, iv) in the table, the offset du
// of the second node along u (0 on a constant axis, as DV), and the tap weights of nodes
// (iu, iv), (iu, iv + 1), (iu + 1, iv), (iu + 1, iv + 1)
typedef struct {
    ivec node;
    int du;
    vec t00, t01, t10, t11;
} taps_t;

// node index and fraction of one axis at fine-table coordinate coord (0, 0 on a constant axis)
inline ivec axis_base(const vec coord, const int nodes, const int ntaps, vec *frac)
{
    if (ntaps == 1) {
        *frac = (vec)0.0f;
        return (ivec)0;
    }
    const vec base = clamp(floor(coord), 0.0f, (float)(nodes - 2));
    *frac = coord - base;
    return TO_INT(base);
}

// the taps at fine-table coordinates (cu, cv) (``fine_coords``)
inline taps_t texel_taps(const vec cu, const vec cv, const int nu, const int nv)
{
    vec fu, fv;
    const ivec iu = axis_base(cu, nu, BD_NU_TAPS, &fu);
    const ivec iv = axis_base(cv, nv, BD_NV_TAPS, &fv);
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
inline taps_t fine_taps(const vec rd, const vec ld, const int nu, const int nv,
                        const float rd_lo, const float rd_hi, const float su, const float ou,
                        const float sv, const float ov)
{
    const vec p = clamp(rd, rd_lo, rd_hi);
    return texel_taps(log(p / (1.0f - p)) * su - ou, log(ld) * sv - ov, nu, nv);
}

// the coordinate arguments every kernel below takes after its own
#define BD_COORD_ARGS const int nu, const int nv, const float rd_lo, const float rd_hi, \
    const float su, const float ou, const float sv, const float ov
#define BD_COORDS nu, nv, rd_lo, rd_hi, su, ou, sv, ov

// weight w_j of basis kernel j (without the Rd factor) from the texels' taps
inline vec texel_weight(__global const float *table, const taps_t tp, const int j)
{
    return tp.t00 * gather(table, tp.node, j) + tp.t01 * gather(table, tp.node, j + DV)
        + tp.t10 * gather(table, tp.node, j + tp.du)
        + tp.t11 * gather(table, tp.node, j + tp.du + DV);
}

// the weight planes: w[j * npix + p] = rd[p] * w_j(p), every weight of the table (the
// separable-Gaussian path's, which has no near field; the tests read the others), for the
// texels p = g * BD_WIDTH + lane < npix
__kernel void lattice_weights(__global const float *rd, __global const float *ld,
                              __global const float *table, __global float *w, const int npix,
                              BD_COORD_ARGS)
{
    const int first = first_texel(get_global_id(0), npix);
    const vec r = VLOAD(0, rd + first);
    const taps_t tp = fine_taps(r, VLOAD(0, ld + first), BD_COORDS);
    for (int j = 0; j < BD_NWEIGHTS; ++j)
        VSTORE(r * texel_weight(table, tp, j), 0, w + (size_t)j * npix + first);
}

// a gathered exitance m with the round-off of a zero result removed (fft.settled, the host's
// rule, which the tests compare): |m| below floor = rd * scale is 0, and so is every m < 0 where
// the irradiance is non-negative (nonneg)
inline vec settle(const vec m, const vec rd, const float scale, const int nonneg)
{
    const vec floor = rd * scale;
#if BD_WIDTH == 1
    return (nonneg ? m < floor : fabs(m) < floor) ? 0.0f : m;
#else
    return select(m, (vec)0.0f, nonneg ? m < floor : fabs(m) < floor);
#endif
}

// the irradiance summed over the cells of near class (a, b) (cells (+-a, +-b), (+-b, +-a), each
// once) around the texels at e (row ``row``'s column x), rows `pitch` floats apart
inline vec class_sum(__global const float *e, const int pitch, const int a, const int b)
{
#define BD_CELL(dy, dx) VLOAD(0, e + (dy) * pitch + (dx))
    vec s = BD_CELL(a, b);
    if (a) s += BD_CELL(-a, b);
    if (b) {
        s += BD_CELL(a, -b);
        if (a) s += BD_CELL(-a, -b);
    }
    if (a != b) {
        s += BD_CELL(b, a);
        if (b) s += BD_CELL(-b, a);
        if (a) {
            s += BD_CELL(b, -a);
            if (b) s += BD_CELL(-b, -a);
        }
    }
#undef BD_CELL
    return s;
}

// the exitance of channel c at the texels (x, y) .. (x + BD_WIDTH - 1, y) of a w x h image (the
// FFT path), gathered from the basis blurs and the near field, and settled: out[(y * w + x) *
// nch + c] = rd * (sum_j w_j * planes[j][y][x0 + x] + sum_m w_m * (near_m * E)), the planes
// `plane` floats apart with rows `pitch` floats apart; e: the channel's irradiance, padded by x0
// texels on every side by the border rule, rows `epitch` floats apart; near_basis: the near
// kernels' values per class (BD_NEAR_RANK x BD_NCLASSES, near_field.near_field_basis)
__kernel void gather_exitance(__global const float *rd, __global const float *ld,
                              __global const float *table, __global const float *planes,
                              __global const float *e, __constant const float *near_basis,
                              __global float *out, const int w, const int h, const int pitch,
                              const int plane, const int epitch, const int x0, const int nch,
                              const int c, const float scale, const int nonneg, BD_COORD_ARGS)
{
    const int x = first_texel(get_global_id(0), w), y = get_global_id(1);
    const size_t p = (size_t)y * w + x;
    const vec r = VLOAD(0, rd + p);
    const taps_t tp = fine_taps(r, VLOAD(0, ld + p), BD_COORDS);
    __global const float *blurred = planes + (size_t)y * pitch + x0 + x;
    vec sum = (vec)0.0f;
    for (int j = 0; j < BD_NBASIS; ++j)
        sum += texel_weight(table, tp, j) * VLOAD(0, blurred + (size_t)j * plane);
#if BD_NEAR >= 0 && BD_NEAR_RANK > 0
    // the near kernels convolved with the irradiance: class sums, shared, times each kernel's
    // value on the class
    __global const float *here = e + (size_t)(y + x0) * epitch + x0 + x;
    vec near[BD_NEAR_RANK];
    for (int m = 0; m < BD_NEAR_RANK; ++m)
        near[m] = (vec)0.0f;
    int k = 0;
    for (int a = 0; a <= BD_NEAR; ++a)
        for (int b = 0; b <= a; ++b, ++k) {
            const vec s = class_sum(here, epitch, a, b);
            for (int m = 0; m < BD_NEAR_RANK; ++m)
                near[m] += near_basis[m * BD_NCLASSES + k] * s;
        }
    for (int m = 0; m < BD_NEAR_RANK; ++m)
        sum += texel_weight(table, tp, BD_NBASIS + m) * near[m];
#endif
    const vec v = settle(r * sum, r, scale, nonneg);
    __global float *o = out + p * nch + c;
#define BD_STORE_LANE(s, i) o[(i) * nch] = v s;
    FOR_LANES(BD_STORE_LANE)
#undef BD_STORE_LANE
}
