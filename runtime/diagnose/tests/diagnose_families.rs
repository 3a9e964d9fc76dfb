//! Every candidate family, end to end on data from the exact simulator: a truth model with one
//! effect hidden, a starting model without it. The diagnosis must rank the right candidate
//! first (significant, right family, right target), and adding its text must bring the residual
//! RMS within 1.2× of the simulated noise. Controls with nothing hidden must report nothing.
//!
//! By default one seed at 500 poses per case (CI); `KIN_DIAGNOSE_FULL=1` runs five seeds at 500
//! and 3000 poses and prints the hit and false-alarm table (best with `--release --nocapture`).
//! `diagnose_timing` (ignored) times the diagnosis alone on 3000 points and 3000 lengths.

use std::time::Instant;

use kin_compiler::{compile, Compiled};
use kin_data::data::{LengthData, Observations, Pose};
use kin_diagnose::{self as diagnose, Diagnosis, Family, Settings};
use kin_estimate::fit::{self, DataSet, FitResult, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_model::interp::Interpreter;
use rand::{Rng, SeedableRng};

/// A CMM with a temperature rise and a load: time and both inputs are in every file, so the
/// thermal, drift and input cross-coupling candidates are always in play.
const CMM: &str = r#"
machine cmm3 {
    task measure
    units { length mm, error um, tilt urad, time min, force N }
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    input T : temperature rise
    input load : force range 0 N .. 500 N
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

/// A 3-axis mill with a C rotary table carrying the part (no time, no inputs).
const MILL: &str = r#"
machine mill4 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis C revolute about z continuous
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

/// The CMM without a temperature or a load: a several-hour measurement with only its time
/// column, where a drift in time has nothing measured to follow.
const TIMED: &str = r#"
machine cmm3t {
    task measure
    units { length mm, error um, tilt urad, time min }
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

/// A 5-axis machine with a trunnion: B tilts about y and carries a C rotary table (no time, no
/// inputs). The model has the locations of both axis lines and of the workpiece on the table.
const TILT: &str = r#"
machine tilt5 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    axis B revolute about y range -90 deg .. 90 deg
    axis C revolute about z continuous
    workpiece chain {
        Y fixed at (0, 200, 0) mm
        X fixed at (250, 0, 120) mm
        B fixed at (0, 0, 150) mm
        C fixed at (0, 0, -60) mm
        workpiece at (0, 0, 20) mm
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
        B.tx = const
        B.tz = const
        B.rx = const
        B.rz = const
        C.tx = const
        C.ty = const
        C.rx = const
        C.ry = const
        workpiece.tx = const
        workpiece.ty = const
        workpiece.rx = const
        workpiece.ry = const
    }
}
"#;

/// A shoulder–elbow arm on a vertical base joint, measured in position only (a tracker): the
/// model has the joints' zero offsets and the links' lengths.
const ARM: &str = r#"
machine arm3 {
    task position
    units { length mm, angle deg, error um, tilt urad }
    axis J1 revolute about z range -170 deg .. 170 deg
    axis J2 revolute about y range -80 deg .. 60 deg
    axis J3 revolute about y range -120 deg .. 120 deg
    tool chain {
        J1 moving
        J2 moving at (0, 0, 450) mm
        J3 moving at (600, 0, 0) mm
        tool flange at (500, 0, 80) mm
    }
    errors {
        J1.rz = const
        J2.ry = const
        J3.ry = const
        J2.tx = const
        J3.tx = const
    }
}
"#;

/// The length of the [`TIMED`] measurement, whatever the number of rows.
const TIMED_HOURS: f64 = 6.0;

const NOISE: f64 = 0.2e-6;

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Cmm,
    Mill,
    Timed,
    Tilt,
    Arm,
}

/// One hidden effect: the line added to the truth (fixed non-linear values), its coefficients in
/// display units, and what the diagnosis must name.
struct Case {
    name: &'static str,
    kind: Kind,
    family: Family,
    target: &'static str,
    hidden: &'static str,
    values: &'static [f64],
    /// Text the top finding's line must contain (the form, not only the family).
    form: &'static str,
}

const CASES: &[Case] = &[
    Case {
        name: "constant (Y.rx tilt)",
        kind: Kind::Cmm,
        family: Family::Constant,
        target: "Y.rx",
        // 4 µrad seen through 100 … 500 mm of tool below the Y carriage: 0.4 … 2 µm in ey.
        hidden: "Y.rx += const",
        values: &[4.0],
        form: "",
    },
    Case {
        name: "abbe (X pitch)",
        kind: Kind::Cmm,
        family: Family::AbbeAngular,
        target: "X.ry",
        // A pitch varying by ≈ 3.5 µrad along X, through up to 0.5 m of Abbe arm.
        hidden: "X.ry += spline(X, knots 2)",
        values: &[12.0, -16.0, 20.0, -12.0],
        form: "",
    },
    Case {
        name: "backlash (X)",
        kind: Kind::Cmm,
        family: Family::Backlash,
        target: "X.tx",
        // ±0.8 µm with the direction of motion.
        hidden: "X.tx += backlash(X)",
        values: &[0.8],
        form: "",
    },
    Case {
        name: "periodic (X pitch 16.3 mm)",
        kind: Kind::Cmm,
        family: Family::Periodic,
        target: "X.tx",
        // ≈ 1.5 µm peak to peak; the peak is off the spectrum's grid, the refit moves λ.
        hidden: "X.tx += periodic(X, wavelength 16.3 mm, knots 2)",
        values: &[40.0, -25.0],
        form: "",
    },
    Case {
        name: "periodic in X.tx and X.ry (one λ)",
        kind: Kind::Cmm,
        family: Family::Periodic,
        target: "X.tx",
        // One leadscrew: 1 µm in the positioning error and 4 µrad of pitch (≈ 0.4 … 2 µm
        // through the Abbe arm) at one wavelength; one line for both, one fitted λ.
        hidden: "X.tx, X.ry += fourier(X, harmonics 1, wavelength 23.7 mm)",
        values: &[0.6, -0.8, 2.4, 3.2],
        form: "X.tx, X.ry += fourier(X, harmonics 1, wavelength fit",
    },
    Case {
        name: "periodic, two harmonics (X 20 mm)",
        kind: Kind::Cmm,
        family: Family::Periodic,
        target: "X.tx",
        // 5 µm at λ = 20 mm and 2 µm at λ/2: one round must take both harmonics.
        hidden: "X.tx += fourier(X, harmonics 1..2, wavelength 20 mm)",
        values: &[5.0, 0.0, 0.0, 2.0],
        form: "fourier(X, harmonics 1..2, wavelength fit",
    },
    Case {
        name: "more knots (X.tx bump)",
        kind: Kind::Cmm,
        family: Family::MoreKnots,
        target: "X.tx",
        // A C¹ bump between 2/8 and 6/8 of the range, ≈ 2.5 µm high: knots 2 cannot follow it.
        hidden: "X.tx += spline(X, knots 7)",
        values: &[0.0, 0.0, 0.0, 80.0, -160.0, 0.0, 160.0, -80.0, 0.0],
        form: "",
    },
    Case {
        name: "cross-coupling (Y.tz with X)",
        kind: Kind::Cmm,
        family: Family::CrossCoupling,
        target: "Y.tz",
        // ±1 µm with X, ±1.5 µm with X·Y.
        hidden: "Y.tz += linear(X) + linear(X) * linear(Y)",
        values: &[1.0, 1.5],
        form: "",
    },
    Case {
        name: "cross-coupling (Y.rx with load)",
        kind: Kind::Cmm,
        family: Family::CrossCoupling,
        target: "Y.rx",
        // ±3 µrad with the load (and with load·Y), through up to 0.5 m of arm.
        hidden: "Y.rx += linear(load) + linear(load) * linear(Y)",
        values: &[3.0, 3.0],
        form: "",
    },
    Case {
        name: "thermal (tool.tz, τ 40 min)",
        kind: Kind::Cmm,
        family: Family::Thermal,
        target: "tool.tz",
        // 0.5 µm/K of a 4 K warm-up through a 40 min lag; the scan tests 10, 30, 90 min and
        // the refit moves τ.
        hidden: "tool.tz += lag(T, tau 40 min) * const",
        values: &[0.5],
        form: "",
    },
    Case {
        name: "thermal in tool.tz and tool.tx (one τ)",
        kind: Kind::Cmm,
        family: Family::Thermal,
        target: "tool.tz",
        // One heat source behind one 40 min lag: 0.5 µm/K along z, 0.3 µm/K along x.
        hidden: "tool.tz, tool.tx += lag(T, tau 40 min) * const",
        values: &[0.5, 0.3],
        form: "tool.tz, tool.tx += lag(T, tau fit",
    },
    Case {
        name: "drift (tool.ty)",
        kind: Kind::Cmm,
        family: Family::Drift,
        target: "tool.ty",
        // 0.004 µm/min: ≈ 1.9 µm over the eight hours.
        hidden: "tool.ty += time * const",
        values: &[0.004],
        form: "",
    },
    Case {
        name: "revolute harmonics (C.tx)",
        kind: Kind::Mill,
        family: Family::RevoluteHarmonics,
        target: "C.tx",
        // Radial error motion at 2, 3, 4 per revolution, ≈ 1 µm.
        hidden: "C.tx += fourier(C, harmonics 2..4)",
        values: &[0.8, -0.5, 0.0, 0.7, 0.3, 0.0],
        form: "",
    },
    Case {
        name: "backlash width (X, no step yet)",
        kind: Kind::Cmm,
        family: Family::Backlash,
        target: "X.tx",
        // A step of ±0.5 µm at mid-travel that grows by ±0.8 µm towards the ends: the constant
        // and its width in one round, not a constant now and the width next.
        hidden: "X.tx += backlash(X) + linear(X) * backlash(X)",
        values: &[0.5, 0.8],
        form: "linear(X) * backlash(X)",
    },
    Case {
        name: "backlash width (Y, step in the model)",
        kind: Kind::Cmm,
        family: Family::Backlash,
        target: "Y.ty",
        // The model has Y's constant step; its width varies by ±1 µm along Y.
        hidden: "Y.ty += linear(Y) * backlash(Y)",
        values: &[1.0],
        form: "linear(Y) * backlash(Y)",
    },
    Case {
        name: "backlash across axes (X with Y)",
        kind: Kind::Cmm,
        family: Family::Backlash,
        target: "X.tx",
        // No step at mid-travel of Y, ±1.2 µm at its ends: the reversal of X is seen as an
        // error that depends on where Y is (the bridge's weight on X's drive).
        hidden: "X.tx += linear(Y) * backlash(X)",
        values: &[1.2],
        form: "linear(Y) * backlash(X)",
    },
    Case {
        name: "hysteresis across axes (Y.rx with X)",
        kind: Kind::Cmm,
        family: Family::Backlash,
        target: "Y.rx",
        // A pitch of Y at its reversals that grows along X by ±4 µrad, seen through the Abbe
        // arm below the Y carriage.
        hidden: "Y.rx += linear(X) * backlash(Y)",
        values: &[4.0],
        form: "linear(X) * backlash(Y)",
    },
    Case {
        name: "once per revolution (C.tz axial)",
        kind: Kind::Mill,
        family: Family::RevoluteHarmonics,
        target: "C.tz",
        // Axial motion of ≈ 1 µm at once per revolution: a wobbling thrust face, which no
        // location constant of C can absorb.
        hidden: "C.tz += fourier(C, harmonics 1)",
        values: &[0.8, -0.6],
        form: "harmonics 1)",
    },
    Case {
        name: "once per revolution (C.rz angular)",
        kind: Kind::Mill,
        family: Family::RevoluteHarmonics,
        target: "C.rz",
        // An eccentric encoder: ≈ 10 µrad of angular positioning error at once per revolution.
        hidden: "C.rz += fourier(C, harmonics 1)",
        values: &[8.0, -6.0],
        form: "harmonics 1)",
    },
    Case {
        name: "tilting table under gravity (C.tx)",
        kind: Kind::Tilt,
        family: Family::CrossCoupling,
        target: "C.tx",
        // The C table and its load on the B trunnion: gravity in the table's frame turns with
        // B, so its radial compliance gives ≈ 1.7 µm as a·sin B + b·cos B.
        hidden: "C.tx += sin(B) * const + cos(B) * const",
        values: &[1.5, 0.8],
        form: "sin(B) * const + cos(B) * const",
    },
    Case {
        name: "arm joint compliance (J2 under two links)",
        kind: Kind::Arm,
        family: Family::CrossCoupling,
        target: "J2.ry",
        // Point masses of 20 kg at (300, 0, 50) mm on the upper arm, 12 kg at 250 mm on the
        // forearm and 5 kg at the flange (500, 0, 80) mm, a shoulder compliance of 2 µrad/N·m,
        // scaled to this sweep's 0.2 µm noise as a tracker's 20 µm is to the real deflection:
        // the torque's cos/sin of J2 and of J2 + J3, in µrad (spec/diagnosis.md, "Joint
        // compliance of an arm").
        hidden: "J2.ry += cos(J2) * const + sin(J2) * const + cos(J2 + J3) * const + sin(J2 + J3) * const",
        values: &[3.18, 0.196, 1.08, 0.078],
        form: "cos(J2 + J3) * const",
    },
    Case {
        name: "counter-rotating tilt motion (C)",
        kind: Kind::Tilt,
        family: Family::RevoluteHarmonics,
        target: "C.rx",
        // A tilt of 5 µrad that turns against the table once per revolution: R(−C) v on
        // (C.rx, C.ry), seen through up to ≈ 0.4 m of arm. No location constant absorbs it.
        hidden: "C.rx, C.ry += fourier(C, harmonics 1)",
        values: &[4.0, -3.0, -3.0, -4.0],
        form: "harmonics 1)",
    },
];

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{src}\n{:#?}", out.diagnostics))
}

fn base_source(kind: Kind) -> &'static str {
    match kind {
        Kind::Cmm => CMM,
        Kind::Mill => MILL,
        Kind::Timed => TIMED,
        Kind::Tilt => TILT,
        Kind::Arm => ARM,
    }
}

/// `src` with `line` added at the end of its (only) `errors` block, and the byte range of the
/// line in the result.
fn with_line(src: &str, line: &str) -> (String, std::ops::Range<usize>) {
    let at = src.rfind("    }\n}").expect("errors block");
    let start = at + 8;
    let out = format!("{}        {line}\n{}", &src[..at], &src[at..]);
    (out, start..start + line.len())
}

/// Truth coefficients: the base model's drawn at random (a few µm or µrad), the hidden line's as
/// given.
fn truth_beta(
    truth: &Compiled,
    hidden: std::ops::Range<usize>,
    values: &[f64],
    seed: u64,
) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5eed);
    let mut k = 0;
    let mut beta = Vec::new();
    for (j, c) in truth.machine.coefficients.iter().enumerate() {
        let span = &truth.map.coefficients[j];
        let v = if span.start >= hidden.start && span.end <= hidden.end {
            k += 1;
            values[k - 1]
        } else {
            rng.random_range(-3.0..3.0)
        };
        beta.push(v * c.unit.scale);
    }
    assert_eq!(k, values.len(), "coefficients of the hidden line");
    beta
}

/// Heated for five hours (4 K, time constant 90 min), then cooling (60 min); time spread over
/// eight hours whatever the number of rows.
fn warmup(n: usize) -> (Vec<f64>, Vec<f64>) {
    let dt = 8.0 * 3600.0 / n as f64;
    let time: Vec<f64> = (0..n).map(|r| dt * r as f64).collect();
    let off = 5.0 * 3600.0;
    let top = 4.0 * (1.0 - (-off / 5400.0f64).exp());
    let temp = time
        .iter()
        .map(|&t| {
            if t < off {
                4.0 * (1.0 - (-t / 5400.0f64).exp())
            } else {
                top * (-(t - off) / 3600.0f64).exp()
            }
        })
        .collect();
    (time, temp)
}

/// Poses of `n` rows for `kind`: directions of motion for every axis, and on the CMM time, the
/// temperature rise and a load (changed every 20 rows).
fn poses(
    m: &kin_compiler::ir::Machine,
    kind: Kind,
    n: usize,
    seed: u64,
) -> kin_data::data::PointData {
    let mut p = sample_points(m, n, seed);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0xd1);
    for d in p.pose.dir.iter_mut() {
        if d.is_none() {
            *d = Some(
                (0..n)
                    .map(|_| if rng.random_bool(0.5) { 1.0 } else { -1.0 })
                    .collect(),
            );
        }
    }
    if kind == Kind::Cmm {
        let (time, temp) = warmup(n);
        let mut load = Vec::with_capacity(n);
        let mut current = 0.0;
        for r in 0..n {
            if r % 20 == 0 {
                current = rng.random_range(0.0..500.0);
            }
            load.push(current);
        }
        p.rows.time = Some(time);
        p.rows.inputs = vec![Some(temp), Some(load)];
    }
    if kind == Kind::Timed {
        let dt = TIMED_HOURS * 3600.0 / n as f64;
        p.rows.time = Some((0..n).map(|r| dt * r as f64).collect());
    }
    p
}

fn fit_model(c: &Compiled, files: &[DataSet]) -> FitResult {
    let mut it = Interpreter::new(&c.machine).unwrap();
    fit::fit(c, &mut it, files, &[], &Options::default(), &mut |_, _| {}).expect("fit")
}

fn rms(r: &FitResult) -> f64 {
    (r.residuals
        .iter()
        .map(|x| x.residual * x.residual)
        .sum::<f64>()
        / r.residuals.len() as f64)
        .sqrt()
}

/// What one run gave.
struct Outcome {
    /// Significant findings: `family target` texts.
    significant: Vec<String>,
    top: Option<(Family, String, String, bool)>,
    /// Residual RMS over the noise of the base fit, and after adding the top candidate's text
    /// and refitting.
    rms_before: f64,
    rms_after: Option<f64>,
    seconds: f64,
}

/// Point data of the truth (`hidden` added to the base, or nothing): `n` poses, noise
/// [`NOISE`], coefficients and noise drawn from `seed`.
fn simulated(kind: Kind, hidden: Option<(&str, &[f64])>, n: usize, seed: u64) -> [DataSet; 1] {
    simulated_on(base_source(kind), kind, hidden, n, seed)
}

/// [`simulated`] with `hidden` added to `base_src` instead of the kind's base.
fn simulated_on(
    base_src: &str,
    kind: Kind,
    hidden: Option<(&str, &[f64])>,
    n: usize,
    seed: u64,
) -> [DataSet; 1] {
    let (truth_src, range) = match hidden {
        Some((line, _)) => with_line(base_src, line),
        None => (base_src.to_string(), 0..0),
    };
    let truth = compiled(&truth_src);
    let beta = truth_beta(&truth, range, hidden.map(|h| h.1).unwrap_or(&[]), seed);
    let p = poses(&truth.machine, kind, n, seed);
    let obs = simulate::simulate(
        &truth.machine,
        &beta,
        &Observations::Points(p),
        &simulate::Options {
            noise: NOISE,
            seed: seed + 1,
            ..simulate::Options::default()
        },
    )
    .unwrap();
    [DataSet {
        path: "data.csv".into(),
        observations: obs,
    }]
}

/// Simulates the truth (`hidden` added to the base, or nothing), fits the base, diagnoses, and
/// when a finding is significant adds the top candidate's text and refits.
fn run(kind: Kind, hidden: Option<(&str, &[f64])>, n: usize, seed: u64) -> (Outcome, Diagnosis) {
    run_on(base_source(kind), kind, hidden, n, seed)
}

/// [`run`] with `base_src` as the model fitted and diagnosed (the truth: the kind's base with
/// `hidden`): a model that already has the hidden line is a control.
fn run_on(
    base_src: &str,
    kind: Kind,
    hidden: Option<(&str, &[f64])>,
    n: usize,
    seed: u64,
) -> (Outcome, Diagnosis) {
    let files = simulated(kind, hidden, n, seed);
    let base = compiled(base_src);
    let r = fit_model(&base, &files);
    let t = Instant::now();
    let d = diagnose::diagnose(
        &base,
        base_src,
        &files,
        &r,
        &Options::default(),
        &Settings::default(),
    )
    .expect("diagnose");
    let seconds = t.elapsed().as_secs_f64();
    let significant: Vec<String> = d
        .findings
        .iter()
        .filter(|f| f.significant)
        .map(|f| f.candidate.text.clone())
        .collect();
    let top = d.findings.first().map(|f| {
        (
            f.candidate.family,
            f.candidate.target.clone(),
            f.candidate.text.clone(),
            f.significant,
        )
    });
    let rms_after = match &top {
        Some((_, _, text, true)) => {
            let (src, _) = with_line(base_src, text);
            let c = compiled(&src);
            let mut it = Interpreter::new(&c.machine).unwrap();
            // A text that does not fit (e.g. rank-deficient) counts as a miss: infinite RMS.
            match fit::fit(
                &c,
                &mut it,
                &files,
                &[],
                &Options::default(),
                &mut |_, _| {},
            ) {
                Ok(r) => Some(rms(&r) / NOISE),
                Err(e) => {
                    eprintln!("refit with `{text}` failed: {e}");
                    Some(f64::INFINITY)
                }
            }
        }
        _ => None,
    };
    (
        Outcome {
            significant,
            top,
            rms_before: rms(&r) / NOISE,
            rms_after,
            seconds,
        },
        d,
    )
}

fn describe(d: &Diagnosis) -> String {
    d.findings
        .iter()
        .take(4)
        .map(|f| {
            format!(
                "\n    {} [{:?}] explained {:.3} F {:.1} p_adj {:.2e} sig {}",
                f.candidate.text, f.candidate.family, f.explained, f.f, f.p_adjusted, f.significant
            )
        })
        .collect()
}

/// One line of the table.
#[derive(Default)]
struct Tally {
    runs: usize,
    hits: usize,
    /// The smallest residual RMS of the base fit (the weakest hidden effect), over the noise.
    least_before: f64,
    /// Controls: the smallest Holm-adjusted p-value of any candidate.
    least_p: f64,
    worst_rms: f64,
    seconds: f64,
    misses: Vec<String>,
}

fn hidden_case(case: &Case, n: usize, seed: u64, tally: &mut Tally) {
    let (o, d) = run(case.kind, Some((case.hidden, case.values)), n, seed);
    tally.runs += 1;
    tally.seconds += o.seconds;
    tally.least_before = if tally.runs == 1 {
        o.rms_before
    } else {
        tally.least_before.min(o.rms_before)
    };
    let ranked = matches!(&o.top, Some((f, t, text, true))
        if *f == case.family && t == case.target && text.contains(case.form));
    let rms_ok = o.rms_after.is_some_and(|r| r <= 1.2);
    if let Some(r) = o.rms_after {
        tally.worst_rms = tally.worst_rms.max(r);
    }
    if ranked && rms_ok {
        tally.hits += 1;
    } else {
        tally.misses.push(format!(
            "seed {seed} n {n}: rms after {:?}, top {}",
            o.rms_after,
            describe(&d)
        ));
    }
}

fn control(kind: Kind, n: usize, seed: u64, tally: &mut Tally) {
    let (o, d) = run(kind, None, n, seed);
    tally.runs += 1;
    tally.seconds += o.seconds;
    tally.least_before = if tally.runs == 1 {
        o.rms_before
    } else {
        tally.least_before.min(o.rms_before)
    };
    // How close the strongest candidate came to an alarm.
    let least_p = d.findings.iter().map(|f| f.p_adjusted).fold(1.0, f64::min);
    tally.least_p = if tally.runs == 1 {
        least_p
    } else {
        tally.least_p.min(least_p)
    };
    if o.significant.is_empty() {
        tally.hits += 1;
    } else {
        tally.misses.push(format!(
            "seed {seed} n {n}: false alarm {:?}{}",
            o.significant,
            describe(&d)
        ));
    }
}

fn full() -> bool {
    std::env::var("KIN_DIAGNOSE_FULL").is_ok_and(|v| v == "1")
}

fn plan() -> (Vec<u64>, Vec<usize>) {
    if full() {
        ((0..5).collect(), vec![500, 3000])
    } else {
        (vec![0], vec![500])
    }
}

fn report(name: &str, t: &Tally) {
    println!(
        "{name:<36} {:>3}/{:<3} rms/σ before ≥ {:.2}, after ≤ {:.3}; diagnose {:.2} s per run",
        t.hits,
        t.runs,
        t.least_before,
        t.worst_rms,
        t.seconds / t.runs.max(1) as f64
    );
    if t.least_p > 0.0 {
        println!(
            "{:<36} smallest adjusted p of any candidate {:.3}",
            "", t.least_p
        );
    }
    for m in &t.misses {
        println!("    miss: {m}");
    }
}

#[test]
fn every_family_is_found_and_fixes_the_fit() {
    let (seeds, sizes) = plan();
    let (mut hits, mut runs) = (0, 0);
    let mut lines = Vec::new();
    for case in CASES {
        for &n in &sizes {
            let mut t = Tally::default();
            for &seed in &seeds {
                hidden_case(case, n, 100 + seed, &mut t);
            }
            report(&format!("{} n={n}", case.name), &t);
            hits += t.hits;
            runs += t.runs;
            lines.push((case.name, n, t));
        }
    }
    let rate = hits as f64 / runs as f64;
    println!("hit rate {hits}/{runs} = {:.1} %", 100.0 * rate);
    if full() {
        assert!(rate >= 0.9, "hit rate {rate}");
    } else {
        // One seed per family: every family must be found.
        let missed: Vec<String> = lines
            .iter()
            .filter(|l| l.2.hits < l.2.runs)
            .map(|l| format!("{} n={}: {:?}", l.0, l.1, l.2.misses))
            .collect();
        assert!(missed.is_empty(), "{missed:#?}");
    }
}

#[test]
fn complete_models_raise_no_false_alarm() {
    let (seeds, sizes) = plan();
    let (mut alarms, mut runs) = (0, 0);
    for kind in [Kind::Cmm, Kind::Mill, Kind::Tilt, Kind::Arm] {
        for &n in &sizes {
            let mut t = Tally::default();
            for &seed in &seeds {
                control(kind, n, 200 + seed, &mut t);
            }
            report(
                &format!(
                    "control {} n={n}",
                    match kind {
                        Kind::Cmm => "cmm",
                        Kind::Mill => "mill",
                        Kind::Tilt => "tilt",
                        Kind::Arm => "arm",
                        Kind::Timed => "timed",
                    }
                ),
                &t,
            );
            alarms += t.runs - t.hits;
            runs += t.runs;
        }
    }
    println!("false alarms {alarms}/{runs}");
    if full() {
        // Each run raises a false alarm with probability α = 0.01 at most (Holm–Bonferroni is
        // family-wise): over 30 runs one alarm comes with probability 26 %, and demanding none
        // would demand a test that never errs. Allowed: what α makes improbable (the count
        // that more runs exceed with probability under 0.1 %). The rate itself is measured by
        // `false_alarm_rate_of_the_controls` (0.7 % on each of two kinds, 150 runs each).
        let allowed = binomial_bound(runs, Settings::default().alpha, 1e-3);
        assert!(
            alarms <= allowed,
            "{alarms} false alarms in {runs} runs (allowed {allowed})"
        );
    } else {
        assert_eq!(alarms, 0);
    }
}

/// The smallest `k` with P(X > k) < `tail` for X binomial(`n`, `p`).
fn binomial_bound(n: usize, p: f64, tail: f64) -> usize {
    let mut term = (1.0 - p).powi(n as i32);
    let mut below = term;
    for k in 0..n {
        if 1.0 - below < tail {
            return k;
        }
        term *= (n - k) as f64 / (k + 1) as f64 * p / (1.0 - p);
        below += term;
    }
    n
}

#[test]
fn binomial_bounds() {
    // 30 runs at 1 %: P(X ≥ 3) = 0.33 %, P(X ≥ 4) = 0.02 %.
    assert_eq!(binomial_bound(30, 0.01, 1e-3), 3);
    assert_eq!(binomial_bound(30, 0.01, 1e-2), 2);
    assert_eq!(binomial_bound(10, 0.0, 1e-3), 0);
}

/// The false-alarm rate of the controls over many seeds: at α = 0.01 family-wise, at most
/// about 1 % of the runs may raise an alarm. A measurement (ignored): run with `--release
/// --ignored --nocapture`, `KIN_ALARM_SEEDS=N` seeds per control (200 by default).
#[test]
#[ignore = "measurement: run with --release --ignored --nocapture"]
fn false_alarm_rate_of_the_controls() {
    let seeds: u64 = std::env::var("KIN_ALARM_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    for (name, kind, n) in [("tilt", Kind::Tilt, 3000), ("mill", Kind::Mill, 3000)] {
        let mut t = Tally::default();
        for seed in 0..seeds {
            control(kind, n, 10_000 + seed, &mut t);
        }
        let alarms = t.runs - t.hits;
        println!(
            "control {name} n={n}: {alarms} false alarms in {} runs ({:.1} %)",
            t.runs,
            100.0 * alarms as f64 / t.runs as f64
        );
        for m in &t.misses {
            println!("    {}", m.lines().next().unwrap_or(""));
        }
    }
}

/// Lengths between consecutive sampled poses of the CMM (a step gauge or ballbar plan).
fn lengths(m: &kin_compiler::ir::Machine, n: usize, seed: u64) -> LengthData {
    let a = poses(m, Kind::Cmm, n, seed);
    let b = poses(m, Kind::Cmm, n, seed + 7);
    let pose = |p: &kin_data::data::PointData| Pose {
        axes: p.pose.axes.clone(),
        dir: p.pose.dir.clone(),
    };
    LengthData {
        rows: a.rows.clone(),
        poses: [pose(&a), pose(&b)],
        dl: vec![0.0; n],
    }
}

#[test]
#[ignore = "timing: run with --release --ignored --nocapture"]
fn diagnose_timing() {
    let n = 3000;
    // Points: the CMM with a hidden backlash.
    let (o, _) = run(Kind::Cmm, Some(("X.tx += backlash(X)", &[0.8])), n, 1);
    println!(
        "points, {n} rows (ex ey ez): diagnose {:.3} s, top {:?}",
        o.seconds, o.top
    );
    // Lengths: the same truth seen through lengths.
    let (truth_src, range) = with_line(CMM, "X.tx += backlash(X)");
    let truth = compiled(&truth_src);
    let beta = truth_beta(&truth, range, &[0.8], 1);
    let l = lengths(&truth.machine, n, 1);
    let obs = simulate::simulate(
        &truth.machine,
        &beta,
        &Observations::Lengths(l),
        &simulate::Options {
            noise: NOISE,
            seed: 2,
            ..simulate::Options::default()
        },
    )
    .unwrap();
    let files = [DataSet {
        path: "lengths.csv".into(),
        observations: obs,
    }];
    let base = compiled(CMM);
    let r = fit_model(&base, &files);
    let t = Instant::now();
    let d = diagnose::diagnose(
        &base,
        CMM,
        &files,
        &r,
        &Options::default(),
        &Settings::default(),
    )
    .expect("diagnose");
    println!(
        "lengths, {n} rows: diagnose {:.3} s, {} candidates tested, top {:?}",
        t.elapsed().as_secs_f64(),
        d.findings.len(),
        d.findings
            .first()
            .map(|f| (&f.candidate.text, f.significant))
    );
}

/// Issue 11, point 1: a periodic error with a strong second harmonic is found and fixed in one
/// round, the refit's ±2σ interval of the fitted wavelength covers the truth, and no
/// half-wavelength term is left significant after it.
#[test]
fn a_two_harmonic_periodic_error_is_fixed_in_one_round() {
    let case = CASES
        .iter()
        .find(|c| c.name.starts_with("periodic, two harmonics"))
        .expect("case");
    let truth_lambda = 20e-3;
    let seeds: Vec<u64> = if full() {
        (0..20).collect()
    } else {
        (0..4).collect()
    };
    let mut covered = 0;
    let mut lines = Vec::new();
    let mut elsewhere = Vec::new();
    for &seed in &seeds {
        let files = simulated(Kind::Cmm, Some((case.hidden, case.values)), 500, 300 + seed);
        let base = compiled(CMM);
        let r = fit_model(&base, &files);
        let d = diagnose::diagnose(
            &base,
            CMM,
            &files,
            &r,
            &Options::default(),
            &Settings::default(),
        )
        .expect("diagnose");
        let top = d.findings.first().expect("a finding");
        assert!(
            top.significant
                && top
                    .candidate
                    .text
                    .starts_with("X.tx += fourier(X, harmonics 1..2, wavelength fit "),
            "seed {seed}: {}",
            describe(&d)
        );
        // The round: the line added as proposed, λ fitted from the scan's value.
        let (src, _) = with_line(CMM, &top.candidate.text);
        let c = compiled(&src);
        let refit = fit_model(&c, &files);
        let after = rms(&refit) / NOISE;
        assert!(after <= 1.1, "seed {seed}: rms after {after}");
        let nl = refit.nonlinear.as_ref().expect("a fitted wavelength");
        let (lambda, se) = (nl.values[0], nl.se[0].expect("its standard error"));
        // Point 8: what the finding states is this refit's, not the scan's.
        let stated = top.fitted.first().expect("the finding states its fitted λ");
        assert!(
            (stated.value - lambda * 1e3).abs() <= 0.1 * se * 1e3
                && (stated.se - se * 1e3).abs() <= 0.1 * se * 1e3,
            "seed {seed}: stated {stated:?}, refit {lambda} ± {se}"
        );
        let refit_rms = rms(&refit) / 1e-6;
        assert!(
            (top.rms_after - refit_rms).abs() <= 1e-3 * refit_rms,
            "seed {seed}: stated RMS after {} µm, refit {refit_rms} µm",
            top.rms_after
        );
        let inside = (lambda - truth_lambda).abs() <= 2.0 * se;
        covered += usize::from(inside);
        lines.push(format!(
            "seed {seed}: λ = {:.5} ± {:.5} mm (2σ), rms after {after:.3} σ",
            lambda * 1e3,
            2.0 * se * 1e3
        ));
        // Nothing periodic is left at the truth's wavelength or one of its harmonics (λ/h):
        // no spurious half-wavelength term. A peak elsewhere is the spectrum's false alarm,
        // counted below.
        let again = diagnose::diagnose(
            &c,
            &src,
            &files,
            &refit,
            &Options::default(),
            &Settings::default(),
        )
        .expect("diagnose after");
        let wavelength = |text: &str| -> Option<f64> {
            text.split("wavelength fit ")
                .nth(1)?
                .split_whitespace()
                .next()?
                .parse()
                .ok()
        };
        for f in again
            .findings
            .iter()
            .filter(|f| f.significant && f.candidate.family == Family::Periodic)
        {
            let text = &f.candidate.text;
            let harmonic = wavelength(text)
                .is_some_and(|w| (1..=4).any(|h| (w * f64::from(h) - 20.0).abs() < 0.2));
            assert!(
                !harmonic,
                "seed {seed}: still periodic after one round: {text}"
            );
            elsewhere.push(format!("seed {seed}: {text}"));
        }
    }
    for l in &lines {
        println!("{l}");
    }
    // The spectrum's false alarms are at the 1 % level: at most one in twenty rounds.
    assert!(
        elsewhere.len() * 20 <= seeds.len().max(20),
        "periodic terms left elsewhere: {elsewhere:#?}"
    );
    println!("left elsewhere: {elsewhere:?}");
    // A 95 % interval misses once in twenty: at most once over four seeds, twice over twenty.
    assert!(
        seeds.len() - covered <= (seeds.len() / 10).max(1),
        "λ's ±2σ covers the truth in {covered}/{}: {lines:#?}",
        seeds.len()
    );
}

/// Issue 31, time: effects that follow the time of a several-hour measurement with no
/// temperature measured ([`TIMED`]).
const TIME_CASES: &[Case] = &[
    Case {
        name: "scale drift (X, 6 h, no temperature)",
        kind: Kind::Timed,
        family: Family::Drift,
        target: "X.tx",
        // 0.003 µm/min at either end of X: ±1.1 µm after six hours, zero at mid-travel.
        hidden: "X.tx += time * linear(X)",
        values: &[0.003],
        form: "X.tx += time * linear(X)",
    },
    Case {
        name: "warm-up (tool.tz, τ 40 min)",
        kind: Kind::Timed,
        family: Family::Drift,
        target: "tool.tz",
        // 1.5 µm of growth over the first two hours, settled after: the scan tests 10, 30 and 90
        // min and the refit moves τ.
        hidden: "tool.tz += warmup(time, tau 40 min) * const",
        values: &[1.5],
        form: "tool.tz += warmup(time, tau fit",
    },
    Case {
        name: "warm-up of the X scale (τ 40 min)",
        kind: Kind::Timed,
        family: Family::Drift,
        target: "X.tx",
        // ±1.5 µm at the ends of X once warm, reached with a 40 min time constant.
        hidden: "X.tx += warmup(time, tau 40 min) * linear(X)",
        values: &[1.5],
        form: "X.tx += warmup(time, tau fit",
    },
];

/// One time case: found first and fixed to 1.1 σ in one round, the time trend named where the
/// model fails; and its control (the same truth, the model complete) raises nothing.
fn time_case(case: &Case, n: usize, seed: u64, hits: &mut Tally, controls: &mut Tally) {
    let (o, d) = run(case.kind, Some((case.hidden, case.values)), n, seed);
    hits.runs += 1;
    hits.seconds += o.seconds;
    hits.least_before = if hits.runs == 1 {
        o.rms_before
    } else {
        hits.least_before.min(o.rms_before)
    };
    let ranked = matches!(&o.top, Some((f, t, text, true))
        if *f == case.family && t == case.target && text.contains(case.form));
    if let Some(r) = o.rms_after {
        hits.worst_rms = hits.worst_rms.max(r);
    }
    let rms_ok = o.rms_after.is_some_and(|r| r <= 1.1);
    let trend = d.regions.iter().any(|r| {
        r.conditions
            .iter()
            .any(|c| c.starts_with("a trend over time"))
    });
    // Outliers are judged after the trend: no row of a warm-up's first two time constants (the
    // first 80 min of the data) is flagged. Elsewhere a row can be: near X = 0 the base model
    // has no constant to take up a drift of the X scale (its spline vanishes there), which the
    // parts' levels and slopes cannot follow either; such rows are counted, not failed.
    let minutes = |line: usize| line as f64 / n as f64 * TIMED_HOURS * 60.0;
    let warm = case.hidden.contains("warmup(");
    let clean = !warm || d.outliers.iter().all(|o| minutes(o.line) >= 80.0);
    if ranked && rms_ok && trend && clean {
        hits.hits += 1;
        if !d.outliers.is_empty() {
            println!(
                "    {} seed {seed} n {n}: found; outliers at {:?} min",
                case.name,
                d.outliers
                    .iter()
                    .map(|o| minutes(o.line).round())
                    .collect::<Vec<_>>()
            );
        }
    } else {
        hits.misses.push(format!(
            "seed {seed} n {n}: rms after {:?}, trend named {trend}, outliers {:?}, regions {:?}, top {}",
            o.rms_after,
            d.outliers
                .iter()
                .map(|o| format!("line {} {} {:.3} (studentized {:.1})", o.line, o.component, o.residual, o.studentized))
                .collect::<Vec<_>>(),
            d.regions.iter().map(|r| &r.text).collect::<Vec<_>>(),
            describe(&d)
        ));
    }
    let (complete, _) = with_line(TIMED, case.hidden);
    let (c, d) = run_on(
        &complete,
        case.kind,
        Some((case.hidden, case.values)),
        n,
        seed,
    );
    controls.runs += 1;
    controls.seconds += c.seconds;
    // A false alarm: any significant line, or any place where the complete model is said to
    // fail. (A periodic line at a residual spectrum's chance peak used to pass here on two of
    // these seeds; its p-value is now corrected for the wavelengths searched.)
    if c.significant.is_empty() && d.regions.is_empty() {
        controls.hits += 1;
    } else {
        controls.misses.push(format!(
            "seed {seed} n {n}: false alarm {:?}, regions {:?}{}",
            c.significant,
            d.regions.iter().map(|r| &r.text).collect::<Vec<_>>(),
            describe(&d)
        ));
    }
    if !d.outliers.is_empty() {
        println!(
            "    control seed {seed} n {n}: {} outlier(s)",
            d.outliers.len()
        );
    }
}

#[test]
fn drifts_in_time_are_found_and_fixed_in_one_round() {
    let (seeds, sizes) = plan();
    let (mut hits, mut runs, mut alarms) = (0, 0, 0);
    for case in TIME_CASES {
        for &n in &sizes {
            let (mut t, mut c) = (Tally::default(), Tally::default());
            for &seed in &seeds {
                time_case(case, n, 400 + seed, &mut t, &mut c);
            }
            report(&format!("{} n={n}", case.name), &t);
            report(&format!("control: {} n={n}", case.name), &c);
            hits += t.hits;
            runs += t.runs;
            alarms += c.runs - c.hits;
        }
    }
    // The plain model of the timed machine with nothing hidden.
    for &n in &sizes {
        let mut t = Tally::default();
        for &seed in &seeds {
            control(Kind::Timed, n, 500 + seed, &mut t);
        }
        report(&format!("control timed n={n}"), &t);
        alarms += t.runs - t.hits;
    }
    let rate = hits as f64 / runs.max(1) as f64;
    println!(
        "time: hit rate {hits}/{runs} = {:.1} %, false alarms {alarms}",
        100.0 * rate
    );
    assert_eq!(alarms, 0);
    if full() {
        assert!(rate >= 0.9, "hit rate {rate}");
    } else {
        assert_eq!(hits, runs);
    }
}

/// A model with a scale error alone (`X.tx = const + linear(X)`) on data whose X positioning error has
/// a shape (the truth's spline): the shape is proposed on top of the line — the curve with its
/// line removed — first, and brings the residual to the noise. Before, the spline candidate
/// repeated the line's column and was dropped, and nothing along X was left to propose.
#[test]
fn a_shape_is_proposed_on_top_of_a_scale_error() {
    let base = CMM.replace("X.tx = spline(X, knots 2)", "X.tx = const + linear(X)");
    assert_ne!(base, CMM, "the CMM model changed");
    for seed in [0, 1] {
        let (o, d) = run_on(&base, Kind::Cmm, None, 500, 900 + seed);
        let top = o.top.as_ref().map(|t| t.2.as_str());
        assert_eq!(
            top,
            Some("X.tx += straightness(X, knots 2)"),
            "seed {seed}: {}",
            describe(&d)
        );
        assert!(
            o.top.as_ref().is_some_and(|t| t.3),
            "seed {seed}: not significant"
        );
        let after = o.rms_after.unwrap_or(f64::INFINITY);
        assert!(after <= 1.2, "seed {seed}: rms after {after}");
    }
}

/// A model without the constant of `X.tx` (`X.tx = linear(X)`) on data with one: the warm-up
/// candidate of the tool takes the constant's place with a time constant shorter than the time
/// between measurements. It may rank high — it does fit the constant — but its refit says what
/// it is, so `--apply` asks for `--force`.
#[test]
fn a_warm_up_faster_than_the_sampling_is_called_a_constant() {
    let base = CMM.replace("X.tx = spline(X, knots 2)", "X.tx = linear(X)");
    let (_, d) = run_on(&base, Kind::Cmm, None, 500, 900);
    let warm = d
        .findings
        .iter()
        .find(|f| f.significant && f.candidate.text.contains("warmup("))
        .unwrap_or_else(|| panic!("no significant warm-up: {}", describe(&d)));
    let doubts = warm
        .plausibility
        .as_ref()
        .map(|p| p.warnings.join("; "))
        .unwrap_or_default();
    assert!(
        doubts.contains("shorter than the time between measurements"),
        "{}: {doubts}",
        warm.candidate.text
    );
}
