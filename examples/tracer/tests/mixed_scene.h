/*
 * mixed_scene.h - what the tracer's unbiasedness tests share: a small scene of materials the
 * furnace cannot hold (plastic, whose coating is a delta lobe inside a guided vertex, a rough
 * conductor, rough plastic) lit by an area light and the sky, and the mean and standard error
 * of an image's pixels.
 */
#ifndef TRACER_TEST_MIXED_SCENE_H
#define TRACER_TEST_MIXED_SCENE_H

#include <math.h>
#include <stddef.h>

#include "image.h"

#define MIXED_SCENE_XML \
    "<scene version=\"3.0.0\">\n" \
    "<integrator type=\"path\"><integer name=\"max_depth\" value=\"6\"/></integrator>\n" \
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"55\"/>\n" \
    "  <transform name=\"to_world\"><lookat origin=\"0.6, 0.4, 1.8\" target=\"-0.2, -0.3, -0.3\" up=\"0, 1, 0\"/></transform>\n" \
    "  <film type=\"hdrfilm\"><integer name=\"width\" value=\"20\"/><integer name=\"height\" value=\"20\"/></film>\n" \
    "</sensor>\n" \
    "<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"-1\"/></transform>" \
    "<bsdf type=\"plastic\"><rgb name=\"diffuse_reflectance\" value=\"0.2, 0.5, 0.7\"/></bsdf></shape>\n" \
    "<shape type=\"rectangle\"><transform name=\"to_world\"><rotate x=\"1\" angle=\"-90\"/><translate y=\"-1\"/></transform>" \
    "<bsdf type=\"roughconductor\"><string name=\"distribution\" value=\"ggx\"/><float name=\"alpha\" value=\"0.3\"/></bsdf></shape>\n" \
    "<shape type=\"sphere\"><point name=\"center\" value=\"0, -0.5, -0.4\"/><float name=\"radius\" value=\"0.4\"/>" \
    "<bsdf type=\"roughplastic\"><float name=\"alpha\" value=\"0.2\"/></bsdf></shape>\n" \
    "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"0.3\"/><rotate x=\"1\" angle=\"90\"/><translate y=\"1\"/></transform>" \
    "<emitter type=\"area\"><rgb name=\"radiance\" value=\"8\"/></emitter></shape>\n" \
    "<emitter type=\"constant\"><rgb name=\"radiance\" value=\"0.3\"/></emitter>\n" \
    "</scene>\n"

/* Mean and standard error of the pixel values of the green channel (in the grey furnace all
 * channels agree; in the mixed scene the colours are correlated anyway). */
static inline void image_stats(const image *img, double *mean, double *stderr_)
{
    size_t n = (size_t)img->width * (size_t)img->height;
    double s = 0.0, s2 = 0.0;
    for (size_t i = 0; i < n; ++i) {
        double v = img->data[3 * i + 1];
        s += v;
        s2 += v * v;
    }
    *mean = s / (double)n;
    double var = (s2 / (double)n - *mean * *mean) * (double)n / (double)(n - 1);
    *stderr_ = sqrt(fmax(var, 0.0) / (double)n);
}

#endif /* TRACER_TEST_MIXED_SCENE_H */
