/*
 * The elastic model against independent computations: central finite
 * differences of ψ and P, the closed-form eigenvalues of ∂P/∂F at
 * F = diag(σ), rigid motions, uniform scaling, and the rotation fit against
 * the SVD.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include <cmocka.h>

#include "bg_elastic.h"
#include "bg_mesh.h"
#include "bg_rotfit.h"
#include "test_support.h"

/* A random F = I + amplitude·noise with det F > 0.2 (well away from the
 * SVD region, where R is smooth and finite differences are meaningful). */
static void random_F(int n, uint64_t *rng, double amplitude, double *F)
{
    for (;;) {
        for (int i = 0; i < n * n; i++)
            F[i] = (i % (n + 1) == 0 ? 1.0 : 0.0) + amplitude * (2.0 * test_uniform(rng) - 1.0);
        double det = n == 2 ? F[0] * F[3] - F[1] * F[2]
                            : F[0] * (F[4] * F[8] - F[5] * F[7]) -
                                  F[1] * (F[3] * F[8] - F[5] * F[6]) +
                                  F[2] * (F[3] * F[7] - F[4] * F[6]);
        if (det > 0.2)
            return;
    }
}

/* Central differences with h = 1e-6 on O(1) entries: truncation O(h²) ≈
 * 1e-12 and round-off O(ε/h) ≈ 1e-10 relative, so 1e-7 leaves a wide margin
 * while any wrong term (a missing dR/dF, a factor 2) shows at O(1). */
#define FD_STEP 1e-6
#define FD_TOL 1e-7

static void check_gradient(int n, double mu, double lambda, uint64_t seed)
{
    uint64_t rng = seed;
    for (int trial = 0; trial < 50; trial++) {
        double F[9], P[9], Fp[9], Fm[9];
        random_F(n, &rng, 0.6, F);
        bg_elastic_psi(n, mu, lambda, F, NULL, P, NULL, 0);
        for (int i = 0; i < n * n; i++) {
            memcpy(Fp, F, sizeof F);
            memcpy(Fm, F, sizeof F);
            Fp[i] += FD_STEP;
            Fm[i] -= FD_STEP;
            double fd = (bg_elastic_psi(n, mu, lambda, Fp, NULL, NULL, NULL, 0) -
                         bg_elastic_psi(n, mu, lambda, Fm, NULL, NULL, NULL, 0)) /
                        (2 * FD_STEP);
            assert_true(fabs(fd - P[i]) <= FD_TOL * (1.0 + fabs(P[i])) * (1.0 + lambda));
        }
    }
}

static void check_hessian(int n, double mu, double lambda, uint64_t seed)
{
    uint64_t rng = seed;
    const int nn = n * n;
    for (int trial = 0; trial < 50; trial++) {
        double F[9], H[81], Fp[9], Fm[9], Pp[9], Pm[9];
        random_F(n, &rng, 0.6, F);
        bg_elastic_psi(n, mu, lambda, F, NULL, NULL, H, 0);
        for (int j = 0; j < nn; j++) {
            memcpy(Fp, F, sizeof F);
            memcpy(Fm, F, sizeof F);
            Fp[j] += FD_STEP;
            Fm[j] -= FD_STEP;
            bg_elastic_psi(n, mu, lambda, Fp, NULL, Pp, NULL, 0);
            bg_elastic_psi(n, mu, lambda, Fm, NULL, Pm, NULL, 0);
            for (int i = 0; i < nn; i++) {
                double fd = (Pp[i] - Pm[i]) / (2 * FD_STEP);
                assert_true(fabs(fd - H[i * nn + j]) <= 1e-6 * (1.0 + fabs(H[i * nn + j])) *
                                                             (1.0 + lambda));
            }
        }
        /* Symmetric, as a Hessian must be. */
        for (int i = 0; i < nn; i++)
            for (int j = 0; j < nn; j++)
                assert_true(fabs(H[i * nn + j] - H[j * nn + i]) <= 1e-12 * (1.0 + lambda));
    }
}

static void gradient_2d(void **state)
{
    check_gradient(2, 0.5, 0.0, 1);
    check_gradient(2, 1.3, 4.0, 2);
}

static void gradient_3d(void **state)
{
    check_gradient(3, 0.5, 0.0, 3);
    check_gradient(3, 1.3, 4.0, 4);
}

static void hessian_2d(void **state)
{
    check_hessian(2, 0.5, 0.0, 5);
    check_hessian(2, 0.7, 3.0, 6);
}

static void hessian_3d(void **state)
{
    check_hessian(3, 0.5, 0.0, 7);
    check_hessian(3, 0.7, 3.0, 8);
}

/* At F = diag(σ) (R = I), ∂P/∂F has: twist eigenvalues
 * 2μ + 2(λ(tr Y − n) − 2μ)/(σi + σj), flips 2μ, and the scaling block
 * 2μ I + λ 11ᵀ (eigenvalues 2μ + nλ once and 2μ n−1 times). */
static void hessian_eigenvalues_diag(void **state)
{
    const double mu = 0.8, lambda = 2.5;
    const double cases[4][3] = {{1.2, 0.9, 1.1}, {0.5, 0.6, 0.7}, {2.0, 1.5, 0.3}, {1, 1, 1}};
    for (int c = 0; c < 4; c++) {
        for (int n = 2; n <= 3; n++) {
            const double *s = cases[c];
            double F[9] = {0}, H[81], w[9], expect[9];
            for (int i = 0; i < n; i++)
                F[i * n + i] = s[i];
            bg_elastic_psi(n, mu, lambda, F, NULL, NULL, H, 0);
            test_sym_eigenvalues(n * n, H, w);
            double tr = 0;
            for (int i = 0; i < n; i++)
                tr += s[i];
            int k = 0;
            for (int i = 0; i < n; i++)
                for (int j = i + 1; j < n; j++) {
                    expect[k++] = 2 * mu + 2 * (lambda * (tr - n) - 2 * mu) / (s[i] + s[j]);
                    expect[k++] = 2 * mu; /* flip partner of the twist pair */
                }
            expect[k++] = 2 * mu + n * lambda;
            for (int i = 1; i < n; i++)
                expect[k++] = 2 * mu;
            assert_int_equal(k, n * n);
            for (int i = 0; i < k; i++)
                for (int j = i + 1; j < k; j++)
                    if (expect[j] < expect[i]) {
                        double t = expect[i];
                        expect[i] = expect[j];
                        expect[j] = t;
                    }
            for (int i = 0; i < k; i++)
                assert_true(fabs(w[i] - expect[i]) <= 1e-10 * (1 + fabs(expect[i])));
        }
    }
}

/* The projected Hessian is PSD for any F, compressed and inverted ones
 * included, and equals the exact one where that is already PSD. */
static void projected_hessian_psd(void **state)
{
    uint64_t rng = 11;
    for (int n = 2; n <= 3; n++)
        for (int trial = 0; trial < 300; trial++) {
            double F[9], H[81], Hx[81], w[9];
            for (int i = 0; i < n * n; i++)
                F[i] = 2.0 * test_uniform(&rng) - 1.0 + (i % (n + 1) == 0 ? 0.3 : 0.0);
            const double lambda = trial % 2 ? 0.0 : 5.0;
            bg_elastic_psi(n, 1.0, lambda, F, NULL, NULL, H, 1);
            test_sym_eigenvalues(n * n, H, w);
            assert_true(w[0] >= -1e-9 * (1.0 + fabs(w[n * n - 1])));
            bg_elastic_psi(n, 1.0, lambda, F, NULL, NULL, Hx, 0);
            double wx[9];
            test_sym_eigenvalues(n * n, Hx, wx);
            if (wx[0] > 1e-9)
                for (int i = 0; i < n * n * n * n; i++)
                    assert_true(fabs(H[i] - Hx[i]) <= 1e-9 * (1 + fabs(Hx[i])));
        }
}

static void uniform_scale_energy(void **state)
{
    const double mu = 0.9, lambda = 3.0;
    const double scales[] = {0.5, 0.9, 1.0, 1.3, 2.0};
    for (int n = 2; n <= 3; n++)
        for (size_t k = 0; k < sizeof scales / sizeof *scales; k++) {
            const double s = scales[k];
            double F[9] = {0};
            for (int i = 0; i < n; i++)
                F[i * n + i] = s;
            double psi = bg_elastic_psi(n, mu, lambda, F, NULL, NULL, NULL, 0);
            double expect = 0.5 * n * (2 * mu + n * lambda) * (s - 1) * (s - 1);
            assert_true(fabs(psi - expect) <= 1e-13 * (1 + expect));
        }
}

/* The fitted rotation equals U Vᵀ of the SVD, whichever path ran, and the
 * warm start from a nearby rotation converges to the same answer. */
static void rotation_fit_paths(void **state)
{
    uint64_t rng = 21;
    int svd_seen = 0;
    for (int trial = 0; trial < 500; trial++) {
        double F[9], U[9], s[3], V[9], Rsvd[9], R[9], q[4] = {0, 0, 0, 0};
        for (int i = 0; i < 9; i++)
            F[i] = 2.0 * test_uniform(&rng) - 1.0;
        bg_svd3(F, U, s, V);
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Rsvd[3 * i + j] = U[3 * i] * V[3 * j] + U[3 * i + 1] * V[3 * j + 1] +
                                  U[3 * i + 2] * V[3 * j + 2];
        /* U Σ Vᵀ reproduces F. */
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double f = 0;
                for (int k = 0; k < 3; k++)
                    f += U[3 * i + k] * s[k] * V[3 * j + k];
                assert_true(fabs(f - F[3 * i + j]) <= 1e-12);
            }
        bg_rotfit_path path = bg_rotfit3(F, q, R);
        svd_seen += path == BG_ROTFIT_SVD;
        /* Where σ2 + σ3 is tiny the closest rotation is ill-conditioned;
         * compare only where it is well defined. */
        if (s[1] + s[2] > 1e-3)
            for (int i = 0; i < 9; i++)
                assert_true(fabs(R[i] - Rsvd[i]) <= 1e-9);
        /* Warm start from a slightly perturbed rotation. */
        double qw[4] = {q[0] + 0.05, q[1] - 0.03, q[2] + 0.02, q[3]}, Rw[9];
        bg_rotfit3(F, qw, Rw);
        if (s[1] + s[2] > 1e-3)
            for (int i = 0; i < 9; i++)
                assert_true(fabs(Rw[i] - Rsvd[i]) <= 1e-9);
    }
    /* Random F have det < 0 half the time: the SVD path must have run. */
    assert_true(svd_seen > 100);
}

static bg_mesh_t *small_box(void)
{
    bg_mesh_t *m = NULL;
    const int32_t cells[3] = {3, 2, 2};
    const double origin[3] = {0.1, -0.2, 0.3}, size[3] = {1.5, 1.0, 0.8};
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &m, NULL), BG_OK);
    return m;
}

static void rigid_motion_zero(void **state)
{
    bg_mesh_t *m = small_box();
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(m, 1.0, 2.0, &md, NULL), BG_OK);
    double q4[4] = {0.8, 0.3, -0.4, 0.2}, R[9];
    double len = sqrt(q4[0] * q4[0] + q4[1] * q4[1] + q4[2] * q4[2] + q4[3] * q4[3]);
    for (int i = 0; i < 4; i++)
        q4[i] /= len;
    bg_quat_to_matrix(q4, R);
    double *q = malloc(sizeof(double) * 3 * m->nv), *g = malloc(sizeof(double) * 3 * m->nv);
    for (int32_t v = 0; v < m->nv; v++)
        for (int i = 0; i < 3; i++)
            q[3 * v + i] = R[3 * i] * m->x[3 * v] + R[3 * i + 1] * m->x[3 * v + 1] +
                           R[3 * i + 2] * m->x[3 * v + 2] + (i + 1) * 0.7;
    double E = bg_elastic_eval(md, q, g);
    assert_true(fabs(E) <= 1e-26);
    for (int32_t i = 0; i < 3 * m->nv; i++)
        assert_true(fabs(g[i]) <= 1e-13);
    free(q);
    free(g);
    bg_elastic_destroy(&md);
    bg_mesh_destroy(&m);
    assert_null(md);
}

/* The mesh-level gradient and the assembled Hessian of md at q against
 * central differences of the mesh energy; a dense scatter map (every local
 * entry to its dense position) makes the check independent of the sparse
 * module. */
static void check_mesh_derivatives(const bg_mesh_t *m, bg_elastic_t *md, double *q)
{
    const int n = bg_elastic_dim(md);
    const int N = n * m->nv, loc = (n + 1) * n, T = BG_ELASTIC_TRI_SIZE(loc);
    double *g = malloc(sizeof(double) * N);
    double *gp = malloc(sizeof(double) * N), *gm = malloc(sizeof(double) * N);
    double *H = calloc((size_t)N * N, sizeof(double));
    int32_t *scatter = malloc(sizeof(int32_t) * T * m->ne);
    for (int32_t e = 0; e < m->ne; e++)
        for (int a = 0; a < loc; a++)
            for (int b = a; b < loc; b++) {
                int ga = m->elements[e * (n + 1) + a / n] * n + a % n;
                int gb = m->elements[e * (n + 1) + b / n] * n + b % n;
                /* upper-triangle entries land in row-major dense (min, max) */
                int lo = ga < gb ? ga : gb, hi = ga < gb ? gb : ga;
                scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(loc, a, b)] = lo * N + hi;
            }
    bg_elastic_eval(md, q, g);
    bg_elastic_assemble_hessian(md, q, 0, 1.0, scatter, H);
    for (int j = 0; j < N; j++) {
        const double qj = q[j];
        q[j] = qj + FD_STEP;
        double Ep = bg_elastic_eval(md, q, gp);
        q[j] = qj - FD_STEP;
        double Em = bg_elastic_eval(md, q, gm);
        q[j] = qj;
        assert_true(fabs((Ep - Em) / (2 * FD_STEP) - g[j]) <= 1e-6 * (1 + fabs(g[j])));
        for (int i = 0; i < N; i++) {
            double fd = (gp[i] - gm[i]) / (2 * FD_STEP);
            int lo = i < j ? i : j, hi = i < j ? j : i;
            double h = H[lo * N + hi];
            assert_true(fabs(fd - h) <= 1e-5 * (1 + fabs(h)));
        }
    }
    free(g);
    free(gp);
    free(gm);
    free(H);
    free(scatter);
}

static bg_mesh_t *small_rectangle(void)
{
    bg_mesh_t *m = NULL;
    const int32_t cells[2] = {3, 2};
    const double origin[2] = {0, 0}, size[2] = {1.2, 0.9};
    assert_int_equal(bg_mesh_generate_rectangle(cells, origin, size, &m, NULL), BG_OK);
    return m;
}

/* At a random deformed state, 2D and 3D. */
static void mesh_gradient_and_hessian(void **state)
{
    for (int n = 2; n <= 3; n++) {
        bg_mesh_t *m = n == 3 ? small_box() : small_rectangle();
        bg_elastic_t *md = NULL;
        assert_int_equal(bg_elastic_new(m, 0.7, 1.9, &md, NULL), BG_OK);
        const int N = n * m->nv;
        double *q = malloc(sizeof(double) * N);
        uint64_t rng = 99 + n;
        for (int i = 0; i < N; i++)
            q[i] = m->x[i] + 0.08 * (2 * test_uniform(&rng) - 1);
        check_mesh_derivatives(m, md, q);
        free(q);
        bg_elastic_destroy(&md);
        bg_mesh_destroy(&m);
    }
}

/*
 * The mesh-level kernels against one element at a time: on the 72-tet box
 * (nine blocks of the vectorised kernels) deformed so far that some
 * elements are inverted (scalar rotation-fit lanes), every element's
 * energy density (in mesh numbering, whatever order the model processes
 * elements in) equals bg_elastic_psi of its F, and the assembled exact
 * and projected Hessians equal Σ_e V Bᵀ (∂P/∂F) B built densely from
 * bg_elastic_psi's own ∂P/∂F (which projects per element with a 9×9
 * eigen-decomposition, independently of the closed form the assembly
 * uses). Once after evaluating at q, once after evaluating elsewhere (the
 * stored rotations then are not q's: the assembly must refit them). The
 * two sides fit rotations from different starts (cold polar or SVD here,
 * warm there) to 1e-14, which bounds the agreement: 1e-9 relative to the
 * largest entry.
 */
static void mesh_hessian_matches_elements(void **state)
{
    bg_mesh_t *m = small_box();
    const double mu = 0.7, lambda = 1.9;
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(m, mu, lambda, &md, NULL), BG_OK);
    const int N = 3 * m->nv, T = BG_ELASTIC_TRI_SIZE(12);
    double *q = malloc(sizeof(double) * N), *q2 = malloc(sizeof(double) * N);
    double *g = malloc(sizeof(double) * N);
    double *H = malloc(sizeof(double) * (size_t)N * N), *ref = malloc(sizeof(double) * (size_t)N * N);
    int32_t *scatter = malloc(sizeof(int32_t) * T * m->ne);
    uint64_t rng = 2024;
    for (int i = 0; i < N; i++) {
        q[i] = m->x[i] + 0.35 * (2 * test_uniform(&rng) - 1);
        q2[i] = q[i] + 0.05 * (2 * test_uniform(&rng) - 1);
    }
    int inverted = 0;
    for (int32_t e = 0; e < m->ne; e++)
        inverted += !(bg_mesh_element_measure(m, q, e) > 0.0);
    assert_true(inverted > 0 && inverted < m->ne);
    for (int32_t e = 0; e < m->ne; e++)
        for (int a = 0; a < 12; a++)
            for (int b = a; b < 12; b++) {
                const int ga = m->elements[e * 4 + a / 3] * 3 + a % 3;
                const int gb = m->elements[e * 4 + b / 3] * 3 + b % 3;
                const int lo = ga < gb ? ga : gb, hi = ga < gb ? gb : ga;
                scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(12, a, b)] = lo * N + hi;
            }
    for (int project = 0; project <= 1; project++)
        for (int elsewhere = 0; elsewhere <= 1; elsewhere++) {
            memset(ref, 0, sizeof(double) * (size_t)N * N);
            double largest = 0.0;
            bg_elastic_eval(md, q, g);
            const double *density = bg_elastic_energy_density(md);
            for (int32_t e = 0; e < m->ne; e++) {
                const int32_t *el = m->elements + 4 * e;
                double Dm[9], Ds[9], Di[9], F[9], P[9], dP[81], quat[4] = {0, 0, 0, 0};
                for (int j = 0; j < 3; j++)
                    for (int c = 0; c < 3; c++) {
                        Dm[3 * c + j] = m->x[3 * el[j + 1] + c] - m->x[3 * el[0] + c];
                        Ds[3 * c + j] = q[3 * el[j + 1] + c] - q[3 * el[0] + c];
                    }
                const double det = Dm[0] * (Dm[4] * Dm[8] - Dm[5] * Dm[7]) -
                                   Dm[1] * (Dm[3] * Dm[8] - Dm[5] * Dm[6]) +
                                   Dm[2] * (Dm[3] * Dm[7] - Dm[4] * Dm[6]);
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) {
                        const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3,
                                  j2 = (j + 2) % 3;
                        Di[3 * j + i] =
                            (Dm[3 * i1 + j1] * Dm[3 * i2 + j2] - Dm[3 * i1 + j2] * Dm[3 * i2 + j1]) /
                            det;
                    }
                for (int i = 0; i < 9; i++) {
                    F[i] = 0.0;
                    for (int k = 0; k < 3; k++)
                        F[i] += Ds[3 * (i / 3) + k] * Di[3 * k + i % 3];
                }
                const double psi = bg_elastic_psi(3, mu, lambda, F, quat, P, dP, project);
                if (!(fabs(psi - density[e]) <= 1e-10 * (1.0 + fabs(psi))))
                    fail_msg("element %d: density %.17g, bg_elastic_psi %.17g", e, density[e],
                             psi);
                /* B: vec(F) = B x_e, F_ab = Σ_node x_node,a g_node,b */
                double gr[4][3];
                for (int b = 0; b < 3; b++) {
                    gr[0][b] = 0.0;
                    for (int j = 0; j < 3; j++) {
                        gr[j + 1][b] = Di[3 * j + b];
                        gr[0][b] -= Di[3 * j + b];
                    }
                }
                const double V = fabs(det) / 6.0;
                for (int A = 0; A < 12; A++)
                    for (int Bc = 0; Bc < 12; Bc++) {
                        double k = 0.0;
                        for (int b = 0; b < 3; b++)
                            for (int d = 0; d < 3; d++)
                                k += gr[A / 3][b] * dP[(3 * (A % 3) + b) * 9 + 3 * (Bc % 3) + d] *
                                     gr[Bc / 3][d];
                        const int ga = el[A / 3] * 3 + A % 3, gb = el[Bc / 3] * 3 + Bc % 3;
                        if (ga <= gb)
                            ref[ga * N + gb] += V * k;
                    }
            }
            for (size_t i = 0; i < (size_t)N * N; i++)
                largest = fmax(largest, fabs(ref[i]));
            if (elsewhere)
                bg_elastic_eval(md, q2, g); /* the stored rotations are q2's now */
            memset(H, 0, sizeof(double) * (size_t)N * N);
            bg_elastic_assemble_hessian(md, q, project, 1.0, scatter, H);
            double worst = 0.0;
            for (size_t i = 0; i < (size_t)N * N; i++)
                worst = fmax(worst, fabs(H[i] - ref[i]));
            print_message("  project %d, rotations %s: %d inverted of %d, max |H - ref| %.3e of "
                          "%.3e\n",
                          project, elsewhere ? "elsewhere" : "at q", inverted, m->ne, worst,
                          largest);
            assert_true(worst <= 1e-9 * largest);
        }
    free(q);
    free(q2);
    free(g);
    free(H);
    free(ref);
    free(scatter);
    bg_elastic_destroy(&md);
    bg_mesh_destroy(&m);
}

/* The 2D area barrier: with the rectangle squashed to 4 % of its height
 * (every triangle below the knee, J ≈ 0.04), gradient and Hessian match
 * finite differences; its projected Hessian blocks are PSD; a flipped
 * triangle costs +∞; above the knee the barrier adds nothing. */
static void area_barrier(void **state)
{
    bg_mesh_t *m = small_rectangle();
    bg_elastic_t *md = NULL, *plain = NULL;
    assert_int_equal(bg_elastic_new(m, 0.5, 0.0, &md, NULL), BG_OK);
    assert_int_equal(bg_elastic_new(m, 0.5, 0.0, &plain, NULL), BG_OK);
    bg_elastic_set_barrier(md, 2.0);
    const int N = 2 * m->nv;
    double *q = malloc(sizeof(double) * N);
    uint64_t rng = 7;
    for (int v = 0; v < m->nv; v++) {
        q[2 * v] = m->x[2 * v] + 0.01 * (2 * test_uniform(&rng) - 1);
        q[2 * v + 1] = 0.04 * m->x[2 * v + 1] + 0.0005 * (2 * test_uniform(&rng) - 1);
    }
    const double squashed = bg_elastic_eval(md, q, NULL), without = bg_elastic_eval(plain, q, NULL);
    assert_true(squashed > without);
    check_mesh_derivatives(m, md, q);
    /* Above the knee (a mild stretch): identical energies. */
    for (int i = 0; i < N; i++)
        q[i] = 1.1 * m->x[i];
    assert_true(bg_elastic_eval(md, q, NULL) == bg_elastic_eval(plain, q, NULL));
    /* Mirror every y: all triangles flipped. */
    for (int v = 0; v < m->nv; v++)
        q[2 * v + 1] = -m->x[2 * v + 1];
    assert_true(bg_elastic_eval(md, q, NULL) == INFINITY);
    assert_true(isfinite(bg_elastic_eval(plain, q, NULL)));
    /* The projection: a random symmetric matrix becomes PSD with the same
     * eigenvectors; a PSD one stays as it was. */
    for (int trial = 0; trial < 50; trial++) {
        double A[16], P[16], S[16];
        for (int i = 0; i < 4; i++)
            for (int j = i; j < 4; j++)
                A[4 * i + j] = A[4 * j + i] = 2 * test_uniform(&rng) - 1;
        memcpy(P, A, sizeof A);
        bg_sym4_project(P);
        /* P − A is PSD-negative part removed: P is PSD (xᵀPx ≥ 0 on random
         * x) and P = A on A's nonnegative eigenspace, so P·P ≈ P·A. */
        for (int t = 0; t < 20; t++) {
            double x[4], Px[4] = {0, 0, 0, 0}, quad = 0.0;
            for (int i = 0; i < 4; i++)
                x[i] = 2 * test_uniform(&rng) - 1;
            for (int i = 0; i < 4; i++)
                for (int j = 0; j < 4; j++)
                    Px[i] += P[4 * i + j] * x[j];
            for (int i = 0; i < 4; i++)
                quad += x[i] * Px[i];
            assert_true(quad >= -1e-12);
        }
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++) {
                double pp = 0.0, pa = 0.0;
                for (int k = 0; k < 4; k++) {
                    pp += P[4 * i + k] * P[4 * k + j];
                    pa += P[4 * i + k] * A[4 * k + j];
                }
                assert_true(fabs(pp - pa) <= 1e-12);
            }
        /* S = PᵀP is PSD: unchanged by the projection. */
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++) {
                S[4 * i + j] = 0.0;
                for (int k = 0; k < 4; k++)
                    S[4 * i + j] += P[4 * k + i] * P[4 * k + j];
            }
        memcpy(P, S, sizeof S);
        bg_sym4_project(P);
        for (int i = 0; i < 16; i++)
            assert_true(fabs(P[i] - S[i]) <= 1e-12 * (1 + fabs(S[i])));
    }
    free(q);
    bg_elastic_destroy(&md);
    bg_elastic_destroy(&plain);
    bg_mesh_destroy(&m);
}

/*
 * bg_elastic_sym3_eigen, the closed form of the projected twist blocks,
 * against its own definition and against the cyclic Jacobi method it
 * replaced (bg_sym3_eigen): on random blocks (with and without a large
 * common diagonal), exactly and nearly repeated eigenvalues (gaps 1e-3 …
 * 1e-15 of the scale and zero), triples (q·I and q·I plus 1e-13 noise),
 * nearly singular and rank-one blocks, diagonal ones and scales 1e±150.
 * With N the largest |entry|, a backward-stable decomposition has
 * ‖V diag(y) Vᵀ − Y‖ and ‖VᵀV − I‖·N of a few ulps of N; by Weyl's
 * theorem two such decompositions' sorted eigenvalues then agree to the
 * sum of their backward errors, and the clamped blocks V diag(max(y − τ,
 * 0)) Vᵀ (the projection's rule, as a 1-Lipschitz function of y, whose
 * matrix function is √2-Lipschitz in the Frobenius norm) to √2 times it,
 * whatever the eigenvectors of a (nearly) repeated eigenvalue are. The
 * tolerance, 1e-14·N (45 ulps), is 2.4 times the worst case measured
 * (4.1e-15, printed); it fails on the broken variants tried: no 2×2
 * rotation (error 0.13), two Newton steps on the cubic instead of three
 * (3e-14), always the cross product of rows 0 and 1 (7e-14).
 */
static void rotation_from(uint64_t *rng, double Q[9])
{
    double q[4], n = 0.0;
    for (int i = 0; i < 4; i++) {
        q[i] = 2.0 * test_uniform(rng) - 1.0;
        n += q[i] * q[i];
    }
    n = sqrt(n);
    const double w = q[0] / n, x = q[1] / n, y = q[2] / n, z = q[3] / n;
    const double R[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                         2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                         2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
    memcpy(Q, R, sizeof R);
}

/* Y = Q diag(l) Qᵀ, symmetrised exactly */
static void rotated(const double Q[9], const double l[3], double Y[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = i; j < 3; j++) {
            double v = 0.0;
            for (int k = 0; k < 3; k++)
                v += Q[3 * i + k] * l[k] * Q[3 * j + k];
            Y[3 * i + j] = Y[3 * j + i] = v;
        }
}

static void sort3(double y[3])
{
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2 - i; j++)
            if (y[j] > y[j + 1]) {
                const double t = y[j];
                y[j] = y[j + 1];
                y[j + 1] = t;
            }
}

/* out = V diag(f(y)) Vᵀ, f(y) = max(y − tau, 0) (the clamping rule), or
 * f the identity when tau is NaN (the reconstruction) */
static void clamped(const double V[9], const double y[3], double tau, double out[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double v = 0.0;
            for (int k = 0; k < 3; k++) {
                const double f = isnan(tau) ? y[k] : fmax(y[k] - tau, 0.0);
                v += V[3 * i + k] * f * V[3 * j + k];
            }
            out[3 * i + j] = v;
        }
}

/* The worst of the four errors, relative to N, for one block. */
static double sym3_errors(const double Y[9], double tau)
{
    double N = 0.0;
    for (int i = 0; i < 9; i++)
        N = fmax(N, fabs(Y[i]));
    if (N == 0.0)
        N = 1.0;
    double y[3], V[9], yj[3], Vj[9], A[9], Aj[9], worst = 0.0;
    bg_elastic_sym3_eigen(Y, y, V);
    /* the Jacobi reference on Y scaled by a power of two to O(1) (its
     * stopping test squares the entries, which underflows at 1e-150) */
    int ex;
    frexp(N, &ex);
    double Ys[9];
    for (int i = 0; i < 9; i++)
        Ys[i] = ldexp(Y[i], -ex);
    bg_sym3_eigen(Ys, yj, Vj);
    for (int k = 0; k < 3; k++)
        yj[k] = ldexp(yj[k], ex);
    for (int k = 0; k < 3; k++)
        if (!isfinite(y[k]))
            return INFINITY;
    clamped(V, y, NAN, A);
    for (int i = 0; i < 9; i++)
        worst = fmax(worst, fabs(A[i] - Y[i]) / N);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            const double d = V[i] * V[j] + V[3 + i] * V[3 + j] + V[6 + i] * V[6 + j];
            worst = fmax(worst, fabs(d - (i == j ? 1.0 : 0.0)));
        }
    double ys[3] = {y[0], y[1], y[2]}, yjs[3] = {yj[0], yj[1], yj[2]};
    sort3(ys);
    sort3(yjs);
    for (int k = 0; k < 3; k++)
        worst = fmax(worst, fabs(ys[k] - yjs[k]) / N);
    clamped(V, y, tau, A);
    clamped(Vj, yj, tau, Aj);
    for (int i = 0; i < 9; i++)
        worst = fmax(worst, fabs(A[i] - Aj[i]) / N);
    return worst;
}

static void sym3_closed_form(void **state)
{
    uint64_t rng = 29;
    const char *names[] = {"random",   "random + 1e3 I", "repeated pair", "near pair",
                           "triple",   "near triple",    "near singular", "rank one",
                           "diagonal", "scale 1e-150",   "scale 1e150"};
    enum { KINDS = sizeof names / sizeof *names, TRIALS = 2000 };
    static const double gaps[] = {1e-3, 1e-6, 1e-9, 1e-12, 1e-15, 0.0};
    double total = 0.0;
    for (int kind = 0; kind < KINDS; kind++) {
        double kind_worst = 0.0;
        for (int trial = 0; trial < TRIALS; trial++) {
            double Y[9], Q[9], l[3];
            rotation_from(&rng, Q);
            for (int k = 0; k < 3; k++)
                l[k] = 2.0 * test_uniform(&rng) - 1.0;
            const double gap = gaps[trial % 6];
            switch (kind) {
            case 0:
            case 1:
            case 9:
            case 10:
                for (int i = 0; i < 3; i++)
                    for (int j = i; j < 3; j++)
                        Y[3 * i + j] = Y[3 * j + i] = 2.0 * test_uniform(&rng) - 1.0;
                for (int i = 0; i < 9; i++)
                    Y[i] *= kind == 9 ? 1e-150 : kind == 10 ? 1e150 : 1.0;
                if (kind == 1)
                    Y[0] += 1e3, Y[4] += 1e3, Y[8] += 1e3;
                break;
            case 2:
            case 3:
                l[1] = l[0] + (kind == 2 ? 0.0 : gap);
                rotated(Q, l, Y);
                break;
            case 4:
            case 5:
                l[1] = l[2] = l[0];
                rotated(Q, l, Y);
                if (kind == 5)
                    for (int i = 0; i < 3; i++)
                        for (int j = i; j < 3; j++)
                            Y[3 * i + j] = Y[3 * j + i] =
                                Y[3 * i + j] + 1e-13 * (2.0 * test_uniform(&rng) - 1.0);
                break;
            case 6:
                l[1] = gap, l[2] = -gap;
                rotated(Q, l, Y);
                break;
            case 7:
                l[1] = l[2] = 0.0;
                rotated(Q, l, Y);
                break;
            default: /* 8: diagonal, some entries equal */
                memset(Y, 0, sizeof Y);
                Y[0] = l[0], Y[4] = trial % 3 ? l[1] : l[0], Y[8] = trial % 5 ? l[2] : l[0];
                break;
            }
            /* clamp at a threshold inside the spectrum (eigenvalues on
             * both sides of it) */
            const double tau = (Y[0] + Y[4] + Y[8]) / 3.0;
            const double e = sym3_errors(Y, tau);
            if (!(e <= 1e-14))
                fail_msg("%s, trial %d: error %.3e of the largest entry (tolerance 1e-14)",
                         names[kind], trial, e);
            kind_worst = fmax(kind_worst, e);
        }
        print_message("  %-15s worst %.2e\n", names[kind], kind_worst);
        total = fmax(total, kind_worst);
    }
    const double zero[9] = {0};
    assert_true(sym3_errors(zero, 0.0) <= 1e-14);
    print_message("  all: worst %.2e of the largest entry\n", total);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(gradient_2d),
        cmocka_unit_test(gradient_3d),
        cmocka_unit_test(hessian_2d),
        cmocka_unit_test(hessian_3d),
        cmocka_unit_test(hessian_eigenvalues_diag),
        cmocka_unit_test(projected_hessian_psd),
        cmocka_unit_test(area_barrier),
        cmocka_unit_test(uniform_scale_energy),
        cmocka_unit_test(rotation_fit_paths),
        cmocka_unit_test(rigid_motion_zero),
        cmocka_unit_test(mesh_gradient_and_hessian),
        cmocka_unit_test(mesh_hessian_matches_elements),
        cmocka_unit_test(sym3_closed_form),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
