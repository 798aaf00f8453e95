/* filter_sheared.cl: the rotated Gaussian of each partition as a sheared one (eq. 9; Hasselgren
 * et al. 2015, section 6.2): a recursive filter along one grid axis (eq. 10, forward then
 * backward) and a Gaussian along the sheared axis, per tile with its guard band.
 *
 * Axis (P_AXIS, from partition_setup): 0 is the paper's decomposition, recursive along x and
 * the Gaussian along (beta, 1), sampled one tap per row; 1 is its transpose, recursive along
 * y and the Gaussian along (1, beta), one tap per column. The Gaussian runs along the axis of
 * larger variance, so its taps are at most about one grid pixel apart: a thin ellipse a few
 * degrees off the x axis has s_v << 1 in the paper's form, and one tap per row would then
 * collapse it to a point (measured: 140 px motion lost 6 dB).
 *
 * The two passes are named for what they do, which P_AXIS does not change (as
 * filter_sheared_x / _y they ran along y and x with axis 1):
 * filter_sheared_recursive: the recursive filter along the recursive axis (x with axis 0, y
 *   with axis 1), in place on the grids. One work-item per FR_VW grid lines of a slot, range
 *   (ceil(DMAX / FR_VW), tiles * MAXP); a line is row (axis 0) or column (axis 1) `line`;
 *   lines of empty slots and lines >= D return. On every channel: forward
 *   y[i] = (1 - gamma) x[i] + gamma y[i - 1] (y[-1] = 0), then the same backward, RECURSIONS
 *   times. gamma gives each pair the variance
 *   2 gamma / (1 - gamma)^2 = v / RECURSIONS, v the variance of the Gaussian of std s_u
 *   sampled at integers (the same discrete filter the Gaussian taps apply; for s_u >= 2 it is
 *   s_u^2, for the in-focus 0.33 px about 0.02). Eq. 10's gamma = exp(-sqrt2 / s_u) is the
 *   large-s_u limit.
 * filter_sheared_gauss: the Gaussian along the sheared axis e, from the grids into the
 *   filtered images. One work-item per GS_VW filtered pixels (i .. i + GS_VW - 1, j) in
 *   [-1, T/s]^2 of a slot, range (ceil(FT / GS_VW), FT, tiles * MAXP), computed as vectors:
 *   out = sum_k exp(-k^2 / (2 s_v^2)) grid((i, j) + G + k e),
 *   e = (beta, 1) or (1, beta), k = -ceil(3 s_v) .. ceil(3 s_v), linear interpolation along
 *   the recursive axis, taps outside the grid dropped. Unnormalised: composite divides the
 *   channels by each other.
 *   grids     float (tiles, MAXP, NCH, DMAX, DMAX), row stride D (reproject's layout)
 *   filtered  float (tiles, MAXP, NCH, FT, FT), index (j + 1) * FT + (i + 1)
 *   params    float (tiles, MAXP, NPAR) from partition_setup (P_SHU, P_SHV, P_BETA, P_AXIS)
 * Compile-time: TILE, MAXP, GMAX, RECURSIONS, FR_VW (1, 4, 8), FR_CH, GS_VW (4, 8, 16).
 * The local size of filter_sheared_gauss is a
 * launch parameter only (tuned); filter_sheared_recursive's is the runtime's.
 */
#include "layered.h"
#include "vec_hint.h"

#ifndef RECURSIONS
#define RECURSIONS 3  /* forward-backward passes (1: the paper's eq. 10) */
#endif

/* Variance of exp(-k^2 / (2 s^2)) sampled at the integers. */
inline float sampled_gauss_var(float s)
{
    if (s >= 2.0f)
        return s * s;
    float num = 0.0f, den = 1.0f;
    for (int k = 1; k <= 6; ++k) {
        const float w = exp(-(float)(k * k) / (2.0f * s * s));
        num += 2.0f * k * k * w;
        den += 2.0f * w;
    }
    return num / den;
}

/* gamma whose forward-backward pair has variance v: 2 g / (1 - g)^2 = v. */
inline float recursive_gamma(float v)
{
    return v > 1e-6f ? ((v + 1.0f) - sqrt(2.0f * v + 1.0f)) / v : 0.0f;
}

#define FR_CAT_(a, b) a##b
#define FR_CAT(a, b) FR_CAT_(a, b)

#ifndef FR_VW
#define FR_VW 1  /* grid lines a work-item of filter_sheared_recursive */
#endif
#ifndef FR_CH
#define FR_CH NCH  /* channels filtered at a time by the vector kernel (divides NCH) */
#endif

#if FR_VW == 1
__kernel void filter_sheared_recursive(__global const float *params, __global float *grids)
{
    const int line = get_global_id(0), slot = get_global_id(1);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (line >= dim)
        return;
    const int along = p[P_AXIS] == 0.0f ? 1 : dim;       /* element stride on the line */
    const int start = p[P_AXIS] == 0.0f ? line * dim : line;
    const float gm = recursive_gamma(sampled_gauss_var(p[P_SHU]) / RECURSIONS);
    const float a = 1.0f - gm;
    /* the NCH channels run side by side: independent recursions the CPU can overlap */
    __global float *r = grids + (size_t)slot * NCH * DMAX * DMAX + start;
    for (int n = 0; n < RECURSIONS; ++n) {
        float y[NCH] = {0.0f};
        for (int i = 0; i < dim; ++i) {
            for (int c = 0; c < NCH; ++c) {
                y[c] = a * r[c * DMAX * DMAX + i * along] + gm * y[c];
                r[c * DMAX * DMAX + i * along] = y[c];
            }
        }
        for (int c = 0; c < NCH; ++c)
            y[c] = 0.0f;
        for (int i = dim - 1; i >= 0; --i) {
            for (int c = 0; c < NCH; ++c) {
                y[c] = a * r[c * DMAX * DMAX + i * along] + gm * y[c];
                r[c * DMAX * DMAX + i * along] = y[c];
            }
        }
    }
}

#else
/* FR_VW lines a work-item (a CPU: PoCL vectorises no kernel that holds vector values, and a
 * line's recursion is a serial chain): lines line0 .. line0 + FR_VW - 1 of every channel
 * are gathered once into a private array, lane l holding line l (lines past dim repeat the
 * last one and are not stored back), filtered there as FR_VW-wide vectors with the NCH
 * channels' chains side by side, and written back. Axis 1's lines are columns, adjacent in
 * memory: a full set of them moves as vector loads and stores; axis 0's are rows, and a full
 * set of them moves FR_VW elements at a time as row vectors and a transpose (fr_transpose). */
typedef FR_CAT(float, FR_VW) frvec;
#define FR_VLOAD(i, p) FR_CAT(vload, FR_VW)(i, p)
#define FR_VSTORE(v, i, p) FR_CAT(vstore, FR_VW)(v, i, p)

/* Transpose the FR_VW x FR_VW block m (m[k] its row k) in registers: log2(FR_VW) rounds of
 * interleaving rows k and k + FR_VW / 2 (lanes a0 b0 a1 b1 .. of the low halves into row 2k,
 * of the high halves into 2k + 1). Axis 0's lines are rows: FR_VW of them move between the
 * grid and the (element, lane) array as row vectors and one transpose per FR_VW elements,
 * where an element-wise copy made the compiler gather (and scatter) them lane by lane: the
 * copies were most of the pass (deep 1280x720 8 spp, PoCL). Pure data movement: the same
 * values. */
inline void fr_transpose(frvec *m)
{
    for (int round = 1; round < FR_VW; round *= 2) {
        frvec t[FR_VW];
        for (int k = 0; k < FR_VW / 2; ++k) {
            const frvec a = m[k], b = m[k + FR_VW / 2];
#if FR_VW == 8
            t[2 * k] = (frvec)(a.s0, b.s0, a.s1, b.s1, a.s2, b.s2, a.s3, b.s3);
            t[2 * k + 1] = (frvec)(a.s4, b.s4, a.s5, b.s5, a.s6, b.s6, a.s7, b.s7);
#else
            t[2 * k] = (frvec)(a.s0, b.s0, a.s1, b.s1);
            t[2 * k + 1] = (frvec)(a.s2, b.s2, a.s3, b.s3);
#endif
        }
        for (int k = 0; k < FR_VW; ++k)
            m[k] = t[k];
    }
}

__kernel SCALAR_WORK_ITEMS
void filter_sheared_recursive(__global const float *params, __global float *grids)
{
    const int line0 = get_global_id(0) * FR_VW, slot = get_global_id(1);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (line0 >= dim)
        return;
    const int ax1 = p[P_AXIS] != 0.0f;
    const int along = ax1 ? dim : 1, across = ax1 ? 1 : dim;
    const int nl = min(FR_VW, dim - line0);
    const int full = ax1 && nl == FR_VW;
    const float gm = recursive_gamma(sampled_gauss_var(p[P_SHU]) / RECURSIONS);
    const float a = 1.0f - gm;
    __global float *base = grids + (size_t)slot * NCH * DMAX * DMAX + (size_t)line0 * across;
    /* FR_CH channels at a time, their chains side by side (a divisor of NCH: the host keeps
     * the array within what PoCL's worker threads hold) */
    float v[FR_CH * DMAX * FR_VW];   /* (channel, element, lane) */
    for (int c0 = 0; c0 < NCH; c0 += FR_CH) {
        for (int c = 0; c < FR_CH; ++c) {
            __global const float *r = base + (c0 + c) * DMAX * DMAX;
            float *o = v + c * DMAX * FR_VW;
            if (full) {
                for (int i = 0; i < dim; ++i)
                    FR_VSTORE(FR_VLOAD(0, r + i * dim), i, o);
            } else {
                int i = 0;
                if (!ax1 && nl == FR_VW) {  /* full rows: blocks of FR_VW elements */
                    for (; i + FR_VW <= dim; i += FR_VW) {
                        frvec m[FR_VW];
                        for (int l = 0; l < FR_VW; ++l)
                            m[l] = FR_VLOAD(0, r + l * dim + i);
                        fr_transpose(m);
                        for (int k = 0; k < FR_VW; ++k)
                            FR_VSTORE(m[k], i + k, o);
                    }
                }
                for (; i < dim; ++i)
                    for (int l = 0; l < FR_VW; ++l)
                        o[i * FR_VW + l] = r[i * along + min(l, nl - 1) * across];
            }
        }
        for (int n = 0; n < RECURSIONS; ++n) {
            frvec y[FR_CH];
            for (int c = 0; c < FR_CH; ++c)
                y[c] = (frvec)(0.0f);
            for (int i = 0; i < dim; ++i) {
                for (int c = 0; c < FR_CH; ++c) {
                    y[c] = a * FR_VLOAD(c * DMAX + i, v) + gm * y[c];
                    FR_VSTORE(y[c], c * DMAX + i, v);
                }
            }
            for (int c = 0; c < FR_CH; ++c)
                y[c] = (frvec)(0.0f);
            for (int i = dim - 1; i >= 0; --i) {
                for (int c = 0; c < FR_CH; ++c) {
                    y[c] = a * FR_VLOAD(c * DMAX + i, v) + gm * y[c];
                    FR_VSTORE(y[c], c * DMAX + i, v);
                }
            }
        }
        for (int c = 0; c < FR_CH; ++c) {
            __global float *r = base + (c0 + c) * DMAX * DMAX;
            const float *o = v + c * DMAX * FR_VW;
            if (full) {
                for (int i = 0; i < dim; ++i)
                    FR_VSTORE(FR_VLOAD(i, o), 0, r + i * dim);
            } else {
                int i = 0;
                if (!ax1 && nl == FR_VW) {
                    for (; i + FR_VW <= dim; i += FR_VW) {
                        frvec m[FR_VW];
                        for (int k = 0; k < FR_VW; ++k)
                            m[k] = FR_VLOAD(i + k, o);
                        fr_transpose(m);
                        for (int l = 0; l < FR_VW; ++l)
                            FR_VSTORE(m[l], 0, r + l * dim + i);
                    }
                }
                for (; i < dim; ++i)
                    for (int l = 0; l < nl; ++l)
                        r[i * along + l * across] = o[i * FR_VW + l];
            }
        }
    }
}
#endif

#ifndef GS_VW
#define GS_VW 4  /* outputs a work-item of filter_sheared_gauss: 4, 8 or 16 */
#endif
typedef FR_CAT(float, GS_VW) gsvec;
#define GS_VLOAD(i, p) FR_CAT(vload, GS_VW)(i, p)
#define GS_VSTORE(v, i, p) FR_CAT(vstore, GS_VW)(v, i, p)

__kernel SCALAR_WORK_ITEMS
void filter_sheared_gauss(__global const float *params, __global const float *grids,
                          __global float *filtered)
{
    /* GS_VW outputs (i0 .. i0 + GS_VW - 1, j) per work-item, as one vector per channel: along
     * x they are consecutive in the grid for either axis (axis 0: along u, axis 1: along w),
     * so a tap is two vector loads per channel where all the lanes lie inside the grid; taps
     * where some lane does not go lane by lane into `edge` (the scalar rule: u < -1 or
     * u >= dim, or w outside, dropped) */
    int i0, j, slot;
    __global const float *p = layered_filtered_item(params, GS_VW, &i0, &j, &slot);
    if (!p)
        return;
    const int dim = (int)p[P_DIM], side = TILE / (int)p[P_SCALE];
    const int g = (int)p[P_GUARD];
    const float sv = p[P_SHV], beta = p[P_BETA];
    /* (u, w): position along the recursive axis and the tap axis; axis 1 swaps x and y */
    const int ax = p[P_AXIS] != 0.0f;
    const int u0 = (ax ? j : i0) + g, w0 = (ax ? i0 : j) + g;   /* of lane 0 */
    const int su = ax ? dim : 1, sw = ax ? 1 : dim;   /* strides of u and w in the grid */
    const int lu = ax ? 0 : 1, lw = ax ? 1 : 0;       /* a lane's step in u and w */
    const int kmax = min((int)ceil(3.0f * sv), dim);
    const float inv = -0.5f / (sv * sv);
    gsvec acc[NCH];
    float edge[NCH * GS_VW];
    for (int c = 0; c < NCH; ++c)
        acc[c] = (gsvec)(0.0f);
    for (int e = 0; e < NCH * GS_VW; ++e)
        edge[e] = 0.0f;
    __global const float *grid = grids + (size_t)slot * NCH * DMAX * DMAX;
    /* the taps exp(inv k^2) by recurrence: w_{k+1} = w_k r_k, r_{k+1} = r_k q, q = exp(2 inv),
     * so two exp per pixel instead of one per tap (relative error < 1e-5 over 2 kmax steps) */
    float wk = exp(inv * (float)(kmax * kmax));
    float rk = exp(inv * (float)(1 - 2 * kmax));
    const float q = exp(2.0f * inv);
    for (int k = -kmax; k <= kmax; ++k, wk *= rk, rk *= q) {
        const int w = w0 + k;
        const float uf = (float)u0 + beta * (float)k;
        const float fu = floor(uf);
        const float f = uf - fu;
        const int u = (int)fu;
        if (ax == 0 && u >= 0 && u + GS_VW < dim && w >= 0 && w < dim) {
            /* lanes at (u + l, w) */
            const float wa = wk * (1.0f - f), wb = wk * f;
            for (int c = 0; c < NCH; ++c) {
                __global const float *r = grid + c * DMAX * DMAX + w * dim + u;
                acc[c] += wa * GS_VLOAD(0, r) + wb * GS_VLOAD(0, r + 1);
            }
        } else if (ax == 1 && u >= -1 && u < dim && w >= 0 && w + GS_VW - 1 < dim) {
            /* lanes at (u, w + l) */
            const float wa = u >= 0 ? wk * (1.0f - f) : 0.0f;
            const float wb = u + 1 < dim ? wk * f : 0.0f;
            for (int c = 0; c < NCH; ++c) {
                __global const float *r = grid + c * DMAX * DMAX + w;
                gsvec v = (gsvec)(0.0f);
                if (wa != 0.0f)
                    v = wa * GS_VLOAD(0, r + u * dim);
                if (wb != 0.0f)
                    v += wb * GS_VLOAD(0, r + (u + 1) * dim);
                acc[c] += v;
            }
        } else {
            for (int l = 0; l < GS_VW; ++l) {
                const int ul = u + l * lu, wl = w + l * lw;
                if (wl < 0 || wl >= dim || ul < -1 || ul >= dim)
                    continue;
                const float wa = ul >= 0 ? wk * (1.0f - f) : 0.0f;
                const float wb = ul + 1 < dim ? wk * f : 0.0f;
                for (int c = 0; c < NCH; ++c) {
                    __global const float *r = grid + c * DMAX * DMAX + wl * sw;
                    edge[c * GS_VW + l] += (wa != 0.0f ? wa * r[ul * su] : 0.0f)
                                           + (wb != 0.0f ? wb * r[(ul + 1) * su] : 0.0f);
                }
            }
        }
    }
    __global float *out = layered_filtered_at(filtered, slot, i0, j);
    const int nl = min(GS_VW, side - i0 + 1);   /* lanes with i <= side */
    for (int c = 0; c < NCH; ++c) {
        const gsvec v = acc[c] + GS_VLOAD(c, edge);
        __global float *o = out + c * FT * FT;
        if (nl == GS_VW) {
            GS_VSTORE(v, 0, o);
        } else {
            GS_VSTORE(v, c, edge);
            for (int l = 0; l < nl; ++l)
                o[l] = edge[c * GS_VW + l];
        }
    }
}
