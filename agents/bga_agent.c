#include "bga_agent.h"

#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bga_transport.h"

/* What the socket loop asks of the worker: the first part of each message
 * on their pipe (the two threads share one binary, so a struct is fine). A
 * call is followed by the caller's routing id and the request's frames. */
enum { ORDER_CALL = 1, ORDER_TOUCH = 2, ORDER_STOP = 3, ORDER_DROP = 4 };
typedef struct order {
    int kind;
    uint64_t job;  /* ORDER_TOUCH: the job whose lease a heartbeat renewed */
    double cores;  /* ORDER_CALL with a market: the cores bought for the call's job */
} order_t;

struct bga_agent {
    void *ctx, *socket;
    bga_zap_t *zap;         /* with CURVE: the context's ZAP handler */
    bga_service_t *service; /* the worker's while bga_agent_run runs */
    bga_market_t *market;
    int poll_ms;
    char endpoint[BGA_AGENT_ENDPOINT_MAX];
    /* While bga_agent_run runs: the loop's and the worker's ends of their
     * pipe, calls handed over and not answered (the loop's), the jobs the
     * worker holds (published after each message), and the worker's fatal
     * failure, if any (set before it exits). */
    void *pipe, *worker_pipe;
    int queued;
    atomic_int jobs;
    atomic_int worker_failed;
    bg_error_t worker_err;
    /* The caller's own new-epoch callback, told after the worker is. */
    void (*on_new_epoch)(void *ctx, uint64_t previous, uint64_t epoch);
    void *epoch_ctx;
};

static void tell_worker(bga_agent_t *a, int kind, uint64_t job);

/* The broker died and a new one registered this agent: its market seller
 * has dropped the dead broker's deals; the worker drops the jobs' state
 * (ORDER_DROP, queued behind any call it has, ahead of any call the new
 * broker's coordinators make, which need a contract made after this). */
static void agent_new_epoch(void *ctx, uint64_t previous, uint64_t epoch)
{
    bga_agent_t *a = ctx;
    if (a->pipe)
        tell_worker(a, ORDER_DROP, 0);
    if (a->on_new_epoch)
        a->on_new_epoch(a->epoch_ctx, previous, epoch);
}

bg_status bga_agent_new(const bga_agent_config_t *config, bga_agent_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = BG_OK;
    bga_agent_t *a = calloc(1, sizeof *a);
    if (!a)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the agent");
    a->poll_ms = config->poll_ms > 0 ? config->poll_ms : 100;
    atomic_init(&a->jobs, 0);
    atomic_init(&a->worker_failed, 0);
    if ((st = bga_service_new(&config->service, &a->service, err)) != BG_OK)
        goto fail;
    a->ctx = zmq_ctx_new();
    a->socket = a->ctx ? zmq_socket(a->ctx, ZMQ_ROUTER) : NULL;
    if (!a->socket) {
        st = bg_error_set(err, BG_ERR_IO, "cannot create a ZeroMQ socket: %s", zmq_strerror(errno));
        goto fail;
    }
    const int linger = BGA_AGENT_LINGER_MS;
    zmq_setsockopt(a->socket, ZMQ_LINGER, &linger, sizeof linger);
    /* Frames over the codec's cap get an error reply; a frame over twice
     * the cap is refused by the transport before it is buffered whole
     * (ZeroMQ then drops that connection). */
    const bga_limits_t lim =
        config->service.limits.max_frame_bytes ? config->service.limits : bga_wire_default_limits();
    const int64_t maxmsg = (int64_t)(2 * lim.max_frame_bytes);
    zmq_setsockopt(a->socket, ZMQ_MAXMSGSIZE, &maxmsg, sizeof maxmsg);
    if (config->curve) {
        /* The handler first: a CURVE socket of a context without one
         * admits every client that knows its public key. */
        const char *names[] = {"broker"};
        const char *keys[] = {config->broker_key ? config->broker_key : ""};
        const bga_zap_config_t zc = {.names = names,
                                     .keys = keys,
                                     .count = 1,
                                     .whose = "the broker's key (--broker-key)",
                                     .log = config->log,
                                     .log_ctx = config->log_ctx};
        if (!bga_curve_key_valid(config->broker_key)) {
            st = bg_error_set(err, BG_ERR_INVALID, "CURVE needs the broker's public key");
            goto fail;
        }
        if ((st = bga_zap_new(a->ctx, &zc, &a->zap, err)) != BG_OK ||
            (st = bga_curve_server(a->socket, config->curve, err)) != BG_OK ||
            (st = bga_zap_watch(a->zap, a->socket, "compute endpoint", 1, err)) != BG_OK)
            goto fail;
    }
    if (zmq_bind(a->socket, config->listen) != 0) {
        st =
            bg_error_set(err, BG_ERR_IO, "cannot bind %s: %s", config->listen, zmq_strerror(errno));
        goto fail;
    }
    size_t len = sizeof a->endpoint;
    if (zmq_getsockopt(a->socket, ZMQ_LAST_ENDPOINT, a->endpoint, &len) != 0) {
        st =
            bg_error_set(err, BG_ERR_IO, "cannot read the bound endpoint: %s", zmq_strerror(errno));
        goto fail;
    }
    if (config->market) {
        bga_market_config_t mc = *config->market;
        mc.endpoint = a->endpoint;
        mc.name = config->service.name;
        mc.curve = config->curve;
        mc.broker_key = config->broker_key;
        mc.zap = a->zap;
        a->on_new_epoch = mc.on_new_epoch;
        a->epoch_ctx = mc.epoch_ctx;
        mc.on_new_epoch = agent_new_epoch;
        mc.epoch_ctx = a;
        if ((st = bga_market_new(a->ctx, &mc, bg_clock_now(), &a->market, err)) != BG_OK)
            goto fail;
    }
    *out = a;
    return BG_OK;
fail:
    bga_agent_destroy(&a);
    return st;
}

void bga_agent_destroy(bga_agent_t **pa)
{
    if (!pa || !*pa)
        return;
    bga_agent_t *a = *pa;
    if (a->socket)
        zmq_close(a->socket);
    bga_market_destroy(&a->market);
    bga_zap_destroy(&a->zap); /* after the sockets it watched, before the context */
    if (a->ctx)
        zmq_ctx_term(a->ctx);
    bga_service_destroy(&a->service);
    free(a);
    *pa = NULL;
}

const char *bga_agent_endpoint(const bga_agent_t *agent)
{
    return agent->endpoint;
}

bga_service_stats_t bga_agent_stats(const bga_agent_t *agent)
{
    return bga_service_stats(agent->service);
}

const bga_market_t *bga_agent_market(const bga_agent_t *agent)
{
    return agent->market;
}

/* With a market, compute calls need a contract for their job. The header
 * is read in place (job at byte 8, type at byte 6, little-endian); a
 * malformed header is left to the codec's own error reply. Control
 * messages (heartbeat, release) are always served. */
static int refused_for_contract(const bga_agent_t *a, const bga_frame_t *views, int count,
                                uint64_t *job)
{
    if (!a->market || count < 1 || views[0].size != BGA_WIRE_HEADER_BYTES)
        return 0;
    const uint8_t *h = views[0].data;
    const unsigned type = h[6] | (unsigned)h[7] << 8;
    if (type < 0x0100)
        return 0;
    uint64_t id = 0;
    for (int i = 7; i >= 0; i--)
        id = id << 8 | h[8 + i];
    *job = id;
    return !bga_market_holds(a->market, id);
}

/* Sends a refusal or a heartbeat's answer to the peer at route; a peer
 * gone before its reply is not the agent's failure. */
static bg_status answer(bga_agent_t *a, const zmq_msg_t *route, const bga_frames_t *reply,
                        bg_error_t *err)
{
    bg_error_t serr = BG_ERROR_INIT;
    if (bga_send(a->socket, route, reply, &serr) != BG_OK && errno != EHOSTUNREACH)
        return bg_error_set(err, BG_ERR_IO, "%s", serr.message);
    return BG_OK;
}

/* Hands a call to the worker: the order, then the routing id and the
 * request's parts, moved (not copied) onto the inproc pipe. */
static bg_status hand_over(bga_agent_t *a, bga_received_t *r, double cores, bg_error_t *err)
{
    const order_t o = {ORDER_CALL, 0, cores};
    int rc = zmq_send(a->pipe, &o, sizeof o, ZMQ_SNDMORE);
    if (rc >= 0)
        rc = zmq_msg_send(&r->route, a->pipe, r->count > 0 ? ZMQ_SNDMORE : 0);
    for (int i = 0; rc >= 0 && i < r->count; i++)
        rc = zmq_msg_send(&r->part[i], a->pipe, i + 1 < r->count ? ZMQ_SNDMORE : 0);
    if (rc < 0)
        return bg_error_set(err, BG_ERR_IO, "cannot hand a call to the worker: %s",
                            zmq_strerror(errno));
    a->queued++;
    return BG_OK;
}

static void tell_worker(bga_agent_t *a, int kind, uint64_t job)
{
    const order_t o = {kind, job, 0.0};
    (void)zmq_send(a->pipe, &o, sizeof o, 0);
}

/*
 * One message from the socket: a heartbeat is answered here, at once; a
 * message with more parts than any schema, a call without a contract and,
 * past BGA_AGENT_QUEUE_MAX calls waiting (or once stopping), any call are
 * refused here, quoting the request's header; the rest goes to the worker.
 */
static bg_status serve_socket(bga_agent_t *a, int stopping, bg_error_t *err)
{
    bga_received_t r;
    bg_error_t rerr = BG_ERROR_INIT;
    bg_status st = bga_recv(a->socket, 1, &r, &rerr);
    if (st == BG_ERR_UNSUPPORTED)
        return BG_OK; /* a signal: the caller looks at the stop flag */
    if (st != BG_OK)
        return bg_error_set(err, st, "%s", rerr.message);
    bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
    bga_received_view(&r, views);
    bga_frames_t reply;
    bga_wire_error_t werr;
    uint64_t job = 0;
    int answered = 1;
    if (r.total > r.count) {
        bga_wire_fail(&werr, BGA_WIRE_FRAME_COUNT, -1, "",
                      "%d frames, no message type has "
                      "more than %d",
                      r.total, BGA_WIRE_MAX_FRAMES);
        st = bga_service_refuse(views, r.count, &werr, &reply, err);
    } else if (bga_service_heartbeat(a->service, atomic_load(&a->jobs), views, r.count, &reply,
                                     &job, &rerr) == BG_OK) {
        if (job != 0)
            tell_worker(a, ORDER_TOUCH, job);
    } else if (refused_for_contract(a, views, r.count, &job)) {
        bga_wire_fail(&werr, BGA_WIRE_NO_JOB, 0, "job",
                      "agent holds no contract for job %llu: buy it on the market first",
                      (unsigned long long)job);
        st = bga_service_refuse(views, r.count, &werr, &reply, err);
    } else if (stopping || a->queued >= BGA_AGENT_QUEUE_MAX) {
        bga_wire_fail(&werr, BGA_WIRE_BUSY, 0, "type",
                      stopping ? "the agent is stopping: it takes no more calls"
                               : "%d calls are queued on this agent: try again later",
                      a->queued);
        st = bga_service_refuse(views, r.count, &werr, &reply, err);
    } else {
        answered = 0;
        st = hand_over(a, &r, a->market ? bga_market_cores(a->market, job) : 0.0, err);
    }
    if (answered && st == BG_OK) {
        st = answer(a, &r.route, &reply, err);
        bga_frames_free(&reply);
    }
    bga_received_close(&r);
    /* No reply could be built (memory): the peer's timeout covers it. */
    return st == BG_ERR_NOMEM ? BG_OK : st;
}

/* A reply from the worker goes to its peer: the routing id and the
 * reply's parts, moved. An empty reply (no memory to build one) is not
 * sent; the peer's timeout covers it. */
static bg_status relay(bga_agent_t *a, bg_error_t *err)
{
    bga_received_t r;
    bg_error_t rerr = BG_ERROR_INIT;
    bg_status st = bga_recv(a->pipe, 1, &r, &rerr);
    if (st == BG_ERR_UNSUPPORTED)
        return BG_OK;
    if (st != BG_OK)
        return bg_error_set(err, st, "worker pipe: %s", rerr.message);
    a->queued--;
    int rc = 0;
    if (r.count > 0 && zmq_msg_size(&r.part[0]) > 0) {
        rc = zmq_msg_send(&r.route, a->socket, ZMQ_SNDMORE);
        for (int i = 0; rc >= 0 && i < r.count; i++)
            rc = zmq_msg_send(&r.part[i], a->socket, i + 1 < r.count ? ZMQ_SNDMORE : 0);
    }
    /* A peer gone before its reply is not the agent's failure. */
    if (rc < 0 && errno != EHOSTUNREACH)
        st = bg_error_set(err, BG_ERR_IO, "send failed: %s", zmq_strerror(errno));
    bga_received_close(&r);
    return st;
}

/* ------------------------------------------------------------- worker */

static void publish_jobs(bga_agent_t *a)
{
    atomic_store(&a->jobs, bga_service_jobs(a->service));
}

/* One call: decode, compute, reply to the loop with the routing id first. */
static bg_status work_one(bga_agent_t *a, const order_t *o, bg_error_t *err)
{
    bga_received_t r;
    bg_status st = bga_recv(a->worker_pipe, 1, &r, err);
    if (st != BG_OK)
        return st;
    bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
    bga_received_view(&r, views);
    if (a->market)
        bga_market_limit_threads(a->market, o->cores);
    bga_frames_t reply;
    bg_error_t herr = BG_ERROR_INIT;
    const bg_status hs = bga_service_handle(a->service, views, r.count, bg_clock_now(), &reply,
                                            &herr);
    if (hs == BG_OK) {
        st = bga_send(a->worker_pipe, &r.route, &reply, err);
        bga_frames_free(&reply);
    } else if (zmq_msg_send(&r.route, a->worker_pipe, ZMQ_SNDMORE) < 0 ||
               zmq_send(a->worker_pipe, "", 0, 0) < 0) {
        /* No reply could be built: an empty one still tells the loop the
         * call is done. */
        st = bg_error_set(err, BG_ERR_IO, "worker pipe: %s", zmq_strerror(errno));
    }
    bga_received_close(&r);
    return st;
}

static void *worker_main(void *arg)
{
    bga_agent_t *a = arg;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = BG_OK;
    for (;;) {
        zmq_pollitem_t item = {a->worker_pipe, 0, ZMQ_POLLIN, 0};
        const int rc = zmq_poll(&item, 1, a->poll_ms);
        if (bga_service_expire(a->service, bg_clock_now()) > 0)
            publish_jobs(a);
        if (rc < 0 && errno == EINTR)
            continue;
        if (rc < 0) {
            st = bg_error_set(&err, BG_ERR_IO, "worker: poll failed: %s", zmq_strerror(errno));
            break;
        }
        if (rc == 0)
            continue;
        order_t o;
        const int n = zmq_recv(a->worker_pipe, &o, sizeof o, 0);
        if (n != (int)sizeof o) {
            st = bg_error_set(&err, BG_ERR_IO, "worker: malformed order on its pipe");
            break;
        }
        if (o.kind == ORDER_STOP)
            break;
        if (o.kind == ORDER_TOUCH) {
            bga_service_touch(a->service, o.job, bg_clock_now());
            continue;
        }
        if (o.kind == ORDER_DROP) {
            if (bga_service_drop_all(a->service) > 0)
                publish_jobs(a);
            continue;
        }
        if ((st = work_one(a, &o, &err)) != BG_OK)
            break;
        publish_jobs(a);
    }
    if (st != BG_OK) {
        a->worker_err = err;
        atomic_store(&a->worker_failed, 1);
    }
    return NULL;
}

/* The worker's end of the pipe and its thread, with every signal blocked
 * there: the daemon's stop signal reaches the loop. */
static bg_status start_worker(bga_agent_t *a, pthread_t *thread, bg_error_t *err)
{
    char name[64];
    snprintf(name, sizeof name, "inproc://bga-agent-%p", (void *)a);
    a->pipe = zmq_socket(a->ctx, ZMQ_PAIR);
    a->worker_pipe = zmq_socket(a->ctx, ZMQ_PAIR);
    if (!a->pipe || !a->worker_pipe || zmq_bind(a->pipe, name) != 0 ||
        zmq_connect(a->worker_pipe, name) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot create the worker's pipe: %s",
                            zmq_strerror(errno));
    const int linger = 0;
    zmq_setsockopt(a->pipe, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(a->worker_pipe, ZMQ_LINGER, &linger, sizeof linger);
    publish_jobs(a);
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    const int rc = pthread_create(thread, NULL, worker_main, a);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc != 0)
        return bg_error_set(err, BG_ERR_NOMEM, "cannot start the agent's worker thread");
    return BG_OK;
}

static void close_pipes(bga_agent_t *a)
{
    if (a->pipe)
        zmq_close(a->pipe);
    if (a->worker_pipe)
        zmq_close(a->worker_pipe);
    a->pipe = a->worker_pipe = NULL;
}

/* ---------------------------------------------------------------- loop */

/* Waits up to wait_ms for the socket, the worker or the market, and serves
 * what came. */
static bg_status loop_once(bga_agent_t *a, int wait_ms, int stopping, bg_error_t *err)
{
    zmq_pollitem_t items[3] = {{a->socket, 0, ZMQ_POLLIN, 0},
                               {a->pipe, 0, ZMQ_POLLIN, 0},
                               {a->market ? bga_market_socket(a->market) : NULL, 0, ZMQ_POLLIN,
                                0}};
    const int rc = zmq_poll(items, a->market ? 3 : 2, wait_ms);
    if (rc < 0) {
        if (errno == EINTR)
            return BG_OK;
        return bg_error_set(err, BG_ERR_IO, "poll failed: %s", zmq_strerror(errno));
    }
    bg_status st = BG_OK;
    if (rc > 0 && (items[1].revents & ZMQ_POLLIN))
        st = relay(a, err);
    if (st == BG_OK && rc > 0 && (items[0].revents & ZMQ_POLLIN))
        st = serve_socket(a, stopping, err);
    if (st == BG_OK && a->market) {
        /* The broker being away is not the agent's failure: it keeps
         * serving and re-registers when the broker answers again. */
        bg_error_t merr = BG_ERROR_INIT;
        if (rc > 0 && (items[2].revents & ZMQ_POLLIN))
            bga_market_on_readable(a->market, bg_clock_now(), &merr);
        bga_market_tick(a->market, bg_clock_now(), &merr);
    }
    if (st == BG_OK && atomic_load(&a->worker_failed))
        st = bg_error_set(err, a->worker_err.status, "%s", a->worker_err.message);
    return st;
}

bg_status bga_agent_run(bga_agent_t *a, const volatile sig_atomic_t *stop, bg_error_t *err)
{
    pthread_t worker;
    bg_status st = start_worker(a, &worker, err);
    if (st != BG_OK) {
        close_pipes(a);
        return st;
    }
    while (st == BG_OK && !*stop)
        st = loop_once(a, a->poll_ms, 0, err);
    /* Stopping: requests already received are handed over, then every
     * call the worker has is answered (pings too, meanwhile); later calls
     * are refused. */
    for (int i = 0; st == BG_OK && i < BGA_AGENT_DRAIN_MAX; i++) {
        zmq_pollitem_t item = {a->socket, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            break;
        st = serve_socket(a, 0, err);
    }
    while (st == BG_OK && a->queued > 0)
        st = loop_once(a, a->poll_ms, 1, err);
    tell_worker(a, ORDER_STOP, 0);
    pthread_join(worker, NULL);
    close_pipes(a);
    return st;
}
