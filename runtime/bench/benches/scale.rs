//! Cost at scale (issue 10, "Bounded cost"): the identifiability analysis `kin check` runs and
//! the JIT compile, on generated models of a given number of coefficients, with wall time and
//! the process's peak resident memory. One size per run, so the peak belongs to it:
//!
//! ```text
//! cargo bench -p kin-bench --bench scale -- 1000
//! cargo bench -p kin-bench --bench scale -- 10000
//! ```
//!
//! The model: X, Y, Z prismatic and C revolute; every translation and rotation error of X, Y and
//! Z a 51-coefficient spline (`knots 50, degree 1, smooth 0`), the rest Fourier harmonics of
//! the six C errors (up to 201 per term, several terms per error).
//! The fit at 10⁷ observations is measured through the CLI (`kin simulate --sample`, then
//! `kin fit` under `/usr/bin/time -v`).
//!
//! Figures (release, shared 2-core machine; spec/cli.md, "Limits"). Same-minute pairs:
//!
//! - JIT compile, 10 000 coefficients: one function 9.5 s, pieces of 1 024 1.5 s (load 10.8);
//!   one function 1.4 s, pieces 0.27 s (load 3). 5 000: 1.9 s → 0.7 s (pieces of 512, load 10.8).
//!   Issue 36 (load 3–4): 0.76–0.85 s before, 0.15–0.16 s with each harmonic built once and the
//!   functions compiled on two threads; 1 000 coefficients 0.04–0.09 s → 0.02–0.03 s. At load
//!   6–8, same-minute pairs: 0.89–1.23 s → 0.56–0.76 s (spec/performance.md, "Compile time").
//! - `kin check`, 5 000 coefficients (load 10–11): 89 s with four rows per coefficient added
//!   row by row (70 s sampling and accumulation, 6 s factorisation), 23 s with two rows, 16 s
//!   with the rows added by pose; 5 s / 240 MB at load 3 with the later slice loops.
//! - `kin check`, 10 000 coefficients: 704 s / 894 MB before (previous measurement, load
//!   8–9); 89 s, then 56 s with the condition estimate on slices (load 10); 26–27 s / 860 MB
//!   at load 3–4.
//! - `kin check`, 10 000 coefficients, split by phase with temporary timers (load 14, 2
//!   threads): Gram matrix 48 s, factorisation 28 s, condition estimate 22 s, 98 s in all;
//!   on one core (`taskset -c 0`) 41 / 28 / 24 s, 94 s — at that load the second thread
//!   found no free core. `kin check` no longer estimates the condition (it never showed it).
//!   Then 93 s / 846 MB at load 9, 7 GFLOP/s where one core's large product reached 14
//!   (the `reference` line); 1 000 coefficients 0.4 s / 28 MB. Session 11 (load ≈ 3): 9.48 s /
//!   846 MB at 70 GFLOP/s against a reference of 72.7; JIT compile 0.27 s / 33 MB.
//! - Fit, 10⁷ observed values (41 coefficients): 101 s wall, 19 s CPU at load 11; 20 s at load
//!   3; 1.1 GB peak (about 110 bytes per value held). 10⁸ values (load 3): `kin simulate`
//!   89 s / 7.4 GB, `kin fit` 206 s / 10.7 GB — linear in time and memory. Streamed
//!   (`fit::stream`, 88 coefficients, load 8): 10⁷ values 152 s / 42 MB against 151 s /
//!   1.18 GB read whole, the same FIT.json; 10⁸ values 1 287 s (537 s CPU, load 8–9) / 50 MB.

use std::fmt::Write as _;
use std::time::Instant;

use kin_estimate::identify::{self, Observe};
use kin_model::engine::Engine;

fn model(coefficients: usize) -> String {
    let mut errors = String::new();
    let mut total = 0usize;
    for axis in ["X", "Y", "Z"] {
        for e in ["tx", "ty", "tz", "rx", "ry", "rz"] {
            if total + 51 > coefficients {
                break;
            }
            let _ = writeln!(
                errors,
                "        {axis}.{e} = spline({axis}, knots 50, degree 1, smooth 0)"
            );
            total += 51;
        }
    }
    // Harmonics from 2 up, spread over the six C errors, at most 201 per term.
    let mut next = [2usize; 6];
    let comps = ["tx", "ty", "tz", "rx", "ry", "rz"];
    let mut slot = 0;
    while total + 2 <= coefficients && next.iter().any(|&h| h <= 1000) {
        let i = slot % 6;
        slot += 1;
        let lo = next[i];
        if lo > 1000 {
            continue;
        }
        let count = ((coefficients - total) / 2).min(201).min(1001 - lo);
        if count == 0 {
            break;
        }
        let op = if lo == 2 { "=" } else { "+=" };
        let _ = writeln!(
            errors,
            "        C.{} {op} fourier(C, harmonics {lo}..{})",
            comps[i],
            lo + count - 1
        );
        next[i] = lo + count;
        total += 2 * count;
    }
    format!(
        "machine scale {{
    task position
    units {{ length mm, angle deg, error um, tilt urad }}
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 800 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    axis C revolute about z continuous
    workpiece chain {{ Y fixed  C fixed  workpiece }}
    tool chain {{ X moving  Z moving at (0, 0, 500) mm  tool a at (30, 20, -100) mm  tool b at (-40, 60, -150) mm }}
    errors {{
{errors}    }}
}}
"
    )
}

fn peak_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
            line.split_whitespace().nth(1)?.parse::<f64>().ok()
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn main() {
    // `cargo bench` passes `--bench`; the size is the first number.
    let size = std::env::args()
        .skip(1)
        .find_map(|a| a.parse::<usize>().ok())
        .unwrap_or(1000);
    let src = model(size);
    let c = kin_compiler::compile(&src)
        .compiled
        .unwrap_or_else(|| panic!("the generated model does not compile:\n{src}"));
    let p = c.machine.coefficients.len();
    println!("model: {p} coefficients");

    let t = Instant::now();
    let jit = kin_model::jit::compile(&c.machine).expect("JIT compiles");
    println!(
        "jit compile: {:.2} s (its own clock {:.2} s), peak RSS {:.0} MB",
        t.elapsed().as_secs_f64(),
        jit.compile_time().as_secs_f64(),
        peak_mb()
    );
    drop(jit);

    let poses = identify::poses_for(p, Observe::Pose);
    let t = Instant::now();
    // What `kin check` runs: the dependencies, no condition estimate.
    let report = identify::sampled_verdicts(
        &c.machine,
        Observe::Pose,
        false,
        poses,
        0x6b696e,
        Engine::Jit,
        identify::Condition::Skip,
    )
    .expect("identifiability");
    let seconds = t.elapsed().as_secs_f64();
    // The floating-point work: the Gram matrix by poses (poses × p²/2 multiply-adds, using the
    // pose structure) and its Cholesky factorisation (p³/6 multiply-adds).
    let flops = 2.0 * poses as f64 * (p as f64).powi(2) / 2.0 + (p as f64).powi(3) / 3.0;
    println!(
        "identifiability (pose, {poses} poses, {} rows): {seconds:.2} s, peak RSS {:.0} MB, rank {} of {}, {} dependencies; {:.0} GFLOP/s on {:.2e} flop",
        report.rows,
        peak_mb(),
        report.rank,
        report.columns,
        report.dependencies.len(),
        flops / seconds / 1e9,
        flops
    );
    println!("reference: {:.1} GFLOP/s", matmul_rate());
}

/// What one core reaches now on a large matrix product (faer, 1536³), in GFLOP/s: the rate
/// the analysis could at best reach per core on this machine at this load.
fn matmul_rate() -> f64 {
    use faer::{Accum, Mat, Par};
    const N: usize = 1536;
    let a = Mat::<f64>::from_fn(N, N, |i, j| ((i * 31 + j * 17) % 97) as f64);
    let b = a.transpose().to_owned();
    let mut c = Mat::<f64>::zeros(N, N);
    let t = Instant::now();
    faer::linalg::matmul::matmul(
        c.as_mut(),
        Accum::Replace,
        a.as_ref(),
        b.as_ref(),
        1.0,
        Par::Seq,
    );
    2.0 * (N as f64).powi(3) / t.elapsed().as_secs_f64() / 1e9
}
