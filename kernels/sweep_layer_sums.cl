/* sweep_layer_sums.cl: per-pixel sums of the sort-free three-layer depth-of-field sweep
 * (Shirley et al. 2011, section 3.1, with Appendix A's 1x1/5x5 blend).
 *
 * sweep_layer_sums: one work-item per pixel. Each sample, with D = dscale * 2|coc(w)| and
 * blend b = clamp((D - 1) / 5, 0, 1), belongs to the narrow (in-focus) layer with weight
 * 1 - b and to a wide layer with weight b: the near one when coc < 0 (in front of the focus
 * plane), the far one otherwise. Writes per pixel and layer (near 0, narrow 1, far 2):
 *   sums float4 (H, W, 3): (sum m * r, sum m * g, sum m * b, sum m)
 * No positions are read: a sample lies inside its pixel, where the 1x1 box is 1.
 * Inputs: color (H,W,S,3), depth (H,W,S). Compile-time: SPP.
 * Local size: a launch parameter only (tuned).
 */
#include "common.h"
#include "vec_hint.h"

#ifndef SPP
#define SPP 16
#endif

__kernel SCALAR_WORK_ITEMS
void sweep_layer_sums(__global const float *color, __global const float *depth,
                      const int width, const int height, const float c0,
                      const float c1, const float dscale, __global float4 *sums)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    const int p = pixel_index(px, py, width);
    const size_t base = (size_t)p * SPP;
    float4 near = (float4)(0.0f), narrow = (float4)(0.0f), far = (float4)(0.0f);
    for (int i = 0; i < SPP; ++i) {
        const float coc = c0 / depth[base + i] + c1;
        const float b = clamp((dscale * 2.0f * fabs(coc) - 1.0f) / 5.0f, 0.0f, 1.0f);
        const float4 c = (float4)(vload3(base + i, color), 1.0f);
        narrow += (1.0f - b) * c;
        if (coc < 0.0f)
            near += b * c;
        else
            far += b * c;
    }
    sums[3 * p + 0] = near;
    sums[3 * p + 1] = narrow;
    sums[3 * p + 2] = far;
}
