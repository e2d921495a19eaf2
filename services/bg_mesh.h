/*
 * bg_mesh — simplicial meshes: triangles in the plane, tetrahedra in space,
 * and triangle surfaces in space.
 *
 * A bg_mesh_t is a plain data record (the numerical kernels read its flat
 * arrays directly). Invariants after bg_mesh_new / a reader / a generator:
 *   dim ∈ {2, 3} coordinates per vertex, nodes_per_element ∈ {3, 4},
 *   (dim, nodes_per_element) ∈ {(2,3) planar, (3,4) volume, (3,3) surface};
 *   x holds nv*dim doubles, vertex v at x[v*dim + c];
 *   elements holds ne*nodes_per_element 0-based vertex indices;
 *   vertex_ref / element_ref hold nv / ne integer labels (0 when the source
 *   format has none: MEDIT references, Gmsh physical tags, selections).
 * The mesh owns all arrays; bg_mesh_destroy frees them.
 */
#ifndef BG_MESH_H
#define BG_MESH_H

#include <stdint.h>

#include "bg_error.h"

/* Hard caps: a reader or generator asked for more refuses with BG_ERR_LIMIT. */
#define BG_MESH_MAX_VERTICES 50000000
#define BG_MESH_MAX_ELEMENTS 200000000

typedef enum bg_mesh_kind {
    BG_MESH_PLANAR = 0,  /* triangles, 2 coordinates */
    BG_MESH_VOLUME = 1,  /* tetrahedra, 3 coordinates */
    BG_MESH_SURFACE = 2, /* triangles, 3 coordinates */
} bg_mesh_kind;

typedef struct bg_mesh {
    int dim;
    int nodes_per_element;
    int32_t nv;
    int32_t ne;
    double *x;
    int32_t *elements;
    int32_t *vertex_ref;
    int32_t *element_ref;
} bg_mesh_t;

/*
 * Allocates a mesh of the given kind with nv vertices and ne elements, all
 * arrays zeroed. Caller owns *out and frees it with bg_mesh_destroy.
 */
bg_status bg_mesh_new(bg_mesh_kind kind, int32_t nv, int32_t ne, bg_mesh_t **out, bg_error_t *err);

/* Frees the mesh and sets *mesh to NULL; accepts NULL and *mesh == NULL. */
void bg_mesh_destroy(bg_mesh_t **mesh);

/* Deep copy. Caller owns *out. */
bg_status bg_mesh_clone(const bg_mesh_t *mesh, bg_mesh_t **out, bg_error_t *err);

bg_mesh_kind bg_mesh_kind_of(const bg_mesh_t *mesh);

/* "planar triangles", "tetrahedra", "surface triangles". */
const char *bg_mesh_kind_name(bg_mesh_kind kind);

/*
 * Checks a mesh for use as a rest shape: every coordinate finite, every
 * index in range, no element repeating a vertex, no element of zero (or,
 * relative to its edge lengths, negligible) area/volume. Planar and volume
 * elements with negative orientation are reoriented in place (two vertices
 * swapped) so that every element has positive signed measure; the count is
 * returned in *reoriented (may be NULL). `source` names the mesh in
 * messages (a file name, "generated box"); elements and vertices are named
 * 1-based, as in the file formats users read.
 */
bg_status bg_mesh_validate(bg_mesh_t *mesh, const char *source, int32_t *reoriented,
                           bg_error_t *err);

/*
 * Signed measure (area for planar, volume for tetrahedra, unsigned area for
 * surface triangles) of element e at positions x (nv*dim, may be mesh->x).
 */
double bg_mesh_element_measure(const bg_mesh_t *mesh, const double *x, int32_t e);

/* Axis-aligned bounds of the mesh positions: lo/hi hold dim values. */
void bg_mesh_bounds(const bg_mesh_t *mesh, double *lo, double *hi);

/*
 * A box [origin, origin + size] of nx*ny*nz cubes, each split into 6
 * positively oriented tetrahedra (Kuhn subdivision, conforming across
 * cells): (nx+1)(ny+1)(nz+1) vertices, 6*nx*ny*nz tetrahedra.
 */
bg_status bg_mesh_generate_box(const int32_t cells[3], const double origin[3], const double size[3],
                               bg_mesh_t **out, bg_error_t *err);

/*
 * A rectangle [origin, origin + size] of nx*ny cells, each split into two
 * counter-clockwise triangles along alternating diagonals.
 */
bg_status bg_mesh_generate_rectangle(const int32_t cells[2], const double origin[2],
                                     const double size[2], bg_mesh_t **out, bg_error_t *err);

/*
 * A disk of the given radius around center, in rings concentric rings: the
 * centre vertex and 6k vertices on ring k (k = 1..rings, radius k/rings of
 * the whole), 1 + 3 rings (rings + 1) vertices and 6 rings² counter-clockwise
 * triangles of nearly equal size. kind is BG_MESH_PLANAR (2 coordinates,
 * center[0..1] read) or BG_MESH_SURFACE (a flat triangle surface in the
 * plane z = center[2], what parameterization and surface editing read).
 */
bg_status bg_mesh_generate_disk(int32_t rings, const double center[3], double radius,
                                bg_mesh_kind kind, bg_mesh_t **out, bg_error_t *err);

/*
 * The boundary loop of a disk-like triangle surface (named `name` in
 * messages): its vertices in order into loop (nv entries available),
 * their number into *count. BG_ERR_INVALID, naming the edge or vertex, if
 * the boundary is not one simple loop: a closed surface, holes, an edge of
 * more than two triangles, a boundary that touches itself.
 */
bg_status bg_mesh_disk_boundary(const bg_mesh_t *surface, const char *name, int32_t *loop,
                                int32_t *count, bg_error_t *err);

/* What a parameterization needs of its mesh, without any solve: a triangle
 * surface in 3D with exactly one boundary loop (linear in the mesh size;
 * what `biotgrid validate` runs). */
bg_status bg_mesh_check_disk(const bg_mesh_t *surface, const char *name, bg_error_t *err);

#endif
