//! The C ABI against the code it calls (issue 36): one pose per call of `kin_eval_jacobian` and
//! `kin_eval` on the 5-axis example, against `Model::eval_jacobian` and `Model::eval` (the
//! generated code behind a length check) and the hand-written Rust evaluator of the same
//! machine (with harmonic recurrences, as `kin bench`'s baseline, and with the interpreter's
//! `sincos` calls), all in this run; and `kin_eval_batch_observed` in blocks of poses and into
//! one output for all, against the hand-written evaluator writing the same rows. The ratios
//! say what the ABI's checks cost an embedder; the last line, how far copies of the same code
//! in one process run apart.
//!
//! `cargo bench -p kin-bench --bench capi` prints the summary first, then criterion's report.
//! With `KIN_CAPI_CALLS` set it only makes calls, for `runtime/bench/cachegrind.sh` to count
//! their instructions and cache misses ([`calls_only`]).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use kin_bench::baseline_5axis::{self, Trig};
use kin_bench::c_abi::c_state;
use kin_capi::{
    kin_eval, kin_eval_batch_observed, kin_eval_jacobian, kin_eval_jacobian_observed,
    kin_model as CModel, kin_state, KIN_OK,
};
use kin_model::jit::StateRows;

#[path = "common/five_axis.rs"]
mod five_axis;
use five_axis::{c_model, c_rows, rate, setup, POSES};

/// `kin_eval_jacobian_observed` over `states` into reused buffers: with `beta` given per call,
/// or the model's bound β (NULL); `observed` one bit per component.
fn abi_jacobian(
    model: *mut CModel,
    states: &[kin_state],
    beta: Option<&[f64]>,
    observed: u32,
    err: &mut [f64; 6],
    jac: &mut [f64],
) {
    let rows = observed.count_ones() as usize;
    let n = jac.len() / 6;
    let (b, n_beta) = beta.map_or((std::ptr::null(), 0), |b| (b.as_ptr(), b.len()));
    for st in states {
        // SAFETY: a live model, a valid state, β of its length or NULL, and buffers of the
        // lengths stated.
        let code = unsafe {
            kin_eval_jacobian_observed(
                model,
                st,
                b,
                n_beta,
                observed,
                err.as_mut_ptr(),
                rows,
                jac.as_mut_ptr(),
                rows * n,
            )
        };
        debug_assert_eq!(code, KIN_OK);
    }
    black_box(&jac);
}

/// `kin_eval_batch_observed` over `rows` in calls of `per_call` rows (β bound), each call's
/// rows at `at(call)` of `err` and `jac`: the same block again (a consumer's reused block) or
/// the next (one output for all).
fn abi_batch(
    model: *mut CModel,
    rows: &StateRows,
    per_call: usize,
    observed: u32,
    reuse: bool,
    err: &mut [f64],
    jac: &mut [f64],
) {
    let k = observed.count_ones() as usize;
    let n = jac.len() / (k * if reuse { per_call } else { rows.len() });
    let mut start = 0;
    let mut call = 0;
    while start < rows.len() {
        let end = (start + per_call).min(rows.len());
        let block = rows.rows(start, end);
        let cr = c_rows(&block);
        let r = end - start;
        let at = if reuse { 0 } else { call * per_call };
        let (e, j) = (
            &mut err[k * at..k * (at + r)],
            &mut jac[k * n * at..k * n * (at + r)],
        );
        // SAFETY: a live model with β bound, rows valid for the lengths they state, buffers of
        // the lengths passed.
        let code = unsafe {
            kin_eval_batch_observed(
                model,
                &cr,
                std::ptr::null(),
                0,
                observed,
                e.as_mut_ptr(),
                e.len(),
                j.as_mut_ptr(),
                j.len(),
            )
        };
        debug_assert_eq!(code, KIN_OK);
        start = end;
        call += 1;
    }
    black_box(&jac);
}

/// The calls alone, for `runtime/bench/cachegrind.sh`: `KIN_CAPI_CALLS` names the path —
/// `abi`, `abi-position`, `abi-error` (the C ABI, β bound), `model`, `model-position`,
/// `model-error` (`Model`, β given) or `hand` (the hand-written evaluator, six rows) — and
/// `KIN_CAPI_REPS` how many times (default 10) to evaluate the 1 000 poses, after the setup
/// every run shares; nothing is timed or printed. `false` for a name it does not know.
fn calls_only(path: &str, reps: usize) -> bool {
    let s = setup();
    let n = s.model.coefficients();
    let cm = c_model(&s.source, Some(&s.beta));
    let states: Vec<kin_state> = (0..POSES).map(|r| c_state(&s.states.get(r))).collect();
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    let mut hand = baseline_5axis::Baseline::new(s.model.machine(), Trig::Recurrence)
        .expect("the 5-axis example");
    let nonlinear = &s.nonlinear;
    let position = kin_model::engine::Observed::POSITION;
    // One pass over the 1 000 poses: the path chosen once, outside the loops it times.
    let pass: Option<Box<dyn FnMut()>> = match path {
        "abi" => Some(Box::new(|| {
            abi_jacobian(cm, &states, None, 63, &mut err, &mut jac)
        })),
        "abi-position" => Some(Box::new(|| {
            abi_jacobian(cm, &states, None, 7, &mut err, &mut jac)
        })),
        "abi-error" => Some(Box::new(|| {
            for st in &states {
                // SAFETY: a live model with β bound, a valid state, an output of six.
                let code = unsafe { kin_eval(cm, st, std::ptr::null(), 0, err.as_mut_ptr(), 6) };
                debug_assert_eq!(code, KIN_OK);
            }
            black_box(&err);
        })),
        "model" => Some(Box::new(|| {
            for r in 0..POSES {
                let done = s
                    .model
                    .eval_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac);
                debug_assert!(done.is_ok());
            }
            black_box(&jac);
        })),
        "model-position" => Some(Box::new(|| {
            for r in 0..POSES {
                let done = s.model.eval_jacobian_observed(
                    &s.states.get(r),
                    &s.beta,
                    position,
                    &mut err[..3],
                    &mut jac[..3 * n],
                );
                debug_assert!(done.is_ok());
            }
            black_box(&jac);
        })),
        "model-error" => Some(Box::new(|| {
            for r in 0..POSES {
                let done = s.model.eval(&s.states.get(r), &s.beta, &mut err);
                debug_assert!(done.is_ok());
            }
            black_box(&err);
        })),
        "hand" => Some(Box::new(|| {
            for r in 0..POSES {
                hand.error_and_jacobian(&s.states.get(r), &s.beta, nonlinear, &mut err, &mut jac);
            }
            black_box(&jac);
        })),
        _ => None,
    };
    let known = pass.is_some();
    if let Some(mut pass) = pass {
        for _ in 0..reps {
            pass();
        }
    }
    // SAFETY: compiled above, freed once.
    unsafe { kin_capi::kin_model_free(cm) };
    known
}

fn summary() {
    let s = setup();
    let n = s.model.coefficients();
    let cm = c_model(&s.source, None);
    let states: Vec<kin_state> = (0..POSES).map(|r| c_state(&s.states.get(r))).collect();
    let budget = Duration::from_millis(1500);
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    // Interleaved rounds, so that a change of the machine's load affects every figure alike.
    let (mut abi, mut abi_own, mut rust, mut hand) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let (mut hand_exact, mut hand_err) = (0.0f64, 0.0f64);
    let (mut abi_err, mut rust_err, mut abi_position) = (0.0f64, 0.0f64, 0.0f64);
    // The same model with β bound once (kin_model_set_beta): calls pass NULL and 0.
    let cm_bound = c_model(&s.source, Some(&s.beta));
    // The hand-written evaluator with harmonic recurrences (`kin bench`'s baseline) and with a
    // `sincos` of every angle the interpreter takes one of (its numbers, more calls).
    let mut baseline = baseline_5axis::Baseline::new(s.model.machine(), Trig::Recurrence)
        .expect("the 5-axis example");
    let mut exact =
        baseline_5axis::Baseline::new(s.model.machine(), Trig::Exact).expect("the 5-axis example");
    let nonlinear = &s.nonlinear;
    // Batches through the C ABI (β bound) against the hand-written evaluator writing the same
    // rows into the same places: six and position rows, in calls of a cache-sized block of
    // poses into one reused block (31 and 63 poses of this example: `BLOCK_BYTES` of kin
    // bench), and all poses in one call into one output for all.
    let buf = kin_model::RowsBuf::from_states(&s.states);
    let rows = buf.rows();
    let per_block = |k: usize| ((256usize << 10) / (8 * k * n)).max(1);
    let batches = [
        (63u32, per_block(6), true),
        (7, per_block(3), true),
        (63, POSES, false),
        (7, POSES, false),
    ];
    let (mut batch_abi, mut batch_hand) = ([0.0f64; 4], [0.0f64; 4]);
    let mut batch_err = vec![0.0; 6 * POSES];
    let mut batch_jac = vec![0.0; 6 * n * POSES];
    for _ in 0..3 {
        abi = abi.max(rate(budget, || {
            abi_jacobian(cm, &states, Some(&s.beta), 63, &mut err, &mut jac)
        }));
        abi_own = abi_own.max(rate(budget, || {
            abi_jacobian(cm_bound, &states, None, 63, &mut err, &mut jac)
        }));
        abi_position = abi_position.max(rate(budget, || {
            abi_jacobian(cm_bound, &states, None, 7, &mut err, &mut jac)
        }));
        rust = rust.max(rate(budget, || {
            for r in 0..POSES {
                s.model
                    .eval_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac)
                    .expect("eval");
            }
            black_box(&jac);
        }));
        hand = hand.max(rate(budget, || {
            for r in 0..POSES {
                baseline.error_and_jacobian(
                    &s.states.get(r),
                    &s.beta,
                    nonlinear,
                    &mut err,
                    &mut jac,
                );
            }
            black_box(&jac);
        }));
        hand_exact = hand_exact.max(rate(budget, || {
            for r in 0..POSES {
                exact.error_and_jacobian(&s.states.get(r), &s.beta, nonlinear, &mut err, &mut jac);
            }
            black_box(&jac);
        }));
        hand_err = hand_err.max(rate(budget, || {
            for r in 0..POSES {
                black_box(baseline.error(&s.states.get(r), &s.beta));
            }
        }));
        abi_err = abi_err.max(rate(budget, || {
            for st in &states {
                // SAFETY: as above.
                let code = unsafe { kin_eval(cm, st, s.beta.as_ptr(), n, err.as_mut_ptr(), 6) };
                debug_assert_eq!(code, KIN_OK);
            }
            black_box(&err);
        }));
        for (i, (observed, per_call, reuse)) in batches.iter().enumerate() {
            let k = observed.count_ones() as usize;
            let r = if *reuse { *per_call } else { POSES };
            let (e, j) = (&mut batch_err[..k * r], &mut batch_jac[..k * n * r]);
            batch_abi[i] = batch_abi[i].max(rate(budget, || {
                abi_batch(cm_bound, &rows, *per_call, *observed, *reuse, e, j)
            }));
            batch_hand[i] = batch_hand[i].max(rate(budget, || {
                let mut e3 = [0.0; 3];
                let mut e6 = [0.0; 6];
                for p in 0..POSES {
                    let at = if *reuse { p % per_call } else { p };
                    let jp = &mut j[k * n * at..k * n * (at + 1)];
                    if k == 3 {
                        baseline.position_error_and_jacobian(
                            &s.states.get(p),
                            &s.beta,
                            &mut e3,
                            jp,
                        );
                        e[3 * at..3 * at + 3].copy_from_slice(&e3);
                    } else {
                        baseline.error_and_jacobian(
                            &s.states.get(p),
                            &s.beta,
                            nonlinear,
                            &mut e6,
                            jp,
                        );
                        e[6 * at..6 * at + 6].copy_from_slice(&e6);
                    }
                }
                black_box(&j);
            }));
        }
        rust_err = rust_err.max(rate(budget, || {
            for r in 0..POSES {
                s.model
                    .eval(&s.states.get(r), &s.beta, &mut err)
                    .expect("eval");
            }
            black_box(&err);
        }));
    }
    eprintln!("\nC ABI on milling_5axis ({n} coefficients), one pose per call (poses/s, best of 3 × 5 rounds):");
    eprintln!("  error + β-Jacobian: C ABI {abi:.0} (β bound once: {abi_own:.0}), Model {rust:.0}, hand-written {hand:.0} (with the interpreter's sincos calls: {hand_exact:.0})");
    eprintln!(
        "    ABI ÷ Model {:.2} (β bound: {:.2}), ABI ÷ hand {:.2} (β bound: {:.2})",
        abi / rust,
        abi_own / rust,
        abi / hand,
        abi_own / hand
    );
    eprintln!(
        "  position rows only (observed = 7, β bound): C ABI {abi_position:.0}: ÷ its six rows {:.2}, ÷ Model's six rows {:.2}",
        abi_position / abi_own,
        abi_position / rust
    );
    eprintln!(
        "  error only:         C ABI {abi_err:.0}, Model {rust_err:.0}, hand-written {hand_err:.0}: ABI ÷ Model {:.2}, ABI ÷ hand {:.2}",
        abi_err / rust_err,
        abi_err / hand_err
    );
    eprintln!("  batches through kin_eval_batch_observed (β bound), against the hand-written evaluator writing the same rows:");
    for (i, (observed, per_call, reuse)) in batches.iter().enumerate() {
        let what = if *observed == 63 {
            "six rows"
        } else {
            "position rows"
        };
        let how = if *reuse {
            format!("blocks of {per_call} poses a call into one reused block")
        } else {
            format!("{POSES} poses in one call into one output")
        };
        eprintln!(
            "    {what}, {how}: C ABI {:.0}, hand-written {:.0}: ABI ÷ hand {:.2}",
            batch_abi[i],
            batch_hand[i],
            batch_abi[i] / batch_hand[i]
        );
    }
    // SAFETY: compiled above, freed once.
    unsafe {
        kin_capi::kin_model_free(cm);
        kin_capi::kin_model_free(cm_bound);
    };
    copies(&s, budget);
}

/// The same machine code in several places: the model compiled `COPIES` times more, each copy's
/// six-row function timed through `Model` in interleaved rounds. How fast a copy runs depends
/// on where its code and the Rust around it land (spec/performance.md, "Where the code
/// lands"); the spread says how far one figure above may be from another build's.
fn copies(s: &five_axis::Setup, budget: Duration) {
    const COPIES: usize = 6;
    let n = s.model.coefficients();
    let models: Vec<kin_model::Model> = (0..COPIES)
        .map(|_| kin_model::Model::compile(&s.source).expect("compiles"))
        .collect();
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    let mut best = [0.0f64; COPIES];
    for _ in 0..3 {
        for (b, m) in best.iter_mut().zip(&models) {
            *b = b.max(rate(budget, || {
                for r in 0..POSES {
                    m.eval_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac)
                        .expect("eval");
                }
                black_box(&jac);
            }));
        }
    }
    let (lo, hi) = best.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(*v), hi.max(*v))
    });
    eprintln!(
        "  the same model compiled {COPIES} times more, six rows through Model: {lo:.0} … {hi:.0} (slowest ÷ fastest {:.2})",
        lo / hi
    );
}

fn bench(c: &mut Criterion) {
    if let Ok(path) = std::env::var("KIN_CAPI_CALLS") {
        let reps = std::env::var("KIN_CAPI_REPS")
            .ok()
            .and_then(|r| r.parse().ok())
            .unwrap_or(10);
        let known = calls_only(&path, reps);
        std::process::exit(if known { 0 } else { 2 });
    }
    summary();
    let s = setup();
    let n = s.model.coefficients();
    let cm = c_model(&s.source, None);
    let states: Vec<kin_state> = (0..POSES).map(|r| c_state(&s.states.get(r))).collect();
    let mut err = [0.0; 6];
    let mut jac = vec![0.0; 6 * n];
    let mut g = c.benchmark_group("capi_1000_poses");
    g.bench_function("kin_eval_jacobian", |b| {
        b.iter(|| {
            for st in &states {
                // SAFETY: as in `summary`.
                unsafe {
                    kin_eval_jacobian(
                        cm,
                        st,
                        s.beta.as_ptr(),
                        n,
                        err.as_mut_ptr(),
                        6,
                        jac.as_mut_ptr(),
                        6 * n,
                    )
                };
            }
            black_box(&jac);
        })
    });
    g.bench_function("Model::eval_jacobian", |b| {
        b.iter(|| {
            for r in 0..POSES {
                s.model
                    .eval_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac)
                    .expect("eval");
            }
            black_box(&jac);
        })
    });
    g.finish();
    // SAFETY: compiled above, freed once.
    unsafe { kin_capi::kin_model_free(cm) };
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).measurement_time(Duration::from_secs(3));
    targets = bench
}
criterion_main!(benches);
