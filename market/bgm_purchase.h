/*
 * bgm_purchase — the buying half of a market agent, embedded by the two
 * role machines that buy: the complex-service buyer (bgm_buyer: one
 * service item of a job per request) and the basic-service seller
 * (bgm_seller: one resource bundle per service it agreed to). It is not a
 * role of its own: it has no agent id beyond its owner's and every
 * message it emits is its owner's.
 *
 * What it holds is its owner's only: the owner's trader state (strategy
 * genes, fitness, markup, remembered prices and the stream its bargaining
 * draws from, which the owner's selling side shares), its overlay
 * neighbours and the calls for proposals it has seen, and its requests:
 * per request the item, its phase (discover, negotiate, wait, committed,
 * done, failed), attempt, phase-timer generation, deadline, the
 * proposals or candidates it is working through and, for a bundle
 * bought in parts, the parts confirmed so far. It reads only those and
 * the messages its owner hands it, and emits into an outbox.
 *
 * Acquisition by mechanism: central, one BID (a service) or RBID (a
 * bundle) and the auctioneer's answer; catallactic, a hop-limited CFP
 * over the overlay (at most overlay_degree calls from each agent,
 * bgm_flood), the proposals gathered for a discovery window, then
 * bargaining with them cheapest first; baseline, a QUERY to the
 * directory, then an ORDER at the posted price to the first candidate
 * within the limit. Its timers follow what it measures, as TCP's do
 * (RFC 6298): a phase waits the owner's smoothed round trip plus four
 * mean deviations (doubled after each timeout until the next answer),
 * a discovery window the same of the delays of proposals, never less
 * than the configured reply_timeout (4x for the directory) and
 * discovery_timeout. A failed attempt is retried after the mechanism's
 * backoff, doubling with each round (BGM_PU_RETRY_MAX_DOUBLINGS), while
 * the deadline allows; at the deadline (or when the owner's host is down
 * as it starts) the request fails for good. A request committed to a
 * seller gets BGM_PU_COMMIT_GRACE past its deadline for the seller's
 * delivery.
 *
 * Request numbers are the host's: the owner opens each request under a
 * number it is given, in increasing order (the simulator numbers every
 * request of a run in one sequence, so its contract log keeps one
 * numbering; a live host numbers per agent).
 */
#ifndef BGM_PURCHASE_H
#define BGM_PURCHASE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_rng.h"
#include "bgm_role.h"
#include "bgm_strategy.h"

/* Its timers (the same numbers as the world's). */
#define BGM_PU_TIMER_REQ 3      /* a phase times out: arg = request | generation << 32 */
#define BGM_PU_TIMER_DEADLINE 4 /* arg = request, bit 63 set for the commitment grace */
#define BGM_PU_TIMER_RETRY 5    /* arg = request | attempt << 32 */
#define BGM_PU_TIMER_LEARN 8    /* a learning meeting */

#define BGM_PU_MAX_NEIGHBOURS 64
/* Proposals a round of discovery keeps, and so bargains with at most. */
#define BGM_PU_MAX_PROPOSALS 8
/* A failed round is retried after retry_backoff x 2^(rounds so far - 1),
 * the doubling capped at this many times. */
#define BGM_PU_RETRY_MAX_DOUBLINGS 5
/* A request's good when it buys a resource bundle. */
#define BGM_PU_BUNDLE (-1)
/* How long past its deadline a request committed to a seller waits. */
#define BGM_PU_COMMIT_GRACE 30.0
/* Requests one owner may open in all, and parts it may hold at once
 * (bundles whose delivery is not answered yet, a few parts each). */
#define BGM_PU_MAX_REQS (1u << 22)
#define BGM_PU_MAX_PARTS ((size_t)1 << 16)

/* A request's phase. */
enum {
    BGM_PU_IDLE,
    BGM_PU_DISCOVER,
    BGM_PU_NEGOTIATE,
    BGM_PU_WAIT,
    BGM_PU_COMMITTED,
    BGM_PU_DONE,
    BGM_PU_FAILED
};

/* What both sides of an agent learn: its strategy and price memory. */
typedef struct bgm_trader {
    bgm_rng_t rng; /* bargaining and learning draws */
    bgm_genes_t genes;
    double fitness, markup;
    double memory[4]; /* remembered price per service good; [3]: resource rate over mean cost */
} bgm_trader_t;

/* A service deal as a basic seller knows it: what the buyer's message
 * (or the auctioneer's MATCH) said and the agreed terms. A bundle's
 * request carries the deal it serves for its owner; the purchase never
 * reads it. */
typedef struct bgm_deal {
    uint32_t buyer, req, attempt;
    int good;
    double work, deadline, price, limit;
} bgm_deal_t;

/* One request as its owner and the host's observer read it. The fields
 * from good to deadline are the item as opened; the purchase writes
 * state to end, the owner may write deal and delivered. */
typedef struct bgm_purchase_req {
    uint32_t id;
    int good;                    /* a service type, or BGM_PU_BUNDLE */
    double work;                 /* a service: units */
    double cores, memory, flops; /* a bundle: its size (0 for a service) */
    double limit;                /* a service: valuation per unit; a bundle: budget in all */
    double created, deadline;
    int state;
    uint32_t seller, attempt, tseq;
    double price;      /* agreed: per unit (a service), rate (a bundle) */
    double start, end; /* a bundle's rental once rented; a service's run once taken */
    uint32_t parts;    /* call markets: parts of the bundle confirmed so far */
    bgm_deal_t deal;   /* the owner's */
    int delivered;     /* the owner's: a bundle's service was delivered */
} bgm_purchase_req_t;

/* Call markets: one part of a bundle, held by its seller and confirmed. */
typedef struct bgm_purchase_part {
    uint32_t req, seller;
    int good;
    double quantity, start, end, rate, limit, cost;
} bgm_purchase_part_t;

/* What one call did that the owner acts on (at most one per call). */
typedef enum bgm_purchase_event_kind {
    BGM_PU_EV_NONE,
    BGM_PU_EV_FAILED, /* request `req` failed for good */
    BGM_PU_EV_RENTED  /* bundle `req` is rented (whole, or every part) */
} bgm_purchase_event_kind;

typedef struct bgm_purchase_event {
    bgm_purchase_event_kind kind;
    uint32_t req;
} bgm_purchase_event_t;

typedef struct bgm_purchase_params {
    const bgm_config_t *cfg; /* borrowed: its owner's copy, which outlives it */
    int mechanism;           /* bgm_mechanism */
    uint32_t self, market;   /* its owner's agent id, the market agent's */
    double horizon;          /* no learning meeting is scheduled after it */
    bgm_trader_t trader;     /* the owner's starting strategy */
    /* overlay neighbours (copied), and which of them share its owner's role */
    const uint32_t *neighbours;
    const uint8_t *same_role;
    int degree; /* <= BGM_PU_MAX_NEIGHBOURS */
    /* Catallactic: a request's discovery window doubles after each of its
     * rounds that no seller answered, at most this many times (0: a fixed
     * window, as the simulator runs). A live buyer whose sellers answer
     * late under load would otherwise hear, every round, only the last
     * round's stragglers (which it ignores). */
    int widen_quiet;
    /* Catallactic: discovery ends as soon as a round has as many proposals
     * as it sent calls, instead of at the window's end. For a host that
     * calls only the sellers it can hear (a live resource sub-job calls its
     * host's one resource seller): waiting out the window for nobody else
     * only adds it to every purchase. 0 in the simulator, whose calls
     * travel on over the overlay. */
    int close_when_heard;
} bgm_purchase_params_t;

typedef struct bgm_purchase bgm_purchase_t;

/* NULL when out of memory, degree is over the cap or widen_quiet outside [0, 16]. */
bgm_purchase_t *bgm_purchase_new(const bgm_purchase_params_t *p);
void bgm_purchase_destroy(bgm_purchase_t **pu);

/* The owner's trader state: borrowed, valid as long as pu. */
bgm_trader_t *bgm_purchase_trader(bgm_purchase_t *pu);
/* An outcome learnt into the trader's fitness and markup. */
void bgm_purchase_learn(bgm_purchase_t *pu, int success, double surplus_share);
/* From now on no outcome is learnt (bgm_seller_fix_strategy). */
void bgm_purchase_fix_strategy(bgm_purchase_t *pu);

/* Opens request `it->id` (greater than every id opened before) for the
 * item in it (good to deadline; the rest is ignored, deal copied) and
 * starts acquiring it: arms its deadline, then its first attempt. `up`
 * says whether the owner's host is up. */
bg_status bgm_purchase_open(bgm_purchase_t *pu, const bgm_purchase_req_t *it, double now, int up,
                            bgm_outbox_t *out, bgm_purchase_event_t *ev);

/* A message from a seller about one of its requests: PROPOSE, LIST,
 * OFFER, ACCEPT, REJECT, CANCEL, RFAIL or RCONFIRM (the owner tells a
 * seller's OFFER or ACCEPT from a buyer's). A message about a request it
 * does not hold, or a stale one, changes nothing. */
bg_status bgm_purchase_on_message(bgm_purchase_t *pu, const bgm_msg_t *m, double now,
                                  bgm_outbox_t *out, bgm_purchase_event_t *ev);
/* Its timers (BGM_PU_TIMER_*). */
bg_status bgm_purchase_on_timer(bgm_purchase_t *pu, int kind, uint64_t arg, double now, int up,
                                bgm_outbox_t *out, bgm_purchase_event_t *ev);

/* Its overlay neighbours from now on (a live host learns them when it
 * registers); BG_ERR_INVALID when degree is over the cap. */
bg_status bgm_purchase_set_neighbours(bgm_purchase_t *pu, const uint32_t *neighbours,
                                      const uint8_t *same_role, int degree);

/* Catallactic overlay duties every trading agent has. */
/* Whether a call for proposals was seen before (it is remembered if not). */
int bgm_purchase_cfp_seen(bgm_purchase_t *pu, const bgm_msg_t *m);
/* Passes a call on to its neighbours, one hop less, when hops remain. */
bg_status bgm_purchase_cfp_forward(bgm_purchase_t *pu, const bgm_msg_t *m, bgm_outbox_t *out);
/* Schedules its first learning meeting. */
bg_status bgm_purchase_learning_start(bgm_purchase_t *pu, double now, bgm_outbox_t *out);
/* GENES from a neighbour: learns only from one of its owner's role. */
bg_status bgm_purchase_on_genes(bgm_purchase_t *pu, const bgm_msg_t *m, bgm_outbox_t *out);

/* Request `id`, NULL when it holds none of that number. Borrowed: valid
 * until the next open. */
bgm_purchase_req_t *bgm_purchase_get(bgm_purchase_t *pu, uint32_t id);
/* The owner ends request `id` as bought (a service it took). */
void bgm_purchase_done(bgm_purchase_t *pu, uint32_t id);
/* Forgets request `id` once it has ended (done or failed), with its
 * parts: a long-lived host keeps only the requests still in play. Returns
 * whether it did; a later message or timer about it changes nothing. */
int bgm_purchase_forget(bgm_purchase_t *pu, uint32_t id);

/* The parts held for bundles not yet answered for, in arrival order.
 * Borrowed: valid until the next call on pu. */
size_t bgm_purchase_part_count(const bgm_purchase_t *pu);
const bgm_purchase_part_t *bgm_purchase_part(const bgm_purchase_t *pu, size_t i);
/* Forgets the parts of bundle `id` (its delivery was answered or is over). */
void bgm_purchase_drop_parts(bgm_purchase_t *pu, uint32_t id);

/* Which timeout fired: a round of calls for proposals nobody answered,
 * a seller quiet after an offer, order or acceptance, the directory
 * quiet after a query, a request's deadline. */
enum {
    BGM_PU_TO_DISCOVERY,
    BGM_PU_TO_REPLY,
    BGM_PU_TO_DIRECTORY,
    BGM_PU_TO_DEADLINE,
    BGM_PU_TO_KINDS
};

/* Counters for the host's metrics. */
typedef struct bgm_purchase_tally {
    double requests;                 /* opened */
    double attempts;                 /* acquisitions started (first ones and retries) */
    double timeouts;                 /* every kind */
    double timeout[BGM_PU_TO_KINDS]; /* by kind */
} bgm_purchase_tally_t;

/* Adds its counters to *t (so that a host sums its machines'). */
void bgm_purchase_counts(const bgm_purchase_t *pu, bgm_purchase_tally_t *t);

#endif
