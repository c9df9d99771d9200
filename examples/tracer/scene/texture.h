/*
 * texture.h - spatially varying colours: a constant, a bitmap (JPEG/PNG via stb_image,
 * bilinear or nearest, repeat or clamp) and Mitsuba's checkerboard, each behind an optional
 * to_uv transform.
 */
#ifndef TRACER_TEXTURE_H
#define TRACER_TEXTURE_H

#include "image.h"
#include "vecmath.h"

typedef enum texture_kind { TEX_CONSTANT, TEX_BITMAP, TEX_CHECKERBOARD } texture_kind;

typedef struct texture {
    texture_kind kind;
    rgb value;          /* TEX_CONSTANT                                        */
    rgb color0, color1; /* TEX_CHECKERBOARD                                    */
    image bitmap;       /* TEX_BITMAP, linear RGB                              */
    image alpha;        /* TEX_BITMAP from a file with alpha: the alpha channel as
                         * grey RGB; data NULL otherwise                       */
    int nearest;        /* bitmap: nearest-neighbour instead of bilinear       */
    int clamp;          /* bitmap: clamp to the edge instead of repeating      */
    float uv[2][3];     /* to_uv: (u', v') = uv * (u, v, 1)                     */
    rgb mean;           /* the average colour (used for sampling weights)      */
} texture;

/* A constant texture (to_uv identity, mean = value). */
void texture_init_constant(texture *t, rgb value);
/* Sets t->mean from the texture's contents; call after filling a bitmap or checkerboard. */
void texture_update_mean(texture *t);
rgb texture_eval(const texture *t, float u, float v);
/* A value in [0, 1] for the mask BSDF's opacity: a bitmap's alpha channel where its file has
 * one, else the luminance of texture_eval, clamped. */
float texture_eval_opacity(const texture *t, float u, float v);
/* The gradient of the texture's luminance with respect to the surface's (u, v), the
 * to_uv transform included, as a bump map needs it (Mitsuba 3's eval_1_grad): the
 * derivative of the bilinear lookup; zero for constants, checkerboards and nearest
 * lookups, which are piecewise constant. */
void texture_eval_gradient(const texture *t, float u, float v, float grad[2]);
void texture_free(texture *t);

#endif /* TRACER_TEXTURE_H */
