/*
 * bench_solve — where the static solvers spend their time, and how fast
 * they reach a given accuracy.
 *
 *   OPENBLAS_NUM_THREADS=1 ./tests/bench/bench_solve [--smoke | --stiff]
 *
 * (OpenBLAS reads the variable when the library loads, so it must be set
 * in the environment: a setenv in main would be too late.)
 *
 * Part 1, per iteration: Newton and local/global with a capped iteration
 * count (the tolerance is set out of reach so that every run does exactly
 * the cap, unless it converges first) on the bunny-edit scene and a box of
 * 201,600 tets; the time split into rotation fit + energy + gradient,
 * assembly, CHOLMOD analysis, factorization and solves; and Newton's time
 * per iteration against CHOLMOD factorize + solve alone on the same
 * matrix (the PSD-projected Hessian at the start positions).
 *
 * Part 2, error against run time: on bar-twist and stiff-bar, the wall
 * time until Newton's relative gradient first reaches 1e-8 and until
 * local/global's first reaches 1e-4, read from the solvers' traces.
 *
 * --smoke: a tiny box for part 1, and part 2 with capped local/global.
 * --stiff: part 3 alone (the README's stiff-bar table).
 * --only CASE: part 1 alone on one of its cases (bunny-edit, box-201600).
 *
 * The Newton / CHOLMOD ratio is also given in CPU time of this thread
 * (newton_over_cholmod_cpu): the Newton iterations after the first (a solve
 * capped at N iterations minus one capped at 1, so set-up and the
 * symbolic analysis drop out) against the factorization and the solve
 * alone. On a machine shared with other work the wall-clock ratio mixes in
 * whatever preempted each phase; the CPU ratio does not (with
 * OMP_THREAD_LIMIT=1 and OPENBLAS_NUM_THREADS=1 everything runs on this
 * thread). Cache contention from neighbours still shows in both. Both
 * sides are medians of three runs. The in-process Newton solver stores its
 * Hessian in the factor's order (bg_sparse_reorder), which CHOLMOD factors
 * without permuting it: the ratio is given against CHOLMOD as it is
 * usually called (the matrix in the unknowns' order, permuted by every
 * factorization: newton_over_cholmod_cpu) and against the same stored
 * order (newton_over_cholmod_stored_cpu, what Newton adds to its own
 * factorization and solve).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench_common.h"
#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_sparse.h"
#include "bg_static.h"

/* Scenes name the public meshes the build makes by their bare names. */
static const bg_scene_options_t MESH_OPTIONS = {.search_path = BG_MESH_DIR};

/* A tolerance no run reaches within its cap: part 1 times whole iterations. */
#define UNREACHABLE_TOLERANCE 1e-300
/* Newton's per-iteration time over CHOLMOD factorize + solve alone. */
#define TARGET_NEWTON_OVER_CHOLMOD 1.3
/* Part 2 thresholds on the relative gradient. */
#define NEWTON_THRESHOLD 1e-8
#define LOCAL_GLOBAL_THRESHOLD 1e-4
/* Part 2 iteration caps. */
#define NEWTON_MAX_ITERATIONS 500
#define LOCAL_GLOBAL_MAX_ITERATIONS_FULL 20000
#define LOCAL_GLOBAL_MAX_ITERATIONS_SMOKE 2000
/* Repetitions of the stand-alone factorization and solve. */
#define CHOLMOD_REPS_FULL 3
#define CHOLMOD_REPS_SMOKE 3
#define SOLVE_REPS 10
/* Repetitions of the Newton CPU-time measurement (its median is taken,
 * like the stand-alone factorization's). */
#define NEWTON_CPU_REPS 3
/* First diagonal shift, relative to the largest entry, if the stand-alone
 * factorization finds the matrix not numerically positive definite (the
 * solver does the same). */
#define CHOLMOD_RETRY_SHIFT 1e-8

/* The large box: 40x40x21 cells x 6 = 201,600 tets, bottom clamped, top
 * moved sideways and down. */
static const char BOX_SCENE_FULL[] =
    "{\"name\": \"box-201600\","
    " \"mesh\": {\"generate\": \"box\", \"cells\": [40, 40, 21], \"size\": [2, 2, 1.05]},"
    " \"material\": {\"mu\": 1, \"lambda\": 1},"
    " \"handles\": ["
    "  {\"select\": {\"box_fraction\": {\"min\": [0, 0, 0], \"max\": [1, 1, 0]}}},"
    "  {\"select\": {\"box_fraction\": {\"min\": [0, 0, 1], \"max\": [1, 1, 1]}},"
    "   \"transform\": {\"translate\": [0.1, 0, -0.1]}}]}";
static const char BOX_SCENE_SMOKE[] =
    "{\"name\": \"box-864\","
    " \"mesh\": {\"generate\": \"box\", \"cells\": [6, 6, 4], \"size\": [1.5, 1.5, 1]},"
    " \"material\": {\"mu\": 1, \"lambda\": 1},"
    " \"handles\": ["
    "  {\"select\": {\"box_fraction\": {\"min\": [0, 0, 0], \"max\": [1, 1, 0]}}},"
    "  {\"select\": {\"box_fraction\": {\"min\": [0, 0, 1], \"max\": [1, 1, 1]}},"
    "   \"transform\": {\"translate\": [0.1, 0, -0.1]}}]}";

typedef struct iteration_case {
    const char *label;
    const char *file; /* scene file under BG_SOURCE_DIR, or NULL */
    const char *json; /* inline scene when file is NULL */
    int newton_cap;
    int local_global_cap;
} iteration_case_t;

/* Per-iteration split of one capped solve (seconds). */
typedef struct split {
    int iterations;
    int converged;
    double relative_gradient;
    double setup;         /* until the first trace point: setup + first evaluation */
    double once;          /* in the loop but paid once: analysis (+ prefactor) */
    double per_iteration; /* (loop time − once) / iterations */
    double rotfit, assembly, factor, solve, other; /* per iteration */
    int64_t factorizations;
    double evaluations; /* energy + gradient evaluations in all */
} split_t;

static bg_status load_scene(const iteration_case_t *c, bg_scene_t **scene, bg_error_t *err)
{
    if (c->file) {
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", BG_SOURCE_DIR, c->file);
        bg_status st = bg_scene_load_with(path, &MESH_OPTIONS, scene, err);
        return st == BG_OK ? bg_prepare_scene(*scene, err) : st;
    }
    bg_status st =
        bg_scene_parse_with(c->json, strlen(c->json), c->label, &MESH_OPTIONS, scene, err);
    return st == BG_OK ? bg_prepare_scene(*scene, err) : st;
}

/* CPU seconds of this thread. */
static double thread_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static bg_status run_solver(const bg_scene_t *scene, bg_method method, double tolerance, int cap,
                            bg_solve_result_t *result, bg_error_t *err)
{
    bg_solve_options_t opts;
    memset(&opts, 0, sizeof opts);
    opts.method = method;
    opts.tolerance = tolerance;
    opts.max_iterations = cap;
    return bg_static_solve(scene, &opts, result, err);
}

/* Splits a capped solve's time per iteration. The solver accumulates the
 * rotation-fit time over every evaluation, including the one before the
 * loop; that one is taken out at the average cost of an evaluation. */
static split_t split_of(const bg_scene_t *scene, const bg_solve_result_t *r)
{
    split_t s;
    memset(&s, 0, sizeof s);
    s.iterations = r->iterations;
    s.converged = r->converged;
    s.relative_gradient = r->relative_gradient;
    s.factorizations = r->factorizations;
    if (r->trace_count < 1 || r->iterations < 1)
        return s;
    const double its = r->iterations;
    s.setup = r->trace[0].seconds;
    const double loop = r->trace[r->trace_count - 1].seconds - r->trace[0].seconds;
    s.evaluations = (double)r->rotfit.calls / scene->mesh->ne;
    const double per_eval = s.evaluations > 0.0 ? r->rotfit_seconds / s.evaluations : 0.0;
    s.rotfit = per_eval * (s.evaluations - 1.0) / its;
    s.solve = r->solve_seconds / its;
    double in_loop_once = 0.0;
    if (r->method == BG_METHOD_NEWTON) {
        s.once = in_loop_once = r->analyze_seconds;
        s.assembly = r->assembly_seconds / its;
        s.factor = r->factor_seconds / its;
    } else {
        /* Local/global assembles and factors its matrix once, in the
         * solver's set-up (before the first trace point). */
        for (int i = 0; i < r->setup.count; i++)
            if (strncmp(r->setup.step[i].name, "local/global", 12) == 0)
                s.once += r->setup.step[i].seconds;
    }
    s.per_iteration = (loop - in_loop_once) / its;
    s.other = s.per_iteration - s.rotfit - s.assembly - s.factor - s.solve;
    return s;
}

/* CHOLMOD alone on the Newton matrix at the scene's start positions:
 * analysis once, then median numeric factorization and median solve.
 * stored 0: the matrix as CHOLMOD is usually handed it (lower triangle in
 * the unknowns' order; each factorization permutes it); 1: stored in its
 * factor's order (bg_sparse_reorder), as the in-process Newton solver
 * stores it, which CHOLMOD factors as it is. */
typedef struct cholmod_alone {
    int32_t size;
    size_t nonzeros;
    double analyze, factor, solve;
    double factor_cpu, solve_cpu; /* medians of this thread's CPU seconds */
} cholmod_alone_t;

static bg_status time_cholmod_alone(const bg_scene_t *scene, int reps, int stored,
                                    cholmod_alone_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    const bg_mesh_t *mesh = scene->mesh;
    const int n = mesh->dim;
    const size_t ndof = (size_t)mesh->nv * (size_t)n;
    bg_elastic_t *model = NULL;
    bg_sparse_t *sys = NULL;
    int32_t *free_index = malloc(ndof * sizeof *free_index);
    double *grad = malloc(ndof * sizeof *grad);
    double *rhs = malloc(ndof * sizeof *rhs);
    double samples[BENCH_MAX_REPS], cpu[BENCH_MAX_REPS];
    bg_status st = BG_OK;
    if (!free_index || !grad || !rhs) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        goto done;
    }
    int32_t nfree = 0;
    for (size_t i = 0; i < ndof; i++)
        free_index[i] = scene->constrained[i] ? -1 : nfree++;
    st = bg_elastic_new(mesh, scene->material.mu, scene->material.lambda, &model, err);
    if (st != BG_OK)
        goto done;
    st = bg_sparse_new(mesh, n, free_index, nfree, &sys, err);
    if (st == BG_OK && stored)
        st = bg_sparse_reorder(sys, err);
    if (st != BG_OK)
        goto done;
    bg_elastic_eval(model, scene->initial, grad);
    bg_sparse_zero(sys);
    bg_elastic_assemble_hessian(model, scene->initial, 1, 1.0, bg_sparse_scatter(sys),
                                bg_sparse_values(sys));
    out->size = bg_sparse_size(sys);
    out->nonzeros = bg_sparse_nonzeros(sys);
    double shift = 0.0;
    bg_error_t local = BG_ERROR_INIT;
    st = bg_sparse_factorize(sys, shift, &local);
    if (st == BG_ERR_NUMERIC) {
        const double *values = bg_sparse_values(sys);
        double largest = 0.0;
        for (size_t i = 0; i < out->nonzeros; i++)
            largest = fmax(largest, fabs(values[i]));
        shift = CHOLMOD_RETRY_SHIFT * largest;
        bg_error_clear(&local);
        st = bg_sparse_factorize(sys, shift, &local);
    }
    if (st != BG_OK) {
        st = bg_error_set(err, st, "%s", local.message);
        goto done;
    }
    /* The first call did the analysis and one factorization. */
    out->analyze = bg_sparse_timing(sys).analyze_seconds;
    for (int r = 0; r < reps; r++) {
        const double t0 = bg_clock_now(), c0 = thread_seconds();
        st = bg_sparse_factorize(sys, shift, err);
        samples[r] = bg_clock_now() - t0;
        cpu[r] = thread_seconds() - c0;
        if (st != BG_OK)
            goto done;
    }
    out->factor = bench_median(samples, reps);
    out->factor_cpu = bench_median(cpu, reps);
    for (size_t i = 0; i < ndof; i++)
        if (free_index[i] >= 0)
            rhs[free_index[i]] = -grad[i];
    for (int r = 0; r < SOLVE_REPS; r++) {
        const double t0 = bg_clock_now(), c0 = thread_seconds();
        st = bg_sparse_solve(sys, rhs, grad, err);
        samples[r] = bg_clock_now() - t0;
        cpu[r] = thread_seconds() - c0;
        if (st != BG_OK)
            goto done;
    }
    out->solve = bench_median(samples, SOLVE_REPS);
    out->solve_cpu = bench_median(cpu, SOLVE_REPS);
done:
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&model);
    free(free_index);
    free(grad);
    free(rhs);
    return st;
}

static void print_split_row(const char *label, const char *method, const split_t *s)
{
    printf("%-11s %-12s %5d %4s %9.3g %9.2f %9.2f %10.2f %9.2f %9.2f %9.2f %9.2f %9.2f %6.2f\n",
           label, method, s->iterations, s->converged ? "yes" : "no", s->relative_gradient,
           1e3 * s->setup, 1e3 * s->once, 1e3 * s->per_iteration, 1e3 * s->rotfit,
           1e3 * s->assembly, 1e3 * s->factor, 1e3 * s->solve, 1e3 * s->other,
           s->iterations > 0 ? (double)s->factorizations / s->iterations : 0.0);
}

static void record_split(const char *label, const char *method, const split_t *s)
{
    char name[BENCH_NAME_MAX];
    const struct {
        const char *key;
        double value;
    } parts[] = {{"per_iteration", s->per_iteration},     {"rotfit_per_iteration", s->rotfit},
                 {"assembly_per_iteration", s->assembly}, {"factor_per_iteration", s->factor},
                 {"solve_per_iteration", s->solve},       {"one_time", s->once}};
    for (size_t i = 0; i < sizeof parts / sizeof parts[0]; i++) {
        snprintf(name, sizeof name, "solve.%s.%s.%s", label, method, parts[i].key);
        bench_record(name, 1e3 * parts[i].value, "ms");
    }
}

static int bench_iterations(const iteration_case_t *c, int cholmod_reps)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *scene = NULL;
    if (load_scene(c, &scene, &err) != BG_OK) {
        fprintf(stderr, "bench_solve: %s\n", err.message);
        bench_fail("scene failed to load");
        return -1;
    }
    const bg_method methods[2] = {BG_METHOD_NEWTON, BG_METHOD_LOCAL_GLOBAL};
    const int caps[2] = {c->newton_cap, c->local_global_cap};
    double newton_per_iteration = NAN, newton_cpu = NAN;
    /* Newton's iterations 2..cap in CPU time: the whole solve capped at
     * cap minus the same capped at 1 (set-up, first evaluation, analysis
     * and first iteration cancel). */
    if (c->newton_cap > 2) { /* two iterations at least: one is within the noise */
        double samples[NEWTON_CPU_REPS];
        int got = 0;
        for (int rep = 0; rep < NEWTON_CPU_REPS; rep++) {
            bg_solve_result_t r1 = BG_SOLVE_RESULT_INIT, rn = BG_SOLVE_RESULT_INIT;
            const double c0 = thread_seconds();
            bg_status st1 =
                run_solver(scene, BG_METHOD_NEWTON, UNREACHABLE_TOLERANCE, 1, &r1, &err);
            const double c1 = thread_seconds();
            if (st1 == BG_OK)
                st1 = run_solver(scene, BG_METHOD_NEWTON, UNREACHABLE_TOLERANCE, c->newton_cap,
                                 &rn, &err);
            const double c2 = thread_seconds();
            if (st1 == BG_OK && rn.iterations == c->newton_cap && r1.iterations == 1)
                samples[got++] = ((c2 - c1) - (c1 - c0)) / (c->newton_cap - 1);
            bg_solve_result_release(&r1);
            bg_solve_result_release(&rn);
        }
        if (got == NEWTON_CPU_REPS)
            newton_cpu = bench_median(samples, got);
    }
    for (int m = 0; m < 2; m++) {
        bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
        if (run_solver(scene, methods[m], UNREACHABLE_TOLERANCE, caps[m], &r, &err) != BG_OK) {
            fprintf(stderr, "bench_solve: %s: %s\n", c->label, err.message);
            bench_fail("solver setup failed");
            bg_scene_destroy(&scene);
            return -1;
        }
        const split_t s = split_of(scene, &r);
        const char *name = bg_method_name(methods[m]);
        print_split_row(c->label, name, &s);
        record_split(c->label, name, &s);
        char what[160];
        snprintf(what, sizeof what, "%s %s time per iteration", c->label, name);
        bench_check_positive(what, s.per_iteration);
        if (!(s.relative_gradient < 1.0)) {
            snprintf(what, sizeof what, "%s %s did not reduce the gradient", c->label, name);
            bench_fail(what);
        }
        if (methods[m] == BG_METHOD_NEWTON)
            newton_per_iteration = s.per_iteration;
        bg_solve_result_release(&r);
    }
    cholmod_alone_t alone, stored;
    if (time_cholmod_alone(scene, cholmod_reps, 0, &alone, &err) != BG_OK ||
        time_cholmod_alone(scene, cholmod_reps, 1, &stored, &err) != BG_OK) {
        fprintf(stderr, "bench_solve: %s: CHOLMOD alone: %s\n", c->label, err.message);
        bench_fail("stand-alone factorization failed");
        bg_scene_destroy(&scene);
        return -1;
    }
    const double alone_total = alone.factor + alone.solve;
    const double ratio = newton_per_iteration / alone_total;
    const double ratio_cpu = newton_cpu / (alone.factor_cpu + alone.solve_cpu);
    const double ratio_stored_cpu = newton_cpu / (stored.factor_cpu + stored.solve_cpu);
    printf("%-11s CHOLMOD alone on the Newton matrix (n = %d, nnz(lower) = %zu): analysis %.2f "
           "ms, factorize %.2f ms, solve %.2f ms; Newton per iteration / (factorize + solve) = "
           "%.3f (target <= %.1f)\n",
           c->label, alone.size, alone.nonzeros, 1e3 * alone.analyze, 1e3 * alone.factor,
           1e3 * alone.solve, ratio, TARGET_NEWTON_OVER_CHOLMOD);
    if (isfinite(ratio_cpu))
        printf("%-11s the same in CPU time: Newton iteration %.2f ms (iterations 2..%d), "
               "factorize %.2f ms, solve %.2f ms: %.3f\n",
               c->label, 1e3 * newton_cpu, c->newton_cap, 1e3 * alone.factor_cpu,
               1e3 * alone.solve_cpu, ratio_cpu);
    if (isfinite(ratio_stored_cpu))
        printf("%-11s against the matrix stored in its factor's order (as Newton stores it), CPU "
               "time: factorize %.2f ms, solve %.2f ms: %.3f\n",
               c->label, 1e3 * stored.factor_cpu, 1e3 * stored.solve_cpu, ratio_stored_cpu);
    char name[BENCH_NAME_MAX];
    snprintf(name, sizeof name, "solve.%s.cholmod.analyze", c->label);
    bench_record(name, 1e3 * alone.analyze, "ms");
    snprintf(name, sizeof name, "solve.%s.cholmod.factorize", c->label);
    bench_record(name, 1e3 * alone.factor, "ms");
    snprintf(name, sizeof name, "solve.%s.cholmod.solve", c->label);
    bench_record(name, 1e3 * alone.solve, "ms");
    snprintf(name, sizeof name, "solve.%s.newton_over_cholmod", c->label);
    bench_record(name, ratio, "ratio");
    bench_check_positive(name, ratio);
    if (isfinite(ratio_cpu)) {
        snprintf(name, sizeof name, "solve.%s.newton_over_cholmod_cpu", c->label);
        bench_record(name, ratio_cpu, "ratio");
        bench_check_positive(name, ratio_cpu);
    }
    if (isfinite(ratio_stored_cpu)) {
        snprintf(name, sizeof name, "solve.%s.newton_over_cholmod_stored_cpu", c->label);
        bench_record(name, ratio_stored_cpu, "ratio");
        bench_check_positive(name, ratio_stored_cpu);
    }
    bg_scene_destroy(&scene);
    return 0;
}

/* Wall time at the first trace point at or below the threshold; NAN if
 * the run never got there. */
static double time_to_reach(const bg_solve_result_t *r, double threshold, int *iteration)
{
    for (int i = 0; i < r->trace_count; i++)
        if (r->trace[i].relative_gradient <= threshold) {
            *iteration = r->trace[i].iteration;
            return r->trace[i].seconds;
        }
    *iteration = -1;
    return NAN;
}

static int bench_accuracy(const char *file, const char *label, int local_global_cap)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *scene = NULL;
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", BG_SOURCE_DIR, file);
    if (bg_scene_load_with(path, &MESH_OPTIONS, &scene, &err) != BG_OK ||
        bg_prepare_scene(scene, &err) != BG_OK) {
        fprintf(stderr, "bench_solve: %s\n", err.message);
        bench_fail("scene failed to load");
        return -1;
    }
    const bg_method methods[2] = {BG_METHOD_NEWTON, BG_METHOD_LOCAL_GLOBAL};
    const double thresholds[2] = {NEWTON_THRESHOLD, LOCAL_GLOBAL_THRESHOLD};
    const int caps[2] = {NEWTON_MAX_ITERATIONS, local_global_cap};
    double reached[2] = {NAN, NAN};
    for (int m = 0; m < 2; m++) {
        bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
        if (run_solver(scene, methods[m], thresholds[m], caps[m], &r, &err) != BG_OK) {
            fprintf(stderr, "bench_solve: %s: %s\n", label, err.message);
            bench_fail("solver setup failed");
            bg_scene_destroy(&scene);
            return -1;
        }
        int at = -1;
        reached[m] = time_to_reach(&r, thresholds[m], &at);
        const char *name = bg_method_name(methods[m]);
        if (isfinite(reached[m]))
            printf("%-10s %-12s %9.0e %10.4f %10d %10d %12.3g  %s\n", label, name, thresholds[m],
                   reached[m], at, r.iterations, r.relative_gradient, r.stop_reason);
        else
            printf("%-10s %-12s %9.0e %10s %10s %10d %12.3g  NOT REACHED in %d iterations "
                   "(%.3f s, %s)\n",
                   label, name, thresholds[m], "-", "-", r.iterations, r.relative_gradient, caps[m],
                   r.wall_seconds, r.stop_reason);
        char fig[BENCH_NAME_MAX];
        snprintf(fig, sizeof fig, "accuracy.%s.%s.seconds_to_threshold", label, name);
        if (isfinite(reached[m]))
            bench_record(fig, reached[m], "s");
        if (methods[m] == BG_METHOD_NEWTON && !isfinite(reached[m])) {
            char what[160];
            snprintf(what, sizeof what, "%s: Newton did not converge to %.0e (%s)", label,
                     NEWTON_THRESHOLD, r.stop_reason);
            bench_fail(what);
        }
        bg_solve_result_release(&r);
    }
    if (isfinite(reached[0]) && isfinite(reached[1])) {
        const double ratio = reached[0] / reached[1];
        printf("%-10s newton(1e-8) / local-global(1e-4) time ratio = %.3f\n", label, ratio);
        char fig[BENCH_NAME_MAX];
        snprintf(fig, sizeof fig, "accuracy.%s.newton_over_local_global", label);
        bench_record(fig, ratio, "ratio");
        bench_check_positive(fig, ratio);
    } else {
        printf("%-10s newton(1e-8) / local-global(1e-4) time ratio: n/a (a threshold was not "
               "reached)\n",
               label);
    }
    bg_scene_destroy(&scene);
    return 0;
}

/*
 * Part 3: Newton on the stiff-bar geometry (16x4x4 cells, 4x1x1, μ = 1)
 * with λ/μ = 10³, 10⁴, 10⁵, the far end turned 90° about the bar's axis
 * (twisted) or about z through the end face's centre (bent), tolerance
 * 1e-8, 1000 iterations at most: the default solve (continuation in λ,
 * chord steps) with its iterations, factorizations, chord steps,
 * continuation stages, seconds, relative gradient and the inverted
 * elements of the result; then, in the same run, the baselines: one solve
 * at the scene's λ (no continuation, chord steps: the previous default)
 * and plain Newton (neither), each with its iterations, seconds and the
 * energy of its result minus the default's (the problem is non-convex: a
 * non-zero difference is another local minimum). Smoke: λ/μ = 10³
 * twisted only.
 */
static void bench_stiff(int smoke)
{
    static const char *const lambdas[3] = {"1e3", "1e4", "1e5"};
    printf("\nPart 3: stiff bar, Newton to 1e-8 (the stiff-bar geometry, mu = 1); one = one solve "
           "at the scene's lambda (no continuation), plain = one solve without chord steps\n");
    printf("%-6s %-8s %6s %6s %6s %6s %8s %11s %5s %6s %8s %10s %6s %8s %10s  %s\n", "lambda",
           "motion", "iters", "facts", "chords", "stages", "seconds", "final_rel_g", "inv",
           "one_it", "one_s", "one_dE", "pl_it", "plain_s", "plain_dE", "stop reason");
    for (int l = 0; l < (smoke ? 1 : 3); l++)
        for (int bent = 0; bent < (smoke ? 1 : 2); bent++) {
            char json[1024];
            snprintf(
                json, sizeof json,
                "{\"mesh\": {\"generate\": \"box\", \"cells\": [16, 4, 4], \"size\": [4, 1, 1]},"
                "\"material\": {\"mu\": 1, \"lambda\": %s},"
                "\"handles\": [{\"select\": {\"box\": {\"min\": [0,0,0], \"max\": [0,1,1]}}},"
                "{\"select\": {\"box\": {\"min\": [4,0,0], \"max\": [4,1,1]}},"
                " \"transform\": {\"rotate\": {\"axis\": %s, \"degrees\": 90,"
                " \"center\": [4, 0.5, 0.5]}}}]}",
                lambdas[l], bent ? "[0, 0, 1]" : "[1, 0, 0]");
            bg_error_t err = BG_ERROR_INIT;
            bg_scene_t *scene = NULL;
            if (bg_prepare_parse(json, strlen(json), "stiff.json", NULL, &scene, &err) != BG_OK) {
                bench_fail(err.message);
                return;
            }
            bg_solve_result_t r = BG_SOLVE_RESULT_INIT, one = BG_SOLVE_RESULT_INIT,
                              plain = BG_SOLVE_RESULT_INIT;
            bg_solve_options_t opts = {
                .method = BG_METHOD_NEWTON, .tolerance = 1e-8, .max_iterations = 1000};
            bg_status st = bg_static_solve(scene, &opts, &r, &err);
            opts.continuation = -1;
            if (st == BG_OK)
                st = bg_static_solve(scene, &opts, &one, &err);
            opts.chord_steps = -1;
            if (st == BG_OK)
                st = bg_static_solve(scene, &opts, &plain, &err);
            if (st != BG_OK) {
                bench_fail(err.message);
                bg_solve_result_release(&r);
                bg_solve_result_release(&one);
                bg_scene_destroy(&scene);
                return;
            }
            printf("%-6s %-8s %6d %6lld %6d %6d %8.3f %11.3e %5lld %6d %8.3f %10.3e %6d %8.3f "
                   "%10.3e  %s\n",
                   lambdas[l], bent ? "bent" : "twisted", r.iterations,
                   (long long)(r.factorizations + r.setup.factorizations), r.chord_steps,
                   r.continuation_stages, r.wall_seconds, r.relative_gradient,
                   (long long)r.inverted_elements, one.iterations, one.wall_seconds,
                   one.energy - r.energy, plain.iterations, plain.wall_seconds,
                   plain.energy - r.energy, r.stop_reason);
            char name[64];
            snprintf(name, sizeof name, "stiff_%s_%s_iterations", bent ? "bent" : "twisted",
                     lambdas[l]);
            bench_record(name, r.iterations, "iterations");
            if (!r.converged || !one.converged || !plain.converged)
                bench_fail("a stiff-bar Newton solve did not converge");
            bg_solve_result_release(&r);
            bg_solve_result_release(&one);
            bg_solve_result_release(&plain);
            bg_scene_destroy(&scene);
        }
}

int main(int argc, char **argv)
{
    int smoke = 0, stiff_only = 0;
    const char *only = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--smoke") == 0) {
            smoke = 1;
        } else if (strcmp(argv[i], "--stiff") == 0) {
            stiff_only = 1; /* Part 3 alone, full */
        } else if (strcmp(argv[i], "--only") == 0 && i + 1 < argc) {
            only = argv[++i]; /* one case of part 1 alone */
        } else {
            fprintf(stderr,
                    "usage: OPENBLAS_NUM_THREADS=1 bench_solve [--smoke | --stiff | --only CASE]\n");
            return 2;
        }
    }
    if (stiff_only) {
        bench_header("bench_solve --stiff: Newton on the stiff bar", 0);
        bench_stiff(0);
        bench_print_figures();
        return bench_failures > 0 ? 1 : 0;
    }
    bench_header("bench_solve: static solvers, time per iteration and time to accuracy", smoke);

    static const iteration_case_t FULL_CASES[] = {
        {"bunny-edit", "configs/scenes/bunny-edit.json", NULL, 5, 50},
        {"box-201600", NULL, BOX_SCENE_FULL, 3, 20},
    };
    static const iteration_case_t SMOKE_CASES[] = {
        {"box-864", NULL, BOX_SCENE_SMOKE, 2, 5},
    };
    const iteration_case_t *cases = smoke ? SMOKE_CASES : FULL_CASES;
    const size_t case_count = smoke ? sizeof SMOKE_CASES / sizeof SMOKE_CASES[0]
                                    : sizeof FULL_CASES / sizeof FULL_CASES[0];

    printf("Part 1: time per iteration (ms). Iterations capped (newton / local-global): ");
    for (size_t i = 0; i < case_count; i++)
        printf("%s %d / %d%s", cases[i].label, cases[i].newton_cap, cases[i].local_global_cap,
               i + 1 < case_count ? ", " : "\n");
    printf("setup = scene to first trace point (model, pattern, first evaluation); once = "
           "CHOLMOD analysis,\nplus for local-global the Laplacian assembly and its single "
           "factorization; per_it excludes both.\nrotfit = rotation fit + energy + gradient "
           "(all line-search evaluations); fact/it = factorizations per iteration.\n\n");
    printf("%-11s %-12s %5s %4s %9s %9s %9s %10s %9s %9s %9s %9s %9s %6s\n", "scene", "method",
           "iters", "conv", "rel_grad", "setup", "once", "per_it", "rotfit", "assembly", "factor",
           "solve", "other", "fact/it");
    int ran = 0;
    for (size_t i = 0; i < case_count; i++)
        if (!only || strcmp(only, cases[i].label) == 0) {
            bench_iterations(&cases[i], smoke ? CHOLMOD_REPS_SMOKE : CHOLMOD_REPS_FULL);
            ran++;
        }
    if (only) {
        if (!ran)
            bench_fail("--only names no case of part 1");
        bench_print_figures();
        return bench_failures > 0 ? 1 : 0;
    }

    printf("\nPart 2: error against run time (seconds from the start of the solve, setup "
           "included)\n");
    printf("%-10s %-12s %9s %10s %10s %10s %12s  %s\n", "scene", "method", "threshold", "seconds",
           "at_iter", "iters", "final_rel_g", "stop reason");
    const int lg_cap = smoke ? LOCAL_GLOBAL_MAX_ITERATIONS_SMOKE : LOCAL_GLOBAL_MAX_ITERATIONS_FULL;
    bench_accuracy("configs/scenes/bar-twist.json", "bar-twist", lg_cap);
    bench_accuracy("configs/scenes/stiff-bar.json", "stiff-bar", lg_cap);
    bench_stiff(smoke);

    bench_print_figures();
    if (bench_failures > 0) {
        printf("\n%d sanity check(s) failed\n", bench_failures);
        return 1;
    }
    return 0;
}
