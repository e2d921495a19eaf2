/*
 * Helpers shared by the unit tests: a seeded generator and a dense
 * symmetric eigenvalue routine used as an independent check.
 */
#ifndef BG_TEST_SUPPORT_H
#define BG_TEST_SUPPORT_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* splitmix64: deterministic, seeded per test. */
static inline double test_uniform(uint64_t *state)
{
    uint64_t z = (*state += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1.0p-53;
}

/* Eigenvalues of a symmetric n×n matrix (row-major, n ≤ 16) by cyclic
 * Jacobi; sorted ascending into w. */
static inline void test_sym_eigenvalues(int n, const double *A_in, double *w)
{
    double A[256];
    memcpy(A, A_in, (size_t)n * n * sizeof *A);
    for (int sweep = 0; sweep < 100; sweep++) {
        double off = 0.0, total = 0.0;
        for (int i = 0; i < n; i++)
            for (int j = 0; j < n; j++) {
                total += A[i * n + j] * A[i * n + j];
                if (i != j)
                    off += A[i * n + j] * A[i * n + j];
            }
        if (off <= 1e-30 * total)
            break;
        for (int p = 0; p < n; p++)
            for (int q = p + 1; q < n; q++) {
                double apq = A[p * n + q];
                if (apq == 0.0)
                    continue;
                double theta = (A[q * n + q] - A[p * n + p]) / (2.0 * apq);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
                for (int k = 0; k < n; k++) {
                    double akp = A[k * n + p], akq = A[k * n + q];
                    A[k * n + p] = c * akp - s * akq;
                    A[k * n + q] = s * akp + c * akq;
                }
                for (int k = 0; k < n; k++) {
                    double apk = A[p * n + k], aqk = A[q * n + k];
                    A[p * n + k] = c * apk - s * aqk;
                    A[q * n + k] = s * apk + c * aqk;
                }
            }
    }
    for (int i = 0; i < n; i++)
        w[i] = A[i * n + i];
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++)
            if (w[j] < w[i]) {
                double t = w[i];
                w[i] = w[j];
                w[j] = t;
            }
}

/*
 * Largest relative change of an edge length between positions a and b (dim
 * coordinates per vertex) over every pair of nodes of every element (k
 * nodes each): zero exactly when b is a rigid motion of a on each element,
 * the check for "the same shape up to a rigid motion".
 */
static inline double test_max_edge_change(const int32_t *elements, int32_t ne, int k, int dim,
                                          const double *a, const double *b)
{
    double worst = 0.0;
    for (int32_t e = 0; e < ne; e++)
        for (int i = 0; i < k; i++)
            for (int j = i + 1; j < k; j++) {
                const int32_t u = elements[(size_t)e * k + i], v = elements[(size_t)e * k + j];
                double la = 0.0, lb = 0.0;
                for (int c = 0; c < dim; c++) {
                    const double da = a[(size_t)u * dim + c] - a[(size_t)v * dim + c];
                    const double db = b[(size_t)u * dim + c] - b[(size_t)v * dim + c];
                    la += da * da;
                    lb += db * db;
                }
                const double change = fabs(sqrt(lb) - sqrt(la)) / sqrt(la);
                if (change > worst)
                    worst = change;
            }
    return worst;
}

#endif
