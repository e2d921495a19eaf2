/*
 * bench_rest — durable submits per second through the broker's REST API.
 *
 * Baseline, measured in the same run: one thread submitting straight to
 * the store, so every job is its own transaction and its own fsync. Then
 * C client threads, each on a keep-alive connection, POST jobs to a real
 * server on a loopback port; the store group-commits whatever is waiting.
 * Every submit is durable before it is answered in both cases. Prints the
 * rates, their ratio, commits and jobs per commit (what group commit buys),
 * and checks that the store holds exactly the jobs that were acknowledged.
 *
 *   bench_rest [--smoke] [--clients C] [--jobs N] [--dir DIR]
 *
 * DIR (default /tmp) should be on the disk whose fsync rate is measured.
 */
#include <cJSON.h>
#include <curl/curl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bgb_rest.h"
#include "bgb_store.h"

#define SCENE "{\"mesh\":{\"generate\":\"box\",\"cells\":[2,1,1],\"size\":[2,1,1]},"           \
              "\"material\":{\"mu\":1,\"lambda\":1},\"handles\":[{\"select\":{\"box\":"         \
              "{\"min\":[0,0,0],\"max\":[0,1,1]}}},{\"select\":{\"box\":{\"min\":[2,0,0],"      \
              "\"max\":[2,1,1]}},\"transform\":{\"translate\":[0.2,0,0]}}]}"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

typedef struct client {
    const char *url;
    int jobs;
    int accepted;
    int failed;
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
    CURL *curl = curl_easy_init();
    if (!curl) {
        c->failed = c->jobs;
        return NULL;
    }
    const char *body = "{\"scene\":" SCENE ",\"mechanism\":\"central\",\"budget\":10}";
    struct curl_slist *headers = curl_slist_append(NULL, "Content-Type: application/json");
    curl_easy_setopt(curl, CURLOPT_URL, c->url);
    curl_easy_setopt(curl, CURLOPT_HTTPHEADER, headers);
    curl_easy_setopt(curl, CURLOPT_POSTFIELDS, body);
    curl_easy_setopt(curl, CURLOPT_WRITEFUNCTION, discard);
    curl_easy_setopt(curl, CURLOPT_TIMEOUT, 30L);
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
    return NULL;
}

static int remove_dir(const char *dir)
{
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    return system(cmd);
}

int main(int argc, char **argv)
{
    int smoke = 0, clients = 16, jobs = 4000;
    const char *base = "/tmp";
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--smoke") == 0) {
            smoke = 1;
        } else if (strcmp(argv[i], "--clients") == 0 && i + 1 < argc) {
            clients = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--jobs") == 0 && i + 1 < argc) {
            jobs = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--dir") == 0 && i + 1 < argc) {
            base = argv[++i];
        } else {
            fprintf(stderr, "usage: bench_rest [--smoke] [--clients C] [--jobs N] [--dir DIR]\n");
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
    bgb_rest_t *rest = NULL;
    char path[600];

    /* Baseline: one submit per transaction, straight into the store. */
    snprintf(path, sizeof path, "%s/baseline.db", dir);
    if (bgb_store_open(path, &store, &err) != BG_OK)
        goto fail;
    const int baseline_jobs = smoke ? 40 : jobs / 8;
    const bgb_submit_t job = {.scene = SCENE, .scene_size = strlen(SCENE),
                              .mechanism = "central", .budget = 10.0};
    double t0 = now();
    for (int i = 0; i < baseline_jobs; i++) {
        char id[BGB_JOB_ID_SIZE];
        int created = 0;
        if (bgb_store_submit(store, &job, id, &created, &err) != BG_OK || !created)
            goto fail;
    }
    const double baseline_seconds = now() - t0;
    int64_t commits = 0, submits = 0;
    bgb_store_commit_stats(store, &commits, &submits);
    bgb_store_destroy(&store);
    const double baseline_rate = baseline_jobs / baseline_seconds;

    /* Through REST, many clients, group commit. */
    snprintf(path, sizeof path, "%s/rest.db", dir);
    if (bgb_store_open(path, &store, &err) != BG_OK)
        goto fail;
    const bgb_rest_config_t config = {.work_dir = dir, .connection_limit = 512};
    if (bgb_rest_start(&config, store, &rest, &err) != BG_OK)
        goto fail;
    char url[128];
    snprintf(url, sizeof url, "http://127.0.0.1:%u/v1/jobs", (unsigned)bgb_rest_port(rest));
    client_t *cs = calloc((size_t)clients, sizeof *cs);
    pthread_t *threads = calloc((size_t)clients, sizeof *threads);
    if (!cs || !threads) {
        free(cs);
        free(threads);
        goto fail;
    }
    t0 = now();
    for (int c = 0; c < clients; c++) {
        cs[c].url = url;
        cs[c].jobs = jobs / clients;
        pthread_create(&threads[c], NULL, run_client, &cs[c]);
    }
    int accepted = 0, failed = 0;
    for (int c = 0; c < clients; c++) {
        pthread_join(threads[c], NULL);
        accepted += cs[c].accepted;
        failed += cs[c].failed;
    }
    const double rest_seconds = now() - t0;
    free(cs);
    free(threads);
    int64_t rest_commits = 0, rest_submits = 0, counts[BGB_JOB_STATE_COUNT];
    bgb_store_commit_stats(store, &rest_commits, &rest_submits);
    if (bgb_store_count(store, counts, &err) != BG_OK)
        goto fail;
    const double rest_rate = accepted / rest_seconds;
    printf("durable submits (synchronous=FULL, %s)\n", dir);
    printf("  store alone, 1 thread:        %6d jobs in %7.3f s = %8.0f /s, %lld commits\n",
           baseline_jobs, baseline_seconds, baseline_rate, (long long)commits);
    printf("  REST, %3d keep-alive clients: %6d jobs in %7.3f s = %8.0f /s, %lld commits "
           "(%.1f jobs per commit)\n",
           clients, accepted, rest_seconds, rest_rate, (long long)rest_commits,
           rest_commits ? (double)rest_submits / (double)rest_commits : 0.0);
    printf("  ratio REST / store alone: %.2f; failed requests: %d\n", rest_rate / baseline_rate,
           failed);
    /* What was acknowledged is exactly what is stored. */
    if (failed != 0 || counts[BGB_JOB_QUEUED] != accepted || rest_submits != accepted ||
        commits != baseline_jobs) {
        fprintf(stderr, "bench_rest: %d acknowledged, %lld stored, %lld counted\n", accepted,
                (long long)counts[BGB_JOB_QUEUED], (long long)rest_submits);
        goto fail;
    }
    status = 0;
fail:
    if (status != 0 && err.message[0])
        fprintf(stderr, "bench_rest: %s\n", err.message);
    bgb_rest_stop(&rest);
    bgb_store_destroy(&store);
    curl_global_cleanup();
    if (remove_dir(dir) != 0)
        status = 1;
    return status;
}
