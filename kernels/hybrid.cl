/* hybrid.cl: two safeguarded images of one frame blended per pixel by their own error
 * estimates (clrecon/methods/hybrid.py has the why and the NumPy reference).
 *
 *   hybrid_blend  per pixel: Sa, Sb the sums of the two error estimates over the
 *                 (2 HR + 1)^2 window around it (pixels inside the image: both windows count
 *                 the same pixels, so the sums' ratio is the means'); the weight of image a
 *                 wa = Sb / (Sa + Sb) (inverse-error weights), or where that sum is 0 or not
 *                 finite, 1, 0 or 1/2 as Sa <, > or == Sb; out = wa a + (1 - wa) b;
 *                 error = (wa sqrt(ea) + (1 - wa) sqrt(eb))^2 from the pixel's own estimates:
 *                 the squared error of the blend if the two estimates were exact and the
 *                 errors fully correlated (both images come from the same samples), the
 *                 largest any correlation gives; saturated at FLT_MAX.
 * Arguments: a, b (H, W, 3), ea, eb (H, W) the estimates (non-negative, finite), out
 * (H, W, 3), error (H, W), W, H. One work-item per pixel (2D range rounded up; items outside
 * the image return); local size: the runtime's.
 * Compile-time: HR (window half side, default 3: the safeguard's 7x7).
 */
#ifndef HR
#define HR 3
#endif

__kernel void hybrid_blend(__global const float *a, __global const float *ea,
                           __global const float *b, __global const float *eb,
                           __global float *out, __global float *error, const int W,
                           const int H)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H)
        return;
    const int x0 = max(0, x - HR), x1 = min(W - 1, x + HR);
    const int y0 = max(0, y - HR), y1 = min(H - 1, y + HR);
    float sa = 0.0f, sb = 0.0f;
    for (int v = y0; v <= y1; ++v)
        for (int u = x0; u <= x1; ++u) {
            sa += ea[v * W + u];
            sb += eb[v * W + u];
        }
    const float s = sa + sb;
    const float wa = (s > 0.0f && isfinite(s)) ? sb / s
                     : (sa < sb ? 1.0f : (sa > sb ? 0.0f : 0.5f));
    const int p = y * W + x;
    const float3 ca = vload3(p, a), cb = vload3(p, b);
    vstore3(cb + wa * (ca - cb), p, out);
    const float r = wa * sqrt(ea[p]) + (1.0f - wa) * sqrt(eb[p]);
    error[p] = fmin(r * r, FLT_MAX);
}
