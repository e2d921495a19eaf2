/*
 * The broker's REST API end to end: a real libmicrohttpd server on a
 * loopback port chosen at run time, a real SQLite store in a temporary
 * directory, and libcurl as the client. Every response is also checked
 * against the OpenAPI document the server publishes: the schema documented
 * for that path, method and status, all the way down (oas_check).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <cJSON.h>
#include <curl/curl.h>
#include <fcntl.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include "bgb_base64.h"
#include "bgb_rest.h"
#include "bgb_store.h"
#include "bgb_tokens.h"
#include "bgb_submission.h"
#include "oas_check.h"

#define MAX_BODY (256 * 1024)
#define SMALL_BOX "{\"mesh\":{\"generate\":\"box\",\"cells\":[4,1,1],\"size\":[4,1,1]},"          \
                  "\"material\":{\"mu\":1,\"lambda\":1},\"handles\":[{\"select\":{\"box\":"     \
                  "{\"min\":[0,0,0],\"max\":[0,1,1]}}},{\"select\":{\"box\":{\"min\":[4,0,0],"  \
                  "\"max\":[4,1,1]}},\"transform\":{\"translate\":[0.5,0,0]}}]}"

typedef struct fixture {
    char dir[64], path[128];
    bgb_store_t *store;
    bgb_rest_t *rest;
    char base[64];
    cJSON *openapi;
    char auth[BGB_TOKEN_SIZE + 32]; /* "Authorization: Bearer <an admin's token>" */
} fixture_t;

typedef struct response {
    long status;
    char *body;
    size_t size;
    char type[128];
    char location[128];
} response_t;

static size_t on_body(char *data, size_t size, size_t n, void *ctx)
{
    response_t *r = ctx;
    const size_t add = size * n;
    char *grown = realloc(r->body, r->size + add + 1);
    assert_non_null(grown);
    r->body = grown;
    memcpy(r->body + r->size, data, add);
    r->size += add;
    r->body[r->size] = '\0';
    return add;
}

static size_t on_header(char *data, size_t size, size_t n, void *ctx)
{
    response_t *r = ctx;
    const size_t len = size * n;
    if (len > 14 && strncasecmp(data, "Content-Type: ", 14) == 0)
        snprintf(r->type, sizeof r->type, "%.*s", (int)(len - 16), data + 14);
    if (len > 10 && strncasecmp(data, "Location: ", 10) == 0)
        snprintf(r->location, sizeof r->location, "%.*s", (int)(len - 12), data + 10);
    return len;
}

/* One request; header may be NULL ("Name: value" otherwise). */
/* A request with the Authorization header auth (NULL: none) and one more
 * header (NULL: none). */
static response_t request_as(const fixture_t *f, const char *auth, const char *method,
                             const char *path, const char *body, const char *header)
{
    response_t r = {0};
    CURL *curl = curl_easy_init();
    assert_non_null(curl);
    char url[512];
    snprintf(url, sizeof url, "%s%s", f->base, path);
    struct curl_slist *headers = curl_slist_append(NULL, "Content-Type: application/json");
    if (auth)
        headers = curl_slist_append(headers, auth);
    if (header)
        headers = curl_slist_append(headers, header);
    curl_easy_setopt(curl, CURLOPT_URL, url);
    curl_easy_setopt(curl, CURLOPT_CUSTOMREQUEST, method);
    curl_easy_setopt(curl, CURLOPT_HTTPHEADER, headers);
    curl_easy_setopt(curl, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(curl, CURLOPT_WRITEDATA, &r);
    curl_easy_setopt(curl, CURLOPT_HEADERFUNCTION, on_header);
    curl_easy_setopt(curl, CURLOPT_HEADERDATA, &r);
    curl_easy_setopt(curl, CURLOPT_TIMEOUT, 30L);
    if (body) {
        curl_easy_setopt(curl, CURLOPT_POSTFIELDS, body);
        curl_easy_setopt(curl, CURLOPT_POSTFIELDSIZE, (long)strlen(body));
    }
    const CURLcode rc = curl_easy_perform(curl);
    if (rc != CURLE_OK)
        fail_msg("%s %s: %s", method, path, curl_easy_strerror(rc));
    curl_easy_getinfo(curl, CURLINFO_RESPONSE_CODE, &r.status);
    curl_slist_free_all(headers);
    curl_easy_cleanup(curl);
    if (!r.body)
        r.body = calloc(1, 1);
    return r;
}

/* A request as the fixture's admin. */
static response_t request(const fixture_t *f, const char *method, const char *path,
                          const char *body, const char *header)
{
    return request_as(f, f->auth, method, path, body, header);
}

/* Follows a local "$ref": "#/a/b/c" in the OpenAPI document. */
static const cJSON *resolve(const fixture_t *f, const cJSON *node)
{
    const cJSON *ref = cJSON_GetObjectItemCaseSensitive(node, "$ref");
    if (!cJSON_IsString(ref))
        return node;
    char path[256];
    snprintf(path, sizeof path, "%s", ref->valuestring + 2);
    const cJSON *at = f->openapi;
    for (char *part = strtok(path, "/"); part && at; part = strtok(NULL, "/"))
        at = cJSON_GetObjectItemCaseSensitive(at, part);
    assert_non_null(at);
    return resolve(f, at);
}

/*
 * The response must be documented for (template, method, status), with the
 * content type the document gives, and a JSON body must hold every
 * property its schema requires.
 */
static void conforms(const fixture_t *f, const char *template, const char *method,
                     const response_t *r)
{
    char status[8], lower[8];
    snprintf(status, sizeof status, "%ld", r->status);
    snprintf(lower, sizeof lower, "%s", method);
    for (char *c = lower; *c; c++)
        *c = (char)(*c - 'A' + 'a');
    const cJSON *paths = cJSON_GetObjectItemCaseSensitive(f->openapi, "paths");
    const cJSON *op = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(paths, template), lower);
    if (!op)
        fail_msg("%s %s is not in the OpenAPI document", method, template);
    const cJSON *resp = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(op, "responses"), status);
    if (!resp)
        fail_msg("%s %s: status %s is not documented", method, template, status);
    resp = resolve(f, resp);
    const cJSON *content = cJSON_GetObjectItemCaseSensitive(resp, "content");
    if (!content)
        return;
    char type[128];
    snprintf(type, sizeof type, "%s", r->type);
    type[strcspn(type, ";")] = '\0';
    const cJSON *media = cJSON_GetObjectItemCaseSensitive(content, type);
    if (!media)
        fail_msg("%s %s %s: content type '%s' is not documented", method, template, status,
                 type);
    if (strstr(type, "json") == NULL)
        return;
    const cJSON *schema = resolve(f, cJSON_GetObjectItemCaseSensitive(media, "schema"));
    cJSON *doc = cJSON_Parse(r->body);
    assert_non_null(doc);
    char why[600];
    if (oas_check(f->openapi, schema, doc, why, sizeof why))
        fail_msg("%s %s %s: %s in %s", method, template, status, why, r->body);
    cJSON_Delete(doc);
}

static void release(response_t *r)
{
    free(r->body);
    r->body = NULL;
}

/* Starts the store and the server with these job size caps. */
static void start_capped(fixture_t *f, int64_t max_vertices, int64_t max_elements)
{
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_open(f->path, &f->store, &err), BG_OK);
    bgb_limits_t limits;
    bgb_limits_default(&limits);
    limits.max_body = MAX_BODY;
    limits.max_vertices = max_vertices;
    limits.max_elements = max_elements;
    const bgb_rest_config_t config = {
        .port = 0, .limits = &limits, .work_dir = f->dir, .name = "test-broker"};
    if (bgb_rest_start(&config, f->store, &f->rest, &err) != BG_OK)
        fail_msg("%s", err.message);
    assert_true(bgb_rest_port(f->rest) > 0);
    char token[BGB_TOKEN_SIZE];
    assert_int_equal(bgb_tokens_create(f->store, "tester", 1, token, &err), BG_OK);
    snprintf(f->auth, sizeof f->auth, "Authorization: Bearer %s", token);
    snprintf(f->base, sizeof f->base, "http://127.0.0.1:%u", (unsigned)bgb_rest_port(f->rest));
}

static void start(fixture_t *f)
{
    start_capped(f, 100000, 500000);
}

static void stop(fixture_t *f)
{
    bgb_rest_stop(&f->rest);
    bgb_store_destroy(&f->store);
}

static int setup(void **state)
{
    fixture_t *f = calloc(1, sizeof *f);
    assert_non_null(f);
    snprintf(f->dir, sizeof f->dir, "/tmp/bgb-rest-XXXXXX");
    assert_non_null(mkdtemp(f->dir));
    snprintf(f->path, sizeof f->path, "%s/jobs.db", f->dir);
    f->openapi = cJSON_Parse(bgb_rest_openapi());
    assert_non_null(f->openapi);
    start(f);
    *state = f;
    return 0;
}

static int teardown(void **state)
{
    fixture_t *f = *state;
    stop(f);
    cJSON_Delete(f->openapi);
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", f->dir);
    assert_int_equal(system(cmd), 0);
    free(f);
    return 0;
}

/* {"scene": SCENE, extra...} */
static char *submission(const char *scene, const char *extra)
{
    const size_t n = strlen(scene) + (extra ? strlen(extra) : 0) + 32;
    char *body = malloc(n);
    assert_non_null(body);
    snprintf(body, n, "{\"scene\":%s%s%s}", scene, extra ? "," : "", extra ? extra : "");
    return body;
}

static char *field_of(const response_t *r, const char *key)
{
    cJSON *doc = cJSON_Parse(r->body);
    assert_non_null(doc);
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(doc, key);
    char *out = cJSON_IsString(v) ? strdup(v->valuestring) : NULL;
    cJSON_Delete(doc);
    return out;
}

/* A request whose answer must have this status, be the one the document
 * gives for template, and (words not NULL) hold these words. */
static void expect(const fixture_t *f, const char *method, const char *path, const char *body,
                   long status, const char *template, const char *words)
{
    response_t r = request(f, method, path, body, NULL);
    if (r.status != status || (words && !strstr(r.body, words)))
        fail_msg("%s %s: %ld %s (expected %ld with '%s')", method, path, r.status, r.body, status,
                 words ? words : "");
    conforms(f, template, method, &r);
    release(&r);
}

/* "{ ... }" of MAX_BODY + 63 bytes, blanks inside (caller frees). */
static char *oversized_body(void)
{
    char *big = malloc(MAX_BODY + 64);
    assert_non_null(big);
    memset(big, ' ', MAX_BODY + 63);
    big[MAX_BODY + 63] = '\0';
    big[0] = '{';
    big[MAX_BODY + 62] = '}';
    return big;
}

/* Submits SMALL_BOX and returns the new job's id (caller frees). */
static char *submit_small(const fixture_t *f, const char *header)
{
    char *body = submission(SMALL_BOX, "\"mechanism\":\"posted\",\"budget\":12.5");
    response_t r = request(f, "POST", "/v1/jobs", body, header);
    free(body);
    if (r.status != 202 && r.status != 200)
        fail_msg("submit: %ld %s", r.status, r.body);
    conforms(f, "/v1/jobs", "POST", &r);
    char *id = field_of(&r, "id");
    assert_non_null(id);
    char location[96];
    snprintf(location, sizeof location, "/v1/jobs/%s", id);
    assert_string_equal(r.location, location);
    release(&r);
    return id;
}

static void test_health_metrics_openapi(void **state)
{
    fixture_t *f = *state;
    response_t r = request(f, "GET", "/healthz", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/healthz", "GET", &r);
    assert_non_null(strstr(r.body, "\"status\":\"ok\""));
    assert_non_null(strstr(r.body, "\"name\":\"test-broker\""));
    release(&r);
    r = request(f, "GET", "/openapi.json", NULL, NULL);
    assert_int_equal(r.status, 200);
    cJSON *doc = cJSON_Parse(r.body);
    assert_non_null(doc);
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(doc, "openapi")->valuestring, "3.0.3");
    cJSON_Delete(doc);
    release(&r);
    free(submit_small(f, NULL));
    r = request(f, "GET", "/metrics", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/metrics", "GET", &r);
    assert_non_null(strstr(r.body, "biotgrid_jobs{state=\"queued\"} 1\n"));
    assert_non_null(strstr(r.body, "biotgrid_store_submits_total 1\n"));
    release(&r);
    r = request(f, "GET", "/nowhere", NULL, NULL);
    assert_int_equal(r.status, 404);
    assert_string_equal(r.type, "application/problem+json");
    release(&r);
    r = request(f, "DELETE", "/v1/jobs", NULL, NULL);
    assert_int_equal(r.status, 405);
    release(&r);
}

/* The market endpoints with no market attached: documented, empty, and
 * the CSVs carry the simulator's headers. The job resource shows the
 * progress and the trace the coordinator wrote as events. */
static void test_market_endpoints(void **state)
{
    fixture_t *f = *state;
    response_t r = request(f, "GET", "/v1/agents", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/agents", "GET", &r);
    assert_non_null(strstr(r.body, "\"agents\":[]"));
    release(&r);
    r = request(f, "GET", "/v1/market", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/market", "GET", &r);
    assert_non_null(strstr(r.body, "\"market\":null"));
    assert_non_null(strstr(r.body, "\"prices\":[]"));
    release(&r);
    r = request(f, "GET", "/v1/market/contracts.csv", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/market/contracts.csv", "GET", &r);
    assert_string_equal(r.body, "scenario,replication,mechanism,layer,request,time,start,end,"
                                "buyer,seller,good,quantity,price,buyer_limit,seller_limit,use,"
                                "clearing,lost\n");
    release(&r);
    r = request(f, "GET", "/v1/market/clearings.csv", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/market/clearings.csv", "GET", &r);
    assert_string_equal(r.body, "clearing,time,layer,good,volume,k,rule,price,low,low_order,"
                                "low_owner,high,high_order,high_owner\n");
    release(&r);
    r = request(f, "GET", "/v1/market/agents.csv", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/market/agents.csv", "GET", &r);
    assert_string_equal(r.body, "scenario,replication,mechanism,agent,role,good,capacity,limit\n");
    release(&r);
    r = request(f, "POST", "/v1/market", "{}", NULL);
    assert_int_equal(r.status, 405);
    release(&r);

    char *id = submit_small(f, NULL);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_add_event(f->store, id, "progress",
                                         "{\"iteration\":1,\"seconds\":0.5,\"error\":0.25}",
                                         &err),
                     BG_OK);
    char path[96];
    snprintf(path, sizeof path, "/v1/jobs/%s", id);
    r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs/{id}", "GET", &r);
    cJSON *doc = cJSON_Parse(r.body);
    assert_non_null(doc);
    const cJSON *trace = cJSON_GetObjectItemCaseSensitive(doc, "trace");
    assert_int_equal(cJSON_GetArraySize(trace), 1);
    assert_true(cJSON_GetObjectItemCaseSensitive(cJSON_GetArrayItem(trace, 0), "error")
                    ->valuedouble == 0.25);
    assert_int_equal(cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(doc, "contracts")), 0);
    cJSON_Delete(doc);
    release(&r);
    /* The run's full trace replaces the progress points. */
    assert_int_equal(bgb_store_add_event(f->store, id, "trace",
                                         "{\"points\":[{\"iteration\":0,\"seconds\":0},"
                                         "{\"iteration\":1,\"seconds\":0.5},"
                                         "{\"iteration\":2,\"seconds\":0.9}]}",
                                         &err),
                     BG_OK);
    r = request(f, "GET", path, NULL, NULL);
    doc = cJSON_Parse(r.body);
    assert_non_null(doc);
    assert_int_equal(cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(doc, "trace")), 3);
    cJSON_Delete(doc);
    release(&r);
    free(id);
}

static void test_submit_and_read(void **state)
{
    fixture_t *f = *state;
    char *id = submit_small(f, NULL);
    char path[96];
    snprintf(path, sizeof path, "/v1/jobs/%s", id);
    response_t r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs/{id}", "GET", &r);
    cJSON *doc = cJSON_Parse(r.body);
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(doc, "state")->valuestring, "queued");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(doc, "mechanism")->valuestring,
                        "posted");
    assert_true(cJSON_GetObjectItemCaseSensitive(doc, "budget")->valuedouble == 12.5);
    assert_true(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(doc, "deadline")));
    /* The plan of a static job: no integration step, and it says why. */
    const cJSON *plan = cJSON_GetObjectItemCaseSensitive(doc, "plan");
    assert_non_null(plan);
    char *plan_text = cJSON_PrintUnformatted(plan);
    assert_non_null(strstr(plan_text, "\"service\":\"rotation-fit\""));
    assert_non_null(strstr(plan_text, "\"service\":\"sparse-solve\""));
    const cJSON *left = cJSON_GetObjectItemCaseSensitive(plan, "left_out");
    int integration_left_out = 0;
    for (const cJSON *item = left->child; item; item = item->next)
        integration_left_out |= strcmp(cJSON_GetObjectItemCaseSensitive(item, "service")
                                           ->valuestring,
                                       "integration-step") == 0;
    assert_true(integration_left_out);
    free(plan_text);
    cJSON_Delete(doc);
    release(&r);
    /* No result while queued. */
    snprintf(path, sizeof path, "/v1/jobs/%s/result", id);
    r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 409);
    conforms(f, "/v1/jobs/{id}/result", "GET", &r);
    assert_non_null(strstr(r.body, "is queued: it has no result yet"));
    release(&r);
    r = request(f, "GET", "/v1/jobs/j0123456789abcdef", NULL, NULL);
    assert_int_equal(r.status, 404);
    conforms(f, "/v1/jobs/{id}", "GET", &r);
    release(&r);
    free(id);
}

/* The 202 body of a new job is the job resource GET shows right after, the
 * scene is stored as the client wrote it (blanks and all), and a scene key
 * spelled with an escape is the same key. */
static void test_submit_answer_is_the_resource(void **state)
{
    fixture_t *f = *state;
    const char *body = "{ \"budget\" : 7.25, \"scene\" :\n  " SMALL_BOX " ,\"mechanism\":"
                       "\"catallactic\", \"deadline\": 90.5 }  \n";
    response_t posted = request(f, "POST", "/v1/jobs", body, NULL);
    assert_int_equal(posted.status, 202);
    conforms(f, "/v1/jobs", "POST", &posted);
    char *id = field_of(&posted, "id");
    assert_non_null(id);
    char path[96];
    snprintf(path, sizeof path, "/v1/jobs/%s", id);
    response_t got = request(f, "GET", path, NULL, NULL);
    assert_int_equal(got.status, 200);
    cJSON *a = cJSON_Parse(posted.body), *b = cJSON_Parse(got.body);
    assert_non_null(a);
    assert_non_null(b);
    if (!cJSON_Compare(a, b, 1))
        fail_msg("POST answered %s\nGET shows %s", posted.body, got.body);
    assert_true(cJSON_GetObjectItemCaseSensitive(a, "budget")->valuedouble == 7.25);
    assert_true(cJSON_GetObjectItemCaseSensitive(a, "deadline")->valuedouble == 90.5);
    assert_non_null(cJSON_GetObjectItemCaseSensitive(a, "plan"));
    cJSON_Delete(a);
    cJSON_Delete(b);
    bgb_job_t job = BGB_JOB_INIT;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    assert_string_equal(job.scene, SMALL_BOX);
    assert_string_equal(job.mechanism, "catallactic");
    assert_true(job.deadline == 90.5);
    bgb_job_release(&job);
    release(&posted);
    release(&got);
    free(id);
    /* "sc\u0065ne" is "scene": cJSON's tree is printed instead. */
    char *escaped = strdup("{\"sc\\u0065ne\":" SMALL_BOX "}");
    posted = request(f, "POST", "/v1/jobs", escaped, NULL);
    free(escaped);
    assert_int_equal(posted.status, 202);
    id = field_of(&posted, "id");
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    cJSON *stored = cJSON_Parse(job.scene), *sent = cJSON_Parse(SMALL_BOX);
    assert_true(cJSON_Compare(stored, sent, 1));
    cJSON_Delete(stored);
    cJSON_Delete(sent);
    bgb_job_release(&job);
    release(&posted);
    free(id);
}

static void test_uploaded_files_only(void **state)
{
    fixture_t *f = *state;
    /* Two positive tets; the scene names the uploaded file. */
    const char *mesh = "MeshVersionFormatted 1\nDimension 3\nVertices\n5\n0 0 0 0\n1 0 0 0\n"
                       "0 1 0 0\n0 0 1 0\n1 1 1 0\nTetrahedra\n2\n1 2 3 4 0\n2 3 4 5 0\nEnd\n";
    char *b64 = bgb_base64_encode((const uint8_t *)mesh, strlen(mesh));
    char files[1024];
    snprintf(files, sizeof files, "\"files\":[{\"name\":\"two.mesh\",\"base64\":\"%s\"}]", b64);
    const char *scene = "{\"mesh\":\"two.mesh\",\"material\":{\"mu\":1,\"lambda\":1},"
                        "\"handles\":[{\"select\":{\"vertices\":[0,1,2]}},{\"select\":"
                        "{\"vertices\":[4]},\"transform\":{\"translate\":[0.1,0,0]}}]}";
    char *body = submission(scene, files);
    response_t r = request(f, "POST", "/v1/jobs", body, NULL);
    assert_int_equal(r.status, 202);
    release(&r);
    free(body);
    struct {
        const char *scene, *field, *words;
    } bad[] = {
        {"{\"mesh\":\"../two.mesh\",\"material\":{\"mu\":1,\"lambda\":1}}", "scene.mesh",
         "'../two.mesh' is outside the job's files"},
        {"{\"mesh\":\"/etc/passwd\",\"material\":{\"mu\":1,\"lambda\":1}}", "scene.mesh",
         "'/etc/passwd' is outside the job's files"},
        {"{\"mesh\":\"sub/../../x.mesh\",\"material\":{\"mu\":1,\"lambda\":1}}", "scene.mesh",
         "is outside the job's files"},
        {"{\"mesh\":\"missing.mesh\",\"material\":{\"mu\":1,\"lambda\":1}}", "scene.mesh",
         "missing.mesh not found"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        body = submission(bad[i].scene, files);
        r = request(f, "POST", "/v1/jobs", body, NULL);
        free(body);
        if (r.status != 422 || !strstr(r.body, bad[i].words))
            fail_msg("case %zu: %ld %s", i, r.status, r.body);
        conforms(f, "/v1/jobs", "POST", &r);
        char *field = field_of(&r, "field");
        assert_non_null(field);
        assert_string_equal(field, bad[i].field);
        free(field);
        release(&r);
    }
    free(b64);
    /* Nothing of the refused submits was stored, and no folder is left. */
    int64_t counts[BGB_JOB_STATE_COUNT];
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    assert_int_equal(counts[BGB_JOB_QUEUED], 1);
    char cmd[160];
    snprintf(cmd, sizeof cmd, "test -z \"$(ls -d '%s'/bgb-job-* 2>/dev/null)\"", f->dir);
    assert_int_equal(system(cmd), 0);
}

static void test_bad_requests(void **state)
{
    fixture_t *f = *state;
    struct {
        const char *body;
        long status;
        const char *field, *words;
    } cases[] = {
        {"{\"scene\": {\"mesh\": ", 400, NULL, "malformed JSON at line 1, column 19"},
        {"", 400, NULL, "empty body"},
        {"{\"scene\":" SMALL_BOX "}\n{\"scene\":" SMALL_BOX "}", 400, NULL,
         "text after the JSON document at line 2, column 1"},
        {"[1,2]", 422, NULL, "must be a JSON object"},
        {"{\"scene\":{},\"colour\":1}", 422, "colour", "unknown key 'colour'"},
        {"{\"budget\":1}", 422, "scene", "scene: missing"},
        {"{\"scene\":" SMALL_BOX ",\"budget\":-3}", 422, "budget", "positive number"},
        {"{\"scene\":" SMALL_BOX ",\"deadline\":0}", 422, "deadline", "seconds after submission"},
        {"{\"scene\":" SMALL_BOX ",\"deadline\":\"soon\"}", 422, "deadline",
         "seconds after submission"},
        {"{\"scene\":" SMALL_BOX ",\"deadline\":1e9}", 422, "deadline", "(0, 1e+07]"},
        {"{\"scene\":" SMALL_BOX ",\"mechanism\":\"auction\"}", 422, "mechanism",
         "mechanism: expected"},
        {"{\"scene\":" SMALL_BOX ",\"budget\":1,\"budget\":2}", 422, "budget",
         "key 'budget' is given twice"},
        {"{\"scene\":{\"mesh\":{\"generate\":\"box\",\"cells\":[1000,1000,30],\"size\":[1,1,1]},"
         "\"material\":{\"mu\":1,\"lambda\":1}}}",
         422, "scene.mesh.cells", "180000000 elements, over the limits"},
        /* The 75-byte request of the broker's first audit: refused for the
         * missing material before its 180 million elements are built. */
        {"{\"scene\":{\"mesh\":{\"generate\":\"box\",\"cells\":[1000,1000,30],\"size\":[1,1,1]}}}",
         422, "scene.material", "material: missing (required)"},
        {"{\"scene\":{\"mesh\":{\"generate\":\"box\",\"cells\":[2,2,2],\"size\":[1,1,1]},"
         "\"material\":{\"mu\":\"soft\",\"lambda\":1}}}",
         422, "scene.material.mu", "material.mu"},
        {"{\"scene\":" SMALL_BOX ",\"files\":[{\"name\":\"a/b\",\"base64\":\"\"}]}", 422,
         "files[0]", "not a plain file name"},
        {"{\"scene\":" SMALL_BOX ",\"files\":[{\"name\":\"a\",\"base64\":\"@@@@\"}]}", 422,
         "files[0]", "bad base64 character at offset 0"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        response_t r = request(f, "POST", "/v1/jobs", cases[i].body, NULL);
        if (r.status != cases[i].status || !strstr(r.body, cases[i].words))
            fail_msg("case %zu: %ld %s", i, r.status, r.body);
        assert_string_equal(r.type, "application/problem+json");
        conforms(f, "/v1/jobs", "POST", &r);
        char *field = field_of(&r, "field");
        if (cases[i].field) {
            if (!field || strcmp(field, cases[i].field) != 0)
                fail_msg("case %zu: field %s, expected %s", i, field ? field : "(none)",
                         cases[i].field);
        }
        free(field);
        release(&r);
    }
    /* A body over the cap is refused before it is read. */
    char *big = oversized_body();
    response_t r = request(f, "POST", "/v1/jobs", big, NULL);
    free(big);
    assert_int_equal(r.status, 413);
    conforms(f, "/v1/jobs", "POST", &r);
    release(&r);
    r = request(f, "GET", "/v1/jobs?state=sleeping", NULL, NULL);
    assert_int_equal(r.status, 400);
    conforms(f, "/v1/jobs", "GET", &r);
    assert_non_null(strstr(r.body, "\"field\":\"state\""));
    release(&r);
    r = request(f, "GET", "/v1/jobs?limit=0", NULL, NULL);
    assert_int_equal(r.status, 400);
    release(&r);
    int64_t counts[BGB_JOB_STATE_COUNT];
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    assert_int_equal(counts[BGB_JOB_QUEUED], 0);
}

static void test_idempotent_resubmit(void **state)
{
    fixture_t *f = *state;
    char *first = submit_small(f, "Idempotency-Key: order-7");
    char *again = submit_small(f, "Idempotency-Key: order-7");
    char *other = submit_small(f, "Idempotency-Key: order-8");
    assert_string_equal(first, again);
    assert_string_not_equal(first, other);
    response_t r = request(f, "GET", "/v1/jobs", NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs", "GET", &r);
    cJSON *doc = cJSON_Parse(r.body);
    assert_int_equal(cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(doc, "jobs")), 2);
    cJSON_Delete(doc);
    release(&r);
    free(first);
    free(again);
    free(other);
}

static void test_list_cancel_events_restart(void **state)
{
    fixture_t *f = *state;
    char *ids[5];
    for (int i = 0; i < 5; i++)
        ids[i] = submit_small(f, NULL);
    char path[160];
    snprintf(path, sizeof path, "/v1/jobs/%s/cancel", ids[1]);
    response_t r = request(f, "POST", path, "", NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs/{id}/cancel", "POST", &r);
    assert_non_null(strstr(r.body, "\"state\":\"cancelled\""));
    assert_non_null(strstr(r.body, "\"reason\":\"cancelled by the client\""));
    release(&r);
    r = request(f, "POST", path, "", NULL);
    assert_int_equal(r.status, 409);
    conforms(f, "/v1/jobs/{id}/cancel", "POST", &r);
    release(&r);

    /* The cancelled job's event stream: its whole log, then the end. */
    snprintf(path, sizeof path, "/v1/jobs/%s/events", ids[1]);
    r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs/{id}/events", "GET", &r);
    assert_string_equal(r.type, "text/event-stream");
    const char *queued = strstr(r.body, "event: state\ndata: {\"state\":\"queued\"}\n\n");
    const char *plan = strstr(r.body, "event: plan\ndata: {\"services\":");
    const char *cancelled = strstr(r.body, "event: state\ndata: {\"state\":\"cancelled\"}\n\n");
    assert_non_null(queued);
    assert_non_null(plan);
    assert_non_null(cancelled);
    assert_true(queued < plan && plan < cancelled);
    release(&r);

    /* The broker restarts between submit and poll: every job is still there. */
    stop(f);
    start(f);
    int seen = 0;
    char cursor[32] = "";
    for (int pages = 0; pages < 10; pages++) {
        snprintf(path, sizeof path, "/v1/jobs?limit=2%s%s", cursor[0] ? "&cursor=" : "", cursor);
        r = request(f, "GET", path, NULL, NULL);
        assert_int_equal(r.status, 200);
        conforms(f, "/v1/jobs", "GET", &r);
        cJSON *doc = cJSON_Parse(r.body);
        const cJSON *jobs = cJSON_GetObjectItemCaseSensitive(doc, "jobs");
        for (const cJSON *j = jobs->child; j; j = j->next, seen++)
            assert_string_equal(cJSON_GetObjectItemCaseSensitive(j, "id")->valuestring,
                                ids[seen]);
        const cJSON *next = cJSON_GetObjectItemCaseSensitive(doc, "next");
        const int more = cJSON_IsString(next);
        if (more)
            snprintf(cursor, sizeof cursor, "%s", next->valuestring);
        cJSON_Delete(doc);
        release(&r);
        if (!more)
            break;
    }
    assert_int_equal(seen, 5);
    r = request(f, "GET", "/v1/jobs?state=cancelled", NULL, NULL);
    assert_int_equal(r.status, 200);
    assert_non_null(strstr(r.body, ids[1]));
    assert_null(strstr(r.body, ids[0]));
    release(&r);
    for (int i = 0; i < 5; i++)
        free(ids[i]);
}

/* An open event stream follows the job: a transition made while the
 * client listens arrives, and the stream ends when the job does. */
typedef struct listener {
    const fixture_t *f;
    char path[96];
    response_t r;
} listener_t;

static void *listen_events(void *arg)
{
    listener_t *l = arg;
    l->r = request(l->f, "GET", l->path, NULL, NULL);
    return NULL;
}

static void test_live_event_stream(void **state)
{
    fixture_t *f = *state;
    char *id = submit_small(f, NULL);
    listener_t l = {.f = f};
    snprintf(l.path, sizeof l.path, "/v1/jobs/%s/events", id);
    pthread_t thread;
    assert_int_equal(pthread_create(&thread, NULL, listen_events, &l), 0);
    const struct timespec pause = {0, 300000000L};
    nanosleep(&pause, NULL);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_QUEUED, BGB_JOB_RUNNING,
                                          NULL, &err),
                     BG_OK);
    assert_int_equal(bgb_store_add_event(f->store, id, "progress", "{\"iteration\":3}", &err),
                     BG_OK);
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_RUNNING, BGB_JOB_FAILED,
                                          "no seller", &err),
                     BG_OK);
    assert_int_equal(pthread_join(thread, NULL), 0);
    assert_int_equal(l.r.status, 200);
    const char *running = strstr(l.r.body, "{\"state\":\"running\"}");
    const char *progress = strstr(l.r.body, "event: progress\ndata: {\"iteration\":3}");
    const char *failed = strstr(l.r.body, "{\"state\":\"failed\"}");
    assert_non_null(running);
    assert_non_null(progress);
    assert_non_null(failed);
    assert_true(running < progress && progress < failed);
    release(&l.r);
    free(id);
}

/* The job paths with an unknown (or malformed) id are 404 problems; a
 * succeeded job serves its result's list and files, with their types; a
 * job that has not succeeded has no result (409), an ended one cannot be
 * cancelled (409). Every answer is the one the document gives. */
static void test_job_paths_and_results(void **state)
{
    fixture_t *f = *state;
    static const struct {
        const char *method, *path, *template;
    } unknown[] = {
        {"GET", "/v1/jobs/j0123456789abcdef", "/v1/jobs/{id}"},
        {"GET", "/v1/jobs/j0123456789abcdef/events", "/v1/jobs/{id}/events"},
        {"POST", "/v1/jobs/j0123456789abcdef/cancel", "/v1/jobs/{id}/cancel"},
        {"GET", "/v1/jobs/j0123456789abcdef/result", "/v1/jobs/{id}/result"},
        {"GET", "/v1/jobs/j0123456789abcdef/result/report.json", "/v1/jobs/{id}/result/{file}"},
        {"GET", "/v1/jobs/not-an-id", "/v1/jobs/{id}"},
    };
    for (size_t i = 0; i < sizeof unknown / sizeof unknown[0]; i++)
        expect(f, unknown[i].method, unknown[i].path,
               strcmp(unknown[i].method, "POST") == 0 ? "" : NULL, 404, unknown[i].template,
               "\"status\":404");
    char *id = submit_small(f, NULL);
    char path[160];
    snprintf(path, sizeof path, "/v1/jobs/%s/result/report.json", id);
    expect(f, "GET", path, NULL, 409, "/v1/jobs/{id}/result/{file}", "has no result yet");
    /* What a coordinator does: run, write the result's files, succeed. */
    bg_error_t err = BG_ERROR_INIT;
    const char *report = "{\"energy\":0.125}";
    const char *svg = "<svg xmlns=\"http://www.w3.org/2000/svg\"/>";
    const bgb_file_t files[] = {{"report.json", (const uint8_t *)report, strlen(report)},
                                {"trace.svg", (const uint8_t *)svg, strlen(svg)}};
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_QUEUED, BGB_JOB_RUNNING,
                                          NULL, &err),
                     BG_OK);
    for (int i = 0; i < 2; i++)
        assert_int_equal(bgb_store_put_file(f->store, id, "result", &files[i], &err), BG_OK);
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_RUNNING, BGB_JOB_SUCCEEDED,
                                          NULL, &err),
                     BG_OK);
    snprintf(path, sizeof path, "/v1/jobs/%s/result", id);
    response_t r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs/{id}/result", "GET", &r);
    cJSON *doc = cJSON_Parse(r.body);
    const cJSON *list = cJSON_GetObjectItemCaseSensitive(doc, "files");
    assert_int_equal(cJSON_GetArraySize(list), 2);
    for (int i = 0; i < 2; i++) {
        const cJSON *item = cJSON_GetArrayItem(list, i);
        assert_string_equal(cJSON_GetObjectItemCaseSensitive(item, "name")->valuestring,
                            files[i].name);
        assert_true(cJSON_GetObjectItemCaseSensitive(item, "size")->valuedouble ==
                    (double)files[i].size);
    }
    cJSON_Delete(doc);
    release(&r);
    static const char *const types[] = {"application/json", "image/svg+xml"};
    for (int i = 0; i < 2; i++) {
        snprintf(path, sizeof path, "/v1/jobs/%s/result/%s", id, files[i].name);
        r = request(f, "GET", path, NULL, NULL);
        assert_int_equal(r.status, 200);
        conforms(f, "/v1/jobs/{id}/result/{file}", "GET", &r);
        assert_string_equal(r.type, types[i]);
        assert_int_equal(r.size, files[i].size);
        assert_memory_equal(r.body, files[i].data, files[i].size);
        release(&r);
    }
    snprintf(path, sizeof path, "/v1/jobs/%s/result/frame-0.vtu", id);
    expect(f, "GET", path, NULL, 404, "/v1/jobs/{id}/result/{file}", "has no result file");
    snprintf(path, sizeof path, "/v1/jobs/%s/cancel", id);
    expect(f, "POST", path, "", 409, "/v1/jobs/{id}/cancel", "is succeeded");
    free(id);
}

/* The state filter and the cursor together: each page holds only jobs in
 * that state, in submission order, and the pages hold all of them. */
static void test_filter_with_pagination(void **state)
{
    fixture_t *f = *state;
    char *ids[7];
    bg_error_t err = BG_ERROR_INIT;
    for (int i = 0; i < 7; i++) {
        ids[i] = submit_small(f, NULL);
        if (i % 3 == 1)
            assert_int_equal(bgb_store_transition(f->store, ids[i], 1u << BGB_JOB_QUEUED,
                                                  BGB_JOB_CANCELLED, NULL, &err),
                             BG_OK);
    }
    static const struct {
        const char *state;
        int want[7], count;
    } cases[] = {{"queued", {0, 2, 3, 5, 6}, 5}, {"cancelled", {1, 4}, 2}, {"running", {0}, 0}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        int seen = 0, pages = 0;
        char cursor[32] = "";
        for (;; pages++) {
            assert_true(pages < 10);
            char path[128];
            snprintf(path, sizeof path, "/v1/jobs?state=%s&limit=2%s%s", cases[c].state,
                     cursor[0] ? "&cursor=" : "", cursor);
            response_t r = request(f, "GET", path, NULL, NULL);
            assert_int_equal(r.status, 200);
            conforms(f, "/v1/jobs", "GET", &r);
            cJSON *doc = cJSON_Parse(r.body);
            const cJSON *jobs = cJSON_GetObjectItemCaseSensitive(doc, "jobs");
            assert_true(cJSON_GetArraySize(jobs) <= 2);
            for (const cJSON *j = jobs->child; j; j = j->next, seen++) {
                assert_true(seen < cases[c].count);
                assert_string_equal(cJSON_GetObjectItemCaseSensitive(j, "id")->valuestring,
                                    ids[cases[c].want[seen]]);
                assert_string_equal(cJSON_GetObjectItemCaseSensitive(j, "state")->valuestring,
                                    cases[c].state);
            }
            const cJSON *next = cJSON_GetObjectItemCaseSensitive(doc, "next");
            const int more = cJSON_IsString(next);
            if (more)
                snprintf(cursor, sizeof cursor, "%s", next->valuestring);
            else
                assert_true(cJSON_IsNull(next));
            cJSON_Delete(doc);
            release(&r);
            if (!more)
                break;
        }
        assert_int_equal(seen, cases[c].count);
    }
    expect(f, "GET", "/v1/jobs?cursor=abc", NULL, 400, "/v1/jobs", "\"field\":\"cursor\"");
    expect(f, "GET", "/v1/jobs?limit=501", NULL, 400, "/v1/jobs", "\"field\":\"limit\"");
    for (int i = 0; i < 7; i++)
        free(ids[i]);
}

/* The caps hold for an uploaded mesh as for a generated one, a body sent
 * in chunks (no Content-Length) over the cap is a 413 too, an
 * Idempotency-Key over its cap is a 400 naming the header, and a key
 * names one job forever: a second submit with it and the same body gets
 * the first job, with another body a 422 naming the key. */
static void test_caps_and_keys(void **state)
{
    fixture_t *f = *state;
    stop(f);
    start_capped(f, 4, 500000);
    const char *mesh = "MeshVersionFormatted 1\nDimension 3\nVertices\n5\n0 0 0 0\n1 0 0 0\n"
                       "0 1 0 0\n0 0 1 0\n1 1 1 0\nTetrahedra\n2\n1 2 3 4 0\n2 3 4 5 0\nEnd\n";
    char *b64 = bgb_base64_encode((const uint8_t *)mesh, strlen(mesh));
    char body[1024];
    snprintf(body, sizeof body,
             "{\"scene\":{\"mesh\":\"two.mesh\",\"material\":{\"mu\":1,\"lambda\":1}},"
             "\"files\":[{\"name\":\"two.mesh\",\"base64\":\"%s\"}]}",
             b64);
    free(b64);
    response_t r = request(f, "POST", "/v1/jobs", body, NULL);
    if (r.status != 422 || !strstr(r.body, "\"type\":\"/problems/job-too-large\""))
        fail_msg("a 5-vertex mesh under a 4-vertex cap: %ld %s", r.status, r.body);
    conforms(f, "/v1/jobs", "POST", &r);
    char *field = field_of(&r, "field");
    assert_non_null(field);
    assert_true(strncmp(field, "scene.mesh", 10) == 0);
    free(field);
    release(&r);
    stop(f);
    start(f);

    char *big = oversized_body();
    r = request(f, "POST", "/v1/jobs", big, "Transfer-Encoding: chunked");
    free(big);
    assert_int_equal(r.status, 413);
    conforms(f, "/v1/jobs", "POST", &r);
    release(&r);

    char key[320] = "Idempotency-Key: ";
    memset(key + strlen(key), 'k', 300);
    key[sizeof key - 1] = '\0';
    char *small = submission(SMALL_BOX, NULL);
    r = request(f, "POST", "/v1/jobs", small, key);
    assert_int_equal(r.status, 400);
    conforms(f, "/v1/jobs", "POST", &r);
    assert_non_null(strstr(r.body, "\"field\":\"Idempotency-Key\""));
    release(&r);
    free(small);

    char *first = submit_small(f, "Idempotency-Key: once");
    /* The same key with another body: 422 naming the key. */
    char *other = submission(SMALL_BOX, "\"budget\":99");
    r = request(f, "POST", "/v1/jobs", other, "Idempotency-Key: once");
    free(other);
    assert_int_equal(r.status, 422);
    conforms(f, "/v1/jobs", "POST", &r);
    assert_non_null(strstr(r.body, "\"field\":\"Idempotency-Key\""));
    release(&r);
    /* The same key with the same body: the earlier job. */
    char *same = submission(SMALL_BOX, "\"mechanism\":\"posted\",\"budget\":12.5");
    r = request(f, "POST", "/v1/jobs", same, "Idempotency-Key: once");
    free(same);
    assert_int_equal(r.status, 200);
    conforms(f, "/v1/jobs", "POST", &r);
    char *again = field_of(&r, "id");
    assert_string_equal(again, first);
    assert_non_null(strstr(r.body, "\"budget\":12.5"));
    char location[96];
    snprintf(location, sizeof location, "/v1/jobs/%s", first);
    assert_string_equal(r.location, location);
    release(&r);
    free(again);
    free(first);
    int64_t counts[BGB_JOB_STATE_COUNT];
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    assert_int_equal(counts[BGB_JOB_QUEUED], 1);
}

/* The value of a metric without labels in /metrics, or -1. */
static long long metric(const fixture_t *f, const char *name)
{
    response_t r = request(f, "GET", "/metrics", NULL, NULL);
    assert_int_equal(r.status, 200);
    char key[128];
    snprintf(key, sizeof key, "\n%s ", name);
    const char *at = strstr(r.body, key);
    const long long value = at ? strtoll(at + strlen(key), NULL, 10) : -1;
    release(&r);
    return value;
}

/* Polls metric name until it equals want; 1 if it did within seconds. */
static int metric_becomes(const fixture_t *f, const char *name, long long want, double seconds)
{
    struct timespec t0, t;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (;;) {
        if (metric(f, name) == want)
            return 1;
        clock_gettime(CLOCK_MONOTONIC, &t);
        if ((double)(t.tv_sec - t0.tv_sec) + 1e-9 * (double)(t.tv_nsec - t0.tv_nsec) > seconds)
            return 0;
        const struct timespec pause = {0, 20000000L};
        nanosleep(&pause, NULL);
    }
}

/*
 * A client that drops an open event stream frees it promptly: curl (a
 * real process) listens to a queued job's events, is killed, and the
 * broker's count of open streams goes back to 0 well before the 15 s
 * keep-alive write that would otherwise be the first to notice.
 */
static void test_dropped_event_stream(void **state)
{
    fixture_t *f = *state;
    char *id = submit_small(f, NULL);
    char url[160];
    snprintf(url, sizeof url, "%s/v1/jobs/%s/events", f->base, id);
    assert_int_equal(metric(f, "biotgrid_event_streams_open"), 0);
    const pid_t curl = fork();
    assert_true(curl >= 0);
    if (curl == 0) {
        const int null = open("/dev/null", O_WRONLY);
        if (null >= 0) {
            dup2(null, STDOUT_FILENO);
            dup2(null, STDERR_FILENO);
        }
        execlp("curl", "curl", "-sN", "--max-time", "60", "-H", f->auth, url, (char *)NULL);
        _exit(127);
    }
    const int opened = metric_becomes(f, "biotgrid_event_streams_open", 1, 30.0);
    kill(curl, SIGKILL);
    int status = 0;
    assert_int_equal(waitpid(curl, &status, 0), curl);
    assert_true(opened);
    /* The stream sends a keep-alive only after 15 s of silence: a count
     * back at 0 within 10 s means the disconnect itself was seen. */
    assert_true(metric_becomes(f, "biotgrid_event_streams_open", 0, 10.0));
    /* The job is untouched and the server still answers its stream. */
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_QUEUED, BGB_JOB_CANCELLED,
                                          NULL, &err),
                     BG_OK);
    char path[96];
    snprintf(path, sizeof path, "/v1/jobs/%s/events", id);
    response_t r = request(f, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    assert_non_null(strstr(r.body, "{\"state\":\"cancelled\"}"));
    release(&r);
    /* MHD frees the ended stream just after its last bytes reach us. */
    assert_true(metric_becomes(f, "biotgrid_event_streams_open", 0, 10.0));
    free(id);
}

/* Sends raw bytes to the server and returns the first line of its answer
 * (the status line), for requests curl will not send. */
static void raw_status(const fixture_t *f, const char *request, char *line, size_t size)
{
    line[0] = '\0';
    const int fd = socket(AF_INET, SOCK_STREAM, 0);
    assert_true(fd >= 0);
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_port = htons(bgb_rest_port(f->rest));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    assert_int_equal(connect(fd, (struct sockaddr *)&addr, sizeof addr), 0);
    const size_t n = strlen(request);
    assert_int_equal(write(fd, request, n), (ssize_t)n);
    size_t got = 0;
    while (got + 1 < size) {
        const ssize_t r = read(fd, line + got, size - 1 - got);
        if (r <= 0)
            break;
        got += (size_t)r;
        line[got] = '\0';
        if (strchr(line, '\n'))
            break;
    }
    close(fd);
}

/* Two Content-Length headers that disagree, or one beside Transfer-
 * Encoding, are the shapes of request smuggling: a 400, never a guess. */
static void test_conflicting_lengths(void **state)
{
    fixture_t *f = *state;
    char line[256];
    raw_status(f,
               "POST /v1/jobs HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n"
               "Content-Length: 2\r\nContent-Length: 3\r\nConnection: close\r\n\r\n{}x",
               line, sizeof line);
    if (strncmp(line, "HTTP/1.1 400", 12) != 0)
        fail_msg("two Content-Length headers: %s", line);
    raw_status(f,
               "POST /v1/jobs HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n"
               "Content-Length: 2\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
               "2\r\n{}\r\n0\r\n\r\n",
               line, sizeof line);
    if (strncmp(line, "HTTP/1.1 400", 12) != 0)
        fail_msg("Content-Length with Transfer-Encoding: %s", line);
    /* The same request with one length is served (a 422: the scene is
     * empty), so the 400s above are about the lengths. */
    char request[512];
    snprintf(request, sizeof request,
             "POST /v1/jobs HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n%s\r\n"
             "Content-Length: 2\r\nConnection: close\r\n\r\n{}",
             f->auth);
    raw_status(f, request, line, sizeof line);
    if (strncmp(line, "HTTP/1.1 422", 12) != 0)
        fail_msg("one Content-Length: %s", line);
}

/* Bearer tokens: every /v1 path and /metrics need one (401 problem
 * otherwise, the same for a missing, malformed or wrong token), /healthz and
 * /openapi.json do not; a user sees and touches only their own jobs
 * (another's is 404, as if it did not exist); only the admin scope reads
 * the agents, the market and the counters, and sees every job. */
static void test_tokens_and_owners(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    char ada_token[BGB_TOKEN_SIZE], bob_token[BGB_TOKEN_SIZE];
    assert_int_equal(bgb_tokens_create(f->store, "ada", 0, ada_token, &err), BG_OK);
    assert_int_equal(bgb_tokens_create(f->store, "bob", 0, bob_token, &err), BG_OK);
    char ada[BGB_TOKEN_SIZE + 32], bob[BGB_TOKEN_SIZE + 32], wrong[BGB_TOKEN_SIZE + 32];
    snprintf(ada, sizeof ada, "Authorization: Bearer %s", ada_token);
    snprintf(bob, sizeof bob, "Authorization: Bearer %s", bob_token);
    /* ada's id with another secret (its first character changed): the
     * right row, the wrong hash. */
    snprintf(wrong, sizeof wrong, "Authorization: Bearer %s", ada_token);
    char *secret = strrchr(wrong, '_') + 1;
    *secret = *secret == 'A' ? 'B' : 'A';
    const char *const bad[] = {NULL, "Authorization: Bearer nonsense", wrong,
                               "Authorization: Basic dGVzdDp0ZXN0"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        response_t r = request_as(f, bad[i], "GET", "/v1/jobs", NULL, NULL);
        if (r.status != 401 || !strstr(r.body, "/problems/unauthorized"))
            fail_msg("credentials %zu: %ld %s", i, r.status, r.body);
        assert_string_equal(r.type, "application/problem+json");
        release(&r);
    }
    response_t r = request_as(f, NULL, "GET", "/healthz", NULL, NULL);
    assert_int_equal(r.status, 200);
    release(&r);
    r = request_as(f, NULL, "GET", "/openapi.json", NULL, NULL);
    assert_int_equal(r.status, 200);
    release(&r);

    char *body = submission(SMALL_BOX, NULL);
    r = request_as(f, ada, "POST", "/v1/jobs", body, NULL);
    free(body);
    assert_int_equal(r.status, 202);
    char *id = field_of(&r, "id");
    release(&r);
    char path[128], missing[128];
    snprintf(missing, sizeof missing, "/v1/jobs/j0123456789abcdef");
    const char *const suffixes[] = {"", "/events", "/result", "/cancel", ""};
    const char *const methods[] = {"GET", "GET", "GET", "POST", "DELETE"};
    for (int k = 0; k < 5; k++) {
        snprintf(path, sizeof path, "/v1/jobs/%s%s", id, suffixes[k]);
        r = request_as(f, bob, methods[k], path, NULL, NULL);
        if (r.status != 404 || !strstr(r.body, "no-such-job"))
            fail_msg("bob %s %s: %ld %s", methods[k], path, r.status, r.body);
        release(&r);
    }
    /* ada's job and a job that does not exist look the same to bob. */
    response_t none = request_as(f, bob, "GET", missing, NULL, NULL);
    assert_int_equal(none.status, 404);
    release(&none);
    snprintf(path, sizeof path, "/v1/jobs/%s", id);
    r = request_as(f, ada, "GET", path, NULL, NULL);
    assert_int_equal(r.status, 200);
    release(&r);
    r = request_as(f, bob, "GET", "/v1/jobs", NULL, NULL);
    assert_int_equal(r.status, 200);
    assert_null(strstr(r.body, id));
    release(&r);
    r = request_as(f, ada, "GET", "/v1/jobs", NULL, NULL);
    assert_non_null(strstr(r.body, id));
    release(&r);
    r = request(f, "GET", "/v1/jobs", NULL, NULL); /* the admin sees every user's */
    assert_non_null(strstr(r.body, id));
    release(&r);
    const char *const operator_paths[] = {"/v1/agents", "/v1/market", "/v1/market/contracts.csv",
                                          "/metrics"};
    for (size_t i = 0; i < 4; i++) {
        r = request_as(f, ada, "GET", operator_paths[i], NULL, NULL);
        if (r.status != 403)
            fail_msg("ada GET %s: %ld", operator_paths[i], r.status);
        release(&r);
        r = request(f, "GET", operator_paths[i], NULL, NULL);
        if (r.status != 200)
            fail_msg("admin GET %s: %ld", operator_paths[i], r.status);
        release(&r);
    }
    free(id);
}

/* A body of many distinct keys is refused in linear time: the repeated-key
 * check compared every pair of keys before the unknown ones were looked
 * at, so 50,000 keys (600 KB) took some 10 s of CPU and the 64 MB a
 * body may have, days (found while writing tests/fuzz/fuzz_submission,
 * whose inputs of a few KB are too small to show it). */
static void test_many_keys_linear(void **state)
{
    (void)state;
    const int keys = 50000;
    char *body = malloc((size_t)keys * 16 + 16);
    assert_non_null(body);
    size_t n = 0;
    body[n++] = '{';
    for (int i = 0; i < keys; i++)
        n += (size_t)sprintf(body + n, "%s\"k%d\":0", i ? "," : "", i);
    body[n++] = '}';
    bgb_submission_t s;
    bgb_problem_t problem;
    const clock_t start = clock();
    assert_int_equal(bgb_submission_parse(body, n, 1024, &s, &problem), 0);
    const double seconds = (double)(clock() - start) / CLOCKS_PER_SEC;
    assert_int_equal(problem.status, 422);
    assert_string_equal(problem.field, "k0");
    assert_non_null(strstr(problem.detail, "unknown key 'k0'"));
    if (seconds > 1.0)
        fail_msg("%d keys took %.2f s of CPU", keys, seconds);
    free(body);
}

int main(void)
{
    curl_global_init(CURL_GLOBAL_DEFAULT);
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_health_metrics_openapi, setup, teardown),
        cmocka_unit_test_setup_teardown(test_submit_and_read, setup, teardown),
        cmocka_unit_test_setup_teardown(test_submit_answer_is_the_resource, setup, teardown),
        cmocka_unit_test_setup_teardown(test_market_endpoints, setup, teardown),
        cmocka_unit_test_setup_teardown(test_uploaded_files_only, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_requests, setup, teardown),
        cmocka_unit_test_setup_teardown(test_idempotent_resubmit, setup, teardown),
        cmocka_unit_test_setup_teardown(test_list_cancel_events_restart, setup, teardown),
        cmocka_unit_test_setup_teardown(test_live_event_stream, setup, teardown),
        cmocka_unit_test_setup_teardown(test_dropped_event_stream, setup, teardown),
        cmocka_unit_test_setup_teardown(test_job_paths_and_results, setup, teardown),
        cmocka_unit_test_setup_teardown(test_filter_with_pagination, setup, teardown),
        cmocka_unit_test_setup_teardown(test_caps_and_keys, setup, teardown),
        cmocka_unit_test_setup_teardown(test_conflicting_lengths, setup, teardown),
        cmocka_unit_test_setup_teardown(test_tokens_and_owners, setup, teardown),
        cmocka_unit_test(test_many_keys_linear),
    };
    const int failed = cmocka_run_group_tests(tests, NULL, NULL);
    curl_global_cleanup();
    return failed;
}
