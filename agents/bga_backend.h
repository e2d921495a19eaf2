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
 * session and per coordinator process), released when the session ends.
 *
 * Failures. While a call waits, its agent is pinged (bga_client liveness);
 * one that goes silent, does not answer in time, or answers that it holds
 * no state for the job is lost. Without a recovery (bga_backend_set_recovery)
 * the failure names the agent and the service and makes the session fail
 * every later call at once. With one, the backend asks it for another
 * agent for the lost one's place, sets that agent up from what this
 * process kept and finishes the call there, so the solver does not see
 * the loss:
 *   rotation-fit     the partition is cut again from the session's mesh (the
 *                    solver's, borrowed) and only its share of the call is
 *                    asked again; rotations start cold there.
 *   sparse-solve     every pattern is sent again and every matrix factored
 *                    again from a copy of the values last factored (the
 *                    checkpoint: nnz values per matrix, copied per factor),
 *                    bit for bit the same factor.
 *   integration-step the state is rebuilt from the last accepted steps: the
 *                    set-up (or the state two accepted steps back) and the
 *                    inputs of the steps since (targets, q*, ∇W(q*): the
 *                    checkpoint), replayed with the step in progress; a
 *                    step's end state does not depend on the momenta it
 *                    starts from, so two replayed steps give the committed
 *                    state bit for bit.
 * A refusal (a bad value, a numerical failure) is the call's own failure,
 * never a loss. Agents given up are kept a while so that their late
 * answers are read and discarded (and counted to the recovery).
 *
 * The backend owns its configuration copy and the per-agent traffic totals;
 * sessions must end before it is destroyed. One thread.
 */
#ifndef BGA_BACKEND_H
#define BGA_BACKEND_H

#include <stdint.h>

#include "bg_backend.h"
#include "bg_error.h"
#include "bga_client.h"

#define BGA_BACKEND_MAX_AGENTS 32
#define BGA_BACKEND_ENDPOINT_MAX 256
/* Agents replaced per call at most before the call fails. */
#define BGA_BACKEND_MAX_RETRIES 8
/* Given-up agents whose late answers are still read. */
#define BGA_BACKEND_GIVEN_UP_MAX 8

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

/* A lost agent: the place it held and why it was given up (all borrowed
 * for the call). `agent` numbers places as bga_backend_usage does: 0 ..
 * nrotfit − 1 the rotation-fit parts, nrotfit the sparse solve, nrotfit +
 * 1 the integration step. */
typedef struct bga_backend_loss {
    int agent;
    const char *service;  /* "rotation-fit", "sparse-solve", "integration-step" */
    const char *endpoint; /* the lost agent's */
    const char *why;      /* the failure's message */
} bga_backend_loss_t;

typedef struct bga_backend_recovery {
    /*
     * Finds an agent for a lost one's place: writes its endpoint into
     * endpoint[0 .. cap) and the job base its contract covers into
     * *job_base (0: the backend picks unused ids), and returns BG_OK; or
     * returns a failure (err says why), which ends the call and the
     * session. Called on the solver's thread inside the call that failed;
     * it may block (a purchase).
     */
    bg_status (*replace)(void *ctx, const bga_backend_loss_t *loss, char *endpoint, size_t cap,
                         uint64_t *job_base, bg_error_t *err);
    /* Optional: the replacement holds the lost agent's state again and
     * the call is about to be retried on it, `seconds` after the loss was
     * noticed. */
    void (*resumed)(void *ctx, const bga_backend_loss_t *loss, const char *endpoint,
                    double seconds);
    /* Optional: `count` late answers from the given-up agent at endpoint
     * were read and discarded. */
    void (*late)(void *ctx, const char *endpoint, int64_t count);
    void *ctx;
} bga_backend_recovery_t;

/* Copies the configuration; connects nothing yet (sessions do). Caller owns *out. */
bg_status bga_backend_new(const bga_backend_config_t *config, bga_backend_t **out,
                          bg_error_t *err);
/* Final read of given-up agents' late answers, then frees; accepts NULL. */
void bga_backend_destroy(bga_backend_t **backend);

/* Gives the backend its integration-step agent (copied; before any
 * session). BG_ERR_INVALID when the endpoint is too long. */
bg_status bga_backend_set_integ(bga_backend_t *backend, const char *endpoint, bg_error_t *err);

/* Lost agents are replaced through `recovery` (copied; before any
 * session), which also turns the checkpoints on: the copies above are
 * kept only with a recovery. NULL: a loss fails the session. */
void bga_backend_set_recovery(bga_backend_t *backend, const bga_backend_recovery_t *recovery);

/* The clients' liveness (bga_client_set_liveness; before any session):
 * the defaults are BGA_CLIENT_PING_MS and BGA_CLIENT_LOST_MS. */
void bga_backend_set_liveness(bga_backend_t *backend, int ping_ms, int lost_ms);

/* The bg_backend to give to the solver (borrowed, lives as long as backend). */
const bg_backend_t *bga_backend_services(const bga_backend_t *backend);

/* Agents 0 .. nrotfit−1 are the rotation-fit ones, the last the sparse-solve one
 * (the integration-step agent is not counted: bga_backend_integ_usage). A
 * place whose agent was replaced names the latest; its traffic is all of
 * them. */
int bga_backend_agents(const bga_backend_t *backend);
bga_agent_usage_t bga_backend_usage(const bga_backend_t *backend, int agent);
/* 1 and *usage when the configuration has an integration-step agent, else 0. */
int bga_backend_integ_usage(const bga_backend_t *backend, bga_agent_usage_t *usage);
/* Agents replaced so far. */
int bga_backend_replacements(const bga_backend_t *backend);
/* Reads the given-up agents' late answers now, without waiting (telling
 * the recovery), and returns how many were discarded in all so far. */
int64_t bga_backend_late_answers(bga_backend_t *backend);

#endif
