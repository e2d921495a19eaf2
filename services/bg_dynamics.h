/*
 * bg_dynamics — the "integration-step" basic service: time integration of a
 * dynamic scene with the fully variational implicit midpoint rule
 * (DESIGN.md §1.6), or backward Euler as the dissipative baseline.
 *
 * Variational (h the step, M the lumped mass, W = E − gravity work):
 *   q* = argmin (2/h²)(q − q_k)ᵀM(q − q_k) + W(q) − (2/h) p_kᵀ(q − q_k)
 *   v = (2/h)(q* − q_k),  q_{k+1} = q_k + h v,  p_{k+1} = M v − (h/2)∇W(q*)
 * Symplectic, second order, linear and angular momentum exactly conserved
 * for a free body (to the inner solve's tolerance), energy in a bounded
 * band. Backward Euler: q_{k+1} = argmin (1/2h²)|q − q_k − h v_k|²_M + W(q),
 * first order, dissipative.
 * Each step is a static solve with an inertia term (bg_solver_t): Newton,
 * or quasi-newton when the scene's solver.inner says so — L-BFGS whose
 * initial Hessian (2μ + λ)L + cM is factored once per inertia coefficient
 * c (the midpoint rule's 4/h², the limiter's backward-Euler redo's 1/h²)
 * and kept for the run. Either way one CHOLMOD analysis per matrix serves
 * the whole run, and both stop at the same force-scaled residual, so they
 * give the same trajectory to that tolerance. The coordinator runs the
 * inner solve and the energy limiter's decisions; q_k, p_k and the step
 * formulas are the integration-step service's (bg_step, through the
 * backend: in process, or on an agent). Optional damping scales
 * the momentum by exp(−γh) per step: a decay rate independent of h.
 */
#ifndef BG_DYNAMICS_H
#define BG_DYNAMICS_H

#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"

/* Where each step's inner solve starts (see choose_start in bg_dynamics.c). */
typedef enum bg_predictor {
    BG_PREDICTOR_BEST = 0,    /* the candidate below with the lowest step energy */
    BG_PREDICTOR_LAST,        /* q_k */
    BG_PREDICTOR_INERTIAL,    /* y plus the constant-load displacement */
    BG_PREDICTOR_EXTRAPOLATE, /* velocity extrapolated from the last two steps */
} bg_predictor;

typedef struct bg_dynamic_options {
    bg_method method;         /* BG_METHOD_VARIATIONAL or BG_METHOD_BACKWARD_EULER */
    double dt;                /* 0: the scene's */
    int steps;                /* 0: the scene's */
    double duration;          /* > 0: run this long (steps = duration/dt, rounded) */
    double tolerance;         /* inner solve: stop at ‖∇‖ ≤ tolerance × the step's force scale
                                 ‖Mg‖ + (2/h)‖p‖ + ‖∇W(q_k)‖ (0: the scene's solver.tolerance) */
    int max_iterations;       /* inner solve's cap per step (0: 200) */
    int output_every;         /* frames every this many steps (0: the scene's) */
    bg_predictor predictor;   /* start of each step's solve (0: the best candidate) */
    int fresh_factor;         /* inner newton: 1: factor the Newton matrix at every inner
                                 iteration; 0: reuse it across iterations and steps with
                                 L-BFGS corrections (bg_solve_options_t.reuse_factor).
                                 Inner quasi-newton keeps its own factors either way */
    bg_frame_fn frame;        /* may be NULL */
    void *frame_ctx;
    bg_progress_fn progress;  /* called after each step with the step's trace point */
    void *progress_ctx;
    const bg_backend_t *backend; /* basic services (borrowed), NULL: in-process. The time
                                    loop's state and step formulas (integration-step, bg_step)
                                    live behind its step ops, in a session of their own; a
                                    backend without step ops keeps them in this process */
} bg_dynamic_options_t;

/*
 * Integrates the scene. The result holds the final positions, a trace
 * point per step (energy = total energy, error = relative energy drift
 * |E − E₀|/|E₀|) and the step records (steps[0] the initial state).
 * converged is 1 when every inner solve reached its tolerance (or the
 * round-off floor). Release with bg_solve_result_release.
 */
bg_status bg_dynamic_solve(const bg_scene_t *scene, const bg_dynamic_options_t *options,
                           bg_solve_result_t *result, bg_error_t *err);

#endif
