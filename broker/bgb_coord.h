/*
 * bgb_coord — the broker's job coordinators: one thread per running job
 * (the job's complex-service agent) and the dispatcher that starts them.
 *
 * A job's coordinator: queued → allocating → running → succeeded, failed
 * or cancelled. It loads the job's scene from the store (bgb_jobscene: the
 * loader the REST API validated it with), buys the plan's services on the
 * market loop (bgb_loop: rotation fit split over the live rotation-fit
 * sellers, sparse-solve ×1, integration-step ×1 when the plan lists it),
 * asking again with backoff for up to BGB_COORD_BUY_PATIENCE seconds while
 * the market answers "no seller" or "timeout" (each retry an "allocation"
 * event), then drives the solve through the agents it bought (bga_backend,
 * behind a bgb_watch that stops between service calls once the job is
 * cancelled), and stores the results (bg_run's files plus the market's side,
 * bgb_jobreport) and the trace. Progress events carry the fraction done:
 * by step or frame for dynamic and morph jobs, by accuracy reached (log of
 * the relative gradient against the tolerance) or iterations for the
 * others. With no agent registered on the market but agents in the
 * configuration (a fixed pool), the job runs on the pool without
 * contracts; with neither, it waits in allocating until an agent registers.
 *
 * The dispatcher sleeps until it is told a job was queued
 * (bgb_coord_notify, called by the REST API) or a coordinator ended, and
 * starts one per queued job while fewer than max_jobs run. Nothing polls.
 */
#ifndef BGB_COORD_H
#define BGB_COORD_H

#include "bg_error.h"
#include "bgb_config.h"
#include "bgb_loop.h"
#include "bgb_store.h"

/* Seconds a job keeps asking the market again while it answers "no
 * seller" or "timeout". */
#define BGB_COORD_BUY_PATIENCE 120.0

typedef struct bgb_coord bgb_coord_t;

/*
 * Starts the dispatcher; it looks at the queue at once (jobs accepted
 * before a restart are queued there). config, store and loop are borrowed
 * and must outlive the coordinators (bgb_coord_stop). Caller owns *out.
 */
bg_status bgb_coord_start(const bgb_config_t *config, bgb_store_t *store, bgb_loop_t *loop,
                          bgb_coord_t **out, bg_error_t *err);

/* A job was queued: the dispatcher looks at the queue. Any thread. */
void bgb_coord_notify(bgb_coord_t *coord);

/* Stops dispatching and waits for the coordinators (a running solve
 * finishes first); accepts NULL. */
void bgb_coord_stop(bgb_coord_t **coord);

#endif
