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
 * planes (GP_PLANES planes of H * W floats, `ps` floats apart); fit: planes, coef (2 x 12
 * planes, `ps` apart): per half and window A row-major (guide channel, output channel) then
 * beta (radiance), fa, fb: var(yA) = fa d^2, var(yB) = fb d^2; apply: planes, coef, qa, qb
 * (H, W, 3).
 * Layout: the fit reads seven of its inputs at every tap, as planes: one tap's values are
 * then 4 bytes apart for neighbouring pixels instead of 12. The planes' pitch `ps` is not a
 * multiple of 4 KiB (the host pads it): at 512x512 planes 1 MiB apart map every tap's
 * seven loads to one L1 set, and the fit took 67 ms against 40 at 500x500.
 * Launch: (W, H) for means, (ceil(W / GF_VW), H, 2) for fit and apply (dim 2: the half).
 * Compile-time: GR, the window radius (1..8); GF_VW, windows a work-item (1, 8 or 16).
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

/* the fit's sums over a window, in units of its scale s: sum u (3), sum e (3), sum u u^T (6),
 * sum u e^T (9, row = guide channel), sum d^2 */
#define GF_SUMS 22

/* A and beta of one window from its sums (n pixels, scale s), into out[i * cs], i < 12 */
__attribute__((always_inline)) inline void guided_solve(const float *acc, float s, float n,
                                                         float fv, __global float *out,
                                                         size_t cs)
{
    float in = 1.0f / n;
    float su0 = acc[0], su1 = acc[1], su2 = acc[2], se0 = acc[3], se1 = acc[4], se2 = acc[5];
    float s00 = acc[6], s01 = acc[7], s02 = acc[8], s11 = acc[9], s12 = acc[10], s22 = acc[11];
    float e00 = acc[12], e01 = acc[13], e02 = acc[14], e10 = acc[15], e11 = acc[16];
    float e12 = acc[17], e20 = acc[18], e21 = acc[19], e22 = acc[20], sdd = acc[21];
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
    out[0] = a0; out[cs] = a1; out[2 * cs] = a2; out[3 * cs] = a3; out[4 * cs] = a4;
    out[5 * cs] = a5; out[6 * cs] = a6; out[7 * cs] = a7; out[8 * cs] = a8;
    out[9 * cs] = b0 * s; out[10 * cs] = b1 * s; out[11 * cs] = b2 * s;
}

/* one window of pixel (x, yy), clipped to the image: the sums, then the solve */
__attribute__((always_inline)) inline void guided_fit_pixel(
    __global const float *g0p, __global const float *g1p, __global const float *g2p,
    __global const float *y0p, __global const float *y1p, __global const float *y2p,
    __global const float *dp, __global const float *mp, int W, int H, int x, int yy, float fv,
    __global float *out, size_t cs)
{
    size_t k = (size_t)yy * W + x;
    float c0 = g0p[k], c1 = g1p[k], c2 = g2p[k];
    int x0 = max(x - GR, 0), x1 = min(x + GR, W - 1);
    int y0 = max(yy - GR, 0), y1 = min(yy + GR, H - 1);
    /* the window's scale: its largest absolute guide, box value or halves' difference */
    float s = 0.0f;
    for (int j = y0; j <= y1; ++j)
        for (int i = x0; i <= x1; ++i)
            s = fmax(s, mp[(size_t)j * W + i]);
    /* an all-zero window: every sum 0, so A = 0 and beta = 0 */
    float is = s > 0.0f ? 1.0f / s : 0.0f;
    float acc[GF_SUMS];
    for (int i = 0; i < GF_SUMS; ++i) acc[i] = 0.0f;
    for (int j = y0; j <= y1; ++j)
        for (int i = x0; i <= x1; ++i) {
            size_t q = (size_t)j * W + i;
            float g0 = g0p[q], g1 = g1p[q], g2 = g2p[q];
            float u0 = (g0 - c0) * is, u1 = (g1 - c1) * is, u2 = (g2 - c2) * is;
            float r0 = (y0p[q] - g0) * is, r1 = (y1p[q] - g1) * is, r2 = (y2p[q] - g2) * is;
            float dq = dp[q] * is;
            acc[0] += u0; acc[1] += u1; acc[2] += u2;
            acc[3] += r0; acc[4] += r1; acc[5] += r2;
            acc[6] += u0 * u0; acc[7] += u0 * u1; acc[8] += u0 * u2;
            acc[9] += u1 * u1; acc[10] += u1 * u2; acc[11] += u2 * u2;
            acc[12] += u0 * r0; acc[13] += u0 * r1; acc[14] += u0 * r2;
            acc[15] += u1 * r0; acc[16] += u1 * r1; acc[17] += u1 * r2;
            acc[18] += u2 * r0; acc[19] += u2 * r1; acc[20] += u2 * r2;
            acc[21] += dq * dq;
        }
    guided_solve(acc, s, (float)((x1 - x0 + 1) * (y1 - y0 + 1)), fv, out, cs);
}

#ifndef GF_VW
#define GF_VW 1
#endif
#if GF_VW == 8
#define GF_V float8
#define GF_LOAD(p) vload8(0, p)
#define GF_STORE(v, p) vstore8(v, 0, p)
#elif GF_VW == 16
#define GF_V float16
#define GF_LOAD(p) vload16(0, p)
#define GF_STORE(v, p) vstore16(v, 0, p)
#elif GF_VW != 1
#error "GF_VW must be 1, 8 or 16"
#endif

/* GF_VW windows of a row a work-item: pixels x0 .. x0 + GF_VW - 1. Where all their windows
 * lie inside the image the sums run as GF_VW lanes of a vector (PoCL 3.1 runs kernels with
 * vector values one work-item at a time; explicit lanes are what vectorises on a CPU), the
 * solve lane by lane; elsewhere each pixel runs guided_fit_pixel. */
__kernel void guided_fit(__global const float *restrict planes, __global float *restrict coef,
                         int W, int H, float fa, float fb, int ps)
{
    int x0 = get_global_id(0) * GF_VW, yy = get_global_id(1), h = get_global_id(2);
    if (x0 >= W || yy >= H) return;
    size_t np = (size_t)ps;
    __global const float *g0p = planes + GP_G(h) * np, *g1p = g0p + np, *g2p = g1p + np;
    __global const float *y0p = planes + GP_Y(h) * np, *y1p = y0p + np, *y2p = y1p + np;
    __global const float *dp = planes + GP_D * np, *mp = planes + GP_M(h) * np;
    float fv = h ? fb : fa;
    __global float *out = coef + (size_t)h * 12 * np + (size_t)yy * W + x0;
#if GF_VW > 1
    if (x0 >= GR && x0 + GF_VW - 1 + GR < W && yy >= GR && yy + GR < H) {
        size_t k = (size_t)yy * W + x0;
        GF_V c0 = GF_LOAD(g0p + k), c1 = GF_LOAD(g1p + k), c2 = GF_LOAD(g2p + k);
        GF_V s = 0.0f;
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di)
                s = fmax(s, GF_LOAD(mp + k + (ptrdiff_t)dj * W + di));
        GF_V is = select((GF_V)(0.0f), 1.0f / s, s > 0.0f);
        GF_V v[GF_SUMS];
        for (int i = 0; i < GF_SUMS; ++i) v[i] = 0.0f;
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di) {
                size_t q = k + (ptrdiff_t)dj * W + di;
                GF_V g0 = GF_LOAD(g0p + q), g1 = GF_LOAD(g1p + q), g2 = GF_LOAD(g2p + q);
                GF_V u0 = (g0 - c0) * is, u1 = (g1 - c1) * is, u2 = (g2 - c2) * is;
                GF_V r0 = (GF_LOAD(y0p + q) - g0) * is, r1 = (GF_LOAD(y1p + q) - g1) * is;
                GF_V r2 = (GF_LOAD(y2p + q) - g2) * is;
                GF_V dq = GF_LOAD(dp + q) * is;
                v[0] += u0; v[1] += u1; v[2] += u2;
                v[3] += r0; v[4] += r1; v[5] += r2;
                v[6] += u0 * u0; v[7] += u0 * u1; v[8] += u0 * u2;
                v[9] += u1 * u1; v[10] += u1 * u2; v[11] += u2 * u2;
                v[12] += u0 * r0; v[13] += u0 * r1; v[14] += u0 * r2;
                v[15] += u1 * r0; v[16] += u1 * r1; v[17] += u1 * r2;
                v[18] += u2 * r0; v[19] += u2 * r1; v[20] += u2 * r2;
                v[21] += dq * dq;
            }
        float lanes[GF_SUMS * GF_VW], sl[GF_VW];
        for (int i = 0; i < GF_SUMS; ++i) GF_STORE(v[i], lanes + i * GF_VW);
        GF_STORE(s, sl);
        for (int l = 0; l < GF_VW; ++l) {
            float acc[GF_SUMS];
            for (int i = 0; i < GF_SUMS; ++i) acc[i] = lanes[i * GF_VW + l];
            guided_solve(acc, sl[l], (float)((2 * GR + 1) * (2 * GR + 1)), fv, out + l, np);
        }
        return;
    }
#endif
    for (int l = 0; l < GF_VW && x0 + l < W; ++l)
        guided_fit_pixel(g0p, g1p, g2p, y0p, y1p, y2p, dp, mp, W, H, x0 + l, yy, fv, out + l,
                         np);
}

/* the refined value of pixel (x, yy), its windows clipped to the image */
__attribute__((always_inline)) inline void guided_apply_pixel(
    __global const float *g0p, __global const float *g1p, __global const float *g2p,
    __global const float *ch, size_t np, int W, int H, int x, int yy, __global float *q)
{
    size_t p = (size_t)yy * W + x;
    float p0 = g0p[p], p1 = g1p[p], p2 = g2p[p];
    int x0 = max(x - GR, 0), x1 = min(x + GR, W - 1);
    int y0 = max(yy - GR, 0), y1 = min(yy + GR, H - 1);
    float o0 = 0.0f, o1 = 0.0f, o2 = 0.0f;
    for (int j = y0; j <= y1; ++j)
        for (int i = x0; i <= x1; ++i) {
            size_t k = (size_t)j * W + i;
            __global const float *a = ch + k;
            float u0 = p0 - g0p[k], u1 = p1 - g1p[k], u2 = p2 - g2p[k];
            o0 += a[0] * u0 + a[3 * np] * u1 + a[6 * np] * u2 + a[9 * np];
            o1 += a[np] * u0 + a[4 * np] * u1 + a[7 * np] * u2 + a[10 * np];
            o2 += a[2 * np] * u0 + a[5 * np] * u1 + a[8 * np] * u2 + a[11 * np];
        }
    float in = 1.0f / (float)((x1 - x0 + 1) * (y1 - y0 + 1));
    q[3 * p] = p0 + o0 * in;
    q[3 * p + 1] = p1 + o1 * in;
    q[3 * p + 2] = p2 + o2 * in;
}

/* GF_VW pixels of a row a work-item, as lanes where all their windows lie inside the
 * image (see guided_fit) */
__kernel void guided_apply(__global const float *restrict planes,
                           __global const float *restrict coef, __global float *restrict qa,
                           __global float *restrict qb, int W, int H, int ps)
{
    int x0 = get_global_id(0) * GF_VW, yy = get_global_id(1), h = get_global_id(2);
    if (x0 >= W || yy >= H) return;
    size_t np = (size_t)ps;
    __global const float *g0p = planes + GP_G(h) * np, *g1p = g0p + np, *g2p = g1p + np;
    __global const float *ch = coef + (size_t)h * 12 * np;
    __global float *q = h ? qb : qa;
#if GF_VW > 1
    if (x0 >= GR && x0 + GF_VW - 1 + GR < W && yy >= GR && yy + GR < H) {
        size_t p = (size_t)yy * W + x0;
        GF_V p0 = GF_LOAD(g0p + p), p1 = GF_LOAD(g1p + p), p2 = GF_LOAD(g2p + p);
        GF_V o0 = 0.0f, o1 = 0.0f, o2 = 0.0f;
        for (int dj = -GR; dj <= GR; ++dj)
            for (int di = -GR; di <= GR; ++di) {
                size_t k = p + (ptrdiff_t)dj * W + di;
                __global const float *a = ch + k;
                GF_V u0 = p0 - GF_LOAD(g0p + k), u1 = p1 - GF_LOAD(g1p + k);
                GF_V u2 = p2 - GF_LOAD(g2p + k);
                o0 += GF_LOAD(a) * u0 + GF_LOAD(a + 3 * np) * u1 + GF_LOAD(a + 6 * np) * u2 +
                      GF_LOAD(a + 9 * np);
                o1 += GF_LOAD(a + np) * u0 + GF_LOAD(a + 4 * np) * u1 +
                      GF_LOAD(a + 7 * np) * u2 + GF_LOAD(a + 10 * np);
                o2 += GF_LOAD(a + 2 * np) * u0 + GF_LOAD(a + 5 * np) * u1 +
                      GF_LOAD(a + 8 * np) * u2 + GF_LOAD(a + 11 * np);
            }
        const float in = 1.0f / (float)((2 * GR + 1) * (2 * GR + 1));
        float r0[GF_VW], r1[GF_VW], r2[GF_VW];
        GF_STORE(p0 + o0 * in, r0);
        GF_STORE(p1 + o1 * in, r1);
        GF_STORE(p2 + o2 * in, r2);
        for (int l = 0; l < GF_VW; ++l) {
            q[3 * (p + l)] = r0[l];
            q[3 * (p + l) + 1] = r1[l];
            q[3 * (p + l) + 2] = r2[l];
        }
        return;
    }
#endif
    for (int l = 0; l < GF_VW && x0 + l < W; ++l)
        guided_apply_pixel(g0p, g1p, g2p, ch, np, W, H, x0 + l, yy, q);
}
