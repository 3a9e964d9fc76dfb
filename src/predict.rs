//! `kin predict`: the fitted model's drift over a duty cycle (a time series of inputs), with
//! its standard uncertainty including the fitted time constants', and against observations
//! when the cycle holds them (spec/cli.md).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::ir::Machine;
use kin_data::data::{self, Groups, Observations, PointData, Pose, Rows, WriteOptions};
use kin_estimate::predict::{self, Drift};

use crate::load::{self, Failed};
use crate::report::plot::{Chart, Series, BLUE, ORANGE};
use crate::report::{esc, num};

pub struct PredictArgs {
    pub machine: PathBuf,
    pub fit: PathBuf,
    pub cycle: PathBuf,
    pub poses: Option<PathBuf>,
    pub output: Option<PathBuf>,
    pub html: Option<PathBuf>,
    pub engine: kin_model::engine::Engine,
    pub data: crate::args::DataOptions,
    pub color: bool,
}

pub fn predict(a: PredictArgs) -> ExitCode {
    Failed::exit(run(a))
}

fn run(a: PredictArgs) -> Result<(), Failed> {
    let inputs: Vec<&Path> = [
        Some(a.machine.as_path()),
        Some(a.fit.as_path()),
        Some(a.cycle.as_path()),
        a.poses.as_deref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    for out in [&a.output, &a.html].into_iter().flatten() {
        crate::files::check(out, &inputs)?;
    }
    if let (Some(o), Some(h)) = (&a.output, &a.html) {
        if kin_data::output::same_file(o, h) {
            eprintln!("error: -o and --html name the same file");
            return Err(Failed::USAGE);
        }
    }
    let compiled = load::machine(&a.machine, Some(&a.fit), a.color)?;
    let m = &compiled.machine;
    let fit = load::fit_report(&a.fit)?;
    let options = data::ReadOptions {
        poses: true,
        series: true,
        ..a.data.read(true)
    };
    let read = data::read_file(&a.cycle, m, &options).map_err(load::read_failed)?;
    // A cycle that takes an axis outside its declared range is extrapolation: W0801.
    load::outside_ranges(&a.cycle, m, &read)?;
    let cycle = match read {
        Observations::Points(p) => p,
        Observations::Lengths(_) => {
            eprintln!(
                "error: `{}`: a duty cycle is a point file (time, inputs, optionally axes and observations), not a length file",
                a.cycle.display()
            );
            return Err(Failed::INPUT);
        }
    };
    let poses: Vec<Vec<f64>> = match &a.poses {
        Some(p) => load::pose_list(p, &compiled, &a.data, "--poses")?,
        None => Vec::new(),
    };
    let (drifts, coverage) =
        predict::drift(m, Some(&fit), &cycle, &poses, a.engine).map_err(|e| {
            eprintln!("error: `{}`: {e}", a.cycle.display());
            Failed::INPUT
        })?;
    if !coverage.missing.is_empty() {
        eprintln!(
            "warning: `{}` holds no joint covariance of {} (a fit written by an older kin): the uncertainty leaves their uncertainty out; refit to include it",
            a.fit.display(),
            coverage.missing.join(", ")
        );
    }
    let own = drifts.first().is_some_and(|d| d.pose.is_empty());
    let observed = own && cycle.observed.iter().any(|c| c.is_some());
    // Summary: the largest drift and, against observations, the RMS per component.
    let eu = &m.units.error;
    let tu = &m.units.tilt;
    let unit = |c: usize| if c < 3 { eu } else { tu };
    for (k, d) in drifts.iter().enumerate() {
        let at = if d.pose.is_empty() {
            "at the cycle's poses".to_string()
        } else {
            format!("at pose {} ({})", k + 1, pose_text(m, &d.pose))
        };
        let mut line = String::new();
        for c in 0..6 {
            let Some((i, e)) = d
                .error
                .iter()
                .enumerate()
                .max_by(|x, y| x.1[c].abs().total_cmp(&y.1[c].abs()))
            else {
                continue;
            };
            let u = d.u.get(i).map_or(0.0, |u| u[c]);
            if e[c] == 0.0 && u == 0.0 {
                continue;
            }
            let _ = write!(
                line,
                " {} {} ± {} {};",
                data::OBSERVED[c],
                num(e[c] / unit(c).scale, 3),
                num(u / unit(c).scale, 2),
                unit(c).name
            );
        }
        println!("largest drift {at}:{}", line.trim_end_matches(';'));
    }
    if observed {
        if let Some(d) = drifts.first() {
            for (c, col) in cycle.observed.iter().enumerate() {
                let Some(col) = col else { continue };
                let pred: Vec<f64> = d.error.iter().map(|e| e[c]).collect();
                let (rms, count) = predict::rms(col, &pred);
                if count > 0 {
                    println!(
                        "observed − predicted {}: RMS {} {} over {count} rows",
                        data::OBSERVED[c],
                        num(rms / unit(c).scale, 3),
                        unit(c).name
                    );
                }
            }
        }
    }
    if let Some(h) = &a.html {
        let page = html(m, &a, &cycle, &drifts, observed).map_err(|e| {
            eprintln!("error: {e}");
            Failed::INPUT
        })?;
        kin_data::output::replace(h, page.as_bytes()).map_err(|e| {
            eprintln!("error: cannot write `{}`: {e}", h.display());
            Failed::USAGE
        })?;
    }
    let table = table(m, &cycle, &drifts, observed);
    let comments = vec![
        format!(
            "predicted by kin from `{}` fitted in `{}` over the cycle `{}` (first-order model, eq. 2.24; lag states integrated over the cycle)",
            a.machine.display(),
            a.fit.display(),
            a.cycle.display()
        ),
        format!(
            "u_… : standard uncertainty (k = 1) from the fit's joint covariance of the coefficients and of {} (eq. 4.12)",
            if coverage.included.is_empty() {
                "no fitted non-linear parameter".to_string()
            } else {
                coverage.included.join(", ")
            }
        ),
    ];
    let options = WriteOptions {
        comments,
        extra: table.1,
        ..WriteOptions::default()
    };
    let out = Observations::Points(table.0);
    match &a.output {
        Some(p) => data::write_file(p, m, &out, &options),
        None => match &out {
            Observations::Points(p) => data::write_points(std::io::stdout().lock(), m, p, &options),
            Observations::Lengths(l) => {
                data::write_lengths(std::io::stdout().lock(), m, l, &options)
            }
        },
    }
    .map_err(|e| {
        eprintln!("error: {e}");
        Failed::USAGE
    })
}

fn pose_text(m: &Machine, q: &[f64]) -> String {
    m.axes
        .iter()
        .zip(q)
        .map(|(a, v)| {
            let u = if a.kind == kin_compiler::ir::JointKind::Revolute {
                &m.units.angle
            } else {
                &m.units.length
            };
            format!("{} {} {}", a.name, num(v / u.scale, 4), u.name)
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The output: one row per cycle row and pose, the prediction as `ex … erz`, its
/// uncertainty as `u_…`, and against observations `obs_…`. With several poses each one's rows
/// form their own runs (`pose 2`, or `RUN pose 2`), so the file reads back in time order.
fn table(
    m: &Machine,
    cycle: &PointData,
    drifts: &[Drift],
    observed: bool,
) -> (PointData, Vec<data::ExtraColumn>) {
    let n = cycle.rows.len();
    let many = drifts.len() > 1;
    let mut rows = Rows {
        tool: Vec::new(),
        inputs: vec![Some(Vec::new()); m.inputs.len()],
        time: cycle.rows.time.as_ref().map(|_| Vec::new()),
        ..Rows::default()
    };
    let mut runs = Groups::<u32> {
        of_row: Vec::new(),
        labels: Vec::new(),
    };
    let mut pose = Pose {
        axes: vec![Vec::new(); m.axes.len()],
        dir: vec![None; m.axes.len()],
    };
    let mut out: [Option<Vec<f64>>; 6] = std::array::from_fn(|_| Some(Vec::new()));
    let mut u: [Vec<f64>; 6] = Default::default();
    let base = cycle.rows.run.as_ref();
    for (k, d) in drifts.iter().enumerate() {
        let first = runs.labels.len() as u32;
        match base {
            Some(g) if many => runs
                .labels
                .extend(g.labels.iter().map(|l| format!("{l} pose {}", k + 1))),
            Some(g) => runs.labels.extend(g.labels.iter().cloned()),
            None if many => runs.labels.push(format!("pose {}", k + 1)),
            None => {}
        }
        for r in 0..n {
            rows.line.push(rows.line.len() + 1);
            rows.tool.push(0);
            if let (Some(t), Some(src)) = (rows.time.as_mut(), cycle.rows.time.as_ref()) {
                t.push(src.get(r).copied().unwrap_or(f64::NAN));
            }
            for (dst, src) in rows.inputs.iter_mut().zip(&cycle.rows.inputs) {
                if let Some(dst) = dst {
                    dst.push(
                        src.as_ref()
                            .and_then(|c| c.get(r).copied())
                            .unwrap_or(f64::NAN),
                    );
                }
            }
            if base.is_some() || many {
                runs.of_row.push(first + cycle.rows.run_of(r));
            }
            for (a, col) in pose.axes.iter_mut().enumerate() {
                col.push(if d.pose.is_empty() {
                    cycle
                        .pose
                        .axes
                        .get(a)
                        .and_then(|c| c.get(r))
                        .copied()
                        .unwrap_or(f64::NAN)
                } else {
                    d.pose.get(a).copied().unwrap_or(f64::NAN)
                });
            }
            let e = d.error.get(r).copied().unwrap_or([f64::NAN; 6]);
            let ur = d.u.get(r).copied().unwrap_or([f64::NAN; 6]);
            for c in 0..6 {
                if let Some(col) = out[c].as_mut() {
                    col.push(e[c]);
                }
                u[c].push(ur[c]);
            }
        }
    }
    // An input the cycle does not hold stays out of the file.
    for (dst, src) in rows.inputs.iter_mut().zip(&cycle.rows.inputs) {
        if src.is_none() {
            *dst = None;
        }
    }
    if base.is_some() || many {
        rows.run = Some(runs);
    }
    let mut extra = Vec::new();
    for (c, values) in u.into_iter().enumerate() {
        extra.push(data::ExtraColumn {
            name: format!("u_{}", data::OBSERVED[c]),
            quantity: quantity(c),
            values,
        });
    }
    if observed {
        for (c, col) in cycle.observed.iter().enumerate() {
            if let Some(col) = col {
                extra.push(data::ExtraColumn {
                    name: format!("obs_{}", data::OBSERVED[c]),
                    quantity: quantity(c),
                    values: col.clone(),
                });
            }
        }
    }
    (
        PointData {
            rows,
            pose,
            observed: out,
            absolute: None,
        },
        extra,
    )
}

fn quantity(c: usize) -> data::ExtraQuantity {
    if c < 3 {
        data::ExtraQuantity::Error
    } else {
        data::ExtraQuantity::Tilt
    }
}

/// The page: per pose and component that moves, the predicted drift over time with its ±2u
/// band, and the observations when the cycle holds them.
fn html(
    m: &Machine,
    a: &PredictArgs,
    cycle: &PointData,
    drifts: &[Drift],
    observed: bool,
) -> Result<String, crate::report::plot::PlotError> {
    let time = cycle.rows.time.clone().unwrap_or_default();
    let tu = &m.units.time;
    let t = |x: f64| x / tu.scale;
    let mut body = format!(
        "<h1>Drift over the cycle <code>{}</code></h1>\n<p>Model <code>{}</code>, fit <code>{}</code>. The band is the prediction ± 2 standard uncertainties (coefficients and fitted time constants).</p>\n",
        esc(&a.cycle.display().to_string()),
        esc(&a.machine.display().to_string()),
        esc(&a.fit.display().to_string())
    );
    for (k, d) in drifts.iter().enumerate() {
        let at = if d.pose.is_empty() {
            "the cycle's poses".to_string()
        } else {
            format!("pose {} ({})", k + 1, pose_text(m, &d.pose))
        };
        for c in 0..6 {
            let unit = if c < 3 { &m.units.error } else { &m.units.tilt };
            let v = |x: f64| x / unit.scale;
            let moves = d.error.iter().any(|e| e[c] != 0.0);
            let obs = cycle
                .observed
                .get(c)
                .and_then(|o| o.as_ref())
                .filter(|_| observed);
            if !moves && obs.is_none() {
                continue;
            }
            let mut chart = Chart::new(
                format!("{} at {at}", data::OBSERVED[c]),
                format!("time [{}]", tu.name),
                format!("{} [{}]", data::OBSERVED[c], unit.name),
                (900, 380),
            );
            if !d.u.is_empty() {
                chart.series.push(Series::Band {
                    x: time.iter().map(|&x| t(x)).collect(),
                    lower: d
                        .error
                        .iter()
                        .zip(&d.u)
                        .map(|(e, u)| v(e[c] - 2.0 * u[c]))
                        .collect(),
                    upper: d
                        .error
                        .iter()
                        .zip(&d.u)
                        .map(|(e, u)| v(e[c] + 2.0 * u[c]))
                        .collect(),
                    color: BLUE,
                    opacity: 0.18,
                });
            }
            if let Some(o) = obs {
                chart.series.push(Series::Points {
                    points: time.iter().zip(o).map(|(&x, &y)| (t(x), v(y))).collect(),
                    color: ORANGE,
                    radius: 2,
                    opacity: 0.9,
                });
            }
            chart.series.push(Series::Line {
                points: time
                    .iter()
                    .zip(&d.error)
                    .map(|(&x, e)| (t(x), v(e[c])))
                    .collect(),
                color: BLUE,
                width: 2,
                dashed: false,
            });
            body.push_str(&chart.svg()?);
            if let Some(o) = obs {
                let pred: Vec<f64> = d.error.iter().map(|e| e[c]).collect();
                let (rms, count) = predict::rms(o, &pred);
                let _ = writeln!(
                    body,
                    "<p>Observed (orange) − predicted (blue): RMS {} {} over {count} rows.</p>",
                    num(rms / unit.scale, 3),
                    esc(&unit.name)
                );
            }
        }
    }
    Ok(crate::iso_html::page("kin predict", &body))
}
