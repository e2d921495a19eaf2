/*
 * JSON field paths ("mesh.cells[2]"), as every error message names them:
 * each built path equals the one snprintf makes of the same parts (an
 * independent construction), including paths cut at BG_JSON_PATH_MAX and
 * marked "...", negative and extreme indices, an empty parent and a
 * parent extended in place; and a vector's bad element is named by its
 * index.
 */
#include <limits.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "bg_json.h"

/* The reference: snprintf, then the truncation mark over the last bytes. */
static void reference(char *out, int written)
{
    static const char mark[] = "...";
    if (written >= BG_JSON_PATH_MAX)
        memcpy(out + BG_JSON_PATH_MAX - sizeof mark, mark, sizeof mark);
}

static void check_key(const char *parent, const char *key)
{
    char got[BG_JSON_PATH_MAX], want[BG_JSON_PATH_MAX];
    memset(got, 'x', sizeof got);
    bg_json_path_key(got, parent, key);
    reference(want, parent && parent[0] ? snprintf(want, sizeof want, "%s.%s", parent, key)
                                        : snprintf(want, sizeof want, "%s", key));
    assert_string_equal(got, want);
    assert_true(strlen(got) < BG_JSON_PATH_MAX);
}

static void check_index(const char *parent, int index)
{
    char got[BG_JSON_PATH_MAX], want[BG_JSON_PATH_MAX];
    bg_json_path_index(got, parent, index);
    reference(want, snprintf(want, sizeof want, "%s[%d]", parent, index));
    assert_string_equal(got, want);
}

static void keys(void **state)
{
    (void)state;
    check_key(NULL, "mesh");
    check_key("", "mesh");
    check_key("scene", "mesh");
    check_key("a.b[3]", "c");
    char long_part[400];
    for (size_t n = 240; n < 270; n++) {
        memset(long_part, 'p', n);
        long_part[n] = '\0';
        check_key(long_part, "key");
        check_key("parent", long_part);
        check_key(NULL, long_part);
    }
}

static void indices(void **state)
{
    (void)state;
    const int values[] = {0, 1, 9, 10, 99, 12345, -1, -10, INT_MAX, INT_MIN};
    for (size_t i = 0; i < sizeof values / sizeof values[0]; i++) {
        check_index("cells", values[i]);
        check_index("", values[i]);
    }
    char long_part[400];
    for (size_t n = 240; n < 260; n++) {
        memset(long_part, 'q', n);
        long_part[n] = '\0';
        check_index(long_part, 123);
    }
}

/* A parent path extended in place, as a walk down a document does. */
static void in_place(void **state)
{
    (void)state;
    char path[BG_JSON_PATH_MAX] = "scene";
    bg_json_path_key(path, path, "mesh");
    bg_json_path_index(path, path, 2);
    bg_json_path_key(path, path, "x");
    assert_string_equal(path, "scene.mesh[2].x");
}

static void vector_names_element(void **state)
{
    (void)state;
    bg_error_t err = BG_ERROR_INIT;
    cJSON *v = cJSON_Parse("[1, 2.5, \"three\"]");
    assert_non_null(v);
    double out[3] = {0};
    assert_int_equal(bg_json_vector(v, "scene.json", "size", 3, out, &err), BG_ERR_INVALID);
    assert_non_null(strstr(err.message, "size[2]"));
    assert_non_null(strstr(err.message, "a string"));
    cJSON_Delete(v);
    v = cJSON_Parse("[1, 2.5, -3e2]");
    assert_int_equal(bg_json_vector(v, "scene.json", "size", 3, out, &err), BG_OK);
    assert_true(out[0] == 1 && out[1] == 2.5 && out[2] == -300);
    cJSON_Delete(v);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(keys),
        cmocka_unit_test(indices),
        cmocka_unit_test(in_place),
        cmocka_unit_test(vector_names_element),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
