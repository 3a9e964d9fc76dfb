//! The fit issue's scale benchmark: 1 million point observations (ex, ey, ez: 3 M rows) of a
//! 200-coefficient model, fitted by the streaming QR (`fit::fit`), next to a dense QR
//! least-squares solve of the same matrix held in memory, in the same run.
//!
//! Reports wall time (row generation / factorisation / residual pass) and the peak resident
//! memory *increase* of each phase: `VmHWM` of `/proc/self/status`, reset before each phase by
//! writing `5` to `/proc/self/clear_refs` (falls back to differences of the never-reset peak).
//!
//! ```text
//! cargo bench -p kin-runtime --bench fit_scale                     # 1 000 000 poses
//! KIN_BENCH_POSES=100000 cargo bench -p kin-runtime --bench fit_scale
//! cargo bench -p kin-runtime --bench fit_scale -- 100000           # same
//! KIN_BENCH_BLOCKS=1024,4096,16384   block sizes of the streaming QR (first one is compared)
//! KIN_BENCH_MODEL=path/to/model.kin  default examples/bench_200.kin
//! KIN_BENCH_DENSE=0                  skip the dense solve (it needs ~3 × m × p × 8 bytes)
//! ```

use std::hint::black_box;
use std::time::{Duration, Instant};

use faer::linalg::solvers::SolveLstsq;
use faer::{Mat, MatRef};
use kin_runtime::data::Observations;
use kin_runtime::fit::{self, DataSet, Options, StreamingQr};
use kin_runtime::interp::Interpreter;
use kin_runtime::simulate::{self, sample_points};
use rand::{Rng, SeedableRng};

// ---- memory ---------------------------------------------------------------------------------

fn status_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Peak-RSS probe of one phase.
struct Peak {
    /// Whether `clear_refs` reset the peak; otherwise `hwm0` is the old, never-reset peak.
    reset: bool,
    rss0: u64,
    hwm0: u64,
}

impl Peak {
    fn start() -> Peak {
        let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
        let rss0 = status_kb("VmRSS:").unwrap_or(0);
        let hwm0 = status_kb("VmHWM:").unwrap_or(0);
        Peak { reset, rss0, hwm0 }
    }
    /// Peak increase over the RSS at `start`, in bytes (`None` when it cannot be told).
    fn increase(&self) -> Option<u64> {
        let hwm = status_kb("VmHWM:")?;
        if self.reset {
            Some(hwm.saturating_sub(self.rss0) * 1024)
        } else if hwm > self.hwm0 {
            // The phase set a new process peak: its increase is at least this.
            Some(hwm.saturating_sub(self.rss0) * 1024)
        } else {
            None
        }
    }
}

fn mb(b: Option<u64>) -> String {
    match b {
        Some(b) => format!("{:.0} MB", b as f64 / 1e6),
        None => "n/a".into(),
    }
}

fn secs(d: Duration) -> String {
    format!("{:.2} s", d.as_secs_f64())
}

// ---- set-up ---------------------------------------------------------------------------------

fn poses_wanted() -> usize {
    let arg = std::env::args().skip(1).find(|a| !a.starts_with('-')).and_then(|a| a.replace('_', "").parse().ok());
    let env = std::env::var("KIN_BENCH_POSES").ok().and_then(|a| a.replace('_', "").parse().ok());
    arg.or(env).unwrap_or(1_000_000)
}

fn blocks_wanted() -> Vec<usize> {
    std::env::var("KIN_BENCH_BLOCKS")
        .ok()
        .map(|s| s.split(',').filter_map(|b| b.trim().replace('_', "").parse().ok()).collect::<Vec<usize>>())
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| vec![4096])
}

/// The matrix `[X | y]` of the problem, in memory (column-major X).
struct Dense {
    x: Mat<f64>,
    y: Mat<f64>,
}

/// Builds X and y with `fit::for_each_row`, copying a few rows at a time so the writes into the
/// column-major matrix are contiguous runs instead of one page per value.
fn build_dense(c: &kin_compiler::Compiled, files: &[DataSet]) -> Dense {
    const CHUNK: usize = 64;
    let m = fit::count_rows(files);
    let layout = fit::Layout::new(&c.machine, files);
    let p = layout.columns();
    let states = fit::states(&c.machine, files).expect("states");
    let mut x = Mat::<f64>::zeros(m, p);
    let mut y = Mat::<f64>::zeros(m, 1);
    let mut buf = vec![0.0; CHUNK * p];
    let (mut i0, mut filled) = (0usize, 0usize);
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let mut flush = |x: &mut Mat<f64>, buf: &[f64], i0: usize, filled: usize| {
        for j in 0..p {
            let col = x.col_mut(j).try_as_col_major_mut().expect("contiguous").as_slice_mut();
            for (k, slot) in col[i0..i0 + filled].iter_mut().enumerate() {
                *slot = buf[k * p + j];
            }
        }
    };
    fit::for_each_row(&mut it, files, &states, &layout, |_, row, v| {
        buf[filled * p..(filled + 1) * p].copy_from_slice(row);
        y[(i0 + filled, 0)] = v;
        filled += 1;
        if filled == CHUNK {
            flush(&mut x, &buf, i0, filled);
            i0 += filled;
            filled = 0;
        }
    })
    .expect("rows");
    flush(&mut x, &buf, i0, filled);
    assert_eq!(i0 + filled, m);
    Dense { x, y }
}

/// Streams the in-memory matrix through `StreamingQr` (no row generation): the streaming
/// factorisation's own cost on exactly the dense solve's matrix.
fn stream_in_memory(x: MatRef<'_, f64>, y: MatRef<'_, f64>, block: usize) -> fit::Reduced {
    let (m, p) = (x.nrows(), x.ncols());
    let mut acc = StreamingQr::new(p, block);
    let chunk = 1024;
    let mut t = Mat::<f64>::zeros(p, chunk);
    let mut i0 = 0;
    while i0 < m {
        let b = chunk.min(m - i0);
        t.get_mut(.., ..b).copy_from(x.get(i0..i0 + b, ..).transpose());
        for k in 0..b {
            acc.push(t.col(k).try_as_col_major().expect("contiguous").as_slice(), y[(i0 + k, 0)]);
        }
        i0 += b;
    }
    acc.finish()
}

/// β from a reduced triangle `[R z; 0 ρ]` by back substitution (what the fit's solve does, minus
/// scaling, rank decision and covariance).
fn back_substitute(red: &fit::Reduced) -> Vec<f64> {
    let p = red.norms.len();
    let mut b = vec![0.0; p];
    for i in (0..p).rev() {
        let s: f64 = (i + 1..p).map(|j| red.r[(i, j)] * b[j]).sum();
        b[i] = (red.r[(i, p)] - s) / red.r[(i, i)];
    }
    b
}

fn max_rel_diff(a: &[f64], b: &[f64]) -> (f64, usize) {
    // Relative to each coefficient, guarded by 1e-6 of the largest (a coefficient that is
    // nearly zero in both solutions is compared on the scale of the others).
    let big = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .enumerate()
        .map(|(j, (a, b))| ((a - b).abs() / b.abs().max(1e-6 * big).max(f64::MIN_POSITIVE), j))
        .fold((0.0, 0), |m, v| if v.0 > m.0 { v } else { m })
}

// ---- main -----------------------------------------------------------------------------------

fn main() {
    let poses = poses_wanted();
    let blocks = blocks_wanted();
    let dense_wanted = std::env::var("KIN_BENCH_DENSE").map(|v| v != "0").unwrap_or(true);
    let model = std::env::var("KIN_BENCH_MODEL").unwrap_or_else(|_| format!("{}/../examples/bench_200.kin", env!("CARGO_MANIFEST_DIR")));
    let src = std::fs::read_to_string(&model).unwrap_or_else(|e| panic!("{model}: {e}"));
    let out = kin_compiler::compile(&src);
    let c = out.compiled.unwrap_or_else(|| panic!("{model}: {:#?}", out.diagnostics));
    let n = c.machine.coefficients.len();
    println!("fit_scale: {model}");
    println!("  {} coefficients, {poses} poses (ex ey ez), blocks {blocks:?}, faer parallelism {:?}", n, faer::get_global_parallelism());

    // ---- data: the exact simulator with noise (not part of the fit)
    let t = Instant::now();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let truth: Vec<f64> = c.machine.coefficients.iter().map(|co| co.unit.scale * rng.random_range(-5.0..5.0)).collect();
    let points = sample_points(&c.machine, poses, 2);
    let t_sample = t.elapsed();
    let options = simulate::Options { noise: 0.5e-6, seed: 3, ..simulate::Options::default() };
    let obs = simulate::simulate(&c.machine, &truth, &Observations::Points(points), &options).expect("simulate");
    let t_sim = t.elapsed() - t_sample;
    let files = vec![DataSet { path: "simulated.csv".into(), observations: obs }];
    let m = fit::count_rows(&files);
    let layout = fit::Layout::new(&c.machine, &files);
    let p = layout.columns();
    println!(
        "  data: sampled in {}, simulated (exact) in {} ({:.0} poses/s); {m} rows × {p} columns; RSS now {} MB",
        secs(t_sample),
        secs(t_sim),
        poses as f64 / t_sim.as_secs_f64(),
        status_kb("VmRSS:").unwrap_or(0) / 1000
    );

    // ---- row generation alone (the interpreter's error + Jacobian per pose)
    let states = fit::states(&c.machine, &files).expect("states");
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let t = Instant::now();
    let mut sink = 0.0;
    fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| sink += x[0] + y).expect("rows");
    black_box(sink);
    let t_rows = t.elapsed();
    drop(states);
    println!("  row generation alone: {} = {:.0} poses/s, {:.0} rows/s", secs(t_rows), poses as f64 / t_rows.as_secs_f64(), m as f64 / t_rows.as_secs_f64());

    // ---- streaming fit, per block size
    struct Streamed {
        block: usize,
        total: Duration,
        pass1: Duration,
        pass2: Duration,
        peak: Option<u64>,
        beta: Vec<f64>,
        se: Vec<f64>,
        rank: usize,
        sigma: f64,
    }
    let mut streamed = Vec::new();
    for &block in &blocks {
        let mut it = Interpreter::new(&c.machine).expect("interpreter");
        let opts = Options { block, ..Options::default() };
        let peak = Peak::start();
        let t0 = Instant::now();
        let mut last_factorising = t0;
        let mut progress = |pass: &'static str, _done: usize| {
            if pass == "factorising" {
                last_factorising = Instant::now();
            }
        };
        let r = fit::fit(&c, &mut it, &files, &[], &opts, &mut progress).expect("fit");
        let total = t0.elapsed();
        let peak = peak.increase();
        let pass1 = last_factorising - t0;
        let g = &r.solution.g;
        let se = (0..g.ncols()).map(|j| r.sigma * (0..g.nrows()).map(|k| g[(k, j)].powi(2)).sum::<f64>().sqrt()).collect();
        println!(
            "  streaming fit, block {block:>6}: {} (pass 1 rows+QR {}, solve + pass 2 rows+residuals+leverage {}), peak +{}, rank {}, σ̂ {:.3} µm",
            secs(total),
            secs(pass1),
            secs(total - pass1),
            mb(peak),
            r.solution.rank,
            r.sigma * 1e6
        );
        streamed.push(Streamed { block, total, pass1, pass2: total - pass1, peak, beta: r.solution.beta.clone(), se, rank: r.solution.rank, sigma: r.sigma });
        drop(r);
    }

    // ---- the streaming factorisation alone: rows generated on the fly, pushed, finished
    let mut qr_only = Vec::new();
    for &block in &blocks {
        let states = fit::states(&c.machine, &files).expect("states");
        let mut it = Interpreter::new(&c.machine).expect("interpreter");
        let t = Instant::now();
        let mut acc = StreamingQr::new(p, block);
        fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| acc.push(x, y)).expect("rows");
        black_box(acc.finish());
        qr_only.push((block, t.elapsed()));
    }

    // ---- dense solve of the same matrix
    struct DenseRun {
        build: Duration,
        factor: Duration,
        solve: Duration,
        resid: Duration,
        peak: Option<u64>,
        beta: Vec<f64>,
        rss: f64,
        in_memory: Vec<(usize, Duration, f64)>,
    }
    let dense = dense_wanted.then(|| {
        let peak = Peak::start();
        let t = Instant::now();
        let d = build_dense(&c, &files);
        let build = t.elapsed();
        let t = Instant::now();
        let qr = d.x.qr();
        let factor = t.elapsed();
        let t = Instant::now();
        let mut rhs = d.y.clone();
        qr.solve_lstsq_in_place(&mut rhs);
        let beta: Vec<f64> = (0..p).map(|j| rhs[(j, 0)]).collect();
        let solve = t.elapsed();
        drop(qr);
        let t = Instant::now();
        let bm = Mat::from_fn(p, 1, |j, _| beta[j]);
        let fitted = &d.x * &bm;
        let rss: f64 = (0..m).map(|i| (d.y[(i, 0)] - fitted[(i, 0)]).powi(2)).sum();
        drop(fitted);
        let resid = t.elapsed();
        let peak = peak.increase();
        // The streaming QR alone on this very matrix (no row generation), per block size.
        let in_memory = blocks
            .iter()
            .map(|&block| {
                let t = Instant::now();
                let red = stream_in_memory(d.x.as_ref(), d.y.as_ref(), block);
                let el = t.elapsed();
                let b = back_substitute(&red);
                (block, el, max_rel_diff(&b, &beta).0)
            })
            .collect();
        drop(d);
        DenseRun { build, factor, solve, resid, peak, beta, rss, in_memory }
    });

    // ---- table
    let s0 = &streamed[0];
    println!();
    println!("rows m = {m} ({poses} poses × 3), columns p = {p}, rank {}, σ̂ = {:.4} µm (noise 0.5 µm)", s0.rank, s0.sigma * 1e6);
    println!("row generation (interpreter error + Jacobian): {:.0} poses/s, {:.2} µs/pose", poses as f64 / t_rows.as_secs_f64(), t_rows.as_secs_f64() * 1e6 / poses as f64);
    println!();
    println!("{:<44} {:>10} {:>12}", "phase", "time", "peak +RSS");
    println!("{:-<44} {:->10} {:->12}", "", "", "");
    for s in &streamed {
        let qr = qr_only.iter().find(|q| q.0 == s.block).map(|q| q.1).unwrap_or_default();
        println!("{:<44} {:>10} {:>12}", format!("streaming fit, block {} (total)", s.block), secs(s.total), mb(s.peak));
        println!("{:<44} {:>10}", "  pass 1: rows + streaming QR", secs(s.pass1));
        println!("{:<44} {:>10}", "    of which rows (generation alone)", secs(t_rows));
        println!("{:<44} {:>10}", "    of which QR (pass 1 − rows)", secs(qr.saturating_sub(t_rows)));
        println!("{:<44} {:>10}", "  solve + pass 2: rows + residuals, leverage", secs(s.pass2));
        println!("{:<44} {:>10}", "    of which residual work (pass 2 − rows)", secs(s.pass2.saturating_sub(t_rows)));
    }
    if let Some(d) = &dense {
        let total = d.build + d.factor + d.solve + d.resid;
        println!("{:<44} {:>10} {:>12}", "dense solve (total)", secs(total), mb(d.peak));
        println!("{:<44} {:>10}", "  build X, y (rows)", secs(d.build));
        println!("{:<44} {:>10}", "  factorise (faer Householder QR)", secs(d.factor));
        println!("{:<44} {:>10}", "  solve (Qᵀy, back substitution)", secs(d.solve));
        println!("{:<44} {:>10}", "  residuals y − Xβ", secs(d.resid));
        for (block, el, _) in &d.in_memory {
            println!("{:<44} {:>10}", format!("streaming QR alone, in memory, block {block}"), secs(*el));
        }
        println!();
        for s in &streamed {
            println!(
                "streaming/dense, block {}: time {:.2} (total), {:.2} (without pass 2), peak memory {}",
                s.block,
                s.total.as_secs_f64() / total.as_secs_f64(),
                s.pass1.as_secs_f64() / total.as_secs_f64(),
                match (s.peak, d.peak) {
                    (Some(a), Some(b)) if b > 0 => format!("{:.3}", a as f64 / b as f64),
                    _ => "n/a".into(),
                }
            );
        }
        for (block, el, _) in &d.in_memory {
            println!("factorisation alone, streaming (block {block}) / dense: {:.2}", el.as_secs_f64() / d.factor.as_secs_f64());
        }
        println!();
        for s in &streamed {
            let (rel, j) = max_rel_diff(&s.beta, &d.beta);
            let se = (0..p).map(|j| (s.beta[j] - d.beta[j]).abs() / s.se[j]).fold(0.0, f64::max);
            println!("agreement, fit (block {}) vs dense: max relative |Δβ| {rel:.2e} (coefficient {j}), max |Δβ|/se {se:.2e}", s.block);
        }
        for (block, _, rel) in &d.in_memory {
            println!("agreement, in-memory streaming QR (block {block}) vs dense: max relative |Δβ| {rel:.2e}");
        }
        println!("dense RSS {:.6e} m², streaming σ̂²·(m − rank) {:.6e} m²", d.rss, s0.sigma.powi(2) * (m - s0.rank) as f64);
    }
    let worst = truth.iter().zip(&s0.beta).zip(&s0.se).map(|((t, b), se)| ((b - t) / se).abs()).fold(0.0, f64::max);
    println!("recovery: max |β̂ − β_true| / se = {worst:.2} over {n} coefficients (first-order fit of exact-simulated data)");
}
