#include "bgb_peers.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define REFUSALS 64

typedef struct peer {
    int used;
    uint8_t connection[BGB_PEERS_CONNECTION_MAX];
    size_t connection_len;
    char name[BGB_PEERS_NAME_MAX];
    char endpoint[BGB_PEERS_ENDPOINT_MAX];
    char address[BGB_PEERS_ADDRESS_MAX];
    char key[BGA_CURVE_KEY_SIZE];
    double seen;
} peer_t;

/* A refusal said lately (the hash of its connection and reason). */
typedef struct refusal {
    uint64_t hash;
    double said;
} refusal_t;

struct bgb_peers {
    int curve;
    double silence;
    pthread_mutex_t lock; /* the table, for key_of's threads */
    peer_t *peer;
    refusal_t refusal[REFUSALS];
    int next_refusal;
};

bg_status bgb_peers_new(int curve, double silence, bgb_peers_t **out, bg_error_t *err)
{
    *out = NULL;
    if (!(silence > 0))
        return bg_error_set(err, BG_ERR_INVALID, "peers: the silence must be positive");
    bgb_peers_t *p = calloc(1, sizeof *p);
    if (!p || !(p->peer = calloc(BGB_PEERS_MAX, sizeof *p->peer))) {
        free(p);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the agents' identities");
    }
    p->curve = curve;
    p->silence = silence;
    pthread_mutex_init(&p->lock, NULL);
    *out = p;
    return BG_OK;
}

void bgb_peers_destroy(bgb_peers_t **pp)
{
    bgb_peers_t *p = pp ? *pp : NULL;
    if (!p)
        return;
    pthread_mutex_destroy(&p->lock);
    free(p->peer);
    free(p);
    *pp = NULL;
}

static int same_connection(const peer_t *e, const uint8_t *c, size_t len)
{
    return e->used && e->connection_len == len && memcmp(e->connection, c, len) == 0;
}

static int live(const bgb_peers_t *p, const peer_t *e, double now)
{
    return e->used && now - e->seen < p->silence;
}

static uint64_t hash_bytes(uint64_t h, const void *data, size_t n)
{
    const uint8_t *b = data;
    for (size_t i = 0; i < n; i++)
        h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

/* Whether this connection's refusal for this reason is news. */
static int news(bgb_peers_t *p, const bgb_peer_claim_t *c, const char *why, double now)
{
    uint64_t h = hash_bytes(1469598103934665603ull, c->connection, c->connection_len);
    h = hash_bytes(h, why, strlen(why));
    for (int i = 0; i < REFUSALS; i++)
        if (p->refusal[i].said > 0 && p->refusal[i].hash == h) {
            if (now - p->refusal[i].said < BGB_PEERS_LOG_REPEAT)
                return 0;
            p->refusal[i].said = now;
            return 1;
        }
    p->refusal[p->next_refusal] = (refusal_t){h, now > 0 ? now : 1e-9};
    p->next_refusal = (p->next_refusal + 1) % REFUSALS;
    return 1;
}

static int refuse(bgb_peers_t *p, const bgb_peer_claim_t *c, double now, const char *why, int *say)
{
    *say = news(p, c, why, now);
    return 0;
}

int bgb_peers_admit(bgb_peers_t *p, const bgb_peer_claim_t *c, double now, char *why, size_t size,
                    int *say)
{
    *say = 0;
    why[0] = '\0';
    if (c->connection_len == 0 || c->connection_len > BGB_PEERS_CONNECTION_MAX ||
        strlen(c->name) >= BGB_PEERS_NAME_MAX || strlen(c->endpoint) >= BGB_PEERS_ENDPOINT_MAX) {
        snprintf(why, size, "a registration with an oversized name, endpoint or routing id");
        return refuse(p, c, now, why, say);
    }
    if (p->curve) {
        if (!c->key_name || !c->key || !c->key_name[0]) {
            snprintf(why, size, "agent '%.63s': its connection carries no CURVE key name", c->name);
            return refuse(p, c, now, why, say);
        }
        if (strcmp(c->key_name, c->name) != 0) {
            snprintf(why, size,
                     "the name '%.63s' is not its key's: the key is authorized as '%.63s' "
                     "(%.63s.pub), and a name belongs to its key",
                     c->name, c->key_name, c->key_name);
            return refuse(p, c, now, why, say);
        }
    }
    pthread_mutex_lock(&p->lock);
    peer_t *mine = NULL, *free_slot = NULL, *stale = NULL;
    for (int i = 0; i < BGB_PEERS_MAX; i++) {
        peer_t *e = &p->peer[i];
        if (!e->used) {
            if (!free_slot)
                free_slot = e;
            continue;
        }
        if (same_connection(e, c->connection, c->connection_len)) {
            mine = e;
            continue;
        }
        const int same_name = strcmp(e->name, c->name) == 0;
        const int same_endpoint = strcmp(e->endpoint, c->endpoint) == 0;
        if (!live(p, e, now)) {
            /* Gone: whatever it held is free, and its slot too. */
            if (same_name || same_endpoint)
                e->used = 0;
            if (!stale || e->seen < stale->seen)
                stale = e;
            continue;
        }
        if (same_name || same_endpoint) {
            if (same_name)
                snprintf(why, size,
                         "the name '%.63s' is registered by another agent (at %.63s) until it "
                         "has been silent for %.3g s",
                         c->name, e->address[0] ? e->address : "an unknown address", p->silence);
            else
                snprintf(why, size,
                         "the endpoint %.200s is registered by agent '%.63s' (at %.63s) until it "
                         "has been silent for %.3g s",
                         c->endpoint, e->name, e->address[0] ? e->address : "an unknown address",
                         p->silence);
            pthread_mutex_unlock(&p->lock);
            return refuse(p, c, now, why, say);
        }
    }
    if (!mine)
        mine = free_slot ? free_slot : stale; /* a silent connection's slot may be taken */
    if (!mine) {
        pthread_mutex_unlock(&p->lock);
        snprintf(why, size, "%d agents are registered, the most the broker keeps", BGB_PEERS_MAX);
        return refuse(p, c, now, why, say);
    }
    memset(mine, 0, sizeof *mine);
    mine->used = 1;
    memcpy(mine->connection, c->connection, c->connection_len);
    mine->connection_len = c->connection_len;
    snprintf(mine->name, sizeof mine->name, "%s", c->name);
    snprintf(mine->endpoint, sizeof mine->endpoint, "%s", c->endpoint);
    snprintf(mine->address, sizeof mine->address, "%s", c->address ? c->address : "");
    snprintf(mine->key, sizeof mine->key, "%s", c->key && p->curve ? c->key : "");
    mine->seen = now;
    pthread_mutex_unlock(&p->lock);
    return 1;
}

void bgb_peers_seen(bgb_peers_t *p, const uint8_t *connection, size_t len, double now)
{
    pthread_mutex_lock(&p->lock);
    for (int i = 0; i < BGB_PEERS_MAX; i++)
        if (same_connection(&p->peer[i], connection, len)) {
            p->peer[i].seen = now;
            break;
        }
    pthread_mutex_unlock(&p->lock);
}

int bgb_peers_lookup(bgb_peers_t *p, const char *name, char *address, size_t size,
                     char key[BGA_CURVE_KEY_SIZE])
{
    int found = 0;
    pthread_mutex_lock(&p->lock);
    const peer_t *best = NULL;
    for (int i = 0; i < BGB_PEERS_MAX; i++) {
        const peer_t *e = &p->peer[i];
        if (e->used && strcmp(e->name, name) == 0 && (!best || e->seen > best->seen))
            best = e;
    }
    if (best) {
        if (address)
            snprintf(address, size, "%s", best->address);
        if (key)
            snprintf(key, BGA_CURVE_KEY_SIZE, "%s", best->key);
        found = 1;
    }
    pthread_mutex_unlock(&p->lock);
    return found;
}

bg_status bgb_peers_key_of(void *ctx, const char *endpoint, char key[BGA_CURVE_KEY_SIZE],
                           bg_error_t *err)
{
    bgb_peers_t *p = ctx;
    key[0] = '\0';
    pthread_mutex_lock(&p->lock);
    const peer_t *best = NULL;
    for (int i = 0; i < BGB_PEERS_MAX; i++) {
        const peer_t *e = &p->peer[i];
        if (e->used && e->key[0] && strcmp(e->endpoint, endpoint) == 0 &&
            (!best || e->seen > best->seen))
            best = e;
    }
    if (best)
        snprintf(key, BGA_CURVE_KEY_SIZE, "%s", best->key);
    pthread_mutex_unlock(&p->lock);
    if (!best)
        return bg_error_set(err, BG_ERR_NOT_FOUND,
                            "no agent with a CURVE key has registered the endpoint %s", endpoint);
    return BG_OK;
}
