/*
 * The broker's limits: the job size caps derived from the machine's RAM
 * invert the memory model exactly (the largest job whose estimated peak
 * fits the budget), a configuration's own caps are kept, and the
 * configuration file's limit keys are read with their ranges.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bgb_config.h"
#include "bgb_limits.h"

static void caps_invert_the_memory_model(void **state)
{
    (void)state;
    const uint64_t rams[] = {(uint64_t)1 << 30, (uint64_t)24 << 30, (uint64_t)1 << 40};
    for (size_t i = 0; i < sizeof rams / sizeof rams[0]; i++) {
        bgb_limits_t l;
        bgb_limits_default(&l);
        bgb_limits_resolve(&l, rams[i]);
        const double budget = l.memory_fraction * (double)rams[i];
        const double e = (double)l.max_elements;
        assert_true(bgb_limits_job_memory(e) <= budget);
        assert_true(bgb_limits_job_memory(e + 1) > budget);
        assert_int_equal(l.max_vertices, l.max_elements);
    }
    /* The model grows faster than linearly (a 3D factor's fill). */
    assert_true(bgb_limits_job_memory(2e5) / 2e5 > bgb_limits_job_memory(2e4) / 2e4);
    /* A configuration's caps are kept; only those left at 0 are derived. */
    bgb_limits_t l;
    bgb_limits_default(&l);
    l.max_elements = 1234;
    bgb_limits_resolve(&l, (uint64_t)24 << 30);
    assert_int_equal(l.max_elements, 1234);
    assert_true(l.max_vertices > 1234);
    char text[1024];
    bgb_limits_describe(&l, (uint64_t)24 << 30, text, sizeof text);
    assert_non_null(strstr(text, "max_elements 1234"));
    assert_non_null(strstr(text, "25 % of 24.0 GiB RAM"));
}

static void config(const char *json, bgb_config_t *c, bg_status expect, const char *words)
{
    char path[] = "/tmp/bgb-limits-XXXXXX";
    const int fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, json, strlen(json)), (ssize_t)strlen(json));
    close(fd);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_config_init(c, &err), BG_OK);
    const bg_status st = bgb_config_read(path, c, &err);
    unlink(path);
    if (st != expect || (words && !strstr(err.message, words)))
        fail_msg("%s: %d %s", json, (int)st, err.message);
}

static void config_keys(void **state)
{
    (void)state;
    bgb_config_t c;
    config("{\"memory_fraction\": 0.5, \"max_work\": 1e6, \"max_jobs_in_flight\": 3,"
           " \"max_stored_bytes\": 4096, \"max_connections\": 10, \"idle_timeout\": 5,"
           " \"max_elements\": 777}",
           &c, BG_OK, NULL);
    assert_true(c.limits.memory_fraction == 0.5);
    assert_true(c.limits.max_work == 1e6);
    assert_int_equal(c.limits.max_jobs_in_flight, 3);
    assert_int_equal(c.limits.max_stored_bytes, 4096);
    assert_int_equal(c.limits.max_connections, 10);
    assert_int_equal(c.limits.idle_timeout, 5);
    assert_int_equal(c.limits.max_elements, 777);
    assert_int_equal(c.limits.max_vertices, 0); /* derived at start */
    bgb_config_release(&c);
    config("{\"memory_fraction\": 0}", &c, BG_ERR_INVALID, "memory_fraction");
    bgb_config_release(&c);
    config("{\"max_jobs_in_flight\": 0}", &c, BG_ERR_INVALID, "max_jobs_in_flight");
    bgb_config_release(&c);
    config("{\"idle_timeout\": \"long\"}", &c, BG_ERR_INVALID, "idle_timeout");
    bgb_config_release(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(caps_invert_the_memory_model),
        cmocka_unit_test(config_keys),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
