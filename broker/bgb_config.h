/*
 * bgb_config — the broker daemon's settings: defaults, the JSON file that
 * overrides them (`biotgrid broker --config FILE`, what `grid up` writes),
 * and the "market" object alone (what the grid checks before it starts a
 * broker with it). Every error names the file and the field.
 */
#ifndef BGB_CONFIG_H
#define BGB_CONFIG_H

#include <stdint.h>

#include <cjson/cJSON.h>

#include "bg_error.h"
#include "bgb_limits.h"
#include "bgb_market.h"

#define BGB_CONFIG_MAX_AGENTS 32
/* Coordinators running at once, at most (max_jobs). */
#define BGB_CONFIG_MAX_JOBS 64

/* One agent of the fixed pool. */
typedef struct bgb_config_agent {
    char *endpoint;    /* tcp://HOST:PORT */
    unsigned services; /* BGA_SERVICE_* bits */
} bgb_config_agent_t;

/* The daemon's settings; strings owned by the config (bgb_config_release). */
typedef struct bgb_config {
    char *name;           /* "biotgrid" */
    char *address;        /* REST address, "127.0.0.1" */
    char *tls_cert;       /* PEM certificate chain for REST over TLS; NULL: plain HTTP */
    char *tls_key;        /* its PEM private key; NULL: plain HTTP (both or neither) */
    int insecure;         /* 1: serve plain HTTP, and the agents' endpoint without CURVE,
                             beyond loopback anyway (tokens and jobs in clear) */
    int port;             /* REST port, 8080; 0: ephemeral */
    char *endpoint;       /* ZeroMQ ROUTER endpoint, "tcp://127.0.0.1:5570"; port '*': ephemeral */
    char *curve_key;      /* the broker's CURVE secret key file; NULL: plaintext ZeroMQ */
    char *authorized_agents; /* the folder of the agents' NAME.pub files (with curve_key) */
    char *state_dir;      /* the store and the jobs' folders, "out/broker" */
    bgb_limits_t limits;  /* every limit (bgb_limits.h); the job size caps 0 until
                             resolved for the machine (bgb_limits_resolve) */
    int max_jobs;         /* coordinators running at once, 4 */
    int agent_timeout_ms; /* per agent request, 10000 */
    int agent_liveness_ms; /* an agent silent this long while a job waits on it is lost (it is
                              pinged every fifth of that), 2000 */
    int agent_recovery;    /* 1: a lost agent's service is bought again and the job resumes
                              (the coordinator keeps checkpoints); 0: the loss fails the job */
    int stop_grace_ms;     /* at SIGTERM, how long running jobs may take to end before they
                              stop and are queued again, 30000 */
    bgb_config_agent_t agents[BGB_CONFIG_MAX_AGENTS];
    int agent_count;
    bgb_market_config_t market; /* the live market's (bgb_market_config_default); name unused */
    /* Not from the file: where the broker's refusals of agents go (one
     * line each, from its threads; bgb_loop.h); NULL: nowhere. */
    void (*log)(void *ctx, const char *line);
    void *log_ctx;
} bgb_config_t;

/* The defaults above. */
bg_status bgb_config_init(bgb_config_t *config, bg_error_t *err);

/*
 * Reads a JSON object over the defaults: name, address, port, endpoint,
 * tls_cert, tls_key (file paths), insecure (boolean), curve_key (a file),
 * authorized_agents (a folder), state_dir, max_jobs, agent_timeout_ms,
 * agent_liveness_ms (100 .. 600000), agent_recovery (true/false),
 * stop_grace_ms (0 .. 3600000), the limits (memory_fraction,
 * max_vertices, max_elements, max_work, max_body, max_jobs_in_flight,
 * max_stored_bytes, max_connections, max_connections_per_client,
 * idle_timeout, request_timeout: bgb_limits.h), agents [{"endpoint",
 * "services"}], market {period,
 * k, heartbeat_timeout, reply_timeout, buy_timeout (seconds, in (0, 3600);
 * k in [0, 1]), overlay_degree in [1, 8], hops in [1, 16], max_rounds in
 * [1, 1000], max_contracts in [1, 10^7]}. An unknown key, a wrong type or
 * range is BG_ERR_INVALID naming the file and the field ("market.k").
 */
bg_status bgb_config_read(const char *path, bgb_config_t *config, bg_error_t *err);
/* The same from a parsed object (borrowed); `path` names its file in
 * messages. */
bg_status bgb_config_read_object(const cJSON *obj, const char *path, bgb_config_t *config,
                                 bg_error_t *err);

/* 1 if a grid config's broker object may give `key` as it is to the
 * broker's config: how jobs run and recover (max_jobs, agent_*_ms,
 * agent_recovery, stop_grace_ms) and the limits; 0 for the rest, which the
 * grid sets itself (name, port, endpoint, the store, the keys). */
int bgb_config_grid_setting(const char *key);

/* The "market" object alone, over *market (`path` names the file in
 * errors): what the grid checks before it starts a broker with it. */
bg_status bgb_config_market_read(const cJSON *obj, const char *path, bgb_market_config_t *market,
                                 bg_error_t *err);

void bgb_config_release(bgb_config_t *config);

/* A deep copy of *from into *to (caller releases it); BG_ERR_NOMEM. */
bg_status bgb_config_copy(bgb_config_t *to, const bgb_config_t *from, bg_error_t *err);

#endif
