/*
 * transform.c - matrix construction, products and inverses for transform.h.
 */
#include "transform.h"

#include <math.h>
#include <string.h>

mat4 mat4_identity(void)
{
    mat4 r;
    memset(&r, 0, sizeof r);
    for (int i = 0; i < 4; ++i)
        r.m[i][i] = 1.0;
    return r;
}

mat4 mat4_mul(const mat4 *a, const mat4 *b)
{
    mat4 r;
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            double s = 0.0;
            for (int k = 0; k < 4; ++k)
                s += a->m[i][k] * b->m[k][j];
            r.m[i][j] = s;
        }
    return r;
}

mat4 mat4_translate(double x, double y, double z)
{
    mat4 r = mat4_identity();
    r.m[0][3] = x;
    r.m[1][3] = y;
    r.m[2][3] = z;
    return r;
}

mat4 mat4_scale(double x, double y, double z)
{
    mat4 r = mat4_identity();
    r.m[0][0] = x;
    r.m[1][1] = y;
    r.m[2][2] = z;
    return r;
}

mat4 mat4_rotate(double ax, double ay, double az, double angle_degrees)
{
    /* Rodrigues' formula for a right-handed rotation about the normalized axis. */
    double len = sqrt(ax * ax + ay * ay + az * az);
    mat4 r = mat4_identity();
    if (len == 0.0)
        return r;
    ax /= len;
    ay /= len;
    az /= len;
    double a = angle_degrees * 3.14159265358979323846 / 180.0;
    double s = sin(a), c = cos(a), t = 1.0 - c;
    r.m[0][0] = t * ax * ax + c;
    r.m[0][1] = t * ax * ay - s * az;
    r.m[0][2] = t * ax * az + s * ay;
    r.m[1][0] = t * ax * ay + s * az;
    r.m[1][1] = t * ay * ay + c;
    r.m[1][2] = t * ay * az - s * ax;
    r.m[2][0] = t * ax * az - s * ay;
    r.m[2][1] = t * ay * az + s * ax;
    r.m[2][2] = t * az * az + c;
    return r;
}

int mat4_lookat(vec3 origin, vec3 target, vec3 up, mat4 *out)
{
    double d[3] = {target.x - origin.x, target.y - origin.y, target.z - origin.z};
    double dl = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (dl == 0.0)
        return 0;
    for (int i = 0; i < 3; ++i)
        d[i] /= dl;
    double u[3] = {up.x, up.y, up.z};
    /* left = normalize(cross(up, dir)); new_up = cross(dir, left) */
    double l[3] = {u[1] * d[2] - u[2] * d[1], u[2] * d[0] - u[0] * d[2], u[0] * d[1] - u[1] * d[0]};
    double ll = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
    if (ll < 1e-12)
        return 0;
    for (int i = 0; i < 3; ++i)
        l[i] /= ll;
    double nu[3] = {d[1] * l[2] - d[2] * l[1], d[2] * l[0] - d[0] * l[2], d[0] * l[1] - d[1] * l[0]};
    mat4 r = mat4_identity();
    double o[3] = {origin.x, origin.y, origin.z};
    for (int i = 0; i < 3; ++i) {
        r.m[i][0] = l[i];
        r.m[i][1] = nu[i];
        r.m[i][2] = d[i];
        r.m[i][3] = o[i];
    }
    *out = r;
    return 1;
}

double mat4_det3(const mat4 *a)
{
    const double(*m)[4] = a->m;
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
           m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

int mat4_inverse(const mat4 *a, mat4 *out)
{
    /* Gauss-Jordan elimination with partial pivoting on [A | I]. */
    double t[4][8];
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            t[i][j] = a->m[i][j];
            t[i][j + 4] = i == j ? 1.0 : 0.0;
        }
    for (int c = 0; c < 4; ++c) {
        int p = c;
        for (int r = c + 1; r < 4; ++r)
            if (fabs(t[r][c]) > fabs(t[p][c]))
                p = r;
        if (fabs(t[p][c]) < 1e-300)
            return 0;
        if (p != c)
            for (int j = 0; j < 8; ++j) {
                double tmp = t[c][j];
                t[c][j] = t[p][j];
                t[p][j] = tmp;
            }
        double inv = 1.0 / t[c][c];
        for (int j = 0; j < 8; ++j)
            t[c][j] *= inv;
        for (int r = 0; r < 4; ++r)
            if (r != c && t[r][c] != 0.0) {
                double f = t[r][c];
                for (int j = 0; j < 8; ++j)
                    t[r][j] -= f * t[c][j];
            }
    }
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j)
            out->m[i][j] = t[i][j + 4];
    return 1;
}

vec3 mat4_point(const mat4 *a, vec3 p)
{
    const double(*m)[4] = a->m;
    double x = m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3];
    double y = m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3];
    double z = m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3];
    double w = m[3][0] * p.x + m[3][1] * p.y + m[3][2] * p.z + m[3][3];
    if (w != 1.0 && w != 0.0) {
        x /= w;
        y /= w;
        z /= w;
    }
    return v3((float)x, (float)y, (float)z);
}

vec3 mat4_vector(const mat4 *a, vec3 v)
{
    const double(*m)[4] = a->m;
    return v3((float)(m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z),
              (float)(m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z),
              (float)(m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z));
}

vec3 mat4_normal(const mat4 *inverse, vec3 n)
{
    const double(*m)[4] = inverse->m; /* transposed product: column i of the inverse */
    return v3((float)(m[0][0] * n.x + m[1][0] * n.y + m[2][0] * n.z),
              (float)(m[0][1] * n.x + m[1][1] * n.y + m[2][1] * n.z),
              (float)(m[0][2] * n.x + m[1][2] * n.y + m[2][2] * n.z));
}
