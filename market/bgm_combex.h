/*
 * bgm_combex — winner determination for a combinatorial exchange of
 * resource bundles.
 *
 * Buyers bid for whole bundles (a vector of quantities: cores, memory, ...)
 * with a reservation price; sellers offer capacity in each dimension. The
 * caller lists the feasible (bid, seller) pairs with the surplus they would
 * create (bid value minus that seller's cost, which may depend on the
 * seller, e.g. through its speed) and the capacity they use; pairs that
 * miss a deadline or lose money are simply not listed. A bundle goes to at
 * most one seller and is never split.
 *
 *   maximise  sum surplus(b,s) x(b,s)
 *   s.t.      sum_s x(b,s) <= 1                   for every bid b
 *             sum_b use_d(b,s) x(b,s) <= cap_d(s) for every seller s, dim d
 *             x binary
 *
 * Exact: the integer program with GLPK (branch and cut) when the number of
 * pairs is at most exact_limit. Beyond that, or if GLPK does not prove
 * optimality within a node budget (deterministic, unlike a time limit), a greedy by decreasing surplus with a work budget (pairs
 * examined) in place of a wall-clock cap, so results stay deterministic.
 * The result says which ran. Pure: no I/O besides GLPK's (silenced).
 */
#ifndef BGM_COMBEX_H
#define BGM_COMBEX_H

#include <stddef.h>

#include "bg_error.h"

#define BGM_COMBEX_DIMS 2

typedef enum bgm_combex_method {
    BGM_COMBEX_AUTO = 0,
    BGM_COMBEX_EXACT = 1,
    BGM_COMBEX_GREEDY = 2
} bgm_combex_method;

typedef struct bgm_combex_pair {
    int bid;
    int seller;
    double surplus; /* > 0 */
    double use[BGM_COMBEX_DIMS];
} bgm_combex_pair_t;

typedef struct bgm_combex_result {
    bgm_combex_method method; /* which ran: EXACT or GREEDY */
    int optimal;              /* 1 when the exact solver proved optimality */
    double objective;         /* total surplus of the chosen pairs */
    long work;                /* pairs examined (greedy) or B&B nodes (exact) */
} bgm_combex_result_t;

typedef struct bgm_combex bgm_combex_t;

/* Caps: bids, sellers and pairs (hard limits on the book). */
bgm_combex_t *bgm_combex_new(int max_bids, int max_sellers, size_t max_pairs);
void bgm_combex_destroy(bgm_combex_t **cx);
/* Empties the book, keeps the buffers. */
void bgm_combex_reset(bgm_combex_t *cx);
/* Returns the new bid's index, or -1 when full. */
int bgm_combex_add_bid(bgm_combex_t *cx);
/* Returns the new seller's index, or -1 when full. */
int bgm_combex_add_seller(bgm_combex_t *cx, const double cap[BGM_COMBEX_DIMS]);
bg_status bgm_combex_add_pair(bgm_combex_t *cx, const bgm_combex_pair_t *pair);
size_t bgm_combex_pair_count(const bgm_combex_t *cx);
const bgm_combex_pair_t *bgm_combex_pairs(const bgm_combex_t *cx);

/* Exact-solver options: relative MIP gap accepted as optimal (0: proven
 * optimum) and the branch-and-bound node budget. */
void bgm_combex_set_exact(bgm_combex_t *cx, double mip_gap, long node_budget);

/*
 * Solves. assignment (caller-allocated, one entry per bid) receives the
 * index of the chosen pair or -1. AUTO picks EXACT when pairs <=
 * exact_limit. greedy_budget caps the pairs the greedy examines (<= 0:
 * unlimited).
 */
bg_status bgm_combex_solve(bgm_combex_t *cx, bgm_combex_method method, size_t exact_limit,
                           long greedy_budget, int *assignment, bgm_combex_result_t *result);

/*
 * Payments that respond to competition. For each winning pair (bid b,
 * seller s) with surplus S_bs, rent[b] receives the share of S_bs the
 * seller gets above its cost (the buyer keeps the rest), priced like the
 * k-double auction on an interval set by the orders left out:
 *   lo = the largest surplus an excluded bid would have created on s in
 *        b's place (it fits s's capacity left over plus b's use): s could
 *        have earned that from it, so b must pay at least as much;
 *   hi = S_bs minus the largest surplus b would have created with another
 *        seller that still has room for it after the allocation: b could
 *        have bought there, so it pays no more above cost than that saves;
 *   rent = lo' + k (hi' - lo'), with [lo', hi'] = [lo, hi] clipped into
 *        [0, S_bs] (and hi' >= lo').
 * Without competition the interval is [0, S_bs] and rent = k S_bs, the
 * plain k-pricing of the pair; excluded demand lifts it, spare supply
 * lowers it. Bids without a pair get 0. assignment is bgm_combex_solve's.
 */
bg_status bgm_combex_rents(const bgm_combex_t *cx, const int *assignment, double k, double *rent);

#endif
