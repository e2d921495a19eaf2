/*
 * Unit tests of bgm_codec: every market message type survives a round
 * trip through the wire framing unchanged (the simulator's generic message
 * and the roles' typed one), and malformed frames are refused with the
 * code and field that name the problem (NaN, out-of-range fields, agent
 * ids, candidate counts, truncation, unknown types).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_mesh.h"
#include "bgm_codec.h"
#include "bgm_outbox.h"

/* bga_wire repeats the engine's mesh caps so the base library needs no
 * engine header; they must agree. */
_Static_assert(BGA_WIRE_MAX_VERTICES == BG_MESH_MAX_VERTICES, "vertex caps differ");
_Static_assert(BGA_WIRE_MAX_ELEMENTS == BG_MESH_MAX_ELEMENTS, "element caps differ");

#define NTYPES (BGM_RM_LAST - BGM_RM_FIRST + 1)

/* A generic message of world type t with every field set to a value that
 * depends on t, so a field swapped or dropped by the codec shows. */
static bgm_msg_t sample(int t)
{
    bgm_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = (uint16_t)t;
    m.good = (int16_t)(t % 6 - 1);
    m.hops = (uint16_t)(t * 3);
    m.ncand = (uint16_t)(t % 9);
    m.from = (uint32_t)(1000 + t);
    m.to = (uint32_t)(2000 + 7 * t);
    m.req = UINT32_MAX - (uint32_t)t;
    m.attempt = (uint32_t)t * 11u;
    m.origin = (uint32_t)(4000000000u + (uint32_t)t);
    m.price = 1.0 / 3.0 + t;
    m.a = -0.1 * t;
    m.b = t == 19 ? INFINITY : 1e-300 * t; /* an unbounded limit is allowed */
    m.c = -INFINITY;
    for (int i = 0; i < BGM_MSG_CANDIDATES; i++) {
        m.cand[i] = (uint32_t)(t * 100 + i);
        m.cand_price[i] = 0.5 * i + t;
        m.cand_speed[i] = 1e9 / (i + 1);
    }
    return m;
}

static void assert_msg_equal(const bgm_msg_t *a, const bgm_msg_t *b)
{
    assert_int_equal(a->type, b->type);
    assert_int_equal(a->good, b->good);
    assert_int_equal(a->hops, b->hops);
    assert_int_equal(a->ncand, b->ncand);
    assert_int_equal(a->from, b->from);
    assert_int_equal(a->to, b->to);
    assert_int_equal(a->req, b->req);
    assert_int_equal(a->attempt, b->attempt);
    assert_int_equal(a->origin, b->origin);
    /* Bit-exact doubles (memcmp, so −0 and +0 would differ too). */
    assert_memory_equal(&a->price, &b->price, sizeof a->price);
    assert_memory_equal(&a->a, &b->a, sizeof a->a);
    assert_memory_equal(&a->b, &b->b, sizeof a->b);
    assert_memory_equal(&a->c, &b->c, sizeof a->c);
    assert_memory_equal(a->cand, b->cand, sizeof a->cand);
    assert_memory_equal(a->cand_price, b->cand_price, sizeof a->cand_price);
    assert_memory_equal(a->cand_speed, b->cand_speed, sizeof a->cand_speed);
}

static bga_wire_code roundtrip(const bgm_msg_t *m, bgm_msg_t *back, bga_wire_error_t *werr)
{
    bga_frames_t fr = {0};
    bg_error_t err;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(m, 42, 7, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    bga_wire_code c = bgm_codec_decode_msg(v, fr.count, back, werr);
    bga_frames_free(&fr);
    return c;
}

static void test_generic_roundtrip_every_type(void **state)
{
    (void)state;
    for (int t = 1; t <= NTYPES; t++) {
        bgm_msg_t m = sample(t), back;
        bga_wire_error_t werr;
        assert_int_equal(roundtrip(&m, &back, &werr), BGA_WIRE_OK);
        assert_msg_equal(&m, &back);
        assert_true(bgm_codec_type_known((uint16_t)(0x1000 + t)));
        assert_string_not_equal(bgm_codec_type_name((uint16_t)(0x1000 + t)), "unknown");
    }
    assert_false(bgm_codec_type_known(0x1000));
    assert_false(bgm_codec_type_known(0x101a));
}

/* Typed → generic → wire → typed gives the same typed message, for
 * every type (compared through the generic form, which has no padding
 * or union slack). */
/* Typed → wire → typed; the decoder's answer. */
static bga_wire_code typed_roundtrip(const bgm_role_msg_t *m, bgm_role_msg_t *back)
{
    bg_error_t err;
    memset(&err, 0, sizeof err);
    bga_frames_t fr = {0};
    assert_int_equal(bgm_codec_encode(m, 9, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    bga_wire_error_t werr;
    bga_wire_code c = bgm_codec_decode(v, fr.count, back, &werr);
    bga_frames_free(&fr);
    return c;
}

static void test_typed_roundtrip_every_type(void **state)
{
    (void)state;
    for (int t = 1; t <= NTYPES; t++) {
        bgm_msg_t g = sample(t);
        g.ncand = (uint16_t)(t % 9);
        bgm_role_msg_t typed, back;
        bg_error_t err;
        memset(&err, 0, sizeof err);
        assert_int_equal(bgm_codec_from_generic(&g, &typed, &err), BG_OK);
        assert_int_equal(typed.type, 0x1000 + t);
        typed.job = 0x0123456789abcdefULL;
        assert_int_equal(typed_roundtrip(&typed, &back), BGA_WIRE_OK);
        assert_int_equal(back.job, typed.job);
        bgm_msg_t g1, g2;
        assert_int_equal(bgm_codec_to_generic(&typed, &g1, &err), BG_OK);
        assert_int_equal(bgm_codec_to_generic(&back, &g2, &err), BG_OK);
        assert_msg_equal(&g1, &g2);
    }
}

/* What the market agent reads of a bid or a resource seller travels in
 * the typed messages too: a resource bid's deadline, a seller's memory
 * cost, a service bid's deadline where the world's generic message has it. */
static void test_typed_fields_market_agent_reads(void **state)
{
    (void)state;
    bg_error_t err;
    memset(&err, 0, sizeof err);
    bgm_role_msg_t r;
    memset(&r, 0, sizeof r);
    bgm_msg_t g;
    r.type = BGM_RM_RBID;
    r.u.rbid = (bgm_rm_rbid_t){2.0, 4.0, 6e9, 1.5, 42.25};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.cand_price[0] == 42.25 && g.a == 2.0 && g.b == 4.0 && g.c == 6e9);
    bgm_role_msg_t back;
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.rbid.deadline == 42.25 && back.u.rbid.limit_total == 1.5);
    r.type = BGM_RM_RASK;
    r.u.rask = (bgm_rm_rask_t){4.0, 8.0, 1e9, 0.05, 0.0125};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.cand_price[0] == 0.0125 && g.price == 0.05);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.rask.memory_cost_rate == 0.0125);
    r.type = BGM_RM_BID;
    r.u.bid = (bgm_rm_bid_t){1, 3.0, 5.0, 77.5, 0, 0, {0}};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.b == 77.5 && g.cand_price[0] == 77.5);
    /* A live bid's exclusions and need group; a query's bundle size and
     * exclusions. */
    r.u.bid = (bgm_rm_bid_t){1, 3.0, 5.0, 77.5, 4, 2, {21, 13}};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.origin == 4 && g.ncand == 2 && g.cand[0] == 21 && g.cand[1] == 13);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.bid.group == 4 && back.u.bid.nexclude == 2 && back.u.bid.exclude[1] == 13);
    r.u.bid.nexclude = BGM_ROLE_CANDIDATES + 1;
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_ERR_INVALID);
    r.type = BGM_RM_QUERY;
    r.u.query = (bgm_rm_query_t){BGM_GOOD_CORES_ID, 9.0, 2.0, 0.5, 1, {7}};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.a == 2.0 && g.b == 0.5 && g.ncand == 1 && g.cand[0] == 7);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.query.cores == 2.0 && back.u.query.memory == 0.5 &&
                back.u.query.nexclude == 1 && back.u.query.exclude[0] == 7);
    g.ncand = BGM_ROLE_CANDIDATES + 1;
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_ERR_INVALID);
    /* What a resource seller reads of a buyer's offer, order and award. */
    r.type = BGM_RM_OFFER;
    r.u.price = (bgm_rm_price_t){0.4, -1, 1, 2.0, 3.0, 8e9, 9.5, 61.0};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.good == -1 && g.hops == 1 && g.a == 2.0 && g.b == 3.0 && g.c == 8e9);
    assert_true(g.cand_price[1] == 9.5 && g.cand_price[2] == 61.0 && g.price == 0.4);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.price.opening == 1 && back.u.price.valid_until == 61.0 &&
                back.u.price.budget == 9.5 && back.u.price.good == -1);
    r.type = BGM_RM_ORDER;
    r.u.order = (bgm_rm_order_t){-1, 0.3, 1.0, 2.0, 4e9, 7.0, 33.0};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.cand_price[1] == 7.0 && g.cand_price[2] == 33.0);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.order.budget == 7.0 && back.u.order.valid_until == 33.0);
    r.type = BGM_RM_RAWARD;
    r.u.raward = (bgm_rm_raward_t){12, 0.2, 2.0, 4.0, 6e9, 0.0, 5.5};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.cand_price[1] == 5.5 && g.origin == 12);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.raward.budget == 5.5);
}

/* Spot checks that typed fields land where the world reads them. */
static void test_typed_field_meaning(void **state)
{
    (void)state;
    bgm_role_msg_t r;
    memset(&r, 0, sizeof r);
    r.type = BGM_RM_BID;
    r.u.bid = (bgm_rm_bid_t){1, 2.5, 4.0, 30.0, 0, 0, {0}};
    bgm_msg_t g;
    bg_error_t err;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_int_equal(g.type, 1);
    assert_int_equal(g.good, 1);
    assert_true(g.price == 2.5 && g.a == 4.0 && g.b == 30.0);
    r.type = BGM_RM_LIST;
    r.u.list.ncand = 2;
    r.u.list.cand[0] = 5;
    r.u.list.cand[1] = 9;
    r.u.list.cand_price[1] = 1.25;
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_int_equal(g.ncand, 2);
    assert_int_equal(g.cand[1], 9);
    assert_true(g.cand_price[1] == 1.25);
    r.u.list.ncand = BGM_ROLE_CANDIDATES + 1;
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_ERR_INVALID);
    r.type = 0x1099;
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_ERR_INVALID);
}

static void test_encode_refuses(void **state)
{
    (void)state;
    bga_frames_t fr = {0};
    bg_error_t err;
    memset(&err, 0, sizeof err);
    bgm_msg_t m = sample(4);
    m.price = NAN;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "price"));
    m = sample(4);
    m.good = 5;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    if (!strstr(err.message, "good"))
        fail_msg("message: %s", err.message);
    m = sample(4);
    m.ncand = BGM_MSG_CANDIDATES + 1;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "ncand"));
    m = sample(4);
    m.cand_speed[3] = INFINITY; /* candidate numbers must be finite */
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    m = sample(4);
    m.to = 1u << 24; /* not an agent id */
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    m = sample(4);
    m.type = 0;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
    m.type = BGM_MT_REFUSE + 1;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 0, 0, &fr, &err), BG_ERR_INVALID);
}

/* The delivery handshake's messages (a basic seller's CONFIRM and the
 * buyer's TAKE or REFUSE) carry the seller's bundle number both ways, and
 * what the buyer reads of a MATCH's deal (the seller's limit, the
 * deadline) lands where the world reads it; a TAKE naming no agent, or
 * with a NaN where a number goes, is refused. */
static void test_delivery_messages(void **state)
{
    (void)state;
    bg_error_t err;
    memset(&err, 0, sizeof err);
    bgm_role_msg_t r, back;
    memset(&r, 0, sizeof r);
    bgm_msg_t g;
    r.type = BGM_RM_CONFIRM;
    r.from = 7;
    r.to = 2;
    r.req = 40;
    r.attempt = 3;
    r.u.confirm = (bgm_rm_confirm_t){912, 1.75, 10.5, 14.25};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_int_equal(g.type, BGM_MT_CONFIRM);
    assert_true(g.origin == 912 && g.price == 1.75 && g.a == 10.5 && g.b == 14.25);
    assert_int_equal(typed_roundtrip(&r, &back), BGA_WIRE_OK);
    assert_true(back.u.confirm.bundle == 912 && back.u.confirm.end == 14.25 && back.req == 40 &&
                back.attempt == 3);
    for (uint16_t t = BGM_RM_TAKE; t <= BGM_RM_REFUSE; t++) {
        memset(&r, 0, sizeof r);
        r.type = t;
        r.from = 2;
        r.to = 7;
        r.req = 40;
        r.u.take.bundle = 912;
        assert_int_equal(typed_roundtrip(&r, &back), BGA_WIRE_OK);
        assert_int_equal(back.type, t);
        assert_int_equal(back.u.take.bundle, 912);
        assert_string_not_equal(bgm_codec_type_name(t), "unknown");
    }
    memset(&r, 0, sizeof r);
    r.type = BGM_RM_MATCH;
    r.u.match = (bgm_rm_match_t){1, 3, 2.5, 4.0, 1.25, 88.0};
    assert_int_equal(bgm_codec_to_generic(&r, &g, &err), BG_OK);
    assert_true(g.origin == 3 && g.a == 4.0 && g.b == 1.25 && g.c == 88.0);
    assert_int_equal(bgm_codec_from_generic(&g, &back, &err), BG_OK);
    assert_true(back.u.match.seller_limit == 1.25 && back.u.match.deadline == 88.0);

    bga_frames_t fr = {0};
    bgm_msg_t bad = bgm_outbox_msg(BGM_MT_TAKE, 2, 1u << 24, 40, 0);
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&bad, 0, 0, &fr, &err), BG_ERR_INVALID);
    bad = bgm_outbox_msg(BGM_MT_REFUSE, 2, 7, 40, 0);
    bad.a = NAN;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&bad, 0, 0, &fr, &err), BG_ERR_INVALID);
    assert_true(err.message[0] != '\0');
}

/* Encodes a valid message, lets `edit` damage a copy of its frames, and
 * returns what decoding says. */
static bga_wire_code decode_damaged(void (*edit)(uint8_t *f[], size_t n[], int *count),
                                    bga_wire_error_t *werr)
{
    bgm_msg_t m = sample(13), back;
    bga_frames_t fr = {0};
    bg_error_t err;
    memset(&err, 0, sizeof err);
    assert_int_equal(bgm_codec_encode_msg(&m, 1, 1, &fr, &err), BG_OK);
    uint8_t *f[BGA_WIRE_MAX_FRAMES];
    size_t n[BGA_WIRE_MAX_FRAMES];
    int count = fr.count;
    for (int i = 0; i < count; i++) {
        f[i] = malloc(fr.size[i] ? fr.size[i] : 1);
        assert_non_null(f[i]);
        memcpy(f[i], fr.data[i], fr.size[i]);
        n[i] = fr.size[i];
    }
    const int allocated = count;
    edit(f, n, &count);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    for (int i = 0; i < count; i++)
        v[i] = (bga_frame_t){f[i], n[i]};
    bga_wire_code c = bgm_codec_decode_msg(v, count, &back, werr);
    for (int i = 0; i < allocated; i++)
        free(f[i]);
    bga_frames_free(&fr);
    return c;
}

static void put_f64(uint8_t *p, double v)
{
    uint64_t u;
    memcpy(&u, &v, sizeof u);
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(u >> (8 * i));
}

static void put_i64(uint8_t *p, int64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)((uint64_t)v >> (8 * i));
}

static void nan_price(uint8_t *f[], size_t n[], int *count)
{
    put_f64(f[1] + 8 * BGA_MK_PRICE, NAN);
}
static void big_good(uint8_t *f[], size_t n[], int *count)
{
    put_i64(f[1] + 8 * BGA_MK_GOOD, 5);
}
static void negative_req(uint8_t *f[], size_t n[], int *count)
{
    put_i64(f[1] + 8 * BGA_MK_REQ, -1);
}
static void big_hops(uint8_t *f[], size_t n[], int *count)
{
    put_i64(f[1] + 8 * BGA_MK_HOPS, 65536);
}
static void nan_candidate(uint8_t *f[], size_t n[], int *count)
{
    put_f64(f[2 + BGA_MK_CAND_PRICE] + 8 * 2, NAN);
}
static void negative_candidate(uint8_t *f[], size_t n[], int *count)
{
    f[2 + BGA_MK_CAND][4 * 1 + 3] = 0x80; /* cand[1] < 0 */
}
static void big_receiver(uint8_t *f[], size_t n[], int *count)
{
    put_i64(f[0] + 32, (int64_t)1 << 24);
}
static void short_scalars(uint8_t *f[], size_t n[], int *count)
{
    n[1] -= 8;
}
static void short_array(uint8_t *f[], size_t n[], int *count)
{
    n[2 + BGA_MK_CAND_SPEED] -= 8;
}
static void missing_array(uint8_t *f[], size_t n[], int *count)
{
    *count -= 1;
}
static void foreign_type(uint8_t *f[], size_t n[], int *count)
{
    f[0][6] = 0x1a; /* type 0x101a, outside the market range and the table */
    f[0][7] = 0x10;
}

static void test_decode_refuses(void **state)
{
    (void)state;
    struct {
        void (*edit)(uint8_t *f[], size_t n[], int *count);
        bga_wire_code code;
        const char *field;
    } cases[] = {
        {nan_price, BGA_WIRE_NOT_FINITE, "price"},
        {big_good, BGA_WIRE_OUT_OF_RANGE, "good"},
        {negative_req, BGA_WIRE_OUT_OF_RANGE, "req"},
        {big_hops, BGA_WIRE_OUT_OF_RANGE, "hops"},
        {nan_candidate, BGA_WIRE_NOT_FINITE, "cand_price"},
        {negative_candidate, BGA_WIRE_OUT_OF_RANGE, "cand"},
        {big_receiver, BGA_WIRE_OUT_OF_RANGE, "receiver"},
        {short_scalars, BGA_WIRE_TRUNCATED, ""},
        {short_array, BGA_WIRE_BAD_LENGTH, "cand_speed"},
        {missing_array, BGA_WIRE_FRAME_COUNT, ""},
        {foreign_type, BGA_WIRE_UNKNOWN_TYPE, ""},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        bga_wire_error_t werr;
        memset(&werr, 0, sizeof werr);
        bga_wire_code c = decode_damaged(cases[i].edit, &werr);
        if (c != cases[i].code)
            fail_msg("case %zu: code %s (%s), expected %s", i, bga_wire_code_name(c),
                     werr.message, bga_wire_code_name(cases[i].code));
        if (cases[i].field[0])
            assert_string_equal(werr.field, cases[i].field);
    }
}

/* A valid non-market message is refused as unexpected, not misread. */
static void test_decode_non_market(void **state)
{
    (void)state;
    bga_msg_t hb;
    bga_msg_init(&hb, BGA_HEARTBEAT, 0, 0);
    hb.field[BGA_HB_SLOTS].i = 2;
    bga_frames_t fr = {0};
    bg_error_t err;
    memset(&err, 0, sizeof err);
    assert_int_equal(bga_wire_encode(&hb, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    bgm_msg_t m;
    bga_wire_error_t werr;
    assert_int_equal(bgm_codec_decode_msg(v, fr.count, &m, &werr), BGA_WIRE_UNEXPECTED);
    bga_frames_free(&fr);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_generic_roundtrip_every_type),
        cmocka_unit_test(test_typed_roundtrip_every_type),
        cmocka_unit_test(test_typed_fields_market_agent_reads),
        cmocka_unit_test(test_typed_field_meaning),
        cmocka_unit_test(test_encode_refuses),
        cmocka_unit_test(test_delivery_messages),
        cmocka_unit_test(test_decode_refuses),
        cmocka_unit_test(test_decode_non_market),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
