/* main.c - checks that an installed libnisflow can be found, compiled against and linked. */
#include <stdio.h>
#include <stdlib.h>

#include <nisflow/nisflow.h>

int main(void)
{
    printf("libnisflow %s (headers %d.%d.%d)\n", nf_version_string(), NF_VERSION_MAJOR,
           NF_VERSION_MINOR, NF_VERSION_PATCH);

    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    nf_model *model = NULL;
    nf_status s = nf_model_create(&cfg, &model);
    if (s != NF_OK) {
        fprintf(stderr, "nf_model_create: %s: %s\n", nf_status_string(s), nf_last_error_message());
        return EXIT_FAILURE;
    }

    /* One sample, so that the flow code (and libm, for static builds) is linked too. */
    nf_context ctx = {{0.5f, 0.5f, 0.5f}, {0.0f, 0.0f, 1.0f}, {0.0f, 0.0f, 1.0f}, 0.0f};
    const float u[2] = {0.25f, 0.75f};
    float dir[3], pdf;
    s = nf_sample(model, 1, &ctx, u, dir, &pdf);
    nf_model_destroy(model);
    if (s != NF_OK || !(pdf > 0.0f)) {
        fprintf(stderr, "nf_sample: %s: %s\n", nf_status_string(s), nf_last_error_message());
        return EXIT_FAILURE;
    }
    printf("sampled (%.3f, %.3f, %.3f) with pdf %.4f: ok\n", dir[0], dir[1], dir[2], pdf);
    return EXIT_SUCCESS;
}
