/*
 * fuzz_wire — the wire protocol's decoder (bga_wire_decode), every type.
 * The first byte picks the limits (lowest bit: tight caps of a few hundred
 * bytes, to reach the oversize paths; else the defaults); the rest is the
 * message's frames, each a length-prefixed chunk (fuzz_input.h), at most
 * BGA_WIRE_MAX_FRAMES + 2 so that too many frames are tried too.
 *
 * A message that decodes is read through the accessors (every element of
 * every array), must encode again (the encoder checks the same rules) and
 * decode again to the same fields; a refused one must have an error reply.
 */
#include <stdlib.h>
#include <string.h>

#include "bga_wire.h"
#include "fuzz_input.h"

#define MAX_CHUNKS (BGA_WIRE_MAX_FRAMES + 2)

/* Each array is its frame, whole: count elements of 1, 4 or 8 bytes. */
static void read_arrays(const bga_msg_t *msg, const bga_frame_t *frames, int nframes)
{
    volatile unsigned sink = 0;
    if (nframes != 2 + msg->narrays)
        abort();
    for (int a = 0; a < msg->narrays; a++) {
        const size_t count = msg->array[a].count, bytes = frames[2 + a].size;
        if (count == 0)
            continue;
        if (msg->array[a].data != frames[2 + a].data ||
            (bytes != count && bytes != 4 * count && bytes != 8 * count))
            abort();
        for (size_t i = 0; i < bytes; i++)
            sink += ((const uint8_t *)msg->array[a].data)[i];
    }
    (void)sink;
}

static void round_trip(const bga_msg_t *msg)
{
    bga_frames_t frames;
    bg_error_t err = BG_ERROR_INIT;
    if (bga_wire_encode(msg, &frames, &err) != BG_OK)
        abort(); /* decode accepted what encode refuses */
    bga_frame_t views[BGA_WIRE_MAX_FRAMES];
    bga_frames_view(&frames, views);
    bga_msg_t back;
    bga_wire_error_t werr;
    const bga_limits_t unlimited = {SIZE_MAX, SIZE_MAX};
    if (bga_wire_decode(views, frames.count, &unlimited, &back, &werr) != BGA_WIRE_OK ||
        back.nfields != msg->nfields || back.narrays != msg->narrays ||
        memcmp(&back.header, &msg->header, sizeof back.header) != 0 ||
        memcmp(back.field, msg->field, sizeof back.field) != 0)
        abort(); /* the encoding does not read back as it was */
    for (int a = 0; a < msg->narrays; a++)
        if (back.array[a].count != msg->array[a].count)
            abort();
    bga_frames_free(&frames);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    fuzz_input_t in = {data, size};
    const uint8_t mode = fuzz_take_byte(&in);
    bga_limits_t limits = bga_wire_default_limits();
    if (mode & 1)
        limits = (bga_limits_t){.max_frame_bytes = 256, .max_message_bytes = 512};
    uint8_t *chunks[MAX_CHUNKS];
    size_t lengths[MAX_CHUNKS];
    const int n = fuzz_take_chunks(&in, MAX_CHUNKS, chunks, lengths);
    if (n >= 0) {
        bga_frame_t frames[MAX_CHUNKS];
        for (int i = 0; i < n; i++)
            frames[i] = (bga_frame_t){chunks[i], lengths[i]};
        bga_msg_t msg;
        bga_wire_error_t werr;
        memset(&msg, 0, sizeof msg);
        memset(&werr, 0, sizeof werr);
        if (bga_wire_decode(frames, n, &limits, &msg, &werr) == BGA_WIRE_OK) {
            read_arrays(&msg, frames, n);
            round_trip(&msg);
        } else {
            bga_frames_t reply;
            bg_error_t err = BG_ERROR_INIT;
            if (bga_wire_error_reply(werr.frame > 0 ? &msg.header : NULL, &werr, &reply, &err) ==
                BG_OK)
                bga_frames_free(&reply);
        }
    }
    fuzz_free_chunks(MAX_CHUNKS, chunks);
    return 0;
}
