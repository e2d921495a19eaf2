/*
 * Shared by the agent tests: a generated mesh cut into element-range
 * partitions (local vertices, local elements, local-to-global map),
 * deformed positions, and the in-process references the agents' answers
 * are compared with (bg_elastic on the whole mesh, CHOLMOD through
 * bg_sparse).
 */
#ifndef AGENT_FIXTURE_H
#define AGENT_FIXTURE_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "bg_elastic.h"
#include "bg_mesh.h"
#include "bg_sparse.h"
#include "bga_client.h"

typedef struct fx_part {
    int32_t nv, ne;
    int32_t *elements; /* local numbering */
    int32_t *local_to_global;
    int32_t *global_elements; /* which global element each local one is */
    double *rest;             /* nv*dim */
    double *q;                /* nv*dim, gathered from the global positions */
} fx_part;

static inline void fx_part_free(fx_part *p)
{
    free(p->elements);
    free(p->local_to_global);
    free(p->global_elements);
    free(p->rest);
    free(p->q);
    memset(p, 0, sizeof *p);
}

/* Part `index` of `count` equal element ranges of mesh, at positions q. */
static inline int fx_part_make(const bg_mesh_t *mesh, const double *q, int index, int count,
                               fx_part *p)
{
    memset(p, 0, sizeof *p);
    const int k = mesh->nodes_per_element, dim = mesh->dim;
    const int32_t e0 = (int32_t)((int64_t)mesh->ne * index / count);
    const int32_t e1 = (int32_t)((int64_t)mesh->ne * (index + 1) / count);
    int32_t *g2l = malloc((size_t)mesh->nv * sizeof *g2l);
    p->ne = e1 - e0;
    p->elements = malloc((size_t)p->ne * k * sizeof *p->elements);
    p->global_elements = malloc((size_t)p->ne * sizeof *p->global_elements);
    p->local_to_global = malloc((size_t)mesh->nv * sizeof *p->local_to_global);
    if (!g2l || !p->elements || !p->global_elements || !p->local_to_global) {
        free(g2l);
        return -1;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        g2l[v] = -1;
    for (int32_t e = e0; e < e1; e++) {
        p->global_elements[e - e0] = e;
        for (int i = 0; i < k; i++) {
            const int32_t g = mesh->elements[(size_t)e * k + i];
            if (g2l[g] < 0) {
                g2l[g] = p->nv;
                p->local_to_global[p->nv++] = g;
            }
            p->elements[(size_t)(e - e0) * k + i] = g2l[g];
        }
    }
    free(g2l);
    p->rest = malloc((size_t)p->nv * dim * sizeof *p->rest);
    p->q = malloc((size_t)p->nv * dim * sizeof *p->q);
    if (!p->rest || !p->q)
        return -1;
    for (int32_t v = 0; v < p->nv; v++)
        for (int c = 0; c < dim; c++) {
            p->rest[(size_t)v * dim + c] = mesh->x[(size_t)p->local_to_global[v] * dim + c];
            p->q[(size_t)v * dim + c] = q[(size_t)p->local_to_global[v] * dim + c];
        }
    return 0;
}

static inline bga_partition_t fx_partition(const fx_part *p, const bg_mesh_t *mesh, double mu,
                                           double lambda)
{
    bga_partition_t bp;
    memset(&bp, 0, sizeof bp);
    bp.dim = mesh->dim;
    bp.nv = p->nv;
    bp.ne = p->ne;
    bp.nglobal = mesh->nv;
    bp.elements = p->elements;
    bp.local_to_global = p->local_to_global;
    bp.rest_positions = p->rest;
    bp.mu = mu;
    bp.lambda = lambda;
    return bp;
}

/* Deformed positions: a rotation about z by `angle`, a stretch along x and
 * a deterministic wobble, so every element has a non-trivial rotation. */
static inline void fx_deform(const bg_mesh_t *mesh, double angle, double *q)
{
    const int dim = mesh->dim;
    const double c = cos(angle), s = sin(angle);
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *x = mesh->x + (size_t)v * dim;
        const double x0 = 1.2 * x[0], x1 = x[1];
        q[(size_t)v * dim + 0] = c * x0 - s * x1 + 0.01 * sin(7.0 * v);
        q[(size_t)v * dim + 1] = s * x0 + c * x1 + 0.01 * cos(5.0 * v);
        if (dim == 3)
            q[(size_t)v * dim + 2] = x[2] * (1.0 + 0.1 * x[0]) + 0.01 * sin(3.0 * v);
    }
}

static inline double fx_max_abs(const double *a, size_t n)
{
    double m = 0.0;
    for (size_t i = 0; i < n; i++)
        if (fabs(a[i]) > m)
            m = fabs(a[i]);
    return m;
}

/* Every dof free: the free index of the whole mesh (nv*dim values). */
static inline int32_t *fx_all_free(const bg_mesh_t *mesh, int n)
{
    int32_t *idx = malloc((size_t)mesh->nv * n * sizeof *idx);
    if (idx)
        for (size_t i = 0; i < (size_t)mesh->nv * n; i++)
            idx[i] = (int32_t)i;
    return idx;
}

#endif
