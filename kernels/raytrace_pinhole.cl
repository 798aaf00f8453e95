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
                               const int row0, CAMERA_ARGS, SAMPLE_FIELDS)
{
    const int px = get_global_id(0), py = get_global_id(1) + row0;
    if (px >= width || py >= height)
        return;
    pixel_t pix;
    pixel_setup(&pix, bounds, nobj, px, py, 0u);
    for (int k = 0; k < 5; ++k)
        pix.shift[k] = 0x80000000U;  /* every lattice dimension at 1/2 (the header) */
    const sample_t s = trace(objs, nobj, &pix, 0u, CAMERA_PASS);
    store_sample(&s, pixel_index(px, py, width), SAMPLE_FIELDS_PASS);
}
