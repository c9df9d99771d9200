/*
 * test_alloc_failure.c - injected allocation failures at every allocation site.
 *
 * The library allocates in nf_model_create, nf_model_clone (through the model's nf_allocator),
 * nf_model_save (one temporary buffer, through the model's allocator), and nf_model_load /
 * nf_model_deserialize (through malloc, whatever the allocator: io.h). A counting allocator
 * that fails its k-th call, for k = 1, 2, ... until a whole scenario succeeds, proves for the
 * first three that each failure
 *   - returns NF_ERROR_OUT_OF_MEMORY with a message, and *out == NULL;
 *   - leaks nothing (allocations minus frees, and bytes, back to where they were);
 *   - leaves every existing model bit-identical (serialized bytes) and an existing file at
 *     the save path untouched.
 * malloc cannot be replaced through the API, so for load and deserialize the failures are
 * injected with an address-space limit (setrlimit RLIMIT_AS) in a forked child on Linux, and
 * the leak check uses glibc's mallinfo2; under the sanitizers (which reserve terabytes of
 * address space) that part is skipped.
 * The shading-point API never allocates (point.h): with the allocator armed to fail, no call
 * of nf_point_prepare / nf_point_sample / nf_point_pdf / nf_points_* reaches it, whether the
 * call succeeds, is refused or finds its point stale. A vertex object (vertex.h) allocates in
 * nf_vertex_create only: each of its allocations fails cleanly there, and its other calls,
 * table builds included, never reach the allocator.
 */
#define _POSIX_C_SOURCE 200809L /* fork, waitpid, getpid, setrlimit */

#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

#if defined(__linux__) && defined(__GLIBC__)
#include <malloc.h>
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>
#include "point_batch.h"
#include "shading_point.h"
#define HAVE_RLIMIT_INJECTION 1
#else
#define HAVE_RLIMIT_INJECTION 0
#endif

/* ---- the failing allocator ------------------------------------------------------------------ */

typedef struct failing {
    unsigned long calls;   /* alloc calls so far                                  */
    unsigned long fail_at; /* the call that returns NULL (1-based; 0 = never)     */
    unsigned long failed;  /* how many calls returned NULL                        */
    long live;             /* allocations not yet freed                           */
    long long live_bytes;  /* their bytes                                         */
    int bad_free;          /* free(NULL) or a pointer we did not hand out         */
} failing;

/* A size header in front of every block, so the allocator can count bytes and recognise its
 * own pointers. max_align_t keeps the returned pointer aligned for anything. */
typedef union header {
    max_align_t align;
    struct {
        size_t size;
        uint32_t magic;
    } h;
} header;
#define MAGIC 0x6e66616cu

static void *failing_alloc(void *user, size_t size)
{
    failing *f = user;
    f->calls++;
    if (f->fail_at != 0 && f->calls == f->fail_at) {
        f->failed++;
        return NULL;
    }
    header *h = malloc(sizeof(header) + size);
    if (!h)
        return NULL;
    h->h.size = size;
    h->h.magic = MAGIC;
    f->live++;
    f->live_bytes += (long long)size;
    return h + 1;
}

static void failing_free(void *user, void *ptr)
{
    failing *f = user;
    if (!ptr) {
        f->bad_free++;
        return;
    }
    header *h = (header *)ptr - 1;
    if (h->h.magic != MAGIC) {
        f->bad_free++;
        return;
    }
    h->h.magic = 0;
    f->live--;
    f->live_bytes -= (long long)h->h.size;
    free(h);
}

static nf_config failing_config(failing *f, nf_preset preset, nf_prior_kind prior)
{
    nf_config cfg = nft_config(preset, prior);
    cfg.allocator.alloc = failing_alloc;
    cfg.allocator.free = failing_free;
    cfg.allocator.user = f;
    return cfg;
}

/* Fails the next allocation after `ahead` successful ones. */
static void fail_in(failing *f, unsigned long ahead)
{
    f->fail_at = f->calls + ahead + 1;
}

static void never_fail(failing *f)
{
    f->fail_at = 0;
}

static int message_mentions_memory(void)
{
    const char *msg = nf_last_error_message();
    return msg[0] != '\0' && (strstr(msg, "alloc") != NULL || strstr(msg, "memory") != NULL);
}

/* ---- helpers ------------------------------------------------------------------------------ */

enum { N = 32 };

static void train(nf_model *m, int steps, uint64_t seed)
{
    nf_context ctx[N];
    float dir[3 * N], w[N];
    nft_rng r;
    nft_rng_seed(&r, seed, 7u);
    for (int s = 0; s < steps; ++s) {
        nft_random_samples(&r, N, ctx, dir, w, 0.0f);
        assert_int_equal(nf_train_step(m, N, ctx, dir, w, NULL), NF_OK);
    }
}

static void temp_path(char *path, size_t size, const char *tag)
{
    snprintf(path, size, "nf_test_alloc_failure_%s_%ld.nfm", tag, (long)getpid());
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(text, 1, strlen(text), f), strlen(text));
    assert_int_equal(fclose(f), 0);
}

static int file_equals(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return 0;
    unsigned char *buf = malloc(size + 1);
    size_t got = buf ? fread(buf, 1, size + 1, f) : 0;
    fclose(f);
    int equal = buf && got == size && memcmp(buf, data, size) == 0;
    free(buf);
    return equal;
}

/* ---- nf_model_create --------------------------------------------------------------------- */

/* Every allocation of nf_model_create fails in turn, for several configurations; the loop
 * ends at the first k where creation succeeds, which proves it has exactly k - 1 allocation
 * sites. */
static void test_create(void **state)
{
    (void)state;
    const nf_preset presets[2] = {NF_PRESET_SMALL, NF_PRESET_LARGE};
    for (int p = 0; p < 2; ++p)
        for (int prior = 0; prior < 4; ++prior) {
            failing f;
            memset(&f, 0, sizeof f);
            nf_config cfg = failing_config(&f, presets[p], (nf_prior_kind)prior);
            unsigned long k = 1;
            for (;; ++k) {
                assert_true(k < 100);
                f.calls = 0;
                f.fail_at = k;
                nf_model *m = (nf_model *)&f; /* not NULL: the library must clear it */
                nf_status st = nf_model_create(&cfg, &m);
                if (st == NF_OK) {
                    assert_non_null(m);
                    assert_true(f.live > 0);
                    nf_model_destroy(m);
                    break;
                }
                assert_int_equal(st, NF_ERROR_OUT_OF_MEMORY);
                assert_null(m);
                assert_true(message_mentions_memory());
                assert_int_equal(f.live, 0);
                assert_true(f.live_bytes == 0);
            }
            /* At least one allocation was made to fail, and all were released. */
            assert_true(k >= 2);
            assert_int_equal(f.failed, k - 1);
            assert_int_equal(f.live, 0);
            assert_true(f.live_bytes == 0);
            assert_int_equal(f.bad_free, 0);
        }
}

/* ---- nf_model_clone ------------------------------------------------------------------------ */

static void test_clone(void **state)
{
    (void)state;
    failing f;
    memset(&f, 0, sizeof f);
    nf_config cfg = failing_config(&f, NF_PRESET_LARGE, NF_PRIOR_CUSTOM);
    nf_model *m = nft_model_from(&cfg);
    train(m, 3, 1u);
    nft_snapshot snap = nft_snapshot_of(m);
    const long live = f.live;
    const long long bytes = f.live_bytes;
    unsigned long k = 0;
    for (;; ++k) {
        assert_true(k < 100);
        fail_in(&f, k);
        nf_model *copy = (nf_model *)&f;
        nf_status st = nf_model_clone(m, &copy);
        /* The source is intact whether or not the clone succeeded. */
        assert_true(nft_snapshot_equal(m, &snap));
        if (st == NF_OK) {
            assert_non_null(copy);
            /* The clone uses the same allocator and is identical. */
            assert_true(f.live > live);
            assert_true(nft_snapshot_equal(copy, &snap));
            nf_model_destroy(copy);
            break;
        }
        assert_int_equal(st, NF_ERROR_OUT_OF_MEMORY);
        assert_null(copy);
        assert_true(message_mentions_memory());
        assert_int_equal(f.live, live);
        assert_true(f.live_bytes == bytes);
    }
    assert_true(k >= 1);
    assert_int_equal(f.live, live);
    never_fail(&f);
    /* A clone of a clone, and training it, still goes through the same allocator. */
    nf_model *copy = NULL;
    assert_int_equal(nf_model_clone(m, &copy), NF_OK);
    train(copy, 1, 2u);
    nf_model_destroy(copy);
    nf_model_destroy(m);
    assert_int_equal(f.live, 0);
    assert_true(f.live_bytes == 0);
    assert_int_equal(f.bad_free, 0);
    nft_snapshot_free(&snap);
}

/* ---- nf_model_save ------------------------------------------------------------------------- */

/* The temporary buffer of nf_model_save fails: NF_ERROR_OUT_OF_MEMORY, nothing leaked, the
 * model untouched, and a file already at the path keeps its content (the buffer is
 * allocated before the file is opened). */
static void test_save(void **state)
{
    (void)state;
    char path[128];
    temp_path(path, sizeof path, "save");
    failing f;
    memset(&f, 0, sizeof f);
    nf_config cfg = failing_config(&f, NF_PRESET_SMALL, NF_PRIOR_COSINE);
    nf_model *m = nft_model_from(&cfg);
    train(m, 2, 3u);
    nft_snapshot snap = nft_snapshot_of(m);
    const char *previous = "a file that was here before";
    write_file(path, previous);
    const long live = f.live;
    unsigned long k = 0;
    for (;; ++k) {
        assert_true(k < 100);
        fail_in(&f, k);
        nf_status st = nf_model_save(m, path);
        assert_true(nft_snapshot_equal(m, &snap));
        assert_int_equal(f.live, live);
        if (st == NF_OK)
            break;
        assert_int_equal(st, NF_ERROR_OUT_OF_MEMORY);
        assert_true(message_mentions_memory());
        if (!file_equals(path, previous, strlen(previous)))
            fail_msg("a failed save (allocation %lu) changed the existing file", k + 1);
    }
    assert_true(k >= 1);
    /* The successful save wrote exactly the serialized bytes. */
    assert_true(file_equals(path, snap.bytes, snap.bytes_size));
    never_fail(&f);
    nf_model *back = NULL;
    nf_status st = nf_model_load(path, NULL, &back);
    remove(path);
    assert_int_equal(st, NF_OK);
    assert_true(nft_snapshot_equal(back, &snap));
    nf_model_destroy(back);
    nf_model_destroy(m);
    assert_int_equal(f.live, 0);
    assert_int_equal(f.bad_free, 0);
    nft_snapshot_free(&snap);
}

/* ---- a whole scenario --------------------------------------------------------------------- */

/* create -> train -> clone -> save -> clone of the clone -> train the clone -> save it, with
 * the k-th allocation of the whole scenario failing, for every k until it runs through. Each
 * step that fails must fail cleanly; steps after it are skipped; at the end everything is
 * destroyed and nothing may be left. */
static int scenario(failing *f, const char *path, unsigned long *failed_step)
{
    nf_config cfg = failing_config(f, NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    nf_model *a = NULL, *b = (nf_model *)f, *c = (nf_model *)f;
    nft_snapshot snap_a, snap_b;
    memset(&snap_a, 0, sizeof snap_a);
    memset(&snap_b, 0, sizeof snap_b);
    int step = 0;
    nf_status st = nf_model_create(&cfg, &a);
    if (st != NF_OK) {
        assert_null(a);
        goto failed;
    }
    train(a, 2, 4u);
    assert_int_equal(nft_snapshot_take(a, &snap_a), 0);
    step = 1;
    if ((st = nf_model_clone(a, &b)) != NF_OK) {
        assert_null(b);
        goto failed;
    }
    step = 2;
    if ((st = nf_model_save(a, path)) != NF_OK)
        goto failed;
    step = 3;
    if ((st = nf_model_clone(b, &c)) != NF_OK) {
        assert_null(c);
        goto failed;
    }
    train(c, 1, 5u);
    assert_int_equal(nft_snapshot_take(b, &snap_b), 0);
    step = 4;
    if ((st = nf_model_save(c, path)) != NF_OK)
        goto failed;
    step = 5;
failed:
    *failed_step = (unsigned long)step;
    if (st != NF_OK) {
        assert_int_equal(st, NF_ERROR_OUT_OF_MEMORY);
        assert_true(message_mentions_memory());
    }
    /* Models that existed when the failure happened are intact. */
    if (snap_a.bytes)
        assert_true(nft_snapshot_equal(a, &snap_a));
    if (snap_b.bytes)
        assert_true(nft_snapshot_equal(b, &snap_b));
    nft_snapshot_free(&snap_a);
    nft_snapshot_free(&snap_b);
    if (c != (nf_model *)f)
        nf_model_destroy(c);
    if (b != (nf_model *)f)
        nf_model_destroy(b);
    nf_model_destroy(a);
    return st == NF_OK;
}

static void test_scenario(void **state)
{
    (void)state;
    char path[128];
    temp_path(path, sizeof path, "scenario");
    unsigned long k = 1, reached[6] = {0};
    for (;; ++k) {
        assert_true(k < 1000);
        failing f;
        memset(&f, 0, sizeof f);
        f.fail_at = k;
        unsigned long step = 0;
        int done = scenario(&f, path, &step);
        assert_int_equal(f.live, 0);
        assert_true(f.live_bytes == 0);
        assert_int_equal(f.bad_free, 0);
        reached[step]++;
        if (done) {
            assert_int_equal(f.failed, 0);
            break;
        }
        assert_int_equal(f.failed, 1);
    }
    remove(path);
    /* Every step of the scenario met a failure: create, clone, save, clone, save. */
    for (int s = 0; s < 5; ++s)
        if (reached[s] == 0)
            fail_msg("no injected failure hit step %d of the scenario", s);
    print_message("  %lu allocations in the scenario, each failed once\n", k - 1);
}

/* ---- nf_model_deserialize and nf_model_load: malloc under an address-space limit -------- */

#if HAVE_RLIMIT_INJECTION
/* Bytes of heap in use, from glibc: the arena's allocated bytes plus mmapped chunks. */
static size_t heap_in_use(void)
{
    struct mallinfo2 mi = mallinfo2();
    return mi.uordblks + mi.hblkhd;
}

/* The current address-space size in bytes (the first field of /proc/self/statm, in pages). */
static long long address_space(void)
{
    FILE *f = fopen("/proc/self/statm", "r");
    long long pages = -1;
    if (f) {
        if (fscanf(f, "%lld", &pages) != 1)
            pages = -1;
        fclose(f);
    }
    return pages < 0 ? -1 : pages * sysconf(_SC_PAGESIZE);
}

/* In a child process limited to `headroom` more bytes of address space, runs `op` (0:
 * deserialize the buffer, 1: load the file) and checks that it failed cleanly. "No heap left
 * behind" allows 1 KB: glibc keeps a freed FILE (fopen/fclose in nf_model_load) in its
 * per-thread cache, which mallinfo2 counts as in use; what the library allocates on these
 * paths (the read buffer, the model block) is megabytes. Exits with: 0 refused with
 * NF_ERROR_OUT_OF_MEMORY, *out NULL, a message containing `expect` (which allocation failed)
 * and no heap left behind; 1 it succeeded (the limit was too generous); 2 another outcome;
 * 3 no limit could be set; 4 the heap inherited from the parent has more than `max_free`
 * bytes free, which malloc could use without growing the address space, so the limit would
 * prove nothing. */
static int child_under_limit(int op, long long headroom, size_t max_free, const char *expect,
                             const void *buf, size_t size, const char *path)
{
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        if (mallinfo2().fordblks > max_free)
            _exit(4);
        long long now = address_space();
        if (now < 0)
            _exit(3);
        struct rlimit lim;
        lim.rlim_cur = lim.rlim_max = (rlim_t)(now + headroom);
        if (setrlimit(RLIMIT_AS, &lim) != 0)
            _exit(3);
        size_t before = heap_in_use();
        nf_model *out = (nf_model *)&lim;
        nf_status st = op == 0 ? nf_model_deserialize(buf, size, NULL, &out)
                               : nf_model_load(path, NULL, &out);
        if (st == NF_OK)
            _exit(1);
        int ok = st == NF_ERROR_OUT_OF_MEMORY && out == NULL && message_mentions_memory() &&
                 strstr(nf_last_error_message(), expect) != NULL &&
                 heap_in_use() <= before + 1024u;
        _exit(ok ? 0 : 2);
    }
    int status = 0;
    assert_true(waitpid(pid, &status, 0) == pid);
    assert_true(WIFEXITED(status));
    return WEXITSTATUS(status);
}
#endif

static void test_load_and_deserialize(void **state)
{
    (void)state;
#if HAVE_RLIMIT_INJECTION
    if (NFT_UNDER_SANITIZER) {
        print_message("  skipped: the sanitizers reserve more address space than any limit\n");
        skip();
    }
    /* The largest model the limits allow: ~2.6 million parameters, a 31.5 MB file and a
     * model block of ~84 MB, so that the limits below separate the allocations clearly. */
    nf_config cfg = nft_config(NF_PRESET_LARGE, NF_PRIOR_COSINE);
    nft_config_largest(&cfg);
    cfg.spline_bins = 16; /* the large preset's: the figures above are for it */
    nf_model *m = nft_model_from(&cfg);
    size_t size = 0;
    assert_int_equal(nf_model_serialize(m, NULL, 0, &size), NF_OK);
    unsigned char *buf = malloc(size);
    assert_non_null(buf);
    assert_int_equal(nf_model_serialize(m, buf, size, &size), NF_OK);
    char path[128];
    temp_path(path, sizeof path, "load");
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(buf, 1, size, f), size);
    assert_int_equal(fclose(f), 0);
    const long long mb = 1 << 20;
    /* The file is ~31.5 MB: nf_model_load's read buffer doubles from 64 KB to 32 MB. */
    assert_true((long long)size > 16 * mb && (long long)size < 32 * mb);

    /* deserialize: the buffer is already in memory; the model block (~84 MB) cannot fit in
     * 48 MB more, whatever the heap holds (blocks above 32 MB are always mmapped). */
    int r_deserialize = child_under_limit(0, 48 * mb, SIZE_MAX, "for a model", buf, size, path);
    /* load, 16 MB: the read buffer cannot grow to 32 MB (unless the inherited heap has that
     * much free space, checked: then the case is inconclusive and reported). */
    int r_load_read = child_under_limit(1, 16 * mb, (size_t)(8 * mb), "read buffer", NULL, 0, path);
    /* load, 64 MB: the read buffer (32 MB) fits, the model block after it does not. */
    int r_load_model = child_under_limit(1, 64 * mb, SIZE_MAX, "for a model", NULL, 0, path);
    /* Generous: everything fits, so the limit itself is not what the refusals measure. */
    int r_fits = child_under_limit(1, 1024 * mb, SIZE_MAX, "", NULL, 0, path);
    remove(path);
    free(buf);
    nf_model_destroy(m);
    if (r_deserialize == 3 || r_fits == 3) {
        print_message("  skipped: could not set an address-space limit here\n");
        skip();
    }
    assert_int_equal(r_deserialize, 0);
    if (r_load_read == 4)
        print_message("  the read-buffer case was inconclusive (free heap); not checked\n");
    else
        assert_int_equal(r_load_read, 0);
    assert_int_equal(r_load_model, 0);
    assert_int_equal(r_fits, 1);
#else
    print_message("  skipped: needs Linux and glibc\n");
    skip();
#endif
}

/* ---- the shading-point API ----------------------------------------------------------------- */

/* point.h: "Nothing here allocates." The library allocates only through the model's
 * allocator (model.h), so that is what can be watched: armed to fail its next call, it must
 * receive none during any number of point calls, on a cached and an uncached (8 x 64 >
 * NF_SHADING_POINT_CACHE_FLOATS) model with a custom prior, per-point callbacks included. */
static void test_shading_points_never_allocate(void **state)
{
    (void)state;
    enum { P = 8, D = 20 };
    for (int big = 0; big < 2; ++big) {
        failing f;
        memset(&f, 0, sizeof f);
        nf_config cfg = failing_config(&f, NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
        if (big) {
            cfg.coupling_layers = 8;
            cfg.hidden_width = 64;
        }
        nf_model *m = nft_model_from(&cfg);
        assert_true(f.calls > 0); /* the allocator is the one the library uses */
        train(m, 2, 5u);
        const unsigned long calls = f.calls;
        const long live = f.live;
        fail_in(&f, 0);

        nf_context ctx[P];
        nf_shading_point pts[P];
        float u[2 * D], din[3 * D], dir[3 * D], pdf[D];
        nft_rng r;
        nft_rng_seed(&r, 6u, 1u);
        for (int i = 0; i < P; ++i)
            nft_random_context(&r, &ctx[i]);
        nft_random_u_dir(&r, D, u, din);
        const nf_prior_callbacks own = nft_phong_callbacks();
        for (int round = 0; round < 2; ++round) {
            for (int i = 0; i < P; ++i) {
                assert_int_equal(nf_point_prepare(m, &ctx[i], i % 2 ? &own : NULL, &pts[i]),
                                 NF_OK);
                assert_int_equal(nf_point_sample(m, &pts[i], D, u, dir, pdf), NF_OK);
                assert_int_equal(nf_point_sample(m, &pts[i], 1, u, dir, NULL), NF_OK);
                assert_int_equal(nf_point_pdf(m, &pts[i], D, din, pdf), NF_OK);
            }
            assert_int_equal(nf_point_sample_batch(m, P, pts, u, dir, pdf), NF_OK);
            assert_int_equal(nf_point_pdf_batch(m, P, pts, din, pdf), NF_OK);
            /* Refused calls. */
            nf_context bad = ctx[0];
            bad.normal[1] = NAN;
            assert_int_equal(nf_point_prepare(m, &bad, NULL, &pts[0]),
                             NF_ERROR_INVALID_ARGUMENT);
            nf_shading_point junk;
            memset(&junk, 0, sizeof junk);
            assert_int_equal(nf_point_sample(m, &junk, D, u, dir, pdf),
                             NF_ERROR_INVALID_ARGUMENT);
            assert_int_equal(nf_point_pdf_batch(m, 1, &junk, din, pdf), NF_ERROR_INVALID_ARGUMENT);
            /* Stale points (the training step itself does not allocate either: train.h). */
            if (round == 0) {
                f.fail_at = 0;
                train(m, 1, 7u);
                fail_in(&f, 0);
                assert_int_equal(nf_point_pdf(m, &pts[1], D, din, pdf), NF_ERROR_STALE);
                assert_int_equal(nf_point_sample_batch(m, P, pts, u, dir, pdf), NF_ERROR_STALE);
            }
        }
        /* Not one call reached the allocator, and nothing was freed. */
        assert_int_equal(f.calls, calls);
        assert_int_equal(f.failed, 0);
        assert_int_equal(f.live, live);
        never_fail(&f);
        nf_model_destroy(m);
        assert_int_equal(f.live, 0);
        assert_int_equal(f.bad_free, 0);
    }
}

/* nf_vertex_create fails cleanly at each of its allocations (its table cache, itself), and
 * once made the object's sets, draws, densities and builds allocate nothing. */
static void test_vertex(void **state)
{
    (void)state;
    failing f;
    memset(&f, 0, sizeof f);
    nf_vertex_config vc;
    nf_vertex_config_init(&vc);
    vc.capacity = 64;
    vc.allocator.alloc = failing_alloc;
    vc.allocator.free = failing_free;
    vc.allocator.user = &f;
    nf_vertex *v = NULL;
    unsigned long k = 0;
    for (;; ++k) {
        fail_in(&f, k);
        v = (nf_vertex *)&f;
        nf_status st = nf_vertex_create(&vc, &v);
        if (st == NF_OK)
            break;
        assert_int_equal(st, NF_ERROR_OUT_OF_MEMORY);
        assert_null(v);
        assert_true(message_mentions_memory());
        assert_non_null(strstr(nf_last_error_message(), "nf_vertex_create"));
        assert_int_equal(f.live, 0);
    }
    assert_true(k >= 2); /* the cache and the object: both failures were seen */
    nf_model *m = nft_random_model();
    const unsigned long calls = f.calls, failed = f.failed;
    assert_int_equal(failed, k); /* one failure per attempt before the one that succeeded */
    fail_in(&f, 0);
    nf_context ctx = nft_context(0.30f, 0.60f, 0.26f, 0.0f, 0.0f, 1.0f, 0.3f, 0.2f, 0.9f);
    const float u[2] = {0.4f, 0.6f}, light[3] = {0.1f, 0.2f, 0.9f};
    float d[3], p, pl;
    for (int round = 0; round < 2; ++round) { /* a point and a build, then the table */
        assert_int_equal(nf_vertex_set(v, m, &ctx, NULL, NF_VERTEX_TABLE), NF_OK);
        assert_int_equal(nf_vertex_sample(v, u, d, &p, 1, light, &pl), NF_OK);
        assert_int_equal(nf_vertex_pdf(v, 1, light, &pl), NF_OK);
        assert_int_equal(nf_vertex_build(v), NF_OK);
    }
    nf_vertex_stats vs;
    assert_int_equal(nf_vertex_get_stats(v, &vs), NF_OK);
    assert_true(vs.points == 1 && vs.tables == 1 && vs.builds == 1);
    assert_int_equal(f.calls, calls);
    assert_int_equal(f.failed, failed);
    never_fail(&f);
    nf_vertex_destroy(v);
    nf_model_destroy(m);
    assert_int_equal(f.live, 0);
    assert_int_equal(f.bad_free, 0);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_create),
    cmocka_unit_test(test_clone),
    cmocka_unit_test(test_save),
    cmocka_unit_test(test_scenario),
    cmocka_unit_test(test_load_and_deserialize),
    cmocka_unit_test(test_shading_points_never_allocate),
    cmocka_unit_test(test_vertex),
)
