#include "bga_market.h"

#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zmq.h>

#include "bga_bseller.h"
#include "bga_rseller.h"
#include "bga_transport.h"

_Static_assert(BGA_BSELLER_JOB_SPAN == BGA_MARKET_JOB_SPAN, "one contract covers one job span");

enum { ROLE_BASIC = 0, ROLE_RESOURCE = 1 };

typedef struct role {
    uint32_t id;
    uint32_t neighbours[BGA_MMSG_MAX_NEIGHBOURS];
    int nneighbours;
} role_t;

struct bga_market {
    bga_market_config_t c;
    char name[BGA_MMSG_NAME_MAX], endpoint[BGA_MMSG_ENDPOINT_MAX];
    void *socket;
    role_t role[2];
    double next_beat;
    int standby;       /* the resource role: the broker said another daemon sells the host */
    char refused[BGA_MMSG_REASON_MAX];  /* the broker's last ERROR reason told ("" none) */
    char broker[BGA_MMSG_ENDPOINT_MAX]; /* its endpoint, to connect again */
    double heard;                       /* when the broker last wrote (or the connection began) */
    bga_bseller_t *bs; /* the basic-service seller role */
    bga_rseller_t *rs; /* the resource seller role (NULL: none) */
    /* Their configurations, to start them afresh under a new broker. */
    bga_bseller_config_t bc;
    bga_rseller_config_t rc;
    uint64_t epoch; /* the broker's, from REGISTERED (0: none yet) */
    int epoch_changes;
    /* The process's compute thread pools (OpenBLAS, OpenMP: CHOLMOD's
     * factorization and the BLAS under it), if linked, and their sizes at
     * start: a job's cap never raises them. */
    void (*blas_set)(int);
    void (*omp_set)(int);
    int blas_max, omp_max;
};

static double host_cores(void)
{
    const long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (double)n : 1.0;
}

/* MemTotal in GiB; 1 if /proc/meminfo cannot be read. */
static double host_memory(void)
{
    FILE *f = fopen("/proc/meminfo", "r");
    double gib = 1.0;
    char line[256];
    while (f && fgets(line, sizeof line, f)) {
        unsigned long long kib = 0;
        if (sscanf(line, "MemTotal: %llu kB", &kib) == 1) {
            gib = (double)kib / (1024.0 * 1024.0);
            break;
        }
    }
    if (f)
        fclose(f);
    return gib;
}

void bga_market_config_default(bga_market_config_t *c)
{
    memset(c, 0, sizeof *c);
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        c->floor[g] = 1.0;
    c->margin = 0.2;
    c->load_slope = 0.5;
    c->heartbeat = 0.5;
    c->slots = 4;
    const double cores[3] = {1, 2, 1}, memory[3] = {1, 4, 2};
    memcpy(c->unit_cores, cores, sizeof cores);
    memcpy(c->unit_memory, memory, sizeof memory);
    c->lease = 3600;
    c->cores = host_cores();
    c->memory = host_memory();
    c->res_floor[0] = 1e-5;
    c->res_floor[1] = 2e-6;
    c->res_margin = 0.2;
    c->res_load_slope = 0.5;
}

double bga_market_price(const bga_market_t *m, int good)
{
    if (good >= 3)
        return m->rs ? bga_rseller_price(m->rs, good) : 0;
    return bga_bseller_price(m->bs, good);
}

int bga_market_used(const bga_market_t *m)
{
    return bga_bseller_used(m->bs);
}

double bga_market_cores_used(const bga_market_t *m)
{
    return m->rs ? bga_rseller_used(m->rs, 0) : 0;
}

uint32_t bga_market_id(const bga_market_t *m)
{
    return m->role[ROLE_BASIC].id;
}

uint32_t bga_market_resource_id(const bga_market_t *m)
{
    return m->role[ROLE_RESOURCE].id;
}

int bga_market_holds(const bga_market_t *m, uint64_t job)
{
    return bga_bseller_holds(m->bs, job);
}

/* A function of the running process by name (NULL if none); memcpy, as
 * ISO C has no cast from an object pointer to a function pointer. */
static void *lookup(const char *name)
{
    void *self = dlopen(NULL, RTLD_LAZY);
    void *f = self ? dlsym(self, name) : NULL;
    if (self)
        dlclose(self);
    return f;
}

static void find_thread_pools(bga_market_t *m)
{
    void *p = lookup("openblas_set_num_threads");
    int (*get)(void) = NULL;
    void *g = lookup("openblas_get_num_threads");
    if (p && g) {
        memcpy(&m->blas_set, &p, sizeof p);
        memcpy(&get, &g, sizeof g);
        m->blas_max = get();
    }
    p = lookup("omp_set_num_threads");
    g = lookup("omp_get_max_threads");
    if (p && g) {
        memcpy(&m->omp_set, &p, sizeof p);
        memcpy(&get, &g, sizeof g);
        m->omp_max = get();
    }
}

void bga_market_limit_threads(const bga_market_t *m, double cores)
{
    if (cores >= 1) {
        const int n = cores < 4096 ? (int)cores : 4096;
        if (m->blas_set && m->blas_max > 0)
            m->blas_set(n < m->blas_max ? n : m->blas_max);
        if (m->omp_set && m->omp_max > 0)
            m->omp_set(n < m->omp_max ? n : m->omp_max);
    }
}

int bga_market_admit(bga_market_t *m, uint64_t job)
{
    if (!bga_market_holds(m, job))
        return 0;
    bga_market_limit_threads(m, bga_market_cores(m, job));
    return 1;
}

double bga_market_cores(const bga_market_t *m, uint64_t job)
{
    return bga_bseller_cores(m->bs, job);
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

/* A message from one of the roles: its id and role flag set. */
static void init_from(const bga_market_t *m, bga_mmsg_t *msg, int type, int role)
{
    bga_mmsg_init(msg, type);
    msg->agent = m->role[role].id;
    msg->resource = role;
}

/* What a role says about itself in REGISTER and HEARTBEAT. */
static void describe(const bga_market_t *m, int role, bga_mmsg_t *msg)
{
    snprintf(msg->name, sizeof msg->name, "%s", m->name);
    snprintf(msg->endpoint, sizeof msg->endpoint, "%s", m->endpoint);
    if (role == ROLE_RESOURCE) {
        bga_rseller_describe(m->rs, msg);
        return;
    }
    bga_bseller_describe(m->bs, msg);
}

bg_status bga_market_new(void *zmq_ctx, const bga_market_config_t *config, double now,
                         bga_market_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = BG_OK;
    const bga_market_config_t *c = config;
    if (c->slots < 1 || c->slots > 4096 || !(c->heartbeat > 0) || !c->broker)
        return bg_error_set(err, BG_ERR_INVALID, "market seller: slots, heartbeat or broker invalid");
    for (int g = 0; g < BGA_MMSG_GOODS; g++)
        if (!(c->floor[g] >= 0 && c->floor[g] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: floor[%d] out of range", g);
    if (!(c->margin >= 0 && c->margin < 1e6) || !(c->load_slope >= 0 && c->load_slope < 1e6) ||
        !(c->res_margin >= 0 && c->res_margin < 1e6) ||
        !(c->res_load_slope >= 0 && c->res_load_slope < 1e6))
        return bg_error_set(err, BG_ERR_INVALID, "market seller: margin or load slope out of range");
    if (!(c->cores >= 0 && c->cores <= 1e6) || !(c->memory >= 0 && c->memory <= 1e9) ||
        !(c->lease > 0 && c->lease <= 1e7))
        return bg_error_set(err, BG_ERR_INVALID,
                            "market seller: cores in [0, 1e6], memory in [0, 1e9] GiB, lease in "
                            "(0, 1e7] s");
    for (int k = 0; k < 2; k++)
        if (!(c->res_floor[k] >= 0 && c->res_floor[k] < 1e12))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: resource floor out of range");
    for (int g = 0; g < 3; g++)
        if (!(c->unit_cores[g] >= 0 && c->unit_cores[g] <= 1e6) ||
            !(c->unit_memory[g] >= 0 && c->unit_memory[g] <= 1e9))
            return bg_error_set(err, BG_ERR_INVALID, "market seller: unit_cores/unit_memory[%d]", g);
    bga_market_t *m = calloc(1, sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the market seller");
    m->c = *c;
    snprintf(m->name, sizeof m->name, "%s", c->name ? c->name : "agent");
    snprintf(m->endpoint, sizeof m->endpoint, "%s", c->endpoint ? c->endpoint : "");
    m->c.name = m->name;
    m->c.endpoint = m->endpoint;
    m->c.broker = NULL;
    /* A unit never needs more than this daemon's host offers, so a small
     * host still serves every good it sells. */
    const double cap_cores = c->cores > 0 ? c->cores : host_cores();
    const double cap_memory = c->cores > 0 && c->memory > 0 ? c->memory : host_memory();
    for (int g = 0; g < 3; g++) {
        if (m->c.unit_cores[g] > cap_cores)
            m->c.unit_cores[g] = cap_cores;
        if (m->c.unit_memory[g] > cap_memory)
            m->c.unit_memory[g] = cap_memory;
    }
    /* Memory adds up over a job's services on a host (every agent keeps
     * its part's state) and the host's one resource seller sells it all,
     * so on a host with less memory than one job of every service takes (a
     * rotation fit in two parts, a sparse solve, an integration step) the
     * nominal needs shrink in proportion: such a job still fits. */
    const double job_memory = 2 * m->c.unit_memory[0] + m->c.unit_memory[1] + m->c.unit_memory[2];
    if (job_memory > cap_memory)
        for (int g = 0; g < 3; g++)
            m->c.unit_memory[g] *= cap_memory / job_memory;
    m->socket = zmq_socket(zmq_ctx, ZMQ_DEALER);
    if (!m->socket) {
        st = bg_error_set(err, BG_ERR_NOMEM, "cannot create the market seller's socket");
        goto fail;
    }
    const int linger = 500;
    zmq_setsockopt(m->socket, ZMQ_LINGER, &linger, sizeof linger);
    if (c->curve &&
        ((st = bga_curve_client(m->socket, c->curve, c->broker_key, err)) != BG_OK ||
         (c->zap && (st = bga_zap_watch(c->zap, m->socket, "broker", 0, err)) != BG_OK)))
        goto fail;
    m->c.curve = NULL; /* borrowed for the call only */
    m->c.broker_key = NULL;
    /* Never block the agent's loop on the broker: a message that cannot be
     * queued (no connection, say a refused handshake) is dropped, and the
     * registration goes again at the next beat. */
    const int no_wait = 0;
    zmq_setsockopt(m->socket, ZMQ_SNDTIMEO, &no_wait, sizeof no_wait);
    snprintf(m->broker, sizeof m->broker, "%s", config->broker);
    m->heard = now;
    if (zmq_connect(m->socket, config->broker) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot connect to the broker %s: %s", config->broker,
                          zmq_strerror(errno));
        goto fail;
    }
    m->next_beat = now; /* the first tick registers */
    uint64_t seed = 1469598103934665603ull;
    for (const char *p = m->name; *p; p++)
        seed = (seed ^ (uint8_t)*p) * 1099511628211ull;
    /* The basic seller expects its resources at its own resource
     * seller's opening rates until it has paid for some. */
    bga_bseller_config_t bc = {.services = c->services,
                               .slots = c->slots,
                               .margin = c->margin,
                               .load_slope = c->load_slope,
                               .lease = c->lease,
                               .seed = seed};
    for (int g = 0; g < 3; g++) {
        bc.floor[g] = c->floor[g];
        bc.unit_cores[g] = m->c.unit_cores[g];
        bc.unit_memory[g] = m->c.unit_memory[g];
    }
    for (int k = 0; k < 2; k++)
        bc.rate[k] = c->res_floor[k] * (1 + c->res_margin);
    m->bc = bc;
    if ((st = bga_bseller_new(&bc, &m->bs, err)) != BG_OK)
        goto fail;
    if (c->cores > 0) {
        const bga_rseller_config_t rc = {.cores = c->cores,
                                         .memory = c->memory,
                                         .floor = {c->res_floor[0], c->res_floor[1]},
                                         .margin = c->res_margin,
                                         .load_slope = c->res_load_slope,
                                         .lease = c->lease,
                                         .seed = seed ^ 0x9e3779b97f4a7c15ull};
        m->rc = rc;
        if ((st = bga_rseller_new(&rc, &m->rs, err)) != BG_OK)
            goto fail;
    }
    find_thread_pools(m);
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
    bga_bseller_destroy(&(*pm)->bs);
    bga_rseller_destroy(&(*pm)->rs);
    free(*pm);
    *pm = NULL;
}

void *bga_market_socket(const bga_market_t *m)
{
    return m->socket;
}

static bg_status send_cb(void *ctx, const bga_mmsg_t *msg, bg_error_t *err)
{
    return send_msg(ctx, msg, err);
}

/* Leases that ran out end their contracts, resources not bought in time
 * are given up (the basic seller's timers), holds end. */
static bg_status expire(bga_market_t *m, double now, bg_error_t *err)
{
    bg_status st = bga_bseller_tick(m->bs, now, send_cb, m, err);
    if (st == BG_OK && m->rs)
        st = bga_rseller_tick(m->rs, now, err);
    return st;
}

bg_status bga_market_tick(bga_market_t *m, double now, bg_error_t *err)
{
    bg_status est = expire(m, now, err);
    if (est != BG_OK)
        return est;
    if (now < m->next_beat)
        return BG_OK;
    m->next_beat = now + m->c.heartbeat;
    /* Unregistered and unheard for a while: connect afresh. libzmq does
     * not retry a handshake the broker refused (a key it did not list yet,
     * a mechanism it does not speak), so a key added to the broker's
     * folder is used without restarting the agent. */
    if (!m->role[0].id && now - m->heard > BGA_MARKET_RECONNECT) {
        (void)zmq_disconnect(m->socket, m->broker);
        if (zmq_connect(m->socket, m->broker) != 0)
            return bg_error_set(err, BG_ERR_IO, "cannot connect to the broker %s again: %s",
                                m->broker, zmq_strerror(zmq_errno()));
        m->heard = now;
    }
    bg_status st = BG_OK;
    const int roles = m->c.cores > 0 ? 2 : 1;
    for (int r = 0; r < roles && st == BG_OK; r++) {
        bga_mmsg_t msg;
        /* Until the broker answers, every beat is a registration: a
         * broker that started late, or restarted, still learns who this is. */
        init_from(m, &msg, m->role[r].id ? BGA_MM_HEARTBEAT : BGA_MM_REGISTER, r);
        describe(m, r, &msg);
        st = send_msg(m, &msg, err);
    }
    return st;
}

uint64_t bga_market_epoch(const bga_market_t *m)
{
    return m->epoch;
}

int bga_market_epoch_changes(const bga_market_t *m)
{
    return m->epoch_changes;
}

/* A REGISTERED from another broker epoch: the previous broker died, and
 * whatever was sold to it (contracts, bargains, resources bought or held,
 * their leases) is dropped at once by starting both role machines afresh;
 * then the caller drops the jobs' compute state (on_new_epoch). The role
 * ids are the new broker's, as its REGISTERED replies arrive. */
static bg_status new_epoch(bga_market_t *m, uint64_t epoch, double now, bg_error_t *err)
{
    const uint64_t previous = m->epoch;
    m->epoch = epoch;
    if (previous == 0)
        return BG_OK;
    bga_bseller_t *bs = NULL;
    bga_rseller_t *rs = NULL;
    bg_status st = bga_bseller_new(&m->bc, &bs, err);
    if (st == BG_OK && m->rs)
        st = bga_rseller_new(&m->rc, &rs, err);
    if (st != BG_OK) {
        bga_bseller_destroy(&bs);
        return st;
    }
    bga_bseller_destroy(&m->bs);
    bga_rseller_destroy(&m->rs);
    m->bs = bs;
    m->rs = rs;
    /* Ids the dead broker gave mean nothing to the new one: a role whose
     * REGISTERED is not this one registers again at its next beat. */
    memset(m->role, 0, sizeof m->role);
    m->next_beat = now;
    m->epoch_changes++;
    if (m->c.on_new_epoch)
        m->c.on_new_epoch(m->c.epoch_ctx, previous, epoch);
    return BG_OK;
}

static bg_status handle(bga_market_t *m, const bga_mmsg_t *in, double now, bg_error_t *err)
{
    const int role = in->resource ? ROLE_RESOURCE : ROLE_BASIC;
    if (in->type == BGA_MM_REGISTERED && in->epoch != 0 && in->epoch != m->epoch) {
        bg_status st = new_epoch(m, in->epoch, now, err);
        if (st != BG_OK)
            return st;
    }
    if (in->type == BGA_MM_REGISTERED && role == ROLE_RESOURCE) {
        /* No id: another daemon sells this host; the next beat asks again. */
        const int standby = in->agent == 0;
        if (standby != m->standby && m->c.on_standby)
            m->c.on_standby(m->c.standby_ctx, standby ? in->reason : NULL);
        m->standby = standby;
        if (standby)
            return BG_OK;
    }
    if (in->type == BGA_MM_REGISTERED) {
        if (in->agent && role == ROLE_BASIC)
            m->refused[0] = '\0'; /* a later refusal is news again */
        m->role[role].id = in->agent;
        m->role[role].nneighbours = in->nneighbours;
        memcpy(m->role[role].neighbours, in->neighbours, sizeof m->role[role].neighbours);
        if (role == ROLE_RESOURCE)
            return m->rs ? bga_rseller_registered(m->rs, in->agent, in->neighbours,
                                                  in->nneighbours, err)
                         : BG_OK;
        return bga_bseller_registered(m->bs, in->agent, in->neighbours, in->nneighbours, err);
    }
    if (in->type == BGA_MM_ERROR) {
        /* The broker forgot this agent (it restarted, or dropped it as
         * dead) or refused it: both roles register again. */
        if (m->c.on_refused && strcmp(m->refused, in->reason) != 0)
            m->c.on_refused(m->c.refused_ctx, in->reason);
        snprintf(m->refused, sizeof m->refused, "%s", in->reason);
        m->role[0].id = m->role[1].id = 0;
        m->next_beat = now;
        return BG_OK;
    }
    /* The resource role's messages go to its role machine's host. */
    if (role == ROLE_RESOURCE)
        return m->rs ? bga_rseller_on_message(m->rs, in, now, send_cb, m, err) : BG_OK;
    return bga_bseller_on_message(m->bs, in, now, send_cb, m, err);
}

static bg_status answer_malformed(bga_market_t *m, const char *why, bg_error_t *err)
{
    bga_mmsg_t e;
    init_from(m, &e, BGA_MM_ERROR, ROLE_BASIC);
    snprintf(e.reason, sizeof e.reason, "malformed message from the broker: %.150s", why);
    return send_msg(m, &e, err);
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
        m->heard = now;
        /* A malformed message from the broker is answered with an ERROR
         * naming what is wrong, and otherwise ignored: never fatal. */
        if (r.total != r.count)
            bg_error_set(&derr, BG_ERR_LIMIT, "%d frames, at most %d", r.total,
                         BGA_WIRE_MAX_FRAMES);
        else if (bga_mmsg_decode(views, r.count, &in, &derr) == BG_OK)
            st = handle(m, &in, now, err);
        bga_received_close(&r);
        if (st == BG_OK && derr.status != BG_OK)
            st = answer_malformed(m, derr.message, err);
        if (st != BG_OK)
            return st;
    }
}
