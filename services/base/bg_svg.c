#include "bg_svg.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Canvas and plot area, in SVG user units (pixels). The legend sits in the
 * right margin so it never hides data. */
#define SVG_WIDTH 720
#define SVG_HEIGHT 440
#define PLOT_LEFT 84.0
#define PLOT_RIGHT 540.0
#define PLOT_TOP 44.0
#define PLOT_BOTTOM 376.0
#define LEGEND_X 556.0
#define LEGEND_Y 56.0
#define LEGEND_ROW 20.0
#define LEGEND_SWATCH 22.0
#define LEGEND_LABEL_MAX 24 /* characters of a label shown in the legend */
#define TICK_LENGTH 5.0
#define MARKER_RADIUS 2.5
#define FONT_FAMILY "Helvetica, Arial, sans-serif"
/* A linear axis aims at about this many intervals, with 1-2-5 steps. */
#define LINEAR_TARGET_INTERVALS 5.0
/* A log axis labels at most this many decades (else every 2nd, 3rd, ...). */
#define LOG_MAX_LABELS 8
#define TICK_TEXT_MAX 32
#define INITIAL_CAPACITY 8192

static const char *const PALETTE[] = {"#1c64c8", "#d4500f", "#2a8a3e", "#c2255c", "#6f42c1",
                                      "#e08e00", "#0c8599", "#495057", "#5c940d", "#8f3f71"};
#define PALETTE_SIZE ((int)(sizeof PALETTE / sizeof PALETTE[0]))

/* ---------------------------------------------------------------- buffer */

typedef struct buffer {
    char *data;
    size_t length;
    size_t capacity;
    int failed; /* an allocation failed: everything after is dropped */
} buffer_t;

static void reserve(buffer_t *b, size_t extra)
{
    if (b->failed || b->length + extra + 1 <= b->capacity)
        return;
    size_t capacity = b->capacity ? b->capacity : INITIAL_CAPACITY;
    while (capacity < b->length + extra + 1)
        capacity *= 2;
    char *grown = realloc(b->data, capacity);
    if (!grown) {
        b->failed = 1;
        return;
    }
    b->data = grown;
    b->capacity = capacity;
}

static void put(buffer_t *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void put(buffer_t *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n < 0) {
        b->failed = 1;
        return;
    }
    reserve(b, (size_t)n);
    if (b->failed)
        return;
    va_start(ap, fmt);
    vsnprintf(b->data + b->length, (size_t)n + 1, fmt, ap);
    va_end(ap);
    b->length += (size_t)n;
}

/* Appends text escaped for XML character data and attribute values; control
 * characters, which XML 1.0 forbids, become '?'. At most `limit` bytes of
 * the source are used (0: all), with "…" marking a cut. */
static void put_escaped(buffer_t *b, const char *text, size_t limit)
{
    size_t n = strlen(text);
    int cut = limit && n > limit;
    if (cut) {
        n = limit;
        /* Do not split a UTF-8 sequence. */
        while (n > 0 && ((unsigned char)text[n] & 0xC0) == 0x80)
            n--;
    }
    for (size_t i = 0; i < n; i++) {
        unsigned char ch = (unsigned char)text[i];
        switch (ch) {
        case '&':
            put(b, "&amp;");
            break;
        case '<':
            put(b, "&lt;");
            break;
        case '>':
            put(b, "&gt;");
            break;
        case '"':
            put(b, "&quot;");
            break;
        case '\'':
            put(b, "&apos;");
            break;
        default:
            if (ch < 0x20 || ch == 0x7F)
                put(b, "?");
            else
                put(b, "%c", (char)ch);
        }
    }
    if (cut)
        put(b, "\xE2\x80\xA6");
}

/* ------------------------------------------------------------------ axes */

typedef struct axis {
    int log;
    double lo, hi; /* in plot coordinates (log10 of the value on a log axis) */
    double step;   /* tick spacing in plot coordinates */
    int has_data;
} axis_t;

/* Whether a value can be drawn on this axis. */
static int usable(const axis_t *a, double v)
{
    return isfinite(v) && (!a->log || v > 0.0);
}

static double to_axis(const axis_t *a, double v)
{
    return a->log ? log10(v) : v;
}

/* Chooses the range and tick step from the data extremes lo, hi. */
static void layout_axis(axis_t *a, double lo, double hi)
{
    if (!a->has_data) {
        lo = 0.0;
        hi = 1.0;
    }
    if (a->log) {
        double first = floor(lo), last = ceil(hi);
        if (first == last) {
            first -= 1.0;
            last += 1.0;
        }
        double step = ceil((last - first) / LOG_MAX_LABELS);
        a->step = step < 1.0 ? 1.0 : step;
        a->lo = floor(first / a->step) * a->step;
        a->hi = ceil(last / a->step) * a->step;
        return;
    }
    if (lo == hi) {
        double pad = fabs(lo) > 0.0 ? 0.5 * fabs(lo) : 1.0;
        lo -= pad;
        hi += pad;
    }
    /* Halved differences: finite even for data spanning ±DBL_MAX. */
    double raw = (0.5 * hi - 0.5 * lo) / (0.5 * LINEAR_TARGET_INTERVALS);
    double magnitude = pow(10.0, floor(log10(raw)));
    double norm = raw / magnitude;
    double nice = norm < 1.5 ? 1.0 : norm < 3.0 ? 2.0 : norm < 7.0 ? 5.0 : 10.0;
    a->step = nice * magnitude;
    a->lo = floor(lo / a->step) * a->step;
    a->hi = ceil(hi / a->step) * a->step;
    if (!isfinite(a->lo) || !isfinite(a->hi)) {
        a->lo = lo;
        a->hi = hi;
    }
}

/* Fraction of the axis range at plot coordinate t, in [0, 1]. */
static double fraction(const axis_t *a, double t)
{
    return (0.5 * t - 0.5 * a->lo) / (0.5 * a->hi - 0.5 * a->lo);
}

static double pixel_x(const axis_t *a, double t)
{
    return PLOT_LEFT + fraction(a, t) * (PLOT_RIGHT - PLOT_LEFT);
}

static double pixel_y(const axis_t *a, double t)
{
    return PLOT_BOTTOM - fraction(a, t) * (PLOT_BOTTOM - PLOT_TOP);
}

static void tick_label(const axis_t *a, double t, char *out)
{
    if (a->log) {
        int exponent = (int)lround(t);
        if (exponent == 0)
            snprintf(out, TICK_TEXT_MAX, "1");
        else
            snprintf(out, TICK_TEXT_MAX, "1e%d", exponent);
        return;
    }
    if (fabs(t) < 1e-9 * a->step)
        t = 0.0; /* no "-0" or "1e-17" where the axis crosses zero */
    double big = fmax(fabs(a->lo), fabs(a->hi));
    if (a->step >= 1e-4 && big < 1e6) {
        int decimals = (int)ceil(-log10(a->step) - 1e-9);
        snprintf(out, TICK_TEXT_MAX, "%.*f", decimals > 0 ? decimals : 0, t);
    } else {
        snprintf(out, TICK_TEXT_MAX, "%.4g", t);
    }
}

/* Number of ticks on the axis (the ends included). */
static int tick_count(const axis_t *a)
{
    double n = floor((0.5 * a->hi - 0.5 * a->lo) / (0.5 * a->step) + 0.5) + 1.0;
    return isfinite(n) && n >= 2.0 && n < 100.0 ? (int)n : 2;
}

static double tick_value(const axis_t *a, int i, int count)
{
    if (i == count - 1)
        return a->hi;
    return a->lo + i * ((0.5 * a->hi - 0.5 * a->lo) / (0.5 * (count - 1)));
}

static void draw_axes(buffer_t *b, const axis_t *ax, const axis_t *ay)
{
    char text[TICK_TEXT_MAX];
    int nx = tick_count(ax), ny = tick_count(ay);
    put(b, "<g stroke=\"#e3e3e3\" stroke-width=\"1\">\n");
    for (int i = 0; i < nx; i++) {
        double px = pixel_x(ax, tick_value(ax, i, nx));
        put(b, "<line x1=\"%.2f\" y1=\"%.2f\" x2=\"%.2f\" y2=\"%.2f\"/>\n", px, PLOT_TOP, px,
            PLOT_BOTTOM);
    }
    for (int i = 0; i < ny; i++) {
        double py = pixel_y(ay, tick_value(ay, i, ny));
        put(b, "<line x1=\"%.2f\" y1=\"%.2f\" x2=\"%.2f\" y2=\"%.2f\"/>\n", PLOT_LEFT, py,
            PLOT_RIGHT, py);
    }
    put(b, "</g>\n");
    put(b,
        "<rect x=\"%.2f\" y=\"%.2f\" width=\"%.2f\" height=\"%.2f\" fill=\"none\" "
        "stroke=\"#333333\" stroke-width=\"1\"/>\n",
        PLOT_LEFT, PLOT_TOP, PLOT_RIGHT - PLOT_LEFT, PLOT_BOTTOM - PLOT_TOP);
    put(b, "<g font-size=\"11\" fill=\"#333333\" stroke=\"#333333\">\n");
    for (int i = 0; i < nx; i++) {
        double t = tick_value(ax, i, nx), px = pixel_x(ax, t);
        tick_label(ax, t, text);
        put(b, "<line x1=\"%.2f\" y1=\"%.2f\" x2=\"%.2f\" y2=\"%.2f\"/>\n", px, PLOT_BOTTOM, px,
            PLOT_BOTTOM + TICK_LENGTH);
        put(b, "<text x=\"%.2f\" y=\"%.2f\" text-anchor=\"middle\" stroke=\"none\">%s</text>\n", px,
            PLOT_BOTTOM + TICK_LENGTH + 13.0, text);
    }
    for (int i = 0; i < ny; i++) {
        double t = tick_value(ay, i, ny), py = pixel_y(ay, t);
        tick_label(ay, t, text);
        put(b, "<line x1=\"%.2f\" y1=\"%.2f\" x2=\"%.2f\" y2=\"%.2f\"/>\n", PLOT_LEFT - TICK_LENGTH,
            py, PLOT_LEFT, py);
        put(b, "<text x=\"%.2f\" y=\"%.2f\" text-anchor=\"end\" stroke=\"none\">%s</text>\n",
            PLOT_LEFT - TICK_LENGTH - 3.0, py + 4.0, text);
    }
    put(b, "</g>\n");
}

static void draw_titles(buffer_t *b, const bg_svg_plot_t *plot)
{
    const double mid_x = 0.5 * (PLOT_LEFT + PLOT_RIGHT), mid_y = 0.5 * (PLOT_TOP + PLOT_BOTTOM);
    if (plot->title) {
        put(b,
            "<text x=\"%.2f\" y=\"26\" text-anchor=\"middle\" font-size=\"15\" "
            "font-weight=\"bold\">",
            mid_x);
        put_escaped(b, plot->title, 0);
        put(b, "</text>\n");
    }
    if (plot->x_label) {
        put(b, "<text x=\"%.2f\" y=\"%.2f\" text-anchor=\"middle\" font-size=\"12\">", mid_x,
            PLOT_BOTTOM + 42.0);
        put_escaped(b, plot->x_label, 0);
        put(b, "</text>\n");
    }
    if (plot->y_label) {
        put(b,
            "<text x=\"22\" y=\"%.2f\" text-anchor=\"middle\" font-size=\"12\" "
            "transform=\"rotate(-90 22 %.2f)\">",
            mid_y, mid_y);
        put_escaped(b, plot->y_label, 0);
        put(b, "</text>\n");
    }
}

/* Draws one series as polylines over its runs of drawable points (a run
 * of a single point becomes a dot); returns the number of points drawn. */
static size_t draw_series(buffer_t *b, const bg_svg_series_t *s, const char *colour,
                          const axis_t *ax, const axis_t *ay)
{
    size_t drawn = 0, i = 0;
    while (i < s->count) {
        while (i < s->count && !(usable(ax, s->x[i]) && usable(ay, s->y[i])))
            i++;
        size_t start = i;
        while (i < s->count && usable(ax, s->x[i]) && usable(ay, s->y[i]))
            i++;
        if (i == start)
            continue;
        drawn += i - start;
        if (i - start == 1) {
            put(b, "<circle cx=\"%.2f\" cy=\"%.2f\" r=\"%.1f\" fill=\"%s\"/>\n",
                pixel_x(ax, to_axis(ax, s->x[start])), pixel_y(ay, to_axis(ay, s->y[start])),
                MARKER_RADIUS, colour);
            continue;
        }
        put(b,
            "<polyline fill=\"none\" stroke=\"%s\" stroke-width=\"1.8\" "
            "stroke-linejoin=\"round\" points=\"",
            colour);
        for (size_t k = start; k < i; k++)
            put(b, "%s%.2f,%.2f", k == start ? "" : " ", pixel_x(ax, to_axis(ax, s->x[k])),
                pixel_y(ay, to_axis(ay, s->y[k])));
        put(b, "\"/>\n");
    }
    return drawn;
}

static void draw_legend(buffer_t *b, const bg_svg_series_t *series, int count)
{
    put(b, "<g font-size=\"11\">\n");
    for (int k = 0; k < count; k++) {
        double y = LEGEND_Y + k * LEGEND_ROW;
        if (y > SVG_HEIGHT - LEGEND_ROW)
            break; /* more series than rows: the rest stay unlabelled */
        const char *colour = PALETTE[k % PALETTE_SIZE];
        put(b,
            "<line x1=\"%.2f\" y1=\"%.2f\" x2=\"%.2f\" y2=\"%.2f\" stroke=\"%s\" "
            "stroke-width=\"2.5\"/>\n",
            LEGEND_X, y, LEGEND_X + LEGEND_SWATCH, y, colour);
        put(b, "<text x=\"%.2f\" y=\"%.2f\">", LEGEND_X + LEGEND_SWATCH + 6.0, y + 4.0);
        if (series[k].label)
            put_escaped(b, series[k].label, LEGEND_LABEL_MAX);
        else
            put(b, "series %d", k + 1);
        put(b, "</text>\n");
    }
    put(b, "</g>\n");
}

/* Scans the drawable points for the data extremes on each axis. */
static void data_extent(const bg_svg_series_t *series, int count, axis_t *ax, axis_t *ay,
                        double *xlo, double *xhi, double *ylo, double *yhi)
{
    *xlo = *ylo = INFINITY;
    *xhi = *yhi = -INFINITY;
    for (int k = 0; k < count; k++)
        for (size_t i = 0; i < series[k].count; i++) {
            double x = series[k].x[i], y = series[k].y[i];
            if (!usable(ax, x) || !usable(ay, y))
                continue;
            double tx = to_axis(ax, x), ty = to_axis(ay, y);
            *xlo = fmin(*xlo, tx);
            *xhi = fmax(*xhi, tx);
            *ylo = fmin(*ylo, ty);
            *yhi = fmax(*yhi, ty);
            ax->has_data = ay->has_data = 1;
        }
}

bg_status bg_svg_render(const bg_svg_plot_t *plot, const bg_svg_series_t *series, int series_count,
                        char **svg, size_t *length, bg_error_t *err)
{
    *svg = NULL;
    if (length)
        *length = 0;
    static const bg_svg_plot_t empty_plot = {NULL, NULL, NULL, 0, 0};
    if (!plot)
        plot = &empty_plot;
    if (series_count < 0 || (series_count > 0 && !series))
        return bg_error_set(err, BG_ERR_INVALID, "svg: %d series given without data", series_count);
    for (int k = 0; k < series_count; k++)
        if (series[k].count > 0 && (!series[k].x || !series[k].y))
            return bg_error_set(err, BG_ERR_INVALID, "svg: series %d has %zu points but no arrays",
                                k + 1, series[k].count);
    axis_t ax = {plot->log_x != 0, 0, 0, 1, 0}, ay = {plot->log_y != 0, 0, 0, 1, 0};
    double xlo = 0, xhi = 0, ylo = 0, yhi = 0;
    data_extent(series, series_count, &ax, &ay, &xlo, &xhi, &ylo, &yhi);
    layout_axis(&ax, xlo, xhi);
    layout_axis(&ay, ylo, yhi);

    buffer_t b = {NULL, 0, 0, 0};
    put(&b,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"%d\" height=\"%d\" "
        "viewBox=\"0 0 %d %d\" font-family=\"%s\">\n",
        SVG_WIDTH, SVG_HEIGHT, SVG_WIDTH, SVG_HEIGHT, FONT_FAMILY);
    put(&b, "<rect width=\"100%%\" height=\"100%%\" fill=\"#ffffff\"/>\n");
    draw_titles(&b, plot);
    draw_axes(&b, &ax, &ay);
    size_t drawn = 0;
    for (int k = 0; k < series_count; k++)
        drawn += draw_series(&b, &series[k], PALETTE[k % PALETTE_SIZE], &ax, &ay);
    if (drawn == 0)
        put(&b,
            "<text x=\"%.2f\" y=\"%.2f\" text-anchor=\"middle\" font-size=\"16\" "
            "fill=\"#888888\">no data</text>\n",
            0.5 * (PLOT_LEFT + PLOT_RIGHT), 0.5 * (PLOT_TOP + PLOT_BOTTOM));
    draw_legend(&b, series, series_count);
    put(&b, "</svg>\n");
    if (b.failed) {
        free(b.data);
        return bg_error_set(err, BG_ERR_NOMEM, "svg: out of memory rendering the plot");
    }
    *svg = b.data;
    if (length)
        *length = b.length;
    return BG_OK;
}

bg_status bg_svg_write(const char *path, const bg_svg_plot_t *plot, const bg_svg_series_t *series,
                       int series_count, bg_error_t *err)
{
    char *svg = NULL;
    size_t length = 0;
    bg_status st = bg_svg_render(plot, series, series_count, &svg, &length, err);
    if (st != BG_OK)
        return st;
    FILE *f = fopen(path, "wb");
    if (!f) {
        st = bg_error_set(err, BG_ERR_IO, "%s: cannot open for writing: %s", path, strerror(errno));
        goto out;
    }
    size_t written = fwrite(svg, 1, length, f);
    int write_error = written != length || ferror(f);
    int saved = errno;
    if (fclose(f) != 0 && !write_error) {
        write_error = 1;
        saved = errno;
    }
    if (write_error)
        st = bg_error_set(err, BG_ERR_IO, "%s: write failed: %s", path, strerror(saved));
out:
    free(svg);
    return st;
}
