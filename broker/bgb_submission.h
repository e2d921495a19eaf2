/*
 * bgb_submission — the body of POST /v1/jobs, parsed: a pure function over
 * (const char *, size_t), so that tests and the fuzzer drive it without a
 * server. {"scene": {...}, "files": [{"name", "base64"}], "mechanism",
 * "budget", "deadline"}: malformed JSON (with its line and column), text after the
 * document, a repeated or unknown key, a scene that is not an object, a
 * mechanism, budget or deadline out of range, too many files, a bad file name or a
 * name given twice, bad base64 — each is a problem with its HTTP status,
 * type, title, field and a detail that says what is wrong.
 *
 * The submission's fingerprint (SHA-256 over the scene's bytes, the files
 * in order, the mechanism and the budget) tells an Idempotency-Key replay
 * from the same key reused with another body.
 */
#ifndef BGB_SUBMISSION_H
#define BGB_SUBMISSION_H

#include <stddef.h>
#include <stdint.h>

#include "bgb_store.h"

#define BGB_SUBMISSION_DEFAULT_BUDGET 1000.0
/* A job's deadline at most, seconds after its submission. */
#define BGB_SUBMISSION_MAX_DEADLINE 1e7
/* Hex digits of a fingerprint, with its NUL. */
#define BGB_FINGERPRINT_SIZE 65

/* Why a request was refused: what the REST API answers as problem+json. */
typedef struct bgb_problem {
    unsigned status;   /* 400, 413, 415, 422, 429, ... */
    const char *type;  /* "malformed-json", ... (static text) */
    const char *title; /* "Malformed JSON", ... (static text) */
    char field[256];   /* the field at fault, "" for none */
    char detail[512];
} bgb_problem_t;

/* Fills *p; returns 0 so that a failing path can `return bgb_problem(...)`. */
int bgb_problem(bgb_problem_t *p, unsigned status, const char *type, const char *title,
                const char *field, const char *fmt, ...) __attribute__((format(printf, 6, 7)));

typedef struct bgb_upload {
    char name[BGB_STORE_MAX_FILE_NAME + 1];
    uint8_t *data; /* owned */
    size_t size;
} bgb_upload_t;

typedef struct bgb_submission {
    char *scene;           /* the scene's JSON text as the client wrote it (owned) */
    const char *mechanism; /* "central", "catallactic" or "posted" (static text) */
    double budget;
    double deadline;       /* seconds after submission by which the job must have its
                              services (a lost agent's too); 0: none given */
    bgb_upload_t files[BGB_STORE_MAX_FILES];
    int file_count;
    int64_t upload_bytes; /* the files' decoded sizes, summed */
    char fingerprint[BGB_FINGERPRINT_SIZE];
} bgb_submission_t;

/*
 * Parses body[0..size) (not NUL-terminated) into *out; a decoded file may
 * have at most max_file bytes. 1 on success (out owns its buffers:
 * bgb_submission_release); 0 with *problem filled (out is then empty).
 */
int bgb_submission_parse(const char *body, size_t size, size_t max_file, bgb_submission_t *out,
                         bgb_problem_t *problem);

/* The files as the store takes them (borrowed from s), into files[]. */
void bgb_submission_files(const bgb_submission_t *s, bgb_file_t *files);

void bgb_submission_release(bgb_submission_t *s);

#endif
