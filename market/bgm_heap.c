#include "bgm_heap.h"

#include <math.h>
#include <stdlib.h>

#define BGM_HEAP_INITIAL 64

struct bgm_heap {
    bgm_event_t *ev;
    size_t count;
    size_t alloc;
    size_t max;
    uint64_t next_seq;
};

bgm_heap_t *bgm_heap_new(size_t max_events)
{
    bgm_heap_t *h = calloc(1, sizeof *h);
    if (!h)
        return NULL;
    h->max = max_events;
    return h;
}

void bgm_heap_destroy(bgm_heap_t **heap)
{
    if (!heap || !*heap)
        return;
    bgm_heap_t *h = *heap;
    for (size_t i = 0; i < h->count; i++)
        free(h->ev[i].msg);
    free(h->ev);
    free(h);
    *heap = NULL;
}

static int before(const bgm_event_t *a, const bgm_event_t *b)
{
    if (a->time != b->time)
        return a->time < b->time;
    return a->seq < b->seq;
}

bg_status bgm_heap_push(bgm_heap_t *h, const bgm_event_t *ev)
{
    if (h->count >= h->max)
        return BG_ERR_LIMIT;
    if (h->count == h->alloc) {
        size_t n = h->alloc ? h->alloc * 2 : BGM_HEAP_INITIAL;
        if (n > h->max)
            n = h->max;
        bgm_event_t *p = realloc(h->ev, n * sizeof *p);
        if (!p)
            return BG_ERR_NOMEM;
        h->ev = p;
        h->alloc = n;
    }
    size_t i = h->count++;
    bgm_event_t e = *ev;
    e.seq = h->next_seq++;
    while (i > 0) {
        size_t parent = (i - 1) / 2;
        if (!before(&e, &h->ev[parent]))
            break;
        h->ev[i] = h->ev[parent];
        i = parent;
    }
    h->ev[i] = e;
    return BG_OK;
}

int bgm_heap_pop(bgm_heap_t *h, bgm_event_t *out)
{
    if (h->count == 0)
        return 0;
    *out = h->ev[0];
    bgm_event_t last = h->ev[--h->count];
    size_t i = 0;
    for (;;) {
        size_t l = 2 * i + 1, r = l + 1, m = i;
        const bgm_event_t *best = &last;
        if (l < h->count && before(&h->ev[l], best)) {
            m = l;
            best = &h->ev[l];
        }
        if (r < h->count && before(&h->ev[r], best))
            m = r;
        if (m == i)
            break;
        h->ev[i] = h->ev[m];
        i = m;
    }
    if (h->count > 0)
        h->ev[i] = last;
    return 1;
}

double bgm_heap_peek_time(const bgm_heap_t *h)
{
    return h->count ? h->ev[0].time : INFINITY;
}

size_t bgm_heap_size(const bgm_heap_t *h)
{
    return h->count;
}
