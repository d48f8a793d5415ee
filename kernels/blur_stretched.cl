// blur_stretched.cl -- the stretched blur's gather (bdipole_cl/ops/blur/stretched_gather.py;
// docs/stretch.md "The gather"): per texel the weights of the shared basis, interpolated in the
// fine table over the lattice variables (logit Rd, ln l, s), l = sqrt(l_u l_v) and s =
// ln(l_u / l_v) (stretched_plan.fine_table3: the node weights' cubic interpolation, REFINE
// points per lattice step), times the basis blurs there, plus the near field's kernels
// convolved with the irradiance itself, times Rd, settled as fft.settled does.
//
// The table is read at the four corners of the texel's tetrahedron in its fine cell (Kuhn's
// six tetrahedra of the cube: from the cell's first corner one step along each axis, the axes
// by decreasing fraction; ``stretched_plan.tetrahedral_taps`` is the host's twin): 4 records a
// texel, not the trilinear 8. An axis on which the maps are constant has one node: its step is
// 0 (it reads the same record) and its fraction 0.
//
// The near field: the cells within BD_NEAR (Chebyshev) of the texel, in classes (a, b) of the
// four cells (+-a rows, +-b columns) (near_field.near_classes, not mirrored: a stretched kernel
// is even in u and in v, not across the diagonal), each class's irradiance summed once and
// multiplied by its own weight (the near kernels are the classes: each node's near cells
// exact).
//
// Every work-item takes BD_WIDTH (1, 4, 8 or 16) neighbouring texels of one row in explicit
// vectors (kernels/lanes.h), as kernels/blur_textured.cl: rows hold at least BD_WIDTH texels,
// the last work-item of a row takes its last BD_WIDTH (``first_texel``). The table's records
// (BD_RECORD floats, the weights then zeros) are read per lane in chunks of BD_CHUNK floats.
//
// Specialized by -DBD_NBASIS=G, -DBD_NEAR, -DBD_WIDTH, -DBD_CHUNK.

#ifndef BD_NBASIS
#error "build with -DBD_NBASIS=<basis size>"
#endif
#ifndef BD_NEAR
#define BD_NEAR (-1)
#endif
#ifndef BD_WIDTH
#error "build with -DBD_WIDTH=<texels per work-item> (kernels/lanes.h, before this file, needs it)"
#endif
#ifndef BD_CHUNK
#error "build with -DBD_CHUNK=<4, 8 or 16: floats per load of a node record>"
#endif
// near classes (every (a, b), 0 <= a, b <= BD_NEAR) and weights per table node
#define BD_NCLASSES ((BD_NEAR + 1) * (BD_NEAR + 1))
#define BD_NWEIGHTS (BD_NBASIS + (BD_NEAR >= 0 ? BD_NCLASSES : 0))
#define BD_RECORD (BD_CHUNK * ((BD_NWEIGHTS + BD_CHUNK - 1) / BD_CHUNK))
#define BD_CHUNK_CAT_(a, b) a##b
#define BD_CHUNK_CAT(a, b) BD_CHUNK_CAT_(a, b)
#ifdef GLOADN
#define CHUNK_LOAD(i, p) GLOADN(BD_CHUNK, i, p)
#else
#define CHUNK_LOAD BD_CHUNK_CAT(vload, BD_CHUNK)
#endif
#define CHUNK_STORE BD_CHUNK_CAT(vstore, BD_CHUNK)

// node index and fraction along one axis at fine coordinate c (0, 0 on a one-node axis)
inline ivec axis_base(const vec c, const int nodes, vec *frac)
{
    if (nodes == 1) {
        *frac = (vec)0.0f;
        return (ivec)0;
    }
    const vec base = clamp(floor(c), 0.0f, (float)(nodes - 2));
    *frac = c - base;
    return TO_INT(base);
}

// the fine table's shape and the map of the lattice variables to its coordinates: t * scale -
// offset per axis (both 0 on a one-node axis), and the albedo's clamp for the kernel's shape
#define BD_LATTICE_ARGS const int n0, const int n1, const int n2, const float rd_lo, \
    const float rd_hi, const float s0, const float o0, const float s1, const float o1, \
    const float s2, const float o2
#define BD_LATTICE n0, n1, n2, rd_lo, rd_hi, s0, o0, s1, o1, s2, o2

// the texels' weights (without the Rd factor), lane i's at wl[i * BD_RECORD ..]: per lane its
// tetrahedron's four records combined a chunk at a time (``stretched_plan.tetrahedral_taps``)
inline void texel_weights(__global const float *table, const vec rd, const vec lu,
                          const vec lv, float *wl, BD_LATTICE_ARGS)
{
    const vec p = clamp(rd, rd_lo, rd_hi);
    const vec a = log(lu), b = log(lv);
    vec f0, f1, f2;
    const ivec i0 = axis_base(log(p / (1.0f - p)) * s0 - o0, n0, &f0);
    const ivec i1 = axis_base(0.5f * (a + b) * s1 - o1, n1, &f1);
    const ivec i2 = axis_base((a - b) * s2 - o2, n2, &f2);
    const ivec node = ((i0 * n1 + i1) * n2 + i2) * BD_RECORD;
    // each axis's step in the table (0 on a one-node axis)
    const int d0 = (n0 > 1) ? n1 * n2 * BD_RECORD : 0;
    const int d1 = (n1 > 1) ? n2 * BD_RECORD : 0;
    const int d2 = (n2 > 1) ? BD_RECORD : 0;
#define BD_LANE_WEIGHTS(s, i) { \
        float fa = f0 s, fb = f1 s, fc = f2 s, ft; \
        int sa = d0, sb = d1, sc = d2, st; \
        if (fb > fa) { ft = fa; fa = fb; fb = ft; st = sa; sa = sb; sb = st; } \
        if (fc > fb) { ft = fb; fb = fc; fc = ft; st = sb; sb = sc; sc = st; } \
        if (fb > fa) { ft = fa; fa = fb; fb = ft; st = sa; sa = sb; sb = st; } \
        __global const float *t0 = table + node s; \
        __global const float *t1 = t0 + sa; \
        __global const float *t2 = t1 + sb; \
        __global const float *t3 = t2 + sc; \
        const float w0 = 1.0f - fa, w1 = fa - fb, w2 = fb - fc, w3 = fc; \
        for (int q = 0; q < BD_RECORD; q += BD_CHUNK) \
            CHUNK_STORE(w0 * CHUNK_LOAD(0, t0 + q) + w1 * CHUNK_LOAD(0, t1 + q) \
                        + w2 * CHUNK_LOAD(0, t2 + q) + w3 * CHUNK_LOAD(0, t3 + q), 0, \
                        wl + (i) * BD_RECORD + q); \
    }
    FOR_LANES(BD_LANE_WEIGHTS)
#undef BD_LANE_WEIGHTS
}

// the irradiance summed over the cells of near class (a, b) (cells (+-a, +-b), each once)
// around the texels at e, rows `pitch` floats apart
inline vec class_sum(__global const float *e, const int pitch, const int a, const int b)
{
#define BD_CELL(dy, dx) GLOAD(0, e + (dy) * pitch + (dx))
    vec s = BD_CELL(a, b);
    if (a) s += BD_CELL(-a, b);
    if (b) {
        s += BD_CELL(a, -b);
        if (a) s += BD_CELL(-a, -b);
    }
#undef BD_CELL
    return s;
}

// out[y * w + x] = settled(rd (sum_j w_j planes[j][row0 + y][x0 + x] + sum_ab w_ab S_ab))
// for the texels (x, y) .. (x + BD_WIDTH - 1, y) of rows row0.. of a band w texels wide, S_ab
// the irradiance summed over near class (a, b): the planes `plane` floats apart with rows
// `pitch` floats apart; e: the band's irradiance padded by x0 texels on every side, rows
// `epitch` floats apart; the maps rd, lu, lv w texels a row, the band's row y at their row
// mrow + y; table: (n0, n1, n2) records of BD_RECORD floats
__kernel void gather_stretched(__global const float *rd, __global const float *lu,
                               __global const float *lv, __global const float *table,
                               __global const float *planes, __global const float *e,
                               __global float *out,
                               const int w, const int pitch, const int plane,
                               const int epitch, const int x0, const int row0, const int mrow,
                               const float scale, const int nonneg, BD_LATTICE_ARGS)
{
    const int x = first_texel(get_global_id(0), w), y = get_global_id(1);
    const size_t p = (size_t)y * w + x, m = (size_t)(y + mrow) * w + x;
    const vec r = GLOAD(0, rd + m);
    float wl[BD_WIDTH * BD_RECORD];
    texel_weights(table, r, GLOAD(0, lu + m), GLOAD(0, lv + m), wl, BD_LATTICE);
    __global const float *blurred = planes + (size_t)(y + row0) * pitch + x0 + x;
    vec sum = (vec)0.0f;
    for (int j = 0; j < BD_NBASIS; ++j)
        sum += texel_weight(wl, BD_RECORD, j) * GLOAD(0, blurred + (size_t)j * plane);
#if BD_NEAR >= 0
    __global const float *here = e + (size_t)(y + row0 + x0) * epitch + x0 + x;
    int k = BD_NBASIS;
    for (int a = 0; a <= BD_NEAR; ++a)
        for (int b = 0; b <= BD_NEAR; ++b, ++k)
            sum += texel_weight(wl, BD_RECORD, k) * class_sum(here, epitch, a, b);
#endif
    GSTORE(settle(r * sum, r, scale, nonneg), 0, out + p);
}
