#include "bga_wire.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const uint8_t MAGIC[4] = {'b', 'g', 'w', 'p'};

enum { KIND_I64 = 1, KIND_F64 = 2 };

/* A scalar field: integers must lie in [min, max]; doubles too, and must
 * be finite unless `nonfinite` allows ±Inf (never NaN). */
typedef struct field_spec {
    const char *name;
    int kind;
    double min, max;
    int nonfinite;
} field_spec;

/* An array: its length is mul·F[a]·F[b]·F[c] + add (fields F, −1 = 1)
 * when mul > 0, free (up to the caps) when mul = 0; an optional array may
 * also be empty. i32 values must lie in [lo, F[hi] + hi_add) when hi ≥ 0;
 * f64 values must be finite when `finite`. */
typedef struct array_spec {
    const char *name;
    int elem;
    int optional;
    int64_t mul;
    int a, b, c;
    int64_t add;
    int finite;
    int32_t lo;
    int hi;
    int64_t hi_add;
} array_spec;

typedef bga_wire_code (*check_fn)(const bga_msg_t *msg, bga_wire_error_t *werr);

typedef struct schema {
    uint16_t type;
    const char *name;
    int nfields;
    const field_spec *fields;
    int narrays;
    const array_spec *arrays;
    check_fn check;
} schema;

#define I64F(n, lo, hi)                                                                            \
    {                                                                                              \
        n, KIND_I64, (double)(lo), (double)(hi), 0                                                 \
    }
#define F64F(n, lo, hi)                                                                            \
    {                                                                                              \
        n, KIND_F64, lo, hi, 0                                                                     \
    }
#define F64ANY(n)                                                                                  \
    {                                                                                              \
        n, KIND_F64, -INFINITY, INFINITY, 1                                                        \
    }
#define LEASE_MAX_MS 86400000
#define FREE_LEN 0, -1, -1, -1, 0
#define NO_IDX 0, -1, 0
#define TEXT(n, opt)                                                                               \
    {                                                                                              \
        n, BGA_ELEM_BYTES, opt, FREE_LEN, 0, NO_IDX                                                \
    }
#define F64FREE(n, fin)                                                                            \
    {                                                                                              \
        n, BGA_ELEM_F64, 0, FREE_LEN, fin, NO_IDX                                                  \
    }

static const field_spec hb_fields[] = {I64F("slots", 0, 1 << 20), I64F("free_slots", 0, 1 << 20),
                                       I64F("services", 0, 7), I64F("jobs", 0, 1 << 20)};
static const array_spec hb_arrays[] = {TEXT("name", 1)};

static const field_spec err_fields[] = {I64F("code", 0, 255),
                                        I64F("frame", -1, BGA_WIRE_MAX_FRAMES),
                                        I64F("type", 0, 65535), I64F("seq", INT64_MIN, INT64_MAX)};
static const array_spec err_arrays[] = {TEXT("field", 1), TEXT("message", 0)};

static const field_spec ack_fields[] = {I64F("type", 0, 65535)};

static const field_spec rs_fields[] = {I64F("dim", 2, 3),
                                       I64F("nodes_per_element", 3, 4),
                                       I64F("vertices", 1, BGA_WIRE_MAX_VERTICES),
                                       I64F("elements", 1, BGA_WIRE_MAX_ELEMENTS),
                                       I64F("global_vertices", 1, BGA_WIRE_MAX_VERTICES),
                                       F64F("mu", 0.0, 1e300),
                                       F64F("lambda", -1e300, 1e300),
                                       F64F("barrier", 0.0, 1e300),
                                       I64F("block", 0, 78),
                                       I64F("values", 0, INT32_MAX),
                                       I64F("lease_ms", 0, LEASE_MAX_MS)};
static const array_spec rs_arrays[] = {
    {"elements", BGA_ELEM_I32, 0, 1, BGA_RS_NE, BGA_RS_NODES, -1, 0, 0, 0, BGA_RS_NV, 0},
    {"local_to_global", BGA_ELEM_I32, 0, 1, BGA_RS_NV, -1, -1, 0, 0, 0, BGA_RS_NGLOBAL, 0},
    {"rest_positions", BGA_ELEM_F64, 1, 1, BGA_RS_NV, BGA_RS_DIM, -1, 0, 1, NO_IDX},
    {"rest_edges", BGA_ELEM_F64, 1, 1, BGA_RS_NE, BGA_RS_DIM, BGA_RS_DIM, 0, 1, NO_IDX},
    {"scatter", BGA_ELEM_I32, 1, 1, BGA_RS_NE, BGA_RS_BLOCK, -1, 0, 0, -1, BGA_RS_NVAL, 0}};

static const field_spec su_fields[] = {I64F("vertices", 3, BGA_WIRE_MAX_VERTICES),
                                       I64F("triangles", 1, BGA_WIRE_MAX_ELEMENTS),
                                       I64F("global_vertices", 3, BGA_WIRE_MAX_VERTICES),
                                       I64F("owned", 1, BGA_WIRE_MAX_VERTICES),
                                       I64F("lease_ms", 0, LEASE_MAX_MS)};
static const array_spec su_arrays[] = {
    {"triangles", BGA_ELEM_I32, 0, 3, BGA_SU_NE, -1, -1, 0, 0, 0, BGA_SU_NV, 0},
    {"local_to_global", BGA_ELEM_I32, 0, 1, BGA_SU_NV, -1, -1, 0, 0, 0, BGA_SU_NGLOBAL, 0},
    {"rest_positions", BGA_ELEM_F64, 0, 3, BGA_SU_NV, -1, -1, 0, 1, NO_IDX},
    {"owned", BGA_ELEM_I32, 0, 1, BGA_SU_NOWNED, -1, -1, 0, 0, 0, BGA_SU_NV, 0}};

static const field_spec rc_fields[] = {I64F("want", 0, 7)};
static const array_spec rc_arrays[] = {F64FREE("positions", 1)};

static const field_spec rr_fields[] = {F64ANY("energy"),           I64F("fits", 0, INT64_MAX),
                                       I64F("warm", 0, INT64_MAX), I64F("polar", 0, INT64_MAX),
                                       I64F("svd", 0, INT64_MAX),  F64F("seconds", 0.0, 1e300)};
static const array_spec rr_arrays[] = {F64FREE("gradient", 0), F64FREE("hessian", 0)};

static const field_spec ss_fields[] = {I64F("n", 1, INT32_MAX - 1), I64F("nnz", 1, INT32_MAX),
                                       I64F("lease_ms", 0, LEASE_MAX_MS),
                                       I64F("options", 0, 3)};
static const array_spec ss_arrays[] = {
    {"colptr", BGA_ELEM_I32, 0, 1, BGA_SS_N, -1, -1, 1, 0, 0, BGA_SS_NNZ, 1},
    {"rowidx", BGA_ELEM_I32, 0, 1, BGA_SS_NNZ, -1, -1, 0, 0, 0, BGA_SS_N, 0}};

static const field_spec sf_fields[] = {F64F("shift", 0.0, 1e300)};
static const array_spec sf_arrays[] = {F64FREE("values", 1)};

static const field_spec sd_fields[] = {
    I64F("positive_definite", 0, 1), F64F("analyze_seconds", 0.0, 1e300),
    F64F("factor_seconds", 0.0, 1e300), F64F("flops", 0.0, 1e300),
    F64F("factor_nonzeros", 0.0, 1e300)};
static const array_spec sd_arrays[] = {TEXT("message", 1)};

static const field_spec sr_fields[] = {I64F("nrhs", 1, 64)};
static const array_spec sr_arrays[] = {F64FREE("rhs", 1)};

static const field_spec sx_fields[] = {F64F("seconds", 0.0, 1e300)};
static const array_spec sx_arrays[] = {F64FREE("x", 0)};

static const field_spec is_fields[] = {I64F("dim", 2, 3), I64F("vertices", 1, BGA_WIRE_MAX_VERTICES),
                                       F64F("h", 0.0, 1e6), F64F("damping", 0.0, 1e6),
                                       I64F("lease_ms", 0, LEASE_MAX_MS)};
static const array_spec is_arrays[] = {
    {"mass", BGA_ELEM_F64, 0, 1, BGA_IS_NV, -1, -1, 0, 1, NO_IDX},
    {"q", BGA_ELEM_F64, 0, 1, BGA_IS_NV, BGA_IS_DIM, -1, 0, 1, NO_IDX},
    {"velocity", BGA_ELEM_F64, 0, 1, BGA_IS_NV, BGA_IS_DIM, -1, 0, 1, NO_IDX},
    {"t0", BGA_ELEM_F64, 0, 1, BGA_IS_NV, BGA_IS_DIM, -1, 0, 1, NO_IDX},
    {"constrained", BGA_ELEM_I32, 0, 1, BGA_IS_NV, BGA_IS_DIM, -1, 0, 0, NO_IDX},
    {"gravity", BGA_ELEM_F64, 0, 1, BGA_IS_DIM, -1, -1, 0, 1, NO_IDX}};

static const field_spec ip_fields[] = {I64F("variational", 0, 1), I64F("trial", 0, 1),
                                       I64F("predictor", 0, 3)};
static const array_spec ip_arrays[] = {F64FREE("t1", 1)};

static const field_spec ii_fields[] = {F64F("coefficient", 0.0, 1e300),
                                       F64F("state_scale", 0.0, 1e300), I64F("candidates", 1, 3),
                                       F64F("seconds", 0.0, 1e300)};
static const array_spec ii_arrays[] = {F64FREE("prediction", 1), F64FREE("targets", 1),
                                       F64FREE("candidates", 1)};

static const array_spec iu_arrays[] = {F64FREE("q_star", 1), F64FREE("gradient", 1)};

static const field_spec it_fields[] = {
    F64F("kinetic", 0.0, 1e300),      F64F("linear_x", -1e300, 1e300),
    F64F("linear_y", -1e300, 1e300),  F64F("linear_z", -1e300, 1e300),
    F64F("angular_x", -1e300, 1e300), F64F("angular_y", -1e300, 1e300),
    F64F("angular_z", -1e300, 1e300), I64F("steps", 0, INT64_MAX),
    F64F("seconds", 0.0, 1e300)};
static const array_spec it_arrays[] = {F64FREE("q", 1)};

static const field_spec ir_fields[] = {F64F("kinetic", 0.0, 1e300),
                                       F64F("handle_work", -1e300, 1e300),
                                       F64F("seconds", 0.0, 1e300)};
static const array_spec ir_arrays[] = {F64FREE("q_next", 1)};

/* Market role messages (0x1001..0x1019, bgm_codec): one schema for all.
 * good −1 is a resource bundle; the numbers may be ±Inf (an unbounded limit
 * or deadline) but never NaN; candidates are fixed-size arrays so every
 * type's numbers survive a round trip unchanged. Agent ids stay below
 * 2^24 (the market caps agents far lower). */
static const field_spec mk_fields[] = {
    I64F("good", -1, 4),        I64F("hops", 0, 65535),       I64F("ncand", 0, BGA_MARKET_CANDIDATES),
    I64F("req", 0, UINT32_MAX), I64F("attempt", 0, UINT32_MAX), I64F("origin", 0, UINT32_MAX),
    F64ANY("price"),            F64ANY("a"),                  F64ANY("b"),
    F64ANY("c")};
static const array_spec mk_arrays[] = {
    {"cand", BGA_ELEM_I32, 0, BGA_MARKET_CANDIDATES, -1, -1, -1, 0, 0, 0, -1, 0},
    {"cand_price", BGA_ELEM_F64, 0, BGA_MARKET_CANDIDATES, -1, -1, -1, 0, 1, NO_IDX},
    {"cand_speed", BGA_ELEM_F64, 0, BGA_MARKET_CANDIDATES, -1, -1, -1, 0, 1, NO_IDX}};

static bga_wire_code check_market(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (m->header.sender > BGA_MARKET_MAX_AGENT || m->header.receiver > BGA_MARKET_MAX_AGENT)
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 0, "receiver",
                             "sender %llu or receiver %llu is not an agent id (< %d)",
                             (unsigned long long)m->header.sender,
                             (unsigned long long)m->header.receiver, BGA_MARKET_MAX_AGENT);
    for (size_t i = 0; i < m->array[BGA_MK_CAND].count; i++) {
        int32_t v = bga_msg_i32(m, BGA_MK_CAND, i);
        if (v < 0 || v > BGA_MARKET_MAX_AGENT)
            return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 2 + BGA_MK_CAND, "cand",
                                 "cand[%zu] = %d is not an agent id", i, (int)v);
    }
    return BGA_WIRE_OK;
}

/* The live market (0x1101..0x1111, bga_mmsg): one schema for all. The
 * ranges are bga_mmsg's; the texts' and the neighbours' caps are its own
 * (it checks them on both sides), the wire only bounds them. */
static const field_spec lm_fields[] = {
    I64F("agent", 0, UINT32_MAX),  I64F("target", 0, UINT32_MAX),
    I64F("origin", 0, UINT32_MAX), I64F("services", 0, 7),
    I64F("resource", 0, 1),        I64F("slots", 0, 4096),
    I64F("free_slots", 0, 4096),   I64F("good", -1, 4),
    I64F("hops", 0, 16),           I64F("attempt", 0, 1000),
    F64F("margin", 0.0, 1e15),     F64F("load_slope", 0.0, 1e15),
    F64F("term", 0.0, 1e15),       F64F("quantity", 0.0, 1e15),
    F64F("price", 0.0, 1e15),      I64F("parent", 0, (int64_t)1 << 53),
    I64F("serves", -1, 2)};
static const array_spec lm_arrays[] = {
    {"floor", BGA_ELEM_F64, 0, BGA_LIVE_GOODS, -1, -1, -1, 0, 1, NO_IDX},
    {"prices", BGA_ELEM_F64, 0, BGA_LIVE_GOODS, -1, -1, -1, 0, 1, NO_IDX},
    {"capacity", BGA_ELEM_F64, 0, 4, -1, -1, -1, 0, 1, NO_IDX},
    {"neighbours", BGA_ELEM_I32, 0, FREE_LEN, 0, NO_IDX},
    TEXT("name", 1),
    TEXT("endpoint", 1),
    TEXT("reason", 1)};

static bga_wire_code check_live(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (m->field[BGA_LM_FREE_SLOTS].i > m->field[BGA_LM_SLOTS].i)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "free_slots",
                             "free_slots %lld exceeds slots %lld",
                             (long long)m->field[BGA_LM_FREE_SLOTS].i,
                             (long long)m->field[BGA_LM_SLOTS].i);
    for (int a = BGA_LM_FLOOR; a <= BGA_LM_CAPACITY; a++)
        for (size_t i = 0; i < m->array[a].count; i++)
            if (bga_msg_f64(m, a, i) < 0)
                return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 2 + a, lm_arrays[a].name,
                                     "%s[%zu] = %g is negative", lm_arrays[a].name, i,
                                     bga_msg_f64(m, a, i));
    for (size_t i = 0; i < m->array[BGA_LM_NEIGHBOURS].count; i++)
        if (bga_msg_i32(m, BGA_LM_NEIGHBOURS, i) < 0)
            return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 2 + BGA_LM_NEIGHBOURS, "neighbours",
                                 "neighbours[%zu] = %d is not an agent id", i,
                                 (int)bga_msg_i32(m, BGA_LM_NEIGHBOURS, i));
    return BGA_WIRE_OK;
}

static bga_wire_code check_heartbeat(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (m->field[BGA_HB_FREE].i > m->field[BGA_HB_SLOTS].i)
        return bga_wire_fail(
            werr, BGA_WIRE_INCONSISTENT, 1, "free_slots", "free_slots %lld exceeds slots %lld",
            (long long)m->field[BGA_HB_FREE].i, (long long)m->field[BGA_HB_SLOTS].i);
    return BGA_WIRE_OK;
}

static bga_wire_code check_rotfit_setup(const bga_msg_t *m, bga_wire_error_t *werr)
{
    const int64_t dim = m->field[BGA_RS_DIM].i, k = m->field[BGA_RS_NODES].i;
    if (k != dim + 1)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "nodes_per_element",
                             "%lld nodes per element in dimension %lld: only triangles in 2D "
                             "and tetrahedra in 3D have an elastic energy",
                             (long long)k, (long long)dim);
    const double mu = m->field[BGA_RS_MU].f, lambda = m->field[BGA_RS_LAMBDA].f;
    if (!(mu > 0.0) || !((double)dim * lambda + 2.0 * mu > 0.0))
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, "mu",
                             "unstable material mu = %g, lambda = %g (need mu > 0 and "
                             "n lambda + 2 mu > 0)",
                             mu, lambda);
    if (dim == 3 && m->field[BGA_RS_BARRIER].f != 0.0)
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, "barrier",
                             "the area barrier exists only in 2D");
    const int has_pos = m->array[BGA_RS_REST_POSITIONS].count > 0;
    const int has_edges = m->array[BGA_RS_REST_EDGES].count > 0;
    if (has_pos == has_edges)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 2 + BGA_RS_REST_POSITIONS,
                             "rest_positions",
                             "exactly one of rest_positions and rest_edges must be given "
                             "(got %s)",
                             has_pos ? "both" : "neither");
    const int64_t local = k * dim, tri = local * (local + 1) / 2;
    const int64_t block = m->field[BGA_RS_BLOCK].i, nval = m->field[BGA_RS_NVAL].i;
    if (block != tri)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "block",
                             "block %lld, but an element's packed Hessian has %lld entries",
                             (long long)block, (long long)tri);
    /* The partition touches at most ne·T entries: a larger count would only
     * make the agent allocate for nothing. */
    if (nval > m->field[BGA_RS_NE].i * tri)
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, "values",
                             "values = %lld exceeds elements x block = %lld", (long long)nval,
                             (long long)(m->field[BGA_RS_NE].i * tri));
    if ((nval > 0) != (m->array[BGA_RS_SCATTER].count > 0))
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 2 + BGA_RS_SCATTER, "scatter",
                             "values = %lld needs %s scatter map", (long long)nval,
                             nval > 0 ? "a" : "no");
    return BGA_WIRE_OK;
}

static bga_wire_code check_surf_setup(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (m->field[BGA_SU_NOWNED].i > m->field[BGA_SU_NV].i)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "owned",
                             "%lld owned vertices of %lld", (long long)m->field[BGA_SU_NOWNED].i,
                             (long long)m->field[BGA_SU_NV].i);
    return BGA_WIRE_OK;
}

static bga_wire_code check_rotfit_call(const bga_msg_t *m, bga_wire_error_t *werr)
{
    const int64_t want = m->field[BGA_RC_WANT].i;
    if ((want & BGA_WANT_PROJECTED) && !(want & BGA_WANT_HESSIAN))
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, 1, "want",
                             "want asks for a projected Hessian without the Hessian");
    return BGA_WIRE_OK;
}

static bga_wire_code check_solve_setup(const bga_msg_t *m, bga_wire_error_t *werr)
{
    const int32_t n = (int32_t)m->field[BGA_SS_N].i, nnz = (int32_t)m->field[BGA_SS_NNZ].i;
    const int cf = 2 + BGA_SS_COLPTR, rf = 2 + BGA_SS_ROWIDX;
    if (bga_msg_i32(m, BGA_SS_COLPTR, 0) != 0)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, cf, "colptr", "colptr[0] is %d, not 0",
                             (int)bga_msg_i32(m, BGA_SS_COLPTR, 0));
    if (bga_msg_i32(m, BGA_SS_COLPTR, (size_t)n) != nnz)
        return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, cf, "colptr",
                             "colptr[%d] is %d, not nnz = %d", (int)n,
                             (int)bga_msg_i32(m, BGA_SS_COLPTR, (size_t)n), (int)nnz);
    for (int32_t col = 0; col < n; col++) {
        const int32_t p0 = bga_msg_i32(m, BGA_SS_COLPTR, (size_t)col);
        const int32_t p1 = bga_msg_i32(m, BGA_SS_COLPTR, (size_t)col + 1);
        if (p1 <= p0)
            return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, cf, "colptr",
                                 "column %d is empty or colptr decreases (%d, %d): every "
                                 "column needs its diagonal",
                                 (int)col, (int)p0, (int)p1);
        if (bga_msg_i32(m, BGA_SS_ROWIDX, (size_t)p0) != col)
            return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, rf, "rowidx",
                                 "column %d starts at row %d: the lower triangle must start "
                                 "at the diagonal",
                                 (int)col, (int)bga_msg_i32(m, BGA_SS_ROWIDX, (size_t)p0));
        for (int32_t p = p0 + 1; p < p1; p++)
            if (bga_msg_i32(m, BGA_SS_ROWIDX, (size_t)p) <=
                bga_msg_i32(m, BGA_SS_ROWIDX, (size_t)p - 1))
                return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, rf, "rowidx",
                                     "rows of column %d not strictly increasing at entry %d",
                                     (int)col, (int)p);
    }
    return BGA_WIRE_OK;
}

static bga_wire_code check_solve_rhs(const bga_msg_t *m, bga_wire_error_t *werr)
{
    const size_t len = m->array[BGA_SR_RHS].count, nrhs = (size_t)m->field[BGA_SR_NRHS].i;
    if (len == 0 || len % nrhs != 0)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_SR_RHS, "rhs",
                             "%zu values do not make %zu non-empty right-hand sides", len, nrhs);
    return BGA_WIRE_OK;
}

static bga_wire_code check_integ_setup(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (!(m->field[BGA_IS_H].f > 0.0))
        return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, "h",
                             "time step h = %g is not "
                             "positive",
                             m->field[BGA_IS_H].f);
    for (size_t v = 0; v < m->array[BGA_IS_MASS].count; v++)
        if (!(bga_msg_f64(m, BGA_IS_MASS, v) > 0.0))
            return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 2 + BGA_IS_MASS, "mass",
                                 "mass[%zu] = %g is not positive", v,
                                 bga_msg_f64(m, BGA_IS_MASS, v));
    for (size_t i = 0; i < m->array[BGA_IS_CONSTRAINED].count; i++) {
        const int32_t c = bga_msg_i32(m, BGA_IS_CONSTRAINED, i);
        if (c != 0 && c != 1)
            return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 2 + BGA_IS_CONSTRAINED,
                                 "constrained", "constrained[%zu] = %d, must be 0 or 1", i,
                                 (int)c);
    }
    return BGA_WIRE_OK;
}

static bga_wire_code check_integ_update(const bga_msg_t *m, bga_wire_error_t *werr)
{
    if (m->array[BGA_IU_QSTAR].count != m->array[BGA_IU_GRAD].count)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_IU_GRAD, "gradient",
                             "%zu gradient values for %zu positions", m->array[BGA_IU_GRAD].count,
                             m->array[BGA_IU_QSTAR].count);
    return BGA_WIRE_OK;
}

/* The candidates are whole position vectors, as many as announced. */
static bga_wire_code check_integ_inertia(const bga_msg_t *m, bga_wire_error_t *werr)
{
    const size_t n = m->array[BGA_II_PREDICT].count;
    if (m->array[BGA_II_TARGETS].count != n ||
        m->array[BGA_II_CANDIDATES].count != n * (size_t)m->field[BGA_II_NCAND].i)
        return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, 2 + BGA_II_CANDIDATES, "candidates",
                             "%zu targets and %zu candidate values for %lld candidates of %zu "
                             "positions",
                             m->array[BGA_II_TARGETS].count, m->array[BGA_II_CANDIDATES].count,
                             (long long)m->field[BGA_II_NCAND].i, n);
    return BGA_WIRE_OK;
}

#define SCHEMA(t, n, f, a, c)                                                                      \
    {                                                                                              \
        t, n, (int)(sizeof f / sizeof f[0]), f, (int)(sizeof a / sizeof a[0]), a, c                \
    }
#define SCHEMA_NOARRAYS(t, n, f, c)                                                                \
    {                                                                                              \
        t, n, (int)(sizeof f / sizeof f[0]), f, 0, NULL, c                                         \
    }

static const schema SCHEMAS[] = {
    SCHEMA(BGA_HEARTBEAT, "heartbeat", hb_fields, hb_arrays, check_heartbeat),
    SCHEMA(BGA_ERROR, "error", err_fields, err_arrays, NULL),
    {BGA_RELEASE, "release", 0, NULL, 0, NULL, NULL},
    SCHEMA_NOARRAYS(BGA_ACK, "ack", ack_fields, NULL),
    SCHEMA(BGA_ROTFIT_SETUP, "rotfit-setup", rs_fields, rs_arrays, check_rotfit_setup),
    SCHEMA(BGA_ROTFIT_CALL, "rotfit-call", rc_fields, rc_arrays, check_rotfit_call),
    SCHEMA(BGA_ROTFIT_RESULT, "rotfit-result", rr_fields, rr_arrays, NULL),
    SCHEMA(BGA_SURF_SETUP, "surface-setup", su_fields, su_arrays, check_surf_setup),
    SCHEMA(BGA_SOLVE_SETUP, "solve-setup", ss_fields, ss_arrays, check_solve_setup),
    SCHEMA(BGA_SOLVE_FACTOR, "solve-factor", sf_fields, sf_arrays, NULL),
    SCHEMA(BGA_SOLVE_FACTORED, "solve-factored", sd_fields, sd_arrays, NULL),
    SCHEMA(BGA_SOLVE_RHS, "solve-rhs", sr_fields, sr_arrays, check_solve_rhs),
    SCHEMA(BGA_SOLVE_RESULT, "solve-result", sx_fields, sx_arrays, NULL),
    SCHEMA(BGA_INTEG_SETUP, "integ-setup", is_fields, is_arrays, check_integ_setup),
    SCHEMA(BGA_INTEG_PREDICT, "integ-predict", ip_fields, ip_arrays, NULL),
    SCHEMA(BGA_INTEG_INERTIA, "integ-inertia", ii_fields, ii_arrays, check_integ_inertia),
    {BGA_INTEG_UPDATE, "integ-update", 0, NULL, 2, iu_arrays, check_integ_update},
    SCHEMA(BGA_INTEG_STATE, "integ-state", it_fields, it_arrays, NULL),
    SCHEMA(BGA_INTEG_TRIAL, "integ-trial", ir_fields, ir_arrays, NULL),
    {BGA_INTEG_ACCEPT, "integ-accept", 0, NULL, 0, NULL, NULL},
    SCHEMA(0x1001, "market-bid", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1002, "market-ask", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1003, "market-free", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1004, "market-match", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1005, "market-rbid", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1006, "market-rask", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1007, "market-rfree", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1008, "market-raward", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1009, "market-rfail", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100a, "market-rconfirm", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100b, "market-confirm", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100c, "market-cancel", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100d, "market-cfp", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100e, "market-propose", mk_fields, mk_arrays, check_market),
    SCHEMA(0x100f, "market-offer", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1010, "market-accept", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1011, "market-reject", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1012, "market-genes", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1013, "market-query", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1014, "market-list", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1015, "market-order", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1016, "market-avail", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1017, "market-rpart", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1018, "market-take", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1019, "market-refuse", mk_fields, mk_arrays, check_market),
    SCHEMA(0x1101, "live-register", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1102, "live-registered", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1103, "live-heartbeat", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1104, "live-order", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1105, "live-confirm", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1106, "live-refuse", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1107, "live-release", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1108, "live-cfp", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1109, "live-propose", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110a, "live-offer", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110b, "live-accept", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110c, "live-reject", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110d, "live-relay", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110e, "live-error", lm_fields, lm_arrays, check_live),
    SCHEMA(0x110f, "live-rbuy", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1110, "live-rbought", lm_fields, lm_arrays, check_live),
    SCHEMA(0x1111, "live-rfail", lm_fields, lm_arrays, check_live),
};

static const schema *find_schema(uint16_t type)
{
    for (size_t i = 0; i < sizeof SCHEMAS / sizeof SCHEMAS[0]; i++)
        if (SCHEMAS[i].type == type)
            return &SCHEMAS[i];
    return NULL;
}

const char *bga_type_name(uint16_t type)
{
    const schema *s = find_schema(type);
    return s ? s->name : "unknown";
}

int bga_type_known(uint16_t type)
{
    return find_schema(type) != NULL;
}

int bga_type_nfields(uint16_t type)
{
    const schema *s = find_schema(type);
    return s ? s->nfields : 0;
}

int bga_type_narrays(uint16_t type)
{
    const schema *s = find_schema(type);
    return s ? s->narrays : 0;
}

const char *bga_wire_code_name(bga_wire_code code)
{
    switch (code) {
    case BGA_WIRE_OK:
        return "ok";
    case BGA_WIRE_TRUNCATED:
        return "truncated";
    case BGA_WIRE_OVERSIZE:
        return "oversize";
    case BGA_WIRE_BAD_MAGIC:
        return "bad magic";
    case BGA_WIRE_WRONG_VERSION:
        return "wrong version";
    case BGA_WIRE_UNKNOWN_TYPE:
        return "unknown type";
    case BGA_WIRE_FRAME_COUNT:
        return "wrong frame count";
    case BGA_WIRE_BAD_LENGTH:
        return "bad length";
    case BGA_WIRE_NOT_FINITE:
        return "not finite";
    case BGA_WIRE_OUT_OF_RANGE:
        return "out of range";
    case BGA_WIRE_INCONSISTENT:
        return "inconsistent";
    case BGA_WIRE_BAD_HEADER:
        return "bad header";
    case BGA_WIRE_NO_JOB:
        return "no such job";
    case BGA_WIRE_BUSY:
        return "no free slot";
    case BGA_WIRE_WRONG_STATE:
        return "wrong state";
    case BGA_WIRE_NUMERIC:
        return "numerical failure";
    case BGA_WIRE_INTERNAL:
        return "internal error";
    case BGA_WIRE_UNEXPECTED:
        return "unexpected message";
    }
    return "unknown code";
}

bga_limits_t bga_wire_default_limits(void)
{
    bga_limits_t l = {BGA_WIRE_MAX_FRAME_BYTES, BGA_WIRE_MAX_MESSAGE_BYTES};
    return l;
}

bga_wire_code bga_wire_fail(bga_wire_error_t *werr, bga_wire_code code, int frame,
                            const char *field, const char *fmt, ...)
{
    if (!werr)
        return code;
    werr->code = code;
    werr->frame = frame;
    snprintf(werr->field, sizeof werr->field, "%s", field ? field : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(werr->message, sizeof werr->message, fmt, ap);
    va_end(ap);
    return code;
}

/* Little-endian loads and stores, independent of the alignment of
 * ZeroMQ's buffers: memcpy on a little-endian host (one unaligned load),
 * byte by byte elsewhere. */
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
#define LE_HOST 1
#else
#define LE_HOST 0
#endif

/* The low n bytes of v (n ≤ 8), little-endian at p, and back. */
static uint64_t load_le(const uint8_t *p, int n)
{
    uint64_t v = 0;
    if (LE_HOST) {
        memcpy(&v, p, (size_t)n);
        return v;
    }
    for (int i = n - 1; i >= 0; i--)
        v = (v << 8) | p[i];
    return v;
}

static void store_le(uint8_t *p, uint64_t v, int n)
{
    if (LE_HOST) {
        memcpy(p, &v, (size_t)n);
        return;
    }
    for (int i = 0; i < n; i++, v >>= 8)
        p[i] = (uint8_t)(v & 0xff);
}

static uint64_t load_u64(const uint8_t *p)
{
    return load_le(p, 8);
}
static uint32_t load_u32(const uint8_t *p)
{
    return (uint32_t)load_le(p, 4);
}
static uint16_t load_u16(const uint8_t *p)
{
    return (uint16_t)load_le(p, 2);
}
static void store_u64(uint8_t *p, uint64_t v)
{
    store_le(p, v, 8);
}
static void store_u32(uint8_t *p, uint32_t v)
{
    store_le(p, v, 4);
}
static void store_u16(uint8_t *p, uint16_t v)
{
    store_le(p, v, 2);
}

static double u64_to_f64(uint64_t u)
{
    double d;
    memcpy(&d, &u, sizeof d);
    return d;
}

static uint64_t f64_to_u64(double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    return u;
}

static size_t elem_size(int elem)
{
    return elem == BGA_ELEM_F64 ? 8 : elem == BGA_ELEM_I32 ? 4 : 1;
}

double bga_msg_f64(const bga_msg_t *msg, int array, size_t i)
{
    return u64_to_f64(load_u64((const uint8_t *)msg->array[array].data + 8 * i));
}

int32_t bga_msg_i32(const bga_msg_t *msg, int array, size_t i)
{
    return (int32_t)load_u32((const uint8_t *)msg->array[array].data + 4 * i);
}

void bga_msg_copy_f64(const bga_msg_t *msg, int array, double *dst)
{
    const uint8_t *p = msg->array[array].data;
    if (LE_HOST) {
        if (msg->array[array].count > 0)
            memcpy(dst, p, msg->array[array].count * sizeof *dst);
        return;
    }
    for (size_t i = 0; i < msg->array[array].count; i++)
        dst[i] = u64_to_f64(load_u64(p + 8 * i));
}

void bga_msg_copy_i32(const bga_msg_t *msg, int array, int32_t *dst)
{
    const uint8_t *p = msg->array[array].data;
    if (LE_HOST) {
        if (msg->array[array].count > 0)
            memcpy(dst, p, msg->array[array].count * sizeof *dst);
        return;
    }
    for (size_t i = 0; i < msg->array[array].count; i++)
        dst[i] = (int32_t)load_u32(p + 4 * i);
}

void bga_msg_init(bga_msg_t *msg, uint16_t type, uint64_t job, uint64_t seq)
{
    memset(msg, 0, sizeof *msg);
    msg->header.version = BGA_WIRE_VERSION;
    msg->header.type = type;
    msg->header.job = job;
    msg->header.seq = seq;
    msg->nfields = bga_type_nfields(type);
    msg->narrays = bga_type_narrays(type);
}

/* Element i of array a of msg: host memory when `host`, wire bytes else. */
static double get_f64(const bga_msg_t *msg, int a, size_t i, int host)
{
    return host ? ((const double *)msg->array[a].data)[i] : bga_msg_f64(msg, a, i);
}

static int32_t get_i32(const bga_msg_t *msg, int a, size_t i, int host)
{
    return host ? ((const int32_t *)msg->array[a].data)[i] : bga_msg_i32(msg, a, i);
}

static int64_t field_or_one(const bga_msg_t *msg, int f)
{
    return f < 0 ? 1 : msg->field[f].i;
}

/* The schema checks shared by decode (wire arrays) and encode (host
 * arrays): field ranges, array lengths, values, the type's own check. */
static bga_wire_code validate(const schema *s, const bga_msg_t *msg, int host,
                              bga_wire_error_t *werr)
{
    for (int f = 0; f < s->nfields; f++) {
        const field_spec *fs = &s->fields[f];
        if (fs->kind == KIND_I64) {
            const int64_t v = msg->field[f].i;
            /* The bounds are exact in double except INT64_MAX/MIN, whose
             * checks are vacuous. */
            if ((fs->min > (double)INT64_MIN && (double)v < fs->min) ||
                (fs->max < (double)INT64_MAX && (double)v > fs->max))
                return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, fs->name,
                                     "%s: field %s = %lld outside [%.0f, %.0f]", s->name, fs->name,
                                     (long long)v, fs->min, fs->max);
        } else {
            const double v = msg->field[f].f;
            if (isnan(v) || (!fs->nonfinite && !isfinite(v)))
                return bga_wire_fail(werr, BGA_WIRE_NOT_FINITE, 1, fs->name,
                                     "%s: field %s is %g, must be finite", s->name, fs->name, v);
            if (v < fs->min || v > fs->max)
                return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, 1, fs->name,
                                     "%s: field %s = %g outside [%g, %g]", s->name, fs->name, v,
                                     fs->min, fs->max);
        }
    }
    for (int a = 0; a < s->narrays; a++) {
        const array_spec *as = &s->arrays[a];
        const size_t count = msg->array[a].count;
        const int frame = 2 + a;
        if (count > 0 && !msg->array[a].data)
            return bga_wire_fail(werr, BGA_WIRE_TRUNCATED, frame, as->name,
                                 "%s: array %s has %zu values and no data", s->name, as->name,
                                 count);
        if (as->mul > 0 && !(as->optional && count == 0)) {
            /* Field caps keep this product far below 2^63. */
            const int64_t want = as->mul * field_or_one(msg, as->a) * field_or_one(msg, as->b) *
                                     field_or_one(msg, as->c) +
                                 as->add;
            if ((int64_t)count != want)
                return bga_wire_fail(werr, BGA_WIRE_BAD_LENGTH, frame, as->name,
                                     "%s: array %s has %zu values, expected %lld", s->name,
                                     as->name, count, (long long)want);
        }
        if (as->elem == BGA_ELEM_F64 && as->finite) {
            for (size_t i = 0; i < count; i++)
                if (!isfinite(get_f64(msg, a, i, host)))
                    return bga_wire_fail(werr, BGA_WIRE_NOT_FINITE, frame, as->name,
                                         "%s: %s[%zu] is %g, must be finite", s->name, as->name, i,
                                         get_f64(msg, a, i, host));
        } else if (as->elem == BGA_ELEM_F64) {
            for (size_t i = 0; i < count; i++)
                if (isnan(get_f64(msg, a, i, host)))
                    return bga_wire_fail(werr, BGA_WIRE_NOT_FINITE, frame, as->name,
                                         "%s: %s[%zu] is NaN", s->name, as->name, i);
        } else if (as->elem == BGA_ELEM_I32 && as->hi >= 0) {
            const int64_t hi = msg->field[as->hi].i + as->hi_add;
            for (size_t i = 0; i < count; i++) {
                const int32_t v = get_i32(msg, a, i, host);
                if (v < as->lo || v >= hi)
                    return bga_wire_fail(werr, BGA_WIRE_OUT_OF_RANGE, frame, as->name,
                                         "%s: %s[%zu] = %d outside [%d, %lld)", s->name, as->name,
                                         i, (int)v, (int)as->lo, (long long)hi);
            }
        } else if (as->elem == BGA_ELEM_BYTES) {
            if (count > BGA_WIRE_MAX_TEXT)
                return bga_wire_fail(werr, BGA_WIRE_OVERSIZE, frame, as->name,
                                     "%s: text %s has %zu bytes, cap %d", s->name, as->name, count,
                                     BGA_WIRE_MAX_TEXT);
            if (count > 0 && memchr(msg->array[a].data, 0, count))
                return bga_wire_fail(werr, BGA_WIRE_INCONSISTENT, frame, as->name,
                                     "%s: text %s contains a NUL byte", s->name, as->name);
        }
    }
    if (!host && s->check) /* host-built messages take the same check below */
        return s->check(msg, werr);
    return BGA_WIRE_OK;
}

bga_wire_code bga_wire_decode(const bga_frame_t *frames, int nframes, const bga_limits_t *limits,
                              bga_msg_t *msg, bga_wire_error_t *werr)
{
    const bga_limits_t def = bga_wire_default_limits();
    if (!limits)
        limits = &def;
    memset(msg, 0, sizeof *msg);
    if (werr)
        memset(werr, 0, sizeof *werr);
    if (nframes < 1 || !frames)
        return bga_wire_fail(werr, BGA_WIRE_FRAME_COUNT, -1, "", "empty message: no header frame");
    size_t total = 0;
    for (int i = 0; i < nframes; i++) {
        if (frames[i].size > limits->max_frame_bytes)
            return bga_wire_fail(werr, BGA_WIRE_OVERSIZE, i, "", "frame %d has %zu bytes, cap %zu",
                                 i, frames[i].size, limits->max_frame_bytes);
        if (frames[i].size > 0 && !frames[i].data)
            return bga_wire_fail(werr, BGA_WIRE_TRUNCATED, i, "", "frame %d has no data", i);
        total += frames[i].size;
        if (total > limits->max_message_bytes)
            return bga_wire_fail(werr, BGA_WIRE_OVERSIZE, i, "",
                                 "message over %zu bytes at frame %d", limits->max_message_bytes,
                                 i);
    }
    const uint8_t *h = frames[0].data;
    if (frames[0].size < BGA_WIRE_HEADER_BYTES)
        return bga_wire_fail(werr, BGA_WIRE_TRUNCATED, 0, "header",
                             "header frame has %zu bytes, expected %d", frames[0].size,
                             BGA_WIRE_HEADER_BYTES);
    if (frames[0].size > BGA_WIRE_HEADER_BYTES)
        return bga_wire_fail(werr, BGA_WIRE_OVERSIZE, 0, "header",
                             "header frame has %zu bytes, expected %d", frames[0].size,
                             BGA_WIRE_HEADER_BYTES);
    if (memcmp(h, MAGIC, 4) != 0)
        return bga_wire_fail(werr, BGA_WIRE_BAD_MAGIC, 0, "magic",
                             "header does not start with \"bgwp\"");
    msg->header.version = load_u16(h + 4);
    msg->header.type = load_u16(h + 6);
    msg->header.job = load_u64(h + 8);
    msg->header.seq = load_u64(h + 16);
    msg->header.sender = load_u64(h + 24);
    msg->header.receiver = load_u64(h + 32);
    if (msg->header.version != BGA_WIRE_VERSION)
        return bga_wire_fail(werr, BGA_WIRE_WRONG_VERSION, 0, "version",
                             "protocol version %u, this side speaks %d",
                             (unsigned)msg->header.version, BGA_WIRE_VERSION);
    if (load_u32(h + 40) != 0 || load_u32(h + 44) != 0)
        return bga_wire_fail(werr, BGA_WIRE_BAD_HEADER, 0, "flags",
                             "flags/reserved are 0x%x/0x%x, must be 0 in version %d",
                             (unsigned)load_u32(h + 40), (unsigned)load_u32(h + 44),
                             BGA_WIRE_VERSION);
    const schema *s = find_schema(msg->header.type);
    if (!s)
        return bga_wire_fail(werr, BGA_WIRE_UNKNOWN_TYPE, 0, "type", "unknown message type 0x%04x",
                             (unsigned)msg->header.type);
    if (nframes != 2 + s->narrays)
        return bga_wire_fail(werr, BGA_WIRE_FRAME_COUNT, -1, "",
                             "%s: %d frames, expected %d (header, fields, %d arrays)", s->name,
                             nframes, 2 + s->narrays, s->narrays);
    msg->nfields = s->nfields;
    msg->narrays = s->narrays;
    if (frames[1].size != (size_t)s->nfields * 8)
        return bga_wire_fail(
            werr, frames[1].size < (size_t)s->nfields * 8 ? BGA_WIRE_TRUNCATED : BGA_WIRE_OVERSIZE,
            1, "fields", "%s: field frame has %zu bytes, expected %d", s->name, frames[1].size,
            s->nfields * 8);
    for (int f = 0; f < s->nfields; f++) {
        const uint64_t u = load_u64(frames[1].data + 8 * f);
        if (s->fields[f].kind == KIND_I64)
            msg->field[f].i = (int64_t)u;
        else
            msg->field[f].f = u64_to_f64(u);
    }
    for (int a = 0; a < s->narrays; a++) {
        const size_t es = elem_size(s->arrays[a].elem);
        const bga_frame_t *fr = &frames[2 + a];
        if (fr->size % es != 0)
            return bga_wire_fail(werr, BGA_WIRE_TRUNCATED, 2 + a, s->arrays[a].name,
                                 "%s: array %s frame has %zu bytes, not a multiple of %zu", s->name,
                                 s->arrays[a].name, fr->size, es);
        msg->array[a].data = fr->data;
        msg->array[a].count = fr->size / es;
    }
    return validate(s, msg, 0, werr);
}

void bga_frames_free(bga_frames_t *frames)
{
    if (!frames)
        return;
    for (int i = 0; i < frames->count; i++)
        free(frames->data[i]);
    memset(frames, 0, sizeof *frames);
}

void bga_frames_view(const bga_frames_t *frames, bga_frame_t *views)
{
    for (int i = 0; i < frames->count; i++) {
        views[i].data = frames->data[i];
        views[i].size = frames->size[i];
    }
}

size_t bga_frames_bytes(const bga_frames_t *frames)
{
    size_t total = 0;
    for (int i = 0; i < frames->count; i++)
        total += frames->size[i];
    return total;
}

/* The per-type checks read wire bytes (bga_msg_*), so for a host-built
 * message they run on the encoded frames, decoded again. */
bg_status bga_wire_encode(const bga_msg_t *msg, bga_frames_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    const schema *s = find_schema(msg->header.type);
    bga_wire_error_t werr;
    if (!s)
        return bg_error_set(err, BG_ERR_INVALID, "encoding an unknown message type 0x%04x",
                            (unsigned)msg->header.type);
    if (validate(s, msg, 1, &werr) != BGA_WIRE_OK)
        return bg_error_set(err, BG_ERR_INVALID, "encoding %s: %s", s->name, werr.message);
    out->count = 2 + s->narrays;
    out->size[0] = BGA_WIRE_HEADER_BYTES;
    out->size[1] = (size_t)s->nfields * 8;
    for (int a = 0; a < s->narrays; a++)
        out->size[2 + a] = msg->array[a].count * elem_size(s->arrays[a].elem);
    for (int i = 0; i < out->count; i++) {
        out->data[i] = malloc(out->size[i] + 1);
        if (!out->data[i]) {
            bga_frames_free(out);
            return bg_error_set(err, BG_ERR_NOMEM,
                                "out of memory encoding %s (frame %d, %zu "
                                "bytes)",
                                s->name, i, out->size[i]);
        }
    }
    uint8_t *h = out->data[0];
    memcpy(h, MAGIC, 4);
    store_u16(h + 4, BGA_WIRE_VERSION);
    store_u16(h + 6, msg->header.type);
    store_u64(h + 8, msg->header.job);
    store_u64(h + 16, msg->header.seq);
    store_u64(h + 24, msg->header.sender);
    store_u64(h + 32, msg->header.receiver);
    store_u32(h + 40, 0);
    store_u32(h + 44, 0);
    for (int f = 0; f < s->nfields; f++)
        store_u64(out->data[1] + 8 * f, s->fields[f].kind == KIND_I64
                                            ? (uint64_t)msg->field[f].i
                                            : f64_to_u64(msg->field[f].f));
    for (int a = 0; a < s->narrays; a++) {
        uint8_t *p = out->data[2 + a];
        const size_t count = msg->array[a].count;
        if (LE_HOST && count > 0 && s->arrays[a].elem != BGA_ELEM_BYTES) {
            memcpy(p, msg->array[a].data, out->size[2 + a]);
        } else if (s->arrays[a].elem == BGA_ELEM_F64) {
            const double *src = msg->array[a].data;
            for (size_t i = 0; i < count; i++)
                store_u64(p + 8 * i, f64_to_u64(src[i]));
        } else if (s->arrays[a].elem == BGA_ELEM_I32) {
            const int32_t *src = msg->array[a].data;
            for (size_t i = 0; i < count; i++)
                store_u32(p + 4 * i, (uint32_t)src[i]);
        } else if (count > 0) {
            memcpy(p, msg->array[a].data, count);
        }
    }
    if (s->check) {
        bga_frame_t views[BGA_WIRE_MAX_FRAMES];
        bga_msg_t back;
        bga_frames_view(out, views);
        bga_limits_t unlimited = {SIZE_MAX, SIZE_MAX};
        if (bga_wire_decode(views, out->count, &unlimited, &back, &werr) != BGA_WIRE_OK) {
            bga_frames_free(out);
            return bg_error_set(err, BG_ERR_INVALID, "encoding %s: %s", s->name, werr.message);
        }
    }
    return BG_OK;
}

bg_status bga_wire_error_reply(const bga_header_t *to, const bga_wire_error_t *werr,
                               bga_frames_t *out, bg_error_t *err)
{
    bga_msg_t m;
    bga_msg_init(&m, BGA_ERROR, to ? to->job : 0, to ? to->seq : 0);
    if (to) {
        m.header.sender = to->receiver;
        m.header.receiver = to->sender;
    }
    m.field[BGA_ERR_CODE].i = werr->code;
    m.field[BGA_ERR_FRAME].i = werr->frame;
    m.field[BGA_ERR_TYPE].i = to ? to->type : 0;
    m.field[BGA_ERR_SEQ].i = to ? (int64_t)to->seq : 0;
    m.array[BGA_ERR_FIELD].data = werr->field;
    m.array[BGA_ERR_FIELD].count = strnlen(werr->field, sizeof werr->field);
    m.array[BGA_ERR_MESSAGE].data = werr->message;
    m.array[BGA_ERR_MESSAGE].count = strnlen(werr->message, sizeof werr->message);
    return bga_wire_encode(&m, out, err);
}
