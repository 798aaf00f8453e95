/* safeguard_fdr.cl: the 7x7 bias mean judged against the frame's own pixels, for the
 * safeguard's blend (kernels/safeguard.cl; clrecon/methods/safeguard_reference.py:
 * fdr_threshold and fdr_shrink_table the NumPy references; the derivation in
 * clrecon/methods/safeguard.py and safeguard_passes.py).
 *
 *   safeguard_fdr_rows    one work-item per image row: each pixel's 7x7 bias mean over its
 *                         standard error, |z| = |mu7| / se7, counted into the row's
 *                         histogram of 2 FDR_BINS bins of width 1 / FDR_SCALE (|z| >=
 *                         FDR_BINS / FDR_SCALE in the last of each half): the first half
 *                         the pixels with mu7 > 0, the second those with mu7 < 0
 *                         (noisy_only = 1: only the windows where box shows noise)
 *   safeguard_fdr_sum     one work-item a column: the rows' histograms summed into the
 *                         first row (the two kernels below read only that row)
 *   safeguard_fdr         one work-item: from the positive half of the totals, z[0] = the
 *                         lowest bin edge t with npix * Q(t) <= q * R(t), R(t) the pixels
 *                         with z >= t and Q the normal's upper tail (Benjamini-Hochberg at
 *                         level q, to the bins' resolution); FDR_BINS / FDR_SCALE where no
 *                         edge passes (the guided chain's test)
 *   safeguard_fdr_shrink  one work-item: from the totals, each bin's factor
 *                         table[j] = 1 - min over i <= j of min(1, N(t_i) / R(t_i)),
 *                         R(t) the pixels with mu7 > 0 and |z| >= t, N(t) the count a
 *                         normal null expects there: the frame's false discovery rate as a
 *                         q-value, its null read off the frame itself (Efron's empirical
 *                         null: a normal matched to the histogram's central peak; a peak
 *                         above 0 is the biased pixels', and the null then N(0, 1)). A
 *                         mean is positive or negative by noise alone
 *                         and positive by a bias as well; where the halves misstate the
 *                         variance, the noise's means are centred off 0 and spread wider or
 *                         narrower than z's unit, which the peak's place and width measure.
 *                         The blend scales a positive mu7 by its bin's factor
 * Arguments: rows, the nine row-segment planes of safeguard_rows (pitch rp, a multiple of
 * SG_VW: kernels/safeguard_vec.h, the host's vector width); hist (H, 2 FDR_BINS) ints; z
 * (1 float), what safeguard_blend reads with fdr = 1; table (FDR_BINS floats), what it
 * reads with fdr = 2.
 * The windows' sums are those of safeguard_blend (the same units, the same order of the
 * additions), so a pixel's z is the blend's mu7 / se7.
 */
#include "common.h"
#include "safeguard_vec.h"

#ifndef FDR_MODE_RADIUS
#define FDR_MODE_RADIUS 8   /* the peak's smoothing: a triangle of +-8 bins (+-0.25 in z) */
#endif

/* SG_VW pixels x0 .. x0 + SG_VW - 1 at a time (the rows' pitch is a multiple of SG_VW; lanes
 * past the width read the row's padding and are not counted) */
__kernel void safeguard_fdr_rows(__global const float *rows, __global int *hist, int width,
                                 int height, int rp, int noisy_only)
{
    const int y = get_global_id(0);
    if (y >= height)
        return;
    __global int *h = hist + (size_t)y * 2 * FDR_BINS;
    for (int i = 0; i < 2 * FDR_BINS; ++i)
        h[i] = 0;
    const size_t rplane = (size_t)rp * height;
    const int y0 = max(y - 3, 0), y1 = min(y + 3, height - 1);
    const int r7 = y1 - y0 + 1;
    /* the scalar operands broadcast explicitly (as safeguard_blend: Oclgrind's min) */
    const vint last = (vint)(width - 1), zero = (vint)(0);
    for (int x0 = 0; x0 < width; x0 += SG_VW) {
        const __global float *col = rows + x0;
        vint emax = (vint)(INT_MIN);
        for (int yy = y0; yy <= y1; ++yy)
            emax = max(emax, CONVERT_INT(VLOAD(col + 7 * rplane + (size_t)yy * rp)));
        /* without noisy_only every window counts (vb7 starts above 0) */
        vfloat e7 = 0.0f, ee7 = 0.0f, vb7 = noisy_only ? 0.0f : 1.0f;
        for (int yy = y0; yy <= y1; ++yy) {
            const __global float *r = col + (size_t)yy * rp;
            const vfloat f7 = pow2_nonpos(2 * (CONVERT_INT(VLOAD(r + 7 * rplane)) - emax));
            e7 += f7 * VLOAD(r + 4 * rplane);
            ee7 += (f7 * f7) * VLOAD(r + 8 * rplane);
            if (noisy_only)
                vb7 += VLOAD(r + 5 * rplane);
        }
        const vint x = x0 + SG_LANES;
        const vfloat n7 = CONVERT_FLOAT((min(x + 3, last) - max(x - 3, zero) + 1) * r7);
        const vfloat mu7 = e7 / n7;
        /* no spread: |z| = inf (a discovery at every edge) */
        const vfloat z = abs_z(mu7, window_se2(mu7, ee7, n7));
        /* noisy_only: a window whose box shows no noise (vb 0 at its every pixel: the
         * blend's weight is 0 there whatever its mean) holds no test, and its mean is
         * rounding, of either sign */
        float zl[SG_VW], ml[SG_VW];
        VSTORE(z, zl);
        VSTORE(select(mu7, (vfloat)(0.0f), vb7 <= 0.0f), ml);
        const int n = min(SG_VW, width - x0);
        for (int i = 0; i < n; ++i)
            if (ml[i] != 0.0f)
                h[(ml[i] > 0.0f ? 0 : FDR_BINS) + fdr_bin(zl[i])] += 1;
    }
}

__kernel void safeguard_fdr(__global const int *hist, int npix, float q, __global float *z)
{
    if (get_global_id(0) != 0)
        return;
    /* R(t_j) for the edges from the top down (the totals in the first row:
     * safeguard_fdr_sum); the lowest edge that passes is kept */
    long count = 0;
    float zs = (float)FDR_BINS / FDR_SCALE;
    for (int j = FDR_BINS - 1; j >= 0; --j) {
        count += hist[j];
        const float t = (float)j / FDR_SCALE;
        /* the normal's upper tail Q(t) = erfc(t / sqrt 2) / 2, in float32 down to ~1e-38 */
        if ((float)npix * 0.5f * erfc(t * M_SQRT1_2_F) <= q * (float)count)
            zs = t;
    }
    z[0] = zs;
}

/* one work-item a column of the rows' histograms (2 FDR_BINS): its total into the first row,
 * the column's own entry (adjacent work-items read adjacent columns) */
__kernel void safeguard_fdr_sum(__global int *hist, int height)
{
    const int c = get_global_id(0);
    if (c >= 2 * FDR_BINS)
        return;
    int n = 0;
    for (int y = 0; y < height; ++y)
        n += hist[(size_t)y * 2 * FDR_BINS + c];
    hist[c] = n;
}

/* the frame's count in signed bin k of z (0 .. 2 FDR_BINS - 1: z from -FDR_BINS / FDR_SCALE
 * up in steps of 1 / FDR_SCALE), from the totals in hist's first row */
inline long signed_count(__global const int *tot, int k)
{
    return k >= FDR_BINS ? tot[k - FDR_BINS] : tot[FDR_BINS + (FDR_BINS - 1 - k)];
}

/* the frame's signed counts about bin k weighted by a triangle, FDR_MODE_RADIUS + 1 - |i - k|
 * for |i - k| <= FDR_MODE_RADIUS (its weights sum to (FDR_MODE_RADIUS + 1)^2) */
inline long smoothed_count(__global const int *tot, int k)
{
    long n = 0;
    for (int i = max(k - FDR_MODE_RADIUS, 0); i <= min(k + FDR_MODE_RADIUS, 2 * FDR_BINS - 1);
         ++i)
        n += (FDR_MODE_RADIUS + 1 - abs(i - k)) * signed_count(tot, i);
    return n;
}

__kernel void safeguard_fdr_shrink(__global const int *hist, __global float *table)
{
    if (get_global_id(0) != 0)
        return;
    /* the null, a normal fitted to the frame's central peak (Efron's empirical null by
     * central matching): its mode, the first bin k* where the smoothed counts peak moved
     * by the vertex of the parabola through it and its neighbours; its half width at half
     * maximum, the narrower side's, each the distance from k* to where the smoothed counts
     * fall below half the peak's, interpolated between the two bins about it (an end of
     * the bins: one past it); its mass from the peak's height. A peak above 0 is the
     * biased pixels', and so is its width: the null is then centred at 0 with z's unit
     * spread, its height the smoothed count just below 0. The interpolations keep the fit
     * continuous in the counts (the NumPy reference's normal_null) */
    long peak = -1, total = 0;
    int km = 0;
    for (int k = 0; k < 2 * FDR_BINS; ++k) {
        const long n = smoothed_count(hist, k);
        total += signed_count(hist, k);
        if (n > peak) {
            peak = n;
            km = k;
        }
    }
    float mu = 0.0f, sigma = 1.0f;
    if (km >= FDR_BINS) {
        peak = smoothed_count(hist, FDR_BINS - 1);
    } else {
        float off = 0.0f;
        if (km > 0) {
            const long l = smoothed_count(hist, km - 1), r = smoothed_count(hist, km + 1);
            if (l - 2 * peak + r < 0)
                off = 0.5f * (float)(l - r) / (float)(l - 2 * peak + r);
        }
        float hw = (float)(2 * FDR_BINS);
        for (int side = -1; side <= 1; side += 2) {
            int d = 1;
            long prev = peak, n = 0;
            bool crossed = false;
            while (km + side * d >= 0 && km + side * d < 2 * FDR_BINS) {
                n = smoothed_count(hist, km + side * d);
                if (2 * n < peak) {
                    crossed = true;
                    break;
                }
                prev = n;
                ++d;
            }
            hw = fmin(hw, crossed ? (float)(d - 1) + ((float)prev - 0.5f * (float)peak)
                                    / (float)(prev - n) : (float)d);
        }
        sigma = hw / ((float)FDR_SCALE * sqrt(2.0f * M_LN2_F));
        mu = fmin(((float)(km - FDR_BINS) + off + 0.5f) / FDR_SCALE, 0.0f);
    }
    const float w2 = (float)((FDR_MODE_RADIUS + 1) * (FDR_MODE_RADIUS + 1));
    const float n0 = fmin((float)peak / w2 * sigma * sqrt(2.0f * M_PI_F) * FDR_SCALE,
                          (float)total);
    /* R(t_j): the positive means at |z| >= t_j = j / FDR_SCALE; N(t_j): the null's expected
     * count above t_j; a q-value: the least rate of any threshold at or below the bin's edge */
    long pos = 0;
    for (int j = FDR_BINS - 1; j >= 0; --j) {
        pos += hist[j];
        const float tail = 0.5f * erfc(((float)j / FDR_SCALE - mu) * M_SQRT1_2_F / sigma);
        table[j] = pos > 0 ? fmin(1.0f, n0 * tail / (float)pos) : 1.0f;
    }
    float q = 1.0f;
    for (int j = 0; j < FDR_BINS; ++j) {
        q = fmin(q, table[j]);
        table[j] = 1.0f - q;
    }
}
