/* splat_mip.cl: method splat's mip plan (mip_radius set): every sample's PSF is drawn at the
 * pyramid level where it is small, after the samples that share a level pixel were merged, so
 * the cost per sample does not grow with the blur (clrecon/splat/mip.py).
 *
 * Levels l = 0 .. NLEV - 1, level pixel = s = 2^l x 2^l frame pixels; level l holds PSFs of
 * radius <= RL[l] and length <= ML[l] level pixels (RL[l] = R0 min(2^(l/2), 4), ML = 4 RL:
 * the coarse levels, whose bins are few, resolve their PSFs more finely). A sample with
 * r = |coc|, L = |motion| (the centre, layer and CoC as in splat.cl) goes to the lowest
 * level with r <= TR[l] = RL[l] 2^l and L <= TM[l] = ML[l] 2^l, at most NLEV - 1; there r / s
 * and L / s are clamped to RL and ML (the centre re-centred by the clamped blur, so the
 * sample stays inside the PSF that is drawn).
 *
 * splat_mip_bin_*: each sample adds into the bin of its layer, level and level pixel
 * q = floor(centre / s) (three float4: (rgb w, w), w (r/s, mx/s, my/s, 0), w (fx, fy, 0, 0),
 * w = 1 / SPP, (fx, fy) the centre's offset inside q).
 * splat_mip_draw_*: each non-empty bin draws one PSF of the bin's mean radius and motion at
 * its weighted centroid, normalised to unit sum, times (rgb w, w) of the bin, into the level
 * image: the disc (|m| < 1/2) clamp(rho + 1/2 - |d|, 0, 1), rho = max(r, 1/2) (below
 * rho = 3/2 the overlap of the pixel with the square of the disc's area), or the disc
 * swept along m, the overlap of the segment with the chord at each pixel centre, averaged
 * over the radii rho -/+ 1/4 (a box-filtered edge); a bin with r, |m| < 1/2 is the pixel q
 * itself (in-focus static samples: the box filter).
 * splat_mip_upsample: level l's image, bilinearly, into level l - 1 (1/4 per child pixel),
 * from the top level down; level 0 is then what splat_composite reads.
 *
 * Layout: float4 images [level][layer][nh_l][nw_l], nw_l = ceil(W / 2^l) + 2 P_l,
 * nh_l = ceil(H / 2^l) + 2 P_l (P_l level pixels of pad on every side); bins the same with
 * three float4 per pixel. lv[l] = (first pixel of level l, nw_l, nh_l, P_l), P_l = 2 E_l,
 * E_l = ceil(RL + ML / 2) + 2 the level's reach: a centre lies within RL + ML / 2 level
 * pixels of its frame pixel and a PSF within E_l of its bin.
 * Compile-time: SPP, HAS_MOTION, NLAYERS, NLEV, and the per-level lists TR, TM, RL, ML
 * (floats, NLEV each; TR[NLEV - 1], TM[NLEV - 1] unused).
 */
#include "common.h"

#ifndef SPP
#define SPP 1
#endif
#ifndef HAS_MOTION
#define HAS_MOTION 1
#endif
#ifndef NLAYERS
#define NLAYERS 1
#endif
#ifndef NLEV
#define NLEV 1
#endif
#ifndef TR
#define TR 8.0f
#define TM 32.0f
#define RL 8.0f
#define ML 32.0f
#endif
__constant float mip_tr[NLEV] = {TR};
__constant float mip_tm[NLEV] = {TM};
__constant float mip_rl[NLEV] = {RL};
__constant float mip_ml[NLEV] = {ML};

#define MISS_DEPTH 1e30f
/* Every helper is always_inline: at their sizes PoCL's inliner keeps some as calls, and a
 * call stops the vectorisation of the work-item loop (the bin pass ran ~20x slower). */

#define MIP_BIN_ARGS \
    __global const float *color, __global const float *position, \
    __global const float *depth, __global const float *lens, __global const float *time, \
    __global const float *motion, const float c0, const float c1, const float inv_far, \
    const float layer_scale, __global const int4 *lv, __global float *bins

#define MIP_BIN_PASS color, position, depth, lens, time, motion, c0, c1, inv_far, \
    layer_scale, lv, bins

__attribute__((always_inline)) inline void mip_add4(__global float *dst, const float4 v, const int atomic)
{
    if (atomic) {
        if (v.x != 0.0f) atomic_add_f32(dst + 0, v.x);
        if (v.y != 0.0f) atomic_add_f32(dst + 1, v.y);
        if (v.z != 0.0f) atomic_add_f32(dst + 2, v.z);
        if (v.w != 0.0f) atomic_add_f32(dst + 3, v.w);
    } else {
        vstore4(vload4(0, dst) + v, 0, dst);
    }
}

/* pixel index of level pixel (qx, qy) (unpadded) of `layer` at level `l` */
__attribute__((always_inline)) inline size_t mip_index(__global const int4 *lv, const int l, const int layer, const int qx,
                        const int qy)
{
    const int4 g = lv[l];
    return (size_t)g.x + ((size_t)layer * g.z + (size_t)(qy + g.w)) * g.y + (size_t)(qx + g.w);
}

/* Sample k's bin (its pixel index, -1: none) and what it adds there: r0..r8 = w (r, g, b, 1,
 * r / s, mx / s, my / s, fx, fy), w = 1 / SPP, (fx, fy) the centre's offset inside its bin.
 * Nine scalars (no private array), so that they stay in registers. */
#define MIP_REC float *r0, float *r1, float *r2, float *r3, float *r4, float *r5, float *r6, \
    float *r7, float *r8
#define MIP_REC_VARS float v0, v1, v2, v3, v4, v5, v6, v7, v8
#define MIP_REC_PASS &v0, &v1, &v2, &v3, &v4, &v5, &v6, &v7, &v8
__attribute__((always_inline)) inline int mip_record(const int k, MIP_BIN_ARGS, MIP_REC)
{
    const float z = depth[k];
    const int miss = z >= MISS_DEPTH;
    const float coc = miss ? c1 : c0 / z + c1;
    const float r = fabs(coc);
    float mx = 0.0f, my = 0.0f;
#if HAS_MOTION
    mx = motion[2 * k];
    my = motion[2 * k + 1];
#endif
    const float len = sqrt(mx * mx + my * my);
    /* the lowest level that holds the PSF (the thresholds increase: a count) */
    int l = 0;
    float rl = mip_rl[0], ml = mip_ml[0];
    for (int j = 0; j + 1 < NLEV; ++j) {
        const int up = r > mip_tr[j] || len > mip_tm[j];
        l += up;
        rl = up ? mip_rl[j + 1] : rl;
        ml = up ? mip_ml[j + 1] : ml;
    }
    const float s = (float)(1 << l), inv_s = 1.0f / s;
    /* beyond the top level: the largest PSF the level holds, re-centred by it */
    const float cs = r * inv_s > rl ? rl * s / r : 1.0f;
    const float ms = len * inv_s > ml ? ml * s / len : 1.0f;
    const float cc = coc * cs;
    float cx = position[2 * k] - cc * lens[2 * k];
    float cy = position[2 * k + 1] - cc * lens[2 * k + 1];
#if HAS_MOTION
    const float dt = (time[k] - 0.5f) * ms;
    cx -= dt * mx;
    cy -= dt * my;
#endif
    const float inv = miss ? 0.0f : 1.0f / z;
    const int layer = clamp((int)floor((inv - inv_far) * layer_scale), 0, NLAYERS - 1);
    cx *= inv_s;
    cy *= inv_s;
    const float fx = floor(cx), fy = floor(cy);
    const int4 g = lv[l];
    const int qx = (int)fx, qy = (int)fy;
    /* centres beyond the pad cannot reach the frame (the host sizes P_l so that none of a
     * valid frame's are); no early return: straight-line code vectorises */
    const int e = g.w / 2;  /* the level's reach */
    const int out = qx < e - g.w || qy < e - g.w || qx >= g.y - g.w - e
                    || qy >= g.z - g.w - e;
    const float w = 1.0f / (float)SPP, wm = w * ms * inv_s;
    *r0 = color[3 * k] * w;
    *r1 = color[3 * k + 1] * w;
    *r2 = color[3 * k + 2] * w;
    *r3 = w;
    *r4 = r * cs * inv_s * w;
    *r5 = mx * wm;
    *r6 = my * wm;
    *r7 = (cx - fx) * w;
    *r8 = (cy - fy) * w;
    return out ? -1 : (int)mip_index(lv, l, layer, qx, qy);
}

/* A record into bin idx: three float4 (rgb w, w), w (r, mx, my, 0) / s, w (fx, fy, 0, 0) */
__attribute__((always_inline)) inline void mip_add1(__global float *dst, const float v, const int atomic)
{
    if (!atomic)
        *dst += v;
    else if (v != 0.0f)
        atomic_add_f32(dst, v);
}

__attribute__((always_inline)) inline void mip_bin_add(__global float *bins, const int idx, const float v0, const float v1,
                        const float v2, const float v3, const float v4, const float v5,
                        const float v6, const float v7, const float v8, const int atomic)
{
    __global float *b = bins + (size_t)idx * 12;
    mip_add1(b + 0, v0, atomic);
    mip_add1(b + 1, v1, atomic);
    mip_add1(b + 2, v2, atomic);
    mip_add1(b + 3, v3, atomic);
    mip_add1(b + 4, v4, atomic);
    mip_add1(b + 5, v5, atomic);
    mip_add1(b + 6, v6, atomic);
    mip_add1(b + 8, v7, atomic);
    mip_add1(b + 9, v8, atomic);
}

/* One work-item per sample, atomic adds (any device). */
__kernel void splat_mip_bin_samples(MIP_BIN_ARGS, const int nsamples)
{
    const int k = get_global_id(0);
    if (k >= nsamples)
        return;
    MIP_REC_VARS;
    const int idx = mip_record(k, MIP_BIN_PASS, MIP_REC_PASS);
    if (idx >= 0)
        mip_bin_add(bins, idx, v0, v1, v2, v3, v4, v5, v6, v7, v8, 1);
}

#define ROW_MAX 512
/* One work-item (and work-group) per owner tile of tile x tile frame pixels: the
 * host launches the k x k phases in turn with (k - 1) tile > 2 R - 1, R bounding how
 * far from its pixel a sample's bin lies (frame pixels), so no two work-items of a launch
 * write the same bin. Along each row of its tile, ROW_MAX samples at a time: the records
 * go into local memory in one loop over contiguous samples, which the compiler vectorises
 * (the same arithmetic interleaved with the adds ran ~10x slower on PoCL), then are added
 * in order: plain adds, a fixed order (reproducible). */
__kernel void splat_mip_bin_tiles(MIP_BIN_ARGS, const int width, const int height,
                                  const int tile, const int k, const int phase_x,
                                  const int phase_y)
{
    __local int ridx[ROW_MAX];
    __local float r0[ROW_MAX], r1[ROW_MAX], r2[ROW_MAX], r3[ROW_MAX], r4[ROW_MAX],
        r5[ROW_MAX], r6[ROW_MAX], r7[ROW_MAX], r8[ROW_MAX];
    const int x0 = (k * (int)get_group_id(0) + phase_x) * tile;
    const int y0 = (k * (int)get_group_id(1) + phase_y) * tile;
    if (x0 >= width || y0 >= height)
        return;
    const int row = (min(x0 + tile, width) - x0) * SPP;
    for (int y = y0; y < min(y0 + tile, height); ++y)
        for (int c = 0; c < row; c += ROW_MAX) {
            const int first = (y * width + x0) * SPP + c, n = min(ROW_MAX, row - c);
            for (int j = 0; j < n; ++j) {
                MIP_REC_VARS;
                ridx[j] = mip_record(first + j, MIP_BIN_PASS, MIP_REC_PASS);
                r0[j] = v0;
                r1[j] = v1;
                r2[j] = v2;
                r3[j] = v3;
                r4[j] = v4;
                r5[j] = v5;
                r6[j] = v6;
                r7[j] = v7;
                r8[j] = v8;
            }
            for (int j = 0; j < n; ++j)
                if (ridx[j] >= 0)
                    mip_bin_add(bins, ridx[j], r0[j], r1[j], r2[j], r3[j], r4[j], r5[j],
                                r6[j], r7[j], r8[j], 0);
        }
}

/* The unnormalised PSF at offset d (level pixels) from its centre: the antialiased disc of
 * radius rho, or (len >= 1/2) that disc swept along len u, u a unit vector. */
__attribute__((always_inline)) inline float mip_psf(const float2 d, const float rho, const float len, const float2 u)
{
    if (len < 0.5f) {
        if (rho >= 1.5f)
            return clamp(rho + 0.5f - length(d), 0.0f, 1.0f);
        /* a small disc: the pixel's overlap with the square of the disc's area (the pixel
         * integral the antialiased disc overestimates by ~40% at the rim here) */
        const float a = 0.886227f * rho;  /* half the side: sqrt(pi) rho / 2 */
        const float ox = fmax(fmin(d.x + 0.5f, a) - fmax(d.x - 0.5f, -a), 0.0f);
        const float oy = fmax(fmin(d.y + 0.5f, a) - fmax(d.y - 0.5f, -a), 0.0f);
        return ox * oy;
    }
    const float x = dot(d, u), y = d.y * u.x - d.x * u.y, half_len = 0.5f * len;
    float v = 0.0f;
    for (int j = 0; j < 2; ++j) {
        const float rr = rho + (j ? 0.25f : -0.25f);
        const float h = sqrt(fmax(rr * rr - y * y, 0.0f));
        v += fmax(fmin(x + h, half_len) - fmax(x - h, -half_len), 0.0f);
    }
    return v;
}

/* A bin's PSF: its weight b0, centre c (level pixels), radius, length, direction, the
 * pixels it covers [x0, x1] x [y0, y1] (within the level's reach of the bin), and where it is. */
typedef struct {
    float4 b0;
    float2 c, u;
    float rho, len, sum;
    int x0, x1, y0, y1, point;
    size_t bi;
} mip_psf_t;

/* The PSF of bin (qx, qy) of `layer` at level l; 0 for an empty bin. A point (r, |m| < 1/2)
 * is the bin's pixel itself; sum is the PSF's analytic sum, or 0 where the pixels must be
 * summed (small radii). */
__attribute__((always_inline)) inline int mip_params(const int l, const int layer, const int qx, const int qy,
                      __global float *bins, __global const int4 *lv, mip_psf_t *p)
{
    p->bi = mip_index(lv, l, layer, qx, qy);
    p->b0 = vload4(0, bins + p->bi * 12);
    if (!(p->b0.w > 0.0f))
        return 0;
    const float iw = 1.0f / p->b0.w;
    const float4 b1 = vload4(0, bins + p->bi * 12 + 4) * iw;
    const float4 b2 = vload4(0, bins + p->bi * 12 + 8) * iw;
    /* the bin is consumed: zeroed for the next frame (the host then skips its clear) */
    vstore4((float4)(0.0f), 0, bins + p->bi * 12);
    vstore4((float4)(0.0f), 0, bins + p->bi * 12 + 4);
    vstore4((float4)(0.0f), 0, bins + p->bi * 12 + 8);
    const float2 m = (float2)(b1.y, b1.z);
    p->len = length(m);
    p->point = b1.x < 0.5f && p->len < 0.5f;
    p->rho = fmax(b1.x, 0.5f);
    p->u = p->len > 0.0f ? m / p->len : (float2)(1.0f, 0.0f);
    p->c = (float2)((float)qx + b2.x, (float)qy + b2.y);
    const float2 e = fabs(p->u) * (0.5f * p->len) + (float2)(p->rho + 1.0f);
    const int reach = lv[l].w / 2;
    p->x0 = max((int)floor(p->c.x - e.x), qx - reach);
    p->x1 = min((int)floor(p->c.x + e.x), qx + reach);
    p->y0 = max((int)floor(p->c.y - e.y), qy - reach);
    p->y1 = min((int)floor(p->c.y + e.y), qy + reach);
    /* the plane integral of mip_psf (the disc pi (rho^2 + 1/12), the swept disc
     * 2 len pi (rho^2 + 1/16)), which the pixel sum matches to ~1% from rho = 3 (disc) and
     * rho = 4 (swept) on (tests/test_splat_mip.py); below, the pixels are summed. (An
     * energy error cancels in the layer's colour, rgb / coverage.) */
    const float r2 = p->rho * p->rho;
    p->sum = p->len < 0.5f ? (p->rho >= 3.0f ? M_PI_F * (r2 + (1.0f / 12.0f)) : 0.0f)
                           : (p->rho >= 4.0f ? 2.0f * p->len * M_PI_F * (r2 + 0.0625f) : 0.0f);
    return 1;
}

__attribute__((always_inline)) inline float mip_psf_at(const mip_psf_t *p, const int x, const int y)
{
    return mip_psf((float2)((float)x + 0.5f, (float)y + 0.5f) - p->c, p->rho, p->len, p->u);
}

/* The chord of row y (pixel centres at y + 1/2) through the disc of radius r at q: [lo, hi],
 * or lo > hi. */
__attribute__((always_inline)) inline float2 mip_chord(const float2 q, const float r,
                                                      const int y)
{
    const float dy = (float)y + 0.5f - q.y;
    if (!(r > 0.0f) || dy * dy > r * r)
        return (float2)(1.0f, -1.0f);
    const float h = sqrt(r * r - dy * dy);
    return (float2)(q.x - h, q.x + h);
}

/* What row y of p's PSF covers: pixels [*xa, *xb] (a superset of the non-zero ones, within
 * the PSF's box) and inside it [*ia, *ib] where the PSF is the constant *vin (empty:
 * *ia > *ib): the disc's inner chord (rho - 1/2: value 1), or for the swept disc the pixels
 * whose discs of radius rho - 1/4 hold the whole segment (value 2 len). The rest is
 * evaluated pixel by pixel. */
__attribute__((always_inline)) inline void mip_row(const mip_psf_t *p, const int y, int *xa,
                                                  int *xb, int *ia, int *ib, float *vin)
{
    float2 out = (float2)((float)p->x0 + 0.5f, (float)p->x1 + 0.5f), in = (float2)(1.0f, -1.0f);
    *vin = 0.0f;
    if (p->len < 0.5f) {
        if (p->rho >= 1.5f) {
            out = mip_chord(p->c, p->rho + 0.5f, y);
            in = mip_chord(p->c, p->rho - 0.5f, y);
            *vin = 1.0f;
        }
    } else {
        /* the swept disc of radius R = rho + 1/4 is convex: its row is one interval, the
         * hull of the end discs' chords and of the band |(x - c) . n| <= R,
         * |(x - c) . u| <= len / 2 between them */
        const float2 e = (0.5f * p->len) * p->u;
        const float R = p->rho + 0.25f, dy = (float)y + 0.5f - p->c.y;
        const float2 ca = mip_chord(p->c - e, R, y), cb = mip_chord(p->c + e, R, y);
        float lo = INFINITY, hi = -INFINITY;
        if (ca.x <= ca.y) { lo = ca.x; hi = ca.y; }
        if (cb.x <= cb.y) { lo = fmin(lo, cb.x); hi = fmax(hi, cb.y); }
        /* band, in t = x - c.x: |dy u.x - t u.y| <= R and |t u.x + dy u.y| <= len / 2 */
        float blo = -INFINITY, bhi = INFINITY;
        const float n0 = dy * p->u.x, m0 = dy * p->u.y, hl = 0.5f * p->len;
        if (fabs(p->u.y) > 1e-6f) {
            const float t1 = (n0 - R) / p->u.y, t2 = (n0 + R) / p->u.y;
            blo = fmax(blo, fmin(t1, t2));
            bhi = fmin(bhi, fmax(t1, t2));
        } else if (fabs(n0) > R) {
            bhi = -INFINITY;
        }
        if (fabs(p->u.x) > 1e-6f) {
            const float t1 = (-hl - m0) / p->u.x, t2 = (hl - m0) / p->u.x;
            blo = fmax(blo, fmin(t1, t2));
            bhi = fmin(bhi, fmax(t1, t2));
        } else if (fabs(m0) > hl) {
            bhi = -INFINITY;
        }
        if (blo <= bhi) { lo = fmin(lo, p->c.x + blo); hi = fmax(hi, p->c.x + bhi); }
        out = (float2)(lo, hi);
        if (p->rho >= 0.5f) {
            const float ri = p->rho - 0.25f;
            const float2 ia_ = mip_chord(p->c - e, ri, y), ib_ = mip_chord(p->c + e, ri, y);
            in = (float2)(fmax(ia_.x, ib_.x), fmin(ia_.y, ib_.y));
            *vin = 2.0f * p->len;
        }
    }
    if (!(out.x <= out.y)) {  /* the row misses the PSF */
        *xa = p->x1 + 1;
        *xb = p->x1;
        *ia = *xb + 1;
        *ib = *xb;
        return;
    }
    /* pixel x's centre x + 1/2; one pixel of slack on the outer range (its value decides) */
    *xa = max(p->x0, (int)floor(out.x - 0.5f));
    *xb = min(p->x1, (int)floor(out.y - 0.5f) + 1);
    *ia = *xb + 1;
    *ib = *xb;
    if (in.x <= in.y) {
        *ia = max((int)ceil(in.x - 0.5f), *xa);
        *ib = min((int)floor(in.y - 0.5f), *xb);
    }
}

/* Draw bin (qx, qy) of `layer` at level l into img, one work-item alone. */
__attribute__((always_inline)) inline void mip_draw_one(const int l, const int layer,
                                                       const int qx, const int qy,
                                                       const int atomic,
                                                       __global float *bins,
                                                       __global float *img,
                                                       __global const int4 *lv)
{
    mip_psf_t p;
    if (!mip_params(l, layer, qx, qy, bins, lv, &p))
        return;
    int xa, xb, ia, ib;
    float vin;
    float sum = p.sum;
    if (!p.point && !(sum > 0.0f)) {
        for (int y = p.y0; y <= p.y1; ++y) {
            mip_row(&p, y, &xa, &xb, &ia, &ib, &vin);
            for (int x = xa; x < ia; ++x)
                sum += mip_psf_at(&p, x, y);
            sum += (float)max(ib - ia + 1, 0) * vin;
            for (int x = max(ib + 1, ia); x <= xb; ++x)
                sum += mip_psf_at(&p, x, y);
        }
    }
    if (p.point || !(sum > 0.0f)) {
        mip_add4(img + p.bi * 4, p.b0, atomic);
        return;
    }
    const float4 wv = p.b0 * (1.0f / sum);
    const int4 g = lv[l];
    __global float *base = img + ((size_t)g.x + (size_t)layer * g.z * g.y) * 4;
    for (int y = p.y0; y <= p.y1; ++y) {
        __global float *row = base + (size_t)(y + g.w) * g.y * 4;
        mip_row(&p, y, &xa, &xb, &ia, &ib, &vin);
        for (int x = xa; x < ia; ++x) {
            const float v = mip_psf_at(&p, x, y);
            if (v > 0.0f)
                mip_add4(row + (size_t)(x + g.w) * 4, v * wv, atomic);
        }
        const float4 wi = vin * wv;
        if (atomic) {
            for (int x = ia; x <= ib; ++x)
                mip_add4(row + (size_t)(x + g.w) * 4, wi, 1);
        } else {  /* a run of plain adds, which vectorises */
            __global float4 *run = (__global float4 *)row + g.w;
            for (int x = ia; x <= ib; ++x)
                run[x] += wi;
        }
        for (int x = max(ib + 1, ia); x <= xb; ++x) {
            const float v = mip_psf_at(&p, x, y);
            if (v > 0.0f)
                mip_add4(row + (size_t)(x + g.w) * 4, v * wv, atomic);
        }
    }
}

/* One work-item per bin (x, y of the widest level, z = level * NLAYERS + layer), atomic. */
__kernel void splat_mip_draw_bins(__global float *bins, __global float *img,
                                  __global const int4 *lv)
{
    const int l = get_global_id(2) / NLAYERS, layer = get_global_id(2) % NLAYERS;
    const int4 g = lv[l];
    const int qx = get_global_id(0) - g.w, qy = get_global_id(1) - g.w;
    if (qx >= g.y - g.w || qy >= g.z - g.w)
        return;
    mip_draw_one(l, layer, qx, qy, 1, bins, img, lv);
}

/* One work-item per tile of tile x tile level pixels at every level (z = level * NLAYERS +
 * layer), phases k x k with (k - 1) tile > 2 E - 1, E the largest level reach: no two
 * work-items of a launch
 * write one pixel, plain adds in a fixed order. Tiles cover the padded grid. */
__kernel void splat_mip_draw_tiles(__global float *bins, __global float *img,
                                   __global const int4 *lv, const int tile, const int k,
                                   const int phase_x, const int phase_y)
{
    const int l = get_global_id(2) / NLAYERS, layer = get_global_id(2) % NLAYERS;
    const int4 g = lv[l];
    const int x0 = (k * get_global_id(0) + phase_x) * tile;
    const int y0 = (k * get_global_id(1) + phase_y) * tile;
    /* bins within the reach of the border hold nothing (mip_record skips them) */
    const int e = g.w / 2;
    if (x0 >= g.y - e || y0 >= g.z - e)
        return;
    const int x1 = min(x0 + tile, g.y - e), y1 = min(y0 + tile, g.z - e);
    const int xs = max(x0, e);
    for (int y = max(y0, e); y < y1; ++y) {
        /* most bins are empty (a layer covers part of the frame): a tight scan of their
         * weights first */
        __global const float *w = bins + mip_index(lv, l, layer, xs - g.w, y - g.w) * 12 + 3;
        for (int x = xs; x < x1; ++x)
            if (w[(size_t)(x - xs) * 12] > 0.0f)
                mip_draw_one(l, layer, x - g.w, y - g.w, 0, bins, img, lv);
    }
}

/* Level l's image, bilinearly, added into level l - 1: one work-item per padded pixel of
 * level l - 1 (z = layer). Level-l pixel i (padded) has its centre at child coordinate
 * 2 (i - P_l) + 1/2 + P_{l-1}; a child pixel j reads its parent at
 * (j - P_{l-1}) / 2 - 1/4 + P_l. */
__kernel void splat_mip_upsample(__global float *img, __global const int4 *lv, const int l,
                                 const int margin)
{
    /* only what is read on: level l - 1's frame region and `margin` pixels around it (0 for
     * level 0, what the composite reads; the next upsample reads within 3 of its frame) */
    const int4 gc = lv[l - 1], gp = lv[l];
    const int x = get_global_id(0) + gc.w - margin, y = get_global_id(1) + gc.w - margin;
    const int layer = get_global_id(2);
    if (x >= gc.y - gc.w + margin || y >= gc.z - gc.w + margin)
        return;
    const float ux = 0.5f * (float)(x - gc.w) - 0.25f + (float)gp.w;
    const float uy = 0.5f * (float)(y - gc.w) - 0.25f + (float)gp.w;
    const float fx0 = floor(ux), fy0 = floor(uy);
    const float fx = ux - fx0, fy = uy - fy0;
    const int ix = (int)fx0, iy = (int)fy0;
    __global const float *par = img + ((size_t)gp.x + (size_t)layer * gp.z * gp.y) * 4;
    float4 acc = (float4)(0.0f);
    for (int dy = 0; dy < 2; ++dy) {
        const int py = iy + dy;
        if (py < 0 || py >= gp.z)
            continue;
        const float wy = dy ? fy : 1.0f - fy;
        for (int dx = 0; dx < 2; ++dx) {
            const int px = ix + dx;
            if (px < 0 || px >= gp.y)
                continue;
            acc += (wy * (dx ? fx : 1.0f - fx)) * vload4((size_t)py * gp.y + px, par);
        }
    }
    __global float *dst = img + ((size_t)gc.x + ((size_t)layer * gc.z + y) * gc.y + x) * 4;
    vstore4(vload4(0, dst) + 0.25f * acc, 0, dst);
}
