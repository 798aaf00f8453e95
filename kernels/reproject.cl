/* reproject.cl: every sample of a tile and its guard band, reprojected to (u, v, t) =
 * (0, 0, 0.5) with the parameters of each partition of the tile (eq. 1) and splatted into
 * that partition's grid (Hasselgren et al. 2015, section 5).
 *
 * reproject_buckets: the depth bucket of every sample (layered_bucket) into `buckets`, one
 * uchar per sample (NBUCKETS <= 256), one work-item per pixel. A sample is gathered by 4-5
 * slots at 1280x720 8 spp (its tile's and its neighbours'); each deciding in front / own /
 * behind from a byte instead of the depth and a division made the two kernels together
 * 1.2x faster than reproject computing the buckets itself (deep, 8 spp, PoCL, 2 cores).
 * reproject: one work-group per (tile, slot) (1D range ntiles * MAXP * WG_X); empty slots
 * (P_DIM == 0) return. The group clears its D x D x NCH grid, then its work-items stride over
 * the samples of the pixels within P_REACH of the tile (clipped to the image). A sample in
 * bucket b of the slot's range [lo, hi] adds (r, g, b, 1) to channels 0-3 ("own"); a sample
 * behind it (b > hi) adds 1 to channel 4 ("behind"); samples in front are skipped. The
 * sample lands at x' = position - A * lens - (t - 0.5) * b, grid coordinate
 * (x' - x0) / s + G - 0.5; nearest grid pixel, or bilinear weights with SPLAT_BILINEAR.
 * Grid pixels outside [0, D) are dropped. With SUBSAMPLE = b_max > 1 (default 8), a slot on a
 * grid of spacing s > 1 reads one pixel per min(s, b_max)^2 block (see below).
 *   inputs  SoA sample fields (color, position, lens, time) with sample_stride samples per
 *           pixel in the buffers, this frame's SPP from sample_offset on (a whole frame:
 *           stride SPP, offset 0; a half of one read in place: the frame's spp); buckets
 *           from reproject_buckets (SPP per pixel, this frame's own);
 *           params from partition_setup; grids float (tiles, MAXP, NCH, DMAX, DMAX), row
 *           stride D.
 * With WG_X > 1 work-items scatter with atomic_add_f32 (common.h); with WG_X == 1 the one
 * work-item owns the grid and adds plainly (no atomics, deterministic order).
 * FIXED == 1 (deterministic=True with WG_X > 1): the group accumulates into its slot of
 * `fixed` (int64, the layout of grids) in scaled fixed point (common.h): 2^e per channel,
 * e = fixed_exponent(klog2, m), 2^klog2 >= the number of samples the slot can read
 * ((bx - ax) (by - ay) SPP: each adds at most m = max |colour| (bound, from
 * reproject_color_bound) to a colour channel and at most 1 to a weight channel), then
 * writes the sums as floats into grids. Integer sums do not depend on the order of the
 * adds: bit-identical run to run. The atomics are the group's own (one group per slot), so
 * a barrier orders accumulation and conversion.
 * LOCAL_ACC == 1 (the host: 20 (DMAX^2 + 8) bytes of local memory fit): with WG_X == 1 a
 * nearest splat's own channels accumulate in local memory (OWN_LOCAL below; OWN_SPARE: its
 * behind counts too).
 * Compile-time: SPP, TILE, NBUCKETS, MAXP, GMAX, HAS_MOTION, SPLAT_BILINEAR, SUBSAMPLE,
 * FIXED, LOCAL_ACC. The vector lanes (VW samples of a pixel at once) are in
 * reproject_lanes.h.
 * Tunables: WG_X (work-group size, the host launches with it).
 */
#include "common.h"
#include "layered.h"

#ifndef SPP
#define SPP 8
#endif
#ifndef WG_X
#define WG_X 1
#endif
#ifndef SPLAT_BILINEAR
#define SPLAT_BILINEAR 0
#endif
#ifndef SUBSAMPLE
#define SUBSAMPLE 8   /* b_max: largest block side read as one pixel (1: every pixel) */
#endif
#ifndef FIXED
#define FIXED 0
#endif
#ifndef LOCAL_ACC
#define LOCAL_ACC 0   /* the host's word that 20 (DMAX^2 + 8) bytes of local memory fit */
#endif
#ifndef JOINT_HA
#define JOINT_HA 0    /* > 0: both of the safeguard's halves in one pass (see reproject) */
#endif
#if JOINT_HA && FIXED
#error "JOINT_HA: the fixed-point accumulation is for one grid"
#endif
#if FIXED && !CLRECON_HAS_FIXED
#error "FIXED needs cl_khr_int64_base_atomics"
#endif

#include "reproject_lanes.h"  /* VW: several samples of a pixel at once; row_hash */

/* GRID_ADD(p, v, s): add v at p of the accumulation grid (s: FIXED's scale of p's channel) */
#if FIXED
#define ACC long
#define GRID_ADD(p, v, s) atomic_add_fixed_scaled((volatile __global long *)(p), (v), (s))
#elif WG_X > 1
#define ACC float
#define GRID_ADD(p, v, s) atomic_add_f32((volatile __global float *)(p), (v))
#else
#define ACC float
#define GRID_ADD(p, v, s) (*(p) += (v))
#endif

/* sc: FIXED's scales of (r, g, b, weights) (unused otherwise) */
inline void splat(__global ACC *grid, int dim, int gx, int gy, float wt, float3 c, int own,
                  float4 sc)
{
    if (gx < 0 || gy < 0 || gx >= dim || gy >= dim || wt == 0.0f)
        return;
    __global ACC *p = grid + gy * dim + gx;
    const int plane = DMAX * DMAX;
    if (own) {
        GRID_ADD(p, wt * c.x, sc.x);
        GRID_ADD(p + plane, wt * c.y, sc.y);
        GRID_ADD(p + 2 * plane, wt * c.z, sc.z);
        GRID_ADD(p + 3 * plane, wt, sc.w);
    } else {
        GRID_ADD(p + 4 * plane, wt, sc.w);
    }
}

/* OWN_LOCAL: the owner (one work-item, plain adds) of a nearest-splat slot accumulates its
 * own channels as one float4 (r, g, b, weight) per cell in local memory and writes the planes
 * at the end: one vector add a sample instead of four scalar ones into planes DMAX^2 floats
 * (a multiple of 4 KiB) apart, which the CPU's store-to-load checks partly serialise (4K
 * aliasing). Measured at 1280x720 8 spp (deep, PoCL): 1.05-1.1x. The same adds in the same
 * order: the same sums. */
#define OWN_LOCAL (LOCAL_ACC && WG_X == 1 && !FIXED && !SPLAT_BILINEAR && VW > 1)
/* OWN_SPARE: one frame's pass (not JOINT_HA) adds its lanes without a branch (see reproject) */
#define OWN_SPARE (OWN_LOCAL && !JOINT_HA)

/* the grid that sample i of a pixel adds to: with JOINT_HA, half A's (grids) or B's */
#if JOINT_HA
#define HALF_ACC(i) ((i) >= JOINT_HA ? acc_b : acc)
#else
#define HALF_ACC(i) acc
#endif

#if NBUCKETS > 256
#error "reproject_buckets stores a bucket in a uchar: NBUCKETS <= 256"
#endif

__kernel void reproject_buckets(__global const float *depth, const int sample_stride,
                                const int sample_offset, const int npix, const float ka,
                                const float kb, const float kc, __global uchar *buckets)
{
    const size_t i = get_global_id(0);
    if (i >= (size_t)npix)
        return;
    const size_t s = i * sample_stride + sample_offset;  /* the pixel's first sample */
#if VW == 1
    for (int k = 0; k < SPP; ++k)
        buckets[i * SPP + k] = (uchar)layered_bucket(depth[s + k], ka, kb, kc);
#else
    for (int k = 0; k < SPP; k += VW)
        VSTORE(CONVERT_UCHARV(bucket_lanes(VLOAD(0, depth + s + k), ka, kb, kc)), 0,
               buckets + i * SPP + k);
#endif
}

__kernel __attribute__((reqd_work_group_size(WG_X, 1, 1)))
void reproject(__global const float *color, __global const float *position,
               __global const uchar *buckets, __global const float *lens,
               __global const float *time, const int sample_stride, const int sample_offset,
               const int width, const int height,
               const int ntx, __global const float *params, __global float *grids
#if JOINT_HA
               , __global float *grids_b
#endif
#if FIXED
               , __global long *fixed, __global const uint *bound
#endif
               )
{
#if OWN_SPARE   /* VW spare cells past the grid's */
    __local float4 own_acc[DMAX * DMAX + VW];
    __local float behind_acc[DMAX * DMAX + VW];
#elif OWN_LOCAL
    __local float4 own_acc[DMAX * DMAX];
#if JOINT_HA
    __local float4 own_acc_b[DMAX * DMAX];
#endif
#endif
    const int slot = get_group_id(0), lid = get_local_id(0);
    const int t = slot / MAXP;
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (dim == 0)
        return;
    const int x0 = (t % ntx) * TILE, y0 = (t / ntx) * TILE;
    const int lo = (int)p[P_LO], hi = (int)p[P_HI], reach = (int)p[P_REACH];
    const float A = p[P_A], inv_s = 1.0f / p[P_SCALE], g = p[P_GUARD];
    const float2 bm = (float2)(p[P_BX], p[P_BY]);
    const int ax = max(0, x0 - reach), bx = min(width, x0 + TILE + reach);
    const int ay = max(0, y0 - reach), by = min(height, y0 + TILE + reach);
    __global float *grid = grids + (size_t)slot * NCH * DMAX * DMAX;
#if FIXED
    /* 2^klog2 >= the samples this slot can read, exactly (ceil log2; n >= 1) */
    const ulong nread = (ulong)(bx - ax) * (ulong)(by - ay) * SPP;
    const int4 ex = fixed_exponents(bound, nread > 1 ? 64 - (int)clz(nread - 1) : 0);
    const float4 sc = fixed_scales(ex);
    __global long *acc = fixed + (size_t)slot * NCH * DMAX * DMAX;
#else
    const float4 sc = (float4)(1.0f);
    __global float *acc = grid;
#endif
#if JOINT_HA
    __global float *grid_b = grids_b + (size_t)slot * NCH * DMAX * DMAX, *acc_b = grid_b;
#endif
#if OWN_LOCAL
    for (int k = 0; k < dim * dim; ++k) {
        own_acc[k] = (float4)(0.0f);
#if OWN_SPARE
        behind_acc[k] = 0.0f;
#else
        acc[4 * DMAX * DMAX + k] = 0.0f;
#endif
#if JOINT_HA
        own_acc_b[k] = (float4)(0.0f);
        acc_b[4 * DMAX * DMAX + k] = 0.0f;
#endif
    }
#else
    for (int c = 0; c < NCH; ++c)
        for (int k = lid; k < dim * dim; k += WG_X) {
            acc[c * DMAX * DMAX + k] = 0;
#if JOINT_HA
            acc_b[c * DMAX * DMAX + k] = 0;
#endif
        }
#endif
    barrier(CLK_GLOBAL_MEM_FENCE);
    /* SUBSAMPLE (b_max, 1: off): a slot on a grid of spacing s > 1 gathers one pixel (all
     * its samples) per b x b block of the image, b = min(s, b_max): one grid pixel's worth
     * (>= SPP samples per grid pixel) while s <= b_max. The pixel is picked by a hash of the
     * block's row (the same in every tile): one image row per block row, every b-th pixel of
     * it, so the reads stream (a hash per block scattered them: 1.5x slower). The slot's
     * channels are divided by each other, so the common weight b^2 of the kept samples
     * cancels. Measured, 512x512 8 spp, b_max 4 -> 8: within 0.11 dB on every scene (huge_coc
     * +0.10, fast_motion -0.11), reproject 1.15x faster at 1280x720. */
    const int sub = min((int)p[P_SCALE], SUBSAMPLE);
    const int cx0 = ax / sub, cy0 = ay / sub;
    const int nbw = (bx + sub - 1) / sub - cx0, nbh = (by + sub - 1) / sub - cy0;
    for (int cy = cy0; cy < cy0 + nbh; ++cy) {
        /* the block row's pixel row and column offset (one hash per row) */
        int py = cy * sub, ox = 0;
        if (sub > 1) {
            const uint h = row_hash(cy, sub);
            ox = (int)(h % (uint)sub);
            py += (int)((h >> 16) % (uint)sub);
        }
        if (py < ay || py >= by)
            continue;
        for (int cx = cx0 + lid; cx < cx0 + nbw; cx += WG_X) {
            const int px = cx * sub + ox;
            if (px < ax || px >= bx)
                continue;
            /* the pixel's first sample in the fields, and its first bucket */
            const size_t base = ((size_t)py * width + px) * sample_stride + sample_offset;
            const size_t kbase = ((size_t)py * width + px) * SPP;
            for (int i0 = 0; i0 < SPP; i0 += VW) {
                /* VW samples at once (SIMD on CPUs), then added one by one */
                float gxa[VW], gya[VW], bka[VW];
                if (!reproject_lanes(base + i0, kbase + i0, position, buckets, lens, time, lo,
                                     A, bm, x0, y0, inv_s, g, gxa, gya, bka))
                    continue;   /* no sample of these lanes at or behind the slot */
#if !SPLAT_BILINEAR && VW > 1
                /* nearest: grid index (-1: dropped) and own flag in vectors, so the scalar
                 * loop only adds (the same cells and order as the per-sample path below) */
                const floatv gxv = VLOAD(0, gxa), gyv = VLOAD(0, gya), bv = VLOAD(0, bka);
                const intv ok = isgreaterequal(bv, (floatv)(lo)) & isgreaterequal(gxv, 0.0f)
                                & isgreaterequal(gyv, 0.0f) & isless(gxv, (floatv)(dim))
                                & isless(gyv, (floatv)(dim));
                int ia[VW];
                VSTORE(CONVERT_INTV(gyv) * dim + CONVERT_INTV(gxv), 0, ia);
                /* the lanes to add as bit masks, own and behind: the loops over their set bits
                 * skip dropped lanes without a branch each (the same adds in the same order
                 * per channel as one loop over the lanes; 1.05x faster) */
                const intv own = islessequal(bv, (floatv)(hi));
                const uint mo_all = lane_bits(ok & own), mb_all = lane_bits(ok & ~own);
#if OWN_LOCAL
                /* the lanes' colours in two vector loads, issued as soon as one lane is own
                 * (one scalar load per own lane waited on its cache line in the add loop:
                 * reproject 1.04-1.05x faster, deep 1280x720 8 spp, PoCL; the same values) */
                float ca[3 * VW];
                if (mo_all)
                    COLOR_LANES(ca, color + 3 * (base + i0));
#endif
#if OWN_SPARE
                /* every lane adds, without a branch: a lane not own (not behind) adds to its own
                 * spare cell DMAX^2 + j; the loops over set bits below mispredicted their exits
                 * (reproject 1.15-1.2x faster, deep 1280x720 8 spp, PoCL; with JOINT_HA they
                 * were faster, 75 against 85 ms). Each cell's adds in the loops' order. */
                const intv iv = VLOAD(0, ia);
                int ic[VW];
                if (mo_all) {
                    LANE_CELLS(ic, iv, mo_all, DMAX * DMAX);
                    for (int j = 0; j < VW; ++j)
                        own_acc[ic[j]] += (float4)(vload3(j, ca), 1.0f);
                }
                if (mb_all) {
                    LANE_CELLS(ic, iv, mb_all, DMAX * DMAX);
                    for (int j = 0; j < VW; ++j)
                        behind_acc[ic[j]] += 1.0f;
                }
#else
#if JOINT_HA
                /* half A's lanes (samples below JOINT_HA) into grids, then half B's into
                 * grids_b: each grid gets its half's adds in the order its own pass makes */
                const uint la = (1u << clamp(JOINT_HA - i0, 0, VW)) - 1u;
                for (int h = 0; h < 2; ++h) {
                    uint mo = mo_all & (h ? ~la : la), mb = mb_all & (h ? ~la : la);
                    __global ACC *hacc = h ? acc_b : acc;
#if OWN_LOCAL
                    __local float4 *hown = h ? own_acc_b : own_acc;
#endif
#else
                {   /* (OWN_LOCAL here is OWN_SPARE's, above) */
                    uint mo = mo_all, mb = mb_all;
                    __global ACC *hacc = acc;
#endif
                while (mo) {
                    const int j = 31 - clz(mo & (0u - mo));
                    mo &= mo - 1u;
#if OWN_LOCAL
                    hown[ia[j]] += (float4)(vload3(j, ca), 1.0f);
#else
                    __global ACC *cell = hacc + ia[j];
                    const float3 c = vload3(base + i0 + j, color);
                    GRID_ADD(cell, c.x, sc.x);
                    GRID_ADD(cell + DMAX * DMAX, c.y, sc.y);
                    GRID_ADD(cell + 2 * DMAX * DMAX, c.z, sc.z);
                    GRID_ADD(cell + 3 * DMAX * DMAX, 1.0f, sc.w);
#endif
                }
                while (mb) {
                    const int j = 31 - clz(mb & (0u - mb));
                    mb &= mb - 1u;
                    GRID_ADD(hacc + ia[j] + 4 * DMAX * DMAX, 1.0f, sc.w);
                }
                }
#endif
#else
                for (int j = 0; j < VW; ++j) {
                    const int b = (int)bka[j];
                    if (b < lo)
                        continue;
                    const float gxf = gxa[j], gyf = gya[j];
                    const float3 c = vload3(base + i0 + j, color);   /* kept samples only */
                    const int own = b <= hi;
#if SPLAT_BILINEAR
                    const float fx = gxf - 0.5f, fy = gyf - 0.5f;
                    const float ix = floor(fx), iy = floor(fy);
                    const float wx = fx - ix, wy = fy - iy;
                    if (ix < -1.0f || iy < -1.0f || ix >= dim || iy >= dim)
                        continue;
                    const int jx = (int)ix, jy = (int)iy;
                    splat(HALF_ACC(i0 + j), dim, jx, jy, (1.0f - wx) * (1.0f - wy), c, own, sc);
                    splat(HALF_ACC(i0 + j), dim, jx + 1, jy, wx * (1.0f - wy), c, own, sc);
                    splat(HALF_ACC(i0 + j), dim, jx, jy + 1, (1.0f - wx) * wy, c, own, sc);
                    splat(HALF_ACC(i0 + j), dim, jx + 1, jy + 1, wx * wy, c, own, sc);
#else
                    if (gxf < 0.0f || gyf < 0.0f || gxf >= dim || gyf >= dim)
                        continue;
                    splat(HALF_ACC(i0 + j), dim, (int)gxf, (int)gyf, 1.0f, c, own, sc);
#endif
                }
#endif
            }
        }
    }
#if OWN_LOCAL
    for (int k = 0; k < dim * dim; ++k) {
        const float4 v = own_acc[k];
        grid[k] = v.x;
        grid[DMAX * DMAX + k] = v.y;
        grid[2 * DMAX * DMAX + k] = v.z;
        grid[3 * DMAX * DMAX + k] = v.w;
#if OWN_SPARE
        grid[4 * DMAX * DMAX + k] = behind_acc[k];
#endif
#if JOINT_HA
        const float4 u = own_acc_b[k];
        grid_b[k] = u.x;
        grid_b[DMAX * DMAX + k] = u.y;
        grid_b[2 * DMAX * DMAX + k] = u.z;
        grid_b[3 * DMAX * DMAX + k] = u.w;
#endif
    }
#endif
#if FIXED
    /* every add of the group done and visible: the sums as floats */
    barrier(CLK_GLOBAL_MEM_FENCE);
    for (int k = lid; k < dim * dim; k += WG_X) {
        grid[k] = fixed_value(acc[k], ex.x);
        grid[DMAX * DMAX + k] = fixed_value(acc[DMAX * DMAX + k], ex.y);
        grid[2 * DMAX * DMAX + k] = fixed_value(acc[2 * DMAX * DMAX + k], ex.z);
        grid[3 * DMAX * DMAX + k] = fixed_value(acc[3 * DMAX * DMAX + k], ex.w);
        grid[4 * DMAX * DMAX + k] = fixed_value(acc[4 * DMAX * DMAX + k], ex.w);
    }
#endif
}

#if FIXED
/* FIXED: max |colour| per channel of the frame's nsamples samples into bound[0..2] (zeroed
 * by the host), for the scales of reproject. */
__kernel void reproject_color_bound(__global const float *color, const int nsamples,
                                    volatile __global uint *bound)
{
    fixed_color_bound(color, nsamples, bound);
}
#endif
