/* composite.cl: front-to-back compositing of the filtered partitions of each pixel's tile
 * (Hasselgren et al. 2015, section 2): e = e_0 + sum_j e_j prod_{k<j} (1 - alpha_k).
 *
 * composite: one work-item per four pixels of a tile row (float4 lanes; one pixel per
 * work-item when TILE < 4), range (ceil(W / 4), H). For each non-empty slot of the pixel's
 * tile, front to back, the filtered channels (r, g, b, own w, behind b) are read bilinearly
 * at the pixel centre's grid coordinate ((x - x0 + 0.5) / s - 0.5, ...) (exact grid pixels
 * when s = 1);
 * premultiplied layer colour e_j = rgb / (w + b), opacity alpha_j = w / (w + b) (layers with
 * w + b <= 1e-6 are skipped). Where the layers do not add up to opaque (no coverage behind),
 * the sum is divided by the accumulated opacity; a pixel no layer covers at all gets the
 * mean of its own samples (box filter).
 *   color     float (H, W, T, 3), T = sample_stride samples per pixel in the buffer, this
 *             frame's S of them from sample_offset on (a whole frame: T = S, offset 0);
 *             params float (tiles, MAXP, NPAR);
 *   filtered  float (tiles, MAXP, NCH, FT, FT); out float (H, W, 3)
 * Compile-time: SPP, TILE, MAXP, GMAX. The local size is a launch
 * parameter only (tuned); nothing here depends on it.
 */
#include "layered.h"

#ifndef SPP
#define SPP 8
#endif

/* The mean of a pixel's own samples: where no layer covers it. */
inline float3 pixel_mean(__global const float *color, int stride, int offset, int width,
                         int x, int y)
{
    const size_t base = ((size_t)y * width + x) * stride + offset;
    float3 res = (float3)(0.0f);
    for (int i = 0; i < SPP; ++i)
        res += vload3(base + i, color);
    return res / (float)SPP;
}

#define QUAD(q, ix) ((float4)((q)[(ix).s0], (q)[(ix).s1], (q)[(ix).s2], (q)[(ix).s3]))

__kernel void composite(__global const float *color, const int sample_stride,
                        const int sample_offset, __global const float *params,
                        __global const float *filtered, const int width, const int height,
                        const int ntx, __global float *out)
{
#if TILE >= 4
    /* four pixels x4 .. x4 + 3 of one tile row per work-item, as float4 lanes: each lane
     * computes exactly the one-pixel expression (FP_CONTRACT is off in layered.h) */
    const int x4 = 4 * (int)get_global_id(0), y = get_global_id(1);
    if (x4 >= width || y >= height)
        return;
    const int t = (y / TILE) * ntx + x4 / TILE;
    const int x0 = (x4 / TILE) * TILE, y0 = (y / TILE) * TILE;
    const float4 px = (float4)((float)(x4 - x0)) + (float4)(0.0f, 1.0f, 2.0f, 3.0f);
    float4 ar = (float4)(0.0f), ag = (float4)(0.0f), ab = (float4)(0.0f);
    float4 trans = (float4)(1.0f);
    for (int k = 0; k < MAXP; ++k) {
        const int slot = t * MAXP + k;
        __global const float *p = params + (size_t)slot * NPAR;
        if (p[P_DIM] == 0.0f)
            break;
        const float inv_s = 1.0f / p[P_SCALE];
        const float4 cx = (px + 0.5f) * inv_s - 0.5f;
        const float cy = ((float)(y - y0) + 0.5f) * inv_s - 0.5f;
        const float4 fx = floor(cx);
        const float fy = floor(cy);
        const float4 wx = cx - fx;
        const float wy = cy - fy;
        const int4 ix = convert_int4(fx) + 1, ix1 = ix + 1;
        const int iy = (int)fy + 1;
        __global const float *f = filtered + (size_t)slot * NCH * FT * FT + iy * FT;
        float4 v[NCH];
        if (inv_s == 1.0f) {
            /* full-resolution grid: pixel centres are texel centres (wx = wy = 0), so the
             * bilinear read is the texel itself, four adjacent ones per quad */
            for (int c = 0; c < NCH; ++c)
                v[c] = vload4(0, f + c * FT * FT + ix.s0);
        } else {
            for (int c = 0; c < NCH; ++c) {
                __global const float *q = f + c * FT * FT;
                v[c] = (1.0f - wy) * ((1.0f - wx) * QUAD(q, ix) + wx * QUAD(q, ix1))
                       + wy * ((1.0f - wx) * QUAD(q + FT, ix) + wx * QUAD(q + FT, ix1));
            }
        }
        const float4 cw = v[3] + v[4];
        const int4 ok = isgreater(cw, (float4)(1e-6f));   /* false for NaN, as !(cw > 1e-6) */
        const float4 zero = (float4)(0.0f);
        ar += select(zero, trans * v[0] / cw, ok);
        ag += select(zero, trans * v[1] / cw, ok);
        ab += select(zero, trans * v[2] / cw, ok);
        trans = select(trans, trans * (v[4] / cw), ok);
    }
    const int4 covered = isless(trans, (float4)(1.0f - 1e-6f));
    const float4 den = 1.0f - trans;
    const float4 rr = ar / den, rg = ag / den, rb = ab / den;
    float r[4], g[4], b[4];
    int cov[4];
    vstore4(rr, 0, r);
    vstore4(rg, 0, g);
    vstore4(rb, 0, b);
    vstore4(covered, 0, cov);
    for (int l = 0; l < 4 && x4 + l < width; ++l) {
        const int x = x4 + l;
        float3 res = (float3)(r[l], g[l], b[l]);
        if (!cov[l])
            res = pixel_mean(color, sample_stride, sample_offset, width, x, y);
        vstore3(res, (size_t)y * width + x, out);
    }
#else
    /* tiles narrower than four pixels: one pixel per work-item */
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
    const float3 res = trans < 1.0f - 1e-6f ? acc / (1.0f - trans)
                                            : pixel_mean(color, sample_stride,
                                                         sample_offset, width, x, y);
    vstore3(res, (size_t)y * width + x, out);
#endif
}
