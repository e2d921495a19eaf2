/*
 * bgb_jobreport — what a job's report adds to `solve`'s: the market side.
 * The money the job had spent at each point of its error-against-time
 * trace (contracts pro-rated by the service time their service had worked,
 * counted by the job's watch, bgb_watch), the "market" section of
 * report.json (mechanism, contracts, money against budget, allocation
 * latency, error against money) and error-vs-time-and-money.svg, and
 * the agents the job lost and what replaced them (the "faults" section).
 */
#ifndef BGB_JOBREPORT_H
#define BGB_JOBREPORT_H

#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "bgb_market.h"

/* Usage records at most per job (one per progress call). */
#define BGB_USAGE_MAX_POINTS (1 << 20)
/* A report.json larger than this is not read back. */
#define BGB_JOBREPORT_MAX_REPORT ((size_t)1 << 30)

/* Seconds the job's bought services had worked (inside rotation-fit and
 * sparse-solve calls) when the solve reached a trace point. */
typedef struct bgb_usage_point {
    double seconds; /* the trace point's */
    double used[2]; /* BGB_WATCH_ROTFIT, BGB_WATCH_SOLVE */
} bgb_usage_point_t;

typedef struct bgb_usage {
    bgb_usage_point_t *points; /* owned */
    int count, cap;
} bgb_usage_t;

#define BGB_USAGE_INIT                                                                             \
    {                                                                                              \
        NULL, 0, 0                                                                                 \
    }

/* Records the service time used at `seconds` into the run. Past the cap
 * later points reuse the last record (the money curve then lags, but stays
 * monotone and still ends at the total). */
void bgb_usage_record(bgb_usage_t *usage, double seconds, const double used[2]);
void bgb_usage_release(bgb_usage_t *usage);

/*
 * The money the job had spent at each trace point of run, into money[k]
 * (run->trace_count entries), from the awards it bought (see the .c).
 */
void bgb_jobreport_money(const bgb_usage_t *usage, const bg_solve_result_t *run,
                         const bgb_award_t *awards, int nawards, double *money);

/*
 * Adds the "market" section to the report.json at path. nawards −1: the
 * job ran on the broker's fixed pool, with no market and nothing spent.
 */
bg_status bgb_jobreport_add_market(const char *path, const char *mechanism, double budget,
                                   const bgb_award_t *awards, int nawards, double spent,
                                   double latency, const double *money, int nmoney,
                                   bg_error_t *err);

/* One agent a job lost and its replacement, as the coordinator saw them. */
typedef struct bgb_fault {
    char service[24];                       /* "rotation-fit", "sparse-solve", ... */
    char lost[BGB_DIRECTORY_NAME_MAX];         /* the lost agent's name ("" when unknown) */
    char lost_endpoint[BGB_DIRECTORY_ENDPOINT_MAX];
    char why[256];                          /* how it was found lost */
    double seconds;                         /* into the run when it was noticed */
    double fraction;                        /* the job's progress then, [0, 1] */
    double settled_quantity, settled_paid;  /* its contract, settled pro rata */
    char agent[BGB_DIRECTORY_NAME_MAX];        /* the replacement ("" when none was found) */
    char endpoint[BGB_DIRECTORY_ENDPOINT_MAX];
    double price, quantity;                 /* the replacement's contract */
    int retries;                            /* the market's answers before it sold */
    double bought_after, resumed_after;     /* seconds from noticed to bought, to computing */
    int64_t late_answers;                   /* the lost agent's, discarded */
} bgb_fault_t;

/* Adds the "faults" section (an array, empty when nothing was lost) to the
 * report.json at path. */
bg_status bgb_jobreport_add_faults(const char *path, const bgb_fault_t *faults, int nfaults,
                                   bg_error_t *err);

/* error-vs-time-and-money.svg at path: the run's error against run time
 * and against money, side by side. */
bg_status bgb_jobreport_money_plot(const char *path, const bg_scene_t *scene,
                                   const bg_solve_result_t *run, const double *money,
                                   bg_error_t *err);

#endif
