/* inspect.cl: one pass over a frame's samples already on the device, computing both the
 * facts of SampleBuffer.inspect() and the value rules of SampleBuffer.validate().
 *
 * inspect_clear: resets result[] (NSLOT uints) before a pass; global size >= NSLOT.
 *
 * inspect_samples: N = H * W * S samples, linear sample index i = (y * W + x) * S + s.
 *   depth     float (N)       always read
 *   color     float (N, 3)    read only with HAS_COLOR
 *   position  float (N, 2)    read only with HAS_POSITION (sensor position, pixels)
 *   lens      float (N, 2)    read only with HAS_LENS
 *   time      float (N)       read only with HAS_TIME
 *   motion    float (N, 2)    read only with HAS_MOTION
 *   (the pointer of a field that is not present may be NULL: it is never dereferenced)
 *   n                         N (< 2^31)
 *   width, width_m, width_sh  W and its udiv31() magic (clrecon.core.inspect.udiv_magic)
 *   spp_m, spp_sh             udiv31() magic of S (only position needs W and S)
 *   c0, c1                    coc(w) = c0 / w + c1 in pixels; a miss (w >= MISS_DEPTH, inf
 *                             and NaN included) has coc = c1
 *   color_lo                  least valid colour channel: 0, or -COLOR_MAX (allow_negative)
 *   coc_lo                    least hit depth whose CoC is within COC_MAX (host:
 *                             clrecon.core.samples.coc_min_depth, exact for the host formula;
 *                             0 when not checked)
 *   result    uint (NSLOT), cleared by inspect_clear, combined with global atomics:
 *     [S_FIRST + r]  smallest i failing rule r, NONE if none       (atomic_min)
 *     [S_COUNT + r]  number of samples failing rule r              (atomic_add)
 *     [S_COC]        bits of max |coc| over every sample           (atomic_max)
 *     [S_MOTION]     bits of max |motion| (Euclidean length)       (atomic_max)
 *     [S_DMIN]       order key of the min hit depth (w < MISS)     (atomic_min)
 *     [S_DMAX]       order key of the max hit depth                (atomic_max)
 *     [S_HITS]       number of hits                                (atomic_add)
 *   Rules r, in SampleBuffer.validate() order (the comparisons are the same, NaN fails):
 *     R_DEPTH    !(w >= MIN_DEPTH)
 *     R_COLOR    any channel !(color_lo <= c <= COLOR_MAX)
 *     R_MOTION   any component !(|m| <= MOTION_MAX)
 *     R_TIME     !(0 <= t <= 1)
 *     R_LENS     !(u^2 + v^2 <= LENS_R2_MAX), computed in double where the device has fp64
 *                (squares of floats are exact in double: one rounding, as NumPy does);
 *                in float otherwise (may differ from the host within an ulp of the bound)
 *     R_POSITION outside [x - POS_TOL, (x + 1) + POS_TOL] x [y - ..., ...], in float with
 *                the same roundings as NumPy's float32 comparisons
 *     R_COC      w < coc_lo: a hit whose |coc| exceeds COC_MAX (reported by the host after
 *                the coefficients, which it checks itself)
 *
 * Max and min of floats by integer atomics: non-negative IEEE floats (|coc|, |motion|)
 * order like their bit patterns read as uint, so atomic_max on the bits is a float max;
 * NaN (bits above 0x7f800000) is dropped (it would beat inf; NaN samples are reported by
 * the rules instead). Depths may be negative in an invalid frame, so they go through the
 * order-preserving key order_key(): sign bit set -> ~bits, clear -> bits | 0x80000000
 * (for non-negative depths this is the bit pattern with the top bit set).
 *
 * Work split: work-group g owns the contiguous chunk [g * WG_SIZE * ITEMS, +WG_SIZE*ITEMS).
 * CONTIGUOUS 0 (GPUs): work-item l visits chunk + k * WG_SIZE + l, k < ITEMS (neighbouring
 * work-items read neighbouring samples: coalesced). CONTIGUOUS 1 (CPUs, PoCL): work-item l
 * visits chunk + l * ITEMS + k (unit stride: the compiler vectorises the k loop). The loop
 * is counted (k < kn, kn = this work-item's samples below n): no per-sample tail test.
 * Each work-item keeps private accumulators (pure min/max/add reductions), the work-group
 * reduces them in local memory (NSLOT * WG_SIZE uints, log2(WG_SIZE) barriers) and
 * work-item s < NSLOT issues the one global atomic of slot s, only when the group's value
 * differs from the cleared one (a valid frame's rule slots cost no atomics).
 * Host launch: global size ceil(n / (WG_SIZE * ITEMS)) * WG_SIZE, local size WG_SIZE.
 *
 * Precision: coc is computed in float (c0, c1 rounded to float; the division is the
 * device's, <= 2.5 ulp); the host rounds a float64 coc to float32: a few ulp apart.
 * |motion| is length2() in float (sqrt of a sum of squares, scaled by a power of two
 * against overflow / underflow: a few ulp); the host takes a float64 sqrt.
 * Preconditions: n < 2^31 (indices, counts and group offsets fit in uint; the host refuses
 * more); W and H < 2^24 (pixel coordinates exact in float); WG_SIZE a power of two >= 32.
 * Tunables: WG_SIZE (work-group size: reqd_work_group_size and the local array), ITEMS
 * (samples per work-item), CONTIGUOUS (the visiting order above). Compile-time (set by
 * clrecon/core/inspect.py): HAS_COLOR, HAS_POSITION, HAS_LENS, HAS_TIME, HAS_MOTION (0/1),
 * MISS_DEPTH, POS_TOL, MIN_DEPTH, COLOR_MAX, MOTION_MAX (exact float literals), LENS_R2_MAX
 * (exact double literal); their defaults are in limits.h.
 */
#include "common.h"
#include "limits.h"

#ifndef WG_SIZE
#define WG_SIZE 256  // work-group size (power of two, >= NSLOT)
#endif
#ifndef ITEMS
#define ITEMS 16     // samples per work-item
#endif
#ifndef CONTIGUOUS
#define CONTIGUOUS 0 // 0: work-items interleave (GPUs); 1: each owns ITEMS in a row (CPUs)
#endif
#ifndef HAS_COLOR
#define HAS_COLOR 1
#endif
#ifndef HAS_POSITION
#define HAS_POSITION 1
#endif
#ifndef HAS_LENS
#define HAS_LENS 1
#endif
#ifndef HAS_TIME
#define HAS_TIME 1
#endif
#ifndef HAS_MOTION
#define HAS_MOTION 1
#endif

#define NRULE 7
#define R_DEPTH 0
#define R_COLOR 1
#define R_MOTION 2
#define R_TIME 3
#define R_LENS 4
#define R_POSITION 5
#define R_COC 6
#define S_FIRST 0
#define S_COUNT NRULE
#define S_COC (2 * NRULE)
#define S_MOTION (S_COC + 1)
#define S_DMIN (S_COC + 2)
#define S_DMAX (S_COC + 3)
#define S_HITS (S_COC + 4)
#define NSLOT (S_COC + 5)
#define NONE 0xffffffffu

/* rules the build checks: bit r set for rule r */
#define RULE_MASK (1 | (HAS_COLOR << R_COLOR) | (HAS_MOTION << R_MOTION) | \
                   (HAS_TIME << R_TIME) | (HAS_LENS << R_LENS) | (HAS_POSITION << R_POSITION) | \
                   (1 << R_COC))

#if (WG_SIZE & (WG_SIZE - 1)) != 0 || WG_SIZE < 32
#error "WG_SIZE must be a power of two >= 32"
#endif

#if HAS_LENS && (defined(cl_khr_fp64) || defined(__opencl_c_fp64))
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#define INSPECT_LENS_FP64 1
#else
#define INSPECT_LENS_FP64 0
#endif

/* Bits of |v| for a bit-pattern max; NaN gives 0 (never wins). */
inline uint abs_bits(float v)
{
    const uint b = as_uint(v) & 0x7fffffffu;
    return b <= 0x7f800000u ? b : 0u;
}

/* Order-preserving uint key of a non-NaN float (see the header). */
inline uint order_key(float v)
{
    const uint b = as_uint(v);
    return (b & 0x80000000u) ? ~b : (b | 0x80000000u);
}

/* Sample i of an (N, 2) / (N, 3) field by scalar loads: PoCL vectorises these across a
 * work-item's loop, not vload2/vload3 (5x slower there); on GPUs the loads of a warp
 * still fall on the same cache lines. */
inline float2 load2(__global const float *p, uint i)
{
    const size_t o = 2 * (size_t)i;
    return (float2)(p[o], p[o + 1]);
}

inline float3 load3(__global const float *p, uint i)
{
    const size_t o = 3 * (size_t)i;
    return (float3)(p[o], p[o + 1], p[o + 2]);
}

/* floor(a / d) for a < 2^31, 1 <= d < 2^31, by the host's m = ceil(2^sh / d),
 * sh = 31 + ceil(log2 d) (Granlund-Montgomery: exact for 31-bit a; m < 2^32). One wide
 * multiply instead of a division (none in hardware on GPUs, none vectorised on CPUs). */
inline uint udiv31(uint a, uint m, uint sh) { return (uint)(((ulong)a * m) >> sh); }

/* |(x, y)| in float without overflow or underflow of the squares: scale by a power of two
 * (exact) when the larger component is outside [2^-60, 2^60]. Vectorises (hypot() does
 * not on PoCL). */
inline float length2(float x, float y)
{
    const float a = fmax(fabs(x), fabs(y));
    const float s = a > 0x1p60f ? 0x1p-70f : (a < 0x1p-60f ? 0x1p100f : 1.0f);
    const float xs = x * s, ys = y * s;
    return sqrt(xs * xs + ys * ys) / s;
}

__kernel void inspect_clear(__global uint *result)
{
    const uint s = get_global_id(0);
    if (s < NSLOT)
        result[s] = (s < S_COUNT || s == S_DMIN) ? NONE : 0u;
}

/* a sample failing rule r when `cond` holds: counted, and first[r] keeps the smallest i */
#define RULE(r, cond)                                        \
    do {                                                     \
        const uint bad_ = (cond) ? 1u : 0u;                  \
        count[r] += bad_;                                    \
        first[r] = min(first[r], bad_ ? i : NONE);           \
    } while (0)

__kernel __attribute__((reqd_work_group_size(WG_SIZE, 1, 1)))
void inspect_samples(__global const float *depth, __global const float *color,
                     __global const float *position, __global const float *lens,
                     __global const float *time, __global const float *motion,
                     const uint n, const uint width, const uint width_m,
                     const uint width_sh, const uint spp_m, const uint spp_sh,
                     const float c0, const float c1, const float color_lo,
                     const float coc_lo, __global uint *result)
{
    __local uint red[NSLOT * WG_SIZE];
    const uint l = get_local_id(0);

    uint first[NRULE], count[NRULE];
    for (int r = 0; r < NRULE; ++r) {
        first[r] = NONE;
        count[r] = 0u;
    }
    uint coc_bits = 0u, motion_bits = 0u, dmin = NONE, dmax = 0u, hits = 0u;

    const uint chunk = get_group_id(0) * (uint)(WG_SIZE * ITEMS);
#if CONTIGUOUS
    const uint start = chunk + l * ITEMS, step = 1u;
#else
    const uint start = chunk + l, step = WG_SIZE;
#endif
    /* this work-item's samples below n: a counted loop, no per-sample tail test */
    const uint kn = start >= n ? 0u : min((uint)ITEMS, (n - start + step - 1u) / step);
    for (uint k = 0; k < kn; ++k) {
        const uint i = start + k * step;
        const float w = depth[i];
        RULE(R_DEPTH, !(w >= MIN_DEPTH));
        RULE(R_COC, w < coc_lo);
        const int hit = w < MISS_DEPTH;
        const float coc = hit ? c0 / w + c1 : c1;
        coc_bits = max(coc_bits, abs_bits(coc));
        const uint key = order_key(w);
        hits += hit ? 1u : 0u;
        dmin = min(dmin, hit ? key : NONE);
        dmax = max(dmax, hit ? key : 0u);
#if HAS_COLOR
        const float3 c = load3(color, i);
        /* & of the comparisons, not &&: the branches of && stop PoCL vectorising (5x) */
        RULE(R_COLOR, !((c.x >= color_lo) & (c.x <= COLOR_MAX) & (c.y >= color_lo) &
                        (c.y <= COLOR_MAX) & (c.z >= color_lo) & (c.z <= COLOR_MAX)));
#endif
#if HAS_MOTION
        const float2 m = load2(motion, i);
        RULE(R_MOTION, !((fabs(m.x) <= MOTION_MAX) & (fabs(m.y) <= MOTION_MAX)));
        motion_bits = max(motion_bits, abs_bits(length2(m.x, m.y)));
#endif
#if HAS_TIME
        const float t = time[i];
        RULE(R_TIME, !(t >= 0.0f && t <= 1.0f));
#endif
#if HAS_LENS
        const float2 uv = load2(lens, i);
#if INSPECT_LENS_FP64
        const double r2 = (double)uv.x * (double)uv.x + (double)uv.y * (double)uv.y;
        RULE(R_LENS, !(r2 <= LENS_R2_MAX));
#else
        const float r2 = uv.x * uv.x + uv.y * uv.y;
        RULE(R_LENS, !(r2 <= (float)LENS_R2_MAX));
#endif
#endif
#if HAS_POSITION
        const uint p = udiv31(i, spp_m, spp_sh);
        const uint py = udiv31(p, width_m, width_sh);
        const float fx = (float)(p - py * width), fy = (float)py;
        const float2 q = load2(position, i);
        RULE(R_POSITION, !(q.x >= fx - POS_TOL && q.x <= (fx + 1.0f) + POS_TOL &&
                           q.y >= fy - POS_TOL && q.y <= (fy + 1.0f) + POS_TOL));
#endif
    }

    for (int r = 0; r < NRULE; ++r) {
        red[(S_FIRST + r) * WG_SIZE + l] = first[r];
        red[(S_COUNT + r) * WG_SIZE + l] = count[r];
    }
    red[S_COC * WG_SIZE + l] = coc_bits;
    red[S_MOTION * WG_SIZE + l] = motion_bits;
    red[S_DMIN * WG_SIZE + l] = dmin;
    red[S_DMAX * WG_SIZE + l] = dmax;
    red[S_HITS * WG_SIZE + l] = hits;
    barrier(CLK_LOCAL_MEM_FENCE);

    for (uint s = WG_SIZE / 2; s > 0; s >>= 1) {
        if (l < s) {
            __local uint *a = red + l;
            for (int r = 0; r < NRULE; ++r) {
                if (RULE_MASK & (1 << r)) {  // constant: absent rules drop out
                    a[(S_FIRST + r) * WG_SIZE] = min(a[(S_FIRST + r) * WG_SIZE],
                                                     a[(S_FIRST + r) * WG_SIZE + s]);
                    a[(S_COUNT + r) * WG_SIZE] += a[(S_COUNT + r) * WG_SIZE + s];
                }
            }
            a[S_COC * WG_SIZE] = max(a[S_COC * WG_SIZE], a[S_COC * WG_SIZE + s]);
#if HAS_MOTION
            a[S_MOTION * WG_SIZE] = max(a[S_MOTION * WG_SIZE], a[S_MOTION * WG_SIZE + s]);
#endif
            a[S_DMIN * WG_SIZE] = min(a[S_DMIN * WG_SIZE], a[S_DMIN * WG_SIZE + s]);
            a[S_DMAX * WG_SIZE] = max(a[S_DMAX * WG_SIZE], a[S_DMAX * WG_SIZE + s]);
            a[S_HITS * WG_SIZE] += a[S_HITS * WG_SIZE + s];
        }
        barrier(CLK_LOCAL_MEM_FENCE);
    }

    /* slots not reduced above still hold work-item 0's cleared value: no atomic for them */
    if (l < NSLOT) {
        const uint v = red[l * WG_SIZE];
        volatile __global uint *dst = result + l;
        if (l < S_COUNT || l == S_DMIN) {
            if (v != NONE)
                atomic_min(dst, v);
        } else if (l == S_COC || l == S_MOTION || l == S_DMAX) {
            if (v != 0u)
                atomic_max(dst, v);
        } else if (v != 0u) {  // counts and hits
            atomic_add(dst, v);
        }
    }
}
