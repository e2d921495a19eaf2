/*
 * The client side of the agent fixture: real agent processes on loopback
 * (started by start_agents.sh, endpoints and PIDs in RUNDIR/NAME.ready).
 *
 *   agent_client compute RUNDIR    two rotation-fit agents (one partition
 *       each) against bg_elastic on the whole mesh; a sparse-solve agent
 *       against an in-process CHOLMOD solve; release; a dead endpoint's
 *       timeout names the agent and the service
 *   agent_client malformed RUNDIR  malformed frames each get the error
 *       reply that names the problem, and the agent keeps serving
 *   agent_client sigterm RUNDIR    requests queued when SIGTERM arrives
 *       are all answered, and the agent exits 0
 *   agent_client busy RUNDIR       an agent with seconds of calls queued
 *       still answers pings at once (a client that gives an agent up after
 *       0.5 s of silence gets its call's answer behind them), and refuses
 *       calls over its queue's cap with BUSY
 * Exit 0 when every check passes, 1 with a message otherwise.
 */
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#include "agent_fixture.h"
#include "bg_clock.h"
#include "bga_agent.h"
#include "bga_client.h"
#include "bga_pool.h"
#include "bga_transport.h"

#define TIMEOUT_MS 10000

static int failures;

#define CHECK(cond, ...)                                                                           \
    do {                                                                                           \
        if (!(cond)) {                                                                             \
            fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__);                                   \
            fprintf(stderr, __VA_ARGS__);                                                          \
            fputc('\n', stderr);                                                                   \
            failures++;                                                                            \
        }                                                                                          \
    } while (0)

typedef struct ready {
    char endpoint[256];
    long pid;
} ready;

static int read_ready(const char *dir, const char *name, ready *r)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s.ready", dir, name);
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "agent_client: %s: %s\n", path, strerror(errno));
        return -1;
    }
    const int n = fscanf(f, "%255s %ld", r->endpoint, &r->pid);
    fclose(f);
    if (n != 2) {
        fprintf(stderr, "agent_client: %s: expected 'ENDPOINT PID'\n", path);
        return -1;
    }
    return 0;
}

static bga_client_t *connect_within(const char *dir, const char *name, const char *service,
                                    int timeout_ms, ready *r)
{
    bga_client_t *c = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (read_ready(dir, name, r) != 0 ||
        bga_client_new(r->endpoint, service, timeout_ms, &c, &err) != BG_OK) {
        fprintf(stderr, "agent_client: %s\n", err.message);
        exit(1);
    }
    return c;
}
static bga_client_t *connect_to(const char *dir, const char *name, const char *service, ready *r)
{
    return connect_within(dir, name, service, TIMEOUT_MS, r);
}

/* The agent holds nothing for job: a call on it is refused as such. */
static void expect_no_job(bga_client_t *c, uint64_t job, const char *what)
{
    const double q[3] = {0, 0, 0};
    double g[3];
    bga_rotfit_out_t out = {0, g, NULL, 3, 0, {0, 0, 0, 0}, 0};
    bg_error_t err = BG_ERROR_INIT;
    const bg_status st = bga_client_rotfit(c, job, q, 3, BGA_WANT_GRADIENT, &out, &err);
    CHECK(st == BG_ERR_NOT_FOUND && strstr(err.message, "no such job"),
          "%s: job %llu should be gone: %s", what, (unsigned long long)job,
          st == BG_OK ? "it answered" : err.message);
}

static double max_rel(const double *a, const double *b, size_t n)
{
    const double scale = fx_max_abs(b, n);
    double m = 0.0;
    for (size_t i = 0; i < n; i++)
        if (fabs(a[i] - b[i]) > m)
            m = fabs(a[i] - b[i]);
    return scale > 0.0 ? m / scale : m;
}

static int run_compute(const char *dir)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL;
    const int32_t cells[3] = {4, 3, 3};
    const double origin[3] = {0, 0, 0}, size[3] = {2, 1.5, 1.5};
    if (bg_mesh_generate_box(cells, origin, size, &mesh, &err) != BG_OK)
        return fprintf(stderr, "%s\n", err.message), 1;
    const int dim = 3, T = 78, NP = 2;
    const double mu = 2.0, lambda = 30.0;
    const size_t ndof = (size_t)mesh->nv * dim;
    double *q = malloc(ndof * sizeof *q), *grad = malloc(ndof * sizeof *grad);
    double *sum_grad = calloc(ndof, sizeof *sum_grad);
    fx_deform(mesh, 1.1, q);
    bg_elastic_t *whole = NULL;
    bg_sparse_t *sys = NULL;
    int32_t *free_index = fx_all_free(mesh, dim);
    if (bg_elastic_new(mesh, mu, lambda, &whole, &err) != BG_OK ||
        bg_sparse_new(mesh, dim, free_index, (int32_t)ndof, &sys, &err) != BG_OK)
        return fprintf(stderr, "%s\n", err.message), 1;
    const double energy = bg_elastic_eval(whole, q, grad);
    const size_t nnz = bg_sparse_nonzeros(sys);
    double *H = malloc(nnz * sizeof *H), *sumH = calloc(nnz, sizeof *sumH);
    bg_sparse_zero(sys);
    bg_elastic_assemble_hessian(whole, q, 0, 1.0, bg_sparse_scatter(sys), bg_sparse_values(sys));
    memcpy(H, bg_sparse_values(sys), nnz * sizeof *H);

    const char *names[2] = {"rotfit1", "rotfit2"};
    double sum_energy = 0.0;
    for (int p = 0; p < NP; p++) {
        ready r;
        bga_client_t *c = connect_to(dir, names[p], "rotation-fit", &r);
        fx_part part;
        if (fx_part_make(mesh, q, p, NP, &part) != 0)
            return fprintf(stderr, "out of memory\n"), 1;
        bga_partition_t bp = fx_partition(&part, mesh, mu, lambda);
        bp.lease_ms = 60000;
        const uint64_t job = 1000 + (uint64_t)p;
        bg_status st = bga_client_rotfit_setup(c, job, &bp, &err);
        CHECK(st == BG_OK, "%s set-up: %s", names[p], err.message);
        /* The same partition in-process: the agent's answer must agree to
         * round-off (it runs the same kernel on the same data). */
        bg_mesh_t *lm = NULL;
        bg_elastic_t *lmodel = NULL;
        bg_mesh_new(BG_MESH_VOLUME, part.nv, part.ne, &lm, &err);
        memcpy(lm->x, part.rest, (size_t)part.nv * dim * sizeof *lm->x);
        memcpy(lm->elements, part.elements, (size_t)part.ne * 4 * sizeof *lm->elements);
        bg_elastic_new(lm, mu, lambda, &lmodel, &err);
        const size_t lndof = (size_t)part.nv * dim, nh = (size_t)part.ne * T;
        double *lgrad = malloc(lndof * sizeof *lgrad), *lH = calloc(nh, sizeof *lH);
        int32_t *ident = malloc(nh * sizeof *ident);
        for (size_t i = 0; i < nh; i++)
            ident[i] = (int32_t)i;
        double *agrad = malloc(lndof * sizeof *agrad), *aH = malloc(nh * sizeof *aH);
        for (int round = 0; round < 2; round++) {
            const double le = bg_elastic_eval(lmodel, part.q, lgrad);
            memset(lH, 0, nh * sizeof *lH);
            bg_elastic_assemble_hessian(lmodel, part.q, 0, 1.0, ident, lH);
            bga_rotfit_out_t out = {0, agrad, aH, lndof, nh, {0, 0, 0, 0}, 0};
            st = bga_client_rotfit(c, job, part.q, lndof, BGA_WANT_GRADIENT | BGA_WANT_HESSIAN,
                                   &out, &err);
            CHECK(st == BG_OK, "%s call: %s", names[p], err.message);
            if (st != BG_OK)
                break;
            CHECK(fabs(out.energy - le) <= 1e-12 * fabs(le), "%s energy %.17g vs %.17g", names[p],
                  out.energy, le);
            CHECK(max_rel(agrad, lgrad, lndof) <= 1e-12, "%s gradient rel %g", names[p],
                  max_rel(agrad, lgrad, lndof));
            CHECK(max_rel(aH, lH, nh) <= 1e-12, "%s Hessian rel %g", names[p], max_rel(aH, lH, nh));
            CHECK(out.fits.calls == part.ne, "%s: %lld fits for %d elements", names[p],
                  (long long)out.fits.calls, (int)part.ne);
            if (round == 1) {
                CHECK(out.fits.warm == part.ne, "%s: second call warm-started %lld of %d", names[p],
                      (long long)out.fits.warm, (int)part.ne);
                sum_energy += out.energy;
                for (int32_t v = 0; v < part.nv; v++)
                    for (int k = 0; k < dim; k++)
                        sum_grad[(size_t)part.local_to_global[v] * dim + k] +=
                            agrad[(size_t)v * dim + k];
                for (int32_t e = 0; e < part.ne; e++)
                    for (int t = 0; t < T; t++) {
                        const int32_t at =
                            bg_sparse_scatter(sys)[(size_t)part.global_elements[e] * T + t];
                        if (at >= 0)
                            sumH[at] += aH[(size_t)e * T + t];
                    }
            }
        }
        /* Other tests share these agents: counts are checked as bounds,
         * this job's own state by name. */
        bga_agent_status_t as;
        st = bga_client_heartbeat(c, job, &as, &err);
        CHECK(st == BG_OK && as.jobs >= 1 && as.free_slots < as.slots,
              "%s heartbeat: %s, %lld jobs", names[p], err.message, (long long)as.jobs);
        CHECK(bga_client_release(c, job, &err) == BG_OK, "%s release: %s", names[p], err.message);
        expect_no_job(c, job, names[p]);
        const bga_traffic_t tr = bga_client_traffic(c);
        printf("%s (%s): %d elements, %lld requests, %lld bytes sent, %lld received, "
               "wait %.3f ms, agent compute %.3f ms\n",
               names[p], r.endpoint, (int)part.ne, (long long)tr.requests, (long long)tr.bytes_sent,
               (long long)tr.bytes_received, 1e3 * tr.wait_seconds, 1e3 * tr.agent_seconds);
        free(lgrad);
        free(lH);
        free(ident);
        free(agrad);
        free(aH);
        bg_elastic_destroy(&lmodel);
        bg_mesh_destroy(&lm);
        fx_part_free(&part);
        bga_client_destroy(&c);
    }
    CHECK(fabs(sum_energy - energy) <= 1e-12 * energy, "energy over 2 agents %.17g vs %.17g",
          sum_energy, energy);
    CHECK(max_rel(sum_grad, grad, ndof) <= 1e-12, "gradient over 2 agents rel %g",
          max_rel(sum_grad, grad, ndof));
    CHECK(max_rel(sumH, H, nnz) <= 1e-12, "Hessian over 2 agents rel %g", max_rel(sumH, H, nnz));
    printf("rotation-fit over 2 agents: energy %.17g (in-process %.17g), gradient rel %.2g, "
           "Hessian rel %.2g\n",
           sum_energy, energy, max_rel(sum_grad, grad, ndof), max_rel(sumH, H, nnz));

    /* The coordinator's pool over both agents: compact scatter maps, the
     * partitions computed in parallel, sums in partition order. */
    {
        ready r1, r2;
        if (read_ready(dir, "rotfit1", &r1) || read_ready(dir, "rotfit2", &r2))
            return 1;
        const char *eps[2] = {r1.endpoint, r2.endpoint};
        bga_pool_config_t pc = {mesh, mu,   lambda,     0.0,  bg_sparse_scatter(sys), nnz, eps,
                                2,    3000, TIMEOUT_MS, 60000, NULL, 0,   NULL, NULL};
        bga_rotfit_pool_t *pool = NULL;
        bg_status st = bga_rotfit_pool_new(&pc, &pool, &err);
        CHECK(st == BG_OK, "pool: %s", err.message);
        double *pgrad = malloc(ndof * sizeof *pgrad), *pH = calloc(nnz, sizeof *pH);
        double pe = 0.0;
        for (int round = 0; round < 2 && st == BG_OK; round++) {
            memset(pH, 0, nnz * sizeof *pH);
            st = bga_rotfit_pool_eval(pool, q, &pe, pgrad, pH, 0, &err);
            CHECK(st == BG_OK, "pool eval: %s", err.message);
        }
        CHECK(fabs(pe - energy) <= 1e-12 * energy, "pool energy %.17g vs %.17g", pe, energy);
        CHECK(max_rel(pgrad, grad, ndof) <= 1e-12, "pool gradient rel %g",
              max_rel(pgrad, grad, ndof));
        CHECK(max_rel(pH, H, nnz) <= 1e-12, "pool Hessian rel %g", max_rel(pH, H, nnz));
        const bga_traffic_t t0 = bga_rotfit_pool_traffic(pool, 0);
        printf("pool of 2: energy rel %.1e, gradient rel %.1e, Hessian rel %.1e; agent 1 "
               "received %lld bytes per call for %d elements (compact Hessian)\n",
               fabs(pe - energy) / energy, max_rel(pgrad, grad, ndof), max_rel(pH, H, nnz),
               (long long)(t0.bytes_received / (t0.requests > 0 ? t0.requests : 1)),
               (int)bga_rotfit_pool_elements(pool, 0));
        bga_rotfit_pool_destroy(&pool);
        for (int i = 0; i < 2; i++) { /* destroy released both jobs */
            bga_client_t *c = connect_to(dir, i ? "rotfit2" : "rotfit1", "rotation-fit", &r1);
            expect_no_job(c, 3000, "after the pool");
            bga_client_destroy(&c);
        }
        free(pgrad);
        free(pH);
    }

    /* Sparse-solve: the projected Hessian plus a shift (the rigid modes
     * make it singular), pattern once, two factorizations, three solves. */
    ready r;
    bga_client_t *c = connect_to(dir, "solve", "sparse-solve", &r);
    bg_sparse_zero(sys);
    bg_elastic_assemble_hessian(whole, q, 1, 1.0, bg_sparse_scatter(sys), bg_sparse_values(sys));
    const int32_t n = bg_sparse_size(sys);
    const double shift = 0.25;
    double *rhs = malloc(3 * (size_t)n * sizeof *rhs), *x = malloc(3 * (size_t)n * sizeof *x);
    double *ref = malloc((size_t)n * sizeof *ref);
    for (size_t i = 0; i < 3 * (size_t)n; i++)
        rhs[i] = cos(0.11 * (double)i) - 0.5;
    const uint64_t job = 2000;
    bg_status st = bga_client_solve_setup(c, job, n, bg_sparse_colptr(sys), bg_sparse_rowidx(sys), 0,
                                          60000, &err);
    CHECK(st == BG_OK, "solve set-up: %s", err.message);
    for (int round = 0; round < 2 && st == BG_OK; round++) {
        if (round == 1)
            for (size_t i = 0; i < nnz; i++)
                bg_sparse_values(sys)[i] *= 0.75;
        int posdef = 0;
        st = bga_client_solve_factor(c, job, bg_sparse_values(sys), nnz, shift, &posdef, &err);
        CHECK(st == BG_OK && posdef, "factor: %s (posdef %d)", err.message, posdef);
        const int nrhs = round == 0 ? 1 : 2;
        st = bga_client_solve(c, job, rhs, n, nrhs, x, &err);
        CHECK(st == BG_OK, "solve: %s", err.message);
        bg_error_t lerr = BG_ERROR_INIT;
        bg_sparse_factorize(sys, shift, &lerr);
        for (int k = 0; k < nrhs && st == BG_OK; k++) {
            bg_sparse_solve(sys, rhs + (size_t)k * n, ref, &lerr);
            CHECK(max_rel(x + (size_t)k * n, ref, (size_t)n) <= 1e-12,
                  "solution %d rel %g against in-process CHOLMOD", k,
                  max_rel(x + (size_t)k * n, ref, (size_t)n));
        }
    }
    CHECK(bga_client_release(c, job, &err) == BG_OK, "solve release: %s", err.message);
    /* After the release the factor is gone: the agent says so. */
    st = bga_client_solve(c, job, rhs, n, 1, x, &err);
    CHECK(st == BG_ERR_NOT_FOUND && strstr(err.message, "no such job") &&
              strstr(err.message, r.endpoint) && strstr(err.message, "sparse-solve"),
          "solve after release: %s", err.message);
    printf("sparse-solve (%s): n = %d, nnz = %zu, matches in-process CHOLMOD\n", r.endpoint, (int)n,
           nnz);
    bga_client_destroy(&c);

    /* Nothing listens on port 1: the timeout names the agent and service. */
    bga_client_t *dead = NULL;
    bg_error_clear(&err);
    bga_client_new("tcp://127.0.0.1:1", "rotation-fit", 300, &dead, &err);
    const double t0 = bg_clock_now();
    st = bga_client_heartbeat(dead, 0, NULL, &err);
    const double waited = bg_clock_now() - t0;
    CHECK(st == BG_ERR_IO && strstr(err.message, "agent tcp://127.0.0.1:1 (rotation-fit)") &&
              strstr(err.message, "no reply to heartbeat within 300 ms") && waited < 2.0,
          "dead agent: %s after %.2f s", err.message, waited);
    bga_client_destroy(&dead);

    free(rhs);
    free(x);
    free(ref);
    free(H);
    free(sumH);
    free(q);
    free(grad);
    free(sum_grad);
    free(free_index);
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&whole);
    bg_mesh_destroy(&mesh);
    return failures ? 1 : 0;
}

/* Sends raw frames, expects an ERROR with `code` whose text has needle. */
/* The refusal of a raw request: its code, a message containing needle,
 * and the sequence number it quotes (seq: the request's, 0 where its
 * header cannot be read), so a client matches it at once. */
static void expect_refusal(bga_client_t *c, const bga_frame_t *f, int n, bga_wire_code code,
                           uint64_t seq, const char *needle, const char *what)
{
    bga_reply_t rep;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_client_request_raw(c, f, n, &rep, &err) != BG_OK) {
        CHECK(0, "%s: %s", what, err.message);
        return;
    }
    char text[BG_ERROR_MESSAGE_MAX] = "";
    if (rep.msg.header.type == BGA_ERROR)
        if (rep.msg.array[BGA_ERR_MESSAGE].count)
            memcpy(text, rep.msg.array[BGA_ERR_MESSAGE].data, rep.msg.array[BGA_ERR_MESSAGE].count);
    CHECK(rep.msg.header.type == BGA_ERROR && rep.msg.field[BGA_ERR_CODE].i == code &&
              strstr(text, needle),
          "%s: got %s code %lld '%s'", what, bga_type_name(rep.msg.header.type),
          rep.msg.header.type == BGA_ERROR ? (long long)rep.msg.field[BGA_ERR_CODE].i : -1LL, text);
    CHECK(rep.msg.header.seq == seq, "%s: the refusal quotes seq %llu, the request's is %llu",
          what, (unsigned long long)rep.msg.header.seq, (unsigned long long)seq);
    printf("%-22s -> %s (seq %llu): %s\n", what, bga_wire_code_name(code),
           (unsigned long long)rep.msg.header.seq, text);
    bga_reply_close(&rep);
}

static int run_malformed(const char *dir)
{
    ready r;
    bga_client_t *c = connect_to(dir, "rotfit1", "rotation-fit", &r);
    bga_msg_t m;
    bga_frames_t fr;
    bg_error_t err = BG_ERROR_INIT;
    const double pos[6] = {1, 2, 3, 4, 5, 6};
    bga_msg_init(&m, BGA_ROTFIT_CALL, 77, 5);
    m.field[BGA_RC_WANT].i = BGA_WANT_GRADIENT;
    m.array[BGA_RC_POSITIONS] = (bga_array_t){pos, 6};
    if (bga_wire_encode(&m, &fr, &err) != BG_OK)
        return fprintf(stderr, "%s\n", err.message), 1;
    bga_frame_t v[16];
    bga_frames_view(&fr, v);
    uint8_t hdr[48], arr[48];

    bga_frame_t t1[1] = {{v[0].data, 20}};
    expect_refusal(c, t1, 1, BGA_WIRE_TRUNCATED, 0, "header frame has 20 bytes",
                   "truncated header");
    memcpy(hdr, v[0].data, 48);
    hdr[6] = 0x99;
    bga_frame_t t2[3] = {{hdr, 48}, v[1], v[2]};
    expect_refusal(c, t2, 3, BGA_WIRE_UNKNOWN_TYPE, 5, "unknown message type 0x0199",
                   "unknown type");
    memcpy(hdr, v[0].data, 48);
    hdr[4] = 9;
    t2[0].data = hdr;
    expect_refusal(c, t2, 3, BGA_WIRE_WRONG_VERSION, 5, "protocol version 9", "wrong version");
    hdr[4] = 0;
    expect_refusal(c, t2, 3, BGA_WIRE_WRONG_VERSION, 5, "protocol version 0", "version 0");
    memcpy(arr, v[2].data, 48);
    const double nan = NAN;
    memcpy(arr + 16, &nan, 8);
    bga_frame_t t3[3] = {v[0], v[1], {arr, 48}};
    expect_refusal(c, t3, 3, BGA_WIRE_NOT_FINITE, 5, "positions[2] is nan", "NaN position");
    bga_frame_t t4[12];
    for (int i = 0; i < 12; i++)
        t4[i] = v[i % 3];
    expect_refusal(c, t4, 12, BGA_WIRE_FRAME_COUNT, 5, "12 frames", "12 frames");
    expect_refusal(c, v, 3, BGA_WIRE_NO_JOB, 5, "no state for job 77", "call without set-up");
    bga_frame_t t5[1] = {{NULL, 0}};
    expect_refusal(c, t5, 1, BGA_WIRE_TRUNCATED, 0, "header frame has 0 bytes", "empty frame");
    bga_frames_free(&fr);

    /* Still serving. */
    bga_agent_status_t as;
    const bg_status st = bga_client_heartbeat(c, 0, &as, &err);
    CHECK(st == BG_OK && strcmp(as.name, "rotfit1") == 0, "heartbeat after malformed input: %s",
          err.message);
    printf("agent %s still serving: %lld slots, %lld free\n", as.name, (long long)as.slots,
           (long long)as.free_slots);
    bga_client_destroy(&c);
    return failures ? 1 : 0;
}

/* Several requests queued, SIGTERM, every reply still arrives, exit 0. */
static int run_sigterm(const char *dir)
{
    ready r;
    if (read_ready(dir, "term", &r) != 0)
        return 1;
    bg_error_t err = BG_ERROR_INIT;
    bga_client_t *c = NULL;
    if (bga_client_new(r.endpoint, "rotation-fit", TIMEOUT_MS, &c, &err) != BG_OK)
        return fprintf(stderr, "%s\n", err.message), 1;
    bg_mesh_t *mesh = NULL;
    const int32_t cells[3] = {12, 12, 12};
    const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
    bg_mesh_generate_box(cells, origin, size, &mesh, &err);
    double *q = malloc((size_t)mesh->nv * 3 * sizeof *q);
    fx_deform(mesh, 0.4, q);
    fx_part part;
    fx_part_make(mesh, q, 0, 1, &part);
    bga_partition_t bp = fx_partition(&part, mesh, 1.0, 5.0);
    bg_status st = bga_client_rotfit_setup(c, 5, &bp, &err);
    CHECK(st == BG_OK, "set-up: %s", err.message);
    /* One call measures the agent's time per call; then enough calls are
     * queued for 0.3 s of work, so the signal (after the first reply)
     * lands while the agent computes, with calls still queued. */
    const size_t nq = (size_t)part.nv * 3, nh = (size_t)part.ne * 78;
    double *gbuf = malloc(nq * sizeof *gbuf), *hbuf = malloc(nh * sizeof *hbuf);
    bga_rotfit_out_t out = {0, gbuf, hbuf, nq, nh, {0, 0, 0, 0}, 0};
    const unsigned want = BGA_WANT_GRADIENT | BGA_WANT_HESSIAN;
    st = bga_client_rotfit(c, 5, part.q, nq, want, &out, &err);
    CHECK(st == BG_OK, "first call: %s", err.message);
    free(gbuf);
    free(hbuf);
    bga_client_destroy(&c);
    int nreq = (int)ceil(0.3 / (out.agent_seconds > 1e-4 ? out.agent_seconds : 1e-4)) + 2;
    if (nreq > BGA_AGENT_DRAIN_MAX - 4)
        nreq = BGA_AGENT_DRAIN_MAX - 4;

    /* A raw DEALER so the requests are pipelined. */
    void *ctx = zmq_ctx_new(), *s = zmq_socket(ctx, ZMQ_DEALER);
    const int linger = 0;
    zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger);
    zmq_connect(s, r.endpoint);
    for (int i = 0; i < nreq; i++) {
        bga_msg_t m;
        bga_frames_t fr;
        bga_msg_init(&m, BGA_ROTFIT_CALL, 5, 100 + (uint64_t)i);
        m.field[BGA_RC_WANT].i = want;
        m.array[BGA_RC_POSITIONS] = (bga_array_t){part.q, nq};
        bga_wire_encode(&m, &fr, &err);
        bga_send(s, NULL, &fr, &err);
        bga_frames_free(&fr);
    }
    /* The signal goes once the first reply is back (the agent has the
     * requests sent before it and works through them) plus 30 ms for the
     * rest to leave this process's I/O thread. */
    struct timespec pause = {0, 30 * 1000 * 1000};
    int got = 0, signalled = 0;
    const double deadline = bg_clock_now() + 20.0;
    while (got < nreq && bg_clock_now() < deadline) {
        zmq_pollitem_t item = {s, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 1000) <= 0)
            continue;
        bga_received_t rx;
        if (bga_recv(s, 0, &rx, &err) != BG_OK)
            break;
        bga_frame_t v[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&rx, v);
        bga_msg_t rep;
        bga_wire_error_t w;
        const bga_wire_code wc = bga_wire_decode(v, rx.count, NULL, &rep, &w);
        CHECK(wc == BGA_WIRE_OK && rep.header.type == BGA_ROTFIT_RESULT &&
                  rep.header.seq == 100 + (uint64_t)got,
              "reply %d: %s seq %llu", got, bga_type_name(rep.header.type),
              (unsigned long long)rep.header.seq);
        bga_received_close(&rx);
        got++;
        if (!signalled) {
            nanosleep(&pause, NULL);
            CHECK(kill((pid_t)r.pid, SIGTERM) == 0, "kill %ld: %s", r.pid, strerror(errno));
            signalled = 1;
        }
    }
    CHECK(got == nreq, "%d of %d queued requests answered after SIGTERM", got, nreq);
    printf("SIGTERM after the first of %d requests of %.1f ms each: %d answered\n", nreq,
           1e3 * out.agent_seconds, got);
    zmq_close(s);
    zmq_ctx_term(ctx);
    /* The fixture's wrapper records the exit status when the agent ends. */
    char path[1024];
    snprintf(path, sizeof path, "%s/term.rc", dir);
    int rc = -1;
    pause.tv_nsec = 100 * 1000 * 1000;
    for (int i = 0; i < 100 && rc < 0; i++) {
        FILE *f = fopen(path, "r");
        if (f) {
            if (fscanf(f, "%d", &rc) != 1)
                rc = -1;
            fclose(f);
        }
        if (rc < 0)
            nanosleep(&pause, NULL);
    }
    CHECK(rc == 0, "agent exit status after SIGTERM: %d (-1: still running after 10 s)", rc);
    printf("agent exit status after SIGTERM: %d\n", rc);
    fx_part_free(&part);
    free(q);
    bg_mesh_destroy(&mesh);
    return failures ? 1 : 0;
}

/* A pipelined rotation-fit call on a raw DEALER (seq 1000 + i). */
static void post_raw(void *s, const fx_part *part, unsigned want, uint64_t seq)
{
    bga_msg_t m;
    bga_frames_t fr;
    bg_error_t err = BG_ERROR_INIT;
    bga_msg_init(&m, BGA_ROTFIT_CALL, 7, seq);
    m.field[BGA_RC_WANT].i = want;
    m.array[BGA_RC_POSITIONS] = (bga_array_t){part->q, (size_t)part->nv * 3};
    bga_wire_encode(&m, &fr, &err);
    bga_send(s, NULL, &fr, &err);
    bga_frames_free(&fr);
}

/*
 * The agent answers pings while it computes: about 3 s of rotation-fit
 * calls are queued on it from a raw DEALER (more than BGA_AGENT_QUEUE_MAX
 * of them, so the last are refused with BUSY at once), then a client whose
 * agent is lost after LOST_MS of silence makes one more call, which waits
 * behind the whole queue: it must get its answer, never give the agent up
 * (the agent's socket loop answers its pings; a loop that computed itself,
 * as before, went silent for the whole queue). Every queued call gets a
 * reply: its result, or BUSY for those over the cap.
 */
#define BUSY_LOST_MS 1000
#define BUSY_QUEUE_SECONDS 4.0
/* The watched call's own timeout: far beyond the queue's 4 s of work even
 * on a machine loaded 10-fold, so that only the liveness rule under test
 * (1 s of silence) could give the agent up. */
#define BUSY_CALL_TIMEOUT_MS 120000

/* Sends `sent` pipelined calls (seq 1000 + i) and counts their replies:
 * results and BUSY refusals. */
static void burst(void *s, const fx_part *part, unsigned want, int sent, int *results, int *busy)
{
    for (int i = 0; i < sent; i++)
        post_raw(s, part, want, 1000 + (uint64_t)i);
    *results = *busy = 0;
    const double deadline = bg_clock_now() + 120.0;
    while (*results + *busy < sent && bg_clock_now() < deadline) {
        zmq_pollitem_t item = {s, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 1000) <= 0)
            continue;
        bga_received_t rx;
        bg_error_t err = BG_ERROR_INIT;
        if (bga_recv(s, 0, &rx, &err) != BG_OK)
            break;
        bga_frame_t v[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&rx, v);
        bga_msg_t rep;
        bga_wire_error_t w;
        if (bga_wire_decode(v, rx.count, NULL, &rep, &w) == BGA_WIRE_OK) {
            if (rep.header.type == BGA_ROTFIT_RESULT)
                (*results)++;
            else if (rep.header.type == BGA_ERROR && rep.field[BGA_ERR_CODE].i == BGA_WIRE_BUSY)
                (*busy)++;
        }
        bga_received_close(&rx);
    }
}
static int run_busy(const char *dir)
{
    ready r;
    bga_client_t *c = connect_within(dir, "rotfit2", "rotation-fit", BUSY_CALL_TIMEOUT_MS, &r);
    bg_error_t err = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL;
    double *q = NULL, *gbuf = NULL, *hbuf = NULL;
    fx_part part;
    memset(&part, 0, sizeof part);
    const unsigned want = BGA_WANT_GRADIENT | BGA_WANT_HESSIAN;
    bga_rotfit_out_t out;
    size_t nq = 0;
    double one = 0.0;
    bg_status st = BG_OK;
    /* A box big enough that BGA_AGENT_QUEUE_MAX calls take the agent
     * BUSY_QUEUE_SECONDS: grown until one call computes long enough. */
    for (int32_t n = 10; st == BG_OK && n <= 40; n = n * 3 / 2) {
        fx_part_free(&part);
        free(q);
        free(gbuf);
        free(hbuf);
        bg_mesh_destroy(&mesh);
        const int32_t cells[3] = {n, n, n};
        const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
        bg_mesh_generate_box(cells, origin, size, &mesh, &err);
        q = malloc((size_t)mesh->nv * 3 * sizeof *q);
        fx_deform(mesh, 0.4, q);
        fx_part_make(mesh, q, 0, 1, &part);
        bga_partition_t bp = fx_partition(&part, mesh, 1.0, 5.0);
        st = bga_client_rotfit_setup(c, 7, &bp, &err);
        CHECK(st == BG_OK, "set-up: %s", err.message);
        nq = (size_t)part.nv * 3;
        const size_t nh = (size_t)part.ne * 78;
        gbuf = malloc(nq * sizeof *gbuf);
        hbuf = malloc(nh * sizeof *hbuf);
        out = (bga_rotfit_out_t){0, gbuf, hbuf, nq, nh, {0, 0, 0, 0}, 0};
        if (st == BG_OK)
            st = bga_client_rotfit(c, 7, part.q, nq, want, &out, &err);
        CHECK(st == BG_OK, "first call: %s", err.message);
        one = out.agent_seconds;
        if (n == 10 && st == BG_OK) {
            /* Cheap calls, all sent at once: those over the cap are refused. */
            void *bctx = zmq_ctx_new(), *bs = zmq_socket(bctx, ZMQ_DEALER);
            const int zero = 0;
            zmq_setsockopt(bs, ZMQ_LINGER, &zero, sizeof zero);
            zmq_connect(bs, r.endpoint);
            const int sent = BGA_AGENT_QUEUE_MAX + 16;
            int results = 0, busy = 0;
            burst(bs, &part, want, sent, &results, &busy);
            printf("%d calls at once: %d results, %d refused BUSY\n", sent, results, busy);
            CHECK(results + busy == sent && busy >= 1 && results >= BGA_AGENT_QUEUE_MAX,
                  "%d calls at once: %d results, %d BUSY", sent, results, busy);
            zmq_close(bs);
            zmq_ctx_term(bctx);
        }
        if (one * BGA_AGENT_QUEUE_MAX >= BUSY_QUEUE_SECONDS)
            break;
    }
    /* Calls for BUSY_QUEUE_SECONDS at least, and 3 over the cap. */
    int queued = (int)ceil(BUSY_QUEUE_SECONDS / (one > 1e-3 ? one : 1e-3));
    if (queued > BGA_AGENT_QUEUE_MAX)
        queued = BGA_AGENT_QUEUE_MAX;
    const int sent = queued + 3;
    void *ctx = zmq_ctx_new(), *s = zmq_socket(ctx, ZMQ_DEALER);
    const int linger = 0;
    zmq_setsockopt(s, ZMQ_LINGER, &linger, sizeof linger);
    zmq_connect(s, r.endpoint);
    for (int i = 0; i < sent; i++)
        post_raw(s, &part, want, 1000 + (uint64_t)i);
    /* Let the queue reach the agent before the watched call joins it. */
    struct timespec pause = {0, 200 * 1000 * 1000};
    nanosleep(&pause, NULL);
    bga_client_set_liveness(c, BUSY_LOST_MS / 5, BUSY_LOST_MS);
    const double t1 = bg_clock_now();
    bg_error_t cerr = BG_ERROR_INIT;
    st = bga_client_rotfit(c, 7, part.q, nq, want, &out, &cerr);
    const double waited = bg_clock_now() - t1;
    CHECK(st == BG_OK, "the call behind %d queued ones (%.1f s of work): %s", queued,
          queued * one, cerr.message);
    CHECK(bga_client_failure(c) == BGA_CLIENT_FINE, "the busy agent was given up (%d, %s)",
          (int)bga_client_failure(c), cerr.message);
    printf("one call %.3f s; %d queued (%d sent), the watched call answered after %.3f s with the "
           "agent lost after %d ms of silence\n",
           one, queued, sent, waited, BUSY_LOST_MS);
    int results = 0, busy = 0;
    const double deadline = bg_clock_now() + 60.0;
    while (results + busy < sent && bg_clock_now() < deadline) {
        zmq_pollitem_t item = {s, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 1000) <= 0)
            continue;
        bga_received_t rx;
        if (bga_recv(s, 0, &rx, &err) != BG_OK)
            break;
        bga_frame_t v[BGA_WIRE_MAX_FRAMES + 1];
        bga_received_view(&rx, v);
        bga_msg_t rep;
        bga_wire_error_t w;
        if (bga_wire_decode(v, rx.count, NULL, &rep, &w) == BGA_WIRE_OK) {
            if (rep.header.type == BGA_ROTFIT_RESULT)
                results++;
            else if (rep.header.type == BGA_ERROR && rep.field[BGA_ERR_CODE].i == BGA_WIRE_BUSY)
                busy++;
        }
        bga_received_close(&rx);
    }
    printf("queued calls: %d results, %d refused BUSY\n", results, busy);
    CHECK(results + busy == sent, "%d of %d queued calls answered", results + busy, sent);

    zmq_close(s);
    zmq_ctx_term(ctx);
    bga_client_release(c, 7, &err);
    bga_client_destroy(&c);
    free(gbuf);
    free(hbuf);
    fx_part_free(&part);
    free(q);
    bg_mesh_destroy(&mesh);
    return failures ? 1 : 0;
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: agent_client compute|malformed|sigterm|busy RUNDIR\n");
        return 2;
    }
    if (strcmp(argv[1], "compute") == 0)
        return run_compute(argv[2]);
    if (strcmp(argv[1], "malformed") == 0)
        return run_malformed(argv[2]);
    if (strcmp(argv[1], "sigterm") == 0)
        return run_sigterm(argv[2]);
    if (strcmp(argv[1], "busy") == 0)
        return run_busy(argv[2]);
    fprintf(stderr, "agent_client: unknown mode '%s'\n", argv[1]);
    return 2;
}
