#include "bg_elastic.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/*
 * The elements are processed in an order of their own: sorted along a
 * Morton (Z-order) curve through their rest centroids, so that elements
 * handled one after another are neighbours in space and share vertices.
 * Meshes from a tetrahedralizer number their vertices without regard to
 * the elements (the bunny's tets span 4,163 of its 7,248 vertex numbers
 * on average, consecutive tets jump by 2,036): in mesh order every
 * element reads and writes four scattered vertex records and Hessian
 * columns; in curve order they are mostly still in cache from the
 * element before. Results are those of the same sums in another order.
 *
 * Per-element data is stored at the element's position p in that order,
 * in blocks of ELASTIC_BLOCK elements, each block in structure-of-arrays
 * form: entry i of position p at (p / B)·width·B + i·B + p % B (soa
 * below). The 3D kernel loads a whole block's D_m⁻¹ or rotations with one
 * aligned vector load per entry; scalar code reads a position through
 * elastic_dminv / quat_load. Arrays are padded to whole blocks (the
 * padding positions repeat the block's first element's vertices).
 */
#define ELASTIC_BLOCK 8

struct bg_elastic {
    const bg_mesh_t *mesh;
    int n;              /* spatial dimension */
    int m;              /* local dofs per element: (n+1)*n */
    double mu, lambda;
    int32_t *order;     /* ne: position → element (mesh numbering) */
    int32_t *slot;      /* ne: element → position */
    int32_t *nodes;     /* padded positions × (n+1): each position's vertices */
    double *dminv;      /* blocks × n·n: D_m⁻¹, row-major per element (soa) */
    double *volume;     /* padded positions, zeros in the padding */
    double *quat;       /* blocks × 4 (3D): warm-start rotations (soa) */
    double *psi;        /* ne, mesh numbering: energy density of the last eval */
    double total_volume;
    double barrier;     /* 2D: weight of the area barrier (0: none) */
    bg_rotfit_stats_t stats;
};

/* Position of entry i (of width per element) of element e, block-SoA. */
static inline size_t soa(size_t e, int i, int width)
{
    return (e / ELASTIC_BLOCK) * (size_t)width * ELASTIC_BLOCK + (size_t)i * ELASTIC_BLOCK +
           e % ELASTIC_BLOCK;
}

static inline void elastic_dminv(const bg_elastic_t *md, size_t e, double *restrict Di)
{
    const int nn = md->n * md->n;
    for (int i = 0; i < nn; i++)
        Di[i] = md->dminv[soa(e, i, nn)];
}

static inline void quat_load(const bg_elastic_t *md, size_t e, double q[4])
{
    for (int i = 0; i < 4; i++)
        q[i] = md->quat[soa(e, i, 4)];
}

/* A pair sum σi + σj of the stretch below this (relative to tr Y) makes
 * W = (tr Y·I − Y)⁻¹ unbounded: R is not differentiable there, and the
 * Hessian uses this floor instead of dividing by zero. */
#define ELASTIC_PAIR_SUM_FLOOR 1e-10

/* Spreads the low 21 bits of x to every third bit (Morton interleave). */
static uint64_t spread3(uint64_t x)
{
    x &= 0x1fffff;
    x = (x | x << 32) & 0x1f00000000ffffULL;
    x = (x | x << 16) & 0x1f0000ff0000ffULL;
    x = (x | x << 8) & 0x100f00f00f00f00fULL;
    x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
    x = (x | x << 2) & 0x1249249249249249ULL;
    return x;
}

typedef struct order_key {
    uint64_t key;
    int32_t element;
} order_key;

static int compare_keys(const void *a, const void *b)
{
    const order_key *x = a, *y = b;
    if (x->key != y->key)
        return x->key < y->key ? -1 : 1;
    return (x->element > y->element) - (x->element < y->element);
}

/* md->order: the elements sorted along the Morton curve through their
 * centroids at mesh->x (ties by element number: deterministic). */
static bg_status elastic_order(bg_elastic_t *md)
{
    const bg_mesh_t *mesh = md->mesh;
    const int k = mesh->nodes_per_element, d = mesh->dim;
    order_key *keys = malloc((size_t)mesh->ne * sizeof *keys + 1);
    if (!keys)
        return BG_ERR_NOMEM;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    bg_mesh_bounds(mesh, lo, hi);
    for (int32_t e = 0; e < mesh->ne; e++) {
        uint64_t key = 0;
        for (int c = 0; c < d && c < 3; c++) {
            double centre = 0.0;
            for (int i = 0; i < k; i++)
                centre += mesh->x[(size_t)mesh->elements[(size_t)e * k + i] * d + c] / k;
            const double span = hi[c] - lo[c];
            const double t = span > 0.0 ? (centre - lo[c]) / span : 0.0;
            key |= spread3((uint64_t)(fmin(fmax(t, 0.0), 1.0) * 2097151.0)) << c;
        }
        keys[e] = (order_key){key, e};
    }
    qsort(keys, (size_t)mesh->ne, sizeof *keys, compare_keys);
    for (int32_t p = 0; p < mesh->ne; p++)
        md->order[p] = keys[p].element;
    free(keys);
    return BG_OK;
}

/* The model over mesh's connectivity with n-dimensional unknowns; rest
 * edge matrices from rest_edges (ne·n·n, row-major, column j = edge j) or,
 * when NULL, from the mesh's positions. */
static bg_status elastic_init(const bg_mesh_t *mesh, int dim, const double *rest_edges, double mu,
                              double lambda, bg_elastic_t **out, bg_error_t *err)
{
    *out = NULL;
    if (!(mu > 0.0) || !isfinite(mu) || !isfinite(lambda))
        return bg_error_set(err, BG_ERR_INVALID, "material: mu = %g must be positive", mu);
    bg_elastic_t *md = calloc(1, sizeof *md);
    if (!md)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the elastic model");
    md->mesh = mesh;
    md->n = dim;
    md->m = (md->n + 1) * md->n;
    md->mu = mu;
    md->lambda = lambda;
    const size_t ne = (size_t)mesh->ne, n = (size_t)md->n;
    const size_t padded = (ne + ELASTIC_BLOCK - 1) / ELASTIC_BLOCK * ELASTIC_BLOCK;
    /* Padding positions: D_m⁻¹ = I and no volume, so the kernel computes
     * finite nothing there. */
    md->order = malloc(ne * sizeof *md->order + 1);
    md->slot = malloc(ne * sizeof *md->slot + 1);
    md->nodes = malloc(padded * (n + 1) * sizeof *md->nodes + 1);
    md->dminv = calloc(padded * n * n + 1, sizeof *md->dminv);
    md->volume = calloc(padded + 1, sizeof *md->volume);
    md->quat = calloc(padded * 4 + 1, sizeof *md->quat);
    md->psi = calloc(ne + 1, sizeof *md->psi);
    if (!md->order || !md->slot || !md->nodes || !md->dminv || !md->volume || !md->quat || !md->psi ||
        elastic_order(md) != BG_OK) {
        bg_elastic_destroy(&md);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the elastic model");
    }
    for (size_t p = 0; p < ne; p++)
        md->slot[md->order[p]] = (int32_t)p;
    for (size_t p = 0; p < padded; p++) {
        const size_t e = (size_t)md->order[p < ne ? p : p - p % ELASTIC_BLOCK];
        memcpy(md->nodes + p * (n + 1), mesh->elements + e * (n + 1),
               (n + 1) * sizeof *md->nodes);
    }
    for (size_t p = ne; p < padded; p++)
        for (size_t a = 0; a < n; a++)
            md->dminv[soa(p, (int)(a * n + a), (int)(n * n))] = 1.0;
    for (size_t p = 0; p < ne; p++) {
        const size_t e = (size_t)md->order[p];
        const int32_t *el = mesh->elements + e * (n + 1);
        double D[9], Di[9];
        if (rest_edges)
            memcpy(D, rest_edges + e * n * n, n * n * sizeof *D);
        else
            for (size_t j = 0; j < n; j++)
                for (size_t a = 0; a < n; a++)
                    D[a * n + j] =
                        mesh->x[(size_t)el[j + 1] * n + a] - mesh->x[(size_t)el[0] * n + a];
        double det;
        if (n == 2) {
            det = D[0] * D[3] - D[1] * D[2];
            Di[0] = D[3] / det;
            Di[1] = -D[1] / det;
            Di[2] = -D[2] / det;
            Di[3] = D[0] / det;
            md->volume[p] = 0.5 * fabs(det);
        } else {
            const double c0 = D[4] * D[8] - D[5] * D[7], c1 = D[5] * D[6] - D[3] * D[8],
                         c2 = D[3] * D[7] - D[4] * D[6];
            det = D[0] * c0 + D[1] * c1 + D[2] * c2;
            Di[0] = c0 / det;
            Di[1] = (D[2] * D[7] - D[1] * D[8]) / det;
            Di[2] = (D[1] * D[5] - D[2] * D[4]) / det;
            Di[3] = c1 / det;
            Di[4] = (D[0] * D[8] - D[2] * D[6]) / det;
            Di[5] = (D[2] * D[3] - D[0] * D[5]) / det;
            Di[6] = c2 / det;
            Di[7] = (D[1] * D[6] - D[0] * D[7]) / det;
            Di[8] = (D[0] * D[4] - D[1] * D[3]) / det;
            md->volume[p] = fabs(det) / 6.0;
        }
        for (size_t i = 0; i < n * n; i++)
            md->dminv[soa(p, (int)i, (int)(n * n))] = Di[i];
        if (!(det > 0.0) || !isfinite(det)) {
            bg_elastic_destroy(&md);
            return bg_error_set(err, BG_ERR_INVALID,
                                "element %zu has a non-positive rest measure (validate the mesh "
                                "first)",
                                e + 1);
        }
        md->total_volume += md->volume[p];
    }
    *out = md;
    return BG_OK;
}

bg_status bg_elastic_new(const bg_mesh_t *mesh, double mu, double lambda, bg_elastic_t **out,
                         bg_error_t *err)
{
    if (bg_mesh_kind_of(mesh) == BG_MESH_SURFACE) {
        *out = NULL;
        return bg_error_set(err, BG_ERR_UNSUPPORTED,
                            "the elastic model needs planar triangles or tetrahedra, not a "
                            "triangle surface in 3D");
    }
    return elastic_init(mesh, mesh->dim, NULL, mu, lambda, out, err);
}

bg_status bg_elastic_new_from_rest(const bg_mesh_t *mesh, int dim, const double *rest_edges,
                                   double mu, double lambda, bg_elastic_t **out, bg_error_t *err)
{
    if (dim + 1 != mesh->nodes_per_element) {
        *out = NULL;
        return bg_error_set(err, BG_ERR_INVALID, "rest frames of dimension %d need elements of "
                            "%d nodes", dim, dim + 1);
    }
    return elastic_init(mesh, dim, rest_edges, mu, lambda, out, err);
}

void bg_elastic_destroy(bg_elastic_t **model)
{
    if (!model || !*model)
        return;
    bg_elastic_t *md = *model;
    free(md->order);
    free(md->slot);
    free(md->nodes);
    free(md->dminv);
    free(md->volume);
    free(md->quat);
    free(md->psi);
    free(md);
    *model = NULL;
}

int bg_elastic_dim(const bg_elastic_t *model)
{
    return model->n;
}

int bg_elastic_local_size(const bg_elastic_t *model)
{
    return model->m;
}

const bg_mesh_t *bg_elastic_mesh(const bg_elastic_t *model)
{
    return model->mesh;
}

const int32_t *bg_elastic_order(const bg_elastic_t *model)
{
    return model->order;
}

double bg_elastic_volume(const bg_elastic_t *model, int32_t e)
{
    return model->volume[model->slot[e]];
}

double bg_elastic_total_volume(const bg_elastic_t *model)
{
    return model->total_volume;
}

const double *bg_elastic_energy_density(const bg_elastic_t *model)
{
    return model->psi;
}

bg_rotfit_stats_t bg_elastic_rotfit_stats(const bg_elastic_t *model)
{
    return model->stats;
}

void bg_elastic_reset_stats(bg_elastic_t *model)
{
    memset(&model->stats, 0, sizeof model->stats);
}

void bg_elastic_forget_rotations(bg_elastic_t *model)
{
    const size_t blocks = ((size_t)model->mesh->ne + ELASTIC_BLOCK - 1) / ELASTIC_BLOCK;
    memset(model->quat, 0, blocks * ELASTIC_BLOCK * 4 * sizeof *model->quat);
}

/*
 * ∂P/∂F in 3D (DESIGN.md §1.3), written as
 *   H = 2μ I₉ + G A Gᵀ + λ vec(R) vec(R)ᵀ,   G = [vec(R[e_k]×)]_k,
 * with A = c W (c = λ(tr Y − 3) − 2μ, W = (tr Y·I − Y)⁻¹) for the exact
 * Hessian. Since GᵀG = 2I, the twist block in an orthonormal basis is
 * T = 2μ I + 2A, with eigenvalues 2μ + 2c/(σi + σj); projecting clamps
 * its negative eigenvalues to zero, A = (T⁺ − 2μ I)/2. Every other
 * eigenvalue is 2μ or 2μ + 3λ, positive for a valid material.
 */
/* M − θI positive definite (Sylvester's criterion, strict). */
static int pd3_shifted(const double M[9], double theta)
{
    const double a = M[0] - theta, b = M[4] - theta, c = M[8] - theta;
    const double minor2 = a * b - M[1] * M[1];
    const double det = a * (b * c - M[5] * M[5]) - M[1] * (M[1] * c - M[5] * M[2]) +
                       M[2] * (M[1] * M[5] - b * M[2]);
    return a > 0.0 && minor2 > 0.0 && det > 0.0;
}

/*
 * Y = V diag(y) Vᵀ for a symmetric 3×3 Y (upper triangle given), V's
 * columns orthonormal, in closed form with a fixed operation count (no
 * sweeps), so that it runs across vector lanes without waiting for the
 * slowest lane. The steps, and why each is stable:
 *
 * 1. B = (Y − qI)/m with q the mean diagonal (re-centred once more, so
 *    tr B is zero to rounding of B's own entries, not of q's) and m the
 *    largest |entry| (m = 0: Y = qI, B = 0). Then |b_ij| ≤ 1 with one
 *    equal to 1, so ‖B‖_F ≥ 1 and B's eigenvalues spread by at least
 *    about one: every later quantity is O(1) and nothing under- or
 *    overflows. Rounding here is a perturbation of Y of a few ulps of
 *    max(|q|, m), which is all a backward-stable decomposition may do.
 * 2. The eigenvalue of B farthest from the other two: with p² = tr B²/6
 *    and β = det B/(2p³) ∈ [−1, 1], the eigenvalues are p·x with
 *    x³ − 3x − 2β = 0 (|β| a rounding above 1 needs no clamp: Newton
 *    then finds the root just above 2, there is no acos to fail). For
 *    β ≥ 0 the largest root x ∈ [√3, 2] lies at least 3p/2 from the
 *    others (for β < 0, the smallest, by symmetry: solve for |β| and
 *    negate). That root is a smooth function of β on [0, 1] (roots meet
 *    only at β = −1), so Newton's method from a quadratic fit (error
 *    < 1.1e-3) reaches full precision in three steps (error squared each
 *    step, times x/(x² − 1) ≤ 0.9); the derivative 3(x² − 1) ≥ 6 there,
 *    so the root's rounding error is that of evaluating the cubic, a few
 *    ulps. (The trigonometric form 2cos(acos β/3) gives the same root but
 *    loses half the digits of the two near-equal roots when β ≈ ±1;
 *    those are not taken from it here.)
 * 3. Its eigenvector v₀ spans the null space of C = B − λ₀I, whose other
 *    eigenvalues are at least 3p/2 ≥ 0.6 away: the cross products of C's
 *    rows are the columns of adj C = μ₁μ₂ v₀v₀ᵀ, the largest at least
 *    |μ₁μ₂|/√3 long, so v₀ is taken from it with an error of rounding
 *    size (relative to O(1) quantities; no cancellation to fear).
 * 4. The other two in the plane orthogonal to v₀: an orthonormal pair
 *    u = v₀ × e_j/|·| (e_j the axis least aligned with v₀, |v₀ × e_j|² =
 *    1 − v₀_j² ≥ 2/3, no cancellation), w = v₀ × u, and the 2×2 matrix
 *    [uᵀBu uᵀBw; · wᵀBw] diagonalised by one Jacobi rotation (the root
 *    of smaller magnitude, |t| ≤ 1, as in
 *    bg_sym3_eigen): exact to rounding however close its two eigenvalues
 *    are, which is where closed forms that take every eigenvector from a
 *    null space fail. v₀'s own eigenvalue is its Rayleigh quotient; the
 *    couplings v₀ᵀBu, v₀ᵀBw left out are the residual of v₀, of rounding
 *    size.
 * So V diag(y) Vᵀ = Y + E with ‖E‖ a few ulps of max(|q|, m) and V
 * orthonormal to a few ulps: the guarantees of the Jacobi method it
 * replaces, and what keeps A = V diag(a(y)) Vᵀ within rounding of the
 * exact clamped block (a Lipschitz in y away from the pair-sum floor).
 *
 * Every operation runs on every lane, the special cases folded into the
 * operands (m = 0 adds 1 to m and to p²; a zero coupling uᵀBw gets a
 * 1e-300 of its sign, so θ is ±∞ or huge and the rotation the identity,
 * or θ = 0 when the 2×2 block is a multiple of I, where any rotation is
 * right): a select of a constant that feeds a division or a square root
 * would leave a branch the vectoriser cannot convert.
 */
static inline __attribute__((always_inline)) void
sym3_eigen_closed(double y00, double y01, double y02, double y11, double y12, double y22,
                  double y[3], double V[9])
{
    const double q = (y00 + y11 + y22) / 3.0;
    double d0 = y00 - q, d1 = y11 - q, d2 = y22 - q;
    const double r = (d0 + d1 + d2) / 3.0;
    d0 -= r, d1 -= r, d2 -= r;
    const double shift = q + r;
    double m = fabs(d0);
    m = fabs(d1) > m ? fabs(d1) : m;
    m = fabs(d2) > m ? fabs(d2) : m;
    m = fabs(y01) > m ? fabs(y01) : m;
    m = fabs(y02) > m ? fabs(y02) : m;
    m = fabs(y12) > m ? fabs(y12) : m;
    const double none = m > 0.0 ? 0.0 : 1.0;
    const double inv = 1.0 / (m + none);
    const double b00 = d0 * inv, b11 = d1 * inv, b22 = d2 * inv;
    const double b01 = y01 * inv, b02 = y02 * inv, b12 = y12 * inv;
    /* Step 2 (B = 0: p taken as 1, β = 0; any orthonormal V will do). */
    const double p2 =
        (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (b01 * b01 + b02 * b02 + b12 * b12)) / 6.0;
    const double p = sqrt(p2 + none);
    const double det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) +
                       b02 * (b01 * b12 - b11 * b02);
    const double beta = fabs(det) / (2.0 * p * p * p);
    /* x(0) = √3, x(1/2) = 2cos(π/9), x(1) = 2 */
    double x = 1.7320508075688772 + beta * (0.32138841 - 0.05343921 * beta);
    for (int it = 0; it < 3; it++)
        x -= (x * (x * x - 3.0) - 2.0 * beta) / (3.0 * (x * x - 1.0));
    const double l0 = copysign(p * x, det);
    /* Step 3 */
    const double c00 = b00 - l0, c11 = b11 - l0, c22 = b22 - l0;
    const double xa0 = b01 * b12 - b02 * c11, xa1 = b02 * b01 - c00 * b12,
                 xa2 = c00 * c11 - b01 * b01; /* row 0 × row 1 */
    const double xb0 = b01 * c22 - b02 * b12, xb1 = b02 * b02 - c00 * c22,
                 xb2 = c00 * b12 - b01 * b02; /* row 0 × row 2 */
    const double xc0 = c11 * c22 - b12 * b12, xc1 = b12 * b02 - b01 * c22,
                 xc2 = b01 * b12 - c11 * b02; /* row 1 × row 2 */
    const double na = xa0 * xa0 + xa1 * xa1 + xa2 * xa2, nb = xb0 * xb0 + xb1 * xb1 + xb2 * xb2,
                 nc = xc0 * xc0 + xc1 * xc1 + xc2 * xc2;
    const int ab = na >= nb;
    double n0 = ab ? na : nb, v0 = ab ? xa0 : xb0, v1 = ab ? xa1 : xb1, v2 = ab ? xa2 : xb2;
    const int cc = nc > n0;
    n0 = cc ? nc : n0, v0 = cc ? xc0 : v0, v1 = cc ? xc1 : v1, v2 = cc ? xc2 : v2;
    const double s0 = 1.0 / sqrt(n0);
    v0 *= s0, v1 *= s0, v2 *= s0;
    /* Step 4: u = v₀ × e_j, j the axis with the smallest |v₀_j| */
    const double a0 = fabs(v0), a1 = fabs(v1), a2 = fabs(v2);
    double amin = a0, u0 = 0.0, u1 = v2, u2 = -v1;
    const int sy = a1 < amin;
    amin = sy ? a1 : amin, u0 = sy ? -v2 : u0, u1 = sy ? 0.0 : u1, u2 = sy ? v0 : u2;
    const int sz = a2 < amin;
    amin = sz ? a2 : amin, u0 = sz ? v1 : u0, u1 = sz ? -v0 : u1, u2 = sz ? 0.0 : u2;
    const double su = 1.0 / sqrt(1.0 - amin * amin);
    u0 *= su, u1 *= su, u2 *= su;
    const double w0 = v1 * u2 - v2 * u1, w1 = v2 * u0 - v0 * u2, w2 = v0 * u1 - v1 * u0;
    const double Bu0 = b00 * u0 + b01 * u1 + b02 * u2, Bu1 = b01 * u0 + b11 * u1 + b12 * u2,
                 Bu2 = b02 * u0 + b12 * u1 + b22 * u2;
    const double Bw0 = b00 * w0 + b01 * w1 + b02 * w2, Bw1 = b01 * w0 + b11 * w1 + b12 * w2,
                 Bw2 = b02 * w0 + b12 * w1 + b22 * w2;
    const double Bv0 = b00 * v0 + b01 * v1 + b02 * v2, Bv1 = b01 * v0 + b11 * v1 + b12 * v2,
                 Bv2 = b02 * v0 + b12 * v1 + b22 * v2;
    const double auu = u0 * Bu0 + u1 * Bu1 + u2 * Bu2, auw = u0 * Bw0 + u1 * Bw1 + u2 * Bw2,
                 aww = w0 * Bw0 + w1 * Bw1 + w2 * Bw2;
    const double theta = (aww - auu) / (2.0 * auw + copysign(1e-300, auw));
    const double t = copysign(1.0, theta) / (fabs(theta) + sqrt(theta * theta + 1.0));
    const double c = 1.0 / sqrt(t * t + 1.0), s = t * c;
    y[0] = shift + m * (v0 * Bv0 + v1 * Bv1 + v2 * Bv2);
    y[1] = shift + m * (auu - t * auw);
    y[2] = shift + m * (aww + t * auw);
    V[0] = v0, V[3] = v1, V[6] = v2;
    V[1] = c * u0 - s * w0, V[4] = c * u1 - s * w1, V[7] = c * u2 - s * w2;
    V[2] = s * u0 + c * w0, V[5] = s * u1 + c * w1, V[8] = s * u2 + c * w2;
}

void bg_elastic_sym3_eigen(const double Y[9], double y[3], double V[9])
{
    sym3_eigen_closed(Y[0], Y[1], Y[2], Y[4], Y[5], Y[8], y, V);
}

/*
 * The twist block A of ∂P/∂F = 2μ I₉ + G A Gᵀ + λ vec(R) vec(R)ᵀ (see
 * dpdf3): A = c W, c = λ(tr Y − 3) − 2μ, W = M⁻¹, M = tr Y·I − Y. Its
 * eigenvalues in an orthonormal twist basis are t_k = 2μ + 2c/s_k with s_k
 * the eigenvalues of M (pair sums σi + σj). When M is safely positive
 * definite and, for a projection with c < 0, s_k > −c/μ (so every t_k > 0),
 * A = c M⁻¹ directly; otherwise an eigen-decomposition floors s_k and, when
 * projecting, clamps negative t_k to zero.
 */
/* The twist block's weight along an eigenvector of M whose eigenvalue is
 * the pair sum s: a = (t − 2μ)/2 with t = 2μ + 2c/s the twist eigenvalue,
 * s floored, t clamped at 0 when projecting. */
static inline double twist_weight(double mu, double c, double s, double floor_, int project)
{
    if (s < floor_)
        s = floor_;
    double t = 2.0 * mu + 2.0 * c / s;
    if (project && t < 0.0)
        t = 0.0;
    return 0.5 * (t - 2.0 * mu);
}

static void twist_block3(double mu, double lambda, const double S[9], double trY, int project,
                         double A[9])
{
    double M[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            M[3 * i + j] = (i == j ? trY : 0.0) - 0.5 * (S[3 * i + j] + S[3 * j + i]);
    const double c = lambda * (trY - 3.0) - 2.0 * mu;
    const double floor_ = ELASTIC_PAIR_SUM_FLOOR * fmax(1.0, fabs(trY));
    const double theta = project && c < 0.0 ? fmax(floor_, -c / mu) : floor_;
    if (pd3_shifted(M, theta)) {
        const double c00 = M[4] * M[8] - M[5] * M[7], c01 = M[2] * M[7] - M[1] * M[8],
                     c02 = M[1] * M[5] - M[2] * M[4], c11 = M[0] * M[8] - M[2] * M[6],
                     c12 = M[2] * M[3] - M[0] * M[5], c22 = M[0] * M[4] - M[1] * M[3];
        const double f = c / (M[0] * c00 + M[1] * c01 + M[2] * c02);
        A[0] = f * c00, A[1] = f * c01, A[2] = f * c02;
        A[3] = f * c01, A[4] = f * c11, A[5] = f * c12;
        A[6] = f * c02, A[7] = f * c12, A[8] = f * c22;
        return;
    }
    double y[3], V[9];
    sym3_eigen_closed(S[0], 0.5 * (S[1] + S[3]), 0.5 * (S[2] + S[6]), S[4], 0.5 * (S[5] + S[7]),
                      S[8], y, V);
    double a[3];
    for (int k = 0; k < 3; k++)
        a[k] = twist_weight(mu, c, trY - y[k], floor_, project);
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            A[3 * i + j] = V[3 * i] * a[0] * V[3 * j] + V[3 * i + 1] * a[1] * V[3 * j + 1] +
                           V[3 * i + 2] * a[2] * V[3 * j + 2];
}

static void dpdf3(double mu, double lambda, const double R[9], const double S[9], double trY,
                  int project, double H[81])
{
    double A[9];
    twist_block3(mu, lambda, S, trY, project, A);
    /* G's columns: vec(R [e_k]×). R[e1]× = [0, R_i2, −R_i1] per row i, etc. */
    double G[9][3];
    for (int i = 0; i < 3; i++) {
        const double r0 = R[3 * i], r1 = R[3 * i + 1], r2 = R[3 * i + 2];
        G[3 * i + 0][0] = 0.0, G[3 * i + 1][0] = r2, G[3 * i + 2][0] = -r1;
        G[3 * i + 0][1] = -r2, G[3 * i + 1][1] = 0.0, G[3 * i + 2][1] = r0;
        G[3 * i + 0][2] = r1, G[3 * i + 1][2] = -r0, G[3 * i + 2][2] = 0.0;
    }
    double GA[9][3];
    for (int r = 0; r < 9; r++)
        for (int k = 0; k < 3; k++)
            GA[r][k] = G[r][0] * A[k] + G[r][1] * A[3 + k] + G[r][2] * A[6 + k];
    for (int r = 0; r < 9; r++)
        for (int s = 0; s < 9; s++)
            H[9 * r + s] = (r == s ? 2.0 * mu : 0.0) +
                           GA[r][0] * G[s][0] + GA[r][1] * G[s][1] + GA[r][2] * G[s][2] +
                           lambda * R[r] * R[s];
}

/* ∂P/∂F in 2D: the twist space is one-dimensional, G = vec(R J), |G|² = 2,
 * W = 1/tr Y, twist eigenvalue 2μ + 2c/tr Y. */
static void dpdf2(double mu, double lambda, const double R[4], double trY, int project,
                  double H[16])
{
    const double G[4] = {R[1], -R[0], R[3], -R[2]}; /* R J with J = [[0, −1], [1, 0]] */
    const double c = lambda * (trY - 2.0) - 2.0 * mu;
    const double s = fmax(trY, ELASTIC_PAIR_SUM_FLOOR * fmax(1.0, fabs(trY)));
    double t = 2.0 * mu + 2.0 * c / s;
    if (project && t < 0.0)
        t = 0.0;
    const double a = 0.5 * (t - 2.0 * mu);
    for (int r = 0; r < 4; r++)
        for (int q = 0; q < 4; q++)
            H[4 * r + q] = (r == q ? 2.0 * mu : 0.0) + a * G[r] * G[q] + lambda * R[r] * R[q];
}

/*
 * The material point: fits R, returns ψ, fills P (if non-NULL) and ∂P/∂F
 * (if non-NULL). Writes R and returns the rotation-fit path via *path.
 */
static double material_point(int n, double mu, double lambda, const double *F, double *quat,
                             double *R, double *P, double *H, int project, int *path)
{
    double S[9];
    double trY = 0.0, dev = 0.0;
    if (n == 3) {
        *path = (int)bg_rotfit3(F, quat, R);
        bg_mul_tn3(R, F, S);
        trY = S[0] + S[4] + S[8];
    } else {
        *path = bg_rotfit2(F, R) ? BG_ROTFIT_SVD : BG_ROTFIT_WARM;
        trY = R[0] * F[0] + R[2] * F[2] + R[1] * F[1] + R[3] * F[3];
    }
    const int nn = n * n;
    for (int i = 0; i < nn; i++) {
        const double d = F[i] - R[i];
        dev += d * d;
    }
    const double vol = trY - n;
    if (P)
        for (int i = 0; i < nn; i++)
            P[i] = 2.0 * mu * (F[i] - R[i]) + lambda * vol * R[i];
    if (H) {
        if (n == 3)
            dpdf3(mu, lambda, R, S, trY, project, H);
        else
            dpdf2(mu, lambda, R, trY, project, H);
    }
    return mu * dev + 0.5 * lambda * vol * vol;
}

double bg_elastic_psi(int n, double mu, double lambda, const double *F, double *quat, double *P,
                      double *dPdF, int project)
{
    double R[9], q0[4] = {0, 0, 0, 0};
    int path;
    return material_point(n, mu, lambda, F, quat ? quat : q0, R, P, dPdF, project, &path);
}

void bg_sym4_project(double A[16])
{
    double a[4][4], V[4][4];
    double scale = 0.0;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            a[i][j] = 0.5 * (A[4 * i + j] + A[4 * j + i]);
            V[i][j] = i == j ? 1.0 : 0.0;
            scale += a[i][j] * a[i][j];
        }
    for (int sweep = 0; sweep < 50; sweep++) {
        double off = 0.0;
        for (int i = 0; i < 4; i++)
            for (int j = i + 1; j < 4; j++)
                off += a[i][j] * a[i][j];
        if (!(off > 1e-32 * scale))
            break;
        for (int p = 0; p < 4; p++)
            for (int q = p + 1; q < 4; q++) {
                if (a[p][q] == 0.0)
                    continue;
                const double theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                const double t = (theta >= 0.0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
                const double c = 1.0 / sqrt(t * t + 1.0), sn = t * c;
                for (int k = 0; k < 4; k++) {
                    const double kp = a[k][p], kq = a[k][q];
                    a[k][p] = c * kp - sn * kq;
                    a[k][q] = sn * kp + c * kq;
                }
                for (int k = 0; k < 4; k++) {
                    const double pk = a[p][k], qk = a[q][k];
                    a[p][k] = c * pk - sn * qk;
                    a[q][k] = sn * pk + c * qk;
                }
                for (int k = 0; k < 4; k++) {
                    const double kp = V[k][p], kq = V[k][q];
                    V[k][p] = c * kp - sn * kq;
                    V[k][q] = sn * kp + c * kq;
                }
            }
    }
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double sum = 0.0;
            for (int k = 0; k < 4; k++)
                sum += V[i][k] * fmax(a[k][k], 0.0) * V[j][k];
            A[4 * i + j] = sum;
        }
}

/*
 * The 2D area barrier b(J) = −(J − k)² log(J/k) for 0 < J < k, 0 for J ≥ k
 * (k = BG_ELASTIC_BARRIER_KNEE, J = det F): C² at the knee, +∞ as a
 * triangle degenerates. Returns b and its first two derivatives in J.
 */
static double barrier_value(double J, double *d1, double *d2)
{
    const double k = BG_ELASTIC_BARRIER_KNEE;
    *d1 = *d2 = 0.0;
    if (!(J > 0.0))
        return INFINITY;
    if (J >= k)
        return 0.0;
    const double d = J - k, l = log(J / k);
    *d1 = -2.0 * d * l - d * d / J;
    *d2 = -2.0 * l - 4.0 * d / J + d * d / (J * J);
    return -d * d * l;
}

void bg_elastic_set_barrier(bg_elastic_t *model, double weight)
{
    model->barrier = model->n == 2 && weight > 0.0 ? weight : 0.0;
}

/* Adds the weighted barrier to ψ, P and ∂P/∂F (2D, vec order F00 F01 F10
 * F11). ∂J/∂F = cof F = (F11, −F10, −F01, F00); ∂²J/∂F² is the constant
 * K with K[0][3] = K[3][0] = 1, K[1][2] = K[2][1] = −1. The Hessian
 * w (b'' c cᵀ + b' K) is indefinite (K has eigenvalues ±1); projecting
 * clamps its negative eigenvalues (it is projected on its own: a sum of
 * PSD parts is PSD). */
static double barrier_point(double w, const double *F, double *P, double *H, int project)
{
    const double J = F[0] * F[3] - F[1] * F[2];
    double d1, d2;
    const double b = barrier_value(J, &d1, &d2);
    if (!(J < BG_ELASTIC_BARRIER_KNEE))
        return b;
    const double c[4] = {F[3], -F[2], -F[1], F[0]};
    if (P)
        for (int i = 0; i < 4; i++)
            P[i] += w * d1 * c[i];
    if (H) {
        double B[16];
        for (int r = 0; r < 4; r++)
            for (int q = 0; q < 4; q++)
                B[4 * r + q] = w * d2 * c[r] * c[q];
        B[3] += w * d1, B[12] += w * d1, B[6] -= w * d1, B[9] -= w * d1;
        if (project)
            bg_sym4_project(B);
        for (int i = 0; i < 16; i++)
            H[i] += B[i];
    }
    return w * b;
}

/* F = Σ_j (q_j − q_0) ⊗ (row j−1 of D_m⁻¹). */
static void deformation_gradient(int n, const int32_t *restrict el, const double *restrict q,
                                 const double *restrict Di, double *restrict F)
{
    double d[3][3];
    for (int j = 0; j < n; j++)
        for (int a = 0; a < n; a++)
            d[j][a] = q[(size_t)el[j + 1] * n + a] - q[(size_t)el[0] * n + a];
    for (int a = 0; a < n; a++)
        for (int b = 0; b < n; b++) {
            double s = 0.0;
            for (int j = 0; j < n; j++)
                s += d[j][a] * Di[j * n + b];
            F[a * n + b] = s;
        }
}


/*
 * The 3D fast path works on blocks of ELASTIC_BLOCK elements in
 * structure-of-arrays form, so that the compiler vectorises across
 * elements (one lane per element) and target_clones picks AVX-512,
 * AVX2+FMA or baseline code at run time from one portable binary; nothing
 * is compiled for the build machine alone. Per block: the edge vectors are
 * gathered lane by lane (the only scattered reads), then F = D D_m⁻¹, the
 * rotation fit, P, ψ and the nodal forces V P D_m⁻ᵀ run vectorised, and
 * the forces are added into the gradient lane by lane (lanes may share a
 * vertex). The fit takes warm-started Newton steps on SO(3) until every
 * lane's skew residual is at rounding level (a lane already there is
 * left alone: repeated evaluations at the same positions return the same
 * rotations) or ELASTIC_BLOCK_STEPS steps are spent; a lane without a warm
 * start, with det F ≤ ε, a Newton matrix that is not positive definite or
 * a residual still above tolerance is redone by the scalar bg_rotfit3
 * (polar iteration or SVD) from its stored rotation.
 */
#define ELASTIC_BLOCK_STEPS 3

typedef struct block3 {
    double F[9][ELASTIC_BLOCK];
    double q[4][ELASTIC_BLOCK];
    double P[9][ELASTIC_BLOCK];
    double f[9][ELASTIC_BLOCK]; /* forces on nodes 1..3, entry 3j + a */
    double psi[ELASTIC_BLOCK];
    double ok[ELASTIC_BLOCK];   /* 1.0: the lane's rotation is final */
    int moved;                  /* some lane's rotation changed (it must be stored) */
} block3_t;

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
#define ELASTIC_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define ELASTIC_CLONES
#endif

/* F = D D_m⁻¹ for the block, D the edge vectors gathered from the
 * positions (el: the block's element records, 4 vertices per lane;
 * gathers where the target has them) and Di the block's D_m⁻¹ (soa,
 * 9 × B). */
ELASTIC_CLONES
static void block3_gradient(block3_t *restrict blk, const int32_t *restrict el,
                            const double *restrict q, const double *restrict Di)
{
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < ELASTIC_BLOCK; b++) {
            const double x0 = q[3 * (size_t)el[4 * b] + a];
            const double d0 = q[3 * (size_t)el[4 * b + 1] + a] - x0,
                         d1 = q[3 * (size_t)el[4 * b + 2] + a] - x0,
                         d2 = q[3 * (size_t)el[4 * b + 3] + a] - x0;
            for (int c = 0; c < 3; c++)
                blk->F[3 * a + c][b] = d0 * Di[c * ELASTIC_BLOCK + b] +
                                       d1 * Di[(3 + c) * ELASTIC_BLOCK + b] +
                                       d2 * Di[(6 + c) * ELASTIC_BLOCK + b];
        }
}

/* The fit, P and ψ of every lane (see above). */
ELASTIC_CLONES
static void block3_fit(block3_t *restrict blk, double mu, double lambda)
{
    double ok[ELASTIC_BLOCK], tol2[ELASTIC_BLOCK], settled[ELASTIC_BLOCK];
    double R[9][ELASTIC_BLOCK], S[9][ELASTIC_BLOCK];
    double f2[ELASTIC_BLOCK] = {0};
    for (int i = 0; i < 9; i++)
        for (int b = 0; b < ELASTIC_BLOCK; b++)
            f2[b] += blk->F[i][b] * blk->F[i][b];
    for (int b = 0; b < ELASTIC_BLOCK; b++) {
        tol2[b] = BG_ROTFIT_SKEW_TOL * BG_ROTFIT_SKEW_TOL * f2[b];
        const double det = blk->F[0][b] * (blk->F[4][b] * blk->F[8][b] - blk->F[5][b] * blk->F[7][b]) -
                           blk->F[1][b] * (blk->F[3][b] * blk->F[8][b] - blk->F[5][b] * blk->F[6][b]) +
                           blk->F[2][b] * (blk->F[3][b] * blk->F[7][b] - blk->F[4][b] * blk->F[6][b]);
        /* det F > ε s^{3/2}, s = ‖F‖²/3, as bg_rotfit3 asks, without the root */
        const double scale = f2[b] / 3.0;
        const double qn = blk->q[0][b] * blk->q[0][b] + blk->q[1][b] * blk->q[1][b] +
                          blk->q[2][b] * blk->q[2][b] + blk->q[3][b] * blk->q[3][b];
        ok[b] = (det > 0.0 &&
                 det * det > BG_ROTFIT_DET_EPS * BG_ROTFIT_DET_EPS * scale * scale * scale &&
                 qn > 0.5)
                    ? 1.0
                    : 0.0;
    }
    blk->moved = 0;
    for (int step = 0;; step++) {
        double done[ELASTIC_BLOCK];
        for (int b = 0; b < ELASTIC_BLOCK; b++) {
            double q[4], Rb[9], F[9], Sb[9];
            for (int i = 0; i < 4; i++)
                q[i] = blk->q[i][b];
            for (int i = 0; i < 9; i++)
                F[i] = blk->F[i][b];
            bg_quat_rotation(q, Rb);
            bg_mul_tn3(Rb, F, Sb);
            for (int i = 0; i < 9; i++) {
                R[i][b] = Rb[i];
                S[i][b] = Sb[i];
            }
            settled[b] = bg_rotfit_skew2(Sb) <= tol2[b] ? 1.0 : 0.0;
            done[b] = settled[b] != 0.0 || ok[b] == 0.0 ? 1.0 : 0.0;
        }
        int all = 1;
        for (int b = 0; b < ELASTIC_BLOCK; b++)
            all &= done[b] != 0.0;
        if (all || step == ELASTIC_BLOCK_STEPS)
            break;
        blk->moved = 1;
        for (int b = 0; b < ELASTIC_BLOCK; b++) {
            double q[4], Sb[9];
            for (int i = 0; i < 4; i++)
                q[i] = blk->q[i][b];
            for (int i = 0; i < 9; i++)
                Sb[i] = S[i][b];
            const int pd = bg_rotfit_step(Sb, q);
            ok[b] = pd || settled[b] != 0.0 ? ok[b] : 0.0;
            /* a settled lane keeps its rotation (its step is rounding) */
            for (int i = 0; i < 4; i++)
                blk->q[i][b] = settled[b] != 0.0 ? blk->q[i][b] : q[i];
        }
    }
    for (int b = 0; b < ELASTIC_BLOCK; b++) {
        double dev = 0.0;
        for (int i = 0; i < 9; i++) {
            const double d = blk->F[i][b] - R[i][b];
            dev += d * d;
        }
        const double vol = S[0][b] + S[4][b] + S[8][b] - 3.0;
        for (int i = 0; i < 9; i++)
            blk->P[i][b] = 2.0 * mu * (blk->F[i][b] - R[i][b]) + lambda * vol * R[i][b];
        blk->psi[b] = mu * dev + 0.5 * lambda * vol * vol;
        blk->ok[b] = settled[b] != 0.0 ? ok[b] : 0.0;
    }
}

/* Forces on nodes 1..3 of every lane: f_j = V P (row j of D_m⁻¹)ᵀ. */
ELASTIC_CLONES
static void block3_forces(block3_t *restrict blk, const double *restrict Di,
                          const double *restrict V)
{
    for (int j = 0; j < 3; j++)
        for (int a = 0; a < 3; a++)
            for (int b = 0; b < ELASTIC_BLOCK; b++)
                blk->f[3 * j + a][b] = (blk->P[3 * a][b] * Di[3 * j * ELASTIC_BLOCK + b] +
                                        blk->P[3 * a + 1][b] * Di[(3 * j + 1) * ELASTIC_BLOCK + b] +
                                        blk->P[3 * a + 2][b] * Di[(3 * j + 2) * ELASTIC_BLOCK + b]) *
                                       V[b];
}

/* V P D_m⁻ᵀ into the element's nodes (node 0 gets minus the sum). */
static void scatter_force(int n, const int32_t *el, const double *Di, double V, const double *P,
                          double *grad)
{
    double f0[3] = {0, 0, 0};
    for (int j = 0; j < n; j++)
        for (int a = 0; a < n; a++) {
            double s = 0.0;
            for (int b = 0; b < n; b++)
                s += P[a * n + b] * Di[j * n + b];
            s *= V;
            grad[(size_t)el[j + 1] * n + a] += s;
            f0[a] += s;
        }
    for (int a = 0; a < n; a++)
        grad[(size_t)el[0] * n + a] -= f0[a];
}

static double eval3(bg_elastic_t *md, const double *restrict q, double *restrict grad)
{
    const bg_mesh_t *mesh = md->mesh;
    double energy = 0.0;
    block3_t blk;
    for (int32_t e0 = 0; e0 < mesh->ne; e0 += ELASTIC_BLOCK) {
        const int count = mesh->ne - e0 < ELASTIC_BLOCK ? (int)(mesh->ne - e0) : ELASTIC_BLOCK;
        const size_t block = (size_t)e0 / ELASTIC_BLOCK;
        const double *Di = md->dminv + block * 9 * ELASTIC_BLOCK;
        double *quat = md->quat + block * 4 * ELASTIC_BLOCK;
        const int32_t *el = md->nodes + (size_t)e0 * 4;
        memcpy(blk.q, quat, sizeof blk.q);
        block3_gradient(&blk, el, q, Di);
        block3_fit(&blk, md->mu, md->lambda);
        int warm = 0;
        for (int b = 0; b < count; b++) {
            if (blk.ok[b] != 0.0) {
                warm++;
                continue;
            }
            /* the scalar path, from the lane's stored warm start */
            double F[9], R[9], P[9], qs[4];
            int path;
            for (int i = 0; i < 9; i++)
                F[i] = blk.F[i][b];
            for (int i = 0; i < 4; i++)
                qs[i] = quat[i * ELASTIC_BLOCK + b];
            blk.psi[b] = material_point(3, md->mu, md->lambda, F, qs, R, P, NULL, 0, &path);
            for (int i = 0; i < 4; i++)
                blk.q[i][b] = qs[i];
            for (int i = 0; i < 9; i++)
                blk.P[i][b] = P[i];
            bg_rotfit_stats_count(&md->stats, (bg_rotfit_path)path);
        }
        md->stats.calls += warm;
        md->stats.warm += warm;
        /* Settled blocks (later iterations near a solution, repeated
         * evaluations) leave their rotations' cache lines clean: 64 bytes
         * per element not written back. */
        if (blk.moved || warm < count)
            for (int i = 0; i < 4; i++)
                for (int b = 0; b < count; b++)
                    quat[i * ELASTIC_BLOCK + b] = blk.q[i][b];
        for (int b = 0; b < count; b++) {
            md->psi[md->order[e0 + b]] = blk.psi[b];
            energy += md->volume[e0 + b] * blk.psi[b];
        }
        if (!grad)
            continue;
        block3_forces(&blk, Di, md->volume + e0);
        for (int b = 0; b < count; b++) {
            const int32_t *nodes = el + 4 * b;
            double f0[3] = {0, 0, 0};
            for (int j = 0; j < 3; j++) {
                double *gj = grad + (size_t)nodes[j + 1] * 3;
                for (int a = 0; a < 3; a++) {
                    gj[a] += blk.f[3 * j + a][b];
                    f0[a] += blk.f[3 * j + a][b];
                }
            }
            double *g0 = grad + (size_t)nodes[0] * 3;
            for (int a = 0; a < 3; a++)
                g0[a] -= f0[a];
        }
    }
    return energy;
}

double bg_elastic_eval(bg_elastic_t *md, const double *restrict q, double *restrict grad)
{
    const int n = md->n, k = n + 1;
    const bg_mesh_t *mesh = md->mesh;
    if (grad)
        memset(grad, 0, (size_t)mesh->nv * (size_t)n * sizeof *grad);
    if (n == 3)
        return eval3(md, q, grad);
    double energy = 0.0;
    double zero_quat[4];
    for (int32_t p = 0; p < mesh->ne; p++) {
        const int32_t *el = md->nodes + (size_t)p * k;
        double Di[9], F[9], R[9], P[9];
        elastic_dminv(md, (size_t)p, Di);
        deformation_gradient(n, el, q, Di, F);
        int path;
        double psi = material_point(n, md->mu, md->lambda, F, zero_quat, R,
                                    grad ? P : NULL, NULL, 0, &path);
        if (md->barrier > 0.0)
            psi += barrier_point(md->barrier, F, grad ? P : NULL, NULL, 0);
        bg_rotfit_stats_count(&md->stats, (bg_rotfit_path)path);
        md->psi[md->order[p]] = psi;
        energy += md->volume[p] * psi;
        if (grad)
            scatter_force(n, el, Di, md->volume[p], P, grad);
    }
    return energy;
}

/* Barycentric gradients g[node][b]: rows of D_m⁻¹ for nodes 1..n, and
 * minus their sum for node 0, so that F_ab = Σ_node q_node,a g[node][b]. */
static void barycentric_gradients(int n, const double *Di, double g[4][3])
{
    for (int b = 0; b < n; b++) {
        g[0][b] = 0.0;
        for (int j = 0; j < n; j++) {
            g[j + 1][b] = Di[j * n + b];
            g[0][b] -= Di[j * n + b];
        }
    }
}

/*
 * K_e = V Bᵀ (2μ I₉ + G A Gᵀ + λ vec R vec Rᵀ) B without forming ∂P/∂F:
 * Bᵀ vec(M) for node i is M g_i, so Bᵀ vec(R) is h_i = R g_i, and the
 * twist columns are R[e_k]× g_i = r_k × h_i (r_k the k-th column of R; a
 * rotation preserves cross products). Then
 *   K[(i,c),(j,d)] = V (2μ δ_cd g_i·g_j + Σ_kl BG_(i,c)k A_kl BG_(j,d)l + λ h_ic h_jd).
 *
 * Like the evaluation, the assembly runs on blocks of ELASTIC_BLOCK
 * elements across vector lanes: F, the rotations, the twist blocks and the
 * 78 packed entries of every K_e, then the entries are added into the
 * pattern lane by lane. The rotations are the ones the last evaluation
 * fitted at these positions (the contract: assemble after bg_elastic_eval
 * at the same q). Lanes whose stored rotation is not settled at q (a
 * rejected trial point's rotations: after a rejected chord step, most of
 * the mesh, 20,161 of the bunny's 25,539 tets) are fitted again as
 * bg_elastic_eval would fit them: the block's vectorised fit, then the
 * scalar bg_rotfit3 from the stored rotation for the lanes it leaves
 * (inverted or flat elements: the SVD's rotation). The scalar fit of
 * every unsettled lane, as this was, cost 20,161 polar iterations in
 * each such assembly. The
 * twist block's closed form covers every lane whose shifted M is safely
 * positive definite; the others take the scalar eigen-decomposition.
 */
#define ELASTIC_TRI3 BG_ELASTIC_TRI_SIZE(12)

typedef struct hess3 {
    double R[9][ELASTIC_BLOCK];
    double S[9][ELASTIC_BLOCK];
    double A[9][ELASTIC_BLOCK];
    double ok[ELASTIC_BLOCK];
    double K[ELASTIC_TRI3][ELASTIC_BLOCK]; /* V·scale·(packed upper triangle of K_e) */
} hess3_t;

/* The block's rotations from its stored quaternions (blk->q) and S = Rᵀ F;
 * ok when the rotation is settled at F and det F > ε (see above). */
ELASTIC_CLONES
static void block3_rotations(const block3_t *restrict blk, hess3_t *restrict h)
{
    for (int b = 0; b < ELASTIC_BLOCK; b++) {
        double q[4], R[9], F[9], S[9], f2 = 0.0;
        for (int i = 0; i < 4; i++)
            q[i] = blk->q[i][b];
        for (int i = 0; i < 9; i++) {
            F[i] = blk->F[i][b];
            f2 += F[i] * F[i];
        }
        bg_quat_rotation(q, R);
        bg_mul_tn3(R, F, S);
        const double det = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
                           F[2] * (F[3] * F[7] - F[4] * F[6]);
        const double scale = f2 / 3.0;
        const int safe = det > 0.0 &&
                         det * det > BG_ROTFIT_DET_EPS * BG_ROTFIT_DET_EPS * scale * scale * scale;
        const int settled = bg_rotfit_skew2(S) <= BG_ROTFIT_SKEW_TOL * BG_ROTFIT_SKEW_TOL * f2;
        h->ok[b] = safe && settled ? 1.0 : 0.0;
        for (int i = 0; i < 9; i++) {
            h->R[i][b] = R[i];
            h->S[i][b] = S[i];
        }
    }
}

/* twist_block3's closed form across the lanes; ok cleared where it does
 * not apply (the lane takes the scalar twist_block3). */
ELASTIC_CLONES
static void block3_twist(hess3_t *restrict h, double mu, double lambda, int project)
{
    for (int b = 0; b < ELASTIC_BLOCK; b++) {
        const double trY = h->S[0][b] + h->S[4][b] + h->S[8][b];
        double M[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                M[3 * i + j] = (i == j ? trY : 0.0) - 0.5 * (h->S[3 * i + j][b] + h->S[3 * j + i][b]);
        const double c = lambda * (trY - 3.0) - 2.0 * mu;
        const double floor_ = ELASTIC_PAIR_SUM_FLOOR * (fabs(trY) > 1.0 ? fabs(trY) : 1.0);
        /* fmax(floor_, −c/μ) as a select: fmax is a libm call the vectoriser
         * does not take (the same value) */
        const double cm = -c / mu;
        const double theta = project && c < 0.0 && cm > floor_ ? cm : floor_;
        const int pd = pd3_shifted(M, theta);
        const double c00 = M[4] * M[8] - M[5] * M[7], c01 = M[2] * M[7] - M[1] * M[8],
                     c02 = M[1] * M[5] - M[2] * M[4], c11 = M[0] * M[8] - M[2] * M[6],
                     c12 = M[2] * M[3] - M[0] * M[5], c22 = M[0] * M[4] - M[1] * M[3];
        const double det = M[0] * c00 + M[1] * c01 + M[2] * c02;
        const double f = c / (pd ? det : 1.0);
        h->A[0][b] = f * c00, h->A[1][b] = f * c01, h->A[2][b] = f * c02;
        h->A[3][b] = f * c01, h->A[4][b] = f * c11, h->A[5][b] = f * c12;
        h->A[6][b] = f * c02, h->A[7][b] = f * c12, h->A[8][b] = f * c22;
        h->ok[b] = pd ? h->ok[b] : 0.0;
    }
}

/*
 * twist_block3's other branch, for the lanes block3_twist left (ok = 0):
 * the eigen-decomposition of sym(S) in closed form (sym3_eigen_closed,
 * the same arithmetic as the scalar branch, so the same bits), the pair
 * sums floored and, when projecting, the twist eigenvalues clamped,
 * A = V diag(a) Vᵀ. In the projected Hessian of a bent or compressed
 * body this is most elements (any pair sum σi + σj below −c/μ ≈ 2 sends
 * a lane here: 18,097 of bunny-edit's 25,539), so it runs on every lane
 * of the block (the closed form has no data-dependent loop; lanes with
 * ok set keep their A) and vectorises.
 */
ELASTIC_CLONES
static void block3_twist_eigen(hess3_t *restrict h, double mu, double lambda, int project)
{
    for (int b = 0; b < ELASTIC_BLOCK; b++) {
        const double trY = h->S[0][b] + h->S[4][b] + h->S[8][b];
        const double c = lambda * (trY - 3.0) - 2.0 * mu;
        /* (fmax is a libm call the vectoriser does not take; the same value) */
        const double floor_ = ELASTIC_PAIR_SUM_FLOOR * (fabs(trY) > 1.0 ? fabs(trY) : 1.0);
        double y[3], Q[9], w[3];
        sym3_eigen_closed(h->S[0][b], 0.5 * (h->S[1][b] + h->S[3][b]),
                          0.5 * (h->S[2][b] + h->S[6][b]), h->S[4][b],
                          0.5 * (h->S[5][b] + h->S[7][b]), h->S[8][b], y, Q);
        for (int k = 0; k < 3; k++)
            w[k] = twist_weight(mu, c, trY - y[k], floor_, project);
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                const double v = Q[3 * i] * w[0] * Q[3 * j] + Q[3 * i + 1] * w[1] * Q[3 * j + 1] +
                                 Q[3 * i + 2] * w[2] * Q[3 * j + 2];
                h->A[3 * i + j][b] = h->ok[b] == 0.0 ? v : h->A[3 * i + j][b];
            }
    }
}

/* A block's lanes as one vector: GCC's and clang's vector extension
 * (each target_clones clone maps it to its own registers). Used where the
 * vectoriser gives up on the lane loops (78 entries of twelve small
 * products each). Loads and stores through memcpy: no alignment assumed. */
typedef double lanes_t __attribute__((vector_size(ELASTIC_BLOCK * sizeof(double))));
/* (a macro, not a function: a vector passed by value would change the ABI
 * between the clones and the baseline) */
#define LANES_LOAD(v, p) memcpy(&(v), (p), sizeof(lanes_t))

/* The 78 packed entries of every lane's K_e, times V·scale (V: the
 * block's volumes, Di its D_m⁻¹), from R and A; the same products in the
 * same order as one element at a time. */
ELASTIC_CLONES
static void block3_stiffness(hess3_t *restrict h, const double *restrict Di,
                             const double *restrict V, double scale, double mu, double lambda)
{
    const lanes_t zero = {0.0};
    lanes_t g[4][3], R[9], A[9], hv[12], BG[12][3], BA[12][3], w;
    for (int i = 0; i < 9; i++) {
        LANES_LOAD(R[i], h->R[i]);
        LANES_LOAD(A[i], h->A[i]);
    }
    for (int c = 0; c < 3; c++) {
        g[0][c] = zero;
        for (int j = 0; j < 3; j++) {
            LANES_LOAD(g[j + 1][c], Di + (3 * j + c) * ELASTIC_BLOCK);
            g[0][c] -= g[j + 1][c];
        }
    }
    for (int i = 0; i < 4; i++) {
        for (int c = 0; c < 3; c++)
            hv[3 * i + c] = R[3 * c] * g[i][0] + R[3 * c + 1] * g[i][1] + R[3 * c + 2] * g[i][2];
        for (int k = 0; k < 3; k++) {
            const lanes_t r0 = R[k], r1 = R[3 + k], r2 = R[6 + k];
            BG[3 * i + 0][k] = r1 * hv[3 * i + 2] - r2 * hv[3 * i + 1];
            BG[3 * i + 1][k] = r2 * hv[3 * i] - r0 * hv[3 * i + 2];
            BG[3 * i + 2][k] = r0 * hv[3 * i + 1] - r1 * hv[3 * i];
        }
    }
    for (int a = 0; a < 12; a++)
        for (int l = 0; l < 3; l++)
            BA[a][l] = BG[a][0] * A[l] + BG[a][1] * A[3 + l] + BG[a][2] * A[6 + l];
    LANES_LOAD(w, V);
    w *= scale;
    const double two_mu = 2.0 * mu;
    int t = 0;
    for (int a = 0; a < 12; a++)
        for (int bb = a; bb < 12; bb++, t++) {
            lanes_t v = BA[a][0] * BG[bb][0] + BA[a][1] * BG[bb][1] + BA[a][2] * BG[bb][2] +
                        lambda * hv[a] * hv[bb];
            if (a % 3 == bb % 3) {
                const int i = a / 3, j = bb / 3;
                v += two_mu * (g[i][0] * g[j][0] + g[i][1] * g[j][1] + g[i][2] * g[j][2]);
            }
            v = w * v;
            memcpy(h->K[t], &v, sizeof v);
        }
}

/* Lane b's K_e (h->K) into values through its vertex-block record bl
 * (bg_elastic_tet_blocks_t): each block column is three adjacent values
 * (fewer on a diagonal block). Every entry is added once, so the values
 * equal the entry scatter's whatever order the entries go in. */
static inline __attribute__((always_inline)) void
add_blocks(const hess3_t *restrict h, int b, const bg_elastic_tet_blocks_t *restrict bl,
           double *restrict values)
{
#pragma GCC unroll 4
    for (int i = 0; i < 4; i++) {
        const int32_t pd = bl->pos[BG_ELASTIC_BLOCK_INDEX(i, i)];
        if (pd >= 0) {
            const int32_t s = bl->stride[i];
#pragma GCC unroll 3
            for (int c = 0; c < 3; c++) {
                double *restrict col = values + pd + c * s - c * (c - 1) / 2;
                for (int d = c; d < 3; d++)
                    col[d] += h->K[BG_ELASTIC_TRI_INDEX(12, 3 * i + c, 3 * i + d)][b];
            }
        }
#pragma GCC unroll 3
        for (int j = i + 1; j < 4; j++) {
            const int k = BG_ELASTIC_BLOCK_INDEX(i, j);
            const int32_t p = bl->pos[k];
            if (p < 0)
                continue;
            if ((bl->transposed >> k) & 1u) {
                /* column vertex j: its column c holds K_e's (i, d), (j, c) */
                const int32_t s = bl->stride[j];
    #pragma GCC unroll 3
            for (int c = 0; c < 3; c++) {
                    double *restrict col = values + p + c * s - c * (c - 1) / 2;
                    for (int d = 0; d < 3; d++)
                        col[d] += h->K[BG_ELASTIC_TRI_INDEX(12, 3 * i + d, 3 * j + c)][b];
                }
            } else {
                const int32_t s = bl->stride[i];
    #pragma GCC unroll 3
            for (int c = 0; c < 3; c++) {
                    double *restrict col = values + p + c * s - c * (c - 1) / 2;
                    for (int d = 0; d < 3; d++)
                        col[d] += h->K[BG_ELASTIC_TRI_INDEX(12, 3 * i + c, 3 * j + d)][b];
                }
            }
        }
    }
}

/* The 3D assembly; the entries go in through the entry scatter map or,
 * when blocks is not NULL, through the vertex-block map in the model's
 * order (the entry map for the elements it marks). */
static void assemble3(const bg_elastic_t *md, const double *q, int project, double scale,
                      const int32_t *restrict scatter, const bg_elastic_tet_blocks_t *blocks,
                      double *restrict values)
{
    const bg_mesh_t *mesh = md->mesh;
    block3_t blk;
    hess3_t h;
    for (int32_t e0 = 0; e0 < mesh->ne; e0 += ELASTIC_BLOCK) {
        const int count = mesh->ne - e0 < ELASTIC_BLOCK ? (int)(mesh->ne - e0) : ELASTIC_BLOCK;
        const size_t block = (size_t)e0 / ELASTIC_BLOCK;
        const double *Di = md->dminv + block * 9 * ELASTIC_BLOCK;
        const double *quat = md->quat + block * 4 * ELASTIC_BLOCK;
        memcpy(blk.q, quat, sizeof blk.q);
        block3_gradient(&blk, md->nodes + (size_t)e0 * 4, q, Di);
        block3_rotations(&blk, &h);
        int unsettled = 0;
        for (int b = 0; b < count; b++)
            unsettled |= h.ok[b] == 0.0;
        if (unsettled) {
            /* Rotations fitted elsewhere (a rejected trial point's, after
             * a chord step: most of the mesh) are fitted again as
             * bg_elastic_eval would fit them at q: the vectorised fit
             * from them, then the scalar fit, from the stored rotation,
             * for the lanes it leaves. Settled lanes are not stepped. */
            block3_fit(&blk, md->mu, md->lambda);
            block3_rotations(&blk, &h);
        }
        for (int b = 0; b < count; b++) {
            if (h.ok[b] != 0.0)
                continue;
            double F[9], R[9], S[9], qs[4];
            for (int i = 0; i < 9; i++)
                F[i] = blk.F[i][b];
            for (int i = 0; i < 4; i++)
                qs[i] = quat[i * ELASTIC_BLOCK + b];
            bg_rotfit3(F, qs, R);
            bg_mul_tn3(R, F, S);
            for (int i = 0; i < 9; i++) {
                h.R[i][b] = R[i];
                h.S[i][b] = S[i];
            }
            h.ok[b] = 1.0;
        }
        block3_twist(&h, md->mu, md->lambda, project);
        int rest = 0;
        for (int b = 0; b < count; b++)
            rest |= h.ok[b] == 0.0;
        if (rest)
            block3_twist_eigen(&h, md->mu, md->lambda, project);
        /* The next block's map rows (entry map: by mesh element, so
         * scattered in curve order) or the values its block records point
         * at (in the factor's order): ask for them early. */
        for (int b = 0; b < ELASTIC_BLOCK && e0 + ELASTIC_BLOCK + b < mesh->ne; b++) {
            const size_t next = (size_t)md->order[e0 + ELASTIC_BLOCK + b];
            if (blocks && !blocks[e0 + ELASTIC_BLOCK + b].entries) {
                const bg_elastic_tet_blocks_t *bl = blocks + e0 + ELASTIC_BLOCK + b;
                for (int k = 0; k < 10; k++)
                    if (bl->pos[k] >= 0)
                        __builtin_prefetch(values + bl->pos[k], 1);
                continue;
            }
            const char *row = (const char *)(scatter + next * ELASTIC_TRI3);
            for (size_t off = 0; off < ELASTIC_TRI3 * sizeof *scatter; off += 64)
                __builtin_prefetch(row + off);
        }
        block3_stiffness(&h, Di, md->volume + e0, scale, md->mu, md->lambda);
        for (int b = 0; b < count; b++) {
            const size_t e = (size_t)md->order[e0 + b];
            if (blocks && !blocks[e0 + b].entries) {
                add_blocks(&h, b, blocks + e0 + b, values);
                continue;
            }
            const int32_t *sc = scatter + e * ELASTIC_TRI3;
            for (int t = 0; t < ELASTIC_TRI3; t++)
                if (sc[t] >= 0)
                    values[sc[t]] += h.K[t][b];
        }
    }
}

void bg_elastic_assemble_hessian_blocks(const bg_elastic_t *md, const double *q, int project,
                                        double scale, const bg_elastic_tet_blocks_t *blocks,
                                        const int32_t *scatter, double *values)
{
    if (md->n == 3)
        assemble3(md, q, project, scale, scatter, blocks, values);
}

void bg_elastic_assemble_hessian(const bg_elastic_t *md, const double *q, int project,
                                 double scale, const int32_t *restrict scatter,
                                 double *restrict values)
{
    const int n = md->n, k = n + 1, m = md->m, nn = n * n, T = BG_ELASTIC_TRI_SIZE(m);
    const bg_mesh_t *mesh = md->mesh;
    if (n == 3) {
        assemble3(md, q, project, scale, scatter, NULL, values);
        return;
    }
    for (int32_t p = 0; p < mesh->ne; p++) {
        const int32_t *el = md->nodes + (size_t)p * k;
        double Di[9], F[9], R[9], H[81], g[4][3];
        double quat[4] = {0, 0, 0, 0}; /* 2D: unused */
        elastic_dminv(md, (size_t)p, Di);
        deformation_gradient(n, el, q, Di, F);
        int path;
        material_point(n, md->mu, md->lambda, F, quat, R, NULL, H, project, &path);
        if (md->barrier > 0.0)
            barrier_point(md->barrier, F, NULL, H, project);
        barycentric_gradients(n, Di, g);
        /* HB[(c,b)][(j,d)] = Σ_e' H[(c,b),(d,e')] g[j][e'], then
         * K[(i,c),(j,d)] = V Σ_b g[i][b] HB[(c,b)][(j,d)]. */
        double HB[9][BG_ELASTIC_MAX_LOCAL];
        for (int r = 0; r < nn; r++)
            for (int j = 0; j < k; j++)
                for (int d = 0; d < n; d++) {
                    double s = 0.0;
                    for (int ep = 0; ep < n; ep++)
                        s += H[r * nn + d * n + ep] * g[j][ep];
                    HB[r][j * n + d] = s;
                }
        const double w = scale * md->volume[p];
        const int32_t *sc = scatter + (size_t)md->order[p] * T;
        for (int a = 0; a < m; a++) {
            const int i = a / n, c = a % n;
            for (int bcol = a; bcol < m; bcol++) {
                const int32_t pos = sc[BG_ELASTIC_TRI_INDEX(m, a, bcol)];
                if (pos < 0)
                    continue;
                double s = 0.0;
                for (int b = 0; b < n; b++)
                    s += g[i][b] * HB[c * n + b][bcol];
                values[pos] += w * s;
            }
        }
    }
}

/*
 * Σ of |terms| behind each gradient entry: per element the entries of
 * |P|ₐ = 2μ(|F|ₐ + |R|) + |λ|(|R|·|F|ₐ + n)|R| (+ the barrier's |terms|),
 * |F|ₐ = Σ_j |q_j − q_0||D_m⁻¹| the magnitudes F is computed from,
 * times |D_m⁻ᵀ|, scaled by V, summed in absolute value per vertex. The
 * round-off of a computed gradient entry is a small multiple of ε times
 * this (the cancellation inside tr Y − n and across elements is what a
 * gradient at its floor is made of). Uses copies of the warm-start
 * rotations, so the model's state is unchanged.
 */
void bg_elastic_force_magnitude(const bg_elastic_t *md, const double *q, double scale,
                                double *mag)
{
    const int n = md->n, k = n + 1, nn = n * n;
    const bg_mesh_t *mesh = md->mesh;
    for (int32_t p = 0; p < mesh->ne; p++) {
        const int32_t *el = md->nodes + (size_t)p * k;
        double Di[9], F[9], R[9], P[9], quat[4] = {0, 0, 0, 0}, g[4][3];
        elastic_dminv(md, (size_t)p, Di);
        if (n == 3)
            quat_load(md, (size_t)p, quat);
        deformation_gradient(n, el, q, Di, F);
        int path;
        material_point(n, md->mu, md->lambda, F, quat, R, NULL, NULL, 0, &path);
        /* The edge differences q_j − q_0 of nearby vertices are exact
         * (Sterbenz), so F's entries carry the round-off of the products
         * that form them: |F|ₐ = |d||D_m⁻¹|. */
        double Fm[9], trY = 0.0;
        for (int a = 0; a < n; a++)
            for (int b = 0; b < n; b++) {
                double m = 0.0;
                for (int j = 0; j < n; j++)
                    m += fabs(q[(size_t)el[j + 1] * n + a] - q[(size_t)el[0] * n + a]) *
                         fabs(Di[j * n + b]);
                Fm[a * n + b] = m;
                trY += fabs(R[a * n + b]) * m;
            }
        for (int i = 0; i < nn; i++)
            P[i] = 2.0 * md->mu * (Fm[i] + fabs(R[i])) + fabs(md->lambda) * (trY + n) * fabs(R[i]);
        if (md->barrier > 0.0) {
            double Pb[4] = {0, 0, 0, 0};
            barrier_point(md->barrier, F, Pb, NULL, 0);
            for (int i = 0; i < 4; i++)
                P[i] += fabs(Pb[i]);
        }
        barycentric_gradients(n, Di, g);
        const double w = scale * md->volume[p];
        for (int i = 0; i < k; i++)
            for (int a = 0; a < n; a++) {
                double s = 0.0;
                for (int b = 0; b < n; b++)
                    s += P[a * n + b] * fabs(g[i][b]);
                mag[(size_t)el[i] * n + a] += w * s;
            }
    }
}

void bg_elastic_apply_laplacian(const bg_elastic_t *md, const double *restrict u,
                                double *restrict out)
{
    const int n = md->n, k = n + 1;
    const bg_mesh_t *mesh = md->mesh;
    memset(out, 0, (size_t)mesh->nv * n * sizeof *out);
    for (int32_t p = 0; p < mesh->ne; p++) {
        const int32_t *el = md->nodes + (size_t)p * k;
        double Di[9], g[4][3];
        elastic_dminv(md, (size_t)p, Di);
        barycentric_gradients(n, Di, g);
        for (int i = 0; i < k; i++)
            for (int j = 0; j < k; j++) {
                double s = 0.0;
                for (int b = 0; b < n; b++)
                    s += g[i][b] * g[j][b];
                s *= md->volume[p];
                for (int c = 0; c < n; c++)
                    out[(size_t)el[i] * n + c] += s * u[(size_t)el[j] * n + c];
            }
    }
}

void bg_elastic_assemble_scalar_laplacian(const bg_elastic_t *md, double scale,
                                          const int32_t *restrict scatter, double *restrict values)
{
    const int n = md->n, k = n + 1, T = BG_ELASTIC_TRI_SIZE(k);
    for (int32_t p = 0; p < md->mesh->ne; p++) {
        double Di[9], g[4][3];
        elastic_dminv(md, (size_t)p, Di);
        barycentric_gradients(n, Di, g);
        const double w = scale * md->volume[p];
        const int32_t *sc = scatter + (size_t)md->order[p] * T;
        for (int i = 0; i < k; i++)
            for (int j = i; j < k; j++) {
                const int32_t pos = sc[BG_ELASTIC_TRI_INDEX(k, i, j)];
                if (pos < 0)
                    continue;
                double s = 0.0;
                for (int b = 0; b < n; b++)
                    s += g[i][b] * g[j][b];
                values[pos] += w * s;
            }
    }
}
