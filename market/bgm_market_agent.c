#include "bgm_market_agent.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_callmarket.h"
#include "bgm_combex.h"
#include "bgm_posted.h"

/* Each book holds at most this many orders a side (a hard cap). */
#define MA_BOOK_MAX 100000
/* Memory is sold in MiB. */
#define MA_MIB 1024.0

/* A service bid as it arrived: with the sellers it must not be matched
 * with and its need group (0: none), which a live buyer sets. */
typedef struct ma_bid {
    uint32_t req, buyer, attempt;
    int good, matched;
    double limit, work, deadline;
    uint32_t group;
    int nexclude;
    uint32_t exclude[BGM_MSG_CANDIDATES];
} ma_bid_t;

/* A resource bid (a bundle for one service) as it arrived. */
typedef struct ma_rbid {
    uint32_t req, buyer, attempt;
    int awarded;
    double cores, memory, flops, limit, deadline;
} ma_rbid_t;

/* A seller as its announcements describe it. */
typedef struct ma_seller {
    uint32_t agent;
    double free_a, free_b, price, speed, mem_cost;
    double reservation[BGM_SERVICE_TYPES];
    int sells[BGM_SERVICE_TYPES];
} ma_seller_t;

struct bgm_market_agent {
    bgm_config_t cfg;
    bgm_market_agent_params_t p;
    ma_bid_t *bids;
    ma_rbid_t *rbids;
    size_t nbid, nrbid;
    ma_seller_t *mb, *mr; /* basic and resource sellers */
    uint32_t nmb, nmr;
    bgm_callmarket_t *cm;
    bgm_combex_t *cx;
    bgm_fill_t *fills;
    int *assign;
    size_t *slot; /* call-market order → bid record, for the clearing under way */
    bgm_posted_t *dir;
    size_t next_fit[BGM_ROLE_GOODS]; /* per good: where the directory's next scan starts */
    double combex_exact, combex_greedy;
    bgm_ma_clearing_t clearings[BGM_MA_CLEARINGS_MAX]; /* the last timer call's */
    size_t nclearings, nmatches;
    bgm_emitter_t em; /* the call under way's outbox and first failure */
};

/* Messages start from a zeroed body with their header set. */
static bgm_msg_t msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    return bgm_outbox_msg(type, from, to, req, attempt);
}

static double duration(const ma_rbid_t *r, double speed)
{
    return r->flops / (speed * (r->cores > 0 ? r->cores : 1.0));
}

bgm_market_agent_t *bgm_market_agent_new(const bgm_market_agent_params_t *p)
{
    bgm_market_agent_t *ma = calloc(1, sizeof *ma);
    if (!ma)
        return NULL;
    ma->em.self = p->self;
    ma->cfg = *p->cfg;
    ma->p = *p;
    ma->p.cfg = &ma->cfg;
    ma->bids = malloc(MA_BOOK_MAX * sizeof *ma->bids);
    ma->rbids = malloc(MA_BOOK_MAX * sizeof *ma->rbids);
    ma->mb = calloc(p->nbasic ? p->nbasic : 1, sizeof *ma->mb);
    ma->mr = calloc(p->nresource ? p->nresource : 1, sizeof *ma->mr);
    ma->cm = bgm_callmarket_new(MA_BOOK_MAX);
    ma->fills = malloc(2 * MA_BOOK_MAX * sizeof *ma->fills);
    ma->assign = malloc(MA_BOOK_MAX * sizeof *ma->assign);
    ma->slot = malloc(MA_BOOK_MAX * sizeof *ma->slot);
    ma->cx = bgm_combex_new(MA_BOOK_MAX, (int)p->nresource, 4u * MA_BOOK_MAX);
    ma->dir = bgm_posted_new((size_t)(p->nbasic * BGM_SERVICE_TYPES + p->nresource));
    if (!ma->bids || !ma->rbids || !ma->mb || !ma->mr || !ma->cm || !ma->fills || !ma->assign ||
        !ma->slot || !ma->cx || !ma->dir)
        bgm_market_agent_destroy(&ma);
    return ma;
}

void bgm_market_agent_destroy(bgm_market_agent_t **pma)
{
    if (!pma || !*pma)
        return;
    bgm_market_agent_t *ma = *pma;
    free(ma->bids);
    free(ma->rbids);
    free(ma->mb);
    free(ma->mr);
    bgm_callmarket_destroy(&ma->cm);
    free(ma->fills);
    free(ma->assign);
    free(ma->slot);
    bgm_combex_destroy(&ma->cx);
    bgm_posted_destroy(&ma->dir);
    free(ma);
    *pma = NULL;
}

void bgm_market_agent_counts(const bgm_market_agent_t *ma, double *exact, double *greedy)
{
    *exact = ma->combex_exact;
    *greedy = ma->combex_greedy;
}

const bgm_ma_clearing_t *bgm_market_agent_clearings(const bgm_market_agent_t *ma, size_t *n)
{
    *n = ma->nclearings;
    return ma->clearings;
}

void bgm_market_agent_books(const bgm_market_agent_t *ma, size_t *bids, size_t *rbids)
{
    *bids = ma->nbid;
    *rbids = ma->nrbid;
}

/* ------------------------------------------------------------- services */

static int excluded(const uint32_t *list, int n, uint32_t seller)
{
    for (int i = 0; i < n; i++)
        if (list[i] == seller)
            return 1;
    return 0;
}

/* Bid r was matched with `seller`: the other bids of its buyer's need
 * group exclude that seller from now on (a need split over n sellers
 * goes to n distinct ones, in this clearing and the next). A full list
 * leaves the rest to the buyer, which refuses a match it cannot take. */
static void group_matched(bgm_market_agent_t *ma, const ma_bid_t *r, uint32_t seller)
{
    for (size_t i = 0; i < ma->nbid; i++) {
        ma_bid_t *o = &ma->bids[i];
        if (o != r && !o->matched && o->buyer == r->buyer && o->group == r->group &&
            o->nexclude < BGM_MSG_CANDIDATES && !excluded(o->exclude, o->nexclude, seller))
            o->exclude[o->nexclude++] = seller;
    }
}

/* Bid r is matched with seller s at `price` (s asked `ask`): the seller
 * is told (MATCH: the bid's work and deadline, the price, its own ask)
 * and so is the buyer (ACCEPT at the price). */
static void match(bgm_market_agent_t *ma, ma_bid_t *r, ma_seller_t *s, double price, double ask)
{
    ma->nmatches++;
    s->free_a -= 1.0;
    r->matched = 1;
    if (r->group)
        group_matched(ma, r, s->agent);
    bgm_msg_t m = msg(BGM_MT_MATCH, ma->p.self, s->agent, r->req, r->attempt);
    m.good = (int16_t)r->good;
    m.price = price;
    m.a = r->work;
    m.b = ask;
    m.c = r->deadline;
    m.origin = r->buyer;
    bgm_emitter_send(&ma->em, &m);
    bgm_msg_t c = msg(BGM_MT_ACCEPT, ma->p.self, r->buyer, r->req, r->attempt);
    c.price = price;
    bgm_emitter_send(&ma->em, &c);
}

/* Places the asks of good t's sellers with a free slot (all of them, or
 * those bid `only` does not exclude). */
static int place_asks(bgm_market_agent_t *ma, int t, const ma_bid_t *only)
{
    for (uint32_t k = 0; k < ma->nmb; k++) {
        const ma_seller_t *s = &ma->mb[k];
        if (!s->sells[t] || s->free_a < 1.0 ||
            (only && excluded(only->exclude, only->nexclude, s->agent)))
            continue;
        bgm_order_t o = {k, s->agent, (int)s->free_a, s->reservation[t]};
        if (bgm_callmarket_ask(ma->cm, &o))
            return -1;
    }
    return 0;
}

/* Records a clearing of good t that made the matches from `first` on. */
static void record(bgm_market_agent_t *ma, int t, const bgm_clearing_t *res, size_t first)
{
    if (ma->nmatches > first && ma->nclearings < BGM_MA_CLEARINGS_MAX)
        ma->clearings[ma->nclearings++] = (bgm_ma_clearing_t){t, *res, first, ma->nmatches - first};
}

/* One k-double call market per service type over the bids still open and
 * the basic sellers' free slots at their reservations; each fill is a
 * match. A bid the uniform clearing paired with a seller it excludes is
 * cleared after it, alone, against the free slots of the sellers it
 * allows, at that book's own k-double price: every trade stays within
 * both limits, and an excluded cheapest seller cannot keep a bid out of
 * the market for ever. (The simulator's buyers exclude nobody.) */
static void clear_services(bgm_market_agent_t *ma, double now)
{
    size_t keep = 0;
    for (size_t i = 0; i < ma->nbid; i++)
        if (ma->bids[i].deadline > now)
            ma->bids[keep++] = ma->bids[i];
    ma->nbid = keep;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        bgm_callmarket_reset(ma->cm);
        size_t nb = 0;
        for (size_t i = 0; i < ma->nbid; i++) {
            const ma_bid_t *r = &ma->bids[i];
            if (r->good != t)
                continue;
            /* The request id is the order's reference: ties break by it. */
            bgm_order_t o = {r->req, r->buyer, 1, r->limit};
            if (bgm_callmarket_bid(ma->cm, &o))
                break;
            ma->slot[nb++] = i;
        }
        bgm_clearing_t res;
        if (place_asks(ma, t, NULL) ||
            bgm_callmarket_clear(ma->cm, ma->cfg.central.k, &res, ma->fills, 2 * MA_BOOK_MAX)) {
            bgm_emitter_fail(&ma->em, BG_ERR_LIMIT);
            return;
        }
        const bgm_order_t *asks = bgm_callmarket_asks(ma->cm);
        const size_t first = ma->nmatches;
        size_t nskipped = 0; /* bid records, in the clearing's order, in assign[] */
        for (size_t f = 0; f < res.fill_count; f++) {
            /* Fills index the book in insertion order (clearing does not
             * reorder it), so slot[] names the bid record. */
            ma_bid_t *r = &ma->bids[ma->slot[ma->fills[f].bid]];
            ma_seller_t *s = &ma->mb[asks[ma->fills[f].ask].ref];
            if (excluded(r->exclude, r->nexclude, s->agent))
                ma->assign[nskipped++] = (int)ma->slot[ma->fills[f].bid];
            else
                match(ma, r, s, res.price, asks[ma->fills[f].ask].price);
        }
        record(ma, t, &res, first);
        for (size_t i = 0; i < nskipped; i++) {
            ma_bid_t *r = &ma->bids[ma->assign[i]];
            bgm_callmarket_reset(ma->cm);
            bgm_order_t o = {r->req, r->buyer, 1, r->limit};
            if (bgm_callmarket_bid(ma->cm, &o) || place_asks(ma, t, r) ||
                bgm_callmarket_clear(ma->cm, ma->cfg.central.k, &res, ma->fills, 2 * MA_BOOK_MAX)) {
                bgm_emitter_fail(&ma->em, BG_ERR_LIMIT);
                return;
            }
            if (res.fill_count == 1) {
                const bgm_order_t *a = &bgm_callmarket_asks(ma->cm)[ma->fills[0].ask];
                const size_t alone = ma->nmatches;
                match(ma, r, &ma->mb[a->ref], res.price, a->price);
                record(ma, t, &res, alone);
            }
        }
    }
    keep = 0;
    for (size_t i = 0; i < ma->nbid; i++)
        if (!ma->bids[i].matched)
            ma->bids[keep++] = ma->bids[i];
    ma->nbid = keep;
}

/* ------------------------------------------------------------ resources */

/* Drops the resource bids whose deadline has passed (their buyers give up
 * on their own then) and those awarded; returns how many remain. */
static size_t compact_rbids(bgm_market_agent_t *ma, double now)
{
    size_t keep = 0;
    for (size_t i = 0; i < ma->nrbid; i++)
        if (ma->rbids[i].deadline > now && !ma->rbids[i].awarded)
            ma->rbids[keep++] = ma->rbids[i];
    ma->nrbid = keep;
    return keep;
}

/* The resource layer through the combinatorial exchange: whole bundles,
 * each from one resource agent, winner determination by bgm_combex, and
 * each award paid its seller's cost plus a rent priced against the bids
 * and sellers left out (bgm_combex_rents). */
static void clear_exchange(bgm_market_agent_t *ma, double now)
{
    if (compact_rbids(ma, now) == 0)
        return;
    bgm_combex_reset(ma->cx);
    int *seller_of = malloc((ma->nmr ? ma->nmr : 1) * sizeof *seller_of);
    uint32_t *mr_of = malloc((ma->nmr ? ma->nmr : 1) * sizeof *mr_of);
    double *rent = NULL;
    if (!seller_of || !mr_of) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    for (size_t i = 0; i < ma->nrbid; i++)
        bgm_combex_add_bid(ma->cx);
    for (uint32_t k = 0; k < ma->nmr; k++) {
        seller_of[k] = -1;
        if (ma->mr[k].free_a <= 0.0)
            continue;
        double cap[BGM_COMBEX_DIMS] = {ma->mr[k].free_a, ma->mr[k].free_b};
        int s = bgm_combex_add_seller(ma->cx, cap);
        seller_of[k] = s;
        mr_of[s] = k;
    }
    for (size_t i = 0; i < ma->nrbid; i++) {
        const ma_rbid_t *r = &ma->rbids[i];
        for (uint32_t k = 0; k < ma->nmr; k++) {
            const ma_seller_t *s = &ma->mr[k];
            if (seller_of[k] < 0 || r->cores > s->free_a || r->memory > s->free_b)
                continue;
            double dur = duration(r, s->speed);
            double cost = (s->price * r->cores + s->mem_cost * r->memory) * dur;
            if (cost >= r->limit)
                continue;
            bgm_combex_pair_t p = {(int)i, seller_of[k], r->limit - cost, {r->cores, r->memory}};
            if (bgm_combex_add_pair(ma->cx, &p))
                break;
        }
    }
    bgm_combex_result_t res;
    if (bgm_combex_solve(ma->cx, BGM_COMBEX_AUTO, (size_t)ma->cfg.central.exact_limit,
                         ma->cfg.central.greedy_budget, ma->assign, &res)) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    if (res.method == BGM_COMBEX_EXACT)
        ma->combex_exact += 1.0;
    else
        ma->combex_greedy += 1.0;
    rent = malloc((ma->nrbid ? ma->nrbid : 1) * sizeof *rent);
    if (!rent || bgm_combex_rents(ma->cx, ma->assign, ma->cfg.central.k, rent)) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    const bgm_combex_pair_t *pairs = bgm_combex_pairs(ma->cx);
    for (size_t i = 0; i < ma->nrbid; i++) {
        if (ma->assign[i] < 0)
            continue;
        const bgm_combex_pair_t *p = &pairs[ma->assign[i]];
        ma_rbid_t *r = &ma->rbids[i];
        ma_seller_t *s = &ma->mr[mr_of[p->seller]];
        double dur = duration(r, s->speed);
        double cost = r->limit - p->surplus;
        double total = cost + rent[i];
        s->free_a -= r->cores;
        s->free_b -= r->memory;
        r->awarded = 1;
        bgm_msg_t m = msg(BGM_MT_RAWARD, ma->p.self, s->agent, r->req, r->attempt);
        m.price = total / dur;
        m.origin = r->buyer;
        m.a = r->cores;
        m.b = r->memory;
        m.c = r->flops;
        m.cand_price[1] = r->limit;
        bgm_emitter_send(&ma->em, &m);
    }
    compact_rbids(ma, now);
out:
    free(seller_of);
    free(mr_of);
    free(rent);
}

/* One bundle's bids on the two call markets, as its proxy places them. */
typedef struct call_bid {
    double tref;     /* run time at the reference speed */
    double bid_core; /* limit per reference core-second */
    double bid_mem;  /* limit per GiB-second */
    double dur;      /* run time on the cores won: the slowest of them */
    double spent;    /* paid for the cores */
    int cores, got_cores;
    long mib, got_mib;
} call_bid_t;

/* Copies the fills of the last clearing: the market's book is reused. */
static bgm_fill_t *copy_fills(const bgm_market_agent_t *ma, size_t n)
{
    bgm_fill_t *f = malloc((n ? n : 1) * sizeof *f);
    if (f)
        memcpy(f, ma->fills, n * sizeof *f);
    return f;
}

/* Sends seller k its part of bundle i: q units of `good` for dur seconds
 * from `start` at rate per unit-second. */
static void award_part(bgm_market_agent_t *ma, size_t i, uint32_t k, int good, double q,
                       double start, double dur, double rate, double limit, int parts)
{
    const ma_rbid_t *r = &ma->rbids[i];
    ma_seller_t *s = &ma->mr[k];
    if (good == BGM_GOOD_CORES_ID)
        s->free_a -= q;
    else
        s->free_b -= q;
    bgm_msg_t m = msg(BGM_MT_RPART, ma->p.self, s->agent, r->req, r->attempt);
    m.good = (int16_t)good;
    m.hops = (uint16_t)parts;
    m.a = q;
    m.b = dur;
    m.price = rate;
    m.c = limit;
    m.origin = r->buyer;
    m.cand_price[0] = start;
    bgm_emitter_send(&ma->em, &m);
}

/*
 * The resource layer through a call market per resource type
 * (central.resource_market "call"): cores first, then memory, each a
 * double auction with one uniform k-price, the auctioneer bidding for each
 * basic agent as its proxy within the budget the bid carried. Cores are
 * priced per reference core-second, memory per GiB-second and sold in
 * MiB; all parts of a bundle start together a period after the clearing.
 * A bundle not filled in full on both markets is cancelled whole before
 * anyone is told and its bid stays in the book (market/README.md, "How the
 * mechanisms run", has the whole protocol).
 */
static void clear_calls(bgm_market_agent_t *ma, double now)
{
    size_t n = compact_rbids(ma, now);
    if (n == 0)
        return;
    const double sref = ma->cfg.network.speed, k = ma->cfg.central.k;
    const double start = now + ma->cfg.central.period;
    call_bid_t *cb = calloc(n, sizeof *cb);
    int *parts = calloc(n, sizeof *parts);
    bgm_fill_t *cf = NULL, *mf = NULL;
    bgm_clearing_t rc, rm;
    if (!cb || !parts) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    bgm_callmarket_reset(ma->cm);
    for (size_t i = 0; i < n; i++) {
        const ma_rbid_t *r = &ma->rbids[i];
        double cc = ma->cfg.resources.core_cost * r->cores,
               mc = ma->cfg.resources.memory_cost * r->memory;
        double share = cc + mc > 0.0 ? cc / (cc + mc) : 1.0;
        cb[i].cores = (int)r->cores;
        cb[i].tref = r->flops / (r->cores * sref);
        cb[i].bid_core = share * r->limit / (r->cores * cb[i].tref);
        cb[i].mib = (long)ceil(r->memory * MA_MIB - 1e-9);
        bgm_order_t o = {i, r->buyer, cb[i].cores, cb[i].bid_core};
        if (bgm_callmarket_bid(ma->cm, &o))
            break;
    }
    for (uint32_t j = 0; j < ma->nmr; j++) {
        const ma_seller_t *s = &ma->mr[j];
        int free = (int)floor(s->free_a + 1e-9);
        bgm_order_t o = {j, s->agent, free, s->price * sref / s->speed};
        if (free >= 1 && bgm_callmarket_ask(ma->cm, &o))
            break;
    }
    if (bgm_callmarket_clear(ma->cm, k, &rc, ma->fills, 2 * MA_BOOK_MAX) ||
        !(cf = copy_fills(ma, rc.fill_count))) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    const bgm_order_t *asks = bgm_callmarket_asks(ma->cm);
    for (size_t f = 0; f < rc.fill_count; f++) {
        /* From here on a fill names the bundle (index into rbids) and the
         * seller (index into mr), read from the orders' refs. */
        size_t i = bgm_callmarket_bids(ma->cm)[cf[f].bid].ref;
        uint32_t j = (uint32_t)asks[cf[f].ask].ref;
        cf[f].bid = i;
        cf[f].ask = j;
        cb[i].got_cores += cf[f].quantity;
        cb[i].dur = fmax(cb[i].dur, cb[i].tref * sref / ma->mr[j].speed);
    }

    bgm_callmarket_reset(ma->cm);
    for (size_t i = 0; i < n; i++) {
        if (cb[i].got_cores < cb[i].cores || cb[i].mib == 0)
            continue;
        cb[i].spent = rc.price * cb[i].cores * cb[i].tref;
        double left = ma->rbids[i].limit - cb[i].spent;
        cb[i].bid_mem = left / ((double)cb[i].mib / MA_MIB * cb[i].dur);
        bgm_order_t o = {i, ma->rbids[i].buyer, (int)cb[i].mib, cb[i].bid_mem};
        if (cb[i].bid_mem > 0.0 && bgm_callmarket_bid(ma->cm, &o))
            break;
    }
    for (uint32_t j = 0; j < ma->nmr; j++) {
        const ma_seller_t *s = &ma->mr[j];
        double free = floor(s->free_b * MA_MIB + 1e-9);
        bgm_order_t o = {j, s->agent, free > INT32_MAX ? INT32_MAX : (int)free, s->mem_cost};
        if (free >= 1.0 && bgm_callmarket_ask(ma->cm, &o))
            break;
    }
    if (bgm_callmarket_clear(ma->cm, k, &rm, ma->fills, 2 * MA_BOOK_MAX) ||
        !(mf = copy_fills(ma, rm.fill_count))) {
        bgm_emitter_fail(&ma->em, BG_ERR_NOMEM);
        goto out;
    }
    asks = bgm_callmarket_asks(ma->cm);
    for (size_t f = 0; f < rm.fill_count; f++) {
        size_t i = bgm_callmarket_bids(ma->cm)[mf[f].bid].ref;
        mf[f].bid = i;
        mf[f].ask = (uint32_t)asks[mf[f].ask].ref;
        cb[i].got_mib += mf[f].quantity;
    }

    /* Award the complete bundles, part by part. */
    for (size_t f = 0; f < rc.fill_count; f++)
        parts[cf[f].bid]++;
    for (size_t f = 0; f < rm.fill_count; f++)
        parts[mf[f].bid]++;
    for (size_t f = 0; f < rc.fill_count; f++) {
        size_t i = cf[f].bid;
        if (cb[i].got_cores < cb[i].cores || cb[i].got_mib < cb[i].mib)
            continue;
        double ratio = ma->mr[cf[f].ask].speed / sref;
        award_part(ma, i, (uint32_t)cf[f].ask, BGM_GOOD_CORES_ID, cf[f].quantity, start,
                   cb[i].tref / ratio, rc.price * ratio, cb[i].bid_core * ratio, parts[i]);
    }
    for (size_t f = 0; f < rm.fill_count; f++) {
        size_t i = mf[f].bid;
        if (cb[i].got_cores < cb[i].cores || cb[i].got_mib < cb[i].mib)
            continue;
        award_part(ma, i, (uint32_t)mf[f].ask, BGM_GOOD_MEMORY_ID, (double)mf[f].quantity / MA_MIB,
                   start, cb[i].dur, rm.price, cb[i].bid_mem, parts[i]);
    }
    for (size_t i = 0; i < n; i++)
        if (cb[i].got_cores >= cb[i].cores && cb[i].got_mib >= cb[i].mib)
            ma->rbids[i].awarded = 1;
    compact_rbids(ma, now);
out:
    free(cb);
    free(parts);
    free(cf);
    free(mf);
}

/* ------------------------------------------------------------ directory */

typedef struct room_ctx {
    const bgm_market_agent_t *ma;
    const bgm_msg_t *query;
} room_ctx_t;

static int has_room(void *ctx, const bgm_posting_t *p)
{
    const room_ctx_t *rc = ctx;
    const bgm_market_agent_t *ma = rc->ma;
    if (excluded(rc->query->cand, rc->query->ncand, p->seller))
        return 0;
    if (rc->query->good == BGM_GOOD_CORES_ID) {
        const ma_seller_t *s = &ma->mr[p->seller - ma->p.first_resource];
        return s->free_a >= rc->query->a && s->free_b >= rc->query->b;
    }
    return ma->mb[p->seller - ma->p.first_basic].free_a >= 1.0;
}

/* Next fit over the sellers the directory believes have room, in
 * registration order from where the previous answer for that good
 * started, up to the candidate cap. Each answer's first candidate is the
 * seller after the previous answer's first: buyers asking at about the
 * same time are spread over the sellers. Plain first fit (every scan from
 * the first seller) sent them all to the same few: the directory's view of
 * free room lags by a message, so at 400 nodes the first candidates of
 * every list were full and buyers spent 43 orders each on refusals
 * (market/README.md, "Issue 31"). */
static void on_query(bgm_market_agent_t *ma, const bgm_msg_t *m)
{
    bgm_posting_t found[BGM_MSG_CANDIDATES];
    int cap = ma->cfg.baseline.candidates < BGM_MSG_CANDIDATES ? ma->cfg.baseline.candidates
                                                               : BGM_MSG_CANDIDATES;
    room_ctx_t rc = {ma, m};
    size_t *cursor = &ma->next_fit[m->good];
    size_t first = *cursor;
    size_t n = bgm_posted_query(ma->dir, m->good, m->price, *cursor, has_room, &rc, found,
                                (size_t)cap, &first);
    if (n > 0)
        *cursor = first + 1;
    bgm_msg_t l = msg(BGM_MT_LIST, ma->p.self, m->from, m->req, m->attempt);
    l.good = m->good;
    l.ncand = (uint16_t)n;
    for (size_t i = 0; i < n; i++) {
        l.cand[i] = found[i].seller;
        l.cand_price[i] = found[i].price;
        if (m->good == BGM_GOOD_CORES_ID) {
            /* A posted bundle rate: the seller's cost rate for the
             * bundle, marked up like every posted price. */
            const ma_seller_t *s = &ma->mr[found[i].seller - ma->p.first_resource];
            l.cand_price[i] =
                (1.0 + ma->cfg.baseline.markup) * (s->price * m->a + s->mem_cost * m->b);
            l.cand_speed[i] = s->speed;
        }
    }
    bgm_emitter_send(&ma->em, &l);
}

/* --------------------------------------------------------------- inputs */

static int is_basic(const bgm_market_agent_t *ma, uint32_t a)
{
    return a >= ma->p.first_basic && a - ma->p.first_basic < ma->p.nbasic;
}

static int is_resource(const bgm_market_agent_t *ma, uint32_t a)
{
    return a >= ma->p.first_resource && a - ma->p.first_resource < ma->p.nresource;
}

bg_status bgm_market_agent_start(bgm_market_agent_t *ma, double now, bgm_outbox_t *out)
{
    if (ma->p.mechanism != BGM_MECH_CENTRAL)
        return BG_OK;
    return bgm_outbox_timer(out, ma->p.self, now + ma->cfg.central.period, BGM_MA_TIMER_CLEAR, 0);
}

bg_status bgm_market_agent_on_message(bgm_market_agent_t *ma, const bgm_msg_t *m, double now,
                                      bgm_outbox_t *out)
{
    bgm_emitter_begin(&ma->em, out);
    switch (m->type) {
    case BGM_MT_BID: {
        if (m->good < 0 || m->good >= BGM_SERVICE_TYPES || m->ncand > BGM_MSG_CANDIDATES)
            return BG_ERR_INVALID;
        if (ma->nbid >= MA_BOOK_MAX)
            return BG_ERR_LIMIT;
        ma_bid_t *r = &ma->bids[ma->nbid++];
        *r = (ma_bid_t){m->req, m->from, m->attempt, m->good, 0, m->price, m->a, m->b,
                        m->origin, m->ncand, {0}};
        memcpy(r->exclude, m->cand, m->ncand * sizeof *m->cand);
        break;
    }
    case BGM_MT_RBID:
        if (ma->nrbid >= MA_BOOK_MAX)
            return BG_ERR_LIMIT;
        ma->rbids[ma->nrbid++] = (ma_rbid_t){m->req, m->from,  m->attempt,      0, m->a, m->b,
                                             m->c,   m->price, m->cand_price[0]};
        break;
    case BGM_MT_ASK: {
        if (!is_basic(ma, m->from) || m->good < 0 || m->good >= BGM_SERVICE_TYPES)
            return BG_ERR_INVALID;
        uint32_t k = m->from - ma->p.first_basic;
        ma_seller_t *s = &ma->mb[k];
        s->agent = m->from;
        s->reservation[m->good] = m->price;
        s->sells[m->good] = 1;
        if (m->a >= 0.0)
            s->free_a = m->a;
        if (k + 1 > ma->nmb)
            ma->nmb = k + 1;
        if (ma->p.mechanism == BGM_MECH_BASELINE &&
            bgm_posted_post(ma->dir, m->from, m->good, m->price))
            bgm_emitter_fail(&ma->em, BG_ERR_LIMIT);
        break;
    }
    case BGM_MT_FREE:
        if (!is_basic(ma, m->from))
            return BG_ERR_INVALID;
        ma->mb[m->from - ma->p.first_basic].free_a += 1.0;
        break;
    case BGM_MT_RASK: {
        if (!is_resource(ma, m->from))
            return BG_ERR_INVALID;
        uint32_t k = m->from - ma->p.first_resource;
        ma_seller_t *s = &ma->mr[k];
        s->agent = m->from;
        s->free_a = m->a;
        s->free_b = m->b;
        s->speed = m->c;
        s->price = m->price;
        s->mem_cost = m->cand_price[0];
        if (k + 1 > ma->nmr)
            ma->nmr = k + 1;
        if (ma->p.mechanism == BGM_MECH_BASELINE &&
            bgm_posted_post(ma->dir, m->from, BGM_GOOD_CORES_ID, m->price))
            bgm_emitter_fail(&ma->em, BG_ERR_LIMIT);
        break;
    }
    case BGM_MT_RFREE: {
        if (!is_resource(ma, m->from))
            return BG_ERR_INVALID;
        ma_seller_t *s = &ma->mr[m->from - ma->p.first_resource];
        s->free_a += m->a;
        s->free_b += m->b;
        break;
    }
    case BGM_MT_AVAIL:
        if (is_basic(ma, m->from)) {
            ma->mb[m->from - ma->p.first_basic].free_a = m->a;
        } else if (is_resource(ma, m->from)) {
            ma->mr[m->from - ma->p.first_resource].free_a = m->a;
            ma->mr[m->from - ma->p.first_resource].free_b = m->b;
        } else {
            return BG_ERR_INVALID;
        }
        break;
    case BGM_MT_QUERY:
        /* A service or a bundle of cores and memory: the goods it lists. */
        if (m->ncand > BGM_MSG_CANDIDATES || m->good < 0 || m->good > BGM_GOOD_CORES_ID)
            return BG_ERR_INVALID;
        on_query(ma, m);
        break;
    default:
        /* Nothing else is addressed to the market agent. */
        break;
    }
    (void)now;
    return ma->em.failure;
}

bg_status bgm_market_agent_on_timer(bgm_market_agent_t *ma, int kind, uint64_t arg, double now,
                                    bgm_outbox_t *out)
{
    (void)arg;
    if (kind != BGM_MA_TIMER_CLEAR)
        return BG_ERR_INVALID;
    bgm_emitter_begin(&ma->em, out);
    ma->nclearings = ma->nmatches = 0;
    clear_services(ma, now);
    if (ma->cfg.central.resource_market == BGM_RM_CALL)
        clear_calls(ma, now);
    else
        clear_exchange(ma, now);
    if (now + ma->cfg.central.period <= ma->p.horizon) {
        bg_status st =
            bgm_outbox_timer(out, ma->p.self, now + ma->cfg.central.period, BGM_MA_TIMER_CLEAR, 0);
        if (st)
            bgm_emitter_fail(&ma->em, st);
    }
    return ma->em.failure;
}

void bgm_market_agent_forget_seller(bgm_market_agent_t *ma, uint32_t seller)
{
    ma_seller_t *s = is_basic(ma, seller)      ? &ma->mb[seller - ma->p.first_basic]
                     : is_resource(ma, seller) ? &ma->mr[seller - ma->p.first_resource]
                                               : NULL;
    if (!s)
        return;
    memset(s, 0, sizeof *s);
    s->agent = seller;
    bgm_posted_withdraw(ma->dir, seller);
}

void bgm_market_agent_forget_bids(bgm_market_agent_t *ma, uint32_t buyer)
{
    size_t keep = 0;
    for (size_t i = 0; i < ma->nbid; i++)
        if (ma->bids[i].buyer != buyer)
            ma->bids[keep++] = ma->bids[i];
    ma->nbid = keep;
    keep = 0;
    for (size_t i = 0; i < ma->nrbid; i++)
        if (ma->rbids[i].buyer != buyer)
            ma->rbids[keep++] = ma->rbids[i];
    ma->nrbid = keep;
}
