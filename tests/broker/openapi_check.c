/*
 * openapi_check OPENAPI TEMPLATE METHOD STATUS TYPE < BODY — checks a
 * response body against the schema the OpenAPI document OPENAPI (a file,
 * e.g. the broker's GET /openapi.json) gives for path TEMPLATE
 * ("/v1/jobs/{id}"), METHOD, STATUS and content TYPE (parameters after a
 * ';' ignored) with oas_check, for the shell tests
 * that drive a real broker. Exit 0: conforms; 1: it does not (the first
 * violation on stderr); 2: usage, an unreadable file or not JSON.
 */
#include <cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "oas_check.h"

#define OPENAPI_CHECK_MAX ((size_t)64 << 20)

static cJSON *read_json(FILE *in, const char *what)
{
    char *text = malloc(OPENAPI_CHECK_MAX + 1);
    if (!text)
        return NULL;
    const size_t n = fread(text, 1, OPENAPI_CHECK_MAX, in);
    text[n] = '\0';
    cJSON *doc = cJSON_ParseWithLength(text, n);
    free(text);
    if (!doc)
        fprintf(stderr, "openapi_check: %s is not a JSON document\n", what);
    return doc;
}

int main(int argc, char **argv)
{
    if (argc != 6) {
        fprintf(stderr, "usage: openapi_check OPENAPI TEMPLATE METHOD STATUS TYPE < BODY\n");
        return 2;
    }
    FILE *f = fopen(argv[1], "rb");
    if (!f) {
        fprintf(stderr, "openapi_check: cannot open %s\n", argv[1]);
        return 2;
    }
    cJSON *openapi = read_json(f, argv[1]);
    fclose(f);
    cJSON *body = openapi ? read_json(stdin, "the body on stdin") : NULL;
    int rc = 2;
    char why[600], type[128];
    snprintf(type, sizeof type, "%s", argv[5]);
    type[strcspn(type, "; ")] = '\0';
    const cJSON *schema =
        body ? oas_response_schema(openapi, argv[2], argv[3], strtol(argv[4], NULL, 10), type, why,
                                   sizeof why)
             : NULL;
    if (body && !schema) {
        fprintf(stderr, "openapi_check: %s\n", why);
        rc = 1;
    } else if (schema) {
        rc = oas_check(openapi, schema, body, why, sizeof why);
        if (rc)
            fprintf(stderr, "openapi_check: %s %s %s: %s\n", argv[3], argv[2], argv[4], why);
    }
    cJSON_Delete(body);
    cJSON_Delete(openapi);
    return rc;
}
