#include "bgb_tokens.h"

#include <gnutls/crypto.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <sys/random.h>

#define PREFIX "bgt_"
#define ID_BYTES 8
#define SECRET_BYTES 32
#define SALT_BYTES 16
#define DIGEST_BYTES 32
/* 32 bytes in base64url without padding. */
#define SECRET_CHARS 43

static const char BASE64URL[] =
    "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";

int bgb_tokens_valid_user(const char *name)
{
    const size_t n = name ? strlen(name) : 0;
    if (n == 0 || n > BGB_USER_MAX)
        return 0;
    for (size_t i = 0; i < n; i++) {
        const char c = name[i];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '.' || c == '_' || c == '-'))
            return 0;
    }
    return 1;
}

static void to_hex(const uint8_t *bytes, size_t n, char *out)
{
    static const char hex[] = "0123456789abcdef";
    for (size_t i = 0; i < n; i++) {
        out[2 * i] = hex[bytes[i] >> 4];
        out[2 * i + 1] = hex[bytes[i] & 15];
    }
    out[2 * n] = '\0';
}

/* Hex text of exactly 2n digits into bytes; 0, or -1 when malformed. */
static int from_hex(const char *text, uint8_t *bytes, size_t n)
{
    for (size_t i = 0; i < 2 * n; i++) {
        const char c = text[i];
        const int v = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
        if (v < 0)
            return -1;
        bytes[i / 2] = (uint8_t)(i % 2 ? (bytes[i / 2] << 4) | v : v);
    }
    return text[2 * n] == '\0' ? 0 : -1;
}

/* 32 bytes as 43 base64url characters (the last one carries 4 bits). */
static void encode_secret(const uint8_t *bytes, char *out)
{
    int k = 0;
    for (int i = 0; i < SECRET_BYTES; i += 3) {
        const uint32_t b0 = bytes[i], b1 = i + 1 < SECRET_BYTES ? bytes[i + 1] : 0,
                       b2 = i + 2 < SECRET_BYTES ? bytes[i + 2] : 0;
        const uint32_t v = b0 << 16 | b1 << 8 | b2;
        const int chars = i + 2 < SECRET_BYTES ? 4 : i + 1 < SECRET_BYTES ? 3 : 2;
        for (int c = 0; c < chars; c++)
            out[k++] = BASE64URL[(v >> (18 - 6 * c)) & 63];
    }
    out[k] = '\0';
}

static int decode_secret(const char *text, uint8_t *bytes)
{
    if (strlen(text) != SECRET_CHARS)
        return -1;
    uint32_t acc = 0;
    int bits = 0, k = 0;
    for (int i = 0; i < SECRET_CHARS; i++) {
        const char *at = strchr(BASE64URL, text[i]);
        if (!at || !text[i])
            return -1;
        acc = acc << 6 | (uint32_t)(at - BASE64URL);
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            if (k < SECRET_BYTES)
                bytes[k++] = (uint8_t)(acc >> bits);
            acc &= (1u << bits) - 1;
        }
    }
    return k == SECRET_BYTES && acc == 0 ? 0 : -1;
}

static int digest(const uint8_t *salt, const uint8_t *secret, uint8_t *out)
{
    gnutls_hash_hd_t h;
    if (gnutls_hash_init(&h, GNUTLS_DIG_SHA256) < 0)
        return -1;
    gnutls_hash(h, salt, SALT_BYTES);
    gnutls_hash(h, secret, SECRET_BYTES);
    gnutls_hash_deinit(h, out);
    return 0;
}

static int random_bytes(uint8_t *out, size_t n)
{
    size_t got = 0;
    while (got < n) {
        const ssize_t r = getrandom(out + got, n - got, 0);
        if (r <= 0)
            return -1;
        got += (size_t)r;
    }
    return 0;
}

bg_status bgb_tokens_create(bgb_store_t *store, const char *user, int admin,
                            char token[BGB_TOKEN_SIZE], bg_error_t *err)
{
    token[0] = '\0';
    if (!bgb_tokens_valid_user(user))
        return bg_error_set(err, BG_ERR_INVALID,
                            "user '%s': a user name is 1 to %d of letters, digits, '.', '_', '-'",
                            user ? user : "", BGB_USER_MAX);
    uint8_t id[ID_BYTES], secret[SECRET_BYTES], salt[SALT_BYTES], hash[DIGEST_BYTES];
    if (random_bytes(id, sizeof id) || random_bytes(secret, sizeof secret) ||
        random_bytes(salt, sizeof salt))
        return bg_error_set(err, BG_ERR_IO, "no random bytes for a token");
    if (digest(salt, secret, hash) != 0)
        return bg_error_set(err, BG_ERR_IO, "cannot hash a token");
    char id_hex[2 * ID_BYTES + 1], salt_hex[2 * SALT_BYTES + 1], hash_hex[2 * DIGEST_BYTES + 1];
    to_hex(id, sizeof id, id_hex);
    to_hex(salt, sizeof salt, salt_hex);
    to_hex(hash, sizeof hash, hash_hex);
    const bgb_token_row_t row = {.id = id_hex, .user = user, .admin = admin != 0,
                                 .salt = salt_hex, .hash = hash_hex};
    const bg_status st = bgb_store_put_token(store, &row, err);
    if (st != BG_OK)
        return st;
    char text[SECRET_CHARS + 1];
    encode_secret(secret, text);
    snprintf(token, BGB_TOKEN_SIZE, PREFIX "%s_%s", id_hex, text);
    return BG_OK;
}

bg_status bgb_tokens_check(bgb_store_t *store, const char *token, char *user, int *admin,
                           bg_error_t *err)
{
    user[0] = '\0';
    *admin = 0;
    const size_t prefix = sizeof PREFIX - 1;
    char id_hex[2 * ID_BYTES + 1];
    uint8_t id[ID_BYTES], secret[SECRET_BYTES], salt[SALT_BYTES];
    uint8_t stored[DIGEST_BYTES] = {0}, hash[DIGEST_BYTES] = {0};
    bgb_token_record_t rec;
    memset(&rec, 0, sizeof rec);
    int ok = token && strlen(token) == BGB_TOKEN_SIZE - 1 && strncmp(token, PREFIX, prefix) == 0 &&
             token[prefix + 2 * ID_BYTES] == '_';
    if (ok) {
        memcpy(id_hex, token + prefix, 2 * ID_BYTES);
        id_hex[2 * ID_BYTES] = '\0';
        ok = from_hex(id_hex, id, sizeof id) == 0 &&
             decode_secret(token + prefix + 2 * ID_BYTES + 1, secret) == 0;
    }
    bg_error_t lookup = BG_ERROR_INIT;
    if (ok) {
        const bg_status st = bgb_store_get_token(store, id_hex, &rec, &lookup);
        if (st == BG_ERR_IO)
            return bg_error_set(err, BG_ERR_IO, "%s", lookup.message);
        ok = st == BG_OK && !rec.revoked && from_hex(rec.salt, salt, sizeof salt) == 0 &&
             from_hex(rec.hash, stored, sizeof stored) == 0 && digest(salt, secret, hash) == 0;
    }
    /* Constant time in the secret: every byte is compared whatever the first
     * difference, so the time says nothing about how much of it was right. */
    unsigned diff = ok ? 0u : 1u;
    for (int i = 0; i < DIGEST_BYTES; i++)
        diff |= (unsigned)(hash[i] ^ stored[i]) & (ok ? 0xffu : 0u);
    if (diff != 0)
        return bg_error_set(err, BG_ERR_NOT_FOUND, "the bearer token is not valid");
    snprintf(user, BGB_USER_MAX + 1, "%s", rec.user);
    *admin = rec.admin;
    return BG_OK;
}
