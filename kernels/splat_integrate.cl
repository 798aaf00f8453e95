/* integrate.cl: Laplacian -> image by a convolution pyramid (Farbman, Fattal, Lischinski 2011;
 * filter sets in REFERENCES.md), float4 (RGB, coverage) pixels, zero boundary.
 *
 * The pyramid is linear, so it runs on the Laplacian itself and the sign is restored by the
 * consumer: image = ring - b0, where b0 is the pyramid's output and ring the mean of b0's
 * outermost ring (the anchor: the padded image is zero there).
 *
 * integrate_down: dst (dh, dw) = decimate(h1 (x) h1 * pad(src, PAD)), i.e.
 *   dst[y][x] = sum_jk h1[j] h1[k] src[2y + j - R1 - PAD][2x + k - R1 - PAD]   (0 outside)
 * integrate_up: out (fh, fw) = crop(h2 (x) h2 * upsample(coarse)) + g (x) g * fine, where
 *   upsample puts coarse[k] at padded position 2k (coarse may be absent: cw == 0, the
 *   coarsest level).
 * integrate_ring: one work-group; ring[0] = mean of b's outermost ring (float4).
 * src/dst offsets (in float4 pixels) let one buffer hold several layers.
 * Compile-time: PYR (5: F_5, 7: F_7), WG_RING (integrate_ring's work-group size:
 * a power of two, the host's choice within the device's limits). The 2D kernels' local size
 * is a launch parameter only (tuned).
 */
#include "vec_hint.h"

#ifndef PYR
#define PYR 5
#endif
#ifndef WG_RING
#define WG_RING 256
#endif

#if PYR == 5
#define R1 2
#define RG 1
__constant float H1[5] = {0.15f, 0.5f, 0.7f, 0.5f, 0.15f};
__constant float H2[5] = {0.15f, 0.5f, 0.7f, 0.5f, 0.15f};
__constant float G[3] = {0.175f, 0.547f, 0.175f};
#else
#define R1 3
#define RG 2
__constant float H1[7] = {0.06110f, 0.26177f, 0.53034f, 0.65934f, 0.53034f, 0.26177f, 0.06110f};
/* 0.51106 scales the 2D filter once: sqrt(0.51106) = 0.714885 per axis */
__constant float H2[7] = {0.06110f * 0.714885f, 0.26177f * 0.714885f, 0.53034f * 0.714885f,
                          0.65934f * 0.714885f, 0.53034f * 0.714885f, 0.26177f * 0.714885f,
                          0.06110f * 0.714885f};
__constant float G[5] = {0.05407f, 0.24453f, 0.57410f, 0.24453f, 0.05407f};
#endif
#define PAD (2 * R1 + 1)

__kernel void integrate_down(__global const float4 *src, const int soff, const int sw,
                             const int sh, __global float4 *dst, const int dw, const int dh)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= dw || y >= dh)
        return;
    src += soff;
    float4 acc = (float4)(0.0f);
    for (int j = 0; j < 2 * R1 + 1; ++j) {
        const int sy = 2 * y + j - R1 - PAD;
        if (sy < 0 || sy >= sh)
            continue;
        float4 row = (float4)(0.0f);
        for (int k = 0; k < 2 * R1 + 1; ++k) {
            const int sx = 2 * x + k - R1 - PAD;
            if (sx >= 0 && sx < sw)
                row += H1[k] * src[sy * sw + sx];
        }
        acc += H1[j] * row;
    }
    dst[y * dw + x] = acc;
}

__kernel SCALAR_WORK_ITEMS
void integrate_up(__global const float4 *coarse, const int cw, const int ch,
                  __global const float4 *fine, const int foff, const int fw,
                  const int fh, __global float4 *out, const int ooff)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= fw || y >= fh)
        return;
    fine += foff;
    float4 acc = (float4)(0.0f);
    /* taps of h2 on the zero-inserted coarse level: only even padded positions */
    for (int j = 0; j < 2 * R1 + 1; ++j) {
        const int py = y + PAD + j - R1;
        if (py & 1)
            continue;
        const int cy = py >> 1;
        if (cy < 0 || cy >= ch)
            continue;
        float4 row = (float4)(0.0f);
        for (int k = 0; k < 2 * R1 + 1; ++k) {
            const int px = x + PAD + k - R1;
            if (px & 1)
                continue;
            const int cx = px >> 1;
            if (cx >= 0 && cx < cw)
                row += H2[k] * coarse[cy * cw + cx];
        }
        acc += H2[j] * row;
    }
    for (int j = -RG; j <= RG; ++j) {
        const int sy = y + j;
        if (sy < 0 || sy >= fh)
            continue;
        float4 row = (float4)(0.0f);
        for (int k = -RG; k <= RG; ++k) {
            const int sx = x + k;
            if (sx >= 0 && sx < fw)
                row += G[k + RG] * fine[sy * fw + sx];
        }
        acc += G[j + RG] * row;
    }
    out[ooff + y * fw + x] = acc;
}

__kernel __attribute__((reqd_work_group_size(WG_RING, 1, 1)))
void integrate_ring(__global const float4 *b, const int boff, const int w, const int h,
                    __global float4 *ring, const int rindex)
{
    __local float4 part[WG_RING];
    const int lid = get_local_id(0);
    b += boff;
    /* ring pixels: top row, bottom row, then the left and right columns without corners */
    const int n = (h <= 2 || w <= 2) ? w * h : 2 * w + 2 * (h - 2);
    float4 acc = (float4)(0.0f);
    for (int i = lid; i < n; i += WG_RING) {
        int x, y;
        if (h <= 2 || w <= 2) { x = i % w; y = i / w; }
        else if (i < w) { x = i; y = 0; }
        else if (i < 2 * w) { x = i - w; y = h - 1; }
        else { const int r = i - 2 * w; x = (r & 1) ? w - 1 : 0; y = 1 + (r >> 1); }
        acc += b[y * w + x];
    }
    part[lid] = acc;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int s = WG_RING / 2; s > 0; s >>= 1) {
        if (lid < s)
            part[lid] += part[lid + s];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    if (lid == 0)
        ring[rindex] = part[0] / (float)n;
}
