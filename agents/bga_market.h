/*
 * bga_market — the agent's side of the live market: a seller hosted in the
 * agent daemon, talking to the broker over a DEALER socket with wall-clock
 * timers (registration retries, heartbeats).
 *
 * The seller registers its compute endpoint, services, slots and price
 * policy, then heartbeats its free slots and current prices every
 * `heartbeat` seconds. Its asking price for a good is
 *     floor · (1 + margin) · (1 + load_slope · used / slots)
 * (a floor from the resources one unit needs, a margin, a price rising
 * with load); it never sells below the floor. It accepts an ORDER (posted)
 * or a MATCH-style ORDER (central) when it has a free slot and the price is
 * at least its floor, and holds the contract until RELEASE. The daemon asks
 * bga_market_holds before computing for a job: no contract, no compute.
 *
 * Ownership: the socket is created in the caller's ZeroMQ context and
 * closed by bga_market_destroy. Single-threaded: called from the agent's
 * loop only.
 */
#ifndef BGA_MARKET_H
#define BGA_MARKET_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_mmsg.h"

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
} bga_market_config_t;

/* Defaults: floors 1.0, margin 0.2, load slope 0.5, heartbeat 0.5 s. */
void bga_market_config_default(bga_market_config_t *c);

bg_status bga_market_new(void *zmq_ctx, const bga_market_config_t *config, double now,
                         bga_market_t **out, bg_error_t *err);
void bga_market_destroy(bga_market_t **m);

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

/* Whether the agent holds a contract (any good) covering this compute job id. */
int bga_market_holds(const bga_market_t *m, uint64_t job);
/* Directory id once registered (0 before). */
uint32_t bga_market_id(const bga_market_t *m);
/* Asking price for a good at the current load. */
double bga_market_price(const bga_market_t *m, int good);
int bga_market_used(const bga_market_t *m);

#endif
