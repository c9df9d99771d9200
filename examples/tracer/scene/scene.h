/*
 * scene.h - everything the integrator needs to know about a scene: the camera, the shapes
 * with their materials and emission, the environment, the light-selection distribution and
 * the Embree acceleration structure. scene_load.c fills it from a Mitsuba 3 XML file.
 */
#ifndef TRACER_SCENE_H
#define TRACER_SCENE_H

#include <stdint.h>

#include <embree3/rtcore.h>

#include "bsdf.h"
#include "distrib.h"
#include "error.h"
#include "image.h"
#include "medium.h"
#include "mesh.h"
#include "texture.h"
#include "transform.h"

typedef struct camera {
    vec3 origin;
    mat4 to_world;              /* camera space: +z forward, +y up, +x to the image's left */
    float tan_half_x, tan_half_y;
} camera;

typedef struct shape {
    mesh m;
    int bsdf;                   /* index into scene.bsdfs                                  */
    int emissive;               /* an area emitter: emits `radiance` on its front side      */
    rgb radiance;
    uint32_t first_light;       /* index of its first triangle in scene.lights              */
    float *tri_area;            /* emissive shapes: the area of each triangle              */
    int interior, exterior;     /* media (indices into scene.media) behind and in front of
                                 * the geometric normal; -1: vacuum. A shape that names
                                 * neither (both -1, media_boundary 0) leaves the medium of
                                 * a ray crossing it unchanged                              */
    int media_boundary;         /* names an interior or exterior medium                    */
    int null_surface;           /* the null BSDF: rays pass straight through               */
    const texture *opacity;     /* its material's mask (bsdf.opacity), for the alpha test;
                                 * NULL: opaque                                             */
} shape;

typedef enum env_kind { ENV_NONE, ENV_CONSTANT, ENV_ENVMAP } env_kind;

typedef struct environment {
    env_kind kind;
    rgb radiance;               /* ENV_CONSTANT                                             */
    image map;                  /* ENV_ENVMAP: lat-long, in its own frame (+y up)           */
    float scale;
    mat4 to_world, to_local;
    distrib2d dist;             /* ENV_ENVMAP: pixel luminance x sin(theta)                 */
} environment;

typedef struct scene {
    char *path;                 /* the XML file                                            */
    int width, height;          /* film size (the command line may override it)            */
    float fov_degrees;
    int fov_axis;               /* 0 x, 1 y, 2 diagonal, 3 smaller, 4 larger               */
    mat4 camera_to_world;
    camera cam;                 /* set by scene_set_resolution                             */
    int max_depth;              /* longest path in segments; -1: unlimited                 */
    int rr_depth;               /* the depth from which Russian roulette may stop a path   */
    int hide_emitters;
    int volumetric;             /* the integrator is volpath, which renders media; path
                                 * (Mitsuba 3's default) ignores them, as Mitsuba's does   */
    int media_ignored;          /* the scene names media that path ignores (nf_tracer says so) */
    int upgraded;               /* the file's version was < 2.0.0 (scene_upgrade.c)          */
    int upgraded_from[3];       /* that version                                            */
    char **warnings;            /* what the loader left out and why ("file:line: ..."), for
                                 * the program to print; owned                              */
    int nwarnings;

    shape *shapes;
    int nshapes;
    bsdf *bsdfs;
    int nbsdfs;
    texture **textures;         /* owned; bsdfs point into them                            */
    int ntextures;
    environment env;

    /* Participating media (scene_media.c, docs/scene-format.md "Participating media"). */
    medium *media;
    int nmedia;
    int camera_medium;          /* the sensor's medium; -1: vacuum                          */
    int has_media;              /* media or null surfaces exist: the integrator tracks the
                                 * medium along paths (0: surfaces only, as before)         */

    /* Light selection: one entry per emissive triangle (all shapes, in order), then the
     * environment if there is one. Weights: emitted power (luminance x area) of a
     * triangle; for the environment, its mean luminance times the area of a disk spanning
     * the scene (the power it can send into the scene's bounding sphere). */
    distrib1d lights;
    uint32_t nlights;
    int *light_shape;           /* the shape of each triangle entry                        */
    int has_lights;

    vec3 bounds_min, bounds_max;
    float radius;               /* of the bounding sphere                                  */

    RTCDevice device;
    RTCScene rtc;
} scene;

/* The world-space range the loader accepts (docs/scene-format.md, "Limits"): every coordinate of
 * the camera origin, of a lookat target, of every vertex after its to_world, and every entry
 * of every <transform> (so the image of the origin and of the unit vectors), after each of
 * its steps, must be finite and within +-SCENE_WORLD_LIMIT; scene_props.c's check_world()
 * is the one place that applies it.
 *
 * Why 1e9: the tracer computes the geometric normal and the area of a triangle as the
 * length of the cross product of two edges, in float. With coordinates within +-B, edge
 * components are within 2B, cross-product components within 8B^2, and its squared length
 * within 192 B^4, which stays below FLT_MAX (3.4e38) for B <= 1.15e9. Beyond that the
 * normal of a large triangle overflows to zero. Everything else the integrator forms is
 * then far inside what Embree takes (SCENE_RAY_LIMIT): ray origins within B (1 + 1e-5)
 * after the offset off the surface, distances and shadow-ray tmax within 2 sqrt(3) B,
 * squared distances within 12 B^2. */
#define SCENE_WORLD_LIMIT 1e9

/* Loads and prepares a scene (scene_load.c). On failure returns 0 with a message naming the
 * file, the line and the element. */
int scene_load(const char *path, scene *s, tr_error *err);
/* The same from a string; relative file names are resolved against `dir`. For tests. */
int scene_load_string(const char *xml, const char *dir, scene *s, tr_error *err);
void scene_free(scene *s);
/* Appends a warning (a copy of the formatted text); returns 0 when out of memory. */
int scene_warn(scene *s, const char *fmt, ...) TR_PRINTF(2, 3);

/* Sets the output resolution and the camera's field of view for it. */
void scene_set_resolution(scene *s, int width, int height);

/* After the shapes, lights and environment are in place: builds the light distribution,
 * the bounds and the Embree scene (scene.c). */
int scene_finalize(scene *s, tr_error *err);

/* ---- Queries used by the integrator ---------------------------------------------------- */

typedef struct ray {
    vec3 o, d;
    float tmax;
} ray;

/* A camera ray through the film position (px, py) in pixels (0..width, 0..height). */
ray camera_ray(const scene *s, float px, float py);

/* Embree's own limit on ray origins and directions (FLT_LARGE in its kernels/common). */
#define SCENE_RAY_LIMIT 1.844e18f

/* Whether Embree can take the ray: every origin and direction component finite and within
 * +-SCENE_RAY_LIMIT, tmax in [0, inf] (tnear is 0). This is Embree's RayK::valid(), which
 * Debian's build asserts (an invalid ray aborts the process), plus tmax >= 0, which Embree
 * documents. scene_intersect and scene_occluded assert it (debug builds) and never pass an
 * invalid ray on: intersect reports a miss, occluded reports occlusion. The integrator
 * checks before it calls them (path_stats.invalid_rays). */
int scene_ray_valid(const ray *r);

typedef struct hit {
    float t;
    int shape;
    uint32_t prim;
    float b1, b2;               /* barycentrics of vertices 1 and 2                         */
} hit;

int scene_intersect(const scene *s, const ray *r, hit *h);
int scene_occluded(const scene *s, const ray *r);

/* A ray origin pushed off a surface of unit geometric normal ng, to the side that `dir`
 * leaves towards, so that the ray does not hit the triangle it starts on. The offset,
 * SCENE_OFFSET_EPS (1 + the largest |coordinate| of p), grows with the coordinates' magnitude
 * because so does their rounding error. */
#define SCENE_OFFSET_EPS 1e-5f
vec3 scene_offset_origin(vec3 p, vec3 ng, vec3 dir);

/* A shadow ray from p towards the point p + wi dist (a light sample; dist INFINITY: the
 * direction wi, unbounded). p lies on a surface of unit geometric normal ng, or in a medium
 * (ng zero: no offset). The origin is offset off the surface (scene_offset_origin) and the
 * ray re-aimed from there, so that it ends where it must whatever the offset: short of the
 * light's point by 1e-4 of dist or by the offset at that point, whichever is larger, and
 * never inside the light that was sampled (an offset along ng moves a ray's far end by as
 * much; on a light parallel to the surface, a light sample at a grazing angle then ends
 * behind the light and is occluded by it). A light closer than that gap gives tmax 0: no
 * occluder fits between. */
void scene_shadow_ray(vec3 p, vec3 ng, vec3 wi, float dist, ray *out);

/* The transmittance along a shadow ray that starts in medium `med` (-1: vacuum) and ends at
 * r->tmax: zero when a surface other than a null one is in the way; null surfaces are
 * crossed (at most 64 of them), switching the medium as a path does (scene_medium_after).
 * After a crossing the ray goes on from just past the boundary re-aimed at the same far end
 * (r->o + r->d r->tmax), which an offset along the boundary's normal would otherwise move
 * into the light that was sampled. Heterogeneous media estimate their part by ratio tracking
 * with numbers from rn (homogeneous ones draw none). *rays counts the rays traced. Scenes
 * without media: scene_occluded's answer. */
rgb scene_transmittance(const scene *s, const ray *r, int med, rng *rn, uint64_t *rays);

/* The medium a ray travelling along d is in after crossing shape `shape` whose geometric
 * normal there is ng, coming from medium `med`: the shape's interior when d goes against
 * ng, its exterior otherwise; `med` for shapes that name no medium. */
int scene_medium_after(const scene *s, int shape, vec3 ng, vec3 d, int med);

/* The differential geometry of a hit. */
typedef struct surface {
    vec3 p;
    vec3 ng;                    /* unit geometric normal (the triangle's winding)          */
    vec3 ns;                    /* unit shading normal, on ng's side; tilted by the
                                 * material's bump map where it has one                    */
    float u, v;                 /* texture coordinates                                     */
} surface;

void scene_surface(const scene *s, const hit *h, const ray *r, surface *out);

/* Radiance arriving from the environment along direction d (from the scene outwards). */
rgb env_eval(const scene *s, vec3 d);

/* A light sample seen from point p: direction, distance, emitted radiance towards p, and the
 * solid-angle density of having chosen it (light selection included). */
typedef struct light_sample {
    vec3 wi;
    float dist;                 /* INFINITY for the environment                            */
    rgb radiance;
    float pdf;
} light_sample;

int light_sample_from(const scene *s, vec3 p, float u_pick, float u0, float u1,
                      light_sample *ls);
/* The solid-angle density with which light_sample_from would produce the point where a ray
 * from p along wi hits emissive shape `shape`, triangle `prim`, at distance t with the
 * geometric normal ng. */
float light_pdf_area(const scene *s, int shape, uint32_t prim, vec3 wi, float t, vec3 ng);
/* The same for an escaped ray hitting the environment. */
float light_pdf_env(const scene *s, vec3 wi);

#endif /* TRACER_SCENE_H */
