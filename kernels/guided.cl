/* The guided refinement: each half's box image (unbiased, noisy) regressed, window by window,
 * on the method's image of the same half (biased, smooth); clrecon/methods/guided.py has the
 * derivation and the NumPy reference.
 *
 *   guided_means  per pixel: the halves' box images yA, yB, the rms over RGB of yA - yB, and
 *                 with the guides, everything the fit reads as planes (GP_* below)
 *   guided_fit    per window k ((2 GR + 1)^2, clipped to the image) and half h: the ridge
 *                 regression of the residual e = y - g on the guide's deviation u = g - g_k,
 *                 e ~ A^T u + beta, ridge eps = var(y) / n (var(y) the window's mean of the
 *                 half's variance, n its pixel count), in units of the window's largest
 *                 absolute value s (so that any valid colour's squares stay finite)
 *   guided_apply  per pixel p and half h: q = g_p + mean over the windows k holding p of
 *                 A_k^T (g_p - g_k) + beta_k
 * Arguments: means: color (H, W, S, 3), ga, gb (H, W, 3) the method's images of the halves,
 * planes (GP_PLANES planes of H * W floats, `ps` floats apart); fit: planes, coef (2, H, W,
 * 12): per half and window A row-major (guide channel, output channel) then beta (radiance),
 * fa, fb: var(yA) = fa d^2, var(yB) = fb d^2; apply: ga, gb, coef, qa, qb (H, W, 3).
 * Layout: the fit reads seven of its inputs at every tap, as planes: one tap's values are
 * then 4 bytes apart for neighbouring pixels instead of 12. The planes' pitch `ps` is not a
 * multiple of 4 KiB (the host pads it): at 512x512 planes 1 MiB apart map every tap's
 * seven loads to one L1 set, and the fit took 67 ms against 40 at 500x500.
 * Launch: (W, H) for means, (W, H, 2) for fit and apply (dim 2: the half). One pixel a
 * work-item.
 * Compile-time: GR, the window radius (1..8).
 */
#include "common.h"

#ifndef GR
#define GR 2
#endif

/* the planes of guided_means' output: per half h, the guide (3) and the box image (3) at
 * 6 h, the halves' rms difference, and per half the largest of |g|, |y| and d at a pixel */
#define GP_G(h) (6 * (h))
#define GP_Y(h) (6 * (h) + 3)
#define GP_D 12
#define GP_M(h) (13 + (h))
#define GP_PLANES 15

__kernel void guided_means(__global const float *restrict color,
                           __global const float *restrict ga, __global const float *restrict gb,
                           __global float *restrict planes, int W, int H, int S, int ha, int ps)
{
    int x = get_global_id(0), yy = get_global_id(1);
    if (x >= W || yy >= H) return;
    size_t p = (size_t)yy * W + x, np = (size_t)ps;
    __global const float *c = color + p * (size_t)S * 3;
    float a0 = 0.0f, a1 = 0.0f, a2 = 0.0f, b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
    for (int i = 0; i < ha; ++i) {
        a0 += c[3 * i]; a1 += c[3 * i + 1]; a2 += c[3 * i + 2];
    }
    for (int i = ha; i < S; ++i) {
        b0 += c[3 * i]; b1 += c[3 * i + 1]; b2 += c[3 * i + 2];
    }
    float ia = 1.0f / (float)ha, ib = 1.0f / (float)(S - ha);
    a0 *= ia; a1 *= ia; a2 *= ia; b0 *= ib; b1 *= ib; b2 *= ib;
    /* rms of the difference, scaled by its largest channel: no square overflows */
    float t0 = a0 - b0, t1 = a1 - b1, t2 = a2 - b2;
    float m = fmax(fabs(t0), fmax(fabs(t1), fabs(t2)));
    float r = 0.0f;
    if (m > 0.0f) {
        t0 /= m; t1 /= m; t2 /= m;
        r = m * sqrt((t0 * t0 + t1 * t1 + t2 * t2) * (1.0f / 3.0f));
    }
    float ga0 = ga[3 * p], ga1 = ga[3 * p + 1], ga2 = ga[3 * p + 2];
    float gb0 = gb[3 * p], gb1 = gb[3 * p + 1], gb2 = gb[3 * p + 2];
    planes[GP_G(0) * np + p] = ga0; planes[(GP_G(0) + 1) * np + p] = ga1;
    planes[(GP_G(0) + 2) * np + p] = ga2;
    planes[GP_Y(0) * np + p] = a0; planes[(GP_Y(0) + 1) * np + p] = a1;
    planes[(GP_Y(0) + 2) * np + p] = a2;
    planes[GP_G(1) * np + p] = gb0; planes[(GP_G(1) + 1) * np + p] = gb1;
    planes[(GP_G(1) + 2) * np + p] = gb2;
    planes[GP_Y(1) * np + p] = b0; planes[(GP_Y(1) + 1) * np + p] = b1;
    planes[(GP_Y(1) + 2) * np + p] = b2;
    planes[GP_D * np + p] = r;
    planes[GP_M(0) * np + p] = fmax(r, fmax(fmax(fabs(ga0), fmax(fabs(ga1), fabs(ga2))),
                                            fmax(fabs(a0), fmax(fabs(a1), fabs(a2)))));
    planes[GP_M(1) * np + p] = fmax(r, fmax(fmax(fabs(gb0), fmax(fabs(gb1), fabs(gb2))),
                                            fmax(fabs(b0), fmax(fabs(b1), fabs(b2)))));
}

__kernel void guided_fit(__global const float *restrict planes, __global float *restrict coef,
                         int W, int H, float fa, float fb, int ps)
{
    int x = get_global_id(0), yy = get_global_id(1), h = get_global_id(2);
    if (x >= W || yy >= H) return;
    size_t np = (size_t)ps;
    __global const float *g0p = planes + GP_G(h) * np, *g1p = g0p + np, *g2p = g1p + np;
    __global const float *y0p = planes + GP_Y(h) * np, *y1p = y0p + np, *y2p = y1p + np;
    __global const float *dp = planes + GP_D * np, *mp = planes + GP_M(h) * np;
    float fv = h ? fb : fa;
    size_t k = (size_t)yy * W + x;
    float c0 = g0p[k], c1 = g1p[k], c2 = g2p[k];
    int x0 = max(x - GR, 0), x1 = min(x + GR, W - 1);
    int y0 = max(yy - GR, 0), y1 = min(yy + GR, H - 1);
    /* interior windows run uniform loops (the same trip count and unit-stride addresses
     * for neighbouring work-items: PoCL vectorises them across work-items); windows that
     * the image clips run the clipped loops */
    const int inner = x >= GR && x < W - GR && yy >= GR && yy < H - GR;
    /* the window's scale: its largest absolute guide, box value or halves' difference */
    float s = 0.0f;
    if (inner) {
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di)
                s = fmax(s, mp[k + (ptrdiff_t)dj * W + di]);
    } else {
        for (int j = y0; j <= y1; ++j)
            for (int i = x0; i <= x1; ++i)
                s = fmax(s, mp[(size_t)j * W + i]);
    }
    /* an all-zero window: every sum 0, so A = 0 and beta = 0 */
    float is = s > 0.0f ? 1.0f / s : 0.0f;
    float su0 = 0, su1 = 0, su2 = 0, se0 = 0, se1 = 0, se2 = 0;
    float s00 = 0, s01 = 0, s02 = 0, s11 = 0, s12 = 0, s22 = 0;
    float e00 = 0, e01 = 0, e02 = 0, e10 = 0, e11 = 0, e12 = 0, e20 = 0, e21 = 0, e22 = 0;
    float sdd = 0;
#define GUIDED_FIT_TAP(q) do { \
        float g0 = g0p[q], g1 = g1p[q], g2 = g2p[q]; \
        float u0 = (g0 - c0) * is, u1 = (g1 - c1) * is, u2 = (g2 - c2) * is; \
        float r0 = (y0p[q] - g0) * is, r1 = (y1p[q] - g1) * is, r2 = (y2p[q] - g2) * is; \
        float dq = dp[q] * is; \
        su0 += u0; su1 += u1; su2 += u2; \
        se0 += r0; se1 += r1; se2 += r2; \
        s00 += u0 * u0; s01 += u0 * u1; s02 += u0 * u2; \
        s11 += u1 * u1; s12 += u1 * u2; s22 += u2 * u2; \
        e00 += u0 * r0; e01 += u0 * r1; e02 += u0 * r2; \
        e10 += u1 * r0; e11 += u1 * r1; e12 += u1 * r2; \
        e20 += u2 * r0; e21 += u2 * r1; e22 += u2 * r2; \
        sdd += dq * dq; \
    } while (0)
    if (inner) {
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di)
                GUIDED_FIT_TAP(k + (ptrdiff_t)dj * W + di);
    } else {
        for (int j = y0; j <= y1; ++j)
            for (int i = x0; i <= x1; ++i)
                GUIDED_FIT_TAP((size_t)j * W + i);
    }
#undef GUIDED_FIT_TAP
    float n = (float)((x1 - x0 + 1) * (y1 - y0 + 1)), in = 1.0f / n;
    float mu0 = su0 * in, mu1 = su1 * in, mu2 = su2 * in;
    float me0 = se0 * in, me1 = se1 * in, me2 = se2 * in;
    /* covariance of the guide, and of the guide with the residual */
    float c00 = s00 * in - mu0 * mu0, c01 = s01 * in - mu0 * mu1, c02 = s02 * in - mu0 * mu2;
    float c11 = s11 * in - mu1 * mu1, c12 = s12 * in - mu1 * mu2, c22 = s22 * in - mu2 * mu2;
    float k00 = e00 * in - mu0 * me0, k01 = e01 * in - mu0 * me1, k02 = e02 * in - mu0 * me2;
    float k10 = e10 * in - mu1 * me0, k11 = e11 * in - mu1 * me1, k12 = e12 * in - mu1 * me2;
    float k20 = e20 * in - mu2 * me0, k21 = e21 * in - mu2 * me1, k22 = e22 * in - mu2 * me2;
    /* ridge: the window's mean variance of y over its pixel count, and floors of 1e-5 of the
     * guide's own variance and 1e-12 of s^2 that keep a flat (or one-dimensional) guide's
     * system regular */
    float tr = fmax(c00 + c11 + c22, 0.0f);
    float eps = fv * sdd * in * in + 1e-5f * tr + 1e-12f;
    c00 += eps; c11 += eps; c22 += eps;
    /* solve (C + eps I) A = K by Cholesky, column by column: backward stable, where the
     * cofactors of a guide whose channels move together (a grey texture: C near rank 1)
     * cancel in float32 */
    float l00 = sqrt(c00), l10 = c01 / l00, l20 = c02 / l00;
    float t11 = c11 - l10 * l10;
    float l11 = sqrt(t11), l21 = (c12 - l20 * l10) / l11;
    float t22 = c22 - l20 * l20 - l21 * l21;
    float l22 = sqrt(t22);
    int ok = c00 > 0.0f && t11 > 0.0f && t22 > 0.0f && isfinite(l21) && isfinite(l22);
    if (!ok) { l00 = l11 = l22 = 1.0f; l10 = l20 = l21 = 0.0f; }
    float okf = ok ? 1.0f : 0.0f;
    float a0, a1, a2, a3, a4, a5, a6, a7, a8;
/* column c of A from column c of K: forward then back substitution */
#define GUIDED_SOLVE(ka, kb, kc, xa, xb, xc) do { \
        float z0 = (ka) / l00, z1 = ((kb) - l10 * z0) / l11; \
        float z2 = ((kc) - l20 * z0 - l21 * z1) / l22; \
        xc = okf * (z2 / l22); \
        xb = okf * ((z1 - l21 * (z2 / l22)) / l11); \
        xa = okf * ((z0 - l10 * ((z1 - l21 * (z2 / l22)) / l11) - l20 * (z2 / l22)) / l00); \
    } while (0)
    GUIDED_SOLVE(k00, k10, k20, a0, a3, a6);
    GUIDED_SOLVE(k01, k11, k21, a1, a4, a7);
    GUIDED_SOLVE(k02, k12, k22, a2, a5, a8);
#undef GUIDED_SOLVE
    /* beta (in units of s) = mean residual - A^T mean deviation, stored in radiance */
    float b0 = me0 - (a0 * mu0 + a3 * mu1 + a6 * mu2);
    float b1 = me1 - (a1 * mu0 + a4 * mu1 + a7 * mu2);
    float b2 = me2 - (a2 * mu0 + a5 * mu1 + a8 * mu2);
    __global float *out = coef + ((size_t)h * W * H + k) * 12;
    out[0] = a0; out[1] = a1; out[2] = a2; out[3] = a3; out[4] = a4; out[5] = a5;
    out[6] = a6; out[7] = a7; out[8] = a8;
    out[9] = b0 * s; out[10] = b1 * s; out[11] = b2 * s;
}

__kernel void guided_apply(__global const float *restrict ga, __global const float *restrict gb,
                           __global const float *restrict coef, __global float *restrict qa,
                           __global float *restrict qb, int W, int H)
{
    int x = get_global_id(0), yy = get_global_id(1), h = get_global_id(2);
    if (x >= W || yy >= H) return;
    __global const float *g = h ? gb : ga;
    __global float *q = h ? qb : qa;
    __global const float *ch = coef + (size_t)h * W * H * 12;
    size_t p = (size_t)yy * W + x;
    float p0 = g[3 * p], p1 = g[3 * p + 1], p2 = g[3 * p + 2];
    int x0 = max(x - GR, 0), x1 = min(x + GR, W - 1);
    int y0 = max(yy - GR, 0), y1 = min(yy + GR, H - 1);
    float o0 = 0.0f, o1 = 0.0f, o2 = 0.0f;
#define GUIDED_APPLY_TAP(kk) do { \
        size_t k = (kk); \
        __global const float *a = ch + k * 12; \
        float u0 = p0 - g[3 * k], u1 = p1 - g[3 * k + 1], u2 = p2 - g[3 * k + 2]; \
        o0 += a[0] * u0 + a[3] * u1 + a[6] * u2 + a[9]; \
        o1 += a[1] * u0 + a[4] * u1 + a[7] * u2 + a[10]; \
        o2 += a[2] * u0 + a[5] * u1 + a[8] * u2 + a[11]; \
    } while (0)
    if (x >= GR && x < W - GR && yy >= GR && yy < H - GR) {  /* uniform: see guided_fit */
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di)
                GUIDED_APPLY_TAP(p + (ptrdiff_t)dj * W + di);
    } else {
        for (int j = y0; j <= y1; ++j)
            for (int i = x0; i <= x1; ++i)
                GUIDED_APPLY_TAP((size_t)j * W + i);
    }
#undef GUIDED_APPLY_TAP
    float in = 1.0f / (float)((x1 - x0 + 1) * (y1 - y0 + 1));
    q[3 * p] = p0 + o0 * in;
    q[3 * p + 1] = p1 + o1 * in;
    q[3 * p + 2] = p2 + o2 * in;
}
