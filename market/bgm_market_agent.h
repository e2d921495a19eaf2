/*
 * bgm_market_agent — the market agent's role machine: the auctioneer of
 * the central market (a k-double call market per service type each
 * period, and the resource layer through the combinatorial exchange or a
 * call market per resource type) and the directory of posted prices of
 * the baseline (first fit).
 *
 * Sans-I/O and share-nothing: it reads only its own records and the
 * message it is handed, and emits messages and timers into an outbox
 * (bgm_outbox.h) that its host routes. What it knows of a bid (its good,
 * limit, work, bundle and deadline) is what the bid carried; what it knows
 * of a seller is what the seller announced (ASK, RASK, FREE, RFREE,
 * AVAIL). It never learns a buyer's state: a bid leaves the book when it
 * is matched or its deadline has passed (its buyer gives up on its own at
 * the deadline, so an expired bid is dropped without a message).
 *
 * Messages it reads (bgm_role.h numbers, fields of bgm_msg_t):
 *   BID    good, price = limit per unit, a = work, b = deadline,
 *          cand[0..ncand) = sellers it must not be matched with, origin =
 *          its need group (0: none; bids of one buyer and group are matched
 *          with distinct sellers). The simulator's buyers send neither; a
 *          live buyer excludes the sellers a unit tried and those its
 *          split need has already.
 *   RBID   price = limit in all, a = cores, b = GiB, c = flops, cand_price[0] = deadline
 *   ASK    good, price = reservation (posted price for the baseline), a = slots (< 0: unchanged)
 *   FREE   one slot free;   RFREE a = cores, b = GiB freed
 *   RASK   a = cores, b = GiB, c = speed, price = cost per core-second,
 *          cand_price[0] = cost per GiB-second
 *   AVAIL  a = free slots | cores, b = free GiB (baseline)
 *   QUERY  good (cores: a bundle of a cores and b GiB), price = limit,
 *          cand[0..ncand) = sellers not to list
 * Messages it sends: MATCH (to the basic seller) and ACCEPT (to the
 * buyer) per service fill, RAWARD or RPART per resource award, LIST per
 * query.
 *
 * Agent ids: the sellers are numbered in two ranges given at creation
 * (basic sellers first_basic.., resource sellers first_resource..); the
 * market agent's table is indexed by those ranges.
 */
#ifndef BGM_MARKET_AGENT_H
#define BGM_MARKET_AGENT_H

#include <stdint.h>

#include "bg_error.h"
#include "bgm_callmarket.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_role.h"

/* Its timer: the clearing period (the same number as the world's). */
#define BGM_MA_TIMER_CLEAR 2
/* Service clearings a timer call records at most (bgm_market_agent_clearings). */
#define BGM_MA_CLEARINGS_MAX 64

/* One service clearing that traded, as the last timer call made it: the
 * uniform clearing of good `good`'s book, or a bid's clearing alone
 * against the sellers it allows. `res` names the orders that set its
 * bounds (a bid: owner = its buyer, ref = its request; an ask: owner =
 * its seller). Its matches are the MATCH messages the call emitted from
 * the `first`-th (counting MATCHes only, from 0), `count` of them. */
typedef struct bgm_ma_clearing {
    int good;
    bgm_clearing_t res;
    size_t first, count;
} bgm_ma_clearing_t;

typedef struct bgm_market_agent_params {
    const bgm_config_t *cfg; /* copied: central, baseline, resources, network.speed */
    int mechanism;           /* bgm_mechanism */
    uint32_t self;           /* its agent id */
    uint32_t first_basic, nbasic, first_resource, nresource;
    double horizon; /* no clearing is scheduled after it */
} bgm_market_agent_params_t;

typedef struct bgm_market_agent bgm_market_agent_t;

/* NULL when out of memory. */
bgm_market_agent_t *bgm_market_agent_new(const bgm_market_agent_params_t *p);
void bgm_market_agent_destroy(bgm_market_agent_t **ma);

/* Emits its first timer (the first clearing, central only). */
bg_status bgm_market_agent_start(bgm_market_agent_t *ma, double now, bgm_outbox_t *out);
/* Handles one message addressed to it (borrowed). BG_ERR_LIMIT when a
 * book is full, BG_ERR_INVALID for a sender outside the seller ranges. */
bg_status bgm_market_agent_on_message(bgm_market_agent_t *ma, const bgm_msg_t *in, double now,
                                      bgm_outbox_t *out);
/* Fires one of its timers (BGM_MA_TIMER_CLEAR): clears every book. */
bg_status bgm_market_agent_on_timer(bgm_market_agent_t *ma, int kind, uint64_t arg, double now,
                                    bgm_outbox_t *out);

/* A live host's bookkeeping, not a message: a seller that left the grid
 * is forgotten (no slots, no postings, sells nothing) so that its id can
 * be given to another; a buyer whose job ended has its bids dropped
 * rather than matched after it stopped listening. */
void bgm_market_agent_forget_seller(bgm_market_agent_t *ma, uint32_t seller);
void bgm_market_agent_forget_bids(bgm_market_agent_t *ma, uint32_t buyer);

/* How the resource layer's winners were determined so far: exact
 * programs and greedy fallbacks of the combinatorial exchange. */
void bgm_market_agent_counts(const bgm_market_agent_t *ma, double *exact, double *greedy);
/* The service clearings of its last timer call that traded, in the
 * order they were made (at most BGM_MA_CLEARINGS_MAX: a host explains a
 * match's price from its clearing; the price itself is in the MATCH).
 * Borrowed until the next call; *n gets their number. */
const bgm_ma_clearing_t *bgm_market_agent_clearings(const bgm_market_agent_t *ma, size_t *n);
/* Bids in its books (service, resource), for tests. */
void bgm_market_agent_books(const bgm_market_agent_t *ma, size_t *bids, size_t *rbids);

#endif
