#include "bgb_base64.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

static const char ALPHABET[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/* The value of each byte in the alphabet, -1 for the others; a table
 * instead of a chain of comparisons, since mesh files are decoded from
 * every submit that uploads them. */
static signed char VALUES[256];
static pthread_once_t values_once = PTHREAD_ONCE_INIT;

static void fill_values(void)
{
    memset(VALUES, -1, sizeof VALUES);
    for (int i = 0; i < 64; i++)
        VALUES[(unsigned char)ALPHABET[i]] = (signed char)i;
}

static int value_of(char c)
{
    return VALUES[(unsigned char)c];
}

bg_status bgb_base64_decode(const char *text, size_t length, size_t max_bytes, uint8_t **out,
                            size_t *size, bg_error_t *err)
{
    *out = NULL;
    *size = 0;
    pthread_once(&values_once, fill_values);
    if (length % 4 != 0)
        return bg_error_set(err, BG_ERR_PARSE,
                            "base64 text of %zu characters is not a whole number of 4-character "
                            "groups",
                            length);
    size_t padding = 0;
    if (length > 0 && text[length - 1] == '=')
        padding = length > 1 && text[length - 2] == '=' ? 2 : 1;
    const size_t bytes = length / 4 * 3 - padding;
    if (bytes > max_bytes)
        return bg_error_set(err, BG_ERR_LIMIT, "a file of %zu bytes exceeds the limit of %zu",
                            bytes, max_bytes);
    uint8_t *buf = malloc(bytes + 1);
    if (!buf)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory decoding %zu bytes", bytes);
    size_t o = 0;
    for (size_t i = 0; i < length; i += 4) {
        int v[4];
        for (int k = 0; k < 4; k++) {
            const size_t at = i + k;
            const int pad_allowed = at >= length - padding;
            v[k] = pad_allowed && text[at] == '=' ? 0 : value_of(text[at]);
            if (v[k] < 0 || (!pad_allowed && text[at] == '=')) {
                free(buf);
                return bg_error_set(err, BG_ERR_PARSE, "bad base64 character at offset %zu",
                                    at);
            }
        }
        const uint32_t group = (uint32_t)v[0] << 18 | (uint32_t)v[1] << 12 |
                               (uint32_t)v[2] << 6 | (uint32_t)v[3];
        const uint8_t three[3] = {(uint8_t)(group >> 16), (uint8_t)(group >> 8), (uint8_t)group};
        for (int k = 0; k < 3 && o < bytes; k++)
            buf[o++] = three[k];
    }
    *out = buf;
    *size = bytes;
    return BG_OK;
}

char *bgb_base64_encode(const uint8_t *data, size_t size)
{
    const size_t length = (size + 2) / 3 * 4;
    char *text = malloc(length + 1);
    if (!text)
        return NULL;
    size_t o = 0;
    for (size_t i = 0; i < size; i += 3) {
        const uint32_t b0 = data[i], b1 = i + 1 < size ? data[i + 1] : 0,
                       b2 = i + 2 < size ? data[i + 2] : 0;
        const uint32_t group = b0 << 16 | b1 << 8 | b2;
        text[o++] = ALPHABET[group >> 18 & 63];
        text[o++] = ALPHABET[group >> 12 & 63];
        text[o++] = i + 1 < size ? ALPHABET[group >> 6 & 63] : '=';
        text[o++] = i + 2 < size ? ALPHABET[group & 63] : '=';
    }
    text[o] = '\0';
    return text;
}
