#include "bgm_world.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_catallactic.h"
#include "bgm_market_agent.h"
#include "bgm_optimum.h"
#include "bgm_outbox.h"
#include "bgm_resource.h"
#include "bgm_session.h"
#include "bgm_rng.h"
#include "bgm_strategy.h"

const char *const bgm_metric_names[BGM_M_COUNT] = {
    "allocation_rate",      "access_time_median",   "access_time_p99",
    "resource_access_time_median", "resource_access_time_p99", "messages_per_allocation",
    "bytes_per_allocation", "welfare",              "welfare_ratio",
    "price_mean",           "price_variance",       "price_convergence_time",
    "utilization",          "job_completion_time",  "job_completion_rate",
    "resource_allocation_rate", "requests",         "contracts",
    "messages",             "bytes",                "combex_exact",
    "combex_greedy",        "timeouts"};
const char *const bgm_good_names[5] = {"rotation-fit", "sparse-solve", "integration-step", "cores",
                                       "memory"};
const char *const bgm_role_names[4] = {"market", "complex", "basic", "resource"};

/* Hard caps (growable tables never exceed these). */
#define BGM_MAX_AGENTS 200000
#define BGM_DEMAND_STREAM (1ULL << 40)
#define BGM_MAX_REQS (1u << 22)
#define BGM_MAX_CONTRACTS (1u << 23)
#define BGM_MAX_NEIGHBOURS 64
#define BGM_MAX_PROPOSALS 8
#define BGM_SEEN_RING 16
/* Bargains a basic seller keeps at once (catallactic; bgm_session). */
#define BGM_BASIC_SESSIONS 32
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
/* A basic agent re-announces its ask when its reservation moves this much. */
#define BGM_ASK_REFRESH 0.1
/* Buyer waits this long past its deadline for a committed seller. */
#define BGM_COMMIT_GRACE 30.0

/* Message types. a/b/c meanings are given per type. */
enum {
    M_BID = BGM_MT_BID, /* C->A service bid: good, price=valuation/unit, a=work, b=deadline */
    M_ASK,      /* B->A: good, price=reservation/unit, a=slots (registration/refresh) */
    M_FREE,     /* B->A: one slot free again */
    M_MATCH,    /* A->B: req, good, price, a=work, b=deadline, c=buyer valuation; origin=buyer */
    M_RBID,     /* B->A resource bid: req, a=cores, b=memory, c=flops, price=limit total */
    M_RASK,     /* R->A registration: a=cores, b=memory, c=speed, price=cost rate/core */
    M_RFREE,    /* R->A: a=cores, b=memory freed */
    M_RAWARD,   /* A->R: req, price=rate, origin=buyer, a=cores, b=memory, c=flops;
                   cand[0]=seller-limit */
    M_RFAIL,    /* A->B or R->B: resource request failed */
    M_RCONFIRM, /* R->B: req, price=rate, a=start, b=end, c=seller limit rate; for a part
                 * (good cores|memory): cand_price[0..2]=quantity, buyer limit and
                 * seller cost per unit-second, hops=parts of the bundle */
    M_CONFIRM,  /* B->C, a delivery: req, attempt, price/unit, a=start, b=end, origin=bundle */
    M_CANCEL,   /* B->C: the agreed service could not get resources */
    M_CFP,      /* call for proposals: req, good, hops, origin, a=work|cores, b=memory, c=flops */
    M_PROPOSE,  /* seller->buyer: price=opening, a=speed */
    M_OFFER,    /* either way: price */
    M_ACCEPT,   /* either way: price agreed */
    M_REJECT,   /* either way */
    M_GENES,    /* learning: cand_price[0..4]=genes, price=fitness, a=1 request, 0 reply */
    M_QUERY,    /* baseline: buyer->A: good (or bundle), price=limit */
    M_LIST,     /* A->buyer: candidates */
    M_ORDER,    /* buyer->seller at posted price: price, a=work|cores, b=memory, c=flops */
    M_AVAIL,    /* baseline seller->directory: a=free slots|cores, b=free memory */
    M_RPART,    /* A->R, call markets: req, good=cores|memory, a=quantity, b=duration,
                 * price=rate per unit-second, c=buyer limit per unit-second,
                 * hops=parts of the bundle, origin=buyer, cand_price[0]=start */
    M_TAKE,     /* C->B: the delivery of req is taken; origin=bundle */
    M_REFUSE    /* C->B: the delivery of req is refused; origin=bundle */
};
_Static_assert((int)M_REFUSE == (int)BGM_MT_REFUSE, "the world's message numbers are bgm_role.h's");

/* Timer kinds. */
enum {
    T_ARRIVAL = 1,  /* complex agent: next job */
    T_CLEAR,        /* market agent: clearing period (BGM_MA_TIMER_CLEAR) */
    T_REQ,          /* request phase timeout: arg = req | tseq << 32 */
    T_DEADLINE,     /* request deadline: arg = req */
    T_RETRY,        /* retry acquisition: arg = req | attempt << 32 */
    T_RELEASE,      /* seller capacity release at contract end: arg = its bundle (req) */
    T_RELEASE_PART, /* resource agent frees one part: arg = part_arg(good, quantity) */
    T_LEARN,        /* catallactic learning meeting */
    T_NODE_FAIL,    /* agent = first agent of node; arg = node */
    T_NODE_REPAIR,
    T_LINK_FAIL,
    T_LINK_REPAIR
};
_Static_assert(T_CLEAR == BGM_MA_TIMER_CLEAR && T_RELEASE == BGM_RS_TIMER_RELEASE &&
                   T_RELEASE_PART == BGM_RS_TIMER_RELEASE_PART && T_LEARN == BGM_RS_TIMER_LEARN,
               "the role machines' timers keep their numbers");

enum { RQ_IDLE, RQ_DISCOVER, RQ_NEGOTIATE, RQ_WAIT, RQ_COMMITTED, RQ_DONE, RQ_FAILED };
/* A bundle's delivery to the job's agent (resource requests). */
enum { DL_NONE, DL_OFFERED, DL_DECIDED };

typedef struct proposal {
    uint32_t seller;
    double price, speed;
} proposal_t;

/* The buyer's bargaining state of a request while it is being acquired
 * by proposals (catallactic) or candidate lists (baseline): kept apart
 * from the request and given back when the request ends, because only a
 * few hundred requests bargain at once while tens of thousands are
 * recorded. A seller's side of the bargain is the seller's own
 * (bgm_session). */
typedef struct nego_state {
    proposal_t prop[BGM_MAX_PROPOSALS];
    int nprop, next_prop;
    bgm_nego_t buyer_nego;
    uint32_t next_free;
} nego_state_t;

#define BGM_NEGO_NONE UINT32_MAX

/* A purchase in progress: a service item of a job (layer 0, buyer C) or a
 * resource bundle for an agreed service (layer 1, buyer B). Owned by its
 * buyer. */
typedef struct req {
    int layer, good, state;
    uint32_t buyer, seller, job, parent; /* parent: service req of a resource req */
    uint32_t attempt;
    uint32_t tseq; /* phase timer generation: only the latest T_REQ counts */
    uint32_t sattempt; /* resource request: the service attempt its basic agent agreed to */
    double work;   /* service: units (a bundle's size follows from its service) */
    double limit;        /* service: valuation/unit; resource: revenue total */
    double created, deadline;
    double price;        /* agreed price (service: per unit; resource: rate) */
    double seller_limit; /* seller's reservation at agreement */
    double start, end;
    uint32_t nego;  /* bargaining state (BGM_NEGO_NONE: none) */
    uint32_t parts; /* call markets: parts of the bundle confirmed so far */
    /* Resource request: the basic agent's own record of the service deal
     * it serves (what the buyer's message said and the agreed terms), so
     * that it never reads the buyer's record. */
    uint32_t sbuyer;
    int sgood, delivery;
    double swork, sprice, slimit;
} req_t;

typedef struct job {
    uint32_t agent;
    double arrival, last_end;
    int items, done, failed;
} job_t;

typedef struct agent {
    int role;
    uint32_t node;
    bgm_rng_t rng;  /* strategy draws: bargaining, learning */
    bgm_rng_t drng; /* demand and endowment draws, independent of the
                     * mechanism, so every mechanism faces the same jobs */
    bgm_genes_t genes;
    double fitness, markup;
    double memory[4]; /* remembered price per service good; [3]: resource price/cost ratio */
    uint32_t *nbr;
    uint8_t *nsame; /* per neighbour: of its role (told at creation, as its overlay links) */
    int ndeg;
    /* basic-service seller */
    int sells[BGM_SERVICE_TYPES];
    int slots, used;
    double cost[BGM_SERVICE_TYPES];      /* own cost per unit */
    double est_res[BGM_SERVICE_TYPES];   /* estimated resource cost per unit */
    double announced[BGM_SERVICE_TYPES]; /* last reservation sent to the market */
    double posted[BGM_SERVICE_TYPES];    /* baseline posted price */
    /* resource seller: its endowment, as drawn (the machine holds the rest) */
    double cores, mem, core_cost, mem_cost, speed;
    /* complex buyer */
    double requested[BGM_SERVICE_TYPES], valuation_sum[BGM_SERVICE_TYPES];
    double paid[2], received[2];
} agent_t;

/* Call markets: one part of a bundle, held by its seller and confirmed
 * to the buyer, paid for once the whole bundle is. */
typedef struct part {
    uint32_t rid, seller;
    int good;
    double quantity, start, end, rate, limit, cost;
} part_t;

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
    /* Catallactic only: per agent, a ring of the calls for proposals it
     * has seen (BGM_SEEN_RING keys) and where the next one goes. */
    uint64_t *seen;
    uint8_t *seen_pos;
    int *node_up, *link_up;
    uint32_t nodes;
    double *speed;
    req_t *reqs;
    uint32_t nreq, req_cap;
    nego_state_t *negos; /* pool; a free list threads the unused ones */
    uint32_t nnego, nego_cap, nego_free;
    job_t *jobs;
    uint32_t njob, job_cap;
    bgm_contract_t *log;
    size_t nlog, log_cap;
    part_t *parts; /* call markets: parts held for bundles not yet complete */
    size_t nparts, parts_cap;
    bgm_market_agent_t *ma; /* agent 0's role machine */
    bgm_resource_t **rsm;   /* the resource sellers' role machines, by agent - first_resource */
    bgm_sessions_t **bsess; /* catallactic: the basic sellers' bargains, by agent - first_basic */
    bgm_outbox_t *ob;       /* what a role machine emits during one call */
    /* accounting */
    double msgs, bytes, timeouts;
    double service_requests, resource_requests;
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
    if (m->type == M_LIST)
        bytes += BGM_CAND_BYTES * m->ncand;
    if (m->type == M_GENES)
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


/* Messages start from a zeroed body with their header set. */
static bgm_msg_t msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    return bgm_outbox_msg(type, from, to, req, attempt);
}

/* Baseline: a basic seller tells the directory its free slots whenever
 * they change, as a plain scheduler's registry would learn them (resource
 * sellers do the same in bgm_resource). */
static void announce(bgm_world_t *w, uint32_t seller)
{
    if (w->p.mechanism != BGM_MECH_BASELINE)
        return;
    const agent_t *a = &w->agents[seller];
    bgm_msg_t m = msg(M_AVAIL, seller, 0, 0, 0);
    m.a = (double)(a->slots - a->used);
    send(w, &m);
}


static uint64_t req_arg(const req_t *r, uint32_t id)
{
    return (uint64_t)id | ((uint64_t)r->attempt << 32);
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

static uint32_t new_req(bgm_world_t *w)
{
    if (w->nreq == w->req_cap) {
        uint32_t n = w->req_cap ? w->req_cap * 2 : 1024;
        if (n > BGM_MAX_REQS) {
            fail(w, BG_ERR_LIMIT);
            return UINT32_MAX;
        }
        req_t *p = realloc(w->reqs, (size_t)n * sizeof *p);
        if (!p) {
            fail(w, BG_ERR_NOMEM);
            return UINT32_MAX;
        }
        w->reqs = p;
        w->req_cap = n;
    }
    memset(&w->reqs[w->nreq], 0, sizeof w->reqs[0]);
    w->reqs[w->nreq].nego = BGM_NEGO_NONE;
    return w->nreq++;
}

/* The request's bargaining state. Only valid while it has one, that is
 * between its first acquisition and its end; the pool may move when a
 * state is taken, so callers fetch it again after anything that starts
 * an acquisition. */
static nego_state_t *ng(bgm_world_t *w, const req_t *r)
{
    return &w->negos[r->nego];
}

/* Gives request r a bargaining state if it has none. Returns 0 when out
 * of memory. */
static int nego_take(bgm_world_t *w, req_t *r)
{
    if (r->nego != BGM_NEGO_NONE)
        return 1;
    if (w->nego_free == BGM_NEGO_NONE) {
        if (w->nnego == w->nego_cap) {
            uint32_t n = w->nego_cap ? w->nego_cap * 2 : 256;
            nego_state_t *p = n <= BGM_MAX_REQS ? realloc(w->negos, (size_t)n * sizeof *p) : NULL;
            if (!p)
                return 0;
            w->negos = p;
            w->nego_cap = n;
        }
        w->negos[w->nnego].next_free = BGM_NEGO_NONE;
        w->nego_free = w->nnego++;
    }
    r->nego = w->nego_free;
    w->nego_free = w->negos[r->nego].next_free;
    memset(&w->negos[r->nego], 0, sizeof w->negos[0]);
    return 1;
}

/* Request r has ended (done or failed): no message about it reads its
 * bargaining state any more (every handler checks the state first). */
static void req_end(bgm_world_t *w, req_t *r, int state)
{
    r->state = state;
    if (r->nego == BGM_NEGO_NONE)
        return;
    w->negos[r->nego].next_free = w->nego_free;
    w->nego_free = r->nego;
    r->nego = BGM_NEGO_NONE;
}

/* A resource request's bundle is what its service's type needs, for the
 * service's work (from the basic agent's record of the deal); a service
 * request has none. Derived, not stored: tens of thousands of requests
 * are recorded at 2000 agents. */
static const bgm_service_cfg_t *bundle_type(const bgm_world_t *w, const req_t *r)
{
    return r->layer == 1 ? &w->cfg.services[r->sgood] : NULL;
}

static double req_cores(const bgm_world_t *w, const req_t *r)
{
    const bgm_service_cfg_t *s = bundle_type(w, r);
    return s ? (double)s->cores : 0.0;
}

static double req_memory(const bgm_world_t *w, const req_t *r)
{
    const bgm_service_cfg_t *s = bundle_type(w, r);
    return s ? s->memory : 0.0;
}

static double req_flops(const bgm_world_t *w, const req_t *r)
{
    const bgm_service_cfg_t *s = bundle_type(w, r);
    return s ? s->flops_per_unit * r->swork : 0.0;
}

static double resource_cost_rate(const agent_t *r, double cores, double mem)
{
    return r->core_cost * cores + r->mem_cost * mem;
}

/* Normaliser for remembered resource prices: the mean cost rate. */
static double mean_rate(const bgm_world_t *w, double cores, double mem)
{
    return w->cfg.resources.core_cost * cores + w->cfg.resources.memory_cost * mem;
}

static double reservation(const agent_t *b, int good)
{
    return b->cost[good] + b->est_res[good];
}

static void learn_outcome(agent_t *a, int success, double surplus_share)
{
    bgm_outcome_learn(&a->genes, &a->fitness, &a->markup, success, surplus_share);
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
    w->nego_free = BGM_NEGO_NONE;
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
                ag->est_res[t] = mean_rate(w, s->cores, s->memory) * s->flops_per_unit /
                                 (c->network.speed * s->cores);
                ag->posted[t] = reservation(ag, t) * (1.0 + c->baseline.markup);
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
    if (p->mechanism == BGM_MECH_CATALLACTIC) {
        w->seen = calloc((size_t)w->nagents * BGM_SEEN_RING, sizeof *w->seen);
        w->seen_pos = calloc(w->nagents, sizeof *w->seen_pos);
        if (!w->seen || !w->seen_pos) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u agents", w->nagents);
            goto out;
        }
    }
    if (p->mechanism == BGM_MECH_CATALLACTIC) {
        w->bsess = calloc(w->nbasic, sizeof *w->bsess);
        for (uint32_t k = 0; w->bsess && k < w->nbasic; k++)
            if (!(w->bsess[k] = bgm_sessions_new(BGM_BASIC_SESSIONS)))
                break;
        if (!w->bsess || (w->nbasic > 0 && !w->bsess[w->nbasic - 1])) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u basic sellers", w->nbasic);
            goto out;
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
    w->rsm = calloc(w->nresource, sizeof *w->rsm);
    if (!w->ma || !w->ob || !w->rsm) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the market books");
        goto out;
    }
    for (uint32_t k = 0; k < w->nresource; k++) {
        const agent_t *ag = &w->agents[w->first_resource + k];
        bgm_resource_params_t rp = {&w->cfg,       p->mechanism, w->first_resource + k, 0,
                                    w->horizon,    ag->cores,    ag->mem,
                                    ag->core_cost, ag->mem_cost, ag->speed,
                                    ag->rng,       ag->genes,    ag->markup,
                                    ag->nbr,       ag->nsame,    ag->ndeg};
        if (!(w->rsm[k] = bgm_resource_new(&rp))) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u resource sellers",
                              w->nresource);
            goto out;
        }
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
    free(w->seen);
    free(w->seen_pos);
    free(w->node_up);
    free(w->link_up);
    free(w->speed);
    free(w->reqs);
    free(w->negos);
    free(w->jobs);
    free(w->log);
    free(w->parts);
    bgm_market_agent_destroy(&w->ma);
    for (uint32_t k = 0; w->rsm && k < w->nresource; k++)
        bgm_resource_destroy(&w->rsm[k]);
    free(w->rsm);
    for (uint32_t k = 0; w->bsess && k < w->nbasic; k++)
        bgm_sessions_destroy(&w->bsess[k]);
    free(w->bsess);
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

/* ------------------------------------------------------------ acquisition */

/* Forgets the parts held for bundle rid: nobody is paid for them. */
static void drop_parts(bgm_world_t *w, uint32_t rid)
{
    size_t keep = 0;
    for (size_t i = 0; i < w->nparts; i++)
        if (w->parts[i].rid != rid)
            w->parts[keep++] = w->parts[i];
    w->nparts = keep;
}

static void start_acquire(bgm_world_t *w, uint32_t rid, double now);

static void final_fail(bgm_world_t *w, uint32_t rid, double now)
{
    req_t *r = &w->reqs[rid];
    if (r->state == RQ_DONE || r->state == RQ_FAILED)
        return;
    req_end(w, r, RQ_FAILED);
    if (r->parts > 0)
        drop_parts(w, rid);
    agent_t *buyer = &w->agents[r->buyer];
    learn_outcome(buyer, 0, 0.0);
    if (r->layer == 0) {
        w->jobs[r->job].failed++;
        return;
    }
    /* A resource request failed: the basic agent gives the slot back and
     * tells its job buyer that the agreed service is off. */
    if (buyer->used > 0)
        buyer->used--;
    announce(w, r->buyer);
    if (w->p.mechanism == BGM_MECH_CENTRAL) {
        bgm_msg_t m = msg(M_FREE, r->buyer, 0, rid, 0);
        send(w, &m);
    }
    bgm_msg_t m = msg(M_CANCEL, r->buyer, r->sbuyer, r->parent, r->sattempt);
    send(w, &m);
    (void)now;
}

/* One attempt failed: retry after a backoff while the deadline allows. */
static void attempt_failed(bgm_world_t *w, uint32_t rid, double now)
{
    req_t *r = &w->reqs[rid];
    double backoff = w->p.mechanism == BGM_MECH_BASELINE ? w->cfg.baseline.retry_backoff
                                                          : w->cfg.catallactic.retry_backoff;
    learn_outcome(&w->agents[r->buyer], 0, 0.0);
    r->attempt++;
    if (now + backoff >= r->deadline) {
        final_fail(w, rid, now);
        return;
    }
    r->state = RQ_IDLE;
    timer(w, r->buyer, now + backoff, T_RETRY, req_arg(r, rid));
}

static double req_duration(const bgm_world_t *w, const req_t *r, double speed)
{
    return req_flops(w, r) / (speed * (req_cores(w, r) > 0 ? req_cores(w, r) : 1.0));
}

/* Arms the request's phase timer; earlier phase timers become stale. */
static void arm(bgm_world_t *w, uint32_t rid, double at)
{
    req_t *r = &w->reqs[rid];
    r->tseq++;
    timer(w, r->buyer, at, T_REQ, (uint64_t)rid | ((uint64_t)r->tseq << 32));
}

static void cfp_send(bgm_world_t *w, uint32_t from, const bgm_msg_t *proto, uint32_t except)
{
    const agent_t *a = &w->agents[from];
    for (int i = 0; i < a->ndeg; i++) {
        if (a->nbr[i] == except || a->nbr[i] == proto->origin)
            continue;
        bgm_msg_t m = *proto;
        m.from = from;
        m.to = a->nbr[i];
        send(w, &m);
    }
}

static void start_acquire(bgm_world_t *w, uint32_t rid, double now)
{
    req_t *r = &w->reqs[rid];
    if (!agent_alive(w, r->buyer)) {
        final_fail(w, rid, now);
        return;
    }
    if (w->p.mechanism != BGM_MECH_CENTRAL) {
        if (!nego_take(w, r)) {
            fail(w, BG_ERR_NOMEM);
            return;
        }
        nego_state_t *g = ng(w, r);
        g->nprop = g->next_prop = 0;
    }
    switch (w->p.mechanism) {
    case BGM_MECH_CENTRAL: {
        bgm_msg_t m = msg(r->layer == 0 ? M_BID : M_RBID, r->buyer, 0, rid, r->attempt);
        m.good = (int16_t)r->good;
        m.price = r->limit;
        m.a = r->layer == 0 ? r->work : req_cores(w, r);
        m.b = r->layer == 0 ? r->deadline : req_memory(w, r);
        m.c = r->layer == 0 ? 0.0 : req_flops(w, r);
        m.cand_price[0] = r->deadline;
        r->state = RQ_WAIT;
        send(w, &m);
        break;
    }
    case BGM_MECH_CATALLACTIC: {
        bgm_msg_t m = msg(M_CFP, r->buyer, 0, rid, r->attempt);
        m.good = (int16_t)r->good;
        m.hops = (uint16_t)w->cfg.catallactic.hops;
        m.origin = r->buyer;
        m.a = r->layer == 0 ? r->work : req_cores(w, r);
        m.b = req_memory(w, r);
        m.c = req_flops(w, r);
        r->state = RQ_DISCOVER;
        cfp_send(w, r->buyer, &m, UINT32_MAX);
        arm(w, rid, now + w->cfg.catallactic.discovery_timeout);
        break;
    }
    default: {
        bgm_msg_t m = msg(M_QUERY, r->buyer, 0, rid, r->attempt);
        m.good = (int16_t)(r->layer == 0 ? r->good : BGM_GOOD_CORES);
        m.price = r->layer == 0 ? r->limit : INFINITY;
        m.a = req_cores(w, r);
        m.b = req_memory(w, r);
        r->state = RQ_WAIT;
        send(w, &m);
        arm(w, rid, now + 4.0 * w->cfg.catallactic.reply_timeout);
        break;
    }
    }
}

/* A service deal as the basic seller knows it: what the buyer's message
 * (or the auctioneer's MATCH) said, and the agreed terms. */
typedef struct deal {
    uint32_t buyer, req, attempt;
    int good;
    double work, deadline, price, limit;
} deal_t;

/* Basic agent b has agreed to serve deal d: it reserves a slot and starts
 * buying the resources, keeping the deal in its own resource request.
 * The deal is bound to the buyer's attempt: whether the buyer still
 * wants it is the buyer's to say when the service is delivered (TAKE or
 * REFUSE). Returns 0 (and changes nothing) when it has no free slot. */
static int service_agreed(bgm_world_t *w, uint32_t b, const deal_t *d, double now)
{
    agent_t *ag = &w->agents[b];
    if (ag->used >= ag->slots || !agent_alive(w, b) || d->good < 0 ||
        d->good >= BGM_SERVICE_TYPES || !(d->work > 0.0))
        return 0;
    uint32_t rid = new_req(w);
    if (rid == UINT32_MAX)
        return 0;
    ag->used++;
    announce(w, b);
    req_t *r = &w->reqs[rid];
    r->layer = 1;
    r->good = BGM_GOOD_BUNDLE;
    r->buyer = b;
    r->parent = d->req;
    r->sattempt = d->attempt;
    r->sbuyer = d->buyer;
    r->sgood = d->good;
    r->swork = d->work;
    r->sprice = d->price;
    r->slimit = d->limit;
    r->limit = d->price * d->work;
    r->created = now;
    r->deadline = d->deadline > now ? d->deadline : now + w->cfg.catallactic.reply_timeout;
    w->resource_requests += 1.0;
    timer(w, b, r->deadline, T_DEADLINE, rid);
    start_acquire(w, rid, now);
    return 1;
}

/* Bundle rid, rented whole from `seller` at `rate` from start to end, is
 * delivered: it becomes a contract (a cores row and a memory row) and is
 * paid. */
static void pay_bundle(bgm_world_t *w, uint32_t rid, uint32_t seller, double rate, double start,
                       double end, double now)
{
    const req_t *r = &w->reqs[rid];
    agent_t *ra = &w->agents[seller];
    double cores = req_cores(w, r), memory = req_memory(w, r);
    double cost = resource_cost_rate(ra, cores, memory);
    double dur = end - start;
    double lim = r->limit / dur;
    double share_c = cost > 0.0 ? ra->core_cost * cores / cost : 1.0;
    bgm_contract_t c = {now,
                        start,
                        end,
                        r->parent,
                        r->buyer,
                        seller,
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
                            r->parent,
                            r->buyer,
                            seller,
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
    w->agents[r->buyer].paid[1] += rate * dur;
    ra->received[1] += rate * dur;
    w->core_seconds += cores * dur;
    w->welfare -= cost * dur;
}

/* Bundle rid is complete: each of its parts becomes a contract and is
 * paid. Returns the money paid in all. */
static double pay_parts(bgm_world_t *w, uint32_t rid, double now)
{
    const req_t *r = &w->reqs[rid];
    double total = 0.0;
    for (size_t i = 0; i < w->nparts; i++) {
        const part_t *p = &w->parts[i];
        if (p->rid != rid)
            continue;
        double dur = p->end - p->start, money = p->rate * p->quantity * dur;
        bgm_contract_t c = {now,       p->start,   p->end,     r->parent, r->buyer, p->seller,
                            1,         p->good,    p->quantity, p->rate,  p->limit, p->cost};
        bg_status st = log_contract(w, &c);
        if (st)
            fail(w, st);
        w->agents[r->buyer].paid[1] += money;
        w->agents[p->seller].received[1] += money;
        if (p->good == BGM_GOOD_CORES)
            w->core_seconds += p->quantity * dur;
        w->welfare -= p->cost * p->quantity * dur;
        total += money;
    }
    drop_parts(w, rid);
    w->bundles += 1.0;
    return total;
}

/* The money the parts held for bundle rid cost its basic agent in all
 * (call markets). */
static double parts_money(const bgm_world_t *w, uint32_t rid)
{
    double total = 0.0;
    for (size_t i = 0; i < w->nparts; i++)
        if (w->parts[i].rid == rid)
            total += w->parts[i].rate * w->parts[i].quantity * (w->parts[i].end - w->parts[i].start);
    return total;
}

/* Basic agent b's bundle rid is rented: it delivers the service to the
 * job's agent (CONFIRM, with the bundle's number), which answers TAKE or
 * REFUSE. The slot is b's until the rental ends, taken or not. */
static void deliver(bgm_world_t *w, uint32_t b, uint32_t rid)
{
    req_t *r = &w->reqs[rid];
    r->delivery = DL_OFFERED;
    timer(w, b, r->end, T_RELEASE, rid);
    bgm_msg_t cm = msg(M_CONFIRM, b, r->sbuyer, r->parent, r->sattempt);
    cm.price = r->sprice;
    cm.a = r->start;
    cm.b = r->end;
    cm.origin = rid;
    send(w, &cm);
}

/* Basic agent b learns that its bundle, or one part of it (call markets),
 * is rented. A bundle bought in parts is rented once every part is: it
 * runs from the first part's start to the last part's end. */
static void on_rconfirm(bgm_world_t *w, uint32_t b, const bgm_msg_t *m, double now)
{
    req_t *r = &w->reqs[m->req];
    /* A late confirm after giving up: nobody pays for it; its seller
     * held it for nothing. */
    if (r->state == RQ_DONE || r->state == RQ_FAILED)
        return;
    if (m->good == BGM_GOOD_CORES || m->good == BGM_GOOD_MEMORY) {
        if (w->nparts == w->parts_cap) {
            size_t cap = w->parts_cap ? 2 * w->parts_cap : 64;
            part_t *p = realloc(w->parts, cap * sizeof *p);
            if (!p) {
                fail(w, BG_ERR_NOMEM);
                return;
            }
            w->parts = p;
            w->parts_cap = cap;
        }
        w->parts[w->nparts++] = (part_t){m->req, m->from,  m->good,          m->cand_price[0], m->a,
                                         m->b,   m->price, m->cand_price[1], m->cand_price[2]};
        r->start = r->parts == 0 ? m->a : fmin(r->start, m->a);
        r->end = r->parts == 0 ? m->b : fmax(r->end, m->b);
        if (++r->parts < m->hops)
            return;
        /* Every part was held from before the common start; the service
         * can run from it only if the bundle is complete by then. A later
         * bundle is void for its sellers (unpaid) and fails for b. */
        if (now > r->start) {
            drop_parts(w, m->req);
            final_fail(w, m->req, now);
            return;
        }
        req_end(w, r, RQ_DONE);
        r->seller = m->from;
        r->price = parts_money(w, m->req) / (r->end - r->start);
        deliver(w, b, m->req);
        return;
    }
    req_end(w, r, RQ_DONE);
    r->seller = m->from;
    r->price = m->price;
    r->start = m->a;
    r->end = m->b;
    deliver(w, b, m->req);
}

/* The contract of bundle rid's service becomes final when the job's agent
 * takes the delivery: the world, as the observer that keeps the contract
 * log and the ledger, books the service contract and the bundle's
 * resource contracts and pays them. A refused delivery is void: nobody
 * pays for the bundle, so no item is ever bought twice and the basic
 * agent never pays for resources it cannot use (its sellers held them for
 * nothing). */
static void book_delivery(bgm_world_t *w, uint32_t rid, int taken, double now)
{
    req_t *r = &w->reqs[rid];
    if (r->delivery != DL_OFFERED)
        return;
    r->delivery = DL_DECIDED;
    if (!taken) {
        if (r->parts > 0)
            drop_parts(w, rid);
        return;
    }
    if (r->parts > 0) {
        pay_parts(w, rid, now);
        if (push_double(&w->acc_r, &w->nacc_r, r->start - r->created))
            fail(w, BG_ERR_NOMEM);
    } else {
        pay_bundle(w, rid, r->seller, r->price, r->start, r->end, now);
    }
    const req_t *s = &w->reqs[r->parent];
    agent_t *ba = &w->agents[r->buyer];
    agent_t *ca = &w->agents[r->sbuyer];
    bgm_contract_t c = {now,      r->start, r->end,    r->parent, r->sbuyer, r->buyer, 0,
                        r->sgood, r->swork, r->sprice, s->limit,  r->slimit};
    bg_status st = log_contract(w, &c);
    if (st)
        fail(w, st);
    ca->paid[0] += r->sprice * r->swork;
    ba->received[0] += r->sprice * r->swork;
    w->welfare += (s->limit - ba->cost[r->sgood]) * r->swork;
    if (push_double(&w->acc_s, &w->nacc_s, now - s->created))
        fail(w, BG_ERR_NOMEM);
}

/* The job's agent answers basic agent b's delivery of bundle rid: a
 * taken service teaches b what resources really cost per unit of it and
 * its price; a refused one counts as a failure. */
static void seller_on_answer(bgm_world_t *w, uint32_t b, const bgm_msg_t *m)
{
    if (m->origin >= w->nreq)
        return;
    req_t *r = &w->reqs[m->origin];
    if (r->layer != 1 || r->buyer != b || r->sbuyer != m->from || r->parent != m->req ||
        r->delivery == DL_NONE)
        return;
    agent_t *ba = &w->agents[b];
    if (m->type == M_REFUSE) {
        learn_outcome(ba, 0, 0.0);
        return;
    }
    double money = r->price * (r->end - r->start);
    ba->est_res[r->sgood] =
        bgm_memory_update(ba->est_res[r->sgood], money / r->swork, ba->genes.weight_memory);
    ba->memory[3] = bgm_memory_update(
        ba->memory[3], r->price / mean_rate(w, req_cores(w, r), req_memory(w, r)),
        ba->genes.weight_memory);
    ba->memory[r->sgood] = bgm_memory_update(ba->memory[r->sgood], r->sprice, ba->genes.weight_memory);
    learn_outcome(ba, 1, (r->sprice - r->slimit) / r->sprice);
    if (w->p.mechanism == BGM_MECH_CENTRAL) {
        double res = reservation(ba, r->sgood);
        if (fabs(res - ba->announced[r->sgood]) > BGM_ASK_REFRESH * ba->announced[r->sgood]) {
            bgm_msg_t a = msg(M_ASK, b, 0, 0, 0);
            a.good = (int16_t)r->sgood;
            a.price = res;
            a.a = -1.0;
            ba->announced[r->sgood] = res;
            send(w, &a);
        }
    }
}

/* The job's agent takes delivery of service request sid: it is bought. */
static void service_delivered(bgm_world_t *w, uint32_t sid, double price, double start, double end)
{
    req_t *r = &w->reqs[sid];
    req_end(w, r, RQ_DONE);
    r->start = start;
    r->end = end;
    job_t *j = &w->jobs[r->job];
    j->done++;
    if (end > j->last_end)
        j->last_end = end;
    agent_t *c = &w->agents[r->buyer];
    c->memory[r->good] = bgm_memory_update(c->memory[r->good], price, c->genes.weight_memory);
    learn_outcome(c, 1, (r->limit - price) / r->limit);
}

/* The job's agent me is offered the delivery of its request m->req: it
 * takes it, once, if it still wants the item from that seller on that
 * attempt (it has not bought it already, has not given up on it, and has
 * not moved on to another attempt or, bargaining, another seller), and
 * refuses it otherwise. Taking is the step at which the item is bought:
 * a TAKE lost on the way back cannot make the job's agent buy the item a
 * second time. A service whose run has already ended serves nothing. */
static void buyer_on_delivery(bgm_world_t *w, uint32_t me, const bgm_msg_t *m, double now)
{
    req_t *r = &w->reqs[m->req];
    if (r->layer != 0 || r->buyer != me || m->origin >= w->nreq)
        return;
    int wanted = r->state != RQ_DONE && r->state != RQ_FAILED && m->attempt == r->attempt &&
                 (w->p.mechanism == BGM_MECH_CENTRAL || r->seller == m->from) && m->b > now;
    bgm_msg_t x = msg(wanted ? M_TAKE : M_REFUSE, me, m->from, m->req, m->attempt);
    x.origin = m->origin;
    if (wanted) {
        r->seller = m->from;
        r->price = m->price;
        service_delivered(w, m->req, m->price, m->a, m->b);
    }
    book_delivery(w, m->origin, wanted, now);
    send(w, &x);
}

/* ---------------------------------------------------------------- market */

/* Routes what a role machine emitted during one call, in emission order,
 * through the world's send (accounting, a sender cut off loses its
 * messages) and the driver's timers, then empties the outbox. The world
 * observes as it routes: a whole bundle confirmed is a resource access,
 * timed from its request's creation (the basic seller's record, which the
 * world keeps for the metrics). */
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
        if (m.type == M_RCONFIRM && m.good == BGM_GOOD_BUNDLE && m.req < w->nreq &&
            push_double(&w->acc_r, &w->nacc_r, now - w->reqs[m.req].created))
            fail(w, BG_ERR_NOMEM);
        send(w, &m);
    }
    bgm_outbox_clear(w->ob);
}

static int is_resource(const bgm_world_t *w, uint32_t a)
{
    return a >= w->first_resource && a < w->nagents;
}

static bgm_resource_t *resource_machine(bgm_world_t *w, uint32_t a)
{
    return w->rsm[a - w->first_resource];
}

/* ------------------------------------------------------------ catallactic */

static int seen_before(bgm_world_t *w, uint32_t agent, uint64_t key)
{
    uint64_t *seen = w->seen + (size_t)agent * BGM_SEEN_RING;
    for (int i = 0; i < BGM_SEEN_RING; i++)
        if (seen[i] == key)
            return 1;
    seen[w->seen_pos[agent]] = key;
    w->seen_pos[agent] = (uint8_t)((w->seen_pos[agent] + 1) % BGM_SEEN_RING);
    return 0;
}

/* A basic seller's reservation and opening for a service of type good
 * (resource sellers bargain in bgm_resource). */
static double seller_limit_for(const agent_t *s, int good)
{
    return reservation(s, good);
}

static double seller_opening(const agent_t *s, int good)
{
    return bgm_nego_opening(BGM_SIDE_SELLER, seller_limit_for(s, good), s->memory[good],
                            s->markup);
}

/* Whether agent s can sell what a call for proposals asks for (its good:
 * a service type, or < 0 for a resource bundle). */
static int can_sell(const agent_t *s, int good)
{
    return good >= 0 && good < BGM_SERVICE_TYPES && s->role == BGM_ROLE_BASIC && s->sells[good] &&
           s->used < s->slots;
}

static void on_cfp(bgm_world_t *w, uint32_t me, const bgm_msg_t *m)
{
    agent_t *a = &w->agents[me];
    uint64_t key = ((uint64_t)m->req << 20) ^ m->attempt ^ ((uint64_t)m->origin << 44);
    if (seen_before(w, me, key))
        return;
    /* What it reads of the request is what the call carries. */
    if (can_sell(a, m->good)) {
        bgm_msg_t p = msg(M_PROPOSE, me, m->origin, m->req, m->attempt);
        p.price = seller_opening(a, m->good);
        p.a = a->speed;
        send(w, &p);
    }
    if (m->hops > 1) {
        bgm_msg_t f = *m;
        f.hops--;
        cfp_send(w, me, &f, m->from);
    }
}

static double buyer_limit_for(const bgm_world_t *w, const req_t *r, const proposal_t *p)
{
    if (r->layer == 0)
        return r->limit;
    return r->limit / req_duration(w, r, p->speed);
}

/* What a seller reads of the request in a buyer's OFFER, ACCEPT or
 * ORDER: the good (a bundle: < 0), the bundle, the budget (a resource
 * seller checks the rent against it) and how long the buyer's offer
 * stands: until its deadline, when the buyer gives up bargaining. */
static void request_fields(const bgm_world_t *w, const req_t *r, bgm_msg_t *m)
{
    m->good = (int16_t)r->good;
    m->a = r->layer == 0 ? r->work : req_cores(w, r);
    m->b = req_memory(w, r);
    m->c = req_flops(w, r);
    m->cand_price[1] = r->limit;
    m->cand_price[2] = r->deadline;
}

static void begin_nego(bgm_world_t *w, uint32_t rid, double now)
{
    req_t *r = &w->reqs[rid];
    agent_t *b = &w->agents[r->buyer];
    nego_state_t *g = ng(w, r);
    while (g->next_prop < g->nprop) {
        const proposal_t *p = &g->prop[g->next_prop];
        double lim = buyer_limit_for(w, r, p);
        double mem = r->layer == 0 ? b->memory[r->good]
                                   : b->memory[3] * mean_rate(w, req_cores(w, r), req_memory(w, r));
        bgm_msg_t o;
        if (w->p.mechanism == BGM_MECH_BASELINE) {
            if (p->price > lim) {
                g->next_prop++;
                continue;
            }
            o = msg(M_ORDER, r->buyer, p->seller, rid, r->attempt);
            o.price = p->price;
            request_fields(w, r, &o);
        } else {
            bgm_nego_open(&g->buyer_nego, BGM_SIDE_BUYER, lim,
                          bgm_nego_opening(BGM_SIDE_BUYER, lim, mem, b->markup), &b->genes,
                          w->cfg.catallactic.max_rounds);
            o = msg(M_OFFER, r->buyer, p->seller, rid, r->attempt);
            o.price = g->buyer_nego.current;
            o.hops = 1; /* opens a bargain: the seller starts afresh */
            request_fields(w, r, &o);
        }
        r->seller = p->seller;
        r->state = RQ_NEGOTIATE;
        send(w, &o);
        arm(w, rid, now + w->cfg.catallactic.reply_timeout);
        return;
    }
    attempt_failed(w, rid, now);
}

static void next_proposal(bgm_world_t *w, uint32_t rid, double now)
{
    ng(w, &w->reqs[rid])->next_prop++;
    begin_nego(w, rid, now);
}

static int cmp_prop(const void *pa, const void *pb)
{
    const proposal_t *a = pa, *b = pb;
    if (a->price != b->price)
        return a->price < b->price ? -1 : 1;
    return (a->seller > b->seller) - (a->seller < b->seller);
}

/* Agreement reached at basic seller `me` on the request a buyer's OFFER,
 * ACCEPT or ORDER names (m->from, m->req, m->attempt, m->good): it commits
 * on its side and tells the buyer ACCEPT (resources follow), or REJECT
 * when it cannot. */
static void seller_commit(bgm_world_t *w, uint32_t me, const bgm_msg_t *m, double price,
                          double limit, double now)
{
    deal_t d = {m->from, m->req, m->attempt, m->good, m->a, m->cand_price[2], price, limit};
    if (!service_agreed(w, me, &d, now)) {
        bgm_msg_t x = msg(M_REJECT, me, m->from, m->req, m->attempt);
        send(w, &x);
        return;
    }
    agent_t *s = &w->agents[me];
    s->memory[m->good] = bgm_memory_update(s->memory[m->good], price, s->genes.weight_memory);
    bgm_msg_t a = msg(M_ACCEPT, me, m->from, m->req, m->attempt);
    a.price = price;
    send(w, &a);
}

/* A buyer's OFFER to basic seller `me`. The seller reads what the offer
 * carries (the good, how long it stands) and its own session of the
 * bargain, opened by the buyer's first offer; an offer of a bargain it
 * does not hold (another attempt, forgotten) gets no answer. */
static void seller_on_offer(bgm_world_t *w, uint32_t me, const bgm_msg_t *m, double now)
{
    agent_t *s = &w->agents[me];
    if (m->good < 0 || m->good >= BGM_SERVICE_TYPES || now > m->cand_price[2])
        return;
    bgm_session_t *ss = bgm_sessions_for(w->bsess[me - w->first_basic], m);
    if (!ss)
        return;
    if (!ss->open) {
        bgm_nego_open(&ss->nego, BGM_SIDE_SELLER, seller_limit_for(s, m->good),
                      seller_opening(s, m->good), &s->genes, w->cfg.catallactic.max_rounds);
        ss->open = 1;
    }
    double reply = 0.0;
    bgm_nego_action act = bgm_nego_respond(&ss->nego, m->price, &s->rng, &reply);
    if (act == BGM_NEGO_ACCEPT) {
        seller_commit(w, me, m, reply, ss->nego.limit, now);
    } else if (act == BGM_NEGO_COUNTER) {
        bgm_msg_t o = msg(M_OFFER, me, m->from, m->req, m->attempt);
        o.price = reply;
        send(w, &o);
    } else {
        learn_outcome(s, 0, 0.0);
        bgm_msg_t x = msg(M_REJECT, me, m->from, m->req, m->attempt);
        send(w, &x);
    }
}

/* The buyer accepted basic seller me's last counter-offer: the seller
 * commits at that price if the bargain is one it holds. */
static void seller_on_accept(bgm_world_t *w, uint32_t me, const bgm_msg_t *m, double now)
{
    if (m->good < 0 || m->good >= BGM_SERVICE_TYPES || !w->bsess)
        return;
    const bgm_session_t *ss = bgm_sessions_find(w->bsess[me - w->first_basic], m->from, m->req,
                                                m->attempt);
    if (!ss || !ss->open) {
        bgm_msg_t x = msg(M_REJECT, me, m->from, m->req, m->attempt);
        send(w, &x);
        return;
    }
    double lim = ss->nego.limit;
    learn_outcome(&w->agents[me], 1, (m->price - lim) / m->price);
    seller_commit(w, me, m, m->price, lim, now);
}

static void buyer_on_offer(bgm_world_t *w, uint32_t me, const bgm_msg_t *m, double now)
{
    req_t *r = &w->reqs[m->req];
    agent_t *b = &w->agents[me];
    if (m->attempt != r->attempt || r->state != RQ_NEGOTIATE || m->from != r->seller)
        return;
    double reply = 0.0;
    bgm_nego_action act = bgm_nego_respond(&ng(w, r)->buyer_nego, m->price, &b->rng, &reply);
    if (act == BGM_NEGO_ACCEPT) {
        bgm_msg_t a = msg(M_ACCEPT, me, m->from, m->req, m->attempt);
        a.price = reply;
        request_fields(w, r, &a);
        r->state = RQ_COMMITTED;
        r->price = reply;
        send(w, &a);
        /* A bundle seller answers at once. A service seller commits as
         * soon as it reads the acceptance and starts buying resources, so
         * the buyer must not walk away on a phase timeout any more: it
         * waits for the seller's answer, and the deadline covers the rest. */
        if (r->layer == 1)
            arm(w, m->req, now + w->cfg.catallactic.reply_timeout);
        else
            r->tseq++;
    } else if (act == BGM_NEGO_COUNTER) {
        bgm_msg_t o = msg(M_OFFER, me, m->from, m->req, m->attempt);
        o.price = reply;
        request_fields(w, r, &o);
        send(w, &o);
        arm(w, m->req, now + w->cfg.catallactic.reply_timeout);
    } else {
        bgm_msg_t x = msg(M_REJECT, me, m->from, m->req, m->attempt);
        send(w, &x);
        next_proposal(w, m->req, now);
    }
}

/* A learning meeting: agent me learns only from an overlay neighbour of
 * its own role, which it was told when its links were made. */
static void learn_meet(bgm_world_t *w, uint32_t me, const bgm_msg_t *m)
{
    agent_t *a = &w->agents[me];
    int same = 0;
    for (int i = 0; i < a->ndeg; i++)
        same |= a->nbr[i] == m->from && a->nsame[i];
    if (!same)
        return;
    if (m->a > 0.0) {
        bgm_msg_t r = msg(M_GENES, me, m->from, 0, 0);
        double g[BGM_GENE_COUNT];
        bgm_genes_pack(&a->genes, g);
        memcpy(r.cand_price, g, sizeof g);
        r.price = a->fitness;
        send(w, &r);
    }
    bgm_genes_t other;
    double g[BGM_GENE_COUNT];
    memcpy(g, m->cand_price, sizeof g);
    bgm_genes_unpack(&other, g);
    bgm_learning_t lp = {w->cfg.catallactic.imitation, w->cfg.catallactic.mutation,
                         w->cfg.catallactic.mutation_sigma};
    bgm_genes_learn(&a->genes, a->fitness, &other, m->price, &lp, &a->rng);
}

/* --------------------------------------------------------------- dispatch */

/* Which side of a bargain a message to agent me is for follows from the
 * roles, not from a record: a job's agent only buys; a basic agent sells
 * services to jobs' agents and buys bundles from resource sellers. */
static int from_seller(const bgm_world_t *w, uint32_t me, const bgm_msg_t *m)
{
    return me < w->first_basic || is_resource(w, m->from);
}

static int from_buyer_of_service(const bgm_world_t *w, uint32_t me, const bgm_msg_t *m)
{
    return me >= w->first_basic && me < w->first_resource && m->from >= 1 &&
           m->from < w->first_basic;
}

static void buyer_committed(bgm_world_t *w, uint32_t me, const bgm_msg_t *m)
{
    req_t *r = &w->reqs[m->req];
    if (m->attempt != r->attempt || r->buyer != me)
        return;
    if (r->state == RQ_NEGOTIATE || r->state == RQ_WAIT || r->state == RQ_COMMITTED) {
        r->state = RQ_COMMITTED;
        r->price = m->price;
        r->tseq++; /* no phase timeout while committed: the deadline rules */
    }
}


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
    if (m->type != M_GENES && m->type != M_CFP && m->req >= w->nreq)
        return BG_ERR_INVALID;
    if (is_resource(w, me)) {
        route(w, bgm_resource_on_message(resource_machine(w, me), m, now, agent_alive(w, me), w->ob),
              now);
        return w->failure;
    }
    req_t *r = m->type == M_GENES ? NULL : &w->reqs[m->req];
    switch (m->type) {
    case M_MATCH: {
        deal_t d = {m->origin, m->req, m->attempt, m->good, m->a, m->c, m->price, m->b};
        if (!service_agreed(w, me, &d, now)) {
            bgm_msg_t c = msg(M_CANCEL, me, m->origin, m->req, m->attempt);
            send(w, &c);
        }
        break;
    }
    case M_RFAIL:
        if (r->state != RQ_DONE && r->state != RQ_FAILED)
            final_fail(w, m->req, now);
        break;
    case M_RCONFIRM:
        on_rconfirm(w, me, m, now);
        break;
    case M_CONFIRM:
        buyer_on_delivery(w, me, m, now);
        break;
    case M_TAKE:
    case M_REFUSE:
        if (from_buyer_of_service(w, me, m))
            seller_on_answer(w, me, m);
        break;
    case M_CANCEL:
        if (m->attempt == r->attempt && r->state == RQ_COMMITTED)
            attempt_failed(w, m->req, now);
        break;
    case M_CFP:
        on_cfp(w, me, m);
        break;
    case M_PROPOSE:
        if (m->attempt == r->attempt && r->state == RQ_DISCOVER) {
            nego_state_t *g = ng(w, r);
            if (g->nprop < BGM_MAX_PROPOSALS)
                g->prop[g->nprop++] = (proposal_t){m->from, m->price, m->a};
        }
        break;
    case M_OFFER:
        if (from_seller(w, me, m))
            buyer_on_offer(w, me, m, now);
        else
            seller_on_offer(w, me, m, now);
        break;
    case M_ACCEPT:
        if (from_seller(w, me, m))
            buyer_committed(w, me, m);
        else
            seller_on_accept(w, me, m, now);
        break;
    case M_REJECT:
        if (r->buyer == me && m->attempt == r->attempt && m->from == r->seller &&
            (r->state == RQ_NEGOTIATE || r->state == RQ_COMMITTED))
            next_proposal(w, m->req, now);
        break;
    case M_GENES:
        learn_meet(w, me, m);
        break;
    case M_LIST:
        if (m->attempt == r->attempt && r->state == RQ_WAIT) {
            nego_state_t *g = ng(w, r);
            g->nprop = m->ncand;
            for (int i = 0; i < m->ncand; i++)
                g->prop[i] = (proposal_t){m->cand[i], m->cand_price[i], m->cand_speed[i]};
            g->next_prop = 0;
            begin_nego(w, m->req, now);
        }
        break;
    case M_ORDER:
        /* At the posted price, while the buyer's order stands. */
        if (m->good >= 0 && m->good < BGM_SERVICE_TYPES && now <= m->cand_price[2] &&
            from_buyer_of_service(w, me, m)) {
            const agent_t *s = &w->agents[me];
            double lim = s->posted[m->good] / (1.0 + w->cfg.baseline.markup);
            seller_commit(w, me, m, m->price, lim, now);
        }
        break;
    default:
        return BG_ERR_INVALID;
    }
    return w->failure;
}

static void new_job(bgm_world_t *w, uint32_t me, double now)
{
    agent_t *c = &w->agents[me];
    const bgm_config_t *cfg = &w->cfg;
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
    uint32_t jid = w->njob++;
    job_t *j = &w->jobs[jid];
    memset(j, 0, sizeof *j);
    j->agent = me;
    j->arrival = now;
    double total = 0.0;
    for (int i = 0; i < cfg->demand.plan_count; i++)
        total += cfg->demand.plans[i].weight;
    double u = bgm_rng_uniform(&c->drng) * total;
    int plan = 0;
    while (plan < cfg->demand.plan_count - 1 && u >= cfg->demand.plans[plan].weight)
        u -= cfg->demand.plans[plan++].weight;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        if (!cfg->demand.plans[plan].services[t])
            continue;
        uint32_t rid = new_req(w);
        if (rid == UINT32_MAX)
            return;
        req_t *r = &w->reqs[rid];
        r->layer = 0;
        r->good = t;
        r->buyer = me;
        r->job = jid;
        int span = cfg->demand.work_max - cfg->demand.work_min + 1;
        r->work = cfg->demand.work_min + (int)bgm_rng_below(&c->drng, (uint32_t)span);
        r->limit = cfg->demand.valuation_mean *
                   (1.0 + cfg->demand.valuation_spread * (2.0 * bgm_rng_uniform(&c->drng) - 1.0));
        r->created = now;
        r->deadline = now + cfg->demand.deadline;
        w->jobs[jid].items++;
        w->service_requests += 1.0;
        c->requested[t] += 1.0;
        c->valuation_sum[t] += r->limit;
        timer(w, me, r->deadline, T_DEADLINE, rid);
        start_acquire(w, rid, now);
    }
}

static double next_arrival(bgm_world_t *w, agent_t *c, double now)
{
    double mean = w->cfg.demand.interarrival_mean;
    if (w->cfg.demand.shock_time >= 0.0 && now >= w->cfg.demand.shock_time)
        mean /= w->cfg.demand.shock_factor;
    return now + bgm_rng_exponential(&c->drng, mean);
}

bg_status bgm_world_on_timer(bgm_world_t *w, uint32_t me, int kind, uint64_t arg, double now)
{
    if (me >= w->nagents)
        return BG_ERR_INVALID;
    agent_t *a = &w->agents[me];
    uint32_t rid = (uint32_t)(arg & 0xffffffffu);
    uint32_t hi = (uint32_t)(arg >> 32);
    int alive = agent_alive(w, me);
    const bgm_dynamics_t *dy = w->p.dynamics;
    if (is_resource(w, me) &&
        (kind == T_RELEASE || kind == T_RELEASE_PART || kind == T_LEARN)) {
        route(w, bgm_resource_on_timer(resource_machine(w, me), kind, arg, now, alive, w->ob), now);
        return w->failure;
    }
    switch (kind) {
    case T_ARRIVAL: {
        if (alive)
            new_job(w, me, now);
        double t = next_arrival(w, a, now);
        if (t < w->arrival_end)
            timer(w, me, t, T_ARRIVAL, 0);
        break;
    }
    case T_CLEAR:
        route(w, bgm_market_agent_on_timer(w->ma, kind, arg, now, w->ob), now);
        break;
    case T_REQ: {
        req_t *r = &w->reqs[rid];
        if (hi != r->tseq || r->state == RQ_DONE || r->state == RQ_FAILED)
            break;
        if (!alive) {
            final_fail(w, rid, now);
        } else if (r->state == RQ_DISCOVER) {
            nego_state_t *g = ng(w, r);
            if (g->nprop == 0)
                w->timeouts += 1.0; /* nobody answered the call for proposals */
            qsort(g->prop, (size_t)g->nprop, sizeof g->prop[0], cmp_prop);
            g->next_prop = 0;
            begin_nego(w, rid, now);
        } else if (r->state == RQ_NEGOTIATE || r->state == RQ_COMMITTED) {
            w->timeouts += 1.0;
            r->state = RQ_NEGOTIATE;
            r->attempt++; /* late answers from that seller are now stale */
            next_proposal(w, rid, now);
        } else if (r->state == RQ_WAIT) {
            w->timeouts += 1.0;
            attempt_failed(w, rid, now);
        }
        break;
    }
    case T_DEADLINE: {
        uint32_t id = (uint32_t)(arg & 0x7fffffffffffffffULL);
        int grace = (arg >> 63) != 0;
        req_t *r = &w->reqs[id];
        if (r->state == RQ_DONE || r->state == RQ_FAILED)
            break;
        if (r->state == RQ_COMMITTED && !grace && alive) {
            timer(w, me, now + BGM_COMMIT_GRACE, T_DEADLINE, (uint64_t)id | (1ULL << 63));
            break;
        }
        w->timeouts += 1.0;
        r->attempt++;
        final_fail(w, id, now);
        break;
    }
    case T_RETRY: {
        req_t *r = &w->reqs[rid];
        if (hi == r->attempt && r->state == RQ_IDLE)
            start_acquire(w, rid, now);
        break;
    }
    case T_RELEASE: /* a basic seller's slot (resource sellers: bgm_resource) */
        /* A delivery never answered (lost on the way) is void by now. */
        if (rid < w->nreq)
            book_delivery(w, rid, 0, now);
        if (a->used > 0)
            a->used--;
        announce(w, me);
        if (w->p.mechanism == BGM_MECH_CENTRAL) {
            bgm_msg_t m = msg(M_FREE, me, 0, rid, 0);
            send(w, &m);
        }
        break;
    case T_LEARN: {
        if (alive && a->ndeg > 0) {
            uint32_t k = bgm_rng_below(&a->rng, (uint32_t)a->ndeg);
            uint32_t other = a->nbr[k];
            if (a->nsame[k]) {
                bgm_msg_t m = msg(M_GENES, me, other, 0, 0);
                double g[BGM_GENE_COUNT];
                bgm_genes_pack(&a->genes, g);
                memcpy(m.cand_price, g, sizeof g);
                m.price = a->fitness;
                m.a = 1.0;
                send(w, &m);
            }
        }
        double t = now + w->cfg.catallactic.learning_period * (0.5 + bgm_rng_uniform(&a->rng));
        if (t < w->horizon)
            timer(w, me, t, T_LEARN, 0);
        break;
    }
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
        return BG_ERR_INVALID;
    }
    return w->failure;
}

bg_status bgm_world_start(bgm_world_t *w, const bgm_sink_t *sink, double now)
{
    w->sink = *sink;
    const bgm_config_t *c = &w->cfg;
    int mech = w->p.mechanism;
    route(w, bgm_market_agent_start(w->ma, now, w->ob), now);
    for (uint32_t i = 1; i < w->nagents; i++) {
        agent_t *a = &w->agents[i];
        if (a->role == BGM_ROLE_COMPLEX) {
            timer(w, i, next_arrival(w, a, now), T_ARRIVAL, 0);
        } else if (a->role == BGM_ROLE_BASIC && mech != BGM_MECH_CATALLACTIC) {
            for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
                if (!a->sells[t])
                    continue;
                bgm_msg_t m = msg(M_ASK, i, 0, 0, 0);
                m.good = (int16_t)t;
                m.price = mech == BGM_MECH_BASELINE ? a->posted[t] : reservation(a, t);
                m.a = a->slots;
                a->announced[t] = reservation(a, t);
                send(w, &m);
            }
        } else if (a->role == BGM_ROLE_RESOURCE) {
            route(w, bgm_resource_start(resource_machine(w, i), now, w->ob), now);
            continue;
        }
        if (mech == BGM_MECH_CATALLACTIC)
            timer(w, i, now + c->catallactic.learning_period * bgm_rng_uniform(&a->rng), T_LEARN, 0);
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

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Quantile by the nearest-rank method on a sorted copy; NaN when empty. */
static double quantile(const double *v, size_t n, double q)
{
    if (n == 0)
        return NAN;
    double *s = malloc(n * sizeof *s);
    if (!s)
        return NAN;
    memcpy(s, v, n * sizeof *s);
    qsort(s, n, sizeof *s, cmp_double);
    size_t k = (size_t)ceil(q * (double)n);
    double r = s[k == 0 ? 0 : k - 1];
    free(s);
    return r;
}

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
static bgm_opt_request_t opt_request(const req_t *x)
{
    return (bgm_opt_request_t){x->good, x->work, x->limit, x->created,
                               x->deadline + BGM_COMMIT_GRACE};
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
        if (w->reqs[i].layer == 0) {
            bgm_opt_request_t x = opt_request(&w->reqs[i]);
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
        if (w->reqs[i].layer == 0)
            q[nq++] = opt_request(&w->reqs[i]);
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
    m[BGM_M_REQUESTS] = w->service_requests;
    m[BGM_M_CONTRACTS] = svc;
    m[BGM_M_MESSAGES] = w->msgs;
    m[BGM_M_BYTES] = w->bytes;
    bgm_market_agent_counts(w->ma, &m[BGM_M_COMBEX_EXACT], &m[BGM_M_COMBEX_GREEDY]);
    m[BGM_M_TIMEOUTS] = w->timeouts;
    if (w->service_requests > 0)
        m[BGM_M_ALLOCATION_RATE] = svc / w->service_requests;
    if (w->resource_requests > 0)
        m[BGM_M_RESOURCE_ALLOCATION_RATE] = w->bundles / w->resource_requests;
    m[BGM_M_ACCESS_TIME_MEDIAN] = quantile(w->acc_s, w->nacc_s, 0.5);
    m[BGM_M_ACCESS_TIME_P99] = quantile(w->acc_s, w->nacc_s, 0.99);
    m[BGM_M_RESOURCE_ACCESS_TIME_MEDIAN] = quantile(w->acc_r, w->nacc_r, 0.5);
    m[BGM_M_RESOURCE_ACCESS_TIME_P99] = quantile(w->acc_r, w->nacc_r, 0.99);
    if (svc > 0) {
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
    snprintf(buf, n, "n%d_d%g_%s", w->p.nodes, w->p.density, w->p.dynamics->name);
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
            for (int t = 0; t < BGM_SERVICE_TYPES; t++)
                if (a->requested[t] > 0)
                    fprintf(f, "%s,%d,%s,%u,%s,%s,%.0f,%.9g\n", sc, w->p.replication, mech, i,
                            role, bgm_good_names[t], a->requested[t],
                            a->valuation_sum[t] / a->requested[t]);
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
