/*
 * The quasi-newton inner solve of a time step (solver.inner:
 * "quasi-newton"; bg_dynamics, bg_static): on the shipped dynamic scenes
 * it follows the Newton inner solve's trajectory to what the step's
 * stopping rule allows, fills the trace, step records and report as the
 * Newton run does, factors its initial Hessian (2μ + λ)L + cM once per
 * inertia coefficient c, and keeps the stiff cantilever within the energy
 * budget of the variational run's limiter.
 *
 * How far two inner solves may put a trajectory apart (the tolerance of
 * the comparison, from the stopping rule): a step stops at
 * ‖∇ε(q*)‖ ≤ τF, F = ‖Mg‖ + (2/h)‖p_k‖ + ‖∇W(q_k)‖ over the free
 * coordinates. Near the step's minimiser q̂, ∇²ε = ∇²W + cM ⪰ c·m_min
 * (W convex there), so ‖q* − q̂‖ ≤ τF/(c m_min), and two solves of the
 * same step are at most 2τF/(c m_min) apart. q_{k+1} = 2q* − q_k doubles
 * that; a symplectic step neither damps nor amplifies an earlier
 * difference much over a short run, so the bound after step k is the sum
 *     e_k = Σ_{j ≤ k} 4τF_j/(c m_min).
 * The total energy moves by ∇Wᵀδq + vᵀδp to first order; δp = M δv̄ −
 * (h/2)∇²W δq*, and ∇²W δq* = δr − cM δq* with δr ≤ 2τF, so with
 * c = 4/h² both parts of δp are (2/h)m_max δq*: |δE| ≤ 4F (m_max/m_min) e_k
 * (backward Euler's redo, c = 1/h², has a smaller δp). F_j is bounded
 * from the Newton run's own states: ‖p‖ ≤ √(2 K m_max), ∇W(q_j) evaluated
 * at each step's positions.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>
#include <cmocka.h>

#include "bg_dynamics.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "test_scenes.h"
#include "test_support.h"

/* The beam's quasi-newton steps need about 4,300-4,700 iterations each to meet
 * τ = 1e-8 (λ/μ = 10³: the Laplacian is a poor model of the stiff body);
 * the scene's cap of 200 stops them early. The cap applies to both runs. */
#define BEAM_STEPS 20
#define BEAM_CAP 20000
#define SPIN_STEPS 1000

/* One run with every step's positions (frames every step) and the bound
 * on each step's force scale F_k. */
typedef struct run {
    bg_solve_result_t r;
    double *q;      /* (steps + 1) × ndof */
    double *grad_w; /* steps + 1: ‖∇W(q_k)‖ over the free coordinates */
    int frames;
} run_t;

typedef struct frames_ctx {
    run_t *run;
    bg_solver_t *solver;
    const bg_scene_t *scene;
    double *grad;
    size_t ndof;
} frames_ctx_t;

static bg_status on_frame(void *ctx, int index, double time, const double *q, bg_error_t *err)
{
    (void)time;
    (void)err;
    frames_ctx_t *f = ctx;
    memcpy(f->run->q + (size_t)index * f->ndof, q, f->ndof * sizeof *q);
    bg_solver_potential(f->solver, q, f->grad);
    double s = 0.0;
    for (size_t i = 0; i < f->ndof; i++)
        if (!f->scene->constrained[i])
            s += f->grad[i] * f->grad[i];
    f->run->grad_w[index] = sqrt(s);
    f->run->frames = index + 1;
    return BG_OK;
}

/* Integrates scene with its inner solve set to inner, recording frames. */
static void integrate(bg_scene_t *s, bg_method inner, int steps, int cap, run_t *run)
{
    const size_t ndof = (size_t)s->mesh->nv * (size_t)s->mesh->dim;
    memset(run, 0, sizeof *run);
    run->q = malloc((size_t)(steps + 1) * ndof * sizeof *run->q);
    run->grad_w = malloc((size_t)(steps + 1) * sizeof *run->grad_w);
    assert_non_null(run->q);
    assert_non_null(run->grad_w);
    frames_ctx_t f = {run, NULL, s, malloc(ndof * sizeof(double)), ndof};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_solver_new(s, BG_METHOD_NEWTON, &f.solver, &err), BG_OK);
    s->inner = inner;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL,
                                    .steps = steps,
                                    .max_iterations = cap,
                                    .output_every = 1,
                                    .frame = on_frame,
                                    .frame_ctx = &f};
    if (bg_dynamic_solve(s, &o, &run->r, &err) != BG_OK)
        fail_msg("%s", err.message);
    s->inner = BG_METHOD_NEWTON;
    assert_int_equal(run->frames, steps + 1);
    bg_solver_destroy(&f.solver);
    free(f.grad);
}

static void run_release(run_t *run)
{
    bg_solve_result_release(&run->r);
    free(run->q);
    free(run->grad_w);
}

typedef struct fixture {
    bg_scene_t *spin, *beam;
    run_t spin_newton, spin_qn, beam_newton, beam_qn;
} fixture_t;

static int group_setup(void **state)
{
    fixture_t *fx = calloc(1, sizeof *fx);
    fx->spin = test_load_scene(SCENES "bar-spin.json");
    fx->beam = test_load_scene(SCENES "beam-cantilever.json");
    integrate(fx->spin, BG_METHOD_NEWTON, SPIN_STEPS, 0, &fx->spin_newton);
    integrate(fx->spin, BG_METHOD_QUASI_NEWTON, SPIN_STEPS, 0, &fx->spin_qn);
    integrate(fx->beam, BG_METHOD_NEWTON, BEAM_STEPS, BEAM_CAP, &fx->beam_newton);
    integrate(fx->beam, BG_METHOD_QUASI_NEWTON, BEAM_STEPS, BEAM_CAP, &fx->beam_qn);
    *state = fx;
    return 0;
}

static int group_teardown(void **state)
{
    fixture_t *fx = *state;
    run_release(&fx->spin_newton);
    run_release(&fx->spin_qn);
    run_release(&fx->beam_newton);
    run_release(&fx->beam_qn);
    bg_scene_destroy(&fx->spin);
    bg_scene_destroy(&fx->beam);
    free(fx);
    return 0;
}

static void mass_range(const bg_scene_t *s, double *lo, double *hi)
{
    double *m = malloc((size_t)s->mesh->nv * sizeof *m);
    bg_static_lumped_mass(s->mesh, s->material.density, m);
    *lo = INFINITY;
    *hi = 0.0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        *lo = fmin(*lo, m[v]);
        *hi = fmax(*hi, m[v]);
    }
    free(m);
}

/* ‖M g‖ over the free coordinates. */
static double load_norm(const bg_scene_t *s)
{
    double *m = malloc((size_t)s->mesh->nv * sizeof *m);
    bg_static_lumped_mass(s->mesh, s->material.density, m);
    const int n = s->mesh->dim;
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)s->mesh->nv * n; i++)
        if (!s->constrained[i]) {
            const double f = m[i / (size_t)n] * s->gravity[i % (size_t)n];
            sum += f * f;
        }
    free(m);
    return sqrt(sum);
}

/*
 * The comparison of the file comment: at every step, the largest
 * coordinate difference against e_k and the total energies against
 * 4 F (m_max/m_min) e_k. Returns the largest ratio of difference to bound
 * seen (≤ 1 passes), so a caller can print how much margin there was.
 */
static double compare(const bg_scene_t *s, const run_t *a, const run_t *b)
{
    const size_t ndof = (size_t)s->mesh->nv * (size_t)s->mesh->dim;
    const double h = s->dynamic.dt, c = 4.0 / (h * h), tau = s->tolerance;
    double m_min = 0.0, m_max = 0.0;
    mass_range(s, &m_min, &m_max);
    const double mg = load_norm(s);
    assert_int_equal(a->r.step_count, b->r.step_count);
    double e = 0.0, worst = 0.0, worst_q = 0.0, worst_e = 0.0;
    for (int k = 1; k < a->r.step_count; k++) {
        const bg_step_record_t *prev = &a->r.steps[k - 1];
        const double F = mg + (2.0 / h) * sqrt(2.0 * prev->kinetic * m_max) + a->grad_w[k - 1];
        e += 4.0 * tau * F / (c * m_min);
        double dq = 0.0;
        for (size_t i = 0; i < ndof; i++)
            dq = fmax(dq, fabs(a->q[(size_t)k * ndof + i] - b->q[(size_t)k * ndof + i]));
        const double dE = fabs(a->r.steps[k].total_energy - b->r.steps[k].total_energy);
        const double e_bound = 4.0 * F * (m_max / m_min) * e;
        /* the same limiter decisions: a step redone in one run only would
         * be a different integrator there */
        assert_int_equal(a->r.steps[k].limited, b->r.steps[k].limited);
        worst_q = fmax(worst_q, dq / e);
        worst_e = fmax(worst_e, dE / e_bound);
        if (dq > e || dE > e_bound)
            fail_msg("%s step %d: positions %.3e apart (bound %.3e), energies %.3e apart "
                     "(bound %.3e)",
                     s->name, k, dq, e, dE, e_bound);
    }
    worst = fmax(worst_q, worst_e);
    print_message("  %s: positions at most %.2e of their bound, energies %.2e of theirs "
                  "(final bound %.3e)\n",
                  s->name, worst_q, worst_e, e);
    return worst;
}

/* bar-spin, 1000 steps, τ = 1e-12: a free body; both runs converge every
 * step and stay within the bound; the two inner solves really differ
 * (quasi-newton takes several times Newton's iterations). */
static void spin_same_trajectory(void **state)
{
    fixture_t *fx = *state;
    const run_t *n = &fx->spin_newton, *q = &fx->spin_qn;
    assert_true(n->r.converged);
    assert_true(q->r.converged);
    assert_int_equal(q->r.limited_steps, 0);
    assert_true(q->r.iterations > 2 * n->r.iterations);
    assert_true(compare(fx->spin, n, q) <= 1.0);
}

/* beam-cantilever, 20 steps (λ/μ = 10³, h = 0.1), each step to τ = 1e-8:
 * the limiter redoes the same steps in both runs (backward Euler's
 * c = 1/h²), and the trajectories stay within the bound. */
static void beam_same_trajectory(void **state)
{
    fixture_t *fx = *state;
    const run_t *n = &fx->beam_newton, *q = &fx->beam_qn;
    assert_true(n->r.converged);
    assert_true(q->r.converged);
    assert_true(q->r.limited_steps >= 1); /* the redo's coefficient is exercised */
    assert_int_equal(q->r.limited_steps, n->r.limited_steps);
    assert_true(compare(fx->beam, n, q) <= 1.0);
}

static const bg_setup_step_t *setup_step(const bg_solve_result_t *r, const char *prefix)
{
    for (int i = 0; i < r->setup.count; i++)
        if (strncmp(r->setup.step[i].name, prefix, strlen(prefix)) == 0)
            return &r->setup.step[i];
    return NULL;
}

/* Everything the Newton run fills, the quasi-newton run fills: the result's
 * counts, times and final state, one trace point and one step record per
 * step with the step's inner iterations, and the set-up list. */
static void complete_like_newton(const bg_scene_t *s, const run_t *nr, const run_t *qr)
{
    const bg_solve_result_t *n = &nr->r, *q = &qr->r;
    assert_int_equal(q->method, BG_METHOD_VARIATIONAL);
    assert_string_equal(q->stop_reason, n->stop_reason);
    assert_int_equal(q->trace_count, n->trace_count);
    assert_int_equal(q->step_count, n->step_count);
    assert_non_null(q->q);
    assert_non_null(q->energy_density);
    assert_true(isfinite(q->energy));
    assert_int_equal(q->inverted_elements, n->inverted_elements);
    assert_true(q->rotfit.calls > 0);
    /* every part of the time split the Newton run spends time in, except
     * its Hessian assembly and per-iteration factorizations, which
     * quasi-newton does not do */
    assert_true(q->rotfit_seconds > 0.0 && q->solve_seconds > 0.0 && q->vector_seconds > 0.0);
    assert_true(q->output_seconds > 0.0 && q->setup.seconds > 0.0);
    assert_true(q->assembly_seconds == 0.0 && q->factor_seconds == 0.0);
    const double parts = q->setup.seconds + q->rotfit_seconds + q->assembly_seconds +
                         q->analyze_seconds + q->factor_seconds + q->solve_seconds +
                         q->vector_seconds + q->output_seconds;
    assert_true(parts <= q->wall_seconds * 1.001 + 1e-4);
    assert_true(parts >= 0.5 * q->wall_seconds);
    for (int k = 0; k < q->trace_count; k++) {
        const bg_trace_point_t *p = &q->trace[k];
        assert_int_equal(p->iteration, n->trace[k].iteration);
        assert_true(isfinite(p->energy) && isfinite(p->error));
        assert_true(k == 0 || (p->seconds >= q->trace[k - 1].seconds && p->gradient_norm > 0.0 &&
                               isfinite(p->relative_gradient)));
        const bg_step_record_t *r = &q->steps[k];
        assert_true(r->time == n->steps[k].time);
        assert_true(k == 0 || (r->iterations >= 1 && r->seconds > 0.0));
    }
    int sum = 0;
    for (int k = 1; k < q->step_count; k++)
        sum += q->steps[k].iterations;
    /* the records count each step's last trial; the total counts redos too */
    assert_true(sum <= q->iterations);
    assert_non_null(setup_step(q, "lumped mass"));
    assert_non_null(setup_step(q, "solver set-up"));
    (void)s;
}

/* The initial Hessian (2μ + λ)L + cM is factored once per coefficient and
 * kept across steps: bar-spin (midpoint only) once, the beam twice (its
 * redos' c = 1/h² too) however often the two alternate; no factorization
 * inside the iterations. Both runs' results are complete (above). */
static void factored_once_per_coefficient(void **state)
{
    fixture_t *fx = *state;
    const bg_solve_result_t *spin = &fx->spin_qn.r, *beam = &fx->beam_qn.r;
    complete_like_newton(fx->spin, &fx->spin_newton, &fx->spin_qn);
    complete_like_newton(fx->beam, &fx->beam_newton, &fx->beam_qn);
    const bg_setup_step_t *ls = setup_step(spin, "quasi-newton: the Laplacian plus the inertia");
    const bg_setup_step_t *lb = setup_step(beam, "quasi-newton: the Laplacian plus the inertia");
    assert_non_null(ls);
    assert_non_null(lb);
    assert_int_equal(ls->factorizations, 1);
    assert_int_equal(spin->setup.factorizations, 1);
    assert_int_equal(lb->factorizations, 2);
    assert_int_equal(beam->setup.factorizations, 2);
    assert_int_equal(spin->factorizations, 0);
    assert_int_equal(beam->factorizations, 0);
    /* no static c = 0 factor was made for a dynamic scene */
    assert_null(setup_step(spin, "quasi-newton: the Laplacian (its initial Hessian)"));
}

/* The report and the plan say which inner solve ran. */
static void report_and_plan(void **state)
{
    fixture_t *fx = *state;
    bg_scene_t *s = fx->spin;
    const bg_method m = BG_METHOD_VARIATIONAL;
    for (int inner = 0; inner < 2; inner++) {
        s->inner = inner ? BG_METHOD_QUASI_NEWTON : BG_METHOD_NEWTON;
        const run_t *run = inner ? &fx->spin_qn : &fx->spin_newton;
        bg_plan_t plan;
        bg_plan_for_scene(s, &m, 1, &plan);
        char *json = NULL;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bg_report_render(s, &plan, &run->r, 1, &json, &err), BG_OK);
        cJSON *root = cJSON_Parse(json);
        assert_non_null(root);
        const cJSON *r0 = cJSON_GetArrayItem(cJSON_GetObjectItem(root, "runs"), 0);
        const cJSON *in = cJSON_GetObjectItem(r0, "inner");
        assert_true(cJSON_IsString(in));
        assert_string_equal(in->valuestring, inner ? "quasi-newton" : "newton");
        int sparse = 0, integ = 0;
        const cJSON *item = NULL;
        cJSON_ArrayForEach(item, cJSON_GetObjectItem(cJSON_GetObjectItem(root, "plan"), "services"))
        {
            const char *name = cJSON_GetObjectItem(item, "name")->valuestring;
            const char *detail = cJSON_GetObjectItem(item, "detail")->valuestring;
            if (strcmp(name, "sparse-solve") == 0)
                sparse =
                    strstr(detail, inner ? "the Laplacian plus the inertia term c M factored "
                                           "once per coefficient c"
                                         : "the Newton matrix factored when it goes stale") != NULL;
            if (strcmp(name, "integration-step") == 0)
                integ = strstr(detail,
                               inner ? "each a quasi-newton solve" : "each a Newton solve") != NULL;
        }
        assert_true(sparse);
        assert_true(integ);
        cJSON_Delete(root);
        free(json);
    }
    s->inner = BG_METHOD_NEWTON;
}

/*
 * The stiff beam stays stable with the quasi-newton inner solve: every
 * step's total energy stays within the budget the variational run's
 * limiter enforces (start energy, no handle work on a clamp, plus 1 % of
 * the largest mechanical energy K + elastic seen), and, step by step, at
 * or below the Newton run's budget-limited energies to the comparison's
 * tolerance. Without the limiter the midpoint rule's energy grows fivefold
 * in 5 steps here (the README's limits).
 */
static void beam_stays_in_budget(void **state)
{
    fixture_t *fx = *state;
    const bg_scene_t *s = fx->beam;
    const run_t *q = &fx->beam_qn;
    const size_t ndof = (size_t)s->mesh->nv * 3;
    double *m = malloc((size_t)s->mesh->nv * sizeof *m);
    bg_static_lumped_mass(s->mesh, s->material.density, m);
    const double E0 = q->r.steps[0].total_energy;
    double budget = E0, mechanical = 0.0;
    for (int k = 0; k < q->r.step_count; k++) {
        double work = 0.0; /* Σ m g·q, what W subtracts */
        for (size_t i = 0; i < ndof; i++)
            work += m[i / 3] * s->gravity[i % 3] * q->q[(size_t)k * ndof + i];
        const bg_step_record_t *r = &q->r.steps[k];
        mechanical = fmax(mechanical, r->kinetic + r->potential + work);
        assert_true(isfinite(r->total_energy));
        if (r->limited) /* the budget ratchets down to a dissipative step's energy */
            budget = fmin(budget, r->total_energy);
        if (!(r->total_energy <= budget + 1e-2 * mechanical))
            fail_msg("step %d: energy %.6e over the budget %.6e + %.3e", k, r->total_energy, budget,
                     1e-2 * mechanical);
    }
    /* the beam falls: the energy bound is not met by a body that stays put */
    assert_true(q->r.steps[q->r.step_count - 1].kinetic > 0.0);
    free(m);
}

/* solver.inner: parsed on dynamic scenes, refused elsewhere and when it is
 * not a string or names no inner solve, naming the file and the field. */
static void inner_setting(void **state)
{
    (void)state;
    static const char *const base =
        "{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 1, 1], \"size\": [2, 1, 1]},"
        " \"material\": {\"E\": 1e6, \"nu\": 0.3}, %s \"solver\": {\"inner\": %s}}";
    static const char *const dyn = "\"task\": {\"kind\": \"dynamic\", \"dt\": 0.01, \"steps\": 2},";
    static const char *const stat = "\"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0, "
                                    "0, 0], \"max\": [0, 1, 1]}}}],";
    const struct {
        const char *task, *value, *message;
    } cases[] = {
        {dyn, "\"quasi-newton\"", NULL},
        {dyn, "\"newton\"", NULL},
        {dyn, "\"local-global\"",
         "mem.json: solver.inner: unknown inner solve 'local-global' "
         "(expected newton or quasi-newton)"},
        {dyn, "\"variational\"", "mem.json: solver.inner: unknown inner solve 'variational'"},
        {dyn, "1", "mem.json: solver.inner: "},
        {stat, "\"quasi-newton\"",
         "mem.json: solver.inner: only a dynamic task has an inner "
         "solve (this is a static task: choose its solver with "
         "solver.method)"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char json[1024];
        snprintf(json, sizeof json, base, cases[i].task, cases[i].value);
        bg_scene_t *s = NULL;
        bg_error_t err = BG_ERROR_INIT;
        const bg_status st = bg_scene_parse_with(json, strlen(json), "mem.json", NULL, &s, &err);
        if (!cases[i].message) {
            assert_int_equal(st, BG_OK);
            assert_int_equal(s->inner, strcmp(cases[i].value, "\"newton\"") == 0
                                           ? BG_METHOD_NEWTON
                                           : BG_METHOD_QUASI_NEWTON);
        } else {
            assert_int_equal(st, BG_ERR_INVALID);
            if (strncmp(err.message, cases[i].message, strlen(cases[i].message)) != 0)
                fail_msg("case %zu: '%s'", i, err.message);
        }
        bg_scene_destroy(&s);
    }
    /* the default, and what the shipped dynamic scenes keep (bunny-drop's
     * file has no solver.inner either; its mesh is not loaded here) */
    static const char *const shipped[] = {SCENES "bar-spin.json", SCENES "beam-cantilever.json"};
    for (size_t i = 0; i < sizeof shipped / sizeof *shipped; i++) {
        bg_scene_t *s = NULL;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bg_scene_load_with(shipped[i], NULL, &s, &err), BG_OK);
        assert_int_equal(s->inner, BG_METHOD_NEWTON);
        bg_scene_destroy(&s);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(spin_same_trajectory),          cmocka_unit_test(beam_same_trajectory),
        cmocka_unit_test(factored_once_per_coefficient), cmocka_unit_test(report_and_plan),
        cmocka_unit_test(beam_stays_in_budget),          cmocka_unit_test(inner_setting),
    };
    return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
