#include "bg_initial.h"

#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_sparse.h"


bg_status bg_initial_interpolate(const bg_scene_t *scene, double *out, bg_scene_prep_t *prep,
                                 bg_error_t *err)
{
    const double t_start = bg_clock_now();
    prep->name = "starting guess: harmonic weights (scalar Laplacian factored once)";
    prep->factorizations = 0;
    const bg_mesh_t *mesh = scene->mesh;
    const int d = mesh->dim;
    const int32_t nv = mesh->nv;
    const size_t ndof = (size_t)nv * d;
    bg_status st = BG_OK;
    bg_elastic_t *model = NULL;
    bg_sparse_t *sys = NULL;
    int32_t *free_index = malloc(((size_t)nv + 1) * sizeof *free_index);
    uint8_t *held = calloc((size_t)nv + 1, 1);
    double *w = calloc(ndof + 1, sizeof *w), *rhs = calloc(ndof + 1, sizeof *rhs);
    double *sol = calloc(ndof + 1, sizeof *sol);
    if (!free_index || !held || !w || !rhs || !sol) {
        st = bg_error_set(err, BG_ERR_NOMEM, "initial guess: out of memory");
        goto out;
    }
    memcpy(out, mesh->x, ndof * sizeof *out);
    /* The weight problem is scalar, one unknown per vertex; a vertex with
     * any constrained coordinate is a boundary vertex of it. */
    for (int32_t v = 0; v < nv; v++)
        for (int c = 0; c < d; c++)
            held[v] |= scene->constrained[(size_t)v * d + c];
    int32_t nfree = 0;
    for (int32_t v = 0; v < nv; v++)
        free_index[v] = held[v] ? -1 : nfree++;
    int moving = 0;
    for (int32_t h = 0; h < scene->handle_count; h++)
        moving |= scene->motions[h].kind != BG_MOTION_FIXED;
    if (nfree > 0 && moving) {
        st = bg_elastic_new(mesh, 1.0, 0.0, &model, err);
        if (st == BG_OK)
            st = bg_sparse_new(mesh, 1, free_index, nfree, &sys, err);
        if (st != BG_OK)
            goto out;
        bg_sparse_zero(sys);
        bg_elastic_assemble_scalar_laplacian(model, 1.0, bg_sparse_scatter(sys),
                                             bg_sparse_values(sys));
        st = bg_sparse_factorize(sys, 0.0, err);
        prep->factorizations++;
        if (st != BG_OK)
            goto out;
    }
    for (int32_t h = 0; h < scene->handle_count && sys; h++) {
        const bg_scene_motion_t *m = &scene->motions[h];
        if (m->kind == BG_MOTION_FIXED)
            continue;
        /* Dirichlet data: 1 on this handle, 0 elsewhere; rhs = −(K w_b)_free.
         * The Laplacian is applied coordinate-wise, so the data ride in the
         * first coordinate of a d-coordinate field. */
        memset(w, 0, ndof * sizeof *w);
        for (int32_t i = 0; i < m->count; i++)
            w[(size_t)m->vertices[i] * d] = 1.0;
        bg_elastic_apply_laplacian(model, w, rhs);
        for (int32_t v = 0; v < nv; v++)
            if (free_index[v] >= 0)
                sol[free_index[v]] = -rhs[(size_t)v * d];
        st = bg_sparse_solve(sys, sol, sol, err);
        if (st != BG_OK)
            goto out;
        for (int32_t v = 0; v < nv; v++) {
            const size_t k = (size_t)v * d;
            const double weight = free_index[v] >= 0 ? sol[free_index[v]] : w[k];
            if (weight == 0.0)
                continue;
            const double *x = mesh->x + k;
            double moved[3];
            if (m->kind == BG_MOTION_RIGID) {
                bg_motion_screw(m, d, weight, x, moved);
            } else {
                for (int c = 0; c < d; c++)
                    moved[c] = x[c] + weight * m->mean_displacement[c];
            }
            for (int c = 0; c < d; c++)
                out[k + c] += moved[c] - x[c];
        }
    }
    for (size_t k = 0; k < ndof; k++)
        if (scene->constrained[k])
            out[k] = scene->target[k];
out:
    prep->seconds = bg_clock_now() - t_start;
    bg_sparse_destroy(&sys);
    bg_elastic_destroy(&model);
    free(free_index);
    free(held);
    free(w);
    free(rhs);
    free(sol);
    return st;
}
