// nf_guide_client.cpp - a per-path C++17 path tracer on libnisflow's guide and schedule: what
// a renderer needs to write to get the library's whole result, and nothing more.
//
// The scene: a closed grey box (albedo 0.7) lit indirectly. Its light is a small square just
// below the ceiling that shines up at it; the floor and the walls below the light see only
// what the bright spot on the ceiling sends back, around the light's black underside, so
// next-event estimation at most of the visible points finds nothing and BSDF sampling rarely
// finds the spot.
// Paths are traced one at a time (ray against the box, next-event estimation with MIS,
// Russian roulette), on two std::threads, as a per-path renderer (Cycles, pbrt) would.
//
// The library decides what each pass is (nisflow/schedule.h): training passes, whose samples
// go to the guide while its previous pass trains on a third thread (the render threads help
// with those steps between rows: nf_guide_help), then guided or plain passes, and the image.
// Each render thread asks the flow through one vertex object (nisflow/vertex.h): at a shading
// point in training passes, and in guided render passes, whose model no longer changes, from a
// table of the flow built once per cell of the walls: a draw and a density there cost a few
// lookups instead of a walk through the flow each.
//
//   nf_guide_client [--seconds S] [--seed N] [--plain] [--out FILE] [--reference FILE]
//   nf_guide_client --check        what ctest runs (50 s): see check() below
//
// FILE: "W H\n" then W x H x 3 little-endian floats. The lines that call the library are
// marked "// nf", those that exist only for guiding "// guide".
#include <nisflow/nisflow.h>

#include <time.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <thread>
#include <vector>

namespace {

constexpr int kWidth = 128, kHeight = 128, kPixels = kWidth * kHeight, kThreads = 2;
constexpr int kMaxDepth = 8, kRrDepth = 3;
constexpr float kPi = 3.14159265358979f, kAlbedo = 0.7f, kLe = 60.0f;
constexpr float kLightZ = 0.95f, kLightLo = 0.45f, kLightHi = 0.55f; // facing +z
constexpr float kLightArea = (kLightHi - kLightLo) * (kLightHi - kLightLo);

struct Vec {
    float x, y, z;
};
Vec operator+(Vec a, Vec b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
Vec operator-(Vec a, Vec b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec operator*(Vec a, float s) { return {a.x * s, a.y * s, a.z * s}; }
float dot(Vec a, Vec b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
Vec normalize(Vec a) { return a * (1.0f / std::sqrt(dot(a, a))); }
float at(Vec v, int a) { return a == 0 ? v.x : a == 1 ? v.y : v.z; }

// ---- The scene ------------------------------------------------------------------------------

struct Hit {
    Vec p, n;   // point and the wall's inward normal
    int light;  // 1: the light's top (emitting), -1: its black underside, 0: a wall
};

// The ray from o (inside the box) along unit d: the nearest wall, or the light if nearer.
Hit intersect(Vec o, Vec d)
{
    Hit h{{0, 0, 0}, {0, 0, 0}, 0};
    float best = INFINITY;
    for (int a = 0; a < 3; ++a) {
        float da = at(d, a);
        if (da == 0.0f)
            continue;
        float t = ((da > 0.0f ? 1.0f : 0.0f) - at(o, a)) / da;
        if (t < best) {
            best = t;
            h.n = Vec{a == 0 ? -da : 0.0f, a == 1 ? -da : 0.0f, a == 2 ? -da : 0.0f};
            h.n = normalize(h.n);
        }
    }
    h.p = o + d * best;
    float t = (kLightZ - o.z) / d.z;
    Vec q = o + d * t;
    if (d.z != 0.0f && t > 1e-5f && t < best && q.x > kLightLo && q.x < kLightHi &&
        q.y > kLightLo && q.y < kLightHi) {
        h.p = q;
        h.light = d.z < 0.0f ? 1 : -1;
    }
    return h;
}

// A point on the light for next-event estimation: direction, distance and solid-angle pdf;
// 0 where x is below the light (its back faces x).
float sample_light(Vec x, float u0, float u1, Vec *wl)
{
    Vec y{kLightLo + (kLightHi - kLightLo) * u0, kLightLo + (kLightHi - kLightLo) * u1, kLightZ};
    Vec e = y - x;
    float d2 = dot(e, e);
    *wl = normalize(e);
    float cos_l = -wl->z;
    return x.z > kLightZ && cos_l > 0.0f ? d2 / (cos_l * kLightArea) : 0.0f;
}

// The light's solid-angle pdf of a ray from x that hit its top at y.
float light_pdf(Vec x, Vec y)
{
    Vec e = y - x;
    float d2 = dot(e, e), cos_l = (x.z - y.z) / std::sqrt(d2);
    return d2 / (cos_l * kLightArea);
}

// Cosine-weighted direction around n.
Vec sample_cosine(Vec n, float u0, float u1)
{
    Vec t = std::fabs(n.x) > 0.5f ? Vec{0, 1, 0} : Vec{1, 0, 0};
    Vec b = normalize(Vec{n.y * t.z - n.z * t.y, n.z * t.x - n.x * t.z, n.x * t.y - n.y * t.x});
    Vec c{b.y * n.z - b.z * n.y, b.z * n.x - b.x * n.z, b.x * n.y - b.y * n.x};
    float r = std::sqrt(u0), phi = 2.0f * kPi * u1;
    return normalize(b * (r * std::cos(phi)) + c * (r * std::sin(phi)) +
                     n * std::sqrt(std::fmax(0.0f, 1.0f - u0)));
}

float power(float a, float b) { return a * a / (a * a + b * b); }

double thread_cpu_seconds()
{
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// ---- The flow at a vertex ---------------------------------------------------------------------

// One render thread's vertex object, and the CPU its tables' builds took: a build is done once
// for the model's whole life, not by the pass that happens to need it first.
struct Flow {
    nf_vertex *v = nullptr; // guide
    double build_cpu = 0.0; // guide
};

// ---- One path -------------------------------------------------------------------------------

// What a path gives the pass: its radiance, its moments (nisflow/schedule.h), its vertices,
// and how many it shaded (guided: those that asked the flow).
struct PathOut {
    float radiance = 0.0f, moments[NF_GUIDE_DEPTHS] = {};
    nf_path_vertex v[kMaxDepth];
    int vertices = 0, shaded = 0, guided = 0;
};

// One camera path through pixel (px, py). m: the model of a guided pass (NULL: plain); its
// vertices up to `guide_depth` deep (0: every one) are guided through the vertex object v, by
// `route` (a cell's table, or a shading point).
void trace(const nf_model *m, const nf_guide_policy *pol, uint32_t guide_depth, int px, int py,
           std::mt19937 &rng, PathOut &out, nf_vertex *v, nf_vertex_route route)
{
    std::uniform_real_distribution<float> uni(0.0f, 1.0f);
    Vec o{0.5f, 0.02f, 0.5f};
    Vec d = normalize(Vec{(px + uni(rng)) / kWidth - 0.5f, 0.7f, 0.5f - (py + uni(rng)) / kHeight});
    float beta = 1.0f, p_scatter = 0.0f, p_bsdf_prev = 0.0f;
    nf_path_state ps;   // guide: the boost, and the moments the schedule weighs
    nf_path_start(&ps); // nf
    std::memset(out.v, 0, sizeof out.v);
    out.vertices = out.shaded = out.guided = 0;
    out.radiance = 0.0f;
    for (int depth = 1;; ++depth) {
        Hit h = intersect(o, d);
        if (h.light == 1) { // the light, seen from the camera or found by scattering
            float w = depth == 1 ? 1.0f : power(p_scatter, light_pdf(o, h.p));
            float w_plain = depth == 1 ? 1.0f : power(p_bsdf_prev, light_pdf(o, h.p)); // guide
            out.radiance += beta * kLe * w;
            nf_path_add(&ps, uint32_t(depth - 1), beta * kLe * w, beta * kLe * w_plain); // nf
            if (depth > 1) {
                nf_path_vertex &prev = out.v[out.vertices - 1];
                // guide: the emission unweighted, with the MIS weight the pixel gave it
                prev.emitted[0] = prev.emitted[1] = prev.emitted[2] = kLe;
                prev.emitted_mis = w;
            }
        }
        if (h.light != 0 || depth > kMaxDepth)
            break;
        Vec x = h.p, n = h.n, wo = d * -1.0f;
        out.shaded++;
        nf_context ctx = {{x.x, x.y, x.z}, {n.x, n.y, n.z}, {wo.x, wo.y, wo.z}, 0.0f}; // nf
        float g = m ? nf_path_mixture_prob(&ps, pol, uint32_t(depth), guide_depth) : 0.0f; // nf
        // The random numbers first: the roulette, the technique, the direction, the light.
        float q = nf_path_survival(&ps, pol, beta); // nf
        bool go_on = depth < kRrDepth || uni(rng) < q;
        float rr = depth >= kRrDepth ? 1.0f / q : 1.0f;
        bool from_flow = go_on && uni(rng) < g;
        float u[2] = {uni(rng), uni(rng)}, wi[3], p_flow = 0.0f, p_flow_l = 0.0f;
        Vec dir{}, wl; // the BSDF's direction, drawn below where the flow does not draw
        float p_light = sample_light(x, uni(rng), uni(rng), &wl), wl3[3] = {wl.x, wl.y, wl.z};
        float cos_l = dot(n, wl);
        bool lit = p_light > 0.0f && cos_l > 0.0f; // the light sample contributes
        bool flow_mis = g > 0.0f && nf_guide_light_mis_uses_flow(pol, uint32_t(depth)); // nf
        // The flow answers only what the vertex uses: the scattered direction if the path goes
        // on, the light sample's density if that sample contributes.
        bool ask_dir = go_on && g > 0.0f, ask_light = flow_mis && lit;
        if ((ask_dir || ask_light) && nf_vertex_set(v, m, &ctx, nullptr, route) != NF_OK) { // nf
            g = 0.0f; // unguided: the BSDF's direction, still unbiased
            from_flow = flow_mis = ask_dir = ask_light = false;
        }
        out.guided += ask_dir || ask_light;
        if (go_on && !from_flow)
            dir = sample_cosine(n, u[0], u[1]);
        nf_status st = NF_OK;
        if (from_flow) { // the flow's direction, and the light sample's density with it
            st = nf_vertex_sample(v, u, wi, &p_flow, ask_light ? 1 : 0, wl3, &p_flow_l); // nf
            dir = Vec{wi[0], wi[1], wi[2]};
        } else if (ask_dir || ask_light) { // the flow's density of the BSDF's direction, light's
            float dirs[6] = {dir.x, dir.y, dir.z, wl.x, wl.y, wl.z}, p[2];
            size_t k = ask_dir && ask_light ? 2 : 1;
            st = nf_vertex_pdf(v, k, ask_dir ? dirs : dirs + 3, p); // nf
            p_flow = ask_dir ? p[0] : 0.0f;
            p_flow_l = ask_light ? p[k - 1] : 0.0f;
        }
        if (st != NF_OK)
            break;
        // Next-event estimation, weighed against the mixture near the camera.
        float p_bsdf_l = cos_l > 0.0f ? cos_l / kPi : 0.0f;
        if (lit) {
            float p_mix_l = flow_mis ? g * p_flow_l + (1.0f - g) * p_bsdf_l : p_bsdf_l;
            float f = kAlbedo / kPi * cos_l * kLe / p_light;
            float direct = f * power(p_light, p_mix_l);
            out.radiance += beta * direct;
            out.v[out.vertices].direct[0] = out.v[out.vertices].direct[1] =
                out.v[out.vertices].direct[2] = direct;
            nf_path_add(&ps, uint32_t(depth), beta * direct, beta * f * power(p_light, p_bsdf_l)); // nf
        }
        nf_path_vertex &v = out.v[out.vertices++];
        if (!go_on)
            break;
        if (depth >= kRrDepth)
            nf_path_survived(&ps, pol, uint32_t(depth), beta, q); // nf
        // Scattering, weighed by the mixture.
        float cos_i = dot(n, dir), p_bsdf = cos_i > 0.0f ? cos_i / kPi : 0.0f;
        float p_mix = g * p_flow + (1.0f - g) * p_bsdf;
        if (!(p_mix > 0.0f) || cos_i <= 0.0f)
            break;
        float weight = kAlbedo / kPi * cos_i / p_mix;
        v.ctx = ctx;                                                         // guide
        v.dir[0] = dir.x, v.dir[1] = dir.y, v.dir[2] = dir.z;                // guide
        v.f_over_p[0] = v.f_over_p[1] = v.f_over_p[2] = weight;              // guide
        v.beta[0] = v.beta[1] = v.beta[2] = weight * rr;
        v.learn = g > 0.0f;                                                  // guide
        nf_path_scatter(&ps, uint32_t(depth), p_bsdf, p_mix, g); // nf: the boost and moments
        beta *= weight * rr;
        p_scatter = flow_mis ? p_mix : p_bsdf;
        p_bsdf_prev = p_bsdf;
        o = x + n * 1e-4f;
        d = dir;
    }
    for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
        out.moments[k] = ps.moments[k].moment; // guide
}

// ---- A pass ---------------------------------------------------------------------------------

double wall_seconds()
{
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

// What a pass cost: the tracing's CPU seconds (helping excluded) and the vertices it shaded.
struct PassCost {
    double cpu = 0.0;
    uint64_t shaded = 0, guided = 0;
};

// One pass: path j through pixel nf_pass_pixel(plan, j), chunks of a row's length shared by
// the threads; a training pass adds its samples to the guide chunk by chunk.
PassCost render_pass(const nf_pass_plan &plan, const nf_model *m, nf_guide *guide,
                     const nf_guide_policy *pol, uint64_t seed, std::vector<float> &rgb,
                     std::vector<float> &moments, std::vector<Flow> &flows)
{
    std::atomic<int> next_chunk{0}; // of a row's length
    std::atomic<double> cpu{0.0};
    std::atomic<uint64_t> shaded{0}, guided{0};
    auto work = [&](int t) {
        std::vector<nf_context> ctx(kWidth * kMaxDepth);    // guide
        std::vector<float> dir(3 * ctx.size()), w(ctx.size()); // guide
        std::vector<uint64_t> key(ctx.size());              // guide
        PathOut path;
        double spent = 0.0;
        uint64_t n_shaded = 0, n_guided = 0;
        for (uint32_t c; (c = uint32_t(next_chunk++)) * kWidth < plan.paths;) {
            double c0 = thread_cpu_seconds();
            Flow &flow = flows[size_t(t)];
            std::mt19937 rng(uint32_t(seed * 1000003u + plan.pass * 7919u + c));
            size_t n = 0;
            for (uint32_t j = c * kWidth; j < (c + 1) * kWidth && j < plan.paths; ++j) {
                int i = int(nf_pass_pixel(&plan, j)); // nf: the pixel of the pass's path j
                trace(m, pol, plan.depth, i % kWidth, i / kWidth, rng, path, flow.v, // guide
                      plan.todo == NF_TODO_GUIDED ? NF_VERTEX_TABLE : NF_VERTEX_POINT); // nf
                n_shaded += uint64_t(path.shaded);
                n_guided += uint64_t(path.guided);
                rgb[3 * j] = rgb[3 * j + 1] = rgb[3 * j + 2] = path.radiance;
                for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
                    moments[k * plan.paths + j] = path.moments[k];
                size_t got = 0;
                if (plan.todo == NF_TODO_TRAIN &&
                    nf_path_training_samples(size_t(path.vertices), path.v, kMaxDepth,    // nf
                                             &ctx[n], &dir[3 * n], &w[n], nullptr, &got) == NF_OK)
                    for (size_t s = 0; s < got; ++s)
                        key[n + s] = uint64_t(j) * kMaxDepth + s; // guide: one key per sample
                n += got;
            }
            if (n > 0) // never refused: samples added while a pass trains wait for the next
                nf_guide_add_samples(guide, n, key.data(), ctx.data(), dir.data(), w.data(), // nf
                                     nullptr);                                             // nf
            // A table is built once for the model's whole life: its cost is not the pass's, whose
            // cost the schedule weighs against plain passes (tables_cpu reports it).
            double b0 = thread_cpu_seconds();
            spent += b0 - c0;
            nf_vertex_build(flow.v); // nf: the tables of the cells this chunk found without one
            flow.build_cpu += thread_cpu_seconds() - b0;
            nf_guide_help(guide); // nf: a share of the training step in progress, if any
        }
        for (double c = cpu; !cpu.compare_exchange_weak(c, c + spent);)
            ;
        shaded += n_shaded;
        guided += n_guided;
    };
    std::vector<std::thread> pool;
    for (int t = 0; t < kThreads; ++t)
        pool.emplace_back(work, t);
    for (auto &th : pool)
        th.join();
    return PassCost{cpu, shaded, guided};
}

// ---- The job --------------------------------------------------------------------------------

struct Result {
    std::vector<float> image;
    nf_schedule_report report;
    std::vector<double> pass_means; // each pass's image mean (the spread of the estimate)
    PassCost kind_cost[2];          // the render passes' cost by kind (nf_pass_kind)
    uint64_t lookups = 0, tables = 0; // vertices asked, tables built, and the builds' CPU seconds
    uint64_t from_tables = 0;
    double tables_cpu = 0.0;
    bool ok = false;
};

// Renders the box in `seconds` with the schedule; guided unless plain.
Result render(double seconds, uint64_t seed, bool plain)
{
    Result r;
    const float box_min[3] = {0.0f, 0.0f, 0.0f}, box_max[3] = {1.0f, 1.0f, 1.0f};
    nf_config cfg;                                       // nf: the best configuration,
    nf_guide_model_config_init(&cfg, box_min, box_max); // nf: inside the scene's bounds
    nf_model *model = nullptr;               // nf
    nf_guide *guide = nullptr;               // nf
    nf_guide_config gc;                      // nf
    nf_guide_config_init(&gc);               // nf
    nf_schedule_config sc;                   // nf
    nf_schedule_config_init(&sc);            // nf
    sc.width = kWidth, sc.height = kHeight, sc.budget = seconds; // nf
    nf_schedule *sched = nullptr;                                // nf
    if (nf_model_create(&cfg, &model) != NF_OK ||                // nf
        (!plain && nf_guide_create(model, &gc, &guide) != NF_OK) || // nf
        nf_schedule_create(guide, &sc, &sched) != NF_OK) {       // nf
        std::fprintf(stderr, "nf_guide_client: %s\n", nf_last_error_message()); // nf
        return r;
    }
    nf_model_destroy(model); // nf: the guide keeps its own copies
    std::vector<float> rgb, moments; // a pass's paths: RGB, and NF_GUIDE_DEPTHS moments each
    std::vector<Flow> flows(kThreads); // guide: each render thread's
    bool made = true;                  // otherwise the error is reported below
    for (Flow &f : flows)
        made = made && nf_vertex_create(nullptr, &f.v) == NF_OK; // nf
    std::thread trainer;     // guide: trains the previous pass while the next one renders
    nf_status trained = NF_OK;
    const double start = wall_seconds();
    for (bool train_next = false; made;) {
        nf_pass_plan plan;                                                  // nf
        if (nf_schedule_next(sched, wall_seconds() - start, nullptr, &plan) != NF_OK) { // nf
            r.ok = false;
            break;
        }
        if (train_next && plan.todo != NF_TODO_STOP) // guide: the last training pass's steps,
            trainer = std::thread([&] {               // guide: beside this pass
                const nf_parallel helpers = nf_guide_helpers(guide);        // nf
                trained = nf_guide_train_pass(guide, &helpers, nullptr, nullptr); // nf
                if (trained == NF_OK)
                    trained = nf_guide_publish(guide);                      // nf
            });
        if (plan.todo == NF_TODO_STOP)
            r.ok = true;
        else {
            const nf_model *m = nullptr;
            if (plan.todo != NF_TODO_PLAIN)
                nf_guide_acquire(guide, &m);                                // nf
            rgb.resize(3 * size_t(plan.paths));
            moments.resize(NF_GUIDE_DEPTHS * size_t(plan.paths));
            double t0 = wall_seconds();
            PassCost cost = render_pass(plan, m, guide, &gc.policy, seed, rgb, moments, flows);
            if (plan.todo != NF_TODO_TRAIN) {
                PassCost &k = r.kind_cost[plan.todo == NF_TODO_PLAIN ? NF_PASS_PLAIN : NF_PASS_GUIDED];
                k.cpu += cost.cpu, k.shaded += cost.shaded, k.guided += cost.guided;
            }
            if (m)
                nf_guide_release(guide, m);                                 // nf
            if (trainer.joinable()) // guide: the schedule reads the guide: training is done
                trainer.join();     // guide
            double mean = 0.0;
            for (uint32_t j = 0; j < plan.paths; ++j)
                mean += rgb[3 * j] / plan.paths;
            r.pass_means.push_back(mean);
            r.ok = nf_schedule_add_pass(sched, &plan, rgb.data(), moments.data(),  // nf
                                        wall_seconds() - t0, cost.cpu, nullptr) == NF_OK; // nf
        }
        train_next = plan.todo == NF_TODO_TRAIN; // guide
        if (!r.ok || trained != NF_OK || plan.todo == NF_TODO_STOP)
            break;
    }
    r.image.resize(3 * kPixels);
    if (!r.ok || trained != NF_OK ||
        nf_schedule_combine(sched, nullptr, r.image.data(), &r.report) != NF_OK) { // nf
        std::fprintf(stderr, "nf_guide_client: %s\n", nf_last_error_message()); // nf
        r.ok = false;
    }
    for (Flow &f : flows) {
        nf_vertex_stats st;                            // nf
        if (nf_vertex_get_stats(f.v, &st) == NF_OK)    // nf
            r.lookups += st.points + st.tables, r.tables += st.builds, r.from_tables += st.tables;
        r.tables_cpu += f.build_cpu;
        nf_vertex_destroy(f.v); // nf
    }
    nf_schedule_destroy(sched); // nf
    nf_guide_destroy(guide);    // nf
    return r;
}

// ---- Files, errors and the check --------------------------------------------------------------

bool write_image(const std::string &path, const std::vector<float> &img)
{
    FILE *f = std::fopen(path.c_str(), "wb");
    if (!f)
        return false;
    std::fprintf(f, "%d %d\n", kWidth, kHeight);
    bool ok = std::fwrite(img.data(), sizeof(float), img.size(), f) == img.size();
    return std::fclose(f) == 0 && ok;
}

bool read_image(const std::string &path, std::vector<float> &img)
{
    FILE *f = std::fopen(path.c_str(), "rb");
    int w = 0, h = 0;
    img.assign(3 * kPixels, 0.0f);
    bool ok = f && std::fscanf(f, "%d %d", &w, &h) == 2 && w == kWidth && h == kHeight &&
              std::fgetc(f) == '\n' &&
              std::fread(img.data(), sizeof(float), img.size(), f) == img.size();
    if (f)
        std::fclose(f);
    return ok;
}

// relMSE as the study measures it: the mean over pixels of (x - r)^2 / (r^2 + 0.01).
double relmse(const std::vector<float> &img, const std::vector<float> &ref)
{
    double acc = 0.0;
    for (int i = 0; i < kPixels; ++i) {
        double d = double(img[3 * i]) - ref[3 * i];
        acc += d * d / (double(ref[3 * i]) * ref[3 * i] + 0.01);
    }
    return acc / kPixels;
}

double image_mean(const std::vector<float> &img)
{
    double acc = 0.0;
    for (int i = 0; i < kPixels; ++i)
        acc += img[3 * i];
    return acc / kPixels;
}

// The standard error of a render's image mean, from its passes' means.
double standard_error(const Result &r)
{
    double n = double(r.pass_means.size()), m = 0.0, v = 0.0;
    for (double x : r.pass_means)
        m += x / n;
    for (double x : r.pass_means)
        v += (x - m) * (x - m) / (n - 1.0);
    return std::sqrt(v / n);
}

void print(const char *name, const Result &r)
{
    const nf_schedule_report &p = r.report;
    double ms[2] = {0.0, 0.0}; // CPU milliseconds per pass of each kind
    for (int k = 0; k < 2; ++k)
        ms[k] = p.kind_passes[k] ? 1e3 * p.kind_cpu_seconds[k] / p.kind_passes[k] : 0.0;
    std::printf("%-7s %u training passes, %u guided (%.2f CPU ms each, depth %u) and %u plain "
                "(%.2f) render passes, variance %.3g and %.3g, guided / plain variance x time "
                "%.3g, image mean %.5f\n",
                name, p.train_passes, p.kind_passes[NF_PASS_GUIDED], ms[0], p.depth,
                p.kind_passes[NF_PASS_PLAIN], ms[1], p.kind_variance[0], p.kind_variance[1],
                p.ratio, image_mean(r.image));
    // A guided pass's vertex costs a plain one's plus, at the share f that asked the flow, the
    // flow's questions: a guided vertex is plain + (guided pass's - plain) / f.
    const PassCost &g = r.kind_cost[NF_PASS_GUIDED], &pl = r.kind_cost[NF_PASS_PLAIN];
    double ns_g = g.shaded ? 1e9 * g.cpu / double(g.shaded) : 0.0;
    double ns_p = pl.shaded ? 1e9 * pl.cpu / double(pl.shaded) : 0.0;
    double f = g.shaded ? double(g.guided) / double(g.shaded) : 0.0;
    std::printf("cost: %.1f CPU ns per vertex in guided passes (%.3f of them asked the flow), "
                "%.1f in plain ones; a guided vertex %.2fx a plain one; %llu tables built in "
                "%.2f CPU s, %.5f of %llu guided vertices answered from one\n",
                ns_g, f, ns_p, ns_p > 0.0 && f > 0.0 ? 1.0 + (ns_g / ns_p - 1.0) / f : 0.0,
                (unsigned long long)r.tables, r.tables_cpu,
                r.lookups ? double(r.from_tables) / double(r.lookups) : 0.0,
                (unsigned long long)r.lookups);
}

// What ctest runs: a guided render and a plain one of 10 s each, and a plain reference of
// 30 s. Guided must agree with plain (image means within 4 standard errors of their
// difference: an unbiased pair fails with probability 6e-5) and must not be worse against the
// reference (relMSE at most plain's; the equal-time script has the figures).
int check()
{
    Result ref = render(30.0, 99, true), guided = render(10.0, 1, false), plain = render(10.0, 2, true);
    if (!ref.ok || !guided.ok || !plain.ok)
        return 1;
    print("guided", guided);
    print("plain", plain);
    double se = std::sqrt(standard_error(guided) * standard_error(guided) +
                          standard_error(plain) * standard_error(plain));
    double diff = image_mean(guided.image) - image_mean(plain.image);
    double eg = relmse(guided.image, ref.image), ep = relmse(plain.image, ref.image);
    // A render whose training ended before kTrained passes had too little time to make a
    // model (a sanitizer's build runs about 3x slower: under ASan 3 training passes in 8 s,
    // against 16 in 10 s in a release build), and guiding then costs its training's share of
    // the budget: only the agreement is judged.
    const uint32_t kTrained = 8;
    bool judged = guided.report.train_passes >= kTrained;
    bool unbiased = std::fabs(diff) < 4.0 * se, not_worse = !judged || eg <= ep;
    std::printf("mean difference %.5f, standard error %.5f\nrelMSE guided %.5f, plain %.5f "
                "(ratio %.3f; the reference's own noise is in both)\n",
                diff, se, eg, ep, eg / ep);
    std::printf("%s: unbiased against plain path tracing\n%s: not worse than plain path "
                "tracing\n",
                unbiased ? "ok" : "FAILED",
                !judged ? "skipped (training too short to judge)" : not_worse ? "ok" : "FAILED");
    return unbiased && not_worse ? 0 : 1;
}

} // namespace

int main(int argc, char **argv)
{
    double seconds = 20.0;
    uint64_t seed = 1;
    bool plain = false;
    std::string out, reference;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        bool value = i + 1 < argc;
        if (a == "--check")
            return check();
        if (a == "--plain")
            plain = true;
        else if (a == "--seconds" && value)
            seconds = std::atof(argv[++i]);
        else if (a == "--seed" && value)
            seed = std::strtoull(argv[++i], nullptr, 10);
        else if (a == "--out" && value)
            out = argv[++i];
        else if (a == "--reference" && value)
            reference = argv[++i];
        else {
            std::fprintf(stderr, "usage: nf_guide_client [--check] [--seconds S] [--seed N] "
                                 "[--plain] [--out FILE] [--reference FILE]\n");
            return 2;
        }
    }
    if (!(seconds > 0.0)) {
        std::fprintf(stderr, "nf_guide_client: --seconds must be > 0\n");
        return 2;
    }
    Result r = render(seconds, seed, plain);
    if (!r.ok)
        return 1;
    print(plain ? "plain" : "guided", r);
    if (!out.empty() && !write_image(out, r.image)) {
        std::fprintf(stderr, "nf_guide_client: cannot write %s\n", out.c_str());
        return 1;
    }
    std::vector<float> ref;
    if (!reference.empty()) {
        if (!read_image(reference, ref)) {
            std::fprintf(stderr, "nf_guide_client: cannot read %s (%d x %d)\n",
                         reference.c_str(), kWidth, kHeight);
            return 1;
        }
        std::printf("relMSE %.6f\n", relmse(r.image, ref));
    }
    return 0;
}
