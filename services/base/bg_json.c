#include "bg_json.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bg_file.h"

/* Objects with more members than this are checked for repeated keys by
 * sorting (n log n) instead of pairwise: a 1 MiB file can hold an object
 * of some 10^5 keys. */
#define PAIRWISE_KEYS_MAX 16
#define TRUNCATED_MARK "..."

bg_status bg_json_fail(bg_error_t *err, bg_status status, const char *name, const char *field,
                       const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    bg_status st = bg_json_vfail(err, status, name, field, fmt, ap);
    va_end(ap);
    return st;
}

bg_status bg_json_vfail(bg_error_t *err, bg_status status, const char *name, const char *field,
                        const char *fmt, va_list ap)
{
    char text[BG_ERROR_MESSAGE_MAX];
    vsnprintf(text, sizeof text, fmt, ap);
    if (field && field[0])
        return bg_error_set(err, status, "%s: %s: %s", name, field, text);
    return bg_error_set(err, status, "%s: %s", name, text);
}

/* A path being built in out[BG_JSON_PATH_MAX]. The paths are made for
 * every value parsed (only a failure prints one), so they are joined with
 * memcpy, not snprintf, which cost a fifth of a REST submit's instructions. */
typedef struct path_buf {
    char *out;
    size_t len;
    int over;
} path_buf_t;

/* Appends n bytes of s; a part that does not fit is cut and marked. The
 * first part may be out itself (a parent path extended in place). */
static void path_put(path_buf_t *b, const char *s, size_t n)
{
    const size_t room = BG_JSON_PATH_MAX - 1 - b->len;
    if (n > room) {
        n = room;
        b->over = 1;
    }
    memmove(b->out + b->len, s, n);
    b->len += n;
}

static void path_end(path_buf_t *b)
{
    b->out[b->len] = '\0';
    if (b->over)
        memcpy(b->out + BG_JSON_PATH_MAX - sizeof TRUNCATED_MARK, TRUNCATED_MARK,
               sizeof TRUNCATED_MARK);
}

void bg_json_path_key(char *out, const char *parent, const char *key)
{
    path_buf_t b = {out, 0, 0};
    if (parent && parent[0]) {
        path_put(&b, parent, strlen(parent));
        path_put(&b, ".", 1);
    }
    path_put(&b, key, strlen(key));
    path_end(&b);
}

void bg_json_path_index(char *out, const char *parent, int index)
{
    char digits[16];
    size_t n = 0;
    /* In unsigned arithmetic: the most negative int has no positive. */
    unsigned v = index < 0 ? 0u - (unsigned)index : (unsigned)index;
    do {
        digits[sizeof digits - 1 - n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    if (index < 0)
        digits[sizeof digits - 1 - n++] = '-';
    path_buf_t b = {out, 0, 0};
    path_put(&b, parent, strlen(parent));
    path_put(&b, "[", 1);
    path_put(&b, digits + sizeof digits - n, n);
    path_put(&b, "]", 1);
    path_end(&b);
}

const char *bg_json_type_name(const cJSON *item)
{
    if (cJSON_IsObject(item))
        return "an object";
    if (cJSON_IsArray(item))
        return "an array";
    if (cJSON_IsString(item))
        return "a string";
    if (cJSON_IsNumber(item))
        return "a number";
    if (cJSON_IsBool(item))
        return "a boolean";
    if (cJSON_IsNull(item))
        return "null";
    return "an invalid value";
}

/* ------------------------------------------------------------- parsing */

static void locate(const char *text, size_t offset, int *line, int *column)
{
    *line = 1;
    *column = 1;
    for (size_t i = 0; i < offset; i++) {
        if (text[i] == '\n') {
            ++*line;
            *column = 1;
        } else {
            ++*column;
        }
    }
}

static int is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\n' || c == '\r';
}

static int cmp_key(const void *a, const void *b)
{
    return strcmp((*(const cJSON *const *)a)->string, (*(const cJSON *const *)b)->string);
}

/* The first key of object that appears twice, or NULL. */
static const char *repeated_key(const cJSON *object, bg_status *st)
{
    size_t n = 0;
    for (const cJSON *c = object->child; c; c = c->next)
        n++;
    if (n <= PAIRWISE_KEYS_MAX) {
        for (const cJSON *c = object->child; c; c = c->next)
            for (const cJSON *prev = object->child; prev != c; prev = prev->next)
                if (strcmp(prev->string, c->string) == 0)
                    return c->string;
        return NULL;
    }
    const cJSON **keys = malloc(n * sizeof *keys);
    if (!keys) {
        *st = BG_ERR_NOMEM;
        return NULL;
    }
    size_t i = 0;
    for (const cJSON *c = object->child; c; c = c->next)
        keys[i++] = c;
    qsort(keys, n, sizeof *keys, cmp_key);
    const char *dup = NULL;
    for (i = 1; i < n && !dup; i++)
        if (strcmp(keys[i - 1]->string, keys[i]->string) == 0)
            dup = keys[i]->string;
    free(keys);
    return dup;
}

/* Rejects repeated keys in item and everything below it. */
static bg_status check_repeats(const cJSON *item, const char *name, const char *field,
                               bg_error_t *err)
{
    if (cJSON_IsObject(item)) {
        bg_status st = BG_OK;
        const char *dup = repeated_key(item, &st);
        if (st != BG_OK)
            return bg_json_fail(err, st, name, field, "out of memory");
        if (dup)
            return bg_json_fail(err, BG_ERR_INVALID, name, field, "key '%s' appears twice", dup);
        for (const cJSON *c = item->child; c; c = c->next) {
            if (!cJSON_IsObject(c) && !cJSON_IsArray(c))
                continue;
            char sub[BG_JSON_PATH_MAX];
            bg_json_path_key(sub, field, c->string);
            if ((st = check_repeats(c, name, sub, err)) != BG_OK)
                return st;
        }
    } else if (cJSON_IsArray(item)) {
        int i = 0;
        for (const cJSON *c = item->child; c; c = c->next, i++) {
            if (!cJSON_IsObject(c) && !cJSON_IsArray(c))
                continue;
            char sub[BG_JSON_PATH_MAX];
            bg_json_path_index(sub, field, i);
            bg_status st = check_repeats(c, name, sub, err);
            if (st != BG_OK)
                return st;
        }
    }
    return BG_OK;
}

bg_status bg_json_parse(const char *text, size_t length, const char *name, cJSON **root,
                        bg_error_t *err)
{
    *root = NULL;
    size_t first = 0;
    while (first < length && is_space(text[first]))
        first++;
    if (first == length || text[first] == '\0')
        return bg_json_fail(err, BG_ERR_PARSE, name, NULL, "empty file");
    const char *end = NULL;
    cJSON *doc = cJSON_ParseWithLengthOpts(text, length, &end, 0);
    if (!doc) {
        int line = 0, column = 0;
        size_t offset = end && end >= text && end <= text + length ? (size_t)(end - text) : length;
        locate(text, offset, &line, &column);
        return bg_json_fail(err, BG_ERR_PARSE, name, NULL,
                            "malformed JSON at line %d, column %d (byte %zu)", line, column,
                            offset);
    }
    /* Only white space (or a terminating NUL) may follow the value. */
    size_t rest = end ? (size_t)(end - text) : length;
    while (rest < length && is_space(text[rest]))
        rest++;
    bg_status st = BG_OK;
    if (rest < length && text[rest] != '\0') {
        int line = 0, column = 0;
        locate(text, rest, &line, &column);
        st = bg_json_fail(err, BG_ERR_PARSE, name, NULL,
                          "text after the JSON value at line %d, column %d", line, column);
    }
    if (st == BG_OK)
        st = check_repeats(doc, name, "", err);
    if (st != BG_OK) {
        cJSON_Delete(doc);
        return st;
    }
    *root = doc;
    return BG_OK;
}

bg_status bg_json_load(const char *path, size_t max_bytes, cJSON **root, bg_error_t *err)
{
    char *text = NULL;
    size_t length = 0;
    *root = NULL;
    bg_status st = bg_file_read_all(path, max_bytes, &text, &length, err);
    if (st == BG_OK)
        st = bg_json_parse(text, length, path, root, err);
    free(text);
    return st;
}

/* ------------------------------------------------------------- fields */

bg_status bg_json_expect_object(const cJSON *item, const char *name, const char *field,
                                bg_error_t *err)
{
    if (!cJSON_IsObject(item))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected an object, got %s",
                            bg_json_type_name(item));
    return BG_OK;
}

bg_status bg_json_check_keys(const cJSON *object, const char *name, const char *field,
                             const char *const *allowed, bg_error_t *err)
{
    for (const cJSON *child = object->child; child; child = child->next) {
        int known = 0;
        for (const char *const *a = allowed; *a && !known; a++)
            known = strcmp(*a, child->string) == 0;
        if (!known) {
            char list[BG_JSON_PATH_MAX] = "";
            size_t used = 0;
            for (const char *const *a = allowed; *a && used < sizeof list; a++) {
                int n =
                    snprintf(list + used, sizeof list - used, "%s%s", a == allowed ? "" : ", ", *a);
                if (n < 0)
                    break;
                used += (size_t)n;
            }
            return bg_json_fail(err, BG_ERR_INVALID, name, field,
                                "unknown key '%s' (expected: %s)", child->string, list);
        }
        for (const cJSON *prev = object->child; prev != child; prev = prev->next)
            if (strcmp(prev->string, child->string) == 0)
                return bg_json_fail(err, BG_ERR_INVALID, name, field, "key '%s' appears twice",
                                    child->string);
    }
    return BG_OK;
}

bg_status bg_json_number(const cJSON *item, const char *name, const char *field, double *out,
                         bg_error_t *err)
{
    if (!cJSON_IsNumber(item))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected a number, got %s",
                            bg_json_type_name(item));
    if (!isfinite(item->valuedouble))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "must be a finite number, got %g",
                            item->valuedouble);
    *out = item->valuedouble;
    return BG_OK;
}

bg_status bg_json_number_in(const cJSON *item, const char *name, const char *field, double lo,
                            double hi, double *out, bg_error_t *err)
{
    double v = 0.0;
    bg_status st = bg_json_number(item, name, field, &v, err);
    if (st != BG_OK)
        return st;
    if (v < lo || v > hi)
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "%.17g is out of range [%.17g, %.17g]",
                            v, lo, hi);
    *out = v;
    return BG_OK;
}

bg_status bg_json_integer(const cJSON *item, const char *name, const char *field, double lo,
                          double hi, int64_t *out, bg_error_t *err)
{
    double v = 0.0;
    bg_status st = bg_json_number(item, name, field, &v, err);
    if (st != BG_OK)
        return st;
    if (v != floor(v))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected an integer, got %.17g", v);
    if (v < lo || v > hi)
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "%.17g is out of range [%.17g, %.17g]",
                            v, lo, hi);
    *out = (int64_t)v;
    return BG_OK;
}

bg_status bg_json_bool(const cJSON *item, const char *name, const char *field, int *out,
                       bg_error_t *err)
{
    if (!cJSON_IsBool(item))
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected true or false, got %s",
                            bg_json_type_name(item));
    *out = cJSON_IsTrue(item);
    return BG_OK;
}

bg_status bg_json_string(const cJSON *item, const char *name, const char *field,
                         const char **out, bg_error_t *err)
{
    if (!cJSON_IsString(item) || !item->valuestring)
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected a string, got %s",
                            bg_json_type_name(item));
    *out = item->valuestring;
    return BG_OK;
}

bg_status bg_json_vector(const cJSON *item, const char *name, const char *field, int n,
                         double *out, bg_error_t *err)
{
    if (!cJSON_IsArray(item) || cJSON_GetArraySize(item) != n)
        return bg_json_fail(err, BG_ERR_INVALID, name, field, "expected an array of %d numbers", n);
    int i = 0;
    for (const cJSON *e = item->child; e; e = e->next, i++) {
        if (cJSON_IsNumber(e) && isfinite(e->valuedouble)) {
            out[i] = e->valuedouble;
            continue;
        }
        /* The element's path only for the message naming it. */
        char sub[BG_JSON_PATH_MAX];
        bg_json_path_index(sub, field, i);
        return bg_json_number(e, name, sub, &out[i], err);
    }
    return BG_OK;
}
