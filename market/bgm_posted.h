/*
 * bgm_posted — the baseline: a directory of posted prices with first-fit
 * matching, what a plain scheduler does.
 *
 * Sellers register (good, price) once; a query for a good returns the
 * sellers whose posted price is within the buyer's limit, in registration
 * order from a position the caller chooses (first fit from there, not
 * best price), up to a cap. The buyer then orders from them one after the
 * other until one has capacity. Pure.
 */
#ifndef BGM_POSTED_H
#define BGM_POSTED_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

typedef struct bgm_posted bgm_posted_t;

typedef struct bgm_posting {
    uint32_t seller;
    int good;
    double price;
} bgm_posting_t;

bgm_posted_t *bgm_posted_new(size_t max_postings);
void bgm_posted_destroy(bgm_posted_t **dir);
/* Registers or re-prices (seller, good). */
bg_status bgm_posted_post(bgm_posted_t *dir, uint32_t seller, int good, double price);
/* Removes every posting of a seller (it left the grid). */
void bgm_posted_withdraw(bgm_posted_t *dir, uint32_t seller);
/*
 * First fit from a position: writes up to max_out postings for `good`
 * with price <= limit and, when has_room is given, has_room(ctx, posting)
 * true (the caller's view of free capacity), scanning the postings in
 * registration order from position `start` (taken modulo their number)
 * and wrapping around. start = 0 is the classic first fit; a caller that
 * passes the position after the previous answer's first posting gets
 * next fit, which spreads simultaneous buyers over the sellers instead of
 * sending them all to the first ones. *first (when not NULL) receives the
 * position of the first posting written (unchanged when none is).
 */
size_t bgm_posted_query(const bgm_posted_t *dir, int good, double limit, size_t start,
                        int (*has_room)(void *ctx, const bgm_posting_t *p), void *ctx,
                        bgm_posting_t *out, size_t max_out, size_t *first);

#endif
