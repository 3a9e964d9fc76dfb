//! What the fit and the commands need from an evaluator, so the interpreter and the JIT are
//! interchangeable (`--engine interp|jit`) and can be checked one against the other.

use kin_compiler::ir::Machine;

use crate::interp::{EvalError, Interpreter, State};
use crate::kinematics::{FirstOrderModel, Pose};

/// Evaluation of one machine's tool-location error and its β-Jacobian.
pub trait Evaluator {
    fn machine(&self) -> &Machine;

    /// Replaces the non-linear parameter values (wavelengths, time constants).
    fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), EvalError>;

    /// The error (task sign) at `state` for `beta`.
    fn error(&mut self, state: &State, beta: &[f64]) -> Result<[f64; 6], EvalError>;

    /// The error and its Jacobian with respect to β (6 × n, row-major): `error = fixed + jac·β`.
    fn error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError>;

    /// A length observation (eq. 4.5) and its design-matrix row.
    fn length_and_row(
        &mut self,
        s1: &State,
        s2: &State,
        beta: &[f64],
        row: &mut [f64],
    ) -> Result<f64, EvalError>;

    /// The nominal tool position in wr at `state` (where an artifact's placement acts).
    fn nominal_position(&mut self, state: &State) -> Result<[f64; 3], EvalError> {
        // A generic fallback; engines override it with their own per-pose pass.
        let first = FirstOrderModel::new(self.machine())?;
        let mut sens = first.sensitivities();
        first.evaluate(
            &Pose {
                q: state.q,
                tool: state.tool,
                tool_offset: state.tool_offset,
            },
            &mut sens,
        )?;
        Ok(sens.location().position.into())
    }
}

impl Evaluator for Interpreter<'_> {
    fn machine(&self) -> &Machine {
        Interpreter::machine(self)
    }
    fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), EvalError> {
        Interpreter::set_nonlinear(self, values)
    }
    fn error(&mut self, state: &State, beta: &[f64]) -> Result<[f64; 6], EvalError> {
        Interpreter::error(self, state, beta)
    }
    fn error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        Interpreter::error_and_jacobian(self, state, beta, err, jac)
    }
    fn length_and_row(
        &mut self,
        s1: &State,
        s2: &State,
        beta: &[f64],
        row: &mut [f64],
    ) -> Result<f64, EvalError> {
        Interpreter::length_and_row(self, s1, s2, beta, row)
    }
    fn nominal_position(&mut self, state: &State) -> Result<[f64; 3], EvalError> {
        Interpreter::nominal_position(self, state)
    }
}
