#include "bgb_submission.h"

#include <cJSON.h>
#include <gnutls/crypto.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bgb_base64.h"

/* The body under parse. */
typedef struct request_view {
    const char *body;
    size_t size;
} request_view_t;

int bgb_problem(bgb_problem_t *p, unsigned status, const char *type, const char *title,
                const char *field, const char *fmt, ...)
{
    p->status = status;
    p->type = type;
    p->title = title;
    snprintf(p->field, sizeof p->field, "%s", field ? field : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(p->detail, sizeof p->detail, fmt, ap);
    va_end(ap);
    return 0;
}

/* Whether an object repeats a key; the first repeated key in *key. */
static int repeats_key(const cJSON *object, const char **key)
{
    for (const cJSON *a = object->child; a; a = a->next)
        for (const cJSON *b = a->next; b; b = b->next)
            if (strcmp(a->string, b->string) == 0) {
                *key = a->string;
                return 1;
            }
    return 0;
}

static void locate(const char *text, size_t offset, int *line, int *column)
{
    *line = 1;
    *column = 1;
    for (size_t i = 0; i < offset; i++) {
        if (text[i] == '\n') {
            (*line)++;
            *column = 1;
        } else {
            (*column)++;
        }
    }
}

/* JSON text scanning for scene_span, on a document cJSON has accepted. */
static const char *skip_space(const char *p, const char *end)
{
    while (p < end && (*p == ' ' || *p == '\t' || *p == '\n' || *p == '\r'))
        p++;
    return p;
}

/* p at a '"': just past the closing quote. */
static const char *skip_string(const char *p, const char *end)
{
    for (p++; p < end; p++) {
        if (*p == '\\')
            p++;
        else if (*p == '"')
            return p + 1;
    }
    return end;
}

static const char *skip_value(const char *p, const char *end)
{
    if (p < end && *p == '"')
        return skip_string(p, end);
    if (p < end && (*p == '{' || *p == '[')) {
        int depth = 0;
        while (p < end) {
            if (*p == '"') {
                p = skip_string(p, end);
                continue;
            }
            if (*p == '{' || *p == '[')
                depth++;
            else if ((*p == '}' || *p == ']') && --depth == 0)
                return p + 1;
            p++;
        }
        return end;
    }
    while (p < end && !strchr(",}] \t\r\n", *p))
        p++;
    return p;
}

/*
 * The bytes of the top-level "scene" value of a request cJSON has parsed
 * (so valid JSON, no repeated key): the scene is stored and validated as
 * the client wrote it, instead of printing cJSON's tree again (printing
 * its numbers was the most expensive step of a small submit). 0 when the
 * key is not found as plain text (a key spelled with escapes): then the
 * caller prints the tree.
 */
static int scene_span(const char *body, size_t size, const char **start, size_t *length)
{
    const char *end = body + size, *p = skip_space(body, end);
    if (p >= end || *p != '{')
        return 0;
    for (p = skip_space(p + 1, end); p < end && *p == '"';) {
        const char *key = p + 1, *after = skip_string(p, end);
        const int is_scene = after - key == 6 && memcmp(key, "scene\"", 6) == 0;
        p = skip_space(after, end);
        if (p >= end || *p != ':')
            return 0;
        const char *value = skip_space(p + 1, end), *value_end = skip_value(value, end);
        if (is_scene) {
            *start = value;
            *length = (size_t)(value_end - value);
            return value_end > value;
        }
        p = skip_space(value_end, end);
        if (p >= end || *p != ',')
            return 0;
        p = skip_space(p + 1, end);
    }
    return 0;
}

/* Reads the request document into s; on a problem sends it and returns 0. */
/*
 * SHA-256 over what the job is: the scene's bytes, each file's name and
 * bytes (with their lengths, so that no two different submissions feed the
 * hash the same stream), the mechanism, the budget and the deadline (when
 * given: a submission without one hashes as before it existed); as hex into
 * s->fingerprint. 0, or -1 when the hash cannot be computed.
 */
static int fingerprint(bgb_submission_t *s)
{
    gnutls_hash_hd_t h;
    if (gnutls_hash_init(&h, GNUTLS_DIG_SHA256) < 0)
        return -1;
    const uint64_t scene_size = strlen(s->scene);
    gnutls_hash(h, &scene_size, sizeof scene_size);
    gnutls_hash(h, s->scene, scene_size);
    for (int i = 0; i < s->file_count; i++) {
        const uint64_t name_size = strlen(s->files[i].name), size = s->files[i].size;
        gnutls_hash(h, &name_size, sizeof name_size);
        gnutls_hash(h, s->files[i].name, name_size);
        gnutls_hash(h, &size, sizeof size);
        gnutls_hash(h, s->files[i].data, size);
    }
    char tail[64];
    const int n = s->deadline > 0 ? snprintf(tail, sizeof tail, "%s %.17g %.17g", s->mechanism,
                                             s->budget, s->deadline)
                                  : snprintf(tail, sizeof tail, "%s %.17g", s->mechanism, s->budget);
    gnutls_hash(h, tail, (size_t)n);
    unsigned char digest[32];
    gnutls_hash_deinit(h, digest);
    for (int i = 0; i < 32; i++)
        snprintf(s->fingerprint + 2 * i, 3, "%02x", digest[i]);
    return 0;
}

int bgb_submission_parse(const char *body, size_t size, size_t max_file, bgb_submission_t *s,
                         bgb_problem_t *problem)
{
    memset(s, 0, sizeof *s);
    const request_view_t view = {body, size}, *req = &view;
    static const char *const keys[] = {"scene", "files", "mechanism", "budget", "deadline"};
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(req->body ? req->body : "", req->size, &end, 0);
    int ok = 0;
    if (!root) {
        int line = 0, column = 0;
        const size_t offset = end && req->body && end >= req->body && end <= req->body + req->size
                                  ? (size_t)(end - req->body)
                                  : req->size;
        locate(req->body ? req->body : "", offset, &line, &column);
        bgb_problem(problem, 400, "malformed-json", "Malformed JSON", NULL,
                    "%s at line %d, column %d", req->size ? "malformed JSON" : "empty body", line,
                    column);
        return 0;
    }
    /* cJSON stops after the document; anything but blanks after it is as
     * malformed as a document cut short. */
    const char *body_end = req->body + req->size;
    const char *rest_of =
        end && end >= req->body && end <= body_end ? skip_space(end, body_end) : body_end;
    if (rest_of != body_end) {
        int line = 0, column = 0;
        locate(req->body, (size_t)(rest_of - req->body), &line, &column);
        bgb_problem(problem, 400, "malformed-json", "Malformed JSON", NULL,
                    "text after the JSON document at line %d, column %d", line, column);
        goto out;
    }
    const char *repeated = NULL;
    if (!cJSON_IsObject(root)) {
        bgb_problem(problem, 422, "invalid-request", "Invalid request", NULL,
                    "the request must be a JSON object");
        goto out;
    }
    /* Unknown keys first: then a repeat is among the first five keys, so
     * the pairwise check stays short however many keys a body holds (the
     * other order took minutes of CPU for a 1 MB body of distinct keys). */
    for (const cJSON *m = root->child; m; m = m->next) {
        int known = 0;
        for (int i = 0; i < 5; i++)
            known |= strcmp(m->string, keys[i]) == 0;
        if (!known) {
            bgb_problem(problem, 422, "invalid-request", "Invalid request", m->string,
                        "unknown key '%s' (expected scene, files, mechanism, budget, deadline)",
                        m->string);
            goto out;
        }
    }
    if (repeats_key(root, &repeated)) {
        bgb_problem(problem, 422, "invalid-request", "Invalid request", repeated,
                    "key '%s' is given twice", repeated);
        goto out;
    }
    const cJSON *scene = cJSON_GetObjectItemCaseSensitive(root, "scene");
    if (!cJSON_IsObject(scene)) {
        bgb_problem(problem, 422, "invalid-scene", "Invalid scene", "scene",
                    scene ? "scene: must be a JSON object (the scene file's content)"
                          : "scene: missing (required)");
        goto out;
    }
    const char *span = NULL;
    size_t span_length = 0;
    if (scene_span(req->body, req->size, &span, &span_length)) {
        s->scene = malloc(span_length + 1);
        if (s->scene) {
            memcpy(s->scene, span, span_length);
            s->scene[span_length] = '\0';
        }
    } else {
        s->scene = cJSON_PrintUnformatted(scene);
    }
    const cJSON *mechanism = cJSON_GetObjectItemCaseSensitive(root, "mechanism");
    s->mechanism = "central";
    if (mechanism) {
        if (!cJSON_IsString(mechanism) || (strcmp(mechanism->valuestring, "central") != 0 &&
                                           strcmp(mechanism->valuestring, "catallactic") != 0 &&
                                           strcmp(mechanism->valuestring, "posted") != 0)) {
            bgb_problem(problem, 422, "invalid-request", "Invalid request", "mechanism",
                        "mechanism: expected \"central\", \"catallactic\" or "
                        "\"posted\"");
            goto out;
        }
        s->mechanism = strcmp(mechanism->valuestring, "central") == 0       ? "central"
                       : strcmp(mechanism->valuestring, "catallactic") == 0 ? "catallactic"
                                                                            : "posted";
    }
    const cJSON *budget = cJSON_GetObjectItemCaseSensitive(root, "budget");
    s->budget = BGB_SUBMISSION_DEFAULT_BUDGET;
    if (budget) {
        if (!cJSON_IsNumber(budget) || !isfinite(budget->valuedouble) ||
            !(budget->valuedouble > 0.0)) {
            bgb_problem(problem, 422, "invalid-request", "Invalid request", "budget",
                        "budget: expected a positive number");
            goto out;
        }
        s->budget = budget->valuedouble;
    }
    const cJSON *deadline = cJSON_GetObjectItemCaseSensitive(root, "deadline");
    if (deadline) {
        if (!cJSON_IsNumber(deadline) || !(deadline->valuedouble > 0.0) ||
            !(deadline->valuedouble <= BGB_SUBMISSION_MAX_DEADLINE)) {
            bgb_problem(problem, 422, "invalid-request", "Invalid request", "deadline",
                        "deadline: expected seconds after submission, a number in (0, %g]",
                        BGB_SUBMISSION_MAX_DEADLINE);
            goto out;
        }
        s->deadline = deadline->valuedouble;
    }
    const cJSON *files = cJSON_GetObjectItemCaseSensitive(root, "files");
    if (files && !cJSON_IsArray(files)) {
        bgb_problem(problem, 422, "invalid-request", "Invalid request", "files",
                    "files: expected an array of {\"name\", \"base64\"}");
        goto out;
    }
    if (files && cJSON_GetArraySize(files) > BGB_STORE_MAX_FILES) {
        bgb_problem(problem, 422, "too-many-files", "Too many files", "files",
                    "files: at most %d files", BGB_STORE_MAX_FILES);
        goto out;
    }
    int index = 0;
    for (const cJSON *f = files ? files->child : NULL; f; f = f->next, index++) {
        char field[64];
        snprintf(field, sizeof field, "files[%d]", index);
        const cJSON *name = cJSON_GetObjectItemCaseSensitive(f, "name");
        const cJSON *data = cJSON_GetObjectItemCaseSensitive(f, "base64");
        if (!cJSON_IsObject(f) || cJSON_GetArraySize(f) != 2 || !cJSON_IsString(name) ||
            !cJSON_IsString(data)) {
            bgb_problem(problem, 422, "invalid-request", "Invalid request", field,
                        "%s: expected {\"name\": string, \"base64\": string}", field);
            goto out;
        }
        char name_field[80];
        snprintf(name_field, sizeof name_field, "%s.name", field);
        bg_error_t bad = BG_ERROR_INIT;
        if (bgb_store_check_file_name(name->valuestring, name_field, &bad) != BG_OK) {
            bgb_problem(problem, 422, "invalid-file-name", "Invalid file name", field, "%s",
                        bad.message);
            goto out;
        }
        for (int j = 0; j < s->file_count; j++)
            if (strcmp(s->files[j].name, name->valuestring) == 0) {
                bgb_problem(problem, 422, "invalid-file-name", "Invalid file name", field,
                            "%s.name: '%s' is uploaded twice", field, name->valuestring);
                goto out;
            }
        bgb_upload_t *u = &s->files[s->file_count];
        bg_error_t err = BG_ERROR_INIT;
        if (bgb_base64_decode(data->valuestring, strlen(data->valuestring), max_file, &u->data,
                              &u->size, &err) != BG_OK) {
            bgb_problem(problem, 422, "invalid-file", "Invalid file", field, "%s.base64: %s", field,
                        err.message);
            goto out;
        }
        snprintf(u->name, sizeof u->name, "%s", name->valuestring);
        s->file_count++;
        s->upload_bytes += (int64_t)u->size;
    }
    ok = s->scene != NULL && fingerprint(s) == 0;
    if (!ok)
        bgb_problem(problem, 500, "internal", "Internal error", NULL, "out of memory");
out:
    cJSON_Delete(root);
    if (!ok)
        bgb_submission_release(s);
    return ok;
}

void bgb_submission_files(const bgb_submission_t *s, bgb_file_t *files)
{
    for (int i = 0; i < s->file_count; i++)
        files[i] = (bgb_file_t){s->files[i].name, s->files[i].data, s->files[i].size};
}

void bgb_submission_release(bgb_submission_t *s)
{
    free(s->scene);
    for (int i = 0; i < s->file_count; i++)
        free(s->files[i].data);
    memset(s, 0, sizeof *s);
}
