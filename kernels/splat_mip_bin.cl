/* splat_mip_bin.cl: the bin passes of method splat's mip plan (splat_mip.h has the plan,
 * its levels and the layout of bins and images).
 *
 * splat_mip_bin_*: each sample adds into the bin of its layer, level and level pixel
 * q = floor(centre / s) (three float4: (rgb w, w), w (r/s, mx/s, my/s, 0), w (fx, fy, 0, 0),
 * w = 1 / SPP (1 / JOINT_HA), (fx, fy) the centre's offset inside q).
 * A sample's centre, layer and CoC are splat.cl's (splat.h); its level is the lowest with
 * r <= TR[l] and L <= TM[l], where r / s and L / s are clamped to RL[l] and ML[l].
 *   splat_mip_bin_samples  one work-item per sample, atomic adds (any device)
 *   splat_mip_bin_tiles    one work-group per owner tile, k x k phases, plain adds in a fixed
 *                          order (reproducible; below)
 * Arguments: the SoA sample fields with `stride` samples per pixel in the buffers, of which
 * this frame's SPP are offset .. offset + SPP - 1 (a whole frame: stride SPP, offset 0; one
 * half of a frame read in place for the safeguard: stride the frame's spp), c0, c1
 * (coc = c0 / depth + c1), inv_far and layer_scale (splat_layer), lv (int4 per level), bins
 * float (pixels, 12), zeroed where they are added to (the draw pass zeroes each bin it
 * consumes); the tiles' flags uchar (pixels), set to 1 for every bin added to, zero
 * elsewhere (the draw's scan reads them, and zeroes them as it draws). Sample k of the frame
 * (k = pixel SPP + i) is element pixel stride + offset + i.
 * Compile-time: SPP, HAS_MOTION, NLAYERS, NLEV, and the per-level lists TR, TM, RL, ML
 * (floats, NLEV each; TR[NLEV - 1], TM[NLEV - 1] unused); BIN_VW (1 or 8: the owner tiles'
 * records 8 samples a step as float8 lanes, on CPUs); JOINT_HA (> 0, owner tiles only: both
 * of the safeguard's equal halves of a whole frame in one pass, SPP == 2 JOINT_HA: samples
 * 0 .. JOINT_HA - 1 of each pixel into bins and flags, the rest into bins_b and flags_b,
 * each weighted 1 / JOINT_HA; the bins equal bit for bit those of each half's own pass).
 */
#include "splat_mip.h"

#ifndef TR
#define TR 8.0f
#define TM 32.0f
#define RL 8.0f
#define ML 32.0f
#endif
#ifndef JOINT_HA
#define JOINT_HA 0
#endif
#if JOINT_HA
#if SPP != 2 * JOINT_HA
#error "JOINT_HA: equal halves of the frame's SPP samples"
#endif
#define W_SPP JOINT_HA  /* a sample's weight: 1 / (its half's samples a pixel) */
#else
#define W_SPP SPP
#endif
__constant float mip_tr[NLEV] = {TR};
__constant float mip_tm[NLEV] = {TM};
__constant float mip_rl[NLEV] = {RL};
__constant float mip_ml[NLEV] = {ML};

#define MIP_BIN_ARGS \
    __global const float *color, __global const float *position, \
    __global const float *depth, __global const float *lens, __global const float *time, \
    __global const float *motion, const int stride, const int offset, const float c0, \
    const float c1, const float inv_far, const float layer_scale, __global const int4 *lv, \
    __global float *bins

#define MIP_BIN_PASS color, position, depth, lens, time, motion, stride, offset, c0, c1, \
    inv_far, layer_scale, lv, bins

/* The sample at element k of the fields: its bin (its pixel index, -1: none) and what it adds there: r0..r8 = w (r, g, b, 1,
 * r / s, mx / s, my / s, fx, fy), w = 1 / W_SPP, (fx, fy) the centre's offset inside its bin.
 * Nine scalars (no private array), so that they stay in registers. */
#define MIP_REC float *r0, float *r1, float *r2, float *r3, float *r4, float *r5, float *r6, \
    float *r7, float *r8
#define MIP_REC_VARS float v0, v1, v2, v3, v4, v5, v6, v7, v8
#define MIP_REC_PASS &v0, &v1, &v2, &v3, &v4, &v5, &v6, &v7, &v8
__attribute__((always_inline)) inline int mip_record(const int k, MIP_BIN_ARGS, MIP_REC)
{
    const float z = depth[k];
    const float coc = splat_coc(z, c0, c1);
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
    const int layer = splat_layer(z, inv_far, layer_scale);
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
    const float w = 1.0f / (float)W_SPP, wm = w * ms * inv_s;
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

#ifndef BIN_VW
#define BIN_VW 1  /* samples a step of the owner tiles' record loop: 1 or 8 (CPUs) */
#endif
#if BIN_VW == 8
#include "splat_mip_lanes.h"  /* mip_record8: 8 samples a step as float8 lanes */
#endif

/* A record into bin idx: three float4 (rgb w, w), w (r, mx, my, 0) / s, w (fx, fy, 0, 0) */
__attribute__((always_inline)) inline void mip_add1(__global float *dst, const float v,
                                                    const int atomic)
{
    if (!atomic)
        *dst += v;
    else if (v != 0.0f)
        atomic_add_f32(dst, v);
}

__attribute__((always_inline)) inline void mip_bin_add(__global float *bins, const int idx,
                                                       const float v0, const float v1,
                                                       const float v2, const float v3,
                                                       const float v4, const float v5,
                                                       const float v6, const float v7,
                                                       const float v8, const int atomic)
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

/* The element of the fields that holds sample ks (ks = pixel SPP + i) of a frame with `stride`
 * samples per pixel in the buffers from `offset` on. */
__attribute__((always_inline)) inline int mip_element(const int ks, const int stride,
                                                      const int offset)
{
    return (ks / SPP) * stride + offset + ks % SPP;
}

#if !JOINT_HA
/* One work-item per sample, atomic adds (any device). */
__kernel void splat_mip_bin_samples(MIP_BIN_ARGS, const int nsamples)
{
    const int ks = get_global_id(0);
    if (ks >= nsamples)
        return;
    MIP_REC_VARS;
    const int idx = mip_record(mip_element(ks, stride, offset), MIP_BIN_PASS, MIP_REC_PASS);
    if (idx >= 0)
        mip_bin_add(bins, idx, v0, v1, v2, v3, v4, v5, v6, v7, v8, 1);
}
#endif

#define ROW_MAX 512
/* sample element k's record into slot j of the tiles' local arrays (one sample; with
 * BIN_VW == 8 the row's steps of 8 go through mip_record8 and this takes the tail) */
#define MIP_RECORD_INTO(j, k) \
    do { \
        MIP_REC_VARS; \
        ridx[j] = mip_record((k), MIP_BIN_PASS, MIP_REC_PASS); \
        r0[j] = v0; r1[j] = v1; r2[j] = v2; r3[j] = v3; r4[j] = v4; \
        r5[j] = v5; r6[j] = v6; r7[j] = v7; r8[j] = v8; \
    } while (0)
/* the run (bin cur, sums a0 .. a8) into its bin and flag, if any */
#define MIP_RUN_END(cur, a0, a1, a2, a3, a4, a5, a6, a7, a8, bins, flags) \
    do { \
        if ((cur) >= 0) { \
            mip_bin_add((bins), (cur), a0, a1, a2, a3, a4, a5, a6, a7, a8, 0); \
            (flags)[cur] = 1; \
        } \
    } while (0)
/* record j of the local arrays: extends the run, or ends it and starts the next */
#define MIP_RUN(cur, a0, a1, a2, a3, a4, a5, a6, a7, a8, bins, flags, j) \
    do { \
        const int idx_ = ridx[j]; \
        if (idx_ != (cur)) { \
            MIP_RUN_END(cur, a0, a1, a2, a3, a4, a5, a6, a7, a8, bins, flags); \
            cur = idx_; \
            a0 = r0[j]; a1 = r1[j]; a2 = r2[j]; a3 = r3[j]; a4 = r4[j]; \
            a5 = r5[j]; a6 = r6[j]; a7 = r7[j]; a8 = r8[j]; \
        } else { \
            a0 += r0[j]; a1 += r1[j]; a2 += r2[j]; a3 += r3[j]; a4 += r4[j]; \
            a5 += r5[j]; a6 += r6[j]; a7 += r7[j]; a8 += r8[j]; \
        } \
    } while (0)
/* One work-item (and work-group) per owner tile of tile x tile frame pixels: the
 * host launches the k x k phases in turn with (k - 1) tile > 2 R - 1, R bounding how
 * far from its pixel a sample's bin lies (frame pixels), so no two work-items of a launch
 * write the same bin. Along each row of its tile, ROW_MAX samples at a time: the records
 * go into local memory in one loop over contiguous samples, which the compiler vectorises
 * (the same arithmetic interleaved with the adds ran ~10x slower on PoCL), then are added
 * in order, each run of records into one bin summed first: plain adds, a fixed order
 * (reproducible). (PoCL 3.1 on AVX-512 hosts left that loop scalar: hence BIN_VW.) */
__kernel void splat_mip_bin_tiles(MIP_BIN_ARGS, const int width, const int height,
                                  const int tile, const int k, const int phase_x,
                                  const int phase_y, __global uchar *flags
#if JOINT_HA
                                  , __global float *bins_b, __global uchar *flags_b
#endif
                                  )
{
    __local int ridx[ROW_MAX];
    __local float r0[ROW_MAX], r1[ROW_MAX], r2[ROW_MAX], r3[ROW_MAX], r4[ROW_MAX],
        r5[ROW_MAX], r6[ROW_MAX], r7[ROW_MAX], r8[ROW_MAX];
    const int x0 = (k * (int)get_group_id(0) + phase_x) * tile;
    const int y0 = (k * (int)get_group_id(1) + phase_y) * tile;
    if (x0 >= width || y0 >= height)
        return;
    const int row = (min(x0 + tile, width) - x0) * SPP;
#if BIN_VW == 8
    int4 glv[NLEV];
    for (int j = 0; j < NLEV; ++j)
        glv[j] = lv[j];
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
#endif
    for (int y = y0; y < min(y0 + tile, height); ++y) {
        /* a run of consecutive records into one bin (a pixel's samples, a coarse level's
         * neighbours) is summed in registers: one add into the bin per run; a run may span
         * the row's chunks (so the adds do not depend on ROW_MAX). With JOINT_HA each half
         * has its own run, and sees its samples in the order of its own pass. */
        int cur = -1;
        float a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, a3 = 0.0f, a4 = 0.0f, a5 = 0.0f, a6 = 0.0f,
              a7 = 0.0f, a8 = 0.0f;
#if JOINT_HA
        int curb = -1;
        float b0 = 0.0f, b1 = 0.0f, b2 = 0.0f, b3 = 0.0f, b4 = 0.0f, b5 = 0.0f, b6 = 0.0f,
              b7 = 0.0f, b8 = 0.0f;
#endif
        for (int c = 0; c < row; c += ROW_MAX) {
            const int first = (y * width + x0) * SPP + c, n = min(ROW_MAX, row - c);
            int j0 = 0;
#if BIN_VW == 8
            /* the three ways to the lanes' elements, each its own loop (the mode a constant
             * in each) */
#define MIP_STEP8(mode, k0, k1, kv) \
    do { \
        float8 v0, v1, v2, v3, v4, v5, v6, v7, v8; \
        const int8 iv = mip_record8((mode), (k0), (k1), (kv), MIP_BIN_PASS, glv, &v0, &v1, \
                                    &v2, &v3, &v4, &v5, &v6, &v7, &v8); \
        vstore8(iv, 0, ridx + j0); \
        vstore8(v0, 0, r0 + j0); vstore8(v1, 0, r1 + j0); vstore8(v2, 0, r2 + j0); \
        vstore8(v3, 0, r3 + j0); vstore8(v4, 0, r4 + j0); vstore8(v5, 0, r5 + j0); \
        vstore8(v6, 0, r6 + j0); vstore8(v7, 0, r7 + j0); vstore8(v8, 0, r8 + j0); \
    } while (0)
            if (stride == SPP) {
                for (; j0 + 8 <= n; j0 += 8)
                    MIP_STEP8(MIP_CONTIG, first + j0, 0, lane);
            } else if (SPP % 8 == 0) {
                /* a view of 8k samples a pixel (the halves of frames of 16, 32, ... spp):
                 * the 8 lanes are one pixel's consecutive samples (first and j0 are
                 * multiples of 8) */
                for (; j0 + 8 <= n; j0 += 8)
                    MIP_STEP8(MIP_CONTIG, mip_element(first + j0, stride, offset), 0, lane);
            } else if (SPP % 4 == 0) {
                /* a view of 4k samples a pixel (the halves of frames of 8, 16, 24, ... spp):
                 * lanes 0-3 and 4-7 each a run of one pixel's (first and j0 are multiples of
                 * 4): two runs of 4 a step, of one pixel or two */
                for (; j0 + 8 <= n; j0 += 8)
                    MIP_STEP8(MIP_RUNS4, mip_element(first + j0, stride, offset),
                              mip_element(first + j0 + 4, stride, offset), lane);
            } else {
                for (; j0 + 8 <= n; j0 += 8) {
                    const int8 ks = first + j0 + lane;
                    MIP_STEP8(MIP_GATHER, 0, 0, (ks / SPP) * stride + offset + ks % SPP);
                }
            }
#undef MIP_STEP8
#endif
            if (stride == SPP) {  /* a whole frame: the row's samples are contiguous */
                for (int j = j0; j < n; ++j)
                    MIP_RECORD_INTO(j, first + j);
            } else {  /* a view of one (kept apart: the mapping turns the loads to gathers) */
                for (int j = j0; j < n; ++j)
                    MIP_RECORD_INTO(j, mip_element(first + j, stride, offset));
            }
            for (int j = 0; j < n; ++j) {
#if JOINT_HA
                if ((c + j) % SPP >= JOINT_HA) {  /* (first - c is a pixel's first sample) */
                    MIP_RUN(curb, b0, b1, b2, b3, b4, b5, b6, b7, b8, bins_b, flags_b, j);
                    continue;
                }
#endif
                MIP_RUN(cur, a0, a1, a2, a3, a4, a5, a6, a7, a8, bins, flags, j);
            }
        }
        MIP_RUN_END(cur, a0, a1, a2, a3, a4, a5, a6, a7, a8, bins, flags);
#if JOINT_HA
        MIP_RUN_END(curb, b0, b1, b2, b3, b4, b5, b6, b7, b8, bins_b, flags_b);
#endif
    }
}
