/*
 * bga_deals — the table a live seller host (bga_bseller, bga_rseller)
 * keeps of the (job, good) pairs the broker has talked to it about. The
 * live protocol names a contract by its job and good; the hosted role
 * machine names it by its buyer's request number, so each pair gets one,
 * drawn from the host's sequence (next_req, which the host also hands its
 * machine for the requests the machine opens itself, so the two never
 * collide).
 *
 * The table is fixed: a pair in talk (a call, a bargain) may be forgotten
 * to make room for a new one, the least recently used first, because a
 * forgotten bargain only costs the buyer a round; an agreed one (state ≠
 * BGA_DEAL_TALK) never is.
 *
 * A plain value the host embeds; no allocation. Single-threaded.
 */
#ifndef BGA_DEALS_H
#define BGA_DEALS_H

#include <stdint.h>

#define BGA_DEALS_MAX 256
/* Request numbers end below this: the hosts' fixed party ids lie above. */
#define BGA_DEALS_REQ_END 0xfff00000u

enum { BGA_DEAL_TALK = 0 }; /* the hosts number their agreed states from 1 */

typedef struct bga_deal {
    int used;
    int state; /* BGA_DEAL_TALK, or the host's agreed state */
    uint64_t job;
    int good;
    uint32_t req;        /* the machine's number for the broker's request */
    int attempt, opened; /* the discovery round (−1 none yet); a bargain open */
    double quantity, term;
    double until; /* agreed: when the host ends it */
    double at;    /* last used */
    /* The hosts' own: the basic seller's bundle request, the resource
     * seller's last price per unit and for the bundle, and the job and
     * service its resources serve with the machine's number for that job. */
    uint32_t bundle;
    double last_unit, last_rate;
    uint64_t parent;
    int serves;
    uint32_t group;
} bga_deal_t;

typedef struct bga_deals {
    bga_deal_t deal[BGA_DEALS_MAX];
    uint32_t next_req; /* the host's request sequence, from 1 */
} bga_deals_t;

void bga_deals_init(bga_deals_t *t);
/* The deal of (job, good), NULL when there is none. */
bga_deal_t *bga_deals_find(bga_deals_t *t, uint64_t job, int good);
/* The deal the machine numbers `req`, NULL when there is none. */
bga_deal_t *bga_deals_by_req(bga_deals_t *t, uint32_t req);
/* The deal of (job, good), a new one in talk if none (attempt −1, at
 * `now`): a free entry, else the least recently used one in talk. NULL
 * when every entry is agreed or the sequence is spent. */
bga_deal_t *bga_deals_for(bga_deals_t *t, uint64_t job, int good, double now);

#endif
