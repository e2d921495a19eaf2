/*
 * bga_backend — the solver's basic services on agents: an implementation
 * of bg_backend (services/bg_backend.h) with bga_client calls.
 *
 *   rotation-fit   every rest shape of a session is cut into balanced
 *                  element ranges, one per rotation-fit agent (bga_pool);
 *                  the partial energies, gradients and Hessian values are
 *                  combined in partition order, so results do not depend
 *                  on which agent answers first.
 *   sparse-solve   each matrix of a session lives on the one sparse-solve
 *                  agent: the pattern is sent once (CHOLMOD analyses it
 *                  once there), then values + shift are factored and the
 *                  factor stays for every solve until the next factor.
 *   integration-   a dynamic run's state (bg_step) lives on the one
 *   step           integration-step agent: each step asks it for the
 *                  prediction and candidate starts, sends it q* and ∇W(q*)
 *                  for the trial end state, and commits the trial (or
 *                  redoes the step with backward Euler first) with explicit
 *                  messages. Without an integration-step agent
 *                  (bga_backend_set_integ) the state stays in this process
 *                  (the same bg_step code).
 *
 * Each solver session is its own job on the agents (job ids distinct per
 * session and per coordinator process), released when the session ends. A failure (a timeout, an
 * error reply) names the agent and the service and makes the session fail
 * every later call at once. The backend owns its configuration copy and
 * the per-agent traffic totals; sessions must end before it is destroyed.
 */
#ifndef BGA_BACKEND_H
#define BGA_BACKEND_H

#include <stdint.h>

#include "bg_backend.h"
#include "bg_error.h"
#include "bga_client.h"

#define BGA_BACKEND_MAX_AGENTS 32

typedef struct bga_backend_config {
    const char *const *rotfit; /* rotation-fit endpoints */
    int nrotfit;               /* 1 .. BGA_BACKEND_MAX_AGENTS − 1 */
    const char *solve;         /* the sparse-solve endpoint */
    int timeout_ms;            /* per request */
    int64_t lease_ms;          /* job lease on the agents (0: none) */
    uint64_t job_base;         /* 0: job ids from this process and the clock; else every
                                  compute job id lies in job_base + [16, 2^32), the range a
                                  market contract for job_base covers (bga_market.h) */
    const bga_curve_peers_t *curve; /* CURVE keys to reach the agents; NULL: plaintext.
                                       Borrowed: must outlive the backend */
} bga_backend_config_t;

typedef struct bga_backend bga_backend_t;

/* What one agent did for the backend's sessions (ended ones). */
typedef struct bga_agent_usage {
    const char *endpoint; /* borrowed from the backend */
    const char *service;  /* "rotation-fit", "sparse-solve", "integration-step" (static text) */
    int64_t elements;     /* rotation-fit: elements of its partitions, summed over sessions */
    bga_traffic_t traffic;
} bga_agent_usage_t;

/* Copies the configuration; connects nothing yet (sessions do). Caller owns *out. */
bg_status bga_backend_new(const bga_backend_config_t *config, bga_backend_t **out,
                          bg_error_t *err);
void bga_backend_destroy(bga_backend_t **backend);

/* Gives the backend its integration-step agent (copied; before any
 * session). BG_ERR_INVALID when the endpoint is too long. */
bg_status bga_backend_set_integ(bga_backend_t *backend, const char *endpoint, bg_error_t *err);

/* The bg_backend to give to the solver (borrowed, lives as long as backend). */
const bg_backend_t *bga_backend_services(const bga_backend_t *backend);

/* Agents 0 .. nrotfit−1 are the rotation-fit ones, the last the sparse-solve one
 * (the integration-step agent is not counted: bga_backend_integ_usage). */
int bga_backend_agents(const bga_backend_t *backend);
bga_agent_usage_t bga_backend_usage(const bga_backend_t *backend, int agent);
/* 1 and *usage when the configuration has an integration-step agent, else 0. */
int bga_backend_integ_usage(const bga_backend_t *backend, bga_agent_usage_t *usage);

#endif
