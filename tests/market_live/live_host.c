/*
 * live_host — a small broker stand-in for the live-market tests and the
 * latency benchmark: binds a ROUTER on loopback (port chosen by the
 * kernel), runs bgb_market on it, and drives jobs through each mechanism.
 *
 *   live_host test  DIR NAGENTS   writes DIR/endpoint, waits for NAGENTS
 *       agents (each a basic-service seller) and their host's one
 *       resource seller, buys a static plan (rotation-fit ×2,
 *       sparse-solve ×1) under each mechanism and checks the awards and
 *       that each awarded seller bought its unit's cores and memory on
 *       layer 1 (rows naming it as buyer and a resource seller, priced
 *       within both limits, costing it no more than the service earns);
 *       a budget too small fails with "budget" and adds no contract; a
 *       compute call for a job an agent holds no contract for is refused
 *       naming the job. The host sells 2 cores and a job holds both (its
 *       rotation fits' 1 + 1 and its sparse solve's 2 share them, as its
 *       phases run one after another): a second job fails, its sellers,
 *       slots free, refusing for want of cores, and leaves no contract;
 *       once the first is released the cores come back. Writes
 *       DIR/contracts.csv and DIR/agents.csv (the script runs the
 *       simulator's audit on them); then writes DIR/phase2 and waits for
 *       the directory to lose the agent selling the host (the script kills
 *       it) and a standby daemon of the host to take its place, and buys
 *       from the survivors.
 * (The latency benchmark that lived here is bench_alloc.) Exits 0 when
 * every check holds, 1 with the first failure otherwise.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zmq.h>

#include "bg_clock.h"
#include "bga_transport.h"
#include "bga_wire.h"
#include "bgb_market.h"
#include "live_net.h"

#define FAIL(...)                                                                                  \
    do {                                                                                           \
        fprintf(stderr, "live_host: FAIL: " __VA_ARGS__);                                          \
        fputc('\n', stderr);                                                                       \
        exit(1);                                                                                   \
    } while (0)

typedef live_net_t host_t;

typedef struct outcome {
    int done;
    char reason[32];
    bgb_award_t awards[16];
    int nawards;
    double spent, latency;
} outcome_t;

static void on_done(void *ctx, const bgb_outcome_t *o)
{
    outcome_t *out = ctx;
    out->done = 1;
    snprintf(out->reason, sizeof out->reason, "%s", o->reason ? o->reason : "");
    out->nawards = o->nawards < 16 ? o->nawards : 16;
    memcpy(out->awards, o->awards, (size_t)out->nawards * sizeof *o->awards);
    out->spent = o->spent;
    out->latency = o->latency;
}

static const bgb_need_t plan[2] = {{BGB_GOOD_ROTFIT, 2000.0, 2}, {BGB_GOOD_SOLVE, 500.0, 1}};

static void buy(host_t *h, uint64_t job, bgb_mechanism mech, double budget, outcome_t *o)
{
    memset(o, 0, sizeof *o);
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_market_buy(h->market, job, mech, budget, plan, 2, bg_clock_now(), on_done, o, &err) !=
        BG_OK)
        FAIL("buy job %llu: %s", (unsigned long long)job, err.message);
    live_net_pump(h, 20.0, &o->done);
    if (!o->done)
        FAIL("job %llu under %s: no outcome in 20 s", (unsigned long long)job,
             bgb_mechanism_name(mech));
}

static size_t count_contracts_cb_n;
static void count_cb(void *ctx, const bgb_contract_t *r)
{
    (void)ctx;
    (void)r;
    count_contracts_cb_n++;
}
static size_t contracts(host_t *h)
{
    count_contracts_cb_n = 0;
    bgb_ledger_each(bgb_market_ledger(h->market), count_cb, NULL);
    return count_contracts_cb_n;
}

/* Directory entries of each role: [0] basic-service sellers, [1] resource sellers. */
static void count_roles(host_t *h, size_t out[2])
{
    bgb_agent_info_t info[64];
    const size_t n = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    out[0] = out[1] = 0;
    for (size_t i = 0; i < n && i < 64; i++)
        out[info[i].resource != 0]++;
}

/* The id of the first resource seller listed (0: none). */
static uint32_t resource_seller(host_t *h)
{
    bgb_agent_info_t info[64];
    const size_t n = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    for (size_t i = 0; i < n && i < 64; i++)
        if (info[i].resource)
            return info[i].id;
    return 0;
}

static const bgb_agent_info_t *find_agent(const bgb_agent_info_t *info, size_t n, uint32_t id)
{
    for (size_t k = 0; k < n; k++)
        if (info[k].id == id)
            return &info[k];
    return NULL;
}

/* The awards of a successful static plan: 2 distinct rotation-fit agents
 * with half the work each, 1 sparse-solve agent, every price within the
 * agents' floors and the total within the budget. */
static void check_awards(host_t *h, const outcome_t *o, double budget, const char *mech)
{
    if (o->reason[0])
        FAIL("%s: job failed: %s", mech, o->reason);
    if (o->nawards != 3)
        FAIL("%s: %d awards (expected 3)", mech, o->nawards);
    int rot = 0, solve = 0;
    double spent = 0;
    bgb_agent_info_t info[64];
    const size_t na = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    for (int i = 0; i < o->nawards; i++) {
        const bgb_award_t *a = &o->awards[i];
        rot += a->good == BGB_GOOD_ROTFIT;
        solve += a->good == BGB_GOOD_SOLVE;
        if (a->good == BGB_GOOD_INTEG)
            FAIL("%s: a static plan bought integration-step", mech);
        const double want = a->good == BGB_GOOD_ROTFIT ? 1000.0 : 500.0;
        if (fabs(a->quantity - want) > 1e-9)
            FAIL("%s: award %d quantity %g (expected %g)", mech, i, a->quantity, want);
        if (strncmp(a->endpoint, "tcp://127.0.0.1:", 16) != 0)
            FAIL("%s: award %d endpoint '%s'", mech, i, a->endpoint);
        int found = 0;
        for (size_t k = 0; k < na; k++)
            if (info[k].id == a->agent) {
                found = 1;
                if (!(info[k].services & (1u << a->good)))
                    FAIL("%s: agent %u does not sell %s", mech, a->agent, bgb_good_name(a->good));
                if (a->price < info[k].floor[a->good] * (1 - 1e-12))
                    FAIL("%s: price %g under agent %u's floor %g", mech, a->price, a->agent,
                         info[k].floor[a->good]);
            }
        if (!found)
            FAIL("%s: award names agent %u, not in the directory", mech, a->agent);
        spent += a->quantity * a->price;
    }
    if (rot != 2 || solve != 1)
        FAIL("%s: %d rotation-fit and %d sparse-solve awards", mech, rot, solve);
    if (o->awards[0].agent == o->awards[1].agent)
        FAIL("%s: both rotation-fit halves went to agent %u", mech, o->awards[0].agent);
    if (fabs(spent - o->spent) > 1e-9 * (1 + spent) || spent > budget * (1 + 1e-12))
        FAIL("%s: spent %g (outcome says %g), budget %g", mech, spent, o->spent, budget);
}

/* A compute call (rotfit-call header) for a job the agent holds no
 * contract for must come back as a NO_JOB error naming the job. */
static void check_refusal(void *ctx, const char *endpoint, uint64_t job)
{
    void *s = zmq_socket(ctx, ZMQ_DEALER);
    const int linger = 0, tmo = 5000;
    zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger);
    zmq_setsockopt(s, ZMQ_RCVTIMEO, &tmo, sizeof tmo);
    if (zmq_connect(s, endpoint) != 0)
        FAIL("connect %s", endpoint);
    bga_msg_t msg;
    bga_msg_init(&msg, BGA_ROTFIT_CALL, job, 1);
    msg.field[BGA_RC_WANT].i = BGA_WANT_GRADIENT;
    const double pos[3] = {0, 0, 0};
    msg.array[BGA_RC_POSITIONS] = (bga_array_t){pos, 3};
    bga_frames_t f;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_wire_encode(&msg, &f, &err) != BG_OK || bga_send(s, NULL, &f, &err) != BG_OK)
        FAIL("refusal probe: %s", err.message);
    bga_frames_free(&f);
    bga_received_t r;
    if (bga_recv(s, 0, &r, &err) != BG_OK)
        FAIL("refusal probe: no reply from %s: %s", endpoint, err.message);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES + 1];
    bga_received_view(&r, v);
    bga_msg_t rep;
    bga_wire_error_t werr;
    if (bga_wire_decode(v, r.count, NULL, &rep, &werr) != BGA_WIRE_OK ||
        rep.header.type != BGA_ERROR || rep.field[BGA_ERR_CODE].i != BGA_WIRE_NO_JOB)
        FAIL("refusal probe: the agent did not refuse job %llu with NO_JOB",
             (unsigned long long)job);
    char text[256] = {0}, want[64];
    const size_t n =
        rep.array[BGA_ERR_MESSAGE].count < 255 ? rep.array[BGA_ERR_MESSAGE].count : 255;
    memcpy(text, rep.array[BGA_ERR_MESSAGE].data, n);
    snprintf(want, sizeof want, "job %llu", (unsigned long long)job);
    if (!strstr(text, want))
        FAIL("refusal message '%s' does not name %s", text, want);
    bga_received_close(&r);
    zmq_close(s);
}

/* ------------------------------------------------------------ layer 1 */

typedef struct rows {
    bgb_contract_t r[1024];
    int n;
} rows_t;

static void collect(void *ctx, const bgb_contract_t *r)
{
    rows_t *rows = ctx;
    if (rows->n < 1024)
        rows->r[rows->n++] = *r;
}

/* What the script's agents need per contract: one core for rotation-fit,
 * two for sparse-solve; 1 GiB for rotation-fit, 4 for sparse-solve. */
static const double unit_cores[3] = {1.0, 2.0, 1.0}, unit_memory[3] = {1.0, 4.0, 2.0};

/* Every awarded seller of job `job` bought its unit's resources: the
 * service row's request has a cores row and a memory row, bought by that
 * seller from a resource seller, each price within both limits, the
 * resources held (`use`) from before the service started, and costing the
 * seller over their lease no more than the service earns. The job pays
 * for its cores once, at its widest phase: the cores rows' quantities add
 * up to 2 (rotation fit 1 + 1, sparse solve 2, one after another). */
static void check_layer1(host_t *h, uint64_t job, const outcome_t *o, const char *mech)
{
    static rows_t rows;
    rows.n = 0;
    bgb_ledger_each(bgb_market_ledger(h->market), collect, &rows);
    bgb_agent_info_t info[64];
    const size_t na = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    for (int i = 0; i < o->nawards; i++) {
        const bgb_award_t *a = &o->awards[i];
        const bgb_contract_t *svc = NULL;
        for (int k = 0; k < rows.n; k++)
            if (rows.r[k].job == job && rows.r[k].layer == 0 && rows.r[k].seller == a->agent &&
                rows.r[k].good == a->good) {
                if (svc)
                    FAIL("%s: two service rows for agent %u", mech, a->agent);
                svc = &rows.r[k];
            }
        if (!svc)
            FAIL("%s: no service row for award %d (agent %u)", mech, i, a->agent);
        double cores = 0, memory = 0, spent = 0, paid = 0;
        for (int k = 0; k < rows.n; k++) {
            const bgb_contract_t *r = &rows.r[k];
            if (r->layer != 1 || r->request != svc->request)
                continue;
            if (r->job != job || r->buyer != a->agent)
                FAIL("%s: resource row of request %llu bought by %llu, not the seller %u", mech,
                     (unsigned long long)r->request, (unsigned long long)r->buyer, a->agent);
            const bgb_agent_info_t *seller = find_agent(info, na, r->seller);
            if (!seller || !seller->resource)
                FAIL("%s: resource row sold by %u, not a resource seller", mech, r->seller);
            if (r->price < r->seller_limit * (1 - 1e-12) || r->price > r->buyer_limit * (1 + 1e-12))
                FAIL("%s: resource price %g outside [%g, %g]", mech, r->price, r->seller_limit,
                     r->buyer_limit);
            if (r->start > svc->start || !(r->end > r->start))
                FAIL("%s: resource row [%g, %g] does not start by the service's %g", mech, r->start,
                     r->end, svc->start);
            if (r->good == BGB_GOOD_CORES) {
                cores += r->use;
                paid += r->quantity;
            } else if (r->good == BGB_GOOD_MEMORY) {
                memory += r->use;
                if (r->quantity != r->use)
                    FAIL("%s: a memory row pays for %g GiB and holds %g", mech, r->quantity,
                         r->use);
            }
            else
                FAIL("%s: a resource row sells %s", mech, bgb_good_name(r->good));
            spent += r->price * r->quantity * (r->end - r->start);
        }
        if (fabs(cores - unit_cores[a->good]) > 1e-12 ||
            fabs(memory - unit_memory[a->good]) > 1e-12)
            FAIL("%s: agent %u bought %g cores and %g GiB for its %s (expected %g and %g)", mech,
                 a->agent, cores, memory, bgb_good_name(a->good), unit_cores[a->good],
                 unit_memory[a->good]);
        if (!(spent > 0) || spent > svc->price * svc->quantity)
            FAIL("%s: agent %u pays %g for resources, its service earns %g", mech, a->agent, spent,
                 svc->price * svc->quantity);
        if (paid > cores + 1e-12)
            FAIL("%s: agent %u pays for %g cores, holds %g", mech, a->agent, paid, cores);
    }
    double paid = 0;
    for (int k = 0; k < rows.n; k++)
        if (rows.r[k].job == job && rows.r[k].layer == 1 && rows.r[k].good == BGB_GOOD_CORES)
            paid += rows.r[k].quantity;
    if (fabs(paid - 2.0) > 1e-12)
        FAIL("%s: the job pays for %g cores, its widest phase holds 2", mech, paid);
}

static long refusals(host_t *h)
{
    bgb_agent_info_t info[64];
    const size_t n = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    long sum = 0;
    for (size_t i = 0; i < n && i < 64; i++)
        sum += info[i].refusals;
    return sum;
}

/* The script's host sells 2 cores and a job holds both: its two rotation
 * fits take one each and its sparse solve two more of the same, its phases
 * never running at once. While one job holds them, a second cannot buy
 * its services (its sellers have free slots but their host no free cores:
 * they refuse) and leaves no contract; released, the cores serve the next
 * job. */
static void check_no_cores(host_t *h, uint64_t job)
{
    outcome_t a, b;
    buy(h, job, BGB_MECH_POSTED, 1e5, &a);
    check_awards(h, &a, 1e5, "posted, first of two");
    live_net_pump(h, 0.7, NULL); /* heartbeats: the directory sees the cores sold */
    bgb_agent_info_t info[64];
    const size_t na = bgb_directory_agents(bgb_market_directory(h->market), info, 64);
    double free_cores = 0;
    for (size_t i = 0; i < na && i < 64; i++) {
        if (info[i].resource)
            free_cores += info[i].free_cores;
        else if (info[i].free_slots < 1)
            FAIL("agent %u has no free slot: the test would not isolate cores", info[i].id);
    }
    if (fabs(free_cores) > 1e-9)
        FAIL("after a job, %g cores are free on the host (expected 0)", free_cores);
    const size_t before = contracts(h);
    const long refused = refusals(h);
    buy(h, job + 1, BGB_MECH_POSTED, 1e5, &b);
    if (!b.reason[0] || b.nawards != 0)
        FAIL("a job with no free core on the host was bought (%d awards)", b.nawards);
    if (contracts(h) != before)
        FAIL("the job that found no cores left contracts");
    if (refusals(h) <= refused)
        FAIL("no seller refused a service order for want of cores");
    printf("no free cores: the second job failed (%s) after %ld refusals, no contract\n", b.reason,
           refusals(h) - refused);
    bgb_market_release(h->market, job, bg_clock_now());
    live_net_pump(h, 0.7, NULL);
    buy(h, job + 2, BGB_MECH_POSTED, 1e5, &b);
    check_awards(h, &b, 1e5, "posted, after the release");
    check_layer1(h, job + 2, &b, "posted, after the release");
    bgb_market_release(h->market, job + 2, bg_clock_now());
}

static void write_csvs(host_t *h, const char *dir)
{
    char path[4096];
    bg_error_t err = BG_ERROR_INIT;
    snprintf(path, sizeof path, "%s/contracts.csv", dir);
    FILE *f = fopen(path, "w");
    if (!f || bgb_ledger_write_contracts_csv(bgb_market_ledger(h->market), f, &err) != BG_OK)
        FAIL("cannot write %s", path);
    fclose(f);
    snprintf(path, sizeof path, "%s/agents.csv", dir);
    f = fopen(path, "w");
    if (!f || bgb_ledger_write_agents_csv(bgb_market_ledger(h->market),
                                          bgb_market_directory(h->market), f, &err) != BG_OK)
        FAIL("cannot write %s", path);
    fclose(f);
}

int main(int argc, char **argv)
{
    if (argc < 4 || strcmp(argv[1], "test") != 0)
        FAIL("usage: live_host test DIR NAGENTS");
    const char *dir = argv[2];
    const size_t nagents = (size_t)atoi(argv[3]);
    host_t h;
    live_net_open(&h, dir, "live-test", 0.05);
    live_net_wait(&h, nagents);
    char path[4096];
    FILE *f = NULL;

    const bgb_mechanism mechs[] = {BGB_MECH_POSTED, BGB_MECH_CENTRAL, BGB_MECH_CATALLACTIC};
    const int nmech = 3;
    {
        uint64_t job = 100;
        for (int mi = 0; mi < nmech; mi++) {
            const double budget = 1e5;
            outcome_t o;
            buy(&h, job, mechs[mi], budget, &o);
            check_awards(&h, &o, budget, bgb_mechanism_name(mechs[mi]));
            check_layer1(&h, job, &o, bgb_mechanism_name(mechs[mi]));
            printf("%s: 3 services bought for %.4g of %.4g in %.1f ms, each with its cores and "
                   "memory\n",
                   bgb_mechanism_name(mechs[mi]), o.spent, budget, o.latency * 1e3);
            /* While the contract holds, the agent computes for the job's id
             * and refuses any other. */
            check_refusal(h.ctx, o.awards[2].endpoint, job + 5000);
            bgb_market_release(h.market, job, bg_clock_now());
            job++;
            /* Floors are 1 per unit: 2500 units cannot be bought for 100. */
            const size_t before = contracts(&h);
            buy(&h, job, mechs[mi], 100.0, &o);
            if (strcmp(o.reason, "budget") != 0 || o.nawards != 0)
                FAIL("%s: budget 100 gave '%s' with %d awards (expected 'budget', 0)",
                     bgb_mechanism_name(mechs[mi]), o.reason, o.nawards);
            if (contracts(&h) != before)
                FAIL("%s: a failed job left contracts", bgb_mechanism_name(mechs[mi]));
            job++;
        }
        live_net_pump(&h, 0.7, NULL);
        check_no_cores(&h, job);
        job += 3;
        live_net_pump(&h, 0.3, NULL);
        write_csvs(&h, dir);
        /* Phase 2: the script kills the daemon selling the host; the
         * directory drops it and the standby daemon takes the host over. */
        const uint32_t first = resource_seller(&h);
        snprintf(path, sizeof path, "%s/phase2", dir);
        f = fopen(path, "w");
        if (f)
            fclose(f);
        const double end = bg_clock_now() + 20;
        size_t roles[2] = {nagents, 1};
        uint32_t next = first;
        while (bg_clock_now() < end && (roles[0] == nagents || roles[1] != 1 || next == first)) {
            live_net_pump(&h, 0.1, NULL);
            count_roles(&h, roles);
            next = resource_seller(&h);
        }
        const size_t n = roles[0];
        if (roles[0] != nagents - 1 || roles[1] != 1 || next == first)
            FAIL("the killed agent was not dropped or not replaced (%zu basic, %zu resource "
                 "entries listed, seller %u, was %u)",
                 roles[0], roles[1], next, first);
        live_net_pump(&h, 0.6, NULL); /* its heartbeat gives its prices */
        /* The survivors still sell, with the new seller's cores. */
        outcome_t o;
        buy(&h, job, BGB_MECH_POSTED, 1e5, &o);
        check_awards(&h, &o, 1e5, "posted after a death");
        check_layer1(&h, job, &o, "posted after a death");
        printf("dead agent dropped (it sold the host: agent %u); agent %u took the host over; "
               "%zu agents left and still selling\n",
               first, next, n);
    }
    live_net_close(&h);
    return 0;
}
