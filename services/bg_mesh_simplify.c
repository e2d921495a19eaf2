#include "bg_mesh_simplify.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* A boundary edge's constraint plane weighs this many times its squared
 * length, against the area of the faces around it for a face plane: moving
 * the boundary off itself costs a thousand times what moving the surface
 * off itself by the same distance does, so boundaries go last and stay. */
#define SIMPLIFY_BOUNDARY_WEIGHT 1000.0
/* A vertex may not gather more faces than this (or than the most any input
 * vertex has): high-valence vertices mean sliver fans, and the cap bounds
 * the per-collapse scratch arrays. */
#define SIMPLIFY_FAN_CAP 32
/* The quadric's 3x3 part is solved only when det(A) > this * trace(A)^3,
 * which bounds its condition number by the inverse; flat and cylindrical
 * patches (rank 1 and 2) fall back to the endpoints and the midpoint. */
#define SIMPLIFY_CONDITION_FLOOR 1e-9
/* A triangle whose quality is below this is degenerate whatever the
 * options say (mirrors bg_mesh_validate's area-to-size ratio). */
#define SIMPLIFY_DEGENERATE_QUALITY 1e-12

/* Symmetric 4x4 quadric, upper triangle row by row:
 * a00 a01 a02 a03 a11 a12 a13 a22 a23 a33. */
typedef struct quadric {
    double a[10];
} quadric_t;

/* A candidate collapse in the queue. It is current while both vertices are
 * alive and their stamps still match: every change of a vertex's quadric,
 * position or neighbourhood bumps its stamp, which lazily invalidates every
 * entry computed before. */
typedef struct heap_entry {
    double cost;
    int32_t u, v; /* u < v; u survives */
    uint32_t su, sv;
    int32_t placement; /* index into the edge's candidate list */
} heap_entry_t;

/* Up to four placements of the merged vertex, cheapest first. */
typedef struct placements {
    int n;
    double p[4][3];
    double cost[4];
} placements_t;

typedef struct simplifier {
    int32_t nv, nf;
    double center[3];     /* quadrics are taken about this point, for precision */
    double *pos;          /* nv*3 current positions */
    quadric_t *q;         /* nv */
    int32_t *tri;         /* nf*3 current vertices; corner c is tri[c] of face c/3 */
    int32_t *corner_next; /* nf*3: next corner of the same vertex, -1 ends */
    int32_t *head;        /* nv: first corner of each vertex, -1 if none */
    int32_t *fan;         /* nv: faces around each vertex */
    uint32_t *stamp;      /* nv */
    uint8_t *vertex_alive, *face_alive, *boundary;
    uint32_t *mark, *ring_mark; /* nv scratch marks compared with a tick */
    uint32_t tick, ring_tick;
    int32_t fan_cap;
    int32_t *fu, *fv, *ring; /* per-collapse scratch, fan_cap (+1) each */
    heap_entry_t *heap;
    size_t heap_n, heap_cap;
    int32_t alive_vertices, alive_faces;
    double min_cos, min_quality;
    bg_simplify_result_t stats;
} simplifier_t;

static void sub3(const double *a, const double *b, double *r)
{
    r[0] = a[0] - b[0];
    r[1] = a[1] - b[1];
    r[2] = a[2] - b[2];
}

static void cross3(const double *a, const double *b, double *r)
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}

static double dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Adds weight * (n.(p - center) + d)^2 for the unit normal n and offset d. */
static void quadric_add_plane(quadric_t *q, const double *n, double d, double weight)
{
    q->a[0] += weight * n[0] * n[0];
    q->a[1] += weight * n[0] * n[1];
    q->a[2] += weight * n[0] * n[2];
    q->a[3] += weight * n[0] * d;
    q->a[4] += weight * n[1] * n[1];
    q->a[5] += weight * n[1] * n[2];
    q->a[6] += weight * n[1] * d;
    q->a[7] += weight * n[2] * n[2];
    q->a[8] += weight * n[2] * d;
    q->a[9] += weight * d * d;
}

/* The quadric's value at p (absolute coordinates), clamped at zero where
 * rounding would make a positive semi-definite form negative. */
static double quadric_eval(const quadric_t *q, const double *center, const double *p)
{
    const double *a = q->a;
    const double x = p[0] - center[0], y = p[1] - center[1], z = p[2] - center[2];
    const double e = a[0] * x * x + 2.0 * a[1] * x * y + 2.0 * a[2] * x * z + 2.0 * a[3] * x +
                     a[4] * y * y + 2.0 * a[5] * y * z + 2.0 * a[6] * y + a[7] * z * z +
                     2.0 * a[8] * z + a[9];
    return e > 0.0 ? e : 0.0;
}

/* Marks are compared with a tick rather than cleared: one increment
 * forgets every mark, and only a wrap-around needs the array wiped. */
static uint32_t next_tick(uint32_t *marks, uint32_t *tick, int32_t n)
{
    if (++*tick == 0) {
        memset(marks, 0, (size_t)n * sizeof *marks);
        *tick = 1;
    }
    return *tick;
}

/* The other two vertices of corner c's face, in the face's orientation. */
static void corner_others(const simplifier_t *s, int32_t c, int32_t *next, int32_t *prev)
{
    const int32_t f = c / 3, k = c % 3;
    *next = s->tri[3 * f + (k + 1) % 3];
    *prev = s->tri[3 * f + (k + 2) % 3];
}

static void free_simplifier(simplifier_t *s)
{
    free(s->pos);
    free(s->q);
    free(s->tri);
    free(s->corner_next);
    free(s->head);
    free(s->fan);
    free(s->stamp);
    free(s->vertex_alive);
    free(s->face_alive);
    free(s->boundary);
    free(s->mark);
    free(s->ring_mark);
    free(s->fu);
    free(s->fv);
    free(s->ring);
    free(s->heap);
}

/* Number of faces around x that also use y (error messages only). */
static int32_t faces_on_edge(const simplifier_t *s, int32_t x, int32_t y, int32_t *list, int cap)
{
    int32_t n = 0;
    for (int32_t c = s->head[x]; c >= 0; c = s->corner_next[c]) {
        int32_t nx, pv;
        corner_others(s, c, &nx, &pv);
        if (nx == y || pv == y) {
            if (n < cap)
                list[n] = c / 3;
            n++;
        }
    }
    return n;
}

/*
 * Checks manifoldness from the corner lists and sets the boundary flags,
 * the fan sizes, the fan cap and *edges (the number of distinct edges).
 * While vertex x is examined, mark[y] == x + 1 records the edge x -> y,
 * ring_mark[z] == x + 1 the edge z -> x, and ring_next[y] = z (nv
 * entries, caller's scratch) that x's face (x, y, z) leads from y to z
 * around x. Messages name vertices and faces 1-based.
 */
static bg_status check_manifold(simplifier_t *s, int32_t *ring_next, int64_t *edges,
                                bg_error_t *err)
{
    int64_t count = 0;
    int32_t widest = 0;
    for (int32_t x = 0; x < s->nv; x++) {
        if (s->head[x] < 0)
            continue;
        const uint32_t t = (uint32_t)x + 1; /* marks start at 0: x + 1 is unique */
        int32_t faces = 0;
        for (int32_t c = s->head[x]; c >= 0; c = s->corner_next[c]) {
            int32_t y, z;
            corner_others(s, c, &y, &z);
            if (s->mark[y] == t) {
                int32_t list[3];
                const int32_t n = faces_on_edge(s, x, y, list, 3);
                if (n > 2)
                    return bg_error_set(err, BG_ERR_INVALID,
                                        "mesh simplification: the edge between vertices %d and %d "
                                        "is shared by %d faces (%d, %d, %d%s); the surface must "
                                        "be a 2-manifold",
                                        (int)x + 1, (int)y + 1, (int)n, (int)list[0] + 1,
                                        (int)list[1] + 1, (int)list[2] + 1, n > 3 ? ", ..." : "");
                return bg_error_set(err, BG_ERR_INVALID,
                                    "mesh simplification: faces %d and %d both run the edge from "
                                    "vertex %d to vertex %d in the same direction; the surface "
                                    "must be consistently oriented",
                                    (int)list[0] + 1, (int)list[1] + 1, (int)x + 1, (int)y + 1);
            }
            s->mark[y] = t;
            s->ring_mark[z] = t;
            ring_next[y] = z;
            faces++;
        }
        /* One fan: a boundary vertex's faces form one path from the only
         * out-edge with no matching in-edge, an interior vertex's one cycle. */
        int32_t start = -1, starts = 0, boundary_edges = 0;
        for (int32_t c = s->head[x]; c >= 0; c = s->corner_next[c]) {
            int32_t y, z;
            corner_others(s, c, &y, &z);
            if (s->ring_mark[y] != t) {
                start = y;
                starts++;
                boundary_edges++;
            } else if (x < y) {
                count++;
            }
            if (s->mark[z] != t)
                boundary_edges++;
        }
        count += starts;
        if (starts > 1)
            return bg_error_set(err, BG_ERR_INVALID,
                                "mesh simplification: vertex %d joins %d separate fans of faces "
                                "(%d boundary edges meet there); the surface must be a 2-manifold",
                                (int)x + 1, (int)starts, (int)boundary_edges);
        if (start < 0)
            start = s->tri[s->head[x] / 3 * 3 + (s->head[x] % 3 + 1) % 3];
        int32_t walked = 0;
        for (int32_t y = start; walked <= faces;) {
            walked++;
            y = ring_next[y];
            if (y == start || s->mark[y] != t)
                break;
        }
        if (walked != faces)
            return bg_error_set(err, BG_ERR_INVALID,
                                "mesh simplification: the %d faces around vertex %d form more "
                                "than one fan; the surface must be a 2-manifold",
                                (int)faces, (int)x + 1);
        if (starts == 0 && faces < 3)
            return bg_error_set(err, BG_ERR_INVALID,
                                "mesh simplification: vertex %d is closed by only %d faces (two "
                                "faces on the same three vertices)",
                                (int)x + 1, (int)faces);
        s->boundary[x] = starts > 0;
        s->fan[x] = faces;
        if (faces > widest)
            widest = faces;
    }
    s->fan_cap = widest > SIMPLIFY_FAN_CAP ? widest : SIMPLIFY_FAN_CAP;
    *edges = count;
    return BG_OK;
}

/* Face planes (area-weighted) and boundary constraint planes into the
 * vertex quadrics. Needs the boundary flags and corner lists. */
static void init_quadrics(simplifier_t *s)
{
    for (int32_t f = 0; f < s->nf; f++) {
        const int32_t *t = s->tri + 3 * (size_t)f;
        double e1[3], e2[3], n[3], rel[3];
        sub3(s->pos + 3 * (size_t)t[1], s->pos + 3 * (size_t)t[0], e1);
        sub3(s->pos + 3 * (size_t)t[2], s->pos + 3 * (size_t)t[0], e2);
        cross3(e1, e2, n);
        const double len = sqrt(dot3(n, n)); /* nonzero: checked on input */
        for (int i = 0; i < 3; i++)
            n[i] /= len;
        sub3(s->pos + 3 * (size_t)t[0], s->center, rel);
        const double d = -dot3(n, rel), area = 0.5 * len;
        for (int k = 0; k < 3; k++)
            quadric_add_plane(&s->q[t[k]], n, d, area);
        for (int k = 0; k < 3; k++) {
            const int32_t x = t[k], y = t[(k + 1) % 3];
            if (!s->boundary[x] || !s->boundary[y])
                continue;
            /* x -> y is a boundary edge when no face runs y -> x. */
            int twin = 0;
            for (int32_t c = s->head[y]; c >= 0 && !twin; c = s->corner_next[c]) {
                int32_t nx, pv;
                corner_others(s, c, &nx, &pv);
                twin = nx == x;
            }
            if (twin)
                continue;
            double e[3], m[3];
            sub3(s->pos + 3 * (size_t)y, s->pos + 3 * (size_t)x, e);
            cross3(e, n, m);
            const double ml = sqrt(dot3(m, m)), l2 = dot3(e, e);
            for (int i = 0; i < 3; i++)
                m[i] /= ml;
            sub3(s->pos + 3 * (size_t)x, s->center, rel);
            const double dm = -dot3(m, rel);
            quadric_add_plane(&s->q[x], m, dm, SIMPLIFY_BOUNDARY_WEIGHT * l2);
            quadric_add_plane(&s->q[y], m, dm, SIMPLIFY_BOUNDARY_WEIGHT * l2);
        }
    }
}

/*
 * The candidate positions of the vertex u-v collapses to, cheapest first
 * (ties keep the order optimum, u, v, midpoint). When exactly one endpoint
 * is on the boundary only its position is offered, so the boundary never
 * moves inwards. The optimum of Q_u + Q_v is offered when its 3x3 system
 * is well conditioned and the point lies within one edge length of the
 * midpoint (a farther optimum is an artefact of a nearly flat patch).
 */
static void compute_placements(const simplifier_t *s, int32_t u, int32_t v, placements_t *pl)
{
    quadric_t q;
    for (int i = 0; i < 10; i++)
        q.a[i] = s->q[u].a[i] + s->q[v].a[i];
    const double *pu = s->pos + 3 * (size_t)u, *pv = s->pos + 3 * (size_t)v;
    pl->n = 0;
    if (s->boundary[u] != s->boundary[v]) {
        memcpy(pl->p[0], s->boundary[u] ? pu : pv, sizeof pl->p[0]);
        pl->cost[0] = quadric_eval(&q, s->center, pl->p[0]);
        pl->n = 1;
        return;
    }
    double mid[3], d[3];
    for (int i = 0; i < 3; i++)
        mid[i] = 0.5 * (pu[i] + pv[i]);
    sub3(pu, pv, d);
    const double len2 = dot3(d, d);
    const double *a = q.a;
    const double c00 = a[4] * a[7] - a[5] * a[5], c01 = a[2] * a[5] - a[1] * a[7],
                 c02 = a[1] * a[5] - a[2] * a[4], c11 = a[0] * a[7] - a[2] * a[2],
                 c12 = a[1] * a[2] - a[0] * a[5], c22 = a[0] * a[4] - a[1] * a[1];
    const double det = a[0] * c00 + a[1] * c01 + a[2] * c02, tr = a[0] + a[4] + a[7];
    if (det > SIMPLIFY_CONDITION_FLOOR * tr * tr * tr) {
        /* x = -A^{-1} b with the adjugate; x is relative to the center. */
        const double b0 = a[3], b1 = a[6], b2 = a[8];
        double *p = pl->p[0];
        p[0] = -(c00 * b0 + c01 * b1 + c02 * b2) / det + s->center[0];
        p[1] = -(c01 * b0 + c11 * b1 + c12 * b2) / det + s->center[1];
        p[2] = -(c02 * b0 + c12 * b1 + c22 * b2) / det + s->center[2];
        double off[3];
        sub3(p, mid, off);
        if (isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]) && dot3(off, off) <= len2)
            pl->n = 1;
    }
    const double *fallback[3] = {pu, pv, mid};
    for (int k = 0; k < 3; k++) {
        int repeated = 0;
        for (int j = 0; j < pl->n; j++)
            repeated |= memcmp(pl->p[j], fallback[k], sizeof pl->p[j]) == 0;
        if (!repeated)
            memcpy(pl->p[pl->n++], fallback[k], sizeof pl->p[0]);
    }
    for (int k = 0; k < pl->n; k++)
        pl->cost[k] = quadric_eval(&q, s->center, pl->p[k]);
    /* Stable insertion sort of at most four. */
    for (int k = 1; k < pl->n; k++)
        for (int j = k; j > 0 && pl->cost[j] < pl->cost[j - 1]; j--) {
            double tp[3], tc = pl->cost[j];
            memcpy(tp, pl->p[j], sizeof tp);
            memcpy(pl->p[j], pl->p[j - 1], sizeof tp);
            memcpy(pl->p[j - 1], tp, sizeof tp);
            pl->cost[j] = pl->cost[j - 1];
            pl->cost[j - 1] = tc;
        }
}

/* ---- the queue: a binary min-heap on (cost, u, v, placement) ---- */

static int entry_less(const heap_entry_t *a, const heap_entry_t *b)
{
    if (a->cost != b->cost)
        return a->cost < b->cost;
    if (a->u != b->u)
        return a->u < b->u;
    if (a->v != b->v)
        return a->v < b->v;
    return a->placement < b->placement;
}

static void sift_down(heap_entry_t *h, size_t n, size_t i)
{
    const heap_entry_t e = h[i];
    for (;;) {
        size_t c = 2 * i + 1;
        if (c >= n)
            break;
        if (c + 1 < n && entry_less(&h[c + 1], &h[c]))
            c++;
        if (!entry_less(&h[c], &e))
            break;
        h[i] = h[c];
        i = c;
    }
    h[i] = e;
}

static int entry_current(const simplifier_t *s, const heap_entry_t *e)
{
    return s->vertex_alive[e->u] && s->vertex_alive[e->v] && s->stamp[e->u] == e->su &&
           s->stamp[e->v] == e->sv;
}

/* Drops the stale entries and re-heapifies. Current entries number at most
 * the live edges (each push follows a stamp change or replaces the popped
 * entry), so a queue of twice the input's edges always regains room. */
static void heap_compact(simplifier_t *s)
{
    size_t n = 0;
    for (size_t i = 0; i < s->heap_n; i++)
        if (entry_current(s, &s->heap[i]))
            s->heap[n++] = s->heap[i];
    s->heap_n = n;
    for (size_t i = n / 2; i-- > 0;)
        sift_down(s->heap, n, i);
}

static void heap_push(simplifier_t *s, const heap_entry_t *e)
{
    if (s->heap_n == s->heap_cap)
        heap_compact(s);
    if (s->heap_n == s->heap_cap)
        return; /* cannot happen (see heap_compact); never write past the cap */
    size_t i = s->heap_n++;
    while (i > 0) {
        const size_t p = (i - 1) / 2;
        if (!entry_less(e, &s->heap[p]))
            break;
        s->heap[i] = s->heap[p];
        i = p;
    }
    s->heap[i] = *e;
}

static heap_entry_t heap_pop(simplifier_t *s)
{
    const heap_entry_t top = s->heap[0];
    s->heap[0] = s->heap[--s->heap_n];
    if (s->heap_n > 0)
        sift_down(s->heap, s->heap_n, 0);
    return top;
}

/* Queues edge x-y with the cost of its cheapest placement. */
static void push_edge(simplifier_t *s, int32_t x, int32_t y)
{
    const int32_t u = x < y ? x : y, v = x < y ? y : x;
    placements_t pl;
    compute_placements(s, u, v, &pl);
    const heap_entry_t e = {
        .cost = pl.cost[0], .u = u, .v = v, .su = s->stamp[u], .sv = s->stamp[v], .placement = 0};
    heap_push(s, &e);
}

/* ---- one collapse ---- */

/* The topology of collapsing u-v: filled by check_link. */
typedef struct link {
    int32_t apex[2]; /* third vertices of the faces on u-v */
    int32_t napex;
    int32_t nfu, nfv; /* corners of u (v) in faces not on u-v: s->fu, s->fv */
} link_t;

/*
 * The link condition for u-v with the boundary coned to a virtual vertex
 * (joined to every boundary edge): the common neighbours of u and v must
 * be exactly the apexes of the faces on u-v (the cone vertex counting as a
 * neighbour of every boundary vertex and as the apex of a boundary edge), and no edge may lie in
 * both links (faces u-a-b and v-a-b both present, or u-a and v-a both boundary edges). This is what
 * keeps the result a 2-manifold of the same genus with the same boundary loops. Also enforces the
 * fan cap. Returns 1 when allowed.
 */
static int check_link(simplifier_t *s, int32_t u, int32_t v, link_t *lk)
{
    const uint32_t t = next_tick(s->mark, &s->tick, s->nv);
    lk->napex = lk->nfu = lk->nfv = 0;
    for (int32_t c = s->head[u]; c >= 0; c = s->corner_next[c]) {
        int32_t y, z;
        corner_others(s, c, &y, &z);
        if (y == v || z == v) {
            if (lk->napex == 2)
                return 0; /* unreachable on a manifold */
            lk->apex[lk->napex++] = y == v ? z : y;
        } else {
            if (lk->nfu == s->fan_cap)
                return 0;
            s->fu[lk->nfu++] = c;
        }
        s->mark[y] = s->mark[z] = t;
    }
    if (lk->napex == 0)
        return 0; /* not an edge any more */
    for (int32_t c = s->head[v]; c >= 0; c = s->corner_next[c]) {
        int32_t y, z;
        corner_others(s, c, &y, &z);
        if (y == u || z == u)
            continue;
        if (lk->nfv == s->fan_cap)
            return 0;
        s->fv[lk->nfv++] = c;
        const int32_t both[2] = {y, z};
        for (int i = 0; i < 2; i++)
            if (s->mark[both[i]] == t && both[i] != lk->apex[0] &&
                (lk->napex < 2 || both[i] != lk->apex[1]))
                return 0; /* a common neighbour off the edge: pinches the surface */
    }
    if (lk->nfu + lk->nfv > s->fan_cap)
        return 0;
    if (lk->napex == 2) {
        /* An interior edge between two boundary vertices would join two
         * boundary stretches into a pinch. */
        if (s->boundary[u] && s->boundary[v])
            return 0;
        /* Faces u-a-b and v-a-b: the apexes' edge is in both links (a
         * tetrahedron, or an apex of valence 3 that would be left with two
         * faces on the same three vertices). */
        const int32_t a = lk->apex[0], b = lk->apex[1];
        int in_u = 0, in_v = 0;
        for (int32_t i = 0; i < lk->nfu && !in_u; i++) {
            int32_t y, z;
            corner_others(s, s->fu[i], &y, &z);
            in_u = (y == a && z == b) || (y == b && z == a);
        }
        for (int32_t i = 0; i < lk->nfv && !in_v; i++) {
            int32_t y, z;
            corner_others(s, s->fv[i], &y, &z);
            in_v = (y == a && z == b) || (y == b && z == a);
        }
        if (in_u && in_v)
            return 0;
    } else {
        /* Boundary edge with apex a: if u-a and v-a are boundary edges too
         * the triangle is a whole component (closing it would leave an
         * edge); a used by another face of u (or v) makes u-a interior. */
        const int32_t a = lk->apex[0];
        int shared = 0;
        for (int32_t i = 0; i < lk->nfu && !shared; i++) {
            int32_t y, z;
            corner_others(s, s->fu[i], &y, &z);
            shared = y == a || z == a;
        }
        for (int32_t i = 0; i < lk->nfv && !shared; i++) {
            int32_t y, z;
            corner_others(s, s->fv[i], &y, &z);
            shared = y == a || z == a;
        }
        if (!shared)
            return 0;
    }
    return 1;
}

/* Quality 4*sqrt(3)*area / (sum of squared edges) from the doubled-area
 * normal n and the three squared edge lengths' sum. */
static double quality_of(const double *n, double sum_sq)
{
    return sum_sq > 0.0 ? 2.0 * sqrt(3.0) * sqrt(dot3(n, n)) / sum_sq : 0.0;
}

/*
 * Whether moving the vertex at each listed corner to w keeps each of those
 * faces non-degenerate, its normal within the allowed rotation (which also
 * rules out flips when the option's cosine is positive) and its quality
 * above the floor or no worse than before.
 */
static int geometry_ok(const simplifier_t *s, const int32_t *corners, int32_t n, const double *w)
{
    for (int32_t i = 0; i < n; i++) {
        int32_t y, z;
        corner_others(s, corners[i], &y, &z);
        const double *p0 = s->pos + 3 * (size_t)s->tri[corners[i]];
        const double *p1 = s->pos + 3 * (size_t)y, *p2 = s->pos + 3 * (size_t)z;
        double a[3], b[3], c[3], n0[3], n1[3];
        sub3(p1, p0, a);
        sub3(p2, p0, b);
        cross3(a, b, n0);
        sub3(p2, p1, c);
        const double q0 = quality_of(n0, dot3(a, a) + dot3(b, b) + dot3(c, c));
        sub3(p1, w, a);
        sub3(p2, w, b);
        cross3(a, b, n1);
        const double q1 = quality_of(n1, dot3(a, a) + dot3(b, b) + dot3(c, c));
        if (!(q1 > SIMPLIFY_DEGENERATE_QUALITY))
            return 0;
        if (dot3(n0, n1) < s->min_cos * sqrt(dot3(n0, n0) * dot3(n1, n1)))
            return 0;
        if (q1 < s->min_quality && q1 < q0)
            return 0;
    }
    return 1;
}

/* Removes the corners of dead faces from x's list. */
static void unlink_dead(simplifier_t *s, int32_t x)
{
    int32_t *slot = &s->head[x];
    while (*slot >= 0) {
        if (!s->face_alive[*slot / 3])
            *slot = s->corner_next[*slot];
        else
            slot = &s->corner_next[*slot];
    }
}

/*
 * Collapses v into u at w (the link checked by check_link, which left the
 * faces on u-v apexes in lk), then requeues every edge whose cost or
 * validity may have changed: those of u and of its new neighbours.
 */
static void collapse(simplifier_t *s, int32_t u, int32_t v, const double *w, const link_t *lk)
{
    for (int32_t c = s->head[u]; c >= 0; c = s->corner_next[c]) {
        int32_t y, z;
        corner_others(s, c, &y, &z);
        if (y == v || z == v) {
            s->face_alive[c / 3] = 0;
            s->alive_faces--;
        }
    }
    unlink_dead(s, u);
    for (int i = 0; i < lk->napex; i++) {
        unlink_dead(s, lk->apex[i]);
        s->fan[lk->apex[i]]--;
    }
    /* v's surviving corners move over to u. */
    for (int32_t c = s->head[v], next; c >= 0; c = next) {
        next = s->corner_next[c];
        if (!s->face_alive[c / 3])
            continue;
        s->tri[c] = u;
        s->corner_next[c] = s->head[u];
        s->head[u] = c;
    }
    s->head[v] = -1;
    s->fan[u] = lk->nfu + lk->nfv;
    s->fan[v] = 0;
    memcpy(s->pos + 3 * (size_t)u, w, 3 * sizeof *w);
    for (int i = 0; i < 10; i++)
        s->q[u].a[i] += s->q[v].a[i];
    s->boundary[u] |= s->boundary[v];
    s->vertex_alive[v] = 0;
    s->alive_vertices--;
    s->stats.collapses++;

    /* The ring: u and its neighbours, all restamped. */
    const uint32_t rt = next_tick(s->ring_mark, &s->ring_tick, s->nv);
    int32_t nring = 0;
    s->ring[nring++] = u;
    s->ring_mark[u] = rt;
    for (int32_t c = s->head[u]; c >= 0; c = s->corner_next[c]) {
        int32_t yz[2];
        corner_others(s, c, &yz[0], &yz[1]);
        for (int i = 0; i < 2; i++)
            if (s->ring_mark[yz[i]] != rt) {
                s->ring_mark[yz[i]] = rt;
                s->ring[nring++] = yz[i];
            }
    }
    for (int32_t i = 0; i < nring; i++)
        s->stamp[s->ring[i]]++;
    for (int32_t i = 0; i < nring; i++) {
        const int32_t x = s->ring[i];
        const uint32_t t = next_tick(s->mark, &s->tick, s->nv);
        for (int32_t c = s->head[x]; c >= 0; c = s->corner_next[c]) {
            int32_t yz[2];
            corner_others(s, c, &yz[0], &yz[1]);
            for (int j = 0; j < 2; j++) {
                const int32_t y = yz[j];
                if (s->mark[y] == t)
                    continue;
                s->mark[y] = t;
                /* An edge inside the ring is queued once, from its lower end. */
                if (s->ring_mark[y] == rt && y < x)
                    continue;
                push_edge(s, x, y);
            }
        }
    }
}

static bg_status check_input(const bg_mesh_t *m, const bg_simplify_options_t *o, bg_error_t *err)
{
    if (bg_mesh_kind_of(m) != BG_MESH_SURFACE)
        return bg_error_set(err, BG_ERR_INVALID,
                            "mesh simplification needs surface triangles, not %s",
                            bg_mesh_kind_name(bg_mesh_kind_of(m)));
    if (o->target_vertices < 4)
        return bg_error_set(err, BG_ERR_INVALID,
                            "mesh simplification: the target of %d vertices is below 4 (a "
                            "tetrahedron, the smallest closed surface)",
                            (int)o->target_vertices);
    if (!(o->max_normal_change >= -1.0 && o->max_normal_change <= 1.0))
        return bg_error_set(err, BG_ERR_INVALID,
                            "mesh simplification: max_normal_change %g is not a cosine in [-1, 1]",
                            o->max_normal_change);
    if (!(o->min_triangle_quality >= 0.0 && o->min_triangle_quality < 1.0))
        return bg_error_set(err, BG_ERR_INVALID,
                            "mesh simplification: min_triangle_quality %g is not in [0, 1)",
                            o->min_triangle_quality);
    if (m->ne > BG_SIMPLIFY_MAX_FACES)
        return bg_error_set(err, BG_ERR_LIMIT,
                            "mesh simplification: %d faces exceed the limit of %d", (int)m->ne,
                            BG_SIMPLIFY_MAX_FACES);
    if (m->ne == 0)
        return bg_error_set(err, BG_ERR_INVALID, "mesh simplification: the surface has no faces");
    for (int32_t v = 0; v < m->nv; v++)
        for (int c = 0; c < 3; c++)
            if (!isfinite(m->x[3 * (size_t)v + c]))
                return bg_error_set(err, BG_ERR_INVALID,
                                    "mesh simplification: vertex %d has a non-finite coordinate %c",
                                    (int)v + 1, "xyz"[c]);
    for (int32_t f = 0; f < m->ne; f++) {
        const int32_t *t = m->elements + 3 * (size_t)f;
        for (int i = 0; i < 3; i++) {
            if (t[i] < 0 || t[i] >= m->nv)
                return bg_error_set(err, BG_ERR_INVALID,
                                    "mesh simplification: face %d refers to vertex %d, outside "
                                    "1..%d",
                                    (int)f + 1, (int)t[i] + 1, (int)m->nv);
            for (int j = 0; j < i; j++)
                if (t[i] == t[j])
                    return bg_error_set(err, BG_ERR_INVALID,
                                        "mesh simplification: face %d repeats vertex %d",
                                        (int)f + 1, (int)t[i] + 1);
        }
        double a[3], b[3], c[3], n[3];
        sub3(m->x + 3 * (size_t)t[1], m->x + 3 * (size_t)t[0], a);
        sub3(m->x + 3 * (size_t)t[2], m->x + 3 * (size_t)t[0], b);
        sub3(m->x + 3 * (size_t)t[2], m->x + 3 * (size_t)t[1], c);
        cross3(a, b, n);
        if (!(quality_of(n, dot3(a, a) + dot3(b, b) + dot3(c, c)) > SIMPLIFY_DEGENERATE_QUALITY))
            return bg_error_set(err, BG_ERR_INVALID,
                                "mesh simplification: face %d (vertices %d %d %d) has zero area "
                                "for its size",
                                (int)f + 1, (int)t[0] + 1, (int)t[1] + 1, (int)t[2] + 1);
    }
    return BG_OK;
}

/* Allocates and fills the working copy (positions, corner lists). */
static bg_status init_simplifier(simplifier_t *s, const bg_mesh_t *m, bg_error_t *err)
{
    const size_t nv = (size_t)m->nv, nf = (size_t)m->ne;
    s->nv = m->nv;
    s->nf = m->ne;
    s->pos = malloc(3 * nv * sizeof *s->pos + 1);
    s->q = calloc(nv + 1, sizeof *s->q);
    s->tri = malloc(3 * nf * sizeof *s->tri);
    s->corner_next = malloc(3 * nf * sizeof *s->corner_next);
    s->head = malloc(nv * sizeof *s->head + 1);
    s->fan = calloc(nv + 1, sizeof *s->fan);
    s->stamp = calloc(nv + 1, sizeof *s->stamp);
    s->vertex_alive = calloc(nv + 1, 1);
    s->face_alive = malloc(nf);
    s->boundary = calloc(nv + 1, 1);
    s->mark = calloc(nv + 1, sizeof *s->mark);
    s->ring_mark = calloc(nv + 1, sizeof *s->ring_mark);
    if (!s->pos || !s->q || !s->tri || !s->corner_next || !s->head || !s->fan || !s->stamp ||
        !s->vertex_alive || !s->face_alive || !s->boundary || !s->mark || !s->ring_mark)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory simplifying a surface of %d vertices",
                            (int)m->nv);
    memcpy(s->pos, m->x, 3 * nv * sizeof *s->pos);
    memcpy(s->tri, m->elements, 3 * nf * sizeof *s->tri);
    memset(s->face_alive, 1, nf);
    for (size_t v = 0; v < nv; v++)
        s->head[v] = -1;
    /* Corners pushed in reverse so each list runs in increasing face order. */
    for (size_t c = 3 * nf; c-- > 0;) {
        s->corner_next[c] = s->head[s->tri[c]];
        s->head[s->tri[c]] = (int32_t)c;
    }
    double lo[3], hi[3];
    bg_mesh_bounds(m, lo, hi);
    for (int i = 0; i < 3; i++)
        s->center[i] = 0.5 * (lo[i] + hi[i]);
    s->alive_faces = m->ne;
    for (size_t v = 0; v < nv; v++)
        if (s->head[v] >= 0) {
            s->vertex_alive[v] = 1;
            s->alive_vertices++;
        }
    return BG_OK;
}

/* The surviving vertices (in input order) and faces as a new mesh. */
static bg_status build_output(const simplifier_t *s, const bg_mesh_t *in, bg_mesh_t **out,
                              bg_error_t *err)
{
    bg_mesh_t *m = NULL;
    bg_status st = bg_mesh_new(BG_MESH_SURFACE, s->alive_vertices, s->alive_faces, &m, err);
    if (st != BG_OK)
        return st;
    /* s->mark is free now: reuse it as the old-to-new vertex map. */
    int32_t n = 0;
    for (int32_t v = 0; v < s->nv; v++) {
        if (!s->vertex_alive[v])
            continue;
        memcpy(m->x + 3 * (size_t)n, s->pos + 3 * (size_t)v, 3 * sizeof *m->x);
        m->vertex_ref[n] = in->vertex_ref[v];
        s->mark[v] = (uint32_t)n++;
    }
    int32_t e = 0;
    for (int32_t f = 0; f < s->nf; f++) {
        if (!s->face_alive[f])
            continue;
        for (int k = 0; k < 3; k++)
            m->elements[3 * (size_t)e + k] = (int32_t)s->mark[s->tri[3 * (size_t)f + k]];
        m->element_ref[e++] = in->element_ref[f];
    }
    *out = m;
    return BG_OK;
}

/*
 * Queues every edge, then performs the cheapest allowed collapse until
 * `target` vertices remain or the queue runs dry (every remaining collapse
 * refused). Allocates nothing: the queue and the scratch are sized already.
 */
static void run_collapses(simplifier_t *s, int32_t target)
{
    if (s->alive_vertices <= target)
        return;
    for (int32_t x = 0; x < s->nv; x++) {
        const uint32_t t = next_tick(s->mark, &s->tick, s->nv);
        for (int32_t c = s->head[x]; c >= 0; c = s->corner_next[c]) {
            int32_t yz[2];
            corner_others(s, c, &yz[0], &yz[1]);
            for (int j = 0; j < 2; j++)
                if (yz[j] > x && s->mark[yz[j]] != t) {
                    s->mark[yz[j]] = t;
                    push_edge(s, x, yz[j]);
                }
        }
    }
    while (s->alive_vertices > target && s->heap_n > 0) {
        heap_entry_t e = heap_pop(s);
        if (!entry_current(s, &e))
            continue;
        link_t lk;
        if (!check_link(s, e.u, e.v, &lk)) {
            s->stats.refused_topology++;
            continue;
        }
        placements_t pl;
        compute_placements(s, e.u, e.v, &pl);
        if (e.placement >= pl.n)
            continue;
        const double *w = pl.p[e.placement];
        if (!geometry_ok(s, s->fu, lk.nfu, w) || !geometry_ok(s, s->fv, lk.nfv, w)) {
            s->stats.refused_geometry++;
            /* Try the next placement in its turn: it costs more. */
            if (e.placement + 1 < pl.n) {
                e.placement++;
                e.cost = pl.cost[e.placement];
                heap_push(s, &e);
            }
            continue;
        }
        if (pl.cost[e.placement] > s->stats.max_error)
            s->stats.max_error = pl.cost[e.placement];
        collapse(s, e.u, e.v, w, &lk);
    }
}

bg_simplify_options_t bg_simplify_defaults(int32_t target_vertices)
{
    const bg_simplify_options_t o = {
        .target_vertices = target_vertices,
        .max_normal_change = 0.5,
        .min_triangle_quality = 0.5,
    };
    return o;
}

bg_status bg_mesh_simplify(const bg_mesh_t *surface, const bg_simplify_options_t *options,
                           bg_mesh_t **out, bg_simplify_result_t *result, bg_error_t *err)
{
    *out = NULL;
    if (result)
        memset(result, 0, sizeof *result);
    bg_status st = check_input(surface, options, err);
    if (st != BG_OK)
        return st;
    simplifier_t s;
    memset(&s, 0, sizeof s);
    s.min_cos = options->max_normal_change;
    s.min_quality = options->min_triangle_quality;
    int32_t *successor = NULL;
    st = init_simplifier(&s, surface, err);
    if (st != BG_OK)
        goto out;
    successor = malloc((size_t)s.nv * sizeof *successor + 1);
    if (!successor) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory simplifying a surface");
        goto out;
    }
    int64_t edges = 0;
    st = check_manifold(&s, successor, &edges, err);
    if (st != BG_OK)
        goto out;
    s.tick = (uint32_t)s.nv + 1; /* check_manifold used ticks 1..nv */
    s.ring_tick = s.tick;
    init_quadrics(&s);
    s.fu = malloc((size_t)s.fan_cap * sizeof *s.fu);
    s.fv = malloc((size_t)s.fan_cap * sizeof *s.fv);
    s.ring = malloc(((size_t)s.fan_cap + 2) * sizeof *s.ring);
    s.heap_cap = 2 * (size_t)edges + 16;
    s.heap = malloc(s.heap_cap * sizeof *s.heap);
    if (!s.fu || !s.fv || !s.ring || !s.heap) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the queue of %lld edges",
                          (long long)edges);
        goto out;
    }
    const int32_t target = options->target_vertices;
    run_collapses(&s, target);
    st = build_output(&s, surface, out, err);
    if (st != BG_OK)
        goto out;
    s.stats.vertices = s.alive_vertices;
    s.stats.faces = s.alive_faces;
    s.stats.reached_target = s.alive_vertices <= target;
    if (result)
        *result = s.stats;
out:
    free(successor);
    free_simplifier(&s);
    return st;
}
