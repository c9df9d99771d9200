/*
 * image.c - image memory, OpenEXR input/output with the OpenEXR Core C API, PNG and JPEG
 * through stb. We write no codec of our own: OpenEXRCore compresses and converts half to
 * float for us, stb_image decodes the textures and stb_image_write encodes the previews.
 */
#include "image.h"

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <openexr.h>
#include <stb_image.h>
#include <stb_image_write.h>

int image_alloc(image *img, int width, int height, tr_error *err)
{
    img->width = img->height = 0;
    img->data = NULL;
    if (width <= 0 || height <= 0 || width > 65536 || height > 65536)
        return tr_fail(err, "bad image size %d x %d", width, height);
    img->data = calloc((size_t)width * (size_t)height * 3u, sizeof(float));
    if (!img->data)
        return tr_fail(err, "out of memory for a %d x %d image", width, height);
    img->width = width;
    img->height = height;
    return 1;
}

void image_free(image *img)
{
    free(img->data);
    img->data = NULL;
    img->width = img->height = 0;
}

/* ---- OpenEXR -------------------------------------------------------------------------------- */

/* OpenEXRCore reports details through a callback (by default it prints them to stderr). We
 * keep the last message of this thread and put it into our own error text instead. */
static _Thread_local char exr_last_message[512];

static void exr_error_handler(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    snprintf(exr_last_message, sizeof exr_last_message, "%s (%s)", msg ? msg : "",
             exr_get_error_code_as_string(code));
}

static int exr_fail(tr_error *err, const char *path, const char *what, exr_result_t rv)
{
    return tr_fail(err, "%s: %s failed: %s%s%s", path, what, exr_get_default_error_message(rv),
                   exr_last_message[0] ? ": " : "", exr_last_message);
}

static exr_context_initializer_t exr_initializer(void)
{
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exr_error_handler;
    exr_last_message[0] = '\0';
    return init;
}

/* A chunk's compressor, kept while exr_compress_keeping_raw stands in for it. */
typedef struct exr_compressor {
    exr_result_t (*fn)(exr_encode_pipeline_t *pipeline);
} exr_compressor;

/* A reader takes a chunk whose compressed size equals its raw size for raw bytes, and the
 * OpenEXR 3.1 of Debian 12 keeps zlib's output when it comes out exactly that long (fixed
 * upstream in 2026): that chunk reads back as noise. It happened to the
 * last 4 lines of a 320 x 180 plain render, and a reference with NaNs turns every error
 * metric into NaN. Such a chunk gets the raw bytes, as the file format asks. */
static exr_result_t exr_compress_keeping_raw(exr_encode_pipeline_t *e)
{
    const exr_compressor *next = e->encoding_user_data;
    exr_result_t rv = next->fn(e);
    if (rv == EXR_ERR_SUCCESS && e->compressed_bytes == e->packed_bytes &&
        e->compressed_buffer != e->packed_buffer)
        memcpy(e->compressed_buffer, e->packed_buffer, e->packed_bytes);
    return rv;
}

int image_write_exr(const image *img, const char *path, tr_error *err)
{
    exr_context_initializer_t init = exr_initializer();
    exr_context_t ctx = NULL;
    exr_result_t rv;
    int part = 0;
    static const char *const names[3] = {"R", "G", "B"};

    /* A temporary file that is renamed at the end: a failed write never leaves half a file. */
    rv = exr_start_write(&ctx, path, EXR_INTERMEDIATE_TEMP_FILE, &init);
    if (rv != EXR_ERR_SUCCESS)
        return exr_fail(err, path, "exr_start_write", rv);
    if ((rv = exr_add_part(ctx, "rgb", EXR_STORAGE_SCANLINE, &part)) != EXR_ERR_SUCCESS ||
        (rv = exr_initialize_required_attr_simple(ctx, part, img->width, img->height,
                                                  EXR_COMPRESSION_ZIP)) != EXR_ERR_SUCCESS)
        goto fail;
    for (int c = 0; c < 3; ++c) {
        rv = exr_add_channel(ctx, part, names[c], EXR_PIXEL_FLOAT, EXR_PERCEPTUALLY_LOGARITHMIC,
                             1, 1);
        if (rv != EXR_ERR_SUCCESS)
            goto fail;
    }
    if ((rv = exr_write_header(ctx)) != EXR_ERR_SUCCESS)
        goto fail;

    int32_t lines = 1;
    if ((rv = exr_get_scanlines_per_chunk(ctx, part, &lines)) != EXR_ERR_SUCCESS)
        goto fail;
    exr_encode_pipeline_t encoder = EXR_ENCODE_PIPELINE_INITIALIZER;
    exr_compressor compressor = {NULL};
    int have_encoder = 0;
    for (int y = 0; y < img->height; y += lines) {
        exr_chunk_info_t cinfo;
        if ((rv = exr_write_scanline_chunk_info(ctx, part, y, &cinfo)) != EXR_ERR_SUCCESS)
            break;
        rv = have_encoder ? exr_encoding_update(ctx, part, &cinfo, &encoder)
                          : exr_encoding_initialize(ctx, part, &cinfo, &encoder);
        if (rv != EXR_ERR_SUCCESS)
            break;
        /* The library sorts channels by name (B, G, R): find each one's source by name. */
        for (int c = 0; c < encoder.channel_count; ++c) {
            exr_coding_channel_info_t *ch = &encoder.channels[c];
            int k = ch->channel_name[0] == 'R' ? 0 : (ch->channel_name[0] == 'G' ? 1 : 2);
            ch->encode_from_ptr = (const uint8_t *)(image_pixel(img, 0, cinfo.start_y) + k);
            ch->user_pixel_stride = 3 * (int32_t)sizeof(float);
            ch->user_line_stride = 3 * (int32_t)sizeof(float) * img->width;
            ch->user_data_type = EXR_PIXEL_FLOAT;
            ch->user_bytes_per_element = (int16_t)sizeof(float);
        }
        if (!have_encoder) {
            if ((rv = exr_encoding_choose_default_routines(ctx, part, &encoder)) != EXR_ERR_SUCCESS)
                break;
            have_encoder = 1;
            if (encoder.compress_fn) {
                compressor.fn = encoder.compress_fn;
                encoder.encoding_user_data = &compressor;
                encoder.compress_fn = exr_compress_keeping_raw;
            }
        }
        if ((rv = exr_encoding_run(ctx, part, &encoder)) != EXR_ERR_SUCCESS)
            break;
    }
    if (have_encoder || encoder.channels)
        exr_encoding_destroy(ctx, &encoder);
    if (rv != EXR_ERR_SUCCESS)
        goto fail;
    if ((rv = exr_finish(&ctx)) != EXR_ERR_SUCCESS)
        return exr_fail(err, path, "writing", rv);
    return 1;
fail:
    exr_fail(err, path, "writing", rv);
    exr_finish(&ctx);
    return 0;
}

int image_read_exr(const char *path, image *img, tr_error *err)
{
    exr_context_initializer_t init = exr_initializer();
    exr_context_t ctx = NULL;
    exr_result_t rv;
    exr_storage_t storage;
    exr_attr_box2i_t dw;
    const exr_attr_chlist_t *chlist = NULL;
    int32_t lines = 1;

    img->data = NULL;
    img->width = img->height = 0;
    rv = exr_start_read(&ctx, path, &init);
    if (rv != EXR_ERR_SUCCESS) {
        if (rv == EXR_ERR_FILE_ACCESS)
            return tr_fail(err, "%s: cannot open: %s", path, strerror(errno ? errno : ENOENT));
        return exr_fail(err, path, "exr_start_read", rv);
    }
    if ((rv = exr_get_storage(ctx, 0, &storage)) != EXR_ERR_SUCCESS ||
        (rv = exr_get_data_window(ctx, 0, &dw)) != EXR_ERR_SUCCESS ||
        (rv = exr_get_channels(ctx, 0, &chlist)) != EXR_ERR_SUCCESS ||
        (rv = exr_get_scanlines_per_chunk(ctx, 0, &lines)) != EXR_ERR_SUCCESS) {
        exr_fail(err, path, "reading the header", rv);
        exr_finish(&ctx);
        return 0;
    }
    if (storage != EXR_STORAGE_SCANLINE) {
        exr_finish(&ctx);
        return tr_fail(err, "%s: only scanline OpenEXR files are supported (this one is %s)",
                       path, storage == EXR_STORAGE_TILED ? "tiled" : "deep");
    }
    int has_rgb = 0, has_y = 0;
    for (int c = 0; c < chlist->num_channels; ++c) {
        const char *n = chlist->entries[c].name.str;
        if (!strcmp(n, "R") || !strcmp(n, "G") || !strcmp(n, "B"))
            ++has_rgb;
        if (!strcmp(n, "Y"))
            has_y = 1;
    }
    if (has_rgb != 3 && !has_y) {
        exr_finish(&ctx);
        return tr_fail(err, "%s: no R, G, B (or Y) channels", path);
    }
    if (!image_alloc(img, dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1, err)) {
        exr_finish(&ctx);
        return 0;
    }

    exr_decode_pipeline_t decoder = EXR_DECODE_PIPELINE_INITIALIZER;
    int have_decoder = 0;
    rv = EXR_ERR_SUCCESS;
    for (int y = dw.min.y; y <= dw.max.y; y += lines) {
        exr_chunk_info_t cinfo;
        if ((rv = exr_read_scanline_chunk_info(ctx, 0, y, &cinfo)) != EXR_ERR_SUCCESS)
            break;
        rv = have_decoder ? exr_decoding_update(ctx, 0, &cinfo, &decoder)
                          : exr_decoding_initialize(ctx, 0, &cinfo, &decoder);
        if (rv != EXR_ERR_SUCCESS)
            break;
        for (int c = 0; c < decoder.channel_count; ++c) {
            exr_coding_channel_info_t *ch = &decoder.channels[c];
            int k = -1;
            if (has_rgb == 3)
                k = !strcmp(ch->channel_name, "R") ? 0
                    : !strcmp(ch->channel_name, "G") ? 1
                    : !strcmp(ch->channel_name, "B") ? 2 : -1;
            else if (!strcmp(ch->channel_name, "Y"))
                k = 0;
            if (k < 0 || ch->height == 0) {
                ch->decode_to_ptr = NULL; /* a channel we do not want: skipped */
                continue;
            }
            ch->decode_to_ptr = (uint8_t *)(image_pixel(img, 0, cinfo.start_y - dw.min.y) + k);
            ch->user_pixel_stride = 3 * (int32_t)sizeof(float);
            ch->user_line_stride = 3 * (int32_t)sizeof(float) * img->width;
            ch->user_data_type = EXR_PIXEL_FLOAT; /* half and uint are converted for us */
            ch->user_bytes_per_element = (int16_t)sizeof(float);
        }
        if (!have_decoder) {
            if ((rv = exr_decoding_choose_default_routines(ctx, 0, &decoder)) != EXR_ERR_SUCCESS)
                break;
            have_decoder = 1;
        }
        if ((rv = exr_decoding_run(ctx, 0, &decoder)) != EXR_ERR_SUCCESS)
            break;
    }
    if (have_decoder || decoder.channels)
        exr_decoding_destroy(ctx, &decoder);
    if (rv != EXR_ERR_SUCCESS) {
        exr_fail(err, path, "decoding", rv);
        exr_finish(&ctx);
        image_free(img);
        return 0;
    }
    exr_finish(&ctx);
    if (has_rgb != 3) { /* luminance only: replicate Y into G and B */
        size_t n = (size_t)img->width * (size_t)img->height;
        for (size_t i = 0; i < n; ++i)
            img->data[3 * i + 1] = img->data[3 * i + 2] = img->data[3 * i];
    }
    return 1;
}

/* ---- 8-bit images ------------------------------------------------------------------------- */

static float srgb_to_linear(float v)
{
    return v <= 0.04045f ? v / 12.92f : powf((v + 0.055f) / 1.055f, 2.4f);
}

static float linear_to_srgb(float v)
{
    return v <= 0.0031308f ? 12.92f * v : 1.055f * powf(v, 1.0f / 2.4f) - 0.055f;
}

int image_write_png(const image *img, const char *path, float exposure, tr_error *err)
{
    size_t n = (size_t)img->width * (size_t)img->height * 3u;
    unsigned char *bytes = malloc(n);
    if (!bytes)
        return tr_fail(err, "%s: out of memory", path);
    float scale = exp2f(exposure);
    for (size_t i = 0; i < n; ++i) {
        float v = img->data[i] * scale;
        v = isfinite(v) ? fminf(fmaxf(v, 0.0f), 1.0f) : 0.0f;
        bytes[i] = (unsigned char)lrintf(255.0f * linear_to_srgb(v));
    }
    int ok = stbi_write_png(path, img->width, img->height, 3, bytes, img->width * 3);
    free(bytes);
    if (!ok)
        return tr_fail(err, "%s: cannot write the PNG file", path);
    return 1;
}

int image_load_ldr(const char *path, int srgb, image *img, image *alpha, tr_error *err)
{
    int w = 0, h = 0, n = 0;
    img->data = NULL;
    if (alpha)
        alpha->data = NULL;
    unsigned char *bytes = stbi_load(path, &w, &h, &n, 4); /* always 4 channels back */
    if (!bytes)
        return tr_fail(err, "%s: cannot load the image: %s", path, stbi_failure_reason());
    int with_alpha = alpha && (n == 2 || n == 4);
    if (!image_alloc(img, w, h, err) || (with_alpha && !image_alloc(alpha, w, h, err))) {
        image_free(img);
        stbi_image_free(bytes);
        return 0;
    }
    /* 256 possible values: decode each once. */
    float table[256];
    for (int i = 0; i < 256; ++i)
        table[i] = srgb ? srgb_to_linear((float)i / 255.0f) : (float)i / 255.0f;
    size_t count = (size_t)w * (size_t)h;
    for (size_t i = 0; i < count; ++i)
        for (int c = 0; c < 3; ++c) {
            img->data[3 * i + c] = table[bytes[4 * i + c]];
            if (with_alpha) /* alpha is linear in every format stb reads */
                alpha->data[3 * i + c] = (float)bytes[4 * i + 3] / 255.0f;
        }
    stbi_image_free(bytes);
    return 1;
}

int image_downsample(const image *src, int width, int height, image *dst, tr_error *err)
{
    if (width <= 0 || height <= 0 || src->width % width || src->height % height ||
        src->width / width != src->height / height)
        return tr_fail(err, "cannot reduce a %d x %d image to %d x %d: the sizes must differ "
                       "by the same integer factor in x and y", src->width, src->height,
                       width, height);
    int f = src->width / width;
    if (!image_alloc(dst, width, height, err))
        return 0;
    float inv = 1.0f / (float)(f * f);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            double acc[3] = {0.0, 0.0, 0.0};
            for (int j = 0; j < f; ++j)
                for (int i = 0; i < f; ++i) {
                    const float *p = image_pixel(src, x * f + i, y * f + j);
                    acc[0] += p[0];
                    acc[1] += p[1];
                    acc[2] += p[2];
                }
            float *q = image_pixel(dst, x, y);
            for (int c = 0; c < 3; ++c)
                q[c] = (float)acc[c] * inv;
        }
    return 1;
}
