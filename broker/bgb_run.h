/*
 * bgb_run — one scene solved into an output folder, the part `biotgrid
 * solve` and the broker's job coordinators share: the dynamic and morph
 * series (frames written as they come, a ParaView collection at the end),
 * the result meshes of a run and a parameterization's UV surface.
 *
 * Nothing here prints; every failure is a bg_error_t naming the file.
 */
#ifndef BGB_RUN_H
#define BGB_RUN_H

#include <stddef.h>

#include "bg_backend.h"
#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"

/*
 * A dynamic run or a morph of `scene` (prepared) with `method`: frames go
 * to DIR/<frames_prefix><method>-<step>.vtu (frames_prefix "frames/" makes
 * that folder; "" keeps every file in DIR, as the broker's store wants),
 * and DIR/<method>.pvd lists them. progress (may be NULL) is called after
 * every step; backend NULL computes in process. run is the caller's
 * (bg_solve_result_release).
 */
bg_status bgb_run_series(const bg_scene_t *scene, bg_method method, double tolerance,
                         int max_iterations, const char *dir, const char *frames_prefix,
                         bg_progress_fn progress, void *progress_ctx, const bg_backend_t *backend,
                         bg_solve_result_t *run, bg_error_t *err);

/*
 * The result files of run: DIR/result.vtu (displacement, the constrained
 * flag and ψ per element) and DIR/result.<input format> with the
 * constrained flag as the MEDIT vertex reference. Writes both paths,
 * separated by "\n  ", to paths (paths_size bytes).
 */
bg_status bgb_run_write_results(const char *dir, const bg_scene_t *scene,
                                const bg_solve_result_t *run, char *paths, size_t paths_size,
                                bg_error_t *err);

/* dir + "/" + name into buf (size bytes); -1 if it does not fit. */
int bgb_run_join_path(char *buf, size_t size, const char *dir, const char *name);

/* A parameterization: fills run->map and writes DIR/<method>-uv.obj. */
bg_status bgb_run_write_parameterization(const bg_scene_t *scene, bg_solve_result_t *run,
                                         const char *dir, bg_error_t *err);

#endif
