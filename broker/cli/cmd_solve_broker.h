/*
 * cmd_solve_broker — `biotgrid solve --grid` on a grid with a broker: the
 * scene's services bought on the broker's market and computed on the
 * agents it bought, one job per method through the REST API, shown as a
 * local solve is shown.
 */
#ifndef CMD_SOLVE_BROKER_H
#define CMD_SOLVE_BROKER_H

#include "bg_scene.h"

/* One solve on a broker; every pointer borrowed for the call. */
typedef struct bg_cmd_broker_solve {
    const char *url;         /* the broker's REST base URL */
    const char *token;       /* its bearer token ("" or NULL: none) */
    const char *scene_path;  /* the scene file, packed as `submit` packs it */
    const char *search_path; /* ':'-separated folders for the files it names */
    const bg_scene_t *scene; /* the same scene, parsed and validated here (not prepared) */
    const bg_method *methods;
    int method_count;        /* 1..4 */
    double tolerance;        /* <= 0: the scene's solver.tolerance */
    int max_iterations;      /* <= 0: the scene's cap for each method */
    const char *inner;       /* a dynamic scene's solver.inner; NULL: the scene's */
    const char *mechanism;   /* central, catallactic or posted */
    double budget;           /* <= 0: the broker's */
    const char *out_dir;     /* NULL: out/<scene name> */
    int quiet;               /* no event lines, no bar */
} bg_cmd_broker_solve_t;

/*
 * For each method in turn: submits the scene with the method, the
 * tolerance and the cap in its solver settings (bgb_client_pack), follows
 * the job's events as `submit --wait` does (cmd_job: plain lines on
 * stderr, or the bar on a terminal), downloads its result files into the
 * output folder (DIR itself for one method, DIR/<method>/ for several, with
 * the combined error-vs-time.svg in DIR) and reads its report.json back.
 * Then prints what `solve` prints of its runs (cmd_runs) and the money
 * each job spent. Returns the exit status `solve` gives: 0 every method
 * met its tolerance, 1 one did not, a job failed or the broker could not
 * be reached (the message says which), 2 the broker refused the input
 * (a 4xx, its message shown).
 */
int bg_cmd_solve_on_broker(const bg_cmd_broker_solve_t *job);

#endif
