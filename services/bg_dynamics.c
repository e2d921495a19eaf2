#include "bg_dynamics.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"

#define DYNAMICS_DEFAULT_MAX_ITERATIONS 200
/* The energy limiter's slack: a midpoint step may raise the total energy
 * above the budget (initial energy plus the handles' work) by this fraction
 * of the largest mechanical energy (kinetic plus elastic) seen so far. The
 * midpoint rule's own bounded oscillation is O(h²) and far smaller on every
 * resolved scene (bar-spin: 5e-5); the nonlinear instability of stiff
 * modes grows the energy by factors within a few steps. */
#define DYNAMICS_ENERGY_SLACK 1e-2

/* The coordinator's side of a run: the integration-step state (q_k, p_k,
 * velocities) lives behind the backend's step service; this keeps what
 * the inner solve and the records need. */
typedef struct state {
    size_t ndof;
    int n;
    const double *mass;
    const bg_backend_t *backend;
    void *session; /* the step service's own session */
    double *q;     /* q_k, copied from the service's last motion summary */
    double *t1, *grad, *grad_next, *work;
    double step_seconds; /* in the step service's calls */
} state_t;

static void state_release(state_t *s)
{
    if (s->session)
        s->backend->ops->session_destroy(s->backend->ctx, s->session);
    free(s->q);
    free(s->t1);
    free(s->grad);
    free(s->grad_next);
    free(s->work);
}

/* Euclidean norm over free coordinates. */
static double free_norm(const bg_scene_t *scene, const double *x, size_t n, double scale)
{
    double sum = 0.0;
    for (size_t i = 0; i < n; i++)
        if (!scene->constrained[i])
            sum += x[i] * x[i];
    return scale * sqrt(sum);
}

/* Copies the service's motion summary into s->q and the record (the
 * potential at q_k, with ∇W(q_k) into s->grad). */
static void record(state_t *s, bg_solver_t *solver, const bg_step_motion_t *motion, double time,
                   bg_step_record_t *rec)
{
    memcpy(s->q, motion->q, s->ndof * sizeof *s->q);
    memset(rec, 0, sizeof *rec);
    rec->time = time;
    rec->potential = bg_solver_potential(solver, s->q, s->grad);
    rec->kinetic = motion->kinetic;
    for (int c = 0; c < 3; c++) {
        rec->linear_momentum[c] = motion->linear[c];
        rec->angular_momentum[c] = motion->angular[c];
    }
    rec->total_energy = rec->kinetic + rec->potential;
}

static bg_status grow(void **array, int *cap, int count, size_t size)
{
    if (count < *cap)
        return BG_OK;
    int grown = *cap ? 2 * *cap : 256;
    void *a = realloc(*array, (size_t)grown * size);
    if (!a)
        return BG_ERR_NOMEM;
    *array = a;
    *cap = grown;
    return BG_OK;
}

static bg_status push(bg_solve_result_t *res, int *trace_cap, int *step_cap,
                      const bg_trace_point_t *pt, const bg_step_record_t *rec)
{
    if (grow((void **)&res->trace, trace_cap, res->trace_count, sizeof *pt) != BG_OK ||
        grow((void **)&res->steps, step_cap, res->step_count, sizeof *rec) != BG_OK)
        return BG_ERR_NOMEM;
    res->trace[res->trace_count++] = *pt;
    res->steps[res->step_count++] = *rec;
    return BG_OK;
}

/* The step's ancillary energy ε(x) = W(x) + (c/2) Σ m |x − y|² (up to a
 * constant), x's constrained coordinates already at their targets. */
static double ancillary(const state_t *s, bg_solver_t *solver, double c, const double *y,
                        const double *x)
{
    double e = bg_solver_potential(solver, x, s->work);
    for (size_t i = 0; i < s->ndof; i++) {
        const double d = x[i] - y[i];
        e += 0.5 * c * s->mass[i / (size_t)s->n] * d * d;
    }
    return e;
}

/*
 * The start of a step's solve among the service's candidates (bg_step.c:
 * the velocity extrapolation, the inertial prediction plus the load, q_k).
 * Which one is closest depends on the motion — extrapolation wins on
 * smooth rigid motion, q_k on a soft body whose finest modes ring
 * (ωh ≫ 1), where extrapolating their velocities overshoots — so
 * BG_PREDICTOR_BEST evaluates ε at each and keeps the lowest (the first
 * of equals): a few energy evaluations, against tens of iterations a poor
 * start costs.
 */
static const double *choose_start(const state_t *s, bg_solver_t *solver,
                                  const bg_step_prediction_t *pr, bg_predictor predictor)
{
    if (predictor != BG_PREDICTOR_BEST)
        return pr->candidate[0];
    const double *start = NULL;
    double best = INFINITY;
    for (int j = 0; j < pr->ncandidates; j++) {
        const double e = ancillary(s, solver, pr->coefficient, pr->y, pr->candidate[j]);
        if (start && !(e < best))
            continue;
        best = e;
        start = pr->candidate[j];
    }
    return start;
}

/* W(x) + K: the total energy of a trial state whose kinetic energy the
 * step service computed (s->work as scratch). */
static double total_energy(const state_t *s, bg_solver_t *solver, const double *x, double kinetic)
{
    return bg_solver_potential(solver, x, s->work) + kinetic;
}

/* Σ_v m_v g·x_v: what W subtracts from the elastic energy. */
static double gravity_work(const state_t *s, const bg_scene_t *scene, const double *x)
{
    double w = 0.0;
    for (size_t i = 0; i < s->ndof; i++)
        w += s->mass[i / (size_t)s->n] * scene->gravity[i % (size_t)s->n] * x[i];
    return w;
}

/*
 * One trial of the step from the committed state to the targets s->t1:
 * the midpoint rule or backward Euler (trial 1: the redo of a rejected
 * first trial). The step service predicts, the inner Newton solve
 * minimises the step energy, the service computes the trial end state
 * into *trial (not committed: the caller accepts it or redoes the step).
 */
static bg_status advance(state_t *s, bg_solver_t *solver, const bg_scene_t *scene,
                         const bg_dynamic_options_t *opt, int variational, int redo,
                         bg_solve_result_t *inner, bg_step_trial_t *trial, bg_error_t *err)
{
    const bg_backend_ops_t *ops = s->backend->ops;
    const bg_step_request_t req = {variational, redo, (int)opt->predictor, s->t1};
    bg_step_prediction_t pr;
    double tv = bg_clock_now();
    bg_status st = ops->step_predict(s->session, &req, &pr, err);
    s->step_seconds += bg_clock_now() - tv;
    if (st != BG_OK)
        return st;
    const double *start = choose_start(s, solver, &pr, opt->predictor);
    const double tau = opt->tolerance > 0.0 ? opt->tolerance : scene->tolerance;
    const bg_inertia_t inertia = {pr.coefficient, pr.y};
    /* The force scale a step's residual is measured against: the load
     * ‖M g‖, the momentum flux (2/h)‖p‖ (the service's part) and the
     * current net force ‖∇W(q_k)‖. A residual τ times this changes
     * momentum by at most 2τ‖p‖ + hτ(…) per step, so τ sets the accuracy
     * of the integration independently of how good the start is. */
    const double force_scale = pr.state_scale + free_norm(scene, s->grad, s->ndof, 1.0);
    const bg_solve_options_t so = {
        .method = scene->inner,
        .tolerance = 0.0, /* the absolute, force-scaled test decides */
        .max_iterations =
            opt->max_iterations > 0 ? opt->max_iterations : DYNAMICS_DEFAULT_MAX_ITERATIONS,
        .absolute_tolerance = tau * force_scale,
        .targets = pr.targets,
        .inertia = &inertia,
        .start = start,
        /* Newton keeps its factored matrix across steps; quasi-newton keeps
         * its own (the Laplacian plus cM, one per c) whatever this says. */
        .reuse_factor = scene->inner == BG_METHOD_NEWTON && !opt->fresh_factor,
    };
    st = bg_solver_minimize(solver, &so, inner, err);
    if (st != BG_OK)
        return st;
    bg_solver_potential(solver, inner->q, s->grad_next);
    tv = bg_clock_now();
    st = ops->step_update(s->session, inner->q, s->grad_next, trial, err);
    s->step_seconds += bg_clock_now() - tv;
    return st;
}

bg_status bg_dynamic_solve(const bg_scene_t *scene, const bg_dynamic_options_t *opt,
                           bg_solve_result_t *res, bg_error_t *err)
{
    memset(res, 0, sizeof *res);
    res->method = opt->method;
    const double t_start = bg_clock_now();
    state_t s = {0};
    bg_solver_t *solver = NULL;
    bg_status st = BG_OK;
    int trace_cap = 0, step_cap = 0;
    double *velocity = NULL, *t0 = NULL;
    const int variational = opt->method == BG_METHOD_VARIATIONAL;
    if (!bg_method_is_dynamic(opt->method))
        return bg_error_set(err, BG_ERR_INVALID, "%s is not a time integrator (use variational "
                            "or backward-euler)", bg_method_name(opt->method));
    const double h = opt->dt > 0.0 ? opt->dt : scene->dynamic.dt;
    int steps = opt->steps > 0 ? opt->steps : scene->dynamic.steps;
    if (opt->duration > 0.0 && h > 0.0)
        steps = (int)lround(opt->duration / h);
    if (!(h > 0.0) || steps < 1)
        return bg_error_set(err, BG_ERR_INVALID, "%s: a dynamic run needs a positive time step "
                            "and at least one step", scene->path);
    const int every = opt->output_every > 0          ? opt->output_every
                      : scene->dynamic.output_every > 0 ? scene->dynamic.output_every
                                                         : 1;
    const int limit = variational && scene->dynamic.energy_limit;

    if (scene->inner != BG_METHOD_NEWTON && scene->inner != BG_METHOD_QUASI_NEWTON)
        return bg_error_set(err, BG_ERR_INVALID, "%s: %s cannot solve a time step (use newton "
                            "or quasi-newton)", scene->path, bg_method_name(scene->inner));
    st = bg_solver_new_on(scene, scene->inner, opt->backend, &solver, err);
    if (st != BG_OK)
        goto out;
    s.n = scene->mesh->dim;
    s.ndof = (size_t)scene->mesh->nv * s.n;
    s.mass = bg_solver_mass(solver);
    if (!s.mass) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the mass matrix");
        goto out;
    }
    double **arrays[] = {&s.q, &s.t1, &s.grad, &s.grad_next, &s.work, &velocity, &t0};
    for (size_t i = 0; i < sizeof arrays / sizeof *arrays; i++) {
        *arrays[i] = calloc(s.ndof + 1, sizeof(double));
        if (!*arrays[i]) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the time integration");
            goto out;
        }
    }
    /* The step service gets a session of its own: its state is the run's,
     * not the solver's, and only a dynamic run opens it. */
    s.backend = opt->backend && opt->backend->ops->step_open ? opt->backend : bg_backend_local();
    double tv = bg_clock_now();
    st = s.backend->ops->session_new(s.backend->ctx, &s.session, err);
    if (st != BG_OK)
        goto out;
    bg_scene_targets_at(scene, 0.0, t0);
    for (size_t i = 0; i < s.ndof; i++) {
        s.q[i] = scene->constrained[i] ? t0[i] : scene->initial[i];
        velocity[i] = scene->velocity && !scene->constrained[i] ? scene->velocity[i] : 0.0;
    }
    const bg_step_setup_t setup = {s.n,      scene->mesh->nv,     h,      scene->dynamic.damping,
                                   s.mass,   s.q,                 velocity, t0,
                                   scene->constrained, scene->gravity};
    bg_step_motion_t motion;
    st = s.backend->ops->step_open(s.session, &setup, &motion, err);
    s.step_seconds += bg_clock_now() - tv;
    if (st != BG_OK)
        goto out;

    bg_step_record_t rec;
    record(&s, solver, &motion, 0.0, &rec);
    const double E0 = rec.total_energy;
    bg_trace_point_t pt = {bg_clock_now() - t_start, 0, E0, 0.0, 0.0, 0.0, 0};
    if (push(res, &trace_cap, &step_cap, &pt, &rec) != BG_OK) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the step records");
        goto out;
    }
    if (opt->frame) {
        const double t_out = bg_clock_now();
        st = opt->frame(opt->frame_ctx, 0, 0.0, s.q, err);
        res->output_seconds += bg_clock_now() - t_out;
        if (st != BG_OK)
            goto out;
    }

    res->converged = 1;
    res->stop_reason = "completed";
    /* The energy budget: the initial energy plus the handles' work. */
    double budget = E0, scale = rec.kinetic + rec.potential + gravity_work(&s, scene, s.q);
    for (int k = 0; k < steps; k++) {
        const double t_step = bg_clock_now();
        const double t1 = (k + 1) * h;
        tv = bg_clock_now();
        bg_scene_targets_at(scene, t1, s.t1);
        res->vector_seconds += bg_clock_now() - tv;
        bg_solve_result_t inner = BG_SOLVE_RESULT_INIT;
        bg_step_trial_t trial;
        st = advance(&s, solver, scene, opt, variational, 0, &inner, &trial, err);
        if (st != BG_OK)
            goto out;
        int limited = 0;
        const double E_next =
            limit ? total_energy(&s, solver, trial.q_next, trial.kinetic) : 0.0;
        /* The mechanical energy the step ends with counts in the scale: a
         * body starting at rest has none before its first step. */
        const double mechanical = E_next + gravity_work(&s, scene, trial.q_next);
        if (limit &&
            E_next > budget + trial.handle_work + DYNAMICS_ENERGY_SLACK * fmax(scale, mechanical)) {
            /* The midpoint rule conserves a quadratic energy exactly but can
             * pump energy into stiff nonlinear modes (Simo and Tarnow 1992):
             * this step would have created energy, so it is redone with
             * backward Euler from the same state, which dissipates. */
            bg_solve_result_accumulate(res, &inner);
            bg_solve_result_release(&inner);
            st = advance(&s, solver, scene, opt, 0, 1, &inner, &trial, err);
            if (st != BG_OK)
                goto out;
            limited = 1;
            res->limited_steps++;
        }
        budget += trial.handle_work;
        /* Energy the limiter removed stays removed: the budget ratchets
         * down to the energy after a dissipative step. */
        if (limited)
            budget = fmin(budget, total_energy(&s, solver, trial.q_next, trial.kinetic));
        const int settled = inner.converged || inner.roundoff_floor;
        if (!settled && res->converged) {
            res->converged = 0;
            res->stop_reason = "an inner solve did not converge";
        }
        bg_solve_result_accumulate(res, &inner);
        tv = bg_clock_now();
        st = s.backend->ops->step_accept(s.session, &motion, err);
        s.step_seconds += bg_clock_now() - tv;
        if (st != BG_OK) {
            bg_solve_result_release(&inner);
            goto out;
        }
        const double inner_gradient = inner.gradient_norm, inner_relative = inner.relative_gradient;
        const int inner_iterations = inner.iterations;
        bg_solve_result_release(&inner);

        record(&s, solver, &motion, t1, &rec);
        tv = bg_clock_now();
        rec.iterations = inner_iterations;
        rec.limited = limited;
        rec.seconds = bg_clock_now() - t_step;
        scale = fmax(scale, rec.kinetic + rec.potential + gravity_work(&s, scene, s.q));
        res->vector_seconds += bg_clock_now() - tv;
        if (!isfinite(rec.total_energy)) {
            st = bg_error_set(err, BG_ERR_NUMERIC, "%s: the energy is not finite at step %d",
                              scene->path, k + 1);
            goto out;
        }
        tv = bg_clock_now();
        pt.seconds = tv - t_start;
        pt.iteration = k + 1;
        pt.energy = rec.total_energy;
        pt.gradient_norm = inner_gradient;
        pt.relative_gradient = inner_relative;
        pt.error = E0 != 0.0 ? fabs(rec.total_energy - E0) / fabs(E0) : fabs(rec.total_energy);
        if (push(res, &trace_cap, &step_cap, &pt, &rec) != BG_OK) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the step records");
            goto out;
        }
        if (opt->progress)
            opt->progress(opt->progress_ctx, opt->method, &pt);
        res->vector_seconds += bg_clock_now() - tv;
        if (opt->frame && ((k + 1) % every == 0 || k + 1 == steps)) {
            const double t_out = bg_clock_now();
            st = opt->frame(opt->frame_ctx, k + 1, t1, s.q, err);
            res->output_seconds += bg_clock_now() - t_out;
            if (st != BG_OK)
                goto out;
        }
    }
    res->energy = rec.total_energy;
    res->q = malloc(s.ndof * sizeof *res->q + 1);
    res->energy_density = malloc((size_t)scene->mesh->ne * sizeof *res->energy_density + 1);
    if (!res->q || !res->energy_density) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the result");
        goto out;
    }
    memcpy(res->q, s.q, s.ndof * sizeof *res->q);
    res->inverted_elements = bg_static_count_inverted(scene->mesh, s.q);
    res->gradient_roundoff = res->force_scale = NAN;
    memcpy(res->energy_density, bg_solver_energy_density(solver),
           (size_t)scene->mesh->ne * sizeof *res->energy_density);
    bg_solver_report(solver, res);
    /* The step service's calls (the integration-step agent's round trips
     * on a remote backend) count with the vector work. */
    res->vector_seconds += s.step_seconds;
    res->wall_seconds = bg_clock_now() - t_start;
    bg_solve_result_add_scene_prep(res, scene);
out:
    bg_solver_destroy(&solver);
    state_release(&s);
    free(velocity);
    free(t0);
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}
