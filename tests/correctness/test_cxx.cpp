// test_cxx.cpp - the public headers compile as C++17 and the library links into a C++
// program: create a model, draw four directions, check the statuses and the densities.
#include <nisflow/nisflow.h>

#include <cmath>
#include <cstdio>

namespace {

int failures = 0;

void check(bool ok, const char *what)
{
    if (!ok) {
        std::fprintf(stderr, "test_cxx: FAILED: %s\n", what);
        ++failures;
    }
}

void check_status(nf_status s, const char *what)
{
    if (s != NF_OK) {
        std::fprintf(stderr, "test_cxx: FAILED: %s returned %s (%s)\n", what,
                     nf_status_string(s), nf_last_error_message());
        ++failures;
    }
}

} // namespace

int main()
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);

    nf_model *model = nullptr;
    check_status(nf_model_create(&cfg, &model), "nf_model_create");
    check(model != nullptr, "nf_model_create gives a model");

    if (model != nullptr) {
        constexpr int n = 4;
        nf_context ctx[n] = {};
        for (nf_context &c : ctx) {
            c.position[0] = c.position[1] = c.position[2] = 0.5f;
            c.normal[2] = 1.0f;
            c.wo[0] = 0.6f;
            c.wo[2] = 0.8f;
        }
        const float u[2 * n] = {0.1f, 0.2f, 0.3f, 0.9f, 0.55f, 0.45f, 0.8f, 0.05f};
        float dir[3 * n] = {};
        float pdf[n] = {};
        check_status(nf_sample(model, n, ctx, u, dir, pdf), "nf_sample");
        for (int i = 0; i < n; ++i) {
            check(std::isfinite(pdf[i]) && pdf[i] > 0.0f, "sampled pdf is finite and > 0");
            const float len = std::sqrt(dir[3 * i] * dir[3 * i] + dir[3 * i + 1] * dir[3 * i + 1] +
                                        dir[3 * i + 2] * dir[3 * i + 2]);
            check(std::fabs(len - 1.0f) < 1e-4f, "sampled direction has unit length");
        }

        float again[n] = {};
        check_status(nf_pdf(model, n, ctx, dir, again), "nf_pdf");
        for (int i = 0; i < n; ++i)
            check(std::isfinite(again[i]) && again[i] > 0.0f, "nf_pdf is finite and > 0");

        nf_model_destroy(model);
    }

    const bool passed = failures == 0;
    std::printf("%d passed, %d failed\n", passed ? 1 : 0, passed ? 0 : 1);
    return passed ? 0 : 1;
}
