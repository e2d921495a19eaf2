#include "bgb_jobreport.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_file.h"
#include "bg_json.h"
#include "bg_report.h"
#include "bg_svg.h"
#include "bgb_watch.h"

/* Records how much service time the solve had used at this point; past
 * the cap later points reuse the last record (the money curve then lags,
 * but stays monotone and still ends at the total). */
void bgb_usage_record(bgb_usage_t *u, double seconds, const double used[2])
{
    if (u->count == u->cap) {
        if (u->cap >= BGB_USAGE_MAX_POINTS)
            return;
        const int grown = u->cap ? 2 * u->cap : 256;
        bgb_usage_point_t *p = realloc(u->points, (size_t)grown * sizeof *p);
        if (!p)
            return;
        u->points = p;
        u->cap = grown;
    }
    u->points[u->count++] = (bgb_usage_point_t){seconds, {used[0], used[1]}};
}

void bgb_usage_release(bgb_usage_t *u)
{
    free(u->points);
    memset(u, 0, sizeof *u);
}

/*
 * The money the job had spent at each trace point of run, into money[k]
 * (run->trace_count entries). Contracts are bought up front, but what a
 * user gets for the money is service time: each contract is pro-rated by
 * the share of its service's working time (seconds inside rotation-fit or
 * sparse-solve calls, from the job's watch) used up to that point; a
 * service that did not work during the run (integration-step: the time
 * loop runs in the broker) is pro-rated by run time. At the last point
 * every share is 1, so the curve ends at exactly what was spent (the same
 * sum in the same order). No purchase (nawards 0): 0 everywhere.
 */
void bgb_jobreport_money(const bgb_usage_t *usage, const bg_solve_result_t *run,
                         const bgb_award_t *awards, int nawards, double *money)
{
    const int n = run->trace_count;
    if (n == 0)
        return;
    /* The service time at each point: the latest record at or before it. */
    double last[2] = {0, 0};
    int j = -1;
    for (int k = 0; k < n; k++) {
        while (j + 1 < usage->count && usage->points[j + 1].seconds <= run->trace[k].seconds)
            j++;
        if (k == n - 1 && j >= 0)
            last[0] = usage->points[j].used[0], last[1] = usage->points[j].used[1];
    }
    const double t_last = run->trace[n - 1].seconds;
    j = -1;
    for (int k = 0; k < n; k++) {
        const double t = run->trace[k].seconds;
        while (j + 1 < usage->count && usage->points[j + 1].seconds <= t)
            j++;
        double m = 0.0;
        for (int c = 0; c < nawards; c++) {
            const bgb_award_t *a = &awards[c];
            const int use = a->good == BGB_GOOD_ROTFIT  ? BGB_WATCH_ROTFIT
                            : a->good == BGB_GOOD_SOLVE ? BGB_WATCH_SOLVE
                                                        : -1;
            double share = 1.0;
            if (k < n - 1) {
                if (use >= 0 && last[use] > 0)
                    share = j >= 0 ? usage->points[j].used[use] / last[use] : 0.0;
                else
                    share = t_last > 0 ? t / t_last : 1.0;
                share = share < 0 ? 0 : share > 1 ? 1 : share;
            }
            m += a->quantity * a->price * share;
        }
        money[k] = m;
    }
}

/*
 * Adds the job's "market" section to DIR/report.json: mechanism, the
 * contracts (service, agent, quantity, price), money spent against the
 * budget, the allocation latency, and the error against run time and
 * against money (money[k] for the run's k-th trace point, see
 * bgb_jobreport_money). nawards −1: the fixed pool, no market, nothing
 * spent.
 */
bg_status bgb_jobreport_add_market(const char *path, const char *mechanism, double budget,
                                   const bgb_award_t *awards, int nawards, double spent,
                                   double latency, const double *money, int nmoney, bg_error_t *err)
{
    cJSON *root = NULL;
    bg_status st = bg_json_load(path, BGB_JOBREPORT_MAX_REPORT, &root, err);
    if (st != BG_OK)
        return st;
    char *text = NULL;
    cJSON *m = cJSON_AddObjectToObject(root, "market");
    cJSON_AddStringToObject(m, "mechanism", mechanism);
    cJSON *contracts = NULL;
    if (nawards >= 0) {
        cJSON_AddStringToObject(m, "market", "live");
        contracts = cJSON_AddArrayToObject(m, "contracts");
        for (int i = 0; i < nawards; i++) {
            const bgb_award_t *a = &awards[i];
            cJSON *e = cJSON_CreateObject();
            cJSON_AddStringToObject(e, "service", bgb_good_name(a->good));
            cJSON_AddStringToObject(e, "agent", a->name);
            cJSON_AddStringToObject(e, "endpoint", a->endpoint);
            cJSON_AddNumberToObject(e, "quantity", a->quantity);
            cJSON_AddNumberToObject(e, "price", a->price);
            cJSON_AddItemToArray(contracts, e);
        }
    } else {
        cJSON_AddNullToObject(m, "market");
        cJSON_AddStringToObject(m, "note",
                                "no agent is registered on the market: the job ran "
                                "on the broker's configured agents without contracts");
        cJSON_AddArrayToObject(m, "contracts");
    }
    cJSON_AddNumberToObject(m, "budget", budget);
    cJSON_AddNumberToObject(m, "spent", spent);
    cJSON_AddNumberToObject(m, "allocation_latency_seconds", latency);
    cJSON_AddStringToObject(m, "money_basis",
                            "the whole price is committed when the services are bought; each "
                            "point's money is every contract pro-rated by the share of its "
                            "service's working time used so far (run time for a service that "
                            "does not work during the run), so the curve ends at spent");
    cJSON *curve = cJSON_AddArrayToObject(m, "error_vs_time_and_money");
    const cJSON *runs = cJSON_GetObjectItemCaseSensitive(root, "runs");
    const cJSON *trace = cJSON_GetObjectItemCaseSensitive(cJSON_GetArrayItem(runs, 0), "trace");
    const cJSON *p;
    int k = 0;
    cJSON_ArrayForEach(p, trace)
    {
        cJSON *e = cJSON_CreateObject();
        const cJSON *s = cJSON_GetObjectItemCaseSensitive(p, "seconds");
        const cJSON *er = cJSON_GetObjectItemCaseSensitive(p, "error");
        cJSON_AddNumberToObject(e, "seconds", cJSON_IsNumber(s) ? s->valuedouble : 0.0);
        cJSON_AddNumberToObject(e, "money", k < nmoney ? money[k] : spent);
        if (cJSON_IsNumber(er))
            cJSON_AddNumberToObject(e, "error", er->valuedouble);
        else
            cJSON_AddNullToObject(e, "error");
        cJSON_AddItemToArray(curve, e);
        k++;
    }
    text = cJSON_Print(root);
    if (!text) {
        st = bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
        goto out;
    }
    st = bg_file_write_all(path, text, strlen(text), 0600, err);
out:
    free(text);
    cJSON_Delete(root);
    return st;
}

bg_status bgb_jobreport_add_faults(const char *path, const bgb_fault_t *faults, int nfaults,
                                   bg_error_t *err)
{
    cJSON *root = NULL;
    bg_status st = bg_json_load(path, BGB_JOBREPORT_MAX_REPORT, &root, err);
    if (st != BG_OK)
        return st;
    cJSON *list = cJSON_AddArrayToObject(root, "faults");
    for (int i = 0; list && i < nfaults; i++) {
        const bgb_fault_t *f = &faults[i];
        cJSON *e = cJSON_CreateObject();
        cJSON_AddStringToObject(e, "service", f->service);
        cJSON_AddStringToObject(e, "lost", f->lost);
        cJSON_AddStringToObject(e, "lost_endpoint", f->lost_endpoint);
        cJSON_AddStringToObject(e, "why", f->why);
        cJSON_AddNumberToObject(e, "seconds", f->seconds);
        cJSON_AddNumberToObject(e, "fraction", f->fraction);
        cJSON_AddNumberToObject(e, "settled_quantity", f->settled_quantity);
        cJSON_AddNumberToObject(e, "settled_paid", f->settled_paid);
        if (f->agent[0]) {
            cJSON *r = cJSON_AddObjectToObject(e, "replacement");
            cJSON_AddStringToObject(r, "agent", f->agent);
            cJSON_AddStringToObject(r, "endpoint", f->endpoint);
            cJSON_AddNumberToObject(r, "price", f->price);
            cJSON_AddNumberToObject(r, "quantity", f->quantity);
            cJSON_AddNumberToObject(r, "cost", f->price * f->quantity);
        } else {
            cJSON_AddNullToObject(e, "replacement");
        }
        cJSON_AddNumberToObject(e, "retries", f->retries);
        cJSON_AddNumberToObject(e, "bought_after_seconds", f->bought_after);
        cJSON_AddNumberToObject(e, "resumed_after_seconds", f->resumed_after);
        cJSON_AddNumberToObject(e, "late_answers", (double)f->late_answers);
        cJSON_AddItemToArray(list, e);
    }
    char *text = cJSON_Print(root);
    st = text ? bg_file_write_all(path, text, strlen(text), 0600, err)
              : bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory", path);
    free(text);
    cJSON_Delete(root);
    return st;
}

/*
 * DIR/error-vs-time-and-money.svg: two panels side by side, the run's
 * error against run time and against money (bgb_jobreport_money), each drawn by
 * bg_svg and placed in one document. The error is what `solve`'s plot
 * shows: against the reference, the energy drift of a dynamic run, else
 * the relative gradient.
 */
bg_status bgb_jobreport_money_plot(const char *path, const bg_scene_t *scene,
                                   const bg_solve_result_t *run, const double *money,
                                   bg_error_t *err)
{
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    const int with_reference = dynamic || scene->reference_kind != BG_REFERENCE_NONE;
    const char *y_label = dynamic          ? "relative energy drift |E - E0| / |E0|"
                          : with_reference ? "relative error |q - q_ref| / |q_ref|"
                                           : "relative gradient |grad W| / force scale";
    const size_t n = (size_t)run->trace_count;
    bg_status st = BG_OK;
    char *panel[2] = {NULL, NULL};
    size_t length[2] = {0, 0};
    double *x = malloc((n + 1) * sizeof *x), *y = malloc((n + 1) * sizeof *y);
    FILE *f = NULL;
    if (!x || !y) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the plot");
        goto out;
    }
    for (size_t k = 0; k < n; k++) {
        x[k] = run->trace[k].seconds;
        y[k] = with_reference ? run->trace[k].error : run->trace[k].relative_gradient;
    }
    char title[2][256];
    snprintf(title[0], sizeof title[0], "%s: error against run time", scene->name);
    snprintf(title[1], sizeof title[1], "%s: error against money", scene->name);
    const bg_svg_plot_t plots[2] = {
        {title[0], "wall time (s)", y_label, 0, 1},
        {title[1], "money spent (pro-rated by service time)", y_label, 0, 1}};
    bg_svg_series_t series = {bg_method_name(run->method), x, y, n};
    if ((st = bg_svg_render(&plots[0], &series, 1, &panel[0], &length[0], err)) != BG_OK)
        goto out;
    series.x = money;
    if ((st = bg_svg_render(&plots[1], &series, 1, &panel[1], &length[1], err)) != BG_OK)
        goto out;
    /* The panels' size is bg_svg's: read from its root element. */
    int width = 0, height = 0;
    const char *w = strstr(panel[0], " width=\""), *h = strstr(panel[0], " height=\"");
    if (!w || !h || sscanf(w, " width=\"%d\"", &width) != 1 ||
        sscanf(h, " height=\"%d\"", &height) != 1 || width <= 0 || height <= 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: the plot has no size", path);
        goto out;
    }
    if (!(f = fopen(path, "w"))) {
        st = bg_error_set(err, BG_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
        goto out;
    }
    fprintf(f,
            "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"%d\" "
            "height=\"%d\" viewBox=\"0 0 %d %d\">\n",
            2 * width, height, 2 * width, height);
    for (int i = 0; i < 2; i++) {
        fprintf(f, "<g transform=\"translate(%d 0)\">\n", i * width);
        fwrite(panel[i], 1, length[i], f);
        fprintf(f, "</g>\n");
    }
    fprintf(f, "</svg>\n");
    const int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        st = bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
out:
    free(panel[0]);
    free(panel[1]);
    free(x);
    free(y);
    return st;
}
