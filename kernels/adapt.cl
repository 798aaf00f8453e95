/* adapt.cl: the input adapter: interleaved sample records (a renderer's struct, or TLFR's 16
 * float32) unpacked into clrecon's structure of arrays, in one pass on the device.
 *
 * unpack_records: sample k (0 <= k < n, order y, x, sample: k = (y * W + x) * S + i) reads
 * record k and writes the fields the host asked for:
 *   rec       uint (n, STRIDE): record k at rec + k * STRIDE; field F's float32 components
 *             at rec[k * STRIDE + OFF_F + c] (offsets and stride in floats, not bytes)
 *   color     (n, 3)   position (n, 2)   depth (n)   lens (n, 2)   time (n)   motion (n, 2)
 *             float32 row-major; an output the build does not write may be a NULL argument.
 * Copies move bit patterns (uint), so every copied field is bit-exact (NaN payloads,
 * denormals, -0 included). Motion is copied the same way with MOTION_TLFR == 0; with
 * MOTION_TLFR == 1 the record holds TLFR's perspective motion mv = (mv_x, mv_y, mv_w) at
 * OFF_MOTION and the screen motion is, in float (clrecon/io/tlfr.py _tlfr_motion, there in
 * float64):
 *   w = depth, t = time, c = position - (c0 / w + c1) * lens
 *   w0 = w - t mv_w, w1 = w + (1 - t) mv_w
 *   miss (!(0 < w < 1e30): inf, >= 1e30, <= 0, NaN)  -> (0, 0)
 *   w0 <= 0 or w1 <= 0 (crosses the camera plane)     -> (NaN, NaN): the host loader raises
 *        here; a kernel cannot, so it writes non-finite motion and device validation
 *        (which flags non-finite motion) refuses the frame
 *   mv_w == 0                                         -> mv_xy / w
 *   otherwise                                         -> w (mv_xy - mv_w c) / (w0 w1),
 *        evaluated as (mv_xy - mv_w c) (w / w0) / w1 (no overflow of w0 w1 in float)
 * Launch: 1D, local size WG (required), ceil(n / (WG * ITEMS)) groups. Group g covers samples
 * [g WG ITEMS, (g + 1) WG ITEMS); in step j of ITEMS its items take WG consecutive samples,
 * so every store of a step is contiguous across the group (coalesced writes).
 * Compile-time (host, required): STRIDE, and for each field F in {COLOR, POSITION, DEPTH, LENS,
 * TIME, MOTION} of the layout OFF_F (required for the fields the build reads: an #error
 * otherwise; the others are never read); WRITE_F (0/1, default 0) for each output;
 * MOTION_TLFR (0/1, default 0; needs OFF_POSITION, OFF_DEPTH, OFF_LENS, OFF_TIME).
 * Tunables: WG (local size, default 128), ITEMS (samples per work-item, default 1), STAGE (1:
 * the group first copies its WG * ITEMS records into local memory with contiguous, coalesced
 * loads, then unpacks from there; 0: each item reads its own record from global memory;
 * default 0; needs WG * ITEMS * STRIDE * 4 bytes of local memory).
 * Preconditions: n >= 1; rec holds n * STRIDE uints; each written output holds n times its
 * component count floats; the launch covers n as above (the kernel guards the tail).
 */
#include "common.h"
#include "limits.h"

#ifndef WG
#define WG 128   // local size (required work-group size)
#endif
#ifndef ITEMS
#define ITEMS 1  // samples per work-item
#endif
#ifndef STAGE
#define STAGE 0  // 1: stage the group's records through local memory
#endif

#ifndef STRIDE
#error "adapt.cl: STRIDE (record size in floats) must be defined by the host"
#endif
#ifndef MOTION_TLFR
#define MOTION_TLFR 0
#endif
#ifndef WRITE_COLOR
#define WRITE_COLOR 0
#endif
#ifndef WRITE_POSITION
#define WRITE_POSITION 0
#endif
#ifndef WRITE_DEPTH
#define WRITE_DEPTH 0
#endif
#ifndef WRITE_LENS
#define WRITE_LENS 0
#endif
#ifndef WRITE_TIME
#define WRITE_TIME 0
#endif
#ifndef WRITE_MOTION
#define WRITE_MOTION 0
#endif

#if (WRITE_COLOR && !defined(OFF_COLOR)) || (WRITE_POSITION && !defined(OFF_POSITION)) \
    || (WRITE_DEPTH && !defined(OFF_DEPTH)) || (WRITE_LENS && !defined(OFF_LENS))    \
    || (WRITE_TIME && !defined(OFF_TIME)) || (WRITE_MOTION && !defined(OFF_MOTION))
#error "adapt.cl: a written field has no OFF_<FIELD>"
#endif
#if WRITE_MOTION && MOTION_TLFR \
    && !(defined(OFF_POSITION) && defined(OFF_DEPTH) && defined(OFF_LENS) && defined(OFF_TIME))
#error "adapt.cl: MOTION_TLFR needs OFF_POSITION, OFF_DEPTH, OFF_LENS and OFF_TIME"
#endif
/* the offsets of the fields that are not read: any value (every read of one sits behind a
 * WRITE_<FIELD> or MOTION_TLFR that is a compile-time 0) */
#ifndef OFF_COLOR
#define OFF_COLOR 0
#endif
#ifndef OFF_POSITION
#define OFF_POSITION 0
#endif
#ifndef OFF_DEPTH
#define OFF_DEPTH 0
#endif
#ifndef OFF_LENS
#define OFF_LENS 0
#endif
#ifndef OFF_TIME
#define OFF_TIME 0
#endif
#ifndef OFF_MOTION
#define OFF_MOTION 0
#endif

/* TLFR perspective motion -> linear screen motion (see the header). */
inline float2 adapt_tlfr_motion(float2 p, float w, float2 lens, float t, float3 mv, float c0,
                                float c1)
{
    if (!(w > 0.0f && w < MISS_DEPTH))
        return (float2)(0.0f);
    const float w0 = w - t * mv.z;
    const float w1 = w + (1.0f - t) * mv.z;
    if (w0 <= 0.0f || w1 <= 0.0f)
        return (float2)(NAN);
    if (mv.z == 0.0f)
        return mv.xy / w;
    const float2 c = p - (c0 / w + c1) * lens;
    /* = w (mv_xy - mv_w c) / (w0 w1); w0 w1 would overflow float beyond w ~ 1e19 and
     * underflow below w ~ 1e-19, w / w0 is near 1 */
    return (mv.xy - mv.z * c) * (w / w0) / w1;
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void unpack_records(__global const uint *restrict rec, const ulong n, const float c0,
                    const float c1, __global uint *restrict color,
                    __global uint *restrict position, __global uint *restrict depth,
                    __global uint *restrict lens, __global uint *restrict time,
                    __global uint *restrict motion)
{
    const size_t lid = get_local_id(0);
    const size_t base = get_group_id(0) * (size_t)(WG * ITEMS);
#if STAGE
    __local uint stage[WG * ITEMS * STRIDE];
    {
        const size_t count = min((size_t)(WG * ITEMS), (size_t)n - base) * STRIDE;
        __global const uint *src = rec + base * STRIDE;
        for (size_t f = lid; f < count; f += WG)
            stage[f] = src[f];
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#define REC(o) stage[r + (o)]
#else
#define REC(o) rec[r + (o)]
#endif
#define REC2(o) ((uint2)(REC(o), REC((o) + 1)))
#define REC3(o) ((uint3)(REC(o), REC((o) + 1), REC((o) + 2)))
    for (int j = 0; j < ITEMS; ++j) {
        const size_t k = base + (size_t)j * WG + lid;
        if (k >= n)
            break;
#if STAGE
        const size_t r = ((size_t)j * WG + lid) * STRIDE;
#else
        const size_t r = k * STRIDE;
#endif
        /* compile-time conditions: an output the build does not write is never touched */
        if (WRITE_COLOR)
            vstore3(REC3(OFF_COLOR), k, color);
        if (WRITE_POSITION)
            vstore2(REC2(OFF_POSITION), k, position);
        if (WRITE_DEPTH)
            depth[k] = REC(OFF_DEPTH);
        if (WRITE_LENS)
            vstore2(REC2(OFF_LENS), k, lens);
        if (WRITE_TIME)
            time[k] = REC(OFF_TIME);
        if (WRITE_MOTION && MOTION_TLFR) {
            const float2 m = adapt_tlfr_motion(
                as_float2(REC2(OFF_POSITION)), as_float(REC(OFF_DEPTH)),
                as_float2(REC2(OFF_LENS)), as_float(REC(OFF_TIME)), as_float3(REC3(OFF_MOTION)),
                c0, c1);
            vstore2(as_uint2(m), k, motion);
        } else if (WRITE_MOTION) {
            vstore2(REC2(OFF_MOTION), k, motion);
        }
    }
#undef REC
#undef REC2
#undef REC3
}
