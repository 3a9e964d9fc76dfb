//! The embedding API: a `.kin` model compiled from source, evaluated from a program.
//!
//! [`Model::compile`] parses, checks and lowers a source and compiles it to native code (the
//! [JIT](crate::jit)); problems come back as [`Diagnostic`]s in the [`Error`](enum@Error), as data, never
//! printed. Parameter values come from the source's own `params` block, from
//! [`Model::with_params`] (a `params { … }` text, e.g. the `FIT.params` a fit writes) or from
//! [`Model::set_beta`]. Evaluation takes `&self`, allocates nothing and takes no lock, so one
//! model serves many threads at once, each with its own output buffers:
//!
//! - [`Model::eval`]: the tool-location error (task sign, spec/kinematics.md) at a [`State`] for a β;
//! - [`Model::eval_jacobian`]: the error and its 6 × n β-Jacobian (the design-matrix rows);
//! - [`Model::nominal_jacobian`]: the nominal tool location and its joint Jacobian;
//! - [`Model::eval_rows`] and [`Model::eval_jacobian_rows`]: the same over many states at once
//!   ([`StateRows`], row-major arrays, e.g. from a [`RowsBuf`]), into buffers the caller reuses;
//!   their `_observed` forms for some components only (the position rows of a tracker);
//! - [`Model::compensator`]: a [`ServoCompensator`], the joint corrections of a commanded pose
//!   (thesis §2.3.5) for a controller's servo cycle: native code, no allocation, no lock;
//! - [`Model::evaluator`]: an [`Evaluator`] (what the fit uses), JIT by default or the
//!   interpreter with [`Model::evaluator_with`]`(`[`Engine::Interp`]`)` to check one against the
//!   other.
//!
//! [`Model::save`] writes the source, the parameter texts bound to it and the exact values of β
//! and of the non-linear parameters as JSON; [`Model::load`] recompiles the source and restores
//! the values bit for bit.
//!
//! All quantities are SI: metres, radians, seconds, kelvin, newtons.
//!
//! ```
//! use kin_model::Model;
//!
//! let model = Model::compile(
//!     "machine slide {
//!         task position
//!         axis X prismatic along x range 0 mm .. 500 mm
//!         tool chain { X moving tool t at (0, 0, -100) mm }
//!         errors { X.tx = spline(X, knots 2)  X.ry = const }
//!     }",
//! )?
//! .with_params("params { X.tx = [2, -1, 0.5, 0.2] um  X.ry[0] = 3 urad }")?;
//!
//! let mut state = model.state();
//! state.q[0] = 0.25; // X = 250 mm
//! let mut err = [0.0; 6];
//! model.eval(&state.get(), model.beta(), &mut err)?;
//! let mut jac = vec![0.0; 6 * model.coefficients()];
//! let mut err2 = [0.0; 6];
//! model.eval_jacobian(&state.get(), model.beta(), &mut err2, &mut jac)?;
//! assert_eq!(err, err2);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::path::{Path, PathBuf};

use kin_compiler::ir::Machine;
use kin_compiler::{Compiled, Diagnostic};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::compensate::{self, CompensateError, Compensated, Options, ServoError};
use crate::engine::{Engine, EngineError, Evaluator, Observed};
use crate::interp::{EvalError, Interpreter, State};
use crate::jit::{self, BatchError, JitError, JitModel, StateRows};
use crate::kinematics::ToolLocation;

/// Why a model could not be made, bound, saved or loaded.
#[derive(Debug, Error)]
pub enum Error {
    /// The source has errors: every diagnostic (warnings included), spans into the source.
    #[error("the source does not compile: {}", summary(diagnostics))]
    Compile { diagnostics: Vec<Diagnostic> },
    /// A parameter text has errors: every diagnostic, spans into that text.
    #[error("the parameter values cannot be bound: {}", summary(diagnostics))]
    Params { diagnostics: Vec<Diagnostic> },
    #[error(transparent)]
    Jit(#[from] JitError),
    #[error("{what} holds {got} values, the model has {expected}")]
    Values {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A value that is not a finite number: every evaluation with it would be NaN, and a
    /// compensation's solve would fail at every call.
    #[error("{what} [{index}] is {value}, not a finite number")]
    NotFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    #[error("`{}`: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A saved model that cannot be read back: not one, of another version, or values that do not
    /// fit the recompiled source.
    #[error("not a saved kin model: {message}")]
    Format { message: String },
}

impl Error {
    /// The diagnostics of a compile or params error (empty for the others).
    pub fn diagnostics(&self) -> &[Diagnostic] {
        match self {
            Error::Compile { diagnostics } | Error::Params { diagnostics } => diagnostics,
            _ => &[],
        }
    }
}

/// The first error's code and message, and how many more there are.
fn summary(diagnostics: &[Diagnostic]) -> String {
    let errors: Vec<&Diagnostic> = diagnostics.iter().filter(|d| d.is_error()).collect();
    match errors.as_slice() {
        [] => "no diagnostic".into(),
        [d] => format!("error[{}]: {}", d.code, d.message),
        [d, rest @ ..] => format!("error[{}]: {} (and {} more)", d.code, d.message, rest.len()),
    }
}

/// A compiled `.kin` model with bound parameter values. See the [module docs](self).
///
/// `Send + Sync` and cheap to evaluate from many threads; cloning copies the machine and shares
/// the native code.
#[derive(Debug, Clone)]
pub struct Model {
    source: String,
    /// Parameter texts bound after the source, in order.
    params: Vec<String>,
    compiled: Compiled,
    warnings: Vec<Diagnostic>,
    /// `compiled.machine.nonlinear`'s values, as the evaluation takes them.
    nonlinear: Vec<f64>,
    jit: JitModel,
}

impl Model {
    /// Compiles `source` (a `machine`, optionally followed by its `params`) to native code.
    pub fn compile(source: &str) -> Result<Model, Error> {
        let out = kin_compiler::compile(source);
        let Some(mut compiled) = out.compiled else {
            return Err(Error::Compile {
                diagnostics: out.diagnostics,
            });
        };
        let m = &mut compiled.machine;
        if m.beta.len() != m.coefficients.len() {
            m.beta = vec![0.0; m.coefficients.len()];
        }
        let jit = jit::compile(m)?;
        Ok(Model {
            source: source.to_string(),
            params: Vec::new(),
            nonlinear: m.nonlinear.iter().map(|p| p.value).collect(),
            compiled,
            warnings: out.diagnostics,
            jit,
        })
    }

    /// Binds a parameter text (`params { … }`) on top of the values bound so far: the values it
    /// gives replace the current ones, the others stay.
    pub fn with_params(mut self, params: &str) -> Result<Model, Error> {
        self.bind_params(params)?;
        Ok(self)
    }

    /// As [`Model::with_params`], in place; on an error the model is unchanged.
    pub fn bind_params(&mut self, params: &str) -> Result<(), Error> {
        let mut machine = self.compiled.machine.clone();
        let diagnostics = kin_compiler::bind_params(&mut machine, params);
        if diagnostics.iter().any(Diagnostic::is_error) {
            return Err(Error::Params { diagnostics });
        }
        self.warnings.extend(diagnostics);
        self.nonlinear = machine.nonlinear.iter().map(|p| p.value).collect();
        self.compiled.machine = machine;
        self.params.push(params.to_string());
        Ok(())
    }

    /// The lowered machine, with the bound values in `beta` and `nonlinear[..].value`.
    pub fn machine(&self) -> &Machine {
        &self.compiled.machine
    }

    /// The machine and the map from its parts back to the source.
    pub fn compiled(&self) -> &Compiled {
        &self.compiled
    }

    pub fn source(&self) -> &str {
        &self.source
    }

    /// The parameter texts bound after the source, in order.
    pub fn params(&self) -> &[String] {
        &self.params
    }

    /// Warnings of the compiler and of the parameter texts.
    pub fn warnings(&self) -> &[Diagnostic] {
        &self.warnings
    }

    /// The native code, for callers that pass their own non-linear parameter values.
    pub fn jit(&self) -> &JitModel {
        &self.jit
    }

    pub fn axes(&self) -> usize {
        self.machine().axes.len()
    }

    pub fn inputs(&self) -> usize {
        self.machine().inputs.len()
    }

    pub fn lags(&self) -> usize {
        self.machine().lags.len()
    }

    pub fn tools(&self) -> usize {
        self.machine().tools.len()
    }

    /// Number of coefficients β: the Jacobian has `6 × coefficients()` entries.
    pub fn coefficients(&self) -> usize {
        self.machine().coefficients.len()
    }

    /// The bound coefficient values (zeros where none was bound), SI, indexed like
    /// `machine().coefficients`.
    pub fn beta(&self) -> &[f64] {
        &self.compiled.machine.beta
    }

    /// Replaces the coefficient values (e.g. with a fit's).
    pub fn set_beta(&mut self, beta: &[f64]) -> Result<(), Error> {
        check_values("β", self.coefficients(), beta.len())?;
        check_finite("β", beta)?;
        self.compiled.machine.beta.copy_from_slice(beta);
        Ok(())
    }

    /// The non-linear parameter values (wavelengths, time constants), SI, indexed like
    /// `machine().nonlinear`.
    pub fn nonlinear(&self) -> &[f64] {
        &self.nonlinear
    }

    /// Replaces the non-linear parameter values.
    pub fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), Error> {
        check_values(
            "the non-linear parameter values",
            self.nonlinear.len(),
            values.len(),
        )?;
        check_finite("the non-linear parameter values", values)?;
        self.nonlinear.copy_from_slice(values);
        for (p, v) in self.compiled.machine.nonlinear.iter_mut().zip(values) {
            p.value = *v;
        }
        Ok(())
    }

    /// Storage for one state of this machine: axes at zero, everything else not given (NaN),
    /// the first tool. Fill in what the model uses and evaluate [`StateBuf::get`].
    pub fn state(&self) -> StateBuf {
        let m = self.machine();
        StateBuf {
            q: vec![0.0; m.axes.len()],
            inputs: vec![f64::NAN; m.inputs.len()],
            lags: vec![f64::NAN; m.lags.len()],
            dirs: vec![f64::NAN; m.axes.len()],
            time: f64::NAN,
            tool: 0,
            tool_offset: None,
        }
    }

    /// The error at `state` for coefficients `beta`: `(ex, ey, ez, erx, ery, erz)` in the
    /// workpiece frame's axes, with the task's sign.
    ///
    /// Every evaluation of a `Model` hands back finite numbers or an error: a state or β too
    /// large for double precision gives [`EvalError::NotFinite`], naming the first value that
    /// came out infinite or NaN. The Jacobian's entries are not looked at one by one: the
    /// processor's overflow flags after the call vouch for them (spec/performance.md, "Finite
    /// outputs without looking at them").
    pub fn eval(&self, state: &State, beta: &[f64], out: &mut [f64; 6]) -> Result<(), EvalError> {
        let err = self.jit.error(state, beta, &self.nonlinear)?;
        jit::finite(true, &err, &[])?;
        *out = err;
        Ok(())
    }

    /// The error and its Jacobian with respect to β, 6 × n row-major (row r is error component
    /// r): `error = fixed + jac·β`.
    pub fn eval_jacobian(
        &self,
        state: &State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.eval_jacobian_observed(state, beta, Observed::FULL, err, jac)
    }

    /// [`Model::eval_jacobian`] of the `observed` components only (position rows alone, say):
    /// `err` holds `observed.rows()` values and `jac` `observed.rows() × n`, row k that of the
    /// k-th observed component, computed by code for those rows (no work on the others).
    pub fn eval_jacobian_observed(
        &self,
        state: &State,
        beta: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.jit.jacobian(
            state,
            beta,
            &self.nonlinear,
            observed,
            err,
            jac,
            jit::Outputs::Finite,
        )
    }

    /// The nominal tool location in the workpiece frame and its Jacobian with respect to the
    /// joint positions: `jac[6j..6j+6]` is `(dp/dq_j, ω_j)`.
    pub fn nominal_jacobian(
        &self,
        state: &State,
        jac: &mut [f64],
    ) -> Result<ToolLocation, EvalError> {
        self.jit.nominal_jacobian(state, jac)
    }

    /// [`Model::eval`] over many states: `err` holds 6 values per row.
    pub fn eval_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        err: &mut [f64],
    ) -> Result<(), BatchError> {
        self.eval_rows_observed(rows, beta, Observed::FULL, err)
    }

    /// [`Model::eval_jacobian`] over many states: `err` holds 6 values per row, `jac` one 6 × n
    /// block per row.
    pub fn eval_jacobian_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), BatchError> {
        self.eval_jacobian_rows_observed(rows, beta, Observed::FULL, err, jac)
    }

    /// [`Model::eval_rows`] of the `observed` components only: `err` holds `observed.rows()`
    /// values per row.
    pub fn eval_rows_observed(
        &self,
        rows: &StateRows,
        beta: &[f64],
        observed: Observed,
        err: &mut [f64],
    ) -> Result<(), BatchError> {
        self.jit
            .observed_error_rows(rows, beta, &self.nonlinear, observed, err)?;
        rows_finite(observed.rows(), err)
    }

    /// [`Model::eval_jacobian_rows`] of the `observed` components only: `err` holds
    /// `observed.rows()` values per row and `jac` one `observed.rows() × n` block per row, each
    /// the rows of [`Model::eval_jacobian_observed`] at that state (a tracker's positions: half
    /// the work and half the memory of the full pose).
    pub fn eval_jacobian_rows_observed(
        &self,
        rows: &StateRows,
        beta: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), BatchError> {
        self.jit.jacobian_rows(
            rows,
            beta,
            &self.nonlinear,
            observed,
            err,
            jac,
            jit::Outputs::Finite,
        )
    }

    /// An [`Evaluator`] on the JIT's code (no compilation), with this model's non-linear values.
    /// It holds scratch: one per thread.
    pub fn evaluator(&self) -> Box<dyn Evaluator + Send + '_> {
        Box::new(self.jit_evaluator())
    }

    /// An [`Evaluator`] by the chosen engine, with this model's non-linear values.
    pub fn evaluator_with(
        &self,
        engine: Engine,
    ) -> Result<Box<dyn Evaluator + Send + '_>, EngineError> {
        Ok(match engine {
            Engine::Jit => Box::new(self.jit_evaluator()),
            Engine::Interp => {
                let mut it = Interpreter::new(self.machine())?;
                it.set_nonlinear(&self.nonlinear)?;
                Box::new(it)
            }
        })
    }

    /// The compensation function of a positioning machine (thesis §2.3.5) with this model's
    /// bound values, for a controller to call every servo cycle: see [`ServoCompensator`].
    /// Refused for a measuring machine, weights that [`Options::check`] refuses, and more than [`compensate::MAX_SERVO_AXES`] axes.
    pub fn compensator(&self, options: Options) -> Result<ServoCompensator, CompensateError> {
        let m = self.machine();
        if m.task.sign() < 0.0 {
            return Err(CompensateError::Measuring(m.name.clone()));
        }
        options.check()?;
        if m.axes.len() > compensate::MAX_SERVO_AXES {
            return Err(CompensateError::TooManyAxes(m.axes.len()));
        }
        Ok(ServoCompensator {
            model: self.clone(),
            options,
        })
    }

    fn jit_evaluator(&self) -> jit::JitEvaluator {
        let mut e = self.jit.evaluator();
        // The code does not depend on the values: only the evaluator's copy is replaced. The
        // lengths agree (both come from this machine), so this cannot fail.
        let _ = e.set_nonlinear(&self.nonlinear);
        e
    }

    /// The model as JSON: source, parameter texts, and the exact values of β and of the
    /// non-linear parameters. See [`Model::save`].
    pub fn to_json(&self) -> Result<String, Error> {
        let m = self.machine();
        let finite = |what: &str, name: &str, v: f64| {
            if v.is_finite() {
                Ok(v)
            } else {
                Err(Error::Format {
                    message: format!("{what} `{name}` is {v}, which a saved model cannot hold"),
                })
            }
        };
        let saved = Saved {
            format: FORMAT.into(),
            version: VERSION,
            machine: m.name.clone(),
            source: self.source.clone(),
            params: self.params.clone(),
            coefficients: m.coefficients.iter().map(|c| c.name.clone()).collect(),
            beta: m
                .coefficients
                .iter()
                .zip(&m.beta)
                .map(|(c, b)| finite("coefficient", &c.name, *b))
                .collect::<Result<_, _>>()?,
            nonlinear: m
                .nonlinear
                .iter()
                .zip(&self.nonlinear)
                .map(|(p, v)| {
                    Ok(Named {
                        name: p.name.clone(),
                        value: finite("parameter", &p.name, *v)?,
                    })
                })
                .collect::<Result<_, Error>>()?,
        };
        serde_json::to_string_pretty(&saved).map_err(|e| Error::Format {
            message: e.to_string(),
        })
    }

    /// Reads [`Model::to_json`]'s text: recompiles the source, binds the parameter texts and
    /// restores the saved values, checking that they fit the machine.
    pub fn from_json(text: &str) -> Result<Model, Error> {
        let saved: Saved = serde_json::from_str(text).map_err(|e| Error::Format {
            message: e.to_string(),
        })?;
        if saved.format != FORMAT {
            return Err(Error::Format {
                message: format!("the format is `{}`, not `{FORMAT}`", saved.format),
            });
        }
        if saved.version != VERSION {
            return Err(Error::Format {
                message: format!(
                    "version {} (this kin reads version {VERSION})",
                    saved.version
                ),
            });
        }
        let mut model = Model::compile(&saved.source)?;
        for p in &saved.params {
            model.bind_params(p)?;
        }
        let names: Vec<&str> = model
            .machine()
            .coefficients
            .iter()
            .map(|c| c.name.as_str())
            .collect();
        if names
            != saved
                .coefficients
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>()
        {
            return Err(Error::Format {
                message: "the saved coefficients are not the source's".into(),
            });
        }
        model.set_beta(&saved.beta)?;
        let mut values = model.nonlinear.clone();
        if saved.nonlinear.len() != values.len() {
            return Err(Error::Values {
                what: "the saved non-linear parameters",
                expected: values.len(),
                got: saved.nonlinear.len(),
            });
        }
        for n in &saved.nonlinear {
            let Some(k) = model
                .machine()
                .nonlinear
                .iter()
                .position(|p| p.name == n.name)
            else {
                return Err(Error::Format {
                    message: format!("the source has no non-linear parameter `{}`", n.name),
                });
            };
            if let Some(slot) = values.get_mut(k) {
                *slot = n.value;
            }
        }
        model.set_nonlinear(&values)?;
        Ok(model)
    }

    /// Saves the model (see [`Model::to_json`]) to `path`, replacing it atomically: an
    /// interrupted save leaves the previous file whole ([`kin_data::output::replace`]).
    pub fn save(&self, path: &Path) -> Result<(), Error> {
        let text = self.to_json()?;
        kin_data::output::replace(path, (text + "\n").as_bytes()).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Loads a model saved with [`Model::save`]. At most
    /// [`MAX_TEXT_BYTES`](kin_data::bounded_read::MAX_TEXT_BYTES) are read, so a path that never
    /// ends (`/dev/zero`) is an error, not unbounded memory.
    pub fn load(path: &Path) -> Result<Model, Error> {
        use kin_data::bounded_read::{read, BoundedReadError, MAX_TEXT_BYTES};
        let io = |source| Error::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = read(path, MAX_TEXT_BYTES).map_err(|e| match e {
            BoundedReadError::Io(e) => io(e),
            other => io(std::io::Error::other(other)),
        })?;
        let text = String::from_utf8(bytes)
            .map_err(|e| io(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))?;
        Model::from_json(&text)
    }
}

/// The joint corrections of a positioning machine's commanded poses, compiled: made once by
/// [`Model::compensator`], called every servo cycle.
///
/// [`ServoCompensator::compensate`] runs the same §2.3.5 iteration as `kin compensate`
/// (column-scaled weighted least squares on the joint Jacobian, then Gauss–Newton steps, one
/// implementation for both) on the JIT's first-order error model applied to the exact nominal
/// kinematics, at most `Options::iterations` linear solves. It takes `&self`, keeps its scratch
/// on the stack, allocates nothing and takes no lock: one compensator serves every thread.
/// `kin compensate` additionally re-evaluates with every frame's error as an exact transform;
/// the two differ by products of two errors (spec/compensation.md).
///
/// ```
/// use kin_model::{compensate::Options, Model};
///
/// let model = Model::compile(
///     "machine slide {
///         task position
///         axis X prismatic along x range 0 mm .. 500 mm
///         tool chain { X moving tool t at (0, 0, -100) mm }
///         errors { X.tx = const }
///     }
///     params { X.tx = [5] um }",
/// )?;
/// let comp = model.compensator(Options::pose(model.machine()))?;
/// let mut state = model.state();
/// state.q[0] = 0.25;
/// let mut dq = [0.0];
/// let done = comp.compensate(&state.get(), &mut dq)?;
/// assert!((dq[0] + 5e-6).abs() < 1e-12); // 5 µm back
/// assert!(done.after[0].abs() < 1e-12);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone)]
pub struct ServoCompensator {
    model: Model,
    options: Options,
}

impl ServoCompensator {
    pub fn model(&self) -> &Model {
        &self.model
    }

    pub fn options(&self) -> &Options {
        &self.options
    }

    /// The correction of the commanded pose `state` into `dq` (one value per axis, m or rad, to
    /// add to the command), with the predicted error before and after it. The state's inputs,
    /// lags, time and directions of motion are those of the commanded motion.
    pub fn compensate(&self, state: &State, dq: &mut [f64]) -> Result<Compensated, ServoError> {
        let model = &self.model;
        let mut flat = [0.0; 6 * compensate::MAX_SERVO_AXES];
        let n = model.axes().min(compensate::MAX_SERVO_AXES);
        let mut engine = compensate::JitEngine {
            jit: &model.jit,
            beta: model.beta(),
            nonlinear: &model.nonlinear,
            flat: &mut flat[..6 * n],
        };
        compensate::servo(&mut engine, model.machine(), &self.options, state, dq)
    }

    /// An interpreter with this model's non-linear values, for
    /// [`ServoCompensator::compensate_interp`] (one per thread).
    pub fn interpreter(&self) -> Result<Interpreter<'_>, EvalError> {
        let mut it = Interpreter::new(self.model.machine())?;
        it.set_nonlinear(&self.model.nonlinear)?;
        Ok(it)
    }

    /// [`ServoCompensator::compensate`] by the interpreter: the reference the native code is
    /// checked against (and timed against in `kin bench`).
    pub fn compensate_interp(
        &self,
        interpreter: &mut Interpreter,
        state: &State,
        dq: &mut [f64],
    ) -> Result<Compensated, ServoError> {
        let mut engine = compensate::InterpEngine {
            interpreter,
            beta: self.model.beta(),
        };
        compensate::servo(&mut engine, self.model.machine(), &self.options, state, dq)
    }
}

/// `Ok` when every error of a batch (`k` per row) is finite, else the row of the first that
/// is not.
fn rows_finite(k: usize, err: &[f64]) -> Result<(), BatchError> {
    // One addition per value: a NaN or infinity makes the sum so (as may finite values that
    // overflow it, which the search then does not find).
    if err.iter().sum::<f64>().is_finite() {
        return Ok(());
    }
    match err.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        None => Ok(()),
        Some((i, &value)) => Err(BatchError::Row {
            row: i / k.max(1),
            source: EvalError::NotFinite {
                what: "err",
                index: i % k.max(1),
                value,
            },
        }),
    }
}

fn check_finite(what: &'static str, values: &[f64]) -> Result<(), Error> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(Error::NotFinite {
            what,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

fn check_values(what: &'static str, expected: usize, got: usize) -> Result<(), Error> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::Values {
            what,
            expected,
            got,
        })
    }
}

const FORMAT: &str = "kin-model";
const VERSION: u32 = 1;

/// What [`Model::save`] writes.
#[derive(Serialize, Deserialize)]
struct Saved {
    format: String,
    version: u32,
    machine: String,
    source: String,
    params: Vec<String>,
    /// Coefficient names, to check the layout on loading.
    coefficients: Vec<String>,
    /// β in SI, exactly (shortest round-trip decimal).
    beta: Vec<f64>,
    nonlinear: Vec<Named>,
}

#[derive(Serialize, Deserialize)]
struct Named {
    name: String,
    value: f64,
}

/// Owned storage for one observation state (see [`State`]); [`Model::state`] sizes one.
#[derive(Debug, Clone, PartialEq)]
pub struct StateBuf {
    /// Joint positions (m, rad), indexed like the machine's axes.
    pub q: Vec<f64>,
    /// Input values (NaN: not given), indexed like the machine's inputs.
    pub inputs: Vec<f64>,
    /// Lag states (see [`crate::lag`]), indexed like the machine's lags.
    pub lags: Vec<f64>,
    /// Direction of motion per axis: +1, −1 or NaN.
    pub dirs: Vec<f64>,
    /// Time (s).
    pub time: f64,
    /// Tool index, in declaration order.
    pub tool: usize,
    /// A translation replacing the tool's declared offset.
    pub tool_offset: Option<[f64; 3]>,
}

impl StateBuf {
    pub fn get(&self) -> State<'_> {
        State {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: self.time,
            dirs: &self.dirs,
            tool: self.tool,
            tool_offset: self.tool_offset,
        }
    }
}

/// Owned storage for many states, row-major, as the batch calls take them ([`StateRows`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RowsBuf {
    pub q: Vec<f64>,
    pub inputs: Vec<f64>,
    pub lags: Vec<f64>,
    pub time: Vec<f64>,
    pub dirs: Vec<f64>,
    pub tool: Vec<usize>,
    pub tool_offset: Vec<Option<[f64; 3]>>,
}

impl RowsBuf {
    /// Appends one state (its slices must have the machine's sizes for the rows to be evaluated).
    pub fn push(&mut self, s: &State) {
        self.q.extend_from_slice(s.q);
        self.inputs.extend_from_slice(s.inputs);
        self.lags.extend_from_slice(s.lags);
        self.dirs.extend_from_slice(s.dirs);
        self.time.push(s.time);
        self.tool.push(s.tool);
        self.tool_offset.push(s.tool_offset);
    }

    /// Every state of `states`, e.g. of a measurement file or [`States::sample`](crate::states::States::sample).
    pub fn from_states(states: &crate::states::States) -> RowsBuf {
        let mut rows = RowsBuf::default();
        for r in 0..states.len() {
            rows.push(&states.get(r));
        }
        rows
    }

    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    pub fn rows(&self) -> StateRows<'_> {
        StateRows {
            q: &self.q,
            inputs: &self.inputs,
            lags: &self.lags,
            time: &self.time,
            dirs: &self.dirs,
            tool: &self.tool,
            tool_offset: &self.tool_offset,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::states::States;

    const SRC: &str = "machine m {
        task position
        axis X prismatic along x range 0 mm .. 500 mm
        axis C revolute about z continuous
        input T : temperature rise
        tool chain { X moving  C moving  tool t at (0, 0, -100) mm }
        errors {
            X.tx = spline(X, knots 2) + lag(T, tau fit 20 min) * const
            C.rz = fourier(C, harmonics 1..2)
            X.ry = const
        }
    }
    params { X.tx.tau = 25 min }";

    fn assert_send_sync<T: Send + Sync>() {}

    #[test]
    fn a_model_is_send_and_sync() {
        assert_send_sync::<Model>();
        assert_send_sync::<ServoCompensator>();
    }

    #[test]
    fn compile_errors_are_data() {
        let err = Model::compile("machine m { axis X wobbly }").expect_err("does not compile");
        assert!(!err.diagnostics().is_empty());
        assert!(
            err.to_string()
                .starts_with("the source does not compile: error["),
            "{err}"
        );
        let model = Model::compile(SRC).expect("compiles");
        let err = model
            .clone()
            .with_params("params { X.tx[0] = 1 }  junk")
            .expect_err("bad params");
        assert!(matches!(err, Error::Params { .. }), "{err}");
        let err = model
            .with_params("params { X.nope[0] = 1 um }")
            .expect_err("unknown");
        assert_eq!(err.diagnostics().first().map(|d| d.code), Some("E0501"));
    }

    #[test]
    fn params_bind_on_top_and_set_values_are_checked() {
        let mut model = Model::compile(SRC)
            .expect("compiles")
            .with_params("params { X.ry[0] = 3 urad }")
            .expect("binds");
        assert!(
            (model.nonlinear()[0] - 1500.0).abs() < 1e-9,
            "the source's own params: {:?}",
            model.nonlinear()
        );
        let k = model
            .machine()
            .coefficients
            .iter()
            .position(|c| c.name == "X.ry[0]")
            .expect("X.ry");
        assert!((model.beta()[k] - 3e-6).abs() < 1e-18);
        model
            .bind_params("params { X.tx.tau = 30 min }")
            .expect("binds");
        assert!((model.nonlinear()[0] - 1800.0).abs() < 1e-9);
        assert!(
            (model.beta()[k] - 3e-6).abs() < 1e-18,
            "earlier values stay"
        );
        assert_eq!(model.params().len(), 2);
        assert!(matches!(model.set_beta(&[1.0]), Err(Error::Values { .. })));
        let mut nan = model.beta().to_vec();
        if let Some(b) = nan.first_mut() {
            *b = f64::NAN;
            let kept = model.beta().to_vec();
            assert!(matches!(
                model.set_beta(&nan),
                Err(Error::NotFinite { index: 0, .. })
            ));
            assert_eq!(model.beta(), &kept[..], "refused values change nothing");
        }
        assert!(matches!(
            model.set_nonlinear(&[]),
            Err(Error::Values { .. })
        ));
    }

    #[test]
    fn both_engines_and_every_call_agree() {
        let mut model = Model::compile(SRC).expect("compiles");
        let n = model.coefficients();
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64 - 2.5)).collect();
        model.set_beta(&beta).expect("β");
        let states = States::sample(model.machine(), 8, 4);
        let mut jit = model.evaluator();
        let mut interp = model.evaluator_with(Engine::Interp).expect("interpreter");
        let (mut e1, mut e2, mut e3) = ([0.0; 6], [0.0; 6], [0.0; 6]);
        let (mut j1, mut j2) = (vec![0.0; 6 * n], vec![0.0; 6 * n]);
        for r in 0..states.len() {
            let s = states.get(r);
            model.eval(&s, model.beta(), &mut e1).expect("eval");
            model
                .eval_jacobian(&s, model.beta(), &mut e2, &mut j1)
                .expect("eval");
            interp
                .error_and_jacobian(&s, model.beta(), &mut e3, &mut j2)
                .expect("interp");
            assert_eq!(jit.error(&s, model.beta()).expect("jit"), e1);
            for (a, b) in e1.iter().zip(&e3).chain(j1.iter().zip(&j2)) {
                assert!(
                    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-9),
                    "{a} vs {b}"
                );
            }
            let mut nj = vec![0.0; 6 * model.axes()];
            let loc = model.nominal_jacobian(&s, &mut nj).expect("nominal");
            assert!(loc.position.iter().all(|x| x.is_finite()));
        }
        assert!(model.eval(&states.get(0), &beta[1..], &mut e1).is_err());
    }

    #[test]
    fn save_and_load_give_identical_numbers() {
        let mut model = Model::compile(SRC)
            .expect("compiles")
            .with_params("params { X.ry[0] = 3 urad }")
            .expect("binds");
        let n = model.coefficients();
        // Values with all 17 digits, which only an exact round trip keeps.
        let beta: Vec<f64> = (0..n)
            .map(|j| (j as f64 + 1.0).sqrt() * 1.234_567_890_123_456_7e-7_f64 / 3.0)
            .collect();
        model.set_beta(&beta).expect("β");
        model
            .set_nonlinear(&[1_234.567_890_123_456_7 / 7.0])
            .expect("τ");
        let dir = std::env::temp_dir().join(format!("kin-embed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("model.json");
        model.save(&path).expect("saves");
        let loaded = Model::load(&path).expect("loads");
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(loaded.beta(), model.beta());
        assert_eq!(loaded.nonlinear(), model.nonlinear());
        assert_eq!(loaded.source(), model.source());
        assert_eq!(loaded.params(), model.params());
        let states = States::sample(model.machine(), 16, 9);
        let (mut a, mut b) = ([0.0; 6], [0.0; 6]);
        let (mut ja, mut jb) = (vec![0.0; 6 * n], vec![0.0; 6 * n]);
        for r in 0..states.len() {
            model
                .eval_jacobian(&states.get(r), model.beta(), &mut a, &mut ja)
                .expect("eval");
            loaded
                .eval_jacobian(&states.get(r), loaded.beta(), &mut b, &mut jb)
                .expect("eval");
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
            assert!(ja.iter().zip(&jb).all(|(x, y)| x.to_bits() == y.to_bits()));
        }
        assert!(matches!(
            Model::load(&dir.join("missing.json")),
            Err(Error::Io { .. })
        ));
        assert!(matches!(Model::from_json("{}"), Err(Error::Format { .. })));
        let other = model
            .to_json()
            .expect("json")
            .replace("\"version\": 1", "\"version\": 99");
        assert!(matches!(
            Model::from_json(&other),
            Err(Error::Format { .. })
        ));
        // A β that is not finite never gets in, so every model saves.
        assert!(matches!(
            model.set_beta(&vec![f64::NAN; n]),
            Err(Error::NotFinite { .. })
        ));
        assert!(model.to_json().is_ok());
    }

    #[test]
    fn batch_rows_match_single_calls() {
        let model = Model::compile(SRC).expect("compiles");
        let n = model.coefficients();
        let beta = vec![2e-6; n];
        let states = States::sample(model.machine(), 5, 2);
        let buf = RowsBuf::from_states(&states);
        let rows = buf.rows();
        let (mut errs, mut jacs) = (vec![0.0; 6 * rows.len()], vec![0.0; 6 * n * rows.len()]);
        model
            .eval_jacobian_rows(&rows, &beta, &mut errs, &mut jacs)
            .expect("batch");
        let mut only = vec![0.0; 6 * rows.len()];
        model.eval_rows(&rows, &beta, &mut only).expect("batch");
        assert!(only
            .iter()
            .zip(&errs)
            .all(|(a, b)| (a - b).abs() <= 1e-12 * a.abs().max(1e-9)));
        let (mut e, mut j) = ([0.0; 6], vec![0.0; 6 * n]);
        for r in 0..rows.len() {
            model
                .eval_jacobian(&states.get(r), &beta, &mut e, &mut j)
                .expect("eval");
            assert_eq!(&errs[6 * r..6 * r + 6], &e);
            assert_eq!(&jacs[6 * n * r..6 * n * (r + 1)], j.as_slice());
        }
        assert!(model.eval_rows(&rows, &beta, &mut only[1..]).is_err());
    }

    /// A result that overflows is refused, naming the row and the value, by the one-pose calls
    /// and the batches alike, the rows before it evaluated; a flag raised by other code before
    /// a call (the test's own overflow here) is no error.
    #[test]
    fn results_that_are_not_finite_are_refused_and_named() {
        let model = Model::compile(SRC).expect("compiles");
        let n = model.coefficients();
        let axes = model.axes();
        let beta = vec![2e-6; n];
        let states = States::sample(model.machine(), 5, 4);
        let mut buf = RowsBuf::from_states(&states);
        // Row 3 at an absurd X: its spline's values overflow.
        buf.q[3 * axes] = 1e300;
        let rows = buf.rows();
        let not_finite =
            |e: &EvalError| matches!(e, EvalError::NotFinite { value, .. } if !value.is_finite());
        let (mut errs, mut jacs) = (vec![0.0; 6 * rows.len()], vec![0.0; 6 * n * rows.len()]);
        match model.eval_jacobian_rows(&rows, &beta, &mut errs, &mut jacs) {
            Err(BatchError::Row { row: 3, source }) => assert!(not_finite(&source), "{source}"),
            other => panic!("{other:?}"),
        }
        match model.eval_rows(&rows, &beta, &mut errs) {
            Err(BatchError::Row { row: 3, source }) => assert!(not_finite(&source), "{source}"),
            other => panic!("{other:?}"),
        }
        let bad = rows.get(3);
        let (mut e, mut j) = ([0.0; 6], vec![0.0; 6 * n]);
        let refused = model
            .eval_jacobian(&bad, &beta, &mut e, &mut j)
            .expect_err("overflows");
        assert!(not_finite(&refused), "{refused}");
        assert!(refused
            .to_string()
            .contains("too large for double precision"));
        let refused = model.eval(&bad, &beta, &mut e).expect_err("overflows");
        assert!(not_finite(&refused), "{refused}");
        // The Jacobian overflows whatever β: with β = 0 the error is NaN (0·∞) and named.
        let zero = vec![0.0; n];
        assert!(model.eval_jacobian(&bad, &zero, &mut e, &mut j).is_err());

        let good = RowsBuf::from_states(&states);
        let good = good.rows();
        std::hint::black_box(std::hint::black_box(1e300f64) * 1e300);
        model
            .eval_jacobian(&good.get(3), &beta, &mut e, &mut j)
            .expect("a flag of other code is no error");
        assert!(e.iter().chain(&j).all(|v| v.is_finite()));
        std::hint::black_box(std::hint::black_box(1e300f64) * 1e300);
        model
            .eval_jacobian_rows(&good, &beta, &mut errs, &mut jacs)
            .expect("a flag of other code is no error");
    }

    /// The observed batches hold, row by row, the bits of the one-pose observed call (the
    /// error-only batch its values); a buffer sized for six rows is refused for three.
    #[test]
    fn observed_batch_rows_match_single_calls() {
        let model = Model::compile(SRC).expect("compiles");
        let n = model.coefficients();
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * (j as f64 - 2.5)).collect();
        let states = States::sample(model.machine(), 7, 3);
        let buf = RowsBuf::from_states(&states);
        let rows = buf.rows();
        for observed in [
            Observed::POSITION,
            Observed::from_flags([false, true, false, true, false, true]),
        ] {
            let k = observed.rows();
            let mut errs = vec![0.0; k * rows.len()];
            let mut jacs = vec![0.0; k * n * rows.len()];
            model
                .eval_jacobian_rows_observed(&rows, &beta, observed, &mut errs, &mut jacs)
                .expect("batch");
            let mut only = vec![0.0; k * rows.len()];
            model
                .eval_rows_observed(&rows, &beta, observed, &mut only)
                .expect("batch");
            let (mut e, mut j) = (vec![0.0; k], vec![0.0; k * n]);
            for r in 0..rows.len() {
                model
                    .eval_jacobian_observed(&states.get(r), &beta, observed, &mut e, &mut j)
                    .expect("eval");
                assert_eq!(&errs[k * r..k * (r + 1)], e.as_slice());
                assert_eq!(&jacs[k * n * r..k * n * (r + 1)], j.as_slice());
                // The error-only code sums in its own order: the same values to rounding.
                assert!(only[k * r..k * (r + 1)]
                    .iter()
                    .zip(&e)
                    .all(|(a, b)| (a - b).abs() <= 1e-12 * a.abs().max(1e-9)));
            }
            let mut six = vec![0.0; 6 * n * rows.len()];
            assert!(model
                .eval_jacobian_rows_observed(&rows, &beta, observed, &mut errs, &mut six)
                .is_err());
        }
    }
}
