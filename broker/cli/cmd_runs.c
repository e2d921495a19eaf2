#include "cmd_runs.h"

#include <math.h>
#include <stdio.h>

#include "bg_report.h"

/* Rows of the error-against-run-time table per run. */
#define RUNS_TABLE_ROWS 24
/* Time-to-accuracy rows: decades from 1e-1 down to the tolerance, at most this many. */
#define RUNS_ACCURACY_ROWS 16

/*
 * For a static comparison: which method reached each accuracy first. Rows
 * are decades of the relative gradient from 1e-1 down to the tolerance (the
 * tolerance itself last); a cell is the first trace point at or below it.
 */
static void print_time_to_accuracy(FILE *out, const bg_solve_result_t *runs, int count,
                                   double tolerance)
{
    double levels[RUNS_ACCURACY_ROWS];
    int rows = 0;
    for (double level = 1e-1; level > tolerance * 1.0000001 && rows < RUNS_ACCURACY_ROWS - 1;
         level /= 10.0)
        levels[rows++] = level;
    levels[rows++] = tolerance;
    fprintf(out, "\ntime to accuracy (relative gradient; first trace point at or below it)\n");
    fprintf(out, "%-12s", "accuracy");
    for (int m = 0; m < count; m++)
        fprintf(out, "  %22s", bg_method_name(runs[m].method));
    fprintf(out, "  first\n");
    for (int r = 0; r < rows; r++) {
        fprintf(out, "%-12.0e", levels[r]);
        int best = -1;
        double best_seconds = 0.0;
        for (int m = 0; m < count; m++) {
            const bg_solve_result_t *run = &runs[m];
            int hit = -1;
            for (int k = 0; k < run->trace_count && hit < 0; k++)
                if (run->trace[k].relative_gradient <= levels[r])
                    hit = k;
            if (hit < 0) {
                fprintf(out, "  %22s", "not reached");
                continue;
            }
            char cell[64];
            snprintf(cell, sizeof cell, "%.3f s (it %d)", run->trace[hit].seconds,
                     run->trace[hit].iteration);
            fprintf(out, "  %22s", cell);
            if (best < 0 || run->trace[hit].seconds < best_seconds) {
                best = m;
                best_seconds = run->trace[hit].seconds;
            }
        }
        fprintf(out, "  %s\n", best < 0 ? "none" : bg_method_name(runs[best].method));
    }
}

void bg_cmd_runs_print_run(const bg_scene_t *scene, const bg_solve_result_t *run,
                            int max_iterations, double tolerance)
{
    const char *method = bg_method_name(run->method);
    if (scene->task == BG_TASK_MORPH)
        fprintf(stderr, "%s: %s, %d frames, %d iterations, %.3f s\n", method, run->stop_reason,
                run->step_count, run->iterations, run->wall_seconds);
    else if (scene->task == BG_TASK_DYNAMIC)
        fprintf(stderr, "%s: %s, %d steps, %d %s iterations, %.3f s (energy drift %.3e)\n",
                method, run->stop_reason, run->step_count - 1, run->iterations,
                scene->inner == BG_METHOD_QUASI_NEWTON ? "quasi-newton" : "Newton",
                run->wall_seconds,
                run->trace_count > 0 ? run->trace[run->trace_count - 1].error : NAN);
    else
        fprintf(stderr, "%s: %s after %d iterations (cap %d), %.3f s (relative gradient %.3e, "
                        "tolerance %.0e)\n",
                method, run->stop_reason, run->iterations, max_iterations, run->wall_seconds,
                run->relative_gradient, tolerance);
    if (run->continuation_stages > 0)
        fprintf(stderr, "%s: %d stages of growing lambda before the scene's (continuation; "
                        "the iterations are their total)\n",
                method, run->continuation_stages);
    if (run->inverted_elements >= 0)
        fprintf(stderr, "%s: %lld inverted elements (det F <= 0) in the result\n", method,
                (long long)run->inverted_elements);
}

void bg_cmd_runs_print_tables(const bg_scene_t *scene, const bg_solve_result_t *runs, int count,
                               double tolerance)
{
    const int series = scene->task == BG_TASK_DYNAMIC || scene->task == BG_TASK_MORPH;
    printf("\nerror against run time (%s)\n",
           scene->task == BG_TASK_DYNAMIC ? "per step: energy = total energy, error = |E - E0| / |E0|"
           : scene->task == BG_TASK_MORPH ? "per frame: energy and relative gradient at M_t"
           : scene->reference_kind == BG_REFERENCE_NONE ? "no reference: error column empty"
                                                        : "error = |q - q_ref| / |q_ref|");
    bg_report_print_table(stdout, runs, count, RUNS_TABLE_ROWS);
    if (count > 1 && !series)
        print_time_to_accuracy(stdout, runs, count, tolerance);
}
