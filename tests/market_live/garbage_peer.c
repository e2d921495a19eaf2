/*
 * garbage_peer — sends malformed market messages to a live daemon and
 * checks it keeps serving (garbage.sh runs it against real processes).
 *
 *   garbage_peer broker ENDPOINT
 *       a DEALER on the broker's agent endpoint: each malformed message
 *       gets an ERROR naming what is wrong, then a valid REGISTER still
 *       gets REGISTERED.
 *   garbage_peer agent FILE
 *       binds a ROUTER on 127.0.0.1 (port chosen by the kernel), writes
 *       its endpoint to FILE and waits for an agent's REGISTER; each
 *       malformed message sent to the agent gets an ERROR naming what is
 *       wrong, then its resource seller, told its id, still confirms an
 *       ORDER for one core.
 * Prints "ok: ..." per check; exit 1 on the first failure.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bga_mmsg.h"

#define FAIL(...)                                                                                  \
    do {                                                                                           \
        fprintf(stderr, "FAIL: " __VA_ARGS__);                                                     \
        fputc('\n', stderr);                                                                       \
        exit(1);                                                                                   \
    } while (0)

#define MANY_FRAMES 40
#define WAIT_MS 5000

typedef struct garbage {
    const char *what;
    int nframes;
    const uint8_t *data[MANY_FRAMES];
    size_t size[MANY_FRAMES];
} garbage_t;

/* A valid ORDER's frames (from a real encoding) and broken copies. */
static uint8_t ok_frames[BGA_WIRE_MAX_FRAMES][BGA_MMSG_MAX_BYTES];
static size_t ok_size[BGA_WIRE_MAX_FRAMES];
static int ok_count;
static uint8_t bad_magic[BGA_WIRE_HEADER_BYTES], bad_type[BGA_WIRE_HEADER_BYTES],
    bad_fields[BGA_MMSG_MAX_BYTES];
static char big_text[BGA_MMSG_MAX_BYTES + 64];

static void frame(garbage_t *g, const void *data, size_t size)
{
    g->data[g->nframes] = data;
    g->size[g->nframes] = size;
    g->nframes++;
}

/* The valid frames with frame `k` replaced (k < 0: none), `drop` of the
 * last ones left out. */
static void valid_but(garbage_t *g, int k, const void *data, size_t size, int drop)
{
    for (int i = 0; i < ok_count - drop; i++)
        if (i == k)
            frame(g, data, size);
        else
            frame(g, ok_frames[i], ok_size[i]);
}

static int garbage_list(garbage_t *list)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_ORDER);
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_mmsg_encode(&m, &f, &err) != BG_OK || f.count != 2 + BGA_LM_NARRAYS)
        FAIL("cannot encode an ORDER: %s", err.message);
    ok_count = f.count;
    for (int i = 0; i < f.count; i++) {
        memcpy(ok_frames[i], f.data[i], f.size[i]);
        ok_size[i] = f.size[i];
    }
    bga_frames_free(&f);
    memcpy(bad_magic, ok_frames[0], sizeof bad_magic);
    bad_magic[0] = 'X';
    memcpy(bad_type, ok_frames[0], sizeof bad_type);
    bad_type[6] = 0xe7; /* type 0x11e7 */
    memcpy(bad_fields, ok_frames[1], ok_size[1]);
    bad_fields[8 * BGA_LM_HOPS] = 99; /* hops 99, over 16 */
    memset(big_text, 'a', sizeof big_text);
    static const char junk[] = "\x01\x02\x03", empty[] = "";
    int n = 0;
    list[n] = (garbage_t){.what = "a 3-byte frame"};
    frame(&list[n++], junk, 3);
    list[n] = (garbage_t){.what = "an empty frame"};
    frame(&list[n++], empty, 0);
    list[n] = (garbage_t){.what = "a wrong magic"};
    valid_but(&list[n++], 0, bad_magic, sizeof bad_magic, 0);
    list[n] = (garbage_t){.what = "an unknown type"};
    valid_but(&list[n++], 0, bad_type, sizeof bad_type, 0);
    list[n] = (garbage_t){.what = "a fields frame of the wrong size"};
    valid_but(&list[n++], 1, ok_frames[1], ok_size[1] - 8, 0);
    list[n] = (garbage_t){.what = "a field out of range"};
    valid_but(&list[n++], 1, bad_fields, ok_size[1], 0);
    list[n] = (garbage_t){.what = "a text over the cap"};
    valid_but(&list[n++], 2 + BGA_LM_NAME, big_text, sizeof big_text, 0);
    list[n] = (garbage_t){.what = "a header alone"};
    frame(&list[n++], ok_frames[0], ok_size[0]);
    list[n] = (garbage_t){.what = "a frame missing"};
    valid_but(&list[n++], -1, NULL, 0, 1);
    list[n] = (garbage_t){.what = "too many frames"};
    for (int i = 0; i < MANY_FRAMES; i++)
        frame(&list[n], ok_frames[0], ok_size[0]);
    n++;
    return n;
}

static void send_raw(void *s, const zmq_msg_t *route, const garbage_t *g)
{
    if (route) {
        zmq_msg_t r;
        zmq_msg_init(&r);
        zmq_msg_copy(&r, (zmq_msg_t *)route);
        if (zmq_msg_send(&r, s, ZMQ_SNDMORE) < 0)
            FAIL("send: %s", zmq_strerror(zmq_errno()));
    }
    for (int i = 0; i < g->nframes; i++)
        if (zmq_send(s, g->data[i], g->size[i], i + 1 < g->nframes ? ZMQ_SNDMORE : 0) < 0)
            FAIL("send: %s", zmq_strerror(zmq_errno()));
}

static void send_msg(void *s, const zmq_msg_t *route, const bga_mmsg_t *m)
{
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_mmsg_encode(m, &f, &err) != BG_OK)
        FAIL("encode %s: %s", bga_mmsg_type_name(m->type), err.message);
    garbage_t g = {.what = "valid"};
    for (int i = 0; i < f.count; i++)
        frame(&g, f.data[i], f.size[i]);
    send_raw(s, route, &g);
    bga_frames_free(&f);
}

/* The next market message within WAIT_MS (0: none); on a ROUTER the
 * sender's routing id goes to *route. Undecodable replies fail. */
static int recv_msg(void *s, int router, zmq_msg_t *route, bga_mmsg_t *out, int wait_ms)
{
    zmq_pollitem_t item = {s, 0, ZMQ_POLLIN, 0};
    if (zmq_poll(&item, 1, wait_ms) <= 0)
        return 0;
    static uint8_t buf[BGA_WIRE_MAX_FRAMES][BGA_MMSG_MAX_BYTES + 16];
    bga_frame_t views[BGA_WIRE_MAX_FRAMES];
    int n = 0, more = 1;
    if (router) {
        zmq_msg_close(route);
        zmq_msg_init(route);
        zmq_msg_recv(route, s, 0);
    }
    while (more) {
        const int k = n < BGA_WIRE_MAX_FRAMES ? n : BGA_WIRE_MAX_FRAMES - 1;
        int got = zmq_recv(s, buf[k], sizeof buf[0], 0);
        if (got < 0)
            FAIL("recv: %s", zmq_strerror(zmq_errno()));
        if (n < BGA_WIRE_MAX_FRAMES)
            views[n] = (bga_frame_t){buf[n], (size_t)got > sizeof buf[0] ? sizeof buf[0] : (size_t)got};
        n++;
        int64_t m = 0;
        size_t ml = sizeof m;
        zmq_getsockopt(s, ZMQ_RCVMORE, &m, &ml);
        more = (int)m;
    }
    bg_error_t err = BG_ERROR_INIT;
    if (n > BGA_WIRE_MAX_FRAMES || bga_mmsg_decode(views, n, out, &err) != BG_OK)
        FAIL("an undecodable reply: %s", err.message);
    return 1;
}

/* Waits for a message of `type` (others are skipped: heartbeats). */
static int wait_for(void *s, int router, zmq_msg_t *route, int type, bga_mmsg_t *out, int wait_ms)
{
    for (int tries = 0; tries < 100; tries++) {
        if (!recv_msg(s, router, route, out, wait_ms))
            return 0;
        if (out->type == type)
            return 1;
    }
    return 0;
}

static void each_garbage(void *s, int router, zmq_msg_t *route, const char *peer)
{
    garbage_t list[16];
    const int n = garbage_list(list);
    for (int i = 0; i < n; i++) {
        send_raw(s, router ? route : NULL, &list[i]);
        bga_mmsg_t r;
        if (!wait_for(s, router, route, BGA_MM_ERROR, &r, WAIT_MS))
            FAIL("%s: no ERROR answered %s", peer, list[i].what);
        if (r.reason[0] == '\0')
            FAIL("%s: the ERROR answering %s names nothing", peer, list[i].what);
        printf("ok: %s answered %s: %s\n", peer, list[i].what, r.reason);
    }
}

static int broker_mode(void *ctx, const char *endpoint)
{
    void *s = zmq_socket(ctx, ZMQ_DEALER);
    const int linger = 0;
    zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_connect(s, endpoint) != 0)
        FAIL("connect %s: %s", endpoint, zmq_strerror(zmq_errno()));
    each_garbage(s, 0, NULL, "the broker");
    bga_mmsg_t reg;
    bga_mmsg_init(&reg, BGA_MM_REGISTER);
    snprintf(reg.name, sizeof reg.name, "garbage-peer");
    snprintf(reg.endpoint, sizeof reg.endpoint, "tcp://127.0.0.1:9");
    reg.services = 1;
    reg.slots = 1;
    reg.free_slots = 1;
    reg.floor[0] = 1;
    reg.prices[0] = 1.2;
    send_msg(s, NULL, &reg);
    bga_mmsg_t r;
    if (!wait_for(s, 0, NULL, BGA_MM_REGISTERED, &r, WAIT_MS) || r.agent == 0)
        FAIL("the broker did not register a valid agent after the garbage");
    printf("ok: the broker still registers agents (id %u)\n", r.agent);
    zmq_close(s);
    return 0;
}

static int agent_mode(void *ctx, const char *file)
{
    void *s = zmq_socket(ctx, ZMQ_ROUTER);
    const int linger = 0;
    zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_bind(s, "tcp://127.0.0.1:*") != 0)
        FAIL("bind: %s", zmq_strerror(zmq_errno()));
    char ep[256];
    size_t len = sizeof ep;
    zmq_getsockopt(s, ZMQ_LAST_ENDPOINT, ep, &len);
    FILE *f = fopen(file, "w");
    if (!f || fprintf(f, "%s\n", ep) < 0 || fclose(f) != 0)
        FAIL("cannot write %s", file);
    zmq_msg_t route;
    zmq_msg_init(&route);
    bga_mmsg_t r;
    /* The resource role registers too; wait for it so its id can be given. */
    int basic = 0, resource = 0;
    for (int i = 0; i < 200 && !(basic && resource); i++) {
        if (!wait_for(s, 1, &route, BGA_MM_REGISTER, &r, 10000))
            FAIL("no agent registered");
        basic |= !r.resource;
        resource |= r.resource;
    }
    printf("ok: the agent registered both roles\n");
    each_garbage(s, 1, &route, "the agent");
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_REGISTERED);
    m.agent = 2;
    m.resource = 1;
    send_msg(s, &route, &m);
    bga_mmsg_init(&m, BGA_MM_ORDER);
    m.agent = 2;
    m.resource = 1;
    m.job = 77;
    m.good = 3;
    m.quantity = 1;
    m.price = 1; /* far over any floor */
    m.term = 30;
    send_msg(s, &route, &m);
    if (!wait_for(s, 1, &route, BGA_MM_CONFIRM, &r, WAIT_MS) || !r.resource || r.job != 77)
        FAIL("the agent's resource seller did not confirm an order after the garbage");
    printf("ok: the agent's resource seller still confirms an order (%g cores free)\n",
           r.free_cores);
    zmq_msg_close(&route);
    zmq_close(s);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 3 || (strcmp(argv[1], "broker") != 0 && strcmp(argv[1], "agent") != 0)) {
        fprintf(stderr, "usage: garbage_peer broker ENDPOINT | agent FILE\n");
        return 2;
    }
    void *ctx = zmq_ctx_new();
    const int rc =
        strcmp(argv[1], "broker") == 0 ? broker_mode(ctx, argv[2]) : agent_mode(ctx, argv[2]);
    zmq_ctx_term(ctx);
    return rc;
}
