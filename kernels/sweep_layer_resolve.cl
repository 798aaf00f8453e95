/* sweep_layer_resolve.cl: combine the three layers of sweep_layer_sums front to back.
 *
 * sweep_layer_resolve: one work-item per pixel. Per layer L, with M_L the layer sums of a
 * pixel (rgb, weight): the narrow terms are M_L(pixel) / SPP (1x1 box), the wide terms the
 * sum of M_L over the 5x5 window (pixels inside the image) / (25 SPP). Layers near wide,
 * narrow, far wide are combined with Appendix A's update (coverage constant within a layer):
 *   wide:   c += (1 - cov_1) C5 + cov_1 C1;  cov += (1 - cov_1) S5 + cov_1 S1;
 *           cov_5 += (1 - cov_1) S5
 *   narrow: c += (1 - cov_5) C1 + cov_5 C5;  cov += (1 - cov_5) S1 + cov_5 S5;
 *           cov_1 += (1 - cov_5) S1
 * Arguments: sums float4 (H, W, 3) of sweep_layer_sums, out (H, W, 3) = c / cov.
 * Compile-time: SPP. Local size: a launch parameter only (tuned).
 */
#include "common.h"

#ifndef SPP
#define SPP 16
#endif

__kernel void sweep_layer_resolve(__global const float4 *sums, const int width,
                                  const int height, __global float *out)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    const int p = pixel_index(px, py, width);
    float4 wide[3] = {(float4)(0.0f), (float4)(0.0f), (float4)(0.0f)};
    const int4 win = window_clip(px, py, 2, width, height);  /* the 5x5 window */
    for (int qy = win.y; qy <= win.w; ++qy) {
        for (int qx = win.x; qx <= win.z; ++qx) {
            const int q = pixel_index(qx, qy, width);
            for (int l = 0; l < 3; ++l)
                wide[l] += sums[3 * q + l];
        }
    }
    float cov_1 = 0.0f, cov_5 = 0.0f, cov = 0.0f;
    float3 c = (float3)(0.0f);
    for (int l = 0; l < 3; ++l) {
        const float4 m1 = sums[3 * p + l] * (1.0f / SPP);
        const float4 m5 = wide[l] * (1.0f / (25.0f * SPP));
        if (l == 1) {
            c += (1.0f - cov_5) * m1.xyz + cov_5 * m5.xyz;
            cov += (1.0f - cov_5) * m1.w + cov_5 * m5.w;
            cov_1 += (1.0f - cov_5) * m1.w;
        } else {
            c += (1.0f - cov_1) * m5.xyz + cov_1 * m1.xyz;
            cov += (1.0f - cov_1) * m5.w + cov_1 * m1.w;
            cov_5 += (1.0f - cov_1) * m5.w;
        }
    }
    vstore3(c / cov, p, out);
}
