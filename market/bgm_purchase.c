#include "bgm_purchase.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_catallactic.h"
#include "bgm_flood.h"

#define PU_NEGO_NONE UINT32_MAX
/* Goods a QUERY names for a bundle (the directory lists resource sellers). */
#define PU_GOOD_CORES BGM_GOOD_CORES_ID

typedef struct proposal {
    uint32_t seller;
    double price, speed;
} proposal_t;

/* The bargaining state of a request while it is acquired by proposals
 * (catallactic) or candidate lists (baseline): kept apart from the
 * request and given back when it ends, because only a few requests of an
 * owner bargain at once while all of them stay recorded. */
typedef struct nego_state {
    proposal_t prop[BGM_PU_MAX_PROPOSALS];
    int nprop, next_prop;
    bgm_nego_t buyer_nego;
    /* Round-trip samples: when the message now awaiting an answer (QUERY,
     * ORDER, OFFER, a bundle's ACCEPT) was sent (< 0: none awaited), and
     * when the last round's calls for proposals went out, for which
     * attempt. */
    double sent_at, cfp_at;
    uint32_t cfp_attempt;
    uint32_t next_free;
} nego_state_t;

typedef struct req {
    bgm_purchase_req_t r;
    uint32_t nego;   /* bargaining state (PU_NEGO_NONE: none) */
    uint32_t quiet;  /* catallactic rounds no seller answered */
    uint32_t calls;  /* catallactic: calls for proposals the round sent */
    uint32_t rounds; /* acquisitions started: the retry backoff doubles with each */
} req_t;

/*
 * A round-trip estimator (RFC 6298, "Computing TCP's Retransmission
 * Timer"): the smoothed round trip and its mean deviation from samples
 * (gains 1/8 and 1/4), and a timeout of srtt + 4 rttvar, never below the
 * configured one, doubled for each timeout since the last sample (capped).
 * A phase timer is then as long as the owner's round trips really are, on
 * a cluster or across a wide-area network, where the configured constant
 * fitted one network only (market/README.md, "Issue 30").
 */
typedef struct rtt {
    double srtt, rttvar;
    uint32_t samples, backoff;
} rtt_t;

#define PU_RTO_MAX_DOUBLINGS 4

static void rtt_sample(rtt_t *e, double r)
{
    if (!(r >= 0.0))
        return;
    if (e->samples == 0) {
        e->srtt = r;
        e->rttvar = r / 2.0;
    } else {
        e->rttvar = 0.75 * e->rttvar + 0.25 * fabs(e->srtt - r);
        e->srtt = 0.875 * e->srtt + 0.125 * r;
    }
    e->samples++;
    e->backoff = 0;
}

static double rtt_timeout(const rtt_t *e, double floor)
{
    const double est = e->samples ? e->srtt + 4.0 * e->rttvar : 0.0;
    return (est > floor ? est : floor) * (double)(1u << e->backoff);
}

static void rtt_backoff(rtt_t *e)
{
    if (e->backoff < PU_RTO_MAX_DOUBLINGS)
        e->backoff++;
}

struct bgm_purchase {
    const bgm_config_t *cfg; /* its owner's */
    bgm_purchase_params_t p;
    uint32_t nbr[BGM_PU_MAX_NEIGHBOURS];
    uint8_t same[BGM_PU_MAX_NEIGHBOURS];
    bgm_trader_t tr;
    bgm_flood_seen_t seen; /* calls for proposals seen */
    req_t *reqs; /* in increasing id order */
    size_t nreq, req_cap;
    nego_state_t *negos; /* pool; a free list threads the unused ones */
    uint32_t nnego, nego_cap, nego_free;
    bgm_purchase_part_t *parts;
    size_t nparts, parts_cap;
    bgm_purchase_tally_t tally;
    rtt_t reply;              /* a seller's (or the directory's) answer to a message */
    rtt_t discovery;          /* a proposal after a round's calls */
    int fixed;                /* bgm_purchase_fix_strategy: no outcome is learnt */
    bgm_emitter_t em;         /* during a call: its outbox and first failure */
    bgm_purchase_event_t *ev; /* during a call */
};

/* ---------------------------------------------------------------- helpers */

static bgm_msg_t msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    return bgm_outbox_msg(type, from, to, req, attempt);
}

/* Starts a call: where it emits and reports, no failure yet. */
static void begin(bgm_purchase_t *pu, bgm_outbox_t *out, bgm_purchase_event_t *ev)
{
    bgm_emitter_begin(&pu->em, out);
    pu->ev = ev;
    ev->kind = BGM_PU_EV_NONE;
    ev->req = 0;
}

static bg_status finish(bgm_purchase_t *pu)
{
    pu->em.out = NULL;
    pu->ev = NULL;
    return pu->em.failure;
}

static void event(bgm_purchase_t *pu, bgm_purchase_event_kind kind, uint32_t id)
{
    pu->ev->kind = kind;
    pu->ev->req = id;
}

static req_t *find(bgm_purchase_t *pu, uint32_t id)
{
    size_t lo = 0, hi = pu->nreq;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (pu->reqs[mid].r.id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < pu->nreq && pu->reqs[lo].r.id == id ? &pu->reqs[lo] : NULL;
}

static int is_bundle(const req_t *q)
{
    return q->r.good < 0;
}

static void learn(bgm_purchase_t *pu, int success, double share)
{
    if (!pu->fixed)
        bgm_outcome_learn(&pu->tr.genes, &pu->tr.fitness, &pu->tr.markup, success, share);
}

/* Normaliser for remembered resource prices: the mean cost rate. */
static double mean_rate(const bgm_purchase_t *pu, double cores, double mem)
{
    return pu->cfg->resources.core_cost * cores + pu->cfg->resources.memory_cost * mem;
}

static uint64_t req_arg(const req_t *q)
{
    return (uint64_t)q->r.id | ((uint64_t)q->r.attempt << 32);
}

/* The request's bargaining state. Only valid while it has one, between
 * its first acquisition and its end; the pool may move when a state is
 * taken, so callers fetch it again after anything that starts one. */
static nego_state_t *ng(bgm_purchase_t *pu, const req_t *q)
{
    return &pu->negos[q->nego];
}

/* Gives request q a bargaining state if it has none. 0 when out of memory. */
static int nego_take(bgm_purchase_t *pu, req_t *q)
{
    if (q->nego != PU_NEGO_NONE)
        return 1;
    if (pu->nego_free == PU_NEGO_NONE) {
        if (pu->nnego == pu->nego_cap) {
            uint32_t n = pu->nego_cap ? pu->nego_cap * 2 : 4;
            nego_state_t *p =
                n <= BGM_PU_MAX_REQS ? realloc(pu->negos, (size_t)n * sizeof *p) : NULL;
            if (!p)
                return 0;
            pu->negos = p;
            pu->nego_cap = n;
        }
        pu->negos[pu->nnego].next_free = PU_NEGO_NONE;
        pu->nego_free = pu->nnego++;
    }
    q->nego = pu->nego_free;
    pu->nego_free = pu->negos[q->nego].next_free;
    memset(&pu->negos[q->nego], 0, sizeof pu->negos[0]);
    return 1;
}

/* Request q has ended (done or failed): no message about it reads its
 * bargaining state any more (every handler checks the state first). */
static void req_end(bgm_purchase_t *pu, req_t *q, int state)
{
    q->r.state = state;
    if (q->nego == PU_NEGO_NONE)
        return;
    pu->negos[q->nego].next_free = pu->nego_free;
    pu->nego_free = q->nego;
    q->nego = PU_NEGO_NONE;
}

static int ended(const req_t *q)
{
    return q->r.state == BGM_PU_DONE || q->r.state == BGM_PU_FAILED;
}

/* ------------------------------------------------------------- lifecycle */

bgm_purchase_t *bgm_purchase_new(const bgm_purchase_params_t *p)
{
    if (p->degree < 0 || p->degree > BGM_PU_MAX_NEIGHBOURS || p->widen_quiet < 0 ||
        p->widen_quiet > 16)
        return NULL;
    bgm_purchase_t *pu = calloc(1, sizeof *pu);
    if (!pu)
        return NULL;
    pu->em.self = p->self;
    pu->cfg = p->cfg;
    pu->p = *p;
    for (int i = 0; i < p->degree; i++) {
        pu->nbr[i] = p->neighbours[i];
        pu->same[i] = p->same_role[i];
    }
    pu->p.neighbours = NULL;
    pu->p.same_role = NULL;
    pu->tr = p->trader;
    pu->nego_free = PU_NEGO_NONE;
    return pu;
}

void bgm_purchase_destroy(bgm_purchase_t **ppu)
{
    if (!ppu || !*ppu)
        return;
    bgm_purchase_t *pu = *ppu;
    free(pu->reqs);
    free(pu->negos);
    free(pu->parts);
    free(pu);
    *ppu = NULL;
}

bgm_trader_t *bgm_purchase_trader(bgm_purchase_t *pu)
{
    return &pu->tr;
}

void bgm_purchase_learn(bgm_purchase_t *pu, int success, double surplus_share)
{
    learn(pu, success, surplus_share);
}

void bgm_purchase_fix_strategy(bgm_purchase_t *pu)
{
    pu->fixed = 1;
}

bg_status bgm_purchase_set_neighbours(bgm_purchase_t *pu, const uint32_t *neighbours,
                                      const uint8_t *same_role, int degree)
{
    if (degree < 0 || degree > BGM_PU_MAX_NEIGHBOURS)
        return BG_ERR_INVALID;
    for (int i = 0; i < degree; i++) {
        pu->nbr[i] = neighbours[i];
        pu->same[i] = same_role[i];
    }
    pu->p.degree = degree;
    return BG_OK;
}

int bgm_purchase_forget(bgm_purchase_t *pu, uint32_t id)
{
    req_t *q = find(pu, id);
    if (!q || !ended(q))
        return 0;
    bgm_purchase_drop_parts(pu, id);
    const size_t i = (size_t)(q - pu->reqs);
    memmove(q, q + 1, (pu->nreq - i - 1) * sizeof *q);
    pu->nreq--;
    return 1;
}

bgm_purchase_req_t *bgm_purchase_get(bgm_purchase_t *pu, uint32_t id)
{
    req_t *q = find(pu, id);
    return q ? &q->r : NULL;
}

void bgm_purchase_done(bgm_purchase_t *pu, uint32_t id)
{
    req_t *q = find(pu, id);
    if (q)
        req_end(pu, q, BGM_PU_DONE);
}

size_t bgm_purchase_part_count(const bgm_purchase_t *pu)
{
    return pu->nparts;
}

const bgm_purchase_part_t *bgm_purchase_part(const bgm_purchase_t *pu, size_t i)
{
    return &pu->parts[i];
}

void bgm_purchase_drop_parts(bgm_purchase_t *pu, uint32_t id)
{
    size_t keep = 0;
    for (size_t i = 0; i < pu->nparts; i++)
        if (pu->parts[i].req != id)
            pu->parts[keep++] = pu->parts[i];
    pu->nparts = keep;
}

void bgm_purchase_counts(const bgm_purchase_t *pu, bgm_purchase_tally_t *t)
{
    t->requests += pu->tally.requests;
    t->attempts += pu->tally.attempts;
    t->timeouts += pu->tally.timeouts;
    for (int k = 0; k < BGM_PU_TO_KINDS; k++)
        t->timeout[k] += pu->tally.timeout[k];
}

static void timed_out(bgm_purchase_t *pu, int kind)
{
    pu->tally.timeouts += 1.0;
    pu->tally.timeout[kind] += 1.0;
}

/* ------------------------------------------------------------ acquisition */

static void final_fail(bgm_purchase_t *pu, req_t *q)
{
    if (ended(q))
        return;
    req_end(pu, q, BGM_PU_FAILED);
    if (q->r.parts > 0)
        bgm_purchase_drop_parts(pu, q->r.id);
    learn(pu, 0, 0.0);
    event(pu, BGM_PU_EV_FAILED, q->r.id);
}

/* One attempt failed: retry after a backoff while the deadline allows.
 * The backoff doubles with each round the request has started (capped):
 * a request retried at a fixed period kept flooding its calls or queries
 * until its deadline, 11 rounds a request on the random platform, where
 * doubling lets it try a bounded number of times (bgm_budget) and spreads
 * the retries of many requests out in time. */
static void attempt_failed(bgm_purchase_t *pu, req_t *q, double now)
{
    const uint32_t doublings =
        q->rounds > 0 ? (q->rounds - 1 < BGM_PU_RETRY_MAX_DOUBLINGS ? q->rounds - 1
                                                                    : BGM_PU_RETRY_MAX_DOUBLINGS)
                      : 0;
    const double backoff =
        (pu->p.mechanism == BGM_MECH_BASELINE ? pu->cfg->baseline.retry_backoff
                                              : pu->cfg->catallactic.retry_backoff) *
        (double)(1u << doublings);
    learn(pu, 0, 0.0);
    q->r.attempt++;
    if (now + backoff >= q->r.deadline) {
        final_fail(pu, q);
        return;
    }
    q->r.state = BGM_PU_IDLE;
    bgm_emitter_timer(&pu->em, now + backoff, BGM_PU_TIMER_RETRY, req_arg(q));
}

static double req_duration(const req_t *q, double speed)
{
    return q->r.flops / (speed * (q->r.cores > 0 ? q->r.cores : 1.0));
}

/* Arms the request's phase timer; earlier phase timers become stale. */
static void arm(bgm_purchase_t *pu, req_t *q, double at)
{
    q->r.tseq++;
    bgm_emitter_timer(&pu->em, at, BGM_PU_TIMER_REQ,
                      (uint64_t)q->r.id | ((uint64_t)q->r.tseq << 32));
}

/* The request has just sent a message that one agent answers (a QUERY to
 * the directory: floor `floor`; an ORDER, OFFER or a bundle's ACCEPT to a
 * seller: the configured reply timeout): the phase timer allows the
 * owner's estimated round trip for it. */
static void await_answer(bgm_purchase_t *pu, req_t *q, double now, double floor)
{
    ng(pu, q)->sent_at = now;
    arm(pu, q, now + rtt_timeout(&pu->reply, floor));
}

static void await_reply(bgm_purchase_t *pu, req_t *q, double now)
{
    await_answer(pu, q, now, pu->cfg->catallactic.reply_timeout);
}

/* The awaited answer came: one round-trip sample (Karn's rule: only an
 * answer to the message awaited now, once). Central's answers come from
 * a clearing, not a round trip, and are not sampled. */
static void answered(bgm_purchase_t *pu, req_t *q, double now)
{
    if (q->nego == PU_NEGO_NONE)
        return;
    nego_state_t *g = ng(pu, q);
    if (g->sent_at >= 0.0)
        rtt_sample(&pu->reply, now - g->sent_at);
    g->sent_at = -1.0;
}

/* Sends a call to its neighbours but `except` and the call's originator,
 * within the overlay's fan-out (bgm_flood); how many it sent. */
static uint32_t cfp_send(bgm_purchase_t *pu, const bgm_msg_t *proto, uint32_t except)
{
    return bgm_flood_pass(&pu->em, proto, pu->nbr, pu->p.degree, except,
                          pu->cfg->agents.overlay_degree);
}

static void start_acquire(bgm_purchase_t *pu, req_t *q, double now, int up)
{
    const bgm_purchase_req_t *r = &q->r;
    const int bundle = is_bundle(q);
    if (!up) {
        final_fail(pu, q);
        return;
    }
    pu->tally.attempts += 1.0;
    q->rounds++;
    if (pu->p.mechanism != BGM_MECH_CENTRAL) {
        if (!nego_take(pu, q)) {
            bgm_emitter_fail(&pu->em, BG_ERR_NOMEM);
            return;
        }
        nego_state_t *g = ng(pu, q);
        g->nprop = g->next_prop = 0;
        g->sent_at = -1.0;
    }
    switch (pu->p.mechanism) {
    case BGM_MECH_CENTRAL: {
        bgm_msg_t m =
            msg(bundle ? BGM_MT_RBID : BGM_MT_BID, pu->p.self, pu->p.market, r->id, r->attempt);
        m.good = (int16_t)r->good;
        m.price = r->limit;
        m.a = bundle ? r->cores : r->work;
        m.b = bundle ? r->memory : r->deadline;
        m.c = bundle ? r->flops : 0.0;
        m.cand_price[0] = r->deadline;
        q->r.state = BGM_PU_WAIT;
        bgm_emitter_send(&pu->em, &m);
        break;
    }
    case BGM_MECH_CATALLACTIC: {
        bgm_msg_t m = msg(BGM_MT_CFP, pu->p.self, 0, r->id, r->attempt);
        m.good = (int16_t)r->good;
        m.hops = (uint16_t)pu->cfg->catallactic.hops;
        m.origin = pu->p.self;
        m.a = bundle ? r->cores : r->work;
        m.b = r->memory;
        m.c = r->flops;
        q->r.state = BGM_PU_DISCOVER;
        q->calls = cfp_send(pu, &m, UINT32_MAX);
        nego_state_t *g = ng(pu, q);
        g->cfp_at = now;
        g->cfp_attempt = r->attempt;
        /* The window lasts as long as proposals have been taking to come
         * back after a round's calls (never less than the configured one),
         * widened after quiet rounds where the host asks for it. */
        const uint32_t doublings =
            q->quiet < (uint32_t)pu->p.widen_quiet ? q->quiet : (uint32_t)pu->p.widen_quiet;
        arm(pu, q,
            now + rtt_timeout(&pu->discovery, pu->cfg->catallactic.discovery_timeout) *
                      (double)(1u << doublings));
        break;
    }
    default: {
        bgm_msg_t m = msg(BGM_MT_QUERY, pu->p.self, pu->p.market, r->id, r->attempt);
        m.good = (int16_t)(bundle ? PU_GOOD_CORES : r->good);
        m.price = bundle ? INFINITY : r->limit;
        m.a = r->cores;
        m.b = r->memory;
        q->r.state = BGM_PU_WAIT;
        bgm_emitter_send(&pu->em, &m);
        await_answer(pu, q, now, 4.0 * pu->cfg->catallactic.reply_timeout);
        break;
    }
    }
}

bg_status bgm_purchase_open(bgm_purchase_t *pu, const bgm_purchase_req_t *it, double now, int up,
                            bgm_outbox_t *out, bgm_purchase_event_t *ev)
{
    begin(pu, out, ev);
    if (pu->nreq > 0 && it->id <= pu->reqs[pu->nreq - 1].r.id)
        bgm_emitter_fail(&pu->em, BG_ERR_INVALID);
    else if (pu->nreq == pu->req_cap) {
        size_t n = pu->req_cap ? pu->req_cap * 2 : 8;
        req_t *p = n <= BGM_PU_MAX_REQS ? realloc(pu->reqs, n * sizeof *p) : NULL;
        if (!p)
            bgm_emitter_fail(&pu->em, n <= BGM_PU_MAX_REQS ? BG_ERR_NOMEM : BG_ERR_LIMIT);
        else {
            pu->reqs = p;
            pu->req_cap = n;
        }
    }
    if (pu->em.failure)
        return finish(pu);
    req_t *q = &pu->reqs[pu->nreq++];
    memset(q, 0, sizeof *q);
    q->nego = PU_NEGO_NONE;
    q->r.id = it->id;
    q->r.good = it->good;
    q->r.work = it->work;
    q->r.cores = it->cores;
    q->r.memory = it->memory;
    q->r.flops = it->flops;
    q->r.limit = it->limit;
    q->r.created = it->created;
    q->r.deadline = it->deadline;
    q->r.deal = it->deal;
    q->r.state = BGM_PU_IDLE;
    pu->tally.requests += 1.0;
    bgm_emitter_timer(&pu->em, q->r.deadline, BGM_PU_TIMER_DEADLINE, q->r.id);
    start_acquire(pu, q, now, up);
    return finish(pu);
}

/* The limit the buyer bargains to with a proposal: its valuation per
 * unit for a service; for a bundle, its budget over the proposer's run
 * time, as a rate. */
static double buyer_limit_for(const req_t *q, const proposal_t *p)
{
    if (!is_bundle(q))
        return q->r.limit;
    return q->r.limit / req_duration(q, p->speed);
}

/* What a seller reads of the request in a buyer's OFFER, ACCEPT or
 * ORDER: the good (a bundle: < 0), the work or the bundle, the budget (a
 * resource seller checks the rent against it) and how long the buyer's
 * offer stands: until its deadline, when the buyer gives up bargaining. */
static void request_fields(const req_t *q, bgm_msg_t *m)
{
    m->good = (int16_t)q->r.good;
    m->a = is_bundle(q) ? q->r.cores : q->r.work;
    m->b = q->r.memory;
    m->c = q->r.flops;
    m->cand_price[1] = q->r.limit;
    m->cand_price[2] = q->r.deadline;
}

static void begin_nego(bgm_purchase_t *pu, req_t *q, double now)
{
    nego_state_t *g = ng(pu, q);
    while (g->next_prop < g->nprop) {
        const proposal_t *p = &g->prop[g->next_prop];
        double lim = buyer_limit_for(q, p);
        double mem = !is_bundle(q) ? pu->tr.memory[q->r.good]
                                   : pu->tr.memory[3] * mean_rate(pu, q->r.cores, q->r.memory);
        bgm_msg_t o;
        if (pu->p.mechanism == BGM_MECH_BASELINE) {
            if (p->price > lim) {
                g->next_prop++;
                continue;
            }
            o = msg(BGM_MT_ORDER, pu->p.self, p->seller, q->r.id, q->r.attempt);
            o.price = p->price;
            request_fields(q, &o);
        } else {
            bgm_nego_open(&g->buyer_nego, BGM_SIDE_BUYER, lim,
                          bgm_nego_opening(BGM_SIDE_BUYER, lim, mem, pu->tr.markup), &pu->tr.genes,
                          pu->cfg->catallactic.max_rounds);
            o = msg(BGM_MT_OFFER, pu->p.self, p->seller, q->r.id, q->r.attempt);
            o.price = g->buyer_nego.current;
            o.hops = 1; /* opens a bargain: the seller starts afresh */
            request_fields(q, &o);
        }
        q->r.seller = p->seller;
        q->r.state = BGM_PU_NEGOTIATE;
        bgm_emitter_send(&pu->em, &o);
        await_reply(pu, q, now);
        return;
    }
    attempt_failed(pu, q, now);
}

static void next_proposal(bgm_purchase_t *pu, req_t *q, double now)
{
    ng(pu, q)->next_prop++;
    begin_nego(pu, q, now);
}

static int cmp_prop(const void *pa, const void *pb)
{
    const proposal_t *a = pa, *b = pb;
    if (a->price != b->price)
        return a->price < b->price ? -1 : 1;
    return (a->seller > b->seller) - (a->seller < b->seller);
}

/* The discovery window closes: bargain with the proposers, cheapest
 * first (a round nobody answered counts as quiet). */
static void end_discovery(bgm_purchase_t *pu, req_t *q, double now)
{
    nego_state_t *g = ng(pu, q);
    if (g->nprop == 0) {
        timed_out(pu, BGM_PU_TO_DISCOVERY); /* nobody answered the call for proposals */
        q->quiet++;
    }
    qsort(g->prop, (size_t)g->nprop, sizeof g->prop[0], cmp_prop);
    g->next_prop = 0;
    begin_nego(pu, q, now);
}

static void on_offer(bgm_purchase_t *pu, req_t *q, const bgm_msg_t *m, double now)
{
    if (m->attempt != q->r.attempt || q->r.state != BGM_PU_NEGOTIATE || m->from != q->r.seller)
        return;
    answered(pu, q, now);
    double reply = 0.0;
    bgm_nego_action act = bgm_nego_respond(&ng(pu, q)->buyer_nego, m->price, &pu->tr.rng, &reply);
    if (act == BGM_NEGO_ACCEPT) {
        bgm_msg_t a = msg(BGM_MT_ACCEPT, pu->p.self, m->from, m->req, m->attempt);
        a.price = reply;
        request_fields(q, &a);
        q->r.state = BGM_PU_COMMITTED;
        q->r.price = reply;
        bgm_emitter_send(&pu->em, &a);
        /* A bundle seller answers at once. A service seller commits as
         * soon as it reads the acceptance and starts buying resources, so
         * the buyer must not walk away on a phase timeout any more: it
         * waits for the seller's answer, and the deadline covers the rest. */
        if (is_bundle(q)) {
            await_reply(pu, q, now);
        } else {
            q->r.tseq++;
            ng(pu, q)->sent_at = now; /* its answer is still a round trip */
        }
    } else if (act == BGM_NEGO_COUNTER) {
        bgm_msg_t o = msg(BGM_MT_OFFER, pu->p.self, m->from, m->req, m->attempt);
        o.price = reply;
        request_fields(q, &o);
        bgm_emitter_send(&pu->em, &o);
        await_reply(pu, q, now);
    } else {
        bgm_msg_t x = msg(BGM_MT_REJECT, pu->p.self, m->from, m->req, m->attempt);
        bgm_emitter_send(&pu->em, &x);
        next_proposal(pu, q, now);
    }
}

static void on_committed(bgm_purchase_t *pu, req_t *q, const bgm_msg_t *m, double now)
{
    if (m->attempt != q->r.attempt)
        return;
    int s = q->r.state;
    if (s == BGM_PU_NEGOTIATE || s == BGM_PU_COMMITTED)
        answered(pu, q, now);
    if (s == BGM_PU_NEGOTIATE || s == BGM_PU_WAIT || s == BGM_PU_COMMITTED) {
        q->r.state = BGM_PU_COMMITTED;
        q->r.price = m->price;
        q->r.tseq++; /* no phase timeout while committed: the deadline rules */
    }
}

static double parts_money(const bgm_purchase_t *pu, uint32_t id)
{
    double total = 0.0;
    for (size_t i = 0; i < pu->nparts; i++)
        if (pu->parts[i].req == id)
            total +=
                pu->parts[i].rate * pu->parts[i].quantity * (pu->parts[i].end - pu->parts[i].start);
    return total;
}

/* The bundle, or one part of it (call markets), is rented. A bundle
 * bought in parts is rented once every part is: it runs from the first
 * part's start to the last part's end. */
static void on_rconfirm(bgm_purchase_t *pu, req_t *q, const bgm_msg_t *m, double now)
{
    /* A late confirm after giving up: nobody pays for it; its seller
     * held it for nothing. */
    if (ended(q))
        return;
    if (m->good == BGM_GOOD_CORES_ID || m->good == BGM_GOOD_MEMORY_ID) {
        if (pu->nparts == pu->parts_cap) {
            size_t cap = pu->parts_cap ? 2 * pu->parts_cap : 8;
            bgm_purchase_part_t *p =
                cap <= BGM_PU_MAX_PARTS ? realloc(pu->parts, cap * sizeof *p) : NULL;
            if (!p) {
                bgm_emitter_fail(&pu->em, cap <= BGM_PU_MAX_PARTS ? BG_ERR_NOMEM : BG_ERR_LIMIT);
                return;
            }
            pu->parts = p;
            pu->parts_cap = cap;
        }
        pu->parts[pu->nparts++] =
            (bgm_purchase_part_t){m->req, m->from,  m->good,          m->cand_price[0], m->a,
                                  m->b,   m->price, m->cand_price[1], m->cand_price[2]};
        q->r.start = q->r.parts == 0 ? m->a : fmin(q->r.start, m->a);
        q->r.end = q->r.parts == 0 ? m->b : fmax(q->r.end, m->b);
        if (++q->r.parts < m->hops)
            return;
        /* Every part was held from before the common start; the service
         * can run from it only if the bundle is complete by then. A later
         * bundle is void for its sellers (unpaid) and fails. */
        if (now > q->r.start) {
            bgm_purchase_drop_parts(pu, q->r.id);
            final_fail(pu, q);
            return;
        }
        req_end(pu, q, BGM_PU_DONE);
        q->r.seller = m->from;
        q->r.price = parts_money(pu, q->r.id) / (q->r.end - q->r.start);
        event(pu, BGM_PU_EV_RENTED, q->r.id);
        return;
    }
    if (m->attempt == q->r.attempt && m->from == q->r.seller &&
        (q->r.state == BGM_PU_NEGOTIATE || q->r.state == BGM_PU_COMMITTED))
        answered(pu, q, now); /* a rent answers an ORDER or an ACCEPT at once */
    req_end(pu, q, BGM_PU_DONE);
    q->r.seller = m->from;
    q->r.price = m->price;
    q->r.start = m->a;
    q->r.end = m->b;
    event(pu, BGM_PU_EV_RENTED, q->r.id);
}

bg_status bgm_purchase_on_message(bgm_purchase_t *pu, const bgm_msg_t *m, double now,
                                  bgm_outbox_t *out, bgm_purchase_event_t *ev)
{
    begin(pu, out, ev);
    req_t *q = find(pu, m->req);
    if (!q)
        return finish(pu);
    switch (m->type) {
    case BGM_MT_PROPOSE:
        /* Every proposal to a round's calls is a sample of how long
         * proposals take, a late one (after the window) too. */
        if (q->nego != PU_NEGO_NONE && m->attempt == ng(pu, q)->cfp_attempt)
            rtt_sample(&pu->discovery, now - ng(pu, q)->cfp_at);
        if (m->attempt == q->r.attempt && q->r.state == BGM_PU_DISCOVER) {
            nego_state_t *g = ng(pu, q);
            if (g->nprop < BGM_PU_MAX_PROPOSALS)
                g->prop[g->nprop++] = (proposal_t){m->from, m->price, m->a};
            if (pu->p.close_when_heard && q->calls > 0 && (uint32_t)g->nprop >= q->calls)
                end_discovery(pu, q, now);
        }
        break;
    case BGM_MT_LIST:
        if (m->attempt == q->r.attempt && q->r.state == BGM_PU_WAIT) {
            answered(pu, q, now);
            nego_state_t *g = ng(pu, q);
            g->nprop = m->ncand;
            for (int i = 0; i < m->ncand; i++)
                g->prop[i] = (proposal_t){m->cand[i], m->cand_price[i], m->cand_speed[i]};
            g->next_prop = 0;
            begin_nego(pu, q, now);
        }
        break;
    case BGM_MT_OFFER:
        on_offer(pu, q, m, now);
        break;
    case BGM_MT_ACCEPT:
        on_committed(pu, q, m, now);
        break;
    case BGM_MT_REJECT:
        if (m->attempt == q->r.attempt && m->from == q->r.seller &&
            (q->r.state == BGM_PU_NEGOTIATE || q->r.state == BGM_PU_COMMITTED)) {
            answered(pu, q, now);
            next_proposal(pu, q, now);
        }
        break;
    case BGM_MT_CANCEL:
        if (m->attempt == q->r.attempt && q->r.state == BGM_PU_COMMITTED)
            attempt_failed(pu, q, now);
        break;
    case BGM_MT_RFAIL:
        final_fail(pu, q);
        break;
    case BGM_MT_RCONFIRM:
        on_rconfirm(pu, q, m, now);
        break;
    default:
        bgm_emitter_fail(&pu->em, BG_ERR_INVALID);
        break;
    }
    return finish(pu);
}

bg_status bgm_purchase_on_timer(bgm_purchase_t *pu, int kind, uint64_t arg, double now, int up,
                                bgm_outbox_t *out, bgm_purchase_event_t *ev)
{
    begin(pu, out, ev);
    uint32_t id = (uint32_t)(arg & 0xffffffffu);
    uint32_t hi = (uint32_t)(arg >> 32);
    switch (kind) {
    case BGM_PU_TIMER_REQ: {
        req_t *q = find(pu, id);
        if (!q || hi != q->r.tseq || ended(q))
            break;
        if (!up) {
            final_fail(pu, q);
        } else if (q->r.state == BGM_PU_DISCOVER) {
            end_discovery(pu, q, now);
        } else if (q->r.state == BGM_PU_NEGOTIATE || q->r.state == BGM_PU_COMMITTED) {
            timed_out(pu, BGM_PU_TO_REPLY);
            rtt_backoff(&pu->reply);
            q->r.state = BGM_PU_NEGOTIATE;
            q->r.attempt++; /* late answers from that seller are now stale */
            next_proposal(pu, q, now);
        } else if (q->r.state == BGM_PU_WAIT) {
            timed_out(pu, BGM_PU_TO_DIRECTORY);
            rtt_backoff(&pu->reply);
            attempt_failed(pu, q, now);
        }
        break;
    }
    case BGM_PU_TIMER_DEADLINE: {
        int grace = (arg >> 63) != 0;
        req_t *q = find(pu, (uint32_t)(arg & 0x7fffffffffffffffULL));
        if (!q || ended(q))
            break;
        if (q->r.state == BGM_PU_COMMITTED && !grace && up) {
            bgm_emitter_timer(&pu->em, now + BGM_PU_COMMIT_GRACE, BGM_PU_TIMER_DEADLINE,
                              (uint64_t)q->r.id | (1ULL << 63));
            break;
        }
        timed_out(pu, BGM_PU_TO_DEADLINE);
        q->r.attempt++;
        final_fail(pu, q);
        break;
    }
    case BGM_PU_TIMER_RETRY: {
        req_t *q = find(pu, id);
        if (q && hi == q->r.attempt && q->r.state == BGM_PU_IDLE)
            start_acquire(pu, q, now, up);
        break;
    }
    case BGM_PU_TIMER_LEARN: {
        if (up && pu->p.degree > 0) {
            uint32_t k = bgm_rng_below(&pu->tr.rng, (uint32_t)pu->p.degree);
            if (pu->same[k]) {
                bgm_msg_t m = msg(BGM_MT_GENES, pu->p.self, pu->nbr[k], 0, 0);
                double g[BGM_GENE_COUNT];
                bgm_genes_pack(&pu->tr.genes, g);
                memcpy(m.cand_price, g, sizeof g);
                m.price = pu->tr.fitness;
                m.a = 1.0;
                bgm_emitter_send(&pu->em, &m);
            }
        }
        double t =
            now + pu->cfg->catallactic.learning_period * (0.5 + bgm_rng_uniform(&pu->tr.rng));
        if (t < pu->p.horizon)
            bgm_emitter_timer(&pu->em, t, BGM_PU_TIMER_LEARN, 0);
        break;
    }
    default:
        bgm_emitter_fail(&pu->em, BG_ERR_INVALID);
        break;
    }
    return finish(pu);
}

/* ------------------------------------------------------------ the overlay */

int bgm_purchase_cfp_seen(bgm_purchase_t *pu, const bgm_msg_t *m)
{
    return bgm_flood_seen(&pu->seen, bgm_flood_key(m));
}

bg_status bgm_purchase_cfp_forward(bgm_purchase_t *pu, const bgm_msg_t *m, bgm_outbox_t *out)
{
    bgm_purchase_event_t ev;
    begin(pu, out, &ev);
    if (m->hops > 1) {
        bgm_msg_t f = *m;
        f.hops--;
        cfp_send(pu, &f, m->from);
    }
    return finish(pu);
}

bg_status bgm_purchase_learning_start(bgm_purchase_t *pu, double now, bgm_outbox_t *out)
{
    bgm_purchase_event_t ev;
    begin(pu, out, &ev);
    bgm_emitter_timer(&pu->em,
                      now + pu->cfg->catallactic.learning_period * bgm_rng_uniform(&pu->tr.rng),
                      BGM_PU_TIMER_LEARN, 0);
    return finish(pu);
}

/* A learning meeting: it learns only from an overlay neighbour of its
 * owner's role, which it was told when its links were made; asked, it
 * answers with its own genes first. */
bg_status bgm_purchase_on_genes(bgm_purchase_t *pu, const bgm_msg_t *m, bgm_outbox_t *out)
{
    bgm_purchase_event_t ev;
    begin(pu, out, &ev);
    int same = 0;
    for (int i = 0; i < pu->p.degree; i++)
        same |= pu->nbr[i] == m->from && pu->same[i];
    if (!same)
        return finish(pu);
    if (m->a > 0.0) {
        bgm_msg_t r = msg(BGM_MT_GENES, pu->p.self, m->from, 0, 0);
        double g[BGM_GENE_COUNT];
        bgm_genes_pack(&pu->tr.genes, g);
        memcpy(r.cand_price, g, sizeof g);
        r.price = pu->tr.fitness;
        bgm_emitter_send(&pu->em, &r);
    }
    bgm_genes_t other;
    double g[BGM_GENE_COUNT];
    memcpy(g, m->cand_price, sizeof g);
    bgm_genes_unpack(&other, g);
    bgm_learning_t lp = {pu->cfg->catallactic.imitation, pu->cfg->catallactic.mutation,
                         pu->cfg->catallactic.mutation_sigma};
    bgm_genes_learn(&pu->tr.genes, pu->tr.fitness, &other, m->price, &lp, &pu->tr.rng);
    return finish(pu);
}
