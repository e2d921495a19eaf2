/*
 * The broker's job store on a real SQLite file in a temporary directory:
 * durability across a reopen, idempotency keys, pagination, state
 * transitions and their conflicts, events, files, field checks, and
 * concurrent submits from many threads (group commit).
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <sqlite3.h>

#include "bgb_store.h"

#define SCENE "{\"mesh\":{\"generate\":\"box\",\"cells\":[2,2,2],\"size\":[1,1,1]}}"
#define THREADS 8
#define PER_THREAD 40

typedef struct fixture {
    char dir[64];
    char path[128];
    bgb_store_t *store;
} fixture_t;

static int setup(void **state)
{
    fixture_t *f = calloc(1, sizeof *f);
    assert_non_null(f);
    snprintf(f->dir, sizeof f->dir, "/tmp/bgb-store-XXXXXX");
    assert_non_null(mkdtemp(f->dir));
    snprintf(f->path, sizeof f->path, "%s/jobs.db", f->dir);
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_open(f->path, &f->store, &err), BG_OK);
    *state = f;
    return 0;
}

static int teardown(void **state)
{
    fixture_t *f = *state;
    bgb_store_destroy(&f->store);
    char cmd[256];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", f->dir);
    assert_int_equal(system(cmd), 0);
    free(f);
    return 0;
}

static bgb_submit_t plain_job(void)
{
    bgb_submit_t j = {.scene = SCENE, .scene_size = strlen(SCENE), .mechanism = "central",
                      .budget = 10.0};
    return j;
}

static void test_submit_get_and_reopen(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    const uint8_t mesh[] = {'M', 0, 'X', 0xff};
    const bgb_file_t files[] = {{"bar.mesh", mesh, sizeof mesh}, {"empty.txt", NULL, 0}};
    bgb_submit_t j = plain_job();
    j.files = files;
    j.file_count = 2;
    j.mechanism = "catallactic";
    j.budget = 2.5;
    char id[BGB_JOB_ID_SIZE];
    int created = 0;
    assert_int_equal(bgb_store_submit(f->store, &j, id, &created, &err), BG_OK);
    assert_true(created);
    assert_int_equal(strlen(id), BGB_JOB_ID_SIZE - 1);
    assert_int_equal(id[0], 'j');

    /* Close and reopen: what was acknowledged is still there. */
    bgb_store_destroy(&f->store);
    assert_null(f->store);
    assert_int_equal(bgb_store_open(f->path, &f->store, &err), BG_OK);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    assert_string_equal(job.id, id);
    assert_int_equal(job.state, BGB_JOB_QUEUED);
    assert_string_equal(job.mechanism, "catallactic");
    assert_true(job.budget == 2.5);
    assert_int_equal(job.scene_size, strlen(SCENE));
    assert_memory_equal(job.scene, SCENE, strlen(SCENE));
    assert_null(job.reason);
    assert_true(job.created > 1.7e9 && job.updated >= job.created);
    bgb_job_release(&job);

    uint8_t *data = NULL;
    size_t size = 0;
    assert_int_equal(bgb_store_get_file(f->store, id, "input", "bar.mesh", &data, &size, &err),
                     BG_OK);
    assert_int_equal(size, sizeof mesh);
    assert_memory_equal(data, mesh, sizeof mesh);
    free(data);
    assert_int_equal(bgb_store_get_file(f->store, id, "input", "empty.txt", &data, &size, &err),
                     BG_OK);
    assert_int_equal(size, 0);
    free(data);
    bg_error_t missing = BG_ERROR_INIT;
    assert_int_equal(bgb_store_get_file(f->store, id, "result", "bar.mesh", &data, &size,
                                        &missing),
                     BG_ERR_NOT_FOUND);
    assert_non_null(strstr(missing.message, "no result file 'bar.mesh'"));
    bg_error_t unknown = BG_ERROR_INIT;
    assert_int_equal(bgb_store_get(f->store, "j0000000000000000", &job, &unknown),
                     BG_ERR_NOT_FOUND);
    assert_non_null(strstr(unknown.message, "no job 'j0000000000000000'"));
}

static void test_idempotency_key(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    bgb_submit_t j = plain_job();
    j.idempotency_key = "client-42";
    char first[BGB_JOB_ID_SIZE], second[BGB_JOB_ID_SIZE], other[BGB_JOB_ID_SIZE];
    int created = 0;
    assert_int_equal(bgb_store_submit(f->store, &j, first, &created, &err), BG_OK);
    assert_true(created);
    /* Same key, even with another body: the first job, nothing stored. */
    j.budget = 99.0;
    assert_int_equal(bgb_store_submit(f->store, &j, second, &created, &err), BG_OK);
    assert_false(created);
    assert_string_equal(first, second);
    j.idempotency_key = "client-43";
    assert_int_equal(bgb_store_submit(f->store, &j, other, &created, &err), BG_OK);
    assert_true(created);
    assert_string_not_equal(first, other);
    int64_t counts[BGB_JOB_STATE_COUNT];
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    assert_int_equal(counts[BGB_JOB_QUEUED], 2);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, first, &job, &err), BG_OK);
    assert_true(job.budget == 10.0);
    bgb_job_release(&job);
}

static void test_bad_fields(void **state)
{
    fixture_t *f = *state;
    char id[BGB_JOB_ID_SIZE];
    int created = 1;
    struct {
        const char *name;
        bgb_submit_t job;
        bg_status status;
        const char *words;
    } cases[6];
    const bgb_file_t escape[] = {{"../etc/passwd", (const uint8_t *)"x", 1}};
    const bgb_file_t twice[] = {{"a.mesh", (const uint8_t *)"x", 1},
                                {"a.mesh", (const uint8_t *)"y", 1}};
    const bgb_file_t dotdot[] = {{"..", (const uint8_t *)"x", 1}};
    for (int i = 0; i < 6; i++)
        cases[i].job = plain_job();
    cases[0].job.mechanism = "auction";
    cases[0].status = BG_ERR_INVALID;
    cases[0].words = "mechanism: 'auction' is not one of central, catallactic, posted";
    cases[1].job.budget = -1.0;
    cases[1].status = BG_ERR_INVALID;
    cases[1].words = "budget: must be a positive number";
    cases[2].job.files = escape;
    cases[2].job.file_count = 1;
    cases[2].status = BG_ERR_INVALID;
    cases[2].words = "'../etc/passwd' is not a plain file name";
    cases[3].job.files = twice;
    cases[3].job.file_count = 2;
    cases[3].status = BG_ERR_INVALID;
    cases[3].words = "'a.mesh' is given twice";
    cases[4].job.files = dotdot;
    cases[4].job.file_count = 1;
    cases[4].status = BG_ERR_INVALID;
    cases[4].words = "'..' is not a plain file name";
    cases[5].job.file_count = BGB_STORE_MAX_FILES + 1;
    cases[5].status = BG_ERR_LIMIT;
    cases[5].words = "files: 65 files, at most 64";
    for (int i = 0; i < 6; i++) {
        bg_error_t err = BG_ERROR_INIT;
        assert_int_equal(bgb_store_submit(f->store, &cases[i].job, id, &created, &err),
                         cases[i].status);
        assert_false(created);
        if (!strstr(err.message, cases[i].words))
            fail_msg("case %d: '%s' lacks '%s'", i, err.message, cases[i].words);
    }
    int64_t counts[BGB_JOB_STATE_COUNT];
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    for (int s = 0; s < BGB_JOB_STATE_COUNT; s++)
        assert_int_equal(counts[s], 0);
}

static void count_event(void *ctx, int64_t sequence, double time, const char *kind,
                        const char *json)
{
    char *log = ctx;
    char line[160];
    snprintf(line, sizeof line, "%s %s;", kind, json);
    strncat(log, line, 1023 - strlen(log));
    (void)sequence;
    assert_true(time > 1.7e9);
}

static void test_transitions_and_events(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    bgb_submit_t j = plain_job();
    char id[BGB_JOB_ID_SIZE];
    int created = 0;
    assert_int_equal(bgb_store_submit(f->store, &j, id, &created, &err), BG_OK);
    const unsigned active = (1u << BGB_JOB_QUEUED) | (1u << BGB_JOB_ALLOCATING) |
                            (1u << BGB_JOB_RUNNING);
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_QUEUED,
                                          BGB_JOB_ALLOCATING, NULL, &err),
                     BG_OK);
    assert_int_equal(bgb_store_add_event(f->store, id, "contract",
                                         "{\"service\":\"rotation-fit\",\"price\":1.5}", &err),
                     BG_OK);
    assert_int_equal(bgb_store_transition(f->store, id, active, BGB_JOB_CANCELLED,
                                          "cancelled by the user", &err),
                     BG_OK);
    /* An ended job cannot be cancelled again or started. */
    bg_error_t conflict = BG_ERROR_INIT;
    assert_int_equal(bgb_store_transition(f->store, id, active, BGB_JOB_CANCELLED, NULL,
                                          &conflict),
                     BG_ERR_CONFLICT);
    assert_non_null(strstr(conflict.message, "is cancelled; it cannot become cancelled"));
    bg_error_t missing = BG_ERROR_INIT;
    assert_int_equal(bgb_store_transition(f->store, "jffffffffffffffff", active,
                                          BGB_JOB_RUNNING, NULL, &missing),
                     BG_ERR_NOT_FOUND);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    assert_int_equal(job.state, BGB_JOB_CANCELLED);
    assert_string_equal(job.reason, "cancelled by the user");
    bgb_job_release(&job);
    char log[1024] = "";
    assert_int_equal(bgb_store_events(f->store, id, 0, count_event, log, &err), BG_OK);
    assert_string_equal(log, "state {\"state\":\"queued\"};state {\"state\":\"allocating\"};"
                             "contract {\"service\":\"rotation-fit\",\"price\":1.5};"
                             "state {\"state\":\"cancelled\"};");
    const bgb_file_t report = {"report.json", (const uint8_t *)"{}", 2};
    assert_int_equal(bgb_store_put_file(f->store, id, "result", &report, &err), BG_OK);
    uint8_t *data = NULL;
    size_t size = 0;
    assert_int_equal(bgb_store_get_file(f->store, id, "result", "report.json", &data, &size,
                                        &err),
                     BG_OK);
    assert_int_equal(size, 2);
    free(data);
    bg_error_t bad = BG_ERROR_INIT;
    const bgb_file_t sneaky = {"a/b", (const uint8_t *)"", 0};
    assert_int_equal(bgb_store_put_file(f->store, id, "result", &sneaky, &bad), BG_ERR_INVALID);
}

static void test_pagination(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    char ids[7][BGB_JOB_ID_SIZE];
    for (int i = 0; i < 7; i++) {
        bgb_submit_t j = plain_job();
        int created = 0;
        assert_int_equal(bgb_store_submit(f->store, &j, ids[i], &created, &err), BG_OK);
    }
    for (int i = 0; i < 7; i += 2)
        assert_int_equal(bgb_store_transition(f->store, ids[i], 1u << BGB_JOB_QUEUED,
                                              BGB_JOB_RUNNING, NULL, &err),
                         BG_OK);
    /* All jobs, three a page, in submission order. */
    bgb_job_t page[3];
    int count = 0, seen = 0;
    int64_t cursor = 0, next = 0;
    do {
        assert_int_equal(bgb_store_list(f->store, -1, cursor, 3, page, &count, &next, &err),
                         BG_OK);
        for (int i = 0; i < count; i++) {
            assert_string_equal(page[i].id, ids[seen + i]);
            bgb_job_release(&page[i]);
        }
        seen += count;
        cursor = next;
    } while (next != 0);
    assert_int_equal(seen, 7);
    /* Only the running ones: 0, 2, 4, 6. */
    assert_int_equal(bgb_store_list(f->store, BGB_JOB_RUNNING, 0, 3, page, &count, &next, &err),
                     BG_OK);
    assert_int_equal(count, 3);
    assert_string_equal(page[2].id, ids[4]);
    for (int i = 0; i < count; i++)
        bgb_job_release(&page[i]);
    assert_true(next != 0);
    assert_int_equal(bgb_store_list(f->store, BGB_JOB_RUNNING, next, 3, page, &count, &next,
                                    &err),
                     BG_OK);
    assert_int_equal(count, 1);
    assert_string_equal(page[0].id, ids[6]);
    assert_int_equal(next, 0);
    bgb_job_release(&page[0]);
}

typedef struct worker {
    bgb_store_t *store;
    int index;
    char ids[PER_THREAD][BGB_JOB_ID_SIZE];
    int failures;
} worker_t;

static void *submit_many(void *arg)
{
    worker_t *w = arg;
    for (int i = 0; i < PER_THREAD; i++) {
        char key[64];
        snprintf(key, sizeof key, "w%d-%d", w->index, i % (PER_THREAD / 2));
        bgb_submit_t j = plain_job();
        j.idempotency_key = key; /* every key twice: half the submits are repeats */
        bg_error_t err = BG_ERROR_INIT;
        int created = 0;
        if (bgb_store_submit(w->store, &j, w->ids[i], &created, &err) != BG_OK ||
            created != (i < PER_THREAD / 2))
            w->failures++;
    }
    return NULL;
}

/* THREADS workers submit_many into store at once; waits for them all. */
static void run_workers(bgb_store_t *store, worker_t workers[THREADS])
{
    pthread_t threads[THREADS];
    for (int t = 0; t < THREADS; t++) {
        memset(&workers[t], 0, sizeof workers[t]);
        workers[t].store = store;
        workers[t].index = t;
        assert_int_equal(pthread_create(&threads[t], NULL, submit_many, &workers[t]), 0);
    }
    for (int t = 0; t < THREADS; t++)
        assert_int_equal(pthread_join(threads[t], NULL), 0);
}

static void test_concurrent_submits(void **state)
{
    fixture_t *f = *state;
    worker_t workers[THREADS];
    run_workers(f->store, workers);
    for (int t = 0; t < THREADS; t++) {
        assert_int_equal(workers[t].failures, 0);
        for (int i = PER_THREAD / 2; i < PER_THREAD; i++)
            assert_string_equal(workers[t].ids[i], workers[t].ids[i - PER_THREAD / 2]);
    }
    int64_t counts[BGB_JOB_STATE_COUNT], commits = 0, submits = 0;
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_count(f->store, counts, &err), BG_OK);
    assert_int_equal(counts[BGB_JOB_QUEUED], THREADS * PER_THREAD / 2);
    bgb_store_commit_stats(f->store, &commits, &submits);
    assert_int_equal(submits, THREADS * PER_THREAD / 2);
    assert_true(commits >= 1 && commits <= THREADS * PER_THREAD);
}

/*
 * Store options: with max_batch 1 every submit (a replay too) is its own
 * transaction, so the commits count them all; the process-safe store keeps
 * what it committed across a reopen; bad options are refused.
 */
static void test_options(void **state)
{
    fixture_t *f = *state;
    bgb_store_destroy(&f->store);
    char path[160];
    snprintf(path, sizeof path, "%s/single.db", f->dir);
    const bgb_store_options_t single = {BGB_STORE_POWER_SAFE, 1};
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bgb_store_open_with(path, &single, &f->store, &err), BG_OK);
    worker_t workers[THREADS];
    run_workers(f->store, workers);
    for (int t = 0; t < THREADS; t++)
        assert_int_equal(workers[t].failures, 0);
    int64_t commits = 0, submits = 0;
    bgb_store_commit_stats(f->store, &commits, &submits);
    assert_int_equal(submits, THREADS * PER_THREAD / 2);
    assert_int_equal(commits, THREADS * PER_THREAD);
    bgb_store_destroy(&f->store);

    snprintf(path, sizeof path, "%s/process-safe.db", f->dir);
    const bgb_store_options_t fast = {BGB_STORE_PROCESS_SAFE, 0};
    assert_int_equal(bgb_store_open_with(path, &fast, &f->store, &err), BG_OK);
    const bgb_submit_t j = plain_job();
    char id[BGB_JOB_ID_SIZE];
    int created = 0;
    double stored_at = 0.0;
    assert_int_equal(bgb_store_submit_at(f->store, &j, id, &created, &stored_at, &err), BG_OK);
    assert_true(created);
    bgb_store_destroy(&f->store);
    assert_int_equal(bgb_store_open_with(path, &fast, &f->store, &err), BG_OK);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    /* submit_at told the time the store recorded. */
    assert_true(job.created == stored_at && job.updated == stored_at);
    bgb_job_release(&job);
    bgb_store_destroy(&f->store);

    const bgb_store_options_t bad[] = {{BGB_STORE_POWER_SAFE, -1}, {(bgb_store_durability)7, 0}};
    for (int i = 0; i < 2; i++) {
        bg_error_t e = BG_ERROR_INIT;
        bgb_store_t *s = NULL;
        assert_int_equal(bgb_store_open_with(path, &bad[i], &s, &e), BG_ERR_INVALID);
        assert_null(s);
    }
    /* teardown destroys f->store: leave an open default store. */
    assert_int_equal(bgb_store_open(f->path, &f->store, &err), BG_OK);
}

/* The schema of a version 1 store, as a broker before owners wrote it. */
static const char V1_SCHEMA[] =
    "CREATE TABLE jobs(seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE,"
    " state INTEGER NOT NULL, mechanism TEXT NOT NULL, budget REAL NOT NULL,"
    " created REAL NOT NULL, updated REAL NOT NULL, reason TEXT,"
    " idempotency_key TEXT UNIQUE, scene BLOB NOT NULL);"
    "CREATE TABLE files(job TEXT NOT NULL REFERENCES jobs(id), kind TEXT NOT NULL,"
    " name TEXT NOT NULL, data BLOB NOT NULL, PRIMARY KEY(job, kind, name));"
    "CREATE TABLE events(seq INTEGER PRIMARY KEY AUTOINCREMENT,"
    " job TEXT NOT NULL REFERENCES jobs(id), time REAL NOT NULL, kind TEXT NOT NULL,"
    " data TEXT NOT NULL);"
    "INSERT INTO jobs(id, state, mechanism, budget, created, updated, idempotency_key, scene)"
    " VALUES('j0000000000000001', 3, 'central', 10, 1, 1, 'k1', '{}');"
    "INSERT INTO files VALUES('j0000000000000001', 'input', 'a.mesh', zeroblob(1000));"
    "INSERT INTO files VALUES('j0000000000000001', 'result', 'r.vtu', zeroblob(234));"
    "PRAGMA user_version=1;";

/* A version 1 store opens: its jobs are the "local" user's, their bytes
 * counted from their files, their keys still replayed (and scoped). */
static void test_migrates_version_1(void **state)
{
    fixture_t *f = *state;
    bgb_store_destroy(&f->store);
    char path[160];
    snprintf(path, sizeof path, "%s/v1.db", f->dir);
    sqlite3 *db = NULL;
    assert_int_equal(sqlite3_open(path, &db), SQLITE_OK);
    assert_int_equal(sqlite3_exec(db, V1_SCHEMA, NULL, NULL, NULL), SQLITE_OK);
    sqlite3_close(db);
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_store_open(path, &f->store, &err) != BG_OK)
        fail_msg("%s", err.message);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, "j0000000000000001", &job, &err), BG_OK);
    assert_string_equal(job.owner, "local");
    assert_int_equal(job.state, BGB_JOB_SUCCEEDED);
    bgb_job_release(&job);
    int in_flight = -1;
    int64_t bytes = -1;
    assert_int_equal(bgb_store_usage(f->store, "local", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 0);
    assert_int_equal(bytes, 1234);
    const bgb_submit_t again = {.idempotency_key = "k1", .scene = "{}", .scene_size = 2,
                                .mechanism = "central", .budget = 10};
    char id[BGB_JOB_ID_SIZE];
    int created = 1;
    assert_int_equal(bgb_store_submit(f->store, &again, id, &created, &err), BG_OK);
    assert_int_equal(created, 0);
    assert_string_equal(id, "j0000000000000001");
    /* Another user's "k1" is another key. */
    const bgb_submit_t other = {.owner = "ada", .idempotency_key = "k1", .scene = "{}",
                                .scene_size = 2, .mechanism = "central", .budget = 10};
    assert_int_equal(bgb_store_submit(f->store, &other, id, &created, &err), BG_OK);
    assert_int_equal(created, 1);
    assert_string_not_equal(id, "j0000000000000001");
}

/* A version 2 store (before deadlines) opens: its jobs have none, and a
 * new job's deadline is kept. */
static void test_migrates_version_2(void **state)
{
    fixture_t *f = *state;
    bgb_store_destroy(&f->store);
    char path[160];
    snprintf(path, sizeof path, "%s/v2.db", f->dir);
    sqlite3 *db = NULL;
    assert_int_equal(sqlite3_open(path, &db), SQLITE_OK);
    assert_int_equal(sqlite3_exec(db, V1_SCHEMA, NULL, NULL, NULL), SQLITE_OK);
    assert_int_equal(sqlite3_exec(db,
                                  "ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT 'local';"
                                  "ALTER TABLE jobs ADD COLUMN bytes INTEGER NOT NULL DEFAULT 0;"
                                  "ALTER TABLE jobs ADD COLUMN fingerprint TEXT;"
                                  "PRAGMA user_version=2;",
                                  NULL, NULL, NULL),
                     SQLITE_OK);
    sqlite3_close(db);
    bg_error_t err = BG_ERROR_INIT;
    if (bgb_store_open(path, &f->store, &err) != BG_OK)
        fail_msg("%s", err.message);
    bgb_job_t job = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, "j0000000000000001", &job, &err), BG_OK);
    assert_true(job.deadline == 0.0);
    bgb_job_release(&job);
    const bgb_submit_t timed = {.scene = "{}", .scene_size = 2, .mechanism = "central",
                                .budget = 10, .deadline = 45};
    char id[BGB_JOB_ID_SIZE];
    int created = 0;
    assert_int_equal(bgb_store_submit(f->store, &timed, id, &created, &err), BG_OK);
    assert_int_equal(bgb_store_get(f->store, id, &job, &err), BG_OK);
    assert_true(job.deadline == 45.0);
    bgb_job_release(&job);
    const bgb_submit_t bad = {.scene = "{}", .scene_size = 2, .mechanism = "central",
                              .budget = 10, .deadline = -1};
    assert_int_equal(bgb_store_submit(f->store, &bad, id, &created, &err), BG_ERR_INVALID);
}

/* Bytes and jobs in flight per user, result files included; a deleted job
 * frees them; an active job cannot be deleted. */
static void test_usage_and_delete(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    const uint8_t data[300] = {0};
    const bgb_file_t in = {"in.mesh", data, 100};
    const bgb_submit_t job = {.owner = "ada", .scene = SCENE, .scene_size = strlen(SCENE),
                              .mechanism = "central", .budget = 1, .files = &in,
                              .file_count = 1};
    char id[BGB_JOB_ID_SIZE], other[BGB_JOB_ID_SIZE];
    int created = 0, in_flight = 0;
    int64_t bytes = 0;
    assert_int_equal(bgb_store_submit(f->store, &job, id, &created, &err), BG_OK);
    assert_int_equal(bgb_store_submit(f->store, &job, other, &created, &err), BG_OK);
    const bgb_file_t out = {"out.vtu", data, 300};
    assert_int_equal(bgb_store_put_file(f->store, id, "result", &out, &err), BG_OK);
    const bgb_file_t smaller = {"out.vtu", data, 50}; /* a replaced file counts once */
    assert_int_equal(bgb_store_put_file(f->store, id, "result", &smaller, &err), BG_OK);
    assert_int_equal(bgb_store_usage(f->store, "ada", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 2);
    assert_int_equal(bytes, 100 + 50 + 100);
    assert_int_equal(bgb_store_usage(f->store, "bob", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 0);
    assert_int_equal(bytes, 0);
    assert_int_equal(bgb_store_delete(f->store, id, &err), BG_ERR_CONFLICT);
    assert_int_equal(bgb_store_transition(f->store, id, 1u << BGB_JOB_QUEUED, BGB_JOB_CANCELLED,
                                          NULL, &err),
                     BG_OK);
    assert_int_equal(bgb_store_delete(f->store, id, &err), BG_OK);
    assert_int_equal(bgb_store_usage(f->store, "ada", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 1);
    assert_int_equal(bytes, 100);
    bgb_job_t gone = BGB_JOB_INIT;
    assert_int_equal(bgb_store_get(f->store, id, &gone, &err), BG_ERR_NOT_FOUND);
    assert_int_equal(bgb_store_delete(f->store, id, &err), BG_ERR_NOT_FOUND);
}

/* The usage the store keeps per user (by triggers) equals a sum over its
 * jobs, computed here on the file itself, after submits by two users,
 * transitions in and out of flight, result files and a delete. */
static void test_usage_matches_jobs(void **state)
{
    fixture_t *f = *state;
    bg_error_t err = BG_ERROR_INIT;
    const uint8_t data[64] = {0};
    const char *owners[2] = {"ada", "bob"};
    char ids[12][BGB_JOB_ID_SIZE];
    for (int i = 0; i < 12; i++) {
        const bgb_file_t in = {"in.mesh", data, (size_t)(1 + i)};
        const bgb_submit_t job = {.owner = owners[i % 2], .scene = SCENE,
                                  .scene_size = strlen(SCENE), .mechanism = "central",
                                  .budget = 1, .files = &in, .file_count = 1};
        int created = 0;
        assert_int_equal(bgb_store_submit(f->store, &job, ids[i], &created, &err), BG_OK);
    }
    for (int i = 0; i < 12; i += 3) { /* in flight, then done */
        assert_int_equal(bgb_store_transition(f->store, ids[i], 1u << BGB_JOB_QUEUED,
                                              BGB_JOB_RUNNING, NULL, &err),
                         BG_OK);
        const bgb_file_t out = {"out.vtu", data, (size_t)(10 + i)};
        assert_int_equal(bgb_store_put_file(f->store, ids[i], "result", &out, &err), BG_OK);
        assert_int_equal(bgb_store_transition(f->store, ids[i], 1u << BGB_JOB_RUNNING,
                                              BGB_JOB_SUCCEEDED, NULL, &err),
                         BG_OK);
    }
    assert_int_equal(bgb_store_delete(f->store, ids[3], &err), BG_OK);
    sqlite3 *db = NULL;
    assert_int_equal(sqlite3_open(f->path, &db), SQLITE_OK);
    sqlite3_stmt *s = NULL;
    assert_int_equal(sqlite3_prepare_v2(db,
                                        "SELECT owner, SUM(state IN (0, 1, 2)), SUM(bytes) "
                                        "FROM jobs GROUP BY owner ORDER BY owner",
                                        -1, &s, NULL),
                     SQLITE_OK);
    int rows = 0;
    while (sqlite3_step(s) == SQLITE_ROW) {
        int in_flight = -1;
        int64_t bytes = -1;
        assert_int_equal(bgb_store_usage(f->store, (const char *)sqlite3_column_text(s, 0),
                                         &in_flight, &bytes, &err),
                         BG_OK);
        assert_int_equal(in_flight, sqlite3_column_int(s, 1));
        assert_int_equal(bytes, sqlite3_column_int64(s, 2));
        rows++;
    }
    sqlite3_finalize(s);
    sqlite3_close(db);
    assert_int_equal(rows, 2);
    int in_flight = -1;
    int64_t bytes = -1;
    /* ada: jobs 0..10 even; 0 and 6 done, the rest in flight; bob: 3 deleted, 9 done. */
    assert_int_equal(bgb_store_usage(f->store, "ada", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 4);
    assert_int_equal(bgb_store_usage(f->store, "bob", &in_flight, &bytes, &err), BG_OK);
    assert_int_equal(in_flight, 4);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_submit_get_and_reopen, setup, teardown),
        cmocka_unit_test_setup_teardown(test_idempotency_key, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_fields, setup, teardown),
        cmocka_unit_test_setup_teardown(test_transitions_and_events, setup, teardown),
        cmocka_unit_test_setup_teardown(test_pagination, setup, teardown),
        cmocka_unit_test_setup_teardown(test_concurrent_submits, setup, teardown),
        cmocka_unit_test_setup_teardown(test_options, setup, teardown),
        cmocka_unit_test_setup_teardown(test_migrates_version_1, setup, teardown),
        cmocka_unit_test_setup_teardown(test_migrates_version_2, setup, teardown),
        cmocka_unit_test_setup_teardown(test_usage_and_delete, setup, teardown),
        cmocka_unit_test_setup_teardown(test_usage_matches_jobs, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
