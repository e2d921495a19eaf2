/*
 * bgm_callmarket — a periodic call market (double auction) for one good.
 *
 * Orders accumulate in a book; bgm_callmarket_clear matches the highest
 * bids with the lowest asks while bid >= ask and prices every trade at one
 * uniform price. With b_m the lowest matched bid, a_m the highest matched
 * ask, b_x the first excluded bid (the highest unit not bought; -inf when
 * every bid is filled) and a_x the first excluded ask (+inf when every ask
 * is filled), every price in
 *     [lo, hi] = [max(a_m, b_x), min(b_m, a_x)]
 * keeps every matched trader willing and every excluded one out. lo <= hi
 * always: a_m <= b_m (they trade), b_x <= b_m and a_m <= a_x (sorted),
 * b_x < a_x (matching stopped).
 *
 * Where in [lo, hi]: the k-double auction (Rustichini, Satterthwaite and
 * Williams 1994) takes p = lo + k (hi - lo), k in [0, 1], and this market
 * does so when demand is rationed: some buyer left out would pay at least
 * the marginal ask (b_x >= a_m), so buyers compete, lo = b_x is a
 * competitor's bid and the price rises towards the buyers' limits as
 * more of them are left out. When no buyer willing to pay the sellers'
 * price is left out (b_x < a_m, or none), nothing but the matched buyers'
 * own limits stands above a_m, and p = lo = a_m: the marginal seller's
 * ask. The textbook rule prices such a book at a_m + k (min(b_m, a_x) -
 * a_m), which makes the price jump by the buyers' limits with whether a
 * seller happens to have one unit to spare: one seller with two free
 * units and one bid prices at its ask (its unsold unit is a_x = a_m),
 * the same seller with one free unit at the midpoint between its ask and
 * the buyer's limit. In the live market, where a limit is a job's budget
 * split over its units, that was a lone job paying ~140 times its usual
 * price one time in three (issue 28). The rule here is monotone: more
 * demand never lowers the price, more supply never raises it, and a
 * price above every matched ask always names a buyer left out.
 *
 * Every clearing says which orders set its bounds (low_by, high_by) and
 * whether k placed the price (rationed), so a price can be explained from
 * the orders alone. No buyer pays above its bid, no seller receives below
 * its ask. Ties break by the order reference, so clearing is
 * deterministic. Pure: no I/O, no clock, no randomness.
 */
#ifndef BGM_CALLMARKET_H
#define BGM_CALLMARKET_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

typedef struct bgm_order {
    uint64_t ref;   /* caller's reference (request id, agent id) */
    uint32_t owner; /* agent id */
    int quantity;   /* units, > 0 */
    double price;   /* limit price per unit */
} bgm_order_t;

typedef struct bgm_fill {
    size_t bid; /* index into the book's bids at clearing time */
    size_t ask; /* index into the book's asks at clearing time */
    int quantity;
} bgm_fill_t;

/* The order that set one end of a clearing's interval. */
typedef struct bgm_bound {
    int is_bid;     /* a bid (else an ask) */
    int excluded;   /* left out of the trade (else the marginal matched order) */
    uint32_t owner; /* the order's owner and reference, as placed */
    uint64_t ref;
    double price; /* its limit: the bound */
} bgm_bound_t;

typedef struct bgm_clearing {
    int volume;       /* units traded */
    double price;     /* uniform price; meaningless when volume == 0 */
    double bid_limit; /* marginal bid b_m */
    double ask_limit; /* marginal ask a_m */
    double bid_excluded; /* first excluded bid b_x, -INFINITY when none */
    double ask_excluded; /* first excluded ask a_x, +INFINITY when none */
    double low, high;    /* the price interval [lo, hi] */
    /* Who set lo (the marginal ask, or an excluded bid) and hi (the
     * marginal bid, or an excluded ask); when volume > 0. */
    bgm_bound_t low_by, high_by;
    int rationed; /* b_x >= a_m: p = lo + k (hi - lo); else p = lo */
    size_t fill_count;
} bgm_clearing_t;

typedef struct bgm_callmarket bgm_callmarket_t;

/* max_orders caps each side of the book. */
bgm_callmarket_t *bgm_callmarket_new(size_t max_orders);
void bgm_callmarket_destroy(bgm_callmarket_t **cm);
/* Empties both books for the next call, keeping their storage: a fresh
 * market per call would allocate and clear the full capacity each time. */
void bgm_callmarket_reset(bgm_callmarket_t *cm);

bg_status bgm_callmarket_bid(bgm_callmarket_t *cm, const bgm_order_t *order);
bg_status bgm_callmarket_ask(bgm_callmarket_t *cm, const bgm_order_t *order);
size_t bgm_callmarket_bid_count(const bgm_callmarket_t *cm);
size_t bgm_callmarket_ask_count(const bgm_callmarket_t *cm);
/* Borrowed views, valid until the next call that changes the book. */
const bgm_order_t *bgm_callmarket_bids(const bgm_callmarket_t *cm);
const bgm_order_t *bgm_callmarket_asks(const bgm_callmarket_t *cm);

/*
 * Clears the book at k-pricing parameter k (the price rule above). Fills are written to fills
 * (caller-allocated, at most max_fills; a fill never spans two orders so
 * bids + asks fills always suffice). The book is not modified: the caller
 * decides what to do with filled and unfilled orders (see _remove_filled).
 */
bg_status bgm_callmarket_clear(bgm_callmarket_t *cm, double k, bgm_clearing_t *result,
                               bgm_fill_t *fills, size_t max_fills);

/* Removes filled quantities (from the last clearing's fills) from the book. */
void bgm_callmarket_remove_filled(bgm_callmarket_t *cm, const bgm_fill_t *fills, size_t count);

/* Removes every order whose (owner, ref) pass keep() == 0. */
void bgm_callmarket_filter(bgm_callmarket_t *cm, int (*keep)(const bgm_order_t *, int is_bid, void *),
                           void *ctx);

#endif
