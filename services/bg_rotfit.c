#include "bg_rotfit.h"

#include <math.h>
#include <string.h>

#define ROTFIT_WARM_MAX_STEPS 8
#define ROTFIT_POLAR_TOL 1e-10
#define ROTFIT_POLAR_MAX_STEPS 40

static double det3(const double A[9])
{
    return A[0] * (A[4] * A[8] - A[5] * A[7]) - A[1] * (A[3] * A[8] - A[5] * A[6]) +
           A[2] * (A[3] * A[7] - A[4] * A[6]);
}

static double frob2_3(const double A[9])
{
    double s = 0.0;
    for (int i = 0; i < 9; i++)
        s += A[i] * A[i];
    return s;
}


/* C = A Bᵀ */
static void mul_nt3(const double A[9], const double B[9], double C[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            C[3 * i + j] =
                A[3 * i] * B[3 * j] + A[3 * i + 1] * B[3 * j + 1] + A[3 * i + 2] * B[3 * j + 2];
}

void bg_quat_to_matrix(const double q[4], double R[9])
{
    bg_quat_rotation(q, R);
}

/* Shepperd's method: divide by the largest of the four candidate
 * magnitudes so that no branch loses precision. */
void bg_matrix_to_quat(const double R[9], double q[4])
{
    const double t = R[0] + R[4] + R[8];
    double w, x, y, z;
    if (t >= R[0] && t >= R[4] && t >= R[8]) {
        double s = 2.0 * sqrt(1.0 + t);
        w = 0.25 * s;
        x = (R[7] - R[5]) / s;
        y = (R[2] - R[6]) / s;
        z = (R[3] - R[1]) / s;
    } else if (R[0] >= R[4] && R[0] >= R[8]) {
        double s = 2.0 * sqrt(fmax(1.0 + R[0] - R[4] - R[8], 0.0) + 1e-300);
        w = (R[7] - R[5]) / s;
        x = 0.25 * s;
        y = (R[1] + R[3]) / s;
        z = (R[2] + R[6]) / s;
    } else if (R[4] >= R[8]) {
        double s = 2.0 * sqrt(fmax(1.0 + R[4] - R[0] - R[8], 0.0) + 1e-300);
        w = (R[2] - R[6]) / s;
        x = (R[1] + R[3]) / s;
        y = 0.25 * s;
        z = (R[5] + R[7]) / s;
    } else {
        double s = 2.0 * sqrt(fmax(1.0 + R[8] - R[0] - R[4], 0.0) + 1e-300);
        w = (R[3] - R[1]) / s;
        x = (R[2] + R[6]) / s;
        y = (R[5] + R[7]) / s;
        z = 0.25 * s;
    }
    double n = sqrt(w * w + x * x + y * y + z * z);
    q[0] = w / n;
    q[1] = x / n;
    q[2] = y / n;
    q[3] = z / n;
}

/*
 * Newton's method on SO(3) (bg_rotfit_step) from the rotation in quat.
 * Returns 1 on convergence with R and quat updated, 0 when the Newton
 * matrix is not positive definite or the steps do not settle.
 */
static int rotfit3_warm(const double F[9], double quat[4], double R[9])
{
    const double tol2 = BG_ROTFIT_SKEW_TOL * BG_ROTFIT_SKEW_TOL * frob2_3(F);
    double q[4];
    memcpy(q, quat, sizeof q);
    for (int step = 0; step <= ROTFIT_WARM_MAX_STEPS; step++) {
        double S[9];
        bg_quat_rotation(q, R);
        bg_mul_tn3(R, F, S);
        if (bg_rotfit_skew2(S) <= tol2) {
            memcpy(quat, q, sizeof q);
            return 1;
        }
        if (step == ROTFIT_WARM_MAX_STEPS || !bg_rotfit_step(S, q))
            break;
    }
    return 0;
}

/*
 * Higham's Newton iteration X ← (γX + (γX)^{-T}) / 2 with the Frobenius
 * scaling γ = (‖X⁻¹‖/‖X‖)^{1/2}: converges to the orthogonal polar factor for
 * any nonsingular X, with det of the sign of det F (positive here). Returns
 * 1 with R set on convergence.
 */
static int rotfit3_polar(const double F[9], double R[9])
{
    double X[9];
    memcpy(X, F, sizeof X);
    for (int step = 0; step < ROTFIT_POLAR_MAX_STEPS; step++) {
        double C[9]; /* cofactor matrix: X^{-T} = C / det X */
        C[0] = X[4] * X[8] - X[5] * X[7];
        C[1] = X[5] * X[6] - X[3] * X[8];
        C[2] = X[3] * X[7] - X[4] * X[6];
        C[3] = X[2] * X[7] - X[1] * X[8];
        C[4] = X[0] * X[8] - X[2] * X[6];
        C[5] = X[1] * X[6] - X[0] * X[7];
        C[6] = X[1] * X[5] - X[2] * X[4];
        C[7] = X[2] * X[3] - X[0] * X[5];
        C[8] = X[0] * X[4] - X[1] * X[3];
        const double det = X[0] * C[0] + X[1] * C[1] + X[2] * C[2];
        if (!(fabs(det) > 0.0) || !isfinite(det))
            return 0;
        double inv2 = 0.0;
        for (int i = 0; i < 9; i++) {
            C[i] /= det;
            inv2 += C[i] * C[i];
        }
        const double gamma = sqrt(sqrt(inv2 / frob2_3(X)));
        double change = 0.0;
        for (int i = 0; i < 9; i++) {
            const double next = 0.5 * (gamma * X[i] + C[i] / gamma);
            change += (next - X[i]) * (next - X[i]);
            X[i] = next;
        }
        if (change <= ROTFIT_POLAR_TOL * ROTFIT_POLAR_TOL * 3.0) {
            memcpy(R, X, sizeof X);
            return 1;
        }
    }
    return 0;
}

/* One-sided Jacobi rotation of columns p, q of A (and V) to make them
 * orthogonal; returns 1 if a rotation was applied. */
static int jacobi_columns(double A[9], double V[9], int p, int q)
{
    double alpha = 0, beta = 0, gamma = 0;
    for (int i = 0; i < 3; i++) {
        alpha += A[3 * i + p] * A[3 * i + p];
        beta += A[3 * i + q] * A[3 * i + q];
        gamma += A[3 * i + p] * A[3 * i + q];
    }
    if (!(fabs(gamma) > 1e-15 * sqrt(alpha * beta)))
        return 0;
    const double zeta = (beta - alpha) / (2.0 * gamma);
    const double t = copysign(1.0, zeta) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
    const double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
    for (int i = 0; i < 3; i++) {
        double ap = A[3 * i + p], aq = A[3 * i + q];
        A[3 * i + p] = c * ap - s * aq;
        A[3 * i + q] = s * ap + c * aq;
        double vp = V[3 * i + p], vq = V[3 * i + q];
        V[3 * i + p] = c * vp - s * vq;
        V[3 * i + q] = s * vp + c * vq;
    }
    return 1;
}

static void swap_columns(double M[9], int p, int q)
{
    for (int i = 0; i < 3; i++) {
        double t = M[3 * i + p];
        M[3 * i + p] = M[3 * i + q];
        M[3 * i + q] = t;
    }
}

static void cross3(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

void bg_svd3(const double F[9], double U[9], double sigma[3], double V[9])
{
    double A[9];
    memcpy(A, F, sizeof A);
    static const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(V, identity, sizeof identity);
    for (int sweep = 0; sweep < BG_ROTFIT_JACOBI_SWEEPS; sweep++) {
        int rotated = jacobi_columns(A, V, 0, 1);
        rotated |= jacobi_columns(A, V, 0, 2);
        rotated |= jacobi_columns(A, V, 1, 2);
        if (!rotated)
            break;
    }
    for (int j = 0; j < 3; j++)
        sigma[j] = sqrt(A[j] * A[j] + A[3 + j] * A[3 + j] + A[6 + j] * A[6 + j]);
    /* Sort columns by decreasing singular value. */
    for (int a = 0; a < 2; a++)
        for (int b = 0; b < 2 - a; b++)
            if (sigma[b] < sigma[b + 1]) {
                double t = sigma[b];
                sigma[b] = sigma[b + 1];
                sigma[b + 1] = t;
                swap_columns(A, b, b + 1);
                swap_columns(V, b, b + 1);
            }
    /* U's columns: normalised columns of A = F V, completed to an
     * orthonormal basis where singular values vanish (collapsed elements). */
    double u[3][3];
    const double tiny = 1e-300 + 1e-14 * sigma[0];
    for (int j = 0; j < 3; j++)
        for (int i = 0; i < 3; i++)
            u[j][i] = A[3 * i + j];
    if (sigma[0] > 1e-300) {
        for (int i = 0; i < 3; i++)
            u[0][i] /= sigma[0];
    } else {
        u[0][0] = 1, u[0][1] = 0, u[0][2] = 0;
    }
    if (sigma[1] > tiny) {
        for (int i = 0; i < 3; i++)
            u[1][i] /= sigma[1];
    } else {
        /* Any unit vector orthogonal to u0: cross with the axis least aligned. */
        int k = fabs(u[0][0]) < fabs(u[0][1]) ? (fabs(u[0][0]) < fabs(u[0][2]) ? 0 : 2)
                                               : (fabs(u[0][1]) < fabs(u[0][2]) ? 1 : 2);
        double e[3] = {0, 0, 0};
        e[k] = 1.0;
        cross3(u[0], e, u[1]);
        double n = sqrt(u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2]);
        for (int i = 0; i < 3; i++)
            u[1][i] /= n;
    }
    if (sigma[2] > tiny) {
        for (int i = 0; i < 3; i++)
            u[2][i] /= sigma[2];
    } else {
        cross3(u[0], u[1], u[2]);
    }
    for (int j = 0; j < 3; j++)
        for (int i = 0; i < 3; i++)
            U[3 * i + j] = u[j][i];
    /* Make V proper (negating a column of V and of U keeps F V = U Σ), then
     * U proper by moving its sign onto σ3: the rotation-variant SVD. */
    if (det3(V) < 0.0)
        for (int i = 0; i < 3; i++) {
            V[3 * i + 2] = -V[3 * i + 2];
            U[3 * i + 2] = -U[3 * i + 2];
        }
    if (det3(U) < 0.0) {
        for (int i = 0; i < 3; i++)
            U[3 * i + 2] = -U[3 * i + 2];
        sigma[2] = -sigma[2];
    }
}

void bg_sym3_eigen(const double A_in[9], double w[3], double Q[9])
{
    double A[9];
    memcpy(A, A_in, sizeof A);
    static const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(Q, identity, sizeof identity);
    for (int sweep = 0; sweep < BG_ROTFIT_JACOBI_SWEEPS; sweep++) {
        double off = A[1] * A[1] + A[2] * A[2] + A[5] * A[5];
        double diag = A[0] * A[0] + A[4] * A[4] + A[8] * A[8];
        if (off <= 1e-32 * diag || off == 0.0)
            break;
        static const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
        for (int k = 0; k < 3; k++) {
            const int p = pairs[k][0], q = pairs[k][1];
            const double apq = A[3 * p + q];
            if (apq == 0.0)
                continue;
            const double theta = (A[3 * q + q] - A[3 * p + p]) / (2.0 * apq);
            const double t = copysign(1.0, theta) / (fabs(theta) + sqrt(theta * theta + 1.0));
            const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
            /* A ← Jᵀ A J with J the rotation in the (p, q) plane. */
            for (int i = 0; i < 3; i++) {
                double aip = A[3 * i + p], aiq = A[3 * i + q];
                A[3 * i + p] = c * aip - s * aiq;
                A[3 * i + q] = s * aip + c * aiq;
            }
            for (int j = 0; j < 3; j++) {
                double apj = A[3 * p + j], aqj = A[3 * q + j];
                A[3 * p + j] = c * apj - s * aqj;
                A[3 * q + j] = s * apj + c * aqj;
            }
            for (int i = 0; i < 3; i++) {
                double qip = Q[3 * i + p], qiq = Q[3 * i + q];
                Q[3 * i + p] = c * qip - s * qiq;
                Q[3 * i + q] = s * qip + c * qiq;
            }
        }
    }
    w[0] = A[0];
    w[1] = A[4];
    w[2] = A[8];
}

bg_rotfit_path bg_rotfit3(const double F[9], double quat[4], double R[9])
{
    const double f2 = frob2_3(F);
    const double scale = f2 / 3.0;
    const double det = det3(F);
    if (det > BG_ROTFIT_DET_EPS * scale * sqrt(scale)) {
        const int have_warm = quat[0] != 0.0 || quat[1] != 0.0 || quat[2] != 0.0 || quat[3] != 0.0;
        if (have_warm && rotfit3_warm(F, quat, R))
            return BG_ROTFIT_WARM;
        double P[9];
        if (rotfit3_polar(F, P)) {
            /* Polish to full precision (and to an exact rotation) with the
             * warm Newton from the polar factor. */
            bg_matrix_to_quat(P, quat);
            if (rotfit3_warm(F, quat, R))
                return BG_ROTFIT_POLAR;
        }
    }
    double U[9], sigma[3], V[9];
    bg_svd3(F, U, sigma, V);
    mul_nt3(U, V, R);
    bg_matrix_to_quat(R, quat);
    bg_quat_to_matrix(quat, R);
    return BG_ROTFIT_SVD;
}

void bg_rotfit_stats_count(bg_rotfit_stats_t *stats, bg_rotfit_path path)
{
    stats->calls++;
    stats->warm += path == BG_ROTFIT_WARM;
    stats->polar += path == BG_ROTFIT_POLAR;
    stats->svd += path == BG_ROTFIT_SVD;
}

int bg_rotfit2(const double F[4], double R[4])
{
    const double a = F[0] + F[3], b = F[2] - F[1];
    const double r = sqrt(a * a + b * b);
    if (!(r > 0.0)) {
        R[0] = 1, R[1] = 0, R[2] = 0, R[3] = 1;
        return 1;
    }
    R[0] = a / r;
    R[1] = -b / r;
    R[2] = b / r;
    R[3] = a / r;
    return 0;
}
