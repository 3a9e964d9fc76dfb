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
use nalgebra::{Matrix4, Matrix6, Rotation3, SMatrix, Vector3, Vector6, SVD};
use thiserror::Error;

use crate::exact;
use crate::interp::{EvalError, Interpreter, State};
use crate::jit::JitModel;
use crate::kinematics::{FrameErrors, KinematicsError, Pose, ToolLocation};

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
    #[error(
        "the weights of the components must each be 0 or from 1e-9 to 1e9 (SI), one of them \
         positive, and the rank tolerance from 0 to below 1"
    )]
    Weights,
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    #[error("the correction does not converge (the singular value decomposition failed)")]
    Solve,
    #[error(transparent)]
    Diverges(#[from] Divergence),
    #[error(
        "the machine has {0} axes; the servo compensation holds its scratch on the stack and takes at most {MAX_SERVO_AXES}"
    )]
    TooManyAxes(usize),
}

/// The singular value decomposition of the step did not converge (non-finite values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Unsolvable;

/// The Gauss–Newton iteration of §2.3.5 leaves the region where it converges: the predicted
/// error is too large (or the model too strongly non-linear in the axes) for a correction
/// linearised on the joint Jacobian. Near a solution each step moves the tool by a small
/// fraction of the one before (the fraction is the relative change of the errors over the
/// step); a step that moves it no less than the previous one, or a pose where the model's
/// error overflows, means the iteration is not approaching one, and carrying on only takes
/// the axes further away (a random model with metre-sized errors reached 10^135 m in four
/// steps).
#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum Divergence {
    #[error(
        "the correction diverges: step {step} moves the tool by {moved:.3e} (weighted, SI), no less than step {previous_step} did ({previous:.3e}); the model's errors are too large for a correction linearised on the joint Jacobian"
    )]
    Grows {
        /// The step (from 1) that did not shrink, and the one before it.
        step: usize,
        previous_step: usize,
        /// `‖W J δ‖` of the two steps.
        moved: f64,
        previous: f64,
    },
    #[error(
        "the correction diverges: after step {step} the model's error is not finite (the axes moved to where it overflows); the model's errors are too large for a correction linearised on the joint Jacobian"
    )]
    Overflows { step: usize },
}

impl From<Unsolvable> for CompensateError {
    fn from(_: Unsolvable) -> Self {
        CompensateError::Solve
    }
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
    /// A step whose effect on the weighted error (`‖W J δ‖`, SI) is below this ends the
    /// iteration: `PICOMETRE` by default. 0 runs all `iterations` solves at every call, the
    /// slowest path, which `kin bench` times apart.
    pub converged: f64,
    /// The axes the correction may move; the others stay at their commanded positions.
    pub movable: Movable,
}

/// A set of axes, by index into `Machine::axes` (the first 64; a servo compensator has at most
/// [`MAX_SERVO_AXES`]): the axes a correction may move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Movable(u64);

impl Movable {
    /// Every axis.
    pub const ALL: Movable = Movable(u64::MAX);

    /// Only the axes listed (indices beyond 63 are ignored).
    pub fn only(axes: impl IntoIterator<Item = usize>) -> Movable {
        Movable(
            axes.into_iter()
                .filter(|j| *j < 64)
                .fold(0, |bits, j| bits | (1 << j)),
        )
    }

    /// The default of a position-only correction: the prismatic axes, or every axis of a
    /// machine that has none (an arm). A rotary axis of a machine tool moved to correct the
    /// position turns the tool or the workpiece, and changes the orientation error it was not
    /// asked about.
    pub fn prismatic_or_all(m: &Machine) -> Movable {
        let prismatic = m
            .axes
            .iter()
            .enumerate()
            .filter(|(_, a)| a.kind == JointKind::Prismatic)
            .map(|(j, _)| j);
        match Movable::only(prismatic) {
            Movable(0) => Movable::ALL,
            some => some,
        }
    }

    /// Whether axis `j` may move.
    pub fn contains(self, j: usize) -> bool {
        j < 64 && self.0 & (1 << j) != 0
    }
}

/// A column whose weighted norm is below this fraction of the largest column's moves nothing
/// that is corrected: it is left out of the solve (a revolute axis through the tool point when
/// only the position is corrected; a real lever of a nanometre per radian against a metre is
/// still 10⁻⁹).
const LEVERAGE: f64 = 1e-10;

/// The default [`Options::converged`]: a step that changes the weighted error by less than a
/// picometre no longer matters. Below it, steps are rounding noise and never a [`Divergence`].
pub(crate) const PICOMETRE: f64 = 1e-12;

/// The smallest and largest non-zero weight of a component (SI): beyond them the squares of the
/// weighted Jacobian under- or overflow, and a solve of rank 0 would return no correction as a
/// success. Only the weights' ratios shape the correction; their size sets what
/// [`Options::converged`] measures.
const WEIGHT_BOUNDS: [f64; 2] = [1e-9, 1e9];

impl Options {
    /// Refuses weights that are not 0 or from 10⁻⁹ to 10⁹ (SI), all zero, and a rank
    /// tolerance outside `[0, 1)`.
    pub fn check(&self) -> Result<(), CompensateError> {
        let [lo, hi] = WEIGHT_BOUNDS;
        let w = self.weights;
        if w.iter().any(|x| !(*x == 0.0 || (lo..=hi).contains(x)))
            || w.iter().all(|x| *x == 0.0)
            || !(self.rank_tolerance >= 0.0 && self.rank_tolerance < 1.0)
        {
            return Err(CompensateError::Weights);
        }
        Ok(())
    }

    /// Every component, a rotation weighed as in the fit (one tilt unit as one error unit):
    /// the machine then corrects all it can, and nothing else changes the solution (a 3-axis
    /// machine's corrections are those of position alone).
    pub fn pose(m: &Machine) -> Options {
        let l = crate::kinematics::rotation_weight(m);
        Options {
            weights: [1.0, 1.0, 1.0, l, l, l],
            iterations: 4,
            rank_tolerance: 1e-9,
            converged: PICOMETRE,
            movable: Movable::ALL,
        }
    }

    /// The tool position only, by the prismatic axes ([`Movable::prismatic_or_all`]): the
    /// orientation errors are not corrected (and the rotary axes, held, do not change them).
    pub fn position(m: &Machine) -> Options {
        Options {
            weights: [1.0, 1.0, 1.0, 0.0, 0.0, 0.0],
            movable: Movable::prismatic_or_all(m),
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
    /// The axes that were free to move but left out of the last step for lack of leverage on
    /// the corrected components (a roll through the tool point under a position-only
    /// correction), indexed like `Machine::axes`: they are not moved, and a caller says so.
    pub idle: Vec<usize>,
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
        options.check()?;
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
    /// `Machine::axes`; all of them when `None`) among the options' [`Movable`] ones: what a
    /// per-axis controller table can do.
    pub fn compensate_with(
        &mut self,
        state: &State,
        free: Option<&[bool]>,
    ) -> Result<Correction, CompensateError> {
        check_range(self.m, state.q)?;
        let n = self.m.axes.len();
        let target = self.target(state)?;
        let mut dq = vec![0.0; n];
        let mut step = vec![0.0; n];
        let mut jacobian = std::mem::take(&mut self.jacobian);
        let options = self.options;
        let mut plant = ExactPlant {
            c: self,
            state,
            target,
        };
        let outcome = iterate(
            &mut plant,
            &options,
            free,
            state.q,
            &mut dq,
            &mut jacobian,
            &mut step,
        );
        self.jacobian = jacobian;
        let outcome = outcome?;
        Ok(Correction {
            dq,
            before: outcome.before.into(),
            after: outcome.after.into(),
            rank: outcome.rank,
            idle: (0..n).filter(|&j| outcome.idle(j)).collect(),
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

/// The first axis whose commanded position `q` lies outside its declared range (continuous axes
/// excepted); allocates nothing, for the servo path. The comparison allows for the rounding of
/// a unit conversion at the ends of the range.
fn out_of_range(m: &Machine, q: &[f64]) -> Option<usize> {
    m.axes
        .iter()
        .zip(q)
        .position(|(axis, &v)| !axis.continuous && !kin_data::data::ranges::within(axis.range, v))
}

/// A commanded position outside an axis's declared range (continuous axes excepted), named in
/// the machine's units.
pub fn check_range(m: &Machine, q: &[f64]) -> Result<(), CompensateError> {
    let Some(k) = out_of_range(m, q) else {
        return Ok(());
    };
    let (Some(axis), Some(&v)) = (m.axes.get(k), q.get(k)) else {
        return Ok(());
    };
    let [lo, hi] = axis.range;
    let unit = match axis.kind {
        JointKind::Prismatic => &m.units.length,
        JointKind::Revolute => &m.units.angle,
    };
    Err(CompensateError::OutOfRange {
        axis: axis.name.clone(),
        value: unit.from_si(v),
        lo: unit.from_si(lo),
        hi: unit.from_si(hi),
        unit: unit.name.clone(),
    })
}

/// What the Gauss–Newton iteration of §2.3.5 asks of a model of the machine: the error of the
/// commanded location when the axes are moved by `dq`, and the joint Jacobian there. The
/// batch compensation answers with the exact transforms ([`Compensator`]), the servo
/// compensation with the first-order model of an engine ([`servo`]).
pub(crate) trait Plant {
    type Error: From<Unsolvable> + From<Divergence>;
    /// The error (actual − commanded location, SI, wr axes) when the axes are moved by `dq`.
    /// The first call of an iteration is at `dq = 0`.
    fn residual(&mut self, dq: &[f64]) -> Result<Vector6<f64>, Self::Error>;
    /// The joint Jacobian at the pose of the last [`Plant::residual`].
    fn jacobian(&mut self, out: &mut [Vector6<f64>]) -> Result<(), Self::Error>;
}

/// What an iteration found.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Outcome {
    pub before: Vector6<f64>,
    pub after: Vector6<f64>,
    pub rank: usize,
    /// Linear solves done (at most `Options::iterations`).
    pub iterations: usize,
    /// Bit `j` set: axis `j` was free but had no leverage in the last step (axes beyond 64
    /// are not recorded; a bit mask keeps the servo path free of allocation).
    pub idle: u64,
}

impl Outcome {
    /// Whether axis `j` was free but left out of the last step for lack of leverage.
    pub fn idle(&self, j: usize) -> bool {
        j < 64 && self.idle & (1 << j) != 0
    }
}

/// The compensation of §2.3.5: `δq` minimising `‖W (J δq + e)‖` on the joint Jacobian (the
/// first step, the thesis' linear solve), then Gauss–Newton steps on the plant's own error at
/// the moved pose, at most `options.iterations` solves. `free` marks the axes that may move
/// (all when `None`). `dq` receives the correction; `jacobian` and `step` are scratch of the
/// machine's axis count. Allocates nothing.
///
/// A step whose effect on the weighted error is below `options.converged` (a picometre) ends
/// the iteration (the error changes by less than that over the step); a step of at least a
/// picometre that does not shrink against the one before, or a non-finite error at the moved
/// pose, is a [`Divergence`].
pub(crate) fn iterate<P: Plant>(
    plant: &mut P,
    options: &Options,
    free: Option<&[bool]>,
    q: &[f64],
    dq: &mut [f64],
    jacobian: &mut [Vector6<f64>],
    step: &mut [f64],
) -> Result<Outcome, P::Error> {
    let w = Vector6::from(options.weights);
    dq.fill(0.0);
    let mut residual = plant.residual(dq)?;
    let before = residual;
    let mut rank = 0;
    let mut iterations = 0;
    let mut previous = f64::INFINITY;
    let mut idle = 0u64;
    let is_free = |j: usize| {
        options.movable.contains(j) && free.is_none_or(|f| f.get(j).copied().unwrap_or(false))
    };
    for k in 0..options.iterations {
        plant.jacobian(jacobian)?;
        for (j, column) in jacobian.iter_mut().enumerate() {
            if !is_free(j) {
                *column = Vector6::zeros();
            }
        }
        rank = solve(jacobian, &w, &residual, options.rank_tolerance, step)?;
        iterations += 1;
        idle = idle_columns(jacobian, &w, is_free);
        for (d, x) in dq.iter_mut().zip(step.iter()) {
            *d += x;
        }
        if dq.iter().any(|d| !d.is_finite()) {
            return Err(Divergence::Overflows { step: k + 1 }.into());
        }
        // The step's effect on the weighted error: below `converged` it no longer matters.
        let effect: f64 = jacobian
            .iter()
            .zip(step.iter())
            .map(|(j, x)| j.component_mul(&w) * *x)
            .sum::<Vector6<f64>>()
            .norm();
        residual = plant.residual(dq)?;
        if residual.iter().any(|x| !x.is_finite()) {
            return Err(Divergence::Overflows { step: k + 1 }.into());
        }
        // Below the rounding of the kinematics at this pose a step is noise: it ends the
        // iteration and is never a divergence.
        let noise = rounding(jacobian, &w, q, dq);
        if effect < options.converged.max(noise) && options.converged > 0.0 && k > 0 {
            break;
        }
        if effect >= previous && effect >= PICOMETRE.max(noise) {
            return Err(Divergence::Grows {
                step: k + 1,
                previous_step: k,
                moved: effect,
                previous,
            }
            .into());
        }
        previous = effect;
    }
    Ok(Outcome {
        before,
        after: residual,
        rank,
        iterations,
        idle,
    })
}

/// Rounding of the evaluated error at the pose `q + dq`, weighted: an axis at `x` (m or rad)
/// is known to `ε·|x|`, which moves the tool by that times its weighted column. A continuous
/// axis far from 0 (a million degrees, 17 000 rad) carries tenths of a nanometre of it, more
/// than the default [`PICOMETRE`]; the factor covers the few roundings of each transform.
fn rounding(jacobian: &[Vector6<f64>], w: &Vector6<f64>, q: &[f64], dq: &[f64]) -> f64 {
    const ROUNDINGS: f64 = 16.0;
    ROUNDINGS
        * f64::EPSILON
        * jacobian
            .iter()
            .zip(q.iter().zip(dq))
            .map(|(c, (x, d))| (x + d).abs() * c.component_mul(w).norm())
            .sum::<f64>()
}

/// The leverage below which a weighted column is left out of the solve: [`LEVERAGE`] of the
/// largest.
fn leverage_floor(jacobian: &[Vector6<f64>], w: &Vector6<f64>) -> f64 {
    LEVERAGE
        * jacobian
            .iter()
            .map(|c| c.component_mul(w).norm())
            .fold(0.0_f64, f64::max)
}

/// The free axes whose weighted column is at or below the leverage floor (bit `j` for axis
/// `j < 64`): [`solve`] gives them no step.
fn idle_columns(
    jacobian: &[Vector6<f64>],
    w: &Vector6<f64>,
    is_free: impl Fn(usize) -> bool,
) -> u64 {
    let floor = leverage_floor(jacobian, w);
    let mut idle = 0u64;
    for (j, c) in jacobian.iter().enumerate().take(64) {
        if is_free(j) && c.component_mul(w).norm() <= floor {
            idle |= 1 << j;
        }
    }
    idle
}

/// The least-squares step `min ‖W (J δ + r)‖` into `step`, returning the rank: the singular
/// value decomposition of the weighted Jacobian `A` with unit-norm columns (so a prismatic and
/// a revolute axis are compared on equal terms); singular values below `tolerance · σ_max` are
/// directions the joints cannot move, and the minimum-norm solution leaves them alone.
///
/// `A` is 6 × n. Up to six axes it is decomposed as it is (zero columns padding it to 6 × 6);
/// beyond, only its row space matters for the minimum-norm solution `Aᵀ (A Aᵀ)⁺ b`, and a
/// 6 × 6 `G` with `G Gᵀ = A Aᵀ` is accumulated six columns at a time by QR factorisations.
/// Everything is fixed-size: no allocation, so the servo path can call it every cycle.
pub(crate) fn solve(
    jacobian: &[Vector6<f64>],
    w: &Vector6<f64>,
    r: &Vector6<f64>,
    tolerance: f64,
    step: &mut [f64],
) -> Result<usize, Unsolvable> {
    let n = jacobian.len();
    if jacobian.iter().any(|c| c.iter().any(|x| !x.is_finite())) {
        return Err(Unsolvable);
    }
    // Column j of A is (w ∘ J_j) / s_j, s_j = ‖w ∘ J_j‖; a column the weights do not see is 0,
    // and so is one with no leverage on what is corrected: the flange's roll when only the
    // position is corrected and the tool point lies on its axis has a column of rounding
    // noise (10⁻¹⁶ of the others), which scaled to unit length would look like a full
    // direction and be given a correction of 10¹⁸ (and a step of no weighted effect, so the
    // iteration would call it converged).
    let floor = leverage_floor(jacobian, w);
    let seen = |wc: &Vector6<f64>| {
        let s = wc.norm();
        (s > floor && s > 0.0).then_some(s)
    };
    let scaled = |c: &Vector6<f64>| {
        let wc = c.component_mul(w);
        match seen(&wc) {
            Some(s) => wc / s,
            None => Vector6::zeros(),
        }
    };
    let mut g = Matrix6::<f64>::zeros();
    if n <= 6 {
        for (j, c) in jacobian.iter().enumerate() {
            g.set_column(j, &scaled(c));
        }
    } else {
        for chunk in jacobian.chunks(6) {
            // [G | chunk] = L Q: L Lᵀ = G Gᵀ + chunk chunkᵀ, L = Rᵀ of the QR of the transpose.
            let mut t = SMatrix::<f64, 12, 6>::zeros();
            t.fixed_view_mut::<6, 6>(0, 0).copy_from(&g.transpose());
            for (k, c) in chunk.iter().enumerate() {
                t.set_row(6 + k, &scaled(c).transpose());
            }
            g = t.qr().r().transpose();
        }
    }
    let b = -r.component_mul(w);
    let svd = SVD::try_new(g, true, true, f64::EPSILON, 1000).ok_or(Unsolvable)?;
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Unsolvable);
    };
    let sigma = svd.singular_values;
    if sigma.iter().any(|s| !s.is_finite()) || b.iter().any(|x| !x.is_finite()) {
        return Err(Unsolvable);
    }
    let largest = sigma.iter().copied().fold(0.0_f64, f64::max);
    step.fill(0.0);
    if largest == 0.0 {
        return Ok(0);
    }
    let eps = tolerance * largest;
    let mut rank = 0;
    // x = A⁺ b in the scaled columns: Σ v_i (u_iᵀ b) / σ_i (n ≤ 6), or
    // y = Σ u_i (u_iᵀ b) / σ_i² and x = Aᵀ y (n > 6).
    let mut x6 = Vector6::<f64>::zeros();
    let mut y = Vector6::<f64>::zeros();
    for (i, &s) in sigma.iter().enumerate() {
        if s > eps {
            rank += 1;
            let c = u.column(i).dot(&b);
            x6 += v_t.row(i).transpose() * (c / s);
            y += u.column(i) * (c / (s * s));
        }
    }
    for (j, (x, c)) in step.iter_mut().zip(jacobian).enumerate() {
        let wc = c.component_mul(w);
        let s2 = wc.norm_squared();
        if seen(&wc).is_some() {
            // Back from the unit-norm column to the axis: δ_j = x_j / s_j.
            *x = if n <= 6 {
                x6[j] / s2.sqrt()
            } else {
                wc.dot(&y) / s2
            };
        }
    }
    Ok(rank)
}

/// The batch compensation's plant: the exact transforms of the interpreter's frame errors.
struct ExactPlant<'c, 'm, 's> {
    c: &'c mut Compensator<'m>,
    state: &'s State<'s>,
    target: Matrix4<f64>,
}

impl Plant for ExactPlant<'_, '_, '_> {
    type Error = CompensateError;

    fn residual(&mut self, dq: &[f64]) -> Result<Vector6<f64>, CompensateError> {
        self.c.error_at(self.state, dq, &self.target)
    }

    fn jacobian(&mut self, out: &mut [Vector6<f64>]) -> Result<(), CompensateError> {
        // `self.c.q` holds the pose of the last residual.
        let moved = State {
            q: &self.c.q,
            ..*self.state
        };
        self.c.it.nominal_jacobian(&moved, out)?;
        Ok(())
    }
}

/// Most axes the servo compensation takes: its scratch is on the stack.
pub const MAX_SERVO_AXES: usize = 16;

/// Why one servo compensation call failed. Nothing here allocates, so a failing call does not
/// either (except an [`EvalError`] naming a missing input).
#[derive(Debug, Error, PartialEq)]
pub enum ServoError {
    #[error("{what} holds {got} values, the machine has {expected}")]
    Size {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what}[{index}] is {value}: {allowed}")]
    Value {
        what: &'static str,
        index: usize,
        value: f64,
        allowed: &'static str,
    },
    /// Axis `axis` (index into the machine's axes) is commanded to `value` (SI), outside its
    /// declared range `lo .. hi` (SI).
    #[error("axis {axis} is commanded to {value} (SI), outside its declared range {lo} .. {hi}")]
    OutOfRange {
        axis: usize,
        value: f64,
        lo: f64,
        hi: f64,
    },
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error("the correction does not converge (the singular value decomposition failed)")]
    Solve,
    #[error("the correction came out as {0}: the model's errors are too large for it")]
    NotFinite(f64),
    #[error(transparent)]
    Diverges(#[from] Divergence),
}

impl From<Unsolvable> for ServoError {
    fn from(_: Unsolvable) -> Self {
        ServoError::Solve
    }
}

/// One servo compensation: the correction is in the caller's buffer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Compensated {
    /// The predicted error at the commanded pose (first-order model, SI).
    pub before: [f64; 6],
    /// The predicted error of the compensated pose against the commanded location (first-order
    /// errors at the moved pose, exact nominal kinematics): what the joints cannot correct.
    pub after: [f64; 6],
    /// How many independent combinations of the weighted components the joints can move.
    pub rank: usize,
    /// Linear solves done, at most `Options::iterations`.
    pub iterations: usize,
}

/// What the servo compensation needs of an engine: the first-order error (eq. 2.24) with the
/// bound coefficients, and the nominal location with its joint Jacobian.
pub trait FirstOrderEngine {
    fn error(&mut self, state: &State) -> Result<[f64; 6], EvalError>;
    fn nominal_jacobian(
        &mut self,
        state: &State,
        out: &mut [Vector6<f64>],
    ) -> Result<ToolLocation, EvalError>;
}

/// The interpreter with coefficients `beta`: the reference the JIT's compensation is checked
/// against.
pub(crate) struct InterpEngine<'a, 'm> {
    pub interpreter: &'a mut Interpreter<'m>,
    pub beta: &'a [f64],
}

impl FirstOrderEngine for InterpEngine<'_, '_> {
    fn error(&mut self, state: &State) -> Result<[f64; 6], EvalError> {
        self.interpreter.error(state, self.beta)
    }
    fn nominal_jacobian(
        &mut self,
        state: &State,
        out: &mut [Vector6<f64>],
    ) -> Result<ToolLocation, EvalError> {
        self.interpreter.nominal_jacobian(state, out)
    }
}

/// The JIT's native code with coefficients and non-linear values; `flat` is the 6 × axes
/// buffer its joint Jacobian is written to.
pub(crate) struct JitEngine<'a> {
    pub jit: &'a JitModel,
    pub beta: &'a [f64],
    pub nonlinear: &'a [f64],
    pub flat: &'a mut [f64],
}

impl FirstOrderEngine for JitEngine<'_> {
    fn error(&mut self, state: &State) -> Result<[f64; 6], EvalError> {
        self.jit.error(state, self.beta, self.nonlinear)
    }
    fn nominal_jacobian(
        &mut self,
        state: &State,
        out: &mut [Vector6<f64>],
    ) -> Result<ToolLocation, EvalError> {
        let loc = self.jit.nominal_jacobian(state, self.flat)?;
        for (column, values) in out.iter_mut().zip(self.flat.chunks_exact(6)) {
            *column = Vector6::from_column_slice(values);
        }
        Ok(loc)
    }
}

/// The servo compensation's plant: the engine's first-order error applied to the exact
/// nominal location at the moved pose.
struct FirstOrderPlant<'e, 's, E> {
    engine: &'e mut E,
    state: &'s State<'s>,
    /// The moved joint positions and the Jacobian there (the first `n` entries are used).
    q: [f64; MAX_SERVO_AXES],
    cache: [Vector6<f64>; MAX_SERVO_AXES],
    n: usize,
    /// The nominal location commanded: that of the first residual, at `dq = 0`.
    target: Option<Matrix4<f64>>,
}

impl<E: FirstOrderEngine> Plant for FirstOrderPlant<'_, '_, E> {
    type Error = ServoError;

    fn residual(&mut self, dq: &[f64]) -> Result<Vector6<f64>, ServoError> {
        let n = self.n;
        for ((slot, q), d) in self.q[..n].iter_mut().zip(self.state.q).zip(dq) {
            *slot = q + d;
        }
        let moved = State {
            q: &self.q[..n],
            ..*self.state
        };
        let nominal = self.engine.nominal_jacobian(&moved, &mut self.cache[..n])?;
        let e = self.engine.error(&moved)?;
        let target = *self.target.get_or_insert_with(|| nominal.to_matrix());
        // The first-order error as the small rigid displacement it stands for (spec/kinematics.md:
        // position error in wr, R_act = exp([r]×) R_nom), so the rest is measured exactly as the
        // batch compensation measures it.
        let rotation = Rotation3::new(Vector3::new(e[3], e[4], e[5])).into_inner();
        let actual = ToolLocation {
            position: nominal.position + Vector3::new(e[0], e[1], e[2]),
            rotation: rotation * nominal.rotation,
        };
        Ok(exact::location_error(&target, &actual.to_matrix()))
    }

    fn jacobian(&mut self, out: &mut [Vector6<f64>]) -> Result<(), ServoError> {
        out.copy_from_slice(&self.cache[..self.n]);
        Ok(())
    }
}

/// The compensation a controller calls every servo cycle: the correction of the commanded pose
/// `state` into `dq` (axis order, SI), by the §2.3.5 iteration of `iterate` on the engine's
/// first-order model (its error applied to the exact nominal kinematics), at most
/// `options.iterations` solves. Its scratch is on the stack: no allocation, no lock, as many
/// threads at once as have their own engine.
///
/// The exact-transform refinement of [`Compensator`] is not done here: it needs every frame's
/// error and a chain of 4 × 4 products per step, and differs from this by the second-order
/// terms of the errors (products of two errors: nanometres for errors of tens of µm and µrad
/// over a metre; spec/compensation.md gives the measured difference).
pub fn servo<E: FirstOrderEngine>(
    engine: &mut E,
    m: &Machine,
    options: &Options,
    state: &State,
    dq: &mut [f64],
) -> Result<Compensated, ServoError> {
    let n = m.axes.len();
    if n > MAX_SERVO_AXES {
        return Err(ServoError::Size {
            what: "the machine's axes",
            expected: MAX_SERVO_AXES,
            got: n,
        });
    }
    for (what, got) in [("the state's q", state.q.len()), ("dq", dq.len())] {
        if got != n {
            return Err(ServoError::Size {
                what,
                expected: n,
                got,
            });
        }
    }
    if let Some((index, &value)) = state.q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(ServoError::Value {
            what: "q",
            index,
            value,
            allowed: "joint positions must be finite",
        });
    }
    if let Some(offset) = state.tool_offset {
        if let Some((index, &value)) = offset.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ServoError::Value {
                what: "tool_offset",
                index,
                value,
                allowed: "a tool offset must be finite",
            });
        }
    }
    if let Some(axis) = out_of_range(m, state.q) {
        let value = state.q.get(axis).copied().unwrap_or(f64::NAN);
        let [lo, hi] = m.axes.get(axis).map_or([f64::NAN; 2], |a| a.range);
        return Err(ServoError::OutOfRange {
            axis,
            value,
            lo,
            hi,
        });
    }
    let mut plant = FirstOrderPlant {
        engine,
        state,
        q: [0.0; MAX_SERVO_AXES],
        cache: [Vector6::zeros(); MAX_SERVO_AXES],
        n,
        target: None,
    };
    let mut jacobian = [Vector6::zeros(); MAX_SERVO_AXES];
    let mut step = [0.0; MAX_SERVO_AXES];
    let outcome = iterate(
        &mut plant,
        options,
        None,
        state.q,
        dq,
        &mut jacobian[..n],
        &mut step[..n],
    )?;
    if let Some(bad) = dq
        .iter()
        .chain(outcome.after.iter())
        .find(|v| !v.is_finite())
    {
        return Err(ServoError::NotFinite(*bad));
    }
    Ok(Compensated {
        before: outcome.before.into(),
        after: outcome.after.into(),
        rank: outcome.rank,
        iterations: outcome.iterations,
    })
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

    /// A 6-axis arm whose tool point lies on the flange's roll axis, corrected in position
    /// only: J6 has no leverage on what is corrected. Over 1 000 random poses every correction
    /// either converges to micro-sized joint moves with the position error cancelled, or is an
    /// error — never a success with a correction of 10¹⁸ (which the unit-scaled column of
    /// rounding noise gave).
    #[test]
    fn a_joint_through_the_tool_point_gets_no_correction_of_noise() {
        let src = include_str!("../../../examples/robot_6axis.kin");
        let c = compile(src).compiled.expect("compiles");
        let m = &c.machine;
        let beta: Vec<f64> = (0..m.coefficients.len())
            .map(|j| 3e-6 * (((j * 7919) % 13) as f64 / 6.0 - 1.0))
            .collect();
        let mut comp = Compensator::new(m, &beta, Options::position(m)).expect("compensator");
        let states = crate::states::States::sample(m, 1000, 17);
        let (mut solved, mut refused) = (0, 0);
        for r in 0..states.len() {
            match comp.compensate(&states.get(r)) {
                Ok(c) => {
                    solved += 1;
                    // Micrometre errors need joint moves of micro-radians; near the wrist's
                    // singularity (J4 and J6 aligned) some milliradians — never more than 0.1.
                    let largest = c.dq.iter().fold(0.0f64, |a, d| a.max(d.abs()));
                    assert!(largest < 0.1, "pose {r}: {:?}", c.dq);
                    assert_eq!(
                        c.dq.last().copied(),
                        Some(0.0),
                        "J6 moves nothing corrected"
                    );
                    assert!(c.idle.contains(&5), "pose {r}: J6 not named: {c:?}");
                    for e in &c.after[..3] {
                        assert!(e.abs() < 1e-9, "pose {r}: {c:?}");
                    }
                }
                Err(CompensateError::Diverges(_) | CompensateError::Solve) => refused += 1,
                Err(e) => panic!("pose {r}: {e}"),
            }
        }
        assert!(solved >= 990, "{solved} solved, {refused} refused");
    }

    /// A mill whose spindle head carries A and then C, the tool point on C's axis: under a
    /// position-only correction C has no leverage. Over 1 000 random poses every correction
    /// converges (position cancelled, C named idle and not moved, no correction beyond an
    /// axis range) or is an error.
    #[test]
    fn a_mill_with_the_tool_on_c_names_c_and_never_blows_up() {
        let src = r#"
machine millc {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis A revolute about x range -90 deg .. 90 deg
    axis C revolute about z continuous
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 450) mm
        A moving at (0, 0, -100) mm
        C moving at (0, 0, -50) mm
        tool long at (0, 0, -150) mm
    }
    workpiece chain {
        workpiece
    }
    errors {
        X.tx = linear(X)
        Y.ty = const
        A.ty = const
        A.rz = const
        C.tx = const
        C.rz = const
    }
}
"#;
        let c = compile(src).compiled.expect("compiles");
        let m = &c.machine;
        let beta: Vec<f64> = (0..m.coefficients.len())
            .map(|j| 5e-6 * (((j * 7919) % 13) as f64 / 6.0 - 1.0))
            .collect();
        // By default a position-only correction holds the rotary axes: nothing to name.
        let mut held = Compensator::new(m, &beta, Options::position(m)).expect("compensator");
        let state = crate::states::States::sample(m, 1, 5);
        let c = held.compensate(&state.get(0)).expect("compensates");
        assert_eq!((c.dq[3], c.dq[4]), (0.0, 0.0), "{c:?}");
        assert!(
            c.idle.is_empty() && c.after[..3].iter().all(|e| e.abs() < 1e-9),
            "{c:?}"
        );
        // Every axis free: C has no leverage on the position and is named.
        let options = Options {
            movable: Movable::ALL,
            ..Options::position(m)
        };
        let mut comp = Compensator::new(m, &beta, options).expect("compensator");
        let states = crate::states::States::sample(m, 1000, 23);
        let (mut solved, mut refused) = (0, 0);
        for r in 0..states.len() {
            match comp.compensate(&states.get(r)) {
                Ok(c) => {
                    solved += 1;
                    for (d, axis) in c.dq.iter().zip(&m.axes) {
                        let span = axis.range[1] - axis.range[0];
                        assert!(d.is_finite() && d.abs() < span.min(1e3), "pose {r}: {c:?}");
                    }
                    assert_eq!(c.dq[4], 0.0, "C moves nothing corrected");
                    assert!(c.idle.contains(&4), "pose {r}: C not named: {c:?}");
                    for e in &c.after[..3] {
                        assert!(e.abs() < 1e-9, "pose {r}: {c:?}");
                    }
                }
                Err(CompensateError::Diverges(_) | CompensateError::Solve) => refused += 1,
                Err(e) => panic!("pose {r}: {e}"),
            }
        }
        assert!(solved >= 990, "{solved} solved, {refused} refused");
    }

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
    fn errors_too_large_to_linearise_are_a_divergence() {
        let c = compile(MILL3).compiled.expect("compiles");
        let m = &c.machine;
        // A scale error of metres over X's 0.5 m: the error's slope along X exceeds 1, so each
        // Gauss–Newton step on the nominal Jacobian overshoots by more than it corrects.
        let beta = vec![1.0, 0.0, 0.0, 0.0];
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
        match comp.compensate(&state) {
            Err(CompensateError::Diverges(Divergence::Grows {
                step: 2,
                previous_step: 1,
                moved,
                previous,
            })) => assert!(moved >= previous, "{moved} {previous}"),
            other => panic!("{other:?}"),
        }
        // The same model with a realistic scale error (50 µm/m) converges.
        let beta = vec![50e-6, 0.0, 0.0, 0.0];
        let mut comp = Compensator::new(m, &beta, Options::pose(m)).expect("compensator");
        assert!(comp.compensate(&state).is_ok());
    }

    #[test]
    fn the_slowest_path_does_every_solve_and_finds_the_same_correction() {
        let c = compile(MILL3).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![50e-6, 20e-6, 30e-6, 10e-6];
        let mut it = Interpreter::new(m).expect("interpreter");
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
        let mut run = |options: Options| {
            let mut engine = InterpEngine {
                interpreter: &mut it,
                beta: &beta,
            };
            let mut dq = [0.0; 3];
            let c = servo(&mut engine, m, &options, &state, &mut dq).expect("compensates");
            (c, dq)
        };
        let (typical, a) = run(Options::pose(m));
        let (slowest, b) = run(Options {
            converged: 0.0,
            ..Options::pose(m)
        });
        assert!(typical.iterations < 4, "{typical:?}");
        assert_eq!(slowest.iterations, 4);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-15, "{a:?} {b:?}");
        }
    }

    /// A table-table mill whose C axis has turned a million degrees (a continuous axis far from
    /// 0): the kinematics at C carry a rounding of about `ε·|C|` radians, tenths of a nanometre
    /// at the tool. Errors of nanometres are corrected, not called a divergence on that noise.
    #[test]
    fn a_continuous_axis_far_from_zero_converges_on_its_rounding() {
        let src = r#"
machine tt {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis A revolute about x range -90 deg .. 90 deg
    axis C revolute about z continuous
    tool chain { Z moving at (0, 0, 450) mm  tool t at (0, 0, -100) mm }
    workpiece chain { Y fixed  X fixed  A fixed  C fixed at (0, 0, 100) mm  workpiece }
    errors {
        X.tx = linear(X)
        A.ty = const
        C.rz = const
        C.tx = const
    }
}
"#;
        let c = compile(src).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![2e-9, 3e-9, 4e-9, 1e-9];
        let mut comp = Compensator::new(m, &beta, Options::pose(m)).expect("compensator");
        let mut worst = 0.0f64;
        for (k, c_deg) in [1e6_f64, -1e6, 3.6e5 + 12.5, 1e6 + 77.0]
            .into_iter()
            .enumerate()
        {
            let q = [0.3, 0.2, -0.1, 0.4, c_deg.to_radians()];
            let state = State {
                q: &q,
                inputs: &[],
                lags: &[],
                time: 0.0,
                dirs: &[1.0; 5],
                tool: 0,
                tool_offset: None,
            };
            let c = comp
                .compensate(&state)
                .unwrap_or_else(|e| panic!("C = {c_deg} deg (pose {k}): {e}"));
            worst = c.after[..3].iter().fold(worst, |a, e| a.max(e.abs()));
        }
        // What is left is the rounding, far below a nanometre.
        assert!(worst < 1e-9, "{worst}");
    }

    /// Weights whose squares under- or overflow (1e-300, 1e300) left a solve of rank 0 that
    /// returned no correction and success; they are refused with the bound named.
    #[test]
    fn weights_beyond_their_bounds_are_refused() {
        let c = compile(MILL3).compiled.expect("compiles");
        let m = &c.machine;
        let beta = vec![50e-6, 20e-6, 30e-6, 10e-6];
        for w in [1e-300, 1e300] {
            let options = Options {
                weights: [w, w, w, 0.0, 0.0, 0.0],
                ..Options::pose(m)
            };
            match Compensator::new(m, &beta, options) {
                Err(e @ CompensateError::Weights) => assert!(e.to_string().contains("1e-9")),
                Err(e) => panic!("{e}"),
                Ok(_) => panic!("weights {w} accepted"),
            }
        }
        let options = Options {
            weights: [1e-9, 1e9, 1.0, 0.0, 0.0, 0.0],
            ..Options::pose(m)
        };
        assert!(Compensator::new(m, &beta, options).is_ok());
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
