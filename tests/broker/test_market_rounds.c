/* bgb_market, catallactic discovery, on a virtual clock with a fake agent
 * (no sockets): a proposal counts only in the round whose call it
 * answers. A late one from an earlier round leaves the round unanswered,
 * so the next round's window widens, and the buyer never bargains on it;
 * a proposal for the current round is taken up with an OFFER. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
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

    /* The round heard nothing: its window is twice as long. An answer to
     * it (attempt 1) is bargained on once the window closes. */
    const double round1 = 1.0 + mc.reply_timeout / 8 + 0.01;
    p.attempt = 1;
    deliver(m, &p, round1 + 0.1);
    const int mark2 = f.nsent;
    (void)bgb_market_tick(m, round1 + mc.reply_timeout / 8 + 0.01);
    assert_null(last_of(&f, BGA_MM_OFFER, mark2)); /* the wider window is still open */
    (void)bgb_market_tick(m, round1 + 2 * mc.reply_timeout / 8 + 0.01);
    const bga_mmsg_t *offer = last_of(&f, BGA_MM_OFFER, mark2);
    assert_non_null(offer);
    assert_int_equal(offer->agent, id);
    assert_true(offer->price > 0 && offer->price <= 1.2);
    bgb_market_destroy(&m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(stale_proposal_is_not_counted)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
