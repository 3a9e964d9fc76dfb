//! Software compensation of a positioning machine (Soons 1993, §2.3.5): the joint corrections
//! `δq` that, added to the commanded axis positions, cancel the predicted tool-location error.
//!
//! The thesis adds a correction variable to every axis and solves the problem linearised on the
//! joint Jacobian: with `J` the nominal Jacobian of the tool location with respect to the joint
//! positions and `e` the predicted error, `δq` minimises `‖W (J δq + e)‖` for a diagonal weight
//! `W` over the six components the user cares about. Here the linear solve is the first
//! Gauss–Newton step; the compensated pose is then re-evaluated with the *exact* transforms
//! (including the errors at the moved position `q + δq`, which differ from those at `q`, and
//! the second-order terms of the rotations) and corrected again, so what is reported as
//! remaining is what the model predicts the machine will really do.
//!
//! The machine corrects only what its joints can move: a 3-axis machine cannot take out an
//! angular error, a table-table 5-axis machine cannot turn the tool about the direction
//! perpendicular to both rotary axes. The rank-revealing solve leaves those parts alone and
//! they stay in the remaining error, which is reported per pose.

use kin_compiler::ir::{JointKind, Machine};
use nalgebra::{DMatrix, DVector, Matrix4, Vector6};
use thiserror::Error;

use crate::exact;
use crate::interp::{EvalError, Interpreter, State};
use crate::kinematics::{FrameErrors, KinematicsError, Pose};

#[derive(Debug, Error)]
pub enum CompensateError {
    #[error(
        "machine `{0}` is a measuring machine (`task measure`): its readings are corrected, not its axes (`kin correct`)"
    )]
    Measuring(String),
    #[error(
        "axis {axis} is commanded to {value} {unit}, outside its declared range {lo} .. {hi} {unit}"
    )]
    OutOfRange {
        axis: String,
        value: f64,
        lo: f64,
        hi: f64,
        unit: String,
    },
    #[error("the weights of the components must be finite and non-negative, and one positive")]
    Weights,
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    #[error("the correction does not converge (the singular value decomposition failed)")]
    Solve,
}

/// What the corrections minimise, and how hard the solve tries.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Weight of each component `(ex, ey, ez, erx, ery, erz)` of the error, in SI (per m for
    /// positions, per rad for rotations); 0 leaves a component out.
    pub weights: [f64; 6],
    /// Gauss–Newton steps with the exact transforms (the first is the thesis' linear solve).
    pub iterations: usize,
    /// Relative size below which a singular value of the column-scaled, weighted Jacobian is a
    /// direction the machine cannot correct.
    pub rank_tolerance: f64,
}

impl Options {
    /// Every component, a rotation weighed as in the fit (one tilt unit as one error unit):
    /// the machine then corrects all it can, and nothing else changes the solution (a 3-axis
    /// machine's corrections are those of position alone).
    pub fn pose(m: &Machine) -> Options {
        let l = crate::fit::rotation_weight(m);
        Options {
            weights: [1.0, 1.0, 1.0, l, l, l],
            iterations: 4,
            rank_tolerance: 1e-9,
        }
    }

    /// The tool position only; orientation errors are left as they are.
    pub fn position(m: &Machine) -> Options {
        Options {
            weights: [1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
            ..Options::pose(m)
        }
    }
}

/// The correction at one commanded pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Correction {
    /// Add to the commanded axis positions (m or rad), indexed like `Machine::axes`.
    pub dq: Vec<f64>,
    /// The predicted positioning error at the commanded pose (actual − nominal, SI).
    pub before: [f64; 6],
    /// The predicted error of the compensated pose against the commanded location: what the
    /// machine cannot correct (and, for unweighted components, what it was not asked to).
    pub after: [f64; 6],
    /// How many independent combinations of the weighted components the joints can move.
    pub rank: usize,
}

/// Compensates poses of one machine with coefficients `beta`; holds the scratch of a pose.
pub struct Compensator<'m> {
    m: &'m Machine,
    beta: &'m [f64],
    it: Interpreter<'m>,
    errors: FrameErrors,
    jacobian: Vec<Vector6<f64>>,
    q: Vec<f64>,
    options: Options,
}

impl<'m> Compensator<'m> {
    pub fn new(m: &'m Machine, beta: &'m [f64], options: Options) -> Result<Self, CompensateError> {
        if m.task.sign() < 0.0 {
            return Err(CompensateError::Measuring(m.name.clone()));
        }
        let w = options.weights;
        if w.iter().any(|x| !(x.is_finite() && *x >= 0.0)) || w.iter().all(|x| *x == 0.0) {
            return Err(CompensateError::Weights);
        }
        Ok(Compensator {
            m,
            beta,
            it: Interpreter::new(m)?,
            errors: FrameErrors::zeros(m),
            jacobian: vec![Vector6::zeros(); m.axes.len()],
            q: vec![0.0; m.axes.len()],
            options,
        })
    }

    /// The interpreter evaluating the model (to set fitted non-linear parameters).
    pub fn interpreter(&mut self) -> &mut Interpreter<'m> {
        &mut self.it
    }

    /// The correction of the commanded pose `state` (its tool, inputs and directions of motion
    /// are kept; the directions are those of the commanded motion, which the small correction
    /// does not reverse).
    pub fn compensate(&mut self, state: &State) -> Result<Correction, CompensateError> {
        self.compensate_with(state, None)
    }

    /// As [`Compensator::compensate`], moving only the axes `free` marks (indexed like
    /// `Machine::axes`; all of them when `None`): what a per-axis controller table can do.
    pub fn compensate_with(
        &mut self,
        state: &State,
        free: Option<&[bool]>,
    ) -> Result<Correction, CompensateError> {
        check_range(self.m, state.q)?;
        let n = self.m.axes.len();
        let target = self.target(state)?;
        let w = Vector6::from(self.options.weights);
        let mut dq = vec![0.0; n];
        let mut residual = self.error_at(state, &dq, &target)?;
        let before = residual;
        let mut rank = 0;
        for step in 0..self.options.iterations {
            // The Jacobian at the pose reached so far (`self.q` holds it after `error_at`).
            let moved = State {
                q: &self.q,
                ..*state
            };
            self.it.nominal_jacobian(&moved, &mut self.jacobian)?;
            if let Some(free) = free {
                for (j, column) in self.jacobian.iter_mut().enumerate() {
                    if !free.get(j).copied().unwrap_or(false) {
                        *column = Vector6::zeros();
                    }
                }
            }
            let (delta, r) = solve(&self.jacobian, &w, &residual, self.options.rank_tolerance)?;
            rank = r;
            for (d, x) in dq.iter_mut().zip(delta.iter()) {
                *d += x;
            }
            // The step's effect on the weighted error: below a picometre it no longer matters.
            let effect: f64 = self
                .jacobian
                .iter()
                .zip(delta.iter())
                .map(|(j, x)| j.component_mul(&w) * *x)
                .sum::<Vector6<f64>>()
                .norm();
            residual = self.error_at(state, &dq, &target)?;
            if effect < 1e-12 && step > 0 {
                break;
            }
        }
        Ok(Correction {
            dq,
            before: before.into(),
            after: residual.into(),
            rank,
        })
    }

    /// The predicted error (exact transforms) of the commanded pose `state` when the axes are
    /// moved by `dq` instead: how well some other correction (a controller table's) does.
    pub fn remaining(&mut self, state: &State, dq: &[f64]) -> Result<[f64; 6], CompensateError> {
        let target = self.target(state)?;
        Ok(self.error_at(state, dq, &target)?.into())
    }

    /// The nominal location the commanded pose asks for.
    fn target(&self, state: &State) -> Result<Matrix4<f64>, CompensateError> {
        let commanded = Pose {
            q: state.q,
            tool: state.tool,
            tool_offset: state.tool_offset,
        };
        Ok(exact::nominal_transform(self.m, &commanded)?)
    }

    /// The actual location at `state.q + dq` (errors evaluated there, same tool, inputs and
    /// directions) against `target`; leaves `self.q` at the moved pose.
    fn error_at(
        &mut self,
        state: &State,
        dq: &[f64],
        target: &Matrix4<f64>,
    ) -> Result<Vector6<f64>, CompensateError> {
        if dq.len() != self.q.len() {
            return Err(KinematicsError::JointCount {
                expected: self.q.len(),
                got: dq.len(),
            }
            .into());
        }
        for ((slot, q), d) in self.q.iter_mut().zip(state.q).zip(dq) {
            *slot = q + d;
        }
        let moved = State {
            q: &self.q,
            ..*state
        };
        self.it.frame_errors(&moved, self.beta, &mut self.errors)?;
        let pose = Pose {
            q: &self.q,
            tool: state.tool,
            tool_offset: state.tool_offset,
        };
        let actual = exact::actual_transform(self.m, &pose, &self.errors)?;
        Ok(exact::location_error(target, &actual))
    }
}

/// A commanded position outside an axis's declared range (continuous axes excepted). The
/// comparison allows for the rounding of a unit conversion at the ends of the range.
pub fn check_range(m: &Machine, q: &[f64]) -> Result<(), CompensateError> {
    for (axis, &v) in m.axes.iter().zip(q) {
        if axis.continuous {
            continue;
        }
        let [lo, hi] = axis.range;
        if !crate::data::ranges::within(axis.range, v) {
            let unit = match axis.kind {
                JointKind::Prismatic => &m.units.length,
                JointKind::Revolute => &m.units.angle,
            };
            return Err(CompensateError::OutOfRange {
                axis: axis.name.clone(),
                value: unit.from_si(v),
                lo: unit.from_si(lo),
                hi: unit.from_si(hi),
                unit: unit.name.clone(),
            });
        }
    }
    Ok(())
}

/// The least-squares step `min ‖W (J δ + r)‖` by the singular value decomposition of the
/// weighted Jacobian with unit-norm columns (so a prismatic and a revolute axis are compared on
/// equal terms); singular values below `tolerance · σ_max` are directions the joints cannot
/// move, and the minimum-norm solution leaves them alone. Returns the step and the rank.
fn solve(
    jacobian: &[Vector6<f64>],
    w: &Vector6<f64>,
    r: &Vector6<f64>,
    tolerance: f64,
) -> Result<(DVector<f64>, usize), CompensateError> {
    let n = jacobian.len();
    let mut a = DMatrix::<f64>::zeros(6, n);
    let mut scale = vec![0.0; n];
    for (j, column) in jacobian.iter().enumerate() {
        let weighted = column.component_mul(w);
        let norm = weighted.norm();
        if norm > 0.0 {
            scale[j] = norm;
            a.set_column(j, &(weighted / norm));
        }
    }
    let b = DVector::from_iterator(6, r.component_mul(w).iter().map(|x| -x));
    let svd = a.svd(true, true);
    let largest = svd.singular_values.iter().copied().fold(0.0_f64, f64::max);
    if largest == 0.0 {
        return Ok((DVector::zeros(n), 0));
    }
    let eps = tolerance * largest;
    let rank = svd.singular_values.iter().filter(|s| **s > eps).count();
    let x = svd.solve(&b, eps).map_err(|_| CompensateError::Solve)?;
    let step = DVector::from_iterator(
        n,
        x.iter()
            .zip(&scale)
            .map(|(x, s)| if *s > 0.0 { x / s } else { 0.0 }),
    );
    Ok((step, rank))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kin_compiler::compile;

    const MILL3: &str = r#"
machine mill3 {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    tool chain { Z moving at (0, 0, 400) mm  tool t at (0, 0, -100) mm }
    workpiece chain { Y fixed  X fixed  workpiece }
    errors {
        X.tx = linear(X)
        X.rz = const
        Y.rx = const
        Z.ty = linear(Z)
    }
}
"#;

    #[test]
    fn a_three_axis_machine_corrects_position_and_reports_the_tilt() {
        let c = compile(MILL3).compiled.expect("compiles");
        let m = &c.machine;
        // 50 µm/m scale, 20 µrad yaw, 30 µrad pitch, 10 µm/m Z straightness.
        let beta = vec![50e-6, 20e-6, 30e-6, 10e-6];
        assert_eq!(beta.len(), m.coefficients.len());
        let mut comp = Compensator::new(m, &beta, Options::pose(m)).expect("compensator");
        let q = [0.3, 0.2, -0.1];
        let state = State {
            q: &q,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &[1.0; 3],
            tool: 0,
            tool_offset: None,
        };
        let c = comp.compensate(&state).expect("compensates");
        assert_eq!(c.rank, 3);
        assert!(c.before[..3].iter().any(|e| e.abs() > 1e-6), "{c:?}");
        for e in &c.after[..3] {
            assert!(e.abs() < 1e-12, "{c:?}");
        }
        // The angular errors stay: nothing a 3-axis machine does turns the tool.
        for k in 3..6 {
            assert!((c.after[k] - c.before[k]).abs() < 1e-9, "{c:?}");
        }
        assert!(c.after[3..].iter().any(|e| e.abs() > 1e-6));
    }

    #[test]
    fn a_command_outside_the_range_is_refused() {
        let c = compile(MILL3).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![0.0; m.coefficients.len()];
        let mut comp = Compensator::new(m, &beta, Options::pose(m)).expect("compensator");
        let q = [0.6, 0.2, -0.1];
        let state = State {
            q: &q,
            inputs: &[],
            lags: &[],
            time: 0.0,
            dirs: &[1.0; 3],
            tool: 0,
            tool_offset: None,
        };
        let e = comp.compensate(&state).expect_err("out of range");
        assert_eq!(
            e.to_string(),
            "axis X is commanded to 600 mm, outside its declared range 0 .. 500 mm"
        );
    }
}
