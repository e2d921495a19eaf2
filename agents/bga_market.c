#include "bga_market.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bga_transport.h"
#include "bgm_catallactic.h"

#define NEGO_MAX 32
#define SEEN_MAX 64
#define SELLER_ROUNDS 12 /* the simulator's default catallactic.max_rounds */

/* A bargain in progress with the broker's buyer for (job, good). */
typedef struct nego {
    int used;
    uint64_t job;
    int good;
    bgm_nego_t side;
} nego_t;

typedef struct held {
    uint64_t job;
    int good;
    double quantity, price;
} held_t;

struct bga_market {
    bga_market_config_t c;
    char name[BGA_MMSG_NAME_MAX], endpoint[BGA_MMSG_ENDPOINT_MAX];
    void *socket;
    uint32_t id;
    uint32_t neighbours[BGA_MMSG_MAX_NEIGHBOURS];
    int nneighbours;
    double next_beat;
    held_t *held; /* slots entries, used first */
    int used;
    nego_t nego[NEGO_MAX];
    uint64_t seen[SEEN_MAX]; /* CFPs already handled: job * 8 + good */
    int nseen;
    bgm_rng_t rng;
    bgm_genes_t genes;
};

void bga_market_config_default(bga_market_config_t *c)
{
    memset(c, 0, sizeof *c);
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        c->floor[g] = 1.0;
    c->margin = 0.2;
    c->load_slope = 0.5;
    c->heartbeat = 0.5;
    c->slots = 4;
}

static int sells(const bga_market_t *m, int good)
{
    return good >= 0 && good < 3 && (m->c.services & (1u << good));
}

double bga_market_price(const bga_market_t *m, int good)
{
    if (!sells(m, good))
        return 0;
    return m->c.floor[good] * (1 + m->c.margin) *
           (1 + m->c.load_slope * (double)m->used / (double)m->c.slots);
}

int bga_market_used(const bga_market_t *m)
{
    return m->used;
}

uint32_t bga_market_id(const bga_market_t *m)
{
    return m->id;
}

int bga_market_holds(const bga_market_t *m, uint64_t job)
{
    for (int i = 0; i < m->used; i++)
        if (job >= m->held[i].job && job - m->held[i].job < BGA_MARKET_JOB_SPAN)
            return 1;
    return 0;
}

static bg_status send_msg(bga_market_t *m, const bga_mmsg_t *msg, bg_error_t *err)
{
    bga_frames_t f;
    bg_status st = bga_mmsg_encode(msg, &f, err);
    if (st != BG_OK)
        return st;
    st = bga_send(m->socket, NULL, &f, err);
    bga_frames_free(&f);
    return st;
}

/* What the seller says about itself in REGISTER and HEARTBEAT. */
static void describe(const bga_market_t *m, bga_mmsg_t *msg)
{
    msg->agent = m->id;
    snprintf(msg->name, sizeof msg->name, "%s", m->name);
    snprintf(msg->endpoint, sizeof msg->endpoint, "%s", m->endpoint);
    msg->services = m->c.services;
    msg->slots = m->c.slots;
    msg->free_slots = m->c.slots - m->used;
    for (int g = 0; g < BGA_MMSG_GOODS; g++) {
        msg->floor[g] = sells(m, g) ? m->c.floor[g] : 0;
        msg->prices[g] = bga_market_price(m, g);
    }
    msg->margin = m->c.margin;
    msg->load_slope = m->c.load_slope;
}

bg_status bga_market_new(void *zmq_ctx, const bga_market_config_t *config, double now,
                         bga_market_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = BG_OK;
    if (config->slots < 1 || config->slots > 4096 || !(config->heartbeat > 0) || !config->broker)
        return bg_error_set(err, BG_ERR_INVALID, "market seller: slots, heartbeat or broker invalid");
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        if (!(config->floor[g] >= 0 && config->floor[g] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: floor[%d] out of range", g);
    if (!(config->margin >= 0 && config->margin < 1e6) ||
        !(config->load_slope >= 0 && config->load_slope < 1e6))
        return bg_error_set(err, BG_ERR_INVALID, "market seller: margin or load slope out of range");
    bga_market_t *m = calloc(1, sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the market seller");
    m->c = *config;
    snprintf(m->name, sizeof m->name, "%s", config->name ? config->name : "agent");
    snprintf(m->endpoint, sizeof m->endpoint, "%s", config->endpoint ? config->endpoint : "");
    m->c.name = m->name;
    m->c.endpoint = m->endpoint;
    m->c.broker = NULL;
    m->held = calloc((size_t)config->slots, sizeof *m->held);
    m->socket = zmq_socket(zmq_ctx, ZMQ_DEALER);
    if (!m->held || !m->socket) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot create the market seller's socket");
        goto fail;
    }
    const int linger = 500;
    zmq_setsockopt(m->socket, ZMQ_LINGER, &linger, sizeof linger);
    if (zmq_connect(m->socket, config->broker) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot connect to the broker %s: %s", config->broker,
                          zmq_strerror(errno));
        goto fail;
    }
    m->next_beat = now; /* the first tick registers */
    uint64_t seed = 1469598103934665603ull;
    for (const char *p = m->name; *p; p++)
        seed = (seed ^ (uint8_t)*p) * 1099511628211ull;
    bgm_rng_seed(&m->rng, seed);
    bgm_genes_random(&m->genes, &m->rng);
    *out = m;
    return BG_OK;
fail:
    bga_market_destroy(&m);
    return st;
}

void bga_market_destroy(bga_market_t **pm)
{
    if (!pm || !*pm)
        return;
    if ((*pm)->socket)
        zmq_close((*pm)->socket);
    free((*pm)->held);
    free(*pm);
    *pm = NULL;
}

void *bga_market_socket(const bga_market_t *m)
{
    return m->socket;
}

bg_status bga_market_tick(bga_market_t *m, double now, bg_error_t *err)
{
    if (now < m->next_beat)
        return BG_OK;
    m->next_beat = now + m->c.heartbeat;
    bga_mmsg_t msg;
    /* Until the broker answers, every beat is a registration: a broker
     * that started late, or restarted, still learns who this is. */
    bga_mmsg_init(&msg, m->id ? BGA_MM_HEARTBEAT : BGA_MM_REGISTER);
    describe(m, &msg);
    return send_msg(m, &msg, err);
}

static void release_job(bga_market_t *m, uint64_t job)
{
    for (int i = 0; i < NEGO_MAX; i++)
        if (m->nego[i].job == job)
            m->nego[i].used = 0;
    int j = 0;
    for (int i = 0; i < m->used; i++)
        if (m->held[i].job != job)
            m->held[j++] = m->held[i];
    m->used = j;
}

static bg_status on_order(bga_market_t *m, const bga_mmsg_t *in, bg_error_t *err)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_REFUSE);
    r.job = in->job;
    r.good = in->good;
    r.agent = m->id;
    r.quantity = in->quantity;
    r.price = in->price;
    if (!sells(m, in->good))
        snprintf(r.reason, sizeof r.reason, "does not sell %d", in->good);
    else if (m->used >= m->c.slots)
        snprintf(r.reason, sizeof r.reason, "no free slot");
    else if (in->price < m->c.floor[in->good])
        snprintf(r.reason, sizeof r.reason, "price %.6g under the floor %.6g", in->price,
                 m->c.floor[in->good]);
    else {
        m->held[m->used++] = (held_t){in->job, in->good, in->quantity, in->price};
        r.type = BGA_MM_CONFIRM;
        r.free_slots = m->c.slots - m->used;
        r.slots = m->c.slots;
        r.floor[in->good] = m->c.floor[in->good];
    }
    return send_msg(m, &r, err);
}

static nego_t *nego_find(bga_market_t *m, uint64_t job, int good)
{
    for (int i = 0; i < NEGO_MAX; i++)
        if (m->nego[i].used && m->nego[i].job == job && m->nego[i].good == good)
            return &m->nego[i];
    return NULL;
}

static bg_status reply_price(bga_market_t *m, int type, const bga_mmsg_t *in, double price,
                             bg_error_t *err)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, type);
    r.job = in->job;
    r.good = in->good;
    r.agent = m->id;
    r.quantity = in->quantity;
    r.price = price;
    return send_msg(m, &r, err);
}

/* Catallactic discovery: propose if it can sell, and pass the call on to
 * the overlay neighbours (relayed by the broker) while hops remain. Each
 * (job, good) call is handled once, however many paths bring it. */
static bg_status on_cfp(bga_market_t *m, const bga_mmsg_t *in, bg_error_t *err)
{
    const uint64_t key = (in->job * 1024 + (uint64_t)in->attempt) * 8 + (uint64_t)in->good;
    for (int i = 0; i < m->nseen; i++)
        if (m->seen[i] == key)
            return BG_OK;
    if (m->nseen == SEEN_MAX)
        memmove(m->seen, m->seen + 1, (SEEN_MAX - 1) * sizeof *m->seen), m->nseen--;
    m->seen[m->nseen++] = key;
    bg_status st = BG_OK;
    /* A new round means the buyer is no longer bargaining over this good
     * (it starts one only when no bargain is pending): restart ours. */
    nego_t *stale = nego_find(m, in->job, in->good);
    if (stale)
        stale->used = 0;
    if (sells(m, in->good) && m->used < m->c.slots) {
        nego_t *n = NULL;
        for (int i = 0; i < NEGO_MAX && !n; i++)
            if (!m->nego[i].used)
                n = &m->nego[i];
        if (n) {
            const double floor_g = m->c.floor[in->good];
            const double open = bgm_nego_opening(BGM_SIDE_SELLER, floor_g,
                                                 bga_market_price(m, in->good), m->c.margin);
            *n = (nego_t){1, in->job, in->good, {0}};
            bgm_nego_open(&n->side, BGM_SIDE_SELLER, floor_g, open, &m->genes, SELLER_ROUNDS);
            st = reply_price(m, BGA_MM_PROPOSE, in, n->side.current, err);
        }
    }
    for (int i = 0; st == BG_OK && in->hops > 1 && i < m->nneighbours; i++) {
        bga_mmsg_t r;
        bga_mmsg_init(&r, BGA_MM_RELAY);
        r.job = in->job;
        r.good = in->good;
        r.agent = m->id;
        r.target = m->neighbours[i];
        r.origin = in->origin ? in->origin : m->id;
        r.hops = in->hops - 1;
        r.attempt = in->attempt;
        r.quantity = in->quantity;
        st = send_msg(m, &r, err);
    }
    return st;
}

/* Commits to a bargain at `price`: a slot, then CONFIRM (or REFUSE). */
static bg_status commit(bga_market_t *m, nego_t *n, const bga_mmsg_t *in, double price,
                        bg_error_t *err)
{
    n->used = 0;
    bga_mmsg_t o = *in;
    o.price = price;
    return on_order(m, &o, err);
}

static bg_status on_bargain(bga_market_t *m, const bga_mmsg_t *in, bg_error_t *err)
{
    nego_t *n = nego_find(m, in->job, in->good);
    if (!n)
        return in->type == BGA_MM_REJECT ? BG_OK : reply_price(m, BGA_MM_REJECT, in, 0, err);
    if (in->type == BGA_MM_REJECT) {
        n->used = 0;
        return BG_OK;
    }
    if (in->type == BGA_MM_ACCEPT) /* the buyer took the seller's price */
        return commit(m, n, in, n->side.current, err);
    double reply = 0;
    switch (bgm_nego_respond(&n->side, in->price, &m->rng, &reply)) {
    case BGM_NEGO_ACCEPT:
        return commit(m, n, in, reply, err);
    case BGM_NEGO_COUNTER:
        return reply_price(m, BGA_MM_OFFER, in, reply, err);
    default:
        n->used = 0;
        return reply_price(m, BGA_MM_REJECT, in, 0, err);
    }
}

static bg_status handle(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    switch (in->type) {
    case BGA_MM_CFP:
        return on_cfp(m, in, err);
    case BGA_MM_OFFER:
    case BGA_MM_ACCEPT:
    case BGA_MM_REJECT:
        return on_bargain(m, in, err);
    case BGA_MM_REGISTERED:
        m->id = in->agent;
        m->nneighbours = in->nneighbours;
        memcpy(m->neighbours, in->neighbours, sizeof m->neighbours);
        m->next_beat = now + m->c.heartbeat;
        return BG_OK;
    case BGA_MM_ORDER:
        return on_order(m, in, err);
    case BGA_MM_RELEASE:
        release_job(m, in->job);
        return BG_OK;
    case BGA_MM_ERROR:
        /* The broker forgot this agent (it restarted, or dropped it as
         * dead): register again. */
        m->id = 0;
        m->next_beat = now;
        return BG_OK;
    default:
        return BG_OK; /* not for a seller; ignored */
    }
}

bg_status bga_market_on_readable(bga_market_t *m, double now, bg_error_t *err)
{
    for (;;) {
        zmq_pollitem_t item = {m->socket, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            return BG_OK;
        bga_received_t r;
        bg_error_t rerr = BG_ERROR_INIT;
        bg_status st = bga_recv(m->socket, 0, &r, &rerr);
        if (st == BG_ERR_UNSUPPORTED)
            return BG_OK;
        if (st != BG_OK)
            return bg_error_set(err, st, "%s", rerr.message);
        bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&r, views);
        bga_mmsg_t in;
        bg_error_t derr = BG_ERROR_INIT;
        /* A malformed message from the broker is dropped, not fatal. */
        if (r.total == r.count && bga_mmsg_decode(views, r.count, &in, &derr) == BG_OK)
            st = handle(m, &in, now, err);
        bga_received_close(&r);
        if (st != BG_OK)
            return st;
    }
}
