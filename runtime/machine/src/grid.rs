//! A regular grid of commanded poses: the values of every axis (one value for an axis held),
//! a direction per axis, the inputs, the tool. `kin compensate --grid` evaluates the corrections
//! on one, and a controller's tables ([`crate::table_set`]) are taken along its axes: the grid's
//! step is the tables' spacing.

use kin_compiler::ir::{Machine, Var};
use kin_data::data::{PointData, Pose, Rows};

/// A grid, in SI: the values of every axis (one value for a held axis), a direction
/// per axis, an input value per input the model uses, the tool.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    pub values: Vec<Vec<f64>>,
    pub dirs: Vec<f64>,
    pub inputs: Vec<Option<f64>>,
    pub tool: usize,
}

impl Grid {
    /// The number of grid points, if it fits in `usize`.
    pub fn count(&self) -> Option<usize> {
        self.values
            .iter()
            .try_fold(1usize, |n, v| n.checked_mul(v.len()))
    }

    /// The grid's poses as a poses table, the first axis varying slowest.
    pub fn points(&self, m: &Machine) -> PointData {
        let n = self.count().unwrap_or(0);
        let axes = self.values.len();
        let mut pose = Pose {
            axes: vec![Vec::with_capacity(n); axes],
            dir: vec![None; axes],
        };
        let mut index = vec![0usize; axes];
        for _ in 0..n {
            for ((col, values), k) in pose.axes.iter_mut().zip(&self.values).zip(&index) {
                col.push(values.get(*k).copied().unwrap_or(0.0));
            }
            // The odometer: the last axis turns fastest.
            for (k, values) in index.iter_mut().zip(&self.values).rev() {
                *k += 1;
                if *k < values.len() {
                    break;
                }
                *k = 0;
            }
        }
        let used = kin_model::states::used_vars(m);
        for (a, slot) in pose.dir.iter_mut().enumerate() {
            if used.contains(&Var::Direction(a)) {
                *slot = Some(vec![self.dirs.get(a).copied().unwrap_or(1.0); n]);
            }
        }
        let rows = Rows {
            line: (1..=n).collect(),
            // Lag states start in steady state with the inputs, which stay constant.
            time: (!m.lags.is_empty()).then(|| vec![0.0; n]),
            tool: vec![self.tool; n],
            inputs: self.inputs.iter().map(|v| v.map(|v| vec![v; n])).collect(),
            ..Rows::default()
        };
        PointData {
            rows,
            pose,
            observed: Default::default(),
            absolute: None,
        }
    }
}
