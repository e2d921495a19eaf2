#include "bg_error.h"

#include <stdarg.h>
#include <stdio.h>

const char *bg_strerror(bg_status status)
{
    switch (status) {
    case BG_OK: return "success";
    case BG_ERR_NOMEM: return "out of memory";
    case BG_ERR_IO: return "input/output error";
    case BG_ERR_PARSE: return "parse error";
    case BG_ERR_INVALID: return "invalid input";
    case BG_ERR_LIMIT: return "size limit exceeded";
    case BG_ERR_NUMERIC: return "numerical failure";
    case BG_ERR_UNSUPPORTED: return "unsupported";
    case BG_ERR_NOT_FOUND: return "not found";
    case BG_ERR_CONFLICT: return "conflict";
    }
    return "unknown status";
}

bg_status bg_error_set(bg_error_t *err, bg_status status, const char *fmt, ...)
{
    if (!err || err->status != BG_OK)
        return status;
    err->status = status;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err->message, sizeof err->message, fmt, ap);
    va_end(ap);
    return status;
}

void bg_error_clear(bg_error_t *err)
{
    if (!err)
        return;
    err->status = BG_OK;
    err->message[0] = '\0';
}
