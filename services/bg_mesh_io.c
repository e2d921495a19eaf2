/*
 * bg_mesh_io — mesh readers and writers (the formats are listed in
 * bg_mesh_io.h).
 *
 * Every reader runs on one bounded scanner over (text, length): tokens are
 * spans of the input, never NUL-terminated in place, and numbers are
 * converted from a small local copy, so nothing reads past `length` and
 * the input need not be NUL-terminated.
 *
 * Records are line-oriented (one vertex or element per line, as every
 * writer of these formats emits): the first field of a record may follow
 * blank or comment lines, the other fields must be on the same line, and
 * anything left on the line is an error. That is what lets a message name
 * the line and the record, and what catches trailing garbage and records
 * missing a field (which a free-format reader would silently re-align).
 *
 * Declared counts are checked against the bytes that remain before any
 * array is sized by them, so a short file claiming 10^9 vertices fails at
 * once; lists without a declared count (OBJ, OFF faces, Gmsh elements)
 * grow geometrically under the BG_MESH_MAX_* caps.
 */
#include "bg_mesh_io.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Longest numeric token accepted (%.17g needs at most 24 characters). */
#define NUMBER_MAX_CHARS 128
/* Decimal digits an integer token may have: 18 always fit in int64_t. */
#define INT_MAX_DIGITS 18
/* Every field takes at least one character and one separator. */
#define MIN_FIELD_BYTES 2
/* Characters of an offending token quoted in a message. */
#define QUOTE_MAX_CHARS 24
/* Room for the detail part of a message before "name:line: " is added. */
#define DETAIL_MAX_CHARS 256
/* stdio buffer for writers: large writes are much faster than 4 KiB ones. */
#define WRITE_BUFFER_BYTES ((size_t)1 << 20)
/* First capacity of a growing list; it doubles from there. */
#define LIST_FIRST_CAPACITY 1024
/* Relative tolerance of bg_mesh_to_planar (see the header). */
#define PLANAR_TOLERANCE 1e-12
/* Exact round trips need 17 significant digits. */
#define DOUBLE_FORMAT "%.17g"
/* Integers written with the 17-digit format that are exact in a double. */
#define INT32_LIMIT 2147483647LL

/* MEDIT: versions 1 (single), 2 (double), 3 and 4 (64-bit) share the ASCII layout. */
#define MEDIT_VERSION_MAX 4
/* MEDIT keyword whose records have one field per coordinate. */
#define MEDIT_FIELDS_DIM (-1)

/* VTK cell types (vtkCellType.h). */
#define VTK_TRIANGLE 5
#define VTK_TETRA 10

/* Gmsh element types (gmsh reference manual, "MSH file format"). */
#define GMSH_TRIANGLE 2
#define GMSH_TETRAHEDRON 4
#define GMSH_TRIANGLE6 9
#define GMSH_TETRAHEDRON10 11
/* Gmsh file-type field: 0 = ASCII, 1 = binary. */
#define GMSH_ASCII 0
/* Gmsh entity dimensions are 0 (points) to 3 (volumes). */
#define GMSH_MAX_ENTITY_DIM 3

/* TetGen: corner counts per element in .ele (second-order lists more nodes). */
#define TETGEN_TRIANGLE6 6
#define TETGEN_TETRAHEDRON10 10

/* ------------------------------------------------------------------------
 * Scanner
 */

typedef struct scan {
    const char *p;   /* next unread byte */
    const char *end; /* one past the last byte */
    const char *name;
    long line;    /* 1-based line of p, hence of the last token read */
    char comment; /* byte that starts a comment to end of line, or 0 */
    bg_error_t *err;
} scan_t;

typedef struct token {
    const char *p;
    size_t n;
} token_t;

static void sc_init(scan_t *s, const char *text, size_t length, const char *name, char comment,
                    bg_error_t *err)
{
    s->p = text;
    s->end = text + length;
    s->name = name ? name : "(unnamed)";
    s->line = 1;
    s->comment = comment;
    s->err = err;
}

static int is_blank(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

static int is_space(char c)
{
    return is_blank(c) || c == '\n';
}

/* Skips blanks and a comment on the current line; stops at '\n' or the end. */
static void sc_skip_inline(scan_t *s)
{
    while (s->p < s->end && is_blank(*s->p))
        s->p++;
    if (s->comment && s->p < s->end && *s->p == s->comment)
        while (s->p < s->end && *s->p != '\n')
            s->p++;
}

/* Skips blanks, comments and whole lines up to the next token. */
static void sc_skip_lines(scan_t *s)
{
    for (;;) {
        sc_skip_inline(s);
        if (s->p < s->end && *s->p == '\n') {
            s->p++;
            s->line++;
            continue;
        }
        return;
    }
}

static int sc_at_eol(scan_t *s)
{
    sc_skip_inline(s);
    return s->p == s->end || *s->p == '\n';
}

static int sc_at_end(scan_t *s)
{
    sc_skip_lines(s);
    return s->p == s->end;
}

/* Moves to the '\n' ending the current line (not past it). */
static void sc_skip_rest_of_line(scan_t *s)
{
    while (s->p < s->end && *s->p != '\n')
        s->p++;
}

/*
 * Next whitespace-delimited token: on the current line only (cross = 0) or
 * after any blank and comment lines (cross = 1). Returns 0 at the end of
 * the line or the input.
 */
static int sc_token(scan_t *s, int cross, token_t *t)
{
    if (cross)
        sc_skip_lines(s);
    else
        sc_skip_inline(s);
    if (s->p == s->end || *s->p == '\n')
        return 0;
    t->p = s->p;
    while (s->p < s->end && !is_space(*s->p))
        s->p++;
    t->n = (size_t)(s->p - t->p);
    return 1;
}

static int tok_is(const token_t *t, const char *word)
{
    size_t n = strlen(word);
    return t->n == n && memcmp(t->p, word, n) == 0;
}

static int lower(char c)
{
    return c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c;
}

static int tok_is_nocase(const token_t *t, const char *word)
{
    size_t n = strlen(word);
    if (t->n != n)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (lower(t->p[i]) != lower(word[i]))
            return 0;
    return 1;
}

/* Copies up to QUOTE_MAX_CHARS of a token for a message, masking bytes
 * that are not printable ASCII so a binary file cannot garble the text. */
static void quote_token(const token_t *t, char *buf, size_t size)
{
    size_t n = t->n < QUOTE_MAX_CHARS ? t->n : QUOTE_MAX_CHARS;
    if (n + 4 > size)
        n = size - 4;
    size_t j = 0;
    for (size_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)t->p[i];
        buf[j++] = c >= 0x20 && c < 0x7f ? (char)c : '?';
    }
    if (n < t->n) {
        memcpy(buf + j, "...", 3);
        j += 3;
    }
    buf[j] = '\0';
}

static bg_status sc_vfail(scan_t *s, bg_status status, const char *fmt, va_list ap)
{
    char detail[DETAIL_MAX_CHARS];
    vsnprintf(detail, sizeof detail, fmt, ap);
    return bg_error_set(s->err, status, "%s:%ld: %s", s->name, s->line, detail);
}

/* Records "name:line: detail" and returns status. */
__attribute__((format(printf, 3, 4))) static bg_status sc_fail(scan_t *s, bg_status status,
                                                               const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    bg_status st = sc_vfail(s, status, fmt, ap);
    va_end(ap);
    return st;
}

/* "expected WHAT" when the field is missing, "expected WHAT, found 'x'"
 * when it is there but malformed. */
static bg_status sc_expect_fail(scan_t *s, int found, const token_t *t, const char *fmt, va_list ap)
{
    char what[DETAIL_MAX_CHARS];
    vsnprintf(what, sizeof what, fmt, ap);
    if (!found)
        return sc_fail(s, BG_ERR_PARSE, "expected %s", what);
    char q[QUOTE_MAX_CHARS + 8];
    quote_token(t, q, sizeof q);
    return sc_fail(s, BG_ERR_PARSE, "expected %s, found '%s'", what, q);
}

/* Reads a token that must be `word` (a section marker). */
static bg_status sc_expect_word(scan_t *s, const char *word)
{
    token_t t = {NULL, 0};
    int found = sc_token(s, 1, &t);
    if (found && tok_is(&t, word))
        return BG_OK;
    if (!found)
        return sc_fail(s, BG_ERR_PARSE, "expected %s (truncated file?)", word);
    char q[QUOTE_MAX_CHARS + 8];
    quote_token(&t, q, sizeof q);
    return sc_fail(s, BG_ERR_PARSE, "expected %s, found '%s'", word, q);
}

/* Strict decimal integer: optional sign, digits, nothing else. */
static int parse_i64(const char *p, size_t n, int64_t *v)
{
    size_t i = 0;
    int negative = 0;
    if (i < n && (p[i] == '+' || p[i] == '-')) {
        negative = p[i] == '-';
        i++;
    }
    if (i == n || n - i > INT_MAX_DIGITS)
        return 0;
    int64_t x = 0;
    for (; i < n; i++) {
        if (p[i] < '0' || p[i] > '9')
            return 0;
        x = x * 10 + (p[i] - '0');
    }
    *v = negative ? -x : x;
    return 1;
}

/* A whole token as a double (strtod on a bounded NUL-terminated copy).
 * Non-finite values parse; callers decide whether they are allowed. */
static int parse_double(const char *p, size_t n, double *v)
{
    char buf[NUMBER_MAX_CHARS + 1];
    if (n == 0 || n > NUMBER_MAX_CHARS)
        return 0;
    memcpy(buf, p, n);
    buf[n] = '\0';
    char *endp = NULL;
    *v = strtod(buf, &endp);
    return endp == buf + n;
}

/* Reads an integer field; on failure the message says what was expected. */
__attribute__((format(printf, 4, 5))) static bg_status sc_int(scan_t *s, int cross, int64_t *v,
                                                              const char *fmt, ...)
{
    token_t t = {NULL, 0};
    int found = sc_token(s, cross, &t);
    if (found && parse_i64(t.p, t.n, v))
        return BG_OK;
    va_list ap;
    va_start(ap, fmt);
    bg_status st = sc_expect_fail(s, found, &t, fmt, ap);
    va_end(ap);
    return st;
}

/* Reads a real field (finite or not); on failure says what was expected. */
__attribute__((format(printf, 4, 5))) static bg_status sc_real(scan_t *s, int cross, double *v,
                                                               const char *fmt, ...)
{
    token_t t = {NULL, 0};
    int found = sc_token(s, cross, &t);
    if (found && parse_double(t.p, t.n, v))
        return BG_OK;
    va_list ap;
    va_start(ap, fmt);
    bg_status st = sc_expect_fail(s, found, &t, fmt, ap);
    va_end(ap);
    return st;
}

/* Requires the rest of the line to be blank (or a comment). */
__attribute__((format(printf, 2, 3))) static bg_status sc_end_record(scan_t *s, const char *fmt,
                                                                     ...)
{
    token_t t;
    if (!sc_token(s, 0, &t))
        return BG_OK;
    char what[DETAIL_MAX_CHARS];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    char q[QUOTE_MAX_CHARS + 8];
    quote_token(&t, q, sizeof q);
    return sc_fail(s, BG_ERR_PARSE, "unexpected '%s' after %s", q, what);
}

/*
 * Checks a declared record count before anything is allocated from it:
 * negative is malformed, over `max` hits the cap, and more records (of at
 * least `fields` fields each) than the remaining bytes can hold means a
 * truncated or lying file.
 */
static bg_status sc_count(scan_t *s, int64_t count, int64_t max, int64_t fields, const char *what)
{
    if (count < 0)
        return sc_fail(s, BG_ERR_PARSE, "negative %s count %lld", what, (long long)count);
    if (count > max)
        return sc_fail(s, BG_ERR_LIMIT, "%lld %s exceed the limit of %lld", (long long)count, what,
                       (long long)max);
    uint64_t remaining = (uint64_t)(s->end - s->p);
    if ((uint64_t)count * (uint64_t)fields * MIN_FIELD_BYTES > remaining + 1)
        return sc_fail(s, BG_ERR_PARSE,
                       "%lld %s declared, but the %llu bytes left cannot hold them (truncated "
                       "file?)",
                       (long long)count, what, (unsigned long long)remaining);
    return BG_OK;
}

/* Reads a reference or tag field that must fit the int32 reference arrays. */
__attribute__((format(printf, 4, 5))) static bg_status sc_ref(scan_t *s, int cross, int32_t *ref,
                                                              const char *fmt, ...)
{
    token_t t = {NULL, 0};
    int64_t v = 0;
    int found = sc_token(s, cross, &t);
    if (found && parse_i64(t.p, t.n, &v)) {
        if (v < -INT32_LIMIT - 1 || v > INT32_LIMIT)
            return sc_fail(s, BG_ERR_INVALID, "reference %lld does not fit 32 bits", (long long)v);
        *ref = (int32_t)v;
        return BG_OK;
    }
    va_list ap;
    va_start(ap, fmt);
    bg_status st = sc_expect_fail(s, found, &t, fmt, ap);
    va_end(ap);
    return st;
}

/* ------------------------------------------------------------------------
 * Growing element lists and mesh assembly
 */

/* k indices and one reference per element. */
typedef struct elist {
    int k;
    int32_t *v;
    int32_t *ref;
    size_t n, cap;
} elist_t;

static void elist_release(elist_t *l)
{
    free(l->v);
    free(l->ref);
    l->v = NULL;
    l->ref = NULL;
    l->n = l->cap = 0;
}

static int elist_reserve(elist_t *l, size_t cap)
{
    if (cap <= l->cap)
        return 1;
    int32_t *v = realloc(l->v, cap * (size_t)l->k * sizeof *v);
    if (!v)
        return 0;
    l->v = v;
    int32_t *r = realloc(l->ref, cap * sizeof *r);
    if (!r)
        return 0;
    l->ref = r;
    l->cap = cap;
    return 1;
}

/* Appends an element, enforcing BG_MESH_MAX_ELEMENTS. */
static bg_status elist_push(scan_t *s, elist_t *l, const int32_t *idx, int32_t ref)
{
    if (l->n >= (size_t)BG_MESH_MAX_ELEMENTS)
        return sc_fail(s, BG_ERR_LIMIT, "more than %d elements", BG_MESH_MAX_ELEMENTS);
    if (l->n == l->cap) {
        if (!elist_reserve(l, l->cap ? 2 * l->cap : LIST_FIRST_CAPACITY))
            return sc_fail(s, BG_ERR_NOMEM, "out of memory after %zu elements", l->n);
    }
    memcpy(l->v + l->n * (size_t)l->k, idx, (size_t)l->k * sizeof *idx);
    l->ref[l->n++] = ref;
    return BG_OK;
}

/* A growing array of vertex coordinates (3 per vertex). */
typedef struct vlist {
    double *x;
    size_t n, cap;
} vlist_t;

static bg_status vlist_push(scan_t *s, vlist_t *l, const double *p)
{
    if (l->n >= (size_t)BG_MESH_MAX_VERTICES)
        return sc_fail(s, BG_ERR_LIMIT, "more than %d vertices", BG_MESH_MAX_VERTICES);
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : LIST_FIRST_CAPACITY;
        double *x = realloc(l->x, 3 * cap * sizeof *x);
        if (!x)
            return sc_fail(s, BG_ERR_NOMEM, "out of memory after %zu vertices", l->n);
        l->x = x;
        l->cap = cap;
    }
    memcpy(l->x + 3 * l->n, p, 3 * sizeof *p);
    l->n++;
    return BG_OK;
}

/*
 * Wraps malloc'ed arrays in a mesh record, which then owns them (the
 * caller's pointers are set to NULL); *vref may be NULL (all refs 0). Then
 * validates the mesh with `name` as its source, so degenerate elements are
 * reported in the reader's words. On failure *out is NULL and the arrays
 * not yet adopted remain the caller's.
 */
static bg_status mesh_adopt(bg_mesh_kind kind, int32_t nv, double **x, int32_t **vref, elist_t *el,
                            const char *name, bg_mesh_t **out, bg_error_t *err)
{
    bg_mesh_t *m = NULL;
    *out = NULL;
    bg_status st = bg_mesh_new(kind, 0, 0, &m, err);
    if (st != BG_OK)
        return st;
    if (!*vref) {
        *vref = calloc((size_t)nv + 1, sizeof **vref);
        if (!*vref) {
            st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", name);
            goto out;
        }
    }
    free(m->x);
    free(m->vertex_ref);
    free(m->elements);
    free(m->element_ref);
    m->x = *x;
    m->vertex_ref = *vref;
    m->elements = el->v;
    m->element_ref = el->ref;
    m->nv = nv;
    m->ne = (int32_t)el->n;
    *x = NULL;
    *vref = NULL;
    el->v = NULL;
    el->ref = NULL;
    el->n = el->cap = 0;
    st = bg_mesh_validate(m, name, NULL, err);
out:
    if (st != BG_OK)
        bg_mesh_destroy(&m);
    *out = m;
    return st;
}

/* ------------------------------------------------------------------------
 * MEDIT .mesh
 */

/* Sections the reader skips, with their fields per record. */
static const struct {
    const char *keyword;
    int fields;
} MEDIT_SKIPPED[] = {
    {"Edges", 3},
    {"Quadrilaterals", 5},
    {"Pyramids", 6},
    {"Prisms", 7},
    {"Hexahedra", 9},
    {"EdgesP2", 4},
    {"TrianglesP2", 7},
    {"TetrahedraP2", 11},
    {"Corners", 1},
    {"Ridges", 1},
    {"RequiredVertices", 1},
    {"RequiredEdges", 1},
    {"RequiredTriangles", 1},
    {"RequiredQuadrilaterals", 1},
    {"RequiredTetrahedra", 1},
    {"Normals", MEDIT_FIELDS_DIM},
    {"Tangents", MEDIT_FIELDS_DIM},
    {"NormalAtVertices", 2},
    {"NormalAtTriangleVertices", 3},
    {"NormalAtQuadrilateralVertices", 3},
    {"TangentAtVertices", 2},
    {"TangentAtEdgeVertices", 3},
};

static bg_status medit_skip(scan_t *s, const token_t *kw, int fields)
{
    int64_t count = 0;
    char what[QUOTE_MAX_CHARS + 8];
    quote_token(kw, what, sizeof what);
    bg_status st = sc_int(s, 1, &count, "a record count after %s", what);
    if (st == BG_OK)
        st = sc_count(s, count, INT32_LIMIT, fields, "records");
    for (int64_t r = 0; st == BG_OK && r < count; r++) {
        for (int f = 0; st == BG_OK && f < fields; f++) {
            double ignored;
            st = sc_real(s, f == 0, &ignored, "%d numbers in %s record %lld", fields, what,
                         (long long)r + 1);
        }
        if (st == BG_OK)
            st = sc_end_record(s, "%s record %lld", what, (long long)r + 1);
    }
    return st;
}

/* Reads the Vertices section: dim coordinates and a reference per line. */
static bg_status medit_vertices(scan_t *s, int dim, int64_t *nv, double **x, int32_t **vref)
{
    int64_t count = 0;
    bg_status st = sc_int(s, 1, &count, "a vertex count after Vertices");
    if (st == BG_OK)
        st = sc_count(s, count, BG_MESH_MAX_VERTICES, dim + 1, "vertices");
    if (st != BG_OK)
        return st;
    *x = malloc(((size_t)count * (size_t)dim + 1) * sizeof **x);
    *vref = malloc(((size_t)count + 1) * sizeof **vref);
    if (!*x || !*vref)
        return sc_fail(s, BG_ERR_NOMEM, "out of memory for %lld vertices", (long long)count);
    for (int64_t v = 0; v < count; v++) {
        double *p = *x + (size_t)v * (size_t)dim;
        for (int c = 0; c < dim; c++) {
            st = sc_real(s, c == 0, &p[c], "%d coordinates and a reference for vertex %lld", dim,
                         (long long)v + 1);
            if (st != BG_OK)
                return st;
            if (!isfinite(p[c]))
                return sc_fail(s, BG_ERR_INVALID, "vertex %lld has a non-finite coordinate %c",
                               (long long)v + 1, "xyz"[c]);
        }
        st = sc_ref(s, 0, *vref + v, "a reference for vertex %lld", (long long)v + 1);
        if (st == BG_OK)
            st = sc_end_record(s, "vertex %lld", (long long)v + 1);
        if (st != BG_OK)
            return st;
    }
    *nv = count;
    return BG_OK;
}

/* Reads a Triangles or Tetrahedra section: 1-based indices and a reference. */
static bg_status medit_elements(scan_t *s, int64_t nv, const char *section, const char *kind,
                                elist_t *l)
{
    int64_t count = 0;
    bg_status st = sc_int(s, 1, &count, "an element count after %s", section);
    if (st == BG_OK)
        st = sc_count(s, count, BG_MESH_MAX_ELEMENTS, l->k + 1, section);
    if (st != BG_OK)
        return st;
    if (!elist_reserve(l, (size_t)count + 1))
        return sc_fail(s, BG_ERR_NOMEM, "out of memory for %lld %s", (long long)count, section);
    for (int64_t e = 0; e < count; e++) {
        int32_t idx[4];
        int32_t ref = 0;
        for (int i = 0; i < l->k; i++) {
            int64_t v = 0;
            st =
                sc_int(s, i == 0, &v, "%d vertex indices in %s %lld", l->k, kind, (long long)e + 1);
            if (st != BG_OK)
                return st;
            if (v < 1 || v > nv)
                return sc_fail(s, BG_ERR_INVALID, "%s %lld refers to vertex %lld, outside 1..%lld",
                               kind, (long long)e + 1, (long long)v, (long long)nv);
            idx[i] = (int32_t)(v - 1);
        }
        st = sc_ref(s, 0, &ref, "a reference for %s %lld", kind, (long long)e + 1);
        if (st == BG_OK)
            st = sc_end_record(s, "%s %lld", kind, (long long)e + 1);
        if (st == BG_OK)
            st = elist_push(s, l, idx, ref);
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

static bg_status parse_medit(const char *text, size_t length, const char *name, bg_mesh_t **out,
                             bg_error_t *err)
{
    scan_t s;
    sc_init(&s, text, length, name, '#', err);
    bg_status st = BG_OK;
    int dim = 0, ended = 0;
    int64_t nv = -1, version = 0;
    double *x = NULL;
    int32_t *vref = NULL;
    elist_t tri = {3, NULL, NULL, 0, 0}, tet = {4, NULL, NULL, 0, 0};
    int saw_tri = 0, saw_tet = 0;
    token_t kw;

    if (!sc_token(&s, 1, &kw) || !tok_is_nocase(&kw, "MeshVersionFormatted")) {
        st = sc_fail(&s, BG_ERR_PARSE, "expected MeshVersionFormatted (not a MEDIT file?)");
        goto out;
    }
    if ((st = sc_int(&s, 1, &version, "a version after MeshVersionFormatted")) != BG_OK)
        goto out;
    if (version < 1 || version > MEDIT_VERSION_MAX) {
        st = sc_fail(&s, BG_ERR_UNSUPPORTED, "MEDIT version %lld is not supported",
                     (long long)version);
        goto out;
    }
    while (!ended && st == BG_OK) {
        if (!sc_token(&s, 1, &kw)) {
            st = sc_fail(&s, BG_ERR_PARSE, "missing End (truncated file?)");
            break;
        }
        if (tok_is_nocase(&kw, "End")) {
            ended = 1;
        } else if (tok_is_nocase(&kw, "Dimension")) {
            int64_t d = 0;
            if ((st = sc_int(&s, 1, &d, "2 or 3 after Dimension")) != BG_OK)
                break;
            if (dim != 0)
                st = sc_fail(&s, BG_ERR_PARSE, "a second Dimension");
            else if (d != 2 && d != 3)
                st = sc_fail(&s, BG_ERR_PARSE, "Dimension %lld, not 2 or 3", (long long)d);
            dim = (int)d;
        } else if (tok_is_nocase(&kw, "Vertices")) {
            if (dim == 0 || nv >= 0)
                st = sc_fail(&s, BG_ERR_PARSE,
                             dim ? "a second Vertices section" : "Vertices before Dimension");
            else
                st = medit_vertices(&s, dim, &nv, &x, &vref);
        } else if (tok_is_nocase(&kw, "Triangles") || tok_is_nocase(&kw, "Tetrahedra")) {
            int is_tet = tok_is_nocase(&kw, "Tetrahedra");
            const char *section = is_tet ? "Tetrahedra" : "Triangles";
            if (nv < 0 || (is_tet ? saw_tet : saw_tri))
                st = sc_fail(&s, BG_ERR_PARSE,
                             nv < 0 ? "%s before Vertices" : "a second %s section", section);
            else
                st = medit_elements(&s, nv, section, is_tet ? "tetrahedron" : "triangle",
                                    is_tet ? &tet : &tri);
            if (is_tet)
                saw_tet = 1;
            else
                saw_tri = 1;
        } else {
            int fields = 0;
            for (size_t i = 0; i < sizeof MEDIT_SKIPPED / sizeof MEDIT_SKIPPED[0]; i++)
                if (tok_is_nocase(&kw, MEDIT_SKIPPED[i].keyword))
                    fields = MEDIT_SKIPPED[i].fields == MEDIT_FIELDS_DIM ? (dim ? dim : 3)
                                                                         : MEDIT_SKIPPED[i].fields;
            if (fields > 0) {
                st = medit_skip(&s, &kw, fields);
            } else {
                char q[QUOTE_MAX_CHARS + 8];
                quote_token(&kw, q, sizeof q);
                st = sc_fail(&s, BG_ERR_PARSE, "unknown MEDIT keyword '%s'", q);
            }
        }
    }
    if (st != BG_OK)
        goto out;
    if (nv < 0) {
        st = sc_fail(&s, BG_ERR_PARSE, "no Vertices section");
        goto out;
    }
    if (tet.n > 0) {
        if (dim != 3) {
            st = sc_fail(&s, BG_ERR_INVALID, "tetrahedra in a mesh of dimension %d", dim);
            goto out;
        }
        st = mesh_adopt(BG_MESH_VOLUME, (int32_t)nv, &x, &vref, &tet, name, out, err);
    } else if (tri.n > 0) {
        st = mesh_adopt(dim == 2 ? BG_MESH_PLANAR : BG_MESH_SURFACE, (int32_t)nv, &x, &vref, &tri,
                        name, out, err);
    } else {
        st = sc_fail(&s, BG_ERR_INVALID, "no Triangles or Tetrahedra");
    }
out:
    free(x);
    free(vref);
    elist_release(&tri);
    elist_release(&tet);
    return st;
}

/* ------------------------------------------------------------------------
 * OFF
 */

/* A polygon being split into the fan of triangles (v0, v_{i-1}, v_i). */
typedef struct fan {
    int64_t n;
    int32_t first, prev;
} fan_t;

static bg_status fan_add(scan_t *s, elist_t *l, fan_t *f, int32_t v)
{
    bg_status st = BG_OK;
    if (f->n == 0)
        f->first = v;
    else if (f->n >= 2) {
        int32_t t[3] = {f->first, f->prev, v};
        st = elist_push(s, l, t, 0);
    }
    f->prev = v;
    f->n++;
    return st;
}

/* Fields of an OFF vertex (x y z) and of the smallest face (3 a b c). */
#define OFF_VERTEX_FIELDS 3
#define OFF_FACE_FIELDS 4

static bg_status parse_off(const char *text, size_t length, const char *name, bg_mesh_t **out,
                           bg_error_t *err)
{
    scan_t s;
    sc_init(&s, text, length, name, '#', err);
    bg_status st = BG_OK;
    double *x = NULL;
    int32_t *vref = NULL;
    elist_t tri = {3, NULL, NULL, 0, 0};
    int64_t nv = 0, nf = 0, nedges = 0;
    token_t t = {NULL, 0};

    if (!sc_token(&s, 1, &t) || !tok_is(&t, "OFF")) {
        char q[QUOTE_MAX_CHARS + 8];
        quote_token(&t, q, sizeof q);
        /* COFF, NOFF, 4OFF, STOFF...: per-vertex extras this reader does not take. */
        if (t.n > 3 && memcmp(t.p + t.n - 3, "OFF", 3) == 0)
            st = sc_fail(&s, BG_ERR_UNSUPPORTED, "OFF variant '%s' is not supported", q);
        else
            st = sc_fail(&s, BG_ERR_PARSE, "expected the OFF header (not an OFF file?)");
        goto out;
    }
    /* The counts may share the header line or follow it. */
    if ((st = sc_int(&s, sc_at_eol(&s), &nv, "vertex, face and edge counts")) != BG_OK ||
        (st = sc_int(&s, 0, &nf, "vertex, face and edge counts")) != BG_OK)
        goto out;
    if (!sc_at_eol(&s) && (st = sc_int(&s, 0, &nedges, "an edge count")) != BG_OK)
        goto out;
    if ((st = sc_end_record(&s, "the counts")) != BG_OK ||
        (st = sc_count(&s, nv, BG_MESH_MAX_VERTICES, OFF_VERTEX_FIELDS, "vertices")) != BG_OK ||
        (st = sc_count(&s, nf, BG_MESH_MAX_ELEMENTS, OFF_FACE_FIELDS, "faces")) != BG_OK ||
        (st = sc_count(&s, OFF_VERTEX_FIELDS * nv + OFF_FACE_FIELDS * nf, INT64_MAX / 4, 1,
                       "vertex and face fields")) != BG_OK)
        goto out;
    x = malloc(((size_t)nv * 3 + 1) * sizeof *x);
    if (!x || !elist_reserve(&tri, (size_t)nf + 1)) {
        st = sc_fail(&s, BG_ERR_NOMEM, "out of memory for %lld vertices", (long long)nv);
        goto out;
    }
    for (int64_t v = 0; v < nv; v++) {
        for (int c = 0; c < 3; c++) {
            double *p = x + 3 * v + c;
            if ((st = sc_real(&s, c == 0, p, "3 coordinates for vertex %lld", (long long)v)) !=
                BG_OK)
                goto out;
            if (!isfinite(*p)) {
                st = sc_fail(&s, BG_ERR_INVALID, "vertex %lld has a non-finite coordinate %c",
                             (long long)v, "xyz"[c]);
                goto out;
            }
        }
        if ((st = sc_end_record(&s, "vertex %lld", (long long)v)) != BG_OK)
            goto out;
    }
    for (int64_t f = 0; f < nf; f++) {
        int64_t n = 0;
        if ((st = sc_int(&s, 1, &n, "a vertex count for face %lld", (long long)f)) != BG_OK)
            goto out;
        if (n < 3) {
            st = sc_fail(&s, BG_ERR_INVALID, "face %lld has %lld vertices; a polygon needs 3",
                         (long long)f, (long long)n);
            goto out;
        }
        fan_t fan = {0, 0, 0};
        for (int64_t i = 0; i < n; i++) {
            int64_t v = 0;
            if ((st = sc_int(&s, 0, &v, "%lld vertex indices in face %lld", (long long)n,
                             (long long)f)) != BG_OK)
                goto out;
            if (v < 0 || v >= nv) {
                st = sc_fail(&s, BG_ERR_INVALID, "face %lld refers to vertex %lld, outside 0..%lld",
                             (long long)f, (long long)v, (long long)nv - 1);
                goto out;
            }
            if ((st = fan_add(&s, &tri, &fan, (int32_t)v)) != BG_OK)
                goto out;
        }
        /* A face may end with a colour: numbers only. */
        while (sc_token(&s, 0, &t)) {
            double ignored;
            if (!parse_double(t.p, t.n, &ignored)) {
                char q[QUOTE_MAX_CHARS + 8];
                quote_token(&t, q, sizeof q);
                st = sc_fail(&s, BG_ERR_PARSE, "unexpected '%s' after face %lld", q, (long long)f);
                goto out;
            }
        }
    }
    if (!sc_at_end(&s)) {
        st = sc_fail(&s, BG_ERR_PARSE, "unexpected content after the last face");
        goto out;
    }
    if (nf == 0) {
        st = sc_fail(&s, BG_ERR_INVALID, "no faces");
        goto out;
    }
    st = mesh_adopt(BG_MESH_SURFACE, (int32_t)nv, &x, &vref, &tri, name, out, err);
out:
    free(x);
    free(vref);
    elist_release(&tri);
    return st;
}

/* ------------------------------------------------------------------------
 * OBJ
 */

/* OBJ statements other than v and f are ignored, but a keyword must look
 * like one: this rejects binary garbage instead of skipping it. */
static int obj_keyword_ok(const token_t *t)
{
    for (size_t i = 0; i < t->n; i++) {
        char c = t->p[i];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '_'))
            return 0;
    }
    return t->n > 0;
}

/* Splits an OBJ face vertex "a", "a/b", "a//c" or "a/b/c" and returns the
 * vertex index a; the texture and normal indices must be integers. */
static int obj_face_vertex(const token_t *t, int64_t *a)
{
    const char *p = t->p, *end = t->p + t->n;
    const char *slash = memchr(p, '/', t->n);
    if (!parse_i64(p, (size_t)((slash ? slash : end) - p), a))
        return 0;
    if (!slash)
        return 1;
    const char *q = slash + 1;
    const char *slash2 = memchr(q, '/', (size_t)(end - q));
    int64_t ignored;
    if (!slash2)
        return parse_i64(q, (size_t)(end - q), &ignored);
    if (slash2 > q && !parse_i64(q, (size_t)(slash2 - q), &ignored))
        return 0;
    return parse_i64(slash2 + 1, (size_t)(end - slash2 - 1), &ignored);
}

/* Extra numbers a `v` line may carry: w (4 numbers), or an RGB colour (6). */
#define OBJ_VERTEX_WITH_W 4
#define OBJ_VERTEX_WITH_RGB 6

static bg_status parse_obj(const char *text, size_t length, const char *name, bg_mesh_t **out,
                           bg_error_t *err)
{
    scan_t s;
    sc_init(&s, text, length, name, '#', err);
    bg_status st = BG_OK;
    vlist_t verts = {NULL, 0, 0};
    elist_t tri = {3, NULL, NULL, 0, 0};
    int32_t *vref = NULL;
    int64_t faces = 0;
    token_t kw, t;

    while (st == BG_OK && sc_token(&s, 1, &kw)) {
        if (tok_is(&kw, "v")) {
            double p[3];
            int64_t v = (int64_t)verts.n + 1;
            for (int c = 0; c < 3 && st == BG_OK; c++) {
                st = sc_real(&s, 0, &p[c], "3 coordinates for vertex %lld", (long long)v);
                if (st == BG_OK && !isfinite(p[c]))
                    st = sc_fail(&s, BG_ERR_INVALID, "vertex %lld has a non-finite coordinate %c",
                                 (long long)v, "xyz"[c]);
            }
            int extra = 3;
            while (st == BG_OK && sc_token(&s, 0, &t)) {
                double ignored;
                if (!parse_double(t.p, t.n, &ignored) || ++extra > OBJ_VERTEX_WITH_RGB) {
                    char q[QUOTE_MAX_CHARS + 8];
                    quote_token(&t, q, sizeof q);
                    st = sc_fail(&s, BG_ERR_PARSE, "unexpected '%s' after vertex %lld", q,
                                 (long long)v);
                }
            }
            if (st == BG_OK && extra != 3 && extra != OBJ_VERTEX_WITH_W &&
                extra != OBJ_VERTEX_WITH_RGB)
                st = sc_fail(&s, BG_ERR_PARSE,
                             "vertex %lld has %d numbers; expected x y z, x y z w or x y z r g b",
                             (long long)v, extra);
            if (st == BG_OK)
                st = vlist_push(&s, &verts, p);
        } else if (tok_is(&kw, "f")) {
            fan_t fan = {0, 0, 0};
            faces++;
            while (st == BG_OK && sc_token(&s, 0, &t)) {
                int64_t a = 0, have = (int64_t)verts.n;
                if (!obj_face_vertex(&t, &a)) {
                    char q[QUOTE_MAX_CHARS + 8];
                    quote_token(&t, q, sizeof q);
                    st = sc_fail(&s, BG_ERR_PARSE,
                                 "face %lld: '%s' is not a vertex reference (a, a/b, a//c, a/b/c)",
                                 (long long)faces, q);
                    break;
                }
                /* Negative indices count back from the last vertex defined. */
                int64_t v = a > 0 ? a - 1 : have + a;
                if (a == 0 || v < 0 || v >= have) {
                    st = sc_fail(&s, BG_ERR_INVALID,
                                 "face %lld refers to vertex %lld, but %lld vertices are defined "
                                 "so far",
                                 (long long)faces, (long long)a, (long long)have);
                    break;
                }
                st = fan_add(&s, &tri, &fan, (int32_t)v);
            }
            if (st == BG_OK && fan.n < 3)
                st = sc_fail(&s, BG_ERR_INVALID, "face %lld has %lld vertices; a polygon needs 3",
                             (long long)faces, (long long)fan.n);
        } else if (obj_keyword_ok(&kw)) {
            sc_skip_rest_of_line(&s);
        } else {
            char q[QUOTE_MAX_CHARS + 8];
            quote_token(&kw, q, sizeof q);
            st = sc_fail(&s, BG_ERR_PARSE, "'%s' is not an OBJ statement", q);
        }
    }
    if (st != BG_OK)
        goto out;
    if (tri.n == 0) {
        st = sc_fail(&s, BG_ERR_INVALID, "no faces");
        goto out;
    }
    st = mesh_adopt(BG_MESH_SURFACE, (int32_t)verts.n, &verts.x, &vref, &tri, name, out, err);
out:
    free(verts.x);
    free(vref);
    elist_release(&tri);
    return st;
}

/* ------------------------------------------------------------------------
 * TetGen .node / .ele
 */

/* A double that is an exact int32 becomes a reference; others give 0
 * (TetGen attributes may be arbitrary reals). */
static int32_t attribute_ref(double a)
{
    if (a >= -INT32_LIMIT - 1 && a <= INT32_LIMIT && a == floor(a))
        return (int32_t)a;
    return 0;
}

typedef struct tetgen_nodes {
    int64_t nv;
    int dim;
    int64_t base; /* number of the first vertex: 0 or 1 */
    double *x;
    int32_t *vref;
} tetgen_nodes_t;

static bg_status tetgen_parse_node(scan_t *s, tetgen_nodes_t *nd)
{
    int64_t nv = 0, dim = 0, nattr = 0, nbm = 0;
    bg_status st;
    if ((st = sc_int(s, 1, &nv, "the vertex count")) != BG_OK ||
        (st = sc_int(s, 0, &dim, "the dimension after the vertex count")) != BG_OK)
        return st;
    if (!sc_at_eol(s) && (st = sc_int(s, 0, &nattr, "an attribute count")) != BG_OK)
        return st;
    if (!sc_at_eol(s) && (st = sc_int(s, 0, &nbm, "a boundary marker count (0 or 1)")) != BG_OK)
        return st;
    if ((st = sc_end_record(s, "the .node header")) != BG_OK)
        return st;
    if (dim != 2 && dim != 3)
        return sc_fail(s, BG_ERR_PARSE, "dimension %lld, not 2 or 3", (long long)dim);
    if (nbm != 0 && nbm != 1)
        return sc_fail(s, BG_ERR_PARSE, "boundary marker count %lld, not 0 or 1", (long long)nbm);
    if (nattr < 0 || nattr > (int64_t)(s->end - s->p))
        return sc_fail(s, BG_ERR_PARSE, "attribute count %lld is impossible here",
                       (long long)nattr);
    if ((st = sc_count(s, nv, BG_MESH_MAX_VERTICES, 1 + dim + nattr + nbm, "vertices")) != BG_OK)
        return st;
    nd->dim = (int)dim;
    nd->x = malloc(((size_t)nv * (size_t)dim + 1) * sizeof *nd->x);
    nd->vref = calloc((size_t)nv + 1, sizeof *nd->vref);
    if (!nd->x || !nd->vref)
        return sc_fail(s, BG_ERR_NOMEM, "out of memory for %lld vertices", (long long)nv);
    for (int64_t v = 0; v < nv; v++) {
        int64_t number = 0;
        if ((st = sc_int(s, 1, &number, "a vertex number")) != BG_OK)
            return st;
        /* TetGen numbers from whatever the first vertex says, 0 or 1. */
        if (v == 0) {
            if (number != 0 && number != 1)
                return sc_fail(s, BG_ERR_PARSE, "the first vertex is numbered %lld, not 0 or 1",
                               (long long)number);
            nd->base = number;
        } else if (number != nd->base + v) {
            return sc_fail(s, BG_ERR_PARSE, "vertex numbered %lld where %lld was expected",
                           (long long)number, (long long)(nd->base + v));
        }
        double *p = nd->x + (size_t)v * (size_t)dim;
        for (int c = 0; c < dim; c++) {
            if ((st = sc_real(s, 0, &p[c], "%d coordinates for vertex %lld", (int)dim,
                              (long long)number)) != BG_OK)
                return st;
            if (!isfinite(p[c]))
                return sc_fail(s, BG_ERR_INVALID, "vertex %lld has a non-finite coordinate %c",
                               (long long)number, "xyz"[c]);
        }
        for (int64_t a = 0; a < nattr; a++) {
            double ignored;
            if ((st = sc_real(s, 0, &ignored, "%lld attributes for vertex %lld", (long long)nattr,
                              (long long)number)) != BG_OK)
                return st;
        }
        if (nbm && (st = sc_ref(s, 0, nd->vref + v, "a boundary marker for vertex %lld",
                                (long long)number)) != BG_OK)
            return st;
        if ((st = sc_end_record(s, "vertex %lld", (long long)number)) != BG_OK)
            return st;
    }
    if (!sc_at_end(s))
        return sc_fail(s, BG_ERR_PARSE, "unexpected content after the last vertex");
    nd->nv = nv;
    return BG_OK;
}

static bg_status tetgen_parse_ele(scan_t *s, const tetgen_nodes_t *nd, elist_t *l)
{
    int64_t ne = 0, npe = 0, nattr = 0;
    bg_status st;
    if ((st = sc_int(s, 1, &ne, "the element count")) != BG_OK ||
        (st = sc_int(s, 0, &npe, "the nodes per element after the element count")) != BG_OK)
        return st;
    if (!sc_at_eol(s) && (st = sc_int(s, 0, &nattr, "an attribute count")) != BG_OK)
        return st;
    if ((st = sc_end_record(s, "the .ele header")) != BG_OK)
        return st;
    if (npe != 3 && npe != 4 && npe != TETGEN_TRIANGLE6 && npe != TETGEN_TETRAHEDRON10)
        return sc_fail(s, BG_ERR_PARSE, "%lld nodes per element, not 3, 4, 6 or 10",
                       (long long)npe);
    if (nattr < 0 || nattr > (int64_t)(s->end - s->p))
        return sc_fail(s, BG_ERR_PARSE, "attribute count %lld is impossible here",
                       (long long)nattr);
    if ((st = sc_count(s, ne, BG_MESH_MAX_ELEMENTS, 1 + npe + nattr, "elements")) != BG_OK)
        return st;
    l->k = npe == 4 || npe == TETGEN_TETRAHEDRON10 ? 4 : 3;
    if (!elist_reserve(l, (size_t)ne + 1))
        return sc_fail(s, BG_ERR_NOMEM, "out of memory for %lld elements", (long long)ne);
    for (int64_t e = 0; e < ne; e++) {
        int64_t number = 0;
        int32_t idx[TETGEN_TETRAHEDRON10], ref = 0;
        if ((st = sc_int(s, 1, &number, "an element number")) != BG_OK)
            return st;
        for (int64_t i = 0; i < npe; i++) {
            int64_t v = 0;
            if ((st = sc_int(s, 0, &v, "%lld vertex numbers in element %lld", (long long)npe,
                             (long long)number)) != BG_OK)
                return st;
            if (v < nd->base || v >= nd->base + nd->nv)
                return sc_fail(s, BG_ERR_INVALID,
                               "element %lld refers to vertex %lld, outside %lld..%lld",
                               (long long)number, (long long)v, (long long)nd->base,
                               (long long)(nd->base + nd->nv - 1));
            idx[i] = (int32_t)(v - nd->base);
        }
        for (int64_t a = 0; a < nattr; a++) {
            double value = 0.0;
            if ((st = sc_real(s, 0, &value, "%lld attributes for element %lld", (long long)nattr,
                              (long long)number)) != BG_OK)
                return st;
            if (a == 0)
                ref = attribute_ref(value);
        }
        if ((st = sc_end_record(s, "element %lld", (long long)number)) != BG_OK ||
            (st = elist_push(s, l, idx, ref)) != BG_OK)
            return st;
    }
    if (!sc_at_end(s))
        return sc_fail(s, BG_ERR_PARSE, "unexpected content after the last element");
    return BG_OK;
}

/* "dir/box.node" or "dir/box.ele" or "dir/box" → "dir/box" + suffix, for
 * messages that must cite the file each line is in. */
static void tetgen_file_name(const char *name, const char *suffix, char *buf, size_t size)
{
    size_t n = strlen(name);
    const char *dot = strrchr(name, '.');
    if (dot && (strcmp(dot, ".node") == 0 || strcmp(dot, ".ele") == 0))
        n = (size_t)(dot - name);
    snprintf(buf, size, "%.*s%s", (int)n, name, suffix);
}

bg_status bg_mesh_parse_tetgen(const char *node_text, size_t node_length, const char *ele_text,
                               size_t ele_length, const char *name, bg_mesh_t **out,
                               bg_error_t *err)
{
    char node_name[BG_ERROR_MESSAGE_MAX], ele_name[BG_ERROR_MESSAGE_MAX];
    tetgen_nodes_t nd = {0, 0, 0, NULL, NULL};
    elist_t el = {4, NULL, NULL, 0, 0};
    scan_t s;
    bg_status st;
    *out = NULL;
    if (!name)
        name = "(unnamed)";
    tetgen_file_name(name, ".node", node_name, sizeof node_name);
    tetgen_file_name(name, ".ele", ele_name, sizeof ele_name);
    sc_init(&s, node_text, node_text ? node_length : 0, node_name, '#', err);
    if ((st = tetgen_parse_node(&s, &nd)) != BG_OK)
        goto out;
    sc_init(&s, ele_text, ele_text ? ele_length : 0, ele_name, '#', err);
    if ((st = tetgen_parse_ele(&s, &nd, &el)) != BG_OK)
        goto out;
    bg_mesh_kind kind = el.k == 4 ? BG_MESH_VOLUME : nd.dim == 2 ? BG_MESH_PLANAR : BG_MESH_SURFACE;
    if (kind == BG_MESH_VOLUME && nd.dim != 3) {
        st = sc_fail(&s, BG_ERR_INVALID, "tetrahedra over 2-dimensional vertices");
        goto out;
    }
    st = mesh_adopt(kind, (int32_t)nd.nv, &nd.x, &nd.vref, &el, name, out, err);
out:
    free(nd.x);
    free(nd.vref);
    elist_release(&el);
    return st;
}

/* ------------------------------------------------------------------------
 * Gmsh .msh 2.2 and 4.1
 */

typedef struct tag_index {
    int64_t tag;
    int32_t index;
} tag_index_t;

typedef struct gmsh_entity {
    int64_t dim;
    int64_t tag;
    int32_t physical;
} gmsh_entity_t;

typedef struct gmsh {
    scan_t s;
    int major; /* 2 or 4; 0 before $MeshFormat */
    int64_t nv;
    double *x;
    int64_t *tags; /* node tag of each vertex */
    int64_t first_tag;
    int contiguous;     /* tags are first_tag, first_tag + 1, ... */
    tag_index_t *index; /* sorted by tag when not contiguous */
    gmsh_entity_t *entities;
    size_t nentities;
    elist_t tri, tet;
    int saw_nodes, saw_elements;
} gmsh_t;

static int cmp_tag_index(const void *a, const void *b)
{
    const tag_index_t *p = a, *q = b;
    return (p->tag > q->tag) - (p->tag < q->tag);
}

static int cmp_entity(const void *a, const void *b)
{
    const gmsh_entity_t *p = a, *q = b;
    if (p->dim != q->dim)
        return (p->dim > q->dim) - (p->dim < q->dim);
    return (p->tag > q->tag) - (p->tag < q->tag);
}

/* Builds the tag → vertex map; node tags need not be contiguous. */
static bg_status gmsh_index_nodes(gmsh_t *g)
{
    g->contiguous = 1;
    g->first_tag = g->nv ? g->tags[0] : 0;
    for (int64_t i = 0; i < g->nv && g->contiguous; i++)
        g->contiguous = g->tags[i] == g->first_tag + i;
    if (g->contiguous)
        return BG_OK;
    g->index = malloc(((size_t)g->nv + 1) * sizeof *g->index);
    if (!g->index)
        return sc_fail(&g->s, BG_ERR_NOMEM, "out of memory indexing %lld nodes", (long long)g->nv);
    for (int64_t i = 0; i < g->nv; i++) {
        g->index[i].tag = g->tags[i];
        g->index[i].index = (int32_t)i;
    }
    qsort(g->index, (size_t)g->nv, sizeof *g->index, cmp_tag_index);
    for (int64_t i = 1; i < g->nv; i++)
        if (g->index[i].tag == g->index[i - 1].tag)
            return sc_fail(&g->s, BG_ERR_INVALID, "node tag %lld appears twice in $Nodes",
                           (long long)g->index[i].tag);
    return BG_OK;
}

static int32_t gmsh_node(const gmsh_t *g, int64_t tag)
{
    if (g->contiguous) {
        if (tag < g->first_tag || tag - g->first_tag >= g->nv)
            return -1;
        return (int32_t)(tag - g->first_tag);
    }
    tag_index_t key = {tag, 0};
    const tag_index_t *hit = bsearch(&key, g->index, (size_t)g->nv, sizeof key, cmp_tag_index);
    return hit ? hit->index : -1;
}

/* Expects the closing $EndName line of a section. */
static bg_status gmsh_section_end(gmsh_t *g, const char *end_marker)
{
    bg_status st = sc_expect_word(&g->s, end_marker);
    return st != BG_OK ? st : sc_end_record(&g->s, "%s", end_marker);
}

/* Corners kept and nodes listed for the element types the reader keeps
 * (second-order elements contribute their corners); 0 for the others. */
static int gmsh_kept_type(int64_t type, int *corners, int *nodes)
{
    switch (type) {
    case GMSH_TRIANGLE:
        *corners = 3, *nodes = 3;
        return 1;
    case GMSH_TETRAHEDRON:
        *corners = 4, *nodes = 4;
        return 1;
    case GMSH_TRIANGLE6:
        *corners = 3, *nodes = 6;
        return 1;
    case GMSH_TETRAHEDRON10:
        *corners = 4, *nodes = 10;
        return 1;
    default:
        return 0;
    }
}

static bg_status gmsh_format(gmsh_t *g)
{
    scan_t *s = &g->s;
    token_t v = {NULL, 0};
    double version = 0.0;
    int64_t file_type = 0, data_size = 0;
    bg_status st;
    if (!sc_token(s, 1, &v) || !parse_double(v.p, v.n, &version))
        return sc_fail(s, BG_ERR_PARSE, "expected a version number in $MeshFormat");
    if (version >= 2.0 && version < 3.0) {
        g->major = 2;
    } else if (tok_is(&v, "4.1")) {
        g->major = 4;
    } else {
        char q[QUOTE_MAX_CHARS + 8];
        quote_token(&v, q, sizeof q);
        return sc_fail(s, BG_ERR_UNSUPPORTED,
                       "Gmsh format version %s is not supported (2.2 or 4.1 ASCII are)", q);
    }
    if ((st = sc_int(s, 0, &file_type, "a file type after the version")) != BG_OK ||
        (st = sc_int(s, 0, &data_size, "a data size after the file type")) != BG_OK ||
        (st = sc_end_record(s, "the format line")) != BG_OK)
        return st;
    if (file_type != GMSH_ASCII)
        return sc_fail(s, BG_ERR_UNSUPPORTED, "binary .msh is not supported; save it as ASCII");
    return gmsh_section_end(g, "$EndMeshFormat");
}

/* Reads x y z (and `extra` parametric numbers) of the node with this tag. */
static bg_status gmsh_coordinates(gmsh_t *g, int64_t i, int64_t tag, int cross, int64_t extra)
{
    double *p = g->x + 3 * i;
    bg_status st;
    for (int c = 0; c < 3; c++) {
        if ((st = sc_real(&g->s, cross && c == 0, &p[c], "3 coordinates for node %lld",
                          (long long)tag)) != BG_OK)
            return st;
        if (!isfinite(p[c]))
            return sc_fail(&g->s, BG_ERR_INVALID, "node %lld has a non-finite coordinate %c",
                           (long long)tag, "xyz"[c]);
    }
    for (int64_t c = 0; c < extra; c++) {
        double ignored;
        if ((st = sc_real(&g->s, 0, &ignored, "parametric coordinates for node %lld",
                          (long long)tag)) != BG_OK)
            return st;
    }
    return sc_end_record(&g->s, "node %lld", (long long)tag);
}

static bg_status gmsh_alloc_nodes(gmsh_t *g, int64_t n)
{
    g->x = malloc(((size_t)n * 3 + 1) * sizeof *g->x);
    g->tags = malloc(((size_t)n + 1) * sizeof *g->tags);
    if (!g->x || !g->tags)
        return sc_fail(&g->s, BG_ERR_NOMEM, "out of memory for %lld nodes", (long long)n);
    return BG_OK;
}

/* Fields of one node at least: a tag and three coordinates. */
#define GMSH_NODE_FIELDS 4

static bg_status gmsh_nodes2(gmsh_t *g)
{
    scan_t *s = &g->s;
    int64_t n = 0;
    bg_status st;
    if ((st = sc_int(s, 1, &n, "a node count")) != BG_OK ||
        (st = sc_end_record(s, "the node count")) != BG_OK ||
        (st = sc_count(s, n, BG_MESH_MAX_VERTICES, GMSH_NODE_FIELDS, "nodes")) != BG_OK ||
        (st = gmsh_alloc_nodes(g, n)) != BG_OK)
        return st;
    for (int64_t i = 0; i < n; i++) {
        if ((st = sc_int(s, 1, &g->tags[i], "a node tag (node %lld of %lld)", (long long)i + 1,
                         (long long)n)) != BG_OK ||
            (st = gmsh_coordinates(g, i, g->tags[i], 0, 0)) != BG_OK)
            return st;
    }
    g->nv = n;
    return gmsh_section_end(g, "$EndNodes");
}

/*
 * A Gmsh 4.1 header: four integers on one record (a section's
 * "numEntityBlocks numX minTag maxTag", a block's "entityDim entityTag
 * third numInBlock"), into v[0..3]. label names the four in messages;
 * where names the header ("the $Nodes header", "node block 3").
 */
static bg_status gmsh4_header(scan_t *s, const char *const label[4], const char *where,
                              int64_t v[4])
{
    bg_status st = sc_int(s, 1, &v[0], "%s %s %s %s in %s", label[0], label[1], label[2],
                          label[3], where);
    for (int k = 1; k < 4 && st == BG_OK; k++)
        st = sc_int(s, 0, &v[k], "%s after %s in %s", label[k], label[k - 1], where);
    return st == BG_OK ? sc_end_record(s, "%s", where) : st;
}

static bg_status gmsh_nodes4(gmsh_t *g)
{
    scan_t *s = &g->s;
    static const char *const section[4] = {"numEntityBlocks", "numNodes", "minNodeTag",
                                           "maxNodeTag"};
    static const char *const block[4] = {"entityDim", "entityTag", "parametric",
                                         "numNodesInBlock"};
    int64_t head[4] = {0}, filled = 0;
    bg_status st;
    if ((st = gmsh4_header(s, section, "the $Nodes header", head)) != BG_OK)
        return st;
    const int64_t blocks = head[0], n = head[1];
    if ((st = sc_count(s, blocks, INT32_LIMIT, 4, "node blocks")) != BG_OK ||
        (st = sc_count(s, n, BG_MESH_MAX_VERTICES, GMSH_NODE_FIELDS, "nodes")) != BG_OK ||
        (st = gmsh_alloc_nodes(g, n)) != BG_OK)
        return st;
    for (int64_t b = 0; b < blocks; b++) {
        char where[48];
        snprintf(where, sizeof where, "node block %lld", (long long)b + 1);
        int64_t bh[4] = {0};
        if ((st = gmsh4_header(s, block, where, bh)) != BG_OK)
            return st;
        const int64_t edim = bh[0], parametric = bh[2], count = bh[3];
        if (edim < 0 || edim > GMSH_MAX_ENTITY_DIM || (parametric != 0 && parametric != 1))
            return sc_fail(s, BG_ERR_PARSE,
                           "node block %lld: entity dimension %lld or parametric "
                           "flag %lld out of range",
                           (long long)b + 1, (long long)edim, (long long)parametric);
        if (count < 0 || count > n - filled)
            return sc_fail(
                s, BG_ERR_PARSE,
                "node block %lld holds %lld nodes; only %lld of the %lld declared remain",
                (long long)b + 1, (long long)count, (long long)(n - filled), (long long)n);
        for (int64_t i = 0; i < count; i++)
            if ((st = sc_int(s, 1, &g->tags[filled + i], "%lld node tags in node block %lld",
                             (long long)count, (long long)b + 1)) != BG_OK ||
                (st = sc_end_record(s, "a node tag")) != BG_OK)
                return st;
        for (int64_t i = 0; i < count; i++)
            if ((st = gmsh_coordinates(g, filled + i, g->tags[filled + i], 1,
                                       parametric ? edim : 0)) != BG_OK)
                return st;
        filled += count;
    }
    if (filled != n)
        return sc_fail(s, BG_ERR_PARSE, "the node blocks hold %lld nodes, not the %lld declared",
                       (long long)filled, (long long)n);
    g->nv = n;
    return gmsh_section_end(g, "$EndNodes");
}

/* Fields of a point entity (tag x y z numPhysicalTags) and of the others
 * (tag, bounding box, numPhysicalTags, numBounding). */
#define GMSH_POINT_ENTITY_FIELDS 5
#define GMSH_ENTITY_FIELDS 9
#define GMSH_BOX_NUMBERS 6

static bg_status gmsh_entities(gmsh_t *g)
{
    scan_t *s = &g->s;
    int64_t counts[GMSH_MAX_ENTITY_DIM + 1], total = 0;
    bg_status st;
    for (int d = 0; d <= GMSH_MAX_ENTITY_DIM; d++) {
        if ((st = sc_int(s, d == 0, &counts[d], "numPoints numCurves numSurfaces numVolumes")) !=
                BG_OK ||
            (st = sc_count(s, counts[d], INT32_LIMIT,
                           d ? GMSH_ENTITY_FIELDS : GMSH_POINT_ENTITY_FIELDS, "entities")) != BG_OK)
            return st;
        total += counts[d];
    }
    if ((st = sc_end_record(s, "the entity counts")) != BG_OK ||
        (st = sc_count(s, total, INT32_LIMIT, GMSH_POINT_ENTITY_FIELDS, "entities")) != BG_OK)
        return st;
    g->entities = malloc(((size_t)total + 1) * sizeof *g->entities);
    if (!g->entities)
        return sc_fail(s, BG_ERR_NOMEM, "out of memory for %lld entities", (long long)total);
    for (int d = 0; d <= GMSH_MAX_ENTITY_DIM; d++)
        for (int64_t i = 0; i < counts[d]; i++) {
            gmsh_entity_t *e = &g->entities[g->nentities];
            int64_t nphys = 0, nbound = 0, ignored_tag = 0;
            double ignored;
            e->dim = d;
            e->physical = 0;
            if ((st = sc_int(s, 1, &e->tag, "an entity tag")) != BG_OK)
                return st;
            for (int c = 0; c < (d ? GMSH_BOX_NUMBERS : 3); c++)
                if ((st = sc_real(s, 0, &ignored, "the coordinates of entity %lld",
                                  (long long)e->tag)) != BG_OK)
                    return st;
            if ((st = sc_int(s, 0, &nphys, "numPhysicalTags of entity %lld", (long long)e->tag)) !=
                BG_OK)
                return st;
            for (int64_t k = 0; k < nphys; k++) {
                int32_t physical = 0;
                if ((st = sc_ref(s, 0, &physical, "%lld physical tags of entity %lld",
                                 (long long)nphys, (long long)e->tag)) != BG_OK)
                    return st;
                if (k == 0)
                    e->physical = physical;
            }
            if (d > 0) {
                if ((st = sc_int(s, 0, &nbound, "the bounding entity count of entity %lld",
                                 (long long)e->tag)) != BG_OK)
                    return st;
                for (int64_t k = 0; k < nbound; k++)
                    if ((st = sc_int(s, 0, &ignored_tag, "%lld bounding entities of entity %lld",
                                     (long long)nbound, (long long)e->tag)) != BG_OK)
                        return st;
            }
            if (nphys < 0 || nbound < 0)
                return sc_fail(s, BG_ERR_PARSE, "negative count in entity %lld", (long long)e->tag);
            if ((st = sc_end_record(s, "entity %lld", (long long)e->tag)) != BG_OK)
                return st;
            g->nentities++;
        }
    qsort(g->entities, g->nentities, sizeof *g->entities, cmp_entity);
    return gmsh_section_end(g, "$EndEntities");
}

/* The physical tag of an entity from $Entities, 0 when unknown. */
static int32_t gmsh_physical(const gmsh_t *g, int64_t dim, int64_t tag)
{
    gmsh_entity_t key = {dim, tag, 0};
    if (!g->entities)
        return 0;
    const gmsh_entity_t *hit = bsearch(&key, g->entities, g->nentities, sizeof key, cmp_entity);
    return hit ? hit->physical : 0;
}

/* Reads the node tags of a kept element (on the current line) and stores
 * it among the triangles or the tetrahedra. */
static bg_status gmsh_element_nodes(gmsh_t *g, int64_t tag, int corners, int nodes,
                                    int32_t physical)
{
    int32_t idx[4];
    bg_status st;
    for (int i = 0; i < nodes; i++) {
        int64_t node = 0;
        if ((st = sc_int(&g->s, 0, &node, "%d node tags in element %lld", nodes, (long long)tag)) !=
            BG_OK)
            return st;
        int32_t v = gmsh_node(g, node);
        if (v < 0)
            return sc_fail(&g->s, BG_ERR_INVALID,
                           "element %lld refers to node %lld, which $Nodes does not define",
                           (long long)tag, (long long)node);
        if (i < corners)
            idx[i] = v;
    }
    if ((st = sc_end_record(&g->s, "element %lld", (long long)tag)) != BG_OK)
        return st;
    return elist_push(&g->s, corners == 4 ? &g->tet : &g->tri, idx, physical);
}

/* Fields of an element line at least: 2.2 "tag type ntags node", 4.1 "tag node". */
#define GMSH2_ELEMENT_FIELDS 4
#define GMSH4_ELEMENT_FIELDS 2

static bg_status gmsh_elements2(gmsh_t *g)
{
    scan_t *s = &g->s;
    int64_t n = 0;
    bg_status st;
    if ((st = sc_int(s, 1, &n, "an element count")) != BG_OK ||
        (st = sc_end_record(s, "the element count")) != BG_OK ||
        (st = sc_count(s, n, BG_MESH_MAX_ELEMENTS, GMSH2_ELEMENT_FIELDS, "elements")) != BG_OK)
        return st;
    for (int64_t e = 0; e < n; e++) {
        int64_t tag = 0, type = 0, ntags = 0;
        int32_t physical = 0;
        int corners = 0, nodes = 0;
        if ((st = sc_int(s, 1, &tag, "an element tag (element %lld of %lld)", (long long)e + 1,
                         (long long)n)) != BG_OK ||
            (st = sc_int(s, 0, &type, "the type of element %lld", (long long)tag)) != BG_OK ||
            (st = sc_int(s, 0, &ntags, "the tag count of element %lld", (long long)tag)) != BG_OK)
            return st;
        if (ntags < 0)
            return sc_fail(s, BG_ERR_PARSE, "element %lld has a negative tag count",
                           (long long)tag);
        for (int64_t k = 0; k < ntags; k++) {
            int32_t value = 0;
            if ((st = sc_ref(s, 0, &value, "%lld tags in element %lld", (long long)ntags,
                             (long long)tag)) != BG_OK)
                return st;
            if (k == 0)
                physical = value;
        }
        if (!gmsh_kept_type(type, &corners, &nodes)) {
            sc_skip_rest_of_line(s);
            continue;
        }
        if ((st = gmsh_element_nodes(g, tag, corners, nodes, physical)) != BG_OK)
            return st;
    }
    return gmsh_section_end(g, "$EndElements");
}

static bg_status gmsh_elements4(gmsh_t *g)
{
    scan_t *s = &g->s;
    static const char *const section[4] = {"numEntityBlocks", "numElements", "minElementTag",
                                           "maxElementTag"};
    static const char *const block[4] = {"entityDim", "entityTag", "elementType",
                                         "numElementsInBlock"};
    int64_t head[4] = {0}, filled = 0;
    bg_status st;
    if ((st = gmsh4_header(s, section, "the $Elements header", head)) != BG_OK)
        return st;
    const int64_t blocks = head[0], n = head[1];
    if ((st = sc_count(s, blocks, INT32_LIMIT, 4, "element blocks")) != BG_OK ||
        (st = sc_count(s, n, BG_MESH_MAX_ELEMENTS, GMSH4_ELEMENT_FIELDS, "elements")) != BG_OK)
        return st;
    for (int64_t b = 0; b < blocks; b++) {
        char where[48];
        snprintf(where, sizeof where, "element block %lld", (long long)b + 1);
        int64_t bh[4] = {0};
        int corners = 0, nodes = 0;
        if ((st = gmsh4_header(s, block, where, bh)) != BG_OK)
            return st;
        const int64_t edim = bh[0], etag = bh[1], type = bh[2], count = bh[3];
        if (count < 0 || count > n - filled)
            return sc_fail(s, BG_ERR_PARSE,
                           "element block %lld holds %lld elements; only %lld of the %lld "
                           "declared remain",
                           (long long)b + 1, (long long)count, (long long)(n - filled),
                           (long long)n);
        int kept = gmsh_kept_type(type, &corners, &nodes);
        int32_t physical = gmsh_physical(g, edim, etag);
        for (int64_t i = 0; i < count; i++) {
            int64_t tag = 0;
            if ((st = sc_int(s, 1, &tag, "%lld elements in element block %lld", (long long)count,
                             (long long)b + 1)) != BG_OK)
                return st;
            if (!kept)
                sc_skip_rest_of_line(s);
            else if ((st = gmsh_element_nodes(g, tag, corners, nodes, physical)) != BG_OK)
                return st;
        }
        filled += count;
    }
    if (filled != n)
        return sc_fail(s, BG_ERR_PARSE,
                       "the element blocks hold %lld elements, not the %lld "
                       "declared",
                       (long long)filled, (long long)n);
    return gmsh_section_end(g, "$EndElements");
}

/* Longest section name whose end marker the reader builds. */
#define GMSH_SECTION_NAME_MAX 64

/* Skips a section the reader does not use, up to its $End marker. */
static bg_status gmsh_skip_section(gmsh_t *g, const token_t *start)
{
    char marker[GMSH_SECTION_NAME_MAX + 8];
    token_t t;
    if (start->n > GMSH_SECTION_NAME_MAX)
        return sc_fail(&g->s, BG_ERR_PARSE, "section name too long");
    snprintf(marker, sizeof marker, "$End%.*s", (int)start->n - 1, start->p + 1);
    while (sc_token(&g->s, 1, &t)) {
        if (tok_is(&t, marker))
            return sc_end_record(&g->s, "%s", marker);
        sc_skip_rest_of_line(&g->s);
    }
    return sc_fail(&g->s, BG_ERR_PARSE, "missing %s (truncated file?)", marker);
}

static bg_status parse_gmsh(const char *text, size_t length, const char *name, bg_mesh_t **out,
                            bg_mesh_format *found, bg_error_t *err)
{
    gmsh_t g;
    bg_status st = BG_OK;
    token_t t;
    memset(&g, 0, sizeof g);
    g.tri.k = 3;
    g.tet.k = 4;
    sc_init(&g.s, text, length, name, 0, err);
    int saw_entities = 0;
    int32_t *vref = NULL;
    while (st == BG_OK && sc_token(&g.s, 1, &t)) {
        char q[QUOTE_MAX_CHARS + 8];
        quote_token(&t, q, sizeof q);
        if (t.p[0] != '$') {
            st = sc_fail(&g.s, BG_ERR_PARSE, "expected a section such as $Nodes, found '%s'", q);
        } else if (!g.major && !tok_is(&t, "$MeshFormat")) {
            st = sc_fail(&g.s, BG_ERR_PARSE, "expected $MeshFormat first, found '%s'", q);
        } else if ((st = sc_end_record(&g.s, "%s", q)) != BG_OK) {
            break;
        } else if (tok_is(&t, "$MeshFormat")) {
            st = g.major ? sc_fail(&g.s, BG_ERR_PARSE, "a second $MeshFormat") : gmsh_format(&g);
        } else if (tok_is(&t, "$Nodes")) {
            if (g.saw_nodes)
                st = sc_fail(&g.s, BG_ERR_PARSE, "a second $Nodes section");
            else if ((st = g.major == 2 ? gmsh_nodes2(&g) : gmsh_nodes4(&g)) == BG_OK)
                st = gmsh_index_nodes(&g);
            g.saw_nodes = 1;
        } else if (tok_is(&t, "$Elements")) {
            if (!g.saw_nodes || g.saw_elements)
                st = sc_fail(&g.s, BG_ERR_PARSE,
                             g.saw_elements ? "a second $Elements section"
                                            : "$Elements before "
                                              "$Nodes");
            else
                st = g.major == 2 ? gmsh_elements2(&g) : gmsh_elements4(&g);
            g.saw_elements = 1;
        } else if (tok_is(&t, "$Entities") && g.major == 4) {
            st = saw_entities ? sc_fail(&g.s, BG_ERR_PARSE, "a second $Entities section")
                              : gmsh_entities(&g);
            saw_entities = 1;
        } else {
            st = gmsh_skip_section(&g, &t);
        }
    }
    if (st != BG_OK)
        goto out;
    if (!g.major || !g.saw_elements) {
        st = sc_fail(&g.s, BG_ERR_PARSE, "no %s section (truncated file?)",
                     !g.major ? "$MeshFormat" : "$Elements");
        goto out;
    }
    if (found)
        *found = g.major == 2 ? BG_FORMAT_GMSH22 : BG_FORMAT_GMSH41;
    if (g.tet.n > 0)
        st = mesh_adopt(BG_MESH_VOLUME, (int32_t)g.nv, &g.x, &vref, &g.tet, name, out, err);
    else if (g.tri.n > 0)
        st = mesh_adopt(BG_MESH_SURFACE, (int32_t)g.nv, &g.x, &vref, &g.tri, name, out, err);
    else
        st = sc_fail(&g.s, BG_ERR_INVALID, "no triangles or tetrahedra in $Elements");
out:
    free(vref);
    free(g.x);
    free(g.tags);
    free(g.index);
    free(g.entities);
    elist_release(&g.tri);
    elist_release(&g.tet);
    return st;
}

/* ------------------------------------------------------------------------
 * VTU (read back of bg_mesh_write_vtu)
 */

/* First occurrence of needle in [p, end), or NULL. */
static const char *find_str(const char *p, const char *end, const char *needle)
{
    size_t n = strlen(needle);
    while (p < end && (size_t)(end - p) >= n) {
        const char *hit = memchr(p, needle[0], (size_t)(end - p) - n + 1);
        if (!hit)
            return NULL;
        if (memcmp(hit, needle, n) == 0)
            return hit;
        p = hit + 1;
    }
    return NULL;
}

/* Longest attribute name looked up. */
#define XML_ATTR_NAME_MAX 48

/* The quoted value of attribute `attr` inside the tag [p, tag_end). */
static int xml_attr(const char *p, const char *tag_end, const char *attr, token_t *val)
{
    char pattern[XML_ATTR_NAME_MAX + 4];
    snprintf(pattern, sizeof pattern, " %s=\"", attr);
    const char *a = find_str(p, tag_end, pattern);
    if (!a)
        return 0;
    a += strlen(pattern);
    const char *q = memchr(a, '"', (size_t)(tag_end - a));
    if (!q)
        return 0;
    val->p = a;
    val->n = (size_t)(q - a);
    return 1;
}

/* Moves the scanner to `to`, counting the lines on the way. */
static void sc_seek(scan_t *s, const char *to)
{
    for (const char *p = s->p; p < to; p++)
        s->line += *p == '\n';
    s->p = to;
}

/* A <DataArray ...> element: its opening tag and its character data. */
typedef struct xml_array {
    const char *tag, *tag_end, *data, *data_end;
} xml_array_t;

/* Finds the next DataArray in [p, end) whose Name is `name` (any when NULL). */
static int vtu_find_array(const char *p, const char *end, const char *name, xml_array_t *a)
{
    while ((a->tag = find_str(p, end, "<DataArray")) != NULL) {
        a->tag_end = memchr(a->tag, '>', (size_t)(end - a->tag));
        if (!a->tag_end)
            return 0;
        a->data = a->tag_end + 1;
        a->data_end = find_str(a->data, end, "</DataArray>");
        if (!a->data_end)
            return 0;
        token_t v;
        if (!name || (xml_attr(a->tag, a->tag_end, "Name", &v) && tok_is(&v, name)))
            return 1;
        p = a->data_end;
    }
    return 0;
}

/* Reads exactly `count` integers in [lo, hi] from a DataArray's data. */
static bg_status vtu_ints(scan_t *whole, const xml_array_t *a, const char *what, int64_t count,
                          int64_t lo, int64_t hi, int32_t *out)
{
    scan_t s = *whole;
    bg_status st;
    sc_seek(&s, a->data);
    s.end = a->data_end;
    if ((st = sc_count(&s, count, BG_MESH_MAX_ELEMENTS * 4LL, 1, what)) != BG_OK)
        return st;
    for (int64_t i = 0; i < count; i++) {
        int64_t v = 0;
        if ((st = sc_int(&s, 1, &v, "%lld values in %s", (long long)count, what)) != BG_OK)
            return st;
        if (v < lo || v > hi)
            return sc_fail(&s, BG_ERR_INVALID, "%s value %lld (entry %lld) outside %lld..%lld",
                           what, (long long)v, (long long)i + 1, (long long)lo, (long long)hi);
        out[i] = (int32_t)v;
    }
    if (!sc_at_end(&s))
        return sc_fail(&s, BG_ERR_PARSE, "more than %lld values in %s", (long long)count, what);
    return BG_OK;
}

bg_status bg_mesh_parse_vtu(const char *text, size_t length, const char *name, bg_mesh_t **out,
                            bg_error_t *err)
{
    scan_t s;
    bg_status st = BG_OK;
    const char *end = text + (text ? length : 0);
    int64_t np = 0, nc = 0;
    double *x = NULL;
    int32_t *vref = NULL, *types = NULL, *offsets = NULL;
    elist_t el = {3, NULL, NULL, 0, 0};
    xml_array_t points, conn, offs, typ;
    token_t v;
    *out = NULL;
    sc_init(&s, text, text ? length : 0, name, 0, err);

    const char *grid = find_str(s.p, end, "<VTKFile");
    const char *grid_end = grid ? memchr(grid, '>', (size_t)(end - grid)) : NULL;
    if (!grid_end || !xml_attr(grid, grid_end, "type", &v) || !tok_is(&v, "UnstructuredGrid")) {
        st = sc_fail(&s, BG_ERR_PARSE, "no <VTKFile type=\"UnstructuredGrid\"> (not a .vtu?)");
        goto out;
    }
    const char *piece = find_str(grid_end, end, "<Piece");
    const char *piece_end = piece ? memchr(piece, '>', (size_t)(end - piece)) : NULL;
    if (!piece_end) {
        st = sc_fail(&s, BG_ERR_PARSE, "no <Piece> element");
        goto out;
    }
    sc_seek(&s, piece);
    if (!xml_attr(piece, piece_end, "NumberOfPoints", &v) || !parse_i64(v.p, v.n, &np) ||
        !xml_attr(piece, piece_end, "NumberOfCells", &v) || !parse_i64(v.p, v.n, &nc)) {
        st = sc_fail(&s, BG_ERR_PARSE, "<Piece> lacks NumberOfPoints or NumberOfCells");
        goto out;
    }
    const char *pts = find_str(piece_end, end, "<Points>");
    const char *cells = find_str(piece_end, end, "<Cells>");
    if (!pts || !cells || !vtu_find_array(pts, end, NULL, &points) ||
        !vtu_find_array(cells, end, "connectivity", &conn) ||
        !vtu_find_array(cells, end, "offsets", &offs) ||
        !vtu_find_array(cells, end, "types", &typ)) {
        st = sc_fail(&s, BG_ERR_PARSE,
                     "missing <Points> or <Cells> with connectivity, offsets and types");
        goto out;
    }
    if ((st = sc_count(&s, np, BG_MESH_MAX_VERTICES, 3, "points")) != BG_OK ||
        (st = sc_count(&s, nc, BG_MESH_MAX_ELEMENTS, 3, "cells")) != BG_OK)
        goto out;
    x = malloc(((size_t)np * 3 + 1) * sizeof *x);
    types = malloc(((size_t)nc + 1) * sizeof *types);
    offsets = malloc(((size_t)nc + 1) * sizeof *offsets);
    if (!x || !types || !offsets) {
        st = sc_fail(&s, BG_ERR_NOMEM, "out of memory for %lld points", (long long)np);
        goto out;
    }
    scan_t ps = s;
    sc_seek(&ps, points.data);
    ps.end = points.data_end;
    for (int64_t i = 0; i < 3 * np; i++) {
        if ((st = sc_real(&ps, 1, &x[i], "3 coordinates for each of %lld points", (long long)np)) !=
            BG_OK)
            goto out;
        if (!isfinite(x[i])) {
            st = sc_fail(&ps, BG_ERR_INVALID, "point %lld has a non-finite coordinate %c",
                         (long long)(i / 3), "xyz"[i % 3]);
            goto out;
        }
    }
    if (!sc_at_end(&ps)) {
        st = sc_fail(&ps, BG_ERR_PARSE, "more than %lld points", (long long)np);
        goto out;
    }
    if ((st = vtu_ints(&s, &typ, "types", nc, 0, INT32_LIMIT, types)) != BG_OK)
        goto out;
    int k = nc > 0 && types[0] == VTK_TETRA ? 4 : 3;
    for (int64_t c = 0; c < nc; c++)
        if (types[c] != (k == 4 ? VTK_TETRA : VTK_TRIANGLE)) {
            sc_seek(&s, typ.data);
            st = sc_fail(&s, BG_ERR_UNSUPPORTED,
                         "cell %lld has VTK type %d; all cells must be triangles (5) or all "
                         "tetrahedra (10)",
                         (long long)c, (int)types[c]);
            goto out;
        }
    if ((st = vtu_ints(&s, &offs, "offsets", nc, 0, INT32_LIMIT, offsets)) != BG_OK)
        goto out;
    for (int64_t c = 0; c < nc; c++)
        if (offsets[c] != k * (c + 1)) {
            sc_seek(&s, offs.data);
            st = sc_fail(&s, BG_ERR_INVALID, "offset of cell %lld is %d, expected %lld",
                         (long long)c, (int)offsets[c], (long long)(k * (c + 1)));
            goto out;
        }
    el.k = k;
    if (!elist_reserve(&el, (size_t)nc + 1)) {
        st = sc_fail(&s, BG_ERR_NOMEM, "out of memory for %lld cells", (long long)nc);
        goto out;
    }
    if ((st = vtu_ints(&s, &conn, "connectivity", nc * k, 0, np - 1, el.v)) != BG_OK)
        goto out;
    memset(el.ref, 0, (size_t)nc * sizeof *el.ref);
    el.n = (size_t)nc;
    st = mesh_adopt(k == 4 ? BG_MESH_VOLUME : BG_MESH_SURFACE, (int32_t)np, &x, &vref, &el, name,
                    out, err);
out:
    free(x);
    free(vref);
    free(types);
    free(offsets);
    elist_release(&el);
    return st;
}

/* ------------------------------------------------------------------------
 * Formats and dispatch
 */

static int ends_with_nocase(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    if (m > n)
        return 0;
    for (size_t i = 0; i < m; i++)
        if (lower(s[n - m + i]) != lower(suffix[i]))
            return 0;
    return 1;
}

bg_mesh_format bg_mesh_format_from_path(const char *path)
{
    static const struct {
        const char *suffix;
        bg_mesh_format format;
    } table[] = {
        {".mesh", BG_FORMAT_MEDIT},  {".off", BG_FORMAT_OFF},    {".obj", BG_FORMAT_OBJ},
        {".node", BG_FORMAT_TETGEN}, {".ele", BG_FORMAT_TETGEN}, {".msh", BG_FORMAT_GMSH41},
        {".vtu", BG_FORMAT_VTU},
    };
    if (!path)
        return BG_FORMAT_UNKNOWN;
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++)
        if (ends_with_nocase(path, table[i].suffix))
            return table[i].format;
    return BG_FORMAT_UNKNOWN;
}

const char *bg_mesh_format_extension(bg_mesh_format format)
{
    switch (format) {
    case BG_FORMAT_MEDIT:
        return "mesh";
    case BG_FORMAT_OFF:
        return "off";
    case BG_FORMAT_OBJ:
        return "obj";
    case BG_FORMAT_TETGEN:
        return "node";
    case BG_FORMAT_GMSH22:
    case BG_FORMAT_GMSH41:
        return "msh";
    case BG_FORMAT_VTU:
        return "vtu";
    case BG_FORMAT_UNKNOWN:
        break;
    }
    return "";
}

const char *bg_mesh_format_name(bg_mesh_format format)
{
    switch (format) {
    case BG_FORMAT_MEDIT:
        return "MEDIT";
    case BG_FORMAT_OFF:
        return "OFF";
    case BG_FORMAT_OBJ:
        return "OBJ";
    case BG_FORMAT_TETGEN:
        return "TetGen";
    case BG_FORMAT_GMSH22:
        return "Gmsh 2.2";
    case BG_FORMAT_GMSH41:
        return "Gmsh 4.1";
    case BG_FORMAT_VTU:
        return "VTU";
    case BG_FORMAT_UNKNOWN:
        break;
    }
    return "unknown";
}

/* As bg_mesh_parse, also reporting the Gmsh version found. */
static bg_status parse_any(bg_mesh_format format, const char *text, size_t length, const char *name,
                           bg_mesh_t **out, bg_mesh_format *found, bg_error_t *err)
{
    *out = NULL;
    if (found)
        *found = format;
    if (!name)
        name = "(unnamed)";
    if (!text)
        length = 0;
    switch (format) {
    case BG_FORMAT_MEDIT:
        return parse_medit(text, length, name, out, err);
    case BG_FORMAT_OFF:
        return parse_off(text, length, name, out, err);
    case BG_FORMAT_OBJ:
        return parse_obj(text, length, name, out, err);
    case BG_FORMAT_GMSH22:
    case BG_FORMAT_GMSH41:
        return parse_gmsh(text, length, name, out, found, err);
    case BG_FORMAT_VTU:
        return bg_mesh_parse_vtu(text, length, name, out, err);
    case BG_FORMAT_TETGEN:
        return bg_error_set(err, BG_ERR_INVALID,
                            "%s: TetGen needs a .node and an .ele text: use bg_mesh_parse_tetgen",
                            name);
    case BG_FORMAT_UNKNOWN:
        break;
    }
    return bg_error_set(err, BG_ERR_INVALID, "%s: unknown mesh format", name);
}

bg_status bg_mesh_parse(bg_mesh_format format, const char *text, size_t length, const char *name,
                        bg_mesh_t **out, bg_error_t *err)
{
    return parse_any(format, text, length, name, out, NULL, err);
}

/* path with its extension (after the last '.' of the last component)
 * replaced by `ext` (with its dot). Caller frees. */
static char *replace_extension(const char *path, const char *ext)
{
    const char *slash = strrchr(path, '/');
    const char *dot = strrchr(path, '.');
    size_t n = dot && (!slash || dot > slash) ? (size_t)(dot - path) : strlen(path);
    char *r = malloc(n + strlen(ext) + 1);
    if (r) {
        memcpy(r, path, n);
        strcpy(r + n, ext);
    }
    return r;
}

bg_status bg_mesh_read(const char *path, bg_mesh_t **out, bg_mesh_format *format, bg_error_t *err)
{
    bg_mesh_format f = bg_mesh_format_from_path(path);
    char *text = NULL, *text2 = NULL, *node_path = NULL, *ele_path = NULL;
    size_t length = 0, length2 = 0;
    bg_status st;
    *out = NULL;
    if (format)
        *format = f;
    if (f == BG_FORMAT_UNKNOWN)
        return bg_error_set(
            err, BG_ERR_INVALID,
            "%s: unknown mesh format (expected .mesh .off .obj .node .ele .msh .vtu)",
            path ? path : "(null)");
    if (f == BG_FORMAT_TETGEN) {
        node_path = replace_extension(path, ".node");
        ele_path = replace_extension(path, ".ele");
        if (!node_path || !ele_path) {
            st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
            goto out;
        }
        if ((st = bg_file_read_all(node_path, BG_MESH_FILE_MAX_BYTES, &text, &length, err)) !=
                BG_OK ||
            (st = bg_file_read_all(ele_path, BG_MESH_FILE_MAX_BYTES, &text2, &length2, err)) !=
                BG_OK)
            goto out;
        st = bg_mesh_parse_tetgen(text, length, text2, length2, path, out, err);
        goto out;
    }
    if ((st = bg_file_read_all(path, BG_MESH_FILE_MAX_BYTES, &text, &length, err)) != BG_OK)
        goto out;
    st = parse_any(f, text, length, path, out, format, err);
out:
    free(text);
    free(text2);
    free(node_path);
    free(ele_path);
    return st;
}

/* ------------------------------------------------------------------------
 * Writers
 */

static bg_status out_open(const char *path, FILE **f, bg_error_t *err)
{
    *f = fopen(path, "w");
    if (!*f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot open for writing: %s", path,
                            strerror(errno));
    setvbuf(*f, NULL, _IOFBF, WRITE_BUFFER_BYTES);
    return BG_OK;
}

/* Closes f and turns a failed write or close into BG_ERR_IO (unless st
 * already reports an error). */
static bg_status out_close(FILE *f, const char *path, bg_status st, bg_error_t *err)
{
    int failed = ferror(f);
    int code = errno;
    if (fclose(f) != 0 && !failed) {
        failed = 1;
        code = errno;
    }
    if (st == BG_OK && failed)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", path, strerror(code));
    return st;
}

/* Writes vertex v's coordinates, padded with zeros to `width` numbers. */
static void put_point(FILE *f, const bg_mesh_t *m, const double *x, int32_t v, int width)
{
    for (int c = 0; c < width; c++)
        fprintf(f, c ? " " DOUBLE_FORMAT : DOUBLE_FORMAT,
                c < m->dim ? x[(size_t)v * m->dim + c] : 0.0);
}

/* Room for one formatted int32 plus a separator. */
#define INT_TEXT_MAX 16

/* Decimal text of v at buf (no NUL); returns its length. Writers format
 * millions of indices, and this is several times faster than fprintf. */
static size_t format_int(char *buf, int64_t v)
{
    char digits[INT_TEXT_MAX];
    size_t n = 0, len = 0;
    uint64_t u = v < 0 ? (uint64_t)0 - (uint64_t)v : (uint64_t)v;
    do {
        digits[n++] = (char)('0' + u % 10);
        u /= 10;
    } while (u);
    if (v < 0)
        buf[len++] = '-';
    while (n)
        buf[len++] = digits[--n];
    return len;
}

/* Writes element e's indices plus `base`, separated by blanks. */
static void put_element(FILE *f, const bg_mesh_t *m, int32_t e, int base)
{
    char line[4 * INT_TEXT_MAX];
    size_t len = 0;
    const int32_t *el = m->elements + (size_t)e * (size_t)m->nodes_per_element;
    for (int i = 0; i < m->nodes_per_element; i++) {
        if (i)
            line[len++] = ' ';
        len += format_int(line + len, (int64_t)el[i] + base);
    }
    fwrite(line, 1, len, f);
}

static void write_medit(FILE *f, const bg_mesh_t *m, const double *x)
{
    fprintf(f, "MeshVersionFormatted 2\nDimension %d\n\nVertices\n%d\n", m->dim, (int)m->nv);
    for (int32_t v = 0; v < m->nv; v++) {
        put_point(f, m, x, v, m->dim);
        fprintf(f, " %d\n", (int)m->vertex_ref[v]);
    }
    fprintf(f, "\n%s\n%d\n", m->nodes_per_element == 4 ? "Tetrahedra" : "Triangles", (int)m->ne);
    for (int32_t e = 0; e < m->ne; e++) {
        put_element(f, m, e, 1);
        fprintf(f, " %d\n", (int)m->element_ref[e]);
    }
    fputs("\nEnd\n", f);
}

static void write_off(FILE *f, const bg_mesh_t *m, const double *x)
{
    fprintf(f, "OFF\n%d %d 0\n", (int)m->nv, (int)m->ne);
    for (int32_t v = 0; v < m->nv; v++) {
        put_point(f, m, x, v, 3);
        fputc('\n', f);
    }
    for (int32_t e = 0; e < m->ne; e++) {
        fputs("3 ", f);
        put_element(f, m, e, 0);
        fputc('\n', f);
    }
}

static void write_obj(FILE *f, const bg_mesh_t *m, const double *x)
{
    for (int32_t v = 0; v < m->nv; v++) {
        fputs("v ", f);
        put_point(f, m, x, v, 3);
        fputc('\n', f);
    }
    for (int32_t e = 0; e < m->ne; e++) {
        fputs("f ", f);
        put_element(f, m, e, 1);
        fputc('\n', f);
    }
}

static void write_gmsh22(FILE *f, const bg_mesh_t *m, const double *x)
{
    int type = m->nodes_per_element == 4 ? GMSH_TETRAHEDRON : GMSH_TRIANGLE;
    fprintf(f, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n", (int)m->nv);
    for (int32_t v = 0; v < m->nv; v++) {
        fprintf(f, "%d ", (int)v + 1);
        put_point(f, m, x, v, 3);
        fputc('\n', f);
    }
    /* Tags: the physical tag carries element_ref; the elementary entity is 1. */
    fprintf(f, "$EndNodes\n$Elements\n%d\n", (int)m->ne);
    for (int32_t e = 0; e < m->ne; e++) {
        fprintf(f, "%d %d 2 %d 1 ", (int)e + 1, type, (int)m->element_ref[e]);
        put_element(f, m, e, 1);
        fputc('\n', f);
    }
    fputs("$EndElements\n", f);
}

static int cmp_int32(const void *a, const void *b)
{
    int32_t p = *(const int32_t *)a, q = *(const int32_t *)b;
    return (p > q) - (p < q);
}

/*
 * Gmsh 4.1 keeps physical tags on entities, so each distinct element_ref
 * becomes one entity (tag = its rank + 1, physical tag = the ref, none for
 * 0) and the elements are written in their own order as blocks of equal
 * refs, which a read-back maps to the same refs in the same order.
 */
static bg_status write_gmsh41(FILE *f, const bg_mesh_t *m, const double *x, bg_error_t *err)
{
    int type = m->nodes_per_element == 4 ? GMSH_TETRAHEDRON : GMSH_TRIANGLE;
    int edim = m->nodes_per_element == 4 ? 3 : 2;
    size_t nrefs = 0, blocks = 0;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    int32_t *refs = malloc(((size_t)m->ne + 1) * sizeof *refs);
    if (!refs)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory writing Gmsh entities");
    memcpy(refs, m->element_ref, (size_t)m->ne * sizeof *refs);
    qsort(refs, (size_t)m->ne, sizeof *refs, cmp_int32);
    for (int32_t e = 0; e < m->ne; e++)
        if (e == 0 || refs[e] != refs[nrefs - 1])
            refs[nrefs++] = refs[e];
    for (int32_t e = 0; e < m->ne; e++)
        blocks += e == 0 || m->element_ref[e] != m->element_ref[e - 1];
    for (int32_t v = 0; v < m->nv; v++)
        for (int c = 0; c < m->dim; c++) {
            double t = x[(size_t)v * m->dim + c];
            lo[c] = v == 0 || t < lo[c] ? t : lo[c];
            hi[c] = v == 0 || t > hi[c] ? t : hi[c];
        }
    fputs("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Entities\n", f);
    fprintf(f, "0 0 %zu %zu\n", edim == 2 ? nrefs : 0, edim == 3 ? nrefs : 0);
    for (size_t i = 0; i < nrefs; i++) {
        fprintf(f, "%zu", i + 1);
        for (int c = 0; c < 3; c++)
            fprintf(f, " " DOUBLE_FORMAT, lo[c]);
        for (int c = 0; c < 3; c++)
            fprintf(f, " " DOUBLE_FORMAT, hi[c]);
        if (refs[i] != 0)
            fprintf(f, " 1 %d 0\n", (int)refs[i]);
        else
            fputs(" 0 0\n", f);
    }
    fprintf(f, "$EndEntities\n$Nodes\n1 %d 1 %d\n%d 1 0 %d\n", (int)m->nv, (int)m->nv, edim,
            (int)m->nv);
    for (int32_t v = 0; v < m->nv; v++)
        fprintf(f, "%d\n", (int)v + 1);
    for (int32_t v = 0; v < m->nv; v++) {
        put_point(f, m, x, v, 3);
        fputc('\n', f);
    }
    fprintf(f, "$EndNodes\n$Elements\n%zu %d 1 %d\n", blocks, (int)m->ne, (int)m->ne);
    for (int32_t e = 0; e < m->ne;) {
        int32_t run = 1;
        while (e + run < m->ne && m->element_ref[e + run] == m->element_ref[e])
            run++;
        const int32_t *hit = bsearch(&m->element_ref[e], refs, nrefs, sizeof *refs, cmp_int32);
        fprintf(f, "%d %d %d %d\n", edim, (int)(hit - refs) + 1, type, (int)run);
        for (int32_t i = e; i < e + run; i++) {
            fprintf(f, "%d ", (int)i + 1);
            put_element(f, m, i, 1);
            fputc('\n', f);
        }
        e += run;
    }
    fputs("$EndElements\n", f);
    free(refs);
    return BG_OK;
}

/* TetGen .node (1-based, boundary marker = vertex_ref) and .ele (region
 * attribute = element_ref); planar meshes give Triangle-style 2D files. */
static bg_status write_tetgen(const bg_mesh_t *m, const double *x, const char *path,
                              bg_error_t *err)
{
    char *node_path = replace_extension(path, ".node");
    char *ele_path = replace_extension(path, ".ele");
    FILE *f = NULL;
    bg_status st = BG_OK;
    if (!node_path || !ele_path) {
        st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
        goto out;
    }
    if ((st = out_open(node_path, &f, err)) != BG_OK)
        goto out;
    fprintf(f, "%d %d 0 1\n", (int)m->nv, m->dim);
    for (int32_t v = 0; v < m->nv; v++) {
        fprintf(f, "%d ", (int)v + 1);
        put_point(f, m, x, v, m->dim);
        fprintf(f, " %d\n", (int)m->vertex_ref[v]);
    }
    if ((st = out_close(f, node_path, st, err)) != BG_OK ||
        (st = out_open(ele_path, &f, err)) != BG_OK)
        goto out;
    fprintf(f, "%d %d 1\n", (int)m->ne, m->nodes_per_element);
    for (int32_t e = 0; e < m->ne; e++) {
        fprintf(f, "%d ", (int)e + 1);
        put_element(f, m, e, 1);
        fprintf(f, " %d\n", (int)m->element_ref[e]);
    }
    st = out_close(f, ele_path, st, err);
out:
    free(node_path);
    free(ele_path);
    return st;
}

bg_status bg_mesh_write(const bg_mesh_t *mesh, const double *x, bg_mesh_format format,
                        const char *path, bg_error_t *err)
{
    FILE *f = NULL;
    bg_status st = BG_OK;
    if (!mesh || !x || !path)
        return bg_error_set(err, BG_ERR_INVALID, "bg_mesh_write: NULL mesh, positions or path");
    if (mesh->nodes_per_element == 4 && (format == BG_FORMAT_OFF || format == BG_FORMAT_OBJ))
        return bg_error_set(err, BG_ERR_UNSUPPORTED,
                            "%s: %s holds triangle surfaces, not tetrahedra", path,
                            bg_mesh_format_name(format));
    switch (format) {
    case BG_FORMAT_TETGEN:
        return write_tetgen(mesh, x, path, err);
    case BG_FORMAT_VTU:
        return bg_mesh_write_vtu(mesh, x, NULL, 0, NULL, 0, path, err);
    case BG_FORMAT_MEDIT:
    case BG_FORMAT_OFF:
    case BG_FORMAT_OBJ:
    case BG_FORMAT_GMSH22:
    case BG_FORMAT_GMSH41:
        break;
    case BG_FORMAT_UNKNOWN:
        return bg_error_set(err, BG_ERR_INVALID, "%s: unknown mesh format for writing", path);
    }
    if ((st = out_open(path, &f, err)) != BG_OK)
        return st;
    switch (format) {
    case BG_FORMAT_MEDIT:
        write_medit(f, mesh, x);
        break;
    case BG_FORMAT_OFF:
        write_off(f, mesh, x);
        break;
    case BG_FORMAT_OBJ:
        write_obj(f, mesh, x);
        break;
    case BG_FORMAT_GMSH22:
        write_gmsh22(f, mesh, x);
        break;
    default:
        st = write_gmsh41(f, mesh, x, err);
        break;
    }
    return out_close(f, path, st, err);
}

/* Writes s with the five XML special characters escaped. */
static void put_xml_escaped(FILE *f, const char *s)
{
    for (; *s; s++)
        switch (*s) {
        case '&':
            fputs("&amp;", f);
            break;
        case '<':
            fputs("&lt;", f);
            break;
        case '>':
            fputs("&gt;", f);
            break;
        case '"':
            fputs("&quot;", f);
            break;
        case '\'':
            fputs("&apos;", f);
            break;
        default:
            fputc(*s, f);
        }
}

/* Checks data arrays before anything is written: VTK's ASCII reader cannot
 * read "nan" or "inf", so non-finite values are refused, naming the tuple. */
static bg_status vtu_check_arrays(const bg_vtu_array_t *a, int n, int32_t tuples, const char *where,
                                  const char *path, bg_error_t *err)
{
    if (n < 0 || (n > 0 && !a))
        return bg_error_set(err, BG_ERR_INVALID, "%s: bad %s array list", path, where);
    for (int i = 0; i < n; i++) {
        if (!a[i].name || a[i].components < 1 || (!a[i].values && tuples > 0))
            return bg_error_set(err, BG_ERR_INVALID,
                                "%s: %s array %d needs a name, components >= 1 and values", path,
                                where, i);
        size_t count = (size_t)tuples * (size_t)a[i].components;
        for (size_t j = 0; j < count; j++)
            if (!isfinite(a[i].values[j]))
                return bg_error_set(err, BG_ERR_INVALID,
                                    "%s: %s array '%s' has a non-finite value at tuple %zu", path,
                                    where, a[i].name, j / (size_t)a[i].components);
    }
    return BG_OK;
}

static void put_vtu_arrays(FILE *f, const char *section, const bg_vtu_array_t *a, int n,
                           int32_t tuples)
{
    fprintf(f, "      <%s>\n", section);
    for (int i = 0; i < n; i++) {
        fputs("        <DataArray type=\"Float64\" Name=\"", f);
        put_xml_escaped(f, a[i].name);
        fprintf(f, "\" NumberOfComponents=\"%d\" format=\"ascii\">\n", a[i].components);
        for (int32_t t = 0; t < tuples; t++) {
            for (int c = 0; c < a[i].components; c++)
                fprintf(f, c ? " " DOUBLE_FORMAT : DOUBLE_FORMAT,
                        a[i].values[(size_t)t * a[i].components + c]);
            fputc('\n', f);
        }
        fputs("        </DataArray>\n", f);
    }
    fprintf(f, "      </%s>\n", section);
}

bg_status bg_mesh_write_vtu(const bg_mesh_t *mesh, const double *x,
                            const bg_vtu_array_t *point_data, int point_arrays,
                            const bg_vtu_array_t *cell_data, int cell_arrays, const char *path,
                            bg_error_t *err)
{
    FILE *f = NULL;
    bg_status st;
    if (!mesh || !x || !path)
        return bg_error_set(err, BG_ERR_INVALID, "bg_mesh_write_vtu: NULL mesh, positions or path");
    size_t nx = (size_t)mesh->nv * (size_t)mesh->dim;
    for (size_t i = 0; i < nx; i++)
        if (!isfinite(x[i]))
            return bg_error_set(err, BG_ERR_INVALID, "%s: vertex %zu has a non-finite coordinate",
                                path, i / (size_t)mesh->dim + 1);
    if ((st = vtu_check_arrays(point_data, point_arrays, mesh->nv, "point", path, err)) != BG_OK ||
        (st = vtu_check_arrays(cell_data, cell_arrays, mesh->ne, "cell", path, err)) != BG_OK ||
        (st = out_open(path, &f, err)) != BG_OK)
        return st;
    const int k = mesh->nodes_per_element;
    fputs("<?xml version=\"1.0\"?>\n"
          "<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
          "  <UnstructuredGrid>\n",
          f);
    fprintf(f, "    <Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n", (int)mesh->nv,
            (int)mesh->ne);
    put_vtu_arrays(f, "PointData", point_data, point_arrays, mesh->nv);
    put_vtu_arrays(f, "CellData", cell_data, cell_arrays, mesh->ne);
    fputs("      <Points>\n"
          "        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n",
          f);
    for (int32_t v = 0; v < mesh->nv; v++) {
        put_point(f, mesh, x, v, 3);
        fputc('\n', f);
    }
    fputs("        </DataArray>\n      </Points>\n      <Cells>\n"
          "        <DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n",
          f);
    for (int32_t e = 0; e < mesh->ne; e++) {
        put_element(f, mesh, e, 0);
        fputc('\n', f);
    }
    fputs("        </DataArray>\n"
          "        <DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n",
          f);
    for (int32_t e = 0; e < mesh->ne; e++)
        fprintf(f, "%lld\n", (long long)k * (e + 1));
    fputs("        </DataArray>\n"
          "        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n",
          f);
    for (int32_t e = 0; e < mesh->ne; e++)
        fprintf(f, "%d\n", k == 4 ? VTK_TETRA : VTK_TRIANGLE);
    fputs("        </DataArray>\n      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n"
          "</VTKFile>\n",
          f);
    return out_close(f, path, BG_OK, err);
}

/* ------------------------------------------------------------------------
 * Planar conversion, positions, selections, files
 */

bg_status bg_mesh_to_planar(const bg_mesh_t *surface, bg_mesh_t **out, bg_error_t *err)
{
    bg_mesh_t *m = NULL;
    bg_status st;
    *out = NULL;
    if (bg_mesh_kind_of(surface) == BG_MESH_PLANAR)
        return bg_mesh_clone(surface, out, err);
    if (bg_mesh_kind_of(surface) != BG_MESH_SURFACE)
        return bg_error_set(err, BG_ERR_INVALID,
                            "a planar mesh needs triangles; this mesh has tetrahedra");
    double lo[3], hi[3], extent = 0.0;
    bg_mesh_bounds(surface, lo, hi);
    for (int c = 0; c < 3; c++)
        extent = fmax(extent, hi[c] - lo[c]);
    const double tolerance = PLANAR_TOLERANCE * extent;
    for (int32_t v = 0; v < surface->nv; v++) {
        double z = surface->x[(size_t)v * 3 + 2];
        if (!(fabs(z) <= tolerance))
            return bg_error_set(err, BG_ERR_INVALID,
                                "vertex %d has z = %g, off the plane z = 0 (tolerance %g)",
                                (int)v + 1, z, tolerance);
    }
    if ((st = bg_mesh_new(BG_MESH_PLANAR, surface->nv, surface->ne, &m, err)) != BG_OK)
        return st;
    for (int32_t v = 0; v < surface->nv; v++) {
        m->x[(size_t)v * 2] = surface->x[(size_t)v * 3];
        m->x[(size_t)v * 2 + 1] = surface->x[(size_t)v * 3 + 1];
    }
    memcpy(m->elements, surface->elements, (size_t)surface->ne * 3 * sizeof *m->elements);
    memcpy(m->vertex_ref, surface->vertex_ref, (size_t)surface->nv * sizeof *m->vertex_ref);
    memcpy(m->element_ref, surface->element_ref, (size_t)surface->ne * sizeof *m->element_ref);
    /* Triangles seen from below (clockwise in the plane) are reoriented. */
    if ((st = bg_mesh_validate(m, "planar copy", NULL, err)) != BG_OK)
        bg_mesh_destroy(&m);
    *out = m;
    return st;
}

bg_status bg_positions_parse(const char *text, size_t length, const char *name, int32_t nv, int dim,
                             double *out, bg_error_t *err)
{
    scan_t s;
    bg_status st;
    if (!name)
        name = "(unnamed)";
    if (nv < 0 || dim < 1 || dim > 3 || (nv > 0 && !out))
        return bg_error_set(err, BG_ERR_INVALID, "%s: bad request (%d vertices of dimension %d)",
                            name, (int)nv, dim);
    sc_init(&s, text, text ? length : 0, name, '#', err);
    for (int32_t v = 0; v < nv; v++) {
        for (int c = 0; c < dim; c++) {
            double *p = out + (size_t)v * (size_t)dim + c;
            if ((st = sc_real(&s, c == 0, p, "%d coordinates for vertex %d (of %d)", dim,
                              (int)v + 1, (int)nv)) != BG_OK)
                return st;
            if (!isfinite(*p))
                return sc_fail(&s, BG_ERR_INVALID, "vertex %d has a non-finite coordinate %c",
                               (int)v + 1, "xyz"[c]);
        }
        if ((st = sc_end_record(&s, "the %d coordinates of vertex %d", dim, (int)v + 1)) != BG_OK)
            return st;
    }
    if (!sc_at_end(&s))
        return sc_fail(&s, BG_ERR_PARSE, "more than %d vertex lines", (int)nv);
    return BG_OK;
}

/* An integer label, written as an integer or an integral real (libigl
 * writes DMAT values as reals). */
static int parse_label(const token_t *t, int32_t *label)
{
    int64_t v = 0;
    double d = 0.0;
    if (!parse_i64(t->p, t->n, &v)) {
        if (!parse_double(t->p, t->n, &d) || d != floor(d) || fabs(d) > (double)INT32_LIMIT)
            return 0;
        v = (int64_t)d;
    }
    if (v < -INT32_LIMIT - 1 || v > INT32_LIMIT)
        return 0;
    *label = (int32_t)v;
    return 1;
}

/*
 * A DMAT header is "cols rows" alone on the first line with rows = nv. A
 * plain index list cannot start that way (index nv is out of range), so
 * the two readings never overlap.
 */
static int is_dmat_header(scan_t probe, int32_t nv, int64_t *cols)
{
    token_t a, b, c;
    int64_t rows = 0;
    if (!sc_token(&probe, 1, &a) || !sc_token(&probe, 0, &b) || sc_token(&probe, 0, &c))
        return 0;
    return parse_i64(a.p, a.n, cols) && parse_i64(b.p, b.n, &rows) && rows == nv;
}

bg_status bg_selection_parse(const char *text, size_t length, const char *name, int32_t nv,
                             int32_t *labels, bg_error_t *err)
{
    scan_t s;
    token_t t;
    int64_t cols = 0;
    bg_status st;
    if (!name)
        name = "(unnamed)";
    if (nv < 0 || (nv > 0 && !labels))
        return bg_error_set(err, BG_ERR_INVALID, "%s: bad request (%d vertices)", name, (int)nv);
    sc_init(&s, text, text ? length : 0, name, '#', err);
    if (is_dmat_header(s, nv, &cols)) {
        sc_token(&s, 1, &t);
        sc_token(&s, 0, &t);
        if (cols != 1)
            return sc_fail(&s, BG_ERR_INVALID, "DMAT with %lld columns; a selection has 1",
                           (long long)cols);
        for (int32_t v = 0; v < nv; v++) {
            if (!sc_token(&s, 1, &t))
                return sc_fail(&s, BG_ERR_PARSE, "expected %d labels, found %d (truncated file?)",
                               (int)nv, (int)v);
            if (!parse_label(&t, &labels[v])) {
                char q[QUOTE_MAX_CHARS + 8];
                quote_token(&t, q, sizeof q);
                return sc_fail(&s, BG_ERR_PARSE, "label %d: '%s' is not an integer", (int)v + 1, q);
            }
        }
        if (!sc_at_end(&s))
            return sc_fail(&s, BG_ERR_PARSE, "more than the %d labels the header declares",
                           (int)nv);
        return BG_OK;
    }
    for (int32_t v = 0; v < nv; v++)
        labels[v] = -1;
    while (sc_token(&s, 1, &t)) {
        int64_t v = 0;
        s.p = t.p;
        if ((st = sc_int(&s, 1, &v, "a 0-based vertex index")) != BG_OK)
            return st;
        if (v < 0 || v >= nv)
            return sc_fail(&s, BG_ERR_INVALID, "vertex index %lld outside 0..%d", (long long)v,
                           (int)nv - 1);
        labels[v] = 1;
    }
    return BG_OK;
}

bg_status bg_positions_read(const char *path, int32_t nv, int dim, double *out, bg_error_t *err)
{
    char *text = NULL;
    size_t length = 0;
    bg_status st = bg_file_read_all(path, BG_MESH_FILE_MAX_BYTES, &text, &length, err);
    if (st == BG_OK)
        st = bg_positions_parse(text, length, path, nv, dim, out, err);
    free(text);
    return st;
}

bg_status bg_selection_read(const char *path, int32_t nv, int32_t *labels, bg_error_t *err)
{
    char *text = NULL;
    size_t length = 0;
    bg_status st = bg_file_read_all(path, BG_MESH_FILE_MAX_BYTES, &text, &length, err);
    if (st == BG_OK)
        st = bg_selection_parse(text, length, path, nv, labels, err);
    free(text);
    return st;
}
