#include "bgm_optimum.h"

#include <glpk.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* A capacity row binds only if its coefficients can sum above the
 * capacity; rows that cannot are left out (their dual is 0). */
#define BGM_OPT_SLACK 1e-9
#define BGM_OPT_MAX_INTERVALS 4096
/* Pairs of each kind a request may bring in per pricing round. */
#define BGM_OPT_ENTER 2
/* A column enters when its reduced cost exceeds this (objective units:
 * money; a request is worth units to tens). */
#define BGM_OPT_PRICE_TOL 1e-7
/* Pricing rounds before giving up on convergence: the bound stays valid,
 * only less tight. */
#define BGM_OPT_MAX_ROUNDS 200
/* Sets T of service types for the pooled slot rows: 1 .. 2^types - 1. */
#define BGM_OPT_SUBSETS ((1 << BGM_SERVICE_TYPES) - 1)

/* The kinds of variables: z(i,r) (or, split, the cores part c(i,r)),
 * m(i,r) the memory part (split only), y(i,b). */
enum { K_RES = 0, K_MEM = 1, K_BASIC = 2, K_KINDS = 3 };

typedef struct interval {
    double lo, hi;
} interval_t;

/* A kept request: one with at least one resource pair of positive
 * surplus. */
typedef struct kept {
    size_t src;             /* index into the problem's requests */
    double dmin, dmax;      /* shortest and longest run over its resource pairs */
    double mem_floor;       /* split: least its memory can cost */
    uint32_t iv_first, niv; /* its intervals (those its deliveries can touch) */
} kept_t;

typedef struct model {
    const bgm_opt_problem_t *p;
    double kmin[BGM_SERVICE_TYPES];
    size_t sellers[BGM_SERVICE_TYPES]; /* basic agents selling each type */
    size_t mem_sellers;                /* resource agents with memory */
    kept_t *kept;
    size_t nkept;
    interval_t *ivs;
    int niv;
    uint32_t *req_iv; /* concatenated interval lists of the kept requests */
    int *rowid;       /* capacity row key -> GLPK row (0: cannot bind) */
    double *rowcap;   /* capacity row key -> right-hand side */
    size_t nkeys;
    double *dual;            /* GLPK row -> dual (1-based) */
    unsigned char *in_model; /* pair -> already a column */
    size_t *ekey;            /* scratch: one pair's capacity entries */
    double *eval;
    int *ind; /* scratch: one column's rows for GLPK (1-based) */
    double *val;
    size_t ncol; /* columns in the simplex */
    glp_prob *lp;
} model_t;

double bgm_optimum_overlap(double release, double latest, double d, double lo, double hi)
{
    /* overlap([s, s+d], [lo, hi]) rises, stays flat, then falls as s
     * grows: its minimum over the window is at one of the window's ends. */
    double a = fmin(release + d, hi) - fmax(release, lo);
    double b = fmin(latest + d, hi) - fmax(latest, lo);
    double m = fmin(a, b);
    return m > 0.0 ? m : 0.0;
}

static const bgm_opt_service_t *service_of(const model_t *m, const bgm_opt_request_t *q)
{
    return &m->p->services[q->type];
}

static double duration(const model_t *m, const bgm_opt_request_t *q, size_t r)
{
    const bgm_opt_service_t *s = service_of(m, q);
    return s->flops_per_unit * q->work / (m->p->resources[r].speed * s->cores);
}

static bg_status check_problem(const bgm_opt_problem_t *p)
{
    for (int t = 0; t < BGM_SERVICE_TYPES; t++) {
        const bgm_opt_service_t *s = &p->services[t];
        if (!(s->flops_per_unit > 0.0) || !(s->cores > 0.0) || !(s->memory >= 0.0))
            return BG_ERR_INVALID;
    }
    for (size_t i = 0; i < p->nrequests; i++) {
        const bgm_opt_request_t *q = &p->requests[i];
        if (q->type < 0 || q->type >= BGM_SERVICE_TYPES || !(q->work > 0.0) ||
            !(q->latest >= q->release) || !isfinite(q->value) || !isfinite(q->latest))
            return BG_ERR_INVALID;
    }
    for (size_t r = 0; r < p->nresources; r++) {
        const bgm_opt_resource_t *ra = &p->resources[r];
        if (!(ra->speed > 0.0) || !(ra->cores >= 0.0) || !(ra->memory >= 0.0) ||
            !(ra->core_cost >= 0.0) || !(ra->memory_cost >= 0.0))
            return BG_ERR_INVALID;
    }
    for (size_t b = 0; b < p->nbasics; b++)
        if (!(p->basics[b].slots >= 0.0))
            return BG_ERR_INVALID;
    if (p->nrequests > UINT32_MAX || p->nresources > UINT32_MAX || p->nbasics > UINT32_MAX)
        return BG_ERR_LIMIT;
    return BG_OK;
}

static int basic_sells(const bgm_opt_basic_t *b, int type)
{
    return b->sells[type] && b->slots > 0.0;
}

/* Whether request q needs memory parts of its own (split bundles). */
static int needs_memory(const model_t *m, const bgm_opt_request_t *q)
{
    return m->p->split && service_of(m, q)->memory > 0.0;
}

/* Split bundles: the least q's memory can cost, held for q's fastest run
 * anywhere at the cheapest memory rate (0 when it needs none). */
static double mem_floor(const model_t *m, const bgm_opt_request_t *q)
{
    if (!needs_memory(m, q))
        return 0.0;
    double fastest = INFINITY, rate = INFINITY;
    for (size_t r = 0; r < m->p->nresources; r++) {
        const bgm_opt_resource_t *ra = &m->p->resources[r];
        if (ra->cores > 0.0)
            fastest = fmin(fastest, duration(m, q, r));
        if (ra->memory > 0.0)
            rate = fmin(rate, ra->memory_cost);
    }
    return rate * service_of(m, q)->memory * fastest;
}

/* Objective coefficient of resource pair (q, r): the valuation less the
 * resource cost of the run on r (of its cores alone when split). */
static double res_obj(const model_t *m, const bgm_opt_request_t *q, size_t r)
{
    const bgm_opt_resource_t *ra = &m->p->resources[r];
    const bgm_opt_service_t *s = service_of(m, q);
    double rate = ra->core_cost * s->cores + (m->p->split ? 0.0 : ra->memory_cost * s->memory);
    return q->value * q->work - rate * duration(m, q, r);
}

/* Best-case surplus of resource pair (q, r), with the cheapest basic agent
 * (and the cheapest memory when split); pairs with surplus <= 0 are not
 * variables of P. A whole bundle must fit on r. */
static double pair_surplus(const model_t *m, const bgm_opt_request_t *q, size_t r, double floor_mem)
{
    const bgm_opt_resource_t *ra = &m->p->resources[r];
    const bgm_opt_service_t *s = service_of(m, q);
    if (!isfinite(m->kmin[q->type]) || !(ra->cores > 0.0))
        return 0.0;
    if (!m->p->split && (ra->cores < s->cores || ra->memory < s->memory))
        return 0.0;
    if (needs_memory(m, q) && m->mem_sellers == 0)
        return 0.0;
    return res_obj(m, q, r) - m->kmin[q->type] * q->work - floor_mem;
}

/* The interval family: the whole span [t0, t1], and its tilings by
 * L0·2^k. (Tilings shifted by half a length as well double the rows and
 * the time for a bound 1e-4 tighter on shock.json.) Returns the count
 * (<= BGM_OPT_MAX_INTERVALS). */
static int build_intervals(double t0, double t1, double l0, interval_t *out)
{
    int n = 0;
    out[n++] = (interval_t){t0, t1};
    if (!(l0 > 0.0))
        return n;
    for (double len = l0; len < t1 - t0; len *= 2.0)
        for (double lo = t0; lo < t1; lo += len) {
            if (n == BGM_OPT_MAX_INTERVALS)
                return n;
            out[n++] = (interval_t){lo, lo + len};
        }
    return n;
}

/*
 * Capacity rows are known by keys: (resource, interval, dim) with dim 0
 * cores and 1 memory; (basic agent, interval); and (T, interval) for each
 * non-empty set T of service types, the slots of all the basic agents
 * selling a type in T pooled. A pooled row charges each delivery its real
 * duration on its resource (a per-agent row can only charge the shortest,
 * not knowing the resource), so it is what makes slots bind: at any time
 * the deliveries of types in T running number at most those slots.
 */
static size_t key_resource(const model_t *m, size_t r, uint32_t iv, int dim)
{
    return (r * (size_t)m->niv + iv) * 2 + (size_t)dim;
}

static size_t key_basic(const model_t *m, size_t b, uint32_t iv)
{
    return m->p->nresources * (size_t)m->niv * 2 + b * (size_t)m->niv + iv;
}

static size_t key_pool(const model_t *m, int set, uint32_t iv)
{
    return (m->p->nresources * 2 + m->p->nbasics + (size_t)(set - 1)) * (size_t)m->niv + iv;
}

/* Writes the capacity-row entries (keys, coefficients) of pair (kept
 * request k, agent) of the given kind to m->ekey and m->eval and returns
 * their count. A delivery's coefficient is its least overlap with the
 * interval, times its cores or memory on a resource row. A run on resource
 * r lasts d(i,r); a memory part or a basic slot is held at least the
 * shortest run, dmin. */
static size_t entries(const model_t *m, size_t k, size_t agent, int kind)
{
    const kept_t *kp = &m->kept[k];
    const bgm_opt_request_t *q = &m->p->requests[kp->src];
    const bgm_opt_service_t *s = service_of(m, q);
    double d = kind == K_RES ? duration(m, q, agent) : kp->dmin;
    size_t n = 0;
    for (uint32_t j = 0; j < kp->niv; j++) {
        uint32_t iv = m->req_iv[kp->iv_first + j];
        double ov = bgm_optimum_overlap(q->release, q->latest, d, m->ivs[iv].lo, m->ivs[iv].hi);
        if (!(ov > 0.0))
            continue;
        if (kind == K_BASIC) {
            m->ekey[n] = key_basic(m, agent, iv);
            m->eval[n++] = ov;
            continue;
        }
        if (kind == K_RES) {
            m->ekey[n] = key_resource(m, agent, iv, 0);
            m->eval[n++] = s->cores * ov;
            for (int set = 1; set <= BGM_OPT_SUBSETS; set++)
                if (set & (1 << q->type)) {
                    m->ekey[n] = key_pool(m, set, iv);
                    m->eval[n++] = ov;
                }
        }
        if (s->memory > 0.0 && (kind == K_MEM || !m->p->split)) {
            m->ekey[n] = key_resource(m, agent, iv, 1);
            m->eval[n++] = s->memory * ov;
        }
    }
    return n;
}

/* Right-hand side of a capacity row. */
static double key_capacity(const model_t *m, size_t key)
{
    const bgm_opt_problem_t *p = m->p;
    size_t niv = (size_t)m->niv, zrows = p->nresources * niv * 2, yrows = p->nbasics * niv;
    if (key < zrows) {
        const bgm_opt_resource_t *ra = &p->resources[key / (niv * 2)];
        const interval_t *iv = &m->ivs[(key / 2) % niv];
        return (key % 2 == 0 ? ra->cores : ra->memory) * (iv->hi - iv->lo);
    }
    if (key < zrows + yrows) {
        const interval_t *iv = &m->ivs[(key - zrows) % niv];
        return p->basics[(key - zrows) / niv].slots * (iv->hi - iv->lo);
    }
    int set = (int)((key - zrows - yrows) / niv) + 1;
    const interval_t *iv = &m->ivs[(key - zrows - yrows) % niv];
    double slots = 0.0;
    for (size_t b = 0; b < p->nbasics; b++)
        for (int t = 0; t < BGM_SERVICE_TYPES; t++)
            if ((set & (1 << t)) && basic_sells(&p->basics[b], t)) {
                slots += p->basics[b].slots;
                break;
            }
    return slots * (iv->hi - iv->lo);
}

/* Whether (k, agent) is a variable of P of the given kind. */
static int is_pair(const model_t *m, size_t k, size_t agent, int kind)
{
    const kept_t *kp = &m->kept[k];
    const bgm_opt_request_t *q = &m->p->requests[kp->src];
    if (kind == K_RES)
        return pair_surplus(m, q, agent, kp->mem_floor) > 0.0;
    if (kind == K_MEM)
        return needs_memory(m, q) && m->p->resources[agent].memory > 0.0;
    return basic_sells(&m->p->basics[agent], q->type);
}

static size_t agents_of(const model_t *m, int kind)
{
    return kind == K_BASIC ? m->p->nbasics : m->p->nresources;
}

static double obj(const model_t *m, size_t k, size_t agent, int kind)
{
    const kept_t *kp = &m->kept[k];
    const bgm_opt_request_t *q = &m->p->requests[kp->src];
    if (kind == K_RES)
        return res_obj(m, q, agent);
    if (kind == K_MEM)
        return -m->p->resources[agent].memory_cost * service_of(m, q)->memory * kp->dmin;
    return -m->p->basics[agent].cost[q->type] * q->work;
}

/* Request rows: 1..n Σ_r z <= 1; n+1..2n Σ_b y − Σ_r z = 0; and when
 * split, 2n+1..3n Σ_r m − Σ_r c = 0. Writes a column's request entries
 * and returns their count. */
static int request_entries(const model_t *m, size_t k, int kind, int *ind, double *val)
{
    int n = 0, one = (int)k + 1, link = (int)(m->nkept + k) + 1, mem = (int)(2 * m->nkept + k) + 1;
    const bgm_opt_request_t *q = &m->p->requests[m->kept[k].src];
    if (kind == K_RES) {
        ind[n] = one;
        val[n++] = 1.0;
        ind[n] = link;
        val[n++] = -1.0;
        if (needs_memory(m, q)) {
            ind[n] = mem;
            val[n++] = -1.0;
        }
    } else {
        ind[n] = kind == K_BASIC ? link : mem;
        val[n++] = 1.0;
    }
    return n;
}

/* Pass over the requests: which are kept, their durations, the span. */
static void keep_requests(model_t *m, double *t0, double *t1, double *l0)
{
    const bgm_opt_problem_t *p = m->p;
    double window = 0.0, dshort = INFINITY;
    *t0 = INFINITY;
    *t1 = -INFINITY;
    for (size_t i = 0; i < p->nrequests; i++) {
        const bgm_opt_request_t *q = &p->requests[i];
        kept_t k = {i, INFINITY, 0.0, mem_floor(m, q), 0, 0};
        for (size_t r = 0; r < p->nresources; r++) {
            if (!(pair_surplus(m, q, r, k.mem_floor) > 0.0))
                continue;
            double d = duration(m, q, r);
            k.dmin = fmin(k.dmin, d);
            k.dmax = fmax(k.dmax, d);
        }
        if (!isfinite(k.dmin))
            continue;
        m->kept[m->nkept++] = k;
        *t0 = fmin(*t0, q->release);
        *t1 = fmax(*t1, q->latest + k.dmax);
        window = fmax(window, q->latest - q->release);
        dshort = fmin(dshort, k.dmin);
    }
    *l0 = window > 0.0 ? window : dshort;
}

/* Each kept request's list of intervals its deliveries can touch, and the
 * scratch space for the longest list. */
static bg_status list_intervals(model_t *m)
{
    size_t cap = 0, n = 0;
    uint32_t most = 0;
    for (size_t k = 0; k < m->nkept; k++) {
        kept_t *kp = &m->kept[k];
        const bgm_opt_request_t *q = &m->p->requests[kp->src];
        kp->iv_first = (uint32_t)n;
        for (int iv = 0; iv < m->niv; iv++) {
            if (m->ivs[iv].hi <= q->release || m->ivs[iv].lo >= q->latest + kp->dmax)
                continue;
            if (n == cap) {
                cap = cap ? 2 * cap : 1024;
                uint32_t *x = realloc(m->req_iv, cap * sizeof *x);
                if (!x)
                    return BG_ERR_NOMEM;
                m->req_iv = x;
            }
            m->req_iv[n++] = (uint32_t)iv;
        }
        kp->niv = (uint32_t)(n - kp->iv_first);
        if (kp->niv > most)
            most = kp->niv;
    }
    /* A pair has per interval at most a cores and a memory row and a
     * pooled row per set holding its type; a column adds three request
     * rows at most. */
    size_t per = 2 + (1u << (BGM_SERVICE_TYPES - 1)), most_entries = per * (size_t)most;
    m->ekey = malloc((most_entries + 1) * sizeof *m->ekey);
    m->eval = malloc((most_entries + 1) * sizeof *m->eval);
    m->ind = malloc((most_entries + 4) * sizeof *m->ind);
    m->val = malloc((most_entries + 4) * sizeof *m->val);
    return m->ekey && m->eval && m->ind && m->val ? BG_OK : BG_ERR_NOMEM;
}

/* Which capacity rows can bind: those whose coefficients over every pair
 * of P sum above the capacity. Adds them, and the request rows, to the
 * simplex. */
static bg_status capacity_rows(model_t *m, size_t *nrows)
{
    double *sum = calloc(m->nkeys, sizeof *sum);
    if (!sum)
        return BG_ERR_NOMEM;
    for (size_t k = 0; k < m->nkept; k++)
        for (int kind = 0; kind < K_KINDS; kind++)
            for (size_t a = 0; a < agents_of(m, kind); a++) {
                if (!is_pair(m, k, a, kind))
                    continue;
                size_t n = entries(m, k, a, kind);
                for (size_t e = 0; e < n; e++)
                    sum[m->ekey[e]] += m->eval[e];
            }
    int next = (int)((m->p->split ? 3 : 2) * m->nkept);
    *nrows = 0;
    for (size_t key = 0; key < m->nkeys; key++) {
        m->rowcap[key] = key_capacity(m, key);
        m->rowid[key] = 0;
        if (sum[key] > m->rowcap[key] * (1.0 + BGM_OPT_SLACK)) {
            m->rowid[key] = ++next;
            (*nrows)++;
        }
    }
    free(sum);
    glp_add_rows(m->lp, next);
    for (size_t k = 0; k < m->nkept; k++) {
        glp_set_row_bnds(m->lp, (int)k + 1, GLP_UP, 0.0, 1.0);
        glp_set_row_bnds(m->lp, (int)(m->nkept + k) + 1, GLP_FX, 0.0, 0.0);
        if (m->p->split)
            glp_set_row_bnds(m->lp, (int)(2 * m->nkept + k) + 1, GLP_FX, 0.0, 0.0);
    }
    for (size_t key = 0; key < m->nkeys; key++)
        if (m->rowid[key])
            glp_set_row_bnds(m->lp, m->rowid[key], GLP_UP, 0.0, m->rowcap[key]);
    return BG_OK;
}

/* Index of a pair in in_model: resource pairs, memory pairs, basic pairs. */
static size_t pair_index(const model_t *m, size_t k, size_t agent, int kind)
{
    size_t nr = m->p->nresources;
    if (kind == K_RES)
        return k * nr + agent;
    if (kind == K_MEM)
        return (m->nkept + k) * nr + agent;
    return 2 * m->nkept * nr + k * m->p->nbasics + agent;
}

/* Adds pair (k, agent) as a column of the simplex. */
static void add_column(model_t *m, size_t k, size_t agent, int kind)
{
    int n = request_entries(m, k, kind, m->ind + 1, m->val + 1);
    size_t ne = entries(m, k, agent, kind);
    for (size_t e = 0; e < ne; e++)
        if (m->rowid[m->ekey[e]]) {
            n++;
            m->ind[n] = m->rowid[m->ekey[e]];
            m->val[n] = m->eval[e];
        }
    int col = glp_add_cols(m->lp, 1);
    glp_set_col_bnds(m->lp, col, GLP_DB, 0.0, 1.0);
    glp_set_obj_coef(m->lp, col, obj(m, k, agent, kind));
    glp_set_mat_col(m->lp, col, n, m->ind, m->val);
    m->ncol++;
    m->in_model[pair_index(m, k, agent, kind)] = 1;
}

/* Reduced cost c_j − π·A_j of pair (k, agent) under the current duals. */
static double reduced_cost(const model_t *m, size_t k, size_t agent, int kind)
{
    int ind[3];
    double val[3];
    double d = obj(m, k, agent, kind);
    int n = request_entries(m, k, kind, ind, val);
    for (int j = 0; j < n; j++)
        d -= m->dual[ind[j]] * val[j];
    size_t ne = entries(m, k, agent, kind);
    for (size_t e = 0; e < ne; e++) {
        int row = m->rowid[m->ekey[e]];
        if (row)
            d -= m->dual[row] * m->eval[e];
    }
    return d;
}

typedef struct ranked {
    double surplus;
    size_t k;
} ranked_t;

static int cmp_ranked(const void *pa, const void *pb)
{
    const ranked_t *a = pa, *b = pb;
    if (a->surplus != b->surplus)
        return a->surplus > b->surplus ? -1 : 1;
    return (a->k > b->k) - (a->k < b->k);
}

/* Adds pair (k, agent) unless it is a column already or none was found. */
static void seed_pair(model_t *m, size_t k, size_t agent, int kind)
{
    if (agent != SIZE_MAX && !m->in_model[pair_index(m, k, agent, kind)])
        add_column(m, k, agent, kind);
}

/* The agent of the given kind with the best objective for request k, and
 * the best of those that fit[] allows (SIZE_MAX: none). */
static void best_agents(const model_t *m, size_t k, int kind, const int *fit, size_t *top,
                        size_t *best_fit)
{
    *top = *best_fit = SIZE_MAX;
    for (size_t a = 0; a < agents_of(m, kind); a++) {
        if (!is_pair(m, k, a, kind))
            continue;
        double v = obj(m, k, a, kind);
        if (*top == SIZE_MAX || v > obj(m, k, *top, kind))
            *top = a;
        if (fit[a] && (*best_fit == SIZE_MAX || v > obj(m, k, *best_fit, kind)))
            *best_fit = a;
    }
}

/* Seeds the simplex with a greedy schedule: requests in decreasing order
 * of their best surplus each take the best resource and the cheapest basic
 * agent with energy left over the whole span (core-, GiB- and
 * slot-seconds), and bring their single best pairs too. A good first
 * basis saves pricing rounds; the bound does not depend on it. */
static bg_status seed_columns(model_t *m, double span)
{
    const bgm_opt_problem_t *p = m->p;
    size_t nr = p->nresources, nb = p->nbasics, most = nr > nb ? nr : nb;
    bg_status st = BG_OK;
    ranked_t *order = malloc(m->nkept * sizeof *order);
    double *left = malloc((2 * nr + nb + 1) * sizeof *left);
    int *fit = malloc((most + 1) * sizeof *fit);
    if (!order || !left || !fit) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    double *core_left = left, *mem_left = left + nr, *slot_left = left + 2 * nr;
    for (size_t r = 0; r < nr; r++) {
        core_left[r] = p->resources[r].cores * span;
        mem_left[r] = p->resources[r].memory * span;
    }
    for (size_t b = 0; b < nb; b++)
        slot_left[b] = p->basics[b].slots * span;
    for (size_t k = 0; k < m->nkept; k++) {
        const bgm_opt_request_t *q = &p->requests[m->kept[k].src];
        double best = 0.0;
        for (size_t r = 0; r < nr; r++)
            best = fmax(best, pair_surplus(m, q, r, m->kept[k].mem_floor));
        order[k] = (ranked_t){best, k};
    }
    qsort(order, m->nkept, sizeof *order, cmp_ranked);
    for (size_t j = 0; j < m->nkept; j++) {
        size_t k = order[j].k, top_r, fit_r, top_b, fit_b, top_m = SIZE_MAX, fit_m = SIZE_MAX;
        const bgm_opt_request_t *q = &p->requests[m->kept[k].src];
        const bgm_opt_service_t *sv = service_of(m, q);
        for (size_t r = 0; r < nr; r++) {
            double d = duration(m, q, r);
            fit[r] = core_left[r] >= sv->cores * d && mem_left[r] >= sv->memory * d;
        }
        best_agents(m, k, K_RES, fit, &top_r, &fit_r);
        double d = fit_r != SIZE_MAX ? duration(m, q, fit_r) : 0.0;
        for (size_t b = 0; b < nb; b++)
            fit[b] = slot_left[b] >= d;
        best_agents(m, k, K_BASIC, fit, &top_b, &fit_b);
        if (needs_memory(m, q)) {
            for (size_t r = 0; r < nr; r++)
                fit[r] = r == fit_r;
            best_agents(m, k, K_MEM, fit, &top_m, &fit_m);
        }
        if (fit_r != SIZE_MAX && fit_b != SIZE_MAX) {
            core_left[fit_r] -= sv->cores * d;
            mem_left[fit_r] -= sv->memory * d;
            slot_left[fit_b] -= d;
            seed_pair(m, k, fit_r, K_RES);
            seed_pair(m, k, fit_b, K_BASIC);
            seed_pair(m, k, fit_m, K_MEM);
        }
        seed_pair(m, k, top_r, K_RES);
        seed_pair(m, k, top_b, K_BASIC);
        seed_pair(m, k, top_m, K_MEM);
    }
out:
    free(order);
    free(left);
    free(fit);
    return st;
}

/* A request's most improving pairs of one kind in a round, best first. */
typedef struct pick {
    size_t agent[BGM_OPT_ENTER];
    double price[BGM_OPT_ENTER];
    int n;
} pick_t;

static void pick_offer(pick_t *pk, size_t agent, double d)
{
    int at = pk->n < BGM_OPT_ENTER ? pk->n++ : BGM_OPT_ENTER;
    if (at == BGM_OPT_ENTER) {
        if (d <= pk->price[BGM_OPT_ENTER - 1])
            return;
        at = BGM_OPT_ENTER - 1;
    }
    while (at > 0 && pk->price[at - 1] < d) {
        pk->price[at] = pk->price[at - 1];
        pk->agent[at] = pk->agent[at - 1];
        at--;
    }
    pk->price[at] = d;
    pk->agent[at] = agent;
}

/* One pricing round over every pair of P: adds each request's most
 * improving pairs, returns how many, and sets *bound to the Lagrangian
 * bound of the current duals. */
static size_t price(model_t *m, double *bound)
{
    int nrows = glp_get_num_rows(m->lp);
    double b = 0.0;
    for (int row = 1; row <= nrows; row++) {
        double y = glp_get_row_dual(m->lp, row);
        int type = glp_get_row_type(m->lp, row);
        /* A multiplier of the wrong sign on an inequality would void the
         * bound; the simplex can leave -1e-15 there, so clamp it. */
        m->dual[row] = type == GLP_UP && y < 0.0 ? 0.0 : y;
        b += m->dual[row] * glp_get_row_ub(m->lp, row);
    }
    size_t added = 0;
    for (size_t k = 0; k < m->nkept; k++) {
        for (int kind = 0; kind < K_KINDS; kind++) {
            pick_t pk = {{0}, {0}, 0};
            for (size_t a = 0; a < agents_of(m, kind); a++) {
                if (!is_pair(m, k, a, kind))
                    continue;
                double d = reduced_cost(m, k, a, kind);
                if (d > 0.0)
                    b += d;
                if (d > BGM_OPT_PRICE_TOL && !m->in_model[pair_index(m, k, a, kind)])
                    pick_offer(&pk, a, d);
            }
            for (int j = 0; j < pk.n; j++)
                add_column(m, k, pk.agent[j], kind);
            added += (size_t)pk.n;
        }
    }
    *bound = b;
    return added;
}

static void model_free(model_t *m)
{
    if (m->lp)
        glp_delete_prob(m->lp);
    free(m->kept);
    free(m->ivs);
    free(m->req_iv);
    free(m->rowid);
    free(m->rowcap);
    free(m->dual);
    free(m->in_model);
    free(m->ekey);
    free(m->eval);
    free(m->ind);
    free(m->val);
}

/* The model's summaries of the agents: cheapest basic cost and sellers
 * per type, resource agents with memory. */
static void model_init(model_t *m, const bgm_opt_problem_t *p)
{
    memset(m, 0, sizeof *m);
    m->p = p;
    for (int t = 0; t < BGM_SERVICE_TYPES; t++)
        m->kmin[t] = INFINITY;
    for (size_t b = 0; b < p->nbasics; b++)
        for (int t = 0; t < BGM_SERVICE_TYPES; t++)
            if (basic_sells(&p->basics[b], t)) {
                m->sellers[t]++;
                m->kmin[t] = fmin(m->kmin[t], p->basics[b].cost[t]);
            }
    for (size_t r = 0; r < p->nresources; r++)
        m->mem_sellers += p->resources[r].memory > 0.0;
}

static size_t pairs_of(const model_t *m, const bgm_opt_request_t *q)
{
    double floor_mem = mem_floor(m, q);
    size_t z = 0;
    for (size_t r = 0; r < m->p->nresources; r++)
        z += pair_surplus(m, q, r, floor_mem) > 0.0;
    if (z == 0)
        return 0;
    return z + m->sellers[q->type] + (needs_memory(m, q) ? m->mem_sellers : 0);
}

size_t bgm_optimum_request_pairs(const bgm_opt_problem_t *p, const bgm_opt_request_t *q)
{
    model_t m;
    model_init(&m, p);
    return pairs_of(&m, q);
}

bg_status bgm_optimum_solve(const bgm_opt_problem_t *p, size_t pair_limit, bgm_opt_result_t *res)
{
    memset(res, 0, sizeof *res);
    res->status = BGM_OPT_SOLVED;
    res->value = res->lp = NAN;
    bg_status st = check_problem(p);
    if (st)
        return st;
    model_t m;
    model_init(&m, p);

    /* Count P's pairs before allocating anything, so an oversized problem
     * costs no memory. */
    size_t nkept = 0;
    for (size_t i = 0; i < p->nrequests; i++) {
        size_t n = pairs_of(&m, &p->requests[i]);
        res->pairs += n;
        nkept += n > 0;
    }
    if (res->pairs > pair_limit) {
        res->status = BGM_OPT_TOO_LARGE;
        return BG_OK;
    }
    if (nkept == 0) {
        res->value = res->lp = 0.0;
        return BG_OK;
    }

    double t0, t1, l0;
    m.kept = malloc(nkept * sizeof *m.kept);
    m.ivs = malloc(BGM_OPT_MAX_INTERVALS * sizeof *m.ivs);
    if (!m.kept || !m.ivs) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    keep_requests(&m, &t0, &t1, &l0);
    m.niv = build_intervals(t0, t1, l0, m.ivs);
    res->intervals = m.niv;
    m.nkeys = (p->nresources * 2 + p->nbasics + BGM_OPT_SUBSETS) * (size_t)m.niv;
    m.rowid = malloc(m.nkeys * sizeof *m.rowid);
    m.rowcap = malloc(m.nkeys * sizeof *m.rowcap);
    m.in_model = calloc(m.nkept * (2 * p->nresources + p->nbasics), 1);
    if (!m.rowid || !m.rowcap || !m.in_model || (st = list_intervals(&m))) {
        st = st ? st : BG_ERR_NOMEM;
        goto out;
    }
    glp_term_out(GLP_OFF);
    m.lp = glp_create_prob();
    glp_set_obj_dir(m.lp, GLP_MAX);
    if ((st = capacity_rows(&m, &res->rows)))
        goto out;
    m.dual = calloc((size_t)glp_get_num_rows(m.lp) + 1, sizeof *m.dual);
    if (!m.dual || (st = seed_columns(&m, t1 - t0))) {
        st = st ? st : BG_ERR_NOMEM;
        goto out;
    }
    glp_smcp sm;
    glp_init_smcp(&sm);
    sm.msg_lev = GLP_MSG_OFF;
    double bound = INFINITY;
    for (int round = 1;; round++) {
        res->rounds = round;
        if (glp_simplex(m.lp, &sm) != 0 || glp_get_status(m.lp) != GLP_OPT) {
            res->status = BGM_OPT_FAILED;
            goto out;
        }
        res->lp = glp_get_obj_val(m.lp);
        double b = INFINITY;
        size_t added = price(&m, &b);
        bound = fmin(bound, b);
        if (added == 0 || round == BGM_OPT_MAX_ROUNDS)
            break;
    }
    res->columns = m.ncol;
    res->value = bound;
out:
    model_free(&m);
    return st;
}
