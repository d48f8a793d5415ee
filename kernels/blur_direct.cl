// blur_direct.cl -- M(x) = sum_cells E(cell) W(cell - x): a 2D gather with the texel-integrated
// Better Dipole weights of one channel (bdipole_cl/ops/blur/weights.py: channel_kernel). Needs bdipole.h
// in front; border mode by -DBD_BORDER_{CLAMP,ZERO,WRAP}.
//
// Work-groups of BD_TILE x BD_TILE outputs stage their (BD_TILE + 2K)^2 input footprint in local memory
// in chunks of BD_CHUNK rows of taps, so each input texel is read from global memory once per
// work-group and chunk instead of once per tap.

#ifndef BD_TILE
#define BD_TILE 16
#endif
#ifndef BD_CHUNK
#define BD_CHUNK 16
#endif

__kernel __attribute__((reqd_work_group_size(BD_TILE, BD_TILE, 1)))
void blur_direct(__global const float *src, __global float *dst, __global const float *weights,
                 const int width, const int height, const int nchan, const int channel,
                 const int radius)
{
    __local float tile[(BD_TILE + 2 * BD_CHUNK) * (BD_TILE + 2 * BD_CHUNK)];
    const int lx = get_local_id(0), ly = get_local_id(1);
    const int x = get_global_id(0), y = get_global_id(1);
    // launches may cover a band of rows (a global offset, a multiple of BD_TILE)
    const int x0 = get_group_id(0) * BD_TILE + (int)get_global_offset(0);
    const int y0 = get_group_id(1) * BD_TILE + (int)get_global_offset(1);
    const int side = 2 * radius + 1;
    const int span = BD_TILE + 2 * BD_CHUNK;
    float acc = 0.0f, comp = 0.0f;          // Neumaier sum: acc + comp is the running total
    // the (2K+1)^2 taps in blocks of (2 BD_CHUNK + 1)^2 centred offsets (cx, cy)
    for (int cy = -radius; cy <= radius; cy += 2 * BD_CHUNK + 1) {
        for (int cx = -radius; cx <= radius; cx += 2 * BD_CHUNK + 1) {
            // stage this block's inputs: rows y0 + cy + [0, span), columns x0 + cx + [0, span)
            barrier(CLK_LOCAL_MEM_FENCE);
            for (int j = ly; j < span; j += BD_TILE) {
                for (int i = lx; i < span; i += BD_TILE) {
                    int gy = bd_border(y0 + cy + j, height);
                    int gx = bd_border(x0 + cx + i, width);
                    tile[j * span + i] = (gx < 0 || gy < 0) ? 0.0f
                                         : src[((size_t)gy * width + gx) * nchan + channel];
                }
            }
            barrier(CLK_LOCAL_MEM_FENCE);
            for (int dy = 0; dy <= 2 * BD_CHUNK; ++dy) {
                int oy = cy + dy;                    // tap offset in y
                if (oy > radius) break;
                __global const float *wrow = weights + (oy + radius) * side + radius;
                __local const float *trow = tile + (ly + dy) * span + lx;
                float part = 0.0f;                   // this row of the block: <= 33 taps
                for (int dx = 0; dx <= 2 * BD_CHUNK; ++dx) {
                    int ox = cx + dx;
                    if (ox > radius) break;
                    part += wrow[ox] * trow[dx];
                }
                float t = acc + part;
                comp += (fabs(acc) >= fabs(part)) ? (acc - t) + part : (part - t) + acc;
                acc = t;
            }
        }
    }
    if (x < width && y < height) dst[((size_t)y * width + x) * nchan + channel] = acc + comp;
}
