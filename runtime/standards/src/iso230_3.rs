//! ISO 230-3 evaluation of thermal tests from their time series (spec/iso230-3.md): the
//! environmental temperature variation error (ETVE) — the largest range of the relative
//! displacement between tool side and workpiece side while only the environment changes — and
//! the thermal distortion caused by a rotating spindle — the drift of each displacement from
//! its value when the spindle started, with the tilts of the spindle axis from pairs of
//! sensors a known distance apart along it.
//!
//! The run file is a small CSV (`time`, displacement channels `X`, `Y`, `Z` or the pairs
//! `X1 X2`, `Y1 Y2`, `Z1 Z2`, temperature channels `T…`), read with the CSV front end of the
//! ISO 230-2 and 230-4 files; `# separation: 100 mm` before the header gives the distance from
//! sensor 1 to sensor 2 of each pair.

use std::path::Path;

use kin_compiler::units::{Dim, Unit};
use serde::Serialize;

pub use crate::table::TestFileError as Iso2303Error;
use crate::table::{self, push, RunProblem, Table};

/// One measured quantity over time: a displacement (m) or a temperature (K, as read).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Channel {
    pub name: String,
    pub values: Vec<f64>,
}

/// A thermal test's time series.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ThermalRun {
    /// Seconds, non-decreasing.
    pub time: Vec<f64>,
    pub displacements: Vec<Channel>,
    pub temperatures: Vec<Channel>,
    /// Distance from sensor 1 to sensor 2 of each pair along the spindle axis, m.
    pub separation: Option<f64>,
    pub line: Vec<usize>,
}

/// The figures of one channel over the test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelFigures {
    pub name: String,
    /// Largest minus least value over the test (the ETVE of a displacement channel).
    pub range: f64,
    /// The value of largest magnitude of `v(t) − v(0)`, signed: the drift from the start.
    pub drift: f64,
    /// When the drift was reached, s from the start.
    pub drift_at: f64,
    /// The drift at the last sample.
    pub end: f64,
}

/// A tilt of the spindle axis from a pair of sensors: `(v₂ − v₁)/separation` per sample.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Tilt {
    /// `X` (tilt in the plane of X and the spindle axis) or `Y`, `Z`.
    pub pair: String,
    pub values: Vec<f64>,
    pub figures: ChannelFigures,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    pub duration: f64,
    pub samples: usize,
    pub displacements: Vec<ChannelFigures>,
    pub tilts: Vec<Tilt>,
    pub temperatures: Vec<ChannelFigures>,
}

/// Range and drift of one series at `time`.
pub fn figures(name: &str, time: &[f64], v: &[f64]) -> ChannelFigures {
    let first = v.first().copied().unwrap_or(0.0);
    let t0 = time.first().copied().unwrap_or(0.0);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let (mut drift, mut at) = (0.0f64, 0.0);
    for (t, x) in time.iter().zip(v) {
        lo = lo.min(*x);
        hi = hi.max(*x);
        if (x - first).abs() > drift.abs() {
            drift = x - first;
            at = t - t0;
        }
    }
    ChannelFigures {
        name: name.to_string(),
        range: if hi >= lo { hi - lo } else { 0.0 },
        drift,
        drift_at: at,
        end: v.last().copied().unwrap_or(first) - first,
    }
}

/// The ETVE and spindle-drift figures of a run.
pub fn evaluate(run: &ThermalRun) -> Evaluation {
    let t = &run.time;
    let displacements = run
        .displacements
        .iter()
        .map(|c| figures(&c.name, t, &c.values))
        .collect();
    let temperatures = run
        .temperatures
        .iter()
        .map(|c| figures(&c.name, t, &c.values))
        .collect();
    let mut tilts = Vec::new();
    if let Some(l) = run.separation.filter(|l| *l > 0.0) {
        for axis in ["X", "Y", "Z"] {
            let find = |k: &str| {
                run.displacements
                    .iter()
                    .find(|c| c.name == format!("{axis}{k}"))
            };
            if let (Some(a), Some(b)) = (find("1"), find("2")) {
                let values: Vec<f64> = a
                    .values
                    .iter()
                    .zip(&b.values)
                    .map(|(v1, v2)| (v2 - v1) / l)
                    .collect();
                let figures = figures(&format!("tilt {axis}"), t, &values);
                tilts.push(Tilt {
                    pair: axis.to_string(),
                    values,
                    figures,
                });
            }
        }
    }
    Evaluation {
        duration: t.last().copied().unwrap_or(0.0) - t.first().copied().unwrap_or(0.0),
        samples: t.len(),
        displacements,
        tilts,
        temperatures,
    }
}

#[derive(Clone)]
enum Role {
    Time(Unit),
    Displacement(Unit),
    Temperature(Unit),
}

const DISPLACEMENTS: [&str; 9] = ["X", "Y", "Z", "X1", "X2", "Y1", "Y2", "Z1", "Z2"];

/// Reads a thermal test's run file from disk (spec/iso230-3.md).
pub fn read_file(path: &Path) -> Result<ThermalRun, Iso2303Error> {
    table::read_file(path, read)
}

/// Times within ±10¹⁰ s (a Unix time stamp fits).
const MAX_TIME: f64 = 1e10;
/// Displacements within ±1 m.
const MAX_DISPLACEMENT: f64 = 1.0;
/// Temperatures within ±10 000 K (in kelvin, so any Celsius reading of a machine fits).
const MAX_TEMPERATURE: f64 = 1e4;

/// Reads a run file from memory; `path` only names it in errors.
pub fn read(bytes: &[u8], path: &Path) -> Result<ThermalRun, Iso2303Error> {
    let mut file = Table::new(bytes).map_err(|p| Iso2303Error::invalid(path, vec![p]))?;
    let mut problems = Vec::new();
    let mut run = ThermalRun::default();
    for &(line, comment) in &file.setup {
        // Only `key: value` (the 230-4 files also take `key = value`).
        let Some((k, v)) = table::setup_entry(comment, &[':']) else {
            continue;
        };
        if !k.eq_ignore_ascii_case("separation") {
            continue;
        }
        // Between a micrometre and ten metres: a tilt is a difference divided by it, and a
        // separation outside any spindle's length would only turn rounding into radians.
        match quantity(v, Dim::LENGTH) {
            Some(x) if (1e-6..=10.0).contains(&x) => run.separation = Some(x),
            _ => push(
                &mut problems,
                RunProblem::Line {
                    line,
                    what: format!(
                        "`{v}`: expected a positive length from 1 um to 10 m, e.g. `separation: 100 mm`"
                    ),
                },
            ),
        }
    }
    let columns = file.header(&mut problems, |cell, columns, problems| {
        let (name, unit) = (cell.name, cell.unit);
        // Any name seen before is a duplicate, an unknown one too (230-2 and 230-4 files call
        // every unknown name unknown). A duplicate leaves an empty name, as a malformed cell does.
        if columns.iter().any(|c| c.name == name) {
            return Err(cell.duplicate());
        }
        let role = if name == "time" {
            match unit.map(Unit::parse) {
                None => Unit::atom("s").map(Role::Time),
                Some(Ok(u)) if u.dim == Dim::TIME => Some(Role::Time(u)),
                Some(_) => {
                    push(
                        problems,
                        cell.at(format!("`{}`: expected a time unit (s, min, h)", cell.text)),
                    );
                    None
                }
            }
        } else if DISPLACEMENTS.contains(&name) {
            match unit.map(table::length_unit) {
                None => Unit::atom("um").map(Role::Displacement),
                Some(Ok(u)) => Some(Role::Displacement(u)),
                Some(Err(e)) => {
                    push(problems, cell.column_problem(e));
                    None
                }
            }
        } else if name.starts_with('T') {
            match unit.map(Unit::parse) {
                None => Unit::atom("degC").map(|u| Role::Temperature(u.as_difference())),
                Some(Ok(u)) if u.dim == Dim::TEMPERATURE => {
                    Some(Role::Temperature(u.as_difference()))
                }
                Some(_) => {
                    push(
                        problems,
                        cell.column_problem("expected a temperature unit (degC, K)"),
                    );
                    None
                }
            }
        } else {
            // Unlike a duplicate, an unknown column keeps its name.
            push(
                problems,
                cell.unknown(
                    "a thermal-test file has time, displacements X Y Z (or X1 X2 Y1 Y2 Z1 Z2) and temperatures T…",
                ),
            );
            None
        };
        Ok(role)
    });
    if !columns
        .iter()
        .any(|c| matches!(c.role, Some(Role::Time(_))))
    {
        push(&mut problems, RunProblem::File("no `time` column".into()));
    }
    if !columns
        .iter()
        .any(|c| matches!(c.role, Some(Role::Displacement(_))))
    {
        push(
            &mut problems,
            RunProblem::File("no displacement column (X, Y, Z, X1 … Z2)".into()),
        );
    }
    let mut values: Vec<Vec<f64>> = vec![Vec::new(); columns.len()];
    let mut last_time: Option<(f64, usize)> = None;
    let dialect = file.dialect;
    // A shorter wording than the 230-2 and 230-4 files' `… but the header has N columns`.
    let mismatch = |cells, columns| format!("{cells} cells, the header has {columns}");
    file.rows(&columns, &mut problems, mismatch, |row, problems| {
        let n = row.line;
        // Every cell is read, and the row counted, whatever its other cells hold.
        for c in row.cells() {
            let unit = match c.role {
                Role::Time(u) | Role::Displacement(u) | Role::Temperature(u) => u,
            };
            // The bounds only keep absurd cells out of the ranges and tilts (a displacement of
            // 1e300 um printed as 300 digits, a tilt of `inf`): a thermal test's displacements
            // are micrometres, its times hours, its temperatures tens of degrees.
            let (limit, within) = match c.role {
                Role::Time(_) => (MAX_TIME, "a time within ±1e10 s"),
                Role::Displacement(_) => (MAX_DISPLACEMENT, "a displacement within ±1 m"),
                Role::Temperature(_) => (MAX_TEMPERATURE, "a temperature within ±10 000 K"),
            };
            let si = match table::bounded(c.text, dialect, unit, |v| unit.to_si(v), limit, within)
            {
                Ok(si) => si,
                Err(expected) => {
                    push(
                        problems,
                        c.at(format!("`{}`: expected {expected} (`{}`)", c.text, c.name)),
                    );
                    continue;
                }
            };
            if let Role::Time(_) = c.role {
                if let Some((prev, prev_line)) = last_time {
                    if si < prev {
                        push(
                            problems,
                            c.at(format!(
                                "time {} is before the time at line {prev_line}: samples must be in time order",
                                c.text
                            )),
                        );
                    }
                }
                last_time = Some((si, n));
            }
            if let Some(col) = values.get_mut(c.index) {
                col.push(si);
            }
        }
        run.line.push(n);
    });
    if run.line.is_empty() && problems.is_empty() {
        push(&mut problems, RunProblem::File("no samples".into()));
    }
    let pairs = columns
        .iter()
        .any(|c| c.name.ends_with('1') || c.name.ends_with('2'));
    if pairs && run.separation.is_none() && problems.is_empty() {
        push(
            &mut problems,
            RunProblem::File(
                "sensor pairs (X1, X2 …) need `# separation: L mm` before the header: the distance from sensor 1 to sensor 2 along the spindle axis".into(),
            ),
        );
    }
    if !problems.is_empty() {
        return Err(Iso2303Error::invalid(path, problems));
    }
    for (column, values) in columns.into_iter().zip(values) {
        let name = column.name;
        match column.role {
            Some(Role::Time(_)) => run.time = values,
            Some(Role::Displacement(_)) => run.displacements.push(Channel { name, values }),
            Some(Role::Temperature(_)) => run.temperatures.push(Channel { name, values }),
            None => {}
        }
    }
    Ok(run)
}

/// `100 mm`, `100mm`: a number and a unit of `dim`, in SI.
fn quantity(text: &str, dim: Dim) -> Option<f64> {
    let split = text
        .find(|c: char| c.is_alphabetic() || c == 'µ')
        .unwrap_or(text.len());
    let (v, u) = text.split_at(split);
    let v: f64 = v.trim().parse().ok()?;
    let unit = Unit::parse(u.trim()).ok()?;
    (unit.dim == dim && v.is_finite()).then_some(v * unit.scale)
}

#[cfg(test)]
mod tests;
