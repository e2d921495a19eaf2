/*
 * bgb_ledger — the live market's contract log: every contract the market
 * makes, on both layers, as a row with the simulator's contracts.csv
 * columns, in a ring capped at `max_rows` (the oldest rows go first), and
 * what is read from it: the recent prices (GET /v1/market), the CSV
 * exports (/v1/market/contracts.csv and /agents.csv, the same files the
 * simulator writes, so one audit reads both), and the closing of a job's
 * rows when it is released.
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
} bgb_contract_t;

typedef void (*bgb_contract_fn)(void *ctx, const bgb_contract_t *row);

typedef struct bgb_ledger bgb_ledger_t;

/* name: the broker's name, `scenario` in the CSVs (copied, truncated to
 * BGB_DIRECTORY_NAME_MAX − 1); max_rows ≥ 1. Caller owns *out. */
bg_status bgb_ledger_new(const char *name, size_t max_rows, bgb_ledger_t **out, bg_error_t *err);
void bgb_ledger_destroy(bgb_ledger_t **l);

/* Each row as it is added (NULL: none), on the adding thread. */
void bgb_ledger_on_contract(bgb_ledger_t *l, bgb_contract_fn fn, void *ctx);

/* Appends a copy of row; when the ring is full the oldest row goes. */
void bgb_ledger_add(bgb_ledger_t *l, const bgb_contract_t *row);

/* Ends now every row of market job `job` (both layers) that ends later:
 * an open service row, a resource row's unused lease. */
void bgb_ledger_close(bgb_ledger_t *l, uint64_t job, double now);

/* Mean price of the last `window` rows of a good under a mechanism;
 * returns the number averaged (0: *mean untouched). */
int bgb_ledger_recent_price(const bgb_ledger_t *l, int good, bgb_mechanism mech, int window,
                            double *mean);

/* Visits every row in order (oldest first). */
void bgb_ledger_each(const bgb_ledger_t *l, bgb_contract_fn fn, void *ctx);

/* contracts.csv / agents.csv with the simulator's columns (scenario = the
 * broker's name, replication 0): both layers' rows; a basic agent's
 * capacity is its slots, a resource seller's its cores and GiB with its
 * floor per unit-second as limit. BG_ERR_IO on a write failure. */
bg_status bgb_ledger_write_contracts_csv(const bgb_ledger_t *l, FILE *out, bg_error_t *err);
bg_status bgb_ledger_write_agents_csv(const bgb_ledger_t *l, const bgb_directory_t *d, FILE *out,
                                      bg_error_t *err);

#endif
