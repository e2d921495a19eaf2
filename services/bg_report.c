#include "bg_report.h"

#include <cjson/cJSON.h>
#include <limits.h>
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "bg_json.h"
#include "bg_svg.h"

static cJSON *number_or_null(double x)
{
    return isfinite(x) ? cJSON_CreateNumber(x) : cJSON_CreateNull();
}

static cJSON *run_json(const bg_solve_result_t *r, int morph)
{
    cJSON *o = cJSON_CreateObject();
    if (!o)
        return NULL;
    cJSON_AddStringToObject(o, "method", bg_method_name(r->method));
    cJSON_AddBoolToObject(o, "converged", r->converged);
    cJSON_AddStringToObject(o, "stop_reason", r->stop_reason ? r->stop_reason : "");
    cJSON_AddNumberToObject(o, "iterations", r->iterations);
    /* solves at a lower λ before the scene's (bg_static's continuation) */
    cJSON_AddNumberToObject(o, "continuation_stages", r->continuation_stages);
    cJSON_AddNumberToObject(o, "wall_seconds", r->wall_seconds);
    cJSON_AddItemToObject(o, "energy", number_or_null(r->energy));
    cJSON_AddItemToObject(o, "gradient_norm", number_or_null(r->gradient_norm));
    cJSON_AddItemToObject(o, "relative_gradient", number_or_null(r->relative_gradient));
    cJSON_AddItemToObject(o, "force_scale", number_or_null(r->force_scale));
    cJSON_AddItemToObject(o, "gradient_roundoff", number_or_null(r->gradient_roundoff));
    cJSON_AddBoolToObject(o, "roundoff_floor", r->roundoff_floor);
    if (r->inverted_elements >= 0)
        cJSON_AddNumberToObject(o, "inverted_elements", (double)r->inverted_elements);
    else
        cJSON_AddNullToObject(o, "inverted_elements");
    cJSON_AddNumberToObject(o, "svd_fallbacks", (double)r->rotfit.svd);
    cJSON *fits = cJSON_AddObjectToObject(o, "rotation_fits");
    if (fits) {
        cJSON_AddNumberToObject(fits, "calls", (double)r->rotfit.calls);
        cJSON_AddNumberToObject(fits, "warm", (double)r->rotfit.warm);
        cJSON_AddNumberToObject(fits, "polar", (double)r->rotfit.polar);
        cJSON_AddNumberToObject(fits, "svd", (double)r->rotfit.svd);
    }
    cJSON *split = cJSON_AddObjectToObject(o, "time_split");
    if (split) {
        const double accounted = r->setup.seconds + r->rotfit_seconds + r->assembly_seconds +
                                 r->analyze_seconds + r->factor_seconds + r->solve_seconds +
                                 r->vector_seconds + r->output_seconds;
        cJSON_AddNumberToObject(split, "setup_seconds", r->setup.seconds);
        cJSON_AddNumberToObject(split, "rotation_fit_seconds", r->rotfit_seconds);
        cJSON_AddNumberToObject(split, "assembly_seconds", r->assembly_seconds);
        cJSON_AddNumberToObject(split, "analyze_seconds", r->analyze_seconds);
        cJSON_AddNumberToObject(split, "factor_seconds", r->factor_seconds);
        cJSON_AddNumberToObject(split, "solve_seconds", r->solve_seconds);
        cJSON_AddNumberToObject(split, "vector_seconds", r->vector_seconds);
        cJSON_AddNumberToObject(split, "output_seconds", r->output_seconds);
        cJSON_AddNumberToObject(split, "accounted_seconds", accounted);
        cJSON_AddNumberToObject(split, "factorizations",
                                (double)(r->factorizations + r->setup.factorizations));
        cJSON_AddNumberToObject(split, "iteration_factorizations", (double)r->factorizations);
        /* Newton's extra solves on an already factored matrix (bg_static) */
        cJSON_AddNumberToObject(split, "chord_steps", (double)r->chord_steps);
    }
    cJSON *setup = cJSON_AddArrayToObject(o, "setup");
    for (int i = 0; setup && i < r->setup.count; i++) {
        const bg_setup_step_t *s = &r->setup.step[i];
        cJSON *it = cJSON_CreateObject();
        if (!it)
            break;
        cJSON_AddStringToObject(it, "step", s->name);
        cJSON_AddNumberToObject(it, "count", (double)s->count);
        cJSON_AddNumberToObject(it, "factorizations", (double)s->factorizations);
        cJSON_AddNumberToObject(it, "seconds", s->seconds);
        cJSON_AddItemToArray(setup, it);
    }
    if (r->map.valid) {
        cJSON_AddNumberToObject(o, "flipped_triangles", (double)r->map.flipped_triangles);
        cJSON *area = cJSON_AddObjectToObject(o, "area_distortion");
        cJSON *angle = cJSON_AddObjectToObject(o, "angle_distortion");
        if (area && angle) {
            cJSON_AddNumberToObject(area, "mean", r->map.area_mean);
            cJSON_AddNumberToObject(area, "max", r->map.area_max);
            cJSON_AddNumberToObject(angle, "mean", r->map.angle_mean);
            cJSON_AddNumberToObject(angle, "max", r->map.angle_max);
        }
    }
    if (r->steps && morph) {
        cJSON *frames = cJSON_AddArrayToObject(o, "frames");
        for (int i = 0; frames && i < r->step_count; i++) {
            const bg_step_record_t *st = &r->steps[i];
            cJSON *t = cJSON_CreateObject();
            if (!t)
                break;
            cJSON_AddNumberToObject(t, "t", st->time);
            cJSON_AddItemToObject(t, "energy", number_or_null(st->total_energy));
            cJSON_AddNumberToObject(t, "iterations", st->iterations);
            cJSON_AddNumberToObject(t, "seconds", st->seconds);
            cJSON_AddItemToArray(frames, t);
        }
    } else if (r->steps) {
        cJSON_AddNumberToObject(o, "limited_steps", r->limited_steps);
        cJSON *steps = cJSON_AddArrayToObject(o, "steps");
        for (int i = 0; steps && i < r->step_count; i++) {
            const bg_step_record_t *st = &r->steps[i];
            cJSON *t = cJSON_CreateObject();
            if (!t)
                break;
            cJSON_AddNumberToObject(t, "time", st->time);
            cJSON_AddItemToObject(t, "kinetic", number_or_null(st->kinetic));
            cJSON_AddItemToObject(t, "potential", number_or_null(st->potential));
            cJSON_AddItemToObject(t, "total_energy", number_or_null(st->total_energy));
            cJSON_AddItemToObject(t, "linear_momentum",
                                  cJSON_CreateDoubleArray(st->linear_momentum, 3));
            cJSON_AddItemToObject(t, "angular_momentum",
                                  cJSON_CreateDoubleArray(st->angular_momentum, 3));
            cJSON_AddNumberToObject(t, "iterations", st->iterations);
            cJSON_AddBoolToObject(t, "limited", st->limited);
            cJSON_AddNumberToObject(t, "seconds", st->seconds);
            cJSON_AddItemToArray(steps, t);
        }
    }
    cJSON *trace = cJSON_AddArrayToObject(o, "trace");
    for (int i = 0; trace && i < r->trace_count; i++) {
        const bg_trace_point_t *p = &r->trace[i];
        cJSON *t = cJSON_CreateObject();
        if (!t)
            break;
        cJSON_AddNumberToObject(t, "seconds", p->seconds);
        cJSON_AddNumberToObject(t, "iteration", p->iteration);
        cJSON_AddNumberToObject(t, "stage", p->stage);
        cJSON_AddItemToObject(t, "energy", number_or_null(p->energy));
        cJSON_AddItemToObject(t, "gradient_norm", number_or_null(p->gradient_norm));
        cJSON_AddItemToObject(t, "relative_gradient", number_or_null(p->relative_gradient));
        cJSON_AddItemToObject(t, "error", number_or_null(p->error));
        cJSON_AddItemToArray(trace, t);
    }
    return o;
}

bg_status bg_report_render(const bg_scene_t *scene, const bg_plan_t *plan,
                           const bg_solve_result_t *runs, int run_count, char **json,
                           bg_error_t *err)
{
    return bg_report_render_agents(scene, plan, runs, run_count, NULL, 0, json, err);
}

static void add_agents(cJSON *root, const bg_report_agent_t *agents, int count)
{
    cJSON *arr = cJSON_AddArrayToObject(root, "agents");
    for (int i = 0; arr && i < count; i++) {
        const bg_report_agent_t *a = &agents[i];
        cJSON *it = cJSON_CreateObject();
        cJSON_AddStringToObject(it, "endpoint", a->endpoint);
        cJSON_AddStringToObject(it, "service", a->service);
        cJSON_AddBoolToObject(it, "contacted", a->contacted);
        cJSON_AddNumberToObject(it, "calls", (double)a->calls);
        cJSON_AddNumberToObject(it, "compute_seconds", a->compute_seconds);
        cJSON_AddNumberToObject(it, "bytes_sent", (double)a->bytes_sent);
        cJSON_AddNumberToObject(it, "bytes_received", (double)a->bytes_received);
        cJSON_AddNumberToObject(it, "encode_seconds", a->encode_seconds);
        cJSON_AddNumberToObject(it, "transit_seconds", a->wait_seconds - a->compute_seconds);
        cJSON_AddNumberToObject(it, "wait_seconds", a->wait_seconds);
        cJSON_AddItemToArray(arr, it);
    }
}

bg_status bg_report_render_agents(const bg_scene_t *scene, const bg_plan_t *plan,
                                  const bg_solve_result_t *runs, int run_count,
                                  const bg_report_agent_t *agents, int agent_count, char **json,
                                  bg_error_t *err)
{
    *json = NULL;
    cJSON *root = cJSON_CreateObject();
    if (!root)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory writing the report");
    cJSON_AddStringToObject(root, "scene", scene->name);
    cJSON_AddStringToObject(root, "scene_file", scene->path);
    cJSON *mesh = cJSON_AddObjectToObject(root, "mesh");
    if (mesh) {
        cJSON_AddNumberToObject(mesh, "dimension", scene->mesh->dim);
        cJSON_AddNumberToObject(mesh, "vertices", scene->mesh->nv);
        cJSON_AddNumberToObject(mesh, "elements", scene->mesh->ne);
        cJSON_AddStringToObject(mesh, "kind", bg_mesh_kind_name(bg_mesh_kind_of(scene->mesh)));
        cJSON_AddStringToObject(mesh, "source", scene->mesh_source);
        cJSON_AddNumberToObject(mesh, "reoriented_elements", scene->reoriented);
    }
    cJSON *pj = cJSON_AddObjectToObject(root, "plan");
    if (pj) {
        cJSON *s = cJSON_AddArrayToObject(pj, "services");
        for (int i = 0; s && i < plan->service_count; i++) {
            cJSON *it = cJSON_CreateObject();
            cJSON_AddStringToObject(it, "name", plan->services[i].service);
            cJSON_AddStringToObject(it, "detail", plan->services[i].detail);
            cJSON_AddItemToArray(s, it);
        }
        cJSON *l = cJSON_AddArrayToObject(pj, "left_out");
        for (int i = 0; l && i < plan->left_out_count; i++) {
            cJSON *it = cJSON_CreateObject();
            cJSON_AddStringToObject(it, "name", plan->left_out[i].service);
            cJSON_AddStringToObject(it, "reason", plan->left_out[i].detail);
            cJSON_AddItemToArray(l, it);
        }
    }
    const char *ref = scene->reference_kind == BG_REFERENCE_POSITIONS ? "given positions"
                      : scene->reference_kind == BG_REFERENCE_NEWTON  ? "tight Newton solve"
                                                                      : NULL;
    if (ref)
        cJSON_AddStringToObject(root, "reference", ref);
    else
        cJSON_AddNullToObject(root, "reference");
    cJSON *rj = cJSON_AddArrayToObject(root, "runs");
    for (int i = 0; rj && i < run_count; i++) {
        cJSON *run = run_json(&runs[i], scene->task == BG_TASK_MORPH);
        /* A time integrator's run names what minimised each step
         * (solver.inner): its iterations are that method's. */
        if (run && scene->task == BG_TASK_DYNAMIC)
            cJSON_AddStringToObject(run, "inner", bg_method_name(scene->inner));
        cJSON_AddItemToArray(rj, run);
    }
    if (agents)
        add_agents(root, agents, agent_count);
    *json = cJSON_Print(root);
    cJSON_Delete(root);
    if (!*json)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory writing the report");
    return BG_OK;
}

bg_status bg_report_write(const char *path, const bg_scene_t *scene, const bg_plan_t *plan,
                          const bg_solve_result_t *runs, int run_count, bg_error_t *err)
{
    return bg_report_write_agents(path, scene, plan, runs, run_count, NULL, 0, err);
}

bg_status bg_report_write_agents(const char *path, const bg_scene_t *scene, const bg_plan_t *plan,
                                 const bg_solve_result_t *runs, int run_count,
                                 const bg_report_agent_t *agents, int agent_count,
                                 bg_error_t *err)
{
    char *json = NULL;
    bg_status st =
        bg_report_render_agents(scene, plan, runs, run_count, agents, agent_count, &json, err);
    if (st != BG_OK)
        return st;
    FILE *f = fopen(path, "w");
    if (!f) {
        free(json);
        return bg_error_set(err, BG_ERR_IO, "%s: cannot write the report", path);
    }
    int bad = fputs(json, f) < 0 || fputc('\n', f) == EOF;
    bad |= fclose(f) != 0;
    free(json);
    if (bad)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
    return BG_OK;
}

bg_status bg_report_write_plot(const char *path, const bg_scene_t *scene,
                               const bg_solve_result_t *runs, int run_count, bg_error_t *err)
{
    bg_status st = BG_OK;
    const int dynamic = scene->task == BG_TASK_DYNAMIC;
    const int with_reference = dynamic || scene->reference_kind != BG_REFERENCE_NONE;
    bg_svg_series_t series[8];
    double *buffers[16] = {0};
    int count = run_count < 8 ? run_count : 8;
    for (int i = 0; i < count; i++) {
        const bg_solve_result_t *r = &runs[i];
        double *x = malloc(sizeof *x * ((size_t)r->trace_count + 1));
        double *y = malloc(sizeof *y * ((size_t)r->trace_count + 1));
        buffers[2 * i] = x;
        buffers[2 * i + 1] = y;
        if (!x || !y) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the plot");
            goto out;
        }
        for (int j = 0; j < r->trace_count; j++) {
            x[j] = r->trace[j].seconds;
            y[j] = with_reference ? r->trace[j].error : r->trace[j].relative_gradient;
        }
        series[i].label = bg_method_name(r->method);
        series[i].x = x;
        series[i].y = y;
        series[i].count = (size_t)r->trace_count;
    }
    char title[256];
    snprintf(title, sizeof title, "%s: error against run time", scene->name);
    const bg_svg_plot_t plot = {title, "wall time (s)",
                                dynamic          ? "relative energy drift |E - E0| / |E0|"
                                : with_reference ? "relative error |q - q_ref| / |q_ref|"
                                                 : "relative gradient |grad W| / force scale",
                                0, 1};
    st = bg_svg_write(path, &plot, series, count, err);
out:
    for (int i = 0; i < 16; i++)
        free(buffers[i]);
    return st;
}

static void print_row(FILE *out, const char *method, const bg_trace_point_t *p)
{
    char error[32];
    if (isfinite(p->error))
        snprintf(error, sizeof error, "%.3e", p->error);
    else
        snprintf(error, sizeof error, "-");
    fprintf(out, "%-13s %6d %10.4f %22.15e %12.3e %12s\n", method, p->iteration, p->seconds,
            p->energy, p->relative_gradient, error);
}

void bg_report_print_table(FILE *out, const bg_solve_result_t *runs, int run_count, int max_rows)
{
    fprintf(out, "%-13s %6s %10s %22s %12s %12s\n", "method", "iter", "seconds", "energy",
            "rel.gradient", "error");
    for (int i = 0; i < run_count; i++) {
        const bg_solve_result_t *r = &runs[i];
        const int n = r->trace_count;
        const int stride = n > max_rows && max_rows > 1 ? (n + max_rows - 2) / (max_rows - 1) : 1;
        for (int j = 0; j < n; j++)
            if (j % stride == 0 || j == n - 1)
                print_row(out, bg_method_name(r->method), &r->trace[j]);
    }
}

/* ------------------------------------------------- reading a report back */

/* A number the report may write as null (a non-finite value: NAN). A
 * missing key is an error when required, else fallback. */
static bg_status read_real(const cJSON *obj, const char *key, int required, double fallback,
                           const char *name, const char *parent, double *out, bg_error_t *err)
{
    char field[BG_JSON_PATH_MAX];
    bg_json_path_key(field, parent, key);
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(obj, key);
    if (!item) {
        *out = fallback;
        return required ? bg_json_fail(err, BG_ERR_INVALID, name, field, "missing") : BG_OK;
    }
    if (cJSON_IsNull(item)) {
        *out = NAN;
        return BG_OK;
    }
    return bg_json_number(item, name, field, out, err);
}

/* A count in [lo, INT_MAX]; missing: an error when required, else fallback. */
static bg_status read_int(const cJSON *obj, const char *key, int required, int lo, int fallback,
                          const char *name, const char *parent, int *out, bg_error_t *err)
{
    char field[BG_JSON_PATH_MAX];
    bg_json_path_key(field, parent, key);
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(obj, key);
    *out = fallback;
    if (!item)
        return required ? bg_json_fail(err, BG_ERR_INVALID, name, field, "missing") : BG_OK;
    int64_t v = 0;
    const bg_status st = bg_json_integer(item, name, field, lo, INT_MAX, &v, err);
    if (st == BG_OK)
        *out = (int)v;
    return st;
}

/* true or false; missing: an error when required, else 0. */
static bg_status read_flag(const cJSON *obj, const char *key, int required, const char *name,
                           const char *parent, int *out, bg_error_t *err)
{
    char field[BG_JSON_PATH_MAX];
    bg_json_path_key(field, parent, key);
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(obj, key);
    *out = 0;
    if (!item)
        return required ? bg_json_fail(err, BG_ERR_INVALID, name, field, "missing") : BG_OK;
    return bg_json_bool(item, name, field, out, err);
}

/* The array under key (NULL when absent and not required), its path in field. */
static bg_status read_array(const cJSON *obj, const char *key, int required, const char *name,
                            const char *parent, char *field, const cJSON **out, bg_error_t *err)
{
    bg_json_path_key(field, parent, key);
    const cJSON *item = cJSON_GetObjectItemCaseSensitive(obj, key);
    *out = NULL;
    if (!item)
        return required ? bg_json_fail(err, BG_ERR_INVALID, name, field, "missing") : BG_OK;
    if (!cJSON_IsArray(item))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected an array, got %s",
                            bg_json_type_name(item));
    *out = item;
    return BG_OK;
}

/* A member of a result read from its key: a number (null: NAN), a count
 * or a flag, at offset in the struct; required, or fallback when absent. */
typedef enum field_kind { FIELD_REAL, FIELD_COUNT, FIELD_FLAG } field_kind;
typedef struct field {
    const char *key;
    field_kind kind;
    int required;
    double fallback;
    size_t offset;
} field_t;

#define REAL(T, key, member, required, fallback)                                                  \
    {key, FIELD_REAL, required, fallback, offsetof(T, member)}
#define COUNT(T, key, member, required) {key, FIELD_COUNT, required, 0, offsetof(T, member)}
#define FLAG(T, key, member, required) {key, FIELD_FLAG, required, 0, offsetof(T, member)}

static const field_t TRACE_FIELDS[] = {
    REAL(bg_trace_point_t, "seconds", seconds, 1, 0.0),
    COUNT(bg_trace_point_t, "iteration", iteration, 1),
    COUNT(bg_trace_point_t, "stage", stage, 0),
    REAL(bg_trace_point_t, "energy", energy, 0, NAN),
    REAL(bg_trace_point_t, "gradient_norm", gradient_norm, 0, NAN),
    REAL(bg_trace_point_t, "relative_gradient", relative_gradient, 1, NAN),
    REAL(bg_trace_point_t, "error", error, 0, NAN),
};
static const field_t STEP_FIELDS[] = {
    REAL(bg_step_record_t, "time", time, 1, 0.0),
    REAL(bg_step_record_t, "kinetic", kinetic, 0, NAN),
    REAL(bg_step_record_t, "potential", potential, 0, NAN),
    REAL(bg_step_record_t, "total_energy", total_energy, 0, NAN),
    COUNT(bg_step_record_t, "iterations", iterations, 0),
    FLAG(bg_step_record_t, "limited", limited, 0),
    REAL(bg_step_record_t, "seconds", seconds, 0, 0.0),
};
static const field_t FRAME_FIELDS[] = {
    REAL(bg_step_record_t, "t", time, 1, 0.0),
    REAL(bg_step_record_t, "energy", total_energy, 0, NAN),
    COUNT(bg_step_record_t, "iterations", iterations, 0),
    REAL(bg_step_record_t, "seconds", seconds, 0, 0.0),
};
static const field_t RUN_FIELDS[] = {
    FLAG(bg_solve_result_t, "converged", converged, 1),
    COUNT(bg_solve_result_t, "iterations", iterations, 1),
    REAL(bg_solve_result_t, "wall_seconds", wall_seconds, 1, 0.0),
    REAL(bg_solve_result_t, "energy", energy, 0, NAN),
    REAL(bg_solve_result_t, "gradient_norm", gradient_norm, 0, NAN),
    REAL(bg_solve_result_t, "relative_gradient", relative_gradient, 1, NAN),
    REAL(bg_solve_result_t, "force_scale", force_scale, 0, NAN),
    REAL(bg_solve_result_t, "gradient_roundoff", gradient_roundoff, 0, NAN),
    FLAG(bg_solve_result_t, "roundoff_floor", roundoff_floor, 0),
    COUNT(bg_solve_result_t, "continuation_stages", continuation_stages, 0),
    COUNT(bg_solve_result_t, "limited_steps", limited_steps, 0),
};
#define FIELDS(table) table, sizeof table / sizeof table[0]

/* The fields of object o (its path: at) into the struct at base. */
static bg_status read_fields(const cJSON *o, const field_t *fields, size_t count, void *base,
                             const char *name, const char *at, bg_error_t *err)
{
    bg_status st = bg_json_expect_object(o, name, at, err);
    for (size_t i = 0; i < count && st == BG_OK; i++) {
        const field_t *f = &fields[i];
        void *member = (char *)base + f->offset;
        if (f->kind == FIELD_REAL)
            st = read_real(o, f->key, f->required, f->fallback, name, at, member, err);
        else if (f->kind == FIELD_COUNT)
            st = read_int(o, f->key, f->required, 0, 0, name, at, member, err);
        else
            st = read_flag(o, f->key, f->required, name, at, member, err);
    }
    return st;
}

/* One trace point (variant unused: the item readers share a signature). */
static bg_status read_point(const cJSON *o, int variant, const char *name, const char *at,
                            void *point, bg_error_t *err)
{
    (void)variant;
    return read_fields(o, FIELDS(TRACE_FIELDS), point, name, at, err);
}

/* A dynamic run's step or (morph) a morph's frame; a step's momenta too. */
static bg_status read_step(const cJSON *o, int morph, const char *name, const char *at,
                           void *step, bg_error_t *err)
{
    bg_step_record_t *s = step;
    bg_status st = morph ? read_fields(o, FIELDS(FRAME_FIELDS), s, name, at, err)
                         : read_fields(o, FIELDS(STEP_FIELDS), s, name, at, err);
    static const char *const momenta[2] = {"linear_momentum", "angular_momentum"};
    for (int k = 0; k < 2 && st == BG_OK && !morph; k++) {
        char field[BG_JSON_PATH_MAX];
        bg_json_path_key(field, at, momenta[k]);
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, momenta[k]);
        if (v)
            st = bg_json_vector(v, name, field, 3, k ? s->angular_momentum : s->linear_momentum,
                                err);
    }
    return st;
}

typedef bg_status (*item_fn)(const cJSON *o, int variant, const char *name, const char *at,
                             void *item, bg_error_t *err);

/* The array under key of o, each element read by fn into a fresh array of
 * size-byte items (*items, caller frees even on failure; *count those
 * read). Absent and not required: nothing, *items NULL. */
static bg_status read_list(const cJSON *o, const char *key, int required, const char *name,
                           const char *at, size_t size, item_fn fn, int variant, void **items,
                           int *count, bg_error_t *err)
{
    char field[BG_JSON_PATH_MAX];
    const cJSON *list = NULL;
    bg_status st = read_array(o, key, required, name, at, field, &list, err);
    if (st != BG_OK || !list)
        return st;
    const int n = cJSON_GetArraySize(list);
    if (!(*items = calloc((size_t)n + 1, size)))
        return bg_error_set(err, BG_ERR_NOMEM, "%s: out of memory for %s", name, field);
    const cJSON *item = list->child;
    for (int k = 0; st == BG_OK && k < n; k++, item = item->next) {
        char path[BG_JSON_PATH_MAX];
        bg_json_path_index(path, field, k);
        st = fn(item, variant, name, path, (char *)*items + (size_t)k * size, err);
        *count = k + 1;
    }
    return st;
}

/* One element of "runs" into r; its stop reason into reason. */
static bg_status read_run(const cJSON *o, const char *name, const char *at, bg_solve_result_t *r,
                          char *reason, bg_error_t *err)
{
    char field[BG_JSON_PATH_MAX];
    const char *text = NULL;
    bg_status st = bg_json_expect_object(o, name, at, err);
    if (st == BG_OK) {
        bg_json_path_key(field, at, "method");
        const cJSON *m = cJSON_GetObjectItemCaseSensitive(o, "method");
        st = m ? bg_json_string(m, name, field, &text, err)
               : bg_json_fail(err, BG_ERR_INVALID, name, field, "missing");
        bg_error_t merr = BG_ERROR_INIT;
        if (st == BG_OK && bg_method_parse(text, &r->method, &merr) != BG_OK)
            st = bg_json_fail(err, BG_ERR_INVALID, name, field, "%s", merr.message);
    }
    if (st == BG_OK) {
        bg_json_path_key(field, at, "stop_reason");
        const cJSON *why = cJSON_GetObjectItemCaseSensitive(o, "stop_reason");
        st = why ? bg_json_string(why, name, field, &text, err)
                 : bg_json_fail(err, BG_ERR_INVALID, name, field, "missing");
        if (st == BG_OK && strlen(text) >= BG_REPORT_REASON_MAX)
            st = bg_json_fail(err, BG_ERR_LIMIT, name, field, "longer than %d bytes",
                              BG_REPORT_REASON_MAX - 1);
        if (st == BG_OK) {
            strcpy(reason, text);
            r->stop_reason = reason;
        }
    }
    if (st == BG_OK)
        st = read_fields(o, FIELDS(RUN_FIELDS), r, name, at, err);
    double inverted = -1.0;
    if (st == BG_OK)
        st = read_real(o, "inverted_elements", 0, -1.0, name, at, &inverted, err);
    r->inverted_elements = isfinite(inverted) ? (int64_t)inverted : -1;
    if (st == BG_OK)
        st = read_list(o, "trace", 1, name, at, sizeof *r->trace, read_point, 0,
                       (void **)&r->trace, &r->trace_count, err);
    const int morph = cJSON_GetObjectItemCaseSensitive(o, "frames") != NULL;
    if (st == BG_OK)
        st = read_list(o, morph ? "frames" : "steps", 0, name, at, sizeof *r->steps, read_step,
                       morph, (void **)&r->steps, &r->step_count, err);
    return st;
}

bg_status bg_report_parse_runs(const char *text, size_t length, const char *name,
                               bg_report_runs_t *out, bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    cJSON *root = NULL;
    const cJSON *runs = NULL;
    char field[BG_JSON_PATH_MAX];
    bg_status st = bg_json_parse(text, length, name, &root, err);
    if (st == BG_OK)
        st = bg_json_expect_object(root, name, "", err);
    if (st == BG_OK)
        st = read_array(root, "runs", 1, name, "", field, &runs, err);
    const int count = runs ? cJSON_GetArraySize(runs) : 0;
    if (st == BG_OK && count > BG_REPORT_MAX_RUNS)
        st = bg_json_fail(err, BG_ERR_LIMIT, name, "runs", "%d runs, at most %d are read", count,
                          BG_REPORT_MAX_RUNS);
    const cJSON *item = runs ? runs->child : NULL;
    for (int i = 0; st == BG_OK && i < count; i++, item = item->next) {
        bg_json_path_index(field, "runs", i);
        out->count = i + 1; /* so a failure releases what this run holds */
        st = read_run(item, name, field, &out->run[i], out->reason[i], err);
    }
    cJSON_Delete(root);
    if (st != BG_OK)
        bg_report_runs_release(out);
    return st;
}

void bg_report_runs_release(bg_report_runs_t *runs)
{
    if (!runs)
        return;
    for (int i = 0; i < runs->count; i++)
        bg_solve_result_release(&runs->run[i]);
    memset(runs, 0, sizeof *runs);
}
