//! The corrections of a positioning machine's axes at commanded poses (Soons 1993, §2.3.5, by
//! [`Compensator`]), and the largest errors the model predicts before and after them: what
//! `kin compensate` writes as a CSV and sums up.

use kin_compiler::ir::Machine;
use kin_data::data::PointData;
use kin_model::compensate::{CompensateError, Compensator, Correction};
use kin_model::states::{StateError, States};
use thiserror::Error;

/// Why the poses could not be corrected.
#[derive(Debug, Error)]
pub enum CorrectionError {
    /// The poses lack a value the model uses.
    #[error(transparent)]
    States(#[from] StateError),
    /// The compensator refused one pose: `line` is its line in its file (its number among a
    /// grid's poses).
    #[error("line {line}: {source}")]
    Pose {
        line: usize,
        source: CompensateError,
    },
}

/// The correction of every row of `points`, in their order, moving only the axes `free` marks
/// (indexed like `Machine::axes`; every axis when `None`). An axis whose `dir_` column the file
/// lacks is taken as approached in the positive direction, as `--grid` does.
pub fn corrections(
    m: &Machine,
    comp: &mut Compensator<'_>,
    points: &PointData,
    free: Option<&[bool]>,
) -> Result<Vec<Correction>, CorrectionError> {
    let mut pose = points.pose.clone();
    for slot in pose.dir.iter_mut() {
        if slot.is_none() {
            *slot = Some(vec![1.0; points.rows.len()]);
        }
    }
    let states = States::new(m, &points.rows, &pose, "")?;
    (0..states.len())
        .map(|r| {
            comp.compensate_with(&states.get(r), free)
                .map_err(|source| CorrectionError::Pose {
                    line: states.line.get(r).copied().unwrap_or(0),
                    source,
                })
        })
        .collect()
}

/// The length of the three components of `v` from `from` (0: the position error, 3: the
/// orientation error).
pub(crate) fn norm3(v: &[f64; 6], from: usize) -> f64 {
    v.iter()
        .skip(from)
        .take(3)
        .map(|x| x * x)
        .sum::<f64>()
        .sqrt()
}

/// Before and after over a set of corrections, in SI: what compensation achieves and what
/// stays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// The largest predicted position error without the corrections …
    pub position_before: f64,
    /// … and with them.
    pub position_after: f64,
    /// The largest predicted orientation error without the corrections …
    pub orientation_before: f64,
    /// … and with them.
    pub orientation_after: f64,
    /// The fewest independent combinations of the weighted components the axes can move at
    /// any of the poses (`None` without poses): below the number of weighted components, what
    /// the axes cannot move stays.
    pub rank: Option<usize>,
}

impl Summary {
    pub fn of(c: &[Correction]) -> Summary {
        let max = |f: &dyn Fn(&Correction) -> f64| c.iter().map(f).fold(0.0_f64, f64::max);
        Summary {
            position_before: max(&|c| norm3(&c.before, 0)),
            position_after: max(&|c| norm3(&c.after, 0)),
            orientation_before: max(&|c| norm3(&c.before, 3)),
            orientation_after: max(&|c| norm3(&c.after, 3)),
            rank: c.iter().map(|c| c.rank).min(),
        }
    }
}
