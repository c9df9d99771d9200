/*
 * image.h - float RGB images and their files: OpenEXR (read and write, through the OpenEXR
 * Core C API), PNG previews and JPEG/PNG textures (through stb_image / stb_image_write).
 */
#ifndef TRACER_IMAGE_H
#define TRACER_IMAGE_H

#include <stddef.h>

#include "error.h"

/* width x height pixels, 3 floats each (R, G, B, linear), row 0 at the top. */
typedef struct image {
    int width, height;
    float *data;
} image;

/* Allocates a black image. Returns 0 on failure (out of memory or a bad size). */
int image_alloc(image *img, int width, int height, tr_error *err);
void image_free(image *img);
static inline float *image_pixel(const image *img, int x, int y)
{
    return img->data + 3 * ((size_t)y * (size_t)img->width + (size_t)x);
}

/* Writes a scanline, ZIP-compressed, 32-bit float RGB OpenEXR file. */
int image_write_exr(const image *img, const char *path, tr_error *err);

/* Reads the R, G and B channels (half, float or uint; any compression OpenEXR supports) of
 * the first part of a scanline OpenEXR file into a float image. A file with a single Y
 * (luminance) channel is read as grey. Tiled and deep files are refused. */
int image_read_exr(const char *path, image *img, tr_error *err);

/* Writes an 8-bit sRGB PNG preview: each value is multiplied by 2^exposure, clamped to
 * [0, 1] and encoded with the sRGB transfer curve (no other tone mapping, so what is white
 * in the PNG is radiance >= 1 in the EXR). */
int image_write_png(const image *img, const char *path, float exposure, tr_error *err);

/* Loads an 8-bit image (JPEG, PNG, ...) as linear float RGB. With srgb != 0 the values are
 * decoded with the sRGB curve (Mitsuba's default for bitmaps, raw=false); otherwise they are
 * divided by 255. Grey and grey+alpha images become grey RGB. When `alpha` is not NULL and
 * the file has an alpha channel, *alpha gets it (linear, the same value in R, G and B);
 * otherwise alpha->data is NULL. */
int image_load_ldr(const char *path, int srgb, image *img, image *alpha, tr_error *err);

/* Reduces `src` by an integer factor in x and y (src width = factor * dst width, same for
 * height) by averaging each factor x factor block: a box-filtered reference at a lower
 * resolution. */
int image_downsample(const image *src, int width, int height, image *dst, tr_error *err);

#endif /* TRACER_IMAGE_H */
