#include "bgm_outbox.h"

#include <stdlib.h>
#include <string.h>

struct bgm_outbox {
    bgm_out_item_t *items;
    size_t n, cap, max;
};

bgm_outbox_t *bgm_outbox_new(size_t max_items)
{
    if (max_items == 0)
        return NULL;
    bgm_outbox_t *ob = calloc(1, sizeof *ob);
    if (ob)
        ob->max = max_items;
    return ob;
}

void bgm_outbox_destroy(bgm_outbox_t **ob)
{
    if (!ob || !*ob)
        return;
    free((*ob)->items);
    free(*ob);
    *ob = NULL;
}

/* The next free item, growing the storage by doubling up to the cap. */
static bgm_out_item_t *next_item(bgm_outbox_t *ob, bg_status *st)
{
    if (ob->n == ob->cap) {
        if (ob->cap >= ob->max) {
            *st = BG_ERR_LIMIT;
            return NULL;
        }
        size_t cap = ob->cap ? 2 * ob->cap : 64;
        if (cap > ob->max)
            cap = ob->max;
        bgm_out_item_t *p = realloc(ob->items, cap * sizeof *p);
        if (!p) {
            *st = BG_ERR_NOMEM;
            return NULL;
        }
        ob->items = p;
        ob->cap = cap;
    }
    bgm_out_item_t *it = &ob->items[ob->n++];
    memset(it, 0, sizeof *it);
    *st = BG_OK;
    return it;
}

bg_status bgm_outbox_send(bgm_outbox_t *ob, const bgm_msg_t *msg)
{
    bg_status st;
    bgm_out_item_t *it = next_item(ob, &st);
    if (it)
        it->msg = *msg;
    return st;
}

bg_status bgm_outbox_timer(bgm_outbox_t *ob, uint32_t agent, double at, int kind, uint64_t arg)
{
    bg_status st;
    bgm_out_item_t *it = next_item(ob, &st);
    if (it) {
        it->is_timer = 1;
        it->agent = agent;
        it->at = at;
        it->kind = kind;
        it->arg = arg;
    }
    return st;
}

size_t bgm_outbox_count(const bgm_outbox_t *ob)
{
    return ob->n;
}

const bgm_out_item_t *bgm_outbox_item(const bgm_outbox_t *ob, size_t i)
{
    return &ob->items[i];
}

void bgm_outbox_clear(bgm_outbox_t *ob)
{
    ob->n = 0;
}

bgm_msg_t bgm_outbox_msg(int type, uint32_t from, uint32_t to, uint32_t req, uint32_t attempt)
{
    bgm_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = (uint16_t)type;
    m.from = from;
    m.to = to;
    m.req = req;
    m.attempt = attempt;
    return m;
}

void bgm_emitter_begin(bgm_emitter_t *e, bgm_outbox_t *out)
{
    e->out = out;
    e->failure = BG_OK;
}

void bgm_emitter_fail(bgm_emitter_t *e, bg_status st)
{
    if (e->failure == BG_OK)
        e->failure = st;
}

void bgm_emitter_send(bgm_emitter_t *e, const bgm_msg_t *m)
{
    bgm_emitter_fail(e, bgm_outbox_send(e->out, m));
}

void bgm_emitter_timer(bgm_emitter_t *e, double at, int kind, uint64_t arg)
{
    bgm_emitter_fail(e, bgm_outbox_timer(e->out, e->self, at, kind, arg));
}
