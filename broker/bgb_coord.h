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
 * others; the largest fraction so far is what a lost agent is paid for.
 *
 * A lost agent (silent for agent_liveness_ms while the job waits on it,
 * or forgetting the job's state) does not end a job that bought it
 * (agent_recovery, on by default): its contract is settled pro rata for
 * the work the job kept ("agent_lost" event: the agent, the service, why,
 * the progress and the money), the service is bought again under the
 * job's mechanism, a whole contract with what is left of the budget,
 * leaving the lost agents out ("rebuy" events while the market has no seller,
 * asking again with backoff until the job's deadline, or for
 * BGB_COORD_BUY_PATIENCE without one; "rebought": the new agent, its
 * price and cost), and the solve resumes on it from the state the
 * coordinator kept ("resumed"; bga_backend.h says what is kept). A late
 * answer from a lost agent is discarded ("late_answer"). Only when no
 * seller can be found in time does the job fail, with that reason. The
 * report's "faults" section lists each loss, its market section every
 * contract (a lost one at what it was settled for). A job on the fixed
 * pool has no market to buy from: a loss fails it. With no agent
 * registered on the market but agents in the
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

/* The broker stops: no job is started any more (allocating ones are left
 * for the next broker process), running jobs get `grace` seconds to end;
 * past it they stop at their next basic-service call, with a `stopped`
 * event ("broker_stopping"), and are queued again. Returns once every
 * coordinator ended; accepts NULL. */
void bgb_coord_drain(bgb_coord_t *coord, double grace);

/* Stops dispatching and waits for the coordinators (a running solve
 * finishes first, unless bgb_coord_drain's grace ran out); accepts NULL. */
void bgb_coord_stop(bgb_coord_t **coord);

#endif
