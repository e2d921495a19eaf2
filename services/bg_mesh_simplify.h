/*
 * bg_mesh_simplify — triangle-surface simplification by edge collapse under
 * the quadric error metric (Garland and Heckbert 1997), for turning large
 * scanned surfaces into inputs a tetrahedral mesher accepts.
 *
 * Each vertex carries the sum of the squared-distance quadrics of the
 * planes of its input faces (area-weighted); an edge u-v collapses to the
 * point that minimises Q_u + Q_v, cheapest first. Boundary edges add
 * heavily weighted planes through them, perpendicular to their face, so
 * open boundaries stay where they are.
 *
 * A collapse is performed only when it keeps the surface a 2-manifold of
 * the same topology (the link condition, with the boundary coned off to a
 * virtual vertex: no boundary loop is closed, merged or split, no two
 * boundary vertices are joined through the interior) and when every
 * triangle it moves keeps its orientation, turns its normal by no more
 * than the option allows and is not left worse than the quality floor.
 * The result is deterministic: ties in cost are broken by vertex indices,
 * so one input gives bit-identical output on every run.
 */
#ifndef BG_MESH_SIMPLIFY_H
#define BG_MESH_SIMPLIFY_H

#include <stdint.h>

#include "bg_error.h"
#include "bg_mesh.h"

/* Surfaces with more faces than this are refused with BG_ERR_LIMIT: the
 * working memory is about 200 bytes per face. */
#define BG_SIMPLIFY_MAX_FACES 20000000

typedef struct bg_simplify_options {
    /* Stop when this many vertices remain (>= 4, a tetrahedron). */
    int32_t target_vertices;
    /* Cosine of the largest rotation of a triangle's normal one collapse
     * may cause, in [-1, 1]: 0.5 allows 60 degrees; -1 allows flips. */
    double max_normal_change;
    /* Quality 4*sqrt(3)*area / (sum of squared edge lengths), 1 for an
     * equilateral triangle, in [0, 1): a collapse may not leave a moved
     * triangle below this unless it was already at least as bad before. */
    double min_triangle_quality;
} bg_simplify_options_t;

/* What a simplification achieved (all counts over the output). */
typedef struct bg_simplify_result {
    int32_t vertices;         /* vertices of the output */
    int32_t faces;            /* faces of the output */
    int32_t collapses;        /* edge collapses performed */
    int reached_target;       /* 1 when vertices == target_vertices (or the
                                 input had no more than that) */
    int64_t refused_topology; /* collapses refused by the link condition,
                                 the boundary rules or the valence cap */
    int64_t refused_geometry; /* candidate placements refused for a flip, a
                                 normal rotation or a poor triangle */
    double max_error;         /* largest quadric error (length^4) of a
                                 performed collapse */
} bg_simplify_result_t;

/* Options that suit tetrahedral meshing: normals turn by at most 60 degrees
 * per collapse, quality floor 0.5 (smallest angles about 17 degrees). */
bg_simplify_options_t bg_simplify_defaults(int32_t target_vertices);

/*
 * Simplifies a BG_MESH_SURFACE mesh down to options->target_vertices.
 *
 * The input must be an oriented 2-manifold, closed or with boundary loops:
 * every edge in one or two faces, two faces on an edge running it in
 * opposite directions, the faces around each vertex one fan, no face of
 * zero area. Anything else (another mesh kind, a target below 4, options
 * out of range) is refused with BG_ERR_INVALID and a message naming the
 * 1-based vertices and faces at fault. Vertices no face uses are dropped.
 *
 * On success *out (caller owns, free with bg_mesh_destroy) is a new
 * surface mesh of the same topology: surviving vertices numbered in their
 * input order (keeping their vertex_ref), surviving faces in their input
 * order with their orientation (keeping their element_ref). When every
 * remaining collapse is refused before the target is reached, the mesh
 * reached is returned all the same and result->reached_target is 0.
 * result may be NULL.
 */
bg_status bg_mesh_simplify(const bg_mesh_t *surface, const bg_simplify_options_t *options,
                           bg_mesh_t **out, bg_simplify_result_t *result, bg_error_t *err);

#endif
