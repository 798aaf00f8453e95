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
 * lv (int4 per level); the tiles' flags uchar (pixels), 1 where the bin pass filled a bin
 * (zeroed as the bin is drawn); the upsample's l (the level read, >= 1) and margin.
 * Compile-time: NLAYERS (default in splat.h; the host builds both files of the plan with the
 * bin pass's defines).
 */
#include "splat_mip_psf.h"  /* the PSFs, their parameters and rows (and splat_mip.h) */

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

/* The swept disc (len >= 1/2) at four pixels of a row: mip_psf, lane by lane (d.x of each
 * lane in dx, the row's d.y in dy). */
__attribute__((always_inline)) inline float4 mip_swept4(const mip_psf_t *p, const float4 dx,
                                                       const float dy)
{
    const float4 x = dx * p->u.x + dy * p->u.y, y = dy * p->u.x - dx * p->u.y;
    const float hl = 0.5f * p->len;
    float4 v = (float4)(0.0f);
    for (int j = 0; j < 2; ++j) {
        const float rr = p->rho + (j ? 0.25f : -0.25f);
        const float4 h = sqrt(fmax(rr * rr - y * y, 0.0f));
        v += fmax(fmin(x + h, hl) - fmax(x - h, -hl), 0.0f);
    }
    return v;
}

/* A PSF's shape (mip_psf): a small disc's pixel overlap, the antialiased disc, the swept disc */
#define MIP_SMALL 0
#define MIP_DISC 1
#define MIP_SWEPT 2

/* mip_psf at four pixels of a row, lane by lane (each lane's d.x in dx, the row's d.y in dy):
 * the antialiased disc, a small disc's pixel overlap or the swept disc. */
__attribute__((always_inline)) inline float4 mip_psf4(const mip_psf_t *p, const float4 dx,
                                                     const float dy, const int shape)
{
    if (shape == MIP_SWEPT)
        return mip_swept4(p, dx, dy);
    if (shape == MIP_DISC)
        return clamp(p->rho + 0.5f - sqrt(dx * dx + dy * dy), 0.0f, 1.0f);
    const float a = 0.886227f * p->rho;
    const float4 ox = fmax(fmin(dx + 0.5f, a) - fmax(dx - 0.5f, -a), 0.0f);
    const float oy = fmax(fmin(dy + 0.5f, a) - fmax(dy - 0.5f, -a), 0.0f);
    return ox * oy;
}

/* Row y of p's PSF over its whole box [x0, x1], four pixels at a time: the sum of its values
 * (add == 0) or their adds of v wv into row (add == 1; plain adds). Every row of a bin runs
 * the same count of steps, the pixels outside the PSF adding 0: the branches stay
 * predictable. Clipping each row to its chord (mip_row) did less arithmetic and took longer:
 * the draw pass of deep 1280x720 at 8 spp (PoCL, Xeon, both of the safeguard's halves)
 * 338-358 ms with the chords and the swept discs pixel by pixel, 273-293 ms with the swept
 * discs in lanes, and about 200 ms over the boxes. */
__attribute__((always_inline)) inline float mip_box_row(const mip_psf_t *p, const int y,
                                                       const float4 wv,
                                                       __global float4 *row, const int add,
                                                       const int shape)
{
    const float dy = (float)y + 0.5f - p->c.y;
    if (shape == MIP_DISC && dy * dy > (p->rho + 0.5f) * (p->rho + 0.5f))
        return 0.0f;  /* the row misses the disc */
    float4 acc = (float4)(0.0f);
    int x = p->x0;
    for (; x + 3 <= p->x1; x += 4) {
        const float4 dx = ((float4)((float)x, (float)x + 1.0f, (float)x + 2.0f,
                                    (float)x + 3.0f) + 0.5f) - p->c.x;
        const float4 v = mip_psf4(p, dx, dy, shape);
        if (add) {
            row[x] += v.x * wv;
            row[x + 1] += v.y * wv;
            row[x + 2] += v.z * wv;
            row[x + 3] += v.w * wv;
        } else {
            acc += v;
        }
    }
    float sum = (acc.x + acc.y) + (acc.z + acc.w);
    for (; x <= p->x1; ++x) {
        const float v = mip_psf4(p, (float4)((float)x + 0.5f - p->c.x), dy, shape).x;
        if (add)
            row[x] += v * wv;
        else
            sum += v;
    }
    return sum;
}

/* p's PSF of the given shape (a constant at each call: one specialised loop a shape), normalised
 * to unit sum (its analytic sum, or its pixels' where none is set), times the bin's
 * (rgb w, w), into its level image with plain adds; a PSF whose pixels sum to 0 adds the
 * bin at its own pixel. */
__attribute__((always_inline)) inline void mip_draw_box(const mip_psf_t *p, __global float *img,
                                                       __global float *base, const int4 g,
                                                       const int shape)
{
    float sum = p->sum;
    if (!(sum > 0.0f))
        for (int y = p->y0; y <= p->y1; ++y)
            sum += mip_box_row(p, y, (float4)(0.0f), 0, 0, shape);
    if (!(sum > 0.0f)) {
        mip_add4(img + p->bi * 4, p->b0, 0);
        return;
    }
    const float4 wv = p->b0 * (1.0f / sum);
    for (int y = p->y0; y <= p->y1; ++y)
        (void)mip_box_row(p, y, wv, (__global float4 *)(base + (size_t)(y + g.w) * g.y * 4)
                          + g.w, 1, shape);
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
    const int4 g = lv[l];
    __global float *base = img + ((size_t)g.x + (size_t)layer * g.z * g.y) * 4;
    float sum = p.sum;
    if (!atomic) {  /* plain adds: the PSF's box, row by row (mip_box_row) */
        if (p.point) {
            mip_add4(img + p.bi * 4, p.b0, 0);
            return;
        }
        if (p.len >= 0.5f)
            mip_draw_box(&p, img, base, g, MIP_SWEPT);
        else if (p.rho >= 1.5f)
            mip_draw_box(&p, img, base, g, MIP_DISC);
        else
            mip_draw_box(&p, img, base, g, MIP_SMALL);
        return;
    }
    /* atomic adds: each row's pixels that the PSF may cover, its constant inside as a run */
    int xa, xb, ia, ib;
    float vin;
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
        mip_add4(img + p.bi * 4, p.b0, 1);
        return;
    }
    const float4 wv = p.b0 * (1.0f / sum);
    for (int y = p.y0; y <= p.y1; ++y) {
        __global float *row = base + (size_t)(y + g.w) * g.y * 4;
        mip_row(&p, y, &xa, &xb, &ia, &ib, &vin);
        for (int x = xa; x < ia; ++x) {
            const float v = mip_psf_at(&p, x, y);
            if (v > 0.0f)
                mip_add4(row + (size_t)(x + g.w) * 4, v * wv, 1);
        }
        const float4 wi = vin * wv;
        for (int x = ia; x <= ib; ++x)
            mip_add4(row + (size_t)(x + g.w) * 4, wi, 1);
        for (int x = max(ib + 1, ia); x <= xb; ++x) {
            const float v = mip_psf_at(&p, x, y);
            if (v > 0.0f)
                mip_add4(row + (size_t)(x + g.w) * 4, v * wv, 1);
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
                                   const int phase_x, const int phase_y,
                                   __global uchar *flags)
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
        /* most bins are empty (a layer covers part of the frame): a scan of their flags
         * first, a byte a bin (the bins' weights are a cache line apart: scanning them read
         * the whole 48-byte-a-bin buffer, 18 ms of a half's 100 at 1280x720) */
        __global uchar *fl = flags + mip_index(lv, l, layer, xs - g.w, y - g.w);
        for (int x = xs; x < x1; ++x)
            if (fl[x - xs]) {
                fl[x - xs] = 0;  /* consumed, as the bin is: clean for the next frame */
                mip_draw_one(l, layer, x - g.w, y - g.w, 0, bins, img, lv);
            }
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
