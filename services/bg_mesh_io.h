/*
 * bg_mesh_io — reading and writing meshes and per-vertex data files.
 *
 * Parsers are pure functions over (text, length): tests and fuzzers drive
 * them without files. `name` is used only in messages, which cite it with
 * the 1-based line number ("bunny.mesh:1234: ..."). Every parser rejects
 * truncated input, garbage, counts that disagree with the data, indices
 * out of range, NaN/Inf coordinates, and sizes over the BG_MESH_MAX_* caps;
 * a successful parse returns a mesh that has passed bg_mesh_validate
 * (degenerate elements rejected, negative elements reoriented).
 *
 * Formats:
 *   MEDIT .mesh  (ASCII, 1-based; Dimension 2 or 3; Vertices with a
 *                 reference; Triangles / Tetrahedra with a reference; a
 *                 file with Tetrahedra is a volume mesh, else triangles)
 *   OFF          (triangle surface; polygons are split into fans)
 *   OBJ          (v / f; 1-based and negative indices; f a/b/c, a//c,
 *                 a/b forms; vt, vn and other statements ignored)
 *   TetGen       (.node + .ele; either path may be given)
 *   Gmsh .msh    2.2 and 4.1 ASCII (tetrahedra if any, else triangles;
 *                 physical tags become element references)
 * Writers produce every format above plus VTK XML UnstructuredGrid .vtu.
 * Triangles whose z coordinates are all zero can be read as a planar mesh
 * with bg_mesh_to_planar.
 */
#ifndef BG_MESH_IO_H
#define BG_MESH_IO_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"
#include "bg_file.h" /* bg_file_read_all, for the readers' callers */
#include "bg_mesh.h"

/* Mesh files larger than this are refused before reading. */
#define BG_MESH_FILE_MAX_BYTES ((size_t)2 << 30)

typedef enum bg_mesh_format {
    BG_FORMAT_UNKNOWN = 0,
    BG_FORMAT_MEDIT,
    BG_FORMAT_OFF,
    BG_FORMAT_OBJ,
    BG_FORMAT_TETGEN,
    BG_FORMAT_GMSH22,
    BG_FORMAT_GMSH41,
    BG_FORMAT_VTU,
} bg_mesh_format;

/* Format from a file name's extension (.mesh .off .obj .node .ele .msh .vtu);
 * for .msh the version is read by the parser, so this returns GMSH41. */
bg_mesh_format bg_mesh_format_from_path(const char *path);

/* "mesh", "off", "obj", "node", "msh", "vtu" (no dot). */
const char *bg_mesh_format_extension(bg_mesh_format format);

/* "MEDIT", "OFF", ... for messages and reports. */
const char *bg_mesh_format_name(bg_mesh_format format);

/*
 * Parses text as the given format (GMSH22 and GMSH41 both accept either
 * version, read from $MeshFormat). TetGen needs two texts, so use
 * bg_mesh_parse_tetgen. Caller owns *out.
 */
bg_status bg_mesh_parse(bg_mesh_format format, const char *text, size_t length, const char *name,
                        bg_mesh_t **out, bg_error_t *err);

bg_status bg_mesh_parse_tetgen(const char *node_text, size_t node_length, const char *ele_text,
                               size_t ele_length, const char *name, bg_mesh_t **out,
                               bg_error_t *err);

/* Reads a mesh file, the format from its extension; *format (may be NULL)
 * receives the format found (GMSH22 or GMSH41 as the file says). */
bg_status bg_mesh_read(const char *path, bg_mesh_t **out, bg_mesh_format *format, bg_error_t *err);

/*
 * Writes mesh connectivity with positions x (nv*dim doubles; pass mesh->x
 * for the rest shape) in the given format. MEDIT writes vertex_ref and
 * element_ref; Gmsh writes element_ref as the physical tag. For TetGen the
 * path's extension is replaced by .node and .ele. Doubles are written with
 * 17 significant digits so a read-back is exact.
 */
bg_status bg_mesh_write(const bg_mesh_t *mesh, const double *x, bg_mesh_format format,
                        const char *path, bg_error_t *err);

/* A named array for VTU point or cell data: count*components doubles,
 * borrowed for the duration of the call. */
typedef struct bg_vtu_array {
    const char *name;
    int components;
    const double *values;
} bg_vtu_array_t;

/*
 * Writes a VTK XML UnstructuredGrid (ASCII) that ParaView opens: points at
 * x (planar meshes get z = 0), the cells, point data arrays (nv tuples
 * each) and cell data arrays (ne tuples each).
 */
bg_status bg_mesh_write_vtu(const bg_mesh_t *mesh, const double *x, const bg_vtu_array_t *point_data,
                            int point_arrays, const bg_vtu_array_t *cell_data, int cell_arrays,
                            const char *path, bg_error_t *err);

/* Reads back a .vtu written by bg_mesh_write_vtu (points and cells only). */
bg_status bg_mesh_parse_vtu(const char *text, size_t length, const char *name, bg_mesh_t **out,
                            bg_error_t *err);

/*
 * A planar copy of a triangle surface whose z coordinates are all zero (to
 * within 1e-12 of its extent); BG_ERR_INVALID naming the first vertex off
 * the plane otherwise. Caller owns *out.
 */
bg_status bg_mesh_to_planar(const bg_mesh_t *surface, bg_mesh_t **out, bg_error_t *err);

/*
 * Positions file: one vertex per line, `dim` numbers separated by blanks
 * (blank lines and lines starting with '#' skipped). Exactly nv lines are
 * required. Writes nv*dim doubles to out (caller-allocated).
 */
bg_status bg_positions_parse(const char *text, size_t length, const char *name, int32_t nv, int dim,
                             double *out, bg_error_t *err);
bg_status bg_positions_read(const char *path, int32_t nv, int dim, double *out, bg_error_t *err);

/*
 * Vertex selection file: either a libigl DMAT text file (header `cols rows`
 * with cols = 1, then one integer per vertex) giving a label per vertex
 * (nv values required), or a plain list of 0-based vertex indices, one or
 * more per line. Either way fills labels[nv] (caller-allocated): for DMAT
 * the file's values, for a list 1 for listed vertices and -1 otherwise.
 */
bg_status bg_selection_parse(const char *text, size_t length, const char *name, int32_t nv,
                             int32_t *labels, bg_error_t *err);
bg_status bg_selection_read(const char *path, int32_t nv, int32_t *labels, bg_error_t *err);

#endif
