/* sweep_block_one_box.h: sweep_block's shortcut for a window whose every sample weighs in one
 * box alone (kernels/sweep_block.cl includes it after its own definitions: SPP, SCALES,
 * SMOOTH_MOTION from sweep.h; R, SW (the work-item window's side) and SB (its outputs' side)):
 *   sweep_block_u        a sample's record field u (the blend, or D with four scales)
 *   sweep_block_radius   the one box that weighs a sample of that u alone (-1: mixed)
 *   sweep_block_uniform  a one-box window's image: the box's mean, unsorted
 */
#ifndef CLRECON_SWEEP_BLOCK_ONE_BOX_H
#define CLRECON_SWEEP_BLOCK_ONE_BOX_H

/* A sample's u (its record's first field): the blend clamp((D - 1) / 5, 0, 1) with two
 * scales, D itself with four; D = dscale * max(2 |coc(z)|, |motion|) */
inline float sweep_block_u(const float z, __global const float *motion, const int g,
                           const float c0, const float c1, const float dscale)
{
    float d = 2.0f * fabs(c0 / z + c1);
#if SMOOTH_MOTION
    const float2 m = vload2(g, motion);
    d = max(d, sqrt(fma(m.x, m.x, m.y * m.y)));
#endif
#if SCALES == 2
    return clamp((dscale * d - 1.0f) * 0.2f, 0.0f, 1.0f);  /* the blend, once */
#else
    return d * dscale;
#endif
}

/* The box radius k that alone weighs a sample whose record holds u (the blend with two
 * scales, D with four), or -1 where the sample's weight mixes boxes. With two scales a blend
 * of exactly 1 takes the 5x5 box alone (k = 2) and 0 the 1x1 box (k = 0); with four, D's band
 * picks one box (as sweep_block_step's branches). */
inline int sweep_block_radius(const float u)
{
#if SCALES == 2
    return u >= 1.0f ? 2 : (u == 0.0f ? 0 : -1);
#else
    return u > 7.0f ? 3 : (u > 5.0f ? 2 : (u > 3.0f ? 1 : 0));
#endif
}

/* A window whose every sample weighs in the same one box of radius k (sweep_block_radius):
 * the sweep's coverage terms of the other boxes stay zero, so every sample's weight in a
 * lane is that box's constant (zero outside the lane's box), whatever the depth order, and
 * Algorithm 2's sum reduces to the mean of the samples of the (2k+1)^2 pixels around each
 * pixel (those in the image): no sort, no sweep. (With two scales the update of
 * sweep_block_step with blend 1 keeps cov_1 = 0 and gives w = w_5 exactly; with blend 0,
 * cov_5 = 0 and w = w_1; with four, each branch with the other three coverages zero gives
 * w = w_k. With EXPONENT_ON the constant raised to EXPONENT cancels in the division too.)
 * The window is the SW x SW pixels from (x0, y0), those in the image (rows ty0 .. ty1 - 1,
 * columns tx0 .. tx1 - 1); colours as sweep_block reads them. pl: 3 SW^2 floats of local
 * scratch (the two sort buffers, unused here: 16 SN >= 12 SW^2 bytes at any SPP), the
 * pixels' mean colours as r, g, b planes, zero outside the image. The box sums run along
 * rows and then columns in SB-wide vectors (a row of a work-item's outputs); each mean is
 * scaled as it is summed, so no partial sum exceeds the largest colour. */
#if SB == 8
#define floatSB float8
#define intSB int8
#define convert_floatSB convert_float8
#define vloadSB vload8
#define vstoreSB vstore8
#define SB_LANES (int8)(0, 1, 2, 3, 4, 5, 6, 7)
#else
#define floatSB float4
#define intSB int4
#define convert_floatSB convert_float4
#define vloadSB vload4
#define vstoreSB vstore4
#define SB_LANES (int4)(0, 1, 2, 3)
#endif
inline void sweep_block_uniform(__global const float *color, const int stride,
                                const int offset, __local float *pl, const int x0,
                                const int y0, const int width, const int height, const int k,
                                __global float *out)
{
    const int tx0 = max(0, -x0), tx1 = min(SW, width - x0);
    const int ty0 = max(0, -y0), ty1 = min(SW, height - y0);
    const float ns_inv = 1.0f / SPP;
    for (int q = 0; q < 3 * SW * SW; ++q)
        pl[q] = 0.0f;
    for (int ty = ty0; ty < ty1; ++ty)
        for (int tx = tx0; tx < tx1; ++tx) {
            const int base = pixel_index(x0 + tx, y0 + ty, width) * stride + offset;
            float3 m = (float3)(0.0f);
            for (int j = 0; j < SPP; ++j)
                m = fma(vload3(base + j, color), (float3)(ns_inv), m);
            pl[ty * SW + tx] = m.x;
            pl[SW * SW + ty * SW + tx] = m.y;
            pl[2 * SW * SW + ty * SW + tx] = m.z;
        }
    /* each output's box, clipped to the image: 1 / its pixel count, by column and by row */
    const intSB o = SB_LANES;
    const intSB nx = min(tx1 - 1, R + o + k) - max(tx0, R + o - k) + 1;
    const intSB ny = min(ty1 - 1, R + o + k) - max(ty0, R + o - k) + 1;
    const floatSB ix = 1.0f / convert_floatSB(nx);
    float fy[SB];
    vstoreSB(1.0f / convert_floatSB(ny), 0, fy);
    /* rows: the horizontal box sum of every window row an output's box reaches, per plane */
    floatSB hr[SW], hg[SW], hb[SW];
    for (int ty = R - k; ty < R + SB + k; ++ty) {
        floatSB r = (floatSB)(0.0f), g = r, b = r;
        for (int dx = -k; dx <= k; ++dx) {
            const int at = ty * SW + R + dx;
            r += vloadSB(0, pl + at);
            g += vloadSB(0, pl + SW * SW + at);
            b += vloadSB(0, pl + 2 * SW * SW + at);
        }
        hr[ty] = r * ix;
        hg[ty] = g * ix;
        hb[ty] = b * ix;
    }
    for (int oy = 0; oy < SB; ++oy) {
        const int py = y0 + R + oy;
        if (py >= height)
            break;
        floatSB r = (floatSB)(0.0f), g = r, b = r;
        for (int ty = R + oy - k; ty <= R + oy + k; ++ty) {
            r += hr[ty];
            g += hg[ty];
            b += hb[ty];
        }
        float vr[SB], vg[SB], vb[SB];
        vstoreSB(r, 0, vr);
        vstoreSB(g, 0, vg);
        vstoreSB(b, 0, vb);
        for (int ox = 0; ox < SB && x0 + R + ox < width; ++ox)
            vstore3((float3)(vr[ox], vg[ox], vb[ox]) * fy[oy],
                    pixel_index(x0 + R + ox, py, width), out);
    }
}

#endif /* CLRECON_SWEEP_BLOCK_ONE_BOX_H */
