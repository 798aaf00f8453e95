/* splat_mip_draw.cl: the draw and upsample passes of method splat's mip plan (splat_mip.h has
 * the plan, its levels and the layout of bins and images).
 *
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
 *   splat_mip_draw_bins    one work-item per bin, atomic adds (any device)
 *   splat_mip_draw_tiles   one work-item per owner tile of every level, k x k phases, plain
 *                          adds in a fixed order (reproducible)
 * Arguments: bins float (pixels, 12) from splat_mip_bin.cl (each drawn bin is zeroed: the
 * next frame's bin pass needs no clear), img float4 (pixels) zeroed before the first draw,
 * lv (int4 per level); the upsample's l (the level read, >= 1) and margin.
 * Compile-time: NLAYERS (default in splat.h; the host builds both files of the plan with the
 * bin pass's defines).
 */
#include "splat_mip.h"

__attribute__((always_inline)) inline void mip_add4(__global float *dst, const float4 v,
                                                    const int atomic)
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

/* The unnormalised PSF at offset d (level pixels) from its centre: the antialiased disc of
 * radius rho, or (len >= 1/2) that disc swept along len u, u a unit vector. */
__attribute__((always_inline)) inline float mip_psf(const float2 d, const float rho,
                                                    const float len, const float2 u)
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
__attribute__((always_inline)) inline int mip_params(const int l, const int layer, const int qx,
                                                     const int qy, __global float *bins,
                                                     __global const int4 *lv, mip_psf_t *p)
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
     * rho = 4 (swept) on (tests/passes/test_splat_mip.py); below, the pixels are summed. (An
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

/* Draw a disc (rho >= 3/2, no motion) with plain adds, row by row: each row's outer chord
 * in one loop, four pixels at a time (inside the inner chord the antialiased disc is 1, so
 * the one expression serves the rim and the inside; mip_row's split into runs is slower
 * here: PoCL ran the draw pass 1.4x faster this way on deep 1280x720). */
__attribute__((always_inline)) inline void mip_disc_plain(const mip_psf_t *p, const float4 wv,
                                                         __global float *base, const int nw,
                                                         const int pad)
{
    const float ro = p->rho + 0.5f;
    for (int y = p->y0; y <= p->y1; ++y) {
        const float dy = (float)y + 0.5f - p->c.y, dy2 = dy * dy;
        if (dy2 > ro * ro)
            continue;
        /* the row's pixels as mip_row has them: the outer chord and one pixel of slack */
        const float h = sqrt(ro * ro - dy2);
        const int xa = max(p->x0, (int)floor(p->c.x - h - 0.5f));
        const int xb = min(p->x1, (int)floor(p->c.x + h - 0.5f) + 1);
        __global float4 *row = (__global float4 *)(base + (size_t)(y + pad) * nw * 4) + pad;
        int x = xa;
        for (; x + 3 <= xb; x += 4) {
            const float4 dx = ((float4)((float)x, (float)x + 1.0f, (float)x + 2.0f,
                                        (float)x + 3.0f) + 0.5f) - p->c.x;
            const float4 v = clamp(ro - sqrt(dx * dx + dy2), 0.0f, 1.0f);
            row[x] += v.x * wv;
            row[x + 1] += v.y * wv;
            row[x + 2] += v.z * wv;
            row[x + 3] += v.w * wv;
        }
        for (; x <= xb; ++x) {
            const float dx = (float)x + 0.5f - p->c.x;
            row[x] += clamp(ro - sqrt(dx * dx + dy2), 0.0f, 1.0f) * wv;
        }
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
    if (!atomic && p.len < 0.5f && p.rho >= 1.5f) {
        mip_disc_plain(&p, wv, base, g.y, g.w);
        return;
    }
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
 * level l - 1, for every layer (the taps' addresses and weights once for all layers: half
 * the time of a work-item per layer on PoCL). Level-l pixel i (padded) has its centre at
 * child coordinate 2 (i - P_l) + 1/2 + P_{l-1}; a child pixel j reads its parent at
 * (j - P_{l-1}) / 2 - 1/4 + P_l. */
__kernel void splat_mip_upsample(__global float *img, __global const int4 *lv, const int l,
                                 const int margin)
{
    /* only what is read on: level l - 1's frame region and `margin` pixels around it (0 for
     * level 0, what the composite reads; the next upsample reads within 3 of its frame) */
    const int4 gc = lv[l - 1], gp = lv[l];
    const int x = get_global_id(0) + gc.w - margin, y = get_global_id(1) + gc.w - margin;
    if (x < gc.y - gc.w + margin && y < gc.z - gc.w + margin) {
        const float ux = 0.5f * (float)(x - gc.w) - 0.25f + (float)gp.w;
        const float uy = 0.5f * (float)(y - gc.w) - 0.25f + (float)gp.w;
        const float fx0 = floor(ux), fy0 = floor(uy);
        const float fx = ux - fx0, fy = uy - fy0;
        const int ix = (int)fx0, iy = (int)fy0;
        /* the four taps at clamped addresses, a tap outside the parent weighted 0: no
         * branch, and the same sum (0 x a finite value adds nothing) */
        const int px0 = clamp(ix, 0, gp.y - 1), px1 = clamp(ix + 1, 0, gp.y - 1);
        const int r0 = clamp(iy, 0, gp.z - 1) * gp.y, r1 = clamp(iy + 1, 0, gp.z - 1) * gp.y;
        const float wx0 = (ix >= 0 && ix < gp.y) ? 1.0f - fx : 0.0f;
        const float wx1 = (ix + 1 >= 0 && ix + 1 < gp.y) ? fx : 0.0f;
        const float wy0 = (iy >= 0 && iy < gp.z) ? 1.0f - fy : 0.0f;
        const float wy1 = (iy + 1 >= 0 && iy + 1 < gp.z) ? fy : 0.0f;
        for (int layer = 0; layer < NLAYERS; ++layer) {
            __global const float4 *par = (__global const float4 *)img + gp.x
                                         + layer * gp.z * gp.y;
            float4 acc = (wy0 * wx0) * par[r0 + px0];
            acc += (wy0 * wx1) * par[r0 + px1];
            acc += (wy1 * wx0) * par[r1 + px0];
            acc += (wy1 * wx1) * par[r1 + px1];
            __global float4 *dst = (__global float4 *)img + gc.x + (layer * gc.z + y) * gc.y + x;
            *dst += 0.25f * acc;
        }
    }
}
