/*
 * nf_compare.c - prints the error of an image against a reference:
 *
 *   nf_compare reference.exr image.exr
 *   MAPE 0.0123 relMSE 0.0045 (1280 x 720)
 *   tail 0.0210 of relMSE in the worst pixel; relMSE 0.004100 without the 10 worst
 *   mean 0.2141 0.2139 difference -0.000200 +- 0.000310
 *   channels R 0.2502 0.2497 (-0.20 %) G 0.2133 0.2135 (+0.09 %) B 0.1788 0.1785 (-0.17 %)
 *
 * MAPE = mean |v - w| / (v + 1e-2) and relMSE = mean (v - w)^2 / (v^2 + 1e-2) over pixels
 * and the R, G, B channels, with v the first (reference) image. A reference that is an
 * integer multiple of the image's size is box-downsampled first. Exit status 0 on success,
 * 1 when a file cannot be read or the sizes do not match, 2 on a bad command line.
 *
 * The second line says how much of relMSE its worst pixels hold (image_relmse_tail): a render
 * whose relMSE is decided by a few paths of huge weight shows most of it in one pixel. The
 * third compares the images' means: the mean over pixels and channels of each,
 * and the mean of the pixel-by-pixel difference with its standard error. For two
 * independent unbiased renders of one scene the difference is within a few standard errors
 * of zero (the image's own structure cancels in the pixel-wise differences). The fourth gives
 * each channel's mean in both images and how far the image's is from the reference's.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "image.h"
#include "metrics.h"

int main(int argc, char **argv)
{
    if (argc == 2 && (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h"))) {
        printf("Usage: %s REFERENCE.exr IMAGE.exr\n"
               "Prints MAPE and relMSE of IMAGE against REFERENCE (epsilon 1e-2).\n", argv[0]);
        return 0;
    }
    if (argc != 3) {
        fprintf(stderr, "Usage: %s REFERENCE.exr IMAGE.exr (try --help)\n", argv[0]);
        return 2;
    }
    image ref, img, small;
    tr_error err;
    if (!image_read_exr(argv[1], &ref, &err)) {
        fprintf(stderr, "nf_compare: %s\n", err.msg);
        return 1;
    }
    if (!image_read_exr(argv[2], &img, &err)) {
        fprintf(stderr, "nf_compare: %s\n", err.msg);
        image_free(&ref);
        return 1;
    }
    if (ref.width != img.width || ref.height != img.height) {
        if (!image_downsample(&ref, img.width, img.height, &small, &err)) {
            fprintf(stderr, "nf_compare: %s\n", err.msg);
            image_free(&ref);
            image_free(&img);
            return 1;
        }
        image_free(&ref);
        ref = small;
    }
    printf("MAPE %.6f relMSE %.6f (%d x %d)\n", image_mape(&ref, &img), image_relmse(&ref, &img),
           img.width, img.height);
    double worst, body;
    image_relmse_tail(&ref, &img, METRIC_TAIL_PIXELS, &worst, &body);
    printf("tail %.4f of relMSE in the worst pixel; relMSE %.6f without the %d worst\n", worst,
           body, METRIC_TAIL_PIXELS);
    /* Per pixel, the difference of the channel means; then its mean and standard error. */
    size_t n = (size_t)img.width * (size_t)img.height;
    double mr = 0.0, mi = 0.0, sd = 0.0, sd2 = 0.0;
    for (size_t i = 0; i < n; ++i) {
        double a = (ref.data[3 * i] + ref.data[3 * i + 1] + ref.data[3 * i + 2]) / 3.0;
        double b = (img.data[3 * i] + img.data[3 * i + 1] + img.data[3 * i + 2]) / 3.0;
        mr += a;
        mi += b;
        sd += b - a;
        sd2 += (b - a) * (b - a);
    }
    double d = sd / (double)n, var = n > 1 ? (sd2 / (double)n - d * d) * (double)n / (double)(n - 1) : 0.0;
    printf("mean %.6f %.6f difference %.6f +- %.6f\n", mr / (double)n, mi / (double)n, d,
           sqrt(var > 0.0 ? var / (double)n : 0.0));
    printf("channels");
    for (int c = 0; c < 3; ++c) {
        double a = 0.0, b = 0.0;
        for (size_t i = 0; i < n; ++i) {
            a += ref.data[3 * i + c];
            b += img.data[3 * i + c];
        }
        printf(" %c %.4f %.4f (%+.2f %%)", "RGB"[c], a / (double)n, b / (double)n,
               a > 0.0 ? 100.0 * (b / a - 1.0) : 0.0);
    }
    printf("\n");
    image_free(&ref);
    image_free(&img);
    return 0;
}
