#include "bga_service.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"
#include "bg_elastic.h"
#include "bg_mesh.h"
#include "bg_sparse.h"
#include "bg_step.h"
#include "bg_surface_cells.h"

/* One job's state on this agent; a slot is free when id == 0. */
typedef struct job {
    uint64_t id;
    double lease_seconds; /* 0: no expiry */
    double expires;
    /* rotation-fit */
    bg_mesh_t *mesh;
    bg_elastic_t *model;
    bg_surface_cells_t *cells; /* a surface partition instead of model (SURF_SETUP) */
    int32_t *scatter; /* ne*T into hess, identity when the set-up sent none */
    size_t nhess;
    double *q, *grad, *hess;
    double energy_fit; /* the energy of the last rotation fit (model partitions) */
    int fitted;        /* the model has been fitted (energy_fit holds its energy) */
    /* sparse-solve */
    bg_sparse_t *sys;
    int factored; /* the last factorization succeeded */
    double *x;
    /* integration step: the run's state (bg_step) and host copies of a
     * request's arrays (two position vectors) */
    bg_step_t *step;
    double *iin;
} job;

struct bga_service {
    bga_service_config_t config;
    char name[64];
    job *jobs;
    bga_service_stats_t stats;
};

static void free_rotfit(job *j)
{
    bg_surface_cells_destroy(&j->cells);
    bg_elastic_destroy(&j->model);
    bg_mesh_destroy(&j->mesh);
    free(j->scatter);
    free(j->q);
    free(j->grad);
    free(j->hess);
    j->scatter = NULL;
    j->q = j->grad = j->hess = NULL;
    j->nhess = 0;
    j->fitted = 0;
}

static void free_solve(job *j)
{
    bg_sparse_destroy(&j->sys);
    free(j->x);
    j->x = NULL;
    j->factored = 0;
}

static void free_integ(job *j)
{
    bg_step_destroy(&j->step);
    free(j->iin);
    j->iin = NULL;
}

static void free_job(job *j)
{
    free_rotfit(j);
    free_solve(j);
    free_integ(j);
    memset(j, 0, sizeof *j);
}

/* A job whose only set-up failed holds nothing: give its slot back. */
static void free_job_if_empty(job *j)
{
    if (!j->model && !j->cells && !j->sys && !j->step)
        free_job(j);
}

bg_status bga_service_new(const bga_service_config_t *config, bga_service_t **out, bg_error_t *err)
{
    *out = NULL;
    if (config->slots < 1 || config->slots > (1 << 20))
        return bg_error_set(err, BG_ERR_INVALID, "slots = %d outside [1, %d]", config->slots,
                            1 << 20);
    if (config->services == 0 || config->services > 7)
        return bg_error_set(err, BG_ERR_INVALID, "no service to offer");
    bga_service_t *svc = calloc(1, sizeof *svc);
    if (!svc)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory creating the agent's job table");
    svc->jobs = calloc((size_t)config->slots, sizeof *svc->jobs);
    if (!svc->jobs) {
        free(svc);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for %d job slots", config->slots);
    }
    svc->config = *config;
    snprintf(svc->name, sizeof svc->name, "%s", config->name ? config->name : "");
    svc->config.name = svc->name;
    if (svc->config.limits.max_frame_bytes == 0)
        svc->config.limits = bga_wire_default_limits();
    *out = svc;
    return BG_OK;
}

void bga_service_destroy(bga_service_t **psvc)
{
    if (!psvc || !*psvc)
        return;
    bga_service_t *svc = *psvc;
    for (int i = 0; i < svc->config.slots; i++)
        free_job(&svc->jobs[i]);
    free(svc->jobs);
    free(svc);
    *psvc = NULL;
}

int bga_service_jobs(const bga_service_t *svc)
{
    int n = 0;
    for (int i = 0; i < svc->config.slots; i++)
        n += svc->jobs[i].id != 0;
    return n;
}

bga_service_stats_t bga_service_stats(const bga_service_t *svc)
{
    return svc->stats;
}

int bga_service_expire(bga_service_t *svc, double now)
{
    int n = 0;
    for (int i = 0; i < svc->config.slots; i++) {
        job *j = &svc->jobs[i];
        if (j->id != 0 && j->lease_seconds > 0.0 && now > j->expires) {
            free_job(j);
            n++;
        }
    }
    svc->stats.expired += n;
    return n;
}

int bga_service_drop_all(bga_service_t *svc)
{
    int n = 0;
    for (int i = 0; i < svc->config.slots; i++)
        if (svc->jobs[i].id != 0) {
            free_job(&svc->jobs[i]);
            n++;
        }
    svc->stats.dropped += n;
    return n;
}

unsigned bga_service_parse_list(const char *list, bg_error_t *err)
{
    unsigned bits = 0;
    const char *p = list;
    while (*p) {
        const char *end = strchr(p, ',');
        const size_t len = end ? (size_t)(end - p) : strlen(p);
        if (len == 3 && strncmp(p, "all", 3) == 0)
            bits |= BGA_SERVICE_ROTFIT | BGA_SERVICE_SOLVE | BGA_SERVICE_INTEG;
        else if (len == 6 && strncmp(p, "rotfit", 6) == 0)
            bits |= BGA_SERVICE_ROTFIT;
        else if (len == 5 && strncmp(p, "solve", 5) == 0)
            bits |= BGA_SERVICE_SOLVE;
        else if (len == 5 && strncmp(p, "integ", 5) == 0)
            bits |= BGA_SERVICE_INTEG;
        else {
            bg_error_set(err, BG_ERR_INVALID,
                         "unknown service '%.*s' (known: rotfit, solve, "
                         "integ, all)",
                         (int)len, p);
            return 0;
        }
        if (!end)
            break;
        p = end + 1;
    }
    if (bits == 0)
        bg_error_set(err, BG_ERR_INVALID, "empty service list");
    return bits;
}

static job *find_job(bga_service_t *svc, uint64_t id)
{
    for (int i = 0; i < svc->config.slots; i++)
        if (svc->jobs[i].id == id)
            return &svc->jobs[i];
    return NULL;
}

/* The job named by a set-up, created in a free slot if new. */
static bga_wire_code claim_job(bga_service_t *svc, uint64_t id, job **out, bga_wire_error_t *werr)
{
    if (id == 0)
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 0, "job",
                             "job id 0 is reserved for control messages");
    *out = find_job(svc, id);
    if (*out)
        return BGA_WIRE_OK;
    *out = find_job(svc, 0);
    if (!*out)
        return bga_wire_fail(werr, BGA_WIRE_BUSY, 0, "job", "no free slot: %d of %d jobs held",
                             svc->config.slots, svc->config.slots);
    (*out)->id = id;
    return BGA_WIRE_OK;
}

static void renew(job *j, double now, int64_t lease_ms);

/* A set-up's common start: the job (new or existing), the service's old
 * state dropped, the lease renewed. */
static bga_wire_code begin_setup(bga_service_t *svc, const bga_msg_t *m, double now,
                                 int64_t lease_ms, void (*drop)(job *), job **j,
                                 bga_wire_error_t *werr)
{
    const bga_wire_code wc = claim_job(svc, m->header.job, j, werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    drop(*j);
    renew(*j, now, lease_ms);
    return BGA_WIRE_OK;
}

static void renew(job *j, double now, int64_t lease_ms)
{
    const double lease = (double)lease_ms / 1000.0;
    if (lease > j->lease_seconds)
        j->lease_seconds = lease;
    j->expires = now + j->lease_seconds;
}

static bga_wire_code need_service(const bga_service_t *svc, unsigned bit, const char *what,
                                  bga_wire_error_t *werr)
{
    if (svc->config.services & bit)
        return BGA_WIRE_OK;
    return bga_wire_fail(werr, BGA_WIRE_UNEXPECTED, 0, "type", "this agent does not serve %s",
                         what);
}

/* A call on a job that never set up this service here. */
static bga_wire_code no_state(const job *j, const char *what, bga_wire_error_t *werr)
{
    return bga_wire_fail(werr, BGA_WIRE_WRONG_STATE, 0, "type", "job %llu has no %s on this agent",
                         (unsigned long long)j->id, what);
}

/* Replies are built into `rep` (a bga_msg_t whose arrays point at job
 * buffers, alive until the reply is encoded). */
static void reply_ack(bga_msg_t *rep, const bga_msg_t *req)
{
    bga_msg_init(rep, BGA_ACK, req->header.job, req->header.seq);
    rep->field[BGA_ACK_TYPE].i = req->header.type;
}

/* det D of a dim×dim row-major matrix (dim 2 or 3). */
static double det_small(int dim, const double *D)
{
    if (dim == 2)
        return D[0] * D[3] - D[1] * D[2];
    return D[0] * (D[4] * D[8] - D[5] * D[7]) - D[1] * (D[3] * D[8] - D[5] * D[6]) +
           D[2] * (D[3] * D[7] - D[4] * D[6]);
}

static bga_wire_code rotfit_setup(bga_service_t *svc, const bga_msg_t *m, double now,
                                  bga_msg_t *rep, bga_wire_error_t *werr)
{
    job *j;
    bga_wire_code wc = begin_setup(svc, m, now, m->field[BGA_RS_LEASE_MS].i, free_rotfit, &j, werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const int dim = (int)m->field[BGA_RS_DIM].i;
    const int32_t nv = (int32_t)m->field[BGA_RS_NV].i, ne = (int32_t)m->field[BGA_RS_NE].i;
    const int T = (int)m->field[BGA_RS_BLOCK].i;
    const size_t nsc = (size_t)ne * (size_t)T;
    double *edges = NULL;
    bg_error_t e = BG_ERROR_INIT;
    bg_status st = BG_OK;
    /* Per-element blocks must fit one reply frame: otherwise the set-up
     * would allocate for replies that can never be sent. */
    if (m->field[BGA_RS_NVAL].i == 0 && nsc * sizeof(double) > svc->config.limits.max_frame_bytes) {
        wc = bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, "values",
                           "%d elements' Hessian blocks (%zu bytes) exceed the %zu-byte frame "
                           "cap: send a scatter map",
                           (int)ne, nsc * sizeof(double), svc->config.limits.max_frame_bytes);
        goto fail;
    }
    if ((st = bg_mesh_new(dim == 2 ? BG_MESH_PLANAR : BG_MESH_VOLUME, nv, ne, &j->mesh, &e)) !=
        BG_OK)
        goto fail;
    bga_msg_copy_i32(m, BGA_RS_ELEMENTS, j->mesh->elements);
    if (m->array[BGA_RS_REST_POSITIONS].count > 0) {
        bga_msg_copy_f64(m, BGA_RS_REST_POSITIONS, j->mesh->x);
        int32_t reoriented = 0;
        if (bg_mesh_validate(j->mesh, "partition", &reoriented, &e) != BG_OK) {
            wc = bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 2 + BGA_RS_ELEMENTS, "elements", "%s",
                               e.message);
            goto fail;
        }
        if (reoriented > 0) {
            wc = bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 2 + BGA_RS_ELEMENTS, "elements",
                               "%d elements are negatively oriented: the coordinator sends "
                               "validated, positively oriented elements",
                               (int)reoriented);
            goto fail;
        }
        st = bg_elastic_new(j->mesh, m->field[BGA_RS_MU].f, m->field[BGA_RS_LAMBDA].f, &j->model,
                            &e);
    } else {
        edges = malloc(m->array[BGA_RS_REST_EDGES].count * sizeof *edges + 1);
        if (!edges) {
            st = BG_ERR_NOMEM;
            goto fail;
        }
        bga_msg_copy_f64(m, BGA_RS_REST_EDGES, edges);
        for (int32_t el = 0; el < ne; el++) {
            const double det = det_small(dim, edges + (size_t)el * dim * dim);
            if (!(det > 0.0) || !isfinite(1.0 / det)) {
                wc = bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 2 + BGA_RS_REST_EDGES, "rest_edges",
                                   "element %d: rest edge matrix has determinant "
                                   "%g, must be positive",
                                   (int)el, det);
                goto fail;
            }
        }
        st = bg_elastic_new_from_rest(j->mesh, dim, edges, m->field[BGA_RS_MU].f,
                                      m->field[BGA_RS_LAMBDA].f, &j->model, &e);
    }
    if (st != BG_OK)
        goto fail;
    bg_elastic_set_barrier(j->model, m->field[BGA_RS_BARRIER].f);
    j->scatter = malloc(nsc * sizeof *j->scatter + 1);
    j->nhess = m->field[BGA_RS_NVAL].i > 0 ? (size_t)m->field[BGA_RS_NVAL].i : nsc;
    j->hess = malloc(j->nhess * sizeof *j->hess + 1);
    j->q = malloc((size_t)nv * dim * sizeof *j->q + 1);
    j->grad = malloc((size_t)nv * dim * sizeof *j->grad + 1);
    if (!j->scatter || !j->hess || !j->q || !j->grad) {
        st = BG_ERR_NOMEM;
        goto fail;
    }
    if (m->array[BGA_RS_SCATTER].count > 0)
        bga_msg_copy_i32(m, BGA_RS_SCATTER, j->scatter);
    else
        for (size_t i = 0; i < nsc; i++)
            j->scatter[i] = (int32_t)i;
    free(edges);
    reply_ack(rep, m);
    return BGA_WIRE_OK;
fail:
    if (wc == BGA_WIRE_OK) /* a library failure, not the request's */
        wc = bga_wire_fail(werr, BGA_WIRE_INTERNAL, -1, "", "rotation-fit set-up: %s",
                           e.message[0] ? e.message : bg_strerror(st));
    free(edges);
    free_rotfit(j);
    free_job_if_empty(j);
    return wc;
}

/* A ROTFIT_RESULT: energy, fit counts, compute seconds and, when grad is
 * non-NULL, the gradient (ndof values, a job buffer). */
static void reply_rotfit(const bga_msg_t *m, double energy, const bg_rotfit_stats_t *rs,
                         double seconds, const double *grad, size_t ndof, bga_msg_t *rep)
{
    bga_msg_init(rep, BGA_ROTFIT_RESULT, m->header.job, m->header.seq);
    /* NaN cannot travel (the decoder refuses it); a NaN energy means a
     * non-finite input reached the kernel, reported as +Inf. */
    rep->field[BGA_RR_ENERGY].f = isnan(energy) ? INFINITY : energy;
    rep->field[BGA_RR_FITS].i = rs->calls;
    rep->field[BGA_RR_WARM].i = rs->warm;
    rep->field[BGA_RR_POLAR].i = rs->polar;
    rep->field[BGA_RR_SVD].i = rs->svd;
    rep->field[BGA_RR_SECONDS].f = seconds;
    if (grad)
        rep->array[BGA_RR_GRADIENT] = (bga_array_t){grad, ndof};
}

/* A surface partition's call: its cells' rotations fitted, their energy
 * and gradient (no Hessian: the surface editor's matrix is constant). */
static bga_wire_code surface_call(job *j, const bga_msg_t *m, bga_msg_t *rep,
                                  bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    const size_t ndof = (size_t)j->mesh->nv * 3;
    const int64_t want = m->field[BGA_RC_WANT].i;
    if (want & BGA_WANT_HESSIAN)
        return bga_wire_fail(werr, BGA_WIRE_WRONG_STATE, 1, "want",
                             "a surface partition has no Hessian to send");
    if (m->array[BGA_RC_POSITIONS].count != ndof)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_RC_POSITIONS, "positions",
                             "%zu position values, the partition has %d vertices x 3 = %zu",
                             m->array[BGA_RC_POSITIONS].count, (int)j->mesh->nv, ndof);
    bga_msg_copy_f64(m, BGA_RC_POSITIONS, j->q);
    const double t0 = bg_clock_now();
    bg_rotfit_stats_t rs = {0};
    const double energy =
        bg_surface_cells_eval(j->cells, j->q, (want & BGA_WANT_GRADIENT) ? j->grad : NULL, &rs);
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    reply_rotfit(m, energy, &rs, seconds, (want & BGA_WANT_GRADIENT) ? j->grad : NULL, ndof, rep);
    return BGA_WIRE_OK;
}

static bga_wire_code surf_setup(bga_service_t *svc, const bga_msg_t *m, double now, bga_msg_t *rep,
                                bga_wire_error_t *werr)
{
    job *j;
    bga_wire_code wc = begin_setup(svc, m, now, m->field[BGA_SU_LEASE_MS].i, free_rotfit, &j, werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const int32_t nv = (int32_t)m->field[BGA_SU_NV].i, ne = (int32_t)m->field[BGA_SU_NE].i;
    const size_t nowned = m->array[BGA_SU_OWNED].count;
    bg_error_t e = BG_ERROR_INIT;
    uint8_t *owned = calloc((size_t)nv + 1, 1);
    int32_t *list = malloc(nowned * sizeof *list + 1);
    bg_status st = owned && list ? BG_OK : BG_ERR_NOMEM;
    if (st == BG_OK)
        st = bg_mesh_new(BG_MESH_SURFACE, nv, ne, &j->mesh, &e);
    if (st == BG_OK) {
        bga_msg_copy_i32(m, BGA_SU_TRIANGLES, j->mesh->elements);
        bga_msg_copy_f64(m, BGA_SU_REST_POSITIONS, j->mesh->x);
        bga_msg_copy_i32(m, BGA_SU_OWNED, list);
        for (size_t i = 0; i < nowned; i++)
            owned[list[i]] = 1;
        j->q = malloc((size_t)nv * 3 * sizeof *j->q + 1);
        j->grad = malloc((size_t)nv * 3 * sizeof *j->grad + 1);
        st = j->q && j->grad ? bg_surface_cells_new(j->mesh, owned, &j->cells, &e) : BG_ERR_NOMEM;
    }
    free(owned);
    free(list);
    if (st != BG_OK) {
        free_rotfit(j);
        free_job_if_empty(j);
        return bga_wire_fail(werr, st == BG_ERR_NOMEM ? BGA_WIRE_INTERNAL : BGA_WIRE_INCONSISTENT,
                             st == BG_ERR_NOMEM ? -1 : 2 + BGA_SU_TRIANGLES, "triangles",
                             "surface set-up of %d vertices: %s", (int)nv,
                             e.message[0] ? e.message : "out of memory");
    }
    reply_ack(rep, m);
    return BGA_WIRE_OK;
}

static bga_wire_code rotfit_call(job *j, const bga_msg_t *m, bga_msg_t *rep,
                                 bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    if (j->cells)
        return surface_call(j, m, rep, stats, werr);
    if (!j->model)
        return no_state(j, "rotation-fit partition", werr);
    const int dim = j->mesh->dim;
    const size_t ndof = (size_t)j->mesh->nv * dim;
    if (m->array[BGA_RC_POSITIONS].count != ndof)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_RC_POSITIONS, "positions",
                             "%zu position values, the partition has %d vertices x %d = %zu",
                             m->array[BGA_RC_POSITIONS].count, (int)j->mesh->nv, dim, ndof);
    bga_msg_copy_f64(m, BGA_RC_POSITIONS, j->q);
    const int64_t want = m->field[BGA_RC_WANT].i;
    const double t0 = bg_clock_now();
    bg_elastic_reset_stats(j->model);
    /* A Hessian alone (Newton's matrix at the iterate the line search has
     * evaluated) is assembled as the solver's fit_hessian assembles it in
     * process (bg_backend.h): bg_elastic_assemble_hessian from the
     * rotations the last fit left, which it takes as they are where they
     * are settled at q and refits where not (after a rejected chord step
     * they were fitted elsewhere). Fitting them all again first,
     * warm-started from themselves, cost a fit per Newton matrix and
     * rounded otherwise, so the partition's Hessian was not the in-process
     * one. The reply's energy is then the last fit's. A partition never
     * fitted is fitted first. */
    const int fit = (want & BGA_WANT_GRADIENT) || !(want & BGA_WANT_HESSIAN) || !j->fitted;
    double energy = j->energy_fit;
    if (fit) {
        energy = bg_elastic_eval(j->model, j->q, (want & BGA_WANT_GRADIENT) ? j->grad : NULL);
        j->energy_fit = energy;
        j->fitted = 1;
    }
    if (want & BGA_WANT_HESSIAN) {
        memset(j->hess, 0, j->nhess * sizeof *j->hess);
        bg_elastic_assemble_hessian(j->model, j->q, (want & BGA_WANT_PROJECTED) != 0, 1.0,
                                    j->scatter, j->hess);
    }
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    const bg_rotfit_stats_t rs = bg_elastic_rotfit_stats(j->model);
    reply_rotfit(m, energy, &rs, seconds, (want & BGA_WANT_GRADIENT) ? j->grad : NULL, ndof, rep);
    if (want & BGA_WANT_HESSIAN) {
        rep->array[BGA_RR_HESSIAN].data = j->hess;
        rep->array[BGA_RR_HESSIAN].count = j->nhess;
    }
    return BGA_WIRE_OK;
}

static bga_wire_code solve_setup(bga_service_t *svc, const bga_msg_t *m, double now, bga_msg_t *rep,
                                 bga_wire_error_t *werr)
{
    job *j;
    const bga_wire_code wc =
        begin_setup(svc, m, now, m->field[BGA_SS_LEASE_MS].i, free_solve, &j, werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const int32_t n = (int32_t)m->field[BGA_SS_N].i;
    const size_t nnz = (size_t)m->field[BGA_SS_NNZ].i;
    int32_t *colptr = malloc(((size_t)n + 1) * sizeof *colptr);
    int32_t *rowidx = malloc(nnz * sizeof *rowidx);
    bg_error_t e = BG_ERROR_INIT;
    bg_status st = BG_ERR_NOMEM;
    if (colptr && rowidx) {
        bga_msg_copy_i32(m, BGA_SS_COLPTR, colptr);
        bga_msg_copy_i32(m, BGA_SS_ROWIDX, rowidx);
        st = bg_sparse_new_csc(n, colptr, rowidx, &j->sys, &e);
        if (st == BG_OK && (m->field[BGA_SS_OPTIONS].i & BGA_SOLVE_PREFER_SOLVES))
            bg_sparse_prefer_solves(j->sys);
        if (st == BG_OK && (m->field[BGA_SS_OPTIONS].i & BGA_SOLVE_ORDERED))
            bg_sparse_keep_order(j->sys);
    }
    free(colptr);
    free(rowidx);
    if (st == BG_OK) {
        j->x = malloc((size_t)n * sizeof *j->x);
        if (!j->x)
            st = BG_ERR_NOMEM;
    }
    if (st != BG_OK) {
        free_solve(j);
        free_job_if_empty(j);
        return bga_wire_fail(werr, st == BG_ERR_INVALID ? BGA_WIRE_INCONSISTENT : BGA_WIRE_INTERNAL,
                             2 + BGA_SS_ROWIDX, "rowidx", "sparse-solve set-up: %s",
                             e.message[0] ? e.message : "out of memory");
    }
    reply_ack(rep, m);
    return BGA_WIRE_OK;
}

static bga_wire_code solve_factor(job *j, const bga_msg_t *m, bga_msg_t *rep, char *text,
                                  size_t text_cap, bga_service_stats_t *stats,
                                  bga_wire_error_t *werr)
{
    if (!j->sys)
        return no_state(j, "sparse-solve pattern", werr);
    const size_t nnz = bg_sparse_nonzeros(j->sys);
    if (m->array[BGA_SF_VALUES].count != nnz)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_SF_VALUES, "values",
                             "%zu values for a pattern of %zu nonzeros",
                             m->array[BGA_SF_VALUES].count, nnz);
    bga_msg_copy_f64(m, BGA_SF_VALUES, bg_sparse_values(j->sys));
    const bg_sparse_timing_t t0 = bg_sparse_timing(j->sys);
    bg_error_t e = BG_ERROR_INIT;
    const bg_status st = bg_sparse_factorize(j->sys, m->field[BGA_SF_SHIFT].f, &e);
    const bg_sparse_timing_t t1 = bg_sparse_timing(j->sys);
    if (st != BG_OK && st != BG_ERR_NUMERIC) {
        j->factored = 0;
        return bga_wire_fail(werr, BGA_WIRE_INTERNAL, -1, "", "factorization: %s", e.message);
    }
    j->factored = st == BG_OK;
    bga_msg_init(rep, BGA_SOLVE_FACTORED, m->header.job, m->header.seq);
    rep->field[BGA_SD_POSDEF].i = j->factored;
    rep->field[BGA_SD_ANALYZE_SECONDS].f = t1.analyze_seconds - t0.analyze_seconds;
    rep->field[BGA_SD_FACTOR_SECONDS].f = t1.factor_seconds - t0.factor_seconds;
    rep->field[BGA_SD_FLOPS].f = bg_sparse_factor_flops(j->sys);
    rep->field[BGA_SD_FACTOR_NONZEROS].f = bg_sparse_factor_nonzeros(j->sys);
    stats->compute_seconds +=
        rep->field[BGA_SD_ANALYZE_SECONDS].f + rep->field[BGA_SD_FACTOR_SECONDS].f;
    if (!j->factored) {
        snprintf(text, text_cap, "%s", e.message);
        rep->array[BGA_SD_MESSAGE].data = text;
        rep->array[BGA_SD_MESSAGE].count = strlen(text);
    }
    return BGA_WIRE_OK;
}

/* Solves into j->x per right-hand side; the reply's x is the whole block,
 * so the job keeps an nrhs·n buffer grown on demand (bounded by the
 * codec's nrhs cap). */
static bga_wire_code solve_rhs(job *j, const bga_msg_t *m, bga_msg_t *rep,
                               bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    if (!j->sys || !j->factored)
        return bga_wire_fail(werr, BGA_WIRE_WRONG_STATE, 0, "type",
                             "job %llu: solve before a successful factorization",
                             (unsigned long long)j->id);
    const size_t n = (size_t)bg_sparse_size(j->sys);
    const size_t nrhs = (size_t)m->field[BGA_SR_NRHS].i;
    if (m->array[BGA_SR_RHS].count != n * nrhs)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_SR_RHS, "rhs",
                             "%zu values for %zu right-hand sides of %zu unknowns",
                             m->array[BGA_SR_RHS].count, nrhs, n);
    if (nrhs > 1) {
        double *grown = realloc(j->x, n * nrhs * sizeof *grown);
        if (!grown)
            return bga_wire_fail(werr, BGA_WIRE_INTERNAL, -1, "",
                                 "out of memory for %zu "
                                 "solutions",
                                 nrhs);
        j->x = grown;
    }
    bga_msg_copy_f64(m, BGA_SR_RHS, j->x);
    const double t0 = bg_clock_now();
    bg_error_t e = BG_ERROR_INIT;
    if (bg_sparse_solve_many(j->sys, (int)nrhs, j->x, j->x, &e) != BG_OK)
        return bga_wire_fail(werr, BGA_WIRE_NUMERIC, -1, "", "solve: %s", e.message);
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    bga_msg_init(rep, BGA_SOLVE_RESULT, m->header.job, m->header.seq);
    rep->field[BGA_SX_SECONDS].f = seconds;
    rep->array[BGA_SX_X].data = j->x;
    rep->array[BGA_SX_X].count = n * nrhs;
    return BGA_WIRE_OK;
}

/* The committed state as the reply to a set-up or an accept. */
static void reply_state(const bga_msg_t *m, const bg_step_motion_t *mo, size_t ndof,
                        double seconds, bga_msg_t *rep)
{
    bga_msg_init(rep, BGA_INTEG_STATE, m->header.job, m->header.seq);
    rep->field[BGA_IT_KINETIC].f = mo->kinetic;
    for (int c = 0; c < 3; c++) {
        rep->field[BGA_IT_LINEAR_X + c].f = mo->linear[c];
        rep->field[BGA_IT_ANGULAR_X + c].f = mo->angular[c];
    }
    rep->field[BGA_IT_STEPS].i = mo->steps;
    rep->field[BGA_IT_SECONDS].f = seconds;
    rep->array[BGA_IT_Q] = (bga_array_t){mo->q, ndof};
}

static bga_wire_code integ_setup(bga_service_t *svc, const bga_msg_t *m, double now, bga_msg_t *rep,
                                 bga_wire_error_t *werr)
{
    job *j;
    const bga_wire_code wc =
        begin_setup(svc, m, now, m->field[BGA_IS_LEASE_MS].i, free_integ, &j, werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const double t0 = bg_clock_now();
    const int dim = (int)m->field[BGA_IS_DIM].i;
    const int32_t nv = (int32_t)m->field[BGA_IS_NV].i;
    const size_t ndof = (size_t)nv * (size_t)dim;
    /* Host copies of the set-up's arrays (the wire's are little-endian views). */
    double *mass = malloc((size_t)nv * sizeof *mass + 1), *arrays = malloc(3 * ndof * sizeof *arrays + 1);
    int32_t *flags = malloc(ndof * sizeof *flags + 1);
    uint8_t *constrained = malloc(ndof + 1);
    j->iin = malloc(2 * ndof * sizeof *j->iin + 1);
    bg_error_t e = BG_ERROR_INIT;
    bg_status st = mass && arrays && flags && constrained && j->iin ? BG_OK : BG_ERR_NOMEM;
    if (st == BG_OK) {
        double gravity[3] = {0, 0, 0};
        bga_msg_copy_f64(m, BGA_IS_MASS, mass);
        bga_msg_copy_f64(m, BGA_IS_Q, arrays);
        bga_msg_copy_f64(m, BGA_IS_VELOCITY, arrays + ndof);
        bga_msg_copy_f64(m, BGA_IS_T0, arrays + 2 * ndof);
        bga_msg_copy_i32(m, BGA_IS_CONSTRAINED, flags);
        bga_msg_copy_f64(m, BGA_IS_GRAVITY, gravity);
        for (size_t i = 0; i < ndof; i++)
            constrained[i] = flags[i] != 0;
        const bg_step_setup_t setup = {dim,          nv,          m->field[BGA_IS_H].f,
                                       m->field[BGA_IS_DAMPING].f, mass, arrays,
                                       arrays + ndof, arrays + 2 * ndof, constrained, gravity};
        st = bg_step_new(&setup, &j->step, &e);
    }
    free(mass);
    free(arrays);
    free(flags);
    free(constrained);
    if (st != BG_OK) {
        free_integ(j);
        free_job_if_empty(j);
        return bga_wire_fail(werr, st == BG_ERR_NOMEM ? BGA_WIRE_INTERNAL : BGA_WIRE_OUT_OF_RANGE,
                             st == BG_ERR_NOMEM ? -1 : 1, "",
                             "integration-step set-up of %d vertices: %s", (int)nv,
                             e.message[0] ? e.message : "out of memory");
    }
    bg_step_motion_t mo;
    bg_step_motion(j->step, &mo);
    const double seconds = bg_clock_now() - t0;
    svc->stats.compute_seconds += seconds;
    reply_state(m, &mo, ndof, seconds, rep);
    return BGA_WIRE_OK;
}

/* A request's position vector of the state's size, or BAD_LENGTH. */
static bga_wire_code need_dofs(const job *j, const bga_msg_t *m, int array, const char *name,
                               bga_wire_error_t *werr)
{
    const size_t ndof = bg_step_dofs(j->step);
    if (m->array[array].count == ndof)
        return BGA_WIRE_OK;
    return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + array, name,
                         "%zu values, the state has %zu", m->array[array].count, ndof);
}

/* bg_step refuses calls out of order (BG_ERR_INVALID): the peer's state is wrong. */
static bga_wire_code step_failed(bg_status st, const bg_error_t *e, bga_wire_error_t *werr)
{
    return bga_wire_fail(werr, st == BG_ERR_INVALID ? BGA_WIRE_WRONG_STATE : BGA_WIRE_INTERNAL, 0,
                         "type", "%s", e->message);
}

static bga_wire_code integ_predict(job *j, const bga_msg_t *m, bga_msg_t *rep,
                                   bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    if (!j->step)
        return no_state(j, "integrator state", werr);
    bga_wire_code wc = need_dofs(j, m, BGA_IP_T1, "t1", werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const double t0 = bg_clock_now();
    const size_t ndof = bg_step_dofs(j->step);
    bga_msg_copy_f64(m, BGA_IP_T1, j->iin);
    const bg_step_request_t req = {(int)m->field[BGA_IP_VARIATIONAL].i,
                                   (int)m->field[BGA_IP_TRIAL].i,
                                   (int)m->field[BGA_IP_PREDICTOR].i, j->iin};
    bg_step_prediction_t pr;
    bg_error_t e = BG_ERROR_INIT;
    const bg_status st = bg_step_predict(j->step, &req, &pr, &e);
    if (st != BG_OK)
        return step_failed(st, &e, werr);
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    bga_msg_init(rep, BGA_INTEG_INERTIA, m->header.job, m->header.seq);
    rep->field[BGA_II_COEF].f = pr.coefficient;
    rep->field[BGA_II_STATE_SCALE].f = pr.state_scale;
    rep->field[BGA_II_NCAND].i = pr.ncandidates;
    rep->field[BGA_II_SECONDS].f = seconds;
    rep->array[BGA_II_PREDICT] = (bga_array_t){pr.y, ndof};
    rep->array[BGA_II_TARGETS] = (bga_array_t){pr.targets, ndof};
    rep->array[BGA_II_CANDIDATES] =
        (bga_array_t){pr.candidate[0], ndof * (size_t)pr.ncandidates};
    return BGA_WIRE_OK;
}

static bga_wire_code integ_update(job *j, const bga_msg_t *m, bga_msg_t *rep,
                                  bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    if (!j->step)
        return no_state(j, "integrator state", werr);
    bga_wire_code wc = need_dofs(j, m, BGA_IU_QSTAR, "q_star", werr);
    if (wc != BGA_WIRE_OK)
        return wc;
    const double t0 = bg_clock_now();
    const size_t ndof = bg_step_dofs(j->step);
    bga_msg_copy_f64(m, BGA_IU_QSTAR, j->iin);
    bga_msg_copy_f64(m, BGA_IU_GRAD, j->iin + ndof);
    bg_step_trial_t tr;
    bg_error_t e = BG_ERROR_INIT;
    const bg_status st = bg_step_update(j->step, j->iin, j->iin + ndof, &tr, &e);
    if (st != BG_OK)
        return step_failed(st, &e, werr);
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    bga_msg_init(rep, BGA_INTEG_TRIAL, m->header.job, m->header.seq);
    rep->field[BGA_IR_KINETIC].f = tr.kinetic;
    rep->field[BGA_IR_WORK].f = tr.handle_work;
    rep->field[BGA_IR_SECONDS].f = seconds;
    rep->array[BGA_IR_QNEXT] = (bga_array_t){tr.q_next, ndof};
    return BGA_WIRE_OK;
}

static bga_wire_code integ_accept(job *j, const bga_msg_t *m, bga_msg_t *rep,
                                  bga_service_stats_t *stats, bga_wire_error_t *werr)
{
    if (!j->step)
        return no_state(j, "integrator state", werr);
    const double t0 = bg_clock_now();
    bg_step_motion_t mo;
    bg_error_t e = BG_ERROR_INIT;
    const bg_status st = bg_step_accept(j->step, &mo, &e);
    if (st != BG_OK)
        return step_failed(st, &e, werr);
    const double seconds = bg_clock_now() - t0;
    stats->compute_seconds += seconds;
    reply_state(m, &mo, bg_step_dofs(j->step), seconds, rep);
    return BGA_WIRE_OK;
}

static void reply_heartbeat(const bga_service_t *svc, int jobs, const bga_msg_t *m, bga_msg_t *rep)
{
    bga_msg_init(rep, BGA_HEARTBEAT, m->header.job, m->header.seq);
    rep->field[BGA_HB_SLOTS].i = svc->config.slots;
    rep->field[BGA_HB_FREE].i = svc->config.slots - jobs;
    rep->field[BGA_HB_SERVICES].i = svc->config.services;
    rep->field[BGA_HB_JOBS].i = jobs;
    rep->array[BGA_HB_NAME].data = svc->name;
    rep->array[BGA_HB_NAME].count = strlen(svc->name);
}

/* A decoded request → *rep, or an error code in werr. */
static bga_wire_code dispatch(bga_service_t *svc, const bga_msg_t *m, double now, bga_msg_t *rep,
                              char *text, size_t text_cap, bga_wire_error_t *werr)
{
    const uint16_t type = m->header.type;
    bga_wire_code wc;
    switch (type) {
    case BGA_HEARTBEAT: {
        job *j = m->header.job ? find_job(svc, m->header.job) : NULL;
        if (j)
            renew(j, now, 0);
        reply_heartbeat(svc, bga_service_jobs(svc), m, rep);
        return BGA_WIRE_OK;
    }
    case BGA_ROTFIT_SETUP:
        if ((wc = need_service(svc, BGA_SERVICE_ROTFIT, "rotation-fit", werr)) != BGA_WIRE_OK)
            return wc;
        return rotfit_setup(svc, m, now, rep, werr);
    case BGA_SURF_SETUP:
        if ((wc = need_service(svc, BGA_SERVICE_ROTFIT, "rotation-fit", werr)) != BGA_WIRE_OK)
            return wc;
        return surf_setup(svc, m, now, rep, werr);
    case BGA_SOLVE_SETUP:
        if ((wc = need_service(svc, BGA_SERVICE_SOLVE, "sparse-solve", werr)) != BGA_WIRE_OK)
            return wc;
        return solve_setup(svc, m, now, rep, werr);
    case BGA_INTEG_SETUP:
        if ((wc = need_service(svc, BGA_SERVICE_INTEG, "integration-step", werr)) != BGA_WIRE_OK)
            return wc;
        return integ_setup(svc, m, now, rep, werr);
    case BGA_RELEASE:
    case BGA_ROTFIT_CALL:
    case BGA_SOLVE_FACTOR:
    case BGA_SOLVE_RHS:
    case BGA_INTEG_PREDICT:
    case BGA_INTEG_UPDATE:
    case BGA_INTEG_ACCEPT:
        break;
    default:
        return bga_wire_fail(werr, BGA_WIRE_UNEXPECTED, 0, "type",
                             "%s is a reply, not a request an agent serves", bga_type_name(type));
    }
    job *j = m->header.job ? find_job(svc, m->header.job) : NULL;
    if (!j)
        return bga_wire_fail(werr, BGA_WIRE_NO_JOB, 0, "job",
                             "%s: this agent holds no state for job %llu (never set up, "
                             "released, or its lease expired)",
                             bga_type_name(type), (unsigned long long)m->header.job);
    renew(j, now, 0);
    switch (type) {
    case BGA_RELEASE:
        free_job(j);
        svc->stats.released++;
        reply_ack(rep, m);
        return BGA_WIRE_OK;
    case BGA_ROTFIT_CALL:
        return rotfit_call(j, m, rep, &svc->stats, werr);
    case BGA_SOLVE_FACTOR:
        return solve_factor(j, m, rep, text, text_cap, &svc->stats, werr);
    case BGA_SOLVE_RHS:
        return solve_rhs(j, m, rep, &svc->stats, werr);
    case BGA_INTEG_PREDICT:
        return integ_predict(j, m, rep, &svc->stats, werr);
    case BGA_INTEG_UPDATE:
        return integ_update(j, m, rep, &svc->stats, werr);
    default:
        return integ_accept(j, m, rep, &svc->stats, werr);
    }
}

bg_status bga_service_handle(bga_service_t *svc, const bga_frame_t *frames, int nframes, double now,
                             bga_frames_t *reply, bg_error_t *err)
{
    memset(reply, 0, sizeof *reply);
    svc->stats.requests++;
    bga_msg_t m, rep;
    bga_wire_error_t werr;
    char text[BG_ERROR_MESSAGE_MAX];
    bga_wire_code wc = bga_wire_decode(frames, nframes, &svc->config.limits, &m, &werr);
    if (wc == BGA_WIRE_OK)
        wc = dispatch(svc, &m, now, &rep, text, sizeof text, &werr);
    if (wc == BGA_WIRE_OK) {
        bg_error_t e = BG_ERROR_INIT;
        if (bga_wire_encode(&rep, reply, &e) == BG_OK)
            return BG_OK;
        /* Only results can fail to encode (a non-finite value the kernel
         * produced, or memory): say so instead of going silent. */
        bga_wire_fail(&werr, BGA_WIRE_INTERNAL, -1, "", "%s", e.message);
    }
    svc->stats.errors++;
    return bga_service_refuse(frames, nframes, &werr, reply, err);
}

bg_status bga_service_heartbeat(const bga_service_t *svc, int jobs, const bga_frame_t *frames,
                                int nframes, bga_frames_t *reply, uint64_t *named, bg_error_t *err)
{
    memset(reply, 0, sizeof *reply);
    bga_msg_t m, rep;
    bga_wire_error_t werr;
    if (bga_wire_decode(frames, nframes, &svc->config.limits, &m, &werr) != BGA_WIRE_OK ||
        m.header.type != BGA_HEARTBEAT)
        return bg_error_set(err, BG_ERR_INVALID, "not a well-formed heartbeat");
    *named = m.header.job;
    reply_heartbeat(svc, jobs, &m, &rep);
    return bga_wire_encode(&rep, reply, err);
}

void bga_service_touch(bga_service_t *svc, uint64_t id, double now)
{
    job *j = id ? find_job(svc, id) : NULL;
    if (j)
        renew(j, now, 0);
}

/* Little-endian field of a raw header (offsets as in bga_wire.h). */
static uint64_t header_field(const uint8_t *h, size_t offset, size_t bytes)
{
    uint64_t v = 0;
    for (size_t i = bytes; i-- > 0;)
        v = v << 8 | h[offset + i];
    return v;
}

bg_status bga_service_refuse(const bga_frame_t *frames, int nframes, const bga_wire_error_t *werr,
                             bga_frames_t *reply, bg_error_t *err)
{
    /* Read in place rather than decoded: the decoder stops at the first
     * fault, which may come before the header (an oversized frame) or
     * concern it (a wrong version), and an over-long message is never
     * decoded at all; the job and seq are still there. */
    if (nframes < 1 || !frames || frames[0].size != BGA_WIRE_HEADER_BYTES || !frames[0].data ||
        memcmp(frames[0].data, "bgwp", 4) != 0)
        return bga_wire_error_reply(NULL, werr, reply, err);
    const uint8_t *h = frames[0].data;
    const bga_header_t to = {.version = (uint16_t)header_field(h, 4, 2),
                             .type = (uint16_t)header_field(h, 6, 2),
                             .job = header_field(h, 8, 8),
                             .seq = header_field(h, 16, 8),
                             .sender = header_field(h, 24, 8),
                             .receiver = header_field(h, 32, 8)};
    return bga_wire_error_reply(&to, werr, reply, err);
}

const char *bga_service_name(unsigned bit)
{
    switch (bit) {
    case BGA_SERVICE_ROTFIT:
        return "rotation-fit";
    case BGA_SERVICE_SOLVE:
        return "sparse-solve";
    case BGA_SERVICE_INTEG:
        return "integration-step";
    default:
        return NULL;
    }
}
