/*
 * bg_morph — shape interpolation (DESIGN.md §1.7): for K values of t from 0
 * to 1, M_t = argmin_x (1 − t) E(M0 → x) + t E(M1 → x), the elastic energy
 * measured from the source M0 and from the target M1 (same connectivity),
 * each frame warm-started from the previous one. Newton or local/global
 * solve every frame; the frames form a series like a dynamic run.
 */
#ifndef BG_MORPH_H
#define BG_MORPH_H

#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"

typedef struct bg_morph_options {
    bg_method method;         /* BG_METHOD_NEWTON or BG_METHOD_LOCAL_GLOBAL */
    double tolerance;         /* per frame, relative gradient (0: the scene's) */
    int max_iterations;       /* per frame (0: the scene's) */
    int fresh_factor;         /* newton: 1 factors at every iteration; 0 reuses the factor
                                 across iterations and frames with L-BFGS corrections */
    bg_frame_fn frame;        /* every frame, may be NULL */
    void *frame_ctx;
    bg_progress_fn progress;  /* after every frame */
    void *progress_ctx;
    const bg_backend_t *backend; /* basic services (borrowed), NULL: in-process */
} bg_morph_options_t;

/*
 * Solves the scene's morph task. The result holds the last frame's
 * positions, a trace point and a record per frame (steps[j]: time = t_j,
 * total_energy = potential = the blended energy at M_t, iterations,
 * seconds). converged is 1 when every frame converged (or reached the
 * round-off floor). Release with bg_solve_result_release.
 */
bg_status bg_morph_solve(const bg_scene_t *scene, const bg_morph_options_t *options,
                         bg_solve_result_t *result, bg_error_t *err);

#endif
