/* bga_mmsg: a round trip keeps every field; malformed bodies are refused
 * with a message naming the field or frame. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

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

/* Decodes a hand-written body and expects a failure naming `word`. */
static void refused(const char *body, int nframes, const char *word)
{
    const uint8_t head[6] = {'b', 'g', 'm', 'k', 3, 0};
    bga_frame_t v[3] = {{head, 6}, {(const uint8_t *)body, strlen(body)}, {head, 6}};
    bga_mmsg_t d;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_not_equal(bga_mmsg_decode(v, nframes, &d, &err), BG_OK);
    if (!strstr(err.message, word))
        fail_msg("'%s' does not name '%s'", err.message, word);
}

/* The body with one key's text swapped, refused naming `word`. */
static void replaced(const char *body, const char *from, const char *to, const char *word)
{
    char out[BGA_MMSG_MAX_BODY + 64];
    const char *p = strstr(body, from);
    assert_non_null(p);
    snprintf(out, sizeof out, "%.*s%s%s", (int)(p - body), body, to, p + strlen(from));
    refused(out, 2, word);
}

static void bad_input(void **state)
{
    (void)state;
    bga_mmsg_t m;
    bga_mmsg_init(&m, BGA_MM_HEARTBEAT);
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_mmsg_encode(&m, &f, &err), BG_OK);
    char body[BGA_MMSG_MAX_BODY + 2];
    memcpy(body, f.data[1], f.size[1]);
    body[f.size[1]] = '\0';
    bga_frames_free(&f);
    refused(body, 3, "frames");
    refused("[1,2]", 2, "JSON object");
    refused("{\"job\":1", 2, "JSON object");
    char edited[BGA_MMSG_MAX_BODY + 64];
    snprintf(edited, sizeof edited, "{\"bogus\":1,%s", body + 1);
    refused(edited, 2, "bogus");
    replaced(body, "\"hops\":0", "\"hops\":99", "hops");
    replaced(body, "\"price\":0", "\"price\":-1", "price");
    replaced(body, "\"name\":\"\"", "\"name\":7", "name");
    replaced(body, "\"free_cores\":0", "\"free_cores\":-2", "free_cores");
    replaced(body, "\"term\":0", "\"term\":\"long\"", "term");
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(round_trip),
                                       cmocka_unit_test(resource_round_trip),
                                       cmocka_unit_test(bad_input)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
