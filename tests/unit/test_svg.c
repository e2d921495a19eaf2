/*
 * SVG plots: structure (one document, one polyline per unbroken series),
 * escaping, tick labels on log and linear axes, and robustness to NaN,
 * infinities and non-positive values on log axes.
 */
#include <ctype.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "bg_svg.h"

static int count_occurrences(const char *text, const char *needle)
{
    int n = 0;
    for (const char *p = strstr(text, needle); p; p = strstr(p + 1, needle))
        n++;
    return n;
}

/* Case-insensitive search, for "nan" / "inf" in any spelling. */
static int contains_nocase(const char *text, const char *needle)
{
    size_t n = strlen(needle);
    for (const char *p = text; *p; p++) {
        size_t i = 0;
        while (i < n && p[i] && tolower((unsigned char)p[i]) == tolower((unsigned char)needle[i]))
            i++;
        if (i == n)
            return 1;
    }
    return 0;
}

/* Structural checks every rendering must pass. */
static void assert_wellformed(const char *svg, size_t length)
{
    assert_int_equal(strlen(svg), length);
    assert_int_equal(strncmp(svg, "<svg", 4), 0);
    size_t end = length;
    while (end > 0 && isspace((unsigned char)svg[end - 1]))
        end--;
    assert_true(end >= 6);
    assert_int_equal(strncmp(svg + end - 6, "</svg>", 6), 0);
    assert_int_equal(count_occurrences(svg, "<svg"), 1);
    assert_int_equal(count_occurrences(svg, "<text"), count_occurrences(svg, "</text>"));
    assert_int_equal(count_occurrences(svg, "<g"), count_occurrences(svg, "</g>"));
    assert_int_equal(count_occurrences(svg, "<"), count_occurrences(svg, ">"));
    assert_false(contains_nocase(svg, "nan"));
    assert_false(contains_nocase(svg, "inf"));
}

static char *render(const bg_svg_plot_t *plot, const bg_svg_series_t *series, int count)
{
    char *svg = NULL;
    size_t length = 0;
    bg_error_t err = BG_ERROR_INIT;
    bg_status st = bg_svg_render(plot, series, count, &svg, &length, &err);
    if (st != BG_OK)
        fail_msg("render failed: %s", err.message);
    assert_wellformed(svg, length);
    return svg;
}

static void test_log_plot(void **state)
{
    (void)state;
    double t[5] = {0.01, 0.02, 0.05, 0.1, 0.2};
    double newton[5] = {1.0, 1e-2, 1e-4, 1e-6, 1e-8};
    double lg[5] = {1.0, 0.5, 0.1, 0.02, 0.004};
    bg_svg_series_t series[2] = {{"newton <exact> & \"tight\"", t, newton, 5},
                                 {"local-global", t, lg, 5}};
    bg_svg_plot_t plot = {"Error vs time", "wall time (s)", "relative error", 0, 1};
    char *svg = render(&plot, series, 2);
    assert_int_equal(count_occurrences(svg, "<polyline"), 2);
    assert_non_null(strstr(svg, "newton &lt;exact&gt; &amp; &quot;tight&quot;"));
    assert_null(strstr(svg, "<exact>"));
    assert_non_null(strstr(svg, ">1e-8<"));
    assert_non_null(strstr(svg, ">1e-4<"));
    assert_non_null(strstr(svg, ">1<"));
    assert_non_null(strstr(svg, "Error vs time"));
    assert_non_null(strstr(svg, "wall time (s)"));
    assert_non_null(strstr(svg, "relative error"));
    /* Two distinct colours. */
    const char *first = strstr(svg, "<polyline");
    const char *second = strstr(first + 1, "<polyline");
    const char *c1 = strstr(first, "stroke=\""), *c2 = strstr(second, "stroke=\"");
    assert_true(strncmp(c1, c2, 16) != 0);
    assert_null(strstr(svg, "no data"));
    free(svg);
}

static void test_many_decades_skip_labels(void **state)
{
    (void)state;
    double x[2] = {1.0, 2.0}, y[2] = {1e-16, 1e2};
    bg_svg_series_t s = {"wide", x, y, 2};
    bg_svg_plot_t plot = {"wide", "x", "y", 0, 1};
    char *svg = render(&plot, &s, 1);
    /* 18 decades do not get 19 labels: every third one. */
    assert_non_null(strstr(svg, ">1e-6<"));
    assert_null(strstr(svg, ">1e-7<"));
    assert_non_null(strstr(svg, ">1e-18<"));
    assert_non_null(strstr(svg, ">1e3<"));
    free(svg);
}

static void test_linear_ticks(void **state)
{
    (void)state;
    double x[3] = {0.0, 5.0, 10.0}, y[3] = {-1.0, 0.0, 1.0};
    bg_svg_series_t s = {"line", x, y, 3};
    bg_svg_plot_t plot = {"linear", "iteration", "value", 0, 0};
    char *svg = render(&plot, &s, 1);
    assert_non_null(strstr(svg, ">0<"));
    assert_non_null(strstr(svg, ">10<"));
    assert_non_null(strstr(svg, ">-1.0<"));
    assert_non_null(strstr(svg, ">0.5<"));
    assert_null(strstr(svg, ">-0.0<"));
    assert_int_equal(count_occurrences(svg, "<polyline"), 1);
    free(svg);
}

static void test_nan_and_nonpositive_break_series(void **state)
{
    (void)state;
    double x[7] = {1, 2, 3, 4, 5, 6, 7};
    double y[7] = {1e-1, 1e-2, NAN, 1e-4, 0.0, -1.0, 1e-6};
    double x2[3] = {1, INFINITY, 3}, y2[3] = {1, 2, -INFINITY};
    bg_svg_series_t series[2] = {{"broken", x, y, 7}, {"unbounded", x2, y2, 3}};
    bg_svg_plot_t plot = {"gaps", "x", "y", 0, 1};
    char *svg = render(&plot, series, 2);
    /* Runs {1e-1, 1e-2} and {1e-4}, {1e-6} singles: one polyline, two dots;
     * the second series keeps only (1, 1): a dot. */
    assert_int_equal(count_occurrences(svg, "<polyline"), 1);
    assert_int_equal(count_occurrences(svg, "<circle"), 3);
    free(svg);
    /* On a linear axis 0 and -1 are drawable, NaN still breaks. */
    plot.log_y = 0;
    svg = render(&plot, series, 1);
    assert_int_equal(count_occurrences(svg, "<polyline"), 2);
    free(svg);
}

static void test_empty_plots(void **state)
{
    (void)state;
    bg_svg_plot_t plot = {"nothing", "x", "y", 1, 1};
    char *svg = render(&plot, NULL, 0);
    assert_non_null(strstr(svg, "no data"));
    assert_int_equal(count_occurrences(svg, "<polyline"), 0);
    free(svg);
    double x[2] = {NAN, 1.0}, y[2] = {1.0, -3.0};
    bg_svg_series_t s = {"all bad", x, y, 2};
    svg = render(&plot, &s, 1);
    assert_non_null(strstr(svg, "no data"));
    assert_non_null(strstr(svg, "all bad"));
    free(svg);
    bg_svg_series_t none = {NULL, NULL, NULL, 0};
    svg = render(NULL, &none, 1);
    assert_non_null(strstr(svg, "no data"));
    free(svg);
}

static void test_single_value_and_palette(void **state)
{
    (void)state;
    enum { SERIES = 12 };
    double x[2] = {3.0, 3.0}, y[2] = {2.0, 2.0};
    bg_svg_series_t series[SERIES];
    char labels[SERIES][16];
    for (int k = 0; k < SERIES; k++) {
        snprintf(labels[k], sizeof labels[k], "s%d", k);
        series[k] = (bg_svg_series_t){labels[k], x, y, 2};
    }
    bg_svg_plot_t plot = {"flat", "x", "y", 0, 0};
    char *svg = render(&plot, series, SERIES);
    assert_int_equal(count_occurrences(svg, "<polyline"), SERIES);
    /* At least 8 distinct stroke colours among the polylines. */
    char colours[SERIES][8];
    int distinct = 0;
    const char *p = svg;
    for (int k = 0; k < SERIES; k++) {
        p = strstr(p, "<polyline");
        const char *c = strstr(p, "stroke=\"#") + 8;
        memcpy(colours[k], c, 7);
        colours[k][7] = '\0';
        int seen = 0;
        for (int j = 0; j < k; j++)
            seen |= strcmp(colours[j], colours[k]) == 0;
        distinct += !seen;
        p++;
    }
    assert_true(distinct >= 8);
    free(svg);
}

static void test_control_characters_escaped(void **state)
{
    (void)state;
    double x[2] = {1, 2}, y[2] = {1, 2};
    bg_svg_series_t s = {"tab\there\x01", x, y, 2};
    bg_svg_plot_t plot = {"a'b", "<x>", "y&", 0, 0};
    char *svg = render(&plot, &s, 1);
    assert_non_null(strstr(svg, "a&apos;b"));
    assert_non_null(strstr(svg, "&lt;x&gt;"));
    assert_non_null(strstr(svg, "y&amp;"));
    assert_null(strchr(svg, '\x01'));
    assert_null(strchr(svg, '\t'));
    free(svg);
}

static void test_write_file(void **state)
{
    (void)state;
    double x[3] = {1, 2, 3}, y[3] = {1e-3, 1e-5, 1e-7};
    bg_svg_series_t s = {"run", x, y, 3};
    bg_svg_plot_t plot = {"file", "t", "err", 1, 1};
    const char *path = BG_BINARY_DIR "/test_svg_output.svg";
    bg_error_t err = BG_ERROR_INIT;
    assert_int_equal(bg_svg_write(path, &plot, &s, 1, &err), BG_OK);
    char *expect = render(&plot, &s, 1);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    char buffer[65536];
    size_t n = fread(buffer, 1, sizeof buffer - 1, f);
    fclose(f);
    buffer[n] = '\0';
    assert_string_equal(buffer, expect);
    free(expect);
    remove(path);
    bg_error_clear(&err);
    assert_int_equal(bg_svg_write("/nonexistent-dir/x.svg", &plot, &s, 1, &err), BG_ERR_IO);
    assert_non_null(strstr(err.message, "/nonexistent-dir/x.svg"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_log_plot),
        cmocka_unit_test(test_many_decades_skip_labels),
        cmocka_unit_test(test_linear_ticks),
        cmocka_unit_test(test_nan_and_nonpositive_break_series),
        cmocka_unit_test(test_empty_plots),
        cmocka_unit_test(test_single_value_and_palette),
        cmocka_unit_test(test_control_characters_escaped),
        cmocka_unit_test(test_write_file),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
