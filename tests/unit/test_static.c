/*
 * Static solves against analytic answers and against each other: the
 * uniaxial bar (lateral contraction −ν(s − 1)), the patch test, Newton and
 * local/global reaching the same minimizer, quadratic convergence read from
 * the trace, and the stiff and extreme cases (inverted start, λ/μ = 10⁴,
 * random initial positions): always finite, energy never increasing.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "bg_elastic.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "test_scenes.h"
#include "test_support.h"

static void solve_chords(const bg_scene_t *s, bg_method method, double tol, int max_it,
                         int chord_steps, bg_solve_result_t *r)
{
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {
        .method = method, .tolerance = tol, .max_iterations = max_it, .chord_steps = chord_steps};
    if (bg_static_solve(s, &o, r, &err) != BG_OK)
        fail_msg("%s", err.message);
}

static void solve(const bg_scene_t *s, bg_method method, double tol, int max_it,
                  bg_solve_result_t *r)
{
    solve_chords(s, method, tol, max_it, 0, r);
}

/* Every trace point finite, the energy never increasing beyond round-off
 * (the line search accepts a non-Armijo step only within 64 ulps of the
 * energy's magnitude, and only if the gradient shrinks) within a
 * continuation stage (between two, λ and with it the energy grows). */
static void assert_stable(const bg_scene_t *s, const bg_solve_result_t *r)
{
    for (int i = 0; i < r->trace_count; i++) {
        assert_true(isfinite(r->trace[i].energy));
        assert_true(isfinite(r->trace[i].gradient_norm));
        if (i > 0 && r->trace[i].stage == r->trace[i - 1].stage)
            assert_true(r->trace[i].energy <=
                        r->trace[i - 1].energy + 1e-13 * fabs(r->trace[0].energy) + 1e-300);
    }
    for (size_t k = 0; k < (size_t)s->mesh->nv * s->mesh->dim; k++)
        assert_true(isfinite(r->q[k]));
}

static double relative_distance(const double *a, const double *b, size_t n)
{
    double num = 0, den = 0;
    for (size_t i = 0; i < n; i++) {
        num += (a[i] - b[i]) * (a[i] - b[i]);
        den += b[i] * b[i];
    }
    return sqrt(num / den);
}

/* Uniaxial stretch by s = 1.2 with rollers and symmetry planes: the exact
 * minimizer is homogeneous, lateral stretch t with t − 1 = −ν(s − 1),
 * ν = λ/(2(λ + μ)). Checked on every vertex, to 1e-6 as the issue asks
 * (Newton lands on it to round-off). */
static void uniaxial_bar(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "stretch-bar.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-12, 50, &r);
    assert_true(r.converged);
    const double mu = s->material.mu, lambda = s->material.lambda;
    const double nu = lambda / (2 * (lambda + mu)), t = 1.0 - nu * 0.2;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *x = s->mesh->x + 3 * (size_t)v, *q = r.q + 3 * (size_t)v;
        assert_true(fabs(q[0] - 1.2 * x[0]) <= 1e-6);
        assert_true(fabs(q[1] - t * x[1]) <= 1e-6);
        assert_true(fabs(q[2] - t * x[2]) <= 1e-6);
    }
    assert_stable(s, &r);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* Patch test: the boundary moved by an affine map x ↦ A x + b; the
 * minimizer is that map everywhere (every element has the same F, so the
 * interior forces Σ V_e P ∇φ cancel). Written as a positions file so the
 * test exercises the handle path users take. */
static void patch_test_dim(int d)
{
    char dir[] = "/tmp/bg-patch-XXXXXX";
    assert_non_null(mkdtemp(dir));
    char positions[256], json[8192];
    snprintf(positions, sizeof positions, "%s/affine.txt", dir);
    const double A[3][3] = {{1.1, 0.2, 0.0}, {-0.1, 0.9, 0.15}, {0.05, 0.0, 1.2}};
    const double b[3] = {0.3, -0.2, 0.1};
    const int cells = 4;
    /* Vertex order of the generators: x fastest, then y, then z. */
    FILE *f = fopen(positions, "w");
    assert_non_null(f);
    const int nz = d == 3 ? cells : 0;
    int boundary[4096], nb = 0;
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= cells; j++)
            for (int i = 0; i <= cells; i++) {
                double x[3] = {(double)i / cells, (double)j / cells, (double)k / cells};
                for (int r = 0; r < d; r++) {
                    double y = b[r];
                    for (int c = 0; c < d; c++)
                        y += A[r][c] * x[c];
                    fprintf(f, "%.17g ", y);
                }
                fputc('\n', f);
                int on = i == 0 || i == cells || j == 0 || j == cells ||
                         (d == 3 && (k == 0 || k == cells));
                if (on)
                    boundary[nb++] = (k * (cells + 1) + j) * (cells + 1) + i;
            }
    fclose(f);
    int len = snprintf(json, sizeof json,
                       "{\"mesh\": {\"generate\": \"%s\", \"cells\": %s, \"size\": %s},"
                       "\"material\": {\"mu\": 1, \"lambda\": 3},"
                       "\"handles\": [{\"select\": {\"vertices\": [",
                       d == 3 ? "box" : "rectangle", d == 3 ? "[4, 4, 4]" : "[4, 4]",
                       d == 3 ? "[1, 1, 1]" : "[1, 1]");
    for (int i = 0; i < nb; i++)
        len += snprintf(json + len, sizeof json - (size_t)len, "%s%d", i ? ", " : "", boundary[i]);
    snprintf(json + len, sizeof json - (size_t)len, "]}, \"positions\": \"%s\"}]}", positions);
    bg_scene_t *s = test_parse_scene(json, "inline.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-12, 50, &r);
    assert_true(r.converged);
    for (int32_t v = 0; v < s->mesh->nv; v++)
        for (int row = 0; row < d; row++) {
            double y = b[row];
            for (int c = 0; c < d; c++)
                y += A[row][c] * s->mesh->x[(size_t)v * d + c];
            assert_true(fabs(r.q[(size_t)v * d + row] - y) <= 1e-9);
        }
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
    remove(positions);
    rmdir(dir);
}

static void patch_test(void **state)
{
    patch_test_dim(2);
    patch_test_dim(3);
}

/*
 * Quadratic convergence read from the trace, above the round-off floor
 * (r > 1e-13): with r_{k+1} ≈ C r_k², the contraction q_k = r_{k+1}/r_k
 * itself shrinks like r_k, so near the end it collapses from one step to
 * the next. Linear convergence keeps q constant (projected-only Newton
 * ≈ 0.13 on plate-bend, local/global ≈ 0.95). Required: some step below
 * 1e-2 whose next contraction is ≤ 1e-2 and ≤ a tenth of its own.
 */
static int converges_quadratically(const bg_solve_result_t *r)
{
    for (int i = 1; i + 2 < r->trace_count; i++) {
        const double a = r->trace[i].relative_gradient, b = r->trace[i + 1].relative_gradient,
                     c = r->trace[i + 2].relative_gradient;
        if (a < 1e-2 && c > 1e-13 && a > 0 && b > 0 && c / b <= 1e-2 && c / b <= 0.1 * (b / a))
            return 1;
    }
    return 0;
}

static void methods_agree(const char *scene, double lg_tol, int lg_max, double agree)
{
    bg_scene_t *s = test_load_scene(scene);
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT, rl = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-10, 200, &rn);
    solve(s, BG_METHOD_LOCAL_GLOBAL, lg_tol, lg_max, &rl);
    assert_true(rn.converged);
    assert_stable(s, &rn);
    assert_stable(s, &rl);
    const size_t n = (size_t)s->mesh->nv * s->mesh->dim;
    double d = relative_distance(rl.q, rn.q, n);
    if (!(d <= agree))
        fail_msg("%s: methods differ by %g (> %g)", scene, d, agree);
    /* Plain Newton (no chord steps, which take the last digits in fewer
     * iterations than the trace can show a rate with) converges
     * quadratically — the Hessian is exact — to the same minimizer. */
    bg_solve_result_t rp = BG_SOLVE_RESULT_INIT;
    solve_chords(s, BG_METHOD_NEWTON, 1e-10, 200, -1, &rp);
    assert_true(rp.converged);
    assert_int_equal(rp.chord_steps, 0);
    if (!converges_quadratically(&rp))
        fail_msg("%s: Newton's trace shows no quadratic convergence", scene);
    d = relative_distance(rp.q, rn.q, n);
    if (!(d <= 1e-9))
        fail_msg("%s: Newton with and without chord steps differ by %g", scene, d);
    bg_solve_result_release(&rp);
    bg_solve_result_release(&rn);
    bg_solve_result_release(&rl);
    bg_scene_destroy(&s);
}

static void bar_twist_same_minimizer(void **state)
{
    methods_agree(SCENES "bar-twist.json", 1e-11, 3000, 1e-7);
}

/* Local/global converges linearly on the bunny, about 3.5x closer to
 * Newton's answer every 250 iterations (relative distance 1.7e-1 at the
 * start, 1.7e-4 at 500, 1.3e-5 at 1,000, 5e-10 at 3,000): 1,000 iterations
 * and 5e-5 leave a factor 4 for platform rounding without admitting a
 * different minimizer (the start itself is 1.7e-1 away). */
static void bunny_edit_same_minimizer(void **state)
{
    methods_agree(SCENES "bunny-edit.json", 1e-12, 1000, 5e-5);
}

/* Every tetrahedron inverted at the start; the solve must come back to the
 * rest shape up to a rigid motion: energy to round-off, every element's
 * edge lengths restored. The edge check is relative per element, so the
 * smallest tetrahedra (1e-9 of a volume of 0.2) need the gradient at its
 * round-off floor, not merely small: at a relative gradient of 7e-11 the
 * total energy is 1e-15 yet a sliver's edge is still 3.5e-6 off. */
static void inverted_bunny_recovers(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "inverted-bunny.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-13, 300, &r);
    assert_true(r.converged || r.roundoff_floor);
    assert_stable(s, &r);
    assert_true(r.rotfit.svd > 0); /* the inverted start went through the SVD path */
    assert_true(r.energy <= 1e-14 * r.trace[0].energy);
    const bg_mesh_t *m = s->mesh;
    assert_true(test_max_edge_change(m->elements, m->ne, 4, 3, m->x, r.q) <= 1e-6);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

static void stiff_bar_converges(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "stiff-bar.json");
    assert_true(s->material.lambda / s->material.mu >= 1e4);
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-8, 500, &r);
    assert_true(r.converged);
    assert_stable(s, &r);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* Random positions in the bounding box (scrambled, many elements inverted
 * or collapsed) must converge with both methods to the same state. */
static void random_start_converges(void **state)
{
    const char *json =
        "{\"mesh\": {\"generate\": \"box\", \"cells\": [8, 2, 2], \"size\": [4, 1, 1]},"
        "\"material\": {\"mu\": 1, \"lambda\": 1},"
        "\"handles\": [{\"select\": {\"box\": {\"min\": [0,0,0], \"max\": [0,1,1]}}},"
        "{\"select\": {\"box\": {\"min\": [4,0,0], \"max\": [4,1,1]}},"
        " \"transform\": {\"translate\": [0.5, 0, 0]}}],"
        "\"initial\": {\"random\": {\"seed\": 7}}}";
    bg_scene_t *s = test_parse_scene(json, "inline.json");
    bg_solve_result_t rn = BG_SOLVE_RESULT_INIT, rl = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-10, 500, &rn);
    solve(s, BG_METHOD_LOCAL_GLOBAL, 1e-10, 5000, &rl);
    assert_true(rn.converged);
    assert_true(rl.converged);
    assert_stable(s, &rn);
    assert_stable(s, &rl);
    assert_true(relative_distance(rl.q, rn.q, (size_t)s->mesh->nv * 3) <= 1e-6);
    bg_solve_result_release(&rn);
    bg_solve_result_release(&rl);
    bg_scene_destroy(&s);
}

/*
 * Gravity: at equilibrium the free coordinates carry no net force, and the
 * elastic forces of a translation-invariant energy sum to zero, so the
 * reaction at the held coordinates equals the weight of the free vertices:
 * Σ_held ∂E/∂q = −Σ_free m_v g (per component). An independent check of the
 * mass matrix and the gravity term, whatever the deformed shape.
 */
static void gravity_reaction_balances_weight(void **state)
{
    const char *json =
        "{\"mesh\": {\"generate\": \"box\", \"cells\": [12, 3, 3], \"size\": [3, 0.5, 0.5]},"
        "\"material\": {\"E\": 2e5, \"nu\": 0.3, \"density\": 1000},"
        "\"gravity\": [0, 0, -9.81],"
        "\"handles\": [{\"select\": {\"box\": {\"min\": [0,0,0], \"max\": [0,0.5,0.5]}}}]}";
    bg_scene_t *s = test_parse_scene(json, "inline.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    solve(s, BG_METHOD_NEWTON, 1e-11, 100, &r);
    assert_true(r.converged);
    assert_stable(s, &r);
    const bg_mesh_t *m = s->mesh;
    /* The beam sags: the free end moved down by a visible amount. */
    double tip = 0.0;
    for (int32_t v = 0; v < m->nv; v++)
        tip = fmin(tip, r.q[3 * (size_t)v + 2] - m->x[3 * (size_t)v + 2]);
    assert_true(tip < -1e-3);
    double *mass = malloc(sizeof(double) * (size_t)m->nv);
    double *grad = malloc(sizeof(double) * 3 * (size_t)m->nv);
    bg_static_lumped_mass(m, s->material.density, mass);
    bg_elastic_t *md = NULL;
    assert_int_equal(bg_elastic_new(m, s->material.mu, s->material.lambda, &md, NULL), BG_OK);
    bg_elastic_eval(md, r.q, grad);
    double total_mass = 0.0;
    for (int32_t v = 0; v < m->nv; v++)
        total_mass += mass[v];
    /* Lumped mass sums to density × volume. */
    assert_true(fabs(total_mass - 1000.0 * 3 * 0.5 * 0.5) <= 1e-9 * total_mass);
    for (int c = 0; c < 3; c++) {
        double reaction = 0.0, weight = 0.0;
        for (int32_t v = 0; v < m->nv; v++) {
            const size_t k = 3 * (size_t)v + c;
            if (s->constrained[k])
                reaction += grad[k];
            else
                weight += mass[v] * s->gravity[c];
        }
        assert_true(fabs(reaction + weight) <= 1e-7 * (fabs(weight) + 1e-3 * total_mass * 9.81));
    }
    free(mass);
    free(grad);
    bg_elastic_destroy(&md);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* A handle moving every vertex leaves nothing to solve: a clear error. */
static void nothing_free_is_an_error(void **state)
{
    bg_scene_t *s =
        test_parse_scene("{\"mesh\": {\"generate\": \"rectangle\", \"cells\": [2, 2], \"size\": "
                         "[1, 1]}, \"material\": {\"mu\": 1, \"lambda\": 0}, \"handles\": "
                         "[{\"select\": {\"box_fraction\": {\"min\": [0, 0], \"max\": [1, 1]}}}]}",
                         "inline.json");
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {
        .method = BG_METHOD_NEWTON, .tolerance = 1e-8, .max_iterations = 10};
    assert_int_equal(bg_static_solve(s, &o, &r, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "nothing to solve"));
    bg_scene_destroy(&s);
}

/* A reference that becomes ready only at the ready_after-th time the solve
 * asks (the coordinator's reference thread, made deterministic). */
typedef struct late_reference {
    const double *q;
    int asked, ready_after;
} late_reference_t;

static const double *late_reference(void *ctx, int wait)
{
    late_reference_t *l = ctx;
    return wait || ++l->asked > l->ready_after ? l->q : NULL;
}

/* The error column of a run whose reference was computed alongside (its
 * first points kept and measured after the run) is the column of the run
 * given the reference from the start, to the bit, and the run itself (its
 * energies, its result) is the same run. */
static void reference_alongside_same_errors(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "bar-twist.json");
    const size_t ndof = (size_t)s->mesh->nv * s->mesh->dim;
    bg_error_t err = BG_ERROR_INIT;
    bg_solve_result_t ref = BG_SOLVE_RESULT_INIT, seq = BG_SOLVE_RESULT_INIT,
                      late = BG_SOLVE_RESULT_INIT;
    const bg_solve_options_t ro = {
        .method = BG_METHOD_NEWTON, .tolerance = 1e-13, .max_iterations = 200};
    if (bg_static_solve(s, &ro, &ref, &err) != BG_OK)
        fail_msg("%s", err.message);
    bg_solve_options_t o = {
        .method = BG_METHOD_LOCAL_GLOBAL, .tolerance = 1e-6, .max_iterations = 60,
        .reference = ref.q};
    if (bg_static_solve(s, &o, &seq, &err) != BG_OK)
        fail_msg("%s", err.message);
    late_reference_t l = {ref.q, 0, 7};
    o.reference = NULL;
    o.reference_ready = late_reference;
    o.reference_ctx = &l;
    if (bg_static_solve(s, &o, &late, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_true(seq.trace_count > 10);
    assert_int_equal(late.trace_count, seq.trace_count);
    assert_int_equal(late.pending_count, 7);
    assert_true(isnan(late.trace[6].error) && !isnan(late.trace[7].error));
    bg_static_fill_errors(&late, ref.q, ndof);
    assert_null(late.pending);
    for (int k = 0; k < seq.trace_count; k++) {
        assert_memory_equal(&late.trace[k].error, &seq.trace[k].error, sizeof(double));
        assert_memory_equal(&late.trace[k].energy, &seq.trace[k].energy, sizeof(double));
    }
    assert_memory_equal(late.q, seq.q, ndof * sizeof *seq.q);
    bg_solve_result_release(&late);
    bg_solve_result_release(&seq);
    bg_solve_result_release(&ref);
    bg_scene_destroy(&s);
}

/* A staged solve (continuation) refuses a reference computed alongside:
 * its stages' pending rows would not follow the merged trace. */
static void reference_alongside_not_staged(void **state)
{
    bg_scene_t *s = test_load_scene(SCENES "stiff-bar.json");
    late_reference_t l = {NULL, 0, 0};
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {.method = BG_METHOD_NEWTON, .tolerance = 1e-8,
                                  .max_iterations = 10, .reference_ready = late_reference,
                                  .reference_ctx = &l};
    assert_true(bg_static_continues(s, BG_METHOD_NEWTON));
    assert_int_equal(bg_static_solve(s, &o, &r, &err), BG_ERR_INVALID);
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(uniaxial_bar),
        cmocka_unit_test(patch_test),
        cmocka_unit_test(bar_twist_same_minimizer),
        cmocka_unit_test(bunny_edit_same_minimizer),
        cmocka_unit_test(inverted_bunny_recovers),
        cmocka_unit_test(stiff_bar_converges),
        cmocka_unit_test(random_start_converges),
        cmocka_unit_test(gravity_reaction_balances_weight),
        cmocka_unit_test(nothing_free_is_an_error),
        cmocka_unit_test(reference_alongside_same_errors),
        cmocka_unit_test(reference_alongside_not_staged),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
