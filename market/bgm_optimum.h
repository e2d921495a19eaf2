/*
 * bgm_optimum — the offline optimum of a run's demand and supply: the
 * welfare that welfare_ratio divides by.
 *
 * The real offline problem is a scheduling problem: serve each service
 * request at most once, by one basic-service agent selling its type and
 * one resource agent, starting its delivery at some time in its window
 * [release, latest], for the request's duration on that resource; at no
 * time may a basic agent run more instances than its slots, nor a resource
 * agent rent more cores or memory than it has. Welfare = Σ valuation −
 * Σ basic agents' own cost − Σ resource cost (duration × cost rate).
 * Solved exactly it is a time-indexed integer program far too large for a
 * run of hundreds of requests, so this module solves an aggregated integer
 * program P instead, whose optimum is never below the real one:
 *
 *   variables  z(i,r) in {0,1}  request i runs on resource agent r
 *              y(i,b) in [0,1]  share of request i served by basic agent b
 *   maximise   Σ (V_i − K_ir) z(i,r) − Σ k_b,t(i) w_i y(i,b)
 *   s.t.       Σ_r z(i,r) <= 1,   Σ_b y(i,b) = Σ_r z(i,r)          every i
 *              Σ_i c_i ov(i, d_ir, I) z(i,r) <= C_r |I|   (and memory)  every r, I
 *              Σ_i ov(i, dmin_i, I) y(i,b)  <= S_b |I|                  every b, I
 *              Σ_{i of a type in T} Σ_r ov(i, d_ir, I) z(i,r) <= S_T |I|  every T, I
 *
 * with V_i the request's valuation (per unit × work w_i), K_ir its
 * resource cost on r, d_ir its duration on r, dmin_i its shortest
 * duration, k_b,t the basic agent's cost per unit, S_T the slots of all
 * the basic agents selling a type in the set T, and ov(i, d, I) the
 * least time a delivery of length d started anywhere in i's window must
 * spend inside the interval I (the overlap is unimodal in the start, so it
 * is the smaller of the overlaps at the window's two ends). The intervals
 * I are the whole span and its tilings by lengths L0·2^k (L0 = the longest
 * window, or the shortest duration when every window is a point).
 *
 * When bundles may split (per-type call markets sell cores and memory
 * apart, from any agents), z(i,r) becomes c(i,r), the share of i's cores
 * on r, costing the cores' run on r; memory gets variables m(i,r) of its
 * own, with Σ_r m(i,r) = Σ_r c(i,r), held and paid at least for dmin_i
 * (a bundle's run is never shorter); and a bundle need not fit on one
 * agent. That program is a relaxation of the first, so it bounds every
 * mechanism, whole bundles or split.
 *
 * Why it bounds the real optimum from above: any real schedule gives a
 * feasible point of P (z, y = 1 on the agents it used; a delivery really
 * spends at least ov inside each interval, so the energy in I never
 * exceeds capacity × |I|; a basic slot is busy at least while the
 * delivery runs, for its real duration on its resource, so the pooled
 * rows hold too) with the same objective. P relaxes the exact timing to
 * energy over intervals and lets a request's basic service split between
 * agents; it is exact when capacity does not bind. Pairs whose surplus is
 * not positive even with the cheapest basic agent are left out: dropping
 * such a request never lowers the real optimum.
 *
 * What is reported is the optimum of P's linear relaxation (z in [0,1]),
 * which bounds P's integer optimum from above in turn. Branch and bound
 * on P buys nothing measurable: on the smoke runs GLPK's integer
 * solutions come within 1e-5 of the relaxation, and at 40 nodes it does
 * not prove the last fraction of a percent in minutes. The relaxation is
 * solved by column generation: GLPK's simplex on the few pairs worth
 * having, priced against every pair of P with the duals until none would
 * improve it. The value returned is the Lagrangian bound of the final
 * duals π (π >= 0 on the inequality rows):
 *
 *   Σ_rows π_k rhs_k + Σ_columns max(0, c_j − π·A_j)
 *
 * which bounds the relaxation from above for any such π, whatever the
 * simplex's rounding, and equals its optimum once no column prices out.
 * Pure: no I/O besides GLPK's (silenced).
 */
#ifndef BGM_OPTIMUM_H
#define BGM_OPTIMUM_H

#include <stddef.h>

#include "bg_error.h"
#include "bgm_config.h"

/* Per service type: what one request of that type needs. */
typedef struct bgm_opt_service {
    double flops_per_unit;
    double cores;
    double memory;
} bgm_opt_service_t;

typedef struct bgm_opt_request {
    int type;       /* service type, 0..BGM_SERVICE_TYPES-1 */
    double work;    /* units, > 0 */
    double value;   /* valuation per unit */
    double release; /* earliest start of delivery */
    double latest;  /* latest start of delivery, >= release */
} bgm_opt_request_t;

typedef struct bgm_opt_basic {
    double slots;                   /* concurrent instances, all types together */
    int sells[BGM_SERVICE_TYPES];   /* 1 when it sells the type */
    double cost[BGM_SERVICE_TYPES]; /* own cost per unit */
} bgm_opt_basic_t;

typedef struct bgm_opt_resource {
    double cores, memory; /* capacity */
    double speed;         /* flops per second per core */
    double core_cost;     /* per core-second */
    double memory_cost;   /* per GiB-second */
} bgm_opt_resource_t;

/* Borrowed arrays; services has BGM_SERVICE_TYPES entries. */
typedef struct bgm_opt_problem {
    const bgm_opt_service_t *services;
    const bgm_opt_request_t *requests;
    size_t nrequests;
    const bgm_opt_basic_t *basics;
    size_t nbasics;
    const bgm_opt_resource_t *resources;
    size_t nresources;
    int split; /* 1: a bundle's cores and memory may come from several
                * resource agents (per-type call markets) */
} bgm_opt_problem_t;

typedef enum bgm_opt_status {
    BGM_OPT_SOLVED = 0,    /* value holds the bound */
    BGM_OPT_TOO_LARGE = 1, /* more pairs than the limit: not attempted */
    BGM_OPT_FAILED = 2     /* the simplex failed (numerically): no bound */
} bgm_opt_status;

typedef struct bgm_opt_result {
    bgm_opt_status status;
    double value;   /* the bound (NaN unless SOLVED) */
    double lp;      /* the restricted relaxation's optimum, <= value */
    size_t pairs;   /* variables of P: request-resource and request-basic pairs */
    size_t columns; /* pairs column generation brought into the simplex */
    size_t rows;    /* capacity rows kept (the others cannot bind) */
    int intervals;  /* intervals in the family */
    int rounds;     /* pricing rounds */
} bgm_opt_result_t;

/*
 * Bounds the offline optimum. pair_limit caps the variables P may have:
 * above it nothing is allocated and the status is TOO_LARGE. Returns
 * BG_ERR_INVALID for a malformed problem and BG_ERR_NOMEM; a problem not
 * solved is a status, not an error.
 */
bg_status bgm_optimum_solve(const bgm_opt_problem_t *p, size_t pair_limit,
                            bgm_opt_result_t *result);

/* The variables request q would bring into P (its resource, memory and
 * basic-agent pairs; 0 if it has no resource pair of positive surplus).
 * p->requests is not read, so a caller can count a problem request by
 * request, without building it, and stop once past its limit. */
size_t bgm_optimum_request_pairs(const bgm_opt_problem_t *p, const bgm_opt_request_t *q);

/* The least time a delivery of length d started anywhere in
 * [release, latest] spends inside [lo, hi] (exposed for the tests). */
double bgm_optimum_overlap(double release, double latest, double d, double lo, double hi);

#endif
