// blur_separable.cl -- one separable Gaussian of the sum-of-Gaussians blur
// (bdipole_cl/ops/blur/fit.py: fit_gaussians): rows then columns with the same texel-integrated 1D
// weights g[-K..K], the column pass adding weight * result into the output channel.
// Needs bdipole.h in front; border mode by -DBD_BORDER_{CLAMP,ZERO,WRAP}. -DBD_PER_TEXEL_WEIGHT: the
// column pass's weight is plane `plane` of per-texel planes (G x H x W, texture-varying parameters:
// bdipole_cl/ops/blur/textured.py), left on the device by the lattice_weights kernel.

#ifdef BD_PER_TEXEL_WEIGHT
#define WEIGHT_PARAM __global const float *weight, const int plane
#define WEIGHT_AT(p) weight[(size_t)plane * width * height + (p)]
#else
#define WEIGHT_PARAM const float weight
#define WEIGHT_AT(p) weight
#endif

// tmp[y, x] = sum_i g[i] src[y, x + i, channel]
__kernel void blur_rows(__global const float *src, __global float *tmp, __global const float *g,
                        const int width, const int height, const int nchan, const int channel,
                        const int radius)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height) return;
    __global const float *row = src + (size_t)y * width * nchan + channel;
    float acc = 0.0f;
    for (int i = -radius; i <= radius; ++i) {
        int gx = bd_border(x + i, width);
        if (gx >= 0) acc += g[i + radius] * row[(size_t)gx * nchan];
    }
    tmp[(size_t)y * width + x] = acc;
}

// dst[y, x, channel] += weight * sum_j g[j] tmp[y + j, x]
__kernel void blur_cols_add(__global const float *tmp, __global float *dst,
                            __global const float *g, const int width, const int height,
                            const int nchan, const int channel, const int radius,
                            WEIGHT_PARAM)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height) return;
    float acc = 0.0f;
    for (int j = -radius; j <= radius; ++j) {
        int gy = bd_border(y + j, height);
        if (gy >= 0) acc += g[j + radius] * tmp[(size_t)gy * width + x];
    }
    dst[((size_t)y * width + x) * nchan + channel] += WEIGHT_AT((size_t)y * width + x) * acc;
}
