/*
 * texture.c - texture lookups. Conventions follow Mitsuba 3: texture coordinate v = 0 is
 * the first (top) row of the bitmap; the checkerboard shows color0 where the fractional
 * parts of u and v are both above or both below 1/2.
 */
#include "texture.h"

#include <math.h>
#include <string.h>

void texture_init_constant(texture *t, rgb value)
{
    memset(t, 0, sizeof *t);
    t->kind = TEX_CONSTANT;
    t->value = t->mean = value;
    t->uv[0][0] = t->uv[1][1] = 1.0f;
}

void texture_update_mean(texture *t)
{
    if (t->kind == TEX_CONSTANT) {
        t->mean = t->value;
    } else if (t->kind == TEX_CHECKERBOARD) {
        t->mean = rgb_scale(rgb_add(t->color0, t->color1), 0.5f);
    } else {
        double s[3] = {0.0, 0.0, 0.0};
        size_t n = (size_t)t->bitmap.width * (size_t)t->bitmap.height;
        for (size_t i = 0; i < n; ++i)
            for (int c = 0; c < 3; ++c)
                s[c] += t->bitmap.data[3 * i + c];
        t->mean = n ? rgb_make((float)(s[0] / n), (float)(s[1] / n), (float)(s[2] / n)) : rgb_gray(0.0f);
    }
}

static int wrap(int i, int n, int clamp)
{
    if (clamp)
        return i < 0 ? 0 : (i >= n ? n - 1 : i);
    i %= n;
    return i < 0 ? i + n : i;
}

static rgb texel(const texture *t, const image *b, int x, int y)
{
    const float *p = image_pixel(b, wrap(x, b->width, t->clamp), wrap(y, b->height, t->clamp));
    return rgb_make(p[0], p[1], p[2]);
}

/* The surface's (u, v) through to_uv; a non-finite result reads as (0, 0). */
static void apply_to_uv(const texture *t, float u0, float v0, float *u, float *v)
{
    *u = t->uv[0][0] * u0 + t->uv[0][1] * v0 + t->uv[0][2];
    *v = t->uv[1][0] * u0 + t->uv[1][1] * v0 + t->uv[1][2];
    if (!isfinite(*u) || !isfinite(*v))
        *u = *v = 0.0f;
}

/* A bitmap's lookup position in texels (texel centres sit at half-integers) for transformed
 * (u, v), wrapped or clamped: the lower texel (ix, iy) of the bilinear cell and the weights
 * (ax, ay) of the next ones; (x, y) itself for the nearest lookup. */
static void texel_cell(const texture *t, const image *b, float u, float v, float *x, float *y,
                       int *ix, int *iy, float *ax, float *ay)
{
    /* Keep u, v in a sane range first so that the float-to-int conversion cannot overflow. */
    if (!t->clamp) {
        u -= floorf(u);
        v -= floorf(v);
    }
    *x = fminf(fmaxf(u * (float)b->width - 0.5f, -2.0f), (float)b->width + 1.0f);
    *y = fminf(fmaxf(v * (float)b->height - 0.5f, -2.0f), (float)b->height + 1.0f);
    float fx = floorf(*x), fy = floorf(*y);
    *ix = (int)fx;
    *iy = (int)fy;
    *ax = *x - fx;
    *ay = *y - fy;
}

static rgb eval_image(const texture *t, const image *b, float u0, float v0)
{
    if (t->kind == TEX_CONSTANT)
        return t->value;
    float u, v;
    apply_to_uv(t, u0, v0, &u, &v);
    if (t->kind == TEX_CHECKERBOARD) {
        int mu = u - floorf(u) > 0.5f, mv = v - floorf(v) > 0.5f;
        return mu == mv ? t->color0 : t->color1;
    }
    float x, y, ax, ay;
    int ix, iy;
    texel_cell(t, b, u, v, &x, &y, &ix, &iy, &ax, &ay);
    if (t->nearest)
        return texel(t, b, (int)floorf(x + 0.5f), (int)floorf(y + 0.5f));
    rgb c00 = texel(t, b, ix, iy), c10 = texel(t, b, ix + 1, iy);
    rgb c01 = texel(t, b, ix, iy + 1), c11 = texel(t, b, ix + 1, iy + 1);
    rgb top = rgb_add(rgb_scale(c00, 1.0f - ax), rgb_scale(c10, ax));
    rgb bottom = rgb_add(rgb_scale(c01, 1.0f - ax), rgb_scale(c11, ax));
    return rgb_add(rgb_scale(top, 1.0f - ay), rgb_scale(bottom, ay));
}

rgb texture_eval(const texture *t, float u, float v)
{
    return eval_image(t, &t->bitmap, u, v);
}

float texture_eval_opacity(const texture *t, float u, float v)
{
    float a = t->kind == TEX_BITMAP && t->alpha.data ? eval_image(t, &t->alpha, u, v).r
                                                     : rgb_luminance(texture_eval(t, u, v));
    return a > 0.0f ? (a < 1.0f ? a : 1.0f) : 0.0f; /* NaN: transparent */
}

void texture_eval_gradient(const texture *t, float u0, float v0, float grad[2])
{
    grad[0] = grad[1] = 0.0f;
    if (t->kind != TEX_BITMAP || t->nearest)
        return;
    const image *b = &t->bitmap;
    float u, v, x, y, ax, ay;
    int ix, iy;
    apply_to_uv(t, u0, v0, &u, &v);
    texel_cell(t, b, u, v, &x, &y, &ix, &iy, &ax, &ay);
    float f00 = rgb_luminance(texel(t, b, ix, iy)), f10 = rgb_luminance(texel(t, b, ix + 1, iy));
    float f01 = rgb_luminance(texel(t, b, ix, iy + 1));
    float f11 = rgb_luminance(texel(t, b, ix + 1, iy + 1));
    /* d/dx and d/dy of the lookup in texels, then to the transformed (u, v) by the
     * resolution and back through to_uv by its transpose. */
    float gx = ((1.0f - ay) * (f10 - f00) + ay * (f11 - f01)) * (float)b->width;
    float gy = ((1.0f - ax) * (f01 - f00) + ax * (f11 - f10)) * (float)b->height;
    grad[0] = t->uv[0][0] * gx + t->uv[1][0] * gy;
    grad[1] = t->uv[0][1] * gx + t->uv[1][1] * gy;
}

void texture_free(texture *t)
{
    if (t->kind == TEX_BITMAP) {
        image_free(&t->bitmap);
        image_free(&t->alpha);
    }
}
