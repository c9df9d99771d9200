/*
 * mesh.c - mesh memory, Mitsuba's built-in shapes as triangles, transforms and vertex
 * normals. The file loaders are in mesh_ply.c and mesh_obj.c.
 */
#include "mesh.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void mesh_free(mesh *m)
{
    free(m->p);
    free(m->n);
    free(m->uv);
    free(m->idx);
    memset(m, 0, sizeof *m);
}

int mesh_alloc(mesh *m, uint32_t nverts, uint32_t ntris, int normals, int uvs)
{
    memset(m, 0, sizeof *m);
    m->nverts = nverts;
    m->ntris = ntris;
    /* Embree reads the last vertex as 16 bytes: pad the position buffer. */
    m->p = malloc((size_t)nverts * sizeof *m->p + 16);
    m->n = normals ? malloc((size_t)nverts * sizeof *m->n + 1) : NULL;
    m->uv = uvs ? malloc((size_t)nverts * 2u * sizeof *m->uv + 1) : NULL;
    m->idx = malloc((size_t)ntris * 3u * sizeof *m->idx + 1);
    if (!m->p || !m->idx || (normals && !m->n) || (uvs && !m->uv)) {
        mesh_free(m);
        return 0;
    }
    return 1;
}

int mesh_read_file(const char *path, char **data, size_t *size, tr_error *err)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return tr_fail(err, "cannot open '%s': %s", path, strerror(errno));
    if (fseek(f, 0, SEEK_END) != 0) {
        fclose(f);
        return tr_fail(err, "cannot read '%s'", path);
    }
    long len = ftell(f);
    rewind(f);
    /* A directory opens on Linux and "ends" at LONG_MAX: refuse sizes no mesh has rather
     * than asking malloc for them (found by fuzz_scene_load, examples/tracer/fuzz/). */
    if (len < 0 || len > (1L << 30)) {
        fclose(f);
        *data = NULL;
        return tr_fail(err, "cannot read '%s': not a regular file, or larger than 1 GiB",
                       path);
    }
    *data = malloc((size_t)len + 1);
    if (!*data || fread(*data, 1, (size_t)len, f) != (size_t)len) {
        fclose(f);
        free(*data);
        *data = NULL;
        return tr_fail(err, "cannot read '%s'", path);
    }
    fclose(f);
    (*data)[len] = '\0';
    *size = (size_t)len;
    return 1;
}

/* ---- Built-in shapes -------------------------------------------------------------------- */

int mesh_make_rectangle(mesh *m, tr_error *err)
{
    if (!mesh_alloc(m, 4, 2, 1, 1))
        return tr_fail(err, "out of memory");
    static const float xy[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
    for (int i = 0; i < 4; ++i) {
        m->p[i] = v3(xy[i][0], xy[i][1], 0.0f);
        m->n[i] = v3(0.0f, 0.0f, 1.0f);
        m->uv[2 * i] = 0.5f * (xy[i][0] + 1.0f);
        m->uv[2 * i + 1] = 0.5f * (xy[i][1] + 1.0f);
    }
    static const uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    memcpy(m->idx, idx, sizeof idx);
    return 1;
}

int mesh_make_disk(mesh *m, tr_error *err)
{
    /* A fan of 64 triangles whose rim radius is chosen so that its area is exactly pi, the
     * unit disk's: an emitting disk then sends out Mitsuba's power. The rim then lies up to
     * 0.08 % outside the circle and 0.08 % inside it between the rim's corners. */
    enum { SEGMENTS = 64 };
    const double step = 2.0 * 3.14159265358979323846 / SEGMENTS;
    const float rim = (float)sqrt(3.14159265358979323846 / (0.5 * SEGMENTS * sin(step)));
    if (!mesh_alloc(m, SEGMENTS + 2, SEGMENTS, 1, 1))
        return tr_fail(err, "out of memory");
    /* Vertex 0 is the centre; 1..SEGMENTS + 1 the rim, the last one repeating the first
     * at phi = 2 pi so that Mitsuba's texture coordinates (r, phi / 2 pi) do not wrap. */
    m->p[0] = v3(0.0f, 0.0f, 0.0f);
    m->uv[0] = m->uv[1] = 0.0f;
    for (int i = 0; i <= SEGMENTS; ++i) {
        const double phi = step * i;
        m->p[i + 1] = v3(rim * (float)cos(phi), rim * (float)sin(phi), 0.0f);
        m->uv[2 * (i + 1)] = 1.0f;
        m->uv[2 * (i + 1) + 1] = (float)i / SEGMENTS;
    }
    for (int i = 0; i < SEGMENTS + 2; ++i)
        m->n[i] = v3(0.0f, 0.0f, 1.0f);
    for (uint32_t t = 0; t < SEGMENTS; ++t) {
        m->idx[3 * t] = 0;
        m->idx[3 * t + 1] = t + 1;
        m->idx[3 * t + 2] = t + 2;
    }
    return 1;
}

int mesh_make_cube(mesh *m, tr_error *err)
{
    if (!mesh_alloc(m, 24, 12, 1, 1))
        return tr_fail(err, "out of memory");
    /* Each face: its normal axis and sign; the corners go counter-clockwise seen from outside. */
    for (int f = 0; f < 6; ++f) {
        int axis = f / 2;
        float sign = (f % 2) ? -1.0f : 1.0f;
        vec3 n = v3(axis == 0 ? sign : 0.0f, axis == 1 ? sign : 0.0f, axis == 2 ? sign : 0.0f);
        frame fr = frame_from_normal(n);
        static const float corner[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (int c = 0; c < 4; ++c) {
            vec3 p = v3_add(n, v3_add(v3_scale(fr.s, corner[c][0]), v3_scale(fr.t, corner[c][1])));
            /* Snap to exact +-1 so that the faces meet without cracks. */
            p = v3(roundf(p.x), roundf(p.y), roundf(p.z));
            m->p[4 * f + c] = p;
            m->n[4 * f + c] = n;
            m->uv[2 * (4 * f + c)] = 0.5f * (corner[c][0] + 1.0f);
            m->uv[2 * (4 * f + c) + 1] = 0.5f * (corner[c][1] + 1.0f);
        }
        uint32_t b = 4u * (uint32_t)f;
        uint32_t t[6] = {b, b + 1, b + 2, b, b + 2, b + 3};
        memcpy(m->idx + 6 * f, t, sizeof t);
    }
    return 1;
}

int mesh_make_sphere(mesh *m, vec3 center, float radius, tr_error *err)
{
    enum { RINGS = 64, SEGMENTS = 128 };
    uint32_t nv = (RINGS + 1) * (SEGMENTS + 1), nt = 2 * RINGS * SEGMENTS;
    if (!mesh_alloc(m, nv, nt, 1, 1))
        return tr_fail(err, "out of memory");
    for (int i = 0; i <= RINGS; ++i)
        for (int j = 0; j <= SEGMENTS; ++j) {
            float theta = PI_F * (float)i / RINGS, phi = 2.0f * PI_F * (float)j / SEGMENTS;
            vec3 d = v3(sinf(theta) * cosf(phi), sinf(theta) * sinf(phi), cosf(theta));
            uint32_t k = (uint32_t)(i * (SEGMENTS + 1) + j);
            m->p[k] = v3_add(center, v3_scale(d, radius));
            m->n[k] = d;
            m->uv[2 * k] = (float)j / SEGMENTS;
            m->uv[2 * k + 1] = (float)i / RINGS;
        }
    uint32_t t = 0;
    for (uint32_t i = 0; i < RINGS; ++i)
        for (uint32_t j = 0; j < SEGMENTS; ++j) {
            uint32_t a = i * (SEGMENTS + 1) + j, b = a + SEGMENTS + 1;
            /* Outward-facing: (a, b, a+1) and (a+1, b, b+1) wind counter-clockwise from outside. */
            uint32_t q[6] = {a, b, a + 1, a + 1, b, b + 1};
            memcpy(m->idx + 3 * t, q, sizeof q);
            t += 2;
        }
    /* Triangles at the poles have two equal corners: mesh_finish drops them. */
    return 1;
}

/* ---- Transforms and normals ------------------------------------------------------------- */

void mesh_transform(mesh *m, const mat4 *to_world)
{
    mat4 inv;
    int invertible = mat4_inverse(to_world, &inv);
    for (uint32_t i = 0; i < m->nverts; ++i) {
        m->p[i] = mat4_point(to_world, m->p[i]);
        if (m->n && invertible)
            m->n[i] = v3_normalize(mat4_normal(&inv, m->n[i]));
    }
    if (mat4_det3(to_world) < 0.0)
        for (uint32_t t = 0; t < m->ntris; ++t) {
            uint32_t tmp = m->idx[3 * t + 1];
            m->idx[3 * t + 1] = m->idx[3 * t + 2];
            m->idx[3 * t + 2] = tmp;
        }
}

static float angle_between(vec3 a, vec3 b)
{
    /* atan2 of |a x b| and a.b: accurate for small and large angles alike. */
    return atan2f(v3_length(v3_cross(a, b)), v3_dot(a, b));
}

int mesh_finish(mesh *m, int face_normals, int flip, tr_error *err)
{
    /* Drop zero-area triangles: they have no normal and Embree would never report them. */
    uint32_t kept = 0;
    for (uint32_t t = 0; t < m->ntris; ++t) {
        const uint32_t *i = m->idx + 3 * t;
        vec3 c = v3_cross(v3_sub(m->p[i[1]], m->p[i[0]]), v3_sub(m->p[i[2]], m->p[i[0]]));
        if (v3_dot(c, c) > 0.0f && v3_is_finite(c))
            memmove(m->idx + 3 * kept++, i, 3 * sizeof *i);
    }
    m->ntris = kept;
    if (kept == 0)
        return 1; /* the caller skips the shape (scene_load.c) */
    if (flip)
        for (uint32_t t = 0; t < m->ntris; ++t) {
            uint32_t tmp = m->idx[3 * t + 1];
            m->idx[3 * t + 1] = m->idx[3 * t + 2];
            m->idx[3 * t + 2] = tmp;
        }
    if (face_normals) {
        free(m->n);
        m->n = NULL;
        return 1;
    }
    if (m->n) {
        for (uint32_t i = 0; i < m->nverts; ++i) {
            vec3 n = v3_normalize(m->n[i]);
            m->n[i] = flip ? v3_neg(n) : n;
        }
        return 1;
    }
    m->n = calloc(m->nverts ? m->nverts : 1, sizeof *m->n);
    if (!m->n)
        return tr_fail(err, "out of memory");
    for (uint32_t t = 0; t < m->ntris; ++t) {
        const uint32_t *i = m->idx + 3 * t;
        vec3 fn = v3_normalize(v3_cross(v3_sub(m->p[i[1]], m->p[i[0]]), v3_sub(m->p[i[2]], m->p[i[0]])));
        for (int c = 0; c < 3; ++c) {
            vec3 p = m->p[i[c]], a = m->p[i[(c + 1) % 3]], b = m->p[i[(c + 2) % 3]];
            float w = angle_between(v3_sub(a, p), v3_sub(b, p));
            m->n[i[c]] = v3_add(m->n[i[c]], v3_scale(fn, w));
        }
    }
    for (uint32_t i = 0; i < m->nverts; ++i) {
        vec3 n = m->n[i];
        /* A vertex that belongs to no triangle keeps a harmless +z. */
        m->n[i] = v3_dot(n, n) > 0.0f ? v3_normalize(n) : v3(0.0f, 0.0f, 1.0f);
    }
    return 1;
}

void mesh_uv_at(const mesh *m, uint32_t tri, float b1, float b2, float *u, float *v)
{
    if (!m->uv) {
        *u = b1;
        *v = b2;
        return;
    }
    const uint32_t *id = m->idx + 3 * tri;
    const float b0 = 1.0f - b1 - b2;
    *u = b0 * m->uv[2 * id[0]] + b1 * m->uv[2 * id[1]] + b2 * m->uv[2 * id[2]];
    *v = b0 * m->uv[2 * id[0] + 1] + b1 * m->uv[2 * id[1] + 1] + b2 * m->uv[2 * id[2] + 1];
}

void mesh_uv_tangents(const mesh *m, uint32_t tri, vec3 *dp_du, vec3 *dp_dv)
{
    const uint32_t *id = m->idx + 3 * tri;
    vec3 dp0 = v3_sub(m->p[id[1]], m->p[id[0]]), dp1 = v3_sub(m->p[id[2]], m->p[id[0]]);
    if (!m->uv) {
        *dp_du = dp0;
        *dp_dv = dp1;
        return;
    }
    const float *t0 = m->uv + 2 * id[0], *t1 = m->uv + 2 * id[1], *t2 = m->uv + 2 * id[2];
    float du0 = t1[0] - t0[0], dv0 = t1[1] - t0[1], du1 = t2[0] - t0[0], dv1 = t2[1] - t0[1];
    float det = du0 * dv1 - dv0 * du1;
    if (det == 0.0f || !isfinite(1.0f / det)) {
        *dp_du = *dp_dv = v3(0.0f, 0.0f, 0.0f);
        return;
    }
    float inv = 1.0f / det;
    *dp_du = v3_scale(v3_sub(v3_scale(dp0, dv1), v3_scale(dp1, dv0)), inv);
    *dp_dv = v3_scale(v3_sub(v3_scale(dp1, du0), v3_scale(dp0, du1)), inv);
}
