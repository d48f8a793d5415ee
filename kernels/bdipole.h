// bdipole.h -- Better Dipole physics shared by every bdipole_cl kernel.
//
// The one OpenCL source of truth for the model; the float64 NumPy twin of every function here is
// in bdipole_cl/physics/reference.py (same names without the bd_ prefix), and tests/ compare the two.
// Sources: d'Eon, "A better dipole" (2012); Hery, Pixar Tech Memo 12-11 (eqs. 1-4);
// Jensen et al. 2001 for the classical dipole (BD_MODEL_DIPOLE).
//
// The host joins this text in front of each kernel (no #include: PoCL compiles from a temporary
// file, so relative include paths break). Build options specialize it:
//   -DBD_DOUBLE         compute and store in double (needs cl_khr_fp64), else float
//   -DBD_MODEL_DIPOLE   Jensen's dipole, Rd = a/2 (1 + e^{-4/3 A s}) e^{-s}, s = sqrt(3 rho)
// Per-channel boundary constants (Cphi, Ce, A and the inversion's split point) come from a small
// __constant array built on the host from eta (bdipole_cl/device/layout.py: channel_params), so one
// compiled program serves every eta and every channel.

// {{{ precision

#ifdef BD_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#define BD_LIT(x) x
#else
typedef float real;
#define BD_LIT(x) x##f
#endif

#define BD_SQRT3 BD_LIT(1.7320508075688772)
#define BD_INV_4PI BD_LIT(0.07957747154594767)

// }}}

// {{{ a GPU's division and sqrt, on any device (-DBD_INEXACT_MATH; tests)
//
// OpenCL lets a device's float division be off by 2.5 ulp and its sqrt by 3 ulp (unless built
// with -cl-fp32-correctly-rounded-divide-sqrt; NVIDIA's are not correctly rounded by default),
// where the CPU runtimes round both correctly. -DBD_INEXACT_MATH makes any device err that way:
// every float sqrt here and in the kernels, and every float division written BD_DIV(a, b) (the
// inversion kernels'), is moved by -2 to +2 ulps, chosen by a hash of its operands' bits, so
// that neighbouring inputs get unrelated errors (the worst a device may do: its results are
// not monotone in their input). With -cl-denorms-are-zero these are what
// bdipole_cl.device.numerics calls "gpu" (docs/numerics.md "What a GPU does"). Needs a
// clang-based compiler (overloaded functions): the CPU runtimes.

#ifdef BD_INEXACT_MATH
#ifndef __clang__
#error "-DBD_INEXACT_MATH needs a clang-based OpenCL compiler (Intel's CPU runtime, PoCL)"
#endif
// v moved by -2 .. 2 ulps (its bits, as integers) as the hash of key picks; zeros, infinities,
// NaN and values below 2^-100 (where a step could cross zero or into the subnormals) unmoved.
#define BD_INEXACT_TYPE(F, I, U, AS_I, AS_F, AS_U, MUL, SHIFT, TINY)                         \
    inline __attribute__((overloadable)) F bd_inexact(F v, U key)                           \
    {                                                                                        \
        I off = AS_I(((key * MUL) >> SHIFT) % (U)5) - (I)2;                                  \
        return isfinite(v) && fabs(v) >= (F)TINY ? AS_F(AS_I(v) + off) : v;                  \
    }                                                                                        \
    inline __attribute__((overloadable)) F bd_inexact_sqrt(F x)                              \
    {                                                                                        \
        return bd_inexact(sqrt(x), AS_U(x));                                                 \
    }                                                                                        \
    inline __attribute__((overloadable)) F bd_inexact_div(F a, F b)                          \
    {                                                                                        \
        return bd_inexact(a / b, AS_U(a) ^ (AS_U(b) * (U)3));                                \
    }
// for float, and for the lanes' vector type where the kernel has one (BD_WIDTH: only that
// width, as PoCL's built-ins take some vector widths otherwise than its kernels pass them)
#define BD_INEXACT_FLOAT(N)                                                                  \
    BD_INEXACT_TYPE(float##N, int##N, uint##N, as_int##N, as_float##N, as_uint##N,            \
                    0x9E3779B1u, 29, 0x1p-100f)
#define BD_INEXACT_FLOAT_OF(N) BD_INEXACT_FLOAT(N)
BD_INEXACT_FLOAT()
#if defined(BD_WIDTH) && BD_WIDTH > 1
BD_INEXACT_FLOAT_OF(BD_WIDTH)
#endif
#ifdef BD_DOUBLE
// double division and sqrt: correctly rounded on every OpenCL device (OpenCL C's table of
// double ulp bounds: 0 for both), so unmoved
inline __attribute__((overloadable)) double bd_inexact_sqrt(double x) { return sqrt(x); }
inline __attribute__((overloadable)) double bd_inexact_div(double a, double b) { return a / b; }
#endif
#undef sqrt                 // PoCL's headers rename the built-in by a macro of that name
#define sqrt(x) bd_inexact_sqrt(x)
#define BD_DIV(a, b) bd_inexact_div(a, b)
#else
#define BD_DIV(a, b) ((a) / (b))
#endif

// }}}

// {{{ sqrt monotone on every device: BD_SQRT_RN (docs/model.md "Monotone inverse")
//
// The float inversion's variable x = sqrt(Rd) must be non-decreasing in Rd, which a sqrt off
// by up to OpenCL's 3 ulp need not be (a GPU's reversed the default table near FLT_MIN). So it
// is made the correctly rounded sqrt, which is monotone, whatever the device's:
//   1. tiny r is scaled by 2^100 (its sqrt by 2^50 at the end, exactly), so that every
//      quantity below (down to ulp^2 >= 2^-106) is a normal float: a device that flushes
//      subnormals (FTZ/DAZ) gets the same answers;
//   2. one Newton step from the device's s, s + (r - s^2) h with h ~ 1/(2s): the residual by
//      fma (relative error 2^-24), h by the bit trick below (relative error <= 5.1%). The
//      device's |s - sqrt r| <= 3 ulp is <= 6 ulps of the binade below sqrt r, so the step's
//      exact value is within 6 x 0.051 = 0.31 of those ulps of sqrt r (the Newton and
//      residual terms add < 2^-20), closer than any two rounding boundaries: its rounding is
//      RN(sqrt r) or a neighbour (so from any sqrt within 9 ulp: 19 of the binade below);
//   3. one exact step to RN(sqrt r): with ulp = 2^E the spacing at s = m 2^E (m < 2^24 an
//      integer), r - s^2 = K 2^2E for an integer K, and sqrt r lies above the midpoint
//      s + ulp/2 iff K > m, i.e. iff fma(-s, s, r) > s ulp (m 2^2E is a float, so the fma's
//      rounding cannot cross it); below the midpoint under s iff fma(-s, s, r) <= -s ulp
//      (-s ulp/2 where s is a power of two, its lower neighbour then ulp/2 away).
// BD_SQRT_RN_DEFINE(name, float type, int type, bit casts) defines it for a scalar or vector
// type (kernels/invert_table.cl's lanes); r <= 0, NaN and a subnormal that the device reads as
// 0 give a value the caller replaces. It costs ~15 operations a value: where the device's sqrt
// is known to be correctly rounded (-DBD_DEVICE_SQRT_RN, below), that is used instead.
#define BD_SQRT_RN_DEFINE(NAME, F, I, AS_I, AS_F)                                           \
    inline F NAME(F r)                                                                       \
    {                                                                                        \
        const I tiny = r < 0x1p-60f;                                                         \
        const F rs = fmax(tiny ? r * 0x1p100f : r, (F)0x1p-60f);                             \
        F s = sqrt(rs);                                                                      \
        const F half_inv = AS_F(0x7e7311c7 - AS_I(s));     /* 1/(2s) within 5.1% */          \
        s = fma(fma(-s, s, rs), half_inv, s);                                                \
        const F ulp = AS_F(AS_I(s) & 0x7f800000) * 0x1p-23f;                                 \
        const F above = s * ulp;                                                             \
        const F below = (AS_I(s) & 0x007fffff) == 0 ? 0.5f * above : above;                  \
        const F e = fma(-s, s, rs);                                                          \
        s = e > above ? AS_F(AS_I(s) + 1) : e <= -below ? AS_F(AS_I(s) - 1) : s;              \
        return tiny ? s * 0x1p-50f : s;                                                      \
    }
// -DBD_DEVICE_SQRT_RN (bdipole_cl/device/numerics.py: the CPU runtimes, whose sqrt is the
// instruction set's IEEE one): the device's sqrt is correctly rounded already, used as it is.
#if defined(BD_DOUBLE) || defined(BD_DEVICE_SQRT_RN)
#undef BD_SQRT_RN_DEFINE
#define BD_SQRT_RN_DEFINE(NAME, F, I, AS_I, AS_F) inline F NAME(F r) { return sqrt(r); }
#endif
// (double sqrt is correctly rounded on every OpenCL device)
BD_SQRT_RN_DEFINE(bd_sqrt_rn, real, int, as_int, as_float)
#define BD_SQRT_RN(x) bd_sqrt_rn(x)

// }}}

// {{{ per-channel constants

// One channel's record in the params array: BD_PARAM_STRIDE reals, field BD_P_<NAME> at its
// index, and the struct's members (BD_PARAM_MEMBERS: each field's name in lower case) and their
// load (BD_PARAM_LOAD) are all generated from bdipole_cl/device/layout.py (PARAM_FIELDS) and
// joined in front of this header by the host, so host and kernels share one definition.
typedef struct {
    BD_PARAM_MEMBERS
} bd_params;

inline bd_params bd_load_params(__constant const real *params, int channel)
{
    __constant const real *p = params + channel * BD_PARAM_STRIDE;
    bd_params out = BD_PARAM_LOAD(p);
    return out;
}

// }}}

// {{{ cancellation-free helpers

// phi1(x) = (1 - e^{-x})/x, 1 at x = 0.
inline real bd_phi1(real x)
{
    return x == BD_LIT(0.0) ? BD_LIT(1.0) : -expm1(-x) / x;
}

// phi2(x) = (e^{-x} - 1 + x)/x^2 = sum_k (-x)^k/(k+2)!; the series below 0.5 avoids the
// cancellation (its truncation error at x = 0.5 is 0.5^12/14! < 3e-15 relative).
inline real bd_phi2(real x)
{
    if (x < BD_LIT(0.5)) {
        real s = BD_LIT(1.0) / BD_LIT(87178291200.0);  // 1/14!
        s = BD_LIT(1.0) / BD_LIT(6227020800.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(479001600.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(39916800.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(3628800.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(362880.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(40320.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(5040.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(720.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(120.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(24.0) - x * s;
        s = BD_LIT(1.0) / BD_LIT(6.0) - x * s;
        return BD_LIT(0.5) - x * s;
    }
    return (expm1(-x) + x) / (x * x);
}

// psi(x) = (1 - e^{-x}(1 + x))/x^2 = -phi1'(x) = sum_k (-x)^k (k+1)/(k+2)!. Only used in
// derivatives (Newton steps, never in a returned value), so a short series suffices.
inline real bd_psi(real x)
{
    if (x < BD_LIT(0.125)) {
        return BD_LIT(0.5) - x * (BD_LIT(1.0) / BD_LIT(3.0)
                                  - x * (BD_LIT(0.125) - x * (BD_LIT(1.0) / BD_LIT(30.0))));
    }
    return (-expm1(-x) - x * exp(-x)) / (x * x);
}

// }}}

// {{{ Rd(alpha'): memo eq. 3 in the split variables
//
// Rd = a^n exp(K(q)), q = sqrt(1 - a), n = 2 (Better Dipole) or 1 (dipole), and
// K(q) = -s(q) + log(1 - b(q)) with b a sum of positive terms (reference.py: _k_terms):
//   better: s = sqrt(3) q/sqrt(1 + q^2), x = 4 A q sqrt((1 + q^2)/3),
//           b = Ce (1 - e^{-x})/2 + 2 A Cphi x phi2(x)     (uses Ce + 2 A Cphi = 1)
//   dipole: s = sqrt(3) q, x = 4/3 A s, b = (1 - e^{-x})/2
// Every term of log Rd then has one sign, so -log Rd (and 1 - Rd = -expm1(log Rd)) keeps
// relative accuracy as q -> 0 (Rd -> 1), and Rd keeps it as a -> 0.

#ifdef BD_MODEL_DIPOLE
#define BD_POWER 1
#else
#define BD_POWER 2
#endif

// K(q) and, through *dk, dK/dq.
inline real bd_k_terms(real q, bd_params p, real *dk)
{
    real q2 = q * q;
#ifdef BD_MODEL_DIPOLE
    real s = BD_SQRT3 * q;
    real ds = BD_SQRT3;
    real x = BD_LIT(4.0) / BD_LIT(3.0) * p.a_coef * s;
    real dx = BD_LIT(4.0) / BD_LIT(3.0) * p.a_coef * BD_SQRT3;
    real e = exp(-x);
    real b = x < BD_LIT(0.5) ? BD_LIT(-0.5) * expm1(-x) : BD_LIT(0.5) * (BD_LIT(1.0) - e);
    real db = BD_LIT(0.5) * e;
    real one_minus_b = BD_LIT(0.5) * (BD_LIT(1.0) + e);
#else
    real root = sqrt(BD_LIT(1.0) + q2);
    real s = BD_SQRT3 * q / root;
    real ds = BD_SQRT3 / (root * root * root);
    real x = BD_LIT(4.0) * p.a_coef * q * root / BD_SQRT3;
    real dx = BD_LIT(4.0) * p.a_coef / BD_SQRT3 * (BD_LIT(1.0) + BD_LIT(2.0) * q2) / root;
    real two_a_cphi = BD_LIT(2.0) * p.a_coef * p.cphi;
    // one exp: e^{-x} - 1 needs expm1 only below x = 1/2 (above, e - 1 loses < 1 ulp)
    real e = exp(-x);
    real em1 = x < BD_LIT(0.5) ? expm1(-x) : e - BD_LIT(1.0);
    real phi1 = x == BD_LIT(0.0) ? BD_LIT(1.0) : -em1 / x;
    real phi2 = x < BD_LIT(0.5) ? bd_phi2(x) : (em1 + x) / (x * x);
    real b = BD_LIT(-0.5) * p.ce * em1 + two_a_cphi * x * phi2;
    real db = BD_LIT(0.5) * p.ce * e + two_a_cphi * bd_psi(x);
    // 1 - b = B/2 summed from its own positive terms: exact where b -> 1 (large A, q -> 1)
    real one_minus_b = BD_LIT(0.5) * p.ce * (BD_LIT(1.0) + e) + two_a_cphi * phi1;
#endif
    *dk = -ds - db * dx / one_minus_b;
    return -s + (b < BD_LIT(0.5) ? log1p(-b) : log(one_minus_b));
}

// Rd(alpha') with a = alpha' given exactly (memo eq. 3).
inline real bd_rd(real a, bd_params p)
{
    real dk;
    real k = bd_k_terms(sqrt(BD_LIT(1.0) - a), p, &dk);
    // a^n exp(K), not exp(n log a + K): exp would amplify log a's rounding as a -> 0
    return (BD_POWER == 2 ? a * a : a) * exp(k);
}

// Lower half (a <= 1/2): F(a) = Rd^(1/n) = a exp(K/n), increasing, nearly linear; *df = dF/da.
inline real bd_lower_residual(real a, bd_params p, real *df)
{
    real q = sqrt(BD_LIT(1.0) - a);
    real dk;
    real ek = exp(bd_k_terms(q, p, &dk) / (real)BD_POWER);
    *df = ek * (BD_LIT(1.0) - a * dk / (BD_LIT(2.0) * (real)BD_POWER * q));
    return a * ek;
}

// log Rd as a function of q = sqrt(1 - a) (a = 1 - q^2 is exact enough for q <= sqrt(1/2));
// *dlog = d(log Rd)/dq.
inline real bd_log_rd_q(real q, bd_params p, real *dlog)
{
    real q2 = q * q;
    real dk;
    real k = bd_k_terms(q, p, &dk);
    *dlog = (real)BD_POWER * BD_LIT(-2.0) * q / (BD_LIT(1.0) - q2) + dk;
    return (real)BD_POWER * log1p(-q2) + k;
}

// Upper half (q <= sqrt(1/2)): G(q) = -log Rd(1 - q^2), increasing, ~ c q as q -> 0, and
// unlike 1 - Rd it keeps a small Rd's relative precision just above the split; *dg = dG/dq.
inline real bd_upper_residual(real q, bd_params p, real *dg)
{
    real g = -bd_log_rd_q(q, p, dg);
    *dg = -*dg;
    return g;
}

// The memo's computeRd exactly as printed (Hery TM 12-11, p. 2): the baseline "memo" method.
inline real bd_rd_memo(real alpha_prime, bd_params p)
{
    real four_a = p.a_coef * BD_LIT(4.0);
    real mu_tr_d = sqrt((BD_LIT(1.0) - alpha_prime) * (BD_LIT(2.0) - alpha_prime) / BD_LIT(3.0));
    real myexp = exp(-four_a * mu_tr_d);
    return BD_LIT(0.5) * alpha_prime * alpha_prime
           * exp(-sqrt(BD_LIT(3.0) * (BD_LIT(1.0) - alpha_prime) / (BD_LIT(2.0) - alpha_prime)))
           * (p.ce * (BD_LIT(1.0) + myexp) + p.cphi / mu_tr_d * (BD_LIT(1.0) - myexp));
}

// mu_tr / sigma_t' from rho = 1 - alpha' (better: D = (1 + rho)/(3 sigma_t')).
inline real bd_mu_over_sigma_t(real rho)
{
#ifdef BD_MODEL_DIPOLE
    return sqrt(BD_LIT(3.0) * rho);
#else
    return sqrt(BD_DIV(BD_LIT(3.0) * rho, BD_LIT(1.0) + rho));
#endif
}

// }}}

// {{{ radial profile R(r) and its energy (Better Dipole only; memo eq. 1)

typedef struct {
    real a2;      // alpha'^2
    real d_coef;  // D = (1 + rho)/(3 sigma_t')
    real mu;      // mu_tr
    real z_r;     // 1/sigma_t'
    real z_v;     // -z_r - 4 A D  (< 0)
    real ce, cphi_over_d;
} bd_geometry;

inline bd_geometry bd_make_geometry(real a, real rho, real sigma_t, bd_params p)
{
    bd_geometry g;
    g.a2 = a * a;
    g.d_coef = (BD_LIT(1.0) + rho) / (BD_LIT(3.0) * sigma_t);
    g.mu = sigma_t * bd_mu_over_sigma_t(rho);
    g.z_r = BD_LIT(1.0) / sigma_t;
    g.z_v = -g.z_r - BD_LIT(4.0) * p.a_coef * g.d_coef;
    g.ce = p.ce;
    g.cphi_over_d = p.cphi / g.d_coef;
    return g;
}

// R(r) [1/length^2], with the Cphi/D terms of the two sources differenced without cancellation.
inline real bd_profile(real r, bd_geometry g)
{
    real d_r = hypot(r, g.z_r);
    real d_v = hypot(r, g.z_v);
    real e_r = exp(-g.mu * d_r);
    real e_v = exp(-g.mu * d_v);
    real ce_part = g.z_r * (g.mu * d_r + BD_LIT(1.0)) * e_r / (d_r * d_r * d_r)
                   - g.z_v * (g.mu * d_v + BD_LIT(1.0)) * e_v / (d_v * d_v * d_v);
    real gap = (g.z_v * g.z_v - g.z_r * g.z_r) / (d_v + d_r);
    real phi_part = e_r / d_r * (gap / d_v - (d_r / d_v) * expm1(-g.mu * gap));
    return g.a2 * BD_INV_4PI * (g.ce * ce_part + g.cphi_over_d * phi_part);
}

// One source's energy inside radius r, divided by alpha'^2/2 (reference.py: _energy_terms).
inline real bd_energy_terms(real r, real z, bd_geometry g)
{
    real az = fabs(z);
    real d = hypot(r, z);
    real dz = r * (r / (d + az));  // d - |z|, without overflow of r^2
    real e0 = exp(-g.mu * az);
    real t = g.mu * dz;
    real ce_term = copysign(e0 * (dz / d - (az / d) * expm1(-t)), z);
    real phi_term = e0 * dz * bd_phi1(t);
    return g.ce * ce_term + g.cphi_over_d * phi_term;
}

// Energy beyond radius r, without the cancellation of Rd - cdf (reference.py: profile_tail).
inline real bd_profile_tail(real r, bd_geometry g)
{
    if (isinf(r)) return BD_LIT(0.0);
    real d_r = hypot(r, g.z_r);
    real d_v = hypot(r, g.z_v);
    real e_r = exp(-g.mu * d_r);
    real e_v = exp(-g.mu * d_v);
    real gap = (g.z_v * g.z_v - g.z_r * g.z_r) / (d_v + d_r);
    real ce_term = g.z_r * e_r / d_r - g.z_v * e_v / d_v;
    real phi_term = e_r * gap * bd_phi1(g.mu * gap);
    return BD_LIT(0.5) * g.a2 * (g.ce * ce_term + g.cphi_over_d * phi_term);
}

// Total energy (= Rd, memo eq. 3), from the geometry: the tail at r = 0.
inline real bd_profile_total(bd_geometry g)
{
    return bd_profile_tail(BD_LIT(0.0), g);
}

// Energy within radius r: 2 pi Int_0^r R(s) s ds (closed form, docs/model.md); -> Rd as r -> inf.
// Summed directly while the tail holds at least half the energy; past that as total - tail,
// because the two sources' Cphi terms cancel at large r when mu_tr is small (alpha' -> 1).
inline real bd_profile_cdf(real r, bd_geometry g)
{
    real total = bd_profile_total(g);
    real tail = bd_profile_tail(r, g);
    if (tail < BD_LIT(0.5) * total) return total - tail;  // tail and total never cancel
    return BD_LIT(0.5) * g.a2 * (bd_energy_terms(r, g.z_r, g) - bd_energy_terms(r, g.z_v, g));
}

// }}}

// {{{ image borders (blur kernels): -DBD_BORDER_ZERO, -DBD_BORDER_WRAP, else clamp to edge

// Index of texel i of a row/column of n for a tap outside [0, n); -1 means "contributes 0".
inline int bd_border(int i, int n)
{
    if (i >= 0 && i < n) return i;
#if defined(BD_BORDER_ZERO)
    return -1;
#elif defined(BD_BORDER_WRAP)
    int m = i % n;
    return m < 0 ? m + n : m;
#else
    return i < 0 ? 0 : n - 1;
#endif
}

// }}}
