/*
 * Spokes-and-rims surface editing: the gradient against central
 * differences of the energy (rotations refitted at every evaluation: they
 * are optimal, so their derivative does not enter), a rigid motion of every
 * handle reproduced exactly, and on the armadillo a monotone energy with
 * the handles at their targets.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_scene.h"
#include "bg_surface_arap.h"
#include "test_scenes.h"
#include "test_support.h"

/* The armadillo with three handles (feet, right fist, head), each moved by
 * `motion` (a handle's "transform" member, or ""). */
static bg_scene_t *armadillo(const char *motion)
{
    char json[2048];
    snprintf(
        json, sizeof json,
        "{\"mesh\": \"armadillo.off\", \"task\": {\"kind\": \"surface-edit\"},"
        "\"handles\": ["
        "{\"select\": {\"box_fraction\": {\"min\": [0, 0, 0], \"max\": [1, 0.06, 1]}}%s},"
        "{\"select\": {\"box_fraction\": {\"min\": [0.82, 0.62, 0], \"max\": [1, 1, 1]}}%s},"
        "{\"select\": {\"box_fraction\": {\"min\": [0.35, 0.9, 0], \"max\": [0.65, 1, 1]}}%s}],"
        "\"initial\": \"rest\", \"solver\": {\"method\": \"local-global\"}}",
        motion, motion, motion);
    return test_parse_scene(json, "armadillo.json");
}

static void gradient_matches_differences(void **state)
{
    bg_scene_t *s = armadillo("");
    const size_t n = (size_t)s->mesh->nv * 3;
    double *q = malloc(n * sizeof *q), *g = malloc(n * sizeof *g);
    uint64_t rng = 5;
    for (size_t i = 0; i < n; i++)
        q[i] = s->mesh->x[i] + 0.02 * (2 * test_uniform(&rng) - 1);
    bg_surface_arap_energy(s, q, g);
    const double h = 1e-6;
    for (size_t i = 0; i < n; i += 7) {
        const double qi = q[i];
        q[i] = qi + h;
        const double Ep = bg_surface_arap_energy(s, q, NULL);
        q[i] = qi - h;
        const double Em = bg_surface_arap_energy(s, q, NULL);
        q[i] = qi;
        assert_true(fabs((Ep - Em) / (2 * h) - g[i]) <= 1e-6 * (1.0 + fabs(g[i])));
    }
    free(q);
    free(g);
    bg_scene_destroy(&s);
}

/* Every handle moved by one rigid motion: the minimiser is the rigidly
 * moved armadillo (zero energy), whatever the free vertices start from. */
static void rigid_motion_reproduced(void **state)
{
    bg_scene_t *s = armadillo(", \"transform\": {\"rotate\": {\"axis\": [0.2, 1, 0.1], "
                              "\"degrees\": 40, \"center\": [0, 20, 0]}, \"translate\": [30, 0, "
                              "-10]}");
    const bg_solve_options_t o = {
        .method = BG_METHOD_LOCAL_GLOBAL, .tolerance = 1e-10, .max_iterations = 5000};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_surface_arap_solve(s, &o, &r, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_true(r.energy <= 1e-12 * r.trace[0].energy);
    /* Edge lengths of every triangle are the rest ones. */
    assert_true(test_max_edge_change(s->mesh->elements, s->mesh->ne, 3, 3, s->mesh->x, r.q) <=
                1e-6);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

static void armadillo_edit_monotone(void **state)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = test_load_scene(SCENES "armadillo-edit.json");
    const bg_solve_options_t o = {
        .method = s->method, .tolerance = s->tolerance, .max_iterations = s->max_iterations};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    if (bg_surface_arap_solve(s, &o, &r, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_true(r.converged);
    for (int i = 1; i < r.trace_count; i++)
        assert_true(r.trace[i].energy <= r.trace[i - 1].energy * (1 + 1e-12));
    assert_true(r.energy < 0.1 * r.trace[0].energy);
    for (size_t k = 0; k < (size_t)s->mesh->nv * 3; k++)
        if (s->constrained[k])
            assert_true(r.q[k] == s->target[k]);
    /* Newton is not offered for this energy: a clear error. */
    const bg_solve_options_t newton = {
        .method = BG_METHOD_NEWTON, .tolerance = 1e-6, .max_iterations = 10};
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT;
    bg_error_clear(&err);
    assert_int_equal(bg_surface_arap_solve(s, &newton, &rn, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "local-global only"));
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(gradient_matches_differences),
        cmocka_unit_test(rigid_motion_reproduced),
        cmocka_unit_test(armadillo_edit_monotone),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
