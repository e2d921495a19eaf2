/*
 * bga_client — the coordinator's side of the wire: one connection to one
 * agent, blocking request/reply with a timeout, and typed calls for the
 * basic services.
 *
 * Every failure names the agent's endpoint and the service: a timeout
 * ("agent tcp://127.0.0.1:40123 (rotation-fit): no reply to rotfit-call
 * within 2000 ms"), an error reply (its code, frame, field and message),
 * or a reply of the wrong shape. One request is in flight at a time; a
 * reply that arrives after its timeout is recognised by its sequence
 * number and dropped (an error reply quoting no number answers the request
 * in flight: the agent could not read its header). The typed calls turn an
 * agent's refusal into a status by its code: no such job BG_ERR_NOT_FOUND,
 * busy or wrong state BG_ERR_CONFLICT, numeric failure BG_ERR_NUMERIC,
 * internal failure BG_ERR_IO, oversize BG_ERR_LIMIT, a type or version it
 * does not serve BG_ERR_UNSUPPORTED, any other malformed request
 * BG_ERR_INVALID. The client owns its ZeroMQ context and DEALER socket.
 *
 * Liveness: while it waits for a reply the client pings the agent (a
 * HEARTBEAT naming the request's job, which renews that job's lease there)
 * every ping_ms, and an agent silent for lost_ms is lost: the wait ends
 * with BG_ERR_IO ("agent ... (service): lost: no answer to heartbeats for
 * N ms ..."). An agent computes off its socket loop (bga_agent) and answers
 * pings at once, so only a dead, hung or cut-off agent goes silent; a long
 * computation does not. The request's own timeout still bounds the wait.
 * bga_client_failure says why the last failed wait got no answer, so a
 * caller can replace a lost agent and retry.
 */
#ifndef BGA_CLIENT_H
#define BGA_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bg_rotfit.h"
#include "bg_step.h"
#include "bga_curve.h"
#include "bga_transport.h"
#include "bga_wire.h"

typedef struct bga_client bga_client_t;

/* Liveness defaults: a ping every 200 ms, lost after 2 s of silence. */
#define BGA_CLIENT_PING_MS 200
#define BGA_CLIENT_LOST_MS 2000

/* Why the last post or wait got no answer. */
typedef enum bga_client_failure {
    BGA_CLIENT_FINE = 0,      /* it got one (perhaps a refusal), or nothing failed */
    BGA_CLIENT_TIMED_OUT = 1, /* no reply within the request's timeout */
    BGA_CLIENT_LOST = 2,      /* the agent went silent: no answer to pings for lost_ms */
    BGA_CLIENT_BROKEN = 3     /* the socket failed (send, poll or receive) */
} bga_client_failure_t;

/* What one request/reply exchange cost, accumulated per client. */
typedef struct bga_traffic {
    int64_t requests;
    int64_t bytes_sent, bytes_received;
    double encode_seconds; /* encoding requests and decoding replies */
    double wait_seconds;   /* from the send to the reply (transit + agent compute) */
    double agent_seconds;  /* compute time the agents reported */
} bga_traffic_t;

/* A decoded reply; msg points into the received frames until closed. */
typedef struct bga_reply {
    bga_received_t frames;
    bga_msg_t msg;
} bga_reply_t;

/*
 * Connects to endpoint. `service` names what this connection is for in
 * messages ("rotation-fit"). Caller owns *out.
 */
bg_status bga_client_new(const char *endpoint, const char *service, int timeout_ms,
                         bga_client_t **out, bg_error_t *err);
/*
 * The same over CURVE when curve is not NULL: the connection presents
 * curve->self and expects the agent's public key that curve->key_of gives
 * for the endpoint (borrowed for the call). An endpoint without a known
 * key is BG_ERR_NOT_FOUND naming it; an agent that refuses the key
 * answers nothing (its log says why), so the first call times out.
 */
bg_status bga_client_new_curve(const char *endpoint, const char *service, int timeout_ms,
                               const bga_curve_peers_t *curve, bga_client_t **out, bg_error_t *err);
void bga_client_destroy(bga_client_t **client);
const char *bga_client_endpoint(const bga_client_t *client);
bga_traffic_t bga_client_traffic(const bga_client_t *client);

/* Pings every ping_ms while a reply is awaited and gives the agent up
 * after lost_ms of silence; 0 for either: no pings, the request's timeout
 * alone. Raw requests never ping. */
void bga_client_set_liveness(bga_client_t *client, int ping_ms, int lost_ms);
bga_client_failure_t bga_client_failure(const bga_client_t *client);
/* Replies to abandoned requests that came in and were discarded (a reply
 * after its timeout, or after its agent was given up), so far. */
int64_t bga_client_late_answers(const bga_client_t *client);
/* Reads, without waiting, whatever has come in and is no reply anyone
 * waits for (nothing may be in flight), and discards it; returns how many
 * of those were late replies (pongs are not counted). A coordinator keeps
 * the client of an agent it gave up for a while and drains it, to count
 * the late answers it discards. */
int64_t bga_client_drain(bga_client_t *client);

/*
 * Sends req (its seq is assigned here) and waits for the matching reply.
 * An ERROR reply is returned too (BG_OK): look at rep->msg.header.type.
 * BG_ERR_IO on a timeout or a transport failure, BG_ERR_PARSE when the
 * reply does not decode. On BG_OK the caller closes *rep.
 */
bg_status bga_client_request(bga_client_t *c, bga_msg_t *req, bga_reply_t *rep, bg_error_t *err);
/*
 * The two halves of bga_client_request, so a coordinator can have one
 * request in flight on each of several agents: post encodes and sends
 * (one request in flight per client: BG_ERR_INVALID otherwise), collect
 * waits for its reply (the timeout counts from the post).
 */
bg_status bga_client_post(bga_client_t *c, bga_msg_t *req, bg_error_t *err);
bg_status bga_client_collect(bga_client_t *c, bga_reply_t *rep, bg_error_t *err);

/* The same with raw frames (tests send malformed messages): the reply
 * is the first one to arrive. */
bg_status bga_client_request_raw(bga_client_t *c, const bga_frame_t *frames, int nframes,
                                 bga_reply_t *rep, bg_error_t *err);
void bga_reply_close(bga_reply_t *rep);

/* The agent's answer to a ping. */
typedef struct bga_agent_status {
    int64_t slots, free_slots, jobs;
    unsigned services;
    char name[64];
} bga_agent_status_t;
bg_status bga_client_heartbeat(bga_client_t *c, uint64_t job, bga_agent_status_t *st,
                               bg_error_t *err);

/* A rotation-fit partition (all arrays borrowed for the call). Exactly one
 * of rest_positions (nv*dim) and rest_edges (ne*dim*dim) is non-NULL;
 * scatter (ne*T into nval entries, −1 skips) may be NULL: then the
 * Hessian comes back as per-element packed upper triangles. */
typedef struct bga_partition {
    int dim;
    int32_t nv, ne, nglobal;
    const int32_t *elements;        /* ne*(dim+1), local vertex numbers */
    const int32_t *local_to_global; /* nv */
    const double *rest_positions;
    const double *rest_edges;
    double mu, lambda, barrier;
    int32_t nval;
    const int32_t *scatter;
    int64_t lease_ms;
} bga_partition_t;

bg_status bga_client_rotfit_setup(bga_client_t *c, uint64_t job, const bga_partition_t *p,
                                  bg_error_t *err);
/* bga_client_rotfit_setup in two halves, as bga_client_rotfit_start and
 * _finish: the partition's arrays are read (encoded and sent) by _start
 * only, so they may be freed once it returns, and every agent of a pool
 * builds its model while the next partition is cut and sent. */
bg_status bga_client_rotfit_setup_start(bga_client_t *c, uint64_t job, const bga_partition_t *p,
                                        bg_error_t *err);
bg_status bga_client_rotfit_setup_finish(bga_client_t *c, bg_error_t *err);

/* A surface partition for the spokes-and-rims rotation fit (arrays
 * borrowed for the call): the triangles of the owned vertices' cells in
 * local numbering, the local vertices' rest positions (nv*3) and global
 * numbers, and the owned local vertices. Calls are bga_client_rotfit with
 * BGA_WANT_GRADIENT (no Hessian). */
typedef struct bga_surface_part {
    int32_t nv, ne, nglobal, nowned;
    const int32_t *triangles;       /* ne*3 */
    const int32_t *local_to_global; /* nv */
    const double *rest_positions;   /* nv*3 */
    const int32_t *owned;           /* nowned */
    int64_t lease_ms;
} bga_surface_part_t;

bg_status bga_client_surface_setup(bga_client_t *c, uint64_t job, const bga_surface_part_t *p,
                                   bg_error_t *err);

typedef struct bga_rotfit_out {
    double energy;
    double *gradient; /* nv*dim, filled when want has BGA_WANT_GRADIENT */
    double *hessian;  /* nval (or ne*T), filled when want has BGA_WANT_HESSIAN */
    size_t gradient_count, hessian_count; /* capacities of the two */
    bg_rotfit_stats_t fits;
    double agent_seconds;
} bga_rotfit_out_t;

bg_status bga_client_rotfit(bga_client_t *c, uint64_t job, const double *positions, size_t count,
                            unsigned want, bga_rotfit_out_t *out, bg_error_t *err);
/* bga_client_rotfit in two halves (start on every agent, then finish
 * each): the partitions are computed in parallel. */
bg_status bga_client_rotfit_start(bga_client_t *c, uint64_t job, const double *positions,
                                  size_t count, unsigned want, bg_error_t *err);
bg_status bga_client_rotfit_finish(bga_client_t *c, bga_rotfit_out_t *out, bg_error_t *err);

/* options: BGA_SOLVE_PREFER_SOLVES (the system will be solved far more
 * often than factored: bg_sparse_prefer_solves), BGA_SOLVE_ORDERED (the
 * pattern is the lower triangle of P A Pᵀ of bg_sparse_reorder: the agent
 * factors it in that order, and the caller permutes right-hand sides and
 * solutions), or 0. */
bg_status bga_client_solve_setup(bga_client_t *c, uint64_t job, int32_t n, const int32_t *colptr,
                                 const int32_t *rowidx, unsigned options, int64_t lease_ms,
                                 bg_error_t *err);
/* *posdef = 0 when the matrix (plus shift·I) is not positive definite:
 * the caller may retry with a larger shift. */
bg_status bga_client_solve_factor(bga_client_t *c, uint64_t job, const double *values, size_t nnz,
                                  double shift, int *posdef, bg_error_t *err);
/* The same, also returning the cost model of the agent's analysis
 * (bg_sparse_factor_flops / _nonzeros there) and the seconds the agent
 * spent analysing the pattern in this call (the first factor's);
 * cost may be NULL. */
typedef struct bga_factor_cost {
    double flops, nonzeros;
    double analyze_seconds;
} bga_factor_cost_t;
bg_status bga_client_solve_factor_cost(bga_client_t *c, uint64_t job, const double *values,
                                       size_t nnz, double shift, int *posdef,
                                       bga_factor_cost_t *cost, bg_error_t *err);
/* x = A⁻¹ rhs for nrhs right-hand sides of n values each (column blocks). */
bg_status bga_client_solve(bga_client_t *c, uint64_t job, const double *rhs, int32_t n, int nrhs,
                           double *x, bg_error_t *err);
bg_status bga_client_release(bga_client_t *c, uint64_t job, bg_error_t *err);

/*
 * integration-step: the calls of bg_step (bg_step.h) on the agent's copy
 * of the run's state. The replies' arrays are copied into the caller's
 * buffers (ndof values each; `candidates` holds BG_STEP_MAX_CANDIDATES·ndof)
 * and the outputs point into them. A reply whose arrays do not have the
 * state's size is BG_ERR_PARSE.
 */
typedef struct bga_step_buffers {
    size_t ndof;
    double *q, *y, *targets, *candidates, *q_next;
} bga_step_buffers_t;

bg_status bga_client_step_setup(bga_client_t *c, uint64_t job, const bg_step_setup_t *setup,
                                int64_t lease_ms, const bga_step_buffers_t *buf,
                                bg_step_motion_t *motion, bg_error_t *err);
bg_status bga_client_step_predict(bga_client_t *c, uint64_t job, const bg_step_request_t *req,
                                  const bga_step_buffers_t *buf, bg_step_prediction_t *out,
                                  bg_error_t *err);
bg_status bga_client_step_update(bga_client_t *c, uint64_t job, const double *q_star,
                                 const double *grad_star, const bga_step_buffers_t *buf,
                                 bg_step_trial_t *out, bg_error_t *err);
bg_status bga_client_step_accept(bga_client_t *c, uint64_t job, const bga_step_buffers_t *buf,
                                 bg_step_motion_t *motion, bg_error_t *err);

#endif
