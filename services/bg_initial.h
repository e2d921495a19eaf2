/*
 * bg_initial — a starting guess that carries the handles' motions into the
 * body, so that Newton's linearised rotations need not discover a large
 * rotation one small step at a time.
 *
 * For each moving handle h, a harmonic weight w_h (1 on h, 0 on every other
 * constrained vertex, ∆w = 0 elsewhere with the cotan Laplacian) is solved
 * once with CHOLMOD; every vertex then moves by Σ_h (T_h^{w_h}(x) − x), where
 * T_h^w is the screw motion "rotate by w·θ about the handle's axis through
 * its centre, translate by w·t" (a fraction of the handle's rigid motion:
 * no collapse, unlike interpolating positions), or the handle's mean
 * displacement scaled by w for handles given as positions. On a bar with
 * one end turned, this is the uniform twist. Constrained coordinates are
 * set to their targets.
 */
#ifndef BG_INITIAL_H
#define BG_INITIAL_H

#include "bg_error.h"
#include "bg_scene.h"

/* Writes nv*dim positions to out. The scene's mesh, constrained, target
 * and motions must be filled. *prep gets the step's name, factorization
 * count and time (the scene reports it with every run). */
bg_status bg_initial_interpolate(const bg_scene_t *scene, double *out, bg_scene_prep_t *prep,
                                 bg_error_t *err);

#endif
