/*
 * rest_host DIR [--max-body BYTES] [--lifetime SECONDS] — the broker's REST
 * library (bgb_rest over a bgb_store in DIR/store.db) served on an
 * ephemeral 127.0.0.1 port, for the client tests until the broker daemon
 * exists. Prints "port N" once it listens, serves until SIGTERM or SIGINT
 * (or the lifetime, default 300 s, so that it can never outlive a killed
 * test), stops and exits 0.
 *
 * A stand-in coordinator works the queued jobs, so that the client's
 * result and --wait paths meet real state changes, events and files. It
 * decides by the scene's "name":
 *   "hold..."  the job stays queued (to be cancelled);
 *   "fail..."  the job fails with the reason "the test host fails jobs named fail*";
 *   otherwise  queued -> running with the events a live broker's job has: an
 *              allocation and a contract (rotation-fit from agent rotfit-1 at 2.5,
 *              spent 2.5, central), or for "free..." an allocation that bought
 *              nothing; a progress event {"fraction": 0.4, "iteration": 12} (for
 *              "dyn...", as the broker says it: {"fraction": 0.25, "unit": "step",
 *              "step": 5, "of": 20, "iteration": 5}); result
 *              files report.json ({"job", "scene", "inputs": [{"name", "size"}]})
 *              and a copy of each uploaded file named "input-<name>"; a "solved"
 *              event, then succeeded.
 * It is a test double for the coordinator, not a solver.
 */
#include <cJSON.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bgb_rest.h"
#include "bgb_store.h"
#include "bgb_tokens.h"

#define HOST_BATCH 64
#define HOST_POLL_NS 50000000L

typedef struct host {
    bgb_store_t *store;
    atomic_int stop;
} host_t;

typedef struct inputs {
    cJSON *list;
} inputs_t;

static void add_input(void *ctx, const char *name, size_t size)
{
    inputs_t *in = ctx;
    cJSON *item = cJSON_CreateObject();
    cJSON_AddStringToObject(item, "name", name);
    cJSON_AddNumberToObject(item, "size", (double)size);
    cJSON_AddItemToArray(in->list, item);
}

static void complete(host_t *h, const bgb_job_t *job, const char *name)
{
    bg_error_t err = BG_ERROR_INIT;
    const unsigned queued = 1u << BGB_JOB_QUEUED, running = 1u << BGB_JOB_RUNNING;
    const int free_job = strncmp(name, "free", 4) == 0, dynamic = strncmp(name, "dyn", 3) == 0;
    const char *allocation =
        free_job ? "{\"market\":null,\"contracts\":[],\"spent\":0,\"message\":\"no agent is "
                   "registered on the market: the job runs on the broker's configured agents, "
                   "without contracts\"}"
                 : "{\"market\":\"live\",\"mechanism\":\"central\",\"contracts\":1,"
                   "\"spent\":2.5,\"latency_seconds\":0.05}";
    const char *progress = dynamic ? "{\"method\":\"variational\",\"fraction\":0.25,\"unit\":"
                                     "\"step\",\"step\":5,\"of\":20,\"iteration\":5}"
                                   : "{\"method\":\"newton\",\"fraction\":0.4,\"iteration\":12}";
    if ((!free_job &&
         bgb_store_add_event(h->store, job->id, "contract",
                             "{\"service\":\"rotation-fit\",\"agent_id\":3,\"agent\":\"rotfit-1\","
                             "\"mechanism\":\"central\",\"quantity\":1,\"price\":2.5}",
                             &err) != BG_OK) ||
        bgb_store_add_event(h->store, job->id, "allocation", allocation, &err) != BG_OK ||
        bgb_store_transition(h->store, job->id, queued, BGB_JOB_RUNNING, NULL, &err) != BG_OK ||
        bgb_store_add_event(h->store, job->id, "progress", progress, &err) != BG_OK)
        goto out;
    cJSON *report = cJSON_CreateObject();
    inputs_t in = {cJSON_AddArrayToObject(report, "inputs")};
    cJSON_AddStringToObject(report, "job", job->id);
    cJSON_AddStringToObject(report, "scene", name);
    if (bgb_store_list_files(h->store, job->id, "input", add_input, &in, &err) != BG_OK) {
        cJSON_Delete(report);
        goto out;
    }
    const cJSON *item;
    cJSON_ArrayForEach(item, in.list)
    {
        const char *file = cJSON_GetObjectItemCaseSensitive(item, "name")->valuestring;
        uint8_t *data = NULL;
        size_t size = 0;
        char copy[BGB_STORE_MAX_FILE_NAME + 8];
        snprintf(copy, sizeof copy, "input-%s", file);
        if (strlen(copy) <= BGB_STORE_MAX_FILE_NAME &&
            bgb_store_get_file(h->store, job->id, "input", file, &data, &size, &err) == BG_OK) {
            const bgb_file_t f = {copy, data, size};
            bgb_store_put_file(h->store, job->id, "result", &f, &err);
        }
        free(data);
    }
    char *text = cJSON_PrintUnformatted(report);
    cJSON_Delete(report);
    if (!text)
        goto out;
    const bgb_file_t f = {"report.json", (const uint8_t *)text, strlen(text)};
    const bg_status st = bgb_store_put_file(h->store, job->id, "result", &f, &err);
    free(text);
    if (st == BG_OK &&
        bgb_store_add_event(h->store, job->id, "solved", "{\"converged\":true}", &err) == BG_OK)
        bgb_store_transition(h->store, job->id, running, BGB_JOB_SUCCEEDED, NULL, &err);
out:
    if (err.status != BG_OK)
        fprintf(stderr, "rest_host: job %s: %s\n", job->id, err.message);
}

static void *coordinate(void *arg)
{
    host_t *h = arg;
    bgb_job_t jobs[HOST_BATCH];
    while (!atomic_load(&h->stop)) {
        int count = 0;
        int64_t next = 0;
        bg_error_t err = BG_ERROR_INIT;
        if (bgb_store_list(h->store, BGB_JOB_QUEUED, 0, HOST_BATCH, jobs, &count, &next, &err) !=
            BG_OK)
            count = 0;
        for (int i = 0; i < count; i++) {
            cJSON *scene = cJSON_Parse(jobs[i].scene);
            const cJSON *n = cJSON_GetObjectItemCaseSensitive(scene, "name");
            const char *name = cJSON_IsString(n) ? n->valuestring : "";
            if (strncmp(name, "fail", 4) == 0)
                bgb_store_transition(h->store, jobs[i].id, 1u << BGB_JOB_QUEUED, BGB_JOB_FAILED,
                                     "the test host fails jobs named fail*", &err);
            else if (strncmp(name, "hold", 4) != 0)
                complete(h, &jobs[i], name);
            cJSON_Delete(scene);
            bgb_job_release(&jobs[i]);
        }
        const struct timespec pause = {0, HOST_POLL_NS};
        nanosleep(&pause, NULL);
    }
    return NULL;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: rest_host DIR [--max-body BYTES] [--lifetime SECONDS]\n");
        return 2;
    }
    bgb_limits_t limits;
    bgb_limits_default(&limits);
    bgb_limits_resolve(&limits, bgb_limits_ram());
    bgb_rest_config_t config = {.work_dir = argv[1], .name = "rest-host", .limits = &limits};
    unsigned lifetime = 300;
    for (int i = 2; i + 1 < argc; i += 2) {
        if (strcmp(argv[i], "--max-body") == 0)
            limits.max_body = (size_t)strtoull(argv[i + 1], NULL, 10);
        else if (strcmp(argv[i], "--lifetime") == 0)
            lifetime = (unsigned)strtoul(argv[i + 1], NULL, 10);
    }
    /* Block the stop signals before any thread starts, so that only sigwait takes them. */
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGTERM);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGALRM);
    pthread_sigmask(SIG_BLOCK, &stop, NULL);
    char path[4096];
    snprintf(path, sizeof path, "%s/store.db", argv[1]);
    host_t h = {0};
    bgb_rest_t *rest = NULL;
    bg_error_t err = BG_ERROR_INIT;
    pthread_t thread;
    int started = 0, rc = 1;
    if (bgb_store_open(path, &h.store, &err) != BG_OK ||
        bgb_rest_start(&config, h.store, &rest, &err) != BG_OK) {
        fprintf(stderr, "rest_host: %s\n", err.message);
        goto out;
    }
    if (pthread_create(&thread, NULL, coordinate, &h) != 0) {
        fprintf(stderr, "rest_host: cannot start the coordinator thread\n");
        goto out;
    }
    started = 1;
    alarm(lifetime);
    char token[BGB_TOKEN_SIZE];
    if (bgb_tokens_create(h.store, "tests", 1, token, &err) != BG_OK) {
        fprintf(stderr, "rest_host: %s\n", err.message);
        goto out;
    }
    printf("token %s\nport %u\n", token, (unsigned)bgb_rest_port(rest));
    fflush(stdout);
    int sig = 0;
    sigwait(&stop, &sig);
    rc = 0;
out:
    if (started) {
        atomic_store(&h.stop, 1);
        pthread_join(thread, NULL);
    }
    bgb_rest_stop(&rest);
    bgb_store_destroy(&h.store);
    return rc;
}
