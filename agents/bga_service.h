/*
 * bga_service — what an agent computes, without sockets: a table of jobs
 * (up to `slots`), each holding the state of the basic services it set up
 * on this agent, and one function that turns a request's frames into the
 * reply's frames.
 *
 *   rotation-fit    ROTFIT_SETUP keeps the partition as a local mesh and a
 *                   bg_elastic model (its warm rotations live there);
 *                   ROTFIT_CALL returns energy, gradient (local vertices)
 *                   and Hessian values: per element packed blocks, or
 *                   summed through the set-up's scatter map into `values`
 *                   entries (the partition's share of the fixed pattern).
 *   sparse-solve    SOLVE_SETUP keeps a bg_sparse system on the CSC
 *                   pattern (CHOLMOD analyses on the first factor, once);
 *                   SOLVE_FACTOR factors values + shift·I and keeps the
 *                   factor; SOLVE_RHS solves with it, as often as asked.
 *   integration     INTEG_SETUP keeps a dynamic run's state (bg_step: masses,
 *                   q_k, p_k, velocities, targets, constraints, h, damping)
 *                   and answers its motion summary (INTEG_STATE);
 *                   INTEG_PREDICT (a step, or trial 1: the backward-Euler
 *                   redo of the step just tried) answers the inertia data
 *                   and candidate starts (INTEG_INERTIA); INTEG_UPDATE takes
 *                   q* and ∇W(q*) and answers the trial end state
 *                   (INTEG_TRIAL); INTEG_ACCEPT commits it (INTEG_STATE).
 *                   The formulas are bg_step's, the coordinator's own:
 *                   the same numbers bit for bit. Out of order: WRONG_STATE.
 *   control         HEARTBEAT answers the agent's status (and renews the
 *                   lease of the job named in the header, if any); RELEASE
 *                   frees the job.
 * Every request on a job renews its lease (the largest lease_ms of its
 * set-ups; 0 = no expiry). A malformed or unserviceable request gets an
 * ERROR reply naming the frame and field; bga_service_handle itself fails
 * only when memory for the reply runs out.
 */
#ifndef BGA_SERVICE_H
#define BGA_SERVICE_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_wire.h"

typedef struct bga_service bga_service_t;

typedef struct bga_service_config {
    int slots;           /* jobs held at once, ≥ 1 */
    unsigned services;   /* BGA_SERVICE_* bits served */
    const char *name;    /* reported in heartbeats (copied), may be NULL */
    bga_limits_t limits; /* decoding caps */
} bga_service_config_t;

typedef struct bga_service_stats {
    int64_t requests, errors, expired, released;
    int64_t dropped; /* freed by bga_service_drop_all (a new broker epoch) */
    double compute_seconds;
} bga_service_stats_t;

/* Caller owns *out. */
bg_status bga_service_new(const bga_service_config_t *config, bga_service_t **out, bg_error_t *err);
void bga_service_destroy(bga_service_t **svc);

/*
 * Handles one request (frames, borrowed) at monotonic time `now`
 * (seconds) and fills *reply (caller frees with bga_frames_free).
 * Returns BG_OK, or BG_ERR_NOMEM when no reply could be built.
 */
bg_status bga_service_handle(bga_service_t *svc, const bga_frame_t *frames, int nframes, double now,
                             bga_frames_t *reply, bg_error_t *err);

/*
 * The ERROR reply to a request (frames, borrowed) that cannot be served,
 * carrying werr. Whatever else is wrong with the message, the reply quotes
 * the request's job, sequence number, type and ids whenever frame 0 holds
 * a readable header (BGA_WIRE_HEADER_BYTES starting with the magic), so
 * that the peer matches it to its request at once instead of waiting for
 * a reply that never comes; otherwise they are 0. Every refusal an agent
 * sends goes through here. Fills *reply (caller frees with
 * bga_frames_free); BG_ERR_NOMEM when it cannot be built.
 */
bg_status bga_service_refuse(const bga_frame_t *frames, int nframes, const bga_wire_error_t *werr,
                             bga_frames_t *reply, bg_error_t *err);

/*
 * The answer to a HEARTBEAT (frames borrowed), as bga_service_handle gives
 * it, for an agent holding `jobs` jobs, into *reply (caller frees with
 * bga_frames_free), and the job the ping names (0: none) into *job. It
 * reads only what bga_service_new fixed (name, slots, services, caps), so
 * a thread that does not own svc may call it while another runs
 * bga_service_handle: the agent's socket loop answers pings this way
 * while its worker computes, and hands the lease renewal to the worker
 * (bga_service_touch). BG_ERR_INVALID, and no reply, for anything but a
 * well-formed HEARTBEAT (bga_service_handle answers those);
 * BG_ERR_NOMEM when the reply cannot be built.
 */
bg_status bga_service_heartbeat(const bga_service_t *svc, int jobs, const bga_frame_t *frames,
                                int nframes, bga_frames_t *reply, uint64_t *job, bg_error_t *err);

/* Renews the lease of job `job` (if held) at `now`: what a heartbeat
 * naming it does in bga_service_handle. */
void bga_service_touch(bga_service_t *svc, uint64_t job, double now);

/* Frees every job whose lease ran out before `now`; returns how many. */
int bga_service_expire(bga_service_t *svc, double now);

/* Frees every job held, whatever its lease: the broker they were bought
 * from died (its successor's epoch was heard). Returns how many. */
int bga_service_drop_all(bga_service_t *svc);

/* Jobs held now. */
int bga_service_jobs(const bga_service_t *svc);
bga_service_stats_t bga_service_stats(const bga_service_t *svc);

/* Parses a --services list ("rotfit,solve,integ" or "all") into bits;
 * 0 on an unknown name (err names it). */
unsigned bga_service_parse_list(const char *list, bg_error_t *err);

/* The name of one service bit as users read it ("rotation-fit",
 * "sparse-solve", "integration-step"); NULL for any other value. */
const char *bga_service_name(unsigned bit);

#endif
