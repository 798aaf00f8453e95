/* safeguard_ratio.cl: the sampler's convergence, measured over the frame, for the safeguard
 * (kernels/safeguard.cl; clrecon/methods/safeguard.py has the derivation, and
 * clrecon/methods/safeguard_reference.py: variance_scale the NumPy reference).
 *
 *   safeguard_blur        one work-item per pixel: the smallest blur of its samples,
 *                         min over them of max(|c0 / z + c1|, |motion|) (CoC radius and
 *                         motion length, px; a non-finite value counts as 0)
 *   safeguard_ratio_rows  one work-item per row: the row's sums of S vb and dq, and with
 *                         spatial = 1 of vb and of L over the row's blurred pixels (below)
 *   safeguard_ratio       one work-item: the frame's factor of the halves' variances
 * Arguments: stats, the five planes of safeguard_stats written with quarters = 1 (pitch sp,
 * pixel x at column x + 3); box, m (H, W, 3) as safeguard_stats left them and blur (H, W)
 * (read with spatial = 1 only); partial (H, 5) floats; scale (1 float), what
 * safeguard_rows reads as vscale. Preconditions: spp >= 16 (each quarter holds >= 4
 * samples).
 *
 * Blurred pixels (spatial = 1, a method's image m given): where every sample of a pixel
 * and of its 8 neighbours is blurred by BLUR_MIN px or more, the true image is smooth at
 * the pixel's scale and m follows it, so the 5-point Laplacian of r = box - m is box's
 * noise, independent from pixel to pixel (each pixel's samples are its own):
 * L = |lap r|^2 / 20 estimates the frame's variance of box there, whatever the sampler,
 * where vb (halves, as if independent) overstates it for stratified samples. The factor is
 * then (sum_blurred L + s sum_other vb) / sum vb: the blurred pixels' variance measured,
 * the others' scaled by the quarters' s (the frame's variance, summed, over the halves').
 */
#include "common.h"

/* 2^n for n <= 0 (a scalar), flushed to 0 below float32's normal range */
inline float pow2_nonpos_s(const int n)
{
    return n >= -126 ? as_float((n + 127) << 23) : 0.0f;
}

#define BLUR_MIN 2.0f  /* px: a pixel's samples blurred at least this much (see above) */

__kernel void safeguard_blur(__global const float *depth, __global const float *motion,
                             int has_motion, int npix, int spp, float c0, float c1,
                             __global float *blur)
{
    const int p = get_global_id(0);
    if (p >= npix)
        return;
    float b = INFINITY;
    for (int i = 0; i < spp; ++i) {
        const size_t s = (size_t)p * spp + i;
        float r = fabs(c0 / depth[s] + c1);
        if (has_motion) {
            const float2 v = vload2(s, motion);
            r = fmax(r, sqrt(v.x * v.x + v.y * v.y));
        }
        b = fmin(b, isfinite(r) ? r : 0.0f);
    }
    blur[p] = b;
}

/* r = box - m at pixel i, in units of 2^e */
inline float3 residual(__global const float *box, __global const float *m, int i, float sc)
{
    return (vload3(i, box) - vload3(i, m)) * sc;
}

/* The sampler's convergence, measured: one work-item per row sums the row's S vb (the
 * halves' squared difference per unit of 1/ha + 1/hb) and dq (the quarters', per unit of
 * theirs) in units of the row's largest exponent: partial[3 y ..] = (sum S vb, sum dq, e).
 * Independent samples give both the same expectation (the samples' variance); stratified
 * ones converge faster than 1/n, so the halves agree better than the quarters. */
__kernel void safeguard_ratio_rows(__global const float *stats, __global float *partial,
                                   int width, int height, int sp, int spp,
                                   __global const float *box, __global const float *m,
                                   __global const float *blur, int spatial)
{
    const int y = get_global_id(0);
    if (y >= height)
        return;
    const size_t plane = (size_t)sp * height;
    const __global float *base = stats + (size_t)y * sp + 3;  /* pixel 0 of the row */
    const __global float *vb = base + plane, *ep = base + 3 * plane, *dq = base + 4 * plane;
    int emax = INT_MIN;
    for (int x = 0; x < width; ++x)
        emax = max(emax, (int)ep[x]);
    float sh = 0.0f, sq = 0.0f, sbv = 0.0f, sl = 0.0f;
    const int inner = spatial && y >= 1 && y < height - 1;
    for (int x = 0; x < width; ++x) {
        const float f = pow2_nonpos_s(2 * ((int)ep[x] - emax));
        sh += f * vb[x];
        sq += f * dq[x];
        if (!inner || x < 1 || x >= width - 1)
            continue;
        float bmin = INFINITY;
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
                bmin = fmin(bmin, blur[(y + dy) * width + x + dx]);
        if (!(bmin >= BLUR_MIN))
            continue;
        /* the Laplacian of box - m in the pixel's units (its statistics' exponent) */
        const int p = y * width + x;
        const float sc = ldexp(1.0f, -(int)ep[x]);
        const float3 lap = 4.0f * residual(box, m, p, sc) - residual(box, m, p - 1, sc)
                           - residual(box, m, p + 1, sc) - residual(box, m, p - width, sc)
                           - residual(box, m, p + width, sc);
        const float l = (lap.x * lap.x + lap.y * lap.y + lap.z * lap.z) * (1.0f / 60.0f);
        if (!isfinite(l))
            continue;   /* a neighbour 2^64 times brighter: left to the quarters */
        sbv += f * vb[x];
        sl += f * l;
    }
    partial[5 * y] = (float)spp * sh;
    partial[5 * y + 1] = sq;
    partial[5 * y + 2] = sbv;
    partial[5 * y + 3] = sl;
    partial[5 * y + 4] = (float)emax;
}

/* One work-item: the rows' sums combined in units of the frame's largest exponent;
 * s = clamp(sum S vb / sum dq, 0, 1) (1 where the quarters show no spread or the sums are
 * not finite), and scale[0], the factor of every variance the halves estimate: s, or with
 * blurred pixels clamp((sum_blurred L + s (sum vb - sum_blurred vb)) / sum vb, 0, 1). */
__kernel void safeguard_ratio(__global const float *partial, int height, int spp,
                              __global float *scale)
{
    if (get_global_id(0) != 0)
        return;
    int emax = INT_MIN;
    for (int y = 0; y < height; ++y)
        emax = max(emax, (int)partial[5 * y + 4]);
    float sh = 0.0f, sq = 0.0f, sbv = 0.0f, sl = 0.0f;
    for (int y = 0; y < height; ++y) {
        const float f = pow2_nonpos_s(2 * ((int)partial[5 * y + 4] - emax));
        sh += f * partial[5 * y];
        sq += f * partial[5 * y + 1];
        sbv += f * partial[5 * y + 2];
        sl += f * partial[5 * y + 3];
    }
    const float r = sh / sq;
    const float s = (sq > 0.0f && isfinite(r)) ? clamp(r, 0.0f, 1.0f) : 1.0f;
    const float tot = sh / (float)spp;   /* sum vb */
    const float g = (sl + s * (tot - sbv)) / tot;
    scale[0] = (sbv > 0.0f && tot > 0.0f && isfinite(g)) ? clamp(g, 0.0f, 1.0f) : s;
}
