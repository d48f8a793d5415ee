// physics_eval.cl -- evaluates one bdipole.h function elementwise, for cross-checks against
// bdipole_cl/physics/reference.py. Needs bdipole.h in front; -DBD_FUNC_<NAME> picks the function:
//   BD_FUNC_RD            x = alpha'                         -> Rd
//   BD_FUNC_ONE_MINUS_RD  x = q = sqrt(1 - alpha') <= 0.71   -> 1 - Rd (= -expm1(log Rd))
//   BD_FUNC_PROFILE       x = r, y = alpha', z = sigma_t'    -> R(r)
//   BD_FUNC_PROFILE_CDF   x = r, y = alpha', z = sigma_t'    -> energy within r
//   BD_FUNC_PROFILE_TAIL  x = r, y = alpha', z = sigma_t'    -> energy beyond r
//   BD_FUNC_SQRT          x                                  -> sqrt(x), the device's own
//   BD_FUNC_SQRT_RN       x = Rd                             -> BD_SQRT_RN(x): the correctly
//                         rounded sqrt the inversion's variable is made of (0 for x <= 0)
// For the profile functions, rho = 1 - alpha' is passed separately (w) so that it is exact.

__kernel void physics_eval(__global const real *x, __global const real *y,
                           __global const real *z, __global const real *w,
                           __global real *out, __constant const real *params, const ulong n)
{
    ulong i = get_global_id(0);
    if (i >= n) return;
    bd_params p = bd_load_params(params, 0);
    real d;
#if defined(BD_FUNC_RD)
    out[i] = bd_rd(x[i], p);
#elif defined(BD_FUNC_SQRT)
    out[i] = sqrt(x[i]);
#elif defined(BD_FUNC_SQRT_RN)
    out[i] = x[i] > BD_LIT(0.0) ? BD_SQRT_RN(x[i]) : BD_LIT(0.0);
#elif defined(BD_FUNC_ONE_MINUS_RD)
    out[i] = -expm1(bd_log_rd_q(x[i], p, &d));
#else
    bd_geometry g = bd_make_geometry(y[i], w[i], z[i], p);
#if defined(BD_FUNC_PROFILE)
    out[i] = bd_profile(x[i], g);
#elif defined(BD_FUNC_PROFILE_CDF)
    out[i] = bd_profile_cdf(x[i], g);
#elif defined(BD_FUNC_PROFILE_TAIL)
    out[i] = bd_profile_tail(x[i], g);
#endif
#endif
}
