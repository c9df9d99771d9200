// nf_guide_client.cpp - the guide from a per-path C++17 renderer: the smallest client that
// shows what libnisflow's guide layer (nisflow/guide.h) gives a renderer.
//
// The scene: a diffuse floor (z = 0, albedo 0.8) seen from above, lit only by a small bright
// sphere that hangs low over one corner, so that cosine sampling finds it rarely. A camera
// path is one bounce: a point on the floor, a scattered direction, the light's radiance if the
// ray hits the sphere (no next-event estimation: the guide has to find the light). Each path
// is traced alone through the shading-point API, on two std::threads, as a per-path renderer
// (Cycles, pbrt) would.
//
// It trains while it renders, with no thread pool and no buffering of its own: the render
// threads trace batches with the newest published model, add their samples (never refused,
// also while a pass trains) and help with the training steps between batches
// (nf_guide_help); a third thread trains whenever samples wait (nf_guide_pending), through
// the guide's own parallel-for (nf_guide_helpers), and publishes.
//
// What it checks (exit status 1 if not):
//   1. unbiased: the guided estimate of the image mean agrees with plain cosine sampling's
//      within 4 standard errors of their difference;
//   2. the guide pays: after training, a guided sample's variance is below half of plain
//      cosine sampling's;
//   3. no add was refused, and every sample added was trained on or counted as dropped.
// The lines that call the library are marked "// nf".
#include <nisflow/nisflow.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <random>
#include <thread>
#include <vector>

namespace {

constexpr float kPi = 3.14159265358979f;
constexpr float kAlbedo = 0.8f;
constexpr float kLightCenter[3] = {0.9f, 0.9f, 0.25f};
constexpr float kLightRadius = 0.05f;
constexpr float kLightRadiance = 400.0f;

struct Vec {
    float x, y, z;
};

// The radiance arriving at floor point p from direction d: the sphere's, if the ray hits it.
float incoming(const Vec &p, const Vec &d)
{
    Vec o{p.x - kLightCenter[0], p.y - kLightCenter[1], p.z - kLightCenter[2]};
    float b = o.x * d.x + o.y * d.y + o.z * d.z;
    float c = o.x * o.x + o.y * o.y + o.z * o.z - kLightRadius * kLightRadius;
    return b * b - c >= 0.0f && -b - std::sqrt(b * b - c) > 0.0f ? kLightRadiance : 0.0f;
}

// Cosine-weighted direction around +z, and its density.
Vec sample_cosine(float u0, float u1, float *pdf)
{
    float r = std::sqrt(u0), phi = 2.0f * kPi * u1;
    Vec d{r * std::cos(phi), r * std::sin(phi), std::sqrt(std::fmax(0.0f, 1.0f - u0))};
    *pdf = d.z / kPi;
    return d;
}

float pdf_cosine(const Vec &d) { return d.z > 0.0f ? d.z / kPi : 0.0f; }

// What a thread of one pass returns.
struct PassResult {
    double sum = 0.0, sum_sq = 0.0;
    size_t paths = 0, added = 0, refused = 0;
};

// Estimates of one pass: `paths` paths through random floor points, each one alone.
// model NULL: plain cosine sampling. guide non-NULL: its training samples are added to it.
PassResult trace(const nf_model *model, nf_guide *guide, const nf_guide_policy *policy,
                 size_t paths, unsigned seed, size_t key_base)
{
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> uni(0.0f, 1.0f);
    std::vector<nf_context> ctx;
    std::vector<float> dirs, weights;
    std::vector<uint64_t> keys;
    PassResult out;
    for (size_t i = 0; i < paths; ++i) {
        Vec p{uni(rng), uni(rng), 0.0f};
        float g = model ? nf_guide_mixture_prob(policy, 1.0f) : 0.0f; // nf
        nf_context c = {{p.x, p.y, p.z}, {0.0f, 0.0f, 1.0f}, {0.0f, 0.0f, 1.0f}, 0.0f};
        nf_shading_point sp;
        if (model && nf_point_prepare(model, &c, nullptr, &sp) != NF_OK) // nf
            g = 0.0f; // a point the guide cannot take: the BSDF alone, still unbiased
        float u[2] = {uni(rng), uni(rng)}, p_flow = 0.0f, p_bsdf = 0.0f, dir[3];
        Vec d{};
        if (uni(rng) < g) {
            if (nf_point_sample(model, &sp, 1, u, dir, &p_flow) != NF_OK) // nf
                continue;
            d = Vec{dir[0], dir[1], dir[2]};
            p_bsdf = pdf_cosine(d);
        } else {
            d = sample_cosine(u[0], u[1], &p_bsdf);
            dir[0] = d.x, dir[1] = d.y, dir[2] = d.z;
            if (g > 0.0f && nf_point_pdf(model, &sp, 1, dir, &p_flow) != NF_OK) // nf
                continue;
        }
        float p_mix = g * p_flow + (1.0f - g) * p_bsdf;
        float f = d.z > 0.0f ? kAlbedo / kPi * d.z : 0.0f; // f_s |cos|
        float value = p_mix > 0.0f ? f * incoming(p, d) / p_mix : 0.0f;
        out.sum += value;
        out.sum_sq += double(value) * value;
        out.paths++;
        if (guide && g > 0.0f && value > 0.0f) { // what the flow learns from: f L / p_mix
            ctx.push_back(c);
            dirs.insert(dirs.end(), dir, dir + 3);
            weights.push_back(value);
            keys.push_back(key_base + i); // a key per path: the same model for any threads
        }
    }
    if (guide && nf_guide_add_samples(guide, weights.size(), keys.data(), ctx.data(), // nf
                                      dirs.data(), weights.data(), nullptr) != NF_OK)  // nf
        out.refused++; // never, while the guide trains or not: counted to show it
    out.added = guide ? weights.size() : 0;
    return out;
}

// Equal samples on `threads` std::threads with one frozen model (NULL: plain sampling).
PassResult evaluate(const nf_model *model, const nf_guide_policy *policy, int threads,
                    size_t paths, unsigned seed)
{
    std::vector<PassResult> part(threads);
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t)
        pool.emplace_back([&, t] {
            part[t] = trace(model, nullptr, policy, paths / threads, seed * 977u + unsigned(t), 0);
        });
    for (auto &th : pool)
        th.join();
    PassResult all;
    for (const auto &r : part) {
        all.sum += r.sum;
        all.sum_sq += r.sum_sq;
        all.paths += r.paths;
    }
    return all;
}

double mean(const PassResult &r) { return r.sum / double(r.paths); }
double variance(const PassResult &r) { return r.sum_sq / double(r.paths) - mean(r) * mean(r); }

} // namespace

int main()
{
    const int threads = 2;
    nf_config cfg;                            // nf
    nf_config_init(&cfg, NF_PRESET_SMALL);    // nf: the cosine prior around the floor's normal
    for (int a = 0; a < 3; ++a) {             // nf: the positions' box
        cfg.bounds_min[a] = a < 2 ? 0.0f : -0.1f; // nf
        cfg.bounds_max[a] = a < 2 ? 1.0f : 0.1f;  // nf
    }
    cfg.sh_bands = 0;        // nf: the position alone (the normal and wo never change here)
    nf_model *model = nullptr;                                          // nf
    nf_guide *guide = nullptr;                                          // nf
    nf_guide_config gc;                                                 // nf
    nf_guide_config_init(&gc);                                          // nf
    gc.steps_per_pass = 16;                                             // nf: small passes
    if (nf_model_create(&cfg, &model) != NF_OK ||                       // nf
        nf_guide_create(model, &gc, &guide) != NF_OK) {                 // nf
        std::fprintf(stderr, "nf_guide_client: %s\n", nf_last_error_message()); // nf
        return 1;
    }
    nf_model_destroy(model); // nf: the guide keeps its own copies

    // The trainer: a training pass whenever kMinNew samples wait, until the guide says stop
    // (patience) or 40 passes; the render threads help with its steps.
    constexpr size_t kMinNew = 256;
    std::atomic<bool> done{false}, failed{false};
    std::thread trainer([&] {
        const nf_parallel helpers = nf_guide_helpers(guide);                       // nf
        for (int k = 0; k < 40 && nf_guide_keep_training(guide, 0.0, 0.0); ++k) { // nf
            while (nf_guide_pending(guide) < kMinNew)                             // nf
                std::this_thread::yield();
            nf_guide_pass_report rep;                                           // nf
            if (nf_guide_train_pass(guide, &helpers, nullptr, &rep) != NF_OK || // nf
                nf_guide_publish(guide) != NF_OK) {                             // nf
                std::fprintf(stderr, "nf_guide_client: %s\n", nf_last_error_message()); // nf
                failed = true;
                break;
            }
            std::printf("training pass %2d: %6llu samples, held-out loss %.4f\n", k,
                        (unsigned long long)rep.new_samples, double(rep.held_out_loss)); // nf
        }
        done = true;
    });
    // The render threads: batches of paths with the newest model, until training is done.
    std::atomic<size_t> added{0}, refused{0};
    std::vector<std::thread> render;
    for (int t = 0; t < threads; ++t)
        render.emplace_back([&, t] {
            for (unsigned batch = 0; !done; ++batch) {
                const nf_model *m = nullptr;
                if (nf_guide_acquire(guide, &m) != NF_OK) // nf
                    break;
                size_t key = (size_t(batch) * threads + size_t(t)) * 1024;
                PassResult r = trace(m, guide, &gc.policy, 1024, 100u + 7u * batch + unsigned(t),
                                     key);
                nf_guide_release(guide, m); // nf
                added += r.added;
                refused += r.refused;
                nf_guide_help(guide); // nf: a share of the training step in progress, if any
            }
        });
    trainer.join();
    for (auto &th : render)
        th.join();
    nf_guide_train_pass(guide, nullptr, nullptr, nullptr); // nf: the last samples too
    nf_guide_stats stats;                                   // nf
    nf_guide_get_stats(guide, &stats);                      // nf
    const bool kept = !failed && refused == 0 && stats.samples + stats.dropped == added;
    std::printf("%zu samples added, %llu trained on, %llu dropped, %zu adds refused\n",
                size_t(added), (unsigned long long)stats.samples,
                (unsigned long long)stats.dropped, size_t(refused));

    // Equal samples, the newest model frozen: guided against plain cosine sampling.
    const size_t n = 200000;
    const nf_model *frozen = nullptr;
    nf_guide_acquire(guide, &frozen); // nf
    PassResult guided = evaluate(frozen, &gc.policy, threads, n, 7u);
    PassResult plain = evaluate(nullptr, &gc.policy, threads, n, 8u);
    nf_guide_release(guide, frozen); // nf
    nf_guide_destroy(guide);         // nf
    double se = std::sqrt(variance(guided) / double(guided.paths) +
                          variance(plain) / double(plain.paths));
    double ratio = variance(guided) / variance(plain);
    std::printf("mean: guided %.5f, plain %.5f (difference %.5f, standard error %.5f)\n",
                mean(guided), mean(plain), mean(guided) - mean(plain), se);
    std::printf("variance per sample: guided %.4f, plain %.4f (ratio %.3f)\n", variance(guided),
                variance(plain), ratio);
    // 4 standard errors: an unbiased pair fails with probability 6e-5. Training runs beside
    // rendering, so the model (and the numbers) vary a little from run to run.
    bool unbiased = std::fabs(mean(guided) - mean(plain)) < 4.0 * se;
    bool pays = ratio < 0.5;
    std::printf("%s: unbiased against plain sampling\n%s: variance below half of plain's\n"
                "%s: no sample refused or lost\n",
                unbiased ? "ok" : "FAILED", pays ? "ok" : "FAILED", kept ? "ok" : "FAILED");
    return unbiased && pays && kept ? 0 : 1;
}
