/*
 * fuzz_mmsg — the live market's decoder (bga_mmsg_decode) between the
 * broker and the agents. The input is the message's frames, each a
 * length-prefixed chunk (fuzz_input.h). A message that decodes must
 * encode again, and its encoding must decode and encode to the same bytes.
 */
#include <stdlib.h>

#include "bga_mmsg.h"
#include "fuzz_input.h"

#define MAX_CHUNKS (BGA_WIRE_MAX_FRAMES + 2)

static void fixed_point(const bga_mmsg_t *m)
{
    bga_frames_t once, twice;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_mmsg_encode(m, &once, &err) != BG_OK)
        abort(); /* decoded, yet refused by the encoder */
    bga_frame_t views[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&once, views);
    bga_mmsg_t back;
    if (bga_mmsg_decode(views, once.count, &back, &err) != BG_OK)
        abort(); /* its own encoding refused */
    if (bga_mmsg_encode(&back, &twice, &err) != BG_OK)
        abort();
    if (!fuzz_chunks_equal(once.count, once.data, once.size, twice.count, twice.data, twice.size))
        abort(); /* a second round trip changed the message */
    bga_frames_free(&once);
    bga_frames_free(&twice);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    uint8_t *chunks[MAX_CHUNKS];
    size_t lengths[MAX_CHUNKS];
    const int n = fuzz_take_chunks(&in, MAX_CHUNKS, chunks, lengths);
    if (n >= 0) {
        bga_frame_t frames[MAX_CHUNKS];
        for (int i = 0; i < n; i++)
            frames[i] = (bga_frame_t){chunks[i], lengths[i]};
        (void)bga_mmsg_is_market(frames, n);
        bga_mmsg_t m;
        bg_error_t err = BG_ERROR_INIT;
        if (bga_mmsg_decode(frames, n, &m, &err) == BG_OK)
            fixed_point(&m);
        else if (!err.message[0])
            abort();
    }
    fuzz_free_chunks(MAX_CHUNKS, chunks);
    return 0;
}
