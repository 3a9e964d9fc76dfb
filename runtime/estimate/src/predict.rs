//! Drift over a duty cycle: the fitted model's error at fixed poses over a time series of
//! inputs, with its standard uncertainty (thesis §5.1.3, where thermal models are validated by
//! predicting the tool's drift over spindle duty cycles they were not fitted to).
//!
//! The lag states follow the cycle's inputs in time ([`kin_model::lag`], per run as in a
//! measurement file), so a prediction depends on the fitted time constants as well as on the
//! coefficients. Its variance is eq. 4.12 extended to the non-linear parameters θ with their
//! joint covariance, as for every prediction ([`crate::uncertainty`]).

use kin_compiler::ir::Machine;
use thiserror::Error;

use crate::fit::report::FitReport;
use crate::uncertainty::PredictionCovariance;
use kin_data::data::{PointData, Pose, Rows};
use kin_model::engine::{Engine, Evaluator};
use kin_model::interp::EvalError;
use kin_model::states::{StateError, States};

#[derive(Debug, Error)]
pub enum PredictError {
    #[error(transparent)]
    State(#[from] StateError),
    #[error("line {line}: {source}")]
    Eval {
        line: usize,
        #[source]
        source: EvalError,
    },
    #[error("{0}")]
    Engine(String),
    #[error("the fit's covariance does not fit this model: {0}")]
    Covariance(String),
    #[error("pose {pose} has {got} axis values, the machine has {want} axes")]
    PoseSize {
        pose: usize,
        got: usize,
        want: usize,
    },
    #[error("the cycle has no rows")]
    Empty,
}

/// The prediction at one pose over every row of the cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct Drift {
    /// Axis positions (SI), indexed like `Machine::axes`.
    pub pose: Vec<f64>,
    /// `ex … erz` at each row (SI, task sign).
    pub error: Vec<[f64; 6]>,
    /// Standard uncertainty (k = 1) of each component at each row (SI); empty without a fit.
    pub u: Vec<[f64; 6]>,
}

pub use crate::uncertainty::Coverage;

/// The default pose of a prediction: every axis at the middle of its declared range (a
/// continuous revolute axis, whose range is a full turn, at its start).
pub fn midpoint_pose(m: &Machine) -> Vec<f64> {
    m.axes
        .iter()
        .map(|a| {
            if a.continuous {
                0.0
            } else {
                0.5 * (a.range[0] + a.range[1])
            }
        })
        .collect()
}

/// The rows of the cycle at one fixed pose: the cycle's time, runs and inputs, the pose on
/// every row (reached moving in +, [`held_directions`](kin_model::states::held_directions)), the
/// first tool.
fn at_pose(cycle: &Rows, m: &Machine, q: &[f64]) -> (Rows, Pose) {
    let n = cycle.len();
    let mut rows = cycle.clone();
    rows.tool = vec![0; n];
    rows.tool_offset = None;
    rows.artifact = None;
    let pose = Pose {
        axes: q.iter().map(|&x| vec![x; n]).collect(),
        dir: kin_model::states::held_directions(m, n),
    };
    (rows, pose)
}

/// The model's error over the cycle at each of `poses` (or, with `poses` empty, at the rows'
/// own poses of `cycle` when it has every axis column, else at [`midpoint_pose`]), with
/// uncertainties from `fit` when given. A [`Drift`] at the rows' own poses has an empty `pose`. `m` carries the fitted coefficients (`m.beta`) and non-linear values.
pub fn drift(
    m: &Machine,
    fit: Option<&FitReport>,
    cycle: &PointData,
    poses: &[Vec<f64>],
    engine: Engine,
) -> Result<(Vec<Drift>, Coverage), PredictError> {
    if cycle.rows.is_empty() {
        return Err(PredictError::Empty);
    }
    let cov = match fit {
        Some(f) => Some(PredictionCovariance::new(m, f).map_err(PredictError::Covariance)?),
        None => None,
    };
    let mut ev =
        kin_model::engine::make(m, engine).map_err(|e| PredictError::Engine(e.to_string()))?;
    let coverage = cov
        .as_ref()
        .map(|c| c.coverage().clone())
        .unwrap_or_default();
    let mut out = Vec::new();
    let n = cycle.rows.len();
    let own = cycle.pose.axes.len() == m.axes.len() && cycle.pose.axes.iter().all(|c| c.len() == n);
    let midpoint = [midpoint_pose(m)];
    let poses = if poses.is_empty() && !own {
        &midpoint[..]
    } else {
        poses
    };
    let targets: Vec<(Rows, Pose, Vec<f64>)> = if poses.is_empty() {
        vec![(cycle.rows.clone(), cycle.pose.clone(), Vec::new())]
    } else {
        let mut v = Vec::new();
        for (k, q) in poses.iter().enumerate() {
            if q.len() != m.axes.len() {
                return Err(PredictError::PoseSize {
                    pose: k + 1,
                    got: q.len(),
                    want: m.axes.len(),
                });
            }
            let (rows, pose) = at_pose(&cycle.rows, m, q);
            v.push((rows, pose, q.clone()));
        }
        v
    };
    for (rows, pose, q) in targets {
        out.push(one(m, cov.as_ref(), ev.as_mut(), &rows, &pose, q)?);
    }
    Ok((out, coverage))
}

fn one(
    m: &Machine,
    cov: Option<&PredictionCovariance>,
    ev: &mut (dyn Evaluator + Send),
    rows: &Rows,
    pose: &Pose,
    q: Vec<f64>,
) -> Result<Drift, PredictError> {
    let mut states = States::new(m, rows, pose, "")?;
    let eval_err = |states: &States, r: usize, source| PredictError::Eval {
        line: states.line.get(r).copied().unwrap_or(0),
        source,
    };
    // The error at β through the Jacobian pass, as the fit computes it (the error-only code of
    // an engine may round differently in the last bit).
    let mut jac = vec![0.0; 6 * m.coefficients.len()];
    let error = (0..states.len())
        .map(|r| {
            let mut e = [0.0; 6];
            ev.error_and_jacobian(&states.get(r), &m.beta, &mut e, &mut jac)
                .map_err(|s| eval_err(&states, r, s))
                .map(|()| e)
        })
        .collect::<Result<Vec<[f64; 6]>, PredictError>>()?;
    let Some(cov) = cov else {
        return Ok(Drift {
            pose: q,
            error,
            u: Vec::new(),
        });
    };
    let u = cov
        .point_variances(m, ev, &mut states, rows)
        .map_err(|e| eval_err(&states, e.row, e.source))?
        .iter()
        .map(|v| v.map(|x| x.max(0.0).sqrt()))
        .collect();
    Ok(Drift { pose: q, error, u })
}

/// Root mean square of `observed − predicted` over the rows where both are finite, and how
/// many rows that is.
pub fn rms(observed: &[f64], predicted: &[f64]) -> (f64, usize) {
    let (mut s, mut count) = (0.0, 0usize);
    for (o, p) in observed.iter().zip(predicted) {
        if o.is_finite() && p.is_finite() {
            s += (o - p).powi(2);
            count += 1;
        }
    }
    if count == 0 {
        (f64::NAN, 0)
    } else {
        ((s / count as f64).sqrt(), count)
    }
}
