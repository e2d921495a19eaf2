#include "bga_agent.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bga_transport.h"

struct bga_agent {
    void *ctx, *socket;
    bga_service_t *service;
    bga_market_t *market;
    int poll_ms;
    char endpoint[BGA_AGENT_ENDPOINT_MAX];
};

bg_status bga_agent_new(const bga_agent_config_t *config, bga_agent_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = BG_OK;
    bga_agent_t *a = calloc(1, sizeof *a);
    if (!a)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the agent");
    a->poll_ms = config->poll_ms > 0 ? config->poll_ms : 100;
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
    return !bga_market_admit(a->market, id);
}

/* One request: decode, compute, reply. A message with more parts than any
 * schema is answered here, without decoding. */
static bg_status serve_one(bga_agent_t *a, bg_error_t *err)
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
    /* Both refusals quote the request's header (job, seq), as the
     * service's own do: the peer sees the agent's message at once. */
    if (r.total > r.count) {
        bga_wire_fail(&werr, BGA_WIRE_FRAME_COUNT, -1, "",
                      "%d frames, no message type has "
                      "more than %d",
                      r.total, BGA_WIRE_MAX_FRAMES);
        st = bga_service_refuse(views, r.count, &werr, &reply, err);
    } else if (refused_for_contract(a, views, r.count, &job)) {
        bga_wire_fail(&werr, BGA_WIRE_NO_JOB, 0, "job",
                      "agent holds no contract for job %llu: buy it on the market first",
                      (unsigned long long)job);
        st = bga_service_refuse(views, r.count, &werr, &reply, err);
    } else {
        st = bga_service_handle(a->service, views, r.count, bg_clock_now(), &reply, err);
    }
    if (st == BG_OK) {
        bg_error_t serr = BG_ERROR_INIT;
        /* A peer gone before its reply is not the agent's failure. */
        if (bga_send(a->socket, &r.route, &reply, &serr) != BG_OK && errno != EHOSTUNREACH)
            st = bg_error_set(err, BG_ERR_IO, "%s", serr.message);
        bga_frames_free(&reply);
    }
    bga_received_close(&r);
    return st;
}

bg_status bga_agent_run(bga_agent_t *a, const volatile sig_atomic_t *stop, bg_error_t *err)
{
    while (!*stop) {
        zmq_pollitem_t items[2] = {{a->socket, 0, ZMQ_POLLIN, 0},
                                   {a->market ? bga_market_socket(a->market) : NULL, 0,
                                    ZMQ_POLLIN, 0}};
        const int rc = zmq_poll(items, a->market ? 2 : 1, a->poll_ms);
        if (rc < 0) {
            if (errno == EINTR)
                continue;
            return bg_error_set(err, BG_ERR_IO, "poll failed: %s", zmq_strerror(errno));
        }
        if (rc > 0 && (items[0].revents & ZMQ_POLLIN)) {
            bg_status st = serve_one(a, err);
            if (st != BG_OK && st != BG_ERR_NOMEM)
                return st;
        }
        if (a->market) {
            /* The broker being away is not the agent's failure: it keeps
             * serving and re-registers when the broker answers again. */
            bg_error_t merr = BG_ERROR_INIT;
            if (rc > 0 && (items[1].revents & ZMQ_POLLIN))
                bga_market_on_readable(a->market, bg_clock_now(), &merr);
            bga_market_tick(a->market, bg_clock_now(), &merr);
        }
        bga_service_expire(a->service, bg_clock_now());
    }
    /* Stopping: requests already received are answered, then nothing more. */
    for (int i = 0; i < BGA_AGENT_DRAIN_MAX; i++) {
        zmq_pollitem_t item = {a->socket, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            break;
        bg_status st = serve_one(a, err);
        if (st != BG_OK && st != BG_ERR_NOMEM)
            return st;
    }
    return BG_OK;
}
