#include "bgm_flood.h"

uint64_t bgm_flood_key(const bgm_msg_t *m)
{
    return ((uint64_t)m->req << 20) ^ m->attempt ^ ((uint64_t)m->origin << 44);
}

/* splitmix64's finaliser: a well-mixed start position from a key. */
static uint64_t mix(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xbf58476d1ce4e5b9ULL;
    x ^= x >> 27;
    x *= 0x94d049bb133111ebULL;
    return x ^ (x >> 31);
}

uint32_t bgm_flood_pass(bgm_emitter_t *em, const bgm_msg_t *proto, const uint32_t *nbr, int degree,
                        uint32_t except, int cap)
{
    if (degree <= 0)
        return 0;
    /* The link the call came by is one of a relay's cap. */
    const int room = cap <= 0 ? degree : (except == UINT32_MAX ? cap : cap - 1);
    /* With room for every neighbour the order is the list's; otherwise
     * the window starts where the call's key and the agent put it. */
    const int start =
        room >= degree
            ? 0
            : (int)(mix(bgm_flood_key(proto) ^ ((uint64_t)em->self << 32)) % (uint64_t)degree);
    uint32_t n = 0;
    for (int j = 0; j < degree && (int)n < room; j++) {
        const uint32_t to = nbr[(start + j) % degree];
        if (to == except || to == proto->origin)
            continue;
        bgm_msg_t m = *proto;
        m.from = em->self;
        m.to = to;
        bgm_emitter_send(em, &m);
        n++;
    }
    return n;
}

int bgm_flood_seen(bgm_flood_seen_t *s, uint64_t key)
{
    for (int i = 0; i < BGM_FLOOD_SEEN; i++)
        if (s->key[i] == key)
            return 1;
    s->key[s->pos] = key;
    s->pos = (s->pos + 1) % BGM_FLOOD_SEEN;
    return 0;
}
