/* fill.cl: zero a buffer's leading bytes with a kernel.
 *
 *   fill_zero   one work-item per 16 bytes: bytes [16 i, 16 i + 16) of the first `nbytes`
 *               (a uint4 store; the item holding the end writes its bytes one by one)
 * Why a kernel rather than clEnqueueFillBuffer: PoCL 3.1's fill runs on one thread. Zeroing
 * splat's 111 MB mip images (deep 1280x720) took 13.5 ms with the fill and 6.5 ms with this
 * kernel on a 2-core Xeon (clrecon/core/fill.py).
 * Arguments: p the buffer (its start is aligned to at least 16 bytes, as every cl_mem's),
 * nbytes <= its size. No compile-time options; the local size is the runtime's.
 */
__kernel void fill_zero(__global uchar *p, const ulong nbytes)
{
    const ulong o = (ulong)get_global_id(0) * 16;
    if (o + 16 <= nbytes) {
        *(__global uint4 *)(p + o) = (uint4)(0u);
    } else {
        for (ulong b = o; b < nbytes; ++b)
            p[b] = 0;
    }
}
