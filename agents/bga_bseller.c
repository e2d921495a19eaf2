#include "bga_bseller.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bga_deals.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_seller.h"

/* Machine ids of the parties the live seller hears from: the broker's
 * buyer (every order and bargain), the market agent (the machine's asks,
 * not sent) and the resource seller that rents it a contract's resources
 * (the broker's layer-1 purchase). Directory ids are small, so these never
 * collide with a neighbour's. */
#define BS_BUYER 0xfffffffeu
#define BS_MARKET 0xfffffffdu
#define BS_RESOURCE 0xfffffffcu
#define BS_TIMERS 1024 /* machine timers pending: two per contract buying at most */
#define BS_OUTBOX 64   /* items one message can cause: a proposal, relays, a reply */
#define BS_INJECT 4    /* messages the host answers the machine with in one call */
#define BS_ROUNDS 12   /* the simulator's default catallactic.max_rounds */
#define BS_MAX_QUANTITY 1e9
#define BS_RESOURCE_HEADROOM 1.5
#define BS_MAX_HOPS 16
#define BS_RATE_SCALE 1e-12 /* a mean rate for resources expected free */

/* A deal's states once agreed (in talk: BGA_DEAL_TALK): buying the
 * machine's bundle for it, then holding the contract. */
enum { D_BUYING = 1, D_HELD };

typedef struct mtimer {
    double at;
    int kind;
    uint64_t arg;
} mtimer_t;

struct bga_bseller {
    bga_bseller_config_t c;
    bgm_config_t cfg;
    bgm_seller_t *machine;
    bgm_outbox_t *out;
    uint32_t id;
    bga_deals_t deals; /* deals.next_req numbers the machine's requests too */
    mtimer_t timer[BS_TIMERS];
    int ntimers;
};

/* What the message being handled was, for the answers it causes. */
typedef struct route {
    bga_bseller_t *bs;
    const bga_mmsg_t *in; /* NULL from a timer or a release */
    bga_deal_t *d;        /* the deal it is about (NULL from a timer) */
    double now;
    int refuse;     /* a REJECT answers an order or acceptance: a REFUSE naming why */
    int no_propose; /* the deal is already agreed: a call is passed on, not answered */
    int quiet;      /* the job ended: nothing is said to the broker */
    char why[BGA_MMSG_REASON_MAX]; /* a CANCEL's reason */
    bga_bseller_send_fn send;
    void *ctx;
    bgm_msg_t inject[BS_INJECT];
    int ninject;
} route_t;

static int sells(const bga_bseller_t *bs, int good)
{
    return good >= 0 && good < 3 && (bs->c.services & (1u << good));
}

bg_status bga_bseller_new(const bga_bseller_config_t *c, bga_bseller_t **out, bg_error_t *err)
{
    *out = NULL;
    if (c->slots < 1 || c->slots > 4096)
        return bg_error_set(err, BG_ERR_INVALID, "basic seller: slots %d outside [1, 4096]",
                            c->slots);
    if (!(c->margin >= 0 && c->margin < 1e6) || !(c->load_slope >= 0 && c->load_slope < 1e6) ||
        !(c->lease > 0 && c->lease <= 1e7))
        return bg_error_set(err, BG_ERR_INVALID,
                            "basic seller: margin, load slope or lease out of range");
    for (int g = 0; g < 3; g++)
        if (!(c->floor[g] >= 0 && c->floor[g] < 1e12) ||
            !(c->unit_cores[g] >= 0 && c->unit_cores[g] <= 1e6) ||
            !(c->unit_memory[g] >= 0 && c->unit_memory[g] <= 1e9))
            return bg_error_set(err, BG_ERR_INVALID,
                                "basic seller: floor, unit cores or unit memory of good %d", g);
    for (int k = 0; k < 2; k++)
        if (!(c->rate[k] >= 0 && c->rate[k] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "basic seller: expected %s rate in [0, 1e12)",
                                k ? "memory" : "core");
    bga_bseller_t *bs = calloc(1, sizeof *bs);
    if (!bs)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the basic seller");
    bs->c = *c;
    /* The machine reads of its config the mean resource rates, each
     * service's cores, memory and work, the node speed, the posted markup
     * and the bargaining rounds. Its resource estimate for a unit is
     * (core rate · cores + memory rate · GiB) · work / (speed · cores);
     * its cores are whole, so the work per unit is set for the estimate
     * to be one lease of the unit's real needs at the expected rates. */
    bgm_config_t *cfg = &bs->cfg;
    /* It weighs what it pays against the mean rates: free resources still
     * need a scale. */
    cfg->resources.core_cost = c->rate[0] > 0 ? c->rate[0] : BS_RATE_SCALE;
    cfg->resources.memory_cost = c->rate[1] > 0 ? c->rate[1] : BS_RATE_SCALE;
    cfg->network.speed = 1.0;
    cfg->baseline.markup = c->margin;
    cfg->catallactic.max_rounds = BS_ROUNDS;
    cfg->catallactic.reply_timeout = BGA_BSELLER_BUY_WAIT;
    cfg->catallactic.retry_backoff = 1.0;
    bgm_seller_params_t p = {.cfg = cfg,
                             .mechanism = BGM_MECH_CENTRAL,
                             .self = 0,
                             .market = BS_MARKET,
                             .first_buyer = BS_BUYER,
                             .nbuyers = 1,
                             .first_resource = BS_RESOURCE,
                             .nresource = 1,
                             .slots = c->slots,
                             .markup = c->margin,
                             .load_slope = c->load_slope,
                             .resource_headroom = BS_RESOURCE_HEADROOM,
                             .posted_follows_cost = 1};
    for (int g = 0; g < 3; g++) {
        bgm_service_cfg_t *sv = &cfg->services[g];
        sv->cores = c->unit_cores[g] > 1 ? (int)ceil(c->unit_cores[g]) : 1;
        sv->memory = c->unit_memory[g];
        const double want = c->rate[0] * c->unit_cores[g] + c->rate[1] * c->unit_memory[g],
                     has = cfg->resources.core_cost * sv->cores +
                           cfg->resources.memory_cost * sv->memory;
        sv->flops_per_unit = c->lease * sv->cores * want / has;
        p.sells[g] = sells(bs, g);
        p.cost[g] = c->floor[g];
    }
    bgm_rng_seed(&p.rng, c->seed);
    bgm_genes_random(&p.genes, &p.rng);
    bg_status st = BG_OK;
    bs->machine = bgm_seller_new(&p);
    bs->out = bgm_outbox_new(BS_OUTBOX);
    if (!bs->machine || !bs->out) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the basic seller");
        goto out;
    }
    /* Its buyer never tells it whom else it bargained with and it meets no
     * neighbour to learn from: learning from its own outcomes alone only
     * moves its markup one way (bga_rseller.h). */
    bgm_seller_fix_strategy(bs->machine);
    bga_deals_init(&bs->deals);
    /* Its asks to the market agent are the heartbeat's business. */
    if (bgm_seller_start(bs->machine, 0.0, bs->out) != BG_OK)
        st = bg_error_set(err, BG_ERR_INVALID, "basic seller: its role machine did not start");
    bgm_outbox_clear(bs->out);
out:
    if (st != BG_OK)
        bga_bseller_destroy(&bs);
    *out = bs;
    return st;
}

void bga_bseller_destroy(bga_bseller_t **pbs)
{
    if (!pbs || !*pbs)
        return;
    bgm_seller_destroy(&(*pbs)->machine);
    bgm_outbox_destroy(&(*pbs)->out);
    free(*pbs);
    *pbs = NULL;
}

bg_status bga_bseller_registered(bga_bseller_t *bs, uint32_t id, const uint32_t *neighbours,
                                 int nneighbours, bg_error_t *err)
{
    /* The broker gives a basic seller neighbours of its own role. */
    uint8_t same[BGA_MMSG_MAX_NEIGHBOURS];
    memset(same, 1, sizeof same);
    if (nneighbours < 0 || nneighbours > BGA_MMSG_MAX_NEIGHBOURS ||
        bgm_seller_set_neighbours(bs->machine, neighbours, same, nneighbours) != BG_OK)
        return bg_error_set(err, BG_ERR_INVALID, "basic seller: %d neighbours", nneighbours);
    bs->id = id;
    return BG_OK;
}

double bga_bseller_price(const bga_bseller_t *bs, int good)
{
    return sells(bs, good) ? bgm_seller_asking(bs->machine, good) : 0.0;
}

double bga_bseller_reservation(const bga_bseller_t *bs, int good)
{
    return sells(bs, good) ? bgm_seller_reservation(bs->machine, good) : 0.0;
}

int bga_bseller_used(const bga_bseller_t *bs)
{
    return bgm_seller_used(bs->machine);
}

static int covers(const bga_deal_t *d, uint64_t job)
{
    return d->used && d->state == D_HELD && job >= d->job && job - d->job < BGA_BSELLER_JOB_SPAN;
}

int bga_bseller_holds(const bga_bseller_t *bs, uint64_t job)
{
    for (int i = 0; i < BGA_DEALS_MAX; i++)
        if (covers(&bs->deals.deal[i], job))
            return 1;
    return 0;
}

double bga_bseller_cores(const bga_bseller_t *bs, uint64_t job)
{
    double cores = 0;
    for (int i = 0; i < BGA_DEALS_MAX; i++)
        if (covers(&bs->deals.deal[i], job))
            cores += bs->c.unit_cores[bs->deals.deal[i].good];
    return cores;
}

void bga_bseller_describe(const bga_bseller_t *bs, bga_mmsg_t *msg)
{
    msg->services = bs->c.services & 7u;
    msg->slots = bs->c.slots;
    msg->free_slots = bs->c.slots - bga_bseller_used(bs);
    for (int g = 0; g < 3; g++) {
        msg->floor[g] = bga_bseller_reservation(bs, g);
        msg->prices[g] = bga_bseller_price(bs, g);
    }
    msg->margin = bs->c.margin;
    msg->load_slope = bs->c.load_slope;
}

/* ---------------------------------------------------------------- deals */

static bga_deal_t *deal_by_bundle(bga_bseller_t *bs, uint32_t bundle)
{
    for (int i = 0; i < BGA_DEALS_MAX; i++) {
        bga_deal_t *d = &bs->deals.deal[i];
        if (d->used && d->state != BGA_DEAL_TALK && d->bundle == bundle)
            return d;
    }
    return NULL;
}

/* ------------------------------------------------------------- routing */

static bg_status machine_status(bg_status st, bg_error_t *err)
{
    return st == BG_OK
               ? BG_OK
               : bg_error_set(err, st, "the basic seller's role machine failed (%d)", (int)st);
}

static bg_status add_timer(bga_bseller_t *bs, const bgm_out_item_t *it, bg_error_t *err)
{
    if (bs->ntimers == BS_TIMERS)
        return bg_error_set(err, BG_ERR_LIMIT, "basic seller: %d timers pending", BS_TIMERS);
    bs->timer[bs->ntimers++] = (mtimer_t){it->at, it->kind, it->arg};
    return BG_OK;
}

/* The live message about a deal from the basic role. */
static void live_init(const bga_bseller_t *bs, bga_mmsg_t *o, int type, const bga_deal_t *d)
{
    bga_mmsg_init(o, type);
    o->agent = bs->id;
    o->resource = 0;
    o->job = d->job;
    o->good = d->good;
    o->quantity = d->quantity;
}

/* Why the machine would not take this order or acceptance, from its state
 * (a REJECT changes nothing, so the state is the one it judged). */
static void refusal_reason(const bga_bseller_t *bs, const route_t *r, char *out, size_t n)
{
    const int g = r->d->good;
    const double floor_g = bga_bseller_reservation(bs, g);
    if (bga_bseller_used(bs) >= bs->c.slots)
        snprintf(out, n, "no free slot");
    else if (r->in->price < floor_g)
        snprintf(out, n, "price %.6g under the floor %.6g", r->in->price, floor_g);
    else if (r->in->type == BGA_MM_ACCEPT)
        snprintf(out, n, "no bargain open for job %llu", (unsigned long long)r->d->job);
    else
        snprintf(out, n, "the basic seller declined");
}

/* Queues the host's own answer to the machine (a free rental's RCONFIRM,
 * a delivery's TAKE), handed to it once the current call is routed. */
static bg_status answer_machine(route_t *r, const bgm_msg_t *m, bg_error_t *err)
{
    if (r->ninject == BS_INJECT)
        return bg_error_set(err, BG_ERR_LIMIT, "basic seller: too many answers in one call");
    r->inject[r->ninject++] = *m;
    return BG_OK;
}

/* The machine's resource purchase: one RBID is the live RBUY for the
 * contract's cores and memory over one lease; a contract that needs none
 * is rented at once for nothing. */
static bg_status on_rbid(route_t *r, const bgm_msg_t *m, bg_error_t *err)
{
    bga_bseller_t *bs = r->bs;
    bga_deal_t *d = r->d;
    if (!d)
        return bg_error_set(err, BG_ERR_INVALID, "basic seller: a resource bid outside a deal");
    d->state = D_BUYING;
    d->bundle = m->req;
    const double cores = bs->c.unit_cores[d->good], memory = bs->c.unit_memory[d->good];
    if (cores <= 0 && memory <= 0) {
        bgm_msg_t c = bgm_outbox_msg(BGM_MT_RCONFIRM, BS_RESOURCE, bs->id, m->req, m->attempt);
        c.good = -1;
        c.price = 0.0;
        c.a = r->now;
        c.b = r->now + bs->c.lease;
        return answer_machine(r, &c, err);
    }
    if (r->quiet)
        return BG_OK;
    bga_mmsg_t o;
    live_init(bs, &o, BGA_MM_RBUY, d);
    o.cores = cores;
    o.memory = memory;
    o.term = bs->c.lease;
    o.price = m->price;
    return r->send(r->ctx, &o, err);
}

/* The machine's delivery: the live CONFIRM, final at once (the host
 * answers it TAKE), the contract held for one lease. */
static bg_status on_confirm(route_t *r, const bgm_msg_t *m, bg_error_t *err)
{
    bga_bseller_t *bs = r->bs;
    bga_deal_t *d = deal_by_bundle(bs, m->origin);
    const bgm_purchase_req_t *b = bgm_seller_bundle(bs->machine, m->origin);
    if (!d || !b)
        return bg_error_set(err, BG_ERR_INVALID, "basic seller: a delivery of no deal");
    d->state = D_HELD;
    d->until = r->now + bs->c.lease;
    bgm_msg_t t = bgm_outbox_msg(BGM_MT_TAKE, BS_BUYER, bs->id, m->req, m->attempt);
    t.origin = m->origin;
    bg_status st = answer_machine(r, &t, err);
    if (st != BG_OK || r->quiet)
        return st;
    bga_mmsg_t o;
    live_init(bs, &o, BGA_MM_CONFIRM, d);
    o.price = m->price;
    o.slots = bs->c.slots;
    o.free_slots = bs->c.slots - bga_bseller_used(bs);
    o.floor[d->good] = b->deal.limit;
    return r->send(r->ctx, &o, err);
}

/* Turns what the machine emitted into live messages, timers and the
 * host's own answers to it (queued in r->inject). */
static bg_status route_out(route_t *r, bg_error_t *err)
{
    bga_bseller_t *bs = r->bs;
    bg_status st = BG_OK;
    const size_t n = bgm_outbox_count(bs->out);
    for (size_t i = 0; i < n && st == BG_OK; i++) {
        const bgm_out_item_t *it = bgm_outbox_item(bs->out, i);
        if (it->is_timer) {
            /* A run's release is the lease's end, which the host keeps
             * with the deal; its purchase's deadline and retry timers
             * run on the host's clock; no learning meeting is held. */
            if (it->kind == BGM_PU_TIMER_REQ || it->kind == BGM_PU_TIMER_DEADLINE ||
                it->kind == BGM_PU_TIMER_RETRY)
                st = add_timer(bs, it, err);
            continue;
        }
        const bgm_msg_t *m = &it->msg;
        if (m->to == BS_MARKET) {
            if (m->type == BGM_MT_RBID)
                st = on_rbid(r, m, err);
            continue; /* its asks and freed slots: the heartbeat says them */
        }
        if (m->type == BGM_MT_CONFIRM) {
            st = on_confirm(r, m, err);
            continue;
        }
        bga_deal_t *d = m->type == BGM_MT_CFP ? r->d : bga_deals_by_req(&bs->deals, m->req);
        if (!d || r->quiet)
            continue;
        bga_mmsg_t o;
        switch (m->type) {
        case BGM_MT_PROPOSE:
            if (r->no_propose)
                continue;
            live_init(bs, &o, BGA_MM_PROPOSE, d);
            o.price = m->price;
            o.term = r->in ? r->in->term : 0;
            o.attempt = d->attempt >= 0 ? d->attempt : 0; /* the round it answers */
            break;
        case BGM_MT_OFFER:
            live_init(bs, &o, BGA_MM_OFFER, d);
            o.price = m->price;
            break;
        case BGM_MT_ACCEPT:
            continue; /* agreed: the live answer is the CONFIRM once it has the resources */
        case BGM_MT_REJECT:
            d->opened = 0;
            live_init(bs, &o, r->refuse ? BGA_MM_REFUSE : BGA_MM_REJECT, d);
            o.price = r->in ? r->in->price : 0;
            if (r->refuse)
                refusal_reason(bs, r, o.reason, sizeof o.reason);
            break;
        case BGM_MT_CANCEL:
            /* The agreed contract lost its resources: the slot is back. */
            live_init(bs, &o, BGA_MM_REFUSE, d);
            snprintf(o.reason, sizeof o.reason, "%s",
                     r->why[0] ? r->why : "resources not bought in time");
            bgm_seller_forget(bs->machine, d->bundle);
            d->state = BGA_DEAL_TALK;
            d->bundle = 0;
            break;
        case BGM_MT_CFP:
            /* Passed on over the overlay: the broker relays it. */
            live_init(bs, &o, BGA_MM_RELAY, d);
            o.target = m->to;
            o.origin = r->in && r->in->origin ? r->in->origin : bs->id;
            o.hops = m->hops;
            o.attempt = r->in ? r->in->attempt : 0;
            o.term = r->in ? r->in->term : 0;
            break;
        default:
            continue; /* nothing else goes to the broker's buyer */
        }
        st = r->send(r->ctx, &o, err);
    }
    bgm_outbox_clear(bs->out);
    return st;
}

/* Hands the machine one message (m) or one of its timers (m NULL: kind,
 * arg) and routes what it emits, then the host's answers to it in turn
 * (a delivery's TAKE, a free rental's RCONFIRM), until none is left. */
static bg_status feed(route_t *r, const bgm_msg_t *m, int kind, uint64_t arg, bg_error_t *err)
{
    bga_bseller_t *bs = r->bs;
    bgm_msg_t queue[2 * BS_INJECT];
    int head = 0, tail = 0;
    bg_status st =
        m ? bgm_seller_on_message(bs->machine, m, r->now, 1, &bs->deals.next_req, bs->out)
          : bgm_seller_on_timer(bs->machine, kind, arg, r->now, 1, bs->out);
    for (;;) {
        if (st != BG_OK) {
            bgm_outbox_clear(bs->out);
            return machine_status(st, err);
        }
        r->ninject = 0;
        if ((st = route_out(r, err)) != BG_OK)
            return st;
        for (int i = 0; i < r->ninject; i++) {
            if (tail == 2 * BS_INJECT)
                return bg_error_set(err, BG_ERR_LIMIT,
                                    "basic seller: too many answers in one call");
            queue[tail++] = r->inject[i];
        }
        if (head == tail)
            return BG_OK;
        st = bgm_seller_on_message(bs->machine, &queue[head++], r->now, 1, &bs->deals.next_req,
                                   bs->out);
    }
}

/* A machine message from the broker's buyer about deal d. */
static bgm_msg_t from_buyer(const bga_bseller_t *bs, int type, const bga_deal_t *d, double price,
                            double now)
{
    bgm_msg_t m = bgm_outbox_msg(type, BS_BUYER, bs->id, d->req,
                                 (uint32_t)(d->attempt >= 0 ? d->attempt : 0));
    m.good = (int16_t)d->good;
    m.price = price;
    m.a = d->quantity;
    m.cand_price[2] = now; /* an offer or order stands while it is handled */
    return m;
}

/* Ends a deal: a contract held gives its slot back (its release timer,
 * early), one still buying its resources is given up; either way the
 * machine forgets its bundle. Nothing is said to the broker. */
static bg_status end_deal(bga_bseller_t *bs, bga_deal_t *d, double now, bg_error_t *err)
{
    bg_status st = BG_OK;
    route_t r = {.bs = bs, .d = d, .now = now, .quiet = 1};
    if (d->state == D_HELD) {
        st = feed(&r, NULL, BGM_SE_TIMER_RELEASE, d->bundle, err);
    } else if (d->state == D_BUYING) {
        bgm_msg_t f = bgm_outbox_msg(BGM_MT_RFAIL, BS_RESOURCE, bs->id, d->bundle, 0);
        st = feed(&r, &f, -1, 0, err);
    }
    if (d->state != BGA_DEAL_TALK)
        bgm_seller_forget(bs->machine, d->bundle);
    d->used = 0;
    d->state = BGA_DEAL_TALK;
    return st;
}

static bg_status refuse_now(bga_bseller_t *bs, const bga_mmsg_t *in, const char *why,
                            bga_bseller_send_fn send, void *ctx, bg_error_t *err)
{
    if (in->type != BGA_MM_ORDER && in->type != BGA_MM_ACCEPT && in->type != BGA_MM_OFFER)
        return BG_OK; /* a call it cannot answer is not answered */
    bga_mmsg_t o;
    bga_mmsg_init(&o, in->type == BGA_MM_OFFER ? BGA_MM_REJECT : BGA_MM_REFUSE);
    o.agent = bs->id;
    o.job = in->job;
    o.good = in->good;
    o.quantity = in->quantity;
    o.price = in->price;
    snprintf(o.reason, sizeof o.reason, "%s", why);
    return send(ctx, &o, err);
}

/* The answer to the broker's layer-1 purchase: the machine's bundle is
 * rented (RCONFIRM, one lease at the resource sellers' asking rates, or
 * at the money paid when the answer names none) or failed (RFAIL). */
static bg_status on_resources(bga_bseller_t *bs, const bga_mmsg_t *in, double now,
                              bga_bseller_send_fn send, void *ctx, bg_error_t *err)
{
    bga_deal_t *d = bga_deals_find(&bs->deals, in->job, in->good);
    if (!d || d->state != D_BUYING)
        return BG_OK; /* released meanwhile: the broker drops the purchase */
    const bgm_purchase_req_t *b = bgm_seller_bundle(bs->machine, d->bundle);
    route_t r = {.bs = bs, .in = in, .d = d, .now = now, .send = send, .ctx = ctx};
    bgm_msg_t m;
    if (in->type == BGA_MM_RBOUGHT) {
        const int g = d->good;
        double rate = 0;
        if (in->prices[3] > 0 || in->prices[4] > 0)
            rate = in->prices[3] * bs->c.unit_cores[g] + in->prices[4] * bs->c.unit_memory[g];
        else if (in->price > 0 && isfinite(in->price))
            rate = in->price / bs->c.lease;
        m = bgm_outbox_msg(BGM_MT_RCONFIRM, BS_RESOURCE, bs->id, d->bundle, b ? b->attempt : 0);
        m.good = -1;
        m.price = rate;
        m.a = now;
        m.b = now + bs->c.lease;
    } else {
        m = bgm_outbox_msg(BGM_MT_RFAIL, BS_RESOURCE, bs->id, d->bundle, 0);
        snprintf(r.why, sizeof r.why, "no resources: %.150s", in->reason);
    }
    return feed(&r, &m, -1, 0, err);
}

bg_status bga_bseller_on_message(bga_bseller_t *bs, const bga_mmsg_t *in, double now,
                                 bga_bseller_send_fn send, void *ctx, bg_error_t *err)
{
    if (in->type == BGA_MM_RELEASE) {
        bg_status st = BG_OK;
        for (int i = 0; i < BGA_DEALS_MAX && st == BG_OK; i++)
            if (bs->deals.deal[i].used && bs->deals.deal[i].job == in->job)
                st = end_deal(bs, &bs->deals.deal[i], now, err);
        return st;
    }
    if (in->type == BGA_MM_RBOUGHT || in->type == BGA_MM_RFAIL)
        return on_resources(bs, in, now, send, ctx, err);
    if (in->type != BGA_MM_ORDER && in->type != BGA_MM_CFP && in->type != BGA_MM_OFFER &&
        in->type != BGA_MM_ACCEPT && in->type != BGA_MM_REJECT)
        return BG_OK;
    if (in->type == BGA_MM_CFP ? !(in->good >= 0 && in->good < BGA_MMSG_GOODS)
                               : !sells(bs, in->good)) {
        char why[64];
        snprintf(why, sizeof why, "does not sell %d", in->good);
        return refuse_now(bs, in, why, send, ctx, err);
    }
    if (!(in->quantity > 0 && in->quantity <= BS_MAX_QUANTITY) ||
        !(in->price >= 0 && in->price < 1e12))
        return refuse_now(bs, in, "quantity or price out of range", send, ctx, err);
    bga_deal_t *d = bga_deals_for(&bs->deals, in->job, in->good, now);
    if (!d)
        return refuse_now(bs, in, "too many contracts held", send, ctx, err);
    if (in->type == BGA_MM_REJECT) {
        d->opened = 0; /* the buyer walked away; the machine has nothing to say */
        return BG_OK;
    }
    if (d->state != BGA_DEAL_TALK && in->type != BGA_MM_CFP) {
        char why[96];
        snprintf(why, sizeof why, "already sold this good for job %llu",
                 (unsigned long long)in->job);
        return refuse_now(bs, in, why, send, ctx, err);
    }
    if (d->state == BGA_DEAL_TALK)
        d->quantity = in->quantity;
    route_t r = {.bs = bs, .in = in, .d = d, .now = now, .send = send, .ctx = ctx};
    bgm_msg_t m;
    switch (in->type) {
    case BGA_MM_CFP:
        /* A new round of discovery: the buyer no longer bargains over
         * this good, so the next offer opens a fresh bargain. */
        if (in->attempt != d->attempt && d->state == BGA_DEAL_TALK) {
            d->opened = 0;
            d->attempt = in->attempt;
        }
        r.no_propose = d->state != BGA_DEAL_TALK;
        m = from_buyer(bs, BGM_MT_CFP, d, 0, now);
        m.attempt = (uint32_t)(in->attempt >= 0 ? in->attempt : 0);
        m.origin = BS_BUYER;
        m.hops = (uint16_t)(in->hops > 0 && in->hops <= BS_MAX_HOPS ? in->hops : 1);
        break;
    case BGA_MM_OFFER:
        m = from_buyer(bs, BGM_MT_OFFER, d, in->price, now);
        m.hops = d->opened ? 0 : 1; /* the first offer opens the machine's session */
        d->opened = 1;
        break;
    case BGA_MM_ACCEPT:
        m = from_buyer(bs, BGM_MT_ACCEPT, d, in->price, now);
        r.refuse = 1;
        break;
    default: /* ORDER */
        m = from_buyer(bs, BGM_MT_ORDER, d, in->price, now);
        r.refuse = 1;
        break;
    }
    return feed(&r, &m, -1, 0, err);
}

bg_status bga_bseller_tick(bga_bseller_t *bs, double now, bga_bseller_send_fn send, void *ctx,
                           bg_error_t *err)
{
    bg_status st = BG_OK;
    /* Timers due, in no particular order (each stands alone); one that
     * fires may add others, which this pass also runs when due. */
    for (int i = 0; i < bs->ntimers && st == BG_OK;) {
        if (bs->timer[i].at > now) {
            i++;
            continue;
        }
        const mtimer_t t = bs->timer[i];
        bs->timer[i] = bs->timer[--bs->ntimers];
        route_t r = {.bs = bs, .now = now, .send = send, .ctx = ctx};
        if (t.kind == BGM_PU_TIMER_DEADLINE) {
            r.d = deal_by_bundle(bs, (uint32_t)(t.arg & 0x7fffffffffffffffull));
            snprintf(r.why, sizeof r.why, "resources not bought within %.3g s",
                     BGA_BSELLER_BUY_WAIT);
        }
        st = feed(&r, NULL, t.kind, t.arg, err);
    }
    for (int i = 0; i < BGA_DEALS_MAX && st == BG_OK; i++)
        if (bs->deals.deal[i].used && bs->deals.deal[i].state == D_HELD &&
            now >= bs->deals.deal[i].until)
            st = end_deal(bs, &bs->deals.deal[i], now, err);
    return st;
}
