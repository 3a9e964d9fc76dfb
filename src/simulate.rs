//! `kin simulate` (measurements with a known truth, exact transforms) and `kin eval`
//! (the first-order model's prediction at given poses).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_data::data::{self, Observations, WriteOptions};
use kin_estimate::simulate::{self, Options};
use kin_estimate::uncertainty::PredictionCovariance;

use crate::args::Spread;
use crate::load::{self, Failed};

/// Which error components a point file holds.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Components {
    /// ex, ey, ez
    Position,
    /// ex, ey, ez, erx, ery, erz
    Pose,
}

impl Components {
    fn mask(self) -> [bool; 6] {
        match self {
            Components::Position => [true, true, true, false, false, false],
            Components::Pose => [true; 6],
        }
    }
}

pub struct SimulateArgs {
    pub machine: PathBuf,
    pub params: Option<PathBuf>,
    pub poses: Option<PathBuf>,
    pub sample: Option<usize>,
    pub cycle: Option<String>,
    pub every: Option<Spread>,
    pub output: Option<PathBuf>,
    /// `--format json`: the measurements as a JSON document on standard output.
    pub json: bool,
    pub noise: Option<Spread>,
    pub noise_tilt: Option<Spread>,
    pub seed: u64,
    pub artifact_shift: Option<Spread>,
    pub artifact_rotation: Option<Spread>,
    pub artifact_length: Option<Spread>,
    pub components: Components,
    /// Columns of the poses file to skip unread.
    pub ignore: crate::args::DataOptions,
    pub color: bool,
}

/// What `kin eval` was asked.
pub struct EvalArgs<'a> {
    pub machine: &'a Path,
    pub params: Option<&'a Path>,
    pub poses: &'a Path,
    pub output: Option<&'a Path>,
    /// `--format json`: the predictions as a JSON document on standard output.
    pub json: bool,
    pub components: Components,
    pub engine: kin_model::engine::Engine,
    /// Columns of the poses file to skip unread.
    pub ignore: &'a crate::args::DataOptions,
    /// Add each prediction's standard uncertainty from the fit given as `params`.
    pub uncertainty: bool,
    /// With `uncertainty`: the level (0 < L < 1) of each pose's confidence ellipsoid.
    pub ellipsoid: Option<f64>,
    /// Add the nominal tool pose (`px` … `prz`).
    pub nominal: bool,
    pub color: bool,
}

fn finish(result: Result<(), Failed>) -> ExitCode {
    Failed::exit(result)
}

pub fn simulate(a: SimulateArgs) -> ExitCode {
    finish(run_simulate(a))
}

fn run_simulate(a: SimulateArgs) -> Result<(), Failed> {
    if let Some(out) = &a.output {
        let inputs: Vec<&Path> = [
            Some(a.machine.as_path()),
            a.params.as_deref(),
            a.poses.as_deref(),
        ]
        .into_iter()
        .flatten()
        .collect();
        crate::files::check(out, &inputs)?;
    }
    let compiled = load::machine(&a.machine, a.params.as_deref(), a.color)?;
    let m = &compiled.machine;
    // A truth with no values simulates a perfect machine: say so rather than write zeros.
    if !m.beta.is_empty() && m.beta.iter().all(|b| *b == 0.0) && !crate::warnings::quiet() {
        eprintln!(
            "warning: every coefficient of `{}` is 0 (the model binds no values and no --params was given): \
             the simulated errors are those of a perfect machine{}",
            m.name,
            if a.noise.is_some() || a.noise_tilt.is_some() { ", plus the noise" } else { "" }
        );
    }
    let mut cycle_comment = None;
    let poses = match (&a.poses, a.sample, &a.cycle) {
        (_, _, Some(text)) => {
            let (points, comment) = cycle_poses(&a, &compiled, text)?;
            cycle_comment = Some(comment);
            Observations::Points(points)
        }
        (Some(p), None, None) => load::observations(p, &compiled, true, &a.ignore)?,
        (None, Some(n), None) => Observations::Points(simulate::sample_points(m, n, a.seed)),
        _ => {
            eprintln!(
                "error: give a poses file (--poses FILE), --sample N or a duty cycle (--cycle)"
            );
            return Err(Failed::USAGE);
        }
    };
    // Validated (finite, ≥ 0, of the right dimension) as the command line was parsed.
    let si = |s: &Option<Spread>| s.as_ref().map_or(0.0, |s| s.si);
    let options = Options {
        observe: a.components.mask(),
        noise: si(&a.noise),
        noise_tilt: si(&a.noise_tilt),
        seed: a.seed,
        artifact_shift: si(&a.artifact_shift),
        artifact_rotation: si(&a.artifact_rotation),
        artifact_length: si(&a.artifact_length),
    };
    let rows = match &poses {
        Observations::Points(p) => p.rows.len(),
        Observations::Lengths(l) => l.rows.len(),
    };
    // Some 10⁵ poses take a second or more: a spinner on a terminal says it is under way.
    let bar = (rows >= 100_000)
        .then(|| crate::warnings::spinner(&format!("simulating {rows} measurements")));
    let started = std::time::Instant::now();
    let out = simulate::simulate(m, &m.beta, &poses, &options);
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    crate::warnings::note(&crate::warnings::timed(
        &format!("simulated {rows} measurements"),
        started,
    ));
    let out = out.map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let mut comments = vec![
        format!(
            "simulated by kin from `{}` (exact transforms)",
            a.machine.display()
        ),
        format!(
            "noise {} (positions), {} (rotations), seed {}",
            a.noise.as_ref().map_or("0", |s| s.text.as_str()),
            a.noise_tilt.as_ref().map_or("0", |s| s.text.as_str()),
            a.seed
        ),
    ];
    comments.extend(cycle_comment);
    write(&out, m, a.output.as_deref(), comments, Vec::new(), a.json)
}

/// The poses table of `--cycle`: a time series file's rows, or a generated cycle sampled
/// every `--every`, at each pose of `--poses` (default: mid-range); and a comment saying which.
fn cycle_poses(
    a: &SimulateArgs,
    compiled: &kin_compiler::Compiled,
    text: &str,
) -> Result<(data::PointData, String), Failed> {
    let m = &compiled.machine;
    let path = Path::new(text);
    // A file when one exists by that name; the generator's text never names one.
    let is_file = !text.contains(';') && path.is_file();
    if !is_file && !text.contains(';') && (text.ends_with(".csv") || text.contains('/')) {
        eprintln!("error: cannot read the cycle `{text}`: no such file");
        return Err(Failed::USAGE);
    }
    let poses: Vec<Vec<f64>> = match &a.poses {
        Some(p) => load::pose_list(p, compiled, &a.ignore, "--poses")?,
        None => vec![kin_estimate::predict::midpoint_pose(m)],
    };
    if is_file {
        if a.every.is_some() {
            eprintln!(
                "error: --every samples a generated cycle; a cycle file's rows are its samples"
            );
            return Err(Failed::USAGE);
        }
        let options = data::ReadOptions {
            poses: true,
            series: true,
            ..a.ignore.read(true)
        };
        let series = match data::read_file(path, m, &options).map_err(load::read_failed)? {
            Observations::Points(p) => p,
            Observations::Lengths(_) => {
                eprintln!("error: `{text}`: a duty cycle is a point file, not a length file");
                return Err(Failed::INPUT);
            }
        };
        let n = series.rows.len();
        let own = series.pose.axes.iter().all(|c| c.len() == n) && !m.axes.is_empty();
        let points = if own && a.poses.is_none() {
            data::PointData {
                observed: Default::default(),
                ..series
            }
        } else {
            simulate::series_points(m, &series.rows, &poses)
        };
        return Ok((points, format!("duty cycle from `{text}`")));
    }
    let cycle = simulate::cycle::parse(text, m).map_err(|e| {
        eprintln!("error: --cycle: {e}");
        eprintln!("  {}", text.replace('\n', " "));
        eprintln!("  {}^", " ".repeat(e.column.saturating_sub(1)));
        eprintln!("note: the cycle's syntax is in spec/cli.md, \"Duty cycles\"");
        Failed::USAGE
    })?;
    let every = a.every.as_ref().map_or(60.0, |s| s.si);
    if cycle.duration() / every > 1e7 {
        eprintln!(
            "error: --every {}: more than 10 million samples",
            a.every.as_ref().map_or("1min", |s| s.text.as_str())
        );
        return Err(Failed::USAGE);
    }
    let (times, inputs) = cycle.sample(m, every);
    let rows = data::Rows {
        line: (1..=times.len()).collect(),
        tool: vec![0; times.len()],
        time: Some(times),
        inputs: inputs.into_iter().map(Some).collect(),
        ..data::Rows::default()
    };
    Ok((
        simulate::series_points(m, &rows, &poses),
        format!(
            "duty cycle `{}`, sampled every {}",
            text.replace('\n', " "),
            a.every.as_ref().map_or("1min", |s| s.text.as_str())
        ),
    ))
}

fn write(
    out: &Observations,
    m: &kin_compiler::ir::Machine,
    path: Option<&Path>,
    comments: Vec<String>,
    extra: Vec<data::ExtraColumn>,
    json: bool,
) -> Result<(), Failed> {
    let options = WriteOptions {
        comments,
        extra,
        ..WriteOptions::default()
    };
    if json {
        if let Some(p) = path {
            data::write_file(p, m, out, &options).map_err(|e| {
                eprintln!("error: {e}");
                Failed::USAGE
            })?;
        }
        // The document is built from the same checked columns as the file: the same columns,
        // units and values.
        let doc = data::measurements_json(m, out, &options).map_err(|e| {
            eprintln!("error: {e}");
            Failed::USAGE
        })?;
        println!("{}", crate::fit::to_json(&doc)?);
        return Ok(());
    }
    let result = match (path, out) {
        (Some(p), _) => data::write_file(p, m, out, &options),
        (None, Observations::Points(p)) => {
            data::write_points(std::io::stdout().lock(), m, p, &options)
        }
        (None, Observations::Lengths(l)) => {
            data::write_lengths(std::io::stdout().lock(), m, l, &options)
        }
    };
    result.map_err(|e| {
        eprintln!("error: {e}");
        Failed::USAGE
    })
}

pub fn eval(a: EvalArgs) -> ExitCode {
    let EvalArgs {
        machine,
        params,
        poses,
        output,
        json,
        components,
        engine,
        ignore,
        uncertainty,
        ellipsoid,
        nominal,
        color,
    } = a;
    finish((|| {
        if let Some(out) = output {
            let inputs: Vec<&Path> = [Some(machine), params, Some(poses)]
                .into_iter()
                .flatten()
                .collect();
            crate::files::check(out, &inputs)?;
        }
        let compiled = load::machine(machine, params, color)?;
        let m = &compiled.machine;
        let poses = load::observations(poses, &compiled, true, ignore)?;
        let fail = |e: simulate::SimulateError| {
            eprintln!("error: {e}");
            Failed::INPUT
        };
        let out =
            simulate::predict_with(m, &m.beta, &poses, components.mask(), engine).map_err(fail)?;
        let mut comments = vec![format!(
            "predicted by kin from `{}` (first-order model, eq. 2.24)",
            machine.display()
        )];
        let mut extra = Vec::new();
        if uncertainty {
            // `--uncertainty` requires `--params`; clap enforces it.
            let Some(path) = params else {
                return Err(Failed::USAGE);
            };
            let fit = load::fit_report(path)?;
            let u =
                simulate::uncertainty(m, &fit, &poses, components.mask(), engine).map_err(fail)?;
            extra = uncertainty_columns(u);
            // Which fitted wavelengths and time constants the uncertainty includes (said only
            // where the model has some).
            let coverage = PredictionCovariance::new(m, &fit)
                .map(|c| c.coverage().clone())
                .unwrap_or_default();
            let share = if coverage.included.is_empty() {
                String::new()
            } else {
                format!(
                    ", with the share of the fitted {}",
                    coverage.included.join(", ")
                )
            };
            comments.push(format!(
                "u_… : standard uncertainty (k = 1) of each prediction from the covariance of `{}` (eq. 4.12{share}); σ̂ = {:.4} {}",
                path.display(),
                fit.sigma,
                fit.error_unit
            ));
            if !coverage.missing.is_empty() {
                eprintln!(
                    "warning: `{}` holds no joint covariance of {}: their share of the uncertainty is left out (refit to include it)",
                    path.display(),
                    coverage.missing.join(", ")
                );
            }
            if let Some(level) = ellipsoid {
                let e = simulate::ellipsoids(m, &fit, &poses, level, engine).map_err(fail)?;
                extra.extend(ellipsoid_columns(&e));
                comments.push(format!(
                    "ell_… : {}% confidence ellipsoid of the position error (χ² with 3 degrees of freedom): semi-axes ell_a1 ≥ ell_a2 ≥ ell_a3 along the unit directions ell_u1 … ell_u3 (workpiece frame)",
                    level * 100.0
                ));
            }
        }
        if nominal {
            extra.extend(nominal_columns(m, &poses)?);
            comments.push(
                "px … pz, prx … prz: the nominal tool pose in the workpiece frame (position, and orientation as a rotation vector), forward kinematics of the nominal machine".into(),
            );
        }
        write(&out, m, output, comments, extra, json)
    })())
}

/// `px`, `py`, `pz` (length unit) and `prx`, `pry`, `prz` (angle unit): the nominal tool pose
/// in the workpiece frame at every row of a point file (exact forward kinematics).
fn nominal_columns(
    m: &kin_compiler::ir::Machine,
    poses: &Observations,
) -> Result<Vec<data::ExtraColumn>, Failed> {
    let Observations::Points(p) = poses else {
        eprintln!("error: --nominal needs a point file of poses: a length file has two per row");
        return Err(Failed::USAGE);
    };
    let mut values: [Vec<f64>; 6] = Default::default();
    let mut q = vec![0.0; m.axes.len()];
    for row in 0..p.rows.len() {
        for (slot, column) in q.iter_mut().zip(&p.pose.axes) {
            *slot = column.get(row).copied().unwrap_or(f64::NAN);
        }
        let offset = p.rows.tool_offset.as_ref().and_then(|o| {
            let v: [f64; 3] = std::array::from_fn(|k| o[k].get(row).copied().unwrap_or(f64::NAN));
            v.iter().all(|x| x.is_finite()).then_some(v)
        });
        let pose = kin_model::kinematics::Pose {
            q: &q,
            tool: p.rows.tool.get(row).copied().unwrap_or(0),
            tool_offset: offset,
        };
        let t = kin_model::exact::nominal_transform(m, &pose).map_err(|e| {
            let line = p.rows.line.get(row).copied().unwrap_or(0);
            eprintln!("error: line {line}: {e}");
            Failed::INPUT
        })?;
        let r = nalgebra::Rotation3::from_matrix_unchecked(t.fixed_view::<3, 3>(0, 0).into_owned())
            .scaled_axis();
        for (k, column) in values.iter_mut().enumerate() {
            column.push(if k < 3 { t[(k, 3)] } else { r[k - 3] });
        }
    }
    let names = ["px", "py", "pz", "prx", "pry", "prz"];
    Ok(names
        .iter()
        .zip(values)
        .enumerate()
        .map(|(k, (name, values))| data::ExtraColumn {
            name: (*name).into(),
            quantity: if k < 3 {
                data::ExtraQuantity::Length
            } else {
                data::ExtraQuantity::Angle
            },
            values,
        })
        .collect())
}

/// `ell_a1 … ell_a3` (error unit) and `ell_u1x … ell_u3z` (direction cosines) for the writer.
fn ellipsoid_columns(e: &[simulate::Ellipsoid]) -> Vec<data::ExtraColumn> {
    let mut out = Vec::with_capacity(12);
    for k in 0..3 {
        out.push(data::ExtraColumn {
            name: format!("ell_a{}", k + 1),
            quantity: data::ExtraQuantity::Error,
            values: e.iter().map(|x| x.semi_axes[k]).collect(),
        });
    }
    for k in 0..3 {
        for (c, axis) in ["x", "y", "z"].iter().enumerate() {
            out.push(data::ExtraColumn {
                name: format!("ell_u{}{axis}", k + 1),
                quantity: data::ExtraQuantity::Ratio,
                values: e.iter().map(|x| x.directions[k][c]).collect(),
            });
        }
    }
    out
}

/// `u_ex` … `u_erz` (or `u_dL`) for the writer.
fn uncertainty_columns(u: simulate::Uncertainty) -> Vec<data::ExtraColumn> {
    match u {
        simulate::Uncertainty::Points(columns) => data::OBSERVED
            .iter()
            .zip(columns)
            .enumerate()
            .filter_map(|(k, (name, values))| {
                Some(data::ExtraColumn {
                    name: format!("u_{name}"),
                    quantity: if k < 3 {
                        data::ExtraQuantity::Error
                    } else {
                        data::ExtraQuantity::Tilt
                    },
                    values: values?,
                })
            })
            .collect(),
        simulate::Uncertainty::Lengths(values) => vec![data::ExtraColumn {
            name: "u_dL".into(),
            quantity: data::ExtraQuantity::Error,
            values,
        }],
    }
}
