/*
 * bg_report — the solve report (report.json) and the error-against-run-time
 * plot and table.
 *
 * report.json: { "scene", "mesh": {"dimension", "vertices", "elements",
 * "kind", "source"}, "plan": {"services": [{"name", "detail"}], "left_out":
 * [{"name", "reason"}]}, "reference", "runs": [ {"method", "converged",
 * "stop_reason", "iterations", "wall_seconds", "energy", "gradient_norm",
 * "relative_gradient", "force_scale" (what relative_gradient divides by),
 * "gradient_roundoff" (the final gradient's round-off estimate),
 * "roundoff_floor", "inverted_elements" (det F <= 0 in the result, null
 * where not counted), "svd_fallbacks", "rotation_fits", "time_split":
 * {"setup_seconds", "rotation_fit_seconds", "assembly_seconds",
 * "analyze_seconds", "factor_seconds", "solve_seconds", "vector_seconds",
 * "output_seconds", "accounted_seconds" (their sum, ≈ wall_seconds),
 * "factorizations" (all, set-up included), "iteration_factorizations"},
 * "setup": [{"step", "count", "factorizations", "seconds"}],
 * "trace": [{"seconds", "iteration", "energy", "gradient_norm",
 * "relative_gradient", "error"}]} ] }. "error" is null without a reference.
 */
#ifndef BG_REPORT_H
#define BG_REPORT_H

#include <stdio.h>

#include "bg_error.h"
#include "bg_plan.h"
#include "bg_scene.h"
#include "bg_static.h"

/* Serialises the report; caller frees *json. */
bg_status bg_report_render(const bg_scene_t *scene, const bg_plan_t *plan,
                           const bg_solve_result_t *runs, int run_count, char **json,
                           bg_error_t *err);

bg_status bg_report_write(const char *path, const bg_scene_t *scene, const bg_plan_t *plan,
                          const bg_solve_result_t *runs, int run_count, bg_error_t *err);

/* What one agent did for a job computed across agents (solve --agents):
 * report.json gets "agents": [{"endpoint", "service", "contacted", "calls",
 * "compute_seconds", "bytes_sent", "bytes_received", "encode_seconds",
 * "transit_seconds", "wait_seconds"}]. wait = from a request's send to its
 * reply; transit = wait − compute. */
typedef struct bg_report_agent {
    const char *endpoint, *service; /* borrowed */
    int contacted;                  /* 0: an agent of the grid the plan did not need */
    long long calls, bytes_sent, bytes_received;
    double compute_seconds, encode_seconds, wait_seconds;
} bg_report_agent_t;

/* bg_report_render with the agents section (agents may be NULL, then none). */
bg_status bg_report_render_agents(const bg_scene_t *scene, const bg_plan_t *plan,
                                  const bg_solve_result_t *runs, int run_count,
                                  const bg_report_agent_t *agents, int agent_count, char **json,
                                  bg_error_t *err);
bg_status bg_report_write_agents(const char *path, const bg_scene_t *scene, const bg_plan_t *plan,
                                 const bg_solve_result_t *runs, int run_count,
                                 const bg_report_agent_t *agents, int agent_count,
                                 bg_error_t *err);

/* error-vs-time.svg: log error (or relative gradient without a reference)
 * against seconds, one curve per run. */
bg_status bg_report_write_plot(const char *path, const bg_scene_t *scene,
                               const bg_solve_result_t *runs, int run_count, bg_error_t *err);

/* The error-against-run-time table, at most max_rows rows per run (evenly
 * spaced, always with the first and the last iteration). */
void bg_report_print_table(FILE *out, const bg_solve_result_t *runs, int run_count, int max_rows);

#endif
