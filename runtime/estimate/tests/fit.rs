//! The fit on data with a known truth: simulated by the exact simulator, fitted back.

use faer::linalg::solvers::{DenseSolveCore, SolveLstsq};
use faer::Mat;
use kin_compiler::{compile, Compiled};
use kin_data::data::{Groups, Observations};
use kin_estimate::fit::{self, DataSet, FitError, Options, Solver};
use kin_estimate::simulate::{self, sample_points};
use kin_estimate::uncertainty::PredictionCovariance;
use kin_model::interp::Interpreter;
use rand::{Rng, SeedableRng};

/// A small 3-axis CMM: squareness, scales, a straightness, a yaw with its Abbe arm and a
/// backlash, 14 coefficients.
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
        tool side at (60, 40, -100) mm
    }
    workpiece chain { workpiece }
    errors {
        X.tx = spline(X, knots 2)
        X.rz = const + linear(X)
        Y.ty = linear(Y) + backlash(Y)
        Y.tx = straightness(Y, knots 2)
        X.ry = const
        Y.rx = const
        Z.tz = linear(Z)
    }
}
"#;

fn machine(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

fn truth(c: &Compiled, seed: u64) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    c.machine
        .coefficients
        .iter()
        .map(|co| co.unit.scale * rng.random_range(-5.0..5.0))
        .collect()
}

fn simulated(
    c: &Compiled,
    beta: &[f64],
    n: usize,
    noise: f64,
    seed: u64,
    artifacts: usize,
) -> DataSet {
    let mut poses = sample_points(&c.machine, n, seed);
    if artifacts > 0 {
        poses.rows.artifact = Some(Groups {
            of_row: (0..n).map(|r| Some((r % artifacts) as u32)).collect(),
            labels: (0..artifacts).map(|a| format!("plate{a}")).collect(),
        });
    }
    let options = simulate::Options {
        noise,
        seed: seed + 1,
        artifact_shift: 50e-6,
        artifact_rotation: 20e-6,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&c.machine, beta, &Observations::Points(poses), &options)
        .expect("simulate");
    DataSet {
        path: format!("sim{seed}.csv").into(),
        observations: obs,
    }
}

fn run(c: &Compiled, files: &[DataSet], options: &Options) -> Result<fit::FitResult, FitError> {
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    fit::fit(c, &mut it, files, &[], options, &mut |_, _| {})
}

fn standard_errors(r: &fit::FitResult) -> Vec<f64> {
    let g = &r.solution.g;
    (0..g.ncols())
        .map(|j| {
            r.sigma
                * (0..g.nrows())
                    .map(|k| g[(k, j)].powi(2))
                    .sum::<f64>()
                    .sqrt()
        })
        .collect()
}

#[test]
fn estimates_cover_the_truth_at_the_stated_rate() {
    // Over many seeds, β̂ falls within 1.96 standard errors of the truth ~95 % of the time and
    // the z-scores have unit variance: the standard errors mean what they say.
    let c = machine(CMM);
    let sigma = 0.3e-6;
    let (mut inside, mut total, mut z2) = (0usize, 0usize, 0.0);
    let mut sigma_ratio = Vec::new();
    for seed in 0..60 {
        let beta = truth(&c, seed);
        let data = simulated(&c, &beta, 300, sigma, 1000 + seed, 0);
        let r = run(&c, &[data], &Options::default()).expect("fit");
        let se = standard_errors(&r);
        for (j, b) in beta.iter().enumerate() {
            let z = (r.solution.beta[j] - b) / se[j];
            inside += usize::from(z.abs() < 1.96);
            z2 += z * z;
            total += 1;
        }
        sigma_ratio.push(r.sigma / sigma);
    }
    let rate = inside as f64 / total as f64;
    let var = z2 / total as f64;
    let mean_sigma = sigma_ratio.iter().sum::<f64>() / sigma_ratio.len() as f64;
    // 840 z-scores: the binomial standard deviation of the rate is 0.0075.
    assert!((0.925..0.975).contains(&rate), "coverage {rate}");
    assert!((0.85..1.15).contains(&var), "var(z) {var}");
    assert!((0.97..1.03).contains(&mean_sigma), "σ̂/σ {mean_sigma}");
}

#[test]
fn every_number_matches_a_dense_reference_solve() {
    let c = machine(CMM);
    let beta = truth(&c, 7);
    let data = simulated(&c, &beta, 200, 0.5e-6, 8, 2);
    let files = [data];
    // Small blocks, so the streaming QR really streams.
    let options = Options {
        block: 37,
        ..Options::default()
    };
    let r = run(&c, &files, &options).expect("fit");

    let mut it = Interpreter::new(&c.machine).unwrap();
    let layout = fit::Layout::new(&c.machine, &files);
    let states = fit::states(&c.machine, &files).unwrap();
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| {
        xs.push(x.to_vec());
        ys.push(y);
    })
    .unwrap();
    let (m, p) = (xs.len(), layout.columns());
    assert_eq!(
        p,
        14 + 12,
        "two artifacts bring six placement parameters each"
    );
    let x = Mat::from_fn(m, p, |i, j| xs[i][j]);
    let y = Mat::from_fn(m, 1, |i, _| ys[i]);
    let dense = x.qr().solve_lstsq(&y);
    for j in 0..p {
        let scale = dense[(j, 0)].abs().max(1e-9);
        assert!(
            (r.solution.beta[j] - dense[(j, 0)]).abs() < 1e-7 * scale + 1e-15,
            "β[{j}]: {} vs {}",
            r.solution.beta[j],
            dense[(j, 0)]
        );
    }
    let resid: Vec<f64> = (0..m)
        .map(|i| ys[i] - (0..p).map(|j| xs[i][j] * dense[(j, 0)]).sum::<f64>())
        .collect();
    let rss: f64 = resid.iter().map(|v| v * v).sum();
    assert!(
        (r.solution.rss - rss).abs() < 1e-8 * rss,
        "rss {} vs {rss}",
        r.solution.rss
    );
    // Covariance σ̂²(XᵀX)⁻¹ (eq. 4.11) and leverages diag X(XᵀX)⁻¹Xᵀ.
    let xtx = x.transpose() * &x;
    let inv = xtx.partial_piv_lu().inverse();
    let sigma2 = rss / (m - p) as f64;
    let se = standard_errors(&r);
    for j in 0..p {
        let want = (sigma2 * inv[(j, j)]).sqrt();
        assert!(
            (se[j] - want).abs() < 1e-6 * want,
            "se[{j}] {} vs {want}",
            se[j]
        );
    }
    for (i, row) in r.residuals.iter().enumerate() {
        let h: f64 = (0..p)
            .map(|a| {
                (0..p)
                    .map(|b| xs[i][a] * inv[(a, b)] * xs[i][b])
                    .sum::<f64>()
            })
            .sum();
        assert!(
            (row.leverage - h).abs() < 1e-7,
            "leverage {i}: {} vs {h}",
            row.leverage
        );
        assert!(
            (row.residual - resid[i]).abs() < 1e-9 * rss.sqrt(),
            "residual {i}"
        );
    }
    let sum_h: f64 = r.residuals.iter().map(|r| r.leverage).sum();
    assert!(
        (sum_h - p as f64).abs() < 1e-6,
        "the leverages sum to the number of parameters: {sum_h}"
    );
    // σ̂, R², studentized residuals and Cook's distance by their textbook formulas.
    let sigma = sigma2.sqrt();
    assert!((r.sigma - sigma).abs() < 1e-9 * sigma);
    let mean = ys.iter().sum::<f64>() / m as f64;
    let sst: f64 = ys.iter().map(|y| (y - mean).powi(2)).sum();
    assert!((r.r2 - (1.0 - rss / sst)).abs() < 1e-9);
    for (i, row) in r.residuals.iter().enumerate() {
        let h: f64 = (0..p)
            .map(|a| {
                (0..p)
                    .map(|b| xs[i][a] * inv[(a, b)] * xs[i][b])
                    .sum::<f64>()
            })
            .sum();
        let t = resid[i] / (sigma * (1.0 - h).sqrt());
        let d = resid[i].powi(2) / (p as f64 * sigma2) * h / (1.0 - h).powi(2);
        assert!(
            (row.studentized - t).abs() < 1e-6 * t.abs().max(1.0),
            "t {i}: {} vs {t}",
            row.studentized
        );
        assert!(
            (row.cook - d).abs() < 1e-6 * d.max(1e-6),
            "Cook {i}: {} vs {d}",
            row.cook
        );
    }
}

#[test]
fn artifact_placements_are_fitted_and_do_not_bias_the_model() {
    let c = machine(CMM);
    let beta = truth(&c, 21);
    // Three plates placed with 50 µm / 20 µrad uncertainty: without nuisance parameters this
    // would swamp 0.2 µm noise.
    let data = simulated(&c, &beta, 900, 0.2e-6, 22, 3);
    let r = run(&c, &[data], &Options::default()).expect("fit");
    assert!((r.sigma / 0.2e-6 - 1.0).abs() < 0.1, "σ̂ {}", r.sigma);
    let se = standard_errors(&r);
    // Offsets of the model that a placement absorbs are not in this model (it has no constant
    // translation): every coefficient is estimable and unbiased.
    for (j, b) in beta.iter().enumerate() {
        assert!(
            ((r.solution.beta[j] - b) / se[j]).abs() < 4.5,
            "{}: {} vs {b}",
            c.machine.coefficients[j].name,
            r.solution.beta[j]
        );
    }
}

#[test]
fn a_rank_deficient_design_is_named_not_solved() {
    // X.tx's constant is a shift, which the plates' placements absorb.
    let src = CMM.replace(
        "X.tx = spline(X, knots 2)",
        "X.tx = spline(X, knots 2) + const",
    );
    let c = machine(&src);
    let beta = vec![1e-6; c.machine.coefficients.len()];
    let data = simulated(&c, &beta, 300, 0.2e-6, 3, 2);
    match run(&c, std::slice::from_ref(&data), &Options::default()) {
        Err(FitError::RankDeficient {
            rank,
            columns,
            diagnostics,
        }) => {
            assert_eq!(columns - rank, 1, "one invisible direction");
            let all: String = diagnostics
                .iter()
                .map(|d| d.message.clone())
                .collect::<Vec<_>>()
                .join("\n");
            assert!(
                all.contains("X.tx[") && all.contains("artifact `plate"),
                "{all}"
            );
            let labelled = diagnostics
                .iter()
                .flat_map(|d| &d.labels)
                .any(|l| &src[l.span.start..l.span.end] == "const");
            assert!(labelled, "points at the declaration");
        }
        other => panic!(
            "expected a rank-deficiency error, got {:?}",
            other.map(|r| r.solution.rank)
        ),
    }
    // With --min-norm the visible part is fitted and what was constrained is said.
    let r = run(
        &c,
        &[data],
        &Options {
            min_norm: true,
            ..Options::default()
        },
    )
    .expect("min-norm fit");
    assert_eq!(r.solution.rank, r.layout.columns() - 1);
    assert!(!r.constrained.is_empty());
    assert!(
        (r.sigma / 0.2e-6 - 1.0).abs() < 0.15,
        "the visible part still fits: σ̂ {}",
        r.sigma
    );
}

#[test]
fn svd_and_pivoted_qr_agree() {
    let c = machine(CMM);
    let beta = truth(&c, 31);
    let data = [simulated(&c, &beta, 300, 0.3e-6, 32, 0)];
    let a = run(&c, &data, &Options::default()).unwrap();
    let b = run(
        &c,
        &data,
        &Options {
            solver: Solver::Svd,
            ..Options::default()
        },
    )
    .unwrap();
    assert_eq!(a.solution.rank, b.solution.rank);
    for (x, y) in a.solution.beta.iter().zip(&b.solution.beta) {
        assert!((x - y).abs() < 1e-9 * x.abs().max(1e-6));
    }
}

#[test]
fn lengths_with_unknown_reference_lengths() {
    // The thesis' 2-D example (§4.4) with ball bars of unknown calibration: each artifact's
    // length error is a nuisance parameter; squareness and scales come back.
    let src = r#"
machine cmm2d {
    task measure
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 1000 mm
    tool chain {
        X moving
        Y moving
        tool probe
    }
    errors {
        X.rz = const
        X.tx = linear(X)
        Y.ty = linear(Y)
    }
}
"#;
    let c = machine(src);
    let beta: Vec<f64> = vec![8e-6, 5e-6, -3e-6];
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    // Bars of three lengths in many orientations, each bar one artifact.
    let n = 240;
    let mut l = kin_data::data::LengthData::default();
    l.rows.line = (1..=n).collect();
    l.rows.tool = vec![0; n];
    l.rows.inputs = vec![];
    for end in 0..2 {
        l.poses[end].axes = vec![Vec::new(), Vec::new()];
        l.poses[end].dir = vec![None, None];
    }
    let mut of_row = Vec::new();
    for r in 0..n {
        let bar = r % 3;
        let len = [0.3, 0.5, 0.7][bar];
        let a: f64 = rng.random_range(0.0..std::f64::consts::PI);
        let (cx, cy) = (rng.random_range(0.4..0.6), rng.random_range(0.4..0.6));
        let (dx, dy) = (len / 2.0 * a.cos(), len / 2.0 * a.sin());
        l.poses[0].axes[0].push(cx - dx);
        l.poses[0].axes[1].push(cy - dy);
        l.poses[1].axes[0].push(cx + dx);
        l.poses[1].axes[1].push(cy + dy);
        // The 300 mm bar is calibrated (no artifact label: its length is known); the other two
        // are not. Without one known length a uniform scale would be invisible (§4.2).
        of_row.push(if bar == 0 { None } else { Some(bar as u32 - 1) });
    }
    l.rows.artifact = Some(Groups {
        of_row,
        labels: vec!["bar500".into(), "bar700".into()],
    });
    l.dl = vec![0.0; n];
    let options = simulate::Options {
        noise: 0.1e-6,
        artifact_length: 2e-6,
        seed: 4,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&c.machine, &beta, &Observations::Lengths(l), &options).unwrap();
    let mut uncalibrated = obs.clone();
    let r = run(
        &c,
        &[DataSet {
            path: "bars.csv".into(),
            observations: obs,
        }],
        &Options::default(),
    )
    .expect("fit");
    assert_eq!(r.layout.columns(), 3 + 2);
    let se = standard_errors(&r);
    for j in 0..3 {
        assert!(
            ((r.solution.beta[j] - beta[j]) / se[j]).abs() < 4.0,
            "β[{j}] {} vs {}",
            r.solution.beta[j],
            beta[j]
        );
    }

    // Every bar of unknown length: the uniform scale is invisible, and the fit says so.
    if let Observations::Lengths(l) = &mut uncalibrated {
        if let Some(g) = &mut l.rows.artifact {
            g.of_row = (0..n).map(|r| Some((r % 3) as u32)).collect();
            g.labels = vec!["bar300".into(), "bar500".into(), "bar700".into()];
        }
    }
    match run(
        &c,
        &[DataSet {
            path: "bars.csv".into(),
            observations: uncalibrated,
        }],
        &Options::default(),
    ) {
        Err(FitError::RankDeficient {
            rank: 5,
            columns: 6,
            diagnostics,
        }) => {
            assert!(
                diagnostics[0].message.contains("length error"),
                "{}",
                diagnostics[0].message
            );
        }
        other => panic!(
            "expected the uniform scale to be invisible, got {:?}",
            other.map(|r| r.solution.rank)
        ),
    }
}

#[test]
fn stepwise_keeps_the_real_effects_and_drops_the_absent_ones() {
    let c = machine(CMM);
    // Only some coefficients are non-zero in the truth.
    let mut beta = vec![0.0; c.machine.coefficients.len()];
    let real = ["X.tx[0]", "X.rz[0]", "Y.ty[1]", "Z.tz[0]"];
    for (j, co) in c.machine.coefficients.iter().enumerate() {
        if real.contains(&co.name.as_str()) {
            beta[j] = 4.0 * co.unit.scale;
        }
    }
    let mut false_keeps = 0;
    for seed in 0..10 {
        let data = simulated(&c, &beta, 400, 0.3e-6, 500 + seed, 0);
        let options = Options {
            stepwise: Some(fit::Stepwise {
                remove: 1e-4,
                enter: Some(1e-5),
            }),
            ..Options::default()
        };
        let r = run(&c, &[data], &options).expect("fit");
        let sel = r.selection.as_ref().expect("selection");
        for (j, co) in c.machine.coefficients.iter().enumerate() {
            if real.contains(&co.name.as_str()) {
                assert!(
                    sel.kept[j],
                    "seed {seed}: {} is real and must stay",
                    co.name
                );
            } else if sel.kept[j] {
                false_keeps += 1;
            } else {
                assert_eq!(r.solution.beta[j], 0.0, "a removed coefficient is zero");
            }
        }
    }
    // 10 absent coefficients × 10 seeds at α = 1e-4: essentially none survive by chance.
    assert!(false_keeps <= 2, "{false_keeps} absent coefficients kept");
}

#[test]
fn time_constant_and_wavelength_are_estimated_with_honest_uncertainty() {
    let src = r#"
machine thermal {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 500 mm
    input T : temperature rise range 0 K .. 5 K
    tool chain {
        X moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = linear(X) + periodic(X, wavelength fit 20 mm, knots 2)
        t.tz = lag(T, tau fit 30 min) * const
    }
}
"#;
    let mut c = machine(src);
    // The truth: τ = 40 min, λ = 20.3 mm; the model starts from 30 min and 20 mm.
    let truth_nl = [40.0 * 60.0, 20.3e-3];
    let names: Vec<String> = c.machine.nonlinear.iter().map(|p| p.name.clone()).collect();
    assert_eq!(names, ["X.tx.wavelength", "t.tz.tau"]);
    let start: Vec<f64> = c.machine.nonlinear.iter().map(|p| p.value).collect();
    let beta = vec![3e-6, 0.5e-6, -0.3e-6, 2e-6 / 1.0];
    // A six-hour warm-up: the spindle-side temperature steps up by 4 K after one hour, readings
    // every two minutes at random X.
    let n = 180;
    let mut poses = sample_points(&c.machine, n, 9);
    poses.rows.time = Some((0..n).map(|r| 120.0 * r as f64).collect());
    poses.rows.inputs = vec![Some(
        (0..n).map(|r| if r < 30 { 0.0 } else { 4.0 }).collect(),
    )];
    let truth_machine = {
        let mut m = c.machine.clone();
        m.nonlinear[0].value = truth_nl[1];
        m.nonlinear[1].value = truth_nl[0];
        m
    };
    let options = simulate::Options {
        noise: 0.1e-6,
        seed: 10,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(
        &truth_machine,
        &beta,
        &Observations::Points(poses),
        &options,
    )
    .unwrap();
    c.machine.nonlinear[0].value = start[0];
    c.machine.nonlinear[1].value = start[1];
    let files = [DataSet {
        path: "warmup.csv".into(),
        observations: obs,
    }];
    let r = run(&c, &files, &Options::default()).expect("fit");
    let nl = r.nonlinear.as_ref().expect("non-linear fit");
    let (lambda, tau) = (nl.values[0], nl.values[1]);
    let (se_lambda, se_tau) = (nl.se[0].unwrap(), nl.se[1].unwrap());
    assert!(se_tau.is_finite() && se_lambda.is_finite());
    assert!(
        ((tau - truth_nl[0]) / se_tau).abs() < 4.0,
        "τ = {} ± {} min",
        tau / 60.0,
        se_tau / 60.0
    );
    assert!(
        ((lambda - truth_nl[1]) / se_lambda).abs() < 4.0,
        "λ = {} ± {} mm",
        lambda * 1e3,
        se_lambda * 1e3
    );
    assert!(
        (tau / 60.0 - 40.0).abs() < 4.0,
        "τ near 40 min: {}",
        tau / 60.0
    );
    assert!((r.sigma / 0.1e-6 - 1.0).abs() < 0.2, "σ̂ {}", r.sigma);
    // The lag moved far from its start: fitted. The periodic error here is weak (0.6 µm
    // against 0.1 µm noise): determined, and its verdict is what the data support.
    assert!(nl.verdicts[1].expect("fitted").significant());
    assert!(nl.verdicts[0].expect("fitted").determined);

    // Reference: plain Gauss–Newton over all parameters at the optimum. J = [X | ∂(Xβ̂)/∂θ]
    // by central differences; the θ block of σ̂²(JᵀJ)⁻¹ must equal the projected estimate.
    let mut at = c.clone();
    at.machine.nonlinear[0].value = lambda;
    at.machine.nonlinear[1].value = tau;
    let design = |mach: &kin_compiler::ir::Machine| -> (Vec<Vec<f64>>, Vec<f64>) {
        let mut it = Interpreter::new(mach).unwrap();
        let layout = fit::Layout::new(mach, &files);
        let states = fit::states(mach, &files).unwrap();
        let (mut xs, mut ys) = (Vec::new(), Vec::new());
        fit::for_each_row(&mut it, &files, &states, &layout, |_, x, y| {
            xs.push(x.to_vec());
            ys.push(y);
        })
        .unwrap();
        (xs, ys)
    };
    let (x0, _) = design(&at.machine);
    let bhat = &r.solution.beta;
    let pred = |xs: &Vec<Vec<f64>>| -> Vec<f64> {
        xs.iter()
            .map(|x| x.iter().zip(bhat).map(|(a, b)| a * b).sum())
            .collect()
    };
    let mut dcols = Vec::new();
    for k in 0..2 {
        let mut up = at.machine.clone();
        let mut dn = at.machine.clone();
        let h = 1e-5 * at.machine.nonlinear[k].value;
        up.nonlinear[k].value += h;
        dn.nonlinear[k].value -= h;
        let (pu, pd) = (pred(&design(&up).0), pred(&design(&dn).0));
        dcols.push(
            pu.iter()
                .zip(&pd)
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect::<Vec<f64>>(),
        );
    }
    let rows = x0.len();
    let pl = bhat.len();
    let jf = Mat::from_fn(rows, pl + 2, |i, j| {
        if j < pl {
            x0[i][j]
        } else {
            dcols[j - pl][i]
        }
    });
    let cov = (jf.transpose() * &jf).partial_piv_lu().inverse();
    let s2 = r.sigma.powi(2) * (rows - pl) as f64 / (rows - pl - 2) as f64;
    for (k, se) in [(0, se_lambda), (1, se_tau)] {
        let want = (s2 * cov[(pl + k, pl + k)]).sqrt();
        assert!(
            (se / want - 1.0).abs() < 0.02,
            "se of {}: projected {se} vs full {want}",
            names[k]
        );
    }
}

const THERMAL: &str = r#"
machine thermal {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 500 mm
    input T : temperature rise range 0 K .. 5 K
    tool chain {
        X moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = linear(X) + periodic(X, wavelength fit 20 mm, knots 2)
        t.tz = lag(T, tau fit 30 min) * const
    }
}
"#;

/// The thermal model fitted (from λ = 20 mm, τ = 30 min) to data simulated with `beta`, the
/// wavelength `lambda` and τ = 40 min.
fn thermal_fit(beta: &[f64], lambda: f64, seed: u64) -> (Compiled, [DataSet; 1], fit::FitResult) {
    let c = machine(THERMAL);
    let n = 180;
    let mut poses = sample_points(&c.machine, n, seed);
    poses.rows.time = Some((0..n).map(|r| 120.0 * r as f64).collect());
    poses.rows.inputs = vec![Some(
        (0..n).map(|r| if r < 30 { 0.0 } else { 4.0 }).collect(),
    )];
    let mut truth_machine = c.machine.clone();
    truth_machine.nonlinear[0].value = lambda;
    truth_machine.nonlinear[1].value = 40.0 * 60.0;
    let options = simulate::Options {
        noise: 0.1e-6,
        seed: seed + 1,
        ..simulate::Options::default()
    };
    let obs =
        simulate::simulate(&truth_machine, beta, &Observations::Points(poses), &options).unwrap();
    let files = [DataSet {
        path: "thermal.csv".into(),
        observations: obs,
    }];
    let r = run(&c, &files, &Options::default()).expect("fit");
    (c, files, r)
}

/// Data without any periodic error: the fitted wavelength shapes nothing but noise. It must be
/// flagged (undetermined or not significant), never reported as fitted, while the real time
/// constant stays fitted.
#[test]
fn a_wavelength_fitted_to_noise_is_flagged() {
    let (c, files, r) = thermal_fit(&[3e-6, 0.0, 0.0, 2e-6], 20e-3, 19);
    let nl = r.nonlinear.as_ref().expect("non-linear fit");
    let lambda = nl.verdicts[0].expect("fitted");
    assert!(
        !lambda.significant(),
        "λ = {} mm: {lambda:?}",
        nl.values[0] * 1e3
    );
    assert!(lambda.term_p > fit::nonlinear::ALPHA, "{lambda:?}");
    let tau = nl.verdicts[1].expect("fitted");
    assert!(
        tau.significant(),
        "τ = {} min: {tau:?}",
        nl.values[1] / 60.0
    );
    // The report says so in words.
    let report = fit::report::build(
        &c.machine,
        THERMAL,
        "interp",
        &files,
        &[],
        &r,
        &Options::default(),
    );
    assert_ne!(report.nonlinear[0].label, "fitted");
    assert!(report.nonlinear[0].note.is_some());
    assert_eq!(report.nonlinear[1].label, "fitted");
    assert!(report.nonlinear[1].note.is_none());
}

/// A clear periodic error at 20.3 mm, fitted from 20 mm: fitted, not flagged, and its interval
/// covers the truth.
#[test]
fn a_real_wavelength_is_fitted_and_covers_the_truth() {
    let (_, _, r) = thermal_fit(&[3e-6, 2e-6, -1.5e-6, 2e-6], 20.3e-3, 29);
    let nl = r.nonlinear.as_ref().expect("non-linear fit");
    let v = nl.verdicts[0].expect("fitted");
    assert!(v.significant(), "{v:?}");
    let (lambda, se) = (nl.values[0], nl.se[0].expect("fitted"));
    assert!(
        ((lambda - 20.3e-3) / se).abs() < 3.0,
        "λ = {} ± {} mm",
        lambda * 1e3,
        se * 1e3
    );
}

#[test]
fn prediction_variance_at_a_training_pose_is_sigma_squared_times_its_leverage() {
    // Eq. 4.12 at the state of a fitted row equals σ̂²·h for that row (no nuisance here).
    let c = machine(CMM);
    let beta = truth(&c, 41);
    let data = simulated(&c, &beta, 200, 0.3e-6, 42, 0);
    let files = [data];
    let r = run(&c, &files, &Options::default()).unwrap();
    let rep = kin_estimate::fit::report::build(
        &c.machine,
        CMM,
        "interp",
        &files,
        &[],
        &r,
        &Options::default(),
    );
    let states = fit::states(&c.machine, &files).unwrap();
    let fit::FileStates::Points(s) = &states[0] else {
        panic!()
    };
    let mut it = Interpreter::new(&c.machine).unwrap();
    let Observations::Points(p) = &files[0].observations else {
        panic!()
    };
    let variances = PredictionCovariance::new(&c.machine, &rep)
        .unwrap()
        .point_variances(&c.machine, &mut it, &mut s.clone(), &p.rows)
        .unwrap();
    for row in r.residuals.iter().take(30) {
        let k = (row.meta.line - 1) as usize;
        let var = variances[k];
        let want = r.sigma.powi(2) * row.leverage;
        let got = var[row.meta.component as usize];
        assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
    }
}

#[test]
fn a_fit_report_with_undetermined_values_reads_back() {
    let c = machine(CMM);
    let beta = truth(&c, 51);
    let files = [simulated(&c, &beta, 100, 0.3e-6, 52, 0)];
    let r = run(&c, &files, &Options::default()).unwrap();
    let mut rep = kin_estimate::fit::report::build(
        &c.machine,
        CMM,
        "interp",
        &files,
        &[],
        &r,
        &Options::default(),
    );
    rep.coefficients[0].se = f64::INFINITY;
    rep.r2 = f64::NAN;
    rep.covariance[0] = f64::NAN;
    if let Some(r) = rep.residuals.first_mut() {
        r.cook = f64::NAN;
    }
    let json = serde_json::to_string(&rep).unwrap();
    let back: kin_estimate::fit::report::FitReport =
        serde_json::from_str(&json).expect("reads back");
    assert!(back.coefficients[0].se.is_nan() && back.r2.is_nan());
    assert!(back.covariance[0].is_nan());
    assert_eq!(back.covariance[1..], rep.covariance[1..]);
    assert!(back.residuals.first().is_some_and(|r| r.cook.is_nan()));
    assert_eq!(back.coefficients[1].value, rep.coefficients[1].value);
}

/// Values that no reader lets through (an axis at 1e157 m, an error of 1e305 m), handed to the
/// fit directly: it stops with an error naming the row, or the overflow, instead of panicking
/// in the solver (once `fit/solve.rs`) or returning ±inf coefficients.
#[test]
fn absurd_values_stop_the_fit_instead_of_overflowing_it() {
    let c = machine(CMM);
    let beta = truth(&c, 3);
    for (axis_value, observed_value) in [(Some(1e157), None), (None, Some(1e305))] {
        let mut set = simulated(&c, &beta, 60, 1e-7, 5, 0);
        let Observations::Points(p) = &mut set.observations else {
            panic!("points");
        };
        if let Some(v) = axis_value {
            p.pose.axes[0][7] = v;
        }
        if let Some(v) = observed_value {
            p.observed[0].as_mut().expect("ex")[7] = v;
        }
        match run(&c, &[set], &Options::default()) {
            Err(FitError::Design(fit::DesignError::NotFinite { line, .. })) => {
                assert_eq!(line, 8, "the row's line")
            }
            Err(FitError::Overflow) => {}
            Err(e) => panic!("unexpected error: {e}"),
            Ok(r) => panic!("fitted absurd data: σ̂ = {}", r.sigma),
        }
    }
}

/// Counts the passes over the data (each begins by setting the non-linear values).
struct Passes<'a> {
    inner: Interpreter<'a>,
    passes: usize,
}

impl kin_model::engine::Evaluator for Passes<'_> {
    fn machine(&self) -> &kin_compiler::ir::Machine {
        self.inner.machine()
    }
    fn set_nonlinear(&mut self, values: &[f64]) -> Result<(), kin_model::interp::EvalError> {
        self.passes += 1;
        self.inner.set_nonlinear(values)
    }
    fn error(
        &mut self,
        state: &kin_model::interp::State,
        beta: &[f64],
    ) -> Result<[f64; 6], kin_model::interp::EvalError> {
        self.inner.error(state, beta)
    }
    fn error_and_jacobian(
        &mut self,
        state: &kin_model::interp::State,
        beta: &[f64],
        err: &mut [f64; 6],
        jac: &mut [f64],
    ) -> Result<(), kin_model::interp::EvalError> {
        self.inner.error_and_jacobian(state, beta, err, jac)
    }
    fn length_and_row(
        &mut self,
        s1: &kin_model::interp::State,
        s2: &kin_model::interp::State,
        beta: &[f64],
        row: &mut [f64],
    ) -> Result<f64, kin_model::interp::EvalError> {
        self.inner.length_and_row(s1, s2, beta, row)
    }
}

/// A design the data cannot solve is refused at the start values of the fitted wavelength,
/// located as without it, after two passes over the data instead of the optimisation's dozens
/// (moving λ changes its columns' values, not which combinations are invisible).
#[test]
fn a_deficient_design_with_a_fitted_wavelength_is_refused_before_optimising() {
    let src = CMM.replace(
        "X.tx = spline(X, knots 2)",
        "X.tx = spline(X, knots 2) + const + periodic(X, wavelength fit 20 mm, knots 2)",
    );
    let c = machine(&src);
    let beta = vec![1e-6; c.machine.coefficients.len()];
    let data = simulated(&c, &beta, 300, 0.2e-6, 3, 2);
    let mut engine = Passes {
        inner: Interpreter::new(&c.machine).expect("interpreter"),
        passes: 0,
    };
    let result = fit::fit(
        &c,
        &mut engine,
        std::slice::from_ref(&data),
        &[],
        &Options::default(),
        &mut |_, _| {},
    );
    match result {
        Err(FitError::RankDeficient {
            rank,
            columns,
            diagnostics,
        }) => {
            assert_eq!(columns - rank, 1, "one invisible direction");
            assert!(diagnostics.iter().any(|d| d.message.contains("X.tx[")));
        }
        other => panic!(
            "expected a rank-deficiency error, got {:?}",
            other.map(|r| r.solution.rank)
        ),
    }
    assert!(
        engine.passes <= 2,
        "{} passes before refusing",
        engine.passes
    );

    // With --min-norm the wavelength is still fitted (the optimisation runs).
    let mut engine = Passes {
        inner: Interpreter::new(&c.machine).expect("interpreter"),
        passes: 0,
    };
    let options = Options {
        min_norm: true,
        ..Options::default()
    };
    fit::fit(&c, &mut engine, &[data], &[], &options, &mut |_, _| {}).expect("min-norm fit");
    assert!(engine.passes > 4, "{} passes", engine.passes);
}
