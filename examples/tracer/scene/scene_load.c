/*
 * scene_load.c - the scene file as a whole (the subset of Mitsuba 3's format described in
 * docs/scene-format.md): <default> parameters and their $substitution, shapes, emitters, the
 * sensor and the integrator. Textures and materials are in scene_materials.c, the typed
 * parameters of an element in scene_props.c.
 */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "progress.h"
#include "scene_xml.h"

/* ---- Emitters ------------------------------------------------------------------------------ */

static int parse_area_emitter(loader *L, xml_node *n, rgb *radiance)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    if (strcmp(type, "area"))
        return fail_at(L, n, "only 'area' emitters can be attached to a shape");
    xml_node *r;
    if (!find_prop(L, n, "radiance", &r))
        return 0;
    if (!r)
        return fail_at(L, n, "missing parameter 'radiance'");
    if (!strcmp(r->name, "texture") || !strcmp(r->name, "ref"))
        return fail_at(L, r, "textured emission is not supported: give a colour");
    if (!parse_colour(L, r, radiance) || !check_all_used(L, n))
        return 0;
    return 1;
}

static int parse_environment(loader *L, xml_node *n)
{
    const char *type = plugin_type(L, n);
    environment *env = &L->s->env;
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    if (!strcmp(type, "area"))
        return fail_at(L, n, "an area emitter must be nested in a <shape>");
    if (strcmp(type, "constant") && strcmp(type, "envmap"))
        return fail_at(L, n, "unsupported emitter type '%s' (area, constant, envmap)", type);
    if (env->kind != ENV_NONE)
        return fail_at(L, n, "only one environment emitter (constant or envmap) is supported");
    env->scale = 1.0f;
    env->to_world = env->to_local = mat4_identity();
    if (!strcmp(type, "constant")) {
        env->kind = ENV_CONSTANT;
        if (!get_rgb(L, n, "radiance", rgb_gray(1.0f), &env->radiance))
            return 0;
    } else {
        const char *file;
        char path[4096];
        if (!get_string(L, n, "filename", NULL, &file) || !get_float(L, n, "scale", 1.0f, &env->scale) ||
            !get_transform(L, n, "to_world", &env->to_world))
            return 0;
        if (!file)
            return fail_at(L, n, "missing parameter 'filename'");
        if (!mat4_inverse(&env->to_world, &env->to_local))
            return fail_at(L, n, "to_world is not invertible");
        if (!resolve_path(L, n, file, path, sizeof path))
            return 0;
        tr_error e;
        if (!image_read_exr(path, &env->map, &e))
            return fail_at(L, n, "%s", e.msg);
        /* Negative values (from filtering in some tools) would break importance sampling. */
        size_t count = (size_t)env->map.width * (size_t)env->map.height * 3u;
        for (size_t i = 0; i < count; ++i)
            if (!(env->map.data[i] > 0.0f))
                env->map.data[i] = 0.0f;
        env->kind = ENV_ENVMAP;
    }
    return check_all_used(L, n);
}

/* ---- Shapes -------------------------------------------------------------------------------- */

/* A <point> child, `value="x, y, z"` and/or x, y, z attributes, into *out. */
static int read_point(loader *L, xml_node *c, vec3 *out)
{
    static const char *const allowed[] = {"name", "value", "x", "y", "z", NULL};
    c->used = 1;
    if (strcmp(c->name, "point") || !check_attrs(L, c, allowed))
        return strcmp(c->name, "point") ? wrong_type(L, c, "point") : 0;
    double v[3] = {out->x, out->y, out->z};
    int count;
    if (xml_attr(c, "value")) {
        if (!parse_numbers(L, c, "value", xml_attr(c, "value"), v, 3, &count))
            return 0;
        if (count != 3)
            return fail_at(L, c, "a point needs 3 numbers");
    }
    static const char *const axes[3] = {"x", "y", "z"};
    for (int a = 0; a < 3; ++a)
        if (xml_attr(c, axes[a]) && !parse_number_attr(L, c, axes[a], &v[a]))
            return 0;
    *out = v3((float)v[0], (float)v[1], (float)v[2]);
    return 1;
}

/* The shape's geometry in its own space: a mesh file or a built-in shape. */
static int load_shape_geometry(loader *L, xml_node *n, const char *type, mesh *m,
                               int *face_normals)
{
    tr_error e;
    int ok;
    if (!strcmp(type, "ply") || !strcmp(type, "obj")) {
        const char *file;
        char path[4096];
        int flip_uv = 1;
        if (!get_string(L, n, "filename", NULL, &file) ||
            !get_bool(L, n, "face_normals", 0, face_normals) ||
            !get_bool(L, n, "flip_tex_coords", 1, &flip_uv))
            return 0;
        if (!file)
            return fail_at(L, n, "missing parameter 'filename'");
        if (!resolve_path(L, n, file, path, sizeof path))
            return 0;
        ok = type[0] == 'p' ? mesh_load_ply(path, m, &e) : mesh_load_obj(path, m, &e);
        if (!ok)
            return fail_at(L, n, "%s", e.msg);
        /* Bitmaps have v = 0 at their top row, mesh files usually at the bottom: flip v.
         * Mitsuba does so for OBJ only; we do it for PLY too, which is what the shipped
         * Veach Ajar's PLY files and its (Tungsten) reference need. flip_tex_coords=false
         * gives Mitsuba's PLY behaviour. */
        if (flip_uv && m->uv)
            for (uint32_t i = 0; i < m->nverts; ++i)
                m->uv[2 * i + 1] = 1.0f - m->uv[2 * i + 1];
        return 1;
    }
    if (!strcmp(type, "rectangle"))
        ok = mesh_make_rectangle(m, &e);
    else if (!strcmp(type, "cube"))
        ok = mesh_make_cube(m, &e);
    else if (!strcmp(type, "disk"))
        ok = mesh_make_disk(m, &e);
    else if (!strcmp(type, "sphere")) {
        vec3 center = v3(0.0f, 0.0f, 0.0f);
        float radius;
        xml_node *c;
        if (!find_prop(L, n, "center", &c) || (c && !read_point(L, c, &center)) ||
            !get_float(L, n, "radius", 1.0f, &radius))
            return 0;
        if (!(radius > 0.0f))
            return fail_at(L, n, "the radius must be > 0");
        ok = mesh_make_sphere(m, center, radius, &e);
    } else
        return fail_at(L, n, "unsupported shape type '%s' (ply, obj, rectangle, disk, cube, "
                       "sphere)", type);
    return ok || fail_at(L, n, "%s", e.msg);
}

/* Nested objects: one material, at most one area emitter, an interior and an exterior
 * medium (<medium name="interior"> or <ref name="interior" id="...">). */
static int parse_shape_children(loader *L, xml_node *n, shape *sh)
{
    for (int i = 0; i < n->nchildren; ++i) {
        xml_node *c = n->children[i];
        const char *role = xml_attr(c, "name");
        int ok = 1;
        if (!strcmp(c->name, "medium") ||
            (!strcmp(c->name, "ref") && role &&
             (!strcmp(role, "interior") || !strcmp(role, "exterior")))) {
            if (!role || (strcmp(role, "interior") && strcmp(role, "exterior")))
                return fail_at(L, c, "a medium in a shape needs name=\"interior\" or "
                               "name=\"exterior\"");
            int *slot = role[0] == 'i' ? &sh->interior : &sh->exterior;
            if (*slot >= 0)
                return fail_at(L, c, "the shape's %s medium is given twice", role);
            ok = nested_medium(L, c, slot);
            sh->media_boundary = 1;
        } else if (!strcmp(c->name, "bsdf") || !strcmp(c->name, "ref")) {
            if (sh->bsdf >= 0)
                return fail_at(L, c, "a shape takes one material");
            ok = nested_bsdf(L, c, &sh->bsdf);
        } else if (!strcmp(c->name, "emitter")) {
            if (sh->emissive)
                return fail_at(L, c, "a shape takes one emitter");
            ok = parse_area_emitter(L, c, &sh->radiance);
            sh->emissive = 1;
        }
        if (!ok)
            return 0;
    }
    return check_all_used(L, n);
}

/* The mesh moved to world space, every vertex checked, normals made; a media boundary must
 * be closed. */
static int place_shape(loader *L, xml_node *n, const char *type, shape *sh,
                       const mat4 *to_world, int face_normals, int flip)
{
    tr_error e;
    mesh_transform(&sh->m, to_world);
    for (uint32_t i = 0; i < sh->m.nverts; ++i) {
        const vec3 p = sh->m.p[i];
        const double pd[3] = {p.x, p.y, p.z};
        char what[80];
        snprintf(what, sizeof what, "vertex %u of %u (after to_world) is at", (unsigned)i,
                 (unsigned)sh->m.nverts);
        if (!check_world(L, n, what, pd, 3))
            return 0;
    }
    if (!mesh_finish(&sh->m, face_normals, flip, &e))
        return fail_at(L, n, "%s", e.msg);
    if (sh->m.ntris == 0)
        return 1; /* parse_shape skips it */
    /* Which side of a boundary a ray is on is only defined for a closed surface. The
     * built-in sphere is closed by construction (its seam's vertices differ by a float
     * rounding, which a check by position would call open). */
    return !sh->media_boundary || !strcmp(type, "sphere") || check_closed(L, n, &sh->m);
}

/* Mitsuba's default material where none is given (diffuse, reflectance 0.5); a null
 * material makes the shape a boundary only, which cannot emit. */
static int shape_material(loader *L, xml_node *n, shape *sh)
{
    if (sh->bsdf < 0) {
        bsdf b;
        memset(&b, 0, sizeof b);
        b.type = BSDF_DIFFUSE;
        b.diffuse = constant_texture(L, n, rgb_gray(0.5f));
        bsdf *grown = b.diffuse ? realloc(L->s->bsdfs, (size_t)(L->s->nbsdfs + 1) * sizeof *grown)
                                : NULL;
        if (!grown)
            return fail_at(L, n, "out of memory");
        L->s->bsdfs = grown;
        sh->bsdf = L->s->nbsdfs;
        L->s->bsdfs[L->s->nbsdfs++] = b;
    }
    /* A masked shape is missing from the rays that pass it by: light sampling, which aims
     * at the whole emitter, and the media walk, which counts boundary crossings, would
     * both disagree with them. */
    if (L->s->bsdfs[sh->bsdf].opacity && sh->emissive)
        return fail_at(L, n, "a shape with a mask material cannot emit");
    if (L->s->bsdfs[sh->bsdf].opacity && sh->media_boundary)
        return fail_at(L, n, "a shape with a mask material cannot bound a medium");
    if (L->s->bsdfs[sh->bsdf].type == BSDF_NULL) {
        if (sh->emissive)
            return fail_at(L, n, "a shape with the null material cannot emit");
        sh->null_surface = 1;
        L->s->has_media = 1;
    }
    return 1;
}

static int parse_shape(loader *L, xml_node *n)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    shape sh;
    memset(&sh, 0, sizeof sh);
    sh.bsdf = sh.interior = sh.exterior = -1;
    int face_normals = 0, flip = 0;
    mat4 to_world;
    if (!get_transform(L, n, "to_world", &to_world) || !get_bool(L, n, "flip_normals", 0, &flip) ||
        !load_shape_geometry(L, n, type, &sh.m, &face_normals))
        return 0;
    int ok = parse_shape_children(L, n, &sh) &&
             place_shape(L, n, type, &sh, &to_world, face_normals, flip) &&
             shape_material(L, n, &sh);
    if (ok && sh.m.ntris == 0) {
        /* Mitsuba 3 loads such a mesh and never hits it; we leave it out and say so. */
        const char *file = xml_attr(n, "type");
        xml_node *f;
        if (find_prop(L, n, "filename", &f) && f && xml_attr(f, "value"))
            file = xml_attr(f, "value");
        mesh_free(&sh.m);
        return scene_warn(L->s, "%s:%d: skipped the shape '%s': it has no triangle of "
                          "non-zero area", L->file, n->line, file) ||
               fail_at(L, n, "out of memory");
    }
    shape *grown = ok ? realloc(L->s->shapes, (size_t)(L->s->nshapes + 1) * sizeof *grown) : NULL;
    if (!grown) {
        mesh_free(&sh.m);
        return ok ? fail_at(L, n, "out of memory") : 0;
    }
    L->s->shapes = grown;
    L->s->shapes[L->s->nshapes++] = sh;
    return register_object(L, n, OBJ_OTHER, L->s->nshapes - 1);
}

/* ---- Sensor and integrator ---------------------------------------------------------------- */

static int parse_film(loader *L, xml_node *film)
{
    const char *type = plugin_type(L, film);
    const char *ignored;
    int flag;
    film->used = 1;
    if (!type || !check_plugin_attrs(L, film))
        return 0;
    if (strcmp(type, "hdrfilm"))
        return fail_at(L, film, "unsupported film type '%s' (hdrfilm)", type);
    if (!get_int(L, film, "width", 768, &L->s->width) ||
        !get_int(L, film, "height", 576, &L->s->height) ||
        /* Output formats: we always write float RGB EXR (and a PNG preview). */
        !get_string(L, film, "file_format", NULL, &ignored) ||
        !get_string(L, film, "pixel_format", NULL, &ignored) ||
        !get_string(L, film, "component_format", NULL, &ignored) ||
        /* Mitsuba 3 accepts both and draws no banner; our box filter has no edges to
         * treat. */
        !get_bool(L, film, "banner", 0, &flag) ||
        !get_bool(L, film, "high_quality_edges", 0, &flag))
        return 0;
    if (L->s->width <= 0 || L->s->height <= 0 || L->s->width > 65536 || L->s->height > 65536)
        return fail_at(L, film, "bad film size %d x %d", L->s->width, L->s->height);
    for (int i = 0; i < film->nchildren; ++i)
        if (!strcmp(film->children[i]->name, "rfilter"))
            accept_ignored(film->children[i]); /* we always use a box filter */
    return check_all_used(L, film);
}

static int parse_sensor(loader *L, xml_node *n)
{
    const char *type = plugin_type(L, n), *axis;
    float ignored;
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    if (L->have_sensor)
        return fail_at(L, n, "only one sensor is supported");
    if (strcmp(type, "perspective"))
        return fail_at(L, n, "unsupported sensor type '%s' (perspective)", type);
    L->have_sensor = 1;
    L->s->camera_medium = -1;
    L->s->width = 768;
    L->s->height = 576;
    if (!get_float(L, n, "fov", 0.0f, &L->s->fov_degrees) ||
        !get_string(L, n, "fov_axis", "x", &axis) ||
        !get_transform(L, n, "to_world", &L->s->camera_to_world) ||
        /* Clipping planes only matter for geometry right at the camera. */
        !get_float(L, n, "near_clip", 0.01f, &ignored) ||
        !get_float(L, n, "far_clip", 1e4f, &ignored))
        return 0;
    if (!(L->s->fov_degrees > 0.0f && L->s->fov_degrees < 180.0f))
        return fail_at(L, n, "needs a 'fov' in (0, 180) degrees");
    /* The transform's entries are in range (parse_transform); a projective one can still
     * divide the origin by a tiny w. A singular one would give every camera ray the same
     * degenerate direction. */
    const vec3 o = mat4_point(&L->s->camera_to_world, v3(0.0f, 0.0f, 0.0f));
    const double od[3] = {o.x, o.y, o.z};
    mat4 inverse;
    if (!check_world(L, n, "the camera origin is at", od, 3))
        return 0;
    if (!mat4_inverse(&L->s->camera_to_world, &inverse))
        return fail_at(L, n, "to_world is not invertible");
    static const char *const axes[] = {"x", "y", "diagonal", "smaller", "larger"};
    L->s->fov_axis = -1;
    for (int i = 0; i < 5; ++i)
        if (!strcmp(axis, axes[i]))
            L->s->fov_axis = i;
    if (L->s->fov_axis < 0)
        return fail_at(L, n, "unknown fov_axis '%s'", axis);
    for (int i = 0; i < n->nchildren; ++i) {
        xml_node *c = n->children[i];
        if (!strcmp(c->name, "film")) {
            if (!parse_film(L, c))
                return 0;
        } else if (!strcmp(c->name, "sampler")) {
            accept_ignored(c); /* we draw independent samples; --spp sets their number */
        } else if (!strcmp(c->name, "medium") || !strcmp(c->name, "ref")) {
            /* the medium the camera is in (Mitsuba: any medium nested in the sensor) */
            if (L->s->camera_medium >= 0)
                return fail_at(L, c, "the sensor takes one medium");
            if (!nested_medium(L, c, &L->s->camera_medium))
                return 0;
        }
    }
    return check_all_used(L, n);
}

static int parse_integrator(loader *L, xml_node *n)
{
    const char *type = plugin_type(L, n);
    n->used = 1;
    if (!type || !check_plugin_attrs(L, n))
        return 0;
    /* volpath renders media; path ignores them (ignore_media), as in Mitsuba 3. */
    if (strcmp(type, "path") && strcmp(type, "volpath"))
        return fail_at(L, n, "unsupported integrator '%s' (path, volpath)", type);
    L->s->volumetric = !strcmp(type, "volpath");
    if (!get_int(L, n, "max_depth", -1, &L->s->max_depth) ||
        !get_int(L, n, "rr_depth", 5, &L->s->rr_depth) ||
        !get_bool(L, n, "hide_emitters", 0, &L->s->hide_emitters))
        return 0;
    if (L->s->max_depth < -1 || L->s->max_depth == 0)
        return fail_at(L, n, "max_depth must be -1 (unlimited) or >= 1");
    if (L->s->rr_depth < 1)
        return fail_at(L, n, "rr_depth must be >= 1");
    return check_all_used(L, n);
}

/* ---- $parameters -------------------------------------------------------------------------- */

typedef struct parameter {
    const char *name, *value;
} parameter;

static int substitute(loader *L, xml_node *n, const parameter *params, int nparams)
{
    for (int i = 0; i < n->nattrs; ++i) {
        const char *v = n->attrs[2 * i + 1];
        if (!strchr(v, '$'))
            continue;
        char out[4096];
        size_t len = 0;
        for (const char *p = v; *p;) {
            if (*p != '$') {
                if (len + 1 < sizeof out)
                    out[len++] = *p;
                ++p;
                continue;
            }
            const char *start = ++p;
            while (isalnum((unsigned char)*p) || *p == '_')
                ++p;
            size_t nlen = (size_t)(p - start);
            const char *value = NULL;
            for (int k = 0; k < nparams && !value; ++k)
                if (strlen(params[k].name) == nlen && !strncmp(params[k].name, start, nlen))
                    value = params[k].value;
            if (!value)
                return fail_at(L, n, "undefined parameter '$%.*s' (declare it with <default>)",
                               (int)nlen, start);
            size_t vl = strlen(value);
            if (len + vl >= sizeof out)
                return fail_at(L, n, "attribute too long after substitution");
            memcpy(out + len, value, vl);
            len += vl;
        }
        out[len] = '\0';
        if (!xml_set_attr(n, i, out))
            return fail_at(L, n, "out of memory");
    }
    for (int i = 0; i < n->nchildren; ++i)
        if (!substitute(L, n->children[i], params, nparams))
            return 0;
    return 1;
}

/* ---- The scene ---------------------------------------------------------------------------- */

/* Mitsuba 3's path integrator (the default one) renders no media: it starts every path in
 * vacuum and changes medium nowhere. Null surfaces stay invisible boundaries
 * (docs/scene-format.md lists how Mitsuba's path treats them instead). The media stay loaded
 * and checked. */
static void ignore_media(scene *s)
{
    s->media_ignored = s->nmedia > 0;
    s->camera_medium = -1;
    s->has_media = 0;
    for (int i = 0; i < s->nshapes; ++i) {
        shape *sh = &s->shapes[i];
        sh->interior = sh->exterior = -1;
        sh->media_boundary = 0;
        s->has_media |= sh->null_surface;
    }
}

static int load_tree(loader *L, xml_node *root)
{
    scene *s = L->s;
    static const char *const scene_attrs[] = {"version", NULL};
    static const char *const default_attrs[] = {"name", "value", NULL};
    if (strcmp(root->name, "scene"))
        return fail_at(L, root, "the root element must be <scene>");
    if (!check_attrs(L, root, scene_attrs) || !scene_upgrade(L, root))
        return 0;
    root->used = 1;
    s->max_depth = -1;
    s->rr_depth = 5;
    s->camera_to_world = mat4_identity();
    s->camera_medium = -1;

    /* <default> parameters first, then substitute them everywhere. */
    parameter *params = calloc((size_t)root->nchildren + 1, sizeof *params);
    int nparams = 0;
    if (!params)
        return fail_at(L, root, "out of memory");
    for (int i = 0; i < root->nchildren; ++i) {
        xml_node *c = root->children[i];
        if (strcmp(c->name, "default"))
            continue;
        c->used = 1;
        const char *name = check_attrs(L, c, default_attrs) ? require_attr(L, c, "name") : NULL;
        const char *value = name ? require_attr(L, c, "value") : NULL;
        if (!value) {
            free(params);
            return 0;
        }
        params[nparams++] = (parameter){name, value};
    }
    int ok = substitute(L, root, params, nparams);
    free(params);
    if (!ok)
        return 0;

    progress bar; /* big meshes and textures take a while */
    progress_start(&bar, "loading", (size_t)root->nchildren);
    for (int i = 0; i < root->nchildren && ok; ++i) {
        xml_node *c = root->children[i];
        int index;
        progress_update(&bar, (size_t)i, NULL);
        if (!strcmp(c->name, "default"))
            continue;
        else if (!strcmp(c->name, "integrator"))
            ok = parse_integrator(L, c);
        else if (!strcmp(c->name, "sensor"))
            ok = parse_sensor(L, c);
        else if (!strcmp(c->name, "bsdf"))
            ok = parse_bsdf(L, c, &index);
        else if (!strcmp(c->name, "texture"))
            ok = parse_texture(L, c) != NULL;
        else if (!strcmp(c->name, "shape"))
            ok = parse_shape(L, c);
        else if (!strcmp(c->name, "emitter"))
            ok = parse_environment(L, c);
        else if (!strcmp(c->name, "medium"))
            ok = parse_medium(L, c, &index);
        else
            ok = fail_at(L, c, "unknown or unsupported element <%s> in <scene>", c->name);
    }
    progress_finish(&bar);
    if (ok && !L->have_sensor)
        ok = fail_at(L, root, "the scene has no <sensor>");
    if (ok && !s->volumetric)
        ignore_media(s);
    return ok;
}

static int load(const char *file, const char *dir, xml_node *root, scene *s, tr_error *err)
{
    loader L;
    memset(&L, 0, sizeof L);
    L.s = s;
    L.file = file;
    L.err = err;
    snprintf(L.dir, sizeof L.dir, "%s", dir ? dir : "");
    int ok = load_tree(&L, root);
    free(L.objects);
    xml_free(root);
    if (ok) {
        tr_error e;
        if (!scene_finalize(s, &e))
            ok = tr_fail(err, "%s: %s", file, e.msg);
    }
    if (ok)
        scene_set_resolution(s, s->width, s->height);
    else
        scene_free(s);
    return ok;
}

int scene_load(const char *path, scene *s, tr_error *err)
{
    xml_node *root;
    memset(s, 0, sizeof *s);
    if (!xml_parse_file(path, &root, err))
        return 0;
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = '\0';
    else
        snprintf(dir, sizeof dir, ".");
    if (!load(path, dir, root, s, err))
        return 0;
    size_t n = strlen(path) + 1;
    if ((s->path = malloc(n)) != NULL)
        memcpy(s->path, path, n);
    return 1;
}

int scene_load_string(const char *xml, const char *dir, scene *s, tr_error *err)
{
    xml_node *root;
    memset(s, 0, sizeof *s);
    if (!xml_parse_string(xml, "<string>", &root, err))
        return 0;
    return load("<string>", dir, root, s, err);
}
