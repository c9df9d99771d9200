/*
 * mesh_ply.c - the Stanford PLY loader (ASCII and binary of either byte order). Every scalar
 * type of the format goes through one "read a value as double" function: simple, and fast
 * enough for meshes of a few hundred thousand triangles.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"

/* ---- PLY -------------------------------------------------------------------------------- */

enum ply_type { PLY_NONE, PLY_I8, PLY_U8, PLY_I16, PLY_U16, PLY_I32, PLY_U32, PLY_F32, PLY_F64 };

static enum ply_type ply_type_from_name(const char *s)
{
    static const struct { const char *name; enum ply_type type; } table[] = {
        {"char", PLY_I8},    {"int8", PLY_I8},     {"uchar", PLY_U8},   {"uint8", PLY_U8},
        {"short", PLY_I16},  {"int16", PLY_I16},   {"ushort", PLY_U16}, {"uint16", PLY_U16},
        {"int", PLY_I32},    {"int32", PLY_I32},   {"uint", PLY_U32},   {"uint32", PLY_U32},
        {"float", PLY_F32},  {"float32", PLY_F32}, {"double", PLY_F64}, {"float64", PLY_F64}};
    for (size_t i = 0; i < sizeof table / sizeof table[0]; ++i)
        if (!strcmp(s, table[i].name))
            return table[i].type;
    return PLY_NONE;
}

static size_t ply_type_size(enum ply_type t)
{
    static const size_t sizes[] = {0, 1, 1, 2, 2, 4, 4, 4, 8};
    return sizes[t];
}

#define PLY_MAX_PROPS 32
#define PLY_MAX_ELEMENTS 8

typedef struct ply_property {
    char name[64];
    enum ply_type type;       /* the value type (the item type for lists)     */
    enum ply_type count_type; /* PLY_NONE for scalars, the length type of lists */
} ply_property;

typedef struct ply_element {
    char name[64];
    uint64_t count;
    int nprops;
    ply_property props[PLY_MAX_PROPS];
} ply_element;

typedef struct ply_reader {
    const char *path;
    const unsigned char *cur, *end; /* binary cursor                           */
    char *text;                     /* ASCII cursor (strtod advances it)       */
    int ascii, swap;                /* swap: file byte order differs from ours */
} ply_reader;

static int host_is_little_endian(void)
{
    uint16_t one = 1;
    unsigned char b;
    memcpy(&b, &one, 1);
    return b == 1;
}

/* Reads one value of type t; returns 0 at the end of the data or on a malformed number. */
static int ply_read(ply_reader *r, enum ply_type t, double *out)
{
    if (r->ascii) {
        char *endp;
        errno = 0;
        double v = strtod(r->text, &endp);
        if (endp == r->text)
            return 0;
        r->text = endp;
        *out = v;
        return 1;
    }
    size_t n = ply_type_size(t);
    if ((size_t)(r->end - r->cur) < n)
        return 0;
    unsigned char b[8];
    memcpy(b, r->cur, n);
    r->cur += n;
    if (r->swap)
        for (size_t i = 0; i < n / 2; ++i) {
            unsigned char tmp = b[i];
            b[i] = b[n - 1 - i];
            b[n - 1 - i] = tmp;
        }
    switch (t) {
    case PLY_I8: { int8_t v; memcpy(&v, b, 1); *out = v; break; }
    case PLY_U8: { uint8_t v; memcpy(&v, b, 1); *out = v; break; }
    case PLY_I16: { int16_t v; memcpy(&v, b, 2); *out = v; break; }
    case PLY_U16: { uint16_t v; memcpy(&v, b, 2); *out = v; break; }
    case PLY_I32: { int32_t v; memcpy(&v, b, 4); *out = v; break; }
    case PLY_U32: { uint32_t v; memcpy(&v, b, 4); *out = v; break; }
    case PLY_F32: { float v; memcpy(&v, b, 4); *out = v; break; }
    case PLY_F64: { double v; memcpy(&v, b, 8); *out = v; break; }
    default: return 0;
    }
    return 1;
}

/* Parses the header; on success *data_start points just after "end_header\n". */
static int ply_parse_header(char *data, size_t size, const char *path, ply_element *elems,
                            int *nelems, ply_reader *r, char **data_start, tr_error *err)
{
    char *hdr_end = NULL;
    for (size_t i = 0; i + 10 <= size; ++i)
        if (!memcmp(data + i, "end_header", 10)) {
            hdr_end = data + i;
            break;
        }
    if (size < 4 || memcmp(data, "ply", 3) != 0 || !hdr_end)
        return tr_fail(err, "'%s' is not a PLY file (no 'ply' magic or no end_header)", path);
    /* The data starts after the end of the end_header line. */
    char *p = hdr_end + 10;
    while (p < data + size && *p != '\n')
        ++p;
    *data_start = p < data + size ? p + 1 : p;
    *hdr_end = '\0';

    *nelems = 0;
    int have_format = 0;
    char *save = NULL;
    for (char *line = strtok_r(data, "\r\n", &save); line; line = strtok_r(NULL, "\r\n", &save)) {
        char a[64] = "", b[64] = "", c[64] = "", d[64] = "", e[64] = "";
        int n = sscanf(line, "%63s %63s %63s %63s %63s", a, b, c, d, e);
        if (n <= 0 || !strcmp(a, "ply") || !strcmp(a, "comment") || !strcmp(a, "obj_info"))
            continue;
        if (!strcmp(a, "format")) {
            have_format = 1;
            if (!strcmp(b, "ascii"))
                r->ascii = 1;
            else if (!strcmp(b, "binary_little_endian"))
                r->swap = !host_is_little_endian();
            else if (!strcmp(b, "binary_big_endian"))
                r->swap = host_is_little_endian();
            else
                return tr_fail(err, "'%s': unknown PLY format '%s'", path, b);
        } else if (!strcmp(a, "element") && n == 3) {
            if (*nelems == PLY_MAX_ELEMENTS)
                return tr_fail(err, "'%s': more than %d PLY elements", path, PLY_MAX_ELEMENTS);
            ply_element *el = &elems[(*nelems)++];
            memset(el, 0, sizeof *el);
            snprintf(el->name, sizeof el->name, "%s", b);
            char *endp;
            el->count = strtoull(c, &endp, 10);
            if (*endp)
                return tr_fail(err, "'%s': bad element count '%s'", path, c);
        } else if (!strcmp(a, "property") && *nelems > 0) {
            ply_element *el = &elems[*nelems - 1];
            if (el->nprops == PLY_MAX_PROPS)
                return tr_fail(err, "'%s': too many properties", path);
            ply_property *pr = &el->props[el->nprops++];
            if (!strcmp(b, "list") && n == 5) {
                pr->count_type = ply_type_from_name(c);
                pr->type = ply_type_from_name(d);
                snprintf(pr->name, sizeof pr->name, "%s", e);
                if (!pr->count_type || !pr->type)
                    return tr_fail(err, "'%s': bad list property '%s'", path, line);
            } else if (n == 3) {
                pr->type = ply_type_from_name(b);
                snprintf(pr->name, sizeof pr->name, "%s", c);
                if (!pr->type)
                    return tr_fail(err, "'%s': unknown property type '%s'", path, b);
            } else {
                return tr_fail(err, "'%s': malformed header line '%s'", path, line);
            }
        } else {
            return tr_fail(err, "'%s': malformed header line '%s'", path, line);
        }
    }
    if (!have_format)
        return tr_fail(err, "'%s': no format line in the PLY header", path);
    return 1;
}

static int prop_index(const ply_element *el, const char *a, const char *b, const char *c)
{
    for (int i = 0; i < el->nprops; ++i)
        if (!strcmp(el->props[i].name, a) || (b && !strcmp(el->props[i].name, b)) ||
            (c && !strcmp(el->props[i].name, c)))
            return i;
    return -1;
}

int mesh_load_ply(const char *path, mesh *m, tr_error *err)
{
    char *data = NULL, *body = NULL;
    size_t size = 0;
    ply_element elems[PLY_MAX_ELEMENTS];
    int nelems = 0;
    ply_reader r = {0};
    memset(m, 0, sizeof *m);
    if (!mesh_read_file(path, &data, &size, err))
        return 0;
    r.path = path;
    if (!ply_parse_header(data, size, path, elems, &nelems, &r, &body, err)) {
        free(data);
        return 0;
    }
    r.cur = (const unsigned char *)body;
    r.end = (const unsigned char *)data + size;
    r.text = body;

    const ply_element *ve = NULL, *fe = NULL;
    for (int i = 0; i < nelems; ++i) {
        if (!strcmp(elems[i].name, "vertex"))
            ve = &elems[i];
        else if (!strcmp(elems[i].name, "face"))
            fe = &elems[i];
    }
    int ix = ve ? prop_index(ve, "x", NULL, NULL) : -1, iy = ve ? prop_index(ve, "y", NULL, NULL) : -1;
    int iz = ve ? prop_index(ve, "z", NULL, NULL) : -1;
    if (ix < 0 || iy < 0 || iz < 0 || !fe || ve->count > 0xffffffffu) {
        free(data);
        return tr_fail(err, "'%s': needs a vertex element with x, y, z and a face element", path);
    }
    int inx = prop_index(ve, "nx", NULL, NULL), iny = prop_index(ve, "ny", NULL, NULL);
    int inz = prop_index(ve, "nz", NULL, NULL);
    int iu = prop_index(ve, "u", "s", "texture_u"), iv = prop_index(ve, "v", "t", "texture_v");
    int has_n = inx >= 0 && iny >= 0 && inz >= 0, has_uv = iu >= 0 && iv >= 0;
    int iface = prop_index(fe, "vertex_indices", "vertex_index", NULL);
    if (iface < 0 || fe->props[iface].count_type == PLY_NONE) {
        free(data);
        return tr_fail(err, "'%s': the face element has no vertex_indices list", path);
    }

    /* Triangles are counted while reading (polygons give several); start with the number of
     * faces and grow. */
    uint32_t cap = fe->count > 0 ? (uint32_t)fe->count : 1u;
    if (!mesh_alloc(m, (uint32_t)ve->count, cap, has_n, has_uv)) {
        free(data);
        return tr_fail(err, "'%s': out of memory", path);
    }
    m->ntris = 0;
    int ok = 1;
    for (int e = 0; e < nelems && ok; ++e) {
        const ply_element *el = &elems[e];
        for (uint64_t k = 0; k < el->count && ok; ++k) {
            double vals[PLY_MAX_PROPS] = {0};
            for (int q = 0; q < el->nprops && ok; ++q) {
                const ply_property *pr = &el->props[q];
                if (pr->count_type == PLY_NONE) {
                    ok = ply_read(&r, pr->type, &vals[q]);
                    continue;
                }
                double cnt;
                if (!(ok = ply_read(&r, pr->count_type, &cnt)))
                    break;
                if (cnt < 0 || cnt > 1024) {
                    free(data);
                    mesh_free(m);
                    return tr_fail(err, "'%s': bad list length %g", path, cnt);
                }
                uint32_t poly[1024];
                for (int j = 0; j < (int)cnt && ok; ++j) {
                    double v;
                    ok = ply_read(&r, pr->type, &v);
                    poly[j] = (uint32_t)v;
                    if (ok && (v < 0 || v >= (double)m->nverts)) {
                        free(data);
                        mesh_free(m);
                        return tr_fail(err, "'%s': face %llu has vertex index %g out of range "
                                       "(%u vertices)", path, (unsigned long long)k, v, m->nverts);
                    }
                }
                if (el == fe && q == iface)
                    for (int j = 2; j < (int)cnt && ok; ++j) {
                        if (m->ntris == cap) {
                            cap *= 2;
                            uint32_t *grown = realloc(m->idx, (size_t)cap * 3u * sizeof *grown);
                            if (!grown) {
                                free(data);
                                mesh_free(m);
                                return tr_fail(err, "'%s': out of memory", path);
                            }
                            m->idx = grown;
                        }
                        uint32_t *t = m->idx + 3u * m->ntris++;
                        t[0] = poly[0];
                        t[1] = poly[j - 1];
                        t[2] = poly[j];
                    }
            }
            if (ok && el == ve) {
                m->p[k] = v3((float)vals[ix], (float)vals[iy], (float)vals[iz]);
                if (has_n)
                    m->n[k] = v3((float)vals[inx], (float)vals[iny], (float)vals[inz]);
                if (has_uv) {
                    m->uv[2 * k] = (float)vals[iu];
                    m->uv[2 * k + 1] = (float)vals[iv];
                }
            }
        }
    }
    free(data);
    if (!ok) {
        mesh_free(m);
        return tr_fail(err, "'%s': the data ends early or holds a malformed value", path);
    }
    return 1;
}
