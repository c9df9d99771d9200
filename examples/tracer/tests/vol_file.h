/*
 * vol_file.h - the tracer tests' writer of .vol grids (Mitsuba 3's format, scene/volume_grid.h),
 * shared by test_volume_grid.c and test_media.c: include it after <cmocka.h>.
 */
#ifndef TRACER_TEST_VOL_FILE_H
#define TRACER_TEST_VOL_FILE_H

#include <stdint.h>
#include <stdio.h>
#include <string.h>

static void put_u32(unsigned char *p, uint32_t v)
{
    for (int k = 0; k < 4; ++k)
        p[k] = (unsigned char)(v >> (8 * k));
}

/* The bytes of a grid of nx ny nz cells and `channels` values each, x fastest, into out
 * (48 + 4 n bytes); returns their count. */
static size_t vol_bytes(unsigned char *out, int nx, int ny, int nz, int channels,
                        const float *values)
{
    memcpy(out, "VOL\3", 4);
    const uint32_t head[5] = {1, (uint32_t)nx, (uint32_t)ny, (uint32_t)nz, (uint32_t)channels};
    for (int k = 0; k < 5; ++k)
        put_u32(out + 4 + 4 * k, head[k]);
    const float box[6] = {0, 0, 0, 1, 1, 1};
    size_t n = (size_t)nx * (size_t)ny * (size_t)nz * (size_t)channels;
    for (size_t i = 0; i < 6 + n; ++i) {
        uint32_t u;
        memcpy(&u, i < 6 ? &box[i] : &values[i - 6], sizeof u);
        put_u32(out + 24 + 4 * i, u);
    }
    return 48 + 4 * n;
}

/* Writes the grid to TRACER_TEST_TMP_DIR/name. */
static void write_vol(const char *name, int nx, int ny, int nz, int channels,
                      const float *values)
{
    static unsigned char bytes[48 + 4 * 4096];
    size_t n = (size_t)nx * (size_t)ny * (size_t)nz * (size_t)channels;
    assert_true(n <= 4096);
    size_t size = vol_bytes(bytes, nx, ny, nz, channels, values);
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", TRACER_TEST_TMP_DIR, name);
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(bytes, 1, size, f), size);
    assert_int_equal(fclose(f), 0);
}

#endif /* TRACER_TEST_VOL_FILE_H */
