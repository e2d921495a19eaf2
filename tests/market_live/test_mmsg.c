/* bga_mmsg: a round trip keeps every field; malformed frames are refused
 * with a message naming the field or frame. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>
#include <math.h>

#include "bga_mmsg.h"

static void round_trip(void **state)
{
    (void)state;
    bga_mmsg_t m, d;
    bga_mmsg_init(&m, BGA_MM_REGISTER);
    m.job = 123456789012ull;
    m.agent = 7;
    snprintf(m.name, sizeof m.name, "r1");
    snprintf(m.endpoint, sizeof m.endpoint, "tcp://127.0.0.1:5555");
    m.services = 3;
    m.slots = 4;
    m.free_slots = 2;
    m.floor[1] = 1.25;
    m.prices[1] = 1.5;
    m.margin = 0.2;
    m.good = 1;
    m.hops = 2;
    m.attempt = 3;
    m.nneighbours = 2;
    m.neighbours[0] = 4;
    m.neighbours[1] = 9;
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&f, v);
    assert_true(bga_mmsg_is_market(v, f.count));
    assert_int_equal(bga_mmsg_decode(v, f.count, &d, &err), BG_OK);
    assert_int_equal(d.type, BGA_MM_REGISTER);
    assert_true(d.job == m.job);
    assert_int_equal(d.agent, 7);
    assert_string_equal(d.name, "r1");
    assert_string_equal(d.endpoint, m.endpoint);
    assert_int_equal(d.free_slots, 2);
    assert_true(d.floor[1] == 1.25 && d.prices[1] == 1.5 && d.margin == 0.2);
    assert_int_equal(d.attempt, 3);
    assert_int_equal(d.nneighbours, 2);
    assert_int_equal(d.neighbours[1], 9);
    bga_frames_free(&f);
}

/* Every type round-trips every field, at the caps of its texts and
 * neighbours, and carries its type in frame 0. */
static void every_type(void **state)
{
    (void)state;
    for (int t = BGA_MM_FIRST; t <= BGA_MM_LAST; t++) {
        bga_mmsg_t m, d;
        bga_mmsg_init(&m, t);
        /* REGISTERED names no job: its header's job carries the epoch. */
        m.job = t == BGA_MM_REGISTERED ? 0 : UINT64_MAX - (uint64_t)t;
        m.epoch = t == BGA_MM_REGISTERED ? ((uint64_t)1 << 53) - 1 : 0;
        m.agent = UINT32_MAX;
        m.target = 3;
        m.origin = 4;
        m.services = 7;
        m.resource = t & 1;
        m.slots = 4096;
        m.free_slots = 17;
        for (int g = 0; g < BGA_MMSG_GOODS; g++) {
            m.floor[g] = 0.1 * (g + 1);
            m.prices[g] = 1e15 / (g + 1);
        }
        m.margin = 0.2;
        m.load_slope = 0.5;
        m.cores = 64;
        m.memory = 1.5;
        m.free_cores = 0.25;
        m.free_memory = 1e-9;
        m.term = 3600;
        m.good = 4;
        m.hops = 16;
        m.attempt = 1000;
        m.quantity = 2;
        m.price = 0.1;
        m.parent = (uint64_t)1 << 53;
        m.serves = 2;
        m.nneighbours = BGA_MMSG_MAX_NEIGHBOURS;
        for (int i = 0; i < m.nneighbours; i++)
            m.neighbours[i] = (uint32_t)(INT32_MAX - i);
        memset(m.name, 'n', sizeof m.name - 1);
        memset(m.endpoint, 'e', sizeof m.endpoint - 1);
        memset(m.reason, 'r', sizeof m.reason - 1);
        bga_frames_t f;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
        bga_frame_t v[BGA_WIRE_MAX_FRAMES];
        bga_frames_view(&f, v);
        assert_true(bga_mmsg_is_market(v, f.count));
        assert_int_equal(v[0].data[6] | v[0].data[7] << 8, BGA_LIVE_FIRST - 1 + t);
        assert_int_equal(bga_mmsg_decode(v, f.count, &d, &err), BG_OK);
        bga_frames_free(&f);
        /* The struct has no padding holes that a copy would leave unset
         * (both were zeroed by init), so one comparison covers it all. */
        assert_memory_equal(&m, &d, sizeof m);
    }
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_LAST + 1);
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_not_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    assert_non_null(strstr(err.message, "unknown"));
    /* An epoch only in REGISTERED, at most 2^53, and REGISTERED no job. */
    const struct {
        int type;
        uint64_t job, epoch;
    } bad[] = {{BGA_MM_HEARTBEAT, 0, 5},
               {BGA_MM_REGISTERED, 0, ((uint64_t)1 << 53) + 1},
               {BGA_MM_REGISTERED, 9, 5}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        bga_mmsg_init(&m, bad[i].type);
        m.job = bad[i].job;
        m.epoch = bad[i].epoch;
        bg_error_clear(&err);
        assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_ERR_INVALID);
        assert_non_null(strstr(err.message, "epoch"));
    }
}

/* The layer-1 messages keep the role flag, the resource quantities, the
 * lease and the rates. */
static void resource_round_trip(void **state)
{
    (void)state;
    bga_mmsg_t m, d;
    bga_mmsg_init(&m, BGA_MM_RBOUGHT);
    m.job = 562949953421312ull + 7; /* a sub-job id: 2^49 + 7 */
    m.resource = 1;
    m.good = 1;
    m.cores = 2;
    m.memory = 4.5;
    m.free_cores = 1;
    m.free_memory = 3.25;
    m.term = 3600;
    m.prices[3] = 1.2e-5;
    m.prices[4] = 2.4e-6;
    m.price = 0.0951;
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&f, v);
    assert_int_equal(bga_mmsg_decode(v, f.count, &d, &err), BG_OK);
    assert_int_equal(d.type, BGA_MM_RBOUGHT);
    assert_string_equal(bga_mmsg_type_name(d.type), "rbought");
    assert_true(d.job == m.job);
    assert_int_equal(d.resource, 1);
    assert_true(d.cores == 2 && d.memory == 4.5 && d.free_cores == 1 && d.free_memory == 3.25);
    assert_true(d.term == 3600 && d.prices[3] == 1.2e-5 && d.prices[4] == 2.4e-6);
    assert_true(d.price == 0.0951);
    bga_frames_free(&f);
    /* A negative lease is refused before it is sent. */
    m.term = -1;
    assert_int_not_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    assert_non_null(strstr(err.message, "term"));
}

/* A valid HEARTBEAT's frames, copied so a test can break them. */
typedef struct frames_copy {
    int count;
    uint8_t data[BGA_WIRE_MAX_FRAMES][BGA_MMSG_MAX_BYTES + 64];
    size_t size[BGA_WIRE_MAX_FRAMES];
} frames_copy_t;

static void valid_frames(frames_copy_t *c)
{
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_HEARTBEAT);
    m.slots = 2;
    m.free_slots = 1;
    snprintf(m.name, sizeof m.name, "a1");
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    c->count = f.count;
    for (int i = 0; i < f.count; i++) {
        assert_true(f.size[i] <= sizeof c->data[i]);
        memcpy(c->data[i], f.data[i], f.size[i]);
        c->size[i] = f.size[i];
    }
    bga_frames_free(&f);
}

/* Decodes the (broken) frames and expects a failure naming `word`. */
static void refused(const frames_copy_t *c, const char *word)
{
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    for (int i = 0; i < c->count; i++)
        v[i] = (bga_frame_t){c->data[i], c->size[i]};
    bga_mmsg_t d;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_not_equal(bga_mmsg_decode(v, c->count, &d, &err), BG_OK);
    if (!strstr(err.message, word))
        fail_msg("'%s' does not name '%s'", err.message, word);
}

static void put_u64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static void put_f64(uint8_t *p, double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    put_u64(p, u);
}

/* The copy the broken cases start from decodes. */
static void valid_is_accepted(void **state)
{
    (void)state;
    frames_copy_t c;
    valid_frames(&c);
    assert_int_equal(c.count, 2 + BGA_LM_NARRAYS);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    for (int i = 0; i < c.count; i++)
        v[i] = (bga_frame_t){c.data[i], c.size[i]};
    assert_true(bga_mmsg_is_market(v, c.count));
    bga_mmsg_t d;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_decode(v, c.count, &d, &err), BG_OK);
    assert_int_equal(d.type, BGA_MM_HEARTBEAT);
    assert_int_equal(d.slots, 2);
    assert_string_equal(d.name, "a1");
}

static void bad_frames(void **state)
{
    (void)state;
    frames_copy_t c;
    valid_frames(&c);
    c.count--;
    refused(&c, "frames");
    valid_frames(&c);
    c.size[1] -= 8;
    char want[64];
    snprintf(want, sizeof want, "field frame has %d bytes, expected %d", 8 * BGA_LM_NFIELDS - 8,
             8 * BGA_LM_NFIELDS);
    refused(&c, want);
    valid_frames(&c);
    c.data[0][0] = 'X';
    refused(&c, "bgwp");
    valid_frames(&c);
    c.data[0][4] = 9; /* protocol version 9 */
    refused(&c, "version");
    valid_frames(&c);
    c.data[0][6] = 0x99; /* type 0x1199: no such type */
    refused(&c, "unknown message type 0x1199");
    valid_frames(&c);
    c.data[0][6] = 0x03; /* type 0x1003: a simulator market type, not a live one */
    c.data[0][7] = 0x10;
    refused(&c, "frames");
    valid_frames(&c);
    c.size[2 + BGA_LM_NAME] = BGA_MMSG_MAX_BYTES + 8; /* over the message cap */
    memset(c.data[2 + BGA_LM_NAME], 'a', c.size[2 + BGA_LM_NAME]);
    refused(&c, "cap");
}

static void bad_fields(void **state)
{
    (void)state;
    frames_copy_t c;
    valid_frames(&c);
    put_u64(c.data[1] + 8 * BGA_LM_HOPS, 99);
    refused(&c, "hops");
    valid_frames(&c);
    put_f64(c.data[1] + 8 * BGA_LM_PRICE, -1);
    refused(&c, "price");
    valid_frames(&c);
    put_f64(c.data[1] + 8 * BGA_LM_TERM, NAN);
    refused(&c, "term");
    valid_frames(&c);
    put_u64(c.data[1] + 8 * BGA_LM_FREE_SLOTS, 3); /* more free than its 2 slots */
    refused(&c, "free_slots");
    valid_frames(&c);
    put_u64(c.data[1] + 8 * BGA_LM_SERVES, 3); /* resources serve services 0..2 only */
    refused(&c, "serves");
    valid_frames(&c);
    put_u64(c.data[1] + 8 * BGA_LM_PARENT, ((uint64_t)1 << 53) + 1);
    refused(&c, "parent");
    valid_frames(&c);
    put_f64(c.data[2 + BGA_LM_CAPACITY] + 8 * 2, -2); /* free cores */
    refused(&c, "capacity");
    valid_frames(&c);
    c.size[2 + BGA_LM_FLOOR] -= 8;
    refused(&c, "floor");
    valid_frames(&c);
    c.size[2 + BGA_LM_NAME] = 100; /* over the 63 bytes of a name */
    memset(c.data[2 + BGA_LM_NAME], 'a', 100);
    refused(&c, "name");
    valid_frames(&c);
    c.data[2 + BGA_LM_NAME][1] = '\0';
    refused(&c, "NUL");
    valid_frames(&c);
    c.size[2 + BGA_LM_NEIGHBOURS] = 4 * (BGA_MMSG_MAX_NEIGHBOURS + 1);
    memset(c.data[2 + BGA_LM_NEIGHBOURS], 0, c.size[2 + BGA_LM_NEIGHBOURS]);
    refused(&c, "neighbours");
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(round_trip),
                                       cmocka_unit_test(every_type),
                                       cmocka_unit_test(resource_round_trip),
                                       cmocka_unit_test(valid_is_accepted),
                                       cmocka_unit_test(bad_frames),
                                       cmocka_unit_test(bad_fields)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
