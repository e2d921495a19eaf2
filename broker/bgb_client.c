#include "bgb_client.h"

#include <curl/curl.h>
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bg_file.h"
#include "bg_mesh_io.h"
#include "bg_scene.h"
#include "bgb_base64.h"
#include "bgb_store.h"

#define CLIENT_CONNECT_TIMEOUT_MS 5000L
#define CLIENT_TIMEOUT_MS 120000L
#define CLIENT_MAX_RESPONSE ((size_t)16 << 20)
#define CLIENT_MAX_FILE ((size_t)1 << 30)
#define CLIENT_MAX_EVENT ((size_t)1 << 20)
/* One uploaded file; the broker's own body cap (64 MiB by default) bites first. */
#define CLIENT_MAX_UPLOAD ((size_t)256 << 20)
/* A stream silent this long is dead: the broker sends a keep-alive every 15 s. */
#define CLIENT_STREAM_SILENCE_S 60L
#define CLIENT_URL_MAX 4096
#define SSE_FIELD_MAX 256

struct bgb_client {
    CURL *curl;
    char *url;
    char *authorization; /* "Authorization: Bearer TOKEN", or NULL */
    char *cacert;        /* the --cacert file, or NULL */
    bgb_client_config_t config;
    long status;
    char curl_error[CURL_ERROR_SIZE]; /* libcurl's detail of the last failure */
};

/* ------------------------------------------------ server-sent events */

struct bgb_sse {
    size_t max;
    bgb_sse_fn fn;
    void *ctx;
    char *line; /* the line being read (max + 1 bytes) */
    size_t line_size;
    char *data; /* the event's data lines, '\n'-joined (max + 1 bytes) */
    size_t data_size;
    int has_data;
    char event[SSE_FIELD_MAX + 1];
    char id[SSE_FIELD_MAX + 1]; /* the last event id: it persists across events */
    int after_cr;               /* the previous byte ended a line with '\r' */
    int stopped;
};

bg_status bgb_sse_new(size_t max_event, bgb_sse_fn fn, void *ctx, bgb_sse_t **out, bg_error_t *err)
{
    *out = NULL;
    bgb_sse_t *s = calloc(1, sizeof *s);
    if (!s)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for an event stream");
    s->max = max_event ? max_event : CLIENT_MAX_EVENT;
    s->fn = fn;
    s->ctx = ctx;
    s->line = malloc(s->max + 1);
    s->data = malloc(s->max + 1);
    if (!s->line || !s->data) {
        bgb_sse_destroy(&s);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for an event stream");
    }
    *out = s;
    return BG_OK;
}

void bgb_sse_destroy(bgb_sse_t **sse)
{
    if (!sse || !*sse)
        return;
    free((*sse)->line);
    free((*sse)->data);
    free(*sse);
    *sse = NULL;
}

static void sse_dispatch(bgb_sse_t *s)
{
    if (s->has_data) {
        if (s->data_size > 0 && s->data[s->data_size - 1] == '\n')
            s->data_size--;
        s->data[s->data_size] = '\0';
        if (s->fn(s->ctx, s->id, s->event[0] ? s->event : "message", s->data) != 0)
            s->stopped = 1;
    }
    s->data_size = 0;
    s->has_data = 0;
    s->event[0] = '\0';
}

static bg_status sse_line(bgb_sse_t *s, bg_error_t *err)
{
    char *line = s->line;
    line[s->line_size] = '\0';
    if (s->line_size == 0) {
        sse_dispatch(s);
        return BG_OK;
    }
    if (line[0] == ':')
        return BG_OK;
    char *colon = memchr(line, ':', s->line_size);
    const char *value = "";
    size_t value_size = 0;
    if (colon) {
        *colon = '\0';
        value = colon + 1;
        if (*value == ' ')
            value++;
        value_size = s->line_size - (size_t)(value - line);
    }
    if (strcmp(line, "data") == 0) {
        if (s->data_size + value_size + 1 > s->max)
            return bg_error_set(err, BG_ERR_LIMIT,
                                "event stream: an event's data exceeds %zu bytes", s->max);
        memcpy(s->data + s->data_size, value, value_size);
        s->data_size += value_size;
        s->data[s->data_size++] = '\n';
        s->has_data = 1;
    } else if (strcmp(line, "event") == 0) {
        snprintf(s->event, sizeof s->event, "%s", value);
    } else if (strcmp(line, "id") == 0) {
        snprintf(s->id, sizeof s->id, "%s", value);
    }
    return BG_OK;
}

bg_status bgb_sse_feed(bgb_sse_t *s, const char *bytes, size_t n, int *stopped, bg_error_t *err)
{
    bg_status st = BG_OK;
    for (size_t i = 0; i < n && !s->stopped && st == BG_OK; i++) {
        const char b = bytes[i];
        if (b == '\n' && s->after_cr) {
            s->after_cr = 0;
            continue;
        }
        s->after_cr = b == '\r';
        if (b == '\n' || b == '\r') {
            st = sse_line(s, err);
            s->line_size = 0;
            continue;
        }
        if (s->line_size >= s->max) {
            st = bg_error_set(err, BG_ERR_LIMIT, "event stream: a line exceeds %zu bytes", s->max);
            break;
        }
        s->line[s->line_size++] = b;
    }
    if (stopped)
        *stopped = s->stopped;
    return st;
}

/* ------------------------------------------------------------ the handle */

bg_status bgb_client_new(const bgb_client_config_t *config, bgb_client_t **out, bg_error_t *err)
{
    *out = NULL;
    if (!config->url || !config->url[0])
        return bg_error_set(err, BG_ERR_INVALID, "no broker URL");
    if (strncmp(config->url, "http://", 7) != 0 && strncmp(config->url, "https://", 8) != 0)
        return bg_error_set(err, BG_ERR_INVALID,
                            "broker URL '%s': expected http://HOST:PORT or https://HOST:PORT",
                            config->url);
    if (strlen(config->url) > CLIENT_URL_MAX / 2)
        return bg_error_set(err, BG_ERR_INVALID, "broker URL is too long");
    if (curl_global_init(CURL_GLOBAL_DEFAULT) != CURLE_OK)
        return bg_error_set(err, BG_ERR_IO, "cannot initialise libcurl");
    bgb_client_t *c = calloc(1, sizeof *c);
    if (!c) {
        curl_global_cleanup();
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the client");
    }
    c->config = *config;
    if (c->config.connect_timeout_ms <= 0)
        c->config.connect_timeout_ms = CLIENT_CONNECT_TIMEOUT_MS;
    if (c->config.timeout_ms <= 0)
        c->config.timeout_ms = CLIENT_TIMEOUT_MS;
    if (!c->config.max_response)
        c->config.max_response = CLIENT_MAX_RESPONSE;
    if (!c->config.max_file)
        c->config.max_file = CLIENT_MAX_FILE;
    c->url = strdup(config->url);
    c->curl = curl_easy_init();
    if (config->token && config->token[0]) {
        if (strpbrk(config->token, "\r\n") || strlen(config->token) > CLIENT_URL_MAX) {
            bgb_client_destroy(&c);
            return bg_error_set(err, BG_ERR_INVALID, "the token is not one line of at most %d "
                                "bytes", CLIENT_URL_MAX);
        }
        const size_t size = strlen(config->token) + 32;
        if ((c->authorization = malloc(size)) != NULL)
            snprintf(c->authorization, size, "Authorization: Bearer %s", config->token);
    }
    c->config.token = NULL; /* held as the header above */
    if (config->cacert && config->cacert[0])
        c->cacert = strdup(config->cacert);
    c->config.cacert = c->cacert;
    if (!c->url || !c->curl || (config->token && config->token[0] && !c->authorization) ||
        (config->cacert && config->cacert[0] && !c->cacert)) {
        bgb_client_destroy(&c);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the client");
    }
    size_t n = strlen(c->url);
    while (n > 0 && c->url[n - 1] == '/')
        c->url[--n] = '\0';
    c->config.url = c->url;
    *out = c;
    return BG_OK;
}

void bgb_client_destroy(bgb_client_t **client)
{
    if (!client || !*client)
        return;
    if ((*client)->curl)
        curl_easy_cleanup((*client)->curl);
    free((*client)->url);
    free((*client)->authorization);
    free((*client)->cacert);
    free(*client);
    *client = NULL;
    /* Pairs bgb_client_new's curl_global_init (libcurl counts them). */
    curl_global_cleanup();
}

const char *bgb_client_url(const bgb_client_t *client)
{
    return client->url;
}

long bgb_client_http_status(const bgb_client_t *client)
{
    return client->status;
}

/* ------------------------------------------------------------- requests */

/* Where a response body goes: a capped memory buffer, a file, or an event parser. */
typedef struct sink {
    char *data;
    size_t size, max;
    int over;
    int fd;         /* >= 0: the body goes to this file */
    bgb_sse_t *sse; /* non-NULL: the body is an event stream */
    bg_status sse_status;
    bg_error_t sse_err;
    int stopped;
    long status; /* the response's status, read when the body starts */
    CURL *curl;
} sink_t;

static size_t on_body(char *bytes, size_t size, size_t count, void *ctx)
{
    sink_t *s = ctx;
    const size_t n = size * count;
    if (!s->status)
        curl_easy_getinfo(s->curl, CURLINFO_RESPONSE_CODE, &s->status);
    /* An error response is always read to memory, to report its problem document. */
    const int success = s->status >= 200 && s->status < 300;
    if (success && s->sse) {
        s->sse_status = bgb_sse_feed(s->sse, bytes, n, &s->stopped, &s->sse_err);
        return s->sse_status == BG_OK && !s->stopped ? n : 0;
    }
    if (s->size + n > s->max) {
        s->over = 1;
        return 0;
    }
    if (success && s->fd >= 0) {
        size_t done = 0;
        while (done < n) {
            const ssize_t w = write(s->fd, bytes + done, n - done);
            if (w <= 0)
                return 0;
            done += (size_t)w;
        }
        s->size += n;
        return n;
    }
    char *grown = realloc(s->data, s->size + n + 1);
    if (!grown)
        return 0;
    s->data = grown;
    memcpy(s->data + s->size, bytes, n);
    s->size += n;
    s->data[s->size] = '\0';
    return n;
}

/* A problem document (or any error body) as the message of a failed request. */
static bg_status problem_error(const char *method, const char *url, long status, const sink_t *s,
                               bg_error_t *err)
{
    const bg_status st = status == 404                   ? BG_ERR_NOT_FOUND
                         : status == 409                 ? BG_ERR_CONFLICT
                         : status == 413                 ? BG_ERR_LIMIT
                         : status >= 400 && status < 500 ? BG_ERR_INVALID
                                                         : BG_ERR_IO;
    cJSON *doc = s->data ? cJSON_ParseWithLength(s->data, s->size) : NULL;
    const cJSON *title = cJSON_GetObjectItemCaseSensitive(doc, "title");
    const cJSON *detail = cJSON_GetObjectItemCaseSensitive(doc, "detail");
    const cJSON *field = cJSON_GetObjectItemCaseSensitive(doc, "field");
    bg_status out;
    if (cJSON_IsString(title) && cJSON_IsString(detail)) {
        char where[160] = "";
        if (cJSON_IsString(field))
            snprintf(where, sizeof where, " (field %s)", field->valuestring);
        out = bg_error_set(err, st, "%s %s: %ld %s: %s%s", method, url, status, title->valuestring,
                           detail->valuestring, where);
    } else {
        const size_t shown = s->size < 200 ? s->size : 200;
        out = bg_error_set(err, st, "%s %s: HTTP %ld%s%.*s", method, url, status, shown ? ": " : "",
                           (int)shown, s->data ? s->data : "");
    }
    cJSON_Delete(doc);
    return out;
}

/*
 * One request to path (already escaped) with an optional JSON body and an
 * optional header (Idempotency-Key, Last-Event-ID). The response goes to the sink; on a non-2xx
 * status the error names the server's problem. stream: no overall timeout.
 */
static bg_status perform(bgb_client_t *c, const char *method, const char *path, const char *body,
                         const char *header, const char *value, sink_t *s, int stream,
                         bg_error_t *err)
{
    char url[CLIENT_URL_MAX];
    if ((size_t)snprintf(url, sizeof url, "%s%s", c->url, path) >= sizeof url)
        return bg_error_set(err, BG_ERR_INVALID, "request URL too long");
    CURL *curl = c->curl;
    struct curl_slist *headers = NULL;
    bg_status st = BG_OK;
    char key_header[BGB_STORE_MAX_KEY + 32];
    curl_easy_reset(curl);
    c->status = 0;
    s->curl = curl;
    s->status = 0;
    curl_easy_setopt(curl, CURLOPT_URL, url);
    curl_easy_setopt(curl, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(curl, CURLOPT_CONNECTTIMEOUT_MS, c->config.connect_timeout_ms);
    if (stream) {
        curl_easy_setopt(curl, CURLOPT_LOW_SPEED_LIMIT, 1L);
        curl_easy_setopt(curl, CURLOPT_LOW_SPEED_TIME, CLIENT_STREAM_SILENCE_S);
    } else {
        curl_easy_setopt(curl, CURLOPT_TIMEOUT_MS, c->config.timeout_ms);
    }
    curl_easy_setopt(curl, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(curl, CURLOPT_WRITEDATA, s);
    curl_easy_setopt(curl, CURLOPT_PROTOCOLS_STR, "http,https");
    c->curl_error[0] = '\0';
    curl_easy_setopt(curl, CURLOPT_ERRORBUFFER, c->curl_error);
    if (c->cacert)
        curl_easy_setopt(curl, CURLOPT_CAINFO, c->cacert);
    headers = curl_slist_append(headers,
                                stream ? "Accept: text/event-stream" : "Accept: application/json");
    if (c->authorization)
        headers = curl_slist_append(headers, c->authorization);
    if (body) {
        headers = curl_slist_append(headers, "Content-Type: application/json");
        curl_easy_setopt(curl, CURLOPT_POSTFIELDS, body);
        curl_easy_setopt(curl, CURLOPT_POSTFIELDSIZE_LARGE, (curl_off_t)strlen(body));
        /* The broker answers an oversized body with 413 at once: no 100-continue wait. */
        headers = curl_slist_append(headers, "Expect:");
    } else if (strcmp(method, "POST") == 0) {
        curl_easy_setopt(curl, CURLOPT_POSTFIELDS, "");
        curl_easy_setopt(curl, CURLOPT_POSTFIELDSIZE_LARGE, (curl_off_t)0);
    }
    if (header && value && value[0]) {
        if (strlen(value) > BGB_STORE_MAX_KEY || strpbrk(value, "\r\n")) {
            st = bg_error_set(err, BG_ERR_INVALID, "%s: at most %d bytes on one line", header,
                              BGB_STORE_MAX_KEY);
            goto out;
        }
        snprintf(key_header, sizeof key_header, "%s: %s", header, value);
        headers = curl_slist_append(headers, key_header);
    }
    curl_easy_setopt(curl, CURLOPT_HTTPHEADER, headers);
    const CURLcode rc = curl_easy_perform(curl);
    long status = 0;
    curl_easy_getinfo(curl, CURLINFO_RESPONSE_CODE, &status);
    c->status = status;
    if (s->over) {
        st = bg_error_set(err, BG_ERR_LIMIT,
                          "%s %s: the response exceeds the client's limit of "
                          "%zu bytes",
                          method, url, s->max);
        goto out;
    }
    if (s->sse && s->sse_status != BG_OK) {
        st = bg_error_set(err, s->sse_status, "%s %s: %s", method, url, s->sse_err.message);
        goto out;
    }
    if (rc == CURLE_WRITE_ERROR && s->stopped)
        goto out;
    if (rc == CURLE_COULDNT_CONNECT || rc == CURLE_COULDNT_RESOLVE_HOST) {
        st = bg_error_set(err, BG_ERR_IO,
                          "cannot reach the broker at %s (%s): start one with `biotgrid grid up` "
                          "(a local grid with its broker) or `biotgrid broker`, or name another "
                          "broker's URL",
                          c->url, curl_easy_strerror(rc));
        goto out;
    }
    if (rc == CURLE_PEER_FAILED_VERIFICATION || rc == CURLE_SSL_CACERT_BADFILE) {
        st = bg_error_set(err, BG_ERR_IO,
                          "%s: the broker's TLS certificate is not trusted (%s): give the "
                          "certificate of the CA that signed it, or its own when self-signed, "
                          "with --cacert FILE",
                          c->url, c->curl_error[0] ? c->curl_error : curl_easy_strerror(rc));
        goto out;
    }
    if (rc == CURLE_GOT_NOTHING && strncmp(c->url, "http://", 7) == 0) {
        st = bg_error_set(err, BG_ERR_IO,
                          "%s %s: the broker closed the connection without an answer (does it "
                          "serve https? then name it https://)",
                          method, url);
        goto out;
    }
    if (rc != CURLE_OK && !(status >= 400 && rc == CURLE_SEND_ERROR)) {
        st = bg_error_set(err, BG_ERR_IO, "%s %s: %s", method, url,
                          c->curl_error[0] ? c->curl_error : curl_easy_strerror(rc));
        goto out;
    }
    if (status < 200 || status >= 300)
        st = problem_error(method, url, status, s, err);
out:
    curl_slist_free_all(headers);
    return st;
}

/* A request whose 2xx answer is a JSON document. */
static bg_status request_json(bgb_client_t *c, const char *method, const char *path,
                              const char *body, const char *key, cJSON **out, bg_error_t *err)
{
    *out = NULL;
    sink_t s = {.max = c->config.max_response, .fd = -1};
    bg_status st = perform(c, method, path, body, key ? "Idempotency-Key" : NULL, key, &s, 0, err);
    if (st != BG_OK)
        goto out;
    *out = s.data ? cJSON_ParseWithLength(s.data, s.size) : NULL;
    if (!*out)
        st = bg_error_set(err, BG_ERR_PARSE, "%s %s%s: the broker's answer is not JSON", method,
                          c->url, path);
out:
    free(s.data);
    return st;
}

/* "/v1/jobs/<escaped id><suffix>". */
static bg_status job_path(bgb_client_t *c, const char *id, const char *suffix, char *path,
                          size_t size, bg_error_t *err)
{
    if (!id || !id[0])
        return bg_error_set(err, BG_ERR_INVALID, "no job id");
    char *escaped = curl_easy_escape(c->curl, id, 0);
    if (!escaped)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    const int n = snprintf(path, size, "/v1/jobs/%s%s", escaped, suffix);
    curl_free(escaped);
    if (n < 0 || (size_t)n >= size)
        return bg_error_set(err, BG_ERR_INVALID, "job id too long");
    return BG_OK;
}

bg_status bgb_client_submit_job(bgb_client_t *c, const bgb_client_submit_t *submit, cJSON **job,
                                bg_error_t *err)
{
    *job = NULL;
    char *body = NULL;
    bg_status st = bgb_client_pack(submit, &body, err);
    if (st == BG_OK)
        st = request_json(c, "POST", "/v1/jobs", body, submit->idempotency_key, job, err);
    free(body);
    return st;
}

bg_status bgb_client_list_jobs(bgb_client_t *c, const char *state, int limit, const char *cursor,
                               cJSON **page, bg_error_t *err)
{
    *page = NULL;
    char path[1024];
    size_t n = (size_t)snprintf(path, sizeof path, "/v1/jobs");
    char sep = '?';
    const char *names[2] = {"state", "cursor"};
    const char *values[2] = {state, cursor};
    for (int i = 0; i < 2; i++) {
        if (!values[i])
            continue;
        char *escaped = curl_easy_escape(c->curl, values[i], 0);
        if (!escaped)
            return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        n += (size_t)snprintf(path + n, sizeof path - n, "%c%s=%s", sep, names[i], escaped);
        curl_free(escaped);
        sep = '&';
        if (n >= sizeof path)
            return bg_error_set(err, BG_ERR_INVALID, "%s too long", names[i]);
    }
    if (limit > 0)
        n += (size_t)snprintf(path + n, sizeof path - n, "%climit=%d", sep, limit);
    if (n >= sizeof path)
        return bg_error_set(err, BG_ERR_INVALID, "query too long");
    return request_json(c, "GET", path, NULL, NULL, page, err);
}

bg_status bgb_client_get_job(bgb_client_t *c, const char *id, cJSON **out, bg_error_t *err)
{
    *out = NULL;
    char path[512];
    bg_status st = job_path(c, id, "", path, sizeof path, err);
    return st == BG_OK ? request_json(c, "GET", path, NULL, NULL, out, err) : st;
}

bg_status bgb_client_cancel_job(bgb_client_t *c, const char *id, cJSON **out, bg_error_t *err)
{
    *out = NULL;
    char path[512];
    bg_status st = job_path(c, id, "/cancel", path, sizeof path, err);
    return st == BG_OK ? request_json(c, "POST", path, NULL, NULL, out, err) : st;
}

bg_status bgb_client_result(bgb_client_t *c, const char *id, cJSON **out, bg_error_t *err)
{
    *out = NULL;
    char path[512];
    bg_status st = job_path(c, id, "/result", path, sizeof path, err);
    return st == BG_OK ? request_json(c, "GET", path, NULL, NULL, out, err) : st;
}

bg_status bgb_client_agents(bgb_client_t *c, cJSON **out, bg_error_t *err)
{
    return request_json(c, "GET", "/v1/agents", NULL, NULL, out, err);
}

bg_status bgb_client_market(bgb_client_t *c, cJSON **out, bg_error_t *err)
{
    return request_json(c, "GET", "/v1/market", NULL, NULL, out, err);
}

bg_status bgb_client_health(bgb_client_t *c, cJSON **out, bg_error_t *err)
{
    return request_json(c, "GET", "/healthz", NULL, NULL, out, err);
}

bg_status bgb_client_download(bgb_client_t *c, const char *id, const char *name, const char *dir,
                              size_t *size, bg_error_t *err)
{
    if (size)
        *size = 0;
    bg_status st = bgb_store_check_file_name(name, "result file name", err);
    if (st != BG_OK)
        return st;
    char path[1024], target[4096], temp[4096];
    char *escaped = curl_easy_escape(c->curl, name, 0);
    if (!escaped)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    char suffix[800];
    const int n = snprintf(suffix, sizeof suffix, "/result/%s", escaped);
    curl_free(escaped);
    if (n < 0 || (size_t)n >= sizeof suffix)
        return bg_error_set(err, BG_ERR_INVALID, "result file name too long");
    if ((st = job_path(c, id, suffix, path, sizeof path, err)) != BG_OK)
        return st;
    if ((size_t)snprintf(target, sizeof target, "%s/%s", dir, name) >= sizeof target ||
        (size_t)snprintf(temp, sizeof temp, "%s/.%s.XXXXXX", dir, name) >= sizeof temp)
        return bg_error_set(err, BG_ERR_INVALID, "%s/%s: path too long", dir, name);
    sink_t s = {.max = c->config.max_file, .fd = mkstemp(temp)};
    if (s.fd < 0)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot create a file there: %s", dir,
                            strerror(errno));
    st = perform(c, "GET", path, NULL, NULL, NULL, &s, 0, err);
    if (close(s.fd) != 0 && st == BG_OK)
        st = bg_error_set(err, BG_ERR_IO, "%s: %s", temp, strerror(errno));
    if (st == BG_OK && rename(temp, target) != 0)
        st = bg_error_set(err, BG_ERR_IO, "%s: %s", target, strerror(errno));
    if (st != BG_OK)
        unlink(temp);
    else if (size)
        *size = s.size;
    free(s.data);
    return st;
}

bg_status bgb_client_events(bgb_client_t *c, const char *id, const char *last_event_id,
                            bgb_sse_fn fn, void *ctx, bg_error_t *err)
{
    char path[512];
    bg_status st = job_path(c, id, "/events", path, sizeof path, err);
    if (st != BG_OK)
        return st;
    sink_t s = {.max = c->config.max_response, .fd = -1};
    if ((st = bgb_sse_new(0, fn, ctx, &s.sse, err)) != BG_OK)
        return st;
    st = perform(c, "GET", path, NULL, "Last-Event-ID", last_event_id, &s, 1, err);
    bgb_sse_destroy(&s.sse);
    free(s.data);
    return st;
}

/* ------------------------------------------------------------- packing */

typedef struct upload {
    char *path; /* as resolved */
    char name[BGB_STORE_MAX_FILE_NAME + 1];
} upload_t;

typedef struct packer {
    const char *scene_path;
    char dir[4096]; /* the scene's folder, with a trailing '/' (or "") */
    const char *search_path;
    upload_t files[BGB_STORE_MAX_FILES];
    int count;
} packer_t;

static int is_file(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 && S_ISREG(sb.st_mode);
}

/* Where `solve` finds a file (bg_file_lookup), but only a regular file:
 * the client reads it whole for the upload. */
static bg_status find_file(packer_t *p, const char *field, const char *relative, char **out,
                           bg_error_t *err)
{
    *out = NULL;
    if (!relative[0])
        return bg_error_set(err, BG_ERR_INVALID, "%s: %s: empty path", p->scene_path, field);
    const char *folders = p->search_path ? p->search_path : "";
    char *tried = NULL;
    const char *why = "";
    bg_status st = bg_file_lookup(p->dir, relative, folders, BG_FILE_REGULAR, out, &tried, &why);
    if (st == BG_ERR_NOMEM)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    if (st != BG_OK) {
        const char *slash = strrchr(relative, '/');
        st = bg_error_set(err, BG_ERR_NOT_FOUND,
                          "%s: %s: %s not found: no file %s (%s), and no %s in the mesh search "
                          "path (%s)",
                          p->scene_path, field, relative, tried ? tried : relative,
                          why, slash ? slash + 1 : relative,
                          folders[0] ? folders : "empty");
    }
    free(tried);
    return st;
}

/* Whether name is unused, or already names path. */
static int name_free(const packer_t *p, const char *name, const char *path)
{
    for (int i = 0; i < p->count; i++)
        if (strcmp(p->files[i].name, name) == 0)
            return strcmp(p->files[i].path, path) == 0;
    return 1;
}

static const upload_t *find_upload(const packer_t *p, const char *path)
{
    for (int i = 0; i < p->count; i++)
        if (strcmp(p->files[i].path, path) == 0)
            return &p->files[i];
    return NULL;
}

static bg_status add_upload(packer_t *p, const char *field, const char *path, const char *name,
                            bg_error_t *err)
{
    if (find_upload(p, path))
        return BG_OK;
    if (p->count == BGB_STORE_MAX_FILES)
        return bg_error_set(err, BG_ERR_LIMIT, "%s: %s: the scene names more than %d files",
                            p->scene_path, field, BGB_STORE_MAX_FILES);
    upload_t *u = &p->files[p->count];
    u->path = strdup(path);
    if (!u->path)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    snprintf(u->name, sizeof u->name, "%s", name);
    p->count++;
    return BG_OK;
}

/* "2-name", "3-name", ... for the k-th candidate (k = 1: name itself). */
static int candidate_name(char *out, size_t size, int k, const char *name)
{
    const int n = k == 1 ? snprintf(out, size, "%s", name) : snprintf(out, size, "%d-%s", k, name);
    return n > 0 && (size_t)n < size;
}

/* The TetGen companion of a .node or .ele path (same stem, other suffix), or 0. */
static int tetgen_companion(const char *path, char *out, size_t size)
{
    const char *dot = strrchr(path, '.');
    const char *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash))
        return 0;
    const char *other = strcmp(dot, ".node") == 0  ? ".ele"
                        : strcmp(dot, ".ele") == 0 ? ".node"
                                                   : NULL;
    if (!other)
        return 0;
    const int n = snprintf(out, size, "%.*s%s", (int)(dot - path), path, other);
    return n > 0 && (size_t)n < size;
}

/* Uploads the file at item (a string member `key` of parent) and renames it in the scene. */
static bg_status pack_ref(packer_t *p, cJSON *parent, const char *key, const char *field, int mesh,
                          bg_error_t *err)
{
    cJSON *item = cJSON_GetObjectItemCaseSensitive(parent, key);
    if (!cJSON_IsString(item))
        return BG_OK; /* not a file reference: the broker validates the rest */
    char *path = NULL;
    bg_status st = find_file(p, field, item->valuestring, &path, err);
    if (st != BG_OK)
        return st;
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    char companion[4096], companion_base[BGB_STORE_MAX_FILE_NAME + 1];
    const int pair = mesh && tetgen_companion(path, companion, sizeof companion);
    if (pair) {
        if (!is_file(companion)) {
            st = bg_error_set(err, BG_ERR_NOT_FOUND, "%s: %s: a TetGen mesh needs %s beside %s",
                              p->scene_path, field, companion, path);
            goto out;
        }
        tetgen_companion(base, companion_base, sizeof companion_base);
    }
    char name[BGB_STORE_MAX_FILE_NAME + 1], name2[BGB_STORE_MAX_FILE_NAME + 1];
    const upload_t *known = find_upload(p, path);
    if (known) {
        snprintf(name, sizeof name, "%s", known->name);
    } else {
        for (int k = 1;; k++) {
            if (k > BGB_STORE_MAX_FILES + 1 || !candidate_name(name, sizeof name, k, base) ||
                (pair && !candidate_name(name2, sizeof name2, k, companion_base))) {
                st = bg_error_set(err, BG_ERR_INVALID, "%s: %s: cannot name %s for upload",
                                  p->scene_path, field, path);
                goto out;
            }
            if (name_free(p, name, path) && (!pair || name_free(p, name2, companion)))
                break;
        }
        if ((st = bgb_store_check_file_name(name, field, err)) != BG_OK ||
            (st = add_upload(p, field, path, name, err)) != BG_OK ||
            (pair && (st = add_upload(p, field, companion, name2, err)) != BG_OK))
            goto out;
    }
    if (!cJSON_ReplaceItemInObjectCaseSensitive(parent, key, cJSON_CreateString(name)))
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory");
out:
    free(path);
    return st;
}

/* Every place a scene names a file (services/bg_scene.c: resolve_path's callers). */
static bg_status pack_refs(packer_t *p, cJSON *scene, bg_error_t *err)
{
    bg_status st = pack_ref(p, scene, "mesh", "mesh", 1, err);
    cJSON *mesh = cJSON_GetObjectItemCaseSensitive(scene, "mesh");
    if (st == BG_OK && cJSON_IsObject(mesh))
        st = pack_ref(p, mesh, "file", "mesh.file", 1, err);
    const char *objects[] = {"initial", "reference"};
    for (int i = 0; i < 2 && st == BG_OK; i++) {
        cJSON *o = cJSON_GetObjectItemCaseSensitive(scene, objects[i]);
        char field[64];
        snprintf(field, sizeof field, "%s.positions", objects[i]);
        if (cJSON_IsObject(o))
            st = pack_ref(p, o, "positions", field, 0, err);
    }
    cJSON *task = cJSON_GetObjectItemCaseSensitive(scene, "task");
    if (st == BG_OK && cJSON_IsObject(task))
        st = pack_ref(p, task, "target", "task.target", 0, err);
    cJSON *handles = cJSON_GetObjectItemCaseSensitive(scene, "handles");
    int index = 0;
    for (cJSON *h = cJSON_IsArray(handles) ? handles->child : NULL; h && st == BG_OK;
         h = h->next, index++) {
        if (!cJSON_IsObject(h))
            continue;
        char field[96];
        cJSON *select = cJSON_GetObjectItemCaseSensitive(h, "select");
        snprintf(field, sizeof field, "handles[%d].select.file", index);
        if (cJSON_IsObject(select))
            st = pack_ref(p, select, "file", field, 0, err);
        snprintf(field, sizeof field, "handles[%d].positions", index);
        if (st == BG_OK)
            st = pack_ref(p, h, "positions", field, 0, err);
    }
    return st;
}

static void line_of(const char *text, size_t offset, int *line, int *column)
{
    *line = 1;
    *column = 1;
    for (size_t i = 0; i < offset; i++) {
        if (text[i] == '\n') {
            (*line)++;
            *column = 1;
        } else {
            (*column)++;
        }
    }
}

/* Replaces member key of object by item (taken over, freed on failure). */
static bg_status set_member(cJSON *object, const char *key, cJSON *item, bg_error_t *err)
{
    cJSON_DeleteItemFromObjectCaseSensitive(object, key);
    if (!item || !cJSON_AddItemToObject(object, key, item)) {
        cJSON_Delete(item);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    }
    return BG_OK;
}

/* The submission's solver settings into the scene's "solver" object. */
static bg_status set_solver(cJSON *scene, const bgb_client_submit_t *s, bg_error_t *err)
{
    if (!s->method && !(s->tolerance > 0.0) && s->max_iterations <= 0 && !s->inner)
        return BG_OK;
    cJSON *solver = cJSON_GetObjectItemCaseSensitive(scene, "solver");
    if (!solver && !(solver = cJSON_AddObjectToObject(scene, "solver")))
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory");
    if (!cJSON_IsObject(solver))
        return bg_error_set(err, BG_ERR_INVALID, "%s: solver: expected an object",
                            s->scene_path);
    bg_status st = BG_OK;
    if (s->method)
        st = set_member(solver, "method", cJSON_CreateString(s->method), err);
    if (st == BG_OK && s->tolerance > 0.0)
        st = set_member(solver, "tolerance", cJSON_CreateNumber(s->tolerance), err);
    if (st == BG_OK && s->max_iterations > 0)
        st = set_member(solver, "max_iterations", cJSON_CreateNumber(s->max_iterations), err);
    if (st == BG_OK && s->inner)
        st = set_member(solver, "inner", cJSON_CreateString(s->inner), err);
    return st;
}

bg_status bgb_client_pack(const bgb_client_submit_t *submit, char **body, bg_error_t *err)
{
    *body = NULL;
    packer_t p;
    memset(&p, 0, sizeof p);
    p.scene_path = submit->scene_path;
    p.search_path = submit->search_path;
    char *text = NULL;
    size_t length = 0;
    cJSON *scene = NULL, *root = NULL;
    bg_status st = bg_file_read_all(submit->scene_path, BG_SCENE_MAX_BYTES, &text, &length, err);
    if (st != BG_OK)
        goto out;
    const char *slash = strrchr(submit->scene_path, '/');
    if (slash) {
        const size_t n = (size_t)(slash - submit->scene_path) + 1;
        if (n >= sizeof p.dir) {
            st = bg_error_set(err, BG_ERR_INVALID, "%s: path too long", submit->scene_path);
            goto out;
        }
        memcpy(p.dir, submit->scene_path, n);
        p.dir[n] = '\0';
    }
    if (length == 0) {
        st = bg_error_set(err, BG_ERR_PARSE, "%s: empty file", submit->scene_path);
        goto out;
    }
    const char *end = NULL;
    scene = cJSON_ParseWithLengthOpts(text, length, &end, 0);
    if (!scene) {
        int line = 0, column = 0;
        const size_t at =
            end && end >= text && end <= text + length ? (size_t)(end - text) : length;
        line_of(text, at, &line, &column);
        st = bg_error_set(err, BG_ERR_PARSE, "%s: malformed JSON at line %d, column %d",
                          submit->scene_path, line, column);
        goto out;
    }
    if (!cJSON_IsObject(scene)) {
        st = bg_error_set(err, BG_ERR_INVALID, "%s: a scene is a JSON object", submit->scene_path);
        goto out;
    }
    if ((st = pack_refs(&p, scene, err)) != BG_OK || (st = set_solver(scene, submit, err)) != BG_OK)
        goto out;
    /* The broker sees the scene without its file: keep the name `solve` would give it. */
    if (!cJSON_GetObjectItemCaseSensitive(scene, "name")) {
        const char *base = slash ? slash + 1 : submit->scene_path;
        const char *dot = strrchr(base, '.');
        const int n = dot && dot != base ? (int)(dot - base) : (int)strlen(base);
        char stem[BGB_STORE_MAX_FILE_NAME + 1];
        snprintf(stem, sizeof stem, "%.*s", n, base);
        if (!cJSON_AddStringToObject(scene, "name", stem)) {
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory");
            goto out;
        }
    }
    root = cJSON_CreateObject();
    if (!root || !cJSON_AddItemToObject(root, "scene", scene)) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory");
        goto out;
    }
    scene = NULL;
    cJSON *files = p.count ? cJSON_AddArrayToObject(root, "files") : NULL;
    for (int i = 0; i < p.count; i++) {
        char *data = NULL;
        size_t size = 0;
        if ((st = bg_file_read_all(p.files[i].path, CLIENT_MAX_UPLOAD, &data, &size, err)) != BG_OK)
            goto out;
        char *encoded = bgb_base64_encode((const uint8_t *)data, size);
        free(data);
        cJSON *item = cJSON_CreateObject();
        if (!encoded || !item || !files ||
            !cJSON_AddStringToObject(item, "name", p.files[i].name) ||
            !cJSON_AddStringToObject(item, "base64", encoded)) {
            free(encoded);
            cJSON_Delete(item);
            st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for %s", p.files[i].path);
            goto out;
        }
        free(encoded);
        cJSON_AddItemToArray(files, item);
    }
    if (submit->mechanism)
        cJSON_AddStringToObject(root, "mechanism", submit->mechanism);
    if (submit->budget > 0.0)
        cJSON_AddNumberToObject(root, "budget", submit->budget);
    if (submit->deadline > 0.0)
        cJSON_AddNumberToObject(root, "deadline", submit->deadline);
    *body = cJSON_PrintUnformatted(root);
    if (!*body)
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the request");
out:
    for (int i = 0; i < p.count; i++)
        free(p.files[i].path);
    cJSON_Delete(scene);
    cJSON_Delete(root);
    free(text);
    return st;
}
