#include "bgm_stats.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* t_{0.975, df} for df = 1..30; beyond that the normal 1.96 is within 2 %. */
static const double t975[30] = {12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306,
                                2.262,  2.228, 2.201, 2.179, 2.160, 2.145, 2.131, 2.120,
                                2.110,  2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
                                2.060,  2.056, 2.052, 2.048, 2.045, 2.042};

double bgm_t975(size_t df)
{
    if (df == 0)
        return NAN;
    return df <= 30 ? t975[df - 1] : 1.96;
}

bgm_summary_t bgm_summarize(const double *v, size_t count, size_t stride)
{
    bgm_summary_t s = {0, NAN, NAN, NAN};
    double sum = 0.0;
    for (size_t i = 0; i < count; i++) {
        double x = v[i * stride];
        if (isfinite(x)) {
            sum += x;
            s.n++;
        }
    }
    if (s.n == 0)
        return s;
    s.mean = sum / (double)s.n;
    if (s.n == 1)
        return s; /* one value: no interval (lo and hi stay NaN) */
    double ss = 0.0;
    for (size_t i = 0; i < count; i++) {
        double x = v[i * stride];
        if (isfinite(x))
            ss += (x - s.mean) * (x - s.mean);
    }
    double half = bgm_t975(s.n - 1) * sqrt(ss / (double)(s.n - 1)) / sqrt((double)s.n);
    s.lo = s.mean - half;
    s.hi = s.mean + half;
    return s;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

void bgm_sort(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
}

double bgm_quantile_sorted(const double *s, size_t n, double q)
{
    if (n == 0)
        return NAN;
    size_t k = (size_t)ceil(q * (double)n);
    return s[k == 0 ? 0 : k - 1];
}

double bgm_quantile(const double *v, size_t n, double q)
{
    if (n == 0)
        return NAN;
    double *s = malloc(n * sizeof *s);
    if (!s)
        return NAN;
    memcpy(s, v, n * sizeof *s);
    bgm_sort(s, n);
    const double r = bgm_quantile_sorted(s, n, q);
    free(s);
    return r;
}
