/*
 * bgm_world — one replication's market: the agents of the three roles, the
 * two layers, and the protocols of the three mechanisms, as a sans-I/O
 * state machine.
 *
 * The world consumes one event at a time — a message delivered to an agent
 * or a timer firing — at a time given by the driver, and emits messages
 * and timers through a bgm_sink_t; it never reads a clock, a socket or a
 * file, and includes no SimGrid header. Two drivers feed it: bgm_evq (an
 * in-process priority queue, for tests) and bgm_simdriver (SimGrid, for
 * experiments). The same message flow would run over ZeroMQ.
 *
 * Agents: id 0 is the market agent (the central auctioneer, and the
 * directory of posted prices for the baseline); then complex-service
 * agents (job buyers), basic-service agents (sell services, buy resources)
 * and resource agents (sell cores and memory for a time). The market agent
 * and every other agent are role machines of their own (bgm_market_agent,
 * bgm_buyer, bgm_seller, bgm_resource) that the world hosts and whose
 * outboxes it routes; the world keeps no role's state, only the
 * observer's: what it drew for each agent, the request and job records it
 * reads from the machines' getters, the contract log, the ledger and the
 * metrics.
 * Every contract is appended to an audit log with both limits, so the
 * invariants (price within limits, no seller over capacity, money
 * conserved) can be checked afterwards from the log alone.
 */
#ifndef BGM_WORLD_H
#define BGM_WORLD_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_purchase.h"
#include "bgm_role.h"

typedef enum bgm_role {
    BGM_ROLE_MARKET = 0,
    BGM_ROLE_COMPLEX = 1,
    BGM_ROLE_BASIC = 2,
    BGM_ROLE_RESOURCE = 3
} bgm_role;


typedef struct bgm_sink {
    void *ctx;
    /* Send *msg (copied by the driver) from msg->from to msg->to, with a
     * simulated size in bytes. */
    void (*send)(void *ctx, const bgm_msg_t *msg, long bytes);
    /* Fire (kind, arg) at agent at absolute time `at`. */
    void (*timer)(void *ctx, uint32_t agent, double at, int kind, uint64_t arg);
} bgm_sink_t;

/* Metrics of one replication, in this order everywhere (CSV, JSON). */
typedef enum bgm_metric {
    BGM_M_ALLOCATION_RATE,
    BGM_M_ACCESS_TIME_MEDIAN,
    BGM_M_ACCESS_TIME_P99,
    BGM_M_RESOURCE_ACCESS_TIME_MEDIAN,
    BGM_M_RESOURCE_ACCESS_TIME_P99,
    BGM_M_MESSAGES_PER_ALLOCATION,
    BGM_M_BYTES_PER_ALLOCATION,
    BGM_M_WELFARE,
    BGM_M_WELFARE_RATIO,
    BGM_M_PRICE_MEAN,
    BGM_M_PRICE_VARIANCE,
    BGM_M_PRICE_CONVERGENCE_TIME,
    BGM_M_UTILIZATION,
    BGM_M_JOB_COMPLETION_TIME,
    BGM_M_JOB_COMPLETION_RATE,
    BGM_M_RESOURCE_ALLOCATION_RATE,
    BGM_M_REQUESTS,
    BGM_M_CONTRACTS,
    BGM_M_MESSAGES,
    BGM_M_BYTES,
    BGM_M_COMBEX_EXACT,
    BGM_M_COMBEX_GREEDY,
    BGM_M_TIMEOUTS,
    BGM_M_TIMEOUTS_PER_REQUEST,
    BGM_M_MESSAGES_PER_REQUEST,
    BGM_M_MESSAGE_BOUND,
    BGM_M_COUNT
} bgm_metric;

extern const char *const bgm_metric_names[BGM_M_COUNT];

typedef struct bgm_world bgm_world_t;

typedef struct bgm_world_params {
    const bgm_config_t *cfg;
    int scenario;    /* stream index, for seeds (bgm_config_scenario_stream) */
    int mechanism;   /* bgm_mechanism */
    int replication; /* index */
    int nodes;
    double density;
    const bgm_dynamics_t *dynamics;
    const double *node_speed; /* flops per core, per node (borrowed); NULL: cfg speed */
    const char *topology;     /* named in the scenario label when the topology is a
                               * factor of the experiment; NULL otherwise */
} bgm_world_params_t;

/* Builds the agents of one replication. Returns NULL on failure (err set). */
bgm_world_t *bgm_world_new(const bgm_world_params_t *p, bg_error_t *err);
void bgm_world_destroy(bgm_world_t **w);

uint32_t bgm_world_agent_count(const bgm_world_t *w);
/* Node (host index) of an agent; the market agent lives on node `nodes`. */
uint32_t bgm_world_agent_node(const bgm_world_t *w, uint32_t agent);
/* End of the simulated horizon (arrivals + drain). */
double bgm_world_horizon(const bgm_world_t *w);

/* Emits the initial timers and messages. */
bg_status bgm_world_start(bgm_world_t *w, const bgm_sink_t *sink, double now);
/* Delivers one message (borrowed). */
bg_status bgm_world_on_message(bgm_world_t *w, const bgm_msg_t *msg, double now);
/* Fires one timer. */
bg_status bgm_world_on_timer(bgm_world_t *w, uint32_t agent, int kind, uint64_t arg, double now);

/* The buying machines' counters summed: the jobs' agents' service
 * requests and the basic sellers' bundle requests (attempts, timeouts by
 * kind). */
void bgm_world_tally(const bgm_world_t *w, bgm_purchase_tally_t *service,
                     bgm_purchase_tally_t *resource);

/* Computes the metrics after the run (NaN = null). */
bg_status bgm_world_metrics(bgm_world_t *w, double metrics[BGM_M_COUNT]);

/* Audit log rows (contracts.csv / agents.csv formats, no header). */
bg_status bgm_world_write_contracts(const bgm_world_t *w, FILE *f);
bg_status bgm_world_write_agents(const bgm_world_t *w, FILE *f);
/* Price over time: "good,bucket_start,mean_price" lines for service goods. */
bg_status bgm_world_write_prices(const bgm_world_t *w, FILE *f);

/* Contract log access for tests. */
typedef struct bgm_contract {
    double time, start, end;
    uint32_t request; /* the service request served (per replication) */
    uint32_t buyer, seller;
    int layer; /* 0 service, 1 resource */
    int good;  /* service type 0..2, or 3 cores, 4 memory */
    double quantity, price, buyer_limit, seller_limit;
} bgm_contract_t;

size_t bgm_world_contract_count(const bgm_world_t *w);
const bgm_contract_t *bgm_world_contracts(const bgm_world_t *w);
/* Money ledger totals per layer: paid by buyers, received by sellers. */
void bgm_world_money(const bgm_world_t *w, double paid[2], double received[2]);

extern const char *const bgm_good_names[5];
extern const char *const bgm_role_names[4];

#endif
