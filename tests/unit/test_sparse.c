/*
 * bg_sparse: several right-hand sides in one solve give what one solve per
 * column gives, on a supernodal and on a simplicial factor, wider and then
 * narrower calls reuse the workspace, and bg_sparse_prefer_solves keeps
 * CHOLMOD's choice of factor kind. A Hessian stored in its factor's order
 * (bg_sparse_reorder) is the same matrix as one assembled in the unknowns' own order, applies
 * as the finite differences of the gradient do, and solves, multiplies and
 * takes a diagonal in the caller's numbering. Its vertex-block map gives
 * the entry scatter map's values to the bit. A supernodal solve-heavy
 * factor's own triangular solves equal CHOLMOD's solve of the same matrix
 * (its own simplicial factor in another ordering) to a few ulps of the
 * condition number, and give a column the same bits alone or in a block.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cholmod.h>
#include <cmocka.h>
#include <math.h>

#include "bg_elastic.h"
#include "bg_mesh.h"
#include "bg_sparse.h"
#include "test_support.h"

/* The scalar cotan Laplacian of a cells[0]×cells[1]×cells[2] box with its
 * bottom layer of vertices held: a solve-heavy system of the kind
 * local/global factors once. Caller destroys both. */
static bg_sparse_t *laplacian(const int32_t cells[3], int prefer, bg_mesh_t **mesh)
{
    const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, mesh, NULL), BG_OK);
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(*mesh, 1.0, 1.0, &md, NULL), BG_OK);
    int32_t *index = malloc(sizeof *index * (size_t)(*mesh)->nv);
    int32_t count = 0;
    for (int32_t v = 0; v < (*mesh)->nv; v++)
        index[v] = (*mesh)->x[3 * (size_t)v + 2] == 0.0 ? -1 : count++;
    bg_sparse_t *sys = NULL;
    assert_int_equal(bg_sparse_new(*mesh, 1, index, count, &sys, NULL), BG_OK);
    if (prefer)
        bg_sparse_prefer_solves(sys);
    bg_sparse_zero(sys);
    bg_elastic_assemble_scalar_laplacian(md, 3.0, bg_sparse_scatter(sys), bg_sparse_values(sys));
    assert_int_equal(bg_sparse_supernodal(sys), -1);
    assert_int_equal(bg_sparse_factorize(sys, 0.0, NULL), BG_OK);
    free(index);
    bg_elastic_destroy(&md);
    return sys;
}

/* Three columns at once against one at a time: both factor kinds solve
 * each column by the same substitutions, a block merely reorders the
 * BLAS work, so they agree to a few ulps of the solution (1e-13
 * relative), and each column solves A x = b to round-off (residual 1e-12
 * of |b|). Then one column again: the wide workspace is reshaped. */
static void check_columns(bg_sparse_t *sys)
{
    const int32_t n = bg_sparse_size(sys);
    double *b = malloc(sizeof *b * 3 * (size_t)n), *x = malloc(sizeof *x * 3 * (size_t)n);
    double *one = malloc(sizeof *one * (size_t)n), *r = malloc(sizeof *r * (size_t)n);
    uint64_t rng = 17;
    for (size_t i = 0; i < 3 * (size_t)n; i++)
        b[i] = 2 * test_uniform(&rng) - 1;
    assert_int_equal(bg_sparse_solve_many(sys, 3, b, x, NULL), BG_OK);
    for (int k = 0; k < 3; k++) {
        assert_int_equal(bg_sparse_solve(sys, b + (size_t)k * n, one, NULL), BG_OK);
        double diff = 0.0, size = 0.0, res = 0.0, bn = 0.0;
        bg_sparse_multiply(sys, x + (size_t)k * n, r);
        for (int32_t i = 0; i < n; i++) {
            diff = fmax(diff, fabs(one[i] - x[(size_t)k * n + i]));
            size = fmax(size, fabs(one[i]));
            res = fmax(res, fabs(r[i] - b[(size_t)k * n + i]));
            bn = fmax(bn, fabs(b[(size_t)k * n + i]));
        }
        assert_true(diff <= 1e-13 * size);
        assert_true(res <= 1e-12 * bn);
    }
    /* in place, and an out-of-range count refused */
    memcpy(x, b, sizeof *x * 2 * (size_t)n);
    assert_int_equal(bg_sparse_solve_many(sys, 2, x, x, NULL), BG_OK);
    assert_int_equal(bg_sparse_solve(sys, b + n, one, NULL), BG_OK);
    for (int32_t i = 0; i < n; i++)
        assert_true(fabs(one[i] - x[(size_t)n + i]) <= 1e-13 * (1.0 + fabs(one[i])));
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_sparse_solve_many(sys, 0, b, x, &err), BG_ERR_INVALID);
    assert_int_equal(bg_sparse_solve_many(sys, BG_SPARSE_MAX_RHS + 1, b, x, &err), BG_ERR_INVALID);
    free(b);
    free(x);
    free(one);
    free(r);
}

/* A 9³ box: flops per nonzero over CHOLMOD's switch of 40, so its factor
 * is supernodal whether or not the system prefers solves (the flag picks
 * the solve kernels, not the factor kind), and the columns check holds
 * through CHOLMOD's solve (default) and bg_sparse's own (prefer); a 16³
 * box's the same with the flag; a 4³ box's, under the switch, simplicial
 * with it. */
static void factor_kinds(void **state)
{
    (void)state;
    const int32_t tiny[3] = {4, 4, 4}, small[3] = {9, 9, 9}, large[3] = {16, 16, 16};
    for (int prefer = 0; prefer <= 1; prefer++) {
        bg_mesh_t *mesh = NULL;
        bg_sparse_t *sys = laplacian(small, prefer, &mesh);
        const double ratio = bg_sparse_factor_flops(sys) / bg_sparse_factor_nonzeros(sys);
        print_message("  9^3 box, prefer_solves %d: flops/nnz %.1f, %s\n", prefer, ratio,
                      bg_sparse_supernodal(sys) ? "supernodal" : "simplicial");
        assert_true(ratio > 40.0);
        assert_int_equal(bg_sparse_prefers_solves(sys), prefer);
        assert_int_equal(bg_sparse_supernodal(sys), 1);
        check_columns(sys);
        bg_sparse_destroy(&sys);
        bg_mesh_destroy(&mesh);
    }
    for (int big = 0; big <= 1; big++) {
        bg_mesh_t *mesh = NULL;
        bg_sparse_t *sys = laplacian(big ? large : tiny, 1, &mesh);
        const double ratio = bg_sparse_factor_flops(sys) / bg_sparse_factor_nonzeros(sys);
        print_message("  %s box, prefer_solves 1: flops/nnz %.1f, %s\n", big ? "16^3" : "4^3",
                      ratio, bg_sparse_supernodal(sys) ? "supernodal" : "simplicial");
        assert_true(big ? ratio > 40.0 : ratio < 40.0);
        assert_int_equal(bg_sparse_supernodal(sys), big);
        check_columns(sys);
        bg_sparse_destroy(&sys);
        bg_mesh_destroy(&mesh);
    }
}

/* A deformed box's Hessian, assembled twice through the scatter maps of
 * two systems on the same unknowns: one in the unknowns' own order, one
 * reordered. Constrained: every coordinate of the bottom layer and the x
 * coordinate of the top layer, so the free set is irregular. */
static void reordered_hessian(void **state)
{
    (void)state;
    const int32_t cells[3] = {5, 4, 3};
    const double origin[3] = {0, 0, 0}, size[3] = {1.0, 0.8, 0.6};
    bg_mesh_t *mesh = NULL;
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &mesh, NULL), BG_OK);
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(mesh, 1.0, 4.0, &md, NULL), BG_OK);
    const size_t ndof = 3 * (size_t)mesh->nv;
    int32_t *index = malloc(sizeof *index * ndof);
    double *q = malloc(sizeof *q * ndof), *qp = malloc(sizeof *qp * ndof);
    double *gp = malloc(sizeof *gp * ndof), *gm = malloc(sizeof *gm * ndof);
    int32_t n = 0;
    uint64_t rng = 29;
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *x = mesh->x + 3 * (size_t)v;
        for (int c = 0; c < 3; c++) {
            const size_t i = 3 * (size_t)v + c;
            index[i] = x[2] == 0.0 || (c == 0 && x[2] == size[2]) ? -1 : n++;
            /* a shear and a stretch, plus noise of a tenth of a cell */
            q[i] = x[c] + (c == 0 ? 0.3 * x[2] : c == 2 ? 0.2 * x[2] : 0.0) +
                   0.02 * (2 * test_uniform(&rng) - 1);
        }
    }
    bg_sparse_t *plain = NULL, *sys = NULL;
    assert_int_equal(bg_sparse_new(mesh, 3, index, n, &plain, NULL), BG_OK);
    assert_int_equal(bg_sparse_new(mesh, 3, index, n, &sys, NULL), BG_OK);
    assert_int_equal(bg_sparse_reorder(sys, NULL), BG_OK);
    assert_null(bg_sparse_permutation(plain));
    const int32_t *perm = bg_sparse_permutation(sys);
    assert_non_null(perm);
    assert_int_equal(bg_sparse_nonzeros(sys), bg_sparse_nonzeros(plain));
    /* perm is a permutation */
    char *seen = calloc((size_t)n, 1);
    for (int32_t k = 0; k < n; k++) {
        assert_true(perm[k] >= 0 && perm[k] < n && !seen[perm[k]]);
        seen[perm[k]] = 1;
    }
    free(seen);
    const int32_t *Bp = bg_sparse_colptr(sys), *Bi = bg_sparse_rowidx(sys);
    for (int32_t k = 0; k < n; k++) { /* lower triangle, rows increasing from the diagonal */
        assert_int_equal(Bi[Bp[k]], k);
        for (int32_t t = Bp[k] + 1; t < Bp[k + 1]; t++)
            assert_true(Bi[t] > Bi[t - 1] && Bi[t] < n);
    }
    bg_elastic_eval(md, q, gp);
    for (int project = 0; project <= 1; project++) {
        bg_sparse_zero(plain);
        bg_sparse_zero(sys);
        bg_elastic_assemble_hessian(md, q, project, 1.0, bg_sparse_scatter(plain),
                                    bg_sparse_values(plain));
        bg_elastic_assemble_hessian(md, q, project, 1.0, bg_sparse_scatter(sys),
                                    bg_sparse_values(sys));
        /* Entry by entry: (r, k) of the reordered matrix is (perm r, perm k)
         * of the plain one, to the bit (the same contributions summed in
         * the same element order). */
        const int32_t *Ap = bg_sparse_colptr(plain), *Ai = bg_sparse_rowidx(plain);
        const double *Ax = bg_sparse_values(plain), *Bx = bg_sparse_values(sys);
        for (int32_t k = 0; k < n; k++)
            for (int32_t t = Bp[k]; t < Bp[k + 1]; t++) {
                int32_t i = perm[Bi[t]], j = perm[k];
                if (i < j) {
                    const int32_t tmp = i;
                    i = j;
                    j = tmp;
                }
                int32_t u = Ap[j];
                while (u < Ap[j + 1] && Ai[u] != i)
                    u++;
                assert_true(u < Ap[j + 1]);
                assert_true(Ax[u] == Bx[t]);
            }
        /* The exact Hessian against central differences of the gradient
         * along a random free direction: truncation O(h²) and round-off
         * O(ε|∇E|/h) are both ~1e-10 of |H v| at h = 1e-5, so 1e-6 leaves
         * room without hiding a wrong entry (one is O(1) of |H v|). */
        double *v = malloc(sizeof *v * (size_t)n), *hv = malloc(sizeof *hv * (size_t)n);
        for (int32_t k = 0; k < n; k++)
            v[k] = 2 * test_uniform(&rng) - 1;
        bg_sparse_multiply(sys, v, hv);
        if (!project) {
            const double h = 1e-5;
            for (int sign = 0; sign < 2; sign++) {
                for (size_t i = 0; i < ndof; i++)
                    qp[i] = q[i] + (index[i] >= 0 ? (sign ? -h : h) * v[index[i]] : 0.0);
                bg_elastic_eval(md, qp, sign ? gm : gp);
            }
            double diff = 0.0, norm = 0.0;
            for (size_t i = 0; i < ndof; i++)
                if (index[i] >= 0) {
                    const double fd = (gp[i] - gm[i]) / (2 * h);
                    diff = fmax(diff, fabs(fd - hv[index[i]]));
                    norm = fmax(norm, fabs(hv[index[i]]));
                }
            print_message("  exact Hessian against finite differences: %.2e of %.2e\n", diff,
                          norm);
            assert_true(diff <= 1e-6 * norm);
            bg_elastic_eval(md, q, gp); /* the rotations back at q */
        }
        /* The same product from the plain system. */
        double *hv0 = malloc(sizeof *hv0 * (size_t)n);
        bg_sparse_multiply(plain, v, hv0);
        for (int32_t k = 0; k < n; k++)
            assert_true(fabs(hv0[k] - hv[k]) <= 1e-13 * (1.0 + fabs(hv0[k])));
        /* A diagonal in the caller's numbering, then solves (the projected
         * Hessian plus a positive diagonal is positive definite): residuals
         * from the plain system's product, 1e-10 of |b| (the matrix's
         * condition number here is below 1e4). */
        if (project) {
            double *d = malloc(sizeof *d * (size_t)n), *b = malloc(sizeof *b * 3 * (size_t)n);
            double *x = malloc(sizeof *x * 3 * (size_t)n);
            for (int32_t k = 0; k < n; k++)
                d[k] = 0.5 + test_uniform(&rng);
            bg_sparse_add_diagonal(plain, d);
            bg_sparse_add_diagonal(sys, d);
            bg_sparse_multiply(sys, v, hv);
            bg_sparse_multiply(plain, v, hv0);
            for (int32_t k = 0; k < n; k++)
                assert_true(fabs(hv0[k] - hv[k]) <= 1e-13 * (1.0 + fabs(hv0[k])));
            for (size_t i = 0; i < 3 * (size_t)n; i++)
                b[i] = 2 * test_uniform(&rng) - 1;
            assert_int_equal(bg_sparse_factorize(sys, 0.0, NULL), BG_OK);
            assert_int_equal(bg_sparse_factorize(plain, 0.0, NULL), BG_OK);
            assert_int_equal(bg_sparse_supernodal(sys), bg_sparse_supernodal(plain));
            assert_true(bg_sparse_factor_flops(sys) == bg_sparse_factor_flops(plain));
            assert_int_equal(bg_sparse_solve_many(sys, 3, b, x, NULL), BG_OK);
            for (int c = 0; c < 3; c++) {
                bg_sparse_multiply(plain, x + (size_t)c * n, hv0);
                double res = 0.0, bn = 0.0;
                for (int32_t k = 0; k < n; k++) {
                    res = fmax(res, fabs(hv0[k] - b[(size_t)c * n + k]));
                    bn = fmax(bn, fabs(b[(size_t)c * n + k]));
                }
                assert_true(res <= 1e-10 * bn);
            }
            free(d);
            free(b);
            free(x);
        }
        free(v);
        free(hv);
        free(hv0);
    }
    bg_sparse_destroy(&plain);
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&md);
    bg_mesh_destroy(&mesh);
    free(index);
    free(q);
    free(qp);
    free(gp);
    free(gm);
}

/* A box's Hessian through the vertex-block map (bg_sparse_tet_blocks):
 * whole vertices held (the bottom and top layers) in one system, the y
 * coordinate of the top layer only in another (its elements there take
 * the entry map), a compressed, sheared and noisy state, so that both
 * twist-block paths of the projected assembly run. The block map must
 * give the entry scatter map's values to the bit (the same contributions
 * to each entry in the same element order), the exact Hessian must apply
 * as the finite differences of the gradient do, rotations fitted
 * elsewhere must be fitted again at q, and a corrupted map must be
 * caught by the comparison. */
static void tet_blocks(void **state)
{
    (void)state;
    const int32_t cells[3] = {5, 4, 3};
    const double origin[3] = {0, 0, 0}, size[3] = {1.0, 0.8, 0.6};
    bg_mesh_t *mesh = NULL;
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &mesh, NULL), BG_OK);
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(mesh, 1.0, 10.0, &md, NULL), BG_OK);
    const size_t ndof = 3 * (size_t)mesh->nv;
    int32_t *index = malloc(sizeof *index * ndof), *partial = malloc(sizeof *partial * ndof);
    double *q = malloc(sizeof *q * ndof), *q2 = malloc(sizeof *q2 * ndof);
    double *gp = malloc(sizeof *gp * ndof), *gm = malloc(sizeof *gm * ndof);
    int32_t n = 0, np = 0;
    uint64_t rng = 31;
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *x = mesh->x + 3 * (size_t)v;
        for (int c = 0; c < 3; c++) {
            const size_t i = 3 * (size_t)v + c;
            index[i] = x[2] == 0.0 || x[2] == size[2] ? -1 : n++;
            partial[i] = x[2] == 0.0 || (c == 1 && x[2] == size[2]) ? -1 : np++;
            /* compressed to 0.8 in z, sheared, a tenth of a cell of noise */
            q[i] = (c == 2 ? 0.8 * x[2] : x[c] + (c == 0 ? 0.3 * x[2] : 0.0)) +
                   0.02 * (2 * test_uniform(&rng) - 1);
            q2[i] = q[i] + 0.05 * (2 * test_uniform(&rng) - 1);
        }
    }
    bg_sparse_t *sys = NULL, *plain = NULL, *part = NULL;
    assert_int_equal(bg_sparse_new(mesh, 3, index, n, &sys, NULL), BG_OK);
    assert_int_equal(bg_sparse_new(mesh, 3, index, n, &plain, NULL), BG_OK);
    assert_int_equal(bg_sparse_new(mesh, 3, partial, np, &part, NULL), BG_OK);
    assert_null(bg_sparse_tet_blocks(sys));
    assert_int_equal(bg_sparse_reorder(sys, NULL), BG_OK);
    assert_int_equal(bg_sparse_reorder(part, NULL), BG_OK);
    /* the records in the model's element order, once */
    assert_null(bg_sparse_tet_blocks_order(sys));
    assert_int_equal(bg_sparse_order_tet_blocks(sys, bg_elastic_order(md), NULL), BG_OK);
    assert_int_equal(bg_sparse_order_tet_blocks(part, bg_elastic_order(md), NULL), BG_OK);
    assert_int_equal(bg_sparse_order_tet_blocks(sys, bg_elastic_order(md), NULL), BG_OK);
    assert_true(bg_sparse_tet_blocks_order(sys) == bg_elastic_order(md));
    assert_int_equal(bg_sparse_order_tet_blocks(sys, index, NULL), BG_ERR_INVALID);
    const bg_elastic_tet_blocks_t *blocks = bg_sparse_tet_blocks(sys);
    assert_non_null(blocks);
    assert_non_null(bg_sparse_tet_blocks(part));
    assert_null(bg_sparse_tet_blocks(plain));
    /* some elements through blocks (on the bunny 83 %); on the partly held system the top
     * layer's elements through the entry map */
    size_t marked = 0, marked_part = 0;
    for (int32_t e = 0; e < mesh->ne; e++) {
        marked += blocks[e].entries != 0;
        marked_part += bg_sparse_tet_blocks(part)[e].entries != 0;
    }
    print_message("  elements on the entry map: %zu, partly held: %zu, of %d\n", marked,
                  marked_part, (int)mesh->ne);
    assert_true(marked < (size_t)mesh->ne);
    assert_true(marked_part > marked);
    const size_t nnz = bg_sparse_nonzeros(sys);
    /* room past the end for the corrupted map below */
    double *ref = malloc(sizeof *ref * 2 * nnz), *val = malloc(sizeof *val * 2 * nnz);
    bg_elastic_eval(md, q, gp);
    for (int project = 0; project <= 1; project++) {
        memset(ref, 0, sizeof *ref * 2 * nnz);
        memset(val, 0, sizeof *val * 2 * nnz);
        bg_elastic_assemble_hessian(md, q, project, 0.7, bg_sparse_scatter(sys), ref);
        bg_elastic_assemble_hessian_blocks(md, q, project, 0.7, blocks, bg_sparse_scatter(sys),
                                           val);
        size_t differ = 0;
        for (size_t t = 0; t < 2 * nnz; t++)
            differ += memcmp(&ref[t], &val[t], sizeof *val) != 0;
        assert_int_equal(differ, 0);
        {
            const size_t pnz = bg_sparse_nonzeros(part);
            double *pr = calloc(pnz, sizeof *pr), *pv = calloc(pnz, sizeof *pv);
            bg_elastic_assemble_hessian(md, q, project, 0.7, bg_sparse_scatter(part), pr);
            bg_elastic_assemble_hessian_blocks(md, q, project, 0.7, bg_sparse_tet_blocks(part),
                                               bg_sparse_scatter(part), pv);
            assert_int_equal(memcmp(pr, pv, sizeof *pv * pnz), 0);
            free(pr);
            free(pv);
        }
        /* the exact Hessian against central differences of the gradient
         * (tolerance as in reordered_hessian) */
        if (!project) {
            memcpy(bg_sparse_values(sys), val, sizeof *val * nnz);
            double *v = malloc(sizeof *v * (size_t)n), *hv = malloc(sizeof *hv * (size_t)n);
            double *qp = malloc(sizeof *qp * ndof);
            for (int32_t k = 0; k < n; k++)
                v[k] = 2 * test_uniform(&rng) - 1;
            bg_sparse_multiply(sys, v, hv);
            const double h = 1e-5;
            for (int sign = 0; sign < 2; sign++) {
                for (size_t i = 0; i < ndof; i++)
                    qp[i] = q[i] + (index[i] >= 0 ? (sign ? -h : h) * v[index[i]] : 0.0);
                bg_elastic_eval(md, qp, sign ? gm : gp);
            }
            double diff = 0.0, norm = 0.0;
            for (size_t i = 0; i < ndof; i++)
                if (index[i] >= 0) {
                    const double fd = (gp[i] - gm[i]) / (2 * h);
                    diff = fmax(diff, fabs(fd - hv[index[i]] / 0.7));
                    norm = fmax(norm, fabs(hv[index[i]] / 0.7));
                }
            print_message("  block-assembled exact Hessian against finite differences: %.2e of "
                          "%.2e\n", diff, norm);
            assert_true(diff <= 1e-6 * norm);
            free(v);
            free(hv);
            free(qp);
            bg_elastic_eval(md, q, gp); /* the rotations back at q */
        }
        /* A corrupted record (one block's transposition flipped) must show. */
        const size_t ne = (size_t)mesh->ne;
        bg_elastic_tet_blocks_t *bad = malloc(sizeof *bad * ne);
        memcpy(bad, blocks, sizeof *bad * ne);
        size_t e = 0;
        while (e < ne && (bad[e].entries || bad[e].pos[BG_ELASTIC_BLOCK_INDEX(0, 1)] < 0 ||
                          bad[e].stride[0] == bad[e].stride[1]))
            e++;
        assert_true(e < ne);
        bad[e].transposed ^= 1u << BG_ELASTIC_BLOCK_INDEX(0, 1);
        memset(val, 0, sizeof *val * 2 * nnz);
        bg_elastic_assemble_hessian_blocks(md, q, project, 0.7, bad, bg_sparse_scatter(sys), val);
        differ = 0;
        for (size_t t = 0; t < 2 * nnz; t++)
            differ += memcmp(&ref[t], &val[t], sizeof *val) != 0;
        assert_true(differ > 0);
        free(bad);
    }
    /* Rotations fitted at another point (a rejected trial's): the assembly
     * fits them again at q as an evaluation would, so the matrix is the
     * one assembled after evaluating at q. Where the vectorised fit leaves
     * a lane to the scalar one, the evaluation stores the scalar fit's
     * rotation as a quaternion and the assembly rebuilds R from it, while
     * the refit uses the scalar R itself: both are the rotation to a few
     * ulps, so entries agree to 1e-12 of the largest. */
    for (int project = 0; project <= 1; project++) {
        bg_elastic_eval(md, q, gp);
        memset(ref, 0, sizeof *ref * nnz);
        bg_elastic_assemble_hessian_blocks(md, q, project, 1.0, blocks, bg_sparse_scatter(sys),
                                           ref);
        bg_elastic_eval(md, q2, gp);
        memset(val, 0, sizeof *val * nnz);
        bg_elastic_assemble_hessian_blocks(md, q, project, 1.0, blocks, bg_sparse_scatter(sys),
                                           val);
        double diff = 0.0, norm = 0.0;
        for (size_t t = 0; t < nnz; t++) {
            diff = fmax(diff, fabs(ref[t] - val[t]));
            norm = fmax(norm, fabs(ref[t]));
        }
        print_message("  rotations fitted elsewhere (project %d): %.2e of %.2e\n", project, diff,
                      norm);
        assert_true(diff <= 1e-12 * norm);
    }
    free(ref);
    free(val);
    bg_sparse_destroy(&sys);
    bg_sparse_destroy(&plain);
    bg_sparse_destroy(&part);
    bg_elastic_destroy(&md);
    bg_mesh_destroy(&mesh);
    free(index);
    free(partial);
    free(q);
    free(q2);
    free(gp);
    free(gm);
}

/*
 * bg_sparse's triangular solves through a supernodal, solve-heavy factor
 * (its own kernels, not CHOLMOD's solve) against an independent
 * computation: CHOLMOD's simplicial LDLᵀ of the same matrix in AMD order
 * instead of METIS, solved by CHOLMOD. Both are backward stable, so the
 * solutions differ by at most about cond(A)·ε relative: the grid
 * Laplacians here have cond < 1e4, and 1e-11 leaves a factor of 50 over
 * that. Widths 1 to 7 cover the one-, three- and general-column kernels
 * and blocks of four columns with every remainder; a column solved alone
 * and in a block of three gives the same bits (the kernels keep one
 * column's order of operations), and a solve in place gives what one
 * into another array gives.
 */
static void super_solve_against_cholmod(void **state)
{
    (void)state;
    const int32_t boxes[2][3] = {{16, 16, 16}, {21, 17, 14}};
    for (int bx = 0; bx < 2; bx++) {
        bg_mesh_t *mesh = NULL;
        bg_sparse_t *sys = laplacian(boxes[bx], 1, &mesh);
        assert_int_equal(bg_sparse_supernodal(sys), 1);
        const int32_t n = bg_sparse_size(sys);
        const int32_t *cp = bg_sparse_colptr(sys), *ri = bg_sparse_rowidx(sys);
        const double *val = bg_sparse_values(sys);
        cholmod_common cc;
        cholmod_start(&cc);
        cc.nmethods = 1;
        cc.method[0].ordering = CHOLMOD_AMD;
        cc.supernodal = CHOLMOD_SIMPLICIAL;
        cholmod_sparse *A = cholmod_allocate_sparse((size_t)n, (size_t)n, (size_t)cp[n], 1, 1, -1,
                                                    CHOLMOD_REAL, &cc);
        assert_non_null(A);
        memcpy(A->p, cp, sizeof(int32_t) * ((size_t)n + 1));
        memcpy(A->i, ri, sizeof(int32_t) * (size_t)cp[n]);
        memcpy(A->x, val, sizeof(double) * (size_t)cp[n]);
        cholmod_factor *F = cholmod_analyze(A, &cc);
        assert_non_null(F);
        assert_true(cholmod_factorize(A, F, &cc));
        assert_false(F->is_super);
        const int most = 7;
        cholmod_dense *B = cholmod_zeros((size_t)n, (size_t)most, CHOLMOD_REAL, &cc);
        double *b = B->x, *x = malloc(sizeof *x * (size_t)most * n);
        double *alone = malloc(sizeof *alone * (size_t)n);
        uint64_t rng = 29 + (uint64_t)bx;
        for (size_t i = 0; i < (size_t)most * n; i++)
            b[i] = 2 * test_uniform(&rng) - 1;
        cholmod_dense *X = cholmod_solve(CHOLMOD_A, F, B, &cc);
        assert_non_null(X);
        const double *ref = X->x;
        double worst = 0.0;
        for (int width = 1; width <= most; width++) {
            assert_int_equal(bg_sparse_solve_many(sys, width, b, x, NULL), BG_OK);
            for (int k = 0; k < width; k++) {
                double diff = 0.0, size = 0.0;
                for (int32_t i = 0; i < n; i++) {
                    const size_t at = (size_t)k * n + (size_t)i;
                    diff = fmax(diff, fabs(x[at] - ref[at]));
                    size = fmax(size, fabs(ref[at]));
                }
                worst = fmax(worst, diff / size);
                assert_true(diff <= 1e-11 * size);
            }
            if (width == 3)
                for (int k = 0; k < 3; k++) {
                    assert_int_equal(bg_sparse_solve(sys, b + (size_t)k * n, alone, NULL), BG_OK);
                    assert_memory_equal(alone, x + (size_t)k * n, sizeof *alone * (size_t)n);
                }
        }
        /* in place, five columns: the same bits as into x */
        assert_int_equal(bg_sparse_solve_many(sys, 5, b, x, NULL), BG_OK);
        double *inplace = malloc(sizeof *inplace * 5 * (size_t)n);
        memcpy(inplace, b, sizeof *inplace * 5 * (size_t)n);
        assert_int_equal(bg_sparse_solve_many(sys, 5, inplace, inplace, NULL), BG_OK);
        assert_memory_equal(inplace, x, sizeof *x * 5 * (size_t)n);
        print_message("  %dx%dx%d box, %d unknowns: largest difference to CHOLMOD's solve "
                      "%.1e of the solution\n",
                      (int)boxes[bx][0], (int)boxes[bx][1], (int)boxes[bx][2], (int)n, worst);
        free(inplace);
        free(alone);
        free(x);
        cholmod_free_dense(&X, &cc);
        cholmod_free_dense(&B, &cc);
        cholmod_free_factor(&F, &cc);
        cholmod_free_sparse(&A, &cc);
        cholmod_finish(&cc);
        bg_sparse_destroy(&sys);
        bg_mesh_destroy(&mesh);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(factor_kinds),
        cmocka_unit_test(reordered_hessian),
        cmocka_unit_test(tet_blocks),
        cmocka_unit_test(super_solve_against_cholmod),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
