/* filter_mip_image.cl: the MIP filter of method `layered` with OpenCL images and the
 * device's linear sampler (Hasselgren et al. 2015, section 6.1), for devices with image
 * support; kernels/filter_mip.cl is the buffer variant and holds the pyramid build both use.
 *
 * Atlas: every slot owns an ATLAS_RW x ATLAS_RH region of two 2D float images, RGBA (r, g, b,
 * own weight) and R (behind weight); slot k's region starts at ((k % ATLAS_PER_ROW) RW,
 * (k / ATLAS_PER_ROW) RH). Within it, level l of a DMAX grid has a box of side
 * level_side(DMAX, l) + 2: level 0 at (0, 0), level 1 right of it, level 2 right of level 1,
 * levels 3.. below level 2 (mip_box). Texel (x, y) of a level sits at box + (1 + x, 1 + y);
 * the ring around the slot's level is zero, so the linear sampler reads 0 outside the grid
 * as the buffer variant does (lookups further out are skipped, as there).
 *
 * filter_mip_pack: one work-item per (x, y) in [0, DMAX + 2)^2 and slot: for every level
 *   whose box (side + 2)^2 holds (x, y), writes the level's texel (x - 1, y - 1) or, on the
 *   ring, zero. Level 0 is the grid, levels >= 1 the pyramid of filter_mip_build.
 * filter_mip_sample_image: filter_mip_sample with every bilinear lookup one read_imagef of
 *   each image (CLK_FILTER_LINEAR, unnormalised coordinates). GPUs interpolate with a few
 *   bits of fraction (8 on NVIDIA), so the result matches the buffer variant to about 1e-3
 *   of the texels' range, not to float precision.
 * Compile-time: TILE, MAXP, GMAX, NLEV, PYR_PLANE, ATLAS_RW, ATLAS_RH, ATLAS_PER_ROW.
 * The local size of filter_mip_sample_image is a launch parameter only (tuned).
 */
#include "filter_mip.h"

/* defaults: one slot per atlas row of the default DMAX 64 grid (reference.mip_atlas); the
 * host sets all three from the device's image limits */
#ifndef ATLAS_RW
#define ATLAS_RW 118
#endif
#ifndef ATLAS_RH
#define ATLAS_RH 66
#endif
#ifndef ATLAS_PER_ROW
#define ATLAS_PER_ROW 1
#endif

/* Box of level l within a slot's region (sized for a DMAX grid). */
inline int2 mip_box(int l)
{
    const int b0 = level_side(DMAX, 0) + 2, b1 = level_side(DMAX, 1) + 2;
    if (l == 0)
        return (int2)(0, 0);
    if (l == 1)
        return (int2)(b0, 0);
    int y = 0;
    for (int m = 2; m < l; ++m)
        y += level_side(DMAX, m) + 2;
    return (int2)(b0 + b1, y);
}

inline int2 slot_origin(int slot)
{
    return (int2)((slot % ATLAS_PER_ROW) * ATLAS_RW, (slot / ATLAS_PER_ROW) * ATLAS_RH);
}

__kernel void filter_mip_pack(__global const float *params, __global const float *grids,
                              __global const float *pyr, __write_only image2d_t rgbw,
                              __write_only image2d_t behind)
{
    const int x = get_global_id(0), y = get_global_id(1), slot = get_global_id(2);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (dim == 0)
        return;
    const int2 o = slot_origin(slot);
    for (int l = 0; l < NLEV; ++l) {
        const int side = level_side(dim, l);
        if (x >= side + 2 || y >= side + 2)
            break;  /* boxes shrink with l */
        const int tx = x - 1, ty = y - 1;
        float v[NCH] = {0.0f};
        if (tx >= 0 && ty >= 0 && tx < side && ty < side) {
            __global const float *b;
            int plane;
            if (l == 0) {
                b = grids + (size_t)slot * NCH * DMAX * DMAX;
                plane = DMAX * DMAX;
            } else {
                b = pyr + (size_t)slot * NCH * PYR_PLANE + level_offset(dim, l);
                plane = PYR_PLANE;
            }
            for (int c = 0; c < NCH; ++c)
                v[c] = b[c * plane + ty * side + tx];
        }
        const int2 at = o + mip_box(l) + (int2)(x, y);
        write_imagef(rgbw, at, (float4)(v[0], v[1], v[2], v[3]));
        write_imagef(behind, at, (float4)(v[4], 0.0f, 0.0f, 0.0f));
    }
}

__constant sampler_t MIP_SAMPLER =
    CLK_NORMALIZED_COORDS_FALSE | CLK_ADDRESS_CLAMP_TO_EDGE | CLK_FILTER_LINEAR;

/* Bilinear lookup of level l (side `side`, box origin `box` in the atlas) at grid coordinate
 * (x, y) with weight wt, by the sampler; skipped where the buffer variant reads only zeros. */
inline void mip_bilinear_image(__read_only image2d_t rgbw, __read_only image2d_t behind,
                               int2 box, int side, int l, float x, float y, float wt,
                               float *acc)
{
    const float sc = (float)(1 << l);
    const float lx = (x - 0.5f * (sc - 1.0f)) / sc, ly = (y - 0.5f * (sc - 1.0f)) / sc;
    const float fx = floor(lx), fy = floor(ly);
    if (fx < -1.0f || fy < -1.0f || fx >= side || fy >= side)
        return;
    /* texel (i, j) is centred at box + (1.5 + i, 1.5 + j) */
    const float2 uv = (float2)((float)box.x + 1.5f + lx, (float)box.y + 1.5f + ly);
    const float4 a = read_imagef(rgbw, MIP_SAMPLER, uv);
    const float b = read_imagef(behind, MIP_SAMPLER, uv).x;
    acc[0] += wt * a.x;
    acc[1] += wt * a.y;
    acc[2] += wt * a.z;
    acc[3] += wt * a.w;
    acc[4] += wt * b;
}

__kernel void filter_mip_sample_image(__global const float *params,
                                      __read_only image2d_t rgbw, __read_only image2d_t behind,
                                      __global float *filtered)
{
    int i, j, slot;
    __global const float *p = layered_filtered_item(params, 1, &i, &j, &slot);
    if (!p)
        return;
    const mip_footprint fp = mip_footprint_of(p, i, j);
    const int2 o = slot_origin(slot);
    const int2 box0 = o + mip_box(fp.l), box1 = o + mip_box(fp.l1);
    const int side0 = level_side(fp.dim, fp.l), side1 = level_side(fp.dim, fp.l1);
    float acc[NCH] = {0.0f};
    for (int t = 0; t < 4; ++t) {
        for (int m = 0; m < fp.n; ++m) {
            const float2 q = mip_probe(&fp, t, m);
            mip_bilinear_image(rgbw, behind, box0, side0, fp.l, q.x, q.y, 1.0f - fp.f, acc);
            if (fp.f > 0.0f)
                mip_bilinear_image(rgbw, behind, box1, side1, fp.l1, q.x, q.y, fp.f, acc);
        }
    }
    layered_store_filtered(filtered, slot, i, j, acc, (float)fp.n);
}
