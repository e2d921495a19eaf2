/*
 * bgm_flood — passing a call for proposals over the agents' overlay, the
 * part every trading agent shares (the buying half, bgm_purchase, and the
 * resource seller): which neighbours a call goes to, and which calls an
 * agent has seen.
 *
 * A call's fan-out is capped so that a round of discovery costs a bounded
 * number of messages whatever degree the random overlay gave an agent:
 * its originator sends it to at most `cap` neighbours, and each agent that
 * passes it on to at most cap - 1 others (the link it came by counts as
 * one of its cap). With hops h a round then sends at most
 *     C(cap, h) = cap + cap (cap - 1) + ... + cap (cap - 1)^(h - 1)
 * calls, duplicates included (bgm_budget). An agent with more neighbours
 * than that picks a window of them, starting at a position drawn from the
 * call's key and its own id, so that calls spread over its links. Pure,
 * deterministic, no allocation.
 */
#ifndef BGM_FLOOD_H
#define BGM_FLOOD_H

#include <stdint.h>

#include "bgm_outbox.h"
#include "bgm_role.h"

#define BGM_FLOOD_SEEN 16

/* A call's identity: its originator, request and attempt. */
uint64_t bgm_flood_key(const bgm_msg_t *call);

/*
 * Emits the call `proto` to the caller's neighbours nbr[0..degree), except
 * `except` (the agent it came from; UINT32_MAX when the caller
 * originates it) and the call's originator, at most `cap` of them (cap
 * <= 0: all), each copy from the emitter's agent. Returns how many it
 * emitted.
 */
uint32_t bgm_flood_pass(bgm_emitter_t *em, const bgm_msg_t *proto, const uint32_t *nbr, int degree,
                        uint32_t except, int cap);

/* The calls an agent saw last: a ring of keys. */
typedef struct bgm_flood_seen {
    uint64_t key[BGM_FLOOD_SEEN];
    int pos;
} bgm_flood_seen_t;

/* Whether `key` was seen (it is remembered if not). */
int bgm_flood_seen(bgm_flood_seen_t *seen, uint64_t key);

#endif
