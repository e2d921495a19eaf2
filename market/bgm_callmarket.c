#include "bgm_callmarket.h"

#include <math.h>
#include <stdlib.h>

struct bgm_callmarket {
    bgm_order_t *bids;
    bgm_order_t *asks;
    size_t nbid, nask, max;
};

bgm_callmarket_t *bgm_callmarket_new(size_t max_orders)
{
    bgm_callmarket_t *cm = calloc(1, sizeof *cm);
    if (!cm)
        return NULL;
    cm->max = max_orders;
    cm->bids = calloc(max_orders ? max_orders : 1, sizeof *cm->bids);
    cm->asks = calloc(max_orders ? max_orders : 1, sizeof *cm->asks);
    if (!cm->bids || !cm->asks)
        bgm_callmarket_destroy(&cm);
    return cm;
}

void bgm_callmarket_destroy(bgm_callmarket_t **cm)
{
    if (!cm || !*cm)
        return;
    free((*cm)->bids);
    free((*cm)->asks);
    free(*cm);
    *cm = NULL;
}

void bgm_callmarket_reset(bgm_callmarket_t *cm)
{
    cm->nbid = cm->nask = 0;
}

static bg_status add(bgm_order_t *side, size_t *n, size_t max, const bgm_order_t *o)
{
    if (o->quantity <= 0 || !(o->price >= 0.0))
        return BG_ERR_INVALID;
    if (*n >= max)
        return BG_ERR_LIMIT;
    side[(*n)++] = *o;
    return BG_OK;
}

bg_status bgm_callmarket_bid(bgm_callmarket_t *cm, const bgm_order_t *o)
{
    return add(cm->bids, &cm->nbid, cm->max, o);
}

bg_status bgm_callmarket_ask(bgm_callmarket_t *cm, const bgm_order_t *o)
{
    return add(cm->asks, &cm->nask, cm->max, o);
}

size_t bgm_callmarket_bid_count(const bgm_callmarket_t *cm) { return cm->nbid; }
size_t bgm_callmarket_ask_count(const bgm_callmarket_t *cm) { return cm->nask; }
const bgm_order_t *bgm_callmarket_bids(const bgm_callmarket_t *cm) { return cm->bids; }
const bgm_order_t *bgm_callmarket_asks(const bgm_callmarket_t *cm) { return cm->asks; }

/* Sort keys: index arrays so fills can name the book's own positions. */
typedef struct keyed {
    size_t index;
    double price;
    uint64_t ref;
} keyed_t;

static int cmp_bid(const void *pa, const void *pb)
{
    const keyed_t *a = pa, *b = pb;
    if (a->price != b->price)
        return a->price > b->price ? -1 : 1;
    return (a->ref > b->ref) - (a->ref < b->ref);
}

static int cmp_ask(const void *pa, const void *pb)
{
    const keyed_t *a = pa, *b = pb;
    if (a->price != b->price)
        return a->price < b->price ? -1 : 1;
    return (a->ref > b->ref) - (a->ref < b->ref);
}

static bgm_bound_t bound(const bgm_order_t *o, int is_bid, int excluded)
{
    return (bgm_bound_t){is_bid, excluded, o->owner, o->ref, o->price};
}

bg_status bgm_callmarket_clear(bgm_callmarket_t *cm, double k, bgm_clearing_t *res,
                               bgm_fill_t *fills, size_t max_fills)
{
    bg_status st = BG_OK;
    keyed_t *kb = NULL, *ka = NULL;
    res->volume = 0;
    res->price = 0.0;
    res->bid_limit = res->ask_limit = 0.0;
    res->bid_excluded = -INFINITY;
    res->ask_excluded = INFINITY;
    res->low = res->high = 0.0;
    res->low_by = res->high_by = (bgm_bound_t){0};
    res->rationed = 0;
    res->fill_count = 0;
    if (!(k >= 0.0 && k <= 1.0))
        return BG_ERR_INVALID;
    if (cm->nbid == 0 || cm->nask == 0)
        return BG_OK;
    kb = malloc(cm->nbid * sizeof *kb);
    ka = malloc(cm->nask * sizeof *ka);
    if (!kb || !ka) {
        st = BG_ERR_NOMEM;
        goto out;
    }
    for (size_t i = 0; i < cm->nbid; i++)
        kb[i] = (keyed_t){i, cm->bids[i].price, cm->bids[i].ref};
    for (size_t i = 0; i < cm->nask; i++)
        ka[i] = (keyed_t){i, cm->asks[i].price, cm->asks[i].ref};
    qsort(kb, cm->nbid, sizeof *kb, cmp_bid);
    qsort(ka, cm->nask, sizeof *ka, cmp_ask);

    size_t ib = 0, ia = 0;
    int rem_b = cm->bids[kb[0].index].quantity, rem_a = cm->asks[ka[0].index].quantity;
    while (ib < cm->nbid && ia < cm->nask && kb[ib].price >= ka[ia].price) {
        int q = rem_b < rem_a ? rem_b : rem_a;
        if (res->fill_count >= max_fills) {
            st = BG_ERR_LIMIT;
            goto out;
        }
        fills[res->fill_count++] = (bgm_fill_t){kb[ib].index, ka[ia].index, q};
        res->volume += q;
        res->bid_limit = kb[ib].price;
        res->ask_limit = ka[ia].price;
        rem_b -= q;
        rem_a -= q;
        if (rem_b == 0 && ++ib < cm->nbid)
            rem_b = cm->bids[kb[ib].index].quantity;
        if (rem_a == 0 && ++ia < cm->nask)
            rem_a = cm->asks[ka[ia].index].quantity;
    }
    /* What is left at ib / ia (a partly filled order's rest included) is
     * the first excluded unit of each side. */
    if (ib < cm->nbid)
        res->bid_excluded = kb[ib].price;
    if (ia < cm->nask)
        res->ask_excluded = ka[ia].price;
    if (res->volume > 0) {
        const bgm_fill_t *last = &fills[res->fill_count - 1];
        const bgm_bound_t bm = bound(&cm->bids[last->bid], 1, 0);
        const bgm_bound_t am = bound(&cm->asks[last->ask], 0, 0);
        res->low_by = am;
        res->high_by = bm;
        if (ib < cm->nbid && res->bid_excluded > res->ask_limit)
            res->low_by = bound(&cm->bids[kb[ib].index], 1, 1);
        if (ia < cm->nask && res->ask_excluded < res->bid_limit)
            res->high_by = bound(&cm->asks[ka[ia].index], 0, 1);
        res->low = res->low_by.price;
        res->high = res->high_by.price;
        /* A buyer left out who would pay the marginal ask: buyers
         * compete, and k places the price (see the header). */
        res->rationed = ib < cm->nbid && res->bid_excluded >= res->ask_limit;
        res->price = res->rationed ? res->low + k * (res->high - res->low) : res->low;
    }
out:
    free(kb);
    free(ka);
    return st;
}

static void compact(bgm_order_t *side, size_t *n)
{
    size_t w = 0;
    for (size_t i = 0; i < *n; i++)
        if (side[i].quantity > 0)
            side[w++] = side[i];
    *n = w;
}

void bgm_callmarket_remove_filled(bgm_callmarket_t *cm, const bgm_fill_t *fills, size_t count)
{
    for (size_t i = 0; i < count; i++) {
        cm->bids[fills[i].bid].quantity -= fills[i].quantity;
        cm->asks[fills[i].ask].quantity -= fills[i].quantity;
    }
    compact(cm->bids, &cm->nbid);
    compact(cm->asks, &cm->nask);
}

void bgm_callmarket_filter(bgm_callmarket_t *cm, int (*keep)(const bgm_order_t *, int, void *),
                           void *ctx)
{
    for (size_t i = 0; i < cm->nbid; i++)
        if (!keep(&cm->bids[i], 1, ctx))
            cm->bids[i].quantity = 0;
    for (size_t i = 0; i < cm->nask; i++)
        if (!keep(&cm->asks[i], 0, ctx))
            cm->asks[i].quantity = 0;
    compact(cm->bids, &cm->nbid);
    compact(cm->asks, &cm->nask);
}
