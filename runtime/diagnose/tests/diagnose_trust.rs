//! Diagnoses a metrologist can trust, on simulated data with a known truth: candidates the
//! sampling can resolve, the simplest explanation first, equivalent readings as one finding in
//! a stable order, and a verdict against a stated noise.

use kin_compiler::{compile, Compiled};
use kin_data::data::{Observations, PointData};
use kin_diagnose::{self as diagnose, Diagnosis, Family, Settings};
use kin_estimate::fit::{self, DataSet, FitResult, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;

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
    errors {
        X.tx = spline(X, knots 2)
        X.rz = const
        Y.ty = linear(Y) + backlash(Y)
        Z.tz = linear(Z)
    }
}
"#;

/// A mill whose rotary table C turns only ±30° (a trunnion, a swivel head).
const SWIVEL: &str = r#"
machine mill4 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis C revolute about z range -30 deg .. 30 deg
    workpiece chain {
        Y fixed at (0, 200, 0) mm
        X fixed at (250, 0, 120) mm
        C fixed at (0, 0, 60) mm
        workpiece at (0, 0, 0) mm
    }
    tool chain {
        Z moving at (0, 0, 700) mm
        tool spindle at (0, 0, -150) mm
        tool probe at (0, 0, -130) mm
    }
    errors {
        X.tx = linear(X)
        Y.ty = linear(Y)
        Z.tz = linear(Z)
        C.tx = const
        C.ty = const
    }
}
"#;

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{src}\n{:#?}", out.diagnostics))
}

/// `src` with `line` added at the end of its errors block.
fn with_line(src: &str, line: &str) -> String {
    let at = src.rfind("    }\n}").expect("errors block");
    format!("{}        {line}\n{}", &src[..at], &src[at..])
}

/// Truth coefficients: every coefficient at `base` display units, the named ones as given.
fn beta(truth: &Compiled, values: &[(&str, f64)]) -> Vec<f64> {
    truth
        .machine
        .coefficients
        .iter()
        .map(|c| {
            let v = values
                .iter()
                .find(|(n, _)| *n == c.name)
                .map(|(_, v)| *v)
                .unwrap_or(1.0);
            v * c.unit.scale
        })
        .collect()
}

/// Simulates `truth` at `poses` with `noise` (m), fits `base`.
fn fitted(
    base: &str,
    truth: &str,
    values: &[(&str, f64)],
    poses: PointData,
    noise: f64,
) -> (Compiled, Vec<DataSet>, FitResult) {
    let t = compiled(truth);
    let obs = simulate::simulate(
        &t.machine,
        &beta(&t, values),
        &Observations::Points(poses),
        &simulate::Options {
            noise,
            seed: 7,
            ..simulate::Options::default()
        },
    )
    .expect("simulate");
    let files = vec![DataSet {
        path: "data.csv".into(),
        observations: obs,
    }];
    let c = compiled(base);
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let r = fit::fit(
        &c,
        &mut it,
        &files,
        &[],
        &Options::default(),
        &mut |_, _| {},
    )
    .expect("fit");
    (c, files, r)
}

fn diagnosed(c: &Compiled, src: &str, files: &[DataSet], r: &FitResult, s: &Settings) -> Diagnosis {
    diagnose::diagnose(c, src, files, r, &Options::default(), s).expect("diagnose")
}

fn listing(d: &Diagnosis) -> Vec<String> {
    d.findings
        .iter()
        .take(6)
        .map(|f| {
            format!(
                "{} [{:?}] sig {} bic {:.1} alts {:?}",
                f.candidate.text,
                f.candidate.family,
                f.significant,
                f.bic,
                f.alternatives.iter().map(|a| &a.text).collect::<Vec<_>>()
            )
        })
        .collect()
}

#[test]
fn a_limited_range_revolute_axis_gets_no_harmonics() {
    // A radial error motion at 2 per revolution over ±30°: a smooth curve there, which the
    // location constants and the other terms must absorb, not a harmonic to propose.
    let truth = with_line(SWIVEL, "C.tx += fourier(C, harmonics 2)");
    let m = compiled(&truth).machine;
    let poses = sample_points(&m, 400, 3);
    let (c, files, r) = fitted(
        SWIVEL,
        &truth,
        &[("C.tx[1]", 1.5), ("C.tx[2]", -1.0)],
        poses,
        0.2e-6,
    );
    let d = diagnosed(&c, SWIVEL, &files, &r, &Settings::default());
    assert!(!d.findings.is_empty());
    let harmonics: Vec<String> = d
        .findings
        .iter()
        .flat_map(|f| std::iter::once(&f.candidate).chain(&f.alternatives))
        .filter(|c| c.family == Family::RevoluteHarmonics || c.text.contains("fourier(C"))
        .map(|c| c.text.clone())
        .collect();
    assert!(harmonics.is_empty(), "{harmonics:?}");
}

#[test]
fn an_aliased_wavelength_is_not_proposed() {
    // X visits 5 positions 10 mm apart; the truth has a 4.5 mm pitch, which these positions
    // cannot resolve (nothing shorter than 20 mm aliases onto a true period).
    // X.tx linear in X: the spline's knots would be outside the 40 mm the data cover.
    let base = CMM.replace("X.tx = spline(X, knots 2)", "X.tx = linear(X)");
    let truth = with_line(&base, "X.tx += periodic(X, wavelength 4.5 mm, knots 2)");
    let m = compiled(&truth).machine;
    let mut poses = sample_points(&m, 600, 5);
    for (r, x) in poses.pose.axes[0].iter_mut().enumerate() {
        *x = 0.100 + 0.010 * (r % 5) as f64;
    }
    let (c, files, r) = fitted(
        &base,
        &truth,
        &[("X.tx[1]", 2.0), ("X.tx[2]", -1.5)],
        poses,
        0.2e-6,
    );
    let d = diagnosed(&c, &base, &files, &r, &Settings::default());
    let periodic: Vec<String> = d
        .findings
        .iter()
        .flat_map(|f| std::iter::once(&f.candidate).chain(&f.alternatives))
        .filter(|c| c.family == Family::Periodic)
        .map(|c| c.text.clone())
        .collect();
    // Nothing between 20 mm (Nyquist) and 40 mm / 3 (three periods in the covered span).
    assert!(periodic.is_empty(), "{periodic:?}");
    // The spectrum along X does not scan below the sampling's Nyquist wavelength either.
    for sp in d.spectra.iter().filter(|s| s.variable == "X") {
        let shortest = sp.wavelengths.iter().copied().fold(f64::INFINITY, f64::min);
        assert!(shortest >= 20.0 - 1e-9, "{shortest}");
    }
}

#[test]
fn a_missing_location_constant_is_proposed_as_the_constant() {
    // The C axis sits 3 µm off along y; the model has no C.ty: a constant, not a periodic term
    // or a coupling that merely adds columns.
    let base = SWIVEL
        .replace("range -30 deg .. 30 deg", "continuous")
        .replace("        C.ty = const\n", "");
    let truth = with_line(&base, "C.ty += const");
    let m = compiled(&truth).machine;
    let poses = sample_points(&m, 500, 11);
    let (c, files, r) = fitted(&base, &truth, &[("C.ty[0]", 3.0)], poses, 0.2e-6);
    let d = diagnosed(&c, &base, &files, &r, &Settings::default());
    let top = d.findings.first().expect("findings");
    assert!(top.significant, "{:#?}", listing(&d));
    assert_eq!(top.candidate.family, Family::Constant, "{:#?}", listing(&d));
    assert_eq!(top.candidate.text, "C.ty += const", "{:#?}", listing(&d));
    // And no linear coupling with the continuous C is on offer.
    assert!(
        !d.findings
            .iter()
            .any(|f| f.candidate.text.contains("linear(C)")),
        "{:#?}",
        listing(&d)
    );
}

#[test]
fn equivalent_candidates_are_one_finding_in_a_stable_order() {
    // A constant rotation of the Y carriage about z: the Z ram rides on Y and moves along z,
    // so the same rotation of the Z frame moves the probe identically; the data cannot decide
    // between the two lines.
    let truth = with_line(CMM, "Y.rz += const");
    let m = compiled(&truth).machine;
    let poses = sample_points(&m, 400, 9);
    let (c, files, r) = fitted(CMM, &truth, &[("Y.rz[0]", 5.0)], poses, 0.2e-6);
    let first = diagnosed(&c, CMM, &files, &r, &Settings::default());
    let top = first.findings.first().expect("findings");
    assert!(top.significant, "{:#?}", listing(&first));
    let mut readings: Vec<&str> = std::iter::once(&top.candidate)
        .chain(&top.alternatives)
        .map(|c| c.text.as_str())
        .collect();
    readings.sort_unstable();
    assert!(
        readings.contains(&"Y.rz += const") && readings.contains(&"Z.rz += const"),
        "{:#?}",
        listing(&first)
    );
    assert!(top.separation.is_some());
    // Canonical: the first by family simplicity, then text.
    assert_eq!(top.candidate.text, "Y.rz += const");
    // No finding repeats a reading of another.
    let all: Vec<&str> = first
        .findings
        .iter()
        .flat_map(|f| std::iter::once(&f.candidate).chain(&f.alternatives))
        .map(|c| c.text.as_str())
        .collect();
    let mut unique = all.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(unique.len(), all.len());
    let order = |d: &Diagnosis| -> Vec<(String, Vec<String>)> {
        d.findings
            .iter()
            .map(|f| {
                (
                    f.candidate.text.clone(),
                    f.alternatives.iter().map(|a| a.text.clone()).collect(),
                )
            })
            .collect()
    };
    let reference = order(&first);
    for run in 1..20 {
        let again = diagnosed(&c, CMM, &files, &r, &Settings::default());
        assert_eq!(order(&again), reference, "run {run} differs");
    }
}

#[test]
fn a_stated_noise_makes_down_to_the_noise_impossible_when_sigma_is_larger() {
    // A complete model, data at 0.54 µm noise, the instrument stated at 0.2 µm: σ̂ ≈ 2.7σ.
    let m = compiled(CMM).machine;
    let poses = sample_points(&m, 500, 13);
    let (c, files, r) = fitted(CMM, CMM, &[], poses, 0.54e-6);
    let stated = Settings {
        noise: Some(0.2e-6),
        ..Settings::default()
    };
    let d = diagnosed(&c, CMM, &files, &r, &stated);
    let chi2 = d.noise.chi2.as_ref().expect("χ² against the stated noise");
    assert!((2.4..3.0).contains(&chi2.ratio), "{chi2:?}");
    assert!(!chi2.consistent && chi2.p < 1e-6, "{chi2:?}");
    // Every component is raised throughout: the regions say so against the stated σ.
    assert!(
        d.regions
            .iter()
            .any(|r| r.text.contains("stated noise") && r.text.contains("throughout")),
        "{:?}",
        d.regions.iter().map(|r| &r.text).collect::<Vec<_>>()
    );
    // Stated right, the same data are consistent with it and nothing is flagged.
    let right = Settings {
        noise: Some(0.54e-6),
        ..Settings::default()
    };
    let d = diagnosed(&c, CMM, &files, &r, &right);
    let chi2 = d.noise.chi2.as_ref().expect("χ²");
    assert!(chi2.consistent, "{chi2:?}");
    assert!(
        d.regions.is_empty(),
        "{:?}",
        d.regions.iter().map(|r| &r.text).collect::<Vec<_>>()
    );
    // Without a statement there is no absolute test.
    let d = diagnosed(&c, CMM, &files, &r, &Settings::default());
    assert!(d.noise.chi2.is_none());
}

#[test]
fn repeated_poses_give_a_lack_of_fit_test() {
    // Every pose measured three times. Complete model: no lack of fit; a hidden backlash of X
    // (the model lacks it) is a lack of fit the pure error shows without any stated noise.
    let m = compiled(CMM).machine;
    let once = sample_points(&m, 200, 17);
    let thrice = |p: &PointData| -> PointData {
        let mut out = p.clone();
        let idx: Vec<usize> = (0..3 * p.pose.axes[0].len()).map(|r| r / 3).collect();
        let pick = |v: &Vec<f64>| idx.iter().map(|&r| v[r]).collect::<Vec<f64>>();
        out.pose.axes = p.pose.axes.iter().map(pick).collect();
        out.pose.dir = p.pose.dir.iter().map(|d| d.as_ref().map(pick)).collect();
        out.rows.line = (1..=idx.len()).collect();
        out.rows.tool = idx.iter().map(|&r| p.rows.tool[r]).collect();
        out.rows.inputs = p.rows.inputs.iter().map(|c| c.as_ref().map(pick)).collect();
        out
    };
    let (c, files, r) = fitted(CMM, CMM, &[], thrice(&once), 0.2e-6);
    let d = diagnosed(&c, CMM, &files, &r, &Settings::default());
    let lof = d.noise.lack_of_fit.as_ref().expect("replicates found");
    assert_eq!(lof.groups, 600, "{lof:?}");
    assert!(lof.consistent, "{lof:?}");
    assert!((0.15..0.25).contains(&lof.sigma_pure), "{lof:?}");

    let truth = with_line(CMM, "X.tx += backlash(X)");
    let mut poses = thrice(&once);
    poses.pose.dir[0] = Some(
        (0..poses.pose.axes[0].len())
            .map(|r| if (r / 3) % 2 == 0 { 1.0 } else { -1.0 })
            .collect(),
    );
    let (c, files, r) = fitted(CMM, &truth, &[("X.tx[4]", 1.0)], poses, 0.2e-6);
    let d = diagnosed(&c, CMM, &files, &r, &Settings::default());
    let lof = d.noise.lack_of_fit.as_ref().expect("replicates found");
    assert!(!lof.consistent, "{lof:?}");
}

#[test]
fn a_gross_outlier_is_named_not_a_failing_region() {
    // A complete model; one reading 25 µm off (a probe hit on dirt): an outlier by its file and
    // line, not a region of the workspace where the model fails.
    let c = compiled(CMM);
    let poses = sample_points(&c.machine, 500, 19);
    let mut obs = simulate::simulate(
        &c.machine,
        &beta(&c, &[]),
        &Observations::Points(poses),
        &simulate::Options {
            noise: 0.2e-6,
            seed: 23,
            ..simulate::Options::default()
        },
    )
    .expect("simulate");
    let Observations::Points(p) = &mut obs else {
        panic!("points")
    };
    let ez = p.observed[2].as_mut().expect("ez");
    ez[123] += 25e-6;
    let line = p.rows.line[123];
    let files = vec![DataSet {
        path: "data.csv".into(),
        observations: obs,
    }];
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    let r = fit::fit(
        &c,
        &mut it,
        &files,
        &[],
        &Options::default(),
        &mut |_, _| {},
    )
    .expect("fit");
    let stated = Settings {
        noise: Some(0.2e-6),
        ..Settings::default()
    };
    let d = diagnosed(&c, CMM, &files, &r, &stated);
    assert!(
        d.outliers
            .iter()
            .any(|o| o.line == line && o.component == "ez" && o.residual > 20.0),
        "{:?}",
        d.outliers
    );
    assert!(
        d.regions.is_empty(),
        "{:?}",
        d.regions.iter().map(|r| &r.text).collect::<Vec<_>>()
    );
    // Left out of the χ² too: the rest is at the stated noise.
    assert!(
        d.noise.chi2.as_ref().is_some_and(|c| c.consistent),
        "{:?}",
        d.noise
    );
}
