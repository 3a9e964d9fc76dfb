//! The fit on several threads (`fit::Options::threads`, `StreamingQr::with_threads`): a given
//! thread count gives the same bits on every run, and another count the same fit to rounding.

use kin_compiler::{compile, Compiled};
use kin_data::data::Observations;
use kin_estimate::fit::{self, DataSet, Options, StreamingQr};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;
use rand::{Rng, SeedableRng};

const CMM: &str = r#"
machine cmm3 {
    task measure
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
    }
    workpiece chain { workpiece }
    errors {
        X.tx = spline(X, knots 4)
        X.ty = straightness(X, knots 3)
        X.rz = const + linear(X)
        Y.ty = spline(Y, knots 3) + backlash(Y)
        Y.tx = straightness(Y, knots 2)
        X.ry = const
        Y.rx = const
        Z.tz = spline(Z, knots 2)
    }
}
"#;

fn machine() -> Compiled {
    let out = compile(CMM);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

/// The triangle with each row's sign fixed by its diagonal (Householder leaves the signs of
/// R's rows to the order of the reflections; RᵀR does not depend on them).
fn signed(r: &faer::Mat<f64>) -> Vec<f64> {
    let k = r.ncols();
    (0..k)
        .flat_map(|i| {
            let s = if r[(i, i)] < 0.0 { -1.0 } else { 1.0 };
            (0..k).map(move |j| s * r[(i, j)])
        })
        .collect()
}

fn triangle(rows: &[(Vec<f64>, f64)], p: usize, block: usize, threads: usize) -> fit::Reduced {
    let mut acc = StreamingQr::with_threads(p, block, threads);
    for (x, y) in rows {
        acc.push(x, *y);
    }
    acc.finish()
}

#[test]
fn the_triangle_is_reproducible_per_thread_count_and_agrees_across_counts() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(9);
    let (m, p) = (5000, 12);
    let rows: Vec<(Vec<f64>, f64)> = (0..m)
        .map(|_| {
            let x: Vec<f64> = (0..p).map(|_| rng.random_range(-1.0..1.0)).collect();
            let y = x.iter().enumerate().map(|(j, v)| v * j as f64).sum::<f64>()
                + rng.random_range(-1e-3..1e-3);
            (x, y)
        })
        .collect();
    let one = triangle(&rows, p, 64, 1);
    for threads in [2, 3] {
        let a = triangle(&rows, p, 64, threads);
        let b = triangle(&rows, p, 64, threads);
        // Bit for bit on the same thread count.
        let (ra, rb) = (signed(&a.r), signed(&b.r));
        assert!(
            ra.iter().zip(&rb).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{threads} threads: two runs differ"
        );
        // The same triangle as on one thread, to rounding.
        let r1 = signed(&one.r);
        let scale = r1.iter().fold(0.0f64, |s, v| s.max(v.abs()));
        for (x, y) in r1.iter().zip(&ra) {
            assert!(
                (x - y).abs() <= 1e-12 * scale,
                "{threads} threads: {x} vs {y}"
            );
        }
        assert_eq!(a.rows, m);
        assert_eq!(a.norms, one.norms);
    }
}

/// Simulated points of the CMM (noise 0.5 µm).
fn files(c: &Compiled, n: usize) -> Vec<DataSet> {
    let beta: Vec<f64> = c
        .machine
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, co)| co.unit.scale * ((j as f64 * 0.37).sin() * 4.0))
        .collect();
    let options = simulate::Options {
        noise: 0.5e-6,
        seed: 3,
        ..simulate::Options::default()
    };
    let poses = Observations::Points(sample_points(&c.machine, n, 2));
    let obs = simulate::simulate(&c.machine, &beta, &poses, &options).expect("simulate");
    vec![DataSet {
        path: "points.csv".into(),
        observations: obs,
    }]
}

fn fitted(c: &Compiled, files: &[DataSet], threads: usize) -> fit::FitResult {
    let options = Options {
        // Small blocks, so that every worker gets several and the residual pass splits them.
        block: 1024,
        threads,
        ..Options::default()
    };
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    fit::fit(c, &mut it, files, &[], &options, &mut |_, _| {}).expect("fit")
}

#[test]
fn a_fit_on_two_threads_is_reproducible_and_equals_the_fit_on_one() {
    let c = machine();
    let files = files(&c, 4000);
    let one = fitted(&c, &files, 1);
    let bits = |r: &fit::FitResult| -> Vec<u64> {
        r.solution
            .beta
            .iter()
            .chain([&r.sigma, &r.r2])
            .chain(
                r.residuals
                    .iter()
                    .flat_map(|q| [&q.residual, &q.leverage, &q.cook]),
            )
            .map(|v| v.to_bits())
            .collect()
    };
    let close = |x: f64, y: f64, what: &str| {
        assert!(
            (x - y).abs() <= 1e-10 * x.abs().max(y.abs()).max(1e-300),
            "{what}: {x} vs {y}"
        )
    };
    // Each thread evaluates and factors its own share of the rows: two, and three (more
    // threads than this machine may have cores, and a share that is not half).
    for threads in [2, 3] {
        let a = fitted(&c, &files, threads);
        let b = fitted(&c, &files, threads);
        assert_eq!(bits(&a), bits(&b), "two runs on {threads} threads differ");
        assert_eq!(one.rows, a.rows);
        assert_eq!(one.solution.rank, a.solution.rank);
        for (x, y) in one.solution.beta.iter().zip(&a.solution.beta) {
            close(*x, *y, "β");
        }
        close(one.sigma, a.sigma, "σ̂");
        assert_eq!(one.residuals.len(), a.residuals.len());
        for (x, y) in one.residuals.iter().zip(&a.residuals) {
            assert_eq!(x.meta, y.meta);
            assert!((x.residual - y.residual).abs() <= 1e-10 * one.sigma);
            close(x.leverage, y.leverage, "leverage");
        }
    }
}
