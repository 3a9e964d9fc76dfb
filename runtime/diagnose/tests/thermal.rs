//! Heat sources, lag cascades and declared initial states, fitted back from simulated data.

use kin_compiler::{compile, Compiled};
use kin_data::data::Observations;
use kin_estimate::fit::{self, DataSet, FitError, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;

fn machine(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

fn run(c: &Compiled, files: &[DataSet], options: &Options) -> Result<fit::FitResult, FitError> {
    let mut it = Interpreter::new(&c.machine).expect("interpreter");
    fit::fit(c, &mut it, files, &[], options, &mut |_, _| {})
}

const RPM: f64 = std::f64::consts::TAU / 60.0;

/// An eight-hour day sampled every two minutes: the room drifts by a sine of ±1.5 K over the
/// day, the spindle is off, runs at 6000 rpm from the first hour, at 3000 rpm from the fourth,
/// and stops for the last hour and a half.
fn day(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let time: Vec<f64> = (0..n).map(|r| 120.0 * r as f64).collect();
    let room = time
        .iter()
        .map(|t| 1.5 * (std::f64::consts::TAU * t / 28_800.0).sin())
        .collect();
    let speed = time
        .iter()
        .map(|&t| {
            let h = t / 3600.0;
            RPM * if h < 1.0 {
                0.0
            } else if h < 4.0 {
                6000.0
            } else if h < 6.5 {
                3000.0
            } else {
                0.0
            }
        })
        .collect();
    (time, room, speed)
}

/// Simulates `src` with the given non-linear values (`truth`, in the machine's order) and
/// coefficients, then fits it back from the values the source states.
fn recover(
    src: &str,
    truth: &[f64],
    beta: &[f64],
    seed: u64,
) -> (Compiled, kin_estimate::fit::FitResult) {
    let c = machine(src);
    let n = 240;
    let mut poses = sample_points(&c.machine, n, seed);
    let (time, room, speed) = day(n);
    poses.rows.time = Some(time);
    poses.rows.inputs = vec![Some(room), Some(speed)];
    let mut truth_machine = c.machine.clone();
    for (p, v) in truth_machine.nonlinear.iter_mut().zip(truth) {
        p.value = *v;
    }
    let options = simulate::Options {
        noise: 0.1e-6,
        seed: seed + 1,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&truth_machine, beta, &Observations::Points(poses), &options)
        .expect("simulate");
    let files = [DataSet {
        path: "day.csv".into(),
        observations: obs,
    }];
    let r = run(&c, &files, &Options::default()).expect("fit");
    (c, r)
}

fn assert_within_se(name: &str, fitted: f64, se: Option<f64>, truth: f64) {
    let se = se.unwrap_or(f64::NAN);
    assert!(se.is_finite() && se > 0.0, "{name}: standard error {se}");
    assert!(
        ((fitted - truth) / se).abs() < 3.0,
        "{name}: {} ± {} min, truth {} min",
        fitted / 60.0,
        se / 60.0,
        truth / 60.0
    );
}

#[test]
fn a_temperature_and_a_spindle_speed_with_their_time_constants_are_recovered() {
    let src = r#"
machine spindle {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 500 mm
    input T_room : temperature rise
    input S : speed
    tool chain {
        X moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = linear(X)
        t.tz = lag(T_room, tau fit 30 min) * const
             + lag(pow(S / 1000 rpm, 1.5), tau fit 10 min, from 0 rpm) * const
    }
}
"#;
    let c = machine(src);
    let names: Vec<&str> = c
        .machine
        .nonlinear
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(names, ["t.tz.tau", "t.tz.tau[1]"]);
    // 1.2 µm/K of room drift, 0.8 µm per (S/1000 rpm)^1.5: 11.8 µm at 6000 rpm.
    let beta = [4e-6, 1.2e-6, 0.8e-6];
    let truth = [75.0 * 60.0, 20.0 * 60.0];
    let (_, r) = recover(src, &truth, &beta, 31);
    let nl = r.nonlinear.as_ref().expect("non-linear fit");
    assert_within_se("τ room", nl.values[0], nl.se[0], truth[0]);
    assert_within_se("τ spindle", nl.values[1], nl.se[1], truth[1]);
    assert!((r.sigma / 0.1e-6 - 1.0).abs() < 0.2, "σ̂ {}", r.sigma);
    let b = &r.solution.beta;
    assert!(
        (b[2] - 0.8e-6).abs() < 0.02e-6,
        "spindle coefficient {}",
        b[2]
    );
}

#[test]
fn both_time_constants_of_a_cascade_are_recovered() {
    // A column warmed by the spindle housing: fast stage 12 min, slow stage 90 min.
    let src = r#"
machine column {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 500 mm
    input T_room : temperature rise
    input S : speed
    tool chain {
        X moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = linear(X) + lag(T_room, tau 60 min) * const
        t.tz = lag(lag(S / 1000 rpm, tau fit 8 min, from 0 rpm), tau fit 60 min) * const
    }
}
"#;
    let beta = [2e-6, 1.0e-6, 3e-6];
    let truth = [60.0 * 60.0, 12.0 * 60.0, 90.0 * 60.0];
    let (c, r) = recover(src, &truth, &beta, 41);
    let names: Vec<&str> = c
        .machine
        .nonlinear
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(names, ["X.tx.tau", "t.tz.tau", "t.tz.tau[1]"]);
    let nl = r.nonlinear.as_ref().expect("non-linear fit");
    assert_within_se("τ fast", nl.values[1], nl.se[1], truth[1]);
    assert_within_se("τ slow", nl.values[2], nl.se[2], truth[2]);
    assert!((r.sigma / 0.1e-6 - 1.0).abs() < 0.2, "σ̂ {}", r.sigma);
}

/// A bed along X, 800 mm between its end sensors, with sensors on its upper and lower faces
/// 200 mm apart; each component one definition (the beam's error differs per component).
const BED: &str = r#"
machine bed {
    task position
    units { length mm, error um, tilt urad, time min }
    axis X prismatic along x range 0 mm .. 1000 mm
    input Tu0 : temperature rise
    input Tu1 : temperature rise
    input Tl0 : temperature rise
    input Tl1 : temperature rise
    tool chain {
        X moving
        tool t at (0, 0, -50) mm
    }
    errors {
        X.tx = 11.5 um/m/K * beam(X, ends at (100, 900) mm, upper at (Tu0, Tu1), lower at (Tl0, Tl1), gap 200 mm, across z)
        X.tz = 11.5 um/m/K * beam(X, ends at (100, 900) mm, upper at (Tu0, Tu1), lower at (Tl0, Tl1), gap 200 mm, across z)
        X.ry = 11.5 um/m/K * beam(X, ends at (100, 900) mm, upper at (Tu0, Tu1), lower at (Tl0, Tl1), gap 200 mm, across z)
    }
}
"#;

/// The fixed error of `component` (index into the machine's error models) at position `x` (m)
/// with the four face temperatures.
fn bed_error(c: &Compiled, error: usize, x: f64, t: [f64; 4]) -> f64 {
    let m = &c.machine;
    let state = kin_model::interp::State {
        q: &[x],
        inputs: &t,
        lags: &[],
        time: 0.0,
        dirs: &[1.0],
        tool: 0,
        tool_offset: None,
    };
    m.errors[error]
        .terms
        .iter()
        .map(|term| kin_model::interp::scalar(&term.scale, &state, m).expect("scalar"))
        .sum()
}

#[test]
fn a_uniformly_heated_beam_only_expands() {
    let c = machine(BED);
    let alpha = 11.5e-6;
    for x in [0.1, 0.35, 0.9, 1.0] {
        let t = [2.0; 4];
        let s = x - 0.1;
        assert!(
            (bed_error(&c, 0, x, t) - alpha * 2.0 * s).abs() < 1e-15,
            "tx at {x}"
        );
        assert_eq!(bed_error(&c, 1, x, t), 0.0, "tz at {x}");
        assert_eq!(bed_error(&c, 2, x, t), 0.0, "ry at {x}");
    }
}

#[test]
fn a_linear_gradient_bends_the_beam_into_a_circle() {
    // The upper face 1.5 K warmer than the lower along the whole beam: constant curvature
    // κ = α ΔT / h; the section at s turns by κ s about +y (eq. 3.59) and the axis drops by
    // κ s²/2 (eq. 3.62), the chord of the circle of radius 1/κ to second order.
    let c = machine(BED);
    let alpha = 11.5e-6;
    let kappa = alpha * 1.5 / 0.2;
    for x in [0.1, 0.3, 0.9] {
        let s = x - 0.1;
        let t = [1.0 + 1.5, 1.0 + 1.5, 1.0, 1.0];
        let angle = bed_error(&c, 2, x, t);
        let drop = bed_error(&c, 1, x, t);
        assert!((angle - kappa * s).abs() < 1e-15, "ry at {x}: {angle}");
        assert!(
            (drop + kappa * s * s / 2.0).abs() < 1e-15,
            "tz at {x}: {drop}"
        );
        // Mean 1.75 K: the expansion.
        assert!((bed_error(&c, 0, x, t) - alpha * 1.75 * s).abs() < 1e-15);
    }
}

#[test]
fn a_gradient_growing_along_the_beam_integrates_exactly() {
    // G(ξ) rising linearly from 0 to G₁ over L: ε = α G₁ s²/(2L), δ = −α G₁ s³/(6L). Checked
    // against a fine midpoint integration of eq. 3.59 and 3.62.
    let c = machine(BED);
    let alpha = 11.5e-6;
    let (l, g1) = (0.8, 3.0 / 0.2);
    let t = [0.0, 3.0, 0.0, 0.0];
    let x = 0.7;
    let s: f64 = x - 0.1;
    let n = 100_000;
    let h = s / n as f64;
    let (mut eps, mut delta) = (0.0, 0.0);
    for i in 0..n {
        let xi = (i as f64 + 0.5) * h;
        // ε = ∫ α G (eq. 3.59) and δ = −∫ ε (eq. 3.62), both by the midpoint rule.
        let g = g1 * xi / l;
        let eps_mid = eps + alpha * g * h / 2.0;
        eps += alpha * g * h;
        delta -= eps_mid * h;
    }
    assert!((bed_error(&c, 2, x, t) - eps).abs() < 1e-12 * eps.abs().max(1e-9));
    assert!((bed_error(&c, 1, x, t) - delta).abs() < 1e-9 * delta.abs());
}

/// A table on a bed along X and a head on Y; the tool point at the bed's level. Two
/// temperatures, of the bed's upper and lower faces, in every file; the model follows the upper
/// one as an expansion of the tool, but knows nothing of the bed's bending.
const TABLE: &str = r#"
machine table {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 1000 mm
    axis Y prismatic along y range 0 mm .. 500 mm
    input T_top : temperature rise
    input T_low : temperature rise
    workpiece chain {
        X moving
        workpiece at (0, 0, 0) mm
    }
    tool chain {
        Y moving
        tool spindle at (0, 0, 0) mm
    }
    errors {
        X.tx = linear(X)
        X.tz = straightness(X, knots 2)
        Y.ty = linear(Y)
        Y.tz = straightness(Y, knots 2)
        tool.tz = T_top * const
    }
}
"#;

const TABLE_NOISE: f64 = 0.2e-6;

/// `src` with `line` added at the end of its errors block.
fn with_line(src: &str, line: &str) -> String {
    let at = src.rfind("    }\n}").expect("errors block");
    format!("{}        {line}\n{}", &src[..at], &src[at..])
}

/// Rows of a table's data: poses at random, the upper faces warming faster and further (to
/// about 3 K) than the lower ones (to about 1.5 K), so that their difference comes and goes.
/// With `hidden`, a line whose one coefficient is the bed's expansion coefficient, α =
/// 11.5 µm/m/K: the truth adds it.
fn table_data(src: &str, hidden: Option<&str>, seed: u64) -> [DataSet; 1] {
    let src = hidden.map_or(src.to_string(), |line| with_line(src, line));
    let c = machine(&src);
    let n = 400;
    let mut p = sample_points(&c.machine, n, seed);
    let f = |r: usize| r as f64 / n as f64;
    p.rows.inputs = c
        .machine
        .inputs
        .iter()
        .enumerate()
        .map(|(k, input)| {
            let (a, rate) = if input.name.starts_with("T_top") {
                (3.0, 4.0)
            } else {
                (1.5, 1.2)
            };
            // Each end of a face a little apart from the other.
            let (a, rate) = (a * (1.0 - 0.1 * k as f64), rate * (1.0 - 0.15 * k as f64));
            Some((0..n).map(|r| a * (1.0 - (-rate * f(r)).exp())).collect())
        })
        .collect();
    // The hidden line's coefficient (the last, its line is the last) is α; the others a few µm.
    let count = c.machine.coefficients.len();
    let beta: Vec<f64> = c
        .machine
        .coefficients
        .iter()
        .enumerate()
        .map(|(j, k)| {
            if hidden.is_some() && j + 1 == count {
                11.5e-6
            } else {
                (2.0 - 0.7 * j as f64) * k.unit.scale
            }
        })
        .collect();
    let options = simulate::Options {
        noise: TABLE_NOISE,
        seed: seed + 1,
        ..simulate::Options::default()
    };
    let obs = simulate::simulate(&c.machine, &beta, &Observations::Points(p), &options)
        .expect("simulate");
    [DataSet {
        path: "table.csv".into(),
        observations: obs,
    }]
}

fn table_diagnosis(src: &str, files: &[DataSet]) -> kin_diagnose::Diagnosis {
    let c = machine(src);
    let r = run(&c, files, &Options::default()).expect("fit");
    kin_diagnose::diagnose(
        &c,
        src,
        files,
        &r,
        &Options::default(),
        &kin_diagnose::Settings::default(),
    )
    .expect("diagnose")
}

/// The top finding of `d` is significant, is `expected` on `X.tz` (or the same on `X.ry`, with
/// `X.tz` an alternative: seen at the bed's level, the bed's rotation moves the point by its
/// distance along X times the angle, the same column on these data), and added to `src` and
/// refitted it leaves the noise.
fn assert_beam_fixes(src: &str, files: &[DataSet], d: &kin_diagnose::Diagnosis, expected: &str) {
    let top = d.findings.first().expect("a finding");
    let listed: Vec<String> = d
        .findings
        .iter()
        .take(5)
        .map(|f| {
            format!(
                "{} (sig {}, bic {:.1})",
                f.candidate.text, f.significant, f.bic
            )
        })
        .collect();
    let text = &top.candidate.text;
    assert!(
        top.significant
            && (text == &format!("X.tz += {expected}") || text == &format!("X.ry += {expected}")),
        "{listed:#?}"
    );
    let named: Vec<&str> = std::iter::once(&top.candidate)
        .chain(&top.alternatives)
        .map(|c| c.target.as_str())
        .collect();
    assert!(named.contains(&"X.tz"), "{named:?}");
    let before = rms(&run(&machine(src), files, &Options::default()).expect("fit"));
    let after =
        rms(&run(&machine(&with_line(src, text)), files, &Options::default()).expect("refit"));
    println!(
        "{}\nrms before {:.3} um, after {:.3} um, noise {:.3} um",
        listed.join("\n"),
        before * 1e6,
        after * 1e6,
        TABLE_NOISE * 1e6
    );
    assert!(
        before > 5.0 * TABLE_NOISE,
        "the bending is visible: {before}"
    );
    assert!(
        after <= 1.1 * TABLE_NOISE,
        "rms after {} um, noise {} um",
        after * 1e6,
        TABLE_NOISE * 1e6
    );
}

fn rms(r: &fit::FitResult) -> f64 {
    let ss: f64 = r.residuals.iter().map(|x| x.residual * x.residual).sum();
    (ss / r.residuals.len() as f64).sqrt()
}

#[test]
fn a_bending_bed_is_found_as_a_beam_and_fixes_the_fit() {
    let hidden = "X.tz += beam(X, ends at (0, 1000) mm, upper at (T_top, T_top), lower at (T_low, T_low), gap 200 mm, across z) * const";
    let files = table_data(TABLE, Some(hidden), 11);
    let d = table_diagnosis(TABLE, &files);
    // Proposed with a gap of 1 m: the coefficient is α × 1 m / 200 mm.
    assert_beam_fixes(
        TABLE,
        &files,
        &d,
        "beam(X, ends at (0, 1000) mm, upper at (T_top, T_top), lower at (T_low, T_low), gap 1000 mm, across z) * const",
    );
}

/// The bed of spec/factors.md: its expansion modelled through a declared beam with the four
/// face temperatures, its bending not. The diagnosis offers the declared call on the bending
/// components.
#[test]
fn a_declared_beam_that_also_bends_is_found_with_its_own_call() {
    let call = "beam(X, ends at (-100, 1100) mm, upper at (T_top0, T_top1), lower at (T_low0, T_low1), gap 250 mm, across z)";
    let src = TABLE
        .replace(
            "    input T_top : temperature rise\n    input T_low : temperature rise\n",
            "    input T_top0 : temperature rise\n    input T_top1 : temperature rise\n    input T_low0 : temperature rise\n    input T_low1 : temperature rise\n",
        )
        .replace(
            "        tool.tz = T_top * const\n",
            &format!("        tool.tz = T_top0 * const\n        X.tx += 11.5 um/m/K * {call}\n"),
        );
    let files = table_data(&src, Some(&format!("X.tz += {call} * const")), 13);
    let d = table_diagnosis(&src, &files);
    assert_beam_fixes(&src, &files, &d, &format!("{call} * const"));
}

#[test]
fn without_a_gradient_effect_no_beam_is_proposed() {
    let d = table_diagnosis(TABLE, &table_data(TABLE, None, 12));
    let beams: Vec<&str> = d
        .findings
        .iter()
        .filter(|f| f.significant && f.candidate.text.contains("beam("))
        .map(|f| f.candidate.text.as_str())
        .collect();
    assert!(beams.is_empty(), "{beams:#?}");
}
