//! The Cranelift JIT: native error and Jacobian functions specialised to one machine.
//!
//! [`compile`] turns a lowered [`Machine`] into three native functions — the tool-location
//! error, the error with its β-Jacobian, and the nominal tool location with its joint
//! Jacobian — that compute what the [interpreter](crate::interp) computes, with every constant
//! of the model folded in and nothing evaluated that the model does not use. The pipeline:
//!
//! 1. `lower`: the IR as expression graphs (`graph`), one per function — kinematics
//!    (eq. 2.35–2.38), the F-matrix columns of the components that carry errors (eq. 2.24–2.28),
//!    the basis values of `kin_compiler::basis` operation for operation, and per coefficient its
//!    six Jacobian entries.
//!    Restricted to the components a data set observes ([`Observed`]: position only for
//!    points without orientation and for lengths), the error functions store only those
//!    rows, and nothing that feeds only the others is emitted.
//! 2. `emit`: each graph as one straight-line Cranelift function, `sin`/`cos`/`%` through the
//!    same `libm` routines the interpreter uses. Past `lower::PIECE` coefficients the error
//!    and Jacobian functions are several such functions called in turn, because the register
//!    allocator's cost grows faster than the length of one function. The functions are
//!    compiled on as many threads as the process has cores (the register allocator is most
//!    of the compile time) and placed in the module in one fixed order, so the code is the
//!    same whatever thread compiled what. The batches of errors
//!    ([`JitModel::error_rows`]) call a second compilation of the error functions that
//!    evaluates two poses a call, one per lane of `f64x2` values, with each pose's bits.
//!
//! # Safety and threads
//!
//! The generated code reads and writes only at offsets fixed at compile time, all inside the
//! buffers whose lengths this module checks before every call; a call allocates nothing and
//! takes no lock — except the first call for a subset of the components other than all six
//! ([`Observed`]), which compiles that subset's code ([`JitModel::prepare`] does it ahead),
//! and the first batch of errors for a subset, which compiles its two-pose code. A
//! [`JitModel`] is `Send + Sync` and cheap to clone: many threads may call it at once, each
//! with its own output buffers (or its own [`JitEvaluator`]).
//!
//! ```
//! # use kin_model::jit;
//! # use kin_model::states::States;
//! let src = "machine m {
//!     task position
//!     axis X prismatic along x range 0 mm .. 500 mm
//!     tool chain { X moving tool t at (0, 0, -100) mm }
//!     errors { X.tx = spline(X, knots 2) }
//! }";
//! let machine = kin_compiler::compile(src).compiled.expect("valid source").machine;
//! let model = jit::compile(&machine).expect("compiles");
//! let states = States::sample(&machine, 1, 7);
//! let beta = vec![1e-6; machine.coefficients.len()];
//! let mut err = [0.0; 6];
//! let mut jac = vec![0.0; 6 * beta.len()];
//! model.error_and_jacobian(&states.get(0), &beta, &[], &mut err, &mut jac).expect("evaluates");
//! ```

mod c_source;
mod emit;
mod flags;
mod graph;
mod lower;
pub mod stream;

use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use cranelift_jit::JITModule;
use kin_compiler::ir::{FrameRef, Machine, Scalar, Var};
use nalgebra::{Matrix3, Vector3};
use thiserror::Error;

use crate::engine::Evaluator;
pub use crate::engine::Observed;
use crate::interp::{var_name, EvalError, State};
use crate::kinematics::{length_direction, length_error, KinematicsError, ToolLocation};
pub use c_source::c_source;
use emit::{Args, RawFn};
use lower::Kind;

/// Why a machine could not be compiled.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum JitError {
    /// The IR refers to something it does not have (a hand-built or corrupted machine).
    #[error("the machine cannot be compiled: {message}")]
    Model { message: String },
    /// Cranelift does not support this host.
    #[error("this host cannot run generated code: {message}")]
    Host { message: String },
    #[error("code generation failed: {message}")]
    Codegen { message: String },
}

/// Why a batch evaluation stopped.
#[derive(Debug, PartialEq, Error)]
pub enum BatchError {
    #[error("{what} holds {got} values, {expected} are needed for {rows} rows")]
    Size {
        what: &'static str,
        rows: usize,
        expected: usize,
        got: usize,
    },
    #[error("row {row}: {source}")]
    Row { row: usize, source: EvalError },
}

/// Many observation states, row-major: row `r` of `q` is `q[r·axes .. (r+1)·axes]`, and so on
/// for `inputs`, `lags` and `dirs`; `time` and `tool` hold one value per row, `tool_offset`
/// one per row or none at all. The number of rows is `time.len()`.
#[derive(Debug, Clone, Copy)]
pub struct StateRows<'a> {
    pub q: &'a [f64],
    pub inputs: &'a [f64],
    pub lags: &'a [f64],
    pub time: &'a [f64],
    pub dirs: &'a [f64],
    pub tool: &'a [usize],
    pub tool_offset: &'a [Option<[f64; 3]>],
}

impl<'a> StateRows<'a> {
    pub fn len(&self) -> usize {
        self.time.len()
    }

    pub fn is_empty(&self) -> bool {
        self.time.is_empty()
    }

    /// Rows `start..end` (clamped to the rows there are): a block of a larger batch, evaluated
    /// on its own into outputs sized for the block.
    pub fn rows(&self, start: usize, end: usize) -> StateRows<'a> {
        let n = self.len();
        let (start, end) = (start.min(n), end.min(n));
        let end = end.max(start);
        let part = |v: &'a [f64]| -> &'a [f64] {
            let width = v.len().checked_div(n).unwrap_or(0);
            v.get(start * width..end * width).unwrap_or(&[])
        };
        StateRows {
            q: part(self.q),
            inputs: part(self.inputs),
            lags: part(self.lags),
            time: self.time.get(start..end).unwrap_or(&[]),
            dirs: part(self.dirs),
            tool: self.tool.get(start..end).unwrap_or(&[]),
            tool_offset: self.tool_offset.get(start..end).unwrap_or(&[]),
        }
    }

    /// Row `r`; a row outside the arrays gives empty slices, which the evaluation rejects.
    pub fn get(&self, r: usize) -> State<'a> {
        let row = |v: &'a [f64], width: usize| -> &'a [f64] {
            v.get(r * width..(r + 1) * width).unwrap_or(&[])
        };
        let width = |v: &[f64]| {
            if self.is_empty() {
                0
            } else {
                v.len() / self.len()
            }
        };
        State {
            q: row(self.q, width(self.q)),
            inputs: row(self.inputs, width(self.inputs)),
            lags: row(self.lags, width(self.lags)),
            time: self.time.get(r).copied().unwrap_or(f64::NAN),
            dirs: row(self.dirs, width(self.dirs)),
            tool: self.tool.get(r).copied().unwrap_or(usize::MAX),
            tool_offset: self.tool_offset.get(r).copied().flatten(),
        }
    }
}

/// Compiles `machine` to native code. See the module docs.
pub fn compile(machine: &Machine) -> Result<JitModel, JitError> {
    let start = Instant::now();
    let tools = tool_transforms(machine);
    let graphs = graphs(machine, &tools)?;
    let emitted = emit::compile(&graphs.named(), emit::Width::Pose, None)?;
    // The functions come back in the order `named` gives: the error pieces, the Jacobian
    // pieces, the nominal function.
    let (e, j) = (graphs.error.len(), graphs.jacobian.len());
    let pointers = emitted.functions.as_slice();
    let (Some(error), Some(jacobian), Some(&nominal), true) = (
        pointers.get(..e),
        pointers.get(e..e + j),
        pointers.get(e + j),
        pointers.len() == e + j + 1,
    ) else {
        // SAFETY: no pointer into the module survives this branch.
        unsafe { emitted.module.free_memory() };
        return Err(JitError::Codegen {
            message: "missing function".into(),
        });
    };
    // SAFETY: each pointer is the entry of a function just compiled with the signature
    // `fn(pointer)` and no result in the host's default (C) calling convention, which is
    // `RawFn`. It stays valid while `module` lives, and `module` lives as long as the `Inner`
    // that holds these pointers (its `Drop` frees the code).
    let raw = |p: &*const u8| unsafe { std::mem::transmute::<*const u8, RawFn>(*p) };
    let (error, jacobian, nominal) = (
        error.iter().map(raw).collect(),
        jacobian.iter().map(raw).collect(),
        raw(&nominal),
    );
    let mut inner = Inner {
        machine: machine.clone(),
        error,
        jacobian,
        nominal,
        tools_finite: tools.iter().flatten().all(|v| v.is_finite()),
        tools,
        used: (0..machine.tools.len())
            .map(|t| used_vars(machine, t))
            .collect(),
        nodes: graphs
            .all()
            .map(|g| g.live().iter().filter(|l| **l).count())
            .sum(),
        compile_time: Duration::ZERO,
        observed: std::array::from_fn(|_| OnceLock::new()),
        pairs: std::array::from_fn(|_| OnceLock::new()),
        module: Mutex::new(Some(emitted.module)),
    };
    inner.compile_time = start.elapsed();
    Ok(JitModel {
        inner: Arc::new(inner),
    })
}

/// The Cranelift IR of the three functions of `machine` and the machine code each became, for
/// tests and for looking at what the code generator does (no command prints it: a test or a
/// scratch program calls this).
pub fn dump_clif(machine: &Machine) -> Result<String, JitError> {
    let graphs = graphs(machine, &tool_transforms(machine))?;
    let mut text = String::new();
    let emitted = emit::compile(&graphs.named(), emit::Width::Pose, Some(&mut text))?;
    // SAFETY: only the text is kept; no pointer into the module was taken.
    unsafe { emitted.module.free_memory() };
    Ok(text)
}

/// The graphs of the error, error-and-Jacobian and nominal functions; the first two in pieces
/// past `lower::PIECE` coefficients, to be called in order.
struct Graphs {
    error: Vec<graph::Graph>,
    jacobian: Vec<graph::Graph>,
    nominal: graph::Graph,
}

impl Graphs {
    fn all(&self) -> impl Iterator<Item = &graph::Graph> {
        self.error
            .iter()
            .chain(&self.jacobian)
            .chain(std::iter::once(&self.nominal))
    }

    /// Each graph with its function's name: `error`, `error_jacobian` and `nominal`, pieces
    /// numbered from 1 after a dot (`error.2`).
    fn named(&self) -> Vec<(String, &graph::Graph)> {
        fn pieces<'g>(name: &str, graphs: &'g [graph::Graph]) -> Vec<(String, &'g graph::Graph)> {
            if let [one] = graphs {
                return vec![(name.to_string(), one)];
            }
            graphs
                .iter()
                .enumerate()
                .map(|(i, g)| (format!("{name}.{}", i + 1), g))
                .collect()
        }
        let mut out = pieces("error", &self.error);
        out.extend(pieces("error_jacobian", &self.jacobian));
        out.push(("nominal".to_string(), &self.nominal));
        out
    }
}

fn graphs(machine: &Machine, tools: &[[f64; 12]]) -> Result<Graphs, JitError> {
    lower::validate(machine)?;
    let rotation = common_rotation(tools);
    let mut nominal = lower::build(machine, Kind::Nominal, rotation, Observed::FULL);
    Ok(Graphs {
        error: lower::build(machine, Kind::Error, rotation, Observed::FULL),
        jacobian: lower::build(machine, Kind::Jacobian, rotation, Observed::FULL),
        nominal: nominal.pop().unwrap_or_default(),
    })
}

/// The error and (with `jacobian`) error-and-Jacobian functions of `machine` restricted to
/// `observed` (`lower::build`), compiled into a module of their own, for one pose a call or
/// two.
fn compile_observed(
    machine: &Machine,
    tools: &[[f64; 12]],
    observed: Observed,
    width: emit::Width,
    jacobian: bool,
) -> Option<Code> {
    let rotation = common_rotation(tools);
    let error = lower::build(machine, Kind::Error, rotation, observed);
    let jacobian = if jacobian {
        lower::build(machine, Kind::Jacobian, rotation, observed)
    } else {
        Vec::new()
    };
    let named: Vec<(String, &graph::Graph)> = error
        .iter()
        .enumerate()
        .map(|(i, g)| (format!("error.{observed}.{}", i + 1), g))
        .chain(
            jacobian
                .iter()
                .enumerate()
                .map(|(i, g)| (format!("error_jacobian.{observed}.{}", i + 1), g)),
        )
        .collect();
    let emitted = emit::compile(&named, width, None).ok()?;
    let e = error.len();
    if emitted.functions.len() != e + jacobian.len() {
        // SAFETY: no pointer into the module survives this branch.
        unsafe { emitted.module.free_memory() };
        return None;
    }
    // SAFETY: as in `compile`: each pointer is a function just compiled with the signature
    // `RawFn`, valid while the module lives, which the returned `Code` owns.
    let raw = |p: &*const u8| unsafe { std::mem::transmute::<*const u8, RawFn>(*p) };
    let (error, jacobian) = emitted.functions.split_at(e);
    Some(Code {
        error: error.iter().map(raw).collect(),
        jacobian: jacobian.iter().map(raw).collect(),
        module: Mutex::new(Some(emitted.module)),
    })
}

/// The error functions of one subset of the components, with the module that owns them.
struct Code {
    error: Vec<RawFn>,
    jacobian: Vec<RawFn>,
    /// Touched only when dropped (see `Inner::module`).
    module: Mutex<Option<JITModule>>,
}

impl Drop for Code {
    fn drop(&mut self) {
        let module = match self.module.get_mut() {
            Ok(m) => m.take(),
            Err(poisoned) => poisoned.into_inner().take(),
        };
        if let Some(module) = module {
            // SAFETY: the pointers live only in this `Code`, which lives in an `Inner`; every
            // call borrows that `Inner`, so none is running once it is dropped.
            unsafe { module.free_memory() };
        }
    }
}

/// A compiled machine. Cloning shares the code.
#[derive(Clone)]
pub struct JitModel {
    inner: Arc<Inner>,
}

struct Inner {
    machine: Machine,
    /// The error and error-and-Jacobian functions, each one or several pieces called in turn.
    error: Vec<RawFn>,
    jacobian: Vec<RawFn>,
    nominal: RawFn,
    /// Per tool: offset rotation (row-major) and translation, as the generated code reads them.
    tools: Vec<[f64; 12]>,
    /// Whether every tool's transform is finite: known once rather than looked at per call (a
    /// fold over 12 values, 73 instructions of every call). One flag for all tools, not one
    /// per tool beside `tools`: where it is false (a transform out of range), a call looks at
    /// its outputs, which is never wrong, only slower.
    tools_finite: bool,
    /// Per tool: the state variables the acting error models read, in the interpreter's order
    /// of evaluation, so that a missing one is reported as the interpreter reports it.
    used: Vec<Vec<Var>>,
    nodes: usize,
    compile_time: Duration,
    /// Per subset of the components ([`Observed::index`]): its own error functions, compiled
    /// at the first call that asks for them (`None`: the compilation failed, and the full
    /// functions serve instead). All six use `error` and `jacobian` above.
    observed: [OnceLock<Option<Code>>; 64],
    /// Per subset (all six included), the error functions for two poses a call
    /// ([`emit::Width::Pair`], no Jacobian functions), compiled at the first batch of errors
    /// that asks for them; `None` where that failed, and the batch then calls one pose at a
    /// time. The error-and-Jacobian batches stay at one pose a call: their two-pose code was
    /// measured slower (spec/performance.md).
    pairs: [OnceLock<Option<Code>>; 64],
    /// Owns the code; touched only when dropped. The mutex makes the model `Sync` (the module
    /// itself is only `Send`); no call ever locks it.
    module: Mutex<Option<JITModule>>,
}

impl Inner {
    /// The code of `observed` held in `cells` (one per subset of the components), compiled by
    /// [`compile_observed`] at the first call; `None` when that failed.
    fn code<'a>(
        &'a self,
        cells: &'a [OnceLock<Option<Code>>; 64],
        observed: Observed,
        width: emit::Width,
        jacobian: bool,
    ) -> Option<&'a Code> {
        cells
            .get(observed.index())?
            .get_or_init(|| compile_observed(&self.machine, &self.tools, observed, width, jacobian))
            .as_ref()
    }
}

impl Drop for Inner {
    fn drop(&mut self) {
        let module = match self.module.get_mut() {
            Ok(m) => m.take(),
            Err(poisoned) => poisoned.into_inner().take(),
        };
        if let Some(module) = module {
            // SAFETY: the function pointers live only in this `Inner`; every call borrows it
            // (through `&JitModel` or a `JitEvaluator`'s clone), so none is running and none
            // can follow once it is dropped.
            unsafe { module.free_memory() };
        }
    }
}

impl std::fmt::Debug for JitModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JitModel")
            .field("machine", &self.inner.machine.name)
            .field("nodes", &self.inner.nodes)
            .field("compile_time", &self.inner.compile_time)
            .finish_non_exhaustive()
    }
}

/// Which generated function to call, and so which buffers it needs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Function {
    Error,
    Jacobian,
    Nominal,
}

/// Outputs of one call: error and position, or position and rotation (see `lower::Kind`).
type Out = [f64; 12];

impl JitModel {
    pub fn machine(&self) -> &Machine {
        &self.inner.machine
    }

    /// Wall time of [`compile`], from the IR to callable functions.
    pub fn compile_time(&self) -> Duration {
        self.inner.compile_time
    }

    /// Number of graph nodes emitted over the three functions (a measure of code size).
    pub fn nodes(&self) -> usize {
        self.inner.nodes
    }

    /// An [`Evaluator`] holding the machine's non-linear parameter values and the scratch a
    /// length row needs; one per thread.
    pub fn evaluator(&self) -> JitEvaluator {
        let n = self.inner.machine.coefficients.len();
        JitEvaluator {
            model: self.clone(),
            nonlinear: self
                .inner
                .machine
                .nonlinear
                .iter()
                .map(|p| p.value)
                .collect(),
            jac1: vec![0.0; 6 * n],
            jac2: vec![0.0; 6 * n],
            joint: vec![0.0; 6 * self.inner.machine.axes.len()],
        }
    }

    /// The tool-location error at `state` (task sign, eq. 2.24/2.31/2.34) for coefficients
    /// `beta` and non-linear parameter values `nonlinear` (indexed like `Machine::nonlinear`).
    pub fn error(
        &self,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
    ) -> Result<[f64; 6], EvalError> {
        let mut out = [0.0; 12];
        self.call(
            Function::Error,
            state,
            beta,
            nonlinear,
            Observed::FULL,
            &mut out,
            &mut [],
        )?;
        Ok(first6(&out))
    }

    /// The error and its Jacobian with respect to β, 6 × n row-major (row r is error component
    /// r): `error = fixed + jac·β`.
    pub fn error_and_jacobian(
        &self,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.jacobian(
            state,
            beta,
            nonlinear,
            Observed::FULL,
            err,
            jac,
            Outputs::AsComputed,
        )
    }

    /// The nominal location of the tool in wr and its Jacobian with respect to the joint
    /// positions: `jac[6j..6j+6]` is `(dp/dq_j, ω_j)` in wr axes, as
    /// `Interpreter::nominal_jacobian` gives `out[j]`.
    pub fn nominal_jacobian(
        &self,
        state: &State,
        jac: &mut [f64],
    ) -> Result<ToolLocation, EvalError> {
        let mut out = [0.0; 12];
        self.call(
            Function::Nominal,
            state,
            &[],
            &[],
            Observed::FULL,
            &mut out,
            jac,
        )?;
        Ok(ToolLocation {
            position: Vector3::new(out[0], out[1], out[2]),
            rotation: Matrix3::new(
                out[3], out[4], out[5], out[6], out[7], out[8], out[9], out[10], out[11],
            ),
        })
    }

    /// [`JitModel::error_and_jacobian`] restricted to the `observed` components (see
    /// [`Evaluator::observed_error_and_jacobian`]): `err` holds `observed.rows()` values and
    /// `jac` `observed.rows() × n`, row k that of the k-th observed component. Code for the
    /// subset is compiled at the first call that asks for it; the values equal the full
    /// evaluation's bit for bit.
    pub fn observed_error_and_jacobian(
        &self,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.jacobian(
            state,
            beta,
            nonlinear,
            observed,
            err,
            jac,
            Outputs::AsComputed,
        )
    }

    /// [`JitModel::observed_error_and_jacobian`], refusing results that are not finite when
    /// `outputs` says so.
    #[allow(clippy::too_many_arguments)] // the evaluation's arguments, one each
    pub(crate) fn jacobian(
        &self,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
        outputs: Outputs,
    ) -> Result<(), EvalError> {
        buffer("the observed error", observed.rows(), err.len())?;
        let mut out = [0.0; 12];
        let read_finite = self.call(
            Function::Jacobian,
            state,
            beta,
            nonlinear,
            observed,
            &mut out,
            jac,
        )?;
        pick(&out, observed, err);
        if outputs == Outputs::Finite {
            finite(flags::quiet() && read_finite, err, jac)?;
        }
        Ok(())
    }

    /// Compiles the code of `observed` now rather than at its first call (so that a timing
    /// leaves the compilation out): its one-pose functions (for all six, [`compile`] compiled
    /// them) and the two-pose error functions of the batches.
    pub fn prepare(&self, observed: Observed) {
        let _ = self.functions(Function::Error, observed);
        let _ = self.pair_error_functions(observed);
    }

    /// [`JitModel::error`] over many rows: `err` holds 6 values per row. Two poses a call
    /// (one per vector lane, each pose's bits), the first call compiling that code.
    pub fn error_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        nonlinear: &[f64],
        err: &mut [f64],
    ) -> Result<(), BatchError> {
        self.observed_error_rows(rows, beta, nonlinear, Observed::FULL, err)
    }

    /// [`JitModel::error_rows`] restricted to the `observed` components: `err` holds
    /// `observed.rows()` values per row.
    pub fn observed_error_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        err: &mut [f64],
    ) -> Result<(), BatchError> {
        self.check_rows(rows)?;
        let k = observed.rows();
        check_len("the error rows", rows.len(), k * rows.len(), err.len())?;
        let [mut out, mut other] = [[0.0; 12]; 2];
        // A subset of no component has empty rows; chunks of 0 are not allowed.
        let mut chunks = err.chunks_exact_mut(k.max(1));
        let mut r = 0;
        while r < rows.len() {
            // Two poses a call where both pass their checks, else one at a time (which
            // reports the row that fails).
            let pair = r + 1 < rows.len()
                && self.error_pair(
                    [&rows.get(r), &rows.get(r + 1)],
                    beta,
                    nonlinear,
                    observed,
                    [&mut out, &mut other],
                );
            if pair {
                if k > 0 {
                    pick(&out, observed, chunks.next().unwrap_or(&mut []));
                    pick(&other, observed, chunks.next().unwrap_or(&mut []));
                }
                r += 2;
                continue;
            }
            self.call(
                Function::Error,
                &rows.get(r),
                beta,
                nonlinear,
                observed,
                &mut out,
                &mut [],
            )
            .map_err(|source| BatchError::Row { row: r, source })?;
            if k > 0 {
                pick(&out, observed, chunks.next().unwrap_or(&mut []));
            }
            r += 1;
        }
        Ok(())
    }

    /// [`JitModel::error_and_jacobian`] over many rows: `err` holds 6 values per row and `jac`
    /// one 6 × n block per row, rows one after the other — the design-matrix rows of a fit.
    pub fn error_and_jacobian_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        nonlinear: &[f64],
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), BatchError> {
        self.observed_error_and_jacobian_rows(rows, beta, nonlinear, Observed::FULL, err, jac)
    }

    /// [`JitModel::error_and_jacobian_rows`] restricted to the `observed` components: `err`
    /// holds `observed.rows()` values per row and `jac` one `observed.rows() × n` block per
    /// row, so nothing is computed or stored that the data set does not observe.
    ///
    /// When the blocks add up to more than a cache holds, each pose's block is computed into
    /// a scratch block that stays in the first-level cache and then written out with
    /// streaming (non-temporal) stores: the destination's lines are written without first
    /// being read into the cache, which halves the memory traffic of a store-bound loop
    /// (see `stream`). A small destination is written directly.
    pub fn observed_error_and_jacobian_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), BatchError> {
        self.jacobian_rows(
            rows,
            beta,
            nonlinear,
            observed,
            err,
            jac,
            Outputs::AsComputed,
        )
    }

    /// [`JitModel::observed_error_and_jacobian_rows`], refusing the first row whose results
    /// are not finite when `outputs` says so: each row's error values as they come, the
    /// Jacobian's by the flags after the last row (every row's values looked at only if a flag
    /// went up or a row read an infinity).
    #[allow(clippy::too_many_arguments)] // the evaluation's arguments, one each
    pub(crate) fn jacobian_rows(
        &self,
        rows: &StateRows,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
        outputs: Outputs,
    ) -> Result<(), BatchError> {
        self.check_rows(rows)?;
        let k = observed.rows();
        let block = k * self.inner.machine.coefficients.len();
        check_len("the error rows", rows.len(), k * rows.len(), err.len())?;
        check_len(
            "the Jacobian rows",
            rows.len(),
            block * rows.len(),
            jac.len(),
        )?;
        let mut out = [0.0; 12];
        let streaming = stream::worth_it(jac.len());
        let prefetch = !streaming && stream::beyond_cache(jac.len());
        let mut scratch = vec![0.0; if streaming { block } else { 0 }];
        // Whether every row read finite values, and the first row whose error is not finite:
        // the Jacobian's entries are known finite when, besides, no flag went up (`flags`),
        // tested once for the whole batch.
        let (mut reads, mut bad) = (true, None);
        // Empty blocks (no coefficient, or no component): chunks of 0 are not allowed.
        let mut blocks = jac.chunks_exact_mut(block.max(1));
        let mut errs = err.chunks_exact_mut(k.max(1));
        for r in 0..rows.len() {
            let j: &mut [f64] = if block == 0 {
                &mut []
            } else {
                blocks.next().unwrap_or(&mut [])
            };
            if prefetch {
                // The next pose's block, requested for writing while this pose is evaluated.
                stream::prefetch_for_writing(j.as_ptr_range().end, block);
            }
            let target: &mut [f64] = if streaming { &mut scratch } else { j };
            let read_finite = self
                .call(
                    Function::Jacobian,
                    &rows.get(r),
                    beta,
                    nonlinear,
                    observed,
                    &mut out,
                    target,
                )
                .map_err(|source| BatchError::Row { row: r, source })?;
            if streaming {
                stream::copy(j, &scratch);
            }
            let e = if k > 0 {
                errs.next().unwrap_or(&mut [])
            } else {
                &mut []
            };
            pick(&out, observed, e);
            if outputs == Outputs::Finite {
                reads &= read_finite;
                if finite(true, e, &[]).is_err() {
                    bad = Some(r);
                    break;
                }
            }
        }
        if streaming {
            stream::fence();
        }
        if outputs == Outputs::Finite && (bad.is_some() || !(flags::quiet() && reads)) {
            // The rows' values, up to the one whose error is not finite: the first row
            // holding a value that is not is named.
            let last = bad.map_or(rows.len(), |r| r + 1);
            for r in 0..last {
                let (e, j) = (
                    err.get(r * k..(r + 1) * k).unwrap_or(&[]),
                    jac.get(r * block..(r + 1) * block).unwrap_or(&[]),
                );
                finite(false, e, j).map_err(|source| BatchError::Row { row: r, source })?;
            }
        }
        Ok(())
    }

    /// The functions of `f` for the `observed` components; `None` when that subset's code
    /// could not be compiled (the caller then uses the full functions).
    fn functions(&self, f: Function, observed: Observed) -> Option<&[RawFn]> {
        let inner = &*self.inner;
        if f == Function::Nominal {
            return Some(std::slice::from_ref(&inner.nominal));
        }
        let (error, jacobian) = if observed == Observed::FULL {
            (inner.error.as_slice(), inner.jacobian.as_slice())
        } else {
            let code = inner.code(&inner.observed, observed, emit::Width::Pose, true)?;
            (code.error.as_slice(), code.jacobian.as_slice())
        };
        Some(if f == Function::Error {
            error
        } else {
            jacobian
        })
    }

    fn check_rows(&self, rows: &StateRows) -> Result<(), BatchError> {
        let m = &self.inner.machine;
        let n = rows.len();
        check_len("q", n, n * m.axes.len(), rows.q.len())?;
        check_len("inputs", n, n * m.inputs.len(), rows.inputs.len())?;
        check_len("lags", n, n * m.lags.len(), rows.lags.len())?;
        check_len("dirs", n, n * m.axes.len(), rows.dirs.len())?;
        check_len("tool", n, n, rows.tool.len())?;
        if !rows.tool_offset.is_empty() {
            check_len("tool_offset", n, n, rows.tool_offset.len())?;
        }
        Ok(())
    }

    /// Checks everything a call of `f` for `state` relies on but the choice of code: the
    /// state's sizes, the buffers (`jac_len` values of Jacobian), the tool, and that no
    /// variable the tool's models read is missing. The selected tool's transform as the
    /// generated code reads it, and whether every value the code reads is finite.
    fn check(
        &self,
        f: Function,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        jac_len: usize,
    ) -> Result<Checked, EvalError> {
        let inner = &*self.inner;
        let m = &inner.machine;
        let sizes = [
            ("axis positions", m.axes.len(), state.q.len()),
            ("inputs", m.inputs.len(), state.inputs.len()),
            ("lag states", m.lags.len(), state.lags.len()),
            ("directions", m.axes.len(), state.dirs.len()),
        ];
        // The four sizes in one test; which one is wrong only when one is.
        if sizes.iter().fold(false, |bad, &(_, e, g)| bad | (e != g)) {
            let (what, expected, got) = sizes
                .into_iter()
                .find(|&(_, e, g)| e != g)
                .unwrap_or(sizes[0]);
            return Err(EvalError::StateSize {
                what,
                expected,
                got,
            });
        }
        let n = m.coefficients.len();
        if f != Function::Nominal {
            buffer("the β", n, beta.len())?;
            buffer(
                "the non-linear parameter",
                m.nonlinear.len(),
                nonlinear.len(),
            )?;
        }
        match f {
            Function::Error => {}
            Function::Jacobian => buffer("the Jacobian", observed.rows() * n, jac_len)?,
            Function::Nominal => buffer("the joint Jacobian", 6 * m.axes.len(), jac_len)?,
        }
        let Some(tool) = inner.tools.get(state.tool) else {
            return Err(KinematicsError::ToolIndex {
                index: state.tool,
                count: m.tools.len(),
            }
            .into());
        };
        let mut tool_tf = *tool;
        let mut tool_finite = inner.tools_finite;
        if let Some(t) = state.tool_offset {
            // S_tl = Trans(t)·R: the override replaces the translation and keeps the rotation.
            tool_tf[9..].copy_from_slice(&t);
            tool_finite = tool_tf.iter().all(|v| v.is_finite());
        }
        // Which variable is missing is looked up only when some value is NaN: the lookup
        // walks the variables the tool's models read, a branch on each one's kind, and cost
        // about 5 % of a position-only evaluation; the scan of every value has no branch.
        let scan = scan(state);
        if f != Function::Nominal && scan.nan {
            for &v in inner.used.get(state.tool).map_or(&[][..], |u| u.as_slice()) {
                if value(v, state).is_none_or(f64::is_nan) {
                    return Err(EvalError::Missing {
                        name: var_name(v, m),
                    });
                }
            }
        }
        Ok(Checked {
            finite: scan.finite && tool_finite,
            tool_tf,
        })
    }

    /// Checks everything a call relies on and calls: `true` when every value the code read
    /// was finite (see [`Checked::finite`]). With [`JitModel::error_pair`], the only place
    /// generated code is entered.
    #[allow(clippy::too_many_arguments)] // the generated functions' arguments, one each
    fn call(
        &self,
        f: Function,
        state: &State,
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        out: &mut Out,
        jac: &mut [f64],
    ) -> Result<bool, EvalError> {
        let Checked { tool_tf, finite } =
            self.check(f, state, beta, nonlinear, observed, jac.len())?;
        let Some(functions) = self.functions(f, observed) else {
            // The subset's code could not be compiled: the full functions, then its rows.
            let n = self.inner.machine.coefficients.len();
            let mut full = vec![0.0; if f == Function::Jacobian { 6 * n } else { 0 }];
            self.call(f, state, beta, nonlinear, Observed::FULL, out, &mut full)?;
            for (row, c) in observed.components().enumerate() {
                if let (Some(dst), Some(src)) = (
                    jac.get_mut(row * n..(row + 1) * n),
                    full.get(c * n..(c + 1) * n),
                ) {
                    dst.copy_from_slice(src);
                }
            }
            return Ok(finite);
        };
        let args = args(state, beta, nonlinear, &tool_tf, out, jac);
        // SAFETY: each function was compiled from this machine by `compile` and is alive while
        // `self` is. It reads `q`, `dirs` at axis indices, `inputs`, `lags` at their indices,
        // `beta` below n, `nonlinear` below the parameter count and `tool_tf` below 12 — all
        // checked by `lower::validate` against the machine and by `check` against the slices
        // (β and the parameters only for the error functions, which alone read them). It
        // writes `out` below 12 and `jac` below k·n (error functions of k observed components,
        // `lower::build`) or 6·axes (nominal), the lengths checked by `check`; the error
        // function writes no `jac`. Every slice outlives the call and the outputs are
        // exclusively borrowed, so nothing else touches them meanwhile. The pieces of one
        // function are called in order on the same arguments: a piece reads `out[9]` only
        // after the piece before it wrote it (`lower::errors`).
        clean_vector_state();
        for function in functions {
            // SAFETY: as above, for each piece.
            unsafe { function(&args) };
        }
        Ok(finite)
    }

    /// [`JitModel::call`] of the error functions for two poses at once, by the two-pose code
    /// ([`emit::Width::Pair`]), with the same results bit for bit. `false`, having called
    /// nothing, when that code is not there or either pose fails a check: the caller then
    /// calls one pose at a time, which reports the failure.
    fn error_pair(
        &self,
        states: [&State; 2],
        beta: &[f64],
        nonlinear: &[f64],
        observed: Observed,
        outs: [&mut Out; 2],
    ) -> bool {
        let [sa, sb] = states;
        let [oa, ob] = outs;
        let check = |s| self.check(Function::Error, s, beta, nonlinear, observed, 0);
        let (Ok(Checked { tool_tf: ta, .. }), Ok(Checked { tool_tf: tb, .. })) =
            (check(sa), check(sb))
        else {
            return false;
        };
        let Some(functions) = self.pair_error_functions(observed) else {
            return false;
        };
        let args = [
            args(sa, beta, nonlinear, &ta, oa, &mut []),
            args(sb, beta, nonlinear, &tb, ob, &mut []),
        ];
        // SAFETY: as in `call`, for each pose: the two-pose functions were compiled from this
        // machine's graphs as the one-pose ones (`compile_observed`) and read and write, for
        // lane `l`, only through `args[l]` — at the offsets the one-pose code uses, which
        // `check` bounded for that pose's buffers — and `beta`, `nonlinear` through `args[0]`
        // (the same slices in both). The two poses' outputs are distinct exclusive borrows;
        // the error functions write no `jac`.
        clean_vector_state();
        for function in functions {
            // SAFETY: as above; the argument points at the two consecutive blocks the code
            // reads.
            unsafe { function(args.as_ptr()) };
        }
        true
    }

    /// The two-pose error functions for `observed`, compiled at the first call; `None` when
    /// they could not be.
    fn pair_error_functions(&self, observed: Observed) -> Option<&[RawFn]> {
        let inner = &*self.inner;
        let code = inner.code(&inner.pairs, observed, emit::Width::Pair, false)?;
        Some(code.error.as_slice())
    }
}

/// The argument block of one pose's call (see `emit::Args`).
fn args(
    state: &State,
    beta: &[f64],
    nonlinear: &[f64],
    tool_tf: &[f64; 12],
    out: &mut Out,
    jac: &mut [f64],
) -> Args {
    Args {
        q: state.q.as_ptr(),
        inputs: state.inputs.as_ptr(),
        lags: state.lags.as_ptr(),
        dirs: state.dirs.as_ptr(),
        beta: beta.as_ptr(),
        nonlinear: nonlinear.as_ptr(),
        tool_tf: tool_tf.as_ptr(),
        out: out.as_mut_ptr(),
        jac: jac.as_mut_ptr(),
        time: state.time,
        tool: state.tool as u64,
    }
}

/// Zeroes the upper halves of the vector registers before generated code runs. The matrix
/// kernels of faer run AVX-512 code; when they leave those halves dirty, every legacy-SSE
/// instruction after them (the generated code's scalar arithmetic, libm's) waits on a merge
/// with the stale bits. Inside a fit, where kernel calls and evaluations alternate, that made
/// each call about 60 times slower (25 µs instead of 0.4 µs a pose on the 5-axis example, the
/// JIT slower than the interpreter); `vzeroupper` costs about a cycle.
#[inline]
fn clean_vector_state() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the CPU has AVX, checked just above.
        unsafe { zero_upper() }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn zero_upper() {
    std::arch::x86_64::_mm256_zeroupper();
}

/// What an evaluation hands back when a result is not a finite number (a state or β too
/// large for double precision): the values as computed (the fits, which test their rows
/// themselves), or an error naming the first such value (the embedding API, `Model`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outputs {
    AsComputed,
    Finite,
}

/// `Ok` when every value of `err` and `jac` is finite, else the first that is not. With
/// `jac_finite` (the call read finite values and raised no flag, see `flags`) the Jacobian is
/// known to be finite — its entries do not depend on β, which the error values do — and only
/// the error values are looked at, by one addition each (a NaN or infinity makes the sum so);
/// each value is looked at only when that quick test fails.
pub(crate) fn finite(jac_finite: bool, err: &[f64], jac: &[f64]) -> Result<(), EvalError> {
    if jac_finite && err.iter().sum::<f64>().is_finite() {
        return Ok(());
    }
    for (what, values) in [("err", err), ("jac", jac)] {
        if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(EvalError::NotFinite { what, index, value });
        }
    }
    Ok(())
}

fn first6(out: &Out) -> [f64; 6] {
    [out[0], out[1], out[2], out[3], out[4], out[5]]
}

/// The observed components of the error in `out` (where the functions leave component `c` at
/// `out[c]`), in order, into `err`.
fn pick(out: &Out, observed: Observed, err: &mut [f64]) {
    // Without a branch on the components: each value goes to the next row, which moves on
    // only past an observed component, so an unobserved value is overwritten by the next
    // observed one or falls beyond the rows. `err` holds `observed.rows()` values.
    let mut row = 0;
    for (c, &value) in out.iter().take(6).enumerate() {
        if let Some(slot) = err.get_mut(row) {
            *slot = value;
        }
        row += usize::from(observed.contains(c));
    }
}

fn buffer(what: &'static str, expected: usize, got: usize) -> Result<(), EvalError> {
    if expected == got {
        Ok(())
    } else {
        Err(EvalError::Buffer {
            what,
            expected,
            got,
        })
    }
}

fn check_len(
    what: &'static str,
    rows: usize,
    expected: usize,
    got: usize,
) -> Result<(), BatchError> {
    if expected == got {
        Ok(())
    } else {
        Err(BatchError::Size {
            what,
            rows,
            expected,
            got,
        })
    }
}

/// What a call checks the generated code's inputs for (see [`JitModel::check`]).
struct Checked {
    /// The selected tool's transform as the code reads it.
    tool_tf: [f64; 12],
    /// Every value the code may read is finite: the joint positions (the kinematics reads them
    /// all) and the tool's transform, and no infinity among the state's other values — a NaN
    /// there is in a variable no model of the tool reads, as `check` refuses the others. The
    /// non-linear parameters were checked when set; β matters only to the error values.
    finite: bool,
}

/// What [`scan`] finds among the state's values.
struct Scan {
    /// Some value is NaN.
    nan: bool,
    /// The joint positions are finite and no other value is infinite.
    finite: bool,
}

/// The state's values looked at in one pass: every value finite ([`State::all_finite`]), the
/// common answer, or else each value looked at.
fn scan(s: &State) -> Scan {
    if s.all_finite() {
        return Scan {
            nan: false,
            finite: true,
        };
    }
    scan_each(s)
}

/// [`scan`] value by value, when some value is not finite.
#[cold]
#[inline(never)]
fn scan_each(s: &State) -> Scan {
    let (q_nan, q_finite) = s.q.iter().fold((false, true), |(nan, finite), v| {
        (nan | v.is_nan(), finite & v.is_finite())
    });
    let (nan, infinite) = s.inputs.iter().chain(s.lags).chain(s.dirs).fold(
        (q_nan | s.time.is_nan(), s.time.is_infinite()),
        |(nan, inf), v| (nan | v.is_nan(), inf | v.is_infinite()),
    );
    Scan {
        nan,
        finite: q_finite & !infinite,
    }
}

fn value(v: Var, s: &State) -> Option<f64> {
    match v {
        Var::Axis(i) => s.q.get(i).copied(),
        Var::Input(i) => s.inputs.get(i).copied(),
        Var::Lag(i) => s.lags.get(i).copied(),
        Var::Time => Some(s.time),
        Var::Direction(i) => s.dirs.get(i).copied(),
    }
}

/// The variables read by the error models acting for `tool`, first occurrence first, in the
/// order the interpreter evaluates them (models, terms, the scale left to right, factors).
fn used_vars(m: &Machine, tool: usize) -> Vec<Var> {
    fn walk(s: &Scalar, out: &mut Vec<Var>) {
        match s {
            Scalar::Num(_) => {}
            Scalar::Var(v) => out.push(*v),
            Scalar::Neg(a) | Scalar::Sin(a) | Scalar::Cos(a) => walk(a, out),
            Scalar::Add(a, b) | Scalar::Sub(a, b) | Scalar::Mul(a, b) | Scalar::Div(a, b) => {
                walk(a, out);
                walk(b, out);
            }
        }
    }
    let mut all = Vec::new();
    for model in &m.errors {
        if matches!(model.frame, FrameRef::ToolEnd(Some(i)) if i != tool) {
            continue;
        }
        for term in &model.terms {
            walk(&term.scale, &mut all);
            all.extend(term.factors.iter().map(|f| f.var));
        }
    }
    let mut out: Vec<Var> = Vec::new();
    for v in all {
        if !out.contains(&v) {
            out.push(v);
        }
    }
    out
}

/// Every tool's offset as the generated code reads it.
fn tool_transforms(m: &Machine) -> Vec<[f64; 12]> {
    m.tools
        .iter()
        .map(|t| {
            let (r, p) = lower::shape_transform(&t.offset);
            let mut tf = [0.0; 12];
            for (i, row) in r.iter().enumerate() {
                for (j, v) in row.iter().enumerate() {
                    tf[3 * i + j] = *v;
                }
            }
            tf[9..].copy_from_slice(&p);
            tf
        })
        .collect()
}

/// The tools' rotation when they all share it bit for bit (usually the identity): it is then
/// folded into the code instead of loaded.
fn common_rotation(tools: &[[f64; 12]]) -> Option<[[f64; 3]; 3]> {
    let first = tools.first()?;
    let same = tools.iter().all(|t| {
        t[..9]
            .iter()
            .zip(&first[..9])
            .all(|(a, b)| a.to_bits() == b.to_bits())
    });
    same.then(|| [0, 1, 2].map(|i| [0, 1, 2].map(|j| first[3 * i + j])))
}

/// The JIT behind the [`Evaluator`] interface: holds the non-linear parameter values and the
/// scratch of a length row, so no call allocates. Not shared between threads: make one each.
#[derive(Debug, Clone)]
pub struct JitEvaluator {
    model: JitModel,
    nonlinear: Vec<f64>,
    jac1: Vec<f64>,
    jac2: Vec<f64>,
    /// Scratch for the joint Jacobian of `nominal_position`.
    joint: Vec<f64>,
}

impl JitEvaluator {
    pub fn model(&self) -> &JitModel {
        &self.model
    }

    pub fn nonlinear(&self) -> &[f64] {
        &self.nonlinear
    }

    pub fn nominal_jacobian(
        &self,
        state: &State,
        jac: &mut [f64],
    ) -> Result<ToolLocation, EvalError> {
        self.model.nominal_jacobian(state, jac)
    }
}

impl Evaluator for JitEvaluator {
    fn machine(&self) -> &Machine {
        self.model.machine()
    }

    fn kind(&self) -> Option<crate::engine::Engine> {
        Some(crate::engine::Engine::Jit)
    }

    fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), EvalError> {
        buffer(
            "the non-linear parameter",
            self.nonlinear.len(),
            values.len(),
        )?;
        self.nonlinear.copy_from_slice(values);
        Ok(())
    }

    fn error(&mut self, state: &State, beta: &[f64]) -> Result<[f64; 6], EvalError> {
        self.model.error(state, beta, &self.nonlinear)
    }

    fn error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.model
            .error_and_jacobian(state, beta, &self.nonlinear, err, jac)
    }

    fn observed_error_and_jacobian(
        &mut self,
        state: &State,
        beta: &[f64],
        observed: Observed,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        self.model
            .observed_error_and_jacobian(state, beta, &self.nonlinear, observed, err, jac)
    }

    /// Eq. 4.5: `dL = u·(Δp₂ − Δp₁)` and its row `uᵀ(J₂ − J₁)` over the position rows, from
    /// two calls of the position-only Jacobian function (which also returns the nominal
    /// positions for `u`): the rotation rows a length does not read are never computed.
    fn length_and_row(
        &mut self,
        s1: &State,
        s2: &State,
        beta: &[f64],
        row: &mut [f64],
    ) -> Result<f64, EvalError> {
        let n = self.model.machine().coefficients.len();
        buffer("the length row", n, row.len())?;
        let (mut o1, mut o2) = ([0.0; 12], [0.0; 12]);
        let rows = Observed::POSITION.rows() * n;
        let (jac1, jac2) = (
            self.jac1.get_mut(..rows).unwrap_or(&mut []),
            self.jac2.get_mut(..rows).unwrap_or(&mut []),
        );
        self.model.call(
            Function::Jacobian,
            s1,
            beta,
            &self.nonlinear,
            Observed::POSITION,
            &mut o1,
            jac1,
        )?;
        self.model.call(
            Function::Jacobian,
            s2,
            beta,
            &self.nonlinear,
            Observed::POSITION,
            &mut o2,
            jac2,
        )?;
        let p1 = Vector3::new(o1[6], o1[7], o1[8]);
        let p2 = Vector3::new(o2[6], o2[7], o2[8]);
        let u = length_direction(&p1, &p2)?;
        for (j, slot) in row.iter_mut().enumerate() {
            let at = |jac: &[f64], r: usize| jac.get(r * n + j).copied().unwrap_or(0.0);
            *slot = (0..3)
                .map(|r| u[r] * (at(&self.jac2, r) - at(&self.jac1, r)))
                .sum();
        }
        let dp1 = Vector3::new(o1[0], o1[1], o1[2]);
        let dp2 = Vector3::new(o2[0], o2[1], o2[2]);
        Ok(length_error(&u, &dp1, &dp2))
    }

    fn nominal_position(&mut self, state: &State) -> Result<[f64; 3], EvalError> {
        let location = self.model.nominal_jacobian(state, &mut self.joint)?;
        Ok(location.position.into())
    }

    /// The compiled code is shared (`JitModel` is reference-counted): a fork copies only the
    /// values and the scratch.
    fn fork(&self) -> Option<Box<dyn Evaluator + Send + '_>> {
        Some(Box::new(self.clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embed::RowsBuf;
    use crate::states::States;

    pub(super) fn example(name: &str) -> Machine {
        let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
        let src = std::fs::read_to_string(&path).expect("example");
        kin_compiler::compile(&src)
            .compiled
            .expect("compiles")
            .machine
    }

    pub(super) const EXAMPLES: [&str; 5] = [
        "milling_5axis",
        "bridge_cmm",
        "robot_6axis",
        "xy_table",
        "bench_200",
    ];

    /// A machine past `lower::PIECE` coefficients, whose functions come in pieces: six Fourier
    /// series of 200 coefficients on a rotary table, and a straightness on the linear axis.
    pub(super) fn large_machine() -> Machine {
        let errors: String = ["tx", "ty", "tz", "rx", "ry", "rz"]
            .iter()
            .map(|e| format!("        C.{e} = fourier(C, harmonics 1..100)\n"))
            .collect();
        let source = format!(
            "machine pieces {{
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    axis C revolute about z continuous
    workpiece chain {{ C fixed  workpiece }}
    tool chain {{ X moving  tool a at (0, 0, -50) mm }}
    errors {{
{errors}        X.ty = straightness(X, knots 10)
    }}
}}"
        );
        let large = kin_compiler::compile(&source)
            .compiled
            .expect("compiles")
            .machine;
        assert!(large.coefficients.len() > lower::PIECE);
        large
    }

    /// Every Jacobian entry is stored by exactly one effect of one piece: the code generator
    /// stores the constant zeros ahead of everything else (`emit::Emitter::zero_entries`), which
    /// is the same only if nothing else writes those places.
    #[test]
    fn each_jacobian_entry_is_written_once() {
        let mut machines: Vec<(String, Machine)> = EXAMPLES
            .iter()
            .map(|name| (name.to_string(), example(name)))
            .collect();
        machines.push(("large".into(), large_machine()));
        let subsets = [
            Observed::FULL,
            Observed::from_flags([true, true, true, false, false, false]),
            Observed::from_flags([false, true, false, true, false, true]),
        ];
        for (name, m) in &machines {
            let n = m.coefficients.len();
            let pieces = lower::build(m, Kind::Jacobian, None, Observed::FULL);
            if name == "large" {
                assert!(pieces.len() > 1, "{name}: one piece");
            }
            for observed in subsets {
                let mut writes = vec![0u32; observed.rows() * n];
                for g in lower::build(m, Kind::Jacobian, None, observed) {
                    for effect in g.effects() {
                        let at: &[u32] = match *effect {
                            graph::Effect::Store(graph::Dst::Jac, i, _) => &[i],
                            graph::Effect::Pair(graph::Dst::Jac, i, ..) => &[i, i + 1],
                            graph::Effect::AddTo(graph::Dst::Jac, ..) => {
                                panic!("{name}: a sum kept in the Jacobian")
                            }
                            _ => &[],
                        };
                        for &i in at {
                            writes[i as usize] += 1;
                        }
                    }
                }
                let wrong = writes.iter().position(|&w| w != 1);
                assert_eq!(
                    wrong.map(|i| (i, writes[i])),
                    None,
                    "{name} {observed:?}: (entry, times written)"
                );
            }
        }
    }

    struct Setup {
        m: Machine,
        model: JitModel,
        rows: RowsBuf,
        beta: Vec<f64>,
        nl: Vec<f64>,
    }

    /// An example compiled, `count` sampled poses whose continuous axes go round by turns —
    /// inside the first turn, outside it, on its ends, negative — and small coefficients.
    fn setup(name: &str, count: usize, seed: u64) -> Setup {
        let turn = std::f64::consts::TAU;
        let m = example(name);
        let model = compile(&m).expect("compiles");
        let n = m.coefficients.len();
        let mut rows = RowsBuf::from_states(&States::sample(&m, count, seed));
        let axes = m.axes.len();
        for (a, axis) in m.axes.iter().enumerate() {
            if !axis.continuous {
                continue;
            }
            for (r, q) in rows.q.iter_mut().skip(a).step_by(axes).enumerate() {
                *q = match r % 5 {
                    0 => *q + 3.0 * turn,
                    1 => -*q,
                    2 => 0.0,
                    3 => turn,
                    _ => *q,
                };
            }
        }
        let beta = (0..n).map(|j| 1e-6 * (j as f64 + 0.5).sin()).collect();
        let nl = m.nonlinear.iter().map(|p| p.value).collect();
        Setup {
            m,
            model,
            rows,
            beta,
            nl,
        }
    }

    /// The generated code raises none of the flags `flags` watches on the examples' sampled
    /// poses (continuous axes past a turn among them): the embedding API's test of its
    /// outputs takes the quick way there, instead of looking at every value.
    #[test]
    fn the_examples_raise_no_flag() {
        for name in EXAMPLES {
            let Setup {
                m,
                model,
                rows,
                beta,
                nl,
            } = setup(name, 200, 11);
            let n = m.coefficients.len();
            let states = rows.rows();
            for observed in [Observed::FULL, Observed::POSITION] {
                let mut jac = vec![0.0; observed.rows() * n];
                flags::quiet();
                for r in 0..states.len() {
                    let mut out = [0.0; 12];
                    let read_finite = model
                        .call(
                            Function::Jacobian,
                            &states.get(r),
                            &beta,
                            &nl,
                            observed,
                            &mut out,
                            &mut jac,
                        )
                        .expect("evaluates");
                    assert!(flags::quiet(), "{name}, {observed}, row {r}");
                    assert!(read_finite, "{name}, row {r}");
                }
            }
        }
    }

    /// Each pose of a two-pose call gets the one-pose code's bits: every example, all six
    /// components and the position alone, the error (as the batches call it) and the error
    /// with its Jacobian (compiled here: the batches do not use it), on pairs whose poses take
    /// different branches — other tools, other directions, a continuous axis inside its first
    /// turn in one lane and outside (or exactly on its ends) in the other.
    #[test]
    fn two_poses_a_call_give_each_pose_the_bits_of_one() {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for name in EXAMPLES {
            let Setup {
                m,
                model,
                rows,
                beta,
                nl,
            } = setup(name, 40, 7);
            let n = m.coefficients.len();
            let states = rows.rows();
            for observed in [Observed::FULL, Observed::POSITION] {
                let k = observed.rows();
                let jacobians =
                    compile_observed(&m, &model.inner.tools, observed, emit::Width::Pair, true)
                        .expect("two-pose code");
                for r in 0..states.len() - 1 {
                    let (a, b) = (states.get(r), states.get(r + 1));
                    let what = format!("{name}, {observed}, rows {r}, {}", r + 1);
                    let one = |f, s: &State| {
                        let (mut out, mut jac) = ([f64::NAN; 12], vec![f64::NAN; k * n]);
                        let len = if f == Function::Jacobian { k * n } else { 0 };
                        model
                            .call(f, s, &beta, &nl, observed, &mut out, &mut jac[..len])
                            .expect("one pose");
                        (out, jac)
                    };
                    // The error, as the batches call it: the outputs an error function leaves
                    // (the error, its position).
                    let (mut oa, mut ob) = ([f64::NAN; 12], [f64::NAN; 12]);
                    assert!(model.error_pair([&a, &b], &beta, &nl, observed, [&mut oa, &mut ob]));
                    for (s, o) in [(&a, &oa), (&b, &ob)] {
                        let (out, _) = one(Function::Error, s);
                        assert_eq!(bits(&o[..9]), bits(&out[..9]), "error, {what}");
                    }
                    // The error and its Jacobian.
                    let (mut oa, mut ob) = ([f64::NAN; 12], [f64::NAN; 12]);
                    let (mut ja, mut jb) = (vec![f64::NAN; k * n], vec![f64::NAN; k * n]);
                    let check = |s| {
                        model
                            .check(Function::Jacobian, s, &beta, &nl, observed, k * n)
                            .expect("checks")
                    };
                    let (ta, tb) = (check(&a), check(&b));
                    let two = [
                        args(&a, &beta, &nl, &ta.tool_tf, &mut oa, &mut ja),
                        args(&b, &beta, &nl, &tb.tool_tf, &mut ob, &mut jb),
                    ];
                    clean_vector_state();
                    for f in &jacobians.jacobian {
                        // SAFETY: as in `error_pair`: both poses checked against the buffers,
                        // each `k·n` long as the Jacobian of `observed` needs.
                        unsafe { f(two.as_ptr()) };
                    }
                    for (s, o, j) in [(&a, &oa, &ja), (&b, &ob, &jb)] {
                        let (out, jac) = one(Function::Jacobian, s);
                        assert_eq!(bits(&o[..9]), bits(&out[..9]), "Jacobian's error, {what}");
                        assert_eq!(bits(j), bits(&jac), "Jacobian, {what}");
                    }
                }
            }
        }
    }

    /// A pose that fails its checks makes the pair call nothing, so that one-pose calls
    /// report it.
    #[test]
    fn a_pair_with_a_missing_value_is_left_to_one_pose_calls() {
        let m = example("milling_5axis");
        let model = compile(&m).expect("compiles");
        let n = m.coefficients.len();
        let mut rows = RowsBuf::from_states(&States::sample(&m, 2, 3));
        if let Some(q) = rows.q.get_mut(m.axes.len()) {
            *q = f64::NAN;
        }
        let states = rows.rows();
        let beta = vec![0.0; n];
        let nl: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let (mut oa, mut ob) = ([0.0; 12], [0.0; 12]);
        assert!(!model.error_pair(
            [&states.get(0), &states.get(1)],
            &beta,
            &nl,
            Observed::FULL,
            [&mut oa, &mut ob],
        ));
        assert!(
            oa.iter().chain(&ob).all(|v| *v == 0.0),
            "nothing was written"
        );
        let mut err = vec![0.0; 12];
        assert!(matches!(
            model.error_rows(&states, &beta, &nl, &mut err),
            Err(BatchError::Row { row: 1, .. })
        ));
    }
}
