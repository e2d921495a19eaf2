#include "bg_cli.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bg_dynamics.h"
#include "bg_mesh_io.h"
#include "bg_morph.h"
#include "bg_param.h"
#include "bg_surface_arap.h"
#include "bg_plan.h"
#include "bg_report.h"
#include "bg_scene.h"
#include "bg_static.h"

#define CLI_MAX_METHODS 4
#define CLI_TABLE_ROWS 24
/* The reference solve goes this far below the requested tolerance. */
#define CLI_REFERENCE_TOLERANCE 1e-13
#define CLI_REFERENCE_MAX_ITERATIONS 200

typedef struct cli_options {
    const char *scene_path;
    const char *out_dir;
    bg_method methods[CLI_MAX_METHODS];
    int method_count;
    double tolerance;      /* < 0: the scene's */
    int max_iterations;    /* < 0: the scene's */
    int quiet;
} cli_options_t;

typedef struct progress {
    int tty;
    int quiet;
} progress_t;

static void usage(FILE *out)
{
    fputs("usage: biotgrid solve SCENE.json [options]\n"
          "\n"
          "  --method newton|local-global   solver (default: the scene's, else newton)\n"
          "  --compare M1,M2                run several methods on the same scene\n"
          "  --tolerance T                  stop at relative gradient T (default 1e-8)\n"
          "  --max-iterations N             iteration cap (default 200)\n"
          "  --out DIR                      output directory (default out/<scene name>)\n"
          "  --quiet                        no per-iteration progress\n"
          "\n"
          "Writes DIR/report.json, DIR/result.vtu, DIR/result.<mesh format> and\n"
          "DIR/error-vs-time.svg. Exit status: 0 converged, 1 not converged, 2 bad input.\n",
          out);
}

int bg_cli_make_directories(const char *path)
{
    char buf[4096];
    size_t len = strlen(path);
    if (len == 0 || len >= sizeof buf)
        return -1;
    memcpy(buf, path, len + 1);
    for (size_t i = 1; i <= len; i++) {
        if (buf[i] == '/' || buf[i] == '\0') {
            char saved = buf[i];
            buf[i] = '\0';
            if (mkdir(buf, 0755) != 0 && errno != EEXIST)
                return -1;
            buf[i] = saved;
        }
    }
    struct stat st;
    return stat(path, &st) == 0 && S_ISDIR(st.st_mode) ? 0 : -1;
}

static int parse_methods(const char *list, cli_options_t *o)
{
    char buf[256];
    if (strlen(list) >= sizeof buf)
        return -1;
    strcpy(buf, list);
    o->method_count = 0;
    for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        bg_error_t err = BG_ERROR_INIT;
        if (o->method_count == CLI_MAX_METHODS) {
            fprintf(stderr, "biotgrid solve: at most %d methods in --compare\n", CLI_MAX_METHODS);
            return -1;
        }
        if (bg_method_parse(tok, &o->methods[o->method_count], &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: --compare: %s\n", err.message);
            return -1;
        }
        o->method_count++;
    }
    return o->method_count > 0 ? 0 : -1;
}

static int parse_args(int argc, char **argv, cli_options_t *o)
{
    memset(o, 0, sizeof *o);
    o->tolerance = -1.0;
    o->max_iterations = -1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *value = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            usage(stdout);
            return 1;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = 1;
        } else if (strcmp(a, "--method") == 0 || strcmp(a, "--compare") == 0 ||
                   strcmp(a, "--tolerance") == 0 || strcmp(a, "--max-iterations") == 0 ||
                   strcmp(a, "--out") == 0) {
            if (!value) {
                fprintf(stderr, "biotgrid solve: %s needs a value\n", a);
                return -1;
            }
            i++;
            char *end = NULL;
            if (strcmp(a, "--method") == 0) {
                if (strchr(value, ',')) {
                    fprintf(stderr, "biotgrid solve: --method takes one method; use --compare "
                                    "for several\n");
                    return -1;
                }
                if (parse_methods(value, o) != 0)
                    return -1;
            } else if (strcmp(a, "--compare") == 0) {
                if (parse_methods(value, o) != 0)
                    return -1;
            } else if (strcmp(a, "--tolerance") == 0) {
                o->tolerance = strtod(value, &end);
                if (!end || *end || !(o->tolerance > 0.0 && o->tolerance < 1.0)) {
                    fprintf(stderr, "biotgrid solve: --tolerance '%s' must be a number in (0, 1)\n",
                            value);
                    return -1;
                }
            } else if (strcmp(a, "--max-iterations") == 0) {
                long n = strtol(value, &end, 10);
                if (!end || *end || n < 1 || n > 1000000) {
                    fprintf(stderr, "biotgrid solve: --max-iterations '%s' must be an integer "
                                    "in 1..1000000\n", value);
                    return -1;
                }
                o->max_iterations = (int)n;
            } else {
                o->out_dir = value;
            }
        } else if (a[0] == '-') {
            fprintf(stderr, "biotgrid solve: unknown option '%s'\n", a);
            return -1;
        } else if (!o->scene_path) {
            o->scene_path = a;
        } else {
            fprintf(stderr, "biotgrid solve: one scene at a time ('%s' and '%s')\n",
                    o->scene_path, a);
            return -1;
        }
    }
    if (!o->scene_path) {
        usage(stderr);
        return -1;
    }
    return 0;
}

static void on_progress(void *ctx, bg_method method, const bg_trace_point_t *p)
{
    const progress_t *pr = ctx;
    if (pr->quiet)
        return;
    char error[32] = "-";
    if (isfinite(p->error))
        snprintf(error, sizeof error, "%.3e", p->error);
    if (pr->tty)
        fprintf(stderr, "\r\033[K%-12s iteration %4d  %8.3f s  rel.gradient %.3e  error %s",
                bg_method_name(method), p->iteration, p->seconds, p->relative_gradient, error);
    else
        fprintf(stderr, "%s iteration %d seconds %.4f energy %.15e relative_gradient %.3e error "
                        "%s\n",
                bg_method_name(method), p->iteration, p->seconds, p->energy,
                p->relative_gradient, error);
    fflush(stderr);
}

/* dir + "/" + name into buf; -1 if it does not fit. */
static int join_path(char *buf, size_t size, const char *dir, const char *name)
{
    const size_t a = strlen(dir), b = strlen(name);
    if (a + 1 + b + 1 > size)
        return -1;
    memcpy(buf, dir, a);
    buf[a] = '/';
    memcpy(buf + a + 1, name, b + 1);
    return 0;
}

/* Result files of the first run: result.vtu with displacement, the
 * constrained flag and ψ per element, and result.<input format> with the
 * constrained flag as the MEDIT vertex reference. */
static bg_status write_results(const char *dir, const bg_scene_t *scene,
                               const bg_solve_result_t *run, char *paths, size_t paths_size,
                               bg_error_t *err)
{
    const bg_mesh_t *mesh = scene->mesh;
    const int n = mesh->dim;
    bg_status st = BG_OK;
    double *disp = calloc((size_t)mesh->nv * 3 + 1, sizeof *disp);
    double *flag = calloc((size_t)mesh->nv + 1, sizeof *flag);
    int32_t *refs = calloc((size_t)mesh->nv + 1, sizeof *refs);
    if (!disp || !flag || !refs) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory writing results");
        goto out;
    }
    for (int32_t v = 0; v < mesh->nv; v++) {
        for (int c = 0; c < n; c++) {
            disp[3 * (size_t)v + c] = run->q[(size_t)v * n + c] - mesh->x[(size_t)v * n + c];
            if (scene->constrained[(size_t)v * n + c])
                refs[v] = 1;
        }
        flag[v] = refs[v];
    }
    char vtu[4200], native[4200], name[32];
    if (join_path(vtu, sizeof vtu, dir, "result.vtu") != 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
        goto out;
    }
    const bg_vtu_array_t point_data[2] = {{"displacement", 3, disp}, {"constrained", 1, flag}};
    const bg_vtu_array_t cell_data[1] = {{"energy_density", 1, run->energy_density}};
    st = bg_mesh_write_vtu(mesh, run->q, point_data, 2, cell_data, 1, vtu, err);
    if (st != BG_OK)
        goto out;
    bg_mesh_format format = scene->mesh_format == BG_FORMAT_UNKNOWN ? BG_FORMAT_MEDIT
                                                                     : scene->mesh_format;
    snprintf(name, sizeof name, "result.%s", bg_mesh_format_extension(format));
    if (join_path(native, sizeof native, dir, name) != 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
        goto out;
    }
    bg_mesh_t marked = *mesh;
    marked.vertex_ref = refs;
    st = bg_mesh_write(&marked, run->q, format, native, err);
    if (st != BG_OK)
        goto out;
    snprintf(paths, paths_size, "%s\n  %s", vtu, native);
out:
    free(disp);
    free(flag);
    free(refs);
    return st;
}

/* Frames of a dynamic run: DIR/frames/<method>-<step>.vtu and the
 * collection DIR/<method>.pvd that ParaView plays as a time series. */
typedef struct frames {
    const bg_scene_t *scene;
    const char *dir;
    const char *method;
    double *displacement;
    int *steps;
    double *times;
    int count, cap;
} frames_t;

static bg_status write_frame(void *ctx, int step, double time, const double *q, bg_error_t *err)
{
    frames_t *f = ctx;
    const bg_mesh_t *mesh = f->scene->mesh;
    const int n = mesh->dim;
    if (f->count == f->cap) {
        int grown = f->cap ? 2 * f->cap : 64;
        int *steps = realloc(f->steps, (size_t)grown * sizeof *steps);
        if (steps)
            f->steps = steps;
        double *times = realloc(f->times, (size_t)grown * sizeof *times);
        if (times)
            f->times = times;
        if (!steps || !times)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the frame list");
        f->cap = grown;
    }
    for (int32_t v = 0; v < mesh->nv; v++)
        for (int c = 0; c < n; c++)
            f->displacement[3 * (size_t)v + c] = q[(size_t)v * n + c] - mesh->x[(size_t)v * n + c];
    char name[96], path[4400];
    snprintf(name, sizeof name, "frames/%s-%06d.vtu", f->method, step);
    if (join_path(path, sizeof path, f->dir, name) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
    const bg_vtu_array_t point_data[1] = {{"displacement", 3, f->displacement}};
    bg_status st = bg_mesh_write_vtu(mesh, q, point_data, 1, NULL, 0, path, err);
    if (st != BG_OK)
        return st;
    f->steps[f->count] = step;
    f->times[f->count] = time;
    f->count++;
    return BG_OK;
}

static bg_status write_pvd(const frames_t *f, bg_error_t *err)
{
    char name[96], path[4400];
    snprintf(name, sizeof name, "%s.pvd", f->method);
    if (join_path(path, sizeof path, f->dir, name) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
    FILE *out = fopen(path, "w");
    if (!out)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(out, "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n"
                 "  <Collection>\n");
    for (int i = 0; i < f->count; i++)
        fprintf(out, "    <DataSet timestep=\"%.17g\" file=\"frames/%s-%06d.vtu\"/>\n", f->times[i],
                f->method, f->steps[i]);
    fprintf(out, "  </Collection>\n</VTKFile>\n");
    if (fclose(out) != 0)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
    return BG_OK;
}

/* The surface with its UVs (DIR/<method>-uv.obj) and the map's quality. */
static bg_status write_parameterization(const bg_scene_t *scene, bg_solve_result_t *run,
                                        const char *dir, bg_error_t *err)
{
    char name[96], path[4400];
    bg_param_quality(scene, run->q, &run->map);
    snprintf(name, sizeof name, "%s-uv.obj", bg_method_name(run->method));
    if (join_path(path, sizeof path, dir, name) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
    return bg_param_write_obj(scene, run->q, path, err);
}

/* A dynamic run or a morph: a series of frames written as it goes. */
static bg_status run_series(const bg_scene_t *scene, bg_method method, double tolerance,
                            int max_iterations, const char *dir, progress_t *pr,
                            bg_solve_result_t *run, bg_error_t *err)
{
    frames_t f = {scene, dir, bg_method_name(method), NULL, NULL, NULL, 0, 0};
    char frames_dir[4200];
    bg_status st = BG_OK;
    f.displacement = calloc((size_t)scene->mesh->nv * 3 + 1, sizeof *f.displacement);
    if (!f.displacement) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for frames");
        goto out;
    }
    if (join_path(frames_dir, sizeof frames_dir, dir, "frames") != 0 ||
        bg_cli_make_directories(frames_dir) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "cannot create %s/frames", dir);
        goto out;
    }
    if (scene->task == BG_TASK_DYNAMIC) {
        const bg_dynamic_options_t opt = {.method = method,
                                          .tolerance = tolerance,
                                          .max_iterations = max_iterations,
                                          .frame = write_frame,
                                          .frame_ctx = &f,
                                          .progress = on_progress,
                                          .progress_ctx = pr};
        st = bg_dynamic_solve(scene, &opt, run, err);
    } else {
        const bg_morph_options_t opt = {.method = method,
                                        .tolerance = tolerance,
                                        .max_iterations = max_iterations,
                                        .frame = write_frame,
                                        .frame_ctx = &f,
                                        .progress = on_progress,
                                        .progress_ctx = pr};
        st = bg_morph_solve(scene, &opt, run, err);
    }
    if (st == BG_OK)
        st = write_pvd(&f, err);
out:
    free(f.displacement);
    free(f.steps);
    free(f.times);
    return st;
}

int bg_cli_solve(int argc, char **argv)
{
    cli_options_t o;
    int rc = parse_args(argc, argv, &o);
    if (rc != 0)
        return rc > 0 ? 0 : BG_EXIT_BAD_INPUT;
    bg_error_t err = BG_ERROR_INIT;
    bg_scene_t *scene = NULL;
    bg_solve_result_t runs[CLI_MAX_METHODS];
    bg_solve_result_t reference = BG_SOLVE_RESULT_INIT;
    int run_count = 0;
    int exit_code = BG_EXIT_BAD_INPUT;
    memset(runs, 0, sizeof runs);

    if (bg_scene_load(o.scene_path, &scene, &err) != BG_OK) {
        fprintf(stderr, "biotgrid solve: %s\n", err.message);
        goto out;
    }
    if (o.method_count == 0) {
        o.methods[0] = scene->method;
        o.method_count = 1;
    }
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    for (int i = 0; i < o.method_count; i++)
        if (bg_method_is_dynamic(o.methods[i]) != dynamic) {
            fprintf(stderr, "biotgrid solve: %s: method %s does not fit a %s scene (use %s)\n",
                    o.scene_path, bg_method_name(o.methods[i]), dynamic ? "dynamic" : "static",
                    dynamic ? "variational or backward-euler" : "newton or local-global");
            goto out;
        }
    const double tolerance = o.tolerance > 0 ? o.tolerance : scene->tolerance;
    const int max_iterations = o.max_iterations > 0 ? o.max_iterations : scene->max_iterations;
    char out_dir[4096];
    if (o.out_dir)
        snprintf(out_dir, sizeof out_dir, "%s", o.out_dir);
    else
        snprintf(out_dir, sizeof out_dir, "out/%s", scene->name);
    if (bg_cli_make_directories(out_dir) != 0) {
        fprintf(stderr, "biotgrid solve: cannot create the output directory %s: %s\n", out_dir,
                strerror(errno));
        goto out;
    }
    progress_t pr = {isatty(fileno(stderr)), o.quiet};
    fprintf(stderr, "%s: %s, %d vertices, %d elements (%s)\n", scene->name,
            bg_mesh_kind_name(bg_mesh_kind_of(scene->mesh)), (int)scene->mesh->nv,
            (int)scene->mesh->ne, scene->mesh_source);

    const double *ref = scene->reference;
    if (scene->reference_kind == BG_REFERENCE_NEWTON && scene->task == BG_TASK_STATIC) {
        if (!o.quiet)
            fprintf(stderr, "computing the reference solution (Newton to its round-off floor)\n");
        const bg_solve_options_t ro = {.method = BG_METHOD_NEWTON,
                                       .tolerance = CLI_REFERENCE_TOLERANCE,
                                       .max_iterations = CLI_REFERENCE_MAX_ITERATIONS};
        if (bg_static_solve(scene, &ro, &reference, &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: reference solve: %s\n", err.message);
            exit_code = BG_EXIT_NOT_CONVERGED;
            goto out;
        }
        ref = reference.q;
    }

    int all_converged = 1;
    for (int i = 0; i < o.method_count; i++) {
        bg_status st;
        if (dynamic || scene->task == BG_TASK_MORPH) {
            st = run_series(scene, o.methods[i], tolerance, max_iterations, out_dir, &pr, &runs[i], &err);
        } else {
            const bg_solve_options_t so = {.method = o.methods[i],
                                           .tolerance = tolerance,
                                           .max_iterations = max_iterations,
                                           .reference = ref,
                                           .progress = on_progress,
                                           .progress_ctx = &pr,
                                           .keep_orientation =
                                               scene->task == BG_TASK_PARAMETERIZE};
            st = scene->task == BG_TASK_SURFACE_EDIT
                     ? bg_surface_arap_solve(scene, &so, &runs[i], &err)
                     : bg_static_solve(scene, &so, &runs[i], &err);
            if (st == BG_OK && scene->task == BG_TASK_PARAMETERIZE)
                st = write_parameterization(scene, &runs[i], out_dir, &err);
        }
        if (st != BG_OK) {
            if (pr.tty && !o.quiet)
                fputc('\n', stderr);
            fprintf(stderr, "biotgrid solve: %s: %s\n", bg_method_name(o.methods[i]),
                    err.message);
            exit_code = err.status == BG_ERR_INVALID ? BG_EXIT_BAD_INPUT : BG_EXIT_NOT_CONVERGED;
            goto out;
        }
        run_count++;
        if (pr.tty && !o.quiet)
            fputc('\n', stderr);
        if (scene->task == BG_TASK_MORPH)
            fprintf(stderr, "%s: %s, %d frames, %d iterations, %.3f s\n",
                    bg_method_name(o.methods[i]), runs[i].stop_reason, runs[i].step_count,
                    runs[i].iterations, runs[i].wall_seconds);
        else if (dynamic)
            fprintf(stderr, "%s: %s, %d steps, %d Newton iterations, %.3f s (energy drift "
                            "%.3e)\n",
                    bg_method_name(o.methods[i]), runs[i].stop_reason, runs[i].step_count - 1,
                    runs[i].iterations, runs[i].wall_seconds,
                    runs[i].trace[runs[i].trace_count - 1].error);
        else
            fprintf(stderr, "%s: %s after %d iterations, %.3f s (relative gradient %.3e)\n",
                    bg_method_name(o.methods[i]), runs[i].stop_reason, runs[i].iterations,
                    runs[i].wall_seconds, runs[i].relative_gradient);
        if (runs[i].inverted_elements >= 0)
            fprintf(stderr, "%s: %lld inverted elements (det F <= 0) in the result\n",
                    bg_method_name(o.methods[i]), (long long)runs[i].inverted_elements);
        all_converged &= runs[i].converged;
    }

    bg_plan_t plan;
    bg_plan_for_scene(scene, o.methods, o.method_count, &plan);
    char report_path[4200], plot_path[4200], result_paths[8500];
    if (join_path(report_path, sizeof report_path, out_dir, "report.json") != 0 ||
        join_path(plot_path, sizeof plot_path, out_dir, "error-vs-time.svg") != 0) {
        fprintf(stderr, "biotgrid solve: output directory name too long\n");
        goto out;
    }
    if (bg_report_write(report_path, scene, &plan, runs, run_count, &err) != BG_OK ||
        bg_report_write_plot(plot_path, scene, runs, run_count, &err) != BG_OK ||
        write_results(out_dir, scene, &runs[0], result_paths, sizeof result_paths, &err) !=
            BG_OK) {
        fprintf(stderr, "biotgrid solve: %s\n", err.message);
        exit_code = BG_EXIT_NOT_CONVERGED;
        goto out;
    }
    printf("\nerror against run time (%s)\n",
           dynamic ? "per step: energy = total energy, error = |E - E0| / |E0|"
           : scene->task == BG_TASK_MORPH ? "per frame: energy and relative gradient at M_t"
           : scene->reference_kind == BG_REFERENCE_NONE ? "no reference: error column empty"
                                                        : "error = |q - q_ref| / |q_ref|");
    bg_report_print_table(stdout, runs, run_count, CLI_TABLE_ROWS);
    printf("\nresults:\n  %s\n  %s\n  %s\n", report_path, plot_path, result_paths);
    exit_code = all_converged ? BG_EXIT_CONVERGED : BG_EXIT_NOT_CONVERGED;
out:
    for (int i = 0; i < CLI_MAX_METHODS; i++)
        bg_solve_result_release(&runs[i]);
    bg_solve_result_release(&reference);
    bg_scene_destroy(&scene);
    return exit_code;
}
