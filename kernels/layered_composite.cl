/* composite.cl: front-to-back compositing of the filtered partitions of each pixel's tile
 * (Hasselgren et al. 2015, section 2): e = e_0 + sum_j e_j prod_{k<j} (1 - alpha_k).
 *
 * composite: one work-item per CW pixels of a tile row (vector lanes: CW = 4, or 8 on a
 * CPU; one pixel per work-item when TILE < 4), range (ceil(W / CW), H). For each non-empty slot of the pixel's
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
 * Compile-time: SPP, TILE, MAXP, GMAX, CW. The local size is a launch
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

#ifndef CW
#define CW 4  /* pixels a work-item with TILE >= 4: 4, 8 or 16 (<= TILE; the host's choice) */
#endif
#if TILE >= 4
#define LC_CAT_(a, b) a##b
#define LC_CAT(a, b) LC_CAT_(a, b)
typedef LC_CAT(float, CW) cwf;
typedef LC_CAT(int, CW) cwi;
typedef LC_CAT(uint, CW) cwu;
#define as_cwu LC_CAT(as_uint, CW)
#define CW_VLOAD(i, p) LC_CAT(vload, CW)(i, p)
#define CW_VSTORE(v, i, p) LC_CAT(vstore, CW)(v, i, p)
#define CW_INT(v) LC_CAT(convert_int, CW)(v)
#if CW == 4
#define CW_LANES ((cwf)(0.0f, 1.0f, 2.0f, 3.0f))
#define CW_GATHER(q, ix) ((cwf)((q)[(ix).s0], (q)[(ix).s1], (q)[(ix).s2], (q)[(ix).s3]))
#elif CW == 8
#define CW_LANES ((cwf)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f))
#define CW_GATHER(q, ix) ((cwf)((q)[(ix).s0], (q)[(ix).s1], (q)[(ix).s2], (q)[(ix).s3], \
                                (q)[(ix).s4], (q)[(ix).s5], (q)[(ix).s6], (q)[(ix).s7]))
#elif CW == 16
#define CW_LANES ((cwf)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f, 8.0f, 9.0f, 10.0f, \
                        11.0f, 12.0f, 13.0f, 14.0f, 15.0f))
#define CW_GATHER(q, ix) ((cwf)((q)[(ix).s0], (q)[(ix).s1], (q)[(ix).s2], (q)[(ix).s3], \
                                (q)[(ix).s4], (q)[(ix).s5], (q)[(ix).s6], (q)[(ix).s7], \
                                (q)[(ix).s8], (q)[(ix).s9], (q)[(ix).sa], (q)[(ix).sb], \
                                (q)[(ix).sc], (q)[(ix).sd], (q)[(ix).se], (q)[(ix).sf]))
#endif
#endif

__kernel void composite(__global const float *color, const int sample_stride,
                        const int sample_offset, __global const float *params,
                        __global const float *filtered, const int width, const int height,
                        const int ntx, __global float *out)
{
#if TILE >= 4
    /* CW pixels x4 .. x4 + CW - 1 of one tile row per work-item, as vector lanes: each lane
     * computes exactly the one-pixel expression (FP_CONTRACT is off in layered.h) */
    const int x4 = CW * (int)get_global_id(0), y = get_global_id(1);
    if (x4 >= width || y >= height)
        return;
    const int t = (y / TILE) * ntx + x4 / TILE;
    const int x0 = (x4 / TILE) * TILE, y0 = (y / TILE) * TILE;
    const cwf px = (cwf)((float)(x4 - x0)) + CW_LANES;
    cwf ar = (cwf)(0.0f), ag = (cwf)(0.0f), ab = (cwf)(0.0f);
    cwf trans = (cwf)(1.0f);
    for (int k = 0; k < MAXP; ++k) {
        const int slot = t * MAXP + k;
        __global const float *p = params + (size_t)slot * NPAR;
        if (p[P_DIM] == 0.0f)
            break;
        const float inv_s = 1.0f / p[P_SCALE];
        const cwf cx = (px + 0.5f) * inv_s - 0.5f;
        const float cy = ((float)(y - y0) + 0.5f) * inv_s - 0.5f;
        const cwf fx = floor(cx);
        const float fy = floor(cy);
        const cwf wx = cx - fx;
        const float wy = cy - fy;
        const cwi ix = CW_INT(fx) + 1, ix1 = ix + 1;
        const int iy = (int)fy + 1;
        __global const float *f = filtered + (size_t)slot * NCH * FT * FT + iy * FT;
        cwf v[NCH];
        if (inv_s == 1.0f) {
            /* full-resolution grid: pixel centres are texel centres (wx = wy = 0), so the
             * bilinear read is the texel itself, CW adjacent ones */
            for (int c = 0; c < NCH; ++c)
                v[c] = CW_VLOAD(0, f + c * FT * FT + ix.s0);
        } else if (inv_s <= 0.5f) {
            /* s >= 2: the lanes' texels ix .. ix1 lie within CW of ix.s0 in the row, so one
             * vector load per row and a lane permutation (shuffle) select them: the same
             * values as gathering them one by one */
            const cwu m0 = as_cwu(ix - ix.s0), m1 = as_cwu(ix1 - ix.s0);
            for (int c = 0; c < NCH; ++c) {
                __global const float *q = f + c * FT * FT + ix.s0;
                const cwf r0 = CW_VLOAD(0, q), r1 = CW_VLOAD(0, q + FT);
                v[c] = (1.0f - wy) * ((1.0f - wx) * shuffle(r0, m0) + wx * shuffle(r0, m1))
                       + wy * ((1.0f - wx) * shuffle(r1, m0) + wx * shuffle(r1, m1));
            }
        } else {
            for (int c = 0; c < NCH; ++c) {
                __global const float *q = f + c * FT * FT;
                v[c] = (1.0f - wy) * ((1.0f - wx) * CW_GATHER(q, ix) + wx * CW_GATHER(q, ix1))
                       + wy * ((1.0f - wx) * CW_GATHER(q + FT, ix)
                               + wx * CW_GATHER(q + FT, ix1));
            }
        }
        const cwf cw = v[3] + v[4];
        const cwi ok = isgreater(cw, (cwf)(1e-6f));   /* false for NaN, as !(cw > 1e-6) */
        const cwf zero = (cwf)(0.0f);
        ar += select(zero, trans * v[0] / cw, ok);
        ag += select(zero, trans * v[1] / cw, ok);
        ab += select(zero, trans * v[2] / cw, ok);
        trans = select(trans, trans * (v[4] / cw), ok);
    }
    const cwi covered = isless(trans, (cwf)(1.0f - 1e-6f));
    const cwf den = 1.0f - trans;
    float r[CW], g[CW], b[CW];
    int cov[CW];
    CW_VSTORE(ar / den, 0, r);
    CW_VSTORE(ag / den, 0, g);
    CW_VSTORE(ab / den, 0, b);
    CW_VSTORE(covered, 0, cov);
    /* the lanes interleaved as rgb, stored as CW-wide vectors where all of them are in the
     * image */
    float o[3 * CW];
    for (int l = 0; l < CW; ++l) {
        float3 res = (float3)(r[l], g[l], b[l]);
        if (!cov[l] && x4 + l < width)
            res = pixel_mean(color, sample_stride, sample_offset, width, x4 + l, y);
        vstore3(res, l, o);
    }
    __global float *dst = out + ((size_t)y * width + x4) * 3;
    if (x4 + CW <= width) {
        for (int i = 0; i < 3; ++i)
            CW_VSTORE(CW_VLOAD(i, o), i, dst);
    } else {
        for (int i = 0; i < 3 * (width - x4); ++i)
            dst[i] = o[i];
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
