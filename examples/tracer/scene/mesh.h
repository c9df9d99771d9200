/*
 * mesh.h - triangle meshes: the PLY and OBJ loaders, the built-in shapes (rectangle, cube,
 * sphere) as triangles, transforms and vertex normals. Embree intersects these triangles;
 * the integrator interpolates normals and texture coordinates from them.
 */
#ifndef TRACER_MESH_H
#define TRACER_MESH_H

#include <stddef.h>
#include <stdint.h>

#include "error.h"
#include "transform.h"
#include "vecmath.h"

typedef struct mesh {
    uint32_t nverts, ntris;
    vec3 *p;       /* positions (world space once transformed)                          */
    vec3 *n;       /* unit vertex normals for smooth shading, or NULL: flat shading      */
    float *uv;     /* 2 texture coordinates per vertex, or NULL                          */
    uint32_t *idx; /* 3 vertex indices per triangle, counter-clockwise seen from outside */
} mesh;

/* Stanford PLY, ASCII or binary (either byte order). Reads the vertex properties x, y, z,
 * nx, ny, nz and u, v (also s, t or texture_u, texture_v) and the face list vertex_indices
 * (or vertex_index); polygons are split into triangle fans; other elements and properties
 * are skipped. */
int mesh_load_ply(const char *path, mesh *m, tr_error *err);

/* Wavefront OBJ: v, vt, vn and f (polygons as fans, negative indices allowed). Groups,
 * smoothing groups and materials (o, g, s, usemtl, mtllib) are skipped: in our scenes the
 * material comes from the XML file. */
int mesh_load_obj(const char *path, mesh *m, tr_error *err);

/* Mitsuba's built-in shapes in object space: the rectangle [-1,1]^2 at z = 0 facing +z, the
 * cube [-1,1]^3 with outward normals, and a sphere tessellated into triangles (64 x 128)
 * with exact vertex normals. */
int mesh_make_rectangle(mesh *m, tr_error *err);
/* Mitsuba's disk: radius 1 in the z = 0 plane around the origin, normal +z, as a fan of
 * triangles with the unit disk's area. */
int mesh_make_disk(mesh *m, tr_error *err);
int mesh_make_cube(mesh *m, tr_error *err);
int mesh_make_sphere(mesh *m, vec3 center, float radius, tr_error *err);

/* Applies to_world to positions and normals. A mirroring transform (negative determinant)
 * also reverses the triangles' winding, so that geometric normals keep agreeing with the
 * transformed shading normals. */
void mesh_transform(mesh *m, const mat4 *to_world);

/* Final clean-up before rendering: drops degenerate triangles, then either discards vertex
 * normals (face_normals: flat shading) or, when the file had none, computes them (each
 * vertex gets the angle-weighted average of its faces' normals, as Mitsuba does). With
 * flip, every normal and the winding are reversed (Mitsuba's flip_normals). A mesh with no
 * triangle of non-zero area is left with ntris == 0 and succeeds: the caller decides. */
int mesh_finish(mesh *m, int face_normals, int flip, tr_error *err);
/* Texture coordinates at barycentrics (b1, b2) of triangle `tri`; without any in the file,
 * (b1, b2) themselves, as Mitsuba does. */
void mesh_uv_at(const mesh *m, uint32_t tri, float b1, float b2, float *u, float *v);
/* The surface's derivatives dp/du and dp/dv on triangle `tri` (world units per texture
 * unit), as Mitsuba computes them: from the texture coordinates where they span the
 * triangle; without any in the file, the edges p1 - p0 and p2 - p0 (u, v are then the
 * barycentrics); where they are degenerate, 0 (the caller picks a frame). */
void mesh_uv_tangents(const mesh *m, uint32_t tri, vec3 *dp_du, vec3 *dp_dv);

void mesh_free(mesh *m);

/* For the loaders: allocates the arrays (normals and uvs only if asked; positions padded as
 * Embree needs) and reads a whole file into memory (NUL-terminated). Both return 0 on
 * failure (mesh_read_file with a message). */
int mesh_alloc(mesh *m, uint32_t nverts, uint32_t ntris, int normals, int uvs);
int mesh_read_file(const char *path, char **data, size_t *size, tr_error *err);

#endif /* TRACER_MESH_H */
