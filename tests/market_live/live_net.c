#include "live_net.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bga_mmsg.h"
#include "bga_transport.h"
#include "bga_wire.h"

void live_net_fail(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("live_net: FAIL: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    exit(1);
}

static bg_status net_send(void *ctx, const uint8_t *idn, size_t len, const bga_frame_t *frames,
                          int nframes)
{
    live_net_t *h = ctx;
    if (zmq_send(h->router, idn, len, ZMQ_SNDMORE) < 0)
        return BG_ERR_IO;
    for (int i = 0; i < nframes; i++)
        if (zmq_send(h->router, frames[i].data, frames[i].size, i + 1 < nframes ? ZMQ_SNDMORE : 0) <
            0)
            return BG_ERR_IO;
    return BG_OK;
}

void live_net_open(live_net_t *h, const char *dir, const char *name, double period)
{
    memset(h, 0, sizeof *h);
    h->ctx = zmq_ctx_new();
    h->router = zmq_socket(h->ctx, ZMQ_ROUTER);
    const int linger = 0;
    zmq_setsockopt(h->router, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_bind(h->router, "tcp://127.0.0.1:*") != 0)
        live_net_fail("bind: %s", zmq_strerror(errno));
    char ep[256];
    size_t len = sizeof ep;
    zmq_getsockopt(h->router, ZMQ_LAST_ENDPOINT, ep, &len);
    bgb_market_config_t mc;
    bgb_market_config_default(&mc);
    mc.name = name;
    mc.heartbeat_timeout = 3.0;
    mc.period = period;
    bgb_market_io_t io = {h, net_send};
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_market_new(&mc, &io, &h->market, &err) != BG_OK)
        live_net_fail("market: %s", err.message);
    char path[4096];
    snprintf(path, sizeof path, "%s/endpoint", dir);
    FILE *f = fopen(path, "w");
    if (!f)
        live_net_fail("cannot write %s", path);
    fprintf(f, "%s\n", ep);
    fclose(f);
}

void live_net_close(live_net_t *h)
{
    bgb_market_destroy(&h->market);
    zmq_close(h->router);
    zmq_ctx_term(h->ctx);
}

/* Notes the socket of a heartbeating seller of either role. */
static void note(live_net_t *h, zmq_msg_t *route, const bga_frame_t *v, int n)
{
    bga_mmsg_t m;
    if (bga_mmsg_decode(v, n, &m, NULL) != BG_OK || m.type != BGA_MM_HEARTBEAT)
        return;
    const int role = m.resource != 0;
    const size_t len = zmq_msg_size(route);
    if (len > sizeof h->seen[0][0] || h->nseen[role] >= LIVE_NET_AGENTS)
        return;
    for (size_t i = 0; i < h->nseen[role]; i++)
        if (h->seen_len[i][role] == len && memcmp(h->seen[i][role], zmq_msg_data(route), len) == 0)
            return;
    memcpy(h->seen[h->nseen[role]][role], zmq_msg_data(route), len);
    h->seen_len[h->nseen[role]++][role] = len;
}

void live_net_pump(live_net_t *h, double seconds, const int *flag)
{
    const double end = bg_clock_now() + seconds;
    while ((!flag || !*flag) && bg_clock_now() < end) {
        double next = bgb_market_tick(h->market, bg_clock_now());
        long ms = (long)ceil((next - bg_clock_now()) * 1000);
        if (ms < 1)
            ms = 1;
        if (ms > 50)
            ms = 50;
        zmq_pollitem_t it = {h->router, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&it, 1, ms) <= 0)
            continue;
        bga_received_t r;
        if (bga_recv(h->router, 1, &r, NULL) != BG_OK)
            continue;
        bga_frame_t v[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&r, v);
        note(h, &r.route, v, r.count);
        bg_error_t err = BG_ERROR_INIT;
        if (bgb_market_on_frames(h->market, zmq_msg_data(&r.route), zmq_msg_size(&r.route), v,
                                 r.count, bg_clock_now(), &err) != BG_OK)
            live_net_fail("on_frames: %s", err.message);
        bga_received_close(&r);
    }
}

void live_net_wait(live_net_t *h, size_t nbasic)
{
    const double end = bg_clock_now() + 30;
    while (bg_clock_now() < end && (h->nseen[0] < nbasic || h->nseen[1] < 1))
        live_net_pump(h, 0.1, NULL);
    if (h->nseen[0] < nbasic || h->nseen[1] < 1)
        live_net_fail("%zu agents and a resource seller did not heartbeat within 30 s (%zu, %zu)",
                      nbasic, h->nseen[0], h->nseen[1]);
    live_net_pump(h, 0.6, NULL);
}
