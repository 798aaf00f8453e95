/* limits.h: the value limits of a frame of samples, the kernels' copy of
 * clrecon/core/limits.py (tests/unit/test_kernel_limits.py checks that the two agree).
 *
 * MISS_DEPTH  depth at or beyond which a sample is a miss (float32(1e30))
 * POS_TOL, LENS_R2_MAX, MIN_DEPTH, COLOR_MAX, MOTION_MAX  the validation bounds that
 *             kernels/inspect.cl checks (exact float literals; LENS_R2_MAX a double)
 * Each is a default: the host may pass its own with -D (clrecon/core/inspect.py passes
 * every one, from clrecon/core/limits.py).
 */
#ifndef CLRECON_LIMITS_H
#define CLRECON_LIMITS_H

#ifndef MISS_DEPTH
#define MISS_DEPTH 0x1.93e594p+99f        // float32(1e30)
#endif
#ifndef POS_TOL
#define POS_TOL 0x1.a36e2ep-14f           // float32(1e-4), POSITION_TOLERANCE
#endif
#ifndef LENS_R2_MAX
#define LENS_R2_MAX 0x1.000d1b9c68abep+0  // (1 + 1e-4)^2 in double, LENS_TOLERANCE
#endif
#ifndef MIN_DEPTH
#define MIN_DEPTH 0x1.79ca1p-67f          // float32(1e-20)
#endif
#ifndef COLOR_MAX
#define COLOR_MAX 0x1.93e594p+99f         // float32(1e30)
#endif
#ifndef MOTION_MAX
#define MOTION_MAX 0x1p+16f               // 2^16
#endif

#endif
