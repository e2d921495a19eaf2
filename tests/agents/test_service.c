/*
 * The agent's computations without sockets (bga_service_handle on encoded
 * messages): rotation-fit partitions against bg_elastic on the whole mesh,
 * sparse-solve against an in-process CHOLMOD solve, the integration step
 * against its closed form, and the job table (slots, release, leases).
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "agent_fixture.h"
#include "bga_service.h"
#include "bga_wire.h"

/* One request through the service; the reply decoded into *rep (views
 * into *keep, which the caller frees). */
static bga_wire_code call(bga_service_t *svc, const bga_msg_t *req, double now, bga_msg_t *rep,
                          bga_frames_t *keep)
{
    bga_frames_t fr;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_wire_encode(req, &fr, &err), BG_OK);
    bga_frame_t v[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&fr, v);
    assert_int_equal(bga_service_handle(svc, v, fr.count, now, keep, &err), BG_OK);
    bga_frames_free(&fr);
    bga_frame_t rv[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(keep, rv);
    bga_wire_error_t w;
    assert_int_equal(bga_wire_decode(rv, keep->count, NULL, rep, &w), BGA_WIRE_OK);
    return rep->header.type == BGA_ERROR ? (bga_wire_code)rep->field[BGA_ERR_CODE].i : BGA_WIRE_OK;
}

static void expect_reply(bga_service_t *svc, const bga_msg_t *req, double now, uint16_t type)
{
    bga_msg_t rep;
    bga_frames_t keep;
    const bga_wire_code wc = call(svc, req, now, &rep, &keep);
    if (rep.header.type != type)
        fail_msg("%s: got %s (code %d: %.*s)", bga_type_name(req->header.type),
                 bga_type_name(rep.header.type), (int)wc,
                 rep.header.type == BGA_ERROR ? (int)rep.array[BGA_ERR_MESSAGE].count : 0,
                 rep.header.type == BGA_ERROR ? (const char *)rep.array[BGA_ERR_MESSAGE].data : "");
    bga_frames_free(&keep);
}

static void expect_code(bga_service_t *svc, const bga_msg_t *req, double now, bga_wire_code code,
                        const char *needle)
{
    bga_msg_t rep;
    bga_frames_t keep;
    const bga_wire_code wc = call(svc, req, now, &rep, &keep);
    assert_int_equal(rep.header.type, BGA_ERROR);
    char text[BG_ERROR_MESSAGE_MAX] = "";
    if (rep.array[BGA_ERR_MESSAGE].count)
        memcpy(text, rep.array[BGA_ERR_MESSAGE].data, rep.array[BGA_ERR_MESSAGE].count);
    if (wc != code || !strstr(text, needle))
        fail_msg("wanted %s '%s', got %s: %s", bga_wire_code_name(code), needle,
                 bga_wire_code_name(wc), text);
    /* The error quotes the request it answers. */
    assert_true(rep.header.seq == req->header.seq && rep.header.job == req->header.job);
    bga_frames_free(&keep);
}

static bga_service_t *service(int slots, unsigned services)
{
    bga_service_config_t cfg = {slots, services, "test", {0, 0}};
    bga_service_t *svc = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bga_service_new(&cfg, &svc, &err), BG_OK);
    return svc;
}

static void setup_msg(bga_msg_t *m, uint64_t job, const bga_partition_t *p, int64_t block,
                      int64_t nval, const int32_t *scatter)
{
    bga_msg_init(m, BGA_ROTFIT_SETUP, job, 1);
    m->field[BGA_RS_DIM].i = p->dim;
    m->field[BGA_RS_NODES].i = p->dim + 1;
    m->field[BGA_RS_NV].i = p->nv;
    m->field[BGA_RS_NE].i = p->ne;
    m->field[BGA_RS_NGLOBAL].i = p->nglobal;
    m->field[BGA_RS_MU].f = p->mu;
    m->field[BGA_RS_LAMBDA].f = p->lambda;
    m->field[BGA_RS_BLOCK].i = block;
    m->field[BGA_RS_NVAL].i = nval;
    m->field[BGA_RS_LEASE_MS].i = p->lease_ms;
    m->array[BGA_RS_ELEMENTS] = (bga_array_t){p->elements, (size_t)p->ne * (p->dim + 1)};
    m->array[BGA_RS_LOCAL_TO_GLOBAL] = (bga_array_t){p->local_to_global, (size_t)p->nv};
    m->array[BGA_RS_REST_POSITIONS] = (bga_array_t){p->rest_positions, (size_t)p->nv * p->dim};
    if (scatter)
        m->array[BGA_RS_SCATTER] = (bga_array_t){scatter, (size_t)p->ne * block};
}

#define MU 1.0
#define LAMBDA 10.0
#define NPARTS 3

/* Both Hessian layouts: per-element blocks assembled here, and the
 * agent-side scatter into the global pattern's values. */
static void test_rotfit_partitions_match_whole_mesh(void **state)
{
    (void)state;
    bg_mesh_t *mesh = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const int32_t cells[3] = {3, 2, 2};
    const double origin[3] = {0, 0, 0}, size[3] = {1.5, 1, 1};
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &mesh, &err), BG_OK);
    const int dim = 3, T = 78;
    const size_t ndof = (size_t)mesh->nv * dim;
    double *q = malloc(ndof * sizeof *q), *grad = malloc(ndof * sizeof *grad);
    double *sum_grad = calloc(ndof, sizeof *sum_grad);
    fx_deform(mesh, 0.7, q);
    bg_elastic_t *whole = NULL;
    assert_int_equal(bg_elastic_new(mesh, MU, LAMBDA, &whole, &err), BG_OK);
    const double energy = bg_elastic_eval(whole, q, grad);
    int32_t *free_index = fx_all_free(mesh, dim);
    bg_sparse_t *sys = NULL;
    assert_int_equal(bg_sparse_new(mesh, dim, free_index, (int32_t)ndof, &sys, &err), BG_OK);
    const size_t nnz = bg_sparse_nonzeros(sys);
    bg_sparse_zero(sys);
    bg_elastic_assemble_hessian(whole, q, 0, 1.0, bg_sparse_scatter(sys), bg_sparse_values(sys));
    double *H = bg_sparse_values(sys);
    double *sum_blocks = calloc(nnz, sizeof *sum_blocks), *sum_scatter = calloc(nnz, sizeof *H);
    bga_service_t *svc = service(2 * NPARTS, BGA_SERVICE_ROTFIT);
    double sum_energy = 0.0;
    for (int p = 0; p < NPARTS; p++) {
        fx_part part;
        assert_int_equal(fx_part_make(mesh, q, p, NPARTS, &part), 0);
        bga_partition_t bp = fx_partition(&part, mesh, MU, LAMBDA);
        /* Job 1+p: per-element blocks; job 100+p: scattered by the agent. */
        int32_t *sc = malloc((size_t)part.ne * T * sizeof *sc);
        for (int32_t e = 0; e < part.ne; e++)
            memcpy(sc + (size_t)e * T, bg_sparse_scatter(sys) + (size_t)part.global_elements[e] * T,
                   T * sizeof *sc);
        bga_msg_t m;
        setup_msg(&m, 1 + (uint64_t)p, &bp, T, 0, NULL);
        expect_reply(svc, &m, 0.0, BGA_ACK);
        setup_msg(&m, 100 + (uint64_t)p, &bp, T, (int64_t)nnz, sc);
        expect_reply(svc, &m, 0.0, BGA_ACK);
        for (int round = 0; round < 2; round++) {
            bga_msg_init(&m, BGA_ROTFIT_CALL, 1 + (uint64_t)p, 2);
            m.field[BGA_RC_WANT].i = BGA_WANT_GRADIENT | BGA_WANT_HESSIAN;
            m.array[BGA_RC_POSITIONS] = (bga_array_t){part.q, (size_t)part.nv * dim};
            bga_msg_t rep;
            bga_frames_t keep;
            assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
            assert_int_equal(rep.header.type, BGA_ROTFIT_RESULT);
            assert_int_equal(rep.field[BGA_RR_FITS].i, part.ne);
            /* The warm rotations stay on the agent: the first call fits
             * cold, the second (same positions) warm-starts every element. */
            if (round == 0)
                assert_int_equal(rep.field[BGA_RR_WARM].i, 0);
            else
                assert_int_equal(rep.field[BGA_RR_WARM].i, part.ne);
            if (round == 1) {
                sum_energy += rep.field[BGA_RR_ENERGY].f;
                assert_int_equal(rep.array[BGA_RR_GRADIENT].count, (size_t)part.nv * dim);
                for (int32_t v = 0; v < part.nv; v++)
                    for (int c = 0; c < dim; c++)
                        sum_grad[(size_t)part.local_to_global[v] * dim + c] +=
                            bga_msg_f64(&rep, BGA_RR_GRADIENT, (size_t)v * dim + c);
                assert_int_equal(rep.array[BGA_RR_HESSIAN].count, (size_t)part.ne * T);
                for (size_t i = 0; i < (size_t)part.ne * T; i++)
                    if (sc[i] >= 0)
                        sum_blocks[sc[i]] += bga_msg_f64(&rep, BGA_RR_HESSIAN, i);
            }
            bga_frames_free(&keep);
        }
        bga_msg_init(&m, BGA_ROTFIT_CALL, 100 + (uint64_t)p, 3);
        m.field[BGA_RC_WANT].i = BGA_WANT_HESSIAN;
        m.array[BGA_RC_POSITIONS] = (bga_array_t){part.q, (size_t)part.nv * dim};
        bga_msg_t rep;
        bga_frames_t keep;
        assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
        assert_int_equal(rep.array[BGA_RR_HESSIAN].count, nnz);
        assert_int_equal(rep.array[BGA_RR_GRADIENT].count, 0);
        for (size_t i = 0; i < nnz; i++)
            sum_scatter[i] += bga_msg_f64(&rep, BGA_RR_HESSIAN, i);
        bga_frames_free(&keep);
        free(sc);
        fx_part_free(&part);
    }
    /* Partial sums over partitions against one evaluation of the whole
     * mesh: only the order of additions differs (1e-12 relative). */
    assert_true(energy > 0.0);
    assert_true(fabs(sum_energy - energy) <= 1e-12 * energy);
    const double gmax = fx_max_abs(grad, ndof), hmax = fx_max_abs(H, nnz);
    for (size_t i = 0; i < ndof; i++)
        assert_true(fabs(sum_grad[i] - grad[i]) <= 1e-12 * gmax);
    for (size_t i = 0; i < nnz; i++) {
        assert_true(fabs(sum_blocks[i] - H[i]) <= 1e-12 * hmax);
        assert_true(fabs(sum_scatter[i] - H[i]) <= 1e-12 * hmax);
    }
    bga_service_destroy(&svc);
    free(sum_blocks);
    free(sum_scatter);
    bg_sparse_destroy(&sys);
    free(free_index);
    bg_elastic_destroy(&whole);
    free(q);
    free(grad);
    free(sum_grad);
    bg_mesh_destroy(&mesh);
}

static void test_rotfit_bad_requests(void **state)
{
    (void)state;
    bg_mesh_t *mesh = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const int32_t cells[3] = {1, 1, 1};
    const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &mesh, &err), BG_OK);
    fx_part part;
    assert_int_equal(fx_part_make(mesh, mesh->x, 0, 1, &part), 0);
    bga_partition_t bp = fx_partition(&part, mesh, MU, LAMBDA);
    bga_service_t *svc = service(2, BGA_SERVICE_ROTFIT);
    bga_msg_t m;
    bga_msg_init(&m, BGA_ROTFIT_CALL, 5, 9);
    m.field[BGA_RC_WANT].i = BGA_WANT_GRADIENT;
    m.array[BGA_RC_POSITIONS] = (bga_array_t){part.q, 3};
    expect_code(svc, &m, 0.0, BGA_WIRE_NO_JOB, "no state for job 5");
    setup_msg(&m, 5, &bp, 78, 0, NULL);
    expect_reply(svc, &m, 0.0, BGA_ACK);
    bga_msg_init(&m, BGA_ROTFIT_CALL, 5, 10);
    m.field[BGA_RC_WANT].i = BGA_WANT_GRADIENT;
    m.array[BGA_RC_POSITIONS] = (bga_array_t){part.q, 3};
    expect_code(svc, &m, 0.0, BGA_WIRE_BAD_LENGTH, "3 position values, the partition has 8");
    /* A negatively oriented element is refused, not silently reoriented
     * (the coordinator's Hessian layout depends on the node order). */
    int32_t swapped[24];
    memcpy(swapped, part.elements, sizeof swapped);
    const int32_t t = swapped[0];
    swapped[0] = swapped[1];
    swapped[1] = t;
    bp.elements = swapped;
    setup_msg(&m, 6, &bp, 78, 0, NULL);
    expect_code(svc, &m, 0.0, BGA_WIRE_INCONSISTENT, "negatively oriented");
    assert_int_equal(bga_service_jobs(svc), 1); /* the failed set-up gave its slot back */
    /* A service this agent does not sell. */
    bga_msg_init(&m, BGA_INTEG_PREDICT, 5, 11);
    expect_code(svc, &m, 0.0, BGA_WIRE_WRONG_STATE, "no integrator state");
    bga_msg_init(&m, BGA_ROTFIT_RESULT, 5, 12);
    expect_code(svc, &m, 0.0, BGA_WIRE_UNEXPECTED, "is a reply");
    bga_service_destroy(&svc);
    /* Per-element blocks that could never fit a reply frame are refused
     * before anything is allocated for them (6 tets x 78 x 8 > 2048). */
    bga_service_config_t small = {1, BGA_SERVICE_ROTFIT, "small", {2048, 1 << 20}};
    bg_error_t err2 = BG_ERROR_INIT;
    assert_int_equal(bga_service_new(&small, &svc, &err2), BG_OK);
    bp.elements = part.elements;
    setup_msg(&m, 8, &bp, 78, 0, NULL);
    expect_code(svc, &m, 0.0, BGA_WIRE_OUT_OF_RANGE, "exceed the 2048-byte frame cap");
    assert_int_equal(bga_service_jobs(svc), 0);
    bga_service_destroy(&svc);
    svc = service(1, BGA_SERVICE_SOLVE);
    setup_msg(&m, 5, &bp, 78, 0, NULL);
    expect_code(svc, &m, 0.0, BGA_WIRE_UNEXPECTED, "does not serve rotation-fit");
    bga_service_destroy(&svc);
    fx_part_free(&part);
    bg_mesh_destroy(&mesh);
}

/* A box of the given cells and size, deformed by fx_deform(amount), its
 * elastic model evaluated there and the (unassembled) Newton system of all
 * its unknowns: what the sparse-solve tests factor on an agent and in
 * process. box_system_free releases all of it. */
typedef struct box_system {
    bg_mesh_t *mesh;
    double *q;
    bg_elastic_t *model;
    int32_t *free_index;
    bg_sparse_t *sys;
} box_system_t;

static void box_system_new(const int32_t cells[3], const double size[3], double amount,
                           box_system_t *b)
{
    bg_error_t err = BG_ERROR_INIT;
    const double origin[3] = {0, 0, 0};
    memset(b, 0, sizeof *b);
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &b->mesh, &err), BG_OK);
    const size_t ndof = (size_t)b->mesh->nv * 3;
    b->q = malloc(ndof * sizeof *b->q);
    assert_non_null(b->q);
    fx_deform(b->mesh, amount, b->q);
    assert_int_equal(bg_elastic_new(b->mesh, MU, LAMBDA, &b->model, &err), BG_OK);
    bg_elastic_eval(b->model, b->q, NULL);
    b->free_index = fx_all_free(b->mesh, 3);
    assert_int_equal(bg_sparse_new(b->mesh, 3, b->free_index, (int32_t)ndof, &b->sys, &err),
                     BG_OK);
}

static void box_system_free(box_system_t *b)
{
    bg_sparse_destroy(&b->sys);
    free(b->free_index);
    bg_elastic_destroy(&b->model);
    free(b->q);
    bg_mesh_destroy(&b->mesh);
}

static void test_sparse_solve_matches_cholmod(void **state)
{
    (void)state;
    const int32_t cells[3] = {3, 3, 2};
    const double size[3] = {1, 1, 1};
    box_system_t box;
    box_system_new(cells, size, 0.3, &box);
    bg_error_t err = BG_ERROR_INIT;
    double *q = box.q;
    bg_elastic_t *model = box.model;
    bg_sparse_t *local = box.sys;
    bg_sparse_zero(local);
    bg_elastic_assemble_hessian(model, q, 1, 1.0, bg_sparse_scatter(local),
                                bg_sparse_values(local));
    const int32_t n = bg_sparse_size(local);
    const size_t nnz = bg_sparse_nonzeros(local);
    const double shift = 0.5; /* the projected Hessian is singular (rigid modes) */
    double *rhs = malloc(2 * (size_t)n * sizeof *rhs), *x = malloc(2 * (size_t)n * sizeof *x);
    for (int32_t i = 0; i < 2 * n; i++)
        rhs[i] = sin(0.37 * i) + (i % 5 == 0 ? 1.0 : 0.0);
    bga_service_t *svc = service(1, BGA_SERVICE_SOLVE);
    bga_msg_t m;
    bga_msg_init(&m, BGA_SOLVE_SETUP, 7, 1);
    m.field[BGA_SS_N].i = n;
    m.field[BGA_SS_NNZ].i = (int64_t)nnz;
    m.array[BGA_SS_COLPTR] = (bga_array_t){bg_sparse_colptr(local), (size_t)n + 1};
    m.array[BGA_SS_ROWIDX] = (bga_array_t){bg_sparse_rowidx(local), nnz};
    expect_reply(svc, &m, 0.0, BGA_ACK);
    bga_msg_init(&m, BGA_SOLVE_RHS, 7, 2);
    m.field[BGA_SR_NRHS].i = 1;
    m.array[BGA_SR_RHS] = (bga_array_t){rhs, (size_t)n};
    expect_code(svc, &m, 0.0, BGA_WIRE_WRONG_STATE, "before a successful factorization");
    /* Two factorizations on the kept analysis (the second at new values),
     * each followed by a two-column solve. */
    for (int round = 0; round < 2; round++) {
        if (round == 1) {
            double *vals = bg_sparse_values(local);
            for (size_t i = 0; i < nnz; i++)
                vals[i] *= 1.5;
        }
        bga_msg_init(&m, BGA_SOLVE_FACTOR, 7, 3);
        m.field[BGA_SF_SHIFT].f = shift;
        m.array[BGA_SF_VALUES] = (bga_array_t){bg_sparse_values(local), nnz};
        bga_msg_t rep;
        bga_frames_t keep;
        assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
        assert_int_equal(rep.header.type, BGA_SOLVE_FACTORED);
        assert_int_equal(rep.field[BGA_SD_POSDEF].i, 1);
        if (round == 0)
            assert_true(rep.field[BGA_SD_ANALYZE_SECONDS].f > 0.0);
        else
            assert_true(rep.field[BGA_SD_ANALYZE_SECONDS].f == 0.0); /* analysed once */
        bga_frames_free(&keep);
        bga_msg_init(&m, BGA_SOLVE_RHS, 7, 4);
        m.field[BGA_SR_NRHS].i = 2;
        m.array[BGA_SR_RHS] = (bga_array_t){rhs, 2 * (size_t)n};
        assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
        assert_int_equal(rep.array[BGA_SX_X].count, 2 * (size_t)n);
        bga_msg_copy_f64(&rep, BGA_SX_X, x);
        bga_frames_free(&keep);
        assert_int_equal(bg_sparse_factorize(local, shift, &err), BG_OK);
        double *ref = malloc((size_t)n * sizeof *ref), *Ax = malloc((size_t)n * sizeof *Ax);
        for (int r = 0; r < 2; r++) {
            assert_int_equal(bg_sparse_solve(local, rhs + (size_t)r * n, ref, &err), BG_OK);
            const double xmax = fx_max_abs(ref, (size_t)n);
            for (int32_t i = 0; i < n; i++)
                assert_true(fabs(x[(size_t)r * n + i] - ref[i]) <= 1e-12 * xmax);
            /* Independently: the residual of (A + shift I) x = b. */
            bg_sparse_multiply(local, x + (size_t)r * n, Ax);
            double res = 0.0, bn = 0.0;
            for (int32_t i = 0; i < n; i++) {
                const double d = Ax[i] + shift * x[(size_t)r * n + i] - rhs[(size_t)r * n + i];
                res += d * d;
                bn += rhs[(size_t)r * n + i] * rhs[(size_t)r * n + i];
            }
            assert_true(sqrt(res) <= 1e-9 * sqrt(bn));
        }
        free(ref);
        free(Ax);
    }
    /* A failed factorization: reported with the in-process verdict on the
     * same values (an all-zero matrix has a zero pivot in either of
     * CHOLMOD's LLᵀ and LDLᵀ paths), and the stale factor is not used. */
    double *neg = calloc(nnz, sizeof *neg);
    bga_msg_init(&m, BGA_SOLVE_FACTOR, 7, 5);
    m.array[BGA_SF_VALUES] = (bga_array_t){neg, nnz};
    bga_msg_t rep;
    bga_frames_t keep;
    if (call(svc, &m, 0.0, &rep, &keep) != BGA_WIRE_OK)
        fail_msg("%.*s", (int)rep.array[BGA_ERR_MESSAGE].count,
                 (const char *)rep.array[BGA_ERR_MESSAGE].data);
    memcpy(bg_sparse_values(local), neg, nnz * sizeof *neg);
    bg_error_t ferr = BG_ERROR_INIT;
    assert_int_equal(bg_sparse_factorize(local, 0.0, &ferr), BG_ERR_NUMERIC);
    assert_int_equal(rep.field[BGA_SD_POSDEF].i, 0);
    assert_true(rep.array[BGA_SD_MESSAGE].count > 0);
    bga_frames_free(&keep);
    bga_msg_init(&m, BGA_SOLVE_RHS, 7, 6);
    m.field[BGA_SR_NRHS].i = 1;
    m.array[BGA_SR_RHS] = (bga_array_t){rhs, (size_t)n};
    expect_code(svc, &m, 0.0, BGA_WIRE_WRONG_STATE, "before a successful factorization");
    bga_msg_init(&m, BGA_SOLVE_FACTOR, 7, 7);
    m.array[BGA_SF_VALUES] = (bga_array_t){neg, nnz - 1};
    expect_code(svc, &m, 0.0, BGA_WIRE_BAD_LENGTH, "values for a pattern of");
    free(neg);
    bga_service_destroy(&svc);
    free(rhs);
    free(x);
    box_system_free(&box);
}

/*
 * A pattern the coordinator reordered (bg_sparse_reorder) and sent with
 * BGA_SOLVE_ORDERED: the agent keeps its order, so its factor is the
 * in-process one (the same cost model) and its solutions, with the
 * right-hand sides permuted as the agents' backend permutes them, are the
 * in-process bg_sparse_solve_many's bit for bit. An agent that ignored the
 * option would analyse the reordered pattern afresh (its own fill-reducing
 * order of it) and miss both.
 */
static void test_sparse_solve_ordered_bit_for_bit(void **state)
{
    (void)state;
    const int32_t cells[3] = {6, 5, 4};
    const double size[3] = {1.2, 1, 0.8};
    box_system_t box;
    box_system_new(cells, size, 0.4, &box);
    bg_error_t err = BG_ERROR_INIT;
    double *q = box.q;
    bg_elastic_t *model = box.model;
    bg_sparse_t *local = box.sys;
    assert_int_equal(bg_sparse_reorder(local, &err), BG_OK);
    const int32_t *perm = bg_sparse_permutation(local);
    assert_non_null(perm);
    int moved = 0;
    for (int32_t k = 0; k < bg_sparse_size(local); k++)
        moved += perm[k] != k;
    assert_true(moved > 0); /* a real renumbering, or the test shows nothing */
    bg_sparse_zero(local);
    bg_elastic_assemble_hessian(model, q, 1, 1.0, bg_sparse_scatter(local),
                                bg_sparse_values(local));
    const int32_t n = bg_sparse_size(local);
    const size_t nnz = bg_sparse_nonzeros(local);
    const double shift = 0.25;
    double *rhs = malloc(2 * (size_t)n * sizeof *rhs), *ref = malloc(2 * (size_t)n * sizeof *ref);
    double *stored = malloc(2 * (size_t)n * sizeof *stored), *x = malloc(2 * (size_t)n * sizeof *x);
    for (int32_t i = 0; i < 2 * n; i++)
        rhs[i] = cos(0.29 * i) + (i % 7 == 0 ? 0.5 : 0.0);
    for (int c = 0; c < 2; c++)
        for (int32_t k = 0; k < n; k++)
            stored[(size_t)c * n + k] = rhs[(size_t)c * n + perm[k]];
    bga_service_t *svc = service(1, BGA_SERVICE_SOLVE);
    bga_msg_t m, rep;
    bga_frames_t keep;
    bga_msg_init(&m, BGA_SOLVE_SETUP, 8, 1);
    m.field[BGA_SS_N].i = n;
    m.field[BGA_SS_NNZ].i = (int64_t)nnz;
    m.field[BGA_SS_OPTIONS].i = BGA_SOLVE_ORDERED;
    m.array[BGA_SS_COLPTR] = (bga_array_t){bg_sparse_colptr(local), (size_t)n + 1};
    m.array[BGA_SS_ROWIDX] = (bga_array_t){bg_sparse_rowidx(local), nnz};
    expect_reply(svc, &m, 0.0, BGA_ACK);
    bga_msg_init(&m, BGA_SOLVE_FACTOR, 8, 2);
    m.field[BGA_SF_SHIFT].f = shift;
    m.array[BGA_SF_VALUES] = (bga_array_t){bg_sparse_values(local), nnz};
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.header.type, BGA_SOLVE_FACTORED);
    assert_int_equal(rep.field[BGA_SD_POSDEF].i, 1);
    assert_true(rep.field[BGA_SD_FLOPS].f == bg_sparse_factor_flops(local));
    assert_true(rep.field[BGA_SD_FACTOR_NONZEROS].f == bg_sparse_factor_nonzeros(local));
    bga_frames_free(&keep);
    bga_msg_init(&m, BGA_SOLVE_RHS, 8, 3);
    m.field[BGA_SR_NRHS].i = 2;
    m.array[BGA_SR_RHS] = (bga_array_t){stored, 2 * (size_t)n};
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.array[BGA_SX_X].count, 2 * (size_t)n);
    bga_msg_copy_f64(&rep, BGA_SX_X, stored);
    bga_frames_free(&keep);
    for (int c = 0; c < 2; c++)
        for (int32_t k = 0; k < n; k++)
            x[(size_t)c * n + perm[k]] = stored[(size_t)c * n + k];
    assert_int_equal(bg_sparse_factorize(local, shift, &err), BG_OK);
    assert_int_equal(bg_sparse_solve_many(local, 2, rhs, ref, &err), BG_OK);
    assert_memory_equal(x, ref, 2 * (size_t)n * sizeof *x);
    bga_service_destroy(&svc);
    free(rhs);
    free(ref);
    free(stored);
    free(x);
    box_system_free(&box);
}

static void test_integration_step_closed_form(void **state)
{
    (void)state;
    const double h = 0.1, gamma = 0.3;
    const double mass[2] = {2.0, 4.0};
    const double q0[4] = {0, 0, 1, 1}, v0[4] = {1, -1, 0, 2}, zero[4] = {0, 0, 0, 0};
    const int32_t free4[4] = {0, 0, 0, 0};
    double p0[4];
    for (int i = 0; i < 4; i++)
        p0[i] = mass[i / 2] * v0[i];
    bga_service_t *svc = service(1, BGA_SERVICE_INTEG);
    bga_msg_t m, rep;
    bga_frames_t keep;
    bga_msg_init(&m, BGA_INTEG_SETUP, 3, 1);
    m.field[BGA_IS_DIM].i = 2;
    m.field[BGA_IS_NV].i = 2;
    m.field[BGA_IS_H].f = h;
    m.field[BGA_IS_DAMPING].f = gamma;
    m.array[BGA_IS_MASS] = (bga_array_t){mass, 2};
    m.array[BGA_IS_Q] = (bga_array_t){q0, 4};
    m.array[BGA_IS_VELOCITY] = (bga_array_t){v0, 4};
    m.array[BGA_IS_T0] = (bga_array_t){q0, 4};
    m.array[BGA_IS_CONSTRAINED] = (bga_array_t){free4, 4};
    m.array[BGA_IS_GRAVITY] = (bga_array_t){zero, 2};
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.header.type, BGA_INTEG_STATE);
    double k0 = 0.0;
    for (int i = 0; i < 4; i++)
        k0 += 0.5 * p0[i] * p0[i] / mass[i / 2];
    assert_true(fabs(rep.field[BGA_IT_KINETIC].f - k0) <= 1e-14 * k0);
    assert_int_equal(rep.field[BGA_IT_STEPS].i, 0);
    bga_frames_free(&keep);
    /* An accept before any trial is refused: the state expects a predict. */
    bga_msg_init(&m, BGA_INTEG_ACCEPT, 3, 2);
    expect_code(svc, &m, 0.0, BGA_WIRE_WRONG_STATE, "accept while ready for a new step");
    bga_msg_init(&m, BGA_INTEG_PREDICT, 3, 3);
    m.field[BGA_IP_VARIATIONAL].i = 1;
    m.field[BGA_IP_TRIAL].i = 1;
    m.array[BGA_IP_T1] = (bga_array_t){q0, 4};
    expect_code(svc, &m, 0.0, BGA_WIRE_WRONG_STATE, "redo while ready");
    m.field[BGA_IP_TRIAL].i = 0;
    m.field[BGA_IP_PREDICTOR].i = 1; /* the last positions: one candidate, q_k */
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.header.type, BGA_INTEG_INERTIA);
    assert_true(fabs(rep.field[BGA_II_COEF].f - 4.0 / (h * h)) <= 1e-12 * 400.0);
    assert_int_equal(rep.field[BGA_II_NCAND].i, 1);
    double pred[4];
    for (int i = 0; i < 4; i++) {
        pred[i] = q0[i] + 0.5 * h * p0[i] / mass[i / 2];
        assert_true(fabs(bga_msg_f64(&rep, BGA_II_PREDICT, (size_t)i) - pred[i]) <= 1e-15);
        assert_true(bga_msg_f64(&rep, BGA_II_CANDIDATES, (size_t)i) == q0[i]);
    }
    /* No gravity: the state's force scale is (2/h)|p|. */
    const double pn = sqrt(p0[0] * p0[0] + p0[1] * p0[1] + p0[2] * p0[2] + p0[3] * p0[3]);
    assert_true(fabs(rep.field[BGA_II_STATE_SCALE].f - 2.0 / h * pn) <= 1e-13 * pn / h);
    bga_frames_free(&keep);
    /* With a constant force f = −∇W the minimiser of the step energy is
     * q* = prediction + (h²/4) M⁻¹ f; the midpoint update then gives
     * q1 = q0 + h M⁻¹ p0 + (h²/2) M⁻¹ f and p1 = e^{−γh}(p0 + h f). */
    const double f[4] = {1, 0, -3, 2};
    double qs[4], g[4];
    for (int i = 0; i < 4; i++) {
        qs[i] = pred[i] + 0.25 * h * h * f[i] / mass[i / 2];
        g[i] = -f[i];
    }
    bga_msg_init(&m, BGA_INTEG_UPDATE, 3, 4);
    m.array[BGA_IU_QSTAR] = (bga_array_t){qs, 2};
    m.array[BGA_IU_GRAD] = (bga_array_t){g, 2};
    expect_code(svc, &m, 0.0, BGA_WIRE_BAD_LENGTH, "2 values, the state has 4");
    m.array[BGA_IU_QSTAR] = (bga_array_t){qs, 4};
    m.array[BGA_IU_GRAD] = (bga_array_t){g, 4};
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.header.type, BGA_INTEG_TRIAL);
    double q1[4], kt = 0.0, k1 = 0.0, lin[2] = {0, 0};
    for (int i = 0; i < 4; i++) {
        q1[i] = q0[i] + h * p0[i] / mass[i / 2] + 0.5 * h * h * f[i] / mass[i / 2];
        const double pt = p0[i] + h * f[i], p1 = exp(-gamma * h) * pt;
        assert_true(fabs(bga_msg_f64(&rep, BGA_IR_QNEXT, (size_t)i) - q1[i]) <= 1e-13);
        kt += 0.5 * pt * pt / mass[i / 2];
        k1 += 0.5 * p1 * p1 / mass[i / 2];
        lin[i % 2] += p1;
    }
    assert_true(fabs(rep.field[BGA_IR_KINETIC].f - kt) <= 1e-12 * kt);
    assert_true(rep.field[BGA_IR_WORK].f == 0.0); /* no constrained coordinate */
    bga_frames_free(&keep);
    bga_msg_init(&m, BGA_INTEG_ACCEPT, 3, 5);
    assert_int_equal(call(svc, &m, 0.0, &rep, &keep), BGA_WIRE_OK);
    assert_int_equal(rep.header.type, BGA_INTEG_STATE);
    assert_int_equal(rep.field[BGA_IT_STEPS].i, 1);
    assert_true(fabs(rep.field[BGA_IT_KINETIC].f - k1) <= 1e-12 * k1);
    assert_true(fabs(rep.field[BGA_IT_LINEAR_X].f - lin[0]) <= 1e-13);
    assert_true(fabs(rep.field[BGA_IT_LINEAR_Y].f - lin[1]) <= 1e-13);
    for (int i = 0; i < 4; i++)
        assert_true(fabs(bga_msg_f64(&rep, BGA_IT_Q, (size_t)i) - q1[i]) <= 1e-13);
    bga_frames_free(&keep);
    bga_service_destroy(&svc);
}

static void integ_setup(bga_msg_t *m, uint64_t job, int64_t lease_ms)
{
    static const double mass[1] = {1.0}, zero[2] = {0.0, 0.0};
    static const int32_t none[2] = {0, 0};
    bga_msg_init(m, BGA_INTEG_SETUP, job, 1);
    m->field[BGA_IS_DIM].i = 2;
    m->field[BGA_IS_NV].i = 1;
    m->field[BGA_IS_H].f = 0.01;
    m->field[BGA_IS_LEASE_MS].i = lease_ms;
    m->array[BGA_IS_MASS] = (bga_array_t){mass, 1};
    m->array[BGA_IS_Q] = (bga_array_t){zero, 2};
    m->array[BGA_IS_VELOCITY] = (bga_array_t){zero, 2};
    m->array[BGA_IS_T0] = (bga_array_t){zero, 2};
    m->array[BGA_IS_CONSTRAINED] = (bga_array_t){none, 2};
    m->array[BGA_IS_GRAVITY] = (bga_array_t){zero, 2};
}

static void test_slots_release_and_leases(void **state)
{
    (void)state;
    bga_service_t *svc = service(2, BGA_SERVICE_INTEG);
    bga_msg_t m;
    integ_setup(&m, 1, 0);
    expect_reply(svc, &m, 0.0, BGA_INTEG_STATE);
    integ_setup(&m, 2, 1000);
    expect_reply(svc, &m, 0.0, BGA_INTEG_STATE);
    integ_setup(&m, 3, 0);
    expect_code(svc, &m, 0.0, BGA_WIRE_BUSY, "no free slot: 2 of 2");
    integ_setup(&m, 0, 0);
    expect_code(svc, &m, 0.0, BGA_WIRE_OUT_OF_RANGE, "job id 0 is reserved");
    bga_msg_init(&m, BGA_RELEASE, 1, 5);
    expect_reply(svc, &m, 0.0, BGA_ACK);
    assert_int_equal(bga_service_jobs(svc), 1);
    bga_msg_init(&m, BGA_INTEG_PREDICT, 1, 6);
    expect_code(svc, &m, 0.0, BGA_WIRE_NO_JOB, "no state for job 1");
    /* Job 2's lease (1 s) is renewed by a heartbeat naming it at 0.8 s,
     * so it is alive at 1.6 s and gone at 2.9 s. */
    bga_msg_init(&m, BGA_HEARTBEAT, 2, 7);
    expect_reply(svc, &m, 0.8, BGA_HEARTBEAT);
    assert_int_equal(bga_service_expire(svc, 1.6), 0);
    assert_int_equal(bga_service_jobs(svc), 1);
    assert_int_equal(bga_service_expire(svc, 2.9), 1);
    assert_int_equal(bga_service_jobs(svc), 0);
    bga_msg_init(&m, BGA_INTEG_PREDICT, 2, 8);
    expect_code(svc, &m, 3.0, BGA_WIRE_NO_JOB, "lease expired");
    assert_int_equal(bga_service_stats(svc).expired, 1);
    assert_int_equal(bga_service_stats(svc).released, 1);
    bga_service_destroy(&svc);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rotfit_partitions_match_whole_mesh),
        cmocka_unit_test(test_rotfit_bad_requests),
        cmocka_unit_test(test_sparse_solve_matches_cholmod),
        cmocka_unit_test(test_sparse_solve_ordered_bit_for_bit),
        cmocka_unit_test(test_integration_step_closed_form),
        cmocka_unit_test(test_slots_release_and_leases),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
