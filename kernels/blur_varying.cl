// blur_varying.cl -- texture-varying blur parameters (bdipole_cl/varying.py): per-texel weights
// of the shared basis, w_j(x) = sum_{a,b} lu[a] lv[b] table[iu + a][iv + b][j], the
// Lagrange-cubic interpolation (4 nodes per axis) of the node weights at the texel's node
// coordinates (cu, cv) (logit Rd and ln ld in lattice steps, from varying.texel_coords). An
// axis on which the texture is constant has one node.
//
// Specialized by -DNBASIS=G (basis size), -DNU_TAPS, -DNV_TAPS (4, or 1 for a constant axis),
// so the loops unroll.

#ifndef NBASIS
#error "build with -DNBASIS=<basis size>"
#endif
#ifndef NU_TAPS
#define NU_TAPS 4
#endif
#ifndef NV_TAPS
#define NV_TAPS 4
#endif

// first node index and the NTAPS weights of one axis at node coordinate coord
inline int axis_taps(const float coord, const int nodes, const int ntaps, float l[4])
{
    if (ntaps == 1) {
        l[0] = 1.0f;
        return 0;
    }
    const int base = clamp((int)floor(coord), 1, nodes - 3);
    const float t = coord - (float)base;      // cubic Lagrange, nodes -1, 0, 1, 2
    l[0] = -t * (t - 1.0f) * (t - 2.0f) / 6.0f;
    l[1] = (t + 1.0f) * (t - 1.0f) * (t - 2.0f) / 2.0f;
    l[2] = -(t + 1.0f) * t * (t - 2.0f) / 2.0f;
    l[3] = (t + 1.0f) * t * (t - 1.0f) / 6.0f;
    return base - 1;
}

// the texel's basis weights acc[j] (without the Rd factor) at node coordinates (cu, cv)
inline void texel_weights(const float cu, const float cv, __global const float *table,
                          const int nu, const int nv, float acc[NBASIS])
{
    float lu[4], lv[4];
    const int iu = axis_taps(cu, nu, NU_TAPS, lu);
    const int iv = axis_taps(cv, nv, NV_TAPS, lv);
    for (int j = 0; j < NBASIS; ++j) acc[j] = 0.0f;
    for (int a = 0; a < NU_TAPS; ++a) {
        for (int b = 0; b < NV_TAPS; ++b) {
            const float tap = lu[a] * lv[b];
            __global const float *node = table + ((iu + a) * nv + iv + b) * NBASIS;
            for (int j = 0; j < NBASIS; ++j) acc[j] += tap * node[j];
        }
    }
}

// the weight planes: w[j * npix + p] = rd[p] * w_j(p)   (the separable-Gaussian path)
__kernel void lattice_weights(__global const float *rd, __global const float *cu,
                              __global const float *cv, __global const float *table,
                              __global float *w, const int npix, const int nu, const int nv)
{
    const int p = get_global_id(0);
    if (p >= npix) return;
    float acc[NBASIS];
    texel_weights(cu[p], cv[p], table, nu, nv, acc);
    const float scale = rd[p];
    for (int j = 0; j < NBASIS; ++j) w[(size_t)j * npix + p] = scale * acc[j];
}

// the exitance of channel c at texel (x, y) of a w x h image (the FFT path), gathered from
// the basis blurs: out[(y * w + x) * nch + c] = rd * sum_j w_j * planes[j][y][x0 + x], the
// planes `plane` floats apart with rows `pitch` floats apart.
__kernel void gather_exitance(__global const float *rd, __global const float *cu,
                              __global const float *cv, __global const float *table,
                              __global const float *planes, __global float *out, const int w,
                              const int h, const int pitch, const int plane, const int x0,
                              const int nch, const int c, const int nu, const int nv)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const size_t p = (size_t)y * w + x;
    float acc[NBASIS];
    texel_weights(cu[p], cv[p], table, nu, nv, acc);
    __global const float *blurred = planes + (size_t)y * pitch + x0 + x;
    float sum = 0.0f;
    for (int j = 0; j < NBASIS; ++j) sum += acc[j] * blurred[(size_t)j * plane];
    out[p * nch + c] = rd[p] * sum;
}
