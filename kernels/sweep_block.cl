/* sweep_block.cl: the front-to-back sweep of Shirley et al. 2011 (Algorithm 2 with the
 * weights of Appendix A, two scales 1x1/5x5 blended, or Appendix B, four scales 1/3/5/7)
 * for 16 pixels per work-item, straight from the sample buffer (no prepare pass).
 *
 * sweep_block: one work-item per 4x4 block of pixels (blocks row-major over the image,
 *   1D range of ceil(W/4) * ceil(H/4) rounded up to GROUP). It
 *   1. reads the samples of the block's window ((4 + 2R)^2 pixels, R = 2 or 3, those in the
 *      image) in window order: rows, columns, sample index, which is the reference's tie
 *      order (clrecon/sweep/reference.py), into local records (x, y, D, r, g, b);
 *   2. sorts their (depth, record index) entries with a stable radix sort in local memory,
 *      once for all 16 pixels (not once per pixel);
 *   3. sweeps the sorted list once with the 16 pixels in float16 lanes: each sample's
 *      record is read once and shared by the lanes, and lanes whose window does not hold
 *      the sample get zero weight (the box filters of Appendix A/B, plus an explicit window
 *      mask for positions on a pixel edge).
 *   Per sample: D = dscale * max(2 |coc(w)|, |motion|) (motion term only with SMOOTH_MOTION),
 *   coc(w) = c0 / w + c1, computed as sweep_prepare does.
 * Inputs: SoA sample fields color (H,W,S,3), position (H,W,S,2), depth (H,W,S) (> 0 or inf),
 *   motion (H,W,S,2). Output: out (H, W, 3) float32.
 * Compile-time: SPP (<= 255), SCALES (2 or 4), SMOOTH_MOTION (0/1), EXPONENT and
 *   EXPONENT_ON (the paper's 1.3 variant: weights raised to EXPONENT).
 * Tunables: GROUP (work-items per group; blocks are independent: no barriers, each item
 *   has its own (4 + 2R)^2 * SPP * 48 bytes of local memory).
 */
#include "common.h"

#ifndef SPP
#define SPP 16
#endif
#ifndef SCALES
#define SCALES 2
#endif
#ifndef SMOOTH_MOTION
#define SMOOTH_MOTION 1
#endif
#ifndef EXPONENT
#define EXPONENT 1.0f
#endif
#ifndef EXPONENT_ON
#define EXPONENT_ON 0
#endif
#ifndef GROUP
#define GROUP 1  // work-items (blocks) per work-group
#endif

#if SCALES == 2
#define R 2
#else
#define R 3
#endif
#define BS 4                 /* block side: 16 pixels, float16 lanes */
#define BW (BS + 2 * R)      /* side of the block's window */
#define BN (BW * BW * SPP)   /* most samples in the window */

/* Stable LSD radix sort, 8-bit digits, of n entries (depth bits << 32 | payload) from a into
 * a or b; returns which. Depth > 0 or inf, so its IEEE bits order like its value. A digit
 * that is the same for every entry is skipped. */
inline __local ulong *sweep_block_sort(__local ulong *a, __local ulong *b, const int n)
{
    uint hist[4][256];
    for (int d = 0; d < 4; ++d)
        for (int v = 0; v < 256; ++v)
            hist[d][v] = 0;
    for (int i = 0; i < n; ++i) {
        const uint z = (uint)(a[i] >> 32);
        ++hist[0][z & 255];
        ++hist[1][(z >> 8) & 255];
        ++hist[2][(z >> 16) & 255];
        ++hist[3][z >> 24];
    }
    for (int d = 0; d < 4; ++d) {
        uint sum = 0;
        bool trivial = false;
        for (int v = 0; v < 256; ++v) {
            const uint c = hist[d][v];
            trivial |= c == (uint)n;
            hist[d][v] = sum;
            sum += c;
        }
        if (trivial)
            continue;
        const int shift = 32 + 8 * d;
        for (int i = 0; i < n; ++i) {
            const ulong e = a[i];
            b[hist[d][(uint)(e >> shift) & 255]++] = e;
        }
        __local ulong *t = a;
        a = b;
        b = t;
    }
    return a;
}

typedef struct {
    float16 cov_1, cov_3, cov_5, cov_7, cov, r, g, b;
} sweep_block_state;

/* One step of the sweep for all 16 lanes. ax, ay: |x - x_c|, |y - y_c| per lane, already
 * raised past every box radius in lanes whose window does not hold the sample's pixel. */
inline void sweep_block_step(sweep_block_state *st, float16 ax, float16 ay, float d, float3 c)
{
    const float ns_inv = 1.0f / SPP;
    const float16 zero = (float16)(0.0f);
    const int16 m1 = isless(ax, (float16)(0.5f)) & isless(ay, (float16)(0.5f));
    const int16 m5 = isless(ax, (float16)(2.5f)) & isless(ay, (float16)(2.5f));
    const float k5 = ns_inv * (0.2f * 0.2f);
    float16 w;
#if SCALES == 2
    /* Appendix A's update, rearranged so that the loop-carried chain through cov_1 and
     * cov_5 is two fused multiply-adds:
     *   cov_5' = cov_5 + b w_5 (1 - cov_1),  cov_1' = cov_1 + (1 - b) w_1 (1 - cov_5'),
     *   w = b w_5 (1 - cov_1) + b w_1 cov_1 + (1 - b) w_1 (1 - cov_5') + (1 - b) w_5 cov_5'
     * with b = blend, w_k = ns_inv * box * box (zero in lanes outside the box). */
    const float blend = clamp((d - 1.0f) * 0.2f, 0.0f, 1.0f), nb = 1.0f - blend;
    const float16 bw5 = select(zero, (float16)(blend * k5), m5);
    const float16 nw5 = select(zero, (float16)(nb * k5), m5);
    const float16 bw1 = select(zero, (float16)(blend * ns_inv), m1);
    const float16 nw1 = select(zero, (float16)(nb * ns_inv), m1);
    const float16 c1 = st->cov_1;
    const float16 c5 = fma(-bw5, c1, st->cov_5 + bw5);
    st->cov_5 = c5;
    st->cov_1 = fma(-nw1, c5, c1 + nw1);
    w = fma(c5, nw5 - nw1, fma(c1, bw1 - bw5, bw5 + nw1));
#else
    const float16 w_1 = select(zero, (float16)(ns_inv), m1);
    const float16 w_3 = select(zero, (float16)(ns_inv * (1.0f / 3.0f) * (1.0f / 3.0f)),
                               isless(ax, (float16)(1.5f)) & isless(ay, (float16)(1.5f)));
    const float16 w_5 = select(zero, (float16)(k5), m5);
    const float16 w_7 = select(zero, (float16)(ns_inv * (1.0f / 7.0f) * (1.0f / 7.0f)),
                               isless(ax, (float16)(3.5f)) & isless(ay, (float16)(3.5f)));
    const float16 c1 = st->cov_1, c3 = st->cov_3, c5 = st->cov_5, c7 = st->cov_7;
    if (d > 7.0f) {
        const float16 a = w_7 * (1.0f - c1 - c3 - c5);
        w = a + w_1 * c1 + w_3 * c3 + w_5 * c5;
        st->cov_7 += a;
    } else if (d > 5.0f) {
        const float16 a = w_5 * (1.0f - c1 - c3 - c7);
        w = a + w_1 * c1 + w_3 * c3 + w_7 * c7;
        st->cov_5 += a;
    } else if (d > 3.0f) {
        const float16 a = w_3 * (1.0f - c1 - c5 - c7);
        w = a + w_1 * c1 + w_5 * c5 + w_7 * c7;
        st->cov_3 += a;
    } else {
        const float16 a = w_1 * (1.0f - c3 - c5 - c7);
        w = a + w_3 * c3 + w_5 * c5 + w_7 * c7;
        st->cov_1 += a;
    }
#endif
#if EXPONENT_ON
    /* exp2/log2 instead of pow, which is a slow generic routine on CPUs */
    w = select(zero, exp2(EXPONENT * log2(w)), isgreater(w, zero));
#endif
    st->cov += w;
    st->r = fma(w, (float16)(c.x), st->r);
    st->g = fma(w, (float16)(c.y), st->g);
    st->b = fma(w, (float16)(c.z), st->b);
}

/* v moved strictly inside pixel p: [p + e, p + 1 - e], e = max(2^-12, 1 ulp), as
 * sweep_prepare and the NumPy reference do, so a sample on a pixel edge is in exactly the
 * blocks of the pixels whose window holds it */
inline float sweep_inside(float v, int p)
{
    const float lo = (float)p, hi = (float)(p + 1);
    return clamp(v, fmax(lo + 0x1p-12f, nextafter(lo, hi)), fmin(hi - 0x1p-12f, nextafter(hi, lo)));
}

__kernel __attribute__((reqd_work_group_size(GROUP, 1, 1)))
void sweep_block(__global const float *color, __global const float *position,
                 __global const float *depth, __global const float *motion,
                 const int width, const int height, const float c0, const float c1,
                 const float dscale, __global float *out)
{
    __local ulong lsort[GROUP][2][BN];
    __local float8 lrec[GROUP][BN];
    const int lid = get_local_id(0);
    const int blocks_x = (width + BS - 1) / BS;
    const int block = get_global_id(0);
    if (block >= blocks_x * ((height + BS - 1) / BS))
        return;
    const int x0 = (block % blocks_x) * BS - R, y0 = (block / blocks_x) * BS - R;
    /* In window order (the reference's tie order), each sample's record (x, y, D, r, g, b)
     * in lrec, read in order from the buffer; its sort entry: depth bits << 32 | the
     * record's index | window pixel t = ty * BW + tx << 16 */
    int n = 0;
    for (int ty = max(0, -y0); ty < min(BW, height - y0); ++ty) {
        for (int tx = max(0, -x0); tx < min(BW, width - x0); ++tx) {
            const int t = ty * BW + tx, base = pixel_index(x0 + tx, y0 + ty, width) * SPP;
            for (int s = 0; s < SPP; ++s, ++n) {
                const int g = base + s;
                const float z = depth[g];
                float d = 2.0f * fabs(c0 / z + c1);
#if SMOOTH_MOTION
                const float2 m = vload2(g, motion);
                d = max(d, sqrt(fma(m.x, m.x, m.y * m.y)));
#endif
                const float2 pos = vload2(g, position);
                const float3 c = vload3(g, color);
                lrec[lid][n] = (float8)(sweep_inside(pos.x, x0 + tx), sweep_inside(pos.y, y0 + ty),
                                        dscale * d, c.x, c.y, c.z, 0.0f, 0.0f);
                lsort[lid][0][n] = ((ulong)as_uint(z) << 32) | (uint)(n | t << 16);
            }
        }
    }
    __local const ulong *sorted = sweep_block_sort(lsort[lid][0], lsort[lid][1], n);

    /* lanes: pixel (x0 + R + (l & 3), y0 + R + (l >> 2)); far[k]: 0 in the lanes whose window
     * holds window column (row) k, beyond every box radius elsewhere (an explicit window
     * for positions on a pixel edge) */
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const int16 lx = lane & 3, ly = lane >> 2;
    const float16 cx = convert_float16(x0 + R + lx) + 0.5f;
    const float16 cy = convert_float16(y0 + R + ly) + 0.5f;
    float16 farx[BW], fary[BW];
    for (int k = 0; k < BW; ++k) {
        farx[k] = select((float16)(0.0f), (float16)(1e30f), abs(k - R - lx) > R);
        fary[k] = select((float16)(0.0f), (float16)(1e30f), abs(k - R - ly) > R);
    }
    sweep_block_state st;
    st.cov_1 = st.cov_3 = st.cov_5 = st.cov_7 = st.cov = (float16)(0.0f);
    st.r = st.g = st.b = (float16)(0.0f);
    for (int p = 0; p < n; ++p) {
        const uint e = (uint)sorted[p];
        const int t = e >> 16;
        const float8 k = lrec[lid][e & 0xFFFF];
        sweep_block_step(&st, max(fabs(k.s0 - cx), farx[t % BW]),
                         max(fabs(k.s1 - cy), fary[t / BW]), k.s2, k.s345);
    }
    float r[16], gr[16], b[16], cov[16];
    vstore16(st.r, 0, r);
    vstore16(st.g, 0, gr);
    vstore16(st.b, 0, b);
    vstore16(st.cov, 0, cov);
    for (int l = 0; l < 16; ++l) {
        const int px = x0 + R + (l & 3), py = y0 + R + (l >> 2);
        if (px < width && py < height)
            vstore3((float3)(r[l], gr[l], b[l]) / cov[l], pixel_index(px, py, width), out);
    }
}
