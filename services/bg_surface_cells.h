/*
 * bg_surface_cells — the cells of the spokes-and-rims as-rigid-as-possible
 * surface energy (bg_surface_arap): each vertex's incident triangles with
 * their cotangent weights and rest edges, its rotation fitted to them, the
 * cells' energy and gradient. This is the energy's rotation-fit service:
 * the same code serves the in-process solve (through bg_backend) and an
 * agent (a vertex partition), so it sits below both.
 */
#ifndef BG_SURFACE_CELLS_H
#define BG_SURFACE_CELLS_H

#include <stdint.h>

#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_rotfit.h"

/*
 * The energy's cells over a subset of the vertices: the rotation-fit
 * service of this energy, the same code in process and on an agent. The
 * cells of the vertices flagged in owned (nv flags; NULL: all) on mesh (a
 * surface; its rest positions in mesh->x, borrowed for the cells' life):
 * for each, its incident triangles with their cotangent weights and rest
 * edges. E over all vertices is the sum of the cells' energies over any
 * partition of the vertices. Caller owns *out.
 */
typedef struct bg_surface_cells bg_surface_cells_t;
bg_status bg_surface_cells_new(const bg_mesh_t *mesh, const uint8_t *owned,
                               bg_surface_cells_t **out, bg_error_t *err);
void bg_surface_cells_destroy(bg_surface_cells_t **cells);
/* Fits R_i of the owned vertices at q (warm-started from the previous
 * call) and returns their cells' energy; grad (nv·3, may be NULL) is
 * overwritten with its gradient (every vertex of the cells gets a share). */
double bg_surface_cells_eval(bg_surface_cells_t *cells, const double *q, double *grad,
                             bg_rotfit_stats_t *stats);

/* The cotangent weights, ne·3: ½ cot of the angle at corner c of triangle
 * e at [3e + c] (the weight of the edge opposite it); borrowed. */
const double *bg_surface_cells_weights(const bg_surface_cells_t *cells);

#endif
