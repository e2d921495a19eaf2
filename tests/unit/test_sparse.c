/*
 * bg_sparse: several right-hand sides in one solve give what one solve per
 * column gives, on a supernodal and on a simplicial factor, wider and then
 * narrower calls reuse the workspace, and bg_sparse_prefer_solves makes a
 * solve-heavy system's factor simplicial only where its flops per nonzero
 * are moderate.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

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

/* A 6×6×6 box: flops per nonzero well under BG_SPARSE_SOLVES_SWITCH and
 * over CHOLMOD's 40, so the default factor is supernodal and the
 * preferred one simplicial; a 16³ box's is over the switch, supernodal
 * either way. */
static void factor_kinds(void **state)
{
    const int32_t small[3] = {9, 9, 9}, large[3] = {16, 16, 16};
    for (int prefer = 0; prefer <= 1; prefer++) {
        bg_mesh_t *mesh = NULL;
        bg_sparse_t *sys = laplacian(small, prefer, &mesh);
        const double ratio = bg_sparse_factor_flops(sys) / bg_sparse_factor_nonzeros(sys);
        print_message("  9^3 box, prefer_solves %d: flops/nnz %.1f, %s\n", prefer, ratio,
                      bg_sparse_supernodal(sys) ? "supernodal" : "simplicial");
        assert_true(ratio > 40.0 && ratio < BG_SPARSE_SOLVES_SWITCH);
        assert_int_equal(bg_sparse_prefers_solves(sys), prefer);
        assert_int_equal(bg_sparse_supernodal(sys), !prefer);
        check_columns(sys);
        bg_sparse_destroy(&sys);
        bg_mesh_destroy(&mesh);
    }
    bg_mesh_t *mesh = NULL;
    bg_sparse_t *sys = laplacian(large, 1, &mesh);
    const double ratio = bg_sparse_factor_flops(sys) / bg_sparse_factor_nonzeros(sys);
    print_message("  16^3 box, prefer_solves 1: flops/nnz %.1f, %s\n", ratio,
                  bg_sparse_supernodal(sys) ? "supernodal" : "simplicial");
    assert_true(ratio >= BG_SPARSE_SOLVES_SWITCH);
    assert_int_equal(bg_sparse_supernodal(sys), 1);
    check_columns(sys);
    bg_sparse_destroy(&sys);
    bg_mesh_destroy(&mesh);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(factor_kinds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
