/* vec_hint.h: SCALAR_WORK_ITEMS, a kernel attribute asking Intel's CPU OpenCL compiler not to
 * vectorise across work-items.
 *
 * Intel's CPU runtime packs several work-items into the lanes of one SIMD register
 * (implicit vectorisation). A kernel written in float4/float16 lanes already, or one that
 * keeps per-item private arrays (sorts, accumulator tables) or leaves most items idle (a
 * merge by one item of the group), is widened a second time: its vectors become wide
 * shuffles and its private arrays gathers and scatters. filter_sheared_y took 615-648 ms
 * there against PoCL's 50 ms (320x180, 16 spp, synthetic frame), and 24 ms with
 * intel_vec_len_hint(1), which keeps one work-item per kernel invocation and the kernel's
 * own vectors as written. Kernels get the attribute only where it measured faster on
 * Intel's runtime (filter_sheared_y, filter_mip_build and _sample, sweep_prepare, both
 * sweep_resolve kernels, sweep_layer_sums, integrate_up); the others are as fast or faster
 * vectorised across items (box, sweep_block, filter_rotated, the 1D layered passes).
 *
 * The attribute exists exactly where the compiler defines the extension macro
 * cl_intel_vec_len_hint: Intel's CPU runtime. PoCL and Oclgrind define neither and would
 * warn about an unknown attribute; there it expands to nothing.
 */
#ifndef CLRECON_VEC_HINT_H
#define CLRECON_VEC_HINT_H

#ifdef cl_intel_vec_len_hint
#define SCALAR_WORK_ITEMS __attribute__((intel_vec_len_hint(1)))
#else
#define SCALAR_WORK_ITEMS
#endif

#endif /* CLRECON_VEC_HINT_H */
