/* The per-pixel safeguard: an error estimate for any method's image, from the samples
 * themselves, and the blend toward the unbiased box estimate that it drives
 * (clrecon/methods/safeguard.py has the derivation and the NumPy reference).
 *
 *   safeguard_split  copy one sample field into its two halves (samples 0..ha-1, ha..S-1 of
 *                    each pixel): two independent estimates of everything
 *   safeguard_stats  per pixel: the box image and, in linear radiance, mean over RGB,
 *                    d2 = |m - box|^2, vb = k |boxA - boxB|^2, vm = k |mA - mB|^2 with
 *                    k = ha hb / S^2 (the variance of the full-frame estimate from its halves);
 *                    with has_method = 2 it first writes m as the halves' mean
 *   safeguard_rows   the windowed sums' row segments (3 and 7 wide), for the blend
 *   safeguard_blend  windowed means (3x3 and 7x7, over the pixels inside the image), the bias
 *                    estimate b2 = max(0, mean7(e), mean3(e) - 2 se3(e)), e = d2 - vm - vb
 *                    (se3: the standard error of the 3x3 mean), the method's
 *                    error b2 + mean3(vm), vbw = max(mean3(vb), mean7(vb)), the weight
 *                    w = vbw / (vbw + error), the image and its estimated squared error
 *                    (box's own: mean3(vb), unbiased)
 * Arguments: split: src (P, S, C) into dst_a (P, ha, C) and dst_b (P, S - ha, C), C = `width`
 * floats a sample; stats: color (H, W, S, 3), m, ma, mb (H, W, 3) the method's images of the
 * frame (or written: the halves' mean) and of its halves, box (H, W, 3), stats float4
 * (H, W); rows: rows3, rows7 float4 (H, W); blend: out (H, W, 3), error (H, W).
 * Preconditions: 1 <= ha < S (both halves hold samples). No compile-time options; the local
 * sizes are launch parameters only.
 */
#include "common.h"

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
                              __global float *box, __global float4 *stats,
                              int width, int height, int spp, int ha, int has_method)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const int p = pixel_index(x, y, width);
    const __global float *c = color + (size_t)p * spp * 3;
    float3 sa = (float3)(0.0f), sb = (float3)(0.0f);
    for (int i = 0; i < ha; ++i)
        sa += vload3(i, c);
    for (int i = ha; i < spp; ++i)
        sb += vload3(i, c);
    const int hb = spp - ha;
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
    stats[p] = (float4)(d2, vb, vm, (float)e);
}

/* 2^n for n <= 0, flushed to 0 below float32's normal range (n < -126): a pixel that much
 * dimmer than its window's brightest adds nothing measurable. Built from the bits, not
 * ldexp: a select the vectoriser keeps in lanes, where ldexp is a library call. */
__attribute__((always_inline)) inline float pow2_nonpos(int n)
{
    return n < -126 ? 0.0f : as_float((n + 127) << 23);
}

/* The windowed means, separably: safeguard_rows sums each pixel's row segments (3 and 7
 * wide, clipped to the image) in units of the segment's largest exponent; safeguard_blend
 * sums 3 and 7 of those segments down the column, each rescaled to the 7x7 window's
 * largest exponent (exact powers of two, so the result is the 2D sums' up to the order of
 * the additions). Unrolled fixed trip counts with clamped loads and masks (PoCL, 1280x720:
 * the single 7x7 kernel took 190 ms, the two take about 50). rows3 = (vb, vm, e, e^2) over
 * 3, rows7 = (e, vb, exponent of the 3-wide segment, of the 7-wide one) over 7, with
 * e = d2 - vm - vb. */
__kernel void safeguard_rows(__global const float4 *stats, __global float4 *rows3,
                             __global float4 *rows7, int width, int height)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x < width && y < height) {
        const int row = y * width;
        int e3max = INT_MIN, e7max = INT_MIN;
        #pragma unroll
        for (int k = -3; k <= 3; ++k) {
            const int xx = x + k;
            const int ex = (int)stats[row + clamp(xx, 0, width - 1)].w;
            const bool in = xx >= 0 && xx < width;
            e7max = in ? max(e7max, ex) : e7max;
            e3max = (in && k >= -1 && k <= 1) ? max(e3max, ex) : e3max;
        }
        float vb3 = 0.0f, vm3 = 0.0f, e3 = 0.0f, ee3 = 0.0f, e7 = 0.0f, vb7 = 0.0f;
        #pragma unroll
        for (int k = -3; k <= 3; ++k) {
            const int xx = x + k;
            const float4 s = stats[row + clamp(xx, 0, width - 1)];
            const bool in = xx >= 0 && xx < width;
            const bool in3 = in && k >= -1 && k <= 1;
            /* to the segment's units */
            const float f7 = in ? pow2_nonpos(2 * ((int)s.w - e7max)) : 0.0f;
            const float f3 = in3 ? pow2_nonpos(2 * ((int)s.w - e3max)) : 0.0f;
            const float e = s.x - s.z - s.y;
            e7 += f7 * e;
            vb7 += f7 * s.y;
            vb3 += f3 * s.y;
            vm3 += f3 * s.z;
            e3 += f3 * e;
            ee3 += (f3 * e) * (f3 * e);
        }
        const int p = row + x;
        rows3[p] = (float4)(vb3, vm3, e3, ee3);
        rows7[p] = (float4)(e7, vb7, (float)e3max, (float)e7max);
    }
}

/* mode 0: box (image = box, error = mean3(vb)); 1: the method alone (image = m, error = its
 * estimate); 2: the blend. error may be written or not (write_error). */
__kernel void safeguard_blend(__global const float4 *rows3, __global const float4 *rows7,
                              __global const float *box, __global const float *m,
                              __global float *out, __global float *error, int width,
                              int height, int mode, int write_error)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x < width && y < height) {
        int emax = INT_MIN;
        #pragma unroll
        for (int k = -3; k <= 3; ++k) {
            const int yy = y + k;
            const int ex = (int)rows7[clamp(yy, 0, height - 1) * width + x].w;
            emax = (yy >= 0 && yy < height) ? max(emax, ex) : emax;
        }
        float vb3 = 0.0f, vb7 = 0.0f, vm3 = 0.0f, e3 = 0.0f, ee3 = 0.0f, e7 = 0.0f;
        #pragma unroll
        for (int k = -3; k <= 3; ++k) {
            const int yy = y + k;
            const int q = clamp(yy, 0, height - 1) * width + x;
            const float4 r7 = rows7[q];
            const bool in = yy >= 0 && yy < height;
            const bool in3 = in && k >= -1 && k <= 1;
            const float f7 = in ? pow2_nonpos(2 * ((int)r7.w - emax)) : 0.0f;
            e7 += f7 * r7.x;
            vb7 += f7 * r7.y;
            if (in3) {
                const float4 r3 = rows3[q];
                const float f3 = pow2_nonpos(2 * ((int)r7.z - emax));
                vb3 += f3 * r3.x;
                vm3 += f3 * r3.y;
                e3 += f3 * r3.z;
                ee3 += (f3 * f3) * r3.w;
            }
        }
        /* the windows' pixel counts inside the image */
        const int c3 = min(x + 1, width - 1) - max(x - 1, 0) + 1;
        const int c7 = min(x + 3, width - 1) - max(x - 3, 0) + 1;
        const int r3 = min(y + 1, height - 1) - max(y - 1, 0) + 1;
        const int r7 = min(y + 3, height - 1) - max(y - 3, 0) + 1;
        const float n3 = (float)(c3 * r3), n7 = (float)(c7 * r7);
        /* box's variance over 3x3, or 7x7 where larger: a pixel whose own samples all missed
         * a rare contributor (a blurred highlight) has halves that agree and a variance near
         * 0, while its neighbours' samples show the spread */
        vb3 /= n3;
        const float vbw = fmax(vb3, vb7 / n7);
        vm3 /= n3;
        /* the 7x7 mean, or the 3x3 one where it stands two standard errors above zero (a
         * bias along a thin edge, which the wider window dilutes; noise alone rarely gets
         * there) */
        const float mu3 = e3 / n3;
        const float se3 = sqrt(fmax(ee3 / n3 - mu3 * mu3, 0.0f) / n3);
        const float b2 = fmax(0.0f, fmax(e7 / n7, mu3 - 2.0f * se3));
        const float err_m = b2 + vm3;
        const int p = pixel_index(x, y, width);
        const float3 bx = load3(box, p);
        float3 img;
        float err;
        if (mode == 0) {
            img = bx;
            err = vb3;
        } else if (mode == 1) {
            img = load3(m, p);
            err = err_m;
        } else {
            const float den = vbw + err_m;
            const float w = den > 0.0f ? vbw / den : 0.0f;
            img = bx + w * (load3(m, p) - bx);
            err = w * w * err_m + (1.0f - w) * (1.0f - w) * vbw;
        }
        vstore3(img, p, out);
        if (write_error) /* back to radiance^2; beyond float32 (colours above ~1e19): FLT_MAX */
            error[p] = fmin(ldexp(err, 2 * emax), FLT_MAX);
    }
}
