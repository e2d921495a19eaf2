/*
 * bgm_codec — pure encode/decode of the market roles' messages with the
 * project's wire framing (bga_wire: header frame, scalar frame, array
 * frames), types 0x1001..0x1019 (bgm_role.h).
 *
 * Every market type has the same schema (so that one decoder serves the
 * simulator's generic message and the roles' typed ones):
 *   header   job, seq, sender = from, receiver = to
 *   scalars  good, hops, ncand, req, attempt, origin (i64, each range-checked),
 *            price, a, b, c (f64, finite)
 *   arrays   cand (i32, ncand, each < 2^31), cand_price (f64, ncand, finite),
 *            cand_speed (f64, ncand, finite)
 * plus per-type rules (e.g. a bid's work and deadline positive, a list's
 * ncand ≤ BGM_ROLE_CANDIDATES). Decoding never allocates; encoding fills a
 * bga_frames_t the caller frees with bga_frames_free.
 *
 * No dependency on the engine: bga_wire and bg_error live in the base
 * library (services/base).
 */
#ifndef BGM_CODEC_H
#define BGM_CODEC_H

#include "bga_wire.h"
#include "bgm_role.h"
#include "bgm_world.h"

/* Whether type is a market message type. */
int bgm_codec_type_known(uint16_t type);
const char *bgm_codec_type_name(uint16_t type);

/* The simulator's generic message (bgm_world.h) ↔ frames. */
bg_status bgm_codec_encode_msg(const bgm_msg_t *m, uint64_t job, uint64_t seq, bga_frames_t *out,
                               bg_error_t *err);
bga_wire_code bgm_codec_decode_msg(const bga_frame_t *frames, int nframes, bgm_msg_t *m,
                                   bga_wire_error_t *werr);

/* The roles' typed message (bgm_role.h) ↔ frames. */
bg_status bgm_codec_encode(const bgm_role_msg_t *m, uint64_t seq, bga_frames_t *out,
                           bg_error_t *err);
bga_wire_code bgm_codec_decode(const bga_frame_t *frames, int nframes, bgm_role_msg_t *m,
                               bga_wire_error_t *werr);

/* Typed ↔ generic (the simulator's world routes generic messages). */
bg_status bgm_codec_to_generic(const bgm_role_msg_t *in, bgm_msg_t *out, bg_error_t *err);
bg_status bgm_codec_from_generic(const bgm_msg_t *in, bgm_role_msg_t *out, bg_error_t *err);

#endif
