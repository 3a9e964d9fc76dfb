//! A controller's whole set of compensation tables from a fitted model over a grid of poses
//! (`kin compensate --table`, spec/compensation.md): one table (or ISO 230-1 component file) per
//! axis the grid ranges over, the grid's step their spacing, every other axis, the tool, the
//! inputs and the directions held at one reference pose; with a note of what each table holds
//! and what the format cannot, and how much of the model's error the tables leave over the
//! grid against the full compensation (§2.3.5).
//!
//! What a format cannot state at all (too many entries, positions off its grid, axis names it
//! does not know) is refused by [`TablePlan::new`] before any table is computed.

use std::fmt::Write as _;

use kin_compiler::ir::{JointKind, Machine};
use kin_model::compensate::{CompensateError, Compensator};
use kin_model::interp::State;
use kin_model::states::{StateError, States};
use thiserror::Error;

use crate::axis_table::{self, AxisTable, Sweep};
use crate::component_errors::{self, ComponentError, ComponentTable, Components};
use crate::controller_tables::{self, fixed, AxisUnit, SinumerikCec, SinumerikLec};
use crate::corrections::norm3;
use crate::grid::Grid;

/// A controller table format (spec/compensation.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// LinuxCNC joint compensation files (`COMP_FILE_TYPE = 0`), one `AXIS.comp` per axis.
    Linuxcnc,
    /// SINUMERIK 840D leadscrew (`AX_EEC.INI`) and sag / cross-error (`NC_CEC.INI`) tables.
    Sinumerik,
    /// ISG bilateral leadscrew error compensation lists (`kw.ssfk`), one `AXIS.lis` per axis.
    IsgLsec,
    /// ISG / Beckhoff VolComp ISO 230-1 component errors, one `AXIS.csv` per axis.
    Volcomp,
}

/// LinuxCNC's limit on the entries of one joint's compensation file.
const LINUXCNC_MAX_ENTRIES: usize = 256;

/// A cross-axis table whose corrections all stay below this (m or rad, 1 nm or 1 nrad) is not
/// written: it would only add noise to the controller's sum. Also the reversal below which an
/// own table is direction-independent.
const NEGLIGIBLE: f64 = 1e-9;

/// Why the tables cannot be made.
#[derive(Debug, Error)]
pub enum TableError {
    #[error("the grid ranges over no axis")]
    NoRangedAxis,
    #[error("the grid gives axis {axis} {positions} positions; a LinuxCNC compensation file holds at most {most}")]
    TooManyPositions {
        axis: String,
        positions: usize,
        most: usize,
    },
    #[error("SINUMERIK tables are equidistant, but the positions of axis {0} are not")]
    NotEquidistant(String),
    #[error("an ISG list states positions in whole 0.1 um (0.0001 deg); a position of axis {0} is not one")]
    NotIsgPosition(String),
    #[error("VolComp names axes by the ISO 230-1 letters X, Y, Z, A, B, C; axis `{0}` is none of them (rename it in the model)")]
    NotIsoName(String),
    /// A ranged axis does not drive the one carriage a VolComp file describes.
    #[error(transparent)]
    Element(ComponentError),
    /// The grid's poses lack a value the model uses.
    #[error(transparent)]
    Grid(#[from] StateError),
    /// The compensator refused a pose (of the grid, or one a table is solved at).
    #[error(transparent)]
    Compensate(#[from] CompensateError),
    /// The component errors of an axis could not be evaluated (VolComp).
    #[error(transparent)]
    Components(#[from] ComponentError),
}

/// The largest predicted position error over the grid without compensation, with the tables,
/// and with the full compensation (SI); and the three at every grid pose, in the order of
/// [`Grid::points`](crate::grid::Grid::points).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GridSummary {
    pub poses: usize,
    pub before: f64,
    pub with_tables: f64,
    pub full: f64,
    /// Per grid pose: `[before, with_tables, full]`.
    pub left: Vec<[f64; 3]>,
}

/// One file of a set: its name in the set's folder and its text.
#[derive(Debug, Clone, PartialEq)]
pub struct TableFile {
    pub name: String,
    pub text: String,
}

/// The tables of one format: the files, the note (one line per table on what it holds and
/// how closely its interpolation follows the model, then what the format cannot hold), and
/// what the tables leave over the grid.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TableSet {
    pub files: Vec<TableFile>,
    pub note: String,
    pub summary: GridSummary,
}

impl TableSet {
    fn add(&mut self, name: impl Into<String>, text: String) {
        self.files.push(TableFile {
            name: name.into(),
            text,
        });
    }
}

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

    fn state(&self) -> State<'_> {
        State {
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

/// Tables of one format over one grid, checked before they are computed: the axes the grid
/// ranges over (those with more than one value) each get a table.
pub struct TablePlan<'a> {
    m: &'a Machine,
    grid: &'a Grid,
    format: Format,
    ranged: Vec<usize>,
    reference: Reference,
}

fn axis_name(m: &Machine, j: usize) -> &str {
    m.axes.get(j).map_or("?", |a| a.name.as_str())
}

fn kind_of(m: &Machine, j: usize) -> JointKind {
    m.axes.get(j).map_or(JointKind::Prismatic, |x| x.kind)
}

fn direction_of(s: &State<'_>, axis: usize) -> f64 {
    let d = s.dirs.get(axis).copied().unwrap_or(1.0);
    if d.is_nan() {
        1.0
    } else {
        d
    }
}

/// The corrections the own-axis tables `own` give at `s`, into `dq` (zero for an axis without
/// one).
fn own_corrections(own: &[AxisTable], s: &State<'_>, dq: &mut [f64]) {
    dq.fill(0.0);
    for table in own {
        let q = s.q.get(table.axis).copied().unwrap_or(0.0);
        if let Some(slot) = dq.get_mut(table.axis) {
            *slot = table.correction(q, direction_of(s, table.axis));
        }
    }
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

impl<'a> TablePlan<'a> {
    /// The tables of `format` for machine `m` over `grid`, refused when the grid ranges over no
    /// axis or the format cannot state a ranged axis's table: more positions than a LinuxCNC
    /// file holds, positions not equidistant (SINUMERIK) or not whole increments (ISG), an axis
    /// VolComp cannot name or describe.
    pub fn new(m: &'a Machine, grid: &'a Grid, format: Format) -> Result<Self, TableError> {
        let ranged: Vec<usize> = (0..m.axes.len())
            .filter(|&j| grid.values.get(j).is_some_and(|v| v.len() > 1))
            .collect();
        if ranged.is_empty() {
            return Err(TableError::NoRangedAxis);
        }
        let plan = TablePlan {
            m,
            grid,
            format,
            ranged,
            reference: Reference::new(m, grid),
        };
        for &j in &plan.ranged {
            let nodes = plan.nodes(j);
            let name = || axis_name(m, j).to_string();
            match format {
                Format::Linuxcnc if nodes.len() > LINUXCNC_MAX_ENTRIES => {
                    return Err(TableError::TooManyPositions {
                        axis: name(),
                        positions: nodes.len(),
                        most: LINUXCNC_MAX_ENTRIES,
                    });
                }
                Format::Sinumerik if equidistant(&nodes).is_none() => {
                    return Err(TableError::NotEquidistant(name()));
                }
                Format::IsgLsec => {
                    let unit = AxisUnit::of(kind_of(m, j));
                    if nodes
                        .iter()
                        .any(|p| controller_tables::isg_position(*p, unit).is_none())
                    {
                        return Err(TableError::NotIsgPosition(name()));
                    }
                }
                Format::Volcomp => {
                    if !matches!(axis_name(m, j), "X" | "Y" | "Z" | "A" | "B" | "C") {
                        return Err(TableError::NotIsoName(name()));
                    }
                    component_errors::element_of(m, j).map_err(TableError::Element)?;
                }
                _ => {}
            }
        }
        Ok(plan)
    }

    /// The axis positions of the reference pose (SI), indexed like `Machine::axes`: each axis
    /// at the middle of its grid values.
    pub fn reference(&self) -> &[f64] {
        &self.reference.q
    }

    /// The grid's positions of axis `j`.
    fn nodes(&self, j: usize) -> Vec<f64> {
        self.grid.values.get(j).cloned().unwrap_or_default()
    }

    /// Computes the tables with `comp` (the fitted model and the components its corrections
    /// minimise). `origin` says in every file's comments where the tables come from, e.g.
    /// ``written by kin from `mill.kin` with the fit `fit.json` ``.
    pub fn build(&self, comp: &mut Compensator<'_>, origin: &str) -> Result<TableSet, TableError> {
        match self.format {
            Format::Linuxcnc | Format::IsgLsec => self.own(comp, origin),
            Format::Sinumerik => self.sinumerik(comp, origin),
            Format::Volcomp => self.volcomp(comp, origin),
        }
    }

    /// Evaluates, at every grid pose, the position error left by the tables
    /// (`with_tables`, given the compensator and the pose) against the full compensation.
    fn grid_summary(
        &self,
        comp: &mut Compensator<'_>,
        mut with_tables: impl FnMut(&mut Compensator<'_>, &State<'_>) -> Result<f64, TableError>,
    ) -> Result<GridSummary, TableError> {
        let points = self.grid.points(self.m);
        let states = States::new(self.m, &points.rows, &points.pose, "")?;
        let mut summary = GridSummary {
            poses: states.len(),
            left: Vec::with_capacity(states.len()),
            ..GridSummary::default()
        };
        for r in 0..states.len() {
            let s = states.get(r);
            let c = comp.compensate(&s)?;
            let left = with_tables(comp, &s)?;
            let (before, full) = (norm3(&c.before, 0), norm3(&c.after, 0));
            summary.before = summary.before.max(before);
            summary.full = summary.full.max(full);
            summary.with_tables = summary.with_tables.max(left);
            summary.left.push([before, left, full]);
        }
        Ok(summary)
    }

    /// LinuxCNC and ISG: one table per ranged axis of its own correction (the compensator's
    /// solve with only that axis free), in both directions.
    fn own(&self, comp: &mut Compensator<'_>, origin: &str) -> Result<TableSet, TableError> {
        let mut set = TableSet::default();
        let m = self.m;
        let e = m.units.error.as_difference();
        let t = m.units.tilt.as_difference();
        let mut own: Vec<AxisTable> = Vec::with_capacity(self.ranged.len());
        for &j in &self.ranged {
            own.push(axis_table::axis_table(
                comp,
                &self.reference.state(),
                j,
                &self.nodes(j),
            )?);
        }
        for table in &own {
            let name = axis_name(m, table.axis);
            if let Format::Linuxcnc = self.format {
                let unit = match kind_of(m, table.axis) {
                    JointKind::Revolute => &m.units.angle,
                    JointKind::Prismatic => &m.units.length,
                };
                set.add(format!("{name}.comp"), table.linuxcnc(unit));
            } else {
                let unit = m
                    .axes
                    .get(table.axis)
                    .map(|x| x.kind)
                    .map_or(AxisUnit::Millimetre, AxisUnit::of);
                let comments = vec![
                    format!("Leadscrew error compensation of axis {name} {origin}."),
                    "pos/neg: position reached minus setpoint moving in +/- (the controller subtracts it), 0.1 um (0.0001 deg on a rotary axis).".to_string(),
                    "kopf.achs_nr is the axis's index in the model plus 1: set the logical axis number of your configuration.".to_string(),
                    "Not in this list: what depends on other axes or inputs, and orientation errors (kin-compensation.txt).".to_string(),
                ];
                let text =
                    controller_tables::isg_lsec(table.axis + 1, name, unit, table, &comments)
                        .ok_or_else(|| TableError::NotIsgPosition(name.to_string()))?;
                set.add(format!("{name}.lis"), text);
            }
            let unit = match kind_of(m, table.axis) {
                JointKind::Revolute => &t,
                JointKind::Prismatic => &e,
            };
            let _ = writeln!(
                &mut set.note,
                "{name}: {} positions; between them, linear interpolation departs from the model's correction by at most {:.4} {} (at the midpoints).",
                table.nominal.len(),
                unit.from_si(table.interpolation_error),
                unit.name,
            );
        }
        if let Format::Linuxcnc = self.format {
            set.note.push_str("Each AXIS.comp is for that joint's [JOINT_n] section: COMP_FILE = AXIS.comp, COMP_FILE_TYPE = 0.\n");
            let _ = writeln!(
                &mut set.note,
                "Lines: nominal position, position reached moving in +, position reached moving in −, in {} (rotary axes in {}); LinuxCNC's machine units must be these.",
                m.units.length.name, m.units.angle.name
            );
        } else {
            set.note.push_str("Each AXIS.lis is an ISG leadscrew error compensation list (kw.ssfk, bilateral, metric): name it in the start-up list (achs_kw[i], achs_kw_log_ax_nr[i]) and enable the compensation in the axis's parameters; values are rounded to 0.1 um (0.0001 deg).\n");
        }
        set.note.push_str("What the model holds that these tables cannot: a table is a function of its own axis's position and direction only, so cross-couplings (errors of one axis that depend on another's position), straightness and squareness, angular errors with their Abbe offsets away from the reference pose, and terms of the inputs (temperatures, load) are not in them; orientation errors are not corrected at all.\n");
        let mut dq = vec![0.0; m.axes.len()];
        set.summary = self.grid_summary(comp, |comp, s| {
            own_corrections(&own, s, &mut dq);
            Ok(norm3(&comp.remaining(s, &dq)?, 0))
        })?;
        Ok(set)
    }

    /// SINUMERIK 840D: the own-axis (LEC) and cross-axis (CEC) tables from the full
    /// compensation swept along every ranged axis. The correction of axis j at a pose is taken
    /// as its own table at q_j plus, for every other ranged axis i, the cross table of i → j at
    /// q_i.
    fn sinumerik(&self, comp: &mut Compensator<'_>, origin: &str) -> Result<TableSet, TableError> {
        let mut set = TableSet::default();
        let (m, reference, ranged) = (self.m, &self.reference, &self.ranged);
        // The solve moves only the axes that get a table: an axis the grid holds at one value
        // (a rotary axis of a mill compensated in X, Y, Z) is never corrected by these tables,
        // and corrections of the others that assume it would be leave its share of the error
        // on the machine.
        let mut free = vec![false; m.axes.len()];
        for &j in ranged {
            if let Some(f) = free.get_mut(j) {
                *f = true;
            }
        }
        let base = comp.compensate_with(&reference.state(), Some(&free))?.dq;
        let mut sweeps: Vec<Sweep> = Vec::with_capacity(ranged.len());
        for &j in ranged {
            sweeps.push(axis_table::sweep(
                comp,
                &reference.state(),
                j,
                &self.nodes(j),
                Some(&free),
            )?);
        }
        let kind = |j: usize| kind_of(m, j);
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
        // A value is what the axis's measuring system is off by: a positive one moves the axis
        // the negative way, so it is the negated correction.
        let values = |j: usize, corrections: &[f64]| -> Vec<f64> {
            corrections.iter().map(|c| unit(j).of_si(-c)).collect()
        };
        let step_min = |table: &AxisTable| {
            let u = unit(table.axis);
            let step = equidistant(&table.nominal).unwrap_or(0.0);
            (
                u.of_si(table.nominal.first().copied().unwrap_or(0.0)),
                u.of_si(step),
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
                // K3: position-dependent backlash is two cross tables of the axis onto itself,
                // one per direction.
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
                    &mut set.note,
                    "{name}: its own table differs between the directions by up to {:.4} {} (backlash), so it is written as two direction-dependent tables of NC_CEC.INI ($AN_CEC_DIRECTION 1 and -1), not as leadscrew compensation.",
                    small(j).from_si(reversal),
                    small(j).name
                );
            } else {
                lec.push(SinumerikLec {
                    name,
                    min,
                    step,
                    values: values(j, &table.forward),
                });
            }
            let _ = writeln!(
                &mut set.note,
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
                &mut set.note,
                "{} as a function of {}: a cross table; linear interpolation departs from the model by at most {:.4} {}.",
                axis_name(m, *out),
                axis_name(m, table.axis),
                small(*out).from_si(table.interpolation_error),
                small(*out).name
            );
        }
        if !lec.is_empty() {
            let mut comments = vec![
                format!("Leadscrew error compensation {origin}."),
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
            set.add(
                "AX_EEC.INI",
                controller_tables::sinumerik_lec(&lec, &comments),
            );
        }
        if !cec.is_empty() {
            let mut comments = vec![
                format!("Sag / cross-error compensation {origin}."),
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
            if let Some(check) = cec_sign_check(m, &cec) {
                comments.push(check.clone());
                set.note.push_str(&check);
                set.note.push('\n');
            }
            set.add(
                "NC_CEC.INI",
                controller_tables::sinumerik_cec(&cec, &comments),
            );
        }
        set.note.push_str("AX_EEC.INI and NC_CEC.INI are SINUMERIK part programs setting the compensation system variables; run them with the compensations disabled, then enable them (MD32700, MD32710).\n");
        set.note.push_str("What the model holds that these tables cannot: the correction is taken as a sum of one table per pair of axes, so effects of two other axes together (an angular error seen through an arm that another axis changes) are only approximated; terms of the inputs are evaluated at the reference pose's values; orientation errors are not corrected.\n");
        let n = m.axes.len();
        let mut dq = vec![0.0; n];
        set.summary = self.grid_summary(comp, |comp, s| {
            own_corrections(&own, s, &mut dq);
            for (out, table) in &cross {
                let q = s.q.get(table.axis).copied().unwrap_or(0.0);
                if *out < n {
                    if let Some(slot) = dq.get_mut(*out) {
                        *slot += table.correction(q, 1.0);
                    }
                }
            }
            Ok(norm3(&comp.remaining(s, &dq)?, 0))
        })?;
        Ok(set)
    }

    /// ISG / Beckhoff VolComp: the ISO 230-1 component errors of every ranged axis, one ISG CSV
    /// file per axis.
    fn volcomp(&self, comp: &mut Compensator<'_>, origin: &str) -> Result<TableSet, TableError> {
        let mut set = TableSet::default();
        let m = self.m;
        let mut components = Components::new(m, &m.beta)?;
        let mut tables: Vec<ComponentTable> = Vec::with_capacity(self.ranged.len());
        for &j in &self.ranged {
            tables.push(component_errors::component_table(
                &mut components,
                &self.reference.state(),
                j,
                &self.nodes(j),
            )?);
        }
        let e = m.units.error.as_difference();
        let t = m.units.tilt.as_difference();
        for table in &tables {
            let name = axis_name(m, table.axis);
            let unit = AxisUnit::of(kind_of(m, table.axis));
            let comments = vec![
                format!("ISO 230-1 component errors of axis {name} {origin}."),
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
            set.add(
                format!("{name}.csv"),
                controller_tables::volcomp_csv(name, unit, table, &comments),
            );
            let _ = writeln!(
                &mut set.note,
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
        set.note.push_str("Each AXIS.csv is a VolComp parameter file in the ISG CSV format (file[j] AXIS.csv, file_format[j] ISG_CSV): the axis's ISO 230-1 component errors EX… EC… in machine axes, as the tool sees them relative to the workpiece (every axis configured on the tool side, workpiece_axes 0); squareness and location errors are held as the constant parts of these columns.\n");
        set.note.push_str("What the model holds that these files cannot: errors of one axis that depend on another axis or on the inputs (cross-couplings, thermal and load terms: evaluated at the reference pose), backlash (the files hold no direction), and errors of the tool and workpiece frames. With the tables the largest position error below is the model's minus what the tables imply when composed along the machine's chains as the model composes them (first order); how the controller composes them is its own.\n");
        set.summary = self.grid_summary(comp, |_, s| {
            let (model, implied) = components.model_and_tables(s, &tables)?;
            Ok(model
                .iter()
                .zip(&implied)
                .map(|(p, q)| (p - q) * (p - q))
                .sum::<f64>()
                .sqrt())
        })?;
        Ok(set)
    }
}

/// The one-line check of the CEC tables' sign a user runs on the machine. Siemens' manual (K3)
/// states the sign for leadscrew tables only ("a positive value moves the axis the negative
/// way"); kin gives cross tables the same sign. The check names the table and point with the
/// largest value, where a wrong sign is easiest to see: the output axis must move against the
/// value, and a move with it means every `$AN_CEC` value is to be negated.
fn cec_sign_check(m: &Machine, cec: &[SinumerikCec<'_>]) -> Option<String> {
    let (t, n, v) = cec
        .iter()
        .enumerate()
        .flat_map(|(t, c)| c.values.iter().enumerate().map(move |(n, v)| (t, n, *v)))
        .max_by(|a, b| a.2.abs().total_cmp(&b.2.abs()))?;
    let table = cec.get(t)?;
    let unit = |name: &str| match m.axes.iter().find(|a| a.name == name).map(|a| a.kind) {
        Some(JointKind::Revolute) => "deg",
        _ => "mm",
    };
    let at = table.min + table.step * n as f64;
    let direction = match table.direction {
        1 => " moving in +",
        -1 => " moving in −",
        _ => "",
    };
    Some(format!(
        "Sign check (the manual states the sign for leadscrew tables only; these are signed alike): with table {t} alone enabled, move {input} to {at} {iu}{direction}; {output}'s actual position, measured on the machine, must change by {neg} {ou} against the same move with the table disabled. If it changes by {pos} {ou}, the controller reads CEC values the other way: negate every $AN_CEC value.",
        input = table.input,
        output = table.output,
        at = fixed(at, 6),
        iu = unit(table.input),
        ou = unit(table.output),
        neg = fixed(-v, 6),
        pos = fixed(v, 6),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kin_compiler::compile;
    use kin_model::compensate::Options;

    /// A slide X carrying the workpiece and a slide Q carrying the tool; X has a linear
    /// positioning error.
    const SLIDES: &str = "machine slides { task position units { length mm, error um, tilt urad }
        axis X prismatic along x range 0 mm .. 500 mm  axis Q prismatic along z range -300 mm .. 0 mm
        tool chain { Q moving  tool t at (0, 0, -100) mm }  workpiece chain { X fixed  workpiece }
        errors { X.tx = linear(X) } }";

    fn grid(x: Vec<f64>, q: Vec<f64>) -> Grid {
        Grid {
            values: vec![x, q],
            dirs: vec![1.0; 2],
            inputs: Vec::new(),
            tool: 0,
        }
    }

    #[test]
    fn a_format_refuses_what_it_cannot_state_before_any_work() {
        let c = compile(SLIDES).compiled.expect("compiles");
        let m = &c.machine;
        let refused = |g: &Grid, format| TablePlan::new(m, g, format).err();
        let held = grid(vec![0.1], vec![-0.1]);
        assert!(matches!(
            refused(&held, Format::Linuxcnc),
            Some(TableError::NoRangedAxis)
        ));
        let fine = grid((0..300).map(|k| k as f64 * 1e-3).collect(), vec![-0.1]);
        assert!(matches!(
            refused(&fine, Format::Linuxcnc),
            Some(TableError::TooManyPositions { positions: 300, .. })
        ));
        let uneven = grid(vec![0.0, 0.1, 0.25], vec![-0.1]);
        assert!(matches!(
            refused(&uneven, Format::Sinumerik),
            Some(TableError::NotEquidistant(axis)) if axis == "X"
        ));
        let off = grid(vec![0.0, 0.1 + 1e-8], vec![-0.1]);
        assert!(matches!(
            refused(&off, Format::IsgLsec),
            Some(TableError::NotIsgPosition(axis)) if axis == "X"
        ));
        let both = grid(vec![0.0, 0.25, 0.5], vec![-0.2, 0.0]);
        assert!(matches!(
            refused(&both, Format::Volcomp),
            Some(TableError::NotIsoName(axis)) if axis == "Q"
        ));
        assert_eq!(equidistant(&[0.0, 0.1, 0.2]), Some(0.1));
        assert_eq!(equidistant(&[0.0]), None);
    }

    #[test]
    fn own_tables_take_out_a_positioning_error_linear_in_the_axis() {
        let c = compile(SLIDES).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![20e-6];
        assert_eq!(beta.len(), m.coefficients.len());
        let mut comp = Compensator::new(m, &beta, Options::position(m)).expect("compensator");
        let g = grid(vec![0.0, 0.25, 0.5], vec![-0.1]);
        let plan = TablePlan::new(m, &g, Format::Linuxcnc).expect("plan");
        assert_eq!(plan.reference(), &[0.25, -0.1]);
        let set = plan.build(&mut comp, "written by a test").expect("tables");
        let names: Vec<&str> = set.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["X.comp"]);
        assert!(set.note.starts_with("X: 3 positions;"), "{}", set.note);
        assert_eq!(set.summary.poses, 3);
        // 20 µm at the ends of the range; linear, so the table's interpolation is exact.
        assert!(
            (set.summary.before - 20e-6).abs() < 1e-12,
            "{:?}",
            set.summary
        );
        assert!(set.summary.with_tables < 1e-9, "{:?}", set.summary);
        assert!(set.summary.full < 1e-9, "{:?}", set.summary);
    }
}
