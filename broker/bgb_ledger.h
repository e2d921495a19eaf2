/*
 * bgb_ledger — the live market's contract log: every contract the market
 * makes, on both layers, as a row with the simulator's contracts.csv
 * columns, in a ring capped at `max_rows` (the oldest rows go first), and
 * what is read from it: the recent prices (GET /v1/market), the CSV
 * exports (/v1/market/contracts.csv and /agents.csv, the same files the
 * simulator writes, so one audit reads both), and the closing of a job's
 * rows when it is released. Beside them, in a ring of the same cap, the
 * central clearings that traded (/v1/market/clearings.csv): each with the
 * orders that set its price interval, so that a central contract's price
 * (its `clearing` column) can be explained from the log alone.
 *
 * Threading: one thread (the broker's market loop). Ownership: rows are
 * copied in; callbacks get borrowed rows, valid for the call.
 */
#ifndef BGB_LEDGER_H
#define BGB_LEDGER_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "bg_error.h"
#include "bgb_directory.h"
#include "bgb_goods.h"

#define BGB_LEDGER_LABEL_MAX 32

/*
 * A contract row, with the simulator's contracts.csv columns. `request` is,
 * as in the simulator, the service item a row serves: a number per service
 * contract, shared by the resource rows bought for it. The service row's
 * buyer is the job (its label, the broker's store id, when set); a
 * resource row's buyer is the basic-service agent that bought it. A
 * service row is priced per unit of work; a resource row (cores, memory)
 * per unit per second, over [start, end]: the lease, ended early when the
 * job is released. An open service row has end = INFINITY.
 *
 * Two columns follow the simulator's in contracts.csv. `use` is what the
 * row's service holds while it runs: its work (service rows), its GiB
 * (memory), its phase's cores (cores rows). A job's phases run one after
 * another and share the cores bought on a host, so a cores row's
 * `quantity`, what is paid, is only what the phase adds to the job's
 * widest phase there (bgb_market); the job pays for its widest phase
 * once. `clearing` is the central clearing that priced the row (0 for
 * none: posted, catallactic). `lost` is 1 on the rows of a request whose
 * seller was lost and settled pro rata (bgb_ledger_settle_lost): its
 * service row keeps the work delivered, its resource rows end then; the
 * seller bears what it paid for resources beyond what it earned.
 */
typedef struct bgb_contract {
    uint64_t job;     /* the market job id the row belongs to (both layers) */
    uint64_t request; /* the service item (see above) */
    double time, start, end;
    uint64_t buyer; /* service: the job id; resource: the basic agent's directory id */
    char buyer_label[BGB_LEDGER_LABEL_MAX]; /* service: the job's label ("" if none) */
    uint32_t seller;                        /* the agent's directory id */
    char seller_name[BGB_DIRECTORY_NAME_MAX];
    int mechanism;
    int layer; /* 0 service, 1 resource */
    int good;
    double quantity, price, buyer_limit, seller_limit;
    double use;        /* units held while the service runs (see above) */
    uint64_t clearing; /* the central clearing that priced it, 0: none */
    int lost;          /* settled after its seller was lost (see above) */
} bgb_contract_t;

typedef void (*bgb_contract_fn)(void *ctx, const bgb_contract_t *row);

/* The order that set one end of a clearing's price interval. */
typedef struct bgb_clearing_bound {
    int is_bid;                     /* a bid (else a seller's ask) */
    int excluded;                   /* the first left out (else the marginal matched one) */
    uint32_t agent;                 /* an ask's seller; a resource bid's basic agent (else 0) */
    char job[BGB_LEDGER_LABEL_MAX]; /* a bid's job: its label, else its number */
    double price;                   /* the order's limit: the bound */
} bgb_clearing_bound_t;

/* A central clearing that traded (market/bgm_callmarket.h has the rule):
 * price = low + k (high − low) when rationed (a buyer left out would have
 * paid the marginal ask), else low, the marginal ask. */
typedef struct bgb_clearing {
    uint64_t id; /* set by bgb_ledger_add_clearing, from 1 */
    double time;
    int layer, good, volume, rationed;
    double k, price, low, high;
    bgb_clearing_bound_t low_by, high_by;
} bgb_clearing_t;

typedef struct bgb_ledger bgb_ledger_t;

/* name: the broker's name, `scenario` in the CSVs (copied, truncated to
 * BGB_DIRECTORY_NAME_MAX − 1); max_rows ≥ 1. Caller owns *out. */
bg_status bgb_ledger_new(const char *name, size_t max_rows, bgb_ledger_t **out, bg_error_t *err);
void bgb_ledger_destroy(bgb_ledger_t **l);

/* Each row as it is added (NULL: none), on the adding thread. */
void bgb_ledger_on_contract(bgb_ledger_t *l, bgb_contract_fn fn, void *ctx);

/* Appends a copy of row; when the ring is full the oldest row goes. */
void bgb_ledger_add(bgb_ledger_t *l, const bgb_contract_t *row);

/* Appends a copy of a clearing (its id set here) to the clearings' ring;
 * returns the id. */
uint64_t bgb_ledger_add_clearing(bgb_ledger_t *l, const bgb_clearing_t *c);

/* Ends now every row of market job `job` (both layers) that ends later:
 * an open service row, a resource row's unused lease. */
void bgb_ledger_close(bgb_ledger_t *l, uint64_t job, double now);

/* A lost seller's contract settled pro rata: job's open service row sold
 * by `seller` for `good` keeps `delivered` units and ends now, and the
 * open resource rows bought for the same request end now too; all are
 * marked lost. Returns that request, or 0 when there is no such open row. */
uint64_t bgb_ledger_settle_lost(bgb_ledger_t *l, uint64_t job, uint32_t seller, int good,
                                double delivered, double now);

int bgb_ledger_recent_price(const bgb_ledger_t *l, int good, bgb_mechanism mech, int window,
                            double *mean);

/* Visits every row in order (oldest first). */
void bgb_ledger_each(const bgb_ledger_t *l, bgb_contract_fn fn, void *ctx);

/* contracts.csv / agents.csv with the simulator's columns (scenario = the
 * broker's name, replication 0): both layers' rows; a basic agent's
 * capacity is its slots, a resource seller's its cores and GiB with its
 * floor per unit-second as limit. BG_ERR_IO on a write failure. */
bg_status bgb_ledger_write_contracts_csv(const bgb_ledger_t *l, FILE *out, bg_error_t *err);
/* clearings.csv: clearing, time, layer, good, volume, k, rule (`k`:
 * rationed, `ask`: the marginal ask), price, low, low_order (`matched ask`
 * or `excluded bid`), low_owner (`agent:ID` or `job:LABEL`), high,
 * high_order (`matched bid` or `excluded ask`), high_owner. */
bg_status bgb_ledger_write_clearings_csv(const bgb_ledger_t *l, FILE *out, bg_error_t *err);
bg_status bgb_ledger_write_agents_csv(const bgb_ledger_t *l, const bgb_directory_t *d, FILE *out,
                                      bg_error_t *err);

#endif
