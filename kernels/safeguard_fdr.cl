/* safeguard_fdr.cl: the guided chain's 7x7 bias test at a false discovery rate, for the
 * safeguard's blend (kernels/safeguard.cl; clrecon/methods/safeguard_reference.py:
 * fdr_threshold the NumPy reference; the derivation in clrecon/methods/safeguard.py).
 *
 *   safeguard_fdr_rows  one work-item per image row: each pixel's 7x7 bias mean over its
 *                       standard error, z = mu7 / se7, counted into the row's histogram
 *                       of FDR_BINS bins of width 1 / FDR_SCALE (z >= FDR_BINS / FDR_SCALE
 *                       in the last; pixels with mu7 <= 0 are not counted)
 *   safeguard_fdr       one work-item: the rows' histograms summed, and z[0] = the lowest
 *                       bin edge t with npix * Q(t) <= q * R(t), R(t) the pixels with z >= t
 *                       and Q the normal's upper tail (Benjamini-Hochberg at level q, to
 *                       the bins' resolution); FDR_BINS / FDR_SCALE where no edge passes
 * Arguments: rows, the nine row-segment planes of safeguard_rows (pitch rp, a multiple of
 * SG_VW: kernels/safeguard_vec.h, the host's vector width); hist
 * (H, FDR_BINS) ints; z (1 float), what safeguard_blend reads with fdr = 1.
 * The windows' sums are those of safeguard_blend (the same units, the same order of the
 * additions), so a pixel's z is the blend's mu7 / se7.
 */
#include "common.h"
#include "safeguard_vec.h"

#ifndef FDR_BINS
#define FDR_BINS 256
#endif
#ifndef FDR_SCALE
#define FDR_SCALE 32
#endif

/* SG_VW pixels x0 .. x0 + SG_VW - 1 at a time (the rows' pitch is a multiple of SG_VW; lanes
 * past the width read the row's padding and are not counted) */
__kernel void safeguard_fdr_rows(__global const float *rows, __global int *hist, int width,
                                 int height, int rp)
{
    const int y = get_global_id(0);
    if (y >= height)
        return;
    __global int *h = hist + (size_t)y * FDR_BINS;
    for (int i = 0; i < FDR_BINS; ++i)
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
        vfloat e7 = 0.0f, ee7 = 0.0f;
        for (int yy = y0; yy <= y1; ++yy) {
            const __global float *r = col + (size_t)yy * rp;
            const vfloat f7 = pow2_nonpos(2 * (CONVERT_INT(VLOAD(r + 7 * rplane)) - emax));
            e7 += f7 * VLOAD(r + 4 * rplane);
            ee7 += (f7 * f7) * VLOAD(r + 8 * rplane);
        }
        const vint x = x0 + SG_LANES;
        const vfloat n7 = CONVERT_FLOAT((min(x + 3, last) - max(x - 3, zero) + 1) * r7);
        const vfloat mu7 = e7 / n7;
        const vfloat var7 = fmax(ee7 / n7 - mu7 * mu7, 0.0f) / n7;
        /* no spread: z = +inf (a discovery at every edge) */
        const vfloat z = select((vfloat)(INFINITY), mu7 / sqrt(var7), var7 > 0.0f);
        float zl[SG_VW], ml[SG_VW];
        VSTORE(z, zl);
        VSTORE(mu7, ml);
        const int n = min(SG_VW, width - x0);
        for (int i = 0; i < n; ++i)
            if (ml[i] > 0.0f)
                h[zl[i] < (float)FDR_BINS / FDR_SCALE ? (int)(zl[i] * FDR_SCALE)
                                                       : FDR_BINS - 1] += 1;
    }
}

__kernel void safeguard_fdr(__global const int *hist, int height, int npix, float q,
                            __global float *z)
{
    if (get_global_id(0) != 0)
        return;
    /* R(t_j) for the edges from the top down; the lowest edge that passes is kept */
    long count = 0;
    float zs = (float)FDR_BINS / FDR_SCALE;
    for (int j = FDR_BINS - 1; j >= 0; --j) {
        for (int y = 0; y < height; ++y)
            count += hist[(size_t)y * FDR_BINS + j];
        const float t = (float)j / FDR_SCALE;
        /* the normal's upper tail Q(t) = erfc(t / sqrt 2) / 2, in float32 down to ~1e-38 */
        if ((float)npix * 0.5f * erfc(t * M_SQRT1_2_F) <= q * (float)count)
            zs = t;
    }
    z[0] = zs;
}
