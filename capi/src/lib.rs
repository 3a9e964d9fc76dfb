//! The C ABI of the `.kin` runtime: compile a model from source, evaluate its tool-location error,
//! the error's β-Jacobian and the nominal joint Jacobian, one state or many at a time.
//!
//! The header is `include/kin.h`; `examples/eval.c` is a complete program. Built as
//! `libkin_capi.so` (or `.dylib`/`.dll`) and `libkin_capi.a`.
//!
//! Every function returns a status (`KIN_OK` or a `KIN_ERR_*` code) and, on failure, leaves a
//! message for [`kin_last_error`] (per thread). Every pointer is checked against NULL (where the
//! length it comes with is not 0) and alignment, every length against the model, and no panic
//! crosses the boundary: one would be caught and reported as `KIN_ERR_PANIC`. The evaluation
//! functions take a `const kin_model*`, allocate nothing on success and take no lock: many threads
//! may call them on one model at once. Functions that change a model (`kin_model_bind_params`,
//! `kin_model_set_beta`) must not run while another thread uses it.
//!
//! All quantities are SI: metres, radians, seconds, kelvin, newtons.
#![allow(non_camel_case_types)]

use std::cell::RefCell;
use std::ffi::{c_char, c_int, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use ::kin_model::embed::Error;
use ::kin_model::engine::Observed;
use ::kin_model::interp::{finite_bits, EvalError, State};
use ::kin_model::jit::{BatchError, StateRows};
use ::kin_model::Model;

pub const KIN_OK: c_int = 0;
/// A pointer is NULL (with a non-zero length) or misaligned.
pub const KIN_ERR_POINTER: c_int = 1;
/// A length does not match the model (axes, inputs, lags, coefficients, outputs).
pub const KIN_ERR_SIZE: c_int = 2;
/// A text is not UTF-8.
pub const KIN_ERR_UTF8: c_int = 3;
/// The source does not compile (the message lists every error with its line and column).
pub const KIN_ERR_COMPILE: c_int = 4;
/// A parameter text cannot be bound.
pub const KIN_ERR_PARAMS: c_int = 5;
/// The state cannot be evaluated: a value the model uses is NaN, the tool index is out of range,
/// two poses of a length coincide.
pub const KIN_ERR_EVAL: c_int = 6;
/// A file cannot be read or written, or is not a saved model.
pub const KIN_ERR_IO: c_int = 7;
/// An index (axis, coefficient) is out of range.
pub const KIN_ERR_INDEX: c_int = 8;
/// A bug: the library panicked. The model is still usable; please report the message.
pub const KIN_ERR_PANIC: c_int = 9;
/// A value is not allowed: a joint position, time, lag state or β that is not finite, an input
/// that is infinite, a direction other than −1, 0, +1 (or NaN, not given); or a result that is
/// not finite (values so large that the error overflows).
pub const KIN_ERR_VALUE: c_int = 10;
/// Output buffers overlap each other or an input: results would overwrite values still to be
/// read (or each other).
pub const KIN_ERR_OVERLAP: c_int = 11;
/// A commanded joint position is outside its axis's declared range (`kin_compensate`).
pub const KIN_ERR_RANGE: c_int = 12;
/// The model is not one a compensator applies to: a measuring machine (`task measure`) or more
/// axes than `KIN_COMPENSATOR_MAX_AXES`.
pub const KIN_ERR_MACHINE: c_int = 13;
/// The compensation does not converge: a Gauss–Newton step did not shrink against the one
/// before, or the model's error overflowed at the moved pose. The model's predicted errors are
/// too large for a correction linearised on the joint Jacobian; apply no correction.
pub const KIN_ERR_DIVERGES: c_int = 14;

/// Most axes a compensator takes (its scratch is on the stack).
pub const KIN_COMPENSATOR_MAX_AXES: usize = ::kin_model::compensate::MAX_SERVO_AXES;

/// A compiled compensation function (opaque to C): see `kin_compensator_new`.
pub struct kin_compensator {
    comp: ::kin_model::embed::ServoCompensator,
}

/// A compiled model (opaque to C).
pub struct kin_model {
    model: Model,
}

/// One observation state. Arrays are indexed like the machine's axes, inputs and lags; a NULL
/// pointer is allowed with a length of 0.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct kin_state {
    /// Joint positions (m, rad).
    pub q: *const f64,
    pub n_q: usize,
    /// Input values; NaN where not given.
    pub inputs: *const f64,
    pub n_inputs: usize,
    /// Lag states.
    pub lags: *const f64,
    pub n_lags: usize,
    /// Direction of motion per axis: +1, 0, -1, or NaN where not given.
    pub dirs: *const f64,
    pub n_dirs: usize,
    /// Time (s); NaN where not given.
    pub time: f64,
    /// Tool index, in declaration order.
    pub tool: usize,
}

/// Many states, row-major: row r of `q` is `q[r*axes .. (r+1)*axes]`, and so on; `time` and
/// `tool` hold one value per row.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct kin_rows {
    pub n_rows: usize,
    pub q: *const f64,
    pub n_q: usize,
    pub inputs: *const f64,
    pub n_inputs: usize,
    pub lags: *const f64,
    pub n_lags: usize,
    pub dirs: *const f64,
    pub n_dirs: usize,
    pub time: *const f64,
    pub n_time: usize,
    pub tool: *const usize,
    pub n_tool: usize,
}

/// A failure: status and message.
struct Fail(c_int, String);

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

/// Runs `f`, catching a panic; on failure records the message and returns the status.
fn guard(f: impl FnOnce() -> Result<(), Fail>) -> c_int {
    // The failures out of line: inlined into every entry point, their formatting and the
    // thread-local store spread a call that succeeds over more instruction-cache lines, which
    // the generated code needs (spec/performance.md, "Where the code lands").
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => KIN_OK,
        Ok(Err(fail)) => failed(fail),
        Err(panic) => panicked(panic),
    }
}

#[cold]
#[inline(never)]
fn panicked(panic: Box<dyn std::any::Any + Send>) -> c_int {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_default();
    failed(Fail(
        KIN_ERR_PANIC,
        format!("internal error (a bug in kin): {what}"),
    ))
}

/// Keeps `fail`'s message for [`kin_last_error`] and returns its code.
#[cold]
#[inline(never)]
fn failed(Fail(code, message): Fail) -> c_int {
    LAST_ERROR.with(|e| {
        if let Ok(mut e) = e.try_borrow_mut() {
            *e = message;
        }
    });
    code
}

/// Copies `text` into `buf` (`len` bytes, NUL-terminated, cut at a character boundary) and
/// returns the length of the whole text, as `snprintf` does.
///
/// # Safety
///
/// `buf` is NULL or valid for `len` bytes of writing.
unsafe fn write_text(buf: *mut c_char, len: usize, text: &str) -> usize {
    if !buf.is_null() && len > 0 {
        let mut n = text.len().min(len - 1);
        while !text.is_char_boundary(n) {
            n -= 1;
        }
        // SAFETY: `buf` is valid for `len > n` bytes (caller's contract), `text` for `n`, and a
        // Rust string cannot overlap the caller's buffer.
        unsafe {
            std::ptr::copy_nonoverlapping(text.as_ptr(), buf.cast::<u8>(), n);
            *buf.add(n) = 0;
        }
    }
    text.len()
}

/// `n` values at `p`: empty when `n` is 0, otherwise `p` must be non-NULL and aligned.
///
/// # Safety
///
/// When non-NULL, `p` points to `n` initialised values that stay valid and unchanged for `'a`.
unsafe fn slice<'a, T>(p: *const T, n: usize, what: &str) -> Result<&'a [T], Fail> {
    if n == 0 {
        return Ok(&[]);
    }
    check_pointer(p, n, what)?;
    // SAFETY: non-NULL, aligned, the size fits an isize (checked), and valid for `n` values for
    // `'a` (caller's contract).
    Ok(unsafe { std::slice::from_raw_parts(p, n) })
}

/// As [`slice`](fn@slice), for writing.
///
/// # Safety
///
/// When non-NULL, `p` points to `n` values that nothing else reads or writes during `'a`.
unsafe fn slice_mut<'a, T>(p: *mut T, n: usize, what: &str) -> Result<&'a mut [T], Fail> {
    if n == 0 {
        return Ok(&mut []);
    }
    check_pointer(p.cast_const(), n, what)?;
    // SAFETY: as in `slice`, and exclusive for `'a` (caller's contract).
    Ok(unsafe { std::slice::from_raw_parts_mut(p, n) })
}

fn check_pointer<T>(p: *const T, n: usize, what: &str) -> Result<(), Fail> {
    if p.is_null() {
        return Err(Fail(
            KIN_ERR_POINTER,
            format!("`{what}` is NULL but its length is {n}"),
        ));
    }
    if !p.is_aligned() {
        return Err(Fail(
            KIN_ERR_POINTER,
            format!("`{what}` is not aligned for its type"),
        ));
    }
    if n.checked_mul(std::mem::size_of::<T>())
        .is_none_or(|bytes| bytes > isize::MAX as usize)
    {
        return Err(Fail(
            KIN_ERR_SIZE,
            format!("`{what}`: a length of {n} cannot be"),
        ));
    }
    Ok(())
}

/// The bytes a buffer covers, for the overlap checks: computed from the address alone, nothing
/// is read.
#[derive(Clone, Copy)]
struct Region {
    start: usize,
    end: usize,
    what: &'static str,
}

fn region<T>(p: *const T, n: usize, what: &'static str) -> Region {
    let start = p as usize;
    // A NULL pointer covers no memory: with a non-zero length it is KIN_ERR_POINTER, reported by
    // the pointer checks, not an overlap with every other buffer.
    let bytes = if p.is_null() {
        0
    } else {
        n.saturating_mul(std::mem::size_of::<T>())
    };
    Region {
        start,
        end: start.saturating_add(bytes),
        what,
    }
}

/// The regions of a state's arrays (and of the state itself), the inputs an output must not
/// overlap.
fn state_regions(state: *const kin_state, s: &kin_state) -> [Region; 5] {
    [
        region(state, 1, "state"),
        region(s.q, s.n_q, "q"),
        region(s.inputs, s.n_inputs, "inputs"),
        region(s.lags, s.n_lags, "lags"),
        region(s.dirs, s.n_dirs, "dirs"),
    ]
}

/// A state's regions and β's: the inputs of an evaluation, on the stack (a call allocates
/// nothing on success).
fn with_beta(state: [Region; 5], beta: *const f64, n_beta: usize) -> [Region; 6] {
    let [a, b, c, d, e] = state;
    [a, b, c, d, e, region(beta, n_beta, "beta")]
}

/// Outputs must not share a byte with each other or with an input: written while inputs are
/// still read, they would give wrong results (an `err` inside `jac` is overwritten by the
/// Jacobian).
fn disjoint(outputs: &[Region], inputs: &[Region]) -> Result<(), Fail> {
    let meet = |a: &Region, b: &Region| {
        a.start < a.end && b.start < b.end && a.start < b.end && b.start < a.end
    };
    let overlap = |a: &Region, b: &Region| {
        Fail(
            KIN_ERR_OVERLAP,
            format!(
                "`{}` and `{}` overlap: an output may share memory with no other buffer",
                a.what, b.what
            ),
        )
    };
    // Plain loops: a chained iterator here cost as much as the rest of the checks.
    for (i, out) in outputs.iter().enumerate() {
        for other in &outputs[i + 1..] {
            if meet(out, other) {
                return Err(overlap(out, other));
            }
        }
        for other in inputs {
            if meet(out, other) {
                return Err(overlap(out, other));
            }
        }
    }
    Ok(())
}

/// The values the state may hold: finite joint positions, lag states and time; inputs finite or
/// NaN (not given); directions −1, 0, +1 or NaN (not given). `row` names a batch row.
fn check_values(
    q: &[f64],
    inputs: &[f64],
    lags: &[f64],
    dirs: &[f64],
    time: &[f64],
    widths: [usize; 4],
) -> Result<(), Fail> {
    let row = |k: usize, width: usize| {
        if widths.iter().all(|&w| w == 0) || width == 0 {
            String::new()
        } else {
            format!("row {}: ", k / width)
        }
    };
    let bad = |what: &str, k: usize, width: usize, v: f64, allowed: &str| {
        Fail(
            KIN_ERR_VALUE,
            format!("{}`{what}[{k}]` is {v}: {allowed}", row(k, width)),
        )
    };
    let [wq, wi, wl, wd] = widths;
    if !all_finite(q) {
        if let Some((k, &v)) = q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(bad("q", k, wq, v, "joint positions must be finite"));
        }
    }
    if let Some((k, &v)) = inputs.iter().enumerate().find(|(_, v)| v.is_infinite()) {
        return Err(bad(
            "inputs",
            k,
            wi,
            v,
            "an input is finite, or NaN when not given",
        ));
    }
    if let Some((k, &v)) = lags.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(bad("lags", k, wl, v, "lag states must be finite"));
    }
    if let Some((k, &v)) = dirs
        .iter()
        .enumerate()
        .find(|(_, &v)| !(v.is_nan() || v == 1.0 || v == -1.0 || v == 0.0))
    {
        return Err(bad(
            "dirs",
            k,
            wd,
            v,
            "a direction of motion is -1, 0 or +1 (NaN when not given)",
        ));
    }
    if let Some((k, &v)) = time.iter().enumerate().find(|(_, v)| v.is_infinite()) {
        return Err(Fail(
            KIN_ERR_VALUE,
            format!("`time[{k}]` is {v}: time is finite, or NaN when not given"),
        ));
    }
    Ok(())
}

/// Whether a state holds values it may hold ([`check_values`], without the messages).
///
/// The usual state — every number finite, every direction −1, 0 or +1 — is told without a
/// branch on a value: the numbers by [`finite_bits`], a direction `d` by the bits of
/// `d·d − |d|`, zero only for −1, 0 and +1 (a product rounds to the factor only for these,
/// and a difference is zero only between equal numbers), all OR-ed together. The directions
/// of consecutive poses change unpredictably, and a branch on each mispredicted (an eighth of
/// a whole call in a profile). The rest, NaN where one may stand, each value.
#[inline]
fn state_fine(s: &State) -> bool {
    let dirs = s
        .dirs
        .iter()
        .fold(0u64, |a, d| a | (d * d - d.abs()).to_bits());
    let numbers = finite_bits(s.q)
        | finite_bits(s.inputs)
        | finite_bits(s.lags)
        | finite_bits(std::slice::from_ref(&s.time));
    if numbers | dirs == 0 {
        return true;
    }
    state_fine_each(s)
}

/// [`state_fine`] value by value, when some value is not a finite number or some direction
/// not −1, 0 or +1.
#[cold]
#[inline(never)]
fn state_fine_each(s: &State) -> bool {
    let inputs = s.inputs.iter().fold(true, |ok, v| ok & !v.is_infinite());
    let dirs = s.dirs.iter().fold(true, |ok, d| {
        ok & (d.is_nan() | (d.abs() == 1.0) | (*d == 0.0))
    });
    all_finite(s.q) & all_finite(s.lags) & !s.time.is_infinite() & inputs & dirs
}

fn check_state(s: &State) -> Result<(), Fail> {
    // The common case in one branch-light pass; the messages only when something is wrong.
    if state_fine(s) {
        return Ok(());
    }
    check_values(
        s.q,
        s.inputs,
        s.lags,
        s.dirs,
        std::slice::from_ref(&s.time),
        [0; 4],
    )
}

/// Whether every value is finite. The common answer, yes, comes from one plain sum: an
/// infinity or a NaN among the values makes the sum infinite or NaN (∞ + x = ∞, ∞ − ∞ = NaN,
/// NaN + x = NaN), so a finite sum proves every value finite with one addition per value. Only a
/// sum that is not finite — a bad value, or finite values whose sum overflows — is looked at
/// value by value. On x86-64 with AVX2 the sum runs in eight vectors of four (an addition waits
/// 3–4 cycles for the one before it in its lane; eight independent chains keep both of a
/// core's adders busy): 34 ns for a Jacobian's 1 038 outputs. Written with the vector
/// operations themselves: arrays of lanes left to the compiler were stored to the stack lane by
/// lane and read back as vectors, each such read waiting for the stores (20 ns for five
/// values).
fn all_finite(values: &[f64]) -> bool {
    // A state's few values in one chain of additions: the vector form's set-up (the feature
    // test, the call, eight lanes to reduce) costs more than it saves below a few dozen.
    let sum = if values.len() < SHORT {
        values.iter().fold(0.0, |a, v| a + v).is_finite()
    } else {
        sum_is_finite(values)
    };
    sum || values.iter().all(|v| v.is_finite())
}

/// Below this many values [`all_finite`] adds them one by one.
const SHORT: usize = 16;

fn sum_is_finite(values: &[f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above), the only requirement of the call.
        return unsafe { sum_is_finite_avx2(values) };
    }
    sum_is_finite_portable(values)
}

/// [`sum_is_finite`] in four independent lanes, each added in order.
fn sum_is_finite_portable(values: &[f64]) -> bool {
    let mut lanes = [0.0f64; 4];
    let quads = values.chunks_exact(4);
    let last = quads.remainder();
    for quad in quads {
        for (lane, v) in lanes.iter_mut().zip(quad) {
            *lane += v;
        }
    }
    let sum = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
    last.iter().fold(sum, |a, v| a + v).is_finite()
}

/// [`sum_is_finite`] in AVX2 vectors.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sum_is_finite_avx2(values: &[f64]) -> bool {
    use std::arch::x86_64::{_mm256_add_pd, _mm256_loadu_pd, _mm256_setzero_pd, _mm256_storeu_pd};
    let mut acc = [_mm256_setzero_pd(); 8];
    let chunks = values.chunks_exact(32);
    let rest = chunks.remainder();
    for chunk in chunks {
        for (k, a) in acc.iter_mut().enumerate() {
            // SAFETY: `chunk` holds 32 values and `4k + 4 <= 32`; unaligned loads.
            *a = _mm256_add_pd(*a, unsafe { _mm256_loadu_pd(chunk.as_ptr().add(4 * k)) });
        }
    }
    let quads = rest.chunks_exact(4);
    let last = quads.remainder();
    for quad in quads {
        // SAFETY: `quad` holds 4 values.
        acc[0] = _mm256_add_pd(acc[0], unsafe { _mm256_loadu_pd(quad.as_ptr()) });
    }
    let [a0, a1, a2, a3, a4, a5, a6, a7] = acc;
    let sum = _mm256_add_pd(
        _mm256_add_pd(_mm256_add_pd(a0, a4), _mm256_add_pd(a1, a5)),
        _mm256_add_pd(_mm256_add_pd(a2, a6), _mm256_add_pd(a3, a7)),
    );
    let mut lanes = [0.0f64; 4];
    // SAFETY: `lanes` holds 4 values.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), sum) };
    let sum = (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]);
    last.iter().fold(sum, |a, v| a + v).is_finite()
}

fn check_beta(b: &[f64]) -> Result<(), Fail> {
    if all_finite(b) {
        return Ok(());
    }
    match b.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        Some((k, v)) => Err(Fail(
            KIN_ERR_VALUE,
            format!("`beta[{k}]` is {v}: coefficients must be finite"),
        )),
        None => Ok(()),
    }
}

/// A result that overflowed is not handed out as if it were one.
fn check_results(what: &str, values: &[f64]) -> Result<(), Fail> {
    if all_finite(values) {
        return Ok(());
    }
    match values.iter().position(|v| !v.is_finite()) {
        Some(k) => Err(Fail(
            KIN_ERR_VALUE,
            format!(
                "`{what}[{k}]` came out as {}: the state or β is too large for double precision",
                values[k]
            ),
        )),
        None => Ok(()),
    }
}

/// The arguments of an evaluation call as C passed them (`jac` NULL and 0 for the error
/// alone).
#[derive(Clone, Copy)]
struct EvalArgs {
    model: *const kin_model,
    state: *const kin_state,
    beta: *const f64,
    n_beta: usize,
    err: *mut f64,
    n_err: usize,
    jac: *mut f64,
    n_jac: usize,
}

/// An evaluation's arguments once every check has passed.
struct Quick<'a> {
    model: &'a Model,
    state: State<'a>,
    beta: &'a [f64],
    err: &'a mut [f64],
    jac: &'a mut [f64],
}

/// The checks of an evaluation call in their usual outcome — everything in order — as plain
/// comparisons with no message: `None` as soon as one fails, and the caller then takes its
/// careful path, which makes the same checks one by one and names what is wrong. Every check
/// here is one the careful path makes (the pointers, alignments and sizes of `slice`, the
/// overlaps of `disjoint`, the values of `check_state` and `check_beta`), so nothing passes here
/// that the careful path would refuse; the output lengths against the model are the caller's.
///
/// Why a second path: the generated Jacobian code of a model like the 5-axis example (27 KB)
/// fills most of a core's 32 KiB first-level instruction cache, and the careful path, its
/// messages' formatting inline between the checks, spread one call over many more cache lines
/// than its few comparisons need. Evicting the generated code's lines made it run a quarter
/// slower through the C ABI than called from Rust (cachegrind: 5.8 times the first-level
/// instruction-cache misses per call; 3.7 times with this path, spec/performance.md).
///
/// # Safety
///
/// `a.model` is NULL or a live model, `a.state` NULL or a `kin_state` whose arrays are valid
/// for their lengths, `a.beta` valid for `n_beta` doubles, `a.err` for `n_err` and `a.jac` for
/// `n_jac`, none of them changed by anything else during `'a`.
#[inline(always)]
unsafe fn quick<'a>(a: EvalArgs) -> Option<Quick<'a>> {
    let EvalArgs {
        model,
        state,
        beta,
        n_beta,
        err,
        n_err,
        jac,
        n_jac,
    } = a;
    if model.is_null() || state.is_null() || !state.is_aligned() {
        return None;
    }
    // SAFETY: a live model (caller's contract).
    let m = unsafe { &(*model).model };
    // SAFETY: non-NULL, aligned and valid (caller's contract); `kin_state` is `Copy`.
    let st = unsafe { *state };
    let own = beta.is_null() && n_beta == 0;
    let fine = usable(st.q, st.n_q)
        && usable(st.inputs, st.n_inputs)
        && usable(st.lags, st.n_lags)
        && usable(st.dirs, st.n_dirs)
        && usable(err.cast_const(), n_err)
        && usable(jac.cast_const(), n_jac)
        && (own || (usable(beta, n_beta) && n_beta == m.coefficients()));
    if !fine {
        return None;
    }
    // The regions of `disjoint`, without their names.
    let outputs = [span(err.cast_const(), n_err), span(jac.cast_const(), n_jac)];
    let inputs = [
        span(state, 1),
        span(st.q, st.n_q),
        span(st.inputs, st.n_inputs),
        span(st.lags, st.n_lags),
        span(st.dirs, st.n_dirs),
        span(beta, n_beta),
    ];
    if any_meet(outputs, &inputs) {
        return None;
    }
    // SAFETY: each pointer is NULL with a length of 0, or non-NULL, aligned, of a size that
    // fits an isize (`usable`) and valid for its length (caller's contract); the outputs overlap
    // nothing (checked above) and nothing else uses them (caller's contract).
    let (s, b, err, jac) = unsafe {
        (
            State {
                q: raw(st.q, st.n_q),
                inputs: raw(st.inputs, st.n_inputs),
                lags: raw(st.lags, st.n_lags),
                time: st.time,
                dirs: raw(st.dirs, st.n_dirs),
                tool: st.tool,
                tool_offset: None,
            },
            if own { m.beta() } else { raw(beta, n_beta) },
            raw_mut(err, n_err),
            raw_mut(jac, n_jac),
        )
    };
    // The model's own β was checked when it was set.
    if !state_fine(&s) || !(own || all_finite(b)) {
        return None;
    }
    Some(Quick {
        model: m,
        state: s,
        beta: b,
        err,
        jac,
    })
}

/// The bytes `n` values at `p` cover, as [`region`] counts them, for arguments [`usable`]
/// accepted (the size within an `isize`, so no saturating product); no values as `(0, 0)`,
/// which [`meet`] finds to share no byte with anything.
#[inline(always)]
fn span<T>(p: *const T, n: usize) -> (usize, usize) {
    let start = p as usize;
    let end = start.wrapping_add(n.wrapping_mul(std::mem::size_of::<T>()));
    if n == 0 {
        (0, 0)
    } else {
        (start, end)
    }
}

/// Whether two [`span`]s share a byte, as [`disjoint`] tests it: an empty span, `(0, 0)`, has
/// no start below the other's end.
#[inline(always)]
fn meet(a: (usize, usize), b: (usize, usize)) -> bool {
    (a.0 < b.1) & (b.0 < a.1)
}

/// Whether the two outputs share a byte with each other or with an input: [`meet`] of each
/// pair, without a branch (`|`, not `||`).
#[inline(always)]
fn any_meet(outputs: [(usize, usize); 2], inputs: &[(usize, usize)]) -> bool {
    let [e, j] = outputs;
    inputs
        .iter()
        .fold(meet(e, j), |hit, i| hit | meet(e, *i) | meet(j, *i))
}

/// What [`slice`](fn@slice) accepts: `n` values at `p`, none, or a non-NULL aligned pointer to
/// fewer bytes than an `isize` counts.
fn usable<T>(p: *const T, n: usize) -> bool {
    n == 0
        || (!p.is_null()
            && p.is_aligned()
            && n.checked_mul(std::mem::size_of::<T>())
                .is_some_and(|bytes| bytes <= isize::MAX as usize))
}

/// As [`slice`](fn@slice), for arguments [`usable`] accepted.
///
/// # Safety
///
/// `usable(p, n)`, and `p` valid for `n` values unchanged during `'a`.
unsafe fn raw<'a, T>(p: *const T, n: usize) -> &'a [T] {
    if n == 0 {
        return &[];
    }
    // SAFETY: the caller's contract.
    unsafe { std::slice::from_raw_parts(p, n) }
}

/// As [`slice_mut`], for arguments [`usable`] accepted.
///
/// # Safety
///
/// `usable(p, n)`, and `p` valid for `n` values nothing else uses during `'a`.
unsafe fn raw_mut<'a, T>(p: *mut T, n: usize) -> &'a mut [T] {
    if n == 0 {
        return &mut [];
    }
    // SAFETY: the caller's contract.
    unsafe { std::slice::from_raw_parts_mut(p, n) }
}

/// The `kin_state` behind a pointer, copied, for the overlap checks before any slice exists.
///
/// # Safety
///
/// `state` is NULL or points to a `kin_state`.
unsafe fn read_state(state: *const kin_state) -> Result<kin_state, Fail> {
    if state.is_null() {
        return Err(Fail(KIN_ERR_POINTER, "the state is NULL".into()));
    }
    if !state.is_aligned() {
        return Err(Fail(KIN_ERR_POINTER, "the state is not aligned".into()));
    }
    // SAFETY: non-NULL, aligned and valid (caller's contract); `kin_state` is `Copy`.
    Ok(unsafe { *state })
}

/// The model behind a pointer.
///
/// # Safety
///
/// `model` is NULL or was returned by this library and not freed.
unsafe fn model<'a>(model: *const kin_model) -> Result<&'a Model, Fail> {
    if model.is_null() {
        return Err(Fail(KIN_ERR_POINTER, "the model is NULL".into()));
    }
    // SAFETY: a live `kin_model` from `Box::into_raw` (caller's contract).
    Ok(unsafe { &(*model).model })
}

/// A text given as pointer and length.
///
/// # Safety
///
/// As [`slice`](fn@slice).
unsafe fn text<'a>(p: *const c_char, len: usize, what: &str) -> Result<&'a str, Fail> {
    // SAFETY: caller's contract.
    let bytes = unsafe { slice(p.cast::<u8>(), len, what)? };
    std::str::from_utf8(bytes)
        .map_err(|e| Fail(KIN_ERR_UTF8, format!("`{what}` is not UTF-8: {e}")))
}

/// A NUL-terminated path.
///
/// # Safety
///
/// `p` is NULL or a NUL-terminated string.
unsafe fn path<'a>(p: *const c_char) -> Result<&'a Path, Fail> {
    if p.is_null() {
        return Err(Fail(KIN_ERR_POINTER, "the path is NULL".into()));
    }
    // SAFETY: NUL-terminated (caller's contract).
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map(Path::new)
        .map_err(|e| Fail(KIN_ERR_UTF8, format!("the path is not UTF-8: {e}")))
}

/// Every error diagnostic as `line:column: error[CODE]: message`, one per line.
fn located(source: &str, e: &Error) -> String {
    let mut out = Vec::new();
    for d in e.diagnostics().iter().filter(|d| d.is_error()) {
        let at = d.primary_span().start.min(source.len());
        let before = source.get(..at).unwrap_or("");
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        let mut text = format!("{line}:{column}: error[{}]: {}", d.code, d.message);
        if let Some(help) = &d.help {
            text.push_str(&format!(" (help: {help})"));
        }
        out.push(text);
    }
    out.join("\n")
}

fn model_error(e: Error, source: &str) -> Fail {
    match e {
        Error::Compile { .. } => Fail(KIN_ERR_COMPILE, located(source, &e)),
        Error::Params { .. } => Fail(KIN_ERR_PARAMS, located(source, &e)),
        Error::Values { .. } => Fail(KIN_ERR_SIZE, e.to_string()),
        Error::NotFinite { .. } => Fail(KIN_ERR_VALUE, e.to_string()),
        Error::Io { .. } | Error::Format { .. } => Fail(KIN_ERR_IO, e.to_string()),
        Error::Jit(_) => Fail(KIN_ERR_COMPILE, e.to_string()),
    }
}

fn eval_error(e: EvalError) -> Fail {
    match e {
        EvalError::StateSize { .. } | EvalError::Buffer { .. } => Fail(KIN_ERR_SIZE, e.to_string()),
        EvalError::NotFinite { .. } => Fail(KIN_ERR_VALUE, e.to_string()),
        _ => Fail(KIN_ERR_EVAL, e.to_string()),
    }
}

fn batch_error(e: BatchError) -> Fail {
    match e {
        BatchError::Size { .. } => Fail(KIN_ERR_SIZE, e.to_string()),
        BatchError::Row { row, source } => {
            let Fail(code, message) = eval_error(source);
            Fail(code, format!("row {row}: {message}"))
        }
    }
}

fn check(what: &str, expected: usize, got: usize) -> Result<(), Fail> {
    if expected == got {
        Ok(())
    } else {
        Err(Fail(
            KIN_ERR_SIZE,
            format!("`{what}` has length {got}, {expected} are needed"),
        ))
    }
}

/// The state behind a `kin_state*`.
///
/// # Safety
///
/// `state` is NULL or points to a `kin_state` whose arrays are valid for their lengths.
unsafe fn state<'a>(state: *const kin_state) -> Result<State<'a>, Fail> {
    if state.is_null() {
        return Err(Fail(KIN_ERR_POINTER, "the state is NULL".into()));
    }
    if !state.is_aligned() {
        return Err(Fail(KIN_ERR_POINTER, "the state is not aligned".into()));
    }
    // SAFETY: non-NULL, aligned and valid (caller's contract); `kin_state` is `Copy`.
    let s = unsafe { *state };
    // SAFETY: each array valid for its length (caller's contract).
    unsafe {
        Ok(State {
            q: slice(s.q, s.n_q, "q")?,
            inputs: slice(s.inputs, s.n_inputs, "inputs")?,
            lags: slice(s.lags, s.n_lags, "lags")?,
            time: s.time,
            dirs: slice(s.dirs, s.n_dirs, "dirs")?,
            tool: s.tool,
            tool_offset: None,
        })
    }
}

/// β from the caller, or the model's bound values when `beta` is NULL and `n_beta` 0.
///
/// # Safety
///
/// As [`slice`](fn@slice).
unsafe fn beta(model: &Model, beta: *const f64, n_beta: usize) -> Result<&[f64], Fail> {
    if beta.is_null() && n_beta == 0 {
        return Ok(model.beta());
    }
    // SAFETY: caller's contract.
    let b = unsafe { slice(beta, n_beta, "beta")? };
    check("beta", model.coefficients(), b.len())?;
    Ok(b)
}

fn compensate_error(e: ::kin_model::compensate::CompensateError) -> Fail {
    use ::kin_model::compensate::CompensateError as E;
    match e {
        E::Measuring(_) | E::TooManyAxes(_) => Fail(KIN_ERR_MACHINE, e.to_string()),
        E::Weights => Fail(KIN_ERR_VALUE, e.to_string()),
        E::OutOfRange { .. } => Fail(KIN_ERR_RANGE, e.to_string()),
        E::Eval(e) => eval_error(e),
        E::Kinematics(_) | E::Solve => Fail(KIN_ERR_EVAL, e.to_string()),
        E::Diverges(_) => Fail(KIN_ERR_DIVERGES, e.to_string()),
    }
}

fn servo_error(m: &Model, e: ::kin_model::compensate::ServoError) -> Fail {
    use ::kin_model::compensate::ServoError as E;
    match e {
        E::Size { .. } => Fail(KIN_ERR_SIZE, e.to_string()),
        E::Value { .. } | E::NotFinite(_) => Fail(KIN_ERR_VALUE, e.to_string()),
        E::OutOfRange {
            axis,
            value,
            lo,
            hi,
        } => {
            let name = m
                .machine()
                .axes
                .get(axis)
                .map_or(String::new(), |a| a.name.clone());
            Fail(
                KIN_ERR_RANGE,
                format!(
                    "axis {name} (index {axis}) is commanded to {value} (SI), outside its declared range {lo} .. {hi}"
                ),
            )
        }
        E::Eval(e) => eval_error(e),
        E::Solve => Fail(KIN_ERR_EVAL, e.to_string()),
        E::Diverges(_) => Fail(KIN_ERR_DIVERGES, e.to_string()),
    }
}

/// The library's version, e.g. `"0.1.0"` (a static string).
#[no_mangle]
pub extern "C" fn kin_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// Copies this thread's last error message into `buf` (`len` bytes, NUL-terminated, truncated if
/// need be) and returns its full length in bytes; `buf` may be NULL to ask for the length.
///
/// # Safety
///
/// `buf` is NULL or valid for `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn kin_last_error(buf: *mut c_char, len: usize) -> usize {
    let message = LAST_ERROR.with(|e| e.try_borrow().map(|e| e.clone()).unwrap_or_default());
    // SAFETY: caller's contract.
    unsafe { write_text(buf, len, &message) }
}

/// Records a failure's message in `err` too (for the functions that take a buffer).
///
/// # Safety
///
/// As [`write_text`].
unsafe fn with_err_buffer(code: c_int, err: *mut c_char, err_len: usize) -> c_int {
    let message = if code == KIN_OK {
        String::new()
    } else {
        LAST_ERROR.with(|e| e.try_borrow().map(|e| e.clone()).unwrap_or_default())
    };
    // SAFETY: caller's contract.
    unsafe { write_text(err, err_len, &message) };
    code
}

/// Compiles `len` bytes of `.kin` source at `src` (a machine, optionally followed by its
/// `params`) to native code. On success `*out` is the model (free it with `kin_model_free`);
/// on failure `*out` is NULL and the message — every error as `line:column: error[CODE]: …` —
/// is written to `err` (`err_len` bytes, may be NULL) and kept for `kin_last_error`.
///
/// # Safety
///
/// `src` is valid for `len` bytes, `out` is NULL or valid for writing one pointer, `err` is NULL
/// or valid for `err_len` bytes.
#[no_mangle]
pub unsafe extern "C" fn kin_model_compile(
    src: *const c_char,
    len: usize,
    out: *mut *mut kin_model,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    let code = guard(|| {
        let out = out_pointer(out)?;
        // SAFETY: caller's contract.
        let source = unsafe { text(src, len, "src")? };
        let model = Model::compile(source).map_err(|e| model_error(e, source))?;
        // SAFETY: `out` checked non-NULL and aligned; valid for writing (caller's contract).
        unsafe { *out = Box::into_raw(Box::new(kin_model { model })) };
        Ok(())
    });
    // SAFETY: caller's contract.
    unsafe { with_err_buffer(code, err, err_len) }
}

/// Checks `out` and sets `*out` to NULL, so a failure leaves no dangling value.
fn out_pointer(out: *mut *mut kin_model) -> Result<*mut *mut kin_model, Fail> {
    if out.is_null() {
        return Err(Fail(KIN_ERR_POINTER, "`out` is NULL".into()));
    }
    if !out.is_aligned() {
        return Err(Fail(KIN_ERR_POINTER, "`out` is not aligned".into()));
    }
    // SAFETY: non-NULL, aligned; valid for writing (the callers' contract).
    unsafe { *out = std::ptr::null_mut() };
    Ok(out)
}

/// Binds a parameter text (`params { … }`, `len` bytes) on top of the model's values. On failure
/// the model is unchanged. Not while other threads use the model.
///
/// # Safety
///
/// `model` is a live model, `src` valid for `len` bytes, `err` NULL or valid for `err_len` bytes.
#[no_mangle]
pub unsafe extern "C" fn kin_model_bind_params(
    model: *mut kin_model,
    src: *const c_char,
    len: usize,
    err: *mut c_char,
    err_len: usize,
) -> c_int {
    let code = guard(|| {
        if model.is_null() {
            return Err(Fail(KIN_ERR_POINTER, "the model is NULL".into()));
        }
        // SAFETY: caller's contract.
        let params = unsafe { text(src, len, "src")? };
        // SAFETY: a live model, not used elsewhere meanwhile (caller's contract).
        let m = unsafe { &mut (*model).model };
        m.bind_params(params).map_err(|e| model_error(e, params))
    });
    // SAFETY: caller's contract.
    unsafe { with_err_buffer(code, err, err_len) }
}

/// Saves the model (source, bound parameter texts, exact values) as JSON to the file at `path`
/// (NUL-terminated).
///
/// # Safety
///
/// `model` is a live model, `path` a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn kin_model_save(model: *const kin_model, path: *const c_char) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let (m, p) = unsafe { (self::model(model)?, self::path(path)?) };
        m.save(p).map_err(|e| model_error(e, ""))
    })
}

/// Loads a model saved by `kin_model_save` (or `Model::save`): the source is compiled again and
/// the values restored exactly. `*out` as for `kin_model_compile`.
///
/// # Safety
///
/// `path` is a NUL-terminated string, `out` NULL or valid for writing one pointer.
#[no_mangle]
pub unsafe extern "C" fn kin_model_load(path: *const c_char, out: *mut *mut kin_model) -> c_int {
    guard(|| {
        let out = out_pointer(out)?;
        // SAFETY: caller's contract.
        let p = unsafe { self::path(path)? };
        let model = Model::load(p).map_err(|e| match e {
            Error::Compile { .. } | Error::Params { .. } => {
                Fail(KIN_ERR_IO, format!("{}: {e}", p.display()))
            }
            e => model_error(e, ""),
        })?;
        // SAFETY: checked by `out_pointer`; valid for writing (caller's contract).
        unsafe { *out = Box::into_raw(Box::new(kin_model { model })) };
        Ok(())
    })
}

/// Frees a model; NULL is ignored.
///
/// # Safety
///
/// `model` is NULL or a live model that no other thread is using; it is invalid afterwards.
#[no_mangle]
pub unsafe extern "C" fn kin_model_free(model: *mut kin_model) {
    if !model.is_null() {
        // Dropping frees the native code; a panic in a destructor must not unwind into C.
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: from `Box::into_raw` in this library, not freed before (caller's contract).
            drop(unsafe { Box::from_raw(model) });
        }));
    }
}

/// Reads a count of a model; 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
unsafe fn count(model: *const kin_model, f: impl Fn(&Model) -> usize) -> usize {
    // SAFETY: caller's contract.
    unsafe { self::model(model) }.map_or(0, f)
}

/// Number of axes (joint positions per state); 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn kin_model_axes(model: *const kin_model) -> usize {
    // SAFETY: caller's contract.
    unsafe { count(model, Model::axes) }
}

/// Number of declared inputs; 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn kin_model_inputs(model: *const kin_model) -> usize {
    // SAFETY: caller's contract.
    unsafe { count(model, Model::inputs) }
}

/// Number of lag states; 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn kin_model_lags(model: *const kin_model) -> usize {
    // SAFETY: caller's contract.
    unsafe { count(model, Model::lags) }
}

/// Number of tools; 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn kin_model_tools(model: *const kin_model) -> usize {
    // SAFETY: caller's contract.
    unsafe { count(model, Model::tools) }
}

/// Number of coefficients β (the Jacobian has 6 × this many entries); 0 for NULL.
///
/// # Safety
///
/// `model` is NULL or a live model.
#[no_mangle]
pub unsafe extern "C" fn kin_model_coefficients(model: *const kin_model) -> usize {
    // SAFETY: caller's contract.
    unsafe { count(model, Model::coefficients) }
}

/// The declared range of axis `axis` (m or rad; `[0, 2π]` for a continuous axis).
///
/// # Safety
///
/// `model` is a live model, `lo` and `hi` valid for writing one double each.
#[no_mangle]
pub unsafe extern "C" fn kin_model_axis_range(
    model: *const kin_model,
    axis: usize,
    lo: *mut f64,
    hi: *mut f64,
) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let (m, lo, hi) = unsafe {
            (
                self::model(model)?,
                slice_mut(lo, 1, "lo")?,
                slice_mut(hi, 1, "hi")?,
            )
        };
        let Some(a) = m.machine().axes.get(axis) else {
            return Err(Fail(KIN_ERR_INDEX, format!("axis {axis} of {}", m.axes())));
        };
        lo.copy_from_slice(&a.range[..1]);
        hi.copy_from_slice(&a.range[1..]);
        Ok(())
    })
}

/// A typical range of input `input` (SI): the declared one, or — as the sampled states of
/// `kin check` use — 18–22 °C for an absolute temperature, 0–4 K for a temperature rise,
/// 0–1000 N for a force, 0–1 otherwise.
///
/// # Safety
///
/// `model` is a live model, `lo` and `hi` valid for writing one double each.
#[no_mangle]
pub unsafe extern "C" fn kin_model_input_range(
    model: *const kin_model,
    input: usize,
    lo: *mut f64,
    hi: *mut f64,
) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let (m, lo, hi) = unsafe {
            (
                self::model(model)?,
                slice_mut(lo, 1, "lo")?,
                slice_mut(hi, 1, "hi")?,
            )
        };
        let Some(i) = m.machine().inputs.get(input) else {
            return Err(Fail(
                KIN_ERR_INDEX,
                format!("input {input} of {}", m.inputs()),
            ));
        };
        use kin_compiler::units::Dim;
        let range = match i.range {
            Some(r) => r,
            None if i.unit.dim == Dim::TEMPERATURE && i.absolute => [291.15, 295.15],
            None if i.unit.dim == Dim::TEMPERATURE => [0.0, 4.0],
            None if i.unit.dim == Dim::FORCE => [0.0, 1000.0],
            None => [0.0, 1.0],
        };
        lo.copy_from_slice(&range[..1]);
        hi.copy_from_slice(&range[1..]);
        Ok(())
    })
}

/// The input whose lag lag state `lag` is (its steady state equals that input's value);
/// `KIN_ERR_INDEX` for a warm-up's state, which follows no input (its steady state is 1).
///
/// # Safety
///
/// `model` is a live model, `input` valid for writing one `size_t`.
#[no_mangle]
pub unsafe extern "C" fn kin_model_lag_input(
    model: *const kin_model,
    lag: usize,
    input: *mut usize,
) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let (m, out) = unsafe { (self::model(model)?, slice_mut(input, 1, "input")?) };
        let Some(l) = m.machine().lags.get(lag) else {
            return Err(Fail(KIN_ERR_INDEX, format!("lag {lag} of {}", m.lags())));
        };
        // A warm-up follows the constant 1 from each run's start, not an input: answering an
        // input index would have the caller feed it that input's value.
        if l.warmup {
            return Err(Fail(
                KIN_ERR_INDEX,
                format!("lag {lag} is a warm-up (`warmup(time, …)`): it follows no input; its steady state is 1"),
            ));
        }
        out.copy_from_slice(&[l.input]);
        Ok(())
    })
}

/// Copies a name — of axis `index` (`what` = 0), input (1), tool (2) or coefficient (3) — into
/// `buf` as [`kin_last_error`] does; returns its length, or -1 (as `(size_t)-1`) if `what` or
/// `index` is out of range or the model is NULL.
///
/// # Safety
///
/// `model` is NULL or a live model, `buf` NULL or valid for `len` bytes.
#[no_mangle]
pub unsafe extern "C" fn kin_model_name(
    model: *const kin_model,
    what: c_int,
    index: usize,
    buf: *mut c_char,
    len: usize,
) -> usize {
    let name = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: caller's contract.
        let m = unsafe { self::model(model) }.ok()?.machine();
        match what {
            0 => m.axes.get(index).map(|a| a.name.clone()),
            1 => m.inputs.get(index).map(|a| a.name.clone()),
            2 => m.tools.get(index).map(|a| a.name.clone()),
            3 => m.coefficients.get(index).map(|a| a.name.clone()),
            _ => None,
        }
    }));
    match name {
        // SAFETY: caller's contract.
        Ok(Some(name)) => unsafe { write_text(buf, len, &name) },
        _ => usize::MAX,
    }
}

/// Copies the model's bound coefficient values (SI; zeros where none was bound) into `beta`
/// (`n_beta` = the number of coefficients).
///
/// # Safety
///
/// `model` is a live model, `beta` valid for `n_beta` doubles.
#[no_mangle]
pub unsafe extern "C" fn kin_model_beta(
    model: *const kin_model,
    beta: *mut f64,
    n_beta: usize,
) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let (m, out) = unsafe { (self::model(model)?, slice_mut(beta, n_beta, "beta")?) };
        check("beta", m.coefficients(), out.len())?;
        out.copy_from_slice(m.beta());
        Ok(())
    })
}

/// Replaces the model's coefficient values (e.g. with a fit's); a value that is not finite is
/// `KIN_ERR_VALUE` and leaves the values as they were. Not while other threads use the model.
///
/// # Safety
///
/// `model` is a live model, `beta` valid for `n_beta` doubles.
#[no_mangle]
pub unsafe extern "C" fn kin_model_set_beta(
    model: *mut kin_model,
    beta: *const f64,
    n_beta: usize,
) -> c_int {
    guard(|| {
        if model.is_null() {
            return Err(Fail(KIN_ERR_POINTER, "the model is NULL".into()));
        }
        // SAFETY: caller's contract.
        let values = unsafe { slice(beta, n_beta, "beta")? };
        // SAFETY: a live model, not used elsewhere meanwhile (caller's contract).
        let m = unsafe { &mut (*model).model };
        m.set_beta(values).map_err(|e| model_error(e, ""))
    })
}

/// The tool-location error at `state` for coefficients `beta` (`n_beta` values; NULL and 0 for
/// the model's bound values): `err` receives (ex, ey, ez, erx, ery, erz) with the task's sign,
/// `n_err` must be 6.
///
/// # Safety
///
/// `model` is a live model, `state` a valid `kin_state`, `beta` valid for `n_beta` doubles and
/// `err` for `n_err`.
#[no_mangle]
pub unsafe extern "C" fn kin_eval(
    model: *const kin_model,
    state: *const kin_state,
    beta: *const f64,
    n_beta: usize,
    err: *mut f64,
    n_err: usize,
) -> c_int {
    guard(|| {
        let a = EvalArgs {
            model,
            state,
            beta,
            n_beta,
            err,
            n_err,
            jac: std::ptr::null_mut(),
            n_jac: 0,
        };
        // SAFETY: the caller's contract.
        if unsafe { quick_eval(a) } {
            return Ok(());
        }
        // SAFETY: the caller's contract.
        unsafe { careful_eval(a) }
    })
}

/// [`kin_eval`] when every check passes, with no message: see [`quick`].
///
/// # Safety
///
/// As [`kin_eval`].
unsafe fn quick_eval(a: EvalArgs) -> bool {
    // SAFETY: the caller's contract.
    let Some(c) = (unsafe { quick(a) }) else {
        return false;
    };
    let Ok(out) = <&mut [f64; 6]>::try_from(c.err) else {
        return false;
    };
    // `Model` hands back finite values or an error.
    c.model.eval(&c.state, c.beta, out).is_ok()
}

/// [`kin_eval`] checking each argument in turn and naming what is wrong.
///
/// # Safety
///
/// As [`kin_eval`].
#[cold]
#[inline(never)]
unsafe fn careful_eval(a: EvalArgs) -> Result<(), Fail> {
    let EvalArgs {
        model,
        state,
        beta,
        n_beta,
        err,
        n_err,
        ..
    } = a;
    // SAFETY: caller's contract.
    let st = unsafe { read_state(state)? };
    let inputs = with_beta(state_regions(state, &st), beta, n_beta);
    disjoint(&[region(err.cast_const(), n_err, "err")], &inputs)?;
    // SAFETY: caller's contract; `err` overlaps no input (checked above).
    let (m, s, out) = unsafe {
        (
            self::model(model)?,
            self::state(state)?,
            slice_mut(err, n_err, "err")?,
        )
    };
    // SAFETY: caller's contract.
    let b = unsafe { self::beta(m, beta, n_beta)? };
    let out: &mut [f64; 6] = out.try_into().map_err(|_| {
        Fail(
            KIN_ERR_SIZE,
            format!("`err` has length {n_err}, 6 are needed"),
        )
    })?;
    check_state(&s)?;
    // The model's own β was checked when it was set.
    if !beta.is_null() {
        check_beta(b)?;
    }
    m.eval(&s, b, out).map_err(eval_error)
}

/// The error and its Jacobian with respect to β: `jac` (`n_jac` = 6 × coefficients) receives the
/// 6 × n matrix row-major (row r is error component r), so that `err = fixed + jac·β`.
///
/// # Safety
///
/// As [`kin_eval`], and `jac` valid for `n_jac` doubles.
#[no_mangle]
pub unsafe extern "C" fn kin_eval_jacobian(
    model: *const kin_model,
    state: *const kin_state,
    beta: *const f64,
    n_beta: usize,
    err: *mut f64,
    n_err: usize,
    jac: *mut f64,
    n_jac: usize,
) -> c_int {
    // SAFETY: the caller's contract, every component observed (the same code and results).
    unsafe { kin_eval_jacobian_observed(model, state, beta, n_beta, 63, err, n_err, jac, n_jac) }
}

/// [`kin_eval_jacobian`] of some components only: bit c of `observed` (1 … 63) selects error
/// component c (bits 0–2 the position ex, ey, ez: `observed` = 7 for a tracker's positions, 63
/// for the full pose). `err` (`n_err` = the number of bits set) receives the selected
/// components in order and `jac` (`n_jac` = that times the coefficients) their rows of the
/// Jacobian, row-major; code for those rows alone does the work (half of it for positions).
///
/// # Safety
///
/// As [`kin_eval_jacobian`].
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn kin_eval_jacobian_observed(
    model: *const kin_model,
    state: *const kin_state,
    beta: *const f64,
    n_beta: usize,
    observed: u32,
    err: *mut f64,
    n_err: usize,
    jac: *mut f64,
    n_jac: usize,
) -> c_int {
    guard(|| {
        let a = EvalArgs {
            model,
            state,
            beta,
            n_beta,
            err,
            n_err,
            jac,
            n_jac,
        };
        if let Some(selected) = Observed::from_bits(observed) {
            // SAFETY: the caller's contract.
            if unsafe { quick_jacobian(a, selected) } {
                return Ok(());
            }
        }
        // SAFETY: the caller's contract.
        unsafe { careful_jacobian(a, observed) }
    })
}

/// [`kin_eval_jacobian_observed`] when every check passes, with no message: see [`quick`].
///
/// # Safety
///
/// As [`kin_eval_jacobian_observed`].
unsafe fn quick_jacobian(a: EvalArgs, selected: Observed) -> bool {
    // SAFETY: the caller's contract.
    let Some(c) = (unsafe { quick(a) }) else {
        return false;
    };
    // `Model` checks the outputs' lengths against the rows (an error sends the caller to the
    // careful path, which names them) and hands back finite values or an error: the
    // processor's overflow flags vouch for the Jacobian's, so no pass over its outputs here.
    c.model
        .eval_jacobian_observed(&c.state, c.beta, selected, c.err, c.jac)
        .is_ok()
}

/// [`kin_eval_jacobian_observed`] checking each argument in turn and naming what is wrong.
///
/// # Safety
///
/// As [`kin_eval_jacobian_observed`].
#[cold]
#[inline(never)]
unsafe fn careful_jacobian(a: EvalArgs, observed: u32) -> Result<(), Fail> {
    let EvalArgs {
        model,
        state,
        beta,
        n_beta,
        err,
        n_err,
        jac,
        n_jac,
    } = a;
    let Some(selected) = Observed::from_bits(observed) else {
        return Err(Fail(
            KIN_ERR_VALUE,
            format!("`observed` is {observed}: one bit per component, from 1 to 63"),
        ));
    };
    let rows = selected.rows();
    // SAFETY: caller's contract.
    let st = unsafe { read_state(state)? };
    let inputs = with_beta(state_regions(state, &st), beta, n_beta);
    disjoint(
        &[
            region(err.cast_const(), n_err, "err"),
            region(jac.cast_const(), n_jac, "jac"),
        ],
        &inputs,
    )?;
    // SAFETY: caller's contract; the outputs overlap nothing (checked above).
    let (m, s, out, jac) = unsafe {
        (
            self::model(model)?,
            self::state(state)?,
            slice_mut(err, n_err, "err")?,
            slice_mut(jac, n_jac, "jac")?,
        )
    };
    // SAFETY: caller's contract.
    let b = unsafe { self::beta(m, beta, n_beta)? };
    check("err", rows, out.len())?;
    check("jac", rows * m.coefficients(), jac.len())?;
    check_state(&s)?;
    // The model's own β was checked when it was set.
    if !beta.is_null() {
        check_beta(b)?;
    }
    m.eval_jacobian_observed(&s, b, selected, out, jac)
        .map_err(eval_error)
}

/// The nominal tool location in the workpiece frame — `location` (`n_location` = 12) receives
/// the position (3) and then the rotation matrix R(wr→tl) row-major (9) — and its Jacobian with
/// respect to the joint positions: `jac` (`n_jac` = 6 × axes), entries `6j .. 6j+6` are
/// (dp/dq_j, ω_j).
///
/// # Safety
///
/// `model` is a live model, `state` a valid `kin_state`, `location` valid for `n_location`
/// doubles and `jac` for `n_jac`.
#[no_mangle]
pub unsafe extern "C" fn kin_nominal_jacobian(
    model: *const kin_model,
    state: *const kin_state,
    location: *mut f64,
    n_location: usize,
    jac: *mut f64,
    n_jac: usize,
) -> c_int {
    guard(|| {
        // SAFETY: caller's contract.
        let st = unsafe { read_state(state)? };
        disjoint(
            &[
                region(location.cast_const(), n_location, "location"),
                region(jac.cast_const(), n_jac, "jac"),
            ],
            &state_regions(state, &st),
        )?;
        // SAFETY: caller's contract; the outputs overlap nothing (checked above).
        let (m, s, loc, jac) = unsafe {
            (
                self::model(model)?,
                self::state(state)?,
                slice_mut(location, n_location, "location")?,
                slice_mut(jac, n_jac, "jac")?,
            )
        };
        check("location", 12, loc.len())?;
        check("jac", 6 * m.axes(), jac.len())?;
        check_state(&s)?;
        let l = m.nominal_jacobian(&s, jac).map_err(eval_error)?;
        check_results("jac", jac)?;
        let r = &l.rotation;
        let values = [
            l.position.x,
            l.position.y,
            l.position.z,
            r.m11,
            r.m12,
            r.m13,
            r.m21,
            r.m22,
            r.m23,
            r.m31,
            r.m32,
            r.m33,
        ];
        check_results("location", &values)?;
        loc.copy_from_slice(&values);
        Ok(())
    })
}

/// [`kin_eval_jacobian`] over `rows->n_rows` states: `err` (`n_err` = 6 × rows) receives 6 values
/// per row and `jac` (`n_jac` = 6 × coefficients × rows) one 6 × n block per row. With `jac` NULL
/// and `n_jac` 0 only the errors are computed. Stops at the first row that cannot be evaluated
/// (the message names it).
///
/// # Safety
///
/// `model` is a live model, `rows` a valid `kin_rows`, `beta` valid for `n_beta` doubles, `err`
/// for `n_err` and `jac` for `n_jac`.
#[no_mangle]
pub unsafe extern "C" fn kin_eval_batch(
    model: *const kin_model,
    rows: *const kin_rows,
    beta: *const f64,
    n_beta: usize,
    err: *mut f64,
    n_err: usize,
    jac: *mut f64,
    n_jac: usize,
) -> c_int {
    // SAFETY: the caller's contract, every component observed (the same code and results).
    unsafe { kin_eval_batch_observed(model, rows, beta, n_beta, 63, err, n_err, jac, n_jac) }
}

/// [`kin_eval_batch`] of some components only, selected by `observed` as in
/// [`kin_eval_jacobian_observed`]: `err` (`n_err` = k × rows, k the bits set) receives k values
/// per row and `jac` (`n_jac` = k × coefficients × rows) one k × n block per row, each row the
/// bits [`kin_eval_jacobian_observed`] gives at that state. Nothing is computed or stored for
/// the other components (a tracker's positions: half the work and memory of full poses).
///
/// # Safety
///
/// As [`kin_eval_batch`].
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn kin_eval_batch_observed(
    model: *const kin_model,
    rows: *const kin_rows,
    beta: *const f64,
    n_beta: usize,
    observed: u32,
    err: *mut f64,
    n_err: usize,
    jac: *mut f64,
    n_jac: usize,
) -> c_int {
    guard(|| {
        let Some(selected) = Observed::from_bits(observed) else {
            return Err(Fail(
                KIN_ERR_VALUE,
                format!("`observed` is {observed}: one bit per component, from 1 to 63"),
            ));
        };
        if rows.is_null() || !rows.is_aligned() {
            return Err(Fail(KIN_ERR_POINTER, "`rows` is NULL or misaligned".into()));
        }
        // SAFETY: non-NULL and aligned, valid (caller's contract); `kin_rows` is `Copy`.
        let r = unsafe { *rows };
        disjoint(
            &[
                region(err.cast_const(), n_err, "err"),
                region(jac.cast_const(), n_jac, "jac"),
            ],
            &[
                region(rows, 1, "rows"),
                region(r.q, r.n_q, "q"),
                region(r.inputs, r.n_inputs, "inputs"),
                region(r.lags, r.n_lags, "lags"),
                region(r.dirs, r.n_dirs, "dirs"),
                region(r.time, r.n_time, "time"),
                region(r.tool, r.n_tool, "tool"),
                region(beta, n_beta, "beta"),
            ],
        )?;
        // SAFETY: caller's contract; the outputs overlap nothing (checked above).
        let (m, out, jac) = unsafe {
            (
                self::model(model)?,
                slice_mut(err, n_err, "err")?,
                slice_mut(jac, n_jac, "jac")?,
            )
        };
        // SAFETY: caller's contract.
        let b = unsafe { self::beta(m, beta, n_beta)? };
        check("time", r.n_rows, r.n_time)?;
        // SAFETY: each array valid for its length (caller's contract).
        let state_rows = unsafe {
            StateRows {
                q: slice(r.q, r.n_q, "q")?,
                inputs: slice(r.inputs, r.n_inputs, "inputs")?,
                lags: slice(r.lags, r.n_lags, "lags")?,
                time: slice(r.time, r.n_time, "time")?,
                dirs: slice(r.dirs, r.n_dirs, "dirs")?,
                tool: slice(r.tool, r.n_tool, "tool")?,
                tool_offset: &[],
            }
        };
        check_values(
            state_rows.q,
            state_rows.inputs,
            state_rows.lags,
            state_rows.dirs,
            state_rows.time,
            [m.axes(), m.inputs(), m.lags(), m.axes()],
        )?;
        // The model's own β was checked when it was set.
        if !beta.is_null() {
            check_beta(b)?;
        }
        if jac.is_empty() && m.coefficients() > 0 && r.n_rows > 0 {
            m.eval_rows_observed(&state_rows, b, selected, out)
                .map_err(batch_error)?;
        } else {
            m.eval_jacobian_rows_observed(&state_rows, b, selected, out, jac)
                .map_err(batch_error)?;
        }
        // `Model` hands back finite values or names the row that is not.
        Ok(())
    })
}

/// Makes the compensation function of a positioning machine with the model's bound values
/// (thesis §2.3.5): the joint corrections that cancel the predicted tool-location error. The
/// compensator keeps its own copy of the model (later changes to `model` do not reach it).
/// `weights` (`n_weights` = 6, or NULL and 0 for every component with a rotation weighed as the
/// fit weighs it) weigh `(ex, ey, ez, erx, ery, erz)` in SI; 0 leaves a component out.
/// `iterations` bounds the linear solves per call (0: the default, 4). The corrections move
/// every axis, except with position weights alone (`erx`, `ery`, `erz` weighed 0), where only
/// the prismatic axes move (every axis of a machine with none), as `kin compensate --correct
/// position` does; [`kin_compensator_new_axes`] chooses them.
///
/// # Safety
///
/// `model` is a live model, `weights` valid for `n_weights` doubles, `out` valid for writing.
#[no_mangle]
pub unsafe extern "C" fn kin_compensator_new(
    model: *const kin_model,
    weights: *const f64,
    n_weights: usize,
    iterations: usize,
    out: *mut *mut kin_compensator,
) -> c_int {
    // SAFETY: the caller's contract, with no axes given.
    unsafe {
        kin_compensator_new_axes(
            model,
            weights,
            n_weights,
            iterations,
            std::ptr::null(),
            0,
            out,
        )
    }
}

/// As [`kin_compensator_new`], with the axes the corrections may move: `movable` (`n_movable` =
/// axes) holds 1 for an axis that may move and 0 for one held at its commanded position, or is
/// NULL and 0 for the default of [`kin_compensator_new`].
///
/// # Safety
///
/// As [`kin_compensator_new`]; `movable` valid for `n_movable` bytes.
#[no_mangle]
pub unsafe extern "C" fn kin_compensator_new_axes(
    model: *const kin_model,
    weights: *const f64,
    n_weights: usize,
    iterations: usize,
    movable: *const u8,
    n_movable: usize,
    out: *mut *mut kin_compensator,
) -> c_int {
    guard(|| {
        if out.is_null() {
            return Err(Fail(KIN_ERR_POINTER, "`out` is NULL".into()));
        }
        if !out.is_aligned() {
            return Err(Fail(KIN_ERR_POINTER, "`out` is not aligned".into()));
        }
        // SAFETY: caller's contract.
        let m = unsafe { self::model(model)? };
        let mut options = ::kin_model::compensate::Options::pose(m.machine());
        if !(weights.is_null() && n_weights == 0) {
            // SAFETY: caller's contract.
            let w = unsafe { slice(weights, n_weights, "weights")? };
            check("weights", 6, w.len())?;
            options.weights.copy_from_slice(w);
            if options.weights[3..].iter().all(|w| *w == 0.0) {
                options.movable = ::kin_model::compensate::Movable::prismatic_or_all(m.machine());
            }
        }
        if !(movable.is_null() && n_movable == 0) {
            // SAFETY: caller's contract.
            let flags = unsafe { slice(movable, n_movable, "movable")? };
            check("movable", m.axes(), flags.len())?;
            if let Some(bad) = flags.iter().find(|f| **f > 1) {
                return Err(Fail(
                    KIN_ERR_VALUE,
                    format!("`movable` holds {bad}: 1 (may move) or 0 (held)"),
                ));
            }
            options.movable = ::kin_model::compensate::Movable::only(
                flags
                    .iter()
                    .enumerate()
                    .filter(|(_, f)| **f == 1)
                    .map(|(j, _)| j),
            );
        }
        if iterations > 0 {
            options.iterations = iterations;
        }
        let comp = m.compensator(options).map_err(compensate_error)?;
        // SAFETY: checked above; valid for writing (caller's contract).
        unsafe { *out = Box::into_raw(Box::new(kin_compensator { comp })) };
        Ok(())
    })
}

/// Frees a compensator; NULL is ignored.
///
/// # Safety
///
/// `comp` is NULL or a live compensator no other thread is using; it is invalid afterwards.
#[no_mangle]
pub unsafe extern "C" fn kin_compensator_free(comp: *mut kin_compensator) {
    if !comp.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: from `Box::into_raw` in this library, not freed before (caller's contract).
            drop(unsafe { Box::from_raw(comp) });
        }));
    }
}

/// The correction of the commanded pose `state`: `dq` (`n_dq` = axes) receives the values to add
/// to the commanded joint positions (m, rad). `before` and `after` (6 each, or NULL and 0)
/// receive the predicted error at the commanded pose and that of the compensated pose (what the
/// joints cannot correct); `rank` (or NULL) how many independent combinations of the weighted
/// components the joints can move. Allocates nothing on success and takes no lock: many threads
/// may call it on one compensator at once.
///
/// # Safety
///
/// `comp` is a live compensator, `state` a valid `kin_state`, each output valid for its length.
#[no_mangle]
pub unsafe extern "C" fn kin_compensate(
    comp: *const kin_compensator,
    state: *const kin_state,
    dq: *mut f64,
    n_dq: usize,
    before: *mut f64,
    n_before: usize,
    after: *mut f64,
    n_after: usize,
    rank: *mut usize,
) -> c_int {
    guard(|| {
        if comp.is_null() {
            return Err(Fail(KIN_ERR_POINTER, "the compensator is NULL".into()));
        }
        // SAFETY: caller's contract.
        let st = unsafe { read_state(state)? };
        disjoint(
            &[
                region(dq.cast_const(), n_dq, "dq"),
                region(before.cast_const(), n_before, "before"),
                region(after.cast_const(), n_after, "after"),
                region(rank.cast_const(), usize::from(!rank.is_null()), "rank"),
            ],
            &state_regions(state, &st),
        )?;
        if !rank.is_null() && !rank.is_aligned() {
            return Err(Fail(KIN_ERR_POINTER, "`rank` is not aligned".into()));
        }
        // SAFETY: a live compensator (caller's contract); the outputs overlap nothing.
        let (c, s, dq, before, after) = unsafe {
            (
                &(*comp).comp,
                self::state(state)?,
                slice_mut(dq, n_dq, "dq")?,
                slice_mut(before, n_before, "before")?,
                slice_mut(after, n_after, "after")?,
            )
        };
        for (what, n) in [("before", before.len()), ("after", after.len())] {
            if n != 0 && n != 6 {
                return Err(Fail(
                    KIN_ERR_SIZE,
                    format!("`{what}` has length {n}, 6 (or 0 with NULL) are needed"),
                ));
            }
        }
        check_state(&s)?;
        let done = c
            .compensate(&s, dq)
            .map_err(|e| servo_error(c.model(), e))?;
        if before.len() == 6 {
            before.copy_from_slice(&done.before);
        }
        if after.len() == 6 {
            after.copy_from_slice(&done.after);
        }
        if !rank.is_null() {
            // SAFETY: non-NULL, aligned, valid for writing (caller's contract).
            unsafe { *rank = done.rank };
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The check agrees with `is_finite` on the edge values at every position of the lanes and
    /// of the tail; a bad value always makes the sum not finite (both the form this CPU
    /// dispatches to and the portable one), and finite values whose sum overflows are finite.
    #[test]
    fn all_finite_is_exact() {
        let edges = [
            0.0,
            -0.0,
            f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            f64::MIN,
            1.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        for len in [0, 1, 7, 31, 32, 33, 64, 100] {
            for at in 0..len {
                for bad in edges {
                    let mut v = vec![1.5; len];
                    v[at] = bad;
                    let expected = v.iter().all(|x| x.is_finite());
                    assert_eq!(all_finite(&v), expected, "{len} {at} {bad}");
                    if !expected {
                        assert!(!sum_is_finite(&v), "{len} {at} {bad}");
                        assert!(!sum_is_finite_portable(&v), "{len} {at} {bad}");
                    }
                }
            }
        }
        // +∞ and −∞ in different lanes, and sums that overflow with every value finite.
        let mut v = vec![0.0; 64];
        v[3] = f64::INFINITY;
        v[40] = f64::NEG_INFINITY;
        assert!(!all_finite(&v));
        for len in [2, 33, 70] {
            let v = vec![f64::MAX; len];
            assert!(!sum_is_finite(&v) && !sum_is_finite_portable(&v));
            assert!(all_finite(&v), "{len} values of f64::MAX are finite");
        }
    }

    /// The quick test of a state (the bits of `v − v` and `d·d − |d|`) answers as the test of
    /// each value does, for every kind of value in every place.
    #[test]
    fn state_fine_is_exact() {
        let edges = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            1.0 + f64::EPSILON,
            1.0 - f64::EPSILON / 2.0,
            -1.0 - f64::EPSILON,
            0.5,
            2.0,
            f64::MIN_POSITIVE,
            5e-324,
            -5e-324,
            1e-200,
            1e200,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            -f64::NAN,
        ];
        // Also values from every part of the range: the bits of a simple generator.
        let mut x = 0x9e37_79b9_7f4a_7c15_u64;
        let random = (0..4000).map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            f64::from_bits(x)
        });
        let values: Vec<f64> = edges.into_iter().chain(random).collect();
        let (q, inputs, lags, dirs) = ([0.3; 3], [20.0; 2], [0.1; 2], [1.0, -1.0, 0.0]);
        for &v in &values {
            for place in 0..5 {
                let (mut q, mut inputs, mut lags, mut dirs, mut time) =
                    (q, inputs, lags, dirs, 60.0);
                match place {
                    0 => q[1] = v,
                    1 => inputs[0] = v,
                    2 => lags[1] = v,
                    3 => dirs[2] = v,
                    _ => time = v,
                }
                let s = State {
                    q: &q,
                    inputs: &inputs,
                    lags: &lags,
                    time,
                    dirs: &dirs,
                    tool: 0,
                    tool_offset: None,
                };
                assert_eq!(
                    state_fine(&s),
                    state_fine_each(&s),
                    "{v:e} in place {place}"
                );
            }
        }
    }

    use std::ptr::{null, null_mut};

    const SRC: &str = "machine m {
        task position
        axis X prismatic along x range 0 mm .. 500 mm
        tool chain { X moving tool t at (0, 0, -100) mm }
        errors { X.tx = spline(X, knots 2)  X.ry = const }
    }";

    fn compile(src: &str) -> Result<*mut kin_model, (c_int, String)> {
        let mut out = null_mut();
        let mut err = [0 as c_char; 512];
        // SAFETY: valid pointers and lengths.
        let code = unsafe {
            kin_model_compile(
                src.as_ptr().cast(),
                src.len(),
                &mut out,
                err.as_mut_ptr(),
                err.len(),
            )
        };
        if code == KIN_OK {
            Ok(out)
        } else {
            // SAFETY: NUL-terminated by `kin_model_compile`.
            let msg = unsafe { CStr::from_ptr(err.as_ptr()) }
                .to_string_lossy()
                .into_owned();
            assert!(out.is_null());
            Err((code, msg))
        }
    }

    /// A warm-up's lag state follows no input: asking which one is refused, never answered
    /// with input 0 (whose value a caller would then feed it).
    #[test]
    fn a_warm_up_lag_names_no_input() {
        let src = "machine m {
            task position
            units { length mm, error um, time min }
            axis X prismatic along x range 0 mm .. 500 mm
            input T : temperature rise
            tool chain { X moving tool t at (0, 0, -100) mm }
            errors {
                X.tx = lag(T, tau 10 min) * const
                X.ty = warmup(time, tau 20 min) * const
            }
        }";
        let model = compile(src).expect("compiles");
        // SAFETY: a live model.
        let lags = unsafe { kin_model_lags(model) };
        assert_eq!(lags, 2);
        let (mut inputs, mut warm) = (Vec::new(), 0);
        for lag in 0..lags {
            let mut input = usize::MAX;
            // SAFETY: a live model; `input` is valid for one size_t.
            match unsafe { kin_model_lag_input(model, lag, &mut input) } {
                KIN_OK => inputs.push(input),
                KIN_ERR_INDEX => {
                    assert!(last_error().contains("warm-up"), "{}", last_error());
                    assert_eq!(input, usize::MAX, "nothing written");
                    warm += 1;
                }
                code => panic!("code {code}: {}", last_error()),
            }
        }
        assert_eq!((inputs, warm), (vec![0], 1));
        // SAFETY: a live model, freed once.
        unsafe { kin_model_free(model) };
    }

    fn last_error() -> String {
        let mut buf = [0 as c_char; 512];
        // SAFETY: valid buffer.
        unsafe { kin_last_error(buf.as_mut_ptr(), buf.len()) };
        // SAFETY: NUL-terminated.
        unsafe { CStr::from_ptr(buf.as_ptr()) }
            .to_string_lossy()
            .into_owned()
    }

    /// Inputs that are not finite (or a direction of 0.5) and overlapping buffers are refused
    /// with their own codes, never KIN_OK with inf or NaN in the outputs.
    /// The quick path accepts nothing the careful path refuses, and where it accepts, both give
    /// the same outputs: every combination of a bad or good value in each argument (NULL,
    /// misaligned, wrong length, overlapping outputs, non-finite or out-of-range values, β per
    /// call or bound).
    #[test]
    fn the_quick_path_accepts_only_what_the_careful_path_accepts() {
        let model = compile(SRC).expect("compiles");
        // One buffer for everything, so that outputs can be made to overlap inputs.
        let mut arena = vec![0.0f64; 256];
        let base = arena.as_mut_ptr();
        let (mut accepted, mut refused) = (0, 0);
        let qs = [0.2, f64::INFINITY, f64::NAN, 1e300];
        let dirs = [1.0, 0.5, f64::NAN, -1.0];
        // (err offset, err length) and (jac offset, jac length): fine, overlapping each
        // other, overlapping q, wrong lengths, NULL.
        let outputs: [(Option<usize>, usize, Option<usize>, usize); 6] = [
            (Some(100), 6, Some(120), 30),
            (Some(100), 6, Some(104), 30),
            (Some(10), 6, Some(120), 30),
            (Some(100), 5, Some(120), 30),
            (Some(100), 6, Some(120), 31),
            (None, 6, Some(120), 30),
        ];
        for (qi, &qv) in qs.iter().enumerate() {
            for &dv in &dirs {
                for &(e_at, n_err, j_at, n_jac) in &outputs {
                    for beta_kind in 0..4 {
                        for misaligned in [false, true] {
                            arena.fill(0.0);
                            arena[10] = qv;
                            arena[11] = dv;
                            arena[20..25].copy_from_slice(&[1e-6, 2e-6, 0.0, 0.0, 3e-6]);
                            if beta_kind == 2 {
                                arena[21] = f64::NAN;
                            }
                            // SAFETY: every pointer is inside `arena` (or NULL, or a
                            // misaligned pointer inside it, which both paths refuse before
                            // reading) and valid for the length given with it.
                            unsafe {
                                let q = if misaligned && qi == 0 {
                                    base.cast::<u8>().add(81).cast::<f64>()
                                } else {
                                    base.add(10)
                                };
                                let st = kin_state {
                                    q,
                                    n_q: 1,
                                    inputs: null(),
                                    n_inputs: 0,
                                    lags: null(),
                                    n_lags: 0,
                                    dirs: base.add(11),
                                    n_dirs: 1,
                                    time: 0.0,
                                    tool: 0,
                                };
                                let (b, n_b) = match beta_kind {
                                    0 => (null(), 0),
                                    3 => (base.add(20).cast_const(), 4),
                                    _ => (base.add(20).cast_const(), 5),
                                };
                                let err = e_at.map_or(null_mut(), |k| base.add(k));
                                let jac = j_at.map_or(null_mut(), |k| base.add(k));
                                let a = EvalArgs {
                                    model,
                                    state: &st,
                                    beta: b,
                                    n_beta: n_b,
                                    err,
                                    n_err,
                                    jac,
                                    n_jac,
                                };
                                let quick_ok = quick_jacobian(a, Observed::FULL);
                                let quick_out = arena.clone();
                                let careful = careful_jacobian(a, 63);
                                if quick_ok {
                                    accepted += 1;
                                    assert!(careful.is_ok(), "q {qv} dirs {dv} β {beta_kind}");
                                    let bits = |v: &[f64]| -> Vec<u64> {
                                        v.iter().map(|x| x.to_bits()).collect()
                                    };
                                    assert_eq!(bits(&quick_out), bits(&arena), "q {qv} dirs {dv}");
                                } else {
                                    refused += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(accepted > 0 && refused > 0, "{accepted} {refused}");
        // SAFETY: compiled above, freed once.
        unsafe { kin_model_free(model) };
    }

    #[test]
    fn every_input_an_output_overlaps_is_found() {
        // The one-pose entry's quick test of the regions, against each input in turn: `q`,
        // `dirs`, β, the state itself, and an empty array (no bytes, so no overlap) pointing
        // inside an output.
        let model = compile(SRC).expect("compiles");
        let beta = [1e-6, 2e-6, 0.0, 0.0, 3e-6];
        let mut mem = [0.0f64; 128];
        let base = mem.as_mut_ptr();
        // `err` at 0..6, `jac` at 6..36 of `mem`; the inputs elsewhere unless placed inside.
        let (q, dirs) = ([0.2], [1.0]);
        let state = |q: *const f64, dirs: *const f64, inputs: *const f64| kin_state {
            q,
            n_q: 1,
            inputs,
            n_inputs: 0,
            lags: null(),
            n_lags: 0,
            dirs,
            n_dirs: 1,
            time: 0.0,
            tool: 0,
        };
        // SAFETY: a live model; every pointer is valid for the length given with it, and what
        // an output overlaps is refused before anything is written.
        unsafe {
            let eval = |s: *const kin_state, b: *const f64| {
                kin_eval_jacobian(model, s, b, 5, base, 6, base.add(6), 30)
            };
            let good = state(q.as_ptr(), dirs.as_ptr(), null());
            assert_eq!(eval(&good, beta.as_ptr()), KIN_OK);
            let empty_inside = state(q.as_ptr(), dirs.as_ptr(), base.add(10));
            assert_eq!(
                eval(&empty_inside, beta.as_ptr()),
                KIN_OK,
                "{}",
                last_error()
            );
            for (at, what) in [(3, "q"), (35, "q"), (20, "dirs")] {
                base.add(at).write(if what == "q" { 0.2 } else { 1.0 });
                let s = if what == "q" {
                    state(base.add(at), dirs.as_ptr(), null())
                } else {
                    state(q.as_ptr(), base.add(at), null())
                };
                assert_eq!(eval(&s, beta.as_ptr()), KIN_ERR_OVERLAP, "{what} at {at}");
                assert!(
                    last_error().contains(&format!("`{what}` overlap")),
                    "{}",
                    last_error()
                );
            }
            // β over the end of `jac`, then just beyond it.
            base.add(33).cast::<[f64; 5]>().write(beta);
            assert_eq!(eval(&good, base.add(33)), KIN_ERR_OVERLAP);
            base.add(36).cast::<[f64; 5]>().write(beta);
            assert_eq!(eval(&good, base.add(36)), KIN_OK, "{}", last_error());
            // The state itself inside `jac`.
            let inside = base.add(12).cast::<kin_state>();
            inside.write(good);
            assert_eq!(eval(inside, beta.as_ptr()), KIN_ERR_OVERLAP);
            assert!(last_error().contains("`state`"), "{}", last_error());
            kin_model_free(model);
        }
    }

    #[test]
    fn bad_values_and_overlapping_buffers_are_refused() {
        let model = compile(SRC).expect("compiles");
        let state = |q: &[f64; 1], dirs: &[f64; 1]| kin_state {
            q: q.as_ptr(),
            n_q: 1,
            inputs: null(),
            n_inputs: 0,
            lags: null(),
            n_lags: 0,
            dirs: dirs.as_ptr(),
            n_dirs: 1,
            time: 0.0,
            tool: 0,
        };
        let beta = [1e-6, 2e-6, 0.0, 0.0, 3e-6];
        let mut err = [0.0; 6];
        let mut jac = [0.0; 30];
        // SAFETY: a live model; every buffer is valid for the length given with it.
        unsafe {
            let (q, dirs) = ([0.2], [1.0]);
            let good = state(&q, &dirs);
            let eval = |s: &kin_state, b: &[f64], err: *mut f64, jac: *mut f64| {
                kin_eval_jacobian(model, s, b.as_ptr(), b.len(), err, 6, jac, 30)
            };
            assert_eq!(
                eval(&good, &beta, err.as_mut_ptr(), jac.as_mut_ptr()),
                KIN_OK
            );
            let (inf, half) = ([f64::INFINITY], [0.5]);
            assert_eq!(
                eval(
                    &state(&inf, &dirs),
                    &beta,
                    err.as_mut_ptr(),
                    jac.as_mut_ptr()
                ),
                KIN_ERR_VALUE
            );
            assert!(last_error().contains("`q[0]` is inf"), "{}", last_error());
            assert_eq!(
                kin_eval(model, &state(&inf, &dirs), null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_VALUE
            );
            assert_eq!(
                eval(&state(&q, &half), &beta, err.as_mut_ptr(), jac.as_mut_ptr()),
                KIN_ERR_VALUE
            );
            assert!(
                last_error().contains("`dirs[0]` is 0.5"),
                "{}",
                last_error()
            );
            for d in [0.0, -1.0, f64::NAN] {
                assert_eq!(
                    eval(&state(&q, &[d]), &beta, err.as_mut_ptr(), jac.as_mut_ptr()),
                    KIN_OK,
                    "direction {d}"
                );
            }
            let nan_beta = [1e-6, f64::NAN, 0.0, 0.0, 3e-6];
            assert_eq!(
                eval(&good, &nan_beta, err.as_mut_ptr(), jac.as_mut_ptr()),
                KIN_ERR_VALUE
            );
            assert!(
                last_error().contains("`beta[1]` is NaN"),
                "{}",
                last_error()
            );
            // Finite but absurd: the result would overflow.
            let huge = [1e300];
            let big_beta = [1e300, 1e300, 1e300, 1e300, 1e300];
            assert_eq!(
                eval(
                    &state(&huge, &dirs),
                    &big_beta,
                    err.as_mut_ptr(),
                    jac.as_mut_ptr()
                ),
                KIN_ERR_VALUE
            );

            // `err` inside `jac`: the Jacobian would overwrite the error (or the reverse).
            let mut both = [0.0; 36];
            let base = both.as_mut_ptr();
            assert_eq!(eval(&good, &beta, base, base), KIN_ERR_OVERLAP);
            assert!(
                last_error().contains("`err` and `jac` overlap"),
                "{}",
                last_error()
            );
            assert_eq!(eval(&good, &beta, base.add(29), base), KIN_ERR_OVERLAP);
            // Side by side in one array is fine.
            assert_eq!(eval(&good, &beta, base.add(30), base), KIN_OK);
            // An output over an input.
            let mut qbuf = [0.2, 0.0, 0.0, 0.0, 0.0, 0.0];
            let over = kin_state {
                q: qbuf.as_ptr(),
                ..good
            };
            assert_eq!(
                kin_eval(model, &over, null(), 0, qbuf.as_mut_ptr(), 6),
                KIN_ERR_OVERLAP
            );
            let mut beta_out = beta;
            assert_eq!(
                kin_eval(model, &good, beta_out.as_ptr(), 5, beta_out.as_mut_ptr(), 5),
                KIN_ERR_OVERLAP
            );
            let mut loc = [0.0; 12];
            let mut njac = [0.0; 6];
            assert_eq!(
                kin_nominal_jacobian(model, &good, loc.as_mut_ptr(), 12, njac.as_mut_ptr(), 6),
                KIN_OK
            );
            assert_eq!(
                kin_nominal_jacobian(
                    model,
                    &good,
                    loc.as_mut_ptr(),
                    12,
                    loc.as_mut_ptr().add(6),
                    6
                ),
                KIN_ERR_OVERLAP
            );
            assert_eq!(
                kin_nominal_jacobian(
                    model,
                    &state(&inf, &dirs),
                    loc.as_mut_ptr(),
                    12,
                    njac.as_mut_ptr(),
                    6
                ),
                KIN_ERR_VALUE
            );

            // Batches: the row is named.
            let qs = [0.1, 0.2, f64::NEG_INFINITY];
            let ds = [1.0, 1.0, 1.0];
            let ts = [0.0; 3];
            let tools = [0usize; 3];
            let rows = kin_rows {
                n_rows: 3,
                q: qs.as_ptr(),
                n_q: 3,
                inputs: null(),
                n_inputs: 0,
                lags: null(),
                n_lags: 0,
                dirs: ds.as_ptr(),
                n_dirs: 3,
                time: ts.as_ptr(),
                n_time: 3,
                tool: tools.as_ptr(),
                n_tool: 3,
            };
            let mut errs = [0.0; 18];
            let mut jacs = [0.0; 90];
            assert_eq!(
                kin_eval_batch(
                    model,
                    &rows,
                    null(),
                    0,
                    errs.as_mut_ptr(),
                    18,
                    jacs.as_mut_ptr(),
                    90
                ),
                KIN_ERR_VALUE
            );
            assert!(
                last_error().contains("row 2: `q[2]` is -inf"),
                "{}",
                last_error()
            );
            let ok_q = [0.1, 0.2, 0.3];
            let ok_rows = kin_rows {
                q: ok_q.as_ptr(),
                ..rows
            };
            assert_eq!(
                kin_eval_batch(
                    model,
                    &ok_rows,
                    null(),
                    0,
                    errs.as_mut_ptr(),
                    18,
                    jacs.as_mut_ptr(),
                    90
                ),
                KIN_OK
            );
            assert_eq!(
                kin_eval_batch(
                    model,
                    &ok_rows,
                    null(),
                    0,
                    jacs.as_mut_ptr().add(80),
                    18,
                    jacs.as_mut_ptr(),
                    90
                ),
                KIN_ERR_OVERLAP
            );
            kin_model_free(model);
        }
    }

    #[test]
    fn compile_errors_have_lines_and_columns() {
        let (code, msg) = compile("machine m {\n  axis X wobbly\n}").expect_err("bad source");
        assert_eq!(code, KIN_ERR_COMPILE);
        assert!(msg.starts_with("2:"), "{msg}");
        assert_eq!(msg, last_error());
        let (code, _) = compile("\u{0}\u{ff}").expect_err("bad source");
        assert_eq!(code, KIN_ERR_COMPILE);
        // Not UTF-8.
        let bytes = [0xffu8, 0xfe];
        let mut out = null_mut();
        // SAFETY: valid pointers; no error buffer.
        let code = unsafe { kin_model_compile(bytes.as_ptr().cast(), 2, &mut out, null_mut(), 0) };
        assert_eq!(code, KIN_ERR_UTF8);
        // SAFETY: NULL source with a length.
        assert_eq!(
            unsafe { kin_model_compile(null(), 3, &mut out, null_mut(), 0) },
            KIN_ERR_POINTER
        );
        // SAFETY: NULL out.
        assert_eq!(
            unsafe { kin_model_compile(SRC.as_ptr().cast(), SRC.len(), null_mut(), null_mut(), 0) },
            KIN_ERR_POINTER
        );
    }

    #[test]
    fn every_length_is_checked() {
        let model = compile(SRC).expect("compiles");
        // SAFETY: a live model; every buffer below is valid for the length given with it.
        unsafe {
            assert_eq!(
                (
                    kin_model_axes(model),
                    kin_model_inputs(model),
                    kin_model_lags(model),
                    kin_model_coefficients(model)
                ),
                (1, 0, 0, 5)
            );
            assert_eq!(kin_model_axes(null()), 0);
            let q = [0.2];
            let dirs = [f64::NAN];
            let mut st = kin_state {
                q: q.as_ptr(),
                n_q: 1,
                inputs: null(),
                n_inputs: 0,
                lags: null(),
                n_lags: 0,
                dirs: dirs.as_ptr(),
                n_dirs: 1,
                time: 0.0,
                tool: 0,
            };
            let beta = [1e-6, 2e-6, 0.0, 0.0, 3e-6];
            let mut err = [0.0; 6];
            let mut jac = [0.0; 30];
            assert_eq!(
                kin_eval(model, &st, beta.as_ptr(), 5, err.as_mut_ptr(), 6),
                KIN_OK
            );
            assert_eq!(
                kin_eval(model, &st, beta.as_ptr(), 4, err.as_mut_ptr(), 6),
                KIN_ERR_SIZE
            );
            assert_eq!(
                kin_eval(model, &st, beta.as_ptr(), 5, err.as_mut_ptr(), 5),
                KIN_ERR_SIZE
            );
            assert_eq!(
                kin_eval(model, &st, null(), 5, err.as_mut_ptr(), 6),
                KIN_ERR_POINTER
            );
            assert_eq!(
                kin_eval(model, &st, null(), 0, err.as_mut_ptr(), 6),
                KIN_OK,
                "bound β"
            );
            assert_eq!(
                kin_eval(model, null(), null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_POINTER
            );
            assert_eq!(
                kin_eval(null(), &st, null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_POINTER
            );
            assert_eq!(
                kin_eval_jacobian(
                    model,
                    &st,
                    beta.as_ptr(),
                    5,
                    err.as_mut_ptr(),
                    6,
                    jac.as_mut_ptr(),
                    29
                ),
                KIN_ERR_SIZE
            );
            assert_eq!(
                kin_eval_jacobian(
                    model,
                    &st,
                    beta.as_ptr(),
                    5,
                    err.as_mut_ptr(),
                    6,
                    jac.as_mut_ptr(),
                    30
                ),
                KIN_OK
            );
            st.tool = 3;
            assert_eq!(
                kin_eval(model, &st, null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_EVAL
            );
            assert!(last_error().contains("tool"), "{}", last_error());
            st.tool = 0;
            st.n_q = 2;
            assert_eq!(
                kin_eval(model, &st, null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_SIZE
            );
            st.n_q = 1;
            let misaligned = (q.as_ptr() as *const u8).add(1).cast::<f64>();
            st.q = misaligned;
            assert_eq!(
                kin_eval(model, &st, null(), 0, err.as_mut_ptr(), 6),
                KIN_ERR_POINTER
            );
            let (mut lo, mut hi) = (0.0, 0.0);
            assert_eq!(kin_model_axis_range(model, 0, &mut lo, &mut hi), KIN_OK);
            assert_eq!((lo, hi), (0.0, 0.5));
            assert_eq!(
                kin_model_axis_range(model, 1, &mut lo, &mut hi),
                KIN_ERR_INDEX
            );
            let mut name = [0 as c_char; 4];
            assert_eq!(
                kin_model_name(model, 3, 4, name.as_mut_ptr(), name.len()),
                "X.ry[0]".len()
            );
            assert_eq!(
                CStr::from_ptr(name.as_ptr()).to_str(),
                Ok("X.r"),
                "truncated"
            );
            assert_eq!(
                kin_model_name(model, 3, 5, name.as_mut_ptr(), name.len()),
                usize::MAX
            );
            let params = "params { X.ry[0] = 3 urad }";
            assert_eq!(
                kin_model_bind_params(model, params.as_ptr().cast(), params.len(), null_mut(), 0),
                KIN_OK
            );
            let mut bound = [0.0; 5];
            assert_eq!(kin_model_beta(model, bound.as_mut_ptr(), 5), KIN_OK);
            assert!((bound[4] - 3e-6).abs() < 1e-18);
            let bad = "params { X.ry = 3 }";
            assert_eq!(
                kin_model_bind_params(model, bad.as_ptr().cast(), bad.len(), null_mut(), 0),
                KIN_ERR_PARAMS
            );
            assert!(last_error().contains("E0501"), "{}", last_error());
            kin_model_free(model);
            kin_model_free(null_mut());
        }
    }

    #[test]
    fn batch_and_save_round_trip() {
        let model = compile(SRC).expect("compiles");
        // SAFETY: a live model; every buffer below is valid for the length given with it.
        unsafe {
            let q = [0.0, 0.1, 0.2, 0.3];
            let time = [0.0; 4];
            let dirs = [f64::NAN; 4];
            let tool = [0usize; 4];
            let rows = kin_rows {
                n_rows: 4,
                q: q.as_ptr(),
                n_q: 4,
                inputs: null(),
                n_inputs: 0,
                lags: null(),
                n_lags: 0,
                dirs: dirs.as_ptr(),
                n_dirs: 4,
                time: time.as_ptr(),
                n_time: 4,
                tool: tool.as_ptr(),
                n_tool: 4,
            };
            let beta = [1e-6, 2e-6, -1e-6, 0.5e-6, 3e-6];
            let mut err = [0.0; 24];
            let mut jac = [0.0; 120];
            assert_eq!(
                kin_eval_batch(
                    model,
                    &rows,
                    beta.as_ptr(),
                    5,
                    err.as_mut_ptr(),
                    24,
                    jac.as_mut_ptr(),
                    120
                ),
                KIN_OK
            );
            let mut only = [0.0; 24];
            assert_eq!(
                kin_eval_batch(
                    model,
                    &rows,
                    beta.as_ptr(),
                    5,
                    only.as_mut_ptr(),
                    24,
                    null_mut(),
                    0
                ),
                KIN_OK
            );
            assert!(err
                .iter()
                .zip(&only)
                .all(|(a, b)| (a - b).abs() <= 1e-12 * a.abs().max(1e-9)));
            assert_eq!(
                kin_eval_batch(
                    model,
                    &rows,
                    beta.as_ptr(),
                    5,
                    err.as_mut_ptr(),
                    23,
                    null_mut(),
                    0
                ),
                KIN_ERR_SIZE
            );
            // A value that is not finite is refused and leaves the model's values as they were.
            let mut bad = beta;
            bad[2] = f64::NAN;
            assert_eq!(kin_model_set_beta(model, bad.as_ptr(), 5), KIN_ERR_VALUE);
            bad[2] = f64::INFINITY;
            assert_eq!(kin_model_set_beta(model, bad.as_ptr(), 5), KIN_ERR_VALUE);
            assert!((*model).model.beta().iter().all(|b| b.is_finite()));
            assert_eq!(kin_model_set_beta(model, beta.as_ptr(), 5), KIN_OK);
            let dir = std::env::temp_dir().join(format!("kin-capi-{}", std::process::id()));
            std::fs::create_dir_all(&dir).expect("temp dir");
            let path =
                std::ffi::CString::new(dir.join("m.json").to_str().expect("utf-8")).expect("path");
            assert_eq!(kin_model_save(model, path.as_ptr()), KIN_OK);
            let mut loaded = null_mut();
            assert_eq!(kin_model_load(path.as_ptr(), &mut loaded), KIN_OK);
            let mut again = [0.0; 24];
            assert_eq!(
                kin_eval_batch(
                    loaded,
                    &rows,
                    null(),
                    0,
                    again.as_mut_ptr(),
                    24,
                    null_mut(),
                    0
                ),
                KIN_OK
            );
            assert_eq!(again, only);
            let missing = std::ffi::CString::new(dir.join("none.json").to_str().expect("utf-8"))
                .expect("path");
            assert_eq!(kin_model_load(missing.as_ptr(), &mut loaded), KIN_ERR_IO);
            assert!(loaded.is_null());
            // A path that never ends is read up to a limit, not into all of memory.
            if Path::new("/dev/zero").exists() {
                let zero = std::ffi::CString::new("/dev/zero").expect("path");
                assert_eq!(kin_model_load(zero.as_ptr(), &mut loaded), KIN_ERR_IO);
                assert!(
                    last_error().contains("larger than 64 MiB"),
                    "{}",
                    last_error()
                );
                assert!(loaded.is_null());
            }
            let _ = std::fs::remove_dir_all(&dir);
            kin_model_free(model);
        }
    }

    /// Position rows alone (observed = 7), and any other subset, are the full Jacobian's rows
    /// to the bit; wrong lengths and masks are refused.
    #[test]
    fn observed_rows_are_the_full_jacobians_rows() {
        let src = include_str!("../../examples/milling_5axis.kin");
        let model = compile(src).expect("compiles");
        // SAFETY: a live model.
        let n = unsafe { kin_model_coefficients(model) };
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
        let q = [0.1, 0.2, -0.1, 0.3, 1.0];
        let inputs = [1.5, 293.0, 100.0];
        let dirs = [1.0, -1.0, 1.0, 1.0, -1.0];
        // SAFETY: a live model.
        let (n_inputs, n_lags) = unsafe { (kin_model_inputs(model), kin_model_lags(model)) };
        let lags = vec![1.0; n_lags];
        let state = kin_state {
            q: q.as_ptr(),
            n_q: 5,
            inputs: inputs.as_ptr(),
            n_inputs,
            lags: lags.as_ptr(),
            n_lags,
            dirs: dirs.as_ptr(),
            n_dirs: 5,
            time: 60.0,
            tool: 0,
        };
        let (mut err, mut jac) = ([0.0; 6], vec![0.0; 6 * n]);
        // SAFETY: valid pointers and lengths throughout.
        unsafe {
            let full = kin_eval_jacobian(
                model,
                &state,
                beta.as_ptr(),
                n,
                err.as_mut_ptr(),
                6,
                jac.as_mut_ptr(),
                6 * n,
            );
            assert_eq!(full, KIN_OK, "{}", last_error());
            for observed in [7u32, 0b101_000, 1, 63] {
                let rows = observed.count_ones() as usize;
                let (mut e, mut j) = (vec![0.0; rows], vec![0.0; rows * n]);
                let code = kin_eval_jacobian_observed(
                    model,
                    &state,
                    beta.as_ptr(),
                    n,
                    observed,
                    e.as_mut_ptr(),
                    rows,
                    j.as_mut_ptr(),
                    rows * n,
                );
                assert_eq!(code, KIN_OK, "{}", last_error());
                let components: Vec<usize> = (0..6).filter(|c| observed & (1 << c) != 0).collect();
                for (k, &c) in components.iter().enumerate() {
                    assert_eq!(e[k].to_bits(), err[c].to_bits(), "{observed}: err {c}");
                    assert_eq!(
                        &j[k * n..(k + 1) * n],
                        &jac[c * n..(c + 1) * n],
                        "{observed}: row {c}"
                    );
                }
            }
            let (mut e, mut j) = (vec![0.0; 3], vec![0.0; 3 * n]);
            let mut call = |observed: u32, n_err: usize| {
                kin_eval_jacobian_observed(
                    model,
                    &state,
                    beta.as_ptr(),
                    n,
                    observed,
                    e.as_mut_ptr(),
                    n_err,
                    j.as_mut_ptr(),
                    3 * n,
                )
            };
            assert_eq!(call(0, 3), KIN_ERR_VALUE);
            assert_eq!(call(64, 3), KIN_ERR_VALUE);
            assert_eq!(call(7, 2), KIN_ERR_SIZE);
            kin_model_free(model);
        }
    }

    /// A batch of observed components holds, row by row, the bits of the one-pose observed
    /// call at that row's state; the error-only batch the same values; a wrong mask or length
    /// is refused.
    #[test]
    fn observed_batches_are_the_one_pose_observed_rows() {
        let src = include_str!("../../examples/milling_5axis.kin");
        let model = compile(src).expect("compiles");
        // SAFETY: a live model.
        let (n, n_inputs, n_lags) = unsafe {
            (
                kin_model_coefficients(model),
                kin_model_inputs(model),
                kin_model_lags(model),
            )
        };
        let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 5) as f64 - 2.0)).collect();
        const ROWS: usize = 5;
        let q: Vec<f64> = (0..5 * ROWS).map(|i| 0.05 * (i % 7) as f64 - 0.1).collect();
        let inputs: Vec<f64> = (0..n_inputs * ROWS)
            .map(|i| 1.0 + 0.5 * (i % 3) as f64)
            .collect();
        let lags = vec![0.5; n_lags * ROWS];
        let dirs: Vec<f64> = (0..5 * ROWS)
            .map(|i| if i % 3 == 0 { -1.0 } else { 1.0 })
            .collect();
        let time: Vec<f64> = (0..ROWS).map(|r| 10.0 * r as f64).collect();
        let tool = [0usize; ROWS];
        let rows = kin_rows {
            n_rows: ROWS,
            q: q.as_ptr(),
            n_q: q.len(),
            inputs: inputs.as_ptr(),
            n_inputs: inputs.len(),
            lags: lags.as_ptr(),
            n_lags: lags.len(),
            dirs: dirs.as_ptr(),
            n_dirs: dirs.len(),
            time: time.as_ptr(),
            n_time: ROWS,
            tool: tool.as_ptr(),
            n_tool: ROWS,
        };
        // SAFETY: a live model; every buffer is valid for the length given with it.
        unsafe {
            for observed in [7u32, 0b110_010, 63] {
                let k = observed.count_ones() as usize;
                let (mut e, mut j) = (vec![0.0; k * ROWS], vec![0.0; k * n * ROWS]);
                let code = kin_eval_batch_observed(
                    model,
                    &rows,
                    beta.as_ptr(),
                    n,
                    observed,
                    e.as_mut_ptr(),
                    e.len(),
                    j.as_mut_ptr(),
                    j.len(),
                );
                assert_eq!(code, KIN_OK, "{}", last_error());
                let mut only = vec![0.0; k * ROWS];
                let code = kin_eval_batch_observed(
                    model,
                    &rows,
                    beta.as_ptr(),
                    n,
                    observed,
                    only.as_mut_ptr(),
                    only.len(),
                    null_mut(),
                    0,
                );
                assert_eq!(code, KIN_OK, "{}", last_error());
                for r in 0..ROWS {
                    let state = kin_state {
                        q: q[5 * r..].as_ptr(),
                        n_q: 5,
                        inputs: inputs[n_inputs * r..].as_ptr(),
                        n_inputs,
                        lags: lags[n_lags * r..].as_ptr(),
                        n_lags,
                        dirs: dirs[5 * r..].as_ptr(),
                        n_dirs: 5,
                        time: time[r],
                        tool: 0,
                    };
                    let (mut e1, mut j1) = (vec![0.0; k], vec![0.0; k * n]);
                    let code = kin_eval_jacobian_observed(
                        model,
                        &state,
                        beta.as_ptr(),
                        n,
                        observed,
                        e1.as_mut_ptr(),
                        k,
                        j1.as_mut_ptr(),
                        k * n,
                    );
                    assert_eq!(code, KIN_OK, "{}", last_error());
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&e[k * r..k * (r + 1)]),
                        bits(&e1),
                        "{observed} row {r}"
                    );
                    assert_eq!(
                        bits(&j[k * n * r..k * n * (r + 1)]),
                        bits(&j1),
                        "{observed} row {r}"
                    );
                    // The error-only code sums in its own order: equal to rounding.
                    for (a, b) in only[k * r..k * (r + 1)].iter().zip(&e1) {
                        assert!((a - b).abs() <= 1e-12 * b.abs().max(1e-9), "{a} {b}");
                    }
                }
            }
            let mut e = vec![0.0; 3 * ROWS];
            let mut call = |observed: u32, n_err: usize| {
                kin_eval_batch_observed(
                    model,
                    &rows,
                    beta.as_ptr(),
                    n,
                    observed,
                    e.as_mut_ptr(),
                    n_err,
                    null_mut(),
                    0,
                )
            };
            assert_eq!(call(0, 3 * ROWS), KIN_ERR_VALUE);
            assert_eq!(call(64, 3 * ROWS), KIN_ERR_VALUE);
            assert_eq!(call(7, 3 * ROWS - 1), KIN_ERR_SIZE);
            assert_eq!(call(7, 3 * ROWS), KIN_OK, "{}", last_error());
            kin_model_free(model);
        }
    }

    /// The C ABI chooses the axes as `kin compensate --axes` does: position weights alone move
    /// the prismatic axes by default (A and C held), 1/0 flags choose any set, and the servo
    /// correction then moves exactly those.
    #[test]
    fn a_compensator_moves_the_axes_it_is_given() {
        let src = "machine mill5 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis A revolute about x range -90 deg .. 90 deg
    axis C revolute about z continuous
    tool chain { Z moving at (0, 0, 450) mm  tool t at (0, 0, -100) mm }
    workpiece chain { Y fixed  X fixed  A fixed  C fixed at (0, 0, 80) mm  workpiece }
    errors { X.tx = linear(X)  A.ty = const  A.rz = const  C.tx = const  C.ry = const }
}
params { X.tx = [20] um  A.ty = [15] um  A.rz = [30] urad  C.tx = [12] um  C.ry = [25] urad }";
        let model = compile(src).expect("compiles");
        let position = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        let q = [0.2, 0.1, -0.1, 0.5, 0.8];
        let dirs = [1.0; 5];
        let state = kin_state {
            q: q.as_ptr(),
            n_q: 5,
            inputs: null(),
            n_inputs: 0,
            lags: null(),
            n_lags: 0,
            dirs: dirs.as_ptr(),
            n_dirs: 5,
            time: f64::NAN,
            tool: 0,
        };
        // SAFETY: valid pointers and lengths throughout.
        let run = |movable: Option<&[u8]>| unsafe {
            let mut comp = null_mut();
            let (p, n) = movable.map_or((null(), 0), |m| (m.as_ptr(), m.len()));
            let status = kin_compensator_new_axes(model, position.as_ptr(), 6, 0, p, n, &mut comp);
            if status != KIN_OK {
                return Err(status);
            }
            let mut dq = [0.0; 5];
            let mut after = [0.0; 6];
            let done = kin_compensate(
                comp,
                &state,
                dq.as_mut_ptr(),
                5,
                null_mut(),
                0,
                after.as_mut_ptr(),
                6,
                null_mut(),
            );
            kin_compensator_free(comp);
            assert_eq!(done, KIN_OK, "{}", last_error());
            Ok((dq, after))
        };
        let (dq, after) = run(None).expect("default");
        assert_eq!(&dq[3..], &[0.0, 0.0], "A and C held by default: {dq:?}");
        assert!(dq[..3].iter().any(|d| d.abs() > 1e-6), "{dq:?}");
        assert!(after[..3].iter().all(|e| e.abs() < 1e-9), "{after:?}");
        let (dq, _) = run(Some(&[1, 1, 1, 1, 1])).expect("all");
        assert!(dq[3].abs() > 0.0 || dq[4].abs() > 0.0, "{dq:?}");
        let (dq, _) = run(Some(&[1, 0, 1, 0, 0])).expect("X and Z");
        assert_eq!((dq[1], dq[3], dq[4]), (0.0, 0.0, 0.0), "{dq:?}");
        assert_eq!(run(Some(&[1, 1, 1])), Err(KIN_ERR_SIZE));
        assert_eq!(run(Some(&[1, 1, 1, 2, 0])), Err(KIN_ERR_VALUE));
        // SAFETY: a model of this test, freed once.
        unsafe { kin_model_free(model) };
    }

    #[test]
    fn a_compensator_refuses_what_it_cannot_do() {
        let model = compile(SRC).expect("compiles");
        let mut comp = null_mut();
        // SAFETY: valid pointers and lengths throughout.
        unsafe {
            assert_eq!(
                kin_compensator_new(
                    model,
                    [1.0, -1.0, 0.0, 0.0, 0.0, 0.0].as_ptr(),
                    6,
                    0,
                    &mut comp
                ),
                KIN_ERR_VALUE
            );
            assert_eq!(
                kin_compensator_new(model, null(), 0, 0, null_mut()),
                KIN_ERR_POINTER
            );
            assert_eq!(kin_compensator_new(model, null(), 0, 0, &mut comp), KIN_OK);
            let q = [0.25];
            let dirs = [1.0];
            let state = kin_state {
                q: q.as_ptr(),
                n_q: 1,
                inputs: null(),
                n_inputs: 0,
                lags: null(),
                n_lags: 0,
                dirs: dirs.as_ptr(),
                n_dirs: 1,
                time: f64::NAN,
                tool: 0,
            };
            let mut dq = [0.0];
            let mut two = [0.0; 2];
            let mut rank = 0usize;
            let call = |dq: *mut f64, n: usize, rank: *mut usize| {
                kin_compensate(comp, &state, dq, n, null_mut(), 0, null_mut(), 0, rank)
            };
            assert_eq!(call(dq.as_mut_ptr(), 1, &mut rank), KIN_OK);
            assert_eq!(rank, 1);
            assert_eq!(call(two.as_mut_ptr(), 2, null_mut()), KIN_ERR_SIZE);
            assert_eq!(call(null_mut(), 1, null_mut()), KIN_ERR_POINTER);
            assert_eq!(
                kin_compensate(
                    null(),
                    &state,
                    dq.as_mut_ptr(),
                    1,
                    null_mut(),
                    0,
                    null_mut(),
                    0,
                    null_mut()
                ),
                KIN_ERR_POINTER
            );
            let far = [0.7];
            let outside = kin_state {
                q: far.as_ptr(),
                ..state
            };
            assert_eq!(
                kin_compensate(
                    comp,
                    &outside,
                    dq.as_mut_ptr(),
                    1,
                    null_mut(),
                    0,
                    null_mut(),
                    0,
                    null_mut()
                ),
                KIN_ERR_RANGE
            );
            let nan = [f64::NAN];
            let bad = kin_state {
                q: nan.as_ptr(),
                ..state
            };
            assert_eq!(
                kin_compensate(
                    comp,
                    &bad,
                    dq.as_mut_ptr(),
                    1,
                    null_mut(),
                    0,
                    null_mut(),
                    0,
                    null_mut()
                ),
                KIN_ERR_VALUE
            );
            kin_compensator_free(comp);
            kin_model_free(model);
            let cmm = compile(&SRC.replace("task position", "task measure")).expect("compiles");
            let mut none = null_mut();
            assert_eq!(
                kin_compensator_new(cmm, null(), 0, 0, &mut none),
                KIN_ERR_MACHINE
            );
            assert!(none.is_null());
            kin_model_free(cmm);
        }
    }
}
