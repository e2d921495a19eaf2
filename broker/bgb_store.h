/*
 * bgb_store — the broker's durable job store: one SQLite file in WAL mode,
 * the source of truth for jobs, the files uploaded with them and written
 * for them, their events and their market contracts.
 *
 * Durability: bgb_store_submit returns only after the transaction holding
 * the job is committed. By default (BGB_STORE_POWER_SAFE) the commit is
 * fsynced (WAL, synchronous=FULL): an acknowledged job survives a crash of
 * the broker process and a power loss or kernel crash, as far as the disk
 * honours its flushes. BGB_STORE_PROCESS_SAFE (synchronous=NORMAL) writes
 * the commit to the WAL file without an fsync: it survives a crash of the
 * process (the kernel holds the write), not a power loss, which may take
 * the last commits back (the database stays consistent either way).
 * Submits from many threads are group-committed: a single writer thread
 * takes the submits that are waiting, writes them in one transaction and
 * wakes their callers, so one fsync serves a whole batch (what bounds
 * throughput is the fsync rate times the batch size, not one fsync per job).
 *
 * Thread safety: every function may be called from any thread; reads use
 * their own connection, serialised by a mutex (SQLite's WAL lets them run
 * beside the writer).
 */
#ifndef BGB_STORE_H
#define BGB_STORE_H

#include <stddef.h>
#include <stdint.h>

#include "bg_error.h"

typedef struct bgb_store bgb_store_t;

/* Job ids are "j" followed by 16 lowercase hex digits. */
#define BGB_JOB_ID_SIZE 18
/* Caps the store enforces whatever its caller checked. */
#define BGB_STORE_MAX_FILES 64
#define BGB_STORE_MAX_FILE_NAME 255
#define BGB_STORE_MAX_KEY 255
#define BGB_STORE_MAX_OWNER 64

typedef enum bgb_job_state {
    BGB_JOB_QUEUED = 0,     /* accepted and stored, not yet allocated */
    BGB_JOB_ALLOCATING = 1, /* its coordinator is buying the plan's services */
    BGB_JOB_RUNNING = 2,    /* the bought agents compute it */
    BGB_JOB_SUCCEEDED = 3,
    BGB_JOB_FAILED = 4,
    BGB_JOB_CANCELLED = 5,
} bgb_job_state;
#define BGB_JOB_STATE_COUNT 6

/* "queued", "allocating", ...; bgb_job_state_parse returns -1 for an unknown name. */
const char *bgb_job_state_name(bgb_job_state state);
int bgb_job_state_parse(const char *name);
/* Whether a job in this state can still change (not succeeded, failed or cancelled). */
int bgb_job_state_is_active(bgb_job_state state);

typedef struct bgb_file {
    const char *name;    /* a plain relative name inside the job's folder */
    const uint8_t *data; /* borrowed */
    size_t size;
} bgb_file_t;

typedef struct bgb_submit {
    const char *owner;           /* the submitting user; NULL or "": "local" */
    const char *idempotency_key; /* NULL or "": none; scoped to the owner */
    const char *fingerprint;     /* what the submission is (bgb_submission): a key reused with
                                    another fingerprint is refused; NULL: not compared */
    const char *scene;           /* the scene JSON, borrowed */
    size_t scene_size;
    const char *mechanism;       /* "central", "catallactic" or "posted" */
    double budget;               /* money the job may spend, > 0 */
    double deadline;             /* seconds after submission by which it must have its
                                    services; 0: none */
    const bgb_file_t *files;     /* the mesh and data files uploaded with the scene */
    int file_count;
    const char *plan;            /* the plan as JSON, stored as the job's "plan" event in the
                                    same transaction; NULL: none */
} bgb_submit_t;

/*
 * A file name a job may upload or be given: a plain name inside the job's
 * folder (1..BGB_STORE_MAX_FILE_NAME bytes, no '/', not "." or "..", no
 * control bytes). BG_ERR_INVALID with "<field>: ..." otherwise. The store
 * checks every name with it; the REST API checks before unpacking.
 */
bg_status bgb_store_check_file_name(const char *name, const char *field, bg_error_t *err);

/* A job as stored; strings owned by the record (bgb_job_release). */
typedef struct bgb_job {
    char id[BGB_JOB_ID_SIZE];
    char owner[BGB_STORE_MAX_OWNER + 1]; /* the user who submitted it */
    bgb_job_state state;
    char *mechanism;
    double budget;
    double created;   /* seconds since the epoch */
    double updated;
    char *reason;     /* why it failed or was cancelled, or NULL */
    char *scene;      /* the submitted scene JSON (NUL-terminated) */
    size_t scene_size;
    int64_t sequence; /* submission order, the pagination cursor */
    double deadline;  /* seconds after created by which it must have its services; 0: none */
} bgb_job_t;

#define BGB_JOB_INIT {{0}, {0}, BGB_JOB_QUEUED, NULL, 0.0, 0.0, 0.0, NULL, NULL, 0, 0, 0.0}

void bgb_job_release(bgb_job_t *job);

typedef enum bgb_store_durability {
    BGB_STORE_POWER_SAFE = 0,   /* fsync per commit (synchronous=FULL), the default */
    BGB_STORE_PROCESS_SAFE = 1, /* no fsync per commit (synchronous=NORMAL) */
} bgb_store_durability;

typedef struct bgb_store_options {
    bgb_store_durability durability;
    int max_batch; /* submits per transaction at most; 0: 256; 1: one commit per submit */
} bgb_store_options_t;

/*
 * Opens (creating if needed) the store at path and starts its writer
 * thread, with the default options. Caller owns *out (bgb_store_destroy).
 */
bg_status bgb_store_open(const char *path, bgb_store_t **out, bg_error_t *err);

/* bgb_store_open with options (NULL: the defaults). */
bg_status bgb_store_open_with(const char *path, const bgb_store_options_t *options,
                              bgb_store_t **out, bg_error_t *err);

/* Stops the writer (after committing what is queued) and closes; accepts NULL. */
void bgb_store_destroy(bgb_store_t **store);

/*
 * Stores a new job in state queued, durably, and writes its id to id. With
 * an idempotency key its owner already used, stores nothing and returns the
 * earlier job's id with *created = 0 (a key names one job forever), or
 * BG_ERR_CONFLICT when the earlier job's fingerprint differs (the key was
 * reused with another body). BG_ERR_INVALID for a bad field (naming it),
 * BG_ERR_LIMIT over the caps above.
 */
bg_status bgb_store_submit(bgb_store_t *store, const bgb_submit_t *job,
                           char id[BGB_JOB_ID_SIZE], int *created, bg_error_t *err);

/*
 * bgb_store_submit that also tells when a new job was stored (its created
 * and updated time, seconds since the epoch) in *stored_at, so that the
 * caller can describe the new job without reading it back; *stored_at is
 * 0 when *created is 0 (read the earlier job with bgb_store_get).
 */
bg_status bgb_store_submit_at(bgb_store_t *store, const bgb_submit_t *job,
                              char id[BGB_JOB_ID_SIZE], int *created, double *stored_at,
                              bg_error_t *err);

/* The job with this id; BG_ERR_NOT_FOUND if there is none. */
bg_status bgb_store_get(bgb_store_t *store, const char *id, bgb_job_t *out, bg_error_t *err);

/*
 * Up to `limit` jobs in submission order after the cursor (0: from the
 * first), only in `state` when state >= 0. Writes them to jobs[] (caller
 * releases each) and their count to *count; *next is the cursor of the
 * next page, 0 when there is none.
 */
bg_status bgb_store_list(bgb_store_t *store, int state, int64_t after, int limit, bgb_job_t *jobs,
                         int *count, int64_t *next, bg_error_t *err);

/* bgb_store_list of one user's jobs only (owner NULL: every user's). */
bg_status bgb_store_list_owner(bgb_store_t *store, const char *owner, int state, int64_t after,
                               int limit, bgb_job_t *jobs, int *count, int64_t *next,
                               bg_error_t *err);

/*
 * Moves a job to state `to` if it is in one of the states of `from_mask`
 * (bit s = state s), recording reason (may be NULL) and an event. The job
 * in another state: BG_ERR_CONFLICT naming its state; no job:
 * BG_ERR_NOT_FOUND. Committed on return.
 */
bg_status bgb_store_transition(bgb_store_t *store, const char *id, unsigned from_mask,
                               bgb_job_state to, const char *reason, bg_error_t *err);

/* Appends an event (kind, JSON data) to the job's log; committed on return. */
bg_status bgb_store_add_event(bgb_store_t *store, const char *id, const char *kind,
                              const char *json, bg_error_t *err);

/*
 * Appends an event without waiting for its commit: the store's writer
 * thread writes it soon after, and before any later bgb_store_transition or
 * bgb_store_add_event (from any thread), so the log keeps the order in
 * which they were called. For a thread that must not wait for a disk (the
 * broker's market loop). BG_ERR_LIMIT when too many already wait (the
 * caller may then write it with bgb_store_add_event); an event of a job
 * that does not exist is dropped when written.
 */
bg_status bgb_store_add_event_later(bgb_store_t *store, const char *id, const char *kind,
                                    const char *json, bg_error_t *err);

/*
 * Waits until events were committed since the caller saw epoch `seen`, or
 * `timeout` seconds passed; returns the current epoch (start with the
 * value of a call with timeout 0). What a server that pushes events to its
 * clients sleeps on instead of polling the store.
 */
int64_t bgb_store_wait_events(bgb_store_t *store, int64_t seen, double timeout);

/* Calls fn for each event of the job with sequence > after, in order. */
typedef void (*bgb_event_fn)(void *ctx, int64_t sequence, double time, const char *kind,
                             const char *json);
bg_status bgb_store_events(bgb_store_t *store, const char *id, int64_t after, bgb_event_fn fn,
                           void *ctx, bg_error_t *err);

/*
 * A file of the job: kind "input" (uploaded with it) or "result" (written
 * for it). put replaces a file of the same kind and name; get returns a
 * malloc'ed copy (caller frees) or BG_ERR_NOT_FOUND.
 */
bg_status bgb_store_put_file(bgb_store_t *store, const char *id, const char *kind,
                             const bgb_file_t *file, bg_error_t *err);
bg_status bgb_store_get_file(bgb_store_t *store, const char *id, const char *kind,
                             const char *name, uint8_t **data, size_t *size, bg_error_t *err);

/* Calls fn with each file name of the job's kind ("input" or "result"), by name. */
typedef void (*bgb_file_fn)(void *ctx, const char *name, size_t size);
bg_status bgb_store_list_files(bgb_store_t *store, const char *id, const char *kind,
                               bgb_file_fn fn, void *ctx, bg_error_t *err);

/*
 * A user's share of the store: their jobs still in flight (queued,
 * allocating or running) and the bytes of all their jobs' files (inputs
 * and results), for the per-user quotas. owner NULL or "": "local".
 */
bg_status bgb_store_usage(bgb_store_t *store, const char *owner, int *in_flight, int64_t *bytes,
                          bg_error_t *err);

/* Deletes an ended job with its files and events (freeing its user's
 * quota); BG_ERR_CONFLICT while it is active, BG_ERR_NOT_FOUND. */
bg_status bgb_store_delete(bgb_store_t *store, const char *id, bg_error_t *err);

/* A REST token's row as bgb_tokens makes it: hex id, its user and scope,
 * hex salt and SHA-256 (borrowed strings). */
typedef struct bgb_token_row {
    const char *id, *user;
    int admin;
    const char *salt, *hash;
} bgb_token_row_t;

/* A token's row as read back. */
typedef struct bgb_token_record {
    char user[BGB_STORE_MAX_OWNER + 1];
    int admin, revoked;
    char salt[33], hash[65];
} bgb_token_record_t;

/* Stores a token's row (committed on return); BG_ERR_IO (a clashing id among
 * them). Any thread, any process sharing the file: a broker picks it up at
 * once. */
bg_status bgb_store_put_token(bgb_store_t *store, const bgb_token_row_t *row, bg_error_t *err);

/* The token row with this id; BG_ERR_NOT_FOUND if there is none. */
bg_status bgb_store_get_token(bgb_store_t *store, const char *id, bgb_token_record_t *out,
                              bg_error_t *err);

/* Jobs per state (counts[BGB_JOB_STATE_COUNT]), for /metrics. */
bg_status bgb_store_count(bgb_store_t *store, int64_t counts[BGB_JOB_STATE_COUNT],
                          bg_error_t *err);

/* Commits and batches so far: submits per commit measures group commit. */
void bgb_store_commit_stats(bgb_store_t *store, int64_t *commits, int64_t *submits);

#endif
