/*
 * report.json read back (bg_report_parse_runs): reports rendered from real
 * solves (static with two methods, dynamic) parse back into the same
 * results, field by field and trace point by trace point (to the epsilon
 * cJSON's number printing keeps); a
 * morph's frames and nulls (non-finite values) read as written; every
 * malformed report fails naming the file and the field, and leaves
 * nothing allocated.
 */
#include <float.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_dynamics.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_static.h"
#include "test_scenes.h"

/* A small twisted bar: both methods converge in a moment. */
static const char BAR[] =
    "{\"name\": \"small-bar\", \"mesh\": {\"generate\": \"box\", \"cells\": [6, 2, 2],"
    " \"size\": [3, 1, 1]}, \"material\": {\"mu\": 1, \"lambda\": 1},"
    " \"handles\": [{\"name\": \"fixed\", \"select\": {\"box\": {\"min\": [0, 0, 0],"
    " \"max\": [0, 1, 1]}}}, {\"name\": \"turn\", \"select\": {\"box\": {\"min\": [3, 0, 0],"
    " \"max\": [3, 1, 1]}}, \"transform\": {\"rotate\": {\"axis\": [1, 0, 0], \"degrees\": 180,"
    " \"center\": [3, 0.5, 0.5]}}}], \"task\": {\"kind\": \"static\"}, \"reference\": \"newton\"}";

/* Equal as the report writes them: non-finite values as null (read back
 * NAN), the others as cJSON prints a number, with 15 significant digits
 * when those read back within one epsilon of it (relative), else 17. So
 * a value comes back within DBL_EPSILON of the largest of the two, often
 * bit for bit, never further. */
static void assert_same(double written, double read, const char *what)
{
    if (!isfinite(written)) {
        if (!isnan(read))
            fail_msg("%s: written non-finite, read %.17g", what, read);
        return;
    }
    const double largest = fabs(written) > fabs(read) ? fabs(written) : fabs(read);
    if (!(fabs(written - read) <= largest * DBL_EPSILON))
        fail_msg("%s: written %.17g, read %.17g", what, written, read);
}

/* The members a report carries, by kind, for comparing structs read back. */
typedef struct member {
    const char *name;
    size_t offset;
    int is_int;
} member_t;
#define REAL_OF(T, m) {#m, offsetof(T, m), 0}
#define INT_OF(T, m) {#m, offsetof(T, m), 1}

static const member_t RUN[] = {
    INT_OF(bg_solve_result_t, method), INT_OF(bg_solve_result_t, converged),
    INT_OF(bg_solve_result_t, iterations), REAL_OF(bg_solve_result_t, wall_seconds),
    REAL_OF(bg_solve_result_t, energy), REAL_OF(bg_solve_result_t, gradient_norm),
    REAL_OF(bg_solve_result_t, relative_gradient), REAL_OF(bg_solve_result_t, force_scale),
    REAL_OF(bg_solve_result_t, gradient_roundoff), INT_OF(bg_solve_result_t, roundoff_floor),
    INT_OF(bg_solve_result_t, continuation_stages), INT_OF(bg_solve_result_t, trace_count),
    INT_OF(bg_solve_result_t, step_count), INT_OF(bg_solve_result_t, limited_steps),
};
static const member_t POINT[] = {
    REAL_OF(bg_trace_point_t, seconds), INT_OF(bg_trace_point_t, iteration),
    INT_OF(bg_trace_point_t, stage), REAL_OF(bg_trace_point_t, energy),
    REAL_OF(bg_trace_point_t, gradient_norm), REAL_OF(bg_trace_point_t, relative_gradient),
    REAL_OF(bg_trace_point_t, error),
};
static const member_t STEP[] = {
    REAL_OF(bg_step_record_t, time), REAL_OF(bg_step_record_t, kinetic),
    REAL_OF(bg_step_record_t, potential), REAL_OF(bg_step_record_t, total_energy),
    REAL_OF(bg_step_record_t, linear_momentum[0]), REAL_OF(bg_step_record_t, linear_momentum[1]),
    REAL_OF(bg_step_record_t, linear_momentum[2]), REAL_OF(bg_step_record_t, angular_momentum[0]),
    REAL_OF(bg_step_record_t, angular_momentum[1]), REAL_OF(bg_step_record_t, angular_momentum[2]),
    INT_OF(bg_step_record_t, iterations), INT_OF(bg_step_record_t, limited),
    REAL_OF(bg_step_record_t, seconds),
};
#define MEMBERS(table) table, sizeof table / sizeof table[0]

/* Every member of the table equal in the structs at a and b (ints exactly,
 * numbers as assert_same). */
static void assert_same_members(const void *a, const void *b, const member_t *m, size_t n,
                                const char *what)
{
    for (size_t i = 0; i < n; i++) {
        const char *x = (const char *)a + m[i].offset, *y = (const char *)b + m[i].offset;
        char label[96];
        snprintf(label, sizeof label, "%s %s", what, m[i].name);
        if (m[i].is_int) {
            int u, v;
            memcpy(&u, x, sizeof u);
            memcpy(&v, y, sizeof v);
            if (u != v)
                fail_msg("%s: written %d, read %d", label, u, v);
        } else {
            double u, v;
            memcpy(&u, x, sizeof u);
            memcpy(&v, y, sizeof v);
            assert_same(u, v, label);
        }
    }
}

static void assert_same_run(const bg_solve_result_t *a, const bg_solve_result_t *b)
{
    assert_same_members(a, b, MEMBERS(RUN), "run");
    assert_string_equal(a->stop_reason, b->stop_reason);
    assert_int_equal(a->inverted_elements, b->inverted_elements);
    for (int k = 0; k < a->trace_count; k++)
        assert_same_members(&a->trace[k], &b->trace[k], MEMBERS(POINT), "trace point");
    for (int k = 0; k < a->step_count; k++)
        assert_same_members(&a->steps[k], &b->steps[k], MEMBERS(STEP), "step");
}

/* Renders runs' report for scene, parses it back and compares every run. */
static void round_trip(const bg_scene_t *scene, const bg_solve_result_t *runs, int count)
{
    bg_method methods[BG_REPORT_MAX_RUNS];
    for (int i = 0; i < count; i++)
        methods[i] = runs[i].method;
    bg_plan_t plan;
    bg_plan_for_scene(scene, methods, count, &plan);
    char *json = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_report_render(scene, &plan, runs, count, &json, &err) != BG_OK)
        fail_msg("%s", err.message);
    bg_report_runs_t back = BG_REPORT_RUNS_INIT;
    if (bg_report_parse_runs(json, strlen(json), "report.json", &back, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_int_equal(back.count, count);
    for (int i = 0; i < count; i++)
        assert_same_run(&runs[i], &back.run[i]);
    bg_report_runs_release(&back);
    assert_int_equal(back.count, 0);
    free(json);
}

static void static_methods_round_trip(void **state)
{
    (void)state;
    bg_scene_t *s = test_parse_scene(BAR, "small-bar.json");
    bg_solve_result_t runs[2] = {BG_SOLVE_RESULT_INIT, BG_SOLVE_RESULT_INIT};
    const bg_method methods[2] = {BG_METHOD_NEWTON, BG_METHOD_LOCAL_GLOBAL};
    bg_solve_result_t reference = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t ro = {.method = BG_METHOD_NEWTON, .tolerance = 1e-12,
                                   .max_iterations = 100};
    if (bg_static_solve(s, &ro, &reference, &err) != BG_OK)
        fail_msg("%s", err.message);
    for (int i = 0; i < 2; i++) {
        const bg_solve_options_t o = {.method = methods[i], .tolerance = 1e-8,
                                      .max_iterations = 2000, .reference = reference.q};
        if (bg_static_solve(s, &o, &runs[i], &err) != BG_OK)
            fail_msg("%s", err.message);
        /* The comparison means something only with real traces and errors. */
        assert_true(runs[i].trace_count > 2);
        assert_true(isfinite(runs[i].trace[runs[i].trace_count - 1].error));
    }
    round_trip(s, runs, 2);
    for (int i = 0; i < 2; i++)
        bg_solve_result_release(&runs[i]);
    bg_solve_result_release(&reference);
    bg_scene_destroy(&s);
}

static void dynamic_run_round_trip(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(BG_SOURCE_DIR "/tests/fixtures/scenes/short-spin.json");
    bg_solve_result_t run = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL};
    if (bg_dynamic_solve(s, &o, &run, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_int_equal(run.step_count, 21);
    round_trip(s, &run, 1);
    bg_solve_result_release(&run);
    bg_scene_destroy(&s);
}

/* A result with the values the report writes as null, and none counted. */
static void nulls_round_trip(void **state)
{
    (void)state;
    bg_scene_t *s = test_parse_scene(BAR, "small-bar.json");
    bg_trace_point_t trace[2] = {{0.0, 0, 1.5, 2.0, 1.0, NAN, 0}, {0.25, 1, NAN, INFINITY, 0.5, NAN, 1}};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    r.method = BG_METHOD_LOCAL_GLOBAL;
    r.stop_reason = "stalled";
    r.iterations = 1;
    r.wall_seconds = 0.25;
    r.energy = NAN;
    r.gradient_norm = 3.0;
    r.relative_gradient = 0.5;
    r.force_scale = 6.0;
    r.gradient_roundoff = 1e-15;
    r.continuation_stages = 2;
    r.inverted_elements = -1;
    r.trace = trace;
    r.trace_count = 2;
    round_trip(s, &r, 1);
    r.inverted_elements = 7;
    round_trip(s, &r, 1);
    bg_scene_destroy(&s);
}

/* A morph's "frames" become its steps (t, energy, iterations, seconds). */
static void morph_frames(void **state)
{
    (void)state;
    static const char json[] =
        "{\"runs\": [{\"method\": \"newton\", \"converged\": true, \"stop_reason\": \"completed\","
        " \"iterations\": 9, \"wall_seconds\": 1.5, \"energy\": null, \"relative_gradient\": 1e-9,"
        " \"frames\": [{\"t\": 0, \"energy\": 0, \"iterations\": 0, \"seconds\": 0},"
        " {\"t\": 0.5, \"energy\": 2.5, \"iterations\": 4, \"seconds\": 0.75},"
        " {\"t\": 1, \"energy\": null, \"iterations\": 5, \"seconds\": 0.5}],"
        " \"trace\": [{\"seconds\": 0.75, \"iteration\": 4, \"energy\": 2.5,"
        " \"relative_gradient\": 1e-9, \"error\": null}]}]}";
    bg_report_runs_t r = BG_REPORT_RUNS_INIT;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_report_parse_runs(json, strlen(json), "morph.json", &r, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_int_equal(r.count, 1);
    const bg_solve_result_t *run = &r.run[0];
    assert_string_equal(run->stop_reason, "completed");
    assert_true(isnan(run->energy));
    assert_int_equal(run->step_count, 3);
    assert_true(run->steps[1].time == 0.5 && run->steps[1].total_energy == 2.5 &&
                run->steps[1].iterations == 4 && run->steps[1].seconds == 0.75);
    assert_true(isnan(run->steps[2].total_energy));
    assert_int_equal(run->trace_count, 1);
    assert_true(isnan(run->trace[0].error) && isnan(run->trace[0].gradient_norm));
    assert_int_equal(run->inverted_elements, -1);
    bg_report_runs_release(&r);
}

/* Each malformed report fails with status and a message naming the field. */
static void malformed_reports(void **state)
{
    (void)state;
#define RUN(extra)                                                                                 \
    "{\"method\": \"newton\", \"converged\": true, \"stop_reason\": \"converged\","              \
    " \"iterations\": 1, \"wall_seconds\": 0.5, \"relative_gradient\": 1e-9" extra "}"
#define TRACE ", \"trace\": [{\"seconds\": 0, \"iteration\": 0, \"relative_gradient\": 1}]"
    static const struct {
        const char *json;
        bg_status status;
        const char *message;
    } cases[] = {
        {"{\"runs\": [" RUN(TRACE) ",", BG_ERR_PARSE, "bad.json: malformed JSON at line 1"},
        {"[]", BG_ERR_INVALID, "bad.json: expected an object, got an array"},
        {"{\"scene\": \"x\"}", BG_ERR_INVALID, "bad.json: runs: missing"},
        {"{\"runs\": {}}", BG_ERR_INVALID, "bad.json: runs: expected an array, got an object"},
        {"{\"runs\": [" RUN("") "]}", BG_ERR_INVALID, "bad.json: runs[0].trace: missing"},
        {"{\"runs\": [" RUN(TRACE) ", " RUN(", \"trace\": [{\"seconds\": 1}]") "]}",
         BG_ERR_INVALID, "bad.json: runs[1].trace[0].iteration: missing"},
        {"{\"runs\": [{\"method\": \"simplex\"}]}", BG_ERR_INVALID,
         "bad.json: runs[0].method: unknown method 'simplex'"},
        {"{\"runs\": [{\"method\": \"newton\", \"stop_reason\": \"x\", \"converged\": 1}]}",
         BG_ERR_INVALID,
         "bad.json: runs[0].converged"},
        {"{\"runs\": [" RUN(", \"trace\": [], \"iterations\": \"5\"") "]}", BG_ERR_INVALID,
         "bad.json: runs[0]: key 'iterations' appears twice"},
        {"{\"runs\": [" RUN(", \"trace\": [], \"steps\": [{\"time\": 0, \"linear_momentum\": [1]}]")
         "]}",
         BG_ERR_INVALID, "bad.json: runs[0].steps[0].linear_momentum"},
        {"{\"runs\": [" RUN(TRACE) "," RUN(TRACE) "," RUN(TRACE) "," RUN(TRACE) "," RUN(TRACE)
         "," RUN(TRACE) "," RUN(TRACE) "," RUN(TRACE) "," RUN(TRACE) "]}",
         BG_ERR_LIMIT, "bad.json: runs: 9 runs, at most 8 are read"},
    };
#undef RUN
#undef TRACE
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        bg_report_runs_t r = BG_REPORT_RUNS_INIT;
        bg_error_t err = BG_ERROR_INIT;
        const bg_status st =
            bg_report_parse_runs(cases[i].json, strlen(cases[i].json), "bad.json", &r, &err);
        if (st != cases[i].status || !strstr(err.message, cases[i].message))
            fail_msg("case %zu: status %d '%s', expected %d '%s'", i, st, err.message,
                     cases[i].status, cases[i].message);
        assert_int_equal(r.count, 0);
        assert_null(r.run[0].trace);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(static_methods_round_trip),
        cmocka_unit_test(dynamic_run_round_trip),
        cmocka_unit_test(nulls_round_trip),
        cmocka_unit_test(morph_frames),
        cmocka_unit_test(malformed_reports),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
