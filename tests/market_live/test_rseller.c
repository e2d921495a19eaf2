/* bga_rseller: the agent's live resource seller, hosting the simulator's
 * bgm_resource machine. Each live message gets the answer the machine's
 * rules imply, checked against the rules themselves (capacity, cost
 * floor, lease, the asking-rate formula), not against recorded output. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "bga_rseller.h"

#define FLOOR_CORES 1e-3
#define FLOOR_MEMORY 2e-4
#define SLOPE 0.5

/* cmocka before 1.1.6 has no assert_double_equal. */
#define assert_near(a, b, tol) assert_true(fabs((double)(a) - (double)(b)) <= (tol))

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

static bga_rseller_t *seller(void)
{
    const bga_rseller_config_t c = {4, 8, {FLOOR_CORES, FLOOR_MEMORY}, 0.2, SLOPE, 100, 42};
    bga_rseller_t *rs = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_new(&c, &rs, &err), BG_OK);
    return rs;
}

/* Hands the seller one broker message for its resource role (a call for
 * proposals of discovery round `attempt` with `hops` left); what it
 * answers lands in *s. */
static void ask_round(bga_rseller_t *rs, sink_t *s, int type, uint64_t job, int good,
                      double quantity, double price, double term, double now, int hops, int attempt)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, type);
    m.resource = 1;
    m.job = job;
    m.good = good;
    m.quantity = quantity;
    m.price = price;
    m.term = term;
    m.hops = hops;
    m.attempt = attempt;
    s->n = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_on_message(rs, &m, now, collect, s, &err), BG_OK);
}

static void ask(bga_rseller_t *rs, sink_t *s, int type, uint64_t job, int good, double quantity,
                double price, double term, double now)
{
    ask_round(rs, s, type, job, good, quantity, price, term, now, 2, 0);
}

static void orders(void **state)
{
    (void)state;
    bga_rseller_t *rs = seller();
    sink_t s;
    bga_mmsg_t d;
    bga_mmsg_init(&d, BGA_MM_HEARTBEAT);
    bga_rseller_describe(rs, &d);
    assert_near(d.free_cores, 4, 0);
    assert_near(d.free_memory, 8, 0);
    /* Idle, both rates carry the same markup: their ratio is the floors'. */
    assert_near(d.prices[3] / d.prices[4], FLOOR_CORES / FLOOR_MEMORY, 1e-9);
    assert_true(d.prices[3] >= FLOOR_CORES);

    /* 3 of 4 cores at a rate over the floor: confirmed at that rate. */
    ask(rs, &s, BGA_MM_ORDER, 7, 3, 3, 1.3e-3, 50, 0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_int_equal(s.msg[0].resource, 1);
    assert_near(s.msg[0].price, 1.3e-3, 0);
    assert_near(s.msg[0].free_cores, 1, 1e-12);
    assert_near(bga_rseller_used(rs, 0), 3, 0);
    /* Loaded at 3/4 the core rate rises by SLOPE · 3/4 over memory's. */
    bga_rseller_describe(rs, &d);
    assert_near(d.prices[3] / d.prices[4], FLOOR_CORES / FLOOR_MEMORY * (1 + SLOPE * 0.75), 1e-9);

    /* More cores than are free, a rate under the floor, a service good,
     * a quantity that is no number: each refused, naming why. */
    ask(rs, &s, BGA_MM_ORDER, 8, 3, 2, 1.3e-3, 50, 1);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "1 cores free, 2 asked"));
    ask(rs, &s, BGA_MM_ORDER, 9, 4, 1, 1e-4, 50, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "under the floor"));
    ask(rs, &s, BGA_MM_ORDER, 9, 1, 1, 1, 50, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "cores (3) and memory (4)"));
    ask(rs, &s, BGA_MM_ORDER, 9, 4, NAN, 1, 50, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "out of range"));
    /* The same good for the same job twice is not sold twice. */
    ask(rs, &s, BGA_MM_ORDER, 7, 3, 1, 1.3e-3, 50, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "already sold"));
    assert_near(bga_rseller_used(rs, 0), 3, 0);

    /* RELEASE gives the cores back at once. */
    ask(rs, &s, BGA_MM_RELEASE, 7, -1, 0, 0, 0, 2);
    assert_int_equal(s.n, 0);
    assert_near(bga_rseller_used(rs, 0), 0, 0);

    /* All the memory for a 50 s lease: held until then, not after. */
    ask(rs, &s, BGA_MM_ORDER, 10, 4, 8, FLOOR_MEMORY, 50, 10);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_tick(rs, 59.9, &err), BG_OK);
    assert_near(bga_rseller_used(rs, 1), 8, 0);
    assert_int_equal(bga_rseller_tick(rs, 60.0, &err), BG_OK);
    assert_near(bga_rseller_used(rs, 1), 0, 0);
    bga_rseller_destroy(&rs);
    assert_null(rs);
}

static void bargaining(void **state)
{
    (void)state;
    bga_rseller_t *rs = seller();
    const uint32_t nbr[2] = {6, 9};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_registered(rs, 5, nbr, 2, &err), BG_OK);
    sink_t s;
    /* A call for 2 cores: a proposal at or over the floor, the call passed
     * on to both neighbours with one hop less; heard once per round. */
    ask(rs, &s, BGA_MM_CFP, 11, 3, 2, 0, 30, 0);
    assert_int_equal(s.n, 3);
    int relays = 0;
    double proposed = 0;
    for (int i = 0; i < s.n; i++) {
        assert_int_equal(s.msg[i].agent, 5);
        if (s.msg[i].type == BGA_MM_RELAY) {
            assert_true(s.msg[i].target == 6 || s.msg[i].target == 9);
            assert_int_equal(s.msg[i].hops, 1);
            relays++;
        } else {
            assert_int_equal(s.msg[i].type, BGA_MM_PROPOSE);
            proposed = s.msg[i].price;
        }
    }
    assert_int_equal(relays, 2);
    assert_true(proposed >= FLOOR_CORES);
    ask(rs, &s, BGA_MM_CFP, 11, 3, 2, 0, 30, 0);
    assert_int_equal(s.n, 0);

    /* A buyer offering half the floor never gets a contract under it: the
     * seller counters at or over its floor, or walks away. */
    double last = proposed;
    int rounds = 0, rejected = 0;
    for (; rounds < 30 && !rejected; rounds++) {
        ask(rs, &s, BGA_MM_OFFER, 11, 3, 2, FLOOR_CORES / 2, 30, 1);
        assert_int_equal(s.n, 1);
        assert_int_not_equal(s.msg[0].type, BGA_MM_CONFIRM);
        if (s.msg[0].type == BGA_MM_REJECT) {
            rejected = 1;
        } else {
            assert_int_equal(s.msg[0].type, BGA_MM_OFFER);
            assert_true(s.msg[0].price >= FLOOR_CORES * (1 - 1e-12));
            assert_true(s.msg[0].price <= last * (1 + 1e-12)); /* concessions only */
            last = s.msg[0].price;
        }
    }
    assert_true(rejected); /* within the machine's 12 rounds */
    assert_near(bga_rseller_used(rs, 0), 0, 0);

    /* A new round: the buyer counters once, then takes the seller's price. */
    ask_round(rs, &s, BGA_MM_CFP, 11, 3, 2, 0, 30, 2, 1, 1);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_PROPOSE);
    double seller_price = s.msg[0].price;
    ask(rs, &s, BGA_MM_OFFER, 11, 3, 2, FLOOR_CORES, 30, 3);
    assert_int_equal(s.n, 1);
    if (s.msg[0].type == BGA_MM_OFFER) {
        seller_price = s.msg[0].price;
        ask(rs, &s, BGA_MM_ACCEPT, 11, 3, 2, seller_price, 30, 4);
    }
    /* Either the seller took the floor offer or the buyer took its price. */
    assert_int_equal(s.n, 1);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_true(s.msg[0].price >= FLOOR_CORES * (1 - 1e-12));
    assert_true(s.msg[0].price == FLOOR_CORES || s.msg[0].price == seller_price);
    assert_near(bga_rseller_used(rs, 0), 2, 0);
    bga_rseller_destroy(&rs);
}

/* An order of `q` cores for sub-job `sub`, serving service `serves` of
 * job `parent`, at a rate over the floor. */
static void order_for(bga_rseller_t *rs, sink_t *s, uint64_t sub, uint64_t parent, int serves,
                      double q, double now)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_ORDER);
    m.resource = 1;
    m.job = sub;
    m.good = 3;
    m.quantity = q;
    m.price = 1.3e-3;
    m.term = 50;
    m.parent = parent;
    m.serves = serves;
    s->n = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_on_message(rs, &m, now, collect, s, &err), BG_OK);
}

/* The broker names the job and service each sub-job's cores serve: a
 * job's phases run one after another, so the seller (4 cores) counts the
 * job's cores as its widest phase's. Job 1's rotation fit (2 + 1 cores)
 * and sparse solve (3) hold 3; job 2 then gets the last core and not two,
 * and the refusal says what the job would add; cores naming no job count
 * alone. Releasing a sub-job frees only what its job's widest phase
 * loses, and the heartbeat says so. */
static void phases_share_cores(void **state)
{
    (void)state;
    bga_rseller_t *rs = seller();
    sink_t s;
    order_for(rs, &s, 101, 1, 0, 2, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    order_for(rs, &s, 102, 1, 0, 1, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    order_for(rs, &s, 103, 1, 1, 3, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_near(s.msg[0].free_cores, 1, 1e-12);
    assert_near(bga_rseller_used(rs, 0), 3, 1e-12);
    assert_near(bga_rseller_used(rs, 1), 0, 0);
    order_for(rs, &s, 201, 2, 0, 2, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    assert_non_null(strstr(s.msg[0].reason, "1 cores free, 2 asked"));
    order_for(rs, &s, 201, 2, 0, 1, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    order_for(rs, &s, 301, 0, -1, 1, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_REFUSE);
    /* Job 1's phase 2 (one core) fits within its widest phase. */
    order_for(rs, &s, 104, 1, 2, 1, 0);
    assert_int_equal(s.msg[0].type, BGA_MM_CONFIRM);
    assert_near(bga_rseller_used(rs, 0), 4, 1e-12);
    /* The sparse solve ends: job 1's widest phase is its rotation fit's 3. */
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_RELEASE);
    r.resource = 1;
    r.job = 103;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_rseller_on_message(rs, &r, 1, collect, &s, &err), BG_OK);
    assert_near(bga_rseller_used(rs, 0), 4, 1e-12);
    r.job = 101;
    assert_int_equal(bga_rseller_on_message(rs, &r, 1, collect, &s, &err), BG_OK);
    assert_near(bga_rseller_used(rs, 0), 2, 1e-12);
    bga_mmsg_t d;
    bga_mmsg_init(&d, BGA_MM_HEARTBEAT);
    bga_rseller_describe(rs, &d);
    assert_near(d.free_cores, 2, 1e-12);
    bga_rseller_destroy(&rs);
}

static void bad_config(void **state)
{
    (void)state;
    bga_rseller_t *rs = NULL;
    bg_error_t err = BG_ERROR_INIT;
    bga_rseller_config_t c = {4, 8, {0, FLOOR_MEMORY}, 0.2, SLOPE, 100, 1};
    assert_int_equal(bga_rseller_new(&c, &rs, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "core floor"));
    assert_null(rs);
    c.floor[0] = FLOOR_CORES;
    c.cores = 0;
    err = (bg_error_t)BG_ERROR_INIT;
    assert_int_equal(bga_rseller_new(&c, &rs, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "cores"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(orders), cmocka_unit_test(bargaining),
                                       cmocka_unit_test(phases_share_cores),
                                       cmocka_unit_test(bad_config)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
