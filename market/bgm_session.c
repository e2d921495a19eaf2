#include "bgm_session.h"

#include <stdlib.h>
#include <string.h>

typedef struct slot {
    int used;
    bgm_session_t s;
} slot_t;

struct bgm_sessions {
    int n, next;
    slot_t slot[]; /* n of them */
};

bgm_sessions_t *bgm_sessions_new(int n)
{
    if (n <= 0 || n > BGM_SESSIONS_MAX)
        return NULL;
    bgm_sessions_t *ss = calloc(1, sizeof *ss + (size_t)n * sizeof ss->slot[0]);
    if (ss)
        ss->n = n;
    return ss;
}

void bgm_sessions_destroy(bgm_sessions_t **ss)
{
    if (!ss || !*ss)
        return;
    free(*ss);
    *ss = NULL;
}

static slot_t *find(bgm_sessions_t *ss, uint32_t buyer, uint32_t req, uint32_t attempt)
{
    for (int i = 0; i < ss->n; i++) {
        slot_t *x = &ss->slot[i];
        if (x->used && x->s.buyer == buyer && x->s.req == req && x->s.attempt == attempt)
            return x;
    }
    return NULL;
}

bgm_session_t *bgm_sessions_find(bgm_sessions_t *ss, uint32_t buyer, uint32_t req,
                                 uint32_t attempt)
{
    slot_t *x = find(ss, buyer, req, attempt);
    return x ? &x->s : NULL;
}

bgm_session_t *bgm_sessions_for(bgm_sessions_t *ss, const bgm_msg_t *m)
{
    slot_t *x = find(ss, m->from, m->req, m->attempt);
    if (m->hops != 1)
        return x ? &x->s : NULL;
    if (!x) {
        x = &ss->slot[ss->next];
        ss->next = (ss->next + 1) % ss->n;
    }
    memset(x, 0, sizeof *x);
    x->used = 1;
    x->s.buyer = m->from;
    x->s.req = m->req;
    x->s.attempt = m->attempt;
    return &x->s;
}
