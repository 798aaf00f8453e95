/* filter_sheared.cl: the rotated Gaussian of each partition as a sheared one (eq. 9; Hasselgren
 * et al. 2015, section 6.2): a recursive filter along x (eq. 10, forward then backward) and a
 * Gaussian along the sheared axis (beta, 1), per tile with its guard band.
 *
 * filter_sheared_x: one work-item per (grid row, slot), range (DMAX, tiles * MAXP); rows of
 *   empty slots and rows >= D return. In place on every channel of the row:
 *   forward  y[i] = (1 - gamma) x[i] + gamma y[i - 1]  (y[-1] = 0), then the same backward.
 *   Forward-backward has variance 2 gamma / (1 - gamma)^2; gamma is solved for variance
 *   s_u^2 / RECURSIONS (eq. 10's exp(-sqrt2 / s_u) is its large-sigma limit). RECURSIONS > 1
 *   repeats the pair: closer to a Gaussian than eq. 10's single pair.
 * filter_sheared_y: one work-item per filtered pixel (i, j) in [-1, T/s]^2 of a slot, range
 *   (FT, FT, tiles * MAXP): out = sum_k exp(-k^2 / (2 s_v^2)) grid(i + G + beta k, j + G + k),
 *   k = -ceil(3 s_v) .. ceil(3 s_v), linear interpolation along x, taps outside the grid
 *   dropped. Unnormalised: composite divides channels by each other.
 *   grids     float (tiles, MAXP, NCH, DMAX, DMAX), row stride D (reproject's layout)
 *   filtered  float (tiles, MAXP, NCH, FT, FT), index (j + 1) * FT + (i + 1)
 * Compile-time: TILE, MAXP, GMAX, RECURSIONS. Tunables: WG_X, WG_Y (local size of
 * filter_sheared_y).
 */
#include "layered.h"

#ifndef WG_X
#define WG_X 8
#endif
#ifndef RECURSIONS
#define RECURSIONS 1  /* forward-backward passes along x (1: the paper's eq. 10) */
#endif
#ifndef WG_Y
#define WG_Y 8
#endif

/* gamma whose forward-backward pair has variance v exactly: 2 g / (1 - g)^2 = v. For large
 * v this is eq. 10's exp(-sqrt(2 / v)); for small v (in-focus, sigma ~ 0.33 px) eq. 10's
 * gamma gives a far narrower filter than asked for. */
inline float recursive_gamma(float v)
{
    return v > 1e-6f ? ((v + 1.0f) - sqrt(2.0f * v + 1.0f)) / v : 0.0f;
}

__kernel void filter_sheared_x(__global const float *params, __global float *grids)
{
    const int row = get_global_id(0), slot = get_global_id(1);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (row >= dim)
        return;
    /* RECURSIONS forward-backward passes of sigma s_u / sqrt(RECURSIONS) each */
    const float gm = recursive_gamma(p[P_SHU] * p[P_SHU] / RECURSIONS);
    const float a = 1.0f - gm;
    for (int c = 0; c < NCH; ++c) {
        __global float *r = grids + ((size_t)slot * NCH + c) * DMAX * DMAX + row * dim;
        for (int n = 0; n < RECURSIONS; ++n) {
            float y = 0.0f;
            for (int i = 0; i < dim; ++i) {
                y = a * r[i] + gm * y;
                r[i] = y;
            }
            y = 0.0f;
            for (int i = dim - 1; i >= 0; --i) {
                y = a * r[i] + gm * y;
                r[i] = y;
            }
        }
    }
}

__kernel void filter_sheared_y(__global const float *params, __global const float *grids,
                               __global float *filtered)
{
    const int i = get_global_id(0) - 1, j = get_global_id(1) - 1, slot = get_global_id(2);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (dim == 0)
        return;
    const int side = TILE / (int)p[P_SCALE];
    if (i > side || j > side)
        return;
    const int g = (int)p[P_GUARD];
    const float sv = p[P_SHV], beta = p[P_BETA];
    const int kmax = min((int)ceil(3.0f * sv), dim);
    const float inv = -0.5f / (sv * sv);
    float acc[NCH] = {0.0f};
    __global const float *grid = grids + (size_t)slot * NCH * DMAX * DMAX;
    for (int k = -kmax; k <= kmax; ++k) {
        const int y = j + g + k;
        if (y < 0 || y >= dim)
            continue;
        const float xf = (float)(i + g) + beta * (float)k;
        const float fx = floor(xf);
        const float f = xf - fx;
        const int x = (int)fx;
        if (x < -1 || x >= dim)
            continue;
        const float wk = exp(inv * (float)(k * k));
        const float w0 = x >= 0 ? wk * (1.0f - f) : 0.0f;
        const float w1 = x + 1 < dim ? wk * f : 0.0f;
        for (int c = 0; c < NCH; ++c) {
            __global const float *r = grid + c * DMAX * DMAX + y * dim;
            acc[c] += (w0 != 0.0f ? w0 * r[x] : 0.0f) + (w1 != 0.0f ? w1 * r[x + 1] : 0.0f);
        }
    }
    __global float *out = filtered + (size_t)slot * NCH * FT * FT + (j + 1) * FT + (i + 1);
    for (int c = 0; c < NCH; ++c)
        out[c * FT * FT] = acc[c];
}
