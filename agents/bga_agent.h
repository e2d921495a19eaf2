/*
 * bga_agent — the agent daemon: a ZeroMQ ROUTER socket bound to an
 * endpoint, requests computed by bga_service, replies routed back, leases
 * expired between requests.
 *
 * Two threads. The socket loop (the caller of bga_agent_run) owns the
 * ROUTER socket and the market seller and never computes: it answers
 * heartbeats at once, checks a compute call's contract (with a market),
 * queues up to BGA_AGENT_QUEUE_MAX calls for the worker and refuses more
 * (BUSY, quoting the request), and relays the worker's replies. The
 * worker thread owns the job table (bga_service) and computes one call at
 * a time, in the order received; the two talk over an inproc pipe.
 * Heartbeats are ping-pong: a peer's HEARTBEAT gets the agent's status
 * (slots, free slots, services, name) at once, even in the middle of a
 * long factorization, and renews the lease of the job it names (the
 * worker does that between calls). So a coordinator tells a computing
 * agent from a lost one, and the broker's market keeps hearing this
 * agent's own heartbeats while it computes.
 *
 * Stopping: a call in progress always finishes and its reply is sent;
 * once the stop flag is seen, requests already queued on the socket (at
 * most BGA_AGENT_DRAIN_MAX) are answered too, then the loop returns; the
 * socket lingers up to BGA_AGENT_LINGER_MS at close so that reply leaves
 * the process.
 */
#ifndef BGA_AGENT_H
#define BGA_AGENT_H

#include <signal.h>

#include "bg_error.h"
#include "bga_curve.h"
#include "bga_market.h"
#include "bga_service.h"

#define BGA_AGENT_LINGER_MS 2000
#define BGA_AGENT_DRAIN_MAX 64
#define BGA_AGENT_ENDPOINT_MAX 256
/* Calls handed to the worker and not yet answered, at most; one more is
 * refused with BUSY (each coordinator has one call in flight per agent). */
#define BGA_AGENT_QUEUE_MAX 64

typedef struct bga_agent bga_agent_t;

typedef struct bga_agent_config {
    const char *listen; /* e.g. tcp://127.0.0.1:0 (an ephemeral port) */
    bga_service_config_t service;
    int poll_ms; /* how often leases and the stop flag are checked */
    /* Sell on a broker's live market (NULL: serve anyone, as before). Its
     * broker, slots and services are used; name and endpoint are the
     * agent's own. With a market, a compute call for a job the agent holds
     * no contract for gets a NO_JOB error naming the job. */
    const bga_market_config_t *market;
    /* CURVE (NULL: plaintext, as before): the agent's key pair, its
     * listening socket's server key and, with a market, its identity to
     * the broker; broker_key is the broker's public key (Z85), the one key
     * the listening socket admits (the broker's coordinators present it)
     * and the key the market connection expects. Both borrowed for
     * bga_agent_new. A ZAP handler (bga_zap) in the agent's context
     * answers for the listening socket and watches both sockets. */
    const bga_curve_keypair_t *curve;
    const char *broker_key;
    /* Refusals on the agent's sockets, one line each, called on the ZAP
     * handler's thread (bga_zap.h); NULL: not logged. */
    bga_zap_log_fn log;
    void *log_ctx;
} bga_agent_config_t;

/* Creates the job table and binds. Caller owns *out. */
bg_status bga_agent_new(const bga_agent_config_t *config, bga_agent_t **out, bg_error_t *err);
void bga_agent_destroy(bga_agent_t **agent);

/* The bound endpoint with the resolved port (tcp://127.0.0.1:40123). */
const char *bga_agent_endpoint(const bga_agent_t *agent);

/*
 * Serves until *stop becomes non-zero (set by the command's signal
 * handler): starts the worker, runs the socket loop on the calling thread,
 * and joins the worker before it returns. Returns BG_OK then, or the
 * failure that ended the loop. Once per agent.
 */
bg_status bga_agent_run(bga_agent_t *agent, const volatile sig_atomic_t *stop, bg_error_t *err);

/* The job table's counters; read it when bga_agent_run has returned (or
 * before it started): the worker owns them while it runs. */
bga_service_stats_t bga_agent_stats(const bga_agent_t *agent);
/* The agent's market seller, NULL without --broker. */
const bga_market_t *bga_agent_market(const bga_agent_t *agent);

#endif
