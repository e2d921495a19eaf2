#include "bgm_combex.h"

#include <glpk.h>
#include <stdlib.h>
#include <string.h>

/* Branch-and-bound budget for GLPK, in subproblems selected. A
 * wall-clock limit would make results depend on the machine; a node count
 * does not. Beyond it the exact solver gives up and the caller falls back
 * (the greedy for clearing; null for the offline optimum). */
#define BGM_COMBEX_DEFAULT_NODE_BUDGET 2000
#define BGM_COMBEX_EPS 1e-9

struct bgm_combex {
    double mip_gap;
    long node_budget;
    int nbid, nseller, max_bids, max_sellers;
    size_t npair, max_pairs;
    double (*cap)[BGM_COMBEX_DIMS];
    bgm_combex_pair_t *pairs;
};

bgm_combex_t *bgm_combex_new(int max_bids, int max_sellers, size_t max_pairs)
{
    bgm_combex_t *cx = calloc(1, sizeof *cx);
    if (!cx)
        return NULL;
    cx->max_bids = max_bids;
    cx->max_sellers = max_sellers;
    cx->max_pairs = max_pairs;
    cx->node_budget = BGM_COMBEX_DEFAULT_NODE_BUDGET;
    cx->cap = calloc((size_t)(max_sellers > 0 ? max_sellers : 1), sizeof *cx->cap);
    cx->pairs = calloc(max_pairs ? max_pairs : 1, sizeof *cx->pairs);
    if (!cx->cap || !cx->pairs)
        bgm_combex_destroy(&cx);
    return cx;
}

void bgm_combex_destroy(bgm_combex_t **cx)
{
    if (!cx || !*cx)
        return;
    free((*cx)->cap);
    free((*cx)->pairs);
    free(*cx);
    *cx = NULL;
}

void bgm_combex_reset(bgm_combex_t *cx)
{
    cx->nbid = cx->nseller = 0;
    cx->npair = 0;
}

int bgm_combex_add_bid(bgm_combex_t *cx)
{
    return cx->nbid < cx->max_bids ? cx->nbid++ : -1;
}

int bgm_combex_add_seller(bgm_combex_t *cx, const double cap[BGM_COMBEX_DIMS])
{
    if (cx->nseller >= cx->max_sellers)
        return -1;
    memcpy(cx->cap[cx->nseller], cap, sizeof cx->cap[0]);
    return cx->nseller++;
}

bg_status bgm_combex_add_pair(bgm_combex_t *cx, const bgm_combex_pair_t *p)
{
    if (p->bid < 0 || p->bid >= cx->nbid || p->seller < 0 || p->seller >= cx->nseller ||
        !(p->surplus > 0.0))
        return BG_ERR_INVALID;
    if (cx->npair >= cx->max_pairs)
        return BG_ERR_LIMIT;
    cx->pairs[cx->npair++] = *p;
    return BG_OK;
}

size_t bgm_combex_pair_count(const bgm_combex_t *cx) { return cx->npair; }
const bgm_combex_pair_t *bgm_combex_pairs(const bgm_combex_t *cx) { return cx->pairs; }

/* qsort_r is not C11; sort an index array with the surplus copied in. */
typedef struct ranked {
    double surplus;
    size_t index;
} ranked_t;

static int cmp_ranked(const void *pa, const void *pb)
{
    const ranked_t *a = pa, *b = pb;
    if (a->surplus != b->surplus)
        return a->surplus > b->surplus ? -1 : 1;
    return (a->index > b->index) - (a->index < b->index);
}

static bg_status solve_greedy(bgm_combex_t *cx, long budget, int *assign, bgm_combex_result_t *r)
{
    bg_status st = BG_OK;
    ranked_t *rk = malloc((cx->npair ? cx->npair : 1) * sizeof *rk);
    double (*left)[BGM_COMBEX_DIMS] = malloc((size_t)(cx->nseller ? cx->nseller : 1) * sizeof *left);
    if (!rk || !left) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    for (size_t i = 0; i < cx->npair; i++)
        rk[i] = (ranked_t){cx->pairs[i].surplus, i};
    qsort(rk, cx->npair, sizeof *rk, cmp_ranked);
    memcpy(left, cx->cap, (size_t)cx->nseller * sizeof *left);
    for (int b = 0; b < cx->nbid; b++)
        assign[b] = -1;
    r->method = BGM_COMBEX_GREEDY;
    r->optimal = 0;
    r->objective = 0.0;
    r->work = 0;
    for (size_t i = 0; i < cx->npair; i++) {
        if (budget > 0 && r->work >= budget)
            break;
        r->work++;
        const bgm_combex_pair_t *p = &cx->pairs[rk[i].index];
        if (assign[p->bid] >= 0)
            continue;
        int fits = 1;
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            if (p->use[d] > left[p->seller][d] + BGM_COMBEX_EPS)
                fits = 0;
        if (!fits)
            continue;
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            left[p->seller][d] -= p->use[d];
        assign[p->bid] = (int)rk[i].index;
        r->objective += p->surplus;
    }
out:
    free(rk);
    free(left);
    return st;
}

void bgm_combex_set_exact(bgm_combex_t *cx, double mip_gap, long node_budget)
{
    cx->mip_gap = mip_gap;
    cx->node_budget = node_budget;
}

typedef struct budget {
    long nodes, max;
} budget_t;

static void on_ios(glp_tree *tree, void *info)
{
    budget_t *b = info;
    if (glp_ios_reason(tree) == GLP_ISELECT && ++b->nodes > b->max)
        glp_ios_terminate(tree);
}

/* Builds and solves the integer program; returns BG_ERR_NUMERIC when GLPK
 * does not prove optimality (the caller falls back to the greedy). */
static bg_status solve_exact(bgm_combex_t *cx, int *assign, bgm_combex_result_t *r)
{
    bg_status st = BG_OK;
    size_t nz_max = cx->npair * (1 + BGM_COMBEX_DIMS);
    int *ia = malloc((nz_max + 1) * sizeof *ia);
    int *ja = malloc((nz_max + 1) * sizeof *ja);
    double *ar = malloc((nz_max + 1) * sizeof *ar);
    glp_prob *lp = NULL;
    if (!ia || !ja || !ar) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    for (int b = 0; b < cx->nbid; b++)
        assign[b] = -1;
    r->method = BGM_COMBEX_EXACT;
    r->optimal = 1;
    r->objective = 0.0;
    r->work = 0;
    if (cx->npair == 0)
        goto out;
    glp_term_out(GLP_OFF);
    lp = glp_create_prob();
    glp_set_obj_dir(lp, GLP_MAX);
    int nrows = cx->nbid + cx->nseller * BGM_COMBEX_DIMS;
    glp_add_rows(lp, nrows);
    for (int b = 0; b < cx->nbid; b++)
        glp_set_row_bnds(lp, 1 + b, GLP_UP, 0.0, 1.0);
    for (int s = 0; s < cx->nseller; s++)
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            glp_set_row_bnds(lp, 1 + cx->nbid + s * BGM_COMBEX_DIMS + d, GLP_UP, 0.0, cx->cap[s][d]);
    glp_add_cols(lp, (int)cx->npair);
    size_t nz = 0;
    for (size_t i = 0; i < cx->npair; i++) {
        const bgm_combex_pair_t *p = &cx->pairs[i];
        int col = (int)i + 1;
        glp_set_col_kind(lp, col, GLP_BV);
        glp_set_obj_coef(lp, col, p->surplus);
        nz++;
        ia[nz] = 1 + p->bid;
        ja[nz] = col;
        ar[nz] = 1.0;
        for (int d = 0; d < BGM_COMBEX_DIMS; d++) {
            if (p->use[d] == 0.0)
                continue;
            nz++;
            ia[nz] = 1 + cx->nbid + p->seller * BGM_COMBEX_DIMS + d;
            ja[nz] = col;
            ar[nz] = p->use[d];
        }
    }
    glp_load_matrix(lp, (int)nz, ia, ja, ar);
    glp_iocp parm;
    glp_init_iocp(&parm);
    parm.presolve = GLP_ON;
    parm.msg_lev = GLP_MSG_OFF;
    budget_t bud = {0, cx->node_budget};
    parm.mip_gap = cx->mip_gap;
    /* Clique and MIR cuts suit assignment-and-knapsack rows. (GLPK 5.0's
     * cover-cut initialisation aborts on presolved-away problems, so
     * cover cuts stay off.) */
    parm.clq_cuts = GLP_ON;
    parm.cb_func = on_ios;
    parm.cb_info = &bud;
    int rc = glp_intopt(lp, &parm);
    r->work = bud.nodes;
    int ms = glp_mip_status(lp);
    if (rc == GLP_EMIPGAP && ms == GLP_FEAS) {
        r->optimal = 0; /* within the configured gap of the optimum */
    } else if (rc != 0 || ms != GLP_OPT) {
        st = BG_ERR_NUMERIC;
        goto out;
    }
    for (size_t i = 0; i < cx->npair; i++) {
        if (glp_mip_col_val(lp, (int)i + 1) > 0.5) {
            assign[cx->pairs[i].bid] = (int)i;
            r->objective += cx->pairs[i].surplus;
        }
    }
out:
    if (lp)
        glp_delete_prob(lp);
    free(ia);
    free(ja);
    free(ar);
    return st;
}

bg_status bgm_combex_solve(bgm_combex_t *cx, bgm_combex_method method, size_t exact_limit,
                           long greedy_budget, int *assign, bgm_combex_result_t *r)
{
    if (method == BGM_COMBEX_AUTO)
        method = cx->npair <= exact_limit ? BGM_COMBEX_EXACT : BGM_COMBEX_GREEDY;
    if (method == BGM_COMBEX_EXACT) {
        bg_status st = solve_exact(cx, assign, r);
        if (st != BG_ERR_NUMERIC)
            return st;
    }
    return solve_greedy(cx, greedy_budget, assign, r);
}

/* Whether a pair's use fits in `room` (per dimension). */
static int fits_in(const bgm_combex_pair_t *p, const double *room)
{
    for (int d = 0; d < BGM_COMBEX_DIMS; d++)
        if (p->use[d] > room[d] + BGM_COMBEX_EPS)
            return 0;
    return 1;
}

bg_status bgm_combex_rents(const bgm_combex_t *cx, const int *assign, double k, double *rent)
{
    bg_status st = BG_OK;
    size_t ns = (size_t)(cx->nseller > 0 ? cx->nseller : 1), nb = (size_t)(cx->nbid > 0 ? cx->nbid : 1);
    double (*left)[BGM_COMBEX_DIMS] = malloc(ns * sizeof *left);
    int *head = malloc(ns * sizeof *head), *next = malloc(nb * sizeof *next);
    double *lo = malloc(nb * sizeof *lo), *alt = malloc(nb * sizeof *alt);
    if (!left || !head || !next || !lo || !alt) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    memcpy(left, cx->cap, (size_t)cx->nseller * sizeof *left);
    for (int s = 0; s < cx->nseller; s++)
        head[s] = -1;
    /* Capacity left after the allocation, and each seller's winners. */
    for (int b = 0; b < cx->nbid; b++) {
        lo[b] = alt[b] = 0.0;
        rent[b] = 0.0;
        if (assign[b] < 0)
            continue;
        const bgm_combex_pair_t *p = &cx->pairs[assign[b]];
        for (int d = 0; d < BGM_COMBEX_DIMS; d++)
            left[p->seller][d] -= p->use[d];
        next[b] = head[p->seller];
        head[p->seller] = b;
    }
    for (size_t i = 0; i < cx->npair; i++) {
        const bgm_combex_pair_t *q = &cx->pairs[i];
        if (assign[q->bid] < 0) {
            /* An excluded bid competes for each winner's place on q's seller. */
            for (int b = head[q->seller]; b >= 0; b = next[b]) {
                const bgm_combex_pair_t *p = &cx->pairs[assign[b]];
                double room[BGM_COMBEX_DIMS];
                for (int d = 0; d < BGM_COMBEX_DIMS; d++)
                    room[d] = left[q->seller][d] + p->use[d];
                if (fits_in(q, room) && q->surplus > lo[b])
                    lo[b] = q->surplus;
            }
        } else if ((size_t)assign[q->bid] != i && fits_in(q, left[q->seller]) &&
                   q->surplus > alt[q->bid]) {
            /* A winner's alternative seller with room to spare. */
            alt[q->bid] = q->surplus;
        }
    }
    for (int b = 0; b < cx->nbid; b++) {
        if (assign[b] < 0)
            continue;
        double sbs = cx->pairs[assign[b]].surplus;
        double l = lo[b] < sbs ? lo[b] : sbs;
        double h = sbs - alt[b];
        if (h < l)
            h = l;
        rent[b] = l + k * (h - l);
    }
out:
    free(left);
    free(head);
    free(next);
    free(lo);
    free(alt);
    return st;
}
