//! The interpreter: evaluates a lowered machine for one observation state.
//!
//! It is the reference the JIT is checked against. Per pose it computes the basis values of
//! every term, the parametric errors of every frame, the F-matrices of both chains (through
//! [`FirstOrderModel`]) and from them the tool-location error (eq. 2.24, task sign eq. 2.31/2.34)
//! and its Jacobian with respect to β. The model is linear in β by construction, and each β
//! touches one parametric error, so a Jacobian column is one F-matrix column times one basis
//! value: no derivative is ever taken numerically.

use kin_compiler::ir::{ErrorModel, FrameRef, Machine, Scalar, Term, Var};
use nalgebra::{Vector3, Vector6};
use thiserror::Error;

use crate::kinematics::{FirstOrderModel, FrameErrors, KinematicsError, Pose, Sensitivities};

#[derive(Debug, Error, PartialEq)]
pub enum EvalError {
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
    #[error("the state has {got} {what}, the machine declares {expected}")]
    StateSize {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{what} buffer has {got} entries, {expected} are needed")]
    Buffer {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("the model uses `{name}`, which this observation does not give")]
    Missing { name: String },
    /// A result that is not a finite number: only the embedding API (`Model`) tests for it.
    #[error(
        "`{what}[{index}]` came out as {value}: the state or β is too large for double precision"
    )]
    NotFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
}

/// One observation state, in SI units (spec/data.md): what an error is a function of.
#[derive(Debug, Clone, Copy)]
pub struct State<'a> {
    /// Joint positions, indexed like `Machine::axes`.
    pub q: &'a [f64],
    /// Input values, indexed like `Machine::inputs` (NaN where not observed).
    pub inputs: &'a [f64],
    /// Lag states, indexed like `Machine::lags` (see [`crate::lag`]).
    pub lags: &'a [f64],
    pub time: f64,
    /// Direction of motion per axis: +1, −1, or NaN where not given.
    pub dirs: &'a [f64],
    pub tool: usize,
    pub tool_offset: Option<[f64; 3]>,
}

impl State<'_> {
    /// Whether every number of the state — joint positions, inputs, lag states, time and
    /// directions — is finite, as most states are ([`finite_bits`] of them all is zero).
    /// Callers that must tell a NaN from an infinity look at each value only when this says no.
    #[inline]
    pub fn all_finite(&self) -> bool {
        finite_bits(self.q)
            | finite_bits(self.inputs)
            | finite_bits(self.lags)
            | finite_bits(self.dirs)
            | finite_bits(std::slice::from_ref(&self.time))
            == 0
    }

    fn pose(&self) -> Pose<'_> {
        Pose {
            q: self.q,
            tool: self.tool,
            tool_offset: self.tool_offset,
        }
    }
}

/// Zero exactly when every value is finite: the OR of the bits of `v − v`, which are zero for a
/// finite `v` and a NaN's (never zero) for an infinity or a NaN. An OR, unlike a sum, has no
/// order to keep, so it runs several values a step with no branch — the quick test of a state
/// before each evaluation ([`State::all_finite`], and the C ABI's with its directions).
#[inline]
#[allow(clippy::eq_op)] // `v − v` is the test: zero exactly when `v` is finite.
pub fn finite_bits(values: &[f64]) -> u64 {
    values.iter().fold(0, |a, v| a | (v - v).to_bits())
}

/// Evaluates one machine; holds per-pose scratch so evaluation allocates nothing.
/// Not `Sync` because of that scratch: clone one per thread.
#[derive(Debug, Clone)]
pub struct Interpreter<'m> {
    machine: &'m Machine,
    first: FirstOrderModel,
    sens: Sensitivities,
    /// Values of the non-linear parameters (wavelengths, time constants).
    nonlinear: Vec<f64>,
    /// Scratch for one term's tensor-product values and one factor's basis values.
    term: Vec<f64>,
    factor: Vec<f64>,
    /// The error models in the order their contributions are summed: by frame, chains from the
    /// base outward ([`frame_order`]), the declaration order within a frame. The JIT sums in
    /// this order too, so that the two engines' errors agree to the last bit (a different
    /// association of the same terms differs by rounding, which cancellation between terms
    /// and the compensation's joint Jacobian amplify).
    order: Vec<&'m ErrorModel>,
}

impl<'m> Interpreter<'m> {
    pub fn new(machine: &'m Machine) -> Result<Self, EvalError> {
        let first = FirstOrderModel::new(machine)?;
        let sens = first.sensitivities();
        let widest_term = machine
            .errors
            .iter()
            .flat_map(|e| &e.terms)
            .map(|t| t.coefficients.max(1))
            .max()
            .unwrap_or(1);
        let widest_factor = machine
            .errors
            .iter()
            .flat_map(|e| &e.terms)
            .flat_map(|t| &t.factors)
            .map(|f| f.basis.size())
            .max()
            .unwrap_or(1);
        Ok(Interpreter {
            machine,
            first,
            sens,
            nonlinear: machine.nonlinear.iter().map(|p| p.value).collect(),
            term: vec![0.0; widest_term],
            factor: vec![0.0; widest_factor],
            order: summation_order(machine),
        })
    }

    pub fn machine(&self) -> &'m Machine {
        self.machine
    }

    /// Replaces the non-linear parameter values (a fit moves them).
    pub fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), EvalError> {
        if values.len() != self.nonlinear.len() {
            return Err(EvalError::Buffer {
                what: "the non-linear parameter",
                expected: self.nonlinear.len(),
                got: values.len(),
            });
        }
        self.nonlinear.copy_from_slice(values);
        Ok(())
    }

    fn check_state(&self, s: &State) -> Result<(), EvalError> {
        let m = self.machine;
        let sizes = [
            ("axis positions", m.axes.len(), s.q.len()),
            ("inputs", m.inputs.len(), s.inputs.len()),
            ("lag states", m.lags.len(), s.lags.len()),
            ("directions", m.axes.len(), s.dirs.len()),
        ];
        for (what, expected, got) in sizes {
            if expected != got {
                return Err(EvalError::StateSize {
                    what,
                    expected,
                    got,
                });
            }
        }
        Ok(())
    }

    /// The parametric errors of every frame at `state` for coefficients `beta` (in SI), in the
    /// frames' own axes. Shared by the first-order model and the exact simulator.
    pub fn frame_errors(
        &mut self,
        state: &State,
        beta: &[f64],
        out: &mut FrameErrors,
    ) -> Result<(), EvalError> {
        self.check_state(state)?;
        self.check_beta(beta)?;
        out.check(self.machine)?;
        for e in out
            .tool_chain
            .iter_mut()
            .chain(out.workpiece_chain.iter_mut())
        {
            *e = [0.0; 6];
        }
        out.tool_end = [0.0; 6];
        out.workpiece_end = [0.0; 6];
        for model in &self.machine.errors {
            if !acts(model.frame, state.tool) {
                continue;
            }
            let value = self.model_value(model, state, beta, None)?;
            if let Some(slot) = out.get_mut(model.frame) {
                if let Some(c) = slot.get_mut(model.component.index()) {
                    *c += value;
                }
            }
        }
        Ok(())
    }

    fn check_beta(&self, beta: &[f64]) -> Result<(), EvalError> {
        let n = self.machine.coefficients.len();
        if beta.len() != n {
            return Err(EvalError::Buffer {
                what: "the β",
                expected: n,
                got: beta.len(),
            });
        }
        Ok(())
    }

    /// The tool-location error (ex, ey, ez, erx, ery, erz) at `state`, with the task's sign:
    /// `Σ F_k E_k` (eq. 2.24) summed model by model, each model's value times its F-matrix
    /// column, in `Interpreter::order`'s order (that of the JIT).
    pub fn error(&mut self, state: &State, beta: &[f64]) -> Result<[f64; 6], EvalError> {
        self.check_state(state)?;
        self.check_beta(beta)?;
        self.first.evaluate(&state.pose(), &mut self.sens)?;
        let sign = self.machine.task.sign();
        let mut total = [0.0; 6];
        for k in 0..self.order.len() {
            let Some(&model) = self.order.get(k) else {
                continue;
            };
            if !acts(model.frame, state.tool) {
                continue;
            }
            let value = self.model_value(model, state, beta, None)?;
            let column = self.sens.column(model.frame, model.component) * sign;
            for (t, c) in total.iter_mut().zip(column.iter()) {
                *t += c * value;
            }
        }
        Ok(total)
    }

    /// The value of one error model: its terms' `Σ v·β` (and fixed terms) as one running sum
    /// in term and coefficient order, the association the JIT uses. With `jac` (6 × n_β,
    /// row-major) and the model's F-matrix `column`, also writes the model's Jacobian entries.
    fn model_value(
        &mut self,
        model: &ErrorModel,
        state: &State,
        beta: &[f64],
        mut jac: Option<(&mut [f64], &Vector6<f64>)>,
    ) -> Result<f64, EvalError> {
        let n = beta.len();
        let mut value: Option<f64> = None;
        let mut add = |x: f64| value = Some(value.map_or(x, |a| a + x));
        for term in &model.terms {
            let count = self.term_values(term, state)?;
            if term.coefficients == 0 {
                add(self.term.first().copied().unwrap_or(0.0));
                continue;
            }
            for (k, v) in self.term.iter().take(count).enumerate() {
                let j = term.first + k;
                if let Some((jac, column)) = jac.as_mut() {
                    for (r, c) in column.iter().enumerate() {
                        if let Some(slot) = jac.get_mut(r * n + j) {
                            *slot = c * v;
                        }
                    }
                }
                add(v * beta.get(j).copied().unwrap_or(0.0));
            }
        }
        Ok(value.unwrap_or(0.0))
    }

    /// The error at `state` and its Jacobian with respect to β: `jac` is 6 × n_β, row-major
    /// (row r is error component r). The error includes the fixed (known) terms, so
    /// `error = fixed + jac · β`.
    pub fn error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.check_state(state)?;
        self.check_beta(beta)?;
        let n = self.machine.coefficients.len();
        if jac.len() != 6 * n {
            return Err(EvalError::Buffer {
                what: "the Jacobian",
                expected: 6 * n,
                got: jac.len(),
            });
        }
        self.first.evaluate(&state.pose(), &mut self.sens)?;
        let sign = self.machine.task.sign();
        jac.fill(0.0);
        let mut total = [0.0; 6];
        for k in 0..self.order.len() {
            let Some(&model) = self.order.get(k) else {
                continue;
            };
            // Another tool's frame: its column is zero, and its variables need not be given.
            if !acts(model.frame, state.tool) {
                continue;
            }
            let column = self.sens.column(model.frame, model.component) * sign;
            let value = self.model_value(model, state, beta, Some((&mut *jac, &column)))?;
            for (t, c) in total.iter_mut().zip(column.iter()) {
                *t += c * value;
            }
        }
        *err = total;
        Ok(())
    }

    /// The nominal tool location in wr (position, then the rotation as a matrix) and its
    /// Jacobian with respect to the joint positions: `out[j]` is `(dp/dq_j, ω_j)` in wr axes.
    pub fn nominal_jacobian(
        &mut self,
        state: &State,
        out: &mut [Vector6<f64>],
    ) -> Result<crate::kinematics::ToolLocation, EvalError> {
        self.check_state(state)?;
        Ok(self
            .first
            .nominal_jacobian(&state.pose(), &mut self.sens, out)?)
    }

    /// The nominal tool position in wr at `state`.
    pub fn nominal_position(&mut self, state: &State) -> Result<[f64; 3], EvalError> {
        self.check_state(state)?;
        self.first.evaluate(&state.pose(), &mut self.sens)?;
        Ok(self.sens.location().position.into())
    }

    /// A length observation between two states (eq. 4.5): `dL = u · (Δp₂ − Δp₁)` with the
    /// task's sign, and its row of the design matrix (`dL = fixed + row · β`).
    pub fn length_and_row(
        &mut self,
        s1: &State,
        s2: &State,
        beta: &[f64],
        row: &mut [f64],
    ) -> Result<f64, EvalError> {
        let n = self.machine.coefficients.len();
        if row.len() != n {
            return Err(EvalError::Buffer {
                what: "the length row",
                expected: n,
                got: row.len(),
            });
        }
        let mut jac = vec![0.0; 6 * n];
        let mut e1 = [0.0; 6];
        let mut e2 = [0.0; 6];
        self.error_and_jacobian(s1, beta, &mut e1, &mut jac)?;
        let p1 = self.sens.location().position;
        let rows1: Vec<f64> = jac.get(..3 * n).unwrap_or(&[]).to_vec();
        self.error_and_jacobian(s2, beta, &mut e2, &mut jac)?;
        let p2 = self.sens.location().position;
        let u = crate::kinematics::length_direction(&p1, &p2)?;
        for (j, slot) in row.iter_mut().enumerate() {
            let at = |rows: &[f64], r: usize| rows.get(r * n + j).copied().unwrap_or(0.0);
            *slot = (0..3).map(|r| u[r] * (at(&jac, r) - at(&rows1, r))).sum();
        }
        let dp1 = Vector3::new(e1[0], e1[1], e1[2]);
        let dp2 = Vector3::new(e2[0], e2[1], e2[2]);
        Ok(crate::kinematics::length_error(&u, &dp1, &dp2))
    }

    /// Writes the tensor-product values of `term` (scale × Π factors, row-major) into
    /// `self.term` and returns how many there are (1 for a fixed term).
    fn term_values(&mut self, term: &Term, state: &State) -> Result<usize, EvalError> {
        let scale = scalar(&term.scale, state, self.machine)?;
        let mut len = 1;
        if let Some(first) = self.term.first_mut() {
            *first = scale;
        }
        for f in &term.factors {
            let mut x = var(f.var, state, self.machine)?;
            if let Var::Axis(a) = f.var {
                // A continuous axis may turn many times: its families live on one turn.
                if self.machine.axes.get(a).is_some_and(|axis| axis.continuous) {
                    x = x.rem_euclid(std::f64::consts::TAU);
                }
            }
            let size = f.basis.size();
            let fv = self.factor.get_mut(..size).unwrap_or(&mut []);
            f.basis.eval(x, &self.nonlinear, fv);
            // Outer product in place, from the back so no value is overwritten before use.
            for i in (0..len).rev() {
                let a = self.term.get(i).copied().unwrap_or(0.0);
                for (k, v) in fv.iter().enumerate().rev() {
                    if let Some(slot) = self.term.get_mut(i * size + k) {
                        *slot = a * v;
                    }
                }
            }
            len *= size;
        }
        Ok(len)
    }
}

/// The error models in summation order: sorted (stably) by [`frame_order`].
fn summation_order(m: &Machine) -> Vec<&ErrorModel> {
    let mut models: Vec<&ErrorModel> = m.errors.iter().collect();
    models.sort_by_key(|e| frame_order(e.frame));
    models
}

/// Sort key grouping error models by frame, chains from the base outward: the order in which
/// both engines sum the models' contributions to the error.
pub(crate) fn frame_order(f: FrameRef) -> (u8, usize) {
    match f {
        FrameRef::Tool(k) => (0, k),
        FrameRef::Workpiece(k) => (1, k),
        FrameRef::ToolEnd(None) => (2, 0),
        FrameRef::ToolEnd(Some(i)) => (2, i + 1),
        FrameRef::WorkpieceEnd => (3, 0),
    }
}

/// Whether errors of `frame` act for the selected tool.
fn acts(frame: FrameRef, tool: usize) -> bool {
    !matches!(frame, FrameRef::ToolEnd(Some(i)) if i != tool)
}

fn var(v: Var, s: &State, m: &Machine) -> Result<f64, EvalError> {
    let value = match v {
        Var::Axis(i) => s.q.get(i).copied(),
        Var::Input(i) => s.inputs.get(i).copied(),
        Var::Lag(i) => s.lags.get(i).copied(),
        Var::Time => Some(s.time),
        Var::Direction(i) => s.dirs.get(i).copied(),
    };
    match value {
        Some(x) if !x.is_nan() => Ok(x),
        _ => Err(EvalError::Missing {
            name: var_name(v, m),
        }),
    }
}

/// How a variable is called in messages and measurement files.
pub fn var_name(v: Var, m: &Machine) -> String {
    let name = match v {
        Var::Axis(i) => m.axes.get(i).map(|a| a.name.clone()),
        Var::Input(i) => m.inputs.get(i).map(|a| a.name.clone()),
        Var::Lag(i) => m.lags.get(i).and_then(|l| {
            if l.warmup {
                Some("warm-up".to_string())
            } else {
                m.inputs.get(l.input).map(|a| format!("lag of {}", a.name))
            }
        }),
        Var::Time => Some("time".to_string()),
        Var::Direction(i) => m.axes.get(i).map(|a| format!("dir_{}", a.name)),
    };
    name.unwrap_or_default()
}

/// Evaluates a known scalar (libm for the trigonometry, so the JIT can agree exactly).
pub fn scalar(s: &Scalar, state: &State, m: &Machine) -> Result<f64, EvalError> {
    Ok(match s {
        Scalar::Num(x) => *x,
        Scalar::Var(v) => var(*v, state, m)?,
        Scalar::Neg(a) => -scalar(a, state, m)?,
        Scalar::Add(a, b) => scalar(a, state, m)? + scalar(b, state, m)?,
        Scalar::Sub(a, b) => scalar(a, state, m)? - scalar(b, state, m)?,
        Scalar::Mul(a, b) => scalar(a, state, m)? * scalar(b, state, m)?,
        Scalar::Div(a, b) => scalar(a, state, m)? / scalar(b, state, m)?,
        Scalar::Sin(a) => libm::sin(scalar(a, state, m)?),
        Scalar::Cos(a) => libm::cos(scalar(a, state, m)?),
    })
}

#[cfg(test)]
mod tests {
    use super::{finite_bits, State};

    /// Zero exactly when every value is finite, wherever the one value that is not stands; a
    /// state's test covers each of its numbers.
    #[test]
    fn finite_bits_is_each_value_finite() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            5e-324,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        for v in values {
            for len in 1..10 {
                for at in 0..len {
                    let mut xs = vec![0.25; len];
                    xs[at] = v;
                    assert_eq!(
                        finite_bits(&xs) == 0,
                        v.is_finite(),
                        "{v:e} at {at} of {len}"
                    );
                }
            }
        }
        assert_eq!(finite_bits(&[]), 0);
        // Every part of a state is in its test.
        let state = |q: &[f64; 2], time, dirs: &[f64; 2]| {
            State {
                q,
                inputs: &[],
                lags: &[],
                time,
                dirs,
                tool: 0,
                tool_offset: None,
            }
            .all_finite()
        };
        let (fine, nan) = ([0.5, 1.0], [1.0, f64::NAN]);
        assert!(state(&fine, 60.0, &fine));
        assert!(!state(&nan, 60.0, &fine));
        assert!(!state(&fine, 60.0, &nan));
        assert!(!state(&fine, f64::INFINITY, &fine));
    }
}
