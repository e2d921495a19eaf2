/*
 * CURVE keys and their files (bga_curve), without sockets: a key pair
 * written and read back, files never overwritten, a secret key others may
 * read refused, a secret key file given as a public key refused, the key
 * line parser's messages, key names from file names, and which endpoints
 * stay on this machine.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "bga_curve.h"

static char dir[64];

static int make_dir(void **state)
{
    (void)state;
    snprintf(dir, sizeof dir, "/tmp/bg-curve-XXXXXX");
    return mkdtemp(dir) ? 0 : -1;
}

static int remove_dir(void **state)
{
    (void)state;
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    return system(cmd) == 0 ? 0 : -1;
}

static void path_of(char *out, size_t size, const char *name)
{
    snprintf(out, size, "%s/%s", dir, name);
}

static unsigned mode_of(const char *path)
{
    struct stat st;
    assert_int_equal(stat(path, &st), 0);
    return (unsigned)(st.st_mode & 0777);
}

static void write_text(const char *path, const char *text, unsigned mode)
{
    FILE *f = fopen(path, "w");
    assert_non_null(f);
    fputs(text, f);
    fclose(f);
    assert_int_equal(chmod(path, mode), 0);
}

static void pair_round_trip(void **state)
{
    (void)state;
    assert_true(bga_curve_available());
    bga_curve_keypair_t pair, back;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_curve_generate(&pair, &err), BG_OK);
    assert_true(bga_curve_key_valid(pair.public_key));
    assert_true(bga_curve_key_valid(pair.secret_key));
    char prefix[96], sec[128], pub[128];
    path_of(prefix, sizeof prefix, "agent-1");
    snprintf(sec, sizeof sec, "%s.key", prefix);
    snprintf(pub, sizeof pub, "%s.pub", prefix);
    assert_int_equal(bga_curve_write(prefix, &pair, &err), BG_OK);
    assert_int_equal(mode_of(sec), 0600);
    assert_int_equal(mode_of(pub), 0644);
    assert_int_equal(bga_curve_read_secret(sec, &back, &err), BG_OK);
    assert_string_equal(back.secret_key, pair.secret_key);
    assert_string_equal(back.public_key, pair.public_key); /* derived from the secret */
    char key[BGA_CURVE_KEY_SIZE];
    assert_int_equal(bga_curve_read_public(pub, key, &err), BG_OK);
    assert_string_equal(key, pair.public_key);
    /* A second pair under the same prefix: refused, the first kept. */
    bga_curve_keypair_t other;
    assert_int_equal(bga_curve_generate(&other, &err), BG_OK);
    bg_error_t werr = BG_ERROR_INIT;
    assert_int_equal(bga_curve_write(prefix, &other, &werr), BG_ERR_CONFLICT);
    assert_non_null(strstr(werr.message, "agent-1.key exists"));
    assert_int_equal(bga_curve_read_secret(sec, &back, &err), BG_OK);
    assert_string_equal(back.secret_key, pair.secret_key);
    /* Only a stray .pub there: still refused, nothing written. */
    char lone[96], lone_key[128];
    path_of(lone, sizeof lone, "lone");
    snprintf(lone_key, sizeof lone_key, "%s.pub", lone);
    write_text(lone_key, "x\n", 0644);
    bg_error_t lerr = BG_ERROR_INIT;
    assert_int_equal(bga_curve_write(lone, &other, &lerr), BG_ERR_CONFLICT);
    snprintf(lone_key, sizeof lone_key, "%s.key", lone);
    assert_int_not_equal(access(lone_key, F_OK), 0);
}

static void secret_protected(void **state)
{
    (void)state;
    bga_curve_keypair_t pair, back;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_curve_generate(&pair, &err), BG_OK);
    char prefix[96], sec[128];
    path_of(prefix, sizeof prefix, "open");
    snprintf(sec, sizeof sec, "%s.key", prefix);
    assert_int_equal(bga_curve_write(prefix, &pair, &err), BG_OK);
    assert_int_equal(chmod(sec, 0640), 0);
    bg_error_t rerr = BG_ERROR_INIT;
    assert_int_equal(bga_curve_read_secret(sec, &back, &rerr), BG_ERR_INVALID);
    assert_non_null(strstr(rerr.message, "mode 0640"));
    assert_non_null(strstr(rerr.message, "chmod 600"));
    assert_string_equal(back.secret_key, "");
    /* The secret file handed over as a public key: refused by its mark. */
    assert_int_equal(chmod(sec, 0600), 0);
    char key[BGA_CURVE_KEY_SIZE];
    bg_error_t perr = BG_ERROR_INIT;
    assert_int_equal(bga_curve_read_public(sec, key, &perr), BG_ERR_INVALID);
    assert_non_null(strstr(perr.message, "is a secret key file"));
    /* A missing file names itself. */
    bg_error_t merr = BG_ERROR_INIT;
    char missing[96];
    path_of(missing, sizeof missing, "missing.key");
    assert_int_equal(bga_curve_read_secret(missing, &back, &merr), BG_ERR_IO);
    assert_non_null(strstr(merr.message, "missing.key: No such file"));
}

static void parse_lines(void **state)
{
    (void)state;
    char key[BGA_CURVE_KEY_SIZE];
    int secret = 0;
    bg_error_t err = BG_ERROR_INIT;
    /* Comments, blank lines, CRLF, and a key that starts with '#'. */
    const char *hash_key = "#abcdefghijklmnopqrstuvwxyz0123456789ABC";
    char text[256];
    snprintf(text, sizeof text, "# a comment\n\n  %s\r\n", hash_key);
    assert_int_equal(bga_curve_parse(text, strlen(text), "k.pub", key, &secret, &err), BG_OK);
    assert_string_equal(key, hash_key);
    assert_int_equal(secret, 0);
    snprintf(text, sizeof text, "%s\n%s\n", BGA_CURVE_SECRET_MARK, hash_key);
    assert_int_equal(bga_curve_parse(text, strlen(text), "k.key", key, &secret, &err), BG_OK);
    assert_int_equal(secret, 1);

    bg_error_t e1 = BG_ERROR_INIT;
    snprintf(text, sizeof text, "%s\n%s\n", hash_key, hash_key);
    assert_int_equal(bga_curve_parse(text, strlen(text), "two.pub", key, NULL, &e1),
                     BG_ERR_INVALID);
    assert_string_equal(e1.message,
                        "two.pub:2: a second key (the first is on line 1): a key file holds one");
    bg_error_t e2 = BG_ERROR_INIT;
    snprintf(text, sizeof text, "# ok\nnot a key at all\n");
    assert_int_equal(bga_curve_parse(text, strlen(text), "bad.pub", key, NULL, &e2),
                     BG_ERR_INVALID);
    assert_non_null(strstr(e2.message, "bad.pub:2: not a CURVE key"));
    assert_non_null(strstr(e2.message, "this one has 16 characters"));
    bg_error_t e3 = BG_ERROR_INIT;
    assert_int_equal(bga_curve_parse("# nothing\n", 10, "empty.pub", key, NULL, &e3),
                     BG_ERR_INVALID);
    assert_non_null(strstr(e3.message, "empty.pub: no key in it"));
    /* 40 characters, one outside the Z85 alphabet (a comma). */
    bg_error_t e4 = BG_ERROR_INIT;
    const char *comma = "abcdefghijklmnopqrstuvwxyz0123456789AB,D";
    assert_int_equal(bga_curve_parse(comma, strlen(comma), "comma.pub", key, NULL, &e4),
                     BG_ERR_INVALID);
    assert_false(bga_curve_key_valid(comma));
    assert_false(bga_curve_key_valid("short"));
    /* A NUL inside the text is no key. */
    bg_error_t e5 = BG_ERROR_INIT;
    char nul[41];
    memcpy(nul, "abcdefghijklmnopqrstuvwxyz0123456789ABCD", 40);
    nul[7] = '\0';
    assert_int_equal(bga_curve_parse(nul, 40, "nul.pub", key, NULL, &e5), BG_ERR_INVALID);
    assert_non_null(strstr(e5.message, "a NUL among them"));
}

static void names(void **state)
{
    (void)state;
    char name[BGA_CURVE_NAME_MAX];
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_curve_name_of("/srv/keys/rotfit-1.pub", ".pub", name, &err), BG_OK);
    assert_string_equal(name, "rotfit-1");
    assert_int_equal(bga_curve_name_of("host.a_b.key", ".key", name, &err), BG_OK);
    assert_string_equal(name, "host.a_b");
    bg_error_t e1 = BG_ERROR_INIT;
    assert_int_equal(bga_curve_name_of("/srv/keys/rotfit-1.txt", ".pub", name, &e1),
                     BG_ERR_INVALID);
    assert_non_null(strstr(e1.message, "ends with .pub"));
    bg_error_t e2 = BG_ERROR_INIT;
    assert_int_equal(bga_curve_name_of("/srv/keys/bad name.pub", ".pub", name, &e2),
                     BG_ERR_INVALID);
    assert_non_null(strstr(e2.message, "'bad name'"));
    assert_false(bga_curve_name_valid(".hidden"));
    assert_false(bga_curve_name_valid(""));
    assert_true(bga_curve_name_valid("agent-42"));
}

static void loopback(void **state)
{
    (void)state;
    static const char *const local[] = {
        "tcp://127.0.0.1:5570", "tcp://127.8.9.1:*", "tcp://localhost:1", "tcp://[::1]:5570",
        "tcp://lo:5570",        "ipc:///tmp/x",      "inproc://x"};
    static const char *const remote[] = {
        "tcp://*:5570",    "tcp://0.0.0.0:5570",        "tcp://10.77.1.1:5570",
        "tcp://[::]:5570", "tcp://eth0:5570",           "tcp://128.0.0.1:1",
        "tcp://127.0.0.1", "pgm://127.0.0.1;1.2.3.4:5", "tcp://10.0.0.1;127.0.0.1:5",
        "tcp://[::2]:1",   "ws://127.0.0.1:1",          ""};
    for (size_t i = 0; i < sizeof local / sizeof *local; i++)
        assert_true(bga_curve_endpoint_is_loopback(local[i]));
    for (size_t i = 0; i < sizeof remote / sizeof *remote; i++) {
        if (bga_curve_endpoint_is_loopback(remote[i]))
            fail_msg("%s taken for loopback", remote[i]);
    }
    assert_false(bga_curve_endpoint_is_loopback(NULL));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(pair_round_trip), cmocka_unit_test(secret_protected),
        cmocka_unit_test(parse_lines),     cmocka_unit_test(names),
        cmocka_unit_test(loopback),
    };
    return cmocka_run_group_tests(tests, make_dir, remove_dir);
}
