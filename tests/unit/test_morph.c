/*
 * Morphing between the shared straight bar and its twisted pose: frame 0 is
 * the source itself, the last frame the target up to a rigid motion (its
 * energy vanishes and every element's edge lengths are the target's), and
 * the energy along the path has no jumps. Without handles the scene is held
 * by the automatic 3-2-1 mount (no rigid-motion null space).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <stdio.h>

#include <cmocka.h>

#include "bg_morph.h"
#include "bg_prepare.h"
#include "bg_scene.h"
#include "test_support.h"

#define SCENES BG_SOURCE_DIR "/configs/scenes/"

static int frames_seen;
static double first_frame_error;

static bg_status check_frame(void *ctx, int index, double t, const double *q, bg_error_t *err)
{
    const bg_scene_t *s = ctx;
    if (index == 0) {
        double e = 0.0;
        for (size_t i = 0; i < (size_t)s->mesh->nv * 3; i++)
            e = fmax(e, fabs(q[i] - s->mesh->x[i]));
        first_frame_error = e;
    }
    frames_seen++;
    return BG_OK;
}

static void bar_morph_newton(void **state)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    if (bg_prepare_load(SCENES "bar-morph.json", NULL, &s, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_int_equal(s->task, BG_TASK_MORPH);
    /* Nothing held: the parser adds the 3-2-1 mount, exactly six held
     * components (3 + 2 + 1) at their rest values, which the t = 0 frame
     * (the source itself) satisfies. */
    int held = 0;
    for (size_t i = 0; i < (size_t)s->mesh->nv * 3; i++)
        if (s->constrained[i]) {
            held++;
            assert_true(s->target[i] == s->mesh->x[i]);
        }
    assert_int_equal(held, 6);
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_morph_options_t o = {.method = BG_METHOD_NEWTON, .frame = check_frame, .frame_ctx = s};
    frames_seen = 0;
    if (bg_morph_solve(s, &o, &r, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_true(r.converged);
    assert_int_equal(r.step_count, s->morph_frames);
    assert_int_equal(frames_seen, s->morph_frames);
    /* t = 0: the source is the minimiser of E(M0 → x), zero energy. */
    assert_true(first_frame_error <= 1e-12);
    double peak = 0.0;
    for (int j = 0; j < r.step_count; j++)
        peak = fmax(peak, r.steps[j].total_energy);
    assert_true(peak > 0.0);
    assert_true(r.steps[0].total_energy <= 1e-20 * peak);
    /* t = 1: the target up to a rigid motion. */
    assert_true(r.steps[r.step_count - 1].total_energy <= 1e-12 * peak);
    assert_true(test_max_edge_change(s->mesh->elements, s->mesh->ne, 4, 3, s->morph_target,
                                     r.q) <= 1e-6);
    /* Smooth path: every interior frame's energy within 15 % of the peak of
     * its neighbours' mean (the measured path deviates by ≤ 7 %; a frame that
     * jumps to another branch deviates by O(1)). */
    for (int j = 1; j + 1 < r.step_count; j++) {
        const double mid = 0.5 * (r.steps[j - 1].total_energy + r.steps[j + 1].total_energy);
        assert_true(fabs(r.steps[j].total_energy - mid) <= 0.15 * peak);
    }
    bg_solve_result_release(&r);
    bg_scene_destroy(&s);
}

/* A target that inverts an element is rejected with the element named. */
static void inverted_target_rejected(void **state)
{
    char dir[] = "/tmp/bg-morph-XXXXXX";
    assert_non_null(mkdtemp(dir));
    char target[256], json[1024];
    snprintf(target, sizeof target, "%s/target.txt", dir);
    FILE *f = fopen(target, "w");
    assert_non_null(f);
    /* A 1-cell box mirrored in x: every tetrahedron inverted. */
    for (int k = 0; k <= 1; k++)
        for (int j = 0; j <= 1; j++)
            for (int i = 0; i <= 1; i++)
                fprintf(f, "%d %d %d\n", -i, j, k);
    fclose(f);
    snprintf(json, sizeof json,
             "{\"mesh\": {\"generate\": \"box\", \"cells\": [1, 1, 1], \"size\": [1, 1, 1]},"
             "\"material\": {\"mu\": 1, \"lambda\": 1},"
             "\"task\": {\"kind\": \"morph\", \"target\": \"%s\", \"frames\": 3}}",
             target);
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *s = NULL;
    assert_int_equal(bg_prepare_parse(json, strlen(json), "mirror.json", NULL, &s, &err), BG_OK);
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const bg_morph_options_t o = {.method = BG_METHOD_NEWTON};
    assert_int_equal(bg_morph_solve(s, &o, &r, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "element 1 is inverted or flat in the morph target"));
    bg_scene_destroy(&s);
    remove(target);
    rmdir(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(bar_morph_newton),
        cmocka_unit_test(inverted_target_rejected),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
