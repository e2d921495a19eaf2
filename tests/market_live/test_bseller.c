/* bga_bseller: the agent's live basic-service seller, hosting the
 * simulator's bgm_seller machine. Each live message gets the answer the
 * machine's rules imply, checked against the rules themselves (slots, the
 * reservation = own cost + one lease of the unit's resources, the asking
 * price formula, the resource bid's cap, the buy wait, the lease), not
 * against recorded output. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "bga_bseller.h"

#define LEASE 100.0
#define RATE_CORES 1e-3
#define RATE_MEMORY 2e-4
#define MARGIN 0.2
#define SLOPE 0.5
#define SLOTS 2

/* cmocka before 1.1.6 has no assert_double_equal. */
#define assert_near(a, b, tol) assert_true(fabs((double)(a) - (double)(b)) <= (tol))

static const double unit_cores[3] = {1, 2, 1}, unit_memory[3] = {1, 4, 2};

typedef struct sink {
    bga_mmsg_t msg[32];
    int n;
} sink_t;

static bg_status collect(void *ctx, const bga_mmsg_t *m, bg_error_t *err)
{
    (void)err;
    sink_t *s = ctx;
    assert_true(s->n < 32);
    s->msg[s->n++] = *m;
    return BG_OK;
}

static bga_bseller_config_t config(void)
{
    bga_bseller_config_t c = {.services = 7,
                              .slots = SLOTS,
                              .floor = {1, 1, 1},
                              .margin = MARGIN,
                              .load_slope = SLOPE,
                              .lease = LEASE,
                              .rate = {RATE_CORES, RATE_MEMORY},
                              .seed = 42};
    memcpy(c.unit_cores, unit_cores, sizeof unit_cores);
    memcpy(c.unit_memory, unit_memory, sizeof unit_memory);
    return c;
}

static bga_bseller_t *seller_with(const bga_bseller_config_t *c)
{
    bga_bseller_t *bs = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_bseller_new(c, &bs, &err), BG_OK);
    uint32_t nb[2] = {7, 9};
    assert_int_equal(bga_bseller_registered(bs, 5, nb, 2, &err), BG_OK);
    return bs;
}

static bga_bseller_t *seller(void)
{
    const bga_bseller_config_t c = config();
    return seller_with(&c);
}

/* One lease of good g's resources at the expected rates. */
static double expected_resources(int g)
{
    return (RATE_CORES * unit_cores[g] + RATE_MEMORY * unit_memory[g]) * LEASE;
}

static void send_in(bga_bseller_t *bs, sink_t *s, const bga_mmsg_t *m, double now)
{
    s->n = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_bseller_on_message(bs, m, now, collect, s, &err), BG_OK);
}

static void ask(bga_bseller_t *bs, sink_t *s, int type, uint64_t job, int good, double price,
                double now)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, type);
    m.job = job;
    m.good = good;
    m.quantity = 1;
    m.price = price;
    send_in(bs, s, &m, now);
}

/* The broker's answer to an RBUY: bought at these asking rates. */
static void bought(bga_bseller_t *bs, sink_t *s, uint64_t job, int good, double rate_cores,
                   double rate_memory, double now)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_RBOUGHT);
    m.job = job;
    m.good = good;
    m.prices[3] = rate_cores;
    m.prices[4] = rate_memory;
    m.price = (rate_cores * unit_cores[good] + rate_memory * unit_memory[good]) * LEASE;
    send_in(bs, s, &m, now);
}

static void tick(bga_bseller_t *bs, sink_t *s, double now)
{
    s->n = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_bseller_tick(bs, now, collect, s, &err), BG_OK);
}

static void release(bga_bseller_t *bs, sink_t *s, uint64_t job, double now)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_RELEASE);
    m.job = job;
    send_in(bs, s, &m, now);
}

/* The reservation is the own floor plus one lease of resources, the
 * asking price posted · (1 + slope · used / slots); an order at it is
 * bought on layer 1 for at most 1.5 times the expected resource cost,
 * then confirmed at the order's price with the reservation as the
 * seller's limit; the contract is held until released. */
static void orders(void **state)
{
    (void)state;
    bga_bseller_t *bs = seller();
    sink_t s;
    for (int g = 0; g < 3; g++) {
        assert_near(bga_bseller_reservation(bs, g), 1.0 + expected_resources(g), 1e-12);
        assert_near(bga_bseller_price(bs, g), (1.0 + expected_resources(g)) * (1 + MARGIN), 1e-12);
    }
    const double price = bga_bseller_price(bs, 1);
    ask(bs, &s, BGA_MM_ORDER, 1000, 1, price, 1.0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_RBUY);
    assert_int_equal(s.msg[0].agent, 5);
    assert_near(s.msg[0].cores, 2, 0);
    assert_near(s.msg[0].memory, 4, 0);
    assert_near(s.msg[0].term, LEASE, 0);
    assert_true(s.msg[0].price > 0);
    assert_true(s.msg[0].price <= 1.5 * expected_resources(1) * (1 + 1e-12));
    assert_int_equal(bga_bseller_used(bs), 1);
    assert_false(bga_bseller_holds(bs, 1000));
    /* The slot counts in the asking price while it buys. */
    assert_near(bga_bseller_price(bs, 0),
                (1.0 + expected_resources(0)) * (1 + MARGIN) * (1 + SLOPE / SLOTS), 1e-12);

    bought(bs, &s, 1000, 1, RATE_CORES, RATE_MEMORY, 1.5);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_near(s.msg[0].price, price, 0);
    assert_near(s.msg[0].floor[1], 1.0 + expected_resources(1), 1e-12);
    assert_int_equal(s.msg[0].free_slots, SLOTS - 1);
    assert_true(bga_bseller_holds(bs, 1000));
    assert_true(bga_bseller_holds(bs, 1000 + 77)); /* a session of the same job */
    assert_false(bga_bseller_holds(bs, 999));
    assert_near(bga_bseller_cores(bs, 1000), 2, 0);

    /* The same (job, good) again, a good it does not sell, a price under
     * the floor: each refused by name. */
    ask(bs, &s, BGA_MM_ORDER, 1000, 1, price, 2.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "already sold"));
    ask(bs, &s, BGA_MM_ORDER, 1001, 3, price, 2.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "does not sell 3"));
    ask(bs, &s, BGA_MM_ORDER, 1001, 0, 0.5 * bga_bseller_reservation(bs, 0), 2.0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "under the floor"));
    assert_int_equal(bga_bseller_used(bs), 1);

    /* Its second slot, then none is left. */
    ask(bs, &s, BGA_MM_ORDER, 1002, 0, bga_bseller_price(bs, 0), 3.0);
    assert_int_equal(s.msg[0].type, BGA_MM_RBUY);
    ask(bs, &s, BGA_MM_ORDER, 1003, 2, 10 * bga_bseller_price(bs, 2), 3.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "no free slot"));

    /* The job ends: its slot is back, nothing is said. */
    release(bs, &s, 1000, 4.0);
    assert_int_equal(s.n, 0);
    assert_false(bga_bseller_holds(bs, 1000));
    assert_int_equal(bga_bseller_used(bs), 1);
    release(bs, &s, 1002, 4.0); /* still buying: given up */
    assert_int_equal(bga_bseller_used(bs), 0);
    bought(bs, &s, 1002, 0, RATE_CORES, RATE_MEMORY, 4.5);
    assert_int_equal(s.n, 0); /* a late answer confirms nothing */
    assert_false(bga_bseller_holds(bs, 1002));
    bga_bseller_destroy(&bs);
    assert_null(bs);
}

/* Resources that cannot be had, or not within the buy wait, end the
 * contract with a REFUSE naming why; a lease ends its contract. */
static void resources_fail(void **state)
{
    (void)state;
    bga_bseller_t *bs = seller();
    sink_t s;
    ask(bs, &s, BGA_MM_ORDER, 1, 0, bga_bseller_price(bs, 0), 0.0);
    bga_mmsg_t f;
    bga_mmsg_init(&f, BGA_MM_RFAIL);
    f.job = 1;
    f.good = 0;
    snprintf(f.reason, sizeof f.reason, "no seller");
    send_in(bs, &s, &f, 0.5);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_string_equal(s.msg[0].reason, "no resources: no seller");
    assert_int_equal(bga_bseller_used(bs), 0);

    ask(bs, &s, BGA_MM_ORDER, 2, 0, bga_bseller_price(bs, 0), 1.0);
    assert_int_equal(s.msg[0].type, BGA_MM_RBUY);
    tick(bs, &s, 1.0 + BGA_BSELLER_BUY_WAIT - 0.01);
    assert_int_equal(s.n, 0);
    assert_int_equal(bga_bseller_used(bs), 1);
    tick(bs, &s, 1.0 + BGA_BSELLER_BUY_WAIT + 0.01);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "not bought within"));
    assert_int_equal(bga_bseller_used(bs), 0);
    bought(bs, &s, 2, 0, RATE_CORES, RATE_MEMORY, 12.0);
    assert_int_equal(s.n, 0);

    ask(bs, &s, BGA_MM_ORDER, 3, 2, bga_bseller_price(bs, 2), 20.0);
    bought(bs, &s, 3, 2, RATE_CORES, RATE_MEMORY, 21.0);
    assert_true(bga_bseller_holds(bs, 3));
    tick(bs, &s, 21.0 + LEASE - 0.5);
    assert_true(bga_bseller_holds(bs, 3));
    tick(bs, &s, 21.0 + LEASE + 0.5);
    assert_false(bga_bseller_holds(bs, 3));
    assert_int_equal(bga_bseller_used(bs), 0);
    bga_bseller_destroy(&bs);
}

/* What a contract's resources cost teaches the reservation: paid at
 * twice the expected rates, it moves towards floor + twice the cost (by
 * the machine's memory weight, in (0, 1]), and the posted price follows. */
static void learns_cost(void **state)
{
    (void)state;
    bga_bseller_t *bs = seller();
    sink_t s;
    const double before = bga_bseller_reservation(bs, 1);
    ask(bs, &s, BGA_MM_ORDER, 1, 1, bga_bseller_price(bs, 1), 0.0);
    bought(bs, &s, 1, 1, 2 * RATE_CORES, 2 * RATE_MEMORY, 0.5);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    const double after = bga_bseller_reservation(bs, 1);
    assert_true(after > before * (1 + 1e-9));
    assert_true(after <= 1.0 + 2 * expected_resources(1) + 1e-12);
    release(bs, &s, 1, 1.0);
    assert_near(bga_bseller_price(bs, 1), after * (1 + MARGIN), 1e-12);
    /* The other goods learnt nothing. */
    assert_near(bga_bseller_reservation(bs, 0), 1.0 + expected_resources(0), 1e-12);
    bga_bseller_destroy(&bs);
}

/* Catallactic: a call is proposed to at the posted price of the round it
 * names and passed on to both neighbours, once per round; a bargain never
 * ends below the reservation; the buyer's acceptance of the seller's last
 * price is bought and confirmed at that price. */
static void bargains(void **state)
{
    (void)state;
    bga_bseller_t *bs = seller();
    sink_t s;
    bga_mmsg_t c;
    bga_mmsg_init(&c, BGA_MM_CFP);
    c.job = 50;
    c.good = 0;
    c.quantity = 1;
    c.hops = 2;
    c.attempt = 3;
    send_in(bs, &s, &c, 0.0);
    assert_int_equal(s.n, 3);
    int proposals = 0, relays = 0;
    double proposal = 0;
    for (int i = 0; i < s.n; i++) {
        if (s.msg[i].type == BGA_MM_PROPOSE) {
            proposals++;
            proposal = s.msg[i].price;
            assert_int_equal(s.msg[i].attempt, 3);
        } else {
            assert_int_equal(s.msg[i].type, BGA_MM_RELAY);
            assert_int_equal(s.msg[i].hops, 1);
            assert_int_equal(s.msg[i].origin, 5);
            assert_true(s.msg[i].target == 7 || s.msg[i].target == 9);
            relays++;
        }
    }
    assert_int_equal(proposals, 1);
    assert_int_equal(relays, 2);
    const double reservation = bga_bseller_reservation(bs, 0);
    assert_near(proposal, reservation * (1 + MARGIN), 1e-12);
    send_in(bs, &s, &c, 0.1); /* the same round by another path */
    assert_int_equal(s.n, 0);

    /* The buyer offers low and concedes until the seller takes its offer
     * or walks away; every counter stays at or above the reservation. */
    double offer = 0.5 * reservation, last_counter = proposal;
    int agreed = 0, over = 0;
    for (int round = 0; round < 40 && !agreed && !over; round++) {
        ask(bs, &s, BGA_MM_OFFER, 50, 0, offer, 0.2 + 0.01 * round);
        assert_int_equal(s.n, 1);
        if (s.msg[0].type == BGA_MM_OFFER) {
            assert_true(s.msg[0].price >= reservation * (1 - 1e-12));
            assert_true(s.msg[0].price <= last_counter * (1 + 1e-12)); /* it concedes */
            last_counter = s.msg[0].price;
            offer += 0.6 * (last_counter - offer);
        } else if (s.msg[0].type == BGA_MM_RBUY) {
            assert_true(offer >= reservation * (1 - 1e-12));
            agreed = 1;
        } else {
            assert_int_equal(s.msg[0].type, BGA_MM_REJECT);
            over = 1;
        }
    }
    assert_true(agreed || over);
    if (agreed) {
        bought(bs, &s, 50, 0, RATE_CORES, RATE_MEMORY, 1.0);
        assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
        assert_near(s.msg[0].price, offer, 1e-12 * offer);
    }

    /* Another job: the buyer takes the seller's first counter. */
    c.job = 60;
    send_in(bs, &s, &c, 2.0);
    ask(bs, &s, BGA_MM_OFFER, 60, 0, 0.5 * reservation, 2.1);
    assert_int_equal(s.msg[0].type, BGA_MM_OFFER);
    last_counter = s.msg[0].price;
    ask(bs, &s, BGA_MM_ACCEPT, 60, 0, last_counter, 2.2);
    assert_int_equal(s.msg[0].type, BGA_MM_RBUY);
    bought(bs, &s, 60, 0, RATE_CORES, RATE_MEMORY, 2.5);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_near(s.msg[0].price, last_counter, 0);
    /* Agreed: a later call of the job is passed on, not proposed to. */
    c.attempt = 5;
    send_in(bs, &s, &c, 3.0);
    assert_int_equal(s.n, 2);
    for (int i = 0; i < s.n; i++)
        assert_int_equal(s.msg[i].type, BGA_MM_RELAY);
    /* An acceptance of no bargain is refused. */
    ask(bs, &s, BGA_MM_ACCEPT, 51, 0, last_counter, 3.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    bga_bseller_destroy(&bs);
}

/* A service that needs no resources is confirmed at once; numbers out of
 * range are refused; a thousand jobs leave no state behind. */
static void edges(void **state)
{
    (void)state;
    bga_bseller_config_t c = config();
    for (int g = 0; g < 3; g++)
        c.unit_cores[g] = c.unit_memory[g] = 0;
    bga_bseller_t *bs = seller_with(&c);
    sink_t s;
    assert_near(bga_bseller_reservation(bs, 0), 1.0, 0);
    ask(bs, &s, BGA_MM_ORDER, 1, 0, bga_bseller_price(bs, 0), 0.0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_true(bga_bseller_holds(bs, 1));
    ask(bs, &s, BGA_MM_ORDER, 2, 0, NAN, 0.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "out of range"));
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_ORDER);
    m.job = 3;
    m.good = 0;
    m.quantity = 0;
    m.price = 2;
    send_in(bs, &s, &m, 0.0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    release(bs, &s, 1, 1.0);
    bga_bseller_destroy(&bs);

    bs = seller();
    for (uint64_t j = 10; j < 1010; j++) {
        ask(bs, &s, BGA_MM_ORDER, j, (int)(j % 3), bga_bseller_price(bs, (int)(j % 3)), (double)j);
        assert_int_equal(s.msg[0].type, BGA_MM_RBUY);
        bought(bs, &s, j, (int)(j % 3), RATE_CORES, RATE_MEMORY, (double)j + 0.1);
        assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
        release(bs, &s, j, (double)j + 0.5);
    }
    assert_int_equal(bga_bseller_used(bs), 0);
    tick(bs, &s, 5000.0);
    assert_int_equal(s.n, 0);
    bga_bseller_destroy(&bs);

    bg_error_t err = BG_ERROR_INIT;
    c = config();
    c.slots = 0;
    assert_int_equal(bga_bseller_new(&c, &bs, &err), BG_ERR_INVALID);
    assert_null(bs);
    assert_non_null(strstr(err.message, "slots"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(orders),   cmocka_unit_test(resources_fail), cmocka_unit_test(learns_cost),
        cmocka_unit_test(bargains), cmocka_unit_test(edges),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
