/*
 * fuzz_input — what every fuzz harness shares: the libFuzzer entry point's
 * prototype, and a reader that cuts one fuzz input into the pieces a
 * parser takes (a selector byte, length-prefixed chunks).
 *
 * Each harness tests/fuzz/fuzz_NAME.c defines LLVMFuzzerTestOneInput. It is
 * linked either with libFuzzer (BIOTGRID_FUZZ=ON, clang) or with replay.c,
 * a main that feeds it the files of a corpus (the normal build's CTest).
 * A harness must never abort on any input: it may only crash where the
 * code under test is wrong, and it frees everything it was given.
 *
 * Every piece is copied into its own allocation of exactly its size, so
 * that AddressSanitizer sees a parser reading past the piece it was given
 * (pointers into the fuzz input would let it read the next piece).
 */
#ifndef FUZZ_INPUT_H
#define FUZZ_INPUT_H

#include <stddef.h>
#include <stdint.h>

/* The entry point libFuzzer calls, once per input; returns 0. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* A cursor over one fuzz input (borrowed). */
typedef struct fuzz_input {
    const uint8_t *data;
    size_t size;
} fuzz_input_t;

/* The next byte, or 0 when the input is exhausted. */
uint8_t fuzz_take_byte(fuzz_input_t *in);

/*
 * The next chunk: a 16-bit little-endian length, then that many bytes
 * (fewer when the input ends first). *out is a fresh allocation of exactly
 * *length bytes (at least 1 byte is allocated so that an empty chunk is
 * not NULL); the caller frees it. Returns 0 when the input is exhausted
 * (nothing allocated), -1 when out of memory, 1 otherwise.
 */
int fuzz_take_chunk(fuzz_input_t *in, uint8_t **out, size_t *length);

/*
 * Up to max chunks (fuzz_take_chunk), until the input is exhausted: the
 * frames of a multipart message. Returns how many were taken, -1 when out
 * of memory. chunks[count..max) are NULL; the caller frees all max of them
 * with fuzz_free_chunks(max, chunks) in every case.
 */
int fuzz_take_chunks(fuzz_input_t *in, int max, uint8_t **chunks, size_t *lengths);
void fuzz_free_chunks(int count, uint8_t **chunks);

/* Whether two lists of chunks hold the same bytes (1) or not (0). */
int fuzz_chunks_equal(int count_a, uint8_t *const *a, const size_t *length_a, int count_b,
                      uint8_t *const *b, const size_t *length_b);

/* The rest of the input, copied as fuzz_take_chunk does (returns the same). */
int fuzz_take_rest(fuzz_input_t *in, uint8_t **out, size_t *length);

#endif
