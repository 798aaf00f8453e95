/* filter_mip.cl: the screen-space filter from a MIP pyramid per partition grid and four
 * anisotropic lookups (Hasselgren et al. 2015, section 6.1). OpenCL has no anisotropic
 * sampler, so each lookup is emulated as hardware does it: trilinear probes along the major
 * axis of its footprint. This file reads buffers; kernels/filter_mip_image.cl reads the same
 * pyramid through image objects and the linear sampler (filter_mip.h: what both share).
 *
 * filter_mip_build: one work-group per slot (1D range tiles * MAXP * n, n items a group);
 *   level l >= 1 of the pyramid (side D_l = ceil(D_{l-1} / 2)) is the mean of 2x2 texels of
 *   level l - 1 (missing texels count as 0); level 0 is the grid itself. Barriers between
 *   levels (the group owns its slot).
 *   pyr  float (tiles, MAXP, NCH, PYR_PLANE): levels 1.. packed, row stride D_l
 * filter_mip_sample: one work-item per filtered pixel (i, j) in [-1, T/s]^2, range (FT, FT,
 *   tiles * MAXP). Four taps at +-MIP_D sigma along u and along v of the partition's
 *   Gaussian (sigma_u, sigma_v, theta in grid pixels); each tap's footprint is the ellipse
 *   (MIP_ALPHA - MIP_D) sigma that touches the MIP_ALPHA sigma edge (MIP_ALPHA = 2.24: 95% of
 *   the energy, eq. 3). A tap is n = ceil(major / minor) (<= MAX_ANISO) trilinear probes at
 *   LOD log2(minor footprint), spread over +-sqrt(3 (tsu^2 - tsv^2)) along the major axis so
 *   that the probes' spread adds the missing variance. Level-l texel k is centred at
 *   k 2^l + (2^l - 1) / 2 in grid coordinates. Unnormalised sums (composite divides).
 * Compile-time: TILE, MAXP, GMAX, NLEV (levels incl. 0), PYR_PLANE. Local sizes are
 * launch parameters only (the host's, tuned for filter_mip_sample).
 */
#include "filter_mip.h"
#include "vec_hint.h"

__kernel SCALAR_WORK_ITEMS
void filter_mip_build(__global const float *params, __global const float *grids,
                      __global float *pyr)
{
    const int slot = get_group_id(0), lid = get_local_id(0), n = get_local_size(0);
    __global const float *p = params + (size_t)slot * NPAR;
    const int dim = (int)p[P_DIM];
    if (dim == 0)
        return;
    __global const float *g0 = grids + (size_t)slot * NCH * DMAX * DMAX;
    __global float *py = pyr + (size_t)slot * NCH * PYR_PLANE;
    for (int l = 1; l < NLEV; ++l) {
        const int ds = level_side(dim, l - 1), dd = level_side(dim, l);
        __global const float *src = l == 1 ? g0 : py + level_offset(dim, l - 1);
        const int sp = l == 1 ? DMAX * DMAX : PYR_PLANE;
        __global float *dst = py + level_offset(dim, l);
        for (int k = lid; k < dd * dd; k += n) {
            const int x = 2 * (k % dd), y = 2 * (k / dd);
            for (int c = 0; c < NCH; ++c) {
                __global const float *s = src + c * sp;
                float v = s[y * ds + x];
                if (x + 1 < ds)
                    v += s[y * ds + x + 1];
                if (y + 1 < ds) {
                    v += s[(y + 1) * ds + x];
                    if (x + 1 < ds)
                        v += s[(y + 1) * ds + x + 1];
                }
                dst[c * PYR_PLANE + k] = 0.25f * v;
            }
        }
        barrier(CLK_GLOBAL_MEM_FENCE);
    }
}

/* One pyramid level as the probes read it: plane pointer, channel stride, side, scale. */
typedef struct {
    __global const float *b;
    int plane, side;
    float sc;
} mip_level;

inline mip_level mip_level_of(__global const float *g0, __global const float *py, int dim,
                              int l)
{
    mip_level m;
    m.b = l == 0 ? g0 : py + level_offset(dim, l);
    m.plane = l == 0 ? DMAX * DMAX : PYR_PLANE;
    m.side = level_side(dim, l);
    m.sc = (float)(1 << l);
    return m;
}

/* Bilinear lookup of a level at grid coordinate (x, y), weight wt; texels outside read 0. */
inline void mip_bilinear(mip_level m, float x, float y, float wt, float *acc)
{
    const float lx = (x - 0.5f * (m.sc - 1.0f)) / m.sc, ly = (y - 0.5f * (m.sc - 1.0f)) / m.sc;
    const int side = m.side;
    const float fx = floor(lx), fy = floor(ly);
    const int ix = (int)fx, iy = (int)fy;
    if (ix < -1 || iy < -1 || ix >= side || iy >= side)
        return;
    const float ax = lx - fx, ay = ly - fy;
    const float w[4] = {(1.0f - ax) * (1.0f - ay), ax * (1.0f - ay), (1.0f - ax) * ay, ax * ay};
    __global const float *b = m.b + iy * side + ix;
    if (ix >= 0 && iy >= 0 && ix + 1 < side && iy + 1 < side) {
        /* interior: all four texels (zero weights add zero, as the skipped taps below) */
        for (int c = 0; c < NCH; ++c) {
            __global const float *q = b + c * m.plane;
            acc[c] += wt * (w[0] * q[0] + w[1] * q[1] + w[2] * q[side] + w[3] * q[side + 1]);
        }
        return;
    }
    for (int q = 0; q < 4; ++q) {
        const int tx = ix + (q & 1), ty = iy + (q >> 1);
        if (tx < 0 || ty < 0 || tx >= side || ty >= side || w[q] == 0.0f)
            continue;
        for (int c = 0; c < NCH; ++c)
            acc[c] += wt * w[q] * m.b[c * m.plane + ty * side + tx];
    }
}

__kernel SCALAR_WORK_ITEMS
void filter_mip_sample(__global const float *params, __global const float *grids,
                       __global const float *pyr, __global float *filtered)
{
    int i, j, slot;
    __global const float *p = layered_filtered_item(params, 1, &i, &j, &slot);
    if (!p)
        return;
    const mip_footprint fp = mip_footprint_of(p, i, j);
    __global const float *g0 = grids + (size_t)slot * NCH * DMAX * DMAX;
    __global const float *py = pyr + (size_t)slot * NCH * PYR_PLANE;
    const mip_level m0 = mip_level_of(g0, py, fp.dim, fp.l);
    const mip_level m1 = mip_level_of(g0, py, fp.dim, fp.l1);
    float acc[NCH] = {0.0f};
    for (int t = 0; t < 4; ++t) {
        for (int m = 0; m < fp.n; ++m) {
            const float2 q = mip_probe(&fp, t, m);
            mip_bilinear(m0, q.x, q.y, 1.0f - fp.f, acc);
            if (fp.f > 0.0f)
                mip_bilinear(m1, q.x, q.y, fp.f, acc);
        }
    }
    layered_store_filtered(filtered, slot, i, j, acc, (float)fp.n);
}
