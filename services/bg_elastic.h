/*
 * bg_elastic — the geometric elastic energy of Chao et al. 2010 on a mesh:
 *
 *   E(q) = Σ_e V_e ψ(F_e),  ψ(F) = μ|F − R|² + (λ/2)(tr Y − n)²,  F = R Y,
 *
 * its gradient (first Piola stress P = 2μ(F − R) + λ(tr Y − n)R, scattered
 * through D_m⁻ᵀ) and its exact Hessian, including the derivative of R
 * (DESIGN.md §1.3), optionally made positive semi-definite by clamping the
 * twist eigenvalues in closed form.
 *
 * Unknowns are the vertex positions q (nv*n doubles, vertex-major, n = 2
 * for planar triangles, 3 for tetrahedra). Element-local degrees of freedom
 * are ordered node-major: a = node*n + component, node ∈ [0, n].
 */
#ifndef BG_ELASTIC_H
#define BG_ELASTIC_H

#include <stdint.h>

#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_rotfit.h"

typedef struct bg_elastic bg_elastic_t;

/* Size of an element's local dof block: (n+1)*n, 6 for triangles, 12 for tets. */
#define BG_ELASTIC_MAX_LOCAL 12
/* Entries of the upper triangle (with diagonal) of a local block: 21 or 78. */
#define BG_ELASTIC_TRI_SIZE(m) ((m) * ((m) + 1) / 2)
/* Index of local entry (a, b), a ≤ b, in the packed upper triangle. */
#define BG_ELASTIC_TRI_INDEX(m, a, b) ((a) * (m) - ((a) * ((a)-1)) / 2 + ((b) - (a)))

/*
 * Precomputes D_m⁻¹ and V_e for a planar or volume rest mesh (which must
 * have passed bg_mesh_validate). The mesh is borrowed: it must outlive the
 * model. Caller owns *out.
 */
bg_status bg_elastic_new(const bg_mesh_t *mesh, double mu, double lambda, bg_elastic_t **out,
                         bg_error_t *err);
void bg_elastic_destroy(bg_elastic_t **model);

/*
 * A model whose rest shape is given per element rather than by positions:
 * rest_edges holds, for each element, the dim×dim edge matrix D_m
 * (row-major, column j = edge from node 0 to node j+1), with positive
 * determinant. Unknowns are dim-dimensional. Used for parameterization,
 * where each surface triangle's rest frame is its own isometric 2D copy.
 * mesh (connectivity only) is borrowed; rest_edges is copied into D_m⁻¹.
 */
bg_status bg_elastic_new_from_rest(const bg_mesh_t *mesh, int dim, const double *rest_edges,
                                   double mu, double lambda, bg_elastic_t **out, bg_error_t *err);

int bg_elastic_dim(const bg_elastic_t *model);
int bg_elastic_local_size(const bg_elastic_t *model);
const bg_mesh_t *bg_elastic_mesh(const bg_elastic_t *model);
/* The order the model visits its elements in (a Morton curve through the
 * rest centroids): position p holds element order[p], mesh numbering; ne
 * values, borrowed, fixed for the model's life. */
const int32_t *bg_elastic_order(const bg_elastic_t *model);
/* Rest measure (area/volume) of element e; the sum over all elements. */
double bg_elastic_volume(const bg_elastic_t *model, int32_t e);
double bg_elastic_total_volume(const bg_elastic_t *model);

/*
 * Fits every element's rotation at positions q (warm-started from the
 * previous call), and returns the energy; if grad is non-NULL it is
 * overwritten with ∇E (nv*n). Rotation-fitting counts accumulate in the
 * model's statistics. Per-element energy densities ψ_e of this call are
 * kept and readable with bg_elastic_energy_density. Allocates nothing.
 */
double bg_elastic_eval(bg_elastic_t *model, const double *q, double *grad);

/*
 * Element stiffness matrices at q: for each element, V_e Bᵀ (∂²ψ/∂F²) B,
 * PSD-projected when `project` is non-zero, accumulated into `values` at
 * positions scatter[e * T + t] for the t-th packed upper-triangle entry
 * (T = BG_ELASTIC_TRI_SIZE(local size)); entries with scatter < 0 are
 * skipped (constrained dofs). Call after bg_elastic_eval at the same q (it
 * reuses the fitted rotations). `scale` multiplies every contribution.
 */
void bg_elastic_assemble_hessian(const bg_elastic_t *model, const double *q, int project,
                                 double scale, const int32_t *scatter, double *values);

/*
 * Where a tetrahedron's element matrix lands in a 3D Hessian whose
 * vertices keep their three unknowns adjacent, in component order, in the
 * stored numbering (bg_sparse_tet_blocks makes the map from the entry
 * scatter map). The 12×12 K_e is ten 3×3 vertex blocks (i, j), i ≤ j
 * local vertices, numbered k = BG_ELASTIC_BLOCK_INDEX(i, j) (row by row:
 * (0,0), (0,1), (0,2), (0,3), (1,1), ...). In the lower-triangle CSC a
 * block's column vertex is the one stored first and its row vertex the
 * other; pos[k] is the value index of the entry (row vertex's component
 * 0, column vertex's component 0), or −1 when a vertex of the block is
 * held. Column c + 1 holds the same rows stride − c entries further on
 * than column c (stride: the column vertex's, by local vertex), so entry
 * (row d, column c) is at pos + d + c·stride − c(c − 1)/2; a diagonal
 * block has rows d ≥ c only. Bit k of transposed is set when block k's
 * column vertex is j: its column c then holds K_e's rows (i, d) of
 * column (j, c). An element with a vertex whose unknowns are not so
 * stored (CHOLMOD's order splits a few; partly held vertices) has
 * entries set and takes its row of the entry scatter map instead. One
 * 64-byte record per element: ten positions instead of 78 entries, each
 * block column three adjacent values.
 */
#define BG_ELASTIC_BLOCK_INDEX(i, j) ((i) * 4 - ((i) * ((i)-1)) / 2 + ((j) - (i)))
typedef struct bg_elastic_tet_blocks {
    int32_t pos[10];
    int32_t stride[4];
    uint32_t transposed;
    uint32_t entries;
} bg_elastic_tet_blocks_t;

/*
 * bg_elastic_assemble_hessian through the vertex-block map blocks and,
 * for the elements marked entries, the entry scatter map it was made
 * from. The records must be in the model's order (record p for element
 * bg_elastic_order(model)[p]: bg_sparse_order_tet_blocks), so that they
 * are read as one stream. The
 * same values to the bit as bg_elastic_assemble_hessian with scatter
 * (each entry gets the same contributions in the same element order).
 * Tetrahedral models only (a no-op otherwise).
 */
void bg_elastic_assemble_hessian_blocks(const bg_elastic_t *model, const double *q, int project,
                                        double scale, const bg_elastic_tet_blocks_t *blocks,
                                        const int32_t *scatter, double *values);

/*
 * The scalar cotan Laplacian scale·V_e G Gᵀ ((n+1)×(n+1) per element),
 * scattered like the Hessian but with local entries numbered by node
 * only: positions scatter[e * T + t], T = BG_ELASTIC_TRI_SIZE(n+1).
 * Local/global solves one such system per coordinate; the interpolated
 * starting guess solves its harmonic weights with it.
 */
void bg_elastic_assemble_scalar_laplacian(const bg_elastic_t *model, double scale,
                                          const int32_t *scatter, double *values);

/* out = K u with K = Σ_e V_e (G Gᵀ ⊗ I_n) over all dofs (u, out: nv*n). */
void bg_elastic_apply_laplacian(const bg_elastic_t *model, const double *u, double *out);

/*
 * Adds scale · Σ_e |element force terms| per coordinate into mag (nv*n):
 * the magnitudes a gradient entry at q is summed from, before they cancel.
 * ε times this bounds the round-off of bg_elastic_eval's gradient. The
 * model's warm-start rotations are read, not changed. Allocates nothing.
 */
void bg_elastic_force_magnitude(const bg_elastic_t *model, const double *q, double scale,
                                double *mag);

/* Per-element ψ of the last bg_elastic_eval (ne values, borrowed). */
const double *bg_elastic_energy_density(const bg_elastic_t *model);

/* Rotation-fitting statistics since creation or the last reset. */
bg_rotfit_stats_t bg_elastic_rotfit_stats(const bg_elastic_t *model);
void bg_elastic_reset_stats(bg_elastic_t *model);
/* Forgets the warm starts (the next eval fits every rotation cold). */
void bg_elastic_forget_rotations(bg_elastic_t *model);

/*
 * 2D models only (a no-op in 3D): adds weight·V·b(det F) per element, b
 * the area barrier −(J − k)² log(J/k) below the knee k =
 * BG_ELASTIC_BARRIER_KNEE and 0 above it. It leaves every element with at
 * least k of its rest area untouched and makes a degenerate or flipped one
 * cost +∞, so a minimiser that starts flip-free converges to a flip-free
 * stationary point instead of stalling against the boundary of the
 * flip-free set (parameterization: ARAP's unconstrained optimum can fold).
 * weight 0 removes it.
 */
#define BG_ELASTIC_BARRIER_KNEE 0.1
void bg_elastic_set_barrier(bg_elastic_t *model, double weight);

/* Projects a symmetric 4×4 matrix (row-major, in place) onto the PSD cone:
 * negative eigenvalues clamped to zero (cyclic Jacobi). */
void bg_sym4_project(double A[16]);

/* Y = V diag(y) Vᵀ for a symmetric 3×3 Y (row-major, upper triangle
 * read), V's columns orthonormal: the closed form the projected twist
 * blocks use (no iteration; backward stable, see bg_elastic.c). */
void bg_elastic_sym3_eigen(const double Y[9], double y[3], double V[9]);

/*
 * Single-element kernel, for tests and other services: ψ(F) and, when the
 * pointers are non-NULL, P (n*n) and ∂P/∂F ((n*n)², row-major over
 * row-major vec(F)), PSD-projected when `project`. quat is the 3D warm
 * start (in/out, may be all zero; unused in 2D). Returns ψ.
 */
double bg_elastic_psi(int n, double mu, double lambda, const double *F, double *quat, double *P,
                      double *dPdF, int project);

#endif
