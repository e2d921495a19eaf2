#include "bgm_evq.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_codec.h"

#define BGM_EVENT_MESSAGE 0

typedef struct run_ctx {
    bgm_evq_queue_t q;
    double latency, bandwidth;
    long messages;
    int wire;       /* 1: every message crosses bgm_codec (encode, then decode) */
    bg_error_t err; /* why a message failed the codec */
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
    const double delay = r->latency + (double)bytes / r->bandwidth;
    if (!r->wire) {
        q_push_msg(&r->q, m, delay);
        return;
    }
    /* The receiver gets only what the frames carry: the message is encoded
     * with the sender's view and decoded into a fresh struct. */
    bga_frames_t frames = {0};
    bga_frame_t views[BGA_WIRE_MAX_FRAMES];
    bgm_msg_t got;
    bga_wire_error_t werr;
    bg_status st = bgm_codec_encode_msg(m, 0, (uint64_t)r->messages, &frames, &r->err);
    if (st == BG_OK) {
        bga_frames_view(&frames, views);
        if (bgm_codec_decode_msg(views, frames.count, &got, &werr) != BGA_WIRE_OK)
            st = bg_error_set(&r->err, BG_ERR_INVALID, "message %s from %u to %u: frame %d, %s: %s",
                              bgm_codec_type_name((uint16_t)(0x1000 + m->type)), (unsigned)m->from,
                              (unsigned)m->to, werr.frame, werr.field, werr.message);
    }
    bga_frames_free(&frames);
    if (st) {
        if (!r->q.status)
            r->q.status = st;
        return;
    }
    q_push_msg(&r->q, &got, delay);
}

static void run_timer(void *ctx, uint32_t agent, double at, int kind, uint64_t arg)
{
    run_ctx_t *r = ctx;
    q_timer(&r->q, agent, at, kind, arg);
}

static bg_status run_world(bgm_world_t *w, double latency, double bandwidth, int wire,
                           bgm_evq_stats_t *stats, bg_error_t *err)
{
    bg_status st = BG_OK;
    run_ctx_t r;
    memset(&r, 0, sizeof r);
    r.wire = wire;
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
    if (st && err) {
        if (r.err.status)
            *err = r.err;
        else
            bg_error_set(err, st, "simulation failed: %s", bg_strerror(st));
    }
    if (stats) {
        stats->events = events;
        stats->messages = r.messages;
        stats->end_time = r.q.now;
    }
    bgm_heap_destroy(&r.q.heap);
    return st;
}

bg_status bgm_evq_run_world(bgm_world_t *w, double latency, double bandwidth,
                            bgm_evq_stats_t *stats)
{
    return run_world(w, latency, bandwidth, 0, stats, NULL);
}

bg_status bgm_evq_run_world_wire(bgm_world_t *w, double latency, double bandwidth,
                                 bgm_evq_stats_t *stats, bg_error_t *err)
{
    return run_world(w, latency, bandwidth, 1, stats, err);
}
