//! A calibration plan read from measurement files, as the units [`crate::design`] chooses
//! among: every row the fit would use, whether or not the file holds the measured errors.
//!
//! A unit is one pose of a point file (its observed components together), one row of a length
//! file, or every row of one `artifact` label of a file: an artifact's placement (or a bar's
//! unknown length) is fitted from its own rows only, so its rows are chosen or dropped together
//! and its nuisance parameters are eliminated inside the unit.

use std::collections::BTreeMap;

use kin_compiler::ir::Machine;

use crate::design::Unit;
use crate::fit::{self as rows, DataSet, DesignError, Layout};
use kin_data::data::Observations;
use kin_model::engine::Evaluator;

/// The units of a plan, and where their rows come from.
#[derive(Debug, Clone)]
pub struct Plan {
    pub units: Vec<Unit>,
    /// Per unit: its file index and the file lines of its rows (in file order, no repeats).
    pub lines: Vec<(usize, Vec<usize>)>,
    /// Per unit: its artifact label, when it is one.
    pub artifact: Vec<Option<String>>,
    /// The number of coefficients (the width of every unit's rows).
    pub coefficients: usize,
}

/// Makes every observation of `files` count, whether or not it holds a measured value: a file
/// of poses becomes the plan of measuring there (ex, ey, ez at a point file's poses when it
/// names no error column; the length at a length file's rows).
pub fn as_planned(files: &mut [DataSet]) {
    for f in files {
        match &mut f.observations {
            Observations::Lengths(l) => {
                for v in &mut l.dl {
                    if v.is_nan() {
                        *v = 0.0;
                    }
                }
            }
            Observations::Points(p) => {
                let n = p.rows.len();
                if p.observed.iter().all(Option::is_none) {
                    for slot in p.observed.iter_mut().take(3) {
                        *slot = Some(vec![0.0; n]);
                    }
                } else if p.observed.iter().flatten().flatten().all(|v| v.is_nan()) {
                    // The columns are there but empty: the plan observes what they name.
                    for v in p.observed.iter_mut().flatten().flatten() {
                        *v = 0.0;
                    }
                }
            }
        }
    }
}

/// The units of `files` (see the module's documentation).
pub fn units(
    m: &Machine,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
) -> Result<Plan, DesignError> {
    let layout = Layout::new(m, files);
    let states = rows::states(m, files)?;
    let p = layout.coefficients;
    // Key: (file, artifact nuisance start) or (file, line) for a row of no artifact.
    #[derive(PartialEq, Eq, PartialOrd, Ord, Clone, Copy)]
    enum Key {
        Artifact(usize, usize),
        Registered(usize),
        Pose(usize, usize),
    }
    let mut order: Vec<Key> = Vec::new();
    let mut collected: BTreeMap<Key, (Vec<f64>, Vec<usize>)> = BTreeMap::new();
    let width = layout.columns();
    rows::for_each_row(engine, files, &states, &layout, |meta, x, _| {
        let first = x
            .get(p..)
            .and_then(|n| n.iter().position(|v| *v != 0.0))
            .map(|k| p + k);
        let registered = first
            .and_then(|c| layout.nuisance.get(c - p))
            .is_some_and(|n| n.kind.registers());
        let key = match first {
            // The instrument's placement and every target's offset are fitted from all the
            // file's rows: the file is one unit, all its registration eliminated inside it.
            Some(_) if registered => Key::Registered(meta.file as usize),
            Some(c) => {
                // The artifact's first nuisance column: its block starts where the label does.
                let start = (p..=c)
                    .rev()
                    .find(|&j| {
                        let here = layout.nuisance.get(j - p);
                        let before = j.checked_sub(p + 1).and_then(|i| layout.nuisance.get(i));
                        match (here, before) {
                            (Some(h), Some(b)) => h.file != b.file || h.artifact != b.artifact,
                            (Some(_), None) => true,
                            _ => false,
                        }
                    })
                    .unwrap_or(c);
                Key::Artifact(meta.file as usize, start)
            }
            None => Key::Pose(meta.file as usize, meta.line as usize),
        };
        let entry = collected.entry(key).or_insert_with(|| {
            order.push(key);
            (Vec::new(), Vec::new())
        });
        entry.0.extend_from_slice(x);
        if entry.1.last() != Some(&(meta.line as usize)) {
            entry.1.push(meta.line as usize);
        }
    })?;
    let mut plan = Plan {
        units: Vec::with_capacity(order.len()),
        lines: Vec::with_capacity(order.len()),
        artifact: Vec::with_capacity(order.len()),
        coefficients: p,
    };
    for key in order {
        let Some((x, lines)) = collected.remove(&key) else {
            continue;
        };
        let (file, unit, label) = match key {
            Key::Pose(file, _) => {
                let coefficients = take(&x, width, 0, p);
                let n = coefficients.len().checked_div(p).unwrap_or(0);
                (
                    file,
                    Unit {
                        rows: coefficients,
                        observations: n,
                    },
                    None,
                )
            }
            Key::Artifact(file, start) => {
                let label = layout.nuisance.get(start - p).map(|n| n.artifact.clone());
                let q = layout
                    .nuisance
                    .iter()
                    .skip(start - p)
                    .take_while(|n| Some(&n.artifact) == label.as_ref() && n.file == file)
                    .count();
                let mut own = Vec::with_capacity(x.len() / width.max(1) * (p + q));
                for row in x.chunks_exact(width.max(1)) {
                    own.extend_from_slice(row.get(..p).unwrap_or(&[]));
                    own.extend_from_slice(row.get(start..start + q).unwrap_or(&[]));
                }
                (file, Unit::eliminated(&own, p, q), label)
            }
            Key::Registered(file) => {
                // The file's instrument and the targets its rows measure (a named target shared
                // with another file is eliminated in each: conservative, never more determined
                // than the joint fit).
                let columns: Vec<usize> = layout
                    .nuisance
                    .iter()
                    .enumerate()
                    .filter(|(j, n)| {
                        n.kind.registers()
                            && x.chunks_exact(width.max(1))
                                .any(|row| row.get(p + j).is_some_and(|v| *v != 0.0))
                    })
                    .map(|(j, _)| p + j)
                    .collect();
                let mut own = Vec::with_capacity(x.len() / width.max(1) * (p + columns.len()));
                for row in x.chunks_exact(width.max(1)) {
                    own.extend_from_slice(row.get(..p).unwrap_or(&[]));
                    own.extend(columns.iter().map(|&j| row.get(j).copied().unwrap_or(0.0)));
                }
                (file, Unit::eliminated(&own, p, columns.len()), None)
            }
        };
        plan.units.push(unit);
        plan.lines.push((file, lines));
        plan.artifact.push(label);
    }
    Ok(plan)
}

fn take(x: &[f64], width: usize, from: usize, count: usize) -> Vec<f64> {
    x.chunks_exact(width.max(1))
        .flat_map(|r| r.get(from..from + count).unwrap_or(&[]).iter().copied())
        .collect()
}
