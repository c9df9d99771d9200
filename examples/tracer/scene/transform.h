/*
 * transform.h - 4x4 affine transforms as the scene format uses them (to_world, to_uv):
 * products of matrix, translate, rotate, scale and lookat, applied in document order.
 */
#ifndef TRACER_TRANSFORM_H
#define TRACER_TRANSFORM_H

#include "vecmath.h"

/* Row-major: m[row][col]; a point p maps to m * (p, 1). Doubles, because long chains of
 * transforms and their inverses (for normals) lose precision in float. */
typedef struct mat4 {
    double m[4][4];
} mat4;

mat4 mat4_identity(void);
mat4 mat4_mul(const mat4 *a, const mat4 *b); /* a * b: b is applied first */
mat4 mat4_translate(double x, double y, double z);
mat4 mat4_scale(double x, double y, double z);
mat4 mat4_rotate(double ax, double ay, double az, double angle_degrees); /* about an axis */
/* Mitsuba's lookat: the camera sits at `origin`, its local +z looks at `target`, +y is `up`
 * and +x points to the left of the image (Mitsuba's and pbrt's convention). Returns 0 when
 * the three points do not define a frame (target == origin, or up parallel to the view). */
int mat4_lookat(vec3 origin, vec3 target, vec3 up, mat4 *out);
/* The inverse; returns 0 when the matrix is singular. */
int mat4_inverse(const mat4 *a, mat4 *out);
double mat4_det3(const mat4 *a); /* determinant of the linear (upper-left 3x3) part */

vec3 mat4_point(const mat4 *a, vec3 p);
vec3 mat4_vector(const mat4 *a, vec3 v);
/* A normal transforms with the inverse transpose: pass the inverse of the transform. */
vec3 mat4_normal(const mat4 *inverse, vec3 n);

#endif /* TRACER_TRANSFORM_H */
