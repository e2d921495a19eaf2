/*
 * bg_rotfit — the "rotation-fit" basic service: the closest rotation R to a
 * deformation gradient F (F = R Y, Y symmetric), over all elements.
 *
 * Matrices are row-major: a 3×3 F is F[3*i + j], a 2×2 is F[2*i + j].
 *
 * 2D: closed form R = [[a, −b], [b, a]] / √(a² + b²) with a = F11 + F22,
 *     b = F21 − F12; valid for inverted elements; tr Y = √(a² + b²).
 *     Degenerate only when a = b = 0 (then R = I, counted as a fallback).
 * 3D: warm start from the element's previous rotation (a unit quaternion):
 *     Newton's method on SO(3) for max tr(Qᵀ F), quadratic, usually 1–2
 *     steps once an outer solve settles. Without a usable warm start:
 *     Higham's scaled Newton iteration for the polar factor. When
 *     det F ≤ ε‖F‖³ (inverted, flat or collapsed) the rotation-variant SVD
 *     (U, V ∈ SO(3), sign on σ3) gives R = U Vᵀ; those calls are counted.
 * The result is always finite, orthogonal to rounding, and det R = +1.
 */
#ifndef BG_ROTFIT_H
#define BG_ROTFIT_H

#include <stddef.h>
#include <stdint.h>

typedef enum bg_rotfit_path {
    BG_ROTFIT_WARM = 0,   /* Newton on SO(3) from the previous rotation */
    BG_ROTFIT_POLAR = 1,  /* Higham's scaled Newton from F */
    BG_ROTFIT_SVD = 2,    /* rotation-variant SVD (det F ≤ ε or no convergence) */
} bg_rotfit_path;

typedef struct bg_rotfit_stats {
    int64_t calls;
    int64_t warm;
    int64_t polar;
    int64_t svd;        /* SVD fallbacks (3D) / degenerate closed forms (2D) */
} bg_rotfit_stats_t;

/*
 * Closest rotation to the 3×3 F. quat holds a unit quaternion (w, x, y, z):
 * on entry the warm start (all zero: none), on exit the fitted rotation.
 * Writes R (row-major) and returns which path produced it.
 */
bg_rotfit_path bg_rotfit3(const double F[9], double quat[4], double R[9]);

/* Closest rotation to the 2×2 F; returns 0, or 1 when F has a = b = 0. */
int bg_rotfit2(const double F[4], double R[4]);

/*
 * Rotation-variant SVD of a 3×3 F: F = U diag(sigma) Vᵀ with U, V proper
 * rotations, |sigma| sorted decreasing, sigma[0], sigma[1] ≥ 0 and the sign
 * of det F on sigma[2]. One-sided Jacobi: accurate for small singular values.
 */
void bg_svd3(const double F[9], double U[9], double sigma[3], double V[9]);

/*
 * Eigen-decomposition of a symmetric 3×3 A (cyclic Jacobi): A = Q diag(w) Qᵀ,
 * eigenvectors in the columns of Q.
 */
void bg_sym3_eigen(const double A[9], double w[3], double Q[9]);

/* Unit quaternion (w, x, y, z) ↔ rotation matrix. */
void bg_quat_to_matrix(const double q[4], double R[9]);
void bg_matrix_to_quat(const double R[9], double q[4]);

#endif
