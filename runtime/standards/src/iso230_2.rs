//! ISO 230-2 evaluation of a bidirectional positioning run along one axis: per target position
//! the mean deviations and their spread in each direction of approach, the reversal value, and
//! the axis figures E, M, B, R and A (spec/iso230-2.md states the definitions).
//!
//! The run file is a small CSV of its own (`target`, `deviation`, `direction`, `cycle`), read with
//! the same CSV front end as measurement files, so quoting, `;`, decimal commas and inch units
//! work the same way.

use std::path::Path;

use kin_compiler::units::Unit;
use serde::Serialize;

use kin_data::data::csv::Dialect;

use crate::table::{self, push, Table};
pub use crate::table::{RunProblem, TestFileError as Iso2302Error};

/// One approach to a target: where, from which side, in which cycle, and the deviation measured
/// there (actual − target), in m.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub target: f64,
    pub up: bool,
    pub cycle: String,
    pub deviation: f64,
    pub line: usize,
}

/// A run as read: its samples, and the units the file used (for printing in the same units).
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub samples: Vec<Sample>,
    pub target_unit: Unit,
    pub deviation_unit: Unit,
}

/// The figures at one target position, in m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetFigures {
    pub target: f64,
    /// Approaches in the positive (↑) and negative (↓) direction.
    pub n_up: usize,
    pub n_down: usize,
    /// Mean unidirectional positional deviations x̄↑, x̄↓ and the bidirectional mean x̄.
    pub mean_up: f64,
    pub mean_down: f64,
    pub mean: f64,
    /// Estimators of the unidirectional standard uncertainty s↑, s↓ (n − 1 in the denominator).
    pub s_up: f64,
    pub s_down: f64,
    /// Reversal value B_i = x̄↑ − x̄↓.
    pub reversal: f64,
    /// Unidirectional repeatabilities R↑ = 4 s↑, R↓ = 4 s↓, and the bidirectional one
    /// R = max(2 s↑ + 2 s↓ + |B_i|, R↑, R↓).
    pub r_up: f64,
    pub r_down: f64,
    pub r: f64,
}

/// The axis figures, in m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisFigures {
    /// Systematic positioning error: range of x̄↑ (E↑), of x̄↓ (E↓), of both together (E).
    pub e_up: f64,
    pub e_down: f64,
    pub e: f64,
    /// Range of the mean bidirectional positional deviations x̄.
    pub m: f64,
    /// Largest |B_i|, and the mean of the B_i.
    pub b: f64,
    pub b_mean: f64,
    /// Largest R↑_i, R↓_i and R_i.
    pub r_up: f64,
    pub r_down: f64,
    pub r: f64,
    /// Accuracy: range of x̄ ± 2s in one direction (A↑, A↓) or both (A).
    pub a_up: f64,
    pub a_down: f64,
    pub a: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    /// In increasing target order.
    pub targets: Vec<TargetFigures>,
    pub axis: AxisFigures,
    /// The largest number of approaches per target and direction (ISO 230-2 asks for 5).
    pub cycles: usize,
}

/// Reads a run file from disk.
pub fn read_file(path: &Path) -> Result<Run, Iso2302Error> {
    table::read_file(path, read)
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Role {
    Target,
    Deviation,
    Direction,
    Cycle,
}

const COLUMNS: [(&str, Role); 4] = [
    ("target", Role::Target),
    ("deviation", Role::Deviation),
    ("direction", Role::Direction),
    ("cycle", Role::Cycle),
];

/// Reads a run file from memory; `path` only names it in errors. Targets default to mm and
/// deviations to um when their header gives no unit.
pub fn read(bytes: &[u8], path: &Path) -> Result<Run, Iso2302Error> {
    let invalid = |p| Iso2302Error::invalid(path, vec![p]);
    let mut file = Table::new(bytes).map_err(invalid)?;
    let mut problems = Vec::new();
    // Header: which column is which, and the units.
    let mut target_unit = Unit::atom("mm");
    let mut deviation_unit = Unit::atom("um");
    let columns = file.header(&mut problems, |cell, columns, problems| {
        let has = "a run file has target, deviation, direction, cycle";
        let role = cell.known(&COLUMNS, columns, has)?;
        match (role, cell.unit) {
            (_, None) => {}
            (Role::Target | Role::Deviation, Some(u)) => match table::length_unit(u) {
                Ok(unit) if role == Role::Target => target_unit = Some(unit),
                Ok(unit) => deviation_unit = Some(unit),
                Err(e) => push(problems, cell.column_problem(e)),
            },
            (_, Some(_)) => push(problems, cell.takes_no_unit()),
        }
        Ok(Some(role))
    });
    if let Some(p) = table::missing(&COLUMNS, &columns, |_| true) {
        push(&mut problems, p);
    }
    let (Some(target_unit), Some(deviation_unit)) = (target_unit, deviation_unit) else {
        return Err(invalid(RunProblem::File(
            "kin's unit table lacks mm or um".into(),
        )));
    };
    let dialect = file.dialect;
    let new = |line| Sample {
        target: f64::NAN,
        up: true,
        cycle: String::new(),
        deviation: f64::NAN,
        line,
    };
    let samples = file.records(&columns, &mut problems, new, |c, sample| {
        // A run covers at most a few metres with deviations of micrometres; the bound only
        // keeps absurd cells from overflowing the sums.
        let length = |unit: &Unit| {
            let within = "a value within ±10 km";
            table::bounded(c.text, dialect, unit, |v| v * unit.scale, 1e4, within)
        };
        match c.role {
            Role::Target => sample.target = length(&target_unit)?,
            Role::Deviation => sample.deviation = length(&deviation_unit)?,
            Role::Direction => {
                sample.up = direction(c.text, dialect)
                    .ok_or("+1 (approached from below) or -1 (from above)")?
            }
            Role::Cycle => sample.cycle = table::label(c.text, "a cycle label")?,
        }
        Ok(())
    });
    table::done(
        path,
        problems,
        Run {
            samples,
            target_unit,
            deviation_unit,
        },
    )
}

/// `+1`, `up` or `+` (approached from below), `-1`, `down` or `-` (from above), as written.
fn direction(cell: &str, dialect: Dialect) -> Option<bool> {
    match cell {
        "+" | "up" => Some(true),
        "-" | "\u{2212}" | "down" => Some(false),
        _ => table::unit_sign(cell, dialect),
    }
}

/// Mean and the estimator of the standard uncertainty (n − 1 in the denominator).
fn mean_and_s(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let ss: f64 = values.iter().map(|v| (v - mean).powi(2)).sum();
    (mean, (ss / (n - 1.0)).sqrt())
}

fn range(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let max = values.clone().fold(f64::NEG_INFINITY, f64::max);
    let min = values.fold(f64::INFINITY, f64::min);
    max - min
}

/// The ISO 230-2 figures of a run. Every target needs at least two approaches from each side
/// (a spread needs two values), and no (target, direction, cycle) may be given twice.
pub fn evaluate(run: &Run, path: &Path) -> Result<Evaluation, Iso2302Error> {
    let mut targets: Vec<f64> = run.samples.iter().map(|s| s.target).collect();
    targets.sort_by(f64::total_cmp);
    targets.dedup();
    let mut problems = Vec::new();
    let mut seen: std::collections::HashMap<(u64, bool, &str), usize> =
        std::collections::HashMap::new();
    for s in &run.samples {
        let key = (s.target.to_bits(), s.up, s.cycle.as_str());
        if let Some(first) = seen.insert(key, s.line) {
            push(
                &mut problems,
                RunProblem::Line {
                    line: s.line,
                    what: format!(
                        "cycle `{}` approaches this target from this side a second time (first at line {first})",
                        s.cycle
                    ),
                },
            );
        }
    }
    let mut figures = Vec::with_capacity(targets.len());
    let mut cycles = 0;
    for &t in &targets {
        let side = |up: bool| -> Vec<f64> {
            run.samples
                .iter()
                .filter(|s| s.target == t && s.up == up)
                .map(|s| s.deviation)
                .collect()
        };
        let (up, down) = (side(true), side(false));
        cycles = cycles.max(up.len()).max(down.len());
        if up.len() < 2 || down.len() < 2 {
            let shown = t / run.target_unit.scale;
            push(
                &mut problems,
                RunProblem::File(format!(
                    "target {shown} {}: {} approach(es) from below and {} from above; each side needs at least 2",
                    run.target_unit.name,
                    up.len(),
                    down.len()
                )),
            );
            continue;
        }
        let (mean_up, s_up) = mean_and_s(&up);
        let (mean_down, s_down) = mean_and_s(&down);
        let reversal = mean_up - mean_down;
        let (r_up, r_down) = (4.0 * s_up, 4.0 * s_down);
        figures.push(TargetFigures {
            target: t,
            n_up: up.len(),
            n_down: down.len(),
            mean_up,
            mean_down,
            mean: (mean_up + mean_down) / 2.0,
            s_up,
            s_down,
            reversal,
            r_up,
            r_down,
            r: (2.0 * s_up + 2.0 * s_down + reversal.abs())
                .max(r_up)
                .max(r_down),
        });
    }
    if !problems.is_empty() {
        return Err(Iso2302Error::invalid(path, problems));
    }
    let f = &figures;
    let max = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::NEG_INFINITY, f64::max);
    let min = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::INFINITY, f64::min);
    let both_means = f.iter().flat_map(|t| [t.mean_up, t.mean_down]);
    let axis = AxisFigures {
        e_up: range(f.iter().map(|t| t.mean_up)),
        e_down: range(f.iter().map(|t| t.mean_down)),
        e: range(both_means),
        m: range(f.iter().map(|t| t.mean)),
        b: max(&mut f.iter().map(|t| t.reversal.abs())),
        b_mean: f.iter().map(|t| t.reversal).sum::<f64>() / f.len() as f64,
        r_up: max(&mut f.iter().map(|t| t.r_up)),
        r_down: max(&mut f.iter().map(|t| t.r_down)),
        r: max(&mut f.iter().map(|t| t.r)),
        a_up: max(&mut f.iter().map(|t| t.mean_up + 2.0 * t.s_up))
            - min(&mut f.iter().map(|t| t.mean_up - 2.0 * t.s_up)),
        a_down: max(&mut f.iter().map(|t| t.mean_down + 2.0 * t.s_down))
            - min(&mut f.iter().map(|t| t.mean_down - 2.0 * t.s_down)),
        a: max(&mut f
            .iter()
            .flat_map(|t| [t.mean_up + 2.0 * t.s_up, t.mean_down + 2.0 * t.s_down]))
            - min(&mut f
                .iter()
                .flat_map(|t| [t.mean_up - 2.0 * t.s_up, t.mean_down - 2.0 * t.s_down])),
    };
    Ok(Evaluation {
        targets: figures,
        axis,
        cycles,
    })
}

/// The pure-error lack-of-fit test of a model's predicted deviations against the run: every
/// (target, direction) is a group of replicates whose scatter about its own mean is the
/// machine's repeatability (pure error); what remains of the residuals `deviation − predicted`
/// is lack of fit. `predicted` is in the order of `run.samples`; `fitted` is how many degrees of
/// freedom a fit to this run's own deviations took (0 when the prediction comes from other
/// data, which makes the test exact). The F-test is the one `kin diagnose` applies to repeated
/// poses ([`kin_estimate::statistics::lack_of_fit`]).
pub fn lack_of_fit(
    run: &Run,
    predicted: &[f64],
    fitted: f64,
    alpha: f64,
) -> Option<kin_estimate::statistics::LackOfFit> {
    let mut groups: std::collections::BTreeMap<(u64, bool), (usize, f64, f64)> =
        std::collections::BTreeMap::new();
    let mut rss = 0.0;
    for (s, p) in run.samples.iter().zip(predicted) {
        let r = s.deviation - p;
        let g = groups
            .entry((s.target.to_bits(), s.up))
            .or_insert((0, 0.0, 0.0));
        g.0 += 1;
        g.1 += r;
        g.2 += r * r;
        rss += r * r;
    }
    let n = run.samples.len().min(predicted.len()) as f64;
    kin_estimate::statistics::lack_of_fit(groups.into_values(), rss, n - fitted, alpha)
}

#[cfg(test)]
mod tests;
