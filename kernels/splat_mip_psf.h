/* splat_mip_psf.h: the PSFs that method splat's mip plan draws (splat_mip_draw.cl), their
 * parameters from a bin and the pixels each row of them covers:
 *   mip_psf         the unnormalised PSF at an offset: the antialiased disc, a small disc's
 *                   pixel overlap, or the disc swept along the motion
 *   mip_params      a bin's PSF (weight, centre, radius, length, direction, pixel box,
 *                   analytic sum); it zeroes the bin it reads
 *   mip_psf_at      mip_psf at a level pixel's centre
 *   mip_chord       one row's chord through a disc
 *   mip_row         the pixels of a row that the PSF may cover, and its constant inside
 */
#ifndef CLRECON_SPLAT_MIP_PSF_H
#define CLRECON_SPLAT_MIP_PSF_H

#include "splat_mip.h"

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

#endif /* CLRECON_SPLAT_MIP_PSF_H */
