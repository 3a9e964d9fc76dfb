//! Over many simulated calibrations, the stated 95 % intervals of the coefficients and of the
//! model's predictions contain the truth about 95 % of the time — here for a fit with
//! artifacts (ball bars of unknown length, thesis §4.2) on the thesis' 2-D CMM (§4.4).

use kin_compiler::{compile, Compiled};
use kin_data::data::{Groups, LengthData, Observations, Rows};
use kin_estimate::fit::{self, DataSet, Options};
use kin_estimate::simulate;
use kin_estimate::uncertainty::PredictionCovariance;
use kin_model::interp::Interpreter;
use kin_model::states::States;
use rand::{Rng, SeedableRng};
use statrs::distribution::{ContinuousCDF, StudentsT};

const CMM: &str = r#"
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

/// `n` bars at random orientations: a calibrated 300 mm bar and two of unknown length.
fn bars(n: usize, seed: u64) -> LengthData {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut l = LengthData::default();
    l.rows.line = (1..=n).collect();
    l.rows.tool = vec![0; n];
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
        of_row.push(if bar == 0 { None } else { Some(bar as u32 - 1) });
    }
    l.rows.artifact = Some(Groups {
        of_row,
        labels: vec!["bar500".into(), "bar700".into()],
    });
    l.dl = vec![0.0; n];
    l
}

/// The binomial band: 95 % of `total` trials, ± 3.5 standard deviations.
fn band(total: usize) -> (f64, f64) {
    let sd = (0.95 * 0.05 / total as f64).sqrt();
    (0.95 - 3.5 * sd, 0.95 + 3.5 * sd)
}

#[test]
fn intervals_of_coefficients_and_predictions_cover_the_truth_at_95_percent() {
    let c: Compiled = compile(CMM).compiled.expect("valid");
    let m = &c.machine;
    let beta = vec![8e-6, 5e-6, -3e-6];
    let rows = 24;
    // Prediction poses: three points of the workspace, both position components.
    let mut poses = States::sample(m, 3, 77);
    let mut it = Interpreter::new(m).expect("interpreter");
    let truth: Vec<[f64; 6]> = (0..poses.len())
        .map(|k| {
            let e = it.error(&poses.get(k), &beta).expect("error");
            let mut out = [0.0; 6];
            out.iter_mut().zip(e.iter()).for_each(|(o, v)| *o = *v);
            out
        })
        .collect();
    let (mut coef_in, mut coef_n, mut pred_in, mut pred_n) = (0, 0, 0, 0);
    for seed in 0..200u64 {
        let options = simulate::Options {
            noise: 0.1e-6,
            artifact_length: 2e-6,
            seed: 10_000 + seed,
            ..simulate::Options::default()
        };
        let obs = simulate::simulate(m, &beta, &Observations::Lengths(bars(rows, seed)), &options)
            .expect("simulated");
        let files = [DataSet {
            path: "bars.csv".into(),
            observations: obs,
        }];
        let r = fit::fit(
            &c,
            &mut it,
            &files,
            &[],
            &Options::default(),
            &mut |_, _| {},
        )
        .expect("fit");
        let dof = (rows - r.layout.columns()) as f64;
        let t = StudentsT::new(0.0, 1.0, dof).expect("t").inverse_cdf(0.975);
        let rep = fit::report::build(m, CMM, "interp", &files, &[], &r, &Options::default());
        for (j, b) in beta.iter().enumerate() {
            let e = &rep.coefficients[j];
            let (value, se) = (
                e.value * m.coefficients[j].unit.scale,
                e.se * m.coefficients[j].unit.scale,
            );
            coef_in += usize::from((value - b).abs() <= t * se);
            coef_n += 1;
        }
        // The sampled poses have no rows of their own; the model has no lags to integrate.
        let var_all = PredictionCovariance::new(m, &rep)
            .expect("covariance")
            .point_variances(m, &mut it, &mut poses, &Rows::default())
            .expect("variance");
        for (k, want) in truth.iter().enumerate() {
            let state = poses.get(k);
            let got = it
                .error(&state, &r.solution.beta[..beta.len()])
                .expect("prediction");
            let var = var_all[k];
            for comp in 0..2 {
                pred_in += usize::from((got[comp] - want[comp]).abs() <= t * var[comp].sqrt());
                pred_n += 1;
            }
        }
    }
    eprintln!("coverage: coefficients {coef_in}/{coef_n}, predictions {pred_in}/{pred_n}");
    let (lo, hi) = band(coef_n);
    let rate = coef_in as f64 / coef_n as f64;
    assert!(
        (lo..=hi).contains(&rate),
        "coefficients: {rate} outside [{lo}, {hi}]"
    );
    // The six predictions of one fit are correlated: the band is wider than binomial; the
    // rate is still expected at 95 %.
    let (lo, hi) = band(pred_n / 6);
    let rate = pred_in as f64 / pred_n as f64;
    assert!(
        (lo..=hi).contains(&rate),
        "predictions: {rate} outside [{lo}, {hi}]"
    );
}
