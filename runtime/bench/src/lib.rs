//! `kin bench`: how fast the engines evaluate a machine, measured in one run.
//!
//! A measurement, not a test: the figures depend on the computer and on what else it is doing.
//! For poses sampled over the machine's ranges it times, per pose, the error and its full
//! β-Jacobian written into a reused buffer (what a fit needs), and the error alone (what a
//! compensation needs), for the [interpreter](kin_model::interp) and the [JIT](kin_model::jit) — one pose
//! at a time and through the batch call — and, when the machine is `examples/milling_5axis.kin`,
//! for the [hand-written baseline](baseline_5axis) of that machine; and the time from source text
//! to callable native functions. Every figure is the best of a few rounds, so a moment of load
//! elsewhere shows less. Then the evaluation paths side by side ([`Paths`]): one pose per call
//! against the batch call, all six rows, the position rows ([`kin_model::jit::Observed`]) and the
//! error alone, against the baseline with harmonic recurrences, as medians of interleaved
//! rounds, so that the ratios compare runs under the same load.
//!
//! For a positioning machine it also times the servo compensation
//! ([`ServoCompensator`](kin_model::embed::ServoCompensator)) call by call, JIT and interpreter, and
//! gives the median, the 99.9th percentile and the largest time of one call: a controller cares
//! about the worst cycle, not the average.

// `!(x > 0.0)` is written on purpose: it is also true for NaN, which must fail the same checks
// as a non-positive number.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod baseline_5axis;
pub mod c_abi;
mod wide_store;

use std::fmt;
use std::hint::black_box;
use std::time::{Duration, Instant};

use kin_compiler::ir::Machine;

use kin_model::embed::{Error, Model, RowsBuf};
use kin_model::interp::{EvalError, Interpreter, State};
use kin_model::jit::{BatchError, StateRows};
use kin_model::states::States;

/// What to measure and for how long.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Poses sampled over the machine's ranges, evaluated in turn.
    pub poses: usize,
    /// Wall time spent on each throughput figure (split over the rounds).
    pub time: Duration,
    /// Rounds per figure; the best counts.
    pub rounds: u32,
    /// Seed of the sampled poses.
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            poses: 1000,
            time: Duration::from_millis(600),
            rounds: 5,
            seed: 1,
        }
    }
}

/// Poses per second of one way of evaluating.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rates {
    /// The error and its 6 × n β-Jacobian.
    pub jacobian: f64,
    /// The error alone.
    pub error: f64,
}

/// Every figure of one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Figures {
    pub machine: String,
    pub coefficients: usize,
    pub axes: usize,
    pub poses: usize,
    pub interp: Rates,
    /// One pose per call.
    pub jit: Rates,
    /// All poses in one batch call, rows out into reused buffers.
    pub jit_batch: Rates,
    /// The hand-written baseline (error and Jacobian only; it computes both at once), with
    /// `libm` harmonics (the interpreter's numbers) and with harmonic recurrences; `None` when the
    /// machine is not the 5-axis example, with the reason.
    pub baseline: Result<BaselineRates, String>,
    /// Writing the 6 × n Jacobian into the reused buffer and nothing else, per pose: the
    /// ceiling of any evaluator that hands out the full Jacobian on this computer.
    pub write_only: f64,
    /// Source text to callable functions: parse, check, lower and JIT-compile.
    pub compile: Duration,
    /// The front end alone (source to IR).
    pub front_end: Duration,
    /// The JIT alone (IR to callable functions).
    pub jit_compile: Duration,
    /// Whether this code was built without optimisations (figures not representative).
    pub debug_build: bool,
    /// Time per servo compensation call; the reason when the machine measures instead.
    pub compensation: Result<CompensationTimes, String>,
    /// The batch path against one pose per call and against the baseline, for all six rows,
    /// the position rows and the error alone: medians of interleaved rounds.
    pub paths: Paths,
}

/// Poses per second of one piece of work by the JIT and (for the 5-axis example) by the
/// hand-written baseline with harmonic recurrences: medians of interleaved rounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathRates {
    /// One pose per call, into a reused buffer.
    pub per_pose: f64,
    /// One call for all poses, each pose's rows into its own place of N-row outputs (what a
    /// fit asks for).
    pub batch: f64,
    /// One batch call per block of poses whose rows fit in `BLOCK_BYTES`, into one reused
    /// block: the rows of a fit that consumes them a block at a time (`None` for the error).
    pub blocked: Option<f64>,
    /// The baseline, one pose per call into a reused buffer.
    pub baseline: Option<f64>,
    /// The baseline writing each pose's rows into N-row outputs.
    pub baseline_batch: Option<f64>,
    /// One pose per call through the C ABI (`kin_eval_jacobian_observed`, `kin_eval`) with the
    /// coefficients bound once, as an embedding program calls it; `None` when the C ABI could
    /// not compile the model.
    pub capi: Option<f64>,
}

/// The evaluation paths measured side by side: every contender runs for a slice of time in
/// turn, round after round, so a change of load elsewhere affects them alike; each figure is
/// the median over the rounds.
#[derive(Debug, Clone, PartialEq)]
pub struct Paths {
    pub rounds: u32,
    /// Error and Jacobian, all six components.
    pub full: PathRates,
    /// Error and Jacobian of the three position components (`Observed::POSITION`).
    pub position: PathRates,
    /// The six error components alone.
    pub error: PathRates,
    /// Why there is no baseline, when there is none.
    pub no_baseline: Option<String>,
    /// Writing the six rows' Jacobian blocks of all poses into the batch's N-row output and
    /// nothing else: the floor of the batch path of all six rows.
    pub floor_full: Floor,
    /// The same for the position rows' blocks.
    pub floor_position: Floor,
    /// Six rows, the generated code storing straight into the N-row output, one call per pose.
    pub direct: f64,
    /// As `direct`, each pose's destination requested for writing before the pose before it
    /// is evaluated.
    pub direct_prefetch: f64,
}

/// The time to write a batch's Jacobian rows to its N-row output without evaluating anything,
/// as poses per second: the memory's write rate, which bounds any batch path into fresh
/// memory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Floor {
    /// Ordinary stores (each line is read into the cache before it is written).
    pub plain: f64,
    /// Streaming stores of 16 bytes (`movntpd`) from a block in the first-level cache, as the
    /// batch path writes a large destination.
    pub streaming: f64,
    /// Streaming stores of 32 bytes (`vmovntpd`), where the CPU has AVX.
    pub streaming_wide: f64,
}

/// The bytes of the rows one batch call writes when a fit consumes them a block at a time
/// ([`PathRates::blocked`]): well inside a core's second-level cache (256 KiB to 2 MiB on
/// current x86-64 CPUs), so the block is written and read back without going to memory.
pub(crate) const BLOCK_BYTES: usize = 256 << 10;

/// The distribution of the time of one call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Latency {
    pub calls: usize,
    pub median: Duration,
    /// The 99.9th percentile.
    pub p999: Duration,
    pub max: Duration,
}

/// The servo compensation timed call by call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompensationTimes {
    /// The bound on the linear solves per call (`Options::iterations`).
    pub iterations: usize,
    /// The default options: the iteration stops once a step changes the error by less than a
    /// picometre (the typical path).
    pub jit: Latency,
    /// The slowest path: every call does all `iterations` solves (and one more evaluation of
    /// the model than solves), JIT. What a controller has to budget for.
    pub jit_worst_path: Latency,
    /// The first linear solve only (one iteration), JIT.
    pub jit_first_solve: Latency,
    pub interp: Latency,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaselineRates {
    pub exact: f64,
    pub recurrence: f64,
}

/// Why a bench could not run.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Model(#[from] Error),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error(transparent)]
    Batch(#[from] BatchError),
    #[error("--poses must be at least 1")]
    NoPoses,
    #[error("the C ABI refused a call of the bench (status {0})")]
    CApi(i32),
    #[error(
        "the batched Jacobian of {poses} poses × {coefficients} coefficients needs more than \
         {MAX_BATCH_VALUES} values (2 GiB); measure with fewer --poses"
    )]
    TooLarge { poses: usize, coefficients: usize },
}

/// The largest batch buffer the bench allocates, in values (2 GiB of f64): a rate measured on
/// more poses than this would only measure the memory system.
const MAX_BATCH_VALUES: usize = 1 << 28;

/// Poses per second of `f`, which evaluates `poses` poses: the best of `rounds` rounds sharing
/// `time`, after one untimed call (code and data in cache).
fn rate<E>(options: &Options, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    f()?;
    let round = options.time / options.rounds.max(1);
    let mut best: f64 = 0.0;
    for _ in 0..options.rounds.max(1) {
        let start = Instant::now();
        let mut calls = 0u32;
        while calls == 0 || start.elapsed() < round {
            f()?;
            calls += 1;
        }
        best = best.max(f64::from(calls) * options.poses as f64 / start.elapsed().as_secs_f64());
    }
    Ok(best)
}

/// The smallest of `k` timings of `f`.
fn fastest<T, E>(k: usize, mut f: impl FnMut() -> Result<T, E>) -> Result<Duration, E> {
    let mut best = Duration::MAX;
    for _ in 0..k {
        let start = Instant::now();
        black_box(f()?);
        best = best.min(start.elapsed());
    }
    Ok(best)
}

/// Measures everything for the machine in `source` (with its own `params` block, if any, bound).
pub fn measure(source: &str, options: &Options) -> Result<Figures, BenchError> {
    if options.poses == 0 {
        return Err(BenchError::NoPoses);
    }
    let model = Model::compile(source)?;
    let compile = fastest(5, || Model::compile(source))?;
    let front_end =
        fastest(5, || kin_compiler::compile(source).compiled.ok_or(())).map_err(|()| {
            Error::Compile {
                diagnostics: kin_compiler::compile(source).diagnostics,
            }
        })?;
    let jit_compile =
        fastest(5, || kin_model::jit::compile(model.machine())).map_err(Error::from)?;
    let m: &Machine = model.machine();
    let n = m.coefficients.len();
    // Checked before anything is sampled: the batch buffer below is poses × 6 × coefficients.
    let values = 6usize
        .checked_mul(n)
        .and_then(|v| v.checked_mul(options.poses))
        .filter(|&v| v <= MAX_BATCH_VALUES)
        .ok_or(BenchError::TooLarge {
            poses: options.poses,
            coefficients: n,
        })?;
    let states = States::sample(m, options.poses, options.seed);
    let poses = RowsBuf::from_states(&states);
    let rows = poses.rows();
    let state = |r: usize| -> State<'_> { rows.get(r) };
    // Small coefficients of both signs: every term contributes, nothing overflows.
    let beta: Vec<f64> = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
    let nonlinear = model.nonlinear().to_vec();
    let count = options.poses;
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];

    let mut it = Interpreter::new(m)?;
    it.set_nonlinear(&nonlinear)?;
    let interp = Rates {
        jacobian: rate(options, || {
            for r in 0..count {
                it.error_and_jacobian(&state(r), &beta, &mut err, &mut jac)?;
            }
            black_box(&jac);
            Ok::<(), EvalError>(())
        })?,
        error: rate(options, || {
            for r in 0..count {
                black_box(it.error(&state(r), &beta)?);
            }
            Ok::<(), EvalError>(())
        })?,
    };

    let jit = model.jit();
    let jit_rates = Rates {
        jacobian: rate(options, || {
            for r in 0..count {
                jit.error_and_jacobian(&state(r), &beta, &nonlinear, &mut err, &mut jac)?;
            }
            black_box(&jac);
            Ok::<(), EvalError>(())
        })?,
        error: rate(options, || {
            for r in 0..count {
                black_box(jit.error(&state(r), &beta, &nonlinear)?);
            }
            Ok::<(), EvalError>(())
        })?,
    };
    let mut errs = vec![0.0; 6 * count];
    let mut jacs = vec![0.0; values];
    let jit_batch = Rates {
        jacobian: rate(options, || {
            jit.error_and_jacobian_rows(&rows, &beta, &nonlinear, &mut errs, &mut jacs)?;
            black_box(&jacs);
            Ok::<(), BatchError>(())
        })?,
        error: rate(options, || {
            jit.error_rows(&rows, &beta, &nonlinear, &mut errs)?;
            black_box(&errs);
            Ok::<(), BatchError>(())
        })?,
    };

    let baseline = baseline_rates(m, options, &rows, &beta, &nonlinear);
    let paths = paths(source, &model, options, &rows, &beta, &mut jacs, &mut errs)?;
    let compensation = compensation_times(&model, options, &rows, &beta)?;
    let write_only = rate(options, || {
        for r in 0..count {
            jac.fill(black_box(r as f64));
            black_box(&mut jac);
        }
        Ok::<(), BatchError>(())
    })?;
    Ok(Figures {
        machine: m.name.clone(),
        coefficients: n,
        axes: m.axes.len(),
        poses: count,
        interp,
        jit: jit_rates,
        jit_batch,
        baseline,
        write_only,
        compile,
        front_end,
        jit_compile,
        debug_build: cfg!(debug_assertions),
        compensation,
        paths,
    })
}

/// A contender of [`interleaved`]: one pass over the poses.
type Pass<'a> = Box<dyn FnMut() -> Result<(), BenchError> + 'a>;

/// Poses per second of each pass (each evaluating `poses` poses): after one untimed pass of
/// each, `rounds` rounds in which every pass runs in turn for `time / rounds`; the median
/// over the rounds.
fn interleaved(options: &Options, passes: &mut [Pass<'_>]) -> Result<Vec<f64>, BenchError> {
    for pass in passes.iter_mut() {
        pass()?;
    }
    let rounds = options.rounds.max(1);
    let slice = options.time / rounds;
    let mut rates = vec![Vec::with_capacity(rounds as usize); passes.len()];
    for _ in 0..rounds {
        for (pass, rates) in passes.iter_mut().zip(rates.iter_mut()) {
            let start = Instant::now();
            let mut calls = 0u32;
            while calls == 0 || start.elapsed() < slice {
                pass()?;
                calls += 1;
            }
            rates.push(f64::from(calls) * options.poses as f64 / start.elapsed().as_secs_f64());
        }
    }
    Ok(rates.into_iter().map(median).collect())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v.get(n / 2).copied().unwrap_or(0.0),
        n => {
            (v.get(n / 2 - 1).copied().unwrap_or(0.0) + v.get(n / 2).copied().unwrap_or(0.0)) / 2.0
        }
    }
}

/// The batch path against one pose per call and against the baseline (with harmonic
/// recurrences), interleaved: error and Jacobian of all six components and of the position
/// rows, and the error alone. `jacs` and `errs` hold six rows per pose: the batch outputs,
/// the baseline's as well as the JIT's.
fn paths(
    source: &str,
    model: &Model,
    options: &Options,
    rows: &StateRows,
    beta: &[f64],
    jacs: &mut [f64],
    errs: &mut [f64],
) -> Result<Paths, BenchError> {
    use baseline_5axis::{Baseline, Trig};
    use kin_model::jit::Observed;
    use std::cell::RefCell;
    let m = model.machine();
    let n = m.coefficients.len();
    let count = rows.len();
    let jit = model.jit();
    let nonlinear = model.nonlinear();
    jit.prepare(Observed::POSITION);
    // The batch outputs, shared by the passes (which run one at a time).
    let out_cell = RefCell::new((errs, jacs));
    let out = &out_cell;
    let no_baseline = Baseline::new(m, Trig::Recurrence)
        .err()
        .map(|e| e.to_string());
    // The C ABI's model and states (passes 21–23), declared before the passes that borrow them.
    let c_model = c_abi::CModel::new(source, beta).ok();
    let c_states = c_abi::states(rows);
    let mut passes: Vec<Pass<'_>> = Vec::new();
    // 0–1: all six rows, per pose and batch.
    let (mut e6, mut j6) = ([0.0; 6], vec![0.0; 6 * n]);
    passes.push(Box::new(move || {
        for r in 0..count {
            jit.error_and_jacobian(&rows.get(r), beta, nonlinear, &mut e6, &mut j6)?;
        }
        black_box(&j6);
        Ok(())
    }));
    passes.push(Box::new(|| {
        let (e, j) = &mut *out.borrow_mut();
        jit.error_and_jacobian_rows(rows, beta, nonlinear, e, j)?;
        black_box(&j);
        Ok(())
    }));
    // 2–3: the position rows.
    let (mut e3, mut j3) = ([0.0; 3], vec![0.0; 3 * n]);
    passes.push(Box::new(move || {
        for r in 0..count {
            jit.observed_error_and_jacobian(
                &rows.get(r),
                beta,
                nonlinear,
                Observed::POSITION,
                &mut e3,
                &mut j3,
            )?;
        }
        black_box(&j3);
        Ok(())
    }));
    passes.push(Box::new(|| {
        let (e, j) = &mut *out.borrow_mut();
        let (e, j) = (
            e.get_mut(..3 * count).unwrap_or(&mut []),
            j.get_mut(..3 * n * count).unwrap_or(&mut []),
        );
        jit.observed_error_and_jacobian_rows(rows, beta, nonlinear, Observed::POSITION, e, j)?;
        black_box(&j);
        Ok(())
    }));
    // 4–5: the error alone.
    passes.push(Box::new(move || {
        for r in 0..count {
            black_box(jit.error(&rows.get(r), beta, nonlinear)?);
        }
        Ok(())
    }));
    passes.push(Box::new(|| {
        let (e, _) = &mut *out.borrow_mut();
        jit.error_rows(rows, beta, nonlinear, e)?;
        black_box(&e);
        Ok(())
    }));
    // 6–7: batch calls over cache-sized blocks of poses into one reused block: six rows,
    // position rows.
    for k in [6usize, 3] {
        let observed = if k == 6 {
            Observed::FULL
        } else {
            Observed::POSITION
        };
        let per_block = (BLOCK_BYTES / (8 * k * n).max(1)).max(1);
        let (mut eb, mut jb) = (vec![0.0; k * per_block], vec![0.0; k * n * per_block]);
        passes.push(Box::new(move || {
            let mut start = 0;
            while start < count {
                let end = (start + per_block).min(count);
                let block = rows.rows(start, end);
                let (e, j) = (
                    eb.get_mut(..k * (end - start)).unwrap_or(&mut []),
                    jb.get_mut(..k * n * (end - start)).unwrap_or(&mut []),
                );
                jit.observed_error_and_jacobian_rows(&block, beta, nonlinear, observed, e, j)?;
                black_box(&j);
                start = end;
            }
            Ok(())
        }));
    }
    // 8–13: the write floor: each pose's block of the Jacobian written into its place of the
    // batch output, nothing evaluated; six rows, then position rows, each with plain stores
    // and with 16- and 32-byte streaming stores from a block in the first-level cache.
    for (k, kind) in [(6usize, 0u8), (6, 1), (6, 2), (3, 0), (3, 1), (3, 2)] {
        let block = k * n;
        let source: Vec<f64> = (0..block).map(|i| i as f64).collect();
        passes.push(Box::new(move || {
            let (_, j) = &mut *out.borrow_mut();
            let dst = j.get_mut(..block * count).unwrap_or(&mut []);
            for (r, b) in dst.chunks_exact_mut(block.max(1)).enumerate() {
                match kind {
                    0 => b.fill(black_box(r as f64)),
                    1 => kin_model::jit::stream::copy(b, &source),
                    _ => wide_store::copy_wide(b, &source),
                }
            }
            kin_model::jit::stream::fence();
            black_box(&dst);
            Ok(())
        }));
    }
    // 14–15: all six rows written by the generated code straight into the batch output (one
    // call per pose), without and with the destination of the next pose requested for
    // writing (`prefetchw`) before the pose is evaluated.
    for ahead in [false, true] {
        let mut e6 = [0.0; 6];
        passes.push(Box::new(move || {
            let (_, j) = &mut *out.borrow_mut();
            let block = 6 * n;
            let dst = j.get_mut(..block * count).unwrap_or(&mut []);
            for (r, b) in dst.chunks_exact_mut(block.max(1)).enumerate() {
                if ahead {
                    kin_model::jit::stream::prefetch_for_writing(b.as_ptr_range().end, block);
                }
                jit.error_and_jacobian(&rows.get(r), beta, nonlinear, &mut e6, b)?;
            }
            black_box(&dst);
            Ok(())
        }));
    }
    // 16–20: the baseline, each pass with its own (it holds no state between calls).
    if let (Ok(mut b6), Ok(mut b6b), Ok(mut b3), Ok(mut b3b), Ok(mut be)) = (
        Baseline::new(m, Trig::Recurrence),
        Baseline::new(m, Trig::Recurrence),
        Baseline::new(m, Trig::Recurrence),
        Baseline::new(m, Trig::Recurrence),
        Baseline::new(m, Trig::Recurrence),
    ) {
        let (mut e6, mut j6) = ([0.0; 6], vec![0.0; 6 * n]);
        passes.push(Box::new(move || {
            for r in 0..count {
                b6.error_and_jacobian(&rows.get(r), beta, nonlinear, &mut e6, &mut j6);
            }
            black_box(&j6);
            Ok(())
        }));
        passes.push(Box::new(move || {
            let (e, j) = &mut *out.borrow_mut();
            for ((r, e), j) in e
                .chunks_exact_mut(6)
                .enumerate()
                .zip(j.chunks_exact_mut(6 * n))
            {
                let mut row = [0.0; 6];
                b6b.error_and_jacobian(&rows.get(r), beta, nonlinear, &mut row, j);
                e.copy_from_slice(&row);
            }
            black_box(&j);
            Ok(())
        }));
        let (mut e3, mut j3) = ([0.0; 3], vec![0.0; 3 * n]);
        passes.push(Box::new(move || {
            for r in 0..count {
                b3.position_error_and_jacobian(&rows.get(r), beta, &mut e3, &mut j3);
            }
            black_box(&j3);
            Ok(())
        }));
        passes.push(Box::new(move || {
            let (e, j) = &mut *out.borrow_mut();
            let rows3 = e
                .chunks_exact_mut(3)
                .zip(j.chunks_exact_mut(3 * n))
                .take(count);
            for (r, (e, j)) in rows3.enumerate() {
                let mut row = [0.0; 3];
                b3b.position_error_and_jacobian(&rows.get(r), beta, &mut row, j);
                e.copy_from_slice(&row);
            }
            black_box(&j);
            Ok(())
        }));
        passes.push(Box::new(move || {
            for r in 0..count {
                black_box(be.error(&rows.get(r), beta));
            }
            Ok(())
        }));
    }
    // 21–23: one pose per call through the C ABI, six rows, position rows, error alone — after
    // the baseline's passes, whose numbers are fixed above. A model the C ABI does not compile
    // (it compiles what `Model::compile` compiles) leaves the column empty.
    let capi_first = passes.len();
    if let Some(cm) = &c_model {
        let nc = cm.coefficients();
        for observed in [63u32, 7] {
            let k = observed.count_ones() as usize;
            let (mut e, mut j) = ([0.0; 6], vec![0.0; k * nc]);
            let c_states = &c_states;
            passes.push(Box::new(move || {
                for st in c_states {
                    cm.jacobian(st, observed, e.get_mut(..k).unwrap_or(&mut []), &mut j)
                        .map_err(|s| BenchError::CApi(s.0))?;
                }
                black_box(&j);
                Ok(())
            }));
        }
        let mut e = [0.0; 6];
        let c_states = &c_states;
        passes.push(Box::new(move || {
            for st in c_states {
                cm.error(st, &mut e).map_err(|s| BenchError::CApi(s.0))?;
            }
            black_box(&e);
            Ok(())
        }));
    }
    let rates = interleaved(options, &mut passes)?;
    drop(passes);
    let capi = |k: usize| {
        c_model
            .as_ref()
            .and_then(|_| rates.get(capi_first + k).copied())
    };
    let at = |i: usize| rates.get(i).copied().unwrap_or(0.0);
    // The baseline's passes, where there are any, come before the C ABI's.
    let base = |i: usize| rates.get(i).copied().filter(|_| i < capi_first);
    Ok(Paths {
        rounds: options.rounds.max(1),
        full: PathRates {
            per_pose: at(0),
            batch: at(1),
            blocked: base(6),
            baseline: base(16),
            baseline_batch: base(17),
            capi: capi(0),
        },
        position: PathRates {
            per_pose: at(2),
            batch: at(3),
            blocked: base(7),
            baseline: base(18),
            baseline_batch: base(19),
            capi: capi(1),
        },
        error: PathRates {
            per_pose: at(4),
            batch: at(5),
            blocked: None,
            baseline: base(20),
            baseline_batch: None,
            capi: capi(2),
        },
        no_baseline,
        floor_full: Floor {
            plain: at(8),
            streaming: at(9),
            streaming_wide: at(10),
        },
        floor_position: Floor {
            plain: at(11),
            streaming: at(12),
            streaming_wide: at(13),
        },
        direct: at(14),
        direct_prefetch: at(15),
    })
}

/// The servo compensation of every sampled pose in turn, each call timed alone, for about
/// `options.time`: JIT with the default iterations, JIT with the first solve only, interpreter.
fn compensation_times(
    model: &Model,
    options: &Options,
    rows: &StateRows,
    beta: &[f64],
) -> Result<Result<CompensationTimes, String>, BenchError> {
    let mut bound = model.clone();
    bound.set_beta(beta)?;
    let defaults = kin_model::compensate::Options::pose(bound.machine());
    let comp = match bound.compensator(defaults) {
        Ok(c) => c,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let first = match bound.compensator(kin_model::compensate::Options {
        iterations: 1,
        ..defaults
    }) {
        Ok(c) => c,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let worst = match bound.compensator(kin_model::compensate::Options {
        converged: 0.0,
        ..defaults
    }) {
        Ok(c) => c,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let mut dq = vec![0.0; bound.axes()];
    let mut it = comp.interpreter()?;
    let jit = latency(options, rows.len(), |r| {
        typical_compensation_call(&comp, &rows.get(r), &mut dq).map(|_| ())
    });
    let jit_worst_path = latency(options, rows.len(), |r| {
        worst_path_compensation_call(&worst, &rows.get(r), &mut dq).map(|_| ())
    });
    let jit_first_solve = latency(options, rows.len(), |r| {
        first.compensate(&rows.get(r), &mut dq).map(|_| ())
    });
    let interp = latency(options, rows.len(), |r| {
        comp.compensate_interp(&mut it, &rows.get(r), &mut dq)
            .map(|_| ())
    });
    Ok(match (jit, jit_worst_path, jit_first_solve, interp) {
        (Ok(jit), Ok(jit_worst_path), Ok(jit_first_solve), Ok(interp)) => Ok(CompensationTimes {
            iterations: defaults.iterations,
            jit,
            jit_worst_path,
            jit_first_solve,
            interp,
        }),
        (Err(e), ..) | (_, Err(e), ..) | (_, _, Err(e), _) | (.., Err(e)) => Err(e.to_string()),
    })
}

/// One call of the typical path, a function of its own (never inlined) so that callgrind can
/// count each call's instructions: `valgrind --tool=callgrind --collect-atstart=no
/// --toggle-collect=kin_bench::typical_compensation_call
/// --dump-after=kin_bench::typical_compensation_call kin bench …` (spec/cli.md,
/// `kin bench`). The result goes through `black_box` so that the
/// call is not a tail jump (callgrind would not see the function return, and dump nothing),
/// and each wrapper names its path so that the linker cannot fold the two identical bodies
/// into one symbol.
#[inline(never)]
fn typical_compensation_call(
    comp: &kin_model::embed::ServoCompensator,
    state: &kin_model::interp::State,
    dq: &mut [f64],
) -> Result<kin_model::compensate::Compensated, kin_model::compensate::ServoError> {
    black_box("typical path");
    black_box(comp.compensate(state, dq))
}

/// One call of the slowest path (every solve done), never inlined, as
/// [`typical_compensation_call`].
#[inline(never)]
fn worst_path_compensation_call(
    comp: &kin_model::embed::ServoCompensator,
    state: &kin_model::interp::State,
    dq: &mut [f64],
) -> Result<kin_model::compensate::Compensated, kin_model::compensate::ServoError> {
    black_box("slowest path");
    black_box(comp.compensate(state, dq))
}

/// Calls `f` on poses `0, 1, …` (cycling), each call timed alone, for `options.time` (at least
/// one pass over the poses after an untimed one); the clock's own cost is in every figure.
fn latency<E>(
    options: &Options,
    poses: usize,
    mut f: impl FnMut(usize) -> Result<(), E>,
) -> Result<Latency, E> {
    for r in 0..poses {
        f(r)?;
    }
    let mut times: Vec<u64> = Vec::with_capacity(poses.max(1 << 16));
    let start = Instant::now();
    let mut r = 0;
    while times.len() < poses || start.elapsed() < options.time {
        let t = Instant::now();
        f(r)?;
        let ns = t.elapsed().as_nanos();
        times.push(u64::try_from(ns).unwrap_or(u64::MAX));
        r = (r + 1) % poses.max(1);
    }
    times.sort_unstable();
    let at = |q: f64| {
        let k = ((times.len() as f64 - 1.0) * q).round() as usize;
        Duration::from_nanos(times.get(k).copied().unwrap_or(0))
    };
    Ok(Latency {
        calls: times.len(),
        median: at(0.5),
        p999: at(0.999),
        max: at(1.0),
    })
}

fn us(d: Duration) -> String {
    format!("{:.2} µs", d.as_secs_f64() * 1e6)
}
fn baseline_rates(
    m: &Machine,
    options: &Options,
    rows: &StateRows,
    beta: &[f64],
    nonlinear: &[f64],
) -> Result<BaselineRates, String> {
    let n = m.coefficients.len();
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    let mut run = |trig| -> Result<f64, String> {
        let mut b = baseline_5axis::Baseline::new(m, trig).map_err(|e| e.to_string())?;
        rate(options, || {
            for r in 0..rows.len() {
                b.error_and_jacobian(&rows.get(r), beta, nonlinear, &mut err, &mut jac);
            }
            black_box(&jac);
            Ok::<(), String>(())
        })
    };
    Ok(BaselineRates {
        exact: run(baseline_5axis::Trig::Exact)?,
        recurrence: run(baseline_5axis::Trig::Recurrence)?,
    })
}

/// `1234567.8` as `1 234 568`.
fn grouped(x: f64) -> String {
    let digits = format!("{:.0}", x.max(0.0));
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i) % 3 == 0 {
            out.push(' ');
        }
        out.push(c);
    }
    out
}

fn ms(d: Duration) -> String {
    format!("{:.2} ms", d.as_secs_f64() * 1e3)
}

impl fmt::Display for Figures {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}: {} axes, {} coefficients; {} poses sampled over the ranges, best of the rounds",
            self.machine, self.axes, self.coefficients, self.poses
        )?;
        writeln!(
            f,
            "A measurement on this computer, not a test: figures vary with the CPU and its load."
        )?;
        if self.debug_build {
            writeln!(f, "warning: this `kin` was built without optimisations; build with --release for representative figures")?;
        }
        writeln!(f)?;
        writeln!(
            f,
            "{:<40} {:>14} {:>9}   {:>14} {:>9}",
            "poses per second", "error + β-Jac", "× interp", "error only", "× interp"
        )?;
        let line = |f: &mut fmt::Formatter<'_>, name: &str, r: &Rates| {
            writeln!(
                f,
                "{name:<40} {:>14} {:>9.1}   {:>14} {:>9.1}",
                grouped(r.jacobian),
                r.jacobian / self.interp.jacobian,
                grouped(r.error),
                r.error / self.interp.error
            )
        };
        line(f, "interpreter", &self.interp)?;
        line(f, "JIT, one pose per call", &self.jit)?;
        line(f, "JIT, batch of all poses", &self.jit_batch)?;
        match &self.baseline {
            Ok(b) => {
                for (name, rate) in [
                    ("hand-written Rust, libm harmonics", b.exact),
                    ("hand-written Rust, harmonic recurrences", b.recurrence),
                ] {
                    writeln!(
                        f,
                        "{name:<40} {:>14} {:>9.1}   {:>14} {:>9}",
                        grouped(rate),
                        rate / self.interp.jacobian,
                        "-",
                        ""
                    )?;
                }
                writeln!(f)?;
                writeln!(
                    f,
                    "baseline / JIT (error + β-Jacobian, one pose per call): {:.2} with libm harmonics, {:.2} with recurrences",
                    b.exact / self.jit.jacobian,
                    b.recurrence / self.jit.jacobian
                )?;
            }
            Err(why) => {
                writeln!(f)?;
                writeln!(f, "no hand-written baseline: it exists for examples/milling_5axis.kin only ({why})")?;
            }
        }
        writeln!(
            f,
            "JIT / interpreter: {:.1}× (error + β-Jacobian), {:.1}× (error only)",
            self.jit.jacobian / self.interp.jacobian,
            self.jit.error / self.interp.error
        )?;
        writeln!(
            f,
            "writing the 6 × {} Jacobian alone, no arithmetic: {} poses/s; the JIT runs at {:.0} % of that ceiling",
            self.coefficients,
            grouped(self.write_only),
            100.0 * self.jit.jacobian / self.write_only
        )?;
        writeln!(
            f,
            "compile, source to callable functions: {} (front end {}, JIT {})",
            ms(self.compile),
            ms(self.front_end),
            ms(self.jit_compile)
        )?;
        writeln!(f)?;
        self.paths.show(f)?;
        writeln!(f)?;
        match &self.compensation {
            Ok(c) => {
                writeln!(
                    f,
                    "{:<40} {:>10} {:>10} {:>10} {:>10} {:>12}",
                    "time per compensation call", "median", "p99.9", "max", "calls", "× interp"
                )?;
                let line = |f: &mut fmt::Formatter<'_>, name: &str, l: &Latency| {
                    writeln!(
                        f,
                        "{name:<40} {:>10} {:>10} {:>10} {:>10} {:>12.1}",
                        us(l.median),
                        us(l.p999),
                        us(l.max),
                        l.calls,
                        c.interp.median.as_secs_f64() / l.median.as_secs_f64().max(1e-12)
                    )
                };
                line(f, "interpreter", &c.interp)?;
                line(f, &format!("JIT, at most {} solves", c.iterations), &c.jit)?;
                line(
                    f,
                    &format!("JIT, slowest path: all {} solves", c.iterations),
                    &c.jit_worst_path,
                )?;
                line(f, "JIT, first solve only", &c.jit_first_solve)?;
                writeln!(
                    f,
                    "(each call timed alone, clock included; × interp compares medians; the slowest path's median is the time to budget per call on this computer; a maximum is what one unlucky cycle took under its load, not a bound)"
                )
            }
            Err(why) => writeln!(f, "no compensation timing: {why}"),
        }
    }
}

impl Paths {
    fn show(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{:<34} {:>11} {:>11} {:>7} {:>11} {:>7} {:>11} {:>11} {:>7} {:>7} {:>11} {:>7} {:>7}",
            format!("medians of {} interleaved rounds", self.rounds),
            "per pose",
            "batch",
            "b / pp",
            "blocks",
            "bl / pp",
            "baseline",
            "base batch",
            "pp / b",
            "b / bb",
            "C ABI",
            "c / pp",
            "c / b"
        )?;
        let opt = |x: Option<f64>| x.map_or("-".to_string(), grouped);
        let ratio = |a: f64, b: Option<f64>| b.map_or("-".to_string(), |b| format!("{:.2}", a / b));
        for (name, r) in [
            ("error + β-Jacobian, six rows", &self.full),
            ("error + β-Jacobian, position rows", &self.position),
            ("error only, six components", &self.error),
        ] {
            writeln!(
                f,
                "{name:<34} {:>11} {:>11} {:>7.2} {:>11} {:>7} {:>11} {:>11} {:>7} {:>7} {:>11} {:>7} {:>7}",
                grouped(r.per_pose),
                grouped(r.batch),
                r.batch / r.per_pose,
                opt(r.blocked),
                r.blocked
                    .map_or("-".to_string(), |b| format!("{:.2}", b / r.per_pose)),
                opt(r.baseline),
                opt(r.baseline_batch),
                ratio(r.per_pose, r.baseline),
                ratio(r.batch, r.baseline_batch.or(r.baseline)),
                opt(r.capi),
                r.capi
                    .map_or("-".to_string(), |c| format!("{:.2}", c / r.per_pose)),
                r.capi.map_or("-".to_string(), |c| ratio(c, r.baseline)),
            )?;
        }
        for (name, fl, r) in [
            ("write floor, six rows", &self.floor_full, &self.full),
            (
                "write floor, position rows",
                &self.floor_position,
                &self.position,
            ),
        ] {
            let best = fl.streaming.max(fl.streaming_wide).max(fl.plain);
            writeln!(
                f,
                "{name:<34} plain {:>11}, streaming {:>11} (16 B) {:>11} (32 B); batch at {:.0} % of the best, per pose at {:.0} %",
                grouped(fl.plain),
                grouped(fl.streaming),
                grouped(fl.streaming_wide),
                100.0 * r.batch / best,
                100.0 * r.per_pose / best,
            )?;
        }
        writeln!(
            f,
            "(poses/s; batch: one call for all poses into N-row outputs; blocks: one call per {} KiB block of rows into a reused block; baseline: hand-written, harmonic recurrences; b / pp: batch ÷ per pose; bl / pp: blocks ÷ per pose; pp / b: JIT ÷ baseline per pose; b / bb: JIT batch ÷ baseline batch, or ÷ baseline per pose for the error; C ABI: one pose per call through the C ABI, coefficients bound once; c / pp: C ABI ÷ per pose; c / b: C ABI ÷ baseline per pose; write floor: the batch's Jacobian bytes written to its output, nothing evaluated)",
            BLOCK_BYTES >> 10
        )?;
        writeln!(
            f,
            "six rows stored by the generated code straight into the N-row output: {} poses/s ({:.2} × per pose), with the next pose's rows prefetched for writing {} ({:.2} ×)",
            grouped(self.direct),
            self.direct / self.full.per_pose,
            grouped(self.direct_prefetch),
            self.direct_prefetch / self.full.per_pose,
        )?;
        if let Some(why) = &self.no_baseline {
            writeln!(f, "no baseline in this comparison: {why}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grouping() {
        assert_eq!(grouped(0.4), "0");
        assert_eq!(grouped(999.0), "999");
        assert_eq!(grouped(1000.0), "1 000");
        assert_eq!(grouped(1234567.8), "1 234 568");
    }

    #[test]
    fn a_short_bench_gives_every_figure() {
        let src = "machine m { task position  axis X prismatic along x range 0 mm .. 500 mm
            tool chain { X moving tool t }  errors { X.tx = spline(X, knots 2)  X.ry = const } }";
        let options = Options {
            poses: 20,
            time: Duration::from_millis(10),
            rounds: 2,
            seed: 3,
        };
        let figures = measure(src, &options).expect("measures");
        for r in [figures.interp, figures.jit, figures.jit_batch] {
            assert!(r.jacobian > 0.0 && r.error > 0.0, "{figures:?}");
        }
        assert!(figures.write_only > 0.0, "{figures:?}");
        let p = &figures.paths;
        for r in [p.full, p.position, p.error] {
            assert!(
                r.per_pose > 0.0 && r.batch > 0.0 && r.baseline.is_none(),
                "{p:?}"
            );
        }
        for r in [p.full, p.position] {
            assert!(r.blocked.is_some_and(|b| b > 0.0), "{p:?}");
        }
        assert!(p.error.blocked.is_none());
        assert!(p.direct > 0.0 && p.direct_prefetch > 0.0, "{p:?}");
        for fl in [p.floor_full, p.floor_position] {
            assert!(
                fl.plain > 0.0 && fl.streaming > 0.0 && fl.streaming_wide > 0.0,
                "{p:?}"
            );
        }
        assert!(p.no_baseline.is_some());
        assert!(figures.baseline.is_err());
        let c = figures
            .compensation
            .as_ref()
            .expect("a positioning machine");
        for l in [c.jit, c.jit_worst_path, c.jit_first_solve, c.interp] {
            assert!(
                l.calls >= 20 && l.median <= l.p999 && l.p999 <= l.max,
                "{c:?}"
            );
        }
        let text = figures.to_string();
        assert!(
            text.contains("not a test")
                && text.contains("no hand-written baseline")
                && text.contains("time per compensation call")
                && text.contains("slowest path: all 4 solves")
                && text.contains("write floor, six rows"),
            "{text}"
        );
        assert!(matches!(
            measure(
                src,
                &Options {
                    poses: 0,
                    ..options
                }
            ),
            Err(BenchError::NoPoses)
        ));
    }
}
