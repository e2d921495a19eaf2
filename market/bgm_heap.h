/*
 * bgm_heap — a min-heap of timed events ordered by (time, sequence).
 *
 * The sequence number is assigned at insertion, so events at the same time
 * pop in insertion order: both drivers rely on this for determinism.
 * Capacity is bounded by max_events given at creation (a hard cap).
 */
#ifndef BGM_HEAP_H
#define BGM_HEAP_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

typedef struct bgm_event {
    double time;
    uint64_t seq;
    uint32_t agent; /* target agent */
    uint32_t kind;  /* timer kind, or BGM_EVENT_MESSAGE */
    uint64_t arg;   /* timer argument */
    void *msg;      /* owned message for BGM_EVENT_MESSAGE, else NULL */
} bgm_event_t;

typedef struct bgm_heap bgm_heap_t;

bgm_heap_t *bgm_heap_new(size_t max_events);
/* Frees the heap; messages still inside are freed with free(). */
void bgm_heap_destroy(bgm_heap_t **heap);
/* Inserts a copy of *ev (its seq is overwritten). BG_ERR_LIMIT when full. */
bg_status bgm_heap_push(bgm_heap_t *heap, const bgm_event_t *ev);
/* Pops the earliest event into *ev; returns 0 when empty, 1 otherwise. */
int bgm_heap_pop(bgm_heap_t *heap, bgm_event_t *ev);
/* Earliest time, or +inf when empty. */
double bgm_heap_peek_time(const bgm_heap_t *heap);
size_t bgm_heap_size(const bgm_heap_t *heap);

#endif
