/*
 * bench_agents RUNDIR [MESH | --box NX NY NZ] [--iterations N] [--smoke]
 *
 * One Newton iteration's basic services in-process against the same on
 * agent processes on loopback (started by start_agents.sh: rotfit1,
 * rotfit2, solve in RUNDIR): energy + gradient + Hessian values (rotation
 * fit over 1 and 2 agents, partial sums combined in partition order),
 * then factor + solve of the shifted Hessian on the sparse-solve agent.
 * Each rotation-fit agent gets a compact scatter map: the partition's
 * Hessian comes back as one value per distinct pattern entry it touches.
 * Prints per iteration: wall time, bytes, and the split agent compute /
 * client encode+decode / transit+queueing (wait − agent compute) /
 * coordinator gather; checks the remote energy (1e-12) and solution (1e-8,
 * see below) against the in-process ones, exit 1 if they differ.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "agent_fixture.h"
#include "bg_clock.h"
#include "bg_mesh_io.h"
#include "bga_client.h"

#define T 78
#define SHIFT 1e-3

typedef struct remote_part {
    fx_part part;
    int32_t nval;
    int32_t *scatter;  /* ne*T into [0, nval) */
    int32_t *to_global; /* nval pattern positions */
    double *grad, *hess;
} remote_part;

/* The partition's compact Hessian layout: each distinct global pattern
 * position its elements touch gets one local value. */
static int compact_scatter(const bg_sparse_t *sys, size_t nnz, remote_part *rp)
{
    const fx_part *p = &rp->part;
    int32_t *local = malloc(nnz * sizeof *local);
    rp->scatter = malloc((size_t)p->ne * T * sizeof *rp->scatter);
    rp->to_global = malloc((size_t)p->ne * T * sizeof *rp->to_global);
    if (!local || !rp->scatter || !rp->to_global)
        return -1;
    for (size_t i = 0; i < nnz; i++)
        local[i] = -1;
    rp->nval = 0;
    for (int32_t e = 0; e < p->ne; e++)
        for (int t = 0; t < T; t++) {
            const int32_t g = bg_sparse_scatter(sys)[(size_t)p->global_elements[e] * T + t];
            int32_t l = -1;
            if (g >= 0) {
                if (local[g] < 0) {
                    local[g] = rp->nval;
                    rp->to_global[rp->nval++] = g;
                }
                l = local[g];
            }
            rp->scatter[(size_t)e * T + t] = l;
        }
    free(local);
    rp->grad = malloc((size_t)p->nv * 3 * sizeof *rp->grad);
    rp->hess = malloc((size_t)rp->nval * sizeof *rp->hess);
    return rp->grad && rp->hess ? 0 : -1;
}

static bga_client_t *open_agent(const char *dir, const char *name, const char *service)
{
    char path[1024], endpoint[256];
    long pid;
    snprintf(path, sizeof path, "%s/%s.ready", dir, name);
    FILE *f = fopen(path, "r");
    if (!f || fscanf(f, "%255s %ld", endpoint, &pid) != 2) {
        fprintf(stderr, "bench_agents: %s: %s\n", path, f ? "malformed" : strerror(errno));
        exit(1);
    }
    fclose(f);
    bga_client_t *c = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_client_new(endpoint, service, 120000, &c, &err) != BG_OK) {
        fprintf(stderr, "bench_agents: %s\n", err.message);
        exit(1);
    }
    return c;
}

static void die(const bg_error_t *err)
{
    fprintf(stderr, "bench_agents: %s\n", err->message);
    exit(1);
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: bench_agents RUNDIR [MESH | --box NX NY NZ] [--iterations N] "
                "[--smoke]\n");
        return 2;
    }
    const char *dir = argv[1], *mesh_path = NULL;
    int32_t cells[3] = {20, 20, 20};
    int iterations = 5;
    for (int i = 2; i < argc; i++) {
        if (strcmp(argv[i], "--box") == 0 && i + 3 < argc) {
            for (int k = 0; k < 3; k++)
                cells[k] = (int32_t)atoi(argv[++i]);
        } else if (strcmp(argv[i], "--iterations") == 0 && i + 1 < argc) {
            iterations = atoi(argv[++i]);
        } else if (strcmp(argv[i], "--smoke") == 0) {
            cells[0] = cells[1] = cells[2] = 5;
            iterations = 2;
        } else {
            mesh_path = argv[i];
        }
    }
    bg_error_t err = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL;
    if (mesh_path) {
        if (bg_mesh_read(mesh_path, &mesh, NULL, &err) != BG_OK ||
            bg_mesh_validate(mesh, mesh_path, NULL, &err) != BG_OK)
            die(&err);
    } else {
        const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
        if (bg_mesh_generate_box(cells, origin, size, &mesh, &err) != BG_OK)
            die(&err);
    }
    if (mesh->dim != 3 || mesh->nodes_per_element != 4) {
        fprintf(stderr, "bench_agents: a tetrahedral mesh is needed\n");
        return 2;
    }
    const double mu = 1.0, lambda = 10.0;
    const size_t ndof = (size_t)mesh->nv * 3;
    double *q = malloc(ndof * sizeof *q), *grad = malloc(ndof * sizeof *grad);
    double *rgrad = malloc(ndof * sizeof *rgrad), *x = malloc(ndof * sizeof *x);
    double *rx = malloc(ndof * sizeof *rx);
    double lo[3], hi[3];
    bg_mesh_bounds(mesh, lo, hi);
    for (size_t i = 0; i < ndof; i++) /* a mild deformation of the rest shape */
        q[i] = mesh->x[i] * (1.0 + 0.05 * sin(3.0 * mesh->x[i - i % 3] / (hi[0] - lo[0] + 1e-300)));
    bg_elastic_t *model = NULL;
    bg_sparse_t *sys = NULL;
    int32_t *free_index = fx_all_free(mesh, 3);
    if (bg_elastic_new(mesh, mu, lambda, &model, &err) != BG_OK ||
        bg_sparse_new(mesh, 3, free_index, (int32_t)ndof, &sys, &err) != BG_OK)
        die(&err);
    const size_t nnz = bg_sparse_nonzeros(sys);
    const int32_t n = bg_sparse_size(sys);
    double *rvalues = malloc(nnz * sizeof *rvalues);
    printf("mesh %s: %d vertices, %d tetrahedra, %zu nonzeros; %d iterations (load: see uptime)\n",
           mesh_path ? mesh_path : "generated box", (int)mesh->nv, (int)mesh->ne, nnz,
           iterations);

    /* In-process: evaluation + assembly, then factor + solve. */
    double t_eval = 0, t_factor = 0, energy = 0;
    bg_elastic_eval(model, q, grad); /* warm the rotations, as a solve's later iterations */
    for (int it = 0; it < iterations; it++) {
        double t0 = bg_clock_now();
        energy = bg_elastic_eval(model, q, grad);
        bg_sparse_zero(sys);
        bg_elastic_assemble_hessian(model, q, 1, 1.0, bg_sparse_scatter(sys),
                                    bg_sparse_values(sys));
        double t1 = bg_clock_now();
        if (bg_sparse_factorize(sys, SHIFT, &err) != BG_OK ||
            bg_sparse_solve(sys, grad, x, &err) != BG_OK)
            die(&err);
        double t2 = bg_clock_now();
        if (it > 0 || iterations == 1) { /* the first factorization includes the analysis */
            t_eval += t1 - t0;
            t_factor += t2 - t1;
        }
    }
    const int timed = iterations > 1 ? iterations - 1 : 1;
    printf("in-process              per iteration %8.2f ms (evaluation + assembly %.2f, factor + "
           "solve %.2f)\n", 1e3 * (t_eval + t_factor) / timed, 1e3 * t_eval / timed,
           1e3 * t_factor / timed);

    int failures = 0;
    bga_client_t *solver = open_agent(dir, "solve", "sparse-solve");
    if (bga_client_solve_setup(solver, 9000, n, bg_sparse_colptr(sys), bg_sparse_rowidx(sys), 0,
                               &err) != BG_OK)
        die(&err);
    const char *names[2] = {"rotfit1", "rotfit2"};
    for (int K = 1; K <= 2; K++) {
        bga_client_t *c[2] = {NULL, NULL};
        remote_part rp[2];
        memset(rp, 0, sizeof rp);
        for (int p = 0; p < K; p++) {
            c[p] = open_agent(dir, names[p], "rotation-fit");
            if (fx_part_make(mesh, q, p, K, &rp[p].part) != 0 ||
                compact_scatter(sys, nnz, &rp[p]) != 0) {
                fprintf(stderr, "bench_agents: out of memory\n");
                return 1;
            }
            bga_partition_t bp = fx_partition(&rp[p].part, mesh, mu, lambda);
            bp.nval = rp[p].nval;
            bp.scatter = rp[p].scatter;
            if (bga_client_rotfit_setup(c[p], 9100 + (uint64_t)K * 10 + (uint64_t)p, &bp, &err) !=
                BG_OK)
                die(&err);
        }
        double wall = 0, gather = 0, renergy = 0;
        bga_traffic_t before[3];
        for (int it = 0; it < iterations; it++) {
            const double t0 = bg_clock_now();
            if (it == 1 || iterations == 1) {
                for (int p = 0; p < K; p++)
                    before[p] = bga_client_traffic(c[p]);
                before[2] = bga_client_traffic(solver);
            }
            for (int p = 0; p < K; p++) {
                fx_part *pp = &rp[p].part;
                for (int32_t v = 0; v < pp->nv; v++) /* gather this iteration's positions */
                    memcpy(pp->q + (size_t)v * 3, q + (size_t)pp->local_to_global[v] * 3,
                           3 * sizeof *q);
                if (bga_client_rotfit_start(c[p], 9100 + (uint64_t)K * 10 + (uint64_t)p, pp->q,
                                            (size_t)pp->nv * 3,
                                            BGA_WANT_GRADIENT | BGA_WANT_HESSIAN |
                                                BGA_WANT_PROJECTED,
                                            &err) != BG_OK)
                    die(&err);
            }
            renergy = 0.0;
            memset(rgrad, 0, ndof * sizeof *rgrad);
            memset(rvalues, 0, nnz * sizeof *rvalues);
            for (int p = 0; p < K; p++) { /* combined in partition order */
                bga_rotfit_out_t out = {0, rp[p].grad, rp[p].hess, (size_t)rp[p].part.nv * 3,
                                        (size_t)rp[p].nval, {0, 0, 0, 0}, 0};
                if (bga_client_rotfit_finish(c[p], &out, &err) != BG_OK)
                    die(&err);
                const double g0 = bg_clock_now();
                renergy += out.energy;
                const fx_part *pp = &rp[p].part;
                for (int32_t v = 0; v < pp->nv; v++)
                    for (int k = 0; k < 3; k++)
                        rgrad[(size_t)pp->local_to_global[v] * 3 + k] += rp[p].grad[(size_t)v * 3 + k];
                for (int32_t l = 0; l < rp[p].nval; l++)
                    rvalues[rp[p].to_global[l]] += rp[p].hess[l];
                gather += it > 0 || iterations == 1 ? bg_clock_now() - g0 : 0.0;
            }
            int posdef = 0;
            if (bga_client_solve_factor(solver, 9000, rvalues, nnz, SHIFT, &posdef, &err) != BG_OK ||
                !posdef || bga_client_solve(solver, 9000, rgrad, n, 1, rx, &err) != BG_OK) {
                fprintf(stderr, "bench_agents: remote factor/solve failed: %s\n", err.message);
                return 1;
            }
            if (it > 0 || iterations == 1)
                wall += bg_clock_now() - t0;
        }
        double agent = 0, codec = 0, wait = 0;
        int64_t bytes = 0;
        for (int p = 0; p <= K; p++) {
            const bga_traffic_t now = bga_client_traffic(p < K ? c[p] : solver);
            const bga_traffic_t *b = &before[p < K ? p : 2];
            agent += now.agent_seconds - b->agent_seconds;
            codec += now.encode_seconds - b->encode_seconds;
            wait += now.wait_seconds - b->wait_seconds;
            bytes += now.bytes_sent - b->bytes_sent + now.bytes_received - b->bytes_received;
        }
        const double ediff = fabs(renergy - energy) / fabs(energy);
        double xd = 0.0;
        for (size_t i = 0; i < ndof; i++)
            if (fabs(rx[i] - x[i]) > xd)
                xd = fabs(rx[i] - x[i]);
        xd /= fx_max_abs(x, ndof);
        printf("%d rotation-fit agent%s + 1 sparse-solve: per iteration %8.2f ms = %.2f x "
               "in-process; %.2f MB; agent compute %.2f ms (summed over agents), client "
               "encode/decode %.2f, transit + queueing (wait - compute) %.2f, gather %.2f; "
               "energy rel diff %.1e, solution rel diff %.1e\n",
               K, K > 1 ? "s" : " ", 1e3 * wall / timed, wall / (t_eval + t_factor),
               bytes / 1e6 / timed, 1e3 * agent / timed, 1e3 * codec / timed,
               1e3 * (wait - agent) / timed, 1e3 * gather / timed, ediff, xd);
        /* The agents fit rotations from a cold start, the in-process run
         * from warm ones: both stop at the fit's 1e-14 skew tolerance, and
         * the shifted projected Hessian (condition ~1e5 with the rigid
         * modes held only by the 1e-3 shift) amplifies that to ~1e-10 in
         * the solution. */
        if (ediff > 1e-12 || xd > 1e-8) {
            fprintf(stderr, "bench_agents: the remote result differs from the in-process one\n");
            failures++;
        }
        for (int p = 0; p < K; p++) {
            bga_client_release(c[p], 9100 + (uint64_t)K * 10 + (uint64_t)p, &err);
            bga_client_destroy(&c[p]);
            fx_part_free(&rp[p].part);
            free(rp[p].scatter);
            free(rp[p].to_global);
            free(rp[p].grad);
            free(rp[p].hess);
        }
    }
    bga_client_release(solver, 9000, &err);
    bga_client_destroy(&solver);
    free(q);
    free(grad);
    free(rgrad);
    free(x);
    free(rx);
    free(rvalues);
    free(free_index);
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&model);
    bg_mesh_destroy(&mesh);
    return failures ? 1 : 0;
}
