#include "cmd_solve_broker.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bg_file.h"
#include "bg_mesh.h"
#include "bg_report.h"
#include "bgb_client.h"
#include "cmd.h"
#include "cmd_job.h"
#include "cmd_runs.h"

#define BROKER_SOLVE_MAX_METHODS 4
#define BROKER_SOLVE_PATH_MAX 4200
/* A job's report.json: traces of long dynamic runs, well under this. */
#define BROKER_SOLVE_REPORT_MAX ((size_t)256 << 20)
/* The "results:" list: every file of every job, cut (with "...") past this. */
#define BROKER_SOLVE_LIST_MAX 16384

/* What one method's job left: its final document and its report read back. */
typedef struct method_job {
    char id[64];
    cJSON *doc;
    bg_report_runs_t report;
    int cap; /* the iteration cap it was submitted with */
} method_job_t;

static int failed(const char *method, const bg_error_t *err)
{
    fprintf(stderr, "biotgrid solve: %s%s%s\n", method ? method : "", method ? ": " : "",
            err->message);
    return bg_cmd_job_exit_for(err->status);
}

/* Appends "\n  DIR/NAME" for every file the job's result lists. */
static void list_files(char *list, size_t size, const char *dir, const cJSON *files)
{
    const cJSON *f;
    cJSON_ArrayForEach(f, cJSON_GetObjectItemCaseSensitive(files, "files"))
    {
        const size_t used = strlen(list);
        const char *name = bg_cmd_string_of(f, "name");
        if (name && used + 1 < size &&
            snprintf(list + used, size - used, "\n  %s/%s", dir, name) >= (int)(size - used))
            snprintf(list + size - 5, 5, "...");
    }
}

/*
 * One method: submit, follow, download into dir, read the report back into
 * mj. Returns -1 to go on, else the exit status after a message.
 */
static int run_method(const bg_cmd_broker_solve_t *r, bgb_client_t *client, bg_method method,
                      const char *dir, method_job_t *mj, char *results, size_t results_size)
{
    const char *name = bg_method_name(method);
    const bgb_client_submit_t submit = {.scene_path = r->scene_path,
                                        .search_path = r->search_path,
                                        .mechanism = r->mechanism,
                                        .budget = r->budget,
                                        .method = name,
                                        .tolerance = r->tolerance,
                                        .max_iterations = mj->cap,
                                        .inner = r->inner};
    bg_error_t err = BG_ERROR_INIT;
    cJSON *job = NULL, *files = NULL;
    char *text = NULL;
    int rc = -1;
    if (bgb_client_submit_job(client, &submit, &job, &err) != BG_OK) {
        rc = failed(name, &err);
        goto out;
    }
    const char *id = bg_cmd_string_of(job, "id");
    if (!id || strlen(id) >= sizeof mj->id) {
        fprintf(stderr, "biotgrid solve: %s: the broker's answer has no job id\n", name);
        rc = BG_EXIT_FAILED;
        goto out;
    }
    strcpy(mj->id, id);
    if (!r->quiet)
        fprintf(stderr, "%s: job %s submitted to %s (%s, cap %d iterations)\n", name, mj->id,
                r->url, r->mechanism, mj->cap);
    const int tty = isatty(STDERR_FILENO);
    const bg_cmd_job_view_t view = {r->quiet ? NULL : stderr, tty && !r->quiet};
    if (bg_cmd_job_wait(client, mj->id, &view, &mj->doc, &err) != BG_OK) {
        rc = failed(name, &err);
        goto out;
    }
    if (!bg_cmd_job_succeeded(mj->doc)) {
        bg_cmd_job_outcome(stderr, mj->doc, 0);
        fprintf(stderr, "biotgrid solve: %s: job %s did not succeed\n", name, mj->id);
        rc = BG_EXIT_FAILED;
        goto out;
    }
    char path[BROKER_SOLVE_PATH_MAX];
    size_t length = 0;
    if (bg_cmd_job_download(client, mj->id, dir, NULL, &files, NULL, &err) != BG_OK) {
        rc = failed(name, &err);
        goto out;
    }
    list_files(results, results_size, dir, files);
    if (bg_file_join(path, sizeof path, dir, "report.json") != 0) {
        fprintf(stderr, "biotgrid solve: %s: output folder name too long\n", dir);
        rc = BG_EXIT_BAD_INPUT;
        goto out;
    }
    if (bg_file_read_all(path, BROKER_SOLVE_REPORT_MAX, &text, &length, &err) != BG_OK ||
        bg_report_parse_runs(text, length, path, &mj->report, &err) != BG_OK) {
        /* The broker's report, not the user's input: the job did not give what it should. */
        err.status = BG_ERR_IO;
        rc = failed(name, &err);
        goto out;
    }
    if (mj->report.count < 1 || mj->report.run[0].method != method) {
        fprintf(stderr, "biotgrid solve: %s: %s has no run of %s\n", name, path, name);
        rc = BG_EXIT_FAILED;
    }
out:
    cJSON_Delete(job);
    cJSON_Delete(files);
    free(text);
    return rc;
}

/* Per job: the money its services cost, as the broker counted it. */
static void print_market(const bg_cmd_broker_solve_t *r, const method_job_t *jobs, int count)
{
    printf("\nmarket (%s; per job, what its services cost)\n", r->mechanism);
    for (int i = 0; i < count; i++) {
        int contracts = 0;
        const double spent = bg_cmd_job_spent(jobs[i].doc, &contracts);
        const cJSON *allocation = cJSON_GetObjectItemCaseSensitive(jobs[i].doc, "allocation");
        const double latency = bg_cmd_number_of(allocation, "latency_seconds");
        printf("  %-14s job %s: %d contract%s, spent %g of budget %g", bg_method_name(r->methods[i]),
               jobs[i].id, contracts, contracts == 1 ? "" : "s", spent,
               bg_cmd_number_of(jobs[i].doc, "budget"));
        if (isfinite(latency))
            printf(", bought in %.3f s", latency);
        putchar('\n');
    }
}

int bg_cmd_solve_on_broker(const bg_cmd_broker_solve_t *r)
{
    const bg_scene_t *scene = r->scene;
    method_job_t jobs[BROKER_SOLVE_MAX_METHODS];
    bg_solve_result_t runs[BROKER_SOLVE_MAX_METHODS];
    memset(jobs, 0, sizeof jobs);
    bgb_client_t *client = NULL;
    bg_error_t err = BG_ERROR_INIT;
    char out_dir[BROKER_SOLVE_PATH_MAX], plot[BROKER_SOLVE_PATH_MAX + 32];
    char *results = calloc(1, BROKER_SOLVE_LIST_MAX);
    int count = 0, all_converged = 1, rc = BG_EXIT_FAILED;
    if (!results || r->method_count < 1 || r->method_count > BROKER_SOLVE_MAX_METHODS) {
        fprintf(stderr, "biotgrid solve: %s\n", results ? "1 to 4 methods" : "out of memory");
        goto out;
    }
    const int too_long =
        r->out_dir ? snprintf(out_dir, sizeof out_dir, "%s", r->out_dir) >= (int)sizeof out_dir
                   : bg_file_join(out_dir, sizeof out_dir, "out", scene->name) != 0;
    if (too_long) {
        fprintf(stderr, "biotgrid solve: output directory name too long\n");
        rc = BG_EXIT_BAD_INPUT;
        goto out;
    }
    if (bg_cmd_make_directories(out_dir) != 0) {
        fprintf(stderr, "biotgrid solve: cannot create the output directory %s: %s\n", out_dir,
                strerror(errno));
        rc = BG_EXIT_BAD_INPUT;
        goto out;
    }
    const bgb_client_config_t config = {
        .url = r->url, .token = r->token, .cacert = bg_cmd_cacert_find(NULL)};
    if (bgb_client_new(&config, &client, &err) != BG_OK) {
        rc = failed(NULL, &err);
        goto out;
    }
    const double tolerance = r->tolerance > 0.0 ? r->tolerance : scene->tolerance;
    fprintf(stderr, "%s: %s, %d vertices, %d elements (%s), on the grid's broker %s\n",
            scene->name, bg_mesh_kind_name(bg_mesh_kind_of(scene->mesh)), (int)scene->mesh->nv,
            (int)scene->mesh->ne, scene->mesh_source, r->url);
    for (int i = 0; i < r->method_count; i++) {
        const bg_method m = r->methods[i];
        char dir[BROKER_SOLVE_PATH_MAX];
        if (r->method_count == 1)
            snprintf(dir, sizeof dir, "%s", out_dir);
        else if (bg_file_join(dir, sizeof dir, out_dir, bg_method_name(m)) != 0) {
            fprintf(stderr, "biotgrid solve: %s: output folder name too long\n", out_dir);
            rc = BG_EXIT_BAD_INPUT;
            goto out;
        }
        jobs[i].cap = r->max_iterations > 0 ? r->max_iterations : bg_scene_max_iterations(scene, m);
        count = i + 1; /* its job is released below whatever happens */
        const int mrc = run_method(r, client, m, dir, &jobs[i], results, BROKER_SOLVE_LIST_MAX);
        if (mrc >= 0) {
            rc = mrc;
            goto out;
        }
        runs[i] = jobs[i].report.run[0]; /* borrowed: jobs[i].report owns it */
        bg_cmd_runs_print_run(scene, &runs[i], jobs[i].cap, tolerance);
        all_converged &= runs[i].converged;
    }
    if (count > 1) {
        /* The comparison's plot, as `solve --compare` draws it. */
        if (bg_file_join(plot, sizeof plot, out_dir, "error-vs-time.svg") != 0 ||
            bg_report_write_plot(plot, scene, runs, count, &err) != BG_OK) {
            fprintf(stderr, "biotgrid solve: %s\n",
                    err.message[0] ? err.message : "output folder name too long");
            goto out;
        }
    }
    bg_cmd_runs_print_tables(scene, runs, count, tolerance);
    print_market(r, jobs, count);
    printf("\nresults:%s%s%s\n", count > 1 ? "\n  " : "", count > 1 ? plot : "", results);
    rc = all_converged ? BG_EXIT_OK : BG_EXIT_FAILED;
out:
    for (int i = 0; i < count; i++) {
        cJSON_Delete(jobs[i].doc);
        bg_report_runs_release(&jobs[i].report);
    }
    bgb_client_destroy(&client);
    free(results);
    return rc;
}
