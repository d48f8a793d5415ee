// blur_textured.cl -- texture-varying blur parameters (bdipole_cl/ops/blur/textured.py): per-texel weights
// of the shared basis, w_j(x) = sum_{a,b = 0,1} lu[a] lv[b] table[iu + a][iv + b][j], the
// bilinear interpolation (2 nodes per axis) of the fine weight table (textured_plan.fine_table: the
// node weights' cubic interpolation, REFINE points per lattice step) at the texel's fine-table
// coordinates (cu, cv) (logit Rd and ln ld, ``fine_coords`` below). An axis on which the texture is
// constant has one node.
//
// The table holds each node's weights as one record of BD_RECORD floats (the weights, then zeros:
// dispatch.node_records), read in aligned vectors of BD_CHUNK floats: a texel's four taps are four
// records, combined a chunk at a time, not one gathered load per tap and weight (its weights then
// cost 4 record loads, not 4 per weight: 1.2x faster on Intel's runtime, 1.5x on PoCL).
//
// The FFT path's gather adds a near field: the cells within BD_NEAR (Chebyshev) of the texel. Its
// kernels are BD_NEAR_RANK fixed kernels of the near cells (near_field.near_field_basis: values per
// class of symmetric cells, near_field.near_classes), each convolved here with the irradiance
// (the class sums, shared by all of them) and weighted per texel from the table like the FFT
// basis kernels (after them).
//
// Every work-item takes BD_WIDTH (1, 4, 8 or 16) neighbouring texels of one row in explicit
// vectors: CPU runtimes compile them to SIMD directly (PoCL leaves a scalar kernel scalar, and
// its scalar log and loads cost ~10x Intel's vectorized ones here); the table's records are
// read per lane. Rows hold at least BD_WIDTH texels (the host builds a narrower kernel for
// a narrower image), and the last work-item of a row takes the row's last BD_WIDTH texels
// (``first_texel``), overlapping the one before: every load is a whole vector, and the texels
// computed twice are written twice with the same value.
//
// Specialized by -DBD_NBASIS=G (blurred basis kernels), -DBD_NEAR (near field radius, -1: none),
// -DBD_NEAR_RANK (near kernels), -DBD_NU_TAPS, -DBD_NV_TAPS (2, or 1 for a constant axis),
// -DBD_WIDTH, -DBD_CHUNK (the table's record loads), so the loops unroll.

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

#ifndef BD_CHUNK
#error "build with -DBD_CHUNK=<4, 8 or 16: floats per load of a node record>"
#endif
#define BD_RECORD (BD_CHUNK * ((BD_NWEIGHTS + BD_CHUNK - 1) / BD_CHUNK))
#define BD_CHUNK_CAT_(a, b) a##b
#define BD_CHUNK_CAT(a, b) BD_CHUNK_CAT_(a, b)
#ifdef GLOADN
// kernels/lanes.h's one vector read (PoCL reads a vloadN element by element); in a one-texel
// kernel, vloadN (Intel's runtime vectorizes that across work-items 1.6x faster)
#define CHUNK_LOAD(i, p) GLOADN(BD_CHUNK, i, p)
#else
#define CHUNK_LOAD BD_CHUNK_CAT(vload, BD_CHUNK)
#endif
#define CHUNK_STORE BD_CHUNK_CAT(vstore, BD_CHUNK)

// offset (floats) of the second node along v: 0 on a constant axis, whose second "node" is
// the first with weight 0 (so every read stays in the table)
#define DV ((BD_NV_TAPS == 2) ? BD_RECORD : 0)

// (the lane types, vec, ivec, GLOAD, GSTORE, TO_INT, FOR_LANES: kernels/lanes.h; first_texel,
// texel_weight, settle: kernels/gather.h)

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
    r.node = (iu * nv + iv) * BD_RECORD;
    r.du = (BD_NU_TAPS == 2) ? nv * BD_RECORD : 0;
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

// the texels' weights (without the Rd factor) from their taps, lane i's at wl[i * BD_RECORD ..]:
// per lane, its four node records combined a chunk at a time
inline void texel_weights(__global const float *table, const taps_t tp, float *wl)
{
#define BD_LANE_WEIGHTS(s, i) \
    for (int q = 0; q < BD_RECORD; q += BD_CHUNK) { \
        __global const float *n = table + tp.node s + q; \
        CHUNK_STORE(tp.t00 s * CHUNK_LOAD(0, n) + tp.t01 s * CHUNK_LOAD(0, n + DV) \
                    + tp.t10 s * CHUNK_LOAD(0, n + tp.du) \
                    + tp.t11 s * CHUNK_LOAD(0, n + tp.du + DV), 0, wl + (i) * BD_RECORD + q); \
    }
    FOR_LANES(BD_LANE_WEIGHTS)
#undef BD_LANE_WEIGHTS
}

// the weight planes: w[j * npix + p] = rd[p] * w_j(p), every weight of the table (the
// separable-Gaussian path's, which has no near field; the tests read the others), for the
// texels p = g * BD_WIDTH + lane < npix
__kernel void lattice_weights(__global const float *rd, __global const float *ld,
                              __global const float *table, __global float *w, const int npix,
                              BD_COORD_ARGS)
{
    const int first = first_texel(get_global_id(0), npix);
    const vec r = GLOAD(0, rd + first);
    const taps_t tp = fine_taps(r, GLOAD(0, ld + first), BD_COORDS);
    float wl[BD_WIDTH * BD_RECORD];
    texel_weights(table, tp, wl);
    for (int j = 0; j < BD_NWEIGHTS; ++j)
        GSTORE(r * texel_weight(wl, BD_RECORD, j), 0, w + (size_t)j * npix + first);
}

// the irradiance summed over the cells of near class (a, b) (cells (+-a, +-b), (+-b, +-a), each
// once) around the texels at e (row ``row``'s column x), rows `pitch` floats apart
inline vec class_sum(__global const float *e, const int pitch, const int a, const int b)
{
#define BD_CELL(dy, dx) GLOAD(0, e + (dy) * pitch + (dx))
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
    const vec r = GLOAD(0, rd + p);
    const taps_t tp = fine_taps(r, GLOAD(0, ld + p), BD_COORDS);
    __global const float *blurred = planes + (size_t)y * pitch + x0 + x;
    float wl[BD_WIDTH * BD_RECORD];
    texel_weights(table, tp, wl);
    vec sum = (vec)0.0f;
    for (int j = 0; j < BD_NBASIS; ++j)
        sum += texel_weight(wl, BD_RECORD, j) * GLOAD(0, blurred + (size_t)j * plane);
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
        sum += texel_weight(wl, BD_RECORD, BD_NBASIS + m) * near[m];
#endif
    const vec v = settle(r * sum, r, scale, nonneg);
    __global float *o = out + p * nch + c;
#define BD_STORE_LANE(s, i) o[(i) * nch] = v s;
    FOR_LANES(BD_STORE_LANE)
#undef BD_STORE_LANE
}
