/*
 * bgm_outbox — what a role machine emits while it handles one message or
 * timer: messages to other agents and timers for itself, in emission
 * order. The host (the simulator's world, or a live daemon) drains it after
 * each call and routes the items in that order, so a role machine never
 * calls into a driver or another role.
 *
 * Messages are copied in; the outbox owns its items until cleared.
 * Capacity grows by doubling up to the cap given at creation; an item past
 * the cap is refused with BG_ERR_LIMIT.
 */
#ifndef BGM_OUTBOX_H
#define BGM_OUTBOX_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bgm_role.h"

typedef struct bgm_out_item {
    int is_timer;
    bgm_msg_t msg; /* a message (is_timer == 0) */
    /* a timer (is_timer == 1): fire (kind, arg) at `agent` at absolute time `at` */
    uint32_t agent;
    int kind;
    uint64_t arg;
    double at;
} bgm_out_item_t;

typedef struct bgm_outbox bgm_outbox_t;

/* max_items > 0 caps the items held between two clears. NULL when out of memory. */
bgm_outbox_t *bgm_outbox_new(size_t max_items);
void bgm_outbox_destroy(bgm_outbox_t **ob);

bg_status bgm_outbox_send(bgm_outbox_t *ob, const bgm_msg_t *msg);
bg_status bgm_outbox_timer(bgm_outbox_t *ob, uint32_t agent, double at, int kind, uint64_t arg);

size_t bgm_outbox_count(const bgm_outbox_t *ob);
/* Borrowed, valid until the next send, timer or clear; i < count. */
const bgm_out_item_t *bgm_outbox_item(const bgm_outbox_t *ob, size_t i);
/* Forgets every item, keeping the storage. */
void bgm_outbox_clear(bgm_outbox_t *ob);

/* A role machine's side of one call: the outbox it emits into and the
 * call's first failure, which sticks (a later failing emit does not hide
 * it) and is what the call returns. Each machine embeds one and sets
 * `self`, which stamps its timers. */
typedef struct bgm_emitter {
    bgm_outbox_t *out; /* the call's; borrowed */
    uint32_t self;
    bg_status failure;
} bgm_emitter_t;

/* Starts a call: emits into out, no failure yet. */
void bgm_emitter_begin(bgm_emitter_t *e, bgm_outbox_t *out);
/* Records st unless the call has failed already (BG_OK records nothing). */
void bgm_emitter_fail(bgm_emitter_t *e, bg_status st);
void bgm_emitter_send(bgm_emitter_t *e, const bgm_msg_t *m);
/* A timer for the machine itself: (kind, arg) at absolute time `at`. */
void bgm_emitter_timer(bgm_emitter_t *e, double at, int kind, uint64_t arg);

/* A message with its header set and every other field zero: what every
 * sender fills in before emitting. */
bgm_msg_t bgm_outbox_msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt);

#endif
