/* sweep_resolve.cl: the front-to-back sweep of Shirley et al. 2011 (Algorithm 2 with the
 * weights of Appendix A, two scales 1x1/5x5 blended, or Appendix B, four scales 1/3/5/7).
 *
 * Input: keys/colors of sweep_prepare (per pixel sorted by depth). Output: out (H, W, 3).
 * Every pixel sweeps the samples of its (2R+1)^2 window (R = 2 or 3; pixels outside the
 * image contribute nothing) in depth order; equal depths keep window order (row-major, then
 * the pixel's own order), as the NumPy reference in clrecon/methods/sweep/reference.py does.
 *
 * Two ways to get that order, same result:
 *   sweep_resolve_pixel: each work-item merges the K sorted lists of its window (K-way
 *     merge by linear scan of the list heads).
 *   sweep_resolve_tile: a TILE x TILE work-group loads the sorted keys of the tile and its
 *     apron into local memory, sorts them once (bitonic, by depth then position in the
 *     tile), and every pixel walks that list, skipping samples outside its window.
 * Both take a shortcut where every sample of a window weighs in one box alone (sweep_radius):
 * that box's mean, unsorted (UNIFORM_BOX, default 1; 0 sweeps every window).
 * Compile-time: SPP, SCALES (2 or 4), EXPONENT and EXPONENT_ON (the paper's 1.3 variant;
 *   defaults and R in sweep.h), UNIFORM_BOX, SORT_N (power of two >= (TILE + 2R)^2 * SPP,
 *   tile kernel only).
 * Tunables: TILE (tile kernel: local size TILE x TILE; the pixel kernel's local size is a
 *   launch parameter only),
 *   TILE_MERGE (tile kernel): 0 = bitonic sort by all work-items (GPUs), 1 = one work-item
 *   merges the tile's per-pixel sorted runs through a winner tree (CPUs, where the items
 *   of a group run one after another anyway: ~5x fewer operations than the network).
 */
#include "sweep.h"
#include "vec_hint.h"

#ifndef TILE
#define TILE 4
#endif
#define WIN (2 * R + 1)
#define TW (TILE + 2 * R)
#define TILE_SAMPLES (TW * TW * SPP)
#ifndef SORT_N
#define SORT_N 1024
#endif
#ifndef TILE_MERGE
#define TILE_MERGE 0
#endif
#define RUNS (TW * TW)
#define LEAVES (RUNS <= 16 ? 16 : RUNS <= 32 ? 32 : RUNS <= 64 ? 64 : RUNS <= 128 ? 128 : \
                RUNS <= 256 ? 256 : RUNS <= 512 ? 512 : 1024)

typedef struct {
    float cov_1, cov_3, cov_5, cov_7, cov;
    float3 sum;
} sweep_state;

/* half-open [-r, r): with positions clamped into [px, px+1) (sweep_prepare) a sample is in
 * exactly the blocks whose pixels it belongs to */
inline float box(float x, float radius)
{
    return (x >= -radius && x < radius) ? 0.5f / radius : 0.0f;
}

/* One step of the sweep for a sample at offset (x, y) from the pixel centre. */
inline void sweep_step(sweep_state *st, float x, float y, float d, float3 c)
{
    const float ns_inv = 1.0f / SPP;
    const float w_1 = ns_inv * box(x, 0.5f) * box(y, 0.5f);
    const float w_5 = ns_inv * box(x, 2.5f) * box(y, 2.5f);
    float w;
#if SCALES == 2
    const float blend = clamp((d - 1.0f) / 5.0f, 0.0f, 1.0f);
    w = blend * (w_5 * (1.0f - st->cov_1) + w_1 * st->cov_1);
    st->cov_5 += blend * (w_5 * (1.0f - st->cov_1));
    w += (1.0f - blend) * (w_1 * (1.0f - st->cov_5) + w_5 * st->cov_5);
    st->cov_1 += (1.0f - blend) * (w_1 * (1.0f - st->cov_5));
#else
    const float w_3 = ns_inv * box(x, 1.5f) * box(y, 1.5f);
    const float w_7 = ns_inv * box(x, 3.5f) * box(y, 3.5f);
    const float c1 = st->cov_1, c3 = st->cov_3, c5 = st->cov_5, c7 = st->cov_7;
    if (d > 7.0f) {
        w = w_7 * (1.0f - c1 - c3 - c5) + w_1 * c1 + w_3 * c3 + w_5 * c5;
        st->cov_7 += w_7 * (1.0f - c1 - c3 - c5);
    } else if (d > 5.0f) {
        w = w_5 * (1.0f - c1 - c3 - c7) + w_1 * c1 + w_3 * c3 + w_7 * c7;
        st->cov_5 += w_5 * (1.0f - c1 - c3 - c7);
    } else if (d > 3.0f) {
        w = w_3 * (1.0f - c1 - c5 - c7) + w_1 * c1 + w_5 * c5 + w_7 * c7;
        st->cov_3 += w_3 * (1.0f - c1 - c5 - c7);
    } else {
        w = w_1 * (1.0f - c3 - c5 - c7) + w_3 * c3 + w_5 * c5 + w_7 * c7;
        st->cov_1 += w_1 * (1.0f - c3 - c5 - c7);
    }
#endif
#if EXPONENT_ON
    /* w >= 0; exp2/log2 instead of pow, which is a slow generic routine on CPUs */
    w = w > 0.0f ? exp2(EXPONENT * log2(w)) : 0.0f;
#endif
    st->cov += w;
    st->sum += w * c;
}

#ifndef UNIFORM_BOX
#define UNIFORM_BOX 1  /* 0: every window is swept (those whose samples weigh in one box too) */
#endif

/* The box radius k that alone weighs a sample of diameter d in sweep_step (its blend 1: the
 * 5x5 box, 0: the 1x1 box, with two scales; D's band with four), -1 where the weight mixes
 * boxes. A window whose every sample has the same k >= 0 keeps the other boxes' coverages
 * at zero, so each sample weighs that box's constant in it, in any depth order: the sweep's
 * image is the box's mean (sweep_box_mean), without the sort or the sweep. */
inline int sweep_radius(const float d)
{
#if SCALES == 2
    const float blend = clamp((d - 1.0f) / 5.0f, 0.0f, 1.0f);  /* as sweep_step */
    return blend >= 1.0f ? 2 : (blend == 0.0f ? 0 : -1);
#else
    return d > 7.0f ? 3 : (d > 5.0f ? 2 : (d > 3.0f ? 1 : 0));
#endif
}

/* The mean colour of the samples of the (2k+1)^2 pixels around (px, py) in the image, each
 * scaled as it is summed (no partial sum exceeds the largest colour). */
inline float3 sweep_box_mean(__global const float4 *colors, const int px, const int py,
                             const int width, const int height, const int k)
{
    const int xa = max(0, px - k), xb = min(width - 1, px + k);
    const int ya = max(0, py - k), yb = min(height - 1, py + k);
    const float inv = 1.0f / (float)((xb - xa + 1) * (yb - ya + 1) * SPP);
    float3 sum = (float3)(0.0f);
    for (int y = ya; y <= yb; ++y)
        for (int x = xa; x <= xb; ++x) {
            const int b = pixel_index(x, y, width) * SPP;
            for (int i = 0; i < SPP; ++i)
                sum = fma(colors[b + i].xyz, (float3)(inv), sum);
        }
    return sum;
}

inline void sweep_init(sweep_state *st)
{
    st->cov_1 = st->cov_3 = st->cov_5 = st->cov_7 = st->cov = 0.0f;
    st->sum = (float3)(0.0f);
}

__kernel SCALAR_WORK_ITEMS
void sweep_resolve_pixel(__global const float4 *keys, __global const float4 *colors,
                         const int width, const int height, __global float *out)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    int base[WIN * WIN], cur[WIN * WIN];
    float head[WIN * WIN];
    for (int j = 0; j < WIN * WIN; ++j) {
        const int qx = px + j % WIN - R, qy = py + j / WIN - R;
        const bool inside = qx >= 0 && qx < width && qy >= 0 && qy < height;
        base[j] = inside ? pixel_index(qx, qy, width) * SPP : 0;
        cur[j] = inside ? 0 : SPP;
        head[j] = inside ? keys[base[j]].z : INFINITY;
    }
#if UNIFORM_BOX
    {   /* one box for every sample of the window: its mean */
        const int k0 = sweep_radius(keys[base[R * WIN + R]].w);  /* (px, py): in the image */
        bool one = k0 >= 0;
        for (int j = 0; one && j < WIN * WIN; ++j)
            for (int i = cur[j]; i < SPP; ++i)
                one &= sweep_radius(keys[base[j] + i].w) == k0;
        if (one) {
            vstore3(sweep_box_mean(colors, px, py, width, height, k0),
                    pixel_index(px, py, width), out);
            return;
        }
    }
#endif
    const float cx = px + 0.5f, cy = py + 0.5f;
    sweep_state st;
    sweep_init(&st);
    for (;;) {
        int best = -1;
        for (int j = 0; j < WIN * WIN; ++j)
            if (cur[j] < SPP && (best < 0 || head[j] < head[best]))
                best = j;
        if (best < 0)
            break;
        const int idx = base[best] + cur[best];
        const float4 k = keys[idx];
        ++cur[best];
        head[best] = cur[best] < SPP ? keys[idx + 1].z : INFINITY;
        sweep_step(&st, k.x - cx, k.y - cy, k.w, colors[idx].xyz);
    }
    vstore3(st.sum / st.cov, pixel_index(px, py, width), out);
}

__kernel SCALAR_WORK_ITEMS __attribute__((reqd_work_group_size(TILE, TILE, 1)))
void sweep_resolve_tile(__global const float4 *keys, __global const float4 *colors,
                        const int width, const int height, __global float *out)
{
    __local float4 lkeys[TILE_SAMPLES];
    __local float lz[SORT_N];
    __local ushort lidx[SORT_N];
#if UNIFORM_BOX
    __local int lk[2];  /* the smallest and largest sweep_radius of the window's samples */
#endif
    const int lx = get_local_id(0), ly = get_local_id(1);
    const int lid = ly * TILE + lx;
    const int x0 = get_group_id(0) * TILE - R, y0 = get_group_id(1) * TILE - R;
#if UNIFORM_BOX
    if (lid == 0) {
        lk[0] = 4;
        lk[1] = -1;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    int klo = 4, khi = -1;
#endif
    for (int i = lid; i < SORT_N; i += TILE * TILE) {
        float z = INFINITY;
        if (i < TILE_SAMPLES) {
            const int t = i / SPP, s = i % SPP;
            const int qx = x0 + t % TW, qy = y0 + t / TW;
            float4 k = (float4)(0.0f, 0.0f, INFINITY, 0.0f);
            if (qx >= 0 && qx < width && qy >= 0 && qy < height) {
                k = keys[pixel_index(qx, qy, width) * SPP + s];
#if UNIFORM_BOX
                const int r = sweep_radius(k.w);
                klo = min(klo, r);
                khi = max(khi, r);
#endif
            }
            lkeys[i] = k;
            z = k.z;
        }
        lz[i] = z;
        lidx[i] = (ushort)i;
    }
#if UNIFORM_BOX
    atomic_min(&lk[0], klo);
    atomic_max(&lk[1], khi);
#endif
    barrier(CLK_LOCAL_MEM_FENCE);
    /* one box weighs every sample of the tile's window: no sort (its loops run no step and
     * every work-item still meets the same barriers; with a return here, before them, PoCL
     * 3.1 wrote NaNs and corrupted its heap at tile 8), then each pixel's box mean */
#if UNIFORM_BOX
    const int kone = lk[0] == lk[1] && lk[0] >= 0 ? lk[0] : -1;
#else
    const int kone = -1;
#endif
#if TILE_MERGE
    /* Each pixel's run of SPP keys is already sorted (sweep_prepare); merge the RUNS runs
     * with a winner tree. Key: depth bits (depth > 0, so its IEEE bits order like the
     * value) above the run index, so ties go to the lower tile index like the sort. */
    if (lid == 0 && kone < 0) {
        ulong tree[2 * LEAVES];
        int pos[RUNS];
        for (int r = 0; r < LEAVES; ++r) {
            ulong key = ULONG_MAX;
            if (r < RUNS) {
                pos[r] = 0;
                key = ((ulong)as_uint(lz[r * SPP]) << 32) | (uint)r;
            }
            tree[LEAVES + r] = key;
        }
        for (int i = LEAVES - 1; i > 0; --i)
            tree[i] = min(tree[2 * i], tree[2 * i + 1]);
        for (int p = 0; p < TILE_SAMPLES; ++p) {
            const int r = (int)(tree[1] & 0xFFFFFFFFUL);
            const int k = r * SPP + pos[r]++;
            lidx[p] = (ushort)k;
            int i = LEAVES + r;
            tree[i] = pos[r] < SPP ? ((ulong)as_uint(lz[k + 1]) << 32) | (uint)r : ULONG_MAX;
            for (i >>= 1; i > 0; i >>= 1)
                tree[i] = min(tree[2 * i], tree[2 * i + 1]);
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#else
    /* bitonic sort of (depth, index): index ties keep tile order, and padding (index >=
     * TILE_SAMPLES, depth inf) sorts after every real entry */
    for (int size = 2; size <= (kone < 0 ? SORT_N : 0); size <<= 1) {
        for (int stride = size >> 1; stride > 0; stride >>= 1) {
            for (int i = lid; i < SORT_N / 2; i += TILE * TILE) {
                const int a = 2 * i - (i & (stride - 1));
                const int b = a + stride;
                const bool up = (a & size) == 0;
                const float za = lz[a], zb = lz[b];
                const ushort ia = lidx[a], ib = lidx[b];
                const bool greater = za > zb || (za == zb && ia > ib);
                if (greater == up) {
                    lz[a] = zb; lz[b] = za;
                    lidx[a] = ib; lidx[b] = ia;
                }
            }
            barrier(CLK_LOCAL_MEM_FENCE);
        }
    }
#endif
    const int px = x0 + R + lx, py = y0 + R + ly;
    if (px >= width || py >= height)
        return;
    if (kone >= 0) {
        vstore3(sweep_box_mean(colors, px, py, width, height, kone), pixel_index(px, py, width),
                out);
        return;
    }
    const float cx = px + 0.5f, cy = py + 0.5f;
    sweep_state st;
    sweep_init(&st);
    for (int p = 0; p < TILE_SAMPLES; ++p) {
        const int i = lidx[p];
        const int t = i / SPP;
        const int tx = t % TW, ty = t / TW;
        if (abs(tx - R - lx) > R || abs(ty - R - ly) > R)
            continue;
        const int qx = x0 + tx, qy = y0 + ty;
        if (qx < 0 || qx >= width || qy < 0 || qy >= height)
            continue;
        const float4 k = lkeys[i];
        const float3 c = colors[pixel_index(qx, qy, width) * SPP + i % SPP].xyz;
        sweep_step(&st, k.x - cx, k.y - cy, k.w, c);
    }
    vstore3(st.sum / st.cov, pixel_index(px, py, width), out);
}
