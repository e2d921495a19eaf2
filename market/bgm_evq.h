/*
 * bgm_evq — the deterministic in-process driver: a priority queue of timed
 * events (messages and timers) that feeds a bgm_world_t, or any other
 * sans-I/O state machine through the same sink, with no simulator.
 *
 * Message delay = latency + bytes / bandwidth (no contention). Node and
 * link failures are the world's own business. Used by the unit tests and
 * by `biotgrid sim --engine inprocess` (a cross-check of the SimGrid runs,
 * and the engine under sanitizers).
 */
#ifndef BGM_EVQ_H
#define BGM_EVQ_H

#include <stddef.h>

#include "bg_error.h"
#include "bgm_heap.h"
#include "bgm_world.h"

#define BGM_EVQ_MAX_EVENTS ((size_t)1 << 24)

typedef struct bgm_evq_stats {
    long events;
    long messages;
    double end_time;
} bgm_evq_stats_t;

/* Runs the world from time 0 to its horizon. */
bg_status bgm_evq_run_world(bgm_world_t *w, double latency, double bandwidth,
                            bgm_evq_stats_t *stats);
/* The same, with every message encoded and decoded by bgm_codec between
 * sender and receiver (`biotgrid sim --engine wire`): the receiver sees
 * only what the wire carries, so the outputs equal bgm_evq_run_world's
 * exactly when the codec loses nothing. A message the codec refuses stops
 * the run with BG_ERR_INVALID, described in *err (may be NULL). */
bg_status bgm_evq_run_world_wire(bgm_world_t *w, double latency, double bandwidth,
                                 bgm_evq_stats_t *stats, bg_error_t *err);

/* A bare queue for driving hand-written state machines in tests: the sink
 * pushes into the heap with the given fixed delay. Caller owns the heap. */
typedef struct bgm_evq_queue {
    bgm_heap_t *heap;
    double now;
    double delay;
    bg_status status;
} bgm_evq_queue_t;

/* A sink whose send/timer push into q (messages are copied). */
bgm_sink_t bgm_evq_sink(bgm_evq_queue_t *q);

#endif
