/*
 * bench_scale — how the cost of a static solve grows with the mesh size.
 *
 *   OPENBLAS_NUM_THREADS=1 ./tests/bench/bench_scale [--smoke] [--csv PATH]
 *                                                    [--svg PATH] [--memory-svg PATH]
 *                                                    [--max-tets N]
 *
 * (OpenBLAS reads the variable when the library loads, so it must be set
 * in the environment.)
 *
 * The scene: a 16:1:1 bar of cubic cells (Kuhn-split into 6 tets per
 * cell), μ = λ = 1, the x = 0 face clamped and the far face turned 90°
 * about the bar's axis, from the interpolated start. Six sizes from 12,000
 * to 1,028,016 tets, a factor 2.1 to 2.7 apart, all of the same shape so
 * that the fitted exponents describe size alone. The largest is the
 * armadillo-sized case: the public armadillo is a triangle surface and the
 * project has no tetrahedralizer, so a box of the same tet count stands in
 * (354 x 22 x 22 cells, 0.1 % fewer than the 1,029,067 of issue 9). The
 * shape sets the factorization's constant, not its growth: nested
 * dissection of an A:1:1 bar costs about n²/A flops, so a compact box
 * costs several times more than this bar at the same size, and much more
 * than the armadillo, whose separators are small for its size.
 *
 * Per size and method, in a child process of its own (fork, then the
 * child's VmHWM, so sizes do not inherit each other's heap): the scene
 * set-up, bg_solver_new, and a solve capped at a fixed number of
 * iterations (tolerance out of reach, as in bench_solve), its time per
 * iteration split into the solver's own counters — rotation fit with
 * energy and gradient (every line-search evaluation), assembly, CHOLMOD
 * numeric factorization, triangular solves, and the unattributed rest —
 * plus the once-per-solve CHOLMOD analysis. The solver reports no
 * factorization time for local/global (it factors c·L inside
 * bg_solver_new, before its counters start), so the child then factors
 * the same scalar Laplacian on its own through bg_sparse; the Newton child
 * likewise factors the PSD-projected Hessian at the start once more on its
 * own to get CHOLMOD's flop count. Both happen after the solver is gone and
 * after the peak memory of the solve has been read.
 *
 * Then, per part, the exponent b of t ≈ a·tets^b fitted by least squares
 * on log-log; a table on stdout, a CSV, and log-log SVG plots of time and
 * peak memory against tets.
 *
 * --max-tets N leaves out the sizes above N tets (a quicker partial run).
 *
 * --smoke: four small bars (768 to 12,000 tets), the fastest of three runs
 * each, a few seconds. Any run fails (exit 1) when a time is not positive,
 * a solve stops before its cap, a fitted exponent is not finite, the
 * exponent of CHOLMOD's flop count or factor size is not that of a 3D
 * nested-dissection factorization, or the named parts do not add up to the
 * measured time per iteration.
 */
#define _GNU_SOURCE /* wait4 */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/time.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bench_common.h"
#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_sparse.h"
#include "bg_static.h"
#include "bg_svg.h"

/* No run reaches it within its cap: every solve does exactly the cap. */
#define UNREACHABLE_TOLERANCE 1e-300
#define NEWTON_CAP_FULL 2
#define NEWTON_CAP_SMOKE 3
#define LOCAL_GLOBAL_CAP_FULL 20
#define LOCAL_GLOBAL_CAP_SMOKE 20
#define TWIST_DEGREES 90.0
/* The smoke run keeps the fastest of a few runs per size: its times are
 * milliseconds, where one preemption on a shared machine would dominate a
 * single run and bend the fitted exponents. */
#define SMOKE_REPEATS 3
/* The named parts must account for the measured time per iteration: the
 * rest is the loop's O(dofs) vector work (gathers, trial points, norms),
 * 0.1 % of a Newton iteration and 2-4 % of a local/global one on an idle
 * machine; an evaluation or factorization left out of the counters would
 * leave far more, and a negative rest beyond the clock's noise would mean
 * a part is counted twice. Both are systematic, present in every run,
 * while scheduler waits on a loaded machine only add to the rest, so the
 * check takes the smallest share over the repeated runs. */
#define MAX_UNATTRIBUTED_SHARE 0.15
#define MIN_UNATTRIBUTED_SHARE -0.02
/* CHOLMOD's flop count and factor size grow as n² and n^(4/3) for a 3D
 * mesh under a nested-dissection ordering (n^(7/3) and n^(5/3) under a
 * banded one). They are deterministic, unlike the times, whose exponents
 * on a shared machine are only required to be finite. */
#define FLOPS_EXPONENT_MIN 1.6
#define FLOPS_EXPONENT_MAX 2.2
#define NONZEROS_EXPONENT_MIN 1.1
#define NONZEROS_EXPONENT_MAX 1.5
/* First diagonal shift, relative to the largest entry, when the stand-alone
 * factorization finds the matrix not numerically positive definite. */
#define RETRY_SHIFT 1e-8
#define MAX_SIZES 8
#define SCENE_JSON_MAX 1024
#define MESSAGE_MAX BG_ERROR_MESSAGE_MAX

typedef struct size_case {
    int32_t cells[3];
} size_case_t;

static const size_case_t FULL_SIZES[] = {
    {{80, 5, 5}},    {{112, 7, 7}},   {{144, 9, 9}},
    {{192, 12, 12}}, {{256, 16, 16}}, {{354, 22, 22}}, /* armadillo-sized */
};
static const size_case_t SMOKE_SIZES[] = {
    {{32, 2, 2}},
    {{48, 3, 3}},
    {{64, 4, 4}},
    {{80, 5, 5}},
};

/* What one child measures (seconds, megabytes); sent to the parent through
 * a pipe as raw bytes (same program on both ends). */
typedef struct measurement {
    int ok;
    char message[MESSAGE_MAX];
    int32_t tets, vertices, unknowns;
    int iterations;
    int64_t factorizations;
    double evaluations;       /* energy + gradient evaluations, the first included */
    double relative_gradient; /* at the cap */
    double parse;             /* generate the box, select the handles */
    double prepare;           /* the interpolated start (a scalar Laplacian solve) */
    double solver_new;        /* model, pattern, analysis (local/global: + factor of c·L) */
    double first_eval;        /* minimize start to its first trace point */
    double analysis;          /* Newton: CHOLMOD analysis, a set-up step */
    double per_iteration;     /* (loop time − analysis) / iterations */
    double rotfit, assembly, factor, solve, other; /* per iteration */
    double alone_analysis, alone_factor;           /* the stand-alone factorization */
    double alone_flops, alone_factor_nonzeros;
    double scene_mb;        /* VmRSS after the scene is ready */
    double peak_mb;         /* VmHWM after the solve (scene included) */
    double child_maxrss_mb; /* the parent's wait4 view of the whole child */
} measurement_t;

/* Both methods' records of one size. */
typedef struct row {
    measurement_t by_method[2]; /* newton, local-global */
} row_t;

/* One plotted and fitted quantity: a double field of measurement_t. */
typedef struct part {
    const char *key; /* CSV column and figure name */
    const char *short_label;
    int method; /* 0 newton, 1 local-global */
    size_t offset;
} part_t;

static const part_t PARTS[] = {
    {"per_iteration", "Newton/iter", 0, offsetof(measurement_t, per_iteration)},
    {"factor", "N factor/iter", 0, offsetof(measurement_t, factor)},
    {"analysis", "N analysis", 0, offsetof(measurement_t, analysis)},
    {"assembly", "N assembly/iter", 0, offsetof(measurement_t, assembly)},
    {"rotfit", "N rotfit/iter", 0, offsetof(measurement_t, rotfit)},
    {"solve", "N solve/iter", 0, offsetof(measurement_t, solve)},
    {"per_iteration", "LG/iter", 1, offsetof(measurement_t, per_iteration)},
    {"rotfit", "LG rotfit/iter", 1, offsetof(measurement_t, rotfit)},
    {"solve", "LG solve/iter", 1, offsetof(measurement_t, solve)},
    {"alone_factor", "LG factor (once)", 1, offsetof(measurement_t, alone_factor)},
};
#define PART_COUNT ((int)(sizeof PARTS / sizeof PARTS[0]))

static const bg_method METHODS[2] = {BG_METHOD_NEWTON, BG_METHOD_LOCAL_GLOBAL};

static double field(const measurement_t *m, size_t offset)
{
    double v;
    memcpy(&v, (const char *)m + offset, sizeof v);
    return v;
}

/* A line of /proc/self/status ("VmHWM", "VmRSS") in megabytes; NAN if absent. */
static double status_megabytes(const char *key)
{
    FILE *f = fopen("/proc/self/status", "r");
    if (!f)
        return NAN;
    const size_t len = strlen(key);
    char line[256];
    double kb = NAN;
    while (fgets(line, sizeof line, f))
        if (strncmp(line, key, len) == 0 && line[len] == ':') {
            kb = strtod(line + len + 1, NULL);
            break;
        }
    fclose(f);
    return kb / 1024.0;
}

static void print_load(const char *when)
{
    double load[3] = {NAN, NAN, NAN};
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf %lf %lf", &load[0], &load[1], &load[2]) != 3)
            load[0] = load[1] = load[2] = NAN;
        fclose(f);
    }
    printf("load average %s: %.2f %.2f %.2f (1, 5, 15 min)\n", when, load[0], load[1], load[2]);
}

static int64_t tets_of(const size_case_t *c)
{
    return 6 * (int64_t)c->cells[0] * c->cells[1] * c->cells[2];
}

/* The scene as JSON: cubic cells of edge 1/cells[1]. */
static void scene_json(const size_case_t *c, char *out, size_t cap)
{
    const double h = 1.0 / c->cells[1];
    const double size[3] = {h * c->cells[0], h * c->cells[1], h * c->cells[2]};
    snprintf(out, cap,
             "{\"name\": \"scale-box\","
             " \"mesh\": {\"generate\": \"box\", \"cells\": [%d, %d, %d],"
             " \"size\": [%.17g, %.17g, %.17g]},"
             " \"material\": {\"mu\": 1, \"lambda\": 1},"
             " \"handles\": ["
             "  {\"name\": \"fixed\", \"select\": {\"box_fraction\": {\"min\": [0, 0, 0],"
             " \"max\": [0, 1, 1]}}},"
             "  {\"name\": \"twist\", \"select\": {\"box_fraction\": {\"min\": [1, 0, 0],"
             " \"max\": [1, 1, 1]}},"
             "   \"transform\": {\"rotate\": {\"axis\": [1, 0, 0], \"degrees\": %.17g,"
             " \"center\": [%.17g, %.17g, %.17g]}}}]}",
             (int)c->cells[0], (int)c->cells[1], (int)c->cells[2], size[0], size[1], size[2],
             TWIST_DEGREES, size[0], 0.5 * size[1], 0.5 * size[2]);
}

/* Splits a capped solve's loop time per iteration with the solver's
 * counters. rotfit_seconds covers every evaluation, the one before the
 * loop and those after the last iteration included; the first is taken out
 * at its own cost, the time to the
 * first trace point (it fits every rotation cold, by polar iteration, and
 * costs several warm evaluations: a mean would overstate the loop's). */
static void split_solve(const bg_solve_result_t *r, int32_t tets, measurement_t *m)
{
    m->iterations = r->iterations;
    m->factorizations = r->factorizations;
    m->relative_gradient = r->relative_gradient;
    if (r->trace_count < 1 || r->iterations < 1)
        return;
    const double its = r->iterations;
    m->first_eval = r->trace[0].seconds;
    /* Everything after the first trace point, the work that follows the
     * last one included (the stop's classification re-evaluates the
     * gradient and its round-off): the counters below cover it too. */
    const double loop = r->wall_seconds - r->trace[0].seconds;
    m->evaluations = (double)r->rotfit.calls / tets;
    /* Newton's symbolic analysis is a set-up step (before the loop); an
     * analysis inside the loop would be a second one */
    m->analysis = r->analyze_seconds;
    for (int i = 0; i < r->setup.count; i++)
        if (strcmp(r->setup.step[i].name, BG_SETUP_NEWTON_ANALYSIS) == 0)
            m->analysis += r->setup.step[i].seconds;
    m->per_iteration = (loop - r->analyze_seconds) / its;
    m->rotfit = fmax(r->rotfit_seconds - m->first_eval, 0.0) / its;
    m->assembly = r->assembly_seconds / its;
    m->factor = r->factor_seconds / its;
    m->solve = r->solve_seconds / its;
    m->other = m->per_iteration - m->rotfit - m->assembly - m->factor - m->solve;
}

/*
 * Factors, on its own, the matrix the method factors: for Newton the
 * PSD-projected Hessian at the start positions over the free coordinates,
 * for local/global (2μ + λ)·L over the free vertices (every handle here
 * holds whole vertices, so the three coordinates share one matrix).
 * Records analysis and factorization time, flops and factor nonzeros.
 */
static bg_status factor_alone(const bg_scene_t *scene, bg_method method, measurement_t *m,
                              bg_error_t *err)
{
    const bg_mesh_t *mesh = scene->mesh;
    const int n = method == BG_METHOD_NEWTON ? mesh->dim : 1;
    const size_t count = (size_t)mesh->nv * (size_t)n;
    bg_elastic_t *model = NULL;
    bg_sparse_t *sys = NULL;
    double *grad = NULL;
    int32_t *free_index = malloc(count * sizeof *free_index + 1);
    bg_status st = BG_OK;
    if (!free_index) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the stand-alone factorization");
        goto out;
    }
    int32_t nfree = 0;
    for (size_t i = 0; i < count; i++)
        free_index[i] = scene->constrained[n == 1 ? i * (size_t)mesh->dim : i] ? -1 : nfree++;
    st = bg_elastic_new(mesh, scene->material.mu, scene->material.lambda, &model, err);
    if (st != BG_OK)
        goto out;
    st = bg_sparse_new(mesh, n, free_index, nfree, &sys, err);
    if (st != BG_OK)
        goto out;
    bg_sparse_zero(sys);
    if (method == BG_METHOD_NEWTON) {
        grad = malloc((size_t)mesh->nv * (size_t)mesh->dim * sizeof *grad + 1);
        if (!grad) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the stand-alone gradient");
            goto out;
        }
        bg_elastic_eval(model, scene->initial, grad);
        bg_elastic_assemble_hessian(model, scene->initial, 1, 1.0, bg_sparse_scatter(sys),
                                    bg_sparse_values(sys));
    } else {
        bg_elastic_assemble_scalar_laplacian(model,
                                             2.0 * scene->material.mu + scene->material.lambda,
                                             bg_sparse_scatter(sys), bg_sparse_values(sys));
    }
    bg_error_t local = BG_ERROR_INIT;
    st = bg_sparse_factorize(sys, 0.0, &local);
    if (st == BG_ERR_NUMERIC) {
        const double *values = bg_sparse_values(sys);
        double largest = 0.0;
        for (size_t i = 0; i < bg_sparse_nonzeros(sys); i++)
            largest = fmax(largest, fabs(values[i]));
        bg_error_clear(&local);
        st = bg_sparse_factorize(sys, RETRY_SHIFT * largest, &local);
    }
    if (st != BG_OK) {
        st = bg_error_set(err, st, "stand-alone factorization: %s", local.message);
        goto out;
    }
    const bg_sparse_timing_t tm = bg_sparse_timing(sys);
    m->alone_analysis = tm.analyze_seconds;
    m->alone_factor = tm.factor_seconds / (double)tm.factorizations;
    m->alone_flops = bg_sparse_factor_flops(sys);
    m->alone_factor_nonzeros = bg_sparse_factor_nonzeros(sys);
out:
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&model);
    free(grad);
    free(free_index);
    return st;
}

/* Everything one child measures for one size and method. */
static void measure(const size_case_t *c, bg_method method, int cap, measurement_t *m)
{
    memset(m, 0, sizeof *m);
    char json[SCENE_JSON_MAX];
    scene_json(c, json, sizeof json);
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *scene = NULL;
    bg_solver_t *solver = NULL;
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    double t0 = bg_clock_now();
    if (bg_scene_parse_with(json, strlen(json), "scale-box", NULL, &scene, &err) != BG_OK)
        goto out;
    m->parse = bg_clock_now() - t0;
    t0 = bg_clock_now();
    if (bg_prepare_scene(scene, &err) != BG_OK)
        goto out;
    m->prepare = bg_clock_now() - t0;
    m->scene_mb = status_megabytes("VmRSS");
    m->tets = scene->mesh->ne;
    m->vertices = scene->mesh->nv;
    for (size_t i = 0; i < (size_t)scene->mesh->nv * (size_t)scene->mesh->dim; i++)
        m->unknowns += !scene->constrained[i];
    t0 = bg_clock_now();
    if (bg_solver_new(scene, method, &solver, &err) != BG_OK)
        goto out;
    m->solver_new = bg_clock_now() - t0;
    bg_solve_options_t opts;
    memset(&opts, 0, sizeof opts);
    opts.method = method;
    opts.tolerance = UNREACHABLE_TOLERANCE;
    opts.max_iterations = cap;
    /* plain Newton: the cost of one iteration (a factorization), not of
     * chord steps that would also end the capped run early */
    opts.chord_steps = -1;
    if (bg_solver_minimize(solver, &opts, &r, &err) != BG_OK)
        goto out;
    bg_solver_report(solver, &r); /* the set-up steps: Newton's analysis among them */
    split_solve(&r, m->tets, m);
    bg_solver_destroy(&solver);
    bg_solve_result_release(&r);
    m->peak_mb = status_megabytes("VmHWM");
    if (factor_alone(scene, method, m, &err) != BG_OK)
        goto out;
    m->ok = 1;
out:
    if (!m->ok)
        snprintf(m->message, sizeof m->message, "%s", err.message);
    bg_solve_result_release(&r);
    bg_solver_destroy(&solver);
    bg_scene_destroy(&scene);
}

/* Moves size bytes through fd, reading into data when `in`, else writing
 * from it, through short transfers and EINTR; −1 on error or end of file. */
static int transfer(int fd, void *data, size_t size, int in)
{
    char *p = data;
    while (size > 0) {
        const ssize_t k = in ? read(fd, p, size) : write(fd, p, size);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            return -1;
        p += k;
        size -= (size_t)k;
    }
    return 0;
}

/* Runs measure() in a child and collects its record and maximum RSS; a
 * child that dies or fails leaves m->ok = 0 with the reason. */
static void measure_in_child(const size_case_t *c, bg_method method, int cap, measurement_t *m)
{
    memset(m, 0, sizeof *m);
    int fds[2];
    if (pipe(fds) != 0) {
        snprintf(m->message, sizeof m->message, "pipe: %s", strerror(errno));
        return;
    }
    fflush(stdout);
    fflush(stderr);
    const pid_t pid = fork();
    if (pid < 0) {
        snprintf(m->message, sizeof m->message, "fork: %s", strerror(errno));
        close(fds[0]);
        close(fds[1]);
        return;
    }
    if (pid == 0) {
        close(fds[0]);
        measurement_t mine;
        measure(c, method, cap, &mine);
        const int sent = transfer(fds[1], &mine, sizeof mine, 0);
        close(fds[1]);
        _exit(sent == 0 && mine.ok ? 0 : 1);
    }
    close(fds[1]);
    const int got = transfer(fds[0], m, sizeof *m, 1);
    close(fds[0]);
    int status = 0;
    struct rusage usage;
    memset(&usage, 0, sizeof usage);
    pid_t waited;
    do
        waited = wait4(pid, &status, 0, &usage);
    while (waited < 0 && errno == EINTR);
    if (got != 0) {
        memset(m, 0, sizeof *m);
        snprintf(m->message, sizeof m->message, "the child sent no record (%s %d)",
                 WIFSIGNALED(status) ? "signal" : "exit status",
                 WIFSIGNALED(status) ? WTERMSIG(status) : WEXITSTATUS(status));
        return;
    }
    m->child_maxrss_mb = usage.ru_maxrss / 1024.0; /* Linux: kilobytes */
}

/* Least-squares slope of log t against log x over the points where both
 * are positive and finite; NAN with fewer than two such points. */
static double fit_exponent(const double *x, const double *t, int count, double *prefactor)
{
    double sx = 0.0, sy = 0.0, sxx = 0.0, sxy = 0.0;
    int k = 0;
    for (int i = 0; i < count; i++) {
        if (!(x[i] > 0.0 && t[i] > 0.0 && isfinite(x[i]) && isfinite(t[i])))
            continue;
        const double lx = log(x[i]), ly = log(t[i]);
        sx += lx;
        sy += ly;
        sxx += lx * lx;
        sxy += lx * ly;
        k++;
    }
    *prefactor = NAN;
    const double denominator = k * sxx - sx * sx;
    if (k < 2 || !(denominator > 0.0))
        return NAN;
    const double b = (k * sxy - sx * sy) / denominator;
    *prefactor = exp((sy - b * sx) / k);
    return b;
}

static void print_tables(const size_case_t *sizes, int count, const row_t *rows)
{
    printf("Newton, per iteration (ms) after the once-per-solve CHOLMOD analysis; alone_fac = "
           "the start's projected Hessian\nfactored stand-alone (GF/s from CHOLMOD's flop "
           "count); peak = VmHWM of the child after the solve (scene included),\nscene = VmRSS "
           "before the solver\n");
    printf("%9s %8s %4s %5s %5s %9s %10s %9s %9s %9s %9s %8s %8s %9s %6s %8s %8s %8s\n", "tets",
           "unknowns", "its", "fact", "evals", "analysis", "per_iter", "factor", "assembly",
           "rotfit", "solve", "other", "rel_grad", "alone_fac", "GF/s", "setup_s", "scene_MB",
           "peak_MB");
    for (int i = 0; i < count; i++) {
        const measurement_t *n = &rows[i].by_method[0];
        if (!n->ok) {
            printf("%9lld FAILED: %s\n", (long long)tets_of(&sizes[i]), n->message);
            continue;
        }
        printf("%9d %8d %4d %5lld %5.1f %9.1f %10.1f %9.1f %9.1f %9.1f %9.1f %8.1f %8.1e %9.1f "
               "%6.2f %8.2f %8.0f %8.0f\n",
               (int)n->tets, (int)n->unknowns, n->iterations, (long long)n->factorizations,
               n->evaluations, 1e3 * n->analysis, 1e3 * n->per_iteration, 1e3 * n->factor,
               1e3 * n->assembly, 1e3 * n->rotfit, 1e3 * n->solve, 1e3 * n->other,
               n->relative_gradient, 1e3 * n->alone_factor, 1e-9 * n->alone_flops / n->alone_factor,
               n->parse + n->prepare + n->solver_new, n->scene_mb, n->peak_mb);
    }
    printf("\nlocal/global, per iteration (ms); factor/analysis = the scalar c*L, once, "
           "factored stand-alone (the solver does it inside bg_solver_new)\n");
    printf("%9s %8s %4s %5s %9s %9s %10s %9s %9s %8s %8s %8s %8s %8s\n", "tets", "vertices", "its",
           "evals", "analysis", "factor", "per_iter", "rotfit", "solve", "other", "rel_grad",
           "setup_s", "scene_MB", "peak_MB");
    for (int i = 0; i < count; i++) {
        const measurement_t *l = &rows[i].by_method[1];
        if (!l->ok) {
            printf("%9lld FAILED: %s\n", (long long)tets_of(&sizes[i]), l->message);
            continue;
        }
        printf("%9d %8d %4d %5.1f %9.1f %9.1f %10.2f %9.2f %9.2f %8.2f %8.1e %8.2f %8.0f "
               "%8.0f\n",
               (int)l->tets, (int)l->vertices, l->iterations, l->evaluations,
               1e3 * l->alone_analysis, 1e3 * l->alone_factor, 1e3 * l->per_iteration,
               1e3 * l->rotfit, 1e3 * l->solve, 1e3 * l->other, l->relative_gradient,
               l->parse + l->prepare + l->solver_new, l->scene_mb, l->peak_mb);
    }
}

static bg_status write_csv(const char *path, int count, const row_t *rows, bg_error_t *err)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot open for writing: %s", path,
                            strerror(errno));
    fprintf(f, "method,tets,vertices,unknowns,iterations,factorizations,evaluations,"
               "relative_gradient,parse_s,prepare_s,solver_new_s,first_eval_s,analysis_s,"
               "per_iteration_s,rotfit_s,assembly_s,factor_s,solve_s,other_s,"
               "alone_analysis_s,alone_factor_s,alone_flops,alone_factor_nonzeros,scene_mb,"
               "peak_mb,child_maxrss_mb\n");
    for (int i = 0; i < count; i++)
        for (int k = 0; k < 2; k++) {
            const measurement_t *x = &rows[i].by_method[k];
            if (!x->ok)
                continue;
            fprintf(f,
                    "%s,%d,%d,%d,%d,%lld,%.3f,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,"
                    "%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.1f,%.1f,%.1f\n",
                    bg_method_name(METHODS[k]), (int)x->tets, (int)x->vertices, (int)x->unknowns,
                    x->iterations, (long long)x->factorizations, x->evaluations,
                    x->relative_gradient, x->parse, x->prepare, x->solver_new, x->first_eval,
                    x->analysis, x->per_iteration, x->rotfit, x->assembly, x->factor, x->solve,
                    x->other, x->alone_analysis, x->alone_factor, x->alone_flops,
                    x->alone_factor_nonzeros, x->scene_mb, x->peak_mb, x->child_maxrss_mb);
        }
    if (fclose(f) != 0)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", path, strerror(errno));
    return BG_OK;
}

static void usage(void)
{
    fprintf(stderr, "usage: OPENBLAS_NUM_THREADS=1 bench_scale [--smoke] [--csv PATH] "
                    "[--svg PATH] [--memory-svg PATH] [--max-tets N]\n");
}

int main(int argc, char **argv)
{
    int smoke = 0;
    const char *csv_path = "bench_scale.csv";
    const char *svg_path = "bench_scale.svg";
    const char *memory_svg_path = "bench_scale-memory.svg";
    long long max_tets = LLONG_MAX;
    for (int i = 1; i < argc; i++) {
        const int has_value = i + 1 < argc;
        if (strcmp(argv[i], "--smoke") == 0) {
            smoke = 1;
        } else if (strcmp(argv[i], "--csv") == 0 && has_value) {
            csv_path = argv[++i];
        } else if (strcmp(argv[i], "--svg") == 0 && has_value) {
            svg_path = argv[++i];
        } else if (strcmp(argv[i], "--memory-svg") == 0 && has_value) {
            memory_svg_path = argv[++i];
        } else if (strcmp(argv[i], "--max-tets") == 0 && has_value) {
            char *end = NULL;
            errno = 0;
            max_tets = strtoll(argv[++i], &end, 10);
            if (errno != 0 || end == argv[i] || *end != '\0' || max_tets <= 0) {
                fprintf(stderr,
                        "bench_scale: --max-tets: expected a positive integer, got "
                        "'%s'\n",
                        argv[i]);
                return 2;
            }
        } else {
            usage();
            return 2;
        }
    }
    const size_case_t *sizes = smoke ? SMOKE_SIZES : FULL_SIZES;
    int count = smoke ? (int)(sizeof SMOKE_SIZES / sizeof SMOKE_SIZES[0])
                      : (int)(sizeof FULL_SIZES / sizeof FULL_SIZES[0]);
    while (count > 0 && tets_of(&sizes[count - 1]) > max_tets)
        count--;
    if (count < 2) {
        fprintf(stderr, "bench_scale: --max-tets %lld leaves fewer than two sizes to fit\n",
                max_tets);
        return 2;
    }
    bench_header("bench_scale: how the cost of a static solve grows with the mesh size", smoke);
    const int caps[2] = {smoke ? NEWTON_CAP_SMOKE : NEWTON_CAP_FULL,
                         smoke ? LOCAL_GLOBAL_CAP_SMOKE : LOCAL_GLOBAL_CAP_FULL};
    printf("scene: 16:1:1 bar of cubic cells (6 tets each), mu = lambda = 1, x = 0 clamped, far "
           "face turned %.0f degrees, interpolated start;\niterations capped at %d (newton) and "
           "%d (local-global); each size and method in its own child process\n",
           TWIST_DEGREES, caps[0], caps[1]);
    print_load("before");
    printf("\n");

    static row_t rows[MAX_SIZES];
    double wall0 = bg_clock_now();
    const int repeats = smoke ? SMOKE_REPEATS : 1;
    static double least_share[MAX_SIZES][2]; /* smallest unattributed share over the runs */
    for (int i = 0; i < count; i++)
        for (int k = 0; k < 2; k++) {
            const double t0 = bg_clock_now();
            measurement_t *best = &rows[i].by_method[k];
            least_share[i][k] = INFINITY;
            for (int rep = 0; rep < repeats; rep++) {
                measurement_t trial;
                measure_in_child(&sizes[i], METHODS[k], caps[k], &trial);
                if (rep == 0 || !best->ok ||
                    (trial.ok && trial.per_iteration < best->per_iteration))
                    *best = trial;
                if (trial.ok)
                    least_share[i][k] = fmin(least_share[i][k], trial.other / trial.per_iteration);
            }
            fprintf(stderr, "bench_scale: %lld tets, %s: %.1f s%s%s\n",
                    (long long)tets_of(&sizes[i]), bg_method_name(METHODS[k]), bg_clock_now() - t0,
                    best->ok ? "" : ": FAILED: ", best->message);
        }
    const double wall = bg_clock_now() - wall0;
    print_tables(sizes, count, rows);

    /* Fits and checks. */
    double x[MAX_SIZES], y[MAX_SIZES];
    double exponents[PART_COUNT], prefactors[PART_COUNT];
    printf("\nfitted t = a * tets^b (least squares on log-log over %d sizes, %lld to %lld tets);"
           "\nlast column: the part at the largest size over that size's time per iteration"
           "\n%-18s %-14s %8s %12s %14s %10s\n",
           count, (long long)tets_of(&sizes[0]), (long long)tets_of(&sizes[count - 1]), "part",
           "method", "b", "a (s)", "largest (ms)", "/ per_iter");
    for (int p = 0; p < PART_COUNT; p++) {
        int k = 0;
        for (int i = 0; i < count; i++) {
            const measurement_t *mm = &rows[i].by_method[PARTS[p].method];
            if (!mm->ok)
                continue;
            x[k] = mm->tets;
            y[k] = field(mm, PARTS[p].offset);
            k++;
        }
        exponents[p] = fit_exponent(x, y, k, &prefactors[p]);
        const measurement_t *top = &rows[count - 1].by_method[PARTS[p].method];
        const double largest = top->ok ? field(top, PARTS[p].offset) : NAN;
        printf("%-18s %-14s %8.3f %12.3g %14.2f %10.3f\n", PARTS[p].short_label,
               bg_method_name(METHODS[PARTS[p].method]), exponents[p], prefactors[p], 1e3 * largest,
               largest / top->per_iteration);
        char name[BENCH_NAME_MAX];
        snprintf(name, sizeof name, "scale.%s.%s.exponent",
                 bg_method_name(METHODS[PARTS[p].method]), PARTS[p].key);
        bench_record(name, exponents[p], "");
        if (!isfinite(exponents[p])) {
            char what[200];
            snprintf(what, sizeof what, "%s exponent is not finite", PARTS[p].short_label);
            bench_fail(what);
        }
    }
    /* Fitted too, not plotted (other units): the cost model behind the times. */
    static const struct {
        part_t part;
        double min, max; /* the exponent's allowed range */
    } COUNTS[] = {
        {{"peak_mb", "peak memory", 0, offsetof(measurement_t, peak_mb)}, -INFINITY, INFINITY},
        {{"peak_mb", "peak memory", 1, offsetof(measurement_t, peak_mb)}, -INFINITY, INFINITY},
        {{"alone_flops", "factor flops", 0, offsetof(measurement_t, alone_flops)},
         FLOPS_EXPONENT_MIN,
         FLOPS_EXPONENT_MAX},
        {{"alone_flops", "factor flops", 1, offsetof(measurement_t, alone_flops)},
         FLOPS_EXPONENT_MIN,
         FLOPS_EXPONENT_MAX},
        {{"alone_factor_nonzeros", "factor nonzeros", 0,
          offsetof(measurement_t, alone_factor_nonzeros)},
         NONZEROS_EXPONENT_MIN,
         NONZEROS_EXPONENT_MAX},
        {{"alone_factor_nonzeros", "factor nonzeros", 1,
          offsetof(measurement_t, alone_factor_nonzeros)},
         NONZEROS_EXPONENT_MIN,
         NONZEROS_EXPONENT_MAX},
    };
    for (size_t c = 0; c < sizeof COUNTS / sizeof COUNTS[0]; c++) {
        const part_t *q = &COUNTS[c].part;
        int k = 0;
        for (int i = 0; i < count; i++) {
            const measurement_t *mm = &rows[i].by_method[q->method];
            if (mm->ok) {
                x[k] = mm->tets;
                y[k] = field(mm, q->offset);
                k++;
            }
        }
        double prefactor;
        const double b = fit_exponent(x, y, k, &prefactor);
        const measurement_t *top = &rows[count - 1].by_method[q->method];
        printf("%-18s %-14s %8.3f %12.3g %14.4g\n", q->short_label,
               bg_method_name(METHODS[q->method]), b, prefactor,
               top->ok ? field(top, q->offset) : NAN);
        char name[BENCH_NAME_MAX];
        snprintf(name, sizeof name, "scale.%s.%s.exponent", bg_method_name(METHODS[q->method]),
                 q->key);
        bench_record(name, b, "");
        if (!(isfinite(b) && b >= COUNTS[c].min && b <= COUNTS[c].max)) {
            char what[200];
            snprintf(what, sizeof what, "%s %s exponent %g is not finite or outside [%g, %g]",
                     bg_method_name(METHODS[q->method]), q->short_label, b, COUNTS[c].min,
                     COUNTS[c].max);
            bench_fail(what);
        }
    }

    for (int i = 0; i < count; i++)
        for (int k = 0; k < 2; k++) {
            const measurement_t *mm = &rows[i].by_method[k];
            char what[200];
            if (!mm->ok) {
                char failure[MESSAGE_MAX + 64];
                snprintf(failure, sizeof failure, "%lld tets %s: %s", (long long)tets_of(&sizes[i]),
                         bg_method_name(METHODS[k]), mm->message);
                bench_fail(failure);
                continue;
            }
            snprintf(what, sizeof what, "%d tets %s time per iteration", (int)mm->tets,
                     bg_method_name(METHODS[k]));
            bench_check_positive(what, mm->per_iteration);
            snprintf(what, sizeof what, "%d tets %s peak memory", (int)mm->tets,
                     bg_method_name(METHODS[k]));
            bench_check_positive(what, mm->peak_mb);
            if (mm->iterations != caps[k]) {
                snprintf(what, sizeof what, "%d tets %s did %d iterations, not the cap %d (%s)",
                         (int)mm->tets, bg_method_name(METHODS[k]), mm->iterations, caps[k],
                         mm->relative_gradient < 1.0 ? "stopped early" : "no progress");
                bench_fail(what);
            }
            const double share = least_share[i][k];
            if (!(share <= MAX_UNATTRIBUTED_SHARE && share >= MIN_UNATTRIBUTED_SHARE)) {
                snprintf(what, sizeof what,
                         "%d tets %s: the parts leave %.1f%% of the time per iteration "
                         "unattributed in the best run (allowed %.0f%% to %.0f%%)",
                         (int)mm->tets, bg_method_name(METHODS[k]), 100.0 * share,
                         100.0 * MIN_UNATTRIBUTED_SHARE, 100.0 * MAX_UNATTRIBUTED_SHARE);
                bench_fail(what);
            }
        }

    /* Outputs. */
    bg_error_t err = BG_ERROR_INIT;
    if (write_csv(csv_path, count, rows, &err) != BG_OK) {
        fprintf(stderr, "bench_scale: %s\n", err.message);
        bench_fail("the CSV could not be written");
    }
    static double px[PART_COUNT][MAX_SIZES], py[PART_COUNT][MAX_SIZES];
    static char labels[PART_COUNT][BENCH_NAME_MAX];
    bg_svg_series_t series[PART_COUNT];
    for (int p = 0; p < PART_COUNT; p++) {
        size_t k = 0;
        for (int i = 0; i < count; i++) {
            const measurement_t *mm = &rows[i].by_method[PARTS[p].method];
            if (!mm->ok)
                continue;
            px[p][k] = mm->tets;
            py[p][k] = field(mm, PARTS[p].offset);
            k++;
        }
        snprintf(labels[p], sizeof labels[p], "%s ^%.2f", PARTS[p].short_label, exponents[p]);
        series[p] = (bg_svg_series_t){labels[p], px[p], py[p], k};
    }
    const bg_svg_plot_t plot = {"Static solve of a twisted bar: seconds per part against size",
                                "tetrahedra", "seconds (per iteration; analysis, LG factor: once)",
                                1, 1};
    if (bg_svg_write(svg_path, &plot, series, PART_COUNT, &err) != BG_OK) {
        fprintf(stderr, "bench_scale: %s\n", err.message);
        bench_fail("the SVG could not be written");
    }
    static double mx[2][MAX_SIZES], my[2][MAX_SIZES];
    bg_svg_series_t memory[2];
    for (int k = 0; k < 2; k++) {
        size_t j = 0;
        for (int i = 0; i < count; i++)
            if (rows[i].by_method[k].ok) {
                mx[k][j] = rows[i].by_method[k].tets;
                my[k][j] = rows[i].by_method[k].peak_mb;
                j++;
            }
        memory[k] =
            (bg_svg_series_t){k == 0 ? "Newton peak" : "local/global peak", mx[k], my[k], j};
    }
    const bg_svg_plot_t memory_plot = {"Peak memory of the solve (scene included)", "tetrahedra",
                                       "MB (VmHWM)", 1, 1};
    bg_error_clear(&err);
    if (bg_svg_write(memory_svg_path, &memory_plot, memory, 2, &err) != BG_OK) {
        fprintf(stderr, "bench_scale: %s\n", err.message);
        bench_fail("the memory SVG could not be written");
    }
    printf("\nwrote %s, %s, %s; all children took %.1f s\n", csv_path, svg_path, memory_svg_path,
           wall);
    print_load("after");
    bench_print_figures();
    if (bench_failures > 0) {
        printf("\n%d sanity check(s) failed\n", bench_failures);
        return 1;
    }
    return 0;
}
