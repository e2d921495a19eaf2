/*
 * fuzz_market_codec — the market roles' decoders (bgm_codec_decode_msg,
 * the simulator's generic message, and bgm_codec_decode, the roles' typed
 * one). The input is the message's frames, each a length-prefixed chunk
 * (fuzz_input.h). A message that decodes must encode again, and its
 * encoding must decode and encode to the same bytes (a fixed point).
 */
#include <stdlib.h>
#include <string.h>

#include "bgm_codec.h"
#include "fuzz_input.h"

#define MAX_CHUNKS (BGA_WIRE_MAX_FRAMES + 2)

/* decode ∘ encode of a typed message is the identity on its encoding. */
static void typed_fixed_point(const bgm_role_msg_t *m)
{
    bga_frames_t once, twice;
    bg_error_t err = BG_ERROR_INIT;
    if (bgm_codec_encode(m, 7, &once, &err) != BG_OK)
        abort(); /* decoded, yet refused by the encoder */
    bga_frame_t views[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&once, views);
    bgm_role_msg_t back;
    bga_wire_error_t werr;
    if (bgm_codec_decode(views, once.count, &back, &werr) != BGA_WIRE_OK)
        abort(); /* its own encoding refused */
    if (bgm_codec_encode(&back, 7, &twice, &err) != BG_OK)
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
        bga_wire_error_t werr;
        bgm_msg_t generic;
        if (bgm_codec_decode_msg(frames, n, &generic, &werr) == BGA_WIRE_OK) {
            bga_frames_t out;
            bg_error_t err = BG_ERROR_INIT;
            if (bgm_codec_encode_msg(&generic, 1, 2, &out, &err) != BG_OK)
                abort();
            bga_frames_free(&out);
        }
        bgm_role_msg_t typed;
        if (bgm_codec_decode(frames, n, &typed, &werr) == BGA_WIRE_OK)
            typed_fixed_point(&typed);
    }
    fuzz_free_chunks(MAX_CHUNKS, chunks);
    return 0;
}
