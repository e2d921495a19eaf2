/*
 * market_audit DIR — checks the invariants of a finished experiment from
 * its output files alone (the audit log is meant for exactly this):
 *   1. every contract's price lies in [seller_limit, buyer_limit];
 *   2. no seller is over capacity at any time (sweep over delivery
 *      intervals; a basic service counts instances against its slots);
 *   3. money is conserved per layer (sum paid by buyers = sum received by
 *      sellers) and flows job -> basic service -> resource: no basic agent
 *      pays more for resources than its services earned;
 *   4. every replication's allocation_rate equals its service contracts
 *      in contracts.csv over its requests;
 *   5. no replication's welfare beats the offline optimum: welfare_ratio
 *      <= 1 wherever it is not null, and at least one is not null;
 *   6. no service request is bought twice (one service row per request
 *      id and run), and every resource row names a request with a
 *      service row;
 *   7. each service's resources cover its delivery interval: every memory
 *      row and every cores row starts by the service's start, every
 *      memory row lasts to its end, and some cores row does too (cores of
 *      a faster seller finish their share of the work earlier).
 * Prints the first violation and exits 1; exits 0 when all hold.
 * market_audit --live DIR audits a live broker's log (GET
 * /v1/market/contracts.csv and agents.csv): checks 1-3, 6 and 7; a live
 * grid has no replications.csv, no request count and no offline optimum,
 * so 4 and 5 do not apply. Live, a job's services run one after another,
 * and its host's resource seller counts the job's cores as its widest
 * phase's, so check 2 counts cores that way there: at any time, over the
 * jobs holding cores of a seller, the sum of each job's most cores held
 * for one service (the service row of the resource row's request names
 * the job, its buyer, and the service, its good).
 *
 * A live log has two more columns after the simulator's: `use`, what a
 * row's service holds while it runs (a cores row's `quantity` is what it
 * pays: what its phase adds to the job's widest phase on that host), and
 * `clearing`. Capacity counts `use` (without the column, `quantity`).
 * market_audit --live --paid-ratio TOL DIR also checks that jobs pay for
 * what they can hold: over the resource rows, the unit-seconds paid
 * (quantity × duration) against those a job can hold at once (per job and
 * seller: cores, its widest service's `use` at each moment; memory, the
 * sum), per good and in all, each within 1 ± TOL. The ratio is printed
 * with every live audit.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Keys and messages are built with snprintf into fixed buffers; names are
 * length-checked on input, so truncation can only shorten a diagnostic. */
#pragma GCC diagnostic ignored "-Wformat-truncation"

#define LINE_MAX_LEN 1024
#define FIELDS_MAX 64
#define KEY_MAX 512
#define REL_TOL 1e-7

#define NAME_MAX_LEN 64

typedef struct contract {
    char key[KEY_MAX / 2]; /* scenario|rep|mechanism */
    char skey[KEY_MAX]; /* key|seller|good */
    /* The job and service a row serves: a service row's buyer and good;
     * a resource row's are its service row's (link_services). */
    char job[NAME_MAX_LEN], service[NAME_MAX_LEN];
    int layer, memory, lost;
    double start, end, quantity, price, blim, slim, use;
    long buyer, seller, request;
} contract_t;

typedef struct cap {
    char skey[KEY_MAX];
    double capacity;
} cap_t;

static int split(char *line, char **f)
{
    int n = 0;
    line[strcspn(line, "\r\n")] = '\0';
    for (char *p = line; n < FIELDS_MAX;) {
        f[n++] = p;
        char *c = strchr(p, ',');
        if (!c)
            break;
        *c = '\0';
        p = c + 1;
    }
    return n;
}

static int cmp_contract(const void *a, const void *b)
{
    return strcmp(((const contract_t *)a)->skey, ((const contract_t *)b)->skey);
}

static int cmp_cap(const void *a, const void *b)
{
    return strcmp(((const cap_t *)a)->skey, ((const cap_t *)b)->skey);
}

typedef struct ev {
    double t, d;
    const contract_t *row;
} ev_t;

static int cmp_ev(const void *a, const void *b)
{
    const ev_t *x = a, *y = b;
    if (x->t != y->t)
        return x->t < y->t ? -1 : 1;
    return (x->d > y->d) - (x->d < y->d); /* releases before new starts */
}

/* Moves the request column (f[4]) to the end, so the other fields keep
 * the positions of the documented order without it. */
static void request_last(char **f)
{
    char *request = f[4];
    for (int i = 4; i < 14; i++)
        f[i] = f[i + 1];
    f[14] = request;
}

static int cmp_request(const void *a, const void *b)
{
    const contract_t *x = *(const contract_t *const *)a, *y = *(const contract_t *const *)b;
    int k = strcmp(x->key, y->key);
    if (k)
        return k;
    if (x->request != y->request)
        return x->request < y->request ? -1 : 1;
    return x->layer - y->layer; /* the service row first */
}

/* 6 and 7 over contracts grouped by (run, request), service row first. */
static int check_requests(const contract_t *c, size_t n, char *msg, size_t cap)
{
    const contract_t **by = malloc((n ? n : 1) * sizeof *by);
    int bad = 0;
    if (!by) {
        snprintf(msg, cap, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++)
        by[i] = &c[i];
    qsort(by, n, sizeof *by, cmp_request);
    const double tol = 1e-5;
    for (size_t i = 0; i < n && !bad;) {
        size_t j = i;
        while (j < n && by[j]->request == by[i]->request && strcmp(by[j]->key, by[i]->key) == 0)
            j++;
        const contract_t *s = by[i];
        if (s->layer != 0) {
            snprintf(msg, cap, "resource row for request %ld without a service contract (%s)",
                     s->request, s->key);
            bad = 1;
        } else if (j > i + 1 && by[i + 1]->layer == 0) {
            snprintf(msg, cap, "request %ld bought twice: at t=%g and t=%g (%s)", s->request,
                     s->start, by[i + 1]->start, s->key);
            bad = 1;
        } else {
            double cores_end = -INFINITY;
            for (size_t k = i + 1; k < j && !bad; k++) {
                const contract_t *r = by[k];
                if (r->start > s->start + tol || (r->memory && r->end < s->end - tol)) {
                    snprintf(msg, cap,
                             "request %ld: %s row [%g, %g] does not cover the service [%g, %g] "
                             "(%s)",
                             s->request, r->memory ? "memory" : "cores", r->start, r->end,
                             s->start, s->end, s->key);
                    bad = 1;
                }
                if (!r->memory && r->end > cores_end)
                    cores_end = r->end;
            }
            if (!bad && cores_end < s->end - tol) {
                snprintf(msg, cap, "request %ld: no cores until the service's end %g (%s)",
                         s->request, s->end, s->key);
                bad = 1;
            }
        }
        i = j;
    }
    free(by);
    return bad;
}

/* Gives every resource row the job and service of its request's service
 * row (check_requests has checked there is one). */
static void link_services(contract_t *c, size_t n)
{
    contract_t **by = malloc((n ? n : 1) * sizeof *by);
    if (!by)
        return;
    for (size_t i = 0; i < n; i++)
        by[i] = &c[i];
    qsort(by, n, sizeof *by, cmp_request);
    for (size_t i = 0; i < n; i++)
        if (by[i]->layer == 1 && i > 0 && by[i - 1]->request == by[i]->request &&
            strcmp(by[i - 1]->key, by[i]->key) == 0) {
            snprintf(by[i]->job, sizeof by[i]->job, "%s", by[i - 1]->job);
            snprintf(by[i]->service, sizeof by[i]->service, "%s", by[i - 1]->service);
        }
    free(by);
}

/* One job's cores at a seller, per service (phase). */
typedef struct job_load {
    const char *job;
    const char *service[8];
    double held[8];
    int nservices;
} job_load_t;

/* The load of a live resource seller's cores after `ev` (sorted): each
 * job counts the most it holds for one service. Returns the first time it
 * exceeds `capacity` through *when, or 0 when it never does. */
static int over_by_phase(const ev_t *ev, size_t k, double capacity, double *when, double *load_out)
{
    job_load_t *jobs = calloc(k ? k : 1, sizeof *jobs);
    size_t njobs = 0;
    int over = 0;
    for (size_t e = 0; e < k && jobs && !over; e++) {
        const contract_t *r = ev[e].row;
        job_load_t *j = NULL;
        for (size_t i = 0; i < njobs && !j; i++)
            if (strcmp(jobs[i].job, r->job) == 0)
                j = &jobs[i];
        if (!j) {
            j = &jobs[njobs++];
            j->job = r->job;
        }
        int p = 0;
        while (p < j->nservices && strcmp(j->service[p], r->service) != 0)
            p++;
        if (p == j->nservices) {
            if (p == 8)
                p = 7; /* more services than the grid has: lumped, never undercounted */
            else
                j->service[j->nservices++] = r->service;
        }
        j->held[p] += ev[e].d;
        double load = 0.0;
        for (size_t i = 0; i < njobs; i++) {
            double most = 0.0;
            for (int q = 0; q < jobs[i].nservices; q++)
                if (jobs[i].held[q] > most)
                    most = jobs[i].held[q];
            load += most;
        }
        if (load > capacity + 1e-6) {
            over = 1;
            *when = ev[e].t;
            *load_out = load;
        }
    }
    free(jobs);
    return over;
}

static int fail(const char *what)
{
    fprintf(stderr, "market_audit: %s\n", what);
    return 1;
}

static int cmp_holding(const void *a, const void *b)
{
    const contract_t *x = *(const contract_t *const *)a, *y = *(const contract_t *const *)b;
    int k = strcmp(x->skey, y->skey);
    return k ? k : strcmp(x->job, y->job);
}

/* Unit-seconds one job can hold of one seller's cores (rows of one
 * (run, seller, good, job), n of them): at each moment the most any of its
 * services holds (`use`), integrated over time. */
static double widest_held(const contract_t *const *rows, size_t n)
{
    ev_t *ev = malloc((2 * n + 1) * sizeof *ev);
    if (!ev)
        return NAN;
    for (size_t i = 0; i < n; i++) {
        ev[2 * i] = (ev_t){rows[i]->start, rows[i]->use, rows[i]};
        ev[2 * i + 1] = (ev_t){rows[i]->end, -rows[i]->use, rows[i]};
    }
    qsort(ev, 2 * n, sizeof *ev, cmp_ev);
    const char *service[8];
    double held[8] = {0}, total = 0, t = ev[0].t;
    int nservices = 0;
    for (size_t e = 0; e < 2 * n; e++) {
        double most = 0;
        for (int q = 0; q < nservices; q++)
            most = held[q] > most ? held[q] : most;
        total += most * (ev[e].t - t);
        t = ev[e].t;
        int p = 0;
        while (p < nservices && strcmp(service[p], ev[e].row->service) != 0)
            p++;
        if (p == nservices) {
            if (p == 8)
                p = 7; /* more services than the grid has: lumped, never undercounted */
            else
                service[nservices++] = ev[e].row->service;
        }
        held[p] += ev[e].d;
    }
    free(ev);
    return total;
}

/*
 * Resource unit-seconds paid against those the jobs can hold at once,
 * per good (0 cores, 1 memory): paid[g] and holdable[g]. Rows are
 * grouped by run, seller, good and job (after link_services).
 */
static int paid_and_holdable(const contract_t *c, size_t n, double paid[2], double holdable[2])
{
    const contract_t **by = malloc((n ? n : 1) * sizeof *by);
    if (!by)
        return -1;
    size_t m = 0;
    paid[0] = paid[1] = holdable[0] = holdable[1] = 0;
    for (size_t i = 0; i < n; i++)
        if (c[i].layer == 1) {
            by[m++] = &c[i];
            paid[c[i].memory] += c[i].quantity * (c[i].end - c[i].start);
        }
    qsort(by, m, sizeof *by, cmp_holding);
    for (size_t i = 0; i < m;) {
        size_t j = i;
        while (j < m && cmp_holding(&by[i], &by[j]) == 0)
            j++;
        if (by[i]->memory)
            for (size_t k = i; k < j; k++)
                holdable[1] += by[k]->use * (by[k]->end - by[k]->start);
        else
            holdable[0] += widest_held(by + i, j - i);
        i = j;
    }
    free(by);
    return 0;
}

int main(int argc, char **argv)
{
    const int live = (argc == 3 || argc == 5) && strcmp(argv[1], "--live") == 0;
    double tolerance = -1; /* --paid-ratio: none */
    if (live && argc == 5) {
        char *end = NULL;
        tolerance = strcmp(argv[2], "--paid-ratio") == 0 ? strtod(argv[3], &end) : -1;
        if (!end || *end || !(tolerance >= 0))
            return fail("usage: market_audit [--live [--paid-ratio TOL]] DIR");
    }
    if (argc != 2 && !live)
        return fail("usage: market_audit [--live [--paid-ratio TOL]] DIR");
    const char *dir = argv[argc - 1];
    char path[4096], line[LINE_MAX_LEN], *f[FIELDS_MAX], msg[512];
    size_t n = 0, alloc = 1024, ncap = 0, capalloc = 1024;
    contract_t *c = malloc(alloc * sizeof *c);
    cap_t *caps = malloc(capalloc * sizeof *caps);
    int rc = 0;

    snprintf(path, sizeof path, "%s/contracts.csv", dir);
    FILE *fp = fopen(path, "r");
    if (!fp || !fgets(line, sizeof line, fp))
        return fail("cannot read contracts.csv");
    const char *header = "scenario,replication,mechanism,layer,request,time,start,end,buyer,seller,"
                         "good,quantity,price,buyer_limit,seller_limit";
    const size_t hlen = strlen(header);
    /* A live log adds its own columns after the simulator's: use and
     * clearing, and lost since the broker settles a lost seller's rows. */
    const int lost_column = strcmp(line + hlen, ",use,clearing,lost\n") == 0;
    const int extra = lost_column || strcmp(line + hlen, ",use,clearing\n") == 0;
    if (strncmp(line, header, hlen) != 0 || (!extra && strcmp(line + hlen, "\n") != 0))
        return fail("contracts.csv header differs from the documented one");
    const int nfields = lost_column ? 18 : extra ? 17 : 15;
    while (fgets(line, sizeof line, fp)) {
        if (split(line, f) != nfields) {
            snprintf(msg, sizeof msg, "contracts.csv: row without %d fields", nfields);
            return fail(msg);
        }
        const double use = extra ? atof(f[15]) : atof(f[11]);
        const int lost = lost_column && strcmp(f[17], "1") == 0;
        if (lost_column && !lost && strcmp(f[17], "0") != 0)
            return fail("contracts.csv: lost is neither 0 nor 1");
        request_last(f);
        if (n == alloc)
            c = realloc(c, (alloc *= 2) * sizeof *c);
        contract_t *x = &c[n++];
        if (strlen(f[0]) + strlen(f[2]) > KEY_MAX / 4)
            return fail("contracts.csv: scenario or mechanism name too long");
        snprintf(x->key, KEY_MAX / 2, "%s|%s|%s", f[0], f[1], f[2]);
        /* A basic agent's slots serve all its service types together. */
        snprintf(x->skey, KEY_MAX, "%s|%s|%s|%s", x->key, f[8],
                 strcmp(f[3], "service") == 0 ? "*" : f[9], f[3]);
        x->layer = strcmp(f[3], "service") == 0 ? 0 : 1;
        x->lost = lost;
        x->job[0] = x->service[0] = '\0';
        if (x->layer == 0) {
            snprintf(x->job, sizeof x->job, "%s", f[7]);
            snprintf(x->service, sizeof x->service, "%s", f[9]);
        }
        x->memory = strcmp(f[9], "memory") == 0;
        x->request = atol(f[14]);
        x->start = atof(f[5]);
        x->end = atof(f[6]);
        x->buyer = atol(f[7]);
        x->seller = atol(f[8]);
        x->quantity = atof(f[10]);
        x->price = atof(f[11]);
        x->blim = atof(f[12]);
        x->slim = atof(f[13]);
        x->use = use;
        if (x->price < x->slim * (1 - REL_TOL) || x->price > x->blim * (1 + REL_TOL)) {
            snprintf(msg, sizeof msg, "price %g outside [%g, %g] (%s)", x->price, x->slim,
                     x->blim, x->skey);
            return fail(msg);
        }
    }
    fclose(fp);

    snprintf(path, sizeof path, "%s/agents.csv", dir);
    fp = fopen(path, "r");
    if (!fp || !fgets(line, sizeof line, fp))
        return fail("cannot read agents.csv");
    if (strcmp(line, "scenario,replication,mechanism,agent,role,good,capacity,limit\n") != 0)
        return fail("agents.csv header differs from the documented one");
    while (fgets(line, sizeof line, fp)) {
        if (split(line, f) != 8)
            return fail("agents.csv: row without 8 fields");
        if (strcmp(f[4], "complex") == 0)
            continue;
        if (ncap == capalloc)
            caps = realloc(caps, (capalloc *= 2) * sizeof *caps);
        int basic = strcmp(f[4], "basic") == 0;
        snprintf(caps[ncap].skey, KEY_MAX, "%s|%s|%s|%s|%s|%s", f[0], f[1], f[2], f[3],
                 basic ? "*" : f[5], basic ? "service" : "resource");
        caps[ncap++].capacity = atof(f[6]);
    }
    fclose(fp);

    if (check_requests(c, n, msg, sizeof msg))
        return fail(msg);
    link_services(c, n);

    /* 2. capacity sweep per (run, seller, good). */
    qsort(c, n, sizeof *c, cmp_contract);
    qsort(caps, ncap, sizeof *caps, cmp_cap);
    ev_t *ev = malloc((2 * n + 1) * sizeof *ev);
    for (size_t i = 0; i < n;) {
        size_t j = i, k = 0;
        while (j < n && strcmp(c[j].skey, c[i].skey) == 0) {
            /* Live cores count what a service holds (by phase, below). */
            double q = c[j].layer == 0 ? 1.0 : live && !c[j].memory ? c[j].use : c[j].quantity;
            ev[k++] = (ev_t){c[j].start, q, &c[j]};
            ev[k++] = (ev_t){c[j].end, -q, &c[j]};
            j++;
        }
        cap_t probe;
        snprintf(probe.skey, KEY_MAX, "%s", c[i].skey);
        cap_t *cp = bsearch(&probe, caps, ncap, sizeof *caps, cmp_cap);
        if (!cp) {
            snprintf(msg, sizeof msg, "seller without an agents.csv row: %s", c[i].skey);
            return fail(msg);
        }
        qsort(ev, k, sizeof *ev, cmp_ev);
        double load = 0.0, when = 0.0;
        if (live && c[i].layer == 1 && !c[i].memory) {
            if (over_by_phase(ev, k, cp->capacity, &when, &load)) {
                snprintf(msg, sizeof msg,
                         "seller over capacity (%g > %g cores, each job counted at its widest "
                         "service) at t=%g: %s",
                         load, cp->capacity, when, c[i].skey);
                return fail(msg);
            }
            i = j;
            continue;
        }
        for (size_t e = 0; e < k; e++) {
            load += ev[e].d;
            if (load > cp->capacity + 1e-6) {
                snprintf(msg, sizeof msg, "seller over capacity (%g > %g) at t=%g: %s", load,
                         cp->capacity, ev[e].t, c[i].skey);
                return fail(msg);
            }
        }
        i = j;
    }

    /* 3. money per run and layer, and no basic agent pays more for
     * resources than it earned. Contracts are grouped by seller now, so
     * tally per run with small linear maps. */
    double paid[2] = {0, 0}, received[2] = {0, 0};
    for (size_t i = 0; i < n; i++) {
        double money = c[i].layer == 0 ? c[i].price * c[i].quantity
                                       : c[i].price * c[i].quantity * (c[i].end - c[i].start);
        paid[c[i].layer] += money;
        received[c[i].layer] += money;
    }
    for (int l = 0; l < 2; l++)
        if (fabs(paid[l] - received[l]) > 1e-6 * (1 + paid[l]))
            return fail("money not conserved");
    for (size_t i = 0; i < n; i++) {
        if (c[i].layer != 0)
            continue;
        /* Basic agent c[i].seller in run c[i].key: earnings vs spending,
         * over the requests it served. A request whose seller was lost
         * (the live log's lost rows) is left out of both: the seller was
         * paid for the work delivered and bears its resources' cost. */
        if (i > 0 && c[i - 1].layer == 0 && c[i - 1].seller == c[i].seller &&
            strcmp(c[i - 1].key, c[i].key) == 0)
            continue;
        double earned = 0, spent = 0;
        for (size_t j = 0; j < n; j++) {
            if (strcmp(c[j].key, c[i].key) != 0 || c[j].lost)
                continue;
            if (c[j].layer == 0 && c[j].seller == c[i].seller)
                earned += c[j].price * c[j].quantity;
            if (c[j].layer == 1 && c[j].buyer == c[i].seller)
                spent += c[j].price * c[j].quantity * (c[j].end - c[j].start);
        }
        if (spent > earned * (1 + 1e-6) + 1e-6) {
            snprintf(msg, sizeof msg, "basic agent %ld spent %g on resources, earned %g (%s)",
                     c[i].seller, spent, earned, c[i].key);
            return fail(msg);
        }
    }

    if (live) {
        double bought[2], holdable[2];
        if (paid_and_holdable(c, n, bought, holdable) != 0)
            return fail("out of memory");
        const double all = (bought[0] + bought[1]) / (holdable[0] + holdable[1]);
        const double ratio[3] = {bought[0] / holdable[0], bought[1] / holdable[1], all};
        printf("market_audit: resources paid/holdable %.4f (cores %.6g/%.6g, memory %.6g/%.6g "
               "unit-seconds)\n",
               all, bought[0], holdable[0], bought[1], holdable[1]);
        for (int g = 0; g < 3 && tolerance >= 0; g++)
            if (!(fabs(ratio[g] - 1.0) <= tolerance) && (g == 2 || holdable[g] > 0)) {
                snprintf(msg, sizeof msg,
                         "jobs pay for %.4f %s units per unit they can hold (1 ± %g allowed)",
                         ratio[g], g == 0 ? "cores" : g == 1 ? "memory" : "resource", tolerance);
                return fail(msg);
            }
        printf("market_audit: %zu live contracts, %zu capacities: invariants 1-3, 6, 7 hold\n", n,
               ncap);
        free(c);
        free(caps);
        free(ev);
        return rc;
    }
    /* 4. allocation rate = service contracts / requests. */
    snprintf(path, sizeof path, "%s/replications.csv", dir);
    fp = fopen(path, "r");
    if (!fp || !fgets(line, sizeof line, fp))
        return fail("cannot read replications.csv");
    int nf = split(line, f), col_rate = -1, col_req = -1, col_ratio = -1;
    for (int i = 0; i < nf; i++) {
        if (strcmp(f[i], "allocation_rate") == 0)
            col_rate = i;
        if (strcmp(f[i], "requests") == 0)
            col_req = i;
        if (strcmp(f[i], "welfare_ratio") == 0)
            col_ratio = i;
    }
    if (col_rate < 0 || col_req < 0 || col_ratio < 0)
        return fail("replications.csv lacks allocation_rate, requests or welfare_ratio");
    int rows = 0, ratios = 0;
    while (fgets(line, sizeof line, fp)) {
        if (split(line, f) != nf)
            return fail("replications.csv: row with a different field count");
        /* 5. welfare against the offline optimum (an empty cell is null). */
        if (f[col_ratio][0] != '\0') {
            double ratio = atof(f[col_ratio]);
            if (!(ratio <= 1.0 + 1e-9)) {
                snprintf(msg, sizeof msg, "%s|%s|%s: welfare_ratio %g above 1", f[0], f[6], f[5],
                         ratio);
                return fail(msg);
            }
            ratios++;
        }
        char key[KEY_MAX];
        snprintf(key, sizeof key, "%s|%s|%s", f[0], f[6], f[5]);
        double svc = 0;
        for (size_t i = 0; i < n; i++)
            svc += c[i].layer == 0 && strcmp(c[i].key, key) == 0;
        double req = atof(f[col_req]), rate = atof(f[col_rate]);
        if (req <= 0 || fabs(rate - svc / req) > 1e-8) {
            snprintf(msg, sizeof msg, "%s: allocation_rate %g but %g contracts / %g requests", key,
                     rate, svc, req);
            return fail(msg);
        }
        rows++;
    }
    fclose(fp);
    if (ratios == 0)
        return fail("welfare_ratio is null in every replication");
    printf("market_audit: %zu contracts, %zu capacities, %d replications (%d welfare ratios): "
           "all invariants hold\n",
           n, ncap, rows, ratios);
    free(c);
    free(caps);
    free(ev);
    return rc;
}
