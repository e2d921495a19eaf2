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

typedef struct state {
    size_t ndof;
    int n;
    int32_t nv;
    const double *mass;
    double *q, *p, *v, *v_prev, *y, *t0, *t1, *targets, *grad, *start, *work, *candidate;
    double *q_next, *p_next, *grad_next; /* a step's result before it is accepted */
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
    free(s->candidate);
    free(s->q_next);
    free(s->p_next);
    free(s->grad_next);
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

/* The step's ancillary energy ε(x) = W(x) + (c/2) Σ m |x − y|² (up to a
 * constant), x's constrained coordinates already at their targets. */
static double ancillary(const state_t *s, bg_solver_t *solver, double c, const double *x)
{
    double e = bg_solver_potential(solver, x, s->work);
    for (size_t i = 0; i < s->ndof; i++) {
        const double d = x[i] - s->y[i];
        e += 0.5 * c * s->mass[i / (size_t)s->n] * d * d;
    }
    return e;
}

/*
 * The start of a step's solve. Candidates: the last positions q_k; the
 * inertial prediction y plus the known load (under a constant load the step
 * lands on y + (h²/4)g for the midpoint rule, y + h²g for Euler); and, from
 * the second step on, a velocity extrapolation from the last two steps,
 * which carries every force to second order. Which one is closest depends
 * on the motion — extrapolation wins on smooth rigid motion, q_k on a soft
 * body whose finest modes ring (ωh ≫ 1), where extrapolating their
 * velocities overshoots — so BG_PREDICTOR_BEST evaluates ε at each and
 * keeps the lowest: a few energy evaluations, against tens of iterations a
 * poor start costs.
 */
static void choose_start(state_t *s, bg_solver_t *solver, const bg_scene_t *scene, double c,
                         int variational, double h, int k, bg_predictor predictor)
{
    static const bg_predictor kinds[3] = {BG_PREDICTOR_EXTRAPOLATE, BG_PREDICTOR_INERTIAL,
                                          BG_PREDICTOR_LAST};
    const double reach = variational ? 0.5 * h : h, load = (variational ? 0.25 : 1.0) * h * h;
    /* The first step has no velocity history: extrapolation is the load. */
    if (predictor == BG_PREDICTOR_EXTRAPOLATE && k == 0)
        predictor = BG_PREDICTOR_INERTIAL;
    double best = INFINITY;
    int have = 0;
    for (int j = 0; j < 3; j++) {
        const bg_predictor kind = kinds[j];
        if ((predictor != BG_PREDICTOR_BEST && predictor != kind) ||
            (kind == BG_PREDICTOR_EXTRAPOLATE && k == 0))
            continue;
        for (size_t i = 0; i < s->ndof; i++) {
            double x;
            if (scene->constrained[i])
                x = s->targets[i];
            else if (kind == BG_PREDICTOR_EXTRAPOLATE)
                x = s->q[i] + reach * (s->v[i] + 0.5 * reach / h * (s->v[i] - s->v_prev[i]) *
                                                     (variational ? 1.0 : 2.0));
            else if (kind == BG_PREDICTOR_INERTIAL)
                x = s->y[i] + load * scene->gravity[i % (size_t)s->n];
            else
                x = s->q[i];
            s->candidate[i] = x;
        }
        if (predictor == BG_PREDICTOR_BEST) {
            const double e = ancillary(s, solver, c, s->candidate);
            if (have && !(e < best))
                continue;
            best = e;
        }
        have = 1;
        double *swap = s->start;
        s->start = s->candidate;
        s->candidate = swap;
    }
}

/* Σ p²/2m + W(x): the total energy of a state (s->work as scratch). */
static double total_energy(const state_t *s, bg_solver_t *solver, const double *x,
                           const double *p)
{
    double e = bg_solver_potential(solver, x, s->work);
    for (size_t i = 0; i < s->ndof; i++)
        e += 0.5 * p[i] * p[i] / s->mass[i / (size_t)s->n];
    return e;
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
 * One step from (q_k, p_k, v_k) = (s->q, s->p, s->v) with targets s->t0 →
 * s->t1: the variational midpoint rule or backward Euler, into s->q_next
 * and s->p_next (before damping). *handle_work is the work the handles did
 * on the body over the step: with R the force they exert, the discrete
 * balance at a constrained coordinate reads (2/h)(m v̄ − p_k) = −∂W/∂q + R
 * (midpoint; (1/h)(m v − p_k) for Euler), and the work is R·(q_{k+1} − q_k).
 */
static bg_status advance(state_t *s, bg_solver_t *solver, const bg_scene_t *scene,
                         const bg_dynamic_options_t *opt, int variational, double h, int k,
                         bg_solve_result_t *inner, double *handle_work, bg_error_t *err)
{
    const double c = variational ? 4.0 / (h * h) : 1.0 / (h * h);
    double tv = bg_clock_now();
    /* y is the inertial prediction (the minimiser without forces); the
     * constrained coordinates sit at the midpoint of their prescribed path
     * (variational) or at its end (Euler). */
    for (size_t i = 0; i < s->ndof; i++) {
        const double m = s->mass[i / (size_t)s->n];
        s->y[i] = variational ? s->q[i] + 0.5 * h * s->p[i] / m : s->q[i] + h * s->v[i];
        s->targets[i] = variational ? 0.5 * (s->t0[i] + s->t1[i]) : s->t1[i];
    }
    const double t_loops = bg_clock_now() - tv;
    choose_start(s, solver, scene, c, variational, h, k, opt->predictor);
    const double tau = opt->tolerance > 0.0 ? opt->tolerance : scene->tolerance;
    const bg_inertia_t inertia = {c, s->y};
    const bg_solve_options_t so = {
        .method = BG_METHOD_NEWTON,
        .tolerance = 0.0, /* the absolute, force-scaled test decides */
        .max_iterations =
            opt->max_iterations > 0 ? opt->max_iterations : DYNAMICS_DEFAULT_MAX_ITERATIONS,
        .absolute_tolerance = tau * force_scale(s, scene, h, s->work),
        .targets = s->targets,
        .inertia = &inertia,
        .start = s->start,
        .reuse_factor = !opt->fresh_factor,
    };
    bg_status st = bg_solver_minimize(solver, &so, inner, err);
    if (st != BG_OK)
        return st;
    const double *qs = inner->q;
    bg_solver_potential(solver, qs, s->grad_next);
    tv = bg_clock_now();
    double work = 0.0;
    for (size_t i = 0; i < s->ndof; i++) {
        const double m = s->mass[i / (size_t)s->n];
        if (variational) {
            /* p_{k+1} = M v̄ − (h/2) ∇W(q*) on free coordinates. */
            const double vbar = 2.0 * (qs[i] - s->q[i]) / h;
            s->q_next[i] = 2.0 * qs[i] - s->q[i];
            if (scene->constrained[i]) {
                s->p_next[i] = m * vbar;
                work += ((2.0 / h) * (m * vbar - s->p[i]) + s->grad_next[i]) * h * vbar;
            } else {
                s->p_next[i] = m * vbar - 0.5 * h * s->grad_next[i];
            }
        } else {
            const double v = (qs[i] - s->q[i]) / h;
            s->q_next[i] = qs[i];
            s->p_next[i] = m * v;
            if (scene->constrained[i])
                work += ((m * v - s->p[i]) / h + s->grad_next[i]) * h * v;
        }
    }
    *handle_work = work;
    inner->vector_seconds += t_loops + (bg_clock_now() - tv);
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
    const int limit = variational && scene->dynamic.energy_limit;

    st = bg_solver_new_on(scene, BG_METHOD_NEWTON, opt->backend, &solver, err);
    if (st != BG_OK)
        goto out;
    s.n = scene->mesh->dim;
    s.nv = scene->mesh->nv;
    s.ndof = (size_t)s.nv * s.n;
    s.mass = bg_solver_mass(solver);
    if (!s.mass) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the mass matrix");
        goto out;
    }
    double **arrays[] = {&s.q,    &s.p,       &s.v,      &s.v_prev,    &s.y,
                         &s.t0,   &s.t1,      &s.targets, &s.grad,     &s.start,
                         &s.work, &s.candidate, &s.q_next, &s.p_next, &s.grad_next};
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
        double tv = bg_clock_now();
        bg_scene_targets_at(scene, t1, s.t1);
        res->vector_seconds += bg_clock_now() - tv;
        bg_solve_result_t inner = BG_SOLVE_RESULT_INIT;
        double work = 0.0;
        st = advance(&s, solver, scene, opt, variational, h, k, &inner, &work, err);
        if (st != BG_OK)
            goto out;
        int limited = 0;
        const double E_next = limit ? total_energy(&s, solver, s.q_next, s.p_next) : 0.0;
        /* The mechanical energy the step ends with counts in the scale: a
         * body starting at rest has none before its first step. */
        const double mechanical = E_next + gravity_work(&s, scene, s.q_next);
        if (limit && E_next > budget + work + DYNAMICS_ENERGY_SLACK * fmax(scale, mechanical)) {
            /* The midpoint rule conserves a quadratic energy exactly but can
             * pump energy into stiff nonlinear modes (Simo and Tarnow 1992):
             * this step would have created energy, so it is redone with
             * backward Euler from the same state, which dissipates. */
            bg_solve_result_accumulate(res, &inner);
            bg_solve_result_release(&inner);
            st = advance(&s, solver, scene, opt, 0, h, k, &inner, &work, err);
            if (st != BG_OK)
                goto out;
            limited = 1;
            res->limited_steps++;
        }
        budget += work;
        /* Energy the limiter removed stays removed: the budget ratchets
         * down to the energy after a dissipative step. */
        if (limited)
            budget = fmin(budget, total_energy(&s, solver, s.q_next, s.p_next));
        const int settled = inner.converged || inner.roundoff_floor;
        if (!settled && res->converged) {
            res->converged = 0;
            res->stop_reason = "an inner solve did not converge";
        }
        bg_solve_result_accumulate(res, &inner);
        tv = bg_clock_now();
        memcpy(s.v_prev, s.v, s.ndof * sizeof *s.v);
        for (size_t i = 0; i < s.ndof; i++) {
            s.q[i] = scene->constrained[i] ? s.t1[i] : s.q_next[i];
            s.p[i] = decay * s.p_next[i];
            s.v[i] = s.p[i] / s.mass[i / (size_t)s.n];
        }
        memcpy(s.t0, s.t1, s.ndof * sizeof *s.t0);
        const double inner_gradient = inner.gradient_norm, inner_relative = inner.relative_gradient;
        const int inner_iterations = inner.iterations;
        bg_solve_result_release(&inner);

        res->vector_seconds += bg_clock_now() - tv;
        record(&s, solver, t1, &rec);
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
    res->wall_seconds = bg_clock_now() - t_start;
    bg_solve_result_add_scene_prep(res, scene);
out:
    bg_solver_destroy(&solver);
    state_release(&s);
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}
