/* The per-pixel safeguard: an error estimate for any method's image, from the samples
 * themselves, and the blend toward the unbiased box estimate that it drives
 * (clrecon/methods/safeguard.py has the derivation and the NumPy reference).
 *
 *   safeguard_split  copy one sample field into its two halves (samples 0..ha-1, ha..S-1 of
 *                    each pixel): two independent estimates of everything
 *   safeguard_box_halves  the samples' means of each half (ma, mb: box's own halves'
 *                    images, which non-local means filters when box is the method)
 *   safeguard_stats  per pixel: the box image and, in linear radiance, mean over RGB,
 *                    d2 = |m - box|^2, vb = k |boxA - boxB|^2, vm = k |mA - mB|^2 with
 *                    k = ha hb / S^2 (the variance of the full-frame estimate from its halves);
 *                    with has_method = 2 it first writes m as the halves' mean
 *                    (with quarters = 1, also dq: the quarters' squared difference that
 *                    kernels/safeguard_ratio.cl sets against the halves' over the frame)
 *   safeguard_rows   the windowed sums' row segments (3 and 7 wide), for the blend, with
 *                    vb and vm times the frame's factor from safeguard_ratio.cl (<= 1: the
 *                    halves' overstatement of stratified samples' variances; 1 below
 *                    16 spp, where it is not measured)
 *   safeguard_blend  windowed means (3x3 and 7x7, over the pixels inside the image), the bias
 *                    estimate b2 = max(0, mean7(e), mean3(e) - 2 se3(e)), e = d2 - vm - vb,
 *                    or with the covariance of m and box modelled (vm_sign = +1, from
 *                    16 spp: clrecon/methods/safeguard.py) e = d2 + vm - vb
 *                    (se3: the standard error of the 3x3 mean), the method's
 *                    error b2 + mean3(vm), vbw = max(mean3(vb), mean7(vb)), the weight
 *                    w = vbw / (vbw + error), the image and its estimated squared error
 *                    (box's own: mean3(vb), unbiased)
 * Arguments: split: src (P, S, C) into dst_a (P, ha, C) and dst_b (P, S - ha, C), C = `width`
 * floats a sample; stats: color (H, W, S, 3), m, ma, mb (H, W, 3) the method's images of the
 * frame (or written: the halves' mean) and of its halves, box (H, W, 3) (with ref_images:
 * the reference's halves are the images ua, ub (H, W, 3) in place of the samples' means:
 * the guided refinement's blend toward its guide), stats: five planes
 * (d2, vb, vm, e, dq) of (H, sp) floats, pixel x at column x + 3, sp >= rp + 6, the columns
 * outside the image 0 and e = SG_PAD_E (dq written only with quarters = 1); rows: vscale
 * (1 float, kernels/safeguard_ratio.cl's scale or 1), vm_sign (-1 or +1: the sign of vm in
 * e) and nine planes of (H, rp) floats, rp a multiple of SG_VW >= W (rows3 = vb3, vm3, e3, ee3;
 * rows7 = e7, vb7, e3max, e7max; then ee7); blend:
 * out (H, W, 3), error (H, W); z7 > 0: the 7x7 bias mean is tested at z7 standard errors;
 * z7 < 0: it is shrunk by its significance, mu7 max(0, 1 - se7^2 / mu7^2) (independent
 * samples declared: clrecon/methods/safeguard.py);
 * test3 = 0: the bias term leaves the 3x3 mean out (the guided chain below 32 spp); fdr = 1:
 * z7 is zfdr[0] (1 float: kernels/safeguard_fdr.cl's threshold), else zfdr is not read.
 * Vector width: safeguard_rows and safeguard_blend run SG_VW consecutive pixels of a row per
 * work-item as floatN (SG_VW 1, 4, 8 or 16; the host passes 16 for CPUs, 1 otherwise). PoCL
 * 3.1 vectorises a kernel across work-items only where its body holds no vector-typed value
 * (its remarks, POCL_VECTORIZER_REMARKS=1: "instruction return type cannot be vectorized"),
 * and LLVM's SLP pass makes them from the taps' adjacent loads: the one-pixel kernels ran
 * scalar. safeguard_rows at 1280x720 on a 2-core Xeon: 10.3 ms one pixel a work-item, 0.9 ms
 * 16 (the same values, bit for bit).
 * Preconditions: 1 <= ha < S (both halves hold samples). Compile-time: SG_VW (default 16);
 * the local sizes are the runtime's.
 */
#include "common.h"
#include "safeguard_vec.h"

/* a padding column's exponent: below every float's, so it never sets a window's largest, and
 * 2^(2 (SG_PAD_E - e)) flushes to 0 */
#define SG_PAD_E (-1000.0f)

__kernel void safeguard_split(__global const float *src, __global float *dst_a,
                              __global float *dst_b, int pixels, int spp, int ha, int width)
{
    const int p = get_global_id(0);
    if (p >= pixels)
        return;
    const int hb = spp - ha;
    const __global float *s = src + (size_t)p * spp * width;
    __global float *a = dst_a + (size_t)p * ha * width;
    __global float *b = dst_b + (size_t)p * hb * width;
    for (int i = 0; i < ha * width; ++i)
        a[i] = s[i];
    for (int i = 0; i < hb * width; ++i)
        b[i] = s[ha * width + i];
}

/* ma, mb (P, 3): the means of samples 0..ha-1 and ha..S-1 of each pixel of color (P, S, 3) */
__kernel void safeguard_box_halves(__global const float *color, __global float *ma,
                                   __global float *mb, int pixels, int spp, int ha)
{
    const int p = get_global_id(0);
    if (p >= pixels)
        return;
    const __global float *c = color + (size_t)p * spp * 3;
    float3 sa = (float3)(0.0f), sb = (float3)(0.0f);
    for (int i = 0; i < ha; ++i)
        sa += vload3(i, c);
    for (int i = ha; i < spp; ++i)
        sb += vload3(i, c);
    vstore3(sa / (float)ha, p, ma);
    vstore3(sb / (float)(spp - ha), p, mb);
}

inline float lum2(float3 d) { return (d.x * d.x + d.y * d.y + d.z * d.z) * (1.0f / 3.0f); }

inline float3 load3(__global const float *a, int i) { return vload3(i, a); }

/* has_method = 0: only the box statistics (m, ma, mb are not read); 1: m is the method's
 * image of the frame; 2: m is written, the halves' mean (ha mA + hb mB) / S.
 *
 * Range: colours up to 1e30 are valid, and their squares overflow float32. Each pixel's
 * statistics are therefore stored in units of 2^(2 e), e the binary exponent of the largest
 * value the pixel's statistics involve (stats.w = e); the blend rescales a window to its
 * largest e before adding (a pixel 2^-63 times dimmer than its window's brightest adds
 * nothing measurable to it). */
__kernel void safeguard_stats(__global const float *color, __global float *m,
                              __global const float *ma, __global const float *mb,
                              __global float *box, __global float *stats,
                              int width, int height, int spp, int ha, int has_method, int sp,
                              __global const float *ua, __global const float *ub,
                              int ref_images, int quarters)
{
    /* one work-item per column of the planes: the padding's too */
    const int col = get_global_id(0), y = get_global_id(1), x = col - 3;
    if (col >= sp || y >= height)
        return;
    const size_t plane = (size_t)sp * height, q = (size_t)y * sp + col;
    if (x < 0 || x >= width) {
        stats[q] = 0.0f;
        stats[q + plane] = 0.0f;
        stats[q + 2 * plane] = 0.0f;
        stats[q + 3 * plane] = SG_PAD_E;
        if (quarters)
            stats[q + 4 * plane] = 0.0f;
        return;
    }
    const int p = pixel_index(x, y, width);
    const int hb = spp - ha;
    float3 sa = (float3)(0.0f), sb = (float3)(0.0f);
    /* with quarters: the first quarter of each half (its first half of samples) apart */
    float3 q0 = (float3)(0.0f), q2 = (float3)(0.0f);
    const int n0 = ha / 2, n2 = hb / 2;
    if (ref_images) {  /* the reference's halves are images (ua, ub), not the samples' means */
        sa = (float)ha * load3(ua, p);
        sb = (float)hb * load3(ub, p);
    } else {
        const __global float *c = color + (size_t)p * spp * 3;
        if (quarters) {  /* one read of the colours, the quarters' sums on the way */
            for (int i = 0; i < n0; ++i)
                q0 += vload3(i, c);
            for (int i = n0; i < ha; ++i)
                sa += vload3(i, c);
            for (int i = ha; i < ha + n2; ++i)
                q2 += vload3(i, c);
            for (int i = ha + n2; i < spp; ++i)
                sb += vload3(i, c);
            sa += q0;
            sb += q2;
        } else {
            for (int i = 0; i < ha; ++i)
                sa += vload3(i, c);
            for (int i = ha; i < spp; ++i)
                sb += vload3(i, c);
        }
    }
    const float3 full = (sa + sb) / (float)spp;
    const float3 a = sa / (float)ha, b = sb / (float)hb;
    float3 vm_ = full, vma = full, vmb = full;
    if (has_method) {
        vma = load3(ma, p);
        vmb = load3(mb, p);
        if (has_method == 2) {  /* the method's image: the mean of its halves' */
            vm_ = ((float)ha * vma + (float)(spp - ha) * vmb) / (float)spp;
            vstore3(vm_, p, m);
        } else {
            vm_ = load3(m, p);
        }
    }
    const float3 big = fmax(fmax(fmax(fabs(a), fabs(b)), fmax(fabs(vm_), fabs(vma))),
                            fabs(vmb));
    int e;
    (void)frexp(fmax(fmax(big.x, big.y), big.z), &e);
    const float sc = ldexp(1.0f, -e);
    const float k = ((float)ha * (float)hb) / ((float)spp * (float)spp);
    const float vb = k * lum2((a - b) * sc);
    float d2 = 0.0f, vm = 0.0f;
    if (has_method) {
        d2 = lum2((vm_ - full) * sc);
        vm = k * lum2((vma - vmb) * sc);
    }
    vstore3(full, p, box);
    stats[q] = d2;
    stats[q + plane] = vb;
    stats[q + 2 * plane] = vm;
    stats[q + 3 * plane] = (float)e;
    if (quarters) {  /* each half's two quarters (the first half of its samples and the
                      * rest): dq, their squared difference per unit of 1/n0 + 1/n1, the
                      * mean over the two halves (safeguard_ratio_rows compares it with
                      * the halves' own, S vb) */
        const int n1 = ha - n0, n3 = hb - n2;
        const float3 da = q0 / (float)n0 - (sa - q0) / (float)n1;
        const float3 db = q2 / (float)n2 - (sb - q2) / (float)n3;
        const float ka = ((float)n0 * (float)n1) / (float)ha;
        const float kb = ((float)n2 * (float)n3) / (float)hb;
        stats[q + 4 * plane] = 0.5f * (ka * lum2(da * sc) + kb * lum2(db * sc));
    }
}

/* The windowed means, separably: safeguard_rows sums each pixel's row segments (3 and 7
 * wide; the padding columns add 0) in units of the segment's largest exponent;
 * safeguard_blend sums 3 and 7 of those segments down the column, each rescaled to the 7x7
 * window's largest exponent (exact powers of two, so the result is the 2D sums' up to the
 * order of the additions). SG_VW pixels x0 .. x0 + SG_VW - 1 a work-item (x0 a multiple of
 * SG_VW; lanes past the image's width compute from the padding and are not stored). */
__kernel void safeguard_rows(__global const float *stats, __global float *rows, int width,
                             int height, int sp, int rp, __global const float *vscale,
                             const float vm_sign)
{
    /* the factor of the halves' variances (safeguard_ratio; 1: independent samples) */
    const float s = vscale[0];
    const int x0 = get_global_id(0) * SG_VW, y = get_global_id(1);
    if (x0 >= width || y >= height)
        return;
    const size_t plane = (size_t)sp * height;
    /* column x0 + 3 + k is pixel x0 + k */
    const __global float *d2 = stats + (size_t)y * sp + x0 + 3;
    const __global float *vbp = d2 + plane, *vmp = d2 + 2 * plane, *ep = d2 + 3 * plane;
    vint e3max = (vint)(INT_MIN), e7max = (vint)(INT_MIN);
    #pragma unroll
    for (int k = -3; k <= 3; ++k) {
        const vint ex = CONVERT_INT(VLOAD(ep + k));
        e7max = max(e7max, ex);
        if (k >= -1 && k <= 1)
            e3max = max(e3max, ex);
    }
    vfloat vb3 = 0.0f, vm3 = 0.0f, e3 = 0.0f, ee3 = 0.0f, e7 = 0.0f, vb7 = 0.0f, ee7 = 0.0f;
    #pragma unroll
    for (int k = -3; k <= 3; ++k) {
        const vint ex = CONVERT_INT(VLOAD(ep + k));
        const vfloat sd = VLOAD(d2 + k), svb = s * VLOAD(vbp + k), svm = s * VLOAD(vmp + k);
        /* to the segment's units */
        const vfloat f7 = pow2_nonpos(2 * (ex - e7max));
        const vfloat e = sd + vm_sign * svm - svb;  /* -1: d2 - vm - vb, bit for bit */
        e7 += f7 * e;
        vb7 += f7 * svb;
        ee7 += (f7 * e) * (f7 * e);
        if (k >= -1 && k <= 1) {
            const vfloat f3 = pow2_nonpos(2 * (ex - e3max));
            vb3 += f3 * svb;
            vm3 += f3 * svm;
            e3 += f3 * e;
            ee3 += (f3 * e) * (f3 * e);
        }
    }
    const size_t rplane = (size_t)rp * height;
    __global float *o = rows + (size_t)y * rp + x0;
    VSTORE(vb3, o);
    VSTORE(vm3, o + rplane);
    VSTORE(e3, o + 2 * rplane);
    VSTORE(ee3, o + 3 * rplane);
    VSTORE(e7, o + 4 * rplane);
    VSTORE(vb7, o + 5 * rplane);
    VSTORE(CONVERT_FLOAT(e3max), o + 6 * rplane);
    VSTORE(CONVERT_FLOAT(e7max), o + 7 * rplane);
    VSTORE(ee7, o + 8 * rplane);
}

/* mode 0: box (image = box, error = mean3(vb)); 1: the method alone (image = m, error = its
 * estimate); 2: the blend. error may be written or not (write_error). */
__kernel void safeguard_blend(__global const float *rows, __global const float *box,
                              __global const float *m, __global float *out,
                              __global float *error, int width, int height, int rp, int mode,
                              int write_error, float z7, int test3, int fdr,
                              __global const float *zfdr)
{
    /* fdr = 1: the 7x7 test's z is the frame's (kernels/safeguard_fdr.cl); fdr = 2: zfdr is
     * the frame's table of factors by |z|'s bin (safeguard_fdr_shrink), z7 unused */
    if (fdr == 1)
        z7 = zfdr[0];
    const int x0 = get_global_id(0) * SG_VW, y = get_global_id(1);
    if (x0 >= width || y >= height)
        return;
    const size_t rplane = (size_t)rp * height;
    const __global float *col = rows + x0;
    vint emax = (vint)(INT_MIN);
    #pragma unroll
    for (int k = -3; k <= 3; ++k) {
        const int yy = y + k;
        if (yy >= 0 && yy < height)
            emax = max(emax, CONVERT_INT(VLOAD(col + 7 * rplane + (size_t)yy * rp)));
    }
    vfloat vb3 = 0.0f, vb7 = 0.0f, vm3 = 0.0f, e3 = 0.0f, ee3 = 0.0f, e7 = 0.0f, ee7 = 0.0f;
    #pragma unroll
    for (int k = -3; k <= 3; ++k) {
        const int yy = y + k;
        if (yy < 0 || yy >= height)
            continue;
        const __global float *r = col + (size_t)yy * rp;
        const vfloat f7 = pow2_nonpos(2 * (CONVERT_INT(VLOAD(r + 7 * rplane)) - emax));
        e7 += f7 * VLOAD(r + 4 * rplane);
        vb7 += f7 * VLOAD(r + 5 * rplane);
        if (z7 != 0.0f || fdr == 2)
            ee7 += (f7 * f7) * VLOAD(r + 8 * rplane);
        if (k >= -1 && k <= 1) {
            const vfloat f3 = pow2_nonpos(2 * (CONVERT_INT(VLOAD(r + 6 * rplane)) - emax));
            vb3 += f3 * VLOAD(r);
            vm3 += f3 * VLOAD(r + rplane);
            e3 += f3 * VLOAD(r + 2 * rplane);
            ee3 += (f3 * f3) * VLOAD(r + 3 * rplane);
        }
    }
    /* the windows' pixel counts inside the image */
    const vint x = x0 + SG_LANES;
    /* the scalar operands broadcast explicitly: Oclgrind's min (gentype, sgentype) reads
     * the scalar wrongly */
    const vint last = (vint)(width - 1), zero = (vint)(0);
    const vint c3 = min(x + 1, last) - max(x - 1, zero) + 1;
    const vint c7 = min(x + 3, last) - max(x - 3, zero) + 1;
    const int r3 = min(y + 1, height - 1) - max(y - 1, 0) + 1;
    const int r7 = min(y + 3, height - 1) - max(y - 3, 0) + 1;
    const vfloat n3 = CONVERT_FLOAT(c3 * r3), n7 = CONVERT_FLOAT(c7 * r7);
    /* box's variance over 3x3, or 7x7 where larger: a pixel whose own samples all missed
     * a rare contributor (a blurred highlight) has halves that agree and a variance near
     * 0, while its neighbours' samples show the spread */
    vb3 /= n3;
    const vfloat vbw = fmax(vb3, vb7 / n7);
    vm3 /= n3;
    /* the 7x7 mean, or the 3x3 one where it stands two standard errors above zero (a
     * bias along a thin edge, which the wider window dilutes; noise alone rarely gets
     * there) */
    const vfloat mu3 = e3 / n3;
    const vfloat se3 = sqrt(fmax(ee3 / n3 - mu3 * mu3, 0.0f) / n3);
    /* with z7 > 0 the 7x7 mean too must stand z7 standard errors above zero (the guided
     * refinement's chain: its regression removes the bias coherent over its windows) */
    vfloat mu7 = e7 / n7;
    if (fdr == 2) {
        /* a positive mean scaled by its significance's bin's factor: 1 minus the share of
         * the frame's means at least as significant that are noise */
        float zl[SG_VW], fl[SG_VW];
        VSTORE(abs_z(mu7, window_se2(mu7, ee7, n7)), zl);
        for (int i = 0; i < SG_VW; ++i)
            fl[i] = zfdr[fdr_bin(zl[i])];
        mu7 = select((vfloat)(0.0f), mu7 * VLOAD(fl), mu7 > 0.0f);
    } else if (z7 != 0.0f) {
        const vfloat var7 = window_se2(mu7, ee7, n7);  /* se7^2 */
        /* z7 < 0: shrunk by its significance (a positive-part James-Stein shrinkage: the
         * positive noise of a mean near 0 no longer pulls the image toward box) */
        mu7 = z7 > 0.0f ? mu7 - z7 * sqrt(var7)
                        : select((vfloat)(0.0f), mu7 - var7 / mu7, mu7 > 0.0f);
    }
    const vfloat b2 = fmax(0.0f, test3 ? fmax(mu7, mu3 - 2.0f * se3) : mu7);
    const vfloat err_m = b2 + vm3;
    vfloat w = 0.0f, err = vb3;
    if (mode == 1) {
        err = err_m;
    } else if (mode == 2) {
        const vfloat den = vbw + err_m;
        w = select((vfloat)(0.0f), vbw / den, den > 0.0f);
        err = w * w * err_m + (1.0f - w) * (1.0f - w) * vbw;
    }
    /* back to radiance^2; beyond float32 (colours above ~1e19): FLT_MAX */
    const vfloat errs = fmin(ldexp(err, 2 * emax), FLT_MAX);
    float wl[SG_VW], el[SG_VW];
    VSTORE(w, wl);
    VSTORE(errs, el);
    const int n = min(SG_VW, width - x0);
    for (int i = 0; i < n; ++i) {
        const int p = pixel_index(x0 + i, y, width);
        const float3 bx = load3(box, p);
        float3 img = bx;
        if (mode == 1)
            img = load3(m, p);
        else if (mode == 2)
            img = bx + wl[i] * (load3(m, p) - bx);
        vstore3(img, p, out);
        if (write_error)
            error[p] = el[i];
    }
}
