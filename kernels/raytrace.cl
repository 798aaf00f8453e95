/* raytrace.cl: stochastic thin-lens + shutter ray tracer over analytic primitives.
 *
 * Writes sample buffers in clrecon's convention (ARCHITECTURE.md section 1) and converged
 * references. Camera space: x right, y down, z forward; lens plane z = 0; the pinhole image
 * of camera-space P is c + f * P.xy / P.z. A sample of pixel (px, py), index i, gets a sensor
 * position s = (px, py) + jitter, a lens point (u, v) in the unit disk (concentric map) and a
 * time t; its ray leaves L = R * (u, v, 0) towards the point of the focus plane z = F that
 * images at s, so that s = pinhole(P) + coc(P.z) * (u, v) with coc(w) = f R / F - f R / w.
 *
 * Objects move linearly parallel to the image plane (velocity z = 0, checked by the host):
 * position at time t = centre + (t - 0.5) * velocity, so screen motion is exactly linear,
 * motion = f * velocity.xy / w, and depth is constant over the shutter.
 *
 * Sampling: a 5D rank-1 lattice (Kronecker / R5 sequence) index i with a per-pixel random
 * Cranley-Patterson shift hashed from (seed, px, py): stratified in every 1D and 2D
 * projection for any sample count; seedable and deterministic.
 *
 * Object records: OBJ_STRIDE floats each (layout written by clrecon/scenes/primitives.py):
 *   0 type (0 sphere, 1 quad, 2 box, 3 plane), 1 texture (0 flat, 1 checker, 2 stripe),
 *   2 emission (> 0: unlit, colour a * emission), 3 texture period (world units),
 *   4-6 centre at t = 0.5, 7 sphere radius, 8-10 velocity per shutter, 11 bounding
 *   radius (INFINITY for planes), 12-14 axis e0,
 *   15 half extent h0, 16-18 e1, 19 h1, 20-22 e2 (quad/plane normal), 23 h2,
 *   24-26 colour a, 27 least depth the object reaches (0 for planes; records are sorted
 *   by it), 28-30 colour b.
 * Shading: Lambert, one directional light plus ambient, two-sided; deterministic per hit
 * point so that the only noise in a sample buffer is pixel/lens/time sampling.
 *
 * bounds: float4 per object (xmin, ymin, xmax, ymax) in pixels, from
 *   clrecon/scenes/primitives.py Scene.screen_bounds; infinite for planes and for objects
 *   reaching the lens plane.
 * Kernels (each takes objs, bounds, nobj, width, height and the camera, CAMERA_ARGS: pinhole
 * centre cx, cy and focal length f in pixels, focus distance F, lens radius R, light =
 * (direction, ambient), background = (rgb, -)):
 *   raytrace_samples: one work-item per pixel of rows [row0, row0 + global size y), samples
 *     0 .. spp - 1 of the sequence of `seed`; SoA outputs (SAMPLE_FIELDS) color (npix*S*3),
 *     position (npix*S*2), depth (npix*S), lens (npix*S*2), time (npix*S), motion (npix*S*2),
 *     index p*S + i with p = y * W + x.
 *   raytrace_reference: one work-item per pixel, samples [first, first + count) of the
 *     sequence averaged into out (npix*3).
 *   (raytrace_pinhole.cl adds the pinhole frame on the same sampler.)
 * Compile-time: MAX_CANDIDATES (objects kept per pixel after culling; default 64). The 2D
 * local size is a launch parameter only (tuned).
 */
#include "common.h"

#define OBJ_STRIDE 32
#define T_EPS 1e-6f

inline uint hash_u32(uint x)
{
    x ^= x >> 16; x *= 0x7feb352dU;
    x ^= x >> 15; x *= 0x846ca68bU;
    x ^= x >> 16;
    return x;
}

inline float u01(uint h) { return (float)(h >> 8) * (1.0f / 16777216.0f); }

/* R5 lattice: alpha_k = frac(phi^-k), phi = 1.13472... the real root of x^6 = x + 1, as
 * 32-bit fixed-point fractions so that i * alpha mod 1 is exact for any index. */
__constant uint R5_ALPHA[5] = {0xE19B01AAU, 0xC6D1D6C8U, 0xAF36D01EU, 0x9A69443FU, 0x881403B9U};

inline float lattice(uint i, int dim, uint shift)
{
    return u01(i * R5_ALPHA[dim] + shift);
}

inline float2 concentric_disk(float a, float b)
{
    float sx = 2.0f * a - 1.0f, sy = 2.0f * b - 1.0f;
    if (sx == 0.0f && sy == 0.0f)
        return (float2)(0.0f);
    float r, phi;
    if (fabs(sx) > fabs(sy)) { r = sx; phi = (M_PI_F / 4.0f) * (sy / sx); }
    else { r = sy; phi = (M_PI_F / 2.0f) - (M_PI_F / 4.0f) * (sx / sy); }
    /* native trig: the lens point is recorded as generated, so its exact value is free to
     * differ by an ulp; the clamp keeps it inside the disk whatever the rounding */
    const float2 p = r * (float2)(native_cos(phi), native_sin(phi));
    const float len2 = dot(p, p);
    return len2 > 1.0f ? p * rsqrt(len2) * 0.99999994f : p;
}

/* Nearest hit of ray o + s d (d normalised) against one object at time t.
 * Returns s (INFINITY for a miss); with full != 0 also sets the normal and texture
 * coordinates (only done again for the winning object: call sites pass a constant). */
inline float intersect(__global const float *ob, float3 o, float3 d, float t, const int full,
                       float3 *n, float3 *uvw)
{
    const int type = (int)ob[0];
    const float3 c = vload3(0, ob + 4) + (t - 0.5f) * vload3(0, ob + 8);
    const float3 e0 = vload3(0, ob + 12), e1 = vload3(0, ob + 16), e2 = vload3(0, ob + 20);
    const float h0 = ob[15], h1 = ob[19], h2 = ob[23];
    const float3 oc = o - c;
    {   /* cheap reject: the ray misses the bounding sphere (radius in slot 11) */
        const float bound = ob[11];
        const float b = dot(oc, d);
        if (dot(oc, oc) - b * b > bound * bound)
            return INFINITY;
    }
    if (type == 0) {  /* sphere */
        const float r = ob[7];
        const float b = dot(oc, d);
        const float disc = b * b - (dot(oc, oc) - r * r);
        if (disc < 0.0f) return INFINITY;
        const float q = sqrt(disc);
        float s = -b - q;
        if (s <= T_EPS) s = -b + q;
        if (s <= T_EPS) return INFINITY;
        if (!full) return s;
        const float3 p = oc + s * d;
        *n = p / r;
        *uvw = (float3)(dot(p, e0), dot(p, e1), dot(p, e2));
        return s;
    }
    if (type == 1 || type == 3) {  /* quad (bounded by h0, h1) or plane */
        const float den = dot(d, e2);
        if (den == 0.0f) return INFINITY;
        const float s = -dot(oc, e2) / den;
        if (!(s > T_EPS)) return INFINITY;
        const float3 p = oc + s * d;
        const float a = dot(p, e0), bb = dot(p, e1);
        if (type == 1 && (fabs(a) > h0 || fabs(bb) > h1)) return INFINITY;
        if (!full) return s;
        *n = e2;
        *uvw = (float3)(a, bb, 0.0f);
        return s;
    }
    /* oriented box: slabs in the local frame */
    const float3 lo = (float3)(dot(oc, e0), dot(oc, e1), dot(oc, e2));
    const float3 ld = (float3)(dot(d, e0), dot(d, e1), dot(d, e2));
    const float3 h = (float3)(h0, h1, h2);
    const float3 inv = 1.0f / ld;
    const float3 ta = (-h - lo) * inv, tb = (h - lo) * inv;
    const float3 tn = fmin(ta, tb), tf = fmax(ta, tb);
    const float snear = fmax(fmax(tn.x, tn.y), tn.z);
    const float sfar = fmin(fmin(tf.x, tf.y), tf.z);
    if (!(snear <= sfar) || sfar <= T_EPS) return INFINITY;
    const float s = snear > T_EPS ? snear : sfar;
    if (!full) return s;
    const float3 p = lo + s * ld;
    /* the face hit is the axis whose slab bound was reached */
    const float3 rel = fabs(p) / h;
    if (rel.x >= rel.y && rel.x >= rel.z) { *n = e0; *uvw = (float3)(p.y, p.z, 0.0f); }
    else if (rel.y >= rel.z) { *n = e1; *uvw = (float3)(p.x, p.z, 0.0f); }
    else { *n = e2; *uvw = (float3)(p.x, p.y, 0.0f); }
    return s;
}

inline float3 shade(__global const float *ob, float3 n, float3 uvw, float3 d,
                    float3 light, float ambient)
{
    const float3 a = vload3(0, ob + 24), b = vload3(0, ob + 28);
    const float emission = ob[2];
    const int tex = (int)ob[1];
    float3 albedo = a;
    if (tex != 0) {
        const float3 cell = floor(uvw / ob[3]);
        const int k = tex == 1 ? (int)(cell.x + cell.y + cell.z) : (int)cell.x;
        albedo = (k & 1) ? b : a;
    }
    if (emission > 0.0f)
        return albedo * emission;
    if (dot(n, d) > 0.0f) n = -n;  /* two-sided */
    return albedo * (ambient + (1.0f - ambient) * fmax(0.0f, dot(n, light)));
}

typedef struct {
    float3 color;
    float2 pos, lens, motion;
    float depth, time;
} sample_t;

/* The per-pixel Cranley-Patterson shifts of the 5 lattice dimensions. */
inline void pixel_shifts(int px, int py, uint seed, uint shift[5])
{
    shift[0] = hash_u32(seed ^ hash_u32((uint)px * 0x9E3779B1U ^ hash_u32((uint)py)));
    for (int k = 1; k < 5; ++k)
        shift[k] = hash_u32(shift[k - 1] + 0x632BE5ABU);
}

/* The sample fields a tracing kernel writes (SoA, ARCHITECTURE.md section 1): one parameter
 * list for every writer (a kernel's parameters cannot come from a function). */
#define SAMPLE_FIELDS __global float *color, __global float *position, __global float *depth, \
    __global float *lens, __global float *time, __global float *motion
#define SAMPLE_FIELDS_PASS color, position, depth, lens, time, motion

/* The camera and light of every tracing kernel: pinhole centre (cx, cy) and focal length
 * (px), focus distance, lens radius, light = (direction toward the light, ambient),
 * background = (rgb, unused); CAMERA_PASS hands them to trace(). */
#define CAMERA_ARGS const float cx, const float cy, const float focal, const float focus, \
    const float lens_radius, const float4 light, const float4 background
#define CAMERA_PASS cx, cy, focal, focus, lens_radius, light.xyz, light.w, background.xyz

/* Sample s into index k of the sample fields. */
__attribute__((always_inline)) inline void store_sample(const sample_t *s, size_t k, SAMPLE_FIELDS)
{
    vstore3(s->color, k, color);
    vstore2(s->pos, k, position);
    depth[k] = s->depth;
    vstore2(s->lens, k, lens);
    time[k] = s->time;
    vstore2(s->motion, k, motion);
}

#ifndef MAX_CANDIDATES
#define MAX_CANDIDATES 64  // objects kept per pixel after screen-space culling
#endif

/* Objects whose screen bounds (pinhole footprint over the shutter, grown by the largest
 * |CoC| over their depth range: a conservative superset of where any sample can see them)
 * touch pixel (px, py). Returns the count; -1 when more than MAX_CANDIDATES (test all). */
inline int pixel_candidates(__global const float4 *bounds, int nobj, int px, int py,
                            uchar cand[MAX_CANDIDATES])
{
    int n = 0;
    for (int k = 0; k < nobj; ++k) {
        const float4 b = bounds[k];
        if (b.x <= px + 1 && b.z >= px && b.y <= py + 1 && b.w >= py) {
            if (n == MAX_CANDIDATES || k > 255) return -1;
            cand[n++] = (uchar)k;
        }
    }
    return n;
}

/* What every sample of pixel (px, py) shares: its lattice shifts and candidate objects. */
typedef struct {
    int px, py;
    uint shift[5];
    int ncand;  /* -1: every object (pixel_candidates) */
    uchar cand[MAX_CANDIDATES];
} pixel_t;

__attribute__((always_inline)) inline void pixel_setup(
    __private pixel_t *pix, __global const float4 *bounds, int nobj, int px, int py, uint seed)
{
    pix->px = px;
    pix->py = py;
    pixel_shifts(px, py, seed, pix->shift);
    pix->ncand = pixel_candidates(bounds, nobj, px, py, pix->cand);
}

/* Sample i of pixel pix's sequence. */
inline sample_t trace(__global const float *objs, int nobj, __private const pixel_t *pix, uint i,
                      float cx, float cy, float focal, float focus, float lens_radius,
                      float3 light, float ambient, float3 background)
{
    const int px = pix->px, py = pix->py, ncand = pix->ncand;
    const uint *shift = pix->shift;
    const uchar *cand = pix->cand;
    sample_t s;
    s.pos = (float2)(px + lattice(i, 0, shift[0]), py + lattice(i, 1, shift[1]));
    /* keep the position strictly inside the pixel whatever the rounding */
    s.pos = fmin(s.pos, (float2)(px, py) + 0.99999994f);
    s.lens = concentric_disk(lattice(i, 2, shift[2]), lattice(i, 3, shift[3]));
    s.time = lattice(i, 4, shift[4]);
    const float3 o = (float3)(lens_radius * s.lens, 0.0f);
    const float3 q = (float3)((s.pos.x - cx) * (focus / focal), (s.pos.y - cy) * (focus / focal),
                              focus);
    const float3 d = normalize(q - o);
    float best = INFINITY;
    int hit = -1;
    float3 n = (float3)(0.0f), uvw = (float3)(0.0f);
    const int count = ncand < 0 ? nobj : ncand;
    for (int j = 0; j < count; ++j) {
        const int k = ncand < 0 ? j : cand[j];
        __global const float *ob = objs + k * OBJ_STRIDE;
        /* objects come nearest-first (slot 27: the least depth any part of them reaches):
         * once the best hit is in front of the next object, no later one can beat it */
        if (best * d.z < ob[27])
            break;
        const float sk = intersect(ob, o, d, s.time, 0, &n, &uvw);
        if (sk < best) { best = sk; hit = k; }
    }
    if (hit >= 0)
        intersect(objs + hit * OBJ_STRIDE, o, d, s.time, 1, &n, &uvw);
    if (hit < 0) {
        s.color = background;
        s.depth = INFINITY;
        s.motion = (float2)(0.0f);
    } else {
        __global const float *ob = objs + hit * OBJ_STRIDE;
        s.color = shade(ob, n, uvw, d, light, ambient);
        s.depth = best * d.z;
        s.motion = focal * vload2(0, ob + 8) / s.depth;
    }
    return s;
}

/* Intel's CPU compiler (pip's intel-opencl-rt 2026.2.0, driver 2026.22.10) miscompiles both
 * kernels below when its vectorizer packs work-items into SIMD lanes: the float3 colours carried
 * through the sample loop come back shuffled between lanes, and lanes 6-7 of an 8-wide group
 * read past the packed values (garbage such as -1e30, different from run to run). Nothing
 * here reads an unset value or relies on undefined behaviour (PoCL, Oclgrind and the NumPy
 * tracer agree); -cl-opt-disable builds it right, and so does the hint below, which keeps
 * one work-item per lane for these kernels alone. Passing the background as float4 instead
 * only moved the fault to hit pixels. The hint cost no speed where measured (fence 160x120
 * at 32 spp: 84 ms, the wrong vectorised build 152 ms). tests/unit/test_trusted_reference.py
 * checks this kernel against the NumPy tracer on every device. */
#ifdef cl_intel_vec_len_hint
#define REFERENCE_VEC_HINT __attribute__((intel_vec_len_hint(1)))
#else
#define REFERENCE_VEC_HINT
#endif

REFERENCE_VEC_HINT
__kernel void raytrace_samples(__global const float *objs, __global const float4 *bounds,
                               const int nobj, const int width, const int height,
                               const int spp, const int row0, const uint seed, CAMERA_ARGS,
                               SAMPLE_FIELDS)
{
    const int px = get_global_id(0), py = get_global_id(1) + row0;
    if (px >= width || py >= height)
        return;
    pixel_t pix;
    pixel_setup(&pix, bounds, nobj, px, py, seed);
    const size_t base = (size_t)pixel_index(px, py, width) * spp;
    for (int i = 0; i < spp; ++i) {
        const sample_t s = trace(objs, nobj, &pix, (uint)i, CAMERA_PASS);
        store_sample(&s, base + i, SAMPLE_FIELDS_PASS);
    }
}

REFERENCE_VEC_HINT
__kernel void raytrace_reference(__global const float *objs, __global const float4 *bounds,
                                 const int nobj, const int width, const int height,
                                 const uint first, const uint count, const uint seed,
                                 CAMERA_ARGS, __global float *out)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    pixel_t pix;
    pixel_setup(&pix, bounds, nobj, px, py, seed);
    float3 sum = (float3)(0.0f);
    for (uint i = first; i < first + count; ++i) {
        const sample_t s = trace(objs, nobj, &pix, i, CAMERA_PASS);
        sum += s.color;
    }
    vstore3(sum / (float)count, pixel_index(px, py, width), out);
}
