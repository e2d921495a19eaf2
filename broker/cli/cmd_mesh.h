/*
 * cmd_mesh — `biotgrid mesh info|convert|simplify`: looking at a mesh file,
 * converting it between the formats the readers know, and simplifying a
 * triangle surface (what the build runs on Debian's public meshes before
 * tetgen fills them with tetrahedra).
 */
#ifndef BG_CMD_MESH_H
#define BG_CMD_MESH_H

/* The --help text, also `biotgrid help mesh` and the manual page. */
extern const char bg_cmd_mesh_usage[];

/*
 * biotgrid mesh info FILE | convert IN OUT | simplify IN OUT --vertices N;
 * argv[0] is "mesh". Returns 0, or 2 with a message naming the file (and
 * line or element) on bad input, 1 when a simplification stops short of
 * its target (the mesh reached is still written).
 */
int bg_cmd_mesh(int argc, char **argv);

#endif
