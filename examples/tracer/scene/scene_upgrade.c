/*
 * scene_upgrade.c - files of scene version < 2.0.0 (Mitsuba 0.5 and 0.6, such as Bitterli's
 * interiors) rewritten in memory into today's format before they are read, with the same
 * steps as Mitsuba 3's loader (docs/tracer.md, "Older scene files", lists them):
 *
 *   - every name="..." except on <default> goes from camelCase to snake_case
 *     (toWorld -> to_world, intIOR -> int_ior, sigmaA -> sigma_a);
 *   - <lookAt> becomes <lookat>;
 *   - an id starting with '_' (reserved since 2.0) becomes "ID<id>__UPGR", in refs too;
 *   - a diffuse BSDF's diffuse_reflectance becomes reflectance;
 *   - a texture's uoffset, voffset, uscale and vscale become a to_uv transform.
 *
 * Nothing else changes: a parameter the tracer does not know is still refused by name.
 */
#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene_xml.h"

/* "a.b.c" into three numbers; 0 unless it is exactly three non-negative integers. */
static int parse_version(const char *text, int v[3])
{
    const char *p = text;
    for (int i = 0; i < 3; ++i) {
        if (!isdigit((unsigned char)*p))
            return 0;
        char *end;
        long x = strtol(p, &end, 10);
        if (x > 1000000)
            return 0;
        v[i] = (int)x;
        p = end;
        if (i < 2 && *p++ != '.')
            return 0;
    }
    return *p == '\0';
}

/* Mitsuba 3's rule, step for step: at each lower-then-upper pair insert '_' and lower the
 * run of capitals that follows ("intIOR" -> "int_ior", "toWorld" -> "to_world"); the letter
 * after such a run is not looked at as the start of a pair, as in Mitsuba's loop. */
static void snake_case(const char *in, char *out, size_t size)
{
    snprintf(out, size, "%s", in);
    size_t n = strlen(out);
    for (size_t i = 0; i + 1 < n; ++i) {
        if (!islower((unsigned char)out[i]) || !isupper((unsigned char)out[i + 1]))
            continue;
        if (n + 2 > size)
            break; /* no room for the '_': leave the rest as it is */
        memmove(out + i + 2, out + i + 1, n - i); /* the tail and its NUL */
        out[i + 1] = '_';
        ++n;
        i += 2;
        while (i < n && isupper((unsigned char)out[i])) {
            out[i] = (char)tolower((unsigned char)out[i]);
            ++i;
        }
    }
}

static int set_attr(loader *L, xml_node *n, const char *name, const char *value)
{
    for (int i = 0; i < n->nattrs; ++i)
        if (!strcmp(n->attrs[2 * i], name))
            return xml_set_attr(n, i, value) || fail_at(L, n, "out of memory");
    return 1;
}

static int rename_attrs(loader *L, xml_node *n)
{
    const char *name = xml_attr(n, "name"), *id = xml_attr(n, "id");
    char buf[4096];
    if (name && strcmp(n->name, "default")) {
        snake_case(name, buf, sizeof buf);
        if (!set_attr(L, n, "name", buf))
            return 0;
    }
    if (id && id[0] == '_') {
        snprintf(buf, sizeof buf, "ID%s__UPGR", id);
        if (!set_attr(L, n, "id", buf))
            return 0;
    }
    if (!strcmp(n->name, "lookAt") && !xml_set_name(n, "lookat"))
        return fail_at(L, n, "out of memory");
    for (int i = 0; i < n->nchildren; ++i)
        if (!rename_attrs(L, n->children[i]))
            return 0;
    return 1;
}

static int is_type(const xml_node *n, const char *tag, const char *type)
{
    const char *t = xml_attr(n, "type");
    return !strcmp(n->name, tag) && t && !strcmp(t, type);
}

/* A child <float name="name" value="..."/>: its index, or -1. */
static int float_child(const xml_node *n, const char *name)
{
    for (int i = 0; i < n->nchildren; ++i) {
        const char *cn = xml_attr(n->children[i], "name");
        if (!strcmp(n->children[i]->name, "float") && cn && !strcmp(cn, name))
            return i;
    }
    return -1;
}

/* uoffset, voffset, uscale, vscale -> <transform name="to_uv"> of a translate then a scale,
 * the order Mitsuba 3 writes them in. */
static int upgrade_uv(loader *L, xml_node *n)
{
    static const char *const names[4] = {"uoffset", "voffset", "uscale", "vscale"};
    const char *values[4] = {"0", "0", "1", "1"};
    char keep[4][64];
    int any = 0;
    for (int k = 0; k < 4; ++k) {
        int i = float_child(n, names[k]);
        if (i < 0)
            continue;
        const char *v = xml_attr(n->children[i], "value");
        if (!v)
            return fail_at(L, n->children[i], "missing attribute 'value'");
        snprintf(keep[k], sizeof keep[k], "%s", v);
        values[k] = keep[k];
        xml_remove_child(n, i);
        any = 1;
    }
    if (any) {
        static const char *const to_uv[] = {"name", "to_uv", NULL};
        xml_node *t = xml_add_child(n, "transform", to_uv);
        const char *const translate[] = {"x", values[0], "y", values[1], NULL};
        const char *const scale[] = {"x", values[2], "y", values[3], NULL};
        if (!t || !xml_add_child(t, "translate", translate) || !xml_add_child(t, "scale", scale))
            return fail_at(L, n, "out of memory");
    }
    for (int i = 0; i < n->nchildren; ++i)
        if (!upgrade_uv(L, n->children[i]))
            return 0;
    return 1;
}

static int upgrade_diffuse(loader *L, xml_node *n)
{
    if (is_type(n, "bsdf", "diffuse"))
        for (int i = 0; i < n->nchildren; ++i) {
            const char *cn = xml_attr(n->children[i], "name");
            if (cn && !strcmp(cn, "diffuse_reflectance") &&
                !set_attr(L, n->children[i], "name", "reflectance"))
                return 0;
        }
    for (int i = 0; i < n->nchildren; ++i)
        if (!upgrade_diffuse(L, n->children[i]))
            return 0;
    return 1;
}

int scene_upgrade(loader *L, xml_node *root)
{
    const char *text = xml_attr(root, "version");
    int v[3];
    if (!text)
        return 1; /* we read a file without a version as today's (Mitsuba 3 requires one) */
    if (!parse_version(text, v))
        return fail_at(L, root, "the version must be three numbers such as \"3.0.0\", not '%s'",
                       text);
    if (v[0] >= 2)
        return 1;
    L->s->upgraded_from[0] = v[0];
    L->s->upgraded_from[1] = v[1];
    L->s->upgraded_from[2] = v[2];
    L->s->upgraded = 1;
    return rename_attrs(L, root) && upgrade_diffuse(L, root) && upgrade_uv(L, root);
}
