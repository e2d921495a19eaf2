/*
 * bgm_resource — the resource seller's role machine: one agent that rents
 * its host's cores and memory for a time, under every mechanism (awards
 * and parts from the central market agent, bargaining after a call for
 * proposals, orders at its posted rate), and learns its strategy from
 * overlay neighbours of its role (catallactic).
 *
 * Sans-I/O and share-nothing: it reads only its own state and the message
 * it is handed, and emits into an outbox (bgm_outbox.h). What it reads of
 * a bundle travels in the message that asks for it:
 *   RAWARD  price = rate, a = cores, b = GiB, c = flops, cand_price[1] = budget, origin = buyer
 *   RPART   good = cores|memory, a = quantity, b = duration, price = rate per unit-second,
 *           c = buyer's limit per unit-second, hops = parts, origin = buyer, cand_price[0] = start
 *   CFP     good < 0 for a bundle: a = cores, b = GiB, c = flops; hops, origin
 *   OFFER   price; a, b, c the bundle; cand_price[1] = budget, cand_price[2] = the
 *           buyer's deadline (the offer stands until then); hops = 1 on the first
 *           offer of a bargain
 *   ACCEPT  price; a, b, c the bundle; cand_price[1] = budget
 *   ORDER   price (the posted rate); a, b, c the bundle; cand_price[1..2] as OFFER
 *   GENES   cand_price[0..4] = genes, price = fitness, a = 1 for a request
 * A seller with share_phases also reads, in every message asking for a
 * whole bundle (RAWARD, CFP, OFFER, ACCEPT, ORDER), the job the bundle
 * serves and its phase: ncand = 2, cand[0] = the job (non-zero),
 * cand[1] = the phase (< BGM_RS_PHASES); without them the bundle counts
 * alone.
 * It answers with RCONFIRM (a bundle or a part held from now; c = its
 * cost rate; for a part cand_price[0..2] = quantity, buyer limit, cost),
 * RFAIL + RFREE (an award it cannot take), PROPOSE, OFFER, REJECT, GENES,
 * and announces itself to the market agent (RASK, RFREE, AVAIL).
 *
 * Its bargaining state is its own (bgm_session): one session per (buyer,
 * request, attempt), opened by an offer that says so; a fixed ring of
 * sessions, the oldest reused first (a seller bargains with a few buyers
 * at a time).
 */
#ifndef BGM_RESOURCE_H
#define BGM_RESOURCE_H

#include <stdint.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_rng.h"
#include "bgm_role.h"
#include "bgm_strategy.h"

/* Its timers (the same numbers as the world's). */
#define BGM_RS_TIMER_RELEASE 6      /* a whole bundle ends: arg = request */
#define BGM_RS_TIMER_RELEASE_PART 7 /* a part ends: arg from the part's good and quantity */
#define BGM_RS_TIMER_LEARN 8        /* a learning meeting */

#define BGM_RS_MAX_NEIGHBOURS 64
/* Phases a job's bundles may name under share_phases. */
#define BGM_RS_PHASES 8

typedef struct bgm_resource_params {
    const bgm_config_t *cfg; /* copied */
    int mechanism;           /* bgm_mechanism */
    uint32_t self, market;   /* its agent id, the market agent's */
    double horizon;          /* no learning meeting is scheduled after it */
    /* endowment */
    double cores, memory, core_cost, memory_cost, speed;
    /* strategy: its stream (already used for the genes), genes, opening markup */
    bgm_rng_t rng;
    bgm_genes_t genes;
    double markup;
    /* overlay neighbours, and which of them sell resources too (learning) */
    const uint32_t *neighbours;
    const uint8_t *same_role;
    int degree; /* <= BGM_RS_MAX_NEIGHBOURS */
    /* Cores sold to the phases of one job that never run at once are
     * counted once: the job occupies the most any one of its phases holds
     * (the sum over the bundles of that phase), not the sum over all its
     * bundles. Memory is always the sum (every phase keeps its state).
     * The live grid's sellers set it: a job's services run one after
     * another. 0 in the simulator, whose bundles name no job. */
    int share_phases;
} bgm_resource_params_t;

typedef struct bgm_resource bgm_resource_t;

/* NULL when out of memory or degree is over the cap. */
bgm_resource_t *bgm_resource_new(const bgm_resource_params_t *p);
void bgm_resource_destroy(bgm_resource_t **rs);

/* Registers with the market agent (central, baseline) or schedules its
 * first learning meeting (catallactic). */
bg_status bgm_resource_start(bgm_resource_t *rs, double now, bgm_outbox_t *out);
/* Handles one message addressed to it; `up` says whether its host is up
 * (a seller on a failed host takes nothing on). */
bg_status bgm_resource_on_message(bgm_resource_t *rs, const bgm_msg_t *in, double now, int up,
                                  bgm_outbox_t *out);
bg_status bgm_resource_on_timer(bgm_resource_t *rs, int kind, uint64_t arg, double now, int up,
                                bgm_outbox_t *out);

/* Cores and GiB held now, for tests and hosts (a live daemon heartbeats
 * what is free); with share_phases each job's cores count as its widest
 * phase's. */
void bgm_resource_used(const bgm_resource_t *rs, double *cores, double *memory);

/* The cores a bundle of `cores` for phase `phase` of job `group` would
 * add to what is sold now: all of them without share_phases or a job,
 * else only what the phase would hold beyond the job's widest phase (for
 * a host's diagnostics; the machine decides on its own). */
double bgm_resource_cores_added(const bgm_resource_t *rs, uint32_t group, int phase, double cores);

/* A live host learns its overlay neighbours only when the broker answers
 * its registration: replaces them (BG_ERR_INVALID over the cap). */
bg_status bgm_resource_set_neighbours(bgm_resource_t *rs, const uint32_t *neighbours,
                                      const uint8_t *same_role, int degree);

/* Keeps its markup and remembered price from now on (a live host: its
 * buyer, the broker, never tells it when it walks away, so learning only
 * from its own outcomes would ratchet its prices up). */
void bgm_resource_fix_strategy(bgm_resource_t *rs);

/* Its asking rate per unit-second of good (BGM_GOOD_CORES_ID or
 * BGM_GOOD_MEMORY_ID; 0 for any other): its cost marked up by its current
 * markup and by its load,
 *     cost · (1 + markup) · (1 + load_slope · held / capacity).
 * The live grid posts it; the simulator's directory prices posted
 * bundles itself from the registered cost, so the simulator never asks. */
double bgm_resource_asking(const bgm_resource_t *rs, int good, double load_slope);

#endif
