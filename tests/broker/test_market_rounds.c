/* bgb_market's per-job buyers (the simulator's purchase machine, hosted
 * by the broker, for jobs and for basic sellers' resource sub-jobs) on a
 * virtual clock with fake agents (no sockets):
 * - catallactic discovery: a proposal counts only in the round whose call
 *   it answers. A late one from an earlier round leaves the round
 *   unanswered, so the next round's window widens, and the buyer never
 *   bargains on it; a proposal for the current round is taken up with an
 *   OFFER below it, at once when every seller its calls reach that could
 *   propose has, else when the window closes;
 * - a need split over two sellers goes to two distinct agents under each
 *   mechanism, and a seller's no moves the unit on to another seller;
 * - a sub-job orders its cores and memory at the posted rates (unit
 *   prices, the lease), and a catallactic one bargains as soon as its
 *   host's seller has proposed;
 * - a host's resources have one seller (the first of its daemons to
 *   register), and a job's phases share that seller's cores. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bga_mmsg.h"
#include "bgb_market.h"

#define LOG_MAX 64

typedef struct fake {
    bga_mmsg_t sent[LOG_MAX];
    int nsent;
    int done;
    char reason[32];
    bgb_award_t awards[8];
    int nawards;
} fake_t;

static bg_status capture(void *ctx, const uint8_t *identity, size_t identity_len,
                         const bga_frame_t *frames, int nframes)
{
    (void)identity;
    (void)identity_len;
    fake_t *f = ctx;
    bg_error_t err = BG_ERROR_INIT;
    if (f->nsent < LOG_MAX && bga_mmsg_decode(frames, nframes, &f->sent[f->nsent], &err) == BG_OK)
        f->nsent++;
    return BG_OK;
}

static void on_done(void *ctx, const bgb_outcome_t *o)
{
    fake_t *f = ctx;
    f->done = 1;
    snprintf(f->reason, sizeof f->reason, "%s", o->reason ? o->reason : "");
    f->nawards = o->nawards < 8 ? o->nawards : 8;
    memcpy(f->awards, o->awards, (size_t)f->nawards * sizeof *o->awards);
}

static const uint8_t ID[] = {'A', '1'};

static void deliver(bgb_market_t *m, const bga_mmsg_t *msg, double now)
{
    bga_frames_t fr;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(msg, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    assert_int_equal(bgb_market_on_frames(m, ID, sizeof ID, v, fr.count, now, &err), BG_OK);
    bga_frames_free(&fr);
}

/* The last message of `type` sent, NULL when none since index `from`. */
static const bga_mmsg_t *last_of(const fake_t *f, int type, int from)
{
    for (int i = f->nsent - 1; i >= from; i--)
        if (f->sent[i].type == type)
            return &f->sent[i];
    return NULL;
}

static void stale_proposal_is_not_counted(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_config_default(&mc);
    bgb_market_io_t io = {&f, capture};
    bgb_market_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_new(&mc, &io, &m, &err), BG_OK);

    bga_mmsg_t reg;
    bga_mmsg_init(&reg, BGA_MM_REGISTER);
    snprintf(reg.name, sizeof reg.name, "a1");
    snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://127.0.0.1:9");
    reg.services = 1; /* rotation fit */
    reg.slots = 2;
    reg.free_slots = 2;
    reg.floor[0] = 1;
    reg.prices[0] = 1.2;
    reg.margin = 0.2;
    deliver(m, &reg, 0.0);
    const bga_mmsg_t *r = last_of(&f, BGA_MM_REGISTERED, 0);
    assert_non_null(r);
    const uint32_t id = r->agent;

    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    assert_int_equal(
        bgb_market_buy(m, 1, BGB_MECH_CATALLACTIC, 1e6, &need, 1, 1.0, on_done, &f, &err), BG_OK);
    const bga_mmsg_t *cfp = last_of(&f, BGA_MM_CFP, 0);
    assert_non_null(cfp);
    assert_int_equal(cfp->attempt, 0);

    /* A proposal naming another round (a straggler): not this round's. */
    bga_mmsg_t p;
    bga_mmsg_init(&p, BGA_MM_PROPOSE);
    p.job = 1;
    p.agent = id;
    p.good = BGB_GOOD_ROTFIT;
    p.quantity = 10;
    p.price = 1.2;
    p.attempt = 5;
    deliver(m, &p, 1.05);
    const int mark = f.nsent;
    (void)bgb_market_tick(m, 1.0 + mc.reply_timeout / 8 + 0.01);
    assert_null(last_of(&f, BGA_MM_OFFER, mark));
    cfp = last_of(&f, BGA_MM_CFP, mark);
    assert_non_null(cfp);
    assert_int_equal(cfp->attempt, 1);
    assert_false(f.done);

    /* An answer to the new round (attempt 1), from the only seller that
     * could propose, is bargained on at once (quiet_round_widens_window
     * has the window itself). */
    const double round1 = 1.0 + mc.reply_timeout / 8 + 0.01;
    p.attempt = 1;
    const int mark2 = f.nsent;
    deliver(m, &p, round1 + 0.1);
    const bga_mmsg_t *offer = last_of(&f, BGA_MM_OFFER, mark2);
    assert_non_null(offer);
    assert_int_equal(offer->agent, id);
    assert_true(offer->price > 0 && offer->price <= 1.2);
    bgb_market_destroy(&m);
}

/* ---------------------------------------------- several fake agents */

static void deliver_from(bgb_market_t *m, uint8_t who, const bga_mmsg_t *msg, double now)
{
    const uint8_t idn[] = {'S', who};
    bga_frames_t fr;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(msg, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    assert_int_equal(bgb_market_on_frames(m, idn, sizeof idn, v, fr.count, now, &err), BG_OK);
    bga_frames_free(&fr);
}

/* Registers a seller of service `good` asking `price` with `slots` free;
 * its id. */
static uint32_t seller_of(bgb_market_t *m, fake_t *f, uint8_t who, int good, double price,
                          int slots)
{
    bga_mmsg_t reg;
    bga_mmsg_init(&reg, BGA_MM_REGISTER);
    snprintf(reg.name, sizeof reg.name, "s%c", who);
    snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://127.0.0.1:%d", 9000 + who);
    reg.services = 1u << good;
    reg.slots = reg.free_slots = slots;
    reg.floor[good] = price / 1.2;
    reg.prices[good] = price;
    reg.margin = 0.2;
    const int mark = f->nsent;
    deliver_from(m, who, &reg, 0.0);
    const bga_mmsg_t *r = last_of(f, BGA_MM_REGISTERED, mark);
    assert_non_null(r);
    return r->agent;
}

/* A rotation-fit seller. */
static uint32_t seller(bgb_market_t *m, fake_t *f, uint8_t who, double price, int slots)
{
    return seller_of(m, f, who, BGB_GOOD_ROTFIT, price, slots);
}

/* How many messages of `type` went to agent `to` since index `from`. */
static int count_to(const fake_t *f, int type, uint32_t to, int from)
{
    int n = 0;
    for (int i = from; i < f->nsent; i++)
        n += f->sent[i].type == type && f->sent[i].agent == to;
    return n;
}

static const bga_mmsg_t *last_to(const fake_t *f, int type, uint32_t to, int from)
{
    for (int i = f->nsent - 1; i >= from; i--)
        if (f->sent[i].type == type && f->sent[i].agent == to)
            return &f->sent[i];
    return NULL;
}

/* Agent `who` (id `id`; its resource role when `resource`) answers about
 * `good` of job `job`; a resource seller says it has `free_cores` cores
 * and 8 GiB free left. */
static void answer_with(bgb_market_t *m, uint8_t who, uint32_t id, int resource, uint64_t job,
                        int type, int good, double quantity, double price, double free_cores,
                        double now)
{
    bga_mmsg_t c;
    bga_mmsg_init(&c, type);
    c.job = job;
    c.agent = id;
    c.resource = resource;
    c.good = good;
    c.quantity = quantity;
    c.price = price;
    c.floor[good] = price / 1.2;
    if (resource) {
        c.free_cores = free_cores;
        c.free_memory = 8;
    }
    deliver_from(m, who, &c, now);
}

/* The same, a resource seller saying it has no core left. */
static void answer_from(bgb_market_t *m, uint8_t who, uint32_t id, int resource, uint64_t job,
                        int type, int good, double quantity, double price, double now)
{
    answer_with(m, who, id, resource, job, type, good, quantity, price, 0.0, now);
}

/* Rotation-fit seller `who` answers about its unit of job 1. */
static void answer_as(bgb_market_t *m, uint8_t who, uint32_t id, int type, double price, double now)
{
    answer_from(m, who, id, 0, 1, type, BGB_GOOD_ROTFIT, 5, price, now);
}

static int awarded(const fake_t *f, uint32_t id)
{
    for (int i = 0; i < f->nawards; i++)
        if (f->awards[i].agent == id)
            return 1;
    return 0;
}

static bgb_market_t *market(fake_t *f, bgb_market_config_t *mc)
{
    bgb_market_config_default(mc);
    bgb_market_io_t io = {f, capture};
    bgb_market_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_new(mc, &io, &m, &err), BG_OK);
    return m;
}

/* Posted: the need's two units order from the two cheapest postings, one
 * each; a refusal moves that unit to the next posting (not back to the
 * refuser, not to its mate's seller); both confirmations buy the job at
 * the posted prices. */
static void posted_split_need_and_refusal(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 2), b = seller(m, &f, 'b', 1.5, 2),
                   c = seller(m, &f, 'c', 2.0, 2);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 2};
    bg_error_t err = BG_ERROR_INIT;
    int mark = f.nsent;
    assert_int_equal(bgb_market_buy(m, 1, BGB_MECH_POSTED, 1000, &need, 1, 0.1, on_done, &f, &err),
                     BG_OK);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, a, mark), 1);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, b, mark), 1);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, c, mark), 0);
    assert_true(last_to(&f, BGA_MM_ORDER, a, mark)->price == 1.0);
    assert_true(last_to(&f, BGA_MM_ORDER, b, mark)->price == 1.5);

    mark = f.nsent;
    answer_as(m, 'a', a, BGA_MM_REFUSE, 0, 0.2);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, c, mark), 1);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, a, mark) + count_to(&f, BGA_MM_ORDER, b, mark), 0);
    answer_as(m, 'b', b, BGA_MM_CONFIRM, 1.5, 0.3);
    assert_false(f.done);
    answer_as(m, 'c', c, BGA_MM_CONFIRM, 2.0, 0.3);
    assert_true(f.done);
    assert_string_equal(f.reason, "");
    assert_int_equal(f.nawards, 2);
    assert_true(awarded(&f, b) && awarded(&f, c) && !awarded(&f, a));
    bgb_market_destroy(&m);
}

/* A proposal for round `attempt` of unit `job`'s rotation fit from
 * agent `who` (id `id`). */
static void propose_in(bgb_market_t *m, uint8_t who, uint32_t id, int attempt, double price,
                       double now)
{
    bga_mmsg_t p;
    bga_mmsg_init(&p, BGA_MM_PROPOSE);
    p.job = 1;
    p.agent = id;
    p.good = BGB_GOOD_ROTFIT;
    p.quantity = 5;
    p.price = price;
    p.attempt = attempt;
    deliver_from(m, who, &p, now);
}

/* A round nobody answered doubles the next one's window: two sellers
 * could propose, one does, and the buyer waits out the doubled window
 * for the other before it bargains. */
static void quiet_round_widens_window(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.2, 2);
    (void)seller(m, &f, 'b', 1.3, 2);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(
        bgb_market_buy(m, 1, BGB_MECH_CATALLACTIC, 1000, &need, 1, 0.1, on_done, &f, &err), BG_OK);
    const double w = mc.reply_timeout / 8, round1 = 0.1 + w + 0.01;
    int mark = f.nsent;
    (void)bgb_market_tick(m, round1);
    const bga_mmsg_t *cfp = last_of(&f, BGA_MM_CFP, mark);
    assert_non_null(cfp);
    assert_int_equal(cfp->attempt, 1);
    mark = f.nsent;
    propose_in(m, 'a', a, 1, 1.2, round1 + 0.05);
    (void)bgb_market_tick(m, round1 + w + 0.01);
    assert_null(last_of(&f, BGA_MM_OFFER, mark)); /* b could still propose: the window is open */
    (void)bgb_market_tick(m, round1 + 2 * w + 0.01);
    const bga_mmsg_t *offer = last_of(&f, BGA_MM_OFFER, mark);
    assert_non_null(offer);
    assert_int_equal(offer->agent, a);
    bgb_market_destroy(&m);
}

/* Catallactic: both units of the need hear both sellers' proposals; once
 * both have proposed (every seller that could), at once rather than at
 * the window's end, they bargain with different sellers (the cheapest
 * first), each opening below the proposal; the deliveries buy the job. */
/* Job 1 buys two rotation-fit units of need 10 under catallaxy from
 * sellers a (price 1.2) and b (1.3), two slots each; both are called and
 * propose at t = 0.15, and nobody is offered anything until the second
 * proposal. *mark: the message count before the proposals. */
static bgb_market_t *catallactic_two_proposals(fake_t *f, bgb_market_config_t *mc, uint32_t *a,
                                               uint32_t *b, int *mark)
{
    bgb_market_t *m = market(f, mc);
    *a = seller(m, f, 'a', 1.2, 2);
    *b = seller(m, f, 'b', 1.3, 2);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 2};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(
        bgb_market_buy(m, 1, BGB_MECH_CATALLACTIC, 1000, &need, 1, 0.1, on_done, f, &err), BG_OK);
    assert_true(count_to(f, BGA_MM_CFP, *a, 0) >= 1 && count_to(f, BGA_MM_CFP, *b, 0) >= 1);
    *mark = f->nsent;
    answer_as(m, 'a', *a, BGA_MM_PROPOSE, 1.2, 0.15);
    assert_int_equal(count_to(f, BGA_MM_OFFER, *a, *mark) + count_to(f, BGA_MM_OFFER, *b, *mark), 0);
    answer_as(m, 'b', *b, BGA_MM_PROPOSE, 1.3, 0.15);
    return m;
}

static void catallactic_split_need(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    uint32_t a, b;
    int mark;
    bgb_market_t *m = catallactic_two_proposals(&f, &mc, &a, &b, &mark);
    assert_true(0.15 < 0.1 + mc.reply_timeout / 8); /* well before the window's end */
    assert_int_equal(count_to(&f, BGA_MM_OFFER, a, mark), 1);
    assert_int_equal(count_to(&f, BGA_MM_OFFER, b, mark), 1);
    const double pa = last_to(&f, BGA_MM_OFFER, a, mark)->price,
                 pb = last_to(&f, BGA_MM_OFFER, b, mark)->price;
    assert_true(pa > 0 && pa < 1.2);
    assert_true(pb > 0 && pb < 1.3);
    answer_as(m, 'a', a, BGA_MM_CONFIRM, pa, 0.5);
    answer_as(m, 'b', b, BGA_MM_CONFIRM, pb, 0.5);
    assert_true(f.done);
    assert_string_equal(f.reason, "");
    assert_true(awarded(&f, a) && awarded(&f, b));
    bgb_market_destroy(&m);
}

/* Central: the clearing matches the unit with the cheapest seller; its
 * refusal makes the unit bid again, and the next clearing gives it the
 * other seller, never the refuser. */
static void central_refusal_bids_again(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 1), b = seller(m, &f, 'b', 1.5, 1);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_buy(m, 1, BGB_MECH_CENTRAL, 1000, &need, 1, 0.1, on_done, &f, &err),
                     BG_OK);
    double t = 0.1;
    for (int i = 0; i < 4 && !last_to(&f, BGA_MM_ORDER, a, 0); i++)
        (void)bgb_market_tick(m, t += mc.period);
    assert_non_null(last_to(&f, BGA_MM_ORDER, a, 0));
    assert_int_equal(count_to(&f, BGA_MM_ORDER, b, 0), 0);
    const int mark = f.nsent;
    answer_as(m, 'a', a, BGA_MM_REFUSE, 0, t + 0.01);
    for (int i = 0; i < 4 && !last_to(&f, BGA_MM_ORDER, b, mark); i++)
        (void)bgb_market_tick(m, t += mc.period);
    const bga_mmsg_t *o = last_to(&f, BGA_MM_ORDER, b, mark);
    assert_non_null(o);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, a, mark), 0);
    answer_as(m, 'b', b, BGA_MM_CONFIRM, o->price, t + 0.01);
    assert_true(f.done);
    assert_string_equal(f.reason, "");
    assert_true(awarded(&f, b) && !awarded(&f, a));
    bgb_market_destroy(&m);
}

/* The contract row of job `job` sold by `seller` (NULL: none). */
typedef struct row_find {
    uint64_t job;
    uint32_t seller;
    bgb_contract_t row;
    int found;
} row_find_t;

static void find_row(void *ctx, const bgb_contract_t *row)
{
    row_find_t *r = ctx;
    if (row->job == r->job && row->seller == r->seller && row->layer == 0) {
        r->row = *row;
        r->found = 1;
    }
}

/* A lost seller: its contract is settled for the work delivered (its row
 * keeps that quantity and ends at the loss, the rest of the job stays),
 * and the service is bought again from anyone else, under each mechanism:
 * the lost agent, though alive and cheapest, is never asked again (posted
 * and central do not order from it, a catallactic job turns its proposal
 * down), not even once it has been dropped and registered again under a
 * new id (its endpoint, from a new socket). */
static void lost_seller_settled_and_left_out(void **state)
{
    (void)state;
    for (int mech = BGB_MECH_CENTRAL; mech <= BGB_MECH_POSTED; mech++) {
        fake_t f = {0};
        bgb_market_config_t mc;
        bgb_market_t *m = market(&f, &mc);
        const uint32_t a = seller_of(m, &f, 'a', BGB_GOOD_SOLVE, 1.0, 2),
                       b = seller_of(m, &f, 'b', BGB_GOOD_SOLVE, 1.5, 2);
        const bgb_need_t need = {BGB_GOOD_SOLVE, 1.0, 1};
        bg_error_t err = BG_ERROR_INIT;
        double t = 0.1;
        /* The job buys from a (posted: the cheapest; central, catallactic:
         * a alone answers). */
        assert_int_equal(bgb_market_buy(m, 1, (bgb_mechanism)mech, 100, &need, 1, t, on_done, &f,
                                        &err),
                         BG_OK);
        if (mech == BGB_MECH_CATALLACTIC) {
            answer_from(m, 'a', a, 0, 1, BGA_MM_PROPOSE, BGB_GOOD_SOLVE, 1, 1.0, t + 0.05);
            (void)bgb_market_tick(m, t += mc.reply_timeout / 8 + 0.01);
            const bga_mmsg_t *o = last_to(&f, BGA_MM_OFFER, a, 0);
            assert_non_null(o);
            answer_from(m, 'a', a, 0, 1, BGA_MM_CONFIRM, BGB_GOOD_SOLVE, 1, o->price, t + 0.01);
        } else {
            for (int i = 0; i < 10 && !last_to(&f, BGA_MM_ORDER, a, 0); i++)
                (void)bgb_market_tick(m, t += mc.period);
            const bga_mmsg_t *o = last_to(&f, BGA_MM_ORDER, a, 0);
            assert_non_null(o);
            answer_from(m, 'a', a, 0, 1, BGA_MM_CONFIRM, BGB_GOOD_SOLVE, 1, o->price, t + 0.01);
        }
        assert_true(f.done);
        assert_string_equal(f.reason, "");
        assert_true(awarded(&f, a));
        const double price = f.awards[0].price;

        /* a is lost at t + 1 having delivered a quarter of the work. */
        const int mark = f.nsent;
        const double paid = bgb_market_settle_lost(m, 1, a, BGB_GOOD_SOLVE, 0.25, t + 1);
        assert_true(fabs(paid - 0.25 * price) <= 1e-12 * price);
        assert_non_null(last_to(&f, BGA_MM_RELEASE, a, mark));
        row_find_t rf = {1, a, {0}, 0};
        bgb_ledger_each(bgb_market_ledger(m), find_row, &rf);
        assert_true(rf.found);
        assert_true(rf.row.quantity == 0.25 && rf.row.end == t + 1);
        assert_true(bgb_market_settle_lost(m, 1, a, BGB_GOOD_SOLVE, 0.25, t + 1) < 0);

        /* a comes back: dropped (silent past the heartbeat timeout, b
         * still beating) and registered again from a new socket, at its
         * endpoint. */
        bga_mmsg_t hb;
        bga_mmsg_init(&hb, BGA_MM_HEARTBEAT);
        hb.agent = b;
        hb.services = 1u << BGB_GOOD_SOLVE;
        hb.slots = hb.free_slots = 2;
        hb.prices[BGB_GOOD_SOLVE] = 1.5;
        hb.floor[BGB_GOOD_SOLVE] = 1.5 / 1.2;
        t += mc.heartbeat_timeout + 0.5;
        deliver_from(m, 'b', &hb, t);
        (void)bgb_market_tick(m, t);
        bga_mmsg_t reg;
        bga_mmsg_init(&reg, BGA_MM_REGISTER);
        snprintf(reg.name, sizeof reg.name, "sa");
        snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://127.0.0.1:%d", 9000 + 'a');
        reg.services = 1u << BGB_GOOD_SOLVE;
        reg.slots = reg.free_slots = 2;
        reg.floor[BGB_GOOD_SOLVE] = 1.0 / 1.2;
        reg.prices[BGB_GOOD_SOLVE] = 1.0;
        reg.margin = 0.2;
        const int mark1 = f.nsent;
        deliver_from(m, 'A', &reg, t);
        const bga_mmsg_t *back = last_of(&f, BGA_MM_REGISTERED, mark1);
        assert_non_null(back);
        const uint32_t a2 = back->agent;
        assert_int_not_equal(a2, a);
        /* The rest, bought again without a: from b. */
        memset(&f.awards, 0, sizeof f.awards);
        f.done = 0;
        const bgb_need_t rest = {BGB_GOOD_SOLVE, 0.75, 1};
        t += 0.1;
        const int mark2 = f.nsent;
        assert_int_equal(bgb_market_buy_excluding(m, 2, (bgb_mechanism)mech, 100, &rest, 1, &a, 1,
                                                  t, on_done, &f, &err),
                         BG_OK);
        assert_false(f.done);
        if (mech == BGB_MECH_CATALLACTIC) {
            answer_from(m, 'A', a2, 0, 2, BGA_MM_PROPOSE, BGB_GOOD_SOLVE, 0.75, 1.0, t + 0.05);
            answer_from(m, 'b', b, 0, 2, BGA_MM_PROPOSE, BGB_GOOD_SOLVE, 0.75, 1.5, t + 0.05);
            (void)bgb_market_tick(m, t += mc.reply_timeout / 8 + 0.01);
        } else {
            for (int i = 0; i < 10 && !last_to(&f, BGA_MM_ORDER, b, mark2); i++)
                (void)bgb_market_tick(m, t += mc.period);
        }
        assert_int_equal(count_to(&f, BGA_MM_ORDER, a2, mark2) +
                             count_to(&f, BGA_MM_OFFER, a2, mark2),
                         0);
        const bga_mmsg_t *o = mech == BGB_MECH_CATALLACTIC ? last_to(&f, BGA_MM_OFFER, b, mark2)
                                                           : last_to(&f, BGA_MM_ORDER, b, mark2);
        assert_non_null(o);
        answer_from(m, 'b', b, 0, 2, BGA_MM_CONFIRM, BGB_GOOD_SOLVE, 0.75, o->price, t + 0.01);
        assert_true(f.done);
        assert_string_equal(f.reason, "");
        assert_true(awarded(&f, b) && !awarded(&f, a) && !awarded(&f, a2));
        assert_true(f.awards[0].quantity == 0.75);
        bgb_market_destroy(&m);
    }
}

/* ------------------------------------------- resource sub-jobs (layer 1) */

/* The resource role of fake daemon `who` on host `host` registers at
 * `now`: `cores` cores and 8 GiB, asking `ask` per core-second and
 * ask / 10 per GiB-second; the REGISTERED it gets back. */
static const bga_mmsg_t *register_resource(bgb_market_t *m, fake_t *f, uint8_t who,
                                           const char *host, double ask, double cores, double now)
{
    bga_mmsg_t reg;
    bga_mmsg_init(&reg, BGA_MM_REGISTER);
    snprintf(reg.name, sizeof reg.name, "s%c", who);
    snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://%s:%d", host, 9000 + who);
    reg.resource = 1;
    reg.cores = reg.free_cores = cores;
    reg.memory = reg.free_memory = 8;
    reg.floor[BGB_GOOD_CORES] = ask / 1.2;
    reg.prices[BGB_GOOD_CORES] = ask;
    reg.floor[BGB_GOOD_MEMORY] = ask / 12;
    reg.prices[BGB_GOOD_MEMORY] = ask / 10;
    reg.margin = 0.2;
    const int mark = f->nsent;
    deliver_from(m, who, &reg, now);
    const bga_mmsg_t *r = last_of(f, BGA_MM_REGISTERED, mark);
    assert_non_null(r);
    assert_int_equal(r->resource, 1);
    return r;
}

/* The resource role of fake daemon `who`, on the service sellers' host;
 * its id. */
static uint32_t rseller(bgb_market_t *m, fake_t *f, uint8_t who, double ask, double cores)
{
    return register_resource(m, f, who, "127.0.0.1", ask, cores, 0.0)->agent;
}

/* Basic seller `who` (id `id`) agreed to its unit of `good` for `job` and
 * asks for `cores` cores and `gib` GiB for 10 s, at most `money`. */
static void rbuy(bgb_market_t *m, uint8_t who, uint32_t id, uint64_t job, int good, double cores,
                 double gib, double money, double now)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_RBUY);
    r.job = job;
    r.agent = id;
    r.good = good;
    r.cores = cores;
    r.memory = gib;
    r.term = 10;
    r.price = money;
    deliver_from(m, who, &r, now);
}

/* Posted: a basic seller's resources are ordered from its host's
 * postings, cores and memory each at the posted rate for the lease; both
 * confirmations answer the basic seller RBOUGHT with the money paid. */
static void posted_subjob(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 2), ra = rseller(m, &f, 'a', 1e-3, 4);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_buy(m, 1, BGB_MECH_POSTED, 1000, &need, 1, 0.1, on_done, &f, &err),
                     BG_OK);
    assert_non_null(last_to(&f, BGA_MM_ORDER, a, 0));
    int mark = f.nsent;
    rbuy(m, 'a', a, 1, BGB_GOOD_ROTFIT, 1, 2, 1.0, 0.2);
    const bga_mmsg_t *oc = NULL, *om = NULL;
    for (int i = mark; i < f.nsent; i++)
        if (f.sent[i].type == BGA_MM_ORDER && f.sent[i].agent == ra) {
            if (f.sent[i].good == BGB_GOOD_CORES)
                oc = &f.sent[i];
            else if (f.sent[i].good == BGB_GOOD_MEMORY)
                om = &f.sent[i];
        }
    assert_non_null(oc);
    assert_non_null(om);
    assert_true(oc->price == 1e-3 && oc->quantity == 1 && oc->term == 10);
    assert_true(om->price == 1e-4 && om->quantity == 2 && om->term == 10);
    const uint64_t sub = oc->job;
    assert_true(sub != 1 && om->job == sub);
    mark = f.nsent;
    answer_from(m, 'a', ra, 1, sub, BGA_MM_CONFIRM, BGB_GOOD_CORES, 1, 1e-3, 0.3);
    assert_null(last_to(&f, BGA_MM_RBOUGHT, a, mark));
    answer_from(m, 'a', ra, 1, sub, BGA_MM_CONFIRM, BGB_GOOD_MEMORY, 2, 1e-4, 0.3);
    const bga_mmsg_t *b = last_to(&f, BGA_MM_RBOUGHT, a, mark);
    assert_non_null(b);
    assert_true(b->cores == 1 && b->memory == 2);
    assert_true(fabs(b->price - (1 * 10 * 1e-3 + 2 * 10 * 1e-4)) < 1e-15);
    bgb_market_destroy(&m);
}

/* A seller that agreed and then left the market (dropped for silence: it
 * was killed) before the job's last agreement has nothing to compute on:
 * the job gets no award naming it (the soak saw a contract with an empty
 * endpoint, and a job failed connecting to it) but "no seller", which the
 * coordinator takes as a reason to ask again; nothing is logged. */
static void seller_gone_before_the_last_deal(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    uint32_t a, b;
    int mark;
    bgb_market_t *m = catallactic_two_proposals(&f, &mc, &a, &b, &mark);
    const bga_mmsg_t *oa = last_to(&f, BGA_MM_OFFER, a, mark),
                     *ob = last_to(&f, BGA_MM_OFFER, b, mark);
    assert_non_null(oa);
    assert_non_null(ob);
    answer_as(m, 'a', a, BGA_MM_CONFIRM, oa->price, 0.5);
    assert_false(f.done);
    /* b lets its offer lapse; a falls silent past the heartbeat timeout
     * while b keeps beating, then b answers the job's next call and
     * confirms. */
    bga_mmsg_t hb;
    bga_mmsg_init(&hb, BGA_MM_HEARTBEAT);
    hb.agent = b;
    hb.services = 1u << BGB_GOOD_ROTFIT;
    hb.slots = hb.free_slots = 2;
    hb.prices[BGB_GOOD_ROTFIT] = 1.3;
    hb.floor[BGB_GOOD_ROTFIT] = 1.3 / 1.2;
    double t = 0.5;
    int answered = f.nsent;
    for (int i = 0; i < 200 && !f.done; i++) {
        t += 0.1;
        if (i % 10 == 0)
            deliver_from(m, 'b', &hb, t);
        (void)bgb_market_tick(m, t);
        if (t < 0.5 + mc.heartbeat_timeout + 0.5)
            continue;
        const int from = answered;
        answered = f.nsent;
        const bga_mmsg_t *o = last_to(&f, BGA_MM_OFFER, b, from),
                         *c = last_to(&f, BGA_MM_CFP, b, from);
        if (o) {
            answer_as(m, 'b', b, BGA_MM_CONFIRM, o->price, t + 0.01);
        } else if (c) { /* a proposal in the call's round */
            bga_mmsg_t p;
            bga_mmsg_init(&p, BGA_MM_PROPOSE);
            p.job = 1;
            p.agent = b;
            p.good = BGB_GOOD_ROTFIT;
            p.quantity = 5;
            p.price = 1.3;
            p.floor[BGB_GOOD_ROTFIT] = 1.3 / 1.2;
            p.attempt = c->attempt;
            deliver_from(m, 'b', &p, t + 0.01);
        }
    }
    assert_true(f.done);
    print_message("reason \"%s\", %d awards, %d messages\n", f.reason, f.nawards, f.nsent);
    assert_non_null(strstr(f.reason, "no seller"));
    assert_int_equal(f.nawards, 0);
    row_find_t rf = {.job = 1, .seller = b};
    bgb_ledger_each(bgb_market_ledger(m), find_row, &rf);
    assert_false(rf.found);
    bgb_market_destroy(&m);
}

/* Catallactic: a basic seller's sub-job calls its host's one resource
 * seller (the call naming the job and service the cores serve), and
 * bargains as soon as that seller has proposed: nobody else can answer, so
 * it does not wait out the discovery window. */
static void catallactic_subjob_bargains_when_heard(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 2), ra = rseller(m, &f, 'a', 1e-3, 2);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(
        bgb_market_buy(m, 1, BGB_MECH_CATALLACTIC, 1000, &need, 1, 0.1, on_done, &f, &err), BG_OK);
    answer_as(m, 'a', a, BGA_MM_PROPOSE, 1.0, 0.15);
    const double t = 0.1 + mc.reply_timeout / 8 + 0.01;
    (void)bgb_market_tick(m, t);
    assert_non_null(last_to(&f, BGA_MM_OFFER, a, 0));
    int mark = f.nsent;
    rbuy(m, 'a', a, 1, BGB_GOOD_ROTFIT, 1, 0, 1.0, t + 0.01);
    const bga_mmsg_t *c = last_to(&f, BGA_MM_CFP, ra, mark);
    assert_non_null(c);
    assert_true(c->good == BGB_GOOD_CORES && c->parent == 1 && c->serves == BGB_GOOD_ROTFIT);
    const uint64_t sub = c->job;
    mark = f.nsent;
    answer_from(m, 'a', ra, 1, sub, BGA_MM_PROPOSE, BGB_GOOD_CORES, 1, 1e-3, t + 0.02);
    const bga_mmsg_t *o = last_to(&f, BGA_MM_OFFER, ra, mark);
    assert_non_null(o);
    assert_true(o->job == sub && o->price > 0 && o->price < 1e-3);
    assert_true(o->parent == 1 && o->serves == BGB_GOOD_ROTFIT);
    bgb_market_destroy(&m);
}

static int resource_sellers(const bgb_market_t *m)
{
    bgb_agent_info_t info[16];
    const size_t n = bgb_directory_agents(bgb_market_directory(m), info, 16);
    int k = 0;
    for (size_t i = 0; i < n && i < 16; i++)
        k += info[i].resource;
    return k;
}

/* A host's cores and memory have one seller: the first daemon of a host
 * to register its resource role gets an id; another daemon of the same
 * host is answered with no id and a reason naming the first, and is not
 * in the directory; a daemon of another host sells its own. Once the
 * first goes silent past the heartbeat timeout and is dropped, the
 * waiting daemon's next registration takes the host over. */
static void one_resource_seller_per_host(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t first = register_resource(m, &f, 'a', "127.0.0.1", 1e-3, 4, 0.0)->agent;
    assert_true(first > 0);
    const bga_mmsg_t *r = register_resource(m, &f, 'b', "127.0.0.1", 1e-3, 4, 0.1);
    assert_int_equal(r->agent, 0);
    char want[64];
    snprintf(want, sizeof want, "agent %u (sa)", first);
    assert_non_null(strstr(r->reason, want));
    assert_non_null(strstr(r->reason, "127.0.0.1"));
    assert_int_equal(resource_sellers(m), 1);
    /* The first one registering again keeps its id. */
    assert_int_equal(register_resource(m, &f, 'a', "127.0.0.1", 1e-3, 4, 0.2)->agent, first);
    const uint32_t other = register_resource(m, &f, 'c', "127.0.0.2", 1e-3, 4, 0.3)->agent;
    assert_true(other > 0 && other != first);
    assert_int_equal(resource_sellers(m), 2);
    /* 'a' falls silent; 'c' keeps beating. */
    bga_mmsg_t hb;
    bga_mmsg_init(&hb, BGA_MM_HEARTBEAT);
    hb.agent = other;
    hb.resource = 1;
    hb.cores = hb.free_cores = 4;
    hb.memory = hb.free_memory = 8;
    const double later = 0.2 + mc.heartbeat_timeout + 0.5;
    deliver_from(m, 'c', &hb, later - 0.1);
    (void)bgb_market_tick(m, later);
    assert_int_equal(resource_sellers(m), 1);
    /* Dropped from the directory, 'a' stays in agents.csv: its contracts
     * stay in the log, and the audit needs the seller of each. */
    char *csv = NULL;
    size_t csv_size = 0;
    FILE *out = open_memstream(&csv, &csv_size);
    bg_error_t err = BG_ERROR_INIT;
    assert_non_null(out);
    assert_int_equal(bgb_ledger_write_agents_csv(bgb_market_ledger(m), bgb_market_directory(m), out, &err), BG_OK);
    fclose(out);
    char row[64];
    snprintf(row, sizeof row, ",central,%u,resource,cores,", first);
    if (!strstr(csv, row))
        fail_msg("agents.csv lacks the dropped seller %u:\n%s", first, csv);
    free(csv);
    const uint32_t next = register_resource(m, &f, 'b', "127.0.0.1", 1e-3, 4, later + 0.1)->agent;
    assert_true(next > 0 && next != first && next != other);
    assert_int_equal(resource_sellers(m), 2);
    bgb_market_destroy(&m);
}

/* The host's resource seller `rid` confirms what it was last ordered since
 * `from` (cores, then memory), saying it has `free_cores` left. */
static void confirm_orders(bgb_market_t *m, fake_t *f, uint32_t rid, int from, double free_cores,
                           double now)
{
    const bga_mmsg_t *oc = NULL, *om = NULL;
    for (int i = from; i < f->nsent; i++)
        if (f->sent[i].type == BGA_MM_ORDER && f->sent[i].agent == rid)
            *(f->sent[i].good == BGB_GOOD_CORES ? &oc : &om) = &f->sent[i];
    assert_non_null(oc);
    assert_non_null(om);
    for (int g = 0; g < 2; g++) {
        const bga_mmsg_t o = g ? *om : *oc;
        answer_with(m, 'r', rid, 1, o.job, BGA_MM_CONFIRM, o.good, o.quantity, o.price, free_cores,
                    now);
    }
}

/* A job's services run one after another, so the host's seller counts the
 * job's cores once, as its widest phase's. On a 2-core host a job's two
 * rotation-fit units (one core each, bought first) leave no core free, and
 * yet its sparse solve's two cores are ordered: they add nothing to the
 * job's widest phase. Every resource order names the job and the service
 * it serves. Another job's rotation fit then finds no free core on the
 * host and its basic seller is told so. */
static void subjobs_share_the_jobs_cores(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 2), b = seller(m, &f, 'b', 1.0, 2);
    const uint32_t c = seller_of(m, &f, 'c', BGB_GOOD_SOLVE, 1.2, 2);
    const uint32_t host = rseller(m, &f, 'r', 1e-3, 2);
    int mark;

    const bgb_need_t needs[2] = {{BGB_GOOD_ROTFIT, 10.0, 2}, {BGB_GOOD_SOLVE, 1.0, 1}};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_buy(m, 1, BGB_MECH_POSTED, 1000, needs, 2, 0.1, on_done, &f, &err),
                     BG_OK);
    assert_non_null(last_to(&f, BGA_MM_ORDER, a, 0));
    assert_non_null(last_to(&f, BGA_MM_ORDER, b, 0));
    assert_non_null(last_to(&f, BGA_MM_ORDER, c, 0));
    mark = f.nsent;
    rbuy(m, 'a', a, 1, BGB_GOOD_ROTFIT, 1, 1, 1.0, 0.2);
    const bga_mmsg_t *o = last_to(&f, BGA_MM_ORDER, host, mark);
    assert_non_null(o);
    assert_true(o->parent == 1 && o->serves == BGB_GOOD_ROTFIT);
    confirm_orders(m, &f, host, mark, 1, 0.25);
    mark = f.nsent;
    rbuy(m, 'b', b, 1, BGB_GOOD_ROTFIT, 1, 1, 1.0, 0.3);
    confirm_orders(m, &f, host, mark, 0, 0.35);
    mark = f.nsent;
    rbuy(m, 'c', c, 1, BGB_GOOD_SOLVE, 2, 1, 1.0, 0.4);
    o = NULL;
    for (int i = mark; i < f.nsent; i++)
        if (f.sent[i].type == BGA_MM_ORDER && f.sent[i].agent == host &&
            f.sent[i].good == BGB_GOOD_CORES)
            o = &f.sent[i];
    assert_non_null(o);
    assert_true(o->quantity == 2 && o->parent == 1 && o->serves == BGB_GOOD_SOLVE);
    assert_null(last_to(&f, BGA_MM_RFAIL, c, mark));
    confirm_orders(m, &f, host, mark, 0, 0.45);
    assert_non_null(last_to(&f, BGA_MM_RBOUGHT, c, mark));

    /* Job 2's rotation fit: the host has no core left for another job. */
    fake_t g = {0};
    const bgb_need_t one = {BGB_GOOD_ROTFIT, 10.0, 1};
    assert_int_equal(bgb_market_buy(m, 2, BGB_MECH_POSTED, 1000, &one, 1, 0.5, on_done, &g, &err),
                     BG_OK);
    const bga_mmsg_t *o2 = NULL;
    for (int i = mark; i < f.nsent; i++)
        if (f.sent[i].type == BGA_MM_ORDER && f.sent[i].job == 2)
            o2 = &f.sent[i];
    assert_non_null(o2);
    const uint32_t s2 = o2->agent;
    mark = f.nsent;
    rbuy(m, s2 == a ? 'a' : 'b', s2, 2, BGB_GOOD_ROTFIT, 1, 1, 1.0, 0.6);
    for (int i = mark; i < f.nsent; i++)
        assert_false(f.sent[i].type == BGA_MM_ORDER && f.sent[i].agent == host &&
                     f.sent[i].good == BGB_GOOD_CORES);
    const bga_mmsg_t *no = last_to(&f, BGA_MM_RFAIL, s2, mark);
    assert_non_null(no);
    assert_non_null(strstr(no->reason, "no free cores"));
    bgb_market_destroy(&m);
}

/* Central: every waiting job that fits on the sellers' free slots enters
 * the book before the clearing (not one job a clearing): three one-unit
 * jobs against three free slots are all ordered at the first clearing. */
static void central_admits_every_fitting_job(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller(m, &f, 'a', 1.0, 2), b = seller(m, &f, 'b', 1.1, 1);
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 1};
    bg_error_t err = BG_ERROR_INIT;
    fake_t done[3];
    memset(done, 0, sizeof done);
    for (uint64_t j = 1; j <= 3; j++)
        assert_int_equal(bgb_market_buy(m, j, BGB_MECH_CENTRAL, 1000, &need, 1, 0.1, on_done,
                                        &done[j - 1], &err),
                         BG_OK);
    double t = 0.1;
    for (int i = 0;
         i < 8 && count_to(&f, BGA_MM_ORDER, a, 0) + count_to(&f, BGA_MM_ORDER, b, 0) == 0; i++)
        (void)bgb_market_tick(m, t += mc.period);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, a, 0), 2);
    assert_int_equal(count_to(&f, BGA_MM_ORDER, b, 0), 1);
    int jobs = 0;
    for (int i = 0; i < f.nsent; i++)
        if (f.sent[i].type == BGA_MM_ORDER)
            jobs |= 1 << (int)f.sent[i].job;
    assert_int_equal(jobs, 2 | 4 | 8);
    bgb_market_destroy(&m);
}

/* A rotation-fit seller of daemon `who` on `host`, 2 slots, asking 1; its id. */
static uint32_t seller_on(bgb_market_t *m, fake_t *f, uint8_t who, const char *host)
{
    bga_mmsg_t reg;
    bga_mmsg_init(&reg, BGA_MM_REGISTER);
    snprintf(reg.name, sizeof reg.name, "s%c", who);
    snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://%s:%d", host, 9000 + who);
    reg.services = 1u << BGB_GOOD_ROTFIT;
    reg.slots = reg.free_slots = 2;
    reg.floor[BGB_GOOD_ROTFIT] = 1.0 / 1.2;
    reg.prices[BGB_GOOD_ROTFIT] = 1.0;
    reg.margin = 0.2;
    const int mark = f->nsent;
    deliver_from(m, who, &reg, 0.0);
    const bga_mmsg_t *r = last_of(f, BGA_MM_REGISTERED, mark);
    assert_non_null(r);
    return r->agent;
}

/* The cores ORDER to `to` since `from`, NULL when none. */
static const bga_mmsg_t *cores_order(const fake_t *f, uint32_t to, int from)
{
    for (int i = f->nsent - 1; i >= from; i--)
        if (f->sent[i].type == BGA_MM_ORDER && f->sent[i].agent == to &&
            f->sent[i].good == BGB_GOOD_CORES)
            return &f->sent[i];
    return NULL;
}

/* Central resources clear per host: two basic sellers on two hosts each
 * ask for cores in the same period; both sub-jobs are ordered from their
 * own host's seller at the same clearing. In one book for every host the
 * higher bid (host 2's) met the cheaper ask (host 1's seller) and the
 * lower bid the dearer ask: both fills crossed hosts and were dropped. */
static void central_resources_cleared_per_host(void **state)
{
    (void)state;
    fake_t f = {0};
    bgb_market_config_t mc;
    bgb_market_t *m = market(&f, &mc);
    const uint32_t a = seller_on(m, &f, 'a', "127.0.0.1"), x = seller_on(m, &f, 'x', "127.0.0.2");
    const uint32_t ra = register_resource(m, &f, 'a', "127.0.0.1", 1e-3, 8, 0.0)->agent;
    const uint32_t rx = register_resource(m, &f, 'x', "127.0.0.2", 2e-3, 8, 0.0)->agent;
    const bgb_need_t need = {BGB_GOOD_ROTFIT, 10.0, 2};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_market_buy(m, 1, BGB_MECH_CENTRAL, 1000, &need, 1, 0.1, on_done, &f, &err),
                     BG_OK);
    double t = 0.1;
    for (int i = 0; i < 8 && !(last_to(&f, BGA_MM_ORDER, a, 0) && last_to(&f, BGA_MM_ORDER, x, 0));
         i++)
        (void)bgb_market_tick(m, t += mc.period);
    assert_non_null(last_to(&f, BGA_MM_ORDER, a, 0));
    assert_non_null(last_to(&f, BGA_MM_ORDER, x, 0));
    const int mark = f.nsent;
    rbuy(m, 'a', a, 1, BGB_GOOD_ROTFIT, 1, 1, 1.0, t + 0.01);
    rbuy(m, 'x', x, 1, BGB_GOOD_ROTFIT, 1, 1, 2.0, t + 0.01);
    for (int i = 0; i < 8 && !cores_order(&f, ra, mark) && !cores_order(&f, rx, mark); i++)
        (void)bgb_market_tick(m, t += mc.period);
    const bga_mmsg_t *oa = cores_order(&f, ra, mark), *ox = cores_order(&f, rx, mark);
    assert_non_null(oa);
    assert_non_null(ox);
    assert_true(oa->job != ox->job && oa->parent == 1 && ox->parent == 1);
    assert_true(oa->price >= 1e-3 && ox->price >= 2e-3);
    bgb_market_destroy(&m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(stale_proposal_is_not_counted),
                                       cmocka_unit_test(posted_split_need_and_refusal),
                                       cmocka_unit_test(catallactic_split_need),
                                       cmocka_unit_test(seller_gone_before_the_last_deal),
                                       cmocka_unit_test(quiet_round_widens_window),
                                       cmocka_unit_test(central_refusal_bids_again),
                                       cmocka_unit_test(lost_seller_settled_and_left_out),
                                       cmocka_unit_test(posted_subjob),
                                       cmocka_unit_test(catallactic_subjob_bargains_when_heard),
                                       cmocka_unit_test(one_resource_seller_per_host),
                                       cmocka_unit_test(subjobs_share_the_jobs_cores),
                                       cmocka_unit_test(central_admits_every_fitting_job),
                                       cmocka_unit_test(central_resources_cleared_per_host)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
