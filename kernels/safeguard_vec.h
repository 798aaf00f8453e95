/* safeguard_vec.h: the safeguard's window passes' vector lanes (kernels/safeguard.cl,
 * kernels/safeguard_fdr.cl): SG_VW consecutive pixels of a row a work-item as floatN
 * (SG_VW 1, 4, 8 or 16; the host passes 16 for CPUs, 1 otherwise:
 * clrecon/methods/safeguard_passes.vector_width). */
#ifndef SAFEGUARD_VEC_H
#define SAFEGUARD_VEC_H

#ifndef SG_VW
#define SG_VW 16
#endif
#define SG_CAT_(a, b) a##b
#define SG_CAT(a, b) SG_CAT_(a, b)
#if SG_VW == 1
typedef float vfloat;
typedef int vint;
#define VLOAD(p) (*(p))
#define VSTORE(v, p) (*(p) = (v))
#define CONVERT_INT(v) ((int)(v))
#define CONVERT_FLOAT(v) ((float)(v))
#define AS_FLOAT(v) as_float(v)
#define SG_LANES 0
#else
typedef SG_CAT(float, SG_VW) vfloat;
typedef SG_CAT(int, SG_VW) vint;
#define VLOAD(p) SG_CAT(vload, SG_VW)(0, p)
#define VSTORE(v, p) SG_CAT(vstore, SG_VW)(v, 0, p)
#define CONVERT_INT(v) SG_CAT(convert_int, SG_VW)(v)
#define CONVERT_FLOAT(v) SG_CAT(convert_float, SG_VW)(v)
#define AS_FLOAT(v) SG_CAT(as_float, SG_VW)(v)
#if SG_VW == 4
#define SG_LANES ((int4)(0, 1, 2, 3))
#elif SG_VW == 8
#define SG_LANES ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#elif SG_VW == 16
#define SG_LANES ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#else
#error "SG_VW must be 1, 4, 8 or 16"
#endif
#endif

/* 2^n for n <= 0, flushed to 0 below float32's normal range (n < -126): a pixel that much
 * dimmer than its window's brightest adds nothing measurable. Built from the bits, not
 * ldexp: a select that stays in lanes, where ldexp is a library call. */
__attribute__((always_inline)) inline vfloat pow2_nonpos(const vint n)
{
    return select((vfloat)(0.0f), AS_FLOAT((n + 127) << 23), n >= -126);
}

/* the histogram of the 7x7 bias means' significance (kernels/safeguard_fdr.cl): FDR_BINS
 * bins of |z| = |mu7| / se7, 1 / FDR_SCALE wide, the last holding |z| >= FDR_BINS /
 * FDR_SCALE (the host passes both: clrecon/methods/safeguard_passes.py) */
#ifndef FDR_BINS
#define FDR_BINS 256
#endif
#ifndef FDR_SCALE
#define FDR_SCALE 32
#endif

/* a 7x7 window's mean's squared standard error from its sums' means mu = sum(e) / n and
 * ee / n = sum(e^2) / n, and the mean's |z| (inf where the window shows no spread): one
 * definition for safeguard_fdr_rows and safeguard_blend, so a pixel's |z| is the same in both */
__attribute__((always_inline)) inline vfloat window_se2(const vfloat mu, const vfloat ee,
                                                        const vfloat n)
{
    return fmax(ee / n - mu * mu, 0.0f) / n;
}

__attribute__((always_inline)) inline vfloat abs_z(const vfloat mu, const vfloat se2)
{
    return select((vfloat)(INFINITY), fabs(mu) / sqrt(se2), se2 > 0.0f);
}

/* the bin of |z| >= 0 (safeguard_fdr_rows counts it, safeguard_blend looks it up) */
inline int fdr_bin(float z)
{
    return z < (float)FDR_BINS / FDR_SCALE ? (int)(z * FDR_SCALE) : FDR_BINS - 1;
}

#endif
