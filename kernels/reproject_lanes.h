/* reproject_lanes.h: how reproject.cl reads VW samples of a pixel at once (CPU compilers map
 * floatVW onto SIMD registers).
 *
 *   VW, floatv, intv, VLOAD.. the lane width (SPP's largest factor among 8 and 4; 1 otherwise)
 *                            and its vector types and loads; COLOR_LANES the lanes' colours
 *   LANE_IDS, LANE_BITS      the lanes' indices and bits, as intv
 *   lane_bits(m), lane_mask  bit j set where lane j of mask m is set, and back (VW > 1)
 *   LANE_CELLS(...)          the lanes' grid cells, a lane not in a mask sent to a spare one
 *   bucket_lanes(w, ...)     layered_bucket of VW depths, as float (VW > 1)
 *   reproject_lanes(...)     the depth buckets and grid positions of VW samples (below)
 *   row_hash(cy, sub)        which pixel of each sub x sub block of a block row is read
 * Include after SPP is defined (reproject.cl's defaults); needs layered.h.
 */
#ifndef CLRECON_REPROJECT_LANES_H
#define CLRECON_REPROJECT_LANES_H

#include "layered.h"

#ifndef SPP
#error "reproject_lanes.h: define SPP first"
#endif

/* VW consecutive samples of a pixel in one vector: SPP's largest factor among 8 and 4 (CPU
 * compilers map floatVW onto SIMD registers; VW = 1 otherwise). Each lane computes exactly
 * the scalar expression (FP_CONTRACT is off in layered.h), so every width gives the same
 * grids. Writes per lane the depth bucket (as float, from `buckets`) and the grid position;
 * returns 0 without reading position, lens and time when every lane is in front of the slot
 * (bucket < lo). */
#if SPP % 8 == 0
#define VW 8
#elif SPP % 4 == 0
#define VW 4
#else
#define VW 1
#endif

#if VW == 8
typedef float8 floatv;
typedef int8 intv;
#define VLOAD vload8
#define CONVERT_INTV convert_int8
#define VSTORE vstore8
#define VLOAD2 vload16
#define CONVERT_FLOATV convert_float8
#define CONVERT_UCHARV convert_uchar8
#define LANE_IDS ((intv)(0, 1, 2, 3, 4, 5, 6, 7))
#define LANE_BITS ((intv)(1, 2, 4, 8, 16, 32, 64, 128))
/* COLOR_LANES(dst, src): the 3 VW floats of VW samples' colours from src into dst */
#define COLOR_LANES(dst, src) \
    (vstore16(vload16(0, (src)), 0, (dst)), vstore8(vload8(0, (src) + 16), 0, (dst) + 16))
#elif VW == 4
typedef float4 floatv;
typedef int4 intv;
#define VLOAD vload4
#define CONVERT_INTV convert_int4
#define VSTORE vstore4
#define VLOAD2 vload8
#define CONVERT_FLOATV convert_float4
#define CONVERT_UCHARV convert_uchar4
#define LANE_IDS ((intv)(0, 1, 2, 3))
#define LANE_BITS ((intv)(1, 2, 4, 8))
#define COLOR_LANES(dst, src) \
    (vstore8(vload8(0, (src)), 0, (dst)), vstore4(vload4(0, (src) + 8), 0, (dst) + 8))
#endif

#if VW > 1
/* Bit j set where lane j of mask m is (all ones). */
inline uint lane_bits(intv m)
{
#if VW == 8
    const intv b = m & LANE_BITS;
    const int4 h = b.lo | b.hi;
#else
    const int4 h = m & LANE_BITS;
#endif
    const int2 q = h.lo | h.hi;
    return (uint)(q.x | q.y);
}

/* Lane j of the mask (all ones) where bit j of bits is set: lane_bits's inverse. */
inline intv lane_mask(uint bits)
{
    return ((intv)((int)bits) & LANE_BITS) != (intv)(0);
}

/* LANE_CELLS(dst, iv, m, spare): lane j of the cells iv (intv) into dst[j] where bit j of m
 * is set, else its spare cell spare + j */
#define LANE_CELLS(dst, iv, m, spare) \
    VSTORE(select((intv)(spare) + LANE_IDS, (iv), lane_mask(m)), 0, (dst))

/* layered_bucket of VW depths, as float (the scalar expression in every lane) */
inline floatv bucket_lanes(floatv w, float ka, float kb, float kc)
{
    floatv l = ka / w;
    l = l + kb * w;
    l = l - kc;
    l = clamp(floor(l), 0.0f, (float)(NBUCKETS - 2));
    /* misses and NaN: the last bucket, as layered_bucket */
    return select((floatv)(NBUCKETS - 1), l, isless(w, (floatv)(MISS_DEPTH)));
}
#endif

/* Hash of block row cy for blocks of side sub: it picks the row and column offset of the
 * pixel read from every block of that row. */
inline uint row_hash(int cy, int sub)
{
    uint h = ((uint)cy * 0xd8163841u) ^ ((uint)sub * 0xcb1ab31fu);
    h ^= h >> 13;
    h *= 0x85ebca6bu;
    h ^= h >> 16;
    return h;
}

inline int reproject_lanes(size_t s0, size_t k0, __global const float *position,
                           __global const uchar *buckets, __global const float *lens,
                           __global const float *time, int lo, float A, float2 bm, int x0,
                           int y0, float inv_s, float g, float *gx, float *gy, float *bk)
{
#if VW == 1
    bk[0] = (float)buckets[k0];
    if (bk[0] < (float)lo)
        return 0;
    float2 q = vload2(s0, position) - A * vload2(s0, lens);
#if HAS_MOTION
    q -= (time[s0] - 0.5f) * bm;
#endif
    gx[0] = (q.x - x0) * inv_s + g;
    gy[0] = (q.y - y0) * inv_s + g;
    return 1;
#else
    const floatv b = CONVERT_FLOATV(VLOAD(0, buckets + k0));
    VSTORE(b, 0, bk);
    /* every sample in front of the slot: skip the other fields' reads */
    if (!any(isgreaterequal(b, (floatv)((float)lo))))
        return 0;
#if VW == 8
    const float16 pp = VLOAD2(0, position + 2 * s0), ll = VLOAD2(0, lens + 2 * s0);
#else
    const float8 pp = VLOAD2(0, position + 2 * s0), ll = VLOAD2(0, lens + 2 * s0);
#endif
    floatv qx = pp.even - A * ll.even, qy = pp.odd - A * ll.odd;
#if HAS_MOTION
    const floatv dt = VLOAD(0, time + s0) - 0.5f;
    qx -= dt * bm.x;
    qy -= dt * bm.y;
#endif
    VSTORE((qx - (float)x0) * inv_s + g, 0, gx);
    VSTORE((qy - (float)y0) * inv_s + g, 0, gy);
    return 1;
#endif
}

#endif /* CLRECON_REPROJECT_LANES_H */
