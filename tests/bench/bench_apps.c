/*
 * bench_apps — the applications on the engine: time integration, morphing
 * and parameterization.
 *
 *   OPENBLAS_NUM_THREADS=1 ./tests/bench/bench_apps [--smoke]
 *
 * Dynamics: per-step wall time and Newton iterations per step of the
 * variational integrator at h = 1/60 on bunny-drop and on a ≥ 100k-tet box,
 * and the step's cost in units of one static Newton iteration on the same
 * mesh (the target: ≤ 3). Morphing (bar-morph) and
 * parameterization (lion-head-param): Newton and local/global side by side,
 * wall time, iterations and the final energy. --smoke runs tiny cases.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_common.h"
#include "bg_clock.h"
#include "bg_dynamics.h"
#include "bg_morph.h"
#include "bg_param.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_static.h"

/* Scenes name the public meshes the build makes by their bare names. */
static const bg_scene_options_t MESH_OPTIONS = {.search_path = BG_MESH_DIR};

#define SCENES BG_SOURCE_DIR "/configs/scenes/"

static const char BOX_DROP_FULL[] =
    "{\"name\": \"box-drop\", \"mesh\": {\"generate\": \"box\", \"cells\": [30, 30, 19], "
    "\"size\": [1, 1, 0.6]}, \"material\": {\"E\": 1e5, \"nu\": 0.4, \"density\": 1000}, "
    "\"gravity\": [0, 0, -9.81], \"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0, 0, "
    "0], "
    "\"max\": [1, 0.02, 1]}}}], \"task\": {\"kind\": \"dynamic\", \"dt\": 0.016666666666666666, "
    "\"steps\": 10}}";
static const char BOX_DROP_SMOKE[] =
    "{\"name\": \"box-drop\", \"mesh\": {\"generate\": \"box\", \"cells\": [4, 4, 3], "
    "\"size\": [1, 1, 0.6]}, \"material\": {\"E\": 1e5, \"nu\": 0.4, \"density\": 1000}, "
    "\"gravity\": [0, 0, -9.81], \"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0, 0, "
    "0], "
    "\"max\": [1, 0.02, 1]}}}], \"task\": {\"kind\": \"dynamic\", \"dt\": 0.016666666666666666, "
    "\"steps\": 3}}";

static bg_scene_t *load(const char *path, const char *json)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    bg_status st =
        json ? bg_scene_parse_with(json, strlen(json), "bench.json", &MESH_OPTIONS, &s, &err)
             : bg_scene_load_with(path, &MESH_OPTIONS, &s, &err);
    if (st == BG_OK)
        st = bg_prepare_scene(s, &err);
    if (st != BG_OK) {
        fprintf(stderr, "bench_apps: %s\n", err.message);
        bench_fail("scene");
    }
    return s;
}

/* One static Newton iteration on the scene's mesh (its Hessian assembly,
 * factorization and solve, line search included): the cost unit of the
 * dynamics target. Measured as the mean over a 3-iteration capped solve. */
static double static_iteration_seconds(const bg_scene_t *s)
{
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {
        .method = BG_METHOD_NEWTON, .tolerance = 1e-300, .max_iterations = 3};
    if (bg_static_solve(s, &o, &r, &err) != BG_OK || r.iterations < 1) {
        bench_fail("static iteration");
        return 0.0;
    }
    const double per = (r.trace[r.trace_count - 1].seconds - r.trace[0].seconds) / r.iterations;
    bg_solve_result_release(&r);
    return per;
}

/* One dynamic run: mean wall seconds per step, Newton iterations per step
 * and factorizations per step; 0 on failure. */
static double run_dynamics(const char *label, bg_scene_t *s, int fresh, double *its,
                           double *factorizations, int *limited)
{
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_dynamic_options_t o = {.method = BG_METHOD_VARIATIONAL, .fresh_factor = fresh};
    if (bg_dynamic_solve(s, &o, &r, &err) != BG_OK) {
        fprintf(stderr, "bench_apps: %s\n", err.message);
        bench_fail(label);
        return 0.0;
    }
    const int steps = r.step_count - 1;
    double seconds = 0.0;
    for (int i = 1; i <= steps; i++)
        seconds += r.steps[i].seconds;
    *its = (double)r.iterations / steps;
    *factorizations = (double)r.factorizations / steps;
    *limited = r.limited_steps;
    bg_solve_result_release(&r);
    return seconds / steps;
}

/* The default integrator (factor reused across iterations and steps, L-BFGS
 * corrections) against the baseline that factors at every Newton
 * iteration, both in units of one static Newton iteration on the mesh. */
static void bench_dynamics(const char *label, bg_scene_t *s)
{
    if (!s)
        return;
    double its = 0.0, fact = 0.0, its0 = 0.0, fact0 = 0.0;
    int limited = 0, limited0 = 0;
    const double per_step = run_dynamics(label, s, 0, &its, &fact, &limited);
    const double baseline = run_dynamics(label, s, 1, &its0, &fact0, &limited0);
    if (!(per_step > 0.0) || !(baseline > 0.0))
        return;
    /* The static iteration runs the scene as a static problem from rest. */
    const bg_task_kind task = s->task;
    s->task = BG_TASK_STATIC;
    const double unit = static_iteration_seconds(s);
    s->task = task;
    printf("%-12s %7d tets %4d steps  reuse: %7.1f ms/step %6.2f it %5.2f factorizations"
           "  step = %5.2f static its (target <= 3)  limited %d\n",
           label, (int)s->mesh->ne, s->dynamic.steps, 1e3 * per_step, its, fact, per_step / unit,
           limited);
    printf("%-12s %7s      %4s        fresh: %7.1f ms/step %6.2f it %5.2f factorizations"
           "  step = %5.2f static its  reuse speed-up %.2fx\n",
           "", "", "", 1e3 * baseline, its0, fact0, baseline / unit, baseline / per_step);
    char name[96];
    snprintf(name, sizeof name, "dynamics.%s.ms_per_step", label);
    bench_record(name, 1e3 * per_step, "ms");
    snprintf(name, sizeof name, "dynamics.%s.iterations_per_step", label);
    bench_record(name, its, "it");
    snprintf(name, sizeof name, "dynamics.%s.step_in_static_iterations", label);
    bench_record(name, per_step / unit, "ratio");
    snprintf(name, sizeof name, "dynamics.%s.fresh_factor_step_in_static_iterations", label);
    bench_record(name, baseline / unit, "ratio");
    bench_check_positive(label, per_step);
}

static void bench_series(const char *label, bg_scene_t *s)
{
    if (!s)
        return;
    const bg_method methods[2] = {BG_METHOD_NEWTON, BG_METHOD_LOCAL_GLOBAL};
    for (int m = 0; m < 2; m++) {
        bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
        bg_error_t err = BG_ERROR_INIT;
        bg_status st;
        if (s->task == BG_TASK_MORPH) {
            const bg_morph_options_t o = {.method = methods[m]};
            st = bg_morph_solve(s, &o, &r, &err);
        } else {
            const bg_solve_options_t o = {.method = methods[m],
                                          .tolerance = s->tolerance,
                                          .max_iterations = bg_scene_max_iterations(s, methods[m]),
                                          .keep_orientation = 1};
            st = bg_static_solve(s, &o, &r, &err);
            if (st == BG_OK)
                bg_param_quality(s, r.q, &r.map);
        }
        if (st != BG_OK) {
            fprintf(stderr, "bench_apps: %s\n", err.message);
            bench_fail(label);
            continue;
        }
        printf("%-16s %-13s %8.3f s %6d iterations  energy %.10g  relative gradient %.3e  %s",
               label, bg_method_name(methods[m]), r.wall_seconds, r.iterations, r.energy,
               r.relative_gradient, r.stop_reason);
        if (r.map.valid)
            printf("  flips %lld area %.3f angle %.3f", (long long)r.map.flipped_triangles,
                   r.map.area_mean, r.map.angle_mean);
        printf("\n");
        char name[96];
        snprintf(name, sizeof name, "%s.%s.seconds", label, bg_method_name(methods[m]));
        bench_record(name, r.wall_seconds, "s");
        bench_check_positive(label, r.wall_seconds);
        bg_solve_result_release(&r);
    }
}

int main(int argc, char **argv)
{
    const int smoke = argc > 1 && strcmp(argv[1], "--smoke") == 0;
    bench_header("bench_apps", smoke);
    printf("Dynamics: variational midpoint at h = 1/60\n");
    bg_scene_t *s = NULL;
    if (!smoke) {
        s = load(SCENES "bunny-drop.json", NULL);
        bench_dynamics("bunny-drop", s);
        bg_scene_destroy(&s);
    }
    s = load(NULL, smoke ? BOX_DROP_SMOKE : BOX_DROP_FULL);
    bench_dynamics("box-drop", s);
    bg_scene_destroy(&s);
    printf("\nMorphing and parameterization: Newton and local/global\n");
    if (!smoke) {
        s = load(SCENES "bar-morph.json", NULL);
        bench_series("bar-morph", s);
        bg_scene_destroy(&s);
        s = load(SCENES "lion-head-param.json", NULL);
        bench_series("lion-head-param", s);
        bg_scene_destroy(&s);
    } else {
        s = load(BG_SOURCE_DIR "/tests/fixtures/scenes/disk-param.json", NULL);
        bench_series("disk-param", s);
        bg_scene_destroy(&s);
    }
    bench_print_figures();
    return bench_failures ? 1 : 0;
}
