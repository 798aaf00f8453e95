/* layered.h: definitions shared by the passes of method `layered` (Hasselgren et al. 2015):
 * the depth-bucket function, the per-partition parameter layout, the filtered images' layout,
 * Morton order and xorshift.
 *
 * Depth buckets (NBUCKETS, default 32): bucket NBUCKETS-1 holds misses (depth >= 1e30); a hit
 * at depth w goes to clamp(floor(ka / w + kb * w - kc), 0, NBUCKETS-2). With
 * ka = -|c0| / (bw f) and kb = 1 / (dz f) a bucket spans at most bw f pixels of CoC and at
 * most dz f of depth: evenly spaced in CoC near the focus plane, where the CoC term varies
 * fastest, and uniform in depth beyond (the host picks bw, dz and the stretch f >= 1 so the
 * frame's depth range fits; clrecon/methods/layered/layout.py: bucket_params).
 *
 * Partition parameters: NPAR floats per (tile, slot), slot-major within a tile:
 *   P_COUNT  samples seen by tile_stats (0: empty slot; slots fill from 0, front to back)
 *   P_LO, P_HI     bucket range [lo, hi] (buckets of a tile are covered without gaps)
 *   P_A            mean signed CoC: x' = x - A * lens - (t - 0.5) * b   (eq. 1)
 *   P_BX, P_BY     mean motion b (pixels over the shutter)
 *   P_SU, P_SV, P_COS, P_SIN   rotated Gaussian, full-resolution pixels, u along the motion
 *   P_SHU, P_SHV, P_BETA, P_GAMMA  sheared form (eq. 9) in grid pixels: recursive std,
 *                  Gaussian std, shear, eq. 10's gamma (informative; filter_sheared solves
 *                  its own); along the axes chosen by P_AXIS
 *   P_SCALE        grid spacing s (power of two, full-res pixels per grid pixel)
 *   P_GUARD        guard band G in grid pixels; the grid of the slot is D x D, D = T/s + 2G
 *   P_REACH        how far (full-res px) outside the tile samples are gathered from
 *   P_DIM          D
 *   P_AXIS         0: recursive along x, Gaussian along (beta, 1) (eq. 9); 1: transposed,
 *                  recursive along y, Gaussian along (1, beta) (when S_xx > S_yy)
 * Grid pixel (i, j) of a slot is centred at full-res (x0 + (i - G + 0.5) s, ...), (x0, y0)
 * the tile corner. Grids are planar: NCH channels (r, g, b own weight w, behind weight)
 * of DMAX x DMAX floats, DMAX = TILE + 2 * GMAX. Filtered images (the filters' output,
 * composite's input): NCH planes of FT x FT floats per slot, filtered pixel (i, j) in
 * [-1, T/s]^2 at (j + 1) FT + (i + 1) (layered_filtered_item, layered_filtered_at).
 */
#include "limits.h"
#ifndef CLRECON_LAYERED_H
#define CLRECON_LAYERED_H

#pragma OPENCL FP_CONTRACT OFF

#ifndef NBUCKETS
#define NBUCKETS 32
#endif
#ifndef TILE
#define TILE 32
#endif
#ifndef MAXP
#define MAXP 4
#endif
#ifndef GMAX
#define GMAX 16
#endif
#ifndef HAS_MOTION
#define HAS_MOTION 1
#endif

#define NSTAT 8   /* n, sum coc, sum coc^2, sum mx, sum my, sum mx^2, sum my^2, sum mx*my */
#define NPAR 20
#define NCH 5
#define DMAX (TILE + 2 * GMAX)
#define FT (TILE + 2)      /* filtered grid side: the tile in grid pixels plus a 1-px border */

enum { P_COUNT, P_LO, P_HI, P_A, P_BX, P_BY, P_SU, P_SV, P_COS, P_SIN, P_SHU, P_SHV, P_BETA,
       P_GAMMA, P_SCALE, P_GUARD, P_REACH, P_DIM, P_AXIS };

/* The start of every kernel that writes a slot's filtered pixels, over the range
 * (ceil(FT / lanes), FT, tiles * MAXP), `lanes` pixels (i .. i + lanes - 1, j) a work-item:
 * sets the work-item's first pixel (*i, *j) and *slot, and returns the slot's parameters, or
 * 0 where the slot is empty or (*i, *j) lies outside its [-1, T/s]^2 (nothing to do). */
__attribute__((always_inline)) inline __global const float *layered_filtered_item(
    __global const float *params, int lanes, int *i, int *j, int *slot)
{
    *i = lanes * (int)get_global_id(0) - 1;
    *j = (int)get_global_id(1) - 1;
    *slot = (int)get_global_id(2);
    __global const float *p = params + (size_t)*slot * NPAR;
    if (p[P_DIM] == 0.0f)
        return 0;
    const int side = TILE / (int)p[P_SCALE];
    return *i > side || *j > side ? 0 : p;
}

/* Filtered pixel (i, j) of a slot, channel 0 (channel c is c FT^2 further on). */
__attribute__((always_inline)) inline __global float *layered_filtered_at(
    __global float *filtered, int slot, int i, int j)
{
    return filtered + (size_t)slot * NCH * FT * FT + (j + 1) * FT + (i + 1);
}

/* acc[c] / n into every channel of filtered pixel (i, j) of a slot. */
__attribute__((always_inline)) inline void layered_store_filtered(
    __global float *filtered, int slot, int i, int j, const float *acc, float n)
{
    __global float *out = layered_filtered_at(filtered, slot, i, j);
    for (int c = 0; c < NCH; ++c)
        out[c * FT * FT] = acc[c] / n;
}

inline int layered_bucket(float w, float ka, float kb, float kc)
{
    if (!(w < MISS_DEPTH))
        return NBUCKETS - 1;
    float l = ka / w;
    l = l + kb * w;
    l = l - kc;
    l = clamp(floor(l), 0.0f, (float)(NBUCKETS - 2));
    return (int)l;
}

/* Bits 0, 2, 4, ... of m (x of a Morton index). */
inline uint morton_even(uint m)
{
    m &= 0x55555555u;
    m = (m | (m >> 1)) & 0x33333333u;
    m = (m | (m >> 2)) & 0x0f0f0f0fu;
    m = (m | (m >> 4)) & 0x00ff00ffu;
    m = (m | (m >> 8)) & 0x0000ffffu;
    return m;
}

inline uint xorshift32(uint *state)
{
    uint x = *state;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    *state = x;
    return x;
}

#endif /* CLRECON_LAYERED_H */
