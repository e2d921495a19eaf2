/*
 * bgb_broker — the broker daemon as a library: the durable store
 * (bgb_store), the REST API (bgb_rest), the ZeroMQ ROUTER endpoint agents
 * connect to, and one coordinator thread per job.
 *
 * Threads: the REST server's own; one loop thread that alone owns the
 * ROUTER socket (and, once the live market is attached, the market: every
 * bgb_market call is made from it); one dispatcher that picks queued jobs
 * up from the store (the store is the source of truth, so a job accepted
 * before a restart is found the same way); one coordinator per job.
 *
 * A job's coordinator: queued → allocating → running → succeeded/failed.
 * Allocation: the loop thread hosts the live market (bgb_market). The
 * coordinator builds the job's needs from its plan (rotation-fit split
 * over up to 4 live rotation-fit sellers, one unit of work per seller;
 * sparse-solve ×1; integration-step ×1 only when the plan lists it),
 * hands the purchase to the loop (a queue under the broker's lock) and
 * waits for the outcome. Each contract is a "contract" event of the job;
 * "no seller" (every able seller busy) and "timeout" are asked again with
 * backoff for up to 120 s, each retry an "allocation" event; a budget
 * failure, or a transient one past that, fails the job before any agent
 * computes; the contracts are released when the job ends. With no agent
 * registered on the market but agents in the configuration ("agents": a
 * fixed pool), the job runs on the pool with no contracts and the
 * "allocation" event says so; with neither, the job waits in allocating
 * until an agent registers. Running drives the solve through the same remote
 * backend (bga_backend) as `solve --agents`, on the awarded agents;
 * progress and the error-against-time trace are events; the
 * result files (report.json with the market section and its error against
 * time and money, error-vs-time.svg, error-vs-time-and-money.svg,
 * result.vtu and the native mesh, <method>.pvd and its frames) go into the
 * store.
 *
 * Cancel (REST) moves the job to cancelled in the store at once. A
 * running solve stops within one basic-service call: the solver calls its
 * services through a backend that reads the job's state (at most every
 * 0.1 s) before forwarding each call, and fails every call once the job is
 * cancelled. The coordinator then records a "stopped" event, stores no
 * result and releases the job's contracts, so its agents' slots are free
 * again. surface-edit computes without basic services and is not
 * interrupted: its coordinator sees the state when the solve returns.
 *
 * Restart: at start, jobs left in allocating are put back in queued
 * (nothing was bought for them), jobs left running are failed with the
 * reason "the broker restarted while the job was running" (their agents'
 * state is gone); queued jobs are picked up again.
 */
#ifndef BGB_BROKER_H
#define BGB_BROKER_H

#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>

#include "bg_error.h"
#include "bgb_market.h"

#define BGB_BROKER_MAX_AGENTS 32

typedef struct bgb_broker bgb_broker_t;

/* One agent of the fixed pool. */
typedef struct bgb_broker_agent {
    char *endpoint; /* tcp://HOST:PORT */
    unsigned services; /* BGA_SERVICE_* bits */
} bgb_broker_agent_t;

/* The daemon's settings; strings owned by the config (bgb_broker_config_release). */
typedef struct bgb_broker_config {
    char *name;            /* "biotgrid" */
    char *address;         /* REST address, "127.0.0.1" */
    int port;              /* REST port, 8080; 0: ephemeral */
    char *endpoint;        /* ZeroMQ ROUTER endpoint, "tcp://127.0.0.1:5570"; port '*': ephemeral */
    char *state_dir;       /* the store and the jobs' folders, "out/broker" */
    int64_t max_body;      /* bytes, 0: bgb_rest's default */
    int64_t max_vertices;  /* job size caps, 0: none beyond the engine's */
    int64_t max_elements;
    int max_jobs;          /* coordinators running at once, 4 */
    int agent_timeout_ms;  /* per agent request, 10000 */
    bgb_broker_agent_t agents[BGB_BROKER_MAX_AGENTS];
    int agent_count;
    bgb_market_config_t market; /* the live market's (bgb_market_config_default); name unused */
} bgb_broker_config_t;

/* The defaults above. */
bg_status bgb_broker_config_init(bgb_broker_config_t *config, bg_error_t *err);

/*
 * Reads a JSON object over the defaults: name, address, port, endpoint,
 * state_dir, max_body, max_vertices, max_elements, max_jobs,
 * agent_timeout_ms, agents [{"endpoint", "services"}], market {period,
 * k, heartbeat_timeout, reply_timeout, buy_timeout (seconds, in (0, 3600);
 * k in [0, 1]), overlay_degree in [1, 8], hops in [1, 16], max_rounds in
 * [1, 1000], max_contracts in [1, 10^7]}. An unknown key, a wrong type or
 * range is BG_ERR_INVALID naming the file and the field ("market.k").
 */
bg_status bgb_broker_config_read(const char *path, bgb_broker_config_t *config, bg_error_t *err);

/* The "market" object alone, over *market (`path` names the file in
 * errors): what the grid checks before it starts a broker with it. */
bg_status bgb_broker_market_read(const cJSON *obj, const char *path, bgb_market_config_t *market,
                                 bg_error_t *err);

void bgb_broker_config_release(bgb_broker_config_t *config);

/* Opens the store, recovers jobs, binds REST and ZeroMQ, starts the
 * threads. config is copied. Caller owns *out (bgb_broker_stop). */
bg_status bgb_broker_start(const bgb_broker_config_t *config, bgb_broker_t **out,
                           bg_error_t *err);

/* The REST port and the ROUTER endpoint actually bound. */
uint16_t bgb_broker_rest_port(const bgb_broker_t *broker);
const char *bgb_broker_endpoint(const bgb_broker_t *broker);

/* Stops REST, waits for the coordinators (a running solve finishes
 * first), stops the loop, closes the store; accepts NULL. */
void bgb_broker_stop(bgb_broker_t **broker);

#endif
