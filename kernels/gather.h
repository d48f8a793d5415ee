// gather.h -- what the per-texel gathers share (kernels/blur_textured.cl, blur_stretched.cl;
// prepended to them after kernels/lanes.h by device/programs.py): a work-item's texels, a
// table weight of its texels as lanes, and the settle rule of a gathered exitance.

// the first of work-item g's BD_WIDTH texels in a row of n >= BD_WIDTH: the last work-item
// takes the row's last BD_WIDTH
inline int first_texel(const int g, const int n)
{
    return min(g * BD_WIDTH, n - BD_WIDTH);
}

// weight j of the texels as lanes, lane i's weights at wl[i * record ..] (a texel_weights')
inline vec texel_weight(const float *wl, const int record, const int j)
{
    vec v;
#define BD_WEIGHT_LANE(s, i) v s = wl[(i) * record + j];
    FOR_LANES(BD_WEIGHT_LANE)
#undef BD_WEIGHT_LANE
    return v;
}

// a gathered exitance m with the round-off of a zero result removed (fft.settled, the host's
// rule, which the tests compare): |m| at or below floor = rd * scale is 0 (+0: an Rd of -0.0
// makes a floor and a product of -0.0), and so is every m < 0 where the irradiance is
// non-negative (nonneg)
inline vec settle(const vec m, const vec rd, const float scale, const int nonneg)
{
    const vec floor = rd * scale;
#if BD_WIDTH == 1
    return (nonneg ? m <= floor : fabs(m) <= floor) ? 0.0f : m;
#else
    return select(m, (vec)0.0f, nonneg ? m <= floor : fabs(m) <= floor);
#endif
}
