/*
 * bgb_watch — a job's solve calls its basic services through this backend,
 * which forwards every call to an inner one (the agents, or in process)
 * once it has checked that the job may go on, and counts the time spent
 * inside rotation-fit and sparse-solve calls (what the job's money is
 * pro-rated by).
 *
 * "May go on" is the caller's check (e.g. the store still says running: a
 * cancel lands there from a REST thread), asked at most every
 * BGB_WATCH_CHECK_SECONDS; once it says no, every call fails with
 * BG_ERR_CONFLICT, so the solver returns after the service call in
 * progress. Used by one thread.
 */
#ifndef BGB_WATCH_H
#define BGB_WATCH_H

#include "bg_backend.h"
#include "bg_error.h"

#define BGB_WATCH_CHECK_SECONDS 0.1

/* Where a forwarded call's time is counted. */
enum { BGB_WATCH_ROTFIT = 0, BGB_WATCH_SOLVE = 1, BGB_WATCH_SERVICES = 2 };

/* 1 while the job may go on; 0 once it must stop. */
typedef int (*bgb_watch_check_fn)(void *ctx);

typedef struct bgb_watch {
    bgb_watch_check_fn check; /* borrowed */
    void *check_ctx;
    const char *what;          /* names the job in the refusal ("job j0123...") */
    const bg_backend_t *inner; /* borrowed */
    double next_check;
    int stopped;          /* the check said no */
    double *used;         /* seconds inside rotation-fit and sparse-solve calls are
                             added to used[BGB_WATCH_ROTFIT], used[BGB_WATCH_SOLVE];
                             NULL: not counted */
    bg_backend_t backend; /* what the solver is given */
} bgb_watch_t;

/* w watches over inner (NULL: in process); w->backend is the solver's
 * backend, valid while w lives. what, check_ctx and used are borrowed. */
void bgb_watch_init(bgb_watch_t *w, bgb_watch_check_fn check, void *check_ctx, const char *what,
                    const bg_backend_t *inner, double *used);

#endif
