#include "cmd_job.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bg_file.h"
#include "cmd.h"

#define JOB_BAR_WIDTH 30
#define JOB_WAIT_RETRIES 3
#define JOB_GRID_STATE_MAX (1 << 20)

int bg_cmd_grid_broker(const char *dir, char *url, size_t size)
{
    char path[4096];
    if (bg_file_join(path, sizeof path, dir, "grid.json") != 0 || access(path, R_OK) != 0)
        return 0;
    char *text = NULL;
    size_t length = 0;
    if (bg_file_read_all(path, JOB_GRID_STATE_MAX, &text, &length, NULL) != BG_OK)
        return 0;
    cJSON *root = cJSON_ParseWithLength(text, length);
    free(text);
    const cJSON *broker = cJSON_GetObjectItemCaseSensitive(root, "broker");
    if (cJSON_IsObject(broker))
        broker = cJSON_GetObjectItemCaseSensitive(broker, "url");
    int found = 0;
    if (cJSON_IsString(broker) && broker->valuestring[0] && strlen(broker->valuestring) < size) {
        snprintf(url, size, "%s", broker->valuestring);
        found = 1;
    }
    cJSON_Delete(root);
    return found;
}

void bg_cmd_token_find(const char *given, const char *grid_dir, char *out, size_t size)
{
    out[0] = '\0';
    const char *env = getenv(BG_CMD_TOKEN_ENV);
    if (given || (env && env[0])) {
        snprintf(out, size, "%s", given ? given : env);
        return;
    }
    char path[4096], *text = NULL;
    size_t length = 0;
    if (bg_file_join(path, sizeof path, grid_dir, BG_CMD_TOKEN_FILE) != 0 ||
        bg_file_read_all(path, BG_CMD_TOKEN_MAX, &text, &length, NULL) != BG_OK)
        return;
    text[strcspn(text, "\r\n")] = '\0';
    snprintf(out, size, "%s", text);
    free(text);
}

const char *bg_cmd_cacert_find(const char *given)
{
    const char *env = getenv(BG_CMD_CACERT_ENV);
    return given ? given : env && env[0] ? env : NULL;
}

int bg_cmd_job_mechanism_ok(const char *name)
{
    return strcmp(name, "central") == 0 || strcmp(name, "catallactic") == 0 ||
           strcmp(name, "posted") == 0;
}

int bg_cmd_job_budget(const char *text, double *out)
{
    char *end = NULL;
    const double v = strtod(text, &end);
    if (!end || *end || end == text || !isfinite(v) || !(v > 0.0))
        return -1;
    *out = v;
    return 0;
}

int bg_cmd_job_exit_for(bg_status status)
{
    return status == BG_ERR_IO || status == BG_ERR_NOMEM ? BG_EXIT_FAILED : BG_EXIT_BAD_INPUT;
}

const char *bg_cmd_string_of(const cJSON *object, const char *key)
{
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(object, key);
    return cJSON_IsString(item) ? item->valuestring : NULL;
}

double bg_cmd_number_of(const cJSON *object, const char *key)
{
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(object, key);
    return cJSON_IsNumber(item) ? item->valuedouble : NAN;
}

static const char *or_unknown(const char *s)
{
    return s ? s : "?";
}

/* A job's contracts hold its services and, on the resource layer, the
 * cores and memory its basic agents bought for it (priced per unit and
 * second): the unit of such a contract, or NULL for a service. */
static const char *resource_unit(const char *good)
{
    if (good && strcmp(good, "cores") == 0)
        return "core";
    if (good && strcmp(good, "memory") == 0)
        return "GiB";
    return NULL;
}

/* One contract, "[resource ]contract: ...", without the line's start. */
static void contract_text(FILE *out, const cJSON *c)
{
    const char *good = bg_cmd_string_of(c, "service"), *unit = resource_unit(good);
    const double quantity = bg_cmd_number_of(c, "quantity");
    if (unit)
        fprintf(out, "resource contract: %g %s from agent %s, price %g per %s-second\n", quantity,
                strcmp(unit, "GiB") == 0 ? "GiB of memory" : quantity == 1.0 ? "core" : "cores",
                or_unknown(bg_cmd_string_of(c, "agent")), bg_cmd_number_of(c, "price"), unit);
    else
        fprintf(out, "contract: %s from agent %s, price %g\n", or_unknown(good),
                or_unknown(bg_cmd_string_of(c, "agent")), bg_cmd_number_of(c, "price"));
}

/* ------------------------------------------------------------ following */

typedef struct follow {
    const char *id;
    const bg_cmd_job_view_t *view;
    char last_id[64]; /* the last event seen, to resume a dropped stream after it */
    char state[32];
    double fraction;  /* NAN until a progress event gives one */
    char unit[48];    /* "iteration 12", "step 3", "frame 7" or "" */
    int bar_shown;
} follow_t;

static int terminal_state(const char *state)
{
    return strcmp(state, "succeeded") == 0 || strcmp(state, "failed") == 0 ||
           strcmp(state, "cancelled") == 0;
}

/* The progress event's unit: the one its "unit" names (the broker's: step,
 * frame or iteration, with the count under that key and the total under
 * "of"), else the finest it carries, a dynamic run's step or a morph's
 * frame before the iteration inside it. "" when it has none. */
static void read_unit(const cJSON *doc, char *unit, size_t size)
{
    static const char *const units[] = {"step", "frame", "iteration"};
    const char *named = bg_cmd_string_of(doc, "unit");
    const double of = bg_cmd_number_of(doc, "of");
    for (size_t i = 0; i < sizeof units / sizeof units[0]; i++) {
        const char *u = named && isfinite(bg_cmd_number_of(doc, named)) ? named : units[i];
        const double n = bg_cmd_number_of(doc, u);
        if (isfinite(n)) {
            if (isfinite(of) && of > 0 && u == named)
                snprintf(unit, size, "%s %.0f of %.0f", u, n, of);
            else
                snprintf(unit, size, "%s %.0f", u, n);
            return;
        }
    }
}

static void draw_bar(follow_t *f)
{
    const double known = isfinite(f->fraction) ? f->fraction : 0.0;
    const double x = known < 0.0 ? 0.0 : known > 1.0 ? 1.0 : known;
    const int filled = (int)lround(x * JOB_BAR_WIDTH);
    char bar[JOB_BAR_WIDTH + 1];
    for (int i = 0; i < JOB_BAR_WIDTH; i++)
        bar[i] = i < filled ? '#' : '.';
    bar[JOB_BAR_WIDTH] = '\0';
    fprintf(stderr, "\r\033[K%s [%s] %3d%% %s%s%s", f->id, bar, (int)lround(100.0 * x), f->state,
            f->unit[0] ? ", " : "", f->unit);
    fflush(stderr);
    f->bar_shown = 1;
}

/* "plan: a, b (left out: c, d)" */
static void plan_line(FILE *out, const char *id, const cJSON *plan)
{
    fprintf(out, "job %s: plan:", id);
    const cJSON *s;
    int n = 0;
    cJSON_ArrayForEach(s, cJSON_GetObjectItemCaseSensitive(plan, "services"))
        fprintf(out, "%s %s", n++ ? "," : "", or_unknown(bg_cmd_string_of(s, "service")));
    n = 0;
    cJSON_ArrayForEach(s, cJSON_GetObjectItemCaseSensitive(plan, "left_out"))
        fprintf(out, "%s%s", n++ ? ", " : " (left out: ", or_unknown(bg_cmd_string_of(s, "service")));
    fputs(n ? ")\n" : "\n", out);
}

static void allocation_line(FILE *out, const char *id, const cJSON *doc)
{
    const cJSON *contracts = cJSON_GetObjectItemCaseSensitive(doc, "contracts");
    const char *message = bg_cmd_string_of(doc, "message");
    const char *mechanism = bg_cmd_string_of(doc, "mechanism");
    if (cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(doc, "failed")))
        fprintf(out, "job %s: the market could not buy the job's services\n", id);
    else if (isfinite(bg_cmd_number_of(doc, "retry")))
        fprintf(out, "job %s: nothing bought yet (%s): asking again in %.1f s\n", id,
                or_unknown(bg_cmd_string_of(doc, "reason")),
                bg_cmd_number_of(doc, "wait_seconds"));
    else if (message)
        fprintf(out, "job %s: allocation: %s\n", id, message);
    else if (cJSON_IsNumber(contracts))
        fprintf(out, "job %s: bought %d service%s for %g (%s, %.3f s)\n", id,
                contracts->valueint, contracts->valueint == 1 ? "" : "s",
                bg_cmd_number_of(doc, "spent"), or_unknown(mechanism),
                bg_cmd_number_of(doc, "latency_seconds"));
    else
        fprintf(out, "job %s: allocation\n", id);
}

static void event_line(FILE *out, const follow_t *f, const char *event, const cJSON *doc)
{
    if (strcmp(event, "state") == 0) {
        if (!terminal_state(f->state)) /* the outcome line says how it ended, once */
            fprintf(out, "job %s: %s\n", f->id, f->state);
    } else if (strcmp(event, "progress") == 0) {
        fprintf(out, "job %s: %s", f->id, f->state);
        if (isfinite(f->fraction))
            fprintf(out, " %.0f%%", 100.0 * f->fraction);
        if (f->unit[0])
            fprintf(out, " (%s)", f->unit);
        fputc('\n', out);
    } else if (strcmp(event, "plan") == 0) {
        plan_line(out, f->id, doc);
    } else if (strcmp(event, "contract") == 0) {
        fprintf(out, "job %s: ", f->id);
        contract_text(out, doc);
    } else if (strcmp(event, "allocation") == 0) {
        allocation_line(out, f->id, doc);
    } else if (strcmp(event, "solved") == 0) {
        fprintf(out, "job %s: solved, %s\n", f->id,
                cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(doc, "converged"))
                    ? "converged"
                    : "did not converge");
    } else if (strcmp(event, "stopped") == 0) {
        fprintf(out, "job %s: stopped after %.1f s\n", f->id, bg_cmd_number_of(doc, "seconds"));
    } else if (strcmp(event, "trace") == 0) {
        fprintf(out, "job %s: error-against-time trace of %d points\n", f->id,
                cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(doc, "points")));
    } else {
        fprintf(out, "job %s: %s\n", f->id, event);
    }
    fflush(out);
}

static int on_event(void *ctx, const char *id, const char *event, const char *data)
{
    follow_t *f = ctx;
    snprintf(f->last_id, sizeof f->last_id, "%s", id);
    cJSON *doc = cJSON_Parse(data);
    if (strcmp(event, "state") == 0) {
        snprintf(f->state, sizeof f->state, "%s", or_unknown(bg_cmd_string_of(doc, "state")));
        if (strcmp(f->state, "succeeded") == 0)
            f->fraction = 1.0;
    } else if (strcmp(event, "progress") == 0) {
        const double x = bg_cmd_number_of(doc, "fraction");
        if (isfinite(x))
            f->fraction = x < 0.0 ? 0.0 : x > 1.0 ? 1.0 : x;
        f->unit[0] = '\0';
        read_unit(doc, f->unit, sizeof f->unit);
    }
    if (f->view->bar)
        draw_bar(f);
    else if (f->view->lines)
        event_line(f->view->lines, f, event, doc);
    cJSON_Delete(doc);
    return 0;
}

bg_status bg_cmd_job_wait(bgb_client_t *client, const char *id, const bg_cmd_job_view_t *view,
                          cJSON **job, bg_error_t *err)
{
    follow_t f = {.id = id, .view = view, .state = "queued", .fraction = NAN};
    *job = NULL;
    bg_status st = BG_OK;
    for (int attempt = 0;; attempt++) {
        bg_error_clear(err);
        st = bgb_client_events(client, id, f.last_id[0] ? f.last_id : NULL, on_event, &f, err);
        if (st == BG_OK)
            st = bgb_client_get_job(client, id, job, err);
        if (st != BG_OK && st != BG_ERR_IO)
            break;
        const char *state = bg_cmd_string_of(*job, "state");
        if (state && terminal_state(state)) {
            st = BG_OK;
            break;
        }
        if (st == BG_OK)
            st = bg_error_set(err, BG_ERR_IO,
                              "the broker at %s closed the events stream while job %s is still %s",
                              bgb_client_url(client), id, or_unknown(state));
        cJSON_Delete(*job);
        *job = NULL;
        if (attempt == JOB_WAIT_RETRIES)
            break;
        sleep(1);
    }
    if (f.bar_shown)
        fputc('\n', stderr);
    return st;
}

int bg_cmd_job_succeeded(const cJSON *job)
{
    const char *state = bg_cmd_string_of(job, "state");
    return state && strcmp(state, "succeeded") == 0;
}

double bg_cmd_job_spent(const cJSON *job, int *contracts)
{
    int n = 0;
    const cJSON *c;
    cJSON_ArrayForEach(c, cJSON_GetObjectItemCaseSensitive(job, "contracts"))
        n += !resource_unit(bg_cmd_string_of(c, "service"));
    const cJSON *allocation = cJSON_GetObjectItemCaseSensitive(job, "allocation");
    const double spent = bg_cmd_number_of(allocation, "spent");
    if (contracts)
        *contracts = n;
    return n > 0 && isfinite(spent) ? spent : 0.0;
}

void bg_cmd_job_outcome(FILE *out, const cJSON *job, int contracts)
{
    const char *reason = bg_cmd_string_of(job, "reason");
    fprintf(out, "job %s: %s%s%s\n", or_unknown(bg_cmd_string_of(job, "id")),
            or_unknown(bg_cmd_string_of(job, "state")), reason ? ": " : "", reason ? reason : "");
    const cJSON *list = contracts ? cJSON_GetObjectItemCaseSensitive(job, "contracts") : NULL;
    const cJSON *c;
    cJSON_ArrayForEach(c, list)
    {
        fputs("  ", out);
        contract_text(out, c);
    }
    int n = 0;
    const double spent = bg_cmd_job_spent(job, &n);
    if (n > 0)
        fprintf(out, "  spent %g of budget %g (%s, %d contract%s)\n", spent,
                bg_cmd_number_of(job, "budget"), or_unknown(bg_cmd_string_of(job, "mechanism")),
                n, n == 1 ? "" : "s");
}

/* ------------------------------------------------------------ result files */

bg_status bg_cmd_job_download(bgb_client_t *client, const char *id, const char *dir, FILE *list,
                              cJSON **files, int *count, bg_error_t *err)
{
    cJSON *doc = NULL;
    int written = 0;
    bg_status st = bgb_client_result(client, id, &doc, err);
    if (st != BG_OK)
        goto out;
    if (bg_file_make_directories(dir) != 0) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: cannot create the folder: %s", dir,
                          strerror(errno));
        goto out;
    }
    const cJSON *file;
    cJSON_ArrayForEach(file, cJSON_GetObjectItemCaseSensitive(doc, "files"))
    {
        const char *name = bg_cmd_string_of(file, "name");
        size_t size = 0;
        if (!name) {
            st = bg_error_set(err, BG_ERR_IO, "job %s: the broker's file list has an entry "
                                              "without a name", id);
            goto out;
        }
        if ((st = bgb_client_download(client, id, name, dir, &size, err)) != BG_OK)
            goto out;
        if (list)
            fprintf(list, "%s/%s (%zu bytes)\n", dir, name, size);
        written++;
    }
out:
    if (count)
        *count = written;
    if (files && st == BG_OK) {
        *files = doc;
        doc = NULL;
    } else if (files) {
        *files = NULL;
    }
    cJSON_Delete(doc);
    return st;
}
