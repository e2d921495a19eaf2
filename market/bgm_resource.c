#include "bgm_resource.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_catallactic.h"
#include "bgm_flood.h"
#include "bgm_session.h"

#define RS_SESSIONS 32
#define RS_MAX_HOLDS 4096
/* Quantities of a part travel in a timer argument as whole MiB. */
#define RS_MIB 1024.0

/* A bundle held until its end (the release timer names its request), and
 * the job and phase it serves (share_phases; group 0: it counts alone). */
typedef struct hold {
    uint32_t req, group;
    int phase;
    double cores, memory;
} hold_t;

struct bgm_resource {
    bgm_config_t cfg;
    bgm_resource_params_t p;
    uint32_t nbr[BGM_RS_MAX_NEIGHBOURS];
    uint8_t same[BGM_RS_MAX_NEIGHBOURS];
    double used_cores, used_mem;
    double fitness, markup, memory; /* remembered price over mean cost rate */
    bgm_rng_t rng;
    bgm_genes_t genes;
    bgm_flood_seen_t seen; /* calls for proposals seen */
    bgm_sessions_t *sess; /* its side of every bargain */
    hold_t *holds;
    size_t nholds, holds_cap;
    bgm_emitter_t em; /* during a call: its outbox and first failure */
    int fixed;        /* bgm_resource_fix_strategy: no learning from outcomes */
};

/* Messages start from a zeroed body with their header set. */
static bgm_msg_t msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    return bgm_outbox_msg(type, from, to, req, attempt);
}

bgm_resource_t *bgm_resource_new(const bgm_resource_params_t *p)
{
    if (p->degree < 0 || p->degree > BGM_RS_MAX_NEIGHBOURS)
        return NULL;
    bgm_resource_t *rs = calloc(1, sizeof *rs);
    if (!rs)
        return NULL;
    rs->em.self = p->self;
    if (!(rs->sess = bgm_sessions_new(RS_SESSIONS))) {
        free(rs);
        return NULL;
    }
    rs->cfg = *p->cfg;
    rs->p = *p;
    rs->p.cfg = &rs->cfg;
    for (int i = 0; i < p->degree; i++) {
        rs->nbr[i] = p->neighbours[i];
        rs->same[i] = p->same_role[i];
    }
    rs->p.neighbours = NULL;
    rs->p.same_role = NULL;
    rs->rng = p->rng;
    rs->genes = p->genes;
    rs->markup = p->markup;
    return rs;
}

void bgm_resource_destroy(bgm_resource_t **prs)
{
    if (!prs || !*prs)
        return;
    free((*prs)->holds);
    bgm_sessions_destroy(&(*prs)->sess);
    free(*prs);
    *prs = NULL;
}

void bgm_resource_used(const bgm_resource_t *rs, double *cores, double *memory)
{
    *cores = rs->used_cores;
    *memory = rs->used_mem;
}

bg_status bgm_resource_set_neighbours(bgm_resource_t *rs, const uint32_t *neighbours,
                                      const uint8_t *same_role, int degree)
{
    if (degree < 0 || degree > BGM_RS_MAX_NEIGHBOURS)
        return BG_ERR_INVALID;
    for (int i = 0; i < degree; i++) {
        rs->nbr[i] = neighbours[i];
        rs->same[i] = same_role[i];
    }
    rs->p.degree = degree;
    return BG_OK;
}

double bgm_resource_asking(const bgm_resource_t *rs, int good, double load_slope)
{
    const int cores = good == BGM_GOOD_CORES_ID;
    if (!cores && good != BGM_GOOD_MEMORY_ID)
        return 0.0;
    const double cap = cores ? rs->p.cores : rs->p.memory;
    const double held = cores ? rs->used_cores : rs->used_mem;
    const double cost = cores ? rs->p.core_cost : rs->p.memory_cost;
    return cost * (1.0 + rs->markup) * (1.0 + (cap > 0.0 ? load_slope * held / cap : 0.0));
}

void bgm_resource_fix_strategy(bgm_resource_t *rs)
{
    rs->fixed = 1;
}

static void learn(bgm_resource_t *rs, int success, double share)
{
    if (!rs->fixed)
        bgm_outcome_learn(&rs->genes, &rs->fitness, &rs->markup, success, share);
}

static double cost_rate(const bgm_resource_t *rs, double cores, double mem)
{
    return rs->p.core_cost * cores + rs->p.memory_cost * mem;
}

/* Normaliser for remembered resource prices: the mean cost rate. */
static double mean_rate(const bgm_resource_t *rs, double cores, double mem)
{
    return rs->cfg.resources.core_cost * cores + rs->cfg.resources.memory_cost * mem;
}

/* Baseline: the directory learns its free capacity whenever it changes. */
static void announce(bgm_resource_t *rs)
{
    if (rs->p.mechanism != BGM_MECH_BASELINE)
        return;
    bgm_msg_t m = msg(BGM_MT_AVAIL, rs->p.self, rs->p.market, 0, 0);
    m.a = rs->p.cores - rs->used_cores;
    m.b = rs->p.memory - rs->used_mem;
    bgm_emitter_send(&rs->em, &m);
}

/* The job a bundle serves and its phase, when the seller shares cores
 * between a job's phases and the message names them (0: it counts alone). */
static uint32_t bundle_group(const bgm_resource_t *rs, const bgm_msg_t *m, int *phase)
{
    *phase = 0;
    if (!rs->p.share_phases || m->ncand < 2 || m->cand[0] == 0 || m->cand[1] >= BGM_RS_PHASES)
        return 0;
    *phase = (int)m->cand[1];
    return m->cand[0];
}

/* The cores job `group` occupies: the most any one of its phases holds
 * (its phases never run at once); `sum` gets each phase's total. */
static double group_cores(const bgm_resource_t *rs, uint32_t group, double sum[BGM_RS_PHASES])
{
    for (int p = 0; p < BGM_RS_PHASES; p++)
        sum[p] = 0.0;
    for (size_t i = 0; i < rs->nholds; i++)
        if (rs->holds[i].group == group)
            sum[rs->holds[i].phase] += rs->holds[i].cores;
    double most = 0.0;
    for (int p = 0; p < BGM_RS_PHASES; p++)
        if (sum[p] > most)
            most = sum[p];
    return most;
}

/* The cores a bundle adds to what is sold: all of them, or, for a phase
 * of a job, what the phase would hold beyond the job's widest phase. */
static double cores_added(const bgm_resource_t *rs, uint32_t group, int phase, double cores)
{
    if (!group)
        return cores;
    double sum[BGM_RS_PHASES];
    const double most = group_cores(rs, group, sum);
    return sum[phase] + cores > most ? sum[phase] + cores - most : 0.0;
}

double bgm_resource_cores_added(const bgm_resource_t *rs, uint32_t group, int phase, double cores)
{
    if (!rs->p.share_phases || phase < 0 || phase >= BGM_RS_PHASES)
        return cores;
    return cores_added(rs, group, phase, cores);
}

/*
 * Rents a whole bundle (m->a cores, m->b GiB for m->c flops) at `rate`
 * per second to `buyer` for its request m->req: it checks that its host
 * is up, that it has the room now (every rental starts when agreed), that
 * the rate covers its cost and stays within the buyer's budget; it holds
 * the bundle until the run ends and confirms. It is paid when the buyer
 * takes delivery. Returns 0 when it cannot.
 */
static int rent(bgm_resource_t *rs, const bgm_msg_t *m, uint32_t buyer, double rate, double now,
                int up)
{
    double cores = m->a, mem = m->b, budget = m->cand_price[1];
    int phase;
    const uint32_t group = bundle_group(rs, m, &phase);
    const double added = cores_added(rs, group, phase, cores);
    if (!up || rs->used_cores + added > rs->p.cores + 1e-9 ||
        rs->used_mem + mem > rs->p.memory + 1e-9)
        return 0;
    double dur = m->c / (rs->p.speed * (cores > 0 ? cores : 1.0));
    double cost = cost_rate(rs, cores, mem);
    if (rate < cost || rate * dur > budget * (1.0 + 1e-12))
        return 0;
    if (rs->nholds == rs->holds_cap) {
        size_t cap = rs->holds_cap ? 2 * rs->holds_cap : 16;
        hold_t *h = cap <= RS_MAX_HOLDS ? realloc(rs->holds, cap * sizeof *h) : NULL;
        if (!h) {
            bgm_emitter_fail(&rs->em, BG_ERR_LIMIT);
            return 0;
        }
        rs->holds = h;
        rs->holds_cap = cap;
    }
    rs->holds[rs->nholds++] = (hold_t){m->req, group, phase, cores, mem};
    rs->used_cores += added;
    rs->used_mem += mem;
    announce(rs);
    if (!rs->fixed)
        rs->memory = bgm_memory_update(rs->memory, rate / mean_rate(rs, cores, mem),
                                       rs->genes.weight_memory);
    learn(rs, 1, (rate - cost) / rate);
    bgm_emitter_timer(&rs->em, now + dur, BGM_RS_TIMER_RELEASE, m->req);
    bgm_msg_t k = msg(BGM_MT_RCONFIRM, rs->p.self, buyer, m->req, m->attempt);
    k.good = -1;
    k.price = rate;
    k.a = now;
    k.b = now + dur;
    k.c = cost;
    bgm_emitter_send(&rs->em, &k);
    return 1;
}

static uint64_t part_arg(int good, double quantity)
{
    return ((uint64_t)good << 40) | (uint64_t)llround(quantity * RS_MIB);
}

/* One part of a call-market bundle: m->a cores or GiB for m->b seconds
 * from the bundle's common start at m->price per unit-second. It holds
 * the part from now until the part's end if its host is up, the start is
 * still ahead and it has the room; it is paid once the buyer has the
 * whole bundle. It learns from the agreement (the rate over its cost).
 * Returns 0 when it cannot. */
static int hold_part(bgm_resource_t *rs, const bgm_msg_t *m, double now, int up)
{
    int is_cores = m->good == BGM_GOOD_CORES_ID;
    double qty = m->a, dur = m->b, rate = m->price, start = m->cand_price[0];
    double cost = is_cores ? rs->p.core_cost : rs->p.memory_cost;
    double *used = is_cores ? &rs->used_cores : &rs->used_mem;
    /* The auctioneer converts the uniform price to this seller's rate, so
     * the rate can sit an ulp below its cost. */
    if (!up || now > start || *used + qty > (is_cores ? rs->p.cores : rs->p.memory) + 1e-9 ||
        rate < cost * (1.0 - 1e-12))
        return 0;
    *used += qty;
    learn(rs, 1, (rate - cost) / rate);
    bgm_emitter_timer(&rs->em, start + dur, BGM_RS_TIMER_RELEASE_PART, part_arg(m->good, qty));
    bgm_msg_t k = msg(BGM_MT_RCONFIRM, rs->p.self, m->origin, m->req, m->attempt);
    k.good = m->good;
    k.hops = m->hops;
    k.price = rate;
    k.a = start;
    k.b = start + dur;
    k.cand_price[0] = qty;
    k.cand_price[1] = m->c;
    k.cand_price[2] = cost;
    bgm_emitter_send(&rs->em, &k);
    return 1;
}

/* Tells the buyer and the market agent that an award cannot be taken. */
static void refuse_award(bgm_resource_t *rs, const bgm_msg_t *m, double cores, double mem)
{
    bgm_msg_t f = msg(BGM_MT_RFAIL, rs->p.self, m->origin, m->req, m->attempt);
    bgm_emitter_send(&rs->em, &f);
    bgm_msg_t g = msg(BGM_MT_RFREE, rs->p.self, rs->p.market, m->req, 0);
    g.a = cores;
    g.b = mem;
    bgm_emitter_send(&rs->em, &g);
}

/* ---------------------------------------------------------- bargaining */

static double opening(const bgm_resource_t *rs, double cores, double mem)
{
    return bgm_nego_opening(BGM_SIDE_SELLER, cost_rate(rs, cores, mem),
                            rs->memory * mean_rate(rs, cores, mem), rs->markup);
}

/* A call for proposals: propose once per (request, attempt, origin) if it
 * has room for the bundle, and pass the call on while hops remain. */
static void on_cfp(bgm_resource_t *rs, const bgm_msg_t *m)
{
    if (bgm_flood_seen(&rs->seen, bgm_flood_key(m)))
        return;
    int phase;
    const uint32_t group = bundle_group(rs, m, &phase);
    if (m->good < 0 && rs->used_cores + cores_added(rs, group, phase, m->a) <= rs->p.cores &&
        rs->used_mem + m->b <= rs->p.memory) {
        bgm_msg_t p = msg(BGM_MT_PROPOSE, rs->p.self, m->origin, m->req, m->attempt);
        p.price = opening(rs, m->a, m->b);
        p.a = rs->p.speed;
        bgm_emitter_send(&rs->em, &p);
    }
    if (m->hops > 1) {
        bgm_msg_t f = *m;
        f.hops--;
        bgm_flood_pass(&rs->em, &f, rs->nbr, rs->p.degree, m->from, rs->cfg.agents.overlay_degree);
    }
}

static void reject(bgm_resource_t *rs, const bgm_msg_t *m)
{
    bgm_msg_t x = msg(BGM_MT_REJECT, rs->p.self, m->from, m->req, m->attempt);
    bgm_emitter_send(&rs->em, &x);
}

static void on_offer(bgm_resource_t *rs, const bgm_msg_t *m, double now, int up)
{
    bgm_session_t *s = bgm_sessions_for(rs->sess, m);
    if (!s)
        return; /* an offer in a bargain it has forgotten: nothing to answer */
    double lim = cost_rate(rs, m->a, m->b);
    if (!s->open) {
        bgm_nego_open(&s->nego, BGM_SIDE_SELLER, lim, opening(rs, m->a, m->b), &rs->genes,
                      rs->cfg.catallactic.max_rounds);
        s->open = 1;
    }
    double reply = 0.0;
    bgm_nego_action act = bgm_nego_respond(&s->nego, m->price, &rs->rng, &reply);
    if (act == BGM_NEGO_ACCEPT) {
        if (!rent(rs, m, m->from, reply, now, up))
            reject(rs, m);
    } else if (act == BGM_NEGO_COUNTER) {
        bgm_msg_t o = msg(BGM_MT_OFFER, rs->p.self, m->from, m->req, m->attempt);
        o.price = reply;
        bgm_emitter_send(&rs->em, &o);
    } else {
        learn(rs, 0, 0.0);
        reject(rs, m);
    }
}

/* The buyer accepted its last counter-offer. */
static void on_accept(bgm_resource_t *rs, const bgm_msg_t *m, double now, int up)
{
    const bgm_session_t *s = bgm_sessions_find(rs->sess, m->from, m->req, m->attempt);
    if (s && s->open)
        learn(rs, 1, (m->price - s->nego.limit) / m->price);
    if (!rent(rs, m, m->from, m->price, now, up))
        reject(rs, m);
}

static void send_genes(bgm_resource_t *rs, uint32_t to, int request)
{
    bgm_msg_t m = msg(BGM_MT_GENES, rs->p.self, to, 0, 0);
    double g[BGM_GENE_COUNT];
    bgm_genes_pack(&rs->genes, g);
    memcpy(m.cand_price, g, sizeof g);
    m.price = rs->fitness;
    m.a = request ? 1.0 : 0.0;
    bgm_emitter_send(&rs->em, &m);
}

/* A learning meeting with a neighbour of its role: answer a request with
 * its own genes, then learn from the other's. */
static void on_genes(bgm_resource_t *rs, const bgm_msg_t *m)
{
    int same = 0;
    for (int i = 0; i < rs->p.degree; i++)
        same |= rs->nbr[i] == m->from && rs->same[i];
    if (!same)
        return;
    if (m->a > 0.0)
        send_genes(rs, m->from, 0);
    bgm_genes_t other;
    double g[BGM_GENE_COUNT];
    memcpy(g, m->cand_price, sizeof g);
    bgm_genes_unpack(&other, g);
    bgm_learning_t lp = {rs->cfg.catallactic.imitation, rs->cfg.catallactic.mutation,
                         rs->cfg.catallactic.mutation_sigma};
    bgm_genes_learn(&rs->genes, rs->fitness, &other, m->price, &lp, &rs->rng);
}

/* --------------------------------------------------------------- inputs */

bg_status bgm_resource_start(bgm_resource_t *rs, double now, bgm_outbox_t *out)
{
    bgm_emitter_begin(&rs->em, out);
    if (rs->p.mechanism != BGM_MECH_CATALLACTIC) {
        bgm_msg_t m = msg(BGM_MT_RASK, rs->p.self, rs->p.market, 0, 0);
        m.a = rs->p.cores;
        m.b = rs->p.memory;
        m.c = rs->p.speed;
        m.price = rs->p.core_cost;
        m.cand_price[0] = rs->p.memory_cost;
        bgm_emitter_send(&rs->em, &m);
    } else {
        bgm_emitter_timer(&rs->em,
                          now + rs->cfg.catallactic.learning_period * bgm_rng_uniform(&rs->rng),
                          BGM_RS_TIMER_LEARN, 0);
    }
    return rs->em.failure;
}

bg_status bgm_resource_on_message(bgm_resource_t *rs, const bgm_msg_t *m, double now, int up,
                                  bgm_outbox_t *out)
{
    bgm_emitter_begin(&rs->em, out);
    switch (m->type) {
    case BGM_MT_RAWARD:
        if (!rent(rs, m, m->origin, m->price, now, up))
            refuse_award(rs, m, m->a, m->b);
        break;
    case BGM_MT_RPART:
        if (!hold_part(rs, m, now, up))
            refuse_award(rs, m, m->good == BGM_GOOD_CORES_ID ? m->a : 0.0,
                         m->good == BGM_GOOD_MEMORY_ID ? m->a : 0.0);
        break;
    case BGM_MT_CFP:
        on_cfp(rs, m);
        break;
    case BGM_MT_OFFER:
        /* An offer past its buyer's deadline stands no more: the buyer
         * has given up bargaining. */
        if (m->good < 0 && now <= m->cand_price[2])
            on_offer(rs, m, now, up);
        break;
    case BGM_MT_ACCEPT:
        if (m->good < 0)
            on_accept(rs, m, now, up);
        break;
    case BGM_MT_ORDER:
        if (m->good < 0 && now <= m->cand_price[2] && !rent(rs, m, m->from, m->price, now, up))
            reject(rs, m);
        break;
    case BGM_MT_GENES:
        on_genes(rs, m);
        break;
    default:
        /* REJECT ends a bargain it will not hear of again; nothing else is
         * addressed to a resource seller. */
        break;
    }
    return rs->em.failure;
}

bg_status bgm_resource_on_timer(bgm_resource_t *rs, int kind, uint64_t arg, double now, int up,
                                bgm_outbox_t *out)
{
    bgm_emitter_begin(&rs->em, out);
    switch (kind) {
    case BGM_RS_TIMER_RELEASE: {
        size_t i = 0;
        while (i < rs->nholds && rs->holds[i].req != (uint32_t)arg)
            i++;
        if (i == rs->nholds)
            return BG_ERR_INVALID;
        const hold_t h = rs->holds[i];
        double sum[BGM_RS_PHASES], freed = h.cores;
        const double before = h.group ? group_cores(rs, h.group, sum) : 0.0;
        rs->holds[i] = rs->holds[--rs->nholds];
        if (h.group)
            freed = before - group_cores(rs, h.group, sum);
        rs->used_cores -= freed;
        rs->used_mem -= h.memory;
        announce(rs);
        if (rs->p.mechanism == BGM_MECH_CENTRAL) {
            bgm_msg_t m = msg(BGM_MT_RFREE, rs->p.self, rs->p.market, h.req, 0);
            m.a = freed;
            m.b = h.memory;
            bgm_emitter_send(&rs->em, &m);
        }
        break;
    }
    case BGM_RS_TIMER_RELEASE_PART: {
        double q = (double)(arg & ((1ULL << 40) - 1)) / RS_MIB;
        int is_cores = (int)(arg >> 40) == BGM_GOOD_CORES_ID;
        if (is_cores)
            rs->used_cores -= q;
        else
            rs->used_mem -= q;
        bgm_msg_t m = msg(BGM_MT_RFREE, rs->p.self, rs->p.market, 0, 0);
        m.a = is_cores ? q : 0.0;
        m.b = is_cores ? 0.0 : q;
        bgm_emitter_send(&rs->em, &m);
        break;
    }
    case BGM_RS_TIMER_LEARN: {
        if (up && rs->p.degree > 0) {
            int k = (int)bgm_rng_below(&rs->rng, (uint32_t)rs->p.degree);
            if (rs->same[k])
                send_genes(rs, rs->nbr[k], 1);
        }
        double t = now + rs->cfg.catallactic.learning_period * (0.5 + bgm_rng_uniform(&rs->rng));
        if (t < rs->p.horizon)
            bgm_emitter_timer(&rs->em, t, BGM_RS_TIMER_LEARN, 0);
        break;
    }
    default:
        return BG_ERR_INVALID;
    }
    return rs->em.failure;
}
