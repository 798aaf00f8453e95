/* splat.cl: Laplacian kernel splatting (Leimkuehler et al. 2018, section 6.2), one work-item
 * per input sample.
 *
 * splat_samples (one work-item per sample, atomic adds) and splat_tiles (one work-item per
 * screen tile, k x k phases, plain adds: for CPUs, where float atomics are CAS loops ~10x the
 * cost of an add) draw, for sample k (index (y * W + x) * SPP + i of the SoA fields)
 *   coc    = c0 / depth + c1 (c1 for misses, depth >= 1e30; splat.h splat_coc)
 *   centre = position - coc * lens - (time - 0.5) * motion       (re-centring, section 6.2;
 *            coc scaled down to the table's range where it exceeds it, so the sample stays
 *            inside the clamped PSF; with NDIM == 1 the PSF has no motion and the motion term
 *            is not re-centred)
 *   nsub   = ceil(|motion| / smax1) where |motion| exceeds the table's range (NDIM 2), else 1:
 *            the segment is drawn as nsub PSFs of length |motion| / nsub centred at
 *            centre + ((j + 0.5) / nsub - 0.5) * motion, each with weight / nsub
 *   layer  = floor((1/depth - inv_far) * layer_scale), clamped to [0, NLAYERS)  (0 = farthest;
 *            uniform in 1/depth: constant parallax; misses at 1/depth = 0; splat_layer)
 *   cell   = the nested-grid cell of (|coc|) or (|coc|, |motion| / nsub) (O(1), see psf.py)
 *   weight = (rgb, 1) / (SPP nsub)
 * and adds weight * value at pixel floor(centre) + offset + pad of every point of the cell:
 *   fast[cell] != 0: the dense PSF (dpts/dvals/doffs) into `direct` (the fast track);
 *   otherwise the spreadlets (pts/vals/offs) into `lap`, the layer's Laplacian image.
 * With NDIM == 2 (Combined) offsets are rotated from +x to the motion direction and rounded.
 * Images: float4 (RGB, coverage), (NLAYERS, PH, PW), PH = H + 2 pad, PW = W + 2 pad.
 * Table: pts short2 (x, y), vals float, offs int (cells + 1); the same for d*; fast uchar.
 * Grid: gn (n0, n1), gsmax (smax0, smax1), ginvb (1/beta0, 1/beta1), levels int4 per 2D level
 *   (first cell, cells along axis 1, cells along axis 0, edge), nlev.
 * Compile-time: SPP, NDIM (1 or 2), HAS_MOTION (0: motion and time unused), NLAYERS
 * (defaults in splat.h), FIXED (1: deterministic=True, splat_samples only, below).
 * The local size of splat_samples is a launch parameter only (tuned: wg).
 * Samples whose PSF would not fit whole into the padded image (centre closer than `reach`,
 * an upper bound of |offset| after rotation and rounding, to its border) are skipped: a
 * partial Laplacian would corrupt the integration. The host makes the pad wide enough that
 * only samples whose PSF cannot reach the frame are skipped.
 *
 * FIXED == 1 (deterministic=True with the atomic scatter): lap and direct are int64 images
 * of the same layout, accumulated in scaled fixed point (common.h) with 2^e per channel,
 * e = fixed_exponent(klog2, m), m = max |colour| of the channel (bound, from
 * splat_color_bound; 1 for coverage), 2^klog2 >= the host's bound on sum |weight * value| a
 * pixel receives per unit of colour (SplatPipeline: the pixels within reach of it times the
 * largest L1 norm of a table cell). splat_fixed_to_float then writes the float images the
 * integration reads. Integer sums do not depend on the order of the adds: bit-identical run
 * to run.
 */
#include "splat.h"

#ifndef NDIM
#define NDIM 1
#endif
#ifndef FIXED
#define FIXED 0
#endif
#if FIXED && !CLRECON_HAS_FIXED
#error "FIXED needs cl_khr_int64_base_atomics"
#endif

#if FIXED
#define ACC long
#define SPLAT_FIXED_ARGS , __global const uint *bound, const int klog2
#define SPLAT_FIXED_PASS , bound, klog2
#else
#define ACC float
#define SPLAT_FIXED_ARGS
#define SPLAT_FIXED_PASS
#endif

inline float splat_grid_coord(float s, float smax, float invb, int n)
{
    return (float)n * pow(clamp(s / smax, 0.0f, 1.0f), invb);
}

/* Cell index of PSF parameters (s0, s1): psf.py NestedGrid.index. */
inline int splat_cell(float s0, float s1, int2 gn, float2 gsmax, float2 ginvb,
                      __global const int4 *levels, int nlev)
{
    const float g0 = fmin(splat_grid_coord(s0, gsmax.x, ginvb.x, gn.x), (float)gn.x - 1e-3f);
#if NDIM == 1
    return (int)g0;
#else
    const float g1 = fmin(splat_grid_coord(s1, gsmax.y, ginvb.y, gn.y), (float)gn.y - 1e-3f);
    const float m = fmin(g0, g1);
    int l = (int)((sqrt(8.0f * m + 1.0f) - 1.0f) * 0.5f);
    /* the float triangular root may be one off at level boundaries */
    while (l > 0 && (float)(l * (l + 1) / 2) > m) --l;
    while (l + 1 < nlev && (float)((l + 1) * (l + 2) / 2) <= m) ++l;
    const int4 lv = levels[l];
    const float t = (float)(l * (l + 1) / 2), e = (float)lv.w;
    if (g0 < t + e)
        return lv.x + min((int)((g1 - t) / e), lv.y - 1);
    return lv.x + lv.y + min((int)((g0 - t - e) / e), lv.z - 1);
#endif
}

/* The arguments every splat kernel shares (layouts in the header). */
#define SPLAT_ARGS \
    __global const float *color, __global const float *position, \
    __global const float *depth, __global const float *lens, __global const float *time, \
    __global const float *motion, const int nsamples, const float c0, const float c1, \
    const float inv_far, const float layer_scale, const int pad, const int pw, const int ph, \
    const int reach, __global const short2 *pts, __global const float *vals, \
    __global const int *offs, __global const short2 *dpts, __global const float *dvals, \
    __global const int *doffs, __global const uchar *fast, const int2 gn, \
    const float2 gsmax, const float2 ginvb, __global const int4 *levels, const int nlev, \
    __global ACC *lap, __global ACC *direct SPLAT_FIXED_ARGS
#define SPLAT_PASS color, position, depth, lens, time, motion, nsamples, c0, c1, inv_far, \
    layer_scale, pad, pw, ph, reach, pts, vals, offs, dpts, dvals, doffs, fast, gn, gsmax, \
    ginvb, levels, nlev, lap, direct SPLAT_FIXED_PASS

/* scale: FIXED's 2^e per channel (unused otherwise) */
inline void splat_add(__global ACC *dst, const float4 c, const int atomic, const float4 scale)
{
#if FIXED
    atomic_add_fixed_scaled(dst + 0, c.x, scale.x);
    atomic_add_fixed_scaled(dst + 1, c.y, scale.y);
    atomic_add_fixed_scaled(dst + 2, c.z, scale.z);
    atomic_add_fixed_scaled(dst + 3, c.w, scale.w);
#else
    if (atomic) {
        atomic_add_f32(dst + 0, c.x);
        atomic_add_f32(dst + 1, c.y);
        atomic_add_f32(dst + 2, c.z);
        atomic_add_f32(dst + 3, c.w);
    } else {
        vstore4(vload4(0, dst) + c, 0, dst);
    }
#endif
}

/* Draw sample k; atomic: 0 only where no other work-item can write the same pixels. */
inline void splat_one(const int k, const int atomic, SPLAT_ARGS)
{
    const float z = depth[k];
    const float coc = splat_coc(z, c0, c1);
    /* beyond the table's CoC range the PSF is clamped: re-centre by the clamped CoC so that
     * the sample stays inside the PSF that is drawn */
    const float cscale = fabs(coc) > gsmax.x ? gsmax.x / fabs(coc) : 1.0f;
    float2 centre = vload2(k, position) - (coc * cscale) * vload2(k, lens);
    float mlen = 0.0f;
    float2 mdir = (float2)(1.0f, 0.0f);
    float2 mot = (float2)(0.0f, 0.0f);
    int nsub = 1;
#if HAS_MOTION && NDIM == 2
    mot = vload2(k, motion);
    mlen = length(mot);
    /* a segment longer than the table's range is drawn as nsub equal sub-segments, each
     * within range: (disc swept over L) = sum over j of (disc swept over L / nsub), shifted */
    if (mlen > gsmax.y)
        nsub = (int)ceil(mlen / gsmax.y);
    centre -= (time[k] - 0.5f) * mot;
    if (mlen > 0.0f)
        mdir = mot / mlen;
#endif
    const int layer = splat_layer(z, inv_far, layer_scale);
    const int cell = splat_cell(fabs(coc), mlen / (float)nsub, gn, gsmax, ginvb, levels, nlev);
    const float4 wgt = (float4)(vload3(k, color), 1.0f) * (1.0f / (float)(SPP * nsub));
    const int use_fast = fast[cell];
    __global const short2 *p = use_fast ? dpts : pts;
    __global const float *v = use_fast ? dvals : vals;
    const int first = use_fast ? doffs[cell] : offs[cell];
    const int last = use_fast ? doffs[cell + 1] : offs[cell + 1];
#if FIXED
    const float4 scale = fixed_scales(fixed_exponents(bound, klog2));
#else
    const float4 scale = (float4)(1.0f);
#endif
    for (int sub = 0; sub < nsub; ++sub) {
        const float2 cs = centre + (((float)sub + 0.5f) / (float)nsub - 0.5f) * mot;
        const float fx = floor(cs.x) + pad, fy = floor(cs.y) + pad;
        if (!(fx >= reach && fy >= reach && fx < pw - reach && fy < ph - reach))
            continue;
        const int cx = (int)fx, cy = (int)fy;
        __global ACC *img = (use_fast ? direct : lap) + (size_t)layer * ph * pw * 4
                              + ((size_t)cy * pw + cx) * 4;
        if (mlen == 0.0f) {  /* no rotation: integer offsets (all of NDIM 1, static samples) */
            for (int j = first; j < last; ++j) {
                const short2 o = p[j];
                splat_add(img + ((int)o.y * pw + (int)o.x) * 4, v[j] * wgt, atomic, scale);
            }
            continue;
        }
        for (int j = first; j < last; ++j) {
            const float2 o = convert_float2(p[j]);
            const int x = (int)rint(o.x * mdir.x - o.y * mdir.y);
            const int y = (int)rint(o.x * mdir.y + o.y * mdir.x);
            splat_add(img + (y * pw + x) * 4, v[j] * wgt, atomic, scale);
        }
    }
}

/* One work-item per sample, atomic adds (any device). */
__kernel void splat_samples(SPLAT_ARGS)
{
    const int k = get_global_id(0);
    if (k < nsamples)
        splat_one(k, 1, SPLAT_PASS);
}

#if !FIXED
/* One work-item per tile of tile x tile pixels, tiles (k i + phase_x, k j + phase_y): every
 * sample of the tile's pixels in order, plain adds. The host launches the k x k phases in
 * turn with (k - 1) * tile > 2 R - 1, R = reach + the largest centre shift + 1 (how far from
 * its pixel a sample writes), so the pixels two tiles of one phase write never overlap: no
 * atomics, and a fixed summation order (reproducible). */
__kernel void splat_tiles(SPLAT_ARGS, const int width, const int height, const int tile,
                          const int k, const int phase_x, const int phase_y)
{
    const int x0 = (k * get_global_id(0) + phase_x) * tile;
    const int y0 = (k * get_global_id(1) + phase_y) * tile;
    if (x0 >= width || y0 >= height)
        return;
    const int x1 = min(x0 + tile, width), y1 = min(y0 + tile, height);
    for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
            for (int i = 0; i < SPP; ++i)
                splat_one((y * width + x) * SPP + i, 0, SPLAT_PASS);
}
#else
/* FIXED: max |colour| per channel of the frame's nsamples samples into bound[0..2] (zeroed
 * by the host), for the scale of splat_samples and splat_fixed_to_float. */
__kernel void splat_color_bound(__global const float *color, const int nsamples,
                                volatile __global uint *bound)
{
    fixed_color_bound(color, nsamples, bound);
}

/* FIXED: the int64 images as floats, one work-item per float4 pixel of npix. */
__kernel void splat_fixed_to_float(__global const long *src, __global float *dst,
                                   const int npix, __global const uint *bound, const int klog2)
{
    const int i = get_global_id(0);
    if (i >= npix)
        return;
    const int4 e = fixed_exponents(bound, klog2);
    const size_t k = (size_t)i * 4;
    dst[k + 0] = fixed_value(src[k + 0], e.x);
    dst[k + 1] = fixed_value(src[k + 1], e.y);
    dst[k + 2] = fixed_value(src[k + 2], e.z);
    dst[k + 3] = fixed_value(src[k + 3], e.w);
}
#endif
