/*
 * oas_check — checks a JSON document against a schema of an OpenAPI 3.0
 * document, for the REST tests: that the broker's answers are what its
 * /openapi.json says they are, all the way down (nested objects, array
 * items), not only their top-level keys.
 *
 * The keywords the broker's document uses are checked: $ref (local),
 * allOf, type (with nullable), enum, required, properties,
 * additionalProperties false, items, maxItems, minimum, maximum,
 * exclusiveMinimum (3.0's boolean form) and pattern (POSIX extended).
 * Any other keyword is refused as not understood, so the document cannot
 * grow a constraint the tests silently skip.
 */
#ifndef OAS_CHECK_H
#define OAS_CHECK_H

#include <stddef.h>

#include <cJSON.h>

/* The schema a response is documented with: paths[template][method]
 * .responses[status].content[type].schema, $ref resolved. NULL (and why
 * in msg) when the document has none. */
const cJSON *oas_response_schema(const cJSON *openapi, const char *template_path,
                                 const char *method, long status, const char *type, char *msg,
                                 size_t msg_size);

/* 0 when doc satisfies schema; else 1 with the first violation in msg, as
 * a JSON pointer into doc and what it broke. */
int oas_check(const cJSON *openapi, const cJSON *schema, const cJSON *doc, char *msg,
              size_t msg_size);

#endif
