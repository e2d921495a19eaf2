/*
 * bgm_catallactic — one side of a bilateral alternating-offers bargain.
 *
 * A pure state machine: the side is opened with its hard limit (a buyer's
 * valuation, a seller's cost) and an opening price; each offer from the
 * other side produces ACCEPT (at the other side's price), COUNTER (with a
 * new own price) or REJECT (walk away). Concession follows the genes:
 * with probability acquisitiveness the side holds its price; otherwise it
 * moves price_step of the gap toward the other's offer. A side that did
 * not concede continues with probability satisfaction. Hard limits hold by
 * construction: a buyer never offers or accepts above its limit, a seller
 * never below. An offer within 2 % of the side's own next price is
 * accepted (geometric concessions never meet exactly). Bargaining ends with REJECT after max_rounds, or as soon as
 * both sides sit at their limits without overlap (a clean failure).
 * Time-outs belong to the caller (the agent), which owns the clock.
 */
#ifndef BGM_CATALLACTIC_H
#define BGM_CATALLACTIC_H

#include "bgm_rng.h"
#include "bgm_strategy.h"

typedef enum bgm_side { BGM_SIDE_BUYER = 0, BGM_SIDE_SELLER = 1 } bgm_side;

typedef enum bgm_nego_action {
    BGM_NEGO_ACCEPT = 0,
    BGM_NEGO_COUNTER = 1,
    BGM_NEGO_REJECT = 2
} bgm_nego_action;

typedef struct bgm_nego {
    bgm_side side;
    double limit;      /* hard limit */
    double current;    /* own standing offer */
    double last_their; /* the other side's previous offer (< 0: none) */
    int rounds;
    int max_rounds;
    bgm_genes_t genes;
} bgm_nego_t;

/* Opens a side; the opening price is clamped to the limit. */
void bgm_nego_open(bgm_nego_t *n, bgm_side side, double limit, double opening,
                   const bgm_genes_t *genes, int max_rounds);

/*
 * Responds to the other side's offer `their`. On COUNTER *reply is the new
 * own price; on ACCEPT *reply is `their` (the agreed price).
 */
bgm_nego_action bgm_nego_respond(bgm_nego_t *n, double their, bgm_rng_t *rng, double *reply);

/* Opening price from a remembered market price and the side's markup in
 * [0, 1]: a seller asks memory * (1 + markup), a buyer offers
 * memory * (1 - markup); clamped to the limit. memory <= 0 opens at the
 * limit scaled by the markup. */
double bgm_nego_opening(bgm_side side, double limit, double memory, double markup);

#endif
