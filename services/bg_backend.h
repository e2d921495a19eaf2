/*
 * bg_backend — the seam between the static solver (bg_static) and its
 * basic services: rotation-fit (energy and gradient, Hessian values into
 * the fixed sparse pattern) and sparse-solve (factor the pattern's values
 * plus a diagonal shift, keep the factor, solve with it).
 *
 * A backend is a table of functions and a context. The solver opens one
 * session per bg_solver_t and, inside it, one rotation-fit per rest shape
 * (id 0: the scene's, 1: a morph target) and one sparse system per matrix
 * (id 0: Newton's Hessian, 1..3: local/global's and quasi-newton's
 * per-coordinate Laplacians, 4..6: the same matrices factored with a second
 * inertia coefficient, for a time integration whose quasi-newton steps use
 * two: bg_static's STATIC_LG_SLOTS). The solver keeps owning its bg_elastic
 * models and bg_sparse systems: the values of a system are assembled into the solver's own
 * bg_sparse_values array and the backend factors those values. The local
 * backend (bg_backend_local) computes with those very objects; a remote
 * one (agents/bga_backend) sends them to agents.
 *
 * Contracts: fit_eval has the contract of bg_elastic_eval (energy into
 * *energy, gradient overwritten, rotations warm-started from the previous
 * call of the same fit); fit_hessian that of bg_elastic_assemble_hessian
 * at the positions of the last fit_eval (scale times the element Hessians
 * added into values). solve_factor returns BG_ERR_NUMERIC when the matrix
 * plus shift·I is not positive definite (the caller may retry with a
 * larger shift). A failed call may leave the session unusable: every later
 * call then fails with the same error, promptly (never another timeout).
 *
 * integration-step: step_open sets up a dynamic run's state (bg_step.h)
 * where the backend keeps it — in this process (local) or on an
 * integration-step agent — and step_predict / step_update / step_accept
 * have the contracts of bg_step_predict / _update / _accept. The arrays
 * in their outputs are borrowed from the session until its next step
 * call. A session opens at most one step state; bg_dynamics uses a session
 * of its own for it, so a static job never opens one (and never contacts
 * an integration-step agent).
 */
#ifndef BG_BACKEND_H
#define BG_BACKEND_H

#include <stddef.h>
#include <stdint.h>

#include "bg_elastic.h"
#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_rotfit.h"
#include "bg_sparse.h"
#include "bg_step.h"

#define BG_BACKEND_MAX_FITS 2
#define BG_BACKEND_MAX_SYSTEMS 7

/* One rest shape for rotation-fit. Borrowed for the session's life. */
typedef struct bg_backend_fit {
    bg_elastic_t *model;       /* the solver's model of this rest shape */
    const bg_mesh_t *mesh;     /* connectivity; rest positions in mesh->x unless rest_edges */
    const double *rest_edges;  /* ne*dim*dim rest edge matrices, or NULL */
    double mu, lambda, barrier;
    const int32_t *scatter;    /* the Newton pattern's scatter map (ne*T), or NULL */
    size_t nval;               /* entries of the pattern's value array */
} bg_backend_fit_t;

typedef struct bg_backend_ops {
    const char *name; /* "in-process", "agents" */
    bg_status (*session_new)(void *ctx, void **session, bg_error_t *err);
    void (*session_destroy)(void *ctx, void *session);
    bg_status (*fit_open)(void *session, int id, const bg_backend_fit_t *fit, bg_error_t *err);
    bg_status (*fit_eval)(void *session, int id, const double *q, double *energy, double *grad,
                          bg_error_t *err);
    bg_status (*fit_hessian)(void *session, int id, const double *q, int project, double scale,
                             double *values, bg_error_t *err);
    /* sys is borrowed for the session's life (its pattern and its values).
     * A backend may renumber a system not marked bg_sparse_prefer_solves
     * here (bg_sparse_reorder, which rewrites its scatter map in place and
     * keeps the caller's numbering in every vector call), so a caller
     * opens a system before it hands its scatter map to fit_open and
     * before it writes any value. */
    bg_status (*solve_open)(void *session, int id, bg_sparse_t *sys, bg_error_t *err);
    bg_status (*solve_factor)(void *session, int id, double shift, bg_error_t *err);
    /* nrhs right-hand sides of system id at once (column-major, 1 to
     * BG_SPARSE_MAX_RHS): one pass over the factor and one round trip. */
    bg_status (*solve)(void *session, int id, int nrhs, const double *rhs, double *x,
                       bg_error_t *err);
    /* The cost model of system id's factor (bg_sparse_factor_flops and
     * _nonzeros of whoever factors it; 0 before the first factor): the
     * solver's refactoring rule must see the same figures either way. */
    void (*solve_cost)(void *session, int id, double *flops, double *nonzeros);
    /* motion: the start state's summary (bg_step_motion). */
    bg_status (*step_open)(void *session, const bg_step_setup_t *setup, bg_step_motion_t *motion,
                           bg_error_t *err);
    bg_status (*step_predict)(void *session, const bg_step_request_t *req,
                              bg_step_prediction_t *out, bg_error_t *err);
    bg_status (*step_update)(void *session, const double *q_star, const double *grad_star,
                             bg_step_trial_t *out, bg_error_t *err);
    bg_status (*step_accept)(void *session, bg_step_motion_t *motion, bg_error_t *err);
    /* The surface editor's rotation fit (bg_surface_arap.h): the cells of
     * every vertex of mesh (borrowed for the session's life; rest positions
     * in mesh->x), evaluated with the contract of bg_surface_cells_eval
     * (energy, gradient overwritten; stats may stay 0 when remote). */
    bg_status (*surface_open)(void *session, const bg_mesh_t *mesh, bg_error_t *err);
    bg_status (*surface_eval)(void *session, const double *q, double *energy, double *grad,
                              bg_rotfit_stats_t *stats, bg_error_t *err);
} bg_backend_ops_t;

typedef struct bg_backend {
    const bg_backend_ops_t *ops;
    void *ctx; /* owned by whoever made the backend; outlives every session */
} bg_backend_t;

/* The in-process implementation (static storage, no context). */
const bg_backend_t *bg_backend_local(void);

#endif
