/*
 * Unit tests of the market's role machines, each driven alone with
 * hand-built messages: what it emits is read back from its outbox and
 * checked against numbers computed here, independently of the mechanism
 * code (the k-double price from its definition, the exchange's rent
 * without competition, first fit over a directory).
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

#include "bgm_config.h"
#include "bgm_market_agent.h"
#include "bgm_outbox.h"
#include "bgm_role.h"

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
    return lo + k * (hi - lo);
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

    double asks[] = {3.0, 7.0, 9.0}, bids[] = {10.0, 6.0, 8.0, 4.5};
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
    assert_true(fabs(p - (7.0 + k * (8.0 - 7.0))) < EPS); /* [max(7, 6), min(8, 9)] */

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

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_auctioneer_clears_to_kdouble_price),
        cmocka_unit_test(test_auctioneer_exchange_rent),
        cmocka_unit_test(test_directory_first_fit),
        cmocka_unit_test(test_auctioneer_refuses_bad_input),
        cmocka_unit_test(test_outbox_order_and_cap),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
