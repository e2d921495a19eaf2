#include "bga_rseller.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bga_deals.h"
#include "bgm_resource.h"

/* Machine ids of the parties the live seller hears from: the broker's
 * buyer (every bargain and order) and the market agent (the machine's
 * registration and freed capacity, not sent). Directory ids are small, so
 * these never collide with a neighbour's. */
#define RS_BUYER 0xfffffffeu
#define RS_MARKET 0xfffffffdu
#define RS_OUTBOX 64 /* items one message can cause: a proposal, relays, a reply */
#define RS_ROUNDS 12 /* the simulator's default catallactic.max_rounds */
#define RS_MAX_QUANTITY 1e9

enum { RS_HELD = 1 }; /* a deal's state once the machine holds its bundle */

struct bga_rseller {
    bga_rseller_config_t c;
    bgm_config_t cfg;
    bgm_resource_t *machine;
    bgm_outbox_t *out;
    uint32_t id;
    bga_deals_t deals;
    uint32_t next_group; /* the machine's job numbers (share_phases) */
};

bg_status bga_rseller_new(const bga_rseller_config_t *c, bga_rseller_t **out, bg_error_t *err)
{
    *out = NULL;
    if (!(c->cores > 0 && c->cores <= 1e6) || !(c->memory >= 0 && c->memory <= 1e9))
        return bg_error_set(err, BG_ERR_INVALID,
                            "resource seller: cores in (0, 1e6], memory in [0, 1e9] GiB");
    /* The machine remembers prices relative to its cost, so a zero cost
     * has no scale. */
    for (int k = 0; k < 2; k++)
        if (!(c->floor[k] > 0 && c->floor[k] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "resource seller: %s floor in (0, 1e12)",
                                k ? "memory" : "core");
    if (!(c->margin >= 0 && c->margin < 1e6) || !(c->load_slope >= 0 && c->load_slope < 1e6) ||
        !(c->lease > 0 && c->lease <= 1e7))
        return bg_error_set(err, BG_ERR_INVALID,
                            "resource seller: margin, load slope or lease out of range");
    bg_status st = BG_OK;
    bga_rseller_t *rs = calloc(1, sizeof *rs);
    if (!rs)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the resource seller");
    rs->c = *c;
    /* The machine reads of its config only the mean costs (its remembered
     * prices are relative to them: here its own) and the bargaining rounds. */
    rs->cfg.resources.core_cost = c->floor[0];
    rs->cfg.resources.memory_cost = c->floor[1];
    rs->cfg.catallactic.max_rounds = RS_ROUNDS;
    bgm_resource_params_t p = {.cfg = &rs->cfg,
                               .mechanism = BGM_MECH_CENTRAL,
                               .self = 0,
                               .market = RS_MARKET,
                               .horizon = 0,
                               .cores = c->cores,
                               .memory = c->memory,
                               .core_cost = c->floor[0],
                               .memory_cost = c->floor[1],
                               .speed = 1.0,
                               .markup = c->margin,
                               .share_phases = 1};
    bgm_rng_seed(&p.rng, c->seed);
    bgm_genes_random(&p.genes, &p.rng);
    rs->machine = bgm_resource_new(&p);
    rs->out = bgm_outbox_new(RS_OUTBOX);
    if (!rs->machine || !rs->out) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the resource seller");
        goto out;
    }
    /* Its buyer never tells it when it walks away, so learning from its
     * own outcomes only raises its prices: 60 deals took its opening from
     * 1.5 to 4 times its cost. It keeps the configured margin. */
    bgm_resource_fix_strategy(rs->machine);
    bga_deals_init(&rs->deals);
    *out = rs;
out:
    if (st != BG_OK)
        bga_rseller_destroy(&rs);
    return st;
}

void bga_rseller_destroy(bga_rseller_t **prs)
{
    if (!prs || !*prs)
        return;
    bgm_resource_destroy(&(*prs)->machine);
    bgm_outbox_destroy(&(*prs)->out);
    free(*prs);
    *prs = NULL;
}

bg_status bga_rseller_registered(bga_rseller_t *rs, uint32_t id, const uint32_t *neighbours,
                                 int nneighbours, bg_error_t *err)
{
    uint8_t same[BGA_MMSG_MAX_NEIGHBOURS];
    if (nneighbours < 0 || nneighbours > BGA_MMSG_MAX_NEIGHBOURS)
        return bg_error_set(err, BG_ERR_INVALID, "resource seller: %d neighbours", nneighbours);
    /* The broker gives a resource seller neighbours of its own role. */
    memset(same, 1, sizeof same);
    rs->id = id;
    if (bgm_resource_set_neighbours(rs->machine, neighbours, same, nneighbours) != BG_OK)
        return bg_error_set(err, BG_ERR_INVALID, "resource seller: %d neighbours", nneighbours);
    return BG_OK;
}

double bga_rseller_used(const bga_rseller_t *rs, int k)
{
    double cores = 0, memory = 0;
    bgm_resource_used(rs->machine, &cores, &memory);
    const double v = k ? memory : cores;
    return v > 1e-12 ? v : 0.0;
}

double bga_rseller_price(const bga_rseller_t *rs, int good)
{
    return bgm_resource_asking(rs->machine, good, rs->c.load_slope);
}

void bga_rseller_describe(const bga_rseller_t *rs, bga_mmsg_t *msg)
{
    msg->cores = rs->c.cores;
    msg->memory = rs->c.memory;
    msg->free_cores = rs->c.cores - bga_rseller_used(rs, 0);
    msg->free_memory = rs->c.memory - bga_rseller_used(rs, 1);
    if (msg->free_cores < 0)
        msg->free_cores = 0;
    if (msg->free_memory < 0)
        msg->free_memory = 0;
    for (int k = 0; k < 2; k++) {
        msg->floor[3 + k] = rs->c.floor[k];
        msg->prices[3 + k] = bga_rseller_price(rs, 3 + k);
    }
    msg->margin = rs->c.margin;
    msg->load_slope = rs->c.load_slope;
}

/* The machine's message for a live one: a one-good bundle of `quantity`
 * for `term` seconds (flops = term · max(cores, 1) at speed 1), at the
 * bundle rate `rate`, its budget the money that rate comes to. */
static bgm_msg_t machine_msg(const bga_rseller_t *rs, int type, const bga_deal_t *d, double rate,
                             double now)
{
    bgm_msg_t m = bgm_outbox_msg(type, RS_BUYER, rs->id, d->req, 0);
    m.good = -1;
    m.origin = RS_BUYER;
    const int cores = d->good == BGM_GOOD_CORES_ID;
    m.a = cores ? d->quantity : 0.0;
    m.b = cores ? 0.0 : d->quantity;
    m.c = d->term * (cores ? d->quantity : 1.0);
    m.price = rate;
    /* The machine's own duration, computed as it does, so the money
     * check compares like with like. */
    m.cand_price[1] = rate * (m.c / (m.a > 0 ? m.a : 1.0));
    m.cand_price[2] = now; /* an offer or order stands while it is handled */
    if (d->group && d->serves >= 0 && d->serves < BGM_RS_PHASES) {
        m.ncand = 2;
        m.cand[0] = d->group;
        m.cand[1] = (uint32_t)d->serves;
    }
    return m;
}

/* The live message about a deal from the resource role. */
static void live_init(const bga_rseller_t *rs, bga_mmsg_t *r, int type, const bga_deal_t *d)
{
    bga_mmsg_init(r, type);
    r->agent = rs->id;
    r->resource = 1;
    r->job = d->job;
    r->good = d->good;
    r->quantity = d->quantity;
    r->term = d->term;
    r->parent = d->parent;
    r->serves = d->serves;
}

/* The machine's number for job `parent` (0 for none): the one another
 * deal of the job has, else one no deal uses. A held deal keeps its number
 * until it is released, so a job keeps one number while it holds anything. */
static uint32_t group_of(bga_rseller_t *rs, const bga_deal_t *self, uint64_t parent)
{
    if (!parent)
        return 0;
    for (int i = 0; i < BGA_DEALS_MAX; i++) {
        const bga_deal_t *d = &rs->deals.deal[i];
        if (d->used && d != self && d->parent == parent && d->group)
            return d->group;
    }
    for (;;) {
        if (++rs->next_group == 0)
            continue;
        int taken = 0;
        for (int i = 0; i < BGA_DEALS_MAX && !taken; i++)
            taken = rs->deals.deal[i].used && rs->deals.deal[i].group == rs->next_group;
        if (!taken)
            return rs->next_group;
    }
}

/* A live unit price for a machine rate: the price it was given or last
 * named when the rate is that one (exactly what the buyer saw), else the
 * rate per unit. */
static double unit_price(const bga_deal_t *d, double rate, double in_rate, double in_unit)
{
    if (rate == in_rate)
        return in_unit;
    if (rate == d->last_rate)
        return d->last_unit;
    return rate / d->quantity;
}

/* Why the machine would not take this deal, from its state. */
static void refusal_reason(const bga_rseller_t *rs, const bga_deal_t *d, double unit, char *out,
                           size_t n)
{
    const int k = d->good - BGM_GOOD_CORES_ID;
    const double cap = k ? rs->c.memory : rs->c.cores;
    const double free_q = cap - bga_rseller_used(rs, k);
    /* Cores for a job's phase take only what it holds beyond the job's
     * widest phase here. */
    const double more =
        k ? d->quantity : bgm_resource_cores_added(rs->machine, d->group, d->serves, d->quantity);
    if (d->state == RS_HELD)
        snprintf(out, n, "already sold %s for job %llu", k ? "memory" : "cores",
                 (unsigned long long)d->job);
    else if (more > free_q + 1e-9)
        snprintf(out, n, "%.6g %s free, %.6g asked", free_q, k ? "GiB" : "cores", more);
    else if (unit < rs->c.floor[k])
        snprintf(out, n, "rate %.6g under the floor %.6g", unit, rs->c.floor[k]);
    else
        snprintf(out, n, "the resource seller declined");
}

typedef struct route {
    bga_rseller_t *rs;
    const bga_mmsg_t *in;
    bga_deal_t *d;
    double in_rate; /* the rate the machine was handed */
    int refuse;     /* a REJECT answers an order: say REFUSE with the reason */
    bga_rseller_send_fn send;
    void *ctx;
} route_t;

/* Turns what the machine emitted into live messages and timers. */
static bg_status route_out(route_t *r, bg_error_t *err)
{
    bga_rseller_t *rs = r->rs;
    bga_deal_t *d = r->d;
    bg_status st = BG_OK;
    const size_t n = bgm_outbox_count(rs->out);
    for (size_t i = 0; i < n && st == BG_OK; i++) {
        const bgm_out_item_t *it = bgm_outbox_item(rs->out, i);
        if (it->is_timer) {
            /* The release of a bundle; the machine schedules no other
             * timer here (no learning meetings, no call-market parts). */
            bga_deal_t *h =
                it->kind == BGM_RS_TIMER_RELEASE ? bga_deals_by_req(&rs->deals, (uint32_t)it->arg) : NULL;
            if (h) {
                h->state = RS_HELD;
                h->until = it->at;
            }
            continue;
        }
        const bgm_msg_t *m = &it->msg;
        if (m->to == RS_MARKET)
            continue; /* the heartbeat tells the broker */
        bga_mmsg_t o;
        switch (m->type) {
        case BGM_MT_PROPOSE:
        case BGM_MT_OFFER:
            live_init(rs, &o, m->type == BGM_MT_PROPOSE ? BGA_MM_PROPOSE : BGA_MM_OFFER, d);
            o.attempt = d->attempt >= 0 ? d->attempt : 0; /* the round it answers */
            o.price = m->price / d->quantity;
            d->last_rate = m->price;
            d->last_unit = o.price;
            break;
        case BGM_MT_RCONFIRM:
            live_init(rs, &o, BGA_MM_CONFIRM, d);
            o.price = unit_price(d, m->price, r->in_rate, r->in->price);
            bga_rseller_describe(rs, &o);
            d->opened = 0;
            break;
        case BGM_MT_REJECT:
            live_init(rs, &o, r->refuse ? BGA_MM_REFUSE : BGA_MM_REJECT, d);
            if (r->refuse)
                refusal_reason(rs, d, r->in->price, o.reason, sizeof o.reason);
            d->opened = 0;
            break;
        case BGM_MT_CFP:
            /* Passed on over the overlay: the broker relays it. */
            live_init(rs, &o, BGA_MM_RELAY, d);
            o.target = m->to;
            o.origin = r->in->origin ? r->in->origin : rs->id;
            o.hops = m->hops;
            o.attempt = r->in->attempt;
            break;
        default:
            continue; /* nothing else goes to the broker's buyer */
        }
        st = r->send(r->ctx, &o, err);
    }
    bgm_outbox_clear(rs->out);
    return st;
}

static bg_status refuse_now(bga_rseller_t *rs, const bga_mmsg_t *in, const char *why,
                            bga_rseller_send_fn send, void *ctx, bg_error_t *err)
{
    if (in->type != BGA_MM_ORDER && in->type != BGA_MM_ACCEPT && in->type != BGA_MM_OFFER)
        return BG_OK; /* a call for proposals it cannot answer is not answered */
    bga_mmsg_t o;
    bga_mmsg_init(&o, in->type == BGA_MM_OFFER ? BGA_MM_REJECT : BGA_MM_REFUSE);
    o.agent = rs->id;
    o.resource = 1;
    o.job = in->job;
    o.good = in->good;
    o.quantity = in->quantity;
    o.price = in->price;
    snprintf(o.reason, sizeof o.reason, "%s", why);
    return send(ctx, &o, err);
}

static bg_status machine_status(bg_status st, bg_error_t *err)
{
    return st == BG_OK
               ? BG_OK
               : bg_error_set(err, st, "the resource seller's role machine failed (%d)", (int)st);
}

/* Ends a hold now: its release timer fires early. */
static bg_status release(bga_rseller_t *rs, bga_deal_t *d, double now, bg_error_t *err)
{
    bg_status st = BG_OK;
    if (d->state == RS_HELD) {
        st = bgm_resource_on_timer(rs->machine, BGM_RS_TIMER_RELEASE, d->req, now, 1, rs->out);
        bgm_outbox_clear(rs->out); /* only RFREE to the market agent */
    }
    d->used = 0;
    d->state = BGA_DEAL_TALK;
    return machine_status(st, err);
}

bg_status bga_rseller_on_message(bga_rseller_t *rs, const bga_mmsg_t *in, double now,
                                 bga_rseller_send_fn send, void *ctx, bg_error_t *err)
{
    if (in->type == BGA_MM_RELEASE) {
        bg_status st = BG_OK;
        for (int i = 0; i < BGA_DEALS_MAX && st == BG_OK; i++)
            if (rs->deals.deal[i].used && rs->deals.deal[i].job == in->job)
                st = release(rs, &rs->deals.deal[i], now, err);
        return st;
    }
    if (in->type != BGA_MM_ORDER && in->type != BGA_MM_CFP && in->type != BGA_MM_OFFER &&
        in->type != BGA_MM_ACCEPT && in->type != BGA_MM_REJECT)
        return BG_OK;
    if (in->good != BGM_GOOD_CORES_ID && in->good != BGM_GOOD_MEMORY_ID)
        return refuse_now(rs, in, "a resource seller sells cores (3) and memory (4) only", send,
                          ctx, err);
    if (!(in->quantity > 0 && in->quantity <= RS_MAX_QUANTITY) ||
        !(in->price >= 0 && in->price < 1e12) || !(in->term >= 0 && in->term <= 1e7))
        return refuse_now(rs, in, "quantity, price or term out of range", send, ctx, err);
    bga_deal_t *d = bga_deals_for(&rs->deals, in->job, in->good, now);
    if (!d)
        return refuse_now(rs, in, "too many resources held", send, ctx, err);
    if (in->type == BGA_MM_REJECT) {
        d->opened = 0; /* the buyer walked away; the machine has nothing to say */
        return BG_OK;
    }
    if (d->state == RS_HELD && in->type != BGA_MM_CFP) {
        char why[BGA_MMSG_REASON_MAX];
        refusal_reason(rs, d, in->price, why, sizeof why);
        return refuse_now(rs, in, why, send, ctx, err);
    }
    d->quantity = in->quantity;
    d->term = in->term > 0 ? in->term : rs->c.lease;
    /* A held deal (only a call for proposals gets here) keeps its job's
     * number: the machine's hold is filed under it. A new deal's parent is
     * 0, so a named job always gets its number. */
    if (d->state != RS_HELD) {
        if (d->parent != in->parent) {
            d->parent = in->parent;
            d->group = group_of(rs, d, in->parent);
        }
        d->serves = in->serves;
    }
    route_t r = {rs, in, d, in->price * in->quantity, 0, send, ctx};
    bgm_msg_t m;
    switch (in->type) {
    case BGA_MM_CFP:
        if (d->state == RS_HELD)
            return BG_OK;
        m = machine_msg(rs, BGM_MT_CFP, d, 0, now);
        m.hops = (uint16_t)(in->hops > 0 && in->hops < 64 ? in->hops : 1);
        m.attempt = (uint32_t)(in->attempt >= 0 ? in->attempt : 0);
        /* A new round of discovery: the buyer no longer bargains over
         * this good, so the next offer opens a fresh bargain. */
        if (in->attempt != d->attempt)
            d->opened = 0;
        d->attempt = in->attempt;
        break;
    case BGA_MM_OFFER:
        m = machine_msg(rs, BGM_MT_OFFER, d, r.in_rate, now);
        m.hops = d->opened ? 0 : 1; /* the first offer opens the machine's session */
        d->opened = 1;
        break;
    case BGA_MM_ACCEPT:
        /* The buyer took the seller's last price: hand the machine its own
         * rate, not one rebuilt from the unit price. */
        if (in->price == d->last_unit && d->last_rate > 0)
            r.in_rate = d->last_rate;
        m = machine_msg(rs, BGM_MT_ACCEPT, d, r.in_rate, now);
        r.refuse = 1;
        break;
    default: /* ORDER */
        m = machine_msg(rs, BGM_MT_ORDER, d, r.in_rate, now);
        r.refuse = 1;
        break;
    }
    bg_status st = bgm_resource_on_message(rs->machine, &m, now, 1, rs->out);
    if (st != BG_OK) {
        bgm_outbox_clear(rs->out);
        return machine_status(st, err);
    }
    return route_out(&r, err);
}

bg_status bga_rseller_tick(bga_rseller_t *rs, double now, bg_error_t *err)
{
    bg_status st = BG_OK;
    for (int i = 0; i < BGA_DEALS_MAX && st == BG_OK; i++) {
        bga_deal_t *d = &rs->deals.deal[i];
        if (d->used && d->state == RS_HELD && now >= d->until)
            st = release(rs, d, now, err);
    }
    return st;
}
