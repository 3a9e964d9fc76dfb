//! Heat sources, lag cascades and declared initial states, fitted back from simulated data.

use kin_compiler::{compile, Compiled};
use kin_runtime::data::Observations;
use kin_runtime::fit::{self, DataSet, FitError, Options};
use kin_runtime::interp::Interpreter;
use kin_runtime::simulate::{self, sample_points};

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
) -> (Compiled, kin_runtime::fit::FitResult) {
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
