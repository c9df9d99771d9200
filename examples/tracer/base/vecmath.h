/*
 * vecmath.h - the small amount of linear algebra a path tracer needs: 3-vectors, RGB
 * colours and orthonormal frames. Everything is a static inline function on plain structs,
 * so the compiler keeps it in registers and no file has to link anything for it.
 */
#ifndef TRACER_VECMATH_H
#define TRACER_VECMATH_H

#include <math.h>

#define PI_F 3.14159265358979323846f
#define INV_PI_F 0.31830988618379067154f

typedef struct vec3 {
    float x, y, z;
} vec3;

/* A linear RGB triple (radiance, reflectance, throughput). Kept separate from vec3 so that
 * a colour is never passed where a direction is meant. */
typedef struct rgb {
    float r, g, b;
} rgb;

static inline vec3 v3(float x, float y, float z) { vec3 v = {x, y, z}; return v; }
static inline vec3 v3_add(vec3 a, vec3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static inline vec3 v3_sub(vec3 a, vec3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static inline vec3 v3_scale(vec3 a, float s) { return v3(a.x * s, a.y * s, a.z * s); }
static inline vec3 v3_neg(vec3 a) { return v3(-a.x, -a.y, -a.z); }
static inline float v3_dot(vec3 a, vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline vec3 v3_cross(vec3 a, vec3 b)
{
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static inline float v3_length(vec3 a) { return sqrtf(v3_dot(a, a)); }
static inline vec3 v3_normalize(vec3 a)
{
    float len = v3_length(a);
    return len > 0.0f ? v3_scale(a, 1.0f / len) : a;
}
static inline float v3_max_abs(vec3 a)
{
    return fmaxf(fabsf(a.x), fmaxf(fabsf(a.y), fabsf(a.z)));
}
static inline vec3 v3_min(vec3 a, vec3 b) { return v3(fminf(a.x, b.x), fminf(a.y, b.y), fminf(a.z, b.z)); }
static inline vec3 v3_max(vec3 a, vec3 b) { return v3(fmaxf(a.x, b.x), fmaxf(a.y, b.y), fmaxf(a.z, b.z)); }
static inline int v3_is_finite(vec3 a) { return isfinite(a.x) && isfinite(a.y) && isfinite(a.z); }
/* The mirror image of `d` about the unit vector `n` (both pointing away from the surface). */
static inline vec3 v3_reflect(vec3 d, vec3 n) { return v3_sub(v3_scale(n, 2.0f * v3_dot(d, n)), d); }

static inline rgb rgb_make(float r, float g, float b) { rgb c = {r, g, b}; return c; }
static inline rgb rgb_gray(float v) { return rgb_make(v, v, v); }
static inline rgb rgb_add(rgb a, rgb b) { return rgb_make(a.r + b.r, a.g + b.g, a.b + b.b); }
static inline rgb rgb_mul(rgb a, rgb b) { return rgb_make(a.r * b.r, a.g * b.g, a.b * b.b); }
static inline rgb rgb_scale(rgb a, float s) { return rgb_make(a.r * s, a.g * s, a.b * s); }
static inline float rgb_max(rgb a) { return fmaxf(a.r, fmaxf(a.g, a.b)); }
static inline float rgb_mean(rgb a) { return (a.r + a.g + a.b) * (1.0f / 3.0f); }
static inline float rgb_luminance(rgb a) { return 0.2126f * a.r + 0.7152f * a.g + 0.0722f * a.b; }
static inline int rgb_is_black(rgb a) { return a.r == 0.0f && a.g == 0.0f && a.b == 0.0f; }
static inline int rgb_is_finite(rgb a) { return isfinite(a.r) && isfinite(a.g) && isfinite(a.b); }

/* An orthonormal frame (s, t, n). Directions in the frame's coordinates are "local": the
 * normal is +z, so cos(theta) of a local direction is simply its z component. */
typedef struct frame {
    vec3 s, t, n;
} frame;

/* The frame around a unit normal, built branch-free and without a singularity (Duff et al.,
 * "Building an Orthonormal Basis, Revisited", JCGT 2017). */
static inline frame frame_from_normal(vec3 n)
{
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    frame f;
    f.s = v3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    f.t = v3(b, sign + n.y * n.y * a, -n.y);
    f.n = n;
    return f;
}
static inline vec3 frame_to_local(const frame *f, vec3 v)
{
    return v3(v3_dot(v, f->s), v3_dot(v, f->t), v3_dot(v, f->n));
}
static inline vec3 frame_to_world(const frame *f, vec3 v)
{
    return v3_add(v3_add(v3_scale(f->s, v.x), v3_scale(f->t, v.y)), v3_scale(f->n, v.z));
}

/* Cosine-weighted direction on the +z hemisphere (Malley's method on a concentric disk
 * would be a little better stratified; the polar map is shorter and we do not stratify). */
static inline vec3 sample_cosine_hemisphere(float u0, float u1)
{
    float r = sqrtf(u0), phi = 2.0f * PI_F * u1;
    return v3(r * cosf(phi), r * sinf(phi), sqrtf(fmaxf(0.0f, 1.0f - u0)));
}
static inline float pdf_cosine_hemisphere(vec3 local) { return fmaxf(local.z, 0.0f) * INV_PI_F; }

static inline vec3 sample_uniform_sphere(float u0, float u1)
{
    float z = 1.0f - 2.0f * u0, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * PI_F * u1;
    return v3(r * cosf(phi), r * sinf(phi), z);
}

static inline float clampf(float v, float lo, float hi) { return v < lo ? lo : (v > hi ? hi : v); }

#endif /* TRACER_VECMATH_H */
