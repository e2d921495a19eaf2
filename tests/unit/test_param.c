/*
 * Parameterization: a flat disk maps to itself (zero energy, edge lengths
 * kept); on the shared camel head, ARAP has no flipped triangle, and with
 * its area barrier reaches a stationary point of lower energy than the
 * flip-preventing line search alone, which stalls against a folding
 * triangle; ASAP keeps angles better than ARAP and ARAP keeps areas better
 * than ASAP; a closed surface is rejected.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_param.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "test_scenes.h"
#include "test_support.h"

/* mesh: the scene's "mesh" value as JSON text. */
static bg_scene_t *param_scene(const char *mesh, double alpha, double barrier)
{
    char json[512];
    snprintf(json, sizeof json,
             "{\"mesh\": %s, \"task\": {\"kind\": \"parameterize\", \"alpha\": %g, "
             "\"beta\": 1, \"barrier\": %g}}",
             mesh, alpha, barrier);
    return test_parse_scene(json, "param.json");
}

#define FLAT_DISK "{\"generate\": \"disk\", \"rings\": 40, \"radius\": 1}"
#define LION_HEAD "\"lion-head.off\""

static void solve_map(const bg_scene_t *s, bg_method method, int max_iterations,
                      bg_solve_result_t *r)
{
    bg_error_t err = BG_ERROR_INIT;
    const bg_solve_options_t o = {.method = method,
                                  .tolerance = 1e-9,
                                  .max_iterations = max_iterations,
                                  .keep_orientation = 1};
    if (bg_static_solve(s, &o, r, &err) != BG_OK)
        fail_msg("%s", err.message);
    bg_param_quality(s, r->q, &r->map);
}

static void flat_disk_maps_to_itself(void **state)
{
    for (int m = 0; m < 2; m++) {
        bg_scene_t *s = param_scene(FLAT_DISK, 1.0, 1.0);
        bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
        solve_map(s, m ? BG_METHOD_LOCAL_GLOBAL : BG_METHOD_NEWTON, 300, &r);
        /* The minimum energy is 0, so the relative gradient can stop at its
         * round-off floor just above the tolerance; the energy decides. */
        assert_true(r.converged || r.roundoff_floor);
        assert_int_equal(r.map.flipped_triangles, 0);
        assert_true(r.energy <= 1e-12);
        /* Up to a rigid motion: every edge keeps its 3D length. The disk lies
         * in z = 0, so its (x, y) are its isometric 2D coordinates. */
        const bg_mesh_t *xyz = s->surface;
        double *flat = malloc(sizeof(double) * 2 * (size_t)xyz->nv);
        for (int32_t v = 0; v < xyz->nv; v++) {
            assert_true(xyz->x[3 * (size_t)v + 2] == 0.0);
            flat[2 * v] = xyz->x[3 * (size_t)v];
            flat[2 * v + 1] = xyz->x[3 * (size_t)v + 1];
        }
        assert_true(test_max_edge_change(xyz->elements, xyz->ne, 3, 2, flat, r.q) <= 1e-6);
        free(flat);
        bg_solve_result_release(&r);
        bg_scene_destroy(&s);
    }
}

static void lion_head_arap_versus_asap(void **state)
{
    bg_scene_t *arap = param_scene(LION_HEAD, 1.0, 1.0);
    bg_scene_t *asap = param_scene(LION_HEAD, 0.0, 1.0);
    bg_scene_t *bare = param_scene(LION_HEAD, 1.0, 0.0);
    bg_solve_result_t ra = BG_SOLVE_RESULT_INIT, rs = BG_SOLVE_RESULT_INIT;
    bg_solve_result_t rb = BG_SOLVE_RESULT_INIT;
    solve_map(arap, BG_METHOD_NEWTON, 60, &ra);
    solve_map(asap, BG_METHOD_NEWTON, 300, &rs);
    solve_map(bare, BG_METHOD_NEWTON, 300, &rb);
    assert_int_equal(ra.map.flipped_triangles, 0);
    assert_int_equal(rs.map.flipped_triangles, 0);
    assert_int_equal(rb.map.flipped_triangles, 0);
    /* Without the barrier the search stops with the gradient barely
     * reduced; with it, Newton goes on to a near-stationary point (the
     * barrier is part of the energy, so it counts against it). */
    assert_true(rb.relative_gradient > 0.1);
    assert_true(ra.relative_gradient < 1e-3);
    assert_true(ra.energy < 0.9 * rb.energy);
    assert_true(rs.converged); /* ASAP is quadratic: Newton lands on it */
    assert_true(rs.map.angle_mean < ra.map.angle_mean);
    assert_true(ra.map.area_mean < rs.map.area_mean);
    bg_solve_result_release(&ra);
    bg_solve_result_release(&rs);
    bg_solve_result_release(&rb);
    bg_scene_destroy(&arap);
    bg_scene_destroy(&asap);
    bg_scene_destroy(&bare);
}

static void closed_surface_rejected(void **state)
{
    const char *json = "{\"mesh\": \"" MESHES "armadillo.off\", \"task\": {\"kind\": "
                       "\"parameterize\"}}";
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    assert_int_equal(bg_prepare_parse(json, strlen(json), "armadillo.json", NULL, &s, &err),
                     BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "closed"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(flat_disk_maps_to_itself),
        cmocka_unit_test(lion_head_arap_versus_asap),
        cmocka_unit_test(closed_surface_rejected),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
