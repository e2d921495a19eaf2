/*
 * bench_alloc — allocation on the live market, per mechanism, against
 * real agent daemons on loopback (tests/market_live/live.sh starts them):
 *
 *   bench_alloc latency DIR NAGENTS ROUNDS
 *       one job at a time (plan rotation-fit x2 + sparse-solve): the
 *       latency from the first ask to all services bought, median, p90,
 *       max and mean. A transient failure (every able seller busy, a buy
 *       past its timeout) is asked again after a backoff, as the broker's
 *       coordinator does, and counted.
 *   bench_alloc saturation DIR NAGENTS JOBS INFLIGHT
 *       INFLIGHT jobs at once, each released as soon as it is bought and
 *       followed by the next, until JOBS are bought: jobs allocated per
 *       second (JOBS over the time from the first ask to the last
 *       allocation) and the latency of each job from its ask, median and
 *       p90; a job that fails for a transient reason is released and asked
 *       again after a backoff (0.1 s doubling to 2 s, as the broker's
 *       coordinator does; counted), its latency running from its first ask.
 *
 *   bench_alloc stream DIR NAGENTS SEED RATE DURATION HOLD [REPS]
 *       the live half of the live-against-simulated experiment
 *       (tests/market_live/live_vs_sim.sh): jobs arrive as a Poisson
 *       stream of RATE a second for DURATION seconds (the arrivals, works
 *       and valuations drawn from SEED), each buying a rotation fit and a
 *       sparse solve of 3 units of work each with a budget of its two
 *       valuations (uniform in [1.5, 4.5] per unit) times the work, asked
 *       again after transient failures until 30 s after it arrived (its
 *       deadline), and held HOLD seconds once bought. Prints, per
 *       mechanism and replication (REPS of them, seeds SEED, SEED + 1, ...):
 *       jobs requested and allocated, the mean price per unit of work and
 *       the mean spend of an allocated job.
 *
 * It uses only the market's calls that older trees have too
 * (bgb_market_new, _buy, _release, _tick, _on_frames), so the same source
 * measures the code before a change and after it in one run
 * (bench_compare.sh). Exits 0, or 1 with the first failure.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"
#include "bgm_rng.h"
#include "live_net.h"

#define BENCH_PATIENCE 60.0 /* s: how long a job is asked again after transient failures */
#define MAX_INFLIGHT 256

static const bgb_need_t plan[2] = {{BGB_GOOD_ROTFIT, 2000.0, 2}, {BGB_GOOD_SOLVE, 500.0, 1}};
static const bgb_mechanism mechs[3] = {BGB_MECH_POSTED, BGB_MECH_CENTRAL, BGB_MECH_CATALLACTIC};

typedef struct slot {
    int done;
    double spent;
    char reason[64];
    uint64_t job;
    double asked;    /* first ask of this slot's current job */
    double retry_at; /* asks again then (0: not waiting) */
    double backoff;
} slot_t;

static void on_done(void *ctx, const bgb_outcome_t *o)
{
    slot_t *s = ctx;
    s->done = 1;
    s->spent = o->spent;
    snprintf(s->reason, sizeof s->reason, "%s", o->reason ? o->reason : "");
}

static int transient(const char *reason)
{
    return strstr(reason, "no seller") != NULL || strcmp(reason, "timeout") == 0;
}

static void ask(live_net_t *h, slot_t *s, uint64_t job, bgb_mechanism mech)
{
    s->done = 0;
    s->reason[0] = '\0';
    s->job = job;
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_market_buy(h->market, job, mech, 1e6, plan, 2, bg_clock_now(), on_done, s, &err) !=
        BG_OK)
        live_net_fail("buy job %llu: %s", (unsigned long long)job, err.message);
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Sorts v and prints its median and p90 (ms), with a label. */
static void quantiles(const char *label, double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    printf("%s median %8.3f ms  p90 %8.3f ms  max %8.3f ms", label, v[n / 2] * 1e3,
           v[(n * 9) / 10] * 1e3, v[n - 1] * 1e3);
}

static void latency(live_net_t *h, size_t nagents, int rounds)
{
    double *lat = calloc((size_t)rounds, sizeof *lat);
    uint64_t job = 1;
    printf("allocation latency, %zu agents on loopback, plan rotation-fit x2 + sparse-solve, "
           "%d rounds, one job at a time\n",
           nagents, rounds);
    for (int mi = 0; mi < 3; mi++) {
        int retried = 0;
        double sum = 0;
        for (int r = 0; r < rounds; r++) {
            slot_t s;
            const double first = bg_clock_now();
            double backoff = 0.1;
            for (;;) {
                ask(h, &s, job, mechs[mi]);
                live_net_pump(h, 20.0, &s.done);
                if (!s.done)
                    live_net_fail("job %llu under %s: no outcome in 20 s",
                                  (unsigned long long)job, bgb_mechanism_name(mechs[mi]));
                if (!s.reason[0] || !transient(s.reason) ||
                    bg_clock_now() + backoff > first + BENCH_PATIENCE)
                    break;
                fprintf(stderr, "bench: %s job %llu: %s, asked again\n",
                        bgb_mechanism_name(mechs[mi]), (unsigned long long)job, s.reason);
                bgb_market_release(h->market, job++, bg_clock_now());
                retried++;
                live_net_pump(h, backoff, NULL);
                backoff = backoff * 2 < 2.0 ? backoff * 2 : 2.0;
            }
            if (s.reason[0])
                live_net_fail("%s failed: %s", bgb_mechanism_name(mechs[mi]), s.reason);
            lat[r] = bg_clock_now() - first;
            sum += lat[r];
            bgb_market_release(h->market, job++, bg_clock_now());
            live_net_pump(h, 0.01, NULL);
        }
        char label[32];
        snprintf(label, sizeof label, "%-12s", bgb_mechanism_name(mechs[mi]));
        quantiles(label, lat, rounds);
        printf("  mean %8.3f ms  (%d asked again)\n", sum / rounds * 1e3, retried);
    }
    free(lat);
}

static void saturation(live_net_t *h, size_t nagents, int jobs, int inflight)
{
    slot_t *slots = calloc((size_t)inflight, sizeof *slots);
    double *lat = calloc((size_t)jobs, sizeof *lat);
    uint64_t job = 1000000;
    printf("saturation, %zu agents on loopback, %d jobs in flight, %d allocations a mechanism, "
           "each released when bought\n",
           nagents, inflight, jobs);
    for (int mi = 0; mi < 3; mi++) {
        int bought = 0, asked = 0, failed = 0;
        const double start = bg_clock_now();
        double last = start;
        for (int i = 0; i < inflight && asked < jobs; i++, asked++) {
            slots[i].asked = bg_clock_now();
            slots[i].retry_at = slots[i].backoff = 0;
            ask(h, &slots[i], job++, mechs[mi]);
        }
        while (bought < jobs) {
            if (bg_clock_now() > start + 10 * BENCH_PATIENCE)
                live_net_fail("%s: %d of %d bought in %g s", bgb_mechanism_name(mechs[mi]), bought,
                              jobs, 10 * BENCH_PATIENCE);
            live_net_pump(h, 0.001, NULL);
            for (int i = 0; i < inflight; i++) {
                slot_t *s = &slots[i];
                const double now = bg_clock_now();
                if (s->retry_at > 0 && now >= s->retry_at) {
                    s->retry_at = 0;
                    ask(h, s, job++, mechs[mi]); /* its latency still from the first ask */
                    continue;
                }
                if (!s->done)
                    continue;
                bgb_market_release(h->market, s->job, now);
                if (s->reason[0]) {
                    if (!transient(s->reason))
                        live_net_fail("%s failed: %s", bgb_mechanism_name(mechs[mi]), s->reason);
                    failed++;
                    s->done = 0;
                    s->backoff = s->backoff > 0 ? (s->backoff * 2 < 2.0 ? s->backoff * 2 : 2.0)
                                                : 0.1;
                    s->retry_at = now + s->backoff;
                    continue;
                }
                s->backoff = 0;
                lat[bought++] = now - s->asked;
                last = now;
                if (asked < jobs) {
                    asked++;
                    s->asked = now;
                    ask(h, s, job++, mechs[mi]);
                } else {
                    s->done = 0;
                    s->job = 0;
                    s->reason[0] = '\0';
                    s->asked = -1;
                }
            }
        }
        char label[48];
        snprintf(label, sizeof label, "%-12s %7.1f jobs/s ", bgb_mechanism_name(mechs[mi]),
                 bought / (last - start));
        quantiles(label, lat, bought);
        printf("  (%d asked again)\n", failed);
        live_net_pump(h, 0.6, NULL); /* heartbeats: every seller idle again */
    }
    free(slots);
    free(lat);
}

/* One job of the stream: its arrival, budget and what became of it. */
typedef struct arrival {
    double at, budget, hold_until, retry_at, backoff;
    int state; /* 0 not yet, 1 buying, 2 holding, 3 done */
    int allocated;
    slot_t slot;
} arrival_t;

#define STREAM_WORK 3.0
#define STREAM_DEADLINE 30.0

static void stream(live_net_t *h, uint64_t seed, double rate, double duration, double hold)
{
    const bgb_need_t needs[2] = {{BGB_GOOD_ROTFIT, STREAM_WORK, 1},
                                 {BGB_GOOD_SOLVE, STREAM_WORK, 1}};
    const int max = (int)(rate * duration * 3 + 16);
    arrival_t *a = calloc((size_t)max, sizeof *a);
    uint64_t job = 2000000;
    for (int mi = 0; mi < 3; mi++) {
        /* The same arrivals, works and valuations under each mechanism. */
        bgm_rng_t rng;
        bgm_rng_seed(&rng, seed);
        int n = 0;
        for (double t = bgm_rng_exponential(&rng, 1.0 / rate); t < duration && n < max;
             t += bgm_rng_exponential(&rng, 1.0 / rate)) {
            memset(&a[n], 0, sizeof a[n]);
            a[n].at = t;
            for (int k = 0; k < 2; k++)
                a[n].budget += (1.5 + 3.0 * bgm_rng_uniform(&rng)) * STREAM_WORK;
            n++;
        }
        const double start = bg_clock_now();
        int open = n, allocated = 0;
        double spent = 0;
        while (open > 0) {
            live_net_pump(h, 0.005, NULL);
            const double now = bg_clock_now(), t = now - start;
            for (int i = 0; i < n; i++) {
                arrival_t *x = &a[i];
                if ((x->state == 0 && t >= x->at) ||
                    (x->state == 1 && x->retry_at > 0 && t >= x->retry_at)) {
                    x->state = 1;
                    x->retry_at = 0;
                    x->slot.done = 0;
                    x->slot.job = job++;
                    bg_error_t err = BG_ERROR_INIT;
                    if (bgb_market_buy(h->market, x->slot.job, mechs[mi], x->budget, needs, 2, now,
                                       on_done, &x->slot, &err) != BG_OK)
                        live_net_fail("buy: %s", err.message);
                } else if (x->state == 1 && x->slot.done) {
                    x->slot.done = 0;
                    if (!x->slot.reason[0]) {
                        x->state = 2;
                        x->allocated = 1;
                        x->hold_until = t + hold;
                        continue;
                    }
                    bgb_market_release(h->market, x->slot.job, now);
                    x->backoff = x->backoff > 0 ? (x->backoff * 2 < 2.0 ? x->backoff * 2 : 2.0) : 0.1;
                    if (transient(x->slot.reason) && t + x->backoff < x->at + STREAM_DEADLINE) {
                        x->retry_at = t + x->backoff;
                    } else {
                        x->state = 3;
                        open--;
                    }
                } else if (x->state == 2 && t >= x->hold_until) {
                    bgb_market_release(h->market, x->slot.job, now);
                    x->state = 3;
                    open--;
                }
            }
        }
        /* What an allocated job paid: its outcome's spend (the services'
         * price times work), which older trees report alike. */
        for (int i = 0; i < n; i++)
            if (a[i].allocated) {
                allocated++;
                spent += a[i].slot.spent;
            }
        printf("stream %s seed %llu requested %d allocated %d rate %.4f price_per_unit %.6g "
               "spend_per_job %.6g\n",
               bgb_mechanism_name(mechs[mi]), (unsigned long long)seed, n, allocated,
               n ? (double)allocated / n : 0.0,
               allocated ? spent / (allocated * 2 * STREAM_WORK) : 0.0,
               allocated ? spent / allocated : 0.0);
        fflush(stdout);
        live_net_pump(h, 1.0, NULL); /* heartbeats: every seller idle again */
    }
    free(a);
}

int main(int argc, char **argv)
{
    const int lat_mode = argc == 5 && strcmp(argv[1], "latency") == 0;
    const int sat_mode = argc == 6 && strcmp(argv[1], "saturation") == 0;
    if ((argc == 8 || argc == 9) && strcmp(argv[1], "stream") == 0) {
        live_net_t h;
        live_net_open(&h, argv[2], "stream", 0.2);
        live_net_wait(&h, (size_t)atoi(argv[3]));
        const uint64_t seed = strtoull(argv[4], NULL, 10);
        const int reps = argc == 9 ? atoi(argv[8]) : 1;
        for (int r = 0; r < reps; r++)
            stream(&h, seed + (uint64_t)r, atof(argv[5]), atof(argv[6]), atof(argv[7]));
        live_net_close(&h);
        return 0;
    }
    if (!lat_mode && !sat_mode)
        live_net_fail("usage: bench_alloc latency DIR NAGENTS ROUNDS | saturation DIR NAGENTS "
                      "JOBS INFLIGHT | stream DIR NAGENTS SEED RATE DURATION HOLD [REPS]");
    const size_t nagents = (size_t)atoi(argv[3]);
    const int n = atoi(argv[4]), inflight = sat_mode ? atoi(argv[5]) : 1;
    if (n < 1 || inflight < 1 || inflight > MAX_INFLIGHT)
        live_net_fail("ROUNDS or JOBS >= 1, INFLIGHT in [1, %d]", MAX_INFLIGHT);
    live_net_t h;
    live_net_open(&h, argv[2], "bench", 0.05);
    live_net_wait(&h, nagents);
    if (lat_mode)
        latency(&h, nagents, n);
    else
        saturation(&h, nagents, n, inflight);
    live_net_close(&h);
    return 0;
}
