//! The report's map of the predicted uncertainty over the workspace: the standard uncertainty
//! of the predicted position error, `√(u_ex² + u_ey² + u_ez²)` from the 3×3 covariance of
//! eq. 4.12, on a grid over the plane of the first two prismatic axes with every other variable
//! held at the reference the curves use (the middle of its range).

use std::fmt::Write as _;

use kin_compiler::ir::{JointKind, Machine, Var};
use kin_estimate::fit::report::FitReport;
use kin_estimate::uncertainty::PredictionCovariance;
use kin_model::interp::Interpreter;
use kin_model::states::States;
use plotters::prelude::*;

use super::{esc, num};
use kin_estimate::curves::{range_of, Ranges};

/// Grid points per axis: fine enough to show the shape of a spline-built uncertainty, small
/// enough (1681 covariance evaluations) to cost nothing next to the fit.
pub const POINTS: usize = 41;

/// The uncertainty over the plane of two prismatic axes.
pub struct Map {
    /// The two axes (indices into `Machine::axes`) and their grid values (SI).
    pub axes: [usize; 2],
    pub u: Vec<f64>,
    pub v: Vec<f64>,
    /// `values[i * v.len() + j]` at `(u[i], v[j])`: the standard uncertainty of position (m).
    pub values: Vec<f64>,
    /// What the other variables are held at, as text.
    pub held: Vec<String>,
}

/// The map of `fit`'s predicted position uncertainty, or why there is none.
pub fn map(m: &Machine, fit: &FitReport, data: &Ranges) -> Result<Map, String> {
    if let Some(why) = fit.covariance_mismatch(m) {
        return Err(why);
    }
    let prismatic: Vec<usize> = m
        .axes
        .iter()
        .enumerate()
        .filter(|(_, a)| a.kind == JointKind::Prismatic)
        .map(|(i, _)| i)
        .collect();
    let [a, b] = match prismatic.as_slice() {
        [a, b, ..] => [*a, *b],
        _ => return Err("the machine has fewer than two prismatic axes".into()),
    };
    let mid = |v: Var| range_of(m, v, data).map_or(0.0, |(lo, hi)| 0.5 * (lo + hi));
    let line = |i: usize| -> Vec<f64> {
        let r = m.axes.get(i).map_or([0.0, 0.0], |x| x.range);
        (0..POINTS)
            .map(|k| r[0] + (r[1] - r[0]) * k as f64 / (POINTS - 1) as f64)
            .collect()
    };
    let (u, v) = (line(a), line(b));
    let mut values = Vec::with_capacity(POINTS);
    let mut held = Vec::new();
    for (i, axis) in m.axes.iter().enumerate() {
        if i == a || i == b {
            values.push(if i == a { u.clone() } else { v.clone() });
            continue;
        }
        let x = mid(Var::Axis(i));
        values.push(vec![x]);
        let (unit, scale) = match axis.kind {
            JointKind::Revolute => ("deg", x.to_degrees()),
            JointKind::Prismatic => ("mm", x * 1e3),
        };
        held.push(format!("{} = {} {unit}", axis.name, num(scale, 4)));
    }
    let inputs: Vec<Option<f64>> = (0..m.inputs.len())
        .map(|i| Some(mid(Var::Input(i))))
        .collect();
    for (i, input) in m.inputs.iter().enumerate() {
        if let Some(Some(x)) = inputs.get(i) {
            held.push(format!(
                "{} = {} {}",
                input.name,
                num(input.unit.from_si(*x), 4),
                input.unit.name
            ));
        }
    }
    let grid = crate::grid::Grid {
        values,
        dirs: vec![1.0; m.axes.len()],
        inputs,
        tool: 0,
    };
    let points = grid.points(m);
    // The fitted model: its non-linear parameters (wavelengths, time constants) and β̂ shape
    // the Jacobian, the lag states and the non-linear parameters' share of the uncertainty.
    let mut fitted = m.clone();
    for (p, v) in fitted.nonlinear.iter_mut().zip(fit.nonlinear_values(m)) {
        p.value = v;
    }
    if fit.coefficients.len() == m.coefficients.len() {
        fitted.beta = fit
            .coefficients
            .iter()
            .zip(&m.coefficients)
            .map(|(e, c)| e.value * c.unit.scale)
            .collect();
    }
    let cov = PredictionCovariance::new(&fitted, fit)?;
    let mut states =
        States::new(&fitted, &points.rows, &points.pose, "").map_err(|e| e.to_string())?;
    let mut engine = Interpreter::new(&fitted).map_err(|e| e.to_string())?;
    let out = cov
        .position_covariances(&fitted, &mut engine, &mut states, &points.rows)
        .map_err(|e| e.source.to_string())?
        .iter()
        .map(|c| (c[0][0] + c[1][1] + c[2][2]).max(0.0).sqrt())
        .collect();
    Ok(Map {
        axes: [a, b],
        u,
        v,
        values: out,
        held,
    })
}

/// The colour of `t` in [0, 1] on a sequential scale (light yellow to dark blue, after the
/// viridis end points, readable in grey).
fn color(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [253.0, 231.0, 37.0]),
        (0.25, [94.0, 201.0, 98.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [59.0, 82.0, 139.0]),
        (1.0, [68.0, 1.0, 84.0]),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let k = STOPS
        .iter()
        .rposition(|(s, _)| *s <= t)
        .unwrap_or(0)
        .min(STOPS.len() - 2);
    let (Some(&(s0, c0)), Some(&(s1, c1))) = (STOPS.get(k), STOPS.get(k + 1)) else {
        return RGBColor(0, 0, 0);
    };
    let w = ((t - s0) / (s1 - s0)).clamp(0.0, 1.0);
    let mix = |i: usize| (c0[i] + (c1[i] - c0[i]) * w).round() as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

fn css(c: RGBColor) -> String {
    format!("#{:02x}{:02x}{:02x}", c.0, c.1, c.2)
}

/// The map as an SVG heat map, in the machine's length and error units.
fn svg(m: &Machine, map: &Map, lo: f64, hi: f64) -> Result<String, String> {
    let name = |i: usize| m.axes.get(i).map_or("", |a| a.name.as_str());
    let (ur, vr) = (
        (
            map.u.first().copied().unwrap_or(0.0),
            map.u.last().copied().unwrap_or(1.0),
        ),
        (
            map.v.first().copied().unwrap_or(0.0),
            map.v.last().copied().unwrap_or(1.0),
        ),
    );
    let (du, dv) = (
        (ur.1 - ur.0) / (POINTS - 1) as f64,
        (vr.1 - vr.0) / (POINTS - 1) as f64,
    );
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (560, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mm = |x: f64| x * 1e3;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "standard uncertainty of position",
                ("sans-serif", 19.0).into_font(),
            )
            .margin(10)
            .x_label_area_size(42)
            .y_label_area_size(60)
            .build_cartesian_2d(
                mm(ur.0 - du / 2.0)..mm(ur.1 + du / 2.0),
                mm(vr.0 - dv / 2.0)..mm(vr.1 + dv / 2.0),
            )
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(format!("{} [mm]", name(map.axes[0])))
            .y_desc(format!("{} [mm]", name(map.axes[1])))
            .label_style(("sans-serif", 14.0))
            .draw()
            .map_err(|e| e.to_string())?;
        let span = (hi - lo).max(f64::MIN_POSITIVE);
        let cells = map
            .u
            .iter()
            .enumerate()
            .flat_map(|(i, &x)| map.v.iter().enumerate().map(move |(j, &y)| (i, j, x, y)));
        chart
            .draw_series(cells.map(|(i, j, x, y)| {
                let value = map.values.get(i * map.v.len() + j).copied().unwrap_or(lo);
                Rectangle::new(
                    [
                        (mm(x - du / 2.0), mm(y - dv / 2.0)),
                        (mm(x + du / 2.0), mm(y + dv / 2.0)),
                    ],
                    color((value - lo) / span).filled(),
                )
            }))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// The report's section: the heat map with its scale, the smallest and largest values and
/// where they are, or why there is no map.
pub fn section(s: &mut String, m: &Machine, fit: &FitReport, data: &Ranges) {
    s.push_str("<section id=\"uncertainty\">\n<h2>Predicted uncertainty over the workspace</h2>\n");
    let map = match map(m, fit, data) {
        Ok(map) => map,
        Err(e) => {
            let _ = writeln!(
                s,
                "<p class=\"note\">No map of the predicted uncertainty: {}.</p>\n</section>",
                esc(&e)
            );
            return;
        }
    };
    let unit = &m.units.error;
    let finite = || map.values.iter().copied().filter(|v| v.is_finite());
    let lo = finite().fold(f64::INFINITY, f64::min);
    let hi = finite().fold(f64::NEG_INFINITY, f64::max);
    let at = |target: f64| {
        map.values
            .iter()
            .position(|&v| v == target)
            .map(|k| {
                let (i, j) = (k / map.v.len().max(1), k % map.v.len().max(1));
                (
                    map.u.get(i).copied().unwrap_or(0.0),
                    map.v.get(j).copied().unwrap_or(0.0),
                )
            })
            .unwrap_or((0.0, 0.0))
    };
    let name = |i: usize| m.axes.get(i).map_or("", |a| a.name.as_str()).to_string();
    let (nu, nv) = (name(map.axes[0]), name(map.axes[1]));
    let _ = writeln!(
        s,
        "<p>The standard uncertainty (k = 1) of the model's predicted position error, √(u<sub>ex</sub>² + u<sub>ey</sub>² + u<sub>ez</sub>²) from the coefficients' covariance (eq. 4.12), over the plane of {} and {} on a {POINTS} × {POINTS} grid; the other variables are held at {}. Where it is large the fit knows the machine least: measure there.</p>",
        esc(&nu),
        esc(&nv),
        if map.held.is_empty() {
            "nothing (the machine has no others)".to_string()
        } else {
            esc(&map.held.join(", "))
        }
    );
    let used = kin_model::states::used_vars(m);
    if used.iter().any(|v| matches!(v, Var::Direction(_))) {
        s.push_str("<p class=\"note\">Every axis is taken as approached in its positive direction (the model has a direction-dependent error).</p>\n");
    }
    if !(lo.is_finite() && hi.is_finite()) {
        s.push_str("<p class=\"note\">The uncertainty is not finite anywhere on the map.</p>\n</section>\n");
        return;
    }
    match svg(m, &map, lo, hi) {
        Ok(svg) => {
            let gradient: Vec<String> = (0..=4).map(|k| css(color(k as f64 / 4.0))).collect();
            let _ = writeln!(
                s,
                "<figure class=\"umap\">{svg}<figcaption><span class=\"scale\" style=\"display:inline-block;width:180px;height:12px;vertical-align:-1px;background:linear-gradient(to right,{})\"></span> from {} to {} {}</figcaption></figure>",
                gradient.join(","),
                num(unit.from_si(lo), 4),
                num(unit.from_si(hi), 4),
                esc(&unit.name)
            );
        }
        Err(e) => {
            let _ = writeln!(
                s,
                "<div class=\"warn\">The map cannot be drawn: {}</div>",
                esc(&e)
            );
        }
    }
    s.push_str("<table class=\"umap-extremes\">\n<tr><th class=\"l\"></th><th>u [");
    s.push_str(&esc(&unit.name));
    let _ = writeln!(
        s,
        "]</th><th>{} [mm]</th><th>{} [mm]</th></tr>",
        esc(&nu),
        esc(&nv)
    );
    for (label, value) in [("smallest", lo), ("largest", hi)] {
        let (x, y) = at(value);
        let _ = writeln!(
            s,
            "<tr><td class=\"l\">{label}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            num(unit.from_si(value), 4),
            num(x * 1e3, 6),
            num(y * 1e3, 6)
        );
    }
    s.push_str("</table>\n</section>\n");
}
