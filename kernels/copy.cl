// copy.cl -- a plain copy: the memory-bound floor that per-texel kernels are compared with.
// Needs bdipole.h in front (for `real`).

__kernel void copy(__global const real *src, __global real *dst, const ulong n)
{
    ulong i = get_global_id(0);
    if (i < n) dst[i] = src[i];
}
