#include "bgm_seller.h"

#include <math.h>
#include <stdlib.h>

#include "bgm_catallactic.h"
#include "bgm_session.h"

/* Bargains it keeps at once (catallactic). */
#define SE_SESSIONS 32
/* It re-announces its ask when its reservation moves this much. */
#define SE_ASK_REFRESH 0.1

struct bgm_seller {
    bgm_config_t cfg;
    bgm_seller_params_t p;
    bgm_purchase_t *pu;                  /* its buying half, and its trader state */
    bgm_trader_t *tr;                    /* pu's */
    bgm_sessions_t *sess;                /* catallactic: its side of every bargain */
    int used;                            /* slots held */
    double est_res[BGM_SERVICE_TYPES];   /* estimated resource cost per unit */
    double announced[BGM_SERVICE_TYPES]; /* last reservation sent to the market */
    double posted[BGM_SERVICE_TYPES];    /* baseline posted price */
    int fixed;        /* bgm_seller_fix_strategy: no strategy or price memory learnt */
    bgm_emitter_t em; /* during a call: its outbox and first failure */
};

static bgm_msg_t msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    return bgm_outbox_msg(type, from, to, req, attempt);
}

/* Normaliser for remembered resource prices: the mean cost rate. */
static double mean_rate(const bgm_seller_t *s, double cores, double mem)
{
    return s->cfg.resources.core_cost * cores + s->cfg.resources.memory_cost * mem;
}

static double reservation(const bgm_seller_t *s, int good)
{
    return s->p.cost[good] + s->est_res[good];
}

static double opening(const bgm_seller_t *s, int good)
{
    return bgm_nego_opening(BGM_SIDE_SELLER, reservation(s, good), s->tr->memory[good],
                            s->tr->markup);
}

static int from_buyer(const bgm_seller_t *s, uint32_t a)
{
    return a >= s->p.first_buyer && a - s->p.first_buyer < s->p.nbuyers;
}

static int from_resource(const bgm_seller_t *s, uint32_t a)
{
    return a >= s->p.first_resource && a - s->p.first_resource < s->p.nresource;
}

static int service_good(int good)
{
    return good >= 0 && good < BGM_SERVICE_TYPES;
}

bgm_seller_t *bgm_seller_new(const bgm_seller_params_t *p)
{
    if (p->degree < 0 || p->degree > BGM_PU_MAX_NEIGHBOURS)
        return NULL;
    bgm_seller_t *s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->em.self = p->self;
    s->cfg = *p->cfg;
    s->p = *p;
    s->p.cfg = &s->cfg;
    s->p.neighbours = NULL;
    s->p.same_role = NULL;
    bgm_trader_t tr = {p->rng, p->genes, 0.0, p->markup, {0.0, 0.0, 0.0, 0.0}};
    bgm_purchase_params_t pp = {&s->cfg, p->mechanism,  p->self,      p->market, p->horizon,
                                tr,      p->neighbours, p->same_role, p->degree, 0, 0};
    s->pu = bgm_purchase_new(&pp);
    if (p->mechanism == BGM_MECH_CATALLACTIC)
        s->sess = bgm_sessions_new(SE_SESSIONS);
    if (!s->pu || (p->mechanism == BGM_MECH_CATALLACTIC && !s->sess)) {
        bgm_seller_destroy(&s);
        return NULL;
    }
    s->tr = bgm_purchase_trader(s->pu);
    const bgm_config_t *c = &s->cfg;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        const bgm_service_cfg_t *sv = &c->services[t];
        /* What a run of one unit costs in resources at the mean cost
         * rate on a node of the nominal speed, until it learns better. */
        s->est_res[t] = mean_rate(s, sv->cores, sv->memory) * sv->flops_per_unit /
                        (c->network.speed * sv->cores);
        s->posted[t] = reservation(s, t) * (1.0 + c->baseline.markup);
    }
    return s;
}

void bgm_seller_destroy(bgm_seller_t **ps)
{
    if (!ps || !*ps)
        return;
    bgm_purchase_destroy(&(*ps)->pu);
    bgm_sessions_destroy(&(*ps)->sess);
    free(*ps);
    *ps = NULL;
}

const bgm_purchase_req_t *bgm_seller_bundle(bgm_seller_t *s, uint32_t id)
{
    return bgm_purchase_get(s->pu, id);
}

size_t bgm_seller_part_count(const bgm_seller_t *s)
{
    return bgm_purchase_part_count(s->pu);
}

const bgm_purchase_part_t *bgm_seller_part(const bgm_seller_t *s, size_t i)
{
    return bgm_purchase_part(s->pu, i);
}

int bgm_seller_used(const bgm_seller_t *s)
{
    return s->used;
}

bg_status bgm_seller_set_neighbours(bgm_seller_t *s, const uint32_t *neighbours,
                                    const uint8_t *same_role, int degree)
{
    return bgm_purchase_set_neighbours(s->pu, neighbours, same_role, degree);
}

int bgm_seller_forget(bgm_seller_t *s, uint32_t id)
{
    return bgm_purchase_forget(s->pu, id);
}

double bgm_seller_reservation(const bgm_seller_t *s, int good)
{
    return service_good(good) ? reservation(s, good) : 0.0;
}

double bgm_seller_asking(const bgm_seller_t *s, int good)
{
    if (!service_good(good))
        return 0.0;
    return s->posted[good] * (1.0 + s->p.load_slope * (double)s->used / (double)s->p.slots);
}

void bgm_seller_fix_strategy(bgm_seller_t *s)
{
    s->fixed = 1;
    bgm_purchase_fix_strategy(s->pu);
}

/* A price it agreed or was paid, remembered unless its strategy is fixed. */
static void remember(bgm_seller_t *s, int slot, double price)
{
    if (!s->fixed)
        s->tr->memory[slot] =
            bgm_memory_update(s->tr->memory[slot], price, s->tr->genes.weight_memory);
}

void bgm_seller_counts(const bgm_seller_t *s, bgm_purchase_tally_t *t)
{
    bgm_purchase_counts(s->pu, t);
}

/* Baseline: it tells the directory its free slots whenever they change,
 * as a plain scheduler's registry would learn them. */
static void announce(bgm_seller_t *s)
{
    if (s->p.mechanism != BGM_MECH_BASELINE)
        return;
    bgm_msg_t m = msg(BGM_MT_AVAIL, s->p.self, s->p.market, 0, 0);
    m.a = (double)(s->p.slots - s->used);
    bgm_emitter_send(&s->em, &m);
}

/* A slot is free again (a run ended, or its bundle could not be had). */
static void free_slot(bgm_seller_t *s, uint32_t id)
{
    if (s->used > 0)
        s->used--;
    announce(s);
    if (s->p.mechanism == BGM_MECH_CENTRAL) {
        bgm_msg_t m = msg(BGM_MT_FREE, s->p.self, s->p.market, id, 0);
        bgm_emitter_send(&s->em, &m);
    }
}

/* Acts on what its buying half reported: a bundle it could not get
 * gives the slot back and tells the job's agent the agreed service is
 * off; a bundle rented is delivered (CONFIRM with the bundle's number),
 * and the slot stays held until the rental ends, taken or not. */
static void absorb(bgm_seller_t *s, bg_status st, const bgm_purchase_event_t *ev)
{
    if (st)
        bgm_emitter_fail(&s->em, st);
    if (ev->kind == BGM_PU_EV_NONE)
        return;
    bgm_purchase_req_t *r = bgm_purchase_get(s->pu, ev->req);
    if (!r)
        return;
    const bgm_deal_t *d = &r->deal;
    if (ev->kind == BGM_PU_EV_FAILED) {
        free_slot(s, r->id);
        bgm_msg_t m = msg(BGM_MT_CANCEL, s->p.self, d->buyer, d->req, d->attempt);
        bgm_emitter_send(&s->em, &m);
        return;
    }
    r->delivered = 1;
    bgm_emitter_timer(&s->em, r->end, BGM_SE_TIMER_RELEASE, r->id);
    bgm_msg_t cm = msg(BGM_MT_CONFIRM, s->p.self, d->buyer, d->req, d->attempt);
    cm.price = d->price;
    cm.a = r->start;
    cm.b = r->end;
    cm.origin = r->id;
    bgm_emitter_send(&s->em, &cm);
}

/* It has agreed to serve deal d: it reserves a slot and starts buying
 * the bundle, keeping the deal in its own request. The deal is bound to
 * the buyer's attempt: whether the buyer still wants it is the buyer's to
 * say when the service is delivered (TAKE or REFUSE). Returns 0 (and
 * changes nothing) when it has no free slot. */
static int service_agreed(bgm_seller_t *s, const bgm_deal_t *d, double now, int up,
                          uint32_t *next_req)
{
    if (s->used >= s->p.slots || !up || !service_good(d->good) || !(d->work > 0.0) ||
        *next_req >= BGM_PU_MAX_REQS)
        return 0;
    s->used++;
    announce(s);
    const bgm_service_cfg_t *sv = &s->cfg.services[d->good];
    bgm_purchase_req_t it = {0};
    it.id = (*next_req)++;
    it.good = BGM_PU_BUNDLE;
    it.cores = (double)sv->cores;
    it.memory = sv->memory;
    it.flops = sv->flops_per_unit * d->work;
    it.limit = d->price * d->work;
    /* A host may keep the bid near what it expects the resources to cost:
     * a lone resource seller facing it would otherwise be handed the
     * whole price of the service by a split-the-difference clearing. */
    const double cap = s->p.resource_headroom * s->est_res[d->good] * d->work;
    if (s->p.resource_headroom > 0.0 && cap < it.limit)
        it.limit = cap;
    it.created = now;
    it.deadline = d->deadline > now ? d->deadline : now + s->cfg.catallactic.reply_timeout;
    it.deal = *d;
    bgm_purchase_event_t ev;
    bg_status st = bgm_purchase_open(s->pu, &it, now, up, s->em.out, &ev);
    absorb(s, st, &ev);
    return 1;
}

/* Agreement reached on the request a buyer's OFFER, ACCEPT or ORDER
 * names: it commits on its side and tells the buyer ACCEPT (resources
 * follow), or REJECT when it cannot. */
static void commit(bgm_seller_t *s, const bgm_msg_t *m, double price, double limit, double now,
                   int up, uint32_t *next_req)
{
    bgm_deal_t d = {m->from, m->req, m->attempt, m->good, m->a, m->cand_price[2], price, limit};
    if (!service_agreed(s, &d, now, up, next_req)) {
        bgm_msg_t x = msg(BGM_MT_REJECT, s->p.self, m->from, m->req, m->attempt);
        bgm_emitter_send(&s->em, &x);
        return;
    }
    remember(s, m->good, price);
    bgm_msg_t a = msg(BGM_MT_ACCEPT, s->p.self, m->from, m->req, m->attempt);
    a.price = price;
    bgm_emitter_send(&s->em, &a);
}

/* A call for proposals: it proposes its opening price for a type it
 * sells with a slot free (a basic seller quotes no speed), and passes the
 * call on. */
static void on_cfp(bgm_seller_t *s, const bgm_msg_t *m)
{
    if (bgm_purchase_cfp_seen(s->pu, m))
        return;
    if (service_good(m->good) && s->p.sells[m->good] && s->used < s->p.slots) {
        bgm_msg_t p = msg(BGM_MT_PROPOSE, s->p.self, m->origin, m->req, m->attempt);
        p.price = opening(s, m->good);
        p.a = 0.0;
        bgm_emitter_send(&s->em, &p);
    }
    bg_status st = bgm_purchase_cfp_forward(s->pu, m, s->em.out);
    if (st)
        bgm_emitter_fail(&s->em, st);
}

/* A buyer's OFFER. It reads what the offer carries (the good, how long
 * it stands) and its own session of the bargain, opened by the buyer's
 * first offer; an offer of a bargain it does not hold (another attempt,
 * forgotten) gets no answer. */
static void on_offer(bgm_seller_t *s, const bgm_msg_t *m, double now, int up, uint32_t *next_req)
{
    if (!service_good(m->good) || now > m->cand_price[2])
        return;
    /* A host that sells under every mechanism bargains only when a buyer
     * opens one: its sessions are made then. */
    if (!s->sess && !(s->sess = bgm_sessions_new(SE_SESSIONS))) {
        bgm_emitter_fail(&s->em, BG_ERR_NOMEM);
        return;
    }
    bgm_session_t *ss = bgm_sessions_for(s->sess, m);
    if (!ss)
        return;
    if (!ss->open) {
        bgm_nego_open(&ss->nego, BGM_SIDE_SELLER, reservation(s, m->good), opening(s, m->good),
                      &s->tr->genes, s->cfg.catallactic.max_rounds);
        ss->open = 1;
    }
    double reply = 0.0;
    bgm_nego_action act = bgm_nego_respond(&ss->nego, m->price, &s->tr->rng, &reply);
    if (act == BGM_NEGO_ACCEPT) {
        commit(s, m, reply, ss->nego.limit, now, up, next_req);
    } else if (act == BGM_NEGO_COUNTER) {
        bgm_msg_t o = msg(BGM_MT_OFFER, s->p.self, m->from, m->req, m->attempt);
        o.price = reply;
        bgm_emitter_send(&s->em, &o);
    } else {
        bgm_purchase_learn(s->pu, 0, 0.0);
        bgm_msg_t x = msg(BGM_MT_REJECT, s->p.self, m->from, m->req, m->attempt);
        bgm_emitter_send(&s->em, &x);
    }
}

/* The buyer accepted its last counter-offer: it commits at that price if
 * the bargain is one it holds. */
static void on_accept(bgm_seller_t *s, const bgm_msg_t *m, double now, int up, uint32_t *next_req)
{
    if (!service_good(m->good) || !s->sess)
        return;
    const bgm_session_t *ss = bgm_sessions_find(s->sess, m->from, m->req, m->attempt);
    if (!ss || !ss->open) {
        bgm_msg_t x = msg(BGM_MT_REJECT, s->p.self, m->from, m->req, m->attempt);
        bgm_emitter_send(&s->em, &x);
        return;
    }
    double lim = ss->nego.limit;
    bgm_purchase_learn(s->pu, 1, (m->price - lim) / m->price);
    commit(s, m, m->price, lim, now, up, next_req);
}

/* The job's agent answers its delivery of bundle m->origin: a taken
 * service teaches it what resources really cost per unit of it and its
 * price (central: a refreshed ASK when its reservation moved); a refused
 * one counts as a failure. Either way the bundle's parts are settled. */
static void on_answer(bgm_seller_t *s, const bgm_msg_t *m)
{
    const bgm_purchase_req_t *r = bgm_purchase_get(s->pu, m->origin);
    if (!r || r->deal.buyer != m->from || r->deal.req != m->req || !r->delivered)
        return;
    bgm_purchase_drop_parts(s->pu, r->id);
    if (m->type == BGM_MT_REFUSE) {
        bgm_purchase_learn(s->pu, 0, 0.0);
        return;
    }
    const bgm_deal_t *d = &r->deal;
    bgm_trader_t *tr = s->tr;
    double money = r->price * (r->end - r->start);
    s->est_res[d->good] =
        bgm_memory_update(s->est_res[d->good], money / d->work, tr->genes.weight_memory);
    remember(s, 3, r->price / mean_rate(s, r->cores, r->memory));
    remember(s, d->good, d->price);
    bgm_purchase_learn(s->pu, 1, (d->price - d->limit) / d->price);
    if (s->p.posted_follows_cost)
        s->posted[d->good] = reservation(s, d->good) * (1.0 + s->cfg.baseline.markup);
    if (s->p.mechanism == BGM_MECH_CENTRAL) {
        double res = reservation(s, d->good);
        if (fabs(res - s->announced[d->good]) > SE_ASK_REFRESH * s->announced[d->good]) {
            bgm_msg_t a = msg(BGM_MT_ASK, s->p.self, s->p.market, 0, 0);
            a.good = (int16_t)d->good;
            a.price = res;
            a.a = -1.0;
            s->announced[d->good] = res;
            bgm_emitter_send(&s->em, &a);
        }
    }
}

static void to_purchase(bgm_seller_t *s, const bgm_msg_t *m, double now)
{
    bgm_purchase_event_t ev;
    bg_status st = bgm_purchase_on_message(s->pu, m, now, s->em.out, &ev);
    absorb(s, st, &ev);
}

bg_status bgm_seller_start(bgm_seller_t *s, double now, bgm_outbox_t *out)
{
    bgm_emitter_begin(&s->em, out);
    if (s->p.mechanism == BGM_MECH_CATALLACTIC) {
        bgm_emitter_fail(&s->em, bgm_purchase_learning_start(s->pu, now, out));
        return s->em.failure;
    }
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        if (!s->p.sells[t])
            continue;
        bgm_msg_t m = msg(BGM_MT_ASK, s->p.self, s->p.market, 0, 0);
        m.good = (int16_t)t;
        m.price = s->p.mechanism == BGM_MECH_BASELINE ? s->posted[t] : reservation(s, t);
        m.a = s->p.slots;
        s->announced[t] = reservation(s, t);
        bgm_emitter_send(&s->em, &m);
    }
    return s->em.failure;
}

bg_status bgm_seller_on_message(bgm_seller_t *s, const bgm_msg_t *m, double now, int up,
                                uint32_t *next_req, bgm_outbox_t *out)
{
    bgm_emitter_begin(&s->em, out);
    switch (m->type) {
    case BGM_MT_MATCH: {
        bgm_deal_t d = {m->origin, m->req, m->attempt, m->good, m->a, m->c, m->price, m->b};
        if (!service_agreed(s, &d, now, up, next_req)) {
            bgm_msg_t c = msg(BGM_MT_CANCEL, s->p.self, m->origin, m->req, m->attempt);
            bgm_emitter_send(&s->em, &c);
        }
        break;
    }
    case BGM_MT_CFP:
        on_cfp(s, m);
        break;
    case BGM_MT_OFFER:
        if (from_resource(s, m->from))
            to_purchase(s, m, now);
        else
            on_offer(s, m, now, up, next_req);
        break;
    case BGM_MT_ACCEPT:
        if (from_resource(s, m->from))
            to_purchase(s, m, now);
        else
            on_accept(s, m, now, up, next_req);
        break;
    case BGM_MT_ORDER: {
        /* At its posted price or above, while the buyer's order stands;
         * one below it is refused. */
        if (!service_good(m->good) || now > m->cand_price[2] || !from_buyer(s, m->from))
            break;
        const double limit = s->posted[m->good] / (1.0 + s->cfg.baseline.markup);
        if (m->price >= limit) {
            commit(s, m, m->price, limit, now, up, next_req);
        } else {
            bgm_msg_t x = msg(BGM_MT_REJECT, s->p.self, m->from, m->req, m->attempt);
            bgm_emitter_send(&s->em, &x);
        }
        break;
    }
    case BGM_MT_TAKE:
    case BGM_MT_REFUSE:
        if (from_buyer(s, m->from))
            on_answer(s, m);
        break;
    case BGM_MT_PROPOSE:
    case BGM_MT_LIST:
    case BGM_MT_REJECT:
    case BGM_MT_CANCEL:
    case BGM_MT_RFAIL:
    case BGM_MT_RCONFIRM:
        to_purchase(s, m, now);
        break;
    case BGM_MT_GENES:
        bgm_emitter_fail(&s->em, bgm_purchase_on_genes(s->pu, m, out));
        break;
    case BGM_MT_CONFIRM:
        break; /* a delivery is for a job's agent */
    default:
        bgm_emitter_fail(&s->em, BG_ERR_INVALID);
        break;
    }
    return s->em.failure;
}

bg_status bgm_seller_on_timer(bgm_seller_t *s, int kind, uint64_t arg, double now, int up,
                              bgm_outbox_t *out)
{
    bgm_emitter_begin(&s->em, out);
    if (kind == BGM_SE_TIMER_RELEASE) {
        /* The run is over: a delivery never answered is void by now. */
        bgm_purchase_drop_parts(s->pu, (uint32_t)arg);
        free_slot(s, (uint32_t)arg);
        return s->em.failure;
    }
    bgm_purchase_event_t ev;
    bg_status st = bgm_purchase_on_timer(s->pu, kind, arg, now, up, out, &ev);
    absorb(s, st, &ev);
    return s->em.failure;
}
