#include "bg_backend.h"

#include <stdlib.h>

#include "bg_surface_cells.h"

/* The in-process backend: the solver's own models and systems, called
 * directly. A session only remembers which object serves which id. */
typedef struct local_session {
    bg_elastic_t *fit[BG_BACKEND_MAX_FITS];
    bg_sparse_t *sys[BG_BACKEND_MAX_SYSTEMS];
    bg_step_t *step;
    bg_surface_cells_t *cells;
} local_session;

static bg_status local_session_new(void *ctx, void **session, bg_error_t *err)
{
    (void)ctx;
    local_session *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for a solver session");
    *session = s;
    return BG_OK;
}

static void local_session_destroy(void *ctx, void *session)
{
    (void)ctx;
    local_session *s = session;
    if (s) {
        bg_step_destroy(&s->step);
        bg_surface_cells_destroy(&s->cells);
    }
    free(s);
}

static bg_status local_fit_open(void *session, int id, const bg_backend_fit_t *fit,
                                bg_error_t *err)
{
    (void)err;
    ((local_session *)session)->fit[id] = fit->model;
    return BG_OK;
}

static bg_status local_fit_eval(void *session, int id, const double *q, double *energy,
                                double *grad, bg_error_t *err)
{
    (void)err;
    *energy = bg_elastic_eval(((local_session *)session)->fit[id], q, grad);
    return BG_OK;
}

static bg_status local_fit_hessian(void *session, int id, const double *q, int project,
                                   double scale, double *values, bg_error_t *err)
{
    (void)err;
    local_session *s = session;
    /* Newton's reordered Hessian has a vertex-block map in its model's
     * element order: ten block positions per tetrahedron instead of 78
     * entries (most elements), the same values. Another model (a morph
     * target's) visits its elements in another order: the entry map. */
    const bg_elastic_tet_blocks_t *blocks = bg_sparse_tet_blocks(s->sys[0]);
    if (blocks && bg_sparse_tet_blocks_order(s->sys[0]) == bg_elastic_order(s->fit[id]))
        bg_elastic_assemble_hessian_blocks(s->fit[id], q, project, scale, blocks,
                                           bg_sparse_scatter(s->sys[0]), values);
    else
        bg_elastic_assemble_hessian(s->fit[id], q, project, scale, bg_sparse_scatter(s->sys[0]),
                                    values);
    return BG_OK;
}

static bg_status local_solve_open(void *session, int id, bg_sparse_t *sys, bg_error_t *err)
{
    (void)err;
    ((local_session *)session)->sys[id] = sys;
    return BG_OK;
}

static bg_status local_solve_factor(void *session, int id, double shift, bg_error_t *err)
{
    return bg_sparse_factorize(((local_session *)session)->sys[id], shift, err);
}

static bg_status local_solve(void *session, int id, int nrhs, const double *rhs, double *x,
                             bg_error_t *err)
{
    return bg_sparse_solve_many(((local_session *)session)->sys[id], nrhs, rhs, x, err);
}

static void local_solve_cost(void *session, int id, double *flops, double *nonzeros)
{
    const bg_sparse_t *sys = ((local_session *)session)->sys[id];
    *flops = bg_sparse_factor_flops(sys);
    *nonzeros = bg_sparse_factor_nonzeros(sys);
}

static bg_status local_step_open(void *session, const bg_step_setup_t *setup,
                                 bg_step_motion_t *motion, bg_error_t *err)
{
    local_session *s = session;
    if (s->step)
        return bg_error_set(err, BG_ERR_INVALID, "this session already holds a step state");
    bg_status st = bg_step_new(setup, &s->step, err);
    if (st == BG_OK)
        bg_step_motion(s->step, motion);
    return st;
}

static bg_status no_step(bg_error_t *err)
{
    return bg_error_set(err, BG_ERR_INVALID, "integration step called before step_open");
}

static bg_status local_step_predict(void *session, const bg_step_request_t *req,
                                    bg_step_prediction_t *out, bg_error_t *err)
{
    local_session *s = session;
    return s->step ? bg_step_predict(s->step, req, out, err) : no_step(err);
}

static bg_status local_step_update(void *session, const double *q_star, const double *grad_star,
                                   bg_step_trial_t *out, bg_error_t *err)
{
    local_session *s = session;
    return s->step ? bg_step_update(s->step, q_star, grad_star, out, err) : no_step(err);
}

static bg_status local_step_accept(void *session, bg_step_motion_t *motion, bg_error_t *err)
{
    local_session *s = session;
    return s->step ? bg_step_accept(s->step, motion, err) : no_step(err);
}

static bg_status local_surface_open(void *session, const bg_mesh_t *mesh, bg_error_t *err)
{
    local_session *s = session;
    bg_surface_cells_destroy(&s->cells);
    return bg_surface_cells_new(mesh, NULL, &s->cells, err);
}

static bg_status local_surface_eval(void *session, const double *q, double *energy, double *grad,
                                    bg_rotfit_stats_t *stats, bg_error_t *err)
{
    local_session *s = session;
    if (!s->cells)
        return bg_error_set(err, BG_ERR_INVALID, "surface rotation fit before surface_open");
    *energy = bg_surface_cells_eval(s->cells, q, grad, stats);
    return BG_OK;
}

static const bg_backend_ops_t local_ops = {
    "in-process",       local_session_new,  local_session_destroy, local_fit_open,
    local_fit_eval,     local_fit_hessian,  local_solve_open,      local_solve_factor,
    local_solve,        local_solve_cost,   local_step_open,       local_step_predict,
    local_step_update,  local_step_accept,  local_surface_open,    local_surface_eval,
};

static const bg_backend_t local_backend = {&local_ops, NULL};

const bg_backend_t *bg_backend_local(void)
{
    return &local_backend;
}
