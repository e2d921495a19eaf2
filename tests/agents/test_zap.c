/*
 * The ZAP handler (bga_zap) against real sockets on loopback, in one
 * process: a CURVE ROUTER whose context has the handler, clients with
 * keys in its folder, not in it, without CURVE, and with the wrong server
 * key. An admitted message carries the key's name as "User-Id" and the
 * key as X-Curve-Key (on its body: bga_zap.h); every refusal is logged with the peer's address
 * (and the key when the peer showed one); a key added to the folder is
 * admitted without a restart, a key removed is refused; a bad folder is
 * refused at start naming the file; a client refused for its key hears it
 * through its own watch.
 */
#include <pthread.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include <cmocka.h>

#include "bga_curve.h"
#include "bga_zap.h"

#define LINES 64

static char dir[64];
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static char lines[LINES][768];
static int nlines;

static void on_log(void *ctx, const char *line)
{
    (void)ctx;
    pthread_mutex_lock(&lock);
    if (nlines < LINES)
        snprintf(lines[nlines++], sizeof lines[0], "%s", line);
    pthread_mutex_unlock(&lock);
}

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* The index of the first log line holding every one of the words (NULL-
 * ended), waiting up to 3 s for it; -1 when none came. */
static int wait_line(const char *a, const char *b, const char *c)
{
    for (int t = 0; t < 300; t++) {
        pthread_mutex_lock(&lock);
        for (int i = 0; i < nlines; i++)
            if (strstr(lines[i], a) && (!b || strstr(lines[i], b)) && (!c || strstr(lines[i], c))) {
                pthread_mutex_unlock(&lock);
                return i;
            }
        pthread_mutex_unlock(&lock);
        sleep_ms(10);
    }
    return -1;
}

static int count_lines(const char *a)
{
    int n = 0;
    pthread_mutex_lock(&lock);
    for (int i = 0; i < nlines; i++)
        n += strstr(lines[i], a) != NULL;
    pthread_mutex_unlock(&lock);
    return n;
}

static void dump_lines(void)
{
    pthread_mutex_lock(&lock);
    for (int i = 0; i < nlines; i++)
        print_message("log: %s\n", lines[i]);
    pthread_mutex_unlock(&lock);
}

static int make_dir(void **state)
{
    (void)state;
    snprintf(dir, sizeof dir, "/tmp/bg-zap-XXXXXX");
    return mkdtemp(dir) ? 0 : -1;
}

static int remove_dir(void **state)
{
    (void)state;
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    return system(cmd) == 0 ? 0 : -1;
}

/* A key pair written as DIR/SUB/NAME.{key,pub}. */
static void new_pair(const char *sub, const char *name, bga_curve_keypair_t *pair)
{
    bg_error_t err = BG_ERROR_INIT;
    char folder[128], prefix[192];
    snprintf(folder, sizeof folder, "%s/%s", dir, sub);
    mkdir(folder, 0700);
    snprintf(prefix, sizeof prefix, "%s/%s", folder, name);
    assert_int_equal(bga_curve_generate(pair, &err), BG_OK);
    assert_int_equal(bga_curve_write(prefix, pair, &err), BG_OK);
}

typedef struct server {
    void *ctx, *router;
    bga_zap_t *zap;
    char endpoint[128];
} server_t;

static void server_start(server_t *s, const bga_zap_config_t *zc, const bga_curve_keypair_t *pair)
{
    bg_error_t err = BG_ERROR_INIT;
    s->ctx = zmq_ctx_new();
    assert_int_equal(bga_zap_new(s->ctx, zc, &s->zap, &err), BG_OK);
    s->router = zmq_socket(s->ctx, ZMQ_ROUTER);
    const int linger = 0;
    zmq_setsockopt(s->router, ZMQ_LINGER, &linger, sizeof linger);
    assert_int_equal(bga_curve_server(s->router, pair, &err), BG_OK);
    assert_int_equal(bga_zap_watch(s->zap, s->router, "test endpoint", 1, &err), BG_OK);
    assert_int_equal(zmq_bind(s->router, "tcp://127.0.0.1:*"), 0);
    size_t len = sizeof s->endpoint;
    zmq_getsockopt(s->router, ZMQ_LAST_ENDPOINT, s->endpoint, &len);
}

static void server_stop(server_t *s)
{
    zmq_close(s->router);
    bga_zap_destroy(&s->zap);
    assert_null(s->zap);
    zmq_ctx_term(s->ctx);
}

/*
 * A DEALER (CURVE with `pair` and server_key, or plaintext when pair is
 * NULL) sends "hello"; returns 1 when the router got it within wait_ms,
 * with the properties of its routing frame in user and key.
 */
static int try_client(server_t *s, void *cctx, const bga_curve_keypair_t *pair,
                      const char *server_key, int wait_ms, char *user, char *key)
{
    bg_error_t err = BG_ERROR_INIT;
    void *d = zmq_socket(cctx, ZMQ_DEALER);
    const int linger = 0;
    zmq_setsockopt(d, ZMQ_LINGER, &linger, sizeof linger);
    if (pair)
        assert_int_equal(bga_curve_client(d, pair, server_key, &err), BG_OK);
    assert_int_equal(zmq_connect(d, s->endpoint), 0);
    zmq_send(d, "hello", 5, ZMQ_DONTWAIT);
    zmq_pollitem_t item = {s->router, 0, ZMQ_POLLIN, 0};
    int got = 0;
    if (zmq_poll(&item, 1, wait_ms) == 1) {
        zmq_msg_t route, body;
        zmq_msg_init(&route);
        zmq_msg_init(&body);
        assert_true(zmq_msg_recv(&route, s->router, 0) >= 0);
        assert_true(zmq_msg_recv(&body, s->router, 0) == 5);
        /* The body's properties: libzmq 4.3 leaves a ROUTER's routing
         * frame without them once zmq_poll has prefetched the message. */
        const char *u = zmq_msg_gets(&body, "User-Id");
        const char *k = zmq_msg_gets(&body, BGA_ZAP_KEY_PROPERTY);
        snprintf(user, 64, "%s", u ? u : "");
        snprintf(key, BGA_CURVE_KEY_SIZE, "%s", k ? k : "");
        zmq_msg_close(&route);
        zmq_msg_close(&body);
        got = 1;
    }
    zmq_close(d);
    return got;
}

/*
 * A client the handshake refuses, tried until the log names its address
 * (the refusal of a peer that leaves at once may come before its address
 * could be read: then the line says so, and a later try shows it): 1 when
 * a line with `why` and 127.0.0.1:PORT came within 10 tries.
 */
static int refused_with_address(server_t *s, void *cctx, const bga_curve_keypair_t *pair,
                                const char *server_key, const char *why, const char *why2)
{
    char user[64], key[BGA_CURVE_KEY_SIZE];
    for (int t = 0; t < 10; t++) {
        assert_false(try_client(s, cctx, pair, server_key, 300, user, key));
        if (wait_line("test endpoint: refused 127.0.0.1:", why, NULL) >= 0 ||
            (why2 && wait_line("test endpoint: refused 127.0.0.1:", why2, NULL) >= 0))
            return 1;
    }
    return 0;
}

static void folder_allowlist(void **state)
{
    (void)state;
    bga_curve_keypair_t server, a, b, rogue;
    new_pair("server", "broker", &server);
    new_pair("allowed", "rotfit-1", &a);
    new_pair("spare", "rotfit-2", &b);
    new_pair("rogue", "rotfit-1", &rogue); /* the right name, another key */
    char allowed[128];
    snprintf(allowed, sizeof allowed, "%s/allowed", dir);
    /* Only .pub files count: the secret key beside it is no key. */
    const bga_zap_config_t zc = {.folder = allowed, .log = on_log};
    server_t s;
    server_start(&s, &zc, &server);
    assert_int_equal(bga_zap_count(s.zap), 1);
    void *cctx = zmq_ctx_new();
    char user[64], key[BGA_CURVE_KEY_SIZE];

    assert_true(try_client(&s, cctx, &a, server.public_key, 3000, user, key));
    assert_string_equal(user, "rotfit-1");
    assert_string_equal(key, a.public_key);

    /* Another key: refused by ZAP, logged with the address and the key. */
    assert_false(try_client(&s, cctx, &rogue, server.public_key, 500, user, key));
    if (wait_line("refused 127.0.0.1: CURVE key", rogue.public_key, "not among") < 0) {
        dump_lines();
        fail_msg("no ZAP refusal line for the rogue key");
    }
    /* Plaintext: refused by the handshake, logged with address and port. */
    if (!refused_with_address(&s, cctx, NULL, NULL, "(no key shown): no CURVE",
                              "(no key shown): it left during the CURVE handshake")) {
        dump_lines();
        fail_msg("no refusal line with an address for the plaintext client");
    }
    /* The right key of a client, the wrong key for the server. */
    if (!refused_with_address(&s, cctx, &a, rogue.public_key,
                              "does not hold this endpoint's public key", NULL)) {
        dump_lines();
        fail_msg("no refusal line for a client with the wrong server key");
    }
    /* The same rogue again within the minute: counted, not logged again. */
    assert_false(try_client(&s, cctx, &rogue, server.public_key, 500, user, key));
    sleep_ms(200);
    assert_int_equal(count_lines(rogue.public_key), 1);

    /* rotfit-2's key put in the folder: admitted without a restart. */
    char from[192], to[192];
    snprintf(from, sizeof from, "%s/spare/rotfit-2.pub", dir);
    snprintf(to, sizeof to, "%s/allowed/rotfit-2.pub", dir);
    assert_int_equal(rename(from, to), 0);
    assert_true(try_client(&s, cctx, &b, server.public_key, 3000, user, key));
    assert_string_equal(user, "rotfit-2");
    /* rotfit-1's removed: its next connection is refused. */
    snprintf(from, sizeof from, "%s/allowed/rotfit-1.pub", dir);
    assert_int_equal(unlink(from), 0);
    sleep_ms(1100); /* past the reload period, whatever the folder's clock */
    assert_false(try_client(&s, cctx, &a, server.public_key, 500, user, key));
    if (wait_line("refused 127.0.0.1: CURVE key", a.public_key, NULL) < 0) {
        dump_lines();
        fail_msg("no refusal line for the removed key");
    }
    zmq_ctx_term(cctx);
    server_stop(&s);
}

static void fixed_list_and_client_watch(void **state)
{
    (void)state;
    bga_curve_keypair_t agent, broker, stranger;
    new_pair("fixed", "agent", &agent);
    new_pair("fixed", "broker", &broker);
    new_pair("fixed", "stranger", &stranger);
    const char *names[] = {"broker"};
    const char *keys[] = {broker.public_key};
    const bga_zap_config_t zc = {
        .names = names, .keys = keys, .count = 1, .whose = "the broker's key", .log = on_log};
    server_t s;
    server_start(&s, &zc, &agent);
    char user[64], key[BGA_CURVE_KEY_SIZE];
    void *cctx = zmq_ctx_new();
    assert_true(try_client(&s, cctx, &broker, agent.public_key, 3000, user, key));
    assert_string_equal(user, "broker");

    /* A refused client watched by its own handler hears why. */
    bga_zap_t *cz = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const bga_zap_config_t cc = {.names = names, .keys = keys, .count = 1, .log = on_log};
    assert_int_equal(bga_zap_new(cctx, &cc, &cz, &err), BG_OK);
    void *d = zmq_socket(cctx, ZMQ_DEALER);
    const int linger = 0;
    zmq_setsockopt(d, ZMQ_LINGER, &linger, sizeof linger);
    assert_int_equal(bga_curve_client(d, &stranger, agent.public_key, &err), BG_OK);
    assert_int_equal(bga_zap_watch(cz, d, "agent", 0, &err), BG_OK);
    assert_int_equal(zmq_connect(d, s.endpoint), 0);
    zmq_send(d, "hello", 5, ZMQ_DONTWAIT);
    if (wait_line("refused 127.0.0.1: CURVE key", stranger.public_key, "is not the broker's key") <
            0 ||
        wait_line("agent tcp://127.0.0.1:", "refused this process's CURVE key (ZAP status 400)",
                  NULL) < 0) {
        dump_lines();
        fail_msg("the stranger's refusal was not logged on both sides");
    }
    zmq_close(d);
    bga_zap_destroy(&cz);
    zmq_ctx_term(cctx);
    server_stop(&s);
}

static void bad_folders(void **state)
{
    (void)state;
    void *ctx = zmq_ctx_new();
    bga_zap_t *z = NULL;
    char folder[128], path[192];
    /* A missing folder. */
    snprintf(folder, sizeof folder, "%s/none", dir);
    bga_zap_config_t zc = {.folder = folder};
    bg_error_t e1 = BG_ERROR_INIT;
    assert_int_equal(bga_zap_new(ctx, &zc, &z, &e1), BG_ERR_INVALID);
    assert_non_null(strstr(e1.message, "none: No such file or directory"));
    assert_null(z);
    /* A malformed key file, named with its line. */
    snprintf(folder, sizeof folder, "%s/bad", dir);
    mkdir(folder, 0700);
    snprintf(path, sizeof path, "%s/x.pub", folder);
    FILE *f = fopen(path, "w");
    fputs("not a key\n", f);
    fclose(f);
    zc.folder = folder;
    bg_error_t e2 = BG_ERROR_INIT;
    assert_int_equal(bga_zap_new(ctx, &zc, &z, &e2), BG_ERR_INVALID);
    assert_non_null(strstr(e2.message, "x.pub:1: not a CURVE key"));
    /* One key in two files. */
    bga_curve_keypair_t k;
    new_pair("twice", "one", &k);
    snprintf(folder, sizeof folder, "%s/twice", dir);
    snprintf(path, sizeof path, "%s/two.pub", folder);
    f = fopen(path, "w");
    fprintf(f, "%s\n", k.public_key);
    fclose(f);
    zc.folder = folder;
    bg_error_t e3 = BG_ERROR_INIT;
    assert_int_equal(bga_zap_new(ctx, &zc, &z, &e3), BG_ERR_INVALID);
    assert_non_null(strstr(e3.message, "two.pub holds the key of 'one' too"));
    /* A second handler in one context is refused. */
    snprintf(folder, sizeof folder, "%s/fixed", dir);
    zc.folder = folder;
    bga_zap_t *first = NULL, *second = NULL;
    bg_error_t e4 = BG_ERROR_INIT;
    assert_int_equal(bga_zap_new(ctx, &zc, &first, &e4), BG_OK);
    assert_int_equal(bga_zap_new(ctx, &zc, &second, &e4), BG_ERR_IO);
    assert_null(second);
    bga_zap_destroy(&first);
    zmq_ctx_term(ctx);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(folder_allowlist),
        cmocka_unit_test(fixed_list_and_client_watch),
        cmocka_unit_test(bad_folders),
    };
    return cmocka_run_group_tests(tests, make_dir, remove_dir);
}
