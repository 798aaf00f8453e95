/* raytrace_pinhole.cl: the synthesis input of method splat, a pinhole frame (ARCHITECTURE.md
 * section 1: S = 1, lens (0, 0), time 0.5), traced with raytrace.cl's own sampler.
 *
 * raytrace_pinhole: one work-item per pixel of rows [row0, row0 + global size y). Every
 *   lattice dimension gets the Cranley-Patterson shift 1/2 and index 0, so the sample sits
 *   at the pixel centre, lens point concentric_disk(1/2, 1/2) = (0, 0), time 1/2. Outputs as
 *   raytrace_samples with S = 1: color (npix*3), position (npix*2), depth, lens (npix*2),
 *   time, motion (npix*2).
 */
#include "raytrace.cl"

__kernel void raytrace_pinhole(__global const float *objs, __global const float4 *bounds,
                               const int nobj, const int width, const int height,
                               const int row0, const float cx, const float cy,
                               const float focal, const float focus, const float lens_radius,
                               const float4 light, const float4 background,
                               __global float *color, __global float *position,
                               __global float *depth, __global float *lens,
                               __global float *time, __global float *motion)
{
    const int px = get_global_id(0), py = get_global_id(1) + row0;
    if (px >= width || py >= height)
        return;
    const uint shift[5] = {0x80000000U, 0x80000000U, 0x80000000U, 0x80000000U, 0x80000000U};
    uchar cand[MAX_CANDIDATES];
    const int ncand = pixel_candidates(bounds, nobj, px, py, cand);
    const sample_t s = trace(objs, nobj, cand, ncand, px, py, 0u, shift, cx, cy, focal, focus,
                             lens_radius, light.xyz, light.w, background.xyz);
    const int k = pixel_index(px, py, width);
    vstore3(s.color, k, color);
    vstore2(s.pos, k, position);
    depth[k] = s.depth;
    vstore2(s.lens, k, lens);
    time[k] = s.time;
    vstore2(s.motion, k, motion);
}
