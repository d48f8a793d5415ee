// blur_fft.cl -- the FFT blur's work on the device around its transforms
// (bdipole_cl/ops/blur/fft_device.py; the host's twin is bdipole_cl/ops/blur/fft.py): each
// channel's range, sum and non-finite count; the planes padded by the border rule; the
// kernels' real spectra multiplied in; the exitance settled and stored.
// Needs bdipole.h in front (real: the transforms' precision), and -DBD_BORDER_{CLAMP,ZERO,WRAP}.
// The irradiance is float32 (H, W, C) interleaved, as the host holds it.

#if !defined(BD_BORDER_CLAMP) && !defined(BD_BORDER_ZERO) && !defined(BD_BORDER_WRAP)
#error "build with -DBD_BORDER_CLAMP, -DBD_BORDER_ZERO or -DBD_BORDER_WRAP"
#endif

// {{{ each channel's range, sum and non-finite count

#ifndef BD_STATS_GROUP
#define BD_STATS_GROUP 256
#endif

// Work-group (group, channel c) reduces texels group, group + groups, ... of channel c:
// partial[(c * groups + group) * 4 + {0, 1, 2, 3}] = min, max, sum (of the finite values), and
// the count of NaN or infinite ones. The host adds the groups' partials (a few KiB).
__kernel __attribute__((reqd_work_group_size(BD_STATS_GROUP, 1, 1)))
void channel_stats(__global const float *e, const ulong texels, const int C,
                   __global float *partial)
{
    __local float lo[BD_STATS_GROUP], hi[BD_STATS_GROUP], sum[BD_STATS_GROUP],
                  bad[BD_STATS_GROUP];
    const size_t l = get_local_id(0), group = get_group_id(0), groups = get_num_groups(0);
    const int c = get_global_id(1);
    float a = INFINITY, b = -INFINITY, s = 0.0f, n = 0.0f;
    for (size_t t = get_global_id(0); t < texels; t += get_global_size(0)) {
        const float v = e[t * C + c];
        if (isfinite(v)) {
            a = fmin(a, v);
            b = fmax(b, v);
            s += v;
        } else {
            n += 1.0f;
        }
    }
    lo[l] = a; hi[l] = b; sum[l] = s; bad[l] = n;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (size_t step = BD_STATS_GROUP / 2; step > 0; step /= 2) {
        if (l < step) {
            lo[l] = fmin(lo[l], lo[l + step]);
            hi[l] = fmax(hi[l], hi[l + step]);
            sum[l] += sum[l + step];
            bad[l] += bad[l + step];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (l == 0) {
        __global float *p = partial + (c * groups + group) * 4;
        p[0] = lo[0]; p[1] = hi[0]; p[2] = sum[0]; p[3] = bad[0];
    }
}

// }}}

// {{{ padded planes

// The source texel of padded position (y, x) of an image of H x W padded by K: the image is at
// [K, K + H) x [K, K + W), the border rule fills [0, H + 2K) x [0, W + 2K) (numpy.pad's edge,
// constant and wrap modes), zeros beyond. Returns 0 where the position holds no texel.
inline int source_texel(int y, int x, const int H, const int W, const int K, int *sy, int *sx)
{
    if (y >= H + 2 * K || x >= W + 2 * K) return 0;
    y -= K;
    x -= K;
#if defined(BD_BORDER_CLAMP)
    *sy = clamp(y, 0, H - 1);
    *sx = clamp(x, 0, W - 1);
    return 1;
#elif defined(BD_BORDER_ZERO)
    *sy = y;
    *sx = x;
    return y >= 0 && y < H && x >= 0 && x < W;
#else
    *sy = ((y % H) + H) % H;
    *sx = ((x % W) + W) % W;
    return 1;
#endif
}

// planes[g][y][x], (G, N0, N1): channel channels[g] of e padded (``source_texel``), times
// 2^-shift[g] (exact: a power of two; planning.peak_exponents), non-finite values as 0 (they
// were counted first: with on_invalid="clamp" they are unlit texels).
__kernel void pad_planes(__global const float *e, __global real *planes,
                         __constant const int *channels, __constant const int *shift,
                         const int H, const int W, const int C, const int K, const int N0,
                         const int N1)
{
    const int x = get_global_id(0), y = get_global_id(1), g = get_global_id(2);
    if (x >= N1 || y >= N0) return;
    int sy, sx;
    real v = BD_LIT(0.0);
    if (source_texel(y, x, H, W, K, &sy, &sx)) {
        const float t = e[((size_t)sy * W + sx) * C + channels[g]];
        v = isfinite(t) ? ldexp((real)t, -shift[g]) : BD_LIT(0.0);
    }
    planes[((size_t)g * N0 + y) * N1 + x] = v;
}

// }}}

// {{{ the kernels' spectra

// spec[g][f][j] *= K_g[f'][j], spec the (G, N0, M1) half spectra (complex, interleaved) and
// K_g the real spectrum of an even kernel over its rows 0 .. N0/2 (ks: (G, N0/2 + 1, M1)):
// row f' = f for f <= N0/2, else N0 - f (an even kernel's rows f and N0 - f are equal).
__kernel void times_spectrum(__global real *spec, __global const real *ks, const int N0,
                             const int M1)
{
    const int j = get_global_id(0), f = get_global_id(1), g = get_global_id(2);
    if (j >= M1 || f >= N0) return;
    const int row = f <= N0 / 2 ? f : N0 - f;
    const real k = ks[((size_t)g * (N0 / 2 + 1) + row) * M1 + j];
    __global real *z = spec + (((size_t)g * N0 + f) * M1 + j) * 2;
    z[0] *= k;
    z[1] *= k;
}

// }}}

// {{{ the exitance settled and stored

// out[y][x][channels[g]] (float32, (H, W, C) interleaved) = the convolution's value at plane
// row row0 + y, column K + x (planes: (G, rows, N1) holding the rows from plane_row0 on),
// settled as bdipole_cl/ops/blur/fft.py ``settled``: |m| <= floor[g] is 0, and where the
// irradiance is non-negative (nonneg[g]) so is m; then times 2^shift[g] (``pad_planes``' scale
// undone; float32's one rounding where the result is subnormal).
__kernel void settle_store(__global const real *planes, __global float *out,
                           __constant const int *channels, __constant const real *floor,
                           __constant const int *nonneg, __constant const int *shift,
                           const int H, const int W, const int C, const int K,
                           const int rows, const int row0, const int N1)
{
    const int x = get_global_id(0), y = get_global_id(1), g = get_global_id(2);
    if (x >= W || y >= H) return;
    real m = planes[((size_t)g * rows + row0 + y) * N1 + K + x];
    if (nonneg[g] ? m <= floor[g] : fabs(m) <= floor[g]) m = BD_LIT(0.0);
    out[((size_t)y * W + x) * C + channels[g]] = (float)ldexp(m, shift[g]);
}

// }}}

// {{{ the direct and separable blurs' input and output on the device

// dst = src scaled per channel by 2^-shift[c] (exact), its NaN and infinite texels 0: the
// irradiance the direct and separable kernels read where a channel's peak is far below 1 or
// some texels were clamped (``pad_planes`` does the same for the transforms)
__kernel void clean_scaled(__global const float *src, __global float *dst,
                           __constant const int *shift, const int C, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n) return;
    const float v = src[i];
    dst[i] = isfinite(v) ? ldexp(v, -shift[i % C]) : 0.0f;
}

// channel c of out ((H, W, C), texels of them) settled (``settle_store``'s rule) and times
// 2^shift
__kernel void settle_channel(__global float *out, const int c, const int C, const real floor,
                             const int nonneg, const int shift, const ulong texels)
{
    const size_t t = get_global_id(0);
    if (t >= texels) return;
    real m = out[t * C + c];
    if (nonneg ? m <= floor : fabs(m) <= floor) m = BD_LIT(0.0);
    out[t * C + c] = (float)ldexp(m, shift);
}

// }}}

// {{{ the texture-varying blur's basis blurs and settle

// out[f][j] = spec[f][j] * K[f'][j] for one plane (``times_spectrum``'s rows), K the real half
// spectrum of basis kernel ``basis`` of ks (G, N0/2 + 1, M1): the spectrum kept for the next
__kernel void times_spectrum_to(__global const real *spec, __global const real *ks,
                                __global real *out, const int N0, const int M1,
                                const int basis)
{
    const int j = get_global_id(0), f = get_global_id(1);
    if (j >= M1 || f >= N0) return;
    const int row = f <= N0 / 2 ? f : N0 - f;
    const real k = ks[((size_t)basis * (N0 / 2 + 1) + row) * M1 + j];
    const size_t i = ((size_t)f * M1 + j) * 2;
    out[i] = spec[i] * k;
    out[i + 1] = spec[i + 1] * k;
}

// dst[dst0 + i] = (float)src[i]: float64 basis blurs stored as the gather reads them
__kernel void narrow(__global const real *src, __global float *dst, const ulong dst0,
                     const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n) dst[dst0 + i] = (float)src[i];
}

// channel c of out settled against a per-texel floor rd[t] * scale (a texture-varying
// channel's Rd map: ``fft.settled`` with a map) and times 2^shift
__kernel void settle_channel_map(__global float *out, const int c, const int C,
                                 __global const float *rd, const real scale, const int nonneg,
                                 const int shift, const ulong texels)
{
    const size_t t = get_global_id(0);
    if (t >= texels) return;
    real m = out[t * C + c];
    const real floor = rd[t] * scale;
    if (nonneg ? m <= floor : fabs(m) <= floor) m = BD_LIT(0.0);
    out[t * C + c] = (float)ldexp(m, shift);
}

// }}}
