/*
 * xml.h - a scene file as a tree of elements, read with expat. Every element keeps the line
 * it started on, so that whoever interprets the tree can name the element and its line in
 * an error message. This file knows nothing about scenes.
 */
#ifndef TRACER_XML_H
#define TRACER_XML_H

#include "error.h"

typedef struct xml_node {
    char *name;                  /* the tag, e.g. "shape"                                 */
    int line;                    /* 1-based line of the start tag                          */
    int nattrs;
    char **attrs;                /* nattrs (name, value) pairs: attrs[2i], attrs[2i + 1]   */
    int nchildren;
    struct xml_node **children;
    struct xml_node *parent;
    int used;                    /* set by the interpreter for each element it consumed    */
} xml_node;

/* Parses a whole file. On failure returns 0 with "path:line: message" in err (a syntax
 * error, or text where only elements may appear). */
int xml_parse_file(const char *path, xml_node **root, tr_error *err);
/* The same for a string in memory (`name` stands for the path in messages). */
int xml_parse_string(const char *text, const char *name, xml_node **root, tr_error *err);
void xml_free(xml_node *root);

/* The value of an attribute, or NULL. */
const char *xml_attr(const xml_node *node, const char *name);
/* Replaces the value of attribute i (the old string is freed; the new one is copied). */
int xml_set_attr(xml_node *node, int i, const char *value);
/* Renames the element (the old name is freed). Returns 0 when out of memory. */
int xml_set_name(xml_node *node, const char *name);
/* Appends a new child <name a0="v0" ...> (attrs: NULL-terminated name, value pairs) at the
 * parent's line; returns it, or NULL when out of memory. */
xml_node *xml_add_child(xml_node *parent, const char *name, const char *const *attrs);
/* Removes and frees child i. */
void xml_remove_child(xml_node *parent, int i);

#endif /* TRACER_XML_H */
