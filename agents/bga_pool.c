#include "bga_pool.h"

#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"

typedef struct part {
    bga_client_t *client;
    uint64_t job;   /* the partition's job id on its agent */
    int32_t r0, r1; /* its element range (a surface: its vertex range) */
    int32_t nv, ne, nval;
    int32_t *local_to_global; /* nv */
    int32_t *to_global;       /* nval: global value position of each local value */
    double *q, *grad, *hess;
    /* The current call: answered (its results in grad, hess and energy),
     * or failed with status st. */
    int answered;
    int posted; /* its set-up is sent and its answer not yet read (pool creation) */
    bg_status st;
    bg_error_t e;
    double energy;
} part;

struct bga_rotfit_pool {
    int n, dim, has_hessian, surface;
    size_t ndof;
    part *parts;
    unsigned want; /* the current call's */
    int ping_ms, lost_ms;
    double gather_seconds;
};

static void part_free(part *p)
{
    free(p->local_to_global);
    free(p->to_global);
    free(p->q);
    free(p->grad);
    free(p->hess);
    p->local_to_global = p->to_global = NULL;
    p->q = p->grad = p->hess = NULL;
    p->nv = p->ne = p->nval = 0;
}

/* Elements [e0, e1) of mesh as a partition: local vertices in order of
 * first use; its Hessian entries compacted likewise. */
static bg_status make_part(const bga_pool_config_t *cfg, int32_t e0, int32_t e1, part *p,
                           bga_partition_t *bp, int32_t **elements, int32_t **scatter,
                           double **rest, bg_error_t *err)
{
    const bg_mesh_t *mesh = cfg->mesh;
    const int k = mesh->nodes_per_element, dim = mesh->dim, local = k * dim;
    const int T = local * (local + 1) / 2;
    bg_status st = BG_OK;
    int32_t *g2l = malloc((size_t)mesh->nv * sizeof *g2l);
    int32_t *v2l = cfg->scatter ? malloc(cfg->nval * sizeof *v2l + 1) : NULL;
    p->ne = e1 - e0;
    *elements = malloc((size_t)p->ne * k * sizeof **elements + 1);
    p->local_to_global = malloc((size_t)p->ne * k * sizeof *p->local_to_global + 1);
    *scatter = cfg->scatter ? malloc((size_t)p->ne * T * sizeof **scatter + 1) : NULL;
    p->to_global = cfg->scatter ? malloc((size_t)p->ne * T * sizeof *p->to_global + 1) : NULL;
    if (!g2l || !*elements || !p->local_to_global ||
        (cfg->scatter && (!v2l || !*scatter || !p->to_global))) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory partitioning %d elements", (int)p->ne);
        goto out;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        g2l[v] = -1;
    for (int32_t e = e0; e < e1; e++)
        for (int i = 0; i < k; i++) {
            const int32_t g = mesh->elements[(size_t)e * k + i];
            if (g2l[g] < 0) {
                g2l[g] = p->nv;
                p->local_to_global[p->nv++] = g;
            }
            (*elements)[(size_t)(e - e0) * k + i] = g2l[g];
        }
    if (cfg->scatter) {
        for (size_t i = 0; i < cfg->nval; i++)
            v2l[i] = -1;
        for (int32_t e = e0; e < e1; e++)
            for (int t = 0; t < T; t++) {
                const int32_t g = cfg->scatter[(size_t)e * T + t];
                int32_t l = -1;
                if (g >= 0) {
                    if (v2l[g] < 0) {
                        v2l[g] = p->nval;
                        p->to_global[p->nval++] = g;
                    }
                    l = v2l[g];
                }
                (*scatter)[(size_t)(e - e0) * T + t] = l;
            }
    }
    const size_t ndof = (size_t)p->nv * dim;
    const size_t nrest = cfg->rest_edges ? (size_t)p->ne * dim * dim : ndof;
    *rest = malloc(nrest * sizeof **rest + 1);
    p->q = malloc(ndof * sizeof *p->q + 1);
    p->grad = malloc(ndof * sizeof *p->grad + 1);
    p->hess = malloc((size_t)p->nval * sizeof *p->hess + 1);
    if (!*rest || !p->q || !p->grad || !p->hess) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for a partition of %d vertices",
                          (int)p->nv);
        goto out;
    }
    if (cfg->rest_edges)
        memcpy(*rest, cfg->rest_edges + (size_t)e0 * dim * dim, nrest * sizeof **rest);
    else
        for (int32_t v = 0; v < p->nv; v++)
            memcpy(*rest + (size_t)v * dim, mesh->x + (size_t)p->local_to_global[v] * dim,
                   (size_t)dim * sizeof **rest);
    memset(bp, 0, sizeof *bp);
    bp->dim = dim;
    bp->nv = p->nv;
    bp->ne = p->ne;
    bp->nglobal = mesh->nv;
    bp->elements = *elements;
    bp->local_to_global = p->local_to_global;
    bp->rest_positions = cfg->rest_edges ? NULL : *rest;
    bp->rest_edges = cfg->rest_edges ? *rest : NULL;
    bp->mu = cfg->mu;
    bp->lambda = cfg->lambda;
    bp->barrier = cfg->barrier;
    bp->nval = p->nval;
    bp->scatter = p->nval > 0 ? *scatter : NULL;
    bp->lease_ms = cfg->lease_ms;
out:
    free(g2l);
    free(v2l);
    return st;
}

/* Vertices [v0, v1) of a surface as a partition: the triangles around
 * them (in mesh order), local vertices in order of first use, and the
 * owned ones. Sets the partition up on p->client. */
static bg_status setup_surface_part(const bga_pool_config_t *cfg, int32_t v0, int32_t v1, part *p,
                                    bg_error_t *err)
{
    const bg_mesh_t *mesh = cfg->mesh;
    bg_status st = BG_OK;
    int32_t *g2l = malloc((size_t)mesh->nv * sizeof *g2l);
    int32_t *tris = malloc((size_t)mesh->ne * 3 * sizeof *tris + 1);
    int32_t *owned = malloc((size_t)(v1 - v0) * sizeof *owned + 1);
    double *rest = NULL;
    p->local_to_global = malloc((size_t)mesh->nv * sizeof *p->local_to_global + 1);
    if (!g2l || !tris || !owned || !p->local_to_global) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory partitioning %d vertices",
                          (int)(v1 - v0));
        goto out;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        g2l[v] = -1;
    int32_t nowned = 0;
    for (int32_t e = 0; e < mesh->ne; e++) {
        const int32_t *el = mesh->elements + 3 * (size_t)e;
        int in = 0;
        for (int c = 0; c < 3; c++)
            in |= el[c] >= v0 && el[c] < v1;
        if (!in)
            continue;
        for (int c = 0; c < 3; c++) {
            if (g2l[el[c]] < 0) {
                g2l[el[c]] = p->nv;
                p->local_to_global[p->nv++] = el[c];
            }
            tris[(size_t)p->ne * 3 + c] = g2l[el[c]];
        }
        p->ne++;
    }
    for (int32_t v = v0; v < v1; v++)
        if (g2l[v] >= 0) /* a vertex in no triangle has an empty cell */
            owned[nowned++] = g2l[v];
    const size_t ndof = (size_t)p->nv * 3;
    rest = malloc(ndof * sizeof *rest + 1);
    p->q = malloc(ndof * sizeof *p->q + 1);
    p->grad = malloc(ndof * sizeof *p->grad + 1);
    p->hess = malloc(sizeof *p->hess);
    if (!rest || !p->q || !p->grad || !p->hess) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for a partition of %d vertices",
                          (int)p->nv);
        goto out;
    }
    for (int32_t v = 0; v < p->nv; v++)
        memcpy(rest + (size_t)v * 3, mesh->x + (size_t)p->local_to_global[v] * 3,
               3 * sizeof *rest);
    if (p->ne == 0 || nowned == 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "vertices %d to %d lie in no triangle",
                          (int)v0, (int)v1 - 1);
        goto out;
    }
    const bga_surface_part_t sp = {p->nv, p->ne, mesh->nv, nowned, tris,
                                   p->local_to_global, rest, owned, cfg->lease_ms};
    st = bga_client_surface_setup(p->client, p->job, &sp, err);
out:
    free(g2l);
    free(tris);
    free(owned);
    free(rest);
    return st;
}

/* Part i's partition set up on its client (the pool's agent i): its
 * element range (or a surface's vertex range) cut from cfg's mesh. With
 * `wait` 0 a volume part's set-up is only sent (*posted = 1), and its
 * answer is awaited by bga_client_rotfit_setup_finish. */
static bg_status setup_part_start(const bga_pool_config_t *cfg, part *p, int wait, int *posted,
                                  bg_error_t *err)
{
    *posted = 0;
    if (cfg->surface)
        return setup_surface_part(cfg, p->r0, p->r1, p, err);
    int32_t *elements = NULL, *scatter = NULL;
    double *rest = NULL;
    bga_partition_t bp;
    bg_status st = make_part(cfg, p->r0, p->r1, p, &bp, &elements, &scatter, &rest, err);
    if (st == BG_OK)
        st = wait ? bga_client_rotfit_setup(p->client, p->job, &bp, err)
                  : bga_client_rotfit_setup_start(p->client, p->job, &bp, err);
    *posted = st == BG_OK && !wait;
    free(elements);
    free(scatter);
    free(rest);
    return st;
}

static bg_status setup_part(const bga_pool_config_t *cfg, part *p, bg_error_t *err)
{
    int posted;
    return setup_part_start(cfg, p, 1, &posted, err);
}

bg_status bga_rotfit_pool_new(const bga_pool_config_t *cfg, bga_rotfit_pool_t **out,
                              bg_error_t *err)
{
    const bg_status st =
        bga_rotfit_pool_new_live(cfg, BGA_CLIENT_PING_MS, BGA_CLIENT_LOST_MS, out, err);
    if (st != BG_OK)
        bga_rotfit_pool_destroy(out);
    return st;
}

bg_status bga_rotfit_pool_new_live(const bga_pool_config_t *cfg, int ping_ms, int lost_ms,
                                   bga_rotfit_pool_t **out, bg_error_t *err)
{
    *out = NULL;
    if (cfg->nagents < 1 || cfg->nagents > cfg->mesh->ne ||
        (cfg->surface && cfg->nagents > cfg->mesh->nv))
        return bg_error_set(err, BG_ERR_INVALID, "%d rotation-fit agents for %d elements",
                            cfg->nagents, (int)cfg->mesh->ne);
    bga_rotfit_pool_t *pool = calloc(1, sizeof *pool);
    if (!pool || !(pool->parts = calloc((size_t)cfg->nagents, sizeof *pool->parts))) {
        free(pool);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for a pool of %d agents",
                            cfg->nagents);
    }
    pool->n = cfg->nagents;
    pool->ping_ms = ping_ms;
    pool->lost_ms = lost_ms;
    pool->dim = cfg->mesh->dim;
    pool->ndof = (size_t)cfg->mesh->nv * (size_t)cfg->mesh->dim;
    pool->surface = cfg->surface;
    pool->has_hessian = cfg->scatter != NULL && !cfg->surface;
    const int32_t count = cfg->surface ? cfg->mesh->nv : cfg->mesh->ne;
    bg_status st = BG_OK;
    for (int i = 0; i < pool->n; i++) {
        part *p = &pool->parts[i];
        p->job = cfg->jobs ? cfg->jobs[i] : cfg->job;
        p->r0 = (int32_t)((int64_t)count * i / pool->n);
        p->r1 = (int32_t)((int64_t)count * (i + 1) / pool->n);
    }
    /* Every part is set up even after one failed, so that each has its
     * own status (a set-up its agent never answered is a lost part). The
     * set-ups are all sent before any answer is awaited: each agent builds
     * its model while the next partition is cut and sent. */
    for (int pass = 0; pass < 2; pass++)
        for (int i = 0; i < pool->n; i++) {
            part *p = &pool->parts[i];
            bg_error_t e = BG_ERROR_INIT;
            if (pass == 0) {
                p->st = bga_client_new_curve(cfg->endpoints[i], "rotation-fit", cfg->timeout_ms,
                                             cfg->curve, &p->client, &e);
                if (p->st == BG_OK) {
                    bga_client_set_liveness(p->client, ping_ms, lost_ms);
                    p->st = setup_part_start(cfg, p, 0, &p->posted, &e);
                }
            } else if (p->posted) {
                p->posted = 0;
                p->st = bga_client_rotfit_setup_finish(p->client, &e);
            } else {
                continue;
            }
            if (p->st != BG_OK) {
                p->e = e;
                if (st == BG_OK)
                    st = bg_error_set(err, p->st, "%s", e.message);
            }
        }
    *out = pool;
    return st;
}

bg_status bga_rotfit_pool_replace(bga_rotfit_pool_t *pool, int i, const bga_pool_config_t *cfg,
                                  const char *endpoint, uint64_t job, bga_client_t **given_up,
                                  bg_error_t *err)
{
    *given_up = NULL;
    if (i < 0 || i >= pool->n)
        return bg_error_set(err, BG_ERR_INVALID, "no partition %d in a pool of %d", i, pool->n);
    part *p = &pool->parts[i];
    bga_client_t *c = NULL;
    bg_status st = bga_client_new_curve(endpoint, "rotation-fit", cfg->timeout_ms, cfg->curve, &c, err);
    if (st != BG_OK)
        return st;
    bga_client_set_liveness(c, pool->ping_ms, pool->lost_ms);
    *given_up = p->client;
    p->client = c;
    p->job = job;
    p->answered = 0;
    part_free(p);
    bg_error_t e = BG_ERROR_INIT;
    st = setup_part(cfg, p, &e);
    p->st = st;
    p->e = e;
    return st == BG_OK ? BG_OK : bg_error_set(err, st, "%s", e.message);
}

bg_status bga_rotfit_pool_failure(const bga_rotfit_pool_t *pool, bg_error_t *err)
{
    for (int i = 0; i < pool->n; i++)
        if (pool->parts[i].st != BG_OK)
            return bg_error_set(err, pool->parts[i].st, "%s", pool->parts[i].e.message);
    return BG_OK;
}

static void pool_free(bga_rotfit_pool_t **ppool, int release)
{
    if (!ppool || !*ppool)
        return;
    bga_rotfit_pool_t *pool = *ppool;
    /* Every release is posted before any reply is awaited: the job's end
     * costs one round trip, not one per agent. Best effort: a job whose
     * release fails is freed by its lease. */
    int *posted = calloc((size_t)pool->n + 1, sizeof *posted);
    for (int i = 0; i < pool->n && release && posted; i++) {
        part *p = &pool->parts[i];
        bga_msg_t m;
        bga_msg_init(&m, BGA_RELEASE, p->job, 0);
        bg_error_t ignored = BG_ERROR_INIT;
        posted[i] = p->client && p->local_to_global && bga_client_post(p->client, &m, &ignored) == BG_OK;
    }
    for (int i = 0; i < pool->n; i++) {
        part *p = &pool->parts[i];
        bga_reply_t rep;
        bg_error_t ignored = BG_ERROR_INIT;
        if (posted && posted[i] && bga_client_collect(p->client, &rep, &ignored) == BG_OK)
            bga_reply_close(&rep);
        bga_client_destroy(&p->client);
        part_free(p);
    }
    free(posted);
    free(pool->parts);
    free(pool);
    *ppool = NULL;
}

void bga_rotfit_pool_destroy(bga_rotfit_pool_t **pool)
{
    pool_free(pool, 1);
}

void bga_rotfit_pool_abandon(bga_rotfit_pool_t **pool)
{
    pool_free(pool, 0);
}

/* Posts the current call to every part without an answer, then collects
 * each (every started request is collected, even after a failure, so no
 * client is left with a request in flight). The first failure goes to
 * err; each part keeps its own status. */
static bg_status run_parts(bga_rotfit_pool_t *pool, bg_error_t *err)
{
    bg_status st = BG_OK;
    const int dim = pool->dim;
    for (int i = 0; i < pool->n; i++) {
        part *p = &pool->parts[i];
        if (p->answered)
            continue;
        bg_error_t e = BG_ERROR_INIT;
        p->st = bga_client_rotfit_start(p->client, p->job, p->q, (size_t)p->nv * dim, pool->want,
                                        &e);
        if (p->st != BG_OK) {
            p->e = e;
            if (st == BG_OK)
                st = bg_error_set(err, p->st, "%s", e.message);
        }
    }
    for (int i = 0; i < pool->n; i++) {
        part *p = &pool->parts[i];
        if (p->answered || p->st != BG_OK)
            continue;
        bga_rotfit_out_t out = {
            0, p->grad, p->hess, (size_t)p->nv * dim, (size_t)p->nval, {0, 0, 0, 0}, 0};
        bg_error_t e = BG_ERROR_INIT;
        p->st = bga_client_rotfit_finish(p->client, &out, &e);
        if (p->st != BG_OK) {
            p->e = e;
            if (st == BG_OK)
                st = bg_error_set(err, p->st, "%s", e.message);
            continue;
        }
        p->answered = 1;
        p->energy = out.energy;
    }
    return st;
}

/* The parts' results summed in partition order (so they do not depend on
 * which agent answered first, or was replaced). */
static void combine(bga_rotfit_pool_t *pool, double *energy, double *grad, double *values)
{
    const double t0 = bg_clock_now();
    const int dim = pool->dim;
    double total = 0.0;
    if (grad)
        memset(grad, 0, pool->ndof * sizeof *grad); /* vertices in no element stay 0 */
    for (int i = 0; i < pool->n; i++) {
        const part *p = &pool->parts[i];
        total += p->energy;
        if (grad)
            for (int32_t v = 0; v < p->nv; v++)
                for (int c = 0; c < dim; c++)
                    grad[(size_t)p->local_to_global[v] * dim + c] += p->grad[(size_t)v * dim + c];
        if (values)
            for (int32_t l = 0; l < p->nval; l++)
                values[p->to_global[l]] += p->hess[l];
    }
    *energy = total;
    pool->gather_seconds += bg_clock_now() - t0;
}

/* The positions of q each part without an answer needs. */
static void scatter_q(bga_rotfit_pool_t *pool, const double *q)
{
    const int dim = pool->dim;
    for (int i = 0; i < pool->n; i++) {
        part *p = &pool->parts[i];
        if (p->answered)
            continue;
        for (int32_t v = 0; v < p->nv; v++)
            memcpy(p->q + (size_t)v * dim, q + (size_t)p->local_to_global[v] * dim,
                   (size_t)dim * sizeof *q);
    }
}

bg_status bga_rotfit_pool_eval(bga_rotfit_pool_t *pool, const double *q, double *energy,
                               double *grad, double *values, int project, bg_error_t *err)
{
    if (values && !pool->has_hessian)
        return bg_error_set(err, BG_ERR_INVALID,
                            "this rotation-fit pool has no Hessian "
                            "scatter map");
    pool->want = (grad ? BGA_WANT_GRADIENT : 0u) |
                 (values ? BGA_WANT_HESSIAN | (project ? BGA_WANT_PROJECTED : 0u) : 0u);
    for (int i = 0; i < pool->n; i++)
        pool->parts[i].answered = 0;
    scatter_q(pool, q);
    bg_status st = run_parts(pool, err);
    if (st == BG_OK)
        combine(pool, energy, grad, values);
    return st;
}

bg_status bga_rotfit_pool_resume(bga_rotfit_pool_t *pool, const double *q, double *energy,
                                 double *grad, double *values, bg_error_t *err)
{
    scatter_q(pool, q);
    bg_status st = run_parts(pool, err);
    if (st == BG_OK)
        combine(pool, energy, grad, values);
    return st;
}

int bga_rotfit_pool_lost_part(const bga_rotfit_pool_t *pool)
{
    for (int i = 0; i < pool->n; i++) {
        const part *p = &pool->parts[i];
        if (p->st == BG_ERR_NOT_FOUND ||
            (p->st != BG_OK && p->client && bga_client_failure(p->client) != BGA_CLIENT_FINE))
            return i;
    }
    return -1;
}

const char *bga_rotfit_pool_endpoint(const bga_rotfit_pool_t *pool, int agent)
{
    return bga_client_endpoint(pool->parts[agent].client);
}

int bga_rotfit_pool_size(const bga_rotfit_pool_t *pool)
{
    return pool->n;
}

bga_traffic_t bga_rotfit_pool_traffic(const bga_rotfit_pool_t *pool, int agent)
{
    return bga_client_traffic(pool->parts[agent].client);
}

int32_t bga_rotfit_pool_elements(const bga_rotfit_pool_t *pool, int agent)
{
    return pool->parts[agent].ne;
}

double bga_rotfit_pool_gather_seconds(const bga_rotfit_pool_t *pool)
{
    return pool->gather_seconds;
}
