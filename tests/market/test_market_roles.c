/*
 * Unit tests of the market's role machines, each driven alone with
 * hand-built messages: what it emits is read back from its outbox and
 * checked against numbers computed here, independently of the mechanism
 * code (the k-double price from its definition, the exchange's rent
 * without competition, first fit over a directory, a resource seller's
 * run time, cost and opening price from its own endowment).
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

#include "bgm_budget.h"
#include "bgm_buyer.h"
#include "bgm_config.h"
#include "bgm_market_agent.h"
#include "bgm_outbox.h"
#include "bgm_purchase.h"
#include "bgm_resource.h"
#include "bgm_rng.h"
#include "bgm_role.h"
#include "bgm_seller.h"
#include "bgm_session.h"
#include "bgm_strategy.h"

#define EPS 1e-12

static bgm_config_t config(const char *mechanism, double k)
{
    char json[512];
    snprintf(json, sizeof json,
             "{\"name\":\"t\",\"seed\":1,\"replications\":1,\"duration\":60,"
             "\"mechanisms\":[\"%s\"],\"factors\":{\"nodes\":[4],\"density\":[1]},"
             "\"central\":{\"period\":1.0,\"k\":%g},\"baseline\":{\"markup\":0.25,\"candidates\":3}}",
             mechanism, k);
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_config_parse(json, strlen(json), NULL, &cfg, &err))
        fail_msg("config: %s", err.message);
    return cfg;
}

/* Agent ids of the tests: market 0, buyers 1..4, basic sellers 5..7,
 * resource sellers 8..9. */
enum { FIRST_BASIC = 5, NBASIC = 3, FIRST_RES = 8, NRES = 2 };

static bgm_market_agent_t *agent(const bgm_config_t *cfg, int mechanism)
{
    bgm_market_agent_params_t p = {cfg, mechanism, 0, FIRST_BASIC, NBASIC, FIRST_RES, NRES, 1000.0};
    bgm_market_agent_t *ma = bgm_market_agent_new(&p);
    assert_non_null(ma);
    return ma;
}

static bgm_msg_t mk(int type, uint32_t from, uint32_t req)
{
    bgm_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = (uint16_t)type;
    m.from = from;
    m.to = 0;
    m.req = req;
    m.attempt = 3;
    return m;
}

static void deliver(bgm_market_agent_t *ma, const bgm_msg_t *m, bgm_outbox_t *ob)
{
    assert_int_equal(bgm_market_agent_on_message(ma, m, 0.5, ob), BG_OK);
}

static void ask(bgm_market_agent_t *ma, bgm_outbox_t *ob, uint32_t seller, int good, double price,
                double slots)
{
    bgm_msg_t m = mk(BGM_MT_ASK, seller, 0);
    m.good = (int16_t)good;
    m.price = price;
    m.a = slots;
    deliver(ma, &m, ob);
}

static void bid(bgm_market_agent_t *ma, bgm_outbox_t *ob, uint32_t buyer, uint32_t req, int good,
                double limit, double work, double deadline)
{
    bgm_msg_t m = mk(BGM_MT_BID, buyer, req);
    m.good = (int16_t)good;
    m.price = limit;
    m.a = work;
    m.b = deadline;
    deliver(ma, &m, ob);
}

/* The k-double price of unit orders from its definition: sort, match
 * while bid >= ask, then p = lo + k (hi - lo) on [max(a_m, b_x), min(b_m, a_x)]. */
static int cmp_down(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x < y) - (x > y);
}

static double kdouble(double *b, int nb, double *a, int na, double k, int *volume)
{
    qsort(b, (size_t)nb, sizeof *b, cmp_down);
    qsort(a, (size_t)na, sizeof *a, cmp_down);
    for (int i = 0; i < na / 2; i++) { /* asks ascending */
        double t = a[i];
        a[i] = a[na - 1 - i];
        a[na - 1 - i] = t;
    }
    int v = 0;
    while (v < nb && v < na && b[v] >= a[v])
        v++;
    *volume = v;
    double bm = b[v - 1], am = a[v - 1];
    double bx = v < nb ? b[v] : -INFINITY, ax = v < na ? a[v] : INFINITY;
    double lo = fmax(am, bx), hi = fmin(bm, ax);
    /* k places the price only where a buyer left out would pay the
     * marginal ask (bgm_callmarket.h). */
    return bx >= am ? lo + k * (hi - lo) : lo;
}

/* A central market agent clears a service book to the k-double price:
 * it tells each matched seller (MATCH, with the bid's work and the
 * seller's own ask) and each matched buyer (ACCEPT), keeps the unmatched
 * bids until their deadline, and drops them silently after it. */
static void test_auctioneer_clears_to_kdouble_price(void **state)
{
    (void)state;
    const double k = 0.3;
    bgm_config_t cfg = config("central", k);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_CENTRAL);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    assert_non_null(ob);
    assert_int_equal(bgm_market_agent_start(ma, 0.0, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 1);
    assert_true(bgm_outbox_item(ob, 0)->is_timer);
    assert_int_equal(bgm_outbox_item(ob, 0)->kind, BGM_MA_TIMER_CLEAR);
    assert_true(fabs(bgm_outbox_item(ob, 0)->at - cfg.central.period) < EPS);
    bgm_outbox_clear(ob);

    double asks[] = {3.0, 7.0, 9.0}, bids[] = {10.0, 7.5, 8.0, 4.5};
    for (int i = 0; i < 3; i++)
        ask(ma, ob, FIRST_BASIC + (uint32_t)i, BGM_GOOD_SOLVE, asks[i], 1.0);
    ask(ma, ob, FIRST_BASIC, BGM_GOOD_ROTFIT, 1.0, 1.0); /* another good: no part of this book */
    for (int i = 0; i < 4; i++)
        bid(ma, ob, 1 + (uint32_t)i, 100 + (uint32_t)i, BGM_GOOD_SOLVE, bids[i], 2.0 + i, 20.0);
    assert_int_equal(bgm_outbox_count(ob), 0); /* books fill silently */
    size_t nb, nr;
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 4);

    double sb[4], sa[3];
    memcpy(sb, bids, sizeof sb);
    memcpy(sa, asks, sizeof sa);
    int volume = 0;
    double p = kdouble(sb, 4, sa, 3, k, &volume);
    assert_int_equal(volume, 2);
    /* The bid of 7.5 is left out above the marginal ask 7: k places the
     * price in [max(7, 7.5), min(8, 9)]. */
    assert_true(fabs(p - (7.5 + k * (8.0 - 7.5))) < EPS);

    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 1.0, ob), BG_OK);
    int matches = 0, accepts = 0, timers = 0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (it->is_timer) {
            timers++;
            assert_true(fabs(it->at - 2.0) < EPS);
            continue;
        }
        const bgm_msg_t *m = &it->msg;
        assert_int_equal(m->from, 0);
        assert_int_equal(m->attempt, 3);
        assert_true(fabs(m->price - p) < EPS);
        assert_true(m->price <= 8.0 && m->price >= 7.0); /* within every matched limit */
        uint32_t buyer = m->type == BGM_MT_MATCH ? m->origin : m->to;
        assert_true(buyer == 1 || buyer == 3); /* the bids of 10 and 8 */
        assert_int_equal(m->req, 99 + buyer);
        if (m->type == BGM_MT_MATCH) {
            matches++;
            assert_true(m->to == FIRST_BASIC || m->to == FIRST_BASIC + 1); /* asks 3 and 7 */
            assert_true(fabs(m->b - asks[m->to - FIRST_BASIC]) < EPS);
            assert_true(fabs(m->a - (1.0 + buyer)) < EPS); /* the bid's work */
            assert_int_equal(m->good, BGM_GOOD_SOLVE);
        } else {
            assert_int_equal(m->type, BGM_MT_ACCEPT);
            accepts++;
        }
    }
    assert_int_equal(matches, 2);
    assert_int_equal(accepts, 2);
    assert_int_equal(timers, 1);
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 2);

    /* The sellers' slots are taken: the remaining bids stay unmatched,
     * and after their deadline they are gone without a message. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 2.0, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 1); /* the next period only */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 20.0, ob), BG_OK);
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 0);
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        assert_true(bgm_outbox_item(ob, i)->is_timer);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
    assert_null(ma);
}

/* The exchange awards a bundle whole to the only seller with room at its
 * cost plus k times the pair's surplus (no competition: nothing excluded
 * and no other seller), as a rate per second of the seller's run time; a
 * bundle whose limit is below every seller's cost is not awarded. */
static void test_auctioneer_exchange_rent(void **state)
{
    (void)state;
    const double k = 0.4;
    bgm_config_t cfg = config("central", k);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_CENTRAL);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    const double cores = 2.0, mem = 4.0, flops = 6e9, speed = 1.5e9, ccost = 0.05, mcost = 0.01;
    bgm_msg_t r = mk(BGM_MT_RASK, FIRST_RES + 1, 0);
    r.a = 4.0;
    r.b = 8.0;
    r.c = speed;
    r.price = ccost;
    r.cand_price[0] = mcost;
    deliver(ma, &r, ob);
    const double dur = flops / (speed * cores), cost = (ccost * cores + mcost * mem) * dur;
    const double limit = 3.0 * cost;
    bgm_msg_t b = mk(BGM_MT_RBID, FIRST_BASIC + 2, 41);
    b.price = limit;
    b.a = cores;
    b.b = mem;
    b.c = flops;
    b.cand_price[0] = 30.0;
    deliver(ma, &b, ob);
    bgm_msg_t poor = b;
    poor.req = 42;
    poor.from = FIRST_BASIC;
    poor.price = 0.5 * cost;
    deliver(ma, &poor, ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 1.0, ob), BG_OK);
    int awards = 0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (it->is_timer)
            continue;
        assert_int_equal(it->msg.type, BGM_MT_RAWARD);
        assert_int_equal(it->msg.to, FIRST_RES + 1);
        assert_int_equal(it->msg.req, 41);
        assert_int_equal(it->msg.origin, FIRST_BASIC + 2);
        double want = (cost + k * (limit - cost)) / dur;
        assert_true(fabs(it->msg.price - want) < 1e-9 * want);
        awards++;
    }
    assert_int_equal(awards, 1);
    size_t nb, nr;
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nr, 1); /* the poor bid waits for its deadline */
    double exact, greedy;
    bgm_market_agent_counts(ma, &exact, &greedy);
    assert_true(exact + greedy == 1.0);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
}

/* The baseline directory answers a query with the first sellers, in
 * registration order, that post the good within the limit and that it
 * believes have room (their last AVAIL), up to the candidate cap. */
static void test_directory_first_fit(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_BASELINE);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    assert_int_equal(bgm_market_agent_start(ma, 0.0, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0); /* no clearing without the central market */
    ask(ma, ob, FIRST_BASIC, BGM_GOOD_INTEG, 5.0, 2.0);
    ask(ma, ob, FIRST_BASIC + 1, BGM_GOOD_INTEG, 3.0, 2.0);
    ask(ma, ob, FIRST_BASIC + 2, BGM_GOOD_INTEG, 4.0, 2.0);
    bgm_msg_t full = mk(BGM_MT_AVAIL, FIRST_BASIC + 1, 0);
    full.a = 0.0;
    deliver(ma, &full, ob);
    bgm_msg_t q = mk(BGM_MT_QUERY, 2, 77);
    q.good = BGM_GOOD_INTEG;
    q.price = 4.5;
    deliver(ma, &q, ob);
    assert_int_equal(bgm_outbox_count(ob), 1);
    const bgm_msg_t *l = &bgm_outbox_item(ob, 0)->msg;
    assert_int_equal(l->type, BGM_MT_LIST);
    assert_int_equal(l->to, 2);
    assert_int_equal(l->req, 77);
    assert_int_equal(l->attempt, 3);
    assert_int_equal(l->ncand, 1); /* 5.0 is above the limit, the 3.0 seller is full */
    assert_int_equal(l->cand[0], FIRST_BASIC + 2);
    assert_true(fabs(l->cand_price[0] - 4.0) < EPS);

    /* A resource bundle: the posted rate is the seller's cost rate for
     * the bundle asked, marked up. */
    bgm_outbox_clear(ob);
    bgm_msg_t r = mk(BGM_MT_RASK, FIRST_RES, 0);
    r.a = 4.0;
    r.b = 8.0;
    r.c = 2e9;
    r.price = 0.1;
    r.cand_price[0] = 0.02;
    deliver(ma, &r, ob);
    bgm_msg_t rq = mk(BGM_MT_QUERY, FIRST_BASIC, 78);
    rq.good = BGM_GOOD_CORES_ID;
    rq.price = INFINITY;
    rq.a = 2.0;
    rq.b = 3.0;
    deliver(ma, &rq, ob);
    l = &bgm_outbox_item(ob, 0)->msg;
    assert_int_equal(l->ncand, 1);
    assert_int_equal(l->cand[0], FIRST_RES);
    assert_true(fabs(l->cand_price[0] - 1.25 * (0.1 * 2.0 + 0.02 * 3.0)) < EPS);
    assert_true(fabs(l->cand_speed[0] - 2e9) < EPS);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
}

/* Next fit: each answer for a good starts at the seller after the
 * previous answer's first, wrapping around, so that buyers asking at
 * about the same time are sent to different sellers first. Plain first
 * fit gave every one of them the same list, whose head the directory's
 * lagging view of free room showed as free while it was full (issue 31:
 * 43 refused orders a request at 400 nodes). */
static void test_directory_next_fit(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_BASELINE);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    for (uint32_t k = 0; k < NBASIC; k++)
        ask(ma, ob, FIRST_BASIC + k, BGM_GOOD_ROTFIT, 1.0, 2.0);
    ask(ma, ob, FIRST_BASIC, BGM_GOOD_SOLVE, 1.0, 2.0);
    for (uint32_t i = 0; i < 2 * NBASIC; i++) {
        bgm_outbox_clear(ob);
        bgm_msg_t q = mk(BGM_MT_QUERY, 1 + i % 4, 100 + i);
        q.good = BGM_GOOD_ROTFIT;
        q.price = 2.0;
        deliver(ma, &q, ob);
        const bgm_msg_t *l = &bgm_outbox_item(ob, 0)->msg;
        assert_int_equal(l->ncand, NBASIC); /* every seller, the cap being 3 */
        for (uint32_t c = 0; c < NBASIC; c++)
            assert_int_equal(l->cand[c], FIRST_BASIC + (i + c) % NBASIC);
    }
    /* Each good has its own position: the first query for another good
     * starts from the first seller. */
    bgm_outbox_clear(ob);
    bgm_msg_t q = mk(BGM_MT_QUERY, 1, 200);
    q.good = BGM_GOOD_SOLVE;
    q.price = 2.0;
    deliver(ma, &q, ob);
    assert_int_equal(bgm_outbox_item(ob, 0)->msg.cand[0], FIRST_BASIC);
    /* A query naming no good the directory lists is refused. */
    q.good = BGM_GOOD_MEMORY_ID;
    assert_int_equal(bgm_market_agent_on_message(ma, &q, 0.5, ob), BG_ERR_INVALID);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
}

/* What a live buyer adds to its bids and queries: sellers it excludes
 * are neither matched nor listed (and keep their slots for others); two
 * bids of one buyer's need group are matched with distinct sellers even
 * when one seller has room for both; a forgotten seller sells nothing and
 * a forgotten buyer's bids are gone. Which fills are taken is worked out
 * by hand from the k-double definition. */
static void test_auctioneer_exclusions_and_groups(void **state)
{
    (void)state;
    bgm_config_t cfg = config("central", 0.5);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_CENTRAL);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    assert_non_null(ob);
    /* Seller 5 asks 1 with two slots, seller 6 asks 2 with one. */
    ask(ma, ob, FIRST_BASIC, BGM_GOOD_ROTFIT, 1.0, 2.0);
    ask(ma, ob, FIRST_BASIC + 1, BGM_GOOD_ROTFIT, 2.0, 1.0);
    /* Buyer 1: two bids of group 1 at limit 10; buyer 2: one bid at 9
     * that excludes seller 5. */
    for (uint32_t r = 0; r < 2; r++) {
        bgm_msg_t m = mk(BGM_MT_BID, 1, 10 + r);
        m.good = BGM_GOOD_ROTFIT;
        m.price = 10.0;
        m.a = 1.0;
        m.b = 50.0;
        m.origin = 1;
        deliver(ma, &m, ob);
    }
    bgm_msg_t x = mk(BGM_MT_BID, 2, 20);
    x.good = BGM_GOOD_ROTFIT;
    x.price = 9.0;
    x.a = 1.0;
    x.b = 50.0;
    x.ncand = 1;
    x.cand[0] = FIRST_BASIC;
    deliver(ma, &x, ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 1.0, ob), BG_OK);
    /* Units in price order: bids 10, 10, 9 against asks 1, 1, 2: all
     * three cross, and the fills pair bid i with ask i. Bid 10 (req 10)
     * gets seller 5; bid 10 (req 11) would get seller 5's second slot but
     * its group has it: left; bid 9 gets seller 6. */
    uint32_t seller_of[3] = {0, 0, 0};
    int matches = 0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (it->is_timer || it->msg.type != BGM_MT_MATCH)
            continue;
        matches++;
        const uint32_t req = it->msg.req;
        assert_true(req == 10 || req == 11 || req == 20);
        seller_of[req == 20 ? 2 : req - 10] = it->msg.to;
    }
    assert_int_equal(matches, 2);
    assert_int_equal(seller_of[2], FIRST_BASIC + 1); /* the excluded seller 5 is never its */
    assert_true((seller_of[0] == FIRST_BASIC) != (seller_of[1] == FIRST_BASIC));
    size_t nb, nr;
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 1); /* the group's second bid waits */
    /* Seller 5 kept its second slot; seller 6 is full, so the next
     * clearing has only seller 5 to offer, which the group has: nothing
     * is matched, in this clearing as in the first. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 2.0, ob), BG_OK);
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        assert_true(bgm_outbox_item(ob, i)->is_timer);
    /* A seller with room for it comes: matched. */
    ask(ma, ob, FIRST_BASIC + 2, BGM_GOOD_ROTFIT, 3.0, 1.0);
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 3.0, ob), BG_OK);
    matches = 0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (!it->is_timer && it->msg.type == BGM_MT_MATCH) {
            matches++;
            assert_int_equal(it->msg.to, FIRST_BASIC + 2);
        }
    }
    assert_int_equal(matches, 1);

    /* Forgetting: seller 5 (one slot left) leaves; buyer 3's bids are
     * dropped when its job ends, before any clearing. */
    bgm_market_agent_forget_seller(ma, FIRST_BASIC);
    bgm_msg_t y = mk(BGM_MT_BID, 3, 30);
    y.good = BGM_GOOD_ROTFIT;
    y.price = 10.0;
    y.a = 1.0;
    y.b = 50.0;
    deliver(ma, &y, ob);
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 1);
    bgm_market_agent_forget_bids(ma, 3);
    bgm_market_agent_books(ma, &nb, &nr);
    assert_int_equal(nb, 0);
    deliver(ma, &y, ob);
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_market_agent_on_timer(ma, BGM_MA_TIMER_CLEAR, 0, 4.0, ob), BG_OK);
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        assert_true(bgm_outbox_item(ob, i)->is_timer); /* seller 5 sells nothing now */

    /* The directory leaves excluded sellers out of a list. */
    bgm_config_t bcfg = config("baseline", 0.5);
    bgm_market_agent_t *dir = agent(&bcfg, BGM_MECH_BASELINE);
    ask(dir, ob, FIRST_BASIC, BGM_GOOD_SOLVE, 1.0, 1.0);
    ask(dir, ob, FIRST_BASIC + 1, BGM_GOOD_SOLVE, 1.0, 1.0);
    bgm_outbox_clear(ob);
    bgm_msg_t q = mk(BGM_MT_QUERY, 1, 40);
    q.good = BGM_GOOD_SOLVE;
    q.price = 5.0;
    q.ncand = 1;
    q.cand[0] = FIRST_BASIC;
    deliver(dir, &q, ob);
    const bgm_msg_t *l = &bgm_outbox_item(ob, 0)->msg;
    assert_int_equal(l->ncand, 1);
    assert_int_equal(l->cand[0], FIRST_BASIC + 1);
    bgm_market_agent_forget_seller(dir, FIRST_BASIC + 1);
    bgm_outbox_clear(ob);
    deliver(dir, &q, ob);
    assert_int_equal(bgm_outbox_item(ob, 0)->msg.ncand, 0);
    bgm_market_agent_destroy(&dir);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
}

/* Announcements from outside the seller ranges, or for a good that does
 * not exist, are refused instead of written anywhere. */
static void test_auctioneer_refuses_bad_input(void **state)
{
    (void)state;
    bgm_config_t cfg = config("central", 0.5);
    bgm_market_agent_t *ma = agent(&cfg, BGM_MECH_CENTRAL);
    bgm_outbox_t *ob = bgm_outbox_new(4);
    bgm_msg_t m = mk(BGM_MT_ASK, FIRST_RES, 0); /* a resource seller cannot ASK */
    assert_int_equal(bgm_market_agent_on_message(ma, &m, 0.0, ob), BG_ERR_INVALID);
    m = mk(BGM_MT_RFREE, FIRST_RES + NRES, 0);
    assert_int_equal(bgm_market_agent_on_message(ma, &m, 0.0, ob), BG_ERR_INVALID);
    m = mk(BGM_MT_BID, 1, 0);
    m.good = 7;
    assert_int_equal(bgm_market_agent_on_message(ma, &m, 0.0, ob), BG_ERR_INVALID);
    assert_int_equal(bgm_market_agent_on_timer(ma, 99, 0, 0.0, ob), BG_ERR_INVALID);
    assert_int_equal(bgm_outbox_count(ob), 0);
    bgm_outbox_destroy(&ob);
    bgm_market_agent_destroy(&ma);
}

/* The outbox keeps emission order and refuses items past its cap. */
static void test_outbox_order_and_cap(void **state)
{
    (void)state;
    bgm_outbox_t *ob = bgm_outbox_new(3);
    bgm_msg_t m = mk(BGM_MT_FREE, 5, 1);
    assert_int_equal(bgm_outbox_send(ob, &m), BG_OK);
    assert_int_equal(bgm_outbox_timer(ob, 4, 2.5, 7, 99), BG_OK);
    m.req = 2;
    assert_int_equal(bgm_outbox_send(ob, &m), BG_OK);
    assert_int_equal(bgm_outbox_send(ob, &m), BG_ERR_LIMIT);
    assert_int_equal(bgm_outbox_count(ob), 3);
    assert_int_equal(bgm_outbox_item(ob, 0)->msg.req, 1);
    assert_true(bgm_outbox_item(ob, 1)->is_timer);
    assert_int_equal(bgm_outbox_item(ob, 1)->arg, 99);
    assert_int_equal(bgm_outbox_item(ob, 2)->msg.req, 2);
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_outbox_count(ob), 0);
    assert_int_equal(bgm_outbox_send(ob, &m), BG_OK);
    bgm_outbox_destroy(&ob);
    assert_null(ob);
    assert_null(bgm_outbox_new(0));
}


/* ------------------------------------------------------- resource seller */

enum { SELF = 9, BUYER = 6 };
static const double R_CORES = 4.0, R_MEM = 8.0, R_CCOST = 0.05, R_MCOST = 0.01, R_SPEED = 2e9;

static bgm_resource_t *seller_sharing(const bgm_config_t *cfg, int mechanism, const uint32_t *nbr,
                                      const uint8_t *same, int degree, int share_phases)
{
    bgm_resource_params_t p;
    memset(&p, 0, sizeof p);
    p.cfg = cfg;
    p.mechanism = mechanism;
    p.self = SELF;
    p.market = 0;
    p.horizon = 1000.0;
    p.cores = R_CORES;
    p.memory = R_MEM;
    p.core_cost = R_CCOST;
    p.memory_cost = R_MCOST;
    p.speed = R_SPEED;
    bgm_rng_derive(&p.rng, 7, 0, 0, 1);
    bgm_genes_random(&p.genes, &p.rng);
    p.markup = 0.2;
    p.neighbours = nbr;
    p.same_role = same;
    p.degree = degree;
    p.share_phases = share_phases;
    bgm_resource_t *rs = bgm_resource_new(&p);
    assert_non_null(rs);
    return rs;
}

static bgm_resource_t *seller(const bgm_config_t *cfg, int mechanism, const uint32_t *nbr,
                              const uint8_t *same, int degree)
{
    return seller_sharing(cfg, mechanism, nbr, same, degree, 0);
}

/* A request for a bundle of `cores` and `mem` for `flops`, within `budget`,
 * standing until `deadline`. */
static bgm_msg_t bundle_msg(int type, uint32_t from, uint32_t req, double cores, double mem,
                            double flops, double price, double budget, double deadline)
{
    bgm_msg_t m = mk(type, from, req);
    m.to = SELF;
    m.good = -1;
    m.a = cores;
    m.b = mem;
    m.c = flops;
    m.price = price;
    m.origin = from;
    m.cand_price[1] = budget;
    m.cand_price[2] = deadline;
    return m;
}

static const bgm_msg_t *only_msg(const bgm_outbox_t *ob, int type)
{
    const bgm_msg_t *found = NULL;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (!it->is_timer && it->msg.type == type) {
            assert_null(found);
            found = &it->msg;
        }
    }
    return found;
}

/* An award it has room for, at a rate covering its cost and within the
 * budget, is held for the run time flops / (speed x cores) and confirmed
 * with its own cost rate; awards beyond its room, below its cost or over
 * the budget are refused (RFAIL to the buyer, RFREE to the market); the
 * release timer gives the room back and tells the market. */
static void test_resource_rents_within_room_cost_and_budget(void **state)
{
    (void)state;
    bgm_config_t cfg = config("central", 0.5);
    bgm_resource_t *rs = seller(&cfg, BGM_MECH_CENTRAL, NULL, NULL, 0);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    assert_int_equal(bgm_resource_start(rs, 0.0, ob), BG_OK);
    const bgm_msg_t *rask = only_msg(ob, BGM_MT_RASK);
    assert_non_null(rask);
    assert_true(rask->a == R_CORES && rask->b == R_MEM && rask->c == R_SPEED);
    assert_true(rask->price == R_CCOST && rask->cand_price[0] == R_MCOST);
    bgm_outbox_clear(ob);

    const double cores = 3.0, mem = 2.0, flops = 12e9, now = 5.0;
    const double dur = flops / (R_SPEED * cores), cost = R_CCOST * cores + R_MCOST * mem;
    bgm_msg_t award = bundle_msg(BGM_MT_RAWARD, 0, 31, cores, mem, flops, 1.5 * cost,
                                 2.0 * cost * dur, 0.0);
    award.origin = BUYER;
    assert_int_equal(bgm_resource_on_message(rs, &award, now, 1, ob), BG_OK);
    const bgm_msg_t *rc = only_msg(ob, BGM_MT_RCONFIRM);
    assert_non_null(rc);
    assert_int_equal(rc->to, BUYER);
    assert_int_equal(rc->req, 31);
    assert_int_equal(rc->good, -1);
    assert_true(fabs(rc->price - 1.5 * cost) < EPS);
    assert_true(fabs(rc->a - now) < EPS && fabs(rc->b - (now + dur)) < 1e-9);
    assert_true(fabs(rc->c - cost) < EPS);
    double uc, um;
    bgm_resource_used(rs, &uc, &um);
    assert_true(uc == cores && um == mem);
    uint64_t release_arg = 0;
    double release_at = 0.0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        if (bgm_outbox_item(ob, i)->is_timer) {
            release_at = bgm_outbox_item(ob, i)->at;
            release_arg = bgm_outbox_item(ob, i)->arg;
            assert_int_equal(bgm_outbox_item(ob, i)->kind, BGM_RS_TIMER_RELEASE);
        }
    assert_true(fabs(release_at - (now + dur)) < 1e-9);

    /* No room for 3 more cores; below cost; over budget; host down. */
    bgm_msg_t bad[4] = {award, award, award, award};
    bad[0].req = 32;
    bad[1].a = 1.0;
    bad[1].price = 0.9 * (R_CCOST + R_MCOST * mem);
    bad[2].a = 1.0;
    bad[2].cand_price[1] = 0.5 * bad[2].price * flops / R_SPEED;
    bad[3].a = 1.0;
    for (int i = 0; i < 4; i++) {
        bgm_outbox_clear(ob);
        assert_int_equal(bgm_resource_on_message(rs, &bad[i], now, i < 3, ob), BG_OK);
        assert_null(only_msg(ob, BGM_MT_RCONFIRM));
        const bgm_msg_t *f = only_msg(ob, BGM_MT_RFAIL), *g = only_msg(ob, BGM_MT_RFREE);
        assert_non_null(f);
        assert_non_null(g);
        assert_int_equal(f->to, BUYER);
        assert_int_equal(g->to, 0);
        assert_true(g->a == bad[i].a && g->b == mem);
    }
    bgm_resource_used(rs, &uc, &um);
    assert_true(uc == cores && um == mem);

    bgm_outbox_clear(ob);
    assert_int_equal(bgm_resource_on_timer(rs, BGM_RS_TIMER_RELEASE, release_arg, release_at, 1, ob),
                     BG_OK);
    const bgm_msg_t *fr = only_msg(ob, BGM_MT_RFREE);
    assert_non_null(fr);
    assert_true(fr->a == cores && fr->b == mem);
    bgm_resource_used(rs, &uc, &um);
    assert_true(uc == 0.0 && um == 0.0);
    /* A release for a bundle it does not hold is an error, not a silent change. */
    assert_int_equal(bgm_resource_on_timer(rs, BGM_RS_TIMER_RELEASE, release_arg, release_at, 1, ob),
                     BG_ERR_INVALID);
    bgm_outbox_destroy(&ob);
    bgm_resource_destroy(&rs);
    assert_null(rs);
}

/* A posted order for `cores` cores and 1 GiB of phase `phase` of job
 * `job` (0: names none), at twice its cost rate within the budget;
 * whether the seller rents it. */
static int order_phase(bgm_resource_t *rs, bgm_outbox_t *ob, uint32_t req, uint32_t job, int phase,
                       double cores)
{
    const double flops = 4e9, rate = 2.0 * (R_CCOST * cores + R_MCOST);
    bgm_msg_t o = bundle_msg(BGM_MT_ORDER, BUYER, req, cores, 1.0, flops, rate,
                             2.0 * rate * flops / (R_SPEED * cores), 10.0);
    if (job) {
        o.ncand = 2;
        o.cand[0] = job;
        o.cand[1] = (uint32_t)phase;
    }
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_resource_on_message(rs, &o, 1.0, 1, ob), BG_OK);
    const int rented = only_msg(ob, BGM_MT_RCONFIRM) != NULL;
    assert_true(rented != (only_msg(ob, BGM_MT_REJECT) != NULL));
    return rented;
}

static double cores_used(const bgm_resource_t *rs)
{
    double uc, um;
    bgm_resource_used(rs, &uc, &um);
    return uc;
}

/* With share_phases (the live grid's sellers) a job's bundles of
 * different phases share cores, its phases never running at once: the
 * job occupies the most any one phase holds (a phase's bundles add up),
 * and only that counts against the capacity and what is said to be held;
 * memory adds up whatever the phase; a bundle naming no job counts alone.
 * Releasing a bundle frees only what the job's widest phase loses. The
 * simulator's sellers (share_phases off) count every bundle. */
static void test_resource_shares_cores_between_a_jobs_phases(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_resource_t *rs = seller_sharing(&cfg, BGM_MECH_BASELINE, NULL, NULL, 0, 1);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    /* R_CORES = 4. Job 7: phase 0 two cores, phase 1 three, phase 0 one more. */
    assert_true(order_phase(rs, ob, 1, 7, 0, 2.0));
    assert_true(cores_used(rs) == 2.0);
    assert_true(order_phase(rs, ob, 2, 7, 1, 3.0));
    assert_true(cores_used(rs) == 3.0);
    assert_true(order_phase(rs, ob, 3, 7, 0, 1.0));
    assert_true(cores_used(rs) == 3.0);
    assert_true(bgm_resource_cores_added(rs, 7, 2, 3.0) == 0.0);
    assert_true(bgm_resource_cores_added(rs, 7, 1, 2.0) == 2.0);
    assert_true(bgm_resource_cores_added(rs, 8, 0, 2.0) == 2.0);
    /* Job 8 fits one core, not two; a bundle of no job does not fit. */
    assert_false(order_phase(rs, ob, 4, 8, 0, 2.0));
    assert_true(order_phase(rs, ob, 5, 8, 0, 1.0));
    assert_true(cores_used(rs) == 4.0);
    assert_false(order_phase(rs, ob, 6, 0, 0, 1.0));
    /* But job 7's phase 2 fits within its widest phase. */
    assert_true(order_phase(rs, ob, 7, 7, 2, 3.0));
    double uc, um;
    bgm_resource_used(rs, &uc, &um);
    assert_true(uc == 4.0 && um == 5.0);
    /* Releasing phase 1 (three cores) frees nothing: phases 0 and 2 hold
     * three each; releasing phase 2 then leaves phase 0's three; then
     * phase 0's two-core bundle frees two of them. */
    const int releases[3][2] = {{2, 0}, {7, 0}, {1, 2}};
    for (int i = 0; i < 3; i++) {
        const double before = cores_used(rs);
        bgm_outbox_clear(ob);
        assert_int_equal(
            bgm_resource_on_timer(rs, BGM_RS_TIMER_RELEASE, (uint64_t)releases[i][0], 2.0, 1, ob),
            BG_OK);
        assert_true(fabs(before - cores_used(rs) - releases[i][1]) < 1e-12);
    }
    assert_true(fabs(cores_used(rs) - 2.0) < 1e-12); /* job 7's one core, job 8's one */
    bgm_resource_destroy(&rs);

    /* Without share_phases the same orders add up. */
    rs = seller_sharing(&cfg, BGM_MECH_BASELINE, NULL, NULL, 0, 0);
    assert_true(order_phase(rs, ob, 1, 7, 0, 2.0));
    assert_false(order_phase(rs, ob, 2, 7, 1, 3.0));
    assert_true(order_phase(rs, ob, 3, 7, 1, 2.0));
    assert_true(cores_used(rs) == 4.0);
    assert_true(bgm_resource_cores_added(rs, 7, 0, 1.0) == 1.0);
    bgm_outbox_destroy(&ob);
    bgm_resource_destroy(&rs);
}

/* Asked for a proposal, it answers from its own price policy only: a
 * fresh seller opens at its cost rate for the bundle times (1 + markup),
 * whoever asks; it proposes only what it has room for, passes the call on
 * to its neighbours but the sender and the originator while hops remain,
 * and ignores a call it has seen. */
static void test_resource_proposes_from_own_policy(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    uint32_t nbr[3] = {3, 6, 8};
    uint8_t same[3] = {0, 0, 1};
    bgm_resource_t *rs = seller(&cfg, BGM_MECH_CATALLACTIC, nbr, same, 3);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    const double cores = 2.0, mem = 3.0;
    const double want = 1.2 * (R_CCOST * cores + R_MCOST * mem);
    for (uint32_t origin = 5; origin <= 6; origin++) {
        bgm_outbox_clear(ob);
        bgm_msg_t cfp = bundle_msg(BGM_MT_CFP, 3, 40 + origin, cores, mem, 8e9, 0.0, 0.0, 0.0);
        cfp.origin = origin;
        cfp.hops = 2;
        assert_int_equal(bgm_resource_on_message(rs, &cfp, 1.0, 1, ob), BG_OK);
        const bgm_msg_t *p = only_msg(ob, BGM_MT_PROPOSE);
        assert_non_null(p);
        assert_int_equal(p->to, origin);
        assert_true(fabs(p->price - want) < EPS);
        assert_true(p->a == R_SPEED);
        size_t forwarded = 0;
        for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
            const bgm_msg_t *m = &bgm_outbox_item(ob, i)->msg;
            if (m->type != BGM_MT_CFP)
                continue;
            forwarded++;
            assert_true(m->to != 3 && m->to != origin);
            assert_int_equal(m->hops, 1);
            assert_int_equal(m->from, SELF);
        }
        assert_int_equal(forwarded, origin == 6 ? 1 : 2);
        /* The same call again: nothing. */
        bgm_outbox_clear(ob);
        assert_int_equal(bgm_resource_on_message(rs, &cfp, 1.1, 1, ob), BG_OK);
        assert_int_equal(bgm_outbox_count(ob), 0);
    }
    /* Too big for its room, or a service: forwarded, no proposal. */
    bgm_outbox_clear(ob);
    bgm_msg_t big = bundle_msg(BGM_MT_CFP, 3, 60, R_CORES + 1.0, mem, 8e9, 0.0, 0.0, 0.0);
    big.hops = 2;
    assert_int_equal(bgm_resource_on_message(rs, &big, 1.0, 1, ob), BG_OK);
    assert_null(only_msg(ob, BGM_MT_PROPOSE));
    bgm_msg_t svc = big;
    svc.req = 61;
    svc.good = BGM_GOOD_SOLVE;
    svc.a = 1.0;
    assert_int_equal(bgm_resource_on_message(rs, &svc, 1.0, 1, ob), BG_OK);
    assert_null(only_msg(ob, BGM_MT_PROPOSE));
    bgm_outbox_destroy(&ob);
    bgm_resource_destroy(&rs);
}

/* A seller's ring of bargains: an opening offer opens a fresh session
 * (forgetting an earlier one of the same key), a continuing offer finds
 * it only with the same buyer, request and attempt, and a full ring
 * reuses its oldest session first. */
static void test_sessions_ring(void **state)
{
    (void)state;
    assert_null(bgm_sessions_new(0));
    assert_null(bgm_sessions_new(BGM_SESSIONS_MAX + 1));
    bgm_sessions_t *ss = bgm_sessions_new(3);
    assert_non_null(ss);
    bgm_msg_t o = mk(BGM_MT_OFFER, 2, 10);
    o.hops = 0;
    assert_null(bgm_sessions_for(ss, &o)); /* a bargain never opened */
    o.hops = 1;
    bgm_session_t *s = bgm_sessions_for(ss, &o);
    assert_non_null(s);
    assert_true(s->buyer == 2 && s->req == 10 && s->attempt == 3 && !s->open);
    s->open = 1;
    s->nego.limit = 7.0;
    o.hops = 0;
    assert_ptr_equal(bgm_sessions_for(ss, &o), s);
    assert_ptr_equal(bgm_sessions_find(ss, 2, 10, 3), s);
    bgm_msg_t stale = o;
    stale.attempt = 2;
    assert_null(bgm_sessions_for(ss, &stale));
    bgm_msg_t other = o;
    other.from = 4;
    assert_null(bgm_sessions_for(ss, &other));
    /* Opening again starts afresh, in the same session. */
    o.hops = 1;
    assert_ptr_equal(bgm_sessions_for(ss, &o), s);
    assert_false(s->open);
    s->open = 1;
    /* Two more fill the ring; a fourth evicts the oldest: (2, 10). */
    for (uint32_t r = 11; r <= 13; r++) {
        bgm_msg_t n = mk(BGM_MT_OFFER, 2, r);
        n.hops = 1;
        assert_non_null(bgm_sessions_for(ss, &n));
    }
    assert_null(bgm_sessions_find(ss, 2, 10, 3));
    for (uint32_t r = 11; r <= 13; r++)
        assert_non_null(bgm_sessions_find(ss, 2, r, 3));
    bgm_sessions_destroy(&ss);
    assert_null(ss);
    bgm_sessions_destroy(&ss);
}

/* Bargaining from its own session: an opening offer at or above its
 * asking price is accepted and rented at that price; an offer below its
 * cost never gets a counter-offer below its cost; an offer past the
 * buyer's deadline, one in a bargain it never opened, or one of an
 * earlier attempt of a bargain it holds, gets no answer;
 * an acceptance whose rent would exceed the buyer's budget is rejected. */
static void test_resource_bargains_from_its_own_session(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    bgm_resource_t *rs = seller(&cfg, BGM_MECH_CATALLACTIC, NULL, NULL, 0);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    const double cores = 1.0, mem = 2.0, flops = 4e9;
    const double cost = R_CCOST * cores + R_MCOST * mem, dur = flops / R_SPEED;
    bgm_msg_t o = bundle_msg(BGM_MT_OFFER, BUYER, 70, cores, mem, flops, 1.3 * cost, 10.0, 50.0);
    o.hops = 1;
    assert_int_equal(bgm_resource_on_message(rs, &o, 2.0, 1, ob), BG_OK);
    const bgm_msg_t *rc = only_msg(ob, BGM_MT_RCONFIRM);
    assert_non_null(rc);
    assert_true(fabs(rc->price - 1.3 * cost) < EPS);
    assert_true(fabs(rc->b - rc->a - dur) < 1e-9);

    for (int round = 0; round < 6; round++) {
        bgm_outbox_clear(ob);
        bgm_msg_t low = bundle_msg(BGM_MT_OFFER, BUYER, 71, cores, mem, flops, 0.5 * cost, 10.0,
                                   50.0);
        low.hops = round == 0;
        assert_int_equal(bgm_resource_on_message(rs, &low, 3.0 + round, 1, ob), BG_OK);
        assert_null(only_msg(ob, BGM_MT_RCONFIRM));
        const bgm_msg_t *c = only_msg(ob, BGM_MT_OFFER);
        if (c)
            assert_true(c->price >= cost);
        else
            break; /* rejected: the bargain is over */
    }
    bgm_outbox_clear(ob);
    bgm_msg_t late = o;
    late.req = 72;
    assert_int_equal(bgm_resource_on_message(rs, &late, 50.5, 1, ob), BG_OK);
    bgm_msg_t unopened = o;
    unopened.req = 73;
    unopened.hops = 0;
    assert_int_equal(bgm_resource_on_message(rs, &unopened, 4.0, 1, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    /* A bargain it holds (the first opening it counters; it may walk
     * away from one at random) ignores an offer of an earlier attempt. */
    bgm_msg_t held = bundle_msg(BGM_MT_OFFER, BUYER, 75, cores, mem, flops, 0.9 * cost, 10.0, 50.0);
    held.hops = 1;
    int countered = 0;
    for (uint32_t r = 75; r < 95 && !countered; r++) {
        bgm_outbox_clear(ob);
        held.req = r;
        assert_int_equal(bgm_resource_on_message(rs, &held, 4.0, 1, ob), BG_OK);
        countered = only_msg(ob, BGM_MT_OFFER) != NULL;
    }
    assert_true(countered);
    bgm_outbox_clear(ob);
    bgm_msg_t stale = held;
    stale.hops = 0;
    stale.attempt = held.attempt - 1;
    stale.price = 2.0 * cost;
    assert_int_equal(bgm_resource_on_message(rs, &stale, 4.1, 1, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    stale.attempt = held.attempt; /* the same price in the held attempt is taken */
    assert_int_equal(bgm_resource_on_message(rs, &stale, 4.2, 1, ob), BG_OK);
    assert_non_null(only_msg(ob, BGM_MT_RCONFIRM));
    bgm_outbox_clear(ob);

    bgm_msg_t acc = bundle_msg(BGM_MT_ACCEPT, BUYER, 74, cores, mem, flops, 2.0 * cost,
                               1.5 * cost * dur, 50.0);
    assert_int_equal(bgm_resource_on_message(rs, &acc, 4.0, 1, ob), BG_OK);
    assert_null(only_msg(ob, BGM_MT_RCONFIRM));
    assert_non_null(only_msg(ob, BGM_MT_REJECT));
    bgm_outbox_destroy(&ob);
    bgm_resource_destroy(&rs);
}

/* Baseline: an order at its posted rate is rented, and the directory is
 * told the room left (AVAIL); a part of a call-market bundle is held from
 * the common start and confirmed with the part's numbers. */
static void test_resource_orders_and_parts(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_resource_t *rs = seller(&cfg, BGM_MECH_BASELINE, NULL, NULL, 0);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    bgm_msg_t ord = bundle_msg(BGM_MT_ORDER, BUYER, 80, 2.0, 1.0, 4e9, 0.2, 100.0, 50.0);
    assert_int_equal(bgm_resource_on_message(rs, &ord, 1.0, 1, ob), BG_OK);
    assert_non_null(only_msg(ob, BGM_MT_RCONFIRM));
    const bgm_msg_t *av = only_msg(ob, BGM_MT_AVAIL);
    assert_non_null(av);
    assert_true(av->a == R_CORES - 2.0 && av->b == R_MEM - 1.0);
    bgm_resource_destroy(&rs);

    cfg = config("central", 0.5);
    rs = seller(&cfg, BGM_MECH_CENTRAL, NULL, NULL, 0);
    bgm_outbox_clear(ob);
    bgm_msg_t part = mk(BGM_MT_RPART, 0, 81);
    part.to = SELF;
    part.good = BGM_GOOD_MEMORY_ID;
    part.a = 1.5;
    part.b = 10.0;
    part.price = 0.02;
    part.c = 0.03;
    part.hops = 3;
    part.origin = BUYER;
    part.cand_price[0] = 2.0;
    assert_int_equal(bgm_resource_on_message(rs, &part, 1.0, 1, ob), BG_OK);
    const bgm_msg_t *rc = only_msg(ob, BGM_MT_RCONFIRM);
    assert_non_null(rc);
    assert_int_equal(rc->to, BUYER);
    assert_int_equal(rc->hops, 3);
    assert_true(rc->a == 2.0 && rc->b == 12.0);
    assert_true(rc->cand_price[0] == 1.5 && rc->cand_price[1] == 0.03 &&
                rc->cand_price[2] == R_MCOST);
    double uc, um;
    bgm_resource_used(rs, &uc, &um);
    assert_true(uc == 0.0 && um == 1.5);
    /* The start has passed: refused. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_resource_on_message(rs, &part, 2.5, 1, ob), BG_OK);
    assert_non_null(only_msg(ob, BGM_MT_RFAIL));
    bgm_outbox_destroy(&ob);
    bgm_resource_destroy(&rs);
}

/* ------------------------------------------------ basic seller, buyer */

/* The basic seller of these tests (agent 6 of the ids above: buyers
 * 1..4, resource sellers 8..9) sells rotation-fit and sparse-solve, not
 * integration-step, with 2 slots. */
enum { BASIC = 6, JOB_AGENT = 2, RESOURCE = 8 };
static const double B_COST[BGM_SERVICE_TYPES] = {0.4, 0.7, 0.9};

static bgm_seller_t *basic(const bgm_config_t *cfg, int mechanism, int slots)
{
    static const uint32_t nbr[3] = {2, 7, 8};
    static const uint8_t same[3] = {0, 1, 0};
    bgm_seller_params_t p;
    memset(&p, 0, sizeof p);
    p.cfg = cfg;
    p.mechanism = mechanism;
    p.self = BASIC;
    p.market = 0;
    p.horizon = 1000.0;
    p.first_buyer = 1;
    p.nbuyers = 4;
    p.first_resource = FIRST_RES;
    p.nresource = NRES;
    p.sells[BGM_GOOD_ROTFIT] = p.sells[BGM_GOOD_SOLVE] = 1;
    p.slots = slots;
    memcpy(p.cost, B_COST, sizeof p.cost);
    bgm_rng_derive(&p.rng, 7, 0, 0, 2);
    bgm_genes_random(&p.genes, &p.rng);
    p.markup = 0.2;
    p.neighbours = nbr;
    p.same_role = same;
    p.degree = 3;
    bgm_seller_t *s = bgm_seller_new(&p);
    assert_non_null(s);
    return s;
}

/* Its reservation for a type from its definition: its own cost plus the
 * resources a unit takes (cores and memory at the mean cost rate for the
 * run time of a unit's flops on a node of the nominal speed). */
static double reservation_of(const bgm_config_t *cfg, int good)
{
    const bgm_service_cfg_t *sv = &cfg->services[good];
    double rate = cfg->resources.core_cost * sv->cores + cfg->resources.memory_cost * sv->memory;
    return B_COST[good] + rate * sv->flops_per_unit / (cfg->network.speed * sv->cores);
}

static bgm_msg_t to_basic(int type, uint32_t from, uint32_t req, int good, double price,
                          double work, double until)
{
    bgm_msg_t m = mk(type, from, req);
    m.to = BASIC;
    m.good = (int16_t)good;
    m.price = price;
    m.a = work;
    m.origin = from;
    m.cand_price[2] = until;
    return m;
}

static size_t count_msgs(const bgm_outbox_t *ob, int type)
{
    size_t n = 0;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        n += !bgm_outbox_item(ob, i)->is_timer && bgm_outbox_item(ob, i)->msg.type == type;
    return n;
}

static const bgm_out_item_t *only_timer(const bgm_outbox_t *ob, int kind)
{
    const bgm_out_item_t *found = NULL;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (it->is_timer && it->kind == kind) {
            assert_null(found);
            found = it;
        }
    }
    return found;
}

/* A call for a type it sells, with a slot free, gets a PROPOSE to the
 * call's originator at its opening price (its reservation marked up by
 * its markup: it remembers no price yet), and is passed on one hop less
 * to its neighbours but the sender and the originator; a call for a type
 * it does not sell is only passed on; a call seen before gets nothing. */
static void test_seller_proposes_what_it_sells(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    bgm_seller_t *s = basic(&cfg, BGM_MECH_CATALLACTIC, 2);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    uint32_t next = 100;
    bgm_msg_t cfp = to_basic(BGM_MT_CFP, 7, 40, BGM_GOOD_SOLVE, 0.0, 3.0, 0.0);
    cfp.origin = JOB_AGENT;
    cfp.hops = 2;
    assert_int_equal(bgm_seller_on_message(s, &cfp, 1.0, 1, &next, ob), BG_OK);
    const bgm_msg_t *p = only_msg(ob, BGM_MT_PROPOSE);
    assert_non_null(p);
    assert_int_equal(p->to, JOB_AGENT);
    assert_int_equal(p->req, 40);
    assert_int_equal(p->attempt, 3);
    assert_true(fabs(p->price - 1.2 * reservation_of(&cfg, BGM_GOOD_SOLVE)) < EPS);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), 1); /* to 8: not 7 (sender), not 2 (origin) */
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_msg_t *m = &bgm_outbox_item(ob, i)->msg;
        if (m->type == BGM_MT_CFP) {
            assert_int_equal(m->to, 8);
            assert_int_equal(m->hops, 1);
            assert_int_equal(m->from, BASIC);
        }
    }
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_seller_on_message(s, &cfp, 1.1, 1, &next, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    bgm_msg_t other = cfp;
    other.req = 41;
    other.good = BGM_GOOD_INTEG;
    assert_int_equal(bgm_seller_on_message(s, &other, 1.2, 1, &next, ob), BG_OK);
    assert_null(only_msg(ob, BGM_MT_PROPOSE));
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), 1);
    assert_int_equal(next, 100); /* no request opened */
    bgm_outbox_destroy(&ob);
    bgm_seller_destroy(&s);
}

/* Central: a MATCH is a deal. The seller takes a slot and bids for the
 * bundle the service needs (the type's cores and memory, flops = flops
 * per unit x work, within the deal's revenue, until the bid's deadline),
 * numbering the request as told. Once the bundle is rented it delivers
 * (CONFIRM to the job's agent with the deal's price and the rental, its
 * bundle's number in origin) and holds the slot until the rental ends,
 * when it frees it at the market. A MATCH with no slot free is cancelled;
 * a bundle it cannot get cancels the deal and frees the slot. */
static void test_seller_match_rents_and_delivers(void **state)
{
    (void)state;
    bgm_config_t cfg = config("central", 0.5);
    bgm_seller_t *s = basic(&cfg, BGM_MECH_CENTRAL, 1);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    uint32_t next = 100;
    const double work = 3.0, price = 2.0, deadline = 40.0;
    bgm_msg_t match = to_basic(BGM_MT_MATCH, 0, 40, BGM_GOOD_SOLVE, price, work, 0.0);
    match.origin = JOB_AGENT;
    match.b = 1.5;
    match.c = deadline;
    assert_int_equal(bgm_seller_on_message(s, &match, 1.0, 1, &next, ob), BG_OK);
    assert_int_equal(next, 101);
    assert_int_equal(bgm_seller_used(s), 1);
    const bgm_msg_t *rb = only_msg(ob, BGM_MT_RBID);
    assert_non_null(rb);
    const bgm_service_cfg_t *sv = &cfg.services[BGM_GOOD_SOLVE];
    assert_int_equal(rb->to, 0);
    assert_int_equal(rb->req, 100);
    assert_true(rb->a == (double)sv->cores && rb->b == sv->memory);
    assert_true(fabs(rb->c - sv->flops_per_unit * work) < EPS);
    assert_true(fabs(rb->price - price * work) < EPS);
    assert_true(rb->cand_price[0] == deadline);
    const bgm_out_item_t *dl = only_timer(ob, BGM_PU_TIMER_DEADLINE);
    assert_non_null(dl);
    assert_true(dl->at == deadline && dl->arg == 100);
    /* No slot left: the next match is cancelled, nothing is bought. */
    bgm_outbox_clear(ob);
    match.req = 41;
    match.origin = 3;
    assert_int_equal(bgm_seller_on_message(s, &match, 1.1, 1, &next, ob), BG_OK);
    const bgm_msg_t *c = only_msg(ob, BGM_MT_CANCEL);
    assert_non_null(c);
    assert_true(c->to == 3 && c->req == 41);
    assert_null(only_msg(ob, BGM_MT_RBID));
    assert_int_equal(next, 101);
    /* The bundle is rented: the service is delivered. */
    bgm_outbox_clear(ob);
    bgm_msg_t rc = mk(BGM_MT_RCONFIRM, RESOURCE, 100);
    rc.to = BASIC;
    rc.attempt = 0;
    rc.good = -1;
    rc.price = 0.25;
    rc.a = 2.0;
    rc.b = 9.0;
    assert_int_equal(bgm_seller_on_message(s, &rc, 2.0, 1, &next, ob), BG_OK);
    const bgm_msg_t *cf = only_msg(ob, BGM_MT_CONFIRM);
    assert_non_null(cf);
    assert_true(cf->to == JOB_AGENT && cf->req == 40 && cf->attempt == 3 && cf->origin == 100);
    assert_true(cf->price == price && cf->a == 2.0 && cf->b == 9.0);
    const bgm_out_item_t *rel = only_timer(ob, BGM_SE_TIMER_RELEASE);
    assert_non_null(rel);
    assert_true(rel->at == 9.0 && rel->arg == 100);
    const bgm_purchase_req_t *b = bgm_seller_bundle(s, 100);
    assert_non_null(b);
    assert_true(b->state == BGM_PU_DONE && b->seller == RESOURCE && b->price == 0.25);
    assert_true(b->deal.buyer == JOB_AGENT && b->deal.req == 40 && b->deal.limit == 1.5);
    /* The run ends: the slot is free again. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_seller_on_timer(s, BGM_SE_TIMER_RELEASE, 100, 9.0, 1, ob), BG_OK);
    assert_int_equal(bgm_seller_used(s), 0);
    const bgm_msg_t *fr = only_msg(ob, BGM_MT_FREE);
    assert_non_null(fr);
    assert_int_equal(fr->to, 0);
    /* A bundle it cannot get: the deal is off, the slot freed. */
    bgm_outbox_clear(ob);
    match.req = 42;
    match.origin = 4;
    assert_int_equal(bgm_seller_on_message(s, &match, 10.0, 1, &next, ob), BG_OK);
    assert_int_equal(next, 102);
    bgm_outbox_clear(ob);
    bgm_msg_t rf = mk(BGM_MT_RFAIL, 0, 101);
    rf.to = BASIC;
    assert_int_equal(bgm_seller_on_message(s, &rf, 10.5, 1, &next, ob), BG_OK);
    c = only_msg(ob, BGM_MT_CANCEL);
    assert_non_null(c);
    assert_true(c->to == 4 && c->req == 42);
    assert_non_null(only_msg(ob, BGM_MT_FREE));
    assert_int_equal(bgm_seller_used(s), 0);
    assert_true(bgm_seller_bundle(s, 101)->state == BGM_PU_FAILED);
    bgm_purchase_tally_t tally = {0};
    bgm_seller_counts(s, &tally);
    assert_true(tally.requests == 2.0 && tally.timeouts == 0.0);
    bgm_outbox_destroy(&ob);
    bgm_seller_destroy(&s);
}

/* Baseline: an ORDER from a job's agent at its posted price (its
 * reservation marked up by the baseline's markup), while the order
 * stands, is accepted at that price and the seller asks the directory
 * for resources; an order past its time, for a type it cannot serve, or
 * not from a job's agent gets nothing. */
static void test_seller_takes_orders_while_they_stand(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_seller_t *s = basic(&cfg, BGM_MECH_BASELINE, 2);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    uint32_t next = 100;
    assert_int_equal(bgm_seller_start(s, 0.0, ob), BG_OK);
    assert_int_equal(count_msgs(ob, BGM_MT_ASK), 2);
    const double posted = reservation_of(&cfg, BGM_GOOD_ROTFIT) * 1.25;
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_msg_t *m = &bgm_outbox_item(ob, i)->msg;
        if (m->good == BGM_GOOD_ROTFIT)
            assert_true(fabs(m->price - posted) < EPS && m->a == 2.0);
    }
    bgm_outbox_clear(ob);
    bgm_msg_t late = to_basic(BGM_MT_ORDER, JOB_AGENT, 40, BGM_GOOD_ROTFIT, posted, 2.0, 4.0);
    assert_int_equal(bgm_seller_on_message(s, &late, 5.0, 1, &next, ob), BG_OK);
    bgm_msg_t notbuyer = to_basic(BGM_MT_ORDER, RESOURCE, 41, BGM_GOOD_ROTFIT, posted, 2.0, 9.0);
    assert_int_equal(bgm_seller_on_message(s, &notbuyer, 5.0, 1, &next, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    bgm_msg_t order = to_basic(BGM_MT_ORDER, JOB_AGENT, 42, BGM_GOOD_ROTFIT, posted, 2.0, 9.0);
    assert_int_equal(bgm_seller_on_message(s, &order, 5.0, 1, &next, ob), BG_OK);
    const bgm_msg_t *a = only_msg(ob, BGM_MT_ACCEPT);
    assert_non_null(a);
    assert_true(a->to == JOB_AGENT && a->req == 42 && a->price == posted);
    const bgm_msg_t *q = only_msg(ob, BGM_MT_QUERY);
    assert_non_null(q);
    assert_true(q->req == 100 && q->good == BGM_GOOD_CORES_ID && isinf(q->price));
    const bgm_msg_t *av = only_msg(ob, BGM_MT_AVAIL);
    assert_non_null(av);
    assert_true(av->a == 1.0); /* one slot of two left */
    bgm_outbox_destroy(&ob);
    bgm_seller_destroy(&s);
}

static bgm_buyer_t *job_agent(const bgm_config_t *cfg, int mechanism)
{
    static const uint32_t nbr[2] = {1, BASIC};
    static const uint8_t same[2] = {1, 0};
    bgm_buyer_params_t p;
    memset(&p, 0, sizeof p);
    p.cfg = cfg;
    p.mechanism = mechanism;
    p.self = JOB_AGENT;
    p.market = 0;
    p.horizon = 1000.0;
    p.arrival_end = 1000.0;
    bgm_rng_derive(&p.demand, 7, 0, 0, 3);
    bgm_rng_derive(&p.rng, 7, 0, 0, 4);
    bgm_genes_random(&p.genes, &p.rng);
    p.markup = 0.2;
    p.neighbours = nbr;
    p.same_role = same;
    p.degree = 2;
    bgm_buyer_t *b = bgm_buyer_new(&p);
    assert_non_null(b);
    return b;
}

/* Fires the earliest timer of `ob` at the buyer (clearing ob first);
 * returns 0 when there is none. The timers of a call are kept in `pend`. */
typedef struct pending {
    bgm_out_item_t t[256];
    int n;
} pending_t;

static void keep_timers(pending_t *pend, const bgm_outbox_t *ob)
{
    for (size_t i = 0; i < bgm_outbox_count(ob); i++)
        if (bgm_outbox_item(ob, i)->is_timer) {
            assert_true(pend->n < 256);
            pend->t[pend->n++] = *bgm_outbox_item(ob, i);
        }
}

static int pop_timer(pending_t *pend, bgm_out_item_t *out)
{
    if (pend->n == 0)
        return 0;
    int best = 0;
    for (int i = 1; i < pend->n; i++)
        if (pend->t[i].at < pend->t[best].at)
            best = i;
    *out = pend->t[best];
    pend->t[best] = pend->t[--pend->n];
    return 1;
}

/* Catallactic, nobody proposing: a job arrives; each of its items calls
 * for proposals over the overlay, waits discovery_timeout, counts a
 * timeout and retries after a backoff that doubles with each round
 * (retry_backoff, then twice, four times it...), and gives up for good
 * once a retry could not start before the deadline. Counted from the
 * definition: round k + 1 starts at s(k) + discovery + backoff(k) while
 * that is before t0 + deadline; the rounds are as many as bgm_budget says
 * a request can start at most, or fewer. */
static void test_buyer_retries_then_fails_at_deadline(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    bgm_buyer_t *b = job_agent(&cfg, BGM_MECH_CATALLACTIC);
    bgm_outbox_t *ob = bgm_outbox_new(256);
    pending_t pend = {.n = 0};
    uint32_t next = 100;
    assert_int_equal(bgm_buyer_start(b, 0.0, ob), BG_OK);
    const bgm_out_item_t *arr = only_timer(ob, BGM_BU_TIMER_ARRIVAL);
    assert_non_null(arr);
    const double t0 = arr->at;
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_buyer_on_timer(b, BGM_BU_TIMER_ARRIVAL, 0, t0, 1, &next, ob), BG_OK);
    assert_int_equal(bgm_buyer_jobs(b), 1);
    const uint32_t items = next - 100;
    assert_true(items >= 2); /* every plan has rotation-fit and sparse-solve */
    const bgm_purchase_req_t *r = bgm_buyer_request(b, 100);
    assert_non_null(r);
    assert_true(r->good == BGM_GOOD_ROTFIT && r->created == t0);
    assert_true(r->deadline == t0 + cfg.demand.deadline);
    int expected = 1;
    double last_start = t0;
    for (;;) {
        const int doublings =
            expected - 1 < BGM_PU_RETRY_MAX_DOUBLINGS ? expected - 1 : BGM_PU_RETRY_MAX_DOUBLINGS;
        const double next_start = last_start + cfg.catallactic.discovery_timeout +
                                  cfg.catallactic.retry_backoff * (double)(1 << doublings);
        if (next_start >= t0 + cfg.demand.deadline)
            break;
        last_start = next_start;
        expected++;
    }
    assert_true(expected >= 3 && expected <= bgm_budget_attempts(cfg.demand.deadline,
                                                                 cfg.catallactic.retry_backoff));
    int calls = 0;
    double last_call = -1.0, failed_at = -1.0;
    for (;;) {
        for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
            const bgm_out_item_t *it = bgm_outbox_item(ob, i);
            if (it->is_timer || it->msg.req != 100)
                continue;
            assert_int_equal(it->msg.type, BGM_MT_CFP);
            assert_int_equal(it->msg.to == 1 || it->msg.to == BASIC, 1);
            assert_int_equal(it->msg.attempt, calls / 2);
            calls++;
        }
        keep_timers(&pend, ob);
        bgm_outbox_clear(ob);
        bgm_out_item_t t;
        if (!pop_timer(&pend, &t))
            break;
        if (t.kind == BGM_BU_TIMER_ARRIVAL)
            continue; /* no second job */
        if ((uint32_t)(t.arg & 0x7fffffff) != 100)
            continue; /* the job's other items */
        int before = bgm_buyer_request(b, 100)->state;
        if (before != BGM_PU_FAILED && t.kind == BGM_PU_TIMER_RETRY)
            last_call = t.at;
        assert_int_equal(bgm_buyer_on_timer(b, t.kind, t.arg, t.at, 1, &next, ob), BG_OK);
        if (before != BGM_PU_FAILED && bgm_buyer_request(b, 100)->state == BGM_PU_FAILED)
            failed_at = t.at;
    }
    assert_int_equal(calls, 2 * expected); /* two neighbours a call */
    assert_true(fabs(last_call - last_start) < 1e-9);
    assert_true(failed_at > last_call && failed_at <= t0 + cfg.demand.deadline);
    assert_int_equal(next, 100 + items); /* retries open no request */
    /* A late proposal changes nothing. */
    bgm_msg_t p = mk(BGM_MT_PROPOSE, BASIC, 100);
    p.to = JOB_AGENT;
    p.attempt = bgm_buyer_request(b, 100)->attempt;
    p.price = 0.1;
    assert_int_equal(bgm_buyer_on_message(b, &p, failed_at + 1.0, 1, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    bgm_purchase_tally_t tally = {0};
    bgm_buyer_counts(b, &tally);
    assert_true(tally.requests == (double)items);
    assert_true(tally.timeouts >= (double)expected);
    bgm_outbox_destroy(&ob);
    bgm_buyer_destroy(&b);
}

/* ----------------------------------------------------- the buying half */

enum { PU_SELF = 3, PU_MARKET = 0 };

/* A purchase with `degree` overlay neighbours numbered 20, 21, ... */
static bgm_purchase_t *purchase(const bgm_config_t *cfg, int mechanism, int degree)
{
    static uint32_t nbr[BGM_PU_MAX_NEIGHBOURS];
    static uint8_t same[BGM_PU_MAX_NEIGHBOURS];
    for (int i = 0; i < degree; i++)
        nbr[i] = 20 + (uint32_t)i;
    bgm_purchase_params_t p;
    memset(&p, 0, sizeof p);
    p.cfg = cfg;
    p.mechanism = mechanism;
    p.self = PU_SELF;
    p.market = PU_MARKET;
    p.horizon = 1000.0;
    bgm_rng_derive(&p.trader.rng, 7, 0, 0, 5);
    bgm_genes_random(&p.trader.genes, &p.trader.rng);
    p.neighbours = nbr;
    p.same_role = same;
    p.degree = degree;
    bgm_purchase_t *pu = bgm_purchase_new(&p);
    assert_non_null(pu);
    return pu;
}

/* Opens service request `id` (rotation-fit, 2 units at up to 5 per unit,
 * deadline 30 s later) at time now. */
static void open_item(bgm_purchase_t *pu, uint32_t id, double now, bgm_outbox_t *ob)
{
    bgm_purchase_req_t it = {0};
    it.id = id;
    it.good = BGM_GOOD_ROTFIT;
    it.work = 2.0;
    it.limit = 5.0;
    it.created = now;
    it.deadline = now + 30.0;
    bgm_purchase_event_t ev;
    assert_int_equal(bgm_purchase_open(pu, &it, now, 1, ob, &ev), BG_OK);
}

/* The phase timer the last call armed: when it fires, and its argument. */
static double phase_timer(const bgm_outbox_t *ob, uint64_t *arg)
{
    const bgm_out_item_t *t = only_timer(ob, BGM_PU_TIMER_REQ);
    assert_non_null(t);
    *arg = t->arg;
    return t->at;
}

static bgm_msg_t to_buyer(int type, uint32_t from, uint32_t req, uint32_t attempt)
{
    bgm_msg_t m = mk(type, from, req);
    m.to = PU_SELF;
    m.attempt = attempt;
    return m;
}

/* Baseline: its timers follow the round trips it measures (RFC 6298).
 * Before any, a query waits 4 reply_timeout and an order reply_timeout;
 * the first sample R gives srtt = R, rttvar = R / 2 and timers of
 * srtt + 4 rttvar = 3 R; each timeout doubles the timer until the next
 * sample, which updates srtt (gain 1/8) and rttvar (gain 1/4 of the
 * deviation). With the configured 0.5 s an order crossing a wide-area
 * network (0.52 s round trips on the random platform) timed out before its
 * answer came, every time. */
static void test_purchase_timers_follow_round_trips(void **state)
{
    (void)state;
    bgm_config_t cfg = config("baseline", 0.5);
    bgm_purchase_t *pu = purchase(&cfg, BGM_MECH_BASELINE, 0);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    bgm_purchase_event_t ev;
    uint64_t arg;
    open_item(pu, 1, 10.0, ob);
    assert_non_null(only_msg(ob, BGM_MT_QUERY));
    assert_true(fabs(phase_timer(ob, &arg) - (10.0 + 4.0 * cfg.catallactic.reply_timeout)) < EPS);
    /* The directory answers 1.2 s later with two candidates. */
    bgm_outbox_clear(ob);
    bgm_msg_t l = to_buyer(BGM_MT_LIST, PU_MARKET, 1, 0);
    l.ncand = 2;
    l.cand[0] = 30;
    l.cand[1] = 31;
    l.cand_price[0] = l.cand_price[1] = 1.0;
    assert_int_equal(bgm_purchase_on_message(pu, &l, 11.2, ob, &ev), BG_OK);
    const bgm_msg_t *o = only_msg(ob, BGM_MT_ORDER);
    assert_true(o && o->to == 30);
    assert_true(fabs(phase_timer(ob, &arg) - (11.2 + 3.0 * 1.2)) < 1e-9);
    /* Seller 30 stays quiet: the next order, to 31, waits twice as long. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_purchase_on_timer(pu, BGM_PU_TIMER_REQ, arg, 14.8, 1, ob, &ev), BG_OK);
    o = only_msg(ob, BGM_MT_ORDER);
    assert_true(o && o->to == 31);
    const uint32_t attempt = o->attempt;
    assert_true(fabs(phase_timer(ob, &arg) - (14.8 + 2.0 * 3.0 * 1.2)) < 1e-9);
    /* 31 accepts 0.4 s later: srtt 1.1, rttvar 0.65, no doubling. */
    bgm_outbox_clear(ob);
    bgm_msg_t a = to_buyer(BGM_MT_ACCEPT, 31, 1, attempt);
    a.price = 1.0;
    assert_int_equal(bgm_purchase_on_message(pu, &a, 15.2, ob, &ev), BG_OK);
    assert_int_equal(bgm_purchase_get(pu, 1)->state, BGM_PU_COMMITTED);
    bgm_outbox_clear(ob);
    open_item(pu, 2, 20.0, ob);
    assert_true(fabs(phase_timer(ob, &arg) - (20.0 + 1.1 + 4.0 * 0.65)) < 1e-9);
    bgm_purchase_tally_t tally = {0};
    bgm_purchase_counts(pu, &tally);
    assert_true(tally.timeout[BGM_PU_TO_REPLY] == 1.0 && tally.timeouts == 1.0);
    bgm_outbox_destroy(&ob);
    bgm_purchase_destroy(&pu);
}

/* Catallactic: a round's discovery window lasts as long as proposals have
 * been taking to come back (the same estimator over proposal delays, a
 * late proposal counted too), never less than discovery_timeout; a failed
 * round is retried after retry_backoff, then twice, four times that. The
 * fixed 0.5 s window closed before proposals crossing the random platform
 * (0.6-1.2 s) came back, and the request retried every 2 s until its
 * deadline: 11 rounds of calls a request. */
static void test_purchase_discovery_window_and_backoff(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    bgm_purchase_t *pu = purchase(&cfg, BGM_MECH_CATALLACTIC, 2);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    bgm_purchase_event_t ev;
    uint64_t arg;
    open_item(pu, 1, 10.0, ob);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), 2);
    assert_true(fabs(phase_timer(ob, &arg) - (10.0 + cfg.catallactic.discovery_timeout)) < EPS);
    /* Nobody answers in the window: a quiet round, retried 2 s later. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_purchase_on_timer(pu, BGM_PU_TIMER_REQ, arg, 10.5, 1, ob, &ev), BG_OK);
    const bgm_out_item_t *r = only_timer(ob, BGM_PU_TIMER_RETRY);
    assert_true(r && fabs(r->at - (10.5 + cfg.catallactic.retry_backoff)) < EPS);
    const bgm_out_item_t retry = *r;
    /* The round's proposal comes 0.9 s after its calls, too late. */
    bgm_outbox_clear(ob);
    bgm_msg_t pr = to_buyer(BGM_MT_PROPOSE, 21, 1, 0);
    pr.price = 1.0;
    assert_int_equal(bgm_purchase_on_message(pu, &pr, 10.9, ob, &ev), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    /* The next round waits 0.9 + 4 x 0.45 = 2.7 s for proposals. */
    assert_int_equal(bgm_purchase_on_timer(pu, BGM_PU_TIMER_RETRY, retry.arg, retry.at, 1, ob, &ev),
                     BG_OK);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), 2);
    assert_true(fabs(phase_timer(ob, &arg) - (retry.at + 2.7)) < 1e-9);
    /* Quiet again: the second retry waits twice the backoff. */
    bgm_outbox_clear(ob);
    assert_int_equal(bgm_purchase_on_timer(pu, BGM_PU_TIMER_REQ, arg, retry.at + 2.7, 1, ob, &ev),
                     BG_OK);
    r = only_timer(ob, BGM_PU_TIMER_RETRY);
    assert_true(r && fabs(r->at - (retry.at + 2.7 + 2.0 * cfg.catallactic.retry_backoff)) < 1e-9);
    bgm_purchase_tally_t tally = {0};
    bgm_purchase_counts(pu, &tally);
    assert_true(tally.timeout[BGM_PU_TO_DISCOVERY] == 2.0 && tally.attempts == 2.0);
    bgm_outbox_destroy(&ob);
    bgm_purchase_destroy(&pu);
}

/* A call for proposals goes to at most overlay_degree neighbours from its
 * originator and to at most overlay_degree - 1 more from each agent that
 * passes it on (never back to where it came from or to its originator),
 * whatever degree the random overlay gave them: a round costs at most
 * D + D (D - 1) + ... calls over its hops (bgm_budget). */
static void test_calls_fan_out_within_the_overlay_degree(void **state)
{
    (void)state;
    bgm_config_t cfg = config("catallactic", 0.5);
    const int D = cfg.agents.overlay_degree, degree = 10;
    assert_true(D < degree - 1);
    bgm_purchase_t *pu = purchase(&cfg, BGM_MECH_CATALLACTIC, degree);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    open_item(pu, 1, 10.0, ob);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), (size_t)D);
    /* A call from neighbour 20, originated by agent 25 (a neighbour too). */
    bgm_outbox_clear(ob);
    bgm_msg_t c = to_buyer(BGM_MT_CFP, 20, 7, 0);
    c.origin = 25;
    c.hops = 2;
    c.good = BGM_GOOD_ROTFIT;
    assert_false(bgm_purchase_cfp_seen(pu, &c));
    assert_true(bgm_purchase_cfp_seen(pu, &c));
    assert_int_equal(bgm_purchase_cfp_forward(pu, &c, ob), BG_OK);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), (size_t)(D - 1));
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_msg_t *m = &bgm_outbox_item(ob, i)->msg;
        assert_true(m->to != 20 && m->to != 25 && m->from == PU_SELF && m->hops == 1);
    }
    bgm_outbox_clear(ob);
    c.hops = 1; /* no hop left: not passed on */
    assert_int_equal(bgm_purchase_cfp_forward(pu, &c, ob), BG_OK);
    assert_int_equal(bgm_outbox_count(ob), 0);
    /* A resource seller with as many neighbours passes it on the same way. */
    uint32_t nbr[10];
    uint8_t same[10] = {0};
    for (int i = 0; i < degree; i++)
        nbr[i] = 20 + (uint32_t)i;
    bgm_resource_t *rs = seller(&cfg, BGM_MECH_CATALLACTIC, nbr, same, degree);
    bgm_msg_t rc = bundle_msg(BGM_MT_CFP, 20, 9, 1.0, 1.0, 1e9, 0.0, 10.0, 100.0);
    rc.origin = 25;
    rc.hops = 2;
    assert_int_equal(bgm_resource_on_message(rs, &rc, 10.0, 1, ob), BG_OK);
    assert_int_equal(count_msgs(ob, BGM_MT_CFP), (size_t)(D - 1));
    bgm_resource_destroy(&rs);
    bgm_outbox_destroy(&ob);
    bgm_purchase_destroy(&pu);
}

/* Central: a job's items are bid for at their valuation, work and
 * deadline. A delivery of an item on its attempt whose run has not ended
 * is taken, once (TAKE, the bundle's number kept); the same item
 * delivered again, or an item whose run has already ended, is refused. */
static void test_buyer_takes_a_delivery_once(void **state)
{
    (void)state;
    bgm_config_t cfg = config("central", 0.5);
    bgm_buyer_t *b = job_agent(&cfg, BGM_MECH_CENTRAL);
    bgm_outbox_t *ob = bgm_outbox_new(64);
    uint32_t next = 100;
    assert_int_equal(bgm_buyer_on_timer(b, BGM_BU_TIMER_ARRIVAL, 0, 5.0, 1, &next, ob), BG_OK);
    assert_int_equal(count_msgs(ob, BGM_MT_BID), next - 100);
    for (size_t i = 0; i < bgm_outbox_count(ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(ob, i);
        if (it->is_timer || it->msg.type != BGM_MT_BID)
            continue;
        const bgm_purchase_req_t *r = bgm_buyer_request(b, it->msg.req);
        assert_non_null(r);
        assert_true(it->msg.to == 0 && it->msg.good == r->good && it->msg.price == r->limit);
        assert_true(it->msg.a == r->work && it->msg.b == r->deadline);
        assert_true(r->work >= cfg.demand.work_min && r->work <= cfg.demand.work_max);
    }
    bgm_outbox_clear(ob);
    bgm_msg_t cf = mk(BGM_MT_CONFIRM, BASIC, 100);
    cf.to = JOB_AGENT;
    cf.attempt = 0;
    cf.price = 1.0;
    cf.a = 6.0;
    cf.b = 20.0;
    cf.origin = 300;
    assert_int_equal(bgm_buyer_on_message(b, &cf, 6.0, 1, ob), BG_OK);
    const bgm_msg_t *x = only_msg(ob, BGM_MT_TAKE);
    assert_non_null(x);
    assert_true(x->to == BASIC && x->req == 100 && x->origin == 300);
    const bgm_purchase_req_t *r = bgm_buyer_request(b, 100);
    assert_true(r->state == BGM_PU_DONE && r->seller == BASIC && r->end == 20.0);
    bgm_outbox_clear(ob);
    cf.origin = 301;
    assert_int_equal(bgm_buyer_on_message(b, &cf, 6.5, 1, ob), BG_OK);
    x = only_msg(ob, BGM_MT_REFUSE);
    assert_non_null(x);
    assert_int_equal(x->origin, 301);
    bgm_outbox_clear(ob);
    cf.req = 101;
    cf.b = 7.0;
    assert_int_equal(bgm_buyer_on_message(b, &cf, 7.0, 1, ob), BG_OK);
    assert_non_null(only_msg(ob, BGM_MT_REFUSE));
    assert_true(bgm_buyer_request(b, 101)->state != BGM_PU_DONE);
    bgm_outbox_destroy(&ob);
    bgm_buyer_destroy(&b);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_auctioneer_clears_to_kdouble_price),
        cmocka_unit_test(test_auctioneer_exchange_rent),
        cmocka_unit_test(test_directory_first_fit),
        cmocka_unit_test(test_directory_next_fit),
        cmocka_unit_test(test_purchase_timers_follow_round_trips),
        cmocka_unit_test(test_purchase_discovery_window_and_backoff),
        cmocka_unit_test(test_calls_fan_out_within_the_overlay_degree),
        cmocka_unit_test(test_auctioneer_exclusions_and_groups),
        cmocka_unit_test(test_auctioneer_refuses_bad_input),
        cmocka_unit_test(test_outbox_order_and_cap),
        cmocka_unit_test(test_resource_rents_within_room_cost_and_budget),
        cmocka_unit_test(test_resource_proposes_from_own_policy),
        cmocka_unit_test(test_resource_shares_cores_between_a_jobs_phases),
        cmocka_unit_test(test_sessions_ring),
        cmocka_unit_test(test_resource_bargains_from_its_own_session),
        cmocka_unit_test(test_resource_orders_and_parts),
        cmocka_unit_test(test_seller_proposes_what_it_sells),
        cmocka_unit_test(test_seller_match_rents_and_delivers),
        cmocka_unit_test(test_seller_takes_orders_while_they_stand),
        cmocka_unit_test(test_buyer_retries_then_fails_at_deadline),
        cmocka_unit_test(test_buyer_takes_a_delivery_once),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
