//! `kin compensate`: the joint corrections of a positioning machine at commanded poses (a poses
//! file or a grid), as a CSV, or per-axis controller tables (`--table linuxcnc|sinumerik|isg-lsec|volcomp`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::ir::{JointKind, Machine};
use kin_data::data::{self, ExtraColumn, ExtraQuantity, Observations, PointData, WriteOptions};
use kin_machine::axis_table::{self, AxisTable, Sweep};
use kin_machine::component_errors::{self, ComponentTable, Components};
use kin_machine::controller_tables::{self, fixed, AxisUnit, SinumerikCec, SinumerikLec};
use kin_model::compensate::{Compensator, Correction, Options};
use kin_model::states::States;

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

/// A controller table format (spec/compensation.md).
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Table {
    /// LinuxCNC joint compensation files (`COMP_FILE`, `COMP_FILE_TYPE = 0`), one per axis.
    Linuxcnc,
    /// SINUMERIK 840D part programs: leadscrew error compensation (`AX_EEC.INI`,
    /// `$AA_ENC_COMP`) and sag / cross-error compensation between axes and for backlash
    /// (`NC_CEC.INI`, `$AN_CEC`).
    Sinumerik,
    /// ISG kernel (Beckhoff TwinCAT CNC) bilateral leadscrew error compensation lists
    /// (`kw.ssfk`), one `AXIS.lis` per axis.
    IsgLsec,
    /// ISG / Beckhoff TwinCAT VolComp: the ISO 230-1 component errors of each axis
    /// (`X EXX EYX EZX EAX EBX ECX`) as ISG CSV files, one `AXIS.csv` per axis.
    Volcomp,
}

impl Table {
    fn title(self) -> &'static str {
        match self {
            Table::Linuxcnc => "LinuxCNC joint compensation files",
            Table::Sinumerik => "SINUMERIK 840D leadscrew and sag compensation",
            Table::IsgLsec => "ISG leadscrew error compensation lists",
            Table::Volcomp => "ISG / Beckhoff VolComp ISO 230-1 component errors",
        }
    }
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
    if let Some(format) = a.table {
        let Some(grid) = grid else {
            eprintln!("error: a table is evaluated on a grid: give --grid (e.g. X=0:500:10)");
            return Err(Failed::USAGE);
        };
        return tables(&a, format, m, &mut comp, &grid, &inputs);
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
    let uncertainty = kin_estimate::simulate::uncertainty(
        m,
        &fit,
        &Observations::Points(points.clone()),
        [true; 6],
        kin_model::engine::Engine::Interp,
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
    uncertainty: kin_estimate::simulate::Uncertainty,
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
    if let kin_estimate::simulate::Uncertainty::Points(columns) = uncertainty {
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

/// A cross-axis table whose corrections all stay below this (m or rad, 1 nm or 1 nrad) is not
/// written: it would only add noise to the controller's sum. Also the reversal below which an
/// own table is direction-independent.
const NEGLIGIBLE: f64 = 1e-9;

/// The reference pose of every table: each axis at the middle of its grid values, the grid's
/// inputs (their lags in steady state), tool and directions.
struct Reference {
    q: Vec<f64>,
    inputs: Vec<f64>,
    lags: Vec<f64>,
    dirs: Vec<f64>,
    tool: usize,
}

impl Reference {
    fn new(m: &Machine, grid: &Grid) -> Reference {
        let inputs: Vec<f64> = grid.inputs.iter().map(|v| v.unwrap_or(0.0)).collect();
        Reference {
            q: grid
                .values
                .iter()
                .map(|v| v.get(v.len() / 2).copied().unwrap_or(0.0))
                .collect(),
            lags: m
                .lags
                .iter()
                .map(|l| l.steady(inputs.get(l.input).copied().unwrap_or(0.0)))
                .collect(),
            inputs,
            dirs: grid.dirs.clone(),
            tool: grid.tool,
        }
    }

    fn state(&self) -> kin_model::interp::State<'_> {
        kin_model::interp::State {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: 0.0,
            dirs: &self.dirs,
            tool: self.tool,
            tool_offset: None,
        }
    }
}

/// The largest predicted position error over the grid without compensation, with the tables,
/// and with the full compensation.
struct GridSummary {
    poses: usize,
    before: f64,
    with_tables: f64,
    full: f64,
}

/// Evaluates `tables_dq` (the corrections the tables give at a pose) over every grid pose,
/// with the exact transforms, against the full compensation.
fn grid_summary(
    m: &Machine,
    comp: &mut Compensator<'_>,
    grid: &Grid,
    mut tables_dq: impl FnMut(&kin_model::interp::State<'_>, &mut [f64]),
) -> Result<GridSummary, Failed> {
    let points = grid.points(m);
    let states = States::new(m, &points.rows, &points.pose, "").map_err(|e| {
        eprintln!("error: --grid: {e}");
        Failed::INPUT
    })?;
    let mut summary = GridSummary {
        poses: states.len(),
        before: 0.0,
        with_tables: 0.0,
        full: 0.0,
    };
    let mut dq = vec![0.0; m.axes.len()];
    for r in 0..states.len() {
        let s = states.get(r);
        dq.fill(0.0);
        tables_dq(&s, &mut dq);
        let c = comp.compensate(&s).map_err(input_error)?;
        let rest = comp.remaining(&s, &dq).map_err(input_error)?;
        summary.before = summary.before.max(norm3(&c.before, 0));
        summary.full = summary.full.max(norm3(&c.after, 0));
        summary.with_tables = summary.with_tables.max(norm3(&rest, 0));
    }
    Ok(summary)
}

fn input_error(e: impl std::fmt::Display) -> Failed {
    eprintln!("error: {e}");
    Failed::INPUT
}

fn axis_name(m: &Machine, j: usize) -> &str {
    m.axes.get(j).map_or("?", |a| a.name.as_str())
}

fn direction_of(s: &kin_model::interp::State<'_>, axis: usize) -> f64 {
    let d = s.dirs.get(axis).copied().unwrap_or(1.0);
    if d.is_nan() {
        1.0
    } else {
        d
    }
}

/// Per-axis controller tables for every axis the grid ranges over, with a note of what they
/// hold and what they cannot, all replaced as one set.
fn tables(
    a: &CompensateArgs,
    format: Table,
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
    let nodes = |j: usize| grid.values.get(j).cloned().unwrap_or_default();
    // What each format cannot state at all is refused before any work.
    match format {
        Table::Linuxcnc => {
            for &j in &ranged {
                let n = nodes(j).len();
                if n > LINUXCNC_MAX_ENTRIES {
                    eprintln!(
                        "error: --grid gives axis {} {n} positions; a LinuxCNC compensation file holds at most {LINUXCNC_MAX_ENTRIES}: a larger STEP",
                        axis_name(m, j)
                    );
                    return Err(Failed::USAGE);
                }
            }
        }
        Table::Sinumerik => {
            for &j in &ranged {
                if equidistant(&nodes(j)).is_none() {
                    eprintln!(
                        "error: --grid: SINUMERIK tables are equidistant, but the positions of axis {} are not: choose a STEP that divides TO − FROM",
                        axis_name(m, j)
                    );
                    return Err(Failed::USAGE);
                }
            }
        }
        Table::IsgLsec => {
            for &j in &ranged {
                let unit = AxisUnit::of(m.axes.get(j).map_or(JointKind::Prismatic, |x| x.kind));
                if nodes(j)
                    .iter()
                    .any(|p| controller_tables::isg_position(*p, unit).is_none())
                {
                    eprintln!(
                        "error: --grid: an ISG list states positions in whole 0.1 um (0.0001 deg); a position of axis {} is not one: choose FROM and STEP on that grid",
                        axis_name(m, j)
                    );
                    return Err(Failed::USAGE);
                }
            }
        }
        Table::Volcomp => {
            for &j in &ranged {
                let name = axis_name(m, j);
                if !matches!(name, "X" | "Y" | "Z" | "A" | "B" | "C") {
                    eprintln!(
                        "error: VolComp names axes by the ISO 230-1 letters X, Y, Z, A, B, C; axis `{name}` is none of them (rename it in the model)"
                    );
                    return Err(Failed::INPUT);
                }
                if let Err(e) = kin_machine::component_errors::element_of(m, j) {
                    eprintln!("error: --table volcomp: {e}");
                    return Err(Failed::INPUT);
                }
            }
        }
    }
    if let Err(e) = std::fs::create_dir_all(&a.output) {
        eprintln!("error: cannot create `{}`: {e}", a.output.display());
        return Err(Failed::USAGE);
    }
    let reference = Reference::new(m, grid);
    let e = m.units.error.as_difference();
    let t = m.units.tilt.as_difference();
    let mut note = String::new();
    let _ = writeln!(
        note,
        "Controller compensation tables ({}) written by kin from `{}` with the fit `{}`.",
        format.title(),
        a.machine.display(),
        a.fit.display()
    );
    let _ = writeln!(
        note,
        "Reference pose of every table (the other axes, tool, inputs, directions): {}.",
        describe_reference(m, &reference.q, grid)
    );
    let mut files: Vec<(String, String)> = Vec::new();
    let summary = match format {
        Table::Linuxcnc | Table::IsgLsec => {
            let mut own: Vec<AxisTable> = Vec::with_capacity(ranged.len());
            for &j in &ranged {
                own.push(
                    axis_table::axis_table(comp, &reference.state(), j, &nodes(j))
                        .map_err(input_error)?,
                );
            }
            for table in &own {
                let name = axis_name(m, table.axis);
                if let Table::Linuxcnc = format {
                    files.push((
                        format!("{name}.comp"),
                        table.linuxcnc(unit_of(m, table.axis)),
                    ));
                } else {
                    let kind = m.axes.get(table.axis).map(|x| x.kind);
                    let unit = kind.map_or(AxisUnit::Millimetre, AxisUnit::of);
                    let comments = vec![
                        format!("Leadscrew error compensation of axis {name} written by kin from `{}` with the fit `{}`.", a.machine.display(), a.fit.display()),
                        "pos/neg: position reached minus setpoint moving in +/- (the controller subtracts it), 0.1 um (0.0001 deg on a rotary axis).".to_string(),
                        "kopf.achs_nr is the axis's index in the model plus 1: set the logical axis number of your configuration.".to_string(),
                        "Not in this list: what depends on other axes or inputs, and orientation errors (kin-compensation.txt).".to_string(),
                    ];
                    let Some(text) =
                        controller_tables::isg_lsec(table.axis + 1, name, unit, table, &comments)
                    else {
                        eprintln!(
                            "error: --grid: an ISG list states positions in whole 0.1 um (0.0001 deg); a position of axis {name} is not one: choose FROM and STEP on that grid"
                        );
                        return Err(Failed::USAGE);
                    };
                    files.push((format!("{name}.lis"), text));
                }
                let unit = match m.axes.get(table.axis).map(|x| x.kind) {
                    Some(JointKind::Revolute) => t.clone(),
                    _ => e.clone(),
                };
                let _ = writeln!(
                    note,
                    "{name}: {} positions; between them, linear interpolation departs from the model's correction by at most {:.4} {} (at the midpoints).",
                    table.nominal.len(),
                    unit.from_si(table.interpolation_error),
                    unit.name,
                );
            }
            if let Table::Linuxcnc = format {
                let _ = writeln!(
                    note,
                    "Each AXIS.comp is for that joint's [JOINT_n] section: COMP_FILE = AXIS.comp, COMP_FILE_TYPE = 0."
                );
                let _ = writeln!(
                    note,
                    "Lines: nominal position, position reached moving in +, position reached moving in −, in {} (rotary axes in {}); LinuxCNC's machine units must be these.",
                    m.units.length.name, m.units.angle.name
                );
            } else {
                let _ = writeln!(
                    note,
                    "Each AXIS.lis is an ISG leadscrew error compensation list (kw.ssfk, bilateral, metric): name it in the start-up list (achs_kw[i], achs_kw_log_ax_nr[i]) and enable the compensation in the axis's parameters; values are rounded to 0.1 um (0.0001 deg)."
                );
            }
            let _ = writeln!(
                note,
                "What the model holds that these tables cannot: a table is a function of its own axis's position and direction only, so cross-couplings (errors of one axis that depend on another's position), straightness and squareness, angular errors with their Abbe offsets away from the reference pose, and terms of the inputs (temperatures, load) are not in them; orientation errors are not corrected at all."
            );
            grid_summary(m, comp, grid, |s, dq| {
                for table in &own {
                    let q = s.q.get(table.axis).copied().unwrap_or(0.0);
                    if let Some(slot) = dq.get_mut(table.axis) {
                        *slot = table.correction(q, direction_of(s, table.axis));
                    }
                }
            })?
        }
        Table::Sinumerik => {
            sinumerik(a, m, comp, grid, &reference, &ranged, &mut files, &mut note)?
        }
        Table::Volcomp => volcomp(a, m, comp, grid, &reference, &ranged, &mut files, &mut note)?,
    };
    let _ = writeln!(
        note,
        "Over the {} grid poses the model predicts a largest position error of {:.4} {u} without compensation, {:.4} {u} with these tables, {:.4} {u} with the full compensation (`kin compensate --grid … -o OUT.csv`).",
        summary.poses,
        e.from_si(summary.before),
        e.from_si(summary.with_tables),
        e.from_si(summary.full),
        u = e.name
    );
    let note_path = a.output.join("kin-compensation.txt");
    let paths: Vec<PathBuf> = files.iter().map(|(f, _)| a.output.join(f)).collect();
    for p in paths.iter().chain([&note_path]) {
        crate::files::check(p, inputs)?;
    }
    // The tables and their note are one result: all are replaced or none (a full disk halfway
    // must not leave one axis's new table beside another's old one).
    let mut set: Vec<(&Path, &[u8])> = paths
        .iter()
        .zip(&files)
        .map(|(p, (_, text))| (p.as_path(), text.as_bytes()))
        .collect();
    set.push((note_path.as_path(), note.as_bytes()));
    kin_data::output::replace_all(&set).map_err(|e| {
        eprintln!(
            "error: cannot write the tables into `{}`: {e}",
            a.output.display()
        );
        Failed::USAGE
    })?;
    eprint!("{note}");
    Ok(())
}

/// The step of equidistant positions (SI), `None` when they are not.
fn equidistant(nodes: &[f64]) -> Option<f64> {
    let (first, last) = (*nodes.first()?, *nodes.last()?);
    let n = nodes.len().checked_sub(1).filter(|n| *n > 0)?;
    let step = (last - first) / n as f64;
    nodes
        .windows(2)
        .all(|w| ((w[1] - w[0]) - step).abs() <= 1e-9 * step.abs())
        .then_some(step)
}

/// SINUMERIK 840D: the own-axis (LEC) and cross-axis (CEC) tables from the full compensation
/// swept along every ranged axis. The correction of axis j at a pose is taken as its own
/// table at q_j plus, for every other ranged axis i, the cross table of i → j at q_i.
#[allow(clippy::too_many_arguments)]
fn sinumerik(
    a: &CompensateArgs,
    m: &Machine,
    comp: &mut Compensator<'_>,
    grid: &Grid,
    reference: &Reference,
    ranged: &[usize],
    files: &mut Vec<(String, String)>,
    note: &mut String,
) -> Result<GridSummary, Failed> {
    let base = comp.compensate(&reference.state()).map_err(input_error)?.dq;
    let mut sweeps: Vec<Sweep> = Vec::with_capacity(ranged.len());
    for &j in ranged {
        let nodes = grid.values.get(j).cloned().unwrap_or_default();
        sweeps.push(axis_table::sweep(comp, &reference.state(), j, &nodes).map_err(input_error)?);
    }
    let kind = |j: usize| m.axes.get(j).map_or(JointKind::Prismatic, |x| x.kind);
    let unit = |j: usize| AxisUnit::of(kind(j));
    let own: Vec<AxisTable> = sweeps.iter().map(|s| s.table(s.axis, None)).collect();
    let mut cross: Vec<(usize, AxisTable)> = Vec::new();
    for s in &sweeps {
        for &out in ranged.iter().filter(|&&o| o != s.axis) {
            let table = s.table(out, Some(base.get(out).copied().unwrap_or(0.0)));
            let largest = table.forward.iter().fold(0.0_f64, |x, v| x.max(v.abs()));
            if largest >= NEGLIGIBLE {
                cross.push((out, table));
            }
        }
    }
    let e = m.units.error.as_difference();
    let t = m.units.tilt.as_difference();
    let small = |j: usize| match kind(j) {
        JointKind::Revolute => t.clone(),
        JointKind::Prismatic => e.clone(),
    };
    // A value is what the axis's measuring system is off by: a positive one moves the axis the
    // negative way, so it is the negated correction.
    let values = |j: usize, corrections: &[f64]| -> Vec<f64> {
        corrections.iter().map(|c| unit(j).from_si(-c)).collect()
    };
    let step_min = |table: &AxisTable| {
        let u = unit(table.axis);
        let step = equidistant(&table.nominal).unwrap_or(0.0);
        (
            u.from_si(table.nominal.first().copied().unwrap_or(0.0)),
            u.from_si(step),
        )
    };
    let mut lec = Vec::new();
    let mut cec = Vec::new();
    for table in &own {
        let j = table.axis;
        let (min, step) = step_min(table);
        let reversal = table
            .forward
            .iter()
            .zip(&table.reverse)
            .fold(0.0_f64, |x, (f, r)| x.max((f - r).abs()));
        let name = axis_name(m, j);
        if reversal >= NEGLIGIBLE {
            // K3: position-dependent backlash is two cross tables of the axis onto itself, one
            // per direction.
            for (direction, corrections) in [(1, &table.forward), (-1, &table.reverse)] {
                cec.push(SinumerikCec {
                    input: name,
                    output: name,
                    min,
                    step,
                    direction,
                    values: values(j, corrections),
                });
            }
            let _ = writeln!(
                note,
                "{name}: its own table differs between the directions by up to {:.4} {} (backlash), so it is written as two direction-dependent tables of NC_CEC.INI ($AN_CEC_DIRECTION 1 and -1), not as leadscrew compensation.",
                small(j).from_si(reversal),
                small(j).name
            );
        } else {
            lec.push(SinumerikLec {
                name,
                unit: unit(j),
                min,
                step,
                values: values(j, &table.forward),
            });
        }
        let _ = writeln!(
            note,
            "{name}: {} interpolation points from {} {u} in steps of {} {u}; between them, linear interpolation departs from the model's correction by at most {:.4} {} (at the midpoints).",
            table.nominal.len(),
            fixed(min, 6),
            fixed(step, 6),
            small(j).from_si(table.interpolation_error),
            small(j).name,
            u = unit(j).name(),
        );
    }
    for (out, table) in &cross {
        let (min, step) = step_min(table);
        cec.push(SinumerikCec {
            input: axis_name(m, table.axis),
            output: axis_name(m, *out),
            min,
            step,
            direction: 0,
            values: values(*out, &table.forward),
        });
        let _ = writeln!(
            note,
            "{} as a function of {}: a cross table; linear interpolation departs from the model by at most {:.4} {}.",
            axis_name(m, *out),
            axis_name(m, table.axis),
            small(*out).from_si(table.interpolation_error),
            small(*out).name
        );
    }
    let source = format!(
        "written by kin from `{}` with the fit `{}`",
        a.machine.display(),
        a.fit.display()
    );
    if !lec.is_empty() {
        let mut comments = vec![
            format!("Leadscrew error compensation {source}."),
            "Values in mm (degrees on a rotary axis): the axis's error at the interpolation point; a positive value moves the axis the negative way.".to_string(),
            "Axis names are the model's: they must be the machine axis names (MD10000). Load with MD32700 ENC_COMP_ENABLE = 0, then set it to 1.".to_string(),
        ];
        for l in &lec {
            comments.push(format!(
                "{}: MD38000 MM_ENC_COMP_MAX_POINTS[0] >= {}.",
                l.name,
                l.values.len()
            ));
        }
        comments.push("Not in this table: what depends on other axes (NC_CEC.INI), on inputs, or on the direction of motion; orientation errors (kin-compensation.txt).".to_string());
        files.push((
            "AX_EEC.INI".to_string(),
            controller_tables::sinumerik_lec(&lec, &comments),
        ));
    }
    if !cec.is_empty() {
        let mut comments = vec![
            format!("Sag / cross-error compensation {source}."),
            "$AN_CEC[t,N]: the output axis's error at interpolation point N of the input axis, in mm (degrees on a rotary axis), signed as the leadscrew table's; the output axis's own table holds its value at the reference pose.".to_string(),
            "Axis names are the model's: they must be the machine axis names. Load with MD32710 CEC_ENABLE = 0 on the output axes, then set it to 1.".to_string(),
        ];
        for (k, c) in cec.iter().enumerate() {
            comments.push(format!(
                "table {k}: {} -> {}, direction {}, MD18342 MM_CEC_MAX_POINTS[{k}] >= {}.",
                c.input,
                c.output,
                c.direction,
                c.values.len()
            ));
        }
        comments.push("Cross tables whose corrections all stay below 1 nm (1 nrad) are left out. Not in these tables: terms of the inputs (temperatures, load) and orientation errors (kin-compensation.txt).".to_string());
        files.push((
            "NC_CEC.INI".to_string(),
            controller_tables::sinumerik_cec(&cec, &comments),
        ));
    }
    let _ = writeln!(
        note,
        "AX_EEC.INI and NC_CEC.INI are SINUMERIK part programs setting the compensation system variables; run them with the compensations disabled, then enable them (MD32700, MD32710)."
    );
    let _ = writeln!(
        note,
        "What the model holds that these tables cannot: the correction is taken as a sum of one table per pair of axes, so effects of two other axes together (an angular error seen through an arm that another axis changes) are only approximated; terms of the inputs are evaluated at the reference pose's values; orientation errors are not corrected."
    );
    let n = m.axes.len();
    grid_summary(m, comp, grid, |s, dq| {
        for table in &own {
            let q = s.q.get(table.axis).copied().unwrap_or(0.0);
            if let Some(slot) = dq.get_mut(table.axis) {
                *slot += table.correction(q, direction_of(s, table.axis));
            }
        }
        for (out, table) in &cross {
            let q = s.q.get(table.axis).copied().unwrap_or(0.0);
            if *out < n {
                if let Some(slot) = dq.get_mut(*out) {
                    *slot += table.correction(q, 1.0);
                }
            }
        }
    })
}

/// ISG / Beckhoff VolComp: the ISO 230-1 component errors of every ranged axis, one ISG CSV
/// file per axis.
#[allow(clippy::too_many_arguments)]
fn volcomp(
    a: &CompensateArgs,
    m: &Machine,
    comp: &mut Compensator<'_>,
    grid: &Grid,
    reference: &Reference,
    ranged: &[usize],
    files: &mut Vec<(String, String)>,
    note: &mut String,
) -> Result<GridSummary, Failed> {
    let mut components = Components::new(m, &m.beta).map_err(input_error)?;
    let mut tables: Vec<ComponentTable> = Vec::with_capacity(ranged.len());
    for &j in ranged {
        let nodes = grid.values.get(j).cloned().unwrap_or_default();
        tables.push(
            component_errors::component_table(&mut components, &reference.state(), j, &nodes)
                .map_err(input_error)?,
        );
    }
    let e = m.units.error.as_difference();
    let t = m.units.tilt.as_difference();
    for table in &tables {
        let name = axis_name(m, table.axis);
        let unit = AxisUnit::of(
            m.axes
                .get(table.axis)
                .map_or(JointKind::Prismatic, |x| x.kind),
        );
        let comments = vec![
            format!(
                "ISO 230-1 component errors of axis {name} written by kin from `{}` with the fit `{}`.",
                a.machine.display(),
                a.fit.display()
            ),
            format!("{name} in {}; EX{name} EY{name} EZ{name} in mm; EA{name} EB{name} EC{name} in rad; machine axes.", unit.name()),
            "Each error is that of the axis's carriage as seen by the tool relative to the workpiece (configure every axis on the tool side: workpiece_axes 0); translations at the carriage frame's origin.".to_string(),
            "Squareness and location errors are the constant parts of these columns; set no position errors (X0Y ...) beside them.".to_string(),
            format!(
                "Not in this file: dependence on other axes and inputs (evaluated at the reference pose), the direction of motion (the mean of both is written; reversal up to {:.4} {} / {:.4} {}), errors of the tool and workpiece frames.",
                e.from_si(table.reversal[0]),
                e.name,
                t.from_si(table.reversal[1]),
                t.name
            ),
        ];
        files.push((
            format!("{name}.csv"),
            controller_tables::volcomp_csv(name, unit, table, &comments),
        ));
        let _ = writeln!(
            note,
            "{name}.csv: {} positions; linear interpolation departs from the model by at most {:.4} {} (translations) and {:.4} {} (rotations) at the midpoints; the two directions of motion differ by up to ±{:.4} {} / ±{:.4} {} (the mean is written).",
            table.nominal.len(),
            e.from_si(table.interpolation_error[0]),
            e.name,
            t.from_si(table.interpolation_error[1]),
            t.name,
            e.from_si(table.reversal[0]),
            e.name,
            t.from_si(table.reversal[1]),
            t.name,
        );
    }
    let _ = writeln!(
        note,
        "Each AXIS.csv is a VolComp parameter file in the ISG CSV format (file[j] AXIS.csv, file_format[j] ISG_CSV): the axis's ISO 230-1 component errors EX… EC… in machine axes, as the tool sees them relative to the workpiece (every axis configured on the tool side, workpiece_axes 0); squareness and location errors are held as the constant parts of these columns."
    );
    let _ = writeln!(
        note,
        "What the model holds that these files cannot: errors of one axis that depend on another axis or on the inputs (cross-couplings, thermal and load terms: evaluated at the reference pose), backlash (the files hold no direction), and errors of the tool and workpiece frames. With the tables the largest position error below is the model's minus what the tables imply when composed along the machine's chains as the model composes them (first order); how the controller composes them is its own."
    );
    let points = grid.points(m);
    let states = States::new(m, &points.rows, &points.pose, "").map_err(|e| {
        eprintln!("error: --grid: {e}");
        Failed::INPUT
    })?;
    let mut summary = GridSummary {
        poses: states.len(),
        before: 0.0,
        with_tables: 0.0,
        full: 0.0,
    };
    for r in 0..states.len() {
        let s = states.get(r);
        let c = comp.compensate(&s).map_err(input_error)?;
        let (model, implied) = components
            .model_and_tables(&s, &tables)
            .map_err(input_error)?;
        let left: f64 = model
            .iter()
            .zip(&implied)
            .map(|(p, q)| (p - q) * (p - q))
            .sum::<f64>()
            .sqrt();
        summary.before = summary.before.max(norm3(&c.before, 0));
        summary.full = summary.full.max(norm3(&c.after, 0));
        summary.with_tables = summary.with_tables.max(left);
    }
    Ok(summary)
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
