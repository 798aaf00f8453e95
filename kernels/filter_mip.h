/* filter_mip.h: what the buffer and image variants of the layered MIP filter share
 * (Hasselgren et al. 2015, section 6.1; kernels/filter_mip.cl, kernels/filter_mip_image.cl):
 * the pyramid's level sizes and offsets, and each filtered pixel's footprint, i.e. the four
 * taps at +-MIP_D sigma along u and v, each n trilinear probes spread along the major axis
 * at one level of detail. Compile-time: NLEV (levels incl. 0), PYR_PLANE.
 */
#ifndef CLRECON_FILTER_MIP_H
#define CLRECON_FILTER_MIP_H

#include "layered.h"

/* defaults: the default layout's DMAX 64 grid (layered.h: TILE 32, GMAX 16; the host sets
 * both from reference.mip_levels) */
#ifndef NLEV
#define NLEV 7
#endif
#ifndef PYR_PLANE
#define PYR_PLANE 1365
#endif
#define MIP_ALPHA 2.24f
#define MIP_D 0.33f
#define MAX_ANISO 16

inline int level_side(int dim, int l) { return (dim + (1 << l) - 1) >> l; }

inline int level_offset(int dim, int l)  /* offset of level l >= 1 within a channel plane */
{
    int off = 0;
    for (int m = 1; m < l; ++m) {
        const int d = level_side(dim, m);
        off += d * d;
    }
    return off;
}

/* The probes of filtered pixel (i, j) of a slot with parameters p: probe m (0 <= m < n) of
 * tap t (0..3) is at c0 + offs[t] + along(m) eu, read trilinearly from levels l (weight
 * 1 - f) and l1 = l + 1 (weight f; l1 = l where f = 0) of the pyramid of the slot's D x D
 * grid (dim = D); the sum is divided by n. */
typedef struct {
    float2 c0, eu, offs[4];
    float spread, f;
    int n, l, l1, dim;
} mip_footprint;

inline mip_footprint mip_footprint_of(__global const float *p, int i, int j)
{
    mip_footprint fp;
    const float g = p[P_GUARD], inv_s = 1.0f / p[P_SCALE];
    const float su = p[P_SU] * inv_s, sv = p[P_SV] * inv_s;
    const float2 eu = (float2)(p[P_COS], p[P_SIN]), ev = (float2)(-p[P_SIN], p[P_COS]);
    const float tsu = (MIP_ALPHA - MIP_D) / MIP_ALPHA * su;  /* tap's own sigma */
    const float tsv = (MIP_ALPHA - MIP_D) / MIP_ALPHA * sv;
    fp.n = clamp((int)ceil(tsu / fmax(tsv, 1e-3f)), 1, MAX_ANISO);
    const float minor = fmax(tsv, tsu / MAX_ANISO);
    fp.spread = sqrt(fmax(3.0f * (tsu * tsu - minor * minor), 0.0f));
    /* trilinear: levels l and l + 1 with weights 1 - f and f, the same for every probe */
    const float lod = clamp(log2(fmax(MIP_ALPHA * minor, 1.0f)), 0.0f, (float)(NLEV - 1));
    fp.l = min((int)lod, NLEV - 2 < 0 ? 0 : NLEV - 2);
    fp.f = NLEV > 1 ? lod - (float)fp.l : 0.0f;
    fp.l1 = fp.f > 0.0f ? fp.l + 1 : fp.l;
    fp.dim = (int)p[P_DIM];
    fp.c0 = (float2)(i + g, j + g);
    fp.eu = eu;
    fp.offs[0] = MIP_D * su * eu;
    fp.offs[1] = -MIP_D * su * eu;
    fp.offs[2] = MIP_D * sv * ev;
    fp.offs[3] = -MIP_D * sv * ev;
    return fp;
}

inline float2 mip_probe(const mip_footprint *fp, int t, int m)
{
    const float along = fp->n > 1 ? fp->spread * (2.0f * (m + 0.5f) / fp->n - 1.0f) : 0.0f;
    return fp->c0 + fp->offs[t] + along * fp->eu;
}

#endif /* CLRECON_FILTER_MIP_H */
