#include "bgm_buyer.h"

#include <stdlib.h>

struct bgm_buyer {
    bgm_config_t cfg;
    bgm_buyer_params_t p;
    bgm_purchase_t *pu; /* its buying half, and its trader state */
    bgm_rng_t demand;
    uint32_t jobs;
    double requested[BGM_SERVICE_TYPES], valuation_sum[BGM_SERVICE_TYPES];
    bgm_emitter_t em; /* during a call: its outbox and first failure */
};

bgm_buyer_t *bgm_buyer_new(const bgm_buyer_params_t *p)
{
    if (p->degree < 0 || p->degree > BGM_PU_MAX_NEIGHBOURS)
        return NULL;
    bgm_buyer_t *b = calloc(1, sizeof *b);
    if (!b)
        return NULL;
    b->em.self = p->self;
    b->cfg = *p->cfg;
    b->p = *p;
    b->p.cfg = &b->cfg;
    b->p.neighbours = NULL;
    b->p.same_role = NULL;
    b->demand = p->demand;
    bgm_trader_t tr = {p->rng, p->genes, 0.0, p->markup, {0.0, 0.0, 0.0, 0.0}};
    bgm_purchase_params_t pp = {&b->cfg, p->mechanism,  p->self,      p->market, p->horizon,
                                tr,      p->neighbours, p->same_role, p->degree, 0, 0};
    if (!(b->pu = bgm_purchase_new(&pp))) {
        free(b);
        return NULL;
    }
    return b;
}

void bgm_buyer_destroy(bgm_buyer_t **pb)
{
    if (!pb || !*pb)
        return;
    bgm_purchase_destroy(&(*pb)->pu);
    free(*pb);
    *pb = NULL;
}

const bgm_purchase_req_t *bgm_buyer_request(bgm_buyer_t *b, uint32_t id)
{
    return bgm_purchase_get(b->pu, id);
}

uint32_t bgm_buyer_jobs(const bgm_buyer_t *b)
{
    return b->jobs;
}

void bgm_buyer_demand(const bgm_buyer_t *b, int good, double *requested, double *valuation_sum)
{
    *requested = b->requested[good];
    *valuation_sum = b->valuation_sum[good];
}

void bgm_buyer_counts(const bgm_buyer_t *b, bgm_purchase_tally_t *t)
{
    bgm_purchase_counts(b->pu, t);
}

static double next_arrival(bgm_buyer_t *b, double now)
{
    double mean = b->cfg.demand.interarrival_mean;
    if (b->cfg.demand.shock_time >= 0.0 && now >= b->cfg.demand.shock_time)
        mean /= b->cfg.demand.shock_factor;
    return now + bgm_rng_exponential(&b->demand, mean);
}

/* A job arrives: it draws the job's plan and opens one request per
 * service type of it, each with its work, valuation and deadline. */
static void new_job(bgm_buyer_t *b, double now, uint32_t *next_req)
{
    const bgm_config_t *cfg = &b->cfg;
    b->jobs++;
    double total = 0.0;
    for (int i = 0; i < cfg->demand.plan_count; i++)
        total += cfg->demand.plans[i].weight;
    double u = bgm_rng_uniform(&b->demand) * total;
    int plan = 0;
    while (plan < cfg->demand.plan_count - 1 && u >= cfg->demand.plans[plan].weight)
        u -= cfg->demand.plans[plan++].weight;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        if (!cfg->demand.plans[plan].services[t])
            continue;
        if (*next_req >= BGM_PU_MAX_REQS) {
            bgm_emitter_fail(&b->em, BG_ERR_LIMIT);
            return;
        }
        bgm_purchase_req_t it = {0};
        it.id = (*next_req)++;
        it.good = t;
        int span = cfg->demand.work_max - cfg->demand.work_min + 1;
        it.work = cfg->demand.work_min + (int)bgm_rng_below(&b->demand, (uint32_t)span);
        it.limit = cfg->demand.valuation_mean *
                   (1.0 + cfg->demand.valuation_spread * (2.0 * bgm_rng_uniform(&b->demand) - 1.0));
        it.created = now;
        it.deadline = now + cfg->demand.deadline;
        b->requested[t] += 1.0;
        b->valuation_sum[t] += it.limit;
        bgm_purchase_event_t ev;
        bgm_emitter_fail(&b->em, bgm_purchase_open(b->pu, &it, now, 1, b->em.out, &ev));
    }
}

/* A delivery of its request m->req: it takes it, once, if it still wants
 * the item from that seller on that attempt (it has not bought it
 * already, has not given up on it, and has not moved on to another
 * attempt or, bargaining, another seller), and refuses it otherwise. A
 * service whose run has already ended serves nothing. */
static void on_delivery(bgm_buyer_t *b, const bgm_msg_t *m, double now)
{
    bgm_purchase_req_t *r = bgm_purchase_get(b->pu, m->req);
    if (!r)
        return;
    int wanted = r->state != BGM_PU_DONE && r->state != BGM_PU_FAILED && m->attempt == r->attempt &&
                 (b->p.mechanism == BGM_MECH_CENTRAL || r->seller == m->from) && m->b > now;
    bgm_msg_t x = bgm_outbox_msg(wanted ? BGM_MT_TAKE : BGM_MT_REFUSE, b->p.self, m->from, m->req,
                                 m->attempt);
    x.origin = m->origin;
    if (wanted) {
        r->seller = m->from;
        r->price = m->price;
        r->start = m->a;
        r->end = m->b;
        bgm_purchase_done(b->pu, m->req);
        bgm_trader_t *tr = bgm_purchase_trader(b->pu);
        tr->memory[r->good] =
            bgm_memory_update(tr->memory[r->good], m->price, tr->genes.weight_memory);
        bgm_purchase_learn(b->pu, 1, (r->limit - m->price) / r->limit);
    }
    bgm_emitter_send(&b->em, &x);
}

bg_status bgm_buyer_start(bgm_buyer_t *b, double now, bgm_outbox_t *out)
{
    bgm_emitter_begin(&b->em, out);
    bgm_emitter_timer(&b->em, next_arrival(b, now), BGM_BU_TIMER_ARRIVAL, 0);
    if (b->p.mechanism == BGM_MECH_CATALLACTIC)
        bgm_emitter_fail(&b->em, bgm_purchase_learning_start(b->pu, now, out));
    return b->em.failure;
}

bg_status bgm_buyer_on_message(bgm_buyer_t *b, const bgm_msg_t *m, double now, int up,
                               bgm_outbox_t *out)
{
    (void)up; /* a lost message never reaches it; what it buys next checks its host */
    bgm_emitter_begin(&b->em, out);
    bgm_purchase_event_t ev;
    switch (m->type) {
    case BGM_MT_CONFIRM:
        on_delivery(b, m, now);
        break;
    case BGM_MT_CFP:
        /* It sells nothing: it only passes the call on. */
        if (!bgm_purchase_cfp_seen(b->pu, m))
            bgm_emitter_fail(&b->em, bgm_purchase_cfp_forward(b->pu, m, out));
        break;
    case BGM_MT_GENES:
        bgm_emitter_fail(&b->em, bgm_purchase_on_genes(b->pu, m, out));
        break;
    case BGM_MT_PROPOSE:
    case BGM_MT_LIST:
    case BGM_MT_OFFER:
    case BGM_MT_ACCEPT:
    case BGM_MT_REJECT:
    case BGM_MT_CANCEL:
    case BGM_MT_RFAIL:
    case BGM_MT_RCONFIRM:
        bgm_emitter_fail(&b->em, bgm_purchase_on_message(b->pu, m, now, out, &ev));
        break;
    case BGM_MT_TAKE:
    case BGM_MT_REFUSE:
    case BGM_MT_ORDER:
    case BGM_MT_MATCH:
        break; /* for a seller */
    default:
        bgm_emitter_fail(&b->em, BG_ERR_INVALID);
        break;
    }
    return b->em.failure;
}

bg_status bgm_buyer_on_timer(bgm_buyer_t *b, int kind, uint64_t arg, double now, int up,
                             uint32_t *next_req, bgm_outbox_t *out)
{
    bgm_emitter_begin(&b->em, out);
    if (kind == BGM_BU_TIMER_ARRIVAL) {
        if (up)
            new_job(b, now, next_req);
        double t = next_arrival(b, now);
        if (t < b->p.arrival_end)
            bgm_emitter_timer(&b->em, t, BGM_BU_TIMER_ARRIVAL, 0);
        return b->em.failure;
    }
    bgm_purchase_event_t ev;
    bgm_emitter_fail(&b->em, bgm_purchase_on_timer(b->pu, kind, arg, now, up, out, &ev));
    return b->em.failure;
}
