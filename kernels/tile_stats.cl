/* tile_stats.cl: per screen tile and depth bucket, the count and the sums from which the
 * mean and variance of CoC and motion follow (Hasselgren et al. 2015, section 4).
 *
 * tile_stats: one work-item per TILE x TILE tile (1D range over ntx * nty tiles).
 *   depth   float (H, W, T); motion float (H, W, T, 2) (read only with HAS_MOTION), T =
 *           sample_stride samples per pixel in the buffers, this frame's S from
 *           sample_offset on (a whole frame: T = S, offset 0)
 *   stats   float (tiles, NBUCKETS, NSTAT): n, sum coc, sum coc^2, sum mx, sum my,
 *           sum mx^2, sum my^2, sum mx*my (layered.h)
 * A tile's samples are addressed a = m * S + i, m the Morton index of the pixel in the tile
 * (TILE a power of two). Sparse statistics (stride n > 1): from each run of n addresses
 * [j n, (j + 1) n) one address j n + r % n, r from a xorshift32 seeded by (seed, tile), is
 * visited; stride 1 visits every sample. Addresses of pixels outside the image are skipped.
 * coc(w) = c0 / w + c1 (misses: c1); buckets as in layered.h. The visits go BATCH at a time:
 * their addresses and loads, then their adds in visit order (the sums of one at a time, bit
 * for bit); the loads of a sparse visit miss the caches, and a batch overlaps them.
 * Compile-time: SPP, TILE, NBUCKETS, HAS_MOTION, BATCH. The local
 * size is a launch parameter only (tuned).
 */
#include "layered.h"

#ifndef SPP
#define SPP 8
#endif
#ifndef BATCH
#define BATCH 32   /* visits whose loads are issued together (16: 0.875x, 32: 0.80x,
                      * 64: as 32, against one at a time; deep 1280x720 8 spp, PoCL) */
#endif

__kernel void tile_stats(__global const float *depth, __global const float *motion,
                         const int sample_stride, const int sample_offset,
                         const int width, const int height, const int ntx, const int ntiles,
                         const float ka, const float kb, const float kc, const float c0,
                         const float c1, const int stride, const uint seed,
                         __global float *stats)
{
    const int t = get_global_id(0);
    if (t >= ntiles)
        return;
    const int x0 = (t % ntx) * TILE, y0 = (t / ntx) * TILE;
    float acc[NBUCKETS * NSTAT];
    for (int k = 0; k < NBUCKETS * NSTAT; ++k)
        acc[k] = 0.0f;
    uint state = (seed * 0x9E3779B9u) ^ ((uint)t * 0x85EBCA6Bu + 0x632BE5ABu);
    if (state == 0u)
        state = 1u;
    const int total = TILE * TILE * SPP;
    /* BATCH visits at a time: their addresses and loads first (independent, so their cache
     * misses overlap), then their adds in visit order (the same sums as one at a time) */
    const int visits = 1 + (total - 1) / stride;   /* v stride < total: no overflow */
    for (int v0 = 0; v0 < visits; v0 += BATCH) {
        float w[BATCH];
#if HAS_MOTION
        float2 mv[BATCH];
#endif
        int ok[BATCH];
        for (int u = 0; u < BATCH; ++u) {
            ok[u] = 0;
            w[u] = 0.0f;
#if HAS_MOTION
            mv[u] = (float2)(0.0f);
#endif
            if (v0 + u >= visits)
                continue;
            const int j = (v0 + u) * stride;
            int a = j;
            if (stride > 1)
                a += (int)(xorshift32(&state) % (uint)min(stride, total - j));
            const uint m = (uint)(a / SPP);
            const int x = x0 + (int)morton_even(m), y = y0 + (int)morton_even(m >> 1);
            if (x >= width || y >= height)
                continue;
            const size_t s = ((size_t)y * width + x) * sample_stride + sample_offset + a % SPP;
            ok[u] = 1;
            w[u] = depth[s];
#if HAS_MOTION
            mv[u] = vload2(s, motion);
#endif
        }
        for (int u = 0; u < BATCH; ++u) {
            if (!ok[u])
                continue;
            const int b = layered_bucket(w[u], ka, kb, kc);
            const float coc = (w[u] < MISS_DEPTH) ? c0 / w[u] + c1 : c1;
            __private float *p = acc + b * NSTAT;
            p[0] += 1.0f;
            p[1] += coc;
            p[2] += coc * coc;
#if HAS_MOTION
            p[3] += mv[u].x;
            p[4] += mv[u].y;
            p[5] += mv[u].x * mv[u].x;
            p[6] += mv[u].y * mv[u].y;
            p[7] += mv[u].x * mv[u].y;
#endif
        }
    }
    __global float *out = stats + (size_t)t * NBUCKETS * NSTAT;
    for (int k = 0; k < NBUCKETS * NSTAT; ++k)
        out[k] = acc[k];
}
