/* common.h: device helpers shared by every clrecon kernel (included with -I kernels/).
 *
 * Float accumulation (scatter passes):
 *   atomic_add_f32(p, v)   float add into global memory. Uses the native fp32 atomic add
 *                          where the compiler offers it (__opencl_c_ext_fp32_global_atomic_add,
 *                          cl_ext_float_atomics), a compare-and-swap loop on the bit pattern
 *                          otherwise. Order of additions is not fixed: results may differ in
 *                          the last bits run to run.
 *   atomic_add_fixed(p, v) fixed-point accumulation into a 64-bit integer (needs
 *                          cl_khr_int64_base_atomics). Integer addition is associative, so the
 *                          sum is bit-identical run to run whatever the scheduling. Resolution
 *                          2^-FIXED_SHIFT; magnitude limit 2^(63-FIXED_SHIFT) (8.8e12 at 20).
 *                          Read back on the host with clrecon.device.fixed_to_float.
 * Tunables: FIXED_SHIFT (fraction bits, default 20).
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

inline void atomic_add_f32(volatile __global float *addr, float val)
{
#if defined(__opencl_c_ext_fp32_global_atomic_add)
    atomic_fetch_add_explicit((volatile __global atomic_float *)addr, val,
                              memory_order_relaxed, memory_scope_device);
#else
    union { uint u; float f; } expected, next, seen;
    seen.f = *addr;
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
#endif

/* Pixel index of a row-major (H, W) image. */
inline int pixel_index(int x, int y, int width) { return y * width + x; }

#endif /* CLRECON_COMMON_H */
