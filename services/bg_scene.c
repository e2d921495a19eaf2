#include "bg_scene.h"

#include "bg_file.h"
#include "bg_json.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* Field paths in messages ("handles[12].transform.rotate.axis") fit here. */
#define FIELD_MAX BG_JSON_PATH_MAX
/* The scene's name in messages when it was parsed from text. */
#define MEMORY_NAME "<memory>"
/* Default scene name for text scenes (there is no file stem). */
#define MEMORY_STEM "scene"
#define DEFAULT_DENSITY 1000.0
#define MAX_ITERATIONS_LIMIT 100000
/* Box selections are inclusive up to this fraction of the mesh extent, so a
 * face at x = 4 is selected by max = 4 despite rounding in the generator. */
#define SELECT_TOLERANCE 1e-9
/* Two handles may prescribe the same coordinate only if the values agree to
 * this fraction of the mesh extent (a shared edge of two fixed faces). */
#define AGREE_TOLERANCE 1e-9
/* Integers are carried as doubles by cJSON; beyond 2^53 they are not exact. */
#define MAX_EXACT_INTEGER 9007199254740992.0
#define PI_VALUE 3.14159265358979323846
#define DEGREES_PER_QUARTER 90.0
#define FULL_TURN_DEGREES 360.0
/* splitmix64 (Steele, Lea, Flood 2014) constants. */
#define SPLITMIX_GAMMA 0x9e3779b97f4a7c15ULL
#define SPLITMIX_MUL1 0xbf58476d1ce4e5b9ULL
#define SPLITMIX_MUL2 0x94d049bb133111ebULL
/* 53 random bits → a double in [0, 1). */
#define TWO_POW_MINUS_53 (1.0 / 9007199254740992.0)

static const char AXIS_NAMES[] = "xyz";
/* Caps and defaults of dynamic tasks. */
#define MAX_STEPS 10000000
#define DEFAULT_FRAMES 100
#define DEFAULT_MORPH_FRAMES 11

typedef struct parser {
    const char *file;        /* the scene as named in messages */
    char *dir;               /* base for relative paths: "" (cwd) or "dir/" */
    const char *search_path; /* ':'-separated folders for files not found beside the scene */
    int64_t max_vertices, max_elements; /* mesh size caps */
    double max_work;                    /* elements × (steps or frames), at most */
    int material_form;                  /* -1: none read; 0 {mu, lambda}, 1 {E, nu}, 2 {alpha, beta} */
    double material_a, material_b;      /* the form's two values, checked */
    int confined;                       /* files only inside the scene's folder */
    bg_error_t *err;
    bg_scene_t *scene;
    int dim;
    double lo[3], hi[3];
    double extent;             /* largest side of the bounding box */
    int32_t *owner;            /* nv*dim: index of the handle prescribing a coordinate, or -1 */
    uint8_t *flag;             /* nv: scratch marks for selections */
    const cJSON *morph_target; /* task.target, read once the mesh is known */
} parser_t;

/* A handle's selected vertices in increasing order, with the coordinates
 * (bit c = coordinate c) each one constrains. */
typedef struct selection {
    int32_t count;
    int32_t *vertices;
    uint8_t *mask;
} selection_t;

/* ------------------------------------------------------------------ errors */

static bg_status fail(parser_t *p, bg_status status, const char *field, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* Records "<file>: <field>: <message>" (or "<file>: <message>" without a
 * field), in bg_json's format. */
static bg_status fail(parser_t *p, bg_status status, const char *field, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    bg_status st = bg_json_vfail(p->err, status, p->file, field, fmt, ap);
    va_end(ap);
    return st;
}

/* Re-raises the error of a service call under the scene's name and field. */
static bg_status relay(parser_t *p, const char *field, const bg_error_t *inner)
{
    return fail(p, inner->status, field, "%s", inner->message);
}

/* Paths, type names and the typed readers come from bg_json, the code
 * the experiment configs share; these wrappers name the scene file. */
/* Field paths longer than FIELD_MAX end in this marker instead. */
#define TRUNCATED_MARK "..."

static void mark_if_truncated(char *out, int written)
{
    if (written >= FIELD_MAX)
        memcpy(out + FIELD_MAX - sizeof TRUNCATED_MARK, TRUNCATED_MARK, sizeof TRUNCATED_MARK);
}

static void field_key(char *out, const char *parent, const char *key)
{
    bg_json_path_key(out, parent, key);
}

static void field_index(char *out, const char *parent, int index)
{
    bg_json_path_index(out, parent, index);
}

static const char *json_type_name(const cJSON *item)
{
    return bg_json_type_name(item);
}

/* ------------------------------------------------------------ JSON access */

static bg_status expect_object(parser_t *p, const cJSON *item, const char *field)
{
    return bg_json_expect_object(item, p->file, field, p->err);
}

/* Rejects keys not in `allowed` (NULL-terminated) and repeated keys. */
static bg_status check_keys(parser_t *p, const cJSON *object, const char *field,
                            const char *const *allowed)
{
    return bg_json_check_keys(object, p->file, field, allowed, p->err);
}

static const cJSON *member(const cJSON *object, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(object, key);
}

static bg_status read_number(parser_t *p, const cJSON *item, const char *field, double *out)
{
    return bg_json_number(item, p->file, field, out, p->err);
}

/* An integer in [lo, hi], written without a fraction. */
static bg_status read_integer(parser_t *p, const cJSON *item, const char *field, double lo,
                              double hi, int64_t *out)
{
    return bg_json_integer(item, p->file, field, lo, hi, out, p->err);
}

static bg_status read_bool(parser_t *p, const cJSON *item, const char *field, int *out)
{
    return bg_json_bool(item, p->file, field, out, p->err);
}

static bg_status read_string(parser_t *p, const cJSON *item, const char *field, const char **out)
{
    return bg_json_string(item, p->file, field, out, p->err);
}

/* An array of exactly n finite numbers. */
static bg_status read_vector(parser_t *p, const cJSON *item, const char *field, int n, double *out)
{
    return bg_json_vector(item, p->file, field, n, out, p->err);
}

/* ------------------------------------------------------------------ paths */

/* The scene's directory with a trailing '/', or "" when it has none. */
static char *directory_of(const char *path)
{
    const char *slash = path ? strrchr(path, '/') : NULL;
    size_t n = slash ? (size_t)(slash - path) + 1 : 0;
    char *dir = malloc(n + 1);
    if (!dir)
        return NULL;
    memcpy(dir, path ? path : "", n);
    dir[n] = '\0';
    return dir;
}

/*
 * A path inside the scene: absolute as given, else relative to the scene's
 * directory. A relative file that is not there is looked up by its file
 * name in each folder of the search path, in order, so that scenes written
 * for one layout of the data (a bare "bunny.mesh" in configs/scenes)
 * run wherever a user keeps the public meshes. Not found anywhere:
 * BG_ERR_NOT_FOUND naming the path tried and the folders searched.
 */
static bg_status resolve_path(parser_t *p, const char *field, const char *relative, char **out)
{
    *out = NULL;
    if (!relative[0])
        return fail(p, BG_ERR_INVALID, field, "empty path");
    if (p->confined) {
        int leaves = relative[0] == '/';
        for (const char *c = relative; *c && !leaves; c += strcspn(c, "/"), c += *c == '/')
            leaves = strncmp(c, "..", 2) == 0 && (c[2] == '/' || c[2] == '\0');
        if (leaves)
            return fail(p, BG_ERR_INVALID, field,
                        "'%s' is outside the job's files: name an uploaded file by a relative "
                        "path inside the job's folder",
                        relative);
    }
    char *tried = NULL;
    const char *why = "";
    const char *folders = p->search_path ? p->search_path : "";
    const bg_status st =
        bg_file_lookup(p->dir, relative, folders, BG_FILE_TRUST_ABSOLUTE, out, &tried, &why);
    if (st == BG_ERR_NOMEM)
        return fail(p, BG_ERR_NOMEM, field, "out of memory");
    if (st != BG_OK) {
        const char *slash = strrchr(relative, '/');
        fail(p, BG_ERR_NOT_FOUND, field,
             "%s not found: no file %s (%s), and no %s in the mesh search path (%s)", relative,
             tried ? tried : relative, why, slash ? slash + 1 : relative,
             folders[0] ? folders : "empty");
    }
    free(tried);
    return st;
}

static char *stem_of(const char *path)
{
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    const char *dot = strrchr(base, '.');
    size_t n = dot && dot != base ? (size_t)(dot - base) : strlen(base);
    char *stem = malloc(n + 1);
    if (!stem)
        return NULL;
    memcpy(stem, base, n);
    stem[n] = '\0';
    return stem;
}

static char *copy_string(const char *s)
{
    size_t n = strlen(s) + 1;
    char *c = malloc(n);
    if (c)
        memcpy(c, s, n);
    return c;
}

/* ------------------------------------------------------------------- mesh */

static bg_status check_work(parser_t *p, double elements);

/* Takes ownership of mesh (into the scene), validates it and records its
 * dimension and bounds for the fields that follow. */
static bg_status finish_mesh(parser_t *p, bg_mesh_t *mesh)
{
    bg_scene_t *s = p->scene;
    bg_error_t inner = BG_ERROR_INIT;
    s->mesh = mesh;
    if (mesh->nv > p->max_vertices || mesh->ne > p->max_elements)
        return fail(p, BG_ERR_LIMIT, "mesh",
                    "%s has %d vertices and %d elements, over the limits of %lld vertices and "
                    "%lld elements",
                    s->mesh_source, (int)mesh->nv, (int)mesh->ne, (long long)p->max_vertices,
                    (long long)p->max_elements);
    bg_status wst = check_work(p, (double)mesh->ne);
    if (wst != BG_OK)
        return wst;
    /* Readers validate already (and do not report their count, so it is 0
     * for file meshes); generators do not, so validate here in all cases. */
    if (bg_mesh_validate(mesh, s->mesh_source, &s->reoriented, &inner) != BG_OK)
        return relay(p, "mesh", &inner);
    const int surface_task = s->task == BG_TASK_PARAMETERIZE || s->task == BG_TASK_SURFACE_EDIT;
    if ((bg_mesh_kind_of(mesh) == BG_MESH_SURFACE) != surface_task &&
        s->task == BG_TASK_SURFACE_EDIT)
        return fail(p, BG_ERR_INVALID, "mesh",
                    "%s holds %s; a surface-edit task needs a triangle "
                    "surface in 3D",
                    s->mesh_source, bg_mesh_kind_name(bg_mesh_kind_of(mesh)));
    if (bg_mesh_kind_of(mesh) == BG_MESH_SURFACE && !surface_task)
        return fail(p, BG_ERR_INVALID, "mesh",
                    "%s is a triangle surface; static elasticity needs tetrahedra or planar "
                    "triangles (set mesh.planar for a flat triangle mesh)",
                    s->mesh_source);
    if (mesh->nv < 1 || mesh->ne < 1)
        return fail(p, BG_ERR_INVALID, "mesh", "%s has no elements", s->mesh_source);
    p->dim = mesh->dim;
    bg_mesh_bounds(mesh, p->lo, p->hi);
    p->extent = 0.0;
    for (int c = 0; c < p->dim; c++)
        p->extent = fmax(p->extent, p->hi[c] - p->lo[c]);
    if (!(p->extent > 0.0))
        return fail(p, BG_ERR_INVALID, "mesh", "%s has zero extent", s->mesh_source);
    return BG_OK;
}

static bg_status load_mesh_file(parser_t *p, const char *field, const char *relative, int planar)
{
    bg_scene_t *s = p->scene;
    bg_error_t inner = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL, *flat = NULL;
    bg_status st = resolve_path(p, field, relative, &s->mesh_source);
    if (st != BG_OK)
        return st;
    if (bg_mesh_read(s->mesh_source, &mesh, &s->mesh_format, &inner) != BG_OK) {
        /* The message must name the resolved path, whatever the reader said. */
        st = strstr(inner.message, s->mesh_source)
                 ? relay(p, field, &inner)
                 : fail(p, inner.status, field, "%s: %s", s->mesh_source, inner.message);
        goto out;
    }
    if (planar && bg_mesh_kind_of(mesh) != BG_MESH_PLANAR) {
        if (bg_mesh_kind_of(mesh) != BG_MESH_SURFACE) {
            st = fail(p, BG_ERR_INVALID, "mesh.planar", "%s holds %s, not a flat triangle surface",
                      s->mesh_source, bg_mesh_kind_name(bg_mesh_kind_of(mesh)));
            goto out;
        }
        if (bg_mesh_to_planar(mesh, &flat, &inner) != BG_OK) {
            st = fail(p, inner.status, "mesh.planar", "%s: %s", s->mesh_source, inner.message);
            goto out;
        }
        bg_mesh_destroy(&mesh);
        mesh = flat;
    }
    st = finish_mesh(p, mesh); /* the scene owns the mesh from here on */
    mesh = NULL;
out:
    bg_mesh_destroy(&mesh);
    return st;
}

/* The work a job asks for, elements × its steps (dynamic) or frames
 * (morph), against the cap; the task is parsed before the mesh, so this
 * holds before a generated mesh is allocated. */
static bg_status check_work(parser_t *p, double elements)
{
    const bg_scene_t *s = p->scene;
    const int dynamic = s->task == BG_TASK_DYNAMIC, morph = s->task == BG_TASK_MORPH;
    const double repeats = dynamic ? (double)s->dynamic.steps
                           : morph ? (double)s->morph_frames
                                   : 1.0;
    if (p->max_work > 0 && elements * repeats > p->max_work)
        return fail(p, BG_ERR_LIMIT, dynamic ? "task.steps" : morph ? "task.frames" : "mesh",
                    "%.0f elements x %.0f %s = %.3g element-%s, over the limit of %.3g", elements,
                    repeats, dynamic ? "steps" : morph ? "frames" : "solve", elements * repeats,
                    dynamic ? "steps" : morph ? "frames" : "solves", p->max_work);
    return BG_OK;
}

/* Caps the generated mesh before the generator allocates: a few bytes of
 * JSON can ask for billions of elements. */
static bg_status check_generated_size(parser_t *p, const char *field, double vertices,
                                      double elements)
{
    if (vertices > (double)p->max_vertices || elements > (double)p->max_elements)
        return fail(p, BG_ERR_LIMIT, field,
                    "the generated mesh would have %.0f vertices and %.0f elements, over the "
                    "limits of %lld vertices and %lld elements",
                    vertices, elements, (long long)p->max_vertices, (long long)p->max_elements);
    return check_work(p, elements);
}

/* {"generate": "disk", "rings": R, "radius": r, "center": [...], "planar": b}:
 * a flat triangle surface in z = center[2] (what parameterization and surface
 * editing read), or planar triangles when "planar" is true. */
static bg_status generate_disk(parser_t *p, const cJSON *spec)
{
    static const char *const keys[] = {"generate", "rings", "radius", "center", "planar", NULL};
    bg_scene_t *s = p->scene;
    bg_status st = check_keys(p, spec, "mesh", keys);
    if (st != BG_OK)
        return st;
    int planar = 0;
    if (member(spec, "planar") &&
        (st = read_bool(p, member(spec, "planar"), "mesh.planar", &planar)) != BG_OK)
        return st;
    int64_t rings = 0;
    if (!member(spec, "rings"))
        return fail(p, BG_ERR_INVALID, "mesh.rings", "missing (required by the disk generator)");
    st = read_integer(p, member(spec, "rings"), "mesh.rings", 1.0, (double)BG_MESH_MAX_VERTICES,
                      &rings);
    if (st != BG_OK)
        return st;
    double radius = 0.0, center[3] = {0, 0, 0};
    if (!member(spec, "radius"))
        return fail(p, BG_ERR_INVALID, "mesh.radius", "missing (required by the disk generator)");
    st = read_number(p, member(spec, "radius"), "mesh.radius", &radius);
    if (st != BG_OK)
        return st;
    if (!(radius > 0.0))
        return fail(p, BG_ERR_INVALID, "mesh.radius", "radius = %g must be positive", radius);
    if (member(spec, "center")) {
        st = read_vector(p, member(spec, "center"), "mesh.center", planar ? 2 : 3, center);
        if (st != BG_OK)
            return st;
    }
    const double r = (double)rings;
    st = check_generated_size(p, "mesh.rings", 1.0 + 3.0 * r * (r + 1.0), 6.0 * r * r);
    if (st != BG_OK)
        return st;
    char source[FIELD_MAX];
    snprintf(source, sizeof source, "generated disk of %d rings", (int)rings);
    s->mesh_source = copy_string(source);
    if (!s->mesh_source)
        return fail(p, BG_ERR_NOMEM, "mesh", "out of memory");
    s->mesh_format = BG_FORMAT_OBJ;
    bg_error_t inner = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL;
    st = bg_mesh_generate_disk((int32_t)rings, center, radius,
                               planar ? BG_MESH_PLANAR : BG_MESH_SURFACE, &mesh, &inner);
    if (st != BG_OK)
        return relay(p, "mesh", &inner);
    return finish_mesh(p, mesh);
}

static bg_status generate_mesh(parser_t *p, const cJSON *spec)
{
    static const char *const keys[] = {"generate", "cells", "size", "origin", NULL};
    bg_scene_t *s = p->scene;
    const char *kind = NULL;
    bg_status st = read_string(p, member(spec, "generate"), "mesh.generate", &kind);
    if (st != BG_OK)
        return st;
    if (strcmp(kind, "disk") == 0)
        return generate_disk(p, spec);
    st = check_keys(p, spec, "mesh", keys);
    if (st != BG_OK)
        return st;
    int n = 0;
    if (strcmp(kind, "box") == 0)
        n = 3;
    else if (strcmp(kind, "rectangle") == 0)
        n = 2;
    else
        return fail(p, BG_ERR_INVALID, "mesh.generate",
                    "unknown generator '%s' (expected box, rectangle or disk)", kind);
    const cJSON *cells_item = member(spec, "cells");
    if (!cJSON_IsArray(cells_item) || cJSON_GetArraySize(cells_item) != n)
        return fail(p, BG_ERR_INVALID, "mesh.cells", "expected an array of %d integers", n);
    int32_t cells[3] = {0, 0, 0};
    int i = 0;
    for (const cJSON *e = cells_item->child; e; e = e->next, i++) {
        char sub[FIELD_MAX];
        int64_t v = 0;
        field_index(sub, "mesh.cells", i);
        st = read_integer(p, e, sub, 1.0, (double)BG_MESH_MAX_VERTICES, &v);
        if (st != BG_OK)
            return st;
        cells[i] = (int32_t)v;
    }
    double size[3] = {0, 0, 0}, origin[3] = {0, 0, 0};
    if (!member(spec, "size"))
        return fail(p, BG_ERR_INVALID, "mesh.size", "missing (required by a generator)");
    st = read_vector(p, member(spec, "size"), "mesh.size", n, size);
    if (st != BG_OK)
        return st;
    for (i = 0; i < n; i++)
        if (!(size[i] > 0.0))
            return fail(p, BG_ERR_INVALID, "mesh.size", "size[%d] = %g must be positive", i,
                        size[i]);
    if (member(spec, "origin")) {
        st = read_vector(p, member(spec, "origin"), "mesh.origin", n, origin);
        if (st != BG_OK)
            return st;
    }
    const double vertices = n == 3 ? ((double)cells[0] + 1) * (cells[1] + 1) * (cells[2] + 1)
                                   : ((double)cells[0] + 1) * (cells[1] + 1),
                 elements =
                     n == 3 ? 6.0 * cells[0] * cells[1] * cells[2] : 2.0 * cells[0] * cells[1];
    st = check_generated_size(p, "mesh.cells", vertices, elements);
    if (st != BG_OK)
        return st;
    char source[FIELD_MAX];
    if (n == 3)
        snprintf(source, sizeof source, "generated box %dx%dx%d", (int)cells[0], (int)cells[1],
                 (int)cells[2]);
    else
        snprintf(source, sizeof source, "generated rectangle %dx%d", (int)cells[0], (int)cells[1]);
    s->mesh_source = copy_string(source);
    if (!s->mesh_source)
        return fail(p, BG_ERR_NOMEM, "mesh", "out of memory");
    s->mesh_format = n == 3 ? BG_FORMAT_MEDIT : BG_FORMAT_OBJ;
    bg_error_t inner = BG_ERROR_INIT;
    bg_mesh_t *mesh = NULL;
    st = n == 3 ? bg_mesh_generate_box(cells, origin, size, &mesh, &inner)
                : bg_mesh_generate_rectangle(cells, origin, size, &mesh, &inner);
    if (st != BG_OK)
        return relay(p, "mesh", &inner);
    return finish_mesh(p, mesh);
}

static bg_status parse_mesh(parser_t *p, const cJSON *item)
{
    static const char *const file_keys[] = {"file", "planar", NULL};
    if (!item)
        return fail(p, BG_ERR_INVALID, "mesh", "missing (required)");
    if (cJSON_IsString(item))
        return load_mesh_file(p, "mesh", item->valuestring, 0);
    if (!cJSON_IsObject(item))
        return fail(p, BG_ERR_INVALID, "mesh", "expected a path or an object, got %s",
                    json_type_name(item));
    bg_status st = BG_OK;
    if (member(item, "generate"))
        return generate_mesh(p, item);
    if (!member(item, "file"))
        return fail(p, BG_ERR_INVALID, "mesh",
                    "expected a path, {\"file\": ...} or {\"generate\": ...}");
    st = check_keys(p, item, "mesh", file_keys);
    if (st != BG_OK)
        return st;
    const char *path = NULL;
    st = read_string(p, member(item, "file"), "mesh.file", &path);
    if (st != BG_OK)
        return st;
    int planar = 0;
    if (member(item, "planar") &&
        (st = read_bool(p, member(item, "planar"), "mesh.planar", &planar)) != BG_OK)
        return st;
    return load_mesh_file(p, "mesh.file", path, planar);
}

/* --------------------------------------------------------------- material */

/*
 * The material's values, checked as far as they can be without the mesh:
 * the keys, exactly one of the three forms, finite numbers, E > 0, ν in
 * (−1, ½), density > 0. Read before the mesh is built, so that a scene
 * missing its material fails before any mesh is generated or read;
 * finish_material converts them once the dimension is known.
 */
static bg_status parse_material(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"mu", "lambda", "E", "nu", "alpha", "beta", "density", NULL};
    static const char *const forms[3][2] = {{"mu", "lambda"}, {"E", "nu"}, {"alpha", "beta"}};
    if (!item)
        return fail(p, BG_ERR_INVALID, "material", "missing (required)");
    bg_status st = expect_object(p, item, "material");
    if (st == BG_OK)
        st = check_keys(p, item, "material", keys);
    if (st != BG_OK)
        return st;
    int form = -1;
    for (int f = 0; f < 3; f++) {
        int have0 = member(item, forms[f][0]) != NULL, have1 = member(item, forms[f][1]) != NULL;
        if (!have0 && !have1)
            continue;
        if (form >= 0)
            return fail(p, BG_ERR_INVALID, "material",
                        "give exactly one of {mu, lambda}, {E, nu}, {alpha, beta}; found both "
                        "'%s' and '%s'",
                        forms[form][0], forms[f][have0 ? 0 : 1]);
        if (!have0 || !have1)
            return fail(p, BG_ERR_INVALID, "material", "'%s' needs '%s'", forms[f][have0 ? 0 : 1],
                        forms[f][have0 ? 1 : 0]);
        form = f;
    }
    if (form < 0)
        return fail(p, BG_ERR_INVALID, "material",
                    "give one of {mu, lambda}, {E, nu}, {alpha, beta}");
    double a = 0.0, b = 0.0;
    char fa[FIELD_MAX], fb[FIELD_MAX];
    field_key(fa, "material", forms[form][0]);
    field_key(fb, "material", forms[form][1]);
    st = read_number(p, member(item, forms[form][0]), fa, &a);
    if (st == BG_OK)
        st = read_number(p, member(item, forms[form][1]), fb, &b);
    if (st != BG_OK)
        return st;
    if (form == 1) {
        if (!(a > 0.0))
            return fail(p, BG_ERR_INVALID, fa, "Young's modulus must be positive, got %g", a);
        if (!(b > -1.0 && b < 0.5))
            return fail(p, BG_ERR_INVALID, fb, "Poisson's ratio must be in (-1, 0.5), got %g", b);
    }
    bg_material_t *m = &p->scene->material;
    m->density = DEFAULT_DENSITY;
    if (member(item, "density")) {
        st = read_number(p, member(item, "density"), "material.density", &m->density);
        if (st != BG_OK)
            return st;
        if (!(m->density > 0.0))
            return fail(p, BG_ERR_INVALID, "material.density", "must be positive, got %g",
                        m->density);
    }
    p->material_form = form;
    p->material_a = a;
    p->material_b = b;
    return BG_OK;
}

/* The material's μ and λ in the mesh's dimension, and the stability check
 * that depends on it. */
static bg_status finish_material(parser_t *p)
{
    const int n = p->dim;
    const double a = p->material_a, b = p->material_b;
    bg_material_t *m = &p->scene->material;
    if (p->material_form == 0) {
        m->mu = a;
        m->lambda = b;
    } else if (p->material_form == 1) {
        m->mu = a / (2.0 * (1.0 + b));
        m->lambda = a * b / ((1.0 + b) * (1.0 - 2.0 * b));
    } else {
        m->mu = 0.5 * b * b;
        m->lambda = (a * a - b * b) / n;
    }
    if (!(m->mu > 0.0) || !(n * m->lambda + 2.0 * m->mu > 0.0) || !isfinite(m->lambda))
        return fail(p, BG_ERR_INVALID, "material",
                    "unstable material mu = %g, lambda = %g: need mu > 0 and %d*lambda + 2*mu > 0",
                    m->mu, m->lambda, n);
    return BG_OK;
}

/* ---------------------------------------------------------------- handles */

static bg_status collect(parser_t *p, const char *field, selection_t *sel)
{
    const int32_t nv = p->scene->mesh->nv;
    int32_t count = 0;
    for (int32_t v = 0; v < nv; v++)
        count += p->flag[v] != 0;
    sel->vertices = malloc(((size_t)count + 1) * sizeof *sel->vertices);
    sel->mask = calloc((size_t)count + 1, sizeof *sel->mask);
    if (!sel->vertices || !sel->mask)
        return fail(p, BG_ERR_NOMEM, field, "out of memory");
    sel->count = 0;
    for (int32_t v = 0; v < nv; v++)
        if (p->flag[v])
            sel->vertices[sel->count++] = v;
    return BG_OK;
}

/* Marks the vertices inside [lo, hi] (inclusive, with the tolerance). */
static void mark_box(parser_t *p, const double *lo, const double *hi)
{
    const bg_mesh_t *mesh = p->scene->mesh;
    const double tol = SELECT_TOLERANCE * p->extent;
    for (int32_t v = 0; v < mesh->nv; v++) {
        int inside = 1;
        for (int c = 0; c < p->dim; c++) {
            double x = mesh->x[(size_t)v * p->dim + c];
            if (x < lo[c] - tol || x > hi[c] + tol)
                inside = 0;
        }
        p->flag[v] = (uint8_t)inside;
    }
}

static bg_status select_box(parser_t *p, const cJSON *spec, const char *field, int fraction)
{
    static const char *const keys[] = {"min", "max", NULL};
    bg_status st = expect_object(p, spec, field);
    if (st == BG_OK)
        st = check_keys(p, spec, field, keys);
    if (st != BG_OK)
        return st;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    char fmin[FIELD_MAX], fmax[FIELD_MAX];
    field_key(fmin, field, "min");
    field_key(fmax, field, "max");
    if (!member(spec, "min") || !member(spec, "max"))
        return fail(p, BG_ERR_INVALID, field, "needs both 'min' and 'max'");
    st = read_vector(p, member(spec, "min"), fmin, p->dim, lo);
    if (st == BG_OK)
        st = read_vector(p, member(spec, "max"), fmax, p->dim, hi);
    if (st != BG_OK)
        return st;
    for (int c = 0; c < p->dim; c++) {
        if (fraction && (lo[c] < 0.0 || lo[c] > 1.0 || hi[c] < 0.0 || hi[c] > 1.0))
            return fail(p, BG_ERR_INVALID, field,
                        "fractions must be in [0, 1], got min %g, max %g on %c", lo[c], hi[c],
                        AXIS_NAMES[c]);
        if (lo[c] > hi[c])
            return fail(p, BG_ERR_INVALID, field, "min %g > max %g on %c", lo[c], hi[c],
                        AXIS_NAMES[c]);
        if (fraction) {
            double span = p->hi[c] - p->lo[c];
            lo[c] = p->lo[c] + lo[c] * span;
            hi[c] = p->lo[c] + hi[c] * span;
        }
    }
    mark_box(p, lo, hi);
    return BG_OK;
}

static bg_status select_vertices(parser_t *p, const cJSON *list, const char *field)
{
    const int32_t nv = p->scene->mesh->nv;
    if (!cJSON_IsArray(list) || cJSON_GetArraySize(list) < 1)
        return fail(p, BG_ERR_INVALID, field, "expected a non-empty array of vertex indices");
    memset(p->flag, 0, (size_t)nv);
    int i = 0;
    for (const cJSON *e = list->child; e; e = e->next, i++) {
        char sub[FIELD_MAX];
        field_index(sub, field, i);
        double v = 0.0;
        bg_status st = read_number(p, e, sub, &v);
        if (st != BG_OK)
            return st;
        if (v != floor(v) || v < 0.0)
            return fail(p, BG_ERR_INVALID, sub, "%.17g is not a vertex index (0-based integer)", v);
        if (v >= nv)
            return fail(p, BG_ERR_INVALID, sub,
                        "vertex index %.0f is out of range (the mesh has %d vertices)", v, (int)nv);
        if (p->flag[(int32_t)v])
            return fail(p, BG_ERR_INVALID, sub, "vertex %.0f is listed twice", v);
        p->flag[(int32_t)v] = 1;
    }
    return BG_OK;
}

static bg_status select_file(parser_t *p, const cJSON *spec, const char *field)
{
    const int32_t nv = p->scene->mesh->nv;
    char ffile[FIELD_MAX], fgroup[FIELD_MAX];
    field_key(ffile, field, "file");
    field_key(fgroup, field, "group");
    const char *relative = NULL;
    bg_status st = read_string(p, member(spec, "file"), ffile, &relative);
    if (st != BG_OK)
        return st;
    /* Without a group every labelled vertex (label >= 0) is selected: all
     * listed vertices of a plain list, all handle groups of a DMAT. */
    int64_t group = -1;
    if (member(spec, "group")) {
        st = read_integer(p, member(spec, "group"), fgroup, 0.0, (double)INT32_MAX, &group);
        if (st != BG_OK)
            return st;
    }
    char *path = NULL;
    int32_t *labels = malloc(((size_t)nv + 1) * sizeof *labels);
    if (!labels)
        return fail(p, BG_ERR_NOMEM, field, "out of memory");
    st = resolve_path(p, ffile, relative, &path);
    if (st != BG_OK)
        goto out;
    bg_error_t inner = BG_ERROR_INIT;
    if (bg_selection_read(path, nv, labels, &inner) != BG_OK) {
        st = relay(p, ffile, &inner);
        goto out;
    }
    for (int32_t v = 0; v < nv; v++)
        p->flag[v] = (uint8_t)(group < 0 ? labels[v] >= 0 : labels[v] == group);
out:
    free(path);
    free(labels);
    return st;
}

static bg_status select_ref(parser_t *p, const cJSON *item, const char *field)
{
    const bg_mesh_t *mesh = p->scene->mesh;
    int64_t ref = 0;
    bg_status st = read_integer(p, item, field, (double)INT32_MIN, (double)INT32_MAX, &ref);
    if (st != BG_OK)
        return st;
    for (int32_t v = 0; v < mesh->nv; v++)
        p->flag[v] = (uint8_t)(mesh->vertex_ref[v] == ref);
    return BG_OK;
}

/*
 * The 3-2-1 kinematic mount: it removes the rigid motions and nothing else.
 * With a fixed, b may only slide along ab (two components of b fixed, the
 * dropped one being ab's dominant axis, so the remaining freedom is a
 * rotation about ab); c then loses that rotation through the component
 * along which the rotation moves it most, the dominant axis of the normal
 * of plane abc. In 2D, a and one component of b suffice.
 */
static bg_status select_rigid_mount(parser_t *p, const char *field, selection_t *sel)
{
    const bg_mesh_t *mesh = p->scene->mesh;
    const int d = p->dim;
    int axis = 0;
    for (int c = 1; c < d; c++)
        if (p->hi[c] - p->lo[c] > p->hi[axis] - p->lo[axis])
            axis = c;
    int32_t a = 0, b = 0;
    for (int32_t v = 1; v < mesh->nv; v++) {
        if (mesh->x[(size_t)v * d + axis] < mesh->x[(size_t)a * d + axis])
            a = v;
        if (mesh->x[(size_t)v * d + axis] > mesh->x[(size_t)b * d + axis])
            b = v;
    }
    const double *pa = mesh->x + (size_t)a * d, *pb = mesh->x + (size_t)b * d;
    double ab[3] = {0, 0, 0};
    int long_axis = 0;
    for (int c = 0; c < d; c++) {
        ab[c] = pb[c] - pa[c];
        if (fabs(ab[c]) > fabs(ab[long_axis]))
            long_axis = c;
    }
    uint8_t all = (uint8_t)((1u << d) - 1u);
    int32_t verts[3] = {a, b, -1};
    uint8_t masks[3] = {all, (uint8_t)(all & ~(1u << long_axis)), 0};
    int used = 2;
    if (d == 3) {
        double best = -1.0, normal[3] = {0, 0, 0};
        int32_t c = -1;
        for (int32_t v = 0; v < mesh->nv; v++) {
            const double *pv = mesh->x + (size_t)v * 3;
            double av[3] = {pv[0] - pa[0], pv[1] - pa[1], pv[2] - pa[2]};
            double n[3] = {ab[1] * av[2] - ab[2] * av[1], ab[2] * av[0] - ab[0] * av[2],
                           ab[0] * av[1] - ab[1] * av[0]};
            /* |ab × av| / |ab| is the distance to the line; |ab| is common. */
            double area = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            if (area > best) {
                best = area;
                c = v;
                memcpy(normal, n, sizeof normal);
            }
        }
        double length = sqrt(ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2]);
        if (!(best / length > SELECT_TOLERANCE * p->extent))
            return fail(p, BG_ERR_INVALID, field, "rigid-mount: all vertices lie on one line");
        int n_axis = 0;
        for (int k = 1; k < 3; k++)
            if (fabs(normal[k]) > fabs(normal[n_axis]))
                n_axis = k;
        verts[2] = c;
        masks[2] = (uint8_t)(1u << n_axis);
        used = 3;
    }
    /* Store in increasing vertex order, as every selection is. */
    for (int i = 0; i < used; i++)
        for (int j = i + 1; j < used; j++)
            if (verts[j] < verts[i]) {
                int32_t tv = verts[i];
                uint8_t tm = masks[i];
                verts[i] = verts[j];
                masks[i] = masks[j];
                verts[j] = tv;
                masks[j] = tm;
            }
    sel->vertices = malloc(sizeof verts);
    sel->mask = malloc(sizeof masks);
    if (!sel->vertices || !sel->mask)
        return fail(p, BG_ERR_NOMEM, field, "out of memory");
    memcpy(sel->vertices, verts, sizeof verts);
    memcpy(sel->mask, masks, sizeof masks);
    sel->count = used;
    return BG_OK;
}

static bg_status parse_select(parser_t *p, const cJSON *spec, const char *field, selection_t *sel)
{
    static const char *const keys[] = {"box",   "box_fraction", "vertices", "file",
                                       "group", "ref",          NULL};
    static const char *const forms[] = {"box", "box_fraction", "vertices", "file", "ref", NULL};
    if (!spec)
        return fail(p, BG_ERR_INVALID, field, "missing (required)");
    if (cJSON_IsString(spec)) {
        if (strcmp(spec->valuestring, "rigid-mount") != 0)
            return fail(p, BG_ERR_INVALID, field,
                        "unknown selection '%s' (the only named selection is \"rigid-mount\")",
                        spec->valuestring);
        return select_rigid_mount(p, field, sel);
    }
    bg_status st = expect_object(p, spec, field);
    if (st == BG_OK)
        st = check_keys(p, spec, field, keys);
    if (st != BG_OK)
        return st;
    const char *form = NULL;
    for (const char *const *f = forms; *f; f++)
        if (member(spec, *f)) {
            if (form)
                return fail(p, BG_ERR_INVALID, field,
                            "give exactly one of box, box_fraction, vertices, file, ref; found "
                            "'%s' and '%s'",
                            form, *f);
            form = *f;
        }
    if (!form)
        return fail(p, BG_ERR_INVALID, field,
                    "give one of box, box_fraction, vertices, file, ref (or \"rigid-mount\")");
    if (member(spec, "group") && strcmp(form, "file") != 0)
        return fail(p, BG_ERR_INVALID, field, "'group' applies only to a 'file' selection");
    char sub[FIELD_MAX];
    field_key(sub, field, form);
    if (strcmp(form, "box") == 0)
        st = select_box(p, member(spec, form), sub, 0);
    else if (strcmp(form, "box_fraction") == 0)
        st = select_box(p, member(spec, form), sub, 1);
    else if (strcmp(form, "vertices") == 0)
        st = select_vertices(p, member(spec, form), sub);
    else if (strcmp(form, "file") == 0)
        st = select_file(p, spec, field);
    else
        st = select_ref(p, member(spec, form), sub);
    if (st != BG_OK)
        return st;
    return collect(p, field, sel);
}

static bg_status parse_components(parser_t *p, const cJSON *item, const char *field, uint8_t *mask)
{
    const char *text = NULL;
    bg_status st = read_string(p, item, field, &text);
    if (st != BG_OK)
        return st;
    *mask = 0;
    for (const char *ch = text; *ch; ch++) {
        int c = -1;
        for (int k = 0; k < p->dim; k++)
            if (*ch == AXIS_NAMES[k])
                c = k;
        if (c < 0)
            return fail(p, BG_ERR_INVALID, field, "'%s': components are letters among \"%.*s\"",
                        text, p->dim, AXIS_NAMES);
        if (*mask & (1u << c))
            return fail(p, BG_ERR_INVALID, field, "'%s' repeats '%c'", text, *ch);
        *mask |= (uint8_t)(1u << c);
    }
    if (!*mask)
        return fail(p, BG_ERR_INVALID, field, "empty (omit it to constrain all coordinates)");
    return BG_OK;
}

/* cos and sin of an angle in degrees, exact at multiples of 90°. */
static void cos_sin_degrees(double degrees, double *c, double *s)
{
    double r = fmod(degrees, FULL_TURN_DEGREES);
    if (r < 0.0)
        r += FULL_TURN_DEGREES;
    if (r == 0.0 || r == DEGREES_PER_QUARTER || r == 2 * DEGREES_PER_QUARTER ||
        r == 3 * DEGREES_PER_QUARTER) {
        static const double cq[4] = {1, 0, -1, 0}, sq[4] = {0, 1, 0, -1};
        int q = (int)(r / DEGREES_PER_QUARTER);
        *c = cq[q];
        *s = sq[q];
        return;
    }
    double rad = degrees * PI_VALUE / (FULL_TURN_DEGREES / 2);
    *c = cos(rad);
    *s = sin(rad);
}

/* Targets R (p − c) + c + t of the selected vertices, into out (count*dim). */
static bg_status apply_transform(parser_t *p, const cJSON *spec, const char *field,
                                 const selection_t *sel, double *out, bg_scene_motion_t *motion)
{
    static const char *const keys[] = {"rotate", "translate", NULL};
    static const char *const rotate_keys[] = {"axis", "degrees", "center", NULL};
    const int d = p->dim;
    const double *x = p->scene->mesh->x;
    bg_status st = expect_object(p, spec, field);
    if (st == BG_OK)
        st = check_keys(p, spec, field, keys);
    if (st != BG_OK)
        return st;
    double rot[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double center[3] = {0, 0, 0}, shift[3] = {0, 0, 0};
    const cJSON *rotate = member(spec, "rotate");
    if (rotate) {
        char fr[FIELD_MAX], sub[FIELD_MAX];
        field_key(fr, field, "rotate");
        st = expect_object(p, rotate, fr);
        if (st == BG_OK)
            st = check_keys(p, rotate, fr, rotate_keys);
        if (st != BG_OK)
            return st;
        double degrees = 0.0, c = 1.0, s = 0.0;
        field_key(sub, fr, "degrees");
        if (!member(rotate, "degrees"))
            return fail(p, BG_ERR_INVALID, sub, "missing (required)");
        st = read_number(p, member(rotate, "degrees"), sub, &degrees);
        if (st != BG_OK)
            return st;
        cos_sin_degrees(degrees, &c, &s);
        motion->radians = degrees * PI_VALUE / (FULL_TURN_DEGREES / 2);
        field_key(sub, fr, "axis");
        if (d == 2) {
            if (member(rotate, "axis"))
                return fail(p, BG_ERR_INVALID, sub,
                            "a planar rotation turns in the plane; omit the axis");
            rot[0][0] = c;
            rot[0][1] = -s;
            rot[1][0] = s;
            rot[1][1] = c;
        } else {
            double k[3] = {0, 0, 0};
            if (!member(rotate, "axis"))
                return fail(p, BG_ERR_INVALID, sub, "missing (required in 3D)");
            st = read_vector(p, member(rotate, "axis"), sub, 3, k);
            if (st != BG_OK)
                return st;
            double norm = sqrt(k[0] * k[0] + k[1] * k[1] + k[2] * k[2]);
            if (!(norm > 0.0) || !isfinite(norm))
                return fail(p, BG_ERR_INVALID, sub, "the axis must be a nonzero vector");
            for (int i = 0; i < 3; i++) {
                k[i] /= norm;
                motion->axis[i] = k[i];
            }
            /* Rodrigues: R = c I + s [k]x + (1 − c) k kᵀ (right-handed). */
            const double kx[3][3] = {{0, -k[2], k[1]}, {k[2], 0, -k[0]}, {-k[1], k[0], 0}};
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    rot[i][j] = (i == j ? c : 0.0) + s * kx[i][j] + (1.0 - c) * k[i] * k[j];
        }
        field_key(sub, fr, "center");
        if (member(rotate, "center")) {
            st = read_vector(p, member(rotate, "center"), sub, d, center);
            if (st != BG_OK)
                return st;
        } else {
            /* Default: the centre of the selection's bounding box. */
            for (int c2 = 0; c2 < d; c2++) {
                double lo = INFINITY, hi = -INFINITY;
                for (int32_t i = 0; i < sel->count; i++) {
                    double v = x[(size_t)sel->vertices[i] * d + c2];
                    lo = fmin(lo, v);
                    hi = fmax(hi, v);
                }
                center[c2] = 0.5 * (lo + hi);
            }
        }
    }
    if (member(spec, "translate")) {
        char sub[FIELD_MAX];
        field_key(sub, field, "translate");
        st = read_vector(p, member(spec, "translate"), sub, d, shift);
        if (st != BG_OK)
            return st;
    }
    memcpy(motion->center, center, sizeof center);
    memcpy(motion->translate, shift, sizeof shift);
    for (int32_t i = 0; i < sel->count; i++) {
        const double *pv = x + (size_t)sel->vertices[i] * d;
        for (int r = 0; r < d; r++) {
            double v = center[r] + shift[r];
            for (int c2 = 0; c2 < d; c2++)
                v += rot[r][c2] * (pv[c2] - center[c2]);
            out[(size_t)i * d + r] = v;
        }
    }
    return BG_OK;
}

/* Number of position lines (non-blank, not starting with '#') in text. */
static int64_t count_data_lines(const char *text, size_t length)
{
    int64_t lines = 0;
    size_t i = 0;
    while (i < length) {
        size_t j = i;
        while (j < length && (text[j] == ' ' || text[j] == '\t' || text[j] == '\r'))
            j++;
        if (j < length && text[j] != '\n' && text[j] != '#')
            lines++;
        while (j < length && text[j] != '\n')
            j++;
        i = j + 1;
    }
    return lines;
}

/*
 * Handle positions from a file: either one line per selected vertex, or one
 * line per mesh vertex (a whole deformed copy, e.g. the twisted bar), from
 * which the selected rows are taken.
 */
static bg_status read_handle_positions(parser_t *p, const char *field, const char *relative,
                                       const selection_t *sel, double *out)
{
    const bg_mesh_t *mesh = p->scene->mesh;
    const int d = p->dim;
    char *path = NULL, *text = NULL;
    double *all = NULL;
    size_t length = 0;
    bg_error_t inner = BG_ERROR_INIT;
    bg_status st = resolve_path(p, field, relative, &path);
    if (st != BG_OK)
        return st;
    if (bg_file_read_all(path, BG_MESH_FILE_MAX_BYTES, &text, &length, &inner) != BG_OK) {
        st = relay(p, field, &inner);
        goto out;
    }
    if (count_data_lines(text, length) == mesh->nv && sel->count != mesh->nv) {
        all = malloc((size_t)mesh->nv * d * sizeof *all);
        if (!all) {
            st = fail(p, BG_ERR_NOMEM, field, "out of memory");
            goto out;
        }
        if (bg_positions_parse(text, length, path, mesh->nv, d, all, &inner) != BG_OK) {
            st = relay(p, field, &inner);
            goto out;
        }
        for (int32_t i = 0; i < sel->count; i++)
            memcpy(out + (size_t)i * d, all + (size_t)sel->vertices[i] * d, d * sizeof *out);
    } else if (bg_positions_parse(text, length, path, sel->count, d, out, &inner) != BG_OK) {
        st = relay(p, field, &inner);
        goto out;
    }
out:
    free(all);
    free(text);
    free(path);
    return st;
}

static bg_status inline_positions(parser_t *p, const cJSON *list, const char *field,
                                  const selection_t *sel, double *out)
{
    if (!cJSON_IsArray(list) || cJSON_GetArraySize(list) != sel->count)
        return fail(p, BG_ERR_INVALID, field,
                    "expected an array of %d positions (one per selected vertex, in increasing "
                    "vertex order) or a file path",
                    (int)sel->count);
    int i = 0;
    for (const cJSON *e = list->child; e; e = e->next, i++) {
        char sub[FIELD_MAX];
        field_index(sub, field, i);
        bg_status st = read_vector(p, e, sub, p->dim, out + (size_t)i * p->dim);
        if (st != BG_OK)
            return st;
    }
    return BG_OK;
}

static void describe_handle(char *out, int index, const char *name)
{
    int written = name ? snprintf(out, FIELD_MAX, "handles[%d] ('%s')", index, name)
                       : snprintf(out, FIELD_MAX, "handles[%d]", index);
    mark_if_truncated(out, written);
}

static bg_status parse_handle(parser_t *p, const cJSON *spec, int index, const char **names)
{
    static const char *const keys[] = {"name",       "select",   "transform", "positions",
                                       "components", "duration", NULL};
    bg_scene_t *s = p->scene;
    const int d = p->dim;
    char field[FIELD_MAX], sub[FIELD_MAX], who[FIELD_MAX];
    field_index(field, "handles", index);
    selection_t sel = {0, NULL, NULL};
    double *goal = NULL;
    bg_status st = expect_object(p, spec, field);
    if (st == BG_OK)
        st = check_keys(p, spec, field, keys);
    if (st != BG_OK)
        return st;
    names[index] = NULL;
    if (member(spec, "name")) {
        field_key(sub, field, "name");
        st = read_string(p, member(spec, "name"), sub, &names[index]);
        if (st != BG_OK)
            return st;
    }
    describe_handle(who, index, names[index]);
    const cJSON *transform = member(spec, "transform"), *positions = member(spec, "positions");
    if (transform && positions)
        return fail(p, BG_ERR_INVALID, field, "give at most one of 'transform' and 'positions'");
    field_key(sub, field, "select");
    const cJSON *select = member(spec, "select");
    int mount = cJSON_IsString(select) && strcmp(select->valuestring, "rigid-mount") == 0;
    if (mount && (transform || positions || member(spec, "components")))
        return fail(p, BG_ERR_INVALID, field,
                    "a \"rigid-mount\" is fixed at rest and chooses its own components; remove "
                    "'%s'",
                    transform   ? "transform"
                    : positions ? "positions"
                                : "components");
    st = parse_select(p, select, sub, &sel);
    if (st != BG_OK)
        goto out;
    if (sel.count == 0) {
        st = fail(p, BG_ERR_INVALID, sub, "%s selects no vertex", who);
        goto out;
    }
    if (!mount) {
        uint8_t mask = (uint8_t)((1u << d) - 1u);
        if (member(spec, "components")) {
            field_key(sub, field, "components");
            st = parse_components(p, member(spec, "components"), sub, &mask);
            if (st != BG_OK)
                goto out;
        }
        memset(sel.mask, mask, (size_t)sel.count);
    }
    goal = malloc((size_t)sel.count * d * sizeof *goal);
    if (!goal) {
        st = fail(p, BG_ERR_NOMEM, field, "out of memory");
        goto out;
    }
    bg_scene_motion_t *motion = &s->motions[index];
    motion->axis[2] = 1.0; /* planar rotations turn about z */
    if (member(spec, "duration")) {
        field_key(sub, field, "duration");
        if (s->task != BG_TASK_DYNAMIC || (!transform && !positions)) {
            st = fail(p, BG_ERR_INVALID, sub, "a duration needs a dynamic task and a motion");
            goto out;
        }
        st = read_number(p, member(spec, "duration"), sub, &motion->duration);
        if (st == BG_OK && !(motion->duration > 0.0))
            st = fail(p, BG_ERR_INVALID, sub, "must be positive, got %g", motion->duration);
        if (st != BG_OK)
            goto out;
    }
    if (transform) {
        field_key(sub, field, "transform");
        motion->kind = BG_MOTION_RIGID;
        st = apply_transform(p, transform, sub, &sel, goal, motion);
    } else if (positions) {
        motion->kind = BG_MOTION_POSITIONS;
        field_key(sub, field, "positions");
        if (cJSON_IsString(positions))
            st = read_handle_positions(p, sub, positions->valuestring, &sel, goal);
        else
            st = inline_positions(p, positions, sub, &sel, goal);
    } else {
        for (int32_t i = 0; i < sel.count; i++)
            memcpy(goal + (size_t)i * d, s->mesh->x + (size_t)sel.vertices[i] * d,
                   d * sizeof *goal);
    }
    if (st != BG_OK)
        goto out;
    motion->vertices = malloc((size_t)sel.count * sizeof *motion->vertices);
    if (!motion->vertices) {
        st = fail(p, BG_ERR_NOMEM, field, "out of memory");
        goto out;
    }
    memcpy(motion->vertices, sel.vertices, (size_t)sel.count * sizeof *motion->vertices);
    motion->count = sel.count;
    for (int32_t i = 0; i < sel.count; i++)
        for (int c = 0; c < d; c++)
            motion->mean_displacement[c] +=
                (goal[(size_t)i * d + c] - s->mesh->x[(size_t)sel.vertices[i] * d + c]) / sel.count;
    const double agree = AGREE_TOLERANCE * p->extent;
    for (int32_t i = 0; i < sel.count; i++) {
        int32_t v = sel.vertices[i];
        for (int c = 0; c < d; c++) {
            if (!(sel.mask[i] & (1u << c)))
                continue;
            size_t k = (size_t)v * d + c;
            double value = goal[(size_t)i * d + c];
            if (p->owner[k] >= 0) {
                if (fabs(s->target[k] - value) <= agree)
                    continue;
                char other[FIELD_MAX];
                describe_handle(other, (int)p->owner[k], names[p->owner[k]]);
                st = fail(p, BG_ERR_INVALID, field,
                          "%s and %s prescribe different values for vertex %d coordinate %c "
                          "(%.17g vs %.17g)",
                          who, other, (int)v, AXIS_NAMES[c], value, s->target[k]);
                goto out;
            }
            p->owner[k] = index;
            s->constrained[k] = 1;
            s->target[k] = value;
        }
    }
out:
    free(goal);
    free(sel.vertices);
    free(sel.mask);
    return st;
}

static bg_status parse_handles(parser_t *p, const cJSON *item)
{
    bg_scene_t *s = p->scene;
    const size_t n = (size_t)s->mesh->nv * p->dim;
    const char **names = NULL;
    if (item && !cJSON_IsArray(item))
        return fail(p, BG_ERR_INVALID, "handles", "expected an array, got %s",
                    json_type_name(item));
    int count = item ? cJSON_GetArraySize(item) : 0;
    if (count > BG_SCENE_MAX_HANDLES)
        return fail(p, BG_ERR_LIMIT, "handles", "%d handles, over the limit of %d", count,
                    BG_SCENE_MAX_HANDLES);
    bg_status st = BG_OK;
    p->owner = malloc((n + 1) * sizeof *p->owner);
    p->flag = calloc((size_t)s->mesh->nv + 1, 1);
    names = calloc((size_t)count + 1, sizeof *names);
    s->motions = calloc((size_t)count + 1, sizeof *s->motions);
    if (!p->owner || !p->flag || !names || !s->motions) {
        st = fail(p, BG_ERR_NOMEM, "handles", "out of memory");
        goto out;
    }
    s->handle_count = count; /* before parsing, so destroy frees partial motions */
    for (size_t k = 0; k < n; k++)
        p->owner[k] = -1;
    int index = 0;
    for (const cJSON *h = item ? item->child : NULL; h; h = h->next, index++) {
        st = parse_handle(p, h, index, names);
        if (st != BG_OK)
            goto out;
    }
    /* A morph with nothing held has a rigid-motion null space: its
     * Hessian is singular, and the Newton steps' components along that
     * space are round-off amplified, so two evaluations that differ in the
     * last bits (partial sums added in another order, as across agents)
     * drift apart by a rigid motion and take other line-search paths. The
     * energy is invariant under rigid motions, so holding the 3-2-1 mount
     * at rest changes no frame's energy and removes that null space. */
    if (s->task == BG_TASK_MORPH && count == 0) {
        cJSON *mount = cJSON_Parse("{\"name\": \"rigid-mount\", \"select\": \"rigid-mount\"}");
        if (!mount) {
            st = fail(p, BG_ERR_NOMEM, "handles", "out of memory");
            goto out;
        }
        st = parse_handle(p, mount, count, names);
        cJSON_Delete(mount);
        if (st != BG_OK)
            goto out;
        count++;
    }
    s->handle_count = count;
    s->constrained_vertices = 0;
    for (int32_t v = 0; v < s->mesh->nv; v++) {
        int any = 0;
        for (int c = 0; c < p->dim; c++)
            any |= s->constrained[(size_t)v * p->dim + c];
        s->constrained_vertices += any;
    }
    if (s->constrained_vertices == 0 &&
        (s->task == BG_TASK_STATIC || s->task == BG_TASK_SURFACE_EDIT))
        st = fail(p, BG_ERR_INVALID, "handles",
                  "a static solve needs handles that hold the body in place (add a fixed handle "
                  "or {\"select\": \"rigid-mount\"})");
out:
    free(names);
    return st;
}

/* ------------------------------------------------------------ misc fields */

static bg_status parse_gravity(parser_t *p, const cJSON *item)
{
    if (!item)
        return BG_OK;
    return read_vector(p, item, "gravity", p->dim, p->scene->gravity);
}

static uint64_t splitmix64(uint64_t *state)
{
    uint64_t z = (*state += SPLITMIX_GAMMA);
    z = (z ^ (z >> 30)) * SPLITMIX_MUL1;
    z = (z ^ (z >> 27)) * SPLITMIX_MUL2;
    return z ^ (z >> 31);
}

/* A positions file (one line per mesh vertex) named relative to the scene. */
static bg_status read_positions_file(parser_t *p, const char *field, const char *relative,
                                     double *out)
{
    char *path = NULL;
    bg_status st = resolve_path(p, field, relative, &path);
    if (st != BG_OK)
        return st;
    bg_error_t inner = BG_ERROR_INIT;
    if (bg_positions_read(path, p->scene->mesh->nv, p->dim, out, &inner) != BG_OK)
        st = relay(p, field, &inner);
    free(path);
    return st;
}

/*
 * task.target = {"twist": {"axis": k, "degrees": d, "center": c}}: the rest
 * shape twisted about the line through c (default: the centre of the mesh's
 * bounding box) along k, each vertex turned by an angle growing linearly
 * with its coordinate along k, from 0 at the mesh's lowest to d at its
 * highest. The morph's far pose without a positions file. 3D meshes only.
 */
static bg_status twist_target(parser_t *p, const cJSON *spec, double *out)
{
    static const char *const keys[] = {"twist", NULL};
    static const char *const twist_keys[] = {"axis", "degrees", "center", NULL};
    const bg_mesh_t *mesh = p->scene->mesh;
    bg_status st = check_keys(p, spec, "task.target", keys);
    const cJSON *twist = member(spec, "twist");
    if (st == BG_OK && !twist)
        st =
            fail(p, BG_ERR_INVALID, "task.target", "expected a positions file or {\"twist\": ...}");
    if (st == BG_OK)
        st = expect_object(p, twist, "task.target.twist");
    if (st == BG_OK)
        st = check_keys(p, twist, "task.target.twist", twist_keys);
    if (st != BG_OK)
        return st;
    if (p->dim != 3)
        return fail(p, BG_ERR_INVALID, "task.target.twist", "a twist needs a 3D mesh");
    double k[3] = {0, 0, 0}, center[3], degrees = 0.0;
    if (!member(twist, "axis") || !member(twist, "degrees"))
        return fail(p, BG_ERR_INVALID, "task.target.twist", "needs 'axis' and 'degrees'");
    st = read_vector(p, member(twist, "axis"), "task.target.twist.axis", 3, k);
    if (st == BG_OK)
        st = read_number(p, member(twist, "degrees"), "task.target.twist.degrees", &degrees);
    if (st != BG_OK)
        return st;
    const double norm = sqrt(k[0] * k[0] + k[1] * k[1] + k[2] * k[2]);
    if (!(norm > 0.0) || !isfinite(norm))
        return fail(p, BG_ERR_INVALID, "task.target.twist.axis",
                    "the axis must be a nonzero vector");
    for (int c = 0; c < 3; c++) {
        k[c] /= norm;
        center[c] = 0.5 * (p->lo[c] + p->hi[c]);
    }
    if (member(twist, "center")) {
        st = read_vector(p, member(twist, "center"), "task.target.twist.center", 3, center);
        if (st != BG_OK)
            return st;
    }
    double lo = INFINITY, hi = -INFINITY;
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *x = mesh->x + 3 * (size_t)v;
        const double along = k[0] * x[0] + k[1] * x[1] + k[2] * x[2];
        lo = fmin(lo, along);
        hi = fmax(hi, along);
    }
    if (!(hi > lo))
        return fail(p, BG_ERR_INVALID, "task.target.twist.axis",
                    "the mesh has no length along the axis");
    const double full = degrees * PI_VALUE / (FULL_TURN_DEGREES / 2);
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *x = mesh->x + 3 * (size_t)v;
        double d[3] = {x[0] - center[0], x[1] - center[1], x[2] - center[2]};
        const double along = k[0] * x[0] + k[1] * x[1] + k[2] * x[2];
        const double angle = full * (along - lo) / (hi - lo);
        const double c = cos(angle), s = sin(angle), kd = k[0] * d[0] + k[1] * d[1] + k[2] * d[2];
        const double kxd[3] = {k[1] * d[2] - k[2] * d[1], k[2] * d[0] - k[0] * d[2],
                               k[0] * d[1] - k[1] * d[0]};
        /* Rodrigues: R d = c d + s (k × d) + (1 − c)(k·d) k. */
        for (int r = 0; r < 3; r++)
            out[3 * (size_t)v + r] = center[r] + c * d[r] + s * kxd[r] + (1.0 - c) * kd * k[r];
    }
    return BG_OK;
}

static bg_status read_all_positions(parser_t *p, const cJSON *item, const char *field, double *out)
{
    const char *relative = NULL;
    bg_status st = read_string(p, item, field, &relative);
    return st == BG_OK ? read_positions_file(p, field, relative, out) : st;
}

static bg_status parse_initial(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"scale", "positions", "random", NULL};
    static const char *const random_keys[] = {"seed", "extent", NULL};
    bg_scene_t *s = p->scene;
    const int d = p->dim;
    const int32_t nv = s->mesh->nv;
    const size_t n = (size_t)nv * d;
    bg_status st = BG_OK;
    int moving = 0;
    for (int32_t h = 0; h < s->handle_count; h++)
        moving |= s->motions[h].kind != BG_MOTION_FIXED;
    const int interpolate = (!item && moving && s->task == BG_TASK_STATIC) ||
                            (cJSON_IsString(item) && strcmp(item->valuestring, "interpolate") == 0);
    if (interpolate) {
        /* The harmonic guess is a solve: bg_prepare_scene computes it. */
        s->initial_kind = BG_INITIAL_INTERPOLATE;
        memcpy(s->initial, s->mesh->x, n * sizeof *s->initial);
    } else if (!item || (cJSON_IsString(item) && strcmp(item->valuestring, "rest") == 0)) {
        s->initial_kind = BG_INITIAL_REST;
        memcpy(s->initial, s->mesh->x, n * sizeof *s->initial);
    } else {
        s->initial_kind = BG_INITIAL_GIVEN;
        if (cJSON_IsString(item))
            return fail(p, BG_ERR_INVALID, "initial",
                        "unknown initial state '%s' (expected \"rest\", \"interpolate\" or an "
                        "object)",
                        item->valuestring);
        st = expect_object(p, item, "initial");
        if (st == BG_OK)
            st = check_keys(p, item, "initial", keys);
        if (st != BG_OK)
            return st;
        if (cJSON_GetArraySize(item) != 1)
            return fail(p, BG_ERR_INVALID, "initial",
                        "give exactly one of scale, positions, random");
        if (member(item, "scale")) {
            double scale = 0.0, centroid[3] = {0, 0, 0};
            st = read_number(p, member(item, "scale"), "initial.scale", &scale);
            if (st != BG_OK)
                return st;
            if (scale == 0.0)
                return fail(p, BG_ERR_INVALID, "initial.scale", "must be nonzero");
            for (int32_t v = 0; v < nv; v++)
                for (int c = 0; c < d; c++)
                    centroid[c] += s->mesh->x[(size_t)v * d + c] / nv;
            for (int32_t v = 0; v < nv; v++)
                for (int c = 0; c < d; c++) {
                    size_t k = (size_t)v * d + c;
                    s->initial[k] = centroid[c] + scale * (s->mesh->x[k] - centroid[c]);
                }
        } else if (member(item, "positions")) {
            st = read_all_positions(p, member(item, "positions"), "initial.positions", s->initial);
            if (st != BG_OK)
                return st;
        } else {
            const cJSON *random = member(item, "random");
            st = expect_object(p, random, "initial.random");
            if (st == BG_OK)
                st = check_keys(p, random, "initial.random", random_keys);
            if (st != BG_OK)
                return st;
            int64_t seed = 0;
            double extent = 1.0;
            if (!member(random, "seed"))
                return fail(p, BG_ERR_INVALID, "initial.random.seed", "missing (required)");
            st = read_integer(p, member(random, "seed"), "initial.random.seed", 0.0,
                              MAX_EXACT_INTEGER, &seed);
            if (st != BG_OK)
                return st;
            if (member(random, "extent")) {
                st = read_number(p, member(random, "extent"), "initial.random.extent", &extent);
                if (st != BG_OK)
                    return st;
                if (!(extent > 0.0))
                    return fail(p, BG_ERR_INVALID, "initial.random.extent",
                                "must be positive, got %g", extent);
            }
            uint64_t state = (uint64_t)seed;
            for (size_t k = 0; k < n; k++) {
                int c = (int)(k % (size_t)d);
                double mid = 0.5 * (p->lo[c] + p->hi[c]), half = 0.5 * (p->hi[c] - p->lo[c]);
                double u = (double)(splitmix64(&state) >> 11) * TWO_POW_MINUS_53;
                s->initial[k] = mid + extent * half * (2.0 * u - 1.0);
            }
        }
    }
    for (size_t k = 0; k < n; k++)
        if (s->constrained[k])
            s->initial[k] = s->target[k];
    return BG_OK;
}

static bg_status parse_task(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"kind",    "dt",           "steps",   "output_every",
                                       "damping", "energy_limit", "target",  "frames",
                                       "alpha",   "beta",         "barrier", NULL};
    bg_scene_t *s = p->scene;
    s->task = BG_TASK_STATIC;
    if (!item)
        return BG_OK;
    bg_status st = expect_object(p, item, "task");
    if (st == BG_OK)
        st = check_keys(p, item, "task", keys);
    if (st != BG_OK || !member(item, "kind"))
        return st;
    const char *kind = NULL;
    st = read_string(p, member(item, "kind"), "task.kind", &kind);
    if (st != BG_OK)
        return st;
    if (strcmp(kind, "static") == 0) {
        static const char *const static_keys[] = {"kind", NULL};
        return check_keys(p, item, "task", static_keys);
    }
    if (strcmp(kind, "surface-edit") == 0) {
        static const char *const edit_keys[] = {"kind", NULL};
        st = check_keys(p, item, "task", edit_keys);
        if (st == BG_OK)
            s->task = BG_TASK_SURFACE_EDIT;
        return st;
    }
    if (strcmp(kind, "parameterize") == 0) {
        static const char *const param_keys[] = {"kind", "alpha", "beta", "barrier", NULL};
        st = check_keys(p, item, "task", param_keys);
        if (st != BG_OK)
            return st;
        s->task = BG_TASK_PARAMETERIZE;
        s->alpha = s->beta = 1.0;
        s->barrier = 1.0;
        if (member(item, "barrier")) {
            st = read_number(p, member(item, "barrier"), "task.barrier", &s->barrier);
            if (st != BG_OK)
                return st;
            if (!(s->barrier >= 0.0))
                return fail(p, BG_ERR_INVALID, "task.barrier", "must be >= 0, got %g", s->barrier);
        }
        if (member(item, "alpha"))
            st = read_number(p, member(item, "alpha"), "task.alpha", &s->alpha);
        if (st == BG_OK && member(item, "beta"))
            st = read_number(p, member(item, "beta"), "task.beta", &s->beta);
        if (st != BG_OK)
            return st;
        if (!(s->alpha >= 0.0) || !(s->beta > 0.0))
            return fail(p, BG_ERR_INVALID, "task", "alpha = %g must be >= 0 and beta = %g positive",
                        s->alpha, s->beta);
        return BG_OK;
    }
    if (strcmp(kind, "morph") == 0) {
        static const char *const morph_keys[] = {"kind", "target", "frames", NULL};
        st = check_keys(p, item, "task", morph_keys);
        if (st != BG_OK)
            return st;
        s->task = BG_TASK_MORPH;
        p->morph_target = member(item, "target");
        if (!p->morph_target)
            return fail(p, BG_ERR_INVALID, "task.target",
                        "missing (a positions file or {\"twist\": ...})");
        if (!cJSON_IsString(p->morph_target) && !cJSON_IsObject(p->morph_target))
            return fail(p, BG_ERR_INVALID, "task.target",
                        "expected a positions file or {\"twist\": ...}, got %s",
                        json_type_name(p->morph_target));
        int64_t frames = DEFAULT_MORPH_FRAMES;
        if (member(item, "frames")) {
            st = read_integer(p, member(item, "frames"), "task.frames", 2.0, (double)MAX_STEPS,
                              &frames);
            if (st != BG_OK)
                return st;
        }
        s->morph_frames = (int)frames;
        return BG_OK;
    }
    if (strcmp(kind, "dynamic") != 0)
        return fail(p, BG_ERR_UNSUPPORTED, "task.kind",
                    "task kind '%s' is not supported (supported: static, dynamic, morph, "
                    "parameterize, surface-edit)",
                    kind);
    static const char *const dynamic_keys[] = {"kind",    "dt",           "steps", "output_every",
                                               "damping", "energy_limit", NULL};
    st = check_keys(p, item, "task", dynamic_keys);
    if (st != BG_OK)
        return st;
    s->task = BG_TASK_DYNAMIC;
    bg_dynamic_task_t *d = &s->dynamic;
    if (!member(item, "dt"))
        return fail(p, BG_ERR_INVALID, "task.dt", "missing (required for a dynamic task)");
    if (!member(item, "steps"))
        return fail(p, BG_ERR_INVALID, "task.steps", "missing (required for a dynamic task)");
    st = read_number(p, member(item, "dt"), "task.dt", &d->dt);
    if (st != BG_OK)
        return st;
    if (!(d->dt > 0.0))
        return fail(p, BG_ERR_INVALID, "task.dt", "must be positive, got %g", d->dt);
    int64_t steps = 0, every = 0;
    st = read_integer(p, member(item, "steps"), "task.steps", 1.0, (double)MAX_STEPS, &steps);
    if (st != BG_OK)
        return st;
    d->steps = (int)steps;
    d->output_every = d->steps / DEFAULT_FRAMES > 0 ? d->steps / DEFAULT_FRAMES : 1;
    if (member(item, "output_every")) {
        st = read_integer(p, member(item, "output_every"), "task.output_every", 1.0,
                          (double)MAX_STEPS, &every);
        if (st != BG_OK)
            return st;
        d->output_every = (int)every;
    }
    if (member(item, "damping")) {
        st = read_number(p, member(item, "damping"), "task.damping", &d->damping);
        if (st != BG_OK)
            return st;
        if (!(d->damping >= 0.0))
            return fail(p, BG_ERR_INVALID, "task.damping", "must be >= 0, got %g", d->damping);
    }
    d->energy_limit = 1;
    if (member(item, "energy_limit") &&
        (st = read_bool(p, member(item, "energy_limit"), "task.energy_limit", &d->energy_limit)) !=
            BG_OK)
        return st;
    return BG_OK;
}

/* "velocity": {"linear": [..], "angular": [3] (planar: a number), "center": [..]}:
 * v(x) = linear + ω × (x − center), center defaulting to the centroid. */
static bg_status parse_velocity(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"linear", "angular", "center", NULL};
    bg_scene_t *s = p->scene;
    if (!item)
        return BG_OK;
    if (s->task != BG_TASK_DYNAMIC)
        return fail(p, BG_ERR_INVALID, "velocity", "an initial velocity needs a dynamic task");
    bg_status st = expect_object(p, item, "velocity");
    if (st == BG_OK)
        st = check_keys(p, item, "velocity", keys);
    if (st != BG_OK)
        return st;
    const int d = p->dim;
    const int32_t nv = s->mesh->nv;
    double linear[3] = {0, 0, 0}, omega[3] = {0, 0, 0}, center[3] = {0, 0, 0};
    if (member(item, "linear")) {
        st = read_vector(p, member(item, "linear"), "velocity.linear", d, linear);
        if (st != BG_OK)
            return st;
    }
    if (member(item, "angular")) {
        if (d == 2)
            st = read_number(p, member(item, "angular"), "velocity.angular", &omega[2]);
        else
            st = read_vector(p, member(item, "angular"), "velocity.angular", 3, omega);
        if (st != BG_OK)
            return st;
    }
    if (member(item, "center")) {
        st = read_vector(p, member(item, "center"), "velocity.center", d, center);
        if (st != BG_OK)
            return st;
    } else {
        for (int32_t v = 0; v < nv; v++)
            for (int c = 0; c < d; c++)
                center[c] += s->mesh->x[(size_t)v * d + c] / nv;
    }
    s->velocity = malloc(((size_t)nv * d + 1) * sizeof *s->velocity);
    if (!s->velocity)
        return fail(p, BG_ERR_NOMEM, "velocity", "out of memory");
    for (int32_t v = 0; v < nv; v++) {
        double r[3] = {0, 0, 0};
        for (int c = 0; c < d; c++)
            r[c] = s->mesh->x[(size_t)v * d + c] - center[c];
        const double w[3] = {omega[1] * r[2] - omega[2] * r[1], omega[2] * r[0] - omega[0] * r[2],
                             omega[0] * r[1] - omega[1] * r[0]};
        for (int c = 0; c < d; c++)
            s->velocity[(size_t)v * d + c] = linear[c] + w[c];
    }
    return BG_OK;
}

static bg_status parse_solver(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"method",       "tolerance", "max_iterations",
                                       "continuation", "inner",     NULL};
    bg_scene_t *s = p->scene;
    const int dynamic = s->task == BG_TASK_DYNAMIC;
    s->method = dynamic                           ? BG_METHOD_VARIATIONAL
                : s->task == BG_TASK_SURFACE_EDIT ? BG_METHOD_LOCAL_GLOBAL
                                                  : BG_METHOD_NEWTON;
    s->inner = BG_METHOD_NEWTON;
    s->tolerance = BG_SCENE_DEFAULT_TOLERANCE;
    s->max_iterations = BG_SCENE_DEFAULT_MAX_ITERATIONS;
    if (!item)
        return BG_OK;
    bg_status st = expect_object(p, item, "solver");
    if (st == BG_OK)
        st = check_keys(p, item, "solver", keys);
    if (st != BG_OK)
        return st;
    if (member(item, "method")) {
        const char *name = NULL;
        bg_error_t inner = BG_ERROR_INIT;
        st = read_string(p, member(item, "method"), "solver.method", &name);
        if (st != BG_OK)
            return st;
        if (bg_method_parse(name, &s->method, &inner) != BG_OK)
            return relay(p, "solver.method", &inner);
        if (bg_method_is_dynamic(s->method) != dynamic)
            return fail(p, BG_ERR_INVALID, "solver.method", "'%s' does not fit a %s task (use %s)",
                        name, dynamic ? "dynamic" : "static",
                        dynamic ? "variational or backward-euler"
                                : "newton, local-global or quasi-newton");
    }
    if (member(item, "inner")) {
        /* Only a time step has an inner solve: a static scene chooses its
         * solver with solver.method, and an inner method there would be a
         * setting that silently does nothing. */
        const char *name = NULL;
        if (!dynamic)
            return fail(p, BG_ERR_INVALID, "solver.inner",
                        "only a dynamic task has an inner solve (this is a %s task: choose its "
                        "solver with solver.method)",
                        s->task == BG_TASK_MORPH          ? "morph"
                        : s->task == BG_TASK_PARAMETERIZE ? "parameterize"
                        : s->task == BG_TASK_SURFACE_EDIT ? "surface-edit"
                                                          : "static");
        if ((st = read_string(p, member(item, "inner"), "solver.inner", &name)) != BG_OK)
            return st;
        if (strcmp(name, "newton") == 0)
            s->inner = BG_METHOD_NEWTON;
        else if (strcmp(name, "quasi-newton") == 0)
            s->inner = BG_METHOD_QUASI_NEWTON;
        else
            return fail(p, BG_ERR_INVALID, "solver.inner",
                        "unknown inner solve '%s' (expected newton or quasi-newton)", name);
    }
    if (member(item, "continuation")) {
        int on = 1;
        if ((st = read_bool(p, member(item, "continuation"), "solver.continuation", &on)) != BG_OK)
            return st;
        s->continuation_off = !on;
    }
    if (member(item, "tolerance")) {
        st = read_number(p, member(item, "tolerance"), "solver.tolerance", &s->tolerance);
        if (st != BG_OK)
            return st;
        if (!(s->tolerance > 0.0 && s->tolerance < 1.0))
            return fail(p, BG_ERR_INVALID, "solver.tolerance", "must be in (0, 1), got %g",
                        s->tolerance);
    }
    const cJSON *cap = member(item, "max_iterations");
    if (cJSON_IsObject(cap)) {
        /* One cap per method: Newton and local/global iterations differ in
         * cost by orders of magnitude, so one number cannot fit both. */
        static const char *const methods[] = {"newton",         "local-global", "variational",
                                              "backward-euler", "quasi-newton", NULL};
        st = check_keys(p, cap, "solver.max_iterations", methods);
        for (const cJSON *m = cap->child; st == BG_OK && m; m = m->next) {
            char field[FIELD_MAX];
            field_key(field, "solver.max_iterations", m->string);
            bg_method method = BG_METHOD_NEWTON;
            int64_t n = 0;
            st = bg_method_parse(m->string, &method, NULL);
            if (st == BG_OK)
                st = read_integer(p, m, field, 1.0, (double)MAX_ITERATIONS_LIMIT, &n);
            if (st == BG_OK)
                s->method_max_iterations[method] = (int)n;
        }
        if (st == BG_OK && s->method_max_iterations[s->method] > 0)
            s->max_iterations = s->method_max_iterations[s->method];
        return st;
    }
    if (cap) {
        int64_t n = 0;
        st = read_integer(p, cap, "solver.max_iterations", 1.0, (double)MAX_ITERATIONS_LIMIT, &n);
        if (st != BG_OK)
            return st;
        s->max_iterations = (int)n;
    }
    return BG_OK;
}

int bg_scene_max_iterations(const bg_scene_t *scene, bg_method method)
{
    const int cap = (int)method >= 0 && (int)method < BG_METHOD_COUNT
                        ? scene->method_max_iterations[method]
                        : 0;
    return cap > 0 ? cap : scene->max_iterations;
}

static bg_status reference_affine(parser_t *p, const cJSON *spec, double *out)
{
    static const char *const keys[] = {"matrix", "translation", NULL};
    const int d = p->dim;
    const bg_mesh_t *mesh = p->scene->mesh;
    bg_status st = expect_object(p, spec, "reference.affine");
    if (st == BG_OK)
        st = check_keys(p, spec, "reference.affine", keys);
    if (st != BG_OK)
        return st;
    double a[3][3] = {{0}}, t[3] = {0, 0, 0};
    const cJSON *matrix = member(spec, "matrix");
    if (!cJSON_IsArray(matrix) || cJSON_GetArraySize(matrix) != d)
        return fail(p, BG_ERR_INVALID, "reference.affine.matrix", "expected %d rows of %d numbers",
                    d, d);
    int r = 0;
    for (const cJSON *row = matrix->child; row; row = row->next, r++) {
        char sub[FIELD_MAX];
        field_index(sub, "reference.affine.matrix", r);
        st = read_vector(p, row, sub, d, a[r]);
        if (st != BG_OK)
            return st;
    }
    if (member(spec, "translation")) {
        st = read_vector(p, member(spec, "translation"), "reference.affine.translation", d, t);
        if (st != BG_OK)
            return st;
    }
    for (int32_t v = 0; v < mesh->nv; v++) {
        const double *pv = mesh->x + (size_t)v * d;
        for (int i = 0; i < d; i++) {
            double value = t[i];
            for (int j = 0; j < d; j++)
                value += a[i][j] * pv[j];
            out[(size_t)v * d + i] = value;
        }
    }
    return BG_OK;
}

/*
 * The exact equilibrium of a bar stretched by s along one axis with free
 * lateral faces: F = diag(s, t, t) (3D) or diag(s, t) (plane) with the
 * lateral stress 2μ(t − 1) + λ(tr F − n) = 0, i.e. t − 1 = −ν (s − 1).
 */
static bg_status reference_uniaxial(parser_t *p, const cJSON *spec, double *out)
{
    static const char *const keys[] = {"axis", "stretch", "origin", NULL};
    const int d = p->dim;
    const bg_mesh_t *mesh = p->scene->mesh;
    const bg_material_t *m = &p->scene->material;
    bg_status st = expect_object(p, spec, "reference.uniaxial");
    if (st == BG_OK)
        st = check_keys(p, spec, "reference.uniaxial", keys);
    if (st != BG_OK)
        return st;
    const char *axis_name = NULL;
    st = read_string(p, member(spec, "axis"), "reference.uniaxial.axis", &axis_name);
    if (st != BG_OK)
        return st;
    int axis = -1;
    for (int c = 0; c < d; c++)
        if (axis_name[0] == AXIS_NAMES[c] && axis_name[1] == '\0')
            axis = c;
    if (axis < 0)
        return fail(p, BG_ERR_INVALID, "reference.uniaxial.axis",
                    "'%s' is not an axis of this %dD mesh", axis_name, d);
    double s = 0.0, origin[3] = {0, 0, 0};
    if (!member(spec, "stretch"))
        return fail(p, BG_ERR_INVALID, "reference.uniaxial.stretch", "missing (required)");
    st = read_number(p, member(spec, "stretch"), "reference.uniaxial.stretch", &s);
    if (st != BG_OK)
        return st;
    if (!(s > 0.0))
        return fail(p, BG_ERR_INVALID, "reference.uniaxial.stretch", "must be positive, got %g", s);
    if (member(spec, "origin")) {
        st = read_vector(p, member(spec, "origin"), "reference.uniaxial.origin", d, origin);
        if (st != BG_OK)
            return st;
    }
    double nu =
        d == 3 ? m->lambda / (2.0 * (m->lambda + m->mu)) : m->lambda / (2.0 * m->mu + m->lambda);
    double t = 1.0 - nu * (s - 1.0);
    if (!(t > 0.0))
        return fail(p, BG_ERR_INVALID, "reference.uniaxial.stretch",
                    "stretch %g gives a lateral factor %g <= 0 (Poisson ratio %g)", s, t, nu);
    for (int32_t v = 0; v < mesh->nv; v++)
        for (int c = 0; c < d; c++) {
            size_t k = (size_t)v * d + c;
            out[k] = origin[c] + (c == axis ? s : t) * (mesh->x[k] - origin[c]);
        }
    return BG_OK;
}

static bg_status parse_reference(parser_t *p, const cJSON *item)
{
    static const char *const keys[] = {"positions", "affine", "uniaxial", NULL};
    bg_scene_t *s = p->scene;
    s->reference_kind = BG_REFERENCE_NONE;
    if (!item)
        return BG_OK;
    if (cJSON_IsString(item)) {
        if (strcmp(item->valuestring, "newton") != 0)
            return fail(p, BG_ERR_INVALID, "reference",
                        "unknown reference '%s' (expected \"newton\" or an object)",
                        item->valuestring);
        s->reference_kind = BG_REFERENCE_NEWTON;
        return BG_OK;
    }
    bg_status st = expect_object(p, item, "reference");
    if (st == BG_OK)
        st = check_keys(p, item, "reference", keys);
    if (st != BG_OK)
        return st;
    if (cJSON_GetArraySize(item) != 1)
        return fail(p, BG_ERR_INVALID, "reference",
                    "give exactly one of positions, affine, uniaxial (or \"newton\")");
    s->reference = malloc(((size_t)s->mesh->nv * p->dim + 1) * sizeof *s->reference);
    if (!s->reference)
        return fail(p, BG_ERR_NOMEM, "reference", "out of memory");
    if (member(item, "positions"))
        st = read_all_positions(p, member(item, "positions"), "reference.positions", s->reference);
    else if (member(item, "affine"))
        st = reference_affine(p, member(item, "affine"), s->reference);
    else
        st = reference_uniaxial(p, member(item, "uniaxial"), s->reference);
    if (st != BG_OK)
        return st;
    s->reference_kind = BG_REFERENCE_POSITIONS;
    return BG_OK;
}

/* ------------------------------------------------------------------ scene */

static bg_status parse_root(parser_t *p, const cJSON *root)
{
    static const char *const keys[] = {"name",    "description", "mesh",     "material",
                                       "gravity", "handles",     "initial",  "task",
                                       "solver",  "reference",   "velocity", NULL};
    bg_scene_t *s = p->scene;
    if (!cJSON_IsObject(root))
        return fail(p, BG_ERR_INVALID, NULL, "a scene is a JSON object, got %s",
                    json_type_name(root));
    bg_status st = check_keys(p, root, "", keys);
    if (st != BG_OK)
        return st;
    const char *text = NULL;
    if (member(root, "description")) {
        st = read_string(p, member(root, "description"), "description", &text);
        if (st != BG_OK)
            return st;
    }
    if (member(root, "name")) {
        st = read_string(p, member(root, "name"), "name", &text);
        if (st != BG_OK)
            return st;
        if (!text[0])
            return fail(p, BG_ERR_INVALID, "name", "must not be empty");
        s->name = copy_string(text);
    } else {
        s->name = strcmp(p->file, MEMORY_NAME) == 0 ? copy_string(MEMORY_STEM) : stem_of(p->file);
    }
    if (!s->name)
        return fail(p, BG_ERR_NOMEM, "name", "out of memory");
    /* Everything that does not depend on the mesh first — the task (an
     * unsupported kind fails before any mesh is read), the solver, the
     * material's values, the members a task does not use — so that a
     * malformed scene is refused before any mesh is generated or read;
     * then the mesh, whose dimension every later field depends on. */
    static const char *const unused_param[] = {"material",  "gravity",  "handles", "initial",
                                               "reference", "velocity", NULL};
    static const char *const unused_surface[] = {"material", "gravity", "velocity", NULL};
    st = parse_task(p, member(root, "task"));
    if (st == BG_OK)
        st = parse_solver(p, member(root, "solver"));
    const char *const *unused = s->task == BG_TASK_PARAMETERIZE    ? unused_param
                                : s->task == BG_TASK_SURFACE_EDIT ? unused_surface
                                                                  : NULL;
    for (int i = 0; st == BG_OK && unused && unused[i]; i++)
        if (member(root, unused[i]))
            return fail(p, BG_ERR_INVALID, unused[i], "not used by a %s task",
                        s->task == BG_TASK_PARAMETERIZE ? "parameterize" : "surface-edit");
    if (st == BG_OK && !unused)
        st = parse_material(p, member(root, "material"));
    if (st == BG_OK)
        st = parse_mesh(p, member(root, "mesh"));
    if (st != BG_OK)
        return st;
    const size_t n = (size_t)s->mesh->nv * p->dim;
    s->constrained = calloc(n + 1, sizeof *s->constrained);
    s->target = malloc((n + 1) * sizeof *s->target);
    s->initial = malloc((n + 1) * sizeof *s->initial);
    if (!s->constrained || !s->target || !s->initial)
        return fail(p, BG_ERR_NOMEM, NULL, "out of memory for %d vertices", (int)s->mesh->nv);
    memcpy(s->target, s->mesh->x, n * sizeof *s->target);
    if (s->task == BG_TASK_PARAMETERIZE) {
        /* The material comes from alpha and beta, the rigid modes are
         * removed by the setup, the start is a Tutte embedding. */
        st = bg_mesh_check_disk(s->mesh, s->path, p->err);
        if (st == BG_OK)
            s->mesh_format = BG_FORMAT_OBJ;
        return st;
    }
    if (s->task == BG_TASK_SURFACE_EDIT) {
        /* The spokes-and-rims energy has no material parameters. */
        s->material.mu = 1.0;
        s->material.density = 1.0;
    } else {
        st = finish_material(p);
    }
    if (st == BG_OK)
        st = parse_gravity(p, member(root, "gravity"));
    if (st == BG_OK)
        st = parse_handles(p, member(root, "handles"));
    if (st == BG_OK)
        st = parse_initial(p, member(root, "initial"));
    if (st == BG_OK && s->task == BG_TASK_MORPH) {
        s->morph_target = malloc((n + 1) * sizeof *s->morph_target);
        if (!s->morph_target)
            return fail(p, BG_ERR_NOMEM, "task.target", "out of memory");
        st = cJSON_IsString(p->morph_target)
                 ? read_positions_file(p, "task.target", p->morph_target->valuestring,
                                       s->morph_target)
                 : twist_target(p, p->morph_target, s->morph_target);
    }
    if (st == BG_OK)
        st = parse_velocity(p, member(root, "velocity"));
    if (st == BG_OK)
        st = parse_reference(p, member(root, "reference"));
    return st;
}

bg_status bg_scene_parse_with(const char *json, size_t length, const char *path,
                              const bg_scene_options_t *options, bg_scene_t **out, bg_error_t *err)
{
    *out = NULL;
    parser_t p = {0};
    p.file = options && options->display_name ? options->display_name : path ? path : MEMORY_NAME;
    p.err = err;
    p.confined = options && options->confined;
    p.search_path = options && !p.confined ? options->search_path : NULL;
    p.max_vertices =
        options && options->max_vertices > 0 ? options->max_vertices : BG_MESH_MAX_VERTICES;
    p.max_elements =
        options && options->max_elements > 0 ? options->max_elements : BG_MESH_MAX_ELEMENTS;
    p.max_work = options && options->max_work > 0 ? options->max_work : 0.0;
    p.material_form = -1;
    cJSON *root = NULL;
    bg_status st = BG_OK;
    if (length > BG_SCENE_MAX_BYTES)
        return fail(&p, BG_ERR_LIMIT, NULL, "scene of %zu bytes exceeds the limit of %zu bytes",
                    length, BG_SCENE_MAX_BYTES);
    p.scene = calloc(1, sizeof *p.scene);
    p.dir = directory_of(path);
    if (!p.scene || !p.dir) {
        st = fail(&p, BG_ERR_NOMEM, NULL, "out of memory");
        goto out;
    }
    p.scene->path = copy_string(p.file);
    if (!p.scene->path) {
        st = fail(&p, BG_ERR_NOMEM, NULL, "out of memory");
        goto out;
    }
    /* Empty files, syntax errors (with line and column), trailing text
     * and repeated keys anywhere are rejected by bg_json. */
    st = bg_json_parse(json, length, p.file, &root, err);
    if (st != BG_OK)
        goto out;
    st = parse_root(&p, root);
out:
    cJSON_Delete(root);
    free(p.owner);
    free(p.flag);
    free(p.dir);
    if (st != BG_OK)
        bg_scene_destroy(&p.scene);
    *out = p.scene;
    return st;
}

bg_status bg_scene_load_with(const char *path, const bg_scene_options_t *options, bg_scene_t **out,
                             bg_error_t *err)
{
    *out = NULL;
    char *text = NULL;
    size_t length = 0;
    bg_status st = bg_file_read_all(path, BG_SCENE_MAX_BYTES, &text, &length, err);
    if (st != BG_OK)
        return st;
    st = bg_scene_parse_with(text, length, path, options, out, err);
    free(text);
    return st;
}

void bg_scene_destroy(bg_scene_t **scene)
{
    if (!scene || !*scene)
        return;
    bg_scene_t *s = *scene;
    free(s->path);
    free(s->name);
    free(s->mesh_source);
    bg_mesh_destroy(&s->mesh);
    free(s->constrained);
    free(s->target);
    free(s->initial);
    free(s->reference);
    free(s->velocity);
    free(s->morph_target);
    bg_mesh_destroy(&s->surface);
    free(s->rest_edges);
    for (int32_t h = 0; s->motions && h < s->handle_count; h++)
        free(s->motions[h].vertices);
    free(s->motions);
    free(s);
    *scene = NULL;
}

const char *bg_method_name(bg_method method)
{
    switch (method) {
    case BG_METHOD_NEWTON:
        return "newton";
    case BG_METHOD_LOCAL_GLOBAL:
        return "local-global";
    case BG_METHOD_VARIATIONAL:
        return "variational";
    case BG_METHOD_BACKWARD_EULER:
        return "backward-euler";
    case BG_METHOD_QUASI_NEWTON:
        return "quasi-newton";
    }
    return "unknown";
}

bg_status bg_method_parse(const char *name, bg_method *out, bg_error_t *err)
{
    for (int i = 0; i < BG_METHOD_COUNT; i++)
        if (name && strcmp(name, bg_method_name((bg_method)i)) == 0) {
            *out = (bg_method)i;
            return BG_OK;
        }
    return bg_error_set(err, BG_ERR_INVALID,
                        "unknown method '%s' (expected newton, local-global, quasi-newton, "
                        "variational or backward-euler)",
                        name ? name : "(null)");
}

int bg_method_is_dynamic(bg_method method)
{
    return method == BG_METHOD_VARIATIONAL || method == BG_METHOD_BACKWARD_EULER;
}

/* Rotation by angle about a unit axis (Rodrigues), row-major. */
static void axis_rotation(const double k[3], double angle, double R[9])
{
    const double c = cos(angle), s = sin(angle);
    const double K[9] = {0, -k[2], k[1], k[2], 0, -k[0], -k[1], k[0], 0};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            R[3 * i + j] = (i == j ? c : 0.0) + s * K[3 * i + j] + (1.0 - c) * k[i] * k[j];
}

void bg_motion_screw(const bg_scene_motion_t *mo, int d, double f, const double *x, double *out)
{
    double R[9];
    axis_rotation(mo->axis, f * mo->radians, R);
    for (int r = 0; r < d; r++) {
        double v = mo->center[r] + f * mo->translate[r];
        for (int c = 0; c < d; c++)
            v += R[3 * r + c] * (x[c] - mo->center[c]);
        out[r] = v;
    }
}

void bg_scene_targets_at(const bg_scene_t *s, double t, double *out)
{
    const bg_mesh_t *m = s->mesh;
    const int d = m->dim;
    const size_t n = (size_t)m->nv * d;
    memcpy(out, s->target, n * sizeof *out);
    for (int32_t h = 0; h < s->handle_count; h++) {
        const bg_scene_motion_t *mo = &s->motions[h];
        if (mo->duration <= 0.0 || mo->kind == BG_MOTION_FIXED)
            continue;
        const double f = t >= mo->duration ? 1.0 : t / mo->duration;
        for (int32_t i = 0; i < mo->count; i++) {
            const size_t k = (size_t)mo->vertices[i] * d;
            const double *x = m->x + k;
            double moved[3];
            if (mo->kind == BG_MOTION_RIGID)
                bg_motion_screw(mo, d, f, x, moved);
            else
                for (int r = 0; r < d; r++)
                    moved[r] = x[r] + f * (s->target[k + r] - x[r]);
            for (int r = 0; r < d; r++)
                if (s->constrained[k + r])
                    out[k + r] = moved[r];
        }
    }
}
