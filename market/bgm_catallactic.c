#include "bgm_catallactic.h"

/* Offers within this relative distance of the side's own next price are
 * accepted: concessions shrink the gap geometrically and would otherwise
 * never close it exactly. The hard limit is checked separately. */
#define BGM_NEGO_REL_EPS 0.02

static double clamp_side(bgm_side side, double limit, double p)
{
    if (side == BGM_SIDE_BUYER)
        return p > limit ? limit : p;
    return p < limit ? limit : p;
}

void bgm_nego_open(bgm_nego_t *n, bgm_side side, double limit, double opening,
                   const bgm_genes_t *genes, int max_rounds)
{
    n->side = side;
    n->limit = limit;
    n->current = clamp_side(side, limit, opening);
    n->last_their = -1.0;
    n->rounds = 0;
    n->max_rounds = max_rounds;
    n->genes = *genes;
}

static int acceptable(const bgm_nego_t *n, double their, double next)
{
    if (n->side == BGM_SIDE_BUYER)
        return their <= n->limit && their <= next * (1.0 + BGM_NEGO_REL_EPS);
    return their >= n->limit && their >= next * (1.0 - BGM_NEGO_REL_EPS);
}

bgm_nego_action bgm_nego_respond(bgm_nego_t *n, double their, bgm_rng_t *rng, double *reply)
{
    n->rounds++;
    int conceded = 0;
    double next = n->current;
    if (bgm_rng_uniform(rng) >= n->genes.acquisitiveness) {
        next = n->current + n->genes.price_step * (their - n->current);
        next = clamp_side(n->side, n->limit, next);
        conceded = next != n->current;
    }
    if (acceptable(n, their, next)) {
        *reply = their;
        return BGM_NEGO_ACCEPT;
    }
    int stuck = next == n->limit && n->last_their >= 0.0 && their == n->last_their;
    n->last_their = their;
    if (n->rounds >= n->max_rounds || stuck)
        return BGM_NEGO_REJECT;
    if (!conceded && bgm_rng_uniform(rng) >= n->genes.satisfaction)
        return BGM_NEGO_REJECT;
    n->current = next;
    *reply = next;
    return BGM_NEGO_COUNTER;
}

double bgm_nego_opening(bgm_side side, double limit, double memory, double markup)
{
    double base = memory > 0.0 ? memory : limit;
    double p = side == BGM_SIDE_SELLER ? base * (1.0 + markup) : base * (1.0 - markup);
    return clamp_side(side, limit, p);
}
