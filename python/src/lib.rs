//! The native part of the `kin` Python package (`kin._kin`): a compiled model evaluated on numpy
//! arrays, the streaming least-squares triangle with its TSQR merge, and the fit, diagnosis and
//! simulation of the runtime with their results as JSON documents, which `kin/__init__.py`
//! turns into Python objects and pandas DataFrames.
//!
//! Evaluation reads the caller's arrays in place and writes into the caller's output arrays
//! (or into one array it allocates), with the GIL released: threads evaluating one model scale
//! with the cores. Every error is a `kin.KinError` subclass carrying what locates it.

use std::path::{Path, PathBuf};

use kin_compiler::Diagnostic;
use kin_data::data::{self, Observations, ReadError, ReadOptions};
use kin_diagnose as diagnose;
use kin_estimate::fit::{self, merge, report, DataSet, Reduced, Solver, StreamingQr};
use kin_model::embed::Error as ModelError;
use kin_model::interp::State;
use kin_model::jit::{BatchError, StateRows};
use kin_model::Model;
use numpy::ndarray::{Dimension, Ix1, Ix2};
use numpy::{
    PyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

create_exception!(
    kin,
    KinError,
    PyException,
    "Base class of every error kin raises. Attributes: `message`, and where known `code`, \
     `path`, `line`, `column`, `row`."
);
create_exception!(
    kin,
    CompileError,
    KinError,
    "A .kin source or parameter text does not compile: `code` (e.g. E0101), `message`, `line` \
     and `column` of the first error; `diagnostics` lists every one."
);
create_exception!(
    kin,
    DataError,
    KinError,
    "A measurement file is wrong: `path`, and `line` and `column` of its first problem; \
     `problems` lists each (at most 20)."
);
create_exception!(
    kin,
    EvalError,
    KinError,
    "A state cannot be evaluated (a value the model uses is NaN, a tool index out of range, \
     arrays of the wrong shape): `row` is the state's index."
);
create_exception!(
    kin,
    FitError,
    KinError,
    "The data cannot determine the model (rank-deficient, too few rows) or a fit failed."
);

/// Where an error is, as the exception's attributes.
#[derive(Default)]
struct Place {
    code: Option<String>,
    path: Option<String>,
    line: Option<usize>,
    column: Option<usize>,
    row: Option<usize>,
}

fn raise<E: pyo3::PyTypeInfo>(py: Python<'_>, message: String, place: Place) -> PyErr {
    let err = PyErr::new::<E, _>(message.clone());
    let value = err.value(py);
    // Setting an attribute on a fresh exception instance cannot fail in practice; should it,
    // the exception still carries its message.
    let _ = value.setattr("message", message);
    let _ = value.setattr("code", place.code);
    let _ = value.setattr("path", place.path);
    let _ = value.setattr("line", place.line);
    let _ = value.setattr("column", place.column);
    let _ = value.setattr("row", place.row);
    err
}

fn kin_error(py: Python<'_>, message: impl std::fmt::Display) -> PyErr {
    raise::<KinError>(py, message.to_string(), Place::default())
}

/// 1-based line and column (in characters) of a byte offset.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// A compile or params error: the first error diagnostic located in `text`, every one listed.
fn compile_error(py: Python<'_>, text: &str, what: &str, diagnostics: &[Diagnostic]) -> PyErr {
    let list = PyList::empty(py);
    let mut first: Option<(String, String, usize, usize)> = None;
    for d in diagnostics {
        let (line, column) = line_column(text, d.primary_span().start);
        let item = PyDict::new(py);
        let severity = if d.is_error() { "error" } else { "warning" };
        let _ = item.set_item("severity", severity);
        let _ = item.set_item("code", d.code);
        let _ = item.set_item("message", &d.message);
        let _ = item.set_item("line", line);
        let _ = item.set_item("column", column);
        let _ = item.set_item("help", d.help.clone());
        let _ = list.append(item);
        if first.is_none() && d.is_error() {
            first = Some((d.code.to_string(), d.message.clone(), line, column));
        }
    }
    let (code, message, line, column) =
        first.unwrap_or_else(|| (String::new(), "no diagnostic".into(), 0, 0));
    let err = raise::<CompileError>(
        py,
        format!("{what}:{line}:{column}: error[{code}]: {message}"),
        Place {
            code: Some(code),
            line: Some(line),
            column: Some(column),
            ..Place::default()
        },
    );
    let _ = err.value(py).setattr("message", message);
    let _ = err.value(py).setattr("diagnostics", list);
    err
}

fn model_error(py: Python<'_>, e: ModelError, source: &str, params: Option<&str>) -> PyErr {
    match &e {
        ModelError::Compile { diagnostics } => compile_error(py, source, "source", diagnostics),
        ModelError::Params { diagnostics } => {
            compile_error(py, params.unwrap_or(source), "params", diagnostics)
        }
        ModelError::Io { path, .. } => raise::<KinError>(
            py,
            e.to_string(),
            Place {
                path: Some(path.display().to_string()),
                ..Place::default()
            },
        ),
        _ => kin_error(py, e),
    }
}

fn data_error(py: Python<'_>, e: ReadError) -> PyErr {
    match &e {
        ReadError::Invalid { path, problems, .. } => {
            // The first problem's place, as the reader gives it (no column for a whole row's).
            let (line, column) = problems
                .first()
                .and_then(|p| p.location())
                .map_or((None, None), |(line, column)| (Some(line), column));
            let list: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
            let err = raise::<DataError>(
                py,
                e.to_string(),
                Place {
                    path: Some(path.display().to_string()),
                    line,
                    column,
                    ..Place::default()
                },
            );
            let _ = err.value(py).setattr("problems", list);
            err
        }
        ReadError::Io { path, .. } | ReadError::TooLarge { path, .. } => raise::<KinError>(
            py,
            e.to_string(),
            Place {
                path: Some(path.display().to_string()),
                ..Place::default()
            },
        ),
    }
}

/// A state batch, borrowed from the caller's arrays: row `r` of each is state `r`.
struct Batch<'a> {
    rows: usize,
    q: &'a [f64],
    inputs: Option<&'a [f64]>,
    time: Option<&'a [f64]>,
    dirs: Option<&'a [f64]>,
    tool: usize,
}

/// The per-row scratch of a batch: NaN for what the caller does not give. Sized by the
/// machine, never by the number of rows.
struct Scratch {
    inputs: Vec<f64>,
    lags: Vec<f64>,
    dirs: Vec<f64>,
}

/// Rows `start..end` of a row-major array of `width` columns the caller gave, if given.
fn pick(given: Option<&[f64]>, width: usize, start: usize, end: usize) -> Option<&[f64]> {
    given.and_then(|v| v.get(start * width..end * width))
}

/// Rows per call of the model's batch functions ([`Batch::blocks`]): a call's own setup is
/// nothing beside a thousand rows, and the scratch standing in for what the caller does not give
/// stays a few kilobytes whatever the batch's size.
const BLOCK: usize = 1024;

impl Batch<'_> {
    /// Calls `f(start, rows)` for the rows in blocks of [`BLOCK`], each block's rows `start ..`
    /// of the batch, with the model's batch functions (the error alone two poses a call, each
    /// pose's bits those of one call; large Jacobians written with streaming stores) until one
    /// fails; returns that row (in the whole batch) and its message, as [`Batch::each`] does.
    fn blocks(
        &self,
        model: &Model,
        mut f: impl FnMut(usize, &StateRows) -> Result<(), BatchError>,
    ) -> Result<(), (usize, String)> {
        let m = model.machine();
        let (na, ni, nl) = (m.axes.len(), m.inputs.len(), m.lags.len());
        let nan = |n: usize| vec![f64::NAN; n];
        let inputs = nan(if self.inputs.is_some() { 0 } else { BLOCK * ni });
        let dirs = nan(if self.dirs.is_some() { 0 } else { BLOCK * na });
        let time = nan(if self.time.is_some() { 0 } else { BLOCK });
        let lags = nan(BLOCK * nl);
        let tools = vec![self.tool; BLOCK];
        let mut start = 0;
        while start < self.rows {
            let end = (start + BLOCK).min(self.rows);
            let b = end - start;
            let rows = StateRows {
                q: self.q.get(start * na..end * na).unwrap_or(&[]),
                inputs: pick(self.inputs, ni, start, end)
                    .unwrap_or(inputs.get(..b * ni).unwrap_or(&[])),
                lags: lags.get(..b * nl).unwrap_or(&[]),
                time: pick(self.time, 1, start, end).unwrap_or(time.get(..b).unwrap_or(&[])),
                dirs: pick(self.dirs, na, start, end).unwrap_or(dirs.get(..b * na).unwrap_or(&[])),
                tool: tools.get(..b).unwrap_or(&[]),
                tool_offset: &[],
            };
            f(start, &rows).map_err(|e| match e {
                BatchError::Row { row, source } => (start + row, source.to_string()),
                other => (start, other.to_string()),
            })?;
            start = end;
        }
        Ok(())
    }

    /// Calls `f(r, state)` for every row until one fails; returns that row and its message.
    fn each(
        &self,
        model: &Model,
        mut f: impl FnMut(usize, &State) -> Result<(), String>,
    ) -> Result<(), (usize, String)> {
        let m = model.machine();
        let (na, ni) = (m.axes.len(), m.inputs.len());
        let scratch = Scratch {
            inputs: vec![f64::NAN; ni],
            lags: vec![f64::NAN; m.lags.len()],
            dirs: vec![f64::NAN; na],
        };
        for r in 0..self.rows {
            let q = self.q.get(r * na..(r + 1) * na).unwrap_or(&[]);
            let inputs = match self.inputs {
                Some(v) => v.get(r * ni..(r + 1) * ni).unwrap_or(&[]),
                None => &scratch.inputs,
            };
            let dirs = match self.dirs {
                Some(v) => v.get(r * na..(r + 1) * na).unwrap_or(&[]),
                None => &scratch.dirs,
            };
            let time = self
                .time
                .and_then(|t| t.get(r).copied())
                .unwrap_or(f64::NAN);
            let state = State {
                q,
                inputs,
                lags: &scratch.lags,
                time,
                dirs,
                tool: self.tool,
                tool_offset: None,
            };
            f(r, &state).map_err(|e| (r, e))?;
        }
        Ok(())
    }
}

fn eval_error(py: Python<'_>, (row, message): (usize, String)) -> PyErr {
    raise::<EvalError>(
        py,
        format!("state {row}: {message}"),
        Place {
            row: Some(row),
            ..Place::default()
        },
    )
}

fn shape_error(py: Python<'_>, message: String) -> PyErr {
    raise::<EvalError>(py, message, Place::default())
}

/// A float64 array argument in any form a numpy user passes: a C-contiguous float64 array as
/// it is (read in place, no copy); anything else — a list, integers, float32, a Fortran-ordered
/// or strided array (what `DataFrame.to_numpy()` returns) — converted by
/// `numpy.ascontiguousarray(x, dtype=float64)`, so that rows are read as rows and every array
/// argument goes through the same conversion.
struct Floats<'py, D: Dimension>(PyReadonlyArray<'py, f64, D>);

type Floats1<'py> = Floats<'py, Ix1>;
type Floats2<'py> = Floats<'py, Ix2>;

impl<'a, 'py, D: Dimension> FromPyObject<'a, 'py> for Floats<'py, D> {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        let py = obj.py();
        let kwargs = PyDict::new(py);
        kwargs.set_item("dtype", "float64")?;
        let converted =
            py.import("numpy")?
                .call_method("ascontiguousarray", (obj,), Some(&kwargs))?;
        let dims = converted
            .getattr("ndim")
            .and_then(|n| n.extract::<usize>())
            .unwrap_or(0);
        let array = converted.cast_into::<PyArray<f64, D>>().map_err(|_| {
            shape_error(
                py,
                format!(
                    "expected a {}-dimensional array of numbers, got {dims} dimension{}",
                    D::NDIM.unwrap_or(0),
                    if dims == 1 { "" } else { "s" }
                ),
            )
        })?;
        Ok(Floats(array.readonly()))
    }
}

impl<'py, D: Dimension> std::ops::Deref for Floats<'py, D> {
    type Target = PyReadonlyArray<'py, f64, D>;

    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

fn contiguous<'a, D: Dimension>(
    py: Python<'_>,
    what: &str,
    a: &'a PyReadonlyArray<'_, f64, D>,
) -> PyResult<&'a [f64]> {
    let refuse = || {
        shape_error(
            py,
            format!("`{what}` must be C-contiguous (numpy.ascontiguousarray makes it so)"),
        )
    };
    // `as_slice` accepts any contiguous array, a Fortran-ordered one too (what
    // `DataFrame.to_numpy()` returns), whose memory is column after column: read as rows it
    // would give wrong numbers without a word.
    if !a.is_c_contiguous() {
        return Err(refuse());
    }
    a.as_slice().map_err(|_| refuse())
}

/// An output array given by the caller: its shape must be `shape`; else a new one.
fn output<'py, D: numpy::ndarray::Dimension>(
    py: Python<'py>,
    what: &str,
    given: Option<Bound<'py, numpy::PyArray<f64, D>>>,
    shape: &[usize],
    make: impl FnOnce() -> Bound<'py, numpy::PyArray<f64, D>>,
) -> PyResult<Bound<'py, numpy::PyArray<f64, D>>> {
    match given {
        Some(a) => {
            if a.shape() != shape {
                return Err(shape_error(
                    py,
                    format!("`{what}` has shape {:?}, {shape:?} is needed", a.shape()),
                ));
            }
            if !a.is_c_contiguous() {
                return Err(shape_error(py, format!("`{what}` must be C-contiguous")));
            }
            Ok(a)
        }
        None => Ok(make()),
    }
}

/// `eval_jacobian`'s result: the errors (N, 6) and the β-Jacobians (N, 6, coefficients).
type ErrorsAndJacobians<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray3<f64>>);

/// A compiled `.kin` model with bound parameter values (immutable: `with_params` and
/// `with_beta` return new models). Quantities are SI: metres, radians, seconds, kelvin.
///
/// States are given as a float64 C-contiguous array of shape (N, axes), the joint positions in
/// the order of `axes`; `inputs` (N, len(inputs)), `time` (N,) and `dirs` (N, axes: +1, −1 or
/// NaN) are optional. Outputs are written into `out=` arrays when given (no allocation).
#[pyclass(name = "Model", module = "kin", frozen)]
struct PyModel {
    model: Model,
}

impl PyModel {
    fn batch<'a>(
        &self,
        py: Python<'_>,
        states: &'a Floats2<'_>,
        inputs: &'a Option<Floats2<'_>>,
        time: &'a Option<Floats1<'_>>,
        dirs: &'a Option<Floats2<'_>>,
        tool: usize,
    ) -> PyResult<Batch<'a>> {
        let m = self.model.machine();
        let (na, ni) = (m.axes.len(), m.inputs.len());
        let shape = states.shape();
        let rows = shape.first().copied().unwrap_or(0);
        if shape.get(1) != Some(&na) {
            return Err(shape_error(
                py,
                format!(
                    "`states` has shape {shape:?}; this machine needs (N, {na}): the axes {}",
                    m.axes
                        .iter()
                        .map(|a| a.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        let q = contiguous(py, "states", states)?;
        let inputs = match inputs {
            Some(a) => {
                if a.shape() != [rows, ni] {
                    return Err(shape_error(
                        py,
                        format!(
                            "`inputs` has shape {:?}, ({rows}, {ni}) is needed",
                            a.shape()
                        ),
                    ));
                }
                Some(contiguous(py, "inputs", a)?)
            }
            None => None,
        };
        let time = match time {
            Some(a) => {
                if a.shape() != [rows] {
                    return Err(shape_error(
                        py,
                        format!("`time` has shape {:?}, ({rows},) is needed", a.shape()),
                    ));
                }
                Some(contiguous(py, "time", a)?)
            }
            None => None,
        };
        let dirs = match dirs {
            Some(a) => {
                if a.shape() != [rows, na] {
                    return Err(shape_error(
                        py,
                        format!("`dirs` has shape {:?}, ({rows}, {na}) is needed", a.shape()),
                    ));
                }
                Some(contiguous(py, "dirs", a)?)
            }
            None => None,
        };
        if tool >= m.tools.len() {
            return Err(shape_error(
                py,
                format!("tool {tool}: the machine has {} tools", m.tools.len()),
            ));
        }
        Ok(Batch {
            rows,
            q,
            inputs,
            time,
            dirs,
            tool,
        })
    }
}

#[pymethods]
impl PyModel {
    /// Compiles a `.kin` source (a `machine`, optionally followed by `params`), then binds the
    /// optional `params` text. Raises `CompileError` with the code and location of the first
    /// error.
    #[staticmethod]
    #[pyo3(signature = (source, params=None))]
    fn compile(py: Python<'_>, source: &str, params: Option<&str>) -> PyResult<PyModel> {
        let model = Model::compile(source).map_err(|e| model_error(py, e, source, None))?;
        let model = match params {
            Some(p) => model
                .with_params(p)
                .map_err(|e| model_error(py, e, source, Some(p)))?,
            None => model,
        };
        Ok(PyModel { model })
    }

    /// Compiles the `.kin` file at `path` (and binds the parameter file `params`, e.g. a fit's
    /// FIT.params, when given).
    #[staticmethod]
    #[pyo3(signature = (path, params=None))]
    fn from_file(py: Python<'_>, path: PathBuf, params: Option<PathBuf>) -> PyResult<PyModel> {
        let read = |p: &Path| {
            std::fs::read_to_string(p).map_err(|e| {
                raise::<KinError>(
                    py,
                    format!("cannot read `{}`: {e}", p.display()),
                    Place {
                        path: Some(p.display().to_string()),
                        ..Place::default()
                    },
                )
            })
        };
        let source = read(&path)?;
        let params = params.as_deref().map(read).transpose()?;
        PyModel::compile(py, &source, params.as_deref()).inspect_err(|e| {
            // Name the file the located error is in.
            let _ = e.value(py).setattr("path", path.display().to_string());
        })
    }

    /// This model with a parameter text (`params { … }`) bound after its own.
    fn with_params(&self, py: Python<'_>, params: &str) -> PyResult<PyModel> {
        let model = self
            .model
            .clone()
            .with_params(params)
            .map_err(|e| model_error(py, e, self.model.source(), Some(params)))?;
        Ok(PyModel { model })
    }

    /// This model with β replaced (SI, in the order of `coefficients`).
    fn with_beta(&self, py: Python<'_>, beta: Floats1<'_>) -> PyResult<PyModel> {
        let mut model = self.model.clone();
        let beta = contiguous(py, "beta", &beta)?;
        model.set_beta(beta).map_err(|e| kin_error(py, e))?;
        Ok(PyModel { model })
    }

    /// The machine's name.
    #[getter]
    fn name(&self) -> String {
        self.model.machine().name.clone()
    }

    /// The axes, in the order of the columns of `states`.
    #[getter]
    fn axes(&self) -> Vec<String> {
        self.model
            .machine()
            .axes
            .iter()
            .map(|a| a.name.clone())
            .collect()
    }

    /// The inputs (temperatures, loads …), in the order of the columns of `inputs`.
    #[getter]
    fn inputs(&self) -> Vec<String> {
        self.model
            .machine()
            .inputs
            .iter()
            .map(|a| a.name.clone())
            .collect()
    }

    /// The tools, by index.
    #[getter]
    fn tools(&self) -> Vec<String> {
        self.model
            .machine()
            .tools
            .iter()
            .map(|t| t.name.clone())
            .collect()
    }

    /// The coefficients' names (`X.tx[0]` …), in the order of β and of the Jacobian's columns.
    #[getter]
    fn coefficients(&self) -> Vec<String> {
        self.model
            .machine()
            .coefficients
            .iter()
            .map(|c| c.name.clone())
            .collect()
    }

    /// The bound β (SI), a copy.
    #[getter]
    fn beta<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.model.beta())
    }

    /// The source text.
    #[getter]
    fn source(&self) -> String {
        self.model.source().to_string()
    }

    /// The warnings the compiler gave, as `line:column: warning[CODE]: message` strings.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.model
            .warnings()
            .iter()
            .map(|d| {
                let (l, c) = line_column(self.model.source(), d.primary_span().start);
                format!("{l}:{c}: warning[{}]: {}", d.code, d.message)
            })
            .collect()
    }

    /// The tool-location errors `(ex, ey, ez, erx, ery, erz)` (m, rad; the task's sign) of every
    /// state for the bound β: an (N, 6) array, `out` when given. The GIL is released.
    #[pyo3(signature = (states, *, inputs=None, time=None, dirs=None, tool=0, out=None))]
    #[allow(clippy::too_many_arguments)]
    fn eval<'py>(
        &self,
        py: Python<'py>,
        states: Floats2<'py>,
        inputs: Option<Floats2<'py>>,
        time: Option<Floats1<'py>>,
        dirs: Option<Floats2<'py>>,
        tool: usize,
        out: Option<Bound<'py, PyArray2<f64>>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let batch = self.batch(py, &states, &inputs, &time, &dirs, tool)?;
        let n = batch.rows;
        let out = output(py, "out", out, &[n, 6], || {
            PyArray2::zeros(py, [n, 6], false)
        })?;
        let mut w = out.try_readwrite()?;
        let dst = w.as_slice_mut().map_err(|e| kin_error(py, e))?;
        let model = &self.model;
        py.detach(|| {
            batch.blocks(model, |start, rows| {
                let e = dst
                    .get_mut(6 * start..6 * (start + rows.len()))
                    .unwrap_or(&mut []);
                model.eval_rows(rows, model.beta(), e)
            })
        })
        .map_err(|e| eval_error(py, e))?;
        drop(w);
        Ok(out)
    }

    /// The errors and their β-Jacobians: `(err, jac)` with `err` (N, k) and `jac` (N, k,
    /// len(coefficients)), `jac[i, c, j]` = ∂ error component c / ∂ βⱼ at state i (so `err =
    /// fixed + jac @ beta`), k = 6 for `observe="pose"` (the default) and 3 for
    /// `observe="position"` (ex, ey, ez alone: half the work, for a tracker's positions).
    /// Written into `out` and `jac_out` when given.
    #[pyo3(signature = (states, *, inputs=None, time=None, dirs=None, tool=0, observe="pose", out=None, jac_out=None))]
    #[allow(clippy::too_many_arguments)]
    fn eval_jacobian<'py>(
        &self,
        py: Python<'py>,
        states: Floats2<'py>,
        inputs: Option<Floats2<'py>>,
        time: Option<Floats1<'py>>,
        dirs: Option<Floats2<'py>>,
        tool: usize,
        observe: &str,
        out: Option<Bound<'py, PyArray2<f64>>>,
        jac_out: Option<Bound<'py, PyArray3<f64>>>,
    ) -> PyResult<ErrorsAndJacobians<'py>> {
        use kin_model::engine::Observed;
        let observed = match observe {
            "pose" => Observed::FULL,
            "position" => Observed::POSITION,
            other => {
                return Err(kin_error(
                    py,
                    format!("observe={other:?}: \"pose\" (six rows) or \"position\" (three)"),
                ))
            }
        };
        let k = observed.rows();
        let batch = self.batch(py, &states, &inputs, &time, &dirs, tool)?;
        let n = batch.rows;
        let p = self.model.coefficients();
        let out = output(py, "out", out, &[n, k], || {
            PyArray2::zeros(py, [n, k], false)
        })?;
        let jac_out = output(py, "jac_out", jac_out, &[n, k, p], || {
            PyArray3::zeros(py, [n, k, p], false)
        })?;
        let mut w = out.try_readwrite()?;
        let mut wj = jac_out.try_readwrite()?;
        let dst = w.as_slice_mut().map_err(|e| kin_error(py, e))?;
        let jdst = wj.as_slice_mut().map_err(|e| kin_error(py, e))?;
        let model = &self.model;
        py.detach(|| {
            batch.blocks(model, |start, rows| {
                let end = start + rows.len();
                let j = jdst.get_mut(start * k * p..end * k * p).unwrap_or(&mut []);
                let e = dst.get_mut(k * start..k * end).unwrap_or(&mut []);
                model.eval_jacobian_rows_observed(rows, model.beta(), observed, e, j)
            })
        })
        .map_err(|e| eval_error(py, e))?;
        drop((w, wj));
        Ok((out, jac_out))
    }

    /// The nominal joint Jacobians: (N, axes, 6), row `[i, j]` = (∂p/∂q_j, ω_j) of the tool
    /// location in the workpiece frame at state i. Written into `out` when given.
    #[pyo3(signature = (states, *, tool=0, out=None))]
    fn joint_jacobian<'py>(
        &self,
        py: Python<'py>,
        states: Floats2<'py>,
        tool: usize,
        out: Option<Bound<'py, PyArray3<f64>>>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let batch = self.batch(py, &states, &None, &None, &None, tool)?;
        let (n, na) = (batch.rows, self.model.axes());
        let out = output(py, "out", out, &[n, na, 6], || {
            PyArray3::zeros(py, [n, na, 6], false)
        })?;
        let mut w = out.try_readwrite()?;
        let dst = w.as_slice_mut().map_err(|e| kin_error(py, e))?;
        let model = &self.model;
        py.detach(|| {
            batch.each(model, |r, s| {
                let j = dst.get_mut(r * 6 * na..(r + 1) * 6 * na).unwrap_or(&mut []);
                model
                    .nominal_jacobian(s, j)
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            })
        })
        .map_err(|e| eval_error(py, e))?;
        drop(w);
        Ok(out)
    }

    /// The joint corrections that cancel the model's predicted error at each commanded state
    /// (thesis §2.3.5, the servo compensator of spec/compensation.md): an (N, axes) array to
    /// add to the commanded joints, `out` when given. `position_only` leaves the tool's
    /// orientation errors as they are, and then moves only the prismatic axes (every axis of an
    /// arm), as `kin compensate --correct position` does; `axes` (names) chooses the axes that
    /// move, the others held at their commanded positions. A measuring machine has no
    /// compensation (KinError).
    #[pyo3(signature = (states, *, inputs=None, time=None, tool=0, position_only=false, axes=None, out=None))]
    #[allow(clippy::too_many_arguments)]
    fn compensate<'py>(
        &self,
        py: Python<'py>,
        states: Floats2<'py>,
        inputs: Option<Floats2<'py>>,
        time: Option<Floats1<'py>>,
        tool: usize,
        position_only: bool,
        axes: Option<Vec<String>>,
        out: Option<Bound<'py, PyArray2<f64>>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let m = self.model.machine();
        let mut options = if position_only {
            kin_model::compensate::Options::position(m)
        } else {
            kin_model::compensate::Options::pose(m)
        };
        if let Some(names) = axes {
            let mut chosen = Vec::with_capacity(names.len());
            for name in &names {
                let Some(j) = m.axes.iter().position(|a| &a.name == name) else {
                    let known: Vec<&str> = m.axes.iter().map(|a| a.name.as_str()).collect();
                    return Err(kin_error(
                        py,
                        format!(
                            "`{name}` is no axis of `{}` (its axes: {})",
                            m.name,
                            known.join(", ")
                        ),
                    ));
                };
                chosen.push(j);
            }
            options.movable = kin_model::compensate::Movable::only(chosen);
        }
        let comp = self
            .model
            .compensator(options)
            .map_err(|e| kin_error(py, e))?;
        let batch = self.batch(py, &states, &inputs, &time, &None, tool)?;
        let (n, na) = (batch.rows, self.model.axes());
        let out = output(py, "out", out, &[n, na], || {
            PyArray2::zeros(py, [n, na], false)
        })?;
        let mut w = out.try_readwrite()?;
        let dst = w.as_slice_mut().map_err(|e| kin_error(py, e))?;
        py.detach(|| {
            batch.each(&self.model, |r, s| {
                let d = dst.get_mut(r * na..(r + 1) * na).unwrap_or(&mut []);
                comp.compensate(s, d).map(|_| ()).map_err(|e| e.to_string())
            })
        })
        .map_err(|e| eval_error(py, e))?;
        drop(w);
        Ok(out)
    }

    /// The model as JSON: its source, bound parameter texts and exact values (`Model.from_json`
    /// restores it bit for bit). Also how a model is pickled to other processes.
    fn to_json(&self, py: Python<'_>) -> PyResult<String> {
        self.model.to_json().map_err(|e| kin_error(py, e))
    }

    #[staticmethod]
    fn from_json(py: Python<'_>, text: &str) -> PyResult<PyModel> {
        let model = Model::from_json(text).map_err(|e| model_error(py, e, text, None))?;
        Ok(PyModel { model })
    }

    /// Writes the model (as `to_json`) to `path`, atomically.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        self.model
            .save(&path)
            .map_err(|e| model_error(py, e, "", None))
    }

    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<PyModel> {
        let model = Model::load(&path).map_err(|e| model_error(py, e, "", None))?;
        Ok(PyModel { model })
    }

    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (String,))> {
        let py = slf.py();
        let json = slf.get().to_json(py)?;
        let restore = py.get_type::<PyModel>().getattr("from_json")?;
        Ok((restore, (json,)))
    }

    fn __repr__(&self) -> String {
        let m = self.model.machine();
        format!(
            "<kin.Model {}: {} axes, {} inputs, {} coefficients>",
            m.name,
            m.axes.len(),
            m.inputs.len(),
            m.coefficients.len()
        )
    }
}

const COMPONENTS: [&str; 6] = ["ex", "ey", "ez", "erx", "ery", "erz"];

/// The least-squares fit of β to observed errors, streamed: batches of states with their
/// observed error components are reduced to the triangle R of `[X | y]` (memory ∝ coefficients²,
/// not rows), and the triangles of different partitions merge (TSQR) into that of all rows.
///
/// A row is one observed component c of one state: `x = ∂e_c/∂β`, `y = observed_c − (e_c −
/// x·β₀)` with β₀ the model's bound β, times the component's weight. NaN observations are
/// skipped. SI units: weight rotations (rad) against positions (m) with `weights`.
#[pyclass(name = "StreamingFit", module = "kin")]
struct PyStreamingFit {
    model: Model,
    observe: Vec<usize>,
    weights: Vec<f64>,
    block: usize,
    acc: StreamingQr,
    /// The merged triangle of what came before `acc` (batches already folded in, or partitions
    /// merged into this one).
    merged: Option<Reduced>,
}

impl PyStreamingFit {
    fn total(&self, py: Python<'_>) -> PyResult<Reduced> {
        // `acc` is single-threaded (`StreamingQr::new`): it always has a snapshot.
        let now = self.acc.snapshot().ok_or_else(|| {
            kin_error(py, "the streaming fit's triangle is held by worker threads")
        })?;
        match &self.merged {
            Some(m) => merge::merge(m, &now).map_err(|e| kin_error(py, e)),
            None => Ok(now),
        }
    }
}

fn components(py: Python<'_>, observe: &[String]) -> PyResult<Vec<usize>> {
    observe
        .iter()
        .map(|name| {
            COMPONENTS.iter().position(|c| c == name).ok_or_else(|| {
                kin_error(
                    py,
                    format!("`{name}` is not an error component: one of ex ey ez erx ery erz"),
                )
            })
        })
        .collect()
}

#[pymethods]
impl PyStreamingFit {
    /// `observe`: the error components each observation row holds, in order (default the
    /// position `ex, ey, ez`); `weights`: one per component (default 1); `block`: rows buffered
    /// before each QR update.
    #[new]
    #[pyo3(signature = (model, observe=None, weights=None, block=4096))]
    fn new(
        py: Python<'_>,
        model: &PyModel,
        observe: Option<Vec<String>>,
        weights: Option<Vec<f64>>,
        block: usize,
    ) -> PyResult<Self> {
        let names = observe.unwrap_or_else(|| vec!["ex".into(), "ey".into(), "ez".into()]);
        let observe = components(py, &names)?;
        let weights = weights.unwrap_or_else(|| vec![1.0; observe.len()]);
        if weights.len() != observe.len() || weights.iter().any(|w| !(w.is_finite() && *w > 0.0)) {
            return Err(kin_error(
                py,
                "`weights` needs one finite positive weight per observed component",
            ));
        }
        let p = model.model.coefficients();
        Ok(PyStreamingFit {
            model: model.model.clone(),
            observe,
            weights,
            block: block.max(1),
            acc: StreamingQr::new(p, block.max(1)),
            merged: None,
        })
    }

    /// Adds the rows of a batch: `states` (N, axes) with `observations` (N, len(observe)),
    /// optional `inputs`, `time` and `dirs` as for `Model.eval`. The GIL is released.
    #[pyo3(signature = (states, observations, *, inputs=None, time=None, dirs=None, tool=0))]
    #[allow(clippy::too_many_arguments)]
    fn add_batch(
        &mut self,
        py: Python<'_>,
        states: Floats2<'_>,
        observations: Floats2<'_>,
        inputs: Option<Floats2<'_>>,
        time: Option<Floats1<'_>>,
        dirs: Option<Floats2<'_>>,
        tool: usize,
    ) -> PyResult<()> {
        let holder = PyModel {
            model: self.model.clone(),
        };
        let batch = holder.batch(py, &states, &inputs, &time, &dirs, tool)?;
        let d = self.observe.len();
        if observations.shape() != [batch.rows, d] {
            return Err(shape_error(
                py,
                format!(
                    "`observations` has shape {:?}, ({}, {d}) is needed",
                    observations.shape(),
                    batch.rows
                ),
            ));
        }
        let obs = contiguous(py, "observations", &observations)?;
        let model = &holder.model;
        let p = model.coefficients();
        let (observe, weights, acc) = (&self.observe, &self.weights, &mut self.acc);
        py.detach(|| {
            let mut jac = vec![0.0; 6 * p];
            let mut x = vec![0.0; p];
            let beta = model.beta();
            batch.each(model, |r, s| {
                let mut e = [0.0; 6];
                model
                    .eval_jacobian(s, beta, &mut e, &mut jac)
                    .map_err(|e| e.to_string())?;
                for (k, (&c, &w)) in observe.iter().zip(weights).enumerate() {
                    let o = obs.get(r * d + k).copied().unwrap_or(f64::NAN);
                    if o.is_nan() {
                        continue;
                    }
                    let row = jac.get(c * p..(c + 1) * p).unwrap_or(&[]);
                    let fixed = e[c] - row.iter().zip(beta).map(|(a, b)| a * b).sum::<f64>();
                    for (xi, ji) in x.iter_mut().zip(row) {
                        *xi = w * ji;
                    }
                    acc.push(&x, w * (o - fixed));
                }
                Ok(())
            })
        })
        .map_err(|e| eval_error(py, e))
    }

    /// Observation rows so far (merged partitions included).
    #[getter]
    fn rows(&self) -> usize {
        self.merged.as_ref().map_or(0, |m| m.rows) + self.acc.rows()
    }

    /// The triangle R (k × k, k = coefficients + 1, the last column that of y) of every row so
    /// far: `RᵀR = [X y]ᵀ[X y]`.
    fn r_factor<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let red = self.total(py)?;
        let k = red.r.ncols();
        let flat: Vec<f64> = (0..k)
            .flat_map(|i| (0..k).map(move |j| (i, j)))
            .map(|(i, j)| red.r[(i, j)])
            .collect();
        PyArray1::from_vec(py, flat).reshape([k, k])
    }

    /// Merges the rows of `other` (a fit of the same model and components, e.g. another
    /// partition's) into this one: the QR of the two stacked triangles.
    fn merge(&mut self, py: Python<'_>, other: &PyStreamingFit) -> PyResult<()> {
        if other.model.coefficients() != self.model.coefficients() || other.observe != self.observe
        {
            return Err(kin_error(
                py,
                "only fits of the same model's coefficients and the same components merge",
            ));
        }
        let merged =
            merge::merge(&self.total(py)?, &other.total(py)?).map_err(|e| kin_error(py, e))?;
        self.merged = Some(merged);
        self.acc = StreamingQr::new(self.model.coefficients(), self.block);
        Ok(())
    }

    /// Solves the triangle by the fit's solver (unit-scaled columns, rank decided at relative
    /// `tolerance`, covariance of eq. 4.11): a dict with `beta` and `se` (SI, in the order of
    /// `names`), `sigma` (σ̂ of the weighted rows), `rss`, `rank`, `rows`, `dof`, `names`.
    /// Raises FitError when the rows cannot determine every coefficient.
    #[pyo3(signature = (tolerance=1e-10))]
    fn solve<'py>(&self, py: Python<'py>, tolerance: f64) -> PyResult<Bound<'py, PyDict>> {
        let red = self.total(py)?;
        let p = self.model.coefficients();
        let s = merge::solve_triangle(&red, Solver::Qr, tolerance, false).map_err(|s| {
            raise::<FitError>(
                py,
                format!(
                    "the rows determine {} of the {p} coefficients (rank-deficient)",
                    s.rank
                ),
                Place::default(),
            )
        })?;
        if red.rows <= s.rank {
            return Err(raise::<FitError>(
                py,
                format!(
                    "{} observed values cannot determine {} coefficients with a noise estimate left over",
                    red.rows, s.rank
                ),
                Place::default(),
            ));
        }
        let dof = red.rows - s.rank;
        let sigma = (s.rss / dof as f64).sqrt();
        let se: Vec<f64> = (0..p)
            .map(|j| {
                let g2: f64 = (0..s.g.nrows()).map(|i| s.g[(i, j)].powi(2)).sum();
                sigma * g2.sqrt()
            })
            .collect();
        let out = PyDict::new(py);
        out.set_item("beta", PyArray1::from_slice(py, &s.beta))?;
        out.set_item("se", PyArray1::from_vec(py, se))?;
        out.set_item("sigma", sigma)?;
        out.set_item("rss", s.rss)?;
        out.set_item("rank", s.rank)?;
        out.set_item("rows", red.rows)?;
        out.set_item("dof", dof)?;
        let names: Vec<String> = self
            .model
            .machine()
            .coefficients
            .iter()
            .map(|c| c.name.clone())
            .collect();
        out.set_item("names", names)?;
        Ok(out)
    }

    /// Everything needed to rebuild this fit in another process (pickling): the model, the
    /// components, weights and the triangle with its row count, column norms and sum of y.
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let py = slf.py();
        let this = slf.borrow();
        let red = this.total(py)?;
        let k = red.r.ncols();
        let flat: Vec<f64> = (0..k)
            .flat_map(|i| (0..k).map(move |j| (i, j)))
            .map(|(i, j)| red.r[(i, j)])
            .collect();
        let observe: Vec<&str> = this.observe.iter().map(|&c| COMPONENTS[c]).collect();
        let model = Py::new(
            py,
            PyModel {
                model: this.model.clone(),
            },
        )?;
        let args = (
            model,
            observe,
            this.weights.clone(),
            this.block,
            flat,
            red.rows,
            red.norms.clone(),
            red.y_sum,
        )
            .into_pyobject(py)?
            .into_any();
        let restore = py.get_type::<PyStreamingFit>().getattr("_restore")?;
        Ok((restore, args))
    }

    #[staticmethod]
    #[allow(clippy::too_many_arguments)]
    fn _restore(
        py: Python<'_>,
        model: &PyModel,
        observe: Vec<String>,
        weights: Vec<f64>,
        block: usize,
        r: Vec<f64>,
        rows: usize,
        norms: Vec<f64>,
        y_sum: f64,
    ) -> PyResult<Self> {
        let mut fit = PyStreamingFit::new(py, model, Some(observe), Some(weights), block)?;
        let k = model.model.coefficients() + 1;
        fit.merged =
            Some(merge::from_triangle(k, &r, rows, norms, y_sum).map_err(|e| kin_error(py, e))?);
        Ok(fit)
    }
}

fn read_files(py: Python<'_>, model: &Model, paths: &[PathBuf]) -> PyResult<Vec<DataSet>> {
    paths
        .iter()
        .map(|p| {
            let observations = data::read_file(p, model.machine(), &ReadOptions::default())
                .map_err(|e| data_error(py, e))?;
            Ok(DataSet {
                path: p.clone(),
                observations,
            })
        })
        .collect()
}

fn fit_options(noise: Option<f64>, noise_tilt: Option<f64>) -> fit::Options {
    fit::Options {
        noise: (noise.is_some() || noise_tilt.is_some()).then_some(fit::Noise {
            position: noise,
            rotation: noise_tilt,
        }),
        ..fit::Options::default()
    }
}

fn fit_error(py: Python<'_>, e: fit::FitError) -> PyErr {
    match e {
        fit::FitError::Read(r) => data_error(py, r),
        e => raise::<FitError>(py, e.to_string(), Place::default()),
    }
}

/// Fits `model` to the measurement files `data` (as `kin fit`): returns FIT.json's document.
fn fit_files(
    py: Python<'_>,
    model: &Model,
    files: &[DataSet],
    options: &fit::Options,
) -> PyResult<(fit::FitResult, report::FitReport)> {
    let compiled = model.compiled();
    let m = &compiled.machine;
    let result = py
        .detach(|| {
            // The model's own native code: nothing is compiled again.
            let mut engine = model.evaluator();
            fit::fit(
                compiled,
                engine.as_mut(),
                files,
                &[],
                options,
                &mut |_, _| {},
            )
        })
        .map_err(|e| fit_error(py, e))?;
    let rep = report::build(m, model.source(), "jit", files, &[], &result, options);
    Ok((result, rep))
}

fn json<T: serde::Serialize>(py: Python<'_>, v: &T) -> PyResult<String> {
    serde_json::to_string(v).map_err(|e| kin_error(py, e))
}

/// Fits `model` to the measurement files `data` as `kin fit` does (unit weights, or the
/// stated noise in SI): FIT.json's document as a JSON string, and FIT.params' text.
#[pyfunction]
#[pyo3(signature = (model, data, *, noise=None, noise_tilt=None))]
fn fit_json(
    py: Python<'_>,
    model: &PyModel,
    data: Vec<PathBuf>,
    noise: Option<f64>,
    noise_tilt: Option<f64>,
) -> PyResult<(String, String)> {
    let files = read_files(py, &model.model, &data)?;
    let options = fit_options(noise, noise_tilt);
    let (_, rep) = fit_files(py, &model.model, &files, &options)?;
    Ok((json(py, &rep)?, rep.params.clone()))
}

/// Fits and diagnoses (as `kin diagnose`): FIT.json's document, its FIT.params text and
/// DIAGNOSE.json's document.
#[pyfunction]
#[pyo3(signature = (model, data, *, alpha=0.01, noise=None, noise_tilt=None))]
fn diagnose_json(
    py: Python<'_>,
    model: &PyModel,
    data: Vec<PathBuf>,
    alpha: f64,
    noise: Option<f64>,
    noise_tilt: Option<f64>,
) -> PyResult<(String, String, String)> {
    let files = read_files(py, &model.model, &data)?;
    let options = fit_options(noise, noise_tilt);
    let (result, rep) = fit_files(py, &model.model, &files, &options)?;
    let settings = diagnose::Settings {
        alpha,
        noise,
        noise_tilt,
        ..diagnose::Settings::default()
    };
    let m = &model.model;
    let diagnosis = py
        .detach(|| {
            diagnose::diagnose(
                m.compiled(),
                m.source(),
                &files,
                &result,
                &options,
                &settings,
            )
        })
        .map_err(|e| raise::<FitError>(py, e.to_string(), Place::default()))?;
    Ok((json(py, &rep)?, rep.params.clone(), json(py, &diagnosis)?))
}

/// Checks a measurement file against `model` with kin's reader (errors located at line and
/// column); returns the number of rows.
#[pyfunction]
fn check_measurements(
    py: Python<'_>,
    model: &PyModel,
    path: PathBuf,
    poses: bool,
) -> PyResult<usize> {
    let options = ReadOptions {
        poses,
        ..ReadOptions::default()
    };
    let obs =
        data::read_file(&path, model.model.machine(), &options).map_err(|e| data_error(py, e))?;
    Ok(obs.rows().line.len())
}

/// Writes `text` (a measurement file) to `path` atomically after checking it with kin's reader
/// against `model`: nothing is written when it would not read back. `inputs` are files the
/// output must not be.
#[pyfunction]
#[pyo3(signature = (model, path, text, *, poses=false, inputs=Vec::new()))]
fn write_measurements_text(
    py: Python<'_>,
    model: &PyModel,
    path: PathBuf,
    text: &str,
    poses: bool,
    inputs: Vec<PathBuf>,
) -> PyResult<()> {
    let options = ReadOptions {
        poses,
        ..ReadOptions::default()
    };
    data::read(text.as_bytes(), &path, model.model.machine(), &options)
        .map_err(|e| data_error(py, e))?;
    write_files(py, vec![(path, text.as_bytes().to_vec())], inputs)
}

/// Replaces every `(path, bytes)` as one set through kin's durable output (a temporary file
/// renamed over each target), after checking no target is one of `inputs`.
#[pyfunction]
#[pyo3(signature = (files, inputs=Vec::new()))]
fn write_files(
    py: Python<'_>,
    files: Vec<(PathBuf, Vec<u8>)>,
    inputs: Vec<PathBuf>,
) -> PyResult<()> {
    let inputs: Vec<&Path> = inputs.iter().map(|p| p.as_path()).collect();
    for (path, _) in &files {
        kin_data::output::check_target(path, &inputs).map_err(|e| {
            raise::<KinError>(
                py,
                e.to_string(),
                Place {
                    path: Some(path.display().to_string()),
                    ..Place::default()
                },
            )
        })?;
    }
    let set: Vec<(&Path, &[u8])> = files
        .iter()
        .map(|(p, b)| (p.as_path(), b.as_slice()))
        .collect();
    kin_data::output::replace_all(&set).map_err(|e| kin_error(py, format!("cannot write: {e}")))
}

/// Simulates a measurement file (as `kin simulate --sample N`): `n` states drawn in the axes'
/// and inputs' ranges, the model's bound β applied with the exact transforms, Gaussian noise
/// `noise` (m) on positions and `noise_tilt` (rad) on rotations; `observe` the components
/// written. Written to `path` atomically.
#[pyfunction]
#[pyo3(signature = (model, path, n, *, noise=0.0, noise_tilt=0.0, seed=0, observe=None))]
#[allow(clippy::too_many_arguments)]
fn simulate(
    py: Python<'_>,
    model: &PyModel,
    path: PathBuf,
    n: usize,
    noise: f64,
    noise_tilt: f64,
    seed: u64,
    observe: Option<Vec<String>>,
) -> PyResult<()> {
    let names = observe.unwrap_or_else(|| vec!["ex".into(), "ey".into(), "ez".into()]);
    let mut which = [false; 6];
    for c in components(py, &names)? {
        which[c] = true;
    }
    let m = model.model.machine();
    let poses = Observations::Points(kin_estimate::simulate::sample_points(m, n, seed));
    let options = kin_estimate::simulate::Options {
        observe: which,
        noise,
        noise_tilt,
        seed,
        ..kin_estimate::simulate::Options::default()
    };
    let out = py
        .detach(|| kin_estimate::simulate::simulate(m, model.model.beta(), &poses, &options))
        .map_err(|e| kin_error(py, e))?;
    let write = data::WriteOptions {
        comments: vec![format!(
            "simulated by kin (Python) from machine `{}` (exact transforms), noise {noise} m, {noise_tilt} rad, seed {seed}",
            m.name
        )],
        ..data::WriteOptions::default()
    };
    data::write_file(&path, m, &out, &write).map_err(|e| kin_error(py, e))
}

/// The baseline of `python/bench.py`: `repeats` evaluations of `states` through the Rust API's
/// own batch call (`Model::eval_rows` on a `RowsBuf`, inputs 0), timed in Rust; seconds per repeat. Not
/// part of the public API.
#[pyfunction]
fn _rust_eval_seconds(
    py: Python<'_>,
    model: &PyModel,
    states: Floats2<'_>,
    repeats: usize,
) -> PyResult<f64> {
    let m = &model.model;
    let q = contiguous(py, "states", &states)?.to_vec();
    let na = m.axes().max(1);
    let n = q.len() / na;
    let mut rows = kin_model::RowsBuf::default();
    let mut one = m.state();
    // Inputs at 0 (no load, no temperature change), as the Python side of the benchmark gives them.
    one.inputs.iter_mut().for_each(|v| *v = 0.0);
    for r in 0..n {
        one.q
            .copy_from_slice(q.get(r * na..(r + 1) * na).unwrap_or(&[]));
        rows.push(&one.get());
    }
    let mut err = vec![0.0; 6 * n];
    py.detach(|| {
        let start = std::time::Instant::now();
        for _ in 0..repeats.max(1) {
            m.eval_rows(&rows.rows(), m.beta(), &mut err)
                .map_err(|e| e.to_string())?;
        }
        Ok::<f64, String>(start.elapsed().as_secs_f64() / repeats.max(1) as f64)
    })
    .map_err(|e| kin_error(py, e))
}

#[pymodule]
fn _kin(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<PyModel>()?;
    m.add_class::<PyStreamingFit>()?;
    m.add("KinError", py.get_type::<KinError>())?;
    m.add("CompileError", py.get_type::<CompileError>())?;
    m.add("DataError", py.get_type::<DataError>())?;
    m.add("EvalError", py.get_type::<EvalError>())?;
    m.add("FitError", py.get_type::<FitError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(fit_json, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose_json, m)?)?;
    m.add_function(wrap_pyfunction!(check_measurements, m)?)?;
    m.add_function(wrap_pyfunction!(write_measurements_text, m)?)?;
    m.add_function(wrap_pyfunction!(write_files, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(_rust_eval_seconds, m)?)?;
    Ok(())
}
