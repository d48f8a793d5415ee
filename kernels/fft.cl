// fft.cl -- batched FFTs on the device: complex Stockham passes (mixed radix 2, 3, 4, 5, 7, 8)
// and the real <-> half-length complex steps of the 2D real FFTs planned by
// bdipole_cl/ops/device_fft.py (the maths: docs/device_fft.md).
//
// Needs bdipole.h in front (real, BD_LIT); -DBD_DOUBLE for double. Everything else (lengths,
// radices, strides, tiles) is a kernel argument, so that one program per precision serves every
// plan: a new image size builds nothing.
//
// Layout. Every kernel works on tiles in local memory: `len` points of each of `cols`
// independent sequences, point i of sequence c at [i * cols + c] (consecutive work-items take
// consecutive sequences, so the stages' reads are free of bank conflicts; their writes, at
// stride R, are not padded against them: a GPU's possible gain). Two such buffers (ping and
// pong) hold a tile; each Stockham stage reads one and writes the other (no in-place shuffle,
// so no stage waits on its own writes), a barrier between stages.
//
// Sign: forward transforms use W_n = exp(-2 pi i / n); inverse ones are conj(DFT(conj(x)))
// (`inverse`: conjugate at load and at store), unnormalised; the host folds 1 / (N0 N1) into
// the first pass's `scale`.
//
// Twiddles: `tw` holds W_nt^m, m in [0, nt), computed on the host in float64 (octant-reduced,
// each within 2 ulps of float64) and rounded to `real`; a stage of radix r at span ns needs
// W_(ns r)^(q k) = tw[q k nt / (ns r)] (ns r divides the axis length, which divides nt).

// {{{ complex helpers

#ifdef BD_DOUBLE
typedef double2 real2;
#else
typedef float2 real2;
#endif

inline real2 cmul(real2 a, real2 b)
{
    return (real2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

inline real2 conj2(real2 a) { return (real2)(a.x, -a.y); }

// a * (-i) and a * i: exact
inline real2 mul_mi(real2 a) { return (real2)(a.y, -a.x); }
inline real2 mul_i(real2 a) { return (real2)(-a.y, a.x); }

#define BD_HALF BD_LIT(0.5)
#define BD_SQRT1_2 BD_LIT(0.70710678118654752440)
#define BD_SIN_PI_3 BD_LIT(0.86602540378443864676)       // sin(2 pi / 3)
#define BD_C5_1 BD_LIT(0.30901699437494742410)           // cos(2 pi / 5)
#define BD_C5_2 BD_LIT(-0.80901699437494742410)          // cos(4 pi / 5)
#define BD_S5_1 BD_LIT(0.95105651629515357212)           // sin(2 pi / 5)
#define BD_S5_2 BD_LIT(0.58778525229247312917)           // sin(4 pi / 5)
#define BD_C7_1 BD_LIT(0.62348980185873353053)           // cos(2 pi m / 7), m = 1, 2, 3
#define BD_C7_2 BD_LIT(-0.22252093395631440429)
#define BD_C7_3 BD_LIT(-0.90096886790241912624)
#define BD_S7_1 BD_LIT(0.78183148246802980871)           // sin(2 pi m / 7)
#define BD_S7_2 BD_LIT(0.97492791218182360702)
#define BD_S7_3 BD_LIT(0.43388373911755812048)

// }}}

// {{{ butterflies: v <- DFT_r(v), forward, natural order in and out

inline void dft2(real2 *v)
{
    real2 a = v[0];
    v[0] = a + v[1];
    v[1] = a - v[1];
}

inline void dft3(real2 *v)
{
    real2 s = v[1] + v[2];
    real2 a = v[0] - BD_HALF * s;
    real2 b = BD_SIN_PI_3 * (v[1] - v[2]);
    v[0] = v[0] + s;
    v[1] = a + mul_mi(b);
    v[2] = a + mul_i(b);
}

inline void dft4(real2 *v)
{
    real2 t0 = v[0] + v[2], t1 = v[0] - v[2];
    real2 t2 = v[1] + v[3], t3 = mul_mi(v[1] - v[3]);
    v[0] = t0 + t2;
    v[1] = t1 + t3;
    v[2] = t0 - t2;
    v[3] = t1 - t3;
}

// y_k = a_k - i b_k and y_(5-k) = a_k + i b_k, k = 1, 2 (the real and odd parts of the sums)
inline void dft5(real2 *v)
{
    real2 s1 = v[1] + v[4], s2 = v[2] + v[3], d1 = v[1] - v[4], d2 = v[2] - v[3];
    real2 a1 = v[0] + BD_C5_1 * s1 + BD_C5_2 * s2;
    real2 a2 = v[0] + BD_C5_2 * s1 + BD_C5_1 * s2;
    real2 b1 = BD_S5_1 * d1 + BD_S5_2 * d2;
    real2 b2 = BD_S5_2 * d1 - BD_S5_1 * d2;
    v[0] = v[0] + s1 + s2;
    v[1] = a1 + mul_mi(b1);
    v[4] = a1 + mul_i(b1);
    v[2] = a2 + mul_mi(b2);
    v[3] = a2 + mul_i(b2);
}

// as dft5: cos and sin of 2 pi m k / 7 reduced to m k mod 7 in {1, 2, 3} (the sines' signs)
inline void dft7(real2 *v)
{
    real2 s1 = v[1] + v[6], s2 = v[2] + v[5], s3 = v[3] + v[4];
    real2 d1 = v[1] - v[6], d2 = v[2] - v[5], d3 = v[3] - v[4];
    real2 a1 = v[0] + BD_C7_1 * s1 + BD_C7_2 * s2 + BD_C7_3 * s3;
    real2 a2 = v[0] + BD_C7_2 * s1 + BD_C7_3 * s2 + BD_C7_1 * s3;
    real2 a3 = v[0] + BD_C7_3 * s1 + BD_C7_1 * s2 + BD_C7_2 * s3;
    real2 b1 = BD_S7_1 * d1 + BD_S7_2 * d2 + BD_S7_3 * d3;
    real2 b2 = BD_S7_2 * d1 - BD_S7_3 * d2 - BD_S7_1 * d3;
    real2 b3 = BD_S7_3 * d1 - BD_S7_1 * d2 + BD_S7_2 * d3;
    v[0] = v[0] + s1 + s2 + s3;
    v[1] = a1 + mul_mi(b1);
    v[6] = a1 + mul_i(b1);
    v[2] = a2 + mul_mi(b2);
    v[5] = a2 + mul_i(b2);
    v[3] = a3 + mul_mi(b3);
    v[4] = a3 + mul_i(b3);
}

// radix 2 on the even and odd points (two DFT4s), joined by W_8^k
inline void dft8(real2 *v)
{
    real2 e[4] = {v[0], v[2], v[4], v[6]};
    real2 o[4] = {v[1], v[3], v[5], v[7]};
    dft4(e);
    dft4(o);
    o[1] = BD_SQRT1_2 * (real2)(o[1].x + o[1].y, o[1].y - o[1].x);    // * (1 - i) / sqrt 2
    o[2] = mul_mi(o[2]);
    o[3] = BD_SQRT1_2 * (real2)(o[3].y - o[3].x, -o[3].x - o[3].y);   // * (-1 - i) / sqrt 2
    for (int k = 0; k < 4; k++) {
        v[k] = e[k] + o[k];
        v[k + 4] = e[k] - o[k];
    }
}

// }}}

// {{{ Stockham stages in local memory

// One stage of radix R at span ns over a tile of `cols` sequences of `len` points, src -> dst:
// butterfly j of a sequence takes points j + q len / R, twiddled by W_(ns R)^(q k), k = j mod
// ns, and writes (j - k) R + k + q ns (Stockham's self-sorting order). A work-item keeps its
// sequence c and steps through butterflies by jstep (the work-group size is a multiple of
// cols: no division a point but k's).
#define BD_STAGE(R, DFT)                                                                     \
    {                                                                                        \
        const int m = len / (R), step = nt / (ns * (R));                                     \
        for (int j = j_first; j < m; j += jstep) {                                           \
            const int k = ns == 1 ? 0 : j % ns;                                              \
            real2 v[R];                                                                      \
            for (int q = 0; q < (R); q++)                                                    \
                v[q] = src[(j + q * m) * cols + c];                                          \
            if (ns > 1)                                                                      \
                for (int q = 1; q < (R); q++)                                                \
                    v[q] = cmul(v[q], tw[q * k * step]);                                     \
            DFT(v);                                                                          \
            const int base = (j - k) * (R) + k;                                              \
            for (int q = 0; q < (R); q++)                                                    \
                dst[(base + q * ns) * cols + c] = v[q];                                      \
        }                                                                                    \
    }

inline void local_stage(__local const real2 *src, __local real2 *dst, const int r, const int ns,
                        const int len, const int cols, const int c, const int j_first,
                        const int jstep, __global const real2 *tw, const int nt)
{
    switch (r) {
    case 2: BD_STAGE(2, dft2) break;
    case 3: BD_STAGE(3, dft3) break;
    case 4: BD_STAGE(4, dft4) break;
    case 5: BD_STAGE(5, dft5) break;
    case 7: BD_STAGE(7, dft7) break;
    case 8: BD_STAGE(8, dft8) break;
    }
}

// The DFT of length len of each of the tile's cols sequences, loaded into `a` (a barrier
// after the load): the stages' radices are the 4-bit digits of `stages`, the first lowest.
// Returns the buffer that holds the result (a or b), after a barrier. The work-group size is
// a multiple of cols.
inline __local real2 *local_fft(__local real2 *a, __local real2 *b, const int len, ulong stages,
                                const int cols, __global const real2 *tw, const int nt)
{
    const int lid = get_local_id(0), c = lid % cols, j_first = lid / cols;
    const int jstep = get_local_size(0) / cols;
    int ns = 1;
    for (; stages; stages >>= 4) {
        const int r = (int)(stages & 15);
        local_stage(a, b, r, ns, len, cols, c, j_first, jstep, tw, nt);
        barrier(CLK_LOCAL_MEM_FENCE);
        __local real2 *s = a;
        a = b;
        b = s;
        ns *= r;
    }
    return a;
}

// }}}

// {{{ the global pass: one radix-R step of a length-n Stockham FFT, R points in local memory

// Data: element (b, i, l) at off + (b / rows) plane + (b % rows) row + i lanes + l, i the
// transformed axis (length n), l one of `lanes` contiguous independent lanes (the columns of a
// plane; 1 for rows). A work-group takes one batch index b, j_tile consecutive butterflies
// j0.. of the pass and lane_tile consecutive lanes: its loads and stores are contiguous runs
// (lanes, or consecutive j) of global memory. Outputs i outside [keep_lo, keep_hi) are not
// stored (a pruned last pass).
__kernel void fft_pass(__global const real2 *in, __global real2 *out,
                       __global const real2 *tw, const int nt,
                       __local real2 *ping, __local real2 *pong,
                       const int n, const int radix, const ulong stages, const int span,
                       const int lanes, const int lane_tile, const int j_tile, const int rows,
                       const long in_off, const long in_plane, const long in_row,
                       const long out_off, const long out_plane, const long out_row,
                       const int keep_lo, const int keep_hi, const real scale,
                       const int inverse)
{
    const int lane_groups = (lanes + lane_tile - 1) / lane_tile;
    const int j_groups = n / radix / j_tile;
    int g = get_group_id(0);
    const int l0 = (g % lane_groups) * lane_tile;
    g /= lane_groups;
    const int j0 = (g % j_groups) * j_tile;
    const int b = g / j_groups;
    const long in_base = in_off + (b / rows) * in_plane + (b % rows) * in_row;
    const long out_base = out_off + (b / rows) * out_plane + (b % rows) * out_row;
    const int cols = j_tile * lane_tile, stride = n / radix;
    const int step = nt / (span * radix);
    const real sign = inverse ? BD_LIT(-1.0) : BD_LIT(1.0);
    // a work-item keeps one column c of the tile (a lane of a butterfly j), its points r
    // stepping by rstep (the work-group size is a multiple of cols)
    const int lid = get_local_id(0), c = lid % cols, rstep = get_local_size(0) / cols;
    const int j = j0 + c / lane_tile, l = l0 + c % lane_tile, k = j % span;
    const int live = l < lanes;
    __global const real2 *src = in + in_base + (long)j * lanes + l;
    const long point = (long)stride * lanes;

    for (int r = lid / cols; r < radix; r += rstep) {
        real2 v = (real2)(BD_LIT(0.0), BD_LIT(0.0));
        if (live) {
            v = src[r * point];
            v = scale * (real2)(v.x, sign * v.y);
            if (k > 0 && r > 0)
                v = cmul(v, tw[r * k * step]);
        }
        ping[r * cols + c] = v;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    __local const real2 *res = local_fft(ping, pong, radix, stages, cols, tw, nt);

    if (span == 1 && lane_tile == 1) {
        // the first pass of a lane-less axis writes j R + r: the tile is one contiguous run,
        // stored in that order (a division a point, on this path only)
        for (int e = lid; e < radix * cols; e += get_local_size(0)) {
            const int r = e % radix, cc = e / radix, i = (j0 + cc) * radix + r;
            if (i >= keep_lo && i < keep_hi) {
                const real2 v = res[r * cols + cc];
                out[out_base + i] = (real2)(v.x, sign * v.y);
            }
        }
    } else if (live) {
        __global real2 *dst = out + out_base + (long)((j - k) * radix + k) * lanes + l;
        const long point_out = (long)span * lanes;
        for (int r = lid / cols; r < radix; r += rstep) {
            const int i = (j - k) * radix + k + r * span;
            if (i >= keep_lo && i < keep_hi) {
                const real2 v = res[r * cols + c];
                dst[r * point_out] = (real2)(v.x, sign * v.y);
            }
        }
    }
}

// }}}

// {{{ real <-> half-length complex

// Real rows x of even length 2m as complex z_n = x_2n + i x_(2n+1) (Z its DFT_m, Z_m = Z_0):
// X_k = ((Z_k + conj Z_(m-k)) - i W_2m^k (Z_k - conj Z_(m-k))) / 2, k = 0..m (the halving is
// exact). The inverse, from a half spectrum X_0..X_m (the imaginary parts of X_0 and X_m
// dropped, as a real inverse does): Z'_k = (X_k + conj X_(m-k)) + i conj(W_2m^k) (X_k -
// conj X_(m-k)) = 2 Z_k, whose inverse DFT_m is 2m z: the host's scale 1 / (N0 N1) makes it z.
inline real2 r2c_twist(const real2 za, const real2 zb, const real2 w)
{
    const real2 e = (real2)(za.x + zb.x, za.y - zb.y);
    const real2 o = (real2)(za.x - zb.x, za.y + zb.y);
    return BD_HALF * (e + mul_mi(cmul(w, o)));
}

inline real2 c2r_twist(const real2 xa, const real2 xb, const real2 w)
{
    const real2 e = (real2)(xa.x + xb.x, xa.y - xb.y);
    const real2 o = (real2)(xa.x - xb.x, xa.y + xb.y);
    return e + mul_i(cmul(conj2(w), o));
}

// Rows that fit a work-group's local memory, in one pass: rows_tile rows of m complex points
// (the reals, 2m a row) a work-group, transformed by local_fft and twisted into m + 1 points.
// Row b (of total_rows) at off + (b / rows) plane + (b % rows) row, in and out alike. A
// work-item keeps one row c of the tile (the work-group size is a multiple of rows_tile).
__kernel void fft_rows_r2c(__global const real2 *in, __global real2 *out,
                           __global const real2 *tw, const int nt,
                           __local real2 *ping, __local real2 *pong,
                           const int m, const ulong stages, const int rows_tile,
                           const int total_rows, const int rows,
                           const long in_off, const long in_plane, const long in_row,
                           const long out_off, const long out_plane, const long out_row)
{
    const int lid = get_local_id(0), c = lid % rows_tile, istep = get_local_size(0) / rows_tile;
    const int b = get_group_id(0) * rows_tile + c, live = b < total_rows;
    __global const real2 *x = in + in_off + (b / rows) * in_plane + (b % rows) * in_row;
    for (int i = lid / rows_tile; i < m; i += istep)
        ping[i * rows_tile + c] = live ? x[i] : (real2)(BD_LIT(0.0), BD_LIT(0.0));
    barrier(CLK_LOCAL_MEM_FENCE);
    __local const real2 *z = local_fft(ping, pong, m, stages, rows_tile, tw, nt);
    if (!live)
        return;                             // no barrier follows
    __global real2 *y = out + out_off + (b / rows) * out_plane + (b % rows) * out_row;
    for (int k = lid / rows_tile; k <= m; k += istep) {
        const int ka = k == m ? 0 : k, kb = k == 0 ? 0 : m - k;     // k and m - k, mod m
        y[k] = r2c_twist(z[ka * rows_tile + c], z[kb * rows_tile + c], tw[k]);
    }
}

// The inverse of fft_rows_r2c: half spectra of m + 1 points in, real rows (m complex) out,
// the inverse DFT_m as conj(DFT(conj)); `scale` multiplies the input.
__kernel void fft_rows_c2r(__global const real2 *in, __global real2 *out,
                           __global const real2 *tw, const int nt,
                           __local real2 *ping, __local real2 *pong,
                           const int m, const ulong stages, const int rows_tile,
                           const int total_rows, const int rows,
                           const long in_off, const long in_plane, const long in_row,
                           const long out_off, const long out_plane, const long out_row,
                           const real scale)
{
    const int lid = get_local_id(0), c = lid % rows_tile, istep = get_local_size(0) / rows_tile;
    const int b = get_group_id(0) * rows_tile + c, live = b < total_rows;
    __global const real2 *x = in + in_off + (b / rows) * in_plane + (b % rows) * in_row;
    for (int i = lid / rows_tile; i < m; i += istep) {
        real2 v = (real2)(BD_LIT(0.0), BD_LIT(0.0));
        if (live) {
            real2 xa = x[i], xb = x[m - i];
            if (i == 0) {                   // X_0 and X_m: their real parts
                xa.y = BD_LIT(0.0);
                xb.y = BD_LIT(0.0);
            }
            v = conj2(scale * c2r_twist(xa, xb, tw[i]));
        }
        ping[i * rows_tile + c] = v;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    __local const real2 *z = local_fft(ping, pong, m, stages, rows_tile, tw, nt);
    if (!live)
        return;
    __global real2 *y = out + out_off + (b / rows) * out_plane + (b % rows) * out_row;
    for (int i = lid / rows_tile; i < m; i += istep)
        y[i] = conj2(z[i * rows_tile + c]);
}

// The twists of rows too long for local memory, in place on rows of m + 1 points (global id:
// row b, pair k in [0, m / 2]: points k and m - k are read and written by one work-item).
// Forward: Z_0..Z_(m-1) -> X_0..X_m.
__kernel void fft_r2c_twist(__global real2 *buf, __global const real2 *tw, const int m,
                            const int total_rows, const int rows,
                            const long off, const long plane, const long row)
{
    const int pairs = m / 2 + 1;
    const long id = get_global_id(0);
    if (id >= (long)total_rows * pairs)
        return;
    const int b = id / pairs, k = id % pairs;
    __global real2 *z = buf + off + (b / rows) * plane + (b % rows) * row;
    const real2 za = z[k], zb = z[(m - k) % m];
    if (k == 0) {
        z[0] = r2c_twist(za, za, tw[0]);
        z[m] = r2c_twist(za, za, tw[m]);
    } else {
        z[k] = r2c_twist(za, zb, tw[k]);
        z[m - k] = r2c_twist(zb, za, tw[m - k]);
    }
}

// Inverse: X_0..X_m -> Z'_0..Z'_(m-1), times scale.
__kernel void fft_c2r_twist(__global real2 *buf, __global const real2 *tw, const int m,
                            const int total_rows, const int rows,
                            const long off, const long plane, const long row,
                            const real scale)
{
    const int pairs = m / 2 + 1;
    const long id = get_global_id(0);
    if (id >= (long)total_rows * pairs)
        return;
    const int b = id / pairs, k = id % pairs;
    __global real2 *x = buf + off + (b / rows) * plane + (b % rows) * row;
    if (k == 0) {
        x[0] = scale * c2r_twist((real2)(x[0].x, BD_LIT(0.0)), (real2)(x[m].x, BD_LIT(0.0)),
                                 tw[0]);
    } else {
        const real2 xa = x[k], xb = x[m - k];
        x[k] = scale * c2r_twist(xa, xb, tw[k]);
        x[m - k] = scale * c2r_twist(xb, xa, tw[m - k]);
    }
}

// }}}
