#include "bga_deals.h"

#include <string.h>

void bga_deals_init(bga_deals_t *t)
{
    memset(t, 0, sizeof *t);
    t->next_req = 1;
}

bga_deal_t *bga_deals_find(bga_deals_t *t, uint64_t job, int good)
{
    for (int i = 0; i < BGA_DEALS_MAX; i++)
        if (t->deal[i].used && t->deal[i].job == job && t->deal[i].good == good)
            return &t->deal[i];
    return NULL;
}

bga_deal_t *bga_deals_by_req(bga_deals_t *t, uint32_t req)
{
    for (int i = 0; i < BGA_DEALS_MAX; i++)
        if (t->deal[i].used && t->deal[i].req == req)
            return &t->deal[i];
    return NULL;
}

bga_deal_t *bga_deals_for(bga_deals_t *t, uint64_t job, int good, double now)
{
    bga_deal_t *d = bga_deals_find(t, job, good);
    if (d) {
        d->at = now;
        return d;
    }
    for (int i = 0; i < BGA_DEALS_MAX; i++) {
        bga_deal_t *e = &t->deal[i];
        if (e->used && e->state != BGA_DEAL_TALK)
            continue;
        if (!d || !e->used || (d->used && e->at < d->at))
            d = e;
    }
    if (!d || t->next_req >= BGA_DEALS_REQ_END)
        return NULL;
    *d = (bga_deal_t){
        .used = 1, .job = job, .good = good, .req = t->next_req++, .attempt = -1, .at = now};
    return d;
}
