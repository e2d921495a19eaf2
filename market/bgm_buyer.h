/*
 * bgm_buyer — the complex-service buyer's role machine: the agent of a
 * stream of jobs. Jobs arrive at random (exponential gaps; a demand
 * shock divides the mean gap by its factor from its time on); each job
 * draws a plan (which service types it needs), and each service item of
 * it, its work and its valuation, is bought as one request by the
 * bgm_purchase it embeds, under every mechanism (a BID to the central
 * auctioneer, a call for proposals and bargaining, a QUERY to the
 * directory and an ORDER).
 *
 * Sans-I/O and share-nothing: it reads only its own state and the
 * message it is handed, and emits into an outbox (bgm_outbox.h). What it
 * reads of a seller travels in the message (PROPOSE, LIST, OFFER,
 * ACCEPT, REJECT, CANCEL); a delivery is CONFIRM (req, attempt, price
 * per unit, a = start, b = end, origin = the seller's bundle), which it
 * answers TAKE when it still wants the item from that seller on that
 * attempt and the run has not ended (taking is the step at which the
 * item is bought, once), REFUSE otherwise, with the same origin.
 *
 * Its demand draws come from their own stream, given at creation, so
 * that every mechanism faces the same jobs.
 */
#ifndef BGM_BUYER_H
#define BGM_BUYER_H

#include <stdint.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_purchase.h"
#include "bgm_rng.h"
#include "bgm_role.h"
#include "bgm_strategy.h"

/* Its timers (the same numbers as the world's). */
#define BGM_BU_TIMER_ARRIVAL 1 /* the next job arrives */

typedef struct bgm_buyer_params {
    const bgm_config_t *cfg; /* copied */
    int mechanism;           /* bgm_mechanism */
    uint32_t self, market;   /* its agent id, the market agent's */
    double horizon;          /* no learning meeting is scheduled after it */
    double arrival_end;      /* no job arrives after it */
    bgm_rng_t demand;        /* its demand stream: arrivals, plans, work, valuations */
    /* strategy: its stream (already used for the genes), genes, opening markup */
    bgm_rng_t rng;
    bgm_genes_t genes;
    double markup;
    /* overlay neighbours, and which of them are jobs' agents too (learning) */
    const uint32_t *neighbours;
    const uint8_t *same_role;
    int degree; /* <= BGM_PU_MAX_NEIGHBOURS */
} bgm_buyer_params_t;

typedef struct bgm_buyer bgm_buyer_t;

/* NULL when out of memory or degree is over the cap. */
bgm_buyer_t *bgm_buyer_new(const bgm_buyer_params_t *p);
void bgm_buyer_destroy(bgm_buyer_t **b);

/* Schedules its first job's arrival and (catallactic) its first
 * learning meeting. */
bg_status bgm_buyer_start(bgm_buyer_t *b, double now, bgm_outbox_t *out);
bg_status bgm_buyer_on_message(bgm_buyer_t *b, const bgm_msg_t *in, double now, int up,
                               bgm_outbox_t *out);
/* Its timers; on an arrival with its host up, a job's requests are
 * numbered from *next_req, which it advances. */
bg_status bgm_buyer_on_timer(bgm_buyer_t *b, int kind, uint64_t arg, double now, int up,
                             uint32_t *next_req, bgm_outbox_t *out);

/* Its request `id` (good, work, valuation per unit, creation, deadline,
 * state), NULL when it has none of that number. Borrowed, valid until the
 * next call on b: the host's observer reads what it needs from it. */
const bgm_purchase_req_t *bgm_buyer_request(bgm_buyer_t *b, uint32_t id);
/* Jobs arrived so far. */
uint32_t bgm_buyer_jobs(const bgm_buyer_t *b);
/* Service items of type good requested so far and their valuations
 * per unit summed. */
void bgm_buyer_demand(const bgm_buyer_t *b, int good, double *requested, double *valuation_sum);
/* Adds its requests, attempts and timeouts to *t, for the host's metrics. */
void bgm_buyer_counts(const bgm_buyer_t *b, bgm_purchase_tally_t *t);

#endif
