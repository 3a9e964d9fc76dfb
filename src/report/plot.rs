//! Small SVG charts for the report, drawn with plotters' SVG backend.
//!
//! A [`Chart`] is plain data (title, axis labels, series); [`Chart::svg`] works out the ranges
//! from the finite values only and draws. Non-finite values never reach plotters: a line or a
//! band is split where a value is missing, so no `NaN` can appear in the SVG's coordinates.

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use thiserror::Error;

#[derive(Debug, Error)]
#[error("cannot draw the chart `{title}`: {message}")]
pub struct PlotError {
    pub title: String,
    pub message: String,
}

/// The report's palette (colour-blind-safe, after Okabe & Ito), so the HTML legends can name
/// the same colours.
pub const BLUE: RGBColor = RGBColor(0, 114, 178);
pub const ORANGE: RGBColor = RGBColor(230, 159, 0);
pub const RED: RGBColor = RGBColor(213, 64, 0);
pub const GREEN: RGBColor = RGBColor(0, 158, 115);
pub const PURPLE: RGBColor = RGBColor(204, 121, 167);
pub const SKY: RGBColor = RGBColor(86, 180, 233);
pub const GREY: RGBColor = RGBColor(120, 126, 138);
pub const PALETTE: [RGBColor; 6] = [BLUE, ORANGE, GREEN, PURPLE, SKY, RED];

/// Tick label size as plotters is told it: its SVG backend writes `size / 1.24` px, so this
/// gives 12 px text at a plot's natural size.
const FONT: f64 = 14.9;

pub fn css(c: RGBColor) -> String {
    format!("#{:02x}{:02x}{:02x}", c.0, c.1, c.2)
}

pub enum Series {
    /// Markers.
    Points {
        points: Vec<(f64, f64)>,
        color: RGBColor,
        radius: u32,
        opacity: f64,
    },
    Line {
        points: Vec<(f64, f64)>,
        color: RGBColor,
        width: u32,
        dashed: bool,
    },
    /// A filled band between `lower` and `upper`, both given at the same abscissae `x`.
    Band {
        x: Vec<f64>,
        lower: Vec<f64>,
        upper: Vec<f64>,
        color: RGBColor,
        opacity: f64,
    },
    /// A horizontal band over the whole x range, e.g. ±3σ̂.
    HBand {
        lo: f64,
        hi: f64,
        color: RGBColor,
        opacity: f64,
    },
}

pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub size: (u32, u32),
    pub x_log: bool,
    /// Keep zero inside the y range, so an error curve is seen against "no error".
    pub y_zero: bool,
    /// Make the y range symmetric about zero (residuals).
    pub y_symmetric: bool,
    /// Integer ticks on x (revision numbers).
    pub x_integer: bool,
    pub series: Vec<Series>,
}

impl Chart {
    pub fn new(
        title: impl Into<String>,
        x_label: impl Into<String>,
        y_label: impl Into<String>,
        size: (u32, u32),
    ) -> Chart {
        Chart {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            size,
            x_log: false,
            y_zero: false,
            y_symmetric: false,
            x_integer: false,
            series: Vec::new(),
        }
    }

    /// The chart as one `<svg>` element.
    pub fn svg(&self) -> Result<String, PlotError> {
        let mut out = String::new();
        let (xr, yr) = self.ranges();
        let fail = |e: String| PlotError {
            title: self.title.clone(),
            message: e,
        };
        {
            let root = SVGBackend::with_string(&mut out, self.size).into_drawing_area();
            root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
            let mut builder = ChartBuilder::on(&root);
            builder
                .caption(
                    &self.title,
                    ("sans-serif", FONT * 1.3)
                        .into_font()
                        .color(&RGBColor(29, 35, 48)),
                )
                .margin_top(6)
                .margin_right(16)
                .margin_left(6)
                .margin_bottom(4)
                .x_label_area_size(42)
                .y_label_area_size(64);
            if self.x_log {
                let mut chart = builder
                    .build_cartesian_2d((xr.0..xr.1).log_scale(), yr.0..yr.1)
                    .map_err(|e| fail(e.to_string()))?;
                self.draw(&mut chart, xr).map_err(fail)?;
            } else {
                let mut chart = builder
                    .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
                    .map_err(|e| fail(e.to_string()))?;
                self.draw(&mut chart, xr).map_err(fail)?;
            }
            root.present().map_err(|e| fail(e.to_string()))?;
        }
        Ok(out)
    }

    /// Data ranges over the finite values (positive x on a log axis), padded a little so
    /// markers at the edge stay whole; a degenerate range is widened.
    fn ranges(&self) -> ((f64, f64), (f64, f64)) {
        let mut xs = Bounds::default();
        let mut ys = Bounds::default();
        let ok_x = |x: f64| x.is_finite() && (!self.x_log || x > 0.0);
        for s in &self.series {
            match s {
                Series::Points { points, .. } | Series::Line { points, .. } => {
                    for &(x, y) in points {
                        if ok_x(x) && y.is_finite() {
                            xs.add(x);
                            ys.add(y);
                        }
                    }
                }
                Series::Band {
                    x, lower, upper, ..
                } => {
                    for ((&x, &lo), &hi) in x.iter().zip(lower).zip(upper) {
                        if ok_x(x) && lo.is_finite() && hi.is_finite() {
                            xs.add(x);
                            ys.add(lo);
                            ys.add(hi);
                        }
                    }
                }
                Series::HBand { lo, hi, .. } => {
                    ys.add(*lo);
                    ys.add(*hi);
                }
            }
        }
        if self.y_zero || self.y_symmetric {
            ys.add(0.0);
        }
        if self.y_symmetric {
            let m = ys.lo.abs().max(ys.hi.abs());
            ys.add(-m);
            ys.add(m);
        }
        let x = if self.x_integer {
            // Whole numbers (revisions) sit half a step inside the frame, even just one.
            let (lo, hi) = xs.get(1.0, 1.0);
            (lo - 0.5, hi + 0.5)
        } else if self.x_log {
            let (lo, hi) = xs.get(1.0, 10.0);
            if hi > lo * 1.000_001 {
                (lo / 1.15, hi * 1.15)
            } else {
                (lo / 2.0, hi * 2.0)
            }
        } else {
            pad(xs.get(0.0, 1.0), 0.02)
        };
        (x, pad(ys.get(-1.0, 1.0), 0.06))
    }

    fn draw<'a, X>(
        &self,
        chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, RangedCoordf64>>,
        xr: (f64, f64),
    ) -> Result<(), String>
    where
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        let e = |e: DrawingAreaErrorKind<std::io::Error>| e.to_string();
        let x_integer = self.x_integer;
        // A tick a rounding error away from zero is zero (`-1.1e-16` otherwise).
        let x_eps = 1e-9 * (xr.1 - xr.0).abs();
        let yr = chart.y_range();
        let y_eps = 1e-9 * (yr.end - yr.start).abs();
        let x_fmt = move |v: &f64| {
            if x_integer {
                if (v - v.round()).abs() < 1e-6 {
                    format!("{}", v.round())
                } else {
                    String::new()
                }
            } else {
                tick(if v.abs() < x_eps { 0.0 } else { *v })
            }
        };
        let y_fmt = move |v: &f64| tick(if v.abs() < y_eps { 0.0 } else { *v });
        chart
            .configure_mesh()
            .x_desc(self.x_label.as_str())
            .y_desc(self.y_label.as_str())
            .x_labels(if self.x_integer {
                ((xr.1 - xr.0).ceil() as usize).clamp(2, 12)
            } else {
                7
            })
            .y_labels(7)
            .x_label_formatter(&x_fmt)
            .y_label_formatter(&y_fmt)
            .label_style(
                ("sans-serif", FONT)
                    .into_font()
                    .color(&RGBColor(70, 76, 88)),
            )
            .axis_desc_style(
                ("sans-serif", FONT * 1.1)
                    .into_font()
                    .color(&RGBColor(29, 35, 48)),
            )
            .bold_line_style(RGBColor(222, 225, 230))
            .light_line_style(RGBColor(243, 244, 246))
            .axis_style(RGBColor(150, 155, 165))
            .draw()
            .map_err(e)?;
        for s in &self.series {
            match s {
                Series::HBand {
                    lo,
                    hi,
                    color,
                    opacity,
                } => {
                    if lo.is_finite() && hi.is_finite() {
                        chart
                            .draw_series(std::iter::once(Rectangle::new(
                                [(xr.0, *lo), (xr.1, *hi)],
                                color.mix(*opacity).filled(),
                            )))
                            .map_err(e)?;
                    }
                }
                Series::Band {
                    x,
                    lower,
                    upper,
                    color,
                    opacity,
                } => {
                    for run in runs(x.len(), |i| {
                        finite(x, i)
                            && finite(lower, i)
                            && finite(upper, i)
                            && (!self.x_log || x[i] > 0.0)
                    }) {
                        let mut poly: Vec<(f64, f64)> =
                            run.clone().map(|i| (x[i], upper[i])).collect();
                        poly.extend(run.rev().map(|i| (x[i], lower[i])));
                        chart
                            .draw_series(std::iter::once(Polygon::new(
                                poly,
                                color.mix(*opacity).filled(),
                            )))
                            .map_err(e)?;
                    }
                }
                Series::Line {
                    points,
                    color,
                    width,
                    dashed,
                } => {
                    let style = ShapeStyle::from(color).stroke_width(*width);
                    for run in runs(points.len(), |i| {
                        points[i].0.is_finite()
                            && points[i].1.is_finite()
                            && (!self.x_log || points[i].0 > 0.0)
                    }) {
                        let pts: Vec<(f64, f64)> = run.map(|i| points[i]).collect();
                        if *dashed {
                            chart
                                .draw_series(DashedLineSeries::new(pts, 6, 4, style))
                                .map_err(e)?;
                        } else {
                            chart.draw_series(LineSeries::new(pts, style)).map_err(e)?;
                        }
                    }
                }
                Series::Points {
                    points,
                    color,
                    radius,
                    opacity,
                } => {
                    let style = color.mix(*opacity).filled();
                    let pts = points.iter().filter(|p| {
                        p.0.is_finite() && p.1.is_finite() && (!self.x_log || p.0 > 0.0)
                    });
                    chart
                        .draw_series(pts.map(|&p| Circle::new(p, *radius, style)))
                        .map_err(e)?;
                }
            }
        }
        Ok(())
    }
}

fn finite(v: &[f64], i: usize) -> bool {
    v.get(i).is_some_and(|x| x.is_finite())
}

/// Maximal runs of consecutive indices where `ok` holds.
fn runs(n: usize, ok: impl Fn(usize) -> bool) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut start = None;
    for i in 0..=n {
        match (i < n && ok(i), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push(s..i);
                start = None;
            }
            _ => {}
        }
    }
    out
}

#[derive(Clone, Copy)]
struct Bounds {
    lo: f64,
    hi: f64,
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }
}

impl Bounds {
    fn add(&mut self, v: f64) {
        if v.is_finite() {
            self.lo = self.lo.min(v);
            self.hi = self.hi.max(v);
        }
    }

    fn get(self, lo: f64, hi: f64) -> (f64, f64) {
        if self.lo <= self.hi {
            (self.lo, self.hi)
        } else {
            (lo, hi)
        }
    }
}

fn pad((lo, hi): (f64, f64), fraction: f64) -> (f64, f64) {
    let span = hi - lo;
    if span > 1e-300 && span > 1e-12 * lo.abs().max(hi.abs()) {
        (lo - fraction * span, hi + fraction * span)
    } else {
        let w = if lo.abs() > 0.0 { 0.05 * lo.abs() } else { 1.0 };
        (lo - w, hi + w)
    }
}

/// A tick label: short, without float noise (`0.30000000000000004`), scientific only for very
/// large or small magnitudes.
pub fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return "0".into();
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.1e}");
    }
    // Enough decimals for three significant digits, trailing zeros trimmed.
    let decimals = (2 - a.log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" {
        "0".into()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_read_well() {
        assert_eq!(tick(0.30000000000000004), "0.3");
        assert_eq!(tick(-0.25), "-0.25");
        assert_eq!(tick(600.0), "600");
        assert_eq!(tick(12.5), "12.5");
        assert_eq!(tick(2.0e-6), "2.0e-6");
    }

    #[test]
    fn missing_values_split_lines_and_never_reach_the_svg() {
        let mut c = Chart::new("t", "x [mm]", "y [um]", (300, 200));
        c.series.push(Series::Line {
            points: vec![(0.0, 1.0), (1.0, f64::NAN), (2.0, 2.0), (3.0, 1.5)],
            color: BLUE,
            width: 2,
            dashed: false,
        });
        c.series.push(Series::Band {
            x: vec![0.0, 1.0, 2.0],
            lower: vec![0.0, f64::NAN, 1.0],
            upper: vec![1.0, 2.0, f64::INFINITY],
            color: BLUE,
            opacity: 0.2,
        });
        c.series.push(Series::Points {
            points: vec![(f64::NAN, 1.0), (1.0, 1.0)],
            color: RED,
            radius: 2,
            opacity: 1.0,
        });
        let svg = c.svg().expect("draws");
        assert!(
            svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"),
            "{svg}"
        );
        assert!(!svg.contains("NaN") && !svg.contains("inf"), "{svg}");
    }

    #[test]
    fn an_empty_or_flat_chart_still_draws() {
        let c = Chart::new("empty", "x", "y", (300, 200));
        assert!(c.svg().is_ok());
        let mut c = Chart::new("flat", "x", "y", (300, 200));
        c.x_log = true;
        c.series.push(Series::Line {
            points: vec![(5.0, 1.0), (5.0, 1.0)],
            color: BLUE,
            width: 1,
            dashed: true,
        });
        let svg = c.svg().expect("draws");
        assert!(!svg.contains("NaN"));
    }

    #[test]
    fn runs_split_at_gaps() {
        let ok = [true, true, false, true, false, false, true];
        assert_eq!(runs(ok.len(), |i| ok[i]), vec![0..2, 3..4, 6..7]);
    }
}
