#include "bgb_loop.h"

#include <cJSON.h>
#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bga_market.h"
#include "bga_service.h"
#include "bga_transport.h"
#include "bga_wire.h"
#include "bgb_peers.h"
#include "bgb_rest.h"

/* Command names on the inproc pipe (the first frame after the routing id). */
#define CMD_BUY "BUY"
#define CMD_BOUGHT "BOUGHT"
#define CMD_RELEASE "RELEASE"
#define CMD_RELEASED "RELEASED"
#define CMD_FORGET "FORGET"
#define CMD_SETTLE "SETTLE"
#define CMD_SETTLED "SETTLED"
#define CMD_VIEW "VIEW"
#define CMD_SETTLE "SETTLE"
#define CMD_SETTLED "SETTLED"
#define CMD_STOP "STOP"
#define CMD_MAX 16
/* A buyer's wait between two calls of keep_going, and an answer's at most. */
#define BUYER_PATIENCE_MS 1000
#define ANSWER_TIMEOUT_MS 5000
/* Agent messages handled before the loop looks at its pipe again. */
#define AGENT_BATCH 64
/* The live-agent count is refreshed at most this often (it copies the directory). */
#define COUNT_PERIOD 0.05
#define IDENTITY_MAX 255

/* SETTLE's argument: a lost seller of a held purchase. */
typedef struct settle {
    uint64_t job;
    uint32_t agent;
    int good;
    double delivered;
} settle_t;

/* A purchase the loop holds for a buyer, from BUY to its release. */
typedef struct held {
    struct held *next;
    uint8_t identity[IDENTITY_MAX];
    size_t identity_len;
    bgb_loop_purchase_t p;
    int answered; /* the outcome was sent (or the buyer is gone) */
    int done;     /* the market gave its outcome */
    int orphan;   /* the buyer gave up: release once done */
} held_t;

struct bgb_loop {
    bgb_loop_config_t config;
    char market_name[BGB_DIRECTORY_NAME_MAX];
    void *zmq;
    void *agents; /* ROUTER, tcp: the agents; the loop thread's alone */
    void *pipe;   /* ROUTER, inproc: buyers, views, stop; the loop thread's alone */
    char pipe_endpoint[64];
    char endpoint[256];
    bgb_market_t *market;   /* the loop thread's alone */
    bgb_agent_info_t *live; /* directory snapshot buffer, the loop thread's */
    held_t *held;
    uint64_t next_job;
    pthread_t thread;
    int started;
    pthread_mutex_t lock; /* guards alive */
    pthread_cond_t agents_changed;
    int alive;
    /* Identity: the registrations' names, endpoints and keys (any thread
     * reads keys), and over CURVE the ZAP handler and the coordinators'
     * view of the keys. */
    bgb_peers_t *peers;
    bga_zap_t *zap;
    bga_curve_keypair_t curve_pair;
    bga_curve_peers_t curve;
    int secure;
};

/* ------------------------------------------------------------ the market's io */

static bg_status agents_send(void *ctx, const uint8_t *identity, size_t identity_len,
                             const bga_frame_t *frames, int nframes)
{
    bgb_loop_t *l = ctx;
    if (zmq_send(l->agents, identity, identity_len, ZMQ_SNDMORE | ZMQ_DONTWAIT) < 0)
        return BG_ERR_IO;
    for (int i = 0; i < nframes; i++)
        if (zmq_send(l->agents, frames[i].data, frames[i].size,
                     (i + 1 < nframes ? ZMQ_SNDMORE : 0) | ZMQ_DONTWAIT) < 0)
            return BG_ERR_IO;
    return BG_OK;
}

/* done_fn: the outcome into the held purchase; it is answered after the event. */
static void on_bought(void *ctx, const bgb_outcome_t *o)
{
    held_t *h = ctx;
    h->p.reason[0] = '\0';
    if (o->reason)
        snprintf(h->p.reason, sizeof h->p.reason, "%s", o->reason);
    h->p.nawards = 0;
    for (int i = 0; !o->reason && i < o->nawards && i < BGB_LOOP_MAX_AWARDS; i++)
        h->p.awards[h->p.nawards++] = o->awards[i];
    h->p.spent = o->spent;
    h->p.latency = o->latency;
    h->done = 1;
}

/* ------------------------------------------------------------- views */

static char *csv_text(const bgb_market_t *m, int what)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *f = open_memstream(&buf, &len);
    if (!f)
        return NULL;
    bg_error_t err = BG_ERROR_INIT;
    const bgb_ledger_t *ledger = bgb_market_ledger(m);
    const bg_status st =
        what == BGB_REST_VIEW_CONTRACTS ? bgb_ledger_write_contracts_csv(ledger, f, &err)
        : what == BGB_REST_VIEW_CLEARINGS
            ? bgb_ledger_write_clearings_csv(ledger, f, &err)
            : bgb_ledger_write_agents_csv(ledger, bgb_market_directory(m), f, &err);
    fclose(f);
    if (st != BG_OK) {
        free(buf);
        return NULL;
    }
    return buf;
}

static void add_services(cJSON *a, unsigned services)
{
    cJSON *s = cJSON_AddArrayToObject(a, "services");
    for (unsigned bit = BGA_SERVICE_ROTFIT; bit <= BGA_SERVICE_INTEG; bit <<= 1)
        if (services & bit)
            cJSON_AddItemToArray(s, cJSON_CreateString(bga_service_name(bit)));
}

/* The directory as a JSON array (GET /v1/agents' market rows). */
static char *agents_json(bgb_loop_t *l)
{
    size_t n =
        bgb_directory_agents(bgb_market_directory(l->market), l->live, BGB_DIRECTORY_MAX_AGENTS);
    if (n > BGB_DIRECTORY_MAX_AGENTS)
        n = BGB_DIRECTORY_MAX_AGENTS;
    cJSON *arr = cJSON_CreateArray();
    for (size_t i = 0; arr && i < n; i++) {
        const bgb_agent_info_t *a = &l->live[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "id", a->id);
        cJSON_AddStringToObject(o, "name", a->name);
        cJSON_AddStringToObject(o, "endpoint", a->endpoint);
        add_services(o, a->services);
        cJSON_AddStringToObject(o, "source", "market");
        char address[BGB_PEERS_ADDRESS_MAX] = "", key[BGA_CURVE_KEY_SIZE] = "";
        bgb_peers_lookup(l->peers, a->name, address, sizeof address, key);
        cJSON_AddStringToObject(o, "address", address);
        if (key[0])
            cJSON_AddStringToObject(o, "key", key);
        else
            cJSON_AddNullToObject(o, "key");
        cJSON_AddBoolToObject(o, "alive", a->alive != 0);
        cJSON_AddNumberToObject(o, "slots", a->slots);
        cJSON_AddNumberToObject(o, "free_slots", a->free_slots);
        cJSON *p = cJSON_AddObjectToObject(o, "prices");
        for (int g = BGB_GOOD_ROTFIT; g <= BGB_GOOD_INTEG; g++)
            if (a->price[g] > 0)
                cJSON_AddNumberToObject(p, bgb_good_name(g), a->price[g]);
        cJSON_AddItemToArray(arr, o);
    }
    char *text = arr ? cJSON_PrintUnformatted(arr) : NULL;
    cJSON_Delete(arr);
    return text;
}

static char *market_json(const bgb_market_t *m)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "market", "live");
    cJSON *prices = cJSON_AddArrayToObject(o, "prices");
    for (int mech = BGB_MECH_CENTRAL; mech <= BGB_MECH_POSTED; mech++)
        for (int g = BGB_GOOD_ROTFIT; g <= BGB_GOOD_INTEG; g++) {
            double mean = 0;
            const int n =
                bgb_ledger_recent_price(bgb_market_ledger(m), g, (bgb_mechanism)mech, 20, &mean);
            if (n == 0)
                continue;
            cJSON *e = cJSON_CreateObject();
            cJSON_AddStringToObject(e, "mechanism", bgb_mechanism_name((bgb_mechanism)mech));
            cJSON_AddStringToObject(e, "service", bgb_good_name(g));
            cJSON_AddNumberToObject(e, "mean_price", mean);
            cJSON_AddNumberToObject(e, "contracts", n);
            cJSON_AddItemToArray(prices, e);
        }
    char *text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return text;
}

static char *render_view(bgb_loop_t *l, int what)
{
    switch (what) {
    case BGB_REST_VIEW_AGENTS:
        return agents_json(l);
    case BGB_REST_VIEW_MARKET:
        return market_json(l->market);
    case BGB_REST_VIEW_CONTRACTS:
    case BGB_REST_VIEW_AGENTS_CSV:
    case BGB_REST_VIEW_CLEARINGS:
        return csv_text(l->market, what);
    default:
        return NULL;
    }
}

/* ------------------------------------------------------------ the loop thread */

/* Rotation fit is split over the live rotation-fit sellers, keeping one
 * agent for the sparse solve when there are several, and over no more of
 * them than the grid's hosts sell cores: the parts run at once, a core
 * each. */
static int rotfit_sellers(bgb_loop_t *l)
{
    size_t n =
        bgb_directory_agents(bgb_market_directory(l->market), l->live, BGB_DIRECTORY_MAX_AGENTS);
    int count = 0, agents = 0, hosts = 0;
    double cores = 0;
    for (size_t i = 0; i < n && i < BGB_DIRECTORY_MAX_AGENTS; i++) {
        const bgb_agent_info_t *a = &l->live[i];
        agents += a->alive != 0;
        count += a->alive && (a->services & BGA_SERVICE_ROTFIT);
        if (a->alive && a->resource) {
            hosts++;
            cores += a->cores;
        }
    }
    if (count > 1 && agents <= count)
        count--;
    if (hosts && count > (int)cores)
        count = (int)cores;
    return count < 1 ? 1 : count > BGB_LOOP_MAX_ROTFIT ? BGB_LOOP_MAX_ROTFIT : count;
}

/* Publishes the number of live agents; wakes whoever waits for the first. */
static void count_alive(bgb_loop_t *l)
{
    size_t n =
        bgb_directory_agents(bgb_market_directory(l->market), l->live, BGB_DIRECTORY_MAX_AGENTS);
    int alive = 0;
    for (size_t i = 0; i < n && i < BGB_DIRECTORY_MAX_AGENTS; i++)
        alive += l->live[i].alive != 0;
    pthread_mutex_lock(&l->lock);
    if (alive != l->alive)
        pthread_cond_broadcast(&l->agents_changed);
    l->alive = alive;
    pthread_mutex_unlock(&l->lock);
}

static void reply(bgb_loop_t *l, const uint8_t *identity, size_t identity_len, const char *cmd,
                  const void *data, size_t size)
{
    if (zmq_send(l->pipe, identity, identity_len, ZMQ_SNDMORE | ZMQ_DONTWAIT) < 0)
        return;
    zmq_send(l->pipe, cmd, strlen(cmd), (data ? ZMQ_SNDMORE : 0) | ZMQ_DONTWAIT);
    if (data)
        zmq_send(l->pipe, data, size, ZMQ_DONTWAIT);
}

static held_t *held_by_job(bgb_loop_t *l, uint64_t job, held_t ***link)
{
    for (held_t **p = &l->held; *p; p = &(*p)->next)
        if ((*p)->p.job == job) {
            if (link)
                *link = p;
            return *p;
        }
    return NULL;
}

static void buy(bgb_loop_t *l, const uint8_t *identity, size_t identity_len,
                const bgb_loop_purchase_t *in, double now)
{
    held_t *h = calloc(1, sizeof *h);
    if (!h) {
        bgb_loop_purchase_t out = *in;
        snprintf(out.reason, sizeof out.reason, "out of memory");
        reply(l, identity, identity_len, CMD_BOUGHT, &out, sizeof out);
        return;
    }
    memcpy(h->identity, identity, identity_len);
    h->identity_len = identity_len;
    h->p = *in;
    h->p.job = ++l->next_job * BGA_MARKET_JOB_SPAN;
    h->next = l->held;
    l->held = h;
    const int n = rotfit_sellers(l);
    const bgb_need_t needs[3] = {
        {BGB_GOOD_ROTFIT, (double)n, n}, {BGB_GOOD_SOLVE, 1.0, 1}, {BGB_GOOD_INTEG, 1.0, 1}};
    const bgb_need_t again = {h->p.good, h->p.quantity, 1};
    const int nexclude = h->p.nexclude < 0                       ? 0
                         : h->p.nexclude > BGB_LOOP_MAX_EXCLUDE ? BGB_LOOP_MAX_EXCLUDE
                                                                : h->p.nexclude;
    bg_error_t err = BG_ERROR_INIT;
    /* The outcome may come from inside this call (no seller at all). */
    const bg_status st =
        h->p.replace ? bgb_market_buy_excluding(l->market, h->p.job, h->p.mechanism, h->p.budget,
                                                &again, 1, h->p.exclude, nexclude, now, on_bought,
                                                h, &err)
                     : bgb_market_buy(l->market, h->p.job, h->p.mechanism, h->p.budget, needs,
                                      h->p.integ ? 3 : 2, now, on_bought, h, &err);
    if (st != BG_OK) {
        snprintf(h->p.reason, sizeof h->p.reason, "%.63s", err.message);
        h->done = 1;
    } else {
        bgb_market_label(l->market, h->p.job, h->p.label);
    }
}

/* Answers the purchases whose outcome came in. A failed one holds nothing
 * (the market released every seller that had agreed) and is forgotten once
 * answered; an orphan's (its buyer gave up) is released. */
static void answer_done(bgb_loop_t *l, double now)
{
    for (held_t **p = &l->held; *p;) {
        held_t *h = *p;
        if (h->done && !h->answered && !h->orphan) {
            reply(l, h->identity, h->identity_len, CMD_BOUGHT, &h->p, sizeof h->p);
            h->answered = 1;
        }
        if (h->done && (h->orphan || h->p.reason[0])) {
            bgb_market_release(l->market, h->p.job, now);
            *p = h->next;
            free(h);
            continue;
        }
        p = &h->next;
    }
}

/* The buyer at identity gave up: what it holds is released, what it is
 * still buying is released when its outcome comes. */
static void forget(bgb_loop_t *l, const uint8_t *identity, size_t identity_len, double now)
{
    for (held_t **p = &l->held; *p;) {
        held_t *h = *p;
        if (h->identity_len != identity_len || memcmp(h->identity, identity, identity_len) != 0) {
            p = &h->next;
            continue;
        }
        if (!h->done) {
            h->orphan = 1;
            p = &h->next;
            continue;
        }
        bgb_market_release(l->market, h->p.job, now);
        *p = h->next;
        free(h);
    }
}

/* A job being cancelled: its bought purchase is settled, one still
 * buying abandoned (bgb_loop_settle). */
static void settle(bgb_loop_t *l, const char *label, double now)
{
    for (held_t *h = l->held; h; h = h->next) {
        if (strcmp(h->p.label, label) != 0 || (h->done && h->p.reason[0]))
            continue;
        if (h->done) {
            bgb_market_settle(l->market, h->p.job, now);
        } else {
            bgb_market_release(l->market, h->p.job, now);
            snprintf(h->p.reason, sizeof h->p.reason, "cancelled");
            h->done = h->orphan = 1; /* answer_done frees it */
        }
    }
}

/* One command from the pipe; returns 1 on STOP. */
static int on_command(bgb_loop_t *l, double now)
{
    zmq_msg_t part[3];
    int count = 0, more = 1;
    while (more && count < 3) {
        zmq_msg_init(&part[count]);
        if (zmq_msg_recv(&part[count], l->pipe, ZMQ_DONTWAIT) < 0) {
            zmq_msg_close(&part[count]);
            break;
        }
        more = zmq_msg_more(&part[count]);
        count++;
    }
    while (more) { /* a malformed command: drop the rest of it */
        zmq_msg_t rest;
        zmq_msg_init(&rest);
        if (zmq_msg_recv(&rest, l->pipe, ZMQ_DONTWAIT) < 0)
            more = 0;
        else
            more = zmq_msg_more(&rest);
        zmq_msg_close(&rest);
    }
    int stop = 0;
    if (count >= 2 && zmq_msg_size(&part[0]) <= IDENTITY_MAX) {
        const uint8_t *id = zmq_msg_data(&part[0]);
        const size_t idlen = zmq_msg_size(&part[0]);
        char cmd[CMD_MAX] = "";
        const size_t clen = zmq_msg_size(&part[1]);
        if (clen < sizeof cmd)
            memcpy(cmd, zmq_msg_data(&part[1]), clen);
        const void *data = count == 3 ? zmq_msg_data(&part[2]) : NULL;
        const size_t size = count == 3 ? zmq_msg_size(&part[2]) : 0;
        if (strcmp(cmd, CMD_BUY) == 0 && size == sizeof(bgb_loop_purchase_t)) {
            bgb_loop_purchase_t in;
            memcpy(&in, data, sizeof in);
            buy(l, id, idlen, &in, now);
        } else if (strcmp(cmd, CMD_RELEASE) == 0 && size == sizeof(uint64_t)) {
            uint64_t job;
            memcpy(&job, data, sizeof job);
            held_t **link = NULL;
            held_t *h = held_by_job(l, job, &link);
            if (h && !h->done) {
                h->orphan = 1; /* released when its outcome comes */
            } else if (h) {
                bgb_market_release(l->market, job, now);
                *link = h->next;
                free(h);
            }
            reply(l, id, idlen, CMD_RELEASED, NULL, 0);
        } else if (strcmp(cmd, CMD_SETTLE) == 0 && size == sizeof(settle_t)) {
            settle_t in;
            memcpy(&in, data, sizeof in);
            const held_t *h = held_by_job(l, in.job, NULL);
            const double paid =
                h && h->done ? bgb_market_settle_lost(l->market, in.job, in.agent, in.good,
                                                      in.delivered, now)
                             : -1.0;
            reply(l, id, idlen, CMD_SETTLED, &paid, sizeof paid);
        } else if (strcmp(cmd, CMD_FORGET) == 0) {
            forget(l, id, idlen, now);
        } else if (strcmp(cmd, CMD_VIEW) == 0 && size == sizeof(int)) {
            int what;
            memcpy(&what, data, sizeof what);
            char *text = render_view(l, what);
            reply(l, id, idlen, CMD_VIEW, text ? text : "", text ? strlen(text) + 1 : 1);
            free(text);
        } else if (strcmp(cmd, CMD_SETTLE) == 0 && size > 0 && size <= BGB_LEDGER_LABEL_MAX &&
                   ((const char *)data)[size - 1] == '\0') {
            settle(l, data, now);
            reply(l, id, idlen, CMD_SETTLED, NULL, 0);
        } else if (strcmp(cmd, CMD_STOP) == 0) {
            reply(l, id, idlen, CMD_STOP, NULL, 0);
            stop = 1;
        }
    }
    for (int i = 0; i < count; i++)
        zmq_msg_close(&part[i]);
    return stop;
}

/* Whether frames are a market REGISTER (the header's type, in place). */
static int is_register(const bga_frame_t *views, int count)
{
    if (!bga_mmsg_is_market(views, count))
        return 0;
    const unsigned type = views[0].data[6] | (unsigned)views[0].data[7] << 8;
    return (type & 0xff) == BGA_MM_REGISTER;
}

/* A property of the connection a message came on ("" when it has none);
 * read on the body: libzmq 4.3's ROUTER drops them from the routing frame
 * of a message zmq_poll looked at. */
static const char *property(const bga_received_t *r, const char *name)
{
    if (r->count < 1)
        return "";
    const char *v = zmq_msg_gets((zmq_msg_t *)&r->part[0], name);
    return v ? v : "";
}

/*
 * A registration may take its name and endpoint (bgb_peers: over CURVE the
 * name is its key's, and no live agent holds either); a refused one is
 * answered with an ERROR saying why and logged once with the peer's
 * address and key. Returns 1 when the market may see it.
 */
static int admitted(bgb_loop_t *l, const bga_received_t *r, const bga_frame_t *views, double now)
{
    const uint8_t *idn = zmq_msg_data((zmq_msg_t *)&r->route);
    const size_t idlen = zmq_msg_size((zmq_msg_t *)&r->route);
    if (!is_register(views, r->count)) {
        bgb_peers_seen(l->peers, idn, idlen, now);
        return 1;
    }
    bga_mmsg_t in;
    bg_error_t derr = BG_ERROR_INIT;
    if (bga_mmsg_decode(views, r->count, &in, &derr) != BG_OK)
        return 1; /* the market answers a malformed message itself */
    const char *address = property(r, "Peer-Address");
    const char *key_name = property(r, "User-Id");
    const char *key = property(r, BGA_ZAP_KEY_PROPERTY);
    const bgb_peer_claim_t claim = {.connection = idn,
                                    .connection_len = idlen,
                                    .name = in.name,
                                    .endpoint = in.endpoint,
                                    .address = address,
                                    .key_name = l->secure ? key_name : NULL,
                                    .key = l->secure ? key : NULL};
    char why[BGA_MMSG_REASON_MAX - 40];
    int say = 0;
    if (bgb_peers_admit(l->peers, &claim, now, why, sizeof why, &say))
        return 1;
    char reason[BGA_MMSG_REASON_MAX];
    snprintf(reason, sizeof reason, "registration refused: %s", why);
    bg_error_t err = BG_ERROR_INIT;
    (void)bgb_market_refuse(l->market, idn, idlen, reason, &err);
    if (say && l->config.log) {
        char line[768];
        if (l->secure)
            snprintf(line, sizeof line,
                     "refused the registration of agent '%.63s' from %s (CURVE key %s, "
                     "authorized as '%.63s'): %s",
                     in.name, address[0] ? address : "an unknown address", key, key_name, why);
        else
            snprintf(line, sizeof line,
                     "refused the registration of agent '%.63s' from %s (no key: plaintext): %s",
                     in.name, address[0] ? address : "an unknown address", why);
        l->config.log(l->config.log_ctx, line);
    }
    return 0;
}

/* Up to AGENT_BATCH agent messages, without blocking. */
static void on_agents(bgb_loop_t *l)
{
    for (int k = 0; k < AGENT_BATCH; k++) {
        zmq_pollitem_t item = {l->agents, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 0) <= 0 || !(item.revents & ZMQ_POLLIN))
            return;
        bga_received_t r;
        bg_error_t err = BG_ERROR_INIT;
        if (bga_recv(l->agents, 1, &r, &err) != BG_OK)
            return;
        bga_frame_t views[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&r, views);
        if (r.total == r.count && !admitted(l, &r, views, bg_clock_now())) {
            /* refused and answered */
        } else if (r.total == r.count) {
            (void)bgb_market_on_frames(l->market, zmq_msg_data(&r.route), zmq_msg_size(&r.route),
                                       views, r.count, bg_clock_now(), &err);
        } else {
            char why[96];
            snprintf(why, sizeof why, "market message: %d frames, at most %d", r.total,
                     BGA_WIRE_MAX_FRAMES);
            (void)bgb_market_refuse(l->market, zmq_msg_data(&r.route), zmq_msg_size(&r.route), why,
                                    &err);
        }
        bga_received_close(&r);
    }
}

/* The loop: sleeps in zmq_poll until an agent or the pipe has something, or
 * the market's next deadline; then serves what came and what is due. */
static void *loop_main(void *arg)
{
    bgb_loop_t *l = arg;
    double next_tick = 0, next_count = 0;
    for (;;) {
        double now = bg_clock_now();
        if (now >= next_tick)
            next_tick = bgb_market_tick(l->market, now);
        answer_done(l, now);
        if (now >= next_count) {
            count_alive(l);
            next_count = now + COUNT_PERIOD;
        }
        double due = next_tick < next_count ? next_tick : next_count;
        long wait_ms = (long)((due - bg_clock_now()) * 1e3) + 1;
        wait_ms = wait_ms < 0 ? 0 : wait_ms > 60000 ? 60000 : wait_ms;
        zmq_pollitem_t items[2] = {{l->agents, 0, ZMQ_POLLIN, 0}, {l->pipe, 0, ZMQ_POLLIN, 0}};
        if (zmq_poll(items, 2, wait_ms) < 0) {
            if (errno == EINTR)
                continue;
            break; /* the context is gone */
        }
        now = bg_clock_now();
        int stop = 0;
        if (items[1].revents & ZMQ_POLLIN)
            for (int k = 0; k < AGENT_BATCH && !stop; k++) {
                zmq_pollitem_t again = {l->pipe, 0, ZMQ_POLLIN, 0};
                if (k > 0 && (zmq_poll(&again, 1, 0) <= 0 || !(again.revents & ZMQ_POLLIN)))
                    break;
                stop = on_command(l, now);
            }
        if (stop)
            break;
        if (items[0].revents & ZMQ_POLLIN) {
            on_agents(l);
            next_tick = 0; /* a message may have changed what is due */
        }
    }
    return NULL;
}

/* ------------------------------------------------------------ lifecycle */

static void contract_row(void *ctx, const bgb_contract_t *row)
{
    bgb_loop_t *l = ctx;
    const held_t *h = held_by_job(l, row->job, NULL);
    if (l->config.on_contract)
        l->config.on_contract(l->config.contract_ctx, h ? h->p.label : "", row);
}

bg_status bgb_loop_start(const bgb_loop_config_t *config, bgb_loop_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_loop_t *l = calloc(1, sizeof *l);
    if (!l)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the broker's market loop");
    l->config = *config;
    snprintf(l->market_name, sizeof l->market_name, "%s",
             config->market.name ? config->market.name : "biotgrid");
    l->config.market.name = l->market_name;
    l->config.endpoint = NULL;
    pthread_mutex_init(&l->lock, NULL);
    pthread_cond_init(&l->agents_changed, NULL);
    bg_status st = BG_OK;
    const int linger = 0;
    l->zmq = zmq_ctx_new();
    l->agents = l->zmq ? zmq_socket(l->zmq, ZMQ_ROUTER) : NULL;
    l->pipe = l->zmq ? zmq_socket(l->zmq, ZMQ_ROUTER) : NULL;
    if (!l->agents || !l->pipe) {
        st = bg_error_set(err, BG_ERR_IO, "cannot create the agents' ZeroMQ socket: %s",
                          zmq_strerror(zmq_errno()));
        goto out;
    }
    zmq_setsockopt(l->agents, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(l->pipe, ZMQ_LINGER, &linger, sizeof linger);
    if ((st = bgb_peers_new(config->curve != NULL, config->market.heartbeat_timeout, &l->peers,
                            err)) != BG_OK)
        goto out;
    if (config->curve) {
        /* The ZAP handler before the bind: a CURVE socket whose context
         * has none admits every client that knows the broker's key. */
        const bga_zap_config_t zc = {
            .folder = config->authorized_agents, .log = config->log, .log_ctx = config->log_ctx};
        char label[BGB_DIRECTORY_ENDPOINT_MAX + 32];
        snprintf(label, sizeof label, "agents' endpoint %s", config->endpoint);
        bg_error_t zerr = BG_ERROR_INIT;
        if (!config->authorized_agents) {
            st = bg_error_set(err, BG_ERR_INVALID,
                              "--authorized-agents: CURVE needs the folder of the agents' keys");
            goto out;
        }
        if ((st = bga_zap_new(l->zmq, &zc, &l->zap, &zerr)) != BG_OK) {
            st = bg_error_set(err, st == BG_ERR_IO ? BG_ERR_IO : BG_ERR_INVALID,
                              "--authorized-agents %s", zerr.message);
            goto out;
        }
        if ((st = bga_curve_server(l->agents, config->curve, err)) != BG_OK ||
            (st = bga_zap_watch(l->zap, l->agents, label, 1, err)) != BG_OK)
            goto out;
        l->curve_pair = *config->curve;
        l->curve = (bga_curve_peers_t){&l->curve_pair, bgb_peers_key_of, l->peers};
        l->secure = 1;
    }
    l->config.curve = NULL; /* copied above, or none */
    l->config.authorized_agents = NULL;
    size_t len = sizeof l->endpoint;
    if (zmq_bind(l->agents, config->endpoint) != 0 ||
        zmq_getsockopt(l->agents, ZMQ_LAST_ENDPOINT, l->endpoint, &len) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "endpoint: cannot bind %s: %s", config->endpoint,
                          zmq_strerror(zmq_errno()));
        goto out;
    }
    snprintf(l->pipe_endpoint, sizeof l->pipe_endpoint, "inproc://bgb-loop-%p", (void *)l);
    if (zmq_bind(l->pipe, l->pipe_endpoint) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot bind the market loop's pipe: %s",
                          zmq_strerror(zmq_errno()));
        goto out;
    }
    if (!(l->live = calloc(BGB_DIRECTORY_MAX_AGENTS, sizeof *l->live))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the agents' directory");
        goto out;
    }
    const bgb_market_io_t io = {l, agents_send};
    if ((st = bgb_market_new(&l->config.market, &io, &l->market, err)) != BG_OK)
        goto out;
    bgb_market_on_contract(l->market, contract_row, l);
    if (pthread_create(&l->thread, NULL, loop_main, l) != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot start the broker's market loop");
        goto out;
    }
    l->started = 1;
out:
    if (st != BG_OK)
        bgb_loop_stop(&l);
    *out = l;
    return st;
}

const char *bgb_loop_endpoint(const bgb_loop_t *l)
{
    return l->endpoint;
}

const bga_curve_peers_t *bgb_loop_curve(const bgb_loop_t *l)
{
    return l->secure ? &l->curve : NULL;
}

int bgb_loop_authorized_keys(const bgb_loop_t *l)
{
    return l->zap ? bga_zap_count(l->zap) : 0;
}

/* A DEALER on the loop's pipe for the calling thread; NULL on failure. */
static void *pipe_socket(bgb_loop_t *l)
{
    void *s = zmq_socket(l->zmq, ZMQ_DEALER);
    const int linger = 0;
    if (s && (zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger) != 0 ||
              zmq_connect(s, l->pipe_endpoint) != 0)) {
        zmq_close(s);
        s = NULL;
    }
    return s;
}

static int send_command(void *s, const char *cmd, const void *data, size_t size)
{
    if (zmq_send(s, cmd, strlen(cmd), data ? ZMQ_SNDMORE : 0) < 0)
        return -1;
    return data && zmq_send(s, data, size, 0) < 0 ? -1 : 0;
}

/* Receives an answer [cmd, data?] within timeout_ms; cmd into cmd[CMD_MAX],
 * data into *data (malloc'd, caller frees) and *size. 0, or -1 on timeout. */
static int receive_answer(void *s, int timeout_ms, char *cmd, void **data, size_t *size)
{
    zmq_pollitem_t item = {s, 0, ZMQ_POLLIN, 0};
    if (zmq_poll(&item, 1, timeout_ms) <= 0 || !(item.revents & ZMQ_POLLIN))
        return -1;
    zmq_msg_t m;
    zmq_msg_init(&m);
    if (zmq_msg_recv(&m, s, 0) < 0) {
        zmq_msg_close(&m);
        return -1;
    }
    const size_t clen = zmq_msg_size(&m) < CMD_MAX - 1 ? zmq_msg_size(&m) : CMD_MAX - 1;
    memcpy(cmd, zmq_msg_data(&m), clen);
    cmd[clen] = '\0';
    int more = zmq_msg_more(&m);
    zmq_msg_close(&m);
    *data = NULL;
    *size = 0;
    while (more) {
        zmq_msg_init(&m);
        if (zmq_msg_recv(&m, s, 0) < 0) {
            zmq_msg_close(&m);
            break;
        }
        more = zmq_msg_more(&m);
        if (!*data && (*data = malloc(zmq_msg_size(&m) + 1)) != NULL) {
            memcpy(*data, zmq_msg_data(&m), zmq_msg_size(&m));
            *size = zmq_msg_size(&m);
        }
        zmq_msg_close(&m);
    }
    return 0;
}

void bgb_loop_stop(bgb_loop_t **lp)
{
    bgb_loop_t *l = lp ? *lp : NULL;
    if (!l)
        return;
    if (l->started) {
        void *s = pipe_socket(l);
        char cmd[CMD_MAX];
        void *data = NULL;
        size_t size = 0;
        if (s && send_command(s, CMD_STOP, NULL, 0) == 0)
            (void)receive_answer(s, -1, cmd, &data, &size);
        free(data);
        if (s)
            zmq_close(s);
        pthread_join(l->thread, NULL);
    }
    while (l->held) {
        held_t *h = l->held;
        l->held = h->next;
        free(h);
    }
    bgb_market_destroy(&l->market);
    free(l->live);
    if (l->pipe)
        zmq_close(l->pipe);
    if (l->agents)
        zmq_close(l->agents);
    bga_zap_destroy(&l->zap); /* after the socket it watched, before the context */
    if (l->zmq)
        zmq_ctx_term(l->zmq);
    bgb_peers_destroy(&l->peers);
    memset(&l->curve_pair, 0, sizeof l->curve_pair);
    pthread_mutex_destroy(&l->lock);
    pthread_cond_destroy(&l->agents_changed);
    free(l);
    *lp = NULL;
}

char *bgb_loop_view(bgb_loop_t *l, int what)
{
    void *s = pipe_socket(l);
    char cmd[CMD_MAX];
    void *data = NULL;
    size_t size = 0;
    if (!s || send_command(s, CMD_VIEW, &what, sizeof what) != 0 ||
        receive_answer(s, ANSWER_TIMEOUT_MS, cmd, &data, &size) != 0 || !data ||
        strcmp(cmd, CMD_VIEW) != 0 || size == 0 || ((char *)data)[size - 1] != '\0' ||
        ((char *)data)[0] == '\0') {
        free(data);
        data = NULL;
    }
    if (s)
        zmq_close(s);
    return data;
}

void bgb_loop_settle(bgb_loop_t *l, const char *label)
{
    char text[BGB_LEDGER_LABEL_MAX];
    snprintf(text, sizeof text, "%s", label);
    void *s = pipe_socket(l);
    char cmd[CMD_MAX];
    void *data = NULL;
    size_t size = 0;
    if (s && send_command(s, CMD_SETTLE, text, strlen(text) + 1) == 0)
        (void)receive_answer(s, ANSWER_TIMEOUT_MS, cmd, &data, &size);
    free(data);
    if (s)
        zmq_close(s);
}

int bgb_loop_live_agents(bgb_loop_t *l, double wait_seconds)
{
    pthread_mutex_lock(&l->lock);
    if (wait_seconds > 0 && l->alive == 0) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        const double end = (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec + wait_seconds;
        ts.tv_sec = (time_t)end;
        ts.tv_nsec = (long)((end - (double)ts.tv_sec) * 1e9);
        while (l->alive == 0 &&
               pthread_cond_timedwait(&l->agents_changed, &l->lock, &ts) != ETIMEDOUT)
            ;
    }
    const int n = l->alive;
    pthread_mutex_unlock(&l->lock);
    return n;
}

/* -------------------------------------------------------------- buyers */

struct bgb_loop_buyer {
    bgb_loop_t *loop;
    void *socket;
    uint64_t holding[BGB_LOOP_MAX_HELD]; /* jobs bought and not released */
    int nholding;
};

static void hold(bgb_loop_buyer_t *b, uint64_t job)
{
    if (b->nholding < BGB_LOOP_MAX_HELD)
        b->holding[b->nholding++] = job;
}

static void unhold(bgb_loop_buyer_t *b, uint64_t job)
{
    for (int i = 0; i < b->nholding; i++)
        if (b->holding[i] == job) {
            b->holding[i] = b->holding[--b->nholding];
            return;
        }
}

bg_status bgb_loop_buyer_new(bgb_loop_t *l, bgb_loop_buyer_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_loop_buyer_t *b = calloc(1, sizeof *b);
    if (!b)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for a buyer");
    b->loop = l;
    if (!(b->socket = pipe_socket(l))) {
        free(b);
        return bg_error_set(err, BG_ERR_IO, "cannot reach the market loop: %s",
                            zmq_strerror(zmq_errno()));
    }
    *out = b;
    return BG_OK;
}

void bgb_loop_buyer_destroy(bgb_loop_buyer_t **bp)
{
    bgb_loop_buyer_t *b = bp ? *bp : NULL;
    if (!b)
        return;
    while (b->nholding > 0)
        bgb_loop_release(b, b->holding[b->nholding - 1]);
    zmq_close(b->socket);
    free(b);
    *bp = NULL;
}

bg_status bgb_loop_buy(bgb_loop_buyer_t *b, bgb_loop_purchase_t *p, int (*keep_going)(void *ctx),
                       void *ctx, bg_error_t *err)
{
    if (send_command(b->socket, CMD_BUY, p, sizeof *p) != 0)
        return bg_error_set(err, BG_ERR_IO, "the market loop is gone");
    for (;;) {
        char cmd[CMD_MAX];
        void *data = NULL;
        size_t size = 0;
        if (receive_answer(b->socket, BUYER_PATIENCE_MS, cmd, &data, &size) == 0) {
            const int ok = strcmp(cmd, CMD_BOUGHT) == 0 && data && size == sizeof *p;
            if (ok)
                memcpy(p, data, sizeof *p);
            free(data);
            if (!ok)
                continue; /* an answer to an earlier request (a release) */
            if (!p->reason[0])
                hold(b, p->job);
            return BG_OK;
        }
        if (keep_going && !keep_going(ctx)) {
            /* The buyer has not heard the purchase's job number yet: the
             * loop forgets by the buyer's socket (everything it holds). */
            (void)send_command(b->socket, CMD_FORGET, NULL, 0);
            b->nholding = 0;
            return bg_error_set(err, BG_ERR_CONFLICT, "the purchase was abandoned");
        }
    }
}

void bgb_loop_release(bgb_loop_buyer_t *b, uint64_t job)
{
    if (!job)
        return;
    if (send_command(b->socket, CMD_RELEASE, &job, sizeof job) == 0) {
        for (;;) {
            char cmd[CMD_MAX];
            void *data = NULL;
            size_t size = 0;
            const int got = receive_answer(b->socket, ANSWER_TIMEOUT_MS, cmd, &data, &size);
            free(data);
            if (got != 0 || strcmp(cmd, CMD_RELEASED) == 0)
                break;
        }
    }
    unhold(b, job);
}

double bgb_loop_settle_lost(bgb_loop_buyer_t *b, uint64_t job, uint32_t agent, int good,
                            double delivered)
{
    const settle_t in = {job, agent, good, delivered};
    if (send_command(b->socket, CMD_SETTLE, &in, sizeof in) != 0)
        return -1.0;
    for (;;) {
        char cmd[CMD_MAX];
        void *data = NULL;
        size_t size = 0;
        if (receive_answer(b->socket, ANSWER_TIMEOUT_MS, cmd, &data, &size) != 0)
            return -1.0;
        double paid = -1.0;
        const int ok = strcmp(cmd, CMD_SETTLED) == 0 && data && size == sizeof paid;
        if (ok)
            memcpy(&paid, data, sizeof paid);
        free(data);
        if (ok)
            return paid;
    }
}
