#include "bgb_watch.h"

#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"

/* A forwarded call whose time is not counted (the integration step: its
 * money accrues with the run's time). */
#define USE_NONE (-1)

typedef struct watch_session {
    bgb_watch_t *watch;
    void *inner;
} watch_session_t;

/* BG_OK while the job may go on; BG_ERR_CONFLICT once it may not. */
static bg_status watch_check(bgb_watch_t *w, bg_error_t *err)
{
    if (!w->stopped) {
        const double now = bg_clock_now();
        if (now < w->next_check)
            return BG_OK;
        w->next_check = now + BGB_WATCH_CHECK_SECONDS;
        w->stopped = !w->check(w->check_ctx);
        if (!w->stopped)
            return BG_OK;
    }
    return bg_error_set(err, BG_ERR_CONFLICT, "%s was stopped: the solve stopped", w->what);
}

/* Adds the seconds since t0 to the service's usage. */
static bg_status watch_used(bgb_watch_t *w, int service, double t0, bg_status st)
{
    if (w->used && service != USE_NONE)
        w->used[service] += bg_clock_now() - t0;
    return st;
}

/* The body of every forwarded service call: stop if the job was
 * cancelled, else call `op` of the inner backend and count its time. */
#define WATCH_FORWARD(service, op, ...)                                                            \
    watch_session_t *s = session;                                                                  \
    const bg_status st = watch_check(s->watch, err);                                               \
    if (st != BG_OK)                                                                               \
        return st;                                                                                 \
    const double t0 = bg_clock_now();                                                              \
    return watch_used(s->watch, service, t0, s->watch->inner->ops->op(s->inner, __VA_ARGS__, err))

static bg_status watch_session_new(void *ctx, void **session, bg_error_t *err)
{
    bgb_watch_t *w = ctx;
    *session = NULL;
    bg_status st = watch_check(w, err);
    if (st != BG_OK)
        return st;
    watch_session_t *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for a solver session");
    s->watch = w;
    if ((st = w->inner->ops->session_new(w->inner->ctx, &s->inner, err)) != BG_OK) {
        free(s);
        return st;
    }
    *session = s;
    return BG_OK;
}

static void watch_session_destroy(void *ctx, void *session)
{
    bgb_watch_t *w = ctx;
    watch_session_t *s = session;
    if (!s)
        return;
    w->inner->ops->session_destroy(w->inner->ctx, s->inner);
    free(s);
}

static bg_status watch_fit_open(void *session, int id, const bg_backend_fit_t *fit, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_ROTFIT, fit_open, id, fit);
}

static bg_status watch_fit_eval(void *session, int id, const double *q, double *energy,
                                double *grad, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_ROTFIT, fit_eval, id, q, energy, grad);
}

static bg_status watch_fit_hessian(void *session, int id, const double *q, int project,
                                   double scale, double *values, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_ROTFIT, fit_hessian, id, q, project, scale, values);
}

static bg_status watch_solve_open(void *session, int id, bg_sparse_t *sys, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_SOLVE, solve_open, id, sys);
}

static bg_status watch_solve_factor(void *session, int id, double shift, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_SOLVE, solve_factor, id, shift);
}

static bg_status watch_solve(void *session, int id, int nrhs, const double *rhs, double *x,
                             bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_SOLVE, solve, id, nrhs, rhs, x);
}

static void watch_solve_cost(void *session, int id, double *flops, double *nonzeros)
{
    watch_session_t *s = session;
    s->watch->inner->ops->solve_cost(s->inner, id, flops, nonzeros);
}

static bg_status watch_step_open(void *session, const bg_step_setup_t *setup,
                                 bg_step_motion_t *motion, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_open, setup, motion);
}

static bg_status watch_step_predict(void *session, const bg_step_request_t *req,
                                    bg_step_prediction_t *out, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_predict, req, out);
}

static bg_status watch_step_update(void *session, const double *q_star, const double *grad_star,
                                   bg_step_trial_t *out, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_update, q_star, grad_star, out);
}

static bg_status watch_step_accept(void *session, bg_step_motion_t *motion, bg_error_t *err)
{
    WATCH_FORWARD(USE_NONE, step_accept, motion);
}

static bg_status watch_surface_open(void *session, const bg_mesh_t *mesh, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_ROTFIT, surface_open, mesh);
}

static bg_status watch_surface_eval(void *session, const double *q, double *energy, double *grad,
                                    bg_rotfit_stats_t *stats, bg_error_t *err)
{
    WATCH_FORWARD(BGB_WATCH_ROTFIT, surface_eval, q, energy, grad, stats);
}

/* The inner backend (in process or agents) implements every operation. */
static const bg_backend_ops_t watch_ops = {
    .name = "stops on cancel",
    .session_new = watch_session_new,
    .session_destroy = watch_session_destroy,
    .fit_open = watch_fit_open,
    .fit_eval = watch_fit_eval,
    .fit_hessian = watch_fit_hessian,
    .solve_open = watch_solve_open,
    .solve_factor = watch_solve_factor,
    .solve = watch_solve,
    .solve_cost = watch_solve_cost,
    .step_open = watch_step_open,
    .step_predict = watch_step_predict,
    .step_update = watch_step_update,
    .step_accept = watch_step_accept,
    .surface_open = watch_surface_open,
    .surface_eval = watch_surface_eval,
};

void bgb_watch_init(bgb_watch_t *w, bgb_watch_check_fn check, void *check_ctx, const char *what,
                    const bg_backend_t *inner, double *used)
{
    memset(w, 0, sizeof *w);
    w->check = check;
    w->check_ctx = check_ctx;
    w->what = what;
    w->used = used;
    w->inner = inner ? inner : bg_backend_local();
    w->backend.ops = &watch_ops;
    w->backend.ctx = w;
}
