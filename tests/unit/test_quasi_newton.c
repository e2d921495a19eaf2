/*
 * The quasi-newton method (L-BFGS on local/global's prefactored Laplacian,
 * bg_static.h) against Newton on the shipped static, morph and
 * parameterize scenes: the same minimum (energy and positions) to the
 * accuracy its tolerance allows, a complete trace (one point per
 * iteration, the last one the result), a report that names the method,
 * its one factorization and its plan entry, and the same line-search
 * guarantees as the other methods (energy never increasing, no inverted
 * element where the scene asks).
 *
 * Tolerances. Newton is run to 1e-11 (quadratic: its answer is the
 * minimum to round-off); quasi-newton to τ = 1e-8. Near a minimum
 * q − q* ≈ H⁻¹∇W, so a relative gradient τ leaves a displacement of
 * about τ·s/λmin(H) (s the force scale) and an energy error of second
 * order. Measured at τ = 1e-8 (max |Δq| over the bounding-box diagonal,
 * |ΔE|/E): bar-twist 1.5e-10 / 1.4e-16, plate-bend 1.4e-10 / 1.5e-15,
 * stretch-bar 1.6e-9 / 2.4e-14, stiff-bar 5.9e-9 / 5.0e-15 (the nearly
 * incompressible body's soft shear modes: the largest), bunny-edit 3.5e-9
 * / 9.0e-15. The bounds are 10τ of the diagonal (17× the largest) and
 * 1e-12 relative in energy (40× the largest; two accurate solutions of a
 * smooth minimum agree in energy to about τ², far below that, so the bound
 * is set by the round-off of a sum over 10⁴–10⁵ elements). A quasi-newton
 * that stops early (relative gradient 1e-3 leaves 1e-5 of the diagonal on
 * bunny-edit) or lands in another minimum fails them.
 */
#include <float.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>
#include <cmocka.h>

#include "bg_morph.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "test_scenes.h"
#include "test_support.h"

#define NEWTON_TOLERANCE 1e-11
#define QN_TOLERANCE 1e-8
#define POSITION_TOL (10.0 * QN_TOLERANCE)
#define ENERGY_TOL 1e-12

static double diagonal(const bg_scene_t *s)
{
    double lo[3], hi[3], d = 0.0;
    bg_mesh_bounds(s->mesh, lo, hi);
    for (int c = 0; c < s->mesh->dim; c++)
        d += (hi[c] - lo[c]) * (hi[c] - lo[c]);
    return sqrt(d);
}

static double max_difference(const double *a, const double *b, size_t n)
{
    double d = 0.0;
    for (size_t i = 0; i < n; i++)
        d = fmax(d, fabs(a[i] - b[i]));
    return d;
}

static void solve(const bg_scene_t *s, bg_method method, double tol, int cap,
                  bg_solve_result_t *r)
{
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {.method = method,
                                  .tolerance = tol,
                                  .max_iterations = cap,
                                  .keep_orientation = s->task == BG_TASK_PARAMETERIZE};
    if (bg_static_solve(s, &o, r, &err) != BG_OK)
        fail_msg("%s: %s: %s", s->name, bg_method_name(method), err.message);
}

/*
 * A complete trace: one point per iteration numbered 0..iterations (a
 * continued solve's stages numbered on), time never going back, the
 * energy never rising within a stage beyond round-off, and the last point
 * the result. Round-off as in unit.static: 1e-13 of the start's energy
 * (the line search accepts a step within 64 ulps of the magnitudes the
 * energy is summed from, which on the stiff bar exceed the energy itself
 * by orders of magnitude). A solve that stalls counts the iteration whose
 * line search found no step (as Newton's and local/global's do) but has no
 * point for it: the trace holds the accepted iterates. On top of that, the
 * rounding of the energy itself: a sum over ne elements carries an error up
 * to about ne u times the sum of the terms' magnitudes (Higham, Accuracy and
 * Stability of Numerical Algorithms, 2002, section 4.2), which with the area
 * barrier active (lion-head) exceeds 1e-13 of the energy: 4 ne u of the start's
 * energy is allowed for it. A real ascent step changes the energy by orders
 * more. (The rounding moves with the order CHOLMOD's threads sum in, so a
 * plateau's last steps may rise within it on one run and not on another.)
 */
static void assert_trace_complete(const bg_solve_result_t *r, int32_t ne)
{
    const double noise = (1e-13 + 4.0 * (double)ne * DBL_EPSILON) * fabs(r->trace[0].energy);
    const int stalled = r->stop_reason && strncmp(r->stop_reason, "stalled", 7) == 0;
    assert_int_equal(r->trace_count, r->iterations + (stalled ? 0 : 1));
    for (int i = 0; i < r->trace_count; i++) {
        const bg_trace_point_t *p = &r->trace[i];
        assert_int_equal(p->iteration, i);
        assert_true(isfinite(p->energy) && isfinite(p->gradient_norm));
        if (i > 0) {
            assert_true(p->seconds >= r->trace[i - 1].seconds);
            if (p->stage == r->trace[i - 1].stage)
                if (!(p->energy <= r->trace[i - 1].energy + noise))
                    fail_msg("iteration %d: the energy rose from %.17g to %.17g", i,
                             r->trace[i - 1].energy, p->energy);
        }
    }
    const bg_trace_point_t *last = &r->trace[r->trace_count - 1];
    assert_true(last->energy == r->energy);
    assert_true(last->gradient_norm == r->gradient_norm);
    assert_true(last->relative_gradient == r->relative_gradient);
}

/* Quasi-newton and Newton on one static scene: converged within
 * max_qn iterations, the same minimum (see the tolerances above), a
 * complete trace, one rotation fit per iteration at least, no
 * factorization after the set-up. */
static void same_as_newton(const char *file, int max_qn)
{
    bg_scene_t *s = test_load_scene(file);
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT, rq = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, NEWTON_TOLERANCE, 500, &rn);
    solve(s, BG_METHOD_QUASI_NEWTON, QN_TOLERANCE, max_qn, &rq);
    assert_true(rn.converged);
    assert_true(rq.converged);
    assert_true(rq.relative_gradient <= QN_TOLERANCE);
    assert_int_equal(rq.method, BG_METHOD_QUASI_NEWTON);
    const size_t n = (size_t)s->mesh->nv * s->mesh->dim;
    const double dq = max_difference(rq.q, rn.q, n) / diagonal(s);
    const double dE = fabs(rq.energy - rn.energy) / fabs(rn.energy);
    print_message("  %s: quasi-newton %d iterations (newton %d), max |dq| %.3e of the diagonal, "
                  "|dE|/E %.3e\n",
                  s->name, rq.iterations, rn.iterations, dq, dE);
    if (!(dq <= POSITION_TOL))
        fail_msg("%s: positions differ by %g of the diagonal (> %g)", s->name, dq, POSITION_TOL);
    if (!(dE <= ENERGY_TOL))
        fail_msg("%s: energies differ by %g relative (> %g)", s->name, dE, ENERGY_TOL);
    assert_trace_complete(&rq, s->mesh->ne);
    /* One factorization, the Laplacian's, in the set-up; none after. */
    assert_int_equal(rq.factorizations, 0);
    assert_true(rq.rotfit.calls >= (int64_t)(rq.iterations + 1) * s->mesh->ne);
    assert_int_equal(rq.continuation_stages, rn.continuation_stages);
    bg_solve_result_release(&rn);
    bg_solve_result_release(&rq);
    bg_scene_destroy(&s);
}

static void bar_twist(void **state)
{
    same_as_newton(SCENES "bar-twist.json", 200);
}

static void plate_bend(void **state)
{
    same_as_newton(SCENES "plate-bend.json", 200);
}

static void stretch_bar(void **state)
{
    same_as_newton(SCENES "stretch-bar.json", 200);
}

/* λ/μ = 10⁴: both continue in λ (bg_static_continues); without the stages
 * quasi-newton descends into another minimum (energy 0.15733 against
 * 0.15445), which the energy bound rejects. */
static void stiff_bar(void **state)
{
    same_as_newton(SCENES "stiff-bar.json", 20000);
}

/* The curvature pairs must do their work: quasi-newton reaches 1e-8 in
 * 140 iterations here, where local/global is still at 7e-8 after 2,000.
 * An L-BFGS that degenerated into local/global's steps would hit the cap
 * of 400. */
static void bunny_edit(void **state)
{
    same_as_newton(SCENES "bunny-edit.json", 400);
}

/*
 * keep_orientation: from a start without inverted elements no accepted
 * step inverts one. bunny-edit's minimum inverts 34 tetrahedra (the ears
 * pulled through the head), so the flip-free solve stops against that
 * boundary — stalled, not converged, as Newton does on a folding map —
 * with no inverted element and an energy that never rose; without the
 * option the same solve ends with the 34.
 */
static void keep_orientation_holds(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bunny-edit.json");
    assert_int_equal(bg_static_count_inverted(s->mesh, s->initial), 0);
    bg_solve_result_t kept = BG_SOLVE_RESULT_INIT, free_ = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    bg_solve_options_t o = {.method = BG_METHOD_QUASI_NEWTON,
                            .tolerance = QN_TOLERANCE,
                            .max_iterations = 400,
                            .keep_orientation = 1};
    assert_int_equal(bg_static_solve(s, &o, &kept, &err), BG_OK);
    o.keep_orientation = 0;
    assert_int_equal(bg_static_solve(s, &o, &free_, &err), BG_OK);
    print_message("  bunny-edit: flip-free %d iterations (%s), %lld inverted; free %lld inverted\n",
                  kept.iterations, kept.stop_reason, (long long)kept.inverted_elements,
                  (long long)free_.inverted_elements);
    assert_int_equal(kept.inverted_elements, 0);
    assert_int_equal(bg_static_count_inverted(s->mesh, kept.q), 0);
    assert_true(free_.inverted_elements > 0);
    assert_true(kept.energy < kept.trace[0].energy);
    assert_trace_complete(&kept, s->mesh->ne);
    bg_solve_result_release(&kept);
    bg_solve_result_release(&free_);
    bg_scene_destroy(&s);
}

/*
 * Every tetrahedron inverted at the start: quasi-newton must bring the
 * bunny back to its rest shape as Newton does. The 3-2-1 mount allows the
 * rest shape or its half turn about the mount's first axis, and the two
 * methods end in different ones, so positions are compared through the
 * shape: the energy at zero (1e-12 of the start's; measured 7e-15 of an
 * energy of order 1) and every element's edge lengths restored to 1e-4
 * relative. The edges are the most sensitive measure there is: a sliver
 * of 1e-9 of the volume keeps a relative edge error long after the total
 * energy is gone (unit.static's Newton needs its round-off floor for
 * 1e-6; at τ = 1e-8 quasi-newton's worst edge is 5.5e-6 off, a minimum
 * other than the rest shape is off by O(1)).
 */
static void inverted_bunny(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "inverted-bunny.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_QUASI_NEWTON, QN_TOLERANCE, 5000, &r);
    assert_true(r.converged);
    assert_true(r.rotfit.svd > 0); /* the inverted start went through the SVD path */
    assert_true(r.energy <= 1e-12 * r.trace[0].energy);
    const bg_mesh_t *m = s->mesh;
    double worst = 0.0;
    for (int32_t e = 0; e < m->ne; e++)
        for (int a = 0; a < 4; a++)
            for (int b = a + 1; b < 4; b++) {
                const int32_t i = m->elements[4 * (size_t)e + a], j = m->elements[4 * (size_t)e + b];
                double l0 = 0.0, l1 = 0.0;
                for (int c = 0; c < 3; c++) {
                    const double d0 = m->x[3 * (size_t)i + c] - m->x[3 * (size_t)j + c];
                    const double d1 = r.q[3 * (size_t)i + c] - r.q[3 * (size_t)j + c];
                    l0 += d0 * d0;
                    l1 += d1 * d1;
                }
                worst = fmax(worst, fabs(sqrt(l1) - sqrt(l0)) / sqrt(l0));
            }
    print_message("  inverted-bunny: %d iterations, energy %.3e, worst edge change %.3e\n",
                  r.iterations, r.energy, worst);
    assert_true(worst <= 1e-4);
    assert_trace_complete(&r, s->mesh->ne);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/*
 * Parameterization (lion head, ARAP with the area barrier, flip-free line
 * search): the same map as Newton's. Both to 1e-6 (the scene asks 1e-4;
 * Newton's barrier-active minimum converges sublinearly, so 1e-11 is out
 * of reach): measured |Δq| 9.6e-8 of the diagonal and |ΔE|/E 5.8e-14,
 * bounded by 10τ and 1e-10. No flipped triangle in either map.
 */
static void lion_head_param(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "lion-head-param.json");
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT, rq = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-6, 300, &rn);
    solve(s, BG_METHOD_QUASI_NEWTON, 1e-6, 5000, &rq);
    assert_true(rn.converged);
    assert_true(rq.converged);
    const size_t n = (size_t)s->mesh->nv * 2;
    const double dq = max_difference(rq.q, rn.q, n) / diagonal(s);
    const double dE = fabs(rq.energy - rn.energy) / fabs(rn.energy);
    print_message("  lion-head-param: quasi-newton %d iterations (newton %d), max |dq| %.3e, "
                  "|dE|/E %.3e\n",
                  rq.iterations, rn.iterations, dq, dE);
    assert_true(dq <= 1e-5);
    assert_true(dE <= 1e-10);
    assert_int_equal(rq.inverted_elements, 0);
    assert_int_equal(bg_static_count_inverted(s->mesh, rq.q), 0);
    assert_trace_complete(&rq, s->mesh->ne);
    bg_solve_result_release(&rn);
    bg_solve_result_release(&rq);
    bg_scene_destroy(&s);
}

/*
 * Morphing (bar-morph, 11 frames, each to the scene's 1e-8 from the last):
 * every frame's energy equal to Newton's to 1e-12 of the series' largest
 * (measured 3e-15; the last frame's energy is ~1e-19, the target up to a
 * rigid motion, so it is compared against that scale) and the final
 * positions to 10τ of the diagonal (measured 1.8e-10). The Laplacian is
 * refactored once per frame (the blend changes), nothing else.
 */
static void bar_morph(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-morph.json");
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT, rq = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    bg_morph_options_t o = {.method = BG_METHOD_NEWTON};
    assert_int_equal(bg_morph_solve(s, &o, &rn, &err), BG_OK);
    o.method = BG_METHOD_QUASI_NEWTON;
    o.max_iterations = bg_scene_max_iterations(s, o.method);
    assert_int_equal(bg_morph_solve(s, &o, &rq, &err), BG_OK);
    assert_true(rn.converged);
    assert_true(rq.converged);
    assert_int_equal(rq.step_count, s->morph_frames);
    double scale = 0.0, worst = 0.0;
    for (int f = 0; f < rn.step_count; f++)
        scale = fmax(scale, fabs(rn.steps[f].total_energy));
    for (int f = 0; f < rq.step_count; f++)
        worst = fmax(worst, fabs(rq.steps[f].total_energy - rn.steps[f].total_energy) / scale);
    const double dq =
        max_difference(rq.q, rn.q, (size_t)s->mesh->nv * s->mesh->dim) / diagonal(s);
    print_message("  bar-morph: quasi-newton %d iterations (newton %d), frame energies to %.3e, "
                  "final positions to %.3e\n",
                  rq.iterations, rn.iterations, worst, dq);
    assert_true(worst <= ENERGY_TOL);
    assert_true(dq <= POSITION_TOL);
    assert_int_equal(rq.factorizations, 0);
    int64_t laplacian = 0;
    for (int i = 0; i < rq.setup.count; i++)
        if (strncmp(rq.setup.step[i].name, "quasi-newton:", 13) == 0)
            laplacian = rq.setup.step[i].count;
    assert_int_equal(laplacian, s->morph_frames);
    bg_solve_result_release(&rn);
    bg_solve_result_release(&rq);
    bg_scene_destroy(&s);
}

static const cJSON *get(const cJSON *o, const char *key)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!v)
        fail_msg("report.json: no '%s'", key);
    return v;
}

/*
 * The report of a comparison names the method, gives its whole trace and
 * time split, its set-up step (the Laplacian, one factorization) and the
 * plan's sparse-solve entry for it (the Laplacian as the L-BFGS initial
 * Hessian). The time split covers the wall time within 10 % (the
 * bookkeeping between timers, at most a few per cent here), less the time
 * the thread waited for a CPU during the solve: on a machine loaded
 * beyond its cores that wait falls between timers too (the kernel counts
 * it: run_delay in /proc/thread-self/schedstat). Code outside every timer
 * is still caught, since it runs rather than waits.
 */
static double run_queue_wait(void)
{
    FILE *f = fopen("/proc/thread-self/schedstat", "r");
    unsigned long long on_cpu = 0, waited = 0;
    if (!f)
        return 0.0;
    const int n = fscanf(f, "%llu %llu", &on_cpu, &waited);
    fclose(f);
    return n == 2 ? (double)waited * 1e-9 : 0.0;
}

static void report_is_complete(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-twist.json");
    bg_solve_result_t runs[2] = {BG_SOLVE_RESULT_INIT, BG_SOLVE_RESULT_INIT};
    const bg_method methods[2] = {BG_METHOD_NEWTON, BG_METHOD_QUASI_NEWTON};
    double waited = 0.0;
    for (int m = 0; m < 2; m++) {
        const double before = run_queue_wait();
        solve(s, methods[m], s->tolerance, bg_scene_max_iterations(s, methods[m]), &runs[m]);
        waited = run_queue_wait() - before;
    }
    bg_plan_t plan;
    bg_plan_for_scene(s, methods, 2, &plan);
    char *json = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_report_render(s, &plan, runs, 2, &json, &err), BG_OK);
    cJSON *root = cJSON_Parse(json);
    assert_non_null(root);
    const cJSON *qn = cJSON_GetArrayItem(get(root, "runs"), 1);
    assert_string_equal(get(qn, "method")->valuestring, "quasi-newton");
    assert_true(cJSON_IsTrue(get(qn, "converged")));
    const int iterations = get(qn, "iterations")->valueint;
    assert_int_equal(iterations, runs[1].iterations);
    assert_int_equal(cJSON_GetArraySize(get(qn, "trace")), iterations + 1);
    const cJSON *split = get(qn, "time_split");
    const double wall = get(qn, "wall_seconds")->valuedouble;
    const double accounted = get(split, "accounted_seconds")->valuedouble;
    assert_true(accounted <= 1.001 * wall + 1e-4 && accounted >= 0.9 * wall - 2e-3 - waited);
    assert_true(get(split, "solve_seconds")->valuedouble > 0.0);
    assert_int_equal(get(split, "iteration_factorizations")->valueint, 0);
    int laplacian = 0;
    const cJSON *step = NULL;
    cJSON_ArrayForEach(step, get(qn, "setup"))
    {
        const char *name = get(step, "step")->valuestring;
        if (strncmp(name, "quasi-newton: the Laplacian", 27) == 0) {
            laplacian = 1;
            assert_int_equal(get(step, "factorizations")->valueint, 1);
        }
    }
    assert_true(laplacian);
    int lbfgs = 0;
    const cJSON *item = NULL;
    cJSON_ArrayForEach(item, get(get(root, "plan"), "services"))
    {
        lbfgs |= strcmp(get(item, "name")->valuestring, "sparse-solve") == 0 &&
                 strstr(get(item, "detail")->valuestring, "L-BFGS initial Hessian") != NULL;
    }
    assert_true(lbfgs);
    cJSON_Delete(root);
    free(json);
    bg_solve_result_release(&runs[0]);
    bg_solve_result_release(&runs[1]);
    bg_scene_destroy(&s);
}

/* A local/global solver refuses an inertia term (a time step is Newton's
 * or quasi-newton's, solver.inner; tests/unit/test_qn_step.c): a clear
 * error, not a wrong answer. */
static void inertia_is_refused(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-twist.json");
    bg_solver_t *solver = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_solver_new(s, BG_METHOD_LOCAL_GLOBAL, &solver, &err), BG_OK);
    const size_t n = (size_t)s->mesh->nv * 3;
    double *y = calloc(n, sizeof *y);
    const bg_inertia_t inertia = {1.0, y};
    const bg_solve_options_t o = {.tolerance = 1e-8, .max_iterations = 10, .inertia = &inertia};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    assert_int_equal(bg_solver_minimize(solver, &o, &r, &err), BG_ERR_UNSUPPORTED);
    assert_non_null(strstr(err.message, "newton or quasi-newton"));
    free(y);
    bg_solver_destroy(&solver);
    bg_scene_destroy(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(bar_twist),       cmocka_unit_test(plate_bend),
        cmocka_unit_test(stretch_bar),     cmocka_unit_test(stiff_bar),
        cmocka_unit_test(bunny_edit),      cmocka_unit_test(keep_orientation_holds),
        cmocka_unit_test(inverted_bunny),
        cmocka_unit_test(lion_head_param), cmocka_unit_test(bar_morph),
        cmocka_unit_test(report_is_complete), cmocka_unit_test(inertia_is_refused),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
