#include "bgm_posted.h"

#include <stdlib.h>

struct bgm_posted {
    bgm_posting_t *p;
    size_t n, max;
};

bgm_posted_t *bgm_posted_new(size_t max_postings)
{
    bgm_posted_t *d = calloc(1, sizeof *d);
    if (!d)
        return NULL;
    d->max = max_postings;
    d->p = calloc(max_postings ? max_postings : 1, sizeof *d->p);
    if (!d->p)
        bgm_posted_destroy(&d);
    return d;
}

void bgm_posted_destroy(bgm_posted_t **dir)
{
    if (!dir || !*dir)
        return;
    free((*dir)->p);
    free(*dir);
    *dir = NULL;
}

bg_status bgm_posted_post(bgm_posted_t *d, uint32_t seller, int good, double price)
{
    for (size_t i = 0; i < d->n; i++) {
        if (d->p[i].seller == seller && d->p[i].good == good) {
            d->p[i].price = price;
            return BG_OK;
        }
    }
    if (d->n >= d->max)
        return BG_ERR_LIMIT;
    d->p[d->n++] = (bgm_posting_t){seller, good, price};
    return BG_OK;
}

void bgm_posted_withdraw(bgm_posted_t *d, uint32_t seller)
{
    size_t w = 0;
    for (size_t i = 0; i < d->n; i++)
        if (d->p[i].seller != seller)
            d->p[w++] = d->p[i];
    d->n = w;
}

size_t bgm_posted_query(const bgm_posted_t *d, int good, double limit, size_t start,
                        int (*has_room)(void *ctx, const bgm_posting_t *p), void *ctx,
                        bgm_posting_t *out, size_t max_out, size_t *first)
{
    size_t k = 0;
    for (size_t j = 0; j < d->n && k < max_out; j++) {
        const size_t at = (start + j) % d->n;
        const bgm_posting_t *p = &d->p[at];
        if (p->good != good || p->price > limit || (has_room && !has_room(ctx, p)))
            continue;
        if (k == 0 && first)
            *first = at;
        out[k++] = *p;
    }
    return k;
}
