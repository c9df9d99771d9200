/*
 * scene_props.c - the scene loader's vocabulary (see scene_xml.h): error messages that name
 * the file, the line and the element; attributes and numbers; ids and references; and the
 * typed parameters of an element, including transforms.
 */
#include <ctype.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "scene_xml.h"

/* ---- Errors ------------------------------------------------------------------------------ */

/* "file:line: <tag a="v" ...>: message" */
int fail_at(loader *L, const xml_node *n, const char *fmt, ...)
{
    char what[600], tag[300];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    size_t len = (size_t)snprintf(tag, sizeof tag, "<%s", n->name);
    for (int i = 0; i < n->nattrs && len < sizeof tag; ++i)
        len += (size_t)snprintf(tag + len, sizeof tag - len, " %s=\"%s\"", n->attrs[2 * i],
                                n->attrs[2 * i + 1]);
    if (len < sizeof tag)
        snprintf(tag + len, sizeof tag - len, ">");
    return tr_fail(L->err, "%s:%d: %s: %s", L->file, n->line, tag, what);
}

/* ---- Attributes and numbers --------------------------------------------------------------- */

int check_attrs(loader *L, const xml_node *n, const char *const *allowed)
{
    for (int i = 0; i < n->nattrs; ++i) {
        int ok = 0;
        for (const char *const *a = allowed; *a && !ok; ++a)
            ok = !strcmp(n->attrs[2 * i], *a);
        if (!ok)
            return fail_at(L, n, "unknown attribute '%s'", n->attrs[2 * i]);
    }
    return 1;
}

const char *require_attr(loader *L, const xml_node *n, const char *name)
{
    const char *v = xml_attr(n, name);
    if (!v)
        fail_at(L, n, "missing attribute '%s'", name);
    return v;
}

/* Parses 1..max numbers separated by commas and/or whitespace. */
int parse_numbers(loader *L, const xml_node *n, const char *attr, const char *text,
                  double *out, int max, int *count)
{
    const char *p = text;
    *count = 0;
    for (;;) {
        while (isspace((unsigned char)*p) || *p == ',')
            ++p;
        if (!*p)
            break;
        if (*count == max)
            return fail_at(L, n, "too many numbers in %s=\"%s\" (at most %d)", attr, text, max);
        char *end;
        errno = 0;
        double v = strtod(p, &end);
        if (end == p || !isfinite(v) || (*end && !isspace((unsigned char)*end) && *end != ','))
            return fail_at(L, n, "'%s' is not a number (in %s=\"%s\")", p, attr, text);
        /* Most numbers end up in floats, where a larger one would become infinite. */
        if (fabs(v) > FLT_MAX)
            return fail_at(L, n, "'%.*s' is out of range (in %s=\"%s\"): numbers must lie "
                           "within +-%g", (int)(end - p), p, attr, text, (double)FLT_MAX);
        out[(*count)++] = v;
        p = end;
    }
    if (*count == 0)
        return fail_at(L, n, "%s=\"%s\" holds no number", attr, text);
    return 1;
}

int parse_number_attr(loader *L, const xml_node *n, const char *attr, double *out)
{
    const char *v = require_attr(L, n, attr);
    int count;
    if (!v || !parse_numbers(L, n, attr, v, out, 1, &count))
        return 0;
    return 1;
}

int parse_vec3_attr(loader *L, const xml_node *n, const char *attr, vec3 *out)
{
    double v[3];
    int count;
    const char *text = require_attr(L, n, attr);
    if (!text || !parse_numbers(L, n, attr, text, v, 3, &count))
        return 0;
    if (count != 3)
        return fail_at(L, n, "%s needs 3 numbers", attr);
    *out = v3((float)v[0], (float)v[1], (float)v[2]);
    return 1;
}

/* ---- The world's range --------------------------------------------------------------------- */

int check_world(loader *L, const xml_node *n, const char *what, const double *v, int count)
{
    int ok = 1;
    for (int i = 0; i < count; ++i)
        ok = ok && fabs(v[i]) <= SCENE_WORLD_LIMIT; /* false for NaN */
    if (ok)
        return 1;
    char values[160];
    size_t len = 0;
    for (int i = 0; i < count && len < sizeof values; ++i) {
        /* %g, unless it would round a value just outside the range to one inside it (a
         * vertex at 1000000128 would read "1e+09"). */
        char shown[40];
        snprintf(shown, sizeof shown, "%g", v[i]);
        if (!(fabs(v[i]) <= SCENE_WORLD_LIMIT) && fabs(strtod(shown, NULL)) <= SCENE_WORLD_LIMIT)
            snprintf(shown, sizeof shown, "%.10g", v[i]);
        len += (size_t)snprintf(values + len, sizeof values - len, "%s%s", i ? ", " : "", shown);
    }
    return fail_at(L, n, "%s (%s), outside the world-space range: coordinates must be "
                   "finite and within +-%g (docs/scene-format.md, \"Limits\")", what, values,
                   SCENE_WORLD_LIMIT);
}

/* Every entry of a transform: the images of the origin and of the unit vectors, and the
 * projective row. */
static int check_world_transform(loader *L, const xml_node *n, const mat4 *m)
{
    static const char *const what[4] = {"the transform maps the origin to",
                                        "the transform maps the unit x vector to",
                                        "the transform maps the unit y vector to",
                                        "the transform maps the unit z vector to"};
    static const int column[4] = {3, 0, 1, 2};
    for (int k = 0; k < 4; ++k) {
        const int c = column[k];
        const double image[3] = {m->m[0][c], m->m[1][c], m->m[2][c]};
        if (!check_world(L, n, what[k], image, 3))
            return 0;
    }
    return check_world(L, n, "the transform's projective row is", m->m[3], 4);
}

/* ---- Object registry ----------------------------------------------------------------------- */

const named_object *find_object(const loader *L, const char *id)
{
    for (int i = 0; i < L->nobjects; ++i)
        if (!strcmp(L->objects[i].id, id))
            return &L->objects[i];
    return NULL;
}

int register_object(loader *L, const xml_node *n, object_kind kind, int index)
{
    const char *id = xml_attr(n, "id");
    if (!id)
        return 1;
    if (find_object(L, id))
        return fail_at(L, n, "the id '%s' is used twice", id);
    named_object *grown = realloc(L->objects, (size_t)(L->nobjects + 1) * sizeof *grown);
    if (!grown)
        return fail_at(L, n, "out of memory");
    L->objects = grown;
    L->objects[L->nobjects++] = (named_object){id, kind, index, n};
    return 1;
}

/* The target of <ref id="..."/>, which must be of the expected kind. */
const named_object *resolve_ref(loader *L, const xml_node *ref, object_kind kind,
                                const char *what)
{
    static const char *const allowed[] = {"id", "name", NULL};
    if (!check_attrs(L, ref, allowed))
        return NULL;
    const char *id = require_attr(L, ref, "id");
    if (!id)
        return NULL;
    const named_object *o = find_object(L, id);
    if (!o) {
        fail_at(L, ref, "no object with id '%s' (objects must be declared before they are "
                "referenced)", id);
        return NULL;
    }
    if (o->kind != kind) {
        fail_at(L, ref, "'%s' (line %d) is not a %s", id, o->node->line, what);
        return NULL;
    }
    return o;
}

/* ---- Files -------------------------------------------------------------------------------- */

/* A file name relative to the scene file's directory. Returns 0 (with an error naming the
 * element) when the result does not fit. */
int resolve_path(loader *L, const xml_node *n, const char *name, char *out, size_t size)
{
    int len = (name[0] == '/' || !L->dir[0]) ? snprintf(out, size, "%s", name)
                                             : snprintf(out, size, "%s/%s", L->dir, name);
    if (len < 0 || (size_t)len >= size)
        return fail_at(L, n, "the file name is too long");
    return 1;
}

/* ---- Properties ---------------------------------------------------------------------------- */

int is_property_tag(const char *tag)
{
    static const char *const tags[] = {"float", "integer", "boolean", "string", "rgb",
                                       "spectrum", "point", "vector", "transform", NULL};
    for (const char *const *t = tags; *t; ++t)
        if (!strcmp(tag, *t))
            return 1;
    return 0;
}

/* The child property called `name` (any tag), or NULL. Two of them are an error. */
int find_prop(loader *L, xml_node *plugin, const char *name, xml_node **out)
{
    xml_node *found = NULL;
    *out = NULL;
    for (int i = 0; i < plugin->nchildren; ++i) {
        xml_node *c = plugin->children[i];
        const char *cn = xml_attr(c, "name");
        if (cn && !strcmp(cn, name)) {
            if (found)
                return fail_at(L, c, "'%s' is given twice (first on line %d)", name, found->line);
            found = c;
        }
    }
    *out = found;
    return 1;
}

int wrong_type(loader *L, const xml_node *n, const char *expected)
{
    return fail_at(L, n, "'%s' must be given as <%s>", xml_attr(n, "name"), expected);
}

/* The property `name` of a plugin, given as a <tag> (or <alt>) element with only name and
 * value attributes: returns 1 with *out the element, or NULL when the plugin does not set
 * it; 0 after recording an error (duplicate, wrong element, stray attribute). */
static int find_value_prop(loader *L, xml_node *plugin, const char *name, const char *tag,
                           const char *alt, xml_node **out)
{
    static const char *const allowed[] = {"name", "value", NULL};
    xml_node *n;
    *out = NULL;
    if (!find_prop(L, plugin, name, &n))
        return 0;
    if (!n)
        return 1;
    n->used = 1;
    if (strcmp(n->name, tag) && (!alt || strcmp(n->name, alt)))
        return wrong_type(L, n, tag);
    if (!check_attrs(L, n, allowed))
        return 0;
    *out = n;
    return 1;
}

int get_float(loader *L, xml_node *plugin, const char *name, float def, float *out)
{
    xml_node *n;
    double v;
    *out = def;
    if (!find_value_prop(L, plugin, name, "float", "integer", &n))
        return 0;
    if (!n)
        return 1;
    if (!parse_number_attr(L, n, "value", &v))
        return 0;
    *out = (float)v;
    return 1;
}

int get_int(loader *L, xml_node *plugin, const char *name, int def, int *out)
{
    xml_node *n;
    double v;
    *out = def;
    if (!find_value_prop(L, plugin, name, "integer", NULL, &n))
        return 0;
    if (!n)
        return 1;
    if (!parse_number_attr(L, n, "value", &v))
        return 0;
    if (v != floor(v) || fabs(v) > 1e9)
        return fail_at(L, n, "'%s' is not an integer", xml_attr(n, "value"));
    *out = (int)v;
    return 1;
}

int get_bool(loader *L, xml_node *plugin, const char *name, int def, int *out)
{
    xml_node *n;
    *out = def;
    if (!find_value_prop(L, plugin, name, "boolean", NULL, &n))
        return 0;
    if (!n)
        return 1;
    const char *v = require_attr(L, n, "value");
    if (!v)
        return 0;
    if (!strcasecmp(v, "true"))
        *out = 1;
    else if (!strcasecmp(v, "false"))
        *out = 0;
    else
        return fail_at(L, n, "'%s' is not a boolean (true or false)", v);
    return 1;
}

/* *out is NULL when absent (and def is NULL). */
int get_string(loader *L, xml_node *plugin, const char *name, const char *def,
               const char **out)
{
    xml_node *n;
    *out = def;
    if (!find_value_prop(L, plugin, name, "string", NULL, &n))
        return 0;
    if (!n)
        return 1;
    return (*out = require_attr(L, n, "value")) != NULL;
}

/* A colour from <rgb value="r, g, b"> (or one grey value), <float> or <spectrum value="v">
 * (a constant spectrum; sampled spectra are refused). */
int parse_colour(loader *L, xml_node *n, rgb *out)
{
    static const char *const allowed[] = {"name", "value", NULL};
    double v[3];
    int count;
    n->used = 1;
    if (strcmp(n->name, "rgb") && strcmp(n->name, "float") && strcmp(n->name, "spectrum"))
        return fail_at(L, n, "expected a colour (<rgb>, <float> or <spectrum>)");
    const char *text = check_attrs(L, n, allowed) ? require_attr(L, n, "value") : NULL;
    if (!text)
        return 0;
    if (!strcmp(n->name, "spectrum") && strchr(text, ':'))
        return fail_at(L, n, "sampled spectra are not supported: give one value or use <rgb>");
    if (!parse_numbers(L, n, "value", text, v, 3, &count))
        return 0;
    if (count == 2 || (count == 3 && strcmp(n->name, "rgb")))
        return fail_at(L, n, "a colour needs 1 or 3 values");
    *out = count == 1 ? rgb_gray((float)v[0]) : rgb_make((float)v[0], (float)v[1], (float)v[2]);
    return 1;
}

int get_rgb(loader *L, xml_node *plugin, const char *name, rgb def, rgb *out)
{
    xml_node *n;
    *out = def;
    if (!find_prop(L, plugin, name, &n))
        return 0;
    return n ? parse_colour(L, n, out) : 1;
}

/* to_world, to_uv: the children in order, each applied after the previous ones. */
int parse_transform(loader *L, xml_node *t, mat4 *out)
{
    static const char *const tr_attrs[] = {"x", "y", "z", "value", NULL};
    static const char *const rot_attrs[] = {"x", "y", "z", "value", "angle", NULL};
    static const char *const mat_attrs[] = {"value", NULL};
    static const char *const look_attrs[] = {"origin", "target", "up", NULL};
    static const char *const own_attrs[] = {"name", NULL};
    t->used = 1;
    if (!check_attrs(L, t, own_attrs))
        return 0;
    mat4 m = mat4_identity();
    for (int i = 0; i < t->nchildren; ++i) {
        xml_node *c = t->children[i];
        mat4 step;
        c->used = 1;
        if (!strcmp(c->name, "translate") || !strcmp(c->name, "scale")) {
            int is_scale = c->name[0] == 's';
            double d = is_scale ? 1.0 : 0.0, v[3] = {d, d, d};
            if (!check_attrs(L, c, tr_attrs))
                return 0;
            const char *value = xml_attr(c, "value");
            if (value) {
                int count;
                if (!parse_numbers(L, c, "value", value, v, 3, &count))
                    return 0;
                if (count == 1 && is_scale)
                    v[1] = v[2] = v[0];
                else if (count != 3)
                    return fail_at(L, c, "value needs 3 numbers%s", is_scale ? " (or 1)" : "");
            }
            static const char *const axes[3] = {"x", "y", "z"};
            for (int a = 0; a < 3; ++a)
                if (xml_attr(c, axes[a]) && !parse_number_attr(L, c, axes[a], &v[a]))
                    return 0;
            step = is_scale ? mat4_scale(v[0], v[1], v[2]) : mat4_translate(v[0], v[1], v[2]);
        } else if (!strcmp(c->name, "rotate")) {
            double v[3] = {0.0, 0.0, 0.0}, angle;
            if (!check_attrs(L, c, rot_attrs))
                return 0;
            const char *value = xml_attr(c, "value");
            if (value) {
                int count;
                if (!parse_numbers(L, c, "value", value, v, 3, &count))
                    return 0;
                if (count != 3)
                    return fail_at(L, c, "value needs 3 numbers (the axis)");
            }
            static const char *const axes[3] = {"x", "y", "z"};
            for (int a = 0; a < 3; ++a)
                if (xml_attr(c, axes[a]) && !parse_number_attr(L, c, axes[a], &v[a]))
                    return 0;
            if (!parse_number_attr(L, c, "angle", &angle))
                return 0;
            if (v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0)
                return fail_at(L, c, "the rotation axis is zero");
            step = mat4_rotate(v[0], v[1], v[2], angle);
        } else if (!strcmp(c->name, "matrix")) {
            double v[16];
            int count;
            const char *value = check_attrs(L, c, mat_attrs) ? require_attr(L, c, "value") : NULL;
            if (!value || !parse_numbers(L, c, "value", value, v, 16, &count))
                return 0;
            step = mat4_identity();
            if (count == 16) {
                for (int k = 0; k < 16; ++k)
                    step.m[k / 4][k % 4] = v[k];
            } else if (count == 9) {
                for (int k = 0; k < 9; ++k)
                    step.m[k / 3][k % 3] = v[k];
            } else {
                return fail_at(L, c, "a matrix needs 16 (or 9) numbers, not %d", count);
            }
        } else if (!strcmp(c->name, "lookat")) {
            vec3 o, target, up = v3(0.0f, 0.0f, 0.0f);
            if (!check_attrs(L, c, look_attrs) || !parse_vec3_attr(L, c, "origin", &o) ||
                !parse_vec3_attr(L, c, "target", &target))
                return 0;
            const double od[3] = {o.x, o.y, o.z}, td[3] = {target.x, target.y, target.z};
            if (!check_world(L, c, "the lookat origin is at", od, 3) ||
                !check_world(L, c, "the lookat target is at", td, 3))
                return 0;
            if (xml_attr(c, "up")) {
                if (!parse_vec3_attr(L, c, "up", &up))
                    return 0;
            } else { /* any up vector perpendicular to the view */
                frame f = frame_from_normal(v3_normalize(v3_sub(target, o)));
                up = f.s;
            }
            if (!mat4_lookat(o, target, up, &step))
                return fail_at(L, c, "origin, target and up do not define a view");
        } else {
            return fail_at(L, c, "unknown transform element (expected translate, scale, rotate, "
                           "matrix or lookat)");
        }
        m = mat4_mul(&step, &m);
        /* After every step, so that the message names the step that left the range. */
        if (!check_world_transform(L, c, &m))
            return 0;
    }
    *out = m;
    return 1;
}

int get_transform(loader *L, xml_node *plugin, const char *name, mat4 *out)
{
    xml_node *n;
    *out = mat4_identity();
    if (!find_prop(L, plugin, name, &n))
        return 0;
    if (!n)
        return 1;
    if (strcmp(n->name, "transform"))
        return wrong_type(L, n, "transform");
    return parse_transform(L, n, out);
}

int check_all_used(loader *L, const xml_node *plugin)
{
    for (int i = 0; i < plugin->nchildren; ++i) {
        const xml_node *c = plugin->children[i];
        if (c->used)
            continue;
        const char *type = xml_attr(plugin, "type");
        if (is_property_tag(c->name) && !xml_attr(c, "name"))
            return fail_at(L, c, "missing attribute 'name'");
        if (is_property_tag(c->name))
            return fail_at(L, c, "unsupported parameter '%s' for <%s type=\"%s\">",
                           xml_attr(c, "name"), plugin->name, type ? type : "");
        return fail_at(L, c, "unexpected element inside <%s%s%s%s>", plugin->name,
                       type ? " type=\"" : "", type ? type : "", type ? "\"" : "");
    }
    return 1;
}

/* Marks a whole subtree used: for elements we accept but that cannot affect our images. */
void accept_ignored(xml_node *n)
{
    n->used = 1;
    for (int i = 0; i < n->nchildren; ++i)
        accept_ignored(n->children[i]);
}

const char *plugin_type(loader *L, const xml_node *n)
{
    return require_attr(L, n, "type");
}

int check_plugin_attrs(loader *L, const xml_node *n)
{
    static const char *const allowed[] = {"type", "id", "name", NULL};
    return check_attrs(L, n, allowed);
}
