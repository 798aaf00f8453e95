/* splat_composite.cl: back-to-front composition of splat's global depth layers with coverage
 * re-weighting (Lee et al. 2008), one work-item per output pixel.
 *
 * splat_composite: for layer l = 0 (farthest) .. NLAYERS - 1, at padded pixel
 * (x + pad, y + pad):
 *   v   = (USE_LAP ? ring[l] - b[l] : 0) + direct[l]     (float4: RGB, coverage)
 *   rgb = max(v.rgb, 0), cov = max(v.w, 0); layers with cov <= COV_EPS are skipped
 *   colour = rgb / cov (the layer's coverage-normalised colour)
 *   a = 1 for the first (farthest) layer with cov >= FILL_COV, else min(cov, 1)
 *   out = a * colour + (1 - a) * out,  alpha = a + (1 - a) * alpha
 * and writes out / alpha (alpha is 1 once a layer filled the pixel).
 * The farthest well-covered layer fills the pixel whole: where a nearer surface hid it in
 * the input its coverage has a hole, and normalising fills the hole with its own colour
 * (blending it with nothing would let the front layer's colour fill it). Its threshold
 * FILL_COV keeps faint layers (the integration's low-level error, ~1e-2) from filling. A
 * flat field stays flat to the image borders.
 *   b, direct: float4 (NLAYERS, ph, pw); ring: float4 (NLAYERS); out: float (H, W, 3).
 * Compile-time: NLAYERS, USE_LAP (0 when everything was drawn densely), FILL_COV.
 * The 2D local size is a launch parameter only (tuned).
 */
#ifndef NLAYERS
#define NLAYERS 1
#endif
#ifndef USE_LAP
#define USE_LAP 1
#endif
#ifndef FILL_COV
#define FILL_COV 0.1f
#endif
#define COV_EPS 1e-7f

/* color, spp: the frame's samples (samples offset .. offset + spp - 1 of `stride` per pixel
 * in the buffer: a whole frame stride spp, offset 0; a half read in place, stride the
 * frame's); a pixel that no layer covers (no sample's PSF reached it, which happens at 1-4
 * spp), or whose layers give black, takes the mean of its own samples, the unbiased
 * estimate, instead of black. spp = 0: no samples given, such a pixel stays as the layers
 * make it. */
__kernel void splat_composite(__global const float4 *b, __global const float4 *direct,
                               __global const float4 *ring, const int width, const int height,
                               const int pad, const int pw, const int ph,
                               __global const float *color, const int spp,
                               const int stride, const int offset, __global float *out)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    const size_t p = (size_t)(y + pad) * pw + (x + pad);
    float3 acc = (float3)(0.0f);
    float alpha = 0.0f;
    int filled = 0;
    for (int l = 0; l < NLAYERS; ++l) {
        float4 v = direct[(size_t)l * ph * pw + p];
#if USE_LAP
        v += ring[l] - b[(size_t)l * ph * pw + p];
#endif
        const float cov = fmax(v.w, 0.0f);
        if (cov <= COV_EPS)
            continue;
        const float3 colour = fmax(v.xyz, 0.0f) / cov;
        float a = fmin(cov, 1.0f);
        if (!filled && cov >= FILL_COV) {
            a = 1.0f;
            filled = 1;
        }
        acc = a * colour + (1.0f - a) * acc;
        alpha = a + (1.0f - a) * alpha;
    }
    float3 res = (float3)(0.0f);
    if (alpha > 0.0f)
        res = acc / alpha;
    /* no layer covers it, or what covers it is black after the clamp (a faint layer's
     * ringing): the pixel's own samples decide */
    if (spp > 0 && fmax(res.x, fmax(res.y, res.z)) <= 0.0f) {
        res = (float3)(0.0f);
        const __global float *c = color + (((size_t)y * width + x) * (size_t)stride
                                           + (size_t)offset) * 3;
        for (int i = 0; i < spp; ++i)
            res += vload3(i, c);
        res = fmax(res / (float)spp, 0.0f);
    }
    vstore3(res, (size_t)y * width + x, out);
}
