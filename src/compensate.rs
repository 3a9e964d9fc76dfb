//! `kin compensate`: the joint corrections of a positioning machine at commanded poses (a poses
//! file or a grid), as a CSV, or per-axis controller tables (`--table linuxcnc`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::ir::{JointKind, Machine};
use kin_runtime::axis_table::{self, AxisTable};
use kin_runtime::compensate::{Compensator, Correction, Options};
use kin_runtime::data::{self, ExtraColumn, ExtraQuantity, Observations, PointData, WriteOptions};
use kin_runtime::states::States;

use crate::grid::{self, Grid};
use crate::load::{self, Failed};

/// Which components of the tool-location error the corrections minimise.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Correct {
    /// Position and orientation, a rotation of one tilt unit weighing as one error unit: the
    /// machine corrects all its joints can (a 3-axis machine: the position).
    Pose,
    /// The position only; orientation errors are left alone.
    Position,
}

/// A controller table format.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Table {
    /// LinuxCNC joint compensation files (`COMP_FILE`, `COMP_FILE_TYPE = 0`), one per axis.
    Linuxcnc,
}

pub struct CompensateArgs {
    pub machine: PathBuf,
    pub fit: PathBuf,
    pub poses: Option<PathBuf>,
    pub grid: Option<String>,
    pub correct: Correct,
    pub table: Option<Table>,
    pub output: PathBuf,
    pub ignore: crate::args::DataOptions,
    pub color: bool,
}

pub fn run(a: CompensateArgs) -> ExitCode {
    Failed::exit(compensate(a))
}

fn compensate(a: CompensateArgs) -> Result<(), Failed> {
    let inputs: Vec<&Path> = [Some(a.machine.as_path()), Some(a.fit.as_path())]
        .into_iter()
        .chain([a.poses.as_deref()])
        .flatten()
        .collect();
    if a.table.is_none() {
        crate::files::check(&a.output, &inputs)?;
    } else if a.output.exists() && !a.output.is_dir() {
        eprintln!(
            "error: with --table, -o names a folder for the tables; `{}` is a file",
            a.output.display()
        );
        return Err(Failed::USAGE);
    }
    let compiled = load::machine(&a.machine, Some(&a.fit), a.color)?;
    let m = &compiled.machine;
    let options = match a.correct {
        Correct::Pose => Options::pose(m),
        Correct::Position => Options::position(m),
    };
    let mut comp = Compensator::new(m, &m.beta, options).map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let grid = match &a.grid {
        Some(spec) => Some(grid::parse(spec, m).map_err(|e| {
            eprintln!("error: --grid: {e}");
            Failed::USAGE
        })?),
        None => None,
    };
    if let Some(Table::Linuxcnc) = a.table {
        let Some(grid) = grid else {
            eprintln!("error: a table is evaluated on a grid: give --grid (e.g. X=0:500:10)");
            return Err(Failed::USAGE);
        };
        return linuxcnc(&a, m, &mut comp, &grid, &inputs);
    }
    let (points, source) = match (&a.poses, &grid) {
        (Some(p), None) => match load::observations(p, &compiled, true, &a.ignore)? {
            Observations::Points(points) => (points, format!("`{}`, line", p.display())),
            Observations::Lengths(_) => {
                eprintln!(
                    "error: `{}` is a length file: compensation needs one commanded pose per row (a point file's columns)",
                    p.display()
                );
                return Err(Failed::INPUT);
            }
        },
        (None, Some(g)) => (g.points(m), "--grid, pose".to_string()),
        _ => {
            eprintln!("error: give the commanded poses: --poses FILE or --grid SPEC");
            return Err(Failed::USAGE);
        }
    };
    let corrections = corrections(m, &mut comp, &points, &source)?;
    let fit = load::fit_report(&a.fit)?;
    let uncertainty = kin_runtime::simulate::uncertainty(
        m,
        &fit,
        &Observations::Points(points.clone()),
        [true; 6],
        kin_runtime::engine::Engine::Interp,
    )
    .map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    let weighted = options.weights.iter().filter(|w| **w > 0.0).count();
    summary(m, &corrections, weighted);
    write_csv(&a, m, points, &corrections, uncertainty)
}

/// The correction of every row of `points`; a row the compensator refuses is reported with
/// its line.
fn corrections(
    m: &Machine,
    comp: &mut Compensator<'_>,
    points: &PointData,
    source: &str,
) -> Result<Vec<Correction>, Failed> {
    let states = States::new(m, &points.rows, &points.pose, "").map_err(|e| {
        eprintln!("error: {e}");
        Failed::INPUT
    })?;
    (0..states.len())
        .map(|r| {
            comp.compensate(&states.get(r)).map_err(|e| {
                let line = states.line.get(r).copied().unwrap_or(0);
                eprintln!("error: {source} {line}: {e}");
                Failed::INPUT
            })
        })
        .collect()
}

fn norm3(v: &[f64; 6], from: usize) -> f64 {
    v.iter()
        .skip(from)
        .take(3)
        .map(|x| x * x)
        .sum::<f64>()
        .sqrt()
}

/// Before and after on standard error: what compensation achieves and what stays.
fn summary(m: &Machine, c: &[Correction], weighted: usize) {
    let e = m.units.error.as_difference();
    let t = m.units.tilt.as_difference();
    let max = |f: &dyn Fn(&Correction) -> f64| c.iter().map(f).fold(0.0_f64, f64::max);
    eprintln!(
        "{} poses: largest predicted position error {:.4} {} before compensation, {:.4} {} after; orientation {:.4} {} before, {:.4} {} after",
        c.len(),
        e.from_si(max(&|c| norm3(&c.before, 0))),
        e.name,
        e.from_si(max(&|c| norm3(&c.after, 0))),
        e.name,
        t.from_si(max(&|c| norm3(&c.before, 3))),
        t.name,
        t.from_si(max(&|c| norm3(&c.after, 3))),
        t.name,
    );
    if let Some(rank) = c.iter().map(|c| c.rank).min() {
        if rank < weighted {
            eprintln!(
                "note: the axes can move at most {rank} independent combinations of the weighted components; what they cannot move stays in the rest_… columns"
            );
        }
    }
}

fn write_csv(
    a: &CompensateArgs,
    m: &Machine,
    mut points: PointData,
    c: &[Correction],
    uncertainty: kin_runtime::simulate::Uncertainty,
) -> Result<(), Failed> {
    for (k, slot) in points.observed.iter_mut().enumerate() {
        *slot = Some(c.iter().map(|c| c.before[k]).collect());
    }
    let mut extra: Vec<ExtraColumn> = m
        .axes
        .iter()
        .enumerate()
        .map(|(j, axis)| ExtraColumn {
            name: format!("corr_{}", axis.name),
            quantity: match axis.kind {
                JointKind::Prismatic => ExtraQuantity::Error,
                JointKind::Revolute => ExtraQuantity::Tilt,
            },
            values: c
                .iter()
                .map(|c| c.dq.get(j).copied().unwrap_or(0.0))
                .collect(),
        })
        .collect();
    for (k, name) in data::OBSERVED.iter().enumerate() {
        extra.push(ExtraColumn {
            name: format!("rest_{name}"),
            quantity: if k < 3 {
                ExtraQuantity::Error
            } else {
                ExtraQuantity::Tilt
            },
            values: c.iter().map(|c| c.after[k]).collect(),
        });
    }
    if let kin_runtime::simulate::Uncertainty::Points(columns) = uncertainty {
        for (k, (name, values)) in data::OBSERVED.iter().zip(columns).enumerate() {
            if let Some(values) = values {
                extra.push(ExtraColumn {
                    name: format!("u_{name}"),
                    quantity: if k < 3 {
                        ExtraQuantity::Error
                    } else {
                        ExtraQuantity::Tilt
                    },
                    values,
                });
            }
        }
    }
    let from = match (&a.poses, &a.grid) {
        (Some(p), _) => format!("the poses of `{}`", p.display()),
        (None, g) => format!("the grid {}", g.as_deref().unwrap_or("")),
    };
    let options = WriteOptions {
        comments: vec![
            format!(
                "compensation by kin of `{}` with the fit `{}`, at {from}",
                a.machine.display(),
                a.fit.display()
            ),
            "ex … erz: predicted error (actual − nominal) at the commanded pose; corr_AXIS: add to the command; rest_…: predicted error after the correction (what the axes cannot correct); u_…: standard uncertainty (k = 1) of the predicted error (eq. 4.12)".into(),
        ],
        extra,
        ..WriteOptions::default()
    };
    data::write_file(&a.output, m, &Observations::Points(points), &options).map_err(|e| {
        eprintln!("error: {e}");
        Failed::USAGE
    })
}

/// LinuxCNC's limit on the entries of one joint's compensation file.
const LINUXCNC_MAX_ENTRIES: usize = 256;

/// One `AXIS.comp` per axis the grid ranges over, plus a note of what the tables leave out.
fn linuxcnc(
    a: &CompensateArgs,
    m: &Machine,
    comp: &mut Compensator<'_>,
    grid: &Grid,
    inputs: &[&Path],
) -> Result<(), Failed> {
    let ranged: Vec<usize> = (0..m.axes.len())
        .filter(|&j| grid.values.get(j).is_some_and(|v| v.len() > 1))
        .collect();
    if ranged.is_empty() {
        eprintln!("error: --grid ranges over no axis: give at least one as FROM:TO:STEP");
        return Err(Failed::USAGE);
    }
    for &j in &ranged {
        let n = grid.values.get(j).map_or(0, Vec::len);
        if n > LINUXCNC_MAX_ENTRIES {
            eprintln!(
                "error: --grid gives axis {} {n} positions; a LinuxCNC compensation file holds at most {LINUXCNC_MAX_ENTRIES}: a larger STEP",
                m.axes.get(j).map_or("?", |x| x.name.as_str())
            );
            return Err(Failed::USAGE);
        }
    }
    if let Err(e) = std::fs::create_dir_all(&a.output) {
        eprintln!("error: cannot create `{}`: {e}", a.output.display());
        return Err(Failed::USAGE);
    }
    let path_of = |j: usize| {
        a.output.join(format!(
            "{}.comp",
            m.axes.get(j).map_or("?", |x| x.name.as_str())
        ))
    };
    let note_path = a.output.join("kin-compensation.txt");
    for &j in &ranged {
        crate::files::check(&path_of(j), inputs)?;
    }
    crate::files::check(&note_path, inputs)?;

    // The reference pose: every axis at the middle of its grid values.
    let reference_q: Vec<f64> = grid
        .values
        .iter()
        .map(|v| v.get(v.len() / 2).copied().unwrap_or(0.0))
        .collect();
    let inputs_si: Vec<f64> = grid.inputs.iter().map(|v| v.unwrap_or(0.0)).collect();
    let lags: Vec<f64> = m
        .lags
        .iter()
        .map(|l| inputs_si.get(l.input).copied().unwrap_or(0.0))
        .collect();
    let reference = kin_runtime::interp::State {
        q: &reference_q,
        inputs: &inputs_si,
        lags: &lags,
        time: 0.0,
        dirs: &grid.dirs,
        tool: grid.tool,
        tool_offset: None,
    };
    let fail = |e: kin_runtime::compensate::CompensateError| {
        eprintln!("error: {e}");
        Failed::INPUT
    };
    let mut tables: Vec<AxisTable> = Vec::with_capacity(ranged.len());
    for &j in &ranged {
        let nodes = grid.values.get(j).cloned().unwrap_or_default();
        tables.push(axis_table::axis_table(comp, &reference, j, &nodes).map_err(fail)?);
    }

    // What the tables do over the whole grid, against the full compensation.
    let points = grid.points(m);
    let states = States::new(m, &points.rows, &points.pose, "").map_err(|e| {
        eprintln!("error: --grid: {e}");
        Failed::INPUT
    })?;
    let (mut before, mut with_tables, mut full) = (0.0_f64, 0.0_f64, 0.0_f64);
    let mut dq = vec![0.0; m.axes.len()];
    for r in 0..states.len() {
        let s = states.get(r);
        dq.fill(0.0);
        for t in &tables {
            let q = s.q.get(t.axis).copied().unwrap_or(0.0);
            let dir = s.dirs.get(t.axis).copied().unwrap_or(1.0);
            if let Some(slot) = dq.get_mut(t.axis) {
                *slot = t.correction(q, if dir.is_nan() { 1.0 } else { dir });
            }
        }
        let c = comp.compensate(&s).map_err(fail)?;
        let rest = comp.remaining(&s, &dq).map_err(fail)?;
        before = before.max(norm3(&c.before, 0));
        full = full.max(norm3(&c.after, 0));
        with_tables = with_tables.max(norm3(&rest, 0));
    }

    let e = m.units.error.as_difference();
    let mut note = String::new();
    let _ = writeln!(
        note,
        "LinuxCNC joint compensation files written by kin from `{}` with the fit `{}`.",
        a.machine.display(),
        a.fit.display()
    );
    let _ = writeln!(
        note,
        "Each AXIS.comp is for that joint's [JOINT_n] section: COMP_FILE = AXIS.comp, COMP_FILE_TYPE = 0."
    );
    let _ = writeln!(
        note,
        "Lines: nominal position, position reached moving in +, position reached moving in −, in {} (rotary axes in {}); LinuxCNC's machine units must be these.",
        m.units.length.name, m.units.angle.name
    );
    let _ = writeln!(
        note,
        "Reference pose of every table (the other axes, tool, inputs, directions): {}.",
        describe_reference(m, &reference_q, grid)
    );
    let _ = writeln!(note);
    let _ = writeln!(
        note,
        "What the model holds that these files cannot: a table is a function of its own joint's position and direction only, so cross-couplings (errors of one axis that depend on another's position), straightness and squareness, angular errors with their Abbe offsets away from the reference pose, and terms of the inputs (temperatures, load) are not in them; orientation errors are not corrected at all."
    );
    let _ = writeln!(
        note,
        "Over the {} grid poses the model predicts a largest position error of {:.4} {u} without compensation, {:.4} {u} with these tables, {:.4} {u} with the full compensation (`kin compensate --grid … -o OUT.csv`).",
        states.len(),
        e.from_si(before),
        e.from_si(with_tables),
        e.from_si(full),
        u = e.name
    );
    for t in &tables {
        // A correction is small: shown in the error (or tilt) unit, not the axis's own.
        let unit = match m.axes.get(t.axis).map(|a| a.kind) {
            Some(JointKind::Revolute) => m.units.tilt.as_difference(),
            _ => e.clone(),
        };
        let _ = writeln!(
            note,
            "{}.comp: {} entries; between them, linear interpolation departs from the model's correction by at most {:.4} {} (at the midpoints).",
            m.axes.get(t.axis).map_or("?", |a| a.name.as_str()),
            t.nominal.len(),
            unit.from_si(t.interpolation_error),
            unit.name,
        );
    }
    // The tables and their note are one result: all are replaced or none (a full disk halfway
    // must not leave one axis's new table beside another's old one).
    let mut set: Vec<(PathBuf, Vec<u8>)> = tables
        .iter()
        .map(|t| (path_of(t.axis), t.linuxcnc(unit_of(m, t.axis)).into_bytes()))
        .collect();
    set.push((note_path.clone(), note.clone().into_bytes()));
    let refs: Vec<(&Path, &[u8])> = set
        .iter()
        .map(|(p, c)| (p.as_path(), c.as_slice()))
        .collect();
    kin_runtime::output::replace_all(&refs).map_err(|e| {
        eprintln!(
            "error: cannot write the tables into `{}`: {e}",
            a.output.display()
        );
        Failed::USAGE
    })?;
    eprint!("{note}");
    Ok(())
}

fn unit_of(m: &Machine, axis: usize) -> &kin_compiler::units::Unit {
    match m.axes.get(axis).map(|a| a.kind) {
        Some(JointKind::Revolute) => &m.units.angle,
        _ => &m.units.length,
    }
}

fn describe_reference(m: &Machine, q: &[f64], grid: &Grid) -> String {
    let mut parts: Vec<String> = m
        .axes
        .iter()
        .zip(q)
        .enumerate()
        .map(|(j, (axis, v))| {
            let u = unit_of(m, j);
            format!("{}={} {}", axis.name, u.as_difference().from_si(*v), u.name)
        })
        .collect();
    if let Some(t) = m.tools.get(grid.tool) {
        parts.push(format!("tool={}", t.name));
    }
    for (input, v) in m.inputs.iter().zip(&grid.inputs) {
        if let Some(v) = v {
            let u = if input.absolute {
                input.unit.as_absolute()
            } else {
                input.unit.as_difference()
            };
            parts.push(format!(
                "{}={} {}",
                input.name,
                u.from_si(*v),
                input.unit.name
            ));
        }
    }
    parts.join(", ")
}
