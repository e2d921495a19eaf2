#include "bg_static.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_backend.h"
#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_sparse.h"

/* Armijo sufficient-decrease constant and the backtracking budget. */
#define STATIC_ARMIJO 1e-4
#define STATIC_MAX_BACKTRACKS 40
/* Energy differences below this many ulps of the energy's magnitude are
 * round-off: there a step is judged by the gradient norm instead. */
#define STATIC_ENERGY_NOISE_ULPS 64.0
/* Shifts tried when a Hessian fails to factor (relative to its mean diagonal). */
#define STATIC_FIRST_SHIFT 1e-10
#define STATIC_SHIFT_GROWTH 100.0
#define STATIC_MAX_SHIFTS 8
/* Newton tries the exact (unprojected) Hessian once the relative gradient
 * is below this, and falls back to the projected one when it does not
 * factor: clamping element twist modes that the assembled system does not
 * need clamped makes the method only linearly convergent, and on nearly
 * incompressible bodies (λ/μ ≥ 10⁴) with a rate close to 1 (the clamped
 * twist eigenvalues are of the order of the pressure λ(tr Y − 3), far
 * from 2μ). After a failed attempt (a wasted factorization) the exact
 * matrix is tried again once the gradient has halved or after a few
 * iterations, whichever comes first. Waiting for a full step and for the
 * gradient to halve, as this solver once did, left stiff solves on the
 * projected matrix for tens of iterations at a time (twisted bar,
 * λ/μ = 10⁵: 115 iterations and a false round-off stop). That is the
 * threshold for nearly incompressible bodies (λ > 100 μ); on the others
 * the projected matrix converges well until later, and the exact one's
 * steps taken earlier are poor: bunny-edit (λ = 10 μ) from 1e-1 on took
 * a step cut to 1/64 (six evaluations) and five more whose gradient
 * barely fell, 11 iterations; from 3e-2 on, 9 iterations and 40 % fewer
 * evaluations. The stiff bar's counts went up with the lower threshold
 * (twisted λ/μ = 10⁴ and 10⁵: 24 → 26 and 47 → 48), hence two. */
#define STATIC_EXACT_HESSIAN_BELOW 3e-2
#define STATIC_EXACT_HESSIAN_BELOW_STIFF 1e-1
#define STATIC_EXACT_RETRY_FACTOR 0.5
#define STATIC_EXACT_RETRY_AFTER 4
/* A step that changes the energy by no more than round-off and the
 * gradient by less than 1 % makes the solver look at the gradient's
 * round-off (below); it stops only if the gradient is there. */
#define STATIC_NO_PROGRESS 0.99
/* The round-off of a computed gradient: this many ulps of the magnitudes
 * it is summed from (bg_elastic_force_magnitude plus the load and inertia
 * terms), over the free coordinates. The magnitudes bound every term, so
 * the estimate is pessimistic by the square root of the number of terms;
 * the ulps cover the rotation fit's residual (BG_ROTFIT_SKEW_TOL = 45 ulps)
 * and the dozen operations per stress entry. A gradient at or below it is
 * noise: no method can say which way is down. */
#define STATIC_GRADIENT_NOISE_ULPS 16.0
/* While steps keep landing in the energy's round-off, the gradient's
 * round-off (one extra pass over the elements) is re-estimated at most
 * once per this many iterations. */
#define STATIC_NOISE_RECHECK 8
/* The absolute floor of the stopping test (DESIGN.md §1.5): a gradient this
 * small relative to the scene's force scale — (2μ + |λ|)·V/L for elastic
 * forces over a body of volume V and size L, plus the weight — is
 * converged whatever the relative test says (a start already at the
 * solution has a relative gradient of pure round-off). It sits a few
 * hundred ulps above round-off: a quasi-Newton solve lands just under its
 * stopping test rather than far below it as Newton does, and a time
 * integration conserves angular momentum only as well as its steps meet
 * this floor (bar-spin: 1e-9 over 1000 steps needs it below 1e-12). */
#define STATIC_ABSOLUTE_FLOOR 1e-13
/* Factor reuse (bg_solve_options_t.reuse_factor): L-BFGS keeps this many
 * curvature pairs on top of the last factored Newton matrix, and the matrix
 * is refactored when this many quasi-Newton steps in a row fail to lower
 * the best gradient norm seen since it was factored. The gradient of an
 * energy-decreasing L-BFGS run is not monotone, so a single rise is no
 * sign of a stale matrix; a factorization costs 10–30 quasi-Newton
 * iterations (rotation fit, gradient, two triangular solves) on the
 * bunny, so patience pays. Tuned on bunny-drop (tests/bench/bench_apps). */
#define STATIC_QN_PAIRS 20
/* The quasi-newton method (Liu, Bouaziz and Kavan 2017): L-BFGS with
 * local/global's prefactored Laplacian as the initial Hessian keeps this
 * many curvature pairs. An iteration costs a rotation fit, one block solve
 * and four passes over the free coordinates per pair. Iterations to 1e-8
 * with 3, 5, 8, 12, 20, 30 pairs: bunny-edit 189, 153, 140, 139, 117, 120;
 * inverted-bunny 1321, 626, 429, 529, 492, 334; bar-twist 60, 51, 50, 50,
 * 45, 45; the stiff bar 5,630 to 6,063 for 5 to 30. Beyond 8 the pairs
 * cost more passes than they save iterations. */
#define STATIC_LBFGS_PAIRS 8
/* Factors of quasi-newton's initial Hessian kept at once, one per inertia
 * coefficient c: (2μ + λ)L + cM. A static solve or a morph frame uses one
 * (c = 0); a time integration two, the midpoint rule's c = 4/h² and the
 * backward-Euler redo's c = 1/h² (bg_dynamics), which alternate whenever the
 * energy limiter redoes a step. A third coefficient replaces the factor used
 * longest ago. */
#define STATIC_LG_SLOTS 2
/* Chord steps (Shamanskii's variant of Newton's method): after a full
 * Newton step is accepted, up to this many (bg_solve_options_t.chord_steps)
 * further steps −A⁻¹∇W with the matrix A already factored, each kept only
 * if it meets the Armijo condition from where it starts (and, with
 * keep_orientation, inverts nothing). A chord step costs a triangular solve
 * and an evaluation, no assembly or factorization. On nearly
 * incompressible bodies a Newton step leaves a large residual in the
 * stiff volumetric modes (the curved constraint tr Y = 3 is left at second
 * order, times λ); the chord step removes most of it, and the next Newton
 * step starts from a point where the pressure, and so the Hessian's
 * geometric term, is consistent (stiff-bar twisted, λ/μ = 10⁴: 59
 * iterations without, 18 with). Not taken with an inertia term or factor
 * reuse, whose own L-BFGS steps already exploit the factor. */
#define STATIC_CHORD_STEPS 8
/* Chord steps are tried only after a full step whose energy decrease was
 * at least this fraction of the quadratic model's, ½∇Wᵀd (the factored
 * matrix predicts the landscape well enough for it to serve again). A
 * chord step that fails costs a solve and an evaluation for nothing. On
 * bunny-edit, where the exact Hessian's steps decrease the energy by 34 to
 * 84 % of the prediction for five iterations, every chord step tried
 * there failed; chord steps succeeded after steps at 102 % and 112 %.
 * On the stiff bar every Newton step does better than predicted (102 to
 * 180 %), so its chord steps, and its counts (8, 21, 24, 52, 47, 88
 * iterations), are unchanged. bunny-edit: 5 evaluations and 5 solves
 * fewer in its 11 iterations. */
#define STATIC_CHORD_MODEL_AGREEMENT 0.9
#define STATIC_REFACTOR_PATIENCE 5
/* The deterministic cost model behind the ski-rental refactoring rule, in
 * units of one flop of a triangular solve (memory bound): a supernodal
 * factorization flop runs about this many times faster (BLAS-3), and one
 * energy-and-gradient evaluation costs about this many units per element
 * (rotation fit, stress, scatter). Measured with CHOLMOD 3.0 + OpenBLAS on
 * the bunny (34k tets): factorization 3.0 Gflop in 0.2 s, solve 19 Mflop
 * in 6 ms, evaluation 1.5 ms. */
#define STATIC_FACTOR_FLOP_SPEEDUP 5.0
#define STATIC_EVALUATION_UNITS 140.0
/* Continuation in λ (bg_static_solve): used above this λ/μ; the first
 * stage at this many μ, λ multiplied by the growth factor each stage, and
 * the relative tolerance of every stage but the last. Newton from the
 * interpolated start of a nearly incompressible, locked P1 mesh crawls:
 * the stiff bar bent 90° at λ/μ = 10⁵ took 259 iterations with full steps
 * of 2–3·10⁻² on a positive definite exact Hessian, one short step at a
 * time along the volumetric constraint's curved valley. At λ = 10 μ the
 * same bar converges in 9 iterations, and each doubling of λ moves the
 * minimum little, so a few iterations per stage follow it. Measured on
 * the stiff bar (bent, twisted; λ/μ = 10³, 10⁴, 10⁵), total iterations
 * with doubling: 21, 52, 88 bent and 8, 24, 47 twisted (one solve: 81, 81,
 * 259 and 3, 18, 41). Other schedules, bent at 10⁵: growth √10 94, growth
 * 10 96 (stage tolerance 10⁻²) to 143 (10⁻¹); doubling with stage
 * tolerance 5·10⁻² 72, 2·10⁻¹ 121. The count at 10⁵ moves with the
 * schedule because stages can end in different local minima of this
 * non-convex, locked problem (tests/unit/test_stops.c checks each result
 * is a minimum); a first stage at λ = μ and growth 10 took 143. */
#define STATIC_CONTINUATION_ABOVE 100.0
#define STATIC_CONTINUATION_FIRST 10.0
#define STATIC_CONTINUATION_GROWTH 2.0
#define STATIC_CONTINUATION_TOLERANCE 1e-1

struct bg_solver {
    const bg_scene_t *scene;
    const bg_mesh_t *mesh;
    int n;
    size_t ndof;
    int32_t *free_index;
    int32_t nfree;
    double *gravity_force; /* ndof: m_v g, or NULL without gravity */
    bg_elastic_t *model;
    bg_mesh_t *target_mesh;        /* morphing: the second rest shape, or NULL */
    bg_elastic_t *target_model;    /* E(M1 → q) */
    double blend;                  /* W uses (1 − blend) E0 + blend E1 */
    double *grad_target;           /* ndof scratch for ∇E1 */
    bg_sparse_t *sys;              /* Newton: the free×free Hessian system */
    /* local/global, quasi-newton: one scalar matrix (2μ + λ)L + lg_c[k]·M
     * per coordinate, one set per slot k (backend system ids 1 + 3k + c) */
    bg_sparse_t *lg[STATIC_LG_SLOTS][3];
    double lg_c[STATIC_LG_SLOTS];  /* the inertia coefficient slot k's factors include */
    int lg_ready[STATIC_LG_SLOTS]; /* slot k's factors are current (blend, lg_c[k]) */
    int64_t lg_used[STATIC_LG_SLOTS]; /* the minimisation that last used slot k */
    int64_t lg_uses;               /* minimisations so far (the clock of lg_used) */
    int lg_slot;                   /* the slot lg_solve solves with */
    int32_t *lg_index[3];          /* per vertex: unknown of coordinate c, or −1 */
    int lg_system[3];              /* which lg[] serves coordinate c (equal free sets share) */
    double *lg_rhs, *lg_x;
    double lg_scale;               /* 2μ + λ */
    double *q, *q_trial, *grad, *grad_trial, *rhs, *step;
    double *mag;           /* ndof scratch: force magnitudes for the round-off estimate */
    double *chord_q, *chord_grad; /* ndof scratch: a chord step's trial point and gradient */
    double *mass;          /* nv lumped masses */
    double *inertia_diag;  /* nfree: c·m on the diagonal, while an inertia term is active */
    const bg_inertia_t *inertia; /* the active inertia term, or NULL */
    /* Factor reuse: sys holds a positive definite factorization built at
     * inertia coefficient factor_c (any such matrix is a valid L-BFGS
     * initial Hessian; a stale one only converges more slowly). The pairs
     * (s_k, y_k) live in free coordinates, qn_count of them, oldest at
     * qn_head. */
    int factor_ready;
    double factor_c;
    double qn_cost;         /* modelled cost of the quasi-Newton iterations on this factor */
    int qn_count, qn_head, qn_pairs; /* pairs held, oldest slot, capacity */
    double *qn_s, *qn_y, *qn_rho, *qn_alpha, *qn_grad; /* pairs, 1/yᵀs, scratch, ∇ (free) */
    bg_method method;
    double last_magnitude; /* |elastic| + |gravity work| + inertia of the last evaluation */
    int fitted_elsewhere;  /* the last evaluation was at a rejected chord step, not the
                              iterate: the model's energy density is not the iterate's */
    double rotfit_seconds; /* evaluations not yet reported (bg_solver_minimize, _report) */
    int mass_ready;        /* mass holds the lumped masses */
    double vector_seconds; /* vector work of the iterations, not yet reported */
    bg_setup_t setup;      /* set-up steps not yet reported */
    double force_floor;    /* absolute gradient floor */
    double energy_spread;  /* Σ |force terms|·|q| at the last round-off estimate */
    const bg_backend_t *backend; /* the basic services (borrowed) */
    void *session;               /* the backend's session for this solver */
    bg_status failed;            /* a basic service failed: every later result is void */
    bg_error_t fail_err;
};
typedef struct bg_solver problem_t;

void bg_setup_add(bg_setup_t *setup, const char *name, int64_t count, int64_t factorizations,
                  double seconds)
{
    int i = 0;
    while (i < setup->count && strcmp(setup->step[i].name, name) != 0)
        i++;
    if (i == setup->count) {
        if (setup->count == BG_SETUP_MAX_STEPS)
            i = BG_SETUP_MAX_STEPS - 1;
        else
            setup->step[setup->count++] = (bg_setup_step_t){name, 0, 0, 0.0};
    }
    setup->step[i].count += count;
    setup->step[i].factorizations += factorizations;
    setup->step[i].seconds += seconds;
    setup->factorizations += factorizations;
    setup->seconds += seconds;
}

void bg_setup_merge(bg_setup_t *into, const bg_setup_t *from)
{
    for (int i = 0; i < from->count; i++)
        bg_setup_add(into, from->step[i].name, from->step[i].count, from->step[i].factorizations,
                     from->step[i].seconds);
}

void bg_static_lumped_mass(const bg_mesh_t *mesh, double density, double *mass)
{
    const int k = mesh->nodes_per_element;
    memset(mass, 0, (size_t)mesh->nv * sizeof *mass);
    for (int32_t e = 0; e < mesh->ne; e++) {
        const double share = density * fabs(bg_mesh_element_measure(mesh, mesh->x, e)) / k;
        for (int i = 0; i < k; i++)
            mass[mesh->elements[(size_t)e * k + i]] += share;
    }
}

static void problem_release(problem_t *p)
{
    if (p->session)
        p->backend->ops->session_destroy(p->backend->ctx, p->session);
    free(p->free_index);
    free(p->gravity_force);
    bg_elastic_destroy(&p->model);
    bg_elastic_destroy(&p->target_model);
    bg_mesh_destroy(&p->target_mesh);
    free(p->grad_target);
    bg_sparse_destroy(&p->sys);
    for (int c = 0; c < 3; c++) {
        for (int k = 0; k < STATIC_LG_SLOTS; k++)
            bg_sparse_destroy(&p->lg[k][c]);
        free(p->lg_index[c]);
    }
    free(p->lg_rhs);
    free(p->lg_x);
    free(p->mass);
    free(p->inertia_diag);
    free(p->q);
    free(p->q_trial);
    free(p->grad);
    free(p->grad_trial);
    free(p->rhs);
    free(p->step);
    free(p->mag);
    free(p->chord_q);
    free(p->chord_grad);
    free(p->qn_s);
    free(p->qn_y);
    free(p->qn_rho);
    free(p->qn_alpha);
    free(p->qn_grad);
}

/*
 * Local/global's matrix (2μ + λ)·L ⊗ I_n with per-coordinate Dirichlet
 * sets is block diagonal: one scalar Laplacian per coordinate, each over
 * the vertices where that coordinate is free. Factoring n scalar systems
 * costs far less than one interleaved n-times-larger one (whose fill grows
 * with the square of the block size), and is done once per solve.
 */
/* Diagonal shifts tried when a matrix fails to factor: 0, then a small
 * multiple of its largest entry, growing geometrically. */
static double next_shift(const bg_sparse_t *sys, double shift)
{
    if (shift > 0.0)
        return shift * STATIC_SHIFT_GROWTH;
    const double *values = bg_sparse_values((bg_sparse_t *)sys);
    double largest = 0.0;
    for (size_t i = 0; i < bg_sparse_nonzeros(sys); i++)
        largest = fmax(largest, fabs(values[i]));
    return STATIC_FIRST_SHIFT * (largest > 0.0 ? largest : 1.0);
}

/* Factors the assembled matrix, adding a growing diagonal shift while it is
 * not numerically positive definite (a coordinate held nowhere leaves the
 * Laplacian singular). */
static bg_status factor_with_shift(problem_t *p, int id, bg_sparse_t *sys, bg_error_t *err)
{
    bg_error_t local = BG_ERROR_INIT;
    double shift = 0.0;
    for (int attempt = 0; attempt <= STATIC_MAX_SHIFTS; attempt++) {
        bg_error_clear(&local);
        bg_status st = p->backend->ops->solve_factor(p->session, id, shift, &local);
        if (st != BG_ERR_NUMERIC)
            return st == BG_OK ? BG_OK : bg_error_set(err, st, "%s", local.message);
        shift = next_shift(sys, shift);
    }
    return bg_error_set(err, BG_ERR_NUMERIC, "%s (even with a diagonal shift)", local.message);
}

/*
 * Assembles and factors slot k's matrices for the current blend of rest
 * shapes and inertia coefficient c: (1 − b)(2μ + λ)L0 + b(2μ + λ)L1 + c·M,
 * M the lumped masses of the free vertices (c > 0 needs bg_solver_mass).
 * A set-up step: once per solve or morph frame (c = 0), once per distinct
 * coefficient of a time integration. The inertia term makes the matrix of
 * a free body (bar-spin) positive definite: no shift is needed there.
 */
static bg_status lg_factor(problem_t *p, int k, double c, bg_error_t *err)
{
    const double t0 = bg_clock_now();
    int64_t before = 0;
    for (int j = 0; j < 3; j++)
        before += p->lg[k][j] ? bg_sparse_timing(p->lg[k][j]).factorizations : 0;
    bg_status st = BG_OK;
    const double b = p->target_model ? p->blend : 0.0;
    p->lg_ready[k] = 0;
    for (int j = 0; j < 3; j++) {
        bg_sparse_t *sys = p->lg[k][j];
        if (!sys)
            continue;
        bg_sparse_zero(sys);
        bg_elastic_assemble_scalar_laplacian(p->model, (1.0 - b) * p->lg_scale,
                                             bg_sparse_scatter(sys), bg_sparse_values(sys));
        if (p->target_model)
            bg_elastic_assemble_scalar_laplacian(p->target_model, b * p->lg_scale,
                                                 bg_sparse_scatter(sys), bg_sparse_values(sys));
        if (c > 0.0) {
            /* lg_x as the diagonal's scratch: it holds nothing between solves */
            const int32_t *idx = p->lg_index[j];
            for (int32_t v = 0; v < p->mesh->nv; v++)
                if (idx[v] >= 0)
                    p->lg_x[idx[v]] = c * p->mass[v];
            bg_sparse_add_diagonal(sys, p->lg_x);
        }
        st = factor_with_shift(p, 1 + 3 * k + j, sys, err);
        if (st != BG_OK)
            break;
    }
    int64_t after = 0;
    for (int j = 0; j < 3; j++)
        after += p->lg[k][j] ? bg_sparse_timing(p->lg[k][j]).factorizations : 0;
    p->lg_ready[k] = st == BG_OK;
    p->lg_c[k] = c;
    bg_setup_add(&p->setup,
                 c > 0.0 ? "quasi-newton: the Laplacian plus the inertia term c M (its initial "
                           "Hessian in a time step) assembled and factored, once per c"
                 : p->method == BG_METHOD_QUASI_NEWTON
                     ? "quasi-newton: the Laplacian (its initial Hessian) assembled and factored"
                     : "local/global: the Laplacian assembled and factored",
                 1, after - before, bg_clock_now() - t0);
    return st;
}

/* Slot k's systems: the patterns of slot 0's (the coordinates that share
 * one there share one here), opened with the backend. */
static bg_status lg_open_slot(problem_t *p, int k, bg_error_t *err)
{
    for (int c = 0; c < p->n; c++) {
        if (!p->lg[0][c] || p->lg[k][c])
            continue;
        const int32_t size = bg_sparse_size(p->lg[0][c]);
        bg_status st = bg_sparse_new(p->mesh, 1, p->lg_index[c], size, &p->lg[k][c], err);
        if (st == BG_OK) {
            bg_sparse_prefer_solves(p->lg[k][c]);
            st = p->backend->ops->solve_open(p->session, 1 + 3 * k + c, p->lg[k][c], err);
        }
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

/*
 * Makes lg_solve use a factor of (2μ + λ)L + c·M: the slot that holds one,
 * else a slot never used or the one used longest ago, (re)factored. Called
 * at the start of a minimisation, never inside its iterations: the
 * factorization is a set-up step, not an iteration's.
 */
static bg_status lg_use(problem_t *p, double c, bg_error_t *err)
{
    p->lg_uses++;
    int k = -1;
    for (int j = 0; j < STATIC_LG_SLOTS && k < 0; j++)
        if (p->lg_ready[j] && p->lg_c[j] == c)
            k = j;
    if (k < 0) {
        k = 0;
        for (int j = 1; j < STATIC_LG_SLOTS; j++)
            if (p->lg_used[j] < p->lg_used[k])
                k = j;
        bg_status st = lg_open_slot(p, k, err);
        if (st == BG_OK)
            st = lg_factor(p, k, c, err);
        if (st != BG_OK)
            return st;
    }
    p->lg_slot = k;
    p->lg_used[k] = p->lg_uses;
    return BG_OK;
}

static bg_status lg_init(problem_t *p, const bg_scene_t *scene, bg_error_t *err)
{
    const int32_t nv = p->mesh->nv;
    /* Room for every coordinate of one system side by side: the
     * coordinates that share a Laplacian are solved as one block. */
    p->lg_rhs = malloc((3 * (size_t)nv + 1) * sizeof *p->lg_rhs);
    p->lg_x = malloc((3 * (size_t)nv + 1) * sizeof *p->lg_x);
    if (!p->lg_rhs || !p->lg_x)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for local/global");
    const double scale = 2.0 * scene->material.mu + scene->material.lambda;
    for (int c = 0; c < p->n; c++) {
        p->lg_index[c] = malloc(((size_t)nv + 1) * sizeof *p->lg_index[c]);
        if (!p->lg_index[c])
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for local/global");
        int32_t count = 0;
        for (int32_t v = 0; v < nv; v++)
            p->lg_index[c][v] = scene->constrained[(size_t)v * p->n + c] ? -1 : count++;
        p->lg_system[c] = c;
        if (count == 0)
            continue; /* this coordinate is prescribed everywhere */
        for (int prev = 0; prev < c; prev++)
            if (p->lg[0][prev] &&
                memcmp(p->lg_index[prev], p->lg_index[c], (size_t)nv * sizeof(int32_t)) == 0)
                p->lg_system[c] = prev;
        if (p->lg_system[c] != c)
            continue; /* same free vertices as an earlier coordinate: same matrix */
        bg_status st = bg_sparse_new(p->mesh, 1, p->lg_index[c], count, &p->lg[0][c], err);
        if (st == BG_OK) {
            bg_sparse_prefer_solves(p->lg[0][c]); /* factored once, solved every iteration */
            st = p->backend->ops->solve_open(p->session, 1 + c, p->lg[0][c], err);
        }
        if (st != BG_OK)
            return st;
    }
    p->lg_scale = scale;
    /* A dynamic scene's steps factor the matrix with their inertia term
     * (lg_use); a static solve's c = 0 factor would go unused. */
    return scene->task == BG_TASK_DYNAMIC ? BG_OK : lg_factor(p, 0, 0.0, err);
}

static bg_status problem_init(problem_t *p, const bg_scene_t *scene, bg_method method,
                              const bg_backend_t *backend, bg_error_t *err)
{
    memset(p, 0, sizeof *p);
    p->method = method;
    p->backend = backend ? backend : bg_backend_local();
    p->scene = scene;
    p->mesh = scene->mesh;
    p->n = scene->mesh->dim;
    p->ndof = (size_t)scene->mesh->nv * (size_t)p->n;
    p->free_index = malloc(p->ndof * sizeof *p->free_index + 1);
    p->q = malloc(p->ndof * sizeof *p->q + 1);
    p->q_trial = malloc(p->ndof * sizeof *p->q + 1);
    p->grad = malloc(p->ndof * sizeof *p->q + 1);
    p->grad_trial = malloc(p->ndof * sizeof *p->q + 1);
    p->rhs = malloc(p->ndof * sizeof *p->q + 1);
    p->step = malloc(p->ndof * sizeof *p->q + 1);
    p->mag = malloc(p->ndof * sizeof *p->q + 1);
    p->chord_q = malloc(p->ndof * sizeof *p->q + 1);
    p->chord_grad = malloc(p->ndof * sizeof *p->q + 1);
    if (!p->free_index || !p->q || !p->q_trial || !p->grad || !p->grad_trial || !p->rhs ||
        !p->step || !p->mag || !p->chord_q || !p->chord_grad)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory setting up the solve");
    for (size_t i = 0; i < p->ndof; i++)
        p->free_index[i] = scene->constrained[i] ? -1 : p->nfree++;
    if (p->nfree == 0)
        return bg_error_set(err, BG_ERR_INVALID,
                            "%s: every coordinate is constrained by the handles: nothing to solve",
                            scene->path);
    p->mass = malloc((size_t)p->mesh->nv * sizeof *p->mass + 1);
    p->inertia_diag = malloc((size_t)p->nfree * sizeof *p->inertia_diag + 1);
    if (!p->mass || !p->inertia_diag)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the mass matrix");
    const double *gv = scene->gravity;
    /* The masses are built only for a load (here) or an inertia term
     * (bg_solver_mass): the plan promises a static scene without gravity
     * none. */
    if (gv[0] != 0.0 || gv[1] != 0.0 || (p->n == 3 && gv[2] != 0.0)) {
        bg_solver_mass(p);
        p->gravity_force = malloc(p->ndof * sizeof *p->gravity_force + 1);
        if (!p->gravity_force)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the gravity load");
        for (int32_t v = 0; v < p->mesh->nv; v++)
            for (int c = 0; c < p->n; c++)
                p->gravity_force[(size_t)v * p->n + c] = p->mass[v] * gv[c];
    }
    double lo[3], hi[3], diagonal = 0.0, weight = 0.0;
    bg_mesh_bounds(p->mesh, lo, hi);
    for (int c = 0; c < p->n; c++)
        diagonal += (hi[c] - lo[c]) * (hi[c] - lo[c]);
    if (p->gravity_force)
        for (size_t i = 0; i < p->ndof; i++)
            weight += p->gravity_force[i] * p->gravity_force[i];
    const double modulus = 2.0 * scene->material.mu + fabs(scene->material.lambda);
    bg_status st =
        scene->rest_edges
            ? bg_elastic_new_from_rest(p->mesh, p->n, scene->rest_edges, scene->material.mu,
                                       scene->material.lambda, &p->model, err)
            : bg_elastic_new(p->mesh, scene->material.mu, scene->material.lambda, &p->model, err);
    if (st != BG_OK)
        return st;
    if (scene->task == BG_TASK_PARAMETERIZE)
        bg_elastic_set_barrier(p->model, scene->barrier * scene->material.mu);
    st = p->backend->ops->session_new(p->backend->ctx, &p->session, err);
    if (st != BG_OK)
        return st;
    p->force_floor = STATIC_ABSOLUTE_FLOOR *
                     (modulus * bg_elastic_total_volume(p->model) / fmax(sqrt(diagonal), 1e-300) +
                      sqrt(weight));
    bg_backend_fit_t fit = {p->model,
                            p->mesh,
                            scene->rest_edges,
                            scene->material.mu,
                            scene->material.lambda,
                            scene->task == BG_TASK_PARAMETERIZE ? scene->barrier * scene->material.mu
                                                                : 0.0,
                            NULL,
                            0};
    if (method != BG_METHOD_NEWTON) {
        st = p->backend->ops->fit_open(p->session, 0, &fit, err);
        return st == BG_OK ? lg_init(p, scene, err) : st;
    }
    st = bg_sparse_new(p->mesh, p->n, p->free_index, p->nfree, &p->sys, err);
    if (st != BG_OK)
        return st;
    fit.scatter = bg_sparse_scatter(p->sys);
    fit.nval = bg_sparse_nonzeros(p->sys);
    st = p->backend->ops->solve_open(p->session, 0, p->sys, err);
    return st == BG_OK ? p->backend->ops->fit_open(p->session, 0, &fit, err) : st;
}

/* The Hessian is stored in its factor's order, so that no factorization
 * permutes it (bg_sparse_reorder: the symbolic analysis, once, before the
 * first assembly), whatever backend computes in this process (the local
 * one, or one wrapping it); the agents' backend has done it at solve_open,
 * before the scatter map went to the rotation-fit agents, and ships the
 * reordered pattern: then this is a no-op. The in-process backend also
 * gets the vertex-block map in the model's element order (its assembly's
 * fast path); agents assemble through the entry map they were sent. */
static bg_status newton_order(problem_t *p, bg_error_t *err)
{
    bg_status st = bg_sparse_reorder(p->sys, err);
    if (st == BG_OK && p->backend == bg_backend_local())
        st = bg_sparse_order_tet_blocks(p->sys, bg_elastic_order(p->model), err);
    return st;
}

/* problem_init, with its time (less the mass and the Laplacian factoring,
 * which record themselves) as the "solver set-up" step. */
static bg_status problem_setup(problem_t *p, const bg_scene_t *scene, bg_method method,
                               const bg_backend_t *backend, bg_error_t *err)
{
    const double t0 = bg_clock_now();
    bg_status st = problem_init(p, scene, method, backend, err);
    /* A backend that renumbers the Hessian at solve_open (the agents')
     * counts that analysis in the system's own timing, as analysis. */
    const double analyzed = st == BG_OK && p->sys ? bg_sparse_timing(p->sys).analyze_seconds : 0.0;
    bg_setup_add(&p->setup,
                 method == BG_METHOD_NEWTON
                     ? "solver set-up: elastic model, Hessian pattern and scatter map"
                     : "solver set-up: elastic model, Laplacian patterns",
                 1, 0, bg_clock_now() - t0 - p->setup.seconds - analyzed);
    if (st != BG_OK || !p->sys)
        return st;
    /* Newton's symbolic analysis depends on the pattern alone: a set-up
     * step, as local/global's Laplacian factorization is, not part of the
     * first iteration (it was: time-to-accuracy curves charged Newton for
     * it and local/global not; the agents' backend has always done it at
     * solve_open, and its time was reported nowhere). */
    const double t1 = bg_clock_now();
    st = newton_order(p, err);
    bg_setup_add(&p->setup, BG_SETUP_NEWTON_ANALYSIS, 1, 0, analyzed + bg_clock_now() - t1);
    return st;
}

/* Records the first failure of a basic service (the solve then stops with it). */
static void service_failed(problem_t *p, bg_status st, const bg_error_t *e)
{
    if (p->failed == BG_OK) {
        p->failed = st;
        bg_error_set(&p->fail_err, st, "%s", e->message);
    }
}

/* Rotation-fit id at q: the energy, NaN when the service failed. */
static double fit_eval(problem_t *p, int id, const double *q, double *grad)
{
    bg_error_t e = BG_ERROR_INIT;
    double energy = NAN;
    const bg_status st = p->backend->ops->fit_eval(p->session, id, q, &energy, grad, &e);
    if (st != BG_OK) {
        service_failed(p, st, &e);
        return NAN;
    }
    return energy;
}

/* W(q) and its full gradient into grad (NaN when a basic service failed). */
static double potential(problem_t *p, const double *q, double *grad)
{
    const double t0 = bg_clock_now();
    p->fitted_elsewhere = 0;
    double elastic = fit_eval(p, 0, q, grad);
    if (p->target_model) {
        const double b = p->blend, e1 = fit_eval(p, 1, q, p->grad_target);
        elastic = (1.0 - b) * elastic + b * e1;
        for (size_t i = 0; i < p->ndof; i++)
            grad[i] = (1.0 - b) * grad[i] + b * p->grad_target[i];
    }
    double work = 0.0, magnitude = fabs(elastic);
    if (p->gravity_force) {
        for (size_t i = 0; i < p->ndof; i++) {
            work += p->gravity_force[i] * q[i];
            grad[i] -= p->gravity_force[i];
            magnitude += fabs(p->gravity_force[i] * q[i]);
        }
    }
    double kinetic = 0.0, spread = 0.0;
    if (p->inertia) {
        const bg_inertia_t *in = p->inertia;
        for (int32_t v = 0; v < p->mesh->nv; v++)
            for (int c = 0; c < p->n; c++) {
                const size_t i = (size_t)v * p->n + c;
                const double d = q[i] - in->y[i], f = in->c * p->mass[v] * d;
                kinetic += 0.5 * f * d;
                grad[i] += f;
                /* d carries the round-off of |q| + |y|, f·d that times |f| */
                spread += fabs(f) * (fabs(q[i]) + fabs(in->y[i]));
            }
        magnitude += kinetic + spread;
    }
    p->last_magnitude = magnitude;
    p->rotfit_seconds += bg_clock_now() - t0;
    return elastic - work + kinetic;
}

/* Round-off in an energy value W: a few ulps of the magnitude of the terms
 * it was summed from (the last evaluation's), and of Σ|P||F| over the
 * elements: ψ = μ|F − R|² + … is computed from F and R, not from their
 * small difference, so near the minimum its error is ε|P||F|, far above
 * ε ψ. Σ_i m_i |q_i| from the last round-off estimate stands for that
 * (the element force magnitudes times the positions they act on). */
static double energy_noise(const problem_t *p, double W)
{
    return STATIC_ENERGY_NOISE_ULPS * DBL_EPSILON *
           (fmax(p->last_magnitude, fabs(W)) + p->energy_spread);
}

/*
 * The round-off of the free gradient at q (DESIGN.md §1.5 stopping):
 * STATIC_GRADIENT_NOISE_ULPS ε ‖m‖ over the free coordinates, m the sum of
 * the magnitudes of every term of each gradient entry (element forces of
 * both rest shapes when morphing, the load, the inertia term). It also
 * refreshes energy_spread = Σ m_i |q_i|, the energy's own round-off scale
 * (energy_noise). *total gets
 * ‖m‖ over all coordinates (a force scale of the state). Counted as
 * evaluation time.
 */
static double gradient_noise(problem_t *p, const double *q, double *total)
{
    const double t0 = bg_clock_now();
    memset(p->mag, 0, p->ndof * sizeof *p->mag);
    const double b = p->target_model ? p->blend : 0.0;
    bg_elastic_force_magnitude(p->model, q, 1.0 - b, p->mag);
    if (p->target_model)
        bg_elastic_force_magnitude(p->target_model, q, b, p->mag);
    if (p->gravity_force)
        for (size_t i = 0; i < p->ndof; i++)
            p->mag[i] += fabs(p->gravity_force[i]);
    /* The inertia force c m (q − y) is a difference of the terms c m q and
     * c m y: its round-off scales with their magnitudes, not with the small
     * difference (one ulp of q moves it by c m ulp(q), which at a small
     * time step can exceed what a tight tolerance asks for). */
    if (p->inertia)
        for (size_t i = 0; i < p->ndof; i++)
            p->mag[i] += p->inertia->c * p->mass[i / (size_t)p->n] *
                         (fabs(q[i]) + fabs(p->inertia->y[i]));
    double free2 = 0.0, all2 = 0.0, spread = 0.0;
    for (size_t i = 0; i < p->ndof; i++) {
        all2 += p->mag[i] * p->mag[i];
        spread += p->mag[i] * fabs(q[i]);
        if (p->free_index[i] >= 0)
            free2 += p->mag[i] * p->mag[i];
    }
    if (total)
        *total = sqrt(all2);
    p->energy_spread = spread;
    p->rotfit_seconds += bg_clock_now() - t0;
    return STATIC_GRADIENT_NOISE_ULPS * DBL_EPSILON * sqrt(free2);
}

int64_t bg_static_count_inverted(const bg_mesh_t *mesh, const double *q)
{
    int64_t count = 0;
    for (int32_t e = 0; e < mesh->ne; e++)
        count += !(bg_mesh_element_measure(mesh, q, e) > 0.0);
    return count;
}

/* Whether positions q invert (or flatten) any element. */
static int inverts(const problem_t *p, const double *q)
{
    for (int32_t e = 0; e < p->mesh->ne; e++)
        if (!(bg_mesh_element_measure(p->mesh, q, e) > 0.0))
            return 1;
    return 0;
}

static double free_norm(const problem_t *p, const double *grad)
{
    double s = 0.0;
    for (size_t i = 0; i < p->ndof; i++)
        if (p->free_index[i] >= 0)
            s += grad[i] * grad[i];
    return sqrt(s);
}

static double relative_error(const double *q, const double *ref, size_t ndof)
{
    if (!ref)
        return NAN;
    double num = 0.0, den = 0.0;
    for (size_t i = 0; i < ndof; i++) {
        num += (q[i] - ref[i]) * (q[i] - ref[i]);
        den += ref[i] * ref[i];
    }
    return den > 0.0 ? sqrt(num / den) : sqrt(num);
}

/*
 * The error of the next trace point, at q: against the reference, or, while
 * one computed alongside is not ready (options->reference_ready), NaN with
 * q kept as the next pending row. The rows are a prefix of the trace: a
 * point after one that was measured is never kept. Past
 * BG_STATIC_PENDING_BYTES the solve waits for the reference instead.
 */
static bg_status trace_error(const bg_solve_options_t *opt, const double *q, size_t ndof,
                             bg_solve_result_t *res, int *pending_cap, double *error)
{
    const double *ref = opt->reference;
    if (!ref && opt->reference_ready) {
        ref = opt->reference_ready(opt->reference_ctx, 0);
        if (!ref && (size_t)(res->pending_count + 1) * ndof * sizeof *q > BG_STATIC_PENDING_BYTES)
            ref = opt->reference_ready(opt->reference_ctx, 1);
        if (!ref && res->pending_count == res->trace_count &&
            (size_t)(res->pending_count + 1) * ndof * sizeof *q <= BG_STATIC_PENDING_BYTES) {
            if (res->pending_count == *pending_cap) {
                const int grown = *pending_cap ? 2 * *pending_cap : 8;
                double *rows = realloc(res->pending, (size_t)grown * ndof * sizeof *rows);
                if (!rows)
                    return BG_ERR_NOMEM;
                res->pending = rows;
                *pending_cap = grown;
            }
            memcpy(res->pending + (size_t)res->pending_count * ndof, q, ndof * sizeof *q);
            res->pending_count++;
        }
    }
    *error = relative_error(q, ref, ndof);
    return BG_OK;
}

void bg_static_fill_errors(bg_solve_result_t *r, const double *ref, size_t ndof)
{
    for (int k = 0; k < r->pending_count && k < r->trace_count; k++)
        r->trace[k].error = relative_error(r->pending + (size_t)k * ndof, ref, ndof);
    free(r->pending);
    r->pending = NULL;
    r->pending_count = 0;
}

static bg_status push_trace(bg_solve_result_t *r, int *cap, const bg_trace_point_t *pt)
{
    if (r->trace_count == *cap) {
        int grown = *cap ? 2 * *cap : 64;
        bg_trace_point_t *t = realloc(r->trace, (size_t)grown * sizeof *t);
        if (!t)
            return BG_ERR_NOMEM;
        r->trace = t;
        *cap = grown;
    }
    r->trace[r->trace_count++] = *pt;
    return BG_OK;
}

/*
 * out = (c L)⁻¹ r on the free coordinates (r and out: nfree values, may
 * not alias): local/global's fixed matrix, block diagonal with one scalar
 * Laplacian per coordinate. The coordinates that share a Laplacian (the
 * same free vertices: usually all three) go to it as one block of
 * right-hand sides, so the factor is streamed from memory once per
 * iteration instead of once per coordinate, and an agent is asked once.
 */
static bg_status lg_solve(problem_t *p, const double *restrict r, double *restrict out,
                          bg_error_t *err)
{
    const int32_t nv = p->mesh->nv;
    for (int s = 0; s < p->n; s++) {
        bg_sparse_t *sys = p->lg[p->lg_slot][s];
        if (!sys)
            continue;
        const size_t size = (size_t)bg_sparse_size(sys);
        int cols[3], ncols = 0;
        for (int c = 0; c < p->n; c++)
            if (p->lg_system[c] == s)
                cols[ncols++] = c;
        double tv = bg_clock_now();
        for (int k = 0; k < ncols; k++) {
            const int c = cols[k];
            const int32_t *idx = p->lg_index[c];
            double *col = p->lg_rhs + (size_t)k * size;
            for (int32_t v = 0; v < nv; v++)
                if (idx[v] >= 0)
                    col[idx[v]] = r[p->free_index[(size_t)v * p->n + c]];
        }
        p->vector_seconds += bg_clock_now() - tv;
        bg_status st = p->backend->ops->solve(p->session, 1 + 3 * p->lg_slot + s, ncols,
                                              p->lg_rhs, p->lg_x, err);
        if (st != BG_OK)
            return st;
        tv = bg_clock_now();
        for (int k = 0; k < ncols; k++) {
            const int c = cols[k];
            const int32_t *idx = p->lg_index[c];
            const double *col = p->lg_x + (size_t)k * size;
            for (int32_t v = 0; v < nv; v++)
                if (idx[v] >= 0)
                    out[p->free_index[(size_t)v * p->n + c]] = col[idx[v]];
        }
        p->vector_seconds += bg_clock_now() - tv;
    }
    return BG_OK;
}

/* out = H₀⁻¹ r (free coordinates): the factored Newton matrix when the
 * solver has one (Newton's factor reuse), else local/global's Laplacian
 * (local/global, and quasi-Newton's initial Hessian). */
static bg_status apply_h0(problem_t *p, const double *r, double *out, bg_error_t *err)
{
    return p->sys ? p->backend->ops->solve(p->session, 0, 1, r, out, err)
                  : lg_solve(p, r, out, err);
}

/* d = H₀⁻¹ rhs into p->step with the current factorization; *slope = ∇Wᵀd
 * (= −rhsᵀd), NaN if d is not finite. */
static bg_status solve_direction(problem_t *p, double *slope, bg_error_t *err)
{
    bg_status st = apply_h0(p, p->rhs, p->step, err);
    if (st != BG_OK)
        return st;
    const double tv = bg_clock_now();
    double s = 0.0;
    for (int32_t i = 0; i < p->nfree; i++)
        s -= p->rhs[i] * p->step[i];
    *slope = isfinite(s) ? s : NAN;
    p->vector_seconds += bg_clock_now() - tv;
    return BG_OK;
}

/* The Newton matrix at p->q into p->sys's values; its time. */
static double assemble_newton(problem_t *p, int project, bg_error_t *err)
{
    const double t0 = bg_clock_now();
    bg_sparse_zero(p->sys);
    const double b = p->target_model ? p->blend : 0.0;
    const bg_backend_ops_t *ops = p->backend->ops;
    bg_status st = ops->fit_hessian(p->session, 0, p->q, project, 1.0 - b,
                                    bg_sparse_values(p->sys), err);
    if (st == BG_OK && p->target_model)
        st = ops->fit_hessian(p->session, 1, p->q, project, b, bg_sparse_values(p->sys), err);
    if (st != BG_OK)
        service_failed(p, st, err);
    if (p->inertia)
        bg_sparse_add_diagonal(p->sys, p->inertia_diag);
    return bg_clock_now() - t0;
}

/*
 * A Newton direction, most accurate first: the exact Hessian (when asked:
 * near the solution, where it gives quadratic convergence), else the
 * PSD-projected one, else the projected one with a growing diagonal shift.
 * The first factorization that succeeds and yields a finite descent
 * direction wins; at collapsed or random states the exact matrix can factor
 * yet give garbage, which the descent test catches.
 */
static bg_status newton_direction(problem_t *p, int try_exact, bg_solve_result_t *res,
                                  double *slope, bg_error_t *err)
{
    bg_error_t local = BG_ERROR_INIT;
    bg_status st;
    *slope = NAN;
    if ((st = newton_order(p, err)) != BG_OK) /* done at set-up: a no-op */
        return st;
    p->factor_ready = 0;
    p->factor_c = p->inertia ? p->inertia->c : 0.0;
    p->qn_count = p->qn_head = 0;
    if (try_exact) {
        res->assembly_seconds += assemble_newton(p, 0, err);
        if (p->failed != BG_OK)
            return p->failed;
        st = p->backend->ops->solve_factor(p->session, 0, 0.0, &local);
        if (st == BG_OK) {
            st = solve_direction(p, slope, err);
            if (st != BG_OK)
                return st;
            if (*slope < 0.0) {
                res->last_direction = BG_DIRECTION_EXACT;
                p->factor_ready = 1;
                return BG_OK;
            }
        } else if (st != BG_ERR_NUMERIC) {
            return bg_error_set(err, st, "%s", local.message);
        }
    }
    res->assembly_seconds += assemble_newton(p, 1, err);
    if (p->failed != BG_OK)
        return p->failed;
    double shift = 0.0;
    for (int attempt = 0; attempt <= STATIC_MAX_SHIFTS; attempt++) {
        bg_error_clear(&local);
        st = p->backend->ops->solve_factor(p->session, 0, shift, &local);
        if (st == BG_OK) {
            st = solve_direction(p, slope, err);
            if (st != BG_OK)
                return st;
            if (*slope < 0.0) {
                res->last_direction = shift > 0.0 ? BG_DIRECTION_SHIFTED : BG_DIRECTION_PROJECTED;
                p->factor_ready = 1;
                return BG_OK;
            }
        } else if (st != BG_ERR_NUMERIC) {
            return bg_error_set(err, st, "%s", local.message);
        }
        shift = next_shift(p->sys, shift);
    }
    res->last_direction = BG_DIRECTION_NONE;
    return BG_OK;
}

static void swap_arrays(double **a, double **b)
{
    double *t = *a;
    *a = *b;
    *b = t;
}

/*
 * Chord steps from the accepted point in q_trial/grad_trial (*W, *g): each
 * solves with the current factorization, takes the whole step and keeps it
 * when W falls by the Armijo fraction of its slope; the first that does
 * not, one that inverts an element when keep_orientation, or a gradient
 * at or below g_stop, ends them. On return q_trial,
 * grad_trial, *W and *g describe the last kept point; *taken counts the
 * kept steps. A rejected step leaves the model's rotations at the point
 * it tried (fitted_elsewhere): they serve only as warm starts, since the
 * next Hessian is assembled after refitting them at the iterate
 * (bg_elastic_assemble_hessian takes settled rotations as they are and
 * refits the others, an agent evaluates first), so evaluating the kept
 * point again, as this once did, cost an evaluation per iteration for
 * nothing; minimize evaluates once at the end if the result's energy
 * density needs it.
 */
static bg_status chord_steps(problem_t *p, int most, double g_stop, int keep_orientation,
                             double *W, double *g, int *taken, bg_error_t *err)
{
    *taken = 0;
    for (int k = 0; k < most && *g > g_stop; k++) {
        double tv = bg_clock_now();
        for (size_t i = 0; i < p->ndof; i++)
            if (p->free_index[i] >= 0)
                p->rhs[p->free_index[i]] = -p->grad_trial[i];
        p->vector_seconds += bg_clock_now() - tv;
        double slope = NAN;
        bg_status st = solve_direction(p, &slope, err);
        if (st != BG_OK)
            return st;
        if (!(slope < 0.0))
            return BG_OK;
        tv = bg_clock_now();
        for (size_t i = 0; i < p->ndof; i++) {
            const int32_t f = p->free_index[i];
            p->chord_q[i] = f >= 0 ? p->q_trial[i] + p->step[f] : p->q_trial[i];
        }
        const int flips = keep_orientation && inverts(p, p->chord_q);
        p->vector_seconds += bg_clock_now() - tv;
        if (flips)
            return BG_OK; /* nothing evaluated: the rotations are still the kept point's */
        const double W_c = potential(p, p->chord_q, p->chord_grad);
        if (p->failed != BG_OK)
            return BG_OK;
        tv = bg_clock_now();
        const double g_c = free_norm(p, p->chord_grad);
        p->vector_seconds += bg_clock_now() - tv;
        /* Kept as the line search keeps a trial: by the Armijo fraction,
         * or, once the energy's fall is within its round-off, when it
         * stays within that and the gradient falls. Near the solution the
         * Armijo test alone compares W to an ulp: a coin toss, which a job
         * on agents (its partitions' energies summed in another order)
         * lost on bunny-edit, so it took a tenth iteration for the chord
         * step in process had taken. */
        if (!(W_c <= *W + STATIC_ARMIJO * slope || (W_c <= *W + energy_noise(p, *W) && g_c < *g))) {
            p->fitted_elsewhere = 1;
            return BG_OK;
        }
        swap_arrays(&p->q_trial, &p->chord_q);
        swap_arrays(&p->grad_trial, &p->chord_grad);
        *W = W_c;
        *g = g_c;
        ++*taken;
    }
    return BG_OK;
}

/* The L-BFGS history: STATIC_QN_PAIRS pairs for Newton's factor reuse,
 * STATIC_LBFGS_PAIRS for the quasi-newton method; allocated once per
 * solver. */
static bg_status qn_alloc(problem_t *p, bg_error_t *err)
{
    if (p->qn_s)
        return BG_OK;
    const size_t nf = (size_t)p->nfree;
    const size_t m = p->method == BG_METHOD_QUASI_NEWTON ? STATIC_LBFGS_PAIRS : STATIC_QN_PAIRS;
    p->qn_pairs = (int)m;
    p->qn_s = malloc(m * nf * sizeof *p->qn_s + 1);
    p->qn_y = malloc(m * nf * sizeof *p->qn_y + 1);
    p->qn_rho = malloc(m * sizeof *p->qn_rho);
    p->qn_alpha = malloc(m * sizeof *p->qn_alpha);
    p->qn_grad = malloc(nf * sizeof *p->qn_grad + 1);
    if (!p->qn_s || !p->qn_y || !p->qn_rho || !p->qn_alpha || !p->qn_grad)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the quasi-Newton history");
    return BG_OK;
}

/* ∇W on the free coordinates, into out (nfree). */
static void gather_free(const problem_t *p, const double *grad, double *out)
{
    for (size_t i = 0; i < p->ndof; i++)
        if (p->free_index[i] >= 0)
            out[p->free_index[i]] = grad[i];
}

/*
 * L-BFGS direction (two-loop recursion) with the factored Newton matrix as
 * the initial Hessian: d = −H⁻¹∇W. p->rhs holds −∇W (free) on entry and is
 * overwritten; p->qn_grad holds ∇W (free). *slope = ∇Wᵀd.
 */
static bg_status qn_direction(problem_t *p, double *slope, bg_error_t *err)
{
    const size_t nf = (size_t)p->nfree;
    double tv = bg_clock_now();
    double *r = p->rhs;
    for (int k = p->qn_count - 1; k >= 0; k--) {
        const int slot = (p->qn_head + k) % p->qn_pairs;
        const double *sk = p->qn_s + (size_t)slot * nf, *yk = p->qn_y + (size_t)slot * nf;
        double a = 0.0;
        for (size_t i = 0; i < nf; i++)
            a += sk[i] * r[i];
        a *= p->qn_rho[slot];
        p->qn_alpha[slot] = a;
        for (size_t i = 0; i < nf; i++)
            r[i] -= a * yk[i];
    }
    p->vector_seconds += bg_clock_now() - tv;
    bg_status st = apply_h0(p, r, p->step, err);
    if (st != BG_OK)
        return st;
    tv = bg_clock_now();
    double *d = p->step;
    for (int k = 0; k < p->qn_count; k++) {
        const int slot = (p->qn_head + k) % p->qn_pairs;
        const double *sk = p->qn_s + (size_t)slot * nf, *yk = p->qn_y + (size_t)slot * nf;
        double b = 0.0;
        for (size_t i = 0; i < nf; i++)
            b += yk[i] * d[i];
        b = p->qn_alpha[slot] - p->qn_rho[slot] * b;
        for (size_t i = 0; i < nf; i++)
            d[i] += b * sk[i];
    }
    double s = 0.0;
    for (size_t i = 0; i < nf; i++)
        s += p->qn_grad[i] * d[i];
    *slope = isfinite(s) ? s : NAN;
    p->vector_seconds += bg_clock_now() - tv;
    return BG_OK;
}

/* Records the pair (s, y) = (α d, ∇W_new − ∇W_old) when it has positive
 * curvature (yᵀs > 0 keeps the L-BFGS matrix positive definite); p->qn_grad
 * holds the old free gradient on entry and the new one on return. */
static void qn_push(problem_t *p, double alpha, const double *grad_new)
{
    const size_t nf = (size_t)p->nfree;
    const int slot = (p->qn_head + p->qn_count) % p->qn_pairs;
    double *sk = p->qn_s + (size_t)slot * nf, *yk = p->qn_y + (size_t)slot * nf;
    double ys = 0.0, yy = 0.0;
    for (size_t i = 0; i < p->ndof; i++) {
        const int32_t f = p->free_index[i];
        if (f < 0)
            continue;
        sk[f] = alpha * p->step[f];
        yk[f] = grad_new[i] - p->qn_grad[f];
        p->qn_grad[f] = grad_new[i];
        ys += yk[f] * sk[f];
        yy += yk[f] * yk[f];
    }
    if (!(ys > DBL_EPSILON * yy) || !isfinite(ys))
        return;
    p->qn_rho[slot] = 1.0 / ys;
    if (p->qn_count < p->qn_pairs)
        p->qn_count++;
    else
        p->qn_head = (p->qn_head + 1) % p->qn_pairs;
}

bg_status bg_solver_new(const bg_scene_t *scene, bg_method method, bg_solver_t **out,
                        bg_error_t *err)
{
    return bg_solver_new_on(scene, method, NULL, out, err);
}

bg_status bg_solver_new_on(const bg_scene_t *scene, bg_method method, const bg_backend_t *backend,
                           bg_solver_t **out, bg_error_t *err)
{
    *out = NULL;
    if (method != BG_METHOD_NEWTON && method != BG_METHOD_LOCAL_GLOBAL &&
        method != BG_METHOD_QUASI_NEWTON)
        return bg_error_set(err, BG_ERR_INVALID, "%s is not a static solver method",
                            bg_method_name(method));
    problem_t *p = malloc(sizeof *p);
    if (!p)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating a solver");
    bg_status st = problem_setup(p, scene, method, backend, err);
    if (st != BG_OK) {
        bg_solver_destroy(&p);
        return st;
    }
    p->method = method;
    *out = p;
    return BG_OK;
}

void bg_solver_destroy(bg_solver_t **solver)
{
    if (!solver || !*solver)
        return;
    problem_release(*solver);
    free(*solver);
    *solver = NULL;
}

bg_status bg_solver_set_blend(bg_solver_t *p, const double *target, double blend,
                              bg_error_t *err)
{
    if (!(blend >= 0.0 && blend <= 1.0))
        return bg_error_set(err, BG_ERR_INVALID, "blend %g outside [0, 1]", blend);
    if (!p->target_model) {
        bg_status st = bg_mesh_clone(p->mesh, &p->target_mesh, err);
        if (st != BG_OK)
            return st;
        memcpy(p->target_mesh->x, target, p->ndof * sizeof *target);
        for (int32_t e = 0; e < p->mesh->ne; e++)
            if (!(bg_mesh_element_measure(p->target_mesh, target, e) > 0.0))
                return bg_error_set(err, BG_ERR_INVALID,
                                    "%s: element %d is inverted or flat in the morph target",
                                    p->scene->path, (int)e + 1);
        p->grad_target = malloc(p->ndof * sizeof *p->grad_target + 1);
        if (!p->grad_target)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the morph target");
        st = bg_elastic_new(p->target_mesh, p->scene->material.mu, p->scene->material.lambda,
                            &p->target_model, err);
        if (st != BG_OK)
            return st;
        const bg_backend_fit_t fit = {p->target_model,
                                      p->target_mesh,
                                      NULL,
                                      p->scene->material.mu,
                                      p->scene->material.lambda,
                                      0.0,
                                      p->sys ? bg_sparse_scatter(p->sys) : NULL,
                                      p->sys ? bg_sparse_nonzeros(p->sys) : 0};
        st = p->backend->ops->fit_open(p->session, 1, &fit, err);
        if (st != BG_OK)
            return st;
    }
    /* The Laplacian factored for the previous blend (0 before any) is
     * still right when the blend does not change. */
    const double previous = p->blend;
    p->blend = blend;
    if (p->sys || blend == previous)
        return BG_OK;
    /* Every factor held is for the old blend; a morph has no inertia term. */
    for (int k = 0; k < STATIC_LG_SLOTS; k++)
        p->lg_ready[k] = 0;
    p->lg_slot = 0;
    return lg_factor(p, 0, 0.0, err);
}

const double *bg_solver_energy_density(const bg_solver_t *solver)
{
    return bg_elastic_energy_density(solver->model);
}

const double *bg_solver_mass(bg_solver_t *solver)
{
    if (!solver->mass_ready && solver->mass) {
        const double t0 = bg_clock_now();
        bg_static_lumped_mass(solver->mesh, solver->scene->material.density, solver->mass);
        solver->mass_ready = 1;
        bg_setup_add(&solver->setup, "lumped mass matrix", 1, 0, bg_clock_now() - t0);
    }
    return solver->mass_ready ? solver->mass : NULL;
}

void bg_solver_report(bg_solver_t *solver, bg_solve_result_t *res)
{
    bg_setup_merge(&res->setup, &solver->setup);
    memset(&solver->setup, 0, sizeof solver->setup);
    res->rotfit_seconds += solver->rotfit_seconds;
    solver->rotfit_seconds = 0.0;
}

void bg_solve_result_add_scene_prep(bg_solve_result_t *res, const bg_scene_t *scene)
{
    for (int i = 0; i < scene->prep_count; i++) {
        bg_setup_add(&res->setup, scene->prep[i].name, 1, scene->prep[i].factorizations,
                     scene->prep[i].seconds);
        res->wall_seconds += scene->prep[i].seconds;
    }
}

double bg_solver_potential(bg_solver_t *p, const double *q, double *grad)
{
    const bg_inertia_t *saved = p->inertia;
    p->inertia = NULL;
    const double W = potential(p, q, grad);
    p->inertia = saved;
    return W;
}

static bg_sparse_timing_t total_timing(const problem_t *p)
{
    bg_sparse_timing_t sum = {0};
    const bg_sparse_t *systems[1 + 3 * STATIC_LG_SLOTS];
    int count = 0;
    systems[count++] = p->sys;
    for (int k = 0; k < STATIC_LG_SLOTS; k++)
        for (int c = 0; c < 3; c++)
            systems[count++] = p->lg[k][c];
    for (int i = 0; i < count; i++)
        if (systems[i]) {
            const bg_sparse_timing_t tm = bg_sparse_timing(systems[i]);
            sum.analyze_seconds += tm.analyze_seconds;
            sum.factor_seconds += tm.factor_seconds;
            sum.solve_seconds += tm.solve_seconds;
            sum.factorizations += tm.factorizations;
        }
    return sum;
}

/* A solve that cannot go on: at the round-off floor if the gradient is
 * within its round-off at the current iterate, else stalled. Returns the
 * estimate. */
static double classify_stop(problem_t *p, double gnorm, bg_solve_result_t *res,
                            const char *at_floor, const char *stalled)
{
    const double noise = gradient_noise(p, p->q, NULL);
    res->roundoff_floor = gnorm <= noise;
    res->stop_reason = res->roundoff_floor ? at_floor : stalled;
    return noise;
}

bg_status bg_solver_minimize(bg_solver_t *solver, const bg_solve_options_t *opt,
                             bg_solve_result_t *res, bg_error_t *err)
{
    memset(res, 0, sizeof *res);
    res->method = solver->method;
    const double t_start = bg_clock_now();
    problem_t *p = solver;
    const bg_scene_t *scene = p->scene;
    int trace_cap = 0, pending_cap = 0;
    bg_status st = BG_OK;
    const size_t ndof = p->ndof;
    if (opt->inertia && solver->method == BG_METHOD_LOCAL_GLOBAL) {
        st = bg_error_set(err, BG_ERR_UNSUPPORTED,
                          "an inertia term needs the newton or quasi-newton method");
        goto out;
    }
    if (opt->inertia && !bg_solver_mass(p)) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the mass matrix");
        goto out;
    }
    p->inertia = opt->inertia;
    if (p->inertia)
        for (int32_t v = 0; v < p->mesh->nv; v++)
            for (int c = 0; c < p->n; c++) {
                const int32_t f = p->free_index[(size_t)v * p->n + c];
                if (f >= 0)
                    p->inertia_diag[f] = p->inertia->c * p->mass[v];
            }
    /* Quasi-newton's initial Hessian includes the inertia term: its factor
     * for this c, made (a set-up step) only when no slot holds one. */
    if (!p->sys && (st = lg_use(p, p->inertia ? p->inertia->c : 0.0, err)) != BG_OK)
        goto out;
    bg_elastic_reset_stats(p->model);
    const bg_sparse_timing_t timing0 = total_timing(p);
    const double *start = opt->start ? opt->start : scene->initial;
    const double *targets = opt->targets ? opt->targets : scene->target;
    for (size_t i = 0; i < ndof; i++)
        p->q[i] = scene->constrained[i] ? targets[i] : start[i];

    p->failed = BG_OK;
    double W = potential(p, p->q, p->grad);
    double gnorm = free_norm(p, p->grad);
    if (p->failed != BG_OK) {
        st = bg_error_set(err, p->failed, "%s", p->fail_err.message);
        goto out;
    }
    if (!isfinite(W) || !isfinite(gnorm)) {
        st = bg_error_set(err, BG_ERR_NUMERIC, "%s: the energy at the initial positions is not "
                          "finite", scene->path);
        goto out;
    }
    /* The relative gradient's scale: the start's free gradient, but at
     * least the reactions at the handles and the load, which do not vanish
     * when the start is already the solution; and when the start's
     * gradient is round-off, the element forces themselves. */
    double reaction = 0.0, load = 0.0;
    for (size_t i = 0; i < ndof; i++) {
        if (p->free_index[i] < 0)
            reaction += p->grad[i] * p->grad[i];
        else if (p->gravity_force)
            load += p->gravity_force[i] * p->gravity_force[i];
    }
    double g0 = fmax(gnorm, fmax(sqrt(reaction), sqrt(load)));
    double noise = NAN;
    int noise_at = -STATIC_NOISE_RECHECK;
    if (!p->inertia) {
        double forces = 0.0;
        noise = gradient_noise(p, p->q, &forces);
        noise_at = 0;
        if (gnorm <= noise)
            g0 = fmax(g0, forces);
    }
    res->force_scale = g0;
    bg_trace_point_t pt = {bg_clock_now() - t_start, 0, W, gnorm, g0 > 0.0 ? gnorm / g0 : 0.0,
                           NAN, 0};
    if (trace_error(opt, p->q, ndof, res, &pending_cap, &pt.error) != BG_OK ||
        push_trace(res, &trace_cap, &pt) != BG_OK) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory recording the trace");
        goto out;
    }
    if (opt->progress)
        opt->progress(opt->progress_ctx, solver->method, &pt);

    const int reuse = opt->reuse_factor && solver->method == BG_METHOD_NEWTON;
    const int lbfgs = solver->method == BG_METHOD_QUASI_NEWTON;
    if ((reuse || lbfgs) && (st = qn_alloc(p, err)) != BG_OK)
        goto out;
    /* From here on qn_push keeps qn_grad equal to the current free gradient. */
    if (reuse || lbfgs)
        gather_free(p, p->grad, p->qn_grad);
    int refactor = !p->factor_ready || p->factor_c != (p->inertia ? p->inertia->c : 0.0);
    p->qn_count = p->qn_head = 0;
    double g_best = INFINITY;
    int since_best = 0;
    res->stop_reason = "iteration limit";
    int it = 0;
    double exact_failed_at = INFINITY; /* gradient norm when the exact Hessian last failed */
    const double exact_below =
        p->scene->material.lambda > STATIC_CONTINUATION_ABOVE * p->scene->material.mu
            ? STATIC_EXACT_HESSIAN_BELOW_STIFF
            : STATIC_EXACT_HESSIAN_BELOW;
    int exact_failed_it = 0;
    for (;;) {
        const double rel = g0 > 0.0 ? gnorm / g0 : 0.0;
        if (rel <= opt->tolerance || gnorm <= opt->absolute_tolerance ||
            (gnorm <= p->force_floor && !opt->no_force_floor)) {
            res->converged = 1;
            res->stop_reason = "converged";
            break;
        }
        if (it >= opt->max_iterations)
            break;
        it++;
    direction:;
        double tv = bg_clock_now();
        for (size_t i = 0; i < ndof; i++)
            if (p->free_index[i] >= 0)
                p->rhs[p->free_index[i]] = -p->grad[i];
        p->vector_seconds += bg_clock_now() - tv;
        double slope = NAN;
        int quasi = 0;
        if (lbfgs && p->qn_count > 0) {
            /* Without pairs (the first iteration, or after a reset) the
             * direction is local/global's, below. */
            quasi = 1;
            if ((st = qn_direction(p, &slope, err)) != BG_OK)
                goto out;
            if (!(slope < 0.0)) { /* the history lost descent: start it again */
                p->qn_count = p->qn_head = 0;
                goto direction;
            }
        } else if (reuse) {
            if (!refactor) {
                quasi = 1;
                if ((st = qn_direction(p, &slope, err)) != BG_OK)
                    goto out;
                if (!(slope < 0.0)) { /* a stale matrix lost descent: refactor now */
                    quasi = 0;
                    for (size_t i = 0; i < ndof; i++)
                        if (p->free_index[i] >= 0)
                            p->rhs[p->free_index[i]] = -p->grad[i];
                }
            }
        }
        if (quasi) {
            res->last_direction = BG_DIRECTION_QUASI_NEWTON;
        } else if (solver->method == BG_METHOD_NEWTON) {
            /* With an inertia term (4/h²)M the exact Hessian is almost
             * always positive definite: try it from the first iteration. */
            const int try_exact =
                p->inertia ||
                (rel < exact_below &&
                 (gnorm < STATIC_EXACT_RETRY_FACTOR * exact_failed_at ||
                  it - exact_failed_it > STATIC_EXACT_RETRY_AFTER));
            st = newton_direction(p, try_exact, res, &slope, err);
            if (try_exact && res->last_direction != BG_DIRECTION_EXACT) {
                exact_failed_at = gnorm;
                exact_failed_it = it;
            }
            refactor = 0;
            p->qn_cost = 0.0;
        } else {
            st = solve_direction(p, &slope, err);
        }
        if (st != BG_OK)
            goto out;
        if (p->failed != BG_OK)
            break;
        if (!(slope < 0.0)) {
            /* Every matrix tried was positive definite or shifted to be, and
             * −A⁻¹∇ is then a descent direction unless the gradient is
             * round-off noise. */
            noise = classify_stop(p, gnorm, res,
                                  "no descent direction: the gradient is at its round-off",
                                  "stalled: no descent direction, the gradient above its "
                                  "round-off");
            noise_at = it;
            break;
        }
        double alpha = 1.0, W_trial = NAN, g_trial = NAN;
        int accepted = 0, bt_used = 0;
        for (int bt = 0; bt <= STATIC_MAX_BACKTRACKS; bt++, alpha *= 0.5) {
            bt_used = bt;
            tv = bg_clock_now();
            for (size_t i = 0; i < ndof; i++) {
                const int32_t f = p->free_index[i];
                p->q_trial[i] = f >= 0 ? p->q[i] + alpha * p->step[f] : p->q[i];
            }
            const int flips = opt->keep_orientation && inverts(p, p->q_trial);
            p->vector_seconds += bg_clock_now() - tv;
            if (flips)
                continue;
            W_trial = potential(p, p->q_trial, p->grad_trial);
            if (!isfinite(W_trial))
                continue;
            tv = bg_clock_now();
            g_trial = free_norm(p, p->grad_trial);
            p->vector_seconds += bg_clock_now() - tv;
            if (W_trial <= W + STATIC_ARMIJO * alpha * slope ||
                (W_trial <= W + energy_noise(p, W) && g_trial < gnorm)) {
                accepted = 1;
                break;
            }
        }
        if (!accepted) {
            /* The last evaluation was at a rejected trial: restore the
             * rotations of the current iterate. */
            W = potential(p, p->q, p->grad);
            if (quasi && lbfgs) { /* the history, not round-off, may be at fault: the same
                                     iteration again from local/global's direction */
                p->qn_count = p->qn_head = 0;
                goto direction;
            }
            if (quasi) { /* the quasi-Newton model, not round-off, may be at fault */
                refactor = 1;
                continue;
            }
            noise = classify_stop(p, gnorm, res, "the gradient reached its round-off floor",
                                  "stalled: no step decreases the energy, the gradient above "
                                  "its round-off");
            noise_at = it;
            break;
        }
        if (alpha == 1.0 && !quasi && !reuse && !p->inertia &&
            solver->method == BG_METHOD_NEWTON &&
            W_trial - W <= STATIC_CHORD_MODEL_AGREEMENT * 0.5 * slope) {
            const double g_stop =
                fmax(fmax(opt->tolerance * g0, opt->absolute_tolerance),
                     opt->no_force_floor ? 0.0 : p->force_floor);
            int taken = 0;
            const int most = opt->chord_steps == 0 ? STATIC_CHORD_STEPS : opt->chord_steps;
            if ((st = chord_steps(p, most, g_stop, opt->keep_orientation, &W_trial, &g_trial,
                                  &taken, err)) != BG_OK)
                goto out;
            if (p->failed != BG_OK)
                break;
            res->chord_steps += taken;
        }
        /* A quasi-Newton step that stalls asks for a fresh matrix, not a
         * stop; any other stalls only where the gradient is its own
         * round-off (checked below, at the accepted point). A gradient
         * that rises once while the energy is flat is no stop: local/global's
         * is not monotone. */
        const int stagnated = (!quasi || lbfgs) && fabs(W_trial - W) <= energy_noise(p, W) &&
                              g_trial > STATIC_NO_PROGRESS * gnorm;
        tv = bg_clock_now();
        if (lbfgs)
            qn_push(p, alpha, p->grad_trial);
        if (reuse) {
            qn_push(p, alpha, p->grad_trial);
            if (!quasi || g_trial < g_best) {
                g_best = g_trial;
                since_best = 0;
            } else if (++since_best >= STATIC_REFACTOR_PATIENCE) {
                refactor = 1;
            }
            /* Ski rental: once the quasi-Newton iterations on this matrix
             * have cost as much as factoring it does, a fresh one is due (at
             * most twice the cost of the better choice made in hindsight).
             * A modelled cost, not the clock, keeps runs reproducible. */
            if (quasi) {
                double flops = 0.0, factor_nonzeros = 0.0;
                p->backend->ops->solve_cost(p->session, 0, &flops, &factor_nonzeros);
                p->qn_cost += 4.0 * factor_nonzeros + 4.0 * p->qn_count * (double)p->nfree +
                              STATIC_EVALUATION_UNITS * p->mesh->ne * (bt_used + 1);
                if (p->qn_cost > flops / STATIC_FACTOR_FLOP_SPEEDUP)
                    refactor = 1;
            }
        }
        swap_arrays(&p->q, &p->q_trial);
        swap_arrays(&p->grad, &p->grad_trial);
        W = W_trial;
        gnorm = g_trial;
        pt.seconds = bg_clock_now() - t_start;
        pt.iteration = it;
        pt.energy = W;
        pt.gradient_norm = gnorm;
        pt.relative_gradient = g0 > 0.0 ? gnorm / g0 : 0.0;
        if (trace_error(opt, p->q, ndof, res, &pending_cap, &pt.error) != BG_OK ||
            push_trace(res, &trace_cap, &pt) != BG_OK) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory recording the trace");
            goto out;
        }
        p->vector_seconds += bg_clock_now() - tv;
        if (stagnated && !(pt.relative_gradient <= opt->tolerance) &&
            it - noise_at >= STATIC_NOISE_RECHECK) {
            noise = gradient_noise(p, p->q, NULL);
            noise_at = it;
        }
        if (opt->progress)
            opt->progress(opt->progress_ctx, solver->method, &pt);
        if (stagnated && !(pt.relative_gradient <= opt->tolerance) && noise_at == it &&
            gnorm <= noise) {
            res->stop_reason = "the gradient reached its round-off floor";
            res->roundoff_floor = 1;
            break;
        }
    }
    if (p->failed != BG_OK) {
        st = bg_error_set(err, p->failed, "%s", p->fail_err.message);
        goto out;
    }
    res->iterations = it;
    res->energy = W;
    res->gradient_norm = gnorm;
    res->relative_gradient = g0 > 0.0 ? gnorm / g0 : 0.0;
    if (noise_at != it || !isfinite(noise))
        noise = gradient_noise(p, p->q, NULL);
    res->gradient_roundoff = noise;
    res->inverted_elements = bg_static_count_inverted(p->mesh, p->q);
    res->rotfit = bg_elastic_rotfit_stats(p->model);
    res->rotfit_seconds = p->rotfit_seconds;
    p->rotfit_seconds = 0.0;
    res->vector_seconds = p->vector_seconds;
    p->vector_seconds = 0.0;
    const bg_sparse_timing_t timing1 = total_timing(p);
    res->analyze_seconds = timing1.analyze_seconds - timing0.analyze_seconds;
    res->factor_seconds = timing1.factor_seconds - timing0.factor_seconds;
    res->solve_seconds = timing1.solve_seconds - timing0.solve_seconds;
    res->factorizations = timing1.factorizations - timing0.factorizations;
    res->q = malloc(ndof * sizeof *res->q + 1);
    res->energy_density = malloc((size_t)scene->mesh->ne * sizeof *res->energy_density + 1);
    if (!res->q || !res->energy_density) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the result");
        goto out;
    }
    memcpy(res->q, p->q, ndof * sizeof *res->q);
    /* A remote backend fitted the rotations on the agents, and a rejected
     * chord step leaves them elsewhere: the energy density of the result
     * comes from one evaluation here. */
    if (p->backend != bg_backend_local())
        bg_elastic_eval(p->model, p->q, p->mag);
    else if (p->fitted_elsewhere)
        potential(p, p->q, p->mag);
    memcpy(res->energy_density, bg_elastic_energy_density(p->model),
           (size_t)scene->mesh->ne * sizeof *res->energy_density);
    res->wall_seconds = bg_clock_now() - t_start;
out:
    p->inertia = NULL;
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}

/* One minimisation of scene with a solver of its own, its set-up reported. */
static bg_status solve_once(const bg_scene_t *scene, const bg_solve_options_t *opt,
                            bg_solve_result_t *res, bg_error_t *err)
{
    bg_solver_t *solver = NULL;
    bg_status st = bg_solver_new_on(scene, opt->method, opt->backend, &solver, err);
    if (st == BG_OK)
        st = bg_solver_minimize(solver, opt, res, err);
    if (st == BG_OK)
        bg_solver_report(solver, res);
    bg_solver_destroy(&solver);
    return st;
}

int bg_static_continues(const bg_scene_t *scene, bg_method method)
{
    return (method == BG_METHOD_NEWTON || method == BG_METHOD_QUASI_NEWTON) &&
           scene->task == BG_TASK_STATIC && !scene->rest_edges && !scene->continuation_off &&
           scene->material.lambda > STATIC_CONTINUATION_ABOVE * scene->material.mu;
}

static int wants_continuation(const bg_scene_t *scene, const bg_solve_options_t *opt)
{
    return opt->continuation >= 0 && !opt->start && !opt->inertia && !opt->reuse_factor &&
           bg_static_continues(scene, opt->method);
}

/* A continuation stage's progress, passed on with the iterations and the
 * time of the stages before it added; a later stage's iteration 0 (the
 * previous stage's result) is not repeated. */
typedef struct stage_progress {
    const bg_solve_options_t *opt;
    int iterations;
    double seconds;
    int stage;
} stage_progress_t;

static void stage_progress(void *ctx, bg_method method, const bg_trace_point_t *point)
{
    const stage_progress_t *sp = ctx;
    if (sp->stage > 0 && point->iteration == 0)
        return;
    bg_trace_point_t pt = *point;
    pt.iteration += sp->iterations;
    pt.seconds += sp->seconds;
    pt.stage = sp->stage;
    sp->opt->progress(sp->opt->progress_ctx, method, &pt);
}

/* Appends part's trace to *trace (*count points), iterations and seconds
 * offset and marked with the stage, its iteration 0 left out after the
 * first stage. */
static bg_status append_trace(bg_trace_point_t **trace, int *count, const bg_solve_result_t *part,
                              const stage_progress_t *sp, bg_error_t *err)
{
    const int first = *count > 0 ? 1 : 0;
    if (part->trace_count <= first)
        return BG_OK;
    bg_trace_point_t *t =
        realloc(*trace, (size_t)(*count + part->trace_count - first) * sizeof *t);
    if (!t)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory recording the trace");
    for (int i = first; i < part->trace_count; i++) {
        t[*count] = part->trace[i];
        t[*count].iteration += sp->iterations;
        t[*count].seconds += sp->seconds;
        t[*count].stage = sp->stage;
        ++*count;
    }
    *trace = t;
    return BG_OK;
}

/* The staged solve of bg_static_solve's contract (continuation in λ). */
static bg_status continuation_solve(const bg_scene_t *scene, const bg_solve_options_t *opt,
                                    bg_solve_result_t *res, bg_error_t *err)
{
    const double t_start = bg_clock_now();
    /* A shallow copy: the solvers borrow the scene, and only λ differs. */
    bg_scene_t stage = *scene;
    bg_solve_result_t done = BG_SOLVE_RESULT_INIT; /* counts and times of the finished stages */
    bg_solve_result_t part = BG_SOLVE_RESULT_INIT;
    bg_trace_point_t *trace = NULL;
    int trace_count = 0, stages = 0;
    double *q = NULL;
    stage_progress_t sp = {opt, 0, 0.0, 0};
    bg_status st = BG_OK;
    for (double lambda = STATIC_CONTINUATION_FIRST * scene->material.mu;;
         lambda *= STATIC_CONTINUATION_GROWTH) {
        const int last = !(lambda < scene->material.lambda);
        stage.material.lambda = last ? scene->material.lambda : lambda;
        bg_solve_options_t o = *opt;
        o.start = q;
        o.continuation = -1;
        o.max_iterations = opt->max_iterations - done.iterations;
        if (!last)
            o.tolerance = fmax(opt->tolerance, STATIC_CONTINUATION_TOLERANCE);
        sp.iterations = done.iterations;
        sp.seconds = bg_clock_now() - t_start;
        sp.stage = stages;
        if (opt->progress) {
            o.progress = stage_progress;
            o.progress_ctx = &sp;
        }
        if ((st = solve_once(&stage, &o, &part, err)) != BG_OK ||
            (st = append_trace(&trace, &trace_count, &part, &sp, err)) != BG_OK || last)
            break;
        free(q);
        q = part.q;
        part.q = NULL;
        bg_solve_result_accumulate(&done, &part);
        bg_setup_merge(&done.setup, &part.setup);
        bg_solve_result_release(&part);
        stages++;
    }
    if (st != BG_OK)
        goto out;
    *res = part;
    part = (bg_solve_result_t)BG_SOLVE_RESULT_INIT;
    bg_solve_result_accumulate(res, &done);
    bg_setup_merge(&res->setup, &done.setup);
    free(res->trace);
    res->trace = trace;
    res->trace_count = trace_count;
    trace = NULL;
    res->continuation_stages = stages;
out:
    free(q);
    free(trace);
    bg_solve_result_release(&part);
    return st;
}

bg_status bg_static_solve(const bg_scene_t *scene, const bg_solve_options_t *opt,
                          bg_solve_result_t *res, bg_error_t *err)
{
    memset(res, 0, sizeof *res);
    const double t_start = bg_clock_now();
    const int staged = wants_continuation(scene, opt);
    /* A stage's pending rows would not line up with the merged trace. */
    if (staged && opt->reference_ready && !opt->reference)
        return bg_error_set(err, BG_ERR_INVALID,
                            "a reference computed alongside needs a solve without continuation");
    const bg_status st = staged ? continuation_solve(scene, opt, res, err)
                                : solve_once(scene, opt, res, err);
    /* Setup (pattern, analysis, factoring local/global's Laplacian) counts,
     * and so does the scene's starting guess. */
    if (st == BG_OK) {
        res->wall_seconds = bg_clock_now() - t_start;
        bg_solve_result_add_scene_prep(res, scene);
    }
    return st;
}

void bg_solve_result_accumulate(bg_solve_result_t *total, const bg_solve_result_t *part)
{
    total->iterations += part->iterations;
    total->rotfit.calls += part->rotfit.calls;
    total->rotfit.warm += part->rotfit.warm;
    total->rotfit.polar += part->rotfit.polar;
    total->rotfit.svd += part->rotfit.svd;
    total->rotfit_seconds += part->rotfit_seconds;
    total->assembly_seconds += part->assembly_seconds;
    total->analyze_seconds += part->analyze_seconds;
    total->factor_seconds += part->factor_seconds;
    total->solve_seconds += part->solve_seconds;
    total->vector_seconds += part->vector_seconds;
    total->output_seconds += part->output_seconds;
    total->factorizations += part->factorizations;
    total->chord_steps += part->chord_steps;
}

void bg_solve_result_release(bg_solve_result_t *r)
{
    if (!r)
        return;
    free(r->q);
    free(r->energy_density);
    free(r->trace);
    free(r->pending);
    free(r->steps);
    memset(r, 0, sizeof *r);
}
