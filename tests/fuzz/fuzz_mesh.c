/*
 * fuzz_mesh — the one-text mesh readers (bg_mesh_parse): the first byte
 * picks the format, modulo 6 so that a hand-written seed starts with an
 * ASCII digit ('0' MEDIT, '1' OFF, '2' OBJ, '3' Gmsh 2.2, '4' Gmsh 4.1,
 * '5' VTU); the rest is the file's text. A parsed mesh must have passed
 * bg_mesh_validate, so the harness walks it as a solver would; a refusal
 * must say why.
 */
#include <stdlib.h>

#include "bg_mesh_io.h"
#include "fuzz_input.h"

static const bg_mesh_format formats[] = {BG_FORMAT_MEDIT,  BG_FORMAT_OFF,    BG_FORMAT_OBJ,
                                         BG_FORMAT_GMSH22, BG_FORMAT_GMSH41, BG_FORMAT_VTU};

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    const bg_mesh_format format = formats[fuzz_take_byte(&in) % 6];
    uint8_t *text = NULL;
    size_t length = 0;
    if (fuzz_take_rest(&in, &text, &length) != 1)
        return 0;
    bg_mesh_t *mesh = NULL;
    bg_error_t err = BG_ERROR_INIT;
    if (bg_mesh_parse(format, (const char *)text, length, "fuzz", &mesh, &err) == BG_OK) {
        const int32_t k = (int32_t)mesh->nodes_per_element;
        for (int64_t i = 0; i < (int64_t)mesh->ne * k; i++)
            if (mesh->elements[i] < 0 || mesh->elements[i] >= mesh->nv)
                abort(); /* an index out of range got through */
    } else if (!err.message[0]) {
        abort(); /* a refusal without a message */
    }
    bg_mesh_destroy(&mesh);
    free(text);
    return 0;
}
