#include "fuzz_input.h"

#include <stdlib.h>
#include <string.h>

uint8_t fuzz_take_byte(fuzz_input_t *in)
{
    if (in->size == 0)
        return 0;
    const uint8_t b = in->data[0];
    in->data++;
    in->size--;
    return b;
}

/* Copies the next n bytes (n ≤ in->size) into an exact-size allocation. */
static int take(fuzz_input_t *in, size_t n, uint8_t **out, size_t *length)
{
    *out = malloc(n ? n : 1);
    if (!*out)
        return -1;
    if (n)
        memcpy(*out, in->data, n);
    *length = n;
    in->data += n;
    in->size -= n;
    return 1;
}

int fuzz_take_chunk(fuzz_input_t *in, uint8_t **out, size_t *length)
{
    *out = NULL;
    *length = 0;
    if (in->size == 0)
        return 0;
    size_t n = fuzz_take_byte(in);
    n |= (size_t)fuzz_take_byte(in) << 8;
    return take(in, n < in->size ? n : in->size, out, length);
}

int fuzz_take_chunks(fuzz_input_t *in, int max, uint8_t **chunks, size_t *lengths)
{
    int count = 0;
    for (int i = 0; i < max; i++)
        chunks[i] = NULL;
    while (count < max) {
        const int got = fuzz_take_chunk(in, &chunks[count], &lengths[count]);
        if (got < 0)
            return -1;
        if (got == 0)
            break;
        count++;
    }
    return count;
}

void fuzz_free_chunks(int count, uint8_t **chunks)
{
    for (int i = 0; i < count; i++) {
        free(chunks[i]);
        chunks[i] = NULL;
    }
}

int fuzz_chunks_equal(int count_a, uint8_t *const *a, const size_t *length_a, int count_b,
                      uint8_t *const *b, const size_t *length_b)
{
    if (count_a != count_b)
        return 0;
    for (int i = 0; i < count_a; i++)
        if (length_a[i] != length_b[i] || (length_a[i] && memcmp(a[i], b[i], length_a[i]) != 0))
            return 0;
    return 1;
}

int fuzz_take_rest(fuzz_input_t *in, uint8_t **out, size_t *length)
{
    *out = NULL;
    *length = 0;
    return take(in, in->size, out, length);
}
