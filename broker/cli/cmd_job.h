/*
 * cmd_job — a broker's job as the command shows it, the part `submit
 * --wait/--out` and `solve --grid` (on a grid with a broker) share:
 * following its events (a progress bar on a terminal, plain lines
 * otherwise), its outcome and money in a few lines, and its result files
 * fetched into a folder. Also the broker a command talks to when none is
 * named, and the job options both commands take (--mechanism, --budget).
 *
 * Plain lines, one per event, "job ID: ..." and never raw JSON:
 *   plan        "plan: rotation-fit, sparse-solve (left out: integration-step)"
 *   state       "allocating", "running" (the end is the outcome line's)
 *   contract    "contract: rotation-fit from agent rotfit-1, price 1.26", or for the
 *               cores and memory its basic agents bought for it "resource contract:
 *               2 cores from agent rotfit-1, price 1.5e-05 per core-second"
 *   allocation  "bought 3 services for 3.87 (central, 0.052 s)", a retry's
 *               "nothing bought yet (no seller): asking again in 0.4 s", or
 *               what the broker said ("allocation: ...")
 *   progress    "running 40% (iteration 12 of 200)": the event's fraction in
 *               [0, 1] and its unit (step, frame or iteration; "unit" names it,
 *               "of" its total) when present
 *   solved, stopped, trace: one short line each; another event its name.
 * On a terminal a bar on stderr shows the state, the fraction and the unit
 * instead, redrawn in place.
 */
#ifndef CMD_JOB_H
#define CMD_JOB_H

#include <cJSON.h>
#include <stddef.h>
#include <stdio.h>

#include "bg_error.h"
#include "bgb_client.h"

/* The broker's URL from the environment and beside the local grid. */
#define BG_CMD_BROKER_ENV "BIOTGRID_BROKER"
#define BG_CMD_DEFAULT_BROKER "http://127.0.0.1:8080"

/*
 * The broker the local grid recorded in DIR/grid.json (key "broker": a
 * URL, or an object with "url") into url[size]. Returns 1 when found, 0
 * when the grid has no broker or no state file (or it cannot be read).
 */
int bg_cmd_grid_broker(const char *dir, char *url, size_t size);

/* The bearer token from the environment, and the local grid's file of it. */
#define BG_CMD_TOKEN_ENV "BIOTGRID_TOKEN"
#define BG_CMD_TOKEN_FILE "token"
#define BG_CMD_TOKEN_MAX 256

/*
 * The token a client command sends: `given` (--token) when not NULL, else
 * $BIOTGRID_TOKEN when set, else the first line of DIR/token (what `grid
 * up` wrote for its user), else "" (then only /healthz answers). Into
 * out[size].
 */
void bg_cmd_token_find(const char *given, const char *grid_dir, char *out, size_t size);

/* The CA file an https broker's certificate is checked against: `given`
 * (--cacert) when not NULL, else $BIOTGRID_CACERT when set, else NULL
 * (the system's CAs). */
#define BG_CMD_CACERT_ENV "BIOTGRID_CACERT"
const char *bg_cmd_cacert_find(const char *given);

/* A --mechanism value: 1 for central, catallactic or posted. */
int bg_cmd_job_mechanism_ok(const char *name);

/* A --budget value: a finite positive number into *out; -1 otherwise. */
int bg_cmd_job_budget(const char *text, double *out);

/* The exit status for a failed request or job: the broker unreachable,
 * a 5xx, out of memory, or the job's own failure are 1 (did not reach its
 * goal); anything else, the broker's 4xx included, is the input's: 2. */
int bg_cmd_job_exit_for(bg_status status);

/* Member key of a JSON object as a string (NULL: absent or not a string)
 * or a number (NAN: absent or not a number). */
const char *bg_cmd_string_of(const cJSON *object, const char *key);
double bg_cmd_number_of(const cJSON *object, const char *key);

/* How a job's events are shown while it is followed. */
typedef struct bg_cmd_job_view {
    FILE *lines; /* plain lines go here; NULL: none (--json, --quiet) */
    int bar;     /* 1: a progress bar on stderr instead of the lines */
} bg_cmd_job_view_t;

/*
 * Follows job id's events until it ends, shown as view says, resuming a
 * stream that drops (or that a stopping broker ends while the job is
 * active) after its last event, a few times, a second apart; then *job is
 * the job's final document (caller deletes). BG_OK whatever the job's
 * outcome (look at its "state"); an error names the broker and the job
 * (the caller prints it): BG_ERR_IO when it cannot be reached any more.
 */
bg_status bg_cmd_job_wait(bgb_client_t *client, const char *id, const bg_cmd_job_view_t *view,
                          cJSON **job, bg_error_t *err);

/* Whether the document's state is succeeded. */
int bg_cmd_job_succeeded(const cJSON *job);

/*
 * The job's outcome to out, once: "job ID: STATE[: reason]", then with
 * contracts each "  contract: SERVICE from agent AGENT, price P" (for a
 * terminal, where the bar hid their events), then "  spent S of budget B
 * (MECHANISM, N contracts)" when it bought any service (nothing for a job
 * that bought nothing); N counts its services, not its agents' resources.
 */
void bg_cmd_job_outcome(FILE *out, const cJSON *job, int contracts);

/* The money the job spent on services (0 when it bought none) and how
 * many service contracts it holds. */
double bg_cmd_job_spent(const cJSON *job, int *contracts);

/*
 * Downloads every result file of job id into dir (created if needed),
 * listing "DIR/NAME (N bytes)" on list (NULL: quiet). *files (may be
 * NULL) receives the broker's file list document (caller deletes), *count
 * (may be NULL) the files written. Errors name the file.
 */
bg_status bg_cmd_job_download(bgb_client_t *client, const char *id, const char *dir, FILE *list,
                              cJSON **files, int *count, bg_error_t *err);

#endif
