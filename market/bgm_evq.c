#include "bgm_evq.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define BGM_EVENT_MESSAGE 0

typedef struct run_ctx {
    bgm_evq_queue_t q;
    double latency, bandwidth;
    long messages;
} run_ctx_t;

static void q_push_msg(bgm_evq_queue_t *q, const bgm_msg_t *m, double delay)
{
    bgm_msg_t *copy = malloc(sizeof *copy);
    if (!copy) {
        q->status = BG_ERR_NOMEM;
        return;
    }
    *copy = *m;
    bgm_event_t ev = {q->now + delay, 0, m->to, BGM_EVENT_MESSAGE, 0, copy};
    bg_status st = bgm_heap_push(q->heap, &ev);
    if (st) {
        free(copy);
        if (!q->status)
            q->status = st;
    }
}

static void q_send(void *ctx, const bgm_msg_t *m, long bytes)
{
    (void)bytes;
    bgm_evq_queue_t *q = ctx;
    q_push_msg(q, m, q->delay);
}

static void q_timer(void *ctx, uint32_t agent, double at, int kind, uint64_t arg)
{
    bgm_evq_queue_t *q = ctx;
    bgm_event_t ev = {at < q->now ? q->now : at, 0, agent, (uint32_t)kind, arg, NULL};
    bg_status st = bgm_heap_push(q->heap, &ev);
    if (st && !q->status)
        q->status = st;
}

bgm_sink_t bgm_evq_sink(bgm_evq_queue_t *q)
{
    bgm_sink_t s = {q, q_send, q_timer};
    return s;
}

static void run_send(void *ctx, const bgm_msg_t *m, long bytes)
{
    run_ctx_t *r = ctx;
    r->messages++;
    q_push_msg(&r->q, m, r->latency + (double)bytes / r->bandwidth);
}

static void run_timer(void *ctx, uint32_t agent, double at, int kind, uint64_t arg)
{
    run_ctx_t *r = ctx;
    q_timer(&r->q, agent, at, kind, arg);
}

bg_status bgm_evq_run_world(bgm_world_t *w, double latency, double bandwidth,
                            bgm_evq_stats_t *stats)
{
    bg_status st = BG_OK;
    run_ctx_t r;
    memset(&r, 0, sizeof r);
    r.latency = latency;
    r.bandwidth = bandwidth;
    r.q.heap = bgm_heap_new(BGM_EVQ_MAX_EVENTS);
    if (!r.q.heap)
        return BG_ERR_NOMEM;
    bgm_sink_t sink = {&r, run_send, run_timer};
    double horizon = bgm_world_horizon(w);
    long events = 0;
    if ((st = bgm_world_start(w, &sink, 0.0)))
        goto out;
    bgm_event_t ev;
    while (bgm_heap_peek_time(r.q.heap) <= horizon && bgm_heap_pop(r.q.heap, &ev)) {
        r.q.now = ev.time;
        events++;
        if (ev.msg) {
            st = bgm_world_on_message(w, ev.msg, ev.time);
            free(ev.msg);
        } else {
            st = bgm_world_on_timer(w, ev.agent, (int)ev.kind, ev.arg, ev.time);
        }
        if (st || (st = r.q.status))
            goto out;
    }
out:
    if (stats) {
        stats->events = events;
        stats->messages = r.messages;
        stats->end_time = r.q.now;
    }
    bgm_heap_destroy(&r.q.heap);
    return st;
}
