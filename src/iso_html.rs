//! The HTML pages of `kin iso230-2 --html` and `kin iso230-4 --html`: the figures as tables and
//! the standards' plots as inline SVG (self-contained, as `kin report`'s page: no scripts, no
//! fetched resources).

use std::fmt::Write as _;

use kin_compiler::units::Unit;
use kin_standards::iso230_2;
use kin_standards::iso230_4::{self, CircularRun, Figures};
use plotters::prelude::*;

use crate::report::plot::{self, Chart, PlotError, Series, BLUE, GREY, ORANGE};
use crate::report::{esc, num, CSS};

pub(crate) fn page(title: &str, body: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n<title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<main>\n{body}<footer>written by kin {}</footer>\n</main>\n</body>\n</html>\n",
        esc(title),
        env!("CARGO_PKG_VERSION")
    )
}

fn card(s: &mut String, key: &str, value: f64, unit: &Unit) {
    let _ = write!(
        s,
        "<div class=\"card\"><div class=\"v\">{} {}</div><div class=\"k\">{}</div></div>",
        num(value / unit.scale, 3),
        esc(&unit.name),
        esc(key)
    );
}

/// The ISO 230-2 page: the axis figures, the plot of the mean deviations ± 2s per direction
/// over the targets (the standard's figure), and the per-target table.
pub fn iso230_2_page(
    name: &str,
    e: &iso230_2::Evaluation,
    target_unit: &Unit,
    unit: &Unit,
) -> Result<String, PlotError> {
    let d = |v: f64| v / unit.scale;
    let x = |t: f64| t / target_unit.scale;
    let mut chart = Chart::new(
        "Positional deviations: means and ±2s per direction",
        format!("target [{}]", target_unit.name),
        format!("deviation [{}]", unit.name),
        (900, 460),
    );
    chart.y_zero = true;
    for (up, color) in [(true, BLUE), (false, ORANGE)] {
        let mean = |t: &iso230_2::TargetFigures| if up { t.mean_up } else { t.mean_down };
        let s = |t: &iso230_2::TargetFigures| if up { t.s_up } else { t.s_down };
        for k in [-2.0, 2.0] {
            chart.series.push(Series::Line {
                points: e
                    .targets
                    .iter()
                    .map(|t| (x(t.target), d(mean(t) + k * s(t))))
                    .collect(),
                color,
                width: 1,
                dashed: true,
            });
        }
        chart.series.push(Series::Line {
            points: e
                .targets
                .iter()
                .map(|t| (x(t.target), d(mean(t))))
                .collect(),
            color,
            width: 2,
            dashed: false,
        });
        chart.series.push(Series::Points {
            points: e
                .targets
                .iter()
                .map(|t| (x(t.target), d(mean(t))))
                .collect(),
            color,
            radius: 3,
            opacity: 1.0,
        });
    }
    chart.series.push(Series::Line {
        points: e.targets.iter().map(|t| (x(t.target), d(t.mean))).collect(),
        color: GREY,
        width: 1,
        dashed: false,
    });
    let svg = chart.svg()?;
    let a = &e.axis;
    let mut s = String::new();
    let _ = write!(
        s,
        "<h1>ISO 230-2 positioning run</h1><div class=\"meta\">{} — {} targets, up to {} approaches per target and direction</div>",
        esc(name),
        e.targets.len(),
        e.cycles
    );
    if e.cycles < 5 {
        s.push_str("<div class=\"warn\">ISO 230-2 asks for 5 cycles; this run has fewer.</div>");
    }
    s.push_str("<div class=\"cards\">");
    for (k, v) in [
        ("A bidirectional accuracy", a.a),
        ("A↑ / positive", a.a_up),
        ("A↓ / negative", a.a_down),
        ("E systematic error", a.e),
        ("M mean bidirectional range", a.m),
        ("R repeatability", a.r),
        ("B reversal value", a.b),
        ("B̄ mean reversal", a.b_mean),
    ] {
        card(&mut s, k, v, unit);
    }
    s.push_str("</div>");
    let _ = write!(
        s,
        "<h2>Deviations along the axis</h2><figure>{svg}<figcaption><span class=\"sw line\" style=\"background:{}\"></span>x̄↑ approached moving positive <span class=\"sw line\" style=\"background:{}\"></span>x̄↓ approached moving negative <span class=\"sw dash\" style=\"color:{}\"></span><span class=\"sw dash\" style=\"color:{}\"></span>x̄ ± 2s of each direction <span class=\"sw line\" style=\"background:{}\"></span>x̄ bidirectional mean</figcaption></figure>",
        plot::css(BLUE),
        plot::css(ORANGE),
        plot::css(BLUE),
        plot::css(ORANGE),
        plot::css(GREY)
    );
    let _ = write!(
        s,
        "<h2>Per target</h2><table><tr><th>target [{}]</th><th>x̄↑</th><th>x̄↓</th><th>x̄</th><th>B_i</th><th>s↑</th><th>s↓</th><th>R↑</th><th>R↓</th><th>R_i</th></tr>",
        esc(&target_unit.name)
    );
    for t in &e.targets {
        // A target as the file wrote it: six significant digits, no trailing zeros.
        let shown = num(x(t.target), 6);
        let shown = if shown.contains('.') && !shown.contains('e') {
            shown
                .trim_end_matches('0')
                .trim_end_matches('.')
                .to_string()
        } else {
            shown
        };
        let _ = write!(s, "<tr><td>{shown}</td>");
        for v in [
            t.mean_up,
            t.mean_down,
            t.mean,
            t.reversal,
            t.s_up,
            t.s_down,
            t.r_up,
            t.r_down,
            t.r,
        ] {
            let _ = write!(s, "<td>{}</td>", num(d(v), 3));
        }
        s.push_str("</tr>");
    }
    let _ = write!(
        s,
        "</table><p class=\"note\">Deviations in {}; definitions in spec/iso230-2.md.</p>",
        esc(&unit.name)
    );
    Ok(page(&format!("kin iso230-2: {name}"), &s))
}

/// A step of 1, 2 or 5 times a power of ten, at least `v`.
fn nice(v: f64) -> f64 {
    if v.is_nan() || v <= 0.0 || v.is_infinite() {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|k| k * p)
        .find(|s| *s >= v * (1.0 - 1e-12))
        .unwrap_or(10.0 * p)
}

/// The polar plot of one run: each direction's radial deviations about the run's least-squares
/// circle, magnified around a nominal circle so that ±2 ring steps span 100 px either side.
/// `traces` are (angle rad, deviation from the circle in the display unit, colour).
fn polar_svg(
    title: &str,
    traces: &[(Vec<(f64, f64)>, RGBColor)],
    plane: &[String; 2],
    unit: &Unit,
) -> Result<(String, f64), PlotError> {
    let size = (620u32, 640u32);
    let (cx, cy) = (310.0, 335.0);
    let nominal = 180.0;
    let largest = traces
        .iter()
        .flat_map(|t| t.0.iter().map(|p| p.1.abs()))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let step = nice(largest / 2.0);
    let px = 50.0 / step;
    let fail = |e: String| PlotError {
        title: title.to_string(),
        message: e,
    };
    let at = |t: f64, r: f64| -> (i32, i32) {
        (
            (cx + r * t.cos()).round() as i32,
            (cy - r * t.sin()).round() as i32,
        )
    };
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| fail(e.to_string()))?;
        let e = |e: DrawingAreaErrorKind<std::io::Error>| fail(e.to_string());
        let ink = RGBColor(29, 35, 48);
        let light = RGBColor(222, 225, 230);
        let text = |s: &str, (x, y): (i32, i32), size: f64, color: RGBColor| {
            Text::new(
                s.to_string(),
                (x, y),
                ("sans-serif", size).into_font().color(&color),
            )
        };
        root.draw(&text(title, (12, 8), 18.0, ink)).map_err(e)?;
        // Rings every step, the nominal circle darker; spokes every 30°.
        for k in -2..=2 {
            let r = nominal + k as f64 * step * px;
            let color = if k == 0 { GREY } else { light };
            let ring: Vec<(i32, i32)> = (0..=360).map(|i| at((i as f64).to_radians(), r)).collect();
            root.draw(&PathElement::new(
                ring,
                ShapeStyle::from(color).stroke_width(1),
            ))
            .map_err(e)?;
            let label = format!(
                "{}{} {}",
                if k > 0 { "+" } else { "" },
                plot::tick(k as f64 * step),
                unit.name
            );
            root.draw(&text(
                &label,
                at(100f64.to_radians(), r + 2.0),
                11.0,
                RGBColor(90, 96, 108),
            ))
            .map_err(e)?;
        }
        for i in 0..12 {
            let t = (i as f64 * 30.0).to_radians();
            root.draw(&PathElement::new(
                vec![
                    at(t, nominal - 2.0 * step * px),
                    at(t, nominal + 2.0 * step * px),
                ],
                ShapeStyle::from(light).stroke_width(1),
            ))
            .map_err(e)?;
            let (x, y) = at(t, nominal + 2.0 * step * px + 16.0);
            root.draw(&text(
                &format!("{}°", i * 30),
                (x - 10, y - 6),
                11.0,
                RGBColor(90, 96, 108),
            ))
            .map_err(e)?;
        }
        // The plane's axes through the centre, named at their positive ends.
        for (t, name) in [(0.0, &plane[0]), (std::f64::consts::FRAC_PI_2, &plane[1])] {
            root.draw(&PathElement::new(
                vec![at(t + std::f64::consts::PI, 30.0), at(t, 30.0)],
                ShapeStyle::from(GREY).stroke_width(1),
            ))
            .map_err(e)?;
            let (x, y) = at(t, 34.0);
            root.draw(&text(name, (x, y - 12), 13.0, ink)).map_err(e)?;
        }
        for (points, color) in traces {
            let mut path: Vec<(i32, i32)> = points
                .iter()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .map(|&(t, r)| at(t, nominal + r * px))
                .collect();
            // A full turn closes on itself: join the last sample to the first when the step
            // between them is no longer than the path's longest step elsewhere.
            let angles: Vec<f64> = points
                .iter()
                .map(|p| p.0)
                .filter(|t| t.is_finite())
                .collect();
            let step = |a: f64, b: f64| {
                let d = (b - a).rem_euclid(std::f64::consts::TAU);
                d.min(std::f64::consts::TAU - d)
            };
            let longest = angles
                .windows(2)
                .map(|w| step(w[0], w[1]))
                .fold(0.0, f64::max);
            if let (Some(&first), Some(&last), Some(&p0)) =
                (angles.first(), angles.last(), path.first())
            {
                let covered: f64 = angles.windows(2).map(|w| (w[1] - w[0]).abs()).sum();
                if covered > 1.5 * std::f64::consts::PI && step(last, first) <= longest * 1.0001 {
                    path.push(p0);
                }
            }
            root.draw(&PathElement::new(
                path,
                ShapeStyle::from(color).stroke_width(2),
            ))
            .map_err(e)?;
        }
        root.present().map_err(|e| fail(e.to_string()))?;
    }
    Ok((out, step))
}

/// The ISO 230-4 page: per run the figures and the polar plot of both directions.
pub fn iso230_4_page(
    name: &str,
    run: &CircularRun,
    e: &iso230_4::Evaluation,
    unit: &Unit,
) -> Result<String, PlotError> {
    let plane = e
        .setup
        .plane
        .clone()
        .unwrap_or_else(|| ["first axis".to_string(), "second axis".to_string()]);
    let mut s = String::new();
    let _ = write!(
        s,
        "<h1>ISO 230-4 circular test</h1><div class=\"meta\">{}",
        esc(name)
    );
    if let Some(r) = e.setup.radius {
        let _ = write!(s, " — radius {} mm", num(r * 1e3, 6));
    }
    if let Some(p) = &e.setup.plane {
        let _ = write!(s, ", plane {}{}", esc(&p[0]), esc(&p[1]));
    }
    if let Some(f) = &e.setup.feed {
        let _ = write!(s, ", feed {}", esc(f));
    }
    s.push_str("</div>");
    for r in &e.runs {
        let _ = write!(s, "<h2>Run {}</h2><div class=\"cards\">", esc(&r.run));
        let figures: [(&str, &Option<Figures>); 3] =
            [("ccw", &r.ccw), ("cw", &r.cw), ("bidirectional", &r.both)];
        for (label, f) in figures {
            if let Some(f) = f {
                card(&mut s, &format!("G circular deviation, {label}"), f.g, unit);
            }
        }
        if let Some(h) = r.h {
            card(&mut s, "H circular hysteresis", h, unit);
        }
        s.push_str("</div>");
        // Both directions about the run's common circle (one direction's own when alone), so
        // the gap between them is the hysteresis.
        let Some(circle) = r
            .both
            .as_ref()
            .or(r.ccw.as_ref())
            .or(r.cw.as_ref())
            .map(|f| f.circle)
        else {
            continue;
        };
        let mut traces = Vec::new();
        for (ccw, color) in [(true, BLUE), (false, ORANGE)] {
            let points: Vec<(f64, f64)> = run
                .samples
                .iter()
                .filter(|x| x.run == r.run && x.ccw == ccw)
                .map(|x| (x.angle, circle.residual(x.angle, x.deviation) / unit.scale))
                .collect();
            if !points.is_empty() {
                traces.push((points, color));
            }
        }
        let (svg, step) = polar_svg(
            &format!("Run {}: radial deviation, magnified", r.run),
            &traces,
            &plane,
            unit,
        )?;
        let _ = write!(
            s,
            "<figure style=\"max-width:640px\">{svg}<figcaption><span class=\"sw line\" style=\"background:{}\"></span>counter-clockwise <span class=\"sw line\" style=\"background:{}\"></span>clockwise — about the least-squares centre, rings every {} {}</figcaption></figure>",
            plot::css(BLUE),
            plot::css(ORANGE),
            plot::tick(step),
            esc(&unit.name)
        );
        let _ = write!(
            s,
            "<table><tr><th class=\"l\"></th><th>G</th><th>F max</th><th>F min</th><th>centre {}</th><th>centre {}</th><th>radius error</th><th>samples</th></tr>",
            esc(&plane[0]),
            esc(&plane[1])
        );
        for (label, f) in figures {
            if let Some(f) = f {
                let _ = write!(s, "<tr><td class=\"l\">{label}</td>");
                for v in [
                    f.g,
                    f.f_max,
                    f.f_min,
                    f.circle.centre[0],
                    f.circle.centre[1],
                    f.circle.radius_error,
                ] {
                    let _ = write!(s, "<td>{}</td>", num(v / unit.scale, 3));
                }
                let _ = write!(s, "<td>{}</td></tr>", f.samples);
            }
        }
        let _ = write!(
            s,
            "</table><p class=\"note\">In {}; centre offsets and F are measured from the instrument's centre (definitions in spec/iso230-4.md).</p>",
            esc(&unit.name)
        );
    }
    Ok(page(&format!("kin iso230-4: {name}"), &s))
}

/// The ISO 230-3 page: the displacements and tilts over time (the standard's drift plot) and
/// the temperatures over time on their own chart, with the figures as a table.
pub fn iso230_3_page(
    name: &str,
    run: &kin_standards::iso230_3::ThermalRun,
    e: &kin_standards::iso230_3::Evaluation,
) -> Result<String, PlotError> {
    let hours: Vec<f64> = run
        .time
        .iter()
        .map(|t| (t - run.time.first().copied().unwrap_or(0.0)) / 3600.0)
        .collect();
    let mut body = format!(
        "<h1>ISO 230-3 thermal test <code>{}</code></h1>\n<p>{} samples over {} h.</p>\n",
        esc(name),
        e.samples,
        num(e.duration / 3600.0, 3)
    );
    let colors = plot::PALETTE;
    let mut chart = Chart::new(
        "Displacements over time",
        "time [h]",
        "displacement [um]",
        (900, 420),
    );
    for (k, c) in run.displacements.iter().enumerate() {
        chart.series.push(Series::Line {
            points: hours
                .iter()
                .zip(&c.values)
                .map(|(&t, &v)| (t, v * 1e6))
                .collect(),
            color: colors[k % colors.len()],
            width: 2,
            dashed: false,
        });
    }
    body.push_str(&chart.svg()?);
    body.push_str(&legend(run.displacements.iter().map(|c| c.name.as_str())));
    if !e.tilts.is_empty() {
        let mut chart = Chart::new(
            "Tilts of the spindle axis",
            "time [h]",
            "tilt [urad]",
            (900, 360),
        );
        for (k, t) in e.tilts.iter().enumerate() {
            chart.series.push(Series::Line {
                points: hours
                    .iter()
                    .zip(&t.values)
                    .map(|(&h, &v)| (h, v * 1e6))
                    .collect(),
                color: colors[k % colors.len()],
                width: 2,
                dashed: false,
            });
        }
        body.push_str(&chart.svg()?);
        body.push_str(&legend(e.tilts.iter().map(|t| t.figures.name.as_str())));
    }
    if !run.temperatures.is_empty() {
        let mut chart = Chart::new(
            "Temperatures over time",
            "time [h]",
            "temperature change [K]",
            (900, 360),
        );
        for (k, c) in run.temperatures.iter().enumerate() {
            let first = c.values.first().copied().unwrap_or(0.0);
            chart.series.push(Series::Line {
                points: hours
                    .iter()
                    .zip(&c.values)
                    .map(|(&t, &v)| (t, v - first))
                    .collect(),
                color: colors[k % colors.len()],
                width: 2,
                dashed: true,
            });
        }
        body.push_str(&chart.svg()?);
        body.push_str(&legend(run.temperatures.iter().map(|c| c.name.as_str())));
    }
    body.push_str("<table><tr><th>channel</th><th>range (ETVE)</th><th>drift from start</th><th>at [min]</th><th>at the end</th></tr>\n");
    let mut row = |n: &str, f: &kin_standards::iso230_3::ChannelFigures, scale: f64, unit: &str| {
        let _ = writeln!(
            body,
            "<tr><td>{}</td><td>{} {unit}</td><td>{} {unit}</td><td>{}</td><td>{} {unit}</td></tr>",
            esc(n),
            num(f.range * scale, 3),
            num(f.drift * scale, 3),
            num(f.drift_at / 60.0, 1),
            num(f.end * scale, 3)
        );
    };
    for c in &e.displacements {
        row(&c.name, c, 1e6, "um");
    }
    for t in &e.tilts {
        row(&t.figures.name, &t.figures, 1e6, "urad");
    }
    for c in &e.temperatures {
        row(&c.name, c, 1.0, "K");
    }
    body.push_str("</table>\n");
    Ok(page(&format!("ISO 230-3: {name}"), &body))
}

fn legend<'a>(names: impl Iterator<Item = &'a str>) -> String {
    let mut s = String::from("<p>");
    for (k, n) in names.enumerate() {
        let c = plot::PALETTE[k % plot::PALETTE.len()];
        let _ = write!(
            s,
            "<span style=\"color:{}\">■</span> {} &nbsp; ",
            plot::css(c),
            esc(n)
        );
    }
    s.push_str("</p>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_steps_are_1_2_5() {
        assert_eq!(nice(0.7), 1.0);
        assert_eq!(nice(1.0), 1.0);
        assert_eq!(nice(1.3), 2.0);
        assert_eq!(nice(3.0), 5.0);
        assert_eq!(nice(6.0), 10.0);
        assert_eq!(nice(0.0), 1.0);
        assert_eq!(nice(f64::NAN), 1.0);
    }
}
