// array_ops.cl -- element-wise helpers for inversions of device-resident arrays
// (bdipole_cl/ops/inversion_device.py): whether an input breaks its rule (the kernels that do
// not test their inputs themselves: float64, methods other than the float32 table), and the
// extinction coefficients' division and sigma_t's sum, so that nothing goes to the host.
// Needs bdipole.h in front (real), and -DBD_MFP_MIN (the least valid mfp, a literal of the
// kernel's precision).

// the rules (bdipole_cl/ops/inversion_plan.py): 1 invert_albedo's albedo (NaN, infinite or
// > 1), 2 the coefficients' albedo (NaN, infinite or >= 1), 3 the mfp (NaN, below BD_MFP_MIN
// or infinite)
inline int breaks_rule(const real v, const int rule)
{
    if (rule == 1) return !(v <= BD_LIT(1.0)) || v == -INFINITY;
    if (rule == 2) return !(v < BD_LIT(1.0)) || v == -INFINITY;
    return !(v >= BD_MFP_MIN) || v == INFINITY;
}

// *flag = 1 where some x[i] breaks ``rule`` (a plain store: every writer writes 1)
__kernel void flag_invalid(__global const real *x, const ulong n, const int rule,
                           __global int *flag)
{
    const size_t i = get_global_id(0);
    if (i < n && breaks_rule(x[i], rule)) *flag = 1;
}

// out = a / b (sigma = alpha' or rho over an extinction mfp)
__kernel void divide(__global real *out, __global const real *a, __global const real *b,
                     const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n) out[i] = a[i] / b[i];
}

// out = a + b (sigma_t' = sigma_a + sigma_s')
__kernel void add(__global real *out, __global const real *a, __global const real *b,
                  const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n) out[i] = a[i] + b[i];
}
