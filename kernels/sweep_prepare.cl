/* sweep_prepare.cl: per-sample denoising diameter and per-pixel front-to-back order, the
 * input of sweep_resolve (Shirley et al. 2011).
 *
 * sweep_prepare: one work-item per pixel. For each of the pixel's SPP samples computes
 *   D = dscale * max(2 |coc(w)|, |motion|)   (the motion term only with SMOOTH_MOTION)
 * and writes the samples sorted by depth (stable: equal depths keep sample order; the order's
 * precision is sweep_order.h's) as
 *   keys   float4 (H, W, SPP): (x, y, order depth, D); the order depth is sweep_order_depth
 *          of the depth, all sweep_resolve compares
 *   colors float4 (H, W, SPP): (r, g, b, 0)
 * Positions are moved strictly inside their own pixel, [p + e, p + 1 - e] with
 * e = max(2^-12, 1 ulp) (validation allows a sample on an edge, or a hair past it): every
 * sample then falls in exactly the blocks of the pixels whose window holds it, so no pixel
 * is left without weight (a 1 spp frame whose samples sit on pixel corners gave 0/0).
 * Inputs are the SoA sample fields: color (H,W,S,3), position (H,W,S,2), depth (H,W,S),
 * motion (H,W,S,2). coc(w) = c0 / w + c1 (inf depth gives c1).
 * Compile-time: SPP (samples per pixel, <= 256), SMOOTH_MOTION (0/1; defaults in sweep.h),
 * DEPTH_KEY_SHIFT (sweep_order.h).
 * Local size: a launch parameter only (tuned).
 */
#include "sweep.h"
#include "sweep_order.h"
#include "vec_hint.h"

/* v moved strictly inside pixel p (see the header); the NumPy reference does the same */
inline float sweep_inside(float v, int p)
{
    const float lo = (float)p, hi = (float)(p + 1);
    return clamp(v, fmax(lo + 0x1p-12f, nextafter(lo, hi)), fmin(hi - 0x1p-12f, nextafter(hi, lo)));
}

__kernel SCALAR_WORK_ITEMS
void sweep_prepare(__global const float *color, __global const float *position,
                   __global const float *depth, __global const float *motion,
                   const int width, const int height, const float c0, const float c1,
                   const float dscale, __global float4 *keys, __global float4 *colors)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    const size_t base = (size_t)pixel_index(px, py, width) * SPP;
    float4 k[SPP];
    int order[SPP];
    for (int i = 0; i < SPP; ++i) {
        const float z = depth[base + i];
        float d = 2.0f * fabs(c0 / z + c1);
#if SMOOTH_MOTION
        d = fmax(d, length(vload2(base + i, motion)));
#endif
        const float2 p = vload2(base + i, position);
        const float x = sweep_inside(p.x, px), y = sweep_inside(p.y, py);
        const float zo = sweep_order_depth(z);
        k[i] = (float4)(x, y, zo, dscale * d);
        /* insertion sort of indices by depth; strict > keeps equal depths in order */
        int j = i;
        while (j > 0 && k[order[j - 1]].z > zo) {
            order[j] = order[j - 1];
            --j;
        }
        order[j] = i;
    }
    for (int i = 0; i < SPP; ++i) {
        const int s = order[i];
        keys[base + i] = k[s];
        colors[base + i] = (float4)(vload3(base + s, color), 0.0f);
    }
}
