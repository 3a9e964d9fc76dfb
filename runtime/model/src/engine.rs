//! What the fit and the commands need from an evaluator, so the interpreter and the JIT are
//! interchangeable (`--engine interp|jit`) and can be checked one against the other.

use kin_compiler::ir::Machine;

use crate::interp::{EvalError, Interpreter, State};
use crate::kinematics::{FirstOrderModel, Pose};

/// The components of the tool-location error a data set observes — a subset of the six
/// (`x y z` position, `rx ry rz` orientation, in that order) — so that an evaluator computes and
/// stores only those rows. Built only from the six flags, so it cannot name a seventh
/// component; the rows it selects keep the six's order ([`Observed::row`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Observed(u8);

impl Observed {
    /// All six components: a full pose (the layout of [`Evaluator::error_and_jacobian`]).
    pub const FULL: Observed = Observed(0b11_1111);
    /// The three position components: a position-only data set, or the two poses of a length
    /// (eq. 4.5 reads only their position rows).
    pub const POSITION: Observed = Observed(0b00_0111);

    /// The components whose flag is set, flag `c` for component `c`.
    pub fn from_flags(flags: [bool; 6]) -> Observed {
        Observed(
            flags
                .iter()
                .enumerate()
                .fold(0, |bits, (c, &f)| bits | (u8::from(f) << c)),
        )
    }

    /// The components whose bit is set, bit `c` for component `c` (the C ABI's `observed`);
    /// `None` for no component or a bit beyond the sixth.
    pub fn from_bits(bits: u32) -> Option<Observed> {
        match u8::try_from(bits) {
            Ok(b) if b != 0 && b <= Observed::FULL.0 => Some(Observed(b)),
            _ => None,
        }
    }

    /// Whether component `c` (0–5) is observed.
    pub fn contains(self, c: usize) -> bool {
        c < 6 && self.0 & (1 << c) != 0
    }

    /// The row component `c` has among the observed rows, if it is observed: `row(4)` of
    /// `{x, y, rx, ry}` is 3.
    pub fn row(self, c: usize) -> Option<usize> {
        self.contains(c)
            .then(|| (self.0 & ((1u8 << c) - 1)).count_ones() as usize)
    }

    /// The number of observed rows.
    pub fn rows(self) -> usize {
        self.0.count_ones() as usize
    }

    /// The observed components, in order.
    pub fn components(self) -> impl Iterator<Item = usize> {
        (0..6).filter(move |&c| self.contains(c))
    }

    /// A small number that tells the 64 subsets apart (for caches indexed by subset).
    pub fn index(self) -> usize {
        usize::from(self.0)
    }
}

impl std::fmt::Display for Observed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        const NAMES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];
        let names: Vec<&str> = self
            .components()
            .filter_map(|c| NAMES.get(c).copied())
            .collect();
        f.write_str(&names.join(" "))
    }
}

/// Evaluation of one machine's tool-location error and its β-Jacobian.
pub trait Evaluator {
    fn machine(&self) -> &Machine;

    /// Which of the [`Engine`]s this is, if one: a fit then evaluates a part of the model (the
    /// terms a time constant moves) with the same kind of engine.
    fn kind(&self) -> Option<Engine> {
        None
    }

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

    /// [`Evaluator::error_and_jacobian`] restricted to the `observed` components: `err[k]` and
    /// Jacobian row `k` (`jac[k·n .. (k+1)·n]`) are those of the k-th observed component, so
    /// `err` holds `observed.rows()` values and `jac` `observed.rows() · n`. The JIT computes
    /// only these rows; each value equals the full evaluation's bit for bit.
    fn observed_error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        // The generic path: the full evaluation, then the observed rows picked out of it.
        let n = self.machine().coefficients.len();
        let k = observed.rows();
        if err.len() != k {
            return Err(EvalError::Buffer {
                what: "the observed error",
                expected: k,
                got: err.len(),
            });
        }
        if jac.len() != k * n {
            return Err(EvalError::Buffer {
                what: "the observed Jacobian",
                expected: k * n,
                got: jac.len(),
            });
        }
        let mut full_err = [0.0; 6];
        let mut full = vec![0.0; 6 * n];
        self.error_and_jacobian(state, beta, &mut full_err, &mut full)?;
        for (row, c) in observed.components().enumerate() {
            if let (Some(e), Some(&v)) = (err.get_mut(row), full_err.get(c)) {
                *e = v;
            }
            if let (Some(dst), Some(src)) = (
                jac.get_mut(row * n..(row + 1) * n),
                full.get(c * n..(c + 1) * n),
            ) {
                dst.copy_from_slice(src);
            }
        }
        Ok(())
    }

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

    /// Another evaluator of the same machine, with the same code and non-linear values, for
    /// another thread (a pass over the rows split over the cores). `None` when the engine
    /// cannot be copied: its callers then work on this one alone.
    fn fork(&self) -> Option<Box<dyn Evaluator + Send + '_>> {
        None
    }
}

impl Evaluator for Interpreter<'_> {
    fn machine(&self) -> &Machine {
        Interpreter::machine(self)
    }
    fn kind(&self) -> Option<Engine> {
        Some(Engine::Interp)
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
    fn fork(&self) -> Option<Box<dyn Evaluator + Send + '_>> {
        Some(Box::new(self.clone()))
    }
}

/// Which engine evaluates a machine: the [interpreter](crate::interp), the reference, or the
/// [JIT](crate::jit), native code specialised to the machine (the default). Both compute the same
/// numbers (to 1e-12 relative, tested on random machines), so a user can check one against the
/// other (`--engine interp|jit`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum Engine {
    Interp,
    #[default]
    Jit,
}

impl Engine {
    pub const ALL: [Engine; 2] = [Engine::Interp, Engine::Jit];

    /// The name on the command line: `interp` or `jit`.
    pub fn name(self) -> &'static str {
        match self {
            Engine::Interp => "interp",
            Engine::Jit => "jit",
        }
    }
}

impl std::fmt::Display for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Engine {
    type Err = String;

    fn from_str(s: &str) -> Result<Engine, String> {
        Engine::ALL
            .into_iter()
            .find(|e| e.name() == s)
            .ok_or_else(|| format!("unknown engine `{s}`: expected `interp` or `jit`"))
    }
}

/// Why an engine could not be made for a machine.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum EngineError {
    #[error(transparent)]
    Interp(#[from] EvalError),
    #[error(transparent)]
    Jit(#[from] crate::jit::JitError),
}

/// An evaluator of `machine` by `engine`, starting from the machine's non-linear parameter
/// values. The JIT compiles here (a few milliseconds); the interpreter borrows the machine.
///
/// ```
/// # use kin_model::engine::{self, Engine};
/// let src = "machine m { task position  axis X prismatic along x range 0 mm .. 500 mm
///     tool chain { X moving tool t }  errors { X.tx = spline(X, knots 2) } }";
/// let machine = kin_compiler::compile(src).compiled.expect("valid").machine;
/// let state = &kin_model::states::States::sample(&machine, 1, 0);
/// let beta = vec![1e-6; machine.coefficients.len()];
/// let mut interp = engine::make(&machine, Engine::Interp).expect("interpreter");
/// let mut jit = engine::make(&machine, "jit".parse().expect("engine")).expect("jit");
/// let a = interp.error(&state.get(0), &beta).expect("eval");
/// let b = jit.error(&state.get(0), &beta).expect("eval");
/// assert!((a[0] - b[0]).abs() <= 1e-12 * a[0].abs());
/// ```
pub fn make(
    machine: &Machine,
    engine: Engine,
) -> Result<Box<dyn Evaluator + Send + '_>, EngineError> {
    Ok(match engine {
        Engine::Interp => Box::new(Interpreter::new(machine)?),
        Engine::Jit => Box::new(crate::jit::compile(machine)?.evaluator()),
    })
}

#[cfg(test)]
mod tests {
    use super::Observed;

    /// Bit `c` is component `c`; no component, or a bit beyond the sixth, is no subset.
    #[test]
    fn from_bits_is_from_flags() {
        for bits in 1..64u32 {
            let flags = std::array::from_fn(|c| bits & (1 << c) != 0);
            assert_eq!(Observed::from_bits(bits), Some(Observed::from_flags(flags)));
        }
        assert_eq!(Observed::from_bits(7), Some(Observed::POSITION));
        assert_eq!(Observed::from_bits(63), Some(Observed::FULL));
        for bits in [0, 64, 65, 127, 255, 256, 1 << 31, u32::MAX] {
            assert_eq!(Observed::from_bits(bits), None, "{bits}");
        }
    }
}
