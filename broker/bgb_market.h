/*
 * bgb_market — the broker's live market: the purchases of jobs and of
 * their sellers' resources.
 *
 * It stands on two modules of its own: bgb_directory (the agents on the
 * market: registration, one resource seller per host, heartbeats and
 * liveness, the overlay, snapshots) and bgb_ledger (the contract log, its
 * recent prices and CSV exports, rows closed at release); this module
 * routes the agents' messages between them and the purchases.
 *
 * Hosts the market agent (the central call markets, cleared every
 * `period` seconds, and the posted-price directory) and one buyer per job,
 * and talks to the agents through the broker's ZeroMQ ROUTER socket, which
 * the broker daemon owns: the daemon hands every agent-originated message
 * to bgb_market_on_frames and sends what the market emits through io.send.
 * Catallactic jobs have no auctioneer: the job's buyer sends a hop-limited
 * call for proposals to a few agents, which forward it to their overlay
 * neighbours (the directory gives each agent a few at registration; the
 * broker only relays frames between them), and bargains directly with the
 * sellers that propose.
 *
 * The messages (agents/bga_mmsg.h) are: REGISTER (agent → broker: compute
 * endpoint, services, slots, price policy, cores, memory) answered by
 * REGISTERED (its id and overlay neighbours); HEARTBEAT (free slots, the
 * agent's current prices); ORDER/MATCH (broker → seller: a contract
 * offer at a price) answered by CONFIRM or REFUSE; CFP, PROPOSE, OFFER,
 * ACCEPT, REJECT for catallactic bargaining; RELEASE (the job ended).
 *
 * Layer 1 (resources): an agent daemon hosts a resource seller too (a
 * second directory entry on the same socket, `resource` set in its
 * messages), one per host (bgb_directory says how). A basic-service seller that agrees to a service unit
 * sends RBUY (cores, memory, lease, its money limit); the market buys them
 * for it as a sub-job from its host's resource seller, on the same
 * mechanism as the job (posted postings, a central call market per
 * resource, catallactic bargaining), and answers RBOUGHT or RFAIL; the
 * seller then confirms or refuses the service. Each message about a
 * sub-job names the job and the service it serves (bga_mmsg parent,
 * serves): a job's services run one after another, so the resource seller
 * counts the job's cores as its widest phase's, and so do the market's
 * room checks. The resource rows are logged with the service rows they
 * serve when the job is bought, and end when the job is released.
 *
 * Threading: every call is made from the broker's ZeroMQ loop thread only;
 * callbacks run on that thread, from inside the call that caused them.
 * Time: `now` is monotonic seconds (bg_clock), supplied by the caller;
 * the module never reads a clock.
 * Ownership: frames passed in are borrowed for the call; frames given to
 * io.send are borrowed for the call too (send copies what it keeps).
 *
 * The service layer runs the simulator's role machines: its auctioneer
 * and posted directory are the market agent machine (bgm_market_agent,
 * hosted by bgb_auction), and each job's buyer is a purchase machine
 * (bgm_purchase, one request per unit: a BID, a QUERY and orders down the
 * directory's list, or calls for proposals and bargaining, with its
 * retries and deadline), whose messages the market carries to the
 * auctioneer, the directory or the agents and whose sellers' answers it
 * hands back. The host adds what the machine does not know: a need split
 * over n sellers goes to n distinct agents, a seller that refused (posted,
 * central) is not asked again, and a job is let into the central book one
 * per clearing. A basic agent's sub-job on its host is a purchase machine
 * too, one bundle request per unit (q cores or q GiB for the lease, at
 * speed 1, priced per second for the whole; live sellers price per
 * unit-second): its RBID waits in the market's call market per resource
 * (bgm_callmarket, cleared every period), its QUERY is answered from the
 * host's postings (bgm_posted), its calls for proposals go to the host's
 * resource seller. The host adds that a sub-job buys only on its host, a
 * catallactic one skips a seller without room for it (counting its job's
 * phases once), and a round whose bargains all failed is played with fresh
 * genes.
 */
#ifndef BGB_MARKET_H
#define BGB_MARKET_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "bg_error.h"
#include "bga_wire.h"
#include "bgb_directory.h"
#include "bgb_goods.h"
#include "bgb_ledger.h"

#define BGB_MARKET_MAX_NEEDS 16

/* How the broker reaches an agent (bgb_directory_io_t). */
typedef bgb_directory_io_t bgb_market_io_t;

typedef struct bgb_market_config {
    const char *name;          /* the broker's name: `scenario` in the CSVs */
    double period;             /* central: clearing period, s (> 0) */
    double k;                  /* central: k-pricing parameter in [0, 1] */
    double heartbeat_timeout;  /* an agent silent this long is dropped, s */
    double reply_timeout;      /* a seller's answer to an order, s */
    double buy_timeout;        /* a job not fully bought by then fails "timeout" */
    int overlay_degree;        /* neighbours given to each agent (≥ 1) */
    int hops;                  /* catallactic CFP hop limit (≥ 1) */
    int max_rounds;            /* catallactic bargaining rounds */
    size_t max_contracts;      /* contract log cap (rows kept; older dropped) */
    /* The market's epoch, sent in every REGISTERED (1 .. 2^53; 0: drawn at
     * random by bgb_market_new, as a broker does at each start). */
    uint64_t epoch;
} bgb_market_config_t;

/* Defaults: period 0.2 s, k 0.5, heartbeat timeout 3 s, reply timeout 2 s,
 * buy timeout 10 s, overlay degree 3, hops 2, 12 rounds, 100000 rows. */
void bgb_market_config_default(bgb_market_config_t *c);

/* One basic service a job needs. */
typedef struct bgb_need {
    int good;        /* BGB_GOOD_ROTFIT..INTEG */
    double quantity; /* units of work (e.g. element-iterations) */
    int sellers;     /* distinct agents it is split over (rotation fit ×2) */
} bgb_need_t;

/* One bought service: what the coordinator needs to drive the agent. */
typedef struct bgb_award {
    int good;
    uint32_t agent;                            /* directory id */
    char name[BGB_DIRECTORY_NAME_MAX];         /* agent's name */
    char endpoint[BGB_DIRECTORY_ENDPOINT_MAX]; /* agent's compute endpoint */
    double quantity;                           /* work this agent sells */
    double price;                              /* per unit of work */
} bgb_award_t;

/*
 * A job's outcome. On success reason is NULL and awards lists every need's
 * sellers (need order, `sellers` rows per need). On failure reason is
 * "budget", "no seller" or "timeout", nawards is 0, and every seller that
 * had agreed has been released. Borrowed for the call.
 */
typedef struct bgb_outcome {
    uint64_t job;
    const char *reason;
    const bgb_award_t *awards;
    int nawards;
    double spent;   /* Σ quantity × price */
    double latency; /* seconds from bgb_market_buy to the outcome */
} bgb_outcome_t;

typedef void (*bgb_done_fn)(void *ctx, const bgb_outcome_t *outcome);

typedef struct bgb_market bgb_market_t;

/* Caller owns *out (bgb_market_destroy). io is copied. */
bg_status bgb_market_new(const bgb_market_config_t *config, const bgb_market_io_t *io,
                         bgb_market_t **out, bg_error_t *err);
/* Jobs still buying get no callback. */
void bgb_market_destroy(bgb_market_t **m);

/* Persist every contract as it is made (NULL: none). */
void bgb_market_on_contract(bgb_market_t *m, bgb_contract_fn fn, void *ctx);

/* The market's directory and contract log, for snapshots and exports
 * (bgb_directory_agents, bgb_ledger_*): borrowed while the market lives,
 * read on the market's thread only. */
const bgb_directory_t *bgb_market_directory(const bgb_market_t *m);
const bgb_ledger_t *bgb_market_ledger(const bgb_market_t *m);

/* Answers the sender of a message its host could not take whole (more
 * frames than the wire allows, so it was not kept) with an ERROR naming
 * why; BG_OK unless the send fails. */
bg_status bgb_market_refuse(bgb_market_t *m, const uint8_t *identity, size_t identity_len,
                            const char *why, bg_error_t *err);

/*
 * One agent-originated message (frames borrowed). A malformed message gets
 * an ERROR reply and BG_OK; the return is a failure only for memory or a
 * failed send (err says which).
 */
bg_status bgb_market_on_frames(bgb_market_t *m, const uint8_t *identity, size_t identity_len,
                               const bga_frame_t *frames, int nframes, double now, bg_error_t *err);

/* Runs what is due at `now` (clearing, timeouts, liveness) and returns the
 * next time it wants to be called. */
double bgb_market_tick(bgb_market_t *m, double now);

/*
 * Starts buying a job's needs under `mechanism` for at most `budget` in
 * all. Asynchronous: done(ctx, outcome) is called once, from a later
 * on_frames/tick (or from inside this call when the outcome is immediate,
 * e.g. no seller or a budget under the sellers' floors). BG_ERR_INVALID
 * for bad arguments (naming the field), BG_ERR_CONFLICT for a job id
 * already buying.
 */
/* The epoch this market sends its agents in REGISTERED: an agent that
 * hears another than before drops what it held for the previous broker
 * (its contracts, bargains, resources and their leases) at once. */
uint64_t bgb_market_epoch(const bgb_market_t *m);

bg_status bgb_market_buy(bgb_market_t *m, uint64_t job, bgb_mechanism mechanism, double budget,
                         const bgb_need_t *needs, int nneeds, double now, bgb_done_fn done,
                         void *ctx, bg_error_t *err);

/*
 * bgb_market_buy for a job that must not get the sellers exclude[0 ..
 * nexclude) (directory ids, at most 32): a re-purchase of a service
 * whose agent was lost leaves that agent out under every mechanism, under
 * its id and its compute endpoint (an agent dropped from the directory
 * and registered again has a new id). The ids are borrowed for the call.
 */
bg_status bgb_market_buy_excluding(bgb_market_t *m, uint64_t job, bgb_mechanism mechanism,
                                   double budget, const bgb_need_t *needs, int nneeds,
                                   const uint32_t *exclude, int nexclude, double now,
                                   bgb_done_fn done, void *ctx, bg_error_t *err);

/*
 * Agent `agent` of bought job `job` was lost while it served good `good`
 * (its coordinator stopped hearing it): the contract is settled pro rata,
 * its service row keeps the work delivered (`delivered`, in the row's
 * units, clamped to [0, quantity]) and ends now; the rows of the resources
 * it bought for that service end now and their sellers get them back; the
 * agent, if still in the directory, is told to release the job. The
 * job's other contracts stay. Returns the money the settled contract
 * comes to (delivered × price), or −1 when the job has no such contract.
 */
double bgb_market_settle_lost(bgb_market_t *m, uint64_t job, uint32_t agent, int good,
                              double delivered, double now);

/* The job ended: its contract rows end now (bgb_ledger_close), its sellers
 * free their slots (RELEASE to each), and the resources its sellers bought
 * are released too. */
void bgb_market_release(bgb_market_t *m, uint64_t job, double now);

/* The job's account is settled now, its sellers not yet released: its
 * rows end now (bgb_ledger_close; a release later moves no end), so the
 * log says what it owes before the job's end is announced, while its
 * coordinator, which releases it, may still be stopping its agents (a
 * cancel). Unknown job: no effect. */
void bgb_market_settle(bgb_market_t *m, uint64_t job, double now);

/* Names a buying or bought job in the contract log (the broker's store id,
 * copied, truncated to BGB_LEDGER_LABEL_MAX − 1). Unknown job: no effect. */
void bgb_market_label(bgb_market_t *m, uint64_t job, const char *label);

#endif
