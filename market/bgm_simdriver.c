#include "bgm_simdriver.h"

#include <math.h>
#include <simgrid/actor.h>
#include <simgrid/comm.h>
#include <simgrid/cond.h>
#include <simgrid/engine.h>
#include <simgrid/host.h>
#include <simgrid/mailbox.h>
#include <simgrid/mutex.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bgm_heap.h"

#define BGM_NODE_MAX_TIMERS ((size_t)1 << 22)
#define BGM_HOST_NAME_MAX 32
#define BGM_MARKET_STACK_BYTES (1u << 20)
/* Envelopes are allocated in chunks that never move: SimGrid holds a
 * pointer to each one until it is delivered. A chunk is written whole
 * when it is threaded onto the free list, so it is resident at once:
 * 512 envelopes (120 KiB) keep that close to what is in flight (about
 * 1,700 messages at 2000 agents) where 4096 made it a fixed 950 KiB. */
#define BGM_ENV_CHUNK_BITS 9
#define BGM_ENV_CHUNK ((uint32_t)1 << BGM_ENV_CHUNK_BITS)
#define BGM_ENV_MAX_CHUNKS ((uint32_t)1 << 15)
#define BGM_ENV_NONE UINT32_MAX

/* A message in flight: the copy SimGrid carries and the communication
 * that carries it. Communications are not detached: SimGrid 3.32 keeps
 * every detached communication in one global list and scans it linearly
 * when each one completes, which made the cost of a message grow with
 * the number of messages in flight. Instead the sending actor keeps its
 * own short list and reaps a communication (a wait that returns at once)
 * after the receiver has handled the message. */
typedef struct envelope {
    bgm_msg_t msg;
    double sent; /* simulated time it was sent, for a trace */
    long bytes;  /* its simulated size, for a trace */
    sg_comm_t comm;
    uint32_t next_free;
    int delivered;
} envelope_t;

/* The envelopes one actor has sent and not yet reaped. */
typedef struct pending {
    uint32_t *env;
    size_t n, cap;
} pending_t;

typedef struct node {
    sg_host_t host;
    sg_mailbox_t mailbox;
    bgm_heap_t *timers;
    sg_cond_t cond;
    sg_mutex_t mutex;
    double waiting_until; /* timer actor sleeps until this (inf: no timer) */
    pending_t sent_by_receiver, sent_by_timer;
} node_t;

/* Effects a world handler emits, held back until the handler returns: a
 * SimGrid call yields to other actors, and the world must never be
 * re-entered in the middle of a handler. */
typedef struct outbox {
    bgm_msg_t *msg;
    long *bytes;
    size_t nmsg, capmsg;
    uint32_t *notify;
    size_t nnotify, capnotify;
} outbox_t;

typedef struct driver {
    outbox_t out;
    outbox_t spare; /* an emptied outbox whose arrays are reused */
    envelope_t **env_chunk; /* grows; the chunks themselves never move */
    uint32_t nenv_chunks, env_chunk_cap;
    uint32_t env_free; /* head of the free list */
    pending_t sent_by_controller;
    bgm_world_t *w;
    const bgm_sim_trace_t *trace; /* NULL: none */
    node_t *nodes;
    uint32_t nnodes; /* world nodes + market */
    double horizon;
    bg_status status;
    long messages, timers;
} driver_t;

/* SimGrid actors take (argc, argv); the driver is process-global for the
 * one run this process makes. */
static driver_t *g_driver;

static node_t *node_of(driver_t *d, uint32_t agent)
{
    return &d->nodes[bgm_world_agent_node(d->w, agent)];
}

static void drv_send(void *ctx, const bgm_msg_t *m, long bytes)
{
    driver_t *d = ctx;
    outbox_t *o = &d->out;
    if (o->nmsg == o->capmsg) {
        size_t n = o->capmsg ? 2 * o->capmsg : 64;
        bgm_msg_t *pm = realloc(o->msg, n * sizeof *pm);
        if (pm)
            o->msg = pm;
        long *pb = realloc(o->bytes, n * sizeof *pb);
        if (pb)
            o->bytes = pb;
        if (!pm || !pb) {
            d->status = BG_ERR_NOMEM;
            return;
        }
        o->capmsg = n;
    }
    o->msg[o->nmsg] = *m;
    o->bytes[o->nmsg++] = bytes;
}

static envelope_t *env_at(driver_t *d, uint32_t id)
{
    return &d->env_chunk[id >> BGM_ENV_CHUNK_BITS][id & (BGM_ENV_CHUNK - 1)];
}

/* Takes an envelope from the free list, adding a chunk when it is empty. */
static uint32_t env_alloc(driver_t *d)
{
    if (d->env_free == BGM_ENV_NONE) {
        if (d->nenv_chunks == BGM_ENV_MAX_CHUNKS)
            return BGM_ENV_NONE;
        if (d->nenv_chunks == d->env_chunk_cap) {
            uint32_t cap = d->env_chunk_cap ? 2 * d->env_chunk_cap : 16;
            envelope_t **p = realloc(d->env_chunk, cap * sizeof *p);
            if (!p)
                return BGM_ENV_NONE;
            d->env_chunk = p;
            d->env_chunk_cap = cap;
        }
        envelope_t *c = malloc(BGM_ENV_CHUNK * sizeof *c);
        if (!c)
            return BGM_ENV_NONE;
        uint32_t base = d->nenv_chunks << BGM_ENV_CHUNK_BITS;
        d->env_chunk[d->nenv_chunks++] = c;
        for (uint32_t i = 0; i < BGM_ENV_CHUNK; i++)
            c[i].next_free = i + 1 < BGM_ENV_CHUNK ? base + i + 1 : BGM_ENV_NONE;
        d->env_free = base;
    }
    uint32_t id = d->env_free;
    d->env_free = env_at(d, id)->next_free;
    return id;
}

static void env_release(driver_t *d, uint32_t id)
{
    env_at(d, id)->next_free = d->env_free;
    d->env_free = id;
}

static bg_status pending_push(pending_t *p, uint32_t id)
{
    if (p->n == p->cap) {
        size_t c = p->cap ? 2 * p->cap : 16;
        uint32_t *q = realloc(p->env, c * sizeof *q);
        if (!q)
            return BG_ERR_NOMEM;
        p->env = q;
        p->cap = c;
    }
    p->env[p->n++] = id;
    return BG_OK;
}

/* Reaps the sender's communications whose message has been handled: their
 * waits return at once, in the order they were sent. */
static void reap(driver_t *d, pending_t *p)
{
    size_t keep = 0;
    for (size_t i = 0; i < p->n; i++) {
        uint32_t id = p->env[i];
        envelope_t *e = env_at(d, id);
        if (!e->delivered) {
            p->env[keep++] = id;
            continue;
        }
        sg_comm_wait(e->comm);
        env_release(d, id);
    }
    p->n = keep;
}

/* Waits for every communication the sender still has out (end of an
 * actor that sends once and then only sleeps). A communication to a
 * permanent receiver completes when its bytes arrive, possibly before the
 * receiver has read the envelope: such an envelope is not reused but kept
 * until the run ends. */
static void reap_all(driver_t *d, pending_t *p)
{
    size_t keep = 0;
    for (size_t i = 0; i < p->n; i++) {
        uint32_t id = p->env[i];
        envelope_t *e = env_at(d, id);
        sg_comm_wait(e->comm);
        if (e->delivered)
            env_release(d, id);
        else
            p->env[keep++] = id;
    }
    p->n = keep;
}

/* Performs the held-back effects, then reaps what the sender may reap.
 * The outbox is detached first, so a handler that runs while this one
 * yields fills a fresh outbox. */
static void flush(driver_t *d, pending_t *sent)
{
    outbox_t o = d->out;
    d->out = d->spare;
    memset(&d->spare, 0, sizeof d->spare);
    for (size_t i = 0; i < o.nmsg; i++) {
        uint32_t id = env_alloc(d);
        if (id == BGM_ENV_NONE || pending_push(sent, id)) {
            if (id != BGM_ENV_NONE)
                env_release(d, id);
            d->status = BG_ERR_NOMEM;
            break;
        }
        envelope_t *e = env_at(d, id);
        e->msg = o.msg[i];
        e->sent = simgrid_get_clock();
        e->bytes = o.bytes[i];
        e->delivered = 0;
        d->messages++;
        e->comm = sg_mailbox_put_async(node_of(d, e->msg.to)->mailbox, e, o.bytes[i]);
    }
    for (size_t i = 0; i < o.nnotify; i++)
        sg_cond_notify_one(d->nodes[o.notify[i]].cond);
    reap(d, sent);
    /* Keep the arrays for the next handler rather than reallocating them. */
    o.nmsg = o.nnotify = 0;
    if (d->spare.capmsg == 0 && d->spare.capnotify == 0) {
        d->spare = o;
    } else {
        free(o.msg);
        free(o.bytes);
        free(o.notify);
    }
}

static void drv_timer(void *ctx, uint32_t agent, double at, int kind, uint64_t arg)
{
    driver_t *d = ctx;
    node_t *n = node_of(d, agent);
    bgm_event_t ev = {at, 0, agent, (uint32_t)kind, arg, NULL};
    bg_status st = bgm_heap_push(n->timers, &ev);
    if (st && !d->status)
        d->status = st;
    if (at < n->waiting_until) {
        outbox_t *o = &d->out;
        if (o->nnotify == o->capnotify) {
            size_t c = o->capnotify ? 2 * o->capnotify : 16;
            uint32_t *p = realloc(o->notify, c * sizeof *p);
            if (!p) {
                d->status = BG_ERR_NOMEM;
                return;
            }
            o->notify = p;
            o->capnotify = c;
        }
        o->notify[o->nnotify++] = (uint32_t)(n - d->nodes);
    }
}

static void receiver(int argc, char **argv)
{
    driver_t *d = g_driver;
    node_t *n = &d->nodes[atoi(argv[1])];
    sg_mailbox_set_receiver(sg_mailbox_get_name(n->mailbox));
    for (;;) {
        envelope_t *e = sg_mailbox_get(n->mailbox);
        const double now = simgrid_get_clock();
        bg_status st = bgm_world_on_message(d->w, &e->msg, now);
        if (d->trace)
            d->trace->delivered(d->trace->ctx, &e->msg, e->bytes, e->sent, now);
        e->delivered = 1; /* its sender may now reap the communication */
        if (st && !d->status)
            d->status = st;
        flush(d, &n->sent_by_receiver);
    }
}

static void timer_actor(int argc, char **argv)
{
    driver_t *d = g_driver;
    node_t *n = &d->nodes[atoi(argv[1])];
    sg_mutex_lock(n->mutex);
    for (;;) {
        double now = simgrid_get_clock();
        double next = bgm_heap_peek_time(n->timers);
        if (next > d->horizon) {
            n->waiting_until = INFINITY;
            sg_cond_wait(n->cond, n->mutex);
            continue;
        }
        if (next > now) {
            n->waiting_until = next;
            sg_cond_wait_for(n->cond, n->mutex, next - now);
            n->waiting_until = INFINITY;
            continue;
        }
        bgm_event_t ev;
        bgm_heap_pop(n->timers, &ev);
        d->timers++;
        bg_status st = bgm_world_on_timer(d->w, ev.agent, (int)ev.kind, ev.arg, now);
        if (st && !d->status)
            d->status = st;
        flush(d, &n->sent_by_timer);
    }
}

static void controller(int argc, char **argv)
{
    driver_t *d = g_driver;
    bgm_sink_t sink = {d, drv_send, drv_timer};
    bg_status st = bgm_world_start(d->w, &sink, 0.0);
    if (st && !d->status)
        d->status = st;
    flush(d, &d->sent_by_controller);
    reap_all(d, &d->sent_by_controller);
    sg_actor_sleep_until(d->horizon);
}

void bgm_simdriver_init(void)
{
    char arg0[] = "biotgrid-sim";
    char arg1[] = "--log=root.thres:critical";
    char arg2[64];
    snprintf(arg2, sizeof arg2, "--cfg=contexts/stack-size:%d", BGM_ACTOR_STACK_KIB);
    char arg3[] = "--log=root.app:stdout";
    char *argv[] = {arg0, arg1, arg2, arg3, NULL};
    int argc = 3;
    simgrid_init(&argc, argv);
}

static int cmp_host(const void *a, const void *b)
{
    return strcmp(sg_host_get_name(*(const sg_host_t *)a), sg_host_get_name(*(const sg_host_t *)b));
}

static void start_actor(const char *name, sg_host_t host, void (*code)(int, char **), int index,
                        int daemon, unsigned stack_bytes)
{
    char idx[16];
    snprintf(idx, sizeof idx, "%d", index);
    const char *argv[] = {name, idx};
    sg_actor_t a = sg_actor_init(name, host);
    if (stack_bytes)
        sg_actor_set_stacksize(a, stack_bytes);
    if (daemon)
        sg_actor_daemonize(a);
    sg_actor_start_(a, code, 2, argv);
}

void bgm_simdriver_load(const char *platform_xml)
{
    simgrid_load_platform(platform_xml);
}

/* Node i's host on a user platform: the market on the first host by name,
 * the nodes round-robin after it (hosts sorted by name). */
static sg_host_t user_host(sg_host_t *hosts, size_t nhosts, uint32_t i, uint32_t nworld)
{
    return i == nworld ? hosts[0] : hosts[(1 + i) % nhosts];
}

bg_status bgm_simdriver_user_speeds(uint32_t nodes, double *speed, bg_error_t *err)
{
    sg_host_t *hosts = sg_host_list();
    size_t nhosts = sg_host_count();
    if (!hosts || nhosts == 0) {
        free(hosts);
        return bg_error_set(err, BG_ERR_INVALID, "the platform has no host");
    }
    qsort(hosts, nhosts, sizeof *hosts, cmp_host);
    for (uint32_t i = 0; i <= nodes; i++)
        speed[i] = sg_host_get_speed(user_host(hosts, nhosts, i, nodes));
    free(hosts);
    return BG_OK;
}

bg_status bgm_simdriver_run(bgm_world_t *w, int user_platform, bgm_sim_stats_t *stats,
                            bg_error_t *err)
{
    return bgm_simdriver_run_traced(w, user_platform, NULL, stats, err);
}

bg_status bgm_simdriver_run_traced(bgm_world_t *w, int user_platform, const bgm_sim_trace_t *trace,
                                   bgm_sim_stats_t *stats, bg_error_t *err)
{
    bg_status st = BG_OK;
    driver_t d;
    memset(&d, 0, sizeof d);
    d.w = w;
    d.trace = trace;
    d.env_free = BGM_ENV_NONE;
    d.horizon = bgm_world_horizon(w);
    g_driver = &d;
    uint32_t nworld = bgm_world_agent_node(w, 0); /* the market's node = world node count */
    d.nnodes = nworld + 1;
    d.nodes = calloc(d.nnodes, sizeof *d.nodes);
    sg_host_t *hosts = sg_host_list();
    size_t nhosts = sg_host_count();
    if (!d.nodes || !hosts || nhosts == 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %u nodes", d.nnodes);
        goto out;
    }
    qsort(hosts, nhosts, sizeof *hosts, cmp_host);
    for (uint32_t i = 0; i < d.nnodes; i++) {
        node_t *n = &d.nodes[i];
        char name[BGM_HOST_NAME_MAX];
        if (user_platform) {
            n->host = user_host(hosts, nhosts, i, nworld);
        } else {
            if (i == nworld)
                snprintf(name, sizeof name, "market");
            else
                snprintf(name, sizeof name, "h%u", i);
            n->host = sg_host_by_name(name);
        }
        if (!n->host) {
            st = bg_error_set(err, BG_ERR_INVALID, "platform has no host for node %u", i);
            goto out;
        }
        char mb[BGM_HOST_NAME_MAX];
        snprintf(mb, sizeof mb, "n%u", i);
        n->mailbox = sg_mailbox_by_name(mb);
        n->timers = bgm_heap_new(BGM_NODE_MAX_TIMERS);
        n->cond = sg_cond_init();
        n->mutex = sg_mutex_init();
        n->waiting_until = INFINITY;
        if (!n->timers) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for node timers");
            goto out;
        }
    }
    /* Agents' actors get small stacks (contexts/stack-size); the market's
     * actors run the clearing, GLPK included, and get a full-size stack. */
    for (uint32_t i = 0; i < d.nnodes; i++) {
        unsigned stack = i == nworld ? BGM_MARKET_STACK_BYTES : 0;
        start_actor("recv", d.nodes[i].host, receiver, (int)i, 1, stack);
        start_actor("timer", d.nodes[i].host, timer_actor, (int)i, 1, stack);
    }
    start_actor("ctl", d.nodes[nworld].host, controller, 0, 0, BGM_MARKET_STACK_BYTES);
    simgrid_run();
    if (d.status)
        st = bg_error_set(err, d.status, "simulation failed: %s", bg_strerror(d.status));
    if (stats) {
        stats->messages = d.messages;
        stats->timers = d.timers;
        stats->end_time = simgrid_get_clock();
    }
out:
    free(hosts);
    if (d.nodes)
        for (uint32_t i = 0; i < d.nnodes; i++) {
            bgm_heap_destroy(&d.nodes[i].timers);
            free(d.nodes[i].sent_by_receiver.env);
            free(d.nodes[i].sent_by_timer.env);
        }
    free(d.nodes);
    free(d.sent_by_controller.env);
    free(d.out.msg);
    free(d.out.bytes);
    free(d.out.notify);
    free(d.spare.msg);
    free(d.spare.bytes);
    free(d.spare.notify);
    /* Envelopes still out belong to communications SimGrid tears down
     * with the engine at exit; the chunks go only after the run. */
    for (uint32_t i = 0; i < d.nenv_chunks; i++)
        free(d.env_chunk[i]);
    free(d.env_chunk);
    g_driver = NULL;
    return st;
}
