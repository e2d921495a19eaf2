#include "bg_surface_arap.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_backend.h"
#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_rotfit.h"
#include "bg_sparse.h"
#include "bg_surface_cells.h"

double bg_surface_arap_energy(const bg_scene_t *scene, const double *q, double *grad)
{
    bg_surface_cells_t *cells = NULL;
    bg_rotfit_stats_t stats = {0};
    double E = NAN;
    if (bg_surface_cells_new(scene->mesh, NULL, &cells, NULL) == BG_OK)
        E = bg_surface_cells_eval(cells, q, grad, &stats);
    bg_surface_cells_destroy(&cells);
    return E;
}

bg_status bg_surface_arap_solve(const bg_scene_t *scene, const bg_solve_options_t *opt,
                                bg_solve_result_t *res, bg_error_t *err)
{
    memset(res, 0, sizeof *res);
    res->method = opt->method;
    if (opt->method != BG_METHOD_LOCAL_GLOBAL)
        return bg_error_set(err, BG_ERR_INVALID, "%s: the spokes-and-rims energy is solved by "
                            "local-global only", scene->path);
    const double t_start = bg_clock_now();
    const bg_mesh_t *mesh = scene->mesh;
    const int32_t nv = mesh->nv;
    const size_t ndof = (size_t)nv * 3;
    bg_surface_cells_t *cells = NULL;
    /* The basic services: the cells' rotation fit and the coordinate
     * systems' factor and solves (in process or on agents). */
    const bg_backend_t *be =
        opt->backend && opt->backend->ops->surface_open ? opt->backend : bg_backend_local();
    const bg_backend_ops_t *ops = be->ops;
    void *session = NULL;
    bg_sparse_t *sys[3] = {NULL, NULL, NULL};
    int system_of[3] = {0, 1, 2}; /* coordinate -> the system it solves with */
    int32_t *index[3] = {NULL, NULL, NULL};
    double *q = malloc(ndof * sizeof *q + 1), *grad = malloc(ndof * sizeof *grad + 1);
    double *rhs = malloc(((size_t)nv + 1) * sizeof *rhs), *x = malloc(((size_t)nv + 1) * sizeof *x);
    int trace_cap = 0;
    bg_status st = bg_surface_cells_new(mesh, NULL, &cells, err);
    if (st == BG_OK && (!q || !grad || !rhs || !x))
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface edit");
    if (st == BG_OK)
        st = ops->session_new(be->ctx, &session, err);
    if (st == BG_OK)
        st = ops->surface_open(session, mesh, err);
    if (st != BG_OK)
        goto out;
    /* K = ∂²E/∂q² per coordinate: each triangle lies in the cells of its
     * three corners, so each of its edges enters three times. */
    const int T = BG_ELASTIC_TRI_SIZE(3);
    for (int c = 0; c < 3; c++) {
        index[c] = malloc(((size_t)nv + 1) * sizeof *index[c]);
        if (!index[c]) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface edit");
            goto out;
        }
        int32_t count = 0;
        for (int32_t v = 0; v < nv; v++)
            index[c][v] = scene->constrained[3 * (size_t)v + c] ? -1 : count++;
        system_of[c] = c;
        if (count == 0)
            continue;
        /* The matrix depends only on which vertices are free: coordinates
         * with the same free set share one system (one factor, one slot on
         * a sparse-solve agent). */
        for (int prev = 0; prev < c; prev++)
            if (sys[prev] && memcmp(index[prev], index[c], (size_t)nv * sizeof(int32_t)) == 0) {
                system_of[c] = prev;
                break;
            }
        if (system_of[c] != c)
            continue;
        st = bg_sparse_new(mesh, 1, index[c], count, &sys[c], err);
        if (st != BG_OK)
            goto out;
        bg_sparse_prefer_solves(sys[c]); /* factored once, solved every iteration */
        bg_sparse_zero(sys[c]);
        double *values = bg_sparse_values(sys[c]);
        const double *weight = bg_surface_cells_weights(cells);
        const int32_t *scatter = bg_sparse_scatter(sys[c]);
        for (int32_t e = 0; e < mesh->ne; e++)
            for (int corner = 0; corner < 3; corner++) {
                const int a = (corner + 1) % 3, b = (corner + 2) % 3;
                const double w = 6.0 * weight[3 * (size_t)e + corner];
                const int lo = a < b ? a : b, hi = a < b ? b : a;
                const int32_t paa = scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(3, a, a)];
                const int32_t pbb = scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(3, b, b)];
                const int32_t pab = scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(3, lo, hi)];
                if (paa >= 0)
                    values[paa] += w;
                if (pbb >= 0)
                    values[pbb] += w;
                if (pab >= 0)
                    values[pab] -= w;
            }
        st = ops->solve_open(session, c, sys[c], err);
        if (st == BG_OK)
            st = ops->solve_factor(session, c, 0.0, err);
        if (st != BG_OK)
            goto out;
    }
    int64_t factored = 0;
    for (int c = 0; c < 3; c++)
        factored += sys[c] ? bg_sparse_timing(sys[c]).factorizations : 0;
    bg_setup_add(&res->setup,
                 "spokes-and-rims model, cotangent weights, one matrix per set of free vertices factored", 1,
                 factored, bg_clock_now() - t_start);
    const double *start = opt->start ? opt->start : scene->initial;
    const double *targets = opt->targets ? opt->targets : scene->target;
    for (size_t i = 0; i < ndof; i++)
        q[i] = scene->constrained[i] ? targets[i] : start[i];
    res->stop_reason = "iteration limit";
    double g0 = 0.0, gnorm = 0.0, E = 0.0;
    for (int it = 0;; it++) {
        double t0 = bg_clock_now();
        st = ops->surface_eval(session, q, &E, grad, &res->rotfit, err);
        if (st != BG_OK)
            goto out;
        const double t1 = bg_clock_now();
        res->rotfit_seconds += t1 - t0;
        gnorm = 0.0;
        for (size_t i = 0; i < ndof; i++)
            if (!scene->constrained[i])
                gnorm += grad[i] * grad[i];
        gnorm = sqrt(gnorm);
        if (it == 0)
            g0 = gnorm;
        const double rel = g0 > 0.0 ? gnorm / g0 : 0.0;
        if (res->trace_count == trace_cap) {
            trace_cap = trace_cap ? 2 * trace_cap : 64;
            bg_trace_point_t *tr = realloc(res->trace, (size_t)trace_cap * sizeof *tr);
            if (!tr) {
                st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the trace");
                goto out;
            }
            res->trace = tr;
        }
        bg_trace_point_t *pt = &res->trace[res->trace_count++];
        *pt = (bg_trace_point_t){bg_clock_now() - t_start, it, E, gnorm, rel, NAN, 0};
        if (opt->progress)
            opt->progress(opt->progress_ctx, opt->method, pt);
        res->vector_seconds += bg_clock_now() - t1;
        res->iterations = it;
        if (rel <= opt->tolerance) {
            res->converged = 1;
            res->stop_reason = "converged";
            break;
        }
        if (it >= opt->max_iterations)
            break;
        /* Global step: q_free ← q_free − K⁻¹ ∇E (the exact minimiser of E
         * for the fitted rotations). */
        for (int c = 0; c < 3; c++) {
            if (!sys[system_of[c]])
                continue;
            double tv = bg_clock_now();
            for (int32_t v = 0; v < nv; v++)
                if (index[c][v] >= 0)
                    rhs[index[c][v]] = grad[3 * (size_t)v + c];
            res->vector_seconds += bg_clock_now() - tv;
            st = ops->solve(session, system_of[c], 1, rhs, x, err);
            if (st != BG_OK)
                goto out;
            tv = bg_clock_now();
            for (int32_t v = 0; v < nv; v++)
                if (index[c][v] >= 0)
                    q[3 * (size_t)v + c] -= x[index[c][v]];
            res->vector_seconds += bg_clock_now() - tv;
        }
    }
    for (int c = 0; c < 3; c++)
        if (sys[c]) {
            /* The analysis and the factorization are set-up (above). */
            res->solve_seconds += bg_sparse_timing(sys[c]).solve_seconds;
        }
    res->energy = E;
    res->gradient_norm = gnorm;
    res->relative_gradient = g0 > 0.0 ? gnorm / g0 : 0.0;
    res->force_scale = g0;
    res->gradient_roundoff = NAN; /* no round-off estimate for this energy */
    res->inverted_elements = -1;  /* a surface has no orientation to invert */
    res->energy_density = calloc((size_t)mesh->ne + 1, sizeof *res->energy_density);
    if (!res->energy_density) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the result");
        goto out;
    }
    res->q = q;
    q = NULL;
    res->wall_seconds = bg_clock_now() - t_start;
    bg_solve_result_add_scene_prep(res, scene);
out:
    if (session)
        ops->session_destroy(be->ctx, session);
    bg_surface_cells_destroy(&cells);
    for (int c = 0; c < 3; c++) {
        bg_sparse_destroy(&sys[c]);
        free(index[c]);
    }
    free(q);
    free(grad);
    free(rhs);
    free(x);
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}
