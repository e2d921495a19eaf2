/*
 * bgm_stats — summary statistics over replications: mean and a 95 %
 * Student-t confidence interval, skipping null (NaN) values; quantiles by
 * the nearest-rank method.
 */
#ifndef BGM_STATS_H
#define BGM_STATS_H

#include <stddef.h>

typedef struct bgm_summary {
    size_t n;     /* non-null values */
    double mean;  /* NaN when n == 0 */
    double lo;    /* 95 % CI; NaN when n < 2 (one value gives no interval) */
    double hi;
} bgm_summary_t;

/* Two-sided 97.5 % quantile of Student's t with df degrees of freedom. */
double bgm_t975(size_t df);
bgm_summary_t bgm_summarize(const double *values, size_t count, size_t stride);

/* Sorts v[0..n) in increasing order, in place. */
void bgm_sort(double *v, size_t n);
/* The q-quantile of sorted values by the nearest-rank method (the value
 * at rank ceil(q n)); NaN when n == 0. */
double bgm_quantile_sorted(const double *sorted, size_t n, double q);
/* The same of values in any order, through a sorted copy; NaN when n == 0
 * or the copy cannot be made. */
double bgm_quantile(const double *v, size_t n, double q);

#endif
