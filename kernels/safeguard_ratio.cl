/* safeguard_ratio.cl: the sampler's convergence, measured over the frame, for the safeguard
 * (kernels/safeguard.cl; clrecon/methods/safeguard.py has the derivation, and
 * clrecon/methods/safeguard_reference.py: variance_scale the NumPy reference).
 *
 *   safeguard_ratio_rows  one work-item per row: the row's sums of S vb and dq
 *   safeguard_ratio       one work-item: the frame's factor of the halves' variances
 * Arguments: stats, the five planes of safeguard_stats written with quarters = 1 (pitch sp,
 * pixel x at column x + 3); partial (H, 3) floats; scale (1 float), what safeguard_rows
 * reads as vscale. Preconditions: spp >= 16 (each quarter holds >= 4 samples).
 */
#include "common.h"

/* 2^n for n <= 0 (a scalar), flushed to 0 below float32's normal range */
inline float pow2_nonpos_s(const int n)
{
    return n >= -126 ? as_float((n + 127) << 23) : 0.0f;
}

/* The sampler's convergence, measured: one work-item per row sums the row's S vb (the
 * halves' squared difference per unit of 1/ha + 1/hb) and dq (the quarters', per unit of
 * theirs) in units of the row's largest exponent: partial[3 y ..] = (sum S vb, sum dq, e).
 * Independent samples give both the same expectation (the samples' variance); stratified
 * ones converge faster than 1/n, so the halves agree better than the quarters. */
__kernel void safeguard_ratio_rows(__global const float *stats, __global float *partial,
                                   int width, int height, int sp, int spp)
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
    float sh = 0.0f, sq = 0.0f;
    for (int x = 0; x < width; ++x) {
        const float f = pow2_nonpos_s(2 * ((int)ep[x] - emax));
        sh += f * vb[x];
        sq += f * dq[x];
    }
    partial[3 * y] = (float)spp * sh;
    partial[3 * y + 1] = sq;
    partial[3 * y + 2] = (float)emax;
}

/* One work-item: the rows' sums combined in units of the frame's largest exponent, and
 * scale[0] = clamp(sum S vb / sum dq, 0, 1), the factor of every variance the halves
 * estimate (1 where the quarters show no spread or the sums are not finite). */
__kernel void safeguard_ratio(__global const float *partial, int height,
                              __global float *scale)
{
    if (get_global_id(0) != 0)
        return;
    int emax = INT_MIN;
    for (int y = 0; y < height; ++y)
        emax = max(emax, (int)partial[3 * y + 2]);
    float sh = 0.0f, sq = 0.0f;
    for (int y = 0; y < height; ++y) {
        const float f = pow2_nonpos_s(2 * ((int)partial[3 * y + 2] - emax));
        sh += f * partial[3 * y];
        sq += f * partial[3 * y + 1];
    }
    const float r = sh / sq;
    scale[0] = (sq > 0.0f && isfinite(r)) ? clamp(r, 0.0f, 1.0f) : 1.0f;
}
