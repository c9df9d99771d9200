/*
 * xml.c - builds the xml_node tree with expat's streaming callbacks. We keep whitespace out
 * of the tree and refuse any other text: the Mitsuba format puts all data in attributes.
 */
#include "xml.h"

#include <errno.h>
#include <expat.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct parse_state {
    XML_Parser parser;
    xml_node *root;
    xml_node *current;
    const char *name; /* file name for messages */
    tr_error *err;
    int failed;
} parse_state;

static char *copy_string(const char *s)
{
    size_t n = strlen(s) + 1;
    char *r = malloc(n);
    if (r)
        memcpy(r, s, n);
    return r;
}

static void stop(parse_state *st, const char *fmt, const char *arg)
{
    char what[512];
    snprintf(what, sizeof what, fmt, arg);
    tr_fail(st->err, "%s:%lu: %s", st->name,
            (unsigned long)XML_GetCurrentLineNumber(st->parser), what);
    st->failed = 1;
    XML_StopParser(st->parser, XML_FALSE);
}

/* A new element <name a0="v0" ...> (attrs: NULL-terminated name, value pairs) at `line`,
 * appended to parent's children (no parent: a root). Returns NULL, with nothing left
 * allocated, when the element or its place in the parent cannot be had; otherwise the
 * element, with *complete 0 when a copy of its name or an attribute failed (it stays
 * linked in, so that xml_free releases it). */
static xml_node *new_node(xml_node *parent, const char *name, const char *const *attrs,
                          int line, int *complete)
{
    xml_node *node = calloc(1, sizeof *node);
    if (!node)
        return NULL;
    if (parent) {
        xml_node **grown =
            realloc(parent->children, (size_t)(parent->nchildren + 1) * sizeof *grown);
        if (!grown) {
            free(node);
            return NULL;
        }
        parent->children = grown;
        parent->children[parent->nchildren++] = node;
    }
    node->parent = parent;
    node->line = line;
    node->name = copy_string(name);
    int n = 0;
    while (attrs && attrs[2 * n])
        ++n;
    node->attrs = calloc((size_t)(2 * n + 1), sizeof(char *));
    node->nattrs = node->attrs ? n : 0;
    int ok = node->name && node->attrs;
    for (int i = 0; ok && i < 2 * n; ++i)
        ok = (node->attrs[i] = copy_string(attrs[i])) != NULL;
    *complete = ok;
    return node;
}

static void XMLCALL on_start(void *user, const XML_Char *name, const XML_Char **attrs)
{
    parse_state *st = user;
    if (st->failed)
        return;
    if (!st->current && st->root) {
        stop(st, "a second top-level element <%s>", name);
        return;
    }
    int complete;
    xml_node *node = new_node(st->current, name, (const char *const *)attrs,
                              (int)XML_GetCurrentLineNumber(st->parser), &complete);
    if (!node) {
        stop(st, "out of memory at <%s>", name);
        return;
    }
    if (!st->current)
        st->root = node;
    st->current = node;
    if (!complete)
        stop(st, "out of memory at <%s>", name);
}

static void XMLCALL on_end(void *user, const XML_Char *name)
{
    parse_state *st = user;
    (void)name;
    if (!st->failed && st->current)
        st->current = st->current->parent;
}

static void XMLCALL on_text(void *user, const XML_Char *s, int len)
{
    parse_state *st = user;
    if (st->failed)
        return;
    for (int i = 0; i < len; ++i)
        if (s[i] != ' ' && s[i] != '\t' && s[i] != '\n' && s[i] != '\r') {
            stop(st, "unexpected text inside <%s> (values go in attributes)",
                 st->current ? st->current->name : "?");
            return;
        }
}

static int parse(parse_state *st, FILE *f, const char *text, xml_node **root)
{
    st->parser = XML_ParserCreate(NULL);
    if (!st->parser)
        return tr_fail(st->err, "%s: out of memory", st->name);
    XML_SetUserData(st->parser, st);
    XML_SetElementHandler(st->parser, on_start, on_end);
    XML_SetCharacterDataHandler(st->parser, on_text);

    int ok = 1;
    if (text) {
        if (XML_Parse(st->parser, text, (int)strlen(text), XML_TRUE) == XML_STATUS_ERROR)
            ok = 0;
    } else {
        char buf[65536];
        for (;;) {
            size_t n = fread(buf, 1, sizeof buf, f);
            int last = n < sizeof buf;
            if (XML_Parse(st->parser, buf, (int)n, last) == XML_STATUS_ERROR) {
                ok = 0;
                break;
            }
            if (last)
                break;
        }
    }
    if (!ok && !st->failed) {
        tr_fail(st->err, "%s:%lu: XML syntax error: %s", st->name,
                (unsigned long)XML_GetCurrentLineNumber(st->parser),
                XML_ErrorString(XML_GetErrorCode(st->parser)));
        st->failed = 1;
    }
    if (!st->failed && !st->root) {
        tr_fail(st->err, "%s: no elements", st->name);
        st->failed = 1;
    }
    XML_ParserFree(st->parser);
    if (st->failed) {
        xml_free(st->root);
        return 0;
    }
    *root = st->root;
    return 1;
}

int xml_parse_file(const char *path, xml_node **root, tr_error *err)
{
    parse_state st = {0};
    st.name = path;
    st.err = err;
    *root = NULL;
    FILE *f = fopen(path, "rb");
    if (!f)
        return tr_fail(err, "%s: cannot open: %s", path, strerror(errno));
    int ok = parse(&st, f, NULL, root);
    fclose(f);
    return ok;
}

int xml_parse_string(const char *text, const char *name, xml_node **root, tr_error *err)
{
    parse_state st = {0};
    st.name = name;
    st.err = err;
    *root = NULL;
    return parse(&st, NULL, text, root);
}

void xml_free(xml_node *node)
{
    if (!node)
        return;
    for (int i = 0; i < node->nchildren; ++i)
        xml_free(node->children[i]);
    free(node->children);
    if (node->attrs)
        for (int i = 0; i < 2 * node->nattrs; ++i)
            free(node->attrs[i]);
    free(node->attrs);
    free(node->name);
    free(node);
}

const char *xml_attr(const xml_node *node, const char *name)
{
    for (int i = 0; i < node->nattrs; ++i)
        if (!strcmp(node->attrs[2 * i], name))
            return node->attrs[2 * i + 1];
    return NULL;
}

int xml_set_attr(xml_node *node, int i, const char *value)
{
    char *v = copy_string(value);
    if (!v)
        return 0;
    free(node->attrs[2 * i + 1]);
    node->attrs[2 * i + 1] = v;
    return 1;
}

int xml_set_name(xml_node *node, const char *name)
{
    char *v = copy_string(name);
    if (!v)
        return 0;
    free(node->name);
    node->name = v;
    return 1;
}

xml_node *xml_add_child(xml_node *parent, const char *name, const char *const *attrs)
{
    int complete;
    xml_node *node = new_node(parent, name, attrs, parent->line, &complete);
    return node && complete ? node : NULL;
}

void xml_remove_child(xml_node *parent, int i)
{
    xml_free(parent->children[i]);
    for (int k = i + 1; k < parent->nchildren; ++k)
        parent->children[k - 1] = parent->children[k];
    --parent->nchildren;
}
