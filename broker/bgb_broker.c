#include "bgb_broker.h"

#include <cjson/cJSON.h>
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bg_json.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "bg_svg.h"
#include "bg_surface_arap.h"
#include "bga_backend.h"
#include "bga_service.h"
#include "bga_wire.h"
#include "bga_market.h"
#include "bga_transport.h"
#include "bgb_market.h"
#include "bgb_rest.h"
#include "bgb_run.h"
#include "bgb_store.h"

#define BROKER_CONFIG_MAX_BYTES (1 << 20)
#define BROKER_PATH_MAX 4096
#define BROKER_MAX_JOBS 64
/* The dispatcher looks for queued jobs this often. */
#define BROKER_POLL_MS 100
/* At most one progress event per job this often (each is a commit). */
#define BROKER_PROGRESS_SECONDS 0.25
/* A running job's backend reads its state from the store at most this
 * often (a cancel lands there from a REST thread). */
#define BROKER_CANCEL_POLL_SECONDS 0.1
/* Service-time records of a job's money curve (one per progress call). */
#define BROKER_MAX_USAGE_POINTS (1 << 20)
#define BROKER_AGENT_LEASE_MS 600000
/* Seconds a job keeps asking the market again while it answers "no
 * seller" or "timeout" (buy_failure_transient). */
#define BROKER_BUY_PATIENCE 120.0
#define BROKER_MAX_RESULT_FILE ((size_t)1 << 30)
/* The loop thread looks at the buy queue at least this often. */
#define BROKER_LOOP_MS 10
/* Rotation-fit is split over at most this many agents. */
#define BROKER_MAX_ROTFIT 4
#define BROKER_MAX_AWARDS (BROKER_MAX_ROTFIT + 2)

/*
 * One job's purchase, handed from its coordinator to the loop thread
 * through broker.reqs (under broker.lock). The coordinator fills the
 * request and links it; the loop calls bgb_market_buy, the done callback
 * fills the outcome and signals `changed`. When the job ends the
 * coordinator sets `release`; the loop then releases the contracts,
 * unlinks and frees the request. Once the loop has exited (loop_gone) the
 * coordinator unlinks and frees it itself.
 */
typedef struct buy_req {
    struct buy_req *next;
    uint64_t job;               /* market job id: a multiple of BGA_MARKET_JOB_SPAN */
    char id[BGB_JOB_ID_SIZE];   /* the store's job id */
    bgb_mechanism mechanism;
    double budget;
    int integ;                  /* the plan lists integration-step */
    int submitted, done, release;
    char reason[64];            /* failure reason; "" on success */
    bgb_award_t awards[BROKER_MAX_AWARDS];
    int nawards;
    double spent, latency;
} buy_req_t;

struct bgb_broker {
    bgb_broker_config_t config;
    bgb_store_t *store;
    bgb_rest_t *rest;
    void *zmq;
    void *router;
    char endpoint[256];
    pthread_t loop, dispatcher;
    int loop_started, dispatcher_started;
    pthread_mutex_t lock;
    pthread_cond_t changed;
    int stopping;
    int running; /* coordinators alive */
    int64_t agent_messages; /* frames sets received on the ROUTER socket */
    bgb_market_t *market;   /* the loop thread's alone */
    bgb_agent_info_t *live; /* directory snapshot buffer, BGB_MARKET_MAX_AGENTS rows, loop's */
    buy_req_t *reqs;        /* under lock */
    uint64_t next_job;      /* under lock */
    int loop_gone;          /* under lock */
    int market_agents;      /* live agents in the directory, published by the loop */
    char *agents_json, *market_json, *contracts_csv, *agents_csv; /* snapshots, under lock */
};

/* ------------------------------------------------------------ config */

static char *dup_or_null(const char *s)
{
    return s ? strdup(s) : NULL;
}

bg_status bgb_broker_config_init(bgb_broker_config_t *c, bg_error_t *err)
{
    memset(c, 0, sizeof *c);
    c->name = strdup("biotgrid");
    c->address = strdup("127.0.0.1");
    c->endpoint = strdup("tcp://127.0.0.1:5570");
    c->state_dir = strdup("out/broker");
    c->port = 8080;
    c->max_jobs = 4;
    c->agent_timeout_ms = 10000;
    bgb_market_config_default(&c->market);
    if (!c->name || !c->address || !c->endpoint || !c->state_dir) {
        bgb_broker_config_release(c);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker's configuration");
    }
    return BG_OK;
}

void bgb_broker_config_release(bgb_broker_config_t *c)
{
    if (!c)
        return;
    free(c->name);
    free(c->address);
    free(c->endpoint);
    free(c->state_dir);
    for (int i = 0; i < c->agent_count; i++)
        free(c->agents[i].endpoint);
    memset(c, 0, sizeof *c);
}

static bg_status replace_string(char **slot, const cJSON *item, const char *path,
                                const char *field, bg_error_t *err)
{
    const char *s = NULL;
    bg_status st = bg_json_string(item, path, field, &s, err);
    if (st != BG_OK)
        return st;
    if (!*s)
        return bg_json_fail(err, BG_ERR_INVALID, path, field, "must not be empty");
    char *copy = strdup(s);
    if (!copy)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    free(*slot);
    *slot = copy;
    return BG_OK;
}

static bg_status read_agents(const cJSON *arr, const char *path, bgb_broker_config_t *c,
                             bg_error_t *err)
{
    if (!cJSON_IsArray(arr))
        return bg_json_fail(err, BG_ERR_INVALID, path, "agents", "expected an array, got %s",
                            bg_json_type_name(arr));
    static const char *const keys[] = {"endpoint", "services", "name", NULL};
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, arr) {
        char field[BG_JSON_PATH_MAX], sub[BG_JSON_PATH_MAX];
        bg_json_path_index(field, "agents", i);
        if (i >= BGB_BROKER_MAX_AGENTS)
            return bg_json_fail(err, BG_ERR_INVALID, path, field, "more than %d agents",
                                BGB_BROKER_MAX_AGENTS);
        bg_status st = bg_json_expect_object(e, path, field, err);
        if (st == BG_OK)
            st = bg_json_check_keys(e, path, field, keys, err);
        if (st != BG_OK)
            return st;
        const char *ep = NULL, *services = NULL;
        bg_json_path_key(sub, field, "endpoint");
        st = bg_json_string(cJSON_GetObjectItemCaseSensitive(e, "endpoint"), path, sub, &ep, err);
        if (st != BG_OK)
            return st;
        if (strncmp(ep, "tcp://", 6) != 0 || strlen(ep) > 200)
            return bg_json_fail(err, BG_ERR_INVALID, path, sub,
                                "'%s' is not tcp://HOST:PORT (at most 200 bytes)", ep);
        bg_json_path_key(sub, field, "services");
        st = bg_json_string(cJSON_GetObjectItemCaseSensitive(e, "services"), path, sub,
                            &services, err);
        if (st != BG_OK)
            return st;
        bg_error_t perr = BG_ERROR_INIT;
        const unsigned bits = bga_service_parse_list(services, &perr);
        if (bits == 0)
            return bg_json_fail(err, BG_ERR_INVALID, path, sub, "%s", perr.message);
        c->agents[i].endpoint = strdup(ep);
        if (!c->agents[i].endpoint)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        c->agents[i].services = bits;
        c->agent_count = ++i;
    }
    return BG_OK;
}

bg_status bgb_broker_market_read(const cJSON *obj, const char *path, bgb_market_config_t *m,
                                 bg_error_t *err)
{
    static const char *const keys[] = {"period",        "k",    "heartbeat_timeout",
                                       "reply_timeout", "buy_timeout", "overlay_degree",
                                       "hops",          "max_rounds",  "max_contracts", NULL};
    bg_status st;
    if ((st = bg_json_expect_object(obj, path, "market", err)) != BG_OK ||
        (st = bg_json_check_keys(obj, path, "market", keys, err)) != BG_OK)
        return st;
    const struct {
        const char *key;
        double *at;
    } times[] = {{"period", &m->period},
                 {"heartbeat_timeout", &m->heartbeat_timeout},
                 {"reply_timeout", &m->reply_timeout},
                 {"buy_timeout", &m->buy_timeout}};
    const struct {
        const char *key;
        double lo, hi;
        int *at;
    } counts[] = {{"overlay_degree", 1, BGA_MMSG_MAX_NEIGHBOURS, &m->overlay_degree},
                  {"hops", 1, 16, &m->hops},
                  {"max_rounds", 1, 1000, &m->max_rounds}};
    const cJSON *item;
    cJSON_ArrayForEach(item, obj) {
        char field[BG_JSON_PATH_MAX];
        bg_json_path_key(field, "market", item->string);
        const char *k = item->string;
        int64_t v = 0;
        if (strcmp(k, "k") == 0)
            st = bg_json_number_in(item, path, field, 0, 1, &m->k, err);
        else if (strcmp(k, "max_contracts") == 0) {
            st = bg_json_integer(item, path, field, 1, 1e7, &v, err);
            m->max_contracts = (size_t)v;
        }
        for (size_t i = 0; i < sizeof times / sizeof times[0]; i++)
            if (strcmp(k, times[i].key) == 0) {
                st = bg_json_number_in(item, path, field, 0, 3600, times[i].at, err);
                if (st == BG_OK && !(*times[i].at > 0 && *times[i].at < 3600))
                    st = bg_json_fail(err, BG_ERR_INVALID, path, field,
                                      "%.17g s is outside (0, 3600)", *times[i].at);
            }
        for (size_t i = 0; i < sizeof counts / sizeof counts[0]; i++)
            if (strcmp(k, counts[i].key) == 0) {
                st = bg_json_integer(item, path, field, counts[i].lo, counts[i].hi, &v, err);
                *counts[i].at = (int)v;
            }
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

bg_status bgb_broker_config_read(const char *path, bgb_broker_config_t *c, bg_error_t *err)
{
    cJSON *root = NULL;
    bg_status st = bg_json_load(path, BROKER_CONFIG_MAX_BYTES, &root, err);
    if (st != BG_OK)
        goto out;
    static const char *const keys[] = {"name",         "address",      "port",
                                       "endpoint",     "state_dir",    "max_body",
                                       "max_vertices", "max_elements", "max_jobs",
                                       "agent_timeout_ms", "agents",   "market", NULL};
    if ((st = bg_json_expect_object(root, path, NULL, err)) != BG_OK ||
        (st = bg_json_check_keys(root, path, NULL, keys, err)) != BG_OK)
        goto out;
    const cJSON *item;
    cJSON_ArrayForEach(item, root) {
        const char *k = item->string;
        int64_t v = 0;
        if (strcmp(k, "name") == 0)
            st = replace_string(&c->name, item, path, k, err);
        else if (strcmp(k, "address") == 0)
            st = replace_string(&c->address, item, path, k, err);
        else if (strcmp(k, "endpoint") == 0)
            st = replace_string(&c->endpoint, item, path, k, err);
        else if (strcmp(k, "state_dir") == 0)
            st = replace_string(&c->state_dir, item, path, k, err);
        else if (strcmp(k, "agents") == 0)
            st = read_agents(item, path, c, err);
        else if (strcmp(k, "market") == 0)
            st = bgb_broker_market_read(item, path, &c->market, err);
        else if (strcmp(k, "port") == 0) {
            st = bg_json_integer(item, path, k, 0, 65535, &v, err);
            c->port = (int)v;
        } else if (strcmp(k, "max_jobs") == 0) {
            st = bg_json_integer(item, path, k, 1, BROKER_MAX_JOBS, &v, err);
            c->max_jobs = (int)v;
        } else if (strcmp(k, "agent_timeout_ms") == 0) {
            st = bg_json_integer(item, path, k, 1, 3600000, &v, err);
            c->agent_timeout_ms = (int)v;
        } else {
            st = bg_json_integer(item, path, k, 0, 1e15, &v, err);
            if (strcmp(k, "max_body") == 0)
                c->max_body = v;
            else if (strcmp(k, "max_vertices") == 0)
                c->max_vertices = v;
            else
                c->max_elements = v;
        }
        if (st != BG_OK)
            goto out;
    }
out:
    cJSON_Delete(root);
    return st;
}

static bg_status copy_config(bgb_broker_config_t *to, const bgb_broker_config_t *from,
                             bg_error_t *err)
{
    *to = *from;
    to->name = dup_or_null(from->name);
    to->address = dup_or_null(from->address);
    to->endpoint = dup_or_null(from->endpoint);
    to->state_dir = dup_or_null(from->state_dir);
    int ok = to->name && to->address && to->endpoint && to->state_dir;
    for (int i = 0; i < from->agent_count; i++) {
        to->agents[i].endpoint = dup_or_null(from->agents[i].endpoint);
        ok &= to->agents[i].endpoint != NULL;
    }
    if (!ok) {
        bgb_broker_config_release(to);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker's configuration");
    }
    return BG_OK;
}

/* ------------------------------------------------------- file helpers */

static bg_status make_dir(const char *path, bg_error_t *err)
{
    char buf[BROKER_PATH_MAX];
    const size_t n = strlen(path);
    if (n >= sizeof buf)
        return bg_error_set(err, BG_ERR_INVALID, "%s: path too long", path);
    memcpy(buf, path, n + 1);
    for (size_t i = 1; i <= n; i++) {
        if (buf[i] != '/' && buf[i] != '\0')
            continue;
        const char c = buf[i];
        buf[i] = '\0';
        if (mkdir(buf, 0777) != 0 && errno != EEXIST)
            return bg_error_set(err, BG_ERR_IO, "%s: cannot create: %s", buf, strerror(errno));
        buf[i] = c;
    }
    return BG_OK;
}

static bg_status write_file(const char *path, const uint8_t *data, size_t size, bg_error_t *err)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    const size_t done = size ? fwrite(data, 1, size, f) : 0;
    if (fclose(f) != 0 || done != size)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
    return BG_OK;
}

static bg_status read_file(const char *path, uint8_t **data, size_t *size, bg_error_t *err)
{
    *data = NULL;
    bg_status st = BG_OK;
    FILE *f = fopen(path, "rb");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot read: %s", path, strerror(errno));
    struct stat sb;
    if (fstat(fileno(f), &sb) != 0 || sb.st_size < 0 ||
        (size_t)sb.st_size > BROKER_MAX_RESULT_FILE) {
        st = bg_error_set(err, BG_ERR_LIMIT, "%s: not a readable file of at most %zu bytes", path,
                          BROKER_MAX_RESULT_FILE);
        goto out;
    }
    *size = (size_t)sb.st_size;
    *data = malloc(*size + 1);
    if (!*data) {
        st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
        goto out;
    }
    if (fread(*data, 1, *size, f) != *size) {
        st = bg_error_set(err, BG_ERR_IO, "%s: read failed", path);
        free(*data);
        *data = NULL;
    }
out:
    fclose(f);
    return st;
}

/* --------------------------------------------------------- coordinator */

/* Seconds the job's bought services had worked (inside rotation-fit and
 * sparse-solve calls) when the solve reached a trace point. */
typedef struct usage_point {
    double seconds; /* the trace point's */
    double used[2]; /* USE_ROTFIT, USE_SOLVE */
} usage_point_t;

/* USE_NONE: a forwarded call whose time is not counted (the integration
 * step: its money accrues with the run's time, money_curve). */
enum { USE_ROTFIT, USE_SOLVE, USE_NONE };

typedef struct job_run {
    bgb_broker_t *broker;
    char id[BGB_JOB_ID_SIZE];
    double last_progress;
    double allocation_latency; /* seconds from allocating to running */
    double used[2];            /* service seconds so far, kept by the job's watch */
    usage_point_t *usage;      /* one per progress call, at most BROKER_MAX_USAGE_POINTS; owned */
    int nusage, usage_cap;
} job_run_t;

/* Records how much service time the solve had used at this point; past
 * the cap later points reuse the last record (the money curve then lags,
 * but stays monotone and still ends at the total). */
static void record_usage(job_run_t *jr, double seconds)
{
    if (jr->nusage == jr->usage_cap) {
        if (jr->usage_cap >= BROKER_MAX_USAGE_POINTS)
            return;
        const int grown = jr->usage_cap ? 2 * jr->usage_cap : 256;
        usage_point_t *u = realloc(jr->usage, (size_t)grown * sizeof *u);
        if (!u)
            return;
        jr->usage = u;
        jr->usage_cap = grown;
    }
    jr->usage[jr->nusage++] = (usage_point_t){seconds, {jr->used[0], jr->used[1]}};
}

static void on_progress(void *ctx, bg_method method, const bg_trace_point_t *p)
{
    job_run_t *jr = ctx;
    record_usage(jr, p->seconds);
    const double now = bg_clock_now();
    if (now - jr->last_progress < BROKER_PROGRESS_SECONDS)
        return;
    jr->last_progress = now;
    char json[512];
    char error[32] = "null";
    if (isfinite(p->error))
        snprintf(error, sizeof error, "%.17g", p->error);
    snprintf(json, sizeof json,
             "{\"method\":\"%s\",\"iteration\":%d,\"seconds\":%.6f,\"energy\":%.17g,"
             "\"relative_gradient\":%.17g,\"error\":%s}",
             bg_method_name(method), p->iteration, p->seconds,
             isfinite(p->energy) ? p->energy : 0.0,
             isfinite(p->relative_gradient) ? p->relative_gradient : 0.0, error);
    bg_error_t err = BG_ERROR_INIT;
    (void)bgb_store_add_event(jr->broker->store, jr->id, "progress", json, &err);
}

/* The run's error-against-time trace as a "trace" event's JSON. */
static char *trace_json(const bg_solve_result_t *run)
{
    cJSON *o = cJSON_CreateObject();
    cJSON *points = cJSON_AddArrayToObject(o, "points");
    cJSON_AddStringToObject(o, "method", bg_method_name(run->method));
    for (int k = 0; points && k < run->trace_count; k++) {
        const bg_trace_point_t *p = &run->trace[k];
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "iteration", p->iteration);
        cJSON_AddNumberToObject(e, "seconds", p->seconds);
        if (isfinite(p->energy))
            cJSON_AddNumberToObject(e, "energy", p->energy);
        if (isfinite(p->relative_gradient))
            cJSON_AddNumberToObject(e, "relative_gradient", p->relative_gradient);
        if (isfinite(p->error))
            cJSON_AddNumberToObject(e, "error", p->error);
        else
            cJSON_AddNullToObject(e, "error");
        cJSON_AddItemToArray(points, e);
    }
    char *s = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return s;
}

/* Every regular file of dir into the store as the job's results. */
static bg_status store_results(bgb_broker_t *b, const char *id, const char *dir,
                               bg_error_t *err)
{
    DIR *d = opendir(dir);
    if (!d)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot list: %s", dir, strerror(errno));
    bg_status st = BG_OK;
    struct dirent *e;
    int count = 0;
    while (st == BG_OK && (e = readdir(d)) != NULL) {
        if (e->d_name[0] == '.' || strcmp(e->d_name, "input") == 0)
            continue;
        char path[BROKER_PATH_MAX + 512];
        snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        struct stat sb;
        if (stat(path, &sb) != 0 || !S_ISREG(sb.st_mode))
            continue;
        if (++count > BGB_STORE_MAX_FILES * 16) {
            st = bg_error_set(err, BG_ERR_LIMIT, "%s: more than %d result files", dir,
                              BGB_STORE_MAX_FILES * 16);
            break;
        }
        uint8_t *data = NULL;
        size_t size = 0;
        st = read_file(path, &data, &size, err);
        if (st == BG_OK) {
            const bgb_file_t f = {e->d_name, data, size};
            st = bgb_store_put_file(b->store, id, "result", &f, err);
        }
        free(data);
    }
    closedir(d);
    return st;
}

/* The names of a job's input files: the store's listing calls back under
 * its read lock, so files are read only after it returns. */
typedef struct input_names {
    char *names[BGB_STORE_MAX_FILES];
    int count;
    int overflow;
} input_names_t;

static void collect_input(void *ctx, const char *name, size_t size)
{
    (void)size;
    input_names_t *in = ctx;
    if (in->count == BGB_STORE_MAX_FILES || !(in->names[in->count] = strdup(name))) {
        in->overflow = 1;
        return;
    }
    in->count++;
}

/* Writes every input file of the job into dir. */
static bg_status write_inputs(bgb_broker_t *b, const char *id, const char *dir, bg_error_t *err)
{
    input_names_t in;
    memset(&in, 0, sizeof in);
    bg_status st = bgb_store_list_files(b->store, id, "input", collect_input, &in, err);
    if (st == BG_OK && in.overflow)
        st = bg_error_set(err, BG_ERR_LIMIT, "job %s: cannot list its input files", id);
    for (int i = 0; st == BG_OK && i < in.count; i++) {
        uint8_t *data = NULL;
        size_t n = 0;
        st = bgb_store_get_file(b->store, id, "input", in.names[i], &data, &n, err);
        if (st == BG_OK) {
            char path[BROKER_PATH_MAX + 512];
            snprintf(path, sizeof path, "%s/%s", dir, in.names[i]);
            st = write_file(path, data, n, err);
        }
        free(data);
    }
    for (int i = 0; i < in.count; i++)
        free(in.names[i]);
    return st;
}

/* The pool's agents for the report, with what each did. */
static int agent_lines(const bgb_broker_config_t *c, const int *role, const bga_backend_t *backend,
                       bg_report_agent_t *out)
{
    const int nrotfit = bga_backend_agents(backend) - 1;
    for (int i = 0; i < c->agent_count; i++) {
        bg_report_agent_t *r = &out[i];
        memset(r, 0, sizeof *r);
        r->endpoint = c->agents[i].endpoint;
        r->service = c->agents[i].services == BGA_SERVICE_INTEG ? "integration-step"
                                                                : "several services";
        if (role[i] == -1)
            continue;
        bga_agent_usage_t u;
        if (role[i] == -3)
            (void)bga_backend_integ_usage(backend, &u);
        else
            u = bga_backend_usage(backend, role[i] == -2 ? nrotfit : role[i]);
        r->service = u.service;
        r->calls = u.traffic.requests;
        r->contacted = r->calls > 0;
        r->bytes_sent = u.traffic.bytes_sent;
        r->bytes_received = u.traffic.bytes_received;
        r->compute_seconds = u.traffic.agent_seconds;
        r->encode_seconds = u.traffic.encode_seconds;
        r->wait_seconds = u.traffic.wait_seconds;
    }
    return c->agent_count;
}

/*
 * The money the job had spent at each trace point of run, into money[k]
 * (run->trace_count entries). Contracts are bought up front, but what a
 * user gets for the money is service time: each contract is pro-rated by
 * the share of its service's working time (seconds inside rotation-fit or
 * sparse-solve calls, from the job's watch) used up to that point; a
 * service that did not work during the run (integration-step: the time
 * loop runs in the broker) is pro-rated by run time. At the last point
 * every share is 1, so the curve ends at exactly bought->spent (the same
 * sum in the same order). No purchase: 0 everywhere.
 */
static void money_curve(const job_run_t *jr, const bg_solve_result_t *run, const buy_req_t *bought,
                        double *money)
{
    const int n = run->trace_count;
    if (n == 0)
        return;
    /* The service time at each point: the latest record at or before it. */
    double last[2] = {0, 0};
    int j = -1;
    for (int k = 0; k < n; k++) {
        while (j + 1 < jr->nusage && jr->usage[j + 1].seconds <= run->trace[k].seconds)
            j++;
        if (k == n - 1 && j >= 0)
            last[0] = jr->usage[j].used[0], last[1] = jr->usage[j].used[1];
    }
    const double t_last = run->trace[n - 1].seconds;
    j = -1;
    for (int k = 0; k < n; k++) {
        const double t = run->trace[k].seconds;
        while (j + 1 < jr->nusage && jr->usage[j + 1].seconds <= t)
            j++;
        double m = 0.0;
        for (int c = 0; bought && c < bought->nawards; c++) {
            const bgb_award_t *a = &bought->awards[c];
            const int use = a->good == BGB_GOOD_ROTFIT ? USE_ROTFIT
                            : a->good == BGB_GOOD_SOLVE ? USE_SOLVE
                                                        : -1;
            double share = 1.0;
            if (k < n - 1) {
                if (use >= 0 && last[use] > 0)
                    share = j >= 0 ? jr->usage[j].used[use] / last[use] : 0.0;
                else
                    share = t_last > 0 ? t / t_last : 1.0;
                share = share < 0 ? 0 : share > 1 ? 1 : share;
            }
            m += a->quantity * a->price * share;
        }
        money[k] = m;
    }
}

/*
 * Adds the job's "market" section to DIR/report.json: mechanism, the
 * contracts (service, agent, quantity, price), money spent against the
 * budget, the allocation latency, and the error against run time and
 * against money (money[k] for the run's k-th trace point, see
 * money_curve). bought NULL: the fixed pool, no contracts, nothing spent.
 */
static bg_status add_market_section(const char *path, const bgb_job_t *job,
                                    const buy_req_t *bought, double latency, const double *money,
                                    int nmoney, bg_error_t *err)
{
    cJSON *root = NULL;
    bg_status st = bg_json_load(path, BROKER_MAX_RESULT_FILE, &root, err);
    if (st != BG_OK)
        return st;
    char *text = NULL;
    const double spent = bought ? bought->spent : 0.0;
    cJSON *m = cJSON_AddObjectToObject(root, "market");
    cJSON_AddStringToObject(m, "mechanism", job->mechanism);
    cJSON *contracts = NULL;
    if (bought) {
        cJSON_AddStringToObject(m, "market", "live");
        contracts = cJSON_AddArrayToObject(m, "contracts");
        for (int i = 0; i < bought->nawards; i++) {
            const bgb_award_t *a = &bought->awards[i];
            cJSON *e = cJSON_CreateObject();
            cJSON_AddStringToObject(e, "service", bgb_good_name(a->good));
            cJSON_AddStringToObject(e, "agent", a->name);
            cJSON_AddStringToObject(e, "endpoint", a->endpoint);
            cJSON_AddNumberToObject(e, "quantity", a->quantity);
            cJSON_AddNumberToObject(e, "price", a->price);
            cJSON_AddItemToArray(contracts, e);
        }
    } else {
        cJSON_AddNullToObject(m, "market");
        cJSON_AddStringToObject(m, "note", "no agent is registered on the market: the job ran "
                                           "on the broker's configured agents without contracts");
        cJSON_AddArrayToObject(m, "contracts");
    }
    cJSON_AddNumberToObject(m, "budget", job->budget);
    cJSON_AddNumberToObject(m, "spent", spent);
    cJSON_AddNumberToObject(m, "allocation_latency_seconds", latency);
    cJSON_AddStringToObject(m, "money_basis",
                            "the whole price is committed when the services are bought; each "
                            "point's money is every contract pro-rated by the share of its "
                            "service's working time used so far (run time for a service that "
                            "does not work during the run), so the curve ends at spent");
    cJSON *curve = cJSON_AddArrayToObject(m, "error_vs_time_and_money");
    const cJSON *runs = cJSON_GetObjectItemCaseSensitive(root, "runs");
    const cJSON *trace = cJSON_GetObjectItemCaseSensitive(cJSON_GetArrayItem(runs, 0), "trace");
    const cJSON *p;
    int k = 0;
    cJSON_ArrayForEach(p, trace) {
        cJSON *e = cJSON_CreateObject();
        const cJSON *s = cJSON_GetObjectItemCaseSensitive(p, "seconds");
        const cJSON *er = cJSON_GetObjectItemCaseSensitive(p, "error");
        cJSON_AddNumberToObject(e, "seconds", cJSON_IsNumber(s) ? s->valuedouble : 0.0);
        cJSON_AddNumberToObject(e, "money", k < nmoney ? money[k] : spent);
        if (cJSON_IsNumber(er))
            cJSON_AddNumberToObject(e, "error", er->valuedouble);
        else
            cJSON_AddNullToObject(e, "error");
        cJSON_AddItemToArray(curve, e);
        k++;
    }
    text = cJSON_Print(root);
    if (!text) {
        st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
        goto out;
    }
    st = write_file(path, (const uint8_t *)text, strlen(text), err);
out:
    free(text);
    cJSON_Delete(root);
    return st;
}

/*
 * DIR/error-vs-time-and-money.svg: two panels side by side, the run's
 * error against run time and against money (money_curve), each drawn by
 * bg_svg and placed in one document. The error is what `solve`'s plot
 * shows: against the reference, the energy drift of a dynamic run, else
 * the relative gradient.
 */
static bg_status write_money_plot(const char *path, const bg_scene_t *scene,
                                  const bg_solve_result_t *run, const double *money,
                                  bg_error_t *err)
{
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    const int with_reference = dynamic || scene->reference_kind != BG_REFERENCE_NONE;
    const char *y_label = dynamic          ? "relative energy drift |E - E0| / |E0|"
                          : with_reference ? "relative error |q - q_ref| / |q_ref|"
                                           : "relative gradient |grad W| / force scale";
    const size_t n = (size_t)run->trace_count;
    bg_status st = BG_OK;
    char *panel[2] = {NULL, NULL};
    size_t length[2] = {0, 0};
    double *x = malloc((n + 1) * sizeof *x), *y = malloc((n + 1) * sizeof *y);
    FILE *f = NULL;
    if (!x || !y) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the plot");
        goto out;
    }
    for (size_t k = 0; k < n; k++) {
        x[k] = run->trace[k].seconds;
        y[k] = with_reference ? run->trace[k].error : run->trace[k].relative_gradient;
    }
    char title[2][256];
    snprintf(title[0], sizeof title[0], "%s: error against run time", scene->name);
    snprintf(title[1], sizeof title[1], "%s: error against money", scene->name);
    const bg_svg_plot_t plots[2] = {{title[0], "wall time (s)", y_label, 0, 1},
                                    {title[1], "money spent (pro-rated by service time)",
                                     y_label, 0, 1}};
    bg_svg_series_t series = {bg_method_name(run->method), x, y, n};
    if ((st = bg_svg_render(&plots[0], &series, 1, &panel[0], &length[0], err)) != BG_OK)
        goto out;
    series.x = money;
    if ((st = bg_svg_render(&plots[1], &series, 1, &panel[1], &length[1], err)) != BG_OK)
        goto out;
    /* The panels' size is bg_svg's: read from its root element. */
    int width = 0, height = 0;
    const char *w = strstr(panel[0], " width=\""), *h = strstr(panel[0], " height=\"");
    if (!w || !h || sscanf(w, " width=\"%d\"", &width) != 1 ||
        sscanf(h, " height=\"%d\"", &height) != 1 || width <= 0 || height <= 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: the plot has no size", path);
        goto out;
    }
    if (!(f = fopen(path, "w"))) {
        st = bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
        goto out;
    }
    fprintf(f, "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"%d\" "
               "height=\"%d\" viewBox=\"0 0 %d %d\">\n",
            2 * width, height, 2 * width, height);
    for (int i = 0; i < 2; i++) {
        fprintf(f, "<g transform=\"translate(%d 0)\">\n", i * width);
        fwrite(panel[i], 1, length[i], f);
        fprintf(f, "</g>\n");
    }
    fprintf(f, "</svg>\n");
    const int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        st = bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
out:
    free(panel[0]);
    free(panel[1]);
    free(x);
    free(y);
    return st;
}

/* Runs the job on the configured agents into dir; the store gets its
 * results and trace. */
static bg_status load_scene(bgb_broker_t *b, const bgb_job_t *job, const char *dir,
                            bg_scene_t **scene, bg_error_t *err)
{
    const bgb_broker_config_t *c = &b->config;
    bg_status st;
    char input[BROKER_PATH_MAX + 16], path[BROKER_PATH_MAX + 96];
    snprintf(input, sizeof input, "%s/input", dir);
    if ((st = make_dir(input, err)) != BG_OK || (st = write_inputs(b, job->id, input, err)) != BG_OK)
        return st;
    snprintf(path, sizeof path, "%s/scene.json", input);
    const bg_scene_options_t so = {.max_vertices = c->max_vertices,
                                   .max_elements = c->max_elements,
                                   .confined = 1,
                                   .display_name = "scene"};
    if ((st = bg_scene_parse_with(job->scene, job->scene_size, path, &so, scene, err)) == BG_OK)
        st = bg_prepare_scene(*scene, err);
    return st;
}

/*
 * Cancel between service calls. A job's solve calls its basic services
 * through this backend, which forwards every call to `inner` (the agents,
 * or in process) once it has checked that the job is still running: the
 * store is read at most every BROKER_CANCEL_POLL_SECONDS. When the job has
 * left running (POST /v1/jobs/{id}/cancel moved it to cancelled) every
 * call fails with BG_ERR_CONFLICT, so the solver returns after the service
 * call in progress; the coordinator then stores no result and releases the
 * contracts. Used by one coordinator thread only.
 */
typedef struct job_watch {
    bgb_broker_t *broker;
    const char *id;            /* borrowed: the job_run_t's */
    const bg_backend_t *inner; /* borrowed */
    double next_check;
    int stopped;               /* the job was seen out of running */
    double *used;              /* seconds inside rotation-fit and sparse-solve calls are added
                                  to used[USE_ROTFIT], used[USE_SOLVE]; NULL: not counted */
    bg_backend_t backend;      /* what the solver is given: watch_ops, this */
} job_watch_t;

typedef struct watch_session {
    job_watch_t *watch;
    void *inner;
} watch_session_t;

/* The market's failure reasons that a later try may not meet, by the
 * name the job's events give them: every able seller busy ("no seller"),
 * or a buy that ran out of time on a loaded grid ("timeout"). NULL for
 * any other reason. */
static const char *buy_failure_transient(const char *reason)
{
    if (strstr(reason, "no seller"))
        return "no seller";
    return strcmp(reason, "timeout") == 0 ? "timeout" : NULL;
}

/* 1 when the store says job `id` is no longer in `state` (a cancel from a
 * REST thread lands there); 0 while it is, or when the store cannot be
 * read (a transient read error must not stop a job). */
static int job_left_state(bgb_broker_t *b, const char *id, bgb_job_state state)
{
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t e = BG_ERROR_INIT;
    const int left = bgb_store_get(b->store, id, &job, &e) == BG_OK && job.state != state;
    bgb_job_release(&job);
    return left;
}

/* BG_OK while the job runs; BG_ERR_CONFLICT once it does not. */
static bg_status watch_check(job_watch_t *w, bg_error_t *err)
{
    if (!w->stopped) {
        const double now = bg_clock_now();
        if (now < w->next_check)
            return BG_OK;
        w->next_check = now + BROKER_CANCEL_POLL_SECONDS;
        w->stopped = job_left_state(w->broker, w->id, BGB_JOB_RUNNING);
        if (!w->stopped)
            return BG_OK;
    }
    return bg_error_set(err, BG_ERR_CONFLICT, "job %s was cancelled: the solve stopped", w->id);
}

/* Adds the seconds since t0 to the service's usage. */
static bg_status watch_used(job_watch_t *w, int service, double t0, bg_status st)
{
    if (w->used && service != USE_NONE)
        w->used[service] += bg_clock_now() - t0;
    return st;
}

/* The body of every forwarded service call: stop if the job was
 * cancelled, else call `op` of the inner backend and count its time. */
#define WATCH_FORWARD(service, op, ...)                                                        \
    watch_session_t *s = session;                                                              \
    const bg_status st = watch_check(s->watch, err);                                           \
    if (st != BG_OK)                                                                           \
        return st;                                                                             \
    const double t0 = bg_clock_now();                                                          \
    return watch_used(s->watch, service, t0, s->watch->inner->ops->op(s->inner, __VA_ARGS__, err))

static bg_status watch_session_new(void *ctx, void **session, bg_error_t *err)
{
    job_watch_t *w = ctx;
    *session = NULL;
    bg_status st = watch_check(w, err);
    if (st != BG_OK)
        return st;
    watch_session_t *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for a solver session");
    s->watch = w;
    if ((st = w->inner->ops->session_new(w->inner->ctx, &s->inner, err)) != BG_OK) {
        free(s);
        return st;
    }
    *session = s;
    return BG_OK;
}

static void watch_session_destroy(void *ctx, void *session)
{
    job_watch_t *w = ctx;
    watch_session_t *s = session;
    if (!s)
        return;
    w->inner->ops->session_destroy(w->inner->ctx, s->inner);
    free(s);
}

static bg_status watch_fit_open(void *session, int id, const bg_backend_fit_t *fit,
                                bg_error_t *err)
{
    WATCH_FORWARD(USE_ROTFIT, fit_open, id, fit);
}

static bg_status watch_fit_eval(void *session, int id, const double *q, double *energy,
                                double *grad, bg_error_t *err)
{
    WATCH_FORWARD(USE_ROTFIT, fit_eval, id, q, energy, grad);
}

static bg_status watch_fit_hessian(void *session, int id, const double *q, int project,
                                   double scale, double *values, bg_error_t *err)
{
    WATCH_FORWARD(USE_ROTFIT, fit_hessian, id, q, project, scale, values);
}

static bg_status watch_solve_open(void *session, int id, bg_sparse_t *sys, bg_error_t *err)
{
    WATCH_FORWARD(USE_SOLVE, solve_open, id, sys);
}

static bg_status watch_solve_factor(void *session, int id, double shift, bg_error_t *err)
{
    WATCH_FORWARD(USE_SOLVE, solve_factor, id, shift);
}

static bg_status watch_solve(void *session, int id, int nrhs, const double *rhs, double *x,
                             bg_error_t *err)
{
    WATCH_FORWARD(USE_SOLVE, solve, id, nrhs, rhs, x);
}

static void watch_solve_cost(void *session, int id, double *flops, double *nonzeros)
{
    watch_session_t *s = session;
    s->watch->inner->ops->solve_cost(s->inner, id, flops, nonzeros);
}

static bg_status watch_step_open(void *session, const bg_step_setup_t *setup,
                                 bg_step_motion_t *motion, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_open, setup, motion);
}

static bg_status watch_step_predict(void *session, const bg_step_request_t *req,
                                    bg_step_prediction_t *out, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_predict, req, out);
}

static bg_status watch_step_update(void *session, const double *q_star, const double *grad_star,
                                   bg_step_trial_t *out, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_update, q_star, grad_star, out);
}

static bg_status watch_step_accept(void *session, bg_step_motion_t *motion, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_accept, motion);
}

static bg_status watch_surface_open(void *session, const bg_mesh_t *mesh, bg_error_t *err)
{
    WATCH_FORWARD(USE_ROTFIT, surface_open, mesh);
}

static bg_status watch_surface_eval(void *session, const double *q, double *energy, double *grad,
                                    bg_rotfit_stats_t *stats, bg_error_t *err)
{
    WATCH_FORWARD(USE_ROTFIT, surface_eval, q, energy, grad, stats);
}

/* The inner backend (in process or agents) implements every operation. */
static const bg_backend_ops_t watch_ops = {
    .name = "stops on cancel",
    .session_new = watch_session_new,
    .session_destroy = watch_session_destroy,
    .fit_open = watch_fit_open,
    .fit_eval = watch_fit_eval,
    .fit_hessian = watch_fit_hessian,
    .solve_open = watch_solve_open,
    .solve_factor = watch_solve_factor,
    .solve = watch_solve,
    .solve_cost = watch_solve_cost,
    .step_open = watch_step_open,
    .step_predict = watch_step_predict,
    .step_update = watch_step_update,
    .step_accept = watch_step_accept,
    .surface_open = watch_surface_open,
    .surface_eval = watch_surface_eval,
};

/* w watches job id over inner (NULL: in process), adding service time to
 * used (may be NULL); w->backend is the solver's backend, valid while w
 * lives. */
static void watch_init(job_watch_t *w, bgb_broker_t *b, const char *id, const bg_backend_t *inner,
                       double *used)
{
    memset(w, 0, sizeof *w);
    w->broker = b;
    w->id = id;
    w->used = used;
    w->inner = inner ? inner : bg_backend_local();
    w->backend.ops = &watch_ops;
    w->backend.ctx = w;
}

/* What the job bought (NULL: the fixed pool, nothing bought). */
typedef struct job_alloc {
    const bgb_broker_agent_t *pool;
    int npool;
    const buy_req_t *bought;
} job_alloc_t;

/* Runs the job on its agents into dir; the store gets its results and
 * trace. scene is borrowed. */
static bg_status solve_job(bgb_broker_t *b, job_run_t *jr, const bgb_job_t *job, const char *dir,
                           bg_scene_t *scene, const job_alloc_t *alloc, int *converged,
                           int *stopped, bg_error_t *err)
{
    bgb_broker_config_t pool = b->config;
    memcpy(pool.agents, alloc->pool, (size_t)alloc->npool * sizeof *alloc->pool);
    pool.agent_count = alloc->npool;
    const bgb_broker_config_t *c = &pool;
    bga_backend_t *remote = NULL;
    bg_solve_result_t run = BG_SOLVE_RESULT_INIT, reference = BG_SOLVE_RESULT_INIT;
    char *trace = NULL;
    double *money = NULL;
    bg_status st;
    char path[BROKER_PATH_MAX + 96];
    job_watch_t local_watch, remote_watch;
    watch_init(&local_watch, b, jr->id, NULL, NULL);
    watch_init(&remote_watch, b, jr->id, NULL, NULL);

    /* The pool: every rotation-fit agent but a dedicated sparse-solve one. */
    const char *rotfit[BGB_BROKER_MAX_AGENTS], *solver = NULL;
    int role[BGB_BROKER_MAX_AGENTS], nrotfit = 0, s = -1;
    for (int i = 0; i < c->agent_count; i++) {
        role[i] = -1;
        if ((c->agents[i].services & BGA_SERVICE_SOLVE) &&
            (s < 0 || c->agents[i].services == BGA_SERVICE_SOLVE))
            s = s >= 0 && c->agents[s].services == BGA_SERVICE_SOLVE ? s : i;
    }
    for (int i = 0; i < c->agent_count; i++)
        if (i != s && (c->agents[i].services & BGA_SERVICE_ROTFIT)) {
            role[i] = nrotfit;
            rotfit[nrotfit++] = c->agents[i].endpoint;
        }
    if (nrotfit == 0 && s >= 0 && (c->agents[s].services & BGA_SERVICE_ROTFIT)) {
        role[s] = 0;
        rotfit[nrotfit++] = c->agents[s].endpoint;
    }
    if (s < 0 || nrotfit == 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "the broker's agents serve no %s",
                          s < 0 ? "sparse-solve" : "rotation-fit");
        goto out;
    }
    if (role[s] == -1)
        role[s] = -2;
    solver = c->agents[s].endpoint;
    const bga_backend_config_t bc = {rotfit, nrotfit, solver, c->agent_timeout_ms,
                                     BROKER_AGENT_LEASE_MS,
                                     alloc->bought ? alloc->bought->job : 0};
    if ((st = bga_backend_new(&bc, &remote, err)) != BG_OK)
        goto out;
    /* The time loop's state goes to the job's integration-step agent (role
     * -3); a static job never opens it, so never contacts that agent. */
    for (int i = 0; i < c->agent_count; i++)
        if (role[i] == -1 && (c->agents[i].services & BGA_SERVICE_INTEG)) {
            if ((st = bga_backend_set_integ(remote, c->agents[i].endpoint, err)) != BG_OK)
                goto out;
            role[i] = -3;
            break;
        }
    /* The reference and the run both stop between service calls once the
     * job is cancelled; the reference is computed in process, as `solve`
     * does. */
    watch_init(&remote_watch, b, jr->id, bga_backend_services(remote), jr->used);
    const double *ref = NULL;
    if ((st = bgb_run_reference(scene, &local_watch.backend, &reference, &ref, err)) != BG_OK)
        goto out;
    const bgb_run_options_t ro = {.method = scene->method,
                                  .tolerance = scene->tolerance,
                                  .max_iterations = bg_scene_max_iterations(scene, scene->method),
                                  .frames_prefix = "",
                                  .progress = on_progress,
                                  .progress_ctx = jr,
                                  .backend = &remote_watch.backend};
    st = bgb_run_method(scene, &ro, ref, dir, &run, err);
    if (st != BG_OK)
        goto out;
    *converged = run.converged;
    bg_plan_t plan;
    bg_plan_for_scene(scene, &scene->method, 1, &plan);
    bg_report_agent_t lines[BGB_BROKER_MAX_AGENTS];
    const int nlines = agent_lines(c, role, remote, lines);
    char paths[2 * BROKER_PATH_MAX + 64];
    if (!(money = calloc((size_t)run.trace_count + 1, sizeof *money))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the money curve");
        goto out;
    }
    money_curve(jr, &run, alloc->bought, money);
    snprintf(path, sizeof path, "%s/report.json", dir);
    if ((st = bg_report_write_agents(path, scene, &plan, &run, 1, lines, nlines, err)) != BG_OK ||
        (st = add_market_section(path, job, alloc->bought, jr->allocation_latency, money,
                                 run.trace_count, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/error-vs-time-and-money.svg", dir);
    if ((st = write_money_plot(path, scene, &run, money, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/error-vs-time.svg", dir);
    if ((st = bg_report_write_plot(path, scene, &run, 1, err)) != BG_OK ||
        (st = bgb_run_write_results(dir, scene, &run, paths, sizeof paths, err)) != BG_OK)
        goto out;
    trace = trace_json(&run);
    if (trace && (st = bgb_store_add_event(b->store, job->id, "trace", trace, err)) != BG_OK)
        goto out;
    st = store_results(b, job->id, dir, err);
out:
    *stopped = local_watch.stopped || remote_watch.stopped;
    free(money);
    free(trace);
    bg_solve_result_release(&run);
    bg_solve_result_release(&reference);
    bga_backend_destroy(&remote);
    return st;
}

#define MASK(s) (1u << (s))

/* Blocks until the market has a live agent (1, *registered set), or the
 * job left allocating or the broker is stopping (0). The loop publishes
 * the directory every 0.1 s and broadcasts `changed` when the first agent
 * comes; the timed wait also looks at the job's state once a second. */
static int wait_for_market_agents(bgb_broker_t *b, const char *id, int *registered)
{
    for (;;) {
        pthread_mutex_lock(&b->lock);
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_sec += 1;
        while (b->market_agents == 0 && !b->stopping && !b->loop_gone)
            if (pthread_cond_timedwait(&b->changed, &b->lock, &ts) == ETIMEDOUT)
                break;
        const int n = b->market_agents, gone = b->stopping || b->loop_gone;
        pthread_mutex_unlock(&b->lock);
        if (gone)
            return 0; /* left in allocating, queued again at restart */
        if (n > 0) {
            *registered = n;
            return 1;
        }
        if (job_left_state(b, id, BGB_JOB_ALLOCATING))
            return 0; /* cancelled */
    }
}

static void *coordinator(void *arg)
{
    job_run_t *jr = arg;
    bgb_broker_t *b = jr->broker;
    bg_error_t err = BG_ERROR_INIT, terr = BG_ERROR_INIT;
    bgb_job_t job = BGB_JOB_INIT;
    bg_scene_t *scene = NULL;
    buy_req_t *req = NULL;
    bgb_broker_agent_t bought[BROKER_MAX_AWARDS];
    job_alloc_t alloc = {b->config.agents, b->config.agent_count, NULL};
    const double t0 = bg_clock_now();
    const unsigned live_or_fail = MASK(BGB_JOB_ALLOCATING) | MASK(BGB_JOB_RUNNING);
    if (bgb_store_get(b->store, jr->id, &job, &err) != BG_OK)
        goto out;
    pthread_mutex_lock(&b->lock);
    int registered = b->market_agents;
    pthread_mutex_unlock(&b->lock);
    if (registered == 0 && b->config.agent_count == 0) {
        /* Nobody to buy from and no fixed pool: the job waits in allocating
         * until an agent registers (a grid's agents register a moment after
         * they are up, and a job may come first), is cancelled, or the
         * broker stops. */
        (void)bgb_store_add_event(b->store, jr->id, "allocation",
                                  "{\"market\":\"live\",\"contracts\":[],\"message\":\"no agent "
                                  "is registered on the market and the broker has no configured "
                                  "agents: nothing was bought; the job waits in allocating until "
                                  "one registers\"}",
                                  &err);
        if (!wait_for_market_agents(b, jr->id, &registered))
            goto out;
    }
    char dir[BROKER_PATH_MAX];
    snprintf(dir, sizeof dir, "%s/jobs/%s", b->config.state_dir, jr->id);
    bg_status st = make_dir(dir, &err);
    if (st == BG_OK)
        st = load_scene(b, &job, dir, &scene, &err);
    if (st != BG_OK) {
        (void)bgb_store_transition(b->store, jr->id, live_or_fail, BGB_JOB_FAILED, err.message,
                                   &terr);
        goto out;
    }
    if (registered == 0) {
        (void)bgb_store_add_event(b->store, jr->id, "allocation",
                                  "{\"market\":null,\"contracts\":[],\"spent\":0,\"message\":\"no "
                                  "agent is registered on the market: the job runs on the "
                                  "broker's configured agents, without contracts\"}",
                                  &err);
    } else {
        const int mech = bgb_mechanism_parse(job.mechanism);
        bg_plan_t plan;
        const bg_method method = scene->method;
        bg_plan_for_scene(scene, &method, 1, &plan);
        /* "no seller" means every seller able to serve is busy now (slots or
         * cores held by other jobs), and "timeout" that the buy did not
         * finish within the market's buy timeout (bargains and layer-1
         * sub-jobs answered late on a loaded host). Both are transient: the
         * job waits and asks again, as a buyer in a market would, for up to
         * BROKER_BUY_PATIENCE seconds; a failed buy holds no contract (the
         * market released what it had). A budget failure is final. */
        const double give_up = bg_clock_now() + BROKER_BUY_PATIENCE;
        double backoff = 0.1;
        int retries = 0;
        for (;;) {
            if (!(req = calloc(1, sizeof *req))) {
                (void)bgb_store_transition(b->store, jr->id, live_or_fail, BGB_JOB_FAILED,
                                           "out of memory", &terr);
                goto out;
            }
            memcpy(req->id, jr->id, sizeof req->id);
            req->mechanism = mech < 0 ? BGB_MECH_CENTRAL : (bgb_mechanism)mech;
            req->budget = job.budget;
            for (int i = 0; i < plan.service_count; i++)
                req->integ |= strcmp(plan.services[i].service, "integration-step") == 0;
            pthread_mutex_lock(&b->lock);
            req->job = ++b->next_job * BGA_MARKET_JOB_SPAN;
            req->next = b->reqs;
            b->reqs = req;
            while (!req->done && !b->loop_gone && !b->stopping)
                pthread_cond_wait(&b->changed, &b->lock);
            const int done = req->done;
            pthread_mutex_unlock(&b->lock);
            if (!done)
                goto out; /* stopping: left in allocating, queued again at restart */
            const char *transient = buy_failure_transient(req->reason);
            if (!transient || bg_clock_now() + backoff > give_up)
                break;
            if (job_left_state(b, jr->id, BGB_JOB_ALLOCATING)) /* cancelled */
                break;
            /* The job's events say that it waits and why. */
            char said[192];
            snprintf(said, sizeof said,
                     "{\"market\":\"live\",\"mechanism\":\"%s\",\"contracts\":[],"
                     "\"retry\":%d,\"reason\":\"%s\",\"wait_seconds\":%.3f}",
                     bgb_mechanism_name(req->mechanism), ++retries, transient, backoff);
            (void)bgb_store_add_event(b->store, jr->id, "allocation", said, &err);
            pthread_mutex_lock(&b->lock);
            req->release = 1; /* the loop frees it (it holds no contract) */
            pthread_mutex_unlock(&b->lock);
            req = NULL;
            /* tv_nsec must stay below 1e9: a pause of 1 s or more given
             * as nanoseconds alone is EINVAL and no pause at all. */
            struct timespec pause = {(time_t)backoff,
                                     (long)((backoff - (double)(time_t)backoff) * 1e9)},
                            rest;
            while (nanosleep(&pause, &rest) != 0 && errno == EINTR)
                pause = rest;
            backoff = backoff * 2.0 > 2.0 ? 2.0 : backoff * 2.0;
        }
        if (req->reason[0]) {
            char reason[160];
            snprintf(reason, sizeof reason, "the market could not buy the job's services: %s",
                     req->reason);
            (void)bgb_store_add_event(b->store, jr->id, "allocation",
                                      "{\"market\":\"live\",\"contracts\":[],\"failed\":true}",
                                      &err);
            (void)bgb_store_transition(b->store, jr->id, live_or_fail, BGB_JOB_FAILED, reason,
                                       &terr);
            goto out;
        }
        int n = 0;
        for (int i = 0; i < req->nawards; i++) {
            const bgb_award_t *a = &req->awards[i];
            bought[n].endpoint = req->awards[i].endpoint;
            bought[n++].services = a->good == BGB_GOOD_ROTFIT  ? BGA_SERVICE_ROTFIT
                                   : a->good == BGB_GOOD_SOLVE ? BGA_SERVICE_SOLVE
                                                               : BGA_SERVICE_INTEG;
        }
        alloc = (job_alloc_t){bought, n, req};
        char json[256];
        snprintf(json, sizeof json,
                 "{\"market\":\"live\",\"mechanism\":\"%s\",\"contracts\":%d,\"spent\":%.17g,"
                 "\"latency_seconds\":%.6f}",
                 bgb_mechanism_name(req->mechanism), req->nawards, req->spent, req->latency);
        (void)bgb_store_add_event(b->store, jr->id, "allocation", json, &err);
    }
    if (bgb_store_transition(b->store, jr->id, MASK(BGB_JOB_ALLOCATING), BGB_JOB_RUNNING, NULL,
                             &err) != BG_OK)
        goto out; /* cancelled meanwhile */
    jr->allocation_latency = bg_clock_now() - t0;
    int converged = 0, stopped = 0;
    st = solve_job(b, jr, &job, dir, scene, &alloc, &converged, &stopped, &err);
    if (stopped) {
        /* Cancelled while running: no result is stored, the contracts are
         * released below. */
        char json[96];
        snprintf(json, sizeof json, "{\"cancelled\":true,\"seconds\":%.6f}",
                 bg_clock_now() - t0);
        (void)bgb_store_add_event(b->store, jr->id, "stopped", json, &terr);
    } else if (st == BG_OK) {
        (void)bgb_store_add_event(b->store, jr->id, "solved",
                                  converged ? "{\"converged\":true}" : "{\"converged\":false}",
                                  &terr);
        (void)bgb_store_transition(b->store, jr->id, MASK(BGB_JOB_RUNNING), BGB_JOB_SUCCEEDED,
                                   NULL, &terr);
    } else {
        (void)bgb_store_transition(b->store, jr->id, MASK(BGB_JOB_RUNNING), BGB_JOB_FAILED,
                                   err.message, &terr);
    }
out:
    bg_scene_destroy(&scene);
    bgb_job_release(&job);
    pthread_mutex_lock(&b->lock);
    if (req && b->loop_gone) {
        for (buy_req_t **p = &b->reqs; *p; p = &(*p)->next)
            if (*p == req) {
                *p = req->next;
                break;
            }
        free(req);
    } else if (req) {
        req->release = 1; /* the loop releases the contracts and frees it */
    }
    b->running--;
    pthread_cond_broadcast(&b->changed);
    pthread_mutex_unlock(&b->lock);
    free(jr->usage);
    free(jr);
    return NULL;
}

/* Starts a coordinator for each queued job while there is room. */
static void dispatch(bgb_broker_t *b)
{
    bgb_job_t jobs[8];
    int count = 0;
    int64_t next = 0;
    bg_error_t err = BG_ERROR_INIT;
    pthread_mutex_lock(&b->lock);
    const int room = b->config.max_jobs - b->running;
    pthread_mutex_unlock(&b->lock);
    if (room <= 0)
        return;
    if (bgb_store_list(b->store, BGB_JOB_QUEUED, 0, room < 8 ? room : 8, jobs, &count, &next,
                       &err) != BG_OK)
        return;
    for (int i = 0; i < count; i++) {
        job_run_t *jr = calloc(1, sizeof *jr);
        /* Taking it out of queued here makes each job start once. */
        if (!jr || bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_QUEUED),
                                        BGB_JOB_ALLOCATING, NULL, &err) != BG_OK) {
            free(jr);
            continue;
        }
        jr->broker = b;
        memcpy(jr->id, jobs[i].id, sizeof jr->id);
        pthread_attr_t attr;
        pthread_attr_init(&attr);
        pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
        pthread_mutex_lock(&b->lock);
        b->running++;
        pthread_mutex_unlock(&b->lock);
        pthread_t t;
        if (pthread_create(&t, &attr, coordinator, jr) != 0) {
            pthread_mutex_lock(&b->lock);
            b->running--;
            pthread_mutex_unlock(&b->lock);
            (void)bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_ALLOCATING),
                                       BGB_JOB_QUEUED, NULL, &err);
            free(jr);
        }
        pthread_attr_destroy(&attr);
    }
    for (int i = 0; i < count; i++)
        bgb_job_release(&jobs[i]);
}

static void *dispatcher_main(void *arg)
{
    bgb_broker_t *b = arg;
    pthread_mutex_lock(&b->lock);
    while (!b->stopping) {
        pthread_mutex_unlock(&b->lock);
        dispatch(b);
        pthread_mutex_lock(&b->lock);
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_nsec += BROKER_POLL_MS * 1000000L;
        if (ts.tv_nsec >= 1000000000L) {
            ts.tv_sec++;
            ts.tv_nsec -= 1000000000L;
        }
        if (!b->stopping)
            pthread_cond_timedwait(&b->changed, &b->lock, &ts);
    }
    pthread_mutex_unlock(&b->lock);
    return NULL;
}

/* --------------------------------------------------------- ZeroMQ loop */

static bg_status router_send(void *ctx, const uint8_t *identity, size_t identity_len,
                             const bga_frame_t *frames, int nframes)
{
    bgb_broker_t *b = ctx;
    if (zmq_send(b->router, identity, identity_len, ZMQ_SNDMORE | ZMQ_DONTWAIT) < 0)
        return BG_ERR_IO;
    for (int i = 0; i < nframes; i++)
        if (zmq_send(b->router, frames[i].data, frames[i].size,
                     (i + 1 < nframes ? ZMQ_SNDMORE : 0) | ZMQ_DONTWAIT) < 0)
            return BG_ERR_IO;
    return BG_OK;
}

/* done_fn: the outcome into the request, and the coordinator woken. */
static void on_bought(void *ctx, const bgb_outcome_t *o)
{
    buy_req_t *r = ctx;
    r->reason[0] = '\0';
    if (o->reason)
        snprintf(r->reason, sizeof r->reason, "%s", o->reason);
    r->nawards = 0;
    for (int i = 0; !o->reason && i < o->nawards && i < BROKER_MAX_AWARDS; i++)
        r->awards[r->nawards++] = o->awards[i];
    r->spent = o->spent;
    r->latency = o->latency;
}

/* contract_fn: every contract is a "contract" event of its job. */
static void on_contract(void *ctx, const bgb_contract_t *row)
{
    bgb_broker_t *b = ctx;
    char id[BGB_JOB_ID_SIZE] = "";
    pthread_mutex_lock(&b->lock);
    for (const buy_req_t *r = b->reqs; r; r = r->next)
        if (r->job == row->job)
            memcpy(id, r->id, sizeof id);
    pthread_mutex_unlock(&b->lock);
    if (!id[0])
        return;
    /* Built with cJSON: an agent's name is the agent's own text. */
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return;
    cJSON_AddStringToObject(o, "service", bgb_good_name(row->good));
    cJSON_AddNumberToObject(o, "agent_id", row->seller);
    cJSON_AddStringToObject(o, "agent", row->seller_name);
    cJSON_AddStringToObject(o, "mechanism", bgb_mechanism_name((bgb_mechanism)row->mechanism));
    cJSON_AddNumberToObject(o, "quantity", row->quantity);
    cJSON_AddNumberToObject(o, "price", row->price);
    cJSON_AddNumberToObject(o, "buyer_limit", row->buyer_limit);
    cJSON_AddNumberToObject(o, "seller_limit", row->seller_limit);
    cJSON_AddNumberToObject(o, "time", row->time);
    char *json = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    if (!json)
        return;
    bg_error_t err = BG_ERROR_INIT;
    (void)bgb_store_add_event(b->store, id, "contract", json, &err);
    free(json);
}

/* The directory, recent prices and the CSVs as text for the REST thread. */
static char *csv_text(const bgb_market_t *m, int contracts)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f)
        return NULL;
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = contracts ? bgb_market_write_contracts_csv(m, f, &err)
                                   : bgb_market_write_agents_csv(m, f, &err);
    fclose(f);
    if (st != BG_OK) {
        free(buf);
        return NULL;
    }
    return buf;
}

static void add_services(cJSON *a, unsigned services)
{
    cJSON *s = cJSON_AddArrayToObject(a, "services");
    if (services & BGA_SERVICE_ROTFIT)
        cJSON_AddItemToArray(s, cJSON_CreateString("rotation-fit"));
    if (services & BGA_SERVICE_SOLVE)
        cJSON_AddItemToArray(s, cJSON_CreateString("sparse-solve"));
    if (services & BGA_SERVICE_INTEG)
        cJSON_AddItemToArray(s, cJSON_CreateString("integration-step"));
}

static char *pool_json(const bgb_broker_config_t *c, const bgb_agent_info_t *live, size_t nlive);

static char *market_json(const bgb_market_t *m)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "market", "live");
    cJSON *prices = cJSON_AddArrayToObject(o, "prices");
    for (int mech = BGB_MECH_CENTRAL; mech <= BGB_MECH_POSTED; mech++)
        for (int g = BGB_GOOD_ROTFIT; g <= BGB_GOOD_INTEG; g++) {
            double mean = 0;
            const int n = bgb_market_recent_price(m, g, (bgb_mechanism)mech, 20, &mean);
            if (n == 0)
                continue;
            cJSON *e = cJSON_CreateObject();
            cJSON_AddStringToObject(e, "mechanism", bgb_mechanism_name((bgb_mechanism)mech));
            cJSON_AddStringToObject(e, "service", bgb_good_name(g));
            cJSON_AddNumberToObject(e, "mean_price", mean);
            cJSON_AddNumberToObject(e, "contracts", n);
            cJSON_AddItemToArray(prices, e);
        }
    char *text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return text;
}

static void publish(bgb_broker_t *b)
{
    bgb_agent_info_t *live = b->live;
    size_t n = bgb_market_agents(b->market, live, BGB_MARKET_MAX_AGENTS);
    if (n > BGB_MARKET_MAX_AGENTS)
        n = BGB_MARKET_MAX_AGENTS;
    int alive = 0;
    for (size_t i = 0; i < n; i++)
        alive += live[i].alive != 0;
    char *aj = pool_json(&b->config, live, n), *mj = market_json(b->market);
    char *cc = csv_text(b->market, 1), *ac = csv_text(b->market, 0);
    pthread_mutex_lock(&b->lock);
    if (b->market_agents == 0 && alive > 0)
        pthread_cond_broadcast(&b->changed); /* jobs waiting for a first agent */
    b->market_agents = alive;
    if (aj && mj && cc && ac) {
        char *old[4] = {b->agents_json, b->market_json, b->contracts_csv, b->agents_csv};
        b->agents_json = aj, b->market_json = mj, b->contracts_csv = cc, b->agents_csv = ac;
        aj = old[0], mj = old[1], cc = old[2], ac = old[3];
    }
    pthread_mutex_unlock(&b->lock);
    free(aj), free(mj), free(cc), free(ac);
}

/* bgb_rest's view: copies of the loop's latest snapshots (REST threads). */
static char *rest_view(void *ctx, int what)
{
    bgb_broker_t *b = ctx;
    pthread_mutex_lock(&b->lock);
    const char *src = what == BGB_REST_VIEW_AGENTS      ? b->agents_json
                      : what == BGB_REST_VIEW_MARKET    ? b->market_json
                      : what == BGB_REST_VIEW_CONTRACTS ? b->contracts_csv
                                                        : b->agents_csv;
    char *copy = src ? strdup(src) : NULL;
    pthread_mutex_unlock(&b->lock);
    return copy;
}

/* Rotation-fit is split over the live rotation-fit sellers, keeping one
 * agent for the sparse solve when there are several, and over no more of
 * them than the grid's hosts sell cores: the parts run at once, a core
 * each. */
static int rotfit_sellers(const bgb_market_t *m, bgb_agent_info_t *live)
{
    size_t n = bgb_market_agents(m, live, BGB_MARKET_MAX_AGENTS);
    int count = 0, agents = 0, hosts = 0;
    double cores = 0;
    for (size_t i = 0; i < n && i < BGB_MARKET_MAX_AGENTS; i++) {
        agents += live[i].alive != 0;
        count += live[i].alive && (live[i].services & BGA_SERVICE_ROTFIT);
        if (live[i].alive && live[i].resource) {
            hosts++;
            cores += live[i].cores;
        }
    }
    if (count > 1 && agents <= count)
        count--;
    if (hosts && count > (int)cores)
        count = (int)cores;
    return count < 1 ? 1 : count > BROKER_MAX_ROTFIT ? BROKER_MAX_ROTFIT : count;
}

/* Submits new requests and releases ended ones (loop thread). */
static void serve_requests(bgb_broker_t *b, double now)
{
    for (;;) {
        buy_req_t *todo = NULL, **link = NULL;
        pthread_mutex_lock(&b->lock);
        for (buy_req_t **p = &b->reqs; *p; p = &(*p)->next)
            if (!(*p)->submitted || (*p)->release) {
                todo = *p;
                link = p;
                break;
            }
        if (todo && todo->release)
            *link = todo->next;
        pthread_mutex_unlock(&b->lock);
        if (!todo)
            return;
        if (todo->release) {
            bgb_market_release(b->market, todo->job, now);
            free(todo);
            continue;
        }
        const int n = rotfit_sellers(b->market, b->live);
        bgb_need_t needs[3] = {{BGB_GOOD_ROTFIT, (double)n, n}, {BGB_GOOD_SOLVE, 1.0, 1},
                               {BGB_GOOD_INTEG, 1.0, 1}};
        bg_error_t err = BG_ERROR_INIT;
        pthread_mutex_lock(&b->lock);
        todo->submitted = 1;
        pthread_mutex_unlock(&b->lock);
        /* The outcome may be written from inside this call: the lock is
         * not held, and `done` is set only once it is complete. */
        const bg_status st =
            bgb_market_buy(b->market, todo->job, todo->mechanism, todo->budget, needs,
                           todo->integ ? 3 : 2, now, on_bought, todo, &err);
        bgb_market_label(b->market, todo->job, todo->id);
        pthread_mutex_lock(&b->lock);
        if (st != BG_OK)
            snprintf(todo->reason, sizeof todo->reason, "%.63s", err.message);
        pthread_mutex_unlock(&b->lock);
    }
}

/* The only thread that touches the ROUTER socket and the market. */
static void *loop_main(void *arg)
{
    bgb_broker_t *b = arg;
    double next_tick = 0, next_publish = 0;
    for (;;) {
        pthread_mutex_lock(&b->lock);
        const int stop = b->stopping;
        pthread_mutex_unlock(&b->lock);
        if (stop)
            break;
        double now = bg_clock_now();
        serve_requests(b, now);
        if (now >= next_tick)
            next_tick = bgb_market_tick(b->market, now);
        if (now >= next_publish) {
            publish(b);
            next_publish = now + 0.1;
        }
        /* Requests whose outcome came in since: wake their coordinators. */
        pthread_mutex_lock(&b->lock);
        int woke = 0;
        for (buy_req_t *r = b->reqs; r; r = r->next)
            if (r->submitted && !r->done && (r->nawards > 0 || r->reason[0])) {
                r->done = 1;
                woke = 1;
            }
        if (woke)
            pthread_cond_broadcast(&b->changed);
        pthread_mutex_unlock(&b->lock);
        int wait_ms = (int)((next_tick - now) * 1e3);
        wait_ms = wait_ms < 0 ? 0 : wait_ms > BROKER_LOOP_MS ? BROKER_LOOP_MS : wait_ms;
        zmq_pollitem_t item = {b->router, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, wait_ms) <= 0 || !(item.revents & ZMQ_POLLIN))
            continue;
        for (int k = 0; k < 64; k++) {
            zmq_pollitem_t again = {b->router, 0, ZMQ_POLLIN, 0};
            if (k > 0 && (zmq_poll(&again, 1, 0) <= 0 || !(again.revents & ZMQ_POLLIN)))
                break;
            bga_received_t r;
            bg_error_t err = BG_ERROR_INIT;
            if (bga_recv(b->router, 1, &r, &err) != BG_OK)
                break;
            bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
            bga_received_view(&r, views);
            if (r.total == r.count) {
                (void)bgb_market_on_frames(b->market, zmq_msg_data(&r.route),
                                           zmq_msg_size(&r.route), views, r.count, bg_clock_now(),
                                           &err);
            } else {
                char why[96];
                snprintf(why, sizeof why, "market message: %d frames, at most %d", r.total,
                         BGA_WIRE_MAX_FRAMES);
                (void)bgb_market_refuse(b->market, zmq_msg_data(&r.route), zmq_msg_size(&r.route),
                                        why, &err);
            }
            bga_received_close(&r);
            pthread_mutex_lock(&b->lock);
            b->agent_messages++;
            pthread_mutex_unlock(&b->lock);
        }
        next_tick = 0; /* a message may have changed what is due */
    }
    pthread_mutex_lock(&b->lock);
    b->loop_gone = 1;
    pthread_cond_broadcast(&b->changed);
    pthread_mutex_unlock(&b->lock);
    return NULL;
}

/* ----------------------------------------------------------- lifecycle */

/* GET /v1/agents: the fixed pool (source "config") and the market's
 * directory (source "market", with slots and prices). */
static char *pool_json(const bgb_broker_config_t *c, const bgb_agent_info_t *live, size_t nlive)
{
    cJSON *arr = cJSON_CreateArray();
    for (int i = 0; arr && i < c->agent_count; i++) {
        cJSON *a = cJSON_CreateObject();
        cJSON_AddStringToObject(a, "endpoint", c->agents[i].endpoint);
        add_services(a, c->agents[i].services);
        cJSON_AddStringToObject(a, "source", "config");
        cJSON_AddItemToArray(arr, a);
    }
    for (size_t i = 0; arr && i < nlive; i++) {
        const bgb_agent_info_t *l = &live[i];
        cJSON *a = cJSON_CreateObject();
        cJSON_AddNumberToObject(a, "id", l->id);
        cJSON_AddStringToObject(a, "name", l->name);
        cJSON_AddStringToObject(a, "endpoint", l->endpoint);
        add_services(a, l->services);
        cJSON_AddStringToObject(a, "source", "market");
        cJSON_AddBoolToObject(a, "alive", l->alive != 0);
        cJSON_AddNumberToObject(a, "slots", l->slots);
        cJSON_AddNumberToObject(a, "free_slots", l->free_slots);
        cJSON *p = cJSON_AddObjectToObject(a, "prices");
        for (int g = BGB_GOOD_ROTFIT; g <= BGB_GOOD_INTEG; g++)
            if (l->price[g] > 0)
                cJSON_AddNumberToObject(p, bgb_good_name(g), l->price[g]);
        cJSON_AddItemToArray(arr, a);
    }
    char *text = arr ? cJSON_PrintUnformatted(arr) : NULL;
    cJSON_Delete(arr);
    return text;
}

/* Jobs a previous broker process left half done (see the header). */
static bg_status recover(bgb_broker_t *b, bg_error_t *err)
{
    for (int state = BGB_JOB_ALLOCATING; state <= BGB_JOB_RUNNING; state++) {
        for (;;) {
            bgb_job_t jobs[16];
            int count = 0;
            int64_t next = 0;
            bg_status st = bgb_store_list(b->store, state, 0, 16, jobs, &count, &next, err);
            if (st != BG_OK)
                return st;
            for (int i = 0; i < count && st == BG_OK; i++) {
                st = state == BGB_JOB_ALLOCATING
                         ? bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_ALLOCATING),
                                                BGB_JOB_QUEUED,
                                                "the broker restarted before the job's services "
                                                "were bought: queued again",
                                                err)
                         : bgb_store_transition(b->store, jobs[i].id, MASK(BGB_JOB_RUNNING),
                                                BGB_JOB_FAILED,
                                                "the broker restarted while the job was running",
                                                err);
            }
            for (int i = 0; i < count; i++)
                bgb_job_release(&jobs[i]);
            if (st != BG_OK)
                return st;
            if (count == 0)
                break;
        }
    }
    return BG_OK;
}

bg_status bgb_broker_start(const bgb_broker_config_t *config, bgb_broker_t **out,
                           bg_error_t *err)
{
    *out = NULL;
    bgb_broker_t *b = calloc(1, sizeof *b);
    if (!b)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker");
    pthread_mutex_init(&b->lock, NULL);
    pthread_cond_init(&b->changed, NULL);
    bg_status st = copy_config(&b->config, config, err);
    if (st != BG_OK) {
        pthread_mutex_destroy(&b->lock);
        pthread_cond_destroy(&b->changed);
        free(b);
        return st;
    }
    char *agents_json = NULL;
    char path[BROKER_PATH_MAX + 32];
    snprintf(path, sizeof path, "%s/jobs", b->config.state_dir);
    if ((st = make_dir(path, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/broker.sqlite", b->config.state_dir);
    if ((st = bgb_store_open(path, &b->store, err)) != BG_OK || (st = recover(b, err)) != BG_OK)
        goto out;
    b->zmq = zmq_ctx_new();
    b->router = b->zmq ? zmq_socket(b->zmq, ZMQ_ROUTER) : NULL;
    if (!b->router) {
        st = bg_error_set(err, BG_ERR_IO, "cannot create the agents' ZeroMQ socket: %s",
                          zmq_strerror(zmq_errno()));
        goto out;
    }
    const int linger = 0;
    zmq_setsockopt(b->router, ZMQ_LINGER, &linger, sizeof linger);
    size_t len = sizeof b->endpoint;
    if (zmq_bind(b->router, b->config.endpoint) != 0 ||
        zmq_getsockopt(b->router, ZMQ_LAST_ENDPOINT, b->endpoint, &len) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "endpoint: cannot bind %s: %s", b->config.endpoint,
                          zmq_strerror(zmq_errno()));
        goto out;
    }
    snprintf(path, sizeof path, "%s/uploads", b->config.state_dir);
    if ((st = make_dir(path, err)) != BG_OK)
        goto out;
    agents_json = pool_json(&b->config, NULL, 0);
    const bgb_rest_config_t rc = {.agents_json = agents_json,.address = b->config.address,
                                  .port = (uint16_t)b->config.port,
                                  .max_body = (size_t)b->config.max_body,
                                  .max_vertices = b->config.max_vertices,
                                  .max_elements = b->config.max_elements,
                                  .work_dir = path,
                                  .name = b->config.name,
                                  .market = "live",
                                  .view = rest_view,
                                  .view_ctx = b};
    if ((st = bgb_rest_start(&rc, b->store, &b->rest, err)) != BG_OK)
        goto out;
    bgb_market_config_t mc = b->config.market;
    mc.name = b->config.name;
    const bgb_market_io_t io = {b, router_send};
    if (!(b->live = calloc(BGB_MARKET_MAX_AGENTS, sizeof *b->live))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the agents' directory");
        goto out;
    }
    if ((st = bgb_market_new(&mc, &io, &b->market, err)) != BG_OK)
        goto out;
    bgb_market_on_contract(b->market, on_contract, b);
    if (pthread_create(&b->loop, NULL, loop_main, b) != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot start the broker's loop thread");
        goto out;
    }
    b->loop_started = 1;
    if (pthread_create(&b->dispatcher, NULL, dispatcher_main, b) != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot start the broker's dispatcher");
        goto out;
    }
    b->dispatcher_started = 1;
out:
    free(agents_json);
    if (st != BG_OK)
        bgb_broker_stop(&b);
    *out = b;
    return st;
}

uint16_t bgb_broker_rest_port(const bgb_broker_t *b)
{
    return bgb_rest_port(b->rest);
}

const char *bgb_broker_endpoint(const bgb_broker_t *b)
{
    return b->endpoint;
}

void bgb_broker_stop(bgb_broker_t **bp)
{
    bgb_broker_t *b = bp ? *bp : NULL;
    if (!b)
        return;
    bgb_rest_stop(&b->rest);
    pthread_mutex_lock(&b->lock);
    b->stopping = 1;
    pthread_cond_broadcast(&b->changed);
    pthread_mutex_unlock(&b->lock);
    if (b->dispatcher_started)
        pthread_join(b->dispatcher, NULL);
    if (b->loop_started)
        pthread_join(b->loop, NULL);
    pthread_mutex_lock(&b->lock);
    while (b->running > 0)
        pthread_cond_wait(&b->changed, &b->lock);
    pthread_mutex_unlock(&b->lock);
    while (b->reqs) {
        buy_req_t *r = b->reqs;
        b->reqs = r->next;
        free(r);
    }
    bgb_market_destroy(&b->market);
    free(b->live);
    free(b->agents_json);
    free(b->market_json);
    free(b->contracts_csv);
    free(b->agents_csv);
    if (b->router)
        zmq_close(b->router);
    if (b->zmq)
        zmq_ctx_term(b->zmq);
    bgb_store_destroy(&b->store);
    bgb_broker_config_release(&b->config);
    pthread_mutex_destroy(&b->lock);
    pthread_cond_destroy(&b->changed);
    free(b);
    *bp = NULL;
}
