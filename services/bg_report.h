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
 * A dynamic scene's runs also carry "inner" (solver.inner: "newton" or
 * "quasi-newton", what minimised each step) and "steps".
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

/* ------------------------------------------------- reading a report back */

/* A report read back holds at most this many runs (solve compares at most
 * 4 methods), and a stop reason of at most this many bytes. */
#define BG_REPORT_MAX_RUNS 8
#define BG_REPORT_REASON_MAX 128

/*
 * The runs of a report.json read back into the results they were written
 * from, so a job solved elsewhere (a broker's) is shown and compared as a
 * local one: per run method, converged, stop_reason, iterations,
 * wall_seconds, energy, gradient_norm, relative_gradient, force_scale,
 * gradient_roundoff, roundoff_floor, continuation_stages,
 * inverted_elements (null: −1), limited_steps, the trace (every point's
 * seconds, iteration, stage, energy, gradient_norm, relative_gradient,
 * error) and a dynamic run's steps or a morph's frames (into steps: time
 * or t, the energies, momenta, iterations, limited, seconds). A null (how
 * the report writes a non-finite value) reads as NAN. What the report does
 * not carry stays zero: positions, energy densities, time split, set-up,
 * rotation-fit counts, the map's quality.
 */
typedef struct bg_report_runs {
    bg_solve_result_t run[BG_REPORT_MAX_RUNS]; /* run[i].stop_reason points at reason[i] */
    char reason[BG_REPORT_MAX_RUNS][BG_REPORT_REASON_MAX];
    int count;
} bg_report_runs_t;

#define BG_REPORT_RUNS_INIT {0}

/*
 * Parses report.json's text[0, length) (name: the file, for messages) into
 * *out (the caller's, empty; bg_report_runs_release). Fails with "<name>:
 * runs[i].field: ..." on malformed JSON, a missing "runs" or a run without
 * method, converged, stop_reason, iterations, wall_seconds,
 * relative_gradient or trace, a value of the wrong type, an unknown
 * method, or more than BG_REPORT_MAX_RUNS runs (BG_ERR_LIMIT); *out is
 * then empty. Unknown keys are ignored (reports grow sections: agents,
 * market). A pure function: no file, no print.
 */
bg_status bg_report_parse_runs(const char *text, size_t length, const char *name,
                               bg_report_runs_t *out, bg_error_t *err);

/* Frees what bg_report_parse_runs allocated; accepts an empty value. */
void bg_report_runs_release(bg_report_runs_t *runs);

#endif
