/* box.cl: the per-pixel box filter, the baseline of every report.
 *
 * box_average: out[y, x, :] = mean over i of color[y, x, i, :].
 *   color  float, (H, W, S, 3) row-major: ((y * W + x) * S + i) * 3 + c
 *   out    float, (H, W, 3)
 * One work-item per pixel on a 2D range rounded up to the local size; items outside the
 * image return early. Sums in float (S <= a few hundred; relative error ~S * 2^-24).
 * Local size: a launch parameter only (tuned); nothing here depends on it.
 */
#include "common.h"


__kernel void box_average(__global const float *color, __global float *out,
                          const int width, const int height, const int spp)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const int p = pixel_index(x, y, width);
    __global const float *c = color + (size_t)p * spp * 3;
    float3 sum = (float3)(0.0f);
    for (int i = 0; i < spp; ++i)
        sum += vload3(i, c);
    vstore3(sum / (float)spp, p, out);
}
