/*
 * bench_market — central clearing time against order-book size.
 *
 *   bench_market [--quick]
 *
 * For growing books: a call market (bids and asks of one good) and the
 * combinatorial exchange's winner determination, exact (GLPK) and greedy,
 * on random bundle books with 4 candidate sellers per bid. Prints one line
 * per size with the median of a few repetitions in milliseconds. Exits 1
 * if the greedy ever beats the exact solver (it must not).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bgm_callmarket.h"
#include "bgm_combex.h"
#include "bgm_rng.h"

#define REPS 3
#define SELLERS_PER_BID 4

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

static double median3(double a, double b, double c)
{
    if (a > b) { double t = a; a = b; b = t; }
    if (b > c) { double t = b; b = c; c = t; }
    return a > b ? a : b;
}

static double bench_callmarket(int n, bgm_rng_t *rng)
{
    double t[REPS];
    bgm_fill_t *fills = malloc(2 * (size_t)n * sizeof *fills);
    for (int r = 0; r < REPS; r++) {
        bgm_callmarket_t *cm = bgm_callmarket_new((size_t)n);
        for (int i = 0; i < n; i++) {
            bgm_order_t b = {(uint64_t)i, (uint32_t)i, 1 + (int)bgm_rng_below(rng, 3),
                             1.0 + 4.0 * bgm_rng_uniform(rng)};
            bgm_order_t a = {(uint64_t)i, (uint32_t)i, 1 + (int)bgm_rng_below(rng, 3),
                             0.5 + 4.0 * bgm_rng_uniform(rng)};
            bgm_callmarket_bid(cm, &b);
            bgm_callmarket_ask(cm, &a);
        }
        bgm_clearing_t res;
        double t0 = now_ms();
        bgm_callmarket_clear(cm, 0.5, &res, fills, 2 * (size_t)n);
        t[r] = now_ms() - t0;
        bgm_callmarket_destroy(&cm);
    }
    free(fills);
    return median3(t[0], t[1], t[2]);
}

static int bench_combex(int bids, bgm_rng_t *rng, double *t_exact, double *t_greedy,
                        int run_exact)
{
    int sellers = bids / 4 + 2;
    double te[REPS], tg[REPS];
    int bad = 0;
    for (int r = 0; r < REPS; r++) {
        bgm_combex_t *cx = bgm_combex_new(bids, sellers, (size_t)bids * SELLERS_PER_BID);
        int *assign = malloc((size_t)bids * sizeof *assign);
        for (int b = 0; b < bids; b++)
            bgm_combex_add_bid(cx);
        for (int s = 0; s < sellers; s++) {
            double cap[BGM_COMBEX_DIMS] = {4.0, 8.0};
            bgm_combex_add_seller(cx, cap);
        }
        for (int b = 0; b < bids; b++)
            for (int k = 0; k < SELLERS_PER_BID; k++) {
                bgm_combex_pair_t p = {b, (int)bgm_rng_below(rng, (uint32_t)sellers),
                                       0.1 + bgm_rng_uniform(rng),
                                       {1.0 + bgm_rng_below(rng, 2), 1.0 + bgm_rng_below(rng, 4)}};
                bgm_combex_add_pair(cx, &p);
            }
        bgm_combex_result_t ex = {0}, gr;
        double t0 = now_ms();
        if (run_exact)
            bgm_combex_solve(cx, BGM_COMBEX_EXACT, (size_t)-1, 0, assign, &ex);
        te[r] = now_ms() - t0;
        t0 = now_ms();
        bgm_combex_solve(cx, BGM_COMBEX_GREEDY, 0, 0, assign, &gr);
        tg[r] = now_ms() - t0;
        if (run_exact && ex.method == BGM_COMBEX_EXACT && gr.objective > ex.objective + 1e-9)
            bad = 1;
        free(assign);
        bgm_combex_destroy(&cx);
    }
    *t_exact = run_exact ? median3(te[0], te[1], te[2]) : -1.0;
    *t_greedy = median3(tg[0], tg[1], tg[2]);
    return bad;
}

int main(int argc, char **argv)
{
    int quick = argc > 1 && strcmp(argv[1], "--quick") == 0;
    static const int sizes[] = {10, 30, 100, 300, 1000, 3000, 10000, 30000, 100000};
    int nsizes = quick ? 4 : (int)(sizeof sizes / sizeof sizes[0]);
    int exact_max = quick ? 30 : 1000;
    bgm_rng_t rng;
    bgm_rng_seed(&rng, 1);
    int bad = 0;
    printf("%8s %14s %8s %16s %17s\n", "orders", "callmarket_ms", "bids", "combex_exact_ms",
           "combex_greedy_ms");
    for (int i = 0; i < nsizes; i++) {
        int n = sizes[i];
        double cm = bench_callmarket(n, &rng);
        double te, tg;
        int bids = n;
        /* Exact only where GLPK answers in seconds on this book shape. */
        bad |= bench_combex(bids, &rng, &te, &tg, bids <= exact_max);
        if (te >= 0)
            printf("%8d %14.3f %8d %16.3f %17.3f\n", n, cm, bids, te, tg);
        else
            printf("%8d %14.3f %8d %16s %17.3f\n", n, cm, bids, "-", tg);
    }
    if (bad)
        fprintf(stderr, "bench_market: the greedy beat the exact solver\n");
    return bad;
}
