// blur_varying.cl -- per-texel weights of the shared basis for texture-varying blur
// parameters (bdipole_cl/varying.py). Each texel's weights are the Lagrange-cubic
// interpolation (4 nodes per axis) of the node weights table[iu][iv][j] at its node
// coordinates (u, v), times the texel's Rd. An axis on which the texture is constant has one
// node. Specialized by -DNBASIS=G (basis size), -DNU_TAPS, -DNV_TAPS (4, or 1 for a constant
// axis), so the loops unroll.

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

// w[j * npix + p] = rd[p] * sum_{a, b} lu[a] lv[b] table[((iu + a) * nv + iv + b) * NBASIS + j]
__kernel void lattice_weights(__global const float2 *coord, __global const float *rd,
                              __global const float *table, __global float *w, const int npix,
                              const int nu, const int nv)
{
    const int p = get_global_id(0);
    if (p >= npix) return;
    float lu[4], lv[4], acc[NBASIS];
    const float2 c = coord[p];
    const int iu = axis_taps(c.x, nu, NU_TAPS, lu);
    const int iv = axis_taps(c.y, nv, NV_TAPS, lv);
    for (int j = 0; j < NBASIS; ++j) acc[j] = 0.0f;
    for (int a = 0; a < NU_TAPS; ++a) {
        for (int b = 0; b < NV_TAPS; ++b) {
            const float tap = lu[a] * lv[b];
            __global const float *node = table + ((size_t)(iu + a) * nv + iv + b) * NBASIS;
            for (int j = 0; j < NBASIS; ++j) acc[j] += tap * node[j];
        }
    }
    const float scale = rd[p];
    for (int j = 0; j < NBASIS; ++j) w[(size_t)j * npix + p] = scale * acc[j];
}
