#include "bg_step.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Where a step's conversation stands. */
typedef enum phase { PHASE_READY, PHASE_PREDICTED, PHASE_UPDATED } phase;

struct bg_step {
    int dim;
    int32_t nv;
    size_t ndof;
    double h, decay;
    double gravity[3];
    double *mass;
    uint8_t *constrained;
    double *q, *p, *v, *v_prev, *t0, *t1, *y, *targets, *q_next, *p_next;
    double *candidate[BG_STEP_MAX_CANDIDATES];
    int64_t steps;
    int variational; /* of the trial in progress */
    phase phase;
};

static const char *const PHASE_NAMES[] = {"ready for a new step", "predicted (expects an update)",
                                          "updated (expects an accept or a redo)"};

void bg_step_destroy(bg_step_t **ps)
{
    if (!ps || !*ps)
        return;
    bg_step_t *s = *ps;
    double **arrays[] = {&s->mass, &s->q,       &s->p,       &s->v,      &s->v_prev,
                         &s->t0,   &s->t1,      &s->y,       &s->targets, &s->q_next,
                         &s->p_next};
    for (size_t i = 0; i < sizeof arrays / sizeof *arrays; i++)
        free(*arrays[i]);
    free(s->candidate[0]);
    free(s->constrained);
    free(s);
    *ps = NULL;
}

bg_status bg_step_new(const bg_step_setup_t *in, bg_step_t **out, bg_error_t *err)
{
    *out = NULL;
    if (in->dim != 2 && in->dim != 3)
        return bg_error_set(err, BG_ERR_INVALID, "integration step: dim = %d (2 or 3)", in->dim);
    if (in->nv < 1)
        return bg_error_set(err, BG_ERR_INVALID, "integration step: %d vertices", (int)in->nv);
    if (!(in->h > 0.0) || !isfinite(in->h))
        return bg_error_set(err, BG_ERR_INVALID, "integration step: h = %g is not positive",
                            in->h);
    if (!(in->damping >= 0.0) || !isfinite(in->damping))
        return bg_error_set(err, BG_ERR_INVALID, "integration step: damping = %g is not >= 0",
                            in->damping);
    for (int32_t v = 0; v < in->nv; v++)
        if (!(in->mass[v] > 0.0) || !isfinite(in->mass[v]))
            return bg_error_set(err, BG_ERR_INVALID,
                                "integration step: mass[%d] = %g is not positive", (int)v,
                                in->mass[v]);
    bg_step_t *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the integration step");
    s->dim = in->dim;
    s->nv = in->nv;
    s->ndof = (size_t)in->nv * (size_t)in->dim;
    s->h = in->h;
    s->decay = exp(-in->damping * in->h);
    for (int c = 0; c < in->dim; c++)
        s->gravity[c] = in->gravity[c];
    const size_t bytes = s->ndof * sizeof(double) + 1;
    double **arrays[] = {&s->q,      &s->p,       &s->v,      &s->v_prev, &s->t0, &s->t1,
                         &s->y,      &s->targets, &s->q_next, &s->p_next};
    int ok = 1;
    for (size_t i = 0; i < sizeof arrays / sizeof *arrays; i++)
        ok &= (*arrays[i] = calloc(1, bytes)) != NULL;
    /* One block: the candidates travel as one array. */
    ok &= (s->candidate[0] = calloc(BG_STEP_MAX_CANDIDATES, bytes)) != NULL;
    for (int c = 1; ok && c < BG_STEP_MAX_CANDIDATES; c++)
        s->candidate[c] = s->candidate[0] + (size_t)c * s->ndof;
    s->mass = malloc((size_t)in->nv * sizeof *s->mass + 1);
    s->constrained = malloc(s->ndof + 1);
    if (!ok || !s->mass || !s->constrained) {
        bg_step_destroy(&s);
        return bg_error_set(err, BG_ERR_NOMEM,
                            "out of memory for the integration state of %d vertices",
                            (int)in->nv);
    }
    memcpy(s->mass, in->mass, (size_t)in->nv * sizeof *s->mass);
    memcpy(s->constrained, in->constrained, s->ndof);
    memcpy(s->q, in->q, s->ndof * sizeof *s->q);
    memcpy(s->t0, in->t0, s->ndof * sizeof *s->t0);
    for (size_t i = 0; i < s->ndof; i++) {
        s->v[i] = in->velocity[i];
        s->p[i] = s->mass[i / (size_t)s->dim] * s->v[i];
    }
    s->phase = PHASE_READY;
    *out = s;
    return BG_OK;
}

size_t bg_step_dofs(const bg_step_t *s)
{
    return s->ndof;
}

static bg_status expect_phase(const bg_step_t *s, phase want, const char *call, bg_error_t *err)
{
    if (s->phase == want)
        return BG_OK;
    return bg_error_set(err, BG_ERR_INVALID, "integration step %lld: %s while %s",
                        (long long)s->steps, call, PHASE_NAMES[s->phase]);
}

/* Euclidean norm over free coordinates, times scale. */
static double free_norm(const bg_step_t *s, const double *x, double scale)
{
    double sum = 0.0;
    for (size_t i = 0; i < s->ndof; i++)
        if (!s->constrained[i])
            sum += x[i] * x[i];
    return scale * sqrt(sum);
}

/*
 * The candidate starts of a step (bg_dynamics.c's choose_start picks
 * among them): the velocity extrapolation from the last two steps (from
 * the second step on), the inertial prediction plus the constant load
 * (y + (h²/4)g for the midpoint rule, y + h²g for Euler), and q_k.
 */
static int candidates(bg_step_t *s, int predictor, const double *targets)
{
    static const int kinds[3] = {BG_STEP_PREDICT_EXTRAPOLATE, BG_STEP_PREDICT_INERTIAL,
                                 BG_STEP_PREDICT_LAST};
    const int variational = s->variational;
    const double h = s->h;
    const double reach = variational ? 0.5 * h : h, load = (variational ? 0.25 : 1.0) * h * h;
    const int first = s->steps == 0;
    if (predictor == BG_STEP_PREDICT_EXTRAPOLATE && first)
        predictor = BG_STEP_PREDICT_INERTIAL;
    int n = 0;
    for (int j = 0; j < 3; j++) {
        const int kind = kinds[j];
        if ((predictor != BG_STEP_PREDICT_BEST && predictor != kind) ||
            (kind == BG_STEP_PREDICT_EXTRAPOLATE && first))
            continue;
        double *x = s->candidate[n++];
        for (size_t i = 0; i < s->ndof; i++) {
            if (s->constrained[i])
                x[i] = targets[i];
            else if (kind == BG_STEP_PREDICT_EXTRAPOLATE)
                x[i] = s->q[i] + reach * (s->v[i] + 0.5 * reach / h * (s->v[i] - s->v_prev[i]) *
                                                        (variational ? 1.0 : 2.0));
            else if (kind == BG_STEP_PREDICT_INERTIAL)
                x[i] = s->y[i] + load * s->gravity[i % (size_t)s->dim];
            else
                x[i] = s->q[i];
        }
    }
    return n;
}

bg_status bg_step_predict(bg_step_t *s, const bg_step_request_t *req, bg_step_prediction_t *out,
                          bg_error_t *err)
{
    const char *call = req->trial ? "redo" : "predict";
    bg_status st = expect_phase(s, req->trial ? PHASE_UPDATED : PHASE_READY, call, err);
    if (st != BG_OK)
        return st;
    if (req->predictor < BG_STEP_PREDICT_BEST || req->predictor > BG_STEP_PREDICT_EXTRAPOLATE)
        return bg_error_set(err, BG_ERR_INVALID, "integration step: unknown predictor %d",
                            req->predictor);
    const int variational = req->variational != 0;
    const double h = s->h;
    s->variational = variational;
    memcpy(s->t1, req->t1, s->ndof * sizeof *s->t1);
    /* y is the inertial prediction (the minimiser without forces); the
     * constrained coordinates sit at the midpoint of their prescribed path
     * (variational) or at its end (Euler). */
    for (size_t i = 0; i < s->ndof; i++) {
        const double m = s->mass[i / (size_t)s->dim];
        s->y[i] = variational ? s->q[i] + 0.5 * h * s->p[i] / m : s->q[i] + h * s->v[i];
        s->targets[i] = variational ? 0.5 * (s->t0[i] + s->t1[i]) : s->t1[i];
    }
    memset(out, 0, sizeof *out);
    out->coefficient = variational ? 4.0 / (h * h) : 1.0 / (h * h);
    for (size_t i = 0; i < s->ndof; i++)
        s->q_next[i] = s->mass[i / (size_t)s->dim] * s->gravity[i % (size_t)s->dim];
    out->state_scale = free_norm(s, s->q_next, 1.0) + free_norm(s, s->p, 2.0 / h);
    out->y = s->y;
    out->targets = s->targets;
    out->ncandidates = candidates(s, req->predictor, s->targets);
    for (int c = 0; c < out->ncandidates; c++)
        out->candidate[c] = s->candidate[c];
    s->phase = PHASE_PREDICTED;
    return BG_OK;
}

bg_status bg_step_update(bg_step_t *s, const double *qs, const double *g, bg_step_trial_t *out,
                         bg_error_t *err)
{
    bg_status st = expect_phase(s, PHASE_PREDICTED, "update", err);
    if (st != BG_OK)
        return st;
    const double h = s->h;
    double work = 0.0, kinetic = 0.0;
    /* The handles' work: with R the force they exert, the discrete balance
     * at a constrained coordinate reads (2/h)(m v̄ − p_k) = −∂W/∂q + R
     * (midpoint; (1/h)(m v − p_k) for Euler), and the work is
     * R·(q_{k+1} − q_k). */
    for (size_t i = 0; i < s->ndof; i++) {
        const double m = s->mass[i / (size_t)s->dim];
        if (s->variational) {
            /* p_{k+1} = M v̄ − (h/2) ∇W(q*) on free coordinates. */
            const double vbar = 2.0 * (qs[i] - s->q[i]) / h;
            s->q_next[i] = 2.0 * qs[i] - s->q[i];
            if (s->constrained[i]) {
                s->p_next[i] = m * vbar;
                work += ((2.0 / h) * (m * vbar - s->p[i]) + g[i]) * h * vbar;
            } else {
                s->p_next[i] = m * vbar - 0.5 * h * g[i];
            }
        } else {
            const double v = (qs[i] - s->q[i]) / h;
            s->q_next[i] = qs[i];
            s->p_next[i] = m * v;
            if (s->constrained[i])
                work += ((m * v - s->p[i]) / h + g[i]) * h * v;
        }
        kinetic += 0.5 * s->p_next[i] * s->p_next[i] / m;
    }
    out->q_next = s->q_next;
    out->kinetic = kinetic;
    out->handle_work = work;
    s->phase = PHASE_UPDATED;
    return BG_OK;
}

void bg_step_motion(const bg_step_t *s, bg_step_motion_t *out)
{
    memset(out, 0, sizeof *out);
    out->q = s->q;
    out->steps = s->steps;
    for (int32_t v = 0; v < s->nv; v++) {
        const double *q = s->q + (size_t)v * s->dim, *p = s->p + (size_t)v * s->dim;
        double r[3] = {0, 0, 0}, m[3] = {0, 0, 0};
        for (int c = 0; c < s->dim; c++) {
            out->kinetic += 0.5 * p[c] * p[c] / s->mass[v];
            out->linear[c] += p[c];
            r[c] = q[c];
            m[c] = p[c];
        }
        out->angular[0] += r[1] * m[2] - r[2] * m[1];
        out->angular[1] += r[2] * m[0] - r[0] * m[2];
        out->angular[2] += r[0] * m[1] - r[1] * m[0];
    }
}

bg_status bg_step_accept(bg_step_t *s, bg_step_motion_t *out, bg_error_t *err)
{
    bg_status st = expect_phase(s, PHASE_UPDATED, "accept", err);
    if (st != BG_OK)
        return st;
    memcpy(s->v_prev, s->v, s->ndof * sizeof *s->v);
    for (size_t i = 0; i < s->ndof; i++) {
        s->q[i] = s->constrained[i] ? s->t1[i] : s->q_next[i];
        s->p[i] = s->decay * s->p_next[i];
        s->v[i] = s->p[i] / s->mass[i / (size_t)s->dim];
    }
    memcpy(s->t0, s->t1, s->ndof * sizeof *s->t0);
    s->steps++;
    s->phase = PHASE_READY;
    bg_step_motion(s, out);
    return BG_OK;
}
