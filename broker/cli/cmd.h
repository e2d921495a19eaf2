/*
 * cmd — what every `biotgrid` subcommand shares: exit statuses and the
 * folders scenes look in for the files they name.
 */
#ifndef BG_CMD_H
#define BG_CMD_H

#include <signal.h>
#include <stddef.h>

/* Exit statuses of every subcommand. */
#define BG_EXIT_OK 0        /* did what was asked (solve: every run converged) */
#define BG_EXIT_FAILED 1    /* ran, but did not reach its goal (a report is still written) */
#define BG_EXIT_BAD_INPUT 2 /* bad input or usage, with a message naming what is wrong */

/* The environment variable holding ':'-separated mesh folders. */
#define BG_CMD_MESH_PATH_ENV "BIOTGRID_MESH_PATH"

/*
 * Appends `folder` (a --mesh-path value) to the ':'-separated list in buf;
 * -1 when it would not fit. The command-line folders come first, then
 * BIOTGRID_MESH_PATH (bg_cmd_mesh_path_finish).
 */
int bg_cmd_mesh_path_add(char *buf, size_t size, const char *folder);
/*
 * Appends BIOTGRID_MESH_PATH (if set), then the command's own mesh folder
 * (bg_cmd_mesh_folder), to buf; -1 when it would not fit.
 */
int bg_cmd_mesh_path_finish(char *buf, size_t size);

/* The meshes the build makes (and `cmake --install` installs), relative to
 * the folder above the executable's: the build tree has the installed
 * layout, so BUILD/share/... beside BUILD/bin/biotgrid as PREFIX/share/...
 * beside PREFIX/bin/biotgrid (broker/cli/CMakeLists.txt). */
#define BG_CMD_MESH_FOLDER "share/biotgrid/meshes"

/* The command's own mesh folder, "<executable's folder>/../share/biotgrid/meshes",
 * into buf; -1 when the executable's path is unknown or does not fit. */
int bg_cmd_mesh_folder(char *buf, size_t size);

/* The hint printed under a "file not found" error of a scene. */
#define BG_CMD_MESH_HINT                                                                           \
    "  The shipped scenes' meshes are made by the build from Debian's libcgal-demo and\n"          \
    "  tetgen into " BG_CMD_MESH_FOLDER " (see README.md, \"Meshes\"). For meshes of your\n"       \
    "  own, pass --mesh-path DIR or set " BG_CMD_MESH_PATH_ENV "=DIR.\n"

/* The local grid's state folder (`grid up` writes grid.json there): the
 * option's value when given (not NULL), else $BIOTGRID_GRID_DIR when set
 * and not empty, else out/grid. */
#define BG_CMD_GRID_DIR_ENV "BIOTGRID_GRID_DIR"
#define BG_CMD_GRID_DIR "out/grid"
const char *bg_cmd_grid_dir(const char *option);

/* mkdir -p (bg_file_make_directories): creates path and its missing parents (mode
 * 0755); -1 on failure (errno set). */
int bg_cmd_make_directories(const char *path);

/*
 * Daemons (agent, broker): call bg_cmd_stop_on_signals before any thread
 * is started. SIGTERM and SIGINT are then blocked in every thread (the
 * mask is inherited) and taken by one waiter thread that sets
 * bg_cmd_stop_requested: loops see it at their next poll timeout, and
 * bg_cmd_wait_for_stop returns. No signal handler runs, so a library that
 * swaps handlers meanwhile (METIS does) cannot hijack the signal.
 */
extern volatile sig_atomic_t bg_cmd_stop_requested;
void bg_cmd_stop_on_signals(void);
/*
 * Called first thing by a daemon's main: libraries start threads before
 * main (OpenBLAS's pool) with the mask the process was born with, and a
 * stop signal delivered to one of them would run whatever handler is in
 * place. Unless SIGTERM and SIGINT are blocked already, this blocks them
 * and execs the program (/proc/self/exe) with argv again, so that every thread of the
 * new image is born with them blocked. Returns when they were (or when
 * the exec failed).
 */
void bg_cmd_daemon_reexec(char **argv);
/* Sleeps until a stop signal has arrived. */
void bg_cmd_wait_for_stop(void);

/*
 * Writes line to path atomically (path.tmp, then rename), so a process
 * waiting for the file never reads half of it. Returns 0, or -1 with errno.
 */
int bg_cmd_write_ready_file(const char *path, const char *line);

#endif
