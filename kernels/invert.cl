// invert.cl -- albedo Rd -> (alpha', rho = 1 - alpha'), and optionally (sigma_a, sigma_s').
//
// Needs bdipole.h in front. One kernel; the method is chosen by build options:
//   -DBD_METHOD_MEMO       Hery TM 12-11's float bisection in alpha' verbatim (baseline);
//                          -DBD_ITERATIONS=n (memo: 50)
//   -DBD_METHOD_BISECTION  bisection in the split variables; -DBD_ITERATIONS=n
//   -DBD_METHOD_SECANT     safeguarded secant in the split variables, seeded (value and slope)
//                          from a coarse table; -DBD_ITERATIONS=max evaluations,
//                          -DBD_TOL=relative, -DBD_TABLE_N=seed intervals per segment
//   -DBD_METHOD_TABLE      cubic Hermite table of the inverse, -DBD_TABLE_N intervals per
//                          segment, -DBD_POLISH=Newton steps on the split residual afterwards
// (bdipole_cl/methods/registry.py: MethodConfig.defines writes these)
//
// Split variables (docs/model.md): below Rd_split = Rd(alpha' = 1/2) the unknown is alpha' with
// residual F(a) = Rd^(1/n); above it the unknown is q = sqrt(rho) with residual G(q) = -log Rd.
// Both are increasing and nearly linear, so rho never comes from 1 - alpha' near alpha' = 1.
//
// The table has three segments, each BD_TABLE_N intervals, each analytic in its variable and none
// needing a log of the input:
//   segment 0: x = Rd^(1/n) in [0, x_split]          -> alpha'
//   segment 1: x = Rd^(1/n) in [x_split, 2^(-1/n)]   -> q     (Rd in [Rd_split, 1/2))
//   segment 2: x = 1 - Rd  in [0, 1/2] (exact)       -> q     (Rd in [1/2, 1))
// Each interval holds the cubic's coefficients in u in [0, 1): v = c.x + u (c.y + u (c.z + u c.w)).

// The split (generated from reference.ALPHA_SPLIT, bdipole_cl/device/layout.py)
#define LOWER_HI BD_ALPHA_SPLIT               // alpha' at the split
#define UPPER_HI BD_Q_SPLIT                   // q = sqrt(1 - alpha') at the split

// Residual of the chosen half (0: F(alpha'), 1: G(q)) and its derivative.
inline real half_residual(int upper, real v, bd_params p, real *df)
{
    return upper ? bd_upper_residual(v, p, df) : bd_lower_residual(v, p, df);
}

#if defined(BD_METHOD_TABLE) || defined(BD_METHOD_SECANT)
// Each segment holds BD_TABLE_N + 1 entries: interval i's cubic in entry i, and in entry
// BD_TABLE_N the end node (its .x). Interval i's value is clamped between its two nodes, the
// .x of entries i and i + 1, which its neighbours share exactly: with a monotone cubic on
// every interval (Fritsch-Carlson, checked when the table is built) the lookup is monotone in
// t across interval boundaries too (docs/model.md "Monotone inverse").
#define BD_SEGMENT_STRIDE (BD_TABLE_N + 1)

// Table lookup: the segment's value v and dv/dx (x the segment's variable).
inline real table_value(__global const float4 *table, int seg, real t, real scale, real *dvdx)
{
    int i = clamp((int)t, 0, BD_TABLE_N - 1);
    real u = t - (real)i;
    float4 c = table[seg * BD_SEGMENT_STRIDE + i];
    real end = (real)table[seg * BD_SEGMENT_STRIDE + i + 1].x;
    *dvdx = scale * ((real)c.y + u * (BD_LIT(2.0) * (real)c.z + u * BD_LIT(3.0) * (real)c.w));
    // c0 + (c1 u + u^2 (c2 + c3 u)): the fma's exact argument moves with u by at least |c1| ulp(u),
    // more than the small term's rounding can take back when |c1| >= 10|c2| + 11|c3| (checked
    // per interval when the table is built), so the value is monotone in u; Horner's
    // u (c1 + u (...)) is not (an increasing factor times one that may round down).
    real small = u * u * ((real)c.z + u * (real)c.w);
    real v = (real)c.x + fma(u, (real)c.y, small);
    return clamp(v, fmin((real)c.x, end), fmax((real)c.x, end));
}

// The table's estimate of the unknown of Rd's half, and (through *slope) dResidual/dUnknown.
inline real table_guess(real rd, real x, bd_params p, __global const float4 *table, real *slope)
{
    real dvdx, v, dgdx;
    if (rd < p.rd_split) {                      // segment 0: residual F = x itself
        v = table_value(table, 0, x * p.scale0, p.scale0, &dvdx);
        dgdx = BD_LIT(1.0);
    } else if (rd < BD_LIT(0.5)) {              // segment 1: G = -log Rd = -n log x
        v = table_value(table, 1, (x - p.x_split) * p.scale1, p.scale1, &dvdx);
        dgdx = BD_DIV(-(real)BD_POWER, x);
    } else {                                    // segment 2: G = -log(1 - x)
        real y = BD_LIT(1.0) - rd;
        v = table_value(table, 2, y * p.scale2, p.scale2, &dvdx);
        dgdx = BD_DIV(BD_LIT(1.0), rd);
    }
    *slope = BD_DIV(dgdx, dvdx);
    return v;
}
#endif

#if defined(BD_METHOD_BISECTION)
// Bisection over the unknown's bit patterns (positive floats are ordered as their bits): the
// smallest v in (0, hi] with residual(v) >= target, to one ulp, denormals included, in at most
// 31 (float) or 63 (double) steps. Monotone in the target by construction: two targets share
// the path until the first midpoint between them, after which each stays on its own side.
#ifdef BD_DOUBLE
typedef ulong bd_bits;
#define BD_AS_REAL(b) as_double(b)
#define BD_AS_BITS(v) as_ulong(v)
#else
typedef uint bd_bits;
#define BD_AS_REAL(b) as_float(b)
#define BD_AS_BITS(v) as_uint(v)
#endif
inline real solve_half(int upper, real target, real rd, real x, bd_params p,
                       __global const float4 *table)
{
    bd_bits lo = 0, hi = BD_AS_BITS(upper ? UPPER_HI : LOWER_HI);
    real df;
    for (int i = 0; i < BD_ITERATIONS && hi - lo > 1; ++i) {
        bd_bits mid = lo + (hi - lo) / 2;
        if (half_residual(upper, BD_AS_REAL(mid), p, &df) < target) lo = mid; else hi = mid;
    }
    return BD_AS_REAL(hi);
}
#elif defined(BD_METHOD_SECANT)
// Secant steps on the last two iterates, the first step using the seed table's slope. Every
// evaluation shrinks the bracket [lo, hi] (known residuals at both ends: F(0) = 0 and the
// split values from the host), and a step that would leave it is replaced by the midpoint, so
// the method never leaves [0, 1] and never stalls. Stops when |residual| <= BD_TOL * target: a
// relative error of ~BD_TOL in the unknown, since both residuals are ~ linear through 0.
inline real solve_half(int upper, real target, real rd, real x, bd_params p,
                       __global const float4 *table)
{
    real lo = BD_LIT(0.0), hi = upper ? UPPER_HI : LOWER_HI, df;
    real slope;
    real v = clamp(table_guess(rd, x, p, table, &slope), lo, hi);
    real v_prev = v, f_prev = BD_LIT(0.0);
    for (int i = 0; i < BD_ITERATIONS; ++i) {
        real f = half_residual(upper, v, p, &df) - target;
        if (fabs(f) <= (real)BD_TOL * target) break;
        if (f < BD_LIT(0.0)) lo = v; else hi = v;
        if (i > 0 && f != f_prev) slope = BD_DIV(f - f_prev, v - v_prev);
        v_prev = v;
        f_prev = f;
        v = v - BD_DIV(f, slope);
        if (!(v > lo && v < hi)) v = BD_LIT(0.5) * (lo + hi);
    }
    return v;
}
#endif

// The two halves' results, each kept on its side of the split (alpha' <= 1/2 below, rho <= 1/2
// above), so that no rounding of q^2 or of the unknown crosses it: the switch at Rd_split is
// monotone.
inline void lower_result(real a, real *alpha, real *rho)
{
    *alpha = fmin(a, LOWER_HI);
    *rho = BD_LIT(1.0) - *alpha;
}

inline void upper_result(real q, real *alpha, real *rho)
{
    *rho = fmin(q * q, BD_RHO_SPLIT);
    *alpha = BD_LIT(1.0) - *rho;
}

#if defined(BD_METHOD_MEMO)
inline void invert_one(real rd, bd_params p, __global const float4 *table, real *alpha, real *rho)
{
    real x0 = BD_LIT(0.0), x1 = BD_LIT(1.0), xmid = BD_LIT(0.5);
    for (int i = 0; i < BD_ITERATIONS; ++i) {
        xmid = BD_LIT(0.5) * (x0 + x1);
        if (bd_rd_memo(xmid, p) < rd) x0 = xmid; else x1 = xmid;
    }
    *alpha = xmid;
    *rho = BD_LIT(1.0) - xmid;
}
#elif defined(BD_METHOD_TABLE)
#if BD_POLISH > 0
// BD_POLISH Newton steps on one half's residual, kept inside that half's domain [0, hi]. Each half
// has its own call with a constant bound: a per-lane `upper ? UPPER_HI : LOWER_HI` bound inside
// the loop was vectorised wrongly by Intel's CPU runtime (upper lanes clamped to 1/2 whenever a
// vector also held lower lanes), which PoCL did not show.
inline real polish_half(int upper, real v, real target, real hi, bd_params p)
{
    real df;
    for (int k = 0; k < BD_POLISH; ++k) {
        real f = half_residual(upper, v, p, &df) - target;
        v = clamp(v - BD_DIV(f, df), BD_LIT(0.0), hi);
    }
    return v;
}
#endif

inline void invert_one(real rd, bd_params p, __global const float4 *table, real *alpha, real *rho)
{
    real x = BD_POWER == 2 ? BD_SQRT_RN(rd) : rd;
    real slope;
    real v = table_guess(rd, x, p, table, &slope);
    if (rd < p.rd_split) {
#if BD_POLISH > 0
        v = polish_half(0, v, x, LOWER_HI, p);
#endif
        lower_result(v, alpha, rho);
    } else {
#if BD_POLISH > 0
        real g = rd >= BD_LIT(0.5) ? -log1p(-(BD_LIT(1.0) - rd)) : -log(rd);
        v = polish_half(1, v, g, UPPER_HI, p);
#endif
        upper_result(v, alpha, rho);
    }
}
#else
inline void invert_one(real rd, bd_params p, __global const float4 *table, real *alpha, real *rho)
{
    real x = BD_POWER == 2 ? BD_SQRT_RN(rd) : rd;
    if (rd < p.rd_split) {
        lower_result(solve_half(0, x, rd, x, p, table), alpha, rho);
    } else {
        // -log Rd; for Rd >= 1/2, 1 - Rd is exact (Sterbenz) and log1p keeps its precision
        real g = rd >= BD_LIT(0.5) ? -log1p(-(BD_LIT(1.0) - rd)) : -log(rd);
        upper_result(solve_half(1, g, rd, x, p, table), alpha, rho);
    }
}
#endif

// Specialisation for one job (bdipole_cl/ops/inversion_kernel.py: InversionKernel(specialise=True)):
//   -DBD_CONST_PARAMS=v,v,...  the channels' constant records compiled in (the params buffer
//                              is not read)
//   -DBD_MFP_CONST=v,...       a constant mfp per channel compiled in (no mfp buffer read)
//   -DBD_OUTPUTS=bits          the outputs written, known at build time (1 alpha', 2 rho,
//                              4 sigma_a, 8 sigma_s'): the others are not computed
#ifdef BD_CONST_PARAMS
__constant real bd_const_params[] = {BD_CONST_PARAMS};
#define BD_PARAM_SOURCE bd_const_params
#else
#define BD_PARAM_SOURCE params
#endif
#ifdef BD_MFP_CONST
__constant real bd_mfp_const[] = {BD_MFP_CONST};
#define BD_MFP(i, c) bd_mfp_const[c]
#define BD_HAS_MFP 1
#else
#define BD_MFP(i, c) mfp[i]
#define BD_HAS_MFP (mfp != 0)
#endif
#ifdef BD_OUTPUTS
#define BD_WANTS(bit, ptr) ((BD_OUTPUTS) & (bit))
#else
#define BD_WANTS(bit, ptr) (ptr != 0)
#endif

// Element i is texel i / nchan, channel i % nchan. Outputs may be NULL (not wanted).
// Rd <= 0 (and NaN, which the host reports or clamps first) -> (0, 1); Rd >= 1 -> (1, 0).
// With mfp (ld = 1/mu_tr, docs/model.md): sigma_t' = 1/(ld mu_tr/sigma_t'), sigma_a = sigma_t' rho,
// sigma_s' = sigma_t' alpha'.
__kernel void invert_albedo(__global const real *rd, __global const real *mfp,
                            __global real *alpha_out, __global real *rho_out,
                            __global real *sigma_a_out, __global real *sigma_s_out,
                            __constant const real *params, __global const float4 *tables,
                            const int nchan, const int table_stride, const uint n)
{
    uint i = get_global_id(0);
    if (i >= n) return;
    int c = nchan == 1 ? 0 : (int)(i % (uint)nchan);
    bd_params p = bd_load_params(BD_PARAM_SOURCE, c);
    real r = rd[i], alpha, rho;
    if (!(r > BD_LIT(0.0))) { alpha = BD_LIT(0.0); rho = BD_LIT(1.0); }
    else if (r >= BD_LIT(1.0)) { alpha = BD_LIT(1.0); rho = BD_LIT(0.0); }
    else invert_one(r, p, tables + c * table_stride, &alpha, &rho);
    if (BD_WANTS(1, alpha_out)) alpha_out[i] = alpha;
    if (BD_WANTS(2, rho_out)) rho_out[i] = rho;
    if (BD_HAS_MFP && (BD_WANTS(4, sigma_a_out) || BD_WANTS(8, sigma_s_out))) {
        real sigma_t = BD_DIV(BD_LIT(1.0), BD_MFP(i, c) * bd_mu_over_sigma_t(rho));
        if (BD_WANTS(4, sigma_a_out)) sigma_a_out[i] = sigma_t * rho;
        if (BD_WANTS(8, sigma_s_out)) sigma_s_out[i] = sigma_t * alpha;
    }
}
