/* splat_mip_lanes.h: the owner tiles' records of 8 samples a step as float8 lanes (BIN_VW == 8,
 * CPUs), for kernels/splat_mip_bin.cl, which includes it after mip_record and its argument
 * macros (MIP_BIN_ARGS, MIP_BIN_PASS, the per-level constants mip_tr .. mip_ml, W_SPP).
 *   mip_ld1/2/3(p, ...)   a field of one, two or three components a sample for the 8 lanes:
 *                         MIP_CONTIG (consecutive elements), MIP_RUNS4 (two runs of 4),
 *                         MIP_GATHER (any view)
 *   mip_record8(...)      mip_record for 8 samples, lane by lane the same expressions
 */
#ifndef CLRECON_SPLAT_MIP_LANES_H
#define CLRECON_SPLAT_MIP_LANES_H

#if BIN_VW == 8
/* mip_record for the samples at elements k.s0 .. k.s7, as the lanes of float8s: the same
 * expressions lane by lane (PoCL 3.1 ran the scalar loop one sample at a time: its divisions
 * and compares were the pass's cost); the level's int4 parameters are picked from glv,
 * lv[0 .. NLEV - 1] read once */
#define G8(p, k) ((float8)((p)[(k).s0], (p)[(k).s1], (p)[(k).s2], (p)[(k).s3], (p)[(k).s4], \
                           (p)[(k).s5], (p)[(k).s6], (p)[(k).s7]))
/* The lanes' elements: MIP_CONTIG, k0 .. k0 + 7 (a whole frame); MIP_RUNS4, k0 .. k0 + 3
 * and k1 .. k1 + 3 (a view of 4k samples a pixel: a half of an 8, 16, 24, ... spp frame);
 * MIP_GATHER, k (any other view). Loads of a field with one, two or three components a
 * sample (component c); gathers were half the pass's time on an AMD EPYC, and the halves'
 * bin at 512x512 (deep) took 68.7 / 188.6 ms at 16 / 64 spp as gathers, 38.6 / 113.5 as
 * runs of 4 (AVX-512 AMD EPYC, PoCL). */
#define MIP_CONTIG 0
#define MIP_RUNS4 1
#define MIP_GATHER 2
__attribute__((always_inline)) inline float8 mip_ld1(__global const float *p, const int mode,
                                                    const int k0, const int k1, const int8 k)
{
    if (mode == MIP_CONTIG)
        return vload8(0, p + k0);
    if (mode == MIP_RUNS4)
        return (float8)(vload4(0, p + k0), vload4(0, p + k1));
    return G8(p, k);
}
__attribute__((always_inline)) inline float8 mip_ld2(__global const float *p, const int c,
                                                    const int mode, const int k0,
                                                    const int k1, const int8 k)
{
    if (mode == MIP_CONTIG) {
        const float16 v = vload16(0, p + 2 * k0);
        return c ? v.odd : v.even;
    }
    if (mode == MIP_RUNS4) {
        const float8 a = vload8(0, p + 2 * k0), b = vload8(0, p + 2 * k1);
        return c ? (float8)(a.odd, b.odd) : (float8)(a.even, b.even);
    }
    return G8(p, 2 * k + c);
}
/* three components of 4 consecutive samples (12 floats at q) */
__attribute__((always_inline)) inline float4 mip_ld3_4(__global const float *q, const int c)
{
    const float4 a = vload4(0, q), b = vload4(1, q), d = vload4(2, q);
    return c == 0 ? (float4)(a.s0, a.s3, b.s2, d.s1)
         : c == 1 ? (float4)(a.s1, b.s0, b.s3, d.s2) : (float4)(a.s2, b.s1, d.s0, d.s3);
}
__attribute__((always_inline)) inline float8 mip_ld3(__global const float *p, const int c,
                                                    const int mode, const int k0,
                                                    const int k1, const int8 k)
{
    if (mode == MIP_CONTIG)
        return (float8)(mip_ld3_4(p + 3 * k0, c), mip_ld3_4(p + 3 * k0 + 12, c));
    if (mode == MIP_RUNS4)
        return (float8)(mip_ld3_4(p + 3 * k0, c), mip_ld3_4(p + 3 * k1, c));
    return G8(p, 3 * k + c);
}
__attribute__((always_inline)) inline int8 mip_record8(
    const int mode, const int k0, const int k1, const int8 k, MIP_BIN_ARGS, const int4 *glv,
    float8 *r0, float8 *r1, float8 *r2,
    float8 *r3, float8 *r4, float8 *r5, float8 *r6, float8 *r7, float8 *r8)
{
    const float8 z = mip_ld1(depth, mode, k0, k1, k);
    const int8 miss = isgreaterequal(z, (float8)(MISS_DEPTH));
    const float8 coc = select(c0 / z + c1, (float8)(c1), miss);
    const float8 r = fabs(coc);
    float8 mx = (float8)(0.0f), my = (float8)(0.0f);
#if HAS_MOTION
    mx = mip_ld2(motion, 0, mode, k0, k1, k);
    my = mip_ld2(motion, 1, mode, k0, k1, k);
#endif
    const float8 len = sqrt(mx * mx + my * my);
    int8 l = (int8)(0);
    float8 rl = (float8)(mip_rl[0]), ml = (float8)(mip_ml[0]);
    for (int j = 0; j + 1 < NLEV; ++j) {
        const int8 up = isgreater(r, (float8)(mip_tr[j])) | isgreater(len, (float8)(mip_tm[j]));
        l -= up;  /* up is -1 in a true lane */
        rl = select(rl, (float8)(mip_rl[j + 1]), up);
        ml = select(ml, (float8)(mip_ml[j + 1]), up);
    }
    const float8 s = convert_float8((int8)(1) << l), inv_s = 1.0f / s;
    const float8 cs = select((float8)(1.0f), rl * s / r, isgreater(r * inv_s, rl));
    const float8 ms = select((float8)(1.0f), ml * s / len, isgreater(len * inv_s, ml));
    const float8 cc = coc * cs;
    float8 cx = mip_ld2(position, 0, mode, k0, k1, k) - cc * mip_ld2(lens, 0, mode, k0, k1, k);
    float8 cy = mip_ld2(position, 1, mode, k0, k1, k) - cc * mip_ld2(lens, 1, mode, k0, k1, k);
#if HAS_MOTION
    const float8 dt = (mip_ld1(time, mode, k0, k1, k) - 0.5f) * ms;
    cx -= dt * mx;
    cy -= dt * my;
#endif
    const float8 inv = select(1.0f / z, (float8)(0.0f), miss);
    /* the bounds as vectors: Oclgrind reads the scalars of clamp(int8, int, int) wrongly */
    const int8 layer = clamp(convert_int8(floor((inv - inv_far) * layer_scale)), (int8)(0),
                             (int8)(NLAYERS - 1));
    cx *= inv_s;
    cy *= inv_s;
    const float8 fx = floor(cx), fy = floor(cy);
    int8 gx = (int8)(glv[0].x), gy = (int8)(glv[0].y), gz = (int8)(glv[0].z),
         gw = (int8)(glv[0].w);
    for (int j = 1; j < NLEV; ++j) {
        const int8 at = l == j;
        gx = select(gx, (int8)(glv[j].x), at);
        gy = select(gy, (int8)(glv[j].y), at);
        gz = select(gz, (int8)(glv[j].z), at);
        gw = select(gw, (int8)(glv[j].w), at);
    }
    const int8 qx = convert_int8(fx), qy = convert_int8(fy);
    const int8 e = gw / 2;
    const int8 out = (qx < e - gw) | (qy < e - gw) | (qx >= gy - gw - e) | (qy >= gz - gw - e);
    const float w = 1.0f / (float)W_SPP;
    const float8 wm = w * ms * inv_s;
    *r0 = mip_ld3(color, 0, mode, k0, k1, k) * w;
    *r1 = mip_ld3(color, 1, mode, k0, k1, k) * w;
    *r2 = mip_ld3(color, 2, mode, k0, k1, k) * w;
    *r3 = (float8)(w);
    *r4 = r * cs * inv_s * w;
    *r5 = mx * wm;
    *r6 = my * wm;
    *r7 = (cx - fx) * w;
    *r8 = (cy - fy) * w;
    return select(gx + (layer * gz + qy + gw) * gy + qx + gw, (int8)(-1), out);
}
#endif

#endif /* CLRECON_SPLAT_MIP_LANES_H */
