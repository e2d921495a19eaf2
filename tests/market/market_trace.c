/*
 * market_trace — one run of an experiment on SimGrid, traced: where its
 * messages go, how long they take, which timeouts fire.
 *
 *   market_trace CONFIG [--scenario S] [--mechanism NAME] [--replication R]
 *                       [--requests K] [--csv FILE]
 *
 * Rebuilds the run's generated platform (the same draw as `biotgrid sim`)
 * and runs the world with a trace of every delivered message, then prints:
 *   - the platform: links, hops and summed link latency of the routes
 *     between nodes and to the market host;
 *   - per message type: count, and one-way time (sent to received)
 *     median, p99 and max, with the route's hops;
 *   - per request: messages about it (by its number, owner's role),
 *     attempts, timeouts by kind;
 *   - the market agent's load: messages in and out per second (mean and
 *     the busiest second), the most messages in flight to it at once, and
 *     the same for the busiest other agent;
 *   - link utilization: bytes each link carried (every message's route),
 *     per second over the run and in its busiest second, against its
 *     bandwidth (SimGrid's link load plugin fails on the communications
 *     its engine cancels at the end of a run, so the tool counts them);
 *   - the first K requests' message sequences (default 2 service
 *     requests that failed and 1 that was bought, after the first 60 s).
 * --csv writes every message (sent, received, type, from, to, req,
 * attempt, hops). A diagnostic tool: the run is the same as the one
 * `biotgrid sim` makes, nothing is written to an experiment's outputs.
 */
#include <math.h>
#include <simgrid/engine.h>
#include <simgrid/host.h>
#include <simgrid/link.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <xbt/dynar.h>

#include "bg_error.h"
#include "bgm_config.h"
#include "bgm_platform.h"
#include "bgm_purchase.h"
#include "bgm_rng.h"
#include "bgm_simdriver.h"
#include "bgm_stats.h"
#include "bgm_world.h"

#define TYPES 26
#define MAX_RECORDS ((size_t)1 << 26)

static const char *const type_names[TYPES] = {
    "?",     "BID",      "ASK",     "FREE",   "MATCH", "RBID",    "RASK",  "RFREE",  "RAWARD",
    "RFAIL", "RCONFIRM", "CONFIRM", "CANCEL", "CFP",   "PROPOSE", "OFFER", "ACCEPT", "REJECT",
    "GENES", "QUERY",    "LIST",    "ORDER",  "AVAIL", "RPART",   "TAKE",  "REFUSE"};

typedef struct record {
    double sent, received;
    uint32_t from, to, req, attempt;
    uint16_t type, hops;
} record_t;

typedef struct trace {
    bgm_world_t *w;
    uint32_t nodes;
    sg_host_t *host; /* per node, the market's last */
    xbt_dynar_t route;
    sg_link_t *links; /* link i's data is i + 1 */
    size_t nlinks, seconds;
    double *link_bytes;  /* per link */
    double *link_second; /* per link and second of the run */
    record_t *rec;
    size_t n, cap;
    int failed;
} trace_t;

static int route_hops(trace_t *t, uint32_t a, uint32_t b, double *latency)
{
    xbt_dynar_reset(t->route);
    sg_host_get_route(t->host[a], t->host[b], t->route);
    if (latency)
        *latency = sg_host_get_route_latency(t->host[a], t->host[b]);
    return (int)xbt_dynar_length(t->route);
}

static void on_delivered(void *ctx, const bgm_msg_t *m, long bytes, double sent, double received)
{
    trace_t *t = ctx;
    if (t->failed)
        return;
    if (t->n == t->cap) {
        size_t c = t->cap ? 2 * t->cap : 65536;
        record_t *p = c <= MAX_RECORDS ? realloc(t->rec, c * sizeof *p) : NULL;
        if (!p) {
            t->failed = 1;
            return;
        }
        t->rec = p;
        t->cap = c;
    }
    uint32_t a = bgm_world_agent_node(t->w, m->from), b = bgm_world_agent_node(t->w, m->to);
    t->rec[t->n++] = (record_t){sent,   received,   m->from, m->to,
                                m->req, m->attempt, m->type, (uint16_t)route_hops(t, a, b, NULL)};
    size_t sec = (size_t)sent < t->seconds ? (size_t)sent : t->seconds - 1;
    for (unsigned i = 0; i < xbt_dynar_length(t->route); i++) {
        sg_link_t l = xbt_dynar_get_as(t->route, i, sg_link_t);
        size_t k = (size_t)(uintptr_t)sg_link_get_data(l) - 1;
        t->link_bytes[k] += (double)bytes;
        t->link_second[k * t->seconds + sec] += (double)bytes;
    }
}

/* Hops and summed latency of the routes between every pair of nodes and
 * from every node to the market. */
static void print_platform(trace_t *t)
{
    double hs = 0, ls = 0, hmax = 0, lmax = 0, n = 0, mh = 0, ml = 0, mhmax = 0;
    for (uint32_t a = 0; a < t->nodes; a++) {
        for (uint32_t b = a + 1; b < t->nodes; b++) {
            double lat;
            double h = route_hops(t, a, b, &lat);
            hs += h;
            ls += lat;
            hmax = fmax(hmax, h);
            lmax = fmax(lmax, lat);
            n += 1;
        }
        double lat;
        double h = route_hops(t, a, t->nodes, &lat);
        mh += h;
        ml += lat;
        mhmax = fmax(mhmax, h);
    }
    printf("platform: %zu links; node to node: %.2f links (max %.0f), summed latency %.4f s "
           "(max %.4f s); node to market: %.2f links (max %.0f), %.4f s\n",
           sg_link_count(), n > 0 ? hs / n : 0.0, hmax, n > 0 ? ls / n : 0.0, lmax, mh / t->nodes,
           mhmax, ml / t->nodes);
}

static void print_types(const trace_t *t)
{
    double *lat = malloc((t->n ? t->n : 1) * sizeof *lat);
    if (!lat)
        return;
    printf("\n| type | messages | per service request | one-way median (s) | p99 | max | "
           "mean route links |\n|---|---|---|---|---|---|---|\n");
    bgm_purchase_tally_t svc, res;
    bgm_world_tally(t->w, &svc, &res);
    for (int ty = 1; ty < TYPES; ty++) {
        size_t k = 0;
        double hops = 0;
        for (size_t i = 0; i < t->n; i++)
            if (t->rec[i].type == ty) {
                lat[k++] = t->rec[i].received - t->rec[i].sent;
                hops += t->rec[i].hops;
            }
        if (k == 0)
            continue;
        bgm_sort(lat, k);
        printf("| %s | %zu | %.2f | %.3f | %.3f | %.3f | %.2f |\n", type_names[ty], k,
               (double)k / fmax(svc.requests, 1), bgm_quantile_sorted(lat, k, 0.5),
               bgm_quantile_sorted(lat, k, 0.99), lat[k - 1], hops / (double)k);
    }
    free(lat);
}

/* Messages about each request, by the role of its owner: the first
 * message naming a request number is its owner's (BID, RBID, CFP or
 * QUERY as it opens). Returns the owner table (caller frees). */
static uint32_t *print_requests(const trace_t *t, uint32_t first_basic, uint32_t *nreq)
{
    uint32_t max = 0;
    for (size_t i = 0; i < t->n; i++)
        if (t->rec[i].type != BGM_MT_GENES && t->rec[i].req > max)
            max = t->rec[i].req;
    *nreq = max + 1;
    uint32_t *owner = malloc((size_t)(max + 1) * sizeof *owner);
    uint32_t *count = calloc((size_t)max + 1, sizeof *count);
    if (!owner || !count) {
        free(owner);
        free(count);
        return NULL;
    }
    for (uint32_t r = 0; r <= max; r++)
        owner[r] = UINT32_MAX;
    static const int about_request[TYPES] = {
        [BGM_MT_BID] = 1,    [BGM_MT_MATCH] = 1,    [BGM_MT_RBID] = 1,    [BGM_MT_RAWARD] = 1,
        [BGM_MT_RFAIL] = 1,  [BGM_MT_RCONFIRM] = 1, [BGM_MT_CONFIRM] = 1, [BGM_MT_CANCEL] = 1,
        [BGM_MT_CFP] = 1,    [BGM_MT_PROPOSE] = 1,  [BGM_MT_OFFER] = 1,   [BGM_MT_ACCEPT] = 1,
        [BGM_MT_REJECT] = 1, [BGM_MT_QUERY] = 1,    [BGM_MT_LIST] = 1,    [BGM_MT_ORDER] = 1,
        [BGM_MT_RPART] = 1,  [BGM_MT_TAKE] = 1,     [BGM_MT_REFUSE] = 1};
    for (size_t i = 0; i < t->n; i++) {
        const record_t *r = &t->rec[i];
        if (!about_request[r->type])
            continue;
        if (owner[r->req] == UINT32_MAX)
            owner[r->req] = r->from;
        count[r->req]++;
    }
    for (int layer = 0; layer < 2; layer++) {
        size_t k = 0;
        double sum = 0;
        double *v = malloc(((size_t)max + 1) * sizeof *v);
        if (!v)
            break;
        for (uint32_t r = 0; r <= max; r++)
            if (owner[r] != UINT32_MAX && (owner[r] >= first_basic) == layer) {
                v[k++] = count[r];
                sum += count[r];
            }
        bgm_sort(v, k);
        if (k > 0)
            printf("%s requests: %zu, messages about one: mean %.1f, median %.0f, p99 %.0f, max "
                   "%.0f\n",
                   layer ? "bundle (basic seller)" : "service (job's agent)", k, sum / (double)k,
                   bgm_quantile_sorted(v, k, 0.5), bgm_quantile_sorted(v, k, 0.99), v[k - 1]);
        free(v);
    }
    free(count);
    return owner;
}

static void print_tally(const char *what, const bgm_purchase_tally_t *t)
{
    static const char *const kinds[BGM_PU_TO_KINDS] = {"discovery", "reply", "directory",
                                                       "deadline"};
    printf("%s: %.0f requests, %.2f attempts each, %.2f timeouts each (", what, t->requests,
           t->attempts / fmax(t->requests, 1), t->timeouts / fmax(t->requests, 1));
    for (int k = 0; k < BGM_PU_TO_KINDS; k++)
        printf("%s%s %.0f", k ? ", " : "", kinds[k], t->timeout[k]);
    printf(")\n");
}

/* Messages to or from one agent: per second (mean, busiest second) and
 * the most in flight to it at once. */
typedef struct load {
    double in, out, busiest_in, flight;
} load_t;

static int cmp_event(const void *a, const void *b)
{
    const double x = fabs(*(const double *)a), y = fabs(*(const double *)b);
    if (x != y)
        return (x > y) - (x < y);
    /* An arrival (negative) before a send at the same instant. */
    return (*(const double *)a > *(const double *)b) - (*(const double *)a < *(const double *)b);
}

static load_t agent_load(const trace_t *t, uint32_t agent, double horizon)
{
    load_t l = {0, 0, 0, 0};
    size_t nb = (size_t)ceil(horizon) + 1, ne = 0;
    double *bucket = calloc(nb, sizeof *bucket);
    double *ev = malloc(2 * (t->n ? t->n : 1) * sizeof *ev);
    if (!bucket || !ev)
        goto out;
    for (size_t i = 0; i < t->n; i++) {
        const record_t *r = &t->rec[i];
        if (r->from == agent)
            l.out += 1;
        if (r->to != agent)
            continue;
        l.in += 1;
        size_t b = (size_t)r->received;
        if (b < nb)
            bucket[b] += 1;
        /* sends as +time, arrivals as -time (time > 0 after the start) */
        ev[ne++] = r->sent + 1e-12;
        ev[ne++] = -(r->received + 1e-12);
    }
    qsort(ev, ne, sizeof *ev, cmp_event);
    double cur = 0;
    for (size_t i = 0; i < ne; i++) {
        cur += ev[i] > 0 ? 1 : -1;
        l.flight = fmax(l.flight, cur);
    }
    for (size_t b = 0; b < nb; b++)
        l.busiest_in = fmax(l.busiest_in, bucket[b]);
    l.in /= horizon;
    l.out /= horizon;
out:
    free(bucket);
    free(ev);
    return l;
}

static void print_loads(const trace_t *t, double horizon)
{
    load_t m = agent_load(t, 0, horizon);
    printf("market agent: %.1f msg/s in, %.1f out, busiest second %.0f in, at most %.0f in flight "
           "to it\n",
           m.in, m.out, m.busiest_in, m.flight);
    /* The busiest other agent by messages received. */
    uint32_t na = bgm_world_agent_count(t->w);
    double *in = calloc(na, sizeof *in);
    if (!in)
        return;
    for (size_t i = 0; i < t->n; i++)
        in[t->rec[i].to] += 1;
    uint32_t best = 1;
    for (uint32_t a = 2; a < na; a++)
        if (in[a] > in[best])
            best = a;
    free(in);
    load_t b = agent_load(t, best, horizon);
    printf("busiest other agent (%u): %.1f msg/s in, busiest second %.0f in, at most %.0f in "
           "flight to it\n",
           best, b.in, b.busiest_in, b.flight);
}

typedef struct link_use {
    const char *name;
    double use, peak; /* mean and busiest second's bytes/s over bandwidth */
    double bytes;
} link_use_t;

static int cmp_use(const void *a, const void *b)
{
    const link_use_t *x = a, *y = b;
    return (x->use < y->use) - (x->use > y->use);
}

static void print_links(const trace_t *t, double horizon)
{
    link_use_t *u = malloc((t->nlinks ? t->nlinks : 1) * sizeof *u);
    if (!u)
        return;
    double sum = 0, peak = 0;
    for (size_t i = 0; i < t->nlinks; i++) {
        const double bw = sg_link_get_bandwidth(t->links[i]);
        u[i].name = sg_link_get_name(t->links[i]);
        u[i].bytes = t->link_bytes[i];
        u[i].use = t->link_bytes[i] / horizon / bw;
        u[i].peak = 0;
        for (size_t s = 0; s < t->seconds; s++)
            u[i].peak = fmax(u[i].peak, t->link_second[i * t->seconds + s] / bw);
        sum += u[i].use;
        peak = fmax(peak, u[i].peak);
    }
    qsort(u, t->nlinks, sizeof *u, cmp_use);
    printf("links: mean utilization %.2e of bandwidth, busiest second of any link %.2e; "
           "busiest links (mean):",
           t->nlinks ? sum / (double)t->nlinks : 0.0, peak);
    for (size_t i = 0; i < t->nlinks && i < 5; i++)
        printf(" %s %.2e (%.0f kB)", u[i].name, u[i].use, u[i].bytes / 1e3);
    printf("\n");
    free(u);
}

/* A request's messages in order: time sent, one-way time, type, from,
 * to, attempt, route links. */
static void print_sequence(const trace_t *t, uint32_t req, const char *what)
{
    printf("\nrequest %u (%s):\n", req, what);
    for (size_t i = 0; i < t->n; i++) {
        const record_t *r = &t->rec[i];
        if (r->req != req || r->type == BGM_MT_GENES || r->type == BGM_MT_ASK ||
            r->type == BGM_MT_AVAIL || r->type == BGM_MT_FREE || r->type == BGM_MT_RASK ||
            r->type == BGM_MT_RFREE)
            continue;
        printf("  %9.3f +%.3f %-8s %5u -> %-5u attempt %u, %u links\n", r->sent,
               r->received - r->sent, type_names[r->type], r->from, r->to, r->attempt, r->hops);
    }
}

static int cmp_record_sent(const void *a, const void *b)
{
    const record_t *x = a, *y = b;
    return (x->sent > y->sent) - (x->sent < y->sent);
}

static void print_samples(const trace_t *t, const uint32_t *owner, uint32_t nreq,
                          uint32_t first_basic, int k)
{
    /* A service request is bought when its buyer sends TAKE for it. */
    uint8_t *bought = calloc(nreq, 1);
    double *opened = malloc(nreq * sizeof *opened);
    if (!bought || !opened)
        goto out;
    for (uint32_t r = 0; r < nreq; r++)
        opened[r] = -1;
    for (size_t i = 0; i < t->n; i++) {
        const record_t *x = &t->rec[i];
        if (x->type == BGM_MT_TAKE && x->req < nreq)
            bought[x->req] = 1;
        if (x->req < nreq && opened[x->req] < 0 && x->type != BGM_MT_GENES)
            opened[x->req] = x->sent;
    }
    int failed = 0, ok = 0;
    for (uint32_t r = 0; r < nreq && (failed < k || ok < 1); r++) {
        if (owner[r] == UINT32_MAX || owner[r] >= first_basic || opened[r] < 60.0)
            continue;
        if (!bought[r] && failed < k) {
            print_sequence(t, r, "service, not bought");
            failed++;
        } else if (bought[r] && ok < 1) {
            print_sequence(t, r, "service, bought");
            ok++;
        }
    }
out:
    free(bought);
    free(opened);
}

static int usage(void)
{
    fprintf(stderr, "usage: market_trace CONFIG [--scenario S] [--mechanism NAME] "
                    "[--replication R] [--requests K] [--csv FILE]\n");
    return 2;
}

int main(int argc, char **argv)
{
    if (argc < 2)
        return usage();
    const char *path = argv[1], *csv = NULL, *mech_name = NULL;
    int scenario = 0, replication = 0, samples = 2;
    for (int i = 2; i < argc; i++) {
        if (i + 1 >= argc)
            return usage();
        if (!strcmp(argv[i], "--scenario"))
            scenario = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--mechanism"))
            mech_name = argv[++i];
        else if (!strcmp(argv[i], "--replication"))
            replication = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--requests"))
            samples = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--csv"))
            csv = argv[++i];
        else
            return usage();
    }
    bgm_config_t cfg;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_config_load(path, &cfg, &err)) {
        fprintf(stderr, "market_trace: %s\n", err.message);
        return 2;
    }
    if (cfg.network.platform[0]) {
        fprintf(stderr, "market_trace: traces generated platforms only\n");
        return 2;
    }
    int mech = cfg.mechanisms[0];
    for (int k = 0; mech_name && k < BGM_MAX_MECHANISMS; k++)
        if (!strcmp(mech_name, bgm_mechanism_names[k]))
            mech = k;
    if (scenario < 0 || scenario >= bgm_config_scenario_count(&cfg) || replication < 0 ||
        replication >= cfg.replications)
        return usage();
    int nodes;
    double density;
    const bgm_dynamics_t *dyn;
    bgm_config_scenario(&cfg, scenario, &nodes, &density, &dyn);
    double *speed = malloc(((size_t)nodes + 1) * sizeof *speed);
    char xml[] = "/tmp/market_trace_XXXXXX";
    int fd = mkstemp(xml);
    FILE *f = fd >= 0 ? fdopen(fd, "w") : NULL;
    if (!speed || !f) {
        fprintf(stderr, "market_trace: cannot write the platform\n");
        return 1;
    }
    /* The same draws as `biotgrid sim` (bgm_sim's run_child). */
    const int stream = bgm_config_scenario_stream(&cfg, scenario);
    const int topology = bgm_config_scenario_topology(&cfg, scenario);
    bgm_rng_t prng;
    bgm_rng_derive(&prng, cfg.seed, (uint64_t)stream, (uint64_t)replication, BGM_PLATFORM_STREAM);
    bg_status st = bgm_platform_write(f, &cfg, topology, nodes, &prng, speed);
    fclose(f);
    if (st) {
        fprintf(stderr, "market_trace: cannot write the platform\n");
        remove(xml);
        return 1;
    }
    bgm_simdriver_init();
    bgm_simdriver_load(xml);
    remove(xml);
    trace_t t = {0};
    t.nlinks = sg_link_count();
    t.links = sg_link_list();
    t.seconds = (size_t)ceil(cfg.duration + cfg.drain) + 1;
    t.link_bytes = calloc(t.nlinks ? t.nlinks : 1, sizeof *t.link_bytes);
    t.link_second = calloc((t.nlinks ? t.nlinks : 1) * t.seconds, sizeof *t.link_second);
    if (!t.links || !t.link_bytes || !t.link_second) {
        fprintf(stderr, "market_trace: out of memory\n");
        return 1;
    }
    for (size_t i = 0; i < t.nlinks; i++)
        sg_link_set_data(t.links[i], (void *)(uintptr_t)(i + 1));
    const char *named = cfg.topology_levels > 0 ? bgm_topology_names[topology] : NULL;
    bgm_world_params_t wp = {&cfg, stream, mech, replication, nodes, density, dyn, speed, named};
    t.w = bgm_world_new(&wp, &err);
    if (!t.w) {
        fprintf(stderr, "market_trace: %s\n", err.message);
        return 1;
    }
    t.nodes = (uint32_t)nodes;
    t.host = malloc(((size_t)nodes + 1) * sizeof *t.host);
    t.route = xbt_dynar_new(sizeof(sg_link_t), NULL);
    for (int i = 0; i <= nodes; i++) {
        char name[32];
        if (i == nodes)
            snprintf(name, sizeof name, "market");
        else
            snprintf(name, sizeof name, "h%d", i);
        t.host[i] = sg_host_by_name(name);
    }
    printf("market_trace: %s, scenario %d (%s, %d nodes, density %g, %s), %s, replication %d\n",
           cfg.name, scenario, bgm_topology_names[topology], nodes, density, dyn->name,
           bgm_mechanism_names[mech], replication);
    bgm_sim_trace_t hook = {&t, on_delivered};
    bgm_sim_stats_t ss;
    st = bgm_simdriver_run_traced(t.w, 0, &hook, &ss, &err);
    if (st || t.failed) {
        fprintf(stderr, "market_trace: %s\n", st ? err.message : "out of memory for the trace");
        return 1;
    }
    /* Routes are computed once the platform is sealed, which the run does. */
    print_platform(&t);
    double m[BGM_M_COUNT];
    bgm_world_metrics(t.w, m);
    printf("allocation rate %.3f, %.0f messages, %.1f per allocation, %.0f requests, %.0f "
           "contracts, access median %.2f s\n",
           m[BGM_M_ALLOCATION_RATE], m[BGM_M_MESSAGES], m[BGM_M_MESSAGES_PER_ALLOCATION],
           m[BGM_M_REQUESTS], m[BGM_M_CONTRACTS], m[BGM_M_ACCESS_TIME_MEDIAN]);
    bgm_purchase_tally_t svc, res;
    bgm_world_tally(t.w, &svc, &res);
    print_tally("service requests", &svc);
    print_tally("bundle requests", &res);
    print_types(&t);
    /* The world's agents: market, jobs' agents, basic sellers, resource
     * sellers; the basic sellers start after the jobs' agents. */
    const uint32_t first_basic = 1 + (uint32_t)lround(nodes * cfg.agents.complex_per_node);
    uint32_t nreq = 0;
    printf("\n");
    uint32_t *owner = print_requests(&t, first_basic, &nreq);
    print_loads(&t, bgm_world_horizon(t.w));
    print_links(&t, bgm_world_horizon(t.w));
    qsort(t.rec, t.n, sizeof *t.rec, cmp_record_sent);
    if (owner)
        print_samples(&t, owner, nreq, first_basic, samples);
    if (csv) {
        FILE *o = fopen(csv, "w");
        if (o) {
            fprintf(o, "sent,received,type,from,to,req,attempt,links\n");
            for (size_t i = 0; i < t.n; i++) {
                const record_t *r = &t.rec[i];
                fprintf(o, "%.6f,%.6f,%s,%u,%u,%u,%u,%u\n", r->sent, r->received,
                        type_names[r->type], r->from, r->to, r->req, r->attempt, r->hops);
            }
            fclose(o);
        }
    }
    free(owner);
    xbt_dynar_free(&t.route);
    free(t.host);
    free(t.rec);
    free(t.links);
    free(t.link_bytes);
    free(t.link_second);
    free(speed);
    bgm_world_destroy(&t.w);
    return 0;
}
