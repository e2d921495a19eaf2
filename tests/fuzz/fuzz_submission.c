/*
 * fuzz_submission — the body of POST /v1/jobs (bgb_submission_parse): the
 * whole input is the body. Decoded files are capped at 4 KiB, so the
 * too-large path is reached too. A refusal must carry an HTTP status and
 * a detail; a submission that parses is handed to the store's view.
 */
#include <stdlib.h>

#include "bgb_submission.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    uint8_t *body = NULL;
    size_t length = 0;
    if (fuzz_take_rest(&in, &body, &length) != 1)
        return 0;
    bgb_submission_t s;
    bgb_problem_t problem;
    if (bgb_submission_parse((const char *)body, length, 4096, &s, &problem)) {
        bgb_file_t files[BGB_STORE_MAX_FILES];
        bgb_submission_files(&s, files);
        if (!s.scene || s.file_count < 0 || s.file_count > BGB_STORE_MAX_FILES)
            abort();
        bgb_submission_release(&s);
    } else if (problem.status < 400 || problem.status > 599 || !problem.detail[0]) {
        abort();
    }
    free(body);
    return 0;
}
