/* composite.cl: front-to-back compositing of the filtered partitions of each pixel's tile
 * (Hasselgren et al. 2015, section 2): e = e_0 + sum_j e_j prod_{k<j} (1 - alpha_k).
 *
 * composite: one work-item per pixel. For each non-empty slot of the pixel's tile, front to
 * back, the filtered channels (r, g, b, own w, behind b) are read bilinearly at the pixel
 * centre's grid coordinate ((x - x0 + 0.5) / s - 0.5, ...) (exact grid pixels when s = 1);
 * premultiplied layer colour e_j = rgb / (w + b), opacity alpha_j = w / (w + b) (layers with
 * w + b <= 1e-6 are skipped). Where the layers do not add up to opaque (no coverage behind),
 * the sum is divided by the accumulated opacity; a pixel no layer covers at all gets the
 * mean of its own samples (box filter).
 *   color     float (H, W, S, 3); params float (tiles, MAXP, NPAR);
 *   filtered  float (tiles, MAXP, NCH, FT, FT); out float (H, W, 3)
 * Compile-time: SPP, TILE, MAXP, GMAX. Tunables: WG_X, WG_Y (local size).
 */
#include "layered.h"

#ifndef SPP
#define SPP 8
#endif
#ifndef WG_X
#define WG_X 16
#endif
#ifndef WG_Y
#define WG_Y 4
#endif

__kernel void composite(__global const float *color, __global const float *params,
                        __global const float *filtered, const int width, const int height,
                        const int ntx, __global float *out)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const int t = (y / TILE) * ntx + x / TILE;
    const int x0 = (x / TILE) * TILE, y0 = (y / TILE) * TILE;
    float3 acc = (float3)(0.0f);
    float trans = 1.0f;
    for (int k = 0; k < MAXP; ++k) {
        const int slot = t * MAXP + k;
        __global const float *p = params + (size_t)slot * NPAR;
        if (p[P_DIM] == 0.0f)
            break;
        const float inv_s = 1.0f / p[P_SCALE];
        const float cx = ((float)(x - x0) + 0.5f) * inv_s - 0.5f;
        const float cy = ((float)(y - y0) + 0.5f) * inv_s - 0.5f;
        const float fx = floor(cx), fy = floor(cy);
        const float wx = cx - fx, wy = cy - fy;
        const int ix = (int)fx + 1, iy = (int)fy + 1;
        __global const float *f = filtered + (size_t)slot * NCH * FT * FT + iy * FT + ix;
        float v[NCH];
        for (int c = 0; c < NCH; ++c) {
            __global const float *q = f + c * FT * FT;
            v[c] = (1.0f - wy) * ((1.0f - wx) * q[0] + wx * q[1])
                   + wy * ((1.0f - wx) * q[FT] + wx * q[FT + 1]);
        }
        const float cw = v[3] + v[4];
        if (!(cw > 1e-6f))
            continue;
        acc += trans * (float3)(v[0], v[1], v[2]) / cw;
        trans *= v[4] / cw;
    }
    float3 res;
    if (trans < 1.0f - 1e-6f) {
        res = acc / (1.0f - trans);
    } else {
        const size_t base = ((size_t)y * width + x) * SPP;
        res = (float3)(0.0f);
        for (int i = 0; i < SPP; ++i)
            res += vload3(base + i, color);
        res /= (float)SPP;
    }
    vstore3(res, (size_t)y * width + x, out);
}
