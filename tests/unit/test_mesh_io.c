/*
 * Tests of bg_mesh_io: round trips through every writer and reader, the
 * hand-written fixtures in tests/fixtures/mesh, the public meshes the
 * build makes, malformed input (with the messages it must produce) and a seeded
 * mutation fuzz loop. Parsers are always fed an exact-length heap copy with
 * no NUL after it, so ASan catches any read past `length`.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bg_error.h"
#include "bg_mesh.h"
#include "bg_mesh_io.h"

#define FIXTURES BG_SOURCE_DIR "/tests/fixtures/mesh/"
#define MESHES BG_MESH_DIR "/"

/* Seed of the fuzz loop's xorshift generator (logged by the test). */
#ifndef FUZZ_SEED
#define FUZZ_SEED 0x9e3779b97f4a7c15ULL
#endif
/* Mutated parses per seed text. */
#ifndef FUZZ_ROUNDS
#define FUZZ_ROUNDS 1500
#endif
/* A file declaring 40 million vertices must be refused by checking the
 * declared counts against the input's length, not by reading or allocating
 * first: a generous bound that also holds under ASan+UBSan in Debug. */
#define FAIL_FAST_MAX_SECONDS 1.0
/* Fake declared count: far beyond the input, below the vertex cap. */
#define LYING_COUNT 40000000

static char tmpdir[64];

/* ---- helpers ---- */

static int setup_tmpdir(void **state)
{
    (void)state;
    strcpy(tmpdir, "/tmp/bg_mesh_io_XXXXXX");
    return mkdtemp(tmpdir) ? 0 : -1;
}

static int remove_tmpdir(void **state)
{
    (void)state;
    DIR *d = opendir(tmpdir);
    if (!d)
        return -1;
    struct dirent *entry;
    char path[512];
    while ((entry = readdir(d)) != NULL) {
        if (strcmp(entry->d_name, ".") == 0 || strcmp(entry->d_name, "..") == 0)
            continue;
        snprintf(path, sizeof path, "%s/%s", tmpdir, entry->d_name);
        unlink(path);
    }
    closedir(d);
    return rmdir(tmpdir);
}

static void tmp_path(char *buf, size_t size, const char *file)
{
    snprintf(buf, size, "%s/%s", tmpdir, file);
}

/* An exact-length copy without a terminating NUL. */
static char *dup_exact(const char *text, size_t length)
{
    char *p = malloc(length ? length : 1);
    assert_non_null(p);
    memcpy(p, text, length);
    return p;
}

static bg_status parse_exact(bg_mesh_format format, const char *text, size_t length,
                             const char *name, bg_mesh_t **out, bg_error_t *err)
{
    char *copy = dup_exact(text, length);
    bg_status st = bg_mesh_parse(format, copy, length, name, out, err);
    free(copy);
    return st;
}

static char *slurp(const char *path, size_t *length)
{
    char *text = NULL;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = bg_file_read_all(path, BG_MESH_FILE_MAX_BYTES, &text, length, &err);
    if (st != BG_OK)
        fail_msg("%s", err.message);
    return text;
}

static bg_mesh_t *read_ok(const char *path, bg_mesh_format *format)
{
    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_read(path, &m, format, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_non_null(m);
    return m;
}

/* Asserts that parsing fails with `status` (0 = any error) and a message
 * holding every given substring (NULL-terminated list). */
static void expect_error(bg_mesh_format format, const char *text, bg_status status, ...)
{
    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = parse_exact(format, text, strlen(text), "bad", &m, &err);
    if (st == BG_OK)
        fail_msg("parse of %s text succeeded; expected an error", bg_mesh_format_name(format));
    assert_null(m);
    assert_int_equal(err.status, st);
    if (status != BG_OK && st != status)
        fail_msg("status %d (%s), expected %d: %s", st, err.message, status, err.message);
    va_list ap;
    va_start(ap, status);
    for (const char *want = va_arg(ap, const char *); want; want = va_arg(ap, const char *))
        if (!strstr(err.message, want))
            fail_msg("message \"%s\" lacks \"%s\"", err.message, want);
    va_end(ap);
}

static void assert_same_elements(const bg_mesh_t *a, const bg_mesh_t *b)
{
    assert_int_equal(a->ne, b->ne);
    assert_int_equal(a->nodes_per_element, b->nodes_per_element);
    assert_memory_equal(a->elements, b->elements,
                        (size_t)a->ne * (size_t)a->nodes_per_element * sizeof *a->elements);
}

/* Same counts, connectivity and bit-identical coordinates (z of a surface
 * read back from a planar original must be exactly 0). */
static void assert_same_mesh(const bg_mesh_t *a, const bg_mesh_t *b, int vref, int eref)
{
    assert_int_equal(a->nv, b->nv);
    assert_same_elements(a, b);
    for (int32_t v = 0; v < a->nv; v++)
        for (int c = 0; c < 3; c++) {
            double p = c < a->dim ? a->x[(size_t)v * a->dim + c] : 0.0;
            double q = c < b->dim ? b->x[(size_t)v * b->dim + c] : 0.0;
            if (memcmp(&p, &q, sizeof p) != 0)
                fail_msg("vertex %d coordinate %d: %.17g != %.17g", (int)v, c, p, q);
        }
    if (vref)
        assert_memory_equal(a->vertex_ref, b->vertex_ref, (size_t)a->nv * sizeof *a->vertex_ref);
    if (eref)
        assert_memory_equal(a->element_ref, b->element_ref, (size_t)a->ne * sizeof *a->element_ref);
}

static bg_mesh_t *make_box(void)
{
    const int32_t cells[3] = {3, 2, 2};
    const double origin[3] = {0.1, -0.2, 0.3}, size[3] = {1.1, 0.7, 1.3};
    bg_mesh_t *m = NULL;
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &m, NULL), BG_OK);
    for (int32_t v = 0; v < m->nv; v++)
        m->vertex_ref[v] = v % 5;
    /* Runs of equal refs with 0 among them, so Gmsh 4.1 needs several blocks. */
    for (int32_t e = 0; e < m->ne; e++)
        m->element_ref[e] = (e / 7) % 4 - 1;
    return m;
}

static bg_mesh_t *make_rectangle(void)
{
    const int32_t cells[2] = {4, 3};
    const double origin[2] = {-0.3, 0.7}, size[2] = {2.2, 1.9};
    bg_mesh_t *m = NULL;
    assert_int_equal(bg_mesh_generate_rectangle(cells, origin, size, &m, NULL), BG_OK);
    for (int32_t v = 0; v < m->nv; v++)
        m->vertex_ref[v] = v % 3;
    for (int32_t e = 0; e < m->ne; e++)
        m->element_ref[e] = e % 2 + 4;
    return m;
}

static void write_ok(const bg_mesh_t *m, bg_mesh_format format, const char *path)
{
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_write(m, m->x, format, path, &err) != BG_OK)
        fail_msg("%s", err.message);
}

/* ---- round trips ---- */

static void test_roundtrip_box(void **state)
{
    (void)state;
    bg_mesh_t *box = make_box();
    static const struct {
        bg_mesh_format format;
        const char *file;
        int vref, eref;
    } cases[] = {
        {BG_FORMAT_MEDIT, "box.mesh", 1, 1},   {BG_FORMAT_TETGEN, "box.node", 1, 1},
        {BG_FORMAT_GMSH22, "box22.msh", 0, 1}, {BG_FORMAT_GMSH41, "box41.msh", 0, 1},
        {BG_FORMAT_VTU, "box.vtu", 0, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char path[256];
        bg_mesh_format found = BG_FORMAT_UNKNOWN;
        tmp_path(path, sizeof path, cases[i].file);
        write_ok(box, cases[i].format, path);
        bg_mesh_t *back = read_ok(path, &found);
        assert_int_equal(found, cases[i].format);
        assert_int_equal(bg_mesh_kind_of(back), BG_MESH_VOLUME);
        assert_same_mesh(box, back, cases[i].vref, cases[i].eref);
        bg_mesh_destroy(&back);
    }
    /* TetGen reads from either path. */
    char ele[256];
    tmp_path(ele, sizeof ele, "box.ele");
    bg_mesh_t *back = read_ok(ele, NULL);
    assert_same_mesh(box, back, 1, 1);
    bg_mesh_destroy(&back);
    /* Tetrahedra have no OFF or OBJ form. */
    char off[256];
    bg_error_t err = BG_ERROR_INIT;
    tmp_path(off, sizeof off, "box.off");
    assert_int_equal(bg_mesh_write(box, box->x, BG_FORMAT_OFF, off, &err), BG_ERR_UNSUPPORTED);
    bg_mesh_destroy(&box);
}

static void test_roundtrip_rectangle(void **state)
{
    (void)state;
    bg_mesh_t *rect = make_rectangle();
    static const struct {
        bg_mesh_format format;
        const char *file;
        int planar; /* read back planar; else a z = 0 surface */
        int vref, eref;
    } cases[] = {
        {BG_FORMAT_MEDIT, "rect.mesh", 1, 1, 1},   {BG_FORMAT_TETGEN, "rect.node", 1, 1, 1},
        {BG_FORMAT_OFF, "rect.off", 0, 0, 0},      {BG_FORMAT_OBJ, "rect.obj", 0, 0, 0},
        {BG_FORMAT_GMSH22, "rect22.msh", 0, 0, 1}, {BG_FORMAT_GMSH41, "rect41.msh", 0, 0, 1},
        {BG_FORMAT_VTU, "rect.vtu", 0, 0, 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char path[256];
        tmp_path(path, sizeof path, cases[i].file);
        write_ok(rect, cases[i].format, path);
        bg_mesh_t *back = read_ok(path, NULL);
        assert_same_mesh(rect, back, cases[i].vref, cases[i].eref);
        if (cases[i].planar) {
            assert_int_equal(bg_mesh_kind_of(back), BG_MESH_PLANAR);
        } else {
            bg_mesh_t *planar = NULL;
            assert_int_equal(bg_mesh_kind_of(back), BG_MESH_SURFACE);
            assert_int_equal(bg_mesh_to_planar(back, &planar, NULL), BG_OK);
            assert_int_equal(bg_mesh_kind_of(planar), BG_MESH_PLANAR);
            assert_same_mesh(rect, planar, cases[i].vref, cases[i].eref);
            bg_mesh_destroy(&planar);
        }
        bg_mesh_destroy(&back);
    }
    bg_mesh_destroy(&rect);
}

/* A curved triangle surface (z != 0) through the surface-capable formats. */
static void test_roundtrip_surface(void **state)
{
    (void)state;
    bg_mesh_t *rect = make_rectangle(), *surf = NULL;
    assert_int_equal(bg_mesh_new(BG_MESH_SURFACE, rect->nv, rect->ne, &surf, NULL), BG_OK);
    for (int32_t v = 0; v < rect->nv; v++) {
        double x = rect->x[2 * v], y = rect->x[2 * v + 1];
        surf->x[3 * v] = x;
        surf->x[3 * v + 1] = y;
        surf->x[3 * v + 2] = 0.1 * x * x - 0.3 * y + 1.0 / 3.0;
        surf->vertex_ref[v] = rect->vertex_ref[v];
    }
    memcpy(surf->elements, rect->elements, (size_t)rect->ne * 3 * sizeof *rect->elements);
    memcpy(surf->element_ref, rect->element_ref, (size_t)rect->ne * sizeof *rect->element_ref);
    const bg_mesh_format formats[] = {BG_FORMAT_MEDIT,  BG_FORMAT_OFF,    BG_FORMAT_OBJ,
                                      BG_FORMAT_GMSH22, BG_FORMAT_GMSH41, BG_FORMAT_VTU};
    for (size_t i = 0; i < sizeof formats / sizeof formats[0]; i++) {
        char path[256], file[32];
        snprintf(file, sizeof file, "surf%zu.%s", i, bg_mesh_format_extension(formats[i]));
        tmp_path(path, sizeof path, file);
        write_ok(surf, formats[i], path);
        bg_mesh_t *back = read_ok(path, NULL);
        assert_int_equal(bg_mesh_kind_of(back), BG_MESH_SURFACE);
        assert_same_mesh(surf, back, formats[i] == BG_FORMAT_MEDIT, 0);
        bg_error_t err = BG_ERROR_INIT;
        bg_mesh_t *planar = NULL;
        assert_int_equal(bg_mesh_to_planar(back, &planar, &err), BG_ERR_INVALID);
        assert_null(planar);
        assert_non_null(strstr(err.message, "off the plane"));
        bg_mesh_destroy(&back);
    }
    bg_mesh_destroy(&surf);
    bg_mesh_destroy(&rect);
}

static void test_vtu_data_arrays(void **state)
{
    (void)state;
    bg_mesh_t *box = make_box();
    double *pd = calloc((size_t)box->nv * 3, sizeof *pd), *cd = calloc((size_t)box->ne, sizeof *cd);
    assert_non_null(pd);
    assert_non_null(cd);
    for (int32_t v = 0; v < box->nv; v++)
        pd[3 * v + 1] = 0.5 * v;
    for (int32_t e = 0; e < box->ne; e++)
        cd[e] = bg_mesh_element_measure(box, box->x, e);
    const bg_vtu_array_t points[] = {{"displacement", 3, pd}}, cells[] = {{"volume<&>", 1, cd}};
    char path[256];
    tmp_path(path, sizeof path, "data.vtu");
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_mesh_write_vtu(box, box->x, points, 1, cells, 1, path, &err), BG_OK);
    size_t length = 0;
    char *text = slurp(path, &length);
    assert_non_null(strstr(text, "<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" "
                                 "byte_order=\"LittleEndian\">"));
    assert_non_null(strstr(text, "Name=\"displacement\" NumberOfComponents=\"3\""));
    assert_non_null(strstr(text, "Name=\"volume&lt;&amp;&gt;\" NumberOfComponents=\"1\""));
    assert_non_null(strstr(text, "<PointData>"));
    assert_non_null(strstr(text, "<CellData>"));
    assert_non_null(strstr(text, "Name=\"types\""));
    bg_mesh_t *back = NULL;
    assert_int_equal(parse_exact(BG_FORMAT_VTU, text, length, path, &back, &err), BG_OK);
    assert_same_mesh(box, back, 0, 0);
    bg_mesh_destroy(&back);
    free(text);
    /* Non-finite data cannot be read by VTK's ASCII reader: refused. */
    pd[4] = NAN;
    bg_error_clear(&err);
    assert_int_equal(bg_mesh_write_vtu(box, box->x, points, 1, NULL, 0, path, &err),
                     BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "tuple 1"));
    free(pd);
    free(cd);
    bg_mesh_destroy(&box);
}

/* ---- fixtures ---- */

static const int32_t TWO_TETS[8] = {0, 1, 2, 3, 1, 2, 3, 4};
static const double TWO_TETS_X[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1};

static void assert_two_tets(const bg_mesh_t *m, const int32_t *order, const int32_t *eref)
{
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_VOLUME);
    assert_int_equal(m->nv, 5);
    assert_int_equal(m->ne, 2);
    /* order[i]: the file position of the canonical vertex i. */
    for (int i = 0; i < 5; i++)
        for (int c = 0; c < 3; c++)
            assert_true(m->x[3 * order[i] + c] == TWO_TETS_X[3 * i + c]);
    for (int i = 0; i < 8; i++)
        assert_int_equal(m->elements[i], order[TWO_TETS[i]]);
    if (eref) {
        assert_int_equal(m->element_ref[0], eref[0]);
        assert_int_equal(m->element_ref[1], eref[1]);
    }
}

static const int32_t IDENTITY[5] = {0, 1, 2, 3, 4};

static void test_fixture_medit(void **state)
{
    (void)state;
    const int32_t eref[2] = {10, 20};
    bg_mesh_t *m = read_ok(FIXTURES "two-tets.mesh", NULL);
    assert_two_tets(m, IDENTITY, eref);
    for (int v = 0; v < 5; v++)
        assert_int_equal(m->vertex_ref[v], v + 1);
    bg_mesh_destroy(&m);

    m = read_ok(FIXTURES "square.mesh", NULL);
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_PLANAR);
    assert_int_equal(m->nv, 4);
    assert_int_equal(m->ne, 2);
    const int32_t tris[6] = {0, 1, 2, 0, 2, 3};
    assert_memory_equal(m->elements, tris, sizeof tris);
    assert_int_equal(m->element_ref[1], 2);
    assert_true(m->x[4] == 1.0 && m->x[5] == 1.0);
    bg_mesh_destroy(&m);
}

static void test_fixture_off_obj(void **state)
{
    (void)state;
    const int32_t off_tris[15] = {3, 2, 1, 3, 1, 0, 0, 1, 4, 1, 2, 4, 2, 3, 4};
    bg_mesh_t *m = read_ok(FIXTURES "pyramid.off", NULL);
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_SURFACE);
    assert_int_equal(m->nv, 5);
    assert_int_equal(m->ne, 5);
    assert_memory_equal(m->elements, off_tris, sizeof off_tris);
    assert_true(m->x[12] == 0.5 && m->x[14] == 1.0);
    bg_mesh_destroy(&m);

    const int32_t obj_tris[18] = {3, 2, 1, 3, 1, 0, 0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4};
    m = read_ok(FIXTURES "pyramid.obj", NULL);
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_SURFACE);
    assert_int_equal(m->nv, 5);
    assert_int_equal(m->ne, 6);
    assert_memory_equal(m->elements, obj_tris, sizeof obj_tris);
    bg_mesh_destroy(&m);
}

static void test_fixture_gmsh(void **state)
{
    (void)state;
    const int32_t eref[2] = {7, 8};
    bg_mesh_format found = BG_FORMAT_UNKNOWN;
    /* 2.2: vertex 4 (1,1,1) has tag 50 and comes before tag 40 in the file. */
    const int32_t order22[5] = {0, 1, 2, 4, 3};
    bg_mesh_t *m = read_ok(FIXTURES "two-tets-22.msh", &found);
    assert_int_equal(found, BG_FORMAT_GMSH22);
    assert_two_tets(m, order22, eref);
    bg_mesh_destroy(&m);
    /* 4.1: tags 3 7 99 42 5 in file order; physical tags from $Entities. */
    const int32_t order41[5] = {0, 1, 2, 4, 3};
    m = read_ok(FIXTURES "two-tets-41.msh", &found);
    assert_int_equal(found, BG_FORMAT_GMSH41);
    assert_two_tets(m, order41, eref);
    bg_mesh_destroy(&m);
}

static void test_fixture_tetgen(void **state)
{
    (void)state;
    const int32_t eref[2] = {10, 20};
    bg_mesh_format found = BG_FORMAT_UNKNOWN;
    bg_mesh_t *m = read_ok(FIXTURES "two-tets-0.node", &found);
    assert_int_equal(found, BG_FORMAT_TETGEN);
    assert_two_tets(m, IDENTITY, eref);
    assert_int_equal(m->vertex_ref[4], 5);
    bg_mesh_destroy(&m);
    m = read_ok(FIXTURES "two-tets-1.ele", NULL);
    assert_two_tets(m, IDENTITY, NULL);
    bg_mesh_destroy(&m);
}

/* ---- the public meshes the build makes (cmake/Meshes.cmake): missing files fail ---- */

static double seconds_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Edges of a triangle list as (low, high) keys with the count of triangles
 * using each and the sum of their orientations (+1 along low->high, -1
 * against), sorted; returns the number of distinct edges. */
typedef struct edge_use {
    int64_t key;
    int uses, direction;
} edge_use_t;

static int compare_edges(const void *a, const void *b)
{
    const int64_t x = ((const edge_use_t *)a)->key, y = ((const edge_use_t *)b)->key;
    return (x > y) - (x < y);
}

static int32_t count_edges(const int32_t *tris, int32_t nt, edge_use_t **out)
{
    edge_use_t *e = malloc(3 * (size_t)nt * sizeof *e);
    assert_non_null(e);
    for (int32_t t = 0; t < nt; t++)
        for (int k = 0; k < 3; k++) {
            const int32_t a = tris[3 * t + k], b = tris[3 * t + (k + 1) % 3];
            e[3 * t + k].key = (int64_t)(a < b ? a : b) << 32 | (a < b ? b : a);
            e[3 * t + k].uses = 1;
            e[3 * t + k].direction = a < b ? 1 : -1;
        }
    qsort(e, 3 * (size_t)nt, sizeof *e, compare_edges);
    int32_t n = 0;
    for (int32_t i = 0; i < 3 * nt; i++) {
        if (n > 0 && e[n - 1].key == e[i].key) {
            e[n - 1].uses++;
            e[n - 1].direction += e[i].direction;
        } else {
            e[n++] = e[i];
        }
    }
    *out = e;
    return n;
}

/* A tetrahedron's face: its vertices sorted (the key) and in outward order. */
typedef struct tet_face {
    int32_t sorted[3], face[3];
} tet_face_t;

/* Any total order groups equal keys: bytewise is enough. */
static int compare_faces(const void *a, const void *b)
{
    return memcmp(((const tet_face_t *)a)->sorted, ((const tet_face_t *)b)->sorted,
                  sizeof((const tet_face_t *)a)->sorted);
}

/* Faces of a tetrahedral mesh used by one tetrahedron only, outward (the
 * mesh is positively oriented after reading), into a new array. */
static int32_t boundary_faces(const bg_mesh_t *m, int32_t **out)
{
    static const int local[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    tet_face_t *f = malloc(4 * (size_t)m->ne * sizeof *f);
    assert_non_null(f);
    for (int32_t e = 0; e < m->ne; e++)
        for (int k = 0; k < 4; k++) {
            tet_face_t *x = &f[4 * e + k];
            for (int i = 0; i < 3; i++)
                x->face[i] = x->sorted[i] = m->elements[4 * (size_t)e + local[k][i]];
            for (int i = 0; i < 3; i++) /* three-element sort */
                for (int j = i + 1; j < 3; j++)
                    if (x->sorted[j] < x->sorted[i]) {
                        int32_t t = x->sorted[i];
                        x->sorted[i] = x->sorted[j];
                        x->sorted[j] = t;
                    }
        }
    qsort(f, 4 * (size_t)m->ne, sizeof *f, compare_faces);
    int32_t *b = malloc(12 * (size_t)m->ne * sizeof *b), n = 0;
    assert_non_null(b);
    for (int32_t i = 0; i < 4 * m->ne;) {
        int32_t j = i + 1;
        while (j < 4 * m->ne && memcmp(f[j].sorted, f[i].sorted, sizeof f[i].sorted) == 0)
            j++;
        assert_true(j - i <= 2); /* a face is shared by at most two tetrahedra */
        if (j - i == 1) {
            memcpy(b + 3 * (size_t)n, f[i].face, sizeof f[i].face);
            n++;
        }
        i = j;
    }
    free(f);
    *out = b;
    return n;
}

/* Volume enclosed by outward triangles (divergence theorem, origin-based). */
static double enclosed_volume(const double *x, const int32_t *tris, int32_t nt)
{
    double v = 0.0;
    for (int32_t t = 0; t < nt; t++) {
        const double *a = x + 3 * (size_t)tris[3 * t], *b = x + 3 * (size_t)tris[3 * t + 1],
                     *c = x + 3 * (size_t)tris[3 * t + 2];
        v += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
              a[2] * (b[0] * c[1] - b[1] * c[0])) /
             6.0;
    }
    return v;
}

/* Euler characteristic V - E + F of a triangle surface, counting only the
 * vertices its triangles use; boundary edges (one triangle) into *open. A
 * closed surface or a disk must use every edge once or twice, consistently
 * oriented (the two uses in opposite directions). */
static int32_t surface_euler(const int32_t *tris, int32_t nt, int32_t nv, int32_t *open)
{
    edge_use_t *e = NULL;
    const int32_t ne = count_edges(tris, nt, &e);
    char *used = calloc((size_t)nv, 1);
    assert_non_null(used);
    int32_t vertices = 0;
    for (int32_t i = 0; i < 3 * nt; i++)
        if (!used[tris[i]]) {
            used[tris[i]] = 1;
            vertices++;
        }
    *open = 0;
    for (int32_t i = 0; i < ne; i++) {
        assert_true(e[i].uses == 1 || e[i].uses == 2);
        if (e[i].uses == 2)
            assert_int_equal(e[i].direction, 0);
        *open += e[i].uses == 1;
    }
    free(used);
    free(e);
    return vertices - ne + nt;
}

/* The tetrahedral bunnies: conforming (every inner face shared by exactly
 * two tetrahedra), their boundary a closed consistently oriented sphere
 * (Euler characteristic 2), and the sum of the tetrahedra's volumes equal
 * to the volume the boundary encloses, an independent computation that any
 * overlap, gap or flipped element would break. */
static void check_public_volume(const char *file, int32_t min_elements, int32_t max_elements)
{
    size_t length = 0;
    char *text = slurp(file, &length);
    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    double t0 = seconds_now();
    if (parse_exact(BG_FORMAT_MEDIT, text, length, file, &m, &err) != BG_OK)
        fail_msg("%s", err.message);
    print_message("%s: %d vertices, %d tetrahedra, parsed in %.1f ms\n", file, (int)m->nv,
                  (int)m->ne, 1e3 * (seconds_now() - t0));
    free(text);
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_VOLUME);
    assert_true(m->ne >= min_elements && m->ne <= max_elements);
    double total = 0.0;
    for (int32_t e = 0; e < m->ne; e++) {
        const double v = bg_mesh_element_measure(m, m->x, e);
        assert_true(v > 0.0);
        total += v;
    }
    int32_t *faces = NULL, open = 0;
    const int32_t nf = boundary_faces(m, &faces);
    assert_int_equal(surface_euler(faces, nf, m->nv, &open), 2);
    assert_int_equal(open, 0);
    /* Both sums add ~1e5 terms of one sign: relative round-off ~1e-12. */
    assert_true(fabs(enclosed_volume(m->x, faces, nf) - total) <= 1e-9 * total);
    free(faces);
    bg_mesh_destroy(&m);
}

static void test_public_meshes(void **state)
{
    (void)state;
    check_public_volume(MESHES "bunny.mesh", 20000, 45000);
    check_public_volume(MESHES "bunny-fine.mesh", 150000, 300000);

    /* The parameterization surface is a disk: V - E + F = 1, one boundary
     * loop (as many boundary edges as boundary vertices, checked by the
     * parameterization's own set-up elsewhere). */
    bg_mesh_t *m = read_ok(MESHES "lion-head.off", NULL);
    int32_t open = 0;
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_SURFACE);
    assert_int_equal(surface_euler(m->elements, m->ne, m->nv, &open), 1);
    assert_true(open > 0);
    bg_mesh_destroy(&m);

    /* The surface-editing armadillo is closed and of genus 0. */
    m = read_ok(MESHES "armadillo.off", NULL);
    assert_int_equal(bg_mesh_kind_of(m), BG_MESH_SURFACE);
    assert_int_equal(surface_euler(m->elements, m->ne, m->nv, &open), 2);
    assert_int_equal(open, 0);
    bg_mesh_destroy(&m);
}

/* ---- bad input ---- */

#define MEDIT_HEAD                                                                                 \
    "MeshVersionFormatted 1\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\n"

static void test_bad_medit(void **state)
{
    (void)state;
    expect_error(BG_FORMAT_MEDIT, MEDIT_HEAD "Tetrahedra\n1\n1 2 3 9 0\nEnd\n", BG_ERR_INVALID,
                 "bad:11:", "tetrahedron 1 refers to vertex 9", NULL);
    expect_error(BG_FORMAT_MEDIT, MEDIT_HEAD "Tetrahedra\n1\n1 2 3\nEnd\n", BG_ERR_PARSE,
                 "bad:11:", "expected 4 vertex indices in tetrahedron 1", NULL);
    expect_error(BG_FORMAT_MEDIT, MEDIT_HEAD "Tetrahedra\n1\n1 2 3 4 0 x\nEnd\n", BG_ERR_PARSE,
                 "bad:11:", "unexpected 'x' after tetrahedron 1", NULL);
    expect_error(BG_FORMAT_MEDIT,
                 "MeshVersionFormatted 1\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\nnan 1 0 "
                 "0\n0 0 1 0\nTetrahedra\n1\n1 2 3 4 0\nEnd\n",
                 BG_ERR_INVALID, "bad:7:", "vertex 3", NULL);
    expect_error(BG_FORMAT_MEDIT,
                 "MeshVersionFormatted 1\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 "
                 "0\n1 1 0 0\nTetrahedra\n1\n1 2 3 4 0\nEnd\n",
                 BG_ERR_INVALID, "bad: element 1", "degenerate", NULL);
    expect_error(BG_FORMAT_MEDIT, MEDIT_HEAD "Tetrahedra\n1\n1 2 3 4 0\n", BG_ERR_PARSE,
                 "missing End", NULL);
    expect_error(BG_FORMAT_MEDIT, MEDIT_HEAD "Tetrahedra\n1\n1 2 3 4 0\nBogus 3\nEnd\n",
                 BG_ERR_PARSE, "bad:12:", "unknown MEDIT keyword 'Bogus'", NULL);
    expect_error(BG_FORMAT_MEDIT, "MeshVersionFormatted 1\nDimension 3\nVertices\n-4\n",
                 BG_ERR_PARSE, "negative", NULL);
}

static void test_bad_counts_fail_fast(void **state)
{
    (void)state;
    char text[256];
    const double t0 = seconds_now();
    snprintf(text, sizeof text, "MeshVersionFormatted 1\nDimension 3\nVertices\n%d\n0 0 0 0\n",
             LYING_COUNT);
    expect_error(BG_FORMAT_MEDIT, text, BG_ERR_PARSE, "bad:4:", "truncated", NULL);
    expect_error(BG_FORMAT_MEDIT, "MeshVersionFormatted 1\nDimension 3\nVertices\n1000000000\n",
                 BG_ERR_LIMIT, "exceed the limit", NULL);
    snprintf(text, sizeof text, "OFF\n%d 1 0\n0 0 0\n", LYING_COUNT);
    expect_error(BG_FORMAT_OFF, text, BG_ERR_PARSE, "bad:2:", NULL);
    snprintf(text, sizeof text, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n1 0 0 0\n",
             LYING_COUNT);
    expect_error(BG_FORMAT_GMSH22, text, BG_ERR_PARSE, "bad:5:", NULL);
    snprintf(text, sizeof text, "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 %d 1 %d\n",
             LYING_COUNT, LYING_COUNT);
    expect_error(BG_FORMAT_GMSH41, text, BG_ERR_PARSE, "bad:5:", NULL);
    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    snprintf(text, sizeof text, "%d 3 0 0\n1 0 0 0\n", LYING_COUNT);
    assert_int_equal(
        bg_mesh_parse_tetgen(text, strlen(text), "1 4 0\n1 1 1 1 1\n", 16, "t", &m, &err),
        BG_ERR_PARSE);
    assert_non_null(strstr(err.message, "t.node:1:"));
    /* No allocation of LYING_COUNT records happened: all of this is instant. */
    assert_true(seconds_now() - t0 < FAIL_FAST_MAX_SECONDS);
}

static void test_bad_other_formats(void **state)
{
    (void)state;
    expect_error(BG_FORMAT_OFF, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", BG_ERR_INVALID,
                 "bad:6:", "face 0 refers to vertex 7", NULL);
    expect_error(BG_FORMAT_OFF, "OFF\n3 1 0\n0 0 0\n1 0 0 junk\n0 1 0\n3 0 1 2\n", BG_ERR_PARSE,
                 "bad:4:", "unexpected 'junk' after vertex 1", NULL);
    expect_error(BG_FORMAT_OFF, "COFF\n3 1 0\n", BG_ERR_UNSUPPORTED, "COFF", NULL);
    expect_error(BG_FORMAT_OBJ, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n", BG_ERR_INVALID,
                 "bad:5:", "face 2 refers to vertex 4", NULL);
    expect_error(BG_FORMAT_OBJ, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n", BG_ERR_INVALID,
                 "bad:4:", "face 1", NULL);
    expect_error(BG_FORMAT_OBJ, "v 0 0 0\nv 1 inf 0\n", BG_ERR_INVALID, "bad:2:", "vertex 2", NULL);
    expect_error(BG_FORMAT_OBJ, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/x 2 3\n", BG_ERR_PARSE,
                 "bad:4:", "'1/x'", NULL);
    expect_error(BG_FORMAT_OBJ, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 1\n", BG_ERR_INVALID,
                 "bad: element 2 repeats vertex 1", NULL);
    const char *gmsh = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 "
                       "0\n4 0 0 1\n$EndNodes\n$Elements\n3\n1 15 2 0 1 1\n2 1 2 0 1 1 2\n3 4 2 0 "
                       "1 1 2 3 99\n$EndElements\n";
    expect_error(BG_FORMAT_GMSH22, gmsh, BG_ERR_INVALID, "bad:15:", "element 3 refers to node 99",
                 NULL);
    expect_error(BG_FORMAT_GMSH22, "$MeshFormat\n2.2 1 8\n$EndMeshFormat\n", BG_ERR_UNSUPPORTED,
                 "binary", NULL);
    expect_error(BG_FORMAT_GMSH41, "$MeshFormat\n4.0 0 8\n$EndMeshFormat\n", BG_ERR_UNSUPPORTED,
                 "4.0", NULL);

    bg_mesh_t *m = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const char *node = "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n";
    const char *ele = "3 4 0\n0 0 1 2 3\n1 0 1 2 3\n2 0 1 2 4\n";
    assert_int_equal(
        bg_mesh_parse_tetgen(node, strlen(node), ele, strlen(ele), "dir/t.node", &m, &err),
        BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "dir/t.ele:4: element 2 refers to vertex 4"));
    bg_error_clear(&err);
    const char *node_gap = "3 3 0 0\n1 0 0 0\n2 1 0 0\n4 0 1 0\n";
    assert_int_equal(
        bg_mesh_parse_tetgen(node_gap, strlen(node_gap), ele, strlen(ele), "u", &m, &err),
        BG_ERR_PARSE);
    assert_non_null(strstr(err.message, "u.node:4:"));
    assert_null(m);
}

/* Binary junk must give an error for every format, never a crash. */
static void test_garbage(void **state)
{
    (void)state;
    unsigned char junk[512];
    uint64_t x = FUZZ_SEED;
    for (size_t i = 0; i < sizeof junk; i++) {
        x ^= x << 13, x ^= x >> 7, x ^= x << 17;
        junk[i] = (unsigned char)x;
    }
    const bg_mesh_format formats[] = {BG_FORMAT_MEDIT,  BG_FORMAT_OFF,    BG_FORMAT_OBJ,
                                      BG_FORMAT_GMSH22, BG_FORMAT_GMSH41, BG_FORMAT_VTU};
    for (size_t i = 0; i < sizeof formats / sizeof formats[0]; i++) {
        bg_mesh_t *m = NULL;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_not_equal(
            parse_exact(formats[i], (const char *)junk, sizeof junk, "junk", &m, &err), BG_OK);
        assert_null(m);
        assert_true(strncmp(err.message, "junk", 4) == 0);
    }
}

/* Texts written by our writers, for truncation and fuzzing. */
typedef struct sample {
    bg_mesh_format format;
    char *text, *ele; /* ele: the TetGen .ele text */
    size_t length, ele_length;
} sample_t;

static void load_samples(sample_t *samples, size_t *n)
{
    const int32_t cells[3] = {1, 1, 1};
    const double origin[3] = {0, 0, 0}, size[3] = {1, 1, 1};
    bg_mesh_t *box = NULL, *rect = make_rectangle();
    assert_int_equal(bg_mesh_generate_box(cells, origin, size, &box, NULL), BG_OK);
    box->element_ref[2] = 3;
    const struct {
        bg_mesh_format format;
        const char *file;
        int use_box;
    } list[] = {
        {BG_FORMAT_MEDIT, "s.mesh", 1},   {BG_FORMAT_OFF, "s.off", 0},
        {BG_FORMAT_OBJ, "s.obj", 0},      {BG_FORMAT_GMSH22, "s22.msh", 1},
        {BG_FORMAT_GMSH41, "s41.msh", 1}, {BG_FORMAT_VTU, "s.vtu", 1},
        {BG_FORMAT_TETGEN, "s.node", 1},
    };
    *n = sizeof list / sizeof list[0];
    for (size_t i = 0; i < *n; i++) {
        char path[256];
        tmp_path(path, sizeof path, list[i].file);
        write_ok(list[i].use_box ? box : rect, list[i].format, path);
        samples[i].format = list[i].format;
        samples[i].text = slurp(path, &samples[i].length);
        samples[i].ele = NULL;
        if (list[i].format == BG_FORMAT_TETGEN) {
            tmp_path(path, sizeof path, "s.ele");
            samples[i].ele = slurp(path, &samples[i].ele_length);
        }
    }
    bg_mesh_destroy(&box);
    bg_mesh_destroy(&rect);
}

static void free_samples(sample_t *samples, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        free(samples[i].text);
        free(samples[i].ele);
    }
}

static bg_status parse_sample(const sample_t *s, const char *text, size_t length, bg_mesh_t **m,
                              bg_error_t *err)
{
    if (s->format != BG_FORMAT_TETGEN)
        return parse_exact(s->format, text, length, "sample", m, err);
    char *node = dup_exact(text, length), *ele = dup_exact(s->ele, s->ele_length);
    bg_status st = bg_mesh_parse_tetgen(node, length, ele, s->ele_length, "sample", m, err);
    free(node);
    free(ele);
    return st;
}

static void test_truncated(void **state)
{
    (void)state;
    sample_t samples[8];
    size_t n = 0;
    load_samples(samples, &n);
    const double cuts[] = {0.25, 0.5, 0.9};
    for (size_t i = 0; i < n; i++) {
        bg_mesh_t *m = NULL;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(parse_sample(&samples[i], samples[i].text, samples[i].length, &m, &err),
                         BG_OK);
        bg_mesh_destroy(&m);
        for (size_t c = 0; c < sizeof cuts / sizeof cuts[0]; c++) {
            /* OBJ declares no counts: a cut among the faces is a smaller valid
             * mesh, so only cuts inside the vertex list must fail. */
            if (samples[i].format == BG_FORMAT_OBJ && cuts[c] > 0.5)
                continue;
            size_t length = (size_t)(cuts[c] * (double)samples[i].length);
            bg_error_clear(&err);
            bg_status st = parse_sample(&samples[i], samples[i].text, length, &m, &err);
            if (st == BG_OK)
                fail_msg("%s cut at %.0f%% parsed", bg_mesh_format_name(samples[i].format),
                         100 * cuts[c]);
            assert_null(m);
            assert_true(err.message[0] != '\0');
        }
    }
    free_samples(samples, n);
}

static uint64_t xorshift(uint64_t *s)
{
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    return *s;
}

/* Bytes the mutator likes: they keep texts close to parseable. */
static const char FUZZ_BYTES[] = "0123456789-+.eE \n\t#$/vfnaNI";

static void test_fuzz(void **state)
{
    (void)state;
    sample_t samples[8];
    size_t n = 0;
    uint64_t seed = FUZZ_SEED;
    load_samples(samples, &n);
    print_message("fuzz seed 0x%llx, %d rounds per format\n", (unsigned long long)seed,
                  FUZZ_ROUNDS);
    long ok = 0, failed = 0;
    for (size_t i = 0; i < n; i++) {
        char *buf = malloc(samples[i].length);
        assert_non_null(buf);
        for (int round = 0; round < FUZZ_ROUNDS; round++) {
            size_t length = samples[i].length;
            memcpy(buf, samples[i].text, length);
            int flips = 1 + (int)(xorshift(&seed) % 4);
            for (int f = 0; f < flips; f++) {
                size_t at = (size_t)(xorshift(&seed) % length);
                uint64_t r = xorshift(&seed);
                buf[at] =
                    r % 3 == 0 ? (char)(r >> 8) : FUZZ_BYTES[(r >> 8) % (sizeof FUZZ_BYTES - 1)];
            }
            if (xorshift(&seed) % 4 == 0)
                length = (size_t)(xorshift(&seed) % length);
            bg_mesh_t *m = NULL;
            bg_error_t err = BG_ERROR_INIT;
            bg_status st = parse_sample(&samples[i], buf, length, &m, &err);
            if (st == BG_OK) {
                assert_non_null(m);
                assert_int_equal(bg_mesh_validate(m, "fuzz", NULL, &err), BG_OK);
                ok++;
            } else {
                assert_null(m);
                assert_int_equal(err.status, st);
                if (err.message[0] == '\0')
                    fail_msg("%s round %d: error %d without a message",
                             bg_mesh_format_name(samples[i].format), round, st);
                failed++;
            }
            bg_mesh_destroy(&m);
        }
        free(buf);
    }
    print_message("fuzz: %ld parsed, %ld rejected\n", ok, failed);
    assert_true(ok > 0 && failed > 0);
    free_samples(samples, n);
}

/* ---- positions, selections, files, formats ---- */

static void test_positions(void **state)
{
    (void)state;
    double p[6];
    bg_error_t err = BG_ERROR_INIT;
    const char *good = "# header\n1 2 3\n\n4 5 6.5\n";
    assert_int_equal(bg_positions_parse(good, strlen(good), "p", 2, 3, p, &err), BG_OK);
    assert_true(p[0] == 1.0 && p[5] == 6.5);
    const char *bad = "1 2 3\n4 nan 6\n";
    assert_int_equal(bg_positions_parse(bad, strlen(bad), "p", 2, 3, p, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "p:2: vertex 2"));
    bg_error_clear(&err);
    const char *short_line = "1 2 3\n4 5\n";
    assert_int_equal(bg_positions_parse(short_line, strlen(short_line), "p", 2, 3, p, &err),
                     BG_ERR_PARSE);
    assert_non_null(strstr(err.message, "p:2:"));
    bg_error_clear(&err);
    const char *planar = "1 2\n3 4\n5 6\n";
    assert_int_equal(bg_positions_parse(planar, strlen(planar), "p", 3, 2, p, &err), BG_OK);
    assert_true(p[4] == 5.0);
}

static void test_selection(void **state)
{
    (void)state;
    int32_t labels[5];
    bg_error_t err = BG_ERROR_INIT;
    const char *list = "# handles\n0 3\n4\n";
    assert_int_equal(bg_selection_parse(list, strlen(list), "s", 5, labels, &err), BG_OK);
    const int32_t want[5] = {1, -1, -1, 1, 1};
    assert_memory_equal(labels, want, sizeof want);
    const char *dmat = "1 5\n-1\n0\n2\n-1\n1\n";
    assert_int_equal(bg_selection_parse(dmat, strlen(dmat), "s", 5, labels, &err), BG_OK);
    const int32_t want2[5] = {-1, 0, 2, -1, 1};
    assert_memory_equal(labels, want2, sizeof want2);
    const char *wide_dmat = "3 5\n";
    assert_int_equal(bg_selection_parse(wide_dmat, strlen(wide_dmat), "s", 5, labels, &err),
                     BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "3 columns"));
    bg_error_clear(&err);
    const char *short_dmat = "1 5\n-1\n0\n";
    assert_int_equal(bg_selection_parse(short_dmat, strlen(short_dmat), "s", 5, labels, &err),
                     BG_ERR_PARSE);
    bg_error_clear(&err);
    const char *bad_index = "1 7\n";
    assert_int_equal(bg_selection_parse(bad_index, strlen(bad_index), "s", 5, labels, &err),
                     BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "s:1: vertex index 7"));
}

static void test_files_and_formats(void **state)
{
    (void)state;
    char *text = NULL;
    size_t length = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_file_read_all("/nonexistent/x.mesh", 100, &text, &length, &err), BG_ERR_IO);
    assert_non_null(strstr(err.message, "/nonexistent/x.mesh"));
    assert_non_null(strstr(err.message, "No such file"));
    assert_null(text);
    bg_error_clear(&err);
    assert_int_equal(bg_file_read_all(FIXTURES "two-tets.mesh", 10, &text, &length, &err),
                     BG_ERR_LIMIT);
    assert_null(text);
    bg_error_clear(&err);
    /* A pipe-like source of unknown size is read up to the cap as well. */
    assert_int_equal(bg_file_read_all("/dev/zero", 1000, &text, &length, &err), BG_ERR_LIMIT);
    assert_null(text);
    text = slurp(FIXTURES "square.mesh", &length);
    assert_true(length > 0 && text[length] == '\0');
    free(text);

    assert_int_equal(bg_mesh_format_from_path("a/b.MESH"), BG_FORMAT_MEDIT);
    assert_int_equal(bg_mesh_format_from_path("b.ele"), BG_FORMAT_TETGEN);
    assert_int_equal(bg_mesh_format_from_path("b.msh"), BG_FORMAT_GMSH41);
    assert_int_equal(bg_mesh_format_from_path("b.stl"), BG_FORMAT_UNKNOWN);
    assert_string_equal(bg_mesh_format_extension(BG_FORMAT_GMSH22), "msh");
    assert_string_equal(bg_mesh_format_name(BG_FORMAT_TETGEN), "TetGen");

    bg_mesh_t *m = NULL;
    bg_error_clear(&err);
    assert_int_equal(bg_mesh_read("x.stl", &m, NULL, &err), BG_ERR_INVALID);
    bg_error_clear(&err);
    assert_int_equal(bg_mesh_read(FIXTURES "absent.off", &m, NULL, &err), BG_ERR_IO);
    assert_null(m);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_roundtrip_box),
        cmocka_unit_test(test_roundtrip_rectangle),
        cmocka_unit_test(test_roundtrip_surface),
        cmocka_unit_test(test_vtu_data_arrays),
        cmocka_unit_test(test_fixture_medit),
        cmocka_unit_test(test_fixture_off_obj),
        cmocka_unit_test(test_fixture_gmsh),
        cmocka_unit_test(test_fixture_tetgen),
        cmocka_unit_test(test_public_meshes),
        cmocka_unit_test(test_bad_medit),
        cmocka_unit_test(test_bad_counts_fail_fast),
        cmocka_unit_test(test_bad_other_formats),
        cmocka_unit_test(test_garbage),
        cmocka_unit_test(test_truncated),
        cmocka_unit_test(test_fuzz),
        cmocka_unit_test(test_positions),
        cmocka_unit_test(test_selection),
        cmocka_unit_test(test_files_and_formats),
    };
    return cmocka_run_group_tests(tests, setup_tmpdir, remove_tmpdir);
}
