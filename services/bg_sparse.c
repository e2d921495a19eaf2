#include "bg_sparse.h"

#include <cholmod.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"
#include "bg_elastic.h"

struct bg_sparse {
    int32_t nfree;
    size_t nnz;
    int32_t *scatter; /* ne * T */
    size_t nscatter;  /* entries of scatter */
    int32_t *perm;    /* bg_sparse_reorder: stored unknown k is the caller's perm[k]; or NULL */
    int n;            /* bg_sparse_new: unknowns per vertex (0: bg_sparse_new_csc) */
    int m;            /* bg_sparse_new: unknowns per element (nodes × n) */
    bg_elastic_tet_blocks_t *blocks; /* bg_sparse_tet_blocks, or NULL */
    const int32_t *blocks_order;     /* bg_sparse_order_tet_blocks (borrowed), or NULL */
    cholmod_common common;
    cholmod_sparse *A;
    cholmod_factor *L;
    cholmod_dense *B, *X, *Y, *E;
    int analyzed;
    int prefer_solves;                    /* bg_sparse_prefer_solves */
    int keep_order;                       /* bg_sparse_keep_order */
    double factor_flops, factor_nonzeros; /* from the analysis */
    bg_sparse_timing_t timing;
    double *solve_work;     /* super_solve's scratch: n·nrhs + rows·nrhs doubles */
    size_t solve_work_size; /* its length; grows to the widest call */
};

static int cmp_int32(const void *a, const void *b)
{
    int32_t x = *(const int32_t *)a, y = *(const int32_t *)b;
    return (x > y) - (x < y);
}

/* Vertex → incident elements, CSR. */
static bg_status incidence(const bg_mesh_t *mesh, int32_t **start_out, int32_t **list_out)
{
    const int k = mesh->nodes_per_element;
    int32_t *start = calloc((size_t)mesh->nv + 1, sizeof *start);
    int32_t *list = malloc((size_t)mesh->ne * k * sizeof *list + 1);
    if (!start || !list) {
        free(start);
        free(list);
        return BG_ERR_NOMEM;
    }
    for (size_t i = 0; i < (size_t)mesh->ne * k; i++)
        start[mesh->elements[i] + 1]++;
    for (int32_t v = 0; v < mesh->nv; v++)
        start[v + 1] += start[v];
    int32_t *fill = malloc((size_t)mesh->nv * sizeof *fill + 1);
    if (!fill) {
        free(start);
        free(list);
        return BG_ERR_NOMEM;
    }
    memcpy(fill, start, (size_t)mesh->nv * sizeof *fill);
    for (int32_t e = 0; e < mesh->ne; e++)
        for (int i = 0; i < k; i++)
            list[fill[mesh->elements[(size_t)e * k + i]]++] = e;
    free(fill);
    *start_out = start;
    *list_out = list;
    return BG_OK;
}

/*
 * Lower-triangular pattern over free dofs: column f = free (v, c) holds
 * rows free (u, d) with u a neighbour of v (or v itself) and dof(u, d) ≥
 * dof(v, c). Because unknown numbers increase with dof numbers, iterating
 * neighbours in increasing order yields sorted rows.
 */
static bg_status build_pattern(bg_sparse_t *sys, const bg_mesh_t *mesh, int n,
                               const int32_t *free_index, bg_error_t *err)
{
    bg_status st = BG_OK;
    int32_t *start = NULL, *list = NULL, *nbr = NULL, *mark = NULL;
    const int k = mesh->nodes_per_element;
    if (incidence(mesh, &start, &list) != BG_OK) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory building the sparse pattern");
        goto out;
    }
    /* Pass 1 counts, pass 2 fills: neighbour lists are rebuilt per vertex
     * rather than stored, keeping peak memory to the final pattern. */
    int32_t max_deg = 0;
    for (int32_t v = 0; v < mesh->nv; v++)
        if (start[v + 1] - start[v] > max_deg)
            max_deg = start[v + 1] - start[v];
    nbr = malloc(((size_t)max_deg * k + 1) * sizeof *nbr);
    mark = malloc(((size_t)mesh->nv + 1) * sizeof *mark);
    if (!nbr || !mark) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory building the sparse pattern");
        goto out;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        mark[v] = -1;
    for (int pass = 0; pass < 2; pass++) {
        int *Ap = sys->A ? (int *)sys->A->p : NULL, *Ai = sys->A ? (int *)sys->A->i : NULL;
        size_t count = 0;
        for (int32_t v = 0; v < mesh->nv; v++) {
            int32_t deg = 0;
            for (int32_t t = start[v]; t < start[v + 1]; t++) {
                const int32_t *el = mesh->elements + (size_t)list[t] * k;
                for (int i = 0; i < k; i++)
                    if (el[i] >= v && mark[el[i]] != v) {
                        mark[el[i]] = v;
                        nbr[deg++] = el[i];
                    }
            }
            qsort(nbr, (size_t)deg, sizeof *nbr, cmp_int32);
            for (int c = 0; c < n; c++) {
                const int32_t col = free_index[(size_t)v * n + c];
                if (col < 0)
                    continue;
                if (pass == 1)
                    Ap[col] = (int)count;
                for (int32_t t = 0; t < deg; t++)
                    for (int d = 0; d < n; d++) {
                        const int32_t row = free_index[(size_t)nbr[t] * n + d];
                        if (row < col)
                            continue;
                        if (pass == 1)
                            Ai[count] = row;
                        count++;
                    }
            }
        }
        if (pass == 0) {
            if (count > (size_t)INT32_MAX) {
                st = bg_error_set(err, BG_ERR_LIMIT, "the sparse system has %zu nonzeros, over "
                                  "the 2^31 limit", count);
                goto out;
            }
            sys->nnz = count;
            sys->A = cholmod_allocate_sparse((size_t)sys->nfree, (size_t)sys->nfree, count, 1, 1,
                                             -1, CHOLMOD_REAL, &sys->common);
            if (!sys->A) {
                st = bg_error_set(err, BG_ERR_NOMEM, "out of memory allocating a %d x %d sparse "
                                  "matrix with %zu nonzeros", (int)sys->nfree, (int)sys->nfree,
                                  count);
                goto out;
            }
            for (int32_t v = 0; v < mesh->nv; v++)
                mark[v] = -1;
        } else {
            Ap[sys->nfree] = (int)count;
        }
    }
out:
    free(start);
    free(list);
    free(nbr);
    free(mark);
    return st;
}

static int32_t find_row(const int *Ap, const int *Ai, int32_t col, int32_t row)
{
    int lo = Ap[col], hi = Ap[col + 1] - 1;
    while (lo <= hi) {
        int mid = lo + (hi - lo) / 2;
        if (Ai[mid] == row)
            return mid;
        if (Ai[mid] < row)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

bg_status bg_sparse_new(const bg_mesh_t *mesh, int n, const int32_t *free_index, int32_t nfree,
                        bg_sparse_t **out, bg_error_t *err)
{
    *out = NULL;
    bg_sparse_t *sys = calloc(1, sizeof *sys);
    if (!sys)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating a sparse system");
    cholmod_start(&sys->common);
    sys->common.print = 0; /* failures are reported through our messages */
    sys->nfree = nfree;
    bg_status st = BG_OK;
    if (nfree <= 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "every coordinate is constrained: nothing to solve");
        goto fail;
    }
    st = build_pattern(sys, mesh, n, free_index, err);
    if (st != BG_OK)
        goto fail;
    sys->n = n;
    sys->m = mesh->nodes_per_element * n;
    const int k = mesh->nodes_per_element, m = k * n, T = BG_ELASTIC_TRI_SIZE(m);
    sys->nscatter = (size_t)mesh->ne * T;
    sys->scatter = malloc(sys->nscatter * sizeof *sys->scatter + 1);
    if (!sys->scatter) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the assembly map");
        goto fail;
    }
    const int *Ap = sys->A->p, *Ai = sys->A->i;
    for (int32_t e = 0; e < mesh->ne; e++) {
        const int32_t *el = mesh->elements + (size_t)e * k;
        int32_t *sc = sys->scatter + (size_t)e * T;
        for (int a = 0; a < m; a++)
            for (int b = a; b < m; b++) {
                const int32_t fa = free_index[(size_t)el[a / n] * n + a % n];
                const int32_t fb = free_index[(size_t)el[b / n] * n + b % n];
                int32_t pos = -1;
                if (fa >= 0 && fb >= 0)
                    pos = fa > fb ? find_row(Ap, Ai, fb, fa) : find_row(Ap, Ai, fa, fb);
                sc[BG_ELASTIC_TRI_INDEX(m, a, b)] = pos;
            }
    }
    sys->B = cholmod_zeros((size_t)nfree, 1, CHOLMOD_REAL, &sys->common);
    if (!sys->B) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the right-hand side");
        goto fail;
    }
    *out = sys;
    return BG_OK;
fail:
    bg_sparse_destroy(&sys);
    return st;
}

bg_status bg_sparse_new_csc(int32_t n, const int32_t *colptr, const int32_t *rowidx,
                            bg_sparse_t **out, bg_error_t *err)
{
    *out = NULL;
    if (n <= 0 || colptr[0] != 0 || colptr[n] <= 0)
        return bg_error_set(err, BG_ERR_INVALID, "sparse pattern: %d columns, colptr[0] = %d, "
                            "colptr[n] = %d", (int)n, n > 0 ? (int)colptr[0] : 0,
                            n > 0 ? (int)colptr[n] : 0);
    for (int32_t col = 0; col < n; col++) {
        if (colptr[col + 1] <= colptr[col] || rowidx[colptr[col]] != col)
            return bg_error_set(err, BG_ERR_INVALID, "sparse pattern: column %d does not start "
                                "at its diagonal", (int)col);
        for (int32_t p = colptr[col] + 1; p < colptr[col + 1]; p++)
            if (rowidx[p] <= rowidx[p - 1] || rowidx[p] >= n)
                return bg_error_set(err, BG_ERR_INVALID, "sparse pattern: column %d, entry %d: "
                                    "row %d out of order or range", (int)col, (int)p,
                                    (int)rowidx[p]);
    }
    bg_sparse_t *sys = calloc(1, sizeof *sys);
    if (!sys)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating a sparse system");
    cholmod_start(&sys->common);
    sys->common.print = 0;
    sys->nfree = n;
    sys->nnz = (size_t)colptr[n];
    bg_status st = BG_OK;
    sys->A = cholmod_allocate_sparse((size_t)n, (size_t)n, sys->nnz, 1, 1, -1, CHOLMOD_REAL,
                                     &sys->common);
    sys->B = cholmod_zeros((size_t)n, 1, CHOLMOD_REAL, &sys->common);
    if (!sys->A || !sys->B) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory allocating a %d x %d sparse matrix "
                          "with %zu nonzeros", (int)n, (int)n, sys->nnz);
        bg_sparse_destroy(&sys);
        return st;
    }
    int *Ap = sys->A->p, *Ai = sys->A->i;
    for (int32_t col = 0; col <= n; col++)
        Ap[col] = colptr[col];
    for (size_t p = 0; p < sys->nnz; p++)
        Ai[p] = rowidx[p];
    memset(sys->A->x, 0, sys->nnz * sizeof(double));
    *out = sys;
    return BG_OK;
}

void bg_sparse_destroy(bg_sparse_t **psys)
{
    if (!psys || !*psys)
        return;
    bg_sparse_t *sys = *psys;
    cholmod_free_sparse(&sys->A, &sys->common);
    cholmod_free_factor(&sys->L, &sys->common);
    cholmod_free_dense(&sys->B, &sys->common);
    cholmod_free_dense(&sys->X, &sys->common);
    cholmod_free_dense(&sys->Y, &sys->common);
    cholmod_free_dense(&sys->E, &sys->common);
    cholmod_finish(&sys->common);
    free(sys->scatter);
    free(sys->perm);
    free(sys->blocks);
    free(sys->solve_work);
    free(sys);
    *psys = NULL;
}

int32_t bg_sparse_size(const bg_sparse_t *sys)
{
    return sys->nfree;
}

size_t bg_sparse_nonzeros(const bg_sparse_t *sys)
{
    return sys->nnz;
}

/* CHOLMOD's int indices are the int32_t of the public interface. */
_Static_assert(sizeof(int) == sizeof(int32_t), "CHOLMOD int indices must be 32-bit");

const int32_t *bg_sparse_colptr(const bg_sparse_t *sys)
{
    return (const int32_t *)sys->A->p;
}

const int32_t *bg_sparse_rowidx(const bg_sparse_t *sys)
{
    return (const int32_t *)sys->A->i;
}

const int32_t *bg_sparse_permutation(const bg_sparse_t *sys)
{
    return sys->perm;
}

const bg_elastic_tet_blocks_t *bg_sparse_tet_blocks(const bg_sparse_t *sys)
{
    return sys->blocks;
}

bg_status bg_sparse_order_tet_blocks(bg_sparse_t *sys, const int32_t *order, bg_error_t *err)
{
    if (!sys->blocks || sys->blocks_order == order)
        return BG_OK;
    if (sys->blocks_order)
        return bg_error_set(err, BG_ERR_INVALID, "the vertex-block map is already in another "
                            "element order");
    const size_t ne = sys->nscatter / BG_ELASTIC_TRI_SIZE(12);
    bg_elastic_tet_blocks_t *by = malloc((ne + 1) * sizeof *by);
    if (!by)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory ordering the vertex-block map");
    for (size_t p = 0; p < ne; p++)
        by[p] = sys->blocks[order[p]];
    free(sys->blocks);
    sys->blocks = by;
    sys->blocks_order = order;
    return BG_OK;
}

const int32_t *bg_sparse_tet_blocks_order(const bg_sparse_t *sys)
{
    return sys->blocks_order;
}

const int32_t *bg_sparse_scatter(const bg_sparse_t *sys)
{
    return sys->scatter;
}

double *bg_sparse_values(bg_sparse_t *sys)
{
    return sys->A->x;
}

void bg_sparse_zero(bg_sparse_t *sys)
{
    memset(sys->A->x, 0, sys->nnz * sizeof(double));
}

void bg_sparse_prefer_solves(bg_sparse_t *sys)
{
    sys->prefer_solves = 1;
}

int bg_sparse_prefers_solves(const bg_sparse_t *sys)
{
    return sys->prefer_solves;
}

int bg_sparse_supernodal(const bg_sparse_t *sys)
{
    return sys->L ? sys->L->is_super != 0 : -1;
}

void bg_sparse_add_diagonal(bg_sparse_t *sys, const double *d)
{
    /* Rows are sorted and the lower triangle starts at the diagonal. */
    const int *Ap = sys->A->p;
    double *Ax = sys->A->x;
    const int32_t *perm = sys->perm;
    for (int32_t col = 0; col < sys->nfree; col++)
        Ax[Ap[col]] += d[perm ? perm[col] : col];
}

/* CHOLMOD's symbolic analysis of the stored pattern (its fill-reducing
 * ordering and supernodes) into sys->L, with the cost model's counts. */
static bg_status analyze(bg_sparse_t *sys, bg_error_t *err)
{
    cholmod_common *c = &sys->common;
    const double t0 = bg_clock_now();
    const int nmethods = c->nmethods, ordering = c->method[0].ordering, post = c->postorder;
    if (sys->keep_order) { /* bg_sparse_keep_order: bg_sparse_reorder's second analysis */
        c->nmethods = 1;
        c->method[0].ordering = CHOLMOD_NATURAL;
        c->postorder = 0;
    }
    sys->L = cholmod_analyze(sys->A, c);
    c->nmethods = nmethods;
    c->method[0].ordering = ordering;
    c->postorder = post;
    sys->timing.analyze_seconds += bg_clock_now() - t0;
    if (!sys->L)
        return bg_error_set(err, c->status == CHOLMOD_OUT_OF_MEMORY ? BG_ERR_NOMEM
                                                                    : BG_ERR_NUMERIC,
                            "CHOLMOD analysis failed (status %d)", c->status);
    if (sys->keep_order && sys->L->ordering != CHOLMOD_NATURAL) {
        cholmod_free_factor(&sys->L, c);
        return bg_error_set(err, BG_ERR_NUMERIC, "CHOLMOD did not keep the given order");
    }
    sys->analyzed = 1;
    sys->factor_flops = c->fl;
    sys->factor_nonzeros = c->lnz;
    return BG_OK;
}

void bg_sparse_keep_order(bg_sparse_t *sys)
{
    if (!sys->analyzed)
        sys->keep_order = 1;
}

/* Entry (row vertex's component d, column vertex's component c) of a
 * vertex block whose entry (0, 0) is at pos (bg_elastic_tet_blocks_t). */
static int32_t block_entry(int32_t pos, int32_t stride, int d, int c)
{
    return pos + d + c * stride - c * (c - 1) / 2;
}

/*
 * The vertex-block map (bg_elastic_tet_blocks_t) of a reordered
 * tetrahedral system, read off its entry scatter map and checked against
 * every one of its 78 entries per element: an element for which the
 * blocks do not give the scatter map's positions (a vertex whose three
 * unknowns CHOLMOD's order does not keep adjacent in component order)
 * is marked to take its row of the entry map. BG_ERR_NOMEM only for
 * memory.
 */
static bg_status build_tet_blocks(bg_sparse_t *sys)
{
    enum { M = 12, T = BG_ELASTIC_TRI_SIZE(12) };
    if (sys->n != 3 || sys->m != M)
        return BG_OK;
    const size_t ne = sys->nscatter / T;
    const int *Ai = sys->A->i;
    bg_elastic_tet_blocks_t *blocks = calloc(ne + 1, sizeof *blocks);
    if (!blocks)
        return BG_ERR_NOMEM;
    for (size_t e = 0; e < ne; e++) {
        const int32_t *sc = sys->scatter + e * T;
        bg_elastic_tet_blocks_t *bl = blocks + e;
        int32_t first[4]; /* each vertex's stored first unknown, or −1 */
        for (int i = 0; i < 4; i++) {
            const int32_t d = sc[BG_ELASTIC_TRI_INDEX(M, 3 * i, 3 * i)];
            first[i] = d >= 0 ? Ai[d] : -1;
            /* row 1 of the diagonal block: column 1 is stride past column 0 */
            bl->stride[i] = d >= 0 ? sc[BG_ELASTIC_TRI_INDEX(M, 3 * i + 1, 3 * i + 1)] -
                                         sc[BG_ELASTIC_TRI_INDEX(M, 3 * i, 3 * i + 1)]
                                   : 0;
        }
        for (int i = 0; i < 4; i++)
            for (int j = i; j < 4; j++) {
                const int k = BG_ELASTIC_BLOCK_INDEX(i, j);
                const int free_ = first[i] >= 0 && first[j] >= 0;
                bl->pos[k] = free_ ? sc[BG_ELASTIC_TRI_INDEX(M, 3 * i, 3 * j)] : -1;
                if (free_ && first[j] < first[i])
                    bl->transposed |= 1u << k;
            }
        /* every entry of K_e where the scatter map puts it */
        for (int a = 0; a < M; a++)
            for (int b = a; b < M; b++) {
                const int i = a / 3, j = b / 3, k = BG_ELASTIC_BLOCK_INDEX(i, j);
                int32_t at = -1;
                if (bl->pos[k] >= 0) {
                    const int t = (bl->transposed >> k) & 1;
                    /* column vertex w, row vertex r: K_e (a, b) is (r's d, w's c) */
                    const int c = t ? b % 3 : a % 3, d = t ? a % 3 : b % 3;
                    at = block_entry(bl->pos[k], bl->stride[t ? j : i], d, c);
                }
                if (at != sc[BG_ELASTIC_TRI_INDEX(M, a, b)])
                    bl->entries = 1;
            }
    }
    sys->blocks = blocks;
    return BG_OK;
}

bg_status bg_sparse_reorder(bg_sparse_t *sys, bg_error_t *err)
{
    if (sys->perm || sys->analyzed)
        return BG_OK;
    bg_status st = analyze(sys, err);
    if (st != BG_OK)
        return st;
    const double t0 = bg_clock_now();
    cholmod_common *c = &sys->common;
    const int32_t n = sys->nfree;
    const size_t nnz = sys->nnz;
    const int *Ap = sys->A->p, *Ai = sys->A->i, *Perm = sys->L->Perm;
    int32_t *perm = malloc((size_t)n * sizeof *perm + 1);
    int32_t *inv = malloc((size_t)n * sizeof *inv + 1);
    int32_t *count = calloc((size_t)n + 1, sizeof *count);
    int32_t *byrow = malloc(nnz * sizeof *byrow + 1);  /* entries of A bucketed by new row */
    int32_t *where = malloc(nnz * sizeof *where + 1);  /* entry of A → entry of P A Pᵀ */
    cholmod_sparse *B = cholmod_allocate_sparse((size_t)n, (size_t)n, nnz, 1, 1, -1,
                                                CHOLMOD_REAL, c);
    if (!perm || !inv || !count || !byrow || !where || !B) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory reordering a %d x %d sparse matrix",
                          (int)n, (int)n);
        goto out;
    }
    for (int32_t k = 0; k < n; k++)
        perm[k] = Perm[k];
    for (int32_t k = 0; k < n; k++)
        inv[perm[k]] = k;
    /* Entry (i, j), i ≥ j, of A lands at (r, s) = (max, min) of (inv i,
     * inv j) in the lower triangle of P A Pᵀ. Two stable counting sorts,
     * by r and then by s, leave each new column's rows increasing. */
    int *Bp = B->p, *Bi = B->i;
    for (int32_t j = 0; j < n; j++)
        for (int p = Ap[j]; p < Ap[j + 1]; p++) {
            const int32_t a = inv[Ai[p]], b = inv[j];
            count[(a > b ? a : b) + 1]++;
            where[p] = j;
        }
    for (int32_t k = 0; k < n; k++)
        count[k + 1] += count[k];
    for (int32_t j = 0; j < n; j++)
        for (int p = Ap[j]; p < Ap[j + 1]; p++) {
            const int32_t a = inv[Ai[p]], b = inv[j];
            byrow[count[a > b ? a : b]++] = p;
        }
    memset(count, 0, ((size_t)n + 1) * sizeof *count);
    for (int32_t j = 0; j < n; j++)
        for (int p = Ap[j]; p < Ap[j + 1]; p++) {
            const int32_t a = inv[Ai[p]], b = inv[j];
            count[(a < b ? a : b) + 1]++;
        }
    for (int32_t k = 0; k < n; k++)
        count[k + 1] += count[k];
    for (int32_t k = 0; k <= n; k++)
        Bp[k] = count[k];
    /* byrow holds the A entries by increasing new row; where[] still
     * holds each entry's column in A (filled before the first sort). */
    for (size_t t = 0; t < nnz; t++) {
        const int32_t p = byrow[t];
        const int32_t a = inv[Ai[p]], b = inv[where[p]];
        const int32_t r = a > b ? a : b, s = a < b ? a : b;
        const int32_t q = count[s]++;
        Bi[q] = r;
        where[p] = q;
    }
    for (size_t t = 0; t < sys->nscatter; t++)
        if (sys->scatter[t] >= 0)
            sys->scatter[t] = where[sys->scatter[t]];
    memset(B->x, 0, nnz * sizeof(double));
    cholmod_free_sparse(&sys->A, c);
    cholmod_free_factor(&sys->L, c);
    sys->A = B;
    B = NULL;
    sys->perm = perm;
    perm = NULL;
    sys->timing.analyze_seconds += bg_clock_now() - t0;
    /* P A Pᵀ is already in its fill-reducing, postordered order: analysed
     * in its natural order it has the same supernodes, and CHOLMOD then
     * factors it as stored, without permuting it. */
    const int nmethods = c->nmethods, ordering = c->method[0].ordering, post = c->postorder;
    c->nmethods = 1;
    c->method[0].ordering = CHOLMOD_NATURAL;
    c->postorder = 0;
    sys->analyzed = 0;
    st = analyze(sys, err);
    c->nmethods = nmethods;
    c->method[0].ordering = ordering;
    c->postorder = post;
    if (st == BG_OK && sys->L->ordering != CHOLMOD_NATURAL)
        st = bg_error_set(err, BG_ERR_NUMERIC, "CHOLMOD did not keep the given order");
    if (st == BG_OK && build_tet_blocks(sys) != BG_OK)
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the vertex-block map");
out:
    cholmod_free_sparse(&B, c);
    free(perm);
    free(inv);
    free(count);
    free(byrow);
    free(where);
    return st;
}

bg_status bg_sparse_factorize(bg_sparse_t *sys, double shift, bg_error_t *err)
{
    cholmod_common *c = &sys->common;
    if (!sys->analyzed) {
        bg_status st = analyze(sys, err);
        if (st != BG_OK)
            return st;
    }
    const double t0 = bg_clock_now();
    double beta[2] = {shift, 0.0};
    int ok = cholmod_factorize_p(sys->A, beta, NULL, 0, sys->L, c);
    sys->timing.factor_seconds += bg_clock_now() - t0;
    sys->timing.factorizations++;
    if (!ok || c->status == CHOLMOD_OUT_OF_MEMORY)
        return bg_error_set(err, BG_ERR_NOMEM, "CHOLMOD factorization failed (status %d)",
                            c->status);
    if (c->status == CHOLMOD_NOT_POSDEF || sys->L->minor < sys->L->n)
        return bg_error_set(err, BG_ERR_NUMERIC,
                            "the matrix is not positive definite (CHOLMOD stopped at column %zu "
                            "of %zu)",
                            (size_t)sys->L->minor, (size_t)sys->L->n);
    return BG_OK;
}

/*
 * Triangular solves through a supernodal factor of a prefer-solves system
 * (super_solve below). The kernels work on four rows or four columns at a
 * time in GCC/Clang vector extensions: a fixed order of operations, so every
 * clone (and a machine without AVX) gives the same bits, with no reliance on
 * the vectoriser reassociating a sum. Macros, not functions, move a v4d: a
 * function passing one by value would change the ABI between the clones.
 */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) &&                             \
    !defined(__SANITIZE_ADDRESS__)
#define SOLVE_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define SOLVE_CLONES
#endif

typedef double v4d __attribute__((vector_size(32)));
#define LOAD4(dst, p) memcpy(&(dst), (p), sizeof(v4d))
#define STORE4(p, src) memcpy((p), &(src), sizeof(v4d))
#define HSUM4(s) (((s)[0] + (s)[2]) + ((s)[1] + (s)[3]))

/* The forward pass: v[i] −= Σₖ cₖ[i]·aₖ over rows [lo, hi), four columns
 * c0..c3 of a supernode applied to one right-hand side. */
static inline void update4(const double *restrict c0, const double *restrict c1,
                           const double *restrict c2, const double *restrict c3, const double a[4],
                           int lo, int hi, double *restrict v)
{
    int i = lo;
    for (; i + 4 <= hi; i += 4) {
        v4d l0, l1, l2, l3, w;
        LOAD4(l0, c0 + i), LOAD4(l1, c1 + i), LOAD4(l2, c2 + i), LOAD4(l3, c3 + i);
        LOAD4(w, v + i);
        w -= (l0 * a[0] + l1 * a[1]) + (l2 * a[2] + l3 * a[3]);
        STORE4(v + i, w);
    }
    for (; i < hi; i++)
        v[i] -= (c0[i] * a[0] + c1[i] * a[1]) + (c2[i] * a[2] + c3[i] * a[3]);
}

/* update4 for three right-hand sides (a local/global step's coordinates):
 * each entry of the four columns is loaded once for all three. */
static inline void update4x3(const double *restrict c0, const double *restrict c1,
                             const double *restrict c2, const double *restrict c3,
                             const double a[3][4], int lo, int hi, double *restrict v0,
                             double *restrict v1, double *restrict v2)
{
    int i = lo;
    for (; i + 4 <= hi; i += 4) {
        v4d l0, l1, l2, l3, w0, w1, w2;
        LOAD4(l0, c0 + i), LOAD4(l1, c1 + i), LOAD4(l2, c2 + i), LOAD4(l3, c3 + i);
        LOAD4(w0, v0 + i), LOAD4(w1, v1 + i), LOAD4(w2, v2 + i);
        w0 -= (l0 * a[0][0] + l1 * a[0][1]) + (l2 * a[0][2] + l3 * a[0][3]);
        w1 -= (l0 * a[1][0] + l1 * a[1][1]) + (l2 * a[1][2] + l3 * a[1][3]);
        w2 -= (l0 * a[2][0] + l1 * a[2][1]) + (l2 * a[2][2] + l3 * a[2][3]);
        STORE4(v0 + i, w0), STORE4(v1 + i, w1), STORE4(v2 + i, w2);
    }
    for (; i < hi; i++) {
        const double l0 = c0[i], l1 = c1[i], l2 = c2[i], l3 = c3[i];
        v0[i] -= (l0 * a[0][0] + l1 * a[0][1]) + (l2 * a[0][2] + l3 * a[0][3]);
        v1[i] -= (l0 * a[1][0] + l1 * a[1][1]) + (l2 * a[1][2] + l3 * a[1][3]);
        v2[i] -= (l0 * a[2][0] + l1 * a[2][1]) + (l2 * a[2][2] + l3 * a[2][3]);
    }
}

/* The backward pass: out[k] = Σᵢ cₖ[i]·v[i] over rows [lo, hi) for four
 * columns, each sum in four interleaved partial sums. */
static inline void dot4(const double *restrict c0, const double *restrict c1,
                        const double *restrict c2, const double *restrict c3,
                        const double *restrict v, int lo, int hi, double out[4])
{
    v4d s0 = {0}, s1 = {0}, s2 = {0}, s3 = {0};
    int i = lo;
    for (; i + 4 <= hi; i += 4) {
        v4d l0, l1, l2, l3, w;
        LOAD4(l0, c0 + i), LOAD4(l1, c1 + i), LOAD4(l2, c2 + i), LOAD4(l3, c3 + i);
        LOAD4(w, v + i);
        s0 += l0 * w, s1 += l1 * w, s2 += l2 * w, s3 += l3 * w;
    }
    out[0] = HSUM4(s0), out[1] = HSUM4(s1), out[2] = HSUM4(s2), out[3] = HSUM4(s3);
    for (; i < hi; i++) {
        out[0] += c0[i] * v[i], out[1] += c1[i] * v[i];
        out[2] += c2[i] * v[i], out[3] += c3[i] * v[i];
    }
}

/* dot4 for three right-hand sides, sharing the columns' loads. */
static inline void dot4x3(const double *restrict c0, const double *restrict c1,
                          const double *restrict c2, const double *restrict c3,
                          const double *restrict v0, const double *restrict v1,
                          const double *restrict v2, int lo, int hi, double out[3][4])
{
    v4d s00 = {0}, s01 = {0}, s02 = {0}, s03 = {0}, s10 = {0}, s11 = {0}, s12 = {0}, s13 = {0},
        s20 = {0}, s21 = {0}, s22 = {0}, s23 = {0};
    int i = lo;
    for (; i + 4 <= hi; i += 4) {
        v4d l0, l1, l2, l3, w0, w1, w2;
        LOAD4(l0, c0 + i), LOAD4(l1, c1 + i), LOAD4(l2, c2 + i), LOAD4(l3, c3 + i);
        LOAD4(w0, v0 + i), LOAD4(w1, v1 + i), LOAD4(w2, v2 + i);
        s00 += l0 * w0, s01 += l1 * w0, s02 += l2 * w0, s03 += l3 * w0;
        s10 += l0 * w1, s11 += l1 * w1, s12 += l2 * w1, s13 += l3 * w1;
        s20 += l0 * w2, s21 += l1 * w2, s22 += l2 * w2, s23 += l3 * w2;
    }
    out[0][0] = HSUM4(s00), out[0][1] = HSUM4(s01), out[0][2] = HSUM4(s02);
    out[0][3] = HSUM4(s03), out[1][0] = HSUM4(s10), out[1][1] = HSUM4(s11);
    out[1][2] = HSUM4(s12), out[1][3] = HSUM4(s13), out[2][0] = HSUM4(s20);
    out[2][1] = HSUM4(s21), out[2][2] = HSUM4(s22), out[2][3] = HSUM4(s23);
    for (; i < hi; i++) {
        const double l0 = c0[i], l1 = c1[i], l2 = c2[i], l3 = c3[i];
        const double w[3] = {v0[i], v1[i], v2[i]};
        for (int c = 0; c < 3; c++) {
            out[c][0] += l0 * w[c], out[c][1] += l1 * w[c];
            out[c][2] += l2 * w[c], out[c][3] += l3 * w[c];
        }
    }
}

static inline double dot1(const double *restrict c0, const double *restrict v, int lo, int hi)
{
    v4d s0 = {0};
    int i = lo;
    for (; i + 4 <= hi; i += 4) {
        v4d l0, w;
        LOAD4(l0, c0 + i), LOAD4(w, v + i);
        s0 += l0 * w;
    }
    double s = HSUM4(s0);
    for (; i < hi; i++)
        s += c0[i] * v[i];
    return s;
}

/* Prefetch entries [from, from + count) of the factor's values x (size
 * entries; the part outside is skipped): the next block of a supernode
 * while this one is used. Supernodes of tens of rows and columns (two
 * thirds of the 32³ box's factor entries) are read as short column
 * streams the hardware prefetcher does not ramp up on, and the factor is
 * one array in supernode order, so the next block is the next memory (the
 * previous one in the backward pass). Taller supernodes' columns stream
 * well on their own, and prefetching them too made their solves slower:
 * only supernodes under SOLVE_PREFETCH_ROWS rows prefetch (the box's
 * solve 22.7 → 21.4 ms, alternated runs). */
#define SOLVE_PREFETCH_ROWS 400
static inline void prefetch_range(const double *x, ptrdiff_t size, ptrdiff_t from, ptrdiff_t count)
{
    const ptrdiff_t a = from < 0 ? 0 : from, b = from + count > size ? size : from + count;
    for (ptrdiff_t i = a; i < b; i += 8)
        __builtin_prefetch(x + i, 0, 3);
}

/* The tallest supernode's row count. */
static size_t super_rows(const cholmod_factor *L)
{
    const int *pi = L->pi;
    size_t rows = 0;
    for (size_t s = 0; s < L->nsuper; s++)
        if ((size_t)(pi[s + 1] - pi[s]) > rows)
            rows = (size_t)(pi[s + 1] - pi[s]);
    return rows;
}

/*
 * x = A⁻¹ rhs through a supernodal LLᵀ factor, nrhs columns (column-major,
 * the caller's numbering; perm as in bg_sparse_t): CHOLMOD's solve without
 * its per-supernode BLAS calls. With a few right-hand sides those calls do
 * matrix–vector work behind a matrix–matrix interface (OpenBLAS packs every
 * diagonal block before its triangular solve: 10 % of a local/global run on
 * the 32³ box). Here a supernode's rows are gathered into one dense vector
 * per right-hand side (v, rows long, rows the tallest supernode) and
 * scattered back once, and its columns are applied four at a time, each
 * entry loaded once for every right-hand side. The factor is read once per
 * pass; the rest stays in cache. work: (n + rows)·nrhs doubles; x may be
 * rhs (it is read whole before x is written).
 *
 * A column's arithmetic does not depend on how many are solved with it
 * (the three-column kernels do each column's operations in the one-column
 * order), so local/global's coordinates solve to the same bits one at a
 * time or together.
 */
SOLVE_CLONES
static void super_solve(const cholmod_factor *L, const int32_t *perm, int nrhs, size_t rows,
                        const double *rhs, double *x, double *restrict work)
{
    const int *super = L->super, *pi = L->pi, *px = L->px, *Ls = L->s, *Perm = L->Perm;
    const double *Lx = L->x;
    const ptrdiff_t xsize = (ptrdiff_t)L->xsize;
    const size_t n = L->n;
    const int nsuper = (int)L->nsuper;
    double *restrict y = work, *restrict v = work + n * (size_t)nrhs;
    /* y = P b: row k of the factor's system is the caller's unknown
     * perm[Perm[k]] (either permutation may be the identity) */
    for (int c = 0; c < nrhs; c++)
        for (size_t k = 0; k < n; k++) {
            const size_t pk = Perm ? (size_t)Perm[k] : k;
            y[c * n + k] = rhs[c * n + (perm ? (size_t)perm[pk] : pk)];
        }
    /* L z = y, supernodes in order */
    for (int s = 0; s < nsuper; s++) {
        const int k1 = super[s], ncol = super[s + 1] - k1, nrow = pi[s + 1] - pi[s];
        const int *ri = Ls + pi[s];
        const double *Lsn = Lx + px[s];
        for (int c = 0; c < nrhs; c++) {
            double *vc = v + (size_t)c * rows, *yc = y + (size_t)c * n;
            memcpy(vc, yc + k1, (size_t)ncol * sizeof *vc);
            memset(vc + ncol, 0, (size_t)(nrow - ncol) * sizeof *vc);
        }
        int j = 0;
        for (; j + 4 <= ncol; j += 4) {
            const double *c0 = Lsn + (size_t)j * nrow, *c1 = c0 + nrow, *c2 = c1 + nrow,
                         *c3 = c2 + nrow;
            if (nrow < SOLVE_PREFETCH_ROWS)
                prefetch_range(Lx, xsize, (c0 - Lx) + 4 * (ptrdiff_t)nrow, 4 * (ptrdiff_t)nrow);
            double a[BG_SPARSE_MAX_RHS][4];
            for (int c = 0; c < nrhs; c++) { /* the 4×4 diagonal block */
                double *vc = v + (size_t)c * rows, *ac = a[c];
                ac[0] = vc[j] / c0[j];
                ac[1] = (vc[j + 1] - c0[j + 1] * ac[0]) / c1[j + 1];
                ac[2] = (vc[j + 2] - c0[j + 2] * ac[0] - c1[j + 2] * ac[1]) / c2[j + 2];
                ac[3] = (vc[j + 3] - c0[j + 3] * ac[0] - c1[j + 3] * ac[1] - c2[j + 3] * ac[2]) /
                        c3[j + 3];
                memcpy(vc + j, ac, sizeof a[c]);
            }
            if (nrhs == 3)
                update4x3(c0, c1, c2, c3, (const double(*)[4])a, j + 4, nrow, v, v + rows,
                          v + 2 * rows);
            else
                for (int c = 0; c < nrhs; c++)
                    update4(c0, c1, c2, c3, a[c], j + 4, nrow, v + (size_t)c * rows);
        }
        for (; j < ncol; j++) {
            const double *c0 = Lsn + (size_t)j * nrow;
            for (int c = 0; c < nrhs; c++) {
                double *restrict vc = v + (size_t)c * rows;
                const double a0 = vc[j] / c0[j];
                vc[j] = a0;
                for (int i = j + 1; i < nrow; i++)
                    vc[i] -= c0[i] * a0;
            }
        }
        for (int c = 0; c < nrhs; c++) {
            const double *vc = v + (size_t)c * rows;
            double *yc = y + (size_t)c * n;
            memcpy(yc + k1, vc, (size_t)ncol * sizeof *vc);
            for (int i = ncol; i < nrow; i++)
                yc[ri[i]] += vc[i];
        }
    }
    /* Lᵀ w = z, supernodes in reverse, a supernode's columns in blocks of
     * four from its last (the remainder, its first columns, one by one) */
    for (int s = nsuper - 1; s >= 0; s--) {
        const int k1 = super[s], ncol = super[s + 1] - k1, nrow = pi[s + 1] - pi[s];
        const int *ri = Ls + pi[s];
        const double *Lsn = Lx + px[s];
        for (int c = 0; c < nrhs; c++) {
            double *vc = v + (size_t)c * rows;
            const double *yc = y + (size_t)c * n;
            memcpy(vc, yc + k1, (size_t)ncol * sizeof *vc);
            for (int i = ncol; i < nrow; i++)
                vc[i] = yc[ri[i]];
        }
        int j = ncol;
        for (; j >= 4; j -= 4) {
            const int j0 = j - 4;
            const double *c0 = Lsn + (size_t)j0 * nrow, *c1 = c0 + nrow, *c2 = c1 + nrow,
                         *c3 = c2 + nrow;
            if (nrow < SOLVE_PREFETCH_ROWS)
                prefetch_range(Lx, xsize, (c0 - Lx) - 4 * (ptrdiff_t)nrow, 4 * (ptrdiff_t)nrow);
            double dd[BG_SPARSE_MAX_RHS][4];
            if (nrhs == 3)
                dot4x3(c0, c1, c2, c3, v, v + rows, v + 2 * rows, j, nrow, dd);
            else
                for (int c = 0; c < nrhs; c++)
                    dot4(c0, c1, c2, c3, v + (size_t)c * rows, j, nrow, dd[c]);
            for (int c = 0; c < nrhs; c++) { /* the 4×4 diagonal block, transposed */
                double *vc = v + (size_t)c * rows;
                const double *d = dd[c];
                vc[j0 + 3] = (vc[j0 + 3] - d[3]) / c3[j0 + 3];
                vc[j0 + 2] = (vc[j0 + 2] - d[2] - c2[j0 + 3] * vc[j0 + 3]) / c2[j0 + 2];
                vc[j0 + 1] =
                    (vc[j0 + 1] - d[1] - c1[j0 + 2] * vc[j0 + 2] - c1[j0 + 3] * vc[j0 + 3]) /
                    c1[j0 + 1];
                vc[j0] = (vc[j0] - d[0] - c0[j0 + 1] * vc[j0 + 1] - c0[j0 + 2] * vc[j0 + 2] -
                          c0[j0 + 3] * vc[j0 + 3]) /
                         c0[j0];
            }
        }
        for (j = j - 1; j >= 0; j--) {
            const double *c0 = Lsn + (size_t)j * nrow;
            for (int c = 0; c < nrhs; c++) {
                double *vc = v + (size_t)c * rows;
                vc[j] = (vc[j] - dot1(c0, vc, j + 1, nrow)) / c0[j];
            }
        }
        for (int c = 0; c < nrhs; c++)
            memcpy(y + (size_t)c * n + k1, v + (size_t)c * rows, (size_t)ncol * sizeof *v);
    }

    for (int c = 0; c < nrhs; c++)
        for (size_t k = 0; k < n; k++) {
            const size_t pk = Perm ? (size_t)Perm[k] : k;
            x[c * n + (perm ? (size_t)perm[pk] : pk)] = y[c * n + k];
        }
}

/* x = A⁻¹ rhs by super_solve, its scratch kept across calls (it grows to
 * the widest call: (n + rows)·BG_SPARSE_MAX_RHS doubles at most). */
static bg_status solve_super(bg_sparse_t *sys, int nrhs, const double *rhs, double *x,
                             bg_error_t *err)
{
    const size_t rows = super_rows(sys->L), need = (sys->L->n + rows) * (size_t)nrhs;
    if (need > sys->solve_work_size) {
        double *w = realloc(sys->solve_work, need * sizeof *w);
        if (!w)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for %d right-hand sides", nrhs);
        sys->solve_work = w;
        sys->solve_work_size = need;
    }
    const double t0 = bg_clock_now();
    super_solve(sys->L, sys->perm, nrhs, rows, rhs, x, sys->solve_work);
    sys->timing.solve_seconds += bg_clock_now() - t0;
    sys->timing.solves += nrhs;
    return BG_OK;
}

bg_status bg_sparse_solve(bg_sparse_t *sys, const double *rhs, double *x, bg_error_t *err)
{
    return bg_sparse_solve_many(sys, 1, rhs, x, err);
}

bg_status bg_sparse_solve_many(bg_sparse_t *sys, int nrhs, const double *rhs, double *x,
                               bg_error_t *err)
{
    if (!sys->L)
        return bg_error_set(err, BG_ERR_INVALID, "bg_sparse_solve before a factorization");
    if (nrhs < 1 || nrhs > BG_SPARSE_MAX_RHS)
        return bg_error_set(err, BG_ERR_INVALID, "%d right-hand sides (1 to %d)", nrhs,
                            BG_SPARSE_MAX_RHS);
    const size_t n = (size_t)sys->nfree, count = n * (size_t)nrhs;
    if (sys->L->is_super && sys->prefer_solves)
        return solve_super(sys, nrhs, rhs, x, err);
    /* B keeps its widest allocation; a narrower call only reshapes it
     * (cholmod_solve2 reshapes X, Y and E the same way). */
    if (!sys->B || sys->B->nzmax < count) {
        cholmod_free_dense(&sys->B, &sys->common);
        sys->B = cholmod_zeros(n, (size_t)nrhs, CHOLMOD_REAL, &sys->common);
        if (!sys->B)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for %d right-hand sides",
                                nrhs);
    }
    sys->B->ncol = (size_t)nrhs;
    const double t0 = bg_clock_now();
    const int32_t *perm = sys->perm;
    double *Bx = sys->B->x;
    if (perm) /* the stored numbering: row k is the caller's perm[k] */
        for (int c = 0; c < nrhs; c++)
            for (size_t k = 0; k < n; k++)
                Bx[c * n + k] = rhs[c * n + (size_t)perm[k]];
    else
        memcpy(Bx, rhs, count * sizeof(double));
    int ok = cholmod_solve2(CHOLMOD_A, sys->L, sys->B, NULL, &sys->X, NULL, &sys->Y, &sys->E,
                            &sys->common);
    sys->timing.solve_seconds += bg_clock_now() - t0;
    sys->timing.solves += nrhs;
    if (!ok)
        return bg_error_set(err, BG_ERR_NUMERIC, "CHOLMOD solve failed (status %d)",
                            sys->common.status);
    const double *Xx = sys->X->x;
    if (perm)
        for (int c = 0; c < nrhs; c++)
            for (size_t k = 0; k < n; k++)
                x[c * n + (size_t)perm[k]] = Xx[c * n + k];
    else
        memcpy(x, Xx, count * sizeof(double));
    return BG_OK;
}

void bg_sparse_multiply(const bg_sparse_t *sys, const double *x, double *y)
{
    const int *Ap = sys->A->p, *Ai = sys->A->i;
    const double *Ax = sys->A->x;
    const int32_t *perm = sys->perm;
    memset(y, 0, (size_t)sys->nfree * sizeof *y);
    for (int32_t k = 0; k < sys->nfree; k++) {
        const int32_t col = perm ? perm[k] : k;
        for (int p = Ap[k]; p < Ap[k + 1]; p++) {
            const int32_t row = perm ? perm[Ai[p]] : Ai[p];
            y[row] += Ax[p] * x[col];
            if (row != col)
                y[col] += Ax[p] * x[row];
        }
    }
}

bg_sparse_timing_t bg_sparse_timing(const bg_sparse_t *sys)
{
    return sys->timing;
}

void bg_sparse_add_timing(bg_sparse_t *sys, const bg_sparse_timing_t *extra)
{
    sys->timing.analyze_seconds += extra->analyze_seconds;
    sys->timing.factor_seconds += extra->factor_seconds;
    sys->timing.solve_seconds += extra->solve_seconds;
    sys->timing.factorizations += extra->factorizations;
    sys->timing.solves += extra->solves;
}

double bg_sparse_factor_flops(const bg_sparse_t *sys)
{
    return sys->factor_flops;
}

double bg_sparse_factor_nonzeros(const bg_sparse_t *sys)
{
    return sys->factor_nonzeros;
}
