//! Drift over a duty cycle: the fitted model's error at fixed poses over a time series of
//! inputs, with its standard uncertainty (thesis §5.1.3, where thermal models are validated by
//! predicting the tool's drift over spindle duty cycles they were not fitted to).
//!
//! The lag states follow the cycle's inputs in time ([`crate::lag`], per run as in a
//! measurement file), so a prediction depends on the fitted time constants as well as on the
//! coefficients. Its variance is eq. 4.12 extended to the non-linear parameters θ with their
//! joint covariance ([`crate::fit::nonlinear::Joint`]):
//! `gᵀC₀g + (h − Aᵀg)ᵀ S (h − Aᵀg)`, `g = ∂e/∂β`, `h = ∂e/∂θ` (central differences: the lag
//! states are integrated again at `θ ± δ`).

use kin_compiler::ir::Machine;
use thiserror::Error;

use crate::data::{PointData, Pose, Rows};
use crate::engine::{Engine, Evaluator};
use crate::fit::report::FitReport;
use crate::interp::EvalError;
use crate::states::{StateError, States};

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

/// Whether the uncertainty includes the non-linear parameters' (the fit holds their joint
/// covariance), and which of them it includes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Coverage {
    /// Names of the fitted non-linear parameters whose uncertainty is included.
    pub included: Vec<String>,
    /// Names of fitted non-linear parameters the fit report carries no joint covariance for
    /// (a report written before it did): their uncertainty is left out.
    pub missing: Vec<String>,
}

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
/// every row (reached moving in +, [`held_directions`](crate::states::held_directions)), the
/// first tool.
fn at_pose(cycle: &Rows, m: &Machine, q: &[f64]) -> (Rows, Pose) {
    let n = cycle.len();
    let mut rows = cycle.clone();
    rows.tool = vec![0; n];
    rows.tool_offset = None;
    rows.artifact = None;
    let pose = Pose {
        axes: q.iter().map(|&x| vec![x; n]).collect(),
        dir: crate::states::held_directions(m, n),
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
    if let Some(f) = fit {
        if let Some(why) = f.covariance_mismatch(m) {
            return Err(PredictError::Covariance(why));
        }
    }
    let mut ev = crate::engine::make(m, engine).map_err(|e| PredictError::Engine(e.to_string()))?;
    let coverage = coverage(m, fit);
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
        out.push(one(m, fit, &coverage, ev.as_mut(), &rows, &pose, q)?);
    }
    Ok((out, coverage))
}

fn coverage(m: &Machine, fit: Option<&FitReport>) -> Coverage {
    let mut c = Coverage::default();
    let Some(f) = fit else { return c };
    let k = m.nonlinear.len();
    let joint = f.nonlinear_covariance.len() == k * k
        && f.nonlinear_sensitivity.len() == m.coefficients.len() * k;
    for (i, p) in m.nonlinear.iter().enumerate() {
        if !p.fitted {
            continue;
        }
        if joint
            && f.nonlinear_covariance
                .get(i * k + i)
                .is_some_and(|v| *v > 0.0)
        {
            c.included.push(p.name.clone());
        } else if !joint {
            c.missing.push(p.name.clone());
        }
    }
    c
}

fn one(
    m: &Machine,
    fit: Option<&FitReport>,
    coverage: &Coverage,
    ev: &mut (dyn Evaluator + Send),
    rows: &Rows,
    pose: &Pose,
    q: Vec<f64>,
) -> Result<Drift, PredictError> {
    let n = m.coefficients.len();
    let k = m.nonlinear.len();
    let mut states = States::new(m, rows, pose, "")?;
    let values: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let eval_err = |states: &States, r: usize, source| PredictError::Eval {
        line: states.line.get(r).copied().unwrap_or(0),
        source,
    };
    let len = states.len();
    let mut error = Vec::with_capacity(len);
    let mut jac = vec![0.0; 6 * n];
    let mut jacs: Vec<Vec<f64>> = Vec::new();
    for r in 0..len {
        let mut e = [0.0; 6];
        ev.error_and_jacobian(&states.get(r), &m.beta, &mut e, &mut jac)
            .map_err(|s| eval_err(&states, r, s))?;
        // `error_and_jacobian` gives the error at β itself; `error` is its definition, and
        // they agree, so one call serves both.
        error.push(e);
        if fit.is_some() {
            jacs.push(jac.clone());
        }
    }
    let Some(fit) = fit else {
        return Ok(Drift {
            pose: q,
            error,
            u: Vec::new(),
        });
    };
    // h = ∂e/∂θ for each included non-linear parameter, by central differences: the lag
    // states are integrated again and the engine told the new values (a wavelength).
    let included: Vec<usize> = m
        .nonlinear
        .iter()
        .enumerate()
        .filter(|(_, p)| coverage.included.contains(&p.name))
        .map(|(i, _)| i)
        .collect();
    let mut h: Vec<Vec<[f64; 6]>> = Vec::with_capacity(included.len());
    for &i in &included {
        let step = 1e-5
            * values
                .get(i)
                .copied()
                .unwrap_or(1.0)
                .abs()
                .max(f64::MIN_POSITIVE);
        let mut side = |sign: f64| -> Result<Vec<[f64; 6]>, PredictError> {
            let mut v = values.clone();
            if let Some(x) = v.get_mut(i) {
                *x += sign * step;
            }
            ev.set_nonlinear(&v).map_err(|s| eval_err(&states, 0, s))?;
            states.integrate_lags(m, rows, &v);
            (0..len)
                .map(|r| {
                    ev.error(&states.get(r), &m.beta)
                        .map_err(|s| eval_err(&states, r, s))
                })
                .collect()
        };
        let up = side(1.0)?;
        let dn = side(-1.0)?;
        h.push(
            up.iter()
                .zip(&dn)
                .map(|(a, b)| std::array::from_fn(|c| (a[c] - b[c]) / (2.0 * step)))
                .collect(),
        );
    }
    ev.set_nonlinear(&values)
        .map_err(|s| eval_err(&states, 0, s))?;
    let mut u = Vec::with_capacity(len);
    let mut d = vec![0.0; included.len()];
    for (r, jr) in jacs.iter().enumerate() {
        let mut ur = [0.0; 6];
        for (c, slot) in ur.iter_mut().enumerate() {
            let g = jr.get(c * n..(c + 1) * n).unwrap_or(&[]);
            let mut var = fit.variance_of(g);
            // d = h − Aᵀg over the included parameters, then dᵀ S d.
            for (a, &i) in included.iter().enumerate() {
                let atg: f64 = g
                    .iter()
                    .enumerate()
                    .map(|(b, gb)| {
                        gb * fit
                            .nonlinear_sensitivity
                            .get(b * k + i)
                            .copied()
                            .unwrap_or(0.0)
                    })
                    .sum();
                let hi = h.get(a).and_then(|col| col.get(r)).map_or(0.0, |e| e[c]);
                if let Some(slot) = d.get_mut(a) {
                    *slot = hi - atg;
                }
            }
            for (a, &i) in included.iter().enumerate() {
                for (b, &j) in included.iter().enumerate() {
                    let s = fit
                        .nonlinear_covariance
                        .get(i * k + j)
                        .copied()
                        .unwrap_or(0.0);
                    var += d[a] * s * d[b];
                }
            }
            *slot = var.max(0.0).sqrt();
        }
        u.push(ur);
    }
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
