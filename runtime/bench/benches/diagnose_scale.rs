//! The diagnosis issue's scale benchmark: `kin diagnose` at 10 000 poses. Two models, each
//! simulated (exact transforms, Gaussian noise) from the bundled example with random
//! coefficients and one effect hidden, fitted without it, then diagnosed:
//!
//! - `examples/milling_5axis.kin` without `X.tx += backlash(X)` (172 coefficients, a fitted
//!   lag, a continuous C table; 175 candidates, 738 candidate columns);
//! - `examples/bridge_cmm.kin` without `Y.ty += backlash(Y)`.
//!
//! Reports per phase the wall time, the CPU time of the calling thread and that of the whole
//! process (every thread: the figure that does not depend on what else the machine runs), and
//! the diagnosis' peak memory above what was held before it (the data and the fit with its
//! residual rows). The diagnosis is
//! timed as `diagnose::diagnose` (what `kin diagnose` does after its fit), and its phases from
//! the progress it reports: up to the first row of the candidates' pass (the spectra, the
//! candidate library, the super-model's compilation), the pass itself, the candidate algebra
//! up to the first refit, the refits, and the rest (regions, noise, outliers).
//!
//! ```text
//! cargo bench -p kin-bench --bench diagnose_scale             # 10 000 poses
//! cargo bench -p kin-bench --bench diagnose_scale -- 3000     # fewer poses
//! KIN_BENCH_REPEAT=3                                            # best of N diagnoses
//! ```
//!
//! At 10⁵ poses on a shared 2-core AMD EPYC (spec/performance.md, "Diagnosis at 10⁵ poses"),
//! the mill's diagnosis in CPU-s of all threads, before → after the pass stopped copying its
//! blocks: 10.0 → 9.7 with faer's AVX-512 kernels, 13.0 → 11.7 with its AVX2 kernels; of
//! that the candidate pass 6.0 → 5.5 and 8.4 → 7.3; peak memory +345 → +168 MB.

use std::time::{Duration, Instant};

use kin_compiler::{compile, Compiled};
use kin_data::data::Observations;
use std::sync::{Arc, Mutex};

use kin_diagnose::{self as diagnose, Settings, Step};
use kin_estimate::fit::{self, DataSet, Options};
use kin_estimate::simulate::{self, sample_points};
use rand::{Rng, SeedableRng};

#[path = "common/memory.rs"]
mod memory;
use memory::Peak;

/// CPU time of the calling thread (ns from the scheduler; zero where it cannot be read).
fn cpu_now() -> Duration {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map(Duration::from_nanos)
        .unwrap_or_default()
}

/// CPU time of the whole process, every thread (user + system, clock ticks of 10 ms).
fn process_cpu() -> Duration {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            // Fields after the command's closing parenthesis; utime and stime are 14 and 15.
            let rest = s.rsplit_once(')')?.1;
            let f: Vec<&str> = rest.split_whitespace().collect();
            let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
            Some(Duration::from_millis(ticks * 10))
        })
        .unwrap_or_default()
}

fn timed<T>(what: &str, f: impl FnOnce() -> T) -> (T, Duration) {
    let (w, c, p) = (Instant::now(), cpu_now(), process_cpu());
    let out = f();
    let (wall, cpu) = (w.elapsed(), cpu_now().saturating_sub(c));
    println!(
        "  {what:<28} wall {:>8.3} s   cpu {:>8.3} s   all threads {:>8.3} s",
        wall.as_secs_f64(),
        cpu.as_secs_f64(),
        process_cpu().saturating_sub(p).as_secs_f64()
    );
    (out, cpu)
}

/// A progress report that marks the phases' ends (wall clock, CPU time of the reporting
/// thread, which is the diagnosing one).
/// A phase's end: its name, the wall clock, this thread's and the process's CPU time.
type Mark = (&'static str, Instant, Duration, Duration);

fn phases(marks: Arc<Mutex<Vec<Mark>>>) -> diagnose::Progress {
    diagnose::Progress::new(move |step, done, total| {
        let Ok(mut m) = marks.lock() else { return };
        let mark = match step {
            Step::Rows if m.is_empty() => "spectra, library, compile",
            Step::Rows if done == total => "candidate pass",
            Step::Pairs if done == total => "pairs pass",
            Step::Refits if done == 0 => "candidate algebra",
            Step::Refits if done == total => "refits",
            _ => return,
        };
        if !m.iter().any(|(w, _, _, _)| *w == mark) {
            m.push((mark, Instant::now(), cpu_now(), process_cpu()));
        }
    })
}

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    match out.compiled {
        Some(c) => c,
        None => panic!("{src}\n{:#?}", out.diagnostics),
    }
}

/// One case: the example's text, the line hidden from the start model and its value (display
/// units), the noise.
fn case(name: &str, path: &str, hidden: &str, value: f64, noise: f64, n: usize, repeat: usize) {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
    let truth_src = std::fs::read_to_string(format!("{root}/{path}")).expect("example");
    let line = truth_src
        .lines()
        .find(|l| l.trim_start().starts_with(hidden))
        .expect("hidden line");
    let at = truth_src.find(line).expect("line");
    let range = at..at + line.len();
    let start_src = truth_src.replacen(&format!("{line}\n"), "", 1);
    let truth = compiled(&truth_src);
    let start = compiled(&start_src);
    println!(
        "{name}: {n} poses, {} coefficients in the fitted model",
        start.machine.coefficients.len()
    );
    let mut rng = rand::rngs::StdRng::seed_from_u64(11);
    let beta: Vec<f64> = truth
        .machine
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let span = &truth.map.coefficients[j];
            let v = if span.start >= range.start && span.end <= range.end {
                value
            } else {
                rng.random_range(-1.0..1.0)
            };
            v * c.unit.scale
        })
        .collect();
    let obs = simulate::simulate(
        &truth.machine,
        &beta,
        &Observations::Points(sample_points(&truth.machine, n, 5)),
        &simulate::Options {
            noise,
            seed: 6,
            ..simulate::Options::default()
        },
    )
    .expect("simulate");
    let files = [DataSet {
        path: format!("{name}.csv").into(),
        observations: obs,
    }];
    // As `kin diagnose` fits: a model the data do not fully determine (the mill's position
    // data do not see every rotation) is fitted by minimum norm, not refused.
    let options = Options {
        min_norm: true,
        ..Options::default()
    };
    let engine = kin_model::engine::Engine::default();
    let (base, _) = timed("fit", || {
        let mut e = kin_model::engine::make(&start.machine, engine).expect("engine");
        fit::fit(&start, e.as_mut(), &files, &[], &options, &mut |_, _| {}).expect("fit")
    });
    let settings = Settings {
        noise: Some(noise),
        ..Settings::default()
    };
    let mut best = Duration::MAX;
    for _ in 0..repeat.max(1) {
        let marks = Arc::new(Mutex::new(Vec::<Mark>::new()));
        let settings = Settings {
            progress: phases(marks.clone()),
            ..settings.clone()
        };
        let (t0, c0, p0) = (Instant::now(), cpu_now(), process_cpu());
        let peak = Peak::start();
        let (d, cpu) = timed("diagnose", || {
            diagnose::diagnose(&start, &start_src, &files, &base, &options, &settings)
                .expect("diagnose")
        });
        if let Some(bytes) = peak.increase() {
            println!(
                "    peak memory +{} MB over the {} MB held before it",
                bytes / 1_000_000,
                peak.before() / 1_000_000
            );
        }
        let mut last = (t0, c0, p0);
        let mut marks = marks.lock().map(|m| m.clone()).unwrap_or_default();
        marks.push(("rest", Instant::now(), cpu_now(), process_cpu()));
        for (what, w, c, p) in marks {
            println!(
                "    {what:<26} wall {:>8.3} s   cpu {:>8.3} s   all threads {:>8.3} s",
                w.duration_since(last.0).as_secs_f64(),
                c.saturating_sub(last.1).as_secs_f64(),
                p.saturating_sub(last.2).as_secs_f64()
            );
            last = (w, c, p);
        }
        best = best.min(cpu);
        if let Some(top) = d.findings.first() {
            println!(
                "  {} candidates; top: {} (significant {})",
                d.findings.len(),
                top.candidate.text,
                top.significant
            );
        }
    }
    println!("  best diagnose cpu {:.3} s\n", best.as_secs_f64());
}

fn main() {
    let n: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(10_000);
    let repeat: usize = std::env::var("KIN_BENCH_REPEAT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    case(
        "milling_5axis",
        "examples/milling_5axis.kin",
        "X.tx += backlash(X)",
        1.5,
        0.3e-6,
        n,
        repeat,
    );
    case(
        "bridge_cmm",
        "examples/bridge_cmm.kin",
        "Y.ty += backlash(Y)",
        1.5,
        0.2e-6,
        n,
        repeat,
    );
}
