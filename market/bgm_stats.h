/*
 * bgm_stats — summary statistics over replications: mean and a 95 %
 * Student-t confidence interval, skipping null (NaN) values.
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

#endif
