/*
 * bga_bseller — the agent daemon's live basic-service seller: the host of
 * one simulator role machine, bgm_seller (market/bgm_seller.h), that makes
 * every decision (whether it has a slot, whether a price covers its
 * reservation, its side of a bargain, what it bids for the resources a
 * service needs, what it learns of their cost, its asking price), while
 * this module only translates between the live market's messages
 * (agents/bga_mmsg.h: one contract per (job, good), its quantity, a price
 * per unit) and the machine's, and runs the timers the machine asks for on
 * the caller's clock.
 *
 * The mapping. The broker's buyer is one fixed machine id, each (job,
 * good) one machine request. An ORDER (posted, and the central
 * auctioneer's clearing) is the machine's posted ORDER, which it takes at
 * its posted price or above; CFP, OFFER, ACCEPT, REJECT are its
 * bargaining messages, a fresh CFP round opening a fresh bargain. The
 * machine sells under one mechanism of the simulator's at a time, so it
 * runs as a central seller (its bundle purchase is one RBID) whose
 * bargaining sessions are made when a buyer first bargains: a live agent
 * sells under all three at once. Its bundle purchase, one RBID, is the
 * live RBUY (the unit's cores and GiB for the lease, at most the machine's
 * budget); the broker buys them on the job's mechanism and answers RBOUGHT,
 * handed to the machine as the resource seller's RCONFIRM of a rental of
 * one lease at the resource sellers' asking rates (what it learns the
 * resources cost), or RFAIL. The machine's delivery (CONFIRM) is the live
 * CONFIRM, and the live protocol's contract is final then: the host
 * answers the delivery TAKE at once. A CANCEL (its resources could not be
 * had, or not within BGA_BSELLER_BUY_WAIT s) is the live REFUSE naming
 * why; a REJECT of an order or acceptance is a REFUSE naming the rule it
 * broke. RELEASE (the job ended) and the end of a lease fire the
 * machine's release timer early or on time. What the machine says to the
 * market agent (its asks, freed slots) is not sent: the broker learns
 * them from the heartbeat (bga_bseller_describe).
 *
 * Price policy, as the machine's: reservation = own floor (cost per unit)
 * plus the resources a unit needs at the rates it expects (at first the
 * ones given, then what it learns), over one lease; posted price =
 * reservation · (1 + margin), set again after each contract;
 * asking = posted · (1 + load_slope · used / slots); a resource bid of at
 * most 1.5 times the expected resource cost (room for a resource seller
 * whose ask rose with its load, and no more: a split-the-difference
 * clearing would hand it the job's budget otherwise).
 *
 * Not live: learning meetings with neighbours. Its strategy is fixed
 * (bgm_seller_fix_strategy): its markup stays the margin and it remembers
 * no service price, so it opens a bargain at its posted price.
 *
 * Ownership: the caller owns the seller (bga_bseller_destroy). Replies go
 * through the send callback, borrowed for the call. Single-threaded.
 */
#ifndef BGA_BSELLER_H
#define BGA_BSELLER_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_mmsg.h"

/* Seconds a contract's resources may take to be bought. */
#define BGA_BSELLER_BUY_WAIT 10.0
/* A contract for market job J covers the compute job ids J .. J + SPAN − 1
 * (bga_market.h BGA_MARKET_JOB_SPAN). */
#define BGA_BSELLER_JOB_SPAN ((uint64_t)1 << 32)

typedef struct bga_bseller bga_bseller_t;

typedef struct bga_bseller_config {
    unsigned services;                    /* bit g: sells service good g (0..2) */
    int slots;                            /* contracts at once, 1..4096 */
    double floor[3];                      /* own cost per unit, ≥ 0 */
    double margin, load_slope;            /* ≥ 0 */
    double unit_cores[3], unit_memory[3]; /* a contract's needs, cores and GiB, ≥ 0 */
    double lease;                         /* s a contract's resources are rented for (> 0) */
    double rate[2]; /* resource rates expected at first, per core-s, GiB-s (> 0) */
    uint64_t seed;  /* the machine's stream (strategy, bargaining) */
} bga_bseller_config_t;

typedef bg_status (*bga_bseller_send_fn)(void *ctx, const bga_mmsg_t *msg, bg_error_t *err);

/* BG_ERR_INVALID naming the field; BG_ERR_NOMEM. */
bg_status bga_bseller_new(const bga_bseller_config_t *config, bga_bseller_t **out, bg_error_t *err);
void bga_bseller_destroy(bga_bseller_t **bs);

/* The directory id and overlay neighbours the broker gave it. */
bg_status bga_bseller_registered(bga_bseller_t *bs, uint32_t id, const uint32_t *neighbours,
                                 int nneighbours, bg_error_t *err);

/* One broker message for the basic role (ORDER, CFP, OFFER, ACCEPT,
 * REJECT, RBOUGHT, RFAIL, RELEASE; others are ignored). One about a good
 * it does not sell or with numbers out of range is refused naming why.
 * The return is a failure only for a failed send or the machine's own. */
bg_status bga_bseller_on_message(bga_bseller_t *bs, const bga_mmsg_t *in, double now,
                                 bga_bseller_send_fn send, void *ctx, bg_error_t *err);

/* Runs the machine's timers due by `now`: resources not bought in time
 * (a REFUSE to the broker), leases that ran out. */
bg_status bga_bseller_tick(bga_bseller_t *bs, double now, bga_bseller_send_fn send, void *ctx,
                           bg_error_t *err);

/* What the role says of itself in REGISTER and HEARTBEAT: services,
 * slots, free slots, its reservations (floor) and asking prices, margin,
 * load slope. */
void bga_bseller_describe(const bga_bseller_t *bs, bga_mmsg_t *msg);

/* The asking price for a service good (0 for one it does not sell). */
double bga_bseller_price(const bga_bseller_t *bs, int good);
/* Its reservation for a service good (0 for one it does not sell). */
double bga_bseller_reservation(const bga_bseller_t *bs, int good);
/* Slots in use: contracts held or buying their resources. */
int bga_bseller_used(const bga_bseller_t *bs);
/* Whether it holds a contract, its resources bought, covering this
 * compute job id; and the cores bought for those contracts. */
int bga_bseller_holds(const bga_bseller_t *bs, uint64_t job);
double bga_bseller_cores(const bga_bseller_t *bs, uint64_t job);

#endif
