#include "bgm_world.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_budget.h"
#include "bgm_buyer.h"
#include "bgm_market_agent.h"
#include "bgm_optimum.h"
#include "bgm_outbox.h"
#include "bgm_purchase.h"
#include "bgm_resource.h"
#include "bgm_rng.h"
#include "bgm_seller.h"
#include "bgm_stats.h"
#include "bgm_strategy.h"

const char *const bgm_metric_names[BGM_M_COUNT] = {
    "allocation_rate",      "access_time_median",   "access_time_p99",
    "resource_access_time_median", "resource_access_time_p99", "messages_per_allocation",
    "bytes_per_allocation", "welfare",              "welfare_ratio",
    "price_mean",           "price_variance",       "price_convergence_time",
    "utilization",          "job_completion_time",  "job_completion_rate",
    "resource_allocation_rate", "requests",         "contracts",
    "messages",             "bytes",                "combex_exact",
    "combex_greedy",        "timeouts",             "timeouts_per_request",
    "messages_per_request", "message_bound"};
const char *const bgm_good_names[5] = {"rotation-fit", "sparse-solve", "integration-step", "cores",
                                       "memory"};
const char *const bgm_role_names[4] = {"market", "complex", "basic", "resource"};

/* Hard caps (growable tables never exceed these). */
#define BGM_MAX_AGENTS 200000
#define BGM_DEMAND_STREAM (1ULL << 40)
#define BGM_MAX_REQS BGM_PU_MAX_REQS
#define BGM_MAX_CONTRACTS (1u << 23)
#define BGM_MAX_NEIGHBOURS BGM_PU_MAX_NEIGHBOURS
/* Items one role machine may emit in one call (a clearing emits two per fill). */
#define BGM_OUTBOX_MAX ((size_t)1 << 20)
#define BGM_GOOD_CORES 3
#define BGM_GOOD_MEMORY 4
#define BGM_GOOD_BUNDLE (-1)
/* Extra simulated bytes for the variable parts of messages. */
#define BGM_CAND_BYTES 20
#define BGM_GENES_BYTES 48
/* The opening-price markup every agent starts from. */
#define BGM_MARKUP_INIT 0.2

/* Timer kinds: the role machines' own, then the world's churn. */
enum {
    T_ARRIVAL = 1,  /* job's agent: next job (BGM_BU_TIMER_ARRIVAL) */
    T_CLEAR,        /* market agent: clearing period (BGM_MA_TIMER_CLEAR) */
    T_REQ,          /* a request's phase timeout (BGM_PU_TIMER_REQ) */
    T_DEADLINE,     /* a request's deadline (BGM_PU_TIMER_DEADLINE) */
    T_RETRY,        /* retry acquisition (BGM_PU_TIMER_RETRY) */
    T_RELEASE,      /* a seller's run or bundle ends: arg = its bundle's request */
    T_RELEASE_PART, /* resource agent frees one part: arg = part_arg(good, quantity) */
    T_LEARN,        /* catallactic learning meeting */
    T_NODE_FAIL,    /* agent = first agent of node; arg = node */
    T_NODE_REPAIR,
    T_LINK_FAIL,
    T_LINK_REPAIR
};
_Static_assert(T_ARRIVAL == BGM_BU_TIMER_ARRIVAL && T_CLEAR == BGM_MA_TIMER_CLEAR &&
                   T_REQ == BGM_PU_TIMER_REQ && T_DEADLINE == BGM_PU_TIMER_DEADLINE &&
                   T_RETRY == BGM_PU_TIMER_RETRY && T_RELEASE == BGM_RS_TIMER_RELEASE &&
                   T_RELEASE == BGM_SE_TIMER_RELEASE && T_RELEASE_PART == BGM_RS_TIMER_RELEASE_PART &&
                   T_LEARN == BGM_RS_TIMER_LEARN && T_LEARN == BGM_PU_TIMER_LEARN,
               "the role machines' timers keep their numbers");

/* A delivery of a bundle's service, as the observer follows it. */
enum { DL_NONE, DL_OFFERED, DL_DECIDED };

/* The observer's record of one request of the run (every request of
 * every machine, by its number): what it read from the owner's machine
 * when the request was opened, and for a bundle whether its delivery was
 * offered and decided. The machines never read it. */
typedef struct obs_req {
    uint32_t owner;
    uint32_t job; /* a service item: its job */
    int layer;    /* 0: a service item of a job; 1: a basic seller's bundle */
    int good, delivery;
    double work, limit, created, deadline;
} obs_req_t;

/* A job as the observer saw it arrive and its items be taken. */
typedef struct job {
    double arrival, last_end;
    int items, done;
} job_t;

/* What the world keeps of an agent: its place, what it drew for it at
 * creation (streams, genes, endowments: the machines hold their own
 * copies from then on) and the money ledger. */
typedef struct agent {
    int role;
    uint32_t node;
    bgm_rng_t rng;  /* strategy draws: bargaining, learning */
    bgm_rng_t drng; /* demand and endowment draws, independent of the
                     * mechanism, so every mechanism faces the same jobs */
    bgm_genes_t genes;
    double markup;
    uint32_t *nbr;
    uint8_t *nsame; /* per neighbour: of its role (told at creation, as its overlay links) */
    int ndeg;
    /* basic-service seller: what it sells, its slots, its own cost per unit */
    int sells[BGM_SERVICE_TYPES];
    int slots;
    double cost[BGM_SERVICE_TYPES];
    /* resource seller: its endowment */
    double cores, mem, core_cost, mem_cost, speed;
    /* the ledger */
    double paid[2], received[2];
} agent_t;

struct bgm_world {
    bgm_config_t cfg;
    bgm_world_params_t p;
    bgm_sink_t sink;
    bgm_rng_t rng;
    double horizon, arrival_end;
    uint32_t nagents, ncomplex, nbasic, nresource, first_basic, first_resource;
    agent_t *agents;
    uint32_t *nbr_pool;
    uint8_t *nsame_pool;
    int *node_up, *link_up;
    uint32_t nodes;
    double *speed;
    /* the role machines */
    bgm_market_agent_t *ma; /* agent 0's */
    bgm_buyer_t **bm;       /* the jobs' agents', by agent - 1 */
    bgm_seller_t **sm;      /* the basic sellers', by agent - first_basic */
    bgm_resource_t **rsm;   /* the resource sellers', by agent - first_resource */
    bgm_outbox_t *ob;       /* what a role machine emits during one call */
    /* the observer: requests by number (nreq: the next number), jobs,
     * contracts, accounting */
    obs_req_t *obs;
    uint32_t nreq, obs_cap;
    job_t *jobs;
    uint32_t njob, job_cap;
    bgm_contract_t *log;
    size_t nlog, log_cap;
    double msgs, bytes;
    double bundles; /* bundles rented (whole, or every part of one paid) */
    double *acc_s, *acc_r;
    size_t nacc_s, nacc_r;
    double welfare, core_seconds;
    bg_status failure; /* first failure inside a handler */
};

/* ---------------------------------------------------------------- helpers */

static void fail(bgm_world_t *w, bg_status st)
{
    if (w->failure == BG_OK)
        w->failure = st;
}

static int agent_alive(const bgm_world_t *w, uint32_t a)
{
    uint32_t n = w->agents[a].node;
    return n >= w->nodes || w->node_up[n];
}

static int agent_reachable(const bgm_world_t *w, uint32_t a)
{
    uint32_t n = w->agents[a].node;
    return n >= w->nodes || (w->node_up[n] && w->link_up[n]);
}

static void send(bgm_world_t *w, bgm_msg_t *m)
{
    long bytes = w->cfg.network.message_bytes;
    if (m->type == BGM_MT_LIST)
        bytes += BGM_CAND_BYTES * m->ncand;
    if (m->type == BGM_MT_GENES)
        bytes += BGM_GENES_BYTES;
    w->msgs += 1.0;
    w->bytes += (double)bytes;
    /* A sender whose node or access link is down loses the message. */
    if (!agent_reachable(w, m->from))
        return;
    w->sink.send(w->sink.ctx, m, bytes);
}

static void timer(bgm_world_t *w, uint32_t agent, double at, int kind, uint64_t arg)
{
    w->sink.timer(w->sink.ctx, agent, at, kind, arg);
}

static bg_status log_contract(bgm_world_t *w, const bgm_contract_t *c)
{
    if (w->nlog == w->log_cap) {
        size_t n = w->log_cap ? w->log_cap * 2 : 1024;
        if (n > BGM_MAX_CONTRACTS)
            return BG_ERR_LIMIT;
        bgm_contract_t *p = realloc(w->log, n * sizeof *p);
        if (!p)
            return BG_ERR_NOMEM;
        w->log = p;
        w->log_cap = n;
    }
    w->log[w->nlog++] = *c;
    return BG_OK;
}

static bg_status push_double(double **arr, size_t *n, double v)
{
    /* Doubling growth; the array length is bounded by the request cap. */
    if ((*n & (*n - 1)) == 0 || *n == 0) {
        size_t cap = *n ? *n * 2 : 256;
        double *p = realloc(*arr, cap * sizeof *p);
        if (!p)
            return BG_ERR_NOMEM;
        *arr = p;
    }
    (*arr)[(*n)++] = v;
    return BG_OK;
}

static int is_buyer(const bgm_world_t *w, uint32_t a)
{
    return a >= 1 && a < w->first_basic;
}

static int is_basic(const bgm_world_t *w, uint32_t a)
{
    return a >= w->first_basic && a < w->first_resource;
}

static int is_resource(const bgm_world_t *w, uint32_t a)
{
    return a >= w->first_resource && a < w->nagents;
}

static bgm_buyer_t *buyer_machine(bgm_world_t *w, uint32_t a)
{
    return w->bm[a - 1];
}

static bgm_seller_t *seller_machine(bgm_world_t *w, uint32_t a)
{
    return w->sm[a - w->first_basic];
}

static bgm_resource_t *resource_machine(bgm_world_t *w, uint32_t a)
{
    return w->rsm[a - w->first_resource];
}

/* ------------------------------------------------------------ construction */

static bg_status build_overlay(bgm_world_t *w)
{
    /* Random overlay among all non-market agents: each agent opens
     * degree/2 links to uniformly drawn others (both directions stored),
     * capped per agent; isolated agents get one link. Built in a
     * fixed-width table, then packed to each agent's real degree: the
     * table is 256 bytes an agent, the packed lists about 24. */
    uint32_t n = w->nagents - 1;
    int half = w->cfg.agents.overlay_degree / 2 > 0 ? w->cfg.agents.overlay_degree / 2 : 1;
    uint32_t *table = calloc((size_t)w->nagents * BGM_MAX_NEIGHBOURS, sizeof *table);
    if (!table)
        return BG_ERR_NOMEM;
    for (uint32_t a = 0; a < w->nagents; a++)
        w->agents[a].nbr = table + (size_t)a * BGM_MAX_NEIGHBOURS;
    for (uint32_t a = 1; a < w->nagents && n >= 2; a++) {
        for (int k = 0; k < half; k++) {
            uint32_t b = 1 + bgm_rng_below(&w->rng, n);
            agent_t *x = &w->agents[a], *y = &w->agents[b];
            if (b == a || x->ndeg >= BGM_MAX_NEIGHBOURS || y->ndeg >= BGM_MAX_NEIGHBOURS)
                continue;
            int dup = 0;
            for (int j = 0; j < x->ndeg; j++)
                dup |= x->nbr[j] == b;
            if (dup)
                continue;
            x->nbr[x->ndeg++] = b;
            y->nbr[y->ndeg++] = a;
        }
    }
    size_t total = 0;
    for (uint32_t a = 0; a < w->nagents; a++)
        total += (size_t)w->agents[a].ndeg;
    w->nbr_pool = malloc((total ? total : 1) * sizeof *w->nbr_pool);
    w->nsame_pool = malloc(total ? total : 1);
    if (!w->nbr_pool || !w->nsame_pool) {
        free(table);
        return BG_ERR_NOMEM;
    }
    size_t at = 0;
    for (uint32_t a = 0; a < w->nagents; a++) {
        agent_t *x = &w->agents[a];
        memcpy(w->nbr_pool + at, x->nbr, (size_t)x->ndeg * sizeof *w->nbr_pool);
        x->nbr = w->nbr_pool + at;
        x->nsame = w->nsame_pool + at;
        at += (size_t)x->ndeg;
    }
    free(table);
    for (uint32_t a = 0; a < w->nagents; a++) {
        agent_t *x = &w->agents[a];
        for (int j = 0; j < x->ndeg; j++)
            x->nsame[j] = w->agents[x->nbr[j]].role == x->role;
    }
    return BG_OK;
}

/* The role machines of the buyers, basic sellers and resource sellers,
 * each given what the world drew for it. */
static bg_status make_machines(bgm_world_t *w)
{
    const int mech = w->p.mechanism;
    w->bm = calloc(w->ncomplex, sizeof *w->bm);
    w->sm = calloc(w->nbasic, sizeof *w->sm);
    w->rsm = calloc(w->nresource, sizeof *w->rsm);
    if (!w->bm || !w->sm || !w->rsm)
        return BG_ERR_NOMEM;
    for (uint32_t k = 0; k < w->ncomplex; k++) {
        const agent_t *ag = &w->agents[1 + k];
        bgm_buyer_params_t bp = {&w->cfg,   mech,    1 + k,      0,        w->horizon,
                                 w->arrival_end, ag->drng, ag->rng, ag->genes, ag->markup,
                                 ag->nbr,   ag->nsame, ag->ndeg};
        if (!(w->bm[k] = bgm_buyer_new(&bp)))
            return BG_ERR_NOMEM;
    }
    for (uint32_t k = 0; k < w->nbasic; k++) {
        const agent_t *ag = &w->agents[w->first_basic + k];
        bgm_seller_params_t sp = {0};
        sp.cfg = &w->cfg;
        sp.mechanism = mech;
        sp.self = w->first_basic + k;
        sp.market = 0;
        sp.horizon = w->horizon;
        sp.first_buyer = 1;
        sp.nbuyers = w->ncomplex;
        sp.first_resource = w->first_resource;
        sp.nresource = w->nresource;
        memcpy(sp.sells, ag->sells, sizeof sp.sells);
        sp.slots = ag->slots;
        memcpy(sp.cost, ag->cost, sizeof sp.cost);
        sp.rng = ag->rng;
        sp.genes = ag->genes;
        sp.markup = ag->markup;
        sp.neighbours = ag->nbr;
        sp.same_role = ag->nsame;
        sp.degree = ag->ndeg;
        if (!(w->sm[k] = bgm_seller_new(&sp)))
            return BG_ERR_NOMEM;
    }
    for (uint32_t k = 0; k < w->nresource; k++) {
        const agent_t *ag = &w->agents[w->first_resource + k];
        bgm_resource_params_t rp = {&w->cfg,       mech,         w->first_resource + k, 0,
                                    w->horizon,    ag->cores,    ag->mem,
                                    ag->core_cost, ag->mem_cost, ag->speed,
                                    ag->rng,       ag->genes,    ag->markup,
                                    ag->nbr,       ag->nsame,    ag->ndeg,
                                    0 /* a simulated bundle names no job */};
        if (!(w->rsm[k] = bgm_resource_new(&rp)))
            return BG_ERR_NOMEM;
    }
    return BG_OK;
}

bgm_world_t *bgm_world_new(const bgm_world_params_t *p, bg_error_t *err)
{
    bg_status st = BG_OK;
    bgm_world_t *w = calloc(1, sizeof *w);
    if (!w) {
        bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        return NULL;
    }
    w->cfg = *p->cfg;
    w->p = *p;
    w->p.cfg = &w->cfg;
    const bgm_config_t *c = &w->cfg;
    bgm_rng_derive(&w->rng, c->seed, (uint64_t)p->scenario, (uint64_t)p->replication, 0);
    w->nodes = (uint32_t)p->nodes;
    w->arrival_end = c->duration;
    w->horizon = c->duration + c->drain;
    int per = (int)lround(p->nodes * p->density);
    int cx = (int)lround(p->nodes * c->agents.complex_per_node);
    w->ncomplex = (uint32_t)(cx < 1 ? 1 : cx);
    w->nbasic = w->nresource = (uint32_t)(per < 1 ? 1 : per);
    w->nagents = 1 + w->ncomplex + w->nbasic + w->nresource;
    if (w->nagents > BGM_MAX_AGENTS) {
        st = bg_error_set(err, BG_ERR_LIMIT, "scenario has %u agents, above the cap of %d",
                          w->nagents, BGM_MAX_AGENTS);
        goto out;
    }
    w->first_basic = 1 + w->ncomplex;
    w->first_resource = w->first_basic + w->nbasic;
    w->agents = calloc(w->nagents, sizeof *w->agents);
    w->node_up = malloc((w->nodes + 1) * sizeof *w->node_up);
    w->link_up = malloc((w->nodes + 1) * sizeof *w->link_up);
    w->speed = malloc((w->nodes + 1) * sizeof *w->speed);
    if (!w->agents || !w->node_up || !w->link_up || !w->speed) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u agents", w->nagents);
        goto out;
    }
    for (uint32_t i = 0; i <= w->nodes; i++) {
        w->node_up[i] = w->link_up[i] = 1;
        w->speed[i] = p->node_speed ? p->node_speed[i < w->nodes ? i : 0] : c->network.speed;
    }
    double spread = c->resources.cost_spread;
    for (uint32_t a = 0; a < w->nagents; a++) {
        agent_t *ag = &w->agents[a];
        bgm_rng_derive(&ag->rng, c->seed, (uint64_t)p->scenario, (uint64_t)p->replication,
                       (uint64_t)a + 1);
        bgm_rng_derive(&ag->drng, c->seed, (uint64_t)p->scenario, (uint64_t)p->replication,
                       BGM_DEMAND_STREAM + (uint64_t)a);
        bgm_genes_random(&ag->genes, &ag->rng);
        ag->markup = BGM_MARKUP_INIT;
        if (a == 0) {
            ag->role = BGM_ROLE_MARKET;
            ag->node = w->nodes;
        } else if (a < w->first_basic) {
            ag->role = BGM_ROLE_COMPLEX;
            ag->node = (a - 1) % w->nodes;
        } else if (a < w->first_resource) {
            ag->role = BGM_ROLE_BASIC;
            ag->node = (a - w->first_basic) % w->nodes;
            ag->slots = c->agents.service_slots;
            /* Each basic agent sells services_per_agent consecutive types
             * starting at a random one, so every type has sellers. */
            int first = (int)bgm_rng_below(&ag->drng, BGM_SERVICE_TYPES);
            for (int k = 0; k < c->agents.services_per_agent; k++)
                ag->sells[(first + k) % BGM_SERVICE_TYPES] = 1;
            for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
                const bgm_service_cfg_t *s = &c->services[t];
                ag->cost[t] = s->cost_per_unit * (1.0 + spread * (2.0 * bgm_rng_uniform(&ag->drng) - 1.0));
            }
        } else {
            ag->role = BGM_ROLE_RESOURCE;
            ag->node = (a - w->first_resource) % w->nodes;
            ag->cores = c->agents.resource_cores;
            ag->mem = c->agents.resource_memory;
            ag->core_cost = c->resources.core_cost * (1.0 + spread * (2.0 * bgm_rng_uniform(&ag->drng) - 1.0));
            ag->mem_cost = c->resources.memory_cost * (1.0 + spread * (2.0 * bgm_rng_uniform(&ag->drng) - 1.0));
            ag->speed = w->speed[ag->node];
        }
    }
    if ((st = build_overlay(w))) {
        bg_error_set(err, st, "out of memory for the overlay");
        goto out;
    }
    bgm_market_agent_params_t mp = {&w->cfg,          p->mechanism, 0,          w->first_basic,
                                    w->nbasic,        w->first_resource, w->nresource,
                                    w->horizon};
    w->ma = bgm_market_agent_new(&mp);
    w->ob = bgm_outbox_new(BGM_OUTBOX_MAX);
    if (!w->ma || !w->ob || make_machines(w)) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u agents' role machines",
                          w->nagents);
        goto out;
    }
out:
    if (st)
        bgm_world_destroy(&w);
    return w;
}

void bgm_world_destroy(bgm_world_t **pw)
{
    if (!pw || !*pw)
        return;
    bgm_world_t *w = *pw;
    free(w->agents);
    free(w->nbr_pool);
    free(w->nsame_pool);
    free(w->node_up);
    free(w->link_up);
    free(w->speed);
    free(w->obs);
    free(w->jobs);
    free(w->log);
    bgm_market_agent_destroy(&w->ma);
    for (uint32_t k = 0; w->bm && k < w->ncomplex; k++)
        bgm_buyer_destroy(&w->bm[k]);
    free(w->bm);
    for (uint32_t k = 0; w->sm && k < w->nbasic; k++)
        bgm_seller_destroy(&w->sm[k]);
    free(w->sm);
    for (uint32_t k = 0; w->rsm && k < w->nresource; k++)
        bgm_resource_destroy(&w->rsm[k]);
    free(w->rsm);
    bgm_outbox_destroy(&w->ob);
    free(w->acc_s);
    free(w->acc_r);
    free(w);
    *pw = NULL;
}

uint32_t bgm_world_agent_count(const bgm_world_t *w) { return w->nagents; }
uint32_t bgm_world_agent_node(const bgm_world_t *w, uint32_t a) { return w->agents[a].node; }
double bgm_world_horizon(const bgm_world_t *w) { return w->horizon; }
size_t bgm_world_contract_count(const bgm_world_t *w) { return w->nlog; }
const bgm_contract_t *bgm_world_contracts(const bgm_world_t *w) { return w->log; }

void bgm_world_money(const bgm_world_t *w, double paid[2], double received[2])
{
    paid[0] = paid[1] = received[0] = received[1] = 0.0;
    for (uint32_t a = 0; a < w->nagents; a++)
        for (int l = 0; l < 2; l++) {
            paid[l] += w->agents[a].paid[l];
            received[l] += w->agents[a].received[l];
        }
}

/* --------------------------------------------------------------- observer */

/* Records the requests agent me's machine opened during one call (the
 * numbers from `first` on): what the observer needs of each later (the
 * valuation, creation and deadline of a service item, for the contract
 * log, the access times and the offline optimum; a bundle's creation), read
 * through the machine's getters. A job's items belong to its last job. */
static void observe_requests(bgm_world_t *w, uint32_t me, uint32_t first)
{
    if (w->nreq == first)
        return;
    if (w->nreq > w->obs_cap) {
        uint32_t n = w->obs_cap ? w->obs_cap : 1024;
        while (n < w->nreq)
            n *= 2;
        obs_req_t *p = n <= BGM_MAX_REQS ? realloc(w->obs, (size_t)n * sizeof *p) : NULL;
        if (!p) {
            fail(w, n <= BGM_MAX_REQS ? BG_ERR_NOMEM : BG_ERR_LIMIT);
            return;
        }
        w->obs = p;
        w->obs_cap = n;
    }
    for (uint32_t id = first; id < w->nreq; id++) {
        obs_req_t *o = &w->obs[id];
        memset(o, 0, sizeof *o);
        o->owner = me;
        const bgm_purchase_req_t *r = is_buyer(w, me) ? bgm_buyer_request(buyer_machine(w, me), id)
                                                      : bgm_seller_bundle(seller_machine(w, me), id);
        if (!r) {
            fail(w, BG_ERR_INVALID);
            continue;
        }
        o->layer = r->good < 0;
        o->job = is_buyer(w, me) && w->njob > 0 ? w->njob - 1 : 0;
        o->good = r->good;
        o->work = r->work;
        o->limit = r->limit;
        o->created = r->created;
        o->deadline = r->deadline;
    }
}

/* A job arrived at agent me: the observer's record of it, its items
 * opened from request `first` on. */
static void observe_job(bgm_world_t *w, double now, uint32_t first)
{
    if (w->njob == w->job_cap) {
        uint32_t n = w->job_cap ? w->job_cap * 2 : 1024;
        job_t *p = n <= BGM_MAX_REQS ? realloc(w->jobs, (size_t)n * sizeof *p) : NULL;
        if (!p) {
            fail(w, BG_ERR_LIMIT);
            return;
        }
        w->jobs = p;
        w->job_cap = n;
    }
    w->jobs[w->njob++] = (job_t){now, 0.0, (int)(w->nreq - first), 0};
}

/* Bundle `b`, rented whole by basic seller `buyer`, is delivered: it
 * becomes a contract (a cores row and a memory row) and is paid. */
static void pay_bundle(bgm_world_t *w, const bgm_purchase_req_t *b, uint32_t buyer, double now)
{
    agent_t *ra = &w->agents[b->seller];
    double rate = b->price, start = b->start, end = b->end;
    double cores = b->cores, memory = b->memory;
    double cost = ra->core_cost * cores + ra->mem_cost * memory;
    double dur = end - start;
    double lim = b->limit / dur;
    double share_c = cost > 0.0 ? ra->core_cost * cores / cost : 1.0;
    bgm_contract_t c = {now,
                        start,
                        end,
                        b->deal.req,
                        buyer,
                        b->seller,
                        1,
                        BGM_GOOD_CORES,
                        cores,
                        rate * share_c / cores,
                        lim * share_c / cores,
                        ra->core_cost};
    bg_status st = log_contract(w, &c);
    if (!st && memory > 0.0) {
        double share_m = 1.0 - share_c;
        bgm_contract_t m = {now,
                            start,
                            end,
                            b->deal.req,
                            buyer,
                            b->seller,
                            1,
                            BGM_GOOD_MEMORY,
                            memory,
                            rate * share_m / memory,
                            lim * share_m / memory,
                            ra->mem_cost};
        st = log_contract(w, &m);
    }
    if (st)
        fail(w, st);
    w->bundles += 1.0;
    w->agents[buyer].paid[1] += rate * dur;
    ra->received[1] += rate * dur;
    w->core_seconds += cores * dur;
    w->welfare -= cost * dur;
}

/* Bundle `b` of basic seller `buyer`, bought in parts, is delivered:
 * each of its parts (the seller's record of them) becomes a contract and
 * is paid. */
static void pay_parts(bgm_world_t *w, bgm_seller_t *sm, const bgm_purchase_req_t *b,
                      uint32_t buyer, double now)
{
    for (size_t i = 0; i < bgm_seller_part_count(sm); i++) {
        const bgm_purchase_part_t *p = bgm_seller_part(sm, i);
        if (p->req != b->id)
            continue;
        double dur = p->end - p->start, money = p->rate * p->quantity * dur;
        bgm_contract_t c = {now,       p->start,   p->end,     b->deal.req, buyer, p->seller,
                            1,         p->good,    p->quantity, p->rate,  p->limit, p->cost};
        bg_status st = log_contract(w, &c);
        if (st)
            fail(w, st);
        w->agents[buyer].paid[1] += money;
        w->agents[p->seller].received[1] += money;
        if (p->good == BGM_GOOD_CORES)
            w->core_seconds += p->quantity * dur;
        w->welfare -= p->cost * p->quantity * dur;
    }
    w->bundles += 1.0;
}

/* The contract of bundle rid's service becomes final when the job's agent
 * takes the delivery: the observer, which keeps the contract log and the
 * ledger, books the service contract and the bundle's resource contracts
 * and pays them, from the basic seller's record of the bundle and the
 * deal. A refused delivery, or one never answered by the time its run
 * ends, is void: nobody pays for the bundle, so no item is ever bought
 * twice and the basic seller never pays for resources it cannot use (its
 * sellers held them for nothing). */
static void book_delivery(bgm_world_t *w, uint32_t rid, int taken, double now)
{
    obs_req_t *o = &w->obs[rid];
    if (o->layer != 1 || o->delivery != DL_OFFERED)
        return;
    o->delivery = DL_DECIDED;
    if (!taken)
        return;
    uint32_t b = o->owner;
    bgm_seller_t *sm = seller_machine(w, b);
    const bgm_purchase_req_t *r = bgm_seller_bundle(sm, rid);
    if (!r) {
        fail(w, BG_ERR_INVALID);
        return;
    }
    if (r->parts > 0) {
        pay_parts(w, sm, r, b, now);
        if (push_double(&w->acc_r, &w->nacc_r, r->start - r->created))
            fail(w, BG_ERR_NOMEM);
    } else {
        pay_bundle(w, r, b, now);
    }
    const bgm_deal_t *d = &r->deal;
    const obs_req_t *s = &w->obs[d->req];
    agent_t *ba = &w->agents[b];
    agent_t *ca = &w->agents[d->buyer];
    bgm_contract_t c = {now,     r->start, r->end,   d->req,   d->buyer, b, 0,
                        d->good, d->work,  d->price, s->limit, d->limit};
    bg_status st = log_contract(w, &c);
    if (st)
        fail(w, st);
    ca->paid[0] += d->price * d->work;
    ba->received[0] += d->price * d->work;
    w->welfare += (s->limit - ba->cost[d->good]) * d->work;
    if (push_double(&w->acc_s, &w->nacc_s, now - s->created))
        fail(w, BG_ERR_NOMEM);
}

/* A job's agent took the delivery of its item `req`, run until `end`. */
static void observe_taken(bgm_world_t *w, uint32_t req, uint32_t bundle)
{
    const obs_req_t *o = &w->obs[req];
    const obs_req_t *ob = &w->obs[bundle];
    const bgm_purchase_req_t *r =
        ob->layer == 1 ? bgm_seller_bundle(seller_machine(w, ob->owner), bundle) : NULL;
    if (o->layer != 0 || !r) {
        fail(w, BG_ERR_INVALID);
        return;
    }
    job_t *j = &w->jobs[o->job];
    j->done++;
    if (r->end > j->last_end)
        j->last_end = r->end;
}

/* Routes what a role machine emitted during one call, in emission order,
 * through the world's send (accounting, a sender cut off loses its
 * messages) and the driver's timers, then empties the outbox. The world
 * observes as it routes: a whole bundle confirmed is a resource access,
 * timed from its request's creation; a basic seller's CONFIRM offers a
 * delivery; a job's agent's TAKE or REFUSE decides it (the contract is
 * booked as the buyer takes, whether or not the TAKE arrives). */
static void route(bgm_world_t *w, bg_status st, double now)
{
    if (st)
        fail(w, st);
    for (size_t i = 0; i < bgm_outbox_count(w->ob); i++) {
        const bgm_out_item_t *it = bgm_outbox_item(w->ob, i);
        if (it->is_timer) {
            timer(w, it->agent, it->at, it->kind, it->arg);
            continue;
        }
        bgm_msg_t m = it->msg;
        if (m.type == BGM_MT_RCONFIRM && m.good == BGM_GOOD_BUNDLE && m.req < w->nreq &&
            push_double(&w->acc_r, &w->nacc_r, now - w->obs[m.req].created))
            fail(w, BG_ERR_NOMEM);
        if (m.type == BGM_MT_CONFIRM && m.origin < w->nreq && w->obs[m.origin].layer == 1)
            w->obs[m.origin].delivery = DL_OFFERED;
        if ((m.type == BGM_MT_TAKE || m.type == BGM_MT_REFUSE) && m.origin < w->nreq &&
            m.req < w->nreq) {
            if (m.type == BGM_MT_TAKE)
                observe_taken(w, m.req, m.origin);
            book_delivery(w, m.origin, m.type == BGM_MT_TAKE, now);
        }
        send(w, &m);
    }
    bgm_outbox_clear(w->ob);
}

/* --------------------------------------------------------------- dispatch */

bg_status bgm_world_on_message(bgm_world_t *w, const bgm_msg_t *m, double now)
{
    uint32_t me = m->to;
    if (me >= w->nagents)
        return BG_ERR_INVALID;
    if (!agent_reachable(w, me))
        return BG_OK; /* lost on a failed node or link */
    if (me == 0) {
        route(w, bgm_market_agent_on_message(w->ma, m, now, w->ob), now);
        return w->failure;
    }
    if (m->type != BGM_MT_GENES && m->type != BGM_MT_CFP && m->req >= w->nreq)
        return BG_ERR_INVALID;
    int up = agent_alive(w, me);
    if (is_resource(w, me)) {
        route(w, bgm_resource_on_message(resource_machine(w, me), m, now, up, w->ob), now);
        return w->failure;
    }
    /* A delivery and its answer name a bundle by its number. */
    if ((m->type == BGM_MT_CONFIRM || m->type == BGM_MT_TAKE || m->type == BGM_MT_REFUSE) &&
        m->origin >= w->nreq)
        return w->failure;
    if (is_buyer(w, me)) {
        route(w, bgm_buyer_on_message(buyer_machine(w, me), m, now, up, w->ob), now);
        return w->failure;
    }
    uint32_t first = w->nreq;
    bg_status st = bgm_seller_on_message(seller_machine(w, me), m, now, up, &w->nreq, w->ob);
    observe_requests(w, me, first);
    route(w, st, now);
    return w->failure;
}

bg_status bgm_world_on_timer(bgm_world_t *w, uint32_t me, int kind, uint64_t arg, double now)
{
    if (me >= w->nagents)
        return BG_ERR_INVALID;
    int alive = agent_alive(w, me);
    const bgm_dynamics_t *dy = w->p.dynamics;
    switch (kind) {
    case T_NODE_FAIL:
        w->node_up[arg] = 0;
        timer(w, 0, now + bgm_rng_exponential(&w->rng, dy->node_repair_mean), T_NODE_REPAIR, arg);
        break;
    case T_NODE_REPAIR: {
        w->node_up[arg] = 1;
        double t = now + bgm_rng_exponential(&w->rng, 1.0 / dy->node_failure_rate);
        if (t < w->horizon)
            timer(w, 0, t, T_NODE_FAIL, arg);
        break;
    }
    case T_LINK_FAIL:
        w->link_up[arg] = 0;
        timer(w, 0, now + bgm_rng_exponential(&w->rng, dy->link_repair_mean), T_LINK_REPAIR, arg);
        break;
    case T_LINK_REPAIR: {
        w->link_up[arg] = 1;
        double t = now + bgm_rng_exponential(&w->rng, 1.0 / dy->link_failure_rate);
        if (t < w->horizon)
            timer(w, 0, t, T_LINK_FAIL, arg);
        break;
    }
    default:
        if (me == 0) {
            route(w, bgm_market_agent_on_timer(w->ma, kind, arg, now, w->ob), now);
        } else if (is_resource(w, me)) {
            route(w, bgm_resource_on_timer(resource_machine(w, me), kind, arg, now, alive, w->ob),
                  now);
        } else if (is_buyer(w, me)) {
            uint32_t first = w->nreq, jobs = bgm_buyer_jobs(buyer_machine(w, me));
            bg_status st =
                bgm_buyer_on_timer(buyer_machine(w, me), kind, arg, now, alive, &w->nreq, w->ob);
            if (bgm_buyer_jobs(buyer_machine(w, me)) != jobs)
                observe_job(w, now, first);
            observe_requests(w, me, first);
            route(w, st, now);
        } else {
            /* A delivery never answered (lost on the way) is void by the
             * end of its run. */
            if (kind == T_RELEASE && (uint32_t)arg < w->nreq)
                book_delivery(w, (uint32_t)arg, 0, now);
            route(w, bgm_seller_on_timer(seller_machine(w, me), kind, arg, now, alive, w->ob), now);
        }
        break;
    }
    return w->failure;
}

bg_status bgm_world_start(bgm_world_t *w, const bgm_sink_t *sink, double now)
{
    w->sink = *sink;
    route(w, bgm_market_agent_start(w->ma, now, w->ob), now);
    for (uint32_t i = 1; i < w->nagents; i++) {
        if (is_buyer(w, i))
            route(w, bgm_buyer_start(buyer_machine(w, i), now, w->ob), now);
        else if (is_basic(w, i))
            route(w, bgm_seller_start(seller_machine(w, i), now, w->ob), now);
        else
            route(w, bgm_resource_start(resource_machine(w, i), now, w->ob), now);
    }
    const bgm_dynamics_t *dy = w->p.dynamics;
    for (uint32_t n = 0; n < w->nodes; n++) {
        if (dy->node_failure_rate > 0.0) {
            double t = now + bgm_rng_exponential(&w->rng, 1.0 / dy->node_failure_rate);
            if (t < w->horizon)
                timer(w, 0, t, T_NODE_FAIL, n);
        }
        if (dy->link_failure_rate > 0.0) {
            double t = now + bgm_rng_exponential(&w->rng, 1.0 / dy->link_failure_rate);
            if (t < w->horizon)
                timer(w, 0, t, T_LINK_FAIL, n);
        }
    }
    return w->failure;
}

/* ---------------------------------------------------------------- metrics */

/*
 * Offline optimum of the same demand and supply (bgm_optimum): every
 * service request of the run with its delivery window, every basic agent
 * with its slots and costs, every resource agent with its capacity, cost
 * and speed, for the whole run (failures ignored: the optimum may use a
 * node that was down, which only raises it). A delivery can start from
 * the request's creation until its deadline plus the commitment grace: no
 * service contract is final later (the job's agent refuses a delivery then). When the
 * config's central market sells resources on per-type call markets,
 * bundles may split across resource agents, in the optimum too, for every
 * mechanism of the run alike (the same demand and supply, the same
 * optimum). NaN (null) when the program has more than
 * central.optimum_limit variables or the simplex fails.
 */
static bgm_opt_request_t opt_request(const obs_req_t *x)
{
    return (bgm_opt_request_t){x->good, x->work, x->limit, x->created,
                               x->deadline + BGM_PU_COMMIT_GRACE};
}

static double offline_optimum(const bgm_world_t *w)
{
    bgm_opt_service_t svc[BGM_SERVICE_TYPES];
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        const bgm_service_cfg_t *s = &w->cfg.services[t];
        svc[t] = (bgm_opt_service_t){s->flops_per_unit, (double)s->cores, s->memory};
    }
    double opt = NAN;
    bgm_opt_request_t *q = NULL;
    bgm_opt_basic_t *b = malloc(w->nbasic * sizeof *b);
    bgm_opt_resource_t *r = malloc(w->nresource * sizeof *r);
    if (!b || !r)
        goto out;
    for (uint32_t k = 0; k < w->nbasic; k++) {
        const agent_t *a = &w->agents[w->first_basic + k];
        b[k].slots = a->slots;
        for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
            b[k].sells[t] = a->sells[t];
            b[k].cost[t] = a->cost[t];
        }
    }
    for (uint32_t k = 0; k < w->nresource; k++) {
        const agent_t *a = &w->agents[w->first_resource + k];
        r[k] = (bgm_opt_resource_t){a->cores, a->mem, a->speed, a->core_cost, a->mem_cost};
    }
    bgm_opt_problem_t prob = {
        svc, NULL, 0, b, w->nbasic, r, w->nresource, w->cfg.central.resource_market == BGM_RM_CALL};
    /* Too large is found request by request, before the requests are
     * copied: the copy would be the largest block of the run's last phase
     * at 2000 agents, and count towards its peak memory. */
    size_t pairs = 0, nq = 0;
    for (uint32_t i = 0; i < w->nreq && pairs <= (size_t)w->cfg.central.optimum_limit; i++)
        if (w->obs[i].layer == 0) {
            bgm_opt_request_t x = opt_request(&w->obs[i]);
            pairs += bgm_optimum_request_pairs(&prob, &x);
            nq++;
        }
    if (pairs > (size_t)w->cfg.central.optimum_limit)
        goto out;
    q = malloc((nq ? nq : 1) * sizeof *q);
    if (!q)
        goto out;
    nq = 0;
    for (uint32_t i = 0; i < w->nreq; i++)
        if (w->obs[i].layer == 0)
            q[nq++] = opt_request(&w->obs[i]);
    prob.requests = q;
    prob.nrequests = nq;
    bgm_opt_result_t res;
    if (bgm_optimum_solve(&prob, (size_t)w->cfg.central.optimum_limit, &res) == BG_OK &&
        res.status == BGM_OPT_SOLVED)
        opt = res.value;
out:
    free(q);
    free(b);
    free(r);
    return opt;
}

/* Buckets needed before the convergence time means anything: the last
 * quarter defines the settled level and at least as many must precede it. */
#define BGM_CONVERGENCE_MIN_BUCKETS 8

/*
 * Time after the demand shock until the service-layer price settles: the
 * contracts after the shock are averaged per time bucket (metrics
 * .price_bucket seconds; single contracts are far too noisy), the settled
 * level is the mean of the last quarter of the non-empty buckets, and the
 * result is the start of the first bucket after which every bucket stays
 * within convergence_tolerance of that level, minus the shock time. NaN
 * (null in the outputs) without a shock, with too few buckets, or when the
 * price only settles inside the tail that defines the level: the run was
 * too short to see it settle.
 */
static double convergence_time(const bgm_world_t *w)
{
    const double shock = w->cfg.demand.shock_time, width = w->cfg.metrics.price_bucket;
    if (shock < 0.0 || !(width > 0.0))
        return NAN;
    double end = shock;
    for (size_t i = 0; i < w->nlog; i++)
        if (w->log[i].layer == 0 && w->log[i].time > end)
            end = w->log[i].time;
    const size_t nb = (size_t)floor((end - shock) / width) + 1;
    double *sum = calloc(nb + 1, sizeof *sum), *mean = calloc(nb + 1, sizeof *mean);
    size_t *count = calloc(nb + 1, sizeof *count), *index = calloc(nb + 1, sizeof *index);
    double result = NAN;
    if (!sum || !mean || !count || !index)
        goto out;
    for (size_t i = 0; i < w->nlog; i++)
        if (w->log[i].layer == 0 && w->log[i].time >= shock) {
            size_t b = (size_t)floor((w->log[i].time - shock) / width);
            if (b >= nb)
                b = nb - 1;
            sum[b] += w->log[i].price;
            count[b]++;
        }
    size_t n = 0; /* non-empty buckets, in time order */
    for (size_t b = 0; b < nb; b++)
        if (count[b] > 0) {
            mean[n] = sum[b] / (double)count[b];
            index[n++] = b;
        }
    if (n < BGM_CONVERGENCE_MIN_BUCKETS)
        goto out;
    const size_t tail = n / 4;
    double target = 0.0;
    for (size_t k = n - tail; k < n; k++)
        target += mean[k];
    target /= (double)tail;
    const double tol = w->cfg.metrics.convergence_tolerance * fabs(target);
    size_t first_in = 0;
    for (size_t k = 0; k < n; k++)
        if (fabs(mean[k] - target) > tol)
            first_in = k + 1;
    if (first_in < n - tail)
        result = (double)index[first_in] * width;
out:
    free(sum);
    free(mean);
    free(count);
    free(index);
    return result;
}

void bgm_world_tally(const bgm_world_t *w, bgm_purchase_tally_t *service,
                     bgm_purchase_tally_t *resource)
{
    memset(service, 0, sizeof *service);
    memset(resource, 0, sizeof *resource);
    for (uint32_t k = 0; k < w->ncomplex; k++)
        bgm_buyer_counts(w->bm[k], service);
    for (uint32_t k = 0; k < w->nbasic; k++)
        bgm_seller_counts(w->sm[k], resource);
}

bg_status bgm_world_metrics(bgm_world_t *w, double m[BGM_M_COUNT])
{
    for (int i = 0; i < BGM_M_COUNT; i++)
        m[i] = NAN;
    double svc = 0.0, psum = 0.0, psq = 0.0;
    for (size_t i = 0; i < w->nlog; i++) {
        if (w->log[i].layer == 0) {
            svc += 1.0;
            psum += w->log[i].price;
            psq += w->log[i].price * w->log[i].price;
        }
    }
    bgm_purchase_tally_t svc_tally, res_tally;
    bgm_world_tally(w, &svc_tally, &res_tally);
    const double service_requests = svc_tally.requests, resource_requests = res_tally.requests;
    const double timeouts = svc_tally.timeouts + res_tally.timeouts;
    m[BGM_M_REQUESTS] = service_requests;
    m[BGM_M_CONTRACTS] = svc;
    m[BGM_M_MESSAGES] = w->msgs;
    m[BGM_M_BYTES] = w->bytes;
    bgm_market_agent_counts(w->ma, &m[BGM_M_COMBEX_EXACT], &m[BGM_M_COMBEX_GREEDY]);
    m[BGM_M_TIMEOUTS] = timeouts;
    if (service_requests > 0)
        m[BGM_M_ALLOCATION_RATE] = svc / service_requests;
    if (resource_requests > 0)
        m[BGM_M_RESOURCE_ALLOCATION_RATE] = w->bundles / resource_requests;
    m[BGM_M_ACCESS_TIME_MEDIAN] = bgm_quantile(w->acc_s, w->nacc_s, 0.5);
    m[BGM_M_ACCESS_TIME_P99] = bgm_quantile(w->acc_s, w->nacc_s, 0.99);
    m[BGM_M_RESOURCE_ACCESS_TIME_MEDIAN] = bgm_quantile(w->acc_r, w->nacc_r, 0.5);
    m[BGM_M_RESOURCE_ACCESS_TIME_P99] = bgm_quantile(w->acc_r, w->nacc_r, 0.99);
    if (service_requests > 0) {
        m[BGM_M_TIMEOUTS_PER_REQUEST] = timeouts / service_requests;
        m[BGM_M_MESSAGES_PER_REQUEST] = w->msgs / service_requests;
    }
    /* The bound the mechanism's parameters put on this run's messages
     * (bgm_budget), per allocation like the measured figure. */
    const bgm_budget_t budget =
        bgm_budget_of(&w->cfg, w->p.mechanism, w->horizon, (double)w->nresource);
    const double bound =
        bgm_budget_messages(&budget, service_requests, resource_requests, (double)w->nagents);
    if (svc > 0) {
        m[BGM_M_MESSAGE_BOUND] = bound / svc;
        m[BGM_M_MESSAGES_PER_ALLOCATION] = w->msgs / svc;
        m[BGM_M_BYTES_PER_ALLOCATION] = w->bytes / svc;
        m[BGM_M_PRICE_MEAN] = psum / svc;
        double var = psq / svc - (psum / svc) * (psum / svc);
        m[BGM_M_PRICE_VARIANCE] = var > 0.0 ? var : 0.0;
    }
    m[BGM_M_WELFARE] = w->welfare;
    double opt = offline_optimum(w);
    if (isfinite(opt) && opt > 0.0)
        m[BGM_M_WELFARE_RATIO] = w->welfare / opt;
    m[BGM_M_PRICE_CONVERGENCE_TIME] = convergence_time(w);
    double cores = 0.0;
    for (uint32_t k = 0; k < w->nresource; k++)
        cores += w->agents[w->first_resource + k].cores;
    m[BGM_M_UTILIZATION] = w->core_seconds / (cores * w->horizon);
    double done = 0.0, ct = 0.0;
    for (uint32_t j = 0; j < w->njob; j++) {
        if (w->jobs[j].done == w->jobs[j].items && w->jobs[j].items > 0) {
            done += 1.0;
            ct += w->jobs[j].last_end - w->jobs[j].arrival;
        }
    }
    if (done > 0)
        m[BGM_M_JOB_COMPLETION_TIME] = ct / done;
    if (w->njob > 0)
        m[BGM_M_JOB_COMPLETION_RATE] = done / (double)w->njob;
    return w->failure;
}

static void scenario_label(const bgm_world_t *w, char *buf, size_t n)
{
    bgm_config_scenario_label(buf, n, w->p.topology, w->p.nodes, w->p.density, w->p.dynamics->name);
}

bg_status bgm_world_write_contracts(const bgm_world_t *w, FILE *f)
{
    char sc[BGM_NAME_MAX * 2];
    scenario_label(w, sc, sizeof sc);
    for (size_t i = 0; i < w->nlog; i++) {
        const bgm_contract_t *c = &w->log[i];
        fprintf(f, "%s,%d,%s,%s,%u,%.6f,%.6f,%.6f,%u,%u,%s,%.6f,%.9g,%.9g,%.9g\n", sc,
                w->p.replication, bgm_mechanism_names[w->p.mechanism],
                c->layer == 0 ? "service" : "resource", c->request, c->time, c->start, c->end,
                c->buyer,
                c->seller, bgm_good_names[c->good], c->quantity, c->price, c->buyer_limit,
                c->seller_limit);
    }
    return ferror(f) ? BG_ERR_IO : BG_OK;
}

bg_status bgm_world_write_agents(const bgm_world_t *w, FILE *f)
{
    char sc[BGM_NAME_MAX * 2];
    scenario_label(w, sc, sizeof sc);
    const char *mech = bgm_mechanism_names[w->p.mechanism];
    for (uint32_t i = 1; i < w->nagents; i++) {
        const agent_t *a = &w->agents[i];
        const char *role = bgm_role_names[a->role];
        if (a->role == BGM_ROLE_COMPLEX) {
            for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
                double requested, valuation_sum;
                bgm_buyer_demand(w->bm[i - 1], t, &requested, &valuation_sum);
                if (requested > 0)
                    fprintf(f, "%s,%d,%s,%u,%s,%s,%.0f,%.9g\n", sc, w->p.replication, mech, i,
                            role, bgm_good_names[t], requested, valuation_sum / requested);
            }
        } else if (a->role == BGM_ROLE_BASIC) {
            for (int t = 0; t < BGM_SERVICE_TYPES; t++)
                if (a->sells[t])
                    fprintf(f, "%s,%d,%s,%u,%s,%s,%d,%.9g\n", sc, w->p.replication, mech, i, role,
                            bgm_good_names[t], a->slots, a->cost[t]);
        } else {
            fprintf(f, "%s,%d,%s,%u,%s,%s,%.0f,%.9g\n", sc, w->p.replication, mech, i, role,
                    bgm_good_names[BGM_GOOD_CORES], a->cores, a->core_cost);
            fprintf(f, "%s,%d,%s,%u,%s,%s,%.6g,%.9g\n", sc, w->p.replication, mech, i, role,
                    bgm_good_names[BGM_GOOD_MEMORY], a->mem, a->mem_cost);
        }
    }
    return ferror(f) ? BG_ERR_IO : BG_OK;
}

bg_status bgm_world_write_prices(const bgm_world_t *w, FILE *f)
{
    double bucket = w->cfg.metrics.price_bucket;
    size_t nb = (size_t)ceil(w->horizon / bucket) + 1;
    double *sum = calloc(nb * BGM_SERVICE_TYPES, sizeof *sum);
    double *cnt = calloc(nb * BGM_SERVICE_TYPES, sizeof *cnt);
    bg_status st = BG_OK;
    if (!sum || !cnt) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    for (size_t i = 0; i < w->nlog; i++) {
        const bgm_contract_t *c = &w->log[i];
        if (c->layer != 0)
            continue;
        size_t b = (size_t)(c->time / bucket);
        if (b >= nb)
            b = nb - 1;
        sum[(size_t)c->good * nb + b] += c->price;
        cnt[(size_t)c->good * nb + b] += 1.0;
    }
    for (int g = 0; g < BGM_SERVICE_TYPES; g++)
        for (size_t b = 0; b < nb; b++)
            if (cnt[(size_t)g * nb + b] > 0)
                fprintf(f, "%d,%.6f,%.9g\n", g, (double)b * bucket,
                        sum[(size_t)g * nb + b] / cnt[(size_t)g * nb + b]);
    if (ferror(f))
        st = BG_ERR_IO;
out:
    free(sum);
    free(cnt);
    return st;
}
