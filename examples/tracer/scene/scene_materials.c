/*
 * scene_materials.c - textures (bitmap, checkerboard) and BSDFs (diffuse, twosided, mask,
 * bumpmap, conductor, roughconductor, dielectric, thindielectric, roughdielectric, plastic,
 * roughplastic) from their XML elements, with Mitsuba 3's parameter names and defaults.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "scene_xml.h"

/* ---- Textures ---------------------------------------------------------------------------- */

static texture *new_texture(loader *L, const xml_node *n, int *index)
{
    texture **grown = realloc(L->s->textures, (size_t)(L->s->ntextures + 1) * sizeof *grown);
    texture *t = calloc(1, sizeof *t);
    if (grown)
        L->s->textures = grown;
    if (!grown || !t) {
        free(t);
        fail_at(L, n, "out of memory");
        return NULL;
    }
    *index = L->s->ntextures;
    L->s->textures[L->s->ntextures++] = t;
    return t;
}

const texture *constant_texture(loader *L, const xml_node *n, rgb value)
{
    int index;
    texture *t = new_texture(L, n, &index);
    if (t)
        texture_init_constant(t, value);
    return t;
}

static int set_uv_transform(loader *L, xml_node *n, texture *t)
{
    mat4 m;
    if (!get_transform(L, n, "to_uv", &m))
        return 0;
    t->uv[0][0] = (float)m.m[0][0];
    t->uv[0][1] = (float)m.m[0][1];
    t->uv[0][2] = (float)m.m[0][3];
    t->uv[1][0] = (float)m.m[1][0];
    t->uv[1][1] = (float)m.m[1][1];
    t->uv[1][2] = (float)m.m[1][3];
    return 1;
}

const texture *parse_texture(loader *L, xml_node *n)
{
    int index;
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return NULL;
    texture *t = new_texture(L, n, &index);
    if (!t)
        return NULL;
    texture_init_constant(t, rgb_gray(0.0f));
    if (!strcmp(type, "bitmap")) {
        const char *file, *filter, *wrap_mode;
        int raw;
        char path[4096];
        if (!get_string(L, n, "filename", NULL, &file) ||
            !get_string(L, n, "filter_type", "bilinear", &filter) ||
            !get_string(L, n, "wrap_mode", "repeat", &wrap_mode) ||
            !get_bool(L, n, "raw", 0, &raw) || !set_uv_transform(L, n, t))
            return NULL;
        if (!file) {
            fail_at(L, n, "missing parameter 'filename'");
            return NULL;
        }
        if (strcmp(filter, "bilinear") && strcmp(filter, "nearest")) {
            fail_at(L, n, "filter_type '%s' is not supported (bilinear or nearest)", filter);
            return NULL;
        }
        if (strcmp(wrap_mode, "repeat") && strcmp(wrap_mode, "clamp")) {
            fail_at(L, n, "wrap_mode '%s' is not supported (repeat or clamp)", wrap_mode);
            return NULL;
        }
        t->kind = TEX_BITMAP;
        t->nearest = !strcmp(filter, "nearest");
        t->clamp = !strcmp(wrap_mode, "clamp");
        if (!resolve_path(L, n, file, path, sizeof path))
            return NULL;
        tr_error e;
        size_t len = strlen(path);
        int ok = len > 4 && !strcasecmp(path + len - 4, ".exr")
                     ? image_read_exr(path, &t->bitmap, &e)
                     : image_load_ldr(path, !raw, &t->bitmap, &t->alpha, &e);
        if (!ok) {
            t->kind = TEX_CONSTANT;
            fail_at(L, n, "%s", e.msg);
            return NULL;
        }
    } else if (!strcmp(type, "checkerboard")) {
        t->kind = TEX_CHECKERBOARD;
        if (!get_rgb(L, n, "color0", rgb_gray(0.4f), &t->color0) ||
            !get_rgb(L, n, "color1", rgb_gray(0.2f), &t->color1) || !set_uv_transform(L, n, t))
            return NULL;
    } else {
        fail_at(L, n, "unsupported texture type '%s' (bitmap or checkerboard)", type);
        return NULL;
    }
    if (!check_all_used(L, n))
        return NULL;
    texture_update_mean(t);
    if (!register_object(L, n, OBJ_TEXTURE, index))
        return NULL;
    return t;
}

/* A texture-valued parameter: a colour, a nested <texture> or a <ref> to one. */
int get_texture(loader *L, xml_node *plugin, const char *name, rgb def, const texture **out)
{
    xml_node *n;
    if (!find_prop(L, plugin, name, &n))
        return 0;
    if (!n) {
        *out = constant_texture(L, plugin, def);
        return *out != NULL;
    }
    if (!strcmp(n->name, "texture")) {
        *out = parse_texture(L, n);
        return *out != NULL;
    }
    if (!strcmp(n->name, "ref")) {
        n->used = 1;
        const named_object *o = resolve_ref(L, n, OBJ_TEXTURE, "texture");
        if (!o)
            return 0;
        *out = L->s->textures[o->index];
        return 1;
    }
    rgb c;
    if (!parse_colour(L, n, &c))
        return 0;
    *out = constant_texture(L, n, c);
    return *out != NULL;
}

/* ---- BSDFs -------------------------------------------------------------------------------- */

/* Named indices of refraction (a subset of Mitsuba's table). */
static int ior_by_name(const char *name, float *out)
{
    static const struct { const char *name; float ior; } table[] = {
        {"vacuum", 1.0f},       {"air", 1.000277f},      {"water", 1.3330f},
        {"water ice", 1.31f},   {"fused quartz", 1.458f}, {"pyrex", 1.470f},
        {"acrylic glass", 1.49f}, {"polypropylene", 1.49f}, {"bk7", 1.5046f},
        {"sodium chloride", 1.544f}, {"amber", 1.55f},    {"pet", 1.575f},
        {"diamond", 2.419f}};
    for (size_t i = 0; i < sizeof table / sizeof table[0]; ++i)
        if (!strcasecmp(name, table[i].name)) {
            *out = table[i].ior;
            return 1;
        }
    return 0;
}

static int get_ior(loader *L, xml_node *plugin, const char *name, float def, float *out)
{
    xml_node *n;
    *out = def;
    if (!find_prop(L, plugin, name, &n))
        return 0;
    if (!n)
        return 1;
    if (!strcmp(n->name, "string")) {
        const char *v;
        if (!get_string(L, plugin, name, NULL, &v))
            return 0;
        if (!ior_by_name(v, out))
            return fail_at(L, n, "unknown material '%s' for an index of refraction", v);
        return 1;
    }
    if (!get_float(L, plugin, name, def, out))
        return 0;
    if (!(*out > 0.0f))
        return fail_at(L, n, "an index of refraction must be > 0");
    return 1;
}

static int get_roughness(loader *L, xml_node *n, bsdf *b)
{
    const char *dist;
    float au, av;
    int visible;
    if (!get_string(L, n, "distribution", "beckmann", &dist) ||
        !get_float(L, n, "alpha", 0.1f, &b->alpha) || !get_float(L, n, "alpha_u", -1.0f, &au) ||
        !get_float(L, n, "alpha_v", -1.0f, &av) ||
        /* Whether to sample visible normals only changes the noise, never the image: we
         * accept the flag and always sample D(h) cos. */
        !get_bool(L, n, "sample_visible", 1, &visible))
        return 0;
    if (!strcmp(dist, "ggx"))
        b->distribution = MF_GGX;
    else if (!strcmp(dist, "beckmann"))
        b->distribution = MF_BECKMANN;
    else
        return fail_at(L, n, "unknown distribution '%s' (ggx or beckmann)", dist);
    if (au >= 0.0f || av >= 0.0f) {
        if (au != av)
            return fail_at(L, n, "anisotropic roughness (alpha_u != alpha_v) is not supported");
        b->alpha = au;
    }
    if (!(b->alpha > 1e-4f) || b->alpha > 4.0f)
        return fail_at(L, n, "alpha = %g is out of range (1e-4, 4]", (double)b->alpha);
    return 1;
}

static int get_conductor(loader *L, xml_node *n, bsdf *b)
{
    const char *material;
    if (!get_string(L, n, "material", "none", &material))
        return 0;
    if (strcmp(material, "none"))
        return fail_at(L, n, "named conductor materials ('%s') are not supported: give eta "
                       "and k", material);
    /* "none" is Mitsuba's default: a perfect mirror (eta 0, k 1 gives F = 1). */
    return get_rgb(L, n, "eta", rgb_gray(0.0f), &b->eta) &&
           get_rgb(L, n, "k", rgb_gray(1.0f), &b->k) &&
           get_texture(L, n, "specular_reflectance", rgb_gray(1.0f), &b->specular);
}

/* The single nested material of a twosided BSDF or a shape: <bsdf> or <ref>. */
int nested_bsdf(loader *L, xml_node *c, int *index)
{
    c->used = 1;
    if (!strcmp(c->name, "bsdf"))
        return parse_bsdf(L, c, index);
    const named_object *o = resolve_ref(L, c, OBJ_BSDF, "bsdf");
    if (!o)
        return 0;
    *index = o->index;
    return 1;
}

/* The one material inside a twosided, a mask or a bumpmap. Other children (the mask's
 * opacity) are left for the caller; children already used (the bumpmap's height) are
 * skipped. */
static int wrapped_bsdf(loader *L, xml_node *n, const char *type, int *inner)
{
    *inner = -1;
    for (int i = 0; i < n->nchildren; ++i) {
        xml_node *c = n->children[i];
        const char *role = xml_attr(c, "name");
        const int opacity_ref = !strcmp(c->name, "ref") && role && !strcmp(role, "opacity");
        if (c->used || (strcmp(c->name, "bsdf") && (strcmp(c->name, "ref") || opacity_ref)))
            continue; /* used: the bumpmap's height texture */
        if (*inner >= 0)
            return fail_at(L, c, "%s takes one material%s", type,
                           type[0] == 't' ? " (two sides that differ are not supported)" : "");
        if (!nested_bsdf(L, c, inner))
            return 0;
    }
    return *inner >= 0 || fail_at(L, n, "%s needs a nested <bsdf> or <ref>", type);
}

/* The bumpmap's one height texture: a nested <texture> (any name) or a <ref> to one. */
static int bump_height(loader *L, xml_node *n, const texture **out)
{
    *out = NULL;
    for (int i = 0; i < n->nchildren; ++i) {
        xml_node *c = n->children[i];
        const named_object *o = NULL;
        if (!strcmp(c->name, "ref")) {
            const char *id = xml_attr(c, "id");
            o = id ? find_object(L, id) : NULL;
            if (!o || o->kind != OBJ_TEXTURE)
                continue; /* a material's ref, or an error wrapped_bsdf reports */
        } else if (strcmp(c->name, "texture")) {
            continue;
        }
        if (*out)
            return fail_at(L, c, "bumpmap takes one texture");
        if (o) {
            if (!resolve_ref(L, c, OBJ_TEXTURE, "texture"))
                return 0;
            c->used = 1;
            *out = L->s->textures[o->index];
        } else if (!(*out = parse_texture(L, c))) {
            return 0;
        }
    }
    return *out != NULL || fail_at(L, n, "bumpmap needs a nested <texture> or a <ref> to one");
}

int parse_bsdf(loader *L, xml_node *n, int *index)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    bsdf b;
    memset(&b, 0, sizeof b);
    int ok = 1;
    float int_ior, ext_ior;
    if (!strcmp(type, "twosided")) {
        int inner;
        if (!wrapped_bsdf(L, n, type, &inner))
            return 0;
        b = L->s->bsdfs[inner];
        if (bsdf_transmits(&b))
            return fail_at(L, n, "a twosided dielectric makes no sense");
        b.twosided = 1;
    } else if (!strcmp(type, "mask")) {
        int inner;
        const texture *opacity;
        if (!wrapped_bsdf(L, n, type, &inner) ||
            !get_texture(L, n, "opacity", rgb_gray(0.5f), &opacity))
            return 0;
        b = L->s->bsdfs[inner];
        if (b.type == BSDF_NULL)
            return fail_at(L, n, "a mask over the null material is the null material");
        b.opacity = opacity;
    } else if (!strcmp(type, "bumpmap")) {
        int inner;
        const texture *height;
        if (!bump_height(L, n, &height) || !wrapped_bsdf(L, n, type, &inner) ||
            !get_float(L, n, "scale", 1.0f, &b.bump_scale))
            return 0;
        float scale = b.bump_scale;
        b = L->s->bsdfs[inner];
        if (b.type == BSDF_NULL)
            return fail_at(L, n, "a bumpmap over the null material has no surface to tilt");
        if (b.bump)
            return fail_at(L, n, "a bumpmap inside a bumpmap is not supported");
        if (!isfinite(scale))
            return fail_at(L, n, "'scale' must be finite");
        b.bump = height;
        b.bump_scale = scale;
    } else if (!strcmp(type, "diffuse")) {
        b.type = BSDF_DIFFUSE;
        ok = get_texture(L, n, "reflectance", rgb_gray(0.5f), &b.diffuse);
    } else if (!strcmp(type, "conductor")) {
        b.type = BSDF_CONDUCTOR;
        ok = get_conductor(L, n, &b);
    } else if (!strcmp(type, "roughconductor")) {
        b.type = BSDF_ROUGHCONDUCTOR;
        ok = get_conductor(L, n, &b) && get_roughness(L, n, &b);
    } else if (!strcmp(type, "dielectric") || !strcmp(type, "thindielectric")) {
        b.type = type[0] == 'd' ? BSDF_DIELECTRIC : BSDF_THINDIELECTRIC;
        ok = get_ior(L, n, "int_ior", 1.5046f, &int_ior) &&
             get_ior(L, n, "ext_ior", 1.000277f, &ext_ior) &&
             get_texture(L, n, "specular_reflectance", rgb_gray(1.0f), &b.specular) &&
             get_texture(L, n, "specular_transmittance", rgb_gray(1.0f), &b.transmission);
        b.ior = ok ? int_ior / ext_ior : 1.0f;
    } else if (!strcmp(type, "roughdielectric")) {
        b.type = BSDF_ROUGHDIELECTRIC;
        ok = get_ior(L, n, "int_ior", 1.5046f, &int_ior) &&
             get_ior(L, n, "ext_ior", 1.000277f, &ext_ior) &&
             get_texture(L, n, "specular_reflectance", rgb_gray(1.0f), &b.specular) &&
             get_texture(L, n, "specular_transmittance", rgb_gray(1.0f), &b.transmission) &&
             get_roughness(L, n, &b);
        b.ior = ok ? int_ior / ext_ior : 1.0f;
    } else if (!strcmp(type, "plastic") || !strcmp(type, "roughplastic")) {
        b.type = type[0] == 'p' ? BSDF_PLASTIC : BSDF_ROUGHPLASTIC;
        ok = get_ior(L, n, "int_ior", 1.49f, &int_ior) &&
             get_ior(L, n, "ext_ior", 1.000277f, &ext_ior) &&
             get_texture(L, n, "diffuse_reflectance", rgb_gray(0.5f), &b.diffuse) &&
             get_texture(L, n, "specular_reflectance", rgb_gray(1.0f), &b.specular) &&
             get_bool(L, n, "nonlinear", 0, &b.nonlinear) &&
             (b.type == BSDF_PLASTIC || get_roughness(L, n, &b));
        b.ior = ok ? int_ior / ext_ior : 1.0f;
    } else if (!strcmp(type, "null")) {
        b.type = BSDF_NULL; /* the invisible boundary of a medium (render/vertex.c) */
    } else {
        return fail_at(L, n, "unsupported BSDF type '%s' (diffuse, twosided, mask, bumpmap, "
                       "conductor, roughconductor, dielectric, thindielectric, "
                       "roughdielectric, plastic, roughplastic, null)", type);
    }
    if (!ok || !check_all_used(L, n))
        return 0;
    if ((bsdf_transmits(&b) || b.type == BSDF_PLASTIC || b.type == BSDF_ROUGHPLASTIC) &&
        fabsf(b.ior - 1.0f) < 1e-6f)
        return fail_at(L, n, "int_ior equals ext_ior: the interface would be invisible");
    bsdf_prepare(&b);
    bsdf *grown = realloc(L->s->bsdfs, (size_t)(L->s->nbsdfs + 1) * sizeof *grown);
    if (!grown)
        return fail_at(L, n, "out of memory");
    L->s->bsdfs = grown;
    *index = L->s->nbsdfs;
    L->s->bsdfs[L->s->nbsdfs++] = b;
    return register_object(L, n, OBJ_BSDF, *index);
}
