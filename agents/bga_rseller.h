/*
 * bga_rseller — the agent daemon's live resource seller: the host of one
 * simulator role machine, bgm_resource (market/bgm_resource.h), that makes
 * every decision (whether it has the room, whether a rate covers its cost,
 * what it holds and until when, its side of a bargain, its asking rate),
 * while this module only translates between the live market's messages
 * (agents/bga_mmsg.h, one good at a time: cores or memory, a quantity, a
 * lease term, a price per unit-second) and the machine's (one bundle of
 * cores and GiB, a rate per second for all of it), and runs the timers
 * the machine asks for on the caller's clock.
 *
 * The mapping: an ORDER (posted, central) is the machine's posted ORDER of
 * a one-good bundle; CFP, OFFER, ACCEPT, REJECT are its bargaining
 * messages; a bundle of q cores or q GiB held for `term` seconds is the
 * machine's bundle (a = q or b = q) of flops = term · max(cores, 1) at
 * speed 1, so the machine's own duration is the lease. Rates are per
 * second for the bundle, so a live unit price p is the rate p · q. The
 * broker's buyer is one fixed machine id, each (job, good) one machine
 * request; the buyer enforces its own limit, so the budget a message
 * carries is the money the offered price comes to. RELEASE (the job
 * ended) fires the hold's release timer early. What the machine says to
 * the market agent (registration, freed capacity) is not sent: the broker
 * learns free capacity and asking rates from the heartbeat
 * (bga_rseller_describe).
 *
 * The machine shares cores between the phases of one job
 * (bgm_resource_params_t.share_phases): the broker names, in every message
 * about resources, the job they serve (`parent`) and the service
 * (`serves`), and the host gives each job one machine number while it
 * holds anything, so a job whose rotation fit, sparse solve and
 * integration step run one after another on this host occupies the cores
 * of its widest phase, not their sum. Memory is the sum. A message that
 * names no job counts alone.
 *
 * Not live: learning. The machine's learning meetings with its overlay
 * neighbours are not held, and its strategy is fixed
 * (bgm_resource_fix_strategy): its markup stays the configured margin and
 * it remembers no price, so it opens at cost · (1 + margin) and asks
 * cost · (1 + margin) · (1 + load_slope · held / capacity), the live
 * seller's policy before it ran on the machine.
 *
 * Ownership: the caller owns the seller (bga_rseller_destroy). Replies go
 * through the send callback, borrowed for the call. Single-threaded.
 */
#ifndef BGA_RSELLER_H
#define BGA_RSELLER_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_mmsg.h"

typedef struct bga_rseller bga_rseller_t;

typedef struct bga_rseller_config {
    double cores, memory; /* capacity: cores (> 0), GiB (≥ 0) */
    double floor[2];      /* cost per core-second, per GiB-second (> 0) */
    double margin;        /* the machine's markup (≥ 0) */
    double load_slope;    /* asking rate rises by this at full load (≥ 0) */
    double lease;         /* term, s, of an order that names none (> 0) */
    uint64_t seed;        /* the machine's stream (strategy, bargaining) */
} bga_rseller_config_t;

/* Sends one reply to the broker. */
typedef bg_status (*bga_rseller_send_fn)(void *ctx, const bga_mmsg_t *msg, bg_error_t *err);

/* BG_ERR_INVALID naming the field; BG_ERR_NOMEM. */
bg_status bga_rseller_new(const bga_rseller_config_t *config, bga_rseller_t **out, bg_error_t *err);
void bga_rseller_destroy(bga_rseller_t **rs);

/* The directory id and overlay neighbours the broker gave it (REGISTERED). */
bg_status bga_rseller_registered(bga_rseller_t *rs, uint32_t id, const uint32_t *neighbours,
                                 int nneighbours, bg_error_t *err);

/* One broker message for the resource role (ORDER, CFP, OFFER, ACCEPT,
 * REJECT, RELEASE; others are ignored). A message about a good it does not
 * sell or with a quantity out of range is refused naming why. The return
 * is a failure only for a failed send or the machine's own failure. */
bg_status bga_rseller_on_message(bga_rseller_t *rs, const bga_mmsg_t *in, double now,
                                 bga_rseller_send_fn send, void *ctx, bg_error_t *err);

/* Ends the holds whose lease ran out by `now`. */
bg_status bga_rseller_tick(bga_rseller_t *rs, double now, bg_error_t *err);

/* What the role says of itself in REGISTER and HEARTBEAT: capacity, free
 * cores and GiB, floors, asking rates, margin, load slope. */
void bga_rseller_describe(const bga_rseller_t *rs, bga_mmsg_t *msg);

/* The asking rate for good 3 (cores) or 4 (memory), the machine's. */
double bga_rseller_price(const bga_rseller_t *rs, int good);
/* Cores (k = 0) or GiB (k = 1) held now. */
double bga_rseller_used(const bga_rseller_t *rs, int k);

#endif
