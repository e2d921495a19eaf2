/*
 * live_net — a broker stand-in's plumbing for the live-market test and
 * benchmark programs (live_host, bench_alloc): the live market (bgb_market)
 * on a ROUTER socket bound on loopback (port chosen by the kernel, written
 * to DIR/endpoint for the script that starts the agents), and the loop
 * that hands it the agents' messages and its ticks. It watches the
 * agents' heartbeats itself, so it waits for them with nothing but the
 * market's public calls (the benchmark is built against older trees too).
 * Every failure is fatal (the programs are tests): it prints and exits 1.
 */
#ifndef LIVE_NET_H
#define LIVE_NET_H

#include <stddef.h>

#include "bgb_market.h"

#define LIVE_NET_AGENTS 64 /* agents' sockets it tells apart */

typedef struct live_net {
    void *ctx, *router;
    bgb_market_t *market;
    /* Sockets that heartbeat a basic seller (role 0) or a resource seller (role 1). */
    unsigned char seen[LIVE_NET_AGENTS][2][256];
    size_t seen_len[LIVE_NET_AGENTS][2];
    size_t nseen[2];
} live_net_t;

/* Prints "live_net: FAIL: ..." on stderr and exits 1. */
void live_net_fail(const char *fmt, ...) __attribute__((format(printf, 1, 2), noreturn));

/* Binds, starts a market named `name` with central clearing period
 * `period`, writes DIR/endpoint. */
void live_net_open(live_net_t *h, const char *dir, const char *name, double period);
void live_net_close(live_net_t *h);

/* Runs the market for at most `seconds`, or until *flag becomes non-zero. */
void live_net_pump(live_net_t *h, double seconds, const int *flag);

/* Waits (at most 30 s) until `nbasic` basic sellers and one resource
 * seller have heartbeaten, then half a second more (every agent has
 * said its prices). */
void live_net_wait(live_net_t *h, size_t nbasic);

#endif
