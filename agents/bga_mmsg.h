/*
 * bga_mmsg — the live market's messages between the broker and the agents
 * (registration, heartbeats, orders, call-market matches, catallactic
 * bargaining), pure encode/decode with no sockets.
 *
 * A message is a bga_wire message of the live range (types 0x1101..0x1111,
 * the low byte being bga_mmsg_type; bga_wire.h): the versioned header
 * frame with the job, the scalar fields frame and one frame per array
 * (floor, prices, capacity, neighbours, name, endpoint, reason), every
 * field present in every type. The same framing and the same checks as
 * the compute services and the simulator's market roles (bgm_codec): a
 * receiver reads the type from frame 0, and a message that breaks the
 * schema, or this module's caps (texts, neighbours, BGA_MMSG_MAX_BYTES in
 * all), is refused naming the frame or field.
 *
 * Ownership: a bga_mmsg_t is a plain value. bga_mmsg_encode fills a
 * bga_frames_t that owns its buffers (bga_frames_free).
 */
#ifndef BGA_MMSG_H
#define BGA_MMSG_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bga_wire.h"

/* A whole message's bytes: the header, 17 fields and the arrays at their
 * caps come to about 900. */
#define BGA_MMSG_MAX_BYTES 2048
#define BGA_MMSG_GOODS 5
#define BGA_MMSG_MAX_NEIGHBOURS 8
#define BGA_MMSG_NAME_MAX 64
#define BGA_MMSG_ENDPOINT_MAX 256
#define BGA_MMSG_REASON_MAX 200

typedef enum bga_mmsg_type {
    BGA_MM_REGISTER = 1,   /* agent → broker: who it is, what it sells */
    BGA_MM_REGISTERED = 2, /* broker → agent: its id and overlay neighbours */
    BGA_MM_HEARTBEAT = 3,  /* agent → broker: free slots, current prices */
    BGA_MM_ORDER = 4,      /* broker → seller: buy (job, good, quantity) at price */
    BGA_MM_CONFIRM = 5,    /* seller → broker: contract made at price */
    BGA_MM_REFUSE = 6,     /* seller → broker: no (reason) */
    BGA_MM_RELEASE = 7,    /* broker → seller: the job ended, free its slots */
    BGA_MM_CFP = 8,        /* call for proposals (job, good, hops, origin) */
    BGA_MM_PROPOSE = 9,    /* seller → buyer: opening price */
    BGA_MM_OFFER = 10,     /* either way: counter-offer at price */
    BGA_MM_ACCEPT = 11,    /* buyer → seller: accepts the seller's price */
    BGA_MM_REJECT = 12,    /* either way: bargaining ended */
    BGA_MM_RELAY = 13,     /* agent → broker: deliver the CFP inside to agent `target` */
    BGA_MM_ERROR = 14,     /* either way: a message was malformed (reason) */
    /* Layer 1: a basic-service seller that agreed to a service (job, good)
     * buys the cores and memory it needs before it confirms. */
    BGA_MM_RBUY = 15,      /* seller → broker: buy cores, memory for term s, at most price */
    BGA_MM_RBOUGHT = 16,   /* broker → seller: bought (prices[3..4] the rates, price the money) */
    BGA_MM_RFAIL = 17,     /* broker → seller: could not (reason) */
    BGA_MM_FIRST = BGA_MM_REGISTER,
    BGA_MM_LAST = BGA_MM_RFAIL
} bga_mmsg_type;

typedef struct bga_mmsg {
    int type;
    uint64_t job;
    /* REGISTERED: the broker's epoch, drawn at random when it starts (1 ..
     * 2^53), carried in the header's job (REGISTERED names no job): an
     * agent that hears a new one knows the broker it sold to died. */
    uint64_t epoch;
    uint32_t agent;   /* the agent's directory id (0 before registration) */
    uint32_t target;  /* RELAY: the neighbour to deliver to */
    uint32_t origin;  /* CFP: the agent that first got it (0: the broker) */
    char name[BGA_MMSG_NAME_MAX];
    char endpoint[BGA_MMSG_ENDPOINT_MAX]; /* compute endpoint */
    unsigned services;                    /* BGA_SERVICE_* bits */
    /* The role a message is from or for: 0 the basic-service seller, 1 the
     * resource seller of the same daemon (one socket, two directory ids). */
    int resource;
    int slots, free_slots;
    double floor[BGA_MMSG_GOODS];         /* price policy */
    double margin, load_slope;
    double prices[BGA_MMSG_GOODS];        /* current asking prices */
    double cores, memory;           /* resource seller: capacity; RBUY: wanted */
    double free_cores, free_memory; /* resource seller: not held */
    double term;                    /* resource goods: lease, s (ORDER, CFP, RBUY) */
    int good;
    int hops;
    int attempt; /* CFP: the buyer's discovery round (a fresh round is heard again) */
    double quantity, price;
    /* Resource goods (ORDER, CFP, OFFER, ACCEPT, REJECT, RELAY to a
     * resource seller): the job whose service they serve and that
     * service's good, so the seller can count the job's phases, which
     * never run at once, against its cores once (bga_rseller). 0 and −1:
     * not said. */
    uint64_t parent;
    int serves;
    int nneighbours;
    uint32_t neighbours[BGA_MMSG_MAX_NEIGHBOURS];
    char reason[BGA_MMSG_REASON_MAX];
} bga_mmsg_t;

/* A zeroed message of the given type (good = -1, serves = -1). */
void bga_mmsg_init(bga_mmsg_t *m, int type);
const char *bga_mmsg_type_name(int type);

/* Whether frames look like a live market message (frame 0's type). */
int bga_mmsg_is_market(const bga_frame_t *frames, int nframes);

/* BG_ERR_INVALID naming the field for an invalid message; BG_ERR_NOMEM. */
bg_status bga_mmsg_encode(const bga_mmsg_t *m, bga_frames_t *out, bg_error_t *err);
/* BG_ERR_PARSE / BG_ERR_INVALID / BG_ERR_LIMIT naming the frame or field. */
bg_status bga_mmsg_decode(const bga_frame_t *frames, int nframes, bga_mmsg_t *m, bg_error_t *err);

#endif
