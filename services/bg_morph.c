#include "bg_morph.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bg_clock.h"

bg_status bg_morph_solve(const bg_scene_t *scene, const bg_morph_options_t *opt,
                         bg_solve_result_t *res, bg_error_t *err)
{
    memset(res, 0, sizeof *res);
    res->method = opt->method;
    if (scene->task != BG_TASK_MORPH || !scene->morph_target || scene->morph_frames < 2)
        return bg_error_set(err, BG_ERR_INVALID, "%s: not a morph scene", scene->path);
    const double t_start = bg_clock_now();
    const int frames = scene->morph_frames;
    const size_t ndof = (size_t)scene->mesh->nv * scene->mesh->dim;
    bg_solver_t *solver = NULL;
    double *q = malloc(ndof * sizeof *q + 1);
    res->trace = calloc((size_t)frames, sizeof *res->trace);
    res->steps = calloc((size_t)frames, sizeof *res->steps);
    bg_status st = BG_OK;
    if (!q || !res->trace || !res->steps) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the morph");
        goto out;
    }
    st = bg_solver_new_on(scene, opt->method, opt->backend, &solver, err);
    if (st != BG_OK)
        goto out;
    memcpy(q, scene->initial, ndof * sizeof *q);
    res->converged = 1;
    res->stop_reason = "completed";
    for (int j = 0; j < frames; j++) {
        const double t_frame = bg_clock_now(), t = (double)j / (frames - 1);
        st = bg_solver_set_blend(solver, scene->morph_target, t, err);
        if (st != BG_OK)
            goto out;
        const bg_solve_options_t so = {
            .method = opt->method,
            .tolerance = opt->tolerance > 0.0 ? opt->tolerance : scene->tolerance,
            .max_iterations = opt->max_iterations > 0 ? opt->max_iterations : scene->max_iterations,
            .start = q,
            .reuse_factor = opt->method == BG_METHOD_NEWTON && !opt->fresh_factor,
        };
        bg_solve_result_t inner = BG_SOLVE_RESULT_INIT;
        st = bg_solver_minimize(solver, &so, &inner, err);
        if (st != BG_OK)
            goto out;
        if (!inner.converged && !inner.roundoff_floor && res->converged) {
            res->converged = 0;
            res->stop_reason = "a frame did not converge";
        }
        memcpy(q, inner.q, ndof * sizeof *q);
        bg_solve_result_accumulate(res, &inner);
        bg_step_record_t *rec = &res->steps[res->step_count++];
        rec->time = t;
        rec->potential = rec->total_energy = inner.energy;
        rec->iterations = inner.iterations;
        rec->seconds = bg_clock_now() - t_frame;
        bg_trace_point_t *pt = &res->trace[res->trace_count++];
        pt->seconds = bg_clock_now() - t_start;
        pt->iteration = j;
        pt->energy = inner.energy;
        pt->gradient_norm = inner.gradient_norm;
        pt->relative_gradient = inner.relative_gradient;
        pt->error = NAN;
        res->energy = inner.energy;
        res->gradient_norm = inner.gradient_norm;
        res->relative_gradient = inner.relative_gradient;
        res->gradient_roundoff = inner.gradient_roundoff;
        res->force_scale = inner.force_scale;
        res->inverted_elements = inner.inverted_elements;
        bg_solve_result_release(&inner);
        if (opt->progress)
            opt->progress(opt->progress_ctx, opt->method, pt);
        if (opt->frame) {
            const double t_out = bg_clock_now();
            st = opt->frame(opt->frame_ctx, j, t, q, err);
            res->output_seconds += bg_clock_now() - t_out;
            if (st != BG_OK)
                goto out;
        }
    }
    res->energy_density = malloc((size_t)scene->mesh->ne * sizeof *res->energy_density + 1);
    if (!res->energy_density) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the result");
        goto out;
    }
    memcpy(res->energy_density, bg_solver_energy_density(solver),
           (size_t)scene->mesh->ne * sizeof *res->energy_density);
    res->q = q;
    q = NULL;
    bg_solver_report(solver, res);
    res->wall_seconds = bg_clock_now() - t_start;
    bg_solve_result_add_scene_prep(res, scene);
out:
    free(q);
    bg_solver_destroy(&solver);
    if (st != BG_OK)
        bg_solve_result_release(res);
    return st;
}
