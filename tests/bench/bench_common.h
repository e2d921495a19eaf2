/*
 * bench_common — small helpers shared by the benchmark programs: medians,
 * the machine-readable "figure" lines, and sanity checks that turn a bad
 * figure (NaN, zero, a failed expectation) into a non-zero exit status, so
 * that the CTest smoke runs catch a broken kernel rather than print garbage.
 *
 * Everything is static inline: each benchmark is one translation unit and
 * uses a different subset.
 */
#ifndef BG_BENCH_COMMON_H
#define BG_BENCH_COMMON_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Upper bound on timed repetitions per measurement (the median's buffer). */
#define BENCH_MAX_REPS 64

/* Failed sanity checks so far; main returns non-zero when it is positive. */
static int bench_failures;

static inline int bench_compare_doubles(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of n samples (sorts them in place). */
static inline double bench_median(double *v, int n)
{
    if (n <= 0)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, bench_compare_doubles);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* Records a failed check and says which, on stderr and in the output. */
static inline void bench_fail(const char *what)
{
    bench_failures++;
    printf("SANITY CHECK FAILED: %s\n", what);
    fprintf(stderr, "SANITY CHECK FAILED: %s\n", what);
}

/* A figure must be a finite, strictly positive number. */
static inline void bench_check_positive(const char *name, double value)
{
    if (!(isfinite(value) && value > 0.0)) {
        char msg[256];
        snprintf(msg, sizeof msg, "%s = %g is not a finite positive number", name, value);
        bench_fail(msg);
    }
}

/* Figures are collected while the tables print and written at the end as
 * machine-readable lines, one per figure: "figure name=value unit". */
#define BENCH_MAX_FIGURES 256
#define BENCH_NAME_MAX 128
#define BENCH_UNIT_MAX 24

typedef struct bench_figure {
    char name[BENCH_NAME_MAX];
    char unit[BENCH_UNIT_MAX];
    double value;
} bench_figure_t;

static bench_figure_t bench_figures[BENCH_MAX_FIGURES];
static int bench_figure_count;

static inline void bench_record(const char *name, double value, const char *unit)
{
    if (bench_figure_count == BENCH_MAX_FIGURES) {
        bench_fail("too many figures for the figure table");
        return;
    }
    bench_figure_t *f = &bench_figures[bench_figure_count++];
    snprintf(f->name, sizeof f->name, "%s", name);
    snprintf(f->unit, sizeof f->unit, "%s", unit);
    f->value = value;
}

static inline void bench_print_figures(void)
{
    printf("\n");
    for (int i = 0; i < bench_figure_count; i++)
        printf("figure %s=%.6g %s\n", bench_figures[i].name, bench_figures[i].value,
               bench_figures[i].unit);
}

/* Prints the run header every benchmark starts with: what it is, and the
 * environment that decides whether the "one core" figures are one core. */
static inline void bench_header(const char *program, int smoke)
{
    const char *blas = getenv("OPENBLAS_NUM_THREADS");
    printf("%s (%s run)\n", program, smoke ? "smoke" : "full");
    printf("OPENBLAS_NUM_THREADS=%s%s\n", blas ? blas : "(unset)",
           blas && strcmp(blas, "1") == 0
               ? ""
               : "  <- one-core figures need OPENBLAS_NUM_THREADS=1 in the environment");
    printf("\n");
}

#endif
