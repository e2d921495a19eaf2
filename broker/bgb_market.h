/*
 * bgb_market — the broker's live market and agent directory.
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
 * messages), one per host: the first daemon of a host (the host part of
 * its endpoint) to register one sells the host's cores and memory, and a
 * later one is answered REGISTERED without an id and with the reason; it
 * stands by and asks again at its heartbeats, so it takes over once the
 * first is dropped. A basic-service seller that agrees to a service unit
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

#define BGB_MARKET_NAME_MAX 64
#define BGB_MARKET_ENDPOINT_MAX 256
#define BGB_MARKET_MAX_NEEDS 16
#define BGB_MARKET_MAX_AGENTS 1024
#define BGB_MARKET_IDENTITY_MAX 255
#define BGB_MARKET_LABEL_MAX 32

/* Goods, numbered as the simulator's (bgm_role.h BGM_GOOD_*). */
typedef enum bgb_good {
    BGB_GOOD_ROTFIT = 0,
    BGB_GOOD_SOLVE = 1,
    BGB_GOOD_INTEG = 2,
    BGB_GOOD_CORES = 3,
    BGB_GOOD_MEMORY = 4,
    BGB_GOODS = 5
} bgb_good;

typedef enum bgb_mechanism {
    BGB_MECH_CENTRAL = 0,
    BGB_MECH_CATALLACTIC = 1,
    BGB_MECH_POSTED = 2
} bgb_mechanism;

/* "central", "catallactic", "posted"; parse returns -1 on an unknown name. */
const char *bgb_mechanism_name(bgb_mechanism m);
int bgb_mechanism_parse(const char *name);
/* "rotation-fit", "sparse-solve", "integration-step", "cores", "memory". */
const char *bgb_good_name(int good);

/* How the broker reaches an agent: send frames to the ROUTER peer whose
 * routing identity is `identity` (as received with its messages). */
typedef struct bgb_market_io {
    void *ctx;
    bg_status (*send)(void *ctx, const uint8_t *identity, size_t identity_len,
                      const bga_frame_t *frames, int nframes);
} bgb_market_io_t;

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
    uint32_t agent;                          /* directory id */
    char name[BGB_MARKET_NAME_MAX];          /* agent's name */
    char endpoint[BGB_MARKET_ENDPOINT_MAX];  /* agent's compute endpoint */
    double quantity;                         /* work this agent sells */
    double price;                            /* per unit of work */
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
    double spent;             /* Σ quantity × price */
    double latency;           /* seconds from bgb_market_buy to the outcome */
} bgb_outcome_t;

typedef void (*bgb_done_fn)(void *ctx, const bgb_outcome_t *outcome);

/*
 * A contract row, with the simulator's contracts.csv columns. `request` is,
 * as in the simulator, the service item a row serves: a number per service
 * contract, shared by the resource rows bought for it. The service row's
 * buyer is the job (its label, the broker's store id, when set with
 * bgb_market_label); a resource row's buyer is the basic-service agent
 * that bought it. A service row is priced per unit of work; a resource row
 * (cores, memory) per unit per second, over [start, end]: the lease,
 * ended early when the job is released.
 */
typedef struct bgb_contract {
    uint64_t job;       /* the market job id the row belongs to (both layers) */
    uint64_t request;   /* the service item (see above) */
    double time, start, end;
    uint64_t buyer;     /* service: the job id; resource: the basic agent's directory id */
    char buyer_label[BGB_MARKET_LABEL_MAX]; /* service: the job's label ("" if none) */
    uint32_t seller;    /* the agent's directory id */
    char seller_name[BGB_MARKET_NAME_MAX];
    int mechanism;
    int layer;          /* 0 service, 1 resource */
    int good;
    double quantity, price, buyer_limit, seller_limit;
} bgb_contract_t;

typedef void (*bgb_contract_fn)(void *ctx, const bgb_contract_t *row);

/* A directory row (GET /v1/agents). */
typedef struct bgb_agent_info {
    uint32_t id;
    char name[BGB_MARKET_NAME_MAX];
    char endpoint[BGB_MARKET_ENDPOINT_MAX];
    unsigned services;       /* BGA_SERVICE_* bits; resource sellers: 0 */
    int resource;            /* a resource seller (cores, memory): the daemon's second entry */
    int slots, free_slots;
    double free_cores, free_memory; /* resource seller: not sold */
    long refusals;           /* orders it refused (no slot, no resources, price) */
    double floor[BGB_GOODS]; /* price policy: floor per unit */
    double margin, load_slope;
    double price[BGB_GOODS]; /* its current asking price per unit (0: not sold) */
    double cores, memory;
    double last_heartbeat;   /* monotonic seconds */
    int alive;
} bgb_agent_info_t;

typedef struct bgb_market bgb_market_t;

/* Caller owns *out (bgb_market_destroy). io is copied. */
bg_status bgb_market_new(const bgb_market_config_t *config, const bgb_market_io_t *io,
                         bgb_market_t **out, bg_error_t *err);
/* Jobs still buying get no callback. */
void bgb_market_destroy(bgb_market_t **m);

/* Persist every contract as it is made (NULL: none). */
void bgb_market_on_contract(bgb_market_t *m, bgb_contract_fn fn, void *ctx);

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
                               const bga_frame_t *frames, int nframes, double now,
                               bg_error_t *err);

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
bg_status bgb_market_buy(bgb_market_t *m, uint64_t job, bgb_mechanism mechanism, double budget,
                         const bgb_need_t *needs, int nneeds, double now, bgb_done_fn done,
                         void *ctx, bg_error_t *err);

/* The job ended: its sellers free their slots (RELEASE to each), and the
 * resources its sellers bought are released too. */
void bgb_market_release(bgb_market_t *m, uint64_t job, double now);

/* Names a buying or bought job in the contract log (the broker's store id,
 * copied, truncated to BGB_MARKET_LABEL_MAX − 1). Unknown job: no effect. */
void bgb_market_label(bgb_market_t *m, uint64_t job, const char *label);

/* Directory snapshot: writes up to max rows, returns the number of agents. */
size_t bgb_market_agents(const bgb_market_t *m, bgb_agent_info_t *out, size_t max);

/* Mean price of the last `window` contracts of a good under a mechanism;
 * returns the number averaged (0: *mean untouched). */
int bgb_market_recent_price(const bgb_market_t *m, int good, bgb_mechanism mech, int window,
                            double *mean);

/* Visits every contract row in order (oldest first). */
void bgb_market_contracts(const bgb_market_t *m, bgb_contract_fn fn, void *ctx);

/* contracts.csv / agents.csv with the simulator's columns (scenario = the
 * broker's name, replication 0): both layers' rows; a basic agent's
 * capacity is its slots, a resource seller's its cores and GiB with its
 * floor per unit-second as limit. BG_ERR_IO on a write failure. */
bg_status bgb_market_write_contracts_csv(const bgb_market_t *m, FILE *out, bg_error_t *err);
bg_status bgb_market_write_agents_csv(const bgb_market_t *m, FILE *out, bg_error_t *err);

#endif
