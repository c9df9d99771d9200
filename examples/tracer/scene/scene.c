/*
 * scene.c - the parts of a scene that exist at render time: the Embree scene, hit geometry,
 * the camera, the environment and light sampling. Loading lives in scene_load.c.
 */
#include "scene.h"

#include <assert.h>
#include <stdarg.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- Life cycle ------------------------------------------------------------------------- */

void scene_free(scene *s)
{
    if (s->rtc)
        rtcReleaseScene(s->rtc);
    if (s->device)
        rtcReleaseDevice(s->device);
    for (int i = 0; i < s->nshapes; ++i) {
        mesh_free(&s->shapes[i].m);
        free(s->shapes[i].tri_area);
    }
    free(s->shapes);
    free(s->bsdfs);
    for (int i = 0; i < s->nmedia; ++i)
        medium_free(&s->media[i]);
    free(s->media);
    for (int i = 0; i < s->ntextures; ++i) {
        texture_free(s->textures[i]);
        free(s->textures[i]);
    }
    free(s->textures);
    image_free(&s->env.map);
    distrib2d_free(&s->env.dist);
    distrib1d_free(&s->lights);
    free(s->light_shape);
    free(s->path);
    for (int i = 0; i < s->nwarnings; ++i)
        free(s->warnings[i]);
    free(s->warnings);
    memset(s, 0, sizeof *s);
}

int scene_warn(scene *s, const char *fmt, ...)
{
    char text[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    char **grown = realloc(s->warnings, (size_t)(s->nwarnings + 1) * sizeof *grown);
    if (!grown)
        return 0;
    s->warnings = grown;
    size_t n = strlen(text) + 1;
    if (!(s->warnings[s->nwarnings] = malloc(n)))
        return 0;
    memcpy(s->warnings[s->nwarnings++], text, n);
    return 1;
}

void scene_set_resolution(scene *s, int width, int height)
{
    s->width = width;
    s->height = height;
    float t = tanf(0.5f * s->fov_degrees * PI_F / 180.0f);
    float w = (float)width, h = (float)height, diag = sqrtf(w * w + h * h);
    int axis = s->fov_axis;
    if (axis == 3)
        axis = width <= height ? 0 : 1; /* "smaller": the fov spans the shorter side */
    else if (axis == 4)
        axis = width >= height ? 0 : 1; /* "larger" */
    switch (axis) {
    case 1:
        s->cam.tan_half_y = t;
        s->cam.tan_half_x = t * w / h;
        break;
    case 2:
        s->cam.tan_half_x = t * w / diag;
        s->cam.tan_half_y = t * h / diag;
        break;
    default:
        s->cam.tan_half_x = t;
        s->cam.tan_half_y = t * h / w;
        break;
    }
    s->cam.to_world = s->camera_to_world;
    s->cam.origin = mat4_point(&s->camera_to_world, v3(0.0f, 0.0f, 0.0f));
}

/* ---- Finalization: lights, bounds, Embree ------------------------------------------------ */

static void embree_error(void *user, enum RTCError code, const char *msg)
{
    char *buf = user;
    snprintf(buf, 256, "Embree error %d: %s", (int)code, msg ? msg : "");
}

static char embree_message[256];

static int build_environment_distribution(environment *env, tr_error *err)
{
    size_t w = (size_t)env->map.width, h = (size_t)env->map.height;
    double *weights = malloc(w * h * sizeof *weights);
    if (!weights)
        return tr_fail(err, "out of memory");
    for (size_t y = 0; y < h; ++y) {
        double sin_theta = sin(3.14159265358979 * ((double)y + 0.5) / (double)h);
        for (size_t x = 0; x < w; ++x) {
            const float *p = image_pixel(&env->map, (int)x, (int)y);
            weights[y * w + x] = rgb_luminance(rgb_make(p[0], p[1], p[2])) * sin_theta;
        }
    }
    int ok = distrib2d_init(&env->dist, weights, w, h);
    free(weights);
    if (!ok)
        return tr_fail(err, "the environment map is black everywhere");
    return 1;
}

/* Mean radiance luminance of the environment over the sphere of directions. */
static double environment_mean_luminance(const environment *env)
{
    if (env->kind == ENV_CONSTANT)
        return rgb_luminance(env->radiance);
    double sum = 0.0, wsum = 0.0;
    for (int y = 0; y < env->map.height; ++y) {
        double sin_theta = sin(3.14159265358979 * ((double)y + 0.5) / env->map.height);
        for (int x = 0; x < env->map.width; ++x) {
            const float *p = image_pixel(&env->map, x, y);
            sum += rgb_luminance(rgb_make(p[0], p[1], p[2])) * sin_theta;
            wsum += sin_theta;
        }
    }
    return wsum > 0.0 ? env->scale * sum / wsum : 0.0;
}

/* ---- Masks -------------------------------------------------------------------------------- */

static uint64_t mix64(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xbf58476d1ce4e5b9ull;
    x ^= x >> 27;
    x *= 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

/* Field k of ray or hit i in Embree's structure-of-arrays packets (RTCRayN, RTCHitN: N
 * values of each field of RTCRay and RTCHit in turn); the C API has no accessors. */
static float soa_float(const void *packet, unsigned n, unsigned k, unsigned i)
{
    float f;
    memcpy(&f, (const char *)packet + (k * n + i) * sizeof f, sizeof f);
    return f;
}

static unsigned soa_uint(const void *packet, unsigned n, unsigned k, unsigned i)
{
    unsigned u;
    memcpy(&u, (const char *)packet + (k * n + i) * sizeof u, sizeof u);
    return u;
}

static uint32_t float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

/* The mask BSDF as an alpha test: a ray meets a masked surface with the probability of its
 * opacity and otherwise goes on as if it were not there, camera rays, scattered rays and
 * shadow rays alike. The random number is a hash of the ray and the triangle, so that the
 * test needs no state and the same ray always gets the same answer (pbrt-v4 does the same);
 * over the renderer's random rays it is uniform, which keeps every estimate unbiased.
 * Mitsuba 3 treats the transparent part as a null BSDF instead (a delta event of the path,
 * opaque to shadow rays): the same image, other noise. */
static void opacity_filter(const struct RTCFilterFunctionNArguments *args)
{
    const shape *sh = args->geometryUserPtr;
    for (unsigned i = 0; i < args->N; ++i) {
        if (!args->valid[i])
            continue;
        const unsigned prim = soa_uint(args->hit, args->N, 5, i);
        const float b1 = soa_float(args->hit, args->N, 3, i);
        const float b2 = soa_float(args->hit, args->N, 4, i);
        float u, v;
        mesh_uv_at(&sh->m, prim, b1, b2, &u, &v);
        const float a = texture_eval_opacity(sh->opacity, u, v);
        if (a >= 1.0f)
            continue;
        uint64_t h = mix64(((uint64_t)float_bits(soa_float(args->ray, args->N, 0, i)) << 32) ^
                           float_bits(soa_float(args->ray, args->N, 1, i)));
        h = mix64(h ^ ((uint64_t)float_bits(soa_float(args->ray, args->N, 2, i)) << 32) ^
                  float_bits(soa_float(args->ray, args->N, 4, i)));
        h = mix64(h ^ ((uint64_t)float_bits(soa_float(args->ray, args->N, 5, i)) << 32) ^
                  float_bits(soa_float(args->ray, args->N, 6, i)));
        h = mix64(h ^ prim);
        const float xi = (float)(h >> 40) * (1.0f / 16777216.0f);
        if (!(xi < a))
            args->valid[i] = 0;
    }
}

int scene_finalize(scene *s, tr_error *err)
{
    /* Bounds. */
    vec3 lo = v3(INFINITY, INFINITY, INFINITY), hi = v3(-INFINITY, -INFINITY, -INFINITY);
    for (int i = 0; i < s->nshapes; ++i)
        for (uint32_t v = 0; v < s->shapes[i].m.nverts; ++v) {
            lo = v3_min(lo, s->shapes[i].m.p[v]);
            hi = v3_max(hi, s->shapes[i].m.p[v]);
        }
    if (s->nshapes == 0) {
        lo = v3(-1.0f, -1.0f, -1.0f);
        hi = v3(1.0f, 1.0f, 1.0f);
    }
    s->bounds_min = lo;
    s->bounds_max = hi;
    s->radius = fmaxf(0.5f * v3_length(v3_sub(hi, lo)), 1e-3f);

    if (s->env.kind == ENV_ENVMAP && !build_environment_distribution(&s->env, err))
        return 0;

    /* Light selection. */
    uint32_t n = 0;
    for (int i = 0; i < s->nshapes; ++i)
        if (s->shapes[i].emissive)
            n += s->shapes[i].m.ntris;
    int with_env = s->env.kind != ENV_NONE;
    double *weights = malloc(((size_t)n + 1) * sizeof *weights);
    s->light_shape = malloc(((size_t)n + 1) * sizeof *s->light_shape);
    if (!weights || !s->light_shape) {
        free(weights);
        return tr_fail(err, "out of memory");
    }
    uint32_t k = 0;
    for (int i = 0; i < s->nshapes; ++i) {
        shape *sh = &s->shapes[i];
        if (!sh->emissive)
            continue;
        sh->first_light = k;
        sh->tri_area = malloc(sh->m.ntris * sizeof *sh->tri_area + 1);
        if (!sh->tri_area) {
            free(weights);
            return tr_fail(err, "out of memory");
        }
        for (uint32_t t = 0; t < sh->m.ntris; ++t) {
            const uint32_t *id = sh->m.idx + 3 * t;
            vec3 c = v3_cross(v3_sub(sh->m.p[id[1]], sh->m.p[id[0]]),
                              v3_sub(sh->m.p[id[2]], sh->m.p[id[0]]));
            sh->tri_area[t] = 0.5f * v3_length(c);
            s->light_shape[k] = i;
            weights[k++] = (double)rgb_luminance(sh->radiance) * sh->tri_area[t];
        }
    }
    if (with_env)
        weights[k++] = environment_mean_luminance(&s->env) * 3.14159265358979 *
                       3.14159265358979 * (double)s->radius * (double)s->radius;
    s->nlights = k;
    s->has_lights = k > 0 && distrib1d_init(&s->lights, weights, k);
    free(weights);

    /* Embree: one triangle geometry per shape, its ID equal to the shape's index. The
     * buffers are shared, not copied: the meshes outlive the Embree scene. */
    embree_message[0] = '\0';
    s->device = rtcNewDevice(NULL);
    if (!s->device)
        return tr_fail(err, "cannot create an Embree device");
    rtcSetDeviceErrorFunction(s->device, embree_error, embree_message);
    s->rtc = rtcNewScene(s->device);
    rtcSetSceneBuildQuality(s->rtc, RTC_BUILD_QUALITY_HIGH);
    for (int i = 0; i < s->nshapes; ++i) {
        const mesh *m = &s->shapes[i].m;
        RTCGeometry g = rtcNewGeometry(s->device, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, m->p, 0,
                                   sizeof(vec3), m->nverts);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, m->idx, 0,
                                   3 * sizeof(uint32_t), m->ntris);
        s->shapes[i].opacity = s->bsdfs[s->shapes[i].bsdf].opacity;
        if (s->shapes[i].opacity) {
            rtcSetGeometryUserData(g, &s->shapes[i]);
            rtcSetGeometryIntersectFilterFunction(g, opacity_filter);
            rtcSetGeometryOccludedFilterFunction(g, opacity_filter);
        }
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(s->rtc, g, (unsigned)i);
        rtcReleaseGeometry(g);
    }
    rtcCommitScene(s->rtc);
    if (embree_message[0] || rtcGetDeviceError(s->device) != RTC_ERROR_NONE)
        return tr_fail(err, "building the Embree scene failed: %s", embree_message);
    return 1;
}

/* ---- Rays --------------------------------------------------------------------------------- */

ray camera_ray(const scene *s, float px, float py)
{
    /* Camera space: +x is the image's left, +y its top. */
    float x = (1.0f - 2.0f * px / (float)s->width) * s->cam.tan_half_x;
    float y = (1.0f - 2.0f * py / (float)s->height) * s->cam.tan_half_y;
    ray r;
    r.o = s->cam.origin;
    r.d = v3_normalize(mat4_vector(&s->cam.to_world, v3(x, y, 1.0f)));
    r.tmax = INFINITY;
    return r;
}

/* NaN fails both comparisons. */
static int within_ray_limit(float v)
{
    return fabsf(v) <= SCENE_RAY_LIMIT;
}

int scene_ray_valid(const ray *r)
{
    return within_ray_limit(r->o.x) && within_ray_limit(r->o.y) && within_ray_limit(r->o.z) &&
           within_ray_limit(r->d.x) && within_ray_limit(r->d.y) && within_ray_limit(r->d.z) &&
           r->tmax >= 0.0f;
}

int scene_intersect(const scene *s, const ray *r, hit *h)
{
    /* The loader's world range (SCENE_WORLD_LIMIT) keeps every ray the integrator forms
     * valid; should one not be, it must not reach Embree, which would abort. */
    assert(scene_ray_valid(r));
    if (!scene_ray_valid(r))
        return 0;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRayHit rh;
    memset(&rh, 0, sizeof rh);
    rh.ray.org_x = r->o.x;
    rh.ray.org_y = r->o.y;
    rh.ray.org_z = r->o.z;
    rh.ray.dir_x = r->d.x;
    rh.ray.dir_y = r->d.y;
    rh.ray.dir_z = r->d.z;
    rh.ray.tnear = 0.0f;
    rh.ray.tfar = r->tmax;
    rh.ray.mask = 0xffffffffu;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(s->rtc, &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID)
        return 0;
    h->t = rh.ray.tfar;
    h->shape = (int)rh.hit.geomID;
    h->prim = rh.hit.primID;
    h->b1 = rh.hit.u;
    h->b2 = rh.hit.v;
    return 1;
}

int scene_occluded(const scene *s, const ray *r)
{
    assert(scene_ray_valid(r));
    if (!scene_ray_valid(r))
        return 1; /* nothing is known to be visible along it: no light arrives */
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    struct RTCRay ry;
    memset(&ry, 0, sizeof ry);
    ry.org_x = r->o.x;
    ry.org_y = r->o.y;
    ry.org_z = r->o.z;
    ry.dir_x = r->d.x;
    ry.dir_y = r->d.y;
    ry.dir_z = r->d.z;
    ry.tnear = 0.0f;
    ry.tfar = r->tmax;
    ry.mask = 0xffffffffu;
    rtcOccluded1(s->rtc, &ctx, &ry);
    return ry.tfar < 0.0f; /* Embree sets tfar to -inf when something is in the way */
}

/* Mitsuba 3's bumpmap: the height's gradient g moves each tangent along the normal,
 * dp/du + n (g_u - n . dp/du) and likewise for v, and the tilted normal is their cross
 * product, turned to the geometric normal's side. A tilt that cannot be formed (degenerate
 * tangents, non-finite heights) keeps the normal it had. */
static vec3 bumped_normal(const bsdf *b, const mesh *m, uint32_t tri, const surface *sf)
{
    float g[2];
    texture_eval_gradient(b->bump, sf->u, sf->v, g);
    vec3 dp_du, dp_dv, n = sf->ns;
    mesh_uv_tangents(m, tri, &dp_du, &dp_dv);
    if (v3_dot(dp_du, dp_du) == 0.0f || v3_dot(dp_dv, dp_dv) == 0.0f) {
        frame f = frame_from_normal(n); /* Mitsuba's fallback: any frame around n */
        dp_du = f.s;
        dp_dv = f.t;
    }
    dp_du = v3_add(dp_du, v3_scale(n, b->bump_scale * g[0] - v3_dot(n, dp_du)));
    dp_dv = v3_add(dp_dv, v3_scale(n, b->bump_scale * g[1] - v3_dot(n, dp_dv)));
    vec3 c = v3_cross(dp_du, dp_dv);
    float len2 = v3_dot(c, c);
    if (!(len2 > 0.0f) || !isfinite(len2))
        return n;
    c = v3_normalize(c);
    return v3_dot(c, sf->ng) < 0.0f ? v3_neg(c) : c;
}

void scene_surface(const scene *s, const hit *h, const ray *r, surface *out)
{
    const mesh *m = &s->shapes[h->shape].m;
    const uint32_t *id = m->idx + 3 * h->prim;
    float b0 = 1.0f - h->b1 - h->b2;
    vec3 p0 = m->p[id[0]], p1 = m->p[id[1]], p2 = m->p[id[2]];
    /* From the barycentrics rather than o + t d: more accurate far from the origin. */
    out->p = v3_add(v3_add(v3_scale(p0, b0), v3_scale(p1, h->b1)), v3_scale(p2, h->b2));
    (void)r;
    out->ng = v3_normalize(v3_cross(v3_sub(p1, p0), v3_sub(p2, p0)));
    if (m->n) {
        vec3 n = v3_add(v3_add(v3_scale(m->n[id[0]], b0), v3_scale(m->n[id[1]], h->b1)),
                        v3_scale(m->n[id[2]], h->b2));
        out->ns = v3_dot(n, n) > 0.0f ? v3_normalize(n) : out->ng;
        /* The winding decides the front side (emitters and one-sided materials depend on
         * it); a vertex normal pointing the other way is turned to that side. */
        if (v3_dot(out->ns, out->ng) < 0.0f)
            out->ns = v3_neg(out->ns);
    } else {
        out->ns = out->ng;
    }
    mesh_uv_at(m, h->prim, h->b1, h->b2, &out->u, &out->v);
    const int bi = s->shapes[h->shape].bsdf;
    if (bi >= 0 && s->bsdfs[bi].bump)
        out->ns = bumped_normal(&s->bsdfs[bi], m, h->prim, out);
}

/* ---- Environment ---------------------------------------------------------------------------- */

/* Mitsuba's lat-long mapping: in the map's frame +y is up, u turns about it starting at -z. */
static void env_direction_to_uv(const environment *env, vec3 d, float *u, float *v)
{
    vec3 l = v3_normalize(mat4_vector(&env->to_local, d));
    float uu = atan2f(l.x, -l.z) * (0.5f * INV_PI_F);
    float vv = acosf(clampf(l.y, -1.0f, 1.0f)) * INV_PI_F;
    *u = uu - floorf(uu);
    *v = vv;
}

static vec3 env_uv_to_direction(const environment *env, float u, float v)
{
    float phi = 2.0f * PI_F * u, theta = PI_F * v;
    vec3 l = v3(sinf(theta) * sinf(phi), cosf(theta), -sinf(theta) * cosf(phi));
    return v3_normalize(mat4_vector(&env->to_world, l));
}

static rgb env_lookup(const environment *env, float u, float v)
{
    /* Nearest pixel: the map is piecewise constant, exactly what its sampling assumes. */
    int x = (int)fminf(u * (float)env->map.width, (float)env->map.width - 1.0f);
    int y = (int)fminf(v * (float)env->map.height, (float)env->map.height - 1.0f);
    const float *p = image_pixel(&env->map, x < 0 ? 0 : x, y < 0 ? 0 : y);
    return rgb_scale(rgb_make(p[0], p[1], p[2]), env->scale);
}

rgb env_eval(const scene *s, vec3 d)
{
    const environment *env = &s->env;
    if (env->kind == ENV_CONSTANT)
        return env->radiance;
    if (env->kind == ENV_NONE)
        return rgb_gray(0.0f);
    float u, v;
    env_direction_to_uv(env, d, &u, &v);
    return env_lookup(env, u, v);
}

static float env_pdf_direction(const environment *env, vec3 d)
{
    if (env->kind == ENV_CONSTANT)
        return 0.25f * INV_PI_F;
    float u, v;
    env_direction_to_uv(env, d, &u, &v);
    float sin_theta = sinf(PI_F * v);
    if (sin_theta <= 0.0f)
        return 0.0f;
    return distrib2d_pdf(&env->dist, u, v) / (2.0f * PI_F * PI_F * sin_theta);
}

/* ---- Lights ----------------------------------------------------------------------------------- */

int light_sample_from(const scene *s, vec3 p, float u_pick, float u0, float u1,
                      light_sample *ls)
{
    if (!s->has_lights)
        return 0;
    size_t i = distrib1d_sample(&s->lights, u_pick, NULL);
    float pick = (float)distrib1d_pmf(&s->lights, i);
    if (s->env.kind != ENV_NONE && i == s->nlights - 1) {
        const environment *env = &s->env;
        if (env->kind == ENV_CONSTANT) {
            ls->wi = sample_uniform_sphere(u0, u1);
            ls->pdf = pick * 0.25f * INV_PI_F;
            ls->radiance = env->radiance;
        } else {
            float u, v, pdf_uv;
            distrib2d_sample(&env->dist, u0, u1, &u, &v, &pdf_uv);
            float sin_theta = sinf(PI_F * v);
            if (sin_theta <= 0.0f || pdf_uv <= 0.0f)
                return 0;
            ls->wi = env_uv_to_direction(env, u, v);
            ls->pdf = pick * pdf_uv / (2.0f * PI_F * PI_F * sin_theta);
            ls->radiance = env_lookup(env, u, v);
        }
        ls->dist = INFINITY;
        return ls->pdf > 0.0f;
    }
    const shape *sh = &s->shapes[s->light_shape[i]];
    uint32_t t = (uint32_t)i - sh->first_light;
    const uint32_t *id = sh->m.idx + 3 * t;
    /* Uniform point on the triangle (the square-root warp). */
    float su = sqrtf(u0), b0 = 1.0f - su, b1 = u1 * su, b2 = 1.0f - b0 - b1;
    vec3 p0 = sh->m.p[id[0]], p1 = sh->m.p[id[1]], p2 = sh->m.p[id[2]];
    vec3 q = v3_add(v3_add(v3_scale(p0, b0), v3_scale(p1, b1)), v3_scale(p2, b2));
    vec3 n = v3_normalize(v3_cross(v3_sub(p1, p0), v3_sub(p2, p0)));
    vec3 d = v3_sub(q, p);
    float dist2 = v3_dot(d, d);
    if (!(dist2 > 0.0f))
        return 0;
    float dist = sqrtf(dist2);
    ls->wi = v3_scale(d, 1.0f / dist);
    float cos_l = -v3_dot(ls->wi, n);
    if (cos_l <= 0.0f)
        return 0; /* the back of a one-sided emitter */
    ls->dist = dist;
    ls->radiance = sh->radiance;
    ls->pdf = pick / sh->tri_area[t] * dist2 / cos_l;
    return isfinite(ls->pdf) && ls->pdf > 0.0f;
}

float light_pdf_area(const scene *s, int shape_index, uint32_t prim, vec3 wi, float t, vec3 ng)
{
    const shape *sh = &s->shapes[shape_index];
    if (!s->has_lights || !sh->emissive)
        return 0.0f;
    float cos_l = fabsf(v3_dot(wi, ng));
    if (cos_l <= 0.0f)
        return 0.0f;
    float pick = (float)distrib1d_pmf(&s->lights, sh->first_light + prim);
    return pick / sh->tri_area[prim] * t * t / cos_l;
}

float light_pdf_env(const scene *s, vec3 wi)
{
    if (!s->has_lights || s->env.kind == ENV_NONE)
        return 0.0f;
    float pick = (float)distrib1d_pmf(&s->lights, s->nlights - 1);
    return pick * env_pdf_direction(&s->env, wi);
}

/* ---- Media along rays -------------------------------------------------------------------- */

int scene_medium_after(const scene *s, int shape, vec3 ng, vec3 d, int med)
{
    const struct shape *sh = &s->shapes[shape];
    if (!sh->media_boundary)
        return med;
    return v3_dot(d, ng) < 0.0f ? sh->interior : sh->exterior;
}

vec3 scene_offset_origin(vec3 p, vec3 ng, vec3 dir)
{
    float eps = SCENE_OFFSET_EPS * (1.0f + v3_max_abs(p));
    return v3_add(p, v3_scale(ng, v3_dot(dir, ng) > 0.0f ? eps : -eps));
}

/* The ray from o to end (not o itself: the caller offsets), tmax its length; tmax 0 when end
 * is not ahead of o along `along` by more than rounding, so that nothing fits between. */
static void ray_to(vec3 o, vec3 end, vec3 along, ray *out)
{
    vec3 v = v3_sub(end, o);
    float len = v3_length(v);
    out->o = o;
    if (!(len > 0.0f) || !(v3_dot(v, along) > 0.0f)) {
        out->d = along;
        out->tmax = 0.0f;
        return;
    }
    out->d = v3_scale(v, 1.0f / len);
    out->tmax = len;
}

void scene_shadow_ray(vec3 p, vec3 ng, vec3 wi, float dist, ray *out)
{
    vec3 o = v3_dot(ng, ng) > 0.0f ? scene_offset_origin(p, ng, wi) : p;
    if (isinf(dist)) {
        out->o = o;
        out->d = wi;
        out->tmax = INFINITY;
        return;
    }
    vec3 target = v3_add(p, v3_scale(wi, dist));
    float gap = fmaxf(1e-4f * dist, SCENE_OFFSET_EPS * (1.0f + v3_max_abs(target)));
    if (!(dist > gap)) {
        out->o = o;
        out->d = wi;
        out->tmax = 0.0f;
        return;
    }
    ray_to(o, v3_add(p, v3_scale(wi, dist - gap)), wi, out);
}

rgb scene_transmittance(const scene *s, const ray *r, int med, rng *rn, uint64_t *rays)
{
    if (!s->has_media) {
        ++*rays;
        return rgb_gray(scene_occluded(s, r) ? 0.0f : 1.0f);
    }
    rgb tr = rgb_gray(1.0f);
    ray seg = *r;
    const int bounded = !isinf(r->tmax);
    const vec3 end = bounded ? v3_add(r->o, v3_scale(r->d, r->tmax)) : r->o;
    for (int crossings = 0; crossings <= 64; ++crossings) {
        hit h;
        if (!scene_ray_valid(&seg))
            return rgb_gray(0.0f);
        ++*rays;
        if (!scene_intersect(s, &seg, &h)) {
            if (med >= 0)
                tr = rgb_mul(tr, medium_segment_transmittance(&s->media[med], seg.o, seg.d,
                                                              seg.tmax, rn));
            return tr;
        }
        if (!s->shapes[h.shape].null_surface)
            return rgb_gray(0.0f);
        if (med >= 0)
            tr = rgb_mul(tr, medium_segment_transmittance(&s->media[med], seg.o, seg.d, h.t, rn));
        if (rgb_is_black(tr))
            return tr;
        surface sf;
        scene_surface(s, &h, &seg, &sf);
        med = scene_medium_after(s, h.shape, sf.ng, seg.d, med);
        /* Go on from just past the boundary towards the same far end: the offset along the
         * boundary's normal must not move the end (into the light the ray was aimed at). */
        vec3 o = scene_offset_origin(sf.p, sf.ng, seg.d);
        if (!bounded) {
            seg.o = o;
            continue;
        }
        float rest = seg.tmax - h.t;
        ray_to(o, end, seg.d, &seg);
        if (!(seg.tmax > 0.0f)) { /* the end lies within the offset: nothing fits between */
            if (med >= 0 && rest > 0.0f)
                tr = rgb_mul(tr, medium_segment_transmittance(&s->media[med], o, seg.d, rest,
                                                              rn));
            return tr;
        }
    }
    return rgb_gray(0.0f); /* more null crossings than any scene here has: treat as blocked */
}
