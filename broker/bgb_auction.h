/*
 * bgb_auction — the broker's service-layer market agent: the simulator's
 * role machine (market/bgm_market_agent) hosted live, twice: one instance
 * is the central auctioneer (a k-double call market per service, cleared
 * every period), the other the posted-price directory (first fit). The
 * broker's live market (bgb_market) feeds them what a simulated seller
 * would announce and reads what they answer; this module only maps the
 * two: no mechanism code of its own.
 *
 * Sellers are named by their directory slot (0 ≤ slot <
 * BGB_AUCTION_MAX_SELLERS), buyers by a number the caller chooses below
 * BGB_AUCTION_MAX_BUYERS (the broker uses its job record's index), and a
 * bid or query by the caller's request number and attempt, which come
 * back with its match or list.
 *
 * What the machines know of a seller is what seller() last said: the
 * goods it sells at which asking price, and its free slots net of orders
 * the caller has in flight. Exclusions: a bid or query may name up to
 * BGB_AUCTION_MAX_EXCLUDE sellers it must not get; a bid's need group
 * (> 0) makes the bids of one buyer and group go to distinct sellers.
 *
 * Threading: one thread (the broker's ZeroMQ loop). Time: `now` is the
 * caller's monotonic seconds. Ownership: the caller owns what it passes.
 */
#ifndef BGB_AUCTION_H
#define BGB_AUCTION_H

#include <stdint.h>

#include "bg_error.h"

#define BGB_AUCTION_MAX_SELLERS 1024
#define BGB_AUCTION_MAX_BUYERS 1024
#define BGB_AUCTION_MAX_EXCLUDE 8
#define BGB_AUCTION_MAX_LIST 8 /* candidates a query returns at most */
#define BGB_AUCTION_SERVICES 3
#define BGB_AUCTION_MAX_CLEARINGS 64 /* clearings a tick names at most */

typedef struct bgb_auction bgb_auction_t;

/* The order that set one end of a clearing's price interval: a bid
 * (buyer, req) or a seller's ask (slot), matched or the first left out. */
typedef struct bgb_auction_bound {
    int is_bid, excluded;
    uint32_t buyer, req; /* a bid's */
    int slot;            /* an ask's seller; -1 for a bid */
    double price;        /* its limit: the bound */
} bgb_auction_bound_t;

/* A service clearing that traded (the rule: market/bgm_callmarket.h):
 * the price is low + k (high − low) when rationed (a buyer left out would
 * have paid the marginal ask), else low, the marginal ask. `index`
 * numbers the clearings of one tick from 0. */
typedef struct bgb_auction_clearing {
    int index, good, volume, rationed;
    double k, price, low, high;
    bgb_auction_bound_t low_by, high_by;
} bgb_auction_clearing_t;

/* A match of the central market: bid (buyer, req, attempt) gets one unit
 * from seller `slot` at `price`, the seller having asked `ask`, in
 * `clearing` (borrowed for the callback; NULL beyond the
 * BGB_AUCTION_MAX_CLEARINGS a tick names). The machine counts the slot as taken
 * until the next seller() call. */
typedef struct bgb_auction_match {
    uint32_t buyer, req, attempt;
    int good, slot;
    double price, ask;
    const bgb_auction_clearing_t *clearing;
} bgb_auction_match_t;

typedef void (*bgb_auction_match_fn)(void *ctx, const bgb_auction_match_t *m);

/* k in [0, 1], period > 0 s. Caller owns *out. */
bg_status bgb_auction_new(double k, double period, double now, bgb_auction_t **out,
                          bg_error_t *err);
void bgb_auction_destroy(bgb_auction_t **a);

/* Seller `slot` sells the goods whose bit is set in `goods` (bit g:
 * BGB_GOOD g < 3) at price[g] per unit, with `free_slots` free. */
bg_status bgb_auction_seller(bgb_auction_t *a, int slot, unsigned goods,
                             const double price[BGB_AUCTION_SERVICES], double free_slots,
                             bg_error_t *err);
/* The seller left: it sells nothing, and its slot may be given to another. */
void bgb_auction_forget_seller(bgb_auction_t *a, int slot);

/* A central bid for one unit of `good` (work units, at most `limit` per
 * unit), in the book until matched, forgotten or past `deadline`. */
bg_status bgb_auction_bid(bgb_auction_t *a, uint32_t buyer, uint32_t req, uint32_t attempt,
                          int good, double limit, double work, double deadline, uint32_t group,
                          const int *exclude, int nexclude, double now, bg_error_t *err);
/* The buyer's job ended: its bids leave the book. */
void bgb_auction_forget_buyer(bgb_auction_t *a, uint32_t buyer);

/* Clears when a clearing is due (match is called once per match, from
 * inside) and sets *next to the time of the next clearing. */
bg_status bgb_auction_tick(bgb_auction_t *a, double now, bgb_auction_match_fn match, void *ctx,
                           double *next, bg_error_t *err);

/* Posted: the sellers of `good` whose posted price is within `limit` and
 * that have a free slot, in the directory's first-fit order, leaving out
 * `exclude`; writes up to max (≤ 8) slots and posted prices and returns
 * how many, or -1 with err set. */
int bgb_auction_query(bgb_auction_t *a, uint32_t buyer, uint32_t req, int good, double limit,
                      const int *exclude, int nexclude, int *slots, double *prices, int max,
                      double now, bg_error_t *err);

#endif
