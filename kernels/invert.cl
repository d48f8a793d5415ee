// invert.cl -- albedo Rd -> (alpha', rho = 1 - alpha'), and optionally (sigma_a, sigma_s').
//
// Needs bdipole.h in front. One kernel; the method is chosen by build options:
//   -DMETHOD_MEMO       Hery TM 12-11's float bisection in alpha' verbatim (baseline);
//                       -DITERATIONS=n (memo: 50)
//   -DMETHOD_BISECTION  bisection in the split variables (alpha' below Rd(1/2), q above);
//                       -DITERATIONS=n
//   -DMETHOD_SECANT     Illinois regula falsi on the same bracket; -DITERATIONS=max, -DTOL=rel
//   -DMETHOD_TABLE      cubic Hermite table in (sqrt(Rd) -> alpha') and (-log Rd -> q), built on
//                       the host in float64; -DTABLE_N=intervals per half, -DPOLISH=Newton steps
// The split variables make each residual increasing and nearly linear on its half
// (bdipole.h: bd_lower_residual, bd_upper_residual), so every method is well conditioned at
// both stiff ends and rho never comes from 1 - alpha' near alpha' = 1.

#define BD_LOWER_HI BD_LIT(0.5)                  // alpha' at the split
#define BD_UPPER_HI BD_LIT(0.70710678118654752)  // q = sqrt(1/2) at the split

// F(v) of the chosen half (lower: alpha' -> Rd^(1/n); upper: q -> -log Rd) and its derivative.
inline real half_residual(int upper, real v, bd_params p, real *df)
{
    return upper ? bd_upper_residual(v, p, df) : bd_lower_residual(v, p, df);
}

#if defined(METHOD_BISECTION)
inline real solve_half(int upper, real target, bd_params p, __global const float4 *table)
{
    real lo = BD_LIT(0.0), hi = upper ? BD_UPPER_HI : BD_LOWER_HI, df;
    for (int i = 0; i < ITERATIONS; ++i) {
        real mid = BD_LIT(0.5) * (lo + hi);
        if (half_residual(upper, mid, p, &df) < target) lo = mid; else hi = mid;
    }
    return BD_LIT(0.5) * (lo + hi);
}
#elif defined(METHOD_SECANT)
// Illinois regula falsi: the bracket [lo, hi] always holds the root, the end kept twice in a
// row has its residual halved (superlinear, never stalls), a secant point that is not strictly
// inside the bracket is replaced by the midpoint. Stops when |F(v) - target| <= TOL * target,
// which is a relative error of ~TOL in v because F(v) ~ v on both halves.
inline real solve_half(int upper, real target, bd_params p, __global const float4 *table)
{
    real df;
    real lo = BD_LIT(0.0), f_lo = -target;
    real hi = upper ? BD_UPPER_HI : BD_LOWER_HI;
    real f_hi = half_residual(upper, hi, p, &df) - target;
    real v = hi;
    int side = 0;
    for (int i = 0; i < ITERATIONS; ++i) {
        v = (lo * f_hi - hi * f_lo) / (f_hi - f_lo);
        if (!(v > lo && v < hi)) v = BD_LIT(0.5) * (lo + hi);
        real f = half_residual(upper, v, p, &df) - target;
        if (fabs(f) <= (real)TOL * target) break;
        if (f < BD_LIT(0.0)) {
            lo = v; f_lo = f;
            if (side == -1) f_hi *= BD_LIT(0.5);
            side = -1;
        } else {
            hi = v; f_hi = f;
            if (side == 1) f_lo *= BD_LIT(0.5);
            side = 1;
        }
    }
    return v;
}
#elif defined(METHOD_TABLE)
// Table layout per channel: TABLE_N lower intervals, then TABLE_N upper intervals, each the
// cubic's coefficients in the local coordinate u in [0, 1): v = c.x + u (c.y + u (c.z + u c.w)).
inline real solve_half(int upper, real target, bd_params p, __global const float4 *table)
{
    real t = target * (upper ? p.hi_scale : p.lo_scale);
    int i = min((int)t, TABLE_N - 1);
    real u = t - (real)i;
    float4 c = table[upper * TABLE_N + i];
    real v = (real)c.x + u * ((real)c.y + u * ((real)c.z + u * (real)c.w));
    real hi = upper ? BD_UPPER_HI : BD_LOWER_HI, df;
    for (int k = 0; k < POLISH; ++k) {
        real f = half_residual(upper, v, p, &df) - target;
        v = clamp(v - f / df, BD_LIT(0.0), hi);
    }
    return v;
}
#endif

// (alpha', rho) of one albedo. Rd <= 0 (and NaN, which the host reports or clamps first)
// -> (0, 1); Rd >= 1 -> (1, 0).
inline void invert_one(real rd, bd_params p, __global const float4 *table, real *alpha, real *rho)
{
    if (!(rd > BD_LIT(0.0))) { *alpha = BD_LIT(0.0); *rho = BD_LIT(1.0); return; }
    if (rd >= BD_LIT(1.0)) { *alpha = BD_LIT(1.0); *rho = BD_LIT(0.0); return; }
#if defined(METHOD_MEMO)
    real x0 = BD_LIT(0.0), x1 = BD_LIT(1.0), xmid = BD_LIT(0.5);
    for (int i = 0; i < ITERATIONS; ++i) {
        xmid = BD_LIT(0.5) * (x0 + x1);
        if (bd_rd_memo(xmid, p) < rd) x0 = xmid; else x1 = xmid;
    }
    *alpha = xmid;
    *rho = BD_LIT(1.0) - xmid;
#else
    if (rd < p.rd_split) {
        real a = solve_half(0, BD_POWER == 2 ? sqrt(rd) : rd, p, table);
        *alpha = a;
        *rho = BD_LIT(1.0) - a;
    } else {
        // -log Rd; for Rd >= 1/2, 1 - Rd is exact (Sterbenz) and log1p keeps its precision
        real neg_log_rd = rd >= BD_LIT(0.5) ? -log1p(-(BD_LIT(1.0) - rd)) : -log(rd);
        real q = solve_half(1, neg_log_rd, p, table);
        *rho = q * q;
        *alpha = BD_LIT(1.0) - *rho;
    }
#endif
}

// Element i is texel i / nchan, channel i % nchan. Outputs may be NULL (not wanted).
// With mfp (ld = 1/mu_tr, SPEC.md): sigma_t' = 1/(ld mu_tr/sigma_t'), sigma_a = sigma_t' rho,
// sigma_s' = sigma_t' alpha'.
__kernel void invert_albedo(__global const real *rd, __global const real *mfp,
                            __global real *alpha_out, __global real *rho_out,
                            __global real *sigma_a_out, __global real *sigma_s_out,
                            __constant const real *params, __global const float4 *tables,
                            const int nchan, const int table_stride, const ulong n)
{
    ulong i = get_global_id(0);
    if (i >= n) return;
    int c = (int)(i % (ulong)nchan);
    bd_params p = bd_load_params(params, c);
    real alpha, rho;
    invert_one(rd[i], p, tables + c * table_stride, &alpha, &rho);
    if (alpha_out) alpha_out[i] = alpha;
    if (rho_out) rho_out[i] = rho;
    if (mfp) {
        real sigma_t = BD_LIT(1.0) / (mfp[i] * bd_mu_over_sigma_t(rho));
        if (sigma_a_out) sigma_a_out[i] = sigma_t * rho;
        if (sigma_s_out) sigma_s_out[i] = sigma_t * alpha;
    }
}
