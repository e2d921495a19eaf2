/*
 * bga_market — the agent's side of the live market: two seller roles hosted
 * in the agent daemon, talking to the broker over one DEALER socket with
 * wall-clock timers (registration retries, heartbeats).
 *
 * The basic-service seller registers its compute endpoint, services, slots
 * and price policy, then heartbeats its free slots and current prices
 * every `heartbeat` seconds. Its decisions are the simulator's
 * basic-seller role machine's (bgm_seller, hosted by bga_bseller): whether
 * it has a slot and a price covers its reservation, its side of a
 * bargain, what it bids for a contract's resources and what it learns
 * they cost. Its reservation for a good is its own floor (`floor`, its
 * cost per unit) plus the resources one contract needs at the rates it
 * expects (at first its own resource seller's opening rates, then the
 * asking rates it met) over one lease:
 *     (rate_cores · unit_cores + rate_memory · unit_memory) · lease,
 * and its asking price
 *     reservation · (1 + margin) · (1 + load_slope · used / slots).
 * It never sells below the reservation. When it agrees to a service
 * contract (an ORDER, a call-market match, or a catallactic bargain) it
 * keeps a slot and buys the unit's cores and memory for `lease` seconds on
 * layer 1 (RBUY; the broker runs the job's mechanism among the resource
 * sellers of its host), bidding at most 1.5 times their expected cost; it
 * CONFIRMs once they are bought and REFUSEs if they cannot be (within
 * BGA_BSELLER_BUY_WAIT). It computes for a job only while it holds both
 * (bga_market_holds); a lease that runs out ends the contract.
 *
 * The resource seller (when `cores` > 0) is a second directory entry of
 * the same daemon: services 0, its host's cores and memory. A host has one
 * resource seller: the broker takes the first daemon of a host to register
 * one and answers the others' registration with no id and the reason; such
 * a role stands by, selling nothing, and registers again at every
 * heartbeat, so it takes over when the first is dropped. Its decisions
 * are the simulator's resource-seller role machine's (bgm_resource, hosted
 * by bga_rseller): whether it has the room and the rate covers its cost
 * (res_floor per core-second and per GiB-second), its side of a bargain,
 * what it holds until the broker releases it or the lease ends, and its
 * asking rate
 *     res_floor · (1 + res_margin) · (1 + res_load_slope · used / capacity)
 * (the machine's markup is held at res_margin: bga_rseller.h says why).
 * It heartbeats what is free. It sells on the same mechanism as the job
 * that causes the purchase.
 *
 * The connection never blocks the agent: a message that cannot be queued
 * (no connection yet, or a handshake the broker refused) is dropped, and
 * an unregistered seller that has heard nothing for BGA_MARKET_RECONNECT
 * seconds connects afresh.
 *
 * Ownership: the socket is created in the caller's ZeroMQ context and
 * closed by bga_market_destroy. Single-threaded: called from the agent's
 * loop only.
 */
#ifndef BGA_MARKET_H
#define BGA_MARKET_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_curve.h"
#include "bga_mmsg.h"
#include "bga_zap.h"

typedef struct bga_market bga_market_t;

typedef struct bga_market_config {
    const char *broker;   /* broker's ROUTER endpoint */
    const char *name;     /* agent's name (copied) */
    const char *endpoint; /* agent's compute endpoint (copied) */
    unsigned services;    /* BGA_SERVICE_* bits sold */
    int slots;
    double floor[BGA_MMSG_GOODS]; /* per unit; goods not sold are ignored */
    double margin, load_slope;
    double heartbeat;     /* seconds between heartbeats (> 0) */
    /* Layer 1, the basic seller's needs per contract of each service good
     * (the simulator's per-service cores and memory) and the lease. */
    double unit_cores[3], unit_memory[3]; /* cores, GiB */
    double lease;                         /* seconds a contract's resources are rented */
    /* The resource seller role: 0 cores sells none. */
    double cores, memory;                 /* capacity: cores, GiB */
    double res_floor[2];                  /* per core-second, per GiB-second */
    double res_margin, res_load_slope;
    /* Told when the resource role starts standing by (`why`: the broker
     * says which daemon sells the host) or selling again (why NULL); called
     * from the agent's loop, `why` borrowed for the call. NULL: not told. */
    void (*on_standby)(void *ctx, const char *why);
    void *standby_ctx;
    /* Told when the broker answers with an ERROR (it refused a
     * registration, say because the name is another agent's): `why` is
     * its reason, said once until it changes or the agent registers.
     * Called from the agent's loop, `why` borrowed. NULL: not told. */
    void (*on_refused)(void *ctx, const char *why);
    void *refused_ctx;
    /* CURVE to the broker (NULL: plaintext): the agent's key pair and the
     * broker's public key (Z85), both borrowed for bga_market_new; the
     * connection is watched by zap (may be NULL) so a refusal is logged. */
    const bga_curve_keypair_t *curve;
    const char *broker_key;
    bga_zap_t *zap;
    /* Told when a REGISTERED brings another broker epoch than the one this
     * seller sold under (the broker died and a new one runs): by then the
     * seller has dropped every contract, bargain, resource holding and
     * lease of the previous broker; the callee drops the jobs' compute
     * state. Called from the agent's loop. NULL: not told. */
    void (*on_new_epoch)(void *ctx, uint64_t previous, uint64_t epoch);
    void *epoch_ctx;
} bga_market_config_t;

/* Defaults: floors 1.0, margin 0.2, load slope 0.5, heartbeat 0.5 s;
 * unit cores 1, 2, 1 and memory 1, 4, 2 GiB (rotation-fit, sparse-solve,
 * integration-step, as the simulator's defaults), lease 3600 s; resource
 * seller with the host's cores (sysconf) and memory (/proc/meminfo),
 * floors 1e-5 per core-second and 2e-6 per GiB-second, margin 0.2, load
 * slope 0.5. A unit's needs are capped at the daemon's own cores and
 * memory, so a small host can still serve every good, and the memory
 * needs shrink in proportion where one job of every service (a rotation
 * fit in two parts) would not fit the host's memory. */
void bga_market_config_default(bga_market_config_t *c);

bg_status bga_market_new(void *zmq_ctx, const bga_market_config_t *config, double now,
                         bga_market_t **out, bg_error_t *err);
void bga_market_destroy(bga_market_t **m);

/* The broker epoch it sells under (0 before the first REGISTERED), and
 * how many times a new one made it drop the previous broker's deals. */
uint64_t bga_market_epoch(const bga_market_t *m);
int bga_market_epoch_changes(const bga_market_t *m);

/* The DEALER socket, for the caller's zmq_poll. */
void *bga_market_socket(const bga_market_t *m);
/* Reads and handles every message waiting on the socket. */
bg_status bga_market_on_readable(bga_market_t *m, double now, bg_error_t *err);
/* Heartbeats and re-registration when due. */
bg_status bga_market_tick(bga_market_t *m, double now, bg_error_t *err);

/* A contract for market job J covers the compute job ids J .. J + SPAN − 1:
 * a solver opens several sessions (and matrices) per job, each with its
 * own compute job id, all drawn from that range (bga_backend job_base). */
#define BGA_MARKET_JOB_SPAN ((uint64_t)1 << 32)

/* Seconds unregistered and unheard after which the seller connects to the
 * broker afresh (a refused handshake is not retried by libzmq). */
#define BGA_MARKET_RECONNECT 10.0

/* Whether the agent holds a service contract (any good) covering this
 * compute job id together with the resources bought for it. */
int bga_market_holds(const bga_market_t *m, uint64_t job);
/* Cores bought for the contracts covering this compute job id (0: none). */
double bga_market_cores(const bga_market_t *m, uint64_t job);
/* Called before each compute call: whether the agent may compute for this
 * job id (bga_market_holds), and if so it caps the process's compute
 * threads — OpenBLAS's and OpenMP's pools (CHOLMOD's factorization and the
 * BLAS under it), where linked — at the cores bought for the job, never
 * above their sizes when the market was created (OPENBLAS_NUM_THREADS,
 * OMP_NUM_THREADS). The daemon computes one call at a time (its worker
 * thread), so the cap is that job's. */
int bga_market_admit(bga_market_t *m, uint64_t job);
/* The cap bga_market_admit applies, alone: the compute thread pools at
 * `cores` (below 1: left as they are). It reads only what bga_market_new
 * fixed, so unlike the rest of this module it may be called from another
 * thread than the agent's loop: the daemon's worker calls it before each
 * computation with the cores the loop found for the call's job. */
void bga_market_limit_threads(const bga_market_t *m, double cores);
/* Directory ids once registered (0 before): the basic seller's and the
 * resource seller's. */
uint32_t bga_market_id(const bga_market_t *m);
uint32_t bga_market_resource_id(const bga_market_t *m);
/* Asking price for a good at the current load (services per unit of
 * work; cores, memory per unit-second; 0 for a good not sold). */
double bga_market_price(const bga_market_t *m, int good);
/* Service slots in use (contracts held or buying their resources). */
int bga_market_used(const bga_market_t *m);
/* Cores the resource seller has sold and not yet got back. */
double bga_market_cores_used(const bga_market_t *m);

#endif
