/* sweep_block.cl: the front-to-back sweep of Shirley et al. 2011 (Algorithm 2 with the
 * weights of Appendix A, two scales 1x1/5x5 blended, or Appendix B, four scales 1/3/5/7)
 * for 4x4 pixel blocks in float16 lanes, straight from the sample buffer (no prepare pass).
 *
 * sweep_block: one work-item per SUPER x SUPER blocks of 4x4 pixels (4 SUPER pixels a side;
 *   work-items row-major over the image, 1D range of ceil(W/(4 SUPER)) * ceil(H/(4 SUPER))
 *   rounded up to GROUP). It
 *   1. reads the samples of its window ((4 SUPER + 2R)^2 pixels, R = 2 or 3, those in the
 *      image) in window order: rows, columns, sample index, which is the reference's tie
 *      order (clrecon/methods/sweep/reference.py), into local records (D or its blend, r, g, b);
 *   2. sorts their (depth key, window position) entries (sweep_order.h) with a stable
 *      radix sort in local memory, once for all its pixels (not once per pixel, nor once
 *      per block: a sample lies in up to four blocks' windows; with SUPER = 2 and R = 2 a
 *      work-item reads and sorts 144 window pixels for 64 pixels, one block alone 64 for 16);
 *   3. with SUPER > 1, splits the sorted list into each block's window (in order);
 *   4. sweeps each block's list once with its 16 pixels in float16 lanes: each sample's
 *      record is read once and shared by the lanes, and lanes whose box does not hold the
 *      sample get zero weight (box membership depends on the sample's pixel alone: see
 *      sweep_block_masks).
 *   Before 1, it reads the window's depths and motions alone: where one box weighs every
 *   sample (sweep_block_radius: two scales' blend exactly 1 or 0, four scales' one band of
 *   D), the image is that box's mean, computed without records, sort or sweep
 *   (sweep_block_uniform; UNIFORM_BOX = 0 sorts and sweeps those windows too). At deep
 *   1280x720 8 spp 97.5% of the work-items' windows are such (every sample's blur >= 6 px).
 *   Per sample: D = dscale * max(2 |coc(w)|, |motion|) (motion term only with SMOOTH_MOTION),
 *   coc(w) = c0 / w + c1, computed as sweep_prepare does.
 * Inputs: SoA sample fields color (H,W,T,3), depth (H,W,T) (> 0 or inf), motion (H,W,T,2)
 *   with T = stride samples per pixel in the buffers, of which this frame's SPP are
 *   offset .. offset + SPP - 1 (a whole frame: stride SPP, offset 0; one half of a frame
 *   read in place for the safeguard: stride the frame's spp); positions are not needed:
 *   every sample counts as inside its own pixel, as the reference's clamp makes it.
 *   Output: out (H, W, 3) float32.
 * Compile-time: SPP (<= 255), SCALES (2 or 4), SMOOTH_MOTION (0/1), DEPTH_KEY_SHIFT
 *   (sweep_order.h), EXPONENT and EXPONENT_ON (the paper's 1.3 variant: weights raised to
 *   EXPONENT; defaults and R in sweep.h), SUPER (1 or 2: the host takes 2 where its local
 *   memory fits, clrecon/methods/sweep/block.py), UNIFORM_BOX (0/1, default 1).
 * Tunables: GROUP (work-items per group; work-items are independent: no barriers, each
 *   has its own local memory: 2 * SORT_SLOTS * 8 + SN * 16 bytes).
 */
#include "sweep.h"
#include "sweep_order.h"

#ifndef GROUP
#define GROUP 1  // work-items (blocks) per work-group
#endif
#ifndef SUPER
#define SUPER 1  /* a work-item's blocks per side: 1 or 2 */
#endif
#ifndef UNIFORM_BOX
#define UNIFORM_BOX 1  /* 0: every window is sorted and swept (the uniform windows too) */
#endif
#define BS 4                 /* block side: 16 pixels, float16 lanes */
#define BW (BS + 2 * R)      /* side of the block's window */
#define BN (BW * BW * SPP)   /* most samples in the window */
#define SB (SUPER * BS)      /* side of a work-item's pixels */
#define SW (SB + 2 * R)      /* side of their window */
#define SN (SW * SW * SPP)   /* most samples in that window */
/* sort slots: the window's samples, and with SUPER > 1 the blocks' lists (BN + 1 uints
 * each) in the spare buffer */
#if SUPER > 1 && SUPER * SUPER * (BN + 1) > 2 * SN
#define SORT_SLOTS ((SUPER * SUPER * (BN + 1) + 1) / 2)
#else
#define SORT_SLOTS SN
#endif

/* Stable LSD radix sort, 8-bit digits, of n entries (key << 32 | payload) from a into a or
 * b; returns which. The keys are sweep_depth_key of the depths (sweep_order.h: they order
 * like the depths, to its precision), reduced first to min(key, cap) - lo with lo the
 * smallest key and cap one past the largest finite one: the same order and ties, fewer
 * digits (a window of misses at inf and finite depths needed all four). Only the digits
 * of the reduced range are sorted, and a digit that is the same for every entry is
 * skipped. */
inline __local ulong *sweep_block_sort(__local ulong *a, __local ulong *b, const int n,
                                       const uint lo, const uint cap)
{
    const uint range = cap - lo;  /* the largest reduced key */
    const int digits = (32 - clz(range) + 7) / 8;
    uint hist[4][256];
    for (int d = 0; d < digits; ++d)
        for (int v = 0; v < 256; ++v)
            hist[d][v] = 0;
    for (int i = 0; i < n; ++i) {
        const ulong e = a[i];
        const uint z = min((uint)(e >> 32), cap) - lo;
        a[i] = (ulong)z << 32 | (uint)e;
        for (int d = 0; d < digits; ++d)
            ++hist[d][(z >> (8 * d)) & 255];
    }
    for (int d = 0; d < digits; ++d) {
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

/* Box membership. Every position lies strictly inside its own pixel and every box is
 * pixel-aligned (an odd number of pixels around the lane's own), so a sample of window
 * pixel (tx, ty) lies in lane l's (2k+1)^2 box exactly when |tx - R - lx| <= k and
 * |ty - R - ly| <= k: the masks depend on the window pixel alone, never on the position
 * (the reference's |x - x_c| < k + 1/2 gives the same). Tables of the boxes' weights per
 * lane: by window pixel with two scales (two loads a step), as the product of per-column
 * weight and per-row 0/1 masks with four; the widest box is the window, so a lane whose
 * window does not hold the pixel gets zero weight in every box. */
typedef struct {
#if SCALES == 2
    float16 w5[BW * BW], w1[BW * BW];  /* by window pixel ty BW + tx: 1/(25 SPP), 1/SPP */
#else
    float16 w1x[BW], w3x[BW], w5x[BW], w7x[BW], m1y[BW], m3y[BW], m5y[BW], m7y[BW];
#endif
} sweep_block_masks;

inline float16 sweep_box(const int c, const int16 l, const int k, const float v)
{
    return select((float16)(0.0f), (float16)(v), abs(c - R - l) <= k);
}

/* One step of the sweep for all 16 lanes, for a sample of window pixel (tx, ty) with
 * colour c and d its blend (two scales) or denoising diameter (four). */
inline void sweep_block_step(sweep_block_state *st, const sweep_block_masks *mk, const int tx,
                             const int ty, const float d, const float3 c)
{
    float16 w;
#if SCALES == 2
    /* Appendix A's update, rearranged so that the loop-carried chain through cov_1 and
     * cov_5 is two fused multiply-adds:
     *   cov_5' = cov_5 + b w_5 (1 - cov_1),  cov_1' = cov_1 + (1 - b) w_1 (1 - cov_5'),
     *   w = b w_5 (1 - cov_1) + b w_1 cov_1 + (1 - b) w_1 (1 - cov_5') + (1 - b) w_5 cov_5'
     *     = b w_5 + (1 - b) w_1 + (w_5 - w_1) ((1 - b) cov_5' - b cov_1)
     * with b = blend, w_k = box weight (zero in lanes outside the box). */
    const float blend = d, nb = 1.0f - blend;
    const float16 w5 = mk->w5[ty * BW + tx], w1 = mk->w1[ty * BW + tx];
    const float16 bw5 = blend * w5, nw1 = nb * w1;
    const float16 c1 = st->cov_1;
    const float16 c5 = fma(-bw5, c1, st->cov_5 + bw5);
    st->cov_5 = c5;
    st->cov_1 = fma(-nw1, c5, c1 + nw1);
    w = fma(w5 - w1, fma(-blend, c1, nb * c5), bw5 + nw1);
#else
    const float16 w_1 = mk->w1x[tx] * mk->m1y[ty], w_3 = mk->w3x[tx] * mk->m3y[ty];
    const float16 w_5 = mk->w5x[tx] * mk->m5y[ty], w_7 = mk->w7x[tx] * mk->m7y[ty];
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
    w = select((float16)(0.0f), exp2(EXPONENT * log2(w)), isgreater(w, (float16)(0.0f)));
#endif
    st->cov += w;
    st->r = fma(w, (float16)(c.x), st->r);
    st->g = fma(w, (float16)(c.y), st->g);
    st->b = fma(w, (float16)(c.z), st->b);
}

#include "sweep_block_one_box.h"  /* the one-box shortcut (UNIFORM_BOX) */

__kernel __attribute__((reqd_work_group_size(GROUP, 1, 1)))
void sweep_block(__global const float *color, __global const float *depth,
                 __global const float *motion, const int stride, const int offset,
                 const int width, const int height,
                 const float c0, const float c1, const float dscale, __global float *out)
{
    __local ulong lsort[GROUP][2][SORT_SLOTS];
    __local float4 lrec[GROUP][SN];
    const int lid = get_local_id(0);
    const int supers_x = (width + SB - 1) / SB;
    const int super = get_global_id(0);
    if (super >= supers_x * ((height + SB - 1) / SB))
        return;
    const int x0 = (super % supers_x) * SB - R, y0 = (super / supers_x) * SB - R;
    /* In window order (the reference's tie order), each sample's record (u, r, g, b) in
     * lrec, read in order from the buffer (u: the blend clamp((D - 1) / 5, 0, 1) with two
     * scales, D itself with four); its sort entry: depth bits << 32 | the record's
     * index | window column tx << 16 | window row ty << 20 */
#if UNIFORM_BOX
    /* First the window's box radii alone (depth and motion read, no colour, nothing stored):
     * where one box weighs every sample, that box's mean (sweep_block_uniform); a mixed
     * window stops at its first pixel that differs and is sorted and swept below. */
    {
        const int tx0 = max(0, -x0), ty0 = max(0, -y0);
        const int g0 = pixel_index(x0 + tx0, y0 + ty0, width) * stride + offset;
        const int k0 = sweep_block_radius(sweep_block_u(depth[g0], motion, g0, c0, c1,
                                                        dscale));
        bool one = k0 >= 0;
        for (int ty = ty0; one && ty < min(SW, height - y0); ++ty)
            for (int tx = tx0; one && tx < min(SW, width - x0); ++tx) {
                const int base = pixel_index(x0 + tx, y0 + ty, width) * stride + offset;
                for (int s = 0; s < SPP; ++s)
                    one &= sweep_block_radius(sweep_block_u(depth[base + s], motion, base + s,
                                                            c0, c1, dscale)) == k0;
            }
        if (one) {
            sweep_block_uniform(color, stride, offset, (__local float *)lsort[lid], x0, y0,
                                width, height, k0, out);
            return;
        }
    }
#endif
    int n = 0;
    uint lo = sweep_depth_key(INFINITY), top = 0;  /* smallest key, largest finite one */
    for (int ty = max(0, -y0); ty < min(SW, height - y0); ++ty) {
        for (int tx = max(0, -x0); tx < min(SW, width - x0); ++tx) {
            const int base = pixel_index(x0 + tx, y0 + ty, width) * stride + offset;
            for (int s = 0; s < SPP; ++s, ++n) {
                const int g = base + s;
                const float z = depth[g];
                lrec[lid][n] = (float4)(sweep_block_u(z, motion, g, c0, c1, dscale),
                                        vload3(g, color));
                const uint key = sweep_depth_key(z);
                lo = min(lo, key);
                top = max(top, as_uint(z) < 0x7F800000u ? key : 0u);
                lsort[lid][0][n] = ((ulong)key << 32) | (uint)(n | tx << 16 | ty << 20);
            }
        }
    }
    __local const ulong *sorted = sweep_block_sort(lsort[lid][0], lsort[lid][1], n, lo,
                                                     max(top + 1, lo));
#if SUPER > 1
    /* each 4x4 block's window samples, in sorted order, into its list (in the sort's spare
     * buffer; BN + 1 slots: a sample outside the window is written past the list's end and
     * not counted), the entry as it is (record index | work-item window column << 16 | row
     * << 20: the sweep takes the block's origin off, so this loop only copies and counts;
     * rewriting each entry's fields for each block made it 1.03-1.07x slower) */
    __local uint *lists = (__local uint *)lsort[lid][sorted == lsort[lid][0] ? 1 : 0];
    int count[SUPER * SUPER];  /* (unrolled: the counters stay in registers) */
#pragma unroll
    for (int q = 0; q < SUPER * SUPER; ++q)
        count[q] = 0;
    for (int p = 0; p < n; ++p) {
        const uint e = (uint)sorted[p];
        const uint tx = (e >> 16) & 15, ty = e >> 20;
#pragma unroll
        for (int q = 0; q < SUPER * SUPER; ++q) {
            lists[q * (BN + 1) + count[q]] = e;
            count[q] += (int)((tx - BS * (q % SUPER) < BW) & (ty - BS * (q / SUPER) < BW));
        }
    }
#endif

    /* lanes: pixel (bx + R + (l & 3), by + R + (l >> 2)) of the block with window origin
     * (bx, by) */
    const int16 lane = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const int16 lx = lane & 3, ly = lane >> 2;
    const float ns_inv = 1.0f / SPP;
    sweep_block_masks mk;
    for (int k = 0; k < BW; ++k) {
#if SCALES == 2
        for (int c = 0; c < BW; ++c) {
            mk.w5[k * BW + c] = sweep_box(c, lx, 2, ns_inv * (0.2f * 0.2f))
                                * sweep_box(k, ly, 2, 1.0f);
            mk.w1[k * BW + c] = sweep_box(c, lx, 0, ns_inv) * sweep_box(k, ly, 0, 1.0f);
        }
#else
        mk.w1x[k] = sweep_box(k, lx, 0, ns_inv);
        mk.w3x[k] = sweep_box(k, lx, 1, ns_inv * (1.0f / 3.0f) * (1.0f / 3.0f));
        mk.w5x[k] = sweep_box(k, lx, 2, ns_inv * (0.2f * 0.2f));
        mk.w7x[k] = sweep_box(k, lx, 3, ns_inv * (1.0f / 7.0f) * (1.0f / 7.0f));
        mk.m1y[k] = sweep_box(k, ly, 0, 1.0f);
        mk.m3y[k] = sweep_box(k, ly, 1, 1.0f);
        mk.m5y[k] = sweep_box(k, ly, 2, 1.0f);
        mk.m7y[k] = sweep_box(k, ly, 3, 1.0f);
#endif
    }
    for (int q = 0; q < SUPER * SUPER; ++q) {
        const int bx = x0 + BS * (q % SUPER), by = y0 + BS * (q / SUPER);
        if (bx + R >= width || by + R >= height)
            continue;  /* a block past the image's edge */
        sweep_block_state st;
        st.cov_1 = st.cov_3 = st.cov_5 = st.cov_7 = st.cov = (float16)(0.0f);
        st.r = st.g = st.b = (float16)(0.0f);
#if SUPER > 1
        __local const uint *list = lists + q * (BN + 1);
        const int m = count[q];
#else
        __local const ulong *list = sorted;
        const int m = n;
#endif
        const int ox = BS * (q % SUPER), oy = BS * (q / SUPER);  /* block window origin */
        for (int p = 0; p < m; ++p) {
            const uint e = (uint)list[p];
            const float4 k = lrec[lid][e & 0xFFFF];
            sweep_block_step(&st, &mk, (int)((e >> 16) & 15) - ox, (int)(e >> 20) - oy, k.x,
                             k.yzw);
        }
        float r[16], gr[16], b[16], cov[16];
        vstore16(st.r, 0, r);
        vstore16(st.g, 0, gr);
        vstore16(st.b, 0, b);
        vstore16(st.cov, 0, cov);
        for (int l = 0; l < 16; ++l) {
            const int px = bx + R + (l & 3), py = by + R + (l >> 2);
            if (px < width && py < height)
                vstore3((float3)(r[l], gr[l], b[l]) / cov[l], pixel_index(px, py, width), out);
        }
    }
}
