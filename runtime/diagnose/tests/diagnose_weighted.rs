//! A diagnosis of pose data (positions in µm and rotations in µrad) weighted by the stated
//! noise of each kind, against the same diagnosis with every row weighed alike.
//!
//! The truth hides a small pitch of the Y carriage (≈ 1 µrad along Y). The rotation rows see it
//! directly but under 20 µrad of noise; the position rows see it through the Abbe arm below the
//! carriage (≈ 0.3 µm at 0.3 µm of noise). Weighed alike, the rotation rows' scatter swamps
//! every test and the tilt is not found; weighed by their stated σ, the position rows carry it.

use kin_compiler::{compile, Compiled};
use kin_data::data::Observations;
use kin_diagnose::{self as diagnose, Diagnosis, Family, Settings};
use kin_estimate::fit::{self, DataSet, FitResult, Noise, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;
use rand::{Rng, SeedableRng};

const BASE: &str = r#"
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
    errors {
        X.tx = spline(X, knots 2)
        X.rz = const
        Y.ty = linear(Y)
        Z.tz = linear(Z)
    }
}
"#;

const HIDDEN: &str = "Y.rx += spline(Y, knots 2)";
/// ≈ 1.2 µrad of pitch along Y.
const VALUES: [f64; 4] = [4.0, -5.0, 7.0, -4.0];
const NOISE: f64 = 0.3e-6;
const NOISE_TILT: f64 = 20e-6;

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{src}\n{:#?}", out.diagnostics))
}

fn with_line(src: &str, line: &str) -> String {
    let at = src.rfind("    }\n}").expect("errors block");
    format!("{}        {line}\n{}", &src[..at], &src[at..])
}

/// Pose data (all six components) of the truth at `n` poses.
fn simulated(n: usize, seed: u64) -> [DataSet; 1] {
    let truth = compiled(&with_line(BASE, HIDDEN));
    let base = compiled(BASE);
    let m = &truth.machine;
    let hidden_from = base.machine.coefficients.len();
    assert_eq!(m.coefficients.len(), hidden_from + VALUES.len());
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let beta: Vec<f64> = m
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, c)| {
            let v = match j.checked_sub(hidden_from) {
                Some(k) => VALUES[k],
                None => rng.random_range(-3.0..3.0),
            };
            v * c.unit.scale
        })
        .collect();
    let obs = simulate::simulate(
        m,
        &beta,
        &Observations::Points(sample_points(m, n, seed)),
        &simulate::Options {
            observe: [true; 6],
            noise: NOISE,
            noise_tilt: NOISE_TILT,
            seed: seed + 1,
            ..simulate::Options::default()
        },
    )
    .expect("simulate");
    [DataSet {
        path: "poses.csv".into(),
        observations: obs,
    }]
}

fn options(weighted: bool) -> Options {
    Options {
        noise: weighted.then_some(Noise {
            position: Some(NOISE),
            rotation: Some(NOISE_TILT),
        }),
        ..Options::default()
    }
}

fn settings() -> Settings {
    Settings {
        noise: Some(NOISE),
        noise_tilt: Some(NOISE_TILT),
        ..Settings::default()
    }
}

fn fitted(src: &str, files: &[DataSet], o: &Options) -> (Compiled, FitResult) {
    let c = compiled(src);
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let r = fit::fit(&c, &mut it, files, &[], o, &mut |_, _| {}).expect("fit");
    (c, r)
}

fn diagnosed(src: &str, files: &[DataSet], weighted: bool) -> Diagnosis {
    let o = options(weighted);
    let (c, r) = fitted(src, files, &o);
    diagnose::diagnose(&c, src, files, &r, &o, &settings()).expect("diagnose")
}

fn describe(d: &Diagnosis) -> String {
    d.findings
        .iter()
        .take(4)
        .map(|f| {
            format!(
                "\n    {} [{:?}] F {:.1} p_adj {:.2e} sig {} rms after {:.3}",
                f.candidate.text, f.candidate.family, f.f, f.p_adjusted, f.significant, f.rms_after
            )
        })
        .collect()
}

#[test]
fn a_tilt_seen_through_positions_is_found_only_with_each_kind_weighed_by_its_noise() {
    for seed in [1u64, 2] {
        let files = simulated(400, seed);

        // Weighed alike (the diagnosis before it weighted its fits): no candidate on Y.rx is
        // significant, and the verdict blames the library or the stated noise.
        let alike = diagnosed(BASE, &files, false);
        assert!(!alike.weighted);
        assert!(
            !alike
                .findings
                .iter()
                .any(|f| f.significant && f.candidate.target == "Y.rx"),
            "seed {seed}: weighed alike, the tilt was found:{}",
            describe(&alike)
        );
        // …while the residuals exceed the stated noise: "no effect of the library accounts
        // for the rest", which is wrong.
        let chi2 = alike
            .noise
            .chi2
            .as_ref()
            .expect("χ² against the stated noise");
        assert!(!chi2.consistent, "seed {seed}: {chi2:?}");

        // Weighed by the stated noise: the tilt ranks first, on its carriage.
        let d = diagnosed(BASE, &files, true);
        assert!(d.weighted);
        let top = d.findings.first().expect("a finding");
        assert!(
            top.significant
                && top.candidate.target == "Y.rx"
                && matches!(top.candidate.family, Family::AbbeAngular | Family::Constant),
            "seed {seed}: {}",
            describe(&d)
        );
        // σ̂ and the RMS after are multiples of the stated noise: the base is above it (a
        // small excess, but over 2400 rows).
        assert!(d.sigma > 1.02, "seed {seed}: σ̂/σ before {}", d.sigma);
        assert!(
            (0.85..1.15).contains(&top.rms_after),
            "seed {seed}: RMS after {} σ",
            top.rms_after
        );

        // The round: the line added, the weighted refit is at the stated noise, and the
        // diagnosis of it finds nothing more and says so.
        let src = with_line(BASE, &top.candidate.text);
        let (_, refit) = fitted(&src, &files, &options(true));
        let ratio = refit.sigma / 1e-6;
        assert!(
            (0.9..1.1).contains(&ratio),
            "seed {seed}: σ̂/σ after {ratio}"
        );
        let after = diagnosed(&src, &files, true);
        let chi2 = after.noise.chi2.as_ref().expect("χ²");
        assert!(
            chi2.consistent && (0.9..1.1).contains(&chi2.ratio),
            "seed {seed}: {chi2:?}"
        );
        assert!(
            after.findings.iter().all(|f| !f.significant),
            "seed {seed}: after the round:{}",
            describe(&after)
        );
    }
}
