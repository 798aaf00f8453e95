/* splat.h: what the splatting passes of method `splat` (splat.cl, and the mip plan's
 * splat_mip_bin.cl / splat_mip_draw.cl through splat_mip.h) share: the defaults of their
 * compile-time options and a sample's CoC and depth layer.
 *
 *   splat_coc(z, c0, c1)    coc = c0 / z + c1, c1 for a miss (depth z >= MISS_DEPTH, 1e30)
 *   splat_layer(z, ...)     floor((1 / z - inv_far) * layer_scale) clamped to [0, NLAYERS)
 *                           (0 = farthest; uniform in 1/depth: constant parallax; misses at
 *                           1/depth = 0)
 * Compile-time: SPP (samples per pixel), HAS_MOTION (0: motion and time unused), NLAYERS.
 */
#ifndef CLRECON_SPLAT_H
#define CLRECON_SPLAT_H

#include "common.h"
#include "limits.h"

#ifndef SPP
#define SPP 1
#endif
#ifndef HAS_MOTION
#define HAS_MOTION 1
#endif
#ifndef NLAYERS
#define NLAYERS 1
#endif

__attribute__((always_inline)) inline float splat_coc(const float z, const float c0,
                                                      const float c1)
{
    return z >= MISS_DEPTH ? c1 : c0 / z + c1;
}

__attribute__((always_inline)) inline int splat_layer(const float z, const float inv_far,
                                                      const float layer_scale)
{
    const float inv = z >= MISS_DEPTH ? 0.0f : 1.0f / z;
    return clamp((int)floor((inv - inv_far) * layer_scale), 0, NLAYERS - 1);
}

#endif /* CLRECON_SPLAT_H */
