#include "bg_param.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_sparse.h"

#define M_PI_VALUE 3.14159265358979323846
/* The conformal start: the ASAP energy is quadratic, one Newton step solves
 * it; the cap only guards against a degenerate surface. */
#define PARAM_CONFORMAL_TOLERANCE 1e-10
#define PARAM_CONFORMAL_MAX_ITERATIONS 20

static double dist3(const double *a, const double *b)
{
    const double x = a[0] - b[0], y = a[1] - b[1], z = a[2] - b[2];
    return sqrt(x * x + y * y + z * z);
}

/*
 * Tutte's embedding: the boundary loop on a circle of the surface's area
 * by arc length, interior vertices at the (uniform-weight) average of their
 * neighbours, i.e. a Laplace solve with CHOLMOD. Triangles get the weight
 * 1/2 per edge, so interior edges weigh 1.
 */
static bg_status tutte(const bg_mesh_t *surface, const int32_t *loop, int32_t nloop,
                       double area, double *uv, bg_error_t *err)
{
    const int32_t nv = surface->nv;
    bg_status st = BG_OK;
    bg_sparse_t *sys = NULL;
    int32_t *index = malloc(((size_t)nv + 1) * sizeof *index);
    double *rhs = calloc(2 * (size_t)nv + 1, sizeof *rhs), *x = calloc((size_t)nv + 1, sizeof *x);
    uint8_t *on_boundary = calloc((size_t)nv + 1, 1);
    if (!index || !rhs || !x || !on_boundary) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the Tutte embedding");
        goto out;
    }
    double perimeter = 0.0;
    for (int32_t i = 0; i < nloop; i++)
        perimeter += dist3(surface->x + 3 * (size_t)loop[i],
                           surface->x + 3 * (size_t)loop[(i + 1) % nloop]);
    const double radius = sqrt(area / M_PI_VALUE);
    double arc = 0.0;
    for (int32_t i = 0; i < nloop; i++) {
        const double angle = 2.0 * M_PI_VALUE * arc / perimeter;
        uv[2 * (size_t)loop[i]] = radius * cos(angle);
        uv[2 * (size_t)loop[i] + 1] = radius * sin(angle);
        on_boundary[loop[i]] = 1;
        arc += dist3(surface->x + 3 * (size_t)loop[i],
                     surface->x + 3 * (size_t)loop[(i + 1) % nloop]);
    }
    int32_t nfree = 0;
    for (int32_t v = 0; v < nv; v++)
        index[v] = on_boundary[v] ? -1 : nfree++;
    if (nfree > 0) {
        st = bg_sparse_new(surface, 1, index, nfree, &sys, err);
        if (st != BG_OK)
            goto out;
        bg_sparse_zero(sys);
        double *values = bg_sparse_values(sys);
        const int32_t *scatter = bg_sparse_scatter(sys);
        const int T = BG_ELASTIC_TRI_SIZE(3);
        for (int32_t e = 0; e < surface->ne; e++) {
            const int32_t *el = surface->elements + 3 * (size_t)e;
            for (int a = 0; a < 3; a++)
                for (int b = a; b < 3; b++) {
                    const int32_t pos = scatter[(size_t)e * T + BG_ELASTIC_TRI_INDEX(3, a, b)];
                    if (pos >= 0)
                        values[pos] += a == b ? 1.0 : -0.5;
                }
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++)
                    if (a != b && index[el[a]] >= 0 && index[el[b]] < 0)
                        for (int c = 0; c < 2; c++)
                            rhs[(size_t)c * nv + index[el[a]]] += 0.5 * uv[2 * (size_t)el[b] + c];
        }
        st = bg_sparse_factorize(sys, 0.0, err);
        for (int c = 0; st == BG_OK && c < 2; c++) {
            st = bg_sparse_solve(sys, rhs + (size_t)c * nv, x, err);
            for (int32_t v = 0; st == BG_OK && v < nv; v++)
                if (index[v] >= 0)
                    uv[2 * (size_t)v + c] = x[index[v]];
        }
    }
out:
    bg_sparse_destroy(&sys);
    free(index);
    free(rhs);
    free(x);
    free(on_boundary);
    return st;
}

/*
 * A better start than Tutte's for α > 0: the conformal (ASAP) map, one
 * Newton step from Tutte since that energy is quadratic, scaled about its
 * centroid to the surface's area. It is flip-free and already has the
 * right angles, so the ARAP solve only redistributes area; from Tutte's
 * uniform-weight map, which crushes the interior, ARAP descends into
 * minima with flipped triangles. Holds a and b while solving, then leaves
 * the 3-2-1 mount (a fully, b in v) at the new positions.
 */
static bg_status conformal_start(bg_scene_t *s, int32_t a, int32_t b, double area,
                                 int64_t *factorizations, bg_error_t *err)
{
    bg_solve_result_t r = BG_SOLVE_RESULT_INIT;
    const size_t n2 = (size_t)s->mesh->nv * 2;
    s->constrained[2 * (size_t)b] = 1;
    s->material.mu = 0.5;
    s->material.lambda = -0.5;
    const bg_solve_options_t o = {.method = BG_METHOD_NEWTON,
                                  .tolerance = PARAM_CONFORMAL_TOLERANCE,
                                  .max_iterations = PARAM_CONFORMAL_MAX_ITERATIONS};
    bg_status st = bg_static_solve(s, &o, &r, err);
    if (st != BG_OK)
        return st;
    *factorizations = r.factorizations + r.setup.factorizations;
    double uv_area = 0.0, centre[2] = {0, 0};
    for (int32_t e = 0; e < s->mesh->ne; e++)
        uv_area += bg_mesh_element_measure(s->mesh, r.q, e);
    for (int32_t v = 0; v < s->mesh->nv; v++)
        for (int c = 0; c < 2; c++)
            centre[c] += r.q[2 * (size_t)v + c] / s->mesh->nv;
    const double k = uv_area > 0.0 ? sqrt(area / uv_area) : 1.0;
    for (size_t i = 0; i < n2; i++) {
        const double x = centre[i % 2] + k * (r.q[i] - centre[i % 2]);
        s->initial[i] = s->target[i] = s->mesh->x[i] = x;
    }
    s->constrained[2 * (size_t)b] = 0;
    bg_solve_result_release(&r);
    return BG_OK;
}

bg_status bg_param_setup(bg_scene_t *s, bg_error_t *err)
{
    const double t_start = bg_clock_now();
    bg_status st = BG_OK;
    bg_mesh_t *surface = s->mesh, *planar = NULL;
    int32_t *loop = NULL;
    int32_t nloop = 0;
    const int32_t nv = surface->nv, ne = surface->ne;
    if (bg_mesh_kind_of(surface) != BG_MESH_SURFACE)
        return bg_error_set(err, BG_ERR_INVALID, "%s: parameterization needs a triangle surface "
                            "in 3D, got %s", s->path, bg_mesh_kind_name(bg_mesh_kind_of(surface)));
    loop = malloc(((size_t)nv + 1) * sizeof *loop);
    s->rest_edges = malloc(((size_t)ne * 4 + 1) * sizeof *s->rest_edges);
    if (!loop || !s->rest_edges) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the parameterization");
        goto out;
    }
    st = bg_mesh_disk_boundary(surface, s->path, loop, &nloop, err);
    if (st != BG_OK)
        goto out;
    /* Each triangle's isometric frame: edge 1 along x, edge 2 above it. */
    double area = 0.0;
    for (int32_t e = 0; e < ne; e++) {
        const int32_t *el = surface->elements + 3 * (size_t)e;
        const double *p0 = surface->x + 3 * (size_t)el[0], *p1 = surface->x + 3 * (size_t)el[1],
                     *p2 = surface->x + 3 * (size_t)el[2];
        double e1[3], e2[3];
        for (int c = 0; c < 3; c++) {
            e1[c] = p1[c] - p0[c];
            e2[c] = p2[c] - p0[c];
        }
        const double l1 = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]);
        const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
                     cz = e1[0] * e2[1] - e1[1] * e2[0];
        double *D = s->rest_edges + 4 * (size_t)e;
        D[0] = l1;
        D[1] = (e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2]) / l1;
        D[2] = 0.0;
        D[3] = sqrt(cx * cx + cy * cy + cz * cz) / l1;
        area += 0.5 * D[0] * D[3];
    }
    st = bg_mesh_new(BG_MESH_PLANAR, nv, ne, &planar, err);
    if (st != BG_OK)
        goto out;
    memcpy(planar->elements, surface->elements, (size_t)ne * 3 * sizeof *planar->elements);
    st = tutte(surface, loop, nloop, area, planar->x, err);
    if (st != BG_OK)
        goto out;
    /* The rest frames are counter-clockwise; mirror the start if the loop
     * ran the other way, so that no triangle starts inverted. */
    double signed_area = 0.0;
    for (int32_t e = 0; e < ne; e++)
        signed_area += bg_mesh_element_measure(planar, planar->x, e);
    if (signed_area < 0.0)
        for (int32_t v = 0; v < nv; v++)
            planar->x[2 * (size_t)v + 1] = -planar->x[2 * (size_t)v + 1];
    /* Mount: the two boundary vertices farthest apart in u. */
    int32_t a = loop[0], b = loop[0];
    for (int32_t i = 0; i < nloop; i++) {
        if (planar->x[2 * (size_t)loop[i]] < planar->x[2 * (size_t)a])
            a = loop[i];
        if (planar->x[2 * (size_t)loop[i]] > planar->x[2 * (size_t)b])
            b = loop[i];
    }
    const size_t n2 = (size_t)nv * 2;
    free(s->constrained);
    free(s->target);
    free(s->initial);
    s->constrained = calloc(n2 + 1, 1);
    s->target = malloc((n2 + 1) * sizeof *s->target);
    s->initial = malloc((n2 + 1) * sizeof *s->initial);
    if (!s->constrained || !s->target || !s->initial) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the parameterization");
        goto out;
    }
    memcpy(s->target, planar->x, n2 * sizeof *s->target);
    memcpy(s->initial, planar->x, n2 * sizeof *s->initial);
    s->constrained[2 * (size_t)a] = s->constrained[2 * (size_t)a + 1] = 1;
    s->constrained[2 * (size_t)b + 1] = 1;
    if (s->alpha == 0.0)
        s->constrained[2 * (size_t)b] = 1; /* ASAP: scale is free too */
    s->constrained_vertices = 2;
    s->surface = surface;
    s->mesh = planar;
    planar = NULL;
    /* Recorded after the conformal solve, which must not report them. */
    const double t_conformal = bg_clock_now();
    int64_t conformal_factorizations = 0;
    if (s->alpha > 0.0) {
        st = conformal_start(s, a, b, area, &conformal_factorizations, err);
        if (st != BG_OK)
            goto out;
    }
    s->prep_count = 0;
    s->prep[s->prep_count++] = (bg_scene_prep_t){
        "parameterization start: boundary loop, rest frames, Tutte embedding (one Laplacian "
        "factorization)",
        1, t_conformal - t_start};
    if (s->alpha > 0.0)
        s->prep[s->prep_count++] =
            (bg_scene_prep_t){"parameterization start: the conformal (ASAP) map, a Newton solve",
                              conformal_factorizations, bg_clock_now() - t_conformal};
    s->material.mu = 0.5 * s->beta * s->beta;
    s->material.lambda = 0.5 * (s->alpha * s->alpha - s->beta * s->beta);
out:
    bg_mesh_destroy(&planar);
    free(loop);
    return st;
}

void bg_param_quality(const bg_scene_t *s, const double *uv, bg_map_quality_t *q)
{
    const bg_mesh_t *m = s->mesh;
    memset(q, 0, sizeof *q);
    double area_uv = 0.0, area_rest = 0.0;
    for (int32_t e = 0; e < m->ne; e++) {
        const double *D = s->rest_edges + 4 * (size_t)e;
        area_rest += 0.5 * (D[0] * D[3] - D[1] * D[2]);
        area_uv += bg_mesh_element_measure(m, uv, e);
    }
    const double scale = area_uv / area_rest;
    int64_t counted = 0;
    for (int32_t e = 0; e < m->ne; e++) {
        const int32_t *el = m->elements + 3 * (size_t)e;
        const double *D = s->rest_edges + 4 * (size_t)e;
        const double ax = uv[2 * (size_t)el[1]] - uv[2 * (size_t)el[0]],
                     ay = uv[2 * (size_t)el[1] + 1] - uv[2 * (size_t)el[0] + 1],
                     bx = uv[2 * (size_t)el[2]] - uv[2 * (size_t)el[0]],
                     by = uv[2 * (size_t)el[2] + 1] - uv[2 * (size_t)el[0] + 1];
        /* J = Ds D⁻¹ with D = [[D0, D1], [D2, D3]] (columns = edges). */
        const double det = D[0] * D[3] - D[1] * D[2];
        const double J00 = (ax * D[3] - bx * D[2]) / det, J01 = (bx * D[0] - ax * D[1]) / det,
                     J10 = (ay * D[3] - by * D[2]) / det, J11 = (by * D[0] - ay * D[1]) / det;
        const double E = 0.5 * (J00 + J11), F = 0.5 * (J00 - J11), G = 0.5 * (J10 + J01),
                     H = 0.5 * (J10 - J01);
        const double Q = sqrt(E * E + H * H), R = sqrt(F * F + G * G);
        const double s1 = Q + R, s2 = Q - R; /* s2 < 0: the triangle is flipped */
        if (!(s2 > 0.0)) {
            q->flipped_triangles++;
            continue;
        }
        const double angle = log(s1 / s2), area = fabs(log(s1 * s2 / scale));
        q->angle_mean += angle;
        q->area_mean += area;
        q->angle_max = fmax(q->angle_max, angle);
        q->area_max = fmax(q->area_max, area);
        counted++;
    }
    if (counted > 0) {
        q->angle_mean /= (double)counted;
        q->area_mean /= (double)counted;
    }
    q->valid = 1;
}

bg_status bg_param_write_obj(const bg_scene_t *s, const double *uv, const char *path,
                             bg_error_t *err)
{
    const bg_mesh_t *m = s->surface;
    FILE *f = fopen(path, "w");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "# biotgrid parameterization of %s: %d vertices, %d triangles\n", s->name,
            (int)m->nv, (int)m->ne);
    for (int32_t v = 0; v < m->nv; v++)
        fprintf(f, "v %.17g %.17g %.17g\n", m->x[3 * (size_t)v], m->x[3 * (size_t)v + 1],
                m->x[3 * (size_t)v + 2]);
    for (int32_t v = 0; v < m->nv; v++)
        fprintf(f, "vt %.17g %.17g\n", uv[2 * (size_t)v], uv[2 * (size_t)v + 1]);
    for (int32_t e = 0; e < m->ne; e++) {
        const int32_t *el = m->elements + 3 * (size_t)e;
        fprintf(f, "f %d/%d %d/%d %d/%d\n", el[0] + 1, el[0] + 1, el[1] + 1, el[1] + 1,
                el[2] + 1, el[2] + 1);
    }
    if (fclose(f) != 0)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
    return BG_OK;
}
