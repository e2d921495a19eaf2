/*
 * bg_run — one scene solved into an output folder, the part `biotgrid
 * solve` and the broker's job coordinators share: the reference solve,
 * one method's run (the dynamic and morph series with frames written as
 * they come and a ParaView collection at the end; the static, surface and
 * parameterization solves with a parameterization's UV surface) and the
 * result meshes of a run.
 *
 * Nothing here prints; every failure is a bg_error_t naming the file.
 */
#ifndef BG_RUN_H
#define BG_RUN_H

#include <stddef.h>

#include "bg_backend.h"
#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"

/* The reference of a static scene with "reference": "newton", as `biotgrid
 * solve` computes it: Newton to its round-off floor. */
#define BG_RUN_REFERENCE_TOLERANCE 1e-13
#define BG_RUN_REFERENCE_MAX_ITERATIONS 200

/* One method of a scene. Every pointer is borrowed for the call. */
typedef struct bg_run_options {
    bg_method method;
    double tolerance;
    int max_iterations;
    /* Dynamic and morph frames go to DIR/<frames_prefix><method>-<step>.vtu
     * ("frames/" makes that folder; "" keeps every file in DIR, as the
     * broker's store wants), and DIR/<method>.pvd lists them. */
    const char *frames_prefix;
    bg_progress_fn progress; /* may be NULL: after every iteration, step or frame */
    void *progress_ctx;
    const bg_backend_t *backend; /* NULL: in process. surface-edit ignores it: its
                                    per-vertex rotations have no agent service */
    /* A static solve whose ref is NULL: the reference computed alongside
     * (bg_solve_options_t.reference_ready); NULL: none. */
    const double *(*reference_ready)(void *ctx, int wait);
    void *reference_ctx;
} bg_run_options_t;

/* 1 when bg_run_reference solves a reference for scene (a static scene
 * with "reference": "newton"), 0 when it only lends the scene's own. */
int bg_run_reference_solves(const bg_scene_t *scene);

/*
 * The reference positions a static run measures its error against: a
 * static scene with "reference": "newton" is solved by Newton at
 * BG_RUN_REFERENCE_TOLERANCE on backend (NULL: in process) into
 * *reference (the caller's, bg_solve_result_release) and *ref points at
 * its positions; otherwise *ref is the scene's own reference (borrowed,
 * may be NULL) and nothing is solved.
 */
bg_status bg_run_reference(const bg_scene_t *scene, const bg_backend_t *backend,
                            bg_solve_result_t *reference, const double **ref, bg_error_t *err);

/*
 * One method of `scene` (prepared) into DIR, the run `biotgrid solve` and
 * the broker's coordinators share: a dynamic run or a morph writes its
 * frames and collection (see frames_prefix); a static, surface-edit or
 * parameterize solve measures its error against ref (from
 * bg_run_reference, may be NULL) and a parameterization writes
 * DIR/<method>-uv.obj. run is the caller's (bg_solve_result_release).
 */
bg_status bg_run_method(const bg_scene_t *scene, const bg_run_options_t *opt,
                         const double *ref, const char *dir, bg_solve_result_t *run,
                         bg_error_t *err);

/*
 * The result files of run: DIR/result.vtu (displacement, the constrained
 * flag and ψ per element) and DIR/result.<input format> with the
 * constrained flag as the MEDIT vertex reference. Writes both paths,
 * separated by "\n  ", to paths (paths_size bytes).
 */
bg_status bg_run_write_results(const char *dir, const bg_scene_t *scene,
                                const bg_solve_result_t *run, char *paths, size_t paths_size,
                                bg_error_t *err);

#endif
