/*
 * bgm_seller — the basic-service seller's role machine: one agent that
 * sells runs of its service types (a few slots at a time) to jobs'
 * agents, and buys for each service it agrees to the resource bundle
 * (cores, memory, a run time) that runs it, under every mechanism:
 * asks to and matches from the central auctioneer, proposals and
 * bargaining after a call for proposals, orders at its posted price.
 *
 * Sans-I/O and share-nothing: it reads only its own state and the
 * message it is handed, and emits into an outbox (bgm_outbox.h). What it
 * reads of a buyer's request travels in the message:
 *   MATCH   good, price (the clearing price), a = work, b = its own ask,
 *           c = the bid's deadline, origin = the buyer
 *   CFP     good, req, attempt, origin, hops
 *   OFFER   price, good, a = work, cand_price[2] = until when it stands,
 *           hops = 1 when it opens a bargain
 *   ACCEPT  price, good, a = work, cand_price[2] as OFFER's
 *   ORDER   price (its posted one), good, a = work, cand_price[2] as OFFER's
 *   TAKE, REFUSE  req, origin = its bundle's number
 * It answers PROPOSE, OFFER, ACCEPT, REJECT, CANCEL (an agreed service
 * lost its resources) and, once the bundle is rented, CONFIRM (a
 * delivery: req and attempt of the buyer, price per unit, a = start,
 * b = end, origin = its bundle); it announces itself to the market agent
 * (ASK; FREE and, baseline, AVAIL as its slots change).
 *
 * Its buying half is a bgm_purchase it embeds: one bundle request per
 * agreed service, carrying the deal it serves. The bargains it sells in
 * are its own too (bgm_session, catallactic).
 *
 * A message's sender is told apart by its id: jobs' agents (buyers) and
 * resource sellers each have an id range, given at creation.
 */
#ifndef BGM_SELLER_H
#define BGM_SELLER_H

#include <stdint.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_purchase.h"
#include "bgm_rng.h"
#include "bgm_role.h"
#include "bgm_strategy.h"

/* Its timers (the same numbers as the world's). */
#define BGM_SE_TIMER_RELEASE 6 /* a service's run ends: arg = its bundle's request */

typedef struct bgm_seller_params {
    const bgm_config_t *cfg; /* copied */
    int mechanism;           /* bgm_mechanism */
    uint32_t self, market;   /* its agent id, the market agent's */
    double horizon;          /* no learning meeting is scheduled after it */
    /* the senders it tells apart: jobs' agents and resource sellers */
    uint32_t first_buyer, nbuyers, first_resource, nresource;
    /* endowment: what it sells, its slots and its own cost per unit */
    int sells[BGM_SERVICE_TYPES];
    int slots;
    double cost[BGM_SERVICE_TYPES];
    /* strategy: its stream (already used for the genes), genes, opening markup */
    bgm_rng_t rng;
    bgm_genes_t genes;
    double markup;
    /* overlay neighbours, and which of them sell services too (learning) */
    const uint32_t *neighbours;
    const uint8_t *same_role;
    int degree; /* <= BGM_PU_MAX_NEIGHBOURS */
    /* Live hosting (all 0 in the simulator, which then behaves as before):
     * its asking price rises by load_slope · used / slots (bgm_seller_asking);
     * a bundle's budget is at most resource_headroom times the resources
     * it expects a unit to need (0: the whole price of the service); and,
     * when posted_follows_cost is set, its posted price is its reservation
     * times (1 + baseline markup) again after each delivery it learns from. */
    double load_slope, resource_headroom;
    int posted_follows_cost;
} bgm_seller_params_t;

typedef struct bgm_seller bgm_seller_t;

/* NULL when out of memory or degree is over the cap. */
bgm_seller_t *bgm_seller_new(const bgm_seller_params_t *p);
void bgm_seller_destroy(bgm_seller_t **s);

/* Asks the market agent for its types (central: its reservation;
 * baseline: its posted price) or schedules its first learning meeting
 * (catallactic). */
bg_status bgm_seller_start(bgm_seller_t *s, double now, bgm_outbox_t *out);
/* Handles one message addressed to it; `up` says whether its host is up.
 * A bundle request it opens is numbered *next_req, which it advances. */
bg_status bgm_seller_on_message(bgm_seller_t *s, const bgm_msg_t *in, double now, int up,
                                uint32_t *next_req, bgm_outbox_t *out);
bg_status bgm_seller_on_timer(bgm_seller_t *s, int kind, uint64_t arg, double now, int up,
                              bgm_outbox_t *out);

/* Its bundle request `id` (deal, size, budget, creation, seller, rate,
 * rental, parts), NULL when it has none of that number; the parts of
 * bundles it was confirmed in parts, until the delivery is answered or
 * over. Borrowed, valid until the next call on s: the host's observer
 * books contracts from them. */
const bgm_purchase_req_t *bgm_seller_bundle(bgm_seller_t *s, uint32_t id);
size_t bgm_seller_part_count(const bgm_seller_t *s);
const bgm_purchase_part_t *bgm_seller_part(const bgm_seller_t *s, size_t i);
/* Its overlay neighbours from now on, as bgm_purchase_set_neighbours. */
bg_status bgm_seller_set_neighbours(bgm_seller_t *s, const uint32_t *neighbours,
                                    const uint8_t *same_role, int degree);
/* Forgets its bundle request `id` once it has ended and its delivery is
 * over (its slot given back): a long-lived host keeps only those in play.
 * Returns whether it did. */
int bgm_seller_forget(bgm_seller_t *s, uint32_t id);
/* Slots in use now. */
int bgm_seller_used(const bgm_seller_t *s);
/* Its reservation for a service good (its own cost plus the resources it
 * expects a unit to need): it sells no unit below it. */
double bgm_seller_reservation(const bgm_seller_t *s, int good);
/* Its posted price for a good at its load now:
 *     posted · (1 + load_slope · used / slots). */
double bgm_seller_asking(const bgm_seller_t *s, int good);
/* A host whose seller meets no neighbour to learn from holds its
 * strategy fixed: its markup stays the one it was created with and it
 * remembers no service price, so it opens every bargain at
 * reservation · (1 + markup). It still learns what resources cost. */
void bgm_seller_fix_strategy(bgm_seller_t *s);
/* Adds its bundle requests, attempts and timeouts to *t, for the host's metrics. */
void bgm_seller_counts(const bgm_seller_t *s, bgm_purchase_tally_t *t);

#endif
