#include "bg_run.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "bg_dynamics.h"
#include "bg_file.h"
#include "bg_mesh_io.h"
#include "bg_morph.h"
#include "bg_param.h"
#include "bg_surface_arap.h"

/* Result files of the first run: result.vtu with displacement, the
 * constrained flag and ψ per element, and result.<input format> with the
 * constrained flag as the MEDIT vertex reference. */
bg_status bg_run_write_results(const char *dir, const bg_scene_t *scene,
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
    if (bg_file_join(vtu, sizeof vtu, dir, "result.vtu") != 0) {
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
    if (bg_file_join(native, sizeof native, dir, name) != 0) {
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

/* Frames of a dynamic run: DIR/<prefix><method>-<step>.vtu and the
 * collection DIR/<method>.pvd that ParaView plays as a time series. */
typedef struct frames {
    const bg_scene_t *scene;
    const char *dir;
    const char *method;
    const char *prefix;
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
    snprintf(name, sizeof name, "%s%s-%06d.vtu", f->prefix, f->method, step);
    if (bg_file_join(path, sizeof path, f->dir, name) != 0)
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
    if (bg_file_join(path, sizeof path, f->dir, name) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
    FILE *out = fopen(path, "w");
    if (!out)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(out, "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n"
                 "  <Collection>\n");
    for (int i = 0; i < f->count; i++)
        fprintf(out, "    <DataSet timestep=\"%.17g\" file=\"%s%s-%06d.vtu\"/>\n", f->times[i],
                f->prefix, f->method, f->steps[i]);
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
    if (bg_file_join(path, sizeof path, dir, name) != 0)
        return bg_error_set(err, BG_ERR_INVALID, "output directory name too long");
    return bg_param_write_obj(scene, run->q, path, err);
}

/* The eight fields a dynamic run's and a morph's options share, by the
 * same names in both types: one list so the two series cannot drift. */
#define SERIES_OPTIONS(o, frames)                                                              \
    .method = (o)->method, .tolerance = (o)->tolerance, .max_iterations = (o)->max_iterations,  \
    .frame = write_frame, .frame_ctx = (frames), .progress = (o)->progress,                    \
    .progress_ctx = (o)->progress_ctx, .backend = (o)->backend

static bg_status run_series(const bg_scene_t *scene, const bg_run_options_t *o, const char *dir,
                            bg_solve_result_t *run, bg_error_t *err)
{
    const char *frames_prefix = o->frames_prefix ? o->frames_prefix : "";
    frames_t f = {scene, dir, bg_method_name(o->method), frames_prefix, NULL, NULL, NULL, 0, 0};
    bg_status st = BG_OK;
    f.displacement = calloc((size_t)scene->mesh->nv * 3 + 1, sizeof *f.displacement);
    if (!f.displacement) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for frames");
        goto out;
    }
    /* A prefix names one folder level below DIR ("frames/"), made here. */
    const size_t plen = strlen(frames_prefix);
    if (plen > 0) {
        char sub[256], frames_dir[4400];
        if (plen >= sizeof sub || frames_prefix[plen - 1] != '/') {
            st = bg_error_set(err, BG_ERR_INVALID, "frames prefix '%s' must be a folder name and '/'",
                              frames_prefix);
            goto out;
        }
        memcpy(sub, frames_prefix, plen - 1);
        sub[plen - 1] = '\0';
        if (bg_file_join(frames_dir, sizeof frames_dir, dir, sub) != 0 ||
            (mkdir(frames_dir, 0777) != 0 && errno != EEXIST)) {
            st = bg_error_set(err, BG_ERR_IO, "cannot create %s/%s: %s", dir, sub,
                              strerror(errno));
            goto out;
        }
    }
    if (scene->task == BG_TASK_DYNAMIC) {
        const bg_dynamic_options_t opt = {SERIES_OPTIONS(o, &f)};
        st = bg_dynamic_solve(scene, &opt, run, err);
    } else {
        const bg_morph_options_t opt = {SERIES_OPTIONS(o, &f)};
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

int bg_run_reference_solves(const bg_scene_t *scene)
{
    return scene->reference_kind == BG_REFERENCE_NEWTON && scene->task == BG_TASK_STATIC;
}

bg_status bg_run_reference(const bg_scene_t *scene, const bg_backend_t *backend,
                            bg_solve_result_t *reference, const double **ref, bg_error_t *err)
{
    *ref = scene->reference;
    if (!bg_run_reference_solves(scene))
        return BG_OK;
    const bg_solve_options_t ro = {.method = BG_METHOD_NEWTON,
                                   .tolerance = BG_RUN_REFERENCE_TOLERANCE,
                                   .max_iterations = BG_RUN_REFERENCE_MAX_ITERATIONS,
                                   .backend = backend};
    const bg_status st = bg_static_solve(scene, &ro, reference, err);
    if (st == BG_OK)
        *ref = reference->q;
    return st;
}

bg_status bg_run_method(const bg_scene_t *scene, const bg_run_options_t *o, const double *ref,
                         const char *dir, bg_solve_result_t *run, bg_error_t *err)
{
    if (scene->task == BG_TASK_DYNAMIC || scene->task == BG_TASK_MORPH)
        return run_series(scene, o, dir, run, err);
    const bg_solve_options_t so = {.method = o->method,
                                   .tolerance = o->tolerance,
                                   .max_iterations = o->max_iterations,
                                   .reference = ref,
                                   .reference_ready = o->reference_ready,
                                   .reference_ctx = o->reference_ctx,
                                   .progress = o->progress,
                                   .progress_ctx = o->progress_ctx,
                                   .keep_orientation = scene->task == BG_TASK_PARAMETERIZE,
                                   .backend = o->backend};
    bg_status st = scene->task == BG_TASK_SURFACE_EDIT ? bg_surface_arap_solve(scene, &so, run, err)
                                                       : bg_static_solve(scene, &so, run, err);
    if (st == BG_OK && scene->task == BG_TASK_PARAMETERIZE)
        st = write_parameterization(scene, run, dir, err);
    return st;
}
