/*
 * The broker's host of the market agent machine (bgb_auction), driven
 * alone: the seller slots, buyers and request numbers it maps come back
 * in its matches and lists; a match callback that announces a seller
 * again (as the broker's order does) while the clearing's matches are
 * being handed out loses none of them; exclusions and need groups hold;
 * a forgotten seller or buyer is out of the market. Prices are checked
 * against the k-double definition worked out here by hand.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <math.h>
#include <string.h>

#include "bgb_auction.h"

#define EPS 1e-12
#define ROTFIT 0
#define SOLVE 1

/* What the test's sellers sell (goods, asks), by slot. */
static const unsigned goods_of[10] = {0, 0, 0, 2u, 0, 0, 0, 3u, 0, 1u};
static const double asks_of[10][3] = {[3] = {0, 4.0, 0}, [7] = {1.0, 2.0, 0}, [9] = {1.5, 0, 0}};

static void announce(bgb_auction_t *a, int slot, double free_slots)
{
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_auction_seller(a, slot, goods_of[slot], asks_of[slot], free_slots, &err),
                     BG_OK);
}

typedef struct seen {
    bgb_auction_t *a;
    int n;
    bgb_auction_match_t m[16];
} seen_t;

/* As the broker does on a match: it orders, and says the seller's room
 * again (its one slot is now in flight), from inside the callback. */
static void on_match(void *ctx, const bgb_auction_match_t *m)
{
    seen_t *s = ctx;
    assert_true(s->n < 16);
    s->m[s->n++] = *m;
    announce(s->a, m->slot, 0.0);
}

static void clear(bgb_auction_t *a, seen_t *s, double now)
{
    double next = 0;
    s->n = 0;
    assert_int_equal(bgb_auction_tick(a, now, on_match, s, &next, NULL), BG_OK);
    assert_true(next > now);
}

static void test_matches_map_back(void **state)
{
    (void)state;
    bgb_auction_t *a = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_auction_new(0.5, 0.2, 0.0, &a, &err), BG_OK);
    /* Slot 7 sells both services (asks 1 and 2), slot 3 only sparse
     * solve (ask 4); one free slot each. */
    announce(a, 7, 1.0);
    announce(a, 3, 1.0);
    /* Buyer 5 bids for a rotation fit at 10 and a sparse solve at 12. */
    assert_int_equal(bgb_auction_bid(a, 5, 41, 1, ROTFIT, 10.0, 3.0, 100.0, 1, NULL, 0, 0, &err),
                     BG_OK);
    assert_int_equal(bgb_auction_bid(a, 5, 42, 2, SOLVE, 12.0, 3.0, 100.0, 2, NULL, 0, 0, &err),
                     BG_OK);
    seen_t s = {.a = a};
    clear(a, &s, 1.0);
    /* Rotation fit clears first: bid 10 against ask 1 (slot 7), nothing
     * else in the book: [lo, hi] = [1, 10], and with no buyer left out the
     * price is the ask, 1. Slot 7's one slot is gone, so the solve bid 12
     * meets slot 3's ask 4: 4. The first match's callback announcing a
     * seller does not lose the second. */
    assert_int_equal(s.n, 2);
    assert_int_equal(s.m[0].buyer, 5);
    assert_int_equal(s.m[0].req, 41);
    assert_int_equal(s.m[0].attempt, 1);
    assert_int_equal(s.m[0].good, ROTFIT);
    assert_int_equal(s.m[0].slot, 7);
    assert_true(fabs(s.m[0].price - 1.0) < EPS && fabs(s.m[0].ask - 1.0) < EPS);
    assert_int_equal(s.m[1].req, 42);
    assert_int_equal(s.m[1].attempt, 2);
    assert_int_equal(s.m[1].slot, 3);
    assert_true(fabs(s.m[1].price - 4.0) < EPS && fabs(s.m[1].ask - 4.0) < EPS);

    /* Exclusions: both sellers free again; buyer 6's solve excludes slot
     * 7, the cheaper ask it is paired with first, so it is cleared alone
     * against slot 3's ask: [4, 12], nobody left out, 4. */
    announce(a, 7, 1.0);
    announce(a, 3, 1.0);
    const int not7[1] = {7};
    assert_int_equal(bgb_auction_bid(a, 6, 43, 1, SOLVE, 12.0, 1.0, 100.0, 1, not7, 1, 0, &err),
                     BG_OK);
    clear(a, &s, 2.0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.m[0].slot, 3);
    assert_true(fabs(s.m[0].price - 4.0) < EPS);

    /* A need group split over two: only slot 7 sells rotation fit, one
     * slot: one bid is matched, at [max(1, 10), 10] = 10 (the other bid
     * of 10 is the first excluded), and the other may not have slot 7
     * even when it is free again. */
    assert_int_equal(bgb_auction_bid(a, 8, 50, 1, ROTFIT, 10.0, 1.0, 100.0, 1, NULL, 0, 0, &err),
                     BG_OK);
    assert_int_equal(bgb_auction_bid(a, 8, 51, 1, ROTFIT, 10.0, 1.0, 100.0, 1, NULL, 0, 0, &err),
                     BG_OK);
    clear(a, &s, 3.0);
    assert_int_equal(s.n, 1);
    assert_int_equal(s.m[0].slot, 7);
    assert_int_equal(s.m[0].req, 50);
    assert_true(fabs(s.m[0].price - 10.0) < EPS);
    announce(a, 7, 1.0);
    clear(a, &s, 4.0);
    assert_int_equal(s.n, 0);
    /* Forgotten: buyer 8's waiting bid would take slot 9 now, but its job
     * ended; slot 3 left. */
    bgb_auction_forget_buyer(a, 8);
    bgb_auction_forget_seller(a, 3);
    announce(a, 9, 1.0);
    clear(a, &s, 5.0);
    assert_int_equal(s.n, 0);

    /* The directory: first fit in announcement order within the limit,
     * with room, leaving out what the query excludes. */
    int slots[BGB_AUCTION_MAX_LIST];
    double prices[BGB_AUCTION_MAX_LIST];
    int n = bgb_auction_query(a, 1, 60, ROTFIT, 1.6, NULL, 0, slots, prices, BGB_AUCTION_MAX_LIST,
                              6.0, &err);
    assert_int_equal(n, 2);
    assert_int_equal(slots[0], 7);
    assert_int_equal(slots[1], 9);
    assert_true(fabs(prices[0] - 1.0) < EPS && fabs(prices[1] - 1.5) < EPS);
    const int not9[1] = {9};
    n = bgb_auction_query(a, 1, 61, ROTFIT, 1.6, not9, 1, slots, prices, BGB_AUCTION_MAX_LIST, 6.0,
                          &err);
    assert_int_equal(n, 1);
    assert_int_equal(slots[0], 7);
    n = bgb_auction_query(a, 1, 62, SOLVE, 100.0, NULL, 0, slots, prices, BGB_AUCTION_MAX_LIST, 6.0,
                          &err);
    assert_int_equal(n, 1); /* slot 3 was forgotten */
    assert_int_equal(slots[0], 7);

    /* Bad arguments are refused with a message, never stored. */
    assert_int_equal(bgb_auction_seller(a, BGB_AUCTION_MAX_SELLERS, 1u, asks_of[9], 1.0, &err),
                     BG_ERR_INVALID);
    const int bad[1] = {-1};
    assert_int_equal(bgb_auction_bid(a, 1, 70, 1, ROTFIT, 1.0, 1.0, 9.0, 0, bad, 1, 0, &err),
                     BG_ERR_INVALID);
    assert_int_equal(bgb_auction_bid(a, BGB_AUCTION_MAX_BUYERS, 70, 1, ROTFIT, 1, 1, 9, 0, NULL, 0,
                                     0, &err),
                     BG_ERR_INVALID);
    assert_true(strlen(err.message) > 0);
    bgb_auction_destroy(&a);
    assert_null(a);
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(test_matches_map_back)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
