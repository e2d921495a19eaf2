#include "bga_market.h"

#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zmq.h>

#include "bga_rseller.h"
#include "bga_transport.h"
#include "bgm_catallactic.h"

#define NEGO_MAX 64
#define SEEN_MAX 128
#define SELLER_ROUNDS 12 /* the simulator's default catallactic.max_rounds */
#define BUY_WAIT 10.0    /* s: a resource purchase the broker never answers is dropped */
#define RATE_WEIGHT 0.5  /* weight of the last asking rate in the expected one */
/* A basic seller bids for a contract's resources at most this many times
 * what it expects them to cost (the rates it priced into its floor): room
 * for a resource seller whose ask rose with its load (1 + load slope, 1.5
 * by default, at full load), and no more. Bidding the whole surplus of the
 * service sale instead would hand the job's budget on to layer 1. */
#define RESOURCE_BID_HEADROOM 1.5

enum { ROLE_BASIC = 0, ROLE_RESOURCE = 1 };

/* A bargain in progress with the broker's buyer for (job, good); the good
 * tells the role (services 0..2, resources 3..4). */
typedef struct nego {
    int used;
    uint64_t job;
    int good;
    double at; /* when it proposed */
    bgm_nego_t side;
} nego_t;

typedef enum held_state { H_BUYING = 1, H_HELD = 2 } held_state;

/* A service contract: agreed and buying its resources, or held. */
typedef struct held {
    held_state state;
    uint64_t job;
    int good;
    double quantity, price, floor, cores, until;
} held_t;

typedef struct role {
    uint32_t id;
    uint32_t neighbours[BGA_MMSG_MAX_NEIGHBOURS];
    int nneighbours;
} role_t;

struct bga_market {
    bga_market_config_t c;
    char name[BGA_MMSG_NAME_MAX], endpoint[BGA_MMSG_ENDPOINT_MAX];
    void *socket;
    role_t role[2];
    double next_beat;
    held_t *held; /* slots entries, used first */
    int used;
    bga_rseller_t *rs;  /* the resource seller role (NULL: none) */
    double rate[2];     /* expected resource rates: per core-second, per GiB-second */
    nego_t nego[NEGO_MAX];
    uint64_t seen[SEEN_MAX]; /* CFPs the basic seller handled: ((job·1024 + attempt)·8 + good)·2 */
    int nseen;
    bgm_rng_t rng;
    bgm_genes_t genes;
    /* The process's compute thread pools (OpenBLAS, OpenMP: CHOLMOD's
     * factorization and the BLAS under it), if linked, and their sizes at
     * start: a job's cap never raises them. */
    void (*blas_set)(int);
    void (*omp_set)(int);
    int blas_max, omp_max;
};

static double host_cores(void)
{
    const long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (double)n : 1.0;
}

/* MemTotal in GiB; 1 if /proc/meminfo cannot be read. */
static double host_memory(void)
{
    FILE *f = fopen("/proc/meminfo", "r");
    double gib = 1.0;
    char line[256];
    while (f && fgets(line, sizeof line, f)) {
        unsigned long long kib = 0;
        if (sscanf(line, "MemTotal: %llu kB", &kib) == 1) {
            gib = (double)kib / (1024.0 * 1024.0);
            break;
        }
    }
    if (f)
        fclose(f);
    return gib;
}

void bga_market_config_default(bga_market_config_t *c)
{
    memset(c, 0, sizeof *c);
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        c->floor[g] = 1.0;
    c->margin = 0.2;
    c->load_slope = 0.5;
    c->heartbeat = 0.5;
    c->slots = 4;
    const double cores[3] = {1, 2, 1}, memory[3] = {1, 4, 2};
    memcpy(c->unit_cores, cores, sizeof cores);
    memcpy(c->unit_memory, memory, sizeof memory);
    c->lease = 3600;
    c->cores = host_cores();
    c->memory = host_memory();
    c->res_floor[0] = 1e-5;
    c->res_floor[1] = 2e-6;
    c->res_margin = 0.2;
    c->res_load_slope = 0.5;
}

static int sells(const bga_market_t *m, int good)
{
    if (good == BGA_MMSG_GOODS - 2)
        return m->c.cores > 0;
    if (good == BGA_MMSG_GOODS - 1)
        return m->c.cores > 0 && m->c.memory > 0;
    return good >= 0 && good < 3 && (m->c.services & (1u << good));
}

/* The service floor: own cost plus one contract's resources at the
 * expected rates over one lease. */
static double service_floor(const bga_market_t *m, int good)
{
    return m->c.floor[good] +
           (m->rate[0] * m->c.unit_cores[good] + m->rate[1] * m->c.unit_memory[good]) * m->c.lease;
}

double bga_market_price(const bga_market_t *m, int good)
{
    if (!sells(m, good))
        return 0;
    if (good >= 3)
        return bga_rseller_price(m->rs, good);
    return service_floor(m, good) * (1 + m->c.margin) *
           (1 + m->c.load_slope * (double)m->used / (double)m->c.slots);
}

int bga_market_used(const bga_market_t *m)
{
    return m->used;
}

double bga_market_cores_used(const bga_market_t *m)
{
    return m->rs ? bga_rseller_used(m->rs, 0) : 0;
}

uint32_t bga_market_id(const bga_market_t *m)
{
    return m->role[ROLE_BASIC].id;
}

uint32_t bga_market_resource_id(const bga_market_t *m)
{
    return m->role[ROLE_RESOURCE].id;
}

static int covers(const held_t *h, uint64_t job)
{
    return h->state == H_HELD && job >= h->job && job - h->job < BGA_MARKET_JOB_SPAN;
}

int bga_market_holds(const bga_market_t *m, uint64_t job)
{
    for (int i = 0; i < m->used; i++)
        if (covers(&m->held[i], job))
            return 1;
    return 0;
}

/* A function of the running process by name (NULL if none); memcpy, as
 * ISO C has no cast from an object pointer to a function pointer. */
static void *lookup(const char *name)
{
    void *self = dlopen(NULL, RTLD_LAZY);
    void *f = self ? dlsym(self, name) : NULL;
    if (self)
        dlclose(self);
    return f;
}

static void find_thread_pools(bga_market_t *m)
{
    void *p = lookup("openblas_set_num_threads");
    int (*get)(void) = NULL;
    void *g = lookup("openblas_get_num_threads");
    if (p && g) {
        memcpy(&m->blas_set, &p, sizeof p);
        memcpy(&get, &g, sizeof g);
        m->blas_max = get();
    }
    p = lookup("omp_set_num_threads");
    g = lookup("omp_get_max_threads");
    if (p && g) {
        memcpy(&m->omp_set, &p, sizeof p);
        memcpy(&get, &g, sizeof g);
        m->omp_max = get();
    }
}

int bga_market_admit(bga_market_t *m, uint64_t job)
{
    if (!bga_market_holds(m, job))
        return 0;
    const double cores = bga_market_cores(m, job);
    if (cores >= 1) {
        const int n = cores < 4096 ? (int)cores : 4096;
        if (m->blas_set && m->blas_max > 0)
            m->blas_set(n < m->blas_max ? n : m->blas_max);
        if (m->omp_set && m->omp_max > 0)
            m->omp_set(n < m->omp_max ? n : m->omp_max);
    }
    return 1;
}

double bga_market_cores(const bga_market_t *m, uint64_t job)
{
    double cores = 0;
    for (int i = 0; i < m->used; i++)
        if (covers(&m->held[i], job))
            cores += m->held[i].cores;
    return cores;
}

static bg_status send_msg(bga_market_t *m, const bga_mmsg_t *msg, bg_error_t *err)
{
    bga_frames_t f;
    bg_status st = bga_mmsg_encode(msg, &f, err);
    if (st != BG_OK)
        return st;
    st = bga_send(m->socket, NULL, &f, err);
    bga_frames_free(&f);
    return st;
}

/* A message from one of the roles: its id and role flag set. */
static void init_from(const bga_market_t *m, bga_mmsg_t *msg, int type, int role)
{
    bga_mmsg_init(msg, type);
    msg->agent = m->role[role].id;
    msg->resource = role;
}

/* What a role says about itself in REGISTER and HEARTBEAT. */
static void describe(const bga_market_t *m, int role, bga_mmsg_t *msg)
{
    snprintf(msg->name, sizeof msg->name, "%s", m->name);
    snprintf(msg->endpoint, sizeof msg->endpoint, "%s", m->endpoint);
    if (role == ROLE_RESOURCE) {
        bga_rseller_describe(m->rs, msg);
        return;
    }
    msg->services = m->c.services;
    msg->slots = m->c.slots;
    msg->free_slots = m->c.slots - m->used;
    for (int g = 0; g < 3; g++) {
        msg->floor[g] = sells(m, g) ? service_floor(m, g) : 0;
        msg->prices[g] = bga_market_price(m, g);
    }
    msg->margin = m->c.margin;
    msg->load_slope = m->c.load_slope;
}

bg_status bga_market_new(void *zmq_ctx, const bga_market_config_t *config, double now,
                         bga_market_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = BG_OK;
    const bga_market_config_t *c = config;
    if (c->slots < 1 || c->slots > 4096 || !(c->heartbeat > 0) || !c->broker)
        return bg_error_set(err, BG_ERR_INVALID, "market seller: slots, heartbeat or broker invalid");
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        if (!(c->floor[g] >= 0 && c->floor[g] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: floor[%d] out of range", g);
    if (!(c->margin >= 0 && c->margin < 1e6) || !(c->load_slope >= 0 && c->load_slope < 1e6) ||
        !(c->res_margin >= 0 && c->res_margin < 1e6) ||
        !(c->res_load_slope >= 0 && c->res_load_slope < 1e6))
        return bg_error_set(err, BG_ERR_INVALID, "market seller: margin or load slope out of range");
    if (!(c->cores >= 0 && c->cores <= 1e6) || !(c->memory >= 0 && c->memory <= 1e9) ||
        !(c->lease > 0 && c->lease <= 1e7))
        return bg_error_set(err, BG_ERR_INVALID,
                            "market seller: cores in [0, 1e6], memory in [0, 1e9] GiB, lease in "
                            "(0, 1e7] s");
    for (int k = 0; k < 2; k++)
        if (!(c->res_floor[k] >= 0 && c->res_floor[k] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: resource floor out of range");
    for (int g = 0; g < 3; g++)
        if (!(c->unit_cores[g] >= 0 && c->unit_cores[g] <= 1e6) ||
            !(c->unit_memory[g] >= 0 && c->unit_memory[g] <= 1e9))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: unit_cores/unit_memory[%d]", g);
    bga_market_t *m = calloc(1, sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the market seller");
    m->c = *c;
    snprintf(m->name, sizeof m->name, "%s", c->name ? c->name : "agent");
    snprintf(m->endpoint, sizeof m->endpoint, "%s", c->endpoint ? c->endpoint : "");
    m->c.name = m->name;
    m->c.endpoint = m->endpoint;
    m->c.broker = NULL;
    /* A unit never needs more than this daemon's host offers, so a small
     * host still serves every good it sells. */
    const double cap_cores = c->cores > 0 ? c->cores : host_cores();
    const double cap_memory = c->cores > 0 && c->memory > 0 ? c->memory : host_memory();
    for (int g = 0; g < 3; g++) {
        if (m->c.unit_cores[g] > cap_cores)
            m->c.unit_cores[g] = cap_cores;
        if (m->c.unit_memory[g] > cap_memory)
            m->c.unit_memory[g] = cap_memory;
    }
    for (int k = 0; k < 2; k++)
        m->rate[k] = c->res_floor[k] * (1 + c->res_margin);
    m->held = calloc((size_t)c->slots, sizeof *m->held);
    m->socket = zmq_socket(zmq_ctx, ZMQ_DEALER);
    if (!m->held || !m->socket) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot create the market seller's socket");
        goto fail;
    }
    const int linger = 500;
    zmq_setsockopt(m->socket, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_connect(m->socket, config->broker) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot connect to the broker %s: %s", config->broker,
                          zmq_strerror(errno));
        goto fail;
    }
    m->next_beat = now; /* the first tick registers */
    uint64_t seed = 1469598103934665603ull;
    for (const char *p = m->name; *p; p++)
        seed = (seed ^ (uint8_t)*p) * 1099511628211ull;
    bgm_rng_seed(&m->rng, seed);
    bgm_genes_random(&m->genes, &m->rng);
    if (c->cores > 0) {
        const bga_rseller_config_t rc = {.cores = c->cores,
                                         .memory = c->memory,
                                         .floor = {c->res_floor[0], c->res_floor[1]},
                                         .margin = c->res_margin,
                                         .load_slope = c->res_load_slope,
                                         .lease = c->lease,
                                         .seed = seed ^ 0x9e3779b97f4a7c15ull};
        if ((st = bga_rseller_new(&rc, &m->rs, err)) != BG_OK)
            goto fail;
    }
    find_thread_pools(m);
    *out = m;
    return BG_OK;
fail:
    bga_market_destroy(&m);
    return st;
}

void bga_market_destroy(bga_market_t **pm)
{
    if (!pm || !*pm)
        return;
    if ((*pm)->socket)
        zmq_close((*pm)->socket);
    bga_rseller_destroy(&(*pm)->rs);
    free((*pm)->held);
    free(*pm);
    *pm = NULL;
}

void *bga_market_socket(const bga_market_t *m)
{
    return m->socket;
}

static void drop_held(bga_market_t *m, int i)
{
    m->held[i] = m->held[--m->used];
}

/* Leases that ran out end their contracts; a purchase never answered is
 * given up. */
static bg_status expire(bga_market_t *m, double now, bg_error_t *err)
{
    for (int i = m->used; i-- > 0;)
        if (now >= m->held[i].until)
            drop_held(m, i);
    return m->rs ? bga_rseller_tick(m->rs, now, err) : BG_OK;
}

bg_status bga_market_tick(bga_market_t *m, double now, bg_error_t *err)
{
    bg_status est = expire(m, now, err);
    if (est != BG_OK)
        return est;
    if (now < m->next_beat)
        return BG_OK;
    m->next_beat = now + m->c.heartbeat;
    bg_status st = BG_OK;
    const int roles = m->c.cores > 0 ? 2 : 1;
    for (int r = 0; r < roles && st == BG_OK; r++) {
        bga_mmsg_t msg;
        /* Until the broker answers, every beat is a registration: a
         * broker that started late, or restarted, still learns who this is. */
        init_from(m, &msg, m->role[r].id ? BGA_MM_HEARTBEAT : BGA_MM_REGISTER, r);
        describe(m, r, &msg);
        st = send_msg(m, &msg, err);
    }
    return st;
}

/* The basic seller's side of RELEASE (the resource seller's is its host's). */
static void release_job(bga_market_t *m, uint64_t job)
{
    for (int i = 0; i < NEGO_MAX; i++)
        if (m->nego[i].used && m->nego[i].job == job)
            m->nego[i].used = 0;
    for (int i = m->used; i-- > 0;)
        if (m->held[i].job == job)
            drop_held(m, i);
}

static void answer_init(const bga_market_t *m, bga_mmsg_t *r, int type, int role,
                        const bga_mmsg_t *in)
{
    init_from(m, r, type, role);
    r->job = in->job;
    r->good = in->good;
    r->quantity = in->quantity;
    r->price = in->price;
}

static held_t *held_find(bga_market_t *m, uint64_t job, int good, held_state state)
{
    for (int i = 0; i < m->used; i++)
        if (m->held[i].job == job && m->held[i].good == good && m->held[i].state == state)
            return &m->held[i];
    return NULL;
}

/* The basic seller's answer about a service contract it agreed to. */
static void about_held(const bga_market_t *m, bga_mmsg_t *r, int type, const held_t *h)
{
    init_from(m, r, type, ROLE_BASIC);
    r->job = h->job;
    r->good = h->good;
    r->quantity = h->quantity;
    r->price = h->price;
}

static bg_status confirm(bga_market_t *m, const held_t *h, bg_error_t *err)
{
    bga_mmsg_t r;
    about_held(m, &r, BGA_MM_CONFIRM, h);
    r.slots = m->c.slots;
    r.free_slots = m->c.slots - m->used;
    r.floor[h->good] = h->floor;
    return send_msg(m, &r, err);
}

/* The basic seller agrees to (job, good) at the price when it has a slot
 * and the price covers its floor; it keeps the slot and buys the unit's
 * resources on layer 1 for at most what the contract leaves over its own
 * cost and RESOURCE_BID_HEADROOM times their expected cost, and confirms
 * once they are bought (on_rbought). */
static bg_status basic_order(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    bga_mmsg_t r;
    answer_init(m, &r, BGA_MM_REFUSE, ROLE_BASIC, in);
    /* A resource good addressed to this role is not its to sell. */
    const int sold = in->good >= 0 && in->good < 3 && sells(m, in->good);
    const double floor_g = sold ? service_floor(m, in->good) : 0;
    if (!sold)
        snprintf(r.reason, sizeof r.reason, "does not sell %d", in->good);
    else if (held_find(m, in->job, in->good, H_BUYING) || held_find(m, in->job, in->good, H_HELD))
        snprintf(r.reason, sizeof r.reason, "already sold this good for job %llu",
                 (unsigned long long)in->job);
    else if (m->used >= m->c.slots)
        snprintf(r.reason, sizeof r.reason, "no free slot");
    else if (in->price < floor_g)
        snprintf(r.reason, sizeof r.reason, "price %.6g under the floor %.6g", in->price, floor_g);
    else {
        const int g = in->good;
        held_t *h = &m->held[m->used++];
        *h = (held_t){H_BUYING, in->job, g, in->quantity, in->price, floor_g, m->c.unit_cores[g],
                      now + BUY_WAIT};
        if (m->c.unit_cores[g] <= 0 && m->c.unit_memory[g] <= 0) {
            h->state = H_HELD;
            h->until = now + m->c.lease;
            return confirm(m, h, err);
        }
        init_from(m, &r, BGA_MM_RBUY, ROLE_BASIC);
        r.job = in->job;
        r.good = g;
        r.quantity = in->quantity;
        r.cores = m->c.unit_cores[g];
        r.memory = m->c.unit_memory[g];
        r.term = m->c.lease;
        const double surplus = (in->price - m->c.floor[g]) * in->quantity,
                     expected = (m->rate[0] * r.cores + m->rate[1] * r.memory) * r.term;
        r.price = surplus < RESOURCE_BID_HEADROOM * expected ? surplus
                                                              : RESOURCE_BID_HEADROOM * expected;
        if (r.price < 0)
            r.price = 0;
    }
    return send_msg(m, &r, err);
}

static bg_status on_rbought(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    held_t *h = held_find(m, in->job, in->good, H_BUYING);
    if (!h)
        return BG_OK; /* released meanwhile: the broker drops the purchase */
    h->state = H_HELD;
    h->until = now + m->c.lease;
    for (int k = 0; k < 2; k++)
        if (in->prices[3 + k] > 0)
            m->rate[k] = (1 - RATE_WEIGHT) * m->rate[k] + RATE_WEIGHT * in->prices[3 + k];
    return confirm(m, h, err);
}

static bg_status on_rfail(bga_market_t *m, const bga_mmsg_t *in, bg_error_t *err)
{
    held_t *h = held_find(m, in->job, in->good, H_BUYING);
    if (!h)
        return BG_OK;
    bga_mmsg_t r;
    about_held(m, &r, BGA_MM_REFUSE, h);
    snprintf(r.reason, sizeof r.reason, "no resources: %.150s", in->reason);
    drop_held(m, (int)(h - m->held));
    return send_msg(m, &r, err);
}

static bg_status on_order(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    return basic_order(m, in, now, err);
}

static nego_t *nego_find(bga_market_t *m, uint64_t job, int good)
{
    for (int i = 0; i < NEGO_MAX; i++)
        if (m->nego[i].used && m->nego[i].job == job && m->nego[i].good == good)
            return &m->nego[i];
    return NULL;
}

static bg_status reply_price(bga_market_t *m, int type, const bga_mmsg_t *in, double price,
                             bg_error_t *err)
{
    bga_mmsg_t r;
    answer_init(m, &r, type, in->resource, in);
    r.price = price;
    r.term = in->term;
    r.attempt = in->attempt; /* a PROPOSE names the round of the call it answers */
    return send_msg(m, &r, err);
}

/* Whether the basic seller could sell this call's good now. */
static int can_propose(const bga_market_t *m, const bga_mmsg_t *in)
{
    return in->good < 3 && sells(m, in->good) && m->used < m->c.slots;
}

/* The basic seller's catallactic discovery: propose if it can sell, and
 * pass the call on to its overlay neighbours (relayed by the broker) while
 * hops remain. Each (job, attempt, good) call is handled once, however
 * many paths bring it. */
static bg_status on_cfp(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    const int role = ROLE_BASIC;
    const uint64_t key = ((in->job * 1024 + (uint64_t)in->attempt) * 8 + (uint64_t)in->good) << 1;
    for (int i = 0; i < m->nseen; i++)
        if (m->seen[i] == key)
            return BG_OK;
    if (m->nseen == SEEN_MAX)
        memmove(m->seen, m->seen + 1, (SEEN_MAX - 1) * sizeof *m->seen), m->nseen--;
    m->seen[m->nseen++] = key;
    bg_status st = BG_OK;
    /* A new round means the buyer is no longer bargaining over this good
     * (it starts one only when no bargain is pending): restart ours. */
    nego_t *stale = nego_find(m, in->job, in->good);
    if (stale)
        stale->used = 0;
    if (can_propose(m, in)) {
        /* A buyer that took another proposer never says so: when the table
         * is full the oldest proposal is forgotten. */
        nego_t *n = &m->nego[0];
        for (int i = 0; i < NEGO_MAX && n->used; i++)
            if (!m->nego[i].used || m->nego[i].at < n->at)
                n = &m->nego[i];
        const double floor_g = service_floor(m, in->good);
        const double open =
            bgm_nego_opening(BGM_SIDE_SELLER, floor_g, bga_market_price(m, in->good), m->c.margin);
        *n = (nego_t){1, in->job, in->good, now, {0}};
        bgm_nego_open(&n->side, BGM_SIDE_SELLER, floor_g, open, &m->genes, SELLER_ROUNDS);
        st = reply_price(m, BGA_MM_PROPOSE, in, n->side.current, err);
    }
    const role_t *me = &m->role[role];
    for (int i = 0; st == BG_OK && in->hops > 1 && i < me->nneighbours; i++) {
        bga_mmsg_t r;
        init_from(m, &r, BGA_MM_RELAY, role);
        r.job = in->job;
        r.good = in->good;
        r.target = me->neighbours[i];
        r.origin = in->origin ? in->origin : me->id;
        r.hops = in->hops - 1;
        r.attempt = in->attempt;
        r.quantity = in->quantity;
        r.term = in->term;
        st = send_msg(m, &r, err);
    }
    return st;
}

/* Commits to a bargain at `price`, as an order at that price. */
static bg_status commit(bga_market_t *m, nego_t *n, const bga_mmsg_t *in, double price, double now,
                        bg_error_t *err)
{
    n->used = 0;
    bga_mmsg_t o = *in;
    o.price = price;
    return on_order(m, &o, now, err);
}

static bg_status on_bargain(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    nego_t *n = nego_find(m, in->job, in->good);
    if (!n)
        return in->type == BGA_MM_REJECT ? BG_OK : reply_price(m, BGA_MM_REJECT, in, 0, err);
    if (in->type == BGA_MM_REJECT) {
        n->used = 0;
        return BG_OK;
    }
    if (in->type == BGA_MM_ACCEPT) /* the buyer took the seller's price */
        return commit(m, n, in, n->side.current, now, err);
    double reply = 0;
    switch (bgm_nego_respond(&n->side, in->price, &m->rng, &reply)) {
    case BGM_NEGO_ACCEPT:
        return commit(m, n, in, reply, now, err);
    case BGM_NEGO_COUNTER:
        return reply_price(m, BGA_MM_OFFER, in, reply, err);
    default:
        n->used = 0;
        return reply_price(m, BGA_MM_REJECT, in, 0, err);
    }
}

static bg_status send_cb(void *ctx, const bga_mmsg_t *msg, bg_error_t *err)
{
    return send_msg(ctx, msg, err);
}

static bg_status handle(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    const int role = in->resource ? ROLE_RESOURCE : ROLE_BASIC;
    if (in->type == BGA_MM_REGISTERED) {
        m->role[role].id = in->agent;
        m->role[role].nneighbours = in->nneighbours;
        memcpy(m->role[role].neighbours, in->neighbours, sizeof m->role[role].neighbours);
        if (role == ROLE_RESOURCE && m->rs)
            return bga_rseller_registered(m->rs, in->agent, in->neighbours, in->nneighbours, err);
        return BG_OK;
    }
    if (in->type == BGA_MM_ERROR) {
        /* The broker forgot this agent (it restarted, or dropped it as
         * dead): both roles register again. */
        m->role[0].id = m->role[1].id = 0;
        m->next_beat = now;
        return BG_OK;
    }
    /* The resource role's messages go to its role machine's host. */
    if (role == ROLE_RESOURCE)
        return m->rs ? bga_rseller_on_message(m->rs, in, now, send_cb, m, err) : BG_OK;
    switch (in->type) {
    case BGA_MM_CFP:
        return on_cfp(m, in, now, err);
    case BGA_MM_OFFER:
    case BGA_MM_ACCEPT:
    case BGA_MM_REJECT:
        return on_bargain(m, in, now, err);
    case BGA_MM_ORDER:
        return on_order(m, in, now, err);
    case BGA_MM_RBOUGHT:
        return on_rbought(m, in, now, err);
    case BGA_MM_RFAIL:
        return on_rfail(m, in, err);
    case BGA_MM_RELEASE:
        release_job(m, in->job);
        return BG_OK;
    default:
        return BG_OK; /* not for a seller; ignored */
    }
}

static bg_status answer_malformed(bga_market_t *m, const char *why, bg_error_t *err)
{
    bga_mmsg_t e;
    init_from(m, &e, BGA_MM_ERROR, ROLE_BASIC);
    snprintf(e.reason, sizeof e.reason, "malformed message from the broker: %.150s", why);
    return send_msg(m, &e, err);
}

bg_status bga_market_on_readable(bga_market_t *m, double now, bg_error_t *err)
{
    for (;;) {
        zmq_pollitem_t item = {m->socket, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            return BG_OK;
        bga_received_t r;
        bg_error_t rerr = BG_ERROR_INIT;
        bg_status st = bga_recv(m->socket, 0, &r, &rerr);
        if (st == BG_ERR_UNSUPPORTED)
            return BG_OK;
        if (st != BG_OK)
            return bg_error_set(err, st, "%s", rerr.message);
        bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&r, views);
        bga_mmsg_t in;
        bg_error_t derr = BG_ERROR_INIT;
        /* A malformed message from the broker is answered with an ERROR
         * naming what is wrong, and otherwise ignored: never fatal. */
        if (r.total != r.count)
            bg_error_set(&derr, BG_ERR_LIMIT, "%d frames, at most %d", r.total,
                         BGA_WIRE_MAX_FRAMES);
        else if (bga_mmsg_decode(views, r.count, &in, &derr) == BG_OK)
            st = handle(m, &in, now, err);
        bga_received_close(&r);
        if (st == BG_OK && derr.status != BG_OK)
            st = answer_malformed(m, derr.message, err);
        if (st != BG_OK)
            return st;
    }
}
