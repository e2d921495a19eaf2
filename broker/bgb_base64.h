/*
 * bgb_base64 — RFC 4648 base64 (standard alphabet, '=' padding), for the
 * files a job uploads inside its JSON request. Pure functions.
 */
#ifndef BGB_BASE64_H
#define BGB_BASE64_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

/*
 * Decodes length characters of text into a new buffer (*out, caller frees;
 * *size its length). White space is not allowed; padding is required when
 * the length is not a multiple of 4 groups. BG_ERR_PARSE naming the offset
 * of the first bad character, BG_ERR_LIMIT when the result would exceed
 * max_bytes.
 */
bg_status bgb_base64_decode(const char *text, size_t length, size_t max_bytes, uint8_t **out,
                            size_t *size, bg_error_t *err);

/* Encodes size bytes into a new NUL-terminated string (caller frees); NULL without memory. */
char *bgb_base64_encode(const uint8_t *data, size_t size);

#endif
