#include "cmd_mesh.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_mesh.h"
#include "bg_mesh_io.h"
#include "bg_mesh_simplify.h"
#include "cmd.h"

const char bg_cmd_mesh_usage[] =
    "usage: biotgrid mesh info FILE\n"
    "       biotgrid mesh convert IN OUT\n"
    "       biotgrid mesh simplify IN OUT --vertices N\n"
    "\n"
    "  info      kind, counts, bounds and total area or volume of a mesh file\n"
    "  convert   writes IN in the format of OUT's extension (.mesh .off .obj\n"
    "            .node/.ele .msh .vtu); TetGen output (x.1.node) reads as is\n"
    "  simplify  collapses edges of a triangle surface (quadric error metric)\n"
    "            until N vertices remain, keeping it a 2-manifold of the same\n"
    "            topology without folded triangles, its boundary in place\n"
    "\n"
    "Formats are told by the extension. Exit status: 0 done, 1 simplify stopped\n"
    "short of N (no collapse left that keeps the surface valid; the mesh reached\n"
    "is written), 2 bad input with a message naming the file and line or element.\n";

static int read_mesh(const char *path, bg_mesh_t **mesh)
{
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_format_from_path(path) == BG_FORMAT_UNKNOWN) {
        fprintf(stderr,
                "biotgrid mesh: %s: unknown format (expected .mesh .off .obj .node .ele "
                ".msh or .vtu)\n",
                path);
        return -1;
    }
    if (bg_mesh_read(path, mesh, NULL, &err) != BG_OK) {
        fprintf(stderr, "biotgrid mesh: %s\n", err.message);
        return -1;
    }
    return 0;
}

static int write_mesh(const bg_mesh_t *mesh, const char *path)
{
    bg_error_t err = BG_ERROR_INIT;
    const bg_mesh_format format = bg_mesh_format_from_path(path);
    bg_status st = BG_OK;
    if (format == BG_FORMAT_UNKNOWN) {
        fprintf(stderr,
                "biotgrid mesh: %s: unknown format (expected .mesh .off .obj .node .ele "
                ".msh or .vtu)\n",
                path);
        return -1;
    }
    st = format == BG_FORMAT_VTU ? bg_mesh_write_vtu(mesh, mesh->x, NULL, 0, NULL, 0, path, &err)
                                 : bg_mesh_write(mesh, mesh->x, format, path, &err);
    if (st != BG_OK) {
        fprintf(stderr, "biotgrid mesh: %s\n", err.message);
        return -1;
    }
    return 0;
}

static int info(const char *path)
{
    bg_mesh_t *mesh = NULL;
    if (read_mesh(path, &mesh) != 0)
        return BG_EXIT_BAD_INPUT;
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0}, total = 0.0, smallest = INFINITY;
    bg_mesh_bounds(mesh, lo, hi);
    for (int32_t e = 0; e < mesh->ne; e++) {
        const double m = fabs(bg_mesh_element_measure(mesh, mesh->x, e));
        total += m;
        smallest = fmin(smallest, m);
    }
    const bg_mesh_kind kind = bg_mesh_kind_of(mesh);
    printf("%s: %s, %d vertices, %d elements\n", path, bg_mesh_kind_name(kind), (int)mesh->nv,
           (int)mesh->ne);
    printf("  bounds   [%.9g, %.9g]", lo[0], hi[0]);
    for (int c = 1; c < mesh->dim; c++)
        printf(" x [%.9g, %.9g]", lo[c], hi[c]);
    printf("\n  %-8s %.9g (smallest element %.3g)\n", kind == BG_MESH_VOLUME ? "volume" : "area",
           total, smallest);
    bg_mesh_destroy(&mesh);
    return BG_EXIT_OK;
}

static int convert(const char *in, const char *out)
{
    bg_mesh_t *mesh = NULL;
    int status = BG_EXIT_BAD_INPUT;
    if (read_mesh(in, &mesh) == 0 && write_mesh(mesh, out) == 0) {
        printf("%s -> %s: %s, %d vertices, %d elements\n", in, out,
               bg_mesh_kind_name(bg_mesh_kind_of(mesh)), (int)mesh->nv, (int)mesh->ne);
        status = BG_EXIT_OK;
    }
    bg_mesh_destroy(&mesh);
    return status;
}

static int simplify(const char *in, const char *out, long long target)
{
    bg_mesh_t *mesh = NULL, *small = NULL;
    bg_error_t err = BG_ERROR_INIT;
    int status = BG_EXIT_BAD_INPUT;
    if (read_mesh(in, &mesh) != 0)
        goto out;
    const bg_simplify_options_t options = bg_simplify_defaults((int32_t)target);
    bg_simplify_result_t result;
    if (bg_mesh_simplify(mesh, &options, &small, &result, &err) != BG_OK) {
        fprintf(stderr, "biotgrid mesh simplify: %s\n", err.message);
        goto out;
    }
    if (write_mesh(small, out) != 0)
        goto out;
    printf("%s -> %s: %d -> %d vertices, %d -> %d triangles\n", in, out, (int)mesh->nv,
           (int)small->nv, (int)mesh->ne, (int)small->ne);
    if (!result.reached_target) {
        fprintf(stderr,
                "biotgrid mesh simplify: stopped at %d vertices, above the %lld asked: no "
                "collapse left keeps the surface valid\n",
                (int)small->nv, target);
        status = BG_EXIT_FAILED;
    } else {
        status = BG_EXIT_OK;
    }
out:
    bg_mesh_destroy(&small);
    bg_mesh_destroy(&mesh);
    return status;
}

int bg_cmd_mesh(int argc, char **argv)
{
    const char *operands[3] = {NULL, NULL, NULL};
    int count = 0;
    long long vertices = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(bg_cmd_mesh_usage, stdout);
            return BG_EXIT_OK;
        } else if (strcmp(a, "--vertices") == 0) {
            char *end = NULL;
            if (i + 1 == argc) {
                fputs("biotgrid mesh: --vertices needs a value\n", stderr);
                return BG_EXIT_BAD_INPUT;
            }
            vertices = strtoll(argv[++i], &end, 10);
            if (!end || *end || vertices < 4 || vertices > BG_MESH_MAX_VERTICES) {
                fprintf(stderr, "biotgrid mesh: --vertices '%s' must be an integer from 4 to %d\n",
                        argv[i], BG_MESH_MAX_VERTICES);
                return BG_EXIT_BAD_INPUT;
            }
        } else if (a[0] == '-' && a[1]) {
            fprintf(stderr, "biotgrid mesh: unknown option '%s' (see biotgrid mesh --help)\n", a);
            return BG_EXIT_BAD_INPUT;
        } else if (count == 3) {
            fprintf(stderr, "biotgrid mesh: too many operands ('%s')\n", a);
            return BG_EXIT_BAD_INPUT;
        } else {
            operands[count++] = a;
        }
    }
    const char *verb = operands[0];
    if (verb && strcmp(verb, "info") == 0 && count == 2 && !vertices)
        return info(operands[1]);
    if (verb && strcmp(verb, "convert") == 0 && count == 3 && !vertices)
        return convert(operands[1], operands[2]);
    if (verb && strcmp(verb, "simplify") == 0 && count == 3) {
        if (!vertices) {
            fputs("biotgrid mesh simplify: --vertices N is required\n", stderr);
            return BG_EXIT_BAD_INPUT;
        }
        return simplify(operands[1], operands[2], vertices);
    }
    fputs(bg_cmd_mesh_usage, stderr);
    return BG_EXIT_BAD_INPUT;
}
