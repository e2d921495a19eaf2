/*
 * bgb_rest — the broker's REST API over libmicrohttpd: jobs in and out of
 * the durable store (bgb_store), errors as RFC 9457 problem documents.
 *
 *   POST /v1/jobs                 submit: {"scene": {...}, "files": [{"name", "base64"}],
 *                                 "mechanism", "budget"}; 202 + Location (200 when an
 *                                 Idempotency-Key replays an earlier submit)
 *   GET  /v1/jobs                 ?state=S&limit=N&cursor=C, oldest first
 *   GET  /v1/jobs/{id}            the job: state, plan, reason, contracts, allocation,
 *                                 progress, the error-against-time trace so far, links
 *   GET  /v1/jobs/{id}/events     server-sent events of the job's log until it ends
 *   POST /v1/jobs/{id}/cancel     409 once the job has ended
 *   GET  /v1/jobs/{id}/result     the result's file list (409 until the job succeeded)
 *   GET  /v1/jobs/{id}/result/{file}
 *   GET  /v1/agents               the agents the broker knows (and, with a market, their
 *                                 slots and prices)
 *   GET  /v1/market               recent prices per good and mechanism
 *   GET  /v1/market/contracts.csv the contract log, agents.csv the agent table, with the
 *                                 simulator's columns (scenario = the broker's name,
 *                                 replication 0; contracts.csv adds use and clearing)
 *   GET  /v1/market/clearings.csv the central clearings and the orders that set their
 *                                 prices
 *   GET  /healthz, /metrics (Prometheus text), /openapi.json
 *
 * A submitted scene is validated exactly as `biotgrid validate` does —
 * parsed, no solve — against the uploaded files only (an absolute path or
 * one that leaves the job's folder is refused) and against the configured
 * size caps before any mesh is built; an invalid one is a 422 naming the
 * field. Bodies over the cap are refused with 413 without being read.
 *
 * The server runs its own threads (one per connection, up to a limit);
 * the store is borrowed and must outlive it.
 */
#ifndef BGB_REST_H
#define BGB_REST_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bgb_limits.h"
#include "bgb_store.h"

typedef struct bgb_rest bgb_rest_t;

typedef struct bgb_rest_config {
    const char *address;     /* IPv4 address to bind; NULL: 127.0.0.1 */
    uint16_t port;           /* 0: an ephemeral port (bgb_rest_port tells which) */
    /* TLS: a PEM certificate chain and its PEM private key (NUL-terminated
     * texts, copied by the server's TLS library), both or neither; NULL:
     * plain HTTP. A pair that does not load, or whose key does not match
     * the certificate, is BG_ERR_INVALID saying why. TLS 1.2 and 1.3 only. */
    const char *tls_cert_pem;
    const char *tls_key_pem;
    /* Every limit (bgb_limits.h), copied; NULL: the defaults, resolved
     * for this machine. */
    const bgb_limits_t *limits;
    const char *work_dir;    /* where submitted scenes are unpacked to be validated; NULL: /tmp */
    const char *name;        /* the broker's name in /healthz and /metrics; NULL: "biotgrid" */
    const char *agents_json; /* the agents known to the broker, a JSON array (copied);
                                NULL: none */
    const char *market;      /* the live market attached, or NULL: none (then /v1/market
                                has no prices and the CSVs only their header) */
    /* Live views, or NULL: the static ones above. view(view_ctx, what)
     * returns a malloc'd text the server frees, or NULL (then the static one); it
     * is called from the server's threads and must be thread-safe. */
    char *(*view)(void *view_ctx, int what);
    void *view_ctx;
    /* Called (from a server thread) after a new job is stored, so that the
     * broker's dispatcher looks at the queue; NULL: none. */
    void (*on_queued)(void *queued_ctx);
    void *queued_ctx;
    /* Called (from a server thread) before job `id` is marked cancelled,
     * so that its market account is settled before the `cancelled` event
     * (bgb_loop_settle); with queued_ctx; NULL: none. */
    void (*on_cancel)(void *queued_ctx, const char *id);
} bgb_rest_config_t;

/* What a view is asked for. */
enum {
    BGB_REST_VIEW_AGENTS = 0,     /* JSON array of agents */
    BGB_REST_VIEW_MARKET = 1,     /* JSON object: "market" and "prices" */
    BGB_REST_VIEW_CONTRACTS = 2,  /* contracts.csv */
    BGB_REST_VIEW_AGENTS_CSV = 3, /* agents.csv */
    BGB_REST_VIEW_CLEARINGS = 4   /* clearings.csv */
};


/* Starts serving; caller owns *out (bgb_rest_stop). */
bg_status bgb_rest_start(const bgb_rest_config_t *config, bgb_store_t *store, bgb_rest_t **out,
                         bg_error_t *err);

/* The port the server listens on. */
uint16_t bgb_rest_port(const bgb_rest_t *rest);

/* 1 when the server speaks TLS (the URL's scheme is https). */
int bgb_rest_tls(const bgb_rest_t *rest);

/* 1 when address is an IPv4 loopback address (127.0.0.0/8), where plain
 * HTTP carries tokens no further than this machine; 0 otherwise (0.0.0.0
 * included: it listens on every interface). */
int bgb_rest_address_is_loopback(const char *address);

/* Stops accepting, waits for the connections in progress, frees; accepts NULL. */
/* The broker is stopping: POST /v1/jobs answers 503 ("stopping") from
 * now on; everything else is served as before. */
void bgb_rest_drain(bgb_rest_t *rest);
/* Stops serving: every event stream of a job still going gets the events
 * not yet sent and a last `end` event ({"reason", "final": true}), then
 * ends (within REST_FINAL_WAIT, 2 s); then the server stops. */
void bgb_rest_stop(bgb_rest_t **rest);

/* The OpenAPI 3 document served at /openapi.json (static text). */
const char *bgb_rest_openapi(void);

#endif
