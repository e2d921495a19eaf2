/*
 * bg_param — parameterization of a disk-like triangle surface onto the
 * plane with the same elastic energy (DESIGN.md §1.7): each triangle's rest
 * shape is its own isometric 2D copy, the unknowns are the UVs, the
 * boundary is free. α = β = 1 gives as-rigid-as-possible, α = 0
 * as-similar-as-possible (conformal), in between a trade-off
 * (μ = β²/2, λ = (α² − β²)/2).
 *
 * The start is a Tutte embedding (boundary on a circle by arc length,
 * interior harmonic with uniform weights): flip-free for a disk. Rigid
 * motions are removed by a 2D 3-2-1 mount on two far-apart vertices held at
 * their start positions (no distortion: the energy is invariant under
 * them); ASAP is also invariant under scaling, so both vertices are held.
 */
#ifndef BG_PARAM_H
#define BG_PARAM_H

#include "bg_error.h"
#include "bg_scene.h"
#include "bg_static.h"

/*
 * Turns a parsed parameterize scene whose `mesh` is the 3D surface into the
 * problem the solvers take: moves the surface to scene->surface, builds the
 * rest frames, the planar Tutte mesh (the new scene->mesh), the mount
 * constraints and the material from alpha and beta. Fails if the surface is
 * not a disk (naming the number of boundary loops).
 */
bg_status bg_param_setup(bg_scene_t *scene, bg_error_t *err);

/* The map's quality at uv (nv·2). */
void bg_param_quality(const bg_scene_t *scene, const double *uv, bg_map_quality_t *quality);

/* The 3D surface with the UVs as OBJ texture coordinates (v, vt, f a/a). */
bg_status bg_param_write_obj(const bg_scene_t *scene, const double *uv, const char *path,
                             bg_error_t *err);

#endif
