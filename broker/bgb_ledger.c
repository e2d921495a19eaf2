#include "bgb_ledger.h"

#include <math.h>
#include <stdlib.h>

struct bgb_ledger {
    char name[BGB_DIRECTORY_NAME_MAX];
    bgb_contract_t *log; /* ring of max rows */
    size_t max, head, count;
    bgb_clearing_t *clearings; /* ring of max clearings */
    size_t chead, ccount;
    uint64_t next_clearing;
    bgb_contract_fn on_contract;
    void *on_contract_ctx;
};

bg_status bgb_ledger_new(const char *name, size_t max_rows, bgb_ledger_t **out, bg_error_t *err)
{
    *out = NULL;
    if (max_rows < 1)
        return bg_error_set(err, BG_ERR_INVALID, "market: max_contracts must be >= 1");
    bgb_ledger_t *l = calloc(1, sizeof *l);
    if (l) {
        l->log = calloc(max_rows, sizeof *l->log);
        l->clearings = calloc(max_rows, sizeof *l->clearings);
    }
    if (!l || !l->log || !l->clearings) {
        if (l) {
            free(l->log);
            free(l->clearings);
        }
        free(l);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for %zu contract rows", max_rows);
    }
    snprintf(l->name, sizeof l->name, "%s", name ? name : "broker");
    l->max = max_rows;
    *out = l;
    return BG_OK;
}

void bgb_ledger_destroy(bgb_ledger_t **pl)
{
    if (!pl || !*pl)
        return;
    free((*pl)->log);
    free((*pl)->clearings);
    free(*pl);
    *pl = NULL;
}

void bgb_ledger_on_contract(bgb_ledger_t *l, bgb_contract_fn fn, void *ctx)
{
    l->on_contract = fn;
    l->on_contract_ctx = ctx;
}

/* The i-th row from the oldest. */
static bgb_contract_t *row_at(const bgb_ledger_t *l, size_t i)
{
    return &l->log[(l->head + i) % l->max];
}

void bgb_ledger_add(bgb_ledger_t *l, const bgb_contract_t *row)
{
    *row_at(l, l->count) = *row;
    if (l->count < l->max)
        l->count++;
    else
        l->head = (l->head + 1) % l->max;
    if (l->on_contract)
        l->on_contract(l->on_contract_ctx, row);
}

uint64_t bgb_ledger_add_clearing(bgb_ledger_t *l, const bgb_clearing_t *c)
{
    bgb_clearing_t *at = &l->clearings[(l->chead + l->ccount) % l->max];
    *at = *c;
    at->id = ++l->next_clearing;
    if (l->ccount < l->max)
        l->ccount++;
    else
        l->chead = (l->chead + 1) % l->max;
    return at->id;
}

void bgb_ledger_close(bgb_ledger_t *l, uint64_t job, double now)
{
    for (size_t i = 0; i < l->count; i++) {
        bgb_contract_t *r = row_at(l, i);
        if (r->job == job && r->end > now)
            r->end = now;
    }
}

uint64_t bgb_ledger_settle_lost(bgb_ledger_t *l, uint64_t job, uint32_t seller, int good,
                                double delivered, double now)
{
    uint64_t request = 0;
    for (size_t i = 0; i < l->count && !request; i++) {
        bgb_contract_t *r = row_at(l, i);
        if (r->job == job && r->layer == 0 && r->seller == seller && r->good == good &&
            r->end > now) {
            request = r->request;
            r->quantity = delivered;
            r->end = now;
            r->lost = 1;
        }
    }
    for (size_t i = 0; i < l->count && request; i++) {
        bgb_contract_t *r = row_at(l, i);
        if (r->job == job && r->layer == 1 && r->request == request && r->end > now) {
            r->end = now;
            r->lost = 1;
        }
    }
    return request;
}

int bgb_ledger_recent_price(const bgb_ledger_t *l, int good, bgb_mechanism mech, int window,
                            double *mean)
{
    int n = 0;
    double sum = 0;
    for (size_t i = l->count; i-- > 0 && n < window;) {
        const bgb_contract_t *r = row_at(l, i);
        if (r->good == good && r->mechanism == (int)mech) {
            sum += r->price;
            n++;
        }
    }
    if (n)
        *mean = sum / n;
    return n;
}

void bgb_ledger_each(const bgb_ledger_t *l, bgb_contract_fn fn, void *ctx)
{
    for (size_t i = 0; i < l->count; i++)
        fn(ctx, row_at(l, i));
}

typedef struct csv_ctx {
    const bgb_ledger_t *l;
    FILE *out;
    int failed;
} csv_ctx;

static void write_row(void *ctx, const bgb_contract_t *r)
{
    csv_ctx *c = ctx;
    /* An open contract (job still running) ends "now" for the audit: it
     * is written with end = start + 1e9 rather than inf. */
    const double end = isinf(r->end) ? r->start + 1e9 : r->end;
    char buyer[BGB_LEDGER_LABEL_MAX];
    if (r->buyer_label[0])
        snprintf(buyer, sizeof buyer, "%s", r->buyer_label);
    else
        snprintf(buyer, sizeof buyer, "%llu", (unsigned long long)r->buyer);
    char clearing[24] = "";
    if (r->clearing)
        snprintf(clearing, sizeof clearing, "%llu", (unsigned long long)r->clearing);
    if (fprintf(c->out, "%s,0,%s,%s,%llu,%.9g,%.9g,%.9g,%s,%u,%s,%.9g,%.9g,%.9g,%.9g,%.9g,%s,%d\n",
                c->l->name, bgb_mechanism_name((bgb_mechanism)r->mechanism),
                r->layer ? "resource" : "service", (unsigned long long)r->request, r->time,
                r->start, end, buyer, r->seller, bgb_good_name(r->good), r->quantity, r->price,
                r->buyer_limit, r->seller_limit, r->use, clearing, r->lost) < 0)
        c->failed = 1;
}

bg_status bgb_ledger_write_contracts_csv(const bgb_ledger_t *l, FILE *out, bg_error_t *err)
{
    csv_ctx c = {l, out, 0};
    if (fputs("scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,good,"
              "quantity,price,buyer_limit,seller_limit,use,clearing,lost\n",
              out) < 0)
        c.failed = 1;
    bgb_ledger_each(l, write_row, &c);
    if (c.failed || fflush(out) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot write contracts.csv");
    return BG_OK;
}

/* "agent:ID" or "job:LABEL", the owner of a clearing's bound. */
static const char *owner(const bgb_clearing_bound_t *b, char *buf, size_t size)
{
    if (b->is_bid)
        snprintf(buf, size, "job:%s", b->job);
    else
        snprintf(buf, size, "agent:%u", b->agent);
    return buf;
}

bg_status bgb_ledger_write_clearings_csv(const bgb_ledger_t *l, FILE *out, bg_error_t *err)
{
    int failed = fputs("clearing,time,layer,good,volume,k,rule,price,low,low_order,low_owner,"
                       "high,high_order,high_owner\n",
                       out) < 0;
    for (size_t i = 0; i < l->ccount; i++) {
        const bgb_clearing_t *c = &l->clearings[(l->chead + i) % l->max];
        char lo[BGB_LEDGER_LABEL_MAX + 8], hi[BGB_LEDGER_LABEL_MAX + 8];
        failed |= fprintf(out, "%llu,%.9g,%s,%s,%d,%.9g,%s,%.9g,%.9g,%s,%s,%.9g,%s,%s\n",
                          (unsigned long long)c->id, c->time, c->layer ? "resource" : "service",
                          bgb_good_name(c->good), c->volume, c->k, c->rationed ? "k" : "ask",
                          c->price, c->low, c->low_by.is_bid ? "excluded bid" : "matched ask",
                          owner(&c->low_by, lo, sizeof lo), c->high,
                          c->high_by.is_bid ? "matched bid" : "excluded ask",
                          owner(&c->high_by, hi, sizeof hi)) < 0;
    }
    if (failed || fflush(out) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot write clearings.csv");
    return BG_OK;
}

/* One agent's rows of agents.csv under one mechanism; nonzero on a write error. */
static int agent_rows(const bgb_ledger_t *l, const bgb_agent_info_t *a, int mech, FILE *out)
{
    int failed = 0;
    for (int g = 0; g < 3; g++)
        if (a->services & (1u << g))
            failed |= fprintf(out, "%s,0,%s,%u,basic,%s,%d,%.9g\n", l->name,
                              bgb_mechanism_name((bgb_mechanism)mech), a->id, bgb_good_name(g),
                              a->slots, a->floor[g]) < 0;
    if (a->resource)
        for (int g = BGB_GOOD_CORES; g <= BGB_GOOD_MEMORY; g++)
            failed |= fprintf(out, "%s,0,%s,%u,resource,%s,%.9g,%.9g\n", l->name,
                              bgb_mechanism_name((bgb_mechanism)mech), a->id, bgb_good_name(g),
                              g == BGB_GOOD_CORES ? a->cores : a->memory, a->floor[g]) < 0;
    return failed;
}

bg_status bgb_ledger_write_agents_csv(const bgb_ledger_t *l, const bgb_directory_t *d, FILE *out,
                                      bg_error_t *err)
{
    const bgb_dir_agent_t *rows = bgb_directory_rows_const(d);
    const size_t ndeparted = bgb_directory_departed_count(d);
    int failed = fputs("scenario,replication,mechanism,agent,role,good,capacity,limit\n", out) < 0;
    for (int mech = 0; mech < BGB_MECHANISMS; mech++) {
        /* The departed first (they registered earlier), then the directory. */
        for (size_t k = 0; k < ndeparted; k++)
            failed |= agent_rows(l, bgb_directory_departed(d, k), mech, out);
        for (int i = 0; i < BGB_DIRECTORY_MAX_AGENTS; i++)
            if (rows[i].used)
                failed |= agent_rows(l, &rows[i].info, mech, out);
    }
    if (failed || fflush(out) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot write agents.csv");
    return BG_OK;
}
