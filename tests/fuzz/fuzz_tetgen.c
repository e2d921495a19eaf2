/*
 * fuzz_tetgen — the TetGen reader (bg_mesh_parse_tetgen), which takes two
 * texts: the input is a length-prefixed chunk (fuzz_input.h), the .node
 * text, then the rest, the .ele text.
 */
#include <stdlib.h>

#include "bg_mesh_io.h"
#include "fuzz_input.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    uint8_t *node = NULL, *ele = NULL;
    size_t node_length = 0, ele_length = 0;
    if (fuzz_take_chunk(&in, &node, &node_length) == 1 &&
        fuzz_take_rest(&in, &ele, &ele_length) == 1) {
        bg_mesh_t *mesh = NULL;
        bg_error_t err = BG_ERROR_INIT;
        if (bg_mesh_parse_tetgen((const char *)node, node_length, (const char *)ele, ele_length,
                                 "fuzz", &mesh, &err) == BG_OK) {
            for (int64_t i = 0; i < (int64_t)mesh->ne * mesh->nodes_per_element; i++)
                if (mesh->elements[i] < 0 || mesh->elements[i] >= mesh->nv)
                    abort();
        } else if (!err.message[0]) {
            abort();
        }
        bg_mesh_destroy(&mesh);
    }
    free(node);
    free(ele);
    return 0;
}
