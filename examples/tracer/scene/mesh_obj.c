/*
 * mesh_obj.c - the Wavefront OBJ loader: positions, texture coordinates, normals and
 * polygonal faces; distinct (position, uv, normal) corners become the mesh's vertices.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"

/* ---- OBJ -------------------------------------------------------------------------------- */

typedef struct growable {
    void *data;
    size_t count, cap, elem;
} growable;

static void *grow(growable *g)
{
    if (g->count == g->cap) {
        size_t cap = g->cap ? 2 * g->cap : 1024;
        void *d = realloc(g->data, cap * g->elem);
        if (!d)
            return NULL;
        g->data = d;
        g->cap = cap;
    }
    return (char *)g->data + g->elem * g->count++;
}

/* An OBJ corner refers to a position, a texture coordinate and a normal separately; a mesh
 * vertex is one distinct triple. A hash table maps triples to vertices so that shared
 * corners stay shared (and computed smooth normals stay smooth). */
typedef struct corner_key {
    int64_t v, t, n;
} corner_key;

typedef struct corner_map {
    corner_key *keys;
    uint32_t *values;
    size_t cap, count;
} corner_map;

static size_t corner_hash(corner_key k)
{
    uint64_t h = (uint64_t)k.v * 0x9e3779b97f4a7c15ULL ^ (uint64_t)k.t * 0xc2b2ae3d27d4eb4fULL ^
                 (uint64_t)k.n * 0x165667b19e3779f9ULL;
    return (size_t)(h ^ (h >> 29));
}

/* Finds the vertex of key k, or inserts `next` for it. Returns UINT32_MAX if out of memory. */
static uint32_t corner_lookup(corner_map *cm, corner_key k, uint32_t next)
{
    if (2 * (cm->count + 1) > cm->cap) {
        size_t cap = cm->cap ? 2 * cm->cap : 4096;
        corner_key *keys = malloc(cap * sizeof *keys);
        uint32_t *values = malloc(cap * sizeof *values);
        if (!keys || !values) {
            free(keys);
            free(values);
            return UINT32_MAX;
        }
        for (size_t i = 0; i < cap; ++i)
            keys[i].v = -1;
        for (size_t i = 0; i < cm->cap; ++i)
            if (cm->keys[i].v >= 0) {
                size_t j = corner_hash(cm->keys[i]) & (cap - 1);
                while (keys[j].v >= 0)
                    j = (j + 1) & (cap - 1);
                keys[j] = cm->keys[i];
                values[j] = cm->values[i];
            }
        free(cm->keys);
        free(cm->values);
        cm->keys = keys;
        cm->values = values;
        cm->cap = cap;
    }
    size_t j = corner_hash(k) & (cm->cap - 1);
    while (cm->keys[j].v >= 0) {
        if (cm->keys[j].v == k.v && cm->keys[j].t == k.t && cm->keys[j].n == k.n)
            return cm->values[j];
        j = (j + 1) & (cm->cap - 1);
    }
    cm->keys[j] = k;
    cm->values[j] = next;
    cm->count++;
    return next;
}

/* Resolves a 1-based (or negative, relative) OBJ index against `count` entries: 0-based
 * result, or -1 when absent, -2 when out of range. */
static int64_t obj_index(const char *s, size_t count)
{
    if (!s || !*s)
        return -1;
    char *endp;
    long long i = strtoll(s, &endp, 10);
    if (endp == s)
        return -2;
    if (i < 0)
        i += (long long)count + 1;
    if (i < 1 || (size_t)i > count)
        return -2;
    return (int64_t)(i - 1);
}

int mesh_load_obj(const char *path, mesh *m, tr_error *err)
{
    char *data = NULL;
    size_t size = 0;
    memset(m, 0, sizeof *m);
    if (!mesh_read_file(path, &data, &size, err))
        return 0;
    growable pos = {0, 0, 0, sizeof(vec3)}, nrm = {0, 0, 0, sizeof(vec3)};
    growable tex = {0, 0, 0, 2 * sizeof(float)}, tris = {0, 0, 0, 3 * sizeof(uint32_t)};
    growable vkeys = {0, 0, 0, sizeof(corner_key)};
    corner_map cm = {0};
    int ok = 1, lineno = 0;
    char msg[256] = "out of memory";
    char *save = NULL;
    for (char *line = strtok_r(data, "\n", &save); line && ok; line = strtok_r(NULL, "\n", &save)) {
        ++lineno;
        while (*line == ' ' || *line == '\t')
            ++line;
        if (line[0] == 'v' && (line[1] == ' ' || line[1] == '\t')) {
            vec3 *v = grow(&pos);
            ok = v && sscanf(line + 2, "%f %f %f", &v->x, &v->y, &v->z) == 3;
        } else if (line[0] == 'v' && line[1] == 'n') {
            vec3 *v = grow(&nrm);
            ok = v && sscanf(line + 2, "%f %f %f", &v->x, &v->y, &v->z) == 3;
        } else if (line[0] == 'v' && line[1] == 't') {
            float *t = grow(&tex);
            ok = t && sscanf(line + 2, "%f %f", &t[0], &t[1]) >= 1;
        } else if (line[0] == 'f' && (line[1] == ' ' || line[1] == '\t')) {
            uint32_t poly[256];
            int count = 0;
            char *tsave = NULL;
            for (char *tok = strtok_r(line + 2, " \t\r", &tsave); tok && ok;
                 tok = strtok_r(NULL, " \t\r", &tsave)) {
                char *s1 = strchr(tok, '/'), *s2 = s1 ? strchr(s1 + 1, '/') : NULL;
                if (s1)
                    *s1 = '\0';
                if (s2)
                    *s2 = '\0';
                corner_key k = {obj_index(tok, pos.count), s1 ? obj_index(s1 + 1, tex.count) : -1,
                                s2 ? obj_index(s2 + 1, nrm.count) : -1};
                if (k.v < 0 || k.t == -2 || k.n == -2 || count == 256) {
                    snprintf(msg, sizeof msg, "bad face index on line %d", lineno);
                    ok = 0;
                    break;
                }
                uint32_t vi = corner_lookup(&cm, k, (uint32_t)vkeys.count);
                if (vi == UINT32_MAX) {
                    ok = 0;
                    break;
                }
                if (vi == vkeys.count) {
                    corner_key *slot = grow(&vkeys);
                    if (!(ok = slot != NULL))
                        break;
                    *slot = k;
                }
                poly[count++] = vi;
            }
            for (int j = 2; j < count && ok; ++j) {
                uint32_t *t = grow(&tris);
                if (!(ok = t != NULL))
                    break;
                t[0] = poly[0];
                t[1] = poly[j - 1];
                t[2] = poly[j];
            }
        }
        if (!ok && !strcmp(msg, "out of memory") && line[0] == 'v')
            snprintf(msg, sizeof msg, "malformed vertex data on line %d", lineno);
    }
    /* Assemble the mesh: a vertex has a normal or uv only if all of them have one. */
    int all_n = vkeys.count > 0, all_t = vkeys.count > 0;
    const corner_key *keys = vkeys.data;
    for (size_t i = 0; i < vkeys.count; ++i) {
        all_n &= keys[i].n >= 0;
        all_t &= keys[i].t >= 0;
    }
    if (ok && (vkeys.count == 0 || tris.count == 0)) {
        snprintf(msg, sizeof msg, "no faces");
        ok = 0;
    }
    if (ok && !mesh_alloc(m, (uint32_t)vkeys.count, (uint32_t)tris.count, all_n, all_t))
        ok = 0;
    if (ok) {
        const vec3 *P = pos.data, *N = nrm.data;
        const float *T = tex.data;
        for (size_t i = 0; i < vkeys.count; ++i) {
            m->p[i] = P[keys[i].v];
            if (all_n)
                m->n[i] = N[keys[i].n];
            if (all_t) {
                m->uv[2 * i] = T[2 * keys[i].t];
                m->uv[2 * i + 1] = T[2 * keys[i].t + 1];
            }
        }
        memcpy(m->idx, tris.data, tris.count * 3u * sizeof(uint32_t));
    }
    free(pos.data);
    free(nrm.data);
    free(tex.data);
    free(tris.data);
    free(vkeys.data);
    free(cm.keys);
    free(cm.values);
    free(data);
    if (!ok) {
        mesh_free(m);
        return tr_fail(err, "'%s': %s", path, msg);
    }
    return 1;
}
