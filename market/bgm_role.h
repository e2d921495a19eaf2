/*
 * bgm_role — the typed messages between the market's roles: the market
 * agent (central auctioneer and posted-price directory), the
 * complex-service buyer (one per job), the basic-service seller (which
 * also buys resources) and the resource seller.
 *
 * The simulator's world hosts one state machine per agent (bgm_market_agent,
 * bgm_buyer, bgm_seller, bgm_resource; the buyer and the basic seller buy
 * through the bgm_purchase each embeds, which is not a role) and routes
 * the generic message bgm_msg_t below between them; `biotgrid sim
 * --engine wire` carries every routed message through the pure codec
 * (bgm_codec.h). A role machine includes this header, never another
 * role's: what it reads of another role travels in a message.
 *
 * The payloads are meant to carry everything a receiver reads, so that a
 * role can live in another process with its messages carried by bgm_codec
 * over ZeroMQ. Messages are plain data, copied by value.
 */
#ifndef BGM_ROLE_H
#define BGM_ROLE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

/* Goods: the three basic services, then the two resources. */
#define BGM_GOOD_ROTFIT 0
#define BGM_GOOD_SOLVE 1
#define BGM_GOOD_INTEG 2
#define BGM_GOOD_CORES_ID 3
#define BGM_GOOD_MEMORY_ID 4
#define BGM_ROLE_GOODS 5

/* Caps of the variable parts of messages and parameters. */
#define BGM_ROLE_CANDIDATES 8 /* = BGM_MSG_CANDIDATES */
#define BGM_ROLE_GENES 5
#define BGM_MSG_CANDIDATES BGM_ROLE_CANDIDATES

/* The simulator's message numbers (bgm_msg_t.type); the wire type is
 * 0x1000 + the number (bgm_role_msg_type below). What a, b, c, price and
 * the candidate arrays carry is given per type next to each sender. */
enum {
    BGM_MT_BID = 1,
    BGM_MT_ASK,
    BGM_MT_FREE,
    BGM_MT_MATCH,
    BGM_MT_RBID,
    BGM_MT_RASK,
    BGM_MT_RFREE,
    BGM_MT_RAWARD,
    BGM_MT_RFAIL,
    BGM_MT_RCONFIRM,
    BGM_MT_CONFIRM,
    BGM_MT_CANCEL,
    BGM_MT_CFP,
    BGM_MT_PROPOSE,
    BGM_MT_OFFER,
    BGM_MT_ACCEPT,
    BGM_MT_REJECT,
    BGM_MT_GENES,
    BGM_MT_QUERY,
    BGM_MT_LIST,
    BGM_MT_ORDER,
    BGM_MT_AVAIL,
    BGM_MT_RPART,
    BGM_MT_TAKE,
    BGM_MT_REFUSE
};

/* A message between agents in the simulator: one generic layout for every
 * type. Plain data, copied by value; drivers own the copies they queue. */
typedef struct bgm_msg {
    uint16_t type;
    int16_t good;
    uint16_t hops;
    uint16_t ncand;
    uint32_t from, to;
    uint32_t req;     /* the request this message is about (its buyer's numbering) */
    uint32_t attempt; /* request attempt; stale attempts are ignored */
    uint32_t origin;  /* CFP originator */
    double price;
    double a, b, c; /* type-specific numbers */
    uint32_t cand[BGM_MSG_CANDIDATES];
    double cand_price[BGM_MSG_CANDIDATES];
    double cand_speed[BGM_MSG_CANDIDATES];
} bgm_msg_t;

/*
 * Message types: the wire type is 0x1000 + the simulator's message number
 * (the same numbers as bgm_world.c's M_* enum), so the simulator's flow
 * and the live grid's flow are one protocol.
 */
typedef enum bgm_role_msg_type {
    BGM_RM_BID = 0x1001,      /* buyer → market: service bid */
    BGM_RM_ASK = 0x1002,      /* basic seller → market: reservation, slots */
    BGM_RM_FREE = 0x1003,     /* basic seller → market: one slot free again */
    BGM_RM_MATCH = 0x1004,    /* market → basic seller: a matched bid */
    BGM_RM_RBID = 0x1005,     /* basic seller → market: resource bid */
    BGM_RM_RASK = 0x1006,     /* resource seller → market: registration */
    BGM_RM_RFREE = 0x1007,    /* resource seller → market: capacity freed */
    BGM_RM_RAWARD = 0x1008,   /* market → resource seller: a resource award */
    BGM_RM_RFAIL = 0x1009,    /* market|resource seller → basic seller: resource failed */
    BGM_RM_RCONFIRM = 0x100a, /* resource seller → basic seller: resources rented */
    BGM_RM_CONFIRM = 0x100b,  /* basic seller → buyer: the service is ready (a delivery) */
    BGM_RM_CANCEL = 0x100c,   /* basic seller → buyer: agreed service lost its resources */
    BGM_RM_CFP = 0x100d,      /* call for proposals (catallactic, hop-limited) */
    BGM_RM_PROPOSE = 0x100e,  /* seller → buyer: opening price */
    BGM_RM_OFFER = 0x100f,    /* either way: counter-offer */
    BGM_RM_ACCEPT = 0x1010,   /* either way: price agreed */
    BGM_RM_REJECT = 0x1011,   /* either way: bargaining ended */
    BGM_RM_GENES = 0x1012,    /* catallactic learning: strategy genes, fitness */
    BGM_RM_QUERY = 0x1013,    /* posted: buyer → directory */
    BGM_RM_LIST = 0x1014,     /* posted: directory → buyer: candidates */
    BGM_RM_ORDER = 0x1015,    /* posted: buyer → seller at the posted price */
    BGM_RM_AVAIL = 0x1016,    /* posted: seller → directory: free capacity */
    BGM_RM_RPART = 0x1017,    /* call markets: market → resource seller, one part */
    BGM_RM_TAKE = 0x1018,     /* buyer → basic seller: a delivery taken (the contract is final) */
    BGM_RM_REFUSE = 0x1019,   /* buyer → basic seller: a delivery refused (no longer wanted) */
    BGM_RM_FIRST = BGM_RM_BID,
    BGM_RM_LAST = BGM_RM_REFUSE
} bgm_role_msg_type;
_Static_assert(BGM_RM_BID == 0x1000 + BGM_MT_BID && BGM_RM_REFUSE == 0x1000 + BGM_MT_REFUSE,
               "wire types are 0x1000 + the simulator's message numbers");

/* Typed payloads (what the receiver reads; units as in bgm_world.c). */
/* BID: a live buyer also names the sellers the bid must not be matched
 * with and its need group (0: none), bgm_market_agent.h. */
typedef struct bgm_rm_bid {
    int good;
    double price_per_unit, work, deadline;
    uint32_t group;
    int nexclude;
    uint32_t exclude[BGM_ROLE_CANDIDATES];
} bgm_rm_bid_t;
typedef struct bgm_rm_ask {
    int good;
    double reservation_per_unit, slots;
} bgm_rm_ask_t;
/* MATCH: what the seller reads to serve the bid: its work, the seller's
 * own ask (its limit) and until when the buyer wants the item. */
typedef struct bgm_rm_match {
    int good;
    uint32_t buyer;
    double price_per_unit, work, seller_limit, deadline;
} bgm_rm_match_t;
typedef struct bgm_rm_rbid {
    double cores, memory, flops, limit_total;
    double deadline; /* the market agent drops the bid after it */
} bgm_rm_rbid_t;
typedef struct bgm_rm_rask {
    double cores, memory, speed, cost_rate_per_core;
    double memory_cost_rate; /* per GiB-second: the exchange prices bundles with it */
} bgm_rm_rask_t;
typedef struct bgm_rm_rfree {
    double cores, memory;
} bgm_rm_rfree_t;
typedef struct bgm_rm_raward {
    uint32_t buyer;
    double rate, cores, memory, flops, seller_limit;
    double budget; /* the bid's limit in all: the seller checks the rent against it */
} bgm_rm_raward_t;
typedef struct bgm_rm_rconfirm {
    int good; /* cores|memory for one part of a call-market bundle, else −1 */
    int parts;
    double rate, start, end, seller_limit_rate;
    double part_quantity, part_buyer_limit, part_seller_cost;
} bgm_rm_rconfirm_t;
/* CONFIRM (a delivery): the basic seller's service for the buyer's
 * request and attempt is ready, at the agreed price, from start to end;
 * bundle is the seller's own number for the resources that run it. The
 * buyer answers TAKE or REFUSE with the same bundle. */
typedef struct bgm_rm_confirm {
    uint32_t bundle;
    double price_per_unit, start, end;
} bgm_rm_confirm_t;
typedef struct bgm_rm_take {
    uint32_t bundle;
} bgm_rm_take_t;
typedef struct bgm_rm_cfp {
    int good, hops;
    uint32_t origin;
    double work_or_cores, memory, flops;
} bgm_rm_cfp_t;
typedef struct bgm_rm_propose {
    double price, speed;
} bgm_rm_propose_t;
/* OFFER, ACCEPT (REJECT carries none). From a buyer to a seller they also
 * carry what the seller reads of the request: the good (< 0: a bundle),
 * its work or bundle, the budget, how long the offer stands (the buyer's
 * deadline) and, on the first offer of a bargain, opening = 1. */
typedef struct bgm_rm_price {
    double price;
    int good, opening;
    double work_or_cores, memory, flops, budget, valid_until;
} bgm_rm_price_t;
typedef struct bgm_rm_genes {
    double genes[BGM_ROLE_GENES], fitness;
    int request; /* 1 request, 0 reply */
} bgm_rm_genes_t;
typedef struct bgm_rm_query {
    int good; /* a service, or cores: a resource bundle of `cores` and `memory` GiB */
    double limit, cores, memory;
    int nexclude; /* sellers not to list */
    uint32_t exclude[BGM_ROLE_CANDIDATES];
} bgm_rm_query_t;
typedef struct bgm_rm_list {
    int ncand;
    uint32_t cand[BGM_ROLE_CANDIDATES];
    double cand_price[BGM_ROLE_CANDIDATES], cand_speed[BGM_ROLE_CANDIDATES];
} bgm_rm_list_t;
typedef struct bgm_rm_order {
    int good;
    double price, work_or_cores, memory, flops;
    double budget, valid_until; /* as an OFFER's */
} bgm_rm_order_t;
typedef struct bgm_rm_avail {
    double free_a, free_b;
} bgm_rm_avail_t;
typedef struct bgm_rm_rpart {
    int good, parts;
    uint32_t buyer;
    double quantity, duration, rate, buyer_limit, start;
} bgm_rm_rpart_t;

/* The payload of a message, by type. */
typedef union bgm_role_payload {
    bgm_rm_bid_t bid;
    bgm_rm_ask_t ask;
    bgm_rm_match_t match;
    bgm_rm_rbid_t rbid;
    bgm_rm_rask_t rask;
    bgm_rm_rfree_t rfree;
    bgm_rm_raward_t raward;
    bgm_rm_rconfirm_t rconfirm;
    bgm_rm_confirm_t confirm;
    bgm_rm_cfp_t cfp;
    bgm_rm_propose_t propose;
    bgm_rm_price_t price; /* OFFER, ACCEPT */
    bgm_rm_genes_t genes;
    bgm_rm_query_t query;
    bgm_rm_list_t list;
    bgm_rm_order_t order;
    bgm_rm_avail_t avail;
    bgm_rm_rpart_t rpart;
    bgm_rm_take_t take; /* TAKE, REFUSE */
} bgm_role_payload_t;

/* One message between roles: header (who, about which request) + payload. */
typedef struct bgm_role_msg {
    uint16_t type; /* bgm_role_msg_type */
    uint32_t from, to;
    uint32_t req;     /* the request this message is about (sender's numbering) */
    uint32_t attempt; /* stale attempts are ignored */
    uint64_t job;     /* live grid: the broker's job id; 0 in the simulator */
    bgm_role_payload_t u;
} bgm_role_msg_t;

#endif
