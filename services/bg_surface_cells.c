#include "bg_surface_cells.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct bg_surface_cells {
    const bg_mesh_t *mesh;
    uint8_t *owned;    /* nv: 1 for the vertices whose cells are evaluated */
    double *weight;    /* ne·3: weight of the edge opposite corner c */
    double *rest_edge; /* ne·3·3: rest vector p_j − p_k of the edge opposite corner c */
    int32_t *start;    /* nv+1: vertex → incident triangles (CSR) */
    int32_t *triangles;
    double *quat;     /* nv·4 warm starts */
    double *rotation; /* nv·9 fitted rotations */
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
            const double *p = mesh->x + 3 * (size_t)el[c],
                         *a = mesh->x + 3 * (size_t)el[(c + 1) % 3],
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
static void cell_edge(const model_t *m, const double *q, int32_t e, int c, int32_t *j, int32_t *k,
                      double *w, const double **rest, double current[3])
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

const double *bg_surface_cells_weights(const bg_surface_cells_t *cells)
{
    return cells->weight;
}
