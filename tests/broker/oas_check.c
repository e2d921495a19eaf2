#include "oas_check.h"

#include <math.h>
#include <regex.h>
#include <stdio.h>
#include <string.h>

#define PATH_MAX_LEN 512
#define REF_DEPTH 16

typedef struct walk {
    const cJSON *openapi;
    char path[PATH_MAX_LEN];
    char *msg;
    size_t msg_size;
} walk_t;

static int fail(walk_t *w, const char *what)
{
    snprintf(w->msg, w->msg_size, "%s: %s", w->path[0] ? w->path : "/", what);
    return 1;
}

/* Follows local "$ref": "#/a/b" chains; NULL for a dangling one. */
static const cJSON *resolve(const cJSON *openapi, const cJSON *node)
{
    for (int depth = 0; node && depth < REF_DEPTH; depth++) {
        const cJSON *ref = cJSON_GetObjectItemCaseSensitive(node, "$ref");
        if (!cJSON_IsString(ref))
            return node;
        if (strncmp(ref->valuestring, "#/", 2) != 0)
            return NULL;
        char buf[256];
        snprintf(buf, sizeof buf, "%s", ref->valuestring + 2);
        const cJSON *at = openapi;
        char *save = NULL;
        for (char *part = strtok_r(buf, "/", &save); part && at; part = strtok_r(NULL, "/", &save))
            at = cJSON_GetObjectItemCaseSensitive(at, part);
        node = at;
    }
    return NULL;
}

static int type_is(const cJSON *doc, const char *type)
{
    if (strcmp(type, "object") == 0)
        return cJSON_IsObject(doc);
    if (strcmp(type, "array") == 0)
        return cJSON_IsArray(doc);
    if (strcmp(type, "string") == 0)
        return cJSON_IsString(doc);
    if (strcmp(type, "boolean") == 0)
        return cJSON_IsBool(doc);
    if (strcmp(type, "number") == 0)
        return cJSON_IsNumber(doc) && isfinite(doc->valuedouble);
    if (strcmp(type, "integer") == 0)
        return cJSON_IsNumber(doc) && isfinite(doc->valuedouble) &&
               doc->valuedouble == floor(doc->valuedouble);
    return 0;
}

static int check(walk_t *w, const cJSON *schema, const cJSON *doc);

/* Appends "/key" to the walk's path for the call, restoring it after. */
static int check_at(walk_t *w, const char *key, const cJSON *schema, const cJSON *doc)
{
    const size_t n = strlen(w->path);
    snprintf(w->path + n, sizeof w->path - n, "/%s", key);
    const int r = check(w, schema, doc);
    w->path[n] = '\0';
    return r;
}

static int known_keyword(const char *k)
{
    static const char *const words[] = {"$ref",
                                        "allOf",
                                        "type",
                                        "nullable",
                                        "enum",
                                        "required",
                                        "properties",
                                        "items",
                                        "maxItems",
                                        "minimum",
                                        "maximum",
                                        "pattern",
                                        "exclusiveMinimum",
                                        "additionalProperties",
                                        "description",
                                        "default",
                                        "format",
                                        "title",
                                        "example"};
    for (size_t i = 0; i < sizeof words / sizeof words[0]; i++)
        if (strcmp(k, words[i]) == 0)
            return 1;
    return 0;
}

static int check_number(walk_t *w, const cJSON *schema, const cJSON *doc)
{
    const cJSON *min = cJSON_GetObjectItemCaseSensitive(schema, "minimum");
    const cJSON *max = cJSON_GetObjectItemCaseSensitive(schema, "maximum");
    const cJSON *excl = cJSON_GetObjectItemCaseSensitive(schema, "exclusiveMinimum");
    if (excl && !cJSON_IsBool(excl))
        return fail(w, "schema: exclusiveMinimum must be a boolean in OpenAPI 3.0");
    if (cJSON_IsNumber(min) && (doc->valuedouble < min->valuedouble ||
                                (cJSON_IsTrue(excl) && doc->valuedouble == min->valuedouble)))
        return fail(w, "below the schema's minimum");
    if (cJSON_IsNumber(max) && doc->valuedouble > max->valuedouble)
        return fail(w, "above the schema's maximum");
    return 0;
}

static int check_string(walk_t *w, const cJSON *schema, const cJSON *doc)
{
    const cJSON *pattern = cJSON_GetObjectItemCaseSensitive(schema, "pattern");
    if (!cJSON_IsString(pattern))
        return 0;
    regex_t re;
    if (regcomp(&re, pattern->valuestring, REG_EXTENDED | REG_NOSUB) != 0)
        return fail(w, "schema: pattern is not a POSIX extended expression");
    const int miss = regexec(&re, doc->valuestring, 0, NULL, 0) != 0;
    regfree(&re);
    return miss ? fail(w, "does not match the schema's pattern") : 0;
}

static int check_object(walk_t *w, const cJSON *schema, const cJSON *doc)
{
    const cJSON *required = cJSON_GetObjectItemCaseSensitive(schema, "required");
    for (const cJSON *k = required ? required->child : NULL; k; k = k->next)
        if (cJSON_IsString(k) && !cJSON_GetObjectItemCaseSensitive(doc, k->valuestring)) {
            char what[160];
            snprintf(what, sizeof what, "lacks required '%s'", k->valuestring);
            return fail(w, what);
        }
    const cJSON *props = cJSON_GetObjectItemCaseSensitive(schema, "properties");
    const cJSON *extra = cJSON_GetObjectItemCaseSensitive(schema, "additionalProperties");
    for (const cJSON *v = doc->child; v; v = v->next) {
        const cJSON *ps = cJSON_GetObjectItemCaseSensitive(props, v->string);
        if (ps) {
            if (check_at(w, v->string, ps, v))
                return 1;
        } else if (cJSON_IsFalse(extra)) {
            char what[160];
            snprintf(what, sizeof what, "'%s' is not a property the schema allows", v->string);
            return fail(w, what);
        }
    }
    return 0;
}

static int check_array(walk_t *w, const cJSON *schema, const cJSON *doc)
{
    const cJSON *max = cJSON_GetObjectItemCaseSensitive(schema, "maxItems");
    if (cJSON_IsNumber(max) && cJSON_GetArraySize(doc) > max->valueint)
        return fail(w, "more items than the schema's maxItems");
    const cJSON *items = cJSON_GetObjectItemCaseSensitive(schema, "items");
    int i = 0;
    for (const cJSON *v = doc->child; v && items; v = v->next, i++) {
        char key[16];
        snprintf(key, sizeof key, "%d", i);
        if (check_at(w, key, items, v))
            return 1;
    }
    return 0;
}

static int check(walk_t *w, const cJSON *schema, const cJSON *doc)
{
    schema = resolve(w->openapi, schema);
    if (!cJSON_IsObject(schema))
        return fail(w, "schema: a $ref that names nothing, or a schema that is not an object");
    for (const cJSON *k = schema->child; k; k = k->next)
        if (!known_keyword(k->string)) {
            char what[160];
            snprintf(what, sizeof what, "schema: keyword '%s' is not checked by oas_check",
                     k->string);
            return fail(w, what);
        }
    const cJSON *all = cJSON_GetObjectItemCaseSensitive(schema, "allOf");
    for (const cJSON *s = all ? all->child : NULL; s; s = s->next)
        if (check(w, s, doc))
            return 1;
    if (cJSON_IsNull(doc))
        return cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(schema, "nullable"))
                   ? 0
                   : fail(w, "null where the schema does not say nullable");
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(schema, "type");
    if (cJSON_IsString(type) && !type_is(doc, type->valuestring)) {
        char what[160];
        snprintf(what, sizeof what, "not of the schema's type '%s'", type->valuestring);
        return fail(w, what);
    }
    const cJSON *choices = cJSON_GetObjectItemCaseSensitive(schema, "enum");
    if (choices) {
        int found = 0;
        for (const cJSON *c = choices->child; c && !found; c = c->next)
            found = cJSON_Compare(c, doc, 1);
        if (!found)
            return fail(w, "not one of the schema's enum values");
    }
    if (cJSON_IsNumber(doc))
        return check_number(w, schema, doc);
    if (cJSON_IsString(doc))
        return check_string(w, schema, doc);
    if (cJSON_IsObject(doc))
        return check_object(w, schema, doc);
    if (cJSON_IsArray(doc))
        return check_array(w, schema, doc);
    return 0;
}

int oas_check(const cJSON *openapi, const cJSON *schema, const cJSON *doc, char *msg,
              size_t msg_size)
{
    walk_t w = {.openapi = openapi, .msg = msg, .msg_size = msg_size};
    if (msg_size)
        msg[0] = '\0';
    return check(&w, schema, doc);
}

const cJSON *oas_response_schema(const cJSON *openapi, const char *template_path,
                                 const char *method, long status, const char *type, char *msg,
                                 size_t msg_size)
{
    char lower[16], code[16];
    snprintf(lower, sizeof lower, "%s", method);
    for (char *c = lower; *c; c++)
        if (*c >= 'A' && *c <= 'Z')
            *c = (char)(*c - 'A' + 'a');
    snprintf(code, sizeof code, "%ld", status);
    const cJSON *paths = cJSON_GetObjectItemCaseSensitive(openapi, "paths");
    const cJSON *op = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(paths, template_path), lower);
    if (!op) {
        snprintf(msg, msg_size, "%s %s is not in the OpenAPI document", method, template_path);
        return NULL;
    }
    const cJSON *resp = resolve(
        openapi,
        cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(op, "responses"), code));
    if (!resp) {
        snprintf(msg, msg_size, "%s %s: status %s is not documented", method, template_path, code);
        return NULL;
    }
    const cJSON *media =
        cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(resp, "content"), type);
    const cJSON *schema =
        media ? resolve(openapi, cJSON_GetObjectItemCaseSensitive(media, "schema")) : NULL;
    if (!schema)
        snprintf(msg, msg_size, "%s %s %s: no schema for content type '%s'", method, template_path,
                 code, type);
    return schema;
}
