/*
 * bgb_loop — the broker's market as an actor (the CZMQ zactor pattern): one
 * thread owns the agents' ROUTER socket and the live market (bgb_market)
 * and does nothing else. Work comes in over an inproc socket — a job's
 * purchase, its release, a view for the REST API, stop — and each answer
 * goes back the same way to whoever asked; the thread sleeps in zmq_poll on
 * its two sockets with the market's next deadline as the timeout, so it
 * wakes when an agent writes, a buyer asks or the market has something due,
 * never on a fixed period. It never touches the disk: contract rows go to
 * a callback that must not block (the broker queues them for the store's
 * writer thread, bgb_store_add_event_later).
 *
 * Identity. Every registration passes bgb_peers before the market sees
 * it: over CURVE (config.curve) the agents' endpoint admits only the keys
 * in config.authorized_agents (a ZAP handler, bga_zap) and an agent's name
 * must be its key's; with or without CURVE, a name or compute endpoint a
 * live agent holds is not taken by another. A refused registration gets
 * an ERROR naming why, and a line in config.log with the peer's address
 * and key, as do connections refused by ZAP or by the handshake.
 *
 * Threads: bgb_loop_start/stop from one thread; a buyer (bgb_loop_buyer_*)
 * belongs to the thread that made it (a ZeroMQ socket is not shared);
 * bgb_loop_view, bgb_loop_live_agents and bgb_loop_curve from any thread.
 */
#ifndef BGB_LOOP_H
#define BGB_LOOP_H

#include <stdint.h>

#include "bg_error.h"
#include "bga_curve.h"
#include "bga_zap.h"
#include "bgb_market.h"

/* Rotation fit is split over at most this many agents. */
#define BGB_LOOP_MAX_ROTFIT 4
#define BGB_LOOP_MAX_AWARDS (BGB_LOOP_MAX_ROTFIT + 2)
#define BGB_LOOP_REASON_MAX 64
/* Sellers a re-purchase may leave out, and purchases a buyer holds at once
 * (its job's, and one per service bought again after a loss). */
#define BGB_LOOP_MAX_EXCLUDE 16
#define BGB_LOOP_MAX_HELD 32

typedef struct bgb_loop bgb_loop_t;

typedef struct bgb_loop_config {
    const char *endpoint;       /* the agents' ROUTER endpoint to bind (tcp://...; port '*') */
    bgb_market_config_t market; /* the live market's settings (name included) */
    /* Each contract row as the market makes it, with the label of the
     * purchase it belongs to (the store's job id; "" for none), called on
     * the loop thread: it must not block. NULL: none. */
    void (*on_contract)(void *ctx, const char *label, const bgb_contract_t *row);
    void *contract_ctx;
    /* CURVE on the agents' endpoint (NULL: plaintext): the broker's key
     * pair (copied) and the folder of the agents' NAME.pub files. */
    const bga_curve_keypair_t *curve;
    const char *authorized_agents;
    /* Refused connections and registrations, one line each, called on the
     * loop's or the ZAP handler's thread; NULL: not logged. */
    bga_zap_log_fn log;
    void *log_ctx;
} bgb_loop_config_t;

/* Binds the endpoint and starts the thread. Caller owns *out (bgb_loop_stop).
 * With CURVE, a bad authorized_agents folder is BG_ERR_INVALID naming it
 * (and the file). */
bg_status bgb_loop_start(const bgb_loop_config_t *config, bgb_loop_t **out, bg_error_t *err);

/* The endpoint actually bound (the port chosen for '*'). */
const char *bgb_loop_endpoint(const bgb_loop_t *loop);

/* Over CURVE, what a coordinator needs to reach the agents: the broker's
 * key pair and each registered agent's key by its endpoint (lives as long
 * as the loop); NULL in plaintext. */
const bga_curve_peers_t *bgb_loop_curve(const bgb_loop_t *loop);

/* Keys in the authorized folder when the loop started (0 in plaintext). */
int bgb_loop_authorized_keys(const bgb_loop_t *loop);

/* Stops the thread (buyers must be gone) and frees; accepts NULL. */
void bgb_loop_stop(bgb_loop_t **loop);

/*
 * A copy of one of the REST API's live views (BGB_REST_VIEW_* of
 * bgb_rest.h: the agents as JSON, the market's prices, contracts.csv,
 * agents.csv), rendered by the loop thread when asked. Caller frees; NULL
 * when the loop does not answer within a few seconds or memory ran out.
 */
char *bgb_loop_view(bgb_loop_t *loop, int what);

/*
 * The number of live agents in the directory (basic-service and resource
 * entries). With wait_seconds > 0, blocks until there is at least one or
 * that long has passed.
 */
int bgb_loop_live_agents(bgb_loop_t *loop, double wait_seconds);

/* One job's purchase: what to buy, then what was bought. */
typedef struct bgb_loop_purchase {
    /* in */
    char label[BGB_LEDGER_LABEL_MAX]; /* the store's job id, for the contract log */
    bgb_mechanism mechanism;
    double budget;
    int integ; /* the plan needs an integration step */
    /* A re-purchase (replace = 1): one service `good` (BGB_GOOD_ROTFIT ..
     * INTEG), `quantity` units of it from one seller, none of exclude[0 ..
     * nexclude) (directory ids: the agents the job lost); integ unused. */
    int replace, good;
    double quantity;
    uint32_t exclude[BGB_LOOP_MAX_EXCLUDE];
    int nexclude;
    /* out */
    uint64_t job;                     /* the market's job number (for release) */
    char reason[BGB_LOOP_REASON_MAX]; /* "" when bought; else why not */
    bgb_award_t awards[BGB_LOOP_MAX_AWARDS];
    int nawards;
    double spent, latency;
} bgb_loop_purchase_t;

typedef struct bgb_loop_buyer bgb_loop_buyer_t;

/* A buyer for the calling thread. Caller owns *out (bgb_loop_buyer_destroy). */
bg_status bgb_loop_buyer_new(bgb_loop_t *loop, bgb_loop_buyer_t **out, bg_error_t *err);

/* Frees the buyer; a purchase it made and did not release is released. */
void bgb_loop_buyer_destroy(bgb_loop_buyer_t **buyer);

/*
 * Buys p's needs (rotation fit split over the directory's sellers, sparse
 * solve, and an integration step when p->integ) and waits for the outcome,
 * calling keep_going(ctx) about once a second: when it returns 0 the
 * purchase is abandoned (the loop releases whatever it gets, and whatever
 * else this buyer holds) and the call returns BG_ERR_CONFLICT. BG_OK: the market answered,
 * p->reason empty (bought: p->awards) or naming why not ("no seller", "timeout", "budget").
 * BG_ERR_IO when the loop is gone. One purchase at a time per buyer.
 */
bg_status bgb_loop_buy(bgb_loop_buyer_t *buyer, bgb_loop_purchase_t *p,
                       int (*keep_going)(void *ctx), void *ctx, bg_error_t *err);

/* The job ended: its sellers are released (answered once done). */
void bgb_loop_release(bgb_loop_buyer_t *buyer, uint64_t job);

/*
 * From any thread, before a job is marked cancelled: the purchase
 * labelled `label` (the store's job id) is settled (bgb_market_settle:
 * its contract rows end now) and its sellers are left to the buyer's
 * release; a purchase still buying is abandoned (nothing bought stays,
 * its buyer is not answered and gives up at its next look at the job).
 * Returns when done, or after a few seconds if the loop does not answer.
 */
void bgb_loop_settle(bgb_loop_t *loop, const char *label);

/*
 * Agent `agent` of the buyer's purchase `job` was lost while serving
 * `good`: its contract is settled for `delivered` units of work
 * (bgb_market_settle_lost), the rest of the purchase stays. Returns the
 * money that contract comes to, or −1 when there is no such contract or
 * the loop does not answer.
 */
double bgb_loop_settle_lost(bgb_loop_buyer_t *buyer, uint64_t job, uint32_t agent, int good,
                            double delivered);

#endif
