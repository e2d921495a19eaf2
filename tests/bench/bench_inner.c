/*
 * bench_inner — the time step's inner solve, Newton against quasi-newton
 * (solver.inner), on the shipped dynamic scenes, in one process:
 *
 *   OPENBLAS_NUM_THREADS=1 OMP_THREAD_LIMIT=1 ./tests/bench/bench_inner [--rounds N]
 *       [--only TEXT]   (the cases whose label contains TEXT)
 *   ./tests/bench/bench_inner --smoke        (the suite: short scenes, one round)
 *
 * Each case runs both inner solves on the same loaded scene, alternated
 * (newton first in even rounds, quasi-newton first in odd ones), each timed
 * by this thread's CPU clock (CLOCK_THREAD_CPUTIME_ID: the solver runs on
 * this thread alone with one BLAS thread) and by the wall clock, with the
 * 1-minute load average read before each run. The table gives the median
 * of the rounds and every round's value, the iterations, limited steps,
 * whether every step met its tolerance, and how far the two final states
 * are apart (largest coordinate difference over the bounding-box
 * diagonal). The beam runs twice: as shipped (the scene's cap of 200
 * iterations per step, which quasi-newton's steps hit) and, for its first
 * 50 steps, with a cap of 20,000 so that every step meets τ = 1e-8; the
 * bunny as shipped (60 steps: from step 45 or 46 on, steps stop at the cap of
 * 200 with either inner solve) and its first 44 steps, which converge.
 * Exit 1 when a figure is not finite or positive, or a smoke run's steps
 * did not converge.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench_common.h"
#include "bg_dynamics.h"
#include "bg_prepare.h"
#include "bg_scene.h"

#define MAX_ROUNDS 16

typedef struct bench_case {
    const char *label;
    const char *path; /* relative to BG_SOURCE_DIR */
    int steps;        /* 0: the scene's */
    int cap;          /* 0: the scene's solver.max_iterations */
} bench_case_t;

static const bench_case_t FULL[] = {
    {"bar-spin", "configs/scenes/bar-spin.json", 0, 0},
    {"beam-cantilever", "configs/scenes/beam-cantilever.json", 0, 0},
    {"beam-cantilever, 50 steps, cap 20000", "configs/scenes/beam-cantilever.json", 50, 20000},
    {"bunny-drop", "configs/scenes/bunny-drop.json", 0, 0},
    {"bunny-drop, 44 steps", "configs/scenes/bunny-drop.json", 44, 0},
};
static const bench_case_t SMOKE[] = {
    {"short-spin", "tests/fixtures/scenes/short-spin.json", 0, 0},
    {"stiff-drop", "tests/fixtures/scenes/stiff-drop-qn.json", 0, 0},
};

typedef struct sample {
    double cpu, wall, load;
    int iterations, limited, converged;
    double *q;
} sample_t;

static double clock_of(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double load_average(void)
{
    double l = NAN;
    FILE *f = fopen("/proc/loadavg", "r");
    if (f) {
        if (fscanf(f, "%lf", &l) != 1)
            l = NAN;
        fclose(f);
    }
    return l;
}

static int run_once(bg_scene_t *s, const bench_case_t *c, bg_method inner, sample_t *out)
{
    s->inner = inner;
    const bg_dynamic_options_t o = {.method = s->method,
                                    .steps = c->steps,
                                    .max_iterations = c->cap > 0 ? c->cap : s->max_iterations};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    out->load = load_average();
    const double w0 = clock_of(CLOCK_MONOTONIC), c0 = clock_of(CLOCK_THREAD_CPUTIME_ID);
    const bg_status st = bg_dynamic_solve(s, &o, &r, &err);
    out->cpu = clock_of(CLOCK_THREAD_CPUTIME_ID) - c0;
    out->wall = clock_of(CLOCK_MONOTONIC) - w0;
    s->inner = BG_METHOD_NEWTON;
    if (st != BG_OK) {
        fprintf(stderr, "bench_inner: %s: %s\n", c->label, err.message);
        return -1;
    }
    out->iterations = r.iterations;
    out->limited = r.limited_steps;
    out->converged = r.converged;
    free(out->q);
    out->q = r.q;
    r.q = NULL;
    bg_solve_result_release(&r);
    return 0;
}

static void print_values(const char *fmt, const double *v, int n)
{
    printf(" [");
    for (int i = 0; i < n; i++) {
        printf(fmt, v[i]);
        printf(i + 1 < n ? ", " : "");
    }
    printf("]");
}

int main(int argc, char **argv)
{
    int smoke = 0, rounds = 2;
    const char *only = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--smoke") == 0) {
            smoke = 1;
        } else if (strcmp(argv[i], "--only") == 0 && i + 1 < argc) {
            only = argv[++i];
        } else if (strcmp(argv[i], "--rounds") == 0 && i + 1 < argc) {
            rounds = atoi(argv[++i]);
            if (rounds < 1 || rounds > MAX_ROUNDS) {
                fprintf(stderr, "bench_inner: --rounds must be in 1..%d\n", MAX_ROUNDS);
                return 2;
            }
        } else {
            fprintf(stderr, "usage: bench_inner [--smoke] [--rounds N] [--only TEXT]\n");
            return 2;
        }
    }
    if (smoke)
        rounds = 1;
    setvbuf(stdout, NULL, _IOLBF, 0); /* a long run's rows as they come */
    bench_header("bench_inner: the time step's inner solve, newton against quasi-newton", smoke);
    const bench_case_t *cases = smoke ? SMOKE : FULL;
    const int ncases =
        smoke ? (int)(sizeof SMOKE / sizeof *SMOKE) : (int)(sizeof FULL / sizeof *FULL);
    static const bg_method inner[2] = {BG_METHOD_NEWTON, BG_METHOD_QUASI_NEWTON};
    printf("| scene | inner | iterations | limited steps | every step converged | thread CPU s "
           "(median [rounds]) | wall s (median [rounds]) | load (1 min) | final states apart |\n");
    printf("|---|---|---|---|---|---|---|---|---|\n");
    for (int ci = 0; ci < ncases; ci++) {
        const bench_case_t *c = &cases[ci];
        if (only && !strstr(c->label, only))
            continue;
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", BG_SOURCE_DIR, c->path);
        const bg_scene_options_t so = {.search_path = BG_MESH_DIR};
        bg_scene_t *s = NULL;
        bg_error_t err = BG_ERROR_INIT;
        if (bg_scene_load_with(path, &so, &s, &err) != BG_OK ||
            bg_prepare_scene(s, &err) != BG_OK) {
            fprintf(stderr, "bench_inner: %s\n", err.message);
            return 1;
        }
        sample_t smp[2][MAX_ROUNDS];
        memset(smp, 0, sizeof smp);
        for (int r = 0; r < rounds; r++)
            for (int k = 0; k < 2; k++) {
                const int m = r % 2 ? 1 - k : k;
                if (run_once(s, c, inner[m], &smp[m][r]) != 0)
                    return 1;
            }
        double lo[3], hi[3], diag = 0.0, apart = 0.0;
        bg_mesh_bounds(s->mesh, lo, hi);
        for (int d = 0; d < s->mesh->dim; d++)
            diag += (hi[d] - lo[d]) * (hi[d] - lo[d]);
        for (size_t i = 0; i < (size_t)s->mesh->nv * s->mesh->dim; i++)
            apart = fmax(apart, fabs(smp[0][0].q[i] - smp[1][0].q[i]));
        apart /= sqrt(diag);
        for (int m = 0; m < 2; m++) {
            double cpu[MAX_ROUNDS], wall[MAX_ROUNDS], load[MAX_ROUNDS];
            int converged = 1;
            for (int r = 0; r < rounds; r++) {
                cpu[r] = smp[m][r].cpu;
                wall[r] = smp[m][r].wall;
                load[r] = smp[m][r].load;
                converged &= smp[m][r].converged;
            }
            printf("| %s | %s | %d | %d | %s |", c->label, bg_method_name(inner[m]),
                   smp[m][0].iterations, smp[m][0].limited, converged ? "yes" : "no");
            double sorted[MAX_ROUNDS];
            memcpy(sorted, cpu, sizeof cpu);
            const double cpu_med = bench_median(sorted, rounds);
            printf(" %.3f", cpu_med);
            print_values("%.3f", cpu, rounds);
            memcpy(sorted, wall, sizeof wall);
            const double wall_med = bench_median(sorted, rounds);
            printf(" | %.3f", wall_med);
            print_values("%.3f", wall, rounds);
            printf(" |");
            print_values("%.1f", load, rounds);
            if (m)
                printf(" | %.2e of the diagonal |\n", apart);
            else
                printf(" | |\n");
            char name[BENCH_NAME_MAX];
            snprintf(name, sizeof name, "%s/%s/cpu", c->label, bg_method_name(inner[m]));
            bench_check_positive(name, cpu_med);
            bench_record(name, cpu_med, "s");
            snprintf(name, sizeof name, "%s/%s/wall", c->label, bg_method_name(inner[m]));
            bench_check_positive(name, wall_med);
            bench_record(name, wall_med, "s");
            if (smoke && !converged)
                bench_fail("a smoke run's step did not converge");
            for (int r = 0; r < rounds; r++)
                free(smp[m][r].q);
        }
        bg_scene_destroy(&s);
    }
    bench_print_figures();
    return bench_failures ? 1 : 0;
}
