/*
 * bg_json — JSON documents read with precise errors: the one piece of code
 * behind the scene loader (bg_scene) and the experiment loader
 * (bgm_config), so both report the same mistakes the same way.
 *
 * Every message has the form "<name>: <field>: <text>" (or "<name>:
 * <text>" for the document as a whole), where <name> is the file as the
 * caller names it and <field> a path into the document such as
 * "handles[1].select" or "factors.nodes[0]":
 *   - an empty file (nothing but white space): "empty file";
 *   - a syntax error: "malformed JSON at line L, column C (byte B)";
 *   - text after the value: "text after the JSON value at line L, column C";
 *   - a key repeated in one object, anywhere in the document:
 *     "key 'k' appears twice" (cJSON would silently keep the first);
 *   - a key not in the caller's list: "unknown key 'k' (expected: a, b)";
 *   - a value of the wrong type or out of range, from the typed readers.
 * Documents are cJSON trees owned by the caller (cJSON_Delete). Nothing
 * here prints; the caller's bg_error_t receives the message.
 */
#ifndef BG_JSON_H
#define BG_JSON_H

#include <cJSON.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

/* Field paths fit in this many bytes; longer ones end in "...". */
#define BG_JSON_PATH_MAX 256

/* Records "<name>: <field>: <text>" (no field: "<name>: <text>") in err
 * and returns status. */
bg_status bg_json_fail(bg_error_t *err, bg_status status, const char *name, const char *field,
                       const char *fmt, ...) __attribute__((format(printf, 5, 6)));
/* The same with a va_list, for callers with their own printf-style front. */
bg_status bg_json_vfail(bg_error_t *err, bg_status status, const char *name, const char *field,
                        const char *fmt, va_list ap) __attribute__((format(printf, 5, 0)));

/* Parses text[0, length) into *root (caller deletes it): rejects an empty
 * document, a syntax error, text after the value and repeated keys, with
 * line and column. *root is NULL on failure. */
bg_status bg_json_parse(const char *text, size_t length, const char *name, cJSON **root,
                        bg_error_t *err);

/* Reads the file at path (at most max_bytes) and parses it as above; a
 * file that cannot be read gives "<path>: cannot open: <reason>". */
bg_status bg_json_load(const char *path, size_t max_bytes, cJSON **root, bg_error_t *err);

/* Path of parent's member key ("a.b", or "b" at the top) and of its
 * element index ("a[3]"), into out[BG_JSON_PATH_MAX]. */
void bg_json_path_key(char *out, const char *parent, const char *key);
void bg_json_path_index(char *out, const char *parent, int index);

/* "an object", "a number", ... for messages. */
const char *bg_json_type_name(const cJSON *item);

/* item must be an object ("expected an object, got ..."). */
bg_status bg_json_expect_object(const cJSON *item, const char *name, const char *field,
                                bg_error_t *err);

/* Rejects keys of object not in allowed (NULL-terminated), listing the
 * allowed ones, and repeated keys. */
bg_status bg_json_check_keys(const cJSON *object, const char *name, const char *field,
                             const char *const *allowed, bg_error_t *err);

/* Typed readers: a finite number; an integer in [lo, hi] written without
 * a fraction; a number in [lo, hi]; true or false; a string (borrowed
 * from item); an array of exactly n finite numbers. */
bg_status bg_json_number(const cJSON *item, const char *name, const char *field, double *out,
                         bg_error_t *err);
bg_status bg_json_integer(const cJSON *item, const char *name, const char *field, double lo,
                          double hi, int64_t *out, bg_error_t *err);
bg_status bg_json_number_in(const cJSON *item, const char *name, const char *field, double lo,
                            double hi, double *out, bg_error_t *err);
bg_status bg_json_bool(const cJSON *item, const char *name, const char *field, int *out,
                       bg_error_t *err);
bg_status bg_json_string(const cJSON *item, const char *name, const char *field,
                         const char **out, bg_error_t *err);
bg_status bg_json_vector(const cJSON *item, const char *name, const char *field, int n,
                         double *out, bg_error_t *err);

#endif
