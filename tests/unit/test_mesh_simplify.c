/*
 * Tests of bg_mesh_simplify on surfaces built here, checked with code that
 * shares nothing with the module: an icosphere (genus 0) and a torus
 * (genus 1) must stay closed oriented 2-manifolds of the same Euler
 * characteristic, near the exact surface, the sphere enclosing nearly the
 * input's volume; a jittered flat square (open) must keep its boundary on
 * the square's sides, stay in z = 0 with every triangle counter-clockwise
 * and tile the square; two runs must agree bit for bit; where the
 * topology forbids reaching the target (a torus asked for 4 vertices, a
 * tetrahedron, a lone triangle, an annulus of two triangular loops) the
 * simplifier must stop at a valid surface and say so; the normal-rotation
 * option is honoured; malformed input is refused with a precise message.
 * Every output also passes bg_mesh_validate and has no triangle worse than
 * both the quality floor and the worst input triangle.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_mesh.h"
#include "bg_mesh_simplify.h"
#include "test_support.h"

/* ---- inputs ---- */

static bg_mesh_t *new_surface(int32_t nv, int32_t nf)
{
    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_new(BG_MESH_SURFACE, nv, nf, &m, &err) != BG_OK)
        fail_msg("%s", err.message);
    return m;
}

/* Index of the midpoint of a-b, created on first use; edge_key/edge_mid
 * is a linear list, fine for the few thousand edges of these tests. */
static int32_t midpoint(bg_mesh_t *m, int32_t *nv, int64_t *edge_key, int32_t *edge_mid,
                        int32_t *nedges, int32_t a, int32_t b)
{
    const int64_t key = (int64_t)(a < b ? a : b) * 1000000 + (a < b ? b : a);
    for (int32_t i = *nedges - 1; i >= 0; i--)
        if (edge_key[i] == key)
            return edge_mid[i];
    const int32_t v = (*nv)++;
    double *p = m->x + 3 * (size_t)v, len = 0.0;
    for (int c = 0; c < 3; c++) {
        p[c] = 0.5 * (m->x[3 * (size_t)a + c] + m->x[3 * (size_t)b + c]);
        len += p[c] * p[c];
    }
    for (int c = 0; c < 3; c++)
        p[c] /= sqrt(len);
    edge_key[*nedges] = key;
    edge_mid[(*nedges)++] = v;
    return v;
}

/* The icosahedron subdivided `levels` times (each triangle into four),
 * every vertex on the unit sphere, faces counter-clockwise seen from
 * outside: 10*4^levels + 2 vertices. */
static bg_mesh_t *icosphere(int levels)
{
    int32_t nv_final = 12, nf_final = 20;
    for (int l = 0; l < levels; l++) {
        nv_final += 3 * nf_final / 2;
        nf_final *= 4;
    }
    bg_mesh_t *m = new_surface(nv_final, nf_final);
    const double t = (1.0 + sqrt(5.0)) / 2.0;
    const double base[12][3] = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    const int32_t faces[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                  {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                  {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                  {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    const double r = sqrt(1.0 + t * t);
    for (int v = 0; v < 12; v++)
        for (int c = 0; c < 3; c++)
            m->x[3 * v + c] = base[v][c] / r;
    int32_t *cur = malloc(3 * (size_t)nf_final * sizeof *cur);
    int32_t *next = malloc(3 * (size_t)nf_final * sizeof *next);
    int64_t *edge_key = malloc((size_t)nf_final * 2 * sizeof *edge_key);
    int32_t *edge_mid = malloc((size_t)nf_final * 2 * sizeof *edge_mid);
    assert_true(cur && next && edge_key && edge_mid);
    memcpy(cur, faces, sizeof faces);
    int32_t nv = 12, nf = 20;
    for (int l = 0; l < levels; l++) {
        int32_t nedges = 0;
        for (int32_t f = 0; f < nf; f++) {
            const int32_t a = cur[3 * f], b = cur[3 * f + 1], c = cur[3 * f + 2];
            const int32_t ab = midpoint(m, &nv, edge_key, edge_mid, &nedges, a, b);
            const int32_t bc = midpoint(m, &nv, edge_key, edge_mid, &nedges, b, c);
            const int32_t ca = midpoint(m, &nv, edge_key, edge_mid, &nedges, c, a);
            const int32_t sub[12] = {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca};
            memcpy(next + 12 * (size_t)f, sub, sizeof sub);
        }
        nf *= 4;
        int32_t *swap = cur;
        cur = next;
        next = swap;
    }
    assert_int_equal(nv, nv_final);
    memcpy(m->elements, cur, 3 * (size_t)nf * sizeof *cur);
    free(cur);
    free(next);
    free(edge_key);
    free(edge_mid);
    return m;
}

/* Torus of radii R (tube centre) and r (tube), n x k vertices, outward
 * counter-clockwise faces. */
static bg_mesh_t *torus(int32_t n, int32_t k, double R, double r)
{
    bg_mesh_t *m = new_surface(n * k, 2 * n * k);
    for (int32_t i = 0; i < n; i++)
        for (int32_t j = 0; j < k; j++) {
            const double u = 2 * M_PI * i / n, v = 2 * M_PI * j / k;
            double *p = m->x + 3 * (size_t)(i * k + j);
            p[0] = (R + r * cos(v)) * cos(u);
            p[1] = (R + r * cos(v)) * sin(u);
            p[2] = r * sin(v);
        }
    int32_t *e = m->elements;
    for (int32_t i = 0; i < n; i++)
        for (int32_t j = 0; j < k; j++) {
            const int32_t a = i * k + j, b = ((i + 1) % n) * k + j,
                          c = ((i + 1) % n) * k + (j + 1) % k, d = i * k + (j + 1) % k;
            const int32_t two[6] = {a, b, c, a, c, d};
            memcpy(e, two, sizeof two);
            e += 6;
        }
    return m;
}

/* The unit square in z = 0 as n x n cells, each split into two
 * counter-clockwise triangles (normal +z). Interior vertices are moved at
 * random by up to `jitter` cells in x and y (seeded), so that collapsing
 * an edge onto one of its ends can fold triangles over. */
static bg_mesh_t *square(int32_t n, double jitter, uint64_t seed)
{
    bg_mesh_t *m = new_surface((n + 1) * (n + 1), 2 * n * n);
    for (int32_t j = 0; j <= n; j++)
        for (int32_t i = 0; i <= n; i++) {
            double *p = m->x + 3 * (size_t)(j * (n + 1) + i);
            p[0] = (double)i / n;
            p[1] = (double)j / n;
            p[2] = 0.0;
            if (i > 0 && i < n && j > 0 && j < n) {
                p[0] += jitter / n * (2.0 * test_uniform(&seed) - 1.0);
                p[1] += jitter / n * (2.0 * test_uniform(&seed) - 1.0);
            }
        }
    int32_t *e = m->elements;
    for (int32_t j = 0; j < n; j++)
        for (int32_t i = 0; i < n; i++) {
            const int32_t a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
            const int32_t two[6] = {a, b, c, a, c, d};
            memcpy(e, two, sizeof two);
            e += 6;
        }
    return m;
}

/* Concatenates two surfaces (b's vertices numbered after a's) and frees
 * both. */
static bg_mesh_t *join(bg_mesh_t *a, bg_mesh_t *b)
{
    bg_mesh_t *m = new_surface(a->nv + b->nv, a->ne + b->ne);
    memcpy(m->x, a->x, 3 * (size_t)a->nv * sizeof *m->x);
    memcpy(m->x + 3 * (size_t)a->nv, b->x, 3 * (size_t)b->nv * sizeof *m->x);
    memcpy(m->elements, a->elements, 3 * (size_t)a->ne * sizeof *m->elements);
    for (size_t i = 0; i < 3 * (size_t)b->ne; i++)
        m->elements[3 * (size_t)a->ne + i] = b->elements[i] + a->nv;
    bg_mesh_destroy(&a);
    bg_mesh_destroy(&b);
    return m;
}

static bg_mesh_t *surface_of(int32_t nv, const double *x, int32_t nf, const int32_t *faces)
{
    bg_mesh_t *m = new_surface(nv, nf);
    memcpy(m->x, x, 3 * (size_t)nv * sizeof *x);
    memcpy(m->elements, faces, 3 * (size_t)nf * sizeof *faces);
    return m;
}

/* ---- independent checks ---- */

static int compare_i64(const void *a, const void *b)
{
    const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Topology from the sorted directed edges: fails if a directed edge
 * repeats (an edge in more than two faces, or two faces running it the
 * same way) or a vertex is unused; returns the number of boundary edges
 * (those whose reverse is missing) and the Euler characteristic V - E + F. */
typedef struct topology {
    int64_t boundary_edges;
    int64_t euler;
} topology_t;

static topology_t topology_of(const bg_mesh_t *m)
{
    const size_t n = 3 * (size_t)m->ne;
    int64_t *d = malloc(n * sizeof *d);
    assert_non_null(d);
    for (int32_t f = 0; f < m->ne; f++)
        for (int k = 0; k < 3; k++)
            d[3 * (size_t)f + k] = (int64_t)m->elements[3 * (size_t)f + k] * m->nv +
                                   m->elements[3 * (size_t)f + (k + 1) % 3];
    qsort(d, n, sizeof *d, compare_i64);
    topology_t t = {0, 0};
    for (size_t i = 0; i < n; i++) {
        if (i > 0 && d[i] == d[i - 1])
            fail_msg("directed edge %lld -> %lld appears twice", (long long)(d[i] / m->nv),
                     (long long)(d[i] % m->nv));
        const int64_t reverse = (d[i] % m->nv) * m->nv + d[i] / m->nv;
        if (!bsearch(&reverse, d, n, sizeof *d, compare_i64))
            t.boundary_edges++;
    }
    /* Interior edges are counted twice among the directed ones. */
    const int64_t edges = ((int64_t)n + t.boundary_edges) / 2;
    t.euler = (int64_t)m->nv - edges + m->ne;
    /* Every vertex is used by a face (no isolated leftovers). */
    uint8_t *used = calloc((size_t)m->nv, 1);
    assert_non_null(used);
    for (size_t i = 0; i < n; i++)
        used[m->elements[i]] = 1;
    for (int32_t v = 0; v < m->nv; v++)
        assert_true(used[v]);
    free(used);
    free(d);
    return t;
}

static void face_normal(const bg_mesh_t *m, int32_t f, double *n)
{
    const int32_t *t = m->elements + 3 * (size_t)f;
    const double *a = m->x + 3 * (size_t)t[0], *b = m->x + 3 * (size_t)t[1],
                 *c = m->x + 3 * (size_t)t[2];
    const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
}

/* Enclosed volume by the divergence theorem (sum of signed tetrahedra
 * from the origin). */
static double enclosed_volume(const bg_mesh_t *m)
{
    double v = 0.0;
    for (int32_t f = 0; f < m->ne; f++) {
        const int32_t *t = m->elements + 3 * (size_t)f;
        const double *a = m->x + 3 * (size_t)t[0], *b = m->x + 3 * (size_t)t[1],
                     *c = m->x + 3 * (size_t)t[2];
        v += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
              a[2] * (b[0] * c[1] - b[1] * c[0])) /
             6.0;
    }
    return v;
}

/* Longest edge at each vertex (caller frees). */
static double *longest_edge_at(const bg_mesh_t *m)
{
    double *L = calloc((size_t)m->nv, sizeof *L);
    assert_non_null(L);
    for (size_t i = 0; i < 3 * (size_t)m->ne; i++) {
        const int32_t a = m->elements[i], b = m->elements[i / 3 * 3 + (i % 3 + 1) % 3];
        double s = 0.0;
        for (int c = 0; c < 3; c++) {
            const double d = m->x[3 * (size_t)a + c] - m->x[3 * (size_t)b + c];
            s += d * d;
        }
        L[a] = fmax(L[a], sqrt(s));
        L[b] = fmax(L[b], sqrt(s));
    }
    return L;
}

/* Smallest 4*sqrt(3)*area / (sum of squared edges) over the faces. */
static double worst_quality(const bg_mesh_t *m)
{
    double worst = 1.0;
    for (int32_t f = 0; f < m->ne; f++) {
        double n[3], sum = 0.0;
        face_normal(m, f, n);
        for (int k = 0; k < 3; k++) {
            const double *a = m->x + 3 * (size_t)m->elements[3 * (size_t)f + k];
            const double *b = m->x + 3 * (size_t)m->elements[3 * (size_t)f + (k + 1) % 3];
            sum += (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                   (a[2] - b[2]) * (a[2] - b[2]);
        }
        worst = fmin(worst, 2.0 * sqrt(3.0) * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) / sum);
    }
    return worst;
}

/* Simplifies, failing the test on an error; checks what every output
 * must satisfy: counts as reported, bg_mesh_validate passes, and no face
 * worse than both the quality floor and the worst input face (a moved
 * face is above the floor or no worse than it was). */
static bg_mesh_t *simplify_ok(const bg_mesh_t *in, const bg_simplify_options_t *o,
                              bg_simplify_result_t *r)
{
    bg_mesh_t *out = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_simplify(in, o, &out, r, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_non_null(out);
    assert_int_equal(out->nv, r->vertices);
    assert_int_equal(out->ne, r->faces);
    /* The output is a mesh the rest of the project accepts. */
    bg_mesh_t *copy = NULL;
    if (bg_mesh_clone(out, &copy, &err) != BG_OK)
        fail_msg("%s", err.message);
    if (bg_mesh_validate(copy, "simplified", NULL, &err) != BG_OK)
        fail_msg("%s", err.message);
    bg_mesh_destroy(&copy);
    const double floor_q = fmin(o->min_triangle_quality, worst_quality(in));
    assert_true(worst_quality(out) >= floor_q * (1.0 - 1e-9));
    return out;
}

/* ---- tests ---- */

/* 2562-vertex icosphere to 500 vertices. */
static void sphere_keeps_shape(void **state)
{
    bg_mesh_t *in = icosphere(4);
    assert_int_equal(in->nv, 2562);
    for (int32_t v = 0; v < in->nv; v++)
        in->vertex_ref[v] = v + 1;
    for (int32_t f = 0; f < in->ne; f++)
        in->element_ref[f] = f + 1;
    const bg_simplify_options_t o = bg_simplify_defaults(500);
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_int_equal(r.vertices, 500);
    assert_true(r.reached_target);
    assert_int_equal(r.collapses, 2562 - 500);

    const topology_t t = topology_of(out);
    assert_int_equal(t.boundary_edges, 0);
    assert_int_equal(t.euler, 2);
    assert_int_equal(out->ne, 2 * 500 - 4);

    /* Every face still faces outwards: its plane's signed distance from
     * the centre is positive (so the surface is star-shaped about it). */
    for (int32_t f = 0; f < out->ne; f++) {
        double n[3];
        face_normal(out, f, n);
        const double *a = out->x + 3 * (size_t)out->elements[3 * (size_t)f];
        assert_true(n[0] * a[0] + n[1] * a[1] + n[2] * a[2] > 0.0);
    }
    /* Radius: an output vertex sits at an input vertex (radius 1), at the
     * midpoint of an edge (a chord of length l sags l^2/8 below the
     * sphere) or at the point nearest to the planes of the input faces
     * merged into it, near-tangent planes touching the sphere within about
     * half an incident edge l/2 of it, an angle phi = l/2: such planes meet
     * at radius at most 1/cos(phi) ~ 1 + l^2/8. So |radius - 1| <= L^2/8
     * with L the longest edge at the vertex. */
    double *longest = longest_edge_at(out);
    double ratio = 0.0, radius_lo = INFINITY, radius_hi = 0.0;
    for (int32_t v = 0; v < out->nv; v++) {
        const double *p = out->x + 3 * (size_t)v;
        const double rho = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        const double bound = longest[v] * longest[v] / 8.0;
        ratio = fmax(ratio, fabs(rho - 1.0) / bound);
        radius_lo = fmin(radius_lo, rho);
        radius_hi = fmax(radius_hi, rho);
        if (fabs(rho - 1.0) > bound)
            fail_msg("vertex %d at radius %.6f, allowed 1 +- %.6f", (int)v + 1, rho, bound);
    }
    print_message("sphere: radius in [%.5f, %.5f], at most %.2f of the allowed deviation\n",
                  radius_lo, radius_hi, ratio);
    free(longest);

    /* Volume: a polyhedron with its vertices on the unit sphere loses a
     * cap over each face; the plane of an equilateral triangle of side l
     * inscribed in the sphere lies l^2/6 deep, so the ball loses about
     * 3 * mean(l^2)/6 = mean(l^2)/2 of its volume. The input (edges four
     * times shorter) loses far less, so the two volumes may differ by
     * that fraction, no more. */
    double sum_l2 = 0.0;
    for (size_t i = 0; i < 3 * (size_t)out->ne; i++) {
        const double *a = out->x + 3 * (size_t)out->elements[i];
        const double *b = out->x + 3 * (size_t)out->elements[i / 3 * 3 + (i % 3 + 1) % 3];
        sum_l2 += (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                  (a[2] - b[2]) * (a[2] - b[2]);
    }
    const double allowed = 0.5 * sum_l2 / (3.0 * out->ne);
    const double v_in = enclosed_volume(in), v_out = enclosed_volume(out);
    print_message("sphere: volume %.5f -> %.5f (%.2f%%, allowed %.2f%%)\n", v_in, v_out,
                  100.0 * (v_out - v_in) / v_in, 100.0 * allowed);
    assert_true(fabs(v_out - v_in) <= allowed * v_in);

    /* Surviving vertices and faces keep their input order and labels. */
    for (int32_t v = 1; v < out->nv; v++)
        assert_true(out->vertex_ref[v] > out->vertex_ref[v - 1]);
    for (int32_t f = 1; f < out->ne; f++)
        assert_true(out->element_ref[f] > out->element_ref[f - 1]);
    assert_true(out->vertex_ref[0] >= 1 && out->vertex_ref[out->nv - 1] <= in->nv);
    assert_true(out->element_ref[0] >= 1 && out->element_ref[out->ne - 1] <= in->ne);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* 48 x 24 torus (1152 vertices) to 300: genus and surface kept. */
static void torus_keeps_genus(void **state)
{
    const double R = 1.0, rt = 0.4;
    bg_mesh_t *in = torus(48, 24, R, rt);
    const bg_simplify_options_t o = bg_simplify_defaults(300);
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_int_equal(r.vertices, 300);
    const topology_t t = topology_of(out);
    assert_int_equal(t.boundary_edges, 0);
    assert_int_equal(t.euler, 0);
    assert_int_equal(out->ne, 2 * 300);
    /* Distance from the exact torus, bounded as for the sphere by the
     * sag L^2/(8 r) of the longest edge at the vertex over the tube radius
     * r (the smaller principal radius of curvature). */
    double *longest = longest_edge_at(out);
    double ratio = 0.0;
    for (int32_t v = 0; v < out->nv; v++) {
        const double *p = out->x + 3 * (size_t)v;
        const double ring = sqrt(p[0] * p[0] + p[1] * p[1]) - R;
        const double off = fabs(sqrt(ring * ring + p[2] * p[2]) - rt);
        const double bound = longest[v] * longest[v] / (8.0 * rt);
        ratio = fmax(ratio, off / bound);
        if (off > bound)
            fail_msg("vertex %d is %.6f off the torus, allowed %.6f", (int)v + 1, off, bound);
    }
    print_message("torus: at most %.2f of the allowed distance from the surface\n", ratio);
    free(longest);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* 20 x 20 jittered cells (441 vertices) to 100: the boundary stays on the
 * square's sides, the surface in z = 0, every triangle counter-clockwise. */
static void square_keeps_boundary(void **state)
{
    bg_mesh_t *in = square(20, 0.3, 3);
    const bg_simplify_options_t o = bg_simplify_defaults(100);
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_int_equal(r.vertices, 100);
    const topology_t t = topology_of(out);
    assert_int_equal(t.euler, 1); /* a disk */

    double area = 0.0;
    for (int32_t f = 0; f < out->ne; f++) {
        double n[3];
        face_normal(out, f, n);
        assert_true(n[2] > 0.0); /* counter-clockwise: no flip, no fold */
        area += 0.5 * n[2];
    }
    for (int32_t v = 0; v < out->nv; v++)
        assert_true(fabs(out->x[3 * (size_t)v + 2]) <= 1e-12);

    /* Boundary edges (no reverse) run along one side of the square each,
     * and they form a single loop through all four corners. */
    int32_t *succ = malloc((size_t)out->nv * sizeof *succ);
    assert_non_null(succ);
    for (int32_t v = 0; v < out->nv; v++)
        succ[v] = -1;
    int64_t boundary = 0;
    for (int32_t f = 0; f < out->ne; f++)
        for (int k = 0; k < 3; k++) {
            const int32_t a = out->elements[3 * (size_t)f + k],
                          b = out->elements[3 * (size_t)f + (k + 1) % 3];
            int twin = 0;
            for (int32_t g = 0; g < out->ne && !twin; g++)
                for (int j = 0; j < 3; j++)
                    twin |= out->elements[3 * (size_t)g + j] == b &&
                            out->elements[3 * (size_t)g + (j + 1) % 3] == a;
            if (twin)
                continue;
            boundary++;
            const double *pa = out->x + 3 * (size_t)a, *pb = out->x + 3 * (size_t)b;
            const int on_side = (fabs(pa[0]) <= 1e-12 && fabs(pb[0]) <= 1e-12) ||
                                (fabs(pa[0] - 1) <= 1e-12 && fabs(pb[0] - 1) <= 1e-12) ||
                                (fabs(pa[1]) <= 1e-12 && fabs(pb[1]) <= 1e-12) ||
                                (fabs(pa[1] - 1) <= 1e-12 && fabs(pb[1] - 1) <= 1e-12);
            if (!on_side)
                fail_msg("boundary edge (%g %g)-(%g %g) is off the square's sides", pa[0], pa[1],
                         pb[0], pb[1]);
            assert_int_equal(succ[a], -1);
            succ[a] = b;
        }
    assert_int_equal(boundary, t.boundary_edges);
    int32_t start = 0;
    while (start < out->nv && succ[start] < 0)
        start++;
    assert_true(start < out->nv);
    int64_t loop = 0;
    int corners = 0;
    int32_t v = start;
    do {
        const double *p = out->x + 3 * (size_t)v;
        corners += (fabs(p[0]) <= 1e-12 || fabs(p[0] - 1) <= 1e-12) &&
                   (fabs(p[1]) <= 1e-12 || fabs(p[1] - 1) <= 1e-12);
        v = succ[v];
        loop++;
    } while (v >= 0 && v != start && loop <= boundary);
    assert_int_equal(loop, boundary); /* one loop holds every boundary edge */
    assert_int_equal(corners, 4);
    /* Counter-clockwise triangles inside a boundary on the square's sides
     * tile it: their areas add up to exactly 1. */
    assert_true(fabs(area - 1.0) <= 1e-12);
    free(succ);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* Two runs on the same input give the same arrays: the square is all ties
 * (every interior collapse costs zero), a perturbed sphere has none. */
static void deterministic(void **state)
{
    bg_mesh_t *inputs[2] = {square(16, 0.0, 0), icosphere(3)};
    uint64_t rng = 11;
    for (int32_t v = 0; v < inputs[1]->nv; v++)
        for (int c = 0; c < 3; c++)
            inputs[1]->x[3 * (size_t)v + c] *= 1.0 + 0.01 * (test_uniform(&rng) - 0.5);
    for (int i = 0; i < 2; i++) {
        const bg_simplify_options_t o = bg_simplify_defaults(inputs[i]->nv / 4);
        bg_simplify_result_t r1, r2;
        bg_mesh_t *a = simplify_ok(inputs[i], &o, &r1), *b = simplify_ok(inputs[i], &o, &r2);
        assert_int_equal(a->nv, b->nv);
        assert_int_equal(a->ne, b->ne);
        assert_memory_equal(a->x, b->x, 3 * (size_t)a->nv * sizeof *a->x);
        assert_memory_equal(a->elements, b->elements, 3 * (size_t)a->ne * sizeof *a->elements);
        assert_memory_equal(&r1, &r2, sizeof r1);
        bg_mesh_destroy(&a);
        bg_mesh_destroy(&b);
        bg_mesh_destroy(&inputs[i]);
    }
}

/* A torus cannot have fewer than 7 vertices (the Moebius-Csaszar torus is
 * the smallest triangulation): asked for 4 with every geometric check off,
 * the simplifier must stop at a valid torus and report the shortfall. */
static void unreachable_target_reported(void **state)
{
    bg_mesh_t *in = torus(12, 6, 1.0, 0.4);
    const bg_simplify_options_t o = {
        .target_vertices = 4, .max_normal_change = -1.0, .min_triangle_quality = 0.0};
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    print_message("torus stopped at %d vertices after %d collapses\n", (int)r.vertices,
                  (int)r.collapses);
    assert_false(r.reached_target);
    assert_true(r.vertices >= 7);
    assert_true(r.vertices < 72);
    assert_true(r.refused_topology > 0);
    const topology_t t = topology_of(out);
    assert_int_equal(t.boundary_edges, 0);
    assert_int_equal(t.euler, 0);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* Separate components in one mesh, every geometric check off, target 4: a
 * tetrahedron cannot lose a vertex (collapsing any edge would leave two
 * faces on the same three vertices), nor can a lone triangle (its
 * boundary loop would close), but an icosphere goes down to a
 * tetrahedron. The first two components come out untouched. */
static void components_kept(void **state)
{
    const double x[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 3, 0, 0, 4, 0, 0, 3, 1, 0};
    const int32_t faces[] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3, 4, 5, 6};
    bg_mesh_t *sphere = icosphere(1);
    for (int32_t v = 0; v < sphere->nv; v++)
        sphere->x[3 * (size_t)v + 1] += 5.0;
    bg_mesh_t *in = join(surface_of(7, x, 5, faces), sphere);
    assert_int_equal(in->nv, 7 + 42);
    const bg_simplify_options_t o = {
        .target_vertices = 4, .max_normal_change = -1.0, .min_triangle_quality = 0.0};
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_false(r.reached_target);
    assert_int_equal(r.vertices, 7 + 4);
    assert_int_equal(r.faces, 5 + 4);
    assert_memory_equal(out->x, x, sizeof x);
    assert_memory_equal(out->elements, faces, sizeof faces);
    const topology_t t = topology_of(out);
    assert_int_equal(t.boundary_edges, 3);
    assert_int_equal(t.euler, 2 + 1 + 2);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* A flat annulus between two triangular loops: every boundary edge
 * collapse would close a loop and every interior edge joins the two loops,
 * so nothing may collapse, whatever the geometry allows. */
static void annulus_cannot_shrink(void **state)
{
    double x[18];
    for (int i = 0; i < 3; i++) {
        const double a = 2.0 * M_PI * i / 3.0;
        const double outer[3] = {2 * cos(a), 2 * sin(a), 0}, inner[3] = {cos(a), sin(a), 0};
        memcpy(x + 3 * i, outer, sizeof outer);
        memcpy(x + 9 + 3 * i, inner, sizeof inner);
    }
    int32_t faces[18];
    for (int i = 0; i < 3; i++) {
        const int32_t o0 = i, o1 = (i + 1) % 3, i0 = 3 + i, i1 = 3 + (i + 1) % 3;
        const int32_t two[6] = {o0, o1, i1, o0, i1, i0};
        memcpy(faces + 6 * i, two, sizeof two);
    }
    bg_mesh_t *in = surface_of(6, x, 6, faces);
    const bg_simplify_options_t o = {
        .target_vertices = 4, .max_normal_change = -1.0, .min_triangle_quality = 0.0};
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_false(r.reached_target);
    assert_int_equal(r.collapses, 0);
    assert_true(r.refused_topology > 0);
    assert_memory_equal(out->elements, faces, sizeof faces);
    const topology_t t = topology_of(out);
    assert_int_equal(t.boundary_edges, 6);
    assert_int_equal(t.euler, 0);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

/* The normal-rotation limit is honoured: on a 642-vertex icosphere every
 * collapse turns some face by a few degrees (neighbouring faces differ by
 * about 9), so allowing half a degree stops the simplification early,
 * while the default 60 degrees reaches the target. */
static void normal_limit_honoured(void **state)
{
    bg_mesh_t *in = icosphere(3);
    bg_simplify_options_t o = bg_simplify_defaults(200);
    bg_simplify_result_t r;
    bg_mesh_t *out = simplify_ok(in, &o, &r);
    assert_true(r.reached_target);
    bg_mesh_destroy(&out);
    o.max_normal_change = cos(0.5 * M_PI / 180.0);
    out = simplify_ok(in, &o, &r);
    print_message("half a degree: %d of 642 vertices left\n", (int)r.vertices);
    assert_false(r.reached_target);
    assert_true(r.vertices > 600);
    assert_true(r.refused_geometry > 0);
    /* Each face kept within half a degree of the sphere's normal at its
     * centroid would be a stronger claim than the option makes; the
     * topology must hold whatever stops the run. */
    const topology_t t = topology_of(out);
    assert_int_equal(t.euler, 2);
    bg_mesh_destroy(&out);
    bg_mesh_destroy(&in);
}

static void expect_refusal(const bg_mesh_t *in, int32_t target, bg_status status, const char *want)
{
    const bg_simplify_options_t o = bg_simplify_defaults(target);
    bg_mesh_t *out = NULL;
    bg_simplify_result_t r;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_mesh_simplify(in, &o, &out, &r, &err), status);
    assert_int_equal(err.status, status);
    assert_null(out);
    if (!strstr(err.message, want))
        fail_msg("message \"%s\" lacks \"%s\"", err.message, want);
}

static void bad_inputs_refused(void **state)
{
    bg_error_t err = BG_ERROR_INIT;
    bg_mesh_t *box = NULL;
    const int32_t cells[3] = {2, 2, 2};
    const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
    if (bg_mesh_generate_box(cells, origin, size, &box, &err) != BG_OK)
        fail_msg("%s", err.message);
    expect_refusal(box, 10, BG_ERR_INVALID, "needs surface triangles, not tetrahedra");
    bg_mesh_destroy(&box);

    bg_mesh_t *sphere = icosphere(1);
    expect_refusal(sphere, 3, BG_ERR_INVALID, "target of 3 vertices is below 4");
    bg_mesh_destroy(&sphere);

    /* Three faces on the edge between vertices 1 and 2 (1-based). */
    const double x[] = {0, 0, 0, 1, 0, 0, 0.5, 1, 0, 0.5, -1, 0, 0.5, 0, 1};
    const int32_t fan[] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    bg_mesh_t *m = surface_of(5, x, 3, fan);
    expect_refusal(m, 4, BG_ERR_INVALID, "vertices 1 and 2 is shared by 3 faces (1, 2, 3)");
    bg_mesh_destroy(&m);

    /* Two faces running the edge 1 -> 2 the same way. */
    const int32_t flipped[] = {0, 1, 2, 0, 1, 3};
    m = surface_of(4, x, 2, flipped);
    expect_refusal(m, 4, BG_ERR_INVALID, "faces 1 and 2 both run the edge from vertex 1");
    bg_mesh_destroy(&m);

    /* Two triangles touching only at vertex 1: a bow tie. */
    const double y[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, -1, 0, 0, -1, -1, 0};
    const int32_t bowtie[] = {0, 1, 2, 0, 3, 4};
    m = surface_of(5, y, 2, bowtie);
    expect_refusal(m, 4, BG_ERR_INVALID, "vertex 1 joins 2 separate fans");
    bg_mesh_destroy(&m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(sphere_keeps_shape),          cmocka_unit_test(torus_keeps_genus),
        cmocka_unit_test(square_keeps_boundary),       cmocka_unit_test(deterministic),
        cmocka_unit_test(unreachable_target_reported), cmocka_unit_test(components_kept),
        cmocka_unit_test(annulus_cannot_shrink),       cmocka_unit_test(normal_limit_honoured),
        cmocka_unit_test(bad_inputs_refused),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
