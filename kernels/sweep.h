/* sweep.h: what the passes of method `sweep` (Shirley et al. 2011) share: the defaults of
 * their compile-time options and the radius of the widest box.
 *
 * Compile-time (the host sets each pass's own: clrecon/methods/sweep/):
 *   SPP            samples per pixel
 *   SCALES         2 (Appendix A: 1x1 and 5x5 boxes blended) or 4 (Appendix B: 1, 3, 5, 7)
 *   SMOOTH_MOTION  0/1: the denoising diameter D takes |motion| into account
 *   EXPONENT, EXPONENT_ON  the paper's 1.3 variant (weights raised to EXPONENT; the host sets
 *                  EXPONENT_ON = 1 when EXPONENT != 1)
 * Derived: R = 2 or 3, the half side of the widest box ((2 R + 1)^2 pixels: a pixel's window).
 */
#ifndef CLRECON_SWEEP_H
#define CLRECON_SWEEP_H

#include "common.h"

#ifndef SPP
#define SPP 16
#endif
#ifndef SCALES
#define SCALES 2
#endif
#ifndef SMOOTH_MOTION
#define SMOOTH_MOTION 1
#endif
#ifndef EXPONENT
#define EXPONENT 1.0f
#endif
#ifndef EXPONENT_ON
#define EXPONENT_ON 0
#endif

#if SCALES == 2
#define R 2
#else
#define R 3
#endif

#endif /* CLRECON_SWEEP_H */
