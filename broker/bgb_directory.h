/*
 * bgb_directory — the live market's agent directory: who is on the
 * market, how to reach them, and what they last said of themselves.
 *
 * An agent daemon registers (REGISTER: its compute endpoint, services,
 * slots, price policy, cores and memory) on the broker's ROUTER socket and
 * is answered REGISTERED with its directory id and its overlay neighbours;
 * it then heartbeats its free slots and prices, and is dropped after
 * `heartbeat_timeout` seconds of silence. A daemon has up to two rows on
 * one socket (routing identity): its basic-service seller, and its host's
 * resource seller (`resource` set in its messages). A host has one
 * resource seller: the first daemon of a host (the host part of its
 * endpoint) to register one sells the host's cores and memory, and a later
 * one is answered REGISTERED without an id and with the reason; it stands
 * by and asks again at its heartbeats, so it takes over once the first is
 * dropped. The overlay links each agent to the most recently registered
 * others of its role (service sellers and resource sellers form one
 * overlay each), symmetrically; the directory relays calls for proposals
 * along it (RELAY → CFP) and the broker does nothing else there.
 *
 * The rows are shared inside broker/: the purchases (bgb_market) read an
 * agent's prices, free room and endpoint from them and keep, in each row,
 * the orders they have in flight to it (`pending`, `pend_res`), which a
 * new registration starts at zero. bgb_agent_info_t is the public part
 * (GET /v1/agents, agents.csv).
 *
 * Threading: one thread (the broker's market loop). Time: `now` is the
 * caller's monotonic seconds; the module reads no clock. Ownership: frames
 * and messages are borrowed for the call; io.send copies what it keeps.
 */
#ifndef BGB_DIRECTORY_H
#define BGB_DIRECTORY_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bga_mmsg.h"
#include "bga_wire.h"
#include "bgb_goods.h"

#define BGB_DIRECTORY_MAX_AGENTS 1024
#define BGB_DIRECTORY_NAME_MAX 64
#define BGB_DIRECTORY_ENDPOINT_MAX 256
#define BGB_DIRECTORY_IDENTITY_MAX 255

/* How the broker reaches an agent: send frames to the ROUTER peer whose
 * routing identity is `identity` (as received with its messages). */
typedef struct bgb_directory_io {
    void *ctx;
    bg_status (*send)(void *ctx, const uint8_t *identity, size_t identity_len,
                      const bga_frame_t *frames, int nframes);
} bgb_directory_io_t;

/* A directory row (GET /v1/agents). */
typedef struct bgb_agent_info {
    uint32_t id;
    char name[BGB_DIRECTORY_NAME_MAX];
    char endpoint[BGB_DIRECTORY_ENDPOINT_MAX];
    unsigned services; /* BGA_SERVICE_* bits; resource sellers: 0 */
    int resource;      /* a resource seller (cores, memory): the daemon's second entry */
    int slots, free_slots;
    double free_cores, free_memory; /* resource seller: not sold */
    long refusals;                  /* orders it refused (no slot, no resources, price) */
    double floor[BGB_GOODS];        /* price policy: floor per unit */
    double margin, load_slope;
    double price[BGB_GOODS]; /* its current asking price per unit (0: not sold) */
    double cores, memory;
    double last_heartbeat; /* monotonic seconds */
    int alive;
} bgb_agent_info_t;

/* A row as the broker keeps it. */
typedef struct bgb_dir_agent {
    int used;
    bgb_agent_info_t info;
    uint8_t identity[BGB_DIRECTORY_IDENTITY_MAX];
    size_t idlen;
    int pending;                          /* the purchases' service orders in flight to it */
    double pend_res[2];                   /* resource seller: cores, GiB ordered, not answered */
    uint32_t nb[BGA_MMSG_MAX_NEIGHBOURS]; /* overlay neighbours (symmetric links) */
    int nnb;
} bgb_dir_agent_t;

typedef struct bgb_directory bgb_directory_t;

/* overlay_degree in [1, BGA_MMSG_MAX_NEIGHBOURS], heartbeat_timeout > 0
 * (checked by the caller, bgb_market_new). Caller owns *out. */
bg_status bgb_directory_new(int overlay_degree, double heartbeat_timeout,
                            const bgb_directory_io_t *io, bgb_directory_t **out, bg_error_t *err);
void bgb_directory_destroy(bgb_directory_t **d);

/* The broker's epoch, sent in every REGISTERED from now on (an agent that
 * hears a new one drops what it held for the previous broker). */
void bgb_directory_set_epoch(bgb_directory_t *d, uint64_t epoch);

/* The BGB_DIRECTORY_MAX_AGENTS rows, in registration-slot order (unused
 * ones have used == 0); borrowed while the directory lives. */
bgb_dir_agent_t *bgb_directory_rows(bgb_directory_t *d);
const bgb_dir_agent_t *bgb_directory_rows_const(const bgb_directory_t *d);
/* A row's slot (its index in rows), which the auctioneer names it by. */
int bgb_directory_slot_of(const bgb_directory_t *d, const bgb_dir_agent_t *a);
/* The live-or-not row with this id, or NULL. */
bgb_dir_agent_t *bgb_directory_by_id(bgb_directory_t *d, uint32_t id);
/* The row of the role (`resource` or not) registered from this socket. */
bgb_dir_agent_t *bgb_directory_by_identity(bgb_directory_t *d, const uint8_t *identity, size_t len,
                                           int resource);

/* Whether two tcp://HOST:PORT endpoints name the same host (the host part
 * compared whole). */
int bgb_directory_same_host(const char *a, const char *b);

/* Sends msg to the agent, marked for the row's role. BG_OK, or the send's
 * failure with err naming the message and the agent. */
bg_status bgb_directory_send(bgb_directory_t *d, const bgb_dir_agent_t *a, const bga_mmsg_t *msg,
                             bg_error_t *err);
/* An ERROR naming `why` to the socket with this identity (registered or
 * not). */
bg_status bgb_directory_reply_error(bgb_directory_t *d, const uint8_t *identity, size_t len,
                                    const char *why, bg_error_t *err);

/*
 * A REGISTER from the socket `identity`: a new row or the same one again
 * (its status refreshed), linked into its role's overlay, answered
 * REGISTERED with its id and neighbours; *out is the row. A resource role
 * whose host another daemon already sells is answered with the reason and
 * *out is NULL, as it is when the directory is full (the agent retries).
 */
bg_status bgb_directory_register(bgb_directory_t *d, const uint8_t *identity, size_t len,
                                 const bga_mmsg_t *in, double now, bgb_dir_agent_t **out,
                                 bg_error_t *err);
/* A REGISTER's or HEARTBEAT's status (slots, prices, free room) into the
 * row; the agent is alive as of now. */
void bgb_directory_heartbeat(bgb_dir_agent_t *a, const bga_mmsg_t *in, double now);
/* A RELAY: the call for proposals it carries goes on to its target, if
 * alive. */
void bgb_directory_relay(bgb_directory_t *d, const bga_mmsg_t *in);

/* Drops every agent silent for more than the heartbeat timeout at `now`,
 * calling gone(ctx, row) first for each (the market withdraws its offers). */
void bgb_directory_expire(bgb_directory_t *d, double now,
                          void (*gone)(void *ctx, bgb_dir_agent_t *a), void *ctx);

/* Agents dropped from the directory, kept (oldest first) for agents.csv
 * since their contracts stay in the ledger: the last this many. */
#define BGB_DIRECTORY_MAX_DEPARTED 4096
size_t bgb_directory_departed_count(const bgb_directory_t *d);
/* The k-th departed agent, oldest first (NULL past the count). */
const bgb_agent_info_t *bgb_directory_departed(const bgb_directory_t *d, size_t k);

/* Snapshot: writes up to max rows, returns the number of agents. */
size_t bgb_directory_agents(const bgb_directory_t *d, bgb_agent_info_t *out, size_t max);

#endif
