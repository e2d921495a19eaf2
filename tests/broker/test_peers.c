/*
 * Who may hold an agent's name and endpoint (bgb_peers), on a virtual
 * clock: a second connection cannot take a live agent's name or endpoint,
 * gets it once the first has been silent for the market's timeout, and
 * is logged once per reason, not at every retry; over CURVE the name must
 * be its key's and the coordinators find each agent's key by endpoint.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "bgb_peers.h"

static const char KEY_A[] = "abcdefghijklmnopqrstuvwxyz0123456789ABCD";
static const char KEY_B[] = "0123456789abcdefghijklmnopqrstuvwxyzABCD";

static bgb_peer_claim_t claim(const char *conn, const char *name, const char *endpoint,
                              const char *address)
{
    return (bgb_peer_claim_t){.connection = (const uint8_t *)conn,
                              .connection_len = strlen(conn),
                              .name = name,
                              .endpoint = endpoint,
                              .address = address};
}

static void names_and_endpoints(void **state)
{
    (void)state;
    bgb_peers_t *p = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_peers_new(0, 3.0, &p, &err), BG_OK);
    char why[256];
    int say = 0;
    bgb_peer_claim_t a = claim("c1", "rotfit-1", "tcp://10.0.0.1:4000", "10.0.0.1");
    assert_int_equal(bgb_peers_admit(p, &a, 10.0, why, sizeof why, &say), 1);
    /* The same connection again (its resource role, a re-registration). */
    assert_int_equal(bgb_peers_admit(p, &a, 10.5, why, sizeof why, &say), 1);

    /* Another connection, the same name: refused, said once. */
    bgb_peer_claim_t b = claim("c2", "rotfit-1", "tcp://10.0.0.2:4000", "10.0.0.2");
    assert_int_equal(bgb_peers_admit(p, &b, 11.0, why, sizeof why, &say), 0);
    assert_string_equal(why, "the name 'rotfit-1' is registered by another agent (at 10.0.0.1) "
                             "until it has been silent for 3 s");
    assert_int_equal(say, 1);
    assert_int_equal(bgb_peers_admit(p, &b, 11.5, why, sizeof why, &say), 0);
    assert_int_equal(say, 0);
    /* Another name, the first one's endpoint: refused naming the holder. */
    bgb_peer_claim_t c = claim("c3", "rotfit-9", "tcp://10.0.0.1:4000", "10.0.0.3");
    assert_int_equal(bgb_peers_admit(p, &c, 11.6, why, sizeof why, &say), 0);
    assert_non_null(strstr(why, "the endpoint tcp://10.0.0.1:4000 is registered by agent "
                                "'rotfit-1' (at 10.0.0.1)"));
    assert_int_equal(say, 1);

    /* Any message keeps the first live. */
    bgb_peers_seen(p, (const uint8_t *)"c1", 2, 13.0);
    assert_int_equal(bgb_peers_admit(p, &b, 15.9, why, sizeof why, &say), 0);
    /* Silent for 3 s: the name passes to the second, the first is gone. */
    assert_int_equal(bgb_peers_admit(p, &b, 16.1, why, sizeof why, &say), 1);
    char address[BGB_PEERS_ADDRESS_MAX], key[BGA_CURVE_KEY_SIZE];
    assert_int_equal(bgb_peers_lookup(p, "rotfit-1", address, sizeof address, key), 1);
    assert_string_equal(address, "10.0.0.2");
    assert_string_equal(key, "");
    assert_int_equal(bgb_peers_admit(p, &c, 16.2, why, sizeof why, &say), 1);
    /* Its old connection cannot come back under the name now. */
    assert_int_equal(bgb_peers_admit(p, &a, 16.3, why, sizeof why, &say), 0);
    assert_int_equal(bgb_peers_lookup(p, "nobody", address, sizeof address, key), 0);
    /* In plaintext no key is known for any endpoint. */
    bg_error_t kerr = BG_ERROR_INIT;
    assert_int_equal(bgb_peers_key_of(p, "tcp://10.0.0.2:4000", key, &kerr), BG_ERR_NOT_FOUND);
    bgb_peers_destroy(&p);
    assert_null(p);
}

static void curve_binds_names_to_keys(void **state)
{
    (void)state;
    bgb_peers_t *p = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_peers_new(1, 3.0, &p, &err), BG_OK);
    char why[256];
    int say = 0;
    bgb_peer_claim_t a = claim("c1", "rotfit-1", "tcp://10.0.0.1:4000", "10.0.0.1");
    /* No key on the connection: refused. */
    assert_int_equal(bgb_peers_admit(p, &a, 1.0, why, sizeof why, &say), 0);
    assert_non_null(strstr(why, "carries no CURVE key name"));
    /* rotfit-2's key claiming rotfit-1's name: refused naming both. */
    a.key_name = "rotfit-2";
    a.key = KEY_B;
    assert_int_equal(bgb_peers_admit(p, &a, 1.0, why, sizeof why, &say), 0);
    assert_string_equal(why, "the name 'rotfit-1' is not its key's: the key is authorized as "
                             "'rotfit-2' (rotfit-2.pub), and a name belongs to its key");
    a.key_name = "rotfit-1";
    a.key = KEY_A;
    assert_int_equal(bgb_peers_admit(p, &a, 1.0, why, sizeof why, &say), 1);
    char key[BGA_CURVE_KEY_SIZE];
    assert_int_equal(bgb_peers_key_of(p, "tcp://10.0.0.1:4000", key, &err), BG_OK);
    assert_string_equal(key, KEY_A);
    bg_error_t kerr = BG_ERROR_INIT;
    assert_int_equal(bgb_peers_key_of(p, "tcp://10.0.0.9:1", key, &kerr), BG_ERR_NOT_FOUND);
    assert_non_null(strstr(kerr.message, "tcp://10.0.0.9:1"));
    /* The same key from a second connection (a copy of the key, or the
     * agent started twice) cannot take the live name. */
    bgb_peer_claim_t twin = claim("c2", "rotfit-1", "tcp://10.0.0.5:4000", "10.0.0.5");
    twin.key_name = "rotfit-1";
    twin.key = KEY_A;
    assert_int_equal(bgb_peers_admit(p, &twin, 2.0, why, sizeof why, &say), 0);
    assert_non_null(strstr(why, "registered by another agent (at 10.0.0.1)"));
    bgb_peers_destroy(&p);
}

static void full_table(void **state)
{
    (void)state;
    bgb_peers_t *p = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_peers_new(0, 3.0, &p, &err), BG_OK);
    char why[256], conn[16], name[32], endpoint[64];
    int say = 0;
    for (int i = 0; i < BGB_PEERS_MAX; i++) {
        snprintf(conn, sizeof conn, "c%d", i);
        snprintf(name, sizeof name, "a%d", i);
        snprintf(endpoint, sizeof endpoint, "tcp://10.0.0.1:%d", 1000 + i);
        bgb_peer_claim_t c = claim(conn, name, endpoint, "10.0.0.1");
        assert_int_equal(bgb_peers_admit(p, &c, 1.0 + i * 1e-3, why, sizeof why, &say), 1);
    }
    bgb_peer_claim_t extra = claim("cx", "ax", "tcp://10.0.0.1:9", "10.0.0.1");
    assert_int_equal(bgb_peers_admit(p, &extra, 2.0, why, sizeof why, &say), 0);
    assert_non_null(strstr(why, "the most the broker keeps"));
    /* Once the others are silent, a slot is taken over. */
    assert_int_equal(bgb_peers_admit(p, &extra, 9.0, why, sizeof why, &say), 1);
    /* Oversized claims are refused, not cut. */
    char longname[128];
    memset(longname, 'n', sizeof longname - 1);
    longname[sizeof longname - 1] = '\0';
    bgb_peer_claim_t big = claim("cy", longname, "tcp://10.0.0.1:10", "10.0.0.1");
    assert_int_equal(bgb_peers_admit(p, &big, 9.0, why, sizeof why, &say), 0);
    assert_non_null(strstr(why, "oversized"));
    bgb_peers_destroy(&p);
    assert_int_equal(bgb_peers_new(0, 0.0, &p, &err), BG_ERR_INVALID);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(names_and_endpoints),
        cmocka_unit_test(curve_binds_names_to_keys),
        cmocka_unit_test(full_table),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
