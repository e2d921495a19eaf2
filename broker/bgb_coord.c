/* syscall(SYS_gettid): the reference thread lowers its own priority. */
#define _DEFAULT_SOURCE
#include "bgb_coord.h"

#include <cJSON.h>
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include "bg_clock.h"
#include "bg_file.h"
#include "bg_prepare.h"
#include "bg_report.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "bga_backend.h"
#include "bga_service.h"
#include "bgb_jobreport.h"
#include "bgb_jobscene.h"
#include "bg_run.h"
#include "bgb_watch.h"

#define COORD_PATH_MAX 4096
/* At most one progress event per job this often (each is a commit). */
#define COORD_PROGRESS_SECONDS 0.25
/* How long an agent keeps a job's state without hearing from it. */
#define COORD_AGENT_LEASE_MS 600000
#define COORD_MAX_RESULT_FILE ((size_t)1 << 30)
/* Queued jobs taken per look at the queue. */
#define COORD_DISPATCH_BATCH 8
/* Agents a job may lose (and replace) in all. */
#define COORD_MAX_FAULTS 16
#define MASK(s) (1u << (s))

struct bgb_coord {
    const bgb_config_t *config; /* borrowed */
    bgb_store_t *store;         /* borrowed */
    bgb_loop_t *loop;           /* borrowed */
    pthread_t dispatcher;
    int dispatcher_started;
    pthread_mutex_t lock;
    pthread_cond_t work; /* the dispatcher's: a job was queued, a coordinator ended, stop */
    pthread_cond_t idle; /* bgb_coord_stop's: a coordinator ended */
    int notified;        /* under lock: look at the queue */
    int stopping;        /* under lock */
    int halting;         /* under lock: the stop grace ran out */
    int running;         /* under lock: coordinators alive */
};

/* One job's coordinator. */
typedef struct job_run {
    bgb_coord_t *coord;
    char id[BGB_JOB_ID_SIZE];
    char what[BGB_JOB_ID_SIZE + 8]; /* "job <id>" */
    const bg_scene_t *scene;        /* borrowed while it runs */
    double tolerance;
    int max_iterations;
    double last_progress;
    double allocation_latency; /* seconds from allocating to running */
    double used[BGB_WATCH_SERVICES];
    bgb_usage_t usage;
    double fraction;    /* the job's progress at its last trace point, [0, 1] */
    double run_started; /* when its solve began (monotonic) */
} job_run_t;

static int stopping(bgb_coord_t *c)
{
    pthread_mutex_lock(&c->lock);
    const int s = c->stopping;
    pthread_mutex_unlock(&c->lock);
    return s;
}

/* 1 while the store says job `id` is in `state`, or cannot be read (a
 * transient read error must not stop a job); 0 once it left it. */
static int job_in_state(bgb_coord_t *c, const char *id, bgb_job_state state)
{
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t e = BG_ERROR_INIT;
    const int left = bgb_store_get(c->store, id, &job, &e) == BG_OK && job.state != state;
    bgb_job_release(&job);
    return !left;
}

/* The broker's stop grace ran out: running jobs stop at their next
 * basic-service call and are queued again. */
static int halting(bgb_coord_t *c)
{
    pthread_mutex_lock(&c->lock);
    const int h = c->halting;
    pthread_mutex_unlock(&c->lock);
    return h;
}

static int still_running(void *ctx)
{
    job_run_t *jr = ctx;
    return !halting(jr->coord) && job_in_state(jr->coord, jr->id, BGB_JOB_RUNNING);
}

static int still_allocating(void *ctx)
{
    job_run_t *jr = ctx;
    return !stopping(jr->coord) && job_in_state(jr->coord, jr->id, BGB_JOB_ALLOCATING);
}

/* ------------------------------------------------------------- progress */

/*
 * How much of the job is done at trace point p, in [0, 1], and its unit:
 * a dynamic job by steps, a morph by frames; a minimisation by the larger
 * of the accuracy reached (log of the relative gradient against the log of
 * the tolerance: 0 at the start, 1 at convergence) and the iterations used
 * against the cap.
 */
static double fraction_done(const job_run_t *jr, const bg_trace_point_t *p, const char **unit,
                            int *total)
{
    const bg_scene_t *s = jr->scene;
    double f = 0.0;
    if (s->task == BG_TASK_DYNAMIC) {
        *unit = "step";
        *total = s->dynamic.steps;
        f = s->dynamic.steps > 0 ? (double)p->iteration / s->dynamic.steps : 0.0;
    } else if (s->task == BG_TASK_MORPH) {
        *unit = "frame";
        *total = s->morph_frames;
        f = s->morph_frames > 0 ? (double)(p->iteration + 1) / s->morph_frames : 0.0;
    } else {
        *unit = "iteration";
        *total = jr->max_iterations;
        const double by_count =
            jr->max_iterations > 0 ? (double)p->iteration / jr->max_iterations : 0.0;
        double by_accuracy = 0.0;
        if (p->relative_gradient > 0 && jr->tolerance > 0 && jr->tolerance < 1)
            by_accuracy = log(p->relative_gradient) / log(jr->tolerance);
        f = by_count > by_accuracy ? by_count : by_accuracy;
    }
    return !(f > 0.0) ? 0.0 : f > 1.0 ? 1.0 : f;
}

static void on_progress(void *ctx, bg_method method, const bg_trace_point_t *p)
{
    job_run_t *jr = ctx;
    bgb_usage_record(&jr->usage, p->seconds, jr->used);
    const char *unit = "iteration";
    int total = 0;
    const double fraction = fraction_done(jr, p, &unit, &total);
    /* What a lost agent is paid for: the work the job kept (a minimisation's
     * accuracy can fall back at a new stage; the work done cannot). */
    if (fraction > jr->fraction)
        jr->fraction = fraction;
    const double now = bg_clock_now();
    if (now - jr->last_progress < COORD_PROGRESS_SECONDS)
        return;
    jr->last_progress = now;
    char json[640];
    char error[32] = "null";
    if (isfinite(p->error))
        snprintf(error, sizeof error, "%.17g", p->error);
    snprintf(json, sizeof json,
             "{\"method\":\"%s\",\"fraction\":%.6f,\"unit\":\"%s\",\"%s\":%d,\"of\":%d,"
             "\"iteration\":%d,\"seconds\":%.6f,\"energy\":%.17g,\"relative_gradient\":%.17g,"
             "\"error\":%s}",
             bg_method_name(method), fraction, unit, unit, p->iteration, total, p->iteration,
             p->seconds, isfinite(p->energy) ? p->energy : 0.0,
             isfinite(p->relative_gradient) ? p->relative_gradient : 0.0, error);
    bg_error_t err = BG_ERROR_INIT;
    (void)bgb_store_add_event(jr->coord->store, jr->id, "progress", json, &err);
}

/* ---------------------------------------------------------------- files */

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
static bg_status store_results(bgb_coord_t *c, const char *id, const char *dir, bg_error_t *err)
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
        char path[COORD_PATH_MAX + 512];
        snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        struct stat sb;
        if (stat(path, &sb) != 0 || !S_ISREG(sb.st_mode))
            continue;
        if (++count > BGB_STORE_MAX_FILES * 16) {
            st = bg_error_set(err, BG_ERR_LIMIT, "%s: more than %d result files", dir,
                              BGB_STORE_MAX_FILES * 16);
            break;
        }
        char *data = NULL;
        size_t size = 0;
        st = bg_file_read_all(path, COORD_MAX_RESULT_FILE, &data, &size, err);
        if (st == BG_OK) {
            const bgb_file_t f = {e->d_name, (const uint8_t *)data, size};
            st = bgb_store_put_file(c->store, id, "result", &f, err);
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

/*
 * The job's scene from the store: its input files written into DIR/input
 * (0700), then parsed against them and planned by the REST API's own
 * loader (bgb_jobscene), then prepared. A job cancelled (or a broker
 * stopping) while its mesh is built is not prepared: *stopped is set and
 * BG_OK returned, the scene left unprepared.
 */
static bg_status load_scene(job_run_t *jr, const bgb_job_t *job, const char *dir,
                            bgb_jobscene_t *js, int *stopped, bg_error_t *err)
{
    bgb_coord_t *c = jr->coord;
    *stopped = 0;
    char input[COORD_PATH_MAX + 16];
    snprintf(input, sizeof input, "%s/input", dir);
    bg_status st = bg_file_make_directories_mode(input, 0700, err);
    input_names_t in;
    memset(&in, 0, sizeof in);
    bgb_file_t files[BGB_STORE_MAX_FILES];
    uint8_t *data[BGB_STORE_MAX_FILES] = {NULL};
    if (st == BG_OK)
        st = bgb_store_list_files(c->store, job->id, "input", collect_input, &in, err);
    if (st == BG_OK && in.overflow)
        st = bg_error_set(err, BG_ERR_LIMIT, "job %s: cannot list its input files", job->id);
    for (int i = 0; st == BG_OK && i < in.count; i++) {
        size_t n = 0;
        st = bgb_store_get_file(c->store, job->id, "input", in.names[i], &data[i], &n, err);
        files[i] = (bgb_file_t){in.names[i], data[i], n};
    }
    /* A retried job (after a restart) finds its files already there. */
    for (int i = 0; st == BG_OK && i < in.count; i++) {
        char path[COORD_PATH_MAX + BGB_STORE_MAX_FILE_NAME + 32];
        snprintf(path, sizeof path, "%s/%s", input, in.names[i]);
        unlink(path);
    }
    if (st == BG_OK)
        st = bgb_jobscene_unpack(input, files, in.count, err);
    if (st == BG_OK)
        st = bgb_jobscene_load(job->scene, job->scene_size, input, &c->config->limits, js, err);
    if (st == BG_OK && !still_allocating(jr))
        *stopped = 1;
    else if (st == BG_OK)
        st = bg_prepare_scene(js->scene, err);
    for (int i = 0; i < in.count; i++) {
        free(in.names[i]);
        free(data[i]);
    }
    return st;
}

/* -------------------------------------------------------------- faults */

static const char *buy_failure_transient(const char *reason);
static void pause_seconds(double seconds);

static double wall_clock(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* The monotonic time by which the job must have its services: its
 * deadline (seconds after its submission) when it has one, else
 * `patience` seconds from now. */
static double give_up_at(const bgb_job_t *job, double patience)
{
    const double now = bg_clock_now();
    return job->deadline > 0 ? now + (job->created + job->deadline - wall_clock())
                             : now + patience;
}

/* src into dst[0 .. cap), cut and terminated (the two are fields of one
 * record, never the same one). */
static void copy_text(char *dst, size_t cap, const char *src)
{
    const size_t n = strnlen(src, cap - 1);
    memcpy(dst, src, n);
    dst[n] = '\0';
}

/* A job event from a cJSON object (taken: deleted here). */
static void add_event(job_run_t *jr, const char *kind, cJSON *o)
{
    char *json = o ? cJSON_PrintUnformatted(o) : NULL;
    cJSON_Delete(o);
    if (!json)
        return;
    bg_error_t err = BG_ERROR_INIT;
    (void)bgb_store_add_event(jr->coord->store, jr->id, kind, json, &err);
    free(json);
}

/* Every contract a job has held: its purchase's, then each replacement's. */
#define COORD_MAX_CONTRACTS (BGB_LOOP_MAX_AWARDS + COORD_MAX_FAULTS)

/*
 * What a job's coordinator needs to replace an agent it lost (the
 * backend's recovery context): the buyer it bought with, its contracts
 * (with the market job each belongs to, the progress at which it began to
 * serve, and a lost one's settlement), which contract serves each of the
 * backend's places, the agents lost so far (left out of re-purchases)
 * and the faults for the events and the report. One thread.
 */
typedef struct coord_recovery {
    job_run_t *jr;
    const bgb_job_t *job;
    bgb_loop_buyer_t *buyer;
    bgb_mechanism mechanism;
    bgb_award_t awards[COORD_MAX_CONTRACTS];
    uint64_t market_job[COORD_MAX_CONTRACTS];
    double from[COORD_MAX_CONTRACTS];
    int settled[COORD_MAX_CONTRACTS];
    double paid[COORD_MAX_CONTRACTS];
    int ncontracts;
    int place_contract[BGA_BACKEND_MAX_AGENTS]; /* −1: none */
    double need[BGA_BACKEND_MAX_AGENTS];        /* the place's whole need: its first quantity */
    uint32_t lost[BGB_LOOP_MAX_EXCLUDE];
    int nlost;
    bgb_fault_t faults[COORD_MAX_FAULTS];
    int nfaults;
} coord_recovery_t;

/* Money the job has committed: every contract at its price, a lost one at
 * what it was settled for. */
static double committed(const coord_recovery_t *r)
{
    double sum = 0.0;
    for (int i = 0; i < r->ncontracts; i++)
        sum += r->settled[i] ? r->paid[i] : r->awards[i].quantity * r->awards[i].price;
    return sum;
}

static bgb_fault_t *fault_of(coord_recovery_t *r, const char *endpoint)
{
    for (int i = r->nfaults - 1; i >= 0; i--)
        if (strcmp(r->faults[i].lost_endpoint, endpoint) == 0)
            return &r->faults[i];
    return NULL;
}

/* The lost contract c is settled for the work the job kept since it
 * began: a contract sells its quantity for the rest of the job from the
 * progress `from` at which it began, so it delivered the share (now −
 * from) / (1 − from) of it. Records the fault. */
static bgb_fault_t *settle_lost(coord_recovery_t *r, const bga_backend_loss_t *loss, int c)
{
    job_run_t *jr = r->jr;
    bgb_fault_t *f = &r->faults[r->nfaults++];
    memset(f, 0, sizeof *f);
    const bgb_award_t *a = &r->awards[c];
    const double fraction = jr->fraction < 0 ? 0 : jr->fraction > 1 ? 1 : jr->fraction;
    snprintf(f->service, sizeof f->service, "%s", loss->service);
    copy_text(f->lost, sizeof f->lost, a->name);
    snprintf(f->lost_endpoint, sizeof f->lost_endpoint, "%s", loss->endpoint);
    snprintf(f->why, sizeof f->why, "%s", loss->why);
    f->seconds = bg_clock_now() - jr->run_started;
    f->fraction = fraction;
    const double rest = 1.0 - r->from[c];
    double delivered = rest > 0 ? a->quantity * (fraction - r->from[c]) / rest : a->quantity;
    delivered = delivered < 0 ? 0 : delivered > a->quantity ? a->quantity : delivered;
    const double paid = bgb_loop_settle_lost(r->buyer, r->market_job[c], a->agent, a->good,
                                             delivered);
    r->settled[c] = 1;
    r->paid[c] = paid >= 0 ? paid : a->quantity * a->price; /* unsettled: the whole price */
    f->settled_quantity = paid >= 0 ? delivered : a->quantity;
    f->settled_paid = r->paid[c];
    if (r->nlost < BGB_LOOP_MAX_EXCLUDE)
        r->lost[r->nlost++] = a->agent;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "service", f->service);
    cJSON_AddStringToObject(o, "agent", f->lost);
    cJSON_AddStringToObject(o, "endpoint", f->lost_endpoint);
    cJSON_AddStringToObject(o, "reason", f->why);
    cJSON_AddNumberToObject(o, "fraction", f->fraction);
    cJSON_AddNumberToObject(o, "seconds", f->seconds);
    cJSON_AddNumberToObject(o, "time", wall_clock());
    cJSON *s = cJSON_AddObjectToObject(o, "settled");
    cJSON_AddNumberToObject(s, "quantity", f->settled_quantity);
    cJSON_AddNumberToObject(s, "of", a->quantity);
    cJSON_AddNumberToObject(s, "price", a->price);
    cJSON_AddNumberToObject(s, "paid", f->settled_paid);
    add_event(jr, "agent_lost", o);
    return f;
}

/*
 * The backend lost the agent in place loss->agent: its contract is
 * settled pro rata, the service is bought again under the job's mechanism
 * with what is left of the budget, from any seller but the agents the job
 * lost: a whole contract of the place's need (a contract is a lease of its
 * seller's cores and memory whatever part of the job is left, and a seller
 * prices it so), asking again with backoff while the market answers
 * "no seller" or "timeout" until the job's deadline; the replacement's
 * endpoint and the job id its contract covers go back to the backend.
 */
static bg_status coord_replace(void *ctx, const bga_backend_loss_t *loss, char *endpoint,
                               size_t cap, uint64_t *job_base, bg_error_t *err)
{
    coord_recovery_t *r = ctx;
    job_run_t *jr = r->jr;
    const double noticed = bg_clock_now();
    const int c = loss->agent >= 0 && loss->agent < BGA_BACKEND_MAX_AGENTS
                      ? r->place_contract[loss->agent]
                      : -1;
    if (c < 0 || r->nfaults == COORD_MAX_FAULTS || r->ncontracts == COORD_MAX_CONTRACTS)
        return bg_error_set(err, BG_ERR_LIMIT, "%s; the job cannot replace it (%d agents lost)",
                            loss->why, r->nfaults);
    bgb_fault_t *f = settle_lost(r, loss, c);
    const bgb_award_t *lost = &r->awards[c];
    const double quantity = r->need[loss->agent];
    const double give_up = give_up_at(r->job, BGB_COORD_BUY_PATIENCE);
    double backoff = 0.1;
    bgb_loop_purchase_t p;
    bg_error_t berr = BG_ERROR_INIT;
    for (;; f->retries++) {
        memset(&p, 0, sizeof p);
        snprintf(p.label, sizeof p.label, "%s", jr->id);
        p.mechanism = r->mechanism;
        p.budget = r->job->budget - committed(r);
        p.replace = 1;
        p.good = lost->good;
        p.quantity = quantity;
        memcpy(p.exclude, r->lost, (size_t)r->nlost * sizeof *r->lost);
        p.nexclude = r->nlost;
        if (!(p.budget > 0)) {
            snprintf(p.reason, sizeof p.reason, "budget");
            break;
        }
        if (bgb_loop_buy(r->buyer, &p, still_running, jr, &berr) != BG_OK)
            return bg_error_set(err, BG_ERR_CONFLICT, "%s; the job stopped while its %s was "
                                "bought again", loss->why, loss->service);
        if (!p.reason[0] && p.nawards == 1)
            break;
        const char *transient = buy_failure_transient(p.reason);
        if (!transient || bg_clock_now() + backoff > give_up || !still_running(jr))
            break;
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "service", loss->service);
        cJSON_AddNumberToObject(o, "retry", f->retries + 1);
        cJSON_AddStringToObject(o, "reason", transient);
        cJSON_AddNumberToObject(o, "wait_seconds", backoff);
        add_event(jr, "rebuy", o);
        pause_seconds(backoff);
        backoff = backoff * 2.0 > 2.0 ? 2.0 : backoff * 2.0;
    }
    if (p.reason[0] || p.nawards != 1) {
        const char *why = p.reason[0] ? p.reason : "no award";
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "service", loss->service);
        cJSON_AddStringToObject(o, "reason", why);
        cJSON_AddBoolToObject(o, "failed", 1);
        add_event(jr, "rebuy", o);
        return bg_error_set(err, BG_ERR_NOT_FOUND,
                            "agent %s (%s) was lost and no seller could be found %s: %s",
                            lost->name[0] ? lost->name : loss->endpoint, loss->service,
                            r->job->deadline > 0 ? "before the job's deadline"
                                                 : "within the broker's patience",
                            why);
    }
    const int n = r->ncontracts++;
    r->awards[n] = p.awards[0];
    r->market_job[n] = p.job;
    r->from[n] = f->fraction;
    r->place_contract[loss->agent] = n;
    const bgb_award_t *a = &r->awards[n];
    copy_text(f->agent, sizeof f->agent, a->name);
    copy_text(f->endpoint, sizeof f->endpoint, a->endpoint);
    f->price = a->price;
    f->quantity = a->quantity;
    f->bought_after = bg_clock_now() - noticed;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "service", loss->service);
    cJSON_AddStringToObject(o, "lost", f->lost);
    cJSON_AddStringToObject(o, "agent", a->name);
    cJSON_AddStringToObject(o, "endpoint", a->endpoint);
    cJSON_AddStringToObject(o, "mechanism", bgb_mechanism_name(r->mechanism));
    cJSON_AddNumberToObject(o, "quantity", a->quantity);
    cJSON_AddNumberToObject(o, "price", a->price);
    cJSON_AddNumberToObject(o, "cost", a->quantity * a->price);
    cJSON_AddNumberToObject(o, "spent", committed(r));
    cJSON_AddNumberToObject(o, "budget", r->job->budget);
    cJSON_AddNumberToObject(o, "retries", f->retries);
    cJSON_AddNumberToObject(o, "seconds", f->bought_after);
    cJSON_AddNumberToObject(o, "time", wall_clock());
    add_event(jr, "rebought", o);
    if (strlen(a->endpoint) >= cap)
        return bg_error_set(err, BG_ERR_LIMIT, "the replacement's endpoint is too long");
    snprintf(endpoint, cap, "%s", a->endpoint);
    *job_base = p.job;
    return BG_OK;
}

static void coord_resumed(void *ctx, const bga_backend_loss_t *loss, const char *endpoint,
                          double seconds)
{
    coord_recovery_t *r = ctx;
    bgb_fault_t *f = fault_of(r, loss->endpoint);
    if (f)
        f->resumed_after = seconds;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "service", loss->service);
    cJSON_AddStringToObject(o, "lost", f ? f->lost : loss->endpoint);
    cJSON_AddStringToObject(o, "agent", f ? f->agent : endpoint);
    cJSON_AddStringToObject(o, "endpoint", endpoint);
    cJSON_AddNumberToObject(o, "seconds", seconds);
    cJSON_AddNumberToObject(o, "time", wall_clock());
    add_event(r->jr, "resumed", o);
}

static void coord_late(void *ctx, const char *endpoint, int64_t count)
{
    coord_recovery_t *r = ctx;
    bgb_fault_t *f = fault_of(r, endpoint);
    if (f)
        f->late_answers += count;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "agent", f ? f->lost : "");
    cJSON_AddStringToObject(o, "endpoint", endpoint);
    cJSON_AddNumberToObject(o, "count", (double)count);
    cJSON_AddStringToObject(o, "outcome", "discarded");
    add_event(r->jr, "late_answer", o);
}

/* ------------------------------------------------------------- solving */

/*
 * A scene's Newton reference solved in process in a thread of its own
 * while the run goes on the agents: it only measures the run's error
 * column, so the agents need not wait for it (`solve` solves it first;
 * here its time overlaps the run's set-up and iterations). The run keeps
 * the positions of the trace points it could not yet measure and they are
 * measured once both are done, with the same arithmetic, so the column is
 * the sequential one to the bit; a progress event before the reference
 * is ready says "error": null.
 *
 * Ownership: the job's coordinator thread makes it (reference_start) and
 * always joins and frees it (reference_finish) before solve_job returns,
 * so no thread outlives its job. The reference thread owns watch and its
 * solver objects (CHOLMOD's common among them: nothing is shared with the
 * run but the read-only scene) and hands result, ref, st and err over by
 * setting done under lock; abandon (under lock) stops it at its next
 * service call when the run failed; a cancel or the broker's halt stops it
 * as it stops the run.
 */
typedef struct coord_reference {
    job_run_t *jr;
    const bg_scene_t *scene;
    bgb_watch_t watch; /* the reference thread's */
    pthread_t thread;
    pthread_mutex_t lock;
    pthread_cond_t ready;
    int done;    /* under lock: result, ref, st and err are final */
    int abandon; /* under lock: the run failed, the reference is not wanted */
    bg_solve_result_t result;
    const double *ref; /* result.q once done and st is BG_OK */
    bg_status st;
    bg_error_t err;
} coord_reference_t;

static int reference_may_go_on(void *ctx)
{
    coord_reference_t *r = ctx;
    pthread_mutex_lock(&r->lock);
    const int abandoned = r->abandon;
    pthread_mutex_unlock(&r->lock);
    return !abandoned && still_running(r->jr);
}

/* How much nicer than the coordinator the reference thread runs. The run
 * is a chain of round trips between the coordinator and the agents on the
 * same cores, each hop waiting for a core: a reference at the same
 * priority delays every hop, so it takes the cycles the run leaves. On
 * Linux a thread's nice value is its own (POSIX says the process's; there
 * this is a no-op or lowers the process, which only costs time). */
#define COORD_REFERENCE_NICE 5

static void *reference_main(void *arg)
{
    coord_reference_t *r = arg;
#ifdef SYS_gettid
    const id_t self = (id_t)syscall(SYS_gettid);
    errno = 0;
    const int nice_now = getpriority(PRIO_PROCESS, self);
    if (errno == 0)
        (void)setpriority(PRIO_PROCESS, self, nice_now + COORD_REFERENCE_NICE);
#endif
    bg_solve_result_t result = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const double *ref = NULL;
    const double t0 = bg_clock_now();
    const bg_status st = bg_run_reference(r->scene, &r->watch.backend, &result, &ref, &err);
    /* The job's timeline shows when the reference ended against the run's
     * progress events (the store takes events from any thread). */
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "seconds", bg_clock_now() - t0);
    cJSON_AddNumberToObject(o, "since_run_start", bg_clock_now() - r->jr->run_started);
    cJSON_AddBoolToObject(o, "ok", st == BG_OK);
    add_event(r->jr, "reference", o);
    pthread_mutex_lock(&r->lock);
    r->result = result;
    r->ref = ref;
    r->st = st;
    r->err = err;
    r->done = 1;
    pthread_cond_broadcast(&r->ready);
    pthread_mutex_unlock(&r->lock);
    return NULL;
}

/* bg_solve_options_t.reference_ready over a coord_reference_t. */
static const double *reference_ready(void *ctx, int wait)
{
    coord_reference_t *r = ctx;
    pthread_mutex_lock(&r->lock);
    while (wait && !r->done)
        pthread_cond_wait(&r->ready, &r->lock);
    const double *ref = r->done && r->st == BG_OK ? r->ref : NULL;
    pthread_mutex_unlock(&r->lock);
    return ref;
}

/* Starts jr's reference thread into *out; NULL (and no thread) when it
 * cannot: the caller then solves the reference itself. */
static void reference_start(job_run_t *jr, const bg_scene_t *scene, coord_reference_t **out)
{
    *out = NULL;
    coord_reference_t *r = calloc(1, sizeof *r);
    if (!r)
        return;
    r->jr = jr;
    r->scene = scene;
    bgb_watch_init(&r->watch, reference_may_go_on, r, jr->what, NULL, NULL);
    if (pthread_mutex_init(&r->lock, NULL) != 0) {
        free(r);
        return;
    }
    if (pthread_cond_init(&r->ready, NULL) != 0) {
        pthread_mutex_destroy(&r->lock);
        free(r);
        return;
    }
    if (pthread_create(&r->thread, NULL, reference_main, r) != 0) {
        pthread_cond_destroy(&r->ready);
        pthread_mutex_destroy(&r->lock);
        free(r);
        return;
    }
    *out = r;
}

/*
 * Ends *rp (NULL: nothing) after the run that ended with st: abandons the
 * reference if the run failed, joins its thread, fills the run's pending
 * errors, frees it. Returns the job's status: the run's failure first,
 * then the reference's. *cancelled: the reference was stopped by the
 * job's cancel or the broker's halt (not by abandon).
 */
static bg_status reference_finish(coord_reference_t **rp, bg_status st, const bg_scene_t *scene,
                                  bg_solve_result_t *run, int *cancelled, bg_error_t *err)
{
    coord_reference_t *r = *rp;
    *cancelled = 0;
    if (!r)
        return st;
    *rp = NULL;
    pthread_mutex_lock(&r->lock);
    if (st != BG_OK)
        r->abandon = 1;
    const int abandoned = r->abandon;
    pthread_mutex_unlock(&r->lock);
    pthread_join(r->thread, NULL);
    *cancelled = r->watch.stopped && !abandoned;
    if (st == BG_OK && r->st != BG_OK) {
        st = r->st;
        if (err)
            *err = r->err;
    } else if (st == BG_OK) {
        bg_static_fill_errors(run, r->ref, (size_t)scene->mesh->nv * (size_t)scene->mesh->dim);
    }
    bg_solve_result_release(&r->result);
    pthread_cond_destroy(&r->ready);
    pthread_mutex_destroy(&r->lock);
    free(r);
    return st;
}

/* The agents a job computes on: the awards it bought, or the fixed pool. */
typedef struct job_alloc {
    const bgb_config_agent_t *agents;
    int count;
    const bgb_loop_purchase_t *bought; /* NULL: the fixed pool, nothing bought */
    bgb_loop_buyer_t *buyer;           /* what bought it (buys a lost agent's service again) */
} job_alloc_t;

/* The agents for the report, with what each did. role[i]: -1 not used, -2
 * the sparse-solve agent, -3 the integration-step agent, k ≥ 0 the k-th
 * rotation-fit agent. */
static int agent_lines(const job_alloc_t *alloc, const int *role, const bga_backend_t *backend,
                       bg_report_agent_t *out)
{
    const int nrotfit = bga_backend_agents(backend) - 1;
    for (int i = 0; i < alloc->count; i++) {
        bg_report_agent_t *r = &out[i];
        memset(r, 0, sizeof *r);
        r->endpoint = alloc->agents[i].endpoint;
        r->service = alloc->agents[i].services == BGA_SERVICE_INTEG ? "integration-step"
                                                                    : "several services";
        if (role[i] == -1)
            continue;
        bga_agent_usage_t u;
        if (role[i] == -3)
            (void)bga_backend_integ_usage(backend, &u);
        else
            u = bga_backend_usage(backend, role[i] == -2 ? nrotfit : role[i]);
        r->endpoint = u.endpoint; /* a replaced agent's place: the agent that finished it */
        r->service = u.service;
        r->calls = u.traffic.requests;
        r->contacted = r->calls > 0;
        r->bytes_sent = u.traffic.bytes_sent;
        r->bytes_received = u.traffic.bytes_received;
        r->compute_seconds = u.traffic.agent_seconds;
        r->encode_seconds = u.traffic.encode_seconds;
        r->wait_seconds = u.traffic.wait_seconds;
    }
    return alloc->count;
}

/*
 * Runs the job on its agents into dir; the store gets its results and
 * trace. *stopped: the job was cancelled during the solve.
 */
static bg_status solve_job(job_run_t *jr, const bgb_job_t *job, const char *dir,
                           const bgb_jobscene_t *js, const job_alloc_t *alloc, int *converged,
                           int *stopped, bg_error_t *err)
{
    bgb_coord_t *c = jr->coord;
    const bg_scene_t *scene = js->scene;
    bga_backend_t *remote = NULL;
    coord_recovery_t *rec = NULL;
    bg_solve_result_t run = BG_SOLVE_RESULT_INIT, reference = BG_SOLVE_RESULT_INIT;
    coord_reference_t *alongside = NULL; /* the reference's thread, while it may run */
    int reference_cancelled = 0;
    char *trace = NULL;
    double *money = NULL;
    bg_status st;
    char path[COORD_PATH_MAX + 96];
    bgb_watch_t local_watch, remote_watch;
    bgb_watch_init(&local_watch, still_running, jr, jr->what, NULL, NULL);
    bgb_watch_init(&remote_watch, still_running, jr, jr->what, NULL, NULL);

    /* Every rotation-fit agent but a dedicated sparse-solve one. */
    const char *rotfit[BGB_CONFIG_MAX_AGENTS], *solver = NULL;
    int role[BGB_CONFIG_MAX_AGENTS], nrotfit = 0, s = -1;
    const bgb_config_agent_t *a = alloc->agents;
    for (int i = 0; i < alloc->count; i++) {
        role[i] = -1;
        if ((a[i].services & BGA_SERVICE_SOLVE) && (s < 0 || a[i].services == BGA_SERVICE_SOLVE))
            s = s >= 0 && a[s].services == BGA_SERVICE_SOLVE ? s : i;
    }
    for (int i = 0; i < alloc->count; i++)
        if (i != s && (a[i].services & BGA_SERVICE_ROTFIT)) {
            role[i] = nrotfit;
            rotfit[nrotfit++] = a[i].endpoint;
        }
    if (nrotfit == 0 && s >= 0 && (a[s].services & BGA_SERVICE_ROTFIT)) {
        role[s] = 0;
        rotfit[nrotfit++] = a[s].endpoint;
    }
    if (s < 0 || nrotfit == 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "the job's agents serve no %s",
                          s < 0 ? "sparse-solve" : "rotation-fit");
        goto out;
    }
    if (role[s] == -1)
        role[s] = -2;
    solver = a[s].endpoint;
    const bga_backend_config_t bc = {rotfit,
                                     nrotfit,
                                     solver,
                                     c->config->agent_timeout_ms,
                                     COORD_AGENT_LEASE_MS,
                                     alloc->bought ? alloc->bought->job : 0,
                                     bgb_loop_curve(c->loop)};
    if ((st = bga_backend_new(&bc, &remote, err)) != BG_OK)
        goto out;
    /* The time loop's state goes to the job's integration-step agent; a
     * static job never opens it, so never contacts that agent. */
    for (int i = 0; i < alloc->count; i++)
        if (role[i] == -1 && (a[i].services & BGA_SERVICE_INTEG)) {
            if ((st = bga_backend_set_integ(remote, a[i].endpoint, err)) != BG_OK)
                goto out;
            role[i] = -3;
            break;
        }
    bga_backend_set_liveness(remote, c->config->agent_liveness_ms / 5,
                             c->config->agent_liveness_ms);
    /* A bought job replaces a lost agent (the fixed pool has no market to
     * buy from): each of the backend's places knows its contract. */
    if (alloc->bought && alloc->buyer && c->config->agent_recovery) {
        if (!(rec = calloc(1, sizeof *rec))) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the job's recovery");
            goto out;
        }
        *rec = (coord_recovery_t){.jr = jr, .job = job, .buyer = alloc->buyer,
                                  .mechanism = alloc->bought->mechanism};
        for (int p = 0; p < BGA_BACKEND_MAX_AGENTS; p++)
            rec->place_contract[p] = -1;
        for (int i = 0; i < alloc->bought->nawards && i < BGB_LOOP_MAX_AWARDS; i++) {
            rec->awards[i] = alloc->bought->awards[i];
            rec->market_job[i] = alloc->bought->job;
            rec->ncontracts++;
        }
        for (int i = 0; i < alloc->count && i < rec->ncontracts; i++) {
            const int place = role[i] >= 0 ? role[i]
                              : role[i] == -2 ? nrotfit
                              : role[i] == -3 ? nrotfit + 1
                                              : -1;
            if (place < 0)
                continue;
            rec->place_contract[place] = i;
            rec->need[place] = rec->awards[i].quantity;
        }
        const bga_backend_recovery_t recovery = {coord_replace, coord_resumed, coord_late, rec};
        bga_backend_set_recovery(remote, &recovery);
    }
    jr->run_started = bg_clock_now();
    /* The reference (in process, as `solve` computes it) and the run both
     * stop between service calls once the job is cancelled. */
    bgb_watch_init(&remote_watch, still_running, jr, jr->what, bga_backend_services(remote),
                   jr->used);
    const double *ref = NULL;
    /* A staged (continuation) run merges its stages' traces, which the
     * pending rows would not follow: its reference comes first, as before. */
    if (bg_run_reference_solves(scene) && !bg_static_continues(scene, scene->method))
        reference_start(jr, scene, &alongside);
    if (!alongside &&
        (st = bg_run_reference(scene, &local_watch.backend, &reference, &ref, err)) != BG_OK)
        goto out;
    const bg_run_options_t ro = {.method = scene->method,
                                 .tolerance = jr->tolerance,
                                 .max_iterations = jr->max_iterations,
                                 .frames_prefix = "",
                                 .progress = on_progress,
                                 .progress_ctx = jr,
                                 .backend = &remote_watch.backend,
                                 .reference_ready = alongside ? reference_ready : NULL,
                                 .reference_ctx = alongside};
    st = bg_run_method(scene, &ro, ref, dir, &run, err);
    st = reference_finish(&alongside, st, scene, &run, &reference_cancelled, err);
    if (st != BG_OK)
        goto out;
    *converged = run.converged;
    (void)bga_backend_late_answers(remote); /* what has come in is in the report */
    bg_report_agent_t lines[BGB_CONFIG_MAX_AGENTS];
    const int nlines = agent_lines(alloc, role, remote, lines);
    char paths[2 * COORD_PATH_MAX + 64];
    if (!(money = calloc((size_t)run.trace_count + 1, sizeof *money))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the money curve");
        goto out;
    }
    /* The contracts as they stand: with a replacement, every one the job
     * held, a lost one at the work it was settled for. */
    const bgb_loop_purchase_t *bought = alloc->bought;
    bgb_award_t held[COORD_MAX_CONTRACTS];
    int nheld = bought ? bought->nawards : -1;
    double spent = bought ? bought->spent : 0.0;
    if (rec) {
        nheld = rec->ncontracts;
        for (int i = 0; i < nheld; i++) {
            held[i] = rec->awards[i];
            if (rec->settled[i] && held[i].price > 0)
                held[i].quantity = rec->paid[i] / held[i].price;
        }
        spent = committed(rec);
    }
    const bgb_award_t *awards = rec ? held : bought ? bought->awards : NULL;
    bgb_jobreport_money(&jr->usage, &run, awards, nheld > 0 ? nheld : 0, money);
    snprintf(path, sizeof path, "%s/report.json", dir);
    if ((st = bg_report_write_agents(path, scene, &js->plan, &run, 1, lines, nlines, err)) !=
            BG_OK ||
        (st = bgb_jobreport_add_market(path, job->mechanism, job->budget, awards, nheld, spent,
                                       jr->allocation_latency, money, run.trace_count, err)) !=
            BG_OK ||
        (st = bgb_jobreport_add_faults(path, rec ? rec->faults : NULL, rec ? rec->nfaults : 0,
                                       err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/error-vs-time-and-money.svg", dir);
    if ((st = bgb_jobreport_money_plot(path, scene, &run, money, err)) != BG_OK)
        goto out;
    snprintf(path, sizeof path, "%s/error-vs-time.svg", dir);
    if ((st = bg_report_write_plot(path, scene, &run, 1, err)) != BG_OK ||
        (st = bg_run_write_results(dir, scene, &run, paths, sizeof paths, err)) != BG_OK)
        goto out;
    trace = trace_json(&run);
    if (trace && (st = bgb_store_add_event(c->store, job->id, "trace", trace, err)) != BG_OK)
        goto out;
    st = store_results(c, job->id, dir, err);
out:
    *stopped = local_watch.stopped || remote_watch.stopped || reference_cancelled;
    free(money);
    free(trace);
    bg_solve_result_release(&run);
    bg_solve_result_release(&reference);
    bga_backend_destroy(&remote); /* its last read of late answers may still tell rec */
    free(rec);
    return st;
}

/* ------------------------------------------------------------- buying */

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

static void pause_seconds(double seconds)
{
    /* tv_nsec must stay below 1e9: a pause of 1 s or more given as
     * nanoseconds alone is EINVAL and no pause at all. */
    struct timespec pause = {(time_t)seconds, (long)((seconds - (double)(time_t)seconds) * 1e9)},
                    rest;
    while (nanosleep(&pause, &rest) != 0 && errno == EINTR)
        pause = rest;
}

/*
 * Buys the job's services, asking again with backoff while the market's
 * answer is transient (until the job's deadline, or for
 * BGB_COORD_BUY_PATIENCE without one). Returns 1 with *p bought, 0 when the job must end
 * here (failed, cancelled, or the broker stopping: the caller looks at
 * *failed_reason, set only for a failure to record).
 */
static int buy_services(job_run_t *jr, bgb_loop_buyer_t *buyer, const bgb_job_t *job,
                        const bgb_jobscene_t *js, bgb_loop_purchase_t *p, char *failed_reason,
                        size_t reason_size)
{
    bgb_coord_t *c = jr->coord;
    const int mech = bgb_mechanism_parse(job->mechanism);
    const double give_up = give_up_at(job, BGB_COORD_BUY_PATIENCE);
    double backoff = 0.1;
    bg_error_t err = BG_ERROR_INIT;
    for (int retries = 0;; retries++) {
        memset(p, 0, sizeof *p);
        snprintf(p->label, sizeof p->label, "%s", jr->id);
        p->mechanism = mech < 0 ? BGB_MECH_CENTRAL : (bgb_mechanism)mech;
        p->budget = job->budget;
        p->integ = bgb_jobscene_needs_integ(js);
        if (bgb_loop_buy(buyer, p, still_allocating, jr, &err) != BG_OK)
            return 0; /* cancelled, or stopping: left in allocating, queued again at restart */
        if (!p->reason[0])
            return 1;
        const char *transient = buy_failure_transient(p->reason);
        if (!job_in_state(c, jr->id, BGB_JOB_ALLOCATING))
            return 0; /* cancelled meanwhile: the loop gave the purchase up */
        if (!transient || bg_clock_now() + backoff > give_up || !still_allocating(jr))
            break;
        /* The job's events say that it waits and why. */
        char said[192];
        snprintf(said, sizeof said,
                 "{\"market\":\"live\",\"mechanism\":\"%s\",\"contracts\":[],"
                 "\"retry\":%d,\"reason\":\"%s\",\"wait_seconds\":%.3f}",
                 bgb_mechanism_name(p->mechanism), retries + 1, transient, backoff);
        (void)bgb_store_add_event(c->store, jr->id, "allocation", said, &err);
        pause_seconds(backoff);
        backoff = backoff * 2.0 > 2.0 ? 2.0 : backoff * 2.0;
    }
    snprintf(failed_reason, reason_size, "the market could not buy the job's services: %s",
             p->reason);
    (void)bgb_store_add_event(c->store, jr->id, "allocation",
                              "{\"market\":\"live\",\"contracts\":[],\"failed\":true}", &err);
    return 0;
}

/* ---------------------------------------------------------- coordinator */

static void *coordinator(void *arg)
{
    job_run_t *jr = arg;
    bgb_coord_t *c = jr->coord;
    bg_error_t err = BG_ERROR_INIT, terr = BG_ERROR_INIT;
    bgb_job_t job = BGB_JOB_INIT;
    bgb_jobscene_t js = BGB_JOBSCENE_INIT;
    bgb_loop_buyer_t *buyer = NULL;
    bgb_loop_purchase_t purchase;
    bgb_config_agent_t bought[BGB_LOOP_MAX_AWARDS];
    job_alloc_t alloc = {c->config->agents, c->config->agent_count, NULL, NULL};
    const double t0 = bg_clock_now();
    const unsigned live_or_fail = MASK(BGB_JOB_ALLOCATING) | MASK(BGB_JOB_RUNNING);
    if (bgb_store_get(c->store, jr->id, &job, &err) != BG_OK)
        goto out;
    int registered = bgb_loop_live_agents(c->loop, 0);
    if (registered == 0 && c->config->agent_count == 0) {
        /* Nobody to buy from and no fixed pool: the job waits in allocating
         * until an agent registers (a grid's agents register a moment after
         * they are up, and a job may come first), is cancelled, or the
         * broker stops. */
        (void)bgb_store_add_event(c->store, jr->id, "allocation",
                                  "{\"market\":\"live\",\"contracts\":[],\"message\":\"no agent "
                                  "is registered on the market and the broker has no configured "
                                  "agents: nothing was bought; the job waits in allocating until "
                                  "one registers\"}",
                                  &err);
        while ((registered = bgb_loop_live_agents(c->loop, 1.0)) == 0)
            if (!still_allocating(jr))
                goto out; /* cancelled, or stopping: queued again at restart */
    }
    char dir[COORD_PATH_MAX];
    snprintf(dir, sizeof dir, "%s/jobs/%s", c->config->state_dir, jr->id);
    bg_status st = bg_file_make_directories_mode(dir, 0700, &err);
    int unprepared = 0;
    if (st == BG_OK)
        st = load_scene(jr, &job, dir, &js, &unprepared, &err);
    if (st == BG_OK && (unprepared || !still_allocating(jr))) {
        /* Cancelled, or the broker stopping, during the preparation:
         * nothing is bought. */
        char json[96];
        snprintf(json, sizeof json,
                 "{\"cancelled\":true,\"during\":\"preparation\",\"seconds\":%.6f}",
                 bg_clock_now() - t0);
        if (!stopping(c))
            (void)bgb_store_add_event(c->store, jr->id, "stopped", json, &terr);
        goto out;
    }
    if (st != BG_OK) {
        (void)bgb_store_transition(c->store, jr->id, live_or_fail, BGB_JOB_FAILED, err.message,
                                   &terr);
        goto out;
    }
    jr->scene = js.scene;
    jr->tolerance = js.scene->tolerance;
    jr->max_iterations = bg_scene_max_iterations(js.scene, js.scene->method);
    if (registered == 0) {
        (void)bgb_store_add_event(c->store, jr->id, "allocation",
                                  "{\"market\":null,\"contracts\":[],\"spent\":0,\"message\":\"no "
                                  "agent is registered on the market: the job runs on the "
                                  "broker's configured agents, without contracts\"}",
                                  &err);
    } else {
        char reason[160] = "";
        if (bgb_loop_buyer_new(c->loop, &buyer, &err) != BG_OK) {
            (void)bgb_store_transition(c->store, jr->id, live_or_fail, BGB_JOB_FAILED, err.message,
                                       &terr);
            goto out;
        }
        if (!buy_services(jr, buyer, &job, &js, &purchase, reason, sizeof reason)) {
            if (reason[0])
                (void)bgb_store_transition(c->store, jr->id, live_or_fail, BGB_JOB_FAILED, reason,
                                           &terr);
            goto out;
        }
        for (int i = 0; i < purchase.nawards; i++) {
            const bgb_award_t *aw = &purchase.awards[i];
            bought[i].endpoint = purchase.awards[i].endpoint;
            bought[i].services = aw->good == BGB_GOOD_ROTFIT  ? BGA_SERVICE_ROTFIT
                                 : aw->good == BGB_GOOD_SOLVE ? BGA_SERVICE_SOLVE
                                                              : BGA_SERVICE_INTEG;
        }
        alloc = (job_alloc_t){bought, purchase.nawards, &purchase, buyer};
        char json[256];
        snprintf(json, sizeof json,
                 "{\"market\":\"live\",\"mechanism\":\"%s\",\"contracts\":%d,\"spent\":%.17g,"
                 "\"latency_seconds\":%.6f}",
                 bgb_mechanism_name(purchase.mechanism), purchase.nawards, purchase.spent,
                 purchase.latency);
        (void)bgb_store_add_event(c->store, jr->id, "allocation", json, &err);
    }
    if (bgb_store_transition(c->store, jr->id, MASK(BGB_JOB_ALLOCATING), BGB_JOB_RUNNING, NULL,
                             &err) != BG_OK)
        goto out; /* cancelled meanwhile */
    jr->allocation_latency = bg_clock_now() - t0;
    int converged = 0, stopped = 0;
    st = solve_job(jr, &job, dir, &js, &alloc, &converged, &stopped, &err);
    /* The job's contracts end here, before its end is announced: a client
     * that reads the market's log when it sees succeeded or failed finds
     * them settled (rows closed at their real end, resources paid to it). */
    const int halted = stopped && halting(c) && job_in_state(c, jr->id, BGB_JOB_RUNNING);
    if (buyer && alloc.bought && !halted)
        bgb_loop_release(buyer, alloc.bought->job);
    if (halted) {
        /* The broker stops and its grace ran out: no result is stored, the
         * job is queued again for the next broker process, which runs it
         * from its start; its stopped event is written first, while the
         * event streams are still open (the stopping loop may take a while
         * to answer the release, at out below). */
        char json[128];
        snprintf(json, sizeof json, "{\"cancelled\":false,\"broker_stopping\":true,\"seconds\":%.6f}",
                 bg_clock_now() - t0);
        (void)bgb_store_add_event(c->store, jr->id, "stopped", json, &terr);
        (void)bgb_store_transition(c->store, jr->id, MASK(BGB_JOB_RUNNING), BGB_JOB_QUEUED,
                                   "the broker stopped before the job ended (its stop grace ran "
                                   "out): queued again",
                                   &terr);
    } else if (stopped) {
        /* Cancelled while running: no result is stored, the contracts are
         * released below. */
        char json[96];
        snprintf(json, sizeof json, "{\"cancelled\":true,\"seconds\":%.6f}", bg_clock_now() - t0);
        (void)bgb_store_add_event(c->store, jr->id, "stopped", json, &terr);
    } else if (st == BG_OK) {
        (void)bgb_store_add_event(c->store, jr->id, "solved",
                                  converged ? "{\"converged\":true}" : "{\"converged\":false}",
                                  &terr);
        (void)bgb_store_transition(c->store, jr->id, MASK(BGB_JOB_RUNNING), BGB_JOB_SUCCEEDED, NULL,
                                   &terr);
    } else {
        (void)bgb_store_transition(c->store, jr->id, MASK(BGB_JOB_RUNNING), BGB_JOB_FAILED,
                                   err.message, &terr);
    }
out:
    bgb_loop_buyer_destroy(&buyer); /* releases what it bought */
    bgb_jobscene_release(&js);
    bgb_job_release(&job);
    bgb_usage_release(&jr->usage);
    free(jr);
    pthread_mutex_lock(&c->lock);
    c->running--;
    c->notified = 1; /* room again: the dispatcher looks at the queue */
    pthread_cond_broadcast(&c->idle);
    pthread_cond_signal(&c->work);
    pthread_mutex_unlock(&c->lock);
    return NULL;
}

/* ----------------------------------------------------------- dispatcher */

/* Starts a coordinator for each queued job while there is room; returns
 * the number started. */
static int dispatch(bgb_coord_t *c)
{
    bgb_job_t jobs[COORD_DISPATCH_BATCH];
    int count = 0, started = 0;
    int64_t next = 0;
    bg_error_t err = BG_ERROR_INIT;
    pthread_mutex_lock(&c->lock);
    const int room = c->config->max_jobs - c->running;
    pthread_mutex_unlock(&c->lock);
    if (room <= 0)
        return 0;
    if (bgb_store_list(c->store, BGB_JOB_QUEUED, 0,
                       room < COORD_DISPATCH_BATCH ? room : COORD_DISPATCH_BATCH, jobs, &count,
                       &next, &err) != BG_OK)
        return 0;
    for (int i = 0; i < count; i++) {
        job_run_t *jr = calloc(1, sizeof *jr);
        /* Taking it out of queued here makes each job start once. */
        if (!jr || bgb_store_transition(c->store, jobs[i].id, MASK(BGB_JOB_QUEUED),
                                        BGB_JOB_ALLOCATING, NULL, &err) != BG_OK) {
            free(jr);
            continue;
        }
        jr->coord = c;
        memcpy(jr->id, jobs[i].id, sizeof jr->id);
        snprintf(jr->what, sizeof jr->what, "job %s", jr->id);
        pthread_attr_t attr;
        pthread_attr_init(&attr);
        pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
        pthread_mutex_lock(&c->lock);
        c->running++;
        pthread_mutex_unlock(&c->lock);
        pthread_t t;
        if (pthread_create(&t, &attr, coordinator, jr) != 0) {
            pthread_mutex_lock(&c->lock);
            c->running--;
            pthread_mutex_unlock(&c->lock);
            (void)bgb_store_transition(c->store, jobs[i].id, MASK(BGB_JOB_ALLOCATING),
                                       BGB_JOB_QUEUED, NULL, &err);
            free(jr);
        } else {
            started++;
        }
        pthread_attr_destroy(&attr);
    }
    for (int i = 0; i < count; i++)
        bgb_job_release(&jobs[i]);
    /* A full batch may have left more queued jobs behind. */
    return count == COORD_DISPATCH_BATCH ? started + 1 : started;
}

static void *dispatcher_main(void *arg)
{
    bgb_coord_t *c = arg;
    pthread_mutex_lock(&c->lock);
    while (!c->stopping) {
        c->notified = 0;
        pthread_mutex_unlock(&c->lock);
        const int more = dispatch(c);
        pthread_mutex_lock(&c->lock);
        /* Sleep until told: a job queued (bgb_coord_notify), a coordinator
         * ended (room again), or stop. */
        while (!more && !c->notified && !c->stopping)
            pthread_cond_wait(&c->work, &c->lock);
    }
    pthread_mutex_unlock(&c->lock);
    return NULL;
}

bg_status bgb_coord_start(const bgb_config_t *config, bgb_store_t *store, bgb_loop_t *loop,
                          bgb_coord_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_coord_t *c = calloc(1, sizeof *c);
    if (!c)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the coordinators");
    c->config = config;
    c->store = store;
    c->loop = loop;
    pthread_mutex_init(&c->lock, NULL);
    pthread_cond_init(&c->work, NULL);
    pthread_cond_init(&c->idle, NULL);
    if (pthread_create(&c->dispatcher, NULL, dispatcher_main, c) != 0) {
        bgb_coord_stop(&c);
        return bg_error_set(err, BG_ERR_NOMEM, "cannot start the broker's dispatcher");
    }
    c->dispatcher_started = 1;
    *out = c;
    return BG_OK;
}

void bgb_coord_notify(bgb_coord_t *c)
{
    pthread_mutex_lock(&c->lock);
    c->notified = 1;
    pthread_cond_signal(&c->work);
    pthread_mutex_unlock(&c->lock);
}

void bgb_coord_drain(bgb_coord_t *c, double grace)
{
    if (!c)
        return;
    pthread_mutex_lock(&c->lock);
    c->stopping = 1;
    pthread_cond_signal(&c->work);
    pthread_mutex_unlock(&c->lock);
    if (c->dispatcher_started)
        pthread_join(c->dispatcher, NULL);
    c->dispatcher_started = 0;
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    const double whole = floor(grace);
    until.tv_sec += (time_t)whole;
    until.tv_nsec += (long)((grace - whole) * 1e9);
    if (until.tv_nsec >= 1000000000L) {
        until.tv_sec++;
        until.tv_nsec -= 1000000000L;
    }
    pthread_mutex_lock(&c->lock);
    int rc = 0;
    while (c->running > 0 && rc != ETIMEDOUT)
        rc = pthread_cond_timedwait(&c->idle, &c->lock, &until);
    /* Past the grace the rest stop at their next basic-service call
     * (each bounded by the agent timeout) and record it, before the
     * event streams are closed. */
    c->halting = c->running > 0;
    while (c->running > 0)
        pthread_cond_wait(&c->idle, &c->lock);
    pthread_mutex_unlock(&c->lock);
}

void bgb_coord_stop(bgb_coord_t **cp)
{
    bgb_coord_t *c = cp ? *cp : NULL;
    if (!c)
        return;
    pthread_mutex_lock(&c->lock);
    c->stopping = 1;
    pthread_cond_signal(&c->work);
    pthread_mutex_unlock(&c->lock);
    if (c->dispatcher_started)
        pthread_join(c->dispatcher, NULL);
    pthread_mutex_lock(&c->lock);
    while (c->running > 0)
        pthread_cond_wait(&c->idle, &c->lock);
    pthread_mutex_unlock(&c->lock);
    pthread_mutex_destroy(&c->lock);
    pthread_cond_destroy(&c->work);
    pthread_cond_destroy(&c->idle);
    free(c);
    *cp = NULL;
}
