#include "bgb_directory.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct bgb_directory {
    bgb_directory_io_t io;
    int overlay_degree;
    double heartbeat_timeout;
    bgb_dir_agent_t *agents; /* BGB_DIRECTORY_MAX_AGENTS */
    uint32_t next_id;
    uint64_t epoch; /* sent in every REGISTERED (bgb_directory_set_epoch) */
    /* Agents dropped (silent too long), oldest first: their contracts stay
     * in the ledger, so agents.csv still lists them. */
    bgb_agent_info_t *departed; /* ring of BGB_DIRECTORY_MAX_DEPARTED */
    size_t departed_head, departed_count;
};

bg_status bgb_directory_new(int overlay_degree, double heartbeat_timeout,
                            const bgb_directory_io_t *io, bgb_directory_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_directory_t *d = calloc(1, sizeof *d);
    if (d) {
        d->agents = calloc(BGB_DIRECTORY_MAX_AGENTS, sizeof *d->agents);
        d->departed = calloc(BGB_DIRECTORY_MAX_DEPARTED, sizeof *d->departed);
    }
    if (!d || !d->agents || !d->departed) {
        if (d) {
            free(d->agents);
            free(d->departed);
        }
        free(d);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the agent directory");
    }
    d->io = *io;
    d->overlay_degree = overlay_degree;
    d->heartbeat_timeout = heartbeat_timeout;
    d->next_id = 1;
    *out = d;
    return BG_OK;
}

void bgb_directory_destroy(bgb_directory_t **pd)
{
    if (!pd || !*pd)
        return;
    free((*pd)->agents);
    free((*pd)->departed);
    free(*pd);
    *pd = NULL;
}

bgb_dir_agent_t *bgb_directory_rows(bgb_directory_t *d)
{
    return d->agents;
}

const bgb_dir_agent_t *bgb_directory_rows_const(const bgb_directory_t *d)
{
    return d->agents;
}

int bgb_directory_slot_of(const bgb_directory_t *d, const bgb_dir_agent_t *a)
{
    return (int)(a - d->agents);
}

void bgb_directory_set_epoch(bgb_directory_t *d, uint64_t epoch)
{
    d->epoch = epoch;
}

bgb_dir_agent_t *bgb_directory_by_id(bgb_directory_t *d, uint32_t id)
{
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++)
        if (d->agents[i].used && d->agents[i].info.id == id)
            return &d->agents[i];
    return NULL;
}

/* Whether the agent's messages come from the socket with this routing
 * identity. */
static int same_identity(const bgb_dir_agent_t *a, const uint8_t *idn, size_t len)
{
    return a->idlen == len && memcmp(a->identity, idn, len) == 0;
}

/* A daemon's two roles share its socket (identity); `resource` tells them apart. */
bgb_dir_agent_t *bgb_directory_by_identity(bgb_directory_t *d, const uint8_t *idn, size_t len,
                                           int resource)
{
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++)
        if (d->agents[i].used && d->agents[i].info.resource == resource &&
            same_identity(&d->agents[i], idn, len))
            return &d->agents[i];
    return NULL;
}

/* Every message to an agent names the role it is for. */
bg_status bgb_directory_send(bgb_directory_t *d, const bgb_dir_agent_t *a, const bga_mmsg_t *msg_in,
                             bg_error_t *err)
{
    bga_mmsg_t copy = *msg_in;
    const bga_mmsg_t *msg = &copy;
    copy.resource = a->info.resource;
    bga_frames_t f;
    bg_status st = bga_mmsg_encode(msg, &f, err);
    if (st != BG_OK)
        return st;
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&f, v);
    st = d->io.send(d->io.ctx, a->identity, a->idlen, v, f.count);
    bga_frames_free(&f);
    if (st != BG_OK)
        bg_error_set(err, st, "market: cannot send %s to agent %u", bga_mmsg_type_name(msg->type),
                     a->info.id);
    return st;
}

/* A message to a socket that has no row (yet) for that role. */
static bg_status send_to_socket(bgb_directory_t *d, const uint8_t *idn, size_t len, int resource,
                                const bga_mmsg_t *msg, bg_error_t *err)
{
    bgb_dir_agent_t tmp = {0};
    memcpy(tmp.identity, idn, len);
    tmp.idlen = len;
    tmp.info.resource = resource;
    return bgb_directory_send(d, &tmp, msg, err);
}

bg_status bgb_directory_reply_error(bgb_directory_t *d, const uint8_t *idn, size_t len,
                                    const char *why, bg_error_t *err)
{
    bga_mmsg_t e;
    bga_mmsg_init(&e, BGA_MM_ERROR);
    snprintf(e.reason, sizeof e.reason, "%.*s", (int)sizeof e.reason - 1, why);
    return send_to_socket(d, idn, len, 0, &e, err);
}

void bgb_directory_heartbeat(bgb_dir_agent_t *a, const bga_mmsg_t *in, double now)
{
    a->info.slots = in->slots;
    a->info.free_slots = in->free_slots;
    for (int g = 0; g < BGB_GOODS; g++) {
        a->info.floor[g] = in->floor[g];
        a->info.price[g] = in->prices[g];
    }
    a->info.margin = in->margin;
    a->info.load_slope = in->load_slope;
    a->info.cores = in->cores;
    a->info.memory = in->memory;
    a->info.free_cores = in->free_cores;
    a->info.free_memory = in->free_memory;
    a->info.last_heartbeat = now;
    a->info.alive = 1;
}

static bg_status send_registered(bgb_directory_t *d, bgb_dir_agent_t *a, bg_error_t *err)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_REGISTERED);
    r.agent = a->info.id;
    r.epoch = d->epoch;
    int n = 0;
    for (int i = 0; i < a->nnb; i++) {
        const bgb_dir_agent_t *b = bgb_directory_by_id(d, a->nb[i]);
        if (b)
            a->nb[n++] = a->nb[i];
    }
    a->nnb = n;
    r.nneighbours = n;
    memcpy(r.neighbours, a->nb, (size_t)n * sizeof *a->nb);
    return bgb_directory_send(d, a, &r, err);
}

/* The host part of a tcp://HOST:PORT endpoint is compared whole. */
static size_t host_len(const char *ep)
{
    const char *h = strstr(ep, "://");
    const char *start = h ? h + 3 : ep;
    const char *colon = strrchr(start, ':');
    return (size_t)((colon ? colon : start + strlen(start)) - ep);
}

int bgb_directory_same_host(const char *a, const char *b)
{
    const size_t n = host_len(a);
    return host_len(b) == n && strncmp(a, b, n) == 0;
}

/* The live resource seller of another daemon that already sells the cores
 * and memory of `endpoint`'s host, if any: a host has one resource seller,
 * since every daemon on it would otherwise sell all of the host's cores. */
static const bgb_dir_agent_t *host_seller(const bgb_directory_t *d, const uint8_t *idn, size_t len,
                                          const char *endpoint)
{
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++) {
        const bgb_dir_agent_t *b = &d->agents[i];
        if (b->used && b->info.resource && b->info.alive && !same_identity(b, idn, len) &&
            bgb_directory_same_host(b->info.endpoint, endpoint))
            return b;
    }
    return NULL;
}

/* A resource role refused because its host has a seller: REGISTERED with
 * no id and the reason. It asks again at every heartbeat, so it takes the
 * host over once the first seller is dropped. */
static bg_status send_standby(bgb_directory_t *d, const uint8_t *idn, size_t len,
                              const char *endpoint, const bgb_dir_agent_t *first, bg_error_t *err)
{
    bga_mmsg_t r;
    bga_mmsg_init(&r, BGA_MM_REGISTERED);
    r.epoch = d->epoch;
    const char *scheme = strstr(endpoint, "://");
    const char *host = scheme ? scheme + 3 : endpoint;
    const size_t n = host_len(endpoint) - (size_t)(host - endpoint);
    snprintf(r.reason, sizeof r.reason, "host %.*s: agent %u (%.40s) sells its cores and memory",
             (int)(n < 80 ? n : 80), host, first->info.id, first->info.name);
    return send_to_socket(d, idn, len, 1, &r, err);
}

bg_status bgb_directory_register(bgb_directory_t *d, const uint8_t *idn, size_t len,
                                 const bga_mmsg_t *in, double now, bgb_dir_agent_t **out,
                                 bg_error_t *err)
{
    *out = NULL;
    bgb_dir_agent_t *a = bgb_directory_by_identity(d, idn, len, in->resource);
    if (!a && in->resource) {
        const bgb_dir_agent_t *first = host_seller(d, idn, len, in->endpoint);
        if (first)
            return send_standby(d, idn, len, in->endpoint, first, err);
    }
    if (!a) {
        for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS && !a; i++)
            if (!d->agents[i].used)
                a = &d->agents[i];
        if (!a)
            return BG_OK; /* directory full: the agent keeps retrying */
        memset(a, 0, sizeof *a);
        a->used = 1;
        a->info.id = d->next_id++;
        a->info.resource = in->resource;
        memcpy(a->identity, idn, len);
        a->idlen = len;
    }
    snprintf(a->info.name, sizeof a->info.name, "%s", in->name);
    snprintf(a->info.endpoint, sizeof a->info.endpoint, "%s", in->endpoint);
    a->info.services = in->services;
    bgb_directory_heartbeat(a, in, now);
    *out = a;
    /* Overlay: links to the most recently registered other agents of the
     * same role (service sellers and resource sellers form one overlay
     * each: a call for proposals travels among those that sell its good),
     * made symmetric (each of them gets this one too, while it has room),
     * so that an agent registered early is reachable from later ones. */
    if (a->nnb == 0)
        for (int i = BGB_DIRECTORY_MAX_AGENTS - 1; i >= 0 && a->nnb < d->overlay_degree; i--) {
            bgb_dir_agent_t *b = &d->agents[i];
            if (!b->used || b == a || b->info.resource != a->info.resource)
                continue;
            a->nb[a->nnb++] = b->info.id;
            if (b->nnb < BGA_MMSG_MAX_NEIGHBOURS) {
                b->nb[b->nnb++] = a->info.id;
                send_registered(d, b, NULL);
            }
        }
    return send_registered(d, a, err);
}

void bgb_directory_relay(bgb_directory_t *d, const bga_mmsg_t *in)
{
    bgb_dir_agent_t *t = bgb_directory_by_id(d, in->target);
    if (t && t->info.alive) {
        bga_mmsg_t c = *in;
        c.type = BGA_MM_CFP;
        c.agent = t->info.id;
        c.target = 0;
        bgb_directory_send(d, t, &c, NULL);
    }
}

void bgb_directory_expire(bgb_directory_t *d, double now,
                          void (*gone)(void *ctx, bgb_dir_agent_t *a), void *ctx)
{
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++) {
        bgb_dir_agent_t *a = &d->agents[i];
        if (a->used && now - a->info.last_heartbeat > d->heartbeat_timeout) {
            if (gone)
                gone(ctx, a);
            d->departed[(d->departed_head + d->departed_count) % BGB_DIRECTORY_MAX_DEPARTED] =
                a->info;
            if (d->departed_count < BGB_DIRECTORY_MAX_DEPARTED)
                d->departed_count++;
            else
                d->departed_head = (d->departed_head + 1) % BGB_DIRECTORY_MAX_DEPARTED;
            a->used = 0;
        }
    }
}

size_t bgb_directory_agents(const bgb_directory_t *d, bgb_agent_info_t *out, size_t max)
{
    size_t n = 0;
    for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++)
        if (d->agents[i].used) {
            if (n < max)
                out[n] = d->agents[i].info;
            n++;
        }
    return n;
}

size_t bgb_directory_departed_count(const bgb_directory_t *d)
{
    return d->departed_count;
}

const bgb_agent_info_t *bgb_directory_departed(const bgb_directory_t *d, size_t k)
{
    return k < d->departed_count ? &d->departed[(d->departed_head + k) % BGB_DIRECTORY_MAX_DEPARTED]
                                 : NULL;
}
