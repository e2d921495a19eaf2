#include "bgb_store.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <sqlite3.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* The schema version this code writes and reads (PRAGMA user_version);
 * a version 1 or 2 store is migrated on open (MIGRATE_1_2, MIGRATE_2_3). */
#define STORE_SCHEMA_VERSION 3
/* Jobs without a user (version 1 stores, and callers that give none). */
#define STORE_DEFAULT_OWNER "local"
/* How long a connection waits for another one's lock before failing. */
#define STORE_BUSY_TIMEOUT_MS 10000
/* Group commit: when the last batch held several submits (callers are
 * submitting concurrently), the writer gives the callers it just answered
 * up to this long to send their next submit before it commits, so batches
 * grow to the number of concurrent callers instead of staying at the few
 * that happened to arrive during the previous fsync. A lone caller never
 * waits (its batches hold one submit). */
#define STORE_GATHER_NS 1000000L
/* Submits per transaction at most, by default. */
#define STORE_DEFAULT_MAX_BATCH 256

static const char SCHEMA[] =
    "CREATE TABLE IF NOT EXISTS jobs("
    "  seq INTEGER PRIMARY KEY AUTOINCREMENT,"
    "  id TEXT NOT NULL UNIQUE,"
    "  state INTEGER NOT NULL,"
    "  mechanism TEXT NOT NULL,"
    "  budget REAL NOT NULL,"
    "  created REAL NOT NULL,"
    "  updated REAL NOT NULL,"
    "  reason TEXT,"
    "  idempotency_key TEXT UNIQUE,"
    "  scene BLOB NOT NULL,"
    "  owner TEXT NOT NULL DEFAULT '" STORE_DEFAULT_OWNER "',"
    "  bytes INTEGER NOT NULL DEFAULT 0,"
    "  fingerprint TEXT,"
    "  deadline REAL NOT NULL DEFAULT 0);"
    "CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs(state, seq);"
    "CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs(owner, state);"
    "CREATE TABLE IF NOT EXISTS files("
    "  job TEXT NOT NULL REFERENCES jobs(id),"
    "  kind TEXT NOT NULL,"
    "  name TEXT NOT NULL,"
    "  data BLOB NOT NULL,"
    "  PRIMARY KEY(job, kind, name));"
    "CREATE TABLE IF NOT EXISTS events("
    "  seq INTEGER PRIMARY KEY AUTOINCREMENT,"
    "  job TEXT NOT NULL REFERENCES jobs(id),"
    "  time REAL NOT NULL,"
    "  kind TEXT NOT NULL,"
    "  data TEXT NOT NULL);"
    "CREATE INDEX IF NOT EXISTS events_by_job ON events(job, seq);"
    "CREATE TABLE IF NOT EXISTS tokens("
    "  id TEXT PRIMARY KEY,"
    "  user TEXT NOT NULL,"
    "  admin INTEGER NOT NULL,"
    "  salt TEXT NOT NULL,"
    "  hash TEXT NOT NULL,"
    "  created REAL NOT NULL,"
    "  revoked INTEGER NOT NULL DEFAULT 0);";

/* Version 1 → 2: jobs get their user (owner), the bytes of their files
 * (for the per-user quota) and the fingerprint of their submission (for
 * Idempotency-Key replays); idempotency keys become "owner\x1fkey". */
static const char MIGRATE_1_2[] =
    "ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '" STORE_DEFAULT_OWNER "';"
    "ALTER TABLE jobs ADD COLUMN bytes INTEGER NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN fingerprint TEXT;"
    "UPDATE jobs SET bytes = (SELECT COALESCE(SUM(length(data)), 0) FROM files "
    "  WHERE files.job = jobs.id);"
    "UPDATE jobs SET idempotency_key = owner || char(31) || idempotency_key "
    "  WHERE idempotency_key IS NOT NULL;";

/* Each user's jobs in flight and stored bytes, kept by triggers in the
 * transactions that change jobs, so the quota check on every submit is
 * one primary-key read instead of a sum over all of the user's jobs
 * (which made n submits cost O(n^2): 1.7 ms of server CPU per submit at
 * 8,000 jobs). A store without the table (any earlier version) gets it
 * filled from its jobs on open (USAGE_FILL), in the same transaction. */
#define USAGE_ADD(who, live, size)                                                                \
    "INSERT INTO usage(owner, in_flight, bytes) VALUES(" who ", " live ", " size ") "               \
    "ON CONFLICT(owner) DO UPDATE SET in_flight = in_flight + excluded.in_flight, "                \
    "bytes = bytes + excluded.bytes;"
static const char USAGE_SCHEMA[] =
    "CREATE TABLE usage("
    "  owner TEXT PRIMARY KEY,"
    "  in_flight INTEGER NOT NULL,"
    "  bytes INTEGER NOT NULL);"
    "CREATE TRIGGER usage_insert AFTER INSERT ON jobs BEGIN "
    USAGE_ADD("NEW.owner", "NEW.state IN (0, 1, 2)", "NEW.bytes") " END;"
    "CREATE TRIGGER usage_update AFTER UPDATE OF state, bytes, owner ON jobs BEGIN "
    USAGE_ADD("OLD.owner", "-(OLD.state IN (0, 1, 2))", "-OLD.bytes")
    USAGE_ADD("NEW.owner", "NEW.state IN (0, 1, 2)", "NEW.bytes") " END;"
    "CREATE TRIGGER usage_delete AFTER DELETE ON jobs BEGIN "
    USAGE_ADD("OLD.owner", "-(OLD.state IN (0, 1, 2))", "-OLD.bytes") " END;";
static const char USAGE_FILL[] =
    "INSERT INTO usage(owner, in_flight, bytes) "
    "SELECT owner, SUM(state IN (0, 1, 2)), SUM(bytes) FROM jobs GROUP BY owner;";
/* Version 2 → 3: jobs get their deadline (0: none). */
static const char MIGRATE_2_3[] = "ALTER TABLE jobs ADD COLUMN deadline REAL NOT NULL DEFAULT 0;";

static const char *const STATE_NAMES[BGB_JOB_STATE_COUNT] = {
    "queued", "allocating", "running", "succeeded", "failed", "cancelled"};

/* A submit waiting for the writer; lives on its caller's stack. */
typedef struct pending {
    const bgb_submit_t *job;
    char id[BGB_JOB_ID_SIZE];
    int created;
    double time; /* when it was stored, if created */
    bg_status status;
    bg_error_t err;
    int done;
    pthread_cond_t wake; /* signalled (under queue_lock) once done is set */
    struct pending *next;
} pending_t;

/* An event appended later by the writer (bgb_store_add_event_later). */
typedef struct later {
    struct later *next;
    double time;
    char id[BGB_JOB_ID_SIZE];
    char *kind, *json;
} later_t;

/* Events waiting for the writer, at most; beyond, add_event_later refuses. */
#define STORE_MAX_LATER 65536

struct bgb_store {
    char *path;
    sqlite3 *writer; /* every write, under write_lock */
    sqlite3 *reader; /* every read, under read_lock */
    pthread_mutex_t write_lock, read_lock, queue_lock;
    pthread_cond_t queue_ready;
    pending_t *queue, *queue_tail;
    later_t *later, *later_tail; /* under queue_lock */
    int nlater;
    pthread_mutex_t notify_lock; /* guards event_epoch */
    pthread_cond_t notify;       /* broadcast when events were committed */
    int64_t event_epoch;
    int max_batch;   /* submits per transaction at most */
    int wake_at;     /* the writer waits for this many queued submits (0: it is not waiting) */
    int queued;      /* submits in queue */
    int last_batch;  /* submits in the last batch written */
    int stopping;
    int thread_started;
    pthread_t thread;
    int64_t commits, submits;
};

const char *bgb_job_state_name(bgb_job_state state)
{
    return (int)state >= 0 && state < BGB_JOB_STATE_COUNT ? STATE_NAMES[state] : "unknown";
}

int bgb_job_state_parse(const char *name)
{
    for (int s = 0; s < BGB_JOB_STATE_COUNT; s++)
        if (strcmp(name, STATE_NAMES[s]) == 0)
            return s;
    return -1;
}

int bgb_job_state_is_active(bgb_job_state state)
{
    return state == BGB_JOB_QUEUED || state == BGB_JOB_ALLOCATING || state == BGB_JOB_RUNNING;
}

void bgb_job_release(bgb_job_t *job)
{
    if (!job)
        return;
    free(job->mechanism);
    free(job->reason);
    free(job->scene);
    const bgb_job_t empty = BGB_JOB_INIT;
    *job = empty;
}

static double wall_clock(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static bg_status sql_fail(sqlite3 *db, bg_error_t *err, const char *what)
{
    return bg_error_set(err, BG_ERR_IO, "job store: %s: %s", what, sqlite3_errmsg(db));
}

static bg_status exec(sqlite3 *db, const char *sql, bg_error_t *err)
{
    char *message = NULL;
    if (sqlite3_exec(db, sql, NULL, NULL, &message) == SQLITE_OK)
        return BG_OK;
    bg_status st = bg_error_set(err, BG_ERR_IO, "job store: %s", message ? message : sql);
    sqlite3_free(message);
    return st;
}

static bg_status open_connection(const char *path, bgb_store_durability durability,
                                 sqlite3 **db, bg_error_t *err)
{
    if (sqlite3_open_v2(path, db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX,
                        NULL) != SQLITE_OK) {
        bg_status st = bg_error_set(err, BG_ERR_IO, "job store %s: cannot open: %s", path,
                                    *db ? sqlite3_errmsg(*db) : "out of memory");
        sqlite3_close(*db);
        *db = NULL;
        return st;
    }
    sqlite3_busy_timeout(*db, STORE_BUSY_TIMEOUT_MS);
    return exec(*db,
                durability == BGB_STORE_PROCESS_SAFE
                    ? "PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL; PRAGMA foreign_keys=ON;"
                    : "PRAGMA journal_mode=WAL; PRAGMA synchronous=FULL; PRAGMA foreign_keys=ON;",
                err);
}

bg_status bgb_store_check_file_name(const char *name, const char *field, bg_error_t *err)
{
    const size_t n = name ? strlen(name) : 0;
    if (n == 0 || n > BGB_STORE_MAX_FILE_NAME)
        return bg_error_set(err, BG_ERR_INVALID, "%s: a file name must have 1 to %d bytes", field,
                            BGB_STORE_MAX_FILE_NAME);
    if (strchr(name, '/') || strcmp(name, ".") == 0 || strcmp(name, "..") == 0)
        return bg_error_set(err, BG_ERR_INVALID,
                            "%s: '%s' is not a plain file name (no '/', '.' or '..')", field, name);
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)name[i] < 0x20)
            return bg_error_set(err, BG_ERR_INVALID, "%s: a file name holds a control byte",
                                field);
    return BG_OK;
}

static bg_status check_submit(const bgb_submit_t *job, bg_error_t *err)
{
    static const char *const mechanisms[] = {"central", "catallactic", "posted"};
    int known = 0;
    for (int i = 0; job->mechanism && i < 3; i++)
        known |= strcmp(job->mechanism, mechanisms[i]) == 0;
    if (!known)
        return bg_error_set(err, BG_ERR_INVALID,
                            "mechanism: '%s' is not one of central, catallactic, posted",
                            job->mechanism ? job->mechanism : "(none)");
    if (!(isfinite(job->budget) && job->budget > 0.0))
        return bg_error_set(err, BG_ERR_INVALID, "budget: must be a positive number, got %g",
                            job->budget);
    if (!(job->deadline >= 0.0 && isfinite(job->deadline)))
        return bg_error_set(err, BG_ERR_INVALID, "deadline: must be a number >= 0, got %g",
                            job->deadline);
    if (!job->scene || job->scene_size == 0)
        return bg_error_set(err, BG_ERR_INVALID, "scene: empty");
    if (job->owner && strlen(job->owner) > BGB_STORE_MAX_OWNER)
        return bg_error_set(err, BG_ERR_INVALID, "owner: longer than %d bytes",
                            BGB_STORE_MAX_OWNER);
    if (job->idempotency_key && strlen(job->idempotency_key) > BGB_STORE_MAX_KEY)
        return bg_error_set(err, BG_ERR_LIMIT, "Idempotency-Key: longer than %d bytes",
                            BGB_STORE_MAX_KEY);
    if (job->file_count < 0 || job->file_count > BGB_STORE_MAX_FILES)
        return bg_error_set(err, BG_ERR_LIMIT, "files: %d files, at most %d", job->file_count,
                            BGB_STORE_MAX_FILES);
    for (int i = 0; i < job->file_count; i++) {
        bg_status st = bgb_store_check_file_name(job->files[i].name, "files", err);
        if (st != BG_OK)
            return st;
        for (int j = 0; j < i; j++)
            if (strcmp(job->files[i].name, job->files[j].name) == 0)
                return bg_error_set(err, BG_ERR_INVALID, "files: '%s' is given twice",
                                    job->files[i].name);
    }
    return BG_OK;
}

static bg_status new_id(char id[BGB_JOB_ID_SIZE], bg_error_t *err)
{
    unsigned char bytes[8];
    if (getrandom(bytes, sizeof bytes, 0) != (ssize_t)sizeof bytes)
        return bg_error_set(err, BG_ERR_IO, "job store: no random bytes for a job id");
    static const char hex[] = "0123456789abcdef";
    id[0] = 'j';
    for (int i = 0; i < 8; i++) {
        id[1 + 2 * i] = hex[bytes[i] >> 4];
        id[2 + 2 * i] = hex[bytes[i] & 15];
    }
    id[BGB_JOB_ID_SIZE - 1] = '\0';
    return BG_OK;
}

/*
 * A statement for sql on db, prepared once per connection: the connection
 * keeps its statements (sqlite3_next_stmt lists them), so a statement that
 * is not in use is found by its text and reused. Compiling SQL cost more
 * than the rest of a submit's writes together (a quarter of all the
 * instructions of a REST submit). Every statement got here is handed back
 * with finish(), never finalized; the connection's statements are
 * finalized when it is closed (close_connection).
 */
static bg_status prepare(sqlite3 *db, const char *sql, sqlite3_stmt **stmt, bg_error_t *err)
{
    for (sqlite3_stmt *s = sqlite3_next_stmt(db, NULL); s; s = sqlite3_next_stmt(db, s))
        if (!sqlite3_stmt_busy(s) && strcmp(sqlite3_sql(s), sql) == 0) {
            *stmt = s;
            return BG_OK;
        }
    if (sqlite3_prepare_v3(db, sql, -1, SQLITE_PREPARE_PERSISTENT, stmt, NULL) != SQLITE_OK)
        return sql_fail(db, err, "prepare");
    return BG_OK;
}

/* Hands a statement from prepare() back: reset (ending its read, if any)
 * and unbound, ready for the next use. Accepts NULL. */
static void finish(sqlite3_stmt *s)
{
    if (!s)
        return;
    sqlite3_reset(s);
    sqlite3_clear_bindings(s);
}

/* Runs one statement without parameters or rows (BEGIN, COMMIT, ...). */
static bg_status run(sqlite3 *db, const char *sql, bg_error_t *err)
{
    sqlite3_stmt *s = NULL;
    bg_status st = prepare(db, sql, &s, err);
    if (st != BG_OK)
        return st;
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, sql);
    finish(s);
    return st;
}

static void close_connection(sqlite3 *db)
{
    if (!db)
        return;
    for (sqlite3_stmt *s; (s = sqlite3_next_stmt(db, NULL)) != NULL;)
        sqlite3_finalize(s);
    sqlite3_close(db);
}

static bg_status insert_event(sqlite3 *db, const char *id, double time, const char *kind,
                              const char *json, bg_error_t *err)
{
    sqlite3_stmt *s = NULL;
    bg_status st = prepare(db, "INSERT INTO events(job, time, kind, data) VALUES(?, ?, ?, ?)", &s,
                           err);
    if (st != BG_OK)
        return st;
    sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
    sqlite3_bind_double(s, 2, time);
    sqlite3_bind_text(s, 3, kind, -1, SQLITE_STATIC);
    sqlite3_bind_text(s, 4, json, -1, SQLITE_STATIC);
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, "insert event");
    finish(s);
    return st;
}

static bg_status insert_file(sqlite3 *db, const char *id, const char *kind, const bgb_file_t *f,
                             bg_error_t *err)
{
    sqlite3_stmt *s = NULL;
    bg_status st = prepare(
        db, "INSERT OR REPLACE INTO files(job, kind, name, data) VALUES(?, ?, ?, ?)", &s, err);
    if (st != BG_OK)
        return st;
    sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
    sqlite3_bind_text(s, 2, kind, -1, SQLITE_STATIC);
    sqlite3_bind_text(s, 3, f->name, -1, SQLITE_STATIC);
    sqlite3_bind_blob64(s, 4, f->size ? (const void *)f->data : (const void *)"", f->size,
                        SQLITE_STATIC);
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, "insert file");
    finish(s);
    return st;
}

/* Writes one submit inside the writer's open transaction. */
static bg_status write_submit(sqlite3 *db, pending_t *p)
{
    const bgb_submit_t *job = p->job;
    bg_error_t *err = &p->err;
    sqlite3_stmt *s = NULL;
    bg_status st = BG_OK;
    const char *owner = job->owner && job->owner[0] ? job->owner : STORE_DEFAULT_OWNER;
    /* A key names one job of its user forever: it is stored scoped by the
     * user ("owner\x1fkey"), so two users' keys never meet. */
    const int keyed = job->idempotency_key && job->idempotency_key[0];
    char key[2 * BGB_STORE_MAX_KEY + 2];
    if (keyed)
        snprintf(key, sizeof key, "%s\x1f%s", owner, job->idempotency_key);
    if (keyed) {
        if ((st = prepare(db, "SELECT id, fingerprint FROM jobs WHERE idempotency_key = ?", &s,
                          err)) != BG_OK)
            return st;
        sqlite3_bind_text(s, 1, key, -1, SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        if (rc == SQLITE_ROW) {
            snprintf(p->id, BGB_JOB_ID_SIZE, "%s", (const char *)sqlite3_column_text(s, 0));
            const char *earlier = (const char *)sqlite3_column_text(s, 1);
            p->created = 0;
            /* The same key with another body is a client's mistake, not a
             * replay: answering with the earlier job would hide it. */
            if (job->fingerprint && earlier && strcmp(earlier, job->fingerprint) != 0)
                st = bg_error_set(err, BG_ERR_CONFLICT,
                                  "Idempotency-Key '%s' was used for job %s with another body",
                                  job->idempotency_key, p->id);
        } else if (rc != SQLITE_DONE) {
            st = sql_fail(db, err, "look up the idempotency key");
        }
        finish(s);
        s = NULL;
        if (st != BG_OK || rc == SQLITE_ROW)
            return st;
    }
    if ((st = new_id(p->id, err)) != BG_OK)
        return st;
    int64_t bytes = 0;
    for (int i = 0; i < job->file_count; i++)
        bytes += (int64_t)job->files[i].size;
    const double now = wall_clock();
    if ((st = prepare(db,
                      "INSERT INTO jobs(id, state, mechanism, budget, created, updated, "
                      "idempotency_key, scene, owner, bytes, fingerprint, deadline) "
                      "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                      &s, err)) != BG_OK)
        return st;
    sqlite3_bind_text(s, 1, p->id, -1, SQLITE_STATIC);
    sqlite3_bind_int(s, 2, BGB_JOB_QUEUED);
    sqlite3_bind_text(s, 3, job->mechanism, -1, SQLITE_STATIC);
    sqlite3_bind_double(s, 4, job->budget);
    sqlite3_bind_double(s, 5, now);
    sqlite3_bind_double(s, 6, now);
    if (keyed)
        sqlite3_bind_text(s, 7, key, -1, SQLITE_STATIC);
    else
        sqlite3_bind_null(s, 7);
    sqlite3_bind_blob64(s, 8, job->scene, job->scene_size, SQLITE_STATIC);
    sqlite3_bind_text(s, 9, owner, -1, SQLITE_STATIC);
    sqlite3_bind_int64(s, 10, bytes);
    sqlite3_bind_double(s, 12, job->deadline > 0 ? job->deadline : 0.0);
    if (job->fingerprint)
        sqlite3_bind_text(s, 11, job->fingerprint, -1, SQLITE_STATIC);
    else
        sqlite3_bind_null(s, 11);
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, "insert job");
    finish(s);
    for (int i = 0; st == BG_OK && i < job->file_count; i++)
        st = insert_file(db, p->id, "input", &job->files[i], err);
    if (st == BG_OK)
        st = insert_event(db, p->id, now, "state", "{\"state\":\"queued\"}", err);
    if (st == BG_OK && job->plan)
        st = insert_event(db, p->id, now, "plan", job->plan, err);
    p->created = st == BG_OK;
    p->time = now;
    return st;
}

/* Events were committed: wakes bgb_store_wait_events. */
static void events_committed(bgb_store_t *store)
{
    pthread_mutex_lock(&store->notify_lock);
    store->event_epoch++;
    pthread_cond_broadcast(&store->notify);
    pthread_mutex_unlock(&store->notify_lock);
}

/* Writes a batch of submits in one transaction; each in its own savepoint so
 * that one failing submit does not take the others with it. */
static void write_batch(bgb_store_t *store, pending_t *batch)
{
    sqlite3 *db = store->writer;
    bg_error_t begin_err = BG_ERROR_INIT;
    pthread_mutex_lock(&store->write_lock);
    bg_status st = run(db, "BEGIN IMMEDIATE", &begin_err);
    int64_t written = 0;
    for (pending_t *p = batch; p; p = p->next) {
        if (st != BG_OK) {
            p->status = bg_error_set(&p->err, st, "%s", begin_err.message);
            continue;
        }
        bg_error_t sp = BG_ERROR_INIT;
        p->status = run(db, "SAVEPOINT submit", &sp);
        if (p->status == BG_OK)
            p->status = write_submit(db, p);
        else
            bg_error_set(&p->err, p->status, "%s", sp.message);
        if (p->status != BG_OK)
            run(db, "ROLLBACK TO submit", &sp);
        run(db, "RELEASE submit", &sp);
        written += p->status == BG_OK && p->created;
    }
    if (st == BG_OK) {
        bg_error_t commit_err = BG_ERROR_INIT;
        if (run(db, "COMMIT", &commit_err) != BG_OK) {
            run(db, "ROLLBACK", NULL);
            for (pending_t *p = batch; p; p = p->next)
                if (p->status == BG_OK) {
                    p->status = bg_error_set(&p->err, BG_ERR_IO, "%s", commit_err.message);
                    p->created = 0;
                }
            written = 0;
        }
    }
    store->commits += st == BG_OK;
    store->submits += written;
    pthread_mutex_unlock(&store->write_lock);
    if (written)
        events_committed(store);
}

static bg_status job_exists(sqlite3 *db, const char *id, bg_error_t *err);


/* Writes the events queued by bgb_store_add_event_later, oldest first, in
 * one transaction; called with write_lock held, so that a synchronous write
 * that comes after them in time also comes after them in the log. An event
 * of a job that does not exist (any more) is dropped, as add_event would
 * refuse it. */
static void flush_later(bgb_store_t *store)
{
    pthread_mutex_lock(&store->queue_lock);
    later_t *list = store->later;
    store->later = store->later_tail = NULL;
    store->nlater = 0;
    pthread_mutex_unlock(&store->queue_lock);
    if (!list)
        return;
    sqlite3 *db = store->writer;
    bg_error_t err = BG_ERROR_INIT;
    const int open = run(db, "BEGIN IMMEDIATE", &err) == BG_OK;
    for (later_t *l = list, *next; l; l = next) {
        next = l->next;
        bg_error_t e = BG_ERROR_INIT;
        if (open && job_exists(db, l->id, &e) == BG_OK)
            (void)insert_event(db, l->id, l->time, l->kind, l->json, &e);
        free(l->kind);
        free(l->json);
        free(l);
    }
    if (open && run(db, "COMMIT", &err) != BG_OK)
        run(db, "ROLLBACK", NULL);
    events_committed(store);
}

static void *writer_main(void *arg)
{
    bgb_store_t *store = arg;
    pthread_mutex_lock(&store->queue_lock);
    for (;;) {
        /* Submitters signal only when the queue reaches wake_at, so that
         * gathering a batch costs the writer one wake-up, not one per submit. */
        store->wake_at = 1;
        while (!store->queue && !store->later && !store->stopping)
            pthread_cond_wait(&store->queue_ready, &store->queue_lock);
        if (store->later) {
            pthread_mutex_unlock(&store->queue_lock);
            pthread_mutex_lock(&store->write_lock);
            flush_later(store);
            pthread_mutex_unlock(&store->write_lock);
            pthread_mutex_lock(&store->queue_lock);
            continue;
        }
        if (!store->queue && store->stopping)
            break;
        if (store->last_batch > 1 && !store->stopping) {
            struct timespec deadline;
            clock_gettime(CLOCK_REALTIME, &deadline);
            deadline.tv_nsec += STORE_GATHER_NS;
            if (deadline.tv_nsec >= 1000000000L) {
                deadline.tv_sec++;
                deadline.tv_nsec -= 1000000000L;
            }
            /* Aim past the last batch so that batches can grow to the
             * callers' concurrency; the deadline bounds the wait. */
            const int target = store->last_batch < store->max_batch / 2 ? 2 * store->last_batch
                                                                        : store->max_batch;
            store->wake_at = target;
            while (store->queued < target && !store->stopping &&
                   pthread_cond_timedwait(&store->queue_ready, &store->queue_lock, &deadline) ==
                       0)
                ;
        }
        store->wake_at = 0;
        /* Take up to max_batch submits off the queue, in order. */
        pending_t *batch = store->queue, *last = batch;
        int taken = 1;
        while (taken < store->max_batch && last->next) {
            last = last->next;
            taken++;
        }
        store->queue = last->next;
        if (!store->queue)
            store->queue_tail = NULL;
        last->next = NULL;
        store->queued -= taken;
        store->last_batch = taken;
        pthread_mutex_unlock(&store->queue_lock);
        write_batch(store, batch);
        pthread_mutex_lock(&store->queue_lock);
        /* Wake exactly the callers of this batch (a broadcast would also
         * wake every caller queued for the next one, only to wait again).
         * A caller may return as soon as done is set, so next is read first. */
        for (pending_t *p = batch, *next; p; p = next) {
            next = p->next;
            p->done = 1;
            pthread_cond_signal(&p->wake);
        }
    }
    pthread_mutex_unlock(&store->queue_lock);
    return NULL;
}

bg_status bgb_store_open(const char *path, bgb_store_t **out, bg_error_t *err)
{
    return bgb_store_open_with(path, NULL, out, err);
}

bg_status bgb_store_open_with(const char *path, const bgb_store_options_t *options,
                              bgb_store_t **out, bg_error_t *err)
{
    const bgb_store_options_t defaults = {BGB_STORE_POWER_SAFE, 0};
    if (!options)
        options = &defaults;
    *out = NULL;
    if (options->max_batch < 0 || (options->durability != BGB_STORE_POWER_SAFE &&
                                   options->durability != BGB_STORE_PROCESS_SAFE))
        return bg_error_set(err, BG_ERR_INVALID, "job store: bad options");
    bgb_store_t *store = calloc(1, sizeof *store);
    if (!store)
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for the job store");
    pthread_mutex_init(&store->write_lock, NULL);
    pthread_mutex_init(&store->read_lock, NULL);
    pthread_mutex_init(&store->queue_lock, NULL);
    pthread_cond_init(&store->queue_ready, NULL);
    pthread_mutex_init(&store->notify_lock, NULL);
    pthread_cond_init(&store->notify, NULL);
    bg_status st = BG_OK;
    store->path = strdup(path);
    if (!store->path) {
        st = bg_error_set(err, BG_ERR_NOMEM, "out of memory for the job store");
        goto out;
    }
    store->max_batch = options->max_batch ? options->max_batch : STORE_DEFAULT_MAX_BATCH;
    /* The store holds every user's scenes and results: its owner alone may
     * read it (SQLite gives its -wal and -shm files the same mode). */
    const int fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0 || fchmod(fd, 0600) != 0) {
        st = bg_error_set(err, BG_ERR_IO, "job store %s: cannot create: %s", path,
                          strerror(errno));
        if (fd >= 0)
            close(fd);
        goto out;
    }
    close(fd);
    if ((st = open_connection(path, options->durability, &store->writer, err)) != BG_OK)
        goto out;
    sqlite3_stmt *s = NULL;
    if ((st = prepare(store->writer, "PRAGMA user_version", &s, err)) != BG_OK)
        goto out;
    const int version = sqlite3_step(s) == SQLITE_ROW ? sqlite3_column_int(s, 0) : -1;
    finish(s);
    if (version != 0 && version != 1 && version != 2 && version != STORE_SCHEMA_VERSION) {
        st = bg_error_set(err, BG_ERR_UNSUPPORTED,
                          "job store %s: schema version %d, this broker reads version %d", path,
                          version, STORE_SCHEMA_VERSION);
        goto out;
    }
    char pragma[64];
    snprintf(pragma, sizeof pragma, "PRAGMA user_version=%d", STORE_SCHEMA_VERSION);
    if ((version == 1 || version == 2) &&
        ((st = exec(store->writer, "BEGIN IMMEDIATE", err)) != BG_OK ||
         (version == 1 && (st = exec(store->writer, MIGRATE_1_2, err)) != BG_OK) ||
         (st = exec(store->writer, MIGRATE_2_3, err)) != BG_OK ||
         (st = exec(store->writer, pragma, err)) != BG_OK ||
                         (st = exec(store->writer, "COMMIT", err)) != BG_OK)) {
        exec(store->writer, "ROLLBACK", NULL);
        goto out;
    }
    if ((st = exec(store->writer, SCHEMA, err)) != BG_OK ||
        (st = exec(store->writer, pragma, err)) != BG_OK)
        goto out;
    if ((st = prepare(store->writer,
                      "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'usage'", &s,
                      err)) != BG_OK)
        goto out;
    const int has_usage = sqlite3_step(s) == SQLITE_ROW;
    finish(s);
    if (!has_usage && ((st = exec(store->writer, "BEGIN IMMEDIATE", err)) != BG_OK ||
                       (st = exec(store->writer, USAGE_SCHEMA, err)) != BG_OK ||
                       (st = exec(store->writer, USAGE_FILL, err)) != BG_OK ||
                       (st = exec(store->writer, "COMMIT", err)) != BG_OK)) {
        exec(store->writer, "ROLLBACK", NULL);
        goto out;
    }
    if ((st = open_connection(path, options->durability, &store->reader, err)) != BG_OK)
        goto out;
    if (pthread_create(&store->thread, NULL, writer_main, store) != 0) {
        st = bg_error_set(err, BG_ERR_NOMEM, "job store: cannot start the writer thread");
        goto out;
    }
    store->thread_started = 1;
out:
    if (st != BG_OK)
        bgb_store_destroy(&store);
    *out = store;
    return st;
}

void bgb_store_destroy(bgb_store_t **storep)
{
    if (!storep || !*storep)
        return;
    bgb_store_t *store = *storep;
    if (store->thread_started) {
        pthread_mutex_lock(&store->queue_lock);
        store->stopping = 1;
        pthread_cond_signal(&store->queue_ready);
        pthread_mutex_unlock(&store->queue_lock);
        pthread_join(store->thread, NULL);
    }
    close_connection(store->reader);
    close_connection(store->writer);
    pthread_mutex_destroy(&store->write_lock);
    pthread_mutex_destroy(&store->read_lock);
    pthread_mutex_destroy(&store->queue_lock);
    pthread_cond_destroy(&store->queue_ready);
    pthread_mutex_destroy(&store->notify_lock);
    pthread_cond_destroy(&store->notify);
    free(store->path);
    free(store);
    *storep = NULL;
}

bg_status bgb_store_submit(bgb_store_t *store, const bgb_submit_t *job,
                           char id[BGB_JOB_ID_SIZE], int *created, bg_error_t *err)
{
    double stored_at = 0.0;
    return bgb_store_submit_at(store, job, id, created, &stored_at, err);
}

bg_status bgb_store_submit_at(bgb_store_t *store, const bgb_submit_t *job,
                              char id[BGB_JOB_ID_SIZE], int *created, double *stored_at,
                              bg_error_t *err)
{
    *created = 0;
    *stored_at = 0.0;
    id[0] = '\0';
    bg_status st = check_submit(job, err);
    if (st != BG_OK)
        return st;
    pending_t p = {.job = job, .status = BG_OK, .err = BG_ERROR_INIT};
    pthread_cond_init(&p.wake, NULL);
    pthread_mutex_lock(&store->queue_lock);
    if (store->queue_tail)
        store->queue_tail->next = &p;
    else
        store->queue = &p;
    store->queue_tail = &p;
    store->queued++;
    if (store->wake_at && store->queued >= store->wake_at)
        pthread_cond_signal(&store->queue_ready);
    while (!p.done)
        pthread_cond_wait(&p.wake, &store->queue_lock);
    pthread_mutex_unlock(&store->queue_lock);
    pthread_cond_destroy(&p.wake);
    if (p.status != BG_OK)
        return bg_error_set(err, p.status, "%s", p.err.message);
    memcpy(id, p.id, BGB_JOB_ID_SIZE);
    *created = p.created;
    *stored_at = p.created ? p.time : 0.0;
    return BG_OK;
}

static char *column_copy(sqlite3_stmt *s, int column, size_t *size)
{
    const int n = sqlite3_column_bytes(s, column);
    const void *data = sqlite3_column_blob(s, column);
    if (!data && sqlite3_column_type(s, column) == SQLITE_NULL)
        return NULL;
    char *copy = malloc((size_t)n + 1);
    if (!copy)
        return NULL;
    if (n > 0)
        memcpy(copy, data, (size_t)n);
    copy[n] = '\0';
    if (size)
        *size = (size_t)n;
    return copy;
}

#define JOB_COLUMNS                                                                                \
    "id, state, mechanism, budget, created, updated, reason, scene, seq, owner, deadline"

static bg_status read_job(sqlite3_stmt *s, bgb_job_t *job, bg_error_t *err)
{
    snprintf(job->id, BGB_JOB_ID_SIZE, "%s", (const char *)sqlite3_column_text(s, 0));
    job->state = (bgb_job_state)sqlite3_column_int(s, 1);
    job->mechanism = column_copy(s, 2, NULL);
    job->budget = sqlite3_column_double(s, 3);
    job->created = sqlite3_column_double(s, 4);
    job->updated = sqlite3_column_double(s, 5);
    job->reason = column_copy(s, 6, NULL);
    job->scene = column_copy(s, 7, &job->scene_size);
    job->sequence = sqlite3_column_int64(s, 8);
    snprintf(job->owner, sizeof job->owner, "%s", (const char *)sqlite3_column_text(s, 9));
    job->deadline = sqlite3_column_double(s, 10);
    if (!job->mechanism || !job->scene || (!job->reason && sqlite3_column_type(s, 6) != SQLITE_NULL)) {
        bgb_job_release(job);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory reading a job");
    }
    return BG_OK;
}

bg_status bgb_store_get(bgb_store_t *store, const char *id, bgb_job_t *out, bg_error_t *err)
{
    const bgb_job_t empty = BGB_JOB_INIT;
    *out = empty;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    bg_status st = prepare(store->reader, "SELECT " JOB_COLUMNS " FROM jobs WHERE id = ?", &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        if (rc == SQLITE_ROW)
            st = read_job(s, out, err);
        else if (rc == SQLITE_DONE)
            st = bg_error_set(err, BG_ERR_NOT_FOUND, "no job '%s'", id);
        else
            st = sql_fail(store->reader, err, "read job");
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

bg_status bgb_store_list(bgb_store_t *store, int state, int64_t after, int limit, bgb_job_t *jobs,
                         int *count, int64_t *next, bg_error_t *err)
{
    return bgb_store_list_owner(store, NULL, state, after, limit, jobs, count, next, err);
}

bg_status bgb_store_list_owner(bgb_store_t *store, const char *owner, int state, int64_t after,
                               int limit, bgb_job_t *jobs, int *count, int64_t *next,
                               bg_error_t *err)
{
    *count = 0;
    *next = 0;
    if (limit < 1)
        return bg_error_set(err, BG_ERR_INVALID, "limit: must be at least 1");
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    /* One row more than asked tells whether there is a next page. */
    bg_status st = prepare(store->reader,
                           owner ? (state >= 0 ? "SELECT " JOB_COLUMNS " FROM jobs WHERE seq > ? "
                                                 "AND state = ? AND owner = ? ORDER BY seq LIMIT ?"
                                               : "SELECT " JOB_COLUMNS " FROM jobs WHERE seq > ? "
                                                 "AND ? < 0 AND owner = ? ORDER BY seq LIMIT ?")
                                 : (state >= 0 ? "SELECT " JOB_COLUMNS " FROM jobs WHERE seq > ? "
                                                 "AND state = ? AND ? IS NULL ORDER BY seq LIMIT ?"
                                               : "SELECT " JOB_COLUMNS " FROM jobs WHERE seq > ? "
                                                 "AND ? < 0 AND ? IS NULL ORDER BY seq LIMIT ?"),
                           &s, err);
    if (st == BG_OK) {
        sqlite3_bind_int64(s, 1, after);
        sqlite3_bind_int(s, 2, state);
        if (owner)
            sqlite3_bind_text(s, 3, owner, -1, SQLITE_STATIC);
        else
            sqlite3_bind_null(s, 3);
        sqlite3_bind_int(s, 4, limit + 1);
        int rc;
        while (st == BG_OK && (rc = sqlite3_step(s)) == SQLITE_ROW) {
            if (*count == limit) {
                *next = jobs[limit - 1].sequence;
                break;
            }
            st = read_job(s, &jobs[*count], err);
            if (st == BG_OK)
                (*count)++;
        }
        if (st == BG_OK && rc != SQLITE_ROW && rc != SQLITE_DONE)
            st = sql_fail(store->reader, err, "list jobs");
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    if (st != BG_OK) {
        for (int i = 0; i < *count; i++)
            bgb_job_release(&jobs[i]);
        *count = 0;
        *next = 0;
    }
    return st;
}

/* Ends a write transaction begun under write_lock: COMMIT when st is
 * BG_OK, ROLLBACK when it is not or the COMMIT fails (harmless where no
 * transaction is open), then releases write_lock. Returns the first
 * failure. */
static bg_status end_write(bgb_store_t *store, bg_status st, bg_error_t *err)
{
    if (st == BG_OK)
        st = run(store->writer, "COMMIT", err);
    if (st != BG_OK)
        run(store->writer, "ROLLBACK", NULL);
    pthread_mutex_unlock(&store->write_lock);
    return st;
}

/*
 * Under write_lock: writes what waits to be written later, opens a write
 * transaction and reads job id's state into *state. On failure (no such
 * job: BG_ERR_NOT_FOUND) the transaction is already rolled back.
 */
static bg_status begin_on_job(bgb_store_t *store, const char *id, int *state, bg_error_t *err)
{
    sqlite3 *db = store->writer;
    sqlite3_stmt *s = NULL;
    flush_later(store);
    bg_status st = run(db, "BEGIN IMMEDIATE", err);
    if (st != BG_OK)
        return st;
    if ((st = prepare(db, "SELECT state FROM jobs WHERE id = ?", &s, err)) == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        *state = rc == SQLITE_ROW ? sqlite3_column_int(s, 0) : -1;
        if (rc == SQLITE_DONE)
            st = bg_error_set(err, BG_ERR_NOT_FOUND, "no job '%s'", id);
        else if (rc != SQLITE_ROW)
            st = sql_fail(db, err, "read job state");
        finish(s);
    }
    if (st != BG_OK)
        run(db, "ROLLBACK", NULL);
    return st;
}

bg_status bgb_store_transition(bgb_store_t *store, const char *id, unsigned from_mask,
                               bgb_job_state to, const char *reason, bg_error_t *err)
{
    if ((int)to < 0 || to >= BGB_JOB_STATE_COUNT)
        return bg_error_set(err, BG_ERR_INVALID, "unknown job state %d", (int)to);
    sqlite3 *db = store->writer;
    sqlite3_stmt *s = NULL;
    int current = -1;
    pthread_mutex_lock(&store->write_lock);
    bg_status st = begin_on_job(store, id, &current, err);
    if (st != BG_OK)
        goto out;
    if (!(from_mask & (1u << current))) {
        st = bg_error_set(err, BG_ERR_CONFLICT, "job %s is %s; it cannot become %s", id,
                          bgb_job_state_name((bgb_job_state)current), bgb_job_state_name(to));
        goto out;
    }
    const double now = wall_clock();
    if ((st = prepare(db, "UPDATE jobs SET state = ?, updated = ?, reason = ? WHERE id = ?", &s,
                      err)) != BG_OK)
        goto out;
    sqlite3_bind_int(s, 1, to);
    sqlite3_bind_double(s, 2, now);
    if (reason)
        sqlite3_bind_text(s, 3, reason, -1, SQLITE_STATIC);
    else
        sqlite3_bind_null(s, 3);
    sqlite3_bind_text(s, 4, id, -1, SQLITE_STATIC);
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, "update job state");
    finish(s);
    if (st == BG_OK) {
        char json[128];
        snprintf(json, sizeof json, "{\"state\":\"%s\"}", bgb_job_state_name(to));
        st = insert_event(db, id, now, "state", json, err);
    }
out:
    if ((st = end_write(store, st, err)) == BG_OK)
        events_committed(store);
    return st;
}

/* BG_OK if the job exists on this connection, else BG_ERR_NOT_FOUND. */
static bg_status job_exists(sqlite3 *db, const char *id, bg_error_t *err)
{
    sqlite3_stmt *s = NULL;
    bg_status st = prepare(db, "SELECT 1 FROM jobs WHERE id = ?", &s, err);
    if (st != BG_OK)
        return st;
    sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
    const int rc = sqlite3_step(s);
    finish(s);
    if (rc == SQLITE_ROW)
        return BG_OK;
    if (rc == SQLITE_DONE)
        return bg_error_set(err, BG_ERR_NOT_FOUND, "no job '%s'", id);
    return sql_fail(db, err, "look up job");
}

bg_status bgb_store_add_event(bgb_store_t *store, const char *id, const char *kind,
                              const char *json, bg_error_t *err)
{
    pthread_mutex_lock(&store->write_lock);
    flush_later(store);
    bg_status st = job_exists(store->writer, id, err);
    if (st == BG_OK)
        st = insert_event(store->writer, id, wall_clock(), kind, json, err);
    pthread_mutex_unlock(&store->write_lock);
    if (st == BG_OK)
        events_committed(store);
    return st;
}

int64_t bgb_store_wait_events(bgb_store_t *store, int64_t seen, double timeout)
{
    pthread_mutex_lock(&store->notify_lock);
    if (store->event_epoch == seen && timeout > 0) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        const double end = (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec + timeout;
        ts.tv_sec = (time_t)end;
        ts.tv_nsec = (long)((end - (double)ts.tv_sec) * 1e9);
        while (store->event_epoch == seen &&
               pthread_cond_timedwait(&store->notify, &store->notify_lock, &ts) == 0)
            ;
    }
    const int64_t epoch = store->event_epoch;
    pthread_mutex_unlock(&store->notify_lock);
    return epoch;
}

bg_status bgb_store_add_event_later(bgb_store_t *store, const char *id, const char *kind,
                                    const char *json, bg_error_t *err)
{
    later_t *l = calloc(1, sizeof *l);
    if (l) {
        l->kind = strdup(kind);
        l->json = strdup(json);
    }
    if (!l || !l->kind || !l->json) {
        if (l) {
            free(l->kind);
            free(l->json);
        }
        free(l);
        return bg_error_set(err, BG_ERR_NOMEM, "out of memory for an event");
    }
    snprintf(l->id, sizeof l->id, "%s", id);
    l->time = wall_clock();
    pthread_mutex_lock(&store->queue_lock);
    const int full = store->nlater >= STORE_MAX_LATER;
    if (!full) {
        if (store->later_tail)
            store->later_tail->next = l;
        else
            store->later = l;
        store->later_tail = l;
        store->nlater++;
        pthread_cond_signal(&store->queue_ready);
    }
    pthread_mutex_unlock(&store->queue_lock);
    if (full) {
        free(l->kind);
        free(l->json);
        free(l);
        return bg_error_set(err, BG_ERR_LIMIT, "%d events already wait for the writer",
                            STORE_MAX_LATER);
    }
    return BG_OK;
}

bg_status bgb_store_events(bgb_store_t *store, const char *id, int64_t after, bgb_event_fn fn,
                           void *ctx, bg_error_t *err)
{
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    bg_status st = job_exists(store->reader, id, err);
    if (st == BG_OK)
        st = prepare(store->reader,
                     "SELECT seq, time, kind, data FROM events WHERE job = ? AND seq > ? "
                     "ORDER BY seq",
                     &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        sqlite3_bind_int64(s, 2, after);
        int rc;
        while ((rc = sqlite3_step(s)) == SQLITE_ROW)
            fn(ctx, sqlite3_column_int64(s, 0), sqlite3_column_double(s, 1),
               (const char *)sqlite3_column_text(s, 2), (const char *)sqlite3_column_text(s, 3));
        if (rc != SQLITE_DONE)
            st = sql_fail(store->reader, err, "read events");
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

static bg_status check_kind(const char *kind, bg_error_t *err)
{
    if (kind && (strcmp(kind, "input") == 0 || strcmp(kind, "result") == 0))
        return BG_OK;
    return bg_error_set(err, BG_ERR_INVALID, "file kind must be input or result");
}

bg_status bgb_store_put_file(bgb_store_t *store, const char *id, const char *kind,
                             const bgb_file_t *file, bg_error_t *err)
{
    bg_status st = check_kind(kind, err);
    if (st == BG_OK)
        st = bgb_store_check_file_name(file->name, "files", err);
    if (st != BG_OK)
        return st;
    sqlite3 *db = store->writer;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->write_lock);
    flush_later(store);
    if ((st = run(db, "BEGIN IMMEDIATE", err)) != BG_OK)
        goto out;
    if ((st = job_exists(db, id, err)) != BG_OK)
        goto out;
    /* The job's bytes (its user's quota) count the file once, replaced or new. */
    int64_t old = 0;
    if ((st = prepare(db, "SELECT length(data) FROM files WHERE job = ? AND kind = ? AND name = ?",
                      &s, err)) != BG_OK)
        goto out;
    sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
    sqlite3_bind_text(s, 2, kind, -1, SQLITE_STATIC);
    sqlite3_bind_text(s, 3, file->name, -1, SQLITE_STATIC);
    if (sqlite3_step(s) == SQLITE_ROW)
        old = sqlite3_column_int64(s, 0);
    finish(s);
    s = NULL;
    if ((st = insert_file(db, id, kind, file, err)) != BG_OK ||
        (st = prepare(db, "UPDATE jobs SET bytes = bytes + ? WHERE id = ?", &s, err)) != BG_OK)
        goto out;
    sqlite3_bind_int64(s, 1, (int64_t)file->size - old);
    sqlite3_bind_text(s, 2, id, -1, SQLITE_STATIC);
    if (sqlite3_step(s) != SQLITE_DONE)
        st = sql_fail(db, err, "count the job's bytes");
    finish(s);
out:
    return end_write(store, st, err);
}

bg_status bgb_store_usage(bgb_store_t *store, const char *owner, int *in_flight, int64_t *bytes,
                          bg_error_t *err)
{
    *in_flight = 0;
    *bytes = 0;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    bg_status st = prepare(store->reader,
                           "SELECT in_flight, bytes FROM usage WHERE owner = ?",
                           &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, owner && owner[0] ? owner : STORE_DEFAULT_OWNER, -1,
                          SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        if (rc == SQLITE_ROW) {
            *in_flight = sqlite3_column_int(s, 0);
            *bytes = sqlite3_column_int64(s, 1);
        } else if (rc != SQLITE_DONE) { /* done: a user without jobs */
            st = sql_fail(store->reader, err, "count a user's jobs");
        }
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

bg_status bgb_store_delete(bgb_store_t *store, const char *id, bg_error_t *err)
{
    sqlite3 *db = store->writer;
    sqlite3_stmt *s = NULL;
    int state = -1;
    pthread_mutex_lock(&store->write_lock);
    bg_status st = begin_on_job(store, id, &state, err);
    if (st != BG_OK)
        goto out;
    if (bgb_job_state_is_active((bgb_job_state)state)) {
        st = bg_error_set(err, BG_ERR_CONFLICT, "job %s is %s; cancel it before deleting it", id,
                          bgb_job_state_name((bgb_job_state)state));
        goto out;
    }
    static const char *const deletes[] = {"DELETE FROM files WHERE job = ?",
                                          "DELETE FROM events WHERE job = ?",
                                          "DELETE FROM jobs WHERE id = ?"};
    for (int i = 0; i < 3 && st == BG_OK; i++) {
        if ((st = prepare(db, deletes[i], &s, err)) != BG_OK)
            break;
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        if (sqlite3_step(s) != SQLITE_DONE)
            st = sql_fail(db, err, "delete a job");
        finish(s);
        s = NULL;
    }
out:
    return end_write(store, st, err);
}

bg_status bgb_store_get_file(bgb_store_t *store, const char *id, const char *kind,
                             const char *name, uint8_t **data, size_t *size, bg_error_t *err)
{
    *data = NULL;
    *size = 0;
    bg_status st = check_kind(kind, err);
    if (st != BG_OK)
        return st;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    st = prepare(store->reader, "SELECT data FROM files WHERE job = ? AND kind = ? AND name = ?",
                 &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        sqlite3_bind_text(s, 2, kind, -1, SQLITE_STATIC);
        sqlite3_bind_text(s, 3, name, -1, SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        if (rc == SQLITE_ROW) {
            *data = (uint8_t *)column_copy(s, 0, size);
            if (!*data)
                st = bg_error_set(err, BG_ERR_NOMEM, "out of memory reading %s", name);
        } else if (rc == SQLITE_DONE) {
            st = bg_error_set(err, BG_ERR_NOT_FOUND, "job %s has no %s file '%s'", id, kind,
                              name);
        } else {
            st = sql_fail(store->reader, err, "read file");
        }
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

bg_status bgb_store_list_files(bgb_store_t *store, const char *id, const char *kind,
                               bgb_file_fn fn, void *ctx, bg_error_t *err)
{
    bg_status st = check_kind(kind, err);
    if (st != BG_OK)
        return st;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    st = job_exists(store->reader, id, err);
    if (st == BG_OK)
        st = prepare(store->reader,
                     "SELECT name, length(data) FROM files WHERE job = ? AND kind = ? ORDER BY "
                     "name",
                     &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        sqlite3_bind_text(s, 2, kind, -1, SQLITE_STATIC);
        int rc;
        while ((rc = sqlite3_step(s)) == SQLITE_ROW)
            fn(ctx, (const char *)sqlite3_column_text(s, 0), (size_t)sqlite3_column_int64(s, 1));
        if (rc != SQLITE_DONE)
            st = sql_fail(store->reader, err, "list files");
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

bg_status bgb_store_count(bgb_store_t *store, int64_t counts[BGB_JOB_STATE_COUNT],
                          bg_error_t *err)
{
    for (int i = 0; i < BGB_JOB_STATE_COUNT; i++)
        counts[i] = 0;
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    bg_status st =
        prepare(store->reader, "SELECT state, count(*) FROM jobs GROUP BY state", &s, err);
    if (st == BG_OK) {
        int rc;
        while ((rc = sqlite3_step(s)) == SQLITE_ROW) {
            const int state = sqlite3_column_int(s, 0);
            if (state >= 0 && state < BGB_JOB_STATE_COUNT)
                counts[state] = sqlite3_column_int64(s, 1);
        }
        if (rc != SQLITE_DONE)
            st = sql_fail(store->reader, err, "count jobs");
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}

void bgb_store_commit_stats(bgb_store_t *store, int64_t *commits, int64_t *submits)
{
    pthread_mutex_lock(&store->write_lock);
    *commits = store->commits;
    *submits = store->submits;
    pthread_mutex_unlock(&store->write_lock);
}

bg_status bgb_store_put_token(bgb_store_t *store, const bgb_token_row_t *row, bg_error_t *err)
{
    if (!row->id || !row->user || !row->salt || !row->hash ||
        strlen(row->user) > BGB_STORE_MAX_OWNER)
        return bg_error_set(err, BG_ERR_INVALID, "token: incomplete or too long a row");
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->write_lock);
    flush_later(store);
    bg_status st = prepare(store->writer,
                           "INSERT INTO tokens(id, user, admin, salt, hash, created) "
                           "VALUES(?, ?, ?, ?, ?, ?)",
                           &s, err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, row->id, -1, SQLITE_STATIC);
        sqlite3_bind_text(s, 2, row->user, -1, SQLITE_STATIC);
        sqlite3_bind_int(s, 3, row->admin != 0);
        sqlite3_bind_text(s, 4, row->salt, -1, SQLITE_STATIC);
        sqlite3_bind_text(s, 5, row->hash, -1, SQLITE_STATIC);
        sqlite3_bind_double(s, 6, wall_clock());
        if (sqlite3_step(s) != SQLITE_DONE)
            st = sql_fail(store->writer, err, "store a token");
    }
    finish(s);
    pthread_mutex_unlock(&store->write_lock);
    return st;
}

bg_status bgb_store_get_token(bgb_store_t *store, const char *id, bgb_token_record_t *out,
                              bg_error_t *err)
{
    memset(out, 0, sizeof *out);
    sqlite3_stmt *s = NULL;
    pthread_mutex_lock(&store->read_lock);
    bg_status st = prepare(store->reader,
                           "SELECT user, admin, salt, hash, revoked FROM tokens WHERE id = ?", &s,
                           err);
    if (st == BG_OK) {
        sqlite3_bind_text(s, 1, id, -1, SQLITE_STATIC);
        const int rc = sqlite3_step(s);
        if (rc == SQLITE_ROW) {
            snprintf(out->user, sizeof out->user, "%s", (const char *)sqlite3_column_text(s, 0));
            out->admin = sqlite3_column_int(s, 1);
            snprintf(out->salt, sizeof out->salt, "%s", (const char *)sqlite3_column_text(s, 2));
            snprintf(out->hash, sizeof out->hash, "%s", (const char *)sqlite3_column_text(s, 3));
            out->revoked = sqlite3_column_int(s, 4);
        } else if (rc == SQLITE_DONE) {
            st = bg_error_set(err, BG_ERR_NOT_FOUND, "no token '%s'", id);
        } else {
            st = sql_fail(store->reader, err, "read a token");
        }
    }
    finish(s);
    pthread_mutex_unlock(&store->read_lock);
    return st;
}
