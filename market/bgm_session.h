/*
 * bgm_session — a seller's side of its bargains: a fixed ring of
 * sessions, one per (buyer, request, attempt), each holding the seller's
 * bgm_nego_t for that bargain. Part of a seller's own state (the resource
 * seller's in bgm_resource, the basic seller's in bgm_seller): it never
 * reads a buyer's record, only the messages the seller is handed.
 *
 * A session is opened by an offer that says so (hops = 1 on an OFFER:
 * the buyer starts a bargain afresh); a later offer of the same attempt
 * finds it, an offer of another attempt does not (it is stale). The ring
 * is fixed: when it is full the oldest session is reused first, because
 * a seller bargains with a few buyers at a time and a forgotten bargain
 * only costs the buyer a timeout.
 */
#ifndef BGM_SESSION_H
#define BGM_SESSION_H

#include <stdint.h>

#include "bgm_catallactic.h"
#include "bgm_role.h"

typedef struct bgm_session {
    uint32_t buyer, req, attempt;
    int open; /* nego holds the seller's side (opened by its owner) */
    bgm_nego_t nego;
} bgm_session_t;

typedef struct bgm_sessions bgm_sessions_t;

/* A ring of n > 0 sessions, all free. NULL when out of memory or n is 0
 * or above BGM_SESSIONS_MAX. */
#define BGM_SESSIONS_MAX 4096
bgm_sessions_t *bgm_sessions_new(int n);
void bgm_sessions_destroy(bgm_sessions_t **ss);

/* The session of (buyer, req, attempt), NULL when there is none.
 * Borrowed: valid until the next bgm_sessions_for on the ring. */
bgm_session_t *bgm_sessions_find(bgm_sessions_t *ss, uint32_t buyer, uint32_t req,
                                 uint32_t attempt);

/* The session an OFFER belongs to (m->from, m->req, m->attempt): a fresh
 * one, not open, when the offer opens a bargain (m->hops == 1, which
 * also forgets an earlier session of that key), the existing one
 * otherwise, NULL when the offer continues a bargain the ring does not
 * hold (forgotten, or of another attempt). Borrowed, as above. */
bgm_session_t *bgm_sessions_for(bgm_sessions_t *ss, const bgm_msg_t *m);

#endif
