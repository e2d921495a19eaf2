#include "cmd_client.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bg_mesh_io.h"
#include "bgb_client.h"
#include "cmd.h"
#include "cmd_job.h"

#define CLIENT_MESH_PATH_MAX 8192
#define CLIENT_URL_MAX 1024
#define CLIENT_DEFAULT_PAGE 100
#define CLIENT_MAX_PAGE 500

#define BROKER_HELP                                                                                \
    "  --broker URL        the broker (default $" BG_CMD_BROKER_ENV ", else the local grid's\n"    \
    "                      broker recorded by `biotgrid grid up`, else " BG_CMD_DEFAULT_BROKER     \
    ")\n"                                                                                          \
    "  --token T           the bearer token (default $" BG_CMD_TOKEN_ENV ", else the local\n"       \
    "                      grid's, written by `biotgrid grid up`; `biotgrid token create`\n"     \
    "                      makes more)\n"                                                         \
    "  --cacert FILE       trust an https broker whose certificate chains to FILE\n"             \
    "                      (default $" BG_CMD_CACERT_ENV ", else the system's CAs)\n"             \
    "  --json              print the broker's JSON document instead of text\n"

const char bg_cmd_submit_usage[] =
    "usage: biotgrid submit SCENE.json [--mechanism M] [--budget B] [--deadline S] [--wait]\n"
    "                       [--out DIR] [options]\n"
    "Submits the scene and every mesh or data file it names (found as `solve` finds\n"
    "them) to the broker, and prints the new job's id.\n"
    "  --mechanism M       central, catallactic or posted (default: the broker's, central)\n"
    "  --budget B          money the job may spend (default: the broker's, 1000)\n"
    "  --deadline S        seconds after submission by which the job must have its\n"
    "                      services, a lost agent's replacement too (default: none: the\n"
    "                      broker asks the market for 120 s after each loss)\n"
    "  --wait              follow the job's events until it ends (a progress bar on a\n"
    "                      terminal, plain lines otherwise); exit 1 unless it succeeded\n"
    "  --out DIR           with --wait (implied): download the result's files into DIR\n"
    "  --idempotency-key K a resubmit with the same key returns the same job\n"
    "  --mesh-path DIR     also look for the scene's files in DIR (repeatable; then\n"
    "                      $" BG_CMD_MESH_PATH_ENV ")\n" BROKER_HELP;

const char bg_cmd_jobs_usage[] =
    "usage: biotgrid jobs [--state S] [--limit N] [--page N] [options]\n"
    "Lists the broker's jobs, oldest first.\n"
    "  --state S           only jobs in state S (queued, allocating, running, succeeded,\n"
    "                      failed, cancelled)\n"
    "  --limit N           at most N jobs (default: all)\n"
    "  --page N            jobs per request, 1..500 (default 100)\n" BROKER_HELP;

const char bg_cmd_status_usage[] = "usage: biotgrid status ID [options]\n"
                                   "Shows a job: its state, mechanism, budget, plan and why it "
                                   "failed or was cancelled.\n" BROKER_HELP;

const char bg_cmd_result_usage[] =
    "usage: biotgrid result ID --out DIR [options]\n"
    "Downloads a succeeded job's result files into DIR (created "
    "if needed).\n"
    "  --out DIR           the folder to write the files to\n" BROKER_HELP;

const char bg_cmd_cancel_usage[] = "usage: biotgrid cancel ID [options]\n"
                                   "Cancels a job that has not ended.\n" BROKER_HELP;

const char bg_cmd_agents_usage[] = "usage: biotgrid agents [options]\n"
                                   "Lists the agents registered with the broker.\n" BROKER_HELP;

const char bg_cmd_market_usage[] =
    "usage: biotgrid market [options]\n"
    "Shows the broker's recent prices per good and mechanism.\n" BROKER_HELP;

/* The options a command accepts beyond --broker, --json and --help. */
enum {
    OPT_MECHANISM = 1 << 0,
    OPT_BUDGET = 1 << 1,
    OPT_WAIT = 1 << 2,
    OPT_KEY = 1 << 3,
    OPT_MESH_PATH = 1 << 4,
    OPT_STATE = 1 << 5,
    OPT_LIMIT = 1 << 6,
    OPT_PAGE = 1 << 7,
    OPT_OUT = 1 << 8,
    OPT_OUT_REQUIRED = 1 << 9, /* result needs --out; submit takes it optionally */
    OPT_DEADLINE = 1 << 10,
};

typedef struct options {
    const char *command;
    const char *usage;
    const char *broker, *token, *cacert;
    int json, wait;
    const char *mechanism;
    double budget, deadline;
    const char *key;
    char mesh_path[CLIENT_MESH_PATH_MAX];
    const char *state;
    long limit, page;
    const char *out;
    const char *positional; /* SCENE or ID */
} options_t;

static int bad_usage(const options_t *o, const char *fmt, const char *what)
{
    fprintf(stderr, "biotgrid %s: ", o->command);
    fprintf(stderr, fmt, what);
    fputc('\n', stderr);
    fputs(o->usage, stderr);
    return -1;
}

static int parse_count(const options_t *o, const char *name, const char *text, long max, long *out)
{
    char *end = NULL;
    errno = 0;
    const long v = strtol(text, &end, 10);
    if (errno || !end || *end || end == text || v < 1 || v > max) {
        fprintf(stderr, "biotgrid %s: %s: '%s' must be an integer in 1..%ld\n", o->command, name,
                text, max);
        return -1;
    }
    *out = v;
    return 0;
}

/* 1: --help printed, 0: go on, -1: bad usage (message printed). positional: 1 if required. */
static int parse(int argc, char **argv, unsigned allowed, int positional, const char *what,
                 options_t *o)
{
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(o->usage, stdout);
            return 1;
        }
        if (strcmp(a, "--json") == 0) {
            o->json = 1;
            continue;
        }
        if (strcmp(a, "--wait") == 0 && (allowed & OPT_WAIT)) {
            o->wait = 1;
            continue;
        }
        static const struct {
            const char *name;
            unsigned bit;
        } valued[] = {{"--broker", 0},
                      {"--token", 0},
                      {"--cacert", 0},
                      {"--mechanism", OPT_MECHANISM},
                      {"--budget", OPT_BUDGET},
                      {"--deadline", OPT_DEADLINE},
                      {"--idempotency-key", OPT_KEY},
                      {"--mesh-path", OPT_MESH_PATH},
                      {"--state", OPT_STATE},
                      {"--limit", OPT_LIMIT},
                      {"--page", OPT_PAGE},
                      {"--out", OPT_OUT}};
        int matched = -1;
        for (size_t k = 0; k < sizeof valued / sizeof valued[0]; k++)
            if (strcmp(a, valued[k].name) == 0 && (!valued[k].bit || (allowed & valued[k].bit)))
                matched = (int)k;
        if (matched >= 0) {
            if (i + 1 >= argc)
                return bad_usage(o, "%s needs a value", a);
            const char *v = argv[++i];
            const unsigned bit = valued[matched].bit;
            if (bit == 0 && strcmp(a, "--token") == 0) {
                o->token = v;
            } else if (bit == 0 && strcmp(a, "--cacert") == 0) {
                o->cacert = v;
            } else if (bit == 0) {
                o->broker = v;
            } else if (bit == OPT_MECHANISM) {
                if (!bg_cmd_job_mechanism_ok(v))
                    return bad_usage(o,
                                     "--mechanism: unknown mechanism '%s' (expected central, "
                                     "catallactic or posted)",
                                     v);
                o->mechanism = v;
            } else if (bit == OPT_BUDGET) {
                if (bg_cmd_job_budget(v, &o->budget) != 0)
                    return bad_usage(o, "--budget: '%s' is not a positive number", v);
            } else if (bit == OPT_DEADLINE) {
                if (bg_cmd_job_budget(v, &o->deadline) != 0)
                    return bad_usage(o, "--deadline: '%s' is not a positive number of seconds", v);
            } else if (bit == OPT_KEY) {
                o->key = v;
            } else if (bit == OPT_MESH_PATH) {
                if (bg_cmd_mesh_path_add(o->mesh_path, sizeof o->mesh_path, v) != 0)
                    return bad_usage(o, "--mesh-path: too many folders%s", "");
            } else if (bit == OPT_STATE) {
                o->state = v;
            } else if (bit == OPT_LIMIT) {
                if (parse_count(o, "--limit", v, 1000000000L, &o->limit) != 0)
                    return -1;
            } else if (bit == OPT_PAGE) {
                if (parse_count(o, "--page", v, CLIENT_MAX_PAGE, &o->page) != 0)
                    return -1;
            } else {
                o->out = v;
            }
            continue;
        }
        if (a[0] == '-' && a[1])
            return bad_usage(o, "unknown option '%s'", a);
        if (!positional || o->positional)
            return bad_usage(o, "unexpected argument '%s'", a);
        o->positional = a;
    }
    if (positional && !o->positional)
        return bad_usage(o, "missing %s", what);
    if ((allowed & OPT_OUT_REQUIRED) && !o->out)
        return bad_usage(o, "missing --out DIR%s", "");
    if ((allowed & OPT_MESH_PATH) &&
        bg_cmd_mesh_path_finish(o->mesh_path, sizeof o->mesh_path) != 0)
        return bad_usage(o, "$%s is too long", BG_CMD_MESH_PATH_ENV);
    return 0;
}

static int fail(const options_t *o, const bg_error_t *err)
{
    fprintf(stderr, "biotgrid %s: %s\n", o->command, err->message);
    return bg_cmd_job_exit_for(err->status);
}

/* Parses the options and opens the client; returns -1 to go on, else the exit status. */
static int start(int argc, char **argv, unsigned allowed, int positional, const char *what,
                 const char *usage, options_t *o, bgb_client_t **client)
{
    memset(o, 0, sizeof *o);
    o->command = argv[0];
    o->usage = usage;
    const int p = parse(argc, argv, allowed, positional, what, o);
    if (p != 0)
        return p > 0 ? BG_EXIT_OK : BG_EXIT_BAD_INPUT;
    char url[CLIENT_URL_MAX];
    const char *env = getenv(BG_CMD_BROKER_ENV);
    if (o->broker)
        snprintf(url, sizeof url, "%s", o->broker);
    else if (env && env[0])
        snprintf(url, sizeof url, "%s", env);
    else if (!bg_cmd_grid_broker(bg_cmd_grid_dir(NULL), url, sizeof url))
        snprintf(url, sizeof url, "%s", BG_CMD_DEFAULT_BROKER);
    char token[BG_CMD_TOKEN_MAX];
    bg_cmd_token_find(o->token, bg_cmd_grid_dir(NULL), token, sizeof token);
    const bgb_client_config_t config = {
        .url = url, .token = token, .cacert = bg_cmd_cacert_find(o->cacert)};
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_client_new(&config, client, &err) != BG_OK)
        return fail(o, &err);
    return -1;
}

/* Prints a document as JSON (--json) and frees it. */
static int print_json(cJSON *doc)
{
    char *text = cJSON_Print(doc);
    cJSON_Delete(doc);
    if (!text) {
        fputs("biotgrid: out of memory\n", stderr);
        return BG_EXIT_FAILED;
    }
    puts(text);
    free(text);
    return BG_EXIT_OK;
}

static void format_time(double t, char *out, size_t size)
{
    const time_t s = isfinite(t) ? (time_t)t : 0;
    struct tm tm;
    if (!gmtime_r(&s, &tm) || !strftime(out, size, "%Y-%m-%dT%H:%M:%SZ", &tm))
        snprintf(out, size, "?");
}

static void print_job(const cJSON *job)
{
    const char *id = bg_cmd_string_of(job, "id"), *state = bg_cmd_string_of(job, "state");
    const char *mechanism = bg_cmd_string_of(job, "mechanism"), *reason = bg_cmd_string_of(job, "reason");
    printf("job %s: %s\n", id ? id : "?", state ? state : "?");
    printf("  mechanism %s, budget %g\n", mechanism ? mechanism : "?", bg_cmd_number_of(job, "budget"));
    char created[32], updated[32];
    format_time(bg_cmd_number_of(job, "created"), created, sizeof created);
    format_time(bg_cmd_number_of(job, "updated"), updated, sizeof updated);
    printf("  submitted %s, updated %s\n", created, updated);
    const cJSON *plan = cJSON_GetObjectItemCaseSensitive(job, "plan");
    const cJSON *services = cJSON_GetObjectItemCaseSensitive(plan, "services");
    const cJSON *s;
    cJSON_ArrayForEach(s, services)
    {
        const char *name = bg_cmd_string_of(s, "service"), *detail = bg_cmd_string_of(s, "detail");
        printf("  plan: %s%s%s\n", name ? name : "?", detail ? ": " : "", detail ? detail : "");
    }
    if (reason)
        printf("  reason: %s\n", reason);
}

/* ------------------------------------------------------------- submit */

/*
 * Follows the job until it ends (cmd_job: plain lines on stdout, or the bar
 * on a terminal; nothing with --json), then prints its outcome once; exit
 * 0 only if it succeeded.
 */
static int wait_for(const options_t *o, bgb_client_t *client, const char *id)
{
    const int tty = isatty(STDERR_FILENO);
    const bg_cmd_job_view_t view = {o->json ? NULL : stdout, tty && !o->json};
    bg_error_t err = BG_ERROR_INIT;
    cJSON *job = NULL;
    if (bg_cmd_job_wait(client, id, &view, &job, &err) != BG_OK)
        return fail(o, &err);
    const int ok = bg_cmd_job_succeeded(job);
    if (o->json)
        return print_json(job) == BG_EXIT_OK && ok ? BG_EXIT_OK : BG_EXIT_FAILED;
    bg_cmd_job_outcome(stdout, job, view.bar);
    if (ok && !o->out)
        printf("  its files: biotgrid result %s --out DIR\n", id);
    cJSON_Delete(job);
    return ok ? BG_EXIT_OK : BG_EXIT_FAILED;
}

static int download_result(const options_t *o, bgb_client_t *client, const char *id, int report);

int bg_cmd_submit(int argc, char **argv)
{
    options_t o;
    bgb_client_t *client = NULL;
    int rc = start(argc, argv,
                   OPT_MECHANISM | OPT_BUDGET | OPT_DEADLINE | OPT_WAIT | OPT_KEY | OPT_MESH_PATH |
                       OPT_OUT,
                   1,
                   "SCENE.json", bg_cmd_submit_usage, &o, &client);
    if (rc >= 0)
        return rc;
    const bgb_client_submit_t submit = {.scene_path = o.positional,
                                        .search_path = o.mesh_path,
                                        .mechanism = o.mechanism,
                                        .budget = o.budget,
                                        .deadline = o.deadline,
                                        .idempotency_key = o.key};
    cJSON *job = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_client_submit_job(client, &submit, &job, &err) != BG_OK) {
        rc = fail(&o, &err);
        goto out;
    }
    const char *id = bg_cmd_string_of(job, "id");
    if (!id) {
        fprintf(stderr, "biotgrid submit: the broker's answer has no job id\n");
        rc = BG_EXIT_FAILED;
        goto out;
    }
    char job_id[64];
    snprintf(job_id, sizeof job_id, "%s", id);
    if (o.wait || o.out) {
        if (!o.json)
            printf("submitted job %s to %s\n", job_id, bgb_client_url(client));
        rc = wait_for(&o, client, job_id);
        if (rc == BG_EXIT_OK && o.out)
            /* With --json, stdout holds the job document alone. */
            rc = download_result(&o, client, job_id, !o.json);
    } else if (o.json) {
        rc = print_json(job);
        job = NULL;
    } else {
        printf("submitted job %s (%s, mechanism %s, budget %g) to %s\n", job_id,
               bg_cmd_string_of(job, "state") ? bg_cmd_string_of(job, "state") : "?",
               bg_cmd_string_of(job, "mechanism") ? bg_cmd_string_of(job, "mechanism") : "?",
               bg_cmd_number_of(job, "budget"), bgb_client_url(client));
        rc = BG_EXIT_OK;
    }
out:
    cJSON_Delete(job);
    bgb_client_destroy(&client);
    return rc;
}

/* --------------------------------------------------------------- jobs */

int bg_cmd_jobs(int argc, char **argv)
{
    options_t o;
    bgb_client_t *client = NULL;
    int rc = start(argc, argv, OPT_STATE | OPT_LIMIT | OPT_PAGE, 0, NULL, bg_cmd_jobs_usage, &o,
                   &client);
    if (rc >= 0)
        return rc;
    cJSON *all = cJSON_CreateArray();
    cJSON *page = NULL;
    char cursor[64] = "";
    long listed = 0;
    const long page_size = o.page ? o.page : CLIENT_DEFAULT_PAGE;
    bg_error_t err = BG_ERROR_INIT;
    rc = BG_EXIT_OK;
    if (!all) {
        fputs("biotgrid jobs: out of memory\n", stderr);
        rc = BG_EXIT_FAILED;
        goto out;
    }
    for (;;) {
        long want = page_size;
        if (o.limit && o.limit - listed < want)
            want = o.limit - listed;
        if (bgb_client_list_jobs(client, o.state, (int)want, cursor[0] ? cursor : NULL, &page,
                                 &err) != BG_OK) {
            rc = fail(&o, &err);
            goto out;
        }
        cJSON *jobs = cJSON_GetObjectItemCaseSensitive(page, "jobs");
        while (cJSON_IsArray(jobs) && jobs->child && (!o.limit || listed < o.limit)) {
            cJSON_AddItemToArray(all, cJSON_DetachItemViaPointer(jobs, jobs->child));
            listed++;
        }
        const char *next = bg_cmd_string_of(page, "next");
        if (!next || (o.limit && listed >= o.limit))
            break;
        if (strlen(next) >= sizeof cursor || strcmp(next, cursor) == 0) {
            fprintf(stderr, "biotgrid jobs: the broker's cursor '%s' does not advance\n", next);
            rc = BG_EXIT_FAILED;
            goto out;
        }
        snprintf(cursor, sizeof cursor, "%s", next);
        cJSON_Delete(page);
        page = NULL;
    }
    if (o.json) {
        cJSON *doc = cJSON_CreateObject();
        if (doc && cJSON_AddItemToObject(doc, "jobs", all)) {
            all = NULL;
            rc = print_json(doc);
        } else {
            cJSON_Delete(doc);
            rc = BG_EXIT_FAILED;
        }
        goto out;
    }
    printf("%-18s %-10s %-11s %10s  %s\n", "ID", "STATE", "MECHANISM", "BUDGET", "SUBMITTED");
    const cJSON *job;
    cJSON_ArrayForEach(job, all)
    {
        char created[32];
        format_time(bg_cmd_number_of(job, "created"), created, sizeof created);
        const char *id = bg_cmd_string_of(job, "id"), *state = bg_cmd_string_of(job, "state");
        const char *mechanism = bg_cmd_string_of(job, "mechanism");
        printf("%-18s %-10s %-11s %10g  %s\n", id ? id : "?", state ? state : "?",
               mechanism ? mechanism : "?", bg_cmd_number_of(job, "budget"), created);
    }
    printf("%ld job%s\n", listed, listed == 1 ? "" : "s");
out:
    cJSON_Delete(all);
    cJSON_Delete(page);
    bgb_client_destroy(&client);
    return rc;
}

/* ------------------------------------------------------ status, cancel */

typedef bg_status (*job_call_fn)(bgb_client_t *, const char *, cJSON **, bg_error_t *);

static int job_command(int argc, char **argv, const char *usage, job_call_fn call, const char *done)
{
    options_t o;
    bgb_client_t *client = NULL;
    int rc = start(argc, argv, 0, 1, "ID", usage, &o, &client);
    if (rc >= 0)
        return rc;
    cJSON *job = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (call(client, o.positional, &job, &err) != BG_OK) {
        rc = fail(&o, &err);
    } else if (o.json) {
        rc = print_json(job);
        job = NULL;
    } else {
        if (done)
            printf("%s %s\n", done, o.positional);
        print_job(job);
        rc = BG_EXIT_OK;
    }
    cJSON_Delete(job);
    bgb_client_destroy(&client);
    return rc;
}

int bg_cmd_status(int argc, char **argv)
{
    return job_command(argc, argv, bg_cmd_status_usage, bgb_client_get_job, NULL);
}

int bg_cmd_cancel(int argc, char **argv)
{
    return job_command(argc, argv, bg_cmd_cancel_usage, bgb_client_cancel_job, "cancelled");
}

/* -------------------------------------------------------------- result */

/* Downloads job id's result files into o->out; with report, prints what it
 * wrote (the file list document with --json). */
static int download_result(const options_t *o, bgb_client_t *client, const char *id, int report)
{
    cJSON *doc = NULL;
    int count = 0;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_cmd_job_download(client, id, o->out, report && !o->json ? stdout : NULL, &doc, &count,
                            &err) != BG_OK)
        return fail(o, &err);
    int rc = BG_EXIT_OK;
    if (report && o->json) {
        cJSON_AddStringToObject(doc, "out", o->out);
        rc = print_json(doc);
        doc = NULL;
    } else if (report) {
        printf("job %s: %d file%s in %s\n", id, count, count == 1 ? "" : "s", o->out);
    }
    cJSON_Delete(doc);
    return rc;
}

int bg_cmd_result(int argc, char **argv)
{
    options_t o;
    bgb_client_t *client = NULL;
    int rc = start(argc, argv, OPT_OUT | OPT_OUT_REQUIRED, 1, "ID", bg_cmd_result_usage, &o,
                   &client);
    if (rc >= 0)
        return rc;
    rc = download_result(&o, client, o.positional, 1);
    bgb_client_destroy(&client);
    return rc;
}

/* ------------------------------------------------------ agents, market */

/* A document as indented "key: value" lines, for the commands whose schema the broker owns. */
static void print_tree(const cJSON *item, int depth)
{
    const cJSON *child;
    cJSON_ArrayForEach(child, item)
    {
        printf("%*s", 2 * depth, "");
        if (child->string)
            printf("%s:", child->string);
        else if (cJSON_IsArray(item))
            printf("-");
        if (cJSON_IsObject(child) || cJSON_IsArray(child)) {
            putchar('\n');
            print_tree(child, depth + 1);
            continue;
        }
        char *text = cJSON_PrintUnformatted(child);
        printf(" %s\n", text ? text : "?");
        free(text);
    }
}

typedef bg_status (*doc_call_fn)(bgb_client_t *, cJSON **, bg_error_t *);

static int document_command(int argc, char **argv, const char *usage, doc_call_fn call)
{
    options_t o;
    bgb_client_t *client = NULL;
    int rc = start(argc, argv, 0, 0, NULL, usage, &o, &client);
    if (rc >= 0)
        return rc;
    cJSON *doc = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (call(client, &doc, &err) != BG_OK) {
        rc = fail(&o, &err);
    } else if (o.json) {
        rc = print_json(doc);
        doc = NULL;
    } else {
        print_tree(doc, 0);
        rc = BG_EXIT_OK;
    }
    cJSON_Delete(doc);
    bgb_client_destroy(&client);
    return rc;
}

int bg_cmd_agents(int argc, char **argv)
{
    return document_command(argc, argv, bg_cmd_agents_usage, bgb_client_agents);
}

int bg_cmd_market(int argc, char **argv)
{
    return document_command(argc, argv, bg_cmd_market_usage, bgb_client_market);
}
