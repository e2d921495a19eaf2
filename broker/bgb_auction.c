#include "bgb_auction.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_config.h"
#include "bgm_market_agent.h"
#include "bgm_outbox.h"
#include "bgm_role.h"

/* Machine ids: the market agent 0, sellers from 1, buyers after them. */
#define SELF 0u
#define FIRST_SELLER 1u
#define FIRST_BUYER (FIRST_SELLER + BGB_AUCTION_MAX_SELLERS)
/* What one call may emit: a clearing matches at most every bid placed
 * (two messages each) plus its timer. */
#define OUTBOX_CAP (4u * BGB_AUCTION_MAX_BUYERS * 64u + 16u)
_Static_assert(BGB_AUCTION_MAX_CLEARINGS == BGM_MA_CLEARINGS_MAX,
               "the machine records the clearings a tick names");
_Static_assert(BGB_AUCTION_MAX_EXCLUDE <= BGM_MSG_CANDIDATES &&
                   BGB_AUCTION_MAX_LIST == BGM_MSG_CANDIDATES,
               "exclusions and lists travel in a message's candidates");

struct bgb_auction {
    bgm_config_t cfg;
    bgm_market_agent_t *central, *directory;
    bgm_outbox_t *out;   /* what a message delivered emits */
    bgm_outbox_t *clear; /* what a clearing emits: read while the caller's
                          * match callbacks deliver messages into out */
    double next_clear;
    unsigned goods[BGB_AUCTION_MAX_SELLERS]; /* what each seller was last said to sell */
    bgb_auction_clearing_t clearings[BGB_AUCTION_MAX_CLEARINGS]; /* the tick under way's */
};

static void config_for(bgm_config_t *cfg, double k, double period)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->central.k = k;
    cfg->central.period = period;
    /* The resource books stay empty (bgb_market trades layer 1 itself);
     * call markets are the mode that needs nothing else configured. */
    cfg->central.resource_market = BGM_RM_CALL;
    cfg->network.speed = 1.0;
    cfg->baseline.candidates = BGM_MSG_CANDIDATES;
}

static bgm_market_agent_t *machine(const bgm_config_t *cfg, int mechanism)
{
    bgm_market_agent_params_t p = {.cfg = cfg,
                                   .mechanism = mechanism,
                                   .self = SELF,
                                   .first_basic = FIRST_SELLER,
                                   .nbasic = BGB_AUCTION_MAX_SELLERS,
                                   .first_resource = FIRST_BUYER + BGB_AUCTION_MAX_BUYERS,
                                   .nresource = 0,
                                   .horizon = INFINITY};
    return bgm_market_agent_new(&p);
}

bg_status bgb_auction_new(double k, double period, double now, bgb_auction_t **out,
                          bg_error_t *err)
{
    *out = NULL;
    if (!(k >= 0 && k <= 1) || !(period > 0 && isfinite(period)))
        return bg_error_set(err, BG_ERR_INVALID, "auction: k in [0, 1] and period > 0");
    bgb_auction_t *a = calloc(1, sizeof *a);
    if (!a)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the auction");
    config_for(&a->cfg, k, period);
    a->central = machine(&a->cfg, BGM_MECH_CENTRAL);
    a->directory = machine(&a->cfg, BGM_MECH_BASELINE);
    a->out = bgm_outbox_new(OUTBOX_CAP);
    a->clear = bgm_outbox_new(OUTBOX_CAP);
    if (!a->central || !a->directory || !a->out || !a->clear) {
        bgb_auction_destroy(&a);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the auction");
    }
    a->next_clear = now + period;
    *out = a;
    return BG_OK;
}

void bgb_auction_destroy(bgb_auction_t **pa)
{
    if (!pa || !*pa)
        return;
    bgb_auction_t *a = *pa;
    bgm_market_agent_destroy(&a->central);
    bgm_market_agent_destroy(&a->directory);
    bgm_outbox_destroy(&a->out);
    bgm_outbox_destroy(&a->clear);
    free(a);
    *pa = NULL;
}

/* One message to one machine; what it emits is left in the outbox. */
static bg_status deliver(bgb_auction_t *a, bgm_market_agent_t *ma, const bgm_msg_t *m, double now,
                         bg_error_t *err)
{
    bgm_outbox_clear(a->out);
    bg_status st = bgm_market_agent_on_message(ma, m, now, a->out);
    if (st != BG_OK)
        return bg_error_set(err, st, "auction: the market agent refused message %u (%s)",
                            (unsigned)m->type, st == BG_ERR_LIMIT ? "book full" : "invalid");
    return BG_OK;
}

bg_status bgb_auction_seller(bgb_auction_t *a, int slot, unsigned goods,
                             const double price[BGB_AUCTION_SERVICES], double free_slots,
                             bg_error_t *err)
{
    if (slot < 0 || slot >= BGB_AUCTION_MAX_SELLERS)
        return bg_error_set(err, BG_ERR_INVALID, "auction: seller slot %d out of range", slot);
    const uint32_t id = FIRST_SELLER + (uint32_t)slot;
    /* A seller's goods can change when it registers again: it starts
     * clean then. Otherwise its asks are re-priced in place, which keeps
     * its postings where first fit finds them. */
    if (a->goods[slot] != goods) {
        bgm_market_agent_forget_seller(a->central, id);
        bgm_market_agent_forget_seller(a->directory, id);
        a->goods[slot] = goods;
    }
    for (int g = 0; g < BGB_AUCTION_SERVICES; g++) {
        if (!(goods & (1u << g)))
            continue;
        bgm_msg_t m = bgm_outbox_msg(BGM_MT_ASK, id, SELF, 0, 0);
        m.good = (int16_t)g;
        m.price = price[g];
        m.a = free_slots > 0 ? free_slots : 0;
        bg_status st = deliver(a, a->central, &m, 0, err);
        if (st == BG_OK)
            st = deliver(a, a->directory, &m, 0, err);
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

void bgb_auction_forget_seller(bgb_auction_t *a, int slot)
{
    if (slot < 0 || slot >= BGB_AUCTION_MAX_SELLERS)
        return;
    bgm_market_agent_forget_seller(a->central, FIRST_SELLER + (uint32_t)slot);
    bgm_market_agent_forget_seller(a->directory, FIRST_SELLER + (uint32_t)slot);
    a->goods[slot] = 0;
}

static bg_status put_exclusions(bgm_msg_t *m, const int *exclude, int n, bg_error_t *err)
{
    if (n < 0 || n > BGB_AUCTION_MAX_EXCLUDE)
        return bg_error_set(err, BG_ERR_INVALID, "auction: %d exclusions (at most %d)", n,
                            BGB_AUCTION_MAX_EXCLUDE);
    for (int i = 0; i < n; i++) {
        if (exclude[i] < 0 || exclude[i] >= BGB_AUCTION_MAX_SELLERS)
            return bg_error_set(err, BG_ERR_INVALID, "auction: excluded slot %d out of range",
                                exclude[i]);
        m->cand[i] = FIRST_SELLER + (uint32_t)exclude[i];
    }
    m->ncand = (uint16_t)n;
    return BG_OK;
}

bg_status bgb_auction_bid(bgb_auction_t *a, uint32_t buyer, uint32_t req, uint32_t attempt,
                          int good, double limit, double work, double deadline, uint32_t group,
                          const int *exclude, int nexclude, double now, bg_error_t *err)
{
    if (buyer >= BGB_AUCTION_MAX_BUYERS || good < 0 || good >= BGB_AUCTION_SERVICES)
        return bg_error_set(err, BG_ERR_INVALID, "auction: bad buyer %u or good %d",
                            (unsigned)buyer, good);
    bgm_msg_t m = bgm_outbox_msg(BGM_MT_BID, FIRST_BUYER + buyer, SELF, req, attempt);
    m.good = (int16_t)good;
    m.price = limit;
    m.a = work;
    m.b = deadline;
    m.origin = group;
    bg_status st = put_exclusions(&m, exclude, nexclude, err);
    return st != BG_OK ? st : deliver(a, a->central, &m, now, err);
}

void bgb_auction_forget_buyer(bgb_auction_t *a, uint32_t buyer)
{
    bgm_market_agent_forget_bids(a->central, FIRST_BUYER + buyer);
}

static bgb_auction_bound_t bound_of(const bgm_bound_t *b)
{
    bgb_auction_bound_t o = {b->is_bid, b->excluded, 0, 0, -1, b->price};
    if (b->is_bid) {
        o.buyer = b->owner - FIRST_BUYER;
        o.req = (uint32_t)b->ref;
    } else {
        o.slot = (int)(b->owner - FIRST_SELLER);
    }
    return o;
}

/* The machine's record of the tick's clearings, in the caller's terms;
 * returns how many. */
static size_t map_clearings(bgb_auction_t *a)
{
    size_t n = 0;
    const bgm_ma_clearing_t *c = bgm_market_agent_clearings(a->central, &n);
    for (size_t i = 0; i < n; i++)
        a->clearings[i] = (bgb_auction_clearing_t){.index = (int)i,
                                                   .good = c[i].good,
                                                   .volume = c[i].res.volume,
                                                   .rationed = c[i].res.rationed,
                                                   .k = a->cfg.central.k,
                                                   .price = c[i].res.price,
                                                   .low = c[i].res.low,
                                                   .high = c[i].res.high,
                                                   .low_by = bound_of(&c[i].res.low_by),
                                                   .high_by = bound_of(&c[i].res.high_by)};
    return n;
}

/* The clearing that made the `nth` match of the tick (NULL: not recorded). */
static const bgb_auction_clearing_t *clearing_of(const bgb_auction_t *a, size_t n, size_t nth)
{
    size_t count = 0;
    const bgm_ma_clearing_t *c = bgm_market_agent_clearings(a->central, &count);
    for (size_t i = 0; i < n && i < count; i++)
        if (nth >= c[i].first && nth < c[i].first + c[i].count)
            return &a->clearings[i];
    return NULL;
}

bg_status bgb_auction_tick(bgb_auction_t *a, double now, bgb_auction_match_fn match, void *ctx,
                           double *next, bg_error_t *err)
{
    bg_status st = BG_OK;
    if (now >= a->next_clear) {
        bgm_outbox_clear(a->clear);
        st = bgm_market_agent_on_timer(a->central, BGM_MA_TIMER_CLEAR, 0, now, a->clear);
        /* The machine schedules its next clearing; a late tick does not
         * make clearings pile up. */
        a->next_clear = now + a->cfg.central.period;
        const size_t nclearings = map_clearings(a);
        size_t nth = 0; /* MATCH messages seen */
        for (size_t i = 0; i < bgm_outbox_count(a->clear); i++) {
            const bgm_out_item_t *it = bgm_outbox_item(a->clear, i);
            if (it->is_timer) {
                a->next_clear = it->at;
                continue;
            }
            const bgm_msg_t *m = &it->msg;
            if (m->type != BGM_MT_MATCH)
                continue;
            const bgb_auction_clearing_t *clearing = clearing_of(a, nclearings, nth++);
            /* The MATCH names everything; the buyer's ACCEPT repeats it. */
            if (m->to < FIRST_SELLER || m->to >= FIRST_BUYER || m->origin < FIRST_BUYER)
                continue;
            bgb_auction_match_t x = {.buyer = m->origin - FIRST_BUYER,
                                     .req = m->req,
                                     .attempt = m->attempt,
                                     .good = m->good,
                                     .slot = (int)(m->to - FIRST_SELLER),
                                     .price = m->price,
                                     .ask = m->b,
                                     .clearing = clearing};
            match(ctx, &x);
        }
        if (st != BG_OK)
            bg_error_set(err, st, "auction: clearing failed (a book is full)");
    }
    *next = a->next_clear;
    return st;
}

int bgb_auction_query(bgb_auction_t *a, uint32_t buyer, uint32_t req, int good, double limit,
                      const int *exclude, int nexclude, int *slots, double *prices, int max,
                      double now, bg_error_t *err)
{
    if (buyer >= BGB_AUCTION_MAX_BUYERS || good < 0 || good >= BGB_AUCTION_SERVICES) {
        bg_error_set(err, BG_ERR_INVALID, "auction: bad buyer %u or good %d", (unsigned)buyer,
                     good);
        return -1;
    }
    bgm_msg_t m = bgm_outbox_msg(BGM_MT_QUERY, FIRST_BUYER + buyer, SELF, req, 0);
    m.good = (int16_t)good;
    m.price = limit;
    if (put_exclusions(&m, exclude, nexclude, err) != BG_OK ||
        deliver(a, a->directory, &m, now, err) != BG_OK)
        return -1;
    int n = 0;
    for (size_t i = 0; i < bgm_outbox_count(a->out); i++) {
        const bgm_msg_t *l = &bgm_outbox_item(a->out, i)->msg;
        if (bgm_outbox_item(a->out, i)->is_timer || l->type != BGM_MT_LIST)
            continue;
        for (int c = 0; c < l->ncand && n < max; c++) {
            slots[n] = (int)(l->cand[c] - FIRST_SELLER);
            prices[n++] = l->cand_price[c];
        }
    }
    return n;
}
