/*
 * bench_rest — durable submits per second through the broker's REST API.
 *
 * C client threads, each on its own keep-alive connection, POST jobs to a
 * real server on a loopback port over a real SQLite store; every submit is
 * committed before it is answered. Measured in the same run, each on a
 * fresh store:
 *   1. one thread straight into the store: one transaction and one fsync
 *      per job (what the disk gives a lone caller);
 *   2. REST with one commit per submit (the store's max_batch = 1): the
 *      path without group commit;
 *   3. REST with group commit (the broker's configuration): the figure;
 *   4. REST with group commit and no fsync per commit (process-safe
 *      durability), which shows what the fsyncs cost against the CPU.
 * For each REST run: submits/s, commits and jobs per commit, and CPU per
 * submit — the whole process (clients + server + store, user + system)
 * and the client threads alone, so the server's share is their
 * difference. The machine's load average is printed before and after.
 * Checks that each store holds exactly the jobs that were acknowledged.
 *
 * Under callgrind (tests/broker/bench_rest_callgrind.sh) only run 3 is
 * instrumented, which gives instructions per submit.
 *
 *   bench_rest [--smoke] [--clients C] [--jobs N] [--dir DIR] [--files]
 *
 * --files uploads the scene's mesh as a base64 file with each job instead
 * of generating it. DIR (default /tmp) should be on the disk whose fsync
 * rate is measured.
 */
#include <cJSON.h>
#include <curl/curl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#if defined(__has_include)
#if __has_include(<valgrind/callgrind.h>)
#include <valgrind/callgrind.h>
#endif
#endif
#ifndef CALLGRIND_START_INSTRUMENTATION
#define CALLGRIND_START_INSTRUMENTATION
#define CALLGRIND_STOP_INSTRUMENTATION
#endif

#include "bgb_base64.h"
#include "bgb_rest.h"
#include "bgb_store.h"
#include "bgb_tokens.h"

#define HANDLES "\"material\":{\"mu\":1,\"lambda\":1},\"handles\":[{\"select\":{\"box\":"      \
                "{\"min\":[0,0,0],\"max\":[0,1,1]}}},{\"select\":{\"box\":{\"min\":[2,0,0],"   \
                "\"max\":[2,1,1]}},\"transform\":{\"translate\":[0.2,0,0]}}]"
#define SCENE "{\"mesh\":{\"generate\":\"box\",\"cells\":[2,1,1],\"size\":[2,1,1]}," HANDLES "}"
/* Two positive tets uploaded as a .mesh file, held by vertices. */
#define FILE_SCENE "{\"mesh\":\"two.mesh\",\"material\":{\"mu\":1,\"lambda\":1}," \
                   "\"handles\":[{\"select\":{\"vertices\":[0,1,2]}},{\"select\":"      \
                   "{\"vertices\":[4]},\"transform\":{\"translate\":[0.1,0,0]}}]}"
static const char TWO_TETS[] = "MeshVersionFormatted 1\nDimension 3\nVertices\n5\n0 0 0 0\n"
                               "1 0 0 0\n0 1 0 0\n0 0 1 0\n1 1 1 0\nTetrahedra\n2\n"
                               "1 2 3 4 0\n2 3 4 5 0\nEnd\n";

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* The process's CPU seconds, user + system, and the system part in *sys. */
static double process_cpu(double *sys)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    *sys = (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
    return (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec + *sys;
}

static double thread_cpu(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

typedef struct client {
    const char *url, *body, *auth;
    int jobs;
    int accepted;
    int failed;
    double cpu; /* this thread's CPU seconds */
} client_t;

static size_t discard(char *data, size_t size, size_t n, void *ctx)
{
    (void)data;
    (void)ctx;
    return size * n;
}

static void *run_client(void *arg)
{
    client_t *c = arg;
    const double cpu0 = thread_cpu();
    CURL *curl = curl_easy_init();
    if (!curl) {
        c->failed = c->jobs;
        return NULL;
    }
    struct curl_slist *headers = curl_slist_append(NULL, "Content-Type: application/json");
    headers = curl_slist_append(headers, c->auth);
    curl_easy_setopt(curl, CURLOPT_URL, c->url);
    curl_easy_setopt(curl, CURLOPT_HTTPHEADER, headers);
    curl_easy_setopt(curl, CURLOPT_POSTFIELDS, c->body);
    curl_easy_setopt(curl, CURLOPT_WRITEFUNCTION, discard);
    curl_easy_setopt(curl, CURLOPT_TIMEOUT, 30L);
    /* No SIGPIPE handler swapped around every request (9 sigaction calls
     * per submit): libcurl sends with MSG_NOSIGNAL on Linux anyway. */
    curl_easy_setopt(curl, CURLOPT_NOSIGNAL, 1L);
    for (int i = 0; i < c->jobs; i++) {
        long status = 0;
        if (curl_easy_perform(curl) == CURLE_OK &&
            curl_easy_getinfo(curl, CURLINFO_RESPONSE_CODE, &status) == CURLE_OK &&
            status == 202)
            c->accepted++;
        else
            c->failed++;
    }
    curl_slist_free_all(headers);
    curl_easy_cleanup(curl);
    c->cpu = thread_cpu() - cpu0;
    return NULL;
}

typedef struct run {
    const char *label;
    bgb_store_options_t options;
    int instrument; /* the run callgrind measures */
    /* results */
    int accepted, failed;
    double seconds, cpu, sys_cpu, client_cpu;
    int64_t commits, stored;
} run_t;

/* One REST run on a fresh store at path; 0 on success. */
static int rest_run(run_t *r, const char *path, const char *dir, const char *body, int clients,
                    int jobs, bg_error_t *err)
{
    bgb_store_t *store = NULL;
    bgb_rest_t *rest = NULL;
    client_t *cs = calloc((size_t)clients, sizeof *cs);
    pthread_t *threads = calloc((size_t)clients, sizeof *threads);
    int rc = 1, started = 0;
    if (!cs || !threads)
        goto out;
    if (bgb_store_open_with(path, &r->options, &store, err) != BG_OK)
        goto out;
    /* The benchmark measures submits, not the quotas: none of its jobs
     * ever runs, so in flight they would all count. */
    bgb_limits_t limits;
    bgb_limits_default(&limits);
    bgb_limits_resolve(&limits, bgb_limits_ram());
    limits.max_jobs_in_flight = 1000000;
    limits.max_stored_bytes = (int64_t)1 << 40;
    const bgb_rest_config_t config = {.work_dir = dir, .limits = &limits};
    if (bgb_rest_start(&config, store, &rest, err) != BG_OK)
        goto out;
    char url[128], token[BGB_TOKEN_SIZE], auth[BGB_TOKEN_SIZE + 32];
    snprintf(url, sizeof url, "http://127.0.0.1:%u/v1/jobs", (unsigned)bgb_rest_port(rest));
    if (bgb_tokens_create(store, "bench", 0, token, err) != BG_OK)
        goto out;
    snprintf(auth, sizeof auth, "Authorization: Bearer %s", token);
    if (r->instrument)
        CALLGRIND_START_INSTRUMENTATION;
    double sys0 = 0.0, sys1 = 0.0;
    const double t0 = now(), cpu0 = process_cpu(&sys0);
    for (; started < clients; started++) {
        cs[started].url = url;
        cs[started].auth = auth;
        cs[started].body = body;
        cs[started].jobs = jobs / clients;
        if (pthread_create(&threads[started], NULL, run_client, &cs[started]) != 0)
            break;
    }
    for (int c = 0; c < started; c++) {
        pthread_join(threads[c], NULL);
        r->accepted += cs[c].accepted;
        r->failed += cs[c].failed;
        r->client_cpu += cs[c].cpu;
    }
    r->seconds = now() - t0;
    r->cpu = process_cpu(&sys1) - cpu0;
    r->sys_cpu = sys1 - sys0;
    if (r->instrument)
        CALLGRIND_STOP_INSTRUMENTATION;
    int64_t submits = 0, counts[BGB_JOB_STATE_COUNT];
    bgb_store_commit_stats(store, &r->commits, &submits);
    if (started != clients || bgb_store_count(store, counts, err) != BG_OK)
        goto out;
    r->stored = counts[BGB_JOB_QUEUED];
    /* What was acknowledged is exactly what is stored. */
    if (r->failed != 0 || r->stored != r->accepted || submits != r->accepted) {
        fprintf(stderr, "bench_rest: %s: %d acknowledged, %d failed, %lld stored, %lld counted\n",
                r->label, r->accepted, r->failed, (long long)r->stored, (long long)submits);
        goto out;
    }
    rc = 0;
out:
    bgb_rest_stop(&rest);
    bgb_store_destroy(&store);
    free(cs);
    free(threads);
    return rc;
}

/* The machine's load average (/proc/loadavg), which the figures depend on. */
static void print_load(const char *when)
{
    char text[128] = "";
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (!fgets(text, sizeof text, f))
            text[0] = '\0';
        fclose(f);
    }
    double load[3] = {0, 0, 0};
    if (sscanf(text, "%lf %lf %lf", &load[0], &load[1], &load[2]) == 3)
        printf("  load average %s: %.2f %.2f %.2f (%ld cores)\n", when, load[0], load[1], load[2],
               sysconf(_SC_NPROCESSORS_ONLN));
}

static int remove_dir(const char *dir)
{
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    return system(cmd);
}

int main(int argc, char **argv)
{
    int smoke = 0, clients = 16, jobs = 4000, files = 0;
    const char *base = "/tmp";
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--smoke") == 0) {
            smoke = 1;
        } else if (strcmp(argv[i], "--files") == 0) {
            files = 1;
        } else if (strcmp(argv[i], "--clients") == 0 && i + 1 < argc) {
            clients = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--jobs") == 0 && i + 1 < argc) {
            jobs = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--dir") == 0 && i + 1 < argc) {
            base = argv[++i];
        } else {
            fprintf(stderr, "usage: bench_rest [--smoke] [--clients C] [--jobs N] [--dir DIR] "
                            "[--files]\n");
            return 2;
        }
    }
    if (smoke) {
        clients = 4;
        jobs = 80;
    }
    if (clients < 1 || clients > 256 || jobs < clients) {
        fprintf(stderr, "bench_rest: need 1..256 clients and at least one job per client\n");
        return 2;
    }
    jobs -= jobs % clients;
    char dir[512];
    snprintf(dir, sizeof dir, "%s/bench-rest-XXXXXX", base);
    if (!mkdtemp(dir)) {
        perror("bench_rest: mkdtemp");
        return 1;
    }
    curl_global_init(CURL_GLOBAL_DEFAULT);
    int status = 1;
    bg_error_t err = BG_ERROR_INIT;
    bgb_store_t *store = NULL;
    char path[600];
    char *body = NULL;
    if (files) {
        char *b64 = bgb_base64_encode((const uint8_t *)TWO_TETS, sizeof TWO_TETS - 1);
        const size_t n = (b64 ? strlen(b64) : 0) + sizeof FILE_SCENE + 128;
        body = b64 ? malloc(n) : NULL;
        if (body)
            snprintf(body, n,
                     "{\"scene\":" FILE_SCENE ",\"files\":[{\"name\":\"two.mesh\",\"base64\":"
                     "\"%s\"}],\"mechanism\":\"central\",\"budget\":10}",
                     b64);
        free(b64);
    } else {
        body = strdup("{\"scene\":" SCENE ",\"mechanism\":\"central\",\"budget\":10}");
    }
    if (!body)
        goto fail;
    printf("durable submits through REST (%s, %d keep-alive clients, %s)\n", dir, clients,
           files ? "mesh uploaded as a file" : "generated mesh");
    print_load("before");

    /* 1. One submit per transaction, straight into the store. */
    snprintf(path, sizeof path, "%s/alone.db", dir);
    if (bgb_store_open(path, &store, &err) != BG_OK)
        goto fail;
    const int alone_jobs = smoke ? 40 : jobs / 8;
    const bgb_submit_t job = {.scene = SCENE, .scene_size = strlen(SCENE),
                              .mechanism = "central", .budget = 10.0};
    double t0 = now();
    for (int i = 0; i < alone_jobs; i++) {
        char id[BGB_JOB_ID_SIZE];
        int created = 0;
        if (bgb_store_submit(store, &job, id, &created, &err) != BG_OK || !created)
            goto fail;
    }
    const double alone_seconds = now() - t0;
    int64_t alone_commits = 0, alone_submits = 0;
    bgb_store_commit_stats(store, &alone_commits, &alone_submits);
    bgb_store_destroy(&store);
    if (alone_commits != alone_jobs)
        goto fail;
    printf("  store alone, fsync per job     %6d jobs in %6.3f s = %6.0f /s\n",
           alone_jobs, alone_seconds, alone_jobs / alone_seconds);

    run_t runs[] = {
        {.label = "REST, one commit per submit", .options = {BGB_STORE_POWER_SAFE, 1}},
        {.label = "REST, group commit", .options = {BGB_STORE_POWER_SAFE, 0}, .instrument = 1},
        {.label = "REST, group commit, no fsync", .options = {BGB_STORE_PROCESS_SAFE, 0}},
    };
    const int nruns = (int)(sizeof runs / sizeof runs[0]);
    for (int i = 0; i < nruns; i++) {
        run_t *r = &runs[i];
        snprintf(path, sizeof path, "%s/rest-%d.db", dir, i);
        /* The one-commit-per-submit run needs fewer jobs to be measured. */
        const int n = i == 0 ? (jobs / 4 < clients ? clients : jobs / 4 - jobs / 4 % clients)
                             : jobs;
        if (rest_run(r, path, dir, body, clients, n, &err) != 0)
            goto fail;
        printf("  %-30s %6d jobs in %6.3f s = %6.0f /s, %5lld commits (%5.1f jobs per "
               "commit), CPU per submit %.0f us (%.0f%% kernel; clients %.0f us, server %.0f "
               "us)\n",
               r->label, r->accepted, r->seconds, r->accepted / r->seconds,
               (long long)r->commits, r->commits ? (double)r->accepted / (double)r->commits : 0.0,
               1e6 * r->cpu / r->accepted, 100.0 * r->sys_cpu / r->cpu,
               1e6 * r->client_cpu / r->accepted, 1e6 * (r->cpu - r->client_cpu) / r->accepted);
    }
    const double single = runs[0].accepted / runs[0].seconds;
    const double group = runs[1].accepted / runs[1].seconds;
    printf("  group commit / one commit per submit: %.2f; group commit / store alone: %.2f\n",
           group / single, group / (alone_jobs / alone_seconds));
    print_load("after");
    status = 0;
fail:
    if (status != 0 && err.message[0])
        fprintf(stderr, "bench_rest: %s\n", err.message);
    bgb_store_destroy(&store);
    free(body);
    curl_global_cleanup();
    if (remove_dir(dir) != 0)
        status = 1;
    return status;
}
