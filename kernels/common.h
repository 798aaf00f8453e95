/* common.h: device helpers shared by every clrecon kernel (included with -I kernels/).
 *
 * Float accumulation (scatter passes):
 *   atomic_add_f32(p, v)   float add into global memory. Uses the native fp32 atomic add
 *                          where the device offers it (cl_ext_float_atomics with the fp32
 *                          global add capability, OpenCL C >= 2.0: the host passes
 *                          -cl-std and -DCLRECON_FP32_ATOMIC_ADD=1, clrecon.core.device
 *                          language_options; or the compiler defines the feature macro
 *                          __opencl_c_ext_fp32_global_atomic_add), a compare-and-swap loop on
 *                          the bit pattern otherwise. CLRECON_NATIVE_F32_ADD says which (1/0).
 *                          Order of additions is not fixed: results may differ in the last
 *                          bits run to run.
 *   atomic_add_fixed(p, v) fixed-point accumulation into a 64-bit integer (needs
 *                          cl_khr_int64_base_atomics). Integer addition is associative, so the
 *                          sum is bit-identical run to run whatever the scheduling. Resolution
 *                          2^-FIXED_SHIFT; magnitude limit 2^(63-FIXED_SHIFT) (8.8e12 at 20).
 *                          Read back on the host with clrecon.core.device.fixed_to_float.
 * Scaled fixed point (deterministic=True of the scatter passes splat and reproject): a sum of
 * terms whose absolute values add up to less than 2^klog2 * m is accumulated in units of
 * 2^-e, e = fixed_exponent(klog2, m) = 61 - klog2 - (ilogb(m) + 1): every partial sum stays
 * below 2^61 units (int64 holds 2^63; the rest absorbs the rounding of each term, at most
 * 1/2 unit), so overflow cannot happen. Each term is rounded once to a multiple of 2^-e,
 * the sum is exact, and fixed_value converts it to the nearest float: the result differs from
 * the exact sum of the float terms by at most n / 2 units of 2^-e for n terms, plus that
 * final rounding. m is
 * clamped to >= 2^-60 and e to <= 120 (a float scale; a smaller scale only gives up
 * resolution). fixed_color_bound gathers m per colour channel: max |colour|, as uint bits
 * (the order of non-negative floats), with atomic_max, which does not depend on order either.
 * Images: pixel_index(x, y, W) (row-major), window_clip(x, y, r, W, H) (a window's pixels
 * inside the image).
 * Tunables: FIXED_SHIFT (fraction bits of atomic_add_fixed, default 20).
 */
#ifndef CLRECON_COMMON_H
#define CLRECON_COMMON_H

#ifndef FIXED_SHIFT
#define FIXED_SHIFT 20
#endif
#define FIXED_ONE ((float)(1L << FIXED_SHIFT))

#if defined(cl_khr_int64_base_atomics)
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#define CLRECON_HAS_FIXED 1
#else
#define CLRECON_HAS_FIXED 0
#endif

#if defined(__opencl_c_ext_fp32_global_atomic_add) || (defined(CLRECON_FP32_ATOMIC_ADD) \
    && CLRECON_FP32_ATOMIC_ADD && defined(__OPENCL_C_VERSION__) && __OPENCL_C_VERSION__ >= 200)
#define CLRECON_NATIVE_F32_ADD 1
#else
#define CLRECON_NATIVE_F32_ADD 0
#endif

inline void atomic_add_f32(volatile __global float *addr, float val)
{
#if CLRECON_NATIVE_F32_ADD
    atomic_fetch_add_explicit((volatile __global atomic_float *)addr, val,
                              memory_order_relaxed, memory_scope_device);
#else
    union { uint u; float f; } expected, next, seen;
    /* the first guess is read atomically too: a plain load racing with other work-items'
     * compare-and-swap is a data race in OpenCL's memory model (Oclgrind reports it) */
    seen.u = atomic_add((volatile __global uint *)addr, 0u);
    do {
        expected.u = seen.u;
        next.f = expected.f + val;
        seen.u = atomic_cmpxchg((volatile __global uint *)addr, expected.u, next.u);
    } while (seen.u != expected.u);
#endif
}

#if CLRECON_HAS_FIXED
inline long fixed_from_float(float v)
{
    return convert_long_sat_rte(v * FIXED_ONE);
}

inline void atomic_add_fixed(volatile __global long *addr, float val)
{
    atom_add(addr, fixed_from_float(val));
}

/* Exponent of the scale of sums below 2^klog2 * m (header). */
inline int fixed_exponent(int klog2, float m)
{
    return min(61 - klog2 - (ilogb(fmax(m, 0x1p-60f)) + 1), 120);
}

/* v in units of 2^-e (scale = 2^e): exact scaling, one rounding (rint: to nearest even).
 * Within the bound of fixed_exponent the integer fits: no saturating conversion needed
 * (convert_long_sat_rte gave the same images 3-10% slower on PoCL and Intel). */
inline long fixed_term(float v, float scale)
{
    return convert_long(rint(v * scale));
}

inline void atomic_add_fixed_scaled(volatile __global long *addr, float v, float scale)
{
    atom_add(addr, fixed_term(v, scale));
}

/* A sum of units of 2^-e as the nearest float (rounded once: the scaling is exact). */
inline float fixed_value(long sum, int e)
{
    return ldexp(convert_float(sum), -e);
}

/* Exponents of (r, g, b, 1): m from bound[0..2] (fixed_color_bound), 1 for weights. */
inline int4 fixed_exponents(__global const uint *bound, int klog2)
{
    return (int4)(fixed_exponent(klog2, as_float(bound[0])),
                  fixed_exponent(klog2, as_float(bound[1])),
                  fixed_exponent(klog2, as_float(bound[2])), fixed_exponent(klog2, 1.0f));
}

inline float4 fixed_scales(int4 e)
{
    return (float4)(ldexp(1.0f, e.x), ldexp(1.0f, e.y), ldexp(1.0f, e.z), ldexp(1.0f, e.w));
}

/* bound[c] = max |colour c| over n RGB triples, as uint bits (bound zeroed by the caller).
 * Launched over a global size that is a multiple of 3: work-item i takes channel i % 3 of
 * one contiguous run of the triples, then one atomic_max (2M triples, 3072 items: 7 ms on
 * PoCL, 18 ms on Intel's CPU runtime; items striding over the whole array took 60 / 28 ms,
 * each item's reads being a global size apart). */
inline void fixed_color_bound(__global const float *color, const int n,
                              volatile __global uint *bound)
{
    const size_t i = get_global_id(0), runs = get_global_size(0) / 3, c = i % 3;
    const size_t per = ((size_t)n + runs - 1) / runs, k0 = (i / 3) * per;
    const size_t k1 = min((size_t)n, k0 + per);
    float m = 0.0f;
    for (size_t k = k0; k < k1; ++k)
        m = fmax(m, fabs(color[3 * k + c]));
    atomic_max(bound + c, as_uint(m));
}
#endif

/* Pixel index of a row-major (H, W) image. */
inline int pixel_index(int x, int y, int width) { return y * width + x; }

/* The (2 r + 1)^2 window around pixel (x, y) clipped to a (height, width) image, as inclusive
 * bounds (x0, y0, x1, y1): a windowed sum visits rows y0..y1, each from x0 to x1, which is
 * the order of a loop over -r..r that skips the pixels outside. */
__attribute__((always_inline)) inline int4 window_clip(int x, int y, int r, int width,
                                                       int height)
{
    return (int4)(max(x - r, 0), max(y - r, 0), min(x + r, width - 1), min(y + r, height - 1));
}

#endif /* CLRECON_COMMON_H */
