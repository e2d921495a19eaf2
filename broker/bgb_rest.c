#include "bgb_rest.h"

#include <arpa/inet.h>
#include <cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <gnutls/gnutls.h>
#include <math.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <pthread.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "bg_plan.h"
#include "bg_scene.h"
#include "bg_clock.h"
#include "bgb_base64.h"
#include "bgb_jobscene.h"
#include "bgb_submission.h"
#include "bgb_tokens.h"

/* Threads serving connections. A submit waits on its thread for the
 * store's group commit (an fsync shared by the submits waiting then), so
 * this also bounds how many submits can share one commit: with 8 threads,
 * 64 clients got 1.8-2.8 jobs per commit and 404-2,400 submits/s; with 64,
 * 8 jobs per commit and 3,600-3,900/s. Suspending the connection during the
 * commit instead would free the thread; not done yet. */
#define REST_THREADS 64
/* Memory MHD may use per connection for headers and buffers. */
#define REST_CONNECTION_MEMORY (64 * 1024)
/* GnuTLS priorities: its defaults without TLS 1.0 and 1.1. */
#define REST_TLS_PRIORITIES "NORMAL:-VERS-ALL:+VERS-TLS1.3:+VERS-TLS1.2"
#define REST_MAX_LIMIT 500
#define REST_DEFAULT_LIMIT 50
/* Server-sent events: how long a stream stays silent before sending a
 * keep-alive comment. */
#define REST_KEEPALIVE_SECONDS 15.0
/* At stop, seconds the event streams get to send their last events. */
#define REST_FINAL_WAIT 2.0
#define REST_PATH_MAX 4096

struct bgb_rest {
    struct MHD_Daemon *daemon;
    bgb_store_t *store;
    bgb_rest_config_t config;
    bgb_limits_t limits; /* in force (a copy of the config's, or the defaults) */
    char *address, *work_dir, *name, *agents_json, *market;
    char *tls_cert, *tls_key; /* the PEM texts, held while the server runs */
    int tls;
    char *(*view)(void *ctx, int what);
    void *view_ctx;
    uint16_t port;
    atomic_int stopping;
    atomic_int draining; /* the broker is stopping: no new job is accepted */
    atomic_llong responses[6]; /* by status class: index 1..5 */
    atomic_llong event_streams; /* event streams open now (for /metrics) */
    pthread_mutex_t streams_lock;
    struct stream *streams; /* every open event stream, under streams_lock */
    pthread_t notifier;
    int notifier_started;
};

/* Who a request comes from: its bearer token's user and scope. */
typedef struct principal {
    char user[BGB_USER_MAX + 1];
    int admin;
} principal_t;

/* A request's state across MHD's calls: the body as it arrives. */
typedef struct request {
    char *body;
    size_t size, cap;
    int too_large;
    double started; /* monotonic seconds of its first call: the body must
                       arrive within the request timeout */
} request_t;

/* ------------------------------------------------------------ responses */

static enum MHD_Result send_text(bgb_rest_t *rest, struct MHD_Connection *c, unsigned status,
                                 const char *type, const char *text, size_t length,
                                 const char *location)
{
    struct MHD_Response *r =
        MHD_create_response_from_buffer(length, (void *)text, MHD_RESPMEM_MUST_COPY);
    if (!r)
        return MHD_NO;
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, type);
    if (location)
        MHD_add_response_header(r, MHD_HTTP_HEADER_LOCATION, location);
    const enum MHD_Result ok = MHD_queue_response(c, status, r);
    MHD_destroy_response(r);
    if (status / 100 >= 1 && status / 100 <= 5)
        atomic_fetch_add(&rest->responses[status / 100], 1);
    return ok;
}

/* Sends and frees a JSON document. */
static enum MHD_Result send_json(bgb_rest_t *rest, struct MHD_Connection *c, unsigned status,
                                 cJSON *doc, const char *type, const char *location)
{
    char *text = doc ? cJSON_PrintUnformatted(doc) : NULL;
    cJSON_Delete(doc);
    if (!text)
        return send_text(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "text/plain",
                         "out of memory\n", 14, NULL);
    const enum MHD_Result ok = send_text(rest, c, status, type, text, strlen(text), location);
    free(text);
    return ok;
}

/*
 * An RFC 9457 problem document: type names the kind of problem
 * (/problems/<slug>), detail says what is wrong, field (when known) the
 * request field it is about.
 */
static enum MHD_Result send_problem(bgb_rest_t *rest, struct MHD_Connection *c, unsigned status,
                                    const char *slug, const char *title, const char *field,
                                    const char *fmt, ...) __attribute__((format(printf, 7, 8)));

static enum MHD_Result send_problem(bgb_rest_t *rest, struct MHD_Connection *c, unsigned status,
                                    const char *slug, const char *title, const char *field,
                                    const char *fmt, ...)
{
    char detail[BG_ERROR_MESSAGE_MAX + 128];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    char type[128];
    snprintf(type, sizeof type, "/problems/%s", slug);
    cJSON *doc = cJSON_CreateObject();
    if (doc) {
        cJSON_AddStringToObject(doc, "type", type);
        cJSON_AddStringToObject(doc, "title", title);
        cJSON_AddNumberToObject(doc, "status", status);
        cJSON_AddStringToObject(doc, "detail", detail);
        if (field)
            cJSON_AddStringToObject(doc, "field", field);
    }
    return send_json(rest, c, status, doc, "application/problem+json", NULL);
}

/* A failed store call as a problem: no such job 404, a job in the wrong
 * state 409, anything else 503 (the store is the broker's source of truth:
 * without it nothing can be answered). */
static enum MHD_Result send_store_problem(bgb_rest_t *rest, struct MHD_Connection *c,
                                          bg_status st, const bg_error_t *err)
{
    if (st == BG_ERR_NOT_FOUND)
        return send_problem(rest, c, MHD_HTTP_NOT_FOUND, "no-such-job", "No such job", NULL,
                            "%s", err->message);
    if (st == BG_ERR_CONFLICT)
        return send_problem(rest, c, MHD_HTTP_CONFLICT, "job-ended", "Job already ended", NULL,
                            "%s", err->message);
    /* The store's own message names its files: it goes to the broker's
     * log, not to the client. */
    fprintf(stderr, "broker: %s\n", err->message);
    return send_problem(rest, c, MHD_HTTP_SERVICE_UNAVAILABLE, "store-unavailable",
                        "Job store unavailable", NULL,
                        "the job store cannot answer now; try again later");
}

/* ------------------------------------------------------------- job JSON */

/* What the job resource shows from the job's events: the plan, the last
 * allocation (contracts and what the market said), the last progress
 * point, and the error-against-time trace so far (the progress points
 * until the run's full "trace" event replaces them). */
#define REST_MAX_TRACE_POINTS 10000

typedef struct plan_capture {
    cJSON *plan, *allocation, *progress, *trace;
    cJSON *contracts; /* the job's "contract" events, in order */
    int final_trace;
} plan_capture_t;

static void replace_json(cJSON **slot, const char *json)
{
    cJSON *parsed = cJSON_Parse(json);
    if (!parsed)
        return;
    cJSON_Delete(*slot);
    *slot = parsed;
}

static void capture_plan(void *ctx, int64_t sequence, double time, const char *kind,
                         const char *json)
{
    plan_capture_t *pc = ctx;
    (void)sequence;
    (void)time;
    if (strcmp(kind, "plan") == 0) {
        replace_json(&pc->plan, json);
    } else if (strcmp(kind, "allocation") == 0) {
        replace_json(&pc->allocation, json);
    } else if (strcmp(kind, "contract") == 0) {
        cJSON *contract = cJSON_Parse(json);
        if (!pc->contracts)
            pc->contracts = cJSON_CreateArray();
        if (contract && pc->contracts &&
            cJSON_GetArraySize(pc->contracts) < REST_MAX_TRACE_POINTS)
            cJSON_AddItemToArray(pc->contracts, contract);
        else
            cJSON_Delete(contract);
    } else if (strcmp(kind, "progress") == 0) {
        replace_json(&pc->progress, json);
        if (!pc->final_trace && pc->progress) {
            if (!pc->trace)
                pc->trace = cJSON_CreateArray();
            if (pc->trace && cJSON_GetArraySize(pc->trace) < REST_MAX_TRACE_POINTS)
                cJSON_AddItemToArray(pc->trace, cJSON_Duplicate(pc->progress, 1));
        }
    } else if (strcmp(kind, "trace") == 0) {
        cJSON *t = cJSON_Parse(json);
        cJSON *points = t ? cJSON_DetachItemFromObjectCaseSensitive(t, "points") : NULL;
        cJSON_Delete(t);
        if (cJSON_IsArray(points)) {
            cJSON_Delete(pc->trace);
            pc->trace = points;
            pc->final_trace = 1;
        } else {
            cJSON_Delete(points);
        }
    }
}

static void plan_capture_release(plan_capture_t *pc)
{
    cJSON_Delete(pc->plan);
    cJSON_Delete(pc->allocation);
    cJSON_Delete(pc->progress);
    cJSON_Delete(pc->trace);
    cJSON_Delete(pc->contracts);
    memset(pc, 0, sizeof *pc);
}

static void add_link(cJSON *links, const char *rel, const char *id, const char *suffix)
{
    char href[96];
    snprintf(href, sizeof href, "/v1/jobs/%s%s", id, suffix);
    cJSON_AddStringToObject(links, rel, href);
}

/* Adds what the job's events show (plan, contracts, allocation, progress,
 * trace) to the job resource o, taking them out of pc. */
static void add_event_views(cJSON *o, plan_capture_t *pc)
{
    if (pc->plan) {
        cJSON_AddItemToObject(o, "plan", pc->plan);
        pc->plan = NULL;
    }
    /* The live market records each contract as its own event; the
     * allocation event lists them only when it has them at hand. */
    cJSON *contracts = NULL;
    if (pc->contracts) {
        contracts = pc->contracts;
        pc->contracts = NULL;
    } else if (pc->allocation) {
        contracts = cJSON_GetObjectItemCaseSensitive(pc->allocation, "contracts");
        contracts = cJSON_IsArray(contracts)
                        ? cJSON_DetachItemFromObjectCaseSensitive(pc->allocation, "contracts")
                        : NULL;
    }
    cJSON_AddItemToObject(o, "contracts", contracts ? contracts : cJSON_CreateArray());
    if (pc->allocation) {
        cJSON_AddItemToObject(o, "allocation", pc->allocation);
        pc->allocation = NULL;
    } else {
        cJSON_AddNullToObject(o, "allocation");
    }
    if (pc->progress) {
        cJSON_AddItemToObject(o, "progress", pc->progress);
        pc->progress = NULL;
    } else {
        cJSON_AddNullToObject(o, "progress");
    }
    cJSON_AddItemToObject(o, "trace", pc->trace ? pc->trace : cJSON_CreateArray());
    pc->trace = NULL;
}

/* The job resource; with_plan adds the views of the job's events. */
static cJSON *job_json(bgb_rest_t *rest, const bgb_job_t *job, int with_plan)
{
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    cJSON_AddStringToObject(o, "id", job->id);
    cJSON_AddStringToObject(o, "state", bgb_job_state_name(job->state));
    cJSON_AddStringToObject(o, "mechanism", job->mechanism);
    cJSON_AddNumberToObject(o, "budget", job->budget);
    if (job->deadline > 0)
        cJSON_AddNumberToObject(o, "deadline", job->deadline);
    else
        cJSON_AddNullToObject(o, "deadline");
    cJSON_AddNumberToObject(o, "created", job->created);
    cJSON_AddNumberToObject(o, "updated", job->updated);
    if (job->reason)
        cJSON_AddStringToObject(o, "reason", job->reason);
    else
        cJSON_AddNullToObject(o, "reason");
    if (with_plan) {
        plan_capture_t pc = {NULL, NULL, NULL, NULL, NULL, 0};
        bg_error_t err = BG_ERROR_INIT;
        if (bgb_store_events(rest->store, job->id, 0, capture_plan, &pc, &err) == BG_OK)
            add_event_views(o, &pc);
        plan_capture_release(&pc);
    }
    cJSON *links = cJSON_AddObjectToObject(o, "links");
    if (links) {
        add_link(links, "self", job->id, "");
        add_link(links, "events", job->id, "/events");
        add_link(links, "cancel", job->id, "/cancel");
        add_link(links, "result", job->id, "/result");
    }
    return o;
}

/* ------------------------------------------------------------ submitting */

/* "scene: handles[0].select: ..." -> "scene.handles[0].select"; "scene" otherwise. */
static void field_of(const char *message, char *field, size_t size)
{
    snprintf(field, size, "scene");
    const char *prefix = "scene: ";
    if (strncmp(message, prefix, strlen(prefix)) != 0)
        return;
    const char *start = message + strlen(prefix);
    const char *end = strstr(start, ": ");
    if (!end || end == start)
        return;
    for (const char *c = start; c < end; c++)
        if (*c == ' ')
            return;
    snprintf(field, size, "scene.%.*s", (int)(end - start), start);
}

/*
 * The resource of a job just stored, as GET /v1/jobs/{id} shows it then
 * (queued, its plan its only event view), written directly: the job is
 * exactly what was committed, and reading it back and printing it with
 * cJSON cost as much as storing it. mechanism is one of the three names,
 * id hex, plan_text JSON (NULL: none), budget and time finite, deadline
 * 0 for none; a test checks that this text and GET's document are the
 * same JSON.
 */
static char *new_job_text(const char *id, const char *mechanism, double budget, double deadline,
                          double time, const char *plan_text)
{
    char deadline_text[40] = "null";
    if (deadline > 0)
        snprintf(deadline_text, sizeof deadline_text, "%.17g", deadline);
    const size_t n = 512 + 4 * BGB_JOB_ID_SIZE + (plan_text ? strlen(plan_text) : 0);
    char *text = malloc(n);
    if (!text)
        return NULL;
    snprintf(text, n,
             "{\"id\":\"%s\",\"state\":\"queued\",\"mechanism\":\"%s\",\"budget\":%.17g,"
             "\"deadline\":%s,\"created\":%.17g,\"updated\":%.17g,\"reason\":null%s%s,\"contracts\":[],"
             "\"allocation\":null,\"progress\":null,\"trace\":[],\"links\":{\"self\":"
             "\"/v1/jobs/%s\",\"events\":\"/v1/jobs/%s/events\",\"cancel\":"
             "\"/v1/jobs/%s/cancel\",\"result\":\"/v1/jobs/%s/result\"}}",
             id, mechanism, budget, deadline_text, time, time, plan_text ? ",\"plan\":" : "",
             plan_text ? plan_text : "", id, id, id, id);
    return text;
}

static enum MHD_Result send_problem_of(bgb_rest_t *rest, struct MHD_Connection *c,
                                       const bgb_problem_t *p)
{
    return send_problem(rest, c, p->status, p->type, p->title, p->field[0] ? p->field : NULL,
                        "%s", p->detail);
}

/*
 * POST /v1/jobs: the body parsed (bgb_submission), the user's quotas
 * checked (jobs in flight 429, stored bytes 413), the scene validated by
 * the loader the coordinator runs it with (bgb_jobscene: size and work
 * caps before any mesh is built), then stored durably.
 */
static enum MHD_Result submit_job(bgb_rest_t *rest, struct MHD_Connection *c,
                                  const request_t *req, const char *owner)
{
    bgb_submission_t s;
    bgb_problem_t problem;
    char dir[REST_PATH_MAX] = "";
    enum MHD_Result sent = MHD_NO;
    bgb_jobscene_t scene = BGB_JOBSCENE_INIT;
    char *plan_text = NULL;
    bgb_file_t files[BGB_STORE_MAX_FILES];
    const bgb_limits_t *limits = &rest->limits;
    const char *key = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Idempotency-Key");
    if (key && strlen(key) > BGB_STORE_MAX_KEY)
        return send_problem(rest, c, MHD_HTTP_BAD_REQUEST, "invalid-header", "Invalid header",
                            "Idempotency-Key", "Idempotency-Key: longer than %d bytes",
                            BGB_STORE_MAX_KEY);
    if (!bgb_submission_parse(req->body, req->size, limits->max_body, &s, &problem))
        return send_problem_of(rest, c, &problem);
    bgb_submission_files(&s, files);
    bg_error_t err = BG_ERROR_INIT;
    int in_flight = 0;
    int64_t stored = 0;
    if (bgb_store_usage(rest->store, owner, &in_flight, &stored, &err) != BG_OK) {
        sent = send_store_problem(rest, c, BG_ERR_IO, &err);
        goto out;
    }
    /* A replay of an earlier submit is answered below whatever the quotas. */
    if (!key && in_flight >= limits->max_jobs_in_flight) {
        sent = send_problem(rest, c, MHD_HTTP_TOO_MANY_REQUESTS, "too-many-jobs",
                            "Too many jobs in flight", NULL,
                            "%d of your jobs are queued or running, the limit is %d: wait for "
                            "one to end",
                            in_flight, limits->max_jobs_in_flight);
        goto out;
    }
    if (!key && stored + s.upload_bytes > limits->max_stored_bytes) {
        sent = send_problem(rest, c, MHD_HTTP_CONTENT_TOO_LARGE, "storage-quota",
                            "Storage quota exceeded", NULL,
                            "your jobs hold %lld bytes and this one brings %lld, over your quota "
                            "of %lld bytes: delete ended jobs (DELETE /v1/jobs/{id})",
                            (long long)stored, (long long)s.upload_bytes,
                            (long long)limits->max_stored_bytes);
        goto out;
    }
    /* A job without uploads needs no folder (creating and removing one per
     * submit costs more than the submit's own commit). */
    if (s.file_count > 0) {
        snprintf(dir, sizeof dir, "%s/bgb-job-XXXXXX", rest->work_dir);
        if (!mkdtemp(dir)) {
            dir[0] = '\0';
            fprintf(stderr, "broker: cannot unpack a job's files: %s\n", strerror(errno));
            sent = send_problem(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "internal",
                                "Internal error", NULL, "cannot unpack the job's files");
            goto out;
        }
        if (bgb_jobscene_unpack(dir, files, s.file_count, &err) != BG_OK) {
            fprintf(stderr, "broker: %s\n", err.message);
            sent = send_problem(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "internal",
                                "Internal error", NULL, "cannot unpack the job's files");
            goto out;
        }
    }
    if (bgb_jobscene_load(s.scene, strlen(s.scene), s.file_count ? dir : NULL, limits, &scene,
                          &err) != BG_OK) {
        char field[256];
        field_of(err.message, field, sizeof field);
        sent = send_problem(rest, c, MHD_HTTP_UNPROCESSABLE_CONTENT,
                            err.status == BG_ERR_LIMIT ? "job-too-large" : "invalid-scene",
                            err.status == BG_ERR_LIMIT ? "Job too large" : "Invalid scene", field,
                            "%s", err.message);
        goto out;
    }
    plan_text = bgb_jobscene_plan_json(&scene);
    const bgb_submit_t job = {.owner = owner,
                              .idempotency_key = key,
                              .fingerprint = s.fingerprint,
                              .scene = s.scene,
                              .scene_size = strlen(s.scene),
                              .mechanism = s.mechanism,
                              .budget = s.budget,
                              .deadline = s.deadline,
                              .files = files,
                              .file_count = s.file_count,
                              .plan = plan_text};
    char id[BGB_JOB_ID_SIZE];
    int created = 0;
    double stored_at = 0.0;
    if (bgb_store_submit_at(rest->store, &job, id, &created, &stored_at, &err) != BG_OK) {
        sent = err.status == BG_ERR_IO ? send_store_problem(rest, c, BG_ERR_IO, &err)
               : err.status == BG_ERR_CONFLICT
                   ? send_problem(rest, c, MHD_HTTP_UNPROCESSABLE_CONTENT, "idempotency-key-reused",
                                  "Idempotency-Key reused", "Idempotency-Key", "%s", err.message)
                   : send_problem(rest, c, MHD_HTTP_UNPROCESSABLE_CONTENT, "invalid-request",
                                  "Invalid request", NULL, "%s", err.message);
        goto out;
    }
    char location[64];
    snprintf(location, sizeof location, "/v1/jobs/%s", id);
    if (created && rest->config.on_queued)
        rest->config.on_queued(rest->config.queued_ctx);
    if (created) {
        char *text = new_job_text(id, s.mechanism, s.budget, s.deadline, stored_at, plan_text);
        sent = text ? send_text(rest, c, MHD_HTTP_ACCEPTED, "application/json", text,
                                strlen(text), location)
                    : send_problem(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "internal",
                                   "Internal error", NULL, "out of memory");
        free(text);
    } else {
        /* An Idempotency-Key replay: the earlier job as it is now. */
        bgb_job_t earlier = BGB_JOB_INIT;
        if (bgb_store_get(rest->store, id, &earlier, &err) != BG_OK) {
            sent = send_store_problem(rest, c, BG_ERR_IO, &err);
            goto out;
        }
        sent = send_json(rest, c, MHD_HTTP_OK, job_json(rest, &earlier, 1), "application/json",
                         location);
        bgb_job_release(&earlier);
    }
out:
    if (dir[0])
        bgb_jobscene_remove(dir, files, s.file_count);
    free(plan_text);
    bgb_jobscene_release(&scene);
    bgb_submission_release(&s);
    return sent;
}

/* -------------------------------------------------------------- reading */

static enum MHD_Result get_job(bgb_rest_t *rest, struct MHD_Connection *c, const char *id)
{
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = bgb_store_get(rest->store, id, &job, &err);
    if (st != BG_OK)
        return send_store_problem(rest, c, st, &err);
    const enum MHD_Result sent =
        send_json(rest, c, MHD_HTTP_OK, job_json(rest, &job, 1), "application/json", NULL);
    bgb_job_release(&job);
    return sent;
}

static enum MHD_Result list_jobs(bgb_rest_t *rest, struct MHD_Connection *c,
                                 const principal_t *who)
{
    const char *state_text = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "state");
    const char *limit_text = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "limit");
    const char *cursor_text = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "cursor");
    int state = -1;
    if (state_text && (state = bgb_job_state_parse(state_text)) < 0)
        return send_problem(rest, c, MHD_HTTP_BAD_REQUEST, "invalid-parameter",
                            "Invalid parameter", "state",
                            "state: '%s' is not one of queued, allocating, running, succeeded, "
                            "failed, cancelled",
                            state_text);
    long limit = REST_DEFAULT_LIMIT;
    if (limit_text) {
        char *end = NULL;
        limit = strtol(limit_text, &end, 10);
        if (!end || *end || limit < 1 || limit > REST_MAX_LIMIT)
            return send_problem(rest, c, MHD_HTTP_BAD_REQUEST, "invalid-parameter",
                                "Invalid parameter", "limit",
                                "limit: '%s' must be an integer in 1..%d", limit_text,
                                REST_MAX_LIMIT);
    }
    long long cursor = 0;
    if (cursor_text) {
        char *end = NULL;
        cursor = strtoll(cursor_text, &end, 10);
        if (!end || *end || cursor < 1)
            return send_problem(rest, c, MHD_HTTP_BAD_REQUEST, "invalid-parameter",
                                "Invalid parameter", "cursor",
                                "cursor: '%s' is not a cursor this server gave", cursor_text);
    }
    bgb_job_t *jobs = calloc((size_t)limit, sizeof *jobs);
    if (!jobs)
        return send_problem(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "internal",
                            "Internal error", NULL, "out of memory");
    int count = 0;
    int64_t next = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_store_list_owner(rest->store, who->admin ? NULL : who->user, state, cursor,
                             (int)limit, jobs, &count, &next, &err) != BG_OK) {
        free(jobs);
        return send_store_problem(rest, c, BG_ERR_IO, &err);
    }
    cJSON *doc = cJSON_CreateObject();
    cJSON *array = cJSON_AddArrayToObject(doc, "jobs");
    for (int i = 0; i < count; i++) {
        cJSON_AddItemToArray(array, job_json(rest, &jobs[i], 0));
        bgb_job_release(&jobs[i]);
    }
    free(jobs);
    if (next) {
        char text[32];
        snprintf(text, sizeof text, "%lld", (long long)next);
        cJSON_AddStringToObject(doc, "next", text);
    } else {
        cJSON_AddNullToObject(doc, "next");
    }
    return send_json(rest, c, MHD_HTTP_OK, doc, "application/json", NULL);
}

static enum MHD_Result cancel_job(bgb_rest_t *rest, struct MHD_Connection *c, const char *id)
{
    const unsigned active = (1u << BGB_JOB_QUEUED) | (1u << BGB_JOB_ALLOCATING) |
                            (1u << BGB_JOB_RUNNING);
    bg_error_t err = BG_ERROR_INIT;
    if (rest->config.on_cancel)
        rest->config.on_cancel(rest->config.queued_ctx, id);
    const bg_status st = bgb_store_transition(rest->store, id, active, BGB_JOB_CANCELLED,
                                              "cancelled by the client", &err);
    return st == BG_OK ? get_job(rest, c, id) : send_store_problem(rest, c, st, &err);
}

/* DELETE /v1/jobs/{id}: an ended job and its files go, freeing their bytes
 * from the user's quota; 204, or 409 while the job is active. */
static enum MHD_Result delete_job(bgb_rest_t *rest, struct MHD_Connection *c, const char *id)
{
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = bgb_store_delete(rest->store, id, &err);
    if (st != BG_OK)
        return st == BG_ERR_CONFLICT ? send_problem(rest, c, MHD_HTTP_CONFLICT, "job-active",
                                                    "Job still active", NULL, "%s", err.message)
                                     : send_store_problem(rest, c, st, &err);
    return send_text(rest, c, MHD_HTTP_NO_CONTENT, "text/plain", "", 0, NULL);
}

static void list_file(void *ctx, const char *name, size_t size)
{
    cJSON *array = ctx;
    cJSON *item = cJSON_CreateObject();
    cJSON_AddStringToObject(item, "name", name);
    cJSON_AddNumberToObject(item, "size", (double)size);
    cJSON_AddItemToArray(array, item);
}

static const char *content_type(const char *name)
{
    static const struct {
        const char *suffix, *type;
    } types[] = {{".json", "application/json"}, {".svg", "image/svg+xml"},
                 {".vtu", "application/xml"},   {".pvd", "application/xml"},
                 {".csv", "text/csv"},          {".obj", "text/plain"},
                 {".off", "text/plain"},        {".mesh", "text/plain"}};
    const size_t n = strlen(name);
    for (size_t i = 0; i < sizeof types / sizeof types[0]; i++) {
        const size_t k = strlen(types[i].suffix);
        if (n > k && strcmp(name + n - k, types[i].suffix) == 0)
            return types[i].type;
    }
    return "application/octet-stream";
}

static enum MHD_Result get_result(bgb_rest_t *rest, struct MHD_Connection *c, const char *id,
                                  const char *file)
{
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = bgb_store_get(rest->store, id, &job, &err);
    if (st != BG_OK)
        return send_store_problem(rest, c, st, &err);
    const bgb_job_state state = job.state;
    bgb_job_release(&job);
    if (state != BGB_JOB_SUCCEEDED)
        return send_problem(rest, c, MHD_HTTP_CONFLICT, "no-result", "No result", NULL,
                            "job %s is %s: it has no result%s", id, bgb_job_state_name(state),
                            bgb_job_state_is_active(state) ? " yet" : "");
    if (!file) {
        cJSON *doc = cJSON_CreateObject();
        cJSON_AddStringToObject(doc, "id", id);
        cJSON *files = cJSON_AddArrayToObject(doc, "files");
        if (bgb_store_list_files(rest->store, id, "result", list_file, files, &err) != BG_OK) {
            cJSON_Delete(doc);
            return send_store_problem(rest, c, BG_ERR_IO, &err);
        }
        return send_json(rest, c, MHD_HTTP_OK, doc, "application/json", NULL);
    }
    uint8_t *data = NULL;
    size_t size = 0;
    st = bgb_store_get_file(rest->store, id, "result", file, &data, &size, &err);
    if (st == BG_ERR_NOT_FOUND || st == BG_ERR_INVALID)
        return send_problem(rest, c, MHD_HTTP_NOT_FOUND, "no-such-file", "No such file", NULL,
                            "%s", err.message);
    if (st != BG_OK)
        return send_store_problem(rest, c, BG_ERR_IO, &err);
    const enum MHD_Result sent =
        send_text(rest, c, MHD_HTTP_OK, content_type(file), (const char *)data, size, NULL);
    free(data);
    return sent;
}

/* ------------------------------------------------------ server-sent events */

typedef struct stream {
    bgb_rest_t *rest;
    struct MHD_Connection *connection;
    char id[BGB_JOB_ID_SIZE];
    int64_t last;
    char *pending; /* formatted events not yet sent */
    size_t pending_size, pending_sent;
    int ended;
    int64_t seen_epoch; /* the store's event epoch when it last read the store */
    double last_sent;   /* monotonic seconds, for the keep-alive */
    int suspended;      /* under rest->streams_lock */
    int fd;             /* the client's socket, watched while suspended; -1: unknown */
    int gone;           /* the client hung up (seen by the notifier) */
    int final_sent;     /* the server stops: its last event queued */
    struct stream *next; /* rest->streams, under rest->streams_lock */
} stream_t;

typedef struct collect {
    stream_t *s;
    size_t cap;
    int failed;
} collect_t;

static void collect_event(void *ctx, int64_t sequence, double time, const char *kind,
                          const char *json)
{
    collect_t *co = ctx;
    stream_t *s = co->s;
    (void)time;
    const size_t need = strlen(kind) + strlen(json) + 64;
    if (co->failed)
        return;
    if (s->pending_size + need > co->cap) {
        size_t grown = co->cap ? co->cap : 4096;
        while (grown < s->pending_size + need)
            grown *= 2;
        char *p = realloc(s->pending, grown);
        if (!p) {
            co->failed = 1;
            return;
        }
        s->pending = p;
        co->cap = grown;
    }
    s->pending_size += (size_t)snprintf(s->pending + s->pending_size, co->cap - s->pending_size,
                                        "id: %lld\nevent: %s\ndata: %s\n\n",
                                        (long long)sequence, kind, json);
    s->last = sequence;
}

/* Refills s->pending from the store; sets ended when the job can no longer change. */
static void refill(stream_t *s)
{
    free(s->pending);
    s->pending = NULL;
    s->pending_size = s->pending_sent = 0;
    collect_t co = {s, 0, 0};
    bg_error_t err = BG_ERROR_INIT;
    bgb_job_t job = BGB_JOB_INIT;
    /* Read the state before the events: an event written after this read
     * is still delivered by the final refill that sees the job ended. */
    if (bgb_store_get(s->rest->store, s->id, &job, &err) != BG_OK) {
        s->ended = 1;
        return;
    }
    const int active = bgb_job_state_is_active(job.state);
    bgb_job_release(&job);
    if (bgb_store_events(s->rest->store, s->id, s->last, collect_event, &co, &err) != BG_OK ||
        co.failed || !active)
        s->ended = 1;
}

/*
 * MHD asks for more of the stream. With nothing to send, the connection is
 * suspended (it then holds no thread and no timer) until the notifier
 * resumes it: events were committed since the stream last read the store,
 * a keep-alive is due, or the server stops. The epoch is read before the
 * store, so an event committed meanwhile moves the epoch on and is not
 * missed.
 */
static ssize_t read_events(void *cls, uint64_t pos, char *buf, size_t max)
{
    stream_t *s = cls;
    bgb_rest_t *rest = s->rest;
    (void)pos;
    for (;;) {
        if (s->pending_sent < s->pending_size) {
            size_t n = s->pending_size - s->pending_sent;
            if (n > max)
                n = max;
            memcpy(buf, s->pending + s->pending_sent, n);
            s->pending_sent += n;
            s->last_sent = bg_clock_now();
            return (ssize_t)n;
        }
        if (s->gone)
            return MHD_CONTENT_READER_END_WITH_ERROR;
        if (s->ended)
            return MHD_CONTENT_READER_END_OF_STREAM;
        if (atomic_load(&rest->stopping)) {
            /* The server stops with the job still going: the events not
             * yet sent, then one last event that says so, then the end. */
            if (s->final_sent)
                return MHD_CONTENT_READER_END_OF_STREAM;
            s->final_sent = 1;
            refill(s);
            if (s->ended)
                continue; /* the job ended meanwhile: its own last events */
            /* No id: it is not one of the job's stored events. */
            static const char last[] =
                "event: end\ndata: {\"reason\":\"the broker is stopping; the job goes on "
                "after its restart\",\"final\":true}\n\n";
            char *p = realloc(s->pending, s->pending_size + sizeof last);
            if (!p)
                return MHD_CONTENT_READER_END_OF_STREAM;
            memcpy(p + s->pending_size, last, sizeof last - 1);
            s->pending = p;
            s->pending_size += sizeof last - 1;
            continue;
        }
        const int64_t epoch = bgb_store_wait_events(rest->store, -1, 0);
        if (epoch != s->seen_epoch) {
            s->seen_epoch = epoch;
            refill(s);
            continue;
        }
        if (bg_clock_now() - s->last_sent >= REST_KEEPALIVE_SECONDS) {
            static const char keepalive[] = ": keep-alive\n\n";
            const size_t n = sizeof keepalive - 1 < max ? sizeof keepalive - 1 : max;
            memcpy(buf, keepalive, n);
            s->last_sent = bg_clock_now();
            return (ssize_t)n;
        }
        pthread_mutex_lock(&rest->streams_lock);
        s->suspended = 1;
        MHD_suspend_connection(s->connection);
        pthread_mutex_unlock(&rest->streams_lock);
        return 0;
    }
}

/* MHD frees the response (and so the stream) once its connection is done
 * with it, however it ended. */
static void free_stream(void *cls)
{
    stream_t *s = cls;
    bgb_rest_t *rest = s->rest;
    pthread_mutex_lock(&rest->streams_lock);
    for (stream_t **p = &rest->streams; *p; p = &(*p)->next)
        if (*p == s) {
            *p = s->next;
            break;
        }
    pthread_mutex_unlock(&rest->streams_lock);
    atomic_fetch_sub(&rest->event_streams, 1);
    free(s->pending);
    free(s);
}

/* Whether the client at fd hung up: MHD does not watch a suspended
 * connection, and would only notice at the next keep-alive's write. Bytes
 * the client sent (a pipelined request) are left for MHD. */
static int client_gone(int fd)
{
    if (fd < 0)
        return 0;
    struct pollfd pfd = {.fd = fd, .events = POLLIN};
    if (poll(&pfd, 1, 0) <= 0)
        return 0;
    if (pfd.revents & (POLLERR | POLLHUP | POLLNVAL))
        return 1;
    char byte;
    const ssize_t got = recv(fd, &byte, 1, MSG_PEEK | MSG_DONTWAIT);
    return got == 0 || (got < 0 && errno != EINTR && errno != EAGAIN);
}

/*
 * The notifier: sleeps on the store's event epoch (at most a second, for
 * keep-alives, hung-up clients and stop) and resumes the suspended streams
 * that have something to send or whose client is gone. At stop it resumes
 * them all (MHD must not be stopped with a suspended connection) and
 * returns.
 */
static void *notifier_main(void *arg)
{
    bgb_rest_t *rest = arg;
    int64_t epoch = bgb_store_wait_events(rest->store, -1, 0);
    for (;;) {
        const int stopping = atomic_load(&rest->stopping);
        const double now = bg_clock_now();
        pthread_mutex_lock(&rest->streams_lock);
        for (stream_t *s = rest->streams; s; s = s->next) {
            if (s->suspended && client_gone(s->fd))
                s->gone = 1;
            if (s->suspended && (stopping || s->gone || s->seen_epoch != epoch ||
                                 now - s->last_sent >= REST_KEEPALIVE_SECONDS)) {
                s->suspended = 0;
                MHD_resume_connection(s->connection);
            }
        }
        pthread_mutex_unlock(&rest->streams_lock);
        if (stopping)
            return NULL;
        epoch = bgb_store_wait_events(rest->store, epoch, 1.0);
    }
}

static enum MHD_Result stream_events(bgb_rest_t *rest, struct MHD_Connection *c, const char *id)
{
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = bgb_store_get(rest->store, id, &job, &err);
    bgb_job_release(&job);
    if (st != BG_OK)
        return send_store_problem(rest, c, st, &err);
    stream_t *s = calloc(1, sizeof *s);
    if (!s)
        return send_problem(rest, c, MHD_HTTP_INTERNAL_SERVER_ERROR, "internal",
                            "Internal error", NULL, "out of memory");
    s->rest = rest;
    s->connection = c;
    s->seen_epoch = -1;
    const union MHD_ConnectionInfo *info =
        MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
    s->fd = info ? info->connect_fd : -1;
    s->last_sent = bg_clock_now();
    atomic_fetch_add(&rest->event_streams, 1);
    snprintf(s->id, sizeof s->id, "%s", id);
    pthread_mutex_lock(&rest->streams_lock);
    s->next = rest->streams;
    rest->streams = s;
    pthread_mutex_unlock(&rest->streams_lock);
    const char *resume = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Last-Event-ID");
    if (resume)
        s->last = strtoll(resume, NULL, 10);
    struct MHD_Response *r =
        MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 4096, read_events, s, free_stream);
    if (!r) {
        free_stream(s);
        return MHD_NO;
    }
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, "text/event-stream");
    MHD_add_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, "no-cache");
    const enum MHD_Result ok = MHD_queue_response(c, MHD_HTTP_OK, r);
    MHD_destroy_response(r);
    atomic_fetch_add(&rest->responses[2], 1);
    return ok;
}

/* ----------------------------------------------------------- the others */

static enum MHD_Result health(bgb_rest_t *rest, struct MHD_Connection *c)
{
    int64_t counts[BGB_JOB_STATE_COUNT];
    bg_error_t err = BG_ERROR_INIT;
    const int store_ok = bgb_store_count(rest->store, counts, &err) == BG_OK;
    cJSON *doc = cJSON_CreateObject();
    cJSON_AddStringToObject(doc, "status", store_ok ? "ok" : "degraded");
    cJSON_AddStringToObject(doc, "name", rest->name);
    cJSON_AddStringToObject(doc, "store", store_ok ? "ok" : err.message);
    return send_json(rest, c, store_ok ? MHD_HTTP_OK : MHD_HTTP_SERVICE_UNAVAILABLE, doc,
                     "application/json", NULL);
}

static enum MHD_Result metrics(bgb_rest_t *rest, struct MHD_Connection *c)
{
    int64_t counts[BGB_JOB_STATE_COUNT], commits = 0, submits = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_store_count(rest->store, counts, &err) != BG_OK)
        return send_store_problem(rest, c, BG_ERR_IO, &err);
    bgb_store_commit_stats(rest->store, &commits, &submits);
    char text[4096];
    size_t n = 0;
    n += (size_t)snprintf(text + n, sizeof text - n,
                          "# HELP biotgrid_jobs Jobs in the store, by state.\n"
                          "# TYPE biotgrid_jobs gauge\n");
    for (int s = 0; s < BGB_JOB_STATE_COUNT; s++)
        n += (size_t)snprintf(text + n, sizeof text - n, "biotgrid_jobs{state=\"%s\"} %lld\n",
                              bgb_job_state_name((bgb_job_state)s), (long long)counts[s]);
    n += (size_t)snprintf(text + n, sizeof text - n,
                          "# HELP biotgrid_store_commits_total Job store write transactions "
                          "committed for submits.\n"
                          "# TYPE biotgrid_store_commits_total counter\n"
                          "biotgrid_store_commits_total %lld\n"
                          "# HELP biotgrid_store_submits_total Jobs stored.\n"
                          "# TYPE biotgrid_store_submits_total counter\n"
                          "biotgrid_store_submits_total %lld\n"
                          "# HELP biotgrid_event_streams_open Job event streams open now.\n"
                          "# TYPE biotgrid_event_streams_open gauge\n"
                          "biotgrid_event_streams_open %lld\n"
                          "# HELP biotgrid_http_responses_total Responses sent, by status "
                          "class.\n"
                          "# TYPE biotgrid_http_responses_total counter\n",
                          (long long)commits, (long long)submits,
                          (long long)atomic_load(&rest->event_streams));
    for (int k = 1; k <= 5; k++)
        n += (size_t)snprintf(text + n, sizeof text - n,
                              "biotgrid_http_responses_total{class=\"%dxx\"} %lld\n", k,
                              (long long)atomic_load(&rest->responses[k]));
    return send_text(rest, c, MHD_HTTP_OK, "text/plain; version=0.0.4", text, n, NULL);
}

/* ------------------------------------------------------------- routing */

static int is_job_id(const char *s, size_t n)
{
    if (n != BGB_JOB_ID_SIZE - 1 || s[0] != 'j')
        return 0;
    for (size_t i = 1; i < n; i++)
        if (!((s[i] >= '0' && s[i] <= '9') || (s[i] >= 'a' && s[i] <= 'f')))
            return 0;
    return 1;
}

static enum MHD_Result method_not_allowed(bgb_rest_t *rest, struct MHD_Connection *c,
                                          const char *method, const char *url,
                                          const char *allowed)
{
    return send_problem(rest, c, MHD_HTTP_METHOD_NOT_ALLOWED, "method-not-allowed",
                        "Method not allowed", NULL, "%s %s: use %s", method, url, allowed);
}

/* ---------------------------------------------------------------- market */

/* A live view's text (malloc'd), or NULL: use the static one. */
static char *view_text(bgb_rest_t *rest, int what)
{
    return rest->view ? rest->view(rest->view_ctx, what) : NULL;
}

static enum MHD_Result get_agents(bgb_rest_t *rest, struct MHD_Connection *c)
{
    cJSON *o = cJSON_CreateObject();
    char *live = view_text(rest, BGB_REST_VIEW_AGENTS);
    cJSON *agents = cJSON_Parse(live ? live : rest->agents_json);
    free(live);
    cJSON_AddItemToObject(o, "agents", cJSON_IsArray(agents) ? agents : cJSON_CreateArray());
    if (agents && !cJSON_IsArray(agents))
        cJSON_Delete(agents);
    return send_json(rest, c, MHD_HTTP_OK, o, "application/json", NULL);
}

static enum MHD_Result get_market(bgb_rest_t *rest, struct MHD_Connection *c)
{
    char *live = view_text(rest, BGB_REST_VIEW_MARKET);
    cJSON *view = live ? cJSON_Parse(live) : NULL;
    free(live);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", rest->name);
    const cJSON *vm = cJSON_GetObjectItemCaseSensitive(view, "market");
    if (cJSON_IsString(vm))
        cJSON_AddStringToObject(o, "market", vm->valuestring);
    else if (rest->market)
        cJSON_AddStringToObject(o, "market", rest->market);
    else
        cJSON_AddNullToObject(o, "market");
    cJSON *mechs = cJSON_AddArrayToObject(o, "mechanisms");
    static const char *const names[] = {"central", "catallactic", "posted"};
    for (int i = 0; mechs && i < 3; i++)
        cJSON_AddItemToArray(mechs, cJSON_CreateString(names[i]));
    /* Recent prices come from the live market's view (none without one). */
    cJSON *prices = cJSON_DetachItemFromObjectCaseSensitive(view, "prices");
    cJSON_AddItemToObject(o, "prices", cJSON_IsArray(prices) ? prices : cJSON_CreateArray());
    if (prices && !cJSON_IsArray(prices))
        cJSON_Delete(prices);
    cJSON_Delete(view);
    return send_json(rest, c, MHD_HTTP_OK, o, "application/json", NULL);
}

/* The market's CSVs (the simulator's headers for contracts and agents);
 * without a market no row exists. */
static enum MHD_Result get_csv(bgb_rest_t *rest, struct MHD_Connection *c, int view)
{
    char *live = view_text(rest, view);
    if (live) {
        const enum MHD_Result r =
            send_text(rest, c, MHD_HTTP_OK, "text/csv", live, strlen(live), NULL);
        free(live);
        return r;
    }
    const char *header =
        view == BGB_REST_VIEW_CONTRACTS
            ? "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,"
              "good,quantity,price,buyer_limit,seller_limit,use,clearing,lost\n"
        : view == BGB_REST_VIEW_CLEARINGS
            ? "clearing,time,layer,good,volume,k,rule,price,low,low_order,low_owner,high,"
              "high_order,high_owner\n"
            : "scenario,replication,mechanism,agent,role,good,capacity,limit\n";
    return send_text(rest, c, MHD_HTTP_OK, "text/csv", header, strlen(header), NULL);
}

/*
 * The request's bearer token: 0 with *who filled, or 1 with a 401 sent
 * (WWW-Authenticate: Bearer) when it has none or a bad one. The problem
 * says the same whatever was wrong with a presented token.
 */
static int authenticate(bgb_rest_t *rest, struct MHD_Connection *c, principal_t *who,
                        enum MHD_Result *sent)
{
    const char *header = MHD_lookup_connection_value(c, MHD_HEADER_KIND,
                                                     MHD_HTTP_HEADER_AUTHORIZATION);
    static const char bearer[] = "Bearer ";
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = BG_ERR_NOT_FOUND;
    if (header && strncasecmp(header, bearer, sizeof bearer - 1) == 0) {
        const char *token = header + sizeof bearer - 1;
        while (*token == ' ')
            token++;
        st = bgb_tokens_check(rest->store, token, who->user, &who->admin, &err);
    }
    if (st == BG_OK)
        return 0;
    if (st == BG_ERR_IO) {
        *sent = send_store_problem(rest, c, BG_ERR_IO, &err);
        return 1;
    }
    char detail[160];
    snprintf(detail, sizeof detail, "%s",
             header ? "the bearer token is not valid"
                    : "this resource needs a bearer token (Authorization: Bearer TOKEN; "
                      "`biotgrid token create NAME` makes one)");
    cJSON *doc = cJSON_CreateObject();
    cJSON_AddStringToObject(doc, "type", "/problems/unauthorized");
    cJSON_AddStringToObject(doc, "title", "Unauthorized");
    cJSON_AddNumberToObject(doc, "status", MHD_HTTP_UNAUTHORIZED);
    cJSON_AddStringToObject(doc, "detail", detail);
    char *text = cJSON_PrintUnformatted(doc);
    cJSON_Delete(doc);
    struct MHD_Response *r = text ? MHD_create_response_from_buffer(strlen(text), text,
                                                                    MHD_RESPMEM_MUST_COPY)
                                  : NULL;
    free(text);
    if (!r) {
        *sent = MHD_NO;
        return 1;
    }
    MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, "application/problem+json");
    MHD_add_response_header(r, MHD_HTTP_HEADER_WWW_AUTHENTICATE, "Bearer realm=\"biotgrid\"");
    *sent = MHD_queue_response(c, MHD_HTTP_UNAUTHORIZED, r);
    MHD_destroy_response(r);
    atomic_fetch_add(&rest->responses[4], 1);
    return 1;
}

/* Another user's job is, to this user, no job at all (404, never 403: its
 * existence is not theirs to learn). 0 when who may see job id. */
static int not_theirs(bgb_rest_t *rest, struct MHD_Connection *c, const principal_t *who,
                      const char *id, enum MHD_Result *sent)
{
    if (who->admin)
        return 0;
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = bgb_store_get(rest->store, id, &job, &err);
    const int theirs = st == BG_OK && strcmp(job.owner, who->user) == 0;
    bgb_job_release(&job);
    if (theirs)
        return 0;
    *sent = st == BG_ERR_IO ? send_store_problem(rest, c, BG_ERR_IO, &err)
                            : send_problem(rest, c, MHD_HTTP_NOT_FOUND, "no-such-job",
                                           "No such job", NULL, "no job '%s'", id);
    return 1;
}

static enum MHD_Result admins_only(bgb_rest_t *rest, struct MHD_Connection *c, const char *url)
{
    return send_problem(rest, c, MHD_HTTP_FORBIDDEN, "forbidden", "Forbidden", NULL,
                        "%s is for tokens with the admin scope", url);
}

static enum MHD_Result route(bgb_rest_t *rest, struct MHD_Connection *c, const char *url,
                             const char *method, const request_t *req)
{
    const int get = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    const int post = strcmp(method, "POST") == 0;
    /* Open to all: the health probe and the API's description. */
    if (strcmp(url, "/healthz") == 0)
        return get ? health(rest, c) : method_not_allowed(rest, c, method, url, "GET");
    if (strcmp(url, "/openapi.json") == 0)
        return get ? send_text(rest, c, MHD_HTTP_OK, "application/json", bgb_rest_openapi(),
                               strlen(bgb_rest_openapi()), NULL)
                   : method_not_allowed(rest, c, method, url, "GET");
    principal_t who;
    enum MHD_Result sent = MHD_NO;
    if (authenticate(rest, c, &who, &sent))
        return sent;
    /* The market, the agents and the server's counters are the operator's. */
    const int market = strncmp(url, "/v1/market", 10) == 0 && (!url[10] || url[10] == '/');
    if (strcmp(url, "/metrics") == 0 || strcmp(url, "/v1/agents") == 0 || market) {
        if (!who.admin)
            return admins_only(rest, c, url);
        if (strcmp(url, "/metrics") == 0)
            return get ? metrics(rest, c) : method_not_allowed(rest, c, method, url, "GET");
        if (strcmp(url, "/v1/agents") == 0)
            return get ? get_agents(rest, c) : method_not_allowed(rest, c, method, url, "GET");
        if (strcmp(url, "/v1/market") == 0)
            return get ? get_market(rest, c) : method_not_allowed(rest, c, method, url, "GET");
        const int csv = strcmp(url, "/v1/market/contracts.csv") == 0   ? BGB_REST_VIEW_CONTRACTS
                        : strcmp(url, "/v1/market/agents.csv") == 0    ? BGB_REST_VIEW_AGENTS_CSV
                        : strcmp(url, "/v1/market/clearings.csv") == 0 ? BGB_REST_VIEW_CLEARINGS
                                                                       : -1;
        if (csv >= 0)
            return get ? get_csv(rest, c, csv) : method_not_allowed(rest, c, method, url, "GET");
    }
    if (strcmp(url, "/v1/jobs") == 0) {
        if (post && atomic_load(&rest->draining))
            return send_problem(rest, c, MHD_HTTP_SERVICE_UNAVAILABLE, "stopping",
                                "The broker is stopping", NULL,
                                "the broker is stopping and accepts no new job; submit it again "
                                "once it has restarted");
        if (post)
            return submit_job(rest, c, req, who.user);
        return get ? list_jobs(rest, c, &who)
                   : method_not_allowed(rest, c, method, url, "GET or POST");
    }
    const char *prefix = "/v1/jobs/";
    if (strncmp(url, prefix, strlen(prefix)) == 0) {
        const char *id = url + strlen(prefix);
        const size_t n = strcspn(id, "/");
        const char *rest_of = id + n;
        char job_id[BGB_JOB_ID_SIZE];
        if (is_job_id(id, n)) {
            memcpy(job_id, id, n);
            job_id[n] = '\0';
            if (not_theirs(rest, c, &who, job_id, &sent))
                return sent;
            if (!rest_of[0])
                return get                             ? get_job(rest, c, job_id)
                       : strcmp(method, "DELETE") == 0 ? delete_job(rest, c, job_id)
                                                       : method_not_allowed(rest, c, method, url,
                                                                            "GET or DELETE");
            if (strcmp(rest_of, "/cancel") == 0)
                return post ? cancel_job(rest, c, job_id)
                            : method_not_allowed(rest, c, method, url, "POST");
            if (strcmp(rest_of, "/events") == 0)
                return get ? stream_events(rest, c, job_id)
                           : method_not_allowed(rest, c, method, url, "GET");
            if (strcmp(rest_of, "/result") == 0)
                return get ? get_result(rest, c, job_id, NULL)
                           : method_not_allowed(rest, c, method, url, "GET");
            if (strncmp(rest_of, "/result/", 8) == 0 && rest_of[8])
                return get ? get_result(rest, c, job_id, rest_of + 8)
                           : method_not_allowed(rest, c, method, url, "GET");
        }
        return send_problem(rest, c, MHD_HTTP_NOT_FOUND, "no-such-job", "No such job", NULL,
                            "no job at %s", url);
    }
    return send_problem(rest, c, MHD_HTTP_NOT_FOUND, "not-found", "Not found", NULL,
                        "no resource at %s (see /openapi.json)", url);
}

/* Counts a request's Content-Length headers and remembers whether they agree. */
typedef struct lengths {
    int count, differ, chunked;
    char first[32];
} lengths_t;

static enum MHD_Result count_lengths(void *cls, enum MHD_ValueKind kind, const char *key,
                                     const char *value)
{
    (void)kind;
    lengths_t *l = cls;
    if (strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH) == 0) {
        if (l->count++ == 0)
            snprintf(l->first, sizeof l->first, "%s", value ? value : "");
        else if (strcmp(l->first, value ? value : "") != 0)
            l->differ = 1;
    } else if (strcasecmp(key, MHD_HTTP_HEADER_TRANSFER_ENCODING) == 0) {
        l->chunked = 1;
    }
    return MHD_YES;
}

/* Whether a Content-Type names JSON ("application/json", parameters allowed). */
static int is_json_type(const char *type)
{
    static const char json[] = "application/json";
    if (!type || strncasecmp(type, json, sizeof json - 1) != 0)
        return 0;
    const char c = type[sizeof json - 1];
    return c == '\0' || c == ';' || c == ' ';
}

/*
 * The first call of a request: what its headers alone decide. Conflicting
 * Content-Length headers, or one beside Transfer-Encoding (the request
 * smuggling shapes), are a 400; a body over the cap a 413 before it is
 * read; a body of another type than JSON a 415 (so that a web page's form
 * cannot submit a job). 0: go on.
 */
static int refuse_headers(bgb_rest_t *rest, struct MHD_Connection *c, const char *method,
                          request_t *req, enum MHD_Result *sent)
{
    lengths_t l = {0};
    MHD_get_connection_values(c, MHD_HEADER_KIND, count_lengths, &l);
    if (l.differ || (l.count > 0 && l.chunked)) {
        *sent = send_problem(rest, c, MHD_HTTP_BAD_REQUEST, "conflicting-length",
                             "Conflicting message length", "Content-Length",
                             l.differ ? "Content-Length is given twice with different values"
                                      : "Content-Length and Transfer-Encoding are both given");
        return 1;
    }
    if (l.count > 0 && strtoull(l.first, NULL, 10) > rest->limits.max_body) {
        req->too_large = 1;
        *sent = send_problem(rest, c, MHD_HTTP_CONTENT_TOO_LARGE, "body-too-large",
                             "Request body too large", NULL,
                             "the body of %s bytes exceeds the limit of %zu bytes", l.first,
                             rest->limits.max_body);
        return 1;
    }
    const int has_body = (l.count > 0 && strtoull(l.first, NULL, 10) > 0) || l.chunked;
    if (has_body && (strcmp(method, "POST") == 0 || strcmp(method, "PUT") == 0) &&
        !is_json_type(MHD_lookup_connection_value(c, MHD_HEADER_KIND,
                                                  MHD_HTTP_HEADER_CONTENT_TYPE))) {
        *sent = send_problem(rest, c, MHD_HTTP_UNSUPPORTED_MEDIA_TYPE, "unsupported-media-type",
                             "Unsupported media type", "Content-Type",
                             "a request body must be application/json");
        return 1;
    }
    return 0;
}

static enum MHD_Result handle(void *cls, struct MHD_Connection *c, const char *url,
                              const char *method, const char *version, const char *upload_data,
                              size_t *upload_data_size, void **con_cls)
{
    bgb_rest_t *rest = cls;
    (void)version;
    request_t *req = *con_cls;
    if (!req) {
        req = calloc(1, sizeof *req);
        if (!req)
            return MHD_NO;
        *con_cls = req;
        req->started = bg_clock_now();
        enum MHD_Result sent = MHD_NO;
        return refuse_headers(rest, c, method, req, &sent) ? sent : MHD_YES;
    }
    if (*upload_data_size > 0) {
        /* A body trickled in slower than the request timeout allows: the
         * connection is closed, whoever sends it. */
        if (bg_clock_now() - req->started > (double)rest->limits.request_timeout)
            return MHD_NO;
        if (!req->too_large) {
            if (req->size + *upload_data_size > rest->limits.max_body) {
                req->too_large = 1;
            } else {
                if (req->size + *upload_data_size + 1 > req->cap) {
                    size_t grown = req->cap ? req->cap : 65536;
                    while (grown < req->size + *upload_data_size + 1)
                        grown *= 2;
                    if (grown > rest->limits.max_body + 1)
                        grown = rest->limits.max_body + 1;
                    char *body = realloc(req->body, grown);
                    if (!body)
                        return MHD_NO;
                    req->body = body;
                    req->cap = grown;
                }
                memcpy(req->body + req->size, upload_data, *upload_data_size);
                req->size += *upload_data_size;
                req->body[req->size] = '\0';
            }
        }
        *upload_data_size = 0;
        return MHD_YES;
    }
    if (req->too_large)
        return send_problem(rest, c, MHD_HTTP_CONTENT_TOO_LARGE, "body-too-large",
                            "Request body too large", NULL,
                            "the body exceeds the limit of %zu bytes", rest->limits.max_body);
    return route(rest, c, url, method, req);
}

/* Loads the pair as the server will, so that a bad file is a message
 * saying what is wrong with it rather than a server that does not start. */
static bg_status check_tls_pair(const char *cert_pem, const char *key_pem, bg_error_t *err)
{
    if (!cert_pem || !key_pem)
        return bg_error_set(err, BG_ERR_INVALID,
                            "TLS needs both a certificate and its private key");
    gnutls_certificate_credentials_t cred = NULL;
    if (gnutls_certificate_allocate_credentials(&cred) < 0)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the TLS credentials");
    const gnutls_datum_t cert = {(unsigned char *)cert_pem, (unsigned)strlen(cert_pem)};
    const gnutls_datum_t key = {(unsigned char *)key_pem, (unsigned)strlen(key_pem)};
    const int rc = gnutls_certificate_set_x509_key_mem(cred, &cert, &key, GNUTLS_X509_FMT_PEM);
    gnutls_certificate_free_credentials(cred);
    if (rc < 0)
        return bg_error_set(err, BG_ERR_INVALID,
                            "the TLS certificate and key do not load as a PEM pair: %s",
                            gnutls_strerror(rc));
    return BG_OK;
}

static void completed(void *cls, struct MHD_Connection *c, void **con_cls,
                      enum MHD_RequestTerminationCode code)
{
    (void)cls;
    (void)c;
    (void)code;
    request_t *req = *con_cls;
    if (req) {
        free(req->body);
        free(req);
        *con_cls = NULL;
    }
}

bg_status bgb_rest_start(const bgb_rest_config_t *config, bgb_store_t *store, bgb_rest_t **out,
                         bg_error_t *err)
{
    *out = NULL;
    bgb_rest_t *rest = calloc(1, sizeof *rest);
    if (!rest)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the REST server");
    rest->store = store;
    rest->config = *config;
    if (config->limits) {
        rest->limits = *config->limits;
    } else {
        bgb_limits_default(&rest->limits);
        bgb_limits_resolve(&rest->limits, bgb_limits_ram());
    }
    rest->config.limits = &rest->limits;
    rest->config.tls_cert_pem = rest->config.tls_key_pem = NULL; /* held below */
    pthread_mutex_init(&rest->streams_lock, NULL);
    rest->address = strdup(config->address ? config->address : "127.0.0.1");
    rest->work_dir = strdup(config->work_dir ? config->work_dir : "/tmp");
    rest->name = strdup(config->name ? config->name : "biotgrid");
    rest->agents_json = strdup(config->agents_json ? config->agents_json : "[]");
    rest->market = config->market ? strdup(config->market) : NULL;
    rest->view = config->view;
    rest->view_ctx = config->view_ctx;
    bg_status st = BG_OK;
    if (!rest->address || !rest->work_dir || !rest->name || !rest->agents_json ||
        (config->market && !rest->market)) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the REST server");
        goto out;
    }
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_port = htons(config->port);
    if (inet_pton(AF_INET, rest->address, &addr.sin_addr) != 1) {
        st = bg_error_set(err, BG_ERR_INVALID, "listen address '%s' is not an IPv4 address",
                          rest->address);
        goto out;
    }
    /* Each connection is a descriptor: make room for the limit. */
    struct rlimit files;
    const rlim_t want = (rlim_t)rest->limits.max_connections + 256;
    if (getrlimit(RLIMIT_NOFILE, &files) == 0 && files.rlim_cur < want) {
        files.rlim_cur = files.rlim_max < want ? files.rlim_max : want;
        setrlimit(RLIMIT_NOFILE, &files);
    }
    /* A pool of threads on epoll: a connection holds memory, never a
     * thread, so clients that send half a request or nothing at all cannot
     * take the server away from the others; event streams suspend while
     * they have nothing to send. */
    unsigned flags = MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_EPOLL | MHD_ALLOW_SUSPEND_RESUME;
    struct MHD_OptionItem options[16];
    int n = 0;
#define REST_OPTION(o, v, p) (options[n++] = (struct MHD_OptionItem){(o), (intptr_t)(v), (p)})
    REST_OPTION(MHD_OPTION_SOCK_ADDR, 0, &addr);
    REST_OPTION(MHD_OPTION_NOTIFY_COMPLETED, (intptr_t)completed, rest);
    REST_OPTION(MHD_OPTION_THREAD_POOL_SIZE, REST_THREADS, NULL);
    REST_OPTION(MHD_OPTION_CONNECTION_LIMIT, rest->limits.max_connections, NULL);
    REST_OPTION(MHD_OPTION_PER_IP_CONNECTION_LIMIT, rest->limits.max_connections_per_client, NULL);
    REST_OPTION(MHD_OPTION_CONNECTION_TIMEOUT, rest->limits.idle_timeout, NULL);
    REST_OPTION(MHD_OPTION_CONNECTION_MEMORY_LIMIT, REST_CONNECTION_MEMORY, NULL);
    if (config->tls_cert_pem || config->tls_key_pem) {
        if ((st = check_tls_pair(config->tls_cert_pem, config->tls_key_pem, err)) != BG_OK)
            goto out;
        rest->tls_cert = strdup(config->tls_cert_pem);
        rest->tls_key = strdup(config->tls_key_pem);
        if (!rest->tls_cert || !rest->tls_key) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the TLS credentials");
            goto out;
        }
        flags |= MHD_USE_TLS;
        REST_OPTION(MHD_OPTION_HTTPS_MEM_CERT, 0, rest->tls_cert);
        REST_OPTION(MHD_OPTION_HTTPS_MEM_KEY, 0, rest->tls_key);
        REST_OPTION(MHD_OPTION_HTTPS_PRIORITIES, 0, (void *)REST_TLS_PRIORITIES);
        rest->tls = 1;
    }
    REST_OPTION(MHD_OPTION_END, 0, NULL);
#undef REST_OPTION
    /* MHD_OPTION_NOTIFY_COMPLETED takes the function in value and its
     * closure in ptr_value through MHD_OPTION_ARRAY. */
    rest->daemon = MHD_start_daemon(flags, config->port, NULL, NULL, handle, rest,
                                    MHD_OPTION_ARRAY, options, MHD_OPTION_END);
    if (!rest->daemon) {
        st = bg_error_set(err, BG_ERR_IO, "cannot listen on %s:%u: %s", rest->address,
                          (unsigned)config->port, strerror(errno));
        goto out;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(rest->daemon,
                                                           MHD_DAEMON_INFO_BIND_PORT);
    rest->port = info ? info->port : config->port;
    if (pthread_create(&rest->notifier, NULL, notifier_main, rest) != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot start the event streams' notifier");
        goto out;
    }
    rest->notifier_started = 1;
out:
    if (st != BG_OK)
        bgb_rest_stop(&rest);
    *out = rest;
    return st;
}

uint16_t bgb_rest_port(const bgb_rest_t *rest)
{
    return rest->port;
}

int bgb_rest_tls(const bgb_rest_t *rest)
{
    return rest->tls;
}

int bgb_rest_address_is_loopback(const char *address)
{
    struct in_addr a;
    if (!address || inet_pton(AF_INET, address, &a) != 1)
        return 0;
    return (ntohl(a.s_addr) >> 24) == 127;
}

void bgb_rest_drain(bgb_rest_t *rest)
{
    if (rest)
        atomic_store(&rest->draining, 1);
}

void bgb_rest_stop(bgb_rest_t **restp)
{
    if (!restp || !*restp)
        return;
    bgb_rest_t *rest = *restp;
    atomic_store(&rest->draining, 1);
    atomic_store(&rest->stopping, 1);
    /* The notifier resumes every suspended stream before it returns: MHD
     * may not be stopped with a connection suspended. */
    if (rest->notifier_started)
        pthread_join(rest->notifier, NULL);
    /* Each stream sends what it has left and its last event, then ends
     * (a client that reads nothing holds it up to REST_FINAL_WAIT s). */
    const double until = bg_clock_now() + REST_FINAL_WAIT;
    while (atomic_load(&rest->event_streams) > 0 && bg_clock_now() < until) {
        struct timespec pause = {0, 20 * 1000 * 1000};
        nanosleep(&pause, NULL);
    }
    if (rest->daemon)
        MHD_stop_daemon(rest->daemon);
    pthread_mutex_destroy(&rest->streams_lock);
    free(rest->address);
    free(rest->work_dir);
    free(rest->name);
    free(rest->agents_json);
    free(rest->market);
    free(rest->tls_cert);
    if (rest->tls_key) {
        gnutls_memset(rest->tls_key, 0, strlen(rest->tls_key)); /* not optimised away */
        free(rest->tls_key);
    }
    free(rest);
    *restp = NULL;
}

/* ------------------------------------------------------- the document */

/* broker/openapi.json, embedded at build time (cmake/embed.cmake). */
extern const char bgb_openapi_json[];

const char *bgb_rest_openapi(void)
{
    return bgb_openapi_json;
}
