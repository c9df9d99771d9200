/*
 * scene_media.c - participating media in the scene file: <medium type="homogeneous"> with
 * its albedo, sigma_t, scale and a nested <phase type="isotropic|hg">; <medium
 * type="heterogeneous"> with <volume type="gridvolume"> grids for sigma_t and the albedo; and
 * the check that a shape bounding a medium is closed (docs/scene-format.md, "Participating media").
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene_xml.h"

/* Coefficients: every channel finite (parse_numbers refuses the rest) and within [lo, hi]. */
static int check_channels(loader *L, xml_node *plugin, const char *name, rgb v, float lo,
                          float hi, const char *range)
{
    const float c[3] = {v.r, v.g, v.b};
    xml_node *n;
    if (!find_prop(L, plugin, name, &n))
        return 0;
    for (int i = 0; i < 3; ++i)
        if (!(c[i] >= lo && c[i] <= hi))
            return fail_at(L, n ? n : plugin, "%s = %g is out of range: it must lie in %s",
                           name, (double)c[i], range);
    return 1;
}

static int parse_phase(loader *L, xml_node *n, float *g)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    *g = 0.0f;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    if (!strcmp(type, "hg")) {
        xml_node *gn;
        if (!get_float(L, n, "g", 0.8f, g) || !find_prop(L, n, "g", &gn))
            return 0;
        if (!(*g > -1.0f && *g < 1.0f))
            return fail_at(L, gn ? gn : n, "g = %g is out of range: it must lie in (-1, 1)",
                           (double)*g);
    } else if (strcmp(type, "isotropic")) {
        return fail_at(L, n, "unsupported phase function '%s' (isotropic, hg)", type);
    }
    return check_all_used(L, n);
}

/* <volume type="gridvolume" name=...>: the grid of its file, placed by its to_world. Values
 * must lie in [lo, hi]; `what` names them in messages. *out is owned by the caller. */
static int parse_gridvolume(loader *L, xml_node *n, const char *what, float lo, float hi,
                            placed_grid **out)
{
    *out = NULL;
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    if (strcmp(type, "gridvolume"))
        return fail_at(L, n, "unsupported volume type '%s' (gridvolume)", type);
    const char *file, *filter, *wrap_mode;
    int raw, use_grid_bbox;
    mat4 to_world, to_local;
    if (!get_string(L, n, "filename", NULL, &file) ||
        !get_string(L, n, "filter_type", "trilinear", &filter) ||
        !get_string(L, n, "wrap_mode", "clamp", &wrap_mode) || !get_bool(L, n, "raw", 0, &raw) ||
        !get_bool(L, n, "use_grid_bbox", 0, &use_grid_bbox) ||
        !get_transform(L, n, "to_world", &to_world) || !check_all_used(L, n))
        return 0;
    if (!file)
        return fail_at(L, n, "missing parameter 'filename'");
    if (strcmp(filter, "trilinear") && strcmp(filter, "nearest"))
        return fail_at(L, n, "filter_type '%s' is not supported (trilinear or nearest)", filter);
    if (strcmp(wrap_mode, "clamp"))
        return fail_at(L, n, "wrap_mode '%s' is not supported (clamp)", wrap_mode);
    if (use_grid_bbox)
        return fail_at(L, n, "use_grid_bbox = true is not supported (the grid fills the unit "
                       "cube that to_world places)");
    if (!mat4_inverse(&to_world, &to_local))
        return fail_at(L, n, "to_world is not invertible");
    char path[4096];
    if (!resolve_path(L, n, file, path, sizeof path))
        return 0;
    placed_grid *pg = calloc(1, sizeof *pg);
    if (!pg)
        return fail_at(L, n, "out of memory");
    tr_error e;
    if (!volume_grid_read(path, what, lo, hi, &pg->grid, &e)) {
        free(pg);
        return fail_at(L, n, "%s", e.msg);
    }
    pg->grid.nearest = !strcmp(filter, "nearest");
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
            pg->to_local[r][c] = (float)to_local.m[r][c];
    *out = pg;
    return 1;
}

/* The coefficients of <medium type="heterogeneous">: sigma_t a one-channel grid (a grey
 * extinction), albedo a constant or a grid of one or three channels. */
static int parse_heterogeneous(loader *L, xml_node *n, medium *m)
{
    xml_node *sn, *an;
    if (!find_prop(L, n, "sigma_t", &sn) || !find_prop(L, n, "albedo", &an))
        return 0;
    if (!sn)
        return fail_at(L, n, "a heterogeneous medium needs sigma_t as <volume "
                       "type=\"gridvolume\"> (a constant one is <medium type=\"homogeneous\">)");
    if (strcmp(sn->name, "volume"))
        return fail_at(L, sn, "sigma_t of a heterogeneous medium must be a <volume "
                       "type=\"gridvolume\"> (a constant one is <medium type=\"homogeneous\">)");
    if (!parse_gridvolume(L, sn, "density", 0.0f, 1e30f, &m->density))
        return 0;
    if (m->density->grid.channels != 1)
        return fail_at(L, sn, "sigma_t's grid has %d channels: only a grey extinction (1 "
                       "channel) is supported", m->density->grid.channels);
    if (an && !strcmp(an->name, "volume"))
        return parse_gridvolume(L, an, "albedo", 0.0f, 1.0f, &m->albedo_grid);
    m->albedo = rgb_gray(0.75f); /* Mitsuba's default */
    return !an || (get_rgb(L, n, "albedo", m->albedo, &m->albedo) &&
                   check_channels(L, n, "albedo", m->albedo, 0.0f, 1.0f, "[0, 1]"));
}

int parse_medium(loader *L, xml_node *n, int *index)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    const int heterogeneous = !strcmp(type, "heterogeneous");
    if (!heterogeneous && strcmp(type, "homogeneous"))
        return fail_at(L, n, "unsupported medium type '%s' (homogeneous, heterogeneous)", type);
    medium m;
    memset(&m, 0, sizeof m);
    float scale;
    int sample_emitters, spectral, ok;
    /* Mitsuba's defaults: albedo 0.75, sigma_t 1, scale 1, isotropic. */
    if (heterogeneous)
        ok = parse_heterogeneous(L, n, &m);
    else
        ok = get_rgb(L, n, "albedo", rgb_gray(0.75f), &m.albedo) &&
             get_rgb(L, n, "sigma_t", rgb_gray(1.0f), &m.sigma_t) &&
             check_channels(L, n, "albedo", m.albedo, 0.0f, 1.0f, "[0, 1]") &&
             check_channels(L, n, "sigma_t", m.sigma_t, 0.0f, 1e30f, "[0, 1e30]");
    ok = ok && get_float(L, n, "scale", 1.0f, &scale) &&
         get_bool(L, n, "sample_emitters", 1, &sample_emitters) &&
         get_bool(L, n, "has_spectral_extinction", 1, &spectral) &&
         check_channels(L, n, "scale", rgb_gray(scale), 0.0f, 1e30f, "[0, 1e30]");
    if (ok && !sample_emitters)
        ok = fail_at(L, n, "sample_emitters = false is not supported (next-event estimation "
                     "is always on)");
    if (ok && heterogeneous) {
        m.scale = scale;
        m.majorant = scale * m.density->grid.max;
        ok = check_channels(L, n, "scale x the density's maximum", rgb_gray(m.majorant), 0.0f,
                            1e30f, "[0, 1e30]");
    } else if (ok) {
        m.sigma_t = rgb_scale(m.sigma_t, scale);
        ok = check_channels(L, n, "scale x sigma_t", m.sigma_t, 0.0f, 1e30f, "[0, 1e30]");
    }
    m.g = 0.0f;
    int phases = 0;
    for (int i = 0; ok && i < n->nchildren; ++i) {
        xml_node *c = n->children[i];
        if (strcmp(c->name, "phase"))
            continue;
        if (phases++)
            ok = fail_at(L, c, "a medium takes one phase function");
        else
            ok = parse_phase(L, c, &m.g);
    }
    ok = ok && check_all_used(L, n);
    medium *grown = ok ? realloc(L->s->media, (size_t)(L->s->nmedia + 1) * sizeof *grown) : NULL;
    if (ok && !grown)
        ok = fail_at(L, n, "out of memory");
    if (!ok) {
        medium_free(&m);
        return 0;
    }
    L->s->media = grown;
    *index = L->s->nmedia;
    L->s->media[L->s->nmedia++] = m;
    L->s->has_media = 1;
    return register_object(L, n, OBJ_MEDIUM, *index);
}

int nested_medium(loader *L, xml_node *c, int *index)
{
    c->used = 1;
    if (!strcmp(c->name, "medium"))
        return parse_medium(L, c, index);
    const named_object *o = resolve_ref(L, c, OBJ_MEDIUM, "medium");
    if (!o)
        return 0;
    *index = o->index;
    return 1;
}

/* ---- Closed shapes ------------------------------------------------------------------------ */

typedef struct edge {
    vec3 a, b; /* ordered: a < b lexicographically */
} edge;

static int vec3_compare(vec3 a, vec3 b)
{
    if (a.x != b.x)
        return a.x < b.x ? -1 : 1;
    if (a.y != b.y)
        return a.y < b.y ? -1 : 1;
    if (a.z != b.z)
        return a.z < b.z ? -1 : 1;
    return 0;
}

static int edge_compare(const void *pa, const void *pb)
{
    const edge *a = pa, *b = pb;
    int c = vec3_compare(a->a, b->a);
    return c ? c : vec3_compare(a->b, b->b);
}

int check_closed(loader *L, const xml_node *n, const mesh *m)
{
    /* By position rather than index: the built-in cube and many files split vertices where
     * normals or texture coordinates differ. */
    size_t ne = 3 * (size_t)m->ntris;
    edge *e = malloc((ne ? ne : 1) * sizeof *e);
    if (!e)
        return fail_at(L, n, "out of memory");
    for (uint32_t t = 0; t < m->ntris; ++t)
        for (int k = 0; k < 3; ++k) {
            vec3 a = m->p[m->idx[3 * t + k]], b = m->p[m->idx[3 * t + (k + 1) % 3]];
            edge *x = &e[3 * (size_t)t + (size_t)k];
            int swap = vec3_compare(a, b) > 0;
            x->a = swap ? b : a;
            x->b = swap ? a : b;
        }
    qsort(e, ne, sizeof *e, edge_compare);
    size_t bad = ne;
    for (size_t i = 0; i < ne && bad == ne;) {
        size_t j = i + 1;
        while (j < ne && !edge_compare(&e[i], &e[j]))
            ++j;
        if (j - i != 2)
            bad = i;
        i = j;
    }
    int ok = 1;
    if (ne == 0)
        ok = fail_at(L, n, "a shape that bounds a medium must be closed: it has no triangles");
    else if (bad < ne)
        ok = fail_at(L, n, "a shape that bounds a medium must be closed: the edge (%g, %g, %g) - "
                     "(%g, %g, %g) belongs to %s triangle(s), not 2", (double)e[bad].a.x,
                     (double)e[bad].a.y, (double)e[bad].a.z, (double)e[bad].b.x,
                     (double)e[bad].b.y, (double)e[bad].b.z,
                     bad + 1 < ne && !edge_compare(&e[bad], &e[bad + 1]) ? "more than 2" : "1");
    free(e);
    return ok;
}
