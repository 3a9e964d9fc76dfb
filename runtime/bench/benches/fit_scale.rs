//! The fit issue's scale benchmark: 1 million point observations (ex, ey, ez: 3 M rows) of a
//! 200-coefficient model (`examples/bench_200.kin`), fitted by the streaming QR (`fit::fit`),
//! next to a dense QR least-squares solve of the same matrix held in memory, in the same run.
//!
//! Reports, per phase, wall time and CPU time of the (single) working thread — everything here
//! runs on the main thread (faer without its `rayon` feature is sequential), so CPU time is the
//! figure that does not depend on what else the machine runs — and the peak resident memory
//! *increase*: `VmHWM` of `/proc/self/status`, reset before each phase by writing `5` to
//! `/proc/self/clear_refs` (falls back to differences of the never-reset peak).
//!
//! ```text
//! cargo bench -p kin-bench --bench fit_scale                     # 1 000 000 poses
//! cargo bench -p kin-bench --bench fit_scale -- 100000           # fewer poses
//! KIN_BENCH_POSES=100000             same, by environment
//! KIN_BENCH_BLOCKS=1024,4096,16384   block sizes of the streaming QR (default 4096)
//! KIN_BENCH_MODEL=path/to/model.kin  default examples/bench_200.kin
//! KIN_BENCH_DENSE=0                  skip the dense solve (it needs ~2 × m × p × 8 bytes)
//! ```
//!
//! The flop limit (issue 15): `-- limit [POSES]` fits POSES (default 1 000 000) simulated poses
//! of `examples/milling_5axis.kin`, its time constants fixed at their starting values (a fitted
//! one is optimised over many passes, measured apart), with the JIT as `kin fit` uses it, on 1
//! and on every core (`KIN_BENCH_THREADS=1,2` to choose). The limit is the Householder flop
//! count of the triangle, 2·m·n² − 2n³/3 for m rows of `[X | y]` (n columns), at the rate a
//! faer GEMM of the streaming QR's block shape (`Bᵀ·B`, B = block × n) reaches on as many threads
//! in the same run. Printed: wall time of the factorisation pass and of the whole fit (pass 2
//! adds each row's residual and leverage, about half the flops again), each ÷ the limit, and
//! the peak memory of the fit. `KIN_BENCH_OBSERVE=pose` observes all six components of each
//! pose (`ex … erz`, 6 M rows) instead of the position (`ex ey ez`).
//!
//! `-- tau [POSES]` (default 100 000): the same model fitted with its two time constants fitted
//! and with them fixed, on the same simulated data, in the same run; prints the ratio of the
//! wall times (issue 15 asks ≤ 3).

use std::hint::black_box;
use std::time::{Duration, Instant};

use faer::linalg::solvers::SolveLstsq;
use faer::{Mat, MatRef};
use kin_compiler::Compiled;
use kin_data::data::Observations;
use kin_estimate::fit::{self, DataSet, Options, StreamingQr};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;
use rand::{Rng, SeedableRng};

// ---- measuring ------------------------------------------------------------------------------

// Not every benchmark uses every helper of the shared module.
#[allow(dead_code)]
#[path = "common/memory.rs"]
mod memory;
use memory::{status_kb, Peak};

/// CPU time of the calling thread (ns precision from the scheduler; `/proc/self/stat`'s 10 ms
/// ticks otherwise).
fn cpu_now() -> Duration {
    if let Some(ns) = std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
    {
        return Duration::from_nanos(ns);
    }
    let ticks = std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1.split_whitespace().collect::<Vec<_>>();
            Some(rest.get(11)?.parse::<u64>().ok()? + rest.get(12)?.parse::<u64>().ok()?)
        })
        .unwrap_or(0);
    Duration::from_millis(ticks * 10)
}

/// Wall and CPU time.
#[derive(Debug, Clone, Copy, Default)]
struct T {
    wall: Duration,
    cpu: Duration,
}

impl T {
    fn sub(self, o: T) -> T {
        T {
            wall: self.wall.saturating_sub(o.wall),
            cpu: self.cpu.saturating_sub(o.cpu),
        }
    }
    fn add(self, o: T) -> T {
        T {
            wall: self.wall + o.wall,
            cpu: self.cpu + o.cpu,
        }
    }
}

#[derive(Clone, Copy)]
struct Clock {
    wall: Instant,
    cpu: Duration,
}

impl Clock {
    fn start() -> Clock {
        Clock {
            wall: Instant::now(),
            cpu: cpu_now(),
        }
    }
    fn elapsed(&self) -> T {
        T {
            wall: self.wall.elapsed(),
            cpu: cpu_now().saturating_sub(self.cpu),
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

fn line(name: &str, t: T, peak: Option<Option<u64>>) {
    let peak = peak.map(mb).unwrap_or_default();
    println!(
        "{name:<46} {:>9} {:>9} {peak:>10}",
        secs(t.wall),
        secs(t.cpu)
    );
}

// ---- set-up ---------------------------------------------------------------------------------

fn poses_wanted() -> usize {
    let parse = |a: String| a.replace('_', "").parse().ok();
    let arg = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .and_then(parse);
    arg.or_else(|| std::env::var("KIN_BENCH_POSES").ok().and_then(parse))
        .unwrap_or(1_000_000)
}

fn blocks_wanted() -> Vec<usize> {
    std::env::var("KIN_BENCH_BLOCKS")
        .ok()
        .map(|s| {
            s.split(',')
                .filter_map(|b| b.trim().replace('_', "").parse().ok())
                .collect::<Vec<usize>>()
        })
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| vec![4096])
}

/// An interpreter at the given non-linear parameter values.
fn interpreter<'m>(c: &'m Compiled, values: &[f64]) -> Interpreter<'m> {
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    it.set_nonlinear(values).expect("non-linear values");
    it
}

/// The matrix `[X | y]` of the problem, in memory (column-major X).
struct Dense {
    x: Mat<f64>,
    y: Mat<f64>,
    /// Of the build: allocating (zeroing) the matrix, and copying rows into it.
    alloc: T,
    copy: T,
}

/// Builds X and y with `fit::for_each_row`, copying a chunk of rows at a time so the writes into
/// the column-major matrix are contiguous runs instead of one page per value.
fn build_dense(c: &Compiled, files: &[DataSet], values: &[f64]) -> Dense {
    const CHUNK: usize = 512;
    let m = fit::count_rows(files);
    let layout = fit::Layout::new(&c.machine, files);
    let p = layout.columns();
    let states = fit::states_with(&c.machine, files, values).expect("states");
    let clock = Clock::start();
    let mut x = Mat::<f64>::zeros(m, p);
    let mut y = Mat::<f64>::zeros(m, 1);
    let alloc = clock.elapsed();
    let mut copy = T::default();
    let mut buf = vec![0.0; CHUNK * p];
    let (mut i0, mut filled) = (0usize, 0usize);
    let mut it = interpreter(c, values);
    let flush = |x: &mut Mat<f64>, buf: &[f64], i0: usize, filled: usize| {
        for j in 0..p {
            let col = x
                .col_mut(j)
                .try_as_col_major_mut()
                .expect("contiguous")
                .as_slice_mut();
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
            let clock = Clock::start();
            flush(&mut x, &buf, i0, filled);
            copy = copy.add(clock.elapsed());
            i0 += filled;
            filled = 0;
        }
    })
    .expect("rows");
    flush(&mut x, &buf, i0, filled);
    assert_eq!(i0 + filled, m);
    Dense { x, y, alloc, copy }
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
        t.get_mut(.., ..b)
            .copy_from(x.get(i0..i0 + b, ..).transpose());
        for k in 0..b {
            acc.push(
                t.col(k).try_as_col_major().expect("contiguous").as_slice(),
                y[(i0 + k, 0)],
            );
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

/// Largest relative difference, each coefficient relative to itself, guarded by 1e-6 of the
/// largest (a coefficient nearly zero in both is compared on the scale of the others).
fn max_rel_diff(a: &[f64], b: &[f64]) -> (f64, usize) {
    let big = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .enumerate()
        .map(|(j, (a, b))| {
            (
                (a - b).abs() / b.abs().max(1e-6 * big).max(f64::MIN_POSITIVE),
                j,
            )
        })
        .fold((0.0, 0), |m, v| if v.0 > m.0 { v } else { m })
}

struct Streamed {
    block: usize,
    total: T,
    pass1: T,
    peak: Option<u64>,
    beta: Vec<f64>,
    se: Vec<f64>,
    rank: usize,
    sigma: f64,
    values: Vec<f64>,
}

struct DenseRun {
    build: T,
    alloc: T,
    copy: T,
    factor: T,
    solve: T,
    resid: T,
    peak: Option<u64>,
    beta: Vec<f64>,
    rss: f64,
    /// Per block size: the streaming QR of the in-memory matrix, and its β's difference.
    in_memory: Vec<(usize, T, f64)>,
    leverage: Leverage,
}

/// The per-row leverage `h = ‖G x‖²` over all rows, two ways, in blocks of 4096 rows.
struct Leverage {
    /// As the fit's residual pass does it: a dense `G` (p × p), `X_b Gᵀ`, row sums read across
    /// the column-major product.
    dense: T,
    /// With the triangle: `Z = R⁻ᵀ X_bᵀ` by a triangular solve, column norms.
    triangular: T,
}

fn leverage_kernels(x: MatRef<'_, f64>, r: MatRef<'_, f64>) -> Leverage {
    use faer::linalg::triangular_solve::solve_lower_triangular_in_place;
    let (m, p) = (x.nrows(), x.ncols());
    const B: usize = 4096;
    // G = R⁻ᵀ (lower triangular, held dense like the fit's SVD-based G).
    let mut g = Mat::<f64>::identity(p, p);
    solve_lower_triangular_in_place(r.transpose(), g.as_mut(), faer::Par::Seq);
    let clock = Clock::start();
    let (mut sum_a, mut i0) = (0.0, 0);
    while i0 < m {
        let b = B.min(m - i0);
        let gx = x.get(i0..i0 + b, ..) * g.transpose();
        for i in 0..b {
            let h: f64 = (0..gx.ncols()).map(|k| gx[(i, k)].powi(2)).sum();
            sum_a += h;
        }
        i0 += b;
    }
    let dense = clock.elapsed();
    let clock = Clock::start();
    let (mut sum_b, mut i0) = (0.0, 0);
    let mut z = Mat::<f64>::zeros(p, B);
    while i0 < m {
        let b = B.min(m - i0);
        z.get_mut(.., ..b)
            .copy_from(x.get(i0..i0 + b, ..).transpose());
        solve_lower_triangular_in_place(r.transpose(), z.get_mut(.., ..b), faer::Par::Seq);
        for i in 0..b {
            sum_b += z.col(i).squared_norm_l2();
        }
        i0 += b;
    }
    let triangular = clock.elapsed();
    // Σ h = trace of the hat matrix = p, both ways.
    assert!(
        (sum_a - p as f64).abs() < 1e-6 * p as f64 && (sum_b - p as f64).abs() < 1e-6 * p as f64,
        "Σh {sum_a} {sum_b}"
    );
    Leverage { dense, triangular }
}

// ---- main -----------------------------------------------------------------------------------

fn main() {
    if std::env::args().skip(1).any(|a| a == "limit") {
        flop_limit(poses_wanted());
        return;
    }
    if std::env::args().skip(1).any(|a| a == "tau") {
        let poses = std::env::args()
            .skip(1)
            .find_map(|a| a.replace('_', "").parse().ok())
            .unwrap_or(100_000);
        fitted_tau(poses);
        return;
    }
    let poses = poses_wanted();
    let blocks = blocks_wanted();
    let dense_wanted = std::env::var("KIN_BENCH_DENSE")
        .map(|v| v != "0")
        .unwrap_or(true);
    let model = std::env::var("KIN_BENCH_MODEL").unwrap_or_else(|_| {
        format!(
            "{}/../../examples/bench_200.kin",
            env!("CARGO_MANIFEST_DIR")
        )
    });
    let src = std::fs::read_to_string(&model).unwrap_or_else(|e| panic!("{model}: {e}"));
    let out = kin_compiler::compile(&src);
    let c = out
        .compiled
        .unwrap_or_else(|| panic!("{model}: {:#?}", out.diagnostics));
    let n = c.machine.coefficients.len();
    println!("fit_scale: {model}");
    println!(
        "  {n} coefficients, {poses} poses (ex ey ez), blocks {blocks:?}, faer parallelism {:?}, {} CPUs, load average {}",
        faer::get_global_parallelism(),
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        std::fs::read_to_string("/proc/loadavg").unwrap_or_default().split_whitespace().take(3).collect::<Vec<_>>().join(" ")
    );
    if c.machine.nonlinear.iter().any(|p| p.fitted) {
        println!("  note: the model has fitted non-linear parameters; fit::fit optimises them first (many passes over the data), the other phases use its optimum");
    }

    // ---- data: the exact simulator with noise (not part of the fit)
    let clock = Clock::start();
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let truth: Vec<f64> = c
        .machine
        .coefficients
        .iter()
        .map(|co| co.unit.scale * rng.random_range(-5.0..5.0))
        .collect();
    let points = sample_points(&c.machine, poses, 2);
    let t_sample = clock.elapsed();
    let options = simulate::Options {
        noise: 0.5e-6,
        seed: 3,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&c.machine, &truth, &Observations::Points(points), &options)
        .expect("simulate");
    let t_sim = clock.elapsed().sub(t_sample);
    let files = vec![DataSet {
        path: "simulated.csv".into(),
        observations: obs,
    }];
    let m = fit::count_rows(&files);
    let layout = fit::Layout::new(&c.machine, &files);
    let p = layout.columns();
    println!(
        "  data: sampled in {}, simulated (exact) in {} wall / {} CPU ({:.0} poses/s CPU); {m} rows × {p} columns; RSS now {} MB",
        secs(t_sample.wall),
        secs(t_sim.wall),
        secs(t_sim.cpu),
        poses as f64 / t_sim.cpu.as_secs_f64(),
        status_kb("VmRSS:").unwrap_or(0) / 1000
    );

    // ---- row generation alone (the interpreter's error + Jacobian per pose)
    let declared: Vec<f64> = c.machine.nonlinear.iter().map(|p| p.value).collect();
    let states = fit::states_with(&c.machine, &files, &declared).expect("states");
    let mut it = interpreter(&c, &declared);
    let clock = Clock::start();
    let mut sink = 0.0;
    fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| {
        sink += x[0] + y
    })
    .expect("rows");
    black_box(sink);
    let t_rows = clock.elapsed();
    drop(states);
    println!(
        "  row generation alone: {} wall, {} CPU = {:.0} poses/s CPU",
        secs(t_rows.wall),
        secs(t_rows.cpu),
        poses as f64 / t_rows.cpu.as_secs_f64()
    );

    // ---- streaming fit, per block size
    let mut streamed = Vec::new();
    for &block in &blocks {
        let mut it = interpreter(&c, &declared);
        let opts = Options {
            block,
            ..Options::default()
        };
        let peak = Peak::start();
        let clock = Clock::start();
        let mut pass1 = T::default();
        let mut progress = |pass: &'static str, _done: usize| {
            if pass == "factorising" {
                pass1 = clock.elapsed();
            }
        };
        let r = fit::fit(&c, &mut it, &files, &[], &opts, &mut progress).expect("fit");
        let total = clock.elapsed();
        let peak = peak.increase();
        let values = r
            .nonlinear
            .as_ref()
            .map(|n| n.values.clone())
            .unwrap_or_else(|| declared.clone());
        if let Some(nl) = &r.nonlinear {
            println!(
                "    non-linear parameters fitted first: {} iterations, values {:?}",
                nl.iterations, nl.values
            );
        }
        let g = &r.solution.g;
        let se = (0..g.ncols())
            .map(|j| {
                r.sigma
                    * (0..g.nrows())
                        .map(|k| g[(k, j)].powi(2))
                        .sum::<f64>()
                        .sqrt()
            })
            .collect();
        println!(
            "  streaming fit, block {block:>6}: {} wall / {} CPU (pass 1 {} CPU, solve + pass 2 {} CPU), peak +{}, rank {}, σ̂ {:.4} µm",
            secs(total.wall),
            secs(total.cpu),
            secs(pass1.cpu),
            secs(total.sub(pass1).cpu),
            mb(peak),
            r.solution.rank,
            r.sigma * 1e6
        );
        streamed.push(Streamed {
            block,
            total,
            pass1,
            peak,
            beta: r.solution.beta.clone(),
            se,
            rank: r.solution.rank,
            sigma: r.sigma,
            values,
        });
    }

    // ---- pass 1 alone: rows generated on the fly and pushed through the streaming QR
    let values = streamed[0].values.clone();
    let mut qr_only = Vec::new();
    for &block in &blocks {
        let states = fit::states_with(&c.machine, &files, &values).expect("states");
        let mut it = interpreter(&c, &values);
        let clock = Clock::start();
        let mut acc = StreamingQr::new(p, block);
        fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| acc.push(x, y))
            .expect("rows");
        black_box(acc.finish());
        qr_only.push((block, clock.elapsed()));
    }

    // ---- dense solve of the same matrix
    let dense = dense_wanted.then(|| {
        let peak = Peak::start();
        let clock = Clock::start();
        let d = build_dense(&c, &files, &values);
        let build = clock.elapsed();
        let clock = Clock::start();
        let qr = d.x.qr();
        let factor = clock.elapsed();
        let clock = Clock::start();
        let mut rhs = d.y.clone();
        qr.solve_lstsq_in_place(&mut rhs);
        let beta: Vec<f64> = (0..p).map(|j| rhs[(j, 0)]).collect();
        let solve = clock.elapsed();
        let rt = Mat::from_fn(p, p, |i, j| if j >= i { qr.thin_R()[(i, j)] } else { 0.0 });
        drop(qr);
        let leverage = leverage_kernels(d.x.as_ref(), rt.as_ref());
        let clock = Clock::start();
        let bm = Mat::from_fn(p, 1, |j, _| beta[j]);
        let fitted = &d.x * &bm;
        let rss: f64 = (0..m).map(|i| (d.y[(i, 0)] - fitted[(i, 0)]).powi(2)).sum();
        drop(fitted);
        let resid = clock.elapsed();
        let peak = peak.increase();
        // The streaming QR alone on this very matrix (no row generation), per block size.
        let in_memory = blocks
            .iter()
            .map(|&block| {
                let clock = Clock::start();
                let red = stream_in_memory(d.x.as_ref(), d.y.as_ref(), block);
                let el = clock.elapsed();
                (block, el, max_rel_diff(&back_substitute(&red), &beta).0)
            })
            .collect();
        let (alloc, copy) = (d.alloc, d.copy);
        drop(d);
        DenseRun {
            build,
            alloc,
            copy,
            factor,
            solve,
            resid,
            peak,
            beta,
            rss,
            in_memory,
            leverage,
        }
    });

    // ---- table
    let s0 = &streamed[0];
    println!();
    println!(
        "rows m = {m} ({poses} poses × 3), columns p = {p}, rank {}, σ̂ = {:.4} µm (noise 0.5 µm)",
        s0.rank,
        s0.sigma * 1e6
    );
    println!(
        "row generation (interpreter error + Jacobian): {:.0} poses/s, {:.2} µs/pose (CPU)",
        poses as f64 / t_rows.cpu.as_secs_f64(),
        t_rows.cpu.as_secs_f64() * 1e6 / poses as f64
    );
    println!();
    println!(
        "{:<46} {:>9} {:>9} {:>10}",
        "phase", "wall", "CPU", "peak +RSS"
    );
    println!("{:-<46} {:->9} {:->9} {:->10}", "", "", "", "");
    for s in &streamed {
        let qr = qr_only
            .iter()
            .find(|q| q.0 == s.block)
            .map(|q| q.1)
            .unwrap_or_default();
        line(
            &format!("streaming fit, block {} (total)", s.block),
            s.total,
            Some(s.peak),
        );
        line("  pass 1: rows + streaming QR", s.pass1, None);
        line("    rows (generation alone, measured apart)", t_rows, None);
        line(
            "    QR (pass 1 alone measured apart − rows)",
            qr.sub(t_rows),
            None,
        );
        line(
            "  solve + pass 2: rows, residuals, leverage",
            s.total.sub(s.pass1),
            None,
        );
        line(
            "    residual work (pass 2 − rows)",
            s.total.sub(s.pass1).sub(t_rows),
            None,
        );
    }
    if let Some(d) = &dense {
        let total = d.build.add(d.factor).add(d.solve).add(d.resid);
        line("dense solve (total)", total, Some(d.peak));
        line("  build X, y (rows)", d.build, None);
        line("    allocating (zeroing) X", d.alloc, None);
        line("    copying rows into X", d.copy, None);
        line("  factorise (faer Householder QR, x.qr())", d.factor, None);
        line("  solve (Qᵀy, back substitution)", d.solve, None);
        line("  residuals y − Xβ", d.resid, None);
        line(
            "leverage kernel as in pass 2: x·Gᵀ, G dense",
            d.leverage.dense,
            None,
        );
        line(
            "leverage kernel, triangular: ‖R⁻ᵀx‖²",
            d.leverage.triangular,
            None,
        );
        for (block, el, _) in &d.in_memory {
            line(
                &format!("streaming QR alone, X in memory, block {block}"),
                *el,
                None,
            );
        }
        println!();
        let ratio = |a: Duration, b: Duration| a.as_secs_f64() / b.as_secs_f64();
        for s in &streamed {
            println!(
                "streaming/dense, block {}: time {:.2} CPU ({:.2} wall), pass 1 alone {:.2} CPU; peak memory {}",
                s.block,
                ratio(s.total.cpu, total.cpu),
                ratio(s.total.wall, total.wall),
                ratio(s.pass1.cpu, total.cpu),
                match (s.peak, d.peak) {
                    (Some(a), Some(b)) if b > 0 => format!("{:.3}", a as f64 / b as f64),
                    _ => "n/a".into(),
                }
            );
        }
        for (block, el, _) in &d.in_memory {
            println!(
                "factorisation alone, streaming (block {block}) / dense: {:.2} CPU",
                ratio(el.cpu, d.factor.cpu)
            );
        }
        println!();
        for s in &streamed {
            let (rel, j) = max_rel_diff(&s.beta, &d.beta);
            let se = (0..p)
                .map(|j| (s.beta[j] - d.beta[j]).abs() / s.se[j])
                .fold(0.0, f64::max);
            println!(
                "agreement, fit (block {}) vs dense: max relative |Δβ| {rel:.2e} (coefficient {j}), max |Δβ|/se {se:.2e}",
                s.block
            );
        }
        for (block, _, rel) in &d.in_memory {
            println!("agreement, streaming QR of the in-memory X (block {block}) vs dense: max relative |Δβ| {rel:.2e}");
        }
        println!(
            "dense RSS {:.6e} m², streaming σ̂²·(m − rank) {:.6e} m²",
            d.rss,
            s0.sigma.powi(2) * (m - s0.rank) as f64
        );
    }
    let worst = truth
        .iter()
        .zip(&s0.beta)
        .zip(&s0.se)
        .map(|((t, b), se)| ((b - t) / se).abs())
        .fold(0.0, f64::max);
    println!("recovery: max |β̂ − β_true| / se = {worst:.2} over {n} coefficients (first-order fit of exact-simulated data)");
}

// ---- the flop limit ---------------------------------------------------------------------------

/// GEMM rate (flop/s) of `Bᵀ·B` for B of `rows × n`, on `threads` threads at once, each its own
/// product (so the rate is what the cores give, not what one product's split gives).
/// Returns the rate per wall second and per CPU second of the process.
fn gemm_rate(rows: usize, n: usize, threads: usize) -> (f64, f64) {
    let b = Mat::from_fn(rows, n, |i, j| ((i * 7 + j * 13) % 17) as f64 - 8.0);
    let flops = 2.0 * rows as f64 * (n * n) as f64;
    let mut reps = 1usize;
    loop {
        let start = Instant::now();
        let cpu0 = process_cpu();
        std::thread::scope(|scope| {
            for _ in 0..threads {
                let b = &b;
                scope.spawn(move || {
                    let mut c = Mat::<f64>::zeros(n, n);
                    for _ in 0..reps {
                        faer::linalg::matmul::matmul(
                            c.as_mut(),
                            faer::Accum::Add,
                            b.transpose(),
                            b.as_ref(),
                            1.0,
                            faer::Par::Seq,
                        );
                    }
                    black_box(c);
                });
            }
        });
        let t = start.elapsed().as_secs_f64();
        if t > 1.5 {
            let cpu = process_cpu().saturating_sub(cpu0).as_secs_f64().max(1e-3);
            let work = flops * (reps * threads) as f64;
            return (work / t, work / cpu);
        }
        reps = (reps * 2).max((reps as f64 * 2.0 / t.max(1e-3)) as usize);
    }
}

/// CPU time of the whole process, every thread (`/proc/self/stat` utime + stime, 10 ms ticks):
/// on a machine others load, work divided by it is what the cores did while they were ours.
fn process_cpu() -> Duration {
    let ticks = std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1.split_whitespace().collect::<Vec<_>>();
            Some(rest.get(11)?.parse::<u64>().ok()? + rest.get(12)?.parse::<u64>().ok()?)
        })
        .unwrap_or(0);
    Duration::from_millis(ticks * 10)
}

fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

/// β of the fit's problem by the previous factorisation, for the agreement check: each block of
/// 4 096 rows stacked under the running triangle and factored whole by faer's Householder QR
/// (`Mat::qr`), on one thread, then solved by the fit's own solver (minimum norm, tolerance
/// 10⁻¹⁰). Also returns the standard errors' factors `‖G_j‖` of that solve.
fn reference_fit(c: &Compiled, files: &[DataSet]) -> (Vec<f64>, Vec<f64>) {
    let values: Vec<f64> = c.machine.nonlinear.iter().map(|p| p.value).collect();
    let layout = fit::Layout::new(&c.machine, files);
    let p = layout.columns();
    let k = p + 1;
    let states = fit::states_with(&c.machine, files, &values).expect("states");
    let mut engine =
        kin_model::engine::make(&c.machine, kin_model::engine::Engine::default()).expect("engine");
    const B: usize = 4096;
    let mut r = Mat::<f64>::zeros(k, k);
    let mut block = Mat::<f64>::zeros(B, k);
    let (mut filled, mut rows, mut y_sum) = (0usize, 0usize, 0.0);
    let mut norms2 = vec![0.0; p];
    let fold = |r: &mut Mat<f64>, block: &Mat<f64>, filled: usize| {
        let stacked = Mat::from_fn(k + filled, k, |i, j| {
            if i < k {
                r[(i, j)]
            } else {
                block[(i - k, j)]
            }
        });
        let qr = stacked.qr();
        let t = qr.thin_R();
        *r = Mat::from_fn(k, k, |i, j| if j >= i { t[(i, j)] } else { 0.0 });
    };
    fit::for_each_row(engine.as_mut(), files, &states, &layout, |_, x, y| {
        for (j, v) in x.iter().enumerate() {
            block[(filled, j)] = *v;
            norms2[j] += v * v;
        }
        block[(filled, p)] = y;
        y_sum += y;
        filled += 1;
        rows += 1;
        if filled == B {
            fold(&mut r, &block, filled);
            filled = 0;
        }
    })
    .expect("rows");
    if filled > 0 {
        fold(&mut r, &block, filled);
    }
    let y_sumsq = (0..k).map(|i| r[(i, p)].powi(2)).sum();
    let red = fit::Reduced {
        r,
        rows,
        norms: norms2.iter().map(|v| v.sqrt()).collect(),
        y_sum,
        y_sumsq,
    };
    let s = match fit::merge::solve_triangle(&red, fit::Solver::Qr, 1e-10, true) {
        Ok(s) | Err(s) => s,
    };
    let g_norms = (0..p)
        .map(|j| {
            (0..s.g.nrows())
                .map(|i| s.g[(i, j)].powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    (s.beta, g_norms)
}

fn flop_limit(poses: usize) {
    let model = format!(
        "{}/../../examples/milling_5axis.kin",
        env!("CARGO_MANIFEST_DIR")
    );
    let src = std::fs::read_to_string(&model).unwrap_or_else(|e| panic!("{model}: {e}"));
    // The time constants fixed at their starting values: the linear fit alone.
    let src = src.replace("tau fit", "tau");
    let out = kin_compiler::compile(&src);
    let c = out
        .compiled
        .unwrap_or_else(|| panic!("{model}: {:#?}", out.diagnostics));
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads: Vec<usize> = std::env::var("KIN_BENCH_THREADS")
        .ok()
        .map(|s| s.split(',').filter_map(|t| t.trim().parse().ok()).collect())
        .filter(|v: &Vec<usize>| !v.is_empty())
        .unwrap_or_else(|| if cores > 1 { vec![1, cores] } else { vec![1] });
    println!(
        "fit_scale limit: {model} (τ fixed), {poses} poses, {cores} CPUs, load average {}",
        load()
    );
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let truth: Vec<f64> = c
        .machine
        .coefficients
        .iter()
        .map(|co| co.unit.scale * rng.random_range(-1.0..1.0))
        .collect();
    let clock = Clock::start();
    let points = sample_points(&c.machine, poses, 2);
    // The point observations of a CMM or a laser tracker (`ex ey ez`), or, with
    // `KIN_BENCH_OBSERVE=pose`, full poses (`ex … erz`: six rows a pose, the issue's 6 M rows).
    let pose = std::env::var("KIN_BENCH_OBSERVE").as_deref() == Ok("pose");
    let options = simulate::Options {
        observe: [true, true, true, pose, pose, pose],
        noise: 0.3e-6,
        noise_tilt: 0.3e-6,
        seed: 3,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&c.machine, &truth, &Observations::Points(points), &options)
        .expect("simulate");
    let files = vec![DataSet {
        path: "simulated.csv".into(),
        observations: obs,
    }];
    let m = fit::count_rows(&files);
    let n = fit::Layout::new(&c.machine, &files).columns() + 1;
    let flops = 2.0 * m as f64 * (n * n) as f64 - 2.0 * (n * n * n) as f64 / 3.0;
    println!(
        "  data simulated in {}: {m} rows, [X | y] {n} columns; Householder flops {:.3e}; RSS now {} MB",
        secs(clock.elapsed().wall),
        flops,
        status_kb("VmRSS:").unwrap_or(0) / 1000
    );
    let block = Options::default().block;
    let reference = (std::env::var("KIN_BENCH_REFERENCE").as_deref() != Ok("0")).then(|| {
        let clock = Clock::start();
        let r = reference_fit(&c, &files);
        println!(
            "  reference (faer's QR of each stacked block, one thread): {} CPU",
            secs(clock.elapsed().cpu)
        );
        r
    });
    let mut first: Option<Vec<f64>> = None;
    // One pass of row evaluation alone (JIT error and Jacobian, weighting, nothing done with
    // the rows): what each of the fit's two passes spends before its own arithmetic.
    {
        let values: Vec<f64> = c.machine.nonlinear.iter().map(|p| p.value).collect();
        let layout = fit::Layout::new(&c.machine, &files);
        let states = fit::states_with(&c.machine, &files, &values).expect("states");
        let mut engine = kin_model::engine::make(&c.machine, kin_model::engine::Engine::default())
            .expect("engine");
        let clock = Clock::start();
        let mut sum = 0.0;
        fit::for_each_row(engine.as_mut(), &files, &states, &layout, |_, x, y| {
            sum += y + x[0];
        })
        .expect("rows");
        black_box(sum);
        println!(
            "  rows alone (one pass, JIT): {} CPU, {} wall",
            secs(clock.elapsed().cpu),
            secs(clock.elapsed().wall)
        );
    }
    let mut one_core: Option<f64> = None;
    for &t in &threads {
        let (rate, rate_cpu) = gemm_rate(block, n, t);
        let one_core_limit = *one_core.get_or_insert_with(|| {
            if t == 1 {
                flops / rate
            } else {
                flops / gemm_rate(block, n, 1).0
            }
        });
        let limit = flops / rate;
        let limit_cpu = flops / rate_cpu;
        let cpu0 = process_cpu();
        let opts = Options {
            threads: t,
            min_norm: true,
            ..Options::default()
        };
        let mut engine = kin_model::engine::make(&c.machine, kin_model::engine::Engine::default())
            .expect("engine");
        let peak = Peak::start();
        let clock = Clock::start();
        let mut pass1 = None;
        let mut pass1_cpu = None;
        let mut progress = |pass: &'static str, _done: usize| {
            if pass == "residuals" && pass1.is_none() {
                pass1 = Some(clock.elapsed());
                pass1_cpu = Some(process_cpu().saturating_sub(cpu0));
            }
        };
        let r = fit::fit(&c, engine.as_mut(), &files, &[], &opts, &mut progress).expect("fit");
        let total = clock.elapsed();
        let total_cpu = process_cpu().saturating_sub(cpu0);
        let peak = peak.increase();
        let pass1 = pass1.unwrap_or(total);
        println!(
            "  {t} thread(s): GEMM {:.1} GFLOP/s → limit {}; factorisation {} wall ({:.2}× the limit), whole fit {} wall ({:.2}×), peak +{} (process peak {} MB), load {}",
            rate / 1e9,
            secs(Duration::from_secs_f64(limit)),
            secs(pass1.wall),
            pass1.wall.as_secs_f64() / limit,
            secs(total.wall),
            total.wall.as_secs_f64() / limit,
            mb(peak),
            status_kb("VmHWM:").unwrap_or(0) / 1000,
            load()
        );
        if t > 1 {
            println!(
                "    against one core's limit ({}): factorisation {:.2}×, whole fit {:.2}× (wall)",
                secs(Duration::from_secs_f64(one_core_limit)),
                pass1.wall.as_secs_f64() / one_core_limit,
                total.wall.as_secs_f64() / one_core_limit
            );
        }
        // The same against the GEMM's work per CPU second: what the fit makes of the cycles it
        // got, whatever else the machine ran (on a loaded machine the wall ratio measures the
        // others too).
        let p1 = pass1_cpu.unwrap_or(total_cpu).as_secs_f64();
        println!(
            "    CPU of the process: GEMM {:.1} GFLOP per CPU-s → {:.2} CPU-s; factorisation {:.2} CPU-s ({:.2}×), whole fit {:.2} CPU-s ({:.2}×)",
            rate_cpu / 1e9,
            limit_cpu,
            p1,
            p1 / limit_cpu,
            total_cpu.as_secs_f64(),
            total_cpu.as_secs_f64() / limit_cpu
        );
        if let Some((beta, g)) = &reference {
            let (d, j) = max_rel_diff(&r.solution.beta, beta);
            let se = r
                .solution
                .beta
                .iter()
                .zip(beta)
                .zip(g)
                .map(|((a, b), g)| (a - b).abs() / (g * r.sigma).max(f64::MIN_POSITIVE))
                .fold(0.0, f64::max);
            println!("    β against the reference: largest relative difference {d:.1e} (coefficient {j}), largest |Δβ|/se {se:.1e}");
        }
        match &first {
            None => first = Some(r.solution.beta.clone()),
            Some(b) => {
                let (d, j) = max_rel_diff(&r.solution.beta, b);
                println!("    β against the first thread count: largest relative difference {d:.1e} (coefficient {j})");
            }
        }
    }
}

fn fitted_tau(poses: usize) {
    let model = format!(
        "{}/../../examples/milling_5axis.kin",
        env!("CARGO_MANIFEST_DIR")
    );
    let src = std::fs::read_to_string(&model).unwrap_or_else(|e| panic!("{model}: {e}"));
    let compile = |src: &str| {
        let out = kin_compiler::compile(src);
        out.compiled
            .unwrap_or_else(|| panic!("{model}: {:#?}", out.diagnostics))
    };
    let free = compile(&src);
    let fixed = compile(&src.replace("tau fit", "tau"));
    println!(
        "fit_scale tau: {model}, {poses} poses, time constants {:?}, load average {}",
        free.machine
            .nonlinear
            .iter()
            .filter(|p| p.fitted)
            .map(|p| p.value)
            .collect::<Vec<_>>(),
        load()
    );
    let mut rng = rand::rngs::StdRng::seed_from_u64(1);
    let truth: Vec<f64> = free
        .machine
        .coefficients
        .iter()
        .map(|co| co.unit.scale * rng.random_range(-1.0..1.0))
        .collect();
    // The truth's time constants 30 % off the model's start values, so the optimiser moves.
    let mut truth_src = src.clone();
    for (from, to) in [
        ("tau fit 25 min", "tau 32 min"),
        ("tau fit 60 min", "tau 45 min"),
    ] {
        truth_src = truth_src.replace(from, to);
    }
    let truth_c = compile(&truth_src);
    let points = sample_points(&truth_c.machine, poses, 2);
    let options = simulate::Options {
        noise: 0.3e-6,
        seed: 3,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(
        &truth_c.machine,
        &truth,
        &Observations::Points(points),
        &options,
    )
    .expect("simulate");
    let files = vec![DataSet {
        path: "simulated.csv".into(),
        observations: obs,
    }];
    let opts = Options {
        min_norm: true,
        ..Options::default()
    };
    let mut walls = Vec::new();
    for (name, c) in [("fixed", &fixed), ("fitted", &free), ("fixed", &fixed)] {
        let mut engine = kin_model::engine::make(&c.machine, kin_model::engine::Engine::default())
            .expect("engine");
        let clock = Clock::start();
        let cpu0 = process_cpu();
        let r = fit::fit(c, engine.as_mut(), &files, &[], &opts, &mut |_, _| {}).expect("fit");
        let t = clock.elapsed();
        let cpu = process_cpu().saturating_sub(cpu0);
        let nl = r
            .nonlinear
            .as_ref()
            .map(|n| {
                let each: Vec<String> = n
                    .values
                    .iter()
                    .zip(&n.se)
                    .zip(&n.verdicts)
                    .map(|((v, se), verdict)| match (se, verdict) {
                        (Some(se), Some(d)) => format!(
                            "{v:.1} ± {se:.1} s ({})",
                            if d.determined {
                                "determined"
                            } else {
                                "undetermined"
                            }
                        ),
                        _ => format!("{v:.1} s (fixed)"),
                    })
                    .collect();
                format!(", {} iterations, τ {}", n.iterations, each.join(", "))
            })
            .unwrap_or_default();
        println!(
            "  τ {name:<6}: {} wall, {} CPU of the process; σ̂ {:.4} µm{nl}",
            secs(t.wall),
            secs(cpu),
            r.sigma * 1e6
        );
        walls.push((t.wall.as_secs_f64(), cpu.as_secs_f64()));
    }
    // What one pass over the rows costs (the lag states at the start values, every row
    // evaluated, nothing accumulated): the unit of the optimiser's work.
    let pass = {
        let m = &free.machine;
        let mut engine =
            kin_model::engine::make(m, kin_model::engine::Engine::default()).expect("engine");
        let values: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
        let layout = fit::Layout::new(m, &files).weighted(m, opts.noise, &[]);
        let clock = Clock::start();
        let cpu0 = process_cpu();
        let states = fit::states_with(m, &files, &values).expect("states");
        let mut sum = 0.0;
        fit::for_each_row(engine.as_mut(), &files, &states, &layout, |_, x, y| {
            sum += x.first().copied().unwrap_or(0.0) + y
        })
        .expect("rows");
        black_box(sum);
        (
            clock.elapsed().wall.as_secs_f64(),
            process_cpu().saturating_sub(cpu0).as_secs_f64(),
        )
    };
    let fixed = |f: fn(&(f64, f64)) -> f64| (f(&walls[0]) + f(&walls[2])) / 2.0;
    println!(
        "  one pass over the rows: {:.2} s wall, {:.2} s CPU; the fitted fit's extra CPU is {:.1} passes",
        pass.0,
        pass.1,
        (walls[1].1 - fixed(|w| w.1)) / pass.1.max(1e-9)
    );
    println!(
        "  fitted ÷ fixed (mean of the two fixed fits around it): {:.2}× wall, {:.2}× CPU, load {}",
        walls[1].0 / fixed(|w| w.0),
        walls[1].1 / fixed(|w| w.1),
        load()
    );
}
