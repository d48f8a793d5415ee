// invert_table.cl -- the default inversion (cubic table, no polish) on BD_WIDTH elements per
// work-item: the same lookup as kernels/invert.cl's BD_METHOD_TABLE with BD_POLISH 0, the same
// operations on the same values (so the same results and the same monotone contract,
// docs/model.md "Monotone inverse"), written for the memory floor:
//   - explicit vectors of BD_WIDTH lanes (1, 2, 4, 8 or 16): CPU runtimes compile them to SIMD
//     directly (PoCL leaves a one-element kernel scalar); at width 1 the kernel is plain
//     scalar code that Intel's runtime vectorises across work-items itself, with gather
//     instructions where the CPU has them (AVX-512: faster than any explicit width there;
//     bdipole_cl/ops/inversion_kernel.py TABLE_WIDTHS holds the measured widths);
//   - no branches: the segment, its variable and scale are chosen lane-wise, one interval is
//     gathered per lane (into the lanes directly, four at a time), both halves' results are
//     formed and one selected, and Rd <= 0 / >= 1 (NaN is reported or clamped on the host
//     first) are selects at the end;
//   - the outputs written fixed at build time (BD_OUTPUTS: 1 alpha', 2 rho, 4 sigma_a,
//     8 sigma_s'), the channel count too (BD_NCHAN), so no NULL or channel tests per element.
// Needs bdipole.h in front, and -DBD_TABLE_N, -DBD_WIDTH, -DBD_NCHAN, -DBD_OUTPUTS
// (and -DBD_MFP_CONST, -DBD_CONST_PARAMS, below).
// The table: kernels/invert.cl's rows as 4-float records (bdipole_cl/ops/inversion_kernel.py:
// interval_records): c0, c1, c2 of the interval, then its end node (the next row's c0), so that
// each lane's interval is one aligned 16-byte load and four lanes one 4x4 transpose; c3 is
// derived, ((end - c0) - c1) - c2, which the host's rows already hold as c3 (physics/tables.py:
// derived_c3), so both kernels use the same floats. (32-byte records holding c3 and the end
// node, which need a fifth shuffle per four lanes: ~5-12% slower on the AVX-512 Xeon.)
// Element e is texel e / BD_NCHAN, channel e % BD_NCHAN (interleaved, as the host holds it).
// Float32 only (the float64 default polishes: kernels/invert.cl).

#define BD_SEGMENT_STRIDE (BD_TABLE_N + 1)

// {{{ the gather's lane groups (the lane types, vec, ivec, VLOAD, ..., BD_LANES: kernels/lanes.h)

// The gather's lane groups. Lanes are set in the coefficient vectors directly, not stored to
// private arrays and loaded back as vectors (the narrow stores cannot forward to the wide
// load: PoCL's code for that was ~15% slower): at width 4 and up four lanes at a time, whose
// four intervals are loaded and transposed into lanes of the four coefficient vectors (a 4x4
// transpose, done with shuffles; ~5-10% faster on Intel's runtime than lane by lane).
// BD_EACH_QUAD(F): F(q, l0, l1, l2, l3) per group of four lanes (q: their component names);
// BD_EACH_LANE(F): F(l) per lane, at widths 1 and 2; BD_LANE(v, l): lane l of v.
#if BD_WIDTH == 1
#define BD_LANE(v, l) (v)
#define BD_EACH_LANE(F) F(0)
#elif BD_WIDTH == 2
#define BD_LANE(v, l) (v).s##l
#define BD_EACH_LANE(F) F(0) F(1)
#elif BD_WIDTH == 4
#define BD_EACH_QUAD(F) F(0123, 0, 1, 2, 3)
#elif BD_WIDTH == 8
#define BD_EACH_QUAD(F) F(0123, 0, 1, 2, 3) F(4567, 4, 5, 6, 7)
#elif BD_WIDTH == 16
#define BD_EACH_QUAD(F) F(0123, 0, 1, 2, 3) F(4567, 4, 5, 6, 7) F(89ab, 8, 9, a, b) \
    F(cdef, c, d, e, f)
#endif
// 1 where a lane's test holds, else 0 (vector comparisons give -1, scalar ones 1)
#define ONE_IF(test) select((ivec)0, (ivec)1, test)

// the correctly rounded sqrt of each lane (bdipole.h: BD_SQRT_RN_DEFINE)
#if BD_WIDTH == 1
#define bd_sqrt_rn_vec bd_sqrt_rn
#else
BD_SQRT_RN_DEFINE(bd_sqrt_rn_vec, vec, ivec, AS_INT, AS_FLOAT)
#endif

// }}}

// {{{ per-lane channel parameters

// Each lane's value of its channel ch from per-channel records of `stride` floats (BD_NCHAN - 1
// selects; none for one channel).
inline vec lane_value(__constant const float *values, int stride, ivec ch)
{
    vec v = (vec)values[0];
    for (int c = 1; c < BD_NCHAN; ++c)
        v = select(v, (vec)values[c * stride], ch == c);
    return v;
}
#define lane_param(params, ch, field) lane_value((params) + (field), BD_PARAM_STRIDE, ch)

// -DBD_CONST_PARAMS=v,...: the channels' constant records compiled in (a specialised kernel:
// the params argument is not read, and the compiler folds the constants)
#ifdef BD_CONST_PARAMS
__constant float bd_const_params[] = {BD_CONST_PARAMS};
#define BD_PARAM_SOURCE bd_const_params
#else
#define BD_PARAM_SOURCE params
#endif

// The mfp: -DBD_MFP_CONST=v,... one per channel compiled in (the mfp argument is not read);
// -DBD_MFP_CHANNELS: the mfp argument holds one value per channel (__constant); else one per
// element.
#ifdef BD_MFP_CONST
__constant float bd_mfp_const[] = {BD_MFP_CONST};
#endif
#ifdef BD_MFP_CHANNELS
#define BD_MFP_SPACE __constant
#else
#define BD_MFP_SPACE __global
#endif

// -DBD_CHECK=1: set *invalid when an Rd is NaN, infinite or > 1 (invert_albedo's rule); 2: when
// an Rd is NaN, infinite or >= 1, or an mfp read is NaN, <= 0 or infinite (the coefficients'
// rule). The host finds and reports (or clamps) them only then; 0 (default): no test.
#ifndef BD_CHECK
#define BD_CHECK 0
#endif

// }}}

// The table's unknown for each lane (clamped between its interval's nodes, as table_value),
// and whether the lane is in the upper half (segments 1 and 2: the unknown is q). The segment's
// variable is chosen by ?: (lane-wise on vectors), which Intel's runtime compiles ~25% faster
// than the same choice by select() at width 1, its constants read before it (read in its
// arms, they are masked reads there: ~25% slower again).
inline vec table_lookup(vec rd, ivec ch, __constant const float *params,
                        __global const float4 *tables, const int table_stride, ivec *upper)
{
    const vec rd_split = lane_param(params, ch, BD_P_RD_SPLIT),
              x_split = lane_param(params, ch, BD_P_X_SPLIT),
              scale0 = lane_param(params, ch, BD_P_SCALE0),
              scale1 = lane_param(params, ch, BD_P_SCALE1),
              scale2 = lane_param(params, ch, BD_P_SCALE2);
    vec x = BD_POWER == 2 ? bd_sqrt_rn_vec(rd) : rd;   // monotone on every device (bdipole.h)
    ivec up = rd >= rd_split, top = rd >= 0.5f;
    vec t = top ? (1.0f - rd) * scale2 : up ? (x - x_split) * scale1 : x * scale0;
    ivec i = clamp(TO_INT(t), 0, BD_TABLE_N - 1);
    vec u = t - TO_FLOAT(i);
    ivec row = ch * table_stride + (ONE_IF(up) + ONE_IF(top)) * BD_SEGMENT_STRIDE + i;
    // the gather: each lane's interval (c0..c2) and its end node, into the lanes
    vec a, b, cc, d, end;
#ifdef BD_EACH_QUAD
#define BD_GATHER_QUAD(q, l0, l1, l2, l3) {                                              \
        float4 r0 = tables[row.s##l0], r1 = tables[row.s##l1], r2 = tables[row.s##l2],    \
               r3 = tables[row.s##l3];                                                   \
        a.s##q = (float4)(r0.s0, r1.s0, r2.s0, r3.s0);                                   \
        b.s##q = (float4)(r0.s1, r1.s1, r2.s1, r3.s1);                                   \
        cc.s##q = (float4)(r0.s2, r1.s2, r2.s2, r3.s2);                                  \
        end.s##q = (float4)(r0.s3, r1.s3, r2.s3, r3.s3); }
    BD_EACH_QUAD(BD_GATHER_QUAD)
#else
#define BD_GATHER_LANE(l) {                                                              \
        __global const float *c = (__global const float *)(tables + BD_LANE(row, l));    \
        BD_LANE(a, l) = c[0]; BD_LANE(b, l) = c[1]; BD_LANE(cc, l) = c[2];                \
        BD_LANE(end, l) = c[3]; }
    BD_EACH_LANE(BD_GATHER_LANE)
#endif
    d = ((end - a) - b) - cc;          // c3, as the host's rows hold it (derived_c3)
    // c0 + fma(u, c1, u^2 (c2 + c3 u)): monotone in u (kernels/invert.cl: table_value)
    vec small = u * u * (cc + u * d);
    *upper = up;
    return clamp(a + fma(u, b, small), fmin(a, end), fmax(a, end));
}

// Work-item g's lanes from p[g * BD_WIDTH ...]; when it is not whole, those at n or above
// are `fill` (a value every later step takes without a NaN).
inline vec load_lanes(__global const float *p, size_t g, int whole, uint n, float fill)
{
    if (whole) return VLOAD(g, p);
    float lanes[BD_WIDTH];
    for (uint j = 0; j < BD_WIDTH; ++j)
        lanes[j] = g * BD_WIDTH + j < n ? p[g * BD_WIDTH + j] : fill;
    return VLOAD(0, lanes);
}

// Work-item g's lanes to out[g * BD_WIDTH ...], only those below n when it is not whole.
inline void store_lanes(vec v, size_t g, int whole, uint n, __global float *out)
{
    if (whole) {
        VSTORE(v, g, out);
        return;
    }
    float lanes[BD_WIDTH];
    VSTORE(v, 0, lanes);
    for (uint j = 0; j < BD_WIDTH && g * BD_WIDTH + j < n; ++j) out[g * BD_WIDTH + j] = lanes[j];
}

__kernel void invert_table(__global const float *rd, BD_MFP_SPACE const float *mfp,
                           __global float *alpha_out, __global float *rho_out,
                           __global float *sigma_a_out, __global float *sigma_s_out,
                           __constant const float *params, __global const float4 *tables,
                           const int table_stride, const uint n, __global int *invalid)
{
    // size_t, not uint: with a 32-bit index Intel's runtime cannot tell that neighbouring
    // work-items read neighbouring elements, and gathers and scatters them (width 1: ~30% slower)
    const size_t g = get_global_id(0), first = g * BD_WIDTH;
    if (first >= n) return;
    const int whole = first + BD_WIDTH <= n;   // the last work-item may hold fewer elements
#if BD_NCHAN == 1
    ivec ch = (ivec)0;
#elif BD_WIDTH == 1
    ivec ch = (int)(first % BD_NCHAN);
#else
    ivec ch = ((ivec)(int)(first % BD_NCHAN) + BD_LANES) % BD_NCHAN;
#endif
    vec r = load_lanes(rd, g, whole, n, 0.5f);
#if BD_CHECK == 1
    if (ANY_LANE(!(r <= 1.0f) | (r == -INFINITY))) *invalid = 1;
#elif BD_CHECK == 2
    if (ANY_LANE(!(r < 1.0f) | (r == -INFINITY))) *invalid = 1;
#endif
    ivec upper;
    vec v = table_lookup(r, ch, BD_PARAM_SOURCE, tables, table_stride, &upper);
    // the two halves kept on their sides of the split (kernels/invert.cl: lower_result,
    // upper_result), then Rd <= 0 -> (0, 1) and Rd >= 1 -> (1, 0)
    vec a_lower = fmin(v, BD_ALPHA_SPLIT), rho_upper = fmin(v * v, BD_RHO_SPLIT);
    vec alpha = select(a_lower, 1.0f - rho_upper, upper);
    vec rho = select(1.0f - a_lower, rho_upper, upper);
    ivec pos = r > 0.0f, one = r >= 1.0f;
    alpha = select((vec)0.0f, select(alpha, (vec)1.0f, one), pos);
    rho = select((vec)1.0f, select(rho, (vec)0.0f, one), pos);
    if (BD_OUTPUTS & 1) store_lanes(alpha, g, whole, n, alpha_out);
    if (BD_OUTPUTS & 2) store_lanes(rho, g, whole, n, rho_out);
#if BD_OUTPUTS & 12
    // with mfp (ld = 1/mu_tr, docs/model.md): sigma_t' = 1/(ld mu_tr/sigma_t'),
    // sigma_a = sigma_t' rho, sigma_s' = sigma_t' alpha' (bdipole.h: bd_mu_over_sigma_t)
#if defined(BD_MFP_CONST)
    vec ld = lane_value(bd_mfp_const, 1, ch);
#elif defined(BD_MFP_CHANNELS)
    vec ld = lane_value(mfp, 1, ch);
#else
    vec ld = load_lanes(mfp, g, whole, n, 1.0f);
#if BD_CHECK == 2
    if (ANY_LANE(!(ld >= BD_MFP_MIN) | (ld == INFINITY))) *invalid = 1;
#endif
#endif
#ifdef BD_MODEL_DIPOLE
    vec mu_over_sigma_t = sqrt(3.0f * rho);
#else
    vec mu_over_sigma_t = sqrt(BD_DIV(3.0f * rho, 1.0f + rho));
#endif
    vec sigma_t = BD_DIV((vec)1.0f, ld * mu_over_sigma_t);
    if (BD_OUTPUTS & 4) store_lanes(sigma_t * rho, g, whole, n, sigma_a_out);
    if (BD_OUTPUTS & 8) store_lanes(sigma_t * alpha, g, whole, n, sigma_s_out);
#endif
}
