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
}

int main(void)
{
    const struct CMUnitTest tests[] = {cmocka_unit_test(round_trip), cmocka_unit_test(bad_input)};
    return cmocka_run_group_tests(tests, NULL, NULL);
}
