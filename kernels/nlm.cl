/* nlm.cl: dual-buffer non-local means on the safeguard's two halves' images (Rousselle, Knaus
 * and Zwicker 2012); clrecon/methods/nlm.py has the derivation and the NumPy reference.
 *
 *   nlm_planes  per padded pixel: the halves' images A and B and v, the 3x3 (clipped) mean of
 *               their squared difference (mean over RGB), as planes with the image's edge
 *               replicated NLM_PAD pixels (and a lane group) around it: every load of the
 *               filter is then in bounds, and a clamped coordinate is a plain offset
 *   nlm_filter  per pixel p and half h: the half's image u = A or B averaged over the
 *               (2 NR + 1)^2 pixels q around p with the weights that the *other* half g
 *               gives: w = exp(-max(0, D2)), D2 the mean over the 3x3 patch (clipped to the
 *               image) of t(s, s + q - p),
 *                 t(s, s') = (|g_s - g_s'|^2 - (v_s + min(v_s, v_s'))) / (k^2 (v_s + v_s'))
 *               (mean over RGB; v the guide half's variance, fg times the plane v); where
 *               v_s + v_s' = 0, t is 0 for equal colours and +inf for others; a NaN
 *               distance weighs 0 and p itself weighs 1. Coordinates off the image clamp.
 * Arguments: planes: ua, ub (H, W, 3), planes (NLM_PLANES planes of `ps` floats: A's RGB,
 * B's RGB, v; padded rows of `pw` floats), W, H; filter: planes, na, nb (H, W, 3), W, H, pw,
 * ps, fa, fb (var(A) = fa v, var(B) = fb v), k2 = k^2.
 * Launch: planes (pw, ph); filter (ceil(W / 8), ceil(H / NLM_ROWS), 2) (dim 2: the half),
 * 1 x 1 x 1 groups. A work-item takes 8 columns as the lanes of a float8 and walks NLM_ROWS
 * rows down; per offset it keeps the patch-row sums of its last two rows (h0, h1), so each
 * term is computed once per row, twice per lane (the left and right neighbours' sets, the
 * lanes' own shuffled from them). Measured at 512x512, R = 5, both halves on PoCL (2
 * cores): 310 ms with every term three times, 240-250 with two, 180 with the rows carried;
 * work-items that kept 8 output rows' accumulators instead spilled them and were slower.
 * Compile-time: NR (search radius, 1..10), NLM_ROWS (rows a work-item).
 */
#ifndef NR
#define NR 5
#endif
/* pad around the image: the search radius and the patch's pixel */
#define NLM_PAD (NR + 1)
#define NLM_PLANES 7
#define NLM_OFFSETS ((2 * NR + 1) * (2 * NR + 1))
#ifndef NLM_ROWS
#define NLM_ROWS 64
#endif

__kernel void nlm_planes(__global const float *restrict ua, __global const float *restrict ub,
                         __global float *restrict planes, const int W, const int H,
                         const int pw, const int ph, const int ps)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= pw || py >= ph)
        return;
    const int x = clamp(px - NLM_PAD, 0, W - 1), y = clamp(py - NLM_PAD, 0, H - 1);
    const size_t i = (size_t)y * W + x;
    const float3 a = vload3(i, ua), b = vload3(i, ub);
    float v = 0.0f;
    int n = 0;
    for (int dy = max(y - 1, 0); dy <= min(y + 1, H - 1); ++dy)
        for (int dx = max(x - 1, 0); dx <= min(x + 1, W - 1); ++dx) {
            const size_t j = (size_t)dy * W + dx;
            const float3 d = vload3(j, ua) - vload3(j, ub);
            v += (d.x * d.x + d.y * d.y + d.z * d.z) * (1.0f / 3.0f);
            ++n;
        }
    const size_t o = (size_t)py * pw + px;
    planes[o] = a.x;
    planes[o + ps] = a.y;
    planes[o + 2 * (size_t)ps] = a.z;
    planes[o + 3 * (size_t)ps] = b.x;
    planes[o + 4 * (size_t)ps] = b.y;
    planes[o + 5 * (size_t)ps] = b.z;
    planes[o + 6 * (size_t)ps] = v / (float)n;
}

/* t of the lanes' pixels s (plane offset os) against s' = s + (ox, oy) (offset oq) */
inline float8 nlm_term(__global const float *g0, __global const float *g1,
                       __global const float *g2, __global const float *v, const size_t os,
                       const size_t oq, const float fg, const float k2)
{
    const float8 d0 = vload8(0, g0 + os) - vload8(0, g0 + oq);
    const float8 d1 = vload8(0, g1 + os) - vload8(0, g1 + oq);
    const float8 d2 = vload8(0, g2 + os) - vload8(0, g2 + oq);
    const float8 dd = (d0 * d0 + d1 * d1 + d2 * d2) * (1.0f / 3.0f);
    const float8 vs = fg * vload8(0, v + os), vq = fg * vload8(0, v + oq);
    const float8 den = k2 * (vs + vq);
    const float8 t = (dd - (vs + fmin(vs, vq))) / den;
    return select(t, select((float8)(0.0f), (float8)(INFINITY), dd > 0.0f), den == 0.0f);
}

/* exp(-x) for x >= 0 (a NaN gives a finite value: the caller weighs it 0): 2^n times a
 * degree-6 Taylor polynomial of e^z on |z| <= ln(2) / 2, relative error ~2e-7; 0 beyond
 * x = 87 (where exp(-x) leaves float32's normal range). PoCL 3.1's own exp of a float8 took
 * 60% of the filter's time (fence 512x512, R = 5: 196 -> 124 ms with this one). */
inline float8 nlm_exp_neg(const float8 x)
{
    const float8 y = -fmin(x, 87.0f) * 1.44269504f; /* log2(e) */
    /* y rounded to an integer by adding 1.5 * 2^23 (round to nearest): n, and its bits */
    const float8 t = y + 12582912.0f;
    const float8 n = t - 12582912.0f;
    const float8 z = (y - n) * 0.693147181f;
    float8 p = 1.0f / 720.0f;
    p = fma(p, z, 1.0f / 120.0f);
    p = fma(p, z, 1.0f / 24.0f);
    p = fma(p, z, 1.0f / 6.0f);
    p = fma(p, z, 0.5f);
    p = fma(p, z, 1.0f);
    p = fma(p, z, 1.0f);
    const float8 e = p * as_float8((as_int8(t) - 0x4B400000 + 127) << 23);
    return select(e, (float8)(0.0f), x > 87.0f);
}

__kernel void nlm_filter(__global const float *restrict planes, __global float *restrict na,
                         __global float *restrict nb, const int W, const int H, const int pw,
                         const int ps, const float fa, const float fb, const float k2)
{
    const int x0 = 8 * get_global_id(0), ya = NLM_ROWS * get_global_id(1);
    const int h = get_global_id(2);
    if (x0 >= W || ya >= H)
        return;
    const int yb = min(ya + NLM_ROWS, H);
    /* u: the half filtered; g, v: the other half's image and variance */
    __global const float *u = planes + (size_t)(h ? 3 : 0) * ps;
    __global const float *g = planes + (size_t)(h ? 0 : 3) * ps;
    __global const float *v = planes + (size_t)6 * ps;
    const float fg = h ? fa : fb;
    const int8 xs = x0 + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    /* the patch's columns x - 1 and x + 1 where they lie in the image (a vector compare is
     * -1 where true), and its width */
    const int8 ml = xs - 1 >= 0, mr = xs + 1 < W;
    const float8 ncol = 1.0f - convert_float8(ml) - convert_float8(mr);
    /* per offset, the patch-row sums of the two rows above the one computed */
    float8 h0[NLM_OFFSETS], h1[NLM_OFFSETS];
    for (int r = ya - 1; r <= yb; ++r) {
        const int row_in = r >= 0 && r < H;
        const int yo = r - 1;  /* the output row whose patch this row completes */
        const int out_row = yo >= ya;
        float inv_nrow = 0.0f;
        if (out_row)
            inv_nrow = 1.0f / (float)(1 + (yo - 1 >= 0) + (yo + 1 < H));
        const float8 inv_n = inv_nrow / ncol;
        const size_t os = (size_t)(r + NLM_PAD) * pw + (size_t)(x0 + NLM_PAD);
        const size_t oo = os - pw;  /* the output row's */
        float8 ar = (float8)(0.0f), ag = ar, ab = ar, ws = ar;
        int k = 0;
        for (int oy = -NR; oy <= NR; ++oy) {
            for (int ox = -NR; ox <= NR; ++ox, ++k) {
                const long dq = (long)oy * pw + ox;
                float8 hr = (float8)(0.0f);
                if (row_in) {
                    /* the lanes' left and right neighbours' terms, and the lanes' own from
                     * them (lanes 0-6: the left ones' lanes 1-7; lane 7: the right ones'
                     * lane 6): two terms a lane, not three */
                    const float8 tl = nlm_term(g, g + ps, g + 2 * (size_t)ps, v, os - 1,
                                               os - 1 + dq, fg, k2);
                    const float8 tr = nlm_term(g, g + ps, g + 2 * (size_t)ps, v, os + 1,
                                               os + 1 + dq, fg, k2);
                    const float8 tc = (float8)(tl.s1234, tl.s567, tr.s6);
                    /* a patch column off the image adds nothing (0 x inf would be NaN) */
                    hr = tc + select((float8)(0.0f), tl, ml) + select((float8)(0.0f), tr, mr);
                }
                if (out_row) {
                    const float8 d2 = (h0[k] + h1[k] + hr) * inv_n;
                    float8 w = select(nlm_exp_neg(fmax(d2, 0.0f)), (float8)(0.0f), isnan(d2));
                    if (ox == 0 && oy == 0)
                        w = (float8)(1.0f);
                    ar += w * vload8(0, u + oo + dq);
                    ag += w * vload8(0, u + ps + oo + dq);
                    ab += w * vload8(0, u + 2 * (size_t)ps + oo + dq);
                    ws += w;
                }
                h0[k] = h1[k];
                h1[k] = hr;
            }
        }
        if (out_row && yo < H) {
            __global float *out = h ? nb : na;
            float r8[8], g8[8], b8[8], w8[8];
            vstore8(ar, 0, r8);
            vstore8(ag, 0, g8);
            vstore8(ab, 0, b8);
            vstore8(ws, 0, w8);
            for (int j = 0; j < 8 && x0 + j < W; ++j)
                vstore3((float3)(r8[j], g8[j], b8[j]) / w8[j], (size_t)yo * W + x0 + j, out);
        }
    }
}

/* More scales (nlm_scales > 1; clrecon/methods/nlm.py: multiscale): each half's low band
 * replaced by the filter of its 2x2 means at half the resolution, recursively.
 *   nlm_down   per coarse pixel and half: the 2x2 mean of the fine image (W, H fine; the
 *              coarse image is (W / 2, H / 2), an odd last row or column left out)
 *   nlm_merge  per fine pixel and half, in place: n += up(m - d), d the coarse 2x2 means of
 *              n (nlm_down's), m their filtered (and merged) image; up: nearest, the rows
 *              and columns past the last 2x2 block replicated, then a [1/4, 1/2, 1/4] tent
 *              along each axis with the edge replicated.
 * Launch: down (W / 2, H / 2, 2), merge (W, H, 2); dim 2: the half. */
__kernel void nlm_down(__global const float *restrict ua, __global const float *restrict ub,
                       __global float *restrict da, __global float *restrict db, const int W,
                       const int H)
{
    const int x = get_global_id(0), y = get_global_id(1), h = get_global_id(2);
    const int w2 = W / 2, h2 = H / 2;
    if (x >= w2 || y >= h2)
        return;
    __global const float *u = h ? ub : ua;
    const size_t i = (size_t)(2 * y) * W + 2 * x;
    const float3 s = (vload3(i, u) + vload3(i + 1, u)) + (vload3(i + W, u) + vload3(i + W + 1, u));
    vstore3(0.25f * s, (size_t)y * w2 + x, h ? db : da);
}

__kernel void nlm_merge(__global float *na, __global float *nb, __global const float *da,
                        __global const float *db, __global const float *ma,
                        __global const float *mb, const int W, const int H)
{
    const int x = get_global_id(0), y = get_global_id(1), h = get_global_id(2);
    if (x >= W || y >= H)
        return;
    const int w2 = W / 2, h2 = H / 2;
    __global const float *d = h ? db : da;
    __global const float *m = h ? mb : ma;
    const float t[3] = {0.25f, 0.5f, 0.25f};
    float3 acc = (float3)(0.0f);
    for (int a = -1; a <= 1; ++a) {
        const int i = min(clamp(y + a, 0, H - 1), 2 * h2 - 1) / 2;
        float3 row = (float3)(0.0f);
        for (int b = -1; b <= 1; ++b) {
            const size_t j = (size_t)i * w2 + min(clamp(x + b, 0, W - 1), 2 * w2 - 1) / 2;
            row += t[b + 1] * (vload3(j, m) - vload3(j, d));
        }
        acc += t[a + 1] * row;
    }
    __global float *n = h ? nb : na;
    const size_t p = (size_t)y * W + x;
    vstore3(vload3(p, n) + acc, p, n);
}
