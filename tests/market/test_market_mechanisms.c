/*
 * Unit tests of the market mechanisms, driven without SimGrid: the call
 * market and the combinatorial exchange on hand-made books, the offline
 * optimum against exhaustive search, alternating offers through the
 * deterministic event queue, timeouts, config validation, the audit
 * invariants over whole in-process runs (both resource markets of the
 * central mechanism), and price convergence after a demand shock against
 * the competitive equilibrium.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_json.h"
#include "bgm_budget.h"
#include "bgm_callmarket.h"
#include "bgm_catallactic.h"
#include "bgm_combex.h"
#include "bgm_config.h"
#include "bgm_evq.h"
#include "bgm_heap.h"
#include "bgm_optimum.h"
#include "bgm_outbox.h"
#include "bgm_posted.h"
#include "bgm_rng.h"
#include "bgm_world.h"

#define EPS 1e-9

/* ------------------------------------------------------------ call market */

static void add_bid(bgm_callmarket_t *cm, uint64_t ref, int q, double p)
{
    bgm_order_t o = {ref, (uint32_t)ref, q, p};
    assert_int_equal(bgm_callmarket_bid(cm, &o), BG_OK);
}

static void add_ask(bgm_callmarket_t *cm, uint64_t ref, int q, double p)
{
    bgm_order_t o = {ref, (uint32_t)ref, q, p};
    assert_int_equal(bgm_callmarket_ask(cm, &o), BG_OK);
}

static void test_callmarket_uniform_price(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(16);
    assert_non_null(cm);
    add_bid(cm, 1, 1, 10.0);
    add_bid(cm, 2, 1, 6.0);
    add_bid(cm, 3, 1, 8.0);
    add_bid(cm, 4, 1, 4.0);
    add_ask(cm, 11, 1, 9.0);
    add_ask(cm, 12, 1, 3.0);
    add_ask(cm, 13, 1, 7.0);
    add_ask(cm, 14, 1, 5.0);
    bgm_fill_t fills[8];
    bgm_clearing_t res;
    /* Matches 10/3 and 8/5; 6 < 7 stops. Marginal pair (8, 5), first
     * excluded bid 6 and ask 7: the price lies in [max(5, 6), min(8, 7)]. */
    const double ks[3] = {0.0, 0.5, 1.0}, expect[3] = {6.0, 6.5, 7.0};
    for (int i = 0; i < 3; i++) {
        assert_int_equal(bgm_callmarket_clear(cm, ks[i], &res, fills, 8), BG_OK);
        assert_int_equal(res.volume, 2);
        assert_float_equal(res.bid_limit, 8.0, EPS);
        assert_float_equal(res.ask_limit, 5.0, EPS);
        assert_float_equal(res.bid_excluded, 6.0, EPS);
        assert_float_equal(res.ask_excluded, 7.0, EPS);
        assert_float_equal(res.price, expect[i], EPS);
    }
    /* The high bid trades with the low ask. */
    const bgm_order_t *bids = bgm_callmarket_bids(cm), *asks = bgm_callmarket_asks(cm);
    assert_int_equal(bids[fills[0].bid].ref, 1);
    assert_int_equal(asks[fills[0].ask].ref, 12);
    bgm_callmarket_remove_filled(cm, fills, res.fill_count);
    assert_int_equal(bgm_callmarket_bid_count(cm), 2);
    assert_int_equal(bgm_callmarket_ask_count(cm), 2);
    assert_int_equal(bgm_callmarket_clear(cm, 0.5, &res, fills, 8), BG_OK);
    assert_int_equal(res.volume, 0);
    bgm_callmarket_destroy(&cm);
    assert_null(cm);
    bgm_callmarket_destroy(&cm); /* accepts NULL */
}

static void test_callmarket_multi_unit(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(16);
    add_bid(cm, 1, 3, 10.0);
    add_ask(cm, 11, 1, 2.0);
    add_ask(cm, 12, 1, 4.0);
    add_ask(cm, 13, 2, 12.0);
    bgm_fill_t fills[8];
    bgm_clearing_t res;
    assert_int_equal(bgm_callmarket_clear(cm, 0.25, &res, fills, 8), BG_OK);
    assert_int_equal(res.volume, 2);
    /* The bid's third unit is left over at 10: excess demand holds the
     * price at the buyer's limit, whatever k. */
    assert_float_equal(res.bid_excluded, 10.0, EPS);
    assert_float_equal(res.ask_excluded, 12.0, EPS);
    assert_float_equal(res.price, 10.0, EPS);
    /* Every matched trader is within its limit at the uniform price. */
    for (size_t i = 0; i < res.fill_count; i++) {
        assert_true(res.price <= bgm_callmarket_bids(cm)[fills[i].bid].price + EPS);
        assert_true(res.price >= bgm_callmarket_asks(cm)[fills[i].ask].price - EPS);
    }
    /* Invalid input is refused, not stored. */
    bgm_order_t bad = {99, 99, 0, 1.0};
    assert_int_equal(bgm_callmarket_bid(cm, &bad), BG_ERR_INVALID);
    assert_int_equal(bgm_callmarket_clear(cm, 1.5, &res, fills, 8), BG_ERR_INVALID);
    bgm_callmarket_destroy(&cm);
}

static double clear_price(bgm_callmarket_t *cm, double k)
{
    bgm_fill_t fills[32];
    bgm_clearing_t res;
    assert_int_equal(bgm_callmarket_clear(cm, k, &res, fills, 32), BG_OK);
    assert_true(res.volume > 0);
    return res.price;
}

/* A book of two trades, bids 10 and 9 against asks 1 and 2. */
static void two_trades(bgm_callmarket_t *cm)
{
    bgm_callmarket_reset(cm);
    add_bid(cm, 1, 1, 10.0);
    add_bid(cm, 2, 1, 9.0);
    add_ask(cm, 11, 1, 1.0);
    add_ask(cm, 12, 1, 2.0);
}

/* A random book: 1 to `most` bids and asks of 1-3 units each, limits
 * uniform in [0, 10); their numbers into *nb and *na. */
static void random_book(bgm_callmarket_t *cm, bgm_rng_t *rng, uint32_t most, int *nb, int *na)
{
    bgm_callmarket_reset(cm);
    *nb = 1 + (int)bgm_rng_below(rng, most);
    *na = 1 + (int)bgm_rng_below(rng, most);
    for (int i = 0; i < *nb; i++)
        add_bid(cm, (uint64_t)i, 1 + (int)bgm_rng_below(rng, 3), 10.0 * bgm_rng_uniform(rng));
    for (int i = 0; i < *na; i++)
        add_ask(cm, (uint64_t)(100 + i), 1 + (int)bgm_rng_below(rng, 3),
                10.0 * bgm_rng_uniform(rng));
}

/* Scarcity moves the price: the same two trades clear higher when buyers
 * who would pay the sellers' asks are left out (excess demand), and at the
 * marginal ask when none is, however many sellers are left out; the old
 * marginal-pair rule priced all three alike. */
static void test_callmarket_scarcity(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(16);
    two_trades(cm);
    const double balanced = clear_price(cm, 0.5);
    assert_float_equal(balanced, 2.0, EPS);
    add_bid(cm, 3, 1, 8.0);
    add_bid(cm, 4, 1, 7.5);
    const double demand = clear_price(cm, 0.5);
    assert_float_equal(demand, 8.0 + 0.5 * (9.0 - 8.0), EPS);
    two_trades(cm);
    add_ask(cm, 13, 1, 3.0);
    add_ask(cm, 14, 1, 4.0);
    const double supply = clear_price(cm, 0.5);
    assert_float_equal(supply, 2.0, EPS);
    assert_true(demand > balanced && balanced >= supply);
    /* A bid left out below the sellers' asks competes with nobody. */
    two_trades(cm);
    add_bid(cm, 3, 1, 1.5);
    assert_float_equal(clear_price(cm, 0.5), 2.0, EPS);
    /* A seller with spare units prices at its own ask. */
    bgm_callmarket_reset(cm);
    add_bid(cm, 1, 2, 10.0);
    add_ask(cm, 11, 5, 4.0);
    assert_float_equal(clear_price(cm, 0.5), 4.0, EPS);

    /* Random books: every matched trader is willing at the price and no
     * excluded unit is (an excluded bid is at most the price, an excluded
     * ask at least). */
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 77);
    bgm_fill_t fills[64];
    for (int trial = 0; trial < 200; trial++) {
        int nb, na;
        random_book(cm, &rng, 8, &nb, &na);
        const double k = bgm_rng_uniform(&rng);
        bgm_clearing_t res;
        assert_int_equal(bgm_callmarket_clear(cm, k, &res, fills, 64), BG_OK);
        if (res.volume == 0)
            continue;
        assert_true(res.low <= res.high + EPS);
        assert_true(res.price >= res.low - EPS && res.price <= res.high + EPS);
        int bought[8] = {0}, sold[8] = {0};
        for (size_t f = 0; f < res.fill_count; f++) {
            assert_true(res.price <= bgm_callmarket_bids(cm)[fills[f].bid].price + EPS);
            assert_true(res.price >= bgm_callmarket_asks(cm)[fills[f].ask].price - EPS);
            bought[fills[f].bid] += fills[f].quantity;
            sold[fills[f].ask] += fills[f].quantity;
        }
        for (int i = 0; i < nb; i++)
            if (bought[i] < bgm_callmarket_bids(cm)[i].quantity)
                assert_true(bgm_callmarket_bids(cm)[i].price <= res.price + EPS);
        for (int i = 0; i < na; i++)
            if (sold[i] < bgm_callmarket_asks(cm)[i].quantity)
                assert_true(bgm_callmarket_asks(cm)[i].price >= res.price - EPS);
    }
    bgm_callmarket_destroy(&cm);
}

/* Clears cm at k into *res (fills discarded); returns the price, or NAN
 * when nothing trades. */
static double clear_into(bgm_callmarket_t *cm, double k, bgm_clearing_t *res)
{
    bgm_fill_t fills[64];
    assert_int_equal(bgm_callmarket_clear(cm, k, res, fills, 64), BG_OK);
    return res->volume > 0 ? res->price : NAN;
}

/* Issue 28's book, by hand: a lone job's sparse-solve bid, its limit a
 * share of a budget of 1,000 (371.88), against the one seller of the good
 * (ask 1.68 at half load). With one free slot nothing is left out on
 * either side; k-pricing put the price at the midpoint, 186.78, where the
 * same seller with a slot to spare priced at its ask: 111 times more for
 * the same job. Now both price at the ask, whatever the buyer's limit and
 * k, and the clearing names the orders that set its bounds. */
static void test_callmarket_lone_bid(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(16);
    bgm_clearing_t res;
    const double ks[3] = {0.0, 0.5, 1.0};
    for (int spare = 0; spare <= 1; spare++)
        for (int i = 0; i < 3; i++) {
            bgm_callmarket_reset(cm);
            add_bid(cm, 7, 1, 371.88);
            add_ask(cm, 40, 1 + spare, 1.68);
            assert_float_equal(clear_into(cm, ks[i], &res), 1.68, EPS);
            assert_int_equal(res.volume, 1);
            assert_false(res.rationed);
            /* lo is the seller's ask; hi the job's own limit, or the
             * seller's unsold slot. */
            assert_false(res.low_by.is_bid);
            assert_false(res.low_by.excluded);
            assert_int_equal(res.low_by.ref, 40);
            assert_float_equal(res.low, 1.68, EPS);
            assert_int_equal(res.high_by.is_bid, !spare);
            assert_int_equal(res.high_by.excluded, spare);
            assert_float_equal(res.high, spare ? 1.68 : 371.88, EPS);
        }
    /* The buyer's limit does not move the price it pays. */
    bgm_callmarket_reset(cm);
    add_bid(cm, 7, 1, 2.0);
    add_ask(cm, 40, 1, 1.68);
    assert_float_equal(clear_into(cm, 0.5, &res), 1.68, EPS);
    /* Two equal jobs for one slot: the one left out bids what the other
     * pays (rationed, lo set by the excluded bid). */
    bgm_callmarket_reset(cm);
    add_bid(cm, 7, 1, 371.88);
    add_bid(cm, 8, 1, 371.88);
    add_ask(cm, 40, 1, 1.68);
    assert_float_equal(clear_into(cm, 0.5, &res), 371.88, EPS);
    assert_true(res.rationed);
    assert_true(res.low_by.is_bid && res.low_by.excluded);
    assert_int_equal(res.low_by.ref, 8);
    /* Rationed, with a spread: k places the price between the bid left
     * out and the seller left out. */
    bgm_callmarket_reset(cm);
    add_bid(cm, 7, 1, 10.0);
    add_bid(cm, 8, 1, 4.0);
    add_ask(cm, 40, 1, 1.0);
    add_ask(cm, 41, 1, 6.0);
    assert_float_equal(clear_into(cm, 0.25, &res), 4.0 + 0.25 * (6.0 - 4.0), EPS);
    assert_true(res.rationed);
    assert_int_equal(res.low_by.ref, 8);
    assert_true(!res.high_by.is_bid && res.high_by.excluded);
    assert_int_equal(res.high_by.ref, 41);
    bgm_callmarket_destroy(&cm);
}

/* Random books: one more bid never lowers the price, one more ask never
 * raises it. The textbook rule had this too; the guard is that pricing an
 * unrationed book at its marginal ask keeps it (lone_bid shows what it
 * changes). */
static void test_callmarket_monotone(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(32);
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 2028);
    int compared = 0;
    for (int trial = 0; trial < 2000; trial++) {
        int nb, na;
        random_book(cm, &rng, 6, &nb, &na);
        const double k = bgm_rng_uniform(&rng);
        bgm_clearing_t res;
        const double before = clear_into(cm, k, &res);
        const int more_demand = bgm_rng_below(&rng, 2) == 0;
        const double p = 10.0 * bgm_rng_uniform(&rng);
        if (more_demand)
            add_bid(cm, 50, 1 + (int)bgm_rng_below(&rng, 3), p);
        else
            add_ask(cm, 150, 1 + (int)bgm_rng_below(&rng, 3), p);
        const double after = clear_into(cm, k, &res);
        if (isnan(before) || isnan(after))
            continue;
        compared++;
        if (more_demand)
            assert_true(after >= before - EPS);
        else
            assert_true(after <= before + EPS);
    }
    assert_true(compared > 500);
    bgm_callmarket_destroy(&cm);
}

static void test_callmarket_cap(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(2);
    add_bid(cm, 1, 1, 1.0);
    add_bid(cm, 2, 1, 1.0);
    bgm_order_t o = {3, 3, 1, 1.0};
    assert_int_equal(bgm_callmarket_bid(cm, &o), BG_ERR_LIMIT);
    bgm_callmarket_destroy(&cm);
}

/* A reset market is empty, takes orders up to its cap again, and clears
 * exactly like a fresh one (the world reuses one market for every call). */
static void test_callmarket_reset(void **state)
{
    (void)state;
    bgm_callmarket_t *cm = bgm_callmarket_new(2);
    add_bid(cm, 1, 1, 9.0);
    add_bid(cm, 2, 1, 8.0);
    add_ask(cm, 11, 1, 1.0);
    bgm_callmarket_reset(cm);
    assert_int_equal(bgm_callmarket_bid_count(cm), 0);
    assert_int_equal(bgm_callmarket_ask_count(cm), 0);
    bgm_fill_t fills[4];
    bgm_clearing_t res;
    assert_int_equal(bgm_callmarket_clear(cm, 0.5, &res, fills, 4), BG_OK);
    assert_int_equal(res.volume, 0);
    add_bid(cm, 3, 1, 10.0);
    add_bid(cm, 4, 1, 6.0);
    add_ask(cm, 12, 1, 4.0);
    bgm_order_t o = {5, 5, 1, 1.0};
    assert_int_equal(bgm_callmarket_bid(cm, &o), BG_ERR_LIMIT);

    bgm_callmarket_t *fresh = bgm_callmarket_new(2);
    add_bid(fresh, 3, 1, 10.0);
    add_bid(fresh, 4, 1, 6.0);
    add_ask(fresh, 12, 1, 4.0);
    bgm_fill_t ffills[4];
    bgm_clearing_t fres;
    assert_int_equal(bgm_callmarket_clear(cm, 0.5, &res, fills, 4), BG_OK);
    assert_int_equal(bgm_callmarket_clear(fresh, 0.5, &fres, ffills, 4), BG_OK);
    assert_int_equal(res.volume, 1);
    assert_int_equal(res.volume, fres.volume);
    assert_float_equal(res.price, fres.price, EPS);
    assert_int_equal(bgm_callmarket_bids(cm)[fills[0].bid].ref, 3);
    bgm_callmarket_destroy(&fresh);
    bgm_callmarket_destroy(&cm);
}

/* ------------------------------------------------- combinatorial exchange */

/* Rent (the seller's share of the pair's surplus) of the only winner of a
 * book: bids with surplus per seller (0: no pair), unit use, unit
 * capacity per seller unless caps says otherwise. */
static double combex_winner_rent(int nb, int ns, const double *surplus, double k, int *winner)
{
    bgm_combex_t *cx = bgm_combex_new(8, 8, 64);
    for (int b = 0; b < nb; b++)
        bgm_combex_add_bid(cx);
    double cap[BGM_COMBEX_DIMS] = {1.0, 1.0};
    for (int s = 0; s < ns; s++)
        bgm_combex_add_seller(cx, cap);
    for (int b = 0; b < nb; b++)
        for (int s = 0; s < ns; s++)
            if (surplus[b * ns + s] > 0.0) {
                bgm_combex_pair_t p = {b, s, surplus[b * ns + s], {1.0, 1.0}};
                assert_int_equal(bgm_combex_add_pair(cx, &p), BG_OK);
            }
    int assign[8];
    double rent[8];
    bgm_combex_result_t res;
    assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_EXACT, 100, 0, assign, &res), BG_OK);
    assert_int_equal(bgm_combex_rents(cx, assign, k, rent), BG_OK);
    *winner = -1;
    double r = 0.0;
    for (int b = 0; b < nb; b++)
        if (assign[b] >= 0) {
            assert_true(rent[b] >= -EPS && rent[b] <= bgm_combex_pairs(cx)[assign[b]].surplus + EPS);
            *winner = b;
            r = rent[b];
        } else {
            assert_float_equal(rent[b], 0.0, 0.0);
        }
    bgm_combex_destroy(&cx);
    return r;
}

/* The exchange's payments respond to competition: a left-out bid raises
 * what the winner pays its seller, a seller with room to spare lowers it;
 * alone, the pair splits its surplus by k as before. */
static void test_combex_competitive_rents(void **state)
{
    (void)state;
    int win;
    const double alone[1] = {8.0};
    assert_float_equal(combex_winner_rent(1, 1, alone, 0.5, &win), 4.0, EPS);
    assert_int_equal(win, 0);
    /* Two bids for one seller's single unit: surplus 8 wins, 6 is out. */
    const double demand[2] = {8.0, 6.0};
    double r = combex_winner_rent(2, 1, demand, 0.5, &win);
    assert_int_equal(win, 0);
    assert_float_equal(r, 6.0 + 0.5 * (8.0 - 6.0), EPS);
    assert_float_equal(combex_winner_rent(2, 1, demand, 0.0, &win), 6.0, EPS);
    /* One bid, two sellers: it creates 8 with seller 0 and 7 with seller
     * 1, which stays idle: b pays at most 1 above seller 0's cost. */
    const double supply[2] = {8.0, 7.0};
    r = combex_winner_rent(1, 2, supply, 0.5, &win);
    assert_float_equal(r, 0.5 * (8.0 - 7.0), EPS);
    assert_float_equal(combex_winner_rent(1, 2, supply, 1.0, &win), 1.0, EPS);
    assert_true(combex_winner_rent(2, 1, demand, 0.5, &win) > combex_winner_rent(1, 1, alone, 0.5, &win));
    assert_true(combex_winner_rent(1, 1, alone, 0.5, &win) > combex_winner_rent(1, 2, supply, 0.5, &win));
}

static void test_combex_known_optimum(void **state)
{
    (void)state;
    /* One seller with 2 cores. Bid 0 wants 2 cores (surplus 5); bids 1
     * and 2 want 1 core each (surplus 3 each). Optimum 6 (bids 1 + 2);
     * the greedy by surplus takes bid 0 and stops at 5. */
    bgm_combex_t *cx = bgm_combex_new(8, 4, 64);
    assert_non_null(cx);
    for (int i = 0; i < 3; i++)
        assert_int_equal(bgm_combex_add_bid(cx), i);
    double cap[BGM_COMBEX_DIMS] = {2.0, 100.0};
    assert_int_equal(bgm_combex_add_seller(cx, cap), 0);
    bgm_combex_pair_t p0 = {0, 0, 5.0, {2.0, 1.0}};
    bgm_combex_pair_t p1 = {1, 0, 3.0, {1.0, 1.0}};
    bgm_combex_pair_t p2 = {2, 0, 3.0, {1.0, 1.0}};
    assert_int_equal(bgm_combex_add_pair(cx, &p0), BG_OK);
    assert_int_equal(bgm_combex_add_pair(cx, &p1), BG_OK);
    assert_int_equal(bgm_combex_add_pair(cx, &p2), BG_OK);
    int assign[3];
    bgm_combex_result_t ex, gr;
    assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_EXACT, 100, 0, assign, &ex), BG_OK);
    assert_int_equal(ex.method, BGM_COMBEX_EXACT);
    assert_true(ex.optimal);
    assert_float_equal(ex.objective, 6.0, EPS);
    assert_int_equal(assign[0], -1);
    assert_int_equal(assign[1], 1);
    assert_int_equal(assign[2], 2);
    assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_GREEDY, 100, 0, assign, &gr), BG_OK);
    assert_int_equal(gr.method, BGM_COMBEX_GREEDY);
    assert_float_equal(gr.objective, 5.0, EPS);
    /* AUTO picks the greedy above the exact limit and says so. */
    assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_AUTO, 2, 0, assign, &gr), BG_OK);
    assert_int_equal(gr.method, BGM_COMBEX_GREEDY);
    bgm_combex_destroy(&cx);
    assert_null(cx);
}

/* Brute force over every assignment of a tiny instance. */
static double brute(const bgm_combex_pair_t *pairs, int np, int nbid, int nsel,
                    const double cap[][BGM_COMBEX_DIMS], int b, double used[][BGM_COMBEX_DIMS])
{
    if (b == nbid)
        return 0.0;
    double best = brute(pairs, np, nbid, nsel, cap, b + 1, used);
    for (int i = 0; i < np; i++) {
        const bgm_combex_pair_t *p = &pairs[i];
        if (p->bid != b)
            continue;
        int ok = 1;
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            ok &= used[p->seller][d] + p->use[d] <= cap[p->seller][d] + EPS;
        if (!ok)
            continue;
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            used[p->seller][d] += p->use[d];
        double v = p->surplus + brute(pairs, np, nbid, nsel, cap, b + 1, used);
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            used[p->seller][d] -= p->use[d];
        if (v > best)
            best = v;
    }
    return best;
}

static void test_combex_random_instances(void **state)
{
    (void)state;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 7);
    for (int inst = 0; inst < 60; inst++) {
        int nbid = 2 + (int)bgm_rng_below(&rng, 5), nsel = 1 + (int)bgm_rng_below(&rng, 3);
        bgm_combex_t *cx = bgm_combex_new(nbid, nsel, 64);
        double cap[4][BGM_COMBEX_DIMS];
        bgm_combex_pair_t pairs[64];
        int np = 0;
        for (int b = 0; b < nbid; b++)
            bgm_combex_add_bid(cx);
        for (int s = 0; s < nsel; s++) {
            cap[s][0] = 1 + bgm_rng_below(&rng, 4);
            cap[s][1] = 1 + bgm_rng_below(&rng, 8);
            bgm_combex_add_seller(cx, cap[s]);
        }
        for (int b = 0; b < nbid; b++)
            for (int s = 0; s < nsel; s++) {
                if (bgm_rng_uniform(&rng) < 0.3)
                    continue;
                bgm_combex_pair_t p = {b, s, 0.5 + 10.0 * bgm_rng_uniform(&rng),
                                       {1.0 + bgm_rng_below(&rng, 3), 1.0 + bgm_rng_below(&rng, 4)}};
                pairs[np++] = p;
                assert_int_equal(bgm_combex_add_pair(cx, &p), BG_OK);
            }
        double used[4][BGM_COMBEX_DIMS] = {{0}};
        double opt = brute(pairs, np, nbid, nsel, (const double(*)[BGM_COMBEX_DIMS])cap, 0, used);
        int assign[8];
        bgm_combex_result_t ex, gr;
        assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_EXACT, 1000, 0, assign, &ex), BG_OK);
        assert_int_equal(ex.method, BGM_COMBEX_EXACT);
        assert_float_equal(ex.objective, opt, 1e-6);
        assert_int_equal(bgm_combex_solve(cx, BGM_COMBEX_GREEDY, 1000, 0, assign, &gr), BG_OK);
        assert_true(gr.objective <= ex.objective + 1e-9);
        bgm_combex_destroy(&cx);
    }
}

/* -------------------------------------------------------- offline optimum */

/* A tiny instance of the offline problem, for checking bgm_optimum against
 * computations written here independently. */
#define TINY_Q 6
#define TINY_B 3
#define TINY_R 3

typedef struct tiny {
    bgm_opt_service_t svc[BGM_SERVICE_TYPES];
    bgm_opt_request_t q[TINY_Q];
    bgm_opt_basic_t b[TINY_B];
    bgm_opt_resource_t r[TINY_R];
    int nq, nb, nr;
} tiny_t;

static bgm_opt_problem_t tiny_problem(const tiny_t *t, int split)
{
    bgm_opt_problem_t p = {t->svc,        t->q, (size_t)t->nq, t->b,
                           (size_t)t->nb, t->r, (size_t)t->nr, split};
    return p;
}

static double tiny_duration(const tiny_t *t, int i, int r)
{
    const bgm_opt_service_t *s = &t->svc[t->q[i].type];
    return s->flops_per_unit * t->q[i].work / (t->r[r].speed * s->cores);
}

/* Welfare of request i delivered by basic agent b with the cores of
 * resource rc and the memory of resource rm (the same for a whole
 * bundle), for the run on rc. */
static double tiny_surplus(const tiny_t *t, int i, int b, int rc, int rm)
{
    const bgm_opt_request_t *q = &t->q[i];
    const bgm_opt_service_t *s = &t->svc[q->type];
    double rate = t->r[rc].core_cost * s->cores + t->r[rm].memory_cost * s->memory;
    return (q->value - t->b[b].cost[q->type]) * q->work - rate * tiny_duration(t, i, rc);
}

typedef struct delivery {
    int b, rc, rm;
    double start, end, cores, memory;
} delivery_t;

/* Whether the chosen deliveries keep every agent within capacity: loads
 * only rise at a start, so checking the starts is enough. */
static int tiny_feasible(const tiny_t *t, const delivery_t *d, int n)
{
    for (int k = 0; k < n; k++) {
        double x = d[k].start;
        for (int a = 0; a < TINY_R || a < TINY_B; a++) {
            double slots = 0.0, cores = 0.0, memory = 0.0;
            for (int j = 0; j < n; j++) {
                if (!(d[j].start <= x && x < d[j].end))
                    continue;
                slots += d[j].b == a;
                cores += d[j].rc == a ? d[j].cores : 0.0;
                memory += d[j].rm == a ? d[j].memory : 0.0;
            }
            if ((a < t->nb && slots > t->b[a].slots + EPS) ||
                (a < t->nr && (cores > t->r[a].cores + EPS || memory > t->r[a].memory + EPS)))
                return 0;
        }
    }
    return 1;
}

/* The real offline problem by exhaustive search: every request is left
 * out or delivered by one basic agent selling its type, with cores and
 * memory from one resource (or, split, memory from any one resource),
 * starting at one of `grid` evenly spaced points of its window. */
static double tiny_brute(const tiny_t *t, int grid, int split, int i, delivery_t *chosen, int n)
{
    /* The recursion ends at the last request, and never past the arrays
     * (t->q and chosen hold TINY_Q): n <= i, so chosen[n] is in range. */
    if (i >= t->nq || i >= TINY_Q)
        return 0.0;
    double best = tiny_brute(t, grid, split, i + 1, chosen, n);
    const bgm_opt_request_t *q = &t->q[i];
    const bgm_opt_service_t *s = &t->svc[q->type];
    for (int b = 0; b < t->nb; b++) {
        if (!t->b[b].sells[q->type] || t->b[b].slots < 1.0)
            continue;
        for (int rc = 0; rc < t->nr; rc++)
            for (int rm = split ? 0 : rc; rm < (split ? t->nr : rc + 1); rm++)
                for (int g = 0; g < grid; g++) {
                    double start = grid == 1
                                       ? q->release
                                       : q->release + (q->latest - q->release) * g / (grid - 1);
                    chosen[n] = (delivery_t){
                        b, rc, rm, start, start + tiny_duration(t, i, rc), s->cores, s->memory};
                    if (!tiny_feasible(t, chosen, n + 1))
                        continue;
                    double v = tiny_surplus(t, i, b, rc, rm) +
                               tiny_brute(t, grid, split, i + 1, chosen, n + 1);
                    if (v > best)
                        best = v;
                }
    }
    return best;
}

/* Σ over requests of their best surplus, capacity ignored. */
static double tiny_uncongested(const tiny_t *t)
{
    double sum = 0.0;
    for (int i = 0; i < t->nq; i++) {
        double best = 0.0;
        for (int b = 0; b < t->nb; b++)
            for (int r = 0; r < t->nr; r++)
                if (t->b[b].sells[t->q[i].type] && t->b[b].slots > 0.0 &&
                    t->r[r].cores >= t->svc[t->q[i].type].cores &&
                    t->r[r].memory >= t->svc[t->q[i].type].memory &&
                    tiny_surplus(t, i, b, r, r) > best)
                    best = tiny_surplus(t, i, b, r, r);
        sum += best;
    }
    return sum;
}

static double tiny_bound(const tiny_t *t, int split)
{
    bgm_opt_problem_t p = tiny_problem(t, split);
    bgm_opt_result_t res;
    assert_int_equal(bgm_optimum_solve(&p, 100000, &res), BG_OK);
    assert_int_equal(res.status, BGM_OPT_SOLVED);
    assert_true(res.lp <= res.value + 1e-9);
    return res.value;
}

static void tiny_random(tiny_t *t, bgm_rng_t *rng, int nq, double capacity)
{
    memset(t, 0, sizeof *t);
    t->svc[0] = (bgm_opt_service_t){2e9, 1.0, 1.0};
    t->svc[1] = (bgm_opt_service_t){5e9, 2.0, 4.0};
    t->svc[2] = (bgm_opt_service_t){3e9, 1.0, 2.0};
    t->nq = nq;
    t->nb = 2;
    t->nr = 2;
    for (int i = 0; i < nq; i++) {
        double rel = 10.0 * bgm_rng_uniform(rng);
        t->q[i] = (bgm_opt_request_t){(int)bgm_rng_below(rng, 3), 1.0 + bgm_rng_below(rng, 4),
                                      1.0 + 3.0 * bgm_rng_uniform(rng), rel,
                                      rel + 6.0 * bgm_rng_uniform(rng)};
    }
    for (int b = 0; b < t->nb; b++) {
        t->b[b].slots = capacity > 100 ? capacity : 1.0 + bgm_rng_below(rng, 2);
        int first = (int)bgm_rng_below(rng, 3);
        t->b[b].sells[first] = t->b[b].sells[(first + 1) % 3] = 1;
        for (int k = 0; k < 3; k++)
            t->b[b].cost[k] = 0.2 + 0.6 * bgm_rng_uniform(rng);
    }
    for (int r = 0; r < t->nr; r++)
        t->r[r] = (bgm_opt_resource_t){
            capacity > 100 ? capacity : 2.0 + bgm_rng_below(rng, 2),
            capacity > 100 ? capacity : 4.0, (0.5 + bgm_rng_uniform(rng)) * 1e9,
            0.05 + 0.1 * bgm_rng_uniform(rng), 0.01 + 0.02 * bgm_rng_uniform(rng)};
}

/* The least overlap against a scan of start times. */
static void test_optimum_overlap(void **state)
{
    (void)state;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 11);
    for (int k = 0; k < 200; k++) {
        double rel = 10.0 * bgm_rng_uniform(&rng), lat = rel + 8.0 * bgm_rng_uniform(&rng);
        double d = 0.5 + 6.0 * bgm_rng_uniform(&rng), lo = 15.0 * bgm_rng_uniform(&rng);
        double hi = lo + 10.0 * bgm_rng_uniform(&rng), least = INFINITY;
        for (int j = 0; j <= 4000; j++) {
            double s = rel + (lat - rel) * j / 4000.0;
            double ov = fmin(s + d, hi) - fmax(s, lo);
            least = fmin(least, ov > 0.0 ? ov : 0.0);
        }
        assert_float_equal(bgm_optimum_overlap(rel, lat, d, lo, hi), least, 1e-9);
    }
}

/* With capacity to spare the bound is every request at its best pair. */
static void test_optimum_uncongested(void **state)
{
    (void)state;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 12);
    tiny_t t;
    for (int k = 0; k < 30; k++) {
        tiny_random(&t, &rng, TINY_Q, 1000.0);
        assert_float_equal(tiny_bound(&t, 0), tiny_uncongested(&t), 1e-6);
    }
}

/* Never below the real optimum, found by exhaustive search over a grid
 * of start times; never above the uncongested value. With split bundles
 * (memory from another agent than the cores) the same, against the
 * search that may split, and never below the whole-bundle bound. */
static void test_optimum_bounds_brute_force(void **state)
{
    (void)state;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 13);
    tiny_t t;
    delivery_t chosen[TINY_Q];
    int binding = 0, split_gains = 0;
    for (int k = 0; k < 25; k++) {
        tiny_random(&t, &rng, 4, 0.0);
        if (k % 2)
            for (int r = 0; r < t.nr; r++)
                t.r[r].memory = 2.0; /* a sparse solve's 4 GiB must split */
        double real = tiny_brute(&t, 3, 0, 0, chosen, 0), bound = tiny_bound(&t, 0);
        assert_true(bound >= real - 1e-6);
        assert_true(bound <= tiny_uncongested(&t) + 1e-6);
        binding += real < tiny_uncongested(&t) - 1e-6;
        double real_split = tiny_brute(&t, 3, 1, 0, chosen, 0), bound_split = tiny_bound(&t, 1);
        assert_true(bound_split >= real_split - 1e-6);
        assert_true(bound_split >= bound - 1e-6);
        split_gains += real_split > real + 1e-6;
    }
    /* The instances must exercise capacity, and splitting, for the checks
     * to mean much. */
    assert_true(binding >= 5);
    assert_true(split_gains >= 3);
}

/* Where the relaxation is exact — all deliveries start at once, so what
 * binds is how many run together — the bound is the real optimum. */
static void test_optimum_exact_when_binding(void **state)
{
    (void)state;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 14);
    delivery_t chosen[TINY_Q];
    tiny_t t;
    for (int k = 0; k < 20; k++) {
        tiny_random(&t, &rng, TINY_Q, 0.0);
        for (int i = 0; i < t.nq; i++) {
            t.q[i].type = 0;
            t.q[i].release = t.q[i].latest = 5.0;
        }
        /* Resources bind: one core each; or basic agents bind: one slot
         * each, ample cores. All basic agents sell type 0. */
        int slots_bind = k % 2;
        for (int b = 0; b < t.nb; b++) {
            t.b[b].sells[0] = 1;
            t.b[b].slots = slots_bind ? 1.0 : 10.0;
        }
        for (int r = 0; r < t.nr; r++)
            t.r[r].cores = t.r[r].memory = slots_bind ? 10.0 : 1.0;
        double real = tiny_brute(&t, 1, 0, 0, chosen, 0);
        assert_true(real < tiny_uncongested(&t) - 1e-6);
        assert_float_equal(tiny_bound(&t, 0), real, 1e-6);
    }
    /* Above the pair limit nothing is solved, and it says so. */
    bgm_opt_problem_t p = tiny_problem(&t, 0);
    bgm_opt_result_t res;
    assert_int_equal(bgm_optimum_solve(&p, 3, &res), BG_OK);
    assert_int_equal(res.status, BGM_OPT_TOO_LARGE);
    assert_true(isnan(res.value));
}

/* ------------------------------------------------------ alternating offers */

/* Two bargaining sides talking through the deterministic event queue,
 * each message delayed by 10 ms. Returns the action that ended it. */
static bgm_nego_action bargain(double buyer_limit, double seller_limit, double *price,
                               int *rounds)
{
    bgm_genes_t g = {0.0, 0.3, 0.2, 0.8, 1.0};
    bgm_nego_t side[2];
    bgm_nego_open(&side[0], BGM_SIDE_BUYER, buyer_limit, buyer_limit * 0.5, &g, 40);
    bgm_nego_open(&side[1], BGM_SIDE_SELLER, seller_limit, seller_limit * 1.5, &g, 40);
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 3);
    bgm_evq_queue_t q = {bgm_heap_new(64), 0.0, 0.01, BG_OK};
    bgm_sink_t sink = bgm_evq_sink(&q);
    bgm_msg_t m;
    memset(&m, 0, sizeof m);
    m.from = 0;
    m.to = 1;
    m.price = side[0].current;
    sink.send(sink.ctx, &m, 100);
    bgm_nego_action last = BGM_NEGO_COUNTER;
    bgm_event_t ev;
    *rounds = 0;
    while (bgm_heap_pop(q.heap, &ev)) {
        q.now = ev.time;
        bgm_msg_t *in = ev.msg;
        bgm_nego_t *me = &side[in->to];
        double reply = 0.0;
        last = bgm_nego_respond(me, in->price, &rng, &reply);
        (*rounds)++;
        /* Hard limits on every offer either side makes. */
        if (last == BGM_NEGO_COUNTER) {
            if (me->side == BGM_SIDE_BUYER)
                assert_true(reply <= buyer_limit + EPS);
            else
                assert_true(reply >= seller_limit - EPS);
            bgm_msg_t out = *in;
            out.from = in->to;
            out.to = in->from;
            out.price = reply;
            sink.send(sink.ctx, &out, 100);
        } else {
            *price = reply;
        }
        free(in);
        if (last != BGM_NEGO_COUNTER)
            break;
    }
    assert_true(q.now > 0.0);
    bgm_heap_destroy(&q.heap);
    return last;
}

static void test_alternating_offers_converge(void **state)
{
    (void)state;
    double price = 0.0;
    int rounds = 0;
    assert_int_equal(bargain(10.0, 6.0, &price, &rounds), BGM_NEGO_ACCEPT);
    assert_true(price >= 6.0 - EPS && price <= 10.0 + EPS);
    assert_true(rounds < 40);
}

static void test_alternating_offers_no_overlap(void **state)
{
    (void)state;
    double price = -1.0;
    int rounds = 0;
    assert_int_equal(bargain(5.0, 6.0, &price, &rounds), BGM_NEGO_REJECT);
    /* Clean failure: stops once both sit at their limits, well before the
     * round cap. */
    assert_true(rounds < 40);
}

static void test_timer_queue_fires_in_order(void **state)
{
    (void)state;
    bgm_evq_queue_t q = {bgm_heap_new(16), 0.0, 0.0, BG_OK};
    bgm_sink_t sink = bgm_evq_sink(&q);
    sink.timer(sink.ctx, 1, 2.5, 7, 70);
    sink.timer(sink.ctx, 1, 0.5, 5, 50);
    sink.timer(sink.ctx, 2, 2.5, 8, 80); /* same time: insertion order */
    bgm_event_t ev;
    assert_true(bgm_heap_pop(q.heap, &ev));
    assert_float_equal(ev.time, 0.5, EPS);
    assert_int_equal(ev.kind, 5);
    assert_true(bgm_heap_pop(q.heap, &ev));
    assert_int_equal(ev.kind, 7);
    assert_true(bgm_heap_pop(q.heap, &ev));
    assert_int_equal(ev.kind, 8);
    assert_false(bgm_heap_pop(q.heap, &ev));
    bgm_heap_destroy(&q.heap);
}

static void test_posted_first_fit(void **state)
{
    (void)state;
    bgm_posted_t *d = bgm_posted_new(8);
    assert_int_equal(bgm_posted_post(d, 5, 0, 3.0), BG_OK);
    assert_int_equal(bgm_posted_post(d, 6, 0, 1.0), BG_OK);
    assert_int_equal(bgm_posted_post(d, 7, 1, 1.0), BG_OK);
    assert_int_equal(bgm_posted_post(d, 8, 0, 2.0), BG_OK);
    bgm_posting_t out[4];
    size_t first = 99;
    size_t n = bgm_posted_query(d, 0, 2.5, 0, NULL, NULL, out, 4, &first);
    /* Registration order, not price order; the 3.0 posting is over limit. */
    assert_int_equal(n, 2);
    assert_int_equal(out[0].seller, 6);
    assert_int_equal(out[1].seller, 8);
    assert_int_equal(first, 1);
    /* Next fit: from the position after the first answer's first posting,
     * wrapping around. */
    n = bgm_posted_query(d, 0, 2.5, first + 1, NULL, NULL, out, 4, &first);
    assert_int_equal(n, 2);
    assert_int_equal(out[0].seller, 8);
    assert_int_equal(out[1].seller, 6);
    assert_int_equal(first, 3);
    bgm_posted_withdraw(d, 6);
    n = bgm_posted_query(d, 0, 2.5, 0, NULL, NULL, out, 4, NULL);
    assert_int_equal(n, 1);
    bgm_posted_destroy(&d);
    assert_null(d);
}

static void test_rng_streams(void **state)
{
    (void)state;
    bgm_rng_t a, b, c;
    bgm_rng_derive(&a, 42, 1, 2, 3);
    bgm_rng_derive(&b, 42, 1, 2, 3);
    bgm_rng_derive(&c, 42, 1, 2, 4);
    int differ = 0;
    for (int i = 0; i < 100; i++) {
        uint64_t x = bgm_rng_next(&a), y = bgm_rng_next(&b), z = bgm_rng_next(&c);
        assert_true(x == y);
        differ |= x != z;
    }
    assert_true(differ);
    for (int i = 0; i < 1000; i++) {
        double u = bgm_rng_uniform(&a);
        assert_true(u >= 0.0 && u < 1.0);
        assert_true(bgm_rng_below(&a, 7) < 7);
    }
}

/* --------------------------------------------------------------- configs */

static const char *good_config =
    "{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
    "\"mechanisms\":[\"central\",\"catallactic\",\"baseline\"],"
    "\"factors\":{\"nodes\":[6],\"density\":[1]}}";

static void expect_reject(const char *json, const char *field)
{
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = bgm_config_parse(json, strlen(json), NULL, &cfg, &err);
    assert_int_not_equal(st, BG_OK);
    if (!strstr(err.message, field))
        fail_msg("message '%s' does not name '%s'", err.message, field);
}

static void test_config_validation(void **state)
{
    (void)state;
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgm_config_parse(good_config, strlen(good_config), NULL, &cfg, &err), BG_OK);
    assert_int_equal(bgm_config_scenario_count(&cfg), 1);
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,\"bogus\":1,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[6],\"density\":[1]}}",
                  "bogus");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[-4],\"density\":[1]}}",
                  "factors.nodes[0]");
    expect_reject("{\"name\":\"t\",\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]}}",
                  "seed");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"auction\"],\"factors\":{\"nodes\":[4],\"density\":[1]}}",
                  "mechanisms[0]");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]},"
                  "\"network\":{\"latencyy\":1}}",
                  "network: unknown key 'latencyy' (expected: topology, platform, latency,");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[-1]}}",
                  "factors.density[0]");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":0,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]}}",
                  "replications");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1],"
                  "\"dynamics\":[\"storm\"]}}",
                  "factors.dynamics[0]");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]},"
                  "\"services\":{\"rotation-fit\":{\"cores\":-2}}}",
                  "services.rotation-fit.cores");
    expect_reject("not json", "<config>: malformed JSON at line 1, column 1");
    expect_reject("{\"name\":\"t\",\n \"seed\":1,,\n}", "malformed JSON at line 2, column 12");
    expect_reject(" \n\t ", "<config>: empty file");
    expect_reject("", "<config>: empty file");
    /* A repeated key is an error at any depth (cJSON would keep the first). */
    expect_reject("{\"name\":\"t\",\"seed\":1,\"seed\":2,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]}}",
                  "<config>: key 'seed' appears twice");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]},"
                  "\"central\":{\"k\":0.5,\"k\":0.9}}",
                  "central: key 'k' appears twice");
    expect_reject("{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                  "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[4],\"density\":[1]},"
                  "\"dynamics\":{\"a\":{},\"a\":{}}}",
                  "dynamics: key 'a' appears twice");
    /* Messages name the file they came from. */
    bgm_config_t named;
    bg_error_t nerr = BG_ERROR_INIT;
    const char *bad = "{\"name\":\"t\"}";
    assert_int_not_equal(bgm_config_parse(bad, strlen(bad), "exp.json", &named, &nerr), BG_OK);
    assert_non_null(strstr(nerr.message, "exp.json: seed: missing"));
}

/* factors.topology: topology is the slowest factor, each level's
 * scenarios share their random streams with the others' (and with the
 * same config on that topology alone), the outputs' labels name it; bad
 * levels and clashes with network.topology or network.platform are
 * refused naming the field. */
static void test_config_topology_factor(void **state)
{
    (void)state;
    static const char *head = "{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
                              "\"mechanisms\":[\"central\"],";
    char json[1024];
    snprintf(json, sizeof json,
             "%s\"factors\":{\"topology\":[\"random\",\"scale-free\",\"cluster\"],"
             "\"nodes\":[8,16],\"density\":[1],\"dynamics\":[\"static\",\"churn\"]},"
             "\"dynamics\":{\"static\":{},\"churn\":{\"node_failure_rate\":0.01}}}",
             head);
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_config_parse(json, strlen(json), NULL, &cfg, &err))
        fail_msg("config: %s", err.message);
    assert_int_equal(cfg.topology_levels, 3);
    assert_int_equal(bgm_config_scenario_count(&cfg), 3 * 2 * 2);
    static const int want_topology[3] = {BGM_TOPO_RANDOM, BGM_TOPO_SCALEFREE, BGM_TOPO_CLUSTER};
    for (int s = 0; s < 12; s++) {
        int nodes;
        double density;
        const bgm_dynamics_t *dy;
        bgm_config_scenario(&cfg, s, &nodes, &density, &dy);
        assert_int_equal(bgm_config_scenario_topology(&cfg, s), want_topology[s / 4]);
        assert_int_equal(bgm_config_scenario_stream(&cfg, s), s % 4);
        assert_int_equal(nodes, s % 4 < 2 ? 8 : 16);
        assert_string_equal(dy->name, s % 2 ? "churn" : "static");
    }
    char label[128];
    bgm_config_scenario_label(label, sizeof label,
                              bgm_topology_names[bgm_config_scenario_topology(&cfg, 5)], 8, 1.0,
                              "churn");
    assert_string_equal(label, "scale-free_n8_d1_churn");
    bgm_config_scenario_label(label, sizeof label, NULL, 8, 1.0, "churn");
    assert_string_equal(label, "n8_d1_churn");

    /* Without the factor: network.topology for every scenario, streams
     * are the scenario indices (the outputs before the factor existed). */
    snprintf(json, sizeof json,
             "%s\"factors\":{\"nodes\":[8,16],\"density\":[1]},"
             "\"network\":{\"topology\":\"scale-free\"}}",
             head);
    if (bgm_config_parse(json, strlen(json), NULL, &cfg, &err))
        fail_msg("config: %s", err.message);
    assert_int_equal(cfg.topology_levels, 0);
    assert_int_equal(bgm_config_scenario_count(&cfg), 2);
    for (int s = 0; s < 2; s++) {
        assert_int_equal(bgm_config_scenario_topology(&cfg, s), BGM_TOPO_SCALEFREE);
        assert_int_equal(bgm_config_scenario_stream(&cfg, s), s);
    }

    static const struct {
        const char *factors, *rest, *message;
    } bad[] = {
        {"\"topology\":[\"ring\"]", "",
         "factors.topology[0]: must be star, cluster, random or scale-free"},
        {"\"topology\":[\"random\",7]", "",
         "factors.topology[1]: must be star, cluster, random or scale-free"},
        {"\"topology\":[\"random\",\"cluster\",\"random\"]", "",
         "factors.topology[2]: repeats 'random'"},
        {"\"topology\":[]", "", "factors.topology: must be an array of 1 to 4 topology names"},
        {"\"topology\":\"random\"", "",
         "factors.topology: must be an array of 1 to 4 topology names"},
        {"\"topology\":[\"random\",\"cluster\",\"star\",\"scale-free\",\"random\"]", "",
         "factors.topology: must be an array of 1 to 4 topology names"},
        {"\"topology\":[\"random\"]", ",\"network\":{\"topology\":\"random\"}",
         "factors.topology: network.topology is given too"},
        {"\"topology\":[\"random\"]", ",\"network\":{\"platform\":\"site.xml\"}",
         "factors.topology: cannot go with network.platform"},
        {"\"topologies\":[\"random\"]", "",
         "factors: unknown key 'topologies' (expected: nodes, density, dynamics, topology)"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        snprintf(json, sizeof json, "%s\"factors\":{\"nodes\":[4],\"density\":[1],%s}%s}", head,
                 bad[i].factors, bad[i].rest);
        expect_reject(json, bad[i].message);
    }
}

/* bg_json, the loader configs share with scenes: repeated keys found at
 * any depth, in small objects (pairwise) and large ones (sorted), with the
 * path; text after the value; a clean document parses. */
static void test_json_loader(void **state)
{
    (void)state;
    char text[4096];
    size_t n = (size_t)snprintf(text, sizeof text, "{\"a\": [1, {");
    for (int k = 0; k < 40; k++)
        n += (size_t)snprintf(text + n, sizeof text - n, "%s\"k%d\": %d", k ? ", " : "", k, k);
    n += (size_t)snprintf(text + n, sizeof text - n, ", \"k7\": 0}]}");
    cJSON *root = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_json_parse(text, n, "t.json", &root, &err), BG_ERR_INVALID);
    assert_null(root);
    assert_string_equal(err.message, "t.json: a[1]: key 'k7' appears twice");
    bg_error_clear(&err);
    const char *small = "{\"x\": {\"y\": 1, \"y\": 2}}";
    assert_int_equal(bg_json_parse(small, strlen(small), "s.json", &root, &err), BG_ERR_INVALID);
    assert_string_equal(err.message, "s.json: x: key 'y' appears twice");
    bg_error_clear(&err);
    const char *trailing = "{}\n  x";
    assert_int_equal(bg_json_parse(trailing, strlen(trailing), "r.json", &root, &err),
                     BG_ERR_PARSE);
    assert_string_equal(err.message, "r.json: text after the JSON value at line 2, column 3");
    bg_error_clear(&err);
    text[n - 8] = '8'; /* "k7": 0 becomes "k8": 0, still a repeat */
    assert_int_equal(bg_json_parse(text, n, "t.json", &root, &err), BG_ERR_INVALID);
    bg_error_clear(&err);
    text[n - 9] = 'q'; /* "q8": 0: no repeat left */
    assert_int_equal(bg_json_parse(text, n, "t.json", &root, &err), BG_OK);
    assert_non_null(root);
    static const char *const allowed[] = {"a", "b", NULL};
    assert_int_equal(bg_json_check_keys(root, "t.json", "", allowed, &err), BG_OK);
    static const char *const only_b[] = {"b", NULL};
    assert_int_equal(bg_json_check_keys(root, "t.json", "", only_b, &err), BG_ERR_INVALID);
    assert_string_equal(err.message, "t.json: unknown key 'a' (expected: b)");
    cJSON_Delete(root);
}

/* ---------------------------------------------- invariants of whole runs */

static bgm_config_t load_cfg(const char *json)
{
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_config_parse(json, strlen(json), NULL, &cfg, &err))
        fail_msg("config: %s", err.message);
    return cfg;
}

/* A world for the config's first scenario, replication 0, run to its end
 * on the in-process driver (stats may be NULL). Caller destroys it. */
static bgm_world_t *run_first_scenario(const bgm_config_t *cfg, int mech, bgm_evq_stats_t *stats)
{
    int nodes;
    double density;
    const bgm_dynamics_t *dy;
    bgm_config_scenario(cfg, 0, &nodes, &density, &dy);
    bgm_world_params_t p = {cfg, 0, mech, 0, nodes, density, dy, NULL, NULL};
    bg_error_t err = BG_ERROR_INIT;
    bgm_world_t *w = bgm_world_new(&p, &err);
    if (!w)
        fail_msg("%s", err.message);
    assert_int_equal(bgm_evq_run_world(w, 0.01, 1.25e8, stats), BG_OK);
    return w;
}

static const char *run_config =
    "{\"name\":\"inv\",\"seed\":99,\"replications\":1,\"duration\":150,\"drain\":40,"
    "\"mechanisms\":[\"central\",\"catallactic\",\"baseline\"],"
    "\"factors\":{\"nodes\":[10],\"density\":[1.5],\"dynamics\":[\"churn\"]},"
    "\"dynamics\":{\"churn\":{\"node_failure_rate\":0.003,\"node_repair_mean\":15,"
    "\"link_failure_rate\":0.003,\"link_repair_mean\":4}},"
    "\"demand\":{\"interarrival_mean\":15,\"deadline\":25}}";

/* Checks one finished world: limits, capacity over time, money, rate. */
static void check_invariants(bgm_world_t *w, const bgm_config_t *cfg)
{
    size_t n = bgm_world_contract_count(w);
    const bgm_contract_t *c = bgm_world_contracts(w);
    assert_true(n > 0);
    double log_paid[2] = {0, 0};
    for (size_t i = 0; i < n; i++) {
        assert_true(c[i].price >= c[i].seller_limit * (1 - 1e-9) - 1e-12);
        assert_true(c[i].price <= c[i].buyer_limit * (1 + 1e-9) + 1e-12);
        assert_true(c[i].end >= c[i].start);
        double money = c[i].layer == 0 ? c[i].price * c[i].quantity
                                       : c[i].price * c[i].quantity * (c[i].end - c[i].start);
        log_paid[c[i].layer] += money;
        /* Capacity: at this contract's start, what its seller has running. */
        double load = 0.0;
        for (size_t j = 0; j < n; j++) {
            if (c[j].seller != c[i].seller || c[j].good != c[i].good || c[j].layer != c[i].layer)
                continue;
            if (c[j].start <= c[i].start && c[i].start < c[j].end)
                load += c[i].layer == 0 ? 1.0 : c[j].quantity;
        }
        double cap = c[i].layer == 0 ? cfg->agents.service_slots
                     : c[i].good == 3 ? cfg->agents.resource_cores
                                      : cfg->agents.resource_memory;
        assert_true(load <= cap + 1e-9);
    }
    /* Each service request is bought at most once, and every resource
     * row serves a request that was bought. */
    for (size_t i = 0; i < n; i++)
        for (size_t j = 0; j < n; j++) {
            if (c[j].request != c[i].request || j == i)
                continue;
            if (c[i].layer == 0 && c[j].layer == 0)
                fail_msg("request %u bought twice", c[i].request);
        }
    for (size_t i = 0; i < n; i++) {
        int served = c[i].layer == 0;
        for (size_t j = 0; j < n && !served; j++)
            served = c[j].layer == 0 && c[j].request == c[i].request;
        assert_true(served);
    }
    double paid[2], received[2];
    bgm_world_money(w, paid, received);
    for (int l = 0; l < 2; l++) {
        assert_float_equal(paid[l], received[l], 1e-6 * (1 + paid[l]));
        assert_float_equal(paid[l], log_paid[l], 1e-6 * (1 + paid[l]));
    }
    double m[BGM_M_COUNT];
    assert_int_equal(bgm_world_metrics(w, m), BG_OK);
    double svc = 0;
    for (size_t i = 0; i < n; i++)
        svc += c[i].layer == 0;
    assert_float_equal(m[BGM_M_ALLOCATION_RATE], svc / m[BGM_M_REQUESTS], 1e-12);
    assert_true(m[BGM_M_ALLOCATION_RATE] > 0.3);
    /* No mechanism beats the offline optimum of its own demand and supply. */
    assert_true(isfinite(m[BGM_M_WELFARE_RATIO]));
    assert_true(m[BGM_M_WELFARE_RATIO] > 0.0 && m[BGM_M_WELFARE_RATIO] <= 1.0 + 1e-9);
}

static void test_invariants_inprocess(void **state)
{
    (void)state;
    bgm_config_t cfg = load_cfg(run_config);
    for (int mech = 0; mech < 3; mech++) {
        bgm_evq_stats_t st;
        bgm_world_t *w = run_first_scenario(&cfg, mech, &st);
        check_invariants(w, &cfg);
        bgm_world_destroy(&w);
        assert_null(w);
    }
}

/* ------------------------------------------ the delivery handshake */

/* A sink that keeps the messages a world sends (timers are dropped: the
 * test plays every event itself). */
typedef struct capture {
    bgm_msg_t m[256];
    int n;
} capture_t;

static void capture_send(void *ctx, const bgm_msg_t *msg, long bytes)
{
    capture_t *c = ctx;
    (void)bytes;
    assert_true(c->n < 256);
    c->m[c->n++] = *msg;
}

static void capture_timer(void *ctx, uint32_t agent, double at, int kind, uint64_t arg)
{
    (void)ctx, (void)agent, (void)at, (void)kind, (void)arg;
}

static const bgm_msg_t *captured(const capture_t *c, int type, uint32_t to)
{
    const bgm_msg_t *found = NULL;
    for (int i = 0; i < c->n; i++)
        if (c->m[i].type == type && c->m[i].to == to) {
            assert_null(found);
            found = &c->m[i];
        }
    return found;
}

/* Central: a basic seller matched to a job's bid buys its bundle and,
 * once the bundle is rented, offers the delivery (CONFIRM, with its
 * bundle's number); the job's agent takes it (TAKE), and only then does
 * the contract exist — a service row at the matched price with the
 * buyer's valuation as its limit, and the bundle's cores and memory rows.
 * The same delivery again, or one for an attempt the buyer is not on,
 * is refused and books nothing: no item is bought twice. */
static void test_delivery_handshake(void **state)
{
    (void)state;
    bgm_config_t cfg = load_cfg(
        "{\"name\":\"dh\",\"seed\":5,\"replications\":1,\"duration\":100,\"mechanisms\":[\"central\"],"
        "\"factors\":{\"nodes\":[4],\"density\":[1]},\"agents\":{\"complex_per_node\":1}}");
    int nodes;
    double density;
    const bgm_dynamics_t *dy;
    bgm_config_scenario(&cfg, 0, &nodes, &density, &dy);
    bgm_world_params_t p = {&cfg, 0, BGM_MECH_CENTRAL, 0, nodes, density, dy, NULL, NULL};
    bg_error_t err = BG_ERROR_INIT;
    bgm_world_t *w = bgm_world_new(&p, &err);
    assert_non_null(w);
    assert_int_equal(bgm_world_agent_count(w), 13); /* market, 4 jobs' agents, 4 basic, 4 resource */
    const uint32_t buyer = 1, seller = 5, resource = 9;
    capture_t *cap = calloc(1, sizeof *cap);
    assert_non_null(cap);
    bgm_sink_t sink = {cap, capture_send, capture_timer};
    assert_int_equal(bgm_world_start(w, &sink, 0.0), BG_OK);
    cap->n = 0;
    assert_int_equal(bgm_world_on_timer(w, buyer, 1 /* arrival */, 0, 1.0), BG_OK);
    const bgm_msg_t *bids[8];
    int nb = 0;
    for (int i = 0; i < cap->n; i++)
        if (cap->m[i].type == BGM_MT_BID && nb < 8)
            bids[nb++] = &cap->m[i];
    assert_true(nb >= 2); /* every plan has two items or more */
    const bgm_msg_t bid = *bids[0], other = *bids[1];

    cap->n = 0;
    const double price = 0.8 * bid.price, ask = 0.5 * bid.price;
    bgm_msg_t match = bgm_outbox_msg(BGM_MT_MATCH, 0, seller, bid.req, bid.attempt);
    match.good = bid.good;
    match.price = price;
    match.a = bid.a;
    match.b = ask;
    match.c = bid.b;
    match.origin = buyer;
    assert_int_equal(bgm_world_on_message(w, &match, 2.0), BG_OK);
    const bgm_msg_t *rbid = captured(cap, BGM_MT_RBID, 0);
    assert_non_null(rbid);
    const uint32_t bundle = rbid->req;
    assert_true(rbid->price == price * bid.a); /* the deal's revenue bounds the bundle */

    cap->n = 0;
    bgm_msg_t rc = bgm_outbox_msg(BGM_MT_RCONFIRM, resource, seller, bundle, 0);
    rc.good = -1;
    rc.price = 0.01;
    rc.a = 2.5;
    rc.b = 12.5;
    rc.c = 0.005;
    assert_int_equal(bgm_world_on_message(w, &rc, 2.5), BG_OK);
    const bgm_msg_t *cm = captured(cap, BGM_MT_CONFIRM, buyer);
    assert_non_null(cm);
    assert_int_equal(cm->origin, bundle);
    assert_int_equal(cm->req, bid.req);
    assert_int_equal(cm->attempt, bid.attempt);
    assert_true(cm->price == price && cm->a == 2.5 && cm->b == 12.5);
    assert_int_equal(bgm_world_contract_count(w), 0); /* not final before the buyer takes it */

    const bgm_msg_t delivery = *cm;
    cap->n = 0;
    assert_int_equal(bgm_world_on_message(w, &delivery, 2.51), BG_OK);
    const bgm_msg_t *take = captured(cap, BGM_MT_TAKE, seller);
    assert_non_null(take);
    assert_int_equal(take->origin, bundle);
    assert_null(captured(cap, BGM_MT_REFUSE, seller));
    assert_int_equal(bgm_world_contract_count(w), 3);
    const bgm_contract_t *c = bgm_world_contracts(w);
    int services = 0;
    for (int i = 0; i < 3; i++) {
        assert_true(c[i].time == 2.51 && c[i].start == 2.5 && c[i].end == 12.5);
        assert_int_equal(c[i].request, bid.req);
        if (c[i].layer == 0) {
            services++;
            assert_int_equal(c[i].buyer, buyer);
            assert_int_equal(c[i].seller, seller);
            assert_true(c[i].price == price && c[i].quantity == bid.a);
            assert_true(c[i].buyer_limit == bid.price && c[i].seller_limit == ask);
        } else {
            assert_int_equal(c[i].buyer, seller);
            assert_int_equal(c[i].seller, resource);
        }
    }
    assert_int_equal(services, 1);

    /* The same delivery again: refused, nothing booked. */
    cap->n = 0;
    assert_int_equal(bgm_world_on_message(w, &delivery, 2.6), BG_OK);
    assert_non_null(captured(cap, BGM_MT_REFUSE, seller));
    assert_null(captured(cap, BGM_MT_TAKE, seller));
    assert_int_equal(bgm_world_contract_count(w), 3);
    /* A delivery for the other item, on an attempt its buyer is not on. */
    bgm_msg_t stale = delivery;
    stale.req = other.req;
    stale.attempt = other.attempt + 1;
    cap->n = 0;
    assert_int_equal(bgm_world_on_message(w, &stale, 2.7), BG_OK);
    assert_non_null(captured(cap, BGM_MT_REFUSE, seller));
    assert_int_equal(bgm_world_contract_count(w), 3);
    double paid[2], received[2];
    bgm_world_money(w, paid, received);
    assert_float_equal(paid[0], price * bid.a, 1e-12);
    assert_float_equal(paid[1], 0.01 * 10.0, 1e-12);
    assert_float_equal(paid[0], received[0], 1e-12);
    assert_float_equal(paid[1], received[1], 1e-12);
    free(cap);
    bgm_world_destroy(&w);
}

/* Call markets: every bundle paid for is paid whole. Its parts are logged
 * together when it completes (same buyer, same time), and hold cores and
 * memory in a bundle's proportions, never one good alone. Returns how
 * many bundles were bought from more than one seller per good. */
static int check_whole_bundles(bgm_world_t *w, const bgm_config_t *cfg)
{
    size_t n = bgm_world_contract_count(w);
    const bgm_contract_t *c = bgm_world_contracts(w);
    double lo = INFINITY, hi = 0.0;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        lo = fmin(lo, cfg->services[t].memory / cfg->services[t].cores);
        hi = fmax(hi, cfg->services[t].memory / cfg->services[t].cores);
    }
    int groups = 0, split = 0;
    for (size_t i = 0; i < n; i++) {
        if (c[i].layer != 1)
            continue;
        int seen = 0;
        for (size_t j = 0; j < i && !seen; j++)
            seen = c[j].layer == 1 && c[j].buyer == c[i].buyer && c[j].time == c[i].time;
        if (seen)
            continue;
        double cores = 0.0, memory = 0.0;
        int rows = 0;
        for (size_t j = i; j < n; j++)
            if (c[j].layer == 1 && c[j].buyer == c[i].buyer && c[j].time == c[i].time) {
                cores += c[j].good == 3 ? c[j].quantity : 0.0;
                memory += c[j].good == 4 ? c[j].quantity : 0.0;
                rows++;
            }
        assert_true(cores >= 1.0 && memory > 0.0);
        assert_true(memory / cores >= lo - 1e-9 && memory / cores <= hi + 1e-9);
        groups++;
        split += rows > 2;
    }
    assert_true(groups > 0);
    return split;
}

static void test_call_markets_inprocess(void **state)
{
    (void)state;
    const char *configs[2] = {
        "{\"name\":\"call\",\"seed\":99,\"replications\":1,\"duration\":150,\"drain\":40,"
        "\"mechanisms\":[\"central\"],"
        "\"factors\":{\"nodes\":[10],\"density\":[1.5],\"dynamics\":[\"churn\"]},"
        "\"dynamics\":{\"churn\":{\"node_failure_rate\":0.003,\"node_repair_mean\":15,"
        "\"link_failure_rate\":0.003,\"link_repair_mean\":4}},"
        "\"central\":{\"resource_market\":\"call\"},"
        "\"demand\":{\"interarrival_mean\":15,\"deadline\":25}}",
        /* One GiB per resource agent: a sparse solve's 4 GiB must come
         * from four sellers, and bundles the memory market cannot fill
         * whole are cancelled. */
        "{\"name\":\"scarce\",\"seed\":7,\"replications\":1,\"duration\":150,\"drain\":40,"
        "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[10],\"density\":[1.5]},"
        "\"agents\":{\"resource_memory\":1},\"central\":{\"resource_market\":\"call\"},"
        "\"demand\":{\"interarrival_mean\":15,\"deadline\":25}}"};
    for (int k = 0; k < 2; k++) {
        bgm_config_t cfg = load_cfg(configs[k]);
        bgm_world_t *w = run_first_scenario(&cfg, BGM_MECH_CENTRAL, NULL);
        check_invariants(w, &cfg);
        int split = check_whole_bundles(w, &cfg);
        double m[BGM_M_COUNT];
        assert_int_equal(bgm_world_metrics(w, m), BG_OK);
        /* No combinatorial exchange ran. */
        assert_true(m[BGM_M_COMBEX_EXACT] == 0.0 && m[BGM_M_COMBEX_GREEDY] == 0.0);
        assert_true(m[BGM_M_RESOURCE_ALLOCATION_RATE] <= 1.0);
        if (k == 1) {
            /* Sparse solves were served, from split memory. */
            size_t n = bgm_world_contract_count(w);
            const bgm_contract_t *c = bgm_world_contracts(w);
            int sparse = 0;
            for (size_t i = 0; i < n; i++)
                sparse += c[i].layer == 0 && c[i].good == 1;
            assert_true(sparse > 0 && split > 0);
        }
        bgm_world_destroy(&w);
    }
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Mean service price over contracts made in [from, to), as the mean of
 * per-bucket means (buckets of `width` from `from`), and the bucket means
 * themselves (NaN for an empty bucket). Returns the bucket count. */
static int bucket_prices(bgm_world_t *w, double from, double to, double width, double *mean)
{
    size_t n = bgm_world_contract_count(w);
    const bgm_contract_t *c = bgm_world_contracts(w);
    int nb = (int)ceil((to - from) / width);
    double sum[64] = {0};
    int count[64] = {0};
    assert_true(nb > 0 && nb <= 64);
    for (size_t i = 0; i < n; i++) {
        if (c[i].layer != 0 || c[i].time < from || c[i].time >= to)
            continue;
        int b = (int)floor((c[i].time - from) / width);
        sum[b] += c[i].price;
        count[b]++;
    }
    for (int b = 0; b < nb; b++)
        mean[b] = count[b] ? sum[b] / count[b] : NAN;
    return nb;
}

static double mean_of(const double *v, int from, int to)
{
    double s = 0.0;
    int n = 0;
    for (int i = from; i < to; i++)
        if (!isnan(v[i])) {
            s += v[i];
            n++;
        }
    assert_true(n > 0);
    return s / n;
}

/*
 * The central service market under a demand shock, against theory. All
 * jobs buy one rotation fit, valued V = 3 per unit; basic agents have one
 * slot each and ask their own cost (resources cost nothing, and with k =
 * 0.02 what they learn about resource prices stays under the 10 % that
 * makes them re-announce). A run lasts well under a period, so a slot
 * matched at one clearing is busy at the next and free at the one after:
 * each slot carries one job per two periods. The competitive equilibrium
 * is then the ask of the marginal slot needed to carry the arrival flow
 * λ, the one of rank 2·λ·period, and the uniform price is that ask moved
 * by k towards V. Doubling demand moves the margin up the supply curve.
 */
static void test_price_convergence_shock(void **state)
{
    (void)state;
    bgm_config_t cfg = load_cfg(
        "{\"name\":\"shock\",\"seed\":3,\"replications\":1,\"duration\":500,\"drain\":20,"
        "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[120],\"density\":[1]},"
        "\"network\":{\"speed\":1e9,\"speed_spread\":0},"
        "\"agents\":{\"complex_per_node\":1.5,\"service_slots\":1,\"services_per_agent\":3},"
        "\"demand\":{\"interarrival_mean\":20,\"work_min\":1,\"work_max\":4,"
        "\"valuation_mean\":3,\"valuation_spread\":0,\"deadline\":20,"
        "\"plans\":[{\"services\":[\"rotation-fit\"],\"weight\":1}],"
        "\"shock\":{\"time\":200,\"factor\":2}},"
        "\"services\":{\"rotation-fit\":{\"flops_per_unit\":1e8,\"cores\":1,\"memory\":1,"
        "\"cost_per_unit\":1}},"
        "\"resources\":{\"core_cost\":0,\"memory_cost\":0,\"cost_spread\":0.5},"
        "\"central\":{\"period\":2,\"k\":0.02},"
        "\"metrics\":{\"convergence_tolerance\":0.1,\"price_bucket\":20}}");
    bgm_world_t *w = run_first_scenario(&cfg, BGM_MECH_CENTRAL, NULL);
    double m[BGM_M_COUNT];
    assert_int_equal(bgm_world_metrics(w, m), BG_OK);
    const double shock = cfg.demand.shock_time, width = cfg.metrics.price_bucket;
    const double conv = m[BGM_M_PRICE_CONVERGENCE_TIME], tol = cfg.metrics.convergence_tolerance;
    assert_true(isfinite(conv) && conv >= 0.0);

    /* The metric's claim, recomputed from the contracts: the settled
     * level is the mean of the last quarter of the post-shock buckets;
     * from the convergence time on every bucket stays within the band,
     * and the bucket just before it does not. */
    double post[64];
    int nb = bucket_prices(w, shock, bgm_world_horizon(w) + 10.0 * width, width, post);
    int nonempty = 0, last = 0;
    for (int b = 0; b < nb; b++)
        if (!isnan(post[b])) {
            nonempty++;
            last = b;
        }
    int tail_from = last + 1, tail = nonempty / 4;
    for (int seen = 0; seen < tail; tail_from--)
        seen += !isnan(post[tail_from - 1]);
    double level = mean_of(post, tail_from, last + 1);
    int first = (int)lround(conv / width);
    for (int b = first; b < nb; b++)
        if (!isnan(post[b]))
            assert_true(fabs(post[b] - level) <= tol * level + 1e-12);
    int before_first = first - 1;
    while (before_first >= 0 && isnan(post[before_first]))
        before_first--;
    if (before_first >= 0)
        assert_true(fabs(post[before_first] - level) > tol * level);

    /* Theory: the equilibrium before and after the shock. */
    double asks[BGM_MAX_NODES];
    int nask = 0;
    FILE *f = tmpfile();
    assert_non_null(f);
    assert_int_equal(bgm_world_write_agents(w, f), BG_OK);
    rewind(f);
    char line[512];
    while (fgets(line, sizeof line, f)) {
        char role[32], good[32];
        double capacity, limit;
        if (sscanf(line, "%*[^,],%*[^,],%*[^,],%*[^,],%31[^,],%31[^,],%lf,%lf", role, good,
                   &capacity, &limit) == 4 &&
            strcmp(role, "basic") == 0 && strcmp(good, "rotation-fit") == 0)
            for (int s = 0; s < (int)capacity; s++)
                asks[nask++] = limit;
    }
    fclose(f);
    qsort(asks, (size_t)nask, sizeof *asks, cmp_double);
    int nodes;
    double density;
    const bgm_dynamics_t *dy;
    bgm_config_scenario(&cfg, 0, &nodes, &density, &dy);
    const double k = cfg.central.k, v = cfg.demand.valuation_mean;
    const double lambda =
        lround(nodes * cfg.agents.complex_per_node) / cfg.demand.interarrival_mean;
    double eq[2];
    for (int j = 0; j < 2; j++) {
        long rank = lround(2.0 * lambda * (j + 1) * cfg.central.period);
        assert_true(rank >= 1 && rank <= nask);
        /* The k-double auction's price: between the marginal ask and the
         * first excluded one (every bid is v, and all are filled). */
        double next = rank < nask && asks[rank] < v ? asks[rank] : v;
        eq[j] = asks[rank - 1] + k * (next - asks[rank - 1]);
    }
    double pre[64];
    int npre = bucket_prices(w, 60.0, shock, width, pre);
    double before = mean_of(pre, 0, npre);
    assert_true(fabs(before / eq[0] - 1.0) < 0.06);
    assert_true(fabs(level / eq[1] - 1.0) < 0.06);
    /* Demand doubled: the price rose, as the equilibria say it must. */
    assert_true(eq[1] > eq[0]);
    assert_true(level > before * (1.0 + tol));
    bgm_world_destroy(&w);
}

/* Every message is lost (access links down almost always): buyers must
 * give up through their timeouts, with nothing contracted. */
/* Mean position of a layer's prices within their [seller, buyer] limits
 * (0: at the seller's limit, 1: at the buyer's). */
static double price_position(const bgm_world_t *w, int layer, int *count)
{
    size_t n = bgm_world_contract_count(w);
    const bgm_contract_t *c = bgm_world_contracts(w);
    double sum = 0.0;
    *count = 0;
    for (size_t i = 0; i < n; i++)
        if (c[i].layer == layer && c[i].buyer_limit > c[i].seller_limit + 1e-12) {
            sum += (c[i].price - c[i].seller_limit) / (c[i].buyer_limit - c[i].seller_limit);
            ++*count;
        }
    return *count ? sum / *count : NAN;
}

/* A simulated market under- and oversupplied (few or many sellers for the
 * same jobs; resource agents with 2 cores each for basic agents with 4
 * slots, so resources are scarce too when sellers are few): the central
 * market's prices sit higher in the limits when demand exceeds supply, on
 * both layers, with the exchange and with the per-type call markets. */
static void test_scarcity_prices_inprocess(void **state)
{
    (void)state;
    static const char *const markets[2] = {"exchange", "call"};
    for (int rm = 0; rm < 2; rm++) {
        char json[1024];
        double pos[2][2];
        for (int level = 0; level < 2; level++) {
            snprintf(json, sizeof json,
                     "{\"name\":\"scarce\",\"seed\":5,\"replications\":1,\"duration\":200,"
                     "\"drain\":40,\"mechanisms\":[\"central\"],"
                     "\"factors\":{\"nodes\":[12],\"density\":[%s]},"
                     "\"network\":{\"speed\":5e8},"
                     "\"agents\":{\"service_slots\":4,\"resource_cores\":2,"
                     "\"resource_memory\":4},"
                     "\"demand\":{\"interarrival_mean\":12,\"deadline\":25},"
                     "\"central\":{\"k\":0.5,\"resource_market\":\"%s\"}}",
                     level == 0 ? "0.35" : "4", markets[rm]);
            bgm_config_t cfg = load_cfg(json);
            bgm_world_t *w = run_first_scenario(&cfg, BGM_MECH_CENTRAL, NULL);
            if (level == 1) /* (the scarce market allocates less than they ask) */
                check_invariants(w, &cfg);
            for (int layer = 0; layer < 2; layer++) {
                int count = 0;
                pos[level][layer] = price_position(w, layer, &count);
                assert_true(count >= 20);
            }
            double m[BGM_M_COUNT];
            assert_int_equal(bgm_world_metrics(w, m), BG_OK);
            print_message("%s, density %s: allocation %.3f, price position service %.3f "
                          "resource %.3f\n",
                          markets[rm], level == 0 ? "0.35" : "4", m[BGM_M_ALLOCATION_RATE],
                          pos[level][0], pos[level][1]);
            bgm_world_destroy(&w);
        }
        for (int layer = 0; layer < 2; layer++)
            assert_true(pos[0][layer] > pos[1][layer] + 0.1);
    }
}

static void test_timeouts_fire(void **state)
{
    (void)state;
    bgm_config_t cfg = load_cfg(
        "{\"name\":\"lossy\",\"seed\":5,\"replications\":1,\"duration\":60,\"drain\":40,"
        "\"mechanisms\":[\"catallactic\"],"
        "\"factors\":{\"nodes\":[6],\"density\":[1],\"dynamics\":[\"dark\"]},"
        "\"dynamics\":{\"dark\":{\"link_failure_rate\":1,\"link_repair_mean\":100000}},"
        "\"demand\":{\"interarrival_mean\":10,\"deadline\":10}}");
    for (int mech = 0; mech < 3; mech++) {
        bgm_world_t *w = run_first_scenario(&cfg, mech, NULL);
        double m[BGM_M_COUNT];
        assert_int_equal(bgm_world_metrics(w, m), BG_OK);
        assert_true(m[BGM_M_REQUESTS] > 0);
        assert_true(m[BGM_M_TIMEOUTS] > 0);
        assert_true(m[BGM_M_ALLOCATION_RATE] < 0.2);
        bgm_world_destroy(&w);
    }
}

/* ------------------------------------------------------ message budget */

/* The rounds a request can start, from the definition: round k + 1 only
 * if the backoffs before it, b 2^min(i, 5) for i < k, sum to less than
 * the deadline. */
static double attempts_by_definition(double deadline, double backoff)
{
    double sum = 0.0, rounds = 1.0;
    for (int i = 0;; i++) {
        sum += backoff *
               (double)(1 << (i < BGM_PU_RETRY_MAX_DOUBLINGS ? i : BGM_PU_RETRY_MAX_DOUBLINGS));
        if (sum >= deadline)
            return rounds;
        rounds += 1.0;
    }
}

/* The world's messages against the bound bgm_budget puts on them: its
 * service requests' rounds, its deals (bundle requests) and its agents'
 * own traffic; the summary's message_bound is that bound per allocation. */
static void check_budget(bgm_world_t *w, const bgm_config_t *cfg, int mech, int nodes,
                         double density)
{
    double m[BGM_M_COUNT];
    assert_int_equal(bgm_world_metrics(w, m), BG_OK);
    bgm_purchase_tally_t svc, res;
    bgm_world_tally(w, &svc, &res);
    const bgm_budget_t b =
        bgm_budget_of(cfg, mech, bgm_world_horizon(w), (double)lround(nodes * density));
    const double bound =
        bgm_budget_messages(&b, svc.requests, res.requests, (double)bgm_world_agent_count(w));
    assert_true(svc.requests > 0 && m[BGM_M_MESSAGES] > 0);
    if (m[BGM_M_MESSAGES] > bound)
        fail_msg("%s: %.0f messages over the bound %.0f", bgm_mechanism_names[mech],
                 m[BGM_M_MESSAGES], bound);
    /* No request starts more rounds than the bound allows. */
    assert_true(svc.attempts <= svc.requests * b.attempts);
    assert_true(res.attempts <= res.requests * b.attempts);
    if (m[BGM_M_CONTRACTS] > 0) {
        assert_float_equal(m[BGM_M_MESSAGE_BOUND], bound / m[BGM_M_CONTRACTS],
                           1e-9 * m[BGM_M_MESSAGE_BOUND]);
        assert_true(m[BGM_M_MESSAGES_PER_ALLOCATION] <= m[BGM_M_MESSAGE_BOUND]);
    }
    assert_float_equal(m[BGM_M_TIMEOUTS_PER_REQUEST], m[BGM_M_TIMEOUTS] / svc.requests, 1e-12);
}

/* Every mechanism stays within its message budget: static and under
 * churn, with messages lost on dark links, with round trips far longer
 * than the configured timeouts (0.6 s one way against 0.5 s timers: late
 * answers, deals made after their buyer moved on) and with central's
 * per-type call markets (bundles in parts). */
static void test_message_budget(void **state)
{
    (void)state;
    assert_true(bgm_budget_calls(6, 2) == 36.0);
    assert_true(bgm_budget_calls(6, 1) == 6.0);
    assert_true(bgm_budget_calls(3, 3) == 21.0);
    assert_true(bgm_budget_calls(1, 4) == 1.0);
    assert_true(isinf(bgm_budget_attempts(30.0, 0.0)));
    const double cases[][2] = {{30, 2}, {30, 100}, {1, 1}, {2, 1}, {1000, 1}, {64.5, 0.5}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        assert_true(bgm_budget_attempts(cases[i][0], cases[i][1]) ==
                    attempts_by_definition(cases[i][0], cases[i][1]));
    assert_true(bgm_budget_attempts(30.0, 2.0) == 4.0);

    const char *const configs[] = {
        run_config,
        "{\"name\":\"static\",\"seed\":7,\"replications\":1,\"duration\":120,\"drain\":40,"
        "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[12],\"density\":[1]},"
        "\"demand\":{\"interarrival_mean\":10,\"deadline\":30}}",
        "{\"name\":\"dark\",\"seed\":5,\"replications\":1,\"duration\":60,\"drain\":40,"
        "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[6],\"density\":[1],"
        "\"dynamics\":[\"dark\"]},\"dynamics\":{\"dark\":{\"link_failure_rate\":0.05,"
        "\"link_repair_mean\":5}},\"demand\":{\"interarrival_mean\":10,\"deadline\":10}}",
        "{\"name\":\"call\",\"seed\":3,\"replications\":1,\"duration\":90,\"drain\":40,"
        "\"mechanisms\":[\"central\"],\"factors\":{\"nodes\":[8],\"density\":[1]},"
        "\"central\":{\"resource_market\":\"call\"}}"};
    for (size_t k = 0; k < sizeof configs / sizeof configs[0]; k++) {
        bgm_config_t cfg = load_cfg(configs[k]);
        int nodes;
        double density;
        const bgm_dynamics_t *dy;
        bgm_config_scenario(&cfg, 0, &nodes, &density, &dy);
        for (int mech = 0; mech < 3; mech++) {
            if (k == 3 && mech != BGM_MECH_CENTRAL)
                continue; /* the call markets are central's */
            for (int slow = 0; slow < 2; slow++) {
                bgm_world_params_t p = {&cfg, 0, mech, 0, nodes, density, dy, NULL, NULL};
                bg_error_t err = BG_ERROR_INIT;
                bgm_world_t *w = bgm_world_new(&p, &err);
                if (!w)
                    fail_msg("%s", err.message);
                assert_int_equal(bgm_evq_run_world(w, slow ? 0.6 : 0.01, 1.25e8, NULL), BG_OK);
                check_budget(w, &cfg, mech, nodes, density);
                bgm_world_destroy(&w);
            }
        }
    }
}

static void test_world_deterministic(void **state)
{
    (void)state;
    bgm_config_t cfg = load_cfg(run_config);
    double first[BGM_M_COUNT];
    for (int rep = 0; rep < 2; rep++) {
        bgm_world_t *w = run_first_scenario(&cfg, BGM_MECH_CATALLACTIC, NULL);
        double m[BGM_M_COUNT];
        bgm_world_metrics(w, m);
        if (rep == 0)
            memcpy(first, m, sizeof m);
        else
            for (int k = 0; k < BGM_M_COUNT; k++)
                assert_true((isnan(first[k]) && isnan(m[k])) || first[k] == m[k]);
        bgm_world_destroy(&w);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_callmarket_uniform_price),
        cmocka_unit_test(test_callmarket_multi_unit),
        cmocka_unit_test(test_callmarket_scarcity),
        cmocka_unit_test(test_callmarket_lone_bid),
        cmocka_unit_test(test_callmarket_monotone),
        cmocka_unit_test(test_callmarket_cap),
        cmocka_unit_test(test_callmarket_reset),
        cmocka_unit_test(test_combex_known_optimum),
        cmocka_unit_test(test_combex_competitive_rents),
        cmocka_unit_test(test_combex_random_instances),
        cmocka_unit_test(test_optimum_overlap),
        cmocka_unit_test(test_optimum_uncongested),
        cmocka_unit_test(test_optimum_bounds_brute_force),
        cmocka_unit_test(test_optimum_exact_when_binding),
        cmocka_unit_test(test_alternating_offers_converge),
        cmocka_unit_test(test_alternating_offers_no_overlap),
        cmocka_unit_test(test_timer_queue_fires_in_order),
        cmocka_unit_test(test_posted_first_fit),
        cmocka_unit_test(test_rng_streams),
        cmocka_unit_test(test_config_validation),
        cmocka_unit_test(test_config_topology_factor),
        cmocka_unit_test(test_json_loader),
        cmocka_unit_test(test_invariants_inprocess),
        cmocka_unit_test(test_delivery_handshake),
        cmocka_unit_test(test_call_markets_inprocess),
        cmocka_unit_test(test_price_convergence_shock),
        cmocka_unit_test(test_scarcity_prices_inprocess),
        cmocka_unit_test(test_timeouts_fire),
        cmocka_unit_test(test_message_budget),
        cmocka_unit_test(test_world_deterministic),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
