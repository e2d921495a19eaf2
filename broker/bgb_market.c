#include "bgb_market.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>
#include <unistd.h>

#include "bga_mmsg.h"
#include "bgb_auction.h"
#include "bgm_callmarket.h"
#include "bgm_catallactic.h"
#include "bgm_config.h"
#include "bgm_outbox.h"
#include "bgm_posted.h"
#include "bgm_purchase.h"
#include "bgm_strategy.h"

#define MAX_UNITS 64
#define MAX_TRIED 32
#define MAX_JOBS 1024
#define BUYER_MARKUP 0.1 /* catallactic buyer's opening below the remembered price */
/* Resource sub-job ids, apart from the callers' (the store's job ids are
 * far below 2^49; the wire header carries all 64 bits). */
#define SUB_JOB_BASE ((uint64_t)1 << 49)
/* A job's purchase machine: the ids it knows the broker's buyer
 * (the broker, as a CFP's origin names it) and the market agent by; the
 * sellers are their directory ids. The host answers for the market agent. */
#define PU_SELF 0u
#define PU_MARKET UINT32_MAX
/* Timers a job's purchase has pending at once: per request its
 * deadline, its latest phase timer and its latest retry (older ones of a
 * kind are stale, so a newer one takes their place). */
#define JOB_TIMERS (3 * MAX_UNITS + 8)
/* Answers the host gives a purchase after handling its outbox (a LIST, a
 * seller it may not have, a match): at most a few per unit at once. */
#define JOB_INBOX (4 * MAX_UNITS)
/* The purchase's discovery window doubles after at most this many quiet rounds. */
#define PU_WIDEN 3

typedef struct bidref bidref_t;
typedef struct admit admit_t;
static admit_t *admit_new(void);
static void admit_free(admit_t *a);

typedef enum unit_state { U_OPEN = 0, U_ORDERED = 1, U_DONE = 2 } unit_state;

typedef struct unit {
    int need, good;
    double quantity, limit; /* limit: per unit of work */
    unit_state state;
    uint32_t agent; /* ordered from / bought from */
    double price, seller_floor, deadline;
    double term; /* resource units: the lease (quantity × term × price is the money) */
    uint32_t tried[MAX_TRIED];
    int ntried;
    /* The purchase request's attempt when it was ordered or bid, and
     * (central services) its bid's number at the market agent. */
    uint32_t req, attempt;
    int in_book;    /* central: its bid is in the book (services: the auctioneer's) */
    double heard;   /* resource units: the seller's last price per unit-second */
    uint32_t drawn; /* catallactic: the round its job's buyer last drew a strategy for */
    uint64_t clearing; /* central: the ledger's clearing that priced its order (0: none) */
    int proposals; /* catallactic: proposals its request heard in round `round` */
    uint32_t round;
} unit_t;

typedef struct ptimer {
    double at;
    int kind;
    uint64_t arg;
} ptimer_t;

typedef struct job job_t;
struct bidref {
    job_t *j;
    unit_t *u;
};

struct job {
    int used;
    uint64_t id;
    bgb_mechanism mech;
    double budget, started, deadline;
    unit_t unit[MAX_UNITS];
    int nunits;
    uint32_t touched[MAX_UNITS]; /* agents that may hold a slot for it */
    int ntouched;
    int finished; /* outcome delivered; kept until release */
    /* Sellers it must not get: a re-purchase leaves out the agents the
     * job lost (bgb_market_buy_excluding), by directory id and by compute
     * endpoint (a hash of it: a lost agent that comes back registers
     * under a new id). */
    uint32_t excluded[MAX_TRIED];
    uint64_t excluded_ep[MAX_TRIED];
    int nexcluded;
    int admitted; /* central: its service units may bid (see admit_fitting) */
    /* The job's buyer: the simulator's purchase machine, one request per
     * unit (request id = unit index + 1), its timers, and the answers the
     * host has for it next. A resource sub-job's machine reads a copy of
     * the purchase configuration of its own (`cfg`: the host's cheapest
     * asks as the mean resource costs). */
    bgm_purchase_t *pu;
    bgm_config_t *cfg;
    ptimer_t *timers;
    int ntimers;
    bgm_msg_t *inbox;
    int ninbox;
    bgb_done_fn done;
    void *ctx;
    char label[BGB_LEDGER_LABEL_MAX];
    /* A resource sub-job: cores and memory a basic agent buys for its unit
     * of service good `sgood` of job `parent`, for `term` seconds, from
     * sellers on `host`. */
    int resource;
    uint64_t parent;
    uint32_t buyer;
    int sgood;
    double term, bought_at;
    char host[BGB_DIRECTORY_ENDPOINT_MAX];
};

struct bgb_market {
    bgb_market_config_t c;
    bgb_directory_t *dir;   /* the agents: who sells what, how to reach them */
    bgb_ledger_t *ledger;   /* the contracts made */
    job_t *jobs;            /* MAX_JOBS */
    bgm_posted_t *posted;   /* layer 1: the resource sellers' postings */
    bgm_callmarket_t *cm;   /* layer 1: the resource call markets */
    bgb_auction_t *auction; /* services: the market agent machine (auctioneer, directory) */
    uint32_t next_req;      /* service bids and queries, numbered for the market agent */
    double next_auction;    /* when the auctioneer clears next */
    double next_clear;
    struct bidref *refs;   /* central: the book's bids, MAX_JOBS * MAX_UNITS */
    struct bidref *run;    /* central: one host's bids, as many */
    admit_t *admit;        /* central: admission's placement (admit_fitting) */
    bgm_fill_t *fills;     /* central: a host's clearing, 2 * MAX_JOBS * MAX_UNITS + 2 */
    uint64_t next_sub;     /* resource sub-job ids */
    uint64_t next_request; /* service items logged */
    bgm_config_t pcfg;     /* what the purchase machines read (borrowed by each) */
    bgm_outbox_t *ob;      /* a purchase call's outbox, emptied after each */
    double memory[3];      /* catallactic: remembered price per service good */
};

void bgb_market_config_default(bgb_market_config_t *c)
{
    memset(c, 0, sizeof *c);
    c->name = "broker";
    c->period = 0.2;
    c->k = 0.5;
    c->heartbeat_timeout = 3.0;
    c->reply_timeout = 2.0;
    c->buy_timeout = 10.0;
    c->overlay_degree = 3;
    c->hops = 2;
    c->max_rounds = 12;
    c->max_contracts = 100000;
}

/* A fresh epoch in [1, 2^53): the kernel's random bytes, or (should
 * getrandom fail) the clock and the process id mixed. */
static uint64_t draw_epoch(void)
{
    uint64_t v = 0;
    if (getrandom(&v, sizeof v, 0) != (ssize_t)sizeof v) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        v = ((uint64_t)ts.tv_sec * 1000000007ull) ^ (uint64_t)ts.tv_nsec ^
            ((uint64_t)getpid() << 32);
        v *= 0x9e3779b97f4a7c15ull;
    }
    v &= ((uint64_t)1 << 53) - 1;
    return v ? v : 1;
}

uint64_t bgb_market_epoch(const bgb_market_t *m)
{
    return m->c.epoch;
}

bg_status bgb_market_new(const bgb_market_config_t *config, const bgb_market_io_t *io,
                         bgb_market_t **out, bg_error_t *err)
{
    *out = NULL;
    const bgb_market_config_t *c = config;
    if (!(c->period > 0 && c->period < 3600))
        return bg_error_set(err, BG_ERR_INVALID, "market: period must be in (0, 3600) s");
    if (!(c->k >= 0 && c->k <= 1))
        return bg_error_set(err, BG_ERR_INVALID, "market: k must be in [0, 1]");
    if (!(c->heartbeat_timeout > 0) || !(c->reply_timeout > 0) || !(c->buy_timeout > 0))
        return bg_error_set(err, BG_ERR_INVALID, "market: timeouts must be > 0");
    if (c->overlay_degree < 1 || c->overlay_degree > BGA_MMSG_MAX_NEIGHBOURS || c->hops < 1 ||
        c->hops > 16 || c->max_rounds < 1 || c->max_contracts < 1)
        return bg_error_set(err, BG_ERR_INVALID,
                            "market: overlay_degree in [1, %d], hops in [1, 16], max_rounds and "
                            "max_contracts >= 1",
                            BGA_MMSG_MAX_NEIGHBOURS);
    if (!io || !io->send)
        return bg_error_set(err, BG_ERR_INVALID, "market: io.send is required");
    if (c->epoch > ((uint64_t)1 << 53))
        return bg_error_set(err, BG_ERR_INVALID, "market: epoch must be at most 2^53");
    bgb_market_t *m = calloc(1, sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the market");
    m->c = *c;
    m->c.name = NULL; /* the ledger keeps the name */
    if (m->c.epoch == 0)
        m->c.epoch = draw_epoch();
    m->next_sub = SUB_JOB_BASE;
    bg_status st = bgb_directory_new(c->overlay_degree, c->heartbeat_timeout, io, &m->dir, err);
    if (st == BG_OK)
        bgb_directory_set_epoch(m->dir, m->c.epoch);
    if (st == BG_OK)
        st = bgb_ledger_new(c->name, c->max_contracts, &m->ledger, err);
    if (st != BG_OK) {
        bgb_market_destroy(&m);
        return st;
    }
    m->jobs = calloc(MAX_JOBS, sizeof *m->jobs);
    m->posted = bgm_posted_new(BGB_DIRECTORY_MAX_AGENTS * BGB_GOODS);
    m->cm = bgm_callmarket_new(MAX_JOBS * MAX_UNITS);
    m->refs = calloc((size_t)MAX_JOBS * MAX_UNITS, sizeof *m->refs);
    m->run = calloc((size_t)MAX_JOBS * MAX_UNITS, sizeof *m->run);
    m->admit = admit_new();
    m->fills = calloc(2 * (size_t)MAX_JOBS * MAX_UNITS + 2, sizeof *m->fills);
    /* The purchase machines' timing, from the live market's: a round of
     * discovery an eighth of the reply timeout (doubling when quiet), a
     * failed catallactic round or refused central bid tried again at once
     * (the next round, the next clearing), a posted unit whose candidates
     * all refused asking the directory again a period later. */
    m->pcfg.catallactic.hops = c->hops;
    m->pcfg.catallactic.discovery_timeout = c->reply_timeout / 8;
    m->pcfg.catallactic.reply_timeout = c->reply_timeout;
    m->pcfg.catallactic.max_rounds = c->max_rounds;
    m->pcfg.catallactic.retry_backoff = 0.0;
    m->pcfg.baseline.retry_backoff = c->period;
    m->ob = bgm_outbox_new(16 * MAX_UNITS);
    bg_error_t aerr = BG_ERROR_INIT;
    if (bgb_auction_new(c->k, c->period, 0.0, &m->auction, &aerr) != BG_OK || !m->refs || !m->run ||
        !m->admit || !m->fills || !m->ob || !m->jobs || !m->posted || !m->cm) {
        bgb_market_destroy(&m);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the market");
    }
    *out = m;
    return BG_OK;
}

/* A job's buyer is done buying: its machine and timers go. */
static void end_purchase(job_t *j)
{
    bgm_purchase_destroy(&j->pu);
    free(j->cfg);
    j->cfg = NULL;
    free(j->timers);
    free(j->inbox);
    j->timers = NULL;
    j->inbox = NULL;
    j->ntimers = j->ninbox = 0;
}

/* The job's record is free again. */
static void forget_job(job_t *j)
{
    end_purchase(j);
    j->used = 0;
}

void bgb_market_destroy(bgb_market_t **pm)
{
    if (!pm || !*pm)
        return;
    bgb_market_t *m = *pm;
    for (int i = 0; m->jobs && i < MAX_JOBS; i++)
        if (m->jobs[i].used)
            forget_job(&m->jobs[i]);
    bgm_outbox_destroy(&m->ob);
    bgb_directory_destroy(&m->dir);
    bgb_ledger_destroy(&m->ledger);
    free(m->jobs);
    free(m->refs);
    free(m->run);
    admit_free(m->admit);
    free(m->fills);
    bgm_posted_destroy(&m->posted);
    bgm_callmarket_destroy(&m->cm);
    bgb_auction_destroy(&m->auction);
    free(m);
    *pm = NULL;
}

void bgb_market_on_contract(bgb_market_t *m, bgb_contract_fn fn, void *ctx)
{
    bgb_ledger_on_contract(m->ledger, fn, ctx);
}

const bgb_directory_t *bgb_market_directory(const bgb_market_t *m)
{
    return m->dir;
}

const bgb_ledger_t *bgb_market_ledger(const bgb_market_t *m)
{
    return m->ledger;
}

/* ------------------------------------------------------------ sellers */

/* A job is its record's index at the market agent. */
static uint32_t buyer_of(const bgb_market_t *m, const job_t *j)
{
    return (uint32_t)(j - m->jobs);
}

/* What the market agent and the resource postings know of a seller: its
 * asking prices and its free room net of the orders in flight to it.
 * Said again whenever either changes (a heartbeat, an order, an answer). */
static void announce(bgb_market_t *m, const bgb_dir_agent_t *a)
{
    if (a->info.resource) {
        bgm_posted_withdraw(m->posted, a->info.id);
        for (int g = BGB_GOOD_CORES; g <= BGB_GOOD_MEMORY; g++)
            bgm_posted_post(m->posted, a->info.id, g, a->info.price[g]);
        return;
    }
    const double free_slots = a->info.alive ? (double)(a->info.free_slots - a->pending) : 0.0;
    bgb_auction_seller(m->auction, bgb_directory_slot_of(m->dir, a), a->info.services & 7u,
                       a->info.price, free_slots, NULL);
}

/* An agent the directory drops (silent too long) sells nothing more. */
static void withdraw(void *ctx, bgb_dir_agent_t *a)
{
    bgb_market_t *m = ctx;
    bgm_posted_withdraw(m->posted, a->info.id);
    bgb_auction_forget_seller(m->auction, bgb_directory_slot_of(m->dir, a));
}

/* ------------------------------------------------------------ jobs */

static job_t *job_by_id(bgb_market_t *m, uint64_t id)
{
    for (int i = 0; i < MAX_JOBS; i++)
        if (m->jobs[i].used && m->jobs[i].id == id)
            return &m->jobs[i];
    return NULL;
}

static void touch(job_t *j, uint32_t agent)
{
    for (int i = 0; i < j->ntouched; i++)
        if (j->touched[i] == agent)
            return;
    if (j->ntouched < MAX_UNITS)
        j->touched[j->ntouched++] = agent;
}

static void release_on(bgb_market_t *m, bgb_dir_agent_t *a, uint64_t job)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_RELEASE);
    r.job = job;
    r.agent = a->info.id;
    bgb_directory_send(m->dir, a, &r, NULL);
}

static void send_release(bgb_market_t *m, job_t *j)
{
    for (int i = 0; i < j->ntouched; i++) {
        bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, j->touched[i]);
        if (a)
            release_on(m, a, j->id);
    }
    j->ntouched = 0;
}

static void unpend(bgb_market_t *m, bgb_dir_agent_t *a, const unit_t *u)
{
    if (!a)
        return;
    if (u->good >= BGB_GOOD_CORES) {
        double *p = &a->pend_res[u->good - BGB_GOOD_CORES];
        *p -= u->quantity;
        if (*p < 1e-12)
            *p = 0;
    } else if (a->pending > 0) {
        a->pending--;
        announce(m, a);
    }
}

/* Units still waiting for an answer stop counting against their sellers. */
static void abandon_units(bgb_market_t *m, job_t *j)
{
    for (int i = 0; i < j->nunits; i++)
        if (j->unit[i].state == U_ORDERED) {
            unpend(m, bgb_directory_by_id(m->dir, j->unit[i].agent), &j->unit[i]);
            j->unit[i].state = U_OPEN;
        }
}

/* The cores the resource sub-jobs of job `parent` have at seller
 * `seller`, per service good they serve: bought (`held`), and bought or
 * being sold (`all`); the sub-job `skip` left out. */
static void job_cores_at(const bgb_market_t *m, uint64_t parent, uint32_t seller, const job_t *skip,
                         double held[3], double all[3])
{
    for (int g = 0; g < 3; g++)
        held[g] = all[g] = 0.0;
    for (int i = 0; i < MAX_JOBS; i++) {
        const job_t *s = &m->jobs[i];
        if (!s->used || !s->resource || s == skip || s->parent != parent || s->sgood < 0 ||
            s->sgood > 2)
            continue;
        for (int k = 0; k < s->nunits; k++) {
            const unit_t *u = &s->unit[k];
            if (u->good != BGB_GOOD_CORES || u->agent != seller || u->state == U_OPEN)
                continue;
            all[s->sgood] += u->quantity;
            if (u->state == U_DONE)
                held[s->sgood] += u->quantity;
        }
    }
}

static double widest(const double v[3])
{
    double most = v[0];
    for (int g = 1; g < 3; g++)
        if (v[g] > most)
            most = v[g];
    return most;
}

/* Drops the resource sub-jobs of job `parent` (bought by `buyer` for
 * service good `sgood`; 0 and -1: any), releasing what their sellers
 * hold. */
static void drop_subjobs(bgb_market_t *m, uint64_t parent, uint32_t buyer, int sgood)
{
    for (int i = 0; i < MAX_JOBS; i++) {
        job_t *s = &m->jobs[i];
        if (!s->used || !s->resource || s->parent != parent || (buyer && s->buyer != buyer) ||
            (sgood >= 0 && s->sgood != sgood))
            continue;
        /* What its sellers get back counts as free before their next
         * heartbeat says so, so the next job sees it. */
        for (int k = 0; k < s->nunits; k++) {
            bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, s->unit[k].agent);
            if (!a || s->unit[k].state != U_DONE)
                continue;
            const int mem = s->unit[k].good == BGB_GOOD_MEMORY;
            double *free_q = mem ? &a->info.free_memory : &a->info.free_cores;
            const double cap = mem ? a->info.memory : a->info.cores;
            double back = s->unit[k].quantity;
            if (!mem) {
                /* The job's cores there shrink only by what its widest
                 * phase loses (room_for). */
                double held[3], all[3];
                job_cores_at(m, s->parent, a->info.id, NULL, held, all);
                back = widest(held);
                job_cores_at(m, s->parent, a->info.id, s, held, all);
                back -= widest(held);
            }
            *free_q = *free_q + back < cap ? *free_q + back : cap;
        }
        abandon_units(m, s);
        send_release(m, s);
        forget_job(s);
    }
}

static const job_t *bought_subjob(const bgb_market_t *m, uint64_t parent, uint32_t buyer, int sgood)
{
    for (int i = 0; i < MAX_JOBS; i++) {
        const job_t *s = &m->jobs[i];
        if (s->used && s->resource && s->finished && s->parent == parent && s->buyer == buyer &&
            s->sgood == sgood)
            return s;
    }
    return NULL;
}

/*
 * The cores job `parent` pays for in cores unit `cu` of one of its
 * sub-jobs, at that unit's seller: what the unit's phase (its service) adds to the
 * widest phase the job holds there, with the job's bought sub-jobs taken
 * in the order they were bought (then by number). A job's phases run one
 * after another and its host's seller counts its cores as its widest
 * phase's (room_for, bgm_resource share_phases), so that is what it can
 * occupy, and the sum over its units is that widest phase, paid once:
 * rotation fit 1 + 1 and sparse solve 2 on a host pay for 2 cores, not 4.
 * The unit keeps its phase's cores (the row's `use`).
 */
static double cores_paid(const bgb_market_t *m, uint64_t parent, const unit_t *cu)
{
    const job_t *subs[MAX_UNITS];
    int n = 0;
    for (int i = 0; i < MAX_JOBS && n < MAX_UNITS; i++) {
        const job_t *s = &m->jobs[i];
        if (s->used && s->resource && s->finished && s->parent == parent && s->sgood >= 0 &&
            s->sgood < 3)
            subs[n++] = s;
    }
    double phase[3] = {0, 0, 0}, most = 0;
    for (int done = 0; done < n; done++) {
        int next = done; /* the earliest bought of those left */
        for (int i = done + 1; i < n; i++)
            if (subs[i]->bought_at < subs[next]->bought_at ||
                (subs[i]->bought_at == subs[next]->bought_at && subs[i]->id < subs[next]->id))
                next = i;
        const job_t *s = subs[next];
        subs[next] = subs[done];
        subs[done] = s;
        for (int k = 0; k < s->nunits; k++) {
            const unit_t *u = &s->unit[k];
            if (u->good != BGB_GOOD_CORES || u->agent != cu->agent || u->state != U_DONE)
                continue;
            phase[s->sgood] += u->quantity;
            const double added = phase[s->sgood] > most ? phase[s->sgood] - most : 0.0;
            most += added;
            if (u == cu)
                return added;
        }
    }
    return cu->quantity; /* not found among the bought: counted whole */
}

/* The resource rows of a service item: one per unit of its sub-job,
 * priced per unit-second, for the lease from when they were bought. A
 * cores row pays for what its phase adds to the job's widest phase on
 * the host (cores_paid) and says, as `use`, what the phase holds. */
static void log_resources(bgb_market_t *m, const job_t *j, const unit_t *su, uint64_t request,
                          double now)
{
    const job_t *s = bought_subjob(m, j->id, su->agent, su->good);
    if (!s)
        return;
    for (int i = 0; i < s->nunits; i++) {
        const unit_t *u = &s->unit[i];
        const bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, u->agent);
        const double paid = u->good == BGB_GOOD_CORES ? cores_paid(m, j->id, u) : u->quantity;
        bgb_contract_t row = {.job = j->id,
                              .request = request,
                              .time = now,
                              .start = s->bought_at,
                              .end = s->bought_at + s->term,
                              .buyer = s->buyer,
                              .seller = u->agent,
                              .mechanism = j->mech,
                              .layer = 1,
                              .good = u->good,
                              .quantity = paid,
                              .price = u->price,
                              .buyer_limit = u->limit,
                              .seller_limit = u->seller_floor,
                              .use = u->quantity,
                              .clearing = u->clearing};
        if (a)
            snprintf(row.seller_name, sizeof row.seller_name, "%s", a->info.name);
        bgb_ledger_add(m->ledger, &row);
    }
}

/* A sub-job's outcome goes to the basic agent that asked: RBOUGHT with
 * the sellers' asking rates when bought (prices[CORES], prices[MEMORY])
 * and the money paid, or RFAIL. The basic agent expects resources to cost
 * the asks, not what it paid: a paid rate lies between the ask and the
 * agent's own limit (k-double auction, bargain), so learning it would feed
 * the agent's limit back into its floor, and a host's one resource seller
 * facing its one service seller would ratchet both prices up job by job. */
static void subjob_done(bgb_market_t *m, job_t *j, const char *reason, double now)
{
    bgb_dir_agent_t *b = bgb_directory_by_id(m->dir, j->buyer);
    bga_mmsg_t r;
    bga_mmsg_init(&r, reason ? BGA_MM_RFAIL : BGA_MM_RBOUGHT);
    r.job = j->parent;
    r.good = j->sgood;
    r.agent = j->buyer;
    r.term = j->term;
    if (reason) {
        snprintf(r.reason, sizeof r.reason, "%s", reason);
    } else {
        j->bought_at = now;
        for (int i = 0; i < j->nunits; i++) {
            const unit_t *u = &j->unit[i];
            const bgb_dir_agent_t *seller = bgb_directory_by_id(m->dir, u->agent);
            r.prices[u->good] =
                seller && seller->info.price[u->good] > 0 ? seller->info.price[u->good] : u->price;
            r.price += u->quantity * u->term * u->price;
            if (u->good == BGB_GOOD_CORES)
                r.cores += u->quantity;
            else
                r.memory += u->quantity;
        }
    }
    if (b)
        bgb_directory_send(m->dir, b, &r, NULL);
}

/* Delivers the outcome once. On success every unit becomes a contract row
 * with the resource rows bought for it (rows are logged only then: a job
 * that fails leaves none, and resources bought for it are released). */
static void finish(bgb_market_t *m, job_t *j, const char *reason, double now)
{
    if (j->finished)
        return;
    j->finished = 1;
    end_purchase(j);
    /* A seller that left the market (killed, dropped for silence) between
     * its agreement and the job's last one has no endpoint to compute on:
     * no deal, the job asks again ("no seller" is a reason to retry). */
    for (int i = 0; !reason && !j->resource && i < j->nunits; i++)
        if (!bgb_directory_by_id(m->dir, j->unit[i].agent))
            reason = "no seller: a seller left the market before the job's last deal";
    /* Bids still in the auctioneer's book are no one's now. */
    bgb_auction_forget_buyer(m->auction, buyer_of(m, j));
    if (reason)
        abandon_units(m, j);
    if (j->resource) {
        subjob_done(m, j, reason, now);
        if (reason) {
            send_release(m, j);
            forget_job(j);
        }
        return;
    }
    bgb_award_t aw[MAX_UNITS];
    bgb_outcome_t o = {.job = j->id, .reason = reason, .awards = aw, .latency = now - j->started};
    if (!reason) {
        for (int i = 0; i < j->nunits; i++) {
            const unit_t *u = &j->unit[i];
            const bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, u->agent);
            bgb_award_t *w = &aw[o.nawards++];
            memset(w, 0, sizeof *w);
            w->good = u->good;
            w->agent = u->agent;
            if (a) {
                snprintf(w->name, sizeof w->name, "%s", a->info.name);
                snprintf(w->endpoint, sizeof w->endpoint, "%s", a->info.endpoint);
            }
            w->quantity = u->quantity;
            w->price = u->price;
            o.spent += u->quantity * u->price;
            bgb_contract_t row = {.job = j->id,
                                  .request = ++m->next_request,
                                  .time = now,
                                  .start = now,
                                  .end = INFINITY,
                                  .buyer = j->id,
                                  .seller = u->agent,
                                  .mechanism = j->mech,
                                  .layer = 0,
                                  .good = u->good,
                                  .quantity = u->quantity,
                                  .price = u->price,
                                  .buyer_limit = u->limit,
                                  .seller_limit = u->seller_floor,
                                  .use = u->quantity,
                                  .clearing = u->clearing};
            snprintf(row.buyer_label, sizeof row.buyer_label, "%s", j->label);
            snprintf(row.seller_name, sizeof row.seller_name, "%s", w->name);
            bgb_ledger_add(m->ledger, &row);
            log_resources(m, j, u, row.request, now);
        }
    } else {
        drop_subjobs(m, j->id, 0, -1);
        send_release(m, j);
    }
    if (j->done)
        j->done(j->ctx, &o);
    if (reason)
        forget_job(j);
}

/* The slots a released job held count as free before their sellers'
 * next heartbeats say so (a heartbeat comes every half second), so the
 * next job is let into the book and matched at once. A seller that holds
 * no slot for it any more is corrected by its heartbeat. */
static void free_slots_of(bgb_market_t *m, const job_t *j)
{
    for (int i = 0; i < j->nunits; i++) {
        bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, j->unit[i].agent);
        if (j->unit[i].state != U_DONE || !a || a->info.resource)
            continue;
        if (a->info.free_slots < a->info.slots)
            a->info.free_slots++;
        announce(m, a);
    }
}

void bgb_market_release(bgb_market_t *m, uint64_t job, double now)
{
    job_t *j = job_by_id(m, job);
    if (!j)
        return;
    bgb_ledger_close(m->ledger, job, now);
    free_slots_of(m, j);
    drop_subjobs(m, job, 0, -1);
    abandon_units(m, j);
    send_release(m, j);
    bgb_auction_forget_buyer(m->auction, buyer_of(m, j));
    forget_job(j);
}

static void mark_tried(unit_t *u, uint32_t agent);

double bgb_market_settle_lost(bgb_market_t *m, uint64_t job, uint32_t agent, int good,
                              double delivered, double now)
{
    job_t *j = job_by_id(m, job);
    unit_t *u = NULL;
    for (int i = 0; j && !j->resource && i < j->nunits && !u; i++)
        if (j->unit[i].state == U_DONE && j->unit[i].agent == agent && j->unit[i].good == good)
            u = &j->unit[i];
    if (!u)
        return -1.0;
    delivered = delivered < 0 ? 0 : delivered > u->quantity ? u->quantity : delivered;
    /* Its service row: the delivered work, ended now; the rows of the
     * resources bought for it (the same request) end now too. */
    (void)bgb_ledger_settle_lost(m->ledger, job, agent, good, delivered, now);
    drop_subjobs(m, job, agent, good);
    bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, agent);
    if (a && !a->info.resource)
        release_on(m, a, job);
    u->state = U_OPEN;
    mark_tried(u, agent);
    return delivered * u->price;
}

void bgb_market_settle(bgb_market_t *m, uint64_t job, double now)
{
    if (job_by_id(m, job))
        bgb_ledger_close(m->ledger, job, now);
}

void bgb_market_label(bgb_market_t *m, uint64_t job, const char *label)
{
    job_t *j = job_by_id(m, job);
    if (j && label)
        snprintf(j->label, sizeof j->label, "%s", label);
}

/* ------------------------------------------------------------ buying */

static int alive_seller(const bgb_dir_agent_t *a, int good)
{
    if (!a->used || !a->info.alive)
        return 0;
    if (good == BGB_GOOD_CORES)
        return a->info.resource && a->info.cores > 0;
    if (good == BGB_GOOD_MEMORY)
        return a->info.resource && a->info.memory > 0;
    return good >= 0 && good < 3 && (a->info.services & (1u << good));
}

/* A sub-job buys only from resource sellers on its basic agent's host:
 * those are the cores it can compute on. */
static int on_host(const job_t *j, const bgb_dir_agent_t *a)
{
    return !j->resource || bgb_directory_same_host(j->host, a->info.endpoint);
}

static int tried(const unit_t *u, uint32_t agent)
{
    for (int i = 0; i < u->ntried; i++)
        if (u->tried[i] == agent)
            return 1;
    return 0;
}

static void mark_tried(unit_t *u, uint32_t agent)
{
    if (u->ntried < MAX_TRIED)
        u->tried[u->ntried++] = agent;
}

/* Whether another unit of the same need already has (or is asking) this
 * agent: a need split over n sellers goes to n distinct agents. */
static int need_has(const job_t *j, const unit_t *u, uint32_t agent)
{
    for (int i = 0; i < j->nunits; i++) {
        const unit_t *v = &j->unit[i];
        if (v != u && v->need == u->need && v->state != U_OPEN && v->agent == agent)
            return 1;
    }
    return 0;
}

/*
 * Whether the agent could take unit u of job j now: a free slot
 * (services) or enough free cores or memory (resources), net of orders in
 * flight. A resource seller counts a job's cores as its widest phase's
 * (its services run one after another; bga_rseller), so the cores of a
 * sub-job need only what they add to what the job's other sub-jobs there
 * have or are buying: its free cores exclude the job's bought widest
 * phase, its pending orders include the job's own.
 */
static int room_for(const bgb_market_t *m, const job_t *j, const bgb_dir_agent_t *a,
                    const unit_t *u)
{
    if (u->good == BGB_GOOD_MEMORY)
        return a->info.free_memory - a->pend_res[1] >= u->quantity - 1e-9;
    if (u->good != BGB_GOOD_CORES)
        return a->info.free_slots - a->pending > 0;
    double more = u->quantity, pend = a->pend_res[0];
    if (j->resource && j->sgood >= 0 && j->sgood < 3) {
        double held[3], all[3];
        job_cores_at(m, j->parent, a->info.id, j, held, all);
        const double after = all[j->sgood] + u->quantity, most = widest(all);
        more = (after > most ? after : most) - widest(held);
        for (int g = 0; g < 3; g++)
            pend -= all[g] - held[g];
    }
    return a->info.free_cores - pend >= more - 1e-9;
}

/* Resource messages name the job and service they serve, so the seller
 * can count the job's phases once. */
static void tag_subjob(const job_t *j, bga_mmsg_t *o)
{
    if (j->resource) {
        o->parent = j->parent;
        o->serves = j->sgood;
    }
}

static bg_status send_price(bgb_market_t *m, const job_t *j, const unit_t *u, bgb_dir_agent_t *a,
                            int type, double price)
{
    bga_mmsg_t o;
    bga_mmsg_init(&o, type);
    o.job = j->id;
    o.agent = a->info.id;
    o.good = u->good;
    o.quantity = u->quantity;
    o.term = j->resource ? j->term : 0;
    o.price = price;
    tag_subjob(j, &o);
    return bgb_directory_send(m->dir, a, &o, NULL);
}

static void pend(bgb_market_t *m, bgb_dir_agent_t *a, const unit_t *u)
{
    if (u->good >= BGB_GOOD_CORES) {
        a->pend_res[u->good - BGB_GOOD_CORES] += u->quantity;
    } else {
        a->pending++;
        announce(m, a);
    }
}

static bg_status order(bgb_market_t *m, job_t *j, unit_t *u, bgb_dir_agent_t *a, double price,
                       double now)
{
    u->state = U_ORDERED;
    u->agent = a->info.id;
    u->price = price;
    u->deadline = now + m->c.reply_timeout;
    pend(m, a, u);
    touch(j, a->info.id);
    return send_price(m, j, u, a, BGA_MM_ORDER, price);
}

typedef struct room_ctx {
    bgb_market_t *m;
    const job_t *j;
    const unit_t *u;
} room_ctx;

static int has_room(void *ctx, const bgm_posting_t *p)
{
    room_ctx *r = ctx;
    bgb_dir_agent_t *a = bgb_directory_by_id(r->m->dir, p->seller);
    return a && a->info.alive && room_for(r->m, r->j, a, r->u) && on_host(r->j, a) &&
           !tried(r->u, p->seller) && !need_has(r->j, r->u, p->seller);
}

/* The sellers a unit must not get, as directory slots, for the market
 * agent: those its need's other units have (a need split over n sellers
 * goes to n distinct agents) first, then those it tried, latest first, up
 * to the message's cap. Whatever the cap leaves out the host still
 * checks when the market agent answers. */
static int is_excluded(const job_t *j, const bgb_dir_agent_t *a);
static uint64_t endpoint_hash(const char *ep);

static int exclusions(bgb_market_t *m, const job_t *j, const unit_t *u, int *out)
{
    uint32_t ids[MAX_UNITS + MAX_TRIED];
    int n = 0, k = 0;
    for (int i = 0; i < j->nunits; i++) {
        const unit_t *v = &j->unit[i];
        if (v != u && v->need == u->need && v->state != U_OPEN)
            ids[n++] = v->agent;
    }
    for (int i = u->ntried - 1; i >= 0; i--)
        ids[n++] = u->tried[i];
    /* Agents the job must not get, under a new id too. */
    const bgb_dir_agent_t *rows = bgb_directory_rows_const(m->dir);
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS && j->nexcluded > 0 && k < BGB_AUCTION_MAX_EXCLUDE;
         i++)
        if (rows[i].used && is_excluded(j, &rows[i]))
            out[k++] = i;
    for (int i = 0; i < n && k < BGB_AUCTION_MAX_EXCLUDE; i++) {
        bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, ids[i]);
        if (!a)
            continue;
        int dup = 0;
        for (int q = 0; q < k; q++)
            dup |= out[q] == bgb_directory_slot_of(m->dir, a);
        if (!dup)
            out[k++] = bgb_directory_slot_of(m->dir, a);
    }
    return k;
}

/* The live service sellers of unit u's good with a free slot net of the
 * orders in flight to them, that do not serve its need already; those
 * marked in `only` alone when it is not NULL (slots). */
static int sellers_with_room(const bgb_market_t *m, const job_t *j, const unit_t *u,
                             const uint8_t *only)
{
    int n = 0;
    const bgb_dir_agent_t *rows = bgb_directory_rows_const(m->dir);
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++)
        n += (!only || only[i]) && alive_seller(&rows[i], u->good) &&
             rows[i].info.free_slots - rows[i].pending > 0 && !need_has(j, u, rows[i].info.id);
    return n;
}

/* Whether the host lets unit u of job j have seller a now: what the
 * market agent's answers and a purchase's choices are checked against
 * (what a message could not carry, a seller gone since). A seller of
 * another host (a sub-job) or one another unit of the need has is never
 * given; central and posted units also skip sellers they tried and
 * sellers without room, while a catallactic service unit leaves both to
 * its bargaining (a seller that walked away may agree in a later round; a
 * busy one does not propose). A catallactic resource unit does skip its
 * host's seller while the room it needs is taken by other sub-jobs
 * bargaining for it or holding it: it would only wait for the refusal. */
/* FNV-1a of an endpoint (0 is never returned: it marks no endpoint). */
static uint64_t endpoint_hash(const char *ep)
{
    uint64_t h = 1469598103934665603ull;
    for (const char *p = ep; *p; p++)
        h = (h ^ (uint8_t)*p) * 1099511628211ull;
    return h ? h : 1;
}

static int is_excluded(const job_t *j, const bgb_dir_agent_t *a)
{
    if (j->nexcluded == 0)
        return 0;
    const uint64_t h = endpoint_hash(a->info.endpoint);
    for (int i = 0; i < j->nexcluded; i++)
        if (j->excluded[i] == a->info.id || (j->excluded_ep[i] && j->excluded_ep[i] == h))
            return 1;
    return 0;
}

static int may_have(const bgb_market_t *m, const job_t *j, const unit_t *u,
                    const bgb_dir_agent_t *a)
{
    if (!a || !a->used || !alive_seller(a, u->good) || !on_host(j, a) ||
        need_has(j, u, a->info.id) || is_excluded(j, a))
        return 0;
    if (j->mech == BGB_MECH_CATALLACTIC)
        return !j->resource || room_for(m, j, a, u);
    return room_for(m, j, a, u) && !tried(u, a->info.id);
}

static void unit_lost(bgb_market_t *m, job_t *j, unit_t *u);

typedef struct match_ctx {
    bgb_market_t *m;
    double now;
    uint64_t logged[BGB_AUCTION_MAX_CLEARINGS]; /* the tick's clearings' ledger ids (0: not yet) */
} match_ctx;

/* ------------------------------------------------------ a job's purchase */

/* A resource unit is one bundle of the machine's (q cores, or q GiB, for
 * the lease): the machine prices bundles per second for the whole (a
 * rate), the live sellers per unit-second, so rate = q · unit price. A
 * rate the machine hands back from the seller's own last price goes back
 * as exactly that price (the seller knows its price, not a rebuilt one). */
static double machine_price(const job_t *j, const unit_t *u, double unit)
{
    return j->resource ? unit * u->quantity : unit;
}

static double live_price(const job_t *j, const unit_t *u, double rate)
{
    if (!j->resource)
        return rate;
    const double unit = rate / u->quantity;
    return u->heard > 0 && fabs(unit - u->heard) <= 1e-12 * u->heard ? u->heard : unit;
}

/* The purchase request of unit u (NULL once the job stopped buying). */
static bgm_purchase_req_t *request_of(job_t *j, const unit_t *u)
{
    return j->pu ? bgm_purchase_get(j->pu, (uint32_t)(u - j->unit) + 1) : NULL;
}

/* An answer for the purchase, handed to it once its outbox is handled. */
static void answer(job_t *j, int type, uint32_t from, uint32_t req, uint32_t attempt, double price)
{
    if (!j->inbox || j->ninbox >= JOB_INBOX)
        return; /* bounded: a lost answer leaves the request to its timers */
    bgm_msg_t *x = &j->inbox[j->ninbox++];
    *x = bgm_outbox_msg(type, from, PU_SELF, req, attempt);
    x->price = price;
}

/* A timer the purchase asks for; a newer phase or retry timer of a
 * request replaces the older (stale once the newer is armed). */
static int add_timer(job_t *j, const bgm_out_item_t *it)
{
    int at = j->ntimers;
    if (it->kind == BGM_PU_TIMER_REQ || it->kind == BGM_PU_TIMER_RETRY)
        for (int i = 0; i < j->ntimers; i++)
            if (j->timers[i].kind == it->kind && (uint32_t)j->timers[i].arg == (uint32_t)it->arg)
                at = i;
    if (at == JOB_TIMERS)
        return 0;
    j->timers[at] = (ptimer_t){it->at, it->kind, it->arg};
    if (at == j->ntimers)
        j->ntimers++;
    return 1;
}

/* The unit gives its seller up (the purchase moved on, or the seller said
 * no): the seller's slot stops counting against it, the resources it was
 * buying for the unit go back, and the unit is open again. */
static void let_go(bgb_market_t *m, job_t *j, unit_t *u)
{
    if (u->state != U_ORDERED)
        return;
    unpend(m, bgb_directory_by_id(m->dir, u->agent), u);
    unit_lost(m, j, u);
}

/* A seller's no to the request of unit u, in the machine's terms: a
 * seller still bargaining (or offered an order) rejects; one committed
 * to (central match, an acceptance) cancels. */
static void seller_said_no(job_t *j, unit_t *u, uint32_t seller)
{
    const bgm_purchase_req_t *q = request_of(j, u);
    if (!q)
        return;
    const uint32_t id = (uint32_t)(u - j->unit) + 1;
    if (q->state == BGM_PU_NEGOTIATE)
        answer(j, BGM_MT_REJECT, seller, id, q->attempt, 0);
    else if (q->state == BGM_PU_COMMITTED)
        answer(j, BGM_MT_CANCEL, seller, id, q->attempt, 0);
}

/* Central: the purchase's BID goes into the auctioneer's book, for one
 * unit at its limit, with the sellers it must not get and its need's
 * group. */
static void central_bid(bgb_market_t *m, job_t *j, unit_t *u, const bgm_msg_t *b, double now)
{
    int excl[BGB_AUCTION_MAX_EXCLUDE];
    const int ne = exclusions(m, j, u, excl);
    u->req = ++m->next_req;
    u->attempt = b->attempt;
    u->in_book = bgb_auction_bid(m->auction, buyer_of(m, j), u->req, b->attempt, u->good, b->price,
                                 b->a, b->b, (uint32_t)u->need + 1, excl, ne, now, NULL) == BG_OK;
}

/* Posted: the purchase's QUERY is answered by the directory (the market
 * agent machine): the first postings within its limit with room, less
 * the sellers the unit may not have, as the machine's LIST. A resource
 * unit's are its host's postings within the unit's limit, listed at the
 * bundle's rate at speed 1 (the lease is the bundle's run time). */
static void posted_list(bgb_market_t *m, job_t *j, unit_t *u, const bgm_msg_t *qm, double now)
{
    if (!j->inbox || j->ninbox >= JOB_INBOX)
        return;
    bgm_msg_t *l = &j->inbox[j->ninbox++];
    *l = bgm_outbox_msg(BGM_MT_LIST, PU_MARKET, PU_SELF, qm->req, qm->attempt);
    if (j->resource) {
        room_ctx rc = {m, j, u};
        bgm_posting_t p[BGM_MSG_CANDIDATES];
        const size_t n = bgm_posted_query(m->posted, u->good, u->limit, 0, has_room, &rc, p,
                                          BGM_MSG_CANDIDATES, NULL);
        for (size_t i = 0; i < n; i++) {
            l->cand[l->ncand] = p[i].seller;
            l->cand_speed[l->ncand] = 1.0;
            l->cand_price[l->ncand++] = machine_price(j, u, p[i].price);
        }
        return;
    }
    int excl[BGB_AUCTION_MAX_EXCLUDE], slots[BGB_AUCTION_MAX_LIST];
    double prices[BGB_AUCTION_MAX_LIST];
    const int ne = exclusions(m, j, u, excl);
    const int n = bgb_auction_query(m->auction, buyer_of(m, j), ++m->next_req, u->good, qm->price,
                                    excl, ne, slots, prices, BGB_AUCTION_MAX_LIST, now, NULL);
    for (int i = 0; i < n && l->ncand < BGM_MSG_CANDIDATES; i++) {
        const bgb_dir_agent_t *a = &bgb_directory_rows_const(m->dir)[slots[i]];
        if (!may_have(m, j, u, a))
            continue;
        l->cand[l->ncand] = a->info.id;
        l->cand_price[l->ncand++] = prices[i];
    }
}

/* The purchase offers (catallactic) or orders (posted) from a seller: the
 * unit holds it from now, unless the host may not give it, when the
 * seller is taken to have said no. */
static void to_seller(bgb_market_t *m, job_t *j, unit_t *u, const bgm_msg_t *o, double now)
{
    if (u->state == U_ORDERED && u->agent != o->to)
        let_go(m, j, u);
    bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, o->to);
    if (u->state != U_ORDERED) {
        if (!may_have(m, j, u, a)) {
            answer(j, BGM_MT_REJECT, o->to, o->req, o->attempt, 0);
            return;
        }
        u->state = U_ORDERED;
        u->agent = a->info.id;
        pend(m, a, u);
        touch(j, a->info.id);
    }
    u->price = live_price(j, u, o->price);
    u->attempt = o->attempt;
    u->deadline = now + m->c.reply_timeout;
    if (a)
        send_price(m, j, u, a, o->type == BGM_MT_ORDER ? BGA_MM_ORDER : BGA_MM_OFFER, u->price);
}

/* Entry points of a catallactic job's calls for proposals: for each good
 * its units buy, a live seller of that good (so every good's sellers hear
 * a call, wherever the overlay would or would not carry it within its
 * hops: a job's calls reached no sparse-solve seller when its entry
 * agents, the same for every job, all sold rotation fit and none of
 * their neighbours sold sparse solve, and every job timed out), then
 * other live sellers of its layer up to the overlay degree; each from an
 * offset that spreads jobs over the directory (a job number's high bits
 * too: the broker's are multiples of 2^32). A sub-job's: its host's
 * resource seller, the only one it may buy from. The overlay carries the
 * calls on. */
static int entry_agents(const bgb_market_t *m, const job_t *j, uint32_t *ids)
{
    const bgb_dir_agent_t *rows = bgb_directory_rows_const(m->dir);
    const int offset = (int)((j->id ^ (j->id >> 32)) % BGB_DIRECTORY_MAX_AGENTS);
    int n = 0;
    for (int pass = 0; pass < 2; pass++)
        for (int i = 0; i < (pass ? 1 : j->nunits); i++) {
            const int good = j->unit[i].good;
            int seen = 0;
            for (int k = 0; k < i && !pass; k++)
                seen |= j->unit[k].good == good;
            for (int k = 0; k < BGB_DIRECTORY_MAX_AGENTS && !seen; k++) {
                const bgb_dir_agent_t *a = &rows[(k + offset) % BGB_DIRECTORY_MAX_AGENTS];
                int have = 0;
                for (int q = 0; q < n; q++)
                    have |= ids[q] == a->info.id;
                if (n >= (pass ? m->c.overlay_degree : BGA_MMSG_MAX_NEIGHBOURS))
                    break;
                if (!have && a->used && a->info.alive && a->info.resource == j->resource &&
                    on_host(j, a) && (pass || alive_seller(a, good))) {
                    ids[n++] = a->info.id;
                    if (!pass)
                        break;
                }
            }
        }
    return n;
}

/* One message of the purchase, carried out: to the market agent machine
 * (BID, QUERY) or to a live seller (CFP, OFFER, ORDER, ACCEPT, REJECT). */
static void route_out(bgb_market_t *m, job_t *j, const bgm_msg_t *x, double now)
{
    if (x->req < 1 || x->req > (uint32_t)j->nunits)
        return;
    unit_t *u = &j->unit[x->req - 1];
    bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, x->to);
    switch (x->type) {
    case BGM_MT_BID:
        central_bid(m, j, u, x, now);
        break;
    case BGM_MT_RBID:
        /* A resource unit's bid: the host's call market for its good
         * takes it at every clearing until it is filled (central_clear). */
        u->in_book = 1;
        u->attempt = x->attempt;
        break;
    case BGM_MT_QUERY:
        posted_list(m, j, u, x, now);
        break;
    case BGM_MT_CFP:
        /* A round every bargain of which failed: the strategy that failed
         * them is dropped for a fresh draw. The simulator's buyers learn
         * from their neighbours across many jobs; a live job has only its
         * own rounds, and the machine's outcome learning moves only its
         * markup, so the same genes would walk away again. */
        if (x->attempt > u->drawn) {
            bgm_trader_t *tr = bgm_purchase_trader(j->pu);
            bgm_genes_random(&tr->genes, &tr->rng);
            u->drawn = x->attempt;
        }
        if (a) {
            bga_mmsg_t c;
            bga_mmsg_init(&c, BGA_MM_CFP);
            c.job = j->id;
            c.agent = a->info.id;
            c.good = u->good;
            c.hops = x->hops;
            c.attempt = (int)x->attempt;
            c.quantity = u->quantity;
            c.term = j->resource ? j->term : 0;
            tag_subjob(j, &c);
            bgb_directory_send(m->dir, a, &c, NULL);
        }
        break;
    case BGM_MT_ORDER:
    case BGM_MT_OFFER:
        to_seller(m, j, u, x, now);
        break;
    case BGM_MT_ACCEPT:
        /* A basic seller now buys the unit's resources before it
         * confirms; a resource seller confirms at once. */
        if (a && u->state == U_ORDERED && u->agent == x->to) {
            u->price = live_price(j, u, x->price);
            u->deadline = now + (j->resource ? 1.0 : 2.5) * m->c.reply_timeout;
            send_price(m, j, u, a, BGA_MM_ACCEPT, u->price);
        }
        break;
    case BGM_MT_REJECT:
        if (a)
            send_price(m, j, u, a, BGA_MM_REJECT, 0);
        if (u->state == U_ORDERED && u->agent == x->to)
            let_go(m, j, u);
        break;
    default:
        break;
    }
}

/* A unit whose request left its seller without a message (a phase
 * timeout, a round given up) gives the seller up too. */
static void reconcile(bgb_market_t *m, job_t *j)
{
    for (int i = 0; i < j->nunits; i++) {
        unit_t *u = &j->unit[i];
        const bgm_purchase_req_t *q = request_of(j, u);
        if (u->state != U_ORDERED || !q)
            continue;
        /* A central resource unit's bid waits in the host's book while
         * the seller it was filled with confirms (the simulator's award). */
        const int held = j->resource && j->mech == BGB_MECH_CENTRAL
                             ? q->state == BGM_PU_WAIT
                             : (q->state == BGM_PU_NEGOTIATE || q->state == BGM_PU_COMMITTED) &&
                                   q->attempt == u->attempt &&
                                   (j->mech == BGB_MECH_CENTRAL || q->seller == u->agent);
        if (!held)
            let_go(m, j, u);
    }
}

/* Carries out what the purchase's last call emitted, then hands it the
 * host's answers one by one, each call's output carried out in turn.
 * A request that failed for good fails the job: it ran out of time. */
static void pump(bgb_market_t *m, job_t *j, bg_status st, const bgm_purchase_event_t *first,
                 double now)
{
    bgm_purchase_event_t ev = *first;
    for (;;) {
        const size_t n = bgm_outbox_count(m->ob);
        for (size_t i = 0; i < n && st == BG_OK; i++) {
            const bgm_out_item_t *it = bgm_outbox_item(m->ob, i);
            if (it->is_timer ? !add_timer(j, it) : (route_out(m, j, &it->msg, now), 0))
                st = BG_ERR_LIMIT;
        }
        bgm_outbox_clear(m->ob);
        if (st != BG_OK) {
            finish(m, j,
                   st == BG_ERR_NOMEM ? "market: out of memory" : "market: buyer over its caps",
                   now);
            return;
        }
        if (ev.kind == BGM_PU_EV_FAILED) {
            finish(m, j, "timeout", now);
            return;
        }
        if (j->ninbox == 0)
            break;
        const bgm_msg_t in = j->inbox[0];
        memmove(j->inbox, j->inbox + 1, (size_t)--j->ninbox * sizeof *j->inbox);
        st = bgm_purchase_on_message(j->pu, &in, now, m->ob, &ev);
    }
    reconcile(m, j);
}

/* A catallactic purchase calls on the current entry agents. Only opening
 * a request and its retry timer send calls, so only those need them. */
static void refresh_neighbours(const bgb_market_t *m, job_t *j)
{
    if (j->mech != BGB_MECH_CATALLACTIC)
        return;
    uint32_t ids[BGA_MMSG_MAX_NEIGHBOURS];
    uint8_t same[BGA_MMSG_MAX_NEIGHBOURS] = {0};
    const int n = entry_agents(m, j, ids);
    bgm_purchase_set_neighbours(j->pu, ids, same, n);
}

/* A message from a seller for the purchase, then what follows from it. */
static void tell(bgb_market_t *m, job_t *j, const bgm_msg_t *x, double now)
{
    if (!j->pu)
        return;
    bgm_purchase_event_t ev;
    const bg_status st = bgm_purchase_on_message(j->pu, x, now, m->ob, &ev);
    pump(m, j, st, &ev, now);
}

/* The host's answers queued outside a purchase call (a clearing's
 * matches) are handed over. */
static void deliver_answers(bgb_market_t *m, job_t *j, double now)
{
    if (!j->pu || j->ninbox == 0)
        return;
    const bgm_purchase_event_t none = {BGM_PU_EV_NONE, 0};
    pump(m, j, BG_OK, &none, now);
}

/* Runs the purchase's timers due at `now` (one that fires may arm others
 * due now too) and returns when the next is due. */
static double run_timers(bgb_market_t *m, job_t *j, double now)
{
    for (int guard = 0; j->pu && guard < 64 * JOB_TIMERS; guard++) {
        int due = -1;
        for (int i = 0; i < j->ntimers; i++)
            if (j->timers[i].at <= now && (due < 0 || j->timers[i].at < j->timers[due].at))
                due = i;
        if (due < 0)
            break;
        const ptimer_t t = j->timers[due];
        j->timers[due] = j->timers[--j->ntimers];
        bgm_purchase_event_t ev;
        refresh_neighbours(m, j);
        const bg_status st = bgm_purchase_on_timer(j->pu, t.kind, t.arg, now, 1, m->ob, &ev);
        pump(m, j, st, &ev, now);
    }
    double next = INFINITY;
    for (int i = 0; j->pu && i < j->ntimers; i++)
        if (j->timers[i].at < next)
            next = j->timers[i].at;
    return next;
}

/* Opens one purchase request per unit of a job, until the job's
 * deadline: a service unit's work at its limit per unit; a resource
 * unit's bundle (q cores or q GiB, run for the lease at speed 1) within
 * the money its limit comes to. */
static void open_requests(bgb_market_t *m, job_t *j, double now)
{
    for (int i = 0; i < j->nunits && j->pu && !j->finished; i++) {
        const unit_t *u = &j->unit[i];
        bgm_purchase_req_t it = {.id = (uint32_t)i + 1,
                                 .good = u->good,
                                 .work = u->quantity,
                                 .limit = u->limit,
                                 .created = now,
                                 .deadline = j->deadline};
        if (j->resource) {
            const int cores = u->good == BGB_GOOD_CORES;
            it.good = BGM_PU_BUNDLE;
            it.work = 0;
            it.cores = cores ? u->quantity : 0;
            it.memory = cores ? 0 : u->quantity;
            it.flops = j->term * (cores ? u->quantity : 1.0);
            it.limit = u->limit * u->quantity * j->term;
        }
        bgm_purchase_event_t ev;
        refresh_neighbours(m, j);
        const bg_status st = bgm_purchase_open(j->pu, &it, now, 1, m->ob, &ev);
        pump(m, j, st, &ev, now);
    }
}

/* A job's buyer: the purchase machine with a trader of its own (a
 * stream from the job id, random genes, the opening markup) that
 * remembers, per service good, the price the broker's catallactic buyers
 * last paid, or else the cheapest ask now (`ref`). A resource sub-job's
 * remembers its host's cheapest asks: they are its copy's mean costs, at
 * a remembered ratio of 1. 0 when out of memory. */
static int start_purchase(bgb_market_t *m, job_t *j, const double *ref)
{
    if (j->resource) {
        j->cfg = malloc(sizeof *j->cfg);
        if (!j->cfg)
            return 0;
        *j->cfg = m->pcfg;
        const double cores = ref[BGB_GOOD_CORES], memory = ref[BGB_GOOD_MEMORY];
        j->cfg->resources.core_cost = isfinite(cores) ? cores : 0;
        j->cfg->resources.memory_cost = isfinite(memory) ? memory : 0;
    }
    bgm_purchase_params_t p = {.cfg = j->resource ? j->cfg : &m->pcfg,
                               .mechanism = (int)j->mech,
                               .self = PU_SELF,
                               .market = PU_MARKET,
                               .widen_quiet = PU_WIDEN,
                               /* A sub-job calls only its host's seller. */
                               .close_when_heard = j->resource};
    bgm_rng_seed(&p.trader.rng, j->id);
    bgm_genes_random(&p.trader.genes, &p.trader.rng);
    p.trader.markup = BUYER_MARKUP;
    for (int g = 0; g < 3 && !j->resource; g++)
        p.trader.memory[g] = m->memory[g] > 0 ? m->memory[g] : (isfinite(ref[g]) ? ref[g] : 0);
    p.trader.memory[3] = j->resource ? 1.0 : 0.0;
    j->pu = bgm_purchase_new(&p);
    j->timers = malloc(JOB_TIMERS * sizeof *j->timers);
    j->inbox = malloc(JOB_INBOX * sizeof *j->inbox);
    if (!j->pu || !j->timers || !j->inbox) {
        end_purchase(j);
        return 0;
    }
    return 1;
}

/*
 * Central admission. A seller's slots are shared by the goods it sells and
 * the auctioneer clears good by good, so jobs let in all at once could
 * fill a seller with one good of each, none of them able to buy the rest,
 * and hold that until they time out, again at every retry (broker.restart
 * found it: four jobs, one agent). The book took one job a clearing
 * (about 5 jobs/s). Now, before each clearing, the waiting jobs are let in
 * in the order they came for as long as the open units of every job in the
 * book can be placed at once on the sellers' free slots (net of orders in
 * flight): a unit on a live seller of its good that its need has not
 * tried or taken, a need's units on distinct sellers. That is a flow
 * problem (needs to sellers, unit edges, sellers' free slots as
 * capacities), solved by augmenting paths; the first job that does not fit
 * waits with those after it, so a large job is not passed over for ever.
 */
#define ADMIT_NEEDS 256 /* (job, need) pairs placed at once, at most */
#define ADMIT_WORDS (BGB_DIRECTORY_MAX_AGENTS / 64)

struct admit {
    const job_t *job[ADMIT_NEEDS];
    int need[ADMIT_NEEDS], good[ADMIT_NEEDS];
    int n;
    uint64_t flow[ADMIT_NEEDS][ADMIT_WORDS]; /* bit r of row l: need l has a unit on seller r */
    int used[BGB_DIRECTORY_MAX_AGENTS], room[BGB_DIRECTORY_MAX_AGENTS];
    uint8_t seen[BGB_DIRECTORY_MAX_AGENTS];
};

static admit_t *admit_new(void)
{
    return malloc(sizeof(admit_t));
}

static void admit_free(admit_t *a)
{
    free(a);
}

static int has_flow(const admit_t *a, int l, int r)
{
    return (int)((a->flow[l][r / 64] >> (r % 64)) & 1u);
}

static void set_flow(admit_t *a, int l, int r, int on)
{
    if (on)
        a->flow[l][r / 64] |= (uint64_t)1 << (r % 64);
    else
        a->flow[l][r / 64] &= ~((uint64_t)1 << (r % 64));
}

/* Whether a unit of need l may go to the seller in slot r: it sells the
 * good, and no unit of the need has tried it or is ordered from it. */
static int admit_edge(const bgb_market_t *m, const admit_t *a, int l, int r)
{
    const bgb_dir_agent_t *s = &bgb_directory_rows_const(m->dir)[r];
    if (a->room[r] <= 0 || !alive_seller(s, a->good[l]))
        return 0;
    const job_t *j = a->job[l];
    for (int i = 0; i < j->nunits; i++) {
        const unit_t *u = &j->unit[i];
        if (u->need == a->need[l] &&
            (tried(u, s->info.id) || (u->state != U_OPEN && u->agent == s->info.id)))
            return 0;
    }
    return 1;
}

/* One more unit of need l, on a seller with a free slot, moving units
 * already placed to other sellers where that makes room (an augmenting
 * path); 0 when there is none. */
static int admit_augment(const bgb_market_t *m, admit_t *a, int l)
{
    for (int r = 0; r < BGB_DIRECTORY_MAX_AGENTS; r++) {
        if (a->seen[r] || has_flow(a, l, r) || !admit_edge(m, a, l, r))
            continue;
        a->seen[r] = 1;
        if (a->used[r] < a->room[r]) {
            set_flow(a, l, r, 1);
            a->used[r]++;
            return 1;
        }
        for (int k = 0; k < a->n; k++)
            if (k != l && has_flow(a, k, r) && admit_augment(m, a, k)) {
                /* k found another seller (one more unit there); it
                 * leaves r, where l takes its place. */
                set_flow(a, k, r, 0);
                set_flow(a, l, r, 1);
                return 1;
            }
    }
    return 0;
}

/* Places job j's open service units; 0 when they do not all fit (the
 * placement is then partial, and the caller stops). */
static int admit_place(const bgb_market_t *m, admit_t *a, const job_t *j)
{
    for (int i = 0; i < j->nunits; i++) {
        const unit_t *u = &j->unit[i];
        if (u->state != U_OPEN)
            continue;
        int l = 0;
        while (l < a->n && !(a->job[l] == j && a->need[l] == u->need))
            l++;
        if (l == a->n) {
            if (a->n == ADMIT_NEEDS)
                return 0;
            a->job[l] = j;
            a->need[l] = u->need;
            a->good[l] = u->good;
            memset(a->flow[l], 0, sizeof a->flow[l]);
            a->n++;
        }
        memset(a->seen, 0, sizeof a->seen);
        if (!admit_augment(m, a, l))
            return 0;
    }
    return 1;
}

static void admit_fitting(bgb_market_t *m, double now)
{
    admit_t *a = m->admit;
    a->n = 0;
    const bgb_dir_agent_t *rows = bgb_directory_rows_const(m->dir);
    for (int r = 0; r < BGB_DIRECTORY_MAX_AGENTS; r++) {
        const bgb_dir_agent_t *s = &rows[r];
        a->used[r] = 0;
        a->room[r] = s->used && s->info.alive && !s->info.resource
                         ? s->info.free_slots - s->pending
                         : 0;
    }
    /* The jobs already in the book keep their place. */
    for (int i = 0; i < MAX_JOBS; i++) {
        const job_t *j = &m->jobs[i];
        if (j->used && !j->finished && !j->resource && j->mech == BGB_MECH_CENTRAL &&
            j->admitted && !admit_place(m, a, j))
            return;
    }
    for (;;) {
        job_t *first = NULL;
        for (int i = 0; i < MAX_JOBS; i++) {
            job_t *j = &m->jobs[i];
            if (j->used && !j->finished && !j->resource && j->mech == BGB_MECH_CENTRAL &&
                !j->admitted && (!first || j->started < first->started ||
                                 (j->started == first->started && j->id < first->id)))
                first = j;
        }
        if (!first || !admit_place(m, a, first))
            return;
        first->admitted = 1;
        open_requests(m, first, now);
    }
}

/* ------------------------------------------------------ clearing records */

/* A job's name in the log: its label (a sub-job's: its job's), else its
 * number. */
static void job_name(const bgb_market_t *m, const job_t *j, char *buf, size_t size)
{
    const job_t *named = j->resource ? job_by_id((bgb_market_t *)m, j->parent) : j;
    if (named && named->label[0])
        snprintf(buf, size, "%s", named->label);
    else
        snprintf(buf, size, "%llu", (unsigned long long)(named ? named->id : j->parent));
}

/* Logs a clearing that traded with the bounds its orders set; returns
 * its ledger id. */
static uint64_t log_clearing(bgb_market_t *m, double now, int layer, int good,
                             const bgm_clearing_t *res, double k,
                             const bgb_clearing_bound_t bounds[2])
{
    bgb_clearing_t c = {.time = now,
                        .layer = layer,
                        .good = good,
                        .volume = res->volume,
                        .rationed = res->rationed,
                        .k = k,
                        .price = res->price,
                        .low = res->low,
                        .high = res->high,
                        .low_by = bounds[0],
                        .high_by = bounds[1]};
    return bgb_ledger_add_clearing(m->ledger, &c);
}

/* Logs a service clearing of this tick once; returns its ledger id. */
static uint64_t log_service_clearing(bgb_market_t *m, match_ctx *mc,
                                     const bgb_auction_clearing_t *x)
{
    if (x->index < 0 || x->index >= BGB_AUCTION_MAX_CLEARINGS)
        return 0;
    if (mc->logged[x->index])
        return mc->logged[x->index];
    const bgm_clearing_t res = {.volume = x->volume,
                                .price = x->price,
                                .low = x->low,
                                .high = x->high,
                                .rationed = x->rationed};
    const bgb_auction_bound_t *in[2] = {&x->low_by, &x->high_by};
    bgb_clearing_bound_t out[2];
    for (int e = 0; e < 2; e++) {
        out[e] = (bgb_clearing_bound_t){
            .is_bid = in[e]->is_bid, .excluded = in[e]->excluded, .price = in[e]->price};
        if (in[e]->is_bid && in[e]->buyer < MAX_JOBS)
            job_name(m, &m->jobs[in[e]->buyer], out[e].job, sizeof out[e].job);
        else if (!in[e]->is_bid && in[e]->slot >= 0 && in[e]->slot < BGB_DIRECTORY_MAX_AGENTS)
            out[e].agent = bgb_directory_rows(m->dir)[in[e]->slot].info.id;
    }
    return mc->logged[x->index] = log_clearing(m, mc->now, 0, x->good, &res, x->k, out);
}

/* Logs a resource clearing (good g) of a host's call market; its bids
 * name the sub-jobs' units (refs), its asks the sellers. */
static uint64_t log_resource_clearing(bgb_market_t *m, int g, const bgm_clearing_t *res,
                                      const bidref_t *refs, double now)
{
    const bgm_bound_t *in[2] = {&res->low_by, &res->high_by};
    bgb_clearing_bound_t out[2];
    for (int e = 0; e < 2; e++) {
        out[e] = (bgb_clearing_bound_t){
            .is_bid = in[e]->is_bid, .excluded = in[e]->excluded, .price = in[e]->price};
        if (in[e]->is_bid) {
            const job_t *sj = refs[in[e]->ref].j;
            job_name(m, sj, out[e].job, sizeof out[e].job);
            out[e].agent = sj->buyer;
        } else {
            out[e].agent = in[e]->owner;
        }
    }
    return log_clearing(m, now, 1, g, res, m->c.k, out);
}

/* The auctioneer matched a unit's bid: the purchase hears the market
 * agent's acceptance, and the unit orders from that seller at the
 * clearing price, unless the host's checks (a seller it tried beyond the
 * message's cap, one gone since) refuse it: then the purchase hears the
 * match cancelled and bids again, and the seller's room is said again. */
static void on_match(void *ctx, const bgb_auction_match_t *x)
{
    match_ctx *mc = ctx;
    bgb_market_t *m = mc->m;
    if (x->buyer >= MAX_JOBS || x->slot < 0 || x->slot >= BGB_DIRECTORY_MAX_AGENTS)
        return;
    job_t *j = &m->jobs[x->buyer];
    bgb_dir_agent_t *a = &bgb_directory_rows(m->dir)[x->slot];
    unit_t *u = NULL;
    for (int i = 0; j->used && !j->finished && i < j->nunits && !u; i++)
        if (j->unit[i].in_book && j->unit[i].req == x->req && j->unit[i].attempt == x->attempt)
            u = &j->unit[i];
    if (!u) {
        if (a->used)
            announce(m, a);
        return;
    }
    u->in_book = 0;
    const uint32_t id = (uint32_t)(u - j->unit) + 1;
    answer(j, BGM_MT_ACCEPT, PU_MARKET, id, x->attempt, x->price);
    if (may_have(m, j, u, a)) {
        order(m, j, u, a, x->price, mc->now);
        u->clearing = x->clearing ? log_service_clearing(m, mc, x->clearing) : 0;
    } else {
        answer(j, BGM_MT_CANCEL, a->info.id, id, x->attempt, 0);
        if (a->used)
            announce(m, a);
    }
}

/* How many of the first nb bids on its host seller a has room for, each
 * taken alone. */
static int bids_with_room(const bgb_market_t *m, const bgb_dir_agent_t *a, const bidref_t *refs,
                          size_t nb)
{
    int n = 0;
    for (size_t i = 0; i < nb; i++)
        n += on_host(refs[i].j, a) && room_for(m, refs[i].j, a, refs[i].u);
    return n;
}

/* One host's call market for resource good g: its sub-jobs' open units
 * (run, n of them) bid at their limits; its seller asks, at its asking
 * price, as many units as bids it has room for, each taken alone (a job's
 * sub-jobs share its cores, so a count of cores would not say what it can
 * serve). A fill the unit cannot use (a seller it tried, room taken by
 * the fills before it) stays open for the next call. */
static void clear_host(bgb_market_t *m, int g, bgb_dir_agent_t *seller, bidref_t *run, size_t n,
                       double now)
{
    bgm_callmarket_reset(m->cm);
    for (size_t i = 0; i < n; i++) {
        bgm_order_t o = {
            .ref = i, .owner = buyer_of(m, run[i].j), .quantity = 1, .price = run[i].u->limit};
        bgm_callmarket_bid(m->cm, &o);
    }
    const int room = bids_with_room(m, seller, run, n);
    if (room == 0)
        return;
    bgm_order_t o = {.ref = (uint64_t)bgb_directory_slot_of(m->dir, seller),
                     .owner = seller->info.id,
                     .quantity = room,
                     .price = seller->info.price[g]};
    bgm_callmarket_ask(m->cm, &o);
    bgm_clearing_t res;
    if (bgm_callmarket_clear(m->cm, m->c.k, &res, m->fills, 2 * n + 2) != BG_OK || res.volume == 0)
        return;
    const uint64_t clearing = log_resource_clearing(m, g, &res, run, now);
    const bgm_order_t *bids = bgm_callmarket_bids(m->cm);
    for (size_t f = 0; f < res.fill_count; f++) {
        bidref_t *r = &run[bids[m->fills[f].bid].ref];
        if (need_has(r->j, r->u, seller->info.id) || tried(r->u, seller->info.id) ||
            !room_for(m, r->j, seller, r->u))
            continue;
        order(m, r->j, r->u, seller, res.price, now);
        r->u->clearing = clearing;
    }
}

/* Central resources (layer 1): a call market per resource good and host,
 * each cleared on its own (clear_host): a sub-job buys only on its basic
 * agent's host, so its bid meets that host's seller and no other, and
 * every fill is one it can take. (A book of every host's bids and sellers
 * paired bids with other hosts' sellers, and those fills were dropped
 * until a later clearing happened to pair them right.) */
static void central_clear(bgb_market_t *m, double now)
{
    bidref_t *refs = m->refs, *run = m->run;
    for (int g = BGB_GOOD_CORES; g < BGB_GOODS; g++) {
        size_t nb = 0;
        for (int ji = 0; ji < MAX_JOBS; ji++) {
            job_t *j = &m->jobs[ji];
            if (!j->used || j->finished || j->mech != BGB_MECH_CENTRAL || !j->resource)
                continue;
            for (int i = 0; i < j->nunits; i++) {
                unit_t *u = &j->unit[i];
                if (u->state == U_OPEN && u->good == g && u->in_book)
                    refs[nb++] = (bidref_t){j, u};
            }
        }
        for (int ai = 0; ai < BGB_DIRECTORY_MAX_AGENTS && nb > 0; ai++) {
            bgb_dir_agent_t *a = &bgb_directory_rows(m->dir)[ai];
            if (!alive_seller(a, g))
                continue;
            size_t n = 0;
            for (size_t i = 0; i < nb; i++)
                if (on_host(refs[i].j, a))
                    run[n++] = refs[i];
            if (n > 0)
                clear_host(m, g, a, run, n, now);
        }
    }
}

static void check_done(bgb_market_t *m, job_t *j, double now)
{
    for (int i = 0; i < j->nunits; i++)
        if (j->unit[i].state != U_DONE)
            return;
    finish(m, j, NULL, now);
}

/* Posted and central: an open unit that every live seller has refused
 * (or that has no seller at all) cannot be bought; the job fails now
 * rather than at its deadline. A sub-job's seller must also have room
 * now and, posted, ask within the unit's limit: its basic agent is
 * holding a service answer, which it refuses at once rather than after a
 * wait for a price or room that may not come. */
static int unbuyable(bgb_market_t *m, const job_t *j, const unit_t *u)
{
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++) {
        const bgb_dir_agent_t *a = &bgb_directory_rows_const(m->dir)[i];
        if (alive_seller(a, u->good) && on_host(j, a) && !tried(u, a->info.id) &&
            !need_has(j, u, a->info.id) && !is_excluded(j, a) &&
            (!j->resource || (room_for(m, j, a, u) &&
                              (j->mech != BGB_MECH_POSTED || a->info.price[u->good] <= u->limit))))
            return 0;
    }
    return 1;
}

/* A service unit given up on its seller: the resources that seller was
 * buying or bought for it go back. */
static void unit_lost(bgb_market_t *m, job_t *j, unit_t *u)
{
    if (!j->resource)
        drop_subjobs(m, j->id, u->agent, u->good);
    mark_tried(u, u->agent);
    u->state = U_OPEN;
}

static void step_job(bgb_market_t *m, job_t *j, double now)
{
    if (j->finished)
        return;
    if (now >= j->deadline) {
        finish(m, j, "timeout", now);
        return;
    }
    /* A seller that did not answer in time is given up; a service unit's
     * purchase hears it as the seller's no (its own phase timers end a
     * bargain that went quiet; this ends a commitment that did). */
    for (int i = 0; i < j->nunits; i++) {
        unit_t *u = &j->unit[i];
        if (u->state == U_ORDERED && now >= u->deadline) {
            const uint32_t seller = u->agent;
            let_go(m, j, u);
            seller_said_no(j, u, seller);
        }
    }
    deliver_answers(m, j, now);
    if (j->finished)
        return;
    /* A catallactic job with a unit that no seller has a slot for gives
     * up now ("no seller") rather than at its deadline: meanwhile it would
     * hold the slots its other units bought, and jobs that each hold part
     * of what they need wait for one another until they time out (16 jobs
     * at once on 8 agents bought 0.6 a second). Its buyer asks again
     * later, as a central or posted one does. */
    if (j->mech == BGB_MECH_CATALLACTIC && !j->resource)
        for (int i = 0; i < j->nunits; i++)
            if (j->unit[i].state == U_OPEN && sellers_with_room(m, j, &j->unit[i], NULL) == 0) {
                finish(m, j, "no seller", now);
                return;
            }
    if (j->mech != BGB_MECH_CATALLACTIC)
        for (int i = 0; i < j->nunits; i++)
            if (j->unit[i].state == U_OPEN && unbuyable(m, j, &j->unit[i])) {
                const char *why = !j->resource ? "no seller"
                                  : j->mech == BGB_MECH_POSTED
                                      ? "no free cores or memory on the host within the limit"
                                      : "no free cores or memory on the host";
                finish(m, j, why, now);
                return;
            }
}

/* A free job record for `job` (resource sub-jobs: term > 0, the lease). */
static bg_status start_job(bgb_market_t *m, job_t **out, uint64_t job, bgb_mechanism mechanism,
                           double budget, double term, double now, double timeout, bg_error_t *err)
{
    job_t *j = NULL;
    for (int i = 0; i < MAX_JOBS && !j; i++)
        if (!m->jobs[i].used)
            j = &m->jobs[i];
    if (!j)
        return bg_error_set(err, BG_ERR_LIMIT, "market: %d jobs buying at once", MAX_JOBS);
    memset(j, 0, sizeof *j);
    j->used = 1;
    j->id = job;
    j->mech = mechanism;
    j->budget = budget;
    j->started = now;
    j->deadline = now + timeout;
    j->term = term;
    *out = j;
    return BG_OK;
}

/* The cheapest asking price per good among live sellers (of the host, for
 * a sub-job): what the job must at least pay. It splits the budget into
 * per-unit limits in proportion to those prices, so Σ quantity × term ×
 * limit = budget and no unit's price can push the total over it. */
static void begin(bgb_market_t *m, job_t *j, const bgb_need_t *needs, int nneeds, double now)
{
    double ref[BGB_GOODS];
    int count[BGB_GOODS] = {0};
    for (int g = 0; g < BGB_GOODS; g++)
        ref[g] = INFINITY;
    for (int ai = 0; ai < BGB_DIRECTORY_MAX_AGENTS; ai++)
        for (int g = 0; g < BGB_GOODS; g++) {
            const bgb_dir_agent_t *a = &bgb_directory_rows_const(m->dir)[ai];
            if (alive_seller(a, g) && on_host(j, a) && !is_excluded(j, a)) {
                count[g]++;
                if (a->info.price[g] < ref[g])
                    ref[g] = a->info.price[g];
            }
        }
    const double weight = j->resource ? j->term : 1.0;
    double least = 0;
    for (int i = 0; i < nneeds; i++) {
        if (count[needs[i].good] < needs[i].sellers) {
            finish(m, j, "no seller", now);
            return;
        }
        least += needs[i].quantity * weight * ref[needs[i].good];
    }
    if (least > j->budget || least <= 0) {
        finish(m, j, least > j->budget ? "budget" : "no seller", now);
        return;
    }
    for (int i = 0; i < nneeds; i++)
        for (int s = 0; s < needs[i].sellers; s++) {
            unit_t *u = &j->unit[j->nunits++];
            u->need = i;
            u->good = needs[i].good;
            u->quantity = needs[i].quantity / needs[i].sellers;
            u->term = weight;
            u->limit = ref[u->good] * j->budget / least;
            /* Central bids and posted queries carry them to the market
             * agent, and the host skips them, as sellers already tried. */
            for (int e = 0; e < j->nexcluded; e++)
                mark_tried(u, j->excluded[e]);
        }
    if (!start_purchase(m, j, ref)) {
        finish(m, j, "market: out of memory", now);
        return;
    }
    /* Central services bid when the job is let into the book (admit_fitting). */
    if (j->resource || j->mech != BGB_MECH_CENTRAL)
        open_requests(m, j, now);
    if (!j->finished)
        step_job(m, j, now);
}

bg_status bgb_market_buy(bgb_market_t *m, uint64_t job, bgb_mechanism mechanism, double budget,
                         const bgb_need_t *needs, int nneeds, double now, bgb_done_fn done,
                         void *ctx, bg_error_t *err)
{
    return bgb_market_buy_excluding(m, job, mechanism, budget, needs, nneeds, NULL, 0, now, done,
                                    ctx, err);
}

bg_status bgb_market_buy_excluding(bgb_market_t *m, uint64_t job, bgb_mechanism mechanism,
                                   double budget, const bgb_need_t *needs, int nneeds,
                                   const uint32_t *exclude, int nexclude, double now,
                                   bgb_done_fn done, void *ctx, bg_error_t *err)
{
    if (nexclude < 0 || nexclude > MAX_TRIED || (nexclude > 0 && !exclude))
        return bg_error_set(err, BG_ERR_INVALID, "exclude: between 0 and %d sellers", MAX_TRIED);
    if ((int)mechanism < 0 || mechanism > BGB_MECH_POSTED)
        return bg_error_set(err, BG_ERR_INVALID, "mechanism: %d is unknown", (int)mechanism);
    if (!(budget >= 0 && isfinite(budget)))
        return bg_error_set(err, BG_ERR_INVALID, "budget: must be a finite number >= 0");
    if (nneeds < 1 || nneeds > BGB_MARKET_MAX_NEEDS)
        return bg_error_set(err, BG_ERR_INVALID, "needs: between 1 and %d", BGB_MARKET_MAX_NEEDS);
    if (job >= SUB_JOB_BASE)
        return bg_error_set(err, BG_ERR_INVALID, "job: ids from 2^49 on are the market's own");
    int nunits = 0;
    for (int i = 0; i < nneeds; i++) {
        if (needs[i].good < 0 || needs[i].good > BGB_GOOD_INTEG)
            return bg_error_set(err, BG_ERR_INVALID, "needs[%d].good: %d is not a service", i,
                                needs[i].good);
        if (!(needs[i].quantity > 0 && isfinite(needs[i].quantity)))
            return bg_error_set(err, BG_ERR_INVALID, "needs[%d].quantity: must be > 0", i);
        if (needs[i].sellers < 1 || needs[i].sellers > 16)
            return bg_error_set(err, BG_ERR_INVALID, "needs[%d].sellers: must be in [1, 16]", i);
        nunits += needs[i].sellers;
    }
    if (nunits > MAX_UNITS)
        return bg_error_set(err, BG_ERR_INVALID, "needs: more than %d sellers in all", MAX_UNITS);
    if (job_by_id(m, job))
        return bg_error_set(err, BG_ERR_CONFLICT, "job %llu is already buying",
                            (unsigned long long)job);
    job_t *j = NULL;
    bg_status st = start_job(m, &j, job, mechanism, budget, 0, now, m->c.buy_timeout, err);
    if (st != BG_OK)
        return st;
    j->done = done;
    j->ctx = ctx;
    for (int i = 0; i < nexclude; i++) {
        const bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, exclude[i]);
        const bgb_agent_info_t *gone = NULL;
        for (size_t g = 0; !a && !gone && g < bgb_directory_departed_count(m->dir); g++)
            if (bgb_directory_departed(m->dir, g)->id == exclude[i])
                gone = bgb_directory_departed(m->dir, g);
        j->excluded[j->nexcluded] = exclude[i];
        j->excluded_ep[j->nexcluded++] = a ? endpoint_hash(a->info.endpoint)
                                         : gone ? endpoint_hash(gone->endpoint)
                                                : 0;
    }
    begin(m, j, needs, nneeds, now);
    return BG_OK;
}

/* ------------------------------------------------------------ messages */

static unit_t *ordered_unit(job_t *j, uint32_t agent, int good)
{
    if (!j || j->finished)
        return NULL;
    for (int i = 0; i < j->nunits; i++)
        if (j->unit[i].state == U_ORDERED && j->unit[i].agent == agent && j->unit[i].good == good)
            return &j->unit[i];
    return NULL;
}

/* Whether the agent still sells the job something: then a stray answer
 * must not release the job on it (RELEASE frees all it holds for a job). */
static int still_serves(const job_t *j, uint32_t agent)
{
    for (int i = 0; j && i < j->nunits; i++)
        if (j->unit[i].state != U_OPEN && j->unit[i].agent == agent)
            return 1;
    return 0;
}

/* A basic agent that agreed to a service unit asks for its resources: a
 * sub-job on the unit's mechanism, among its host's resource sellers, for
 * at most the money it names. The unit waits for it. */
static void on_rbuy(bgb_market_t *m, bgb_dir_agent_t *a, const bga_mmsg_t *in, double now)
{
    job_t *j = job_by_id(m, in->job);
    unit_t *u = ordered_unit(j, a->info.id, in->good);
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_RFAIL);
    r.job = in->job;
    r.good = in->good;
    r.agent = a->info.id;
    bgb_need_t needs[2];
    int n = 0;
    if (in->cores > 0)
        needs[n++] = (bgb_need_t){BGB_GOOD_CORES, in->cores, 1};
    if (in->memory > 0)
        needs[n++] = (bgb_need_t){BGB_GOOD_MEMORY, in->memory, 1};
    if (!u || j->resource || n == 0 || !(in->term > 0)) {
        snprintf(r.reason, sizeof r.reason, "%s", !u ? "no such order" : "nothing to buy");
        bgb_directory_send(m->dir, a, &r, NULL);
        return;
    }
    drop_subjobs(m, j->id, a->info.id, in->good); /* an earlier try of the same unit */
    job_t *s = NULL;
    const double timeout = 1.5 * m->c.reply_timeout;
    if (start_job(m, &s, m->next_sub++, j->mech, in->price, in->term, now, timeout, NULL) !=
        BG_OK) {
        snprintf(r.reason, sizeof r.reason, "market full");
        bgb_directory_send(m->dir, a, &r, NULL);
        return;
    }
    s->resource = 1;
    s->parent = j->id;
    s->buyer = a->info.id;
    s->sgood = in->good;
    snprintf(s->host, sizeof s->host, "%s", a->info.endpoint);
    u->deadline = now + timeout + m->c.reply_timeout;
    /* The seller agreed (an order, an offer it accepted): the purchase is
     * committed to it now and waits for its delivery. */
    const bgm_purchase_req_t *q = request_of(j, u);
    if (q && q->state == BGM_PU_NEGOTIATE)
        answer(j, BGM_MT_ACCEPT, a->info.id, (uint32_t)(u - j->unit) + 1, q->attempt, u->price);
    deliver_answers(m, j, now);
    begin(m, s, needs, n, now);
}

/* The seller of unit u said no (a refusal, a confirmation that is not a
 * contract, walking away from a bargain): the unit gives it up, and a
 * job's purchase hears it and goes on (the next candidate or
 * proposal, or a new attempt). */
static void refused(bgb_market_t *m, job_t *j, unit_t *u, double now)
{
    const uint32_t seller = u->agent;
    let_go(m, j, u);
    seller_said_no(j, u, seller);
    deliver_answers(m, j, now);
    step_job(m, j, now);
}

static void on_answer(bgb_market_t *m, bgb_dir_agent_t *a, const bga_mmsg_t *in, double now)
{
    job_t *j = job_by_id(m, in->job);
    unit_t *u = ordered_unit(j, a->info.id, in->good);
    if (in->type == BGA_MM_REFUSE)
        a->info.refusals++;
    if (!u) {
        /* Late or unknown: a confirmation nobody wants is released. */
        if (in->type == BGA_MM_CONFIRM && !still_serves(j, a->info.id)) {
            release_on(m, a, in->job);
            if (!a->info.resource)
                drop_subjobs(m, in->job, a->info.id, in->good);
        }
        return;
    }
    if (in->type == BGA_MM_CONFIRM && in->price > u->limit * (1 + 1e-12)) {
        /* A seller confirming above the buyer's limit is not a contract. */
        release_on(m, a, in->job);
        refused(m, j, u, now);
    } else if (in->type == BGA_MM_CONFIRM) {
        unpend(m, a, u);
        if (j->pu) {
            /* The delivery, taken (a resource seller's confirmation is the
             * bundle's RCONFIRM): the request is bought. */
            bgm_purchase_done(j->pu, (uint32_t)(u - j->unit) + 1);
            if (j->mech == BGB_MECH_CATALLACTIC && !j->resource)
                m->memory[u->good] = bgm_memory_update(
                    m->memory[u->good], in->price, bgm_purchase_trader(j->pu)->genes.weight_memory);
        }
        u->state = U_DONE;
        u->price = in->price;
        u->seller_floor = in->floor[u->good];
        if (a->info.resource) {
            a->info.free_cores = in->free_cores;
            a->info.free_memory = in->free_memory;
        } else {
            a->info.free_slots = in->free_slots;
            announce(m, a);
        }
        check_done(m, j, now);
    } else {
        refused(m, j, u, now);
    }
}

/* The service sellers that could answer unit u's call for proposals now:
 * those its calls reach (its job's entry agents and, while hops are left,
 * their overlay neighbours, as the agents pass calls on: bgm_purchase
 * cfp_forward), alive, selling its good, with a free slot net of the
 * orders in flight to them, and not serving its need already (those do
 * not propose). INT_MAX when there is none: the round runs its window. */
static int could_propose(bgb_market_t *m, const job_t *j, const unit_t *u)
{
    uint32_t frontier[BGB_DIRECTORY_MAX_AGENTS];
    uint8_t reached[BGB_DIRECTORY_MAX_AGENTS] = {0};
    int n = entry_agents(m, j, frontier), first = 0, count = 0;
    for (int i = 0; i < n; i++) {
        bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, frontier[i]);
        reached[a ? bgb_directory_slot_of(m->dir, a) : 0] = a != NULL;
    }
    for (int hop = 1; hop < m->c.hops; hop++) {
        const int last = n;
        for (int i = first; i < last; i++) {
            const bgb_dir_agent_t *a = bgb_directory_by_id(m->dir, frontier[i]);
            for (int k = 0; a && k < a->nnb; k++) {
                bgb_dir_agent_t *b = bgb_directory_by_id(m->dir, a->nb[k]);
                if (b && b->info.alive && !reached[bgb_directory_slot_of(m->dir, b)]) {
                    reached[bgb_directory_slot_of(m->dir, b)] = 1;
                    frontier[n++] = b->info.id;
                }
            }
        }
        first = last;
    }
    count = sellers_with_room(m, j, u, reached);
    return count > 0 ? count : INT_MAX;
}

/* Unit u's round of discovery ends now rather than at its window's end:
 * every seller that could propose has (could_propose). Its purchase's
 * discovery timer is brought forward and run, so the machine bargains
 * with the proposals it holds exactly as it would at the window's end;
 * the window stays the wait for sellers that are slow or unknown. */
static void close_discovery(bgb_market_t *m, job_t *j, const unit_t *u, double now)
{
    const bgm_purchase_req_t *q = request_of(j, u);
    if (!q || q->state != BGM_PU_DISCOVER)
        return;
    const uint32_t id = (uint32_t)(u - j->unit) + 1;
    for (int i = 0; i < j->ntimers; i++)
        if (j->timers[i].kind == BGM_PU_TIMER_REQ && (uint32_t)j->timers[i].arg == id &&
            j->timers[i].at > now)
            j->timers[i].at = now;
    run_timers(m, j, now);
}

/* A seller's bargaining message: a proposal goes to every request of its
 * good discovering in the round it answers (the seller answers one call
 * per good and round: two units of a need hear the same sellers); a
 * counter-offer or walking away goes to the request bargaining with that
 * seller, in the request's attempt. A sub-job hears only its host's
 * resource sellers, at their bundle's rate and speed 1. */
static void on_bargain_msg(bgb_market_t *m, bgb_dir_agent_t *a, const bga_mmsg_t *in, double now)
{
    job_t *j = job_by_id(m, in->job);
    if (!j || j->finished || j->mech != BGB_MECH_CATALLACTIC || !j->pu)
        return;
    if (in->type == BGA_MM_PROPOSE) {
        if (!on_host(j, a))
            return;
        for (int i = 0; i < j->nunits && j->pu; i++) {
            unit_t *u = &j->unit[i];
            const bgm_purchase_req_t *q = request_of(j, u);
            if (u->good != in->good || !q || q->state != BGM_PU_DISCOVER || in->attempt < 0 ||
                q->attempt != (uint32_t)in->attempt)
                continue;
            bgm_msg_t p =
                bgm_outbox_msg(BGM_MT_PROPOSE, a->info.id, PU_SELF, (uint32_t)i + 1, q->attempt);
            p.good = (int16_t)q->good;
            p.price = machine_price(j, u, in->price);
            p.a = 1.0;
            if (u->round != q->attempt)
                u->proposals = 0;
            u->round = q->attempt;
            u->proposals++;
            tell(m, j, &p, now);
            if (!j->resource && j->pu && u->proposals >= could_propose(m, j, u))
                close_discovery(m, j, u, now);
        }
        return;
    }
    unit_t *u = ordered_unit(j, a->info.id, in->good);
    const bgm_purchase_req_t *q = u ? request_of(j, u) : NULL;
    if (!q)
        return;
    if (in->type == BGA_MM_OFFER) {
        bgm_msg_t o = bgm_outbox_msg(BGM_MT_OFFER, a->info.id, PU_SELF, (uint32_t)(u - j->unit) + 1,
                                     q->attempt);
        o.good = (int16_t)q->good;
        u->heard = in->price;
        o.price = machine_price(j, u, in->price);
        tell(m, j, &o, now);
        step_job(m, j, now);
    } else {
        refused(m, j, u, now);
    }
}

bg_status bgb_market_refuse(bgb_market_t *m, const uint8_t *identity, size_t identity_len,
                            const char *why, bg_error_t *err)
{
    if (identity_len == 0 || identity_len > BGB_DIRECTORY_IDENTITY_MAX)
        return BG_OK;
    return bgb_directory_reply_error(m->dir, identity, identity_len, why, err);
}

bg_status bgb_market_on_frames(bgb_market_t *m, const uint8_t *identity, size_t identity_len,
                               const bga_frame_t *frames, int nframes, double now, bg_error_t *err)
{
    if (identity_len == 0 || identity_len > BGB_DIRECTORY_IDENTITY_MAX)
        return BG_OK;
    bga_mmsg_t in;
    bg_error_t derr = BG_ERROR_INIT;
    if (bga_mmsg_decode(frames, nframes, &in, &derr) != BG_OK)
        return bgb_directory_reply_error(m->dir, identity, identity_len, derr.message, err);
    if (in.type == BGA_MM_REGISTER) {
        bgb_dir_agent_t *a = NULL;
        const bg_status st =
            bgb_directory_register(m->dir, identity, identity_len, &in, now, &a, err);
        if (a)
            announce(m, a);
        return st;
    }
    bgb_dir_agent_t *a = bgb_directory_by_identity(m->dir, identity, identity_len, in.resource);
    if (!a)
        return bgb_directory_reply_error(m->dir, identity, identity_len,
                                         "unknown agent: register first", err);
    switch (in.type) {
    case BGA_MM_HEARTBEAT:
        bgb_directory_heartbeat(a, &in, now);
        announce(m, a);
        break;
    case BGA_MM_CONFIRM:
    case BGA_MM_REFUSE:
        on_answer(m, a, &in, now);
        break;
    case BGA_MM_PROPOSE:
    case BGA_MM_OFFER:
    case BGA_MM_REJECT:
        on_bargain_msg(m, a, &in, now);
        break;
    case BGA_MM_RBUY:
        if (!a->info.resource)
            on_rbuy(m, a, &in, now);
        break;
    case BGA_MM_RELAY:
        bgb_directory_relay(m->dir, &in);
        break;
    default:
        break;
    }
    return BG_OK;
}

double bgb_market_tick(bgb_market_t *m, double now)
{
    bgb_directory_expire(m->dir, now, withdraw, m);
    match_ctx mc = {.m = m, .now = now};
    if (now >= m->next_auction)
        admit_fitting(m, now);
    bgb_auction_tick(m->auction, now, on_match, &mc, &m->next_auction, NULL);
    for (int i = 0; i < MAX_JOBS; i++)
        if (m->jobs[i].used)
            deliver_answers(m, &m->jobs[i], now); /* the clearing's matches */
    const double next_services = m->next_auction;
    if (now >= m->next_clear) {
        central_clear(m, now);
        m->next_clear = now + m->c.period;
    }
    double next = m->next_clear < next_services ? m->next_clear : next_services;
    for (int i = 0; i < MAX_JOBS; i++) {
        job_t *j = &m->jobs[i];
        if (!j->used || j->finished)
            continue;
        const double timer = run_timers(m, j, now);
        if (timer < next)
            next = timer;
        step_job(m, j, now);
        if (j->used && !j->finished) {
            if (j->deadline < next)
                next = j->deadline;
            for (int k = 0; k < j->nunits; k++)
                if (j->unit[k].state == U_ORDERED && j->unit[k].deadline < next)
                    next = j->unit[k].deadline;
        }
    }
    const double beat = now + m->c.heartbeat_timeout / 4;
    return beat < next ? beat : next;
}
