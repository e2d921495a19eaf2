/*
 * bg_surface_arap — handle-based editing of triangle surfaces with the
 * per-vertex "spokes-and-rims" as-rigid-as-possible energy (Sorkine and
 * Alexa 2007, the variant libigl users know as SPOKES_AND_RIMS):
 *
 *   E(p') = Σ_i Σ_{t ∋ i} Σ_{(j,k) ∈ t} w_jk^t |(p'_j − p'_k) − R_i (p_j − p_k)|²
 *
 * with one rotation R_i per vertex over its cell (every edge of every
 * triangle around i: spokes and rims) and w_jk^t = ½ cot of the angle of t
 * opposite (j, k). Solved by local/global: the local step fits each R_i
 * with the rotation-fit service (warm-started), the global step solves with
 * the constant matrix K = ∂²E/∂p'² (one scalar system per coordinate,
 * factored once). Each iteration never increases E. Handles come from the
 * scene (selection files, boxes, rigid transforms).
 */
#ifndef BG_SURFACE_ARAP_H
#define BG_SURFACE_ARAP_H

#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_rotfit.h"
#include "bg_scene.h"
#include "bg_static.h"
#include "bg_surface_cells.h"

/*
 * Minimises E over the free coordinates from options->start (or the
 * scene's initial positions), constrained coordinates at their targets.
 * Only BG_METHOD_LOCAL_GLOBAL is available for this energy. The result
 * is filled as for bg_static_solve (trace, time split, final positions).
 */
bg_status bg_surface_arap_solve(const bg_scene_t *scene, const bg_solve_options_t *options,
                                bg_solve_result_t *result, bg_error_t *err);

/* E at positions q with each R_i fitted; grad (nv·3, may be NULL) gets ∂E/∂q. */
double bg_surface_arap_energy(const bg_scene_t *scene, const double *q, double *grad);

#endif
