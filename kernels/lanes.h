// lanes.h -- explicit vector lanes for kernels that take BD_WIDTH elements a work-item
// (kernels/invert_table.cl, kernels/blur_textured.cl): CPU runtimes compile vector types to
// SIMD directly, where they may vectorise a scalar kernel across work-items poorly or not at
// all (PoCL leaves it scalar; Intel's runtime does well with some kernels, not others: the
// widths are measured per kernel and runtime). Prepended to every kernel after bdipole.h
// (bdipole_cl/device/programs.py); empty unless BD_WIDTH is defined.
//   vec, ivec           float and int lanes (scalars at width 1)
//   VLOAD, VSTORE       vloadN / vstoreN (a plain element at width 1)
//   GLOAD, GSTORE       the same from and to __global memory, as one vector access (PoCL
//                       compiles vloadN and vstoreN to N element accesses: the blur gather
//                       took 1.6x as long with them there); GLOADN(N, i, p) for N floats
//                       (defined at widths 2 and up, with clang: else use vloadN)
//   TO_INT, TO_FLOAT    lane-wise conversions
//   AS_INT, AS_FLOAT    lane-wise bit casts (as_intN, as_floatN)
//   ANY_LANE(test)      whether any lane's test holds
//   BD_LANES            the lane numbers 0 .. BD_WIDTH - 1 (ivec; widths 2 and up)
//   FOR_LANES(M)        M(.sK, K) for each lane K (M(, 0) at width 1): per-lane code

#ifdef BD_WIDTH

#if BD_WIDTH == 1
typedef float vec;
typedef int ivec;
#define VLOAD(i, p) ((p)[i])
#define VSTORE(v, i, p) ((p)[i] = (v))
#define TO_INT(v) ((int)(v))
#define TO_FLOAT(v) ((float)(v))
#define AS_INT(v) as_int(v)
#define AS_FLOAT(v) as_float(v)
#define ANY_LANE(test) (test)
#define FOR_LANES(M) M(, 0)
#else
#define BD_CAT_(a, b) a##b
#define BD_CAT(a, b) BD_CAT_(a, b)
typedef BD_CAT(float, BD_WIDTH) vec;
typedef BD_CAT(int, BD_WIDTH) ivec;
#define VLOAD(i, p) BD_CAT(vload, BD_WIDTH)(i, p)
#define VSTORE(v, i, p) BD_CAT(vstore, BD_WIDTH)(v, i, p)
#define TO_INT(v) BD_CAT(convert_int, BD_WIDTH)(v)
#define TO_FLOAT(v) BD_CAT(convert_float, BD_WIDTH)(v)
#define AS_INT(v) BD_CAT(as_int, BD_WIDTH)(v)
#define AS_FLOAT(v) BD_CAT(as_float, BD_WIDTH)(v)
#define ANY_LANE(test) any(test)
#endif

#if BD_WIDTH > 1 && defined(__clang__)
// vectors of N floats aligned as a float: a pointer to one may point anywhere vloadN may read,
// and it is read as one unaligned vector (the vector type's own alignment would be assumed).
// GLOADN(N, i, p): vloadN(i, p) from __global memory so (N: 2, 4, 8 or 16)
typedef float bd_float2_u __attribute__((ext_vector_type(2), aligned(4)));
typedef float bd_float4_u __attribute__((ext_vector_type(4), aligned(4)));
typedef float bd_float8_u __attribute__((ext_vector_type(8), aligned(4)));
typedef float bd_float16_u __attribute__((ext_vector_type(16), aligned(4)));
#define GLOADN(n, i, p) (((__global const BD_CAT(BD_CAT(bd_float, n), _u) *)(p))[i])
#define GLOAD(i, p) GLOADN(BD_WIDTH, i, p)
#define GSTORE(v, i, p) (((__global BD_CAT(BD_CAT(bd_float, BD_WIDTH), _u) *)(p))[i] = (v))
#else
#define GLOAD VLOAD
#define GSTORE VSTORE
#endif

#if BD_WIDTH == 2
#define BD_LANES (ivec)(0, 1)
#define FOR_LANES(M) M(.s0, 0) M(.s1, 1)
#elif BD_WIDTH == 4
#define BD_LANES (ivec)(0, 1, 2, 3)
#define FOR_LANES(M) M(.s0, 0) M(.s1, 1) M(.s2, 2) M(.s3, 3)
#elif BD_WIDTH == 8
#define BD_LANES (ivec)(0, 1, 2, 3, 4, 5, 6, 7)
#define FOR_LANES(M) M(.s0, 0) M(.s1, 1) M(.s2, 2) M(.s3, 3) M(.s4, 4) M(.s5, 5) M(.s6, 6) \
    M(.s7, 7)
#elif BD_WIDTH == 16
#define BD_LANES (ivec)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15)
#define FOR_LANES(M) M(.s0, 0) M(.s1, 1) M(.s2, 2) M(.s3, 3) M(.s4, 4) M(.s5, 5) M(.s6, 6) \
    M(.s7, 7) M(.s8, 8) M(.s9, 9) M(.sa, 10) M(.sb, 11) M(.sc, 12) M(.sd, 13) M(.se, 14) M(.sf, 15)
#elif BD_WIDTH != 1
#error "BD_WIDTH must be 1, 2, 4, 8 or 16"
#endif

#endif
