/*
 * bgb_client first without a server: the server-sent events parser (every chunk
 * boundary, line endings, comments, the caps, stopping) and the packing of
 * a scene with the files it names (found beside the scene or through the
 * search path, renamed, TetGen pairs, name clashes, errors naming the field).
 * Then the HTTP side at the library level against the REST library served
 * in process on an ephemeral loopback port: the response cap, statuses,
 * the events stream. The commands are tests/broker/client.sh.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bg_file.h"
#include "bgb_base64.h"
#include "bgb_client.h"
#include "bgb_rest.h"
#include "bgb_store.h"
#include "bgb_tokens.h"

/* ------------------------------------------------------------ events */

#define MAX_EVENTS 16

typedef struct seen {
    char text[MAX_EVENTS][256];
    int count;
    int stop_after; /* 0: never */
} seen_t;

static int record(void *ctx, const char *id, const char *event, const char *data)
{
    seen_t *s = ctx;
    assert_true(s->count < MAX_EVENTS);
    snprintf(s->text[s->count], sizeof s->text[0], "%s|%s|%s", id, event, data);
    s->count++;
    return s->stop_after && s->count >= s->stop_after;
}

/* A stream exercising the format: LF, CRLF and CR line ends, comments, a
 * field without a colon, an unknown field, multi-line data, an id that
 * persists, an event without data (not dispatched), one without a type. */
static const char STREAM[] = ": keep-alive\n\n"
                             "id: 1\nevent: state\ndata: {\"state\":\"queued\"}\n\n"
                             "id: 2\r\nevent: progress\r\ndata: {\"fraction\":0.5}\r\n\r\n"
                             "event: contract\rdata:first\rdata: second\r\r"
                             "retry: 10\nid: 7\nevent: nothing\n\n"
                             "data\nunknown: x\n\n"
                             "id:9\ndata: a: b\n\n";

static const char *const EXPECTED[] = {"1|state|{\"state\":\"queued\"}",
                                       "2|progress|{\"fraction\":0.5}", "2|contract|first\nsecond",
                                       "7|message|", "9|message|a: b"};
#define EXPECTED_COUNT 5

static void feed_split(const size_t *cuts, int ncuts, seen_t *seen)
{
    bgb_sse_t *sse = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_sse_new(0, record, seen, &sse, &err), BG_OK);
    size_t from = 0;
    for (int i = 0; i <= ncuts; i++) {
        const size_t to = i < ncuts ? cuts[i] : sizeof STREAM - 1;
        int stopped = 0;
        assert_int_equal(bgb_sse_feed(sse, STREAM + from, to - from, &stopped, &err), BG_OK);
        assert_int_equal(stopped, 0);
        from = to;
    }
    bgb_sse_destroy(&sse);
    assert_null(sse);
}

static void expect_all(const seen_t *seen)
{
    assert_int_equal(seen->count, EXPECTED_COUNT);
    for (int i = 0; i < EXPECTED_COUNT; i++)
        assert_string_equal(seen->text[i], EXPECTED[i]);
}

static void test_sse_every_boundary(void **state)
{
    (void)state;
    seen_t whole = {0};
    feed_split(NULL, 0, &whole);
    expect_all(&whole);
    /* Two chunks cut at every byte, then three chunks at every pair of cuts. */
    const size_t n = sizeof STREAM - 1;
    for (size_t cut = 0; cut <= n; cut++) {
        seen_t seen = {0};
        feed_split(&cut, 1, &seen);
        expect_all(&seen);
    }
    for (size_t a = 0; a <= n; a += 3)
        for (size_t b = a; b <= n; b += 5) {
            const size_t cuts[2] = {a, b};
            seen_t seen = {0};
            feed_split(cuts, 2, &seen);
            expect_all(&seen);
        }
    /* One byte at a time. */
    size_t cuts[sizeof STREAM];
    for (size_t i = 0; i < n; i++)
        cuts[i] = i + 1;
    seen_t bytes = {0};
    feed_split(cuts, (int)n - 1, &bytes);
    expect_all(&bytes);
}

static void test_sse_caps(void **state)
{
    (void)state;
    seen_t seen = {0};
    bgb_sse_t *sse = NULL;
    bg_error_t err = BG_ERROR_INIT;
    /* Data lines of 10 bytes each: the third would take the event over 32 bytes. */
    assert_int_equal(bgb_sse_new(32, record, &seen, &sse, &err), BG_OK);
    const char ok[] = "data: 0123456789\n\n";
    assert_int_equal(bgb_sse_feed(sse, ok, sizeof ok - 1, NULL, &err), BG_OK);
    assert_int_equal(seen.count, 1);
    const char big[] = "data: 0123456789\ndata: 0123456789\ndata: 0123456789\n";
    assert_int_equal(bgb_sse_feed(sse, big, sizeof big - 1, NULL, &err), BG_ERR_LIMIT);
    assert_non_null(strstr(err.message, "exceeds 32 bytes"));
    bgb_sse_destroy(&sse);
    /* A line that never ends is refused at the cap, not buffered. */
    bg_error_t err2 = BG_ERROR_INIT;
    assert_int_equal(bgb_sse_new(32, record, &seen, &sse, &err2), BG_OK);
    char endless[100];
    memset(endless, 'x', sizeof endless);
    assert_int_equal(bgb_sse_feed(sse, endless, sizeof endless, NULL, &err2), BG_ERR_LIMIT);
    assert_non_null(strstr(err2.message, "a line exceeds 32 bytes"));
    assert_int_equal(seen.count, 1);
    bgb_sse_destroy(&sse);
}

static void test_sse_stop(void **state)
{
    (void)state;
    seen_t seen = {.stop_after = 2};
    bgb_sse_t *sse = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_sse_new(0, record, &seen, &sse, &err), BG_OK);
    int stopped = 0;
    assert_int_equal(bgb_sse_feed(sse, STREAM, sizeof STREAM - 1, &stopped, &err), BG_OK);
    assert_int_equal(stopped, 1);
    assert_int_equal(seen.count, 2);
    assert_int_equal(bgb_sse_feed(sse, STREAM, sizeof STREAM - 1, &stopped, &err), BG_OK);
    assert_int_equal(seen.count, 2);
    bgb_sse_destroy(&sse);
}

/* ----------------------------------------------------------- packing */

typedef struct folder {
    char dir[64];
} folder_t;

static void write_file(const folder_t *f, const char *relative, const char *text)
{
    char path[256];
    snprintf(path, sizeof path, "%s/%s", f->dir, relative);
    /* The folders below f->dir, each in turn. */
    for (char *slash = strchr(path + strlen(f->dir) + 1, '/'); slash;
         slash = strchr(slash + 1, '/')) {
        *slash = '\0';
        mkdir(path, 0755);
        *slash = '/';
    }
    FILE *out = fopen(path, "w");
    assert_non_null(out);
    fputs(text, out);
    fclose(out);
}

static int setup_folder(void **state)
{
    folder_t *f = calloc(1, sizeof *f);
    snprintf(f->dir, sizeof f->dir, "/tmp/bgb-client-test.XXXXXX");
    assert_non_null(mkdtemp(f->dir));
    *state = f;
    return 0;
}

static int teardown_folder(void **state)
{
    folder_t *f = *state;
    char command[128];
    snprintf(command, sizeof command, "rm -rf '%s'", f->dir);
    assert_int_equal(system(command), 0);
    free(f);
    return 0;
}

/* The uploaded file called name, decoded; NULL if none. */
static char *uploaded(const cJSON *root, const char *name)
{
    const cJSON *f;
    cJSON_ArrayForEach(f, cJSON_GetObjectItemCaseSensitive(root, "files"))
    {
        if (strcmp(cJSON_GetObjectItemCaseSensitive(f, "name")->valuestring, name) != 0)
            continue;
        const char *b64 = cJSON_GetObjectItemCaseSensitive(f, "base64")->valuestring;
        uint8_t *data = NULL;
        size_t size = 0;
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bgb_base64_decode(b64, strlen(b64), 1 << 20, &data, &size, &err), BG_OK);
        char *text = malloc(size + 1);
        memcpy(text, data, size);
        text[size] = '\0';
        free(data);
        return text;
    }
    return NULL;
}

static void assert_uploaded(const cJSON *root, const char *name, const char *text)
{
    char *got = uploaded(root, name);
    assert_non_null(got);
    assert_string_equal(got, text);
    free(got);
}

static void test_pack_files(void **state)
{
    folder_t *f = *state;
    /* A TetGen mesh in a subfolder, two different files both called a.txt,
     * one file named twice, and a positions file found only through the
     * search path. */
    write_file(f, "scene/mesh/box.node", "node text\n");
    write_file(f, "scene/mesh/box.ele", "ele text\n");
    write_file(f, "scene/sel/a.txt", "selection\n");
    write_file(f, "scene/pos/a.txt", "positions\n");
    write_file(f, "library/goal.txt", "goal\n");
    write_file(f, "scene/job.json",
               "{\"mesh\": \"mesh/box.node\",\n"
               " \"handles\": [{\"select\": {\"file\": \"sel/a.txt\"}, \"positions\": "
               "\"pos/a.txt\"},\n"
               "             {\"select\": {\"file\": \"sel/a.txt\", \"group\": 2}}],\n"
               " \"task\": {\"kind\": \"morph\", \"target\": \"elsewhere/goal.txt\"},\n"
               " \"reference\": \"newton\"}\n");
    char scene[128], search[160];
    snprintf(scene, sizeof scene, "%s/scene/job.json", f->dir);
    snprintf(search, sizeof search, "/nonexistent:%s/library", f->dir);
    const bgb_client_submit_t submit = {
        .scene_path = scene, .search_path = search, .mechanism = "posted", .budget = 7.5};
    char *body = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_OK);
    cJSON *root = cJSON_Parse(body);
    free(body);
    assert_non_null(root);
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(root, "mechanism")->valuestring, "posted");
    assert_true(cJSON_GetObjectItemCaseSensitive(root, "budget")->valuedouble == 7.5);
    assert_int_equal(cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(root, "files")), 5);
    assert_uploaded(root, "box.node", "node text\n");
    assert_uploaded(root, "box.ele", "ele text\n");
    assert_uploaded(root, "a.txt", "selection\n");
    assert_uploaded(root, "2-a.txt", "positions\n");
    assert_uploaded(root, "goal.txt", "goal\n");
    const cJSON *s = cJSON_GetObjectItemCaseSensitive(root, "scene");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(s, "mesh")->valuestring, "box.node");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(s, "name")->valuestring, "job");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(s, "reference")->valuestring, "newton");
    const cJSON *handles = cJSON_GetObjectItemCaseSensitive(s, "handles");
    const cJSON *h0 = cJSON_GetArrayItem(handles, 0), *h1 = cJSON_GetArrayItem(handles, 1);
    assert_string_equal(
        cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(h0, "select"), "file")
            ->valuestring,
        "a.txt");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(h0, "positions")->valuestring, "2-a.txt");
    const cJSON *select1 = cJSON_GetObjectItemCaseSensitive(h1, "select");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(select1, "file")->valuestring, "a.txt");
    assert_int_equal(cJSON_GetObjectItemCaseSensitive(select1, "group")->valueint, 2);
    assert_string_equal(
        cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(s, "task"), "target")
            ->valuestring,
        "goal.txt");
    cJSON_Delete(root);
}

/* The solver settings of a submission replace the scene's members of
 * those names and keep the others; a scene without "solver" gets one, and
 * one whose "solver" is not an object is refused naming the field. */
static void test_pack_solver(void **state)
{
    folder_t *f = *state;
    write_file(f, "s/with.json",
               "{\"name\": \"w\", \"mesh\": {\"generate\": \"box\"}, \"solver\": {\"method\": "
               "\"newton\", \"tolerance\": 1e-8, \"max_iterations\": {\"newton\": 200}, "
               "\"continuation\": false}}");
    write_file(f, "s/without.json", "{\"name\": \"o\", \"mesh\": {\"generate\": \"box\"}}");
    write_file(f, "s/bad.json", "{\"name\": \"b\", \"solver\": [1]}");
    char path[128];
    snprintf(path, sizeof path, "%s/s/with.json", f->dir);
    bgb_client_submit_t submit = {.scene_path = path, .method = "local-global",
                                  .tolerance = 1e-6, .max_iterations = 50};
    char *body = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_OK);
    cJSON *root = cJSON_Parse(body);
    free(body);
    const cJSON *solver = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(root, "scene"), "solver");
    assert_string_equal(cJSON_GetObjectItemCaseSensitive(solver, "method")->valuestring,
                        "local-global");
    assert_true(cJSON_GetObjectItemCaseSensitive(solver, "tolerance")->valuedouble == 1e-6);
    assert_int_equal(cJSON_GetObjectItemCaseSensitive(solver, "max_iterations")->valueint, 50);
    assert_true(cJSON_IsFalse(cJSON_GetObjectItemCaseSensitive(solver, "continuation")));
    assert_int_equal(cJSON_GetArraySize(solver), 4);
    cJSON_Delete(root);

    /* Only the method: the scene's tolerance and caps stay. */
    submit = (bgb_client_submit_t){.scene_path = path, .method = "newton"};
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_OK);
    root = cJSON_Parse(body);
    free(body);
    solver = cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(root, "scene"),
                                              "solver");
    assert_true(cJSON_GetObjectItemCaseSensitive(solver, "tolerance")->valuedouble == 1e-8);
    assert_true(cJSON_IsObject(cJSON_GetObjectItemCaseSensitive(solver, "max_iterations")));
    cJSON_Delete(root);

    snprintf(path, sizeof path, "%s/s/without.json", f->dir);
    submit = (bgb_client_submit_t){.scene_path = path, .max_iterations = 7};
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_OK);
    root = cJSON_Parse(body);
    free(body);
    solver = cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(root, "scene"),
                                              "solver");
    assert_int_equal(cJSON_GetArraySize(solver), 1);
    assert_int_equal(cJSON_GetObjectItemCaseSensitive(solver, "max_iterations")->valueint, 7);
    cJSON_Delete(root);

    snprintf(path, sizeof path, "%s/s/bad.json", f->dir);
    submit = (bgb_client_submit_t){.scene_path = path, .tolerance = 1e-6};
    body = NULL;
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_ERR_INVALID);
    assert_null(body);
    assert_non_null(strstr(err.message, "bad.json: solver: expected an object"));
}

static void test_pack_errors(void **state)
{
    folder_t *f = *state;
    char scene[128];
    snprintf(scene, sizeof scene, "%s/s/missing.json", f->dir);
    write_file(f, "s/missing.json", "{\"name\": \"m\", \"mesh\": {\"file\": \"gone/x.mesh\"}}");
    const bgb_client_submit_t submit = {.scene_path = scene};
    char *body = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_ERR_NOT_FOUND);
    assert_null(body);
    assert_non_null(strstr(err.message, "missing.json: mesh.file: gone/x.mesh not found"));
    assert_non_null(strstr(err.message, "mesh search path (empty)"));

    write_file(f, "s/tet.json", "{\"mesh\": \"t.ele\"}");
    write_file(f, "s/t.ele", "ele\n");
    snprintf(scene, sizeof scene, "%s/s/tet.json", f->dir);
    bg_error_t err2 = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err2), BG_ERR_NOT_FOUND);
    assert_non_null(strstr(err2.message, "tet.json: mesh: a TetGen mesh needs"));
    assert_non_null(strstr(err2.message, "t.node"));

    write_file(f, "s/bad.json", "{\"mesh\":\n  [1, 2,,]}");
    snprintf(scene, sizeof scene, "%s/s/bad.json", f->dir);
    bg_error_t err3 = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err3), BG_ERR_PARSE);
    assert_non_null(strstr(err3.message, "bad.json: malformed JSON at line 2"));

    snprintf(scene, sizeof scene, "%s/s/none.json", f->dir);
    bg_error_t err4 = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err4), BG_ERR_IO);
    assert_non_null(strstr(err4.message, "none.json"));
}

/*
 * The one lookup `solve` and `submit` share: the scene parser takes any
 * non-directory (and an absolute path unchecked), the client only a
 * regular file, since it reads the file whole for the upload; a FIFO or a
 * directory is "not found" for the client, with the reason.
 */
static void test_lookup_kinds(void **state)
{
    folder_t *f = *state;
    char dir[160], path[200], scene[200];
    snprintf(dir, sizeof dir, "%s/s/", f->dir);
    write_file(f, "s/m.mesh", "x\n");
    snprintf(path, sizeof path, "%s/s/pipe", f->dir);
    assert_int_equal(mkfifo(path, 0600), 0);
    snprintf(path, sizeof path, "%s/s/sub", f->dir);
    assert_int_equal(mkdir(path, 0700), 0);
    char *found = NULL, *tried = NULL;
    const char *why = NULL;

    assert_int_equal(bg_file_lookup(dir, "pipe", NULL, BG_FILE_TRUST_ABSOLUTE, &found, &tried, &why),
                     BG_OK);
    assert_non_null(strstr(found, "/s/pipe"));
    free(found);
    assert_int_equal(bg_file_lookup(dir, "pipe", NULL, BG_FILE_REGULAR, &found, &tried, &why),
                     BG_ERR_NOT_FOUND);
    assert_null(found);
    assert_string_equal(why, "not a regular file");
    free(tried);
    assert_int_equal(bg_file_lookup(dir, "sub", NULL, 0, &found, &tried, &why), BG_ERR_NOT_FOUND);
    assert_string_equal(why, "a directory");
    free(tried);
    /* An absolute path: trusted by the scene, checked by the client. */
    assert_int_equal(bg_file_lookup(dir, "/nonexistent/x.mesh", dir, BG_FILE_TRUST_ABSOLUTE,
                                    &found, &tried, &why),
                     BG_OK);
    assert_string_equal(found, "/nonexistent/x.mesh");
    free(found);
    assert_int_equal(bg_file_lookup(dir, "/nonexistent/x.mesh", dir, BG_FILE_REGULAR, &found,
                                    &tried, &why),
                     BG_ERR_NOT_FOUND);
    free(tried);
    /* Not beside the scene: by name in the search path's folders, in order. */
    char search[400];
    snprintf(search, sizeof search, "%s/none:%s/s//", f->dir, f->dir);
    assert_int_equal(bg_file_lookup("elsewhere/", "data/m.mesh", search, BG_FILE_REGULAR, &found,
                                    &tried, &why),
                     BG_OK);
    snprintf(path, sizeof path, "%s/s/m.mesh", f->dir);
    assert_string_equal(found, path);
    free(found);

    write_file(f, "s/fifo.json", "{\"mesh\": \"pipe\"}");
    snprintf(scene, sizeof scene, "%s/s/fifo.json", f->dir);
    const bgb_client_submit_t submit = {.scene_path = scene};
    char *body = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_pack(&submit, &body, &err), BG_ERR_NOT_FOUND);
    assert_null(body);
    assert_non_null(strstr(err.message, "fifo.json: mesh: pipe not found"));
    assert_non_null(strstr(err.message, "(not a regular file)"));
}

/* A result file name that could leave --out is refused before any request. */
static void test_download_names(void **state)
{
    folder_t *f = *state;
    const bgb_client_config_t config = {.url = "http://127.0.0.1:9/"};
    bgb_client_t *client = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_new(&config, &client, &err), BG_OK);
    assert_string_equal(bgb_client_url(client), "http://127.0.0.1:9");
    static const char *const bad[] = {"../escape", "a/b", "..", ".", "", "x\ny"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        bg_error_t e = BG_ERROR_INIT;
        assert_int_equal(bgb_client_download(client, "j0123456789abcdef", bad[i], f->dir, NULL, &e),
                         BG_ERR_INVALID);
        assert_non_null(strstr(e.message, "result file name"));
    }
    assert_int_equal(bgb_client_http_status(client), 0);
    bgb_client_destroy(&client);
    assert_null(client);
    const bgb_client_config_t ftp = {.url = "ftp://127.0.0.1/"};
    bg_error_t e = BG_ERROR_INIT;
    assert_int_equal(bgb_client_new(&ftp, &client, &e), BG_ERR_INVALID);
    assert_non_null(strstr(e.message, "expected http://HOST:PORT"));
}

/* ------------------------------------------- against an in-process server */

typedef struct served {
    folder_t folder;
    bgb_store_t *store;
    bgb_rest_t *rest;
    char url[64];
    char token[BGB_TOKEN_SIZE]; /* an admin's */
} served_t;

static int setup_server(void **state)
{
    served_t *s = calloc(1, sizeof *s);
    snprintf(s->folder.dir, sizeof s->folder.dir, "/tmp/bgb-client-test.XXXXXX");
    assert_non_null(mkdtemp(s->folder.dir));
    char path[128];
    snprintf(path, sizeof path, "%s/store.db", s->folder.dir);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_open(path, &s->store, &err), BG_OK);
    const bgb_rest_config_t config = {.work_dir = s->folder.dir};
    assert_int_equal(bgb_rest_start(&config, s->store, &s->rest, &err), BG_OK);
    snprintf(s->url, sizeof s->url, "http://127.0.0.1:%u", (unsigned)bgb_rest_port(s->rest));
    assert_int_equal(bgb_tokens_create(s->store, "tester", 1, s->token, &err), BG_OK);
    *state = s;
    return 0;
}

static int teardown_server(void **state)
{
    served_t *s = *state;
    bgb_rest_stop(&s->rest);
    bgb_store_destroy(&s->store);
    folder_t *f = malloc(sizeof *f);
    *f = s->folder;
    free(s);
    *state = f;
    return teardown_folder(state);
}

static void submit_box(served_t *s, bgb_client_t *client, char id[32])
{
    write_file(
        &s->folder, "box.json",
        "{\"mesh\": {\"generate\": \"box\", \"cells\": [2, 1, 1], \"size\": [2, 1, 1]},"
        " \"material\": {\"mu\": 1, \"lambda\": 1},"
        " \"handles\": [{\"select\": {\"box\": {\"min\": [0, 0, 0], \"max\": [0, 1, 1]}}}]}");
    char scene[128];
    snprintf(scene, sizeof scene, "%s/box.json", s->folder.dir);
    const bgb_client_submit_t submit = {.scene_path = scene};
    cJSON *job = NULL;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_client_submit_job(client, &submit, &job, &err), BG_OK);
    assert_int_equal(bgb_client_http_status(client), 202);
    snprintf(id, 32, "%s", cJSON_GetObjectItemCaseSensitive(job, "id")->valuestring);
    cJSON_Delete(job);
}

/* A response over the client's cap is refused; the statuses map to bg_status. */
static void test_caps_and_statuses(void **state)
{
    served_t *s = *state;
    bgb_client_t *client = NULL, *small = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const bgb_client_config_t config = {.url = s->url, .token = s->token};
    const bgb_client_config_t tiny = {.url = s->url, .token = s->token, .max_response = 64};
    assert_int_equal(bgb_client_new(&config, &client, &err), BG_OK);
    assert_int_equal(bgb_client_new(&tiny, &small, &err), BG_OK);
    char id[32];
    submit_box(s, client, id);
    cJSON *doc = NULL;
    assert_int_equal(bgb_client_get_job(client, id, &doc, &err), BG_OK);
    char *text = cJSON_PrintUnformatted(doc);
    assert_true(strlen(text) > 64);
    free(text);
    cJSON_Delete(doc);
    bg_error_t over = BG_ERROR_INIT;
    assert_int_equal(bgb_client_get_job(small, id, &doc, &over), BG_ERR_LIMIT);
    assert_null(doc);
    assert_non_null(strstr(over.message, "exceeds the client's limit of 64 bytes"));

    bg_error_t missing = BG_ERROR_INIT;
    assert_int_equal(bgb_client_get_job(client, "j0000000000000000", &doc, &missing),
                     BG_ERR_NOT_FOUND);
    assert_int_equal(bgb_client_http_status(client), 404);
    assert_non_null(strstr(missing.message, ": 404 No such job: "));
    bg_error_t early = BG_ERROR_INIT;
    assert_int_equal(bgb_client_result(client, id, &doc, &early), BG_ERR_CONFLICT);
    assert_non_null(strstr(early.message, "409 No result"));
    bg_error_t bad = BG_ERROR_INIT;
    assert_int_equal(bgb_client_list_jobs(client, "nope", 0, NULL, &doc, &bad), BG_ERR_INVALID);
    assert_non_null(strstr(bad.message, "(field state)"));
    bgb_client_destroy(&small);
    bgb_client_destroy(&client);
}

typedef struct stream_seen {
    int count;
    char first_event[32];
    char last_id[32];
} stream_seen_t;

static int count_events(void *ctx, const char *id, const char *event, const char *data)
{
    stream_seen_t *s = ctx;
    (void)data;
    if (s->count++ == 0)
        snprintf(s->first_event, sizeof s->first_event, "%s", event);
    snprintf(s->last_id, sizeof s->last_id, "%s", id);
    return 0;
}

static int stop_at_first(void *ctx, const char *id, const char *event, const char *data)
{
    count_events(ctx, id, event, data);
    return 1;
}

/* The real events stream: it ends when the job has ended; a callback can stop
 * it early (an active job's stream would otherwise go on); Last-Event-ID resumes. */
static void test_events_stream(void **state)
{
    served_t *s = *state;
    bgb_client_t *client = NULL;
    bg_error_t err = BG_ERROR_INIT;
    const bgb_client_config_t config = {.url = s->url, .token = s->token};
    assert_int_equal(bgb_client_new(&config, &client, &err), BG_OK);
    char id[32];
    submit_box(s, client, id);
    stream_seen_t first = {0};
    assert_int_equal(bgb_client_events(client, id, NULL, stop_at_first, &first, &err), BG_OK);
    assert_int_equal(first.count, 1);
    cJSON *doc = NULL;
    assert_int_equal(bgb_client_cancel_job(client, id, &doc, &err), BG_OK);
    cJSON_Delete(doc);
    /* Ended: the whole log (queued, plan, cancelled — in the store's order) then the end. */
    stream_seen_t all = {0};
    assert_int_equal(bgb_client_events(client, id, NULL, count_events, &all, &err), BG_OK);
    assert_int_equal(all.count, 3);
    stream_seen_t rest = {0};
    assert_int_equal(bgb_client_events(client, id, first.last_id, count_events, &rest, &err),
                     BG_OK);
    assert_int_equal(rest.count, 2);
    assert_string_equal(rest.last_id, all.last_id);
    bg_error_t missing = BG_ERROR_INIT;
    assert_int_equal(
        bgb_client_events(client, "j0000000000000000", NULL, count_events, &all, &missing),
        BG_ERR_NOT_FOUND);
    bgb_client_destroy(&client);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sse_every_boundary),
        cmocka_unit_test(test_sse_caps),
        cmocka_unit_test(test_sse_stop),
        cmocka_unit_test_setup_teardown(test_pack_files, setup_folder, teardown_folder),
        cmocka_unit_test_setup_teardown(test_pack_solver, setup_folder, teardown_folder),
        cmocka_unit_test_setup_teardown(test_pack_errors, setup_folder, teardown_folder),
        cmocka_unit_test_setup_teardown(test_lookup_kinds, setup_folder, teardown_folder),
        cmocka_unit_test_setup_teardown(test_download_names, setup_folder, teardown_folder),
        cmocka_unit_test_setup_teardown(test_caps_and_statuses, setup_server, teardown_server),
        cmocka_unit_test_setup_teardown(test_events_stream, setup_server, teardown_server),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
