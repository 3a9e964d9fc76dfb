//! JIT throughput against the interpreter and a hand-written baseline, in one run (issue 4):
//! poses per second for the error plus its full β-Jacobian (written into a reused buffer) and
//! for the error alone, on every bundled example; the hand-written Rust evaluator of the
//! 5-axis mill; and the compile time from IR to callable functions.
//!
//! Besides criterion's report, a summary with the ratios is printed at the start
//! (`cargo bench -p kin-bench --bench jit`).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kin_bench::baseline_5axis;
use kin_compiler::ir::Machine;
use kin_model::interp::Interpreter;
use kin_model::jit::{self, Observed};
use kin_model::states::States;

// The 5-axis benchmarks' module for its timing loop and pose count; the rest is theirs.
#[allow(dead_code)]
#[path = "common/five_axis.rs"]
mod five_axis;
use five_axis::{rate, POSES};

const EXAMPLES: [&str; 3] = ["milling_5axis", "bridge_cmm", "robot_6axis"];

fn machine(name: &str) -> Machine {
    let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
    let src = std::fs::read_to_string(path).expect("example");
    kin_compiler::compile(&src)
        .compiled
        .expect("compiles")
        .machine
}

struct Setup {
    m: Machine,
    states: States,
    beta: Vec<f64>,
    nonlinear: Vec<f64>,
}

fn setup(name: &str) -> Setup {
    let m = machine(name);
    let n = m.coefficients.len();
    let states = States::sample(&m, POSES, 1);
    let beta = (0..n).map(|j| 1e-6 * ((j % 7) as f64 - 3.0)).collect();
    let nonlinear = m.nonlinear.iter().map(|p| p.value).collect();
    Setup {
        m,
        states,
        beta,
        nonlinear,
    }
}

/// The summary: every figure measured here, in this run, so the ratios compare like with like.
fn summary() {
    let budget = Duration::from_millis(1500);
    eprintln!("\nerror + full β-Jacobian per pose, written into a reused buffer (poses/s, best of 5 rounds):");
    eprintln!(
        "{:<16} {:>4} {:>12} {:>12} {:>8} {:>12} {:>12} {:>12}",
        "machine", "β", "interp", "jit", "×interp", "jit error", "compile ms", "from source"
    );
    let mut milling = None;
    for name in EXAMPLES {
        let s = setup(name);
        let n = s.m.coefficients.len();
        let mut jac = vec![0.0; 6 * n];
        let mut err = [0.0; 6];
        let mut it = Interpreter::new(&s.m).expect("interpreter");
        let interp = rate(budget, || {
            for r in 0..POSES {
                it.error_and_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac)
                    .expect("eval");
            }
            black_box(&jac);
        });
        let compile_ms = (0..5)
            .map(|_| {
                jit::compile(&s.m)
                    .expect("compiles")
                    .compile_time()
                    .as_secs_f64()
                    * 1e3
            })
            .fold(f64::INFINITY, f64::min);
        let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
        let src = std::fs::read_to_string(path).expect("example");
        let source_ms = (0..5)
            .map(|_| {
                let start = Instant::now();
                let m = kin_compiler::compile(&src)
                    .compiled
                    .expect("compiles")
                    .machine;
                black_box(jit::compile(&m).expect("compiles"));
                start.elapsed().as_secs_f64() * 1e3
            })
            .fold(f64::INFINITY, f64::min);
        let model = jit::compile(&s.m).expect("compiles");
        let fast = rate(budget, || {
            for r in 0..POSES {
                model
                    .error_and_jacobian(&s.states.get(r), &s.beta, &s.nonlinear, &mut err, &mut jac)
                    .expect("eval");
            }
            black_box(&jac);
        });
        let error_only = rate(budget, || {
            for r in 0..POSES {
                black_box(
                    model
                        .error(&s.states.get(r), &s.beta, &s.nonlinear)
                        .expect("eval"),
                );
            }
        });
        eprintln!("{name:<16} {n:>4} {interp:>12.0} {fast:>12.0} {:>8.1} {error_only:>12.0} {compile_ms:>12.2} {source_ms:>12.2}", fast / interp);
        if name == "milling_5axis" {
            let mut base = |trig| {
                let mut b = baseline_5axis::Baseline::new(&s.m, trig).expect("the 5-axis example");
                rate(budget, || {
                    for r in 0..POSES {
                        b.error_and_jacobian(
                            &s.states.get(r),
                            &s.beta,
                            &s.nonlinear,
                            &mut err,
                            &mut jac,
                        );
                    }
                    black_box(&jac);
                })
            };
            let exact = base(baseline_5axis::Trig::Exact);
            let recurrence = base(baseline_5axis::Trig::Recurrence);
            milling = Some((fast, exact, recurrence));
        }
    }
    if let Some((fast, exact, recurrence)) = milling {
        eprintln!("hand-written baseline, milling_5axis: {exact:.0} poses/s with libm harmonics (baseline/jit {:.2}), {recurrence:.0} with harmonic recurrences ({:.2})", exact / fast, recurrence / fast);
    }
    eprintln!();
}

/// The rate per pose against the place of the Jacobian buffer: six rows of the 5-axis example,
/// JIT and baseline, one pose per call into one buffer placed at 256 offsets 16 bytes apart
/// (every 16-byte alignment within a 4 KiB page), in interleaved rounds, medians; run with
/// `KIN_BENCH_PLACEMENT=1 cargo bench -p kin-bench --bench jit`. It checks
/// whether the rate per pose depends on where the caller's buffer lies (4 KiB aliasing between
/// the Jacobian's stores and the code's stack reads would show as slow placements): measured,
/// it does not (spec/performance.md, "Run-to-run variation").
fn placement() {
    let s = setup("milling_5axis");
    let n = s.m.coefficients.len();
    let model = jit::compile(&s.m).expect("compiles");
    let Ok(mut base) = baseline_5axis::Baseline::new(&s.m, baseline_5axis::Trig::Recurrence) else {
        return;
    };
    let mut area = vec![0.0; 6 * n + 512];
    let start = area.as_ptr() as usize;
    let mut err = [0.0; 6];
    let offsets: Vec<usize> = (0..256).map(|k| 2 * k).collect();
    let mut jit_rates = vec![Vec::new(); offsets.len()];
    let mut base_rates = vec![Vec::new(); offsets.len()];
    let time = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        f();
        POSES as f64 / t.elapsed().as_secs_f64()
    };
    for _ in 0..5 {
        for (k, &o) in offsets.iter().enumerate() {
            let jac = &mut area[o..o + 6 * n];
            jit_rates[k].push(time(&mut || {
                for r in 0..POSES {
                    model
                        .error_and_jacobian(&s.states.get(r), &s.beta, &s.nonlinear, &mut err, jac)
                        .expect("eval");
                }
                black_box(&jac);
            }));
            base_rates[k].push(time(&mut || {
                for r in 0..POSES {
                    base.error_and_jacobian(&s.states.get(r), &s.beta, &s.nonlinear, &mut err, jac);
                }
                black_box(&jac);
            }));
        }
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    eprintln!("six rows per pose against the Jacobian's address mod 4096 (poses/s, medians of 5 interleaved rounds):");
    eprintln!(
        "{:>6} {:>12} {:>12} {:>8}",
        "mod 4K", "jit", "baseline", "jit/base"
    );
    let mut pairs: Vec<(usize, f64, f64)> = offsets
        .iter()
        .zip(jit_rates.into_iter().zip(base_rates))
        .map(|(&o, (j, b))| ((start + 8 * o) % 4096, median(j), median(b)))
        .collect();
    pairs.sort_by_key(|p| p.0);
    for &(at, j, b) in &pairs {
        eprintln!("{at:>6} {j:>12.0} {b:>12.0} {:>8.2}", j / b);
    }
    let mut j: Vec<f64> = pairs.iter().map(|p| p.1).collect();
    let mut b: Vec<f64> = pairs.iter().map(|p| p.2).collect();
    j.sort_by(f64::total_cmp);
    b.sort_by(f64::total_cmp);
    eprintln!(
        "jit: min {:.0}, median {:.0}, max {:.0}; baseline: min {:.0}, median {:.0}, max {:.0}; medians jit/base {:.2}\n",
        j[0],
        j[j.len() / 2],
        j[j.len() - 1],
        b[0],
        b[b.len() / 2],
        b[b.len() - 1],
        j[j.len() / 2] / b[b.len() / 2]
    );
}

fn bench(c: &mut Criterion) {
    if std::env::var_os("KIN_BENCH_PLACEMENT").is_some() {
        placement();
        return;
    }
    summary();
    let mut group = c.benchmark_group("error+jacobian");
    group.throughput(Throughput::Elements(POSES as u64));
    for name in EXAMPLES {
        let s = setup(name);
        let n = s.m.coefficients.len();
        let label = format!("{name} ({n} coefficients)");
        let mut jac = vec![0.0; 6 * n];
        let mut err = [0.0; 6];
        let mut it = Interpreter::new(&s.m).expect("interpreter");
        group.bench_with_input(BenchmarkId::new("interpreter", &label), &(), |b, _| {
            b.iter(|| {
                for r in 0..POSES {
                    it.error_and_jacobian(&s.states.get(r), &s.beta, &mut err, &mut jac)
                        .expect("eval");
                }
                black_box(&jac);
            })
        });
        let model = jit::compile(&s.m).expect("compiles");
        group.bench_with_input(BenchmarkId::new("jit", &label), &(), |b, _| {
            b.iter(|| {
                for r in 0..POSES {
                    model
                        .error_and_jacobian(
                            &s.states.get(r),
                            &s.beta,
                            &s.nonlinear,
                            &mut err,
                            &mut jac,
                        )
                        .expect("eval");
                }
                black_box(&jac);
            })
        });
        if name == "milling_5axis" {
            let mut base = baseline_5axis::Baseline::new(&s.m, baseline_5axis::Trig::Exact)
                .expect("the 5-axis example");
            group.bench_with_input(BenchmarkId::new("baseline", &label), &(), |b, _| {
                b.iter(|| {
                    for r in 0..POSES {
                        base.error_and_jacobian(
                            &s.states.get(r),
                            &s.beta,
                            &s.nonlinear,
                            &mut err,
                            &mut jac,
                        );
                    }
                    black_box(&jac);
                })
            });
        }
    }
    group.finish();

    let mut group = c.benchmark_group("error");
    group.throughput(Throughput::Elements(POSES as u64));
    for name in EXAMPLES {
        let s = setup(name);
        let label = format!("{name} ({} coefficients)", s.m.coefficients.len());
        let mut it = Interpreter::new(&s.m).expect("interpreter");
        group.bench_with_input(BenchmarkId::new("interpreter", &label), &(), |b, _| {
            b.iter(|| {
                for r in 0..POSES {
                    black_box(it.error(&s.states.get(r), &s.beta).expect("eval"));
                }
            })
        });
        let model = jit::compile(&s.m).expect("compiles");
        group.bench_with_input(BenchmarkId::new("jit", &label), &(), |b, _| {
            b.iter(|| {
                for r in 0..POSES {
                    black_box(
                        model
                            .error(&s.states.get(r), &s.beta, &s.nonlinear)
                            .expect("eval"),
                    );
                }
            })
        });
    }
    group.finish();

    // The paths a fit uses on the 5-axis example: the position rows only (`Observed`) and
    // the batch call into N-row outputs, against the baseline's position rows.
    let mut group = c.benchmark_group("paths");
    group.throughput(Throughput::Elements(POSES as u64));
    {
        let s = setup("milling_5axis");
        let n = s.m.coefficients.len();
        let model = jit::compile(&s.m).expect("compiles");
        model.prepare(Observed::POSITION);
        let (mut e3, mut j3) = ([0.0; 3], vec![0.0; 3 * n]);
        group.bench_function("jit position rows, per pose", |b| {
            b.iter(|| {
                for r in 0..POSES {
                    model
                        .observed_error_and_jacobian(
                            &s.states.get(r),
                            &s.beta,
                            &s.nonlinear,
                            Observed::POSITION,
                            &mut e3,
                            &mut j3,
                        )
                        .expect("eval");
                }
                black_box(&j3);
            })
        });
        let mut base = baseline_5axis::Baseline::new(&s.m, baseline_5axis::Trig::Recurrence)
            .expect("the 5-axis example");
        group.bench_function("baseline position rows, recurrences, per pose", |b| {
            b.iter(|| {
                for r in 0..POSES {
                    base.position_error_and_jacobian(&s.states.get(r), &s.beta, &mut e3, &mut j3);
                }
                black_box(&j3);
            })
        });
        let buf = kin_model::RowsBuf::from_states(&s.states);
        let rows = buf.rows();
        let mut errs = vec![0.0; 6 * POSES];
        let mut jacs = vec![0.0; 6 * n * POSES];
        group.bench_function("jit six rows, batch", |b| {
            b.iter(|| {
                model
                    .error_and_jacobian_rows(&rows, &s.beta, &s.nonlinear, &mut errs, &mut jacs)
                    .expect("batch");
                black_box(&jacs);
            })
        });
        group.bench_function("jit position rows, batch", |b| {
            b.iter(|| {
                model
                    .observed_error_and_jacobian_rows(
                        &rows,
                        &s.beta,
                        &s.nonlinear,
                        Observed::POSITION,
                        &mut errs[..3 * POSES],
                        &mut jacs[..3 * n * POSES],
                    )
                    .expect("batch");
                black_box(&jacs);
            })
        });
        group.bench_function("baseline error only, recurrences", |b| {
            b.iter(|| {
                for r in 0..POSES {
                    black_box(base.error(&s.states.get(r), &s.beta));
                }
            })
        });
    }
    group.finish();

    let mut group = c.benchmark_group("compile");
    for name in EXAMPLES {
        let m = machine(name);
        group.bench_with_input(BenchmarkId::new("ir to callable", name), &(), |b, _| {
            b.iter(|| black_box(jit::compile(&m).expect("compiles")))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
