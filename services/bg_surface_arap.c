#include "bg_surface_arap.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_backend.h"
#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_rotfit.h"
#include "bg_sparse.h"

struct bg_surface_cells {
    const bg_mesh_t *mesh;
    uint8_t *owned;     /* nv: 1 for the vertices whose cells are evaluated */
    double *weight;     /* ne·3: weight of the edge opposite corner c */
    double *rest_edge;  /* ne·3·3: rest vector p_j − p_k of the edge opposite corner c */
    int32_t *start;     /* nv+1: vertex → incident triangles (CSR) */
    int32_t *triangles;
    double *quat;       /* nv·4 warm starts */
    double *rotation;   /* nv·9 fitted rotations */
};
typedef struct bg_surface_cells model_t;

static void model_release(model_t *m)
{
    free(m->owned);
    free(m->weight);
    free(m->rest_edge);
    free(m->start);
    free(m->triangles);
    free(m->quat);
    free(m->rotation);
}

static bg_status model_init(model_t *m, const bg_mesh_t *mesh, const uint8_t *owned,
                            bg_error_t *err)
{
    memset(m, 0, sizeof *m);
    m->mesh = mesh;
    const int32_t nv = mesh->nv, ne = mesh->ne;
    m->owned = malloc((size_t)nv + 1);
    if (!m->owned)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface model");
    for (int32_t v = 0; v < nv; v++)
        m->owned[v] = owned ? owned[v] != 0 : 1;
    m->weight = malloc(((size_t)ne * 3 + 1) * sizeof *m->weight);
    m->rest_edge = malloc(((size_t)ne * 9 + 1) * sizeof *m->rest_edge);
    m->start = calloc((size_t)nv + 1, sizeof *m->start);
    m->triangles = malloc(((size_t)ne * 3 + 1) * sizeof *m->triangles);
    m->quat = calloc((size_t)nv * 4 + 1, sizeof *m->quat);
    m->rotation = malloc(((size_t)nv * 9 + 1) * sizeof *m->rotation);
    if (!m->weight || !m->rest_edge || !m->start || !m->triangles || !m->quat || !m->rotation)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface model");
    for (int32_t e = 0; e < ne; e++) {
        const int32_t *el = mesh->elements + 3 * (size_t)e;
        for (int c = 0; c < 3; c++) {
            /* ½ cot of the angle at corner c, i.e. opposite edge (c+1, c+2). */
            const double *p = mesh->x + 3 * (size_t)el[c], *a = mesh->x + 3 * (size_t)el[(c + 1) % 3],
                         *b = mesh->x + 3 * (size_t)el[(c + 2) % 3];
            double u[3], v[3];
            for (int k = 0; k < 3; k++) {
                u[k] = a[k] - p[k];
                v[k] = b[k] - p[k];
            }
            const double dot = u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
            const double cx = u[1] * v[2] - u[2] * v[1], cy = u[2] * v[0] - u[0] * v[2],
                         cz = u[0] * v[1] - u[1] * v[0];
            m->weight[3 * (size_t)e + c] = 0.5 * dot / sqrt(cx * cx + cy * cy + cz * cz);
            for (int k = 0; k < 3; k++)
                m->rest_edge[9 * (size_t)e + 3 * c + k] = a[k] - b[k];
        }
        for (int c = 0; c < 3; c++)
            m->start[el[c] + 1]++;
    }
    for (int32_t v = 0; v < nv; v++)
        m->start[v + 1] += m->start[v];
    int32_t *fill = malloc(((size_t)nv + 1) * sizeof *fill);
    if (!fill)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface model");
    memcpy(fill, m->start, (size_t)nv * sizeof *fill);
    for (int32_t e = 0; e < ne; e++)
        for (int c = 0; c < 3; c++)
            m->triangles[fill[mesh->elements[3 * (size_t)e + c]]++] = e;
    free(fill);
    return BG_OK;
}

/*
 * Edge c of triangle e in a vertex's cell: the edge opposite corner c, from
 * j to k, its weight, its rest vector (p_j − p_k, precomputed) and its
 * current vector q_j − q_k. Both passes over the cells read edges this way.
 */
static void cell_edge(const model_t *m, const double *q, int32_t e, int c, int32_t *j,
                      int32_t *k, double *w, const double **rest, double current[3])
{
    const int32_t *el = m->mesh->elements + 3 * (size_t)e;
    *j = el[(c + 1) % 3];
    *k = el[(c + 2) % 3];
    *w = m->weight[3 * (size_t)e + c];
    *rest = m->rest_edge + 9 * (size_t)e + 3 * c;
    for (int r = 0; r < 3; r++)
        current[r] = q[3 * (size_t)*j + r] - q[3 * (size_t)*k + r];
}

/* Local step: R_i closest to M_i = Σ w e'_jk e_jkᵀ over vertex i's cell. */
static void fit_rotations(model_t *m, const double *q, bg_rotfit_stats_t *stats)
{
    for (int32_t i = 0; i < m->mesh->nv; i++) {
        if (!m->owned[i])
            continue;
        double M[9] = {0};
        for (int32_t t = m->start[i]; t < m->start[i + 1]; t++)
            for (int c = 0; c < 3; c++) {
                int32_t j, k;
                double w, dp[3];
                const double *d;
                cell_edge(m, q, m->triangles[t], c, &j, &k, &w, &d, dp);
                for (int r = 0; r < 3; r++)
                    for (int s = 0; s < 3; s++)
                        M[3 * r + s] += w * dp[r] * d[s];
            }
        bg_rotfit_stats_count(stats,
                              bg_rotfit3(M, m->quat + 4 * (size_t)i, m->rotation + 9 * (size_t)i));
    }
}

/* E with the current rotations and its gradient (the rotations are optimal,
 * so this is ∂E/∂q: their derivative does not enter). */
static double energy_with_rotations(const model_t *m, const double *q, double *grad)
{
    const bg_mesh_t *mesh = m->mesh;
    double E = 0.0;
    if (grad)
        memset(grad, 0, (size_t)mesh->nv * 3 * sizeof *grad);
    for (int32_t i = 0; i < mesh->nv; i++) {
        if (!m->owned[i])
            continue;
        const double *R = m->rotation + 9 * (size_t)i;
        for (int32_t t = m->start[i]; t < m->start[i + 1]; t++)
            for (int c = 0; c < 3; c++) {
                int32_t j, k;
                double w, dp[3];
                const double *d;
                cell_edge(m, q, m->triangles[t], c, &j, &k, &w, &d, dp);
                for (int a = 0; a < 3; a++) {
                    const double r =
                        dp[a] - (R[3 * a] * d[0] + R[3 * a + 1] * d[1] + R[3 * a + 2] * d[2]);
                    E += w * r * r;
                    if (grad) {
                        grad[3 * (size_t)j + a] += 2.0 * w * r;
                        grad[3 * (size_t)k + a] -= 2.0 * w * r;
                    }
                }
            }
    }
    return E;
}

bg_status bg_surface_cells_new(const bg_mesh_t *mesh, const uint8_t *owned,
                               bg_surface_cells_t **out, bg_error_t *err)
{
    *out = NULL;
    model_t *m = malloc(sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the surface model");
    const bg_status st = model_init(m, mesh, owned, err);
    if (st != BG_OK) {
        model_release(m);
        free(m);
        return st;
    }
    *out = m;
    return BG_OK;
}

void bg_surface_cells_destroy(bg_surface_cells_t **pm)
{
    if (!pm || !*pm)
        return;
    model_release(*pm);
    free(*pm);
    *pm = NULL;
}

double bg_surface_cells_eval(bg_surface_cells_t *m, const double *q, double *grad,
                             bg_rotfit_stats_t *stats)
{
    fit_rotations(m, q, stats);
    return energy_with_rotations(m, q, grad);
}

double bg_surface_arap_energy(const bg_scene_t *scene, const double *q, double *grad)
{
    model_t m;
    bg_rotfit_stats_t stats = {0};
    double E = NAN;
    if (model_init(&m, scene->mesh, NULL, NULL) == BG_OK) {
        fit_rotations(&m, q, &stats);
        E = energy_with_rotations(&m, q, grad);
    }
    model_release(&m);
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
    model_t m;
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
    bg_status st = model_init(&m, mesh, NULL, err);
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
        bg_sparse_zero(sys[c]);
        double *values = bg_sparse_values(sys[c]);
        const int32_t *scatter = bg_sparse_scatter(sys[c]);
        for (int32_t e = 0; e < mesh->ne; e++)
            for (int corner = 0; corner < 3; corner++) {
                const int a = (corner + 1) % 3, b = (corner + 2) % 3;
                const double w = 6.0 * m.weight[3 * (size_t)e + corner];
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
            st = ops->solve(session, system_of[c], rhs, x, err);
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
    model_release(&m);
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
