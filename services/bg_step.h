/*
 * bg_step — the integration-step service's state and formulas: the
 * positions q_k, momenta p_k and velocities of a dynamic run, and what a
 * step does with them around the inner minimisation (bg_dynamics.h has
 * the scheme). The same code runs in the coordinator (bg_backend_local)
 * and on an integration-step agent (agents/bga_service), so a run gives
 * bit-identical numbers wherever its state lives.
 *
 * One step is a short conversation:
 *   predict  (trial 0, or trial 1 = the backward-Euler redo of a step whose
 *            first trial the coordinator rejected): the targets at the end
 *            of the step in; the inertial prediction y, the inertia
 *            coefficient c, the constrained coordinates' targets for the
 *            solve, the candidate starts and the state's part of the force
 *            scale out;
 *   update   q* (the inner minimiser) and ∇W(q*) in; the trial end state
 *            (q_{k+1}, its kinetic energy, the handles' work) out, not yet
 *            committed;
 *   accept   commits the trial: q_{k+1} (constrained coordinates at their
 *            targets), p_{k+1} = e^{−γh} p_trial, v = p/m; the motion
 *            summary (kinetic energy, linear and angular momentum) out.
 * Calls out of this order fail with BG_ERR_INVALID naming what was
 * expected, so a confused peer cannot corrupt a run silently.
 *
 * Ownership: bg_step_new copies every input array. Arrays in the outputs
 * point into the state and stay valid until the next call on it.
 */
#ifndef BG_STEP_H
#define BG_STEP_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

#define BG_STEP_MAX_CANDIDATES 3

/* Candidate starts (the values of bg_predictor in bg_dynamics.h). */
enum {
    BG_STEP_PREDICT_BEST = 0,
    BG_STEP_PREDICT_LAST = 1,
    BG_STEP_PREDICT_INERTIAL = 2,
    BG_STEP_PREDICT_EXTRAPOLATE = 3
};

typedef struct bg_step_setup {
    int dim;                    /* 2 or 3 */
    int32_t nv;                 /* vertices */
    double h;                   /* time step, > 0 */
    double damping;             /* γ ≥ 0: momenta scaled by e^{−γh} per step */
    const double *mass;         /* nv lumped masses, > 0 */
    const double *q;            /* nv*dim start positions (constrained at their targets) */
    const double *velocity;     /* nv*dim start velocities (0 on constrained coordinates) */
    const double *t0;           /* nv*dim targets at time 0 */
    const uint8_t *constrained; /* nv*dim: 1 where the coordinate is prescribed */
    const double *gravity;      /* dim: the acceleration of gravity */
} bg_step_setup_t;

typedef struct bg_step_request {
    int variational; /* 1: the midpoint rule, 0: backward Euler */
    int trial;       /* 0: a new step; 1: redo the step just tried (after update) */
    int predictor;   /* BG_STEP_PREDICT_* */
    const double *t1; /* nv*dim targets at the end of the step */
} bg_step_request_t;

typedef struct bg_step_prediction {
    double coefficient;   /* c: the inertia term (c/2)|q − y|²_M */
    double state_scale;   /* ‖M g‖ + (2/h)‖p_k‖ over free coordinates */
    const double *y;      /* the inertial prediction */
    const double *targets; /* where the solve holds the constrained coordinates */
    int ncandidates;       /* 1 .. BG_STEP_MAX_CANDIDATES, in the order to try */
    const double *candidate[BG_STEP_MAX_CANDIDATES]; /* candidate[c] = candidate[0] + c·ndof */
} bg_step_prediction_t;

typedef struct bg_step_trial {
    const double *q_next; /* the trial end positions */
    double kinetic;       /* Σ p_trial²/2m */
    double handle_work;   /* the handles' work over the step */
} bg_step_trial_t;

typedef struct bg_step_motion {
    const double *q;
    double kinetic;
    double linear[3], angular[3];
    int64_t steps; /* steps accepted so far */
} bg_step_motion_t;

typedef struct bg_step bg_step_t;

/* Checks and copies the set-up (BG_ERR_INVALID names a bad field). Caller owns *out. */
bg_status bg_step_new(const bg_step_setup_t *setup, bg_step_t **out, bg_error_t *err);
void bg_step_destroy(bg_step_t **step);
size_t bg_step_dofs(const bg_step_t *step);

bg_status bg_step_predict(bg_step_t *step, const bg_step_request_t *req,
                          bg_step_prediction_t *out, bg_error_t *err);
bg_status bg_step_update(bg_step_t *step, const double *q_star, const double *grad_star,
                         bg_step_trial_t *out, bg_error_t *err);
bg_status bg_step_accept(bg_step_t *step, bg_step_motion_t *out, bg_error_t *err);
/* The committed state's summary (after set-up or an accept). */
void bg_step_motion(const bg_step_t *step, bg_step_motion_t *out);

#endif
