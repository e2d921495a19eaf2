/*
 * bgm_simdriver — runs one bgm_world_t on SimGrid (C API, 3.32).
 *
 * One SimGrid host per node plus "market"; per host two small actors: a
 * receiver blocked on the host's mailbox (a permanent receiver, so
 * transfers start when sent, like an asynchronous network) and a timer
 * actor sleeping on a condition variable until the host's next timer.
 * Messages are copied into pooled envelopes carried by asynchronous
 * communications whose simulated size the world gives, so latency,
 * bandwidth and contention on the generated (or user) platform decide
 * when they arrive. The sending actor reaps each communication once the
 * receiver has handled it (not detached: SimGrid 3.32 scans one global
 * list of detached communications each time one completes). The world is single-threaded
 * state: SimGrid runs actors one at a time, so no locking is needed.
 *
 * SimGrid's engine is initialised once per process: call this in a fresh
 * (forked) process, once.
 */
#ifndef BGM_SIMDRIVER_H
#define BGM_SIMDRIVER_H

#include "bg_error.h"
#include "bgm_world.h"

#define BGM_ACTOR_STACK_KIB 32

typedef struct bgm_sim_stats {
    long messages;
    long timers;
    double end_time;
} bgm_sim_stats_t;

/* Initialises SimGrid (silenced, small actor stacks). Once per process. */
void bgm_simdriver_init(void);

/* Loads platform_xml into the engine (after init, once per process).
 * SimGrid aborts the process on a file it cannot load: validate user
 * platforms in a disposable process first (bgm_sim_check_platform). */
void bgm_simdriver_load(const char *platform_xml);

/* For a user platform (loaded): speed[0..nodes] receives the speed of the
 * host each node runs on (the market's, index nodes, last), as
 * bgm_simdriver_run maps them: the market on the first host by name, the
 * nodes round-robin over the hosts after it. */
bg_status bgm_simdriver_user_speeds(uint32_t nodes, double *speed, bg_error_t *err);

/*
 * Runs the world to its horizon on the loaded platform, whose hosts must
 * include h0..h{nodes-1} and "market" (generated), or any hosts (user
 * platform: mapped as above).
 */
bg_status bgm_simdriver_run(bgm_world_t *w, int user_platform, bgm_sim_stats_t *stats,
                            bg_error_t *err);

/* An observer of every message the run delivers, for tracing tools
 * (market_trace): called in the receiving actor just after the world has
 * handled the message, with its simulated size and the simulated times
 * it was sent and received. It must not call the world or the driver; it may call
 * SimGrid's read-only functions (routes, links). */
typedef struct bgm_sim_trace {
    void *ctx;
    void (*delivered)(void *ctx, const bgm_msg_t *m, long bytes, double sent, double received);
} bgm_sim_trace_t;

/* bgm_simdriver_run with a trace (NULL: none); the run is the same. */
bg_status bgm_simdriver_run_traced(bgm_world_t *w, int user_platform, const bgm_sim_trace_t *trace,
                                   bgm_sim_stats_t *stats, bg_error_t *err);

#endif
