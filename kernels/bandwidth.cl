/* bandwidth.cl: the device's streaming bandwidth, the peak the bench's per-pass GB/s are
 * compared with (clrecon/bench/bandwidth.py).
 *
 * copy_float4: dst[i] = src[i] for i < n.
 *   src, dst  float4, n elements each (the host sizes both far beyond the last-level cache)
 * One work-item per float4; the local size is left to the runtime (the peak must not
 * depend on one of our launch choices), and items past n return early should a host round
 * the range up. No arithmetic: the kernel's time is the memory system's.
 */

__kernel void copy_float4(__global const float4 *restrict src, __global float4 *restrict dst,
                          const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    dst[i] = src[i];
}
