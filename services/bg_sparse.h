/*
 * bg_sparse — the "sparse-solve" basic service: a symmetric positive
 * definite system over the free degrees of freedom of a mesh, assembled on
 * a fixed pattern and solved with CHOLMOD.
 *
 * The pattern (lower triangle, CSC, rows sorted) and, for every element,
 * where each of its packed upper-triangle local entries lands in the value
 * array are computed once (bg_sparse_new). Each Newton iteration then only
 * zeroes the values, scatters element matrices (bg_elastic_assemble_*),
 * and calls bg_sparse_factorize: the symbolic analysis (fill-reducing
 * ordering, supernodes) runs on the first call only; later calls do the
 * numeric factorization alone. bg_sparse_solve reuses CHOLMOD workspace
 * (cholmod_solve2), so a solve allocates nothing after the first.
 */
#ifndef BG_SPARSE_H
#define BG_SPARSE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_elastic.h"
#include "bg_error.h"
#include "bg_mesh.h"

typedef struct bg_sparse bg_sparse_t;

typedef struct bg_sparse_timing {
    double analyze_seconds;
    double factor_seconds;
    double solve_seconds;
    int64_t factorizations;
    int64_t solves;
} bg_sparse_timing_t;

/*
 * A system on the mesh's element graph with n unknowns per vertex.
 * free_index maps each dof (vertex*n + component) to its unknown number
 * (increasing with the dof number) or to −1 if the dof is constrained;
 * nfree unknowns in all. Both are copied. Caller owns *out.
 */
bg_status bg_sparse_new(const bg_mesh_t *mesh, int n, const int32_t *free_index, int32_t nfree,
                        bg_sparse_t **out, bg_error_t *err);
void bg_sparse_destroy(bg_sparse_t **sys);

/*
 * A system on a given lower-triangle CSC pattern (the sparse-solve
 * agent's form: the pattern arrives over the wire, with no mesh): n
 * columns, colptr[n + 1], rowidx[colptr[n]], rows strictly increasing in
 * each column and starting at the diagonal. The pattern is checked
 * (BG_ERR_INVALID naming the column) and copied. There is no element
 * scatter map (bg_sparse_scatter returns NULL). Caller owns *out.
 */
bg_status bg_sparse_new_csc(int32_t n, const int32_t *colptr, const int32_t *rowidx,
                            bg_sparse_t **out, bg_error_t *err);

int32_t bg_sparse_size(const bg_sparse_t *sys);
size_t bg_sparse_nonzeros(const bg_sparse_t *sys);

/* The lower-triangle CSC pattern (size() + 1 column starts, nonzeros()
 * row indices), borrowed: what a sparse-solve agent is sent once. */
const int32_t *bg_sparse_colptr(const bg_sparse_t *sys);
const int32_t *bg_sparse_rowidx(const bg_sparse_t *sys);

/* Per element, BG_ELASTIC_TRI_SIZE(local size) positions (or −1); borrowed. */
const int32_t *bg_sparse_scatter(const bg_sparse_t *sys);

/* The value array (nonzeros entries), to be filled through the scatter. */
double *bg_sparse_values(bg_sparse_t *sys);
void bg_sparse_zero(bg_sparse_t *sys);

/*
 * The system will be solved far more often than it is factored (a
 * prefactored method's Laplacian: hundreds of solves per factorization):
 * when CHOLMOD makes its factor supernodal (flops per nonzero from 40 on),
 * bg_sparse solves through it with its own kernels instead of CHOLMOD's
 * solve, whose per-supernode BLAS calls (matrix–matrix kernels on
 * matrix–vector work, every diagonal block packed first) dominate with a
 * few right-hand sides. Three right-hand sides, one thread: the 32³ box's
 * scalar Laplacian (flops/nnz 722) 24–25 ms → 20–21.5 ms a solve; on
 * smaller ones the kernels also beat the simplicial factor this flag once
 * asked for (CHOLMOD's simplicial solve had beaten its supernodal one):
 * the bending slab's (188) 1.06 → 0.84 ms, bar-twist's (66) 0.083 →
 * 0.072 ms, the bunny's (85) 0.43 ms either way. Call before the first
 * factorization; the sparse-solve agent is told (solve-setup), so a grid
 * run solves to the same bits as one in process.
 */
void bg_sparse_prefer_solves(bg_sparse_t *sys);
int bg_sparse_prefers_solves(const bg_sparse_t *sys);
/* 1 when the factor is supernodal, 0 simplicial, −1 before the analysis. */
int bg_sparse_supernodal(const bg_sparse_t *sys);

/*
 * The system will be factored about as often as it is assembled (Newton's
 * Hessian): runs the symbolic analysis now and renumbers the stored matrix
 * by its fill-reducing, postordered permutation P, so that from here on
 * the values, colptr, rowidx and the scatter map are those of the lower
 * triangle of P A Pᵀ, which CHOLMOD then factors in its natural order as
 * stored. Without this, every numeric factorization first builds
 * (P A Pᵀ)ᵀ and its transpose from A (two passes of scattered writes over
 * the matrix): on the bunny's Hessian (n 15,897, 282,345 nonzeros) a
 * factorization takes 30.4 ms instead of 35.8 and a solve 3.5 instead of
 * 4.0 (one thread). solve, solve_many, multiply and add_diagonal keep the
 * caller's numbering (the vectors are permuted on the way in and out);
 * bg_sparse_permutation gives P. Call before any value is written (the
 * values are zeroed) and before the first factorization; a no-op after
 * it. A system whose pattern is shipped to a sparse-solve agent is
 * reordered by its sender (the coordinator), and the agent keeps the
 * order it is sent (bg_sparse_keep_order).
 */
bg_status bg_sparse_reorder(bg_sparse_t *sys, bg_error_t *err);
/*
 * After bg_sparse_reorder of a system made by bg_sparse_new for
 * tetrahedra with 3 unknowns per vertex: the vertex-block map of the
 * element matrices (bg_elastic_tet_blocks_t, one record per element, mesh
 * numbering), read off the entry scatter map and checked against all 78
 * of its entries per element, borrowed. CHOLMOD's order keeps most
 * vertices' unknowns adjacent in component order (AMD's supervariables:
 * 4,944 of the bunny's 5,299 free vertices); elements with any other
 * vertex are marked to take the entry map's row. The order itself is
 * CHOLMOD's, unchanged: an order made vertex-blocked (each vertex placed
 * at its first unknown) counts the same flops but rounds differently,
 * which moved the stiff bar's iteration counts and made a damped
 * inverted free body (unit.dynamics) end in another state. NULL for any
 * other system.
 */
const bg_elastic_tet_blocks_t *bg_sparse_tet_blocks(const bg_sparse_t *sys);

/*
 * Stores the block records in the order an elastic model visits its
 * elements (order: ne element numbers, bg_elastic_order; borrowed, must
 * outlive the system's use of it): record p is then element order[p],
 * read as one stream by bg_elastic_assemble_hessian_blocks instead of one
 * scattered record per element (a cache miss each after a
 * factorization). bg_sparse_tet_blocks_order gives the order the records
 * are in (NULL: mesh numbering). A no-op without a block map or with the
 * order already given; BG_ERR_INVALID for a second, other order.
 */
bg_status bg_sparse_order_tet_blocks(bg_sparse_t *sys, const int32_t *order, bg_error_t *err);
const int32_t *bg_sparse_tet_blocks_order(const bg_sparse_t *sys);

/* After bg_sparse_reorder: stored unknown k is the caller's unknown
 * perm[k] (size() values, borrowed); NULL for a system in the caller's
 * numbering. */
const int32_t *bg_sparse_permutation(const bg_sparse_t *sys);

/*
 * The pattern is already in its factor's order: it is the lower triangle
 * of P A Pᵀ that bg_sparse_reorder made in another process (the
 * coordinator) and shipped, as a sparse-solve agent receives it. The
 * analysis then keeps the order as bg_sparse_reorder's own second
 * analysis does (CHOLMOD's natural ordering, no postordering), so the
 * factor, and every solve with it, is the one the reordering process
 * would have computed from the same values, bit for bit, and no
 * factorization permutes the matrix. Call before the first
 * factorization; a no-op after it.
 */
void bg_sparse_keep_order(bg_sparse_t *sys);

/* Adds d[i] to diagonal entry i (d holds size() values; i in the caller's
 * numbering). */
void bg_sparse_add_diagonal(bg_sparse_t *sys, const double *d);

/*
 * Factors A + shift·I. BG_ERR_NUMERIC when the matrix is not positive
 * definite (the message gives the failing column), so a caller can retry
 * with a larger shift.
 */
bg_status bg_sparse_factorize(bg_sparse_t *sys, double shift, bg_error_t *err);

/* x = A⁻¹ rhs with the last factorization; rhs and x hold size() values
 * and may alias. */
bg_status bg_sparse_solve(bg_sparse_t *sys, const double *rhs, double *x, bg_error_t *err);

/*
 * X = A⁻¹ B for nrhs right-hand sides at once (1 ≤ nrhs ≤
 * BG_SPARSE_MAX_RHS), column-major: column k of rhs and x at offset
 * k·size(); rhs and x may alias. The triangular solves stream the whole
 * factor from memory once per call, whatever the number of columns, so
 * one call with three columns costs far less than three calls (the 32³
 * box's scalar Laplacian: 27 ms against 3 × 19 ms). Workspace grows to
 * the widest call and is reused: no allocation once it has been seen.
 */
#define BG_SPARSE_MAX_RHS 64
bg_status bg_sparse_solve_many(bg_sparse_t *sys, int nrhs, const double *rhs, double *x,
                               bg_error_t *err);

/* y = A x with the current values (symmetric, from the stored lower half;
 * x and y in the caller's numbering). */
void bg_sparse_multiply(const bg_sparse_t *sys, const double *x, double *y);

bg_sparse_timing_t bg_sparse_timing(const bg_sparse_t *sys);
/* Adds extra to the system's timing: a backend that factors and solves
 * the system elsewhere (a sparse-solve agent) credits its calls' time
 * here, so the solver's time split still covers them. */
void bg_sparse_add_timing(bg_sparse_t *sys, const bg_sparse_timing_t *extra);

/* Floating-point operations of one numeric factorization and the nonzeros
 * of the factor, as CHOLMOD's analysis counts them (0 before the first
 * factorization): a deterministic cost model for callers choosing between
 * refactoring and reusing a factor. */
double bg_sparse_factor_flops(const bg_sparse_t *sys);
double bg_sparse_factor_nonzeros(const bg_sparse_t *sys);

#endif
