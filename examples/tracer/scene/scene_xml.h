/*
 * scene_xml.h - the internals shared by the scene loader's three files:
 *
 *   scene_props.c      errors, attributes, numbers, ids, and the typed parameters of an
 *                      element (<float>, <rgb>, <transform>, ...)
 *   scene_materials.c  textures and BSDFs
 *   scene_media.c      participating media and the closed shapes that bound them
 *   scene_load.c       shapes, emitters, sensor, integrator, $parameters, the whole scene
 *   scene_upgrade.c    files older than version 2.0.0, rewritten as Mitsuba 3 does
 *
 * Every element is either interpreted or refused: each function that consumes an element
 * marks the children it used, and check_all_used() turns any child left over into an error
 * naming it and its line. All functions return 0 (or NULL) after writing the error.
 */
#ifndef TRACER_SCENE_XML_H
#define TRACER_SCENE_XML_H

#include <stddef.h>

#include "scene.h"
#include "xml.h"

typedef enum object_kind { OBJ_BSDF, OBJ_TEXTURE, OBJ_MEDIUM, OBJ_OTHER } object_kind;

/* An element with an id, for <ref id="..."/>. */
typedef struct named_object {
    const char *id;
    object_kind kind;
    int index;              /* OBJ_BSDF: into scene.bsdfs; OBJ_TEXTURE: into scene.textures;
                             * OBJ_MEDIUM: into scene.media                                */
    const xml_node *node;
} named_object;

typedef struct loader {
    scene *s;
    const char *file;       /* for messages */
    char dir[4096];         /* for relative file names */
    tr_error *err;
    named_object *objects;
    int nobjects;
    int have_sensor;
} loader;

/* ---- scene_props.c ------------------------------------------------------------------------- */

/* Writes "file:line: <tag a="v" ...>: message" and returns 0. */
int fail_at(loader *L, const xml_node *n, const char *fmt, ...) TR_PRINTF(3, 4);

/* Refuses attributes not in the NULL-terminated list `allowed`. */
int check_attrs(loader *L, const xml_node *n, const char *const *allowed);
const char *require_attr(loader *L, const xml_node *n, const char *name);
/* 1..max numbers separated by commas and/or whitespace, from attribute `attr` = text. */
int parse_numbers(loader *L, const xml_node *n, const char *attr, const char *text,
                  double *out, int max, int *count);
int parse_number_attr(loader *L, const xml_node *n, const char *attr, double *out);
int parse_vec3_attr(loader *L, const xml_node *n, const char *attr, vec3 *out);

/* The world-space range (SCENE_WORLD_LIMIT in scene.h, docs/scene-format.md "Limits"), applied
 * here and nowhere else: returns 1 when every one of the `count` values is finite and within
 * +-SCENE_WORLD_LIMIT, else 0 with "<what> (v0, v1, ...), outside the world-space range: ..."
 * on element n (what: "the camera origin is at", ...). */
int check_world(loader *L, const xml_node *n, const char *what, const double *v, int count);

const named_object *find_object(const loader *L, const char *id);
/* Registers n's id attribute, if it has one. */
int register_object(loader *L, const xml_node *n, object_kind kind, int index);
/* The target of <ref id="..."/>, which must be of the given kind (`what` names it). */
const named_object *resolve_ref(loader *L, const xml_node *ref, object_kind kind,
                                const char *what);
/* A file name relative to the scene file's directory. */
int resolve_path(loader *L, const xml_node *n, const char *name, char *out, size_t size);

/* Whether a tag is a typed parameter (<float>, <rgb>, ...). */
int is_property_tag(const char *tag);
/* The child with name="name" in *out, NULL when the plugin does not set it: returns 1, or 0
 * after recording an error when it is given twice. Every property lookup starts here. */
int find_prop(loader *L, xml_node *plugin, const char *name, xml_node **out);
int wrong_type(loader *L, const xml_node *n, const char *expected);
/* Typed parameters: *out = def when absent; marks the element used when present. */
int get_float(loader *L, xml_node *plugin, const char *name, float def, float *out);
int get_int(loader *L, xml_node *plugin, const char *name, int def, int *out);
int get_bool(loader *L, xml_node *plugin, const char *name, int def, int *out);
int get_string(loader *L, xml_node *plugin, const char *name, const char *def,
               const char **out);
/* A colour from <rgb>, <float> or a constant <spectrum>. */
int parse_colour(loader *L, xml_node *n, rgb *out);
int get_rgb(loader *L, xml_node *plugin, const char *name, rgb def, rgb *out);
/* A <transform>: its children in document order, each applied after the previous ones. */
int parse_transform(loader *L, xml_node *t, mat4 *out);
int get_transform(loader *L, xml_node *plugin, const char *name, mat4 *out);

/* The error for the first child of `plugin` nobody used. */
int check_all_used(loader *L, const xml_node *plugin);
/* Marks a subtree used: elements we accept although they cannot change our images. */
void accept_ignored(xml_node *n);
const char *plugin_type(loader *L, const xml_node *n);
/* An object element (bsdf, shape, ...) may carry type, id and name. */
int check_plugin_attrs(loader *L, const xml_node *n);

/* ---- scene_materials.c --------------------------------------------------------------------- */

const texture *constant_texture(loader *L, const xml_node *n, rgb value);
/* <texture type="bitmap|checkerboard">, registered under its id. */
const texture *parse_texture(loader *L, xml_node *n);
/* A texture-valued parameter: a colour, a nested <texture> or a <ref> to one. */
int get_texture(loader *L, xml_node *plugin, const char *name, rgb def, const texture **out);
/* <bsdf ...>: appended to scene.bsdfs, *index its position. */
int parse_bsdf(loader *L, xml_node *n, int *index);
/* The material nested in a shape or a twosided BSDF: <bsdf> or <ref>. */
int nested_bsdf(loader *L, xml_node *c, int *index);

/* ---- scene_media.c ------------------------------------------------------------------------- */

/* <medium type="homogeneous">, appended to scene.media (*index its position) and registered
 * under its id. */
int parse_medium(loader *L, xml_node *n, int *index);
/* A medium nested in a shape or the sensor: <medium> or <ref> to one. */
int nested_medium(loader *L, xml_node *c, int *index);
/* Whether a shape that bounds a medium is closed: every edge (by vertex position) shared by
 * exactly two of its triangles. Returns 0 with an error on element n naming the first open
 * edge otherwise. */
int check_closed(loader *L, const xml_node *n, const mesh *m);

/* ---- scene_upgrade.c ----------------------------------------------------------------------- */

/* When the root's version is < 2.0.0, rewrites the tree in place as Mitsuba 3's loader does
 * (camelCase names to snake_case, and the renames listed in scene_upgrade.c) and records
 * the version in the scene. A missing version is read as today's. */
int scene_upgrade(loader *L, xml_node *root);

#endif /* TRACER_SCENE_XML_H */
