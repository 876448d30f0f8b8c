//! The SVG figures of the run reports, the campaign report and the generated results pages,
//! drawn with `plotters` (SVG backend, no font rendering: the SVG carries
//! `<text>` elements the browser lays out).
//!
//! A [`Figure`] is one chart: line, point, band, bar and disc layers, its title above, the
//! legend in a strip reserved right of the chart (never on the curves), and tick counts chosen
//! so that no two tick labels overlap (label widths estimated as [`CHAR_W`] times the font
//! size per character). With [`Figure::equal_scale`] the ranges are widened so that a metre
//! takes as many pixels in x as in y (top views), and the plot height follows the aspect of
//! the data within [`MIN_PLOT_H`]..[`MAX_PLOT_H`].
//!
//! The root `<svg>` of every figure carries its plotting area and ranges as data attributes:
//! `data-plot-px="x0 x1 y0 y1"` (pixels of the plotting area; y0 is the top),
//! `data-x-range="lo hi"`, `data-y-range="lo hi"` and `data-equal-scale="true|false"`. The
//! geometry checks of the tests ([`svg_texts`], [`overlapping_texts`], [`plot_geometry`],
//! [`tick_scales`]) read them and the tick labels back from the SVG text. Rendering is a pure
//! function of the figure (byte-identical output for identical input).

use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Width of every figure, px.
pub const FIG_W: u32 = 960;
/// Smallest plotting-area height of an equal-scale figure, px.
pub const MIN_PLOT_H: f64 = 220.0;
/// Largest plotting-area height of an equal-scale figure, px.
pub const MAX_PLOT_H: f64 = 620.0;
/// Estimated width of one character as a fraction of the font size (sans-serif digits and
/// lower case are about 0.5-0.55 em; the checks use this larger figure).
pub const CHAR_W: f64 = 0.6;
/// Font size of the title, SVG px.
const TITLE_PX: f64 = 15.0;
/// Font size of the tick labels, SVG px.
const TICK_PX: f64 = 11.0;
/// Font size of the axis descriptions, SVG px.
const DESC_PX: f64 = 12.0;
/// Font size of the legend, SVG px.
const LEGEND_PX: f64 = 12.0;
/// Vertical distance of legend entries, px.
const LEGEND_STEP: i32 = 18;
/// Height of the x label area (tick labels and the axis description), px.
const X_LABEL_AREA: u32 = 46;
/// Margins of the chart inside its area, px.
const MARGIN_TOP: u32 = 10;
const MARGIN_RIGHT: u32 = 14;
const MARGIN_LEFT: u32 = 6;
const MARGIN_BOTTOM: u32 = 4;
/// Smallest legend strip, px (a common width keeps the time axes of a page aligned).
const MIN_LEGEND_W: f64 = 230.0;
/// Smallest y label area, px (same reason).
const MIN_Y_LABEL_AREA: f64 = 66.0;
/// Height of the title strip (plotters' estimate of the title height plus its padding), px.
const TITLE_H: u32 = 24;
/// Largest number of points drawn per line (longer lines are decimated by a fixed stride).
const MAX_LINE_POINTS: usize = 2500;

/// Line style of a [`Mark::Line`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stroke {
    /// Continuous.
    Solid,
    /// 6 px dashes, 4 px gaps.
    Dashed,
    /// 2 px dashes, 3 px gaps.
    Dotted,
}

/// What a layer draws, in data units.
#[derive(Debug, Clone, PartialEq)]
pub enum Mark {
    /// A polyline.
    Line {
        /// Points `(x, y)`.
        points: Vec<(f64, f64)>,
        /// Stroke width, px.
        width: u32,
        /// Line style.
        stroke: Stroke,
    },
    /// Filled circles of a fixed pixel radius.
    Points {
        /// Points `(x, y)`.
        points: Vec<(f64, f64)>,
        /// Radius, px.
        radius: u32,
    },
    /// A filled band between `lo` and `hi` over `x` (for example the +-3 sigma bounds).
    Band {
        /// Abscissae.
        x: Vec<f64>,
        /// Lower edge at each abscissa.
        lo: Vec<f64>,
        /// Upper edge at each abscissa.
        hi: Vec<f64>,
    },
    /// Filled rectangles `[x0, x1, y0, y1]`.
    Bars(Vec<[f64; 4]>),
    /// Filled circles `(x, y, radius)` with the radius in data units (rocks in a top view;
    /// scaled by the x axis). Context only: they do not widen the ranges, and only the circles
    /// wholly inside the ranges are drawn.
    Discs(Vec<(f64, f64, f64)>),
}

/// One layer of a figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Layer {
    /// Legend text (`None`: not in the legend).
    pub name: Option<String>,
    /// Colour.
    pub color: RGBColor,
    /// What to draw.
    pub mark: Mark,
}

impl Layer {
    /// A named line.
    pub fn line(name: &str, color: RGBColor, stroke: Stroke, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: Some(name.to_string()),
            color,
            mark: Mark::Line {
                points,
                width: if stroke == Stroke::Solid { 2 } else { 1 },
                stroke,
            },
        }
    }

    /// Named points.
    pub fn points(name: &str, color: RGBColor, radius: u32, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: Some(name.to_string()),
            color,
            mark: Mark::Points { points, radius },
        }
    }
}

/// How the y tick labels read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum YLabels {
    /// The value.
    Plain,
    /// Minus the value (a top view with north to the right plots minus east upwards, so the
    /// labels read east, increasing downwards).
    Negated,
    /// Ten to the value (the data are decimal logarithms; integer ticks only).
    Pow10,
}

/// One chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Title above the chart.
    pub title: String,
    /// x axis description.
    pub x_desc: String,
    /// y axis description.
    pub y_desc: String,
    /// Layers, drawn in order (bands, bars and discs first, then lines, then points).
    pub layers: Vec<Layer>,
    /// Equal metres per pixel in x and y.
    pub equal_scale: bool,
    /// y tick labels.
    pub y_labels: YLabels,
    /// Height of the plotting area, px (equal-scale figures choose theirs from the data).
    pub plot_height: u32,
    /// y values the range must include (for example 0).
    pub y_include: Vec<f64>,
}

impl Figure {
    /// A time-series figure (`x` is time in s) with the plotting area `plot_height` px high.
    pub fn new(title: &str, x_desc: &str, y_desc: &str, plot_height: u32) -> Self {
        Self {
            title: title.to_string(),
            x_desc: x_desc.to_string(),
            y_desc: y_desc.to_string(),
            layers: Vec::new(),
            equal_scale: false,
            y_labels: YLabels::Plain,
            plot_height,
            y_include: Vec::new(),
        }
    }
}

fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("plot: {e:?}")
}

/// A text style of `px` SVG pixels (plotters writes `size / 1.24` into the SVG).
fn font(px: f64) -> TextStyle<'static> {
    TextStyle::from(("sans-serif", px * 1.24).into_font())
}

/// Estimated width of `text` at `px`, px.
fn text_w(text: &str, px: f64) -> f64 {
    CHAR_W * px * text.chars().count() as f64
}

/// `v` with `decimals` decimals, without a minus sign on zero.
fn fmt_fixed(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Decimals that show a tick step exactly (steps are 1, 2 or 5 times a power of ten).
fn decimals_for_step(step: f64) -> usize {
    if !(step.is_finite() && step > 0.0) {
        return 0;
    }
    let d = (-(step.log10()) - 1e-9).ceil();
    d.clamp(0.0, 9.0) as usize
}

/// Ticks of `lo..hi` with at most `n` points, as plotters computes them for `x_labels(n)`.
fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    RangedCoordf64::from(lo..hi).key_points(n)
}

/// Tick labels of `ticks`.
fn labels(ticks: &[f64], kind: YLabels) -> Vec<String> {
    let step = ticks
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(f64::INFINITY, f64::min);
    let dec = decimals_for_step(step);
    ticks.iter().map(|&v| label(v, kind, dec)).collect()
}

fn label(v: f64, kind: YLabels, dec: usize) -> String {
    match kind {
        YLabels::Plain => fmt_fixed(v, dec),
        YLabels::Negated => fmt_fixed(-v, dec),
        YLabels::Pow10 => {
            let e = v.round();
            if e >= 0.0 {
                format!("{:.0}", 10f64.powf(e))
            } else {
                fmt_fixed(10f64.powf(e), (-e) as usize)
            }
        }
    }
}

/// The largest tick count `<= 24` whose labels fit along `len_px` with `gap_px` between
/// neighbours; `along_width`: the labels are laid out along their width (x axis), otherwise
/// along their height (y axis). Pow10 axes take integer steps only.
fn tick_count(lo: f64, hi: f64, len_px: f64, kind: YLabels, along_width: bool) -> usize {
    let span = (hi - lo).abs().max(f64::MIN_POSITIVE);
    for n in (2..=24).rev() {
        let t = ticks(lo, hi, n);
        if t.len() < 2 {
            return n;
        }
        let step = t
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(f64::INFINITY, f64::min);
        if kind == YLabels::Pow10 && (step < 0.999 || (t[0] - t[0].round()).abs() > 1e-9) {
            continue;
        }
        let spacing = step / span * len_px;
        let need = if along_width {
            labels(&t, kind)
                .iter()
                .map(|l| text_w(l, TICK_PX))
                .fold(0.0, f64::max)
                + 12.0
        } else {
            TICK_PX * 1.8
        };
        if spacing >= need {
            return n;
        }
    }
    2
}

/// Width of the y label area for the ticks of `lo..hi` along `len_px`.
fn y_label_area(lo: f64, hi: f64, len_px: f64, kind: YLabels) -> u32 {
    let n = tick_count(lo, hi, len_px, kind, false);
    let widest = labels(&ticks(lo, hi, n), kind)
        .iter()
        .map(|l| text_w(l, TICK_PX))
        .fold(0.0, f64::max);
    // Axis description (rotated) + gap + labels + plotters' label distance (2 x tick size).
    (DESC_PX + 8.0 + widest + 10.0 + 6.0)
        .max(MIN_Y_LABEL_AREA)
        .ceil() as u32
}

/// Every finite data coordinate of `layers` (discs left out: they are context).
fn data_points(layers: &[Layer]) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    for l in layers {
        match &l.mark {
            Mark::Line { points, .. } | Mark::Points { points, .. } => {
                out.extend(points.iter().copied())
            }
            Mark::Band { x, lo, hi } => {
                for ((&x, &a), &b) in x.iter().zip(lo).zip(hi) {
                    out.push((x, a));
                    out.push((x, b));
                }
            }
            Mark::Bars(r) => {
                for b in r {
                    out.push((b[0], b[2]));
                    out.push((b[1], b[3]));
                }
            }
            // Context (rocks): drawn where they fall inside the range of the other layers,
            // never widening it.
            Mark::Discs(_) => {}
        }
    }
    out.retain(|p| p.0.is_finite() && p.1.is_finite());
    out
}

/// `(x_lo, x_hi, y_lo, y_hi)` of the data with margins, never empty.
fn data_bounds(fig: &Figure) -> (f64, f64, f64, f64) {
    let pts = data_points(&fig.layers);
    let mut b = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in &pts {
        b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
    }
    for &y in fig.y_include.iter().filter(|y| y.is_finite()) {
        b = (b.0, b.1, b.2.min(y), b.3.max(y));
    }
    if !b.0.is_finite() {
        b.0 = 0.0;
        b.1 = 1.0;
    }
    if !b.2.is_finite() {
        b.2 = 0.0;
        b.3 = 1.0;
    }
    let widen = |lo: f64, hi: f64, frac: f64| {
        let span = hi - lo;
        if span < 1e-12 {
            let d = (lo.abs() * 0.1).max(0.5);
            (lo - d, hi + d)
        } else {
            (lo - frac * span, hi + frac * span)
        }
    };
    let x_pad = if fig.equal_scale { 0.04 } else { 0.0 };
    let (x0, x1) = widen(b.0, b.1, x_pad);
    let (y0, y1) = widen(b.2, b.3, if fig.equal_scale { 0.04 } else { 0.06 });
    (x0, x1, y0, y1)
}

/// Every `k`-th point so that at most [`MAX_LINE_POINTS`] remain (the last point kept).
fn decimate(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let step = points.len().div_ceil(MAX_LINE_POINTS).max(1);
    let mut out: Vec<_> = points.iter().copied().step_by(step).collect();
    if let (Some(&last), Some(&kept)) = (points.last(), out.last()) {
        if last != kept {
            out.push(last);
        }
    }
    out
}

/// Legend entries: `(name, colour, mark)`.
fn legend_entries(fig: &Figure) -> Vec<(&str, RGBColor, &Mark)> {
    fig.layers
        .iter()
        .filter_map(|l| l.name.as_deref().map(|n| (n, l.color, &l.mark)))
        .collect()
}

/// Width of the legend strip, px.
fn legend_width(fig: &Figure) -> u32 {
    let widest = legend_entries(fig)
        .iter()
        .map(|e| text_w(e.0, LEGEND_PX))
        .fold(0.0, f64::max);
    (widest + 64.0).max(MIN_LEGEND_W).ceil() as u32
}

/// A chart of a figure: `f64` coordinates on an SVG drawing area.
type Chart<'a, 'b> = ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A chart with its final x and y ranges.
type SettledChart<'a, 'b> = (Chart<'a, 'b>, (f64, f64), (f64, f64));

/// The chart of `area` over the ranges `x`, `y` with a y label area of `ylab` pixels.
fn build_chart<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    x: (f64, f64),
    y: (f64, f64),
    ylab: u32,
) -> anyhow::Result<Chart<'a, 'b>> {
    ChartBuilder::on(area)
        .margin_top(MARGIN_TOP)
        .margin_right(MARGIN_RIGHT)
        .margin_left(MARGIN_LEFT)
        .margin_bottom(MARGIN_BOTTOM)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(ylab)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(plot_err)
}

/// Width and height of the plotting area of `chart`, px.
fn plot_size(chart: &Chart) -> (f64, f64) {
    let (px, py) = chart.plotting_area().get_pixel_range();
    (f64::from(px.end - px.start), f64::from(py.end - py.start))
}

/// The ranges of an equal-scale chart of the data bounds `b` on a plotting area of `pw` x `ph`
/// pixels: centred on the data, a metre as many pixels in x as in y.
fn equal_scale_ranges(b: (f64, f64, f64, f64), pw: f64, ph: f64) -> ((f64, f64), (f64, f64)) {
    let (bx0, bx1, by0, by1) = b;
    let s = ((bx1 - bx0) / pw).max((by1 - by0) / ph);
    let (cx, cy) = (0.5 * (bx0 + bx1), 0.5 * (by0 + by1));
    (
        (cx - 0.5 * s * pw, cx + 0.5 * s * pw),
        (cy - 0.5 * s * ph, cy + 0.5 * s * ph),
    )
}

/// The chart of `fig` on `area` with its final ranges and y label area.
///
/// Building a chart draws nothing (no caption): build, read the plotting area, adjust the
/// ranges and the y label area, build again.
fn settled_chart<'a, 'b>(
    fig: &Figure,
    area: &'a DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
    bounds: (f64, f64, f64, f64),
    ylab: u32,
) -> anyhow::Result<SettledChart<'a, 'b>> {
    let (bx0, bx1, by0, by1) = bounds;
    let mut ylab = ylab;
    let (mut xr, mut yr) = ((bx0, bx1), (by0, by1));
    let mut chart = build_chart(area, xr, yr, ylab)?;
    for _ in 0..4 {
        let (pw, ph) = plot_size(&chart);
        if fig.equal_scale {
            (xr, yr) = equal_scale_ranges(bounds, pw, ph);
        }
        let need = y_label_area(yr.0, yr.1, ph, fig.y_labels);
        let stable = need == ylab;
        ylab = need;
        chart = build_chart(area, xr, yr, ylab)?;
        if stable && !fig.equal_scale {
            break;
        }
        if stable {
            // Ranges of an equal-scale chart depend on its plotting area: one more pass
            // with the final label area settles them.
            let (pw, ph) = plot_size(&chart);
            (xr, yr) = equal_scale_ranges(bounds, pw, ph);
            chart = build_chart(area, xr, yr, ylab)?;
            break;
        }
    }
    Ok((chart, xr, yr))
}

/// The plotting area's background, the grid, the ticks and their labels, the axis titles.
fn draw_mesh(
    chart: &mut Chart,
    fig: &Figure,
    xr: (f64, f64),
    yr: (f64, f64),
) -> anyhow::Result<()> {
    let (pw, ph) = plot_size(chart);
    let y_kind = fig.y_labels;
    let nx = tick_count(xr.0, xr.1, pw, YLabels::Plain, true);
    let ny = tick_count(yr.0, yr.1, ph, y_kind, false);
    let x_dec = decimals_for_step(step_of(&ticks(xr.0, xr.1, nx)));
    let y_dec = decimals_for_step(step_of(&ticks(yr.0, yr.1, ny)));
    let x_fmt = move |v: &f64| label(*v, YLabels::Plain, x_dec);
    let y_fmt = move |v: &f64| label(*v, y_kind, y_dec);
    chart
        .plotting_area()
        .fill(&RGBColor(252, 252, 252))
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_labels(nx)
        .y_labels(ny)
        .max_light_lines(4)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .x_desc(fig.x_desc.as_str())
        .y_desc(fig.y_desc.as_str())
        .label_style(font(TICK_PX))
        .axis_desc_style(font(DESC_PX))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(240, 240, 240))
        .axis_style(RGBColor(90, 90, 90))
        .draw()
        .map_err(plot_err)?;
    Ok(())
}

/// The layers of `fig`: areas first (pass 0), then lines (1), then points (2).
fn draw_layers(
    chart: &mut Chart,
    fig: &Figure,
    xr: (f64, f64),
    yr: (f64, f64),
) -> anyhow::Result<()> {
    let (pw, _) = plot_size(chart);
    let mpp_x = (xr.1 - xr.0) / pw;
    for pass in 0..3 {
        for l in &fig.layers {
            let c = l.color;
            match (&l.mark, pass) {
                (Mark::Discs(d), 0) => {
                    let inside = |&&(x, y, r): &&(f64, f64, f64)| {
                        x - r >= xr.0 && x + r <= xr.1 && y - r >= yr.0 && y + r <= yr.1
                    };
                    chart
                        .draw_series(d.iter().filter(inside).map(|&(x, y, r)| {
                            let rp = (r / mpp_x).round().max(1.0) as i32;
                            Circle::new((x, y), rp, c.mix(0.55).filled())
                        }))
                        .map_err(plot_err)?;
                }
                (Mark::Band { x, lo, hi }, 0) => {
                    let mut poly: Vec<(f64, f64)> =
                        x.iter().copied().zip(hi.iter().copied()).collect();
                    poly.extend(x.iter().copied().zip(lo.iter().copied()).rev());
                    poly.retain(|p| p.0.is_finite() && p.1.is_finite());
                    let poly = decimate(&poly);
                    chart
                        .draw_series(std::iter::once(Polygon::new(poly, c.mix(0.22).filled())))
                        .map_err(plot_err)?;
                }
                (Mark::Bars(r), 0) => {
                    chart
                        .draw_series(
                            r.iter()
                                .map(|b| Rectangle::new([(b[0], b[2]), (b[1], b[3])], c.filled())),
                        )
                        .map_err(plot_err)?;
                }
                (
                    Mark::Line {
                        points,
                        width,
                        stroke,
                    },
                    1,
                ) => draw_line(chart, points, c.stroke_width(*width), *stroke)?,
                (Mark::Points { points, radius }, 2) => {
                    chart
                        .draw_series(
                            points
                                .iter()
                                .filter(|p| p.0.is_finite() && p.1.is_finite())
                                .map(|&p| Circle::new(p, *radius, c.filled())),
                        )
                        .map_err(plot_err)?;
                }
                _ => {}
            }
        }
    }
    Ok(())
}

/// One line layer (decimated) with its stroke.
fn draw_line(
    chart: &mut Chart,
    points: &[(f64, f64)],
    style: ShapeStyle,
    stroke: Stroke,
) -> anyhow::Result<()> {
    let pts = decimate(points);
    match stroke {
        Stroke::Solid => {
            chart
                .draw_series(LineSeries::new(pts, style))
                .map_err(plot_err)?;
        }
        Stroke::Dashed => {
            chart
                .draw_series(DashedLineSeries::new(pts, 6, 4, style))
                .map_err(plot_err)?;
        }
        Stroke::Dotted => {
            chart
                .draw_series(DashedLineSeries::new(pts, 2, 3, style))
                .map_err(plot_err)?;
        }
    }
    Ok(())
}

/// The legend in its own strip, its first entry `top` pixels below the strip's top.
fn draw_legend(
    legend_area: &DrawingArea<SVGBackend, plotters::coord::Shift>,
    fig: &Figure,
    top: i32,
) -> anyhow::Result<()> {
    for (k, (name, c, mark)) in legend_entries(fig).into_iter().enumerate() {
        let y = top + LEGEND_STEP * k as i32;
        let (x0, x1) = (10, 40);
        match mark {
            Mark::Line { width, stroke, .. } => {
                let style = c.stroke_width(*width);
                let segments: Vec<(i32, i32)> = match stroke {
                    Stroke::Solid => vec![(x0, x1)],
                    Stroke::Dashed => {
                        vec![(x0, x0 + 6), (x0 + 10, x0 + 16), (x0 + 20, x0 + 26)]
                    }
                    Stroke::Dotted => (0..6).map(|i| (x0 + 5 * i, x0 + 5 * i + 2)).collect(),
                };
                for (a, b) in segments {
                    legend_area
                        .draw(&PathElement::new(vec![(a, y), (b, y)], style))
                        .map_err(plot_err)?;
                }
            }
            Mark::Points { radius, .. } => {
                legend_area
                    .draw(&Circle::new((25, y), (*radius).max(3), c.filled()))
                    .map_err(plot_err)?;
            }
            Mark::Band { .. } | Mark::Discs(_) => {
                legend_area
                    .draw(&Rectangle::new(
                        [(x0, y - 5), (x1, y + 5)],
                        c.mix(0.3).filled(),
                    ))
                    .map_err(plot_err)?;
            }
            Mark::Bars(_) => {
                legend_area
                    .draw(&Rectangle::new([(x0, y - 5), (x1, y + 5)], c.filled()))
                    .map_err(plot_err)?;
            }
        }
        let style = font(LEGEND_PX).pos(Pos::new(HPos::Left, VPos::Center));
        legend_area
            .draw(&Text::new(name.to_string(), (x1 + 8, y), style))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// The SVG text of `fig`.
pub fn render(fig: &Figure) -> anyhow::Result<String> {
    let bounds = data_bounds(fig);
    let (bx0, bx1, by0, by1) = bounds;
    let legend_w = legend_width(fig);
    let chart_w = FIG_W - legend_w;
    let legend_h = legend_entries(fig).len() as f64 * LEGEND_STEP as f64 + 12.0;
    // Plotting-area height: equal-scale figures follow the aspect of the data.
    let ylab = y_label_area(by0, by1, fig.plot_height as f64, fig.y_labels);
    let pw_est = f64::from(chart_w - MARGIN_LEFT - MARGIN_RIGHT) - f64::from(ylab);
    let ph = if fig.equal_scale {
        (pw_est * (by1 - by0) / (bx1 - bx0)).clamp(MIN_PLOT_H, MAX_PLOT_H)
    } else {
        f64::from(fig.plot_height)
    }
    .max(legend_h);
    let height = TITLE_H + MARGIN_TOP + MARGIN_BOTTOM + X_LABEL_AREA + ph.round() as u32;
    let mut text = String::new();
    let geometry;
    {
        let root = SVGBackend::with_string(&mut text, (FIG_W, height)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let body = root.titled(&fig.title, font(TITLE_PX)).map_err(plot_err)?;
        let (chart_area, legend_area) = body.split_horizontally(chart_w);
        let (mut chart, xr, yr) = settled_chart(fig, &chart_area, bounds, ylab)?;
        let (px, py) = chart.plotting_area().get_pixel_range();
        geometry = (px.clone(), py.clone(), xr, yr);
        draw_mesh(&mut chart, fig, xr, yr)?;
        draw_layers(&mut chart, fig, xr, yr)?;
        // Legend in its own strip, aligned with the top of the plotting area.
        let (_, lpy) = legend_area.get_pixel_range();
        draw_legend(&legend_area, fig, py.start - lpy.start + 8)?;
        root.present().map_err(plot_err)?;
    }
    let (px, py, xr, yr) = geometry;
    let attrs = format!(
        "<svg data-plot-px=\"{} {} {} {}\" data-x-range=\"{} {}\" data-y-range=\"{} {}\" \
         data-equal-scale=\"{}\" ",
        px.start, px.end, py.start, py.end, xr.0, xr.1, yr.0, yr.1, fig.equal_scale
    );
    Ok(text.replacen("<svg ", &attrs, 1))
}

fn step_of(t: &[f64]) -> f64 {
    t.windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(f64::INFINITY, f64::min)
}

/// One `<text>` of an SVG with its estimated bounding box (px, SVG coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct TextBox {
    /// The text.
    pub text: String,
    /// Anchor point `x`, `y` as written.
    pub anchor: (f64, f64),
    /// `text-anchor` (`start`, `middle`, `end`).
    pub h_anchor: String,
    /// Font size, px.
    pub font_px: f64,
    /// Rotation, degrees (0 when none).
    pub rotation_deg: f64,
    /// Bounding box `[x0, y0, x1, y1]`: width [`CHAR_W`] x font size x characters, height one
    /// font size placed by the SVG `dy` of plotters' vertical anchors.
    pub bbox: [f64; 4],
}

/// The `<svg>...</svg>` elements of an HTML page, in order.
pub fn svg_elements(html: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(a) = rest.find("<svg") {
        let Some(b) = rest[a..].find("</svg>") else {
            break;
        };
        out.push(&rest[a..a + b + 6]);
        rest = &rest[a + b + 6..];
    }
    out
}

/// Attribute `name` of the tag text `tag` (between `<` and `>`).
fn attr<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let a = tag.find(&key)? + key.len();
    let b = tag[a..].find('"')?;
    Some(&tag[a..a + b])
}

fn unescape(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}

/// Every `<text>` of `svg` with its estimated bounding box.
pub fn svg_texts(svg: &str) -> Vec<TextBox> {
    let mut out = Vec::new();
    let mut rest = svg;
    while let Some(a) = rest.find("<text") {
        let Some(close) = rest[a..].find('>') else {
            break;
        };
        let tag = &rest[a..a + close];
        let body_start = a + close + 1;
        let Some(end) = rest[body_start..].find("</text>") else {
            break;
        };
        let text = unescape(rest[body_start..body_start + end].trim());
        rest = &rest[body_start + end..];
        let num = |n: &str| attr(tag, n).and_then(|v| v.trim().parse::<f64>().ok());
        let (x, y) = (num("x").unwrap_or(0.0), num("y").unwrap_or(0.0));
        let fs = num("font-size").unwrap_or(16.0);
        let h_anchor = attr(tag, "text-anchor").unwrap_or("start").to_string();
        let w = text_w(&text, fs);
        let (bx0, bx1) = match h_anchor.as_str() {
            "middle" => (x - 0.5 * w, x + 0.5 * w),
            "end" => (x - w, x),
            _ => (x, x + w),
        };
        let (by0, by1) = match attr(tag, "dy") {
            Some("0.76em") => (y, y + fs),
            Some("0.5ex") => (y - 0.5 * fs, y + 0.5 * fs),
            Some("-0.5ex") => (y - fs, y),
            _ => (y - 0.8 * fs, y + 0.2 * fs),
        };
        // rotate(a, cx, cy) or rotate(a cx cy)
        let rotation = attr(tag, "transform")
            .and_then(|t| t.strip_prefix("rotate("))
            .and_then(|t| t.strip_suffix(')'))
            .map(|t| {
                t.split([',', ' '])
                    .filter(|s| !s.is_empty())
                    .filter_map(|s| s.parse::<f64>().ok())
                    .collect::<Vec<_>>()
            });
        let (mut bbox, mut rot) = ([bx0, by0, bx1, by1], 0.0);
        if let Some(r) = rotation.filter(|r| !r.is_empty()) {
            let (deg, cx, cy) = (r[0], *r.get(1).unwrap_or(&0.0), *r.get(2).unwrap_or(&0.0));
            let (s, c) = deg.to_radians().sin_cos();
            let mut b = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            for (px, py) in [(bx0, by0), (bx1, by0), (bx0, by1), (bx1, by1)] {
                let (dx, dy) = (px - cx, py - cy);
                let (qx, qy) = (cx + c * dx - s * dy, cy + s * dx + c * dy);
                b = [b[0].min(qx), b[1].min(qy), b[2].max(qx), b[3].max(qy)];
            }
            bbox = b;
            rot = deg;
        }
        if !text.is_empty() {
            out.push(TextBox {
                text,
                anchor: (x, y),
                h_anchor,
                font_px: fs,
                rotation_deg: rot,
                bbox,
            });
        }
    }
    out
}

/// Pairs of texts of `svg` whose estimated boxes overlap (by more than 0.5 px both ways).
pub fn overlapping_texts(svg: &str) -> Vec<(TextBox, TextBox)> {
    let t = svg_texts(svg);
    let mut out = Vec::new();
    for (i, a) in t.iter().enumerate() {
        for b in &t[i + 1..] {
            let ox = a.bbox[2].min(b.bbox[2]) - a.bbox[0].max(b.bbox[0]);
            let oy = a.bbox[3].min(b.bbox[3]) - a.bbox[1].max(b.bbox[1]);
            if ox > 0.5 && oy > 0.5 {
                out.push((a.clone(), b.clone()));
            }
        }
    }
    out
}

/// The plotting area and ranges a figure declares in its data attributes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotGeometry {
    /// Pixels of the plotting area `[x0, x1, y0, y1]` (y0 the top).
    pub plot_px: [f64; 4],
    /// x range `[lo, hi]`.
    pub x_range: [f64; 2],
    /// y range `[lo, hi]`.
    pub y_range: [f64; 2],
    /// The figure declares equal scales.
    pub equal_scale: bool,
}

impl PlotGeometry {
    /// Data units per pixel in x and y.
    pub fn units_per_px(&self) -> (f64, f64) {
        (
            (self.x_range[1] - self.x_range[0]) / (self.plot_px[1] - self.plot_px[0]),
            (self.y_range[1] - self.y_range[0]) / (self.plot_px[3] - self.plot_px[2]),
        )
    }
}

/// The geometry of the figure `svg` (its root's data attributes).
pub fn plot_geometry(svg: &str) -> Option<PlotGeometry> {
    let root = &svg[..svg.find('>')?];
    let nums = |name: &str| -> Option<Vec<f64>> {
        attr(root, name)?
            .split_whitespace()
            .map(|s| s.parse().ok())
            .collect()
    };
    let p = nums("data-plot-px")?;
    let x = nums("data-x-range")?;
    let y = nums("data-y-range")?;
    Some(PlotGeometry {
        plot_px: [*p.first()?, *p.get(1)?, *p.get(2)?, *p.get(3)?],
        x_range: [*x.first()?, *x.get(1)?],
        y_range: [*y.first()?, *y.get(1)?],
        equal_scale: attr(root, "data-equal-scale") == Some("true"),
    })
}

/// Pixels per unit along x and y measured from the tick labels of `svg`: the x tick labels
/// (numbers centred below the plotting area) and the y tick labels (numbers right-aligned
/// left of it), least-squares fits of pixel position against the label's value. `None` when
/// an axis has fewer than 3 numeric labels.
pub fn tick_scales(svg: &str) -> Option<(f64, f64)> {
    let g = plot_geometry(svg)?;
    let texts = svg_texts(svg);
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for t in &texts {
        let Ok(v) = t.text.parse::<f64>() else {
            continue;
        };
        if t.rotation_deg != 0.0 {
            continue;
        }
        if t.h_anchor == "middle" && t.anchor.1 > g.plot_px[3] {
            xs.push((v, t.anchor.0));
        } else if t.h_anchor == "end" && t.anchor.0 < g.plot_px[0] {
            ys.push((v, t.anchor.1));
        }
    }
    let slope = |p: &[(f64, f64)]| -> Option<f64> {
        if p.len() < 3 {
            return None;
        }
        let n = p.len() as f64;
        let (mx, my) = (
            p.iter().map(|q| q.0).sum::<f64>() / n,
            p.iter().map(|q| q.1).sum::<f64>() / n,
        );
        let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
        let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
        (sxx > 0.0).then(|| sxy / sxx)
    };
    Some((slope(&xs)?.abs(), slope(&ys)?.abs()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_show_the_step() {
        assert_eq!(decimals_for_step(0.5), 1);
        assert_eq!(decimals_for_step(0.1), 1);
        assert_eq!(decimals_for_step(0.05), 2);
        assert_eq!(decimals_for_step(2.0), 0);
        assert_eq!(fmt_fixed(-0.0001, 2), "0.00");
        assert_eq!(label(-2.0, YLabels::Pow10, 0), "0.01");
        assert_eq!(label(3.0, YLabels::Pow10, 0), "1000");
        assert_eq!(label(0.25, YLabels::Negated, 2), "-0.25");
    }

    #[test]
    fn text_boxes_follow_anchor_and_rotation() {
        let svg = r#"<svg data-plot-px="10 110 0 100" data-x-range="0 1" data-y-range="0 1" data-equal-scale="true" width="200">
<text x="50" y="20" dy="0.76em" text-anchor="middle" font-size="10">abcd</text>
<text x="50" y="20" dy="0.5ex" text-anchor="end" font-size="10" transform="rotate(270, 50, 20)">abcdefghij</text>
</svg>"#;
        let t = svg_texts(svg);
        assert_eq!(t.len(), 2);
        assert_eq!(t[0].bbox, [38.0, 20.0, 62.0, 30.0]);
        // 60 px wide ending at the anchor, rotated -90 deg: it reads upwards and ends at the
        // anchor, so it lies below it.
        let b = t[1].bbox;
        assert!(
            (b[0] - 45.0).abs() < 1e-9 && (b[2] - 55.0).abs() < 1e-9,
            "{b:?}"
        );
        assert!(
            (b[1] - 20.0).abs() < 1e-9 && (b[3] - 80.0).abs() < 1e-9,
            "{b:?}"
        );
        // The rotated label crosses the first one.
        assert_eq!(overlapping_texts(svg).len(), 1);
        let g = plot_geometry(svg).unwrap();
        assert!(g.equal_scale);
        assert_eq!(g.units_per_px(), (0.01, 0.01));
    }
}
