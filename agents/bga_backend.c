#include "bga_backend.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bg_clock.h"
#include "bga_pool.h"

#define BACKEND_ENDPOINT_MAX BGA_BACKEND_ENDPOINT_MAX
/* Job ids: session s uses (s << 4) + fit id for its rotation-fit pools and
 * (s << 4) + 8 + system id for its matrices (ids below
 * BG_BACKEND_MAX_SYSTEMS = 7: at most 14), above its place's base. */
#define BACKEND_JOB_SHIFT 4
#define BACKEND_SYSTEM_JOB 8
#define BACKEND_STEP_JOB 2
#define BACKEND_SURFACE_JOB 3
_Static_assert(BACKEND_SYSTEM_JOB + BG_BACKEND_MAX_SYSTEMS <= (1 << BACKEND_JOB_SHIFT),
               "a session's matrices must fit in its job-id block");
/* A replacement whose recovery names no job base of its own (no market
 * contract) moves the place's base by this much: sessions number below
 * 2^24, so (session << 4) + 15 stays below it, and its ids meet none of
 * the backend's others on an agent that holds several places. */
#define BACKEND_REPLACEMENT_STRIDE ((uint64_t)1 << 28)
/* Given-up agents are read for late answers at most this often. */
#define BACKEND_DRAIN_SECONDS 0.1

/* A place a session's calls go to: a rotation-fit part, the sparse solve,
 * the integration step; its agent changes when one is lost. */
typedef struct place {
    char endpoint[BACKEND_ENDPOINT_MAX];
    uint64_t base;  /* compute job ids on its agent: base + (session << 4) + offset */
    int generation; /* agents replaced in this place so far */
} place_t;

/* A client of an agent given up, still read for its late answers. */
typedef struct given_up {
    bga_client_t *client;
} given_up_t;

struct bga_backend {
    bg_backend_t services;
    place_t place[BGA_BACKEND_MAX_AGENTS]; /* rotation fit 0 .. nrotfit−1, then solve, integ */
    int nrotfit;
    int has_integ; /* place[nrotfit + 1] is the integration-step agent */
    int timeout_ms, ping_ms, lost_ms;
    int64_t lease_ms;
    const bga_curve_peers_t *curve; /* borrowed; NULL: plaintext */
    uint64_t base, sessions;
    int replacements;
    int recover; /* a recovery is set: checkpoints are kept */
    bga_backend_recovery_t recovery;
    bga_agent_usage_t usage[BGA_BACKEND_MAX_AGENTS];
    given_up_t given_up[BGA_BACKEND_GIVEN_UP_MAX];
    int ngiven_up;
    double next_drain;
    int64_t late; /* late answers discarded */
};

/* One accepted step (or a trial of the step in progress) as the
 * integration-step agent got it: enough to play it again. */
typedef struct step_rec {
    int variational, predictor;
    double *t1, *qs, *gs; /* its targets, q* and ∇W(q*) (ndof each) */
    double *q_after;      /* an accepted step's end positions */
} step_rec;

/*
 * What rebuilds a lost integration-step agent's state: the set-up's
 * constants, the state S_b after step b (positions, targets; velocities
 * only for b = 0), the accepted steps since (at most two between calls)
 * and the trials of the step in progress. A step's end state — positions,
 * momenta, velocities — depends on its start positions and its inputs,
 * not on the momenta it starts from (bg_step_update), so S_b plus two
 * replayed steps is the committed state bit for bit, previous velocities
 * (the extrapolating predictor's) included.
 */
typedef struct step_ckpt {
    double *block;        /* every array below */
    uint8_t *constrained; /* ndof */
    double *mass, *v0, *q_b, *t_b;
    double gravity[3], h, damping;
    int dim;
    int32_t nv;
    int64_t b;
    step_rec done[3];
    int ndone;
    step_rec trial[2];
    int predicted[2], updated[2];
    int64_t offset; /* steps the present agent's count lags the run's */
} step_ckpt;

typedef struct session {
    bga_backend_t *b;
    uint64_t n; /* the session's number */
    bga_rotfit_pool_t *pool[BG_BACKEND_MAX_FITS];
    bg_backend_fit_t fit[BG_BACKEND_MAX_FITS]; /* the solver's, borrowed for the session */
    int pool_gen[BG_BACKEND_MAX_FITS][BGA_BACKEND_MAX_AGENTS];
    double *scratch[BG_BACKEND_MAX_FITS]; /* nval: a scaled Hessian's unscaled values */
    size_t nval[BG_BACKEND_MAX_FITS];
    bga_client_t *solver;
    int solver_gen;
    bg_sparse_t *sys[BG_BACKEND_MAX_SYSTEMS];
    int set_up[BG_BACKEND_MAX_SYSTEMS];
    double flops[BG_BACKEND_MAX_SYSTEMS], nonzeros[BG_BACKEND_MAX_SYSTEMS]; /* the agent's */
    /* A reordered system's right-hand sides and solutions in its stored
     * order (bg_sparse_permutation), grown to the widest call: no
     * allocation per solve once it has been seen. */
    double *pbuf[BG_BACKEND_MAX_SYSTEMS];
    size_t pcap[BG_BACKEND_MAX_SYSTEMS];
    /* The checkpoint of each matrix: the values and shift last factored. */
    double *fvalues[BG_BACKEND_MAX_SYSTEMS];
    double fshift[BG_BACKEND_MAX_SYSTEMS];
    int fkept[BG_BACKEND_MAX_SYSTEMS];
    /* integration-step: on the agent (integ, with reply buffers), or in
     * this process when the backend has no such agent (local_step) */
    bga_client_t *integ;
    int integ_gen;
    bga_step_buffers_t sbuf;
    double *sblock;
    bg_step_t *local_step;
    step_ckpt ck;
    int ck_on;
    bga_rotfit_pool_t *surface; /* the surface editor's cells over the rotation-fit agents */
    const bg_mesh_t *surface_mesh;
    int surface_gen[BGA_BACKEND_MAX_AGENTS];
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

static uint64_t job_on(const session *s, int place, uint64_t offset)
{
    return s->b->place[place].base + (s->n << BACKEND_JOB_SHIFT) + offset;
}

static int solve_place(const bga_backend_t *b)
{
    return b->nrotfit;
}

static int integ_place(const bga_backend_t *b)
{
    return b->nrotfit + 1;
}

/* ------------------------------------------------------------ losses */

/* Late answers of the agents given up, read without waiting (at most every
 * BACKEND_DRAIN_SECONDS unless forced) and told to the recovery. */
static void drain_given_up(bga_backend_t *b, int force)
{
    const double now = bg_clock_now();
    if (b->ngiven_up == 0 || (!force && now < b->next_drain))
        return;
    b->next_drain = now + BACKEND_DRAIN_SECONDS;
    for (int i = 0; i < b->ngiven_up; i++) {
        bga_client_t *c = b->given_up[i].client;
        const int64_t n = bga_client_drain(c);
        b->late += n;
        if (n > 0 && b->recovery.late)
            b->recovery.late(b->recovery.ctx, bga_client_endpoint(c), n);
    }
}

/* The client of an agent given up in place `place`: its traffic goes to
 * the place's totals, and it is kept (the oldest goes when full) so that
 * its late answers are read and discarded. Takes ownership. */
static void give_up(bga_backend_t *b, bga_client_t *c, int place)
{
    if (!c)
        return;
    add_traffic(&b->usage[place].traffic, bga_client_traffic(c));
    if (b->ngiven_up == BGA_BACKEND_GIVEN_UP_MAX) {
        drain_given_up(b, 1);
        bga_client_destroy(&b->given_up[0].client);
        memmove(&b->given_up[0], &b->given_up[1],
                (BGA_BACKEND_GIVEN_UP_MAX - 1) * sizeof b->given_up[0]);
        b->ngiven_up--;
    }
    b->given_up[b->ngiven_up++].client = c;
}

/* Whether a call failed because its agent is lost: no answer (silent,
 * timed out, a broken socket) or "no state for this job" (it restarted,
 * or its lease or contract ended). A refusal is the call's own failure. */
static int lost(const bga_client_t *c, bg_status st)
{
    return c && (st == BG_ERR_NOT_FOUND ||
                 (st == BG_ERR_IO && bga_client_failure(c) != BGA_CLIENT_FINE));
}

/* What a place's loss looks like to the recovery; why and endpoint are
 * borrowed. */
static bga_backend_loss_t loss_of(const bga_backend_t *b, int place, const char *endpoint,
                                  const char *why)
{
    return (bga_backend_loss_t){place, b->usage[place].service, endpoint, why};
}

/* The outcome of a call that may have been retried: its last failure
 * (in e, the call's own error record) goes to the caller's err. */
static bg_status outcome(bg_status st, const bg_error_t *e, bg_error_t *err)
{
    return st == BG_OK ? BG_OK : bg_error_set(err, st, "%s", e->message);
}

/*
 * Place `place`'s agent, as the caller saw it (generation `seen`), failed
 * with e (the call's own error record, which says why): makes sure the
 * place has a newer agent — the recovery's, unless another session
 * already got one — and returns BG_OK with e cleared; else the failure
 * that ends the call, which replaces e. lost_endpoint receives the
 * given-up agent's endpoint.
 */
static bg_status renew_place(bga_backend_t *b, int place, int seen, char *lost_endpoint,
                             bg_error_t *e)
{
    place_t *p = &b->place[place];
    snprintf(lost_endpoint, BACKEND_ENDPOINT_MAX, "%s", p->endpoint);
    if (p->generation > seen) {
        bg_error_clear(e);
        return BG_OK;
    }
    const bga_backend_loss_t loss = loss_of(b, place, p->endpoint, e->message);
    char endpoint[BACKEND_ENDPOINT_MAX] = "";
    uint64_t base = 0;
    bg_error_t rerr = BG_ERROR_INIT;
    bg_status st =
        b->recovery.replace(b->recovery.ctx, &loss, endpoint, sizeof endpoint, &base, &rerr);
    if (st == BG_OK && (!endpoint[0] || strlen(endpoint) >= sizeof endpoint - 1))
        st = bg_error_set(&rerr, BG_ERR_INVALID, "the replacement for agent %s has no endpoint",
                          p->endpoint);
    bg_error_clear(e);
    if (st != BG_OK)
        return bg_error_set(e, st, "%s", rerr.message);
    snprintf(p->endpoint, sizeof p->endpoint, "%s", endpoint);
    p->base = base ? base : b->base + (uint64_t)(b->replacements + 1) * BACKEND_REPLACEMENT_STRIDE;
    p->generation++;
    b->replacements++;
    return BG_OK;
}

static void resumed(const bga_backend_t *b, int place, const char *lost_endpoint, double noticed)
{
    if (b->recovery.resumed) {
        const bga_backend_loss_t loss = loss_of(b, place, lost_endpoint, "");
        b->recovery.resumed(b->recovery.ctx, &loss, b->place[place].endpoint,
                            bg_clock_now() - noticed);
    }
}

static bg_status new_client(const bga_backend_t *b, int place, const char *service,
                            bga_client_t **out, bg_error_t *err)
{
    bg_status st =
        bga_client_new_curve(b->place[place].endpoint, service, b->timeout_ms, b->curve, out, err);
    if (st == BG_OK)
        bga_client_set_liveness(*out, b->ping_ms, b->lost_ms);
    return st;
}

/* ------------------------------------------------------------ sessions */

static bg_status session_new(void *ctx, void **out, bg_error_t *err)
{
    session *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for an agents session");
    s->b = ctx;
    s->n = ++s->b->sessions;
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
                bga_client_release(s->solver, job_on(s, solve_place(b), BACKEND_SYSTEM_JOB + i),
                                   &ignored);
            }
        add_traffic(&b->usage[solve_place(b)].traffic, bga_client_traffic(s->solver));
        bga_client_destroy(&s->solver);
    }
    for (int i = 0; i < BG_BACKEND_MAX_SYSTEMS; i++) {
        free(s->fvalues[i]);
        free(s->pbuf[i]);
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
            bga_client_release(s->integ, job_on(s, integ_place(b), BACKEND_STEP_JOB), &ignored);
        }
        add_traffic(&b->usage[integ_place(b)].traffic, bga_client_traffic(s->integ));
        bga_client_destroy(&s->integ);
    }
    bg_step_destroy(&s->local_step);
    free(s->sblock);
    free(s->ck.block);
    free(s->ck.constrained);
    free(s);
}

/* --------------------------------------------------------- rotation fit */

/* The pool configuration of a rest shape (id: a fit, or −1: the surface)
 * as the session's places have it now; jobs (nrotfit) is filled. */
static bga_pool_config_t pool_config(const session *s, int id, const char **eps, uint64_t *jobs)
{
    const bga_backend_t *b = s->b;
    for (int i = 0; i < b->nrotfit; i++) {
        eps[i] = b->place[i].endpoint;
        jobs[i] = job_on(s, i, id >= 0 ? (uint64_t)id : BACKEND_SURFACE_JOB);
    }
    if (id < 0)
        return (bga_pool_config_t){.mesh = s->surface_mesh,
                                   .endpoints = eps,
                                   .nagents = b->nrotfit,
                                   .timeout_ms = b->timeout_ms,
                                   .lease_ms = b->lease_ms,
                                   .surface = 1,
                                   .jobs = jobs,
                                   .curve = b->curve};
    const bg_backend_fit_t *fit = &s->fit[id];
    return (bga_pool_config_t){.mesh = fit->mesh,
                               .mu = fit->mu,
                               .lambda = fit->lambda,
                               .barrier = fit->barrier,
                               .scatter = fit->scatter,
                               .nval = fit->nval,
                               .endpoints = eps,
                               .nagents = b->nrotfit,
                               .timeout_ms = b->timeout_ms,
                               .lease_ms = b->lease_ms,
                               .rest_edges = fit->rest_edges,
                               .jobs = jobs,
                               .curve = b->curve};
}

/*
 * A rotation-fit pool's call failed with st (why in e): while a part's
 * agent is lost (and there is a recovery), its place gets a new agent,
 * the part is set up there and, when `q` is given, the call finished
 * (resume) into energy, grad, values. Returns the outcome, e the last
 * failure.
 */
static bg_status recover_pool(session *s, int id, bga_rotfit_pool_t *pool, int *gen,
                              const double *q, double *energy, double *grad, double *values,
                              bg_status st, bg_error_t *e)
{
    bga_backend_t *b = s->b;
    for (int tries = 0; st != BG_OK && b->recover && tries < BGA_BACKEND_MAX_RETRIES; tries++) {
        const int part = bga_rotfit_pool_lost_part(pool);
        if (part < 0)
            break;
        const double noticed = bg_clock_now();
        char lost_ep[BACKEND_ENDPOINT_MAX];
        if ((st = renew_place(b, part, gen[part], lost_ep, e)) != BG_OK)
            return st;
        const char *eps[BGA_BACKEND_MAX_AGENTS];
        uint64_t jobs[BGA_BACKEND_MAX_AGENTS];
        const bga_pool_config_t cfg = pool_config(s, id, eps, jobs);
        bga_client_t *old = NULL;
        st = bga_rotfit_pool_replace(pool, part, &cfg, b->place[part].endpoint, jobs[part], &old,
                                     e);
        give_up(b, old, part);
        gen[part] = b->place[part].generation;
        if (st != BG_OK)
            continue; /* the new agent failed too: the next try sees it */
        resumed(b, part, lost_ep, noticed);
        st = q ? bga_rotfit_pool_resume(pool, q, energy, grad, values, e)
               : bga_rotfit_pool_failure(pool, e);
    }
    return st;
}

/* A pool for rest shape id (−1: the surface), its lost set-ups replaced. */
static bg_status open_pool(session *s, int id, bga_rotfit_pool_t **out, int *gen,
                           bg_error_t *err)
{
    bga_backend_t *b = s->b;
    const char *eps[BGA_BACKEND_MAX_AGENTS];
    uint64_t jobs[BGA_BACKEND_MAX_AGENTS];
    const bga_pool_config_t cfg = pool_config(s, id, eps, jobs);
    for (int i = 0; i < b->nrotfit; i++)
        gen[i] = b->place[i].generation;
    bg_error_t e = BG_ERROR_INIT;
    bg_status st = bga_rotfit_pool_new_live(&cfg, b->ping_ms, b->lost_ms, out, &e);
    if (st != BG_OK && *out)
        st = recover_pool(s, id, *out, gen, NULL, NULL, NULL, NULL, st, &e);
    if (st != BG_OK)
        bga_rotfit_pool_destroy(out);
    return outcome(st, &e, err);
}

static bg_status fit_open(void *opaque, int id, const bg_backend_fit_t *fit, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st == BG_OK && fit->scatter) {
        s->scratch[id] = malloc(fit->nval * sizeof *s->scratch[id] + 1);
        s->nval[id] = fit->nval;
        if (!s->scratch[id])
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the Hessian values");
    }
    s->fit[id] = *fit;
    if (st == BG_OK)
        st = open_pool(s, id, &s->pool[id], s->pool_gen[id], err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

/* A pool's evaluation, its lost agents replaced. */
static bg_status pool_eval(session *s, int id, bga_rotfit_pool_t *pool, int *gen, const double *q,
                           double *energy, double *grad, double *values, int project,
                           bg_error_t *err)
{
    drain_given_up(s->b, 0);
    bg_error_t e = BG_ERROR_INIT;
    bg_status st = bga_rotfit_pool_eval(pool, q, energy, grad, values, project, &e);
    if (st != BG_OK)
        st = recover_pool(s, id, pool, gen, q, energy, grad, values, st, &e);
    return outcome(st, &e, err);
}

static bg_status fit_eval(void *opaque, int id, const double *q, double *energy, double *grad,
                          bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st == BG_OK)
        st = pool_eval(s, id, s->pool[id], s->pool_gen[id], q, energy, grad, NULL, 0, err);
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
        st = pool_eval(s, id, s->pool[id], s->pool_gen[id], q, &energy, NULL, values, project,
                       err);
    } else {
        double *h = s->scratch[id];
        memset(h, 0, s->nval[id] * sizeof *h);
        st = pool_eval(s, id, s->pool[id], s->pool_gen[id], q, &energy, NULL, h, project, err);
        if (st == BG_OK)
            for (size_t i = 0; i < s->nval[id]; i++)
                values[i] += scale * h[i];
    }
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

/* --------------------------------------------------------- sparse solve */

/*
 * A system that is factored about as often as it is assembled (Newton's
 * Hessian: not bg_sparse_prefer_solves) is renumbered here, as the solver
 * renumbers it in process (bg_sparse_reorder: CHOLMOD's analysis, once,
 * in this process), before its scatter map reaches the rotation-fit
 * agents (fit_open comes after) and before any value is written. The
 * agent then gets the pattern in its factor's order and keeps that order
 * (BGA_SOLVE_ORDERED): its factor is the one the solver's process would
 * have made, bit for bit, no factorization permutes the matrix, and the
 * right-hand sides and solutions are permuted here (solve).
 */
static bg_status solve_open(void *opaque, int id, bg_sparse_t *sys, bg_error_t *err)
{
    session *s = opaque;
    bga_backend_t *b = s->b;
    bg_status st = check(s, err);
    if (st == BG_OK && !bg_sparse_prefers_solves(sys))
        st = bg_sparse_reorder(sys, err);
    if (st == BG_OK && !s->solver) {
        s->solver_gen = b->place[solve_place(b)].generation;
        st = new_client(b, solve_place(b), "sparse-solve", &s->solver, err);
    }
    if (st != BG_OK)
        return fail(s, st, err);
    s->sys[id] = sys;
    return BG_OK;
}

/* Factors system id's values (+ shift) on the agent, sending its pattern
 * first if this agent has not got it. */
static bg_status factor_on_agent(session *s, int id, const double *values, double shift,
                                 int *posdef, bga_factor_cost_t *cost, bg_error_t *err)
{
    bg_sparse_t *sys = s->sys[id];
    const uint64_t job = job_on(s, solve_place(s->b), BACKEND_SYSTEM_JOB + (uint64_t)id);
    bg_status st = BG_OK;
    if (!s->set_up[id]) {
        const unsigned options = (bg_sparse_prefers_solves(sys) ? BGA_SOLVE_PREFER_SOLVES : 0u) |
                                 (bg_sparse_permutation(sys) ? BGA_SOLVE_ORDERED : 0u);
        st = bga_client_solve_setup(s->solver, job, bg_sparse_size(sys), bg_sparse_colptr(sys),
                                    bg_sparse_rowidx(sys), options, s->b->lease_ms, err);
        s->set_up[id] = st == BG_OK;
    }
    if (st == BG_OK)
        st = bga_client_solve_factor_cost(s->solver, job, values, bg_sparse_nonzeros(sys), shift,
                                          posdef, cost, err);
    return st;
}

/* The sparse-solve agent was lost: another takes its place and gets every
 * matrix again, factored from its checkpoint (the values and shift last
 * factored), so it holds what the lost one held. */
static bg_status recover_solver(session *s, bg_error_t *err)
{
    bga_backend_t *b = s->b;
    const int place = solve_place(b);
    const double noticed = bg_clock_now();
    char lost_ep[BACKEND_ENDPOINT_MAX];
    bg_status st = renew_place(b, place, s->solver_gen, lost_ep, err); /* err: the call's own */
    if (st != BG_OK)
        return st;
    give_up(b, s->solver, place);
    s->solver = NULL;
    s->solver_gen = b->place[place].generation;
    memset(s->set_up, 0, sizeof s->set_up);
    if ((st = new_client(b, place, "sparse-solve", &s->solver, err)) != BG_OK)
        return st;
    for (int i = 0; i < BG_BACKEND_MAX_SYSTEMS && st == BG_OK; i++) {
        int posdef = 0;
        bga_factor_cost_t cost = {0};
        if (s->fkept[i])
            st = factor_on_agent(s, i, s->fvalues[i], s->fshift[i], &posdef, &cost, err);
    }
    if (st == BG_OK)
        resumed(b, place, lost_ep, noticed);
    return st;
}

/* Whether a failed sparse-solve call should be retried on another agent. */
static int solver_lost(const session *s, bg_status st)
{
    return s->b->recover && lost(s->solver, st);
}

static bg_status solve_factor(void *opaque, int id, double shift, bg_error_t *err)
{
    session *s = opaque;
    bg_sparse_t *sys = s->sys[id];
    bg_status st = check(s, err);
    int posdef = 0;
    bga_factor_cost_t cost = {0};
    const double t_setup = bg_clock_now();
    const int had_pattern = s->set_up[id];
    double t0 = t_setup;
    bg_error_t e = BG_ERROR_INIT;
    drain_given_up(s->b, 0);
    for (int tries = 0; st == BG_OK; tries++) {
        t0 = had_pattern ? bg_clock_now() : t_setup;
        bg_error_clear(&e);
        st = factor_on_agent(s, id, bg_sparse_values(sys), shift, &posdef, &cost, &e);
        if (st == BG_OK || !solver_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES)
            break;
        st = recover_solver(s, &e);
    }
    st = outcome(st, &e, err);
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
    if (s->b->recover) {
        /* The checkpoint: what a replacement must factor to hold this. */
        const size_t nnz = bg_sparse_nonzeros(sys);
        if (!s->fvalues[id] && !(s->fvalues[id] = malloc(nnz * sizeof *s->fvalues[id] + 1)))
            return fail(s, bg_error_set(err, BG_ERR_NOMEM, "out of memory for a checkpoint"),
                        err);
        memcpy(s->fvalues[id], bg_sparse_values(sys), nnz * sizeof *s->fvalues[id]);
        s->fshift[id] = shift;
        s->fkept[id] = 1;
    }
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
    const int32_t *perm = bg_sparse_permutation(s->sys[id]);
    const size_t n = (size_t)bg_sparse_size(s->sys[id]);
    const size_t count = n * (size_t)(nrhs > 0 ? nrhs : 0);
    if (st == BG_OK && perm && s->pcap[id] < count) {
        double *grown = realloc(s->pbuf[id], count * sizeof *grown);
        if (!grown)
            return fail(s, bg_error_set(err, BG_ERR_NOMEM, "out of memory for %d right-hand "
                                        "sides", nrhs), err);
        s->pbuf[id] = grown;
        s->pcap[id] = count;
    }
    double *buf = perm ? s->pbuf[id] : x;
    bg_error_t e = BG_ERROR_INIT;
    drain_given_up(s->b, 0);
    for (int tries = 0; st == BG_OK; tries++) {
        bg_error_clear(&e);
        /* The stored order, as bg_sparse_solve_many permutes in process:
         * row k is the caller's perm[k] (again on a retry: a failed call
         * may have left part of a solution in buf). */
        if (perm)
            for (int c = 0; c < nrhs; c++)
                for (size_t k = 0; k < n; k++)
                    buf[c * n + k] = rhs[c * n + (size_t)perm[k]];
        st = bga_client_solve(s->solver, job_on(s, solve_place(s->b), BACKEND_SYSTEM_JOB + id),
                              perm ? buf : rhs, (int32_t)n, nrhs, buf, &e);
        if (st == BG_OK || !solver_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES)
            break;
        st = recover_solver(s, &e);
    }
    if (st == BG_OK && perm)
        for (int c = 0; c < nrhs; c++)
            for (size_t k = 0; k < n; k++)
                x[c * n + (size_t)perm[k]] = buf[c * n + k];
    st = outcome(st, &e, err);
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

/* ------------------------------------------------------ integration step */

static void swap_recs(step_rec *a, step_rec *b)
{
    const step_rec t = *a;
    *a = *b;
    *b = t;
}

/* The checkpoint's arrays and the set-up's copy (S_0). */
static bg_status ckpt_open(step_ckpt *ck, const bg_step_setup_t *setup, bg_error_t *err)
{
    const size_t ndof = (size_t)setup->nv * (size_t)setup->dim;
    /* mass (nv), v0, q_b, t_b, and 5 records of 4 arrays */
    const size_t count = (size_t)setup->nv + (3 + 5 * 4) * ndof;
    ck->block = malloc(count * sizeof *ck->block + 1);
    ck->constrained = malloc(ndof + 1);
    if (!ck->block || !ck->constrained)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the step checkpoint");
    double *p = ck->block;
    ck->mass = p;
    p += setup->nv;
    ck->v0 = p;
    p += ndof;
    ck->q_b = p;
    p += ndof;
    ck->t_b = p;
    p += ndof;
    step_rec *recs[5] = {&ck->done[0], &ck->done[1], &ck->done[2], &ck->trial[0], &ck->trial[1]};
    for (int r = 0; r < 5; r++) {
        recs[r]->t1 = p;
        recs[r]->qs = p + ndof;
        recs[r]->gs = p + 2 * ndof;
        recs[r]->q_after = p + 3 * ndof;
        p += 4 * ndof;
    }
    memcpy(ck->mass, setup->mass, (size_t)setup->nv * sizeof *ck->mass);
    memcpy(ck->v0, setup->velocity, ndof * sizeof *ck->v0);
    memcpy(ck->q_b, setup->q, ndof * sizeof *ck->q_b);
    memcpy(ck->t_b, setup->t0, ndof * sizeof *ck->t_b);
    memcpy(ck->constrained, setup->constrained, ndof);
    for (int c = 0; c < 3; c++)
        ck->gravity[c] = c < setup->dim ? setup->gravity[c] : 0.0;
    ck->h = setup->h;
    ck->damping = setup->damping;
    ck->dim = setup->dim;
    ck->nv = setup->nv;
    return BG_OK;
}

static bg_step_setup_t ckpt_setup(const step_ckpt *ck)
{
    return (bg_step_setup_t){ck->dim,  ck->nv,   ck->h,   ck->damping,     ck->mass,
                             ck->q_b,  ck->v0,   ck->t_b, ck->constrained, ck->gravity};
}

static void ckpt_predicted(step_ckpt *ck, const bg_step_request_t *req, size_t ndof)
{
    const int t = req->trial != 0;
    if (t == 0)
        ck->predicted[0] = ck->predicted[1] = ck->updated[0] = ck->updated[1] = 0;
    step_rec *r = &ck->trial[t];
    r->variational = req->variational;
    r->predictor = req->predictor;
    memcpy(r->t1, req->t1, ndof * sizeof *r->t1);
    ck->predicted[t] = 1;
    ck->updated[t] = 0;
}

static void ckpt_updated(step_ckpt *ck, const double *q_star, const double *grad_star,
                         size_t ndof)
{
    const int t = ck->predicted[1];
    memcpy(ck->trial[t].qs, q_star, ndof * sizeof *q_star);
    memcpy(ck->trial[t].gs, grad_star, ndof * sizeof *grad_star);
    ck->updated[t] = 1;
}

/* The trial accepted becomes the latest accepted step; past two of them
 * the oldest moves into S_b. */
static void ckpt_accepted(step_ckpt *ck, const double *q, size_t ndof)
{
    const int t = ck->predicted[1] && ck->updated[1];
    swap_recs(&ck->trial[t], &ck->done[ck->ndone]);
    memcpy(ck->done[ck->ndone].q_after, q, ndof * sizeof *q);
    ck->ndone++;
    ck->predicted[0] = ck->predicted[1] = ck->updated[0] = ck->updated[1] = 0;
    if (ck->ndone == 3) {
        double *tmp = ck->q_b;
        ck->q_b = ck->done[0].q_after;
        ck->done[0].q_after = tmp;
        tmp = ck->t_b;
        ck->t_b = ck->done[0].t1;
        ck->done[0].t1 = tmp;
        ck->b++;
        swap_recs(&ck->done[0], &ck->done[1]);
        swap_recs(&ck->done[1], &ck->done[2]);
        ck->ndone = 2;
    }
}

/* A step (or trial) played again on the agent. */
static bg_status replay(session *s, uint64_t job, const step_rec *r, int trial, int update,
                        int accept, bg_error_t *err)
{
    const bg_step_request_t req = {r->variational, trial, r->predictor, r->t1};
    bg_step_prediction_t pr;
    bg_step_trial_t tr;
    bg_step_motion_t mo;
    bg_status st = bga_client_step_predict(s->integ, job, &req, &s->sbuf, &pr, err);
    if (st == BG_OK && update)
        st = bga_client_step_update(s->integ, job, r->qs, r->gs, &s->sbuf, &tr, err);
    if (st == BG_OK && accept)
        st = bga_client_step_accept(s->integ, job, &s->sbuf, &mo, err);
    return st;
}

/* The integration-step agent was lost: another takes its place and its
 * state is rebuilt from the checkpoint (set-up of S_b, the accepted steps
 * since, the trials of the step in progress). */
static bg_status recover_integ(session *s, bg_error_t *err)
{
    bga_backend_t *b = s->b;
    const int place = integ_place(b);
    step_ckpt *ck = &s->ck;
    const double noticed = bg_clock_now();
    char lost_ep[BACKEND_ENDPOINT_MAX];
    bg_status st = renew_place(b, place, s->integ_gen, lost_ep, err);
    if (st != BG_OK)
        return st;
    give_up(b, s->integ, place);
    s->integ = NULL;
    s->integ_gen = b->place[place].generation;
    if ((st = new_client(b, place, "integration-step", &s->integ, err)) != BG_OK)
        return st;
    const uint64_t job = job_on(s, place, BACKEND_STEP_JOB);
    const bg_step_setup_t setup = ckpt_setup(ck);
    bg_step_motion_t mo;
    st = bga_client_step_setup(s->integ, job, &setup, b->lease_ms, &s->sbuf, &mo, err);
    for (int k = 0; k < ck->ndone && st == BG_OK; k++)
        st = replay(s, job, &ck->done[k], 0, 1, 1, err);
    for (int t = 0; t < 2 && st == BG_OK && ck->predicted[t]; t++)
        st = replay(s, job, &ck->trial[t], t, ck->updated[t], 0, err);
    ck->offset = ck->b;
    if (st == BG_OK)
        resumed(b, place, lost_ep, noticed);
    return st;
}

static int integ_lost(const session *s, bg_status st)
{
    return s->ck_on && lost(s->integ, st);
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
    if (b->recover) {
        if ((st = ckpt_open(&s->ck, setup, err)) != BG_OK)
            return fail(s, st, err);
        s->ck_on = 1;
    }
    s->integ_gen = b->place[integ_place(b)].generation;
    bg_error_t e = BG_ERROR_INIT;
    st = new_client(b, integ_place(b), "integration-step", &s->integ, &e);
    for (int tries = 0; st == BG_OK; tries++) {
        bg_error_clear(&e);
        st = bga_client_step_setup(s->integ, job_on(s, integ_place(b), BACKEND_STEP_JOB), setup,
                                   b->lease_ms, &s->sbuf, motion, &e);
        if (st == BG_OK || !integ_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES)
            break;
        st = recover_integ(s, &e);
    }
    return st == BG_OK ? BG_OK : fail(s, outcome(st, &e, err), err);
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
        return (st = bg_step_predict(s->local_step, req, out, err)) == BG_OK ? BG_OK
                                                                            : fail(s, st, err);
    if (!s->integ)
        return no_step(s, err);
    drain_given_up(s->b, 0);
    bg_error_t e = BG_ERROR_INIT;
    for (int tries = 0;; tries++) {
        bg_error_clear(&e);
        st = bga_client_step_predict(s->integ, job_on(s, integ_place(s->b), BACKEND_STEP_JOB), req,
                                     &s->sbuf, out, &e);
        if (st == BG_OK || !integ_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES ||
            (st = recover_integ(s, &e)) != BG_OK)
            break;
    }
    if (st == BG_OK && s->ck_on)
        ckpt_predicted(&s->ck, req, s->sbuf.ndof);
    return st == BG_OK ? BG_OK : fail(s, outcome(st, &e, err), err);
}

static bg_status step_update(void *opaque, const double *q_star, const double *grad_star,
                             bg_step_trial_t *out, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->local_step)
        return (st = bg_step_update(s->local_step, q_star, grad_star, out, err)) == BG_OK
                   ? BG_OK
                   : fail(s, st, err);
    if (!s->integ)
        return no_step(s, err);
    drain_given_up(s->b, 0);
    bg_error_t e = BG_ERROR_INIT;
    for (int tries = 0;; tries++) {
        bg_error_clear(&e);
        st = bga_client_step_update(s->integ, job_on(s, integ_place(s->b), BACKEND_STEP_JOB),
                                    q_star, grad_star, &s->sbuf, out, &e);
        if (st == BG_OK || !integ_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES ||
            (st = recover_integ(s, &e)) != BG_OK)
            break;
    }
    if (st == BG_OK && s->ck_on)
        ckpt_updated(&s->ck, q_star, grad_star, s->sbuf.ndof);
    return st == BG_OK ? BG_OK : fail(s, outcome(st, &e, err), err);
}

static bg_status step_accept(void *opaque, bg_step_motion_t *motion, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->local_step)
        return (st = bg_step_accept(s->local_step, motion, err)) == BG_OK ? BG_OK
                                                                          : fail(s, st, err);
    if (!s->integ)
        return no_step(s, err);
    drain_given_up(s->b, 0);
    bg_error_t e = BG_ERROR_INIT;
    for (int tries = 0;; tries++) {
        bg_error_clear(&e);
        st = bga_client_step_accept(s->integ, job_on(s, integ_place(s->b), BACKEND_STEP_JOB),
                                    &s->sbuf, motion, &e);
        if (st == BG_OK || !integ_lost(s, st) || tries == BGA_BACKEND_MAX_RETRIES ||
            (st = recover_integ(s, &e)) != BG_OK)
            break;
    }
    if (st != BG_OK)
        return fail(s, outcome(st, &e, err), err);
    if (s->ck_on) {
        motion->steps += s->ck.offset;
        ckpt_accepted(&s->ck, motion->q, s->sbuf.ndof);
    }
    return BG_OK;
}

/* ---------------------------------------------------------------- surface */

static bg_status surface_open(void *opaque, const bg_mesh_t *mesh, bg_error_t *err)
{
    session *s = opaque;
    bg_status st = check(s, err);
    if (st != BG_OK)
        return st;
    if (s->surface)
        return bg_error_set(err, BG_ERR_INVALID, "this session already holds a surface");
    s->surface_mesh = mesh;
    st = open_pool(s, -1, &s->surface, s->surface_gen, err);
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
    st = pool_eval(s, -1, s->surface, s->surface_gen, q, energy, grad, NULL, 0, err);
    return st == BG_OK ? BG_OK : fail(s, st, err);
}

static const bg_backend_ops_t agents_ops = {
    "agents",    session_new, session_destroy, fit_open,     fit_eval,     fit_hessian,
    solve_open,  solve_factor, solve,          solve_cost,   step_open,    step_predict,
    step_update, step_accept,  surface_open, surface_eval,
};

/* ---------------------------------------------------------------- backend */

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
    /* Several coordinators share agents: job ids start from this
     * process's id and the clock, so two jobs never meet on an agent. */
    b->base = ((uint64_t)getpid() << 20 | ((uint64_t)(bg_clock_now() * 1e3) & 0xfffffu)) << 20;
    if (cfg->job_base)
        b->base = cfg->job_base;
    b->nrotfit = cfg->nrotfit;
    for (int i = 0; i <= cfg->nrotfit; i++) {
        const char *ep = i < cfg->nrotfit ? cfg->rotfit[i] : cfg->solve;
        if (strlen(ep) >= BACKEND_ENDPOINT_MAX) {
            free(b);
            return bg_error_set(err, BG_ERR_INVALID, "agent endpoint too long: %.40s...", ep);
        }
        strcpy(b->place[i].endpoint, ep);
        b->place[i].base = b->base;
        b->usage[i].endpoint = b->place[i].endpoint;
        b->usage[i].service = i < cfg->nrotfit ? "rotation-fit" : "sparse-solve";
    }
    b->timeout_ms = cfg->timeout_ms;
    b->ping_ms = BGA_CLIENT_PING_MS;
    b->lost_ms = BGA_CLIENT_LOST_MS;
    b->lease_ms = cfg->lease_ms;
    b->curve = cfg->curve;
    b->services = (bg_backend_t){&agents_ops, b};
    *out = b;
    return BG_OK;
}

bg_status bga_backend_set_integ(bga_backend_t *b, const char *endpoint, bg_error_t *err)
{
    if (strlen(endpoint) >= BACKEND_ENDPOINT_MAX)
        return bg_error_set(err, BG_ERR_INVALID, "agent endpoint too long: %.40s...", endpoint);
    const int i = integ_place(b);
    strcpy(b->place[i].endpoint, endpoint);
    b->place[i].base = b->base;
    b->usage[i] = (bga_agent_usage_t){b->place[i].endpoint, "integration-step", 0, {0}};
    b->has_integ = 1;
    return BG_OK;
}

void bga_backend_set_recovery(bga_backend_t *b, const bga_backend_recovery_t *recovery)
{
    b->recover = recovery && recovery->replace;
    if (b->recover)
        b->recovery = *recovery;
    else
        memset(&b->recovery, 0, sizeof b->recovery);
}

void bga_backend_set_liveness(bga_backend_t *b, int ping_ms, int lost_ms)
{
    b->ping_ms = ping_ms;
    b->lost_ms = lost_ms;
}

void bga_backend_destroy(bga_backend_t **backend)
{
    if (!backend || !*backend)
        return;
    bga_backend_t *b = *backend;
    drain_given_up(b, 1);
    for (int i = 0; i < b->ngiven_up; i++)
        bga_client_destroy(&b->given_up[i].client);
    free(b);
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
    *usage = backend->usage[integ_place(backend)];
    return 1;
}

int bga_backend_replacements(const bga_backend_t *backend)
{
    return backend->replacements;
}

int64_t bga_backend_late_answers(bga_backend_t *backend)
{
    drain_given_up(backend, 1);
    return backend->late;
}
