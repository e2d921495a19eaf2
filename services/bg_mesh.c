#include "bg_mesh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* An element whose measure is below this fraction of (longest edge)^n is
 * degenerate: its D_m is numerically singular and D_m^{-1} meaningless. */
#define BG_MESH_DEGENERACY_RATIO 1e-12

bg_status bg_mesh_new(bg_mesh_kind kind, int32_t nv, int32_t ne, bg_mesh_t **out, bg_error_t *err)
{
    *out = NULL;
    if (nv < 0 || ne < 0)
        return bg_error_set(err, BG_ERR_INVALID, "negative mesh size (%d vertices, %d elements)",
                            (int)nv, (int)ne);
    if (nv > BG_MESH_MAX_VERTICES || ne > BG_MESH_MAX_ELEMENTS)
        return bg_error_set(err, BG_ERR_LIMIT,
                            "mesh of %d vertices and %d elements exceeds the limits (%d, %d)",
                            (int)nv, (int)ne, BG_MESH_MAX_VERTICES, BG_MESH_MAX_ELEMENTS);
    bg_mesh_t *m = calloc(1, sizeof *m);
    if (!m)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory allocating a mesh");
    m->dim = kind == BG_MESH_PLANAR ? 2 : 3;
    m->nodes_per_element = kind == BG_MESH_VOLUME ? 4 : 3;
    m->nv = nv;
    m->ne = ne;
    m->x = calloc((size_t)nv * (size_t)m->dim + 1, sizeof *m->x);
    m->elements = calloc((size_t)ne * (size_t)m->nodes_per_element + 1, sizeof *m->elements);
    m->vertex_ref = calloc((size_t)nv + 1, sizeof *m->vertex_ref);
    m->element_ref = calloc((size_t)ne + 1, sizeof *m->element_ref);
    if (!m->x || !m->elements || !m->vertex_ref || !m->element_ref) {
        bg_mesh_destroy(&m);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory allocating a mesh of %d vertices",
                            (int)nv);
    }
    *out = m;
    return BG_OK;
}

void bg_mesh_destroy(bg_mesh_t **mesh)
{
    if (!mesh || !*mesh)
        return;
    bg_mesh_t *m = *mesh;
    free(m->x);
    free(m->elements);
    free(m->vertex_ref);
    free(m->element_ref);
    free(m);
    *mesh = NULL;
}

bg_status bg_mesh_clone(const bg_mesh_t *mesh, bg_mesh_t **out, bg_error_t *err)
{
    bg_status st = bg_mesh_new(bg_mesh_kind_of(mesh), mesh->nv, mesh->ne, out, err);
    if (st != BG_OK)
        return st;
    bg_mesh_t *m = *out;
    memcpy(m->x, mesh->x, (size_t)mesh->nv * (size_t)mesh->dim * sizeof *m->x);
    memcpy(m->elements, mesh->elements,
           (size_t)mesh->ne * (size_t)mesh->nodes_per_element * sizeof *m->elements);
    memcpy(m->vertex_ref, mesh->vertex_ref, (size_t)mesh->nv * sizeof *m->vertex_ref);
    memcpy(m->element_ref, mesh->element_ref, (size_t)mesh->ne * sizeof *m->element_ref);
    return BG_OK;
}

bg_mesh_kind bg_mesh_kind_of(const bg_mesh_t *mesh)
{
    if (mesh->dim == 2)
        return BG_MESH_PLANAR;
    return mesh->nodes_per_element == 4 ? BG_MESH_VOLUME : BG_MESH_SURFACE;
}

const char *bg_mesh_kind_name(bg_mesh_kind kind)
{
    switch (kind) {
    case BG_MESH_PLANAR:
        return "planar triangles";
    case BG_MESH_VOLUME:
        return "tetrahedra";
    case BG_MESH_SURFACE:
        return "surface triangles";
    }
    return "unknown";
}

double bg_mesh_element_measure(const bg_mesh_t *mesh, const double *x, int32_t e)
{
    const int32_t *el = mesh->elements + (size_t)e * (size_t)mesh->nodes_per_element;
    const int d = mesh->dim;
    double a[3] = {0}, b[3] = {0}, c[3] = {0};
    for (int i = 0; i < d; i++) {
        a[i] = x[(size_t)el[1] * d + i] - x[(size_t)el[0] * d + i];
        b[i] = x[(size_t)el[2] * d + i] - x[(size_t)el[0] * d + i];
        if (mesh->nodes_per_element == 4)
            c[i] = x[(size_t)el[3] * d + i] - x[(size_t)el[0] * d + i];
    }
    switch (bg_mesh_kind_of(mesh)) {
    case BG_MESH_PLANAR:
        return 0.5 * (a[0] * b[1] - a[1] * b[0]);
    case BG_MESH_VOLUME:
        return (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
                a[2] * (b[0] * c[1] - b[1] * c[0])) /
               6.0;
    case BG_MESH_SURFACE: {
        double n0 = a[1] * b[2] - a[2] * b[1], n1 = a[2] * b[0] - a[0] * b[2],
               n2 = a[0] * b[1] - a[1] * b[0];
        return 0.5 * sqrt(n0 * n0 + n1 * n1 + n2 * n2);
    }
    }
    return 0.0;
}

static double longest_edge(const bg_mesh_t *mesh, int32_t e)
{
    const int k = mesh->nodes_per_element, d = mesh->dim;
    const int32_t *el = mesh->elements + (size_t)e * (size_t)k;
    double longest = 0.0;
    for (int i = 0; i < k; i++)
        for (int j = i + 1; j < k; j++) {
            double s = 0.0;
            for (int c = 0; c < d; c++) {
                double t = mesh->x[(size_t)el[i] * d + c] - mesh->x[(size_t)el[j] * d + c];
                s += t * t;
            }
            longest = fmax(longest, s);
        }
    return sqrt(longest);
}

bg_status bg_mesh_validate(bg_mesh_t *mesh, const char *source, int32_t *reoriented,
                           bg_error_t *err)
{
    const int k = mesh->nodes_per_element, d = mesh->dim;
    int32_t flips = 0;
    if (reoriented)
        *reoriented = 0;
    if (mesh->nv == 0 || mesh->ne == 0)
        return bg_error_set(err, BG_ERR_INVALID, "%s: the mesh has %d vertices and %d elements",
                            source, (int)mesh->nv, (int)mesh->ne);
    for (int32_t v = 0; v < mesh->nv; v++)
        for (int c = 0; c < d; c++)
            if (!isfinite(mesh->x[(size_t)v * d + c]))
                return bg_error_set(err, BG_ERR_INVALID,
                                    "%s: vertex %d has a non-finite coordinate %c", source,
                                    (int)v + 1, "xyz"[c]);
    for (int32_t e = 0; e < mesh->ne; e++) {
        int32_t *el = mesh->elements + (size_t)e * (size_t)k;
        for (int i = 0; i < k; i++) {
            if (el[i] < 0 || el[i] >= mesh->nv)
                return bg_error_set(err, BG_ERR_INVALID,
                                    "%s: element %d refers to vertex %d, outside 1..%d", source,
                                    (int)e + 1, (int)el[i] + 1, (int)mesh->nv);
            for (int j = 0; j < i; j++)
                if (el[i] == el[j])
                    return bg_error_set(err, BG_ERR_INVALID, "%s: element %d repeats vertex %d",
                                        source, (int)e + 1, (int)el[i] + 1);
        }
        double measure = bg_mesh_element_measure(mesh, mesh->x, e);
        double scale = pow(longest_edge(mesh, e), k - 1);
        if (!(fabs(measure) > BG_MESH_DEGENERACY_RATIO * scale)) {
            char fourth[16] = "";
            if (k == 4)
                snprintf(fourth, sizeof fourth, " %d", (int)el[3] + 1);
            return bg_error_set(err, BG_ERR_INVALID,
                                "%s: element %d (vertices %d %d %d%s) is degenerate: its %s is "
                                "%.3g, zero for its size",
                                source, (int)e + 1, (int)el[0] + 1, (int)el[1] + 1, (int)el[2] + 1,
                                fourth, k == 4 ? "volume" : "area", measure);
        }
        if (measure < 0.0 && bg_mesh_kind_of(mesh) != BG_MESH_SURFACE) {
            int32_t t = el[1];
            el[1] = el[2];
            el[2] = t;
            flips++;
        }
    }
    if (reoriented)
        *reoriented = flips;
    return BG_OK;
}

void bg_mesh_bounds(const bg_mesh_t *mesh, double *lo, double *hi)
{
    const int d = mesh->dim;
    for (int c = 0; c < d; c++) {
        lo[c] = INFINITY;
        hi[c] = -INFINITY;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        for (int c = 0; c < d; c++) {
            double t = mesh->x[(size_t)v * d + c];
            lo[c] = fmin(lo[c], t);
            hi[c] = fmax(hi[c], t);
        }
}

static bg_status check_cells(int n, const int32_t *cells, const double *size, bg_error_t *err)
{
    double total = 1.0;
    for (int i = 0; i < n; i++) {
        if (cells[i] < 1)
            return bg_error_set(err, BG_ERR_INVALID, "generator: cells[%d] = %d must be >= 1", i,
                                (int)cells[i]);
        if (!(size[i] > 0.0) || !isfinite(size[i]))
            return bg_error_set(err, BG_ERR_INVALID, "generator: size[%d] = %g must be positive", i,
                                size[i]);
        total *= (double)cells[i] + 1.0;
    }
    if (total > (double)BG_MESH_MAX_VERTICES)
        return bg_error_set(err, BG_ERR_LIMIT, "generator: %.0f vertices exceed the limit %d",
                            total, BG_MESH_MAX_VERTICES);
    return BG_OK;
}

bg_status bg_mesh_generate_box(const int32_t cells[3], const double origin[3], const double size[3],
                               bg_mesh_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = check_cells(3, cells, size, err);
    if (st != BG_OK)
        return st;
    const int32_t nx = cells[0], ny = cells[1], nz = cells[2];
    if (6.0 * nx * ny * nz > (double)BG_MESH_MAX_ELEMENTS)
        return bg_error_set(err, BG_ERR_LIMIT, "generator: box of %d x %d x %d cells is too large",
                            (int)nx, (int)ny, (int)nz);
    bg_mesh_t *m = NULL;
    st = bg_mesh_new(BG_MESH_VOLUME, (nx + 1) * (ny + 1) * (nz + 1), 6 * nx * ny * nz, &m, err);
    if (st != BG_OK)
        return st;
#define BOX_VERTEX(i, j, k) (((k) * (ny + 1) + (j)) * (nx + 1) + (i))
    for (int32_t k = 0; k <= nz; k++)
        for (int32_t j = 0; j <= ny; j++)
            for (int32_t i = 0; i <= nx; i++) {
                double *p = m->x + 3 * (size_t)BOX_VERTEX(i, j, k);
                p[0] = origin[0] + size[0] * i / nx;
                p[1] = origin[1] + size[1] * j / ny;
                p[2] = origin[2] + size[2] * k / nz;
            }
    /* Kuhn subdivision: each tetrahedron follows one monotone path from the
     * cube's corner (0,0,0) to (1,1,1); the axis order is a permutation, and
     * odd permutations swap two vertices to keep the orientation positive. */
    static const int perms[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1},
                                    {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
    int32_t *el = m->elements;
    for (int32_t k = 0; k < nz; k++)
        for (int32_t j = 0; j < ny; j++)
            for (int32_t i = 0; i < nx; i++)
                for (int p = 0; p < 6; p++) {
                    int32_t c[3] = {i, j, k};
                    int32_t path[4];
                    path[0] = BOX_VERTEX(c[0], c[1], c[2]);
                    for (int s = 0; s < 3; s++) {
                        c[perms[p][s]]++;
                        path[s + 1] = BOX_VERTEX(c[0], c[1], c[2]);
                    }
                    if (p >= 3) {
                        int32_t t = path[1];
                        path[1] = path[2];
                        path[2] = t;
                    }
                    memcpy(el, path, sizeof path);
                    el += 4;
                }
#undef BOX_VERTEX
    *out = m;
    return BG_OK;
}

bg_status bg_mesh_generate_rectangle(const int32_t cells[2], const double origin[2],
                                     const double size[2], bg_mesh_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_status st = check_cells(2, cells, size, err);
    if (st != BG_OK)
        return st;
    const int32_t nx = cells[0], ny = cells[1];
    if (2.0 * nx * ny > (double)BG_MESH_MAX_ELEMENTS)
        return bg_error_set(err, BG_ERR_LIMIT, "generator: rectangle of %d x %d cells is too large",
                            (int)nx, (int)ny);
    bg_mesh_t *m = NULL;
    st = bg_mesh_new(BG_MESH_PLANAR, (nx + 1) * (ny + 1), 2 * nx * ny, &m, err);
    if (st != BG_OK)
        return st;
    for (int32_t j = 0; j <= ny; j++)
        for (int32_t i = 0; i <= nx; i++) {
            double *p = m->x + 2 * (size_t)(j * (nx + 1) + i);
            p[0] = origin[0] + size[0] * i / nx;
            p[1] = origin[1] + size[1] * j / ny;
        }
    int32_t *el = m->elements;
    for (int32_t j = 0; j < ny; j++)
        for (int32_t i = 0; i < nx; i++) {
            int32_t a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
            /* Alternate the diagonal so the mesh has no preferred direction. */
            if ((i + j) % 2 == 0) {
                int32_t t[6] = {a, b, d, a, d, c};
                memcpy(el, t, sizeof t);
            } else {
                int32_t t[6] = {a, b, c, b, d, c};
                memcpy(el, t, sizeof t);
            }
            el += 6;
        }
    *out = m;
    return BG_OK;
}

/* Vertex j (taken modulo the ring's 6k vertices) of ring k; ring 0 is the centre. */
static int32_t disk_vertex(int32_t k, int32_t j)
{
    if (k == 0)
        return 0;
    const int32_t count = 6 * k;
    return 1 + 3 * k * (k - 1) + j % count;
}

bg_status bg_mesh_generate_disk(int32_t rings, const double center[3], double radius,
                                bg_mesh_kind kind, bg_mesh_t **out, bg_error_t *err)
{
    *out = NULL;
    if (kind != BG_MESH_PLANAR && kind != BG_MESH_SURFACE)
        return bg_error_set(err, BG_ERR_INVALID, "generator: a disk is planar or a surface");
    if (rings < 1)
        return bg_error_set(err, BG_ERR_INVALID, "generator: rings = %d must be >= 1", (int)rings);
    if (!(radius > 0.0) || !isfinite(radius))
        return bg_error_set(err, BG_ERR_INVALID, "generator: radius = %g must be positive", radius);
    const int dim = kind == BG_MESH_PLANAR ? 2 : 3;
    for (int c = 0; c < dim; c++)
        if (!isfinite(center[c]))
            return bg_error_set(err, BG_ERR_INVALID, "generator: center[%d] is not finite", c);
    const double vertices = 1.0 + 3.0 * rings * ((double)rings + 1.0),
                 triangles = 6.0 * (double)rings * rings;
    if (vertices > (double)BG_MESH_MAX_VERTICES || triangles > (double)BG_MESH_MAX_ELEMENTS)
        return bg_error_set(err, BG_ERR_LIMIT, "generator: a disk of %d rings is too large",
                            (int)rings);
    bg_mesh_t *m = NULL;
    bg_status st = bg_mesh_new(kind, (int32_t)vertices, (int32_t)triangles, &m, err);
    if (st != BG_OK)
        return st;
    const double two_pi = 6.283185307179586476925;
    for (int32_t k = 0; k <= rings; k++) {
        const int32_t count = k ? 6 * k : 1;
        const double r = radius * k / rings;
        for (int32_t j = 0; j < count; j++) {
            const double angle = two_pi * j / count;
            double *p = m->x + (size_t)dim * disk_vertex(k, j);
            p[0] = center[0] + r * cos(angle);
            p[1] = center[1] + r * sin(angle);
            if (dim == 3)
                p[2] = center[2];
        }
    }
    /* Between rings k−1 and k each of the six sectors holds k triangles with
     * an edge on ring k and k − 1 with an edge on ring k − 1 (2k − 1 in all),
     * every one counter-clockwise as angles grow counter-clockwise. */
    int32_t *el = m->elements;
    for (int32_t k = 1; k <= rings; k++)
        for (int32_t s = 0; s < 6; s++) {
            const int32_t in0 = s * (k - 1), out0 = s * k;
            for (int32_t j = 0; j < k; j++) {
                el[0] = disk_vertex(k - 1, in0 + j);
                el[1] = disk_vertex(k, out0 + j);
                el[2] = disk_vertex(k, out0 + j + 1);
                el += 3;
            }
            for (int32_t i = 0; i + 1 < k; i++) {
                el[0] = disk_vertex(k - 1, in0 + i);
                el[1] = disk_vertex(k, out0 + i + 1);
                el[2] = disk_vertex(k - 1, in0 + i + 1);
                el += 3;
            }
        }
    *out = m;
    return BG_OK;
}

/* ------------------------------------------------------ disk topology */

typedef struct edge {
    int32_t lo, hi;     /* undirected key */
    int32_t from, to;   /* as the triangle runs it */
} edge_t;

static int edge_cmp(const void *a, const void *b)
{
    const edge_t *x = a, *y = b;
    if (x->lo != y->lo)
        return (x->lo > y->lo) - (x->lo < y->lo);
    return (x->hi > y->hi) - (x->hi < y->hi);
}

/* Boundary edges are those used by one triangle; each gives next[from] = to. */
bg_status bg_mesh_disk_boundary(const bg_mesh_t *m, const char *name, int32_t *loop,
                                int32_t *count, bg_error_t *err)
{
    bg_status st = BG_OK;
    const size_t ne3 = (size_t)m->ne * 3;
    edge_t *edges = malloc(ne3 * sizeof *edges + 1);
    int32_t *next = malloc(((size_t)m->nv + 1) * sizeof *next);
    if (!edges || !next) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory finding the boundary");
        goto out;
    }
    for (int32_t e = 0; e < m->ne; e++)
        for (int i = 0; i < 3; i++) {
            const int32_t a = m->elements[3 * e + i], b = m->elements[3 * e + (i + 1) % 3];
            edges[3 * (size_t)e + i] = (edge_t){a < b ? a : b, a < b ? b : a, a, b};
        }
    qsort(edges, ne3, sizeof *edges, edge_cmp);
    for (int32_t v = 0; v < m->nv; v++)
        next[v] = -1;
    int32_t boundary = 0, start = -1;
    for (size_t i = 0; i < ne3;) {
        size_t j = i;
        while (j < ne3 && edges[j].lo == edges[i].lo && edges[j].hi == edges[i].hi)
            j++;
        if (j - i > 2) {
            st = bg_error_set(err, BG_ERR_INVALID, "%s: edge %d-%d is shared by %zu triangles "
                              "(not a manifold surface)", name, (int)edges[i].lo + 1,
                              (int)edges[i].hi + 1, j - i);
            goto out;
        }
        if (j - i == 1) {
            if (next[edges[i].from] >= 0) {
                st = bg_error_set(err, BG_ERR_INVALID, "%s: the boundary touches itself at "
                                  "vertex %d", name, (int)edges[i].from + 1);
                goto out;
            }
            next[edges[i].from] = edges[i].to;
            start = edges[i].from;
            boundary++;
        }
        i = j;
    }
    if (boundary == 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: the surface is closed; parameterization needs "
                          "a disk (one boundary loop)", name);
        goto out;
    }
    int32_t n = 0;
    for (int32_t v = start; n == 0 || v != start; v = next[v]) {
        if (v < 0 || n >= boundary) {
            st = bg_error_set(err, BG_ERR_INVALID, "%s: the boundary is not one closed loop",
                              name);
            goto out;
        }
        loop[n++] = v;
    }
    if (n != boundary) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: the surface has several boundary loops (%d "
                          "boundary edges, the first loop has %d); parameterization needs a "
                          "disk", name, (int)boundary, (int)n);
        goto out;
    }
    *count = n;
out:
    free(edges);
    free(next);
    return st;
}

bg_status bg_mesh_check_disk(const bg_mesh_t *surface, const char *name, bg_error_t *err)
{
    if (bg_mesh_kind_of(surface) != BG_MESH_SURFACE)
        return bg_error_set(err, BG_ERR_INVALID, "%s: parameterization needs a triangle surface "
                            "in 3D, got %s", name, bg_mesh_kind_name(bg_mesh_kind_of(surface)));
    int32_t *loop = malloc(((size_t)surface->nv + 1) * sizeof *loop);
    int32_t nloop = 0;
    if (!loop)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory checking the parameterization");
    bg_status st = bg_mesh_disk_boundary(surface, name, loop, &nloop, err);
    free(loop);
    return st;
}
