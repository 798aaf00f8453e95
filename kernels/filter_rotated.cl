/* filter_rotated.cl: the LRDM baseline's screen-space filter (Munkberg et al. 2014, as
 * summarised by Hasselgren et al. 2015, section 6): the rotated Gaussian of each partition as
 * two 1D Gaussians along u = (cos, sin) and v = (-sin, cos), each tap a bilinear lookup.
 *
 * filter_rotated_u: one work-item per grid pixel (x, y) of a slot, range (DMAX, DMAX,
 *   tiles * MAXP): tmp(x, y) = sum_k exp(-k^2 / (2 (sigma_u/s)^2)) grid((x, y) + k u),
 *   k = -ceil(3 sigma_u / s) .. ceil(3 sigma_u / s); lookups outside the grid read 0.
 * filter_rotated_v: one work-item per filtered pixel (i, j) in [-1, T/s]^2, range (FT, FT,
 *   tiles * MAXP): out = sum_k exp(-k^2 / (2 (sigma_v/s)^2)) tmp((i + G, j + G) + k v).
 *   grids, tmp  float (tiles, MAXP, NCH, DMAX, DMAX), row stride D
 *   filtered    float (tiles, MAXP, NCH, FT, FT), index (j + 1) * FT + (i + 1)
 * Unnormalised (composite divides channels by each other). Compile-time: TILE, MAXP, GMAX.
 * The local size of both kernels is a launch parameter only (tuned).
 */
#include "layered.h"

/* Bilinear lookup of all channels at grid coordinate (x, y); outside reads 0. */
inline void rotated_tap(__global const float *g, int dim, float x, float y, float wk,
                        float *acc)
{
    const float fx = floor(x), fy = floor(y);
    const int ix = (int)fx, iy = (int)fy;
    if (ix < -1 || iy < -1 || ix >= dim || iy >= dim)
        return;
    const float ax = x - fx, ay = y - fy;
    float w[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    int o[4] = {0, 1, dim, dim + 1};
    const int inx[2] = {ix >= 0, ix + 1 < dim}, iny[2] = {iy >= 0, iy + 1 < dim};
    for (int q = 0; q < 4; ++q) {
        if (!(inx[q & 1] && iny[q >> 1]) || w[q] == 0.0f)
            continue;
        const int at = iy * dim + ix + o[q];
        for (int c = 0; c < NCH; ++c)
            acc[c] += wk * w[q] * g[c * DMAX * DMAX + at];
    }
}

__kernel void filter_rotated_u(__global const float *params, __global const float *grids,
                               __global float *tmp)
{
    const int x = get_global_id(0), y = get_global_id(1), slot = get_global_id(2);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (x >= dim || y >= dim)
        return;
    const float sig = p[P_SU] / p[P_SCALE];
    const float dx = p[P_COS], dy = p[P_SIN];
    const int kmax = min((int)ceil(3.0f * sig), dim);
    const float inv = -0.5f / (sig * sig);
    float acc[NCH] = {0.0f};
    __global const float *g = grids + (size_t)slot * NCH * DMAX * DMAX;
    for (int k = -kmax; k <= kmax; ++k)
        rotated_tap(g, dim, x + k * dx, y + k * dy, exp(inv * (float)(k * k)), acc);
    __global float *o = tmp + (size_t)slot * NCH * DMAX * DMAX + y * dim + x;
    for (int c = 0; c < NCH; ++c)
        o[c * DMAX * DMAX] = acc[c];
}

__kernel void filter_rotated_v(__global const float *params, __global const float *tmp,
                               __global float *filtered)
{
    int i, j, slot;
    __global const float *p = layered_filtered_item(params, 1, &i, &j, &slot);
    if (!p)
        return;
    const int dim = (int)p[P_DIM];
    const float g0 = p[P_GUARD];
    const float sig = p[P_SV] / p[P_SCALE];
    const float dx = -p[P_SIN], dy = p[P_COS];
    const int kmax = min((int)ceil(3.0f * sig), dim);
    const float inv = -0.5f / (sig * sig);
    float acc[NCH] = {0.0f};
    __global const float *g = tmp + (size_t)slot * NCH * DMAX * DMAX;
    for (int k = -kmax; k <= kmax; ++k)
        rotated_tap(g, dim, i + g0 + k * dx, j + g0 + k * dy, exp(inv * (float)(k * k)), acc);
    layered_store_filtered(filtered, slot, i, j, acc, 1.0f);
}
