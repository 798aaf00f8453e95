/* sweep_order.h: the key of the sweep's front-to-back order (sweep_prepare, sweep_block; the
 * NumPy reference's clrecon/methods/sweep/reference.py: depth_order_key).
 *
 * A depth z (> 0 or inf) orders by its float bits without the DEPTH_KEY_SHIFT lowest
 * mantissa bits: positive floats order like their bits, so this is the order of the depths
 * with depths that agree in their top 24 - DEPTH_KEY_SHIFT significant bits taken as ties
 * (which keep window order, as equal depths do). The host's default 12 keeps 12 bits, a
 * relative step of 2^-11 (~5e-4: 5 mm at 10 m); 0 is the exact order (the sweep's knob
 * exact_depth_order). It is what makes sweep_block's radix sort short: the keys of a window
 * whose depths span a factor of up to 2^16 fit two 8-bit digits, where exact keys took
 * three or four.
 *   sweep_depth_key(z)    the key as a uint
 *   sweep_order_depth(z)  the depth the key leaves (its low bits cleared; inf stays inf)
 */
#ifndef CLRECON_SWEEP_ORDER_H
#define CLRECON_SWEEP_ORDER_H

#ifndef DEPTH_KEY_SHIFT
#define DEPTH_KEY_SHIFT 12
#endif
#if DEPTH_KEY_SHIFT < 0 || DEPTH_KEY_SHIFT > 20
#error "DEPTH_KEY_SHIFT: 0 (exact) to 20"
#endif

inline uint sweep_depth_key(float z)
{
    return as_uint(z) >> DEPTH_KEY_SHIFT;
}

inline float sweep_order_depth(float z)
{
    return as_float(as_uint(z) & ~((1u << DEPTH_KEY_SHIFT) - 1u));
}

#endif /* CLRECON_SWEEP_ORDER_H */
