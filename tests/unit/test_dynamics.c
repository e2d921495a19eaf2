/*
 * Time integration against what the methods must do: the variational
 * midpoint rule conserves linear and angular momentum of a free body to the
 * inner solve's tolerance and keeps the energy in a band without drift;
 * backward Euler loses energy; the midpoint rule is second order in time
 * and backward Euler first order (errors against a fine-step reference);
 * a stiff undamped cantilever stays bounded with h = 0.1 (the energy
 * limiter at work); an inverted start
 * recovers; scenes with handles over time follow them.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_dynamics.h"
#include "bg_plan.h"
#include "bg_scene.h"
#include "test_scenes.h"
#include "test_support.h"

static void integrate(const bg_scene_t *s, const bg_dynamic_options_t *o, bg_solve_result_t *r)
{
    bg_error_t err = BG_ERROR_INIT;
    if (bg_dynamic_solve(s, o, r, &err) != BG_OK)
        fail_msg("%s", err.message);
}

static double norm3(const double *v)
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static double mean_energy(const bg_solve_result_t *r, int from, int count)
{
    double s = 0.0;
    for (int i = from; i < from + count; i++)
        s += r->steps[i].total_energy;
    return s / count;
}

/* bar-spin: a free body, no gravity. Momenta constant to 1e-9 relative over
 * 1000 steps (the inner tolerance 1e-10 bounds the per-step error); energy
 * mean over the last 100 steps within 0.5 % of the first 100. */
static void bar_spin_conserves(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-spin.json");
    assert_int_equal(s->task, BG_TASK_DYNAMIC);
    assert_int_equal(s->dynamic.steps, 1000);
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL};
    integrate(s, &o, &r);
    assert_true(r.converged);
    assert_int_equal(r.step_count, 1001);
    assert_int_equal(r.limited_steps, 0); /* the limiter must not touch a conservative run */
    const bg_step_record_t *first = &r.steps[0];
    const double P0 = norm3(first->linear_momentum), L0 = norm3(first->angular_momentum);
    assert_true(P0 > 0.0 && L0 > 0.0);
    for (int i = 1; i < r.step_count; i++) {
        double dP[3], dL[3];
        for (int c = 0; c < 3; c++) {
            dP[c] = r.steps[i].linear_momentum[c] - first->linear_momentum[c];
            dL[c] = r.steps[i].angular_momentum[c] - first->angular_momentum[c];
        }
        if (!(norm3(dP) <= 1e-9 * P0 && norm3(dL) <= 1e-9 * L0))
            fail_msg("step %d: momentum drift %g, angular %g", i, norm3(dP) / P0, norm3(dL) / L0);
    }
    const double head = mean_energy(&r, 1, 100), tail = mean_energy(&r, r.step_count - 100, 100);
    assert_true(fabs(tail - head) <= 0.005 * fabs(head));
    bg_solve_result_release(&r);

    const bg_dynamic_options_t be = {.method = BG_METHOD_BACKWARD_EULER};
    integrate(s, &be, &r);
    /* Backward Euler dissipates: the same run ends with much less energy. */
    assert_true(r.steps[r.step_count - 1].total_energy < 0.9 * r.steps[0].total_energy);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* Errors at T = 0.1 s against a run with h/64, for h = 2, 1, 0.5, 0.25 ms:
 * the midpoint rule's error falls 4× (±20 %) per halving, backward
 * Euler's 2× (±20 %). The steps resolve the bar's fastest vibrations
 * (ωh ≤ 0.5), the asymptotic regime where orders are meaningful. */
static double *final_positions(const bg_scene_t *s, bg_method m, double h)
{
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_dynamic_options_t o = {.method = m, .dt = h, .duration = 0.1, .tolerance = 1e-12};
    integrate(s, &o, &r);
    double *q = r.q;
    r.q = NULL;
    bg_solve_result_release(&r);
    return q;
}

static void check_order(const bg_scene_t *s, bg_method m, double expected)
{
    const double h0 = 0.002;
    const size_t n = (size_t)s->mesh->nv * 3;
    double *ref = final_positions(s, m, h0 / 64), previous = 0.0;
    for (int k = 0; k < 4; k++) {
        double *q = final_positions(s, m, h0 / (1 << k)), e = 0.0, d = 0.0;
        for (size_t i = 0; i < n; i++) {
            e += (q[i] - ref[i]) * (q[i] - ref[i]);
            d += (ref[i] - s->mesh->x[i]) * (ref[i] - s->mesh->x[i]);
        }
        e = sqrt(e / d);
        if (k > 0) {
            const double ratio = previous / e;
            if (!(fabs(ratio - expected) <= 0.2 * expected))
                fail_msg("%s: error ratio %g at h = %g, expected %g", bg_method_name(m), ratio,
                         h0 / (1 << k), expected);
        }
        previous = e;
        free(q);
    }
    free(ref);
}

static void order_in_time(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-spin.json");
    check_order(s, BG_METHOD_VARIATIONAL, 4.0);
    check_order(s, BG_METHOD_BACKWARD_EULER, 2.0);
    bg_scene_destroy(&s);
}

/* The clamped beam, undamped, λ/μ = 10³, h = 0.1, 500 steps: always
 * finite, every inner solve settled, the total energy never above its start
 * (no handle moves, so no work enters), while the beam keeps swinging.
 * The energy limiter is what makes this hold: without it the midpoint rule
 * gains energy in the stiff nonlinear modes and the same scene's energy
 * more than doubles within 30 steps. */
static void stiff_cantilever_stable(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "beam-cantilever.json");
    assert_true(s->material.lambda >= 1e3 * s->material.mu);
    assert_true(s->dynamic.dt >= 0.1 && s->dynamic.steps >= 500);
    assert_true(s->dynamic.damping == 0.0 && s->dynamic.energy_limit);
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL};
    integrate(s, &o, &r);
    assert_true(r.converged);
    assert_true(r.limited_steps > 0 && r.limited_steps < r.step_count / 2);
    const double E0 = r.steps[0].total_energy;
    double late_kinetic = 0.0;
    for (int i = 0; i < r.step_count; i++) {
        assert_true(isfinite(r.steps[i].total_energy));
        assert_true(r.steps[i].total_energy <= E0 + 1e-9 * fabs(E0));
        if (i >= r.step_count - 100)
            late_kinetic = fmax(late_kinetic, r.steps[i].kinetic);
    }
    /* Still moving in the last 10 s: bounded, not damped out. */
    assert_true(late_kinetic > 1e-3 * fabs(E0));
    for (size_t i = 0; i < (size_t)s->mesh->nv * 3; i++)
        assert_true(isfinite(r.q[i]));
    bg_solve_result_release(&r);

    s->dynamic.energy_limit = 0;
    const bg_dynamic_options_t unlimited = {.method = BG_METHOD_VARIATIONAL, .steps = 30};
    integrate(s, &unlimited, &r);
    double peak = -INFINITY;
    for (int i = 0; i < r.step_count; i++)
        peak = fmax(peak, r.steps[i].total_energy);
    assert_int_equal(r.limited_steps, 0);
    assert_true(peak > 2.0 * fabs(E0));
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* Every element inverted at the start, free body with damping: the energy
 * returns to (near) zero — the shape recovers its rest form. */
static void inverted_start_recovers(void **state)
{
    const char *json = "{\"mesh\": {\"generate\": \"box\", \"cells\": [4, 2, 2], \"size\": [2, 1, 1]},"
                       "\"material\": {\"E\": 1e5, \"nu\": 0.3, \"density\": 1000},"
                       "\"initial\": {\"scale\": -0.75},"
                       "\"task\": {\"kind\": \"dynamic\", \"dt\": 0.01, \"steps\": 400, \"damping\": 10}}";
    bg_scene_t *s = test_parse_scene(json, "inverted.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL};
    integrate(s, &o, &r);
    assert_true(r.converged);
    assert_true(r.rotfit.svd > 0);
    const double W0 = r.steps[0].potential, W = r.steps[r.step_count - 1].potential;
    assert_true(W0 > 0.0);
    assert_true(W <= 1e-6 * W0);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* A handle with a duration reaches its motion progressively: halfway
 * through, a 90° turn is at 45°; targets after the duration stay put. */
static void handles_over_time(void **state)
{
    const char *json = "{\"mesh\": {\"generate\": \"box\", \"cells\": [4, 1, 1], \"size\": [4, 1, 1]},"
                       "\"material\": {\"mu\": 1, \"lambda\": 1},"
                       "\"handles\": [{\"select\": {\"box\": {\"min\": [4, 0, 0], \"max\": [4, 1, 1]}},"
                       " \"transform\": {\"rotate\": {\"axis\": [1, 0, 0], \"degrees\": 90,"
                       " \"center\": [4, 0.5, 0.5]}}, \"duration\": 2}],"
                       "\"task\": {\"kind\": \"dynamic\", \"dt\": 0.1, \"steps\": 5}}";
    bg_scene_t *s = test_parse_scene(json, "turn.json");
    const size_t n = (size_t)s->mesh->nv * 3;
    double *t = malloc(n * sizeof *t);
    for (int phase = 0; phase < 3; phase++) {
        const double time = phase == 0 ? 0.0 : phase == 1 ? 1.0 : 5.0;
        const double a = (phase == 0 ? 0.0 : phase == 1 ? 45.0 : 90.0) * M_PI / 180.0;
        bg_scene_targets_at(s, time, t);
        for (int32_t v = 0; v < s->mesh->nv; v++) {
            const double *x = s->mesh->x + 3 * (size_t)v;
            if (!s->constrained[3 * (size_t)v])
                continue;
            const double y = x[1] - 0.5, z = x[2] - 0.5;
            assert_true(fabs(t[3 * v + 1] - (0.5 + cos(a) * y - sin(a) * z)) <= 1e-12);
            assert_true(fabs(t[3 * v + 2] - (0.5 + sin(a) * y + cos(a) * z)) <= 1e-12);
        }
    }
    free(t);
    bg_scene_destroy(&s);
}

/* The plan buys an integration step for dynamic scenes and leaves it out,
 * with the reason, for static ones. */
static void plan_lists_integration_step(void **state)
{
    const char *files[2] = {SCENES "bar-spin.json", SCENES "bar-twist.json"};
    for (int i = 0; i < 2; i++) {
        bg_scene_t *s = test_load_scene(files[i]);
        bg_plan_t plan;
        bg_plan_for_scene(s, &s->method, 1, &plan);
        int needed = 0, left = 0;
        for (int k = 0; k < plan.service_count; k++)
            needed |= strcmp(plan.services[k].service, "integration-step") == 0;
        for (int k = 0; k < plan.left_out_count; k++)
            left |= strcmp(plan.left_out[k].service, "integration-step") == 0 &&
                    strstr(plan.left_out[k].detail, "static") != NULL;
        assert_int_equal(needed, i == 0);
        assert_int_equal(left, i == 1);
        bg_scene_destroy(&s);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(bar_spin_conserves),       cmocka_unit_test(order_in_time),
        cmocka_unit_test(stiff_cantilever_stable),  cmocka_unit_test(inverted_start_recovers),
        cmocka_unit_test(handles_over_time),        cmocka_unit_test(plan_lists_integration_step),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
