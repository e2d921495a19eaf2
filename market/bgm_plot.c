#include "bgm_plot.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

/* Canvas and plot area, in SVG user units. */
#define W 760.0
#define H 460.0
#define LEFT 80.0
#define RIGHT 170.0
#define TOP 60.0
#define BOTTOM 60.0
#define TICKS 5 /* about this many tick intervals per axis */
#define MARKER_RADIUS 3.5
#define BAND_OPACITY 0.18

static const char *const colours[BGM_PLOT_MAX_SERIES] = {"#1f77b4", "#d62728", "#2ca02c",
                                                         "#9467bd", "#ff7f0e", "#8c564b",
                                                         "#e377c2", "#7f7f7f"};

typedef struct range {
    double lo, hi;
} range_t;

static void widen(range_t *r, double v)
{
    if (!isfinite(v))
        return;
    if (v < r->lo)
        r->lo = v;
    if (v > r->hi)
        r->hi = v;
}

/* A step of 1, 2 or 5 times a power of ten near span / TICKS. */
static double nice_step(double span)
{
    double raw = span / TICKS, mag = pow(10.0, floor(log10(raw))), f = raw / mag;
    return (f <= 1.0 ? 1.0 : f <= 2.0 ? 2.0 : f <= 5.0 ? 5.0 : 10.0) * mag;
}

/* A degenerate or empty range gets some room so the axis still scales;
 * then both ends move out to whole steps, so ticks fall on round values. */
static void settle(range_t *r, double *step)
{
    if (!(r->lo <= r->hi)) {
        r->lo = 0.0;
        r->hi = 1.0;
    } else if (r->hi - r->lo < 1e-12 * (1.0 + fabs(r->hi))) {
        double pad = r->hi != 0.0 ? 0.1 * fabs(r->hi) : 1.0;
        r->lo -= pad;
        r->hi += pad;
    }
    *step = nice_step(r->hi - r->lo);
    r->lo = floor(r->lo / *step + 1e-9) * *step;
    r->hi = ceil(r->hi / *step - 1e-9) * *step;
}

static double px(const range_t *r, double v)
{
    return LEFT + (v - r->lo) / (r->hi - r->lo) * (W - LEFT - RIGHT);
}

static double py(const range_t *r, double v)
{
    return H - BOTTOM - (v - r->lo) / (r->hi - r->lo) * (H - TOP - BOTTOM);
}

/* Writes s with the XML specials escaped. */
static void put_text(FILE *f, const char *s)
{
    for (; s && *s; s++) {
        if (*s == '<')
            fputs("&lt;", f);
        else if (*s == '>')
            fputs("&gt;", f);
        else if (*s == '&')
            fputs("&amp;", f);
        else
            fputc(*s, f);
    }
}

static void axes(FILE *f, const bgm_plot_t *plot, const range_t *xr, double xstep,
                 const range_t *yr, double ystep)
{
    fprintf(f, "<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"none\" "
               "stroke=\"#444\"/>\n",
            LEFT, TOP, W - LEFT - RIGHT, H - TOP - BOTTOM);
    for (double vx = xr->lo; vx <= xr->hi + 1e-9 * xstep; vx += xstep)
        fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" font-size=\"11\" text-anchor=\"middle\">%.4g</text>\n",
                px(xr, vx), H - BOTTOM + 16.0, fabs(vx) < 1e-9 * xstep ? 0.0 : vx);
    for (double vy = yr->lo; vy <= yr->hi + 1e-9 * ystep; vy += ystep) {
        fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>\n", LEFT,
                py(yr, vy), W - RIGHT, py(yr, vy));
        fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" font-size=\"11\" text-anchor=\"end\">%.4g</text>\n",
                LEFT - 6.0, py(yr, vy) + 4.0, fabs(vy) < 1e-9 * ystep ? 0.0 : vy);
    }
    fputs("<text x=\"380\" y=\"24\" font-size=\"15\" text-anchor=\"middle\">", f);
    put_text(f, plot->title);
    fputs("</text>\n", f);
    if (plot->note) {
        fputs("<text x=\"380\" y=\"42\" font-size=\"11\" text-anchor=\"middle\" fill=\"#555\">", f);
        put_text(f, plot->note);
        fputs("</text>\n", f);
    }
    fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" font-size=\"12\" text-anchor=\"middle\">",
            (LEFT + W - RIGHT) / 2.0, H - 18.0);
    put_text(f, plot->x_label);
    fprintf(f, "</text>\n<text x=\"18\" y=\"%.1f\" font-size=\"12\" text-anchor=\"middle\" "
               "transform=\"rotate(-90 18 %.1f)\">",
            (TOP + H - BOTTOM) / 2.0, (TOP + H - BOTTOM) / 2.0);
    put_text(f, plot->y_label);
    fputs("</text>\n", f);
}

/* The band of one series: one polygon per run of points with both bounds. */
static void band(FILE *f, const bgm_plot_series_t *s, const char *colour, const range_t *xr,
                 const range_t *yr)
{
    size_t i = 0;
    while (i < s->count) {
        size_t j = i;
        while (j < s->count && isfinite(s->x[j]) && isfinite(s->lo[j]) && isfinite(s->hi[j]))
            j++;
        if (j > i) {
            fprintf(f, "<polygon fill=\"%s\" fill-opacity=\"%.2f\" stroke=\"none\" points=\"",
                    colour, BAND_OPACITY);
            for (size_t k = i; k < j; k++)
                fprintf(f, "%.1f,%.1f ", px(xr, s->x[k]), py(yr, s->hi[k]));
            for (size_t k = j; k > i; k--)
                fprintf(f, "%.1f,%.1f ", px(xr, s->x[k - 1]), py(yr, s->lo[k - 1]));
            fputs("\"/>\n", f);
        }
        i = j + 1;
    }
}

static void line_and_markers(FILE *f, const bgm_plot_series_t *s, const char *colour,
                             const range_t *xr, const range_t *yr)
{
    int open = 0;
    for (size_t k = 0; k < s->count; k++) {
        int ok = isfinite(s->x[k]) && isfinite(s->y[k]);
        if (ok && !open) {
            fprintf(f, "<polyline fill=\"none\" stroke=\"%s\" stroke-width=\"2\" points=\"", colour);
            open = 1;
        } else if (!ok && open) {
            fputs("\"/>\n", f);
            open = 0;
        }
        if (ok)
            fprintf(f, "%.1f,%.1f ", px(xr, s->x[k]), py(yr, s->y[k]));
    }
    if (open)
        fputs("\"/>\n", f);
    for (size_t k = 0; k < s->count; k++)
        if (isfinite(s->x[k]) && isfinite(s->y[k]))
            fprintf(f, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%.1f\" fill=\"%s\"/>\n", px(xr, s->x[k]),
                    py(yr, s->y[k]), MARKER_RADIUS, colour);
}

bg_status bgm_plot_write(const char *path, const bgm_plot_t *plot, const bgm_plot_series_t *series,
                         int count, bg_error_t *err)
{
    if (count < 0 || count > BGM_PLOT_MAX_SERIES)
        return bg_error_set(err, BG_ERR_INVALID, "%s: %d series, at most %d", path, count,
                            BGM_PLOT_MAX_SERIES);
    range_t xr = {INFINITY, -INFINITY}, yr = {INFINITY, -INFINITY};
    for (int i = 0; i < count; i++)
        for (size_t k = 0; k < series[i].count; k++) {
            if (!isfinite(series[i].x[k]) || !isfinite(series[i].y[k]))
                continue;
            widen(&xr, series[i].x[k]);
            widen(&yr, series[i].y[k]);
            if (series[i].lo && series[i].hi) {
                widen(&yr, series[i].lo[k]);
                widen(&yr, series[i].hi[k]);
            }
        }
    double xstep = 1.0, ystep = 1.0;
    settle(&xr, &xstep);
    settle(&yr, &ystep);
    FILE *f = fopen(path, "w");
    if (!f)
        return bg_error_set(err, BG_ERR_IO, "%s: cannot open for writing: %s", path,
                            strerror(errno));
    fprintf(f, "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
               "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\">\n"
               "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n",
            W, H, W, H);
    axes(f, plot, &xr, xstep, &yr, ystep);
    for (int i = 0; i < count; i++)
        if (series[i].lo && series[i].hi)
            band(f, &series[i], colours[i], &xr, &yr);
    for (int i = 0; i < count; i++) {
        line_and_markers(f, &series[i], colours[i], &xr, &yr);
        double ly = TOP + 14.0 + 20.0 * i;
        fprintf(f, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%.1f\" fill=\"%s\"/>\n", W - RIGHT + 18.0,
                ly - 4.0, MARKER_RADIUS, colours[i]);
        fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" font-size=\"12\">", W - RIGHT + 28.0, ly);
        put_text(f, series[i].label);
        fputs("</text>\n", f);
    }
    fputs("</svg>\n", f);
    int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        return bg_error_set(err, BG_ERR_IO, "%s: write failed", path);
    return BG_OK;
}
