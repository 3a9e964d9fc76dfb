//! `kin compensate`: the joint corrections of a positioning machine at commanded poses (a poses
//! file or a grid), as a CSV, or per-axis controller tables (`--table linuxcnc|sinumerik|isg-lsec|volcomp`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use kin_compiler::ir::{JointKind, Machine};
use kin_data::data::{self, ExtraColumn, ExtraQuantity, Observations, PointData, WriteOptions};
use kin_machine::controller_tables::fixed;
use kin_machine::corrections::{CorrectionError, Summary};
use kin_machine::table_set::{Format, GridSummary, TableError, TablePlan};
use kin_model::compensate::{Compensator, Correction, Movable, Options};

use crate::grid::{self, Grid};
use crate::load::{self, Failed};

/// Which components of the tool-location error the corrections minimise.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Correct {
    /// Position and orientation, a rotation of one tilt unit weighing as one error unit: the
    /// machine corrects all its joints can (a 3-axis machine: the position).
    Pose,
    /// The position only: rotations weigh 0, so orientation is whatever the moves that cancel
    /// the position error leave (reported); an axis with no leverage on the position stays.
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
    fn format(self) -> Format {
        match self {
            Table::Linuxcnc => Format::Linuxcnc,
            Table::Sinumerik => Format::Sinumerik,
            Table::IsgLsec => Format::IsgLsec,
            Table::Volcomp => Format::Volcomp,
        }
    }

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
    /// The axes the corrections may move (`--axes`); `None`: the default of `correct`.
    pub axes: Option<String>,
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
    // The axes are chosen per row below (--axes), and per table by the format.
    let options = Options {
        movable: Movable::ALL,
        ..options
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
    let free = free_axes(m, a.correct, a.axes.as_deref())?;
    let held: Vec<&str> = m
        .axes
        .iter()
        .zip(&free)
        .filter(|(_, f)| !**f)
        .map(|(axis, _)| axis.name.as_str())
        .collect();
    if !held.is_empty() {
        eprintln!(
            "note: {} held at the commanded positions (not moved by the corrections){}",
            held.join(", "),
            if a.axes.is_none() {
                "; --axes names the axes to move"
            } else {
                ""
            }
        );
    }
    let mut points = points;
    undirected(m, &mut points);
    let corrections = corrections(m, &mut comp, &points, &source, &free)?;
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
    free: &[bool],
) -> Result<Vec<Correction>, Failed> {
    kin_machine::corrections::corrections(m, comp, points, Some(free)).map_err(|e| {
        match e {
            CorrectionError::States(e) => eprintln!("error: {e}"),
            CorrectionError::Pose { line, source: e } => eprintln!("error: {source} {line}: {e}"),
        }
        Failed::INPUT
    })
}

/// The axes the corrections may move: those `--axes` names, else every axis for `pose`, and
/// for `position` the prismatic axes (every axis of a machine that has none, an arm): a
/// rotary axis of a machine tool moved to correct position turns the tool and the workpiece,
/// and changes the orientation error it was not asked about.
fn free_axes(m: &Machine, correct: Correct, axes: Option<&str>) -> Result<Vec<bool>, Failed> {
    let Some(list) = axes else {
        let movable = match correct {
            Correct::Position => Movable::prismatic_or_all(m),
            Correct::Pose => Movable::ALL,
        };
        return Ok((0..m.axes.len()).map(|j| movable.contains(j)).collect());
    };
    let mut free = vec![false; m.axes.len()];
    for name in list.split(',').map(str::trim) {
        let Some(j) = m.axes.iter().position(|a| a.name == name) else {
            let names: Vec<&str> = m.axes.iter().map(|a| a.name.as_str()).collect();
            eprintln!(
                "error: --axes: `{name}` is no axis of machine `{}` (its axes: {})",
                m.name,
                names.join(", ")
            );
            return Err(Failed::USAGE);
        };
        free[j] = true;
    }
    Ok(free)
}

/// Every axis whose direction of approach the model uses (backlash) and the poses do not give
/// is taken as approached moving in its positive direction, as `--grid` does (spec/data.md:
/// `dir_X` is optional), with a note; the output then has the `dir_` column it assumed.
fn undirected(m: &Machine, points: &mut PointData) {
    let used = kin_model::states::used_vars(m);
    let rows = points.rows.len();
    for (j, axis) in m.axes.iter().enumerate() {
        let Some(slot) = points.pose.dir.get_mut(j) else {
            continue;
        };
        if slot.is_none() && used.contains(&kin_compiler::ir::Var::Direction(j)) {
            *slot = Some(vec![1.0; rows]);
            eprintln!(
                "note: the poses have no dir_{0} column: {0} is taken as approached moving in its positive direction (as --grid does)",
                axis.name
            );
        }
    }
}

/// Before and after on standard error: what compensation achieves and what stays.
fn summary(m: &Machine, c: &[Correction], weighted: usize) {
    let e = m.units.error.as_difference();
    let t = m.units.tilt.as_difference();
    let s = Summary::of(c);
    eprintln!(
        "{} poses: largest predicted position error {:.4} {} before compensation, {:.4} {} after; orientation {:.4} {} before, {:.4} {} after",
        c.len(),
        e.from_si(s.position_before),
        e.name,
        e.from_si(s.position_after),
        e.name,
        t.from_si(s.orientation_before),
        t.name,
        t.from_si(s.orientation_after),
        t.name,
    );
    let mut idle: Vec<(usize, usize)> = Vec::new();
    for j in c.iter().flat_map(|c| &c.idle) {
        match idle.iter_mut().find(|(k, _)| k == j) {
            Some((_, n)) => *n += 1,
            None => idle.push((*j, 1)),
        }
    }
    for (j, n) in idle {
        if let Some(axis) = m.axes.get(j) {
            eprintln!(
                "note: {} has no leverage on the corrected components at {n} of {} poses (it turns about the tool point): it is not moved there",
                axis.name,
                c.len()
            );
        }
    }
    if let Some(rank) = s.rank {
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
    // What each format cannot state at all is refused before any work.
    let plan = TablePlan::new(m, grid, format.format()).map_err(table_error)?;
    // The folder itself is made with the set (crate::folder); the folders above it here.
    if let Some(parent) = a.output.parent().filter(|p| !p.as_os_str().is_empty()) {
        if let Err(e) = std::fs::create_dir_all(parent) {
            eprintln!("error: cannot create `{}`: {e}", parent.display());
            return Err(Failed::USAGE);
        }
    }
    let origin = format!(
        "written by kin from `{}` with the fit `{}`",
        a.machine.display(),
        a.fit.display()
    );
    let e = m.units.error.as_difference();
    let mut note = String::new();
    let _ = writeln!(
        note,
        "Controller compensation tables ({}) {origin}.",
        format.title(),
    );
    let _ = writeln!(
        note,
        "Reference pose of every table (the other axes, tool, inputs, directions): {}.",
        describe_reference(m, plan.reference(), grid)
    );
    let set = plan.build(comp, &origin).map_err(table_error)?;
    note.push_str(&set.note);
    let summary = set.summary;
    let _ = writeln!(
        note,
        "Over the {} grid poses the model predicts a largest position error of {:.4} {u} without compensation, {:.4} {u} with these tables, {:.4} {u} with the full compensation (`kin compensate --grid … -o OUT.csv`).",
        summary.poses,
        e.from_si(summary.before),
        e.from_si(summary.with_tables),
        e.from_si(summary.full),
        u = e.name
    );
    let _ = writeln!(
        note,
        "{LEFTOVER} holds the three at every grid pose: where the tables fall short of the full compensation."
    );
    let leftover = leftover_csv(m, grid, &summary, &origin);
    let note_path = a.output.join("kin-compensation.txt");
    let paths: Vec<PathBuf> = set.files.iter().map(|f| a.output.join(&f.name)).collect();
    // A folder not made yet holds no input.
    if a.output.is_dir() {
        for p in paths.iter().chain([&note_path]) {
            crate::files::check(p, inputs)?;
        }
    }
    // The tables and their note are one result: the folder is replaced as one, so a reader
    // sees the old set or the new one, and no table of an earlier set stays beside the new
    // (crate::folder).
    let names: Vec<String> = set
        .files
        .iter()
        .map(|f| f.name.clone())
        .chain([LEFTOVER.to_string(), "kin-compensation.txt".to_string()])
        .collect();
    let _ = writeln!(note, "Files of this set: {}.", names.join(", "));
    let mut files: Vec<(String, &[u8])> = set
        .files
        .iter()
        .map(|f| (f.name.clone(), f.text.as_bytes()))
        .collect();
    files.push((LEFTOVER.to_string(), leftover.as_bytes()));
    files.push(("kin-compensation.txt".to_string(), note.as_bytes()));
    // An earlier set's files: those its note lists, and any whose comments name kin as their
    // origin (a LinuxCNC table has no comments; a note of an older kin lists nothing).
    let listed = earlier_set(&a.output.join("kin-compensation.txt"));
    let replaced = crate::folder::replace_folder(&a.output, &files, |p| {
        p.file_name()
            .is_some_and(|n| listed.iter().any(|l| n.to_string_lossy() == l.as_str()))
            || crate::folder::written_by(p, "written by kin from")
    })
    .map_err(|e| {
        eprintln!(
            "error: cannot write the tables into `{}`: {e}",
            a.output.display()
        );
        Failed::USAGE
    })?;
    eprint!("{note}");
    if !replaced.stale.is_empty() {
        eprintln!(
            "Removed with the earlier set, which this one replaces: {} (a controller must not keep loading them).",
            replaced.stale.join(", ")
        );
    }
    if !replaced.kept.is_empty() {
        eprintln!(
            "Kept in `{}`, as files kin did not write: {}.",
            a.output.display(),
            replaced.kept.join(", ")
        );
    }
    Ok(())
}

/// The file of a table set that holds the predicted position error at every grid pose.
const LEFTOVER: &str = "kin-leftover.csv";

/// `kin-leftover.csv`: every grid pose (the axes in the model's units) with the predicted
/// position error's length without compensation, with the tables and with the full
/// compensation, in the error unit; a measurement-style CSV with `#` comments.
fn leftover_csv(m: &Machine, grid: &Grid, summary: &GridSummary, origin: &str) -> String {
    let e = m.units.error.as_difference();
    let units: Vec<_> = m
        .axes
        .iter()
        .map(|axis| match axis.kind {
            JointKind::Prismatic => m.units.length.as_difference(),
            JointKind::Revolute => m.units.angle.as_difference(),
        })
        .collect();
    let mut out = format!(
        "# position error left at each grid pose, {origin}\n\
         # before: no compensation; tables: with these tables as the controller applies them; full: `kin compensate --grid` (every axis the model may move)\n"
    );
    let header: Vec<String> = m
        .axes
        .iter()
        .zip(&units)
        .map(|(axis, u)| format!("{}[{}]", axis.name, u.name))
        .chain(["before", "tables", "full"].map(|c| format!("{c}[{}]", e.name)))
        .collect();
    out.push_str(&header.join(","));
    out.push('\n');
    let points = grid.points(m);
    for (r, left) in summary.left.iter().enumerate() {
        let cells: Vec<String> = points
            .pose
            .axes
            .iter()
            .zip(&units)
            .map(|(col, u)| fixed(u.from_si(col.get(r).copied().unwrap_or(f64::NAN)), 9))
            .chain(left.iter().map(|v| fixed(e.from_si(*v), 6)))
            .collect();
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// The files an earlier set's note lists (`Files of this set: X.comp, …`); none without one.
fn earlier_set(note: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(note) else {
        return Vec::new();
    };
    text.lines()
        .find_map(|l| l.strip_prefix("Files of this set: "))
        .map(|list| {
            list.trim_end_matches('.')
                .split(", ")
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

/// The message of a table the grid or the model cannot give, in the terms of `--grid` and
/// `--table`.
fn table_error(e: TableError) -> Failed {
    let (message, code) = match &e {
        TableError::NoRangedAxis => (
            "--grid ranges over no axis: give at least one as FROM:TO:STEP".to_string(),
            Failed::USAGE,
        ),
        TableError::TooManyPositions {
            axis,
            positions,
            most,
        } => (
            format!("--grid gives axis {axis} {positions} positions; a LinuxCNC compensation file holds at most {most}: a larger STEP"),
            Failed::USAGE,
        ),
        TableError::NotEquidistant(_) => (
            format!("--grid: {e}: choose a STEP that divides TO − FROM"),
            Failed::USAGE,
        ),
        TableError::NotIsgPosition(_) => (
            format!("--grid: {e}: choose FROM and STEP on that grid"),
            Failed::USAGE,
        ),
        TableError::Element(_) => (format!("--table volcomp: {e}"), Failed::INPUT),
        TableError::Grid(_) => (format!("--grid: {e}"), Failed::INPUT),
        TableError::NotIsoName(_) | TableError::Compensate(_) | TableError::Components(_) => {
            (e.to_string(), Failed::INPUT)
        }
    };
    eprintln!("error: {message}");
    code
}

fn unit_of(m: &Machine, axis: usize) -> &kin_compiler::units::Unit {
    match m.axes.get(axis).map(|a| a.kind) {
        Some(JointKind::Revolute) => &m.units.angle,
        _ => &m.units.length,
    }
}

/// A value back from SI in the unit the user wrote it in, to twelve significant digits: 30°
/// goes through radians and comes back 29.999999999999996, which no user wrote.
fn tidy(v: f64) -> f64 {
    format!("{v:.11e}").parse().unwrap_or(v)
}

fn describe_reference(m: &Machine, q: &[f64], grid: &Grid) -> String {
    let mut parts: Vec<String> = m
        .axes
        .iter()
        .zip(q)
        .enumerate()
        .map(|(j, (axis, v))| {
            let u = unit_of(m, j);
            format!(
                "{}={} {}",
                axis.name,
                tidy(u.as_difference().from_si(*v)),
                u.name
            )
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
                tidy(u.from_si(*v)),
                input.unit.name
            ));
        }
    }
    parts.join(", ")
}
