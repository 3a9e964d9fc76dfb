//! The C ABI harness: a sequence of calls, decoded from the bytes with `arbitrary`, against models
//! compiled once from the examples. Values (positions, inputs, β, time, tool and name indices)
//! and lengths are fuzzed; buffers are always real allocations of the length passed, or NULL,
//! because a C caller that lies about a length is outside the contract (undefined behaviour, not
//! a bug in kin). Every call's status must be a documented code other than `KIN_ERR_PANIC`.

use std::ffi::c_char;
use std::ptr::{null, null_mut};
use std::sync::{Mutex, OnceLock};

use arbitrary::{Arbitrary, Unstructured};
use kin_capi::{
    kin_eval, kin_eval_batch, kin_eval_batch_observed, kin_eval_jacobian,
    kin_eval_jacobian_observed, kin_last_error, kin_model, kin_model_axes, kin_model_axis_range,
    kin_model_beta, kin_model_bind_params, kin_model_coefficients, kin_model_compile,
    kin_model_free, kin_model_input_range, kin_model_inputs, kin_model_lag_input, kin_model_lags,
    kin_model_name, kin_model_set_beta, kin_nominal_jacobian, kin_rows, kin_state, KIN_ERR_OVERLAP,
    KIN_ERR_PANIC, KIN_OK,
};

use super::MACHINES;

/// The examples compiled through the C ABI once per process. Only this harness uses them, one
/// call at a time (libFuzzer and the regression test are single-threaded per model use).
fn models() -> &'static [usize] {
    static MODELS: OnceLock<Vec<usize>> = OnceLock::new();
    MODELS.get_or_init(|| {
        MACHINES
            .iter()
            .map(|(name, source)| {
                let mut out = null_mut();
                // SAFETY: `source` is valid for its length, `out` for one pointer, `err` NULL.
                let code = unsafe {
                    kin_model_compile(
                        source.as_ptr().cast(),
                        source.len(),
                        &mut out,
                        null_mut(),
                        0,
                    )
                };
                assert_eq!(code, KIN_OK, "examples/{name}.kin does not compile");
                // Kept as an address: a raw pointer is neither `Send` nor `Sync`.
                out as usize
            })
            .collect()
    })
}

/// A length relative to what the model needs: mostly right, sometimes off, sometimes NULL.
#[derive(Arbitrary, Debug, Clone, Copy)]
enum Len {
    Exact,
    Plus(u8),
    Minus(u8),
    Empty,
    /// A NULL pointer with the exact length (an error unless the length is 0).
    Null,
    /// A NULL pointer with a huge length: size arithmetic must not overflow.
    NullHuge(u8),
}

/// The rows a call's mask selects (six for none, or for a mask the ABI refuses): what the
/// buffers' lengths are measured from.
fn components(observed: Option<u8>) -> usize {
    match observed {
        Some(m @ 1..=63) => m.count_ones() as usize,
        _ => 6,
    }
}

/// A caller's array: `None` is a NULL pointer with the given length.
struct Array {
    values: Option<Vec<f64>>,
    len: usize,
}

impl Array {
    fn new(len: Len, need: usize, fill: &[f64]) -> Array {
        let n = match len {
            Len::Exact | Len::Null => need,
            Len::Plus(k) => need.saturating_add(usize::from(k)),
            Len::Minus(k) => need.saturating_sub(usize::from(k)),
            Len::Empty => 0,
            Len::NullHuge(k) => usize::MAX - usize::from(k),
        };
        let values = match len {
            Len::Null | Len::NullHuge(_) => None,
            _ => Some((0..n).map(|i| value(fill, i)).collect()),
        };
        Array { values, len: n }
    }

    fn ptr(&self) -> *const f64 {
        self.values.as_ref().map_or(null(), |v| v.as_ptr())
    }

    fn ptr_mut(&mut self) -> *mut f64 {
        self.values.as_mut().map_or(null_mut(), |v| v.as_mut_ptr())
    }
}

/// The fuzzed values, cycled; plain zeros when none were given.
fn value(fill: &[f64], i: usize) -> f64 {
    match fill.len() {
        0 => 0.0,
        n => fill.get(i % n).copied().unwrap_or(0.0),
    }
}

#[derive(Arbitrary, Debug, Clone)]
struct StateIn {
    q: Len,
    inputs: Len,
    lags: Len,
    dirs: Len,
    values: Vec<f64>,
    time: f64,
    tool: usize,
}

#[derive(Arbitrary, Debug)]
struct RowsIn {
    n_rows: u8,
    huge_rows: bool,
    q: Len,
    inputs: Len,
    lags: Len,
    dirs: Len,
    time: Len,
    tool: Len,
    values: Vec<f64>,
    tools: Vec<usize>,
}

#[derive(Arbitrary, Debug)]
enum Call {
    Eval {
        state: StateIn,
        beta: Option<(Len, Vec<f64>)>,
        err: Len,
    },
    EvalJacobian {
        state: StateIn,
        beta: Option<(Len, Vec<f64>)>,
        /// `None`: `kin_eval_jacobian`; a mask (any byte, so also invalid ones): the
        /// `_observed` call.
        observed: Option<u8>,
        err: Len,
        jac: Len,
    },
    NominalJacobian {
        state: StateIn,
        location: Len,
        jac: Len,
    },
    Batch {
        rows: RowsIn,
        beta: Option<(Len, Vec<f64>)>,
        /// As for [`Call::EvalJacobian`].
        observed: Option<u8>,
        err: Len,
        jac: Option<Len>,
    },
    SetBeta {
        beta: (Len, Vec<f64>),
    },
    Beta {
        beta: Len,
    },
    Name {
        what: i32,
        index: usize,
        len: u16,
        null: bool,
    },
    AxisRange {
        axis: usize,
    },
    InputRange {
        input: usize,
    },
    LagInput {
        lag: usize,
    },
    LastError {
        len: u16,
        null: bool,
    },
    /// Compiles fuzzed text (and frees what compiles).
    Compile {
        text: String,
        err_len: u16,
    },
    /// Binds fuzzed parameters on a fresh copy of the small machine (binding changes a model for
    /// good, so not on the shared ones), then evaluates it once.
    BindParams {
        params: String,
        err_len: u16,
        state: StateIn,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    model: u8,
    calls: Vec<Call>,
}

/// The documented status codes other than a panic or an overlap.
fn status(code: i32, call: &str) {
    assert_ne!(code, KIN_ERR_PANIC, "{call} panicked: {}", last_error());
    // The harness's buffers are separate allocations (or NULL): an overlap reported here is
    // a wrong verdict (a NULL pointer with a length once covered every address).
    assert_ne!(
        code,
        KIN_ERR_OVERLAP,
        "{call} saw an overlap of separate buffers: {}",
        last_error()
    );
    assert!(
        (KIN_OK..=KIN_ERR_OVERLAP).contains(&code),
        "{call} returned the undocumented status {code}"
    );
}

fn last_error() -> String {
    let mut buf = vec![0 as c_char; 4096];
    // SAFETY: `buf` is valid for its length.
    unsafe { kin_last_error(buf.as_mut_ptr(), buf.len()) };
    let bytes: Vec<u8> = buf
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c.to_ne_bytes()[0])
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

/// A state's arrays, kept alive while the `kin_state` pointing into them is used.
struct StateArrays {
    q: Array,
    inputs: Array,
    lags: Array,
    dirs: Array,
}

impl StateArrays {
    fn new(s: &StateIn, axes: usize, inputs: usize, lags: usize) -> StateArrays {
        StateArrays {
            q: Array::new(s.q, axes, &s.values),
            inputs: Array::new(s.inputs, inputs, &s.values),
            lags: Array::new(s.lags, lags, &s.values),
            dirs: Array::new(s.dirs, axes, &s.values),
        }
    }

    fn state(&self, s: &StateIn) -> kin_state {
        kin_state {
            q: self.q.ptr(),
            n_q: self.q.len,
            inputs: self.inputs.ptr(),
            n_inputs: self.inputs.len,
            lags: self.lags.ptr(),
            n_lags: self.lags.len,
            dirs: self.dirs.ptr(),
            n_dirs: self.dirs.len,
            time: s.time,
            tool: s.tool,
        }
    }
}

/// Runs one call on `model`. Every pointer passed is NULL or a live allocation of the length
/// passed with it, and no two output buffers overlap: the C ABI's contract.
fn call(model: *mut kin_model, c: &Call) {
    // SAFETY (all calls below): `model` is live; arrays as described above.
    let (axes, inputs, lags, n) = unsafe {
        (
            kin_model_axes(model),
            kin_model_inputs(model),
            kin_model_lags(model),
            kin_model_coefficients(model),
        )
    };
    let beta_array = |b: &Option<(Len, Vec<f64>)>| match b {
        Some((len, values)) => Array::new(*len, n, values),
        None => Array {
            values: None,
            len: 0,
        },
    };
    match c {
        Call::Eval { state, beta, err } => {
            let arrays = StateArrays::new(state, axes, inputs, lags);
            let s = arrays.state(state);
            let b = beta_array(beta);
            let mut e = Array::new(*err, 6, &[]);
            let code = unsafe { kin_eval(model, &s, b.ptr(), b.len, e.ptr_mut(), e.len) };
            status(code, "kin_eval");
        }
        Call::EvalJacobian {
            state,
            beta,
            observed,
            err,
            jac,
        } => {
            let arrays = StateArrays::new(state, axes, inputs, lags);
            let s = arrays.state(state);
            let b = beta_array(beta);
            let k = components(*observed);
            let mut e = Array::new(*err, k, &[]);
            let mut j = Array::new(*jac, k * n, &[]);
            let code = unsafe {
                match observed {
                    None => kin_eval_jacobian(
                        model,
                        &s,
                        b.ptr(),
                        b.len,
                        e.ptr_mut(),
                        e.len,
                        j.ptr_mut(),
                        j.len,
                    ),
                    Some(m) => kin_eval_jacobian_observed(
                        model,
                        &s,
                        b.ptr(),
                        b.len,
                        u32::from(*m),
                        e.ptr_mut(),
                        e.len,
                        j.ptr_mut(),
                        j.len,
                    ),
                }
            };
            status(code, "kin_eval_jacobian");
        }
        Call::NominalJacobian {
            state,
            location,
            jac,
        } => {
            let arrays = StateArrays::new(state, axes, inputs, lags);
            let s = arrays.state(state);
            let mut loc = Array::new(*location, 12, &[]);
            let mut j = Array::new(*jac, 6 * axes, &[]);
            let code = unsafe {
                kin_nominal_jacobian(model, &s, loc.ptr_mut(), loc.len, j.ptr_mut(), j.len)
            };
            status(code, "kin_nominal_jacobian");
        }
        Call::Batch {
            rows,
            beta,
            observed,
            err,
            jac,
        } => {
            let r = usize::from(rows.n_rows);
            let q = Array::new(rows.q, r * axes, &rows.values);
            let inp = Array::new(rows.inputs, r * inputs, &rows.values);
            let lg = Array::new(rows.lags, r * lags, &rows.values);
            let dirs = Array::new(rows.dirs, r * axes, &rows.values);
            let time = Array::new(rows.time, r, &rows.values);
            // Tool indices: fuzzed, cycled, as many as the time column has.
            let tools: Vec<usize> = (0..time.len.min(r + 256))
                .map(|i| match rows.tools.len() {
                    0 => 0,
                    k => rows.tools.get(i % k).copied().unwrap_or(0),
                })
                .collect();
            let (tool_ptr, n_tool) = match rows.tool {
                Len::Null | Len::NullHuge(_) => (null(), time.len),
                _ => (tools.as_ptr(), tools.len()),
            };
            let kr = kin_rows {
                // A row count no array can match: the size checks must not overflow.
                n_rows: if rows.huge_rows {
                    usize::MAX / 2 + 1
                } else {
                    r
                },
                q: q.ptr(),
                n_q: q.len,
                inputs: inp.ptr(),
                n_inputs: inp.len,
                lags: lg.ptr(),
                n_lags: lg.len,
                dirs: dirs.ptr(),
                n_dirs: dirs.len,
                time: time.ptr(),
                n_time: time.len,
                tool: tool_ptr,
                n_tool,
            };
            let b = beta_array(beta);
            let k = components(*observed);
            let mut e = Array::new(*err, k * r, &[]);
            let mut j = match jac {
                Some(len) => Array::new(*len, k * n * r, &[]),
                None => Array {
                    values: None,
                    len: 0,
                },
            };
            let code = unsafe {
                match observed {
                    None => kin_eval_batch(
                        model,
                        &kr,
                        b.ptr(),
                        b.len,
                        e.ptr_mut(),
                        e.len,
                        j.ptr_mut(),
                        j.len,
                    ),
                    Some(m) => kin_eval_batch_observed(
                        model,
                        &kr,
                        b.ptr(),
                        b.len,
                        u32::from(*m),
                        e.ptr_mut(),
                        e.len,
                        j.ptr_mut(),
                        j.len,
                    ),
                }
            };
            status(code, "kin_eval_batch");
        }
        Call::SetBeta { beta } => {
            let b = Array::new(beta.0, n, &beta.1);
            let code = unsafe { kin_model_set_beta(model, b.ptr(), b.len) };
            status(code, "kin_model_set_beta");
        }
        Call::Beta { beta } => {
            let mut b = Array::new(*beta, n, &[]);
            let code = unsafe { kin_model_beta(model, b.ptr_mut(), b.len) };
            status(code, "kin_model_beta");
        }
        Call::Name {
            what,
            index,
            len,
            null,
        } => {
            let mut buf = vec![0 as c_char; usize::from(*len)];
            let (ptr, n) = if *null {
                (null_mut(), 0)
            } else {
                (buf.as_mut_ptr(), buf.len())
            };
            let needed = unsafe { kin_model_name(model, *what, *index, ptr, n) };
            // Whatever fitted is NUL-terminated.
            if n > 0 {
                assert!(
                    buf.contains(&0),
                    "kin_model_name left no NUL (needs {needed})"
                );
            }
        }
        Call::AxisRange { axis } => {
            let (mut lo, mut hi) = (0.0, 0.0);
            let code = unsafe { kin_model_axis_range(model, *axis, &mut lo, &mut hi) };
            status(code, "kin_model_axis_range");
        }
        Call::InputRange { input } => {
            let (mut lo, mut hi) = (0.0, 0.0);
            let code = unsafe { kin_model_input_range(model, *input, &mut lo, &mut hi) };
            status(code, "kin_model_input_range");
        }
        Call::LagInput { lag } => {
            let mut input = 0usize;
            let code = unsafe { kin_model_lag_input(model, *lag, &mut input) };
            status(code, "kin_model_lag_input");
        }
        Call::LastError { len, null } => {
            let mut buf = vec![0 as c_char; usize::from(*len)];
            let (ptr, n) = if *null {
                (null_mut(), 0)
            } else {
                (buf.as_mut_ptr(), buf.len())
            };
            unsafe { kin_last_error(ptr, n) };
            if n > 0 {
                assert!(buf.contains(&0), "kin_last_error left no NUL");
            }
        }
        Call::Compile { text, err_len } => {
            let mut err = vec![0 as c_char; usize::from(*err_len)];
            let model = compile_model(text, &mut err);
            if !model.is_null() {
                unsafe { kin_model_free(model) };
            }
        }
        Call::BindParams {
            params,
            err_len,
            state,
        } => {
            let mut err = vec![0 as c_char; usize::from(*err_len)];
            let mut slot = tiny_model().lock().unwrap_or_else(|e| e.into_inner());
            let tiny = *slot as *mut kin_model;
            let before = beta_bits(tiny);
            let code = unsafe {
                kin_model_bind_params(
                    tiny,
                    params.as_ptr().cast(),
                    params.len(),
                    err.as_mut_ptr(),
                    err.len(),
                )
            };
            status(code, "kin_model_bind_params");
            let eval = Call::Eval {
                state: state.clone(),
                beta: None,
                err: Len::Exact,
            };
            call(tiny, &eval);
            if code == KIN_OK {
                // Bound for good: start the next input from a fresh model.
                unsafe { kin_model_free(tiny) };
                *slot = compile_model(super::TINY, &mut err) as usize;
                assert!(*slot != 0, "fuzz/src/tiny.kin does not compile");
            } else {
                assert!(
                    beta_bits(tiny) == before,
                    "a failed kin_model_bind_params changed the model's values"
                );
            }
        }
    }
}

/// The small machine, compiled through the C ABI, for fuzzed parameter texts. Recompiled after
/// every successful bind, so that each input starts from the same model.
fn tiny_model() -> &'static Mutex<usize> {
    static MODEL: OnceLock<Mutex<usize>> = OnceLock::new();
    MODEL.get_or_init(|| {
        let model = compile_model(super::TINY, &mut []);
        assert!(!model.is_null(), "fuzz/src/tiny.kin does not compile");
        Mutex::new(model as usize)
    })
}

/// A model's bound values, bit for bit.
fn beta_bits(model: *mut kin_model) -> Vec<u64> {
    let n = unsafe { kin_model_coefficients(model) };
    let mut beta = vec![0.0f64; n];
    status(
        unsafe { kin_model_beta(model, beta.as_mut_ptr(), beta.len()) },
        "kin_model_beta",
    );
    beta.iter().map(|b| b.to_bits()).collect()
}

/// `kin_model_compile`, checking its status; NULL when the text does not compile.
fn compile_model(source: &str, err: &mut [c_char]) -> *mut kin_model {
    let mut out = null_mut();
    // SAFETY: `source` and `err` are valid for their lengths, `out` for one pointer.
    let code = unsafe {
        kin_model_compile(
            source.as_ptr().cast(),
            source.len(),
            &mut out,
            err.as_mut_ptr(),
            err.len(),
        )
    };
    status(code, "kin_model_compile");
    if code != KIN_OK {
        assert!(out.is_null(), "a failed compile left a model");
    }
    out
}

/// C ABI: a handful of calls on one of the example models.
pub fn capi(data: &[u8]) {
    let Ok(input) = Input::arbitrary_take_rest(Unstructured::new(data)) else {
        return;
    };
    let models = models();
    let Some(&address) = models.get(usize::from(input.model) % models.len()) else {
        return;
    };
    let model = address as *mut kin_model;
    // The model is shared by every run: keep its β to put back, so that no input depends on
    // the ones before it (a crash must reproduce on its own).
    let n = unsafe { kin_model_coefficients(model) };
    let mut saved = vec![0.0; n];
    status(
        unsafe { kin_model_beta(model, saved.as_mut_ptr(), saved.len()) },
        "kin_model_beta",
    );
    for c in input.calls.iter().take(32) {
        call(model, c);
    }
    status(
        unsafe { kin_model_set_beta(model, saved.as_ptr(), saved.len()) },
        "kin_model_set_beta",
    );
}
