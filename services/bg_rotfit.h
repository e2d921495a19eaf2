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

#include <math.h>
#include <stddef.h>
#include <stdint.h>

/* det F below this multiple of (‖F‖_F/√3)³ — the determinant of a matrix of
 * that size with equal singular values — sends a call to the SVD: the
 * element is inverted, flat or collapsed and the polar factor is either
 * not the closest rotation or ill-conditioned. */
#define BG_ROTFIT_DET_EPS 1e-6
/* The warm Newton stops when the skew part of Qᵀ F is this small relative
 * to ‖F‖: below that, rounding dominates. */
#define BG_ROTFIT_SKEW_TOL 1e-14

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

/* Counts one fit that took `path` in stats. */
void bg_rotfit_stats_count(bg_rotfit_stats_t *stats, bg_rotfit_path path);

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
 * Eigen-decomposition of a symmetric 3×3 A (cyclic Jacobi, at most
 * BG_ROTFIT_JACOBI_SWEEPS sweeps): A = Q diag(w) Qᵀ, eigenvectors in the
 * columns of Q.
 */
#define BG_ROTFIT_JACOBI_SWEEPS 30
void bg_sym3_eigen(const double A[9], double w[3], double Q[9]);

/* Unit quaternion (w, x, y, z) ↔ rotation matrix. */
void bg_quat_to_matrix(const double q[4], double R[9]);
void bg_matrix_to_quat(const double R[9], double q[4]);

/*
 * The pieces of the warm-started fit, inline because the element kernel
 * (bg_elastic) runs them across a block of elements and needs them
 * visible to the vectoriser; bg_rotfit3 runs the same code per element.
 */

/* R from a unit quaternion (w, x, y, z). */
static inline void bg_quat_rotation(const double q[4], double R[9])
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z);
    R[1] = 2 * (x * y - w * z);
    R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);
    R[4] = 1 - 2 * (x * x + z * z);
    R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);
    R[7] = 2 * (y * z + w * x);
    R[8] = 1 - 2 * (x * x + y * y);
}

/* C = Aᵀ B for row-major 3×3 matrices. */
static inline void bg_mul_tn3(const double A[9], const double B[9], double C[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            C[3 * i + j] = A[i] * B[j] + A[3 + i] * B[3 + j] + A[6 + i] * B[6 + j];
}

/* |skew part of S|², scaled: the squared norm of a = 2 axial(skew S). */
static inline double bg_rotfit_skew2(const double S[9])
{
    const double a0 = S[7] - S[5], a1 = S[2] - S[6], a2 = S[3] - S[1];
    return a0 * a0 + a1 * a1 + a2 * a2;
}

/*
 * One Newton step for max tr(Qᵀ F) over rotations, at Q = R(q) with
 * S = Qᵀ F. Linearising Q ← Q exp([ω]×) gives (tr S·I − sym S) ω = a,
 * a = 2 axial(skew S); the step is applied as the Cayley rotation
 * q ← q ⊗ (1, ω/2), renormalised, exact to second order so convergence
 * stays quadratic. Returns 1 when the Newton matrix is positive definite
 * (Sylvester's criterion) and q was updated, 0 (q unchanged) otherwise:
 * then the start is on the wrong side of a stationary point.
 */
static inline int bg_rotfit_step(const double S[9], double q[4])
{
    const double a0 = S[7] - S[5], a1 = S[2] - S[6], a2 = S[3] - S[1];
    const double tr = S[0] + S[4] + S[8];
    const double m00 = tr - S[0], m11 = tr - S[4], m22 = tr - S[8];
    const double m01 = -0.5 * (S[1] + S[3]), m02 = -0.5 * (S[2] + S[6]),
                 m12 = -0.5 * (S[5] + S[7]);
    const double c00 = m11 * m22 - m12 * m12, c01 = m02 * m12 - m01 * m22,
                 c02 = m01 * m12 - m02 * m11;
    const double c11 = m00 * m22 - m02 * m02, c12 = m01 * m02 - m00 * m12,
                 c22 = m00 * m11 - m01 * m01;
    const double det = m00 * c00 + m01 * c01 + m02 * c02;
    const int pd = m00 > 0.0 && c22 > 0.0 && det > 0.0;
    const double half_inv = pd ? 0.5 / det : 0.0;
    const double dx = half_inv * (c00 * a0 + c01 * a1 + c02 * a2);
    const double dy = half_inv * (c01 * a0 + c11 * a1 + c12 * a2);
    const double dz = half_inv * (c02 * a0 + c12 * a1 + c22 * a2);
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double nw = w - x * dx - y * dy - z * dz;
    const double nx = w * dx + x + y * dz - z * dy;
    const double ny = w * dy - x * dz + y + z * dx;
    const double nz = w * dz + x * dy - y * dx + z;
    const double len = 1.0 / sqrt(nw * nw + nx * nx + ny * ny + nz * nz);
    q[0] = nw * len;
    q[1] = nx * len;
    q[2] = ny * len;
    q[3] = nz * len;
    return pd;
}

#endif
