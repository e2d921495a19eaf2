/*
 * bg_prepare — the set-up a parsed scene needs before a solve, which
 * parsing (bg_scene) leaves out so that validation stays cheap: the
 * harmonic starting guess of an "interpolate" start (a scalar Laplacian
 * factorization, bg_initial) and, for a parameterize task, the Tutte and
 * conformal start that replaces the 3D surface by the planar UV mesh
 * (bg_param). It sits above the solvers it runs; bg_scene below them knows
 * none of them.
 */
#ifndef BG_PREPARE_H
#define BG_PREPARE_H

#include <stddef.h>

#include "bg_error.h"
#include "bg_scene.h"

/*
 * Runs the scene's set-up. Idempotent; each step is recorded in
 * scene->prep[] (name, factorizations, seconds), which every run of the
 * scene reports in its set-up list. Solvers need a prepared scene.
 */
bg_status bg_prepare_scene(bg_scene_t *scene, bg_error_t *err);

/* bg_scene_parse_with followed by bg_prepare_scene: a scene ready to
 * solve (options may be NULL). Caller owns *out; NULL on failure. */
bg_status bg_prepare_parse(const char *json, size_t length, const char *path,
                           const bg_scene_options_t *options, bg_scene_t **out, bg_error_t *err);

/* bg_scene_load_with followed by bg_prepare_scene. */
bg_status bg_prepare_load(const char *path, const bg_scene_options_t *options, bg_scene_t **out,
                          bg_error_t *err);

#endif
