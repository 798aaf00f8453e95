/* partition_setup.cl: per tile, merge populated depth buckets into at most MAXP partitions and
 * derive each partition's reprojection and screen-space filter (Hasselgren et al. 2015, sec. 4;
 * the derivation is in clrecon/methods/layered/__init__.py).
 *
 * partition_setup: one work-item per tile (1D range).
 *   stats   float (tiles, NBUCKETS, NSTAT) from tile_stats
 *   params  float (tiles, MAXP, NPAR), layout in layered.h; unused slots get P_DIM = 0
 * Merging, front to back over populated buckets: the running partition absorbs the next one
 * when the merged filter's sigma_u and sigma_v both stay >= (1 - threshold) times the
 * largest of the constituent buckets' own filters and <= 1 / (1 - threshold) times the
 * smallest (threshold < 0: never). If more than MAXP partitions remain, the
 * adjacent pair whose merge changes the filter least is merged until MAXP remain. Partition
 * k covers buckets (hi_{k-1}, hi_k]; the last one extends to NBUCKETS - 1, so every sample
 * has a partition. A tile without statistics gets one in-focus static partition.
 * Filter of a partition with mean CoC c and mean motion m: covariance
 *   S = (c^2 / 4 + sigma_x^2) I + m m^T / 12,
 * sigma_u >= sigma_v its principal standard deviations, theta along the major axis. The grid
 * spacing s is the smallest power of two (<= TILE) with ceil(3 sigma_u / s) + 1 <= GMAX.
 * Sheared form (B B^T = S / s^2, eq. 9): the Gaussian axis is y (P_AXIS 0, beta = S_xy/S_yy)
 * or, when S_xx > S_yy, x (P_AXIS 1, beta = S_xy/S_xx); the recursive std is
 * sqrt(det S / S_axis) / s. Reach: min(G s + ceil(|A| + |b| / 2) + 1, REACH_MAX).
 * Arguments: ntiles, sigma_x (px, the sigma_x of S above), threshold (the merge test
 * above). Compile-time: TILE, NBUCKETS, MAXP, GMAX, HAS_MOTION, REACH_MAX (gather reach cap,
 * px). The local size is a launch parameter only (tuned).
 */
#include "layered.h"

#ifndef REACH_MAX
#define REACH_MAX 96
#endif

/* A partition's mean signed CoC (the return value) and mean motion (*mx, *my; 0 without
 * HAS_MOTION) from its statistics s (NSTAT sums, layered.h). */
__attribute__((always_inline)) inline float layered_means(const float *s, float *mx, float *my)
{
    const float n = fmax(s[0], 1e-30f);
    *mx = 0.0f;
    *my = 0.0f;
#if HAS_MOTION
    *mx = s[3] / n;
    *my = s[4] / n;
#endif
    return s[1] / n;
}

/* Principal axes of a partition's filter covariance: (lambda_u, lambda_v, cov xx, xy, yy). */
inline void layered_filter(const float *s, float sx2, float *sig)
{
    float mx, my;
    const float c = layered_means(s, &mx, &my);
    const float iso = c * c * 0.25f + sx2;
    const float a = fmax(iso + mx * mx / 12.0f, 1e-4f);
    const float b = fmax(iso + my * my / 12.0f, 1e-4f);
    const float xy = mx * my / 12.0f;
    const float h = 0.5f * (a + b);
    const float d = sqrt(0.25f * (a - b) * (a - b) + xy * xy);
    sig[0] = sqrt(h + d);
    sig[1] = sqrt(fmax(h - d, 1e-4f));
    sig[2] = a;
    sig[3] = xy;
    sig[4] = b;
}

/* How far the merged filter of a and b strays from the filters of their constituent buckets
 * (ea, eb: per-axis extremes {max sigma_u, max sigma_v, min sigma_u, min sigma_v}): the larger
 * of its relative shrink below the largest (the paper's test) and of its relative growth
 * above the smallest (so that a few sharp samples are not absorbed into a wide filter).
 * Judging against the constituents, not the running mean, keeps chained merges from
 * drifting. 0: no change. */
inline float layered_shrink(const float *a, const float *b, const float *ea, const float *eb,
                            float sx2)
{
    float m[NSTAT], fm[5];
    for (int k = 0; k < NSTAT; ++k)
        m[k] = a[k] + b[k];
    layered_filter(m, sx2, fm);
    const float shrink = fmax(1.0f - fm[0] / fmax(ea[0], eb[0]),
                              1.0f - fm[1] / fmax(ea[1], eb[1]));
    const float grow = fmax(1.0f - fmin(ea[2], eb[2]) / fm[0],
                            1.0f - fmin(ea[3], eb[3]) / fm[1]);
    return fmax(shrink, grow);
}

inline void layered_extremes(float *e, const float *f)
{
    e[0] = fmax(e[0], f[0]);
    e[1] = fmax(e[1], f[1]);
    e[2] = fmin(e[2], f[2]);
    e[3] = fmin(e[3], f[3]);
}

inline void layered_write(__global float *p, const float *s, int lo, int hi, float sx2)
{
    float f[5];
    layered_filter(s, sx2, f);
    float bx, by;
    const float A = layered_means(s, &bx, &by);
    /* major axis direction: eigenvector of (lambda_u) */
    const float theta = 0.5f * atan2(2.0f * f[3], f[2] - f[4]);
    int sc = 1;
    while (sc < TILE && (int)ceil(3.0f * f[0] / sc) + 1 > GMAX)
        sc *= 2;
    const int g = min(GMAX, (int)ceil(3.0f * f[0] / sc) + 1);
    const float inv2 = 1.0f / (float)(sc * sc);
    /* sheared form: B B^T = S with the Gaussian along the axis of larger variance */
    const int axis = f[2] > f[4];
    const float along = axis ? f[2] : f[4];
    const float shv2 = along * inv2;
    const float shu2 = fmax((f[2] * f[4] - f[3] * f[3]) / along * inv2, 1e-8f);
    const float shu = sqrt(shu2);
    const float shift = fabs(A) + 0.5f * sqrt(bx * bx + by * by);
    p[P_COUNT] = s[0];
    p[P_LO] = (float)lo;
    p[P_HI] = (float)hi;
    p[P_A] = A;
    p[P_BX] = bx;
    p[P_BY] = by;
    p[P_SU] = f[0];
    p[P_SV] = f[1];
    p[P_COS] = cos(theta);
    p[P_SIN] = sin(theta);
    p[P_SHU] = shu;
    p[P_SHV] = sqrt(shv2);
    p[P_BETA] = f[3] / along;
    p[P_GAMMA] = exp(-1.41421356f / shu);
    p[P_SCALE] = (float)sc;
    p[P_GUARD] = (float)g;
    p[P_REACH] = (float)min(g * sc + (int)ceil(shift) + 1, REACH_MAX);
    p[P_DIM] = (float)(TILE / sc + 2 * g);
    p[P_AXIS] = (float)axis;
}

__kernel void partition_setup(__global const float *stats, const int ntiles,
                              const float sigma_x, const float threshold,
                              __global float *params)
{
    const int t = get_global_id(0);
    if (t >= ntiles)
        return;
    const float sx2 = sigma_x * sigma_x;
    float part[NBUCKETS][NSTAT], big[NBUCKETS][4];
    int hi[NBUCKETS];
    int np = 0;
    __global const float *st = stats + (size_t)t * NBUCKETS * NSTAT;
    for (int b = 0; b < NBUCKETS; ++b) {
        float s[NSTAT], f[5];
        for (int k = 0; k < NSTAT; ++k)
            s[k] = st[b * NSTAT + k];
        if (!(s[0] > 0.0f))
            continue;
        layered_filter(s, sx2, f);
        f[2] = f[0];
        f[3] = f[1];
        if (np > 0 && threshold >= 0.0f
            && layered_shrink(part[np - 1], s, big[np - 1], f, sx2) <= threshold) {
            for (int k = 0; k < NSTAT; ++k)
                part[np - 1][k] += s[k];
            layered_extremes(big[np - 1], f);
            hi[np - 1] = b;
            continue;
        }
        for (int k = 0; k < NSTAT; ++k)
            part[np][k] = s[k];
        for (int k = 0; k < 4; ++k)
            big[np][k] = f[k];
        hi[np] = b;
        ++np;
    }
    while (np > MAXP) {  /* too many partitions: merge the pair that loses least */
        int best = 0;
        float loss = INFINITY;
        for (int i = 0; i + 1 < np; ++i) {
            const float l = layered_shrink(part[i], part[i + 1], big[i], big[i + 1], sx2);
            if (l < loss) {
                loss = l;
                best = i;
            }
        }
        for (int k = 0; k < NSTAT; ++k)
            part[best][k] += part[best + 1][k];
        layered_extremes(big[best], big[best + 1]);
        hi[best] = hi[best + 1];
        for (int i = best + 1; i + 1 < np; ++i) {
            for (int k = 0; k < NSTAT; ++k)
                part[i][k] = part[i + 1][k];
            for (int k = 0; k < 4; ++k)
                big[i][k] = big[i + 1][k];
            hi[i] = hi[i + 1];
        }
        --np;
    }
    __global float *out = params + (size_t)t * MAXP * NPAR;
    for (int k = 0; k < MAXP * NPAR; ++k)
        out[k] = 0.0f;
    if (np == 0) {  /* no statistics: one in-focus static partition over every bucket */
        float s[NSTAT] = {0.0f};
        layered_write(out, s, 0, NBUCKETS - 1, sx2);
        return;
    }
    hi[np - 1] = NBUCKETS - 1;
    for (int i = 0; i < np; ++i)
        layered_write(out + i * NPAR, part[i], i == 0 ? 0 : hi[i - 1] + 1, hi[i], sx2);
}
