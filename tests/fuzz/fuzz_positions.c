/*
 * fuzz_positions — the positions reader (bg_positions_parse): the first
 * byte gives the dimension (2 + its lowest bit) and the vertex count (1 +
 * the rest modulo 32); the rest is the file's text. The output buffer is
 * exactly nv·dim doubles, so a write past it is an ASan report.
 */
#include <stdlib.h>

#include "bg_mesh_io.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    const uint8_t head = fuzz_take_byte(&in);
    const int dim = 2 + (head & 1);
    const int32_t nv = 1 + (head >> 1) % 32;
    uint8_t *text = NULL;
    size_t length = 0;
    double *out = malloc((size_t)nv * (size_t)dim * sizeof *out);
    if (out && fuzz_take_rest(&in, &text, &length) == 1) {
        bg_error_t err = BG_ERROR_INIT;
        if (bg_positions_parse((const char *)text, length, "fuzz", nv, dim, out, &err) != BG_OK &&
            !err.message[0])
            abort();
    }
    free(out);
    free(text);
    return 0;
}
