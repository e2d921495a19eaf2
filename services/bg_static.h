/*
 * bg_static — static equilibrium of a scene: minimise
 *   W(q) = E(q) − Σ_v m_v g·q_v
 * over the free coordinates, the constrained ones held at their targets.
 *
 * Methods:
 *   newton        exact Hessian with the twist eigenvalues clamped (PSD),
 *                 CHOLMOD with one symbolic analysis and a numeric
 *                 factorization per iteration, backtracking line search;
 *                 after a full step, a few chord steps on the same
 *                 factorization (static solves without factor reuse).
 *                 Quadratic convergence near the solution.
 *   local-global  the prefactored method: the matrix c·L (L the cotan
 *                 Laplacian per coordinate, c = 2μ + λ) is factored once,
 *                 and each iteration fits rotations (local step) and
 *                 solves with it (global step), d = −(cL)⁻¹ ∇W. For λ = 0
 *                 this is exactly Sorkine–Alexa / Liu et al. (the step lands
 *                 on L⁻¹ b(R)); for λ > 0 the same fixed matrix serves as a
 *                 preconditioner under the same line search. Linear
 *                 convergence.
 *   quasi-newton  L-BFGS whose initial Hessian is local/global's factored
 *                 matrix (Liu, Bouaziz and Kavan, "Quasi-Newton Methods
 *                 for Real-Time Simulation of Hyperelastic Materials",
 *                 2017): the same one factorization and, per iteration,
 *                 one rotation fit, one block solve of the coordinates and
 *                 the two-loop recursion over the last few curvature
 *                 pairs, under the same line search. Linear convergence,
 *                 at a far better rate than local/global's (bunny-edit
 *                 to 1e-8: 140 iterations; local/global is at 7e-8 after
 *                 2,000). With an inertia term (a time step's inner solve)
 *                 the initial Hessian is (2μ + λ)L + cM, factored once per
 *                 coefficient c and kept by the solver (two at a time).
 * All three stop when ‖∇W‖/s ≤ tolerance (free coordinates; s the start's free
 * gradient, at least the reactions at the handles and the load), at the
 * iteration cap, or when the gradient is at its own round-off (estimated
 * from the magnitudes of the element forces that sum to it) and no step
 * improves it: "round-off floor". A line search that fails above that
 * floor is reported as "stalled". They never produce NaN: a non-finite
 * energy is a rejected step.
 */
#ifndef BG_STATIC_H
#define BG_STATIC_H

#include <stdint.h>

#include "bg_backend.h"
#include "bg_error.h"
#include "bg_rotfit.h"
#include "bg_scene.h"

typedef struct bg_trace_point {
    double seconds;           /* wall time since the solve started */
    int iteration;
    double energy;
    double gradient_norm;
    double relative_gradient;
    double error;             /* ‖q − q_ref‖/‖q_ref‖, NAN without a reference */
    int stage;                /* continuation stage (bg_static_solve; 0: the first or only):
                                 energies fall within a stage, and rise with λ between */
} bg_trace_point_t;

typedef void (*bg_progress_fn)(void *ctx, bg_method method, const bg_trace_point_t *point);

/* Called with the positions of every output frame of a series (a dynamic
 * run's steps, a morph's frames), the first included. */
typedef bg_status (*bg_frame_fn)(void *ctx, int index, double time, const double *q,
                                 bg_error_t *err);

/* An inertia term (c/2) Σ_v m_v |q_v − y_v|² added to W: a time step of an
 * implicit integrator minimises W plus this (bg_dynamics). */
typedef struct bg_inertia {
    double c;          /* 4/h² for the variational midpoint, 1/h² for backward Euler */
    const double *y;   /* nv*n: the inertial prediction */
} bg_inertia_t;

typedef struct bg_solve_options {
    bg_method method;
    double tolerance;
    int max_iterations;
    double absolute_tolerance; /* also stop when ‖∇‖ ≤ this (0: unused) */
    int no_force_floor;       /* ignore the scene's absolute floor (1e-13 of its force scale):
                                 run to the gradient's round-off (tests of the round-off stop) */
    const double *targets;    /* nv*n values of the constrained coordinates, or NULL for scene->target */
    const bg_inertia_t *inertia; /* NULL for a static solve; newton or quasi-newton only */
    int chord_steps;          /* newton without reuse_factor or inertia: at most this many
                                 chord steps after each full Newton step (0: the default, 8;
                                 negative: none, plain Newton, e.g. to read its quadratic
                                 convergence from the trace) */
    int continuation;         /* bg_static_solve, newton or quasi-newton from the scene's
                                 own start (start NULL, no inertia, no factor reuse) with
                                 λ > 100 μ:
                                 0 solves in stages of growing λ (bg_static_solve); negative:
                                 one solve at the scene's λ (plain) */
    int keep_orientation;     /* reject steps that invert an element (from a start
                                 without inverted elements: the result has none) */
    const double *reference;  /* nv*n reference positions for the error column, or NULL */
    /* A reference still being computed (by another thread) while this
     * solve runs, asked when reference is NULL: reference_ready(ctx, 0)
     * returns its nv*n positions once they are final (the same pointer
     * ever after), else NULL; reference_ready(ctx, 1) waits for them (NULL:
     * the reference failed). Until they are ready a trace point's error
     * is NaN and its positions are kept in the result's pending rows, for
     * bg_static_fill_errors; past BG_STATIC_PENDING_BYTES of rows the
     * solve waits for the reference. Called from the solving thread only.
     * Not with continuation (bg_static_continues): BG_ERR_INVALID. */
    const double *(*reference_ready)(void *ctx, int wait);
    void *reference_ctx;
    const double *start;      /* nv*n start positions, or NULL for scene->initial */
    int reuse_factor;         /* newton: keep the factored matrix across iterations and calls,
                                 and take L-BFGS steps on it (a few curvature pairs), refactoring
                                 only when a step shrinks the gradient by less than half. Pays
                                 when successive problems are close: the steps of a time
                                 integration, the frames of a morph. Linear momentum stays exact
                                 (every direction keeps Σ m d = 0 for a free body). */
    bg_progress_fn progress;  /* called after every iteration (may be NULL) */
    void *progress_ctx;
    const bg_backend_t *backend; /* bg_static_solve: the basic services (borrowed), NULL for
                                    in-process; bg_solver_minimize uses the solver's */
} bg_solve_options_t;

/* Which matrix gave the last Newton direction. */
typedef enum bg_direction {
    BG_DIRECTION_NONE = 0,
    BG_DIRECTION_EXACT,     /* exact Hessian */
    BG_DIRECTION_PROJECTED, /* twist eigenvalues clamped */
    BG_DIRECTION_SHIFTED,   /* projected plus a diagonal shift */
    BG_DIRECTION_QUASI_NEWTON, /* L-BFGS on a reused factorization (reuse_factor) */
} bg_direction;

/* One time step of a dynamic run (bg_dynamics). Momenta are Σ_v p_v and
 * Σ_v q_v × p_v over all vertices (planar: the angular momentum is along z). */
typedef struct bg_step_record {
    double time;
    double kinetic;
    double potential;         /* W = E − gravity work */
    double total_energy;
    double linear_momentum[3];
    double angular_momentum[3];
    int iterations;           /* Newton iterations of the step */
    int limited;              /* the energy limiter redid the step with backward Euler */
    double seconds;           /* wall time of the step */
} bg_step_record_t;

/* Quality of a 2D map of a surface (parameterization): per triangle the
 * singular values σ1 ≥ σ2 of the map from its rest frame; angle distortion
 * |log σ1/σ2| (0 for conformal), area distortion |log(σ1σ2/s)| with s the
 * global area ratio (0 for area-preserving up to a uniform scale). */
typedef struct bg_map_quality {
    int valid;
    int64_t flipped_triangles;
    double area_mean, area_max;
    double angle_mean, angle_max;
} bg_map_quality_t;

/* Set-up work of a run, outside its iterations: each step once per name
 * with how often it ran, its numeric factorizations and its time. */
#define BG_SETUP_MAX_STEPS 8
typedef struct bg_setup_step {
    const char *name;         /* static text */
    int64_t count;
    int64_t factorizations;
    double seconds;
} bg_setup_step_t;

typedef struct bg_setup {
    bg_setup_step_t step[BG_SETUP_MAX_STEPS];
    int count;
    double seconds;           /* Σ step[].seconds */
    int64_t factorizations;   /* Σ step[].factorizations */
} bg_setup_t;

/* The set-up step of Newton's symbolic analysis (the fill-reducing order,
 * the Hessian stored in it): once per solver, before the iterations. */
#define BG_SETUP_NEWTON_ANALYSIS                                                                   \
    "Newton: the Hessian's symbolic analysis, stored in its factor's order"

/* Adds one run of a set-up step (merged with an earlier one of the same
 * name; steps beyond BG_SETUP_MAX_STEPS go into the last one). */
void bg_setup_add(bg_setup_t *setup, const char *name, int64_t count, int64_t factorizations,
                  double seconds);
/* Adds every step of from to into. */
void bg_setup_merge(bg_setup_t *into, const bg_setup_t *from);

typedef struct bg_solve_result {
    bg_method method;
    int converged;
    const char *stop_reason;  /* static text: "converged", "iteration limit", ... */
    int iterations;
    double wall_seconds;
    double energy;
    double gradient_norm;
    double relative_gradient;
    bg_rotfit_stats_t rotfit;
    /* Time split (seconds): rotation fitting with energy and gradient
     * (every evaluation, the round-off estimates included), Hessian/matrix
     * assembly, CHOLMOD symbolic analysis, numeric factorization, triangular
     * solves, the vector work of the iterations (line search, L-BFGS
     * recursion, orientation checks, norms), writing output frames. With
     * setup.seconds they add up to wall_seconds (the difference is
     * bookkeeping between these timers). */
    double rotfit_seconds, assembly_seconds, analyze_seconds, factor_seconds, solve_seconds;
    double vector_seconds, output_seconds;
    int64_t factorizations;   /* numeric factorizations of the iterations (setup's: in setup) */
    int chord_steps;          /* newton: extra steps on an already factored matrix after a full
                                 step (one solve and one evaluation each, no factorization) */
    int continuation_stages;  /* bg_static_solve: solves at a lower λ before the scene's (0:
                                 none); iterations, counts and times include theirs */
    bg_setup_t setup;         /* the set-up steps: solver, lumped mass, local/global's
                                 Laplacian, the scene's starting guess */
    bg_direction last_direction;
    int roundoff_floor;       /* stopped where the free gradient is at most its own round-off
                                 (gradient_roundoff): no method can make further progress */
    double gradient_roundoff; /* the round-off of the final gradient norm, estimated from the
                                 magnitudes of the element forces that sum to it */
    double force_scale;       /* what relative_gradient divides by: the start's free gradient,
                                 at least the handles' reactions and the load there */
    int64_t inverted_elements; /* elements of the result with det F <= 0 (-1: not counted) */
    double *q;                /* final positions, nv*n; owned */
    double *energy_density;   /* final ψ per element, ne; owned */
    bg_trace_point_t *trace;  /* one point per iteration from 0 (dynamic: per step); owned */
    int trace_count;
    double *pending;          /* reference_ready: nv*n positions of trace points
                                 0..pending_count-1, whose error awaited the reference; owned */
    int pending_count;
    bg_map_quality_t map;     /* parameterize runs */
    bg_step_record_t *steps;  /* dynamic runs: steps[0] is the initial state; owned */
    int step_count;
    int limited_steps;        /* dynamic runs: steps the energy limiter redid */
} bg_solve_result_t;

#define BG_SOLVE_RESULT_INIT {0}

/* Whether bg_static_solve solves scene with method in stages of growing λ
 * (continuation, below) when the caller leaves options->continuation at 0
 * and starts from the scene's own guess without inertia or factor reuse:
 * Newton or quasi-newton on a static volume scene with λ > 100 μ whose
 * solver.continuation is not false. The plan (bg_plan) says so from the
 * same test. Quasi-newton continues for the same reason as Newton: from
 * the interpolated start of the stiff bar it descends into another local
 * minimum (energy 0.15733 against 0.15445) unless the stages lead it. */
int bg_static_continues(const bg_scene_t *scene, bg_method method);

/*
 * Solves the scene's static problem. On BG_OK the result is filled
 * (converged or not: see converged and stop_reason); release it with
 * bg_solve_result_release. Errors are setup failures (out of memory, a
 * scene with nothing free).
 *
 * Continuation in λ (options->continuation): a nearly incompressible body
 * (λ > 100 μ) solved with Newton or quasi-newton from the scene's own
 * starting guess is
 * first solved at λ = 10 μ, then at λ doubled each stage, each stage
 * warm-started from the last and stopped at relative gradient 10⁻¹ (or
 * the caller's tolerance if looser), the last at the scene's λ to the
 * caller's tolerance. The result is the last stage's, with every stage's
 * iterations, evaluations, factorizations, times and trace points (a
 * continuous iteration count) added in; the iteration cap bounds the
 * total. On such a non-convex, locked problem the stages can end in
 * another local minimum than one solve from the start would.
 */
bg_status bg_static_solve(const bg_scene_t *scene, const bg_solve_options_t *options,
                          bg_solve_result_t *result, bg_error_t *err);

void bg_solve_result_release(bg_solve_result_t *result);

/* What the pending rows of a solve (options->reference_ready) may hold
 * before it waits for the reference: with a run of fast iterations the
 * rows would otherwise grow as long as the reference takes. */
#define BG_STATIC_PENDING_BYTES (256u << 20)

/*
 * Fills the error of result's pending trace points against ref (nv*n
 * positions, ndof = nv*n values), with the same arithmetic the solve
 * uses for the points it could measure, and frees the pending rows.
 */
void bg_static_fill_errors(bg_solve_result_t *result, const double *ref, size_t ndof);

/* Adds part's iterations, rotation-fit counts and time split to total: a
 * series of solves (time steps, morph frames) reports their sum. */
void bg_solve_result_accumulate(bg_solve_result_t *total, const bg_solve_result_t *part);

/*
 * A solver kept across many minimisations of the same scene (the steps of a
 * time integration): the elastic model, the sparse pattern, CHOLMOD's
 * symbolic analysis, local/global's factorization and the warm-start
 * rotations persist. The scene is borrowed and must outlive the solver.
 */
typedef struct bg_solver bg_solver_t;

bg_status bg_solver_new(const bg_scene_t *scene, bg_method method, bg_solver_t **out,
                        bg_error_t *err);
/* The same with the basic services of backend (borrowed, outlives the
 * solver; NULL: in-process). A failure of a service mid-solve ends the
 * minimisation with its error (which names the agent and the service). */
bg_status bg_solver_new_on(const bg_scene_t *scene, bg_method method, const bg_backend_t *backend,
                           bg_solver_t **out, bg_error_t *err);
void bg_solver_destroy(bg_solver_t **solver);

/* One minimisation from options->start (or the scene's initial positions);
 * options->method is ignored (the solver's method is used). */
bg_status bg_solver_minimize(bg_solver_t *solver, const bg_solve_options_t *options,
                             bg_solve_result_t *result, bg_error_t *err);

/*
 * Morphing: from now on W uses (1 − blend)·E(M0 → q) + blend·E(M1 → q),
 * with M1 the same connectivity at the target positions (nv*n, copied on
 * the first call; later calls only change the blend, in [0, 1]). Fails
 * naming the element if the target inverts or flattens one.
 */
bg_status bg_solver_set_blend(bg_solver_t *solver, const double *target, double blend,
                              bg_error_t *err);

/* W(q) = E(q) − gravity work, without any inertia term; grad (nv*n) filled. */
double bg_solver_potential(bg_solver_t *solver, const double *q, double *grad);

/* ψ per element at the last evaluated positions (ne values), borrowed. */
const double *bg_solver_energy_density(const bg_solver_t *solver);

/* The lumped vertex masses (nv), borrowed; built on the first call (a
 * solver without gravity needs them only for an inertia term). NULL when
 * out of memory. */
const double *bg_solver_mass(bg_solver_t *solver);

/*
 * Adds to res what the solver did outside the minimisations already
 * reported: its set-up steps (model and pattern, lumped mass, local/global's
 * Laplacian factorizations, also those of bg_solver_set_blend) and the
 * evaluations made through bg_solver_potential since the last
 * bg_solver_minimize. Call once, at the end of a series.
 */
void bg_solver_report(bg_solver_t *solver, bg_solve_result_t *res);

/* Adds the scene's load-time set-up (scene->prep) to res: set-up list and
 * wall time. */
void bg_solve_result_add_scene_prep(bg_solve_result_t *res, const bg_scene_t *scene);

/* Elements of the mesh at positions q with measure <= 0: inverted or flat
 * tetrahedra (det F <= 0) or planar triangles. */
int64_t bg_static_count_inverted(const bg_mesh_t *mesh, const double *q);

/* Lumped vertex masses ρ Σ V_e/(n+1) of the scene's mesh into mass[nv]. */
void bg_static_lumped_mass(const bg_mesh_t *mesh, double density, double *mass);

#endif
