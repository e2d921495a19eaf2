/*
 * Scene files: the shipped scenes parse to the constraints they describe
 * (counts and targets recomputed here from the mesh, independently of the
 * selection code), material conversions, the exact uniaxial reference, the
 * 3-2-1 mount, and error messages that name the offending field.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "bg_mesh_io.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "test_scenes.h"

#define FIXTURES_DIR BG_SOURCE_DIR "/tests/fixtures/scenes/"
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif
#define EXACT 1e-12
#define CLOSE 1e-9

/* cmocka 1.1 compares only floats; doubles need their own check. */
#define assert_close(a, b, tol) check_close((a), (b), (tol), #a, __FILE__, __LINE__)

static void check_close(double a, double b, double tol, const char *expr, const char *file,
                        int line)
{
    if (!(fabs(a - b) <= tol))
        fail_msg("%s:%d: %s = %.17g, expected %.17g (tolerance %g)", file, line, expr, a, b, tol);
}

static int count_constrained(const bg_scene_t *s)
{
    int n = 0;
    for (size_t k = 0; k < (size_t)s->mesh->nv * s->mesh->dim; k++)
        n += s->constrained[k] != 0;
    return n;
}

static int near(double a, double b)
{
    return fabs(a - b) <= EXACT;
}

/*
 * Scenes whose handles move start from the interpolated guess (bg_initial).
 * On a bar clamped at x = 0 and turned at x = 4, linear finite elements
 * reproduce the harmonic weight w = x/4 exactly, so every vertex starts
 * turned by (x/4)·degrees about the bar's axis: the uniform twist.
 */
static void assert_twist_initial(const bg_scene_t *s, int degrees)
{
    assert_int_equal(s->initial_kind, BG_INITIAL_INTERPOLATE);
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v;
        const double a = (p[0] / 4.0) * degrees * M_PI / 180.0;
        const double y = p[1] - 0.5, z = p[2] - 0.5;
        assert_close(s->initial[3 * (size_t)v], p[0], 1e-9);
        assert_close(s->initial[3 * (size_t)v + 1], 0.5 + cos(a) * y - sin(a) * z, 1e-9);
        assert_close(s->initial[3 * (size_t)v + 2], 0.5 + sin(a) * y + cos(a) * z, 1e-9);
    }
}

/* Checks a bar clamped at x = 0 and turned by `degrees` (90 or 180) about
 * the line y = z = 1/2 at x = 4. */
static void check_twisted_bar(const bg_scene_t *s, int nx, int ny, int nz, int degrees)
{
    assert_int_equal(s->mesh->dim, 3);
    assert_int_equal(s->mesh->nv, (nx + 1) * (ny + 1) * (nz + 1));
    assert_int_equal(s->mesh_format, BG_FORMAT_MEDIT);
    const int face = (ny + 1) * (nz + 1);
    int clamped = 0, turned = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v;
        const double *t = s->target + 3 * (size_t)v;
        const uint8_t *c = s->constrained + 3 * (size_t)v;
        if (near(p[0], 0.0)) {
            clamped++;
            assert_true(c[0] && c[1] && c[2]);
            for (int i = 0; i < 3; i++)
                assert_close(t[i], p[i], EXACT);
        } else if (near(p[0], 4.0)) {
            turned++;
            assert_true(c[0] && c[1] && c[2]);
            /* 180°: (4, y, z) -> (4, 1 - y, 1 - z); 90° about +x: (4, 1 - z, y). */
            double y = degrees == 180 ? 1.0 - p[1] : 1.0 - p[2];
            double z = degrees == 180 ? 1.0 - p[2] : p[1];
            assert_close(t[0], 4.0, EXACT);
            assert_close(t[1], y, EXACT);
            assert_close(t[2], z, EXACT);
        } else {
            assert_false(c[0] || c[1] || c[2]);
        }
    }
    assert_int_equal(clamped, face);
    assert_int_equal(turned, face);
    assert_int_equal(s->constrained_vertices, 2 * face);
    assert_int_equal(count_constrained(s), 3 * 2 * face);
    assert_int_equal(s->handle_count, 2);
    assert_int_equal(s->reference_kind, BG_REFERENCE_NEWTON);
    assert_null(s->reference);
    assert_int_equal(s->method, BG_METHOD_NEWTON);
    assert_int_equal(s->task, BG_TASK_STATIC);
    assert_twist_initial(s, degrees);
}

static void test_bar_twist(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "bar-twist.json");
    check_twisted_bar(s, 24, 6, 6, 180);
    assert_int_equal(s->constrained_vertices, 98); /* two faces of 7 x 7 */
    assert_string_equal(s->name, "bar-twist");
    assert_string_equal(s->mesh_source, "generated box 24x6x6");
    assert_close(s->material.mu, 1.0, 0.0);
    assert_close(s->material.lambda, 1.0, 0.0);
    assert_close(s->material.density, 1000.0, 0.0);
    assert_close(s->tolerance, 1e-8, 0.0);
    assert_int_equal(s->max_iterations, 200);
    /* Two vertices by hand: (4, 0, 1/6) -> (4, 1, 5/6); (4, 1/2, 1/2) fixed. */
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v, *t = s->target + 3 * (size_t)v;
        if (near(p[0], 4.0) && near(p[1], 0.0) && near(p[2], 1.0 / 6.0)) {
            assert_close(t[1], 1.0, EXACT);
            assert_close(t[2], 5.0 / 6.0, EXACT);
        }
        if (near(p[0], 4.0) && near(p[1], 0.5) && near(p[2], 0.5)) {
            assert_close(t[1], 0.5, EXACT);
            assert_close(t[2], 0.5, EXACT);
        }
    }
    bg_scene_destroy(&s);
    assert_null(s);
}

static void test_stiff_bar(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "stiff-bar.json");
    check_twisted_bar(s, 16, 4, 4, 90);
    assert_close(s->material.lambda, 1e4, 0.0);
    assert_int_equal(s->max_iterations, 500);
    bg_scene_destroy(&s);
}

static void test_stretch_bar(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "stretch-bar.json");
    assert_int_equal(s->mesh->nv, 17 * 5 * 5);
    int per_axis[3] = {0, 0, 0}, vertices = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v, *t = s->target + 3 * (size_t)v;
        const uint8_t *c = s->constrained + 3 * (size_t)v;
        int want_x = near(p[0], 0.0) || near(p[0], 2.0);
        int want_y = near(p[1], 0.0), want_z = near(p[2], 0.0);
        assert_int_equal(c[0], want_x);
        assert_int_equal(c[1], want_y);
        assert_int_equal(c[2], want_z);
        per_axis[0] += want_x;
        per_axis[1] += want_y;
        per_axis[2] += want_z;
        vertices += want_x || want_y || want_z;
        if (near(p[0], 2.0))
            assert_close(t[0], 2.4, EXACT);
        if (want_y)
            assert_close(t[1], 0.0, 0.0);
    }
    assert_int_equal(per_axis[0], 2 * 5 * 5);
    assert_int_equal(per_axis[1], 17 * 5);
    assert_int_equal(per_axis[2], 17 * 5);
    assert_int_equal(count_constrained(s), 50 + 85 + 85);
    assert_int_equal(vertices, 17 * 25 - 15 * 16);
    assert_int_equal(s->constrained_vertices, vertices);
    assert_close(s->tolerance, 1e-10, 0.0);
    /* Exact reference: nu = lambda / (2 (lambda + mu)) = 1/3, t = 1 - nu (s - 1). */
    assert_int_equal(s->reference_kind, BG_REFERENCE_POSITIONS);
    const double lateral = 1.0 - (2.0 / (2.0 * 3.0)) * 0.2;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v, *r = s->reference + 3 * (size_t)v;
        assert_close(r[0], 1.2 * p[0], EXACT);
        assert_close(r[1], lateral * p[1], EXACT);
        assert_close(r[2], lateral * p[2], EXACT);
    }
    /* The reference satisfies the roller data it has to. */
    for (int32_t v = 0; v < s->mesh->nv; v++)
        for (int c = 0; c < 3; c++)
            if (s->constrained[3 * (size_t)v + c])
                assert_close(s->reference[3 * (size_t)v + c], s->target[3 * (size_t)v + c], EXACT);
    bg_scene_destroy(&s);
}

static void test_plate_bend(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "plate-bend.json");
    assert_int_equal(s->mesh->dim, 2);
    assert_int_equal(s->mesh->nv, 41 * 11);
    assert_int_equal(s->mesh_format, BG_FORMAT_OBJ);
    int left = 0, right = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 2 * (size_t)v, *t = s->target + 2 * (size_t)v;
        const uint8_t *c = s->constrained + 2 * (size_t)v;
        if (near(p[0], 0.0)) {
            left++;
            assert_true(c[0] && c[1]);
            assert_close(t[1], p[1], 0.0);
        } else if (near(p[0], 4.0)) {
            right++;
            assert_true(c[0] && c[1]);
            assert_close(t[0], 4.0, EXACT);
            assert_close(t[1], p[1] + 1.5, EXACT);
        } else {
            assert_false(c[0] || c[1]);
        }
    }
    assert_int_equal(left, 11);
    assert_int_equal(right, 11);
    assert_int_equal(s->constrained_vertices, 22);
    assert_int_equal(count_constrained(s), 44);
    /* E = 1, nu = 0.35: mu = 1 / 2.7, lambda = 0.35 / (1.35 * 0.3). */
    assert_close(s->material.mu, 1.0 / 2.7, EXACT);
    assert_close(s->material.lambda, 0.35 / (1.35 * 0.3), EXACT);
    /* Interpolated start: the harmonic weight is x/4, so the translation
     * (0, 1.5) of the right edge is shared out linearly along the plate. */
    assert_int_equal(s->initial_kind, BG_INITIAL_INTERPOLATE);
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 2 * (size_t)v;
        assert_close(s->initial[2 * (size_t)v], p[0], 1e-9);
        assert_close(s->initial[2 * (size_t)v + 1], p[1] + 1.5 * p[0] / 4.0, 1e-9);
    }
    bg_scene_destroy(&s);
}

static void test_bunny_edit(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "bunny-edit.json");
    assert_int_equal(s->mesh->dim, 3);
    assert_int_equal(s->mesh->nodes_per_element, 4);
    /* The scene found the build's bunny through the search path: the same
     * mesh as the file read directly. */
    bg_mesh_t *file = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_read(MESHES "bunny.mesh", &file, NULL, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_int_equal(s->mesh->nv, file->nv);
    assert_int_equal(s->mesh->ne, file->ne);
    assert_memory_equal(s->mesh->x, file->x, 3 * (size_t)file->nv * sizeof *file->x);
    bg_mesh_destroy(&file);
    assert_int_equal(s->mesh_format, BG_FORMAT_MEDIT);
    assert_non_null(strstr(s->mesh_source, "share/biotgrid/meshes/bunny.mesh"));
    double lo = INFINITY, hi = -INFINITY;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        lo = fmin(lo, s->mesh->x[3 * (size_t)v + 1]);
        hi = fmax(hi, s->mesh->x[3 * (size_t)v + 1]);
    }
    const double base_top = lo + 0.08 * (hi - lo), ears = lo + 0.85 * (hi - lo);
    int base = 0, pull = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v, *t = s->target + 3 * (size_t)v;
        const uint8_t *c = s->constrained + 3 * (size_t)v;
        if (p[1] <= base_top) {
            base++;
            assert_true(c[0] && c[1] && c[2]);
            assert_close(t[1], p[1], 0.0);
        } else if (p[1] >= ears) {
            pull++;
            assert_true(c[0] && c[1] && c[2]);
            assert_close(t[0], p[0] + 0.5, EXACT);
            assert_close(t[1], p[1] + 0.3, EXACT);
            assert_close(t[2], p[2], EXACT);
        } else {
            assert_false(c[0] || c[1] || c[2]);
        }
    }
    assert_true(base > 0);
    assert_true(pull > 0);
    assert_int_equal(s->constrained_vertices, base + pull);
    assert_int_equal(count_constrained(s), 3 * (base + pull));
    assert_int_equal(s->reference_kind, BG_REFERENCE_NEWTON);
    bg_scene_destroy(&s);
}

/* Determinant by Gaussian elimination with partial pivoting (a is n×n, destroyed). */
static double determinant(double *a, int n)
{
    double det = 1.0;
    for (int col = 0; col < n; col++) {
        int pivot = col;
        for (int r = col + 1; r < n; r++)
            if (fabs(a[r * n + col]) > fabs(a[pivot * n + col]))
                pivot = r;
        if (a[pivot * n + col] == 0.0)
            return 0.0;
        if (pivot != col) {
            for (int k = 0; k < n; k++) {
                double t = a[col * n + k];
                a[col * n + k] = a[pivot * n + k];
                a[pivot * n + k] = t;
            }
            det = -det;
        }
        det *= a[col * n + col];
        for (int r = col + 1; r < n; r++) {
            double f = a[r * n + col] / a[col * n + col];
            for (int k = col; k < n; k++)
                a[r * n + k] -= f * a[col * n + k];
        }
    }
    return det;
}

/*
 * The mount must remove every rigid motion: the rows of the rigid-motion
 * basis (translations; infinitesimal rotations about the centroid, scaled
 * by the extent so the entries are O(1)) at the constrained coordinates
 * form a square nonsingular matrix.
 */
static void assert_mount_is_321(const bg_scene_t *s)
{
    const int d = s->mesh->dim, modes = d == 3 ? 6 : 3;
    assert_int_equal(count_constrained(s), modes);
    assert_int_equal(s->constrained_vertices, d);
    double centre[3] = {0, 0, 0}, lo[3], hi[3], extent = 0.0;
    bg_mesh_bounds(s->mesh, lo, hi);
    for (int c = 0; c < d; c++) {
        centre[c] = 0.5 * (lo[c] + hi[c]);
        extent = fmax(extent, hi[c] - lo[c]);
    }
    double m[36];
    int row = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++)
        for (int c = 0; c < d; c++) {
            if (!s->constrained[(size_t)v * d + c])
                continue;
            assert_close(s->target[(size_t)v * d + c], s->mesh->x[(size_t)v * d + c], 0.0);
            double q[3] = {0, 0, 0};
            for (int i = 0; i < d; i++)
                q[i] = (s->mesh->x[(size_t)v * d + i] - centre[i]) / extent;
            for (int t = 0; t < d; t++)
                m[row * modes + t] = t == c ? 1.0 : 0.0;
            if (d == 2) {
                /* rotation: (x, y) -> (-y, x) */
                m[row * modes + 2] = c == 0 ? -q[1] : q[0];
            } else {
                for (int axis = 0; axis < 3; axis++) {
                    double e[3] = {0, 0, 0}, w[3];
                    e[axis] = 1.0;
                    w[0] = e[1] * q[2] - e[2] * q[1];
                    w[1] = e[2] * q[0] - e[0] * q[2];
                    w[2] = e[0] * q[1] - e[1] * q[0];
                    m[row * modes + 3 + axis] = w[c];
                }
            }
            row++;
        }
    assert_int_equal(row, modes);
    double det = determinant(m, modes);
    if (!(fabs(det) > 1e-6))
        fail_msg("rigid-mount constraint matrix is singular: det = %g", det);
}

static void test_inverted_bunny(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(SCENES "inverted-bunny.json");
    assert_mount_is_321(s);
    assert_int_equal(s->max_iterations, 300);
    assert_int_equal(s->reference_kind, BG_REFERENCE_NONE);
    assert_int_equal(s->initial_kind, BG_INITIAL_GIVEN);
    const size_t n = (size_t)s->mesh->nv * 3;
    double centroid[3] = {0, 0, 0};
    for (int32_t v = 0; v < s->mesh->nv; v++)
        for (int c = 0; c < 3; c++)
            centroid[c] += s->mesh->x[3 * (size_t)v + c] / s->mesh->nv;
    for (size_t k = 0; k < n; k++) {
        double expect = s->constrained[k]
                            ? s->mesh->x[k]
                            : centroid[k % 3] - 0.75 * (s->mesh->x[k] - centroid[k % 3]);
        assert_close(s->initial[k], expect, CLOSE);
    }
    bg_scene_destroy(&s);
}

static void test_rigid_mount_generated(void **state)
{
    (void)state;
    bg_scene_t *s = test_parse_scene(
        "{\"mesh\": {\"generate\": \"rectangle\", \"cells\": [6, 3], \"size\": [3, 1.5],"
        " \"origin\": [1, -2]}, \"material\": {\"mu\": 1, \"lambda\": 1},"
        " \"handles\": [{\"select\": \"rigid-mount\"}]}",
        "inline.json");
    assert_mount_is_321(s);
    bg_scene_destroy(&s);
    s = test_parse_scene(
        "{\"mesh\": {\"generate\": \"box\", \"cells\": [3, 5, 2], \"size\": [1, 2, 0.5]},"
        " \"material\": {\"mu\": 1, \"lambda\": 1},"
        " \"handles\": [{\"select\": \"rigid-mount\"}]}",
        "inline.json");
    assert_mount_is_321(s);
    bg_scene_destroy(&s);
}

#define BOX_MESH "\"mesh\": {\"generate\": \"box\", \"cells\": [2, 2, 2], \"size\": [1, 1, 1]}"
#define RECT_MESH "\"mesh\": {\"generate\": \"rectangle\", \"cells\": [2, 2], \"size\": [1, 1]}"
#define FIX_ALL                                                                                    \
    "\"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0,0,0], \"max\": [0,1,1]}}}]"
#define FIX_ALL_2D                                                                                 \
    "\"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0,0], \"max\": [0,1]}}}]"

static void check_material(const char *json, double mu, double lambda)
{
    bg_scene_t *s = test_parse_scene(json, "inline.json");
    assert_close(s->material.mu, mu, EXACT);
    assert_close(s->material.lambda, lambda, EXACT);
    bg_scene_destroy(&s);
}

static void test_materials(void **state)
{
    (void)state;
    check_material("{" BOX_MESH ", " FIX_ALL ", \"material\": {\"mu\": 0.7, \"lambda\": 3}}", 0.7,
                   3.0);
    /* E = 2.6, nu = 0.3: mu = 2.6 / 2.6 = 1, lambda = 0.78 / (1.3 * 0.4) = 1.5. */
    check_material("{" BOX_MESH ", " FIX_ALL ", \"material\": {\"E\": 2.6, \"nu\": 0.3}}", 1.0,
                   1.5);
    /* alpha = 2, beta = 1: mu = 1/2, lambda = (4 - 1) / n. */
    check_material("{" BOX_MESH ", " FIX_ALL ", \"material\": {\"alpha\": 2, \"beta\": 1}}", 0.5,
                   1.0);
    check_material("{" RECT_MESH ", " FIX_ALL_2D ", \"material\": {\"alpha\": 2, \"beta\": 1}}",
                   0.5, 1.5);
    /* ARAP (alpha = beta = 1): mu = 1/2, lambda = 0. (ASAP, alpha = 0, has
     * 2 lambda + 2 mu = 0 and is refused: see test_bad_scenes.) */
    check_material("{" RECT_MESH ", " FIX_ALL_2D ", \"material\": {\"alpha\": 1, \"beta\": 1}}",
                   0.5, 0.0);
    /* A negative lambda is fine while 3 lambda + 2 mu > 0. */
    check_material("{" BOX_MESH ", " FIX_ALL ", \"material\": {\"mu\": 1, \"lambda\": -0.5}}", 1.0,
                   -0.5);
    bg_scene_t *s = test_parse_scene(
        "{" BOX_MESH ", " FIX_ALL ", \"material\": {\"mu\": 1, \"lambda\": 1, \"density\": 7850},"
        " \"gravity\": [0, -9.81, 0]}",
        "inline.json");
    assert_close(s->material.density, 7850.0, 0.0);
    assert_close(s->gravity[1], -9.81, 0.0);
    assert_close(s->gravity[0], 0.0, 0.0);
    bg_scene_destroy(&s);
}

static void test_uniaxial_planar(void **state)
{
    (void)state;
    /* Plane: nu = lambda / (2 mu + lambda) = 2 / 4; stretch 0.9 about origin [1, 1]. */
    bg_scene_t *s = test_parse_scene(
        "{" RECT_MESH ", " FIX_ALL_2D ", \"material\": {\"mu\": 1, \"lambda\": 2},"
        " \"reference\": {\"uniaxial\": {\"axis\": \"y\", \"stretch\": 0.9, \"origin\": [1, 1]}}}",
        "inline.json");
    const double t = 1.0 - 0.5 * (0.9 - 1.0);
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 2 * (size_t)v, *r = s->reference + 2 * (size_t)v;
        assert_close(r[0], 1.0 + t * (p[0] - 1.0), EXACT);
        assert_close(r[1], 1.0 + 0.9 * (p[1] - 1.0), EXACT);
    }
    /* The lateral stress of F = diag(t, s) vanishes: 2 mu (t - 1) + lambda (s + t - 2) = 0. */
    assert_close(2.0 * (t - 1.0) + 2.0 * (0.9 + t - 2.0), 0.0, EXACT);
    bg_scene_destroy(&s);
}

static void test_affine_reference_and_defaults(void **state)
{
    (void)state;
    bg_scene_t *s = test_parse_scene(
        "{" BOX_MESH ", " FIX_ALL ", \"material\": {\"mu\": 1, \"lambda\": 1},"
        " \"reference\": {\"affine\": {\"matrix\": [[2, 0, 0], [0, 1, 1], [0, 0, 1]],"
        " \"translation\": [1, 2, 3]}}}",
        "inline.json");
    assert_string_equal(s->name, "inline");
    assert_string_equal(s->path, "inline.json");
    assert_int_equal(s->method, BG_METHOD_NEWTON);
    assert_close(s->tolerance, BG_SCENE_DEFAULT_TOLERANCE, 0.0);
    assert_int_equal(s->max_iterations, BG_SCENE_DEFAULT_MAX_ITERATIONS);
    assert_int_equal(s->constrained_vertices, 9);
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        const double *p = s->mesh->x + 3 * (size_t)v, *r = s->reference + 3 * (size_t)v;
        assert_close(r[0], 2 * p[0] + 1, EXACT);
        assert_close(r[1], p[1] + p[2] + 2, EXACT);
        assert_close(r[2], p[2] + 3, EXACT);
    }
    bg_scene_destroy(&s);
}

static void test_agreeing_overlap_and_components(void **state)
{
    (void)state;
    /* Two fixed faces sharing an edge agree there; a roller and a fixed face
     * on the same coordinates with the same values are accepted too. */
    bg_scene_t *s = test_parse_scene(
        "{" BOX_MESH ", \"material\": {\"mu\": 1, \"lambda\": 1}, \"handles\": ["
        "{\"select\": {\"box\": {\"min\": [0,0,0], \"max\": [0,1,1]}}},"
        "{\"select\": {\"box\": {\"min\": [0,0,0], \"max\": [1,0,1]}}, \"components\": \"yz\"},"
        "{\"select\": {\"vertices\": [26]}, \"positions\": [[1.5, 1, 1]], \"components\": "
        "\"x\"}]}",
        "inline.json");
    assert_int_equal(s->handle_count, 3);
    assert_int_equal(s->constrained_vertices, 9 + 6 + 1);
    assert_int_equal(count_constrained(s), 27 + 12 + 1);
    assert_close(s->target[3 * 26], 1.5, 0.0);
    assert_false(s->constrained[3 * 26 + 1]);
    assert_close(s->initial[3 * 26], 1.5, 0.0);
    bg_scene_destroy(&s);
}

static void test_random_initial(void **state)
{
    (void)state;
    const char *fmt = "{" BOX_MESH ", " FIX_ALL ", \"material\": {\"mu\": 1, \"lambda\": 1},"
                      " \"initial\": {\"random\": {\"seed\": %d, \"extent\": 2}}}";
    char json[1024];
    snprintf(json, sizeof json, fmt, 7);
    bg_scene_t *a = test_parse_scene(json, "inline.json"),
               *b = test_parse_scene(json, "inline.json");
    snprintf(json, sizeof json, fmt, 8);
    bg_scene_t *c = test_parse_scene(json, "inline.json");
    int differ = 0;
    for (size_t k = 0; k < (size_t)a->mesh->nv * 3; k++) {
        assert_close(a->initial[k], b->initial[k], 0.0);
        differ += a->initial[k] != c->initial[k];
        if (a->constrained[k]) {
            assert_close(a->initial[k], a->target[k], 0.0);
        } else {
            /* extent 2 about the box centre 0.5: [-0.5, 1.5] */
            assert_true(a->initial[k] >= -0.5 && a->initial[k] <= 1.5);
        }
    }
    assert_true(differ > 0);
    bg_scene_destroy(&a);
    bg_scene_destroy(&b);
    bg_scene_destroy(&c);
}

static void test_planar_file_fixture(void **state)
{
    (void)state;
    bg_scene_t *s = test_load_scene(FIXTURES_DIR "flat-square.json");
    assert_string_equal(s->name, "flat-square");
    assert_int_equal(s->mesh->dim, 2);
    assert_int_equal(s->mesh->nv, 4);
    assert_int_equal(s->mesh_format, BG_FORMAT_OBJ);
    assert_non_null(strstr(s->mesh_source, "square.obj"));
    assert_int_equal(s->method, BG_METHOD_LOCAL_GLOBAL);
    assert_int_equal(s->max_iterations, 1000);
    /* planar alpha/beta: mu = 1/2, lambda = (4 - 1) / 2 */
    assert_close(s->material.lambda, 1.5, EXACT);
    static const double target[8] = {0, 0, 1.5, 0, 1.5, 1, 0, 1};
    for (int k = 0; k < 8; k++) {
        assert_true(s->constrained[k]);
        assert_close(s->target[k], target[k], 0.0);
        assert_close(s->initial[k], target[k], 0.0);
    }
    assert_int_equal(s->reference_kind, BG_REFERENCE_NONE);
    bg_scene_destroy(&s);
}

/* The bar the positions tests use: 11 x 3 x 3 vertices over [0,5]x[0,1]x[0,1]. */
#define TWIST_BAR "{\"generate\": \"box\", \"cells\": [10, 2, 2], \"size\": [5, 1, 1]}"
#define TWIST_BAR_VERTICES 99

/* The bar twisted half a turn about its axis (y = z = 0.5), each vertex by
 * π x / 5: written out from the box's own vertex numbering (x fastest, then
 * y, then z), independently of the scene library. */
static void twisted_bar(double *out)
{
    int v = 0;
    for (int k = 0; k <= 2; k++)
        for (int j = 0; j <= 2; j++)
            for (int i = 0; i <= 10; i++, v++) {
                const double x = 0.5 * i, y = 0.5 * j - 0.5, z = 0.5 * k - 0.5;
                const double a = M_PI * x / 5.0;
                out[3 * v] = x;
                out[3 * v + 1] = 0.5 + cos(a) * y - sin(a) * z;
                out[3 * v + 2] = 0.5 + sin(a) * y + cos(a) * z;
            }
}

/* task.target {"twist"} is the same pose, to round-off. */
static void test_morph_twist_target(void **state)
{
    (void)state;
    bg_scene_t *s = test_parse_scene(
        "{\"mesh\": " TWIST_BAR ", \"material\": {\"mu\": 1, \"lambda\": 1},"
        " \"task\": {\"kind\": \"morph\", \"target\": {\"twist\": {\"axis\": [2, 0, 0],"
        " \"degrees\": 180}}}}",
        "twist.json");
    double expected[3 * TWIST_BAR_VERTICES];
    twisted_bar(expected);
    assert_int_equal(s->mesh->nv, TWIST_BAR_VERTICES);
    for (int i = 0; i < 3 * TWIST_BAR_VERTICES; i++)
        assert_true(fabs(s->morph_target[i] - expected[i]) <= 1e-14);
    bg_scene_destroy(&s);
    /* Twists need an axis, a 3D mesh and no stray keys. */
    static const char *const bad[][2] = {
        {"{\"twist\": {\"degrees\": 90}}", "needs 'axis' and 'degrees'"},
        {"{\"twist\": {\"axis\": [0, 0, 0], \"degrees\": 90}}", "nonzero vector"},
        {"{\"twist\": {\"axis\": [1, 0, 0], \"degrees\": 90, \"turns\": 1}}", "turns"},
        {"{\"spin\": 1}", "spin"},
        {"7", "got a number"},
    };
    for (size_t b = 0; b < sizeof bad / sizeof bad[0]; b++) {
        char json[512];
        snprintf(json, sizeof json,
                 "{\"mesh\": " TWIST_BAR ", \"material\": {\"mu\": 1, \"lambda\": 1},"
                 " \"task\": {\"kind\": \"morph\", \"target\": %s}}",
                 bad[b][0]);
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bg_prepare_parse(json, strlen(json), "twist.json", NULL, &s, &err),
                         BG_ERR_INVALID);
        if (!strstr(err.message, bad[b][1]) || !strstr(err.message, "task.target"))
            fail_msg("%s: unexpected message: %s", bad[b][0], err.message);
    }
}

/* Elements × steps (or frames) against options.max_work, refused naming
 * the task's field before the mesh is built: a 180-million-element box
 * asked for 10 steps fails at once. */
static void test_work_cap(void **state)
{
    (void)state;
    static const char *const scenes[][2] = {
        {"{\"mesh\": {\"generate\": \"box\", \"cells\": [10, 10, 10], \"size\": [1, 1, 1]},"
         " \"material\": {\"E\": 1e4, \"nu\": 0.3}, \"task\": {\"kind\": \"dynamic\","
         " \"dt\": 0.01, \"steps\": 1000}}",
         "task.steps"},
        {"{\"mesh\": {\"generate\": \"box\", \"cells\": [10, 10, 10], \"size\": [1, 1, 1]},"
         " \"material\": {\"mu\": 1, \"lambda\": 1}, \"task\": {\"kind\": \"morph\","
         " \"frames\": 1000, \"target\": {\"twist\": {\"axis\": [1, 0, 0], \"degrees\": 90}}}}",
         "task.frames"},
        {"{\"mesh\": {\"generate\": \"box\", \"cells\": [1000, 1000, 30], \"size\": [1, 1, 1]},"
         " \"material\": {\"E\": 1e4, \"nu\": 0.3}, \"task\": {\"kind\": \"dynamic\","
         " \"dt\": 0.01, \"steps\": 10}}",
         "task.steps"},
    };
    for (size_t i = 0; i < sizeof scenes / sizeof scenes[0]; i++) {
        bg_scene_options_t o = {.max_work = 1e6};
        bg_scene_t *s = NULL;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bg_scene_parse_with(scenes[i][0], strlen(scenes[i][0]), "work.json", &o,
                                             &s, &err),
                         BG_ERR_LIMIT);
        if (!strstr(err.message, scenes[i][1]) || !strstr(err.message, "over the limit of 1e+06"))
            fail_msg("case %zu: %s", i, err.message);
        assert_null(s);
        if (i < 2) { /* 6,000 elements x 1,000 = 6e6: within a cap of 1e7 */
            o.max_work = 1e7;
            bg_error_clear(&err);
            if (bg_scene_parse_with(scenes[i][0], strlen(scenes[i][0]), "work.json", &o, &s,
                                    &err) != BG_OK)
                fail_msg("case %zu under the cap: %s", i, err.message);
            bg_scene_destroy(&s);
        }
    }
}

/* A scene of many small handles is refused before any is selected: each
 * selection scans every vertex, so 20,000 one-vertex handles (670 KB) on
 * a box of a million vertices took 14 s of CPU, and a 16 MB scene some
 * minutes. BG_SCENE_MAX_HANDLES handles are still served. */
static void test_handle_cap(void **state)
{
    (void)state;
    for (int extra = 0; extra <= 1; extra++) {
        const int handles = BG_SCENE_MAX_HANDLES + extra;
        char *text = malloc((size_t)handles * 48 + 256);
        assert_non_null(text);
        size_t n = (size_t)sprintf(text, "{\"mesh\": {\"generate\": \"box\", \"cells\": "
                                         "[10, 10, 10], \"size\": [1, 1, 1]}, \"material\": "
                                         "{\"mu\": 1, \"lambda\": 1}, \"handles\": [");
        for (int i = 0; i < handles; i++)
            n += (size_t)sprintf(text + n, "%s{\"select\": {\"vertices\": [%d]}}", i ? ", " : "",
                                 i);
        n += (size_t)sprintf(text + n, "]}");
        bg_scene_t *s = NULL;
        bg_error_t err = BG_ERROR_INIT;
        const bg_status st = bg_scene_parse_with(text, n, "handles.json", NULL, &s, &err);
        if (extra == 0) {
            if (st != BG_OK)
                fail_msg("%d handles: %s", handles, err.message);
            assert_int_equal(s->handle_count, handles);
        } else {
            assert_int_equal(st, BG_ERR_LIMIT);
            assert_null(s);
            if (!strstr(err.message, "handles.json: handles: 1025 handles, over the limit of 1024"))
                fail_msg("%s", err.message);
        }
        bg_scene_destroy(&s);
        free(text);
    }
}

/* A positions file with one line per mesh vertex (a twisted copy of the
 * bar) serves a handle (its selected rows) and a reference (all rows). */
static void test_whole_mesh_positions_file(void **state)
{
    (void)state;
    char dir[] = "/tmp/bg_scene_XXXXXX", file[64], json[1024];
    assert_non_null(mkdtemp(dir));
    snprintf(file, sizeof file, "%s/twisted.txt", dir);
    double twisted[3 * TWIST_BAR_VERTICES];
    twisted_bar(twisted);
    FILE *f = fopen(file, "w");
    assert_non_null(f);
    for (int v = 0; v < TWIST_BAR_VERTICES; v++)
        fprintf(f, "%.17g %.17g %.17g\n", twisted[3 * v], twisted[3 * v + 1], twisted[3 * v + 2]);
    assert_int_equal(fclose(f), 0);
    snprintf(json, sizeof json,
             "{\"mesh\": " TWIST_BAR ", \"material\": {\"mu\": 1, \"lambda\": 1},"
             " \"handles\": [{\"select\": {\"box_fraction\": {\"min\": [0, 0, 0], \"max\": [0.02, "
             "1, 1]}}},"
             " {\"select\": {\"box_fraction\": {\"min\": [0.98, 0, 0], \"max\": [1, 1, 1]}},"
             " \"positions\": \"%s\"}],"
             " \"reference\": {\"positions\": \"%s\"}}",
             file, file);
    bg_scene_t *s = test_parse_scene(json, "inline.json");
    assert_int_equal(remove(file), 0);
    assert_int_equal(rmdir(dir), 0);
    for (int i = 0; i < 3 * TWIST_BAR_VERTICES; i++)
        assert_true(s->reference[i] == twisted[i]); /* 17 digits read back exactly */
    assert_int_equal(s->reference_kind, BG_REFERENCE_POSITIONS);
    double lo = INFINITY, hi = -INFINITY;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        lo = fmin(lo, s->mesh->x[3 * (size_t)v]);
        hi = fmax(hi, s->mesh->x[3 * (size_t)v]);
    }
    int moved = 0, fixed = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        double x = s->mesh->x[3 * (size_t)v];
        for (int c = 0; c < 3; c++) {
            size_t k = 3 * (size_t)v + c;
            if (x >= lo + 0.98 * (hi - lo)) {
                assert_true(s->constrained[k]);
                assert_close(s->target[k], s->reference[k], 0.0);
                moved += c == 0;
            } else if (x <= lo + 0.02 * (hi - lo)) {
                assert_true(s->constrained[k]);
                assert_close(s->target[k], s->mesh->x[k], 0.0);
                fixed += c == 0;
            } else {
                assert_false(s->constrained[k]);
            }
        }
    }
    assert_true(moved > 0 && fixed > 0);
    assert_int_equal(s->constrained_vertices, moved + fixed);
    bg_scene_destroy(&s);
}

/* Every bad scene must fail with the given status and mention `needle`. */
typedef struct bad_case {
    const char *json;
    bg_status status;
    const char *needle;
} bad_case_t;

#define MAT "\"material\": {\"mu\": 1, \"lambda\": 1}"

static const bad_case_t BAD_CASES[] = {
    {"{\"mesh\": {\"generate\": \"box\",\n \"cells\": [1, 1, }", BG_ERR_PARSE, "line 2"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL "} trailing", BG_ERR_PARSE, "after the JSON value"},
    {"[1, 2]", BG_ERR_INVALID, "a scene is a JSON object"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": \"rigid-mount\"},"
     " {\"select\": {\"bx\": {}}}]}",
     BG_ERR_INVALID, "bad.json: handles[1].select: unknown key 'bx'"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"colour\": 1}", BG_ERR_INVALID, "unknown key 'colour'"},
    {"{" BOX_MESH ", \"material\": {\"mu\": \"1\", \"lambda\": 1}, " FIX_ALL "}", BG_ERR_INVALID,
     "material.mu: expected a number, got a string"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 2, 2], \"size\": [1e999, 1, 1]}, " MAT
     ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh.size[0]: must be a finite number"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [2, -3, 2], \"size\": [1, 1, 1]}, " MAT
     ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh.cells[1]: -3 is out of range"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [0, 2, 2], \"size\": [1, 1, 1]}, " MAT
     ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh.cells[0]: 0 is out of range"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 2, 2], \"size\": [1, 0, 1]}, " MAT
     ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh.size: size[1] = 0 must be positive"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 2.5, 2], \"size\": [1, 1, 1]}, " MAT
     ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh.cells[1]: expected an integer"},
    {"{\"mesh\": {\"generate\": \"sphere\"}, " MAT ", " FIX_ALL "}", BG_ERR_INVALID,
     "mesh.generate: unknown generator 'sphere'"},
    {"{" BOX_MESH ", " FIX_ALL "}", BG_ERR_INVALID, "material: missing"},
    {"{" BOX_MESH ", \"material\": {\"mu\": 1, \"lambda\": 1, \"E\": 1, \"nu\": 0.3}, " FIX_ALL "}",
     BG_ERR_INVALID, "material: give exactly one of"},
    {"{" BOX_MESH ", \"material\": {\"mu\": 1}, " FIX_ALL "}", BG_ERR_INVALID,
     "material: 'mu' needs 'lambda'"},
    {"{" BOX_MESH ", \"material\": {\"E\": 1, \"nu\": 0.5}, " FIX_ALL "}", BG_ERR_INVALID,
     "material.nu: Poisson's ratio must be in (-1, 0.5), got 0.5"},
    {"{" BOX_MESH ", \"material\": {\"mu\": 1, \"lambda\": -1}, " FIX_ALL "}", BG_ERR_INVALID,
     "unstable material mu = 1, lambda = -1"},
    {"{" RECT_MESH ", \"material\": {\"alpha\": 0, \"beta\": 1}, " FIX_ALL_2D "}", BG_ERR_INVALID,
     "unstable material"},
    {"{" BOX_MESH ", \"material\": {\"mu\": 0, \"lambda\": 1}, " FIX_ALL "}", BG_ERR_INVALID,
     "need mu > 0"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"solver\": {\"method\": \"gauss\"}}", BG_ERR_INVALID,
     "solver.method: unknown method 'gauss'"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"solver\": {\"tolerance\": 2}}", BG_ERR_INVALID,
     "solver.tolerance: must be in (0, 1), got 2"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"solver\": {\"max_iterations\": 0}}", BG_ERR_INVALID,
     "solver.max_iterations: 0 is out of range"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"solver\": {\"continuation\": 1}}", BG_ERR_INVALID,
     "solver.continuation: expected"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"name\": \"far\", \"select\": {\"box\":"
     " {\"min\": [5, 5, 5], \"max\": [6, 6, 6]}}}]}",
     BG_ERR_INVALID, "handles[0].select: handles[0] ('far') selects no vertex"},
    {"{" BOX_MESH ", " MAT ", \"handles\": ["
     "{\"name\": \"left\", \"select\": {\"box_fraction\":"
     " {\"min\": [0, 0, 0], \"max\": [0, 1, 1]}}},"
     "{\"name\": \"push\", \"select\": {\"box_fraction\": {\"min\": [0, 0, 0], \"max\": [1, 0, "
     "1]}},"
     " \"transform\": {\"translate\": [0, 0.1, 0]}}]}",
     BG_ERR_INVALID, "handles[1] ('push') and handles[0] ('left') prescribe different values"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": {\"vertices\": [0, 27]}}]}",
     BG_ERR_INVALID, "handles[0].select.vertices[1]: vertex index 27 is out of range"},
    {"{" BOX_MESH ", " MAT
     ", \"handles\": [{\"select\": {\"vertices\": [0]}, \"components\": \"xw\"}]}",
     BG_ERR_INVALID, "handles[0].components"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": {\"vertices\": [0]},"
     " \"transform\": {\"rotate\": {\"degrees\": 30}}}]}",
     BG_ERR_INVALID, "handles[0].transform.rotate.axis: missing"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": {\"vertices\": [0, 1]},"
     " \"positions\": [[0, 0, 0]]}]}",
     BG_ERR_INVALID, "handles[0].positions: expected an array of 2 positions"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": \"rigid-mount\","
     " \"transform\": {\"translate\": [1, 0, 0]}}]}",
     BG_ERR_INVALID, "remove 'transform'"},
    {"{" BOX_MESH ", " MAT ", \"handles\": [{\"select\": {\"box\": {\"min\": [0, 0, 0],"
     " \"max\": [0, 1, 1]}, \"ref\": 2}}]}",
     BG_ERR_INVALID, "give exactly one of box"},
    {"{" BOX_MESH ", " MAT "}", BG_ERR_INVALID, "handles: a static solve needs handles"},
    {"{" RECT_MESH ", " MAT ", " FIX_ALL_2D ", \"gravity\": [0, -9.81, 0]}", BG_ERR_INVALID,
     "gravity: expected an array of 2 numbers"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"initial\": {\"scale\": 0}}", BG_ERR_INVALID,
     "initial.scale: must be nonzero"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"task\": {\"kind\": \"dynamics\"}}", BG_ERR_UNSUPPORTED,
     "task.kind: task kind 'dynamics' is not supported"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"reference\": {\"uniaxial\": {\"axis\": \"w\","
     " \"stretch\": 1.1}}}",
     BG_ERR_INVALID, "reference.uniaxial.axis: 'w' is not an axis"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL
     ", \"reference\": {\"affine\": {\"matrix\": [[1, 0], [0, 1]]}}}",
     BG_ERR_INVALID, "reference.affine.matrix: expected 3 rows of 3 numbers"},
    {"{" BOX_MESH ", " MAT ", " FIX_ALL ", \"reference\": \"exact\"}", BG_ERR_INVALID,
     "reference: unknown reference 'exact'"},
    {"{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 2, 2], \"size\": [1, 1, 1], \"cells\": [1, "
     "1, 1]}, " MAT ", " FIX_ALL "}",
     BG_ERR_INVALID, "mesh: key 'cells' appears twice"},
};

static void test_bad_scenes(void **state)
{
    (void)state;
    for (size_t i = 0; i < sizeof BAD_CASES / sizeof BAD_CASES[0]; i++) {
        const bad_case_t *c = &BAD_CASES[i];
        bg_error_t err = BG_ERROR_INIT;
        bg_scene_t *s = NULL;
        bg_status st = bg_prepare_parse(c->json, strlen(c->json), "bad.json", NULL, &s, &err);
        if (st != c->status || !strstr(err.message, c->needle) ||
            strncmp(err.message, "bad.json: ", 10) != 0)
            fail_msg("case %zu: status %d (want %d), message \"%s\" (want \"%s\")", i, (int)st,
                     (int)c->status, err.message, c->needle);
        assert_null(s);
    }
}

static void test_missing_mesh_names_resolved_path(void **state)
{
    (void)state;
    const char *json = "{\"mesh\": \"meshes/missing.mesh\", " MAT ", " FIX_ALL "}";
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    bg_status st = bg_prepare_parse(json, strlen(json), "/no/such/dir/scene.json", NULL, &s, &err);
    assert_int_not_equal(st, BG_OK);
    assert_null(s);
    if (!strstr(err.message, "/no/such/dir/meshes/missing.mesh"))
        fail_msg("message lacks the resolved path: %s", err.message);
    assert_non_null(strstr(err.message, "scene.json: mesh"));
}

static void test_surface_mesh_rejected(void **state)
{
    (void)state;
    const char *json = "{\"mesh\": \"" MESHES "armadillo.off\", " MAT ", " FIX_ALL "}";
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    bg_status st = bg_prepare_parse(json, strlen(json), "armadillo.json", NULL, &s, &err);
    assert_int_equal(st, BG_ERR_INVALID);
    assert_null(s);
    if (!strstr(err.message, "armadillo.off is a triangle surface; static elasticity needs "
                             "tetrahedra or planar triangles (set mesh.planar"))
        fail_msg("unexpected message: %s", err.message);
    /* planar: true on a surface that is not flat names the problem too. */
    const char *flat = "{\"mesh\": {\"file\": \"" MESHES "armadillo.off\","
                       " \"planar\": true}, " MAT ", " FIX_ALL "}";
    bg_error_clear(&err);
    st = bg_prepare_parse(flat, strlen(flat), "armadillo.json", NULL, &s, &err);
    assert_int_not_equal(st, BG_OK);
    assert_non_null(strstr(err.message, "armadillo.json: mesh.planar"));
}

static void test_method_names(void **state)
{
    (void)state;
    bg_method m = BG_METHOD_NEWTON;
    assert_int_equal(bg_method_parse("local-global", &m, NULL), BG_OK);
    assert_int_equal(m, BG_METHOD_LOCAL_GLOBAL);
    assert_string_equal(bg_method_name(m), "local-global");
    assert_string_equal(bg_method_name(BG_METHOD_NEWTON), "newton");
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_method_parse("Newton", &m, &err), BG_ERR_INVALID);
    assert_non_null(
        strstr(err.message, "newton, local-global, quasi-newton, variational or backward-euler"));
    assert_int_equal(bg_method_parse("quasi-newton", &m, NULL), BG_OK);
    assert_int_equal(m, BG_METHOD_QUASI_NEWTON);
    assert_string_equal(bg_method_name(m), "quasi-newton");
    assert_false(bg_method_is_dynamic(m));
    assert_int_equal(bg_method_parse("backward-euler", &m, NULL), BG_OK);
    assert_int_equal(m, BG_METHOD_BACKWARD_EULER);
    assert_true(bg_method_is_dynamic(m));
    assert_false(bg_method_is_dynamic(BG_METHOD_NEWTON));
    bg_scene_destroy(NULL);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bar_twist),
        cmocka_unit_test(test_stiff_bar),
        cmocka_unit_test(test_stretch_bar),
        cmocka_unit_test(test_plate_bend),
        cmocka_unit_test(test_bunny_edit),
        cmocka_unit_test(test_inverted_bunny),
        cmocka_unit_test(test_rigid_mount_generated),
        cmocka_unit_test(test_materials),
        cmocka_unit_test(test_uniaxial_planar),
        cmocka_unit_test(test_affine_reference_and_defaults),
        cmocka_unit_test(test_agreeing_overlap_and_components),
        cmocka_unit_test(test_random_initial),
        cmocka_unit_test(test_planar_file_fixture),
        cmocka_unit_test(test_whole_mesh_positions_file),
        cmocka_unit_test(test_morph_twist_target),
        cmocka_unit_test(test_work_cap),
        cmocka_unit_test(test_handle_cap),
        cmocka_unit_test(test_bad_scenes),
        cmocka_unit_test(test_missing_mesh_names_resolved_path),
        cmocka_unit_test(test_surface_mesh_rejected),
        cmocka_unit_test(test_method_names),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
