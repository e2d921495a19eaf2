/*
 * fuzz_selection — the vertex selection reader (bg_selection_parse): the
 * first byte gives the vertex count (1 + it modulo 64); the rest is the
 * file's text (a DMAT file or a list of indices). The labels buffer is
 * exactly nv values, so a write past it is an ASan report.
 */
#include <stdlib.h>

#include "bg_mesh_io.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    const int32_t nv = 1 + fuzz_take_byte(&in) % 64;
    uint8_t *text = NULL;
    size_t length = 0;
    int32_t *labels = malloc((size_t)nv * sizeof *labels);
    if (labels && fuzz_take_rest(&in, &text, &length) == 1) {
        bg_error_t err = BG_ERROR_INIT;
        if (bg_selection_parse((const char *)text, length, "fuzz", nv, labels, &err) != BG_OK &&
            !err.message[0])
            abort();
    }
    free(labels);
    free(text);
    return 0;
}
