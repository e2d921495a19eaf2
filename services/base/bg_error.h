/*
 * bg_error — status codes and the error record every fallible call fills.
 *
 * Every function that can fail returns a bg_status (0 on success, negative
 * on failure) and, when given a non-NULL bg_error_t, writes a message that
 * names what is wrong precisely enough for a user to fix it: the file, the
 * line, the element, the field. Callers own the bg_error_t (it lives on
 * their stack); nothing in it needs freeing.
 */
#ifndef BG_ERROR_H
#define BG_ERROR_H

#include <stddef.h>

typedef enum bg_status {
    BG_OK = 0,
    BG_ERR_NOMEM = -1,      /* allocation failed */
    BG_ERR_IO = -2,         /* a file could not be opened, read or written */
    BG_ERR_PARSE = -3,      /* malformed input text */
    BG_ERR_INVALID = -4,    /* well-formed input with invalid content */
    BG_ERR_LIMIT = -5,      /* input exceeds a hard size cap */
    BG_ERR_NUMERIC = -6,    /* a numerical failure (factorization, NaN) */
    BG_ERR_UNSUPPORTED = -7, /* a valid request this build cannot serve */
    BG_ERR_NOT_FOUND = -8,   /* a file, job or record the input names does not exist */
    BG_ERR_CONFLICT = -9     /* the request does not fit the current state (a job already ended) */
} bg_status;

#define BG_ERROR_MESSAGE_MAX 512

typedef struct bg_error {
    bg_status status;
    char message[BG_ERROR_MESSAGE_MAX];
} bg_error_t;

#define BG_ERROR_INIT {BG_OK, {0}}

/* Returns a short constant name for a status ("out of memory", ...). */
const char *bg_strerror(bg_status status);

/*
 * Records status and a printf-style message in err (if err is non-NULL) and
 * returns status, so a failing path can `return bg_error_set(err, ...)`.
 * A message already recorded is kept: the first, most specific cause wins.
 */
bg_status bg_error_set(bg_error_t *err, bg_status status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* Clears err back to BG_OK with an empty message. */
void bg_error_clear(bg_error_t *err);

#endif
