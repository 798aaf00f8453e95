/* splat_mip.h: what the two files of method splat's mip plan (mip_radius set) share. Every
 * sample's PSF is drawn at the pyramid level where it is small, after the samples that share
 * a level pixel were merged, so the cost per sample does not grow with the blur
 * (clrecon/methods/splat/mip.py; NumPy reference clrecon/methods/splat/mip_reference.py):
 *   splat_mip_bin.cl   splat_mip_bin_*: the samples into the bins of their level pixels
 *   splat_mip_draw.cl  splat_mip_draw_*: one PSF per bin into the level images, and
 *                      splat_mip_upsample: the levels down into level 0
 *
 * Levels l = 0 .. NLEV - 1, level pixel = s = 2^l x 2^l frame pixels; level l holds PSFs of
 * radius <= RL[l] and length <= ML[l] level pixels (RL[l] = R0 min(2^(l/2), 4), ML = 4 RL:
 * the coarse levels, whose bins are few, resolve their PSFs more finely). A sample with
 * r = |coc|, L = |motion| (the centre, layer and CoC as in splat.cl) goes to the lowest
 * level with r <= TR[l] = RL[l] 2^l and L <= TM[l] = ML[l] 2^l, at most NLEV - 1; there r / s
 * and L / s are clamped to RL and ML (the centre re-centred by the clamped blur, so the
 * sample stays inside the PSF that is drawn).
 *
 * Layout: float4 images [level][layer][nh_l][nw_l], nw_l = ceil(W / 2^l) + 2 P_l,
 * nh_l = ceil(H / 2^l) + 2 P_l (P_l level pixels of pad on every side); bins the same with
 * three float4 per pixel. lv[l] = (first pixel of level l, nw_l, nh_l, P_l), P_l = 2 E_l,
 * E_l = ceil(RL + ML / 2) + 2 the level's reach: a centre lies within RL + ML / 2 level
 * pixels of its frame pixel and a PSF within E_l of its bin.
 *   mip_index(lv, l, layer, qx, qy)  pixel index of unpadded level pixel (qx, qy)
 * Compile-time: SPP, HAS_MOTION, NLAYERS (defaults in splat.h), NLEV (levels).
 */
#ifndef CLRECON_SPLAT_MIP_H
#define CLRECON_SPLAT_MIP_H

#include "splat.h"

#ifndef NLEV
#define NLEV 1
#endif

/* Every helper is always_inline: at their sizes PoCL's inliner keeps some as calls, and a
 * call stops the vectorisation of the work-item loop (the bin pass ran ~20x slower). */

/* pixel index of level pixel (qx, qy) (unpadded) of `layer` at level `l` */
__attribute__((always_inline)) inline size_t mip_index(__global const int4 *lv, const int l,
                                                       const int layer, const int qx,
                                                       const int qy)
{
    const int4 g = lv[l];
    return (size_t)g.x + ((size_t)layer * g.z + (size_t)(qy + g.w)) * g.y + (size_t)(qx + g.w);
}

#endif /* CLRECON_SPLAT_MIP_H */
