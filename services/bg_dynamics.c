#include "bg_dynamics.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"

#define DYNAMICS_DEFAULT_MAX_ITERATIONS 200

typedef struct state {
    size_t ndof;
    int n;
    int32_t nv;
    const double *mass;
    double *q, *p, *v, *v_prev, *y, *t0, *t1, *targets, *grad, *start, *work;
} state_t;

static void state_release(state_t *s)
{
    free(s->q);
    free(s->p);
    free(s->v);
    free(s->v_prev);
    free(s->y);
    free(s->t0);
    free(s->t1);
    free(s->targets);
    free(s->grad);
    free(s->start);
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

/*
 * The force scale a step's residual is measured against: the load
 * ‖M g‖, the momentum flux (2/h)‖p‖ and the current net force ‖∇W(q_k)‖
 * (s->grad holds ∇W at q_k after record()). A residual τ times this
 * changes momentum by at most 2τ‖p‖ + hτ(…) per step, so τ sets the
 * accuracy of the integration independently of how good the start is.
 */
static double force_scale(const state_t *s, const bg_scene_t *scene, double h, double *work)
{
    for (size_t i = 0; i < s->ndof; i++)
        work[i] = s->mass[i / (size_t)s->n] * scene->gravity[i % (size_t)s->n];
    return free_norm(scene, work, s->ndof, 1.0) + free_norm(scene, s->p, s->ndof, 2.0 / h) +
           free_norm(scene, s->grad, s->ndof, 1.0);
}

static void record(const state_t *s, bg_solver_t *solver, double time, bg_step_record_t *rec)
{
    memset(rec, 0, sizeof *rec);
    rec->time = time;
    rec->potential = bg_solver_potential(solver, s->q, s->grad);
    for (int32_t v = 0; v < s->nv; v++) {
        const double *q = s->q + (size_t)v * s->n, *p = s->p + (size_t)v * s->n;
        double r[3] = {0, 0, 0}, m[3] = {0, 0, 0};
        for (int c = 0; c < s->n; c++) {
            rec->kinetic += 0.5 * p[c] * p[c] / s->mass[v];
            rec->linear_momentum[c] += p[c];
            r[c] = q[c];
            m[c] = p[c];
        }
        rec->angular_momentum[0] += r[1] * m[2] - r[2] * m[1];
        rec->angular_momentum[1] += r[2] * m[0] - r[0] * m[2];
        rec->angular_momentum[2] += r[0] * m[1] - r[1] * m[0];
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
    const double decay = exp(-scene->dynamic.damping * h);
    const double c = variational ? 4.0 / (h * h) : 1.0 / (h * h);

    st = bg_solver_new(scene, BG_METHOD_NEWTON, &solver, err);
    if (st != BG_OK)
        goto out;
    s.n = scene->mesh->dim;
    s.nv = scene->mesh->nv;
    s.ndof = (size_t)s.nv * s.n;
    s.mass = bg_solver_mass(solver);
    double **arrays[] = {&s.q,  &s.p,  &s.v,       &s.v_prev, &s.y,    &s.t0,
                         &s.t1, &s.targets, &s.grad, &s.start, &s.work};
    for (size_t i = 0; i < sizeof arrays / sizeof *arrays; i++) {
        *arrays[i] = calloc(s.ndof + 1, sizeof(double));
        if (!*arrays[i]) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the time integration");
            goto out;
        }
    }
    bg_scene_targets_at(scene, 0.0, s.t0);
    for (size_t i = 0; i < s.ndof; i++) {
        s.q[i] = scene->constrained[i] ? s.t0[i] : scene->initial[i];
        s.v[i] = scene->velocity && !scene->constrained[i] ? scene->velocity[i] : 0.0;
        s.p[i] = s.mass[i / (size_t)s.n] * s.v[i];
    }

    bg_step_record_t rec;
    record(&s, solver, 0.0, &rec);
    const double E0 = rec.total_energy;
    bg_trace_point_t pt = {bg_clock_now() - t_start, 0, E0, 0.0, 0.0, 0.0};
    if (push(res, &trace_cap, &step_cap, &pt, &rec) != BG_OK) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the step records");
        goto out;
    }
    if (opt->frame && (st = opt->frame(opt->frame_ctx, 0, 0.0, s.q, err)) != BG_OK)
        goto out;

    res->converged = 1;
    res->stop_reason = "completed";
    const bg_inertia_t inertia = {c, s.y};
    for (int k = 0; k < steps; k++) {
        const double t_step = bg_clock_now();
        const double t1 = (k + 1) * h;
        bg_scene_targets_at(scene, t1, s.t1);
        /* The inertial prediction y (the minimiser without forces) starts
         * the solve; the constrained coordinates sit at the midpoint of
         * their prescribed path (variational) or at its end (Euler). */
        for (size_t i = 0; i < s.ndof; i++) {
            const double m = s.mass[i / (size_t)s.n];
            s.y[i] = variational ? s.q[i] + 0.5 * h * s.p[i] / m : s.q[i] + h * s.v[i];
            s.targets[i] = variational ? 0.5 * (s.t0[i] + s.t1[i]) : s.t1[i];
            /* The starting guess extrapolates the velocity from the last two
             * steps (a ≈ (v_k − v_{k−1})/h carries every force, elastic ones
             * included, to second order); the first step knows only gravity:
             * under a constant load the step lands on y + (h²/4)g (midpoint)
             * or y + h²g (Euler). */
            const double reach = variational ? 0.5 * h : h;
            if (k > 0)
                s.start[i] = s.q[i] + reach * (s.v[i] + 0.5 * reach / h * (s.v[i] - s.v_prev[i]) *
                                                             (variational ? 1.0 : 2.0));
            else
                s.start[i] = s.y[i] + (variational ? 0.25 : 1.0) * h * h *
                                          scene->gravity[i % (size_t)s.n];
        }
        const double tau = opt->tolerance > 0.0 ? opt->tolerance : scene->tolerance;
        const bg_solve_options_t so = {
            .method = BG_METHOD_NEWTON,
            .tolerance = 0.0, /* the absolute, force-scaled test below decides */
            .max_iterations =
                opt->max_iterations > 0 ? opt->max_iterations : DYNAMICS_DEFAULT_MAX_ITERATIONS,
            .absolute_tolerance = tau * force_scale(&s, scene, h, s.work),
            .targets = s.targets,
            .inertia = &inertia,
            .start = s.start,
        };
        bg_solve_result_t inner = BG_SOLVE_RESULT_INIT;
        st = bg_solver_minimize(solver, &so, &inner, err);
        if (st != BG_OK)
            goto out;
        const int settled = inner.converged || inner.roundoff_floor;
        if (!settled && res->converged) {
            res->converged = 0;
            res->stop_reason = "an inner solve did not converge";
        }
        bg_solve_result_accumulate(res, &inner);
        memcpy(s.v_prev, s.v, s.ndof * sizeof *s.v);
        const double *qs = inner.q;
        if (variational) {
            /* p_{k+1} = M v − (h/2) ∇W(q*) on free coordinates. */
            bg_solver_potential(solver, qs, s.grad);
            for (size_t i = 0; i < s.ndof; i++) {
                const double m = s.mass[i / (size_t)s.n];
                s.v[i] = 2.0 * (qs[i] - s.q[i]) / h;
                s.p[i] = m * s.v[i] - (scene->constrained[i] ? 0.0 : 0.5 * h * s.grad[i]);
                s.q[i] = 2.0 * qs[i] - s.q[i];
            }
        } else {
            for (size_t i = 0; i < s.ndof; i++) {
                s.v[i] = (qs[i] - s.q[i]) / h;
                s.p[i] = s.mass[i / (size_t)s.n] * s.v[i];
                s.q[i] = qs[i];
            }
        }
        for (size_t i = 0; i < s.ndof; i++) {
            s.p[i] *= decay;
            s.v[i] = s.p[i] / s.mass[i / (size_t)s.n];
            if (scene->constrained[i])
                s.q[i] = s.t1[i];
        }
        memcpy(s.t0, s.t1, s.ndof * sizeof *s.t0);
        const double inner_gradient = inner.gradient_norm, inner_relative = inner.relative_gradient;
        const int inner_iterations = inner.iterations;
        bg_solve_result_release(&inner);

        record(&s, solver, t1, &rec);
        rec.iterations = inner_iterations;
        rec.seconds = bg_clock_now() - t_step;
        if (!isfinite(rec.total_energy)) {
            st = bg_error_set(err, BG_ERR_NUMERIC, "%s: the energy is not finite at step %d",
                              scene->path, k + 1);
            goto out;
        }
        pt.seconds = bg_clock_now() - t_start;
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
        if (opt->frame && ((k + 1) % every == 0 || k + 1 == steps) &&
            (st = opt->frame(opt->frame_ctx, k + 1, t1, s.q, err)) != BG_OK)
            goto out;
    }
    res->energy = rec.total_energy;
    res->q = malloc(s.ndof * sizeof *res->q + 1);
    res->energy_density = malloc((size_t)scene->mesh->ne * sizeof *res->energy_density + 1);
    if (!res->q || !res->energy_density) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the result");
        goto out;
    }
    memcpy(res->q, s.q, s.ndof * sizeof *res->q);
    memcpy(res->energy_density, bg_solver_energy_density(solver),
           (size_t)scene->mesh->ne * sizeof *res->energy_density);
    res->wall_seconds = bg_clock_now() - t_start;
out:
    bg_solver_destroy(&solver);
    state_release(&s);
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}
