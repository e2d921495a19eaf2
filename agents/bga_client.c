#include "bga_client.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bg_clock.h"

struct bga_client {
    void *ctx, *socket;
    char endpoint[256];
    char service[48];
    int timeout_ms;
    uint64_t seq;
    bga_traffic_t traffic;
    /* The request in flight (pending = 0: none). */
    int pending;
    uint64_t pending_seq;
    uint16_t pending_type;
    unsigned pending_want;
    double pending_sent;
    uint64_t pending_job;
    /* Liveness (bga_client_set_liveness) and what the last wait saw. */
    int ping_ms, lost_ms;
    bga_client_failure_t failure;
    int64_t late; /* replies to abandoned requests, discarded */
};

bg_status bga_client_new(const char *endpoint, const char *service, int timeout_ms,
                         bga_client_t **out, bg_error_t *err)
{
    return bga_client_new_curve(endpoint, service, timeout_ms, NULL, out, err);
}

bg_status bga_client_new_curve(const char *endpoint, const char *service, int timeout_ms,
                               const bga_curve_peers_t *curve, bga_client_t **out, bg_error_t *err)
{
    *out = NULL;
    bga_client_t *c = calloc(1, sizeof *c);
    if (!c)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating a client");
    snprintf(c->endpoint, sizeof c->endpoint, "%s", endpoint);
    snprintf(c->service, sizeof c->service, "%s", service ? service : "agent");
    c->timeout_ms = timeout_ms > 0 ? timeout_ms : 10000;
    c->ping_ms = BGA_CLIENT_PING_MS;
    c->lost_ms = BGA_CLIENT_LOST_MS;
    bg_status st = BG_OK;
    c->ctx = zmq_ctx_new();
    c->socket = c->ctx ? zmq_socket(c->ctx, ZMQ_DEALER) : NULL;
    if (!c->socket) {
        st = bg_error_set(err, BG_ERR_IO, "agent %s (%s): cannot create a socket: %s", endpoint,
                          c->service, zmq_strerror(errno));
        goto fail;
    }
    const int linger = 0; /* a request to a dead agent must not hold the exit */
    zmq_setsockopt(c->socket, ZMQ_LINGER, &linger, sizeof linger);
    /* A send never blocks longer than a reply may take. */
    zmq_setsockopt(c->socket, ZMQ_SNDTIMEO, &c->timeout_ms, sizeof c->timeout_ms);
    if (curve) {
        char key[BGA_CURVE_KEY_SIZE];
        bg_error_t kerr = BG_ERROR_INIT;
        if ((st = curve->key_of(curve->ctx, endpoint, key, &kerr)) == BG_OK)
            st = bga_curve_client(c->socket, curve->self, key, &kerr);
        if (st != BG_OK) {
            bg_error_set(err, st, "agent %s (%s): %s", endpoint, c->service, kerr.message);
            goto fail;
        }
    }
    if (zmq_connect(c->socket, endpoint) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "agent %s (%s): cannot connect: %s", endpoint, c->service,
                          zmq_strerror(errno));
        goto fail;
    }
    *out = c;
    return BG_OK;
fail:
    bga_client_destroy(&c);
    return st;
}

void bga_client_destroy(bga_client_t **pc)
{
    if (!pc || !*pc)
        return;
    bga_client_t *c = *pc;
    if (c->socket)
        zmq_close(c->socket);
    if (c->ctx)
        zmq_ctx_term(c->ctx);
    free(c);
    *pc = NULL;
}

const char *bga_client_endpoint(const bga_client_t *c)
{
    return c->endpoint;
}

bga_traffic_t bga_client_traffic(const bga_client_t *c)
{
    return c->traffic;
}

void bga_reply_close(bga_reply_t *rep)
{
    bga_received_close(&rep->frames);
}

void bga_client_set_liveness(bga_client_t *c, int ping_ms, int lost_ms)
{
    c->ping_ms = ping_ms > 0 && lost_ms > 0 ? ping_ms : 0;
    c->lost_ms = ping_ms > 0 && lost_ms > 0 ? lost_ms : 0;
}

bga_client_failure_t bga_client_failure(const bga_client_t *c)
{
    return c->failure;
}

int64_t bga_client_late_answers(const bga_client_t *c)
{
    return c->late;
}

/* A ping for the request in flight (its job's lease is renewed too); sent
 * without blocking: a ping that cannot leave now is skipped. */
static void ping(bga_client_t *c)
{
    bga_msg_t m;
    bga_frames_t frames;
    bg_error_t ignored = BG_ERROR_INIT;
    bga_msg_init(&m, BGA_HEARTBEAT, c->pending_job, ++c->seq);
    if (bga_wire_encode(&m, &frames, &ignored) != BG_OK)
        return;
    for (int i = 0; i < frames.count; i++)
        if (zmq_send(c->socket, frames.data[i], frames.size[i],
                     ZMQ_DONTWAIT | (i + 1 < frames.count ? ZMQ_SNDMORE : 0)) < 0)
            break;
    bga_frames_free(&frames);
}

static bg_status silent(bga_client_t *c, bga_client_failure_t why, bg_status st)
{
    c->failure = why;
    return st;
}

/*
 * Waits for the reply to `seq` (any reply when raw) until the request's
 * timeout from t_sent. While it waits it pings the agent every ping_ms and
 * gives up once the agent has been silent for lost_ms (silence is counted
 * from the start of this wait: a pool collects its agents one after
 * another). Any message from the agent is a sign of life; a reply to an
 * abandoned request is discarded and counted, a pong dropped.
 */
static bg_status await_reply(bga_client_t *c, uint64_t seq, int raw, uint16_t type, double t_sent,
                             bga_reply_t *rep, bg_error_t *err)
{
    const double deadline = t_sent + c->timeout_ms / 1000.0;
    const int pinging = !raw && c->lost_ms > 0;
    const double ping_s = c->ping_ms / 1000.0, lost_s = c->lost_ms / 1000.0;
    double heard = bg_clock_now(), next_ping = heard + ping_s;
    c->failure = BGA_CLIENT_FINE;
    for (;;) {
        const double now = bg_clock_now();
        if (pinging && now - heard >= lost_s)
            return silent(c, BGA_CLIENT_LOST,
                          bg_error_set(err, BG_ERR_IO,
                                       "agent %s (%s): lost: no answer to heartbeats for %d ms "
                                       "while waiting for the reply to %s",
                                       c->endpoint, c->service, c->lost_ms, bga_type_name(type)));
        if (now >= deadline)
            return silent(c, BGA_CLIENT_TIMED_OUT,
                          bg_error_set(err, BG_ERR_IO, "agent %s (%s): no reply to %s within %d ms",
                                       c->endpoint, c->service, bga_type_name(type),
                                       c->timeout_ms));
        if (pinging && now >= next_ping) {
            ping(c);
            next_ping = now + ping_s;
        }
        double until = deadline;
        if (pinging) {
            until = next_ping < until ? next_ping : until;
            until = heard + lost_s < until ? heard + lost_s : until;
        }
        zmq_pollitem_t item = {c->socket, 0, ZMQ_POLLIN, 0};
        const double left = until - now;
        const int rc = left > 0.0 ? zmq_poll(&item, 1, (long)(left * 1000.0) + 1) : 0;
        if (rc < 0 && errno == EINTR)
            continue;
        if (rc < 0)
            return silent(c, BGA_CLIENT_BROKEN,
                          bg_error_set(err, BG_ERR_IO, "agent %s (%s): poll failed: %s",
                                       c->endpoint, c->service, zmq_strerror(errno)));
        if (rc == 0)
            continue;
        bg_error_t rerr = BG_ERROR_INIT;
        bg_status st = bga_recv(c->socket, 0, &rep->frames, &rerr);
        if (st == BG_ERR_UNSUPPORTED)
            continue;
        if (st != BG_OK)
            return silent(c, BGA_CLIENT_BROKEN,
                          bg_error_set(err, st, "agent %s (%s): %s", c->endpoint, c->service,
                                       rerr.message));
        const double t_got = bg_clock_now();
        heard = t_got;
        bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&rep->frames, views);
        bga_wire_error_t werr;
        const bga_wire_code wc =
            rep->frames.total > rep->frames.count
                ? BGA_WIRE_FRAME_COUNT
                : bga_wire_decode(views, rep->frames.count, NULL, &rep->msg, &werr);
        c->traffic.bytes_received += (int64_t)rep->frames.bytes;
        c->traffic.encode_seconds += bg_clock_now() - t_got;
        if (wc != BGA_WIRE_OK) {
            bga_received_close(&rep->frames);
            return bg_error_set(err, BG_ERR_PARSE, "agent %s (%s): malformed reply to %s: %s",
                                c->endpoint, c->service, bga_type_name(type),
                                wc == BGA_WIRE_FRAME_COUNT && rep->frames.total ? "too many frames"
                                                                                : werr.message);
        }
        /* An ERROR that quotes no sequence number comes from an agent that
         * could not read the request's header: with one request in flight
         * it is that request's answer, shown at once rather than waited
         * past (requests are numbered from 1, so no reply quotes 0). */
        if (raw || rep->msg.header.seq == seq ||
            (rep->msg.header.type == BGA_ERROR && rep->msg.header.seq == 0)) {
            c->traffic.wait_seconds += t_got - t_sent;
            return BG_OK;
        }
        /* A pong, or a late reply to an abandoned request. */
        if (rep->msg.header.type != BGA_HEARTBEAT)
            c->late++;
        bga_received_close(&rep->frames);
    }
}

int64_t bga_client_drain(bga_client_t *c)
{
    const int64_t before = c->late;
    for (;;) {
        zmq_pollitem_t item = {c->socket, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            break;
        bga_received_t r;
        bg_error_t ignored = BG_ERROR_INIT;
        if (bga_recv(c->socket, 0, &r, &ignored) != BG_OK)
            break;
        bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&r, views);
        bga_msg_t m;
        bga_wire_error_t werr;
        if (r.total == r.count && bga_wire_decode(views, r.count, NULL, &m, &werr) == BGA_WIRE_OK &&
            m.header.type != BGA_HEARTBEAT)
            c->late++;
        bga_received_close(&r);
    }
    return c->late - before;
}

bg_status bga_client_post(bga_client_t *c, bga_msg_t *req, bg_error_t *err)
{
    if (c->pending)
        return bg_error_set(err, BG_ERR_INVALID, "agent %s (%s): %s posted while %s is in flight",
                            c->endpoint, c->service, bga_type_name(req->header.type),
                            bga_type_name(c->pending_type));
    req->header.seq = ++c->seq;
    const double t0 = bg_clock_now();
    bga_frames_t frames;
    bg_error_t eerr = BG_ERROR_INIT;
    if (bga_wire_encode(req, &frames, &eerr) != BG_OK)
        return bg_error_set(err, eerr.status, "agent %s (%s): %s", c->endpoint, c->service,
                            eerr.message);
    const double t1 = bg_clock_now();
    c->traffic.encode_seconds += t1 - t0;
    c->traffic.requests++;
    c->traffic.bytes_sent += (int64_t)bga_frames_bytes(&frames);
    bg_status st = bga_send(c->socket, NULL, &frames, &eerr);
    bga_frames_free(&frames);
    c->failure = st == BG_OK ? BGA_CLIENT_FINE : BGA_CLIENT_BROKEN;
    if (st != BG_OK)
        return bg_error_set(err, st, "agent %s (%s): %s", c->endpoint, c->service, eerr.message);
    c->pending = 1;
    c->pending_seq = req->header.seq;
    c->pending_type = req->header.type;
    c->pending_job = req->header.job;
    c->pending_sent = t1;
    return BG_OK;
}

bg_status bga_client_collect(bga_client_t *c, bga_reply_t *rep, bg_error_t *err)
{
    memset(rep, 0, sizeof *rep);
    if (!c->pending)
        return bg_error_set(err, BG_ERR_INVALID, "agent %s (%s): nothing to collect", c->endpoint,
                            c->service);
    c->pending = 0;
    return await_reply(c, c->pending_seq, 0, c->pending_type, c->pending_sent, rep, err);
}

bg_status bga_client_request(bga_client_t *c, bga_msg_t *req, bga_reply_t *rep, bg_error_t *err)
{
    memset(rep, 0, sizeof *rep);
    bg_status st = bga_client_post(c, req, err);
    return st == BG_OK ? bga_client_collect(c, rep, err) : st;
}

bg_status bga_client_request_raw(bga_client_t *c, const bga_frame_t *frames, int nframes,
                                 bga_reply_t *rep, bg_error_t *err)
{
    memset(rep, 0, sizeof *rep);
    bg_error_t eerr = BG_ERROR_INIT;
    const double t1 = bg_clock_now();
    bg_status st = bga_send_views(c->socket, frames, nframes, &eerr);
    if (st != BG_OK)
        return bg_error_set(err, st, "agent %s (%s): %s", c->endpoint, c->service, eerr.message);
    c->traffic.requests++;
    return await_reply(c, 0, 1, 0, t1, rep, err);
}

/* A decoded text array as a C string, cut to cap − 1 bytes. */
static void copy_text(char *dst, size_t cap, const bga_array_t *a)
{
    const size_t n = a->count < cap ? a->count : cap - 1;
    if (n > 0)
        memcpy(dst, a->data, n);
    dst[n] = 0;
}

/* What an agent's refusal means to the caller: a job the agent does not
 * hold (never set up, released, no contract) is not found; a busy agent or
 * a call out of order conflicts with its state; its own failures are
 * numeric or I/O; a request it cannot read is invalid (or over a cap). */
static bg_status refusal_status(bga_wire_code code)
{
    switch (code) {
    case BGA_WIRE_NO_JOB: return BG_ERR_NOT_FOUND;
    case BGA_WIRE_BUSY:
    case BGA_WIRE_WRONG_STATE: return BG_ERR_CONFLICT;
    case BGA_WIRE_NUMERIC: return BG_ERR_NUMERIC;
    case BGA_WIRE_INTERNAL: return BG_ERR_IO;
    case BGA_WIRE_OVERSIZE: return BG_ERR_LIMIT;
    case BGA_WIRE_UNKNOWN_TYPE:
    case BGA_WIRE_WRONG_VERSION:
    case BGA_WIRE_UNEXPECTED: return BG_ERR_UNSUPPORTED;
    default: return BG_ERR_INVALID;
    }
}

/* Turns an ERROR reply or a reply of the wrong type into a message that
 * names the agent, the service and the request, with the status of
 * refusal_status. */
static bg_status expect(bga_client_t *c, const bga_reply_t *rep, uint16_t req_type, uint16_t want,
                        bg_error_t *err)
{
    const bga_msg_t *m = &rep->msg;
    if (m->header.type == want)
        return BG_OK;
    if (m->header.type == BGA_ERROR) {
        char field[64], text[BG_ERROR_MESSAGE_MAX];
        copy_text(field, sizeof field, &m->array[BGA_ERR_FIELD]);
        copy_text(text, sizeof text, &m->array[BGA_ERR_MESSAGE]);
        return bg_error_set(err, refusal_status((bga_wire_code)m->field[BGA_ERR_CODE].i),
                            "agent %s (%s): %s refused: %s (frame %lld%s%s): "
                            "%s",
                            c->endpoint, c->service, bga_type_name(req_type),
                            bga_wire_code_name((bga_wire_code)m->field[BGA_ERR_CODE].i),
                            (long long)m->field[BGA_ERR_FRAME].i, field[0] ? ", " : "", field,
                            text);
    }
    return bg_error_set(err, BG_ERR_PARSE, "agent %s (%s): %s answered with %s, expected %s",
                        c->endpoint, c->service, bga_type_name(req_type),
                        bga_type_name(m->header.type), bga_type_name(want));
}

/* One typed exchange: request, then the reply checked for `want`. */
static bg_status exchange(bga_client_t *c, bga_msg_t *req, uint16_t want, bga_reply_t *rep,
                          bg_error_t *err)
{
    bg_status st = bga_client_request(c, req, rep, err);
    if (st != BG_OK)
        return st;
    st = expect(c, rep, req->header.type, want, err);
    if (st != BG_OK)
        bga_reply_close(rep);
    return st;
}

/* Copies reply array a (count values) into dst of capacity cap. */
static bg_status take_f64(bga_client_t *c, const bga_reply_t *rep, int a, double *dst, size_t cap,
                          const char *what, bg_error_t *err)
{
    const size_t n = rep->msg.array[a].count;
    if (n != cap)
        return bg_error_set(err, BG_ERR_PARSE, "agent %s (%s): %s has %zu values, expected %zu",
                            c->endpoint, c->service, what, n, cap);
    bga_msg_copy_f64(&rep->msg, a, dst);
    return BG_OK;
}

bg_status bga_client_heartbeat(bga_client_t *c, uint64_t job, bga_agent_status_t *st,
                               bg_error_t *err)
{
    bga_msg_t req;
    bga_reply_t rep;
    bga_msg_init(&req, BGA_HEARTBEAT, job, 0);
    bg_status s = exchange(c, &req, BGA_HEARTBEAT, &rep, err);
    if (s != BG_OK)
        return s;
    if (st) {
        memset(st, 0, sizeof *st);
        st->slots = rep.msg.field[BGA_HB_SLOTS].i;
        st->free_slots = rep.msg.field[BGA_HB_FREE].i;
        st->jobs = rep.msg.field[BGA_HB_JOBS].i;
        st->services = (unsigned)rep.msg.field[BGA_HB_SERVICES].i;
        copy_text(st->name, sizeof st->name, &rep.msg.array[BGA_HB_NAME]);
    }
    bga_reply_close(&rep);
    return BG_OK;
}

static bg_status simple(bga_client_t *c, bga_msg_t *req, bg_error_t *err)
{
    bga_reply_t rep;
    bg_status st = exchange(c, req, BGA_ACK, &rep, err);
    if (st == BG_OK)
        bga_reply_close(&rep);
    return st;
}

bg_status bga_client_rotfit_setup(bga_client_t *c, uint64_t job, const bga_partition_t *p,
                                  bg_error_t *err)
{
    bg_status st = bga_client_rotfit_setup_start(c, job, p, err);
    return st == BG_OK ? bga_client_rotfit_setup_finish(c, err) : st;
}

bg_status bga_client_rotfit_setup_finish(bga_client_t *c, bg_error_t *err)
{
    const uint16_t type = c->pending_type;
    bga_reply_t rep;
    bg_status st = bga_client_collect(c, &rep, err);
    if (st != BG_OK)
        return st;
    st = expect(c, &rep, type, BGA_ACK, err);
    bga_reply_close(&rep);
    return st;
}

bg_status bga_client_rotfit_setup_start(bga_client_t *c, uint64_t job, const bga_partition_t *p,
                                        bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_ROTFIT_SETUP, job, 0);
    const int k = p->dim + 1, local = k * p->dim;
    m.field[BGA_RS_DIM].i = p->dim;
    m.field[BGA_RS_NODES].i = k;
    m.field[BGA_RS_NV].i = p->nv;
    m.field[BGA_RS_NE].i = p->ne;
    m.field[BGA_RS_NGLOBAL].i = p->nglobal;
    m.field[BGA_RS_MU].f = p->mu;
    m.field[BGA_RS_LAMBDA].f = p->lambda;
    m.field[BGA_RS_BARRIER].f = p->barrier;
    m.field[BGA_RS_BLOCK].i = local * (local + 1) / 2;
    m.field[BGA_RS_NVAL].i = p->scatter ? p->nval : 0;
    m.field[BGA_RS_LEASE_MS].i = p->lease_ms;
    m.array[BGA_RS_ELEMENTS] = (bga_array_t){p->elements, (size_t)p->ne * k};
    m.array[BGA_RS_LOCAL_TO_GLOBAL] = (bga_array_t){p->local_to_global, (size_t)p->nv};
    if (p->rest_positions)
        m.array[BGA_RS_REST_POSITIONS] = (bga_array_t){p->rest_positions, (size_t)p->nv * p->dim};
    if (p->rest_edges)
        m.array[BGA_RS_REST_EDGES] = (bga_array_t){p->rest_edges, (size_t)p->ne * p->dim * p->dim};
    if (p->scatter)
        m.array[BGA_RS_SCATTER] =
            (bga_array_t){p->scatter, (size_t)p->ne * (size_t)m.field[BGA_RS_BLOCK].i};
    return bga_client_post(c, &m, err);
}

bg_status bga_client_surface_setup(bga_client_t *c, uint64_t job, const bga_surface_part_t *p,
                                   bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_SURF_SETUP, job, 0);
    m.field[BGA_SU_NV].i = p->nv;
    m.field[BGA_SU_NE].i = p->ne;
    m.field[BGA_SU_NGLOBAL].i = p->nglobal;
    m.field[BGA_SU_NOWNED].i = p->nowned;
    m.field[BGA_SU_LEASE_MS].i = p->lease_ms;
    m.array[BGA_SU_TRIANGLES] = (bga_array_t){p->triangles, (size_t)p->ne * 3};
    m.array[BGA_SU_LOCAL_TO_GLOBAL] = (bga_array_t){p->local_to_global, (size_t)p->nv};
    m.array[BGA_SU_REST_POSITIONS] = (bga_array_t){p->rest_positions, (size_t)p->nv * 3};
    m.array[BGA_SU_OWNED] = (bga_array_t){p->owned, (size_t)p->nowned};
    return simple(c, &m, err);
}

bg_status bga_client_rotfit_start(bga_client_t *c, uint64_t job, const double *positions,
                                  size_t count, unsigned want, bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_ROTFIT_CALL, job, 0);
    m.field[BGA_RC_WANT].i = want;
    m.array[BGA_RC_POSITIONS] = (bga_array_t){positions, count};
    bg_status st = bga_client_post(c, &m, err);
    if (st == BG_OK)
        c->pending_want = want;
    return st;
}

bg_status bga_client_rotfit_finish(bga_client_t *c, bga_rotfit_out_t *out, bg_error_t *err)
{
    const unsigned want = c->pending_want;
    bga_reply_t rep;
    bg_status st = bga_client_collect(c, &rep, err);
    if (st != BG_OK)
        return st;
    if ((st = expect(c, &rep, BGA_ROTFIT_CALL, BGA_ROTFIT_RESULT, err)) != BG_OK) {
        bga_reply_close(&rep);
        return st;
    }
    out->energy = rep.msg.field[BGA_RR_ENERGY].f;
    out->fits.calls = rep.msg.field[BGA_RR_FITS].i;
    out->fits.warm = rep.msg.field[BGA_RR_WARM].i;
    out->fits.polar = rep.msg.field[BGA_RR_POLAR].i;
    out->fits.svd = rep.msg.field[BGA_RR_SVD].i;
    out->agent_seconds = rep.msg.field[BGA_RR_SECONDS].f;
    c->traffic.agent_seconds += out->agent_seconds;
    const double t0 = bg_clock_now();
    if (want & BGA_WANT_GRADIENT)
        st =
            take_f64(c, &rep, BGA_RR_GRADIENT, out->gradient, out->gradient_count, "gradient", err);
    if (st == BG_OK && (want & BGA_WANT_HESSIAN))
        st = take_f64(c, &rep, BGA_RR_HESSIAN, out->hessian, out->hessian_count, "Hessian", err);
    c->traffic.encode_seconds += bg_clock_now() - t0;
    bga_reply_close(&rep);
    return st;
}

bg_status bga_client_rotfit(bga_client_t *c, uint64_t job, const double *positions, size_t count,
                            unsigned want, bga_rotfit_out_t *out, bg_error_t *err)
{
    bg_status st = bga_client_rotfit_start(c, job, positions, count, want, err);
    return st == BG_OK ? bga_client_rotfit_finish(c, out, err) : st;
}

bg_status bga_client_solve_setup(bga_client_t *c, uint64_t job, int32_t n, const int32_t *colptr,
                                 const int32_t *rowidx, unsigned options, int64_t lease_ms,
                                 bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_SOLVE_SETUP, job, 0);
    m.field[BGA_SS_N].i = n;
    m.field[BGA_SS_NNZ].i = colptr[n];
    m.field[BGA_SS_LEASE_MS].i = lease_ms;
    m.field[BGA_SS_OPTIONS].i = options & (BGA_SOLVE_PREFER_SOLVES | BGA_SOLVE_ORDERED);
    m.array[BGA_SS_COLPTR] = (bga_array_t){colptr, (size_t)n + 1};
    m.array[BGA_SS_ROWIDX] = (bga_array_t){rowidx, (size_t)colptr[n]};
    return simple(c, &m, err);
}

bg_status bga_client_solve_factor(bga_client_t *c, uint64_t job, const double *values, size_t nnz,
                                  double shift, int *posdef, bg_error_t *err)
{
    return bga_client_solve_factor_cost(c, job, values, nnz, shift, posdef, NULL, err);
}

bg_status bga_client_solve_factor_cost(bga_client_t *c, uint64_t job, const double *values,
                                       size_t nnz, double shift, int *posdef,
                                       bga_factor_cost_t *cost, bg_error_t *err)
{
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_SOLVE_FACTOR, job, 0);
    m.field[BGA_SF_SHIFT].f = shift;
    m.array[BGA_SF_VALUES] = (bga_array_t){values, nnz};
    bg_status st = exchange(c, &m, BGA_SOLVE_FACTORED, &rep, err);
    if (st != BG_OK)
        return st;
    *posdef = (int)rep.msg.field[BGA_SD_POSDEF].i;
    if (cost) {
        cost->flops = rep.msg.field[BGA_SD_FLOPS].f;
        cost->nonzeros = rep.msg.field[BGA_SD_FACTOR_NONZEROS].f;
        cost->analyze_seconds = rep.msg.field[BGA_SD_ANALYZE_SECONDS].f;
    }
    c->traffic.agent_seconds +=
        rep.msg.field[BGA_SD_ANALYZE_SECONDS].f + rep.msg.field[BGA_SD_FACTOR_SECONDS].f;
    bga_reply_close(&rep);
    return BG_OK;
}

bg_status bga_client_solve(bga_client_t *c, uint64_t job, const double *rhs, int32_t n, int nrhs,
                           double *x, bg_error_t *err)
{
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_SOLVE_RHS, job, 0);
    m.field[BGA_SR_NRHS].i = nrhs;
    m.array[BGA_SR_RHS] = (bga_array_t){rhs, (size_t)n * (size_t)nrhs};
    bg_status st = exchange(c, &m, BGA_SOLVE_RESULT, &rep, err);
    if (st != BG_OK)
        return st;
    c->traffic.agent_seconds += rep.msg.field[BGA_SX_SECONDS].f;
    st = take_f64(c, &rep, BGA_SX_X, x, (size_t)n * (size_t)nrhs, "solution", err);
    bga_reply_close(&rep);
    return st;
}

bg_status bga_client_release(bga_client_t *c, uint64_t job, bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_RELEASE, job, 0);
    return simple(c, &m, err);
}

/* An INTEG_STATE reply into *motion (q into buf->q). */
static bg_status take_state(bga_client_t *c, const bga_reply_t *rep, const bga_step_buffers_t *buf,
                            bg_step_motion_t *mo, bg_error_t *err)
{
    const bga_msg_t *m = &rep->msg;
    memset(mo, 0, sizeof *mo);
    mo->kinetic = m->field[BGA_IT_KINETIC].f;
    for (int k = 0; k < 3; k++) {
        mo->linear[k] = m->field[BGA_IT_LINEAR_X + k].f;
        mo->angular[k] = m->field[BGA_IT_ANGULAR_X + k].f;
    }
    mo->steps = m->field[BGA_IT_STEPS].i;
    mo->q = buf->q;
    c->traffic.agent_seconds += m->field[BGA_IT_SECONDS].f;
    return take_f64(c, rep, BGA_IT_Q, buf->q, buf->ndof, "positions", err);
}

bg_status bga_client_step_setup(bga_client_t *c, uint64_t job, const bg_step_setup_t *setup,
                                int64_t lease_ms, const bga_step_buffers_t *buf,
                                bg_step_motion_t *motion, bg_error_t *err)
{
    const size_t ndof = buf->ndof;
    int32_t *flags = malloc(ndof * sizeof *flags + 1);
    if (!flags)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the constraint flags");
    for (size_t i = 0; i < ndof; i++)
        flags[i] = setup->constrained[i] != 0;
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_INTEG_SETUP, job, 0);
    m.field[BGA_IS_DIM].i = setup->dim;
    m.field[BGA_IS_NV].i = setup->nv;
    m.field[BGA_IS_H].f = setup->h;
    m.field[BGA_IS_DAMPING].f = setup->damping;
    m.field[BGA_IS_LEASE_MS].i = lease_ms;
    m.array[BGA_IS_MASS] = (bga_array_t){setup->mass, (size_t)setup->nv};
    m.array[BGA_IS_Q] = (bga_array_t){setup->q, ndof};
    m.array[BGA_IS_VELOCITY] = (bga_array_t){setup->velocity, ndof};
    m.array[BGA_IS_T0] = (bga_array_t){setup->t0, ndof};
    m.array[BGA_IS_CONSTRAINED] = (bga_array_t){flags, ndof};
    m.array[BGA_IS_GRAVITY] = (bga_array_t){setup->gravity, (size_t)setup->dim};
    bg_status st = exchange(c, &m, BGA_INTEG_STATE, &rep, err);
    free(flags);
    if (st != BG_OK)
        return st;
    st = take_state(c, &rep, buf, motion, err);
    bga_reply_close(&rep);
    return st;
}

bg_status bga_client_step_predict(bga_client_t *c, uint64_t job, const bg_step_request_t *req,
                                  const bga_step_buffers_t *buf, bg_step_prediction_t *out,
                                  bg_error_t *err)
{
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_INTEG_PREDICT, job, 0);
    m.field[BGA_IP_VARIATIONAL].i = req->variational != 0;
    m.field[BGA_IP_TRIAL].i = req->trial != 0;
    m.field[BGA_IP_PREDICTOR].i = req->predictor;
    m.array[BGA_IP_T1] = (bga_array_t){req->t1, buf->ndof};
    bg_status st = exchange(c, &m, BGA_INTEG_INERTIA, &rep, err);
    if (st != BG_OK)
        return st;
    memset(out, 0, sizeof *out);
    out->coefficient = rep.msg.field[BGA_II_COEF].f;
    out->state_scale = rep.msg.field[BGA_II_STATE_SCALE].f;
    out->ncandidates = (int)rep.msg.field[BGA_II_NCAND].i;
    c->traffic.agent_seconds += rep.msg.field[BGA_II_SECONDS].f;
    const double t0 = bg_clock_now();
    st = take_f64(c, &rep, BGA_II_PREDICT, buf->y, buf->ndof, "prediction", err);
    if (st == BG_OK)
        st = take_f64(c, &rep, BGA_II_TARGETS, buf->targets, buf->ndof, "targets", err);
    if (st == BG_OK)
        st = take_f64(c, &rep, BGA_II_CANDIDATES, buf->candidates,
                      buf->ndof * (size_t)out->ncandidates, "candidates", err);
    c->traffic.encode_seconds += bg_clock_now() - t0;
    bga_reply_close(&rep);
    out->y = buf->y;
    out->targets = buf->targets;
    for (int k = 0; k < out->ncandidates; k++)
        out->candidate[k] = buf->candidates + (size_t)k * buf->ndof;
    return st;
}

bg_status bga_client_step_update(bga_client_t *c, uint64_t job, const double *q_star,
                                 const double *grad_star, const bga_step_buffers_t *buf,
                                 bg_step_trial_t *out, bg_error_t *err)
{
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_INTEG_UPDATE, job, 0);
    m.array[BGA_IU_QSTAR] = (bga_array_t){q_star, buf->ndof};
    m.array[BGA_IU_GRAD] = (bga_array_t){grad_star, buf->ndof};
    bg_status st = exchange(c, &m, BGA_INTEG_TRIAL, &rep, err);
    if (st != BG_OK)
        return st;
    out->kinetic = rep.msg.field[BGA_IR_KINETIC].f;
    out->handle_work = rep.msg.field[BGA_IR_WORK].f;
    out->q_next = buf->q_next;
    c->traffic.agent_seconds += rep.msg.field[BGA_IR_SECONDS].f;
    st = take_f64(c, &rep, BGA_IR_QNEXT, buf->q_next, buf->ndof, "trial positions", err);
    bga_reply_close(&rep);
    return st;
}

bg_status bga_client_step_accept(bga_client_t *c, uint64_t job, const bga_step_buffers_t *buf,
                                 bg_step_motion_t *motion, bg_error_t *err)
{
    bga_msg_t m;
    bga_reply_t rep;
    bga_msg_init(&m, BGA_INTEG_ACCEPT, job, 0);
    bg_status st = exchange(c, &m, BGA_INTEG_STATE, &rep, err);
    if (st != BG_OK)
        return st;
    st = take_state(c, &rep, buf, motion, err);
    bga_reply_close(&rep);
    return st;
}
