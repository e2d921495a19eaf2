#include "bga_backend.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bg_clock.h"
#include "bga_pool.h"

#define BACKEND_ENDPOINT_MAX 256
/* Job ids: session s uses (s << 4) + fit id for its rotation-fit pools and
 * (s << 4) + 8 + system id for its matrices. */
#define BACKEND_JOB_SHIFT 4
#define BACKEND_SYSTEM_JOB 8
#define BACKEND_STEP_JOB 2
#define BACKEND_SURFACE_JOB 3

struct bga_backend {
    bg_backend_t services;
    char endpoint[BGA_BACKEND_MAX_AGENTS][BACKEND_ENDPOINT_MAX];
    int nrotfit;
    int has_integ; /* endpoint[nrotfit + 1] is the integration-step agent */
    int timeout_ms;
    int64_t lease_ms;
    uint64_t sessions;
    bga_agent_usage_t usage[BGA_BACKEND_MAX_AGENTS];
};

typedef struct session {
    bga_backend_t *b;
    uint64_t job;
    bga_rotfit_pool_t *pool[BG_BACKEND_MAX_FITS];
    double *scratch[BG_BACKEND_MAX_FITS]; /* nval: a scaled Hessian's unscaled values */
    size_t nval[BG_BACKEND_MAX_FITS];
    bga_client_t *solver;
    bg_sparse_t *sys[BG_BACKEND_MAX_SYSTEMS];
    int set_up[BG_BACKEND_MAX_SYSTEMS];
    double flops[BG_BACKEND_MAX_SYSTEMS], nonzeros[BG_BACKEND_MAX_SYSTEMS]; /* the agent's */
    /* integration-step: on the agent (integ, with reply buffers), or in
     * this process when the backend has no such agent (local_step) */
    bga_client_t *integ;
    bga_step_buffers_t sbuf;
    double *sblock;
    bg_step_t *local_step;
    bga_rotfit_pool_t *surface; /* the surface editor's cells over the rotation-fit agents */
    bg_status failed;
    bg_error_t fail_err;
} session;

static void add_traffic(bga_traffic_t *into, bga_traffic_t t)
{
    into->requests += t.requests;
    into->bytes_sent += t.bytes_sent;
    into->bytes_received += t.bytes_received;
    into->encode_seconds += t.encode_seconds;
    into->wait_seconds += t.wait_seconds;
    into->agent_seconds += t.agent_seconds;
}

/* The first failure sticks: later calls repeat it without a new timeout. */
static bg_status fail(session *s, bg_status st, bg_error_t *err)
{
    if (s->failed == BG_OK) {
        s->failed = st;
        bg_error_set(&s->fail_err, st, "%s", err->message);
    }
    return st;
}

static bg_status check(session *s, bg_error_t *err)
{
    return s->failed == BG_OK ? BG_OK : bg_error_set(err, s->failed, "%s", s->fail_err.message);
}

static bg_status session_new(void *ctx, void **out, bg_error_t *err)
{
    session *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for an agents session");
    s->b = ctx;
    s->job = ++s->b->sessions << BACKEND_JOB_SHIFT;
    *out = s;
    return BG_OK;
}

static void session_destroy(void *ctx, void *opaque)
{
    bga_backend_t *b = ctx;
    session *s = opaque;
    /* Releases are sent unless a call failed in transport (BG_ERR_IO: an
     * agent that does not answer, whose lease frees its jobs): after an
     * answered refusal (no free slot, a bad value) every agent still
     * answers, and its other jobs' state must not wait for the lease. */
    const int release = s->failed != BG_ERR_IO;
    for (int f = 0; f < BG_BACKEND_MAX_FITS; f++) {
        if (s->pool[f])
            for (int i = 0; i < b->nrotfit; i++) {
                add_traffic(&b->usage[i].traffic, bga_rotfit_pool_traffic(s->pool[f], i));
                b->usage[i].elements += bga_rotfit_pool_elements(s->pool[f], i);
            }
        if (release)
            bga_rotfit_pool_destroy(&s->pool[f]);
        else
            bga_rotfit_pool_abandon(&s->pool[f]);
        free(s->scratch[f]);
    }
    if (s->solver) {
        for (int i = 0; i < BG_BACKEND_MAX_SYSTEMS && release; i++)
            if (s->set_up[i]) {
                bg_error_t ignored = BG_ERROR_INIT; /* best effort: the lease frees it otherwise */
                bga_client_release(s->solver, s->job + BACKEND_SYSTEM_JOB + (uint64_t)i,
                                   &ignored);
            }
        add_traffic(&b->usage[b->nrotfit].traffic, bga_client_traffic(s->solver));
        bga_client_destroy(&s->solver);
    }
    if (s->surface) {
        for (int i = 0; i < b->nrotfit; i++) {
            add_traffic(&b->usage[i].traffic, bga_rotfit_pool_traffic(s->surface, i));
            b->usage[i].elements += bga_rotfit_pool_elements(s->surface, i);
        }
        if (release)
            bga_rotfit_pool_destroy(&s->surface);
        else
            bga_rotfit_pool_abandon(&s->surface);
    }
    if (s->integ) {
        if (release) {
            bg_error_t ignored = BG_ERROR_INIT; /* best effort: the lease frees it otherwise */
            bga_client_release(s->integ, s->job + BACKEND_STEP_JOB, &ignored);
        }
        add_traffic(&b->usage[b->nrotfit + 1].traffic, bga_client_traffic(s->integ));
        bga_client_destroy(&s->integ);
    }
    bg_step_destroy(&s->local_step);
    free(s->sblock);
    free(s);
}

static bg_status fit_open(void *opaque, int id, const bg_backend_fit_t *fit, bg_error_t *err)
{
    session *s = opaque;
    bga_backend_t *b = s->b;
    const char *eps[BGA_BACKEND_MAX_AGENTS];
    for (int i = 0; i < b->nrotfit; i++)
        eps[i] = b->endpoint[i];
    const bga_pool_config_t cfg = {.mesh = fit->mesh,
                                   .mu = fit->mu,
                                   .lambda = fit->lambda,
                                   .barrier = fit->barrier,
                                   .scatter = fit->scatter,
                                   .nval = fit->nval,
                                   .endpoints = eps,
                                   .nagents = b->nrotfit,
                                   .job = s->job + (uint64_t)id,
                                   .timeout_ms = b->timeout_ms,
                                   .lease_ms = b->lease_ms,
                                   .rest_edges = fit->rest_edges};
    bg_status st = check(s, err);
    if (st == BG_OK && fit->scatter) {
        s->scratch[id] = malloc(fit->nval * sizeof *s->scratch[id] + 1);
        s->nval[id] = fit->nval;
        if (!s->scratch[id])
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the Hessian values");
    }
    if (st == BG_OK)
        st = bga_rotfit_pool_new(&cfg, &s->pool[id], err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status fit_eval(void *opaque, int id, const double *q, double *energy, double *grad,
                          bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st == BG_OK)
        st = bga_rotfit_pool_eval(s->pool[id], q, energy, grad, NULL, 0, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status fit_hessian(void *opaque, int id, const double *q, int project, double scale,
                             double *values, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    double energy = 0.0;
    if (scale == 1.0) {
        st = bga_rotfit_pool_eval(s->pool[id], q, &energy, NULL, values, project, err);
    } else {
        double *h = s->scratch[id];
        memset(h, 0, s->nval[id] * sizeof *h);
        st = bga_rotfit_pool_eval(s->pool[id], q, &energy, NULL, h, project, err);
        if (st == BG_OK)
            for (size_t i = 0; i < s->nval[id]; i++)
                values[i] += scale * h[i];
    }
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status solve_open(void *opaque, int id, bg_sparse_t *sys, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st == BG_OK && !s->solver)
        st = bga_client_new(s->b->endpoint[s->b->nrotfit], "sparse-solve", s->b->timeout_ms,
                            &s->solver, err);
    if (st != BG_OK)
        return fail(s, st, err);
    s->sys[id] = sys;
    return BG_OK;
}

static bg_status solve_factor(void *opaque, int id, double shift, bg_error_t *err)
{
    session *s = opaque;
    bg_sparse_t *sys = s->sys[id];
    const uint64_t job = s->job + BACKEND_SYSTEM_JOB + (uint64_t)id;
    bg_status st = check(s, err);
    const double t_setup = bg_clock_now();
    if (st == BG_OK && !s->set_up[id]) {
        st = bga_client_solve_setup(s->solver, job, bg_sparse_size(sys), bg_sparse_colptr(sys),
                                    bg_sparse_rowidx(sys), bg_sparse_prefers_solves(sys),
                                    s->b->lease_ms, err);
        s->set_up[id] = st == BG_OK;
    }
    int posdef = 0;
    bga_factor_cost_t cost = {0};
    const double t0 = bg_clock_now();
    if (st == BG_OK)
        st = bga_client_solve_factor_cost(s->solver, job, bg_sparse_values(sys),
                                          bg_sparse_nonzeros(sys), shift, &posdef, &cost, err);
    s->flops[id] = cost.flops;
    s->nonzeros[id] = cost.nonzeros;
    /* The round trips count as the solver's factor time, the pattern's
     * upload and the agent's analysis of it as analysis, as a local
     * factor's would. */
    const double elapsed = bg_clock_now() - t0;
    const double analyze = fmin(cost.analyze_seconds, elapsed);
    const bg_sparse_timing_t spent = {analyze + (t0 - t_setup), elapsed - analyze, 0.0,
                                      st == BG_OK, 0};
    bg_sparse_add_timing(sys, &spent);
    if (st != BG_OK)
        return fail(s, st, err);
    if (!posdef)
        return bg_error_set(err, BG_ERR_NUMERIC,
                            "agent %s (sparse-solve): the matrix plus %g I is not positive "
                            "definite",
                            bga_client_endpoint(s->solver), shift);
    return BG_OK;
}

static bg_status solve(void *opaque, int id, int nrhs, const double *rhs, double *x,
                       bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    const double t0 = bg_clock_now();
    if (st == BG_OK)
        st = bga_client_solve(s->solver, s->job + BACKEND_SYSTEM_JOB + (uint64_t)id, rhs,
                              bg_sparse_size(s->sys[id]), nrhs, x, err);
    const bg_sparse_timing_t spent = {0.0, 0.0, bg_clock_now() - t0, 0, st == BG_OK ? nrhs : 0};
    bg_sparse_add_timing(s->sys[id], &spent);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static void solve_cost(void *opaque, int id, double *flops, double *nonzeros)
{
    const session *s = opaque;
    *flops = s->flops[id];
    *nonzeros = s->nonzeros[id];
}

static bg_status step_open(void *opaque, const bg_step_setup_t *setup, bg_step_motion_t *motion,
                           bg_error_t *err)
{
    session *s = opaque;
    bga_backend_t *b = s->b;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->integ || s->local_step)
        return bg_error_set(err, BG_ERR_INVALID, "this session already holds a step state");
    if (!b->has_integ) {
        st = bg_step_new(setup, &s->local_step, err);
        if (st == BG_OK)
            bg_step_motion(s->local_step, motion);
        return st == BG_OK ? BG_OK : fail(s, st, err);
    }
    const size_t ndof = (size_t)setup->nv * (size_t)setup->dim;
    s->sblock = malloc((4 + BG_STEP_MAX_CANDIDATES) * ndof * sizeof *s->sblock + 1);
    if (!s->sblock)
        return fail(s, bg_error_set(err, BG_ERR_NOMEM, "out of memory for the step buffers"),
                    err);
    s->sbuf = (bga_step_buffers_t){ndof,           s->sblock,        s->sblock + ndof,
                                   s->sblock + 2 * ndof, s->sblock + 4 * ndof, s->sblock + 3 * ndof};
    st = bga_client_new(b->endpoint[b->nrotfit + 1], "integration-step", b->timeout_ms, &s->integ,
                        err);
    if (st == BG_OK)
        st = bga_client_step_setup(s->integ, s->job + BACKEND_STEP_JOB, setup, b->lease_ms,
                                   &s->sbuf, motion, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status no_step(session *s, bg_error_t *err)
{
    return fail(s, bg_error_set(err, BG_ERR_INVALID, "integration step called before step_open"),
                err);
}

static bg_status step_predict(void *opaque, const bg_step_request_t *req,
                              bg_step_prediction_t *out, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->local_step)
        st = bg_step_predict(s->local_step, req, out, err);
    else if (s->integ)
        st = bga_client_step_predict(s->integ, s->job + BACKEND_STEP_JOB, req, &s->sbuf, out, err);
    else
        return no_step(s, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status step_update(void *opaque, const double *q_star, const double *grad_star,
                             bg_step_trial_t *out, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->local_step)
        st = bg_step_update(s->local_step, q_star, grad_star, out, err);
    else if (s->integ)
        st = bga_client_step_update(s->integ, s->job + BACKEND_STEP_JOB, q_star, grad_star,
                                    &s->sbuf, out, err);
    else
        return no_step(s, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status step_accept(void *opaque, bg_step_motion_t *motion, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->local_step)
        st = bg_step_accept(s->local_step, motion, err);
    else if (s->integ)
        st = bga_client_step_accept(s->integ, s->job + BACKEND_STEP_JOB, &s->sbuf, motion, err);
    else
        return no_step(s, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status surface_open(void *opaque, const bg_mesh_t *mesh, bg_error_t *err)
{
    session *s = opaque;
    bga_backend_t *b = s->b;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->surface)
        return bg_error_set(err, BG_ERR_INVALID, "this session already holds a surface");
    const char *eps[BGA_BACKEND_MAX_AGENTS];
    for (int i = 0; i < b->nrotfit; i++)
        eps[i] = b->endpoint[i];
    const bga_pool_config_t cfg = {.mesh = mesh,
                                   .endpoints = eps,
                                   .nagents = b->nrotfit,
                                   .job = s->job + BACKEND_SURFACE_JOB,
                                   .timeout_ms = b->timeout_ms,
                                   .lease_ms = b->lease_ms,
                                   .surface = 1};
    st = bga_rotfit_pool_new(&cfg, &s->surface, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static bg_status surface_eval(void *opaque, const double *q, double *energy, double *grad,
                              bg_rotfit_stats_t *stats, bg_error_t *err)
{
    (void)stats; /* the fit counts stay on the agents */
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (!s->surface)
        return fail(s, bg_error_set(err, BG_ERR_INVALID, "surface fit before surface_open"), err);
    st = bga_rotfit_pool_eval(s->surface, q, energy, grad, NULL, 0, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static const bg_backend_ops_t agents_ops = {
    "agents",    session_new, session_destroy, fit_open,     fit_eval,     fit_hessian,
    solve_open,  solve_factor, solve,          solve_cost,   step_open,    step_predict,
    step_update, step_accept,  surface_open, surface_eval,
};

bg_status bga_backend_new(const bga_backend_config_t *cfg, bga_backend_t **out, bg_error_t *err)
{
    *out = NULL;
    if (cfg->nrotfit < 1 || cfg->nrotfit >= BGA_BACKEND_MAX_AGENTS - 1 || !cfg->solve)
        return bg_error_set(err, BG_ERR_INVALID,
                            "agents: %d rotation-fit agents (1 to %d) and %s sparse-solve agent",
                            cfg->nrotfit, BGA_BACKEND_MAX_AGENTS - 2, cfg->solve ? "a" : "no");
    bga_backend_t *b = calloc(1, sizeof *b);
    if (!b)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the agents backend");
    b->nrotfit = cfg->nrotfit;
    for (int i = 0; i <= cfg->nrotfit; i++) {
        const char *ep = i < cfg->nrotfit ? cfg->rotfit[i] : cfg->solve;
        if (strlen(ep) >= BACKEND_ENDPOINT_MAX) {
            free(b);
            return bg_error_set(err, BG_ERR_INVALID, "agent endpoint too long: %.40s...", ep);
        }
        strcpy(b->endpoint[i], ep);
        b->usage[i].endpoint = b->endpoint[i];
        b->usage[i].service = i < cfg->nrotfit ? "rotation-fit" : "sparse-solve";
    }
    b->timeout_ms = cfg->timeout_ms;
    b->lease_ms = cfg->lease_ms;
    /* Several coordinators share agents: job ids start from this
     * process's id and the clock, so two jobs never meet on an agent. */
    b->sessions = ((uint64_t)getpid() << 20 | ((uint64_t)(bg_clock_now() * 1e3) & 0xfffffu))
                  << 16;
    if (cfg->job_base)
        b->sessions = cfg->job_base >> BACKEND_JOB_SHIFT;
    b->services = (bg_backend_t){&agents_ops, b};
    *out = b;
    return BG_OK;
}

bg_status bga_backend_set_integ(bga_backend_t *b, const char *endpoint, bg_error_t *err)
{
    if (strlen(endpoint) >= BACKEND_ENDPOINT_MAX)
        return bg_error_set(err, BG_ERR_INVALID, "agent endpoint too long: %.40s...", endpoint);
    const int i = b->nrotfit + 1;
    strcpy(b->endpoint[i], endpoint);
    b->usage[i] = (bga_agent_usage_t){b->endpoint[i], "integration-step", 0, {0}};
    b->has_integ = 1;
    return BG_OK;
}

void bga_backend_destroy(bga_backend_t **backend)
{
    if (!backend || !*backend)
        return;
    free(*backend);
    *backend = NULL;
}

const bg_backend_t *bga_backend_services(const bga_backend_t *backend)
{
    return &backend->services;
}

int bga_backend_agents(const bga_backend_t *backend)
{
    return backend->nrotfit + 1;
}

bga_agent_usage_t bga_backend_usage(const bga_backend_t *backend, int agent)
{
    return backend->usage[agent];
}

int bga_backend_integ_usage(const bga_backend_t *backend, bga_agent_usage_t *usage)
{
    if (!backend->has_integ)
        return 0;
    *usage = backend->usage[backend->nrotfit + 1];
    return 1;
}
