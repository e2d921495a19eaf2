/*
 * bgb_client — the broker's REST API from the client side, over libcurl
 * (the API is described in bgb_rest.h and openapi.json). A library: it
 * prints nothing; every failure is a bg_error naming what went wrong.
 *
 * Errors. A response with an RFC 9457 problem document becomes a message
 * "<METHOD> <url>: <status> <title>: <detail> (field <field>)" and a status
 * by HTTP code: 404 BG_ERR_NOT_FOUND, 409 BG_ERR_CONFLICT, 413
 * BG_ERR_LIMIT, any other 4xx BG_ERR_INVALID, 5xx BG_ERR_IO. A broker that
 * cannot be reached is BG_ERR_IO naming the URL and how to start one; an
 * https broker whose certificate is not trusted (or does not name its
 * host) is BG_ERR_IO saying so and naming --cacert.
 * bgb_client_http_status tells the HTTP status of the last response.
 *
 * Every response body is capped (config.max_response for JSON documents,
 * config.max_file for a downloaded result file): a longer one is
 * BG_ERR_LIMIT, never an unbounded buffer.
 *
 * A handle is used by one thread at a time.
 */
#ifndef BGB_CLIENT_H
#define BGB_CLIENT_H

#include <cJSON.h>
#include <stddef.h>

#include "bg_error.h"

typedef struct bgb_client bgb_client_t;

typedef struct bgb_client_config {
    const char *url;         /* the broker's base URL, e.g. "http://127.0.0.1:8080" */
    const char *token;       /* sent as "Authorization: Bearer TOKEN" on every request;
                                NULL: none (only /healthz and /openapi.json answer then) */
    const char *cacert;      /* PEM file of the CAs an https broker's certificate must chain
                                to (e.g. its self-signed certificate); NULL: the system's */
    long connect_timeout_ms; /* 0: 5000 */
    long timeout_ms;         /* a whole request, events streams excepted; 0: 120000 */
    size_t max_response;     /* a JSON response over this is refused; 0: 16 MiB */
    size_t max_file;         /* a downloaded result file over this is refused; 0: 1 GiB */
} bgb_client_config_t;

/* Copies the configuration; caller owns *out (bgb_client_destroy). */
bg_status bgb_client_new(const bgb_client_config_t *config, bgb_client_t **out, bg_error_t *err);
/* Frees; accepts NULL and sets *client to NULL. */
void bgb_client_destroy(bgb_client_t **client);

/* The base URL in use (no trailing '/'). */
const char *bgb_client_url(const bgb_client_t *client);
/* The HTTP status of the last response (0: none, e.g. the broker was not reached). */
long bgb_client_http_status(const bgb_client_t *client);

typedef struct bgb_client_submit {
    const char *scene_path;      /* the scene file */
    const char *search_path;     /* ':'-separated mesh folders, as `solve --mesh-path` */
    const char *mechanism;       /* NULL: the broker's default */
    double budget;               /* <= 0: the broker's default */
    double deadline;             /* seconds after submission; <= 0: none */
    const char *idempotency_key; /* NULL or "": none */
    /* The job's solver settings in place of the scene file's (the broker
     * solves the scene's solver.method to its tolerance and cap), as
     * `solve --method/--tolerance/--max-iterations` does locally: */
    const char *method;          /* solver.method; NULL: the scene's */
    double tolerance;            /* solver.tolerance; <= 0: the scene's */
    int max_iterations;          /* solver.max_iterations, one cap; <= 0: the scene's */
    const char *inner;           /* solver.inner (dynamic scenes); NULL: the scene's */
} bgb_client_submit_t;

/*
 * Packs a submission as the API expects: {"scene": {...}, "files":
 * [{"name", "base64"}], "mechanism", "budget", "deadline"}. Every file the scene names
 * (mesh, mesh.file — with a TetGen .node its .ele and the other way round
 * —, handles[i].select.file, handles[i].positions, initial.positions,
 * reference.positions, task.target) is found as `solve` finds it (beside
 * the scene, else by file name in search_path), uploaded under its plain
 * file name (prefixed "2-", "3-"... when two different files share one)
 * and renamed so in the uploaded scene. A scene without a "name" gets its
 * file's stem, the name `solve` reports (the broker never sees the file).
 * The solver settings given (method, tolerance, max_iterations) replace
 * the scene's "solver" members of those names, the others kept; a
 * "solver" that is not an object is BG_ERR_INVALID. *body is a NUL-terminated string
 * the caller frees. BG_ERR_NOT_FOUND / BG_ERR_PARSE / BG_ERR_INVALID name
 * the scene file and the field.
 */
bg_status bgb_client_pack(const bgb_client_submit_t *submit, char **body, bg_error_t *err);

/* POST /v1/jobs: *job is the job resource (caller frees with cJSON_Delete). */
bg_status bgb_client_submit_job(bgb_client_t *client, const bgb_client_submit_t *submit,
                                cJSON **job, bg_error_t *err);

/*
 * GET /v1/jobs: one page, oldest first. state NULL: every state; limit <= 0:
 * the broker's default; cursor NULL: the first page. *page is {"jobs": [...],
 * "next": cursor or null} (caller frees).
 */
bg_status bgb_client_list_jobs(bgb_client_t *client, const char *state, int limit,
                               const char *cursor, cJSON **page, bg_error_t *err);

/* GET /v1/jobs/{id}, POST /v1/jobs/{id}/cancel, GET /v1/jobs/{id}/result
 * ({"id", "files": [{"name", "size"}]}), GET /v1/agents, GET /v1/market:
 * the response document in *out (caller frees). */
bg_status bgb_client_get_job(bgb_client_t *client, const char *id, cJSON **out, bg_error_t *err);
bg_status bgb_client_cancel_job(bgb_client_t *client, const char *id, cJSON **out, bg_error_t *err);
bg_status bgb_client_result(bgb_client_t *client, const char *id, cJSON **out, bg_error_t *err);
bg_status bgb_client_agents(bgb_client_t *client, cJSON **out, bg_error_t *err);
bg_status bgb_client_market(bgb_client_t *client, cJSON **out, bg_error_t *err);
/* GET /healthz (no token needed): the broker's name and state. */
bg_status bgb_client_health(bgb_client_t *client, cJSON **out, bg_error_t *err);

/*
 * Downloads result file `name` of job `id` into folder dir (which must
 * exist) as dir/name. The name must be a plain file name (no '/', not "."
 * or "..", no control bytes: bgb_store_check_file_name), so nothing is ever
 * written outside dir; the file is written to a temporary name and renamed,
 * and a symbolic link at dir/name is replaced, never followed. *size (may
 * be NULL) receives the bytes written.
 */
bg_status bgb_client_download(bgb_client_t *client, const char *id, const char *name,
                              const char *dir, size_t *size, bg_error_t *err);

/* ------------------------------------------------ server-sent events */

/*
 * One event: id, event (type, "message" when the stream gave none) and
 * data (the data: lines joined by '\n'), each NUL-terminated and valid only
 * during the call. Returns non-zero to stop the stream.
 */
typedef int (*bgb_sse_fn)(void *ctx, const char *id, const char *event, const char *data);

/*
 * An incremental text/event-stream parser: feed it the bytes as they come,
 * cut anywhere; it calls fn once per complete event (a blank line ends
 * one), ignoring comment lines (":...") and unknown fields. Lines end in
 * "\n", "\r\n" or "\r". An event longer than max_event bytes (0: 1 MiB) is
 * BG_ERR_LIMIT: the buffer never grows past the cap.
 */
typedef struct bgb_sse bgb_sse_t;

bg_status bgb_sse_new(size_t max_event, bgb_sse_fn fn, void *ctx, bgb_sse_t **out, bg_error_t *err);
/* Parses n more bytes. Returns BG_OK, or BG_ERR_LIMIT; *stopped (may be NULL) is set
 * to 1 once fn asked to stop (the rest of the bytes are then ignored). */
bg_status bgb_sse_feed(bgb_sse_t *sse, const char *bytes, size_t n, int *stopped, bg_error_t *err);
void bgb_sse_destroy(bgb_sse_t **sse);

/*
 * GET /v1/jobs/{id}/events: follows the job's events until the broker ends
 * the stream (the job ended), fn asks to stop, or the connection drops.
 * last_event_id (NULL: none) resumes after that event. No overall
 * timeout: a stream silent for over 60 s (the broker sends keep-alives
 * every 15 s) is BG_ERR_IO.
 */
bg_status bgb_client_events(bgb_client_t *client, const char *id, const char *last_event_id,
                            bgb_sse_fn fn, void *ctx, bg_error_t *err);

#endif
