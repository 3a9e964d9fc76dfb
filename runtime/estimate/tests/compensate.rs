//! The closed loop of software compensation: a machine with known errors (the exact simulator)
//! is measured, the model fitted, the commanded poses compensated with the *fitted* model, and
//! the machine "run" again, exactly, with the corrections added to its axes. What remains must
//! be what the fit cannot know (its prediction uncertainty, eq. 4.12) plus what the joints
//! cannot correct (which the compensation predicts).

use kin_compiler::ir::Machine;
use kin_compiler::units::Dim;
use kin_compiler::{compile, Compiled};
use kin_data::data::{Observations, PointData};
use kin_estimate::fit::{self, report, DataSet, Options};
use kin_estimate::simulate::{self, sample_points};
use kin_estimate::uncertainty::PredictionCovariance;
use kin_model::compensate::{Compensator, Options as CompOptions};
use kin_model::exact;
use kin_model::interp::Interpreter;
use kin_model::kinematics::{FrameErrors, Pose};
use kin_model::states::States;
use rand::{Rng, SeedableRng};

/// A 3-axis vertical mill (Y and X move the table, Z the head) with scale, straightness,
/// angular, squareness and backlash errors: 21 coefficients.
const MILL3: &str = r#"
machine mill3 {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along -x range 0 mm .. 500 mm
    axis Y prismatic along -y range 0 mm .. 400 mm
    axis Z prismatic along z range -300 mm .. 0 mm
    tool chain {
        Z moving at (0, 0, 450) mm
        tool long at (0, 0, -150) mm
        tool short at (0, 0, -80) mm
    }
    workpiece chain {
        Y fixed at (0, 200, 0) mm
        X fixed at (250, 0, 100) mm
        workpiece
    }
    errors {
        X.tx = spline(X, knots 2) + backlash(X)
        X.ty = straightness(X, knots 2)
        X.rz = const + linear(X)
        X.ry = linear(X)
        Y.ty = linear(Y) + backlash(Y)
        Y.rx = linear(Y)
        Z.tz = linear(Z)
        Z.rx = const
        Z.ry = const
        tool.tz = const
    }
}
"#;

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

/// Poses over the ranges with a direction for every axis, one minute per row and
/// temperatures following a warm-up (what a lag needs to be seen).
fn poses(m: &Machine, n: usize, seed: u64) -> PointData {
    let mut p = sample_points(m, n, seed);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5eed);
    for d in p.pose.dir.iter_mut() {
        *d = Some(
            (0..n)
                .map(|_| if rng.random_bool(0.5) { 1.0 } else { -1.0 })
                .collect(),
        );
    }
    let time: Vec<f64> = (0..n).map(|r| 60.0 * r as f64).collect();
    for (i, input) in m.inputs.iter().enumerate() {
        if input.unit.dim == Dim::TEMPERATURE {
            let base = if input.absolute { 292.15 } else { 0.0 };
            p.rows.inputs[i] = Some(
                time.iter()
                    .map(|t| {
                        base + 3.0 * (1.0 - (-t / 5400.0f64).exp()) + rng.random_range(-0.05..0.05)
                    })
                    .collect(),
            );
        }
    }
    p.rows.time = Some(time);
    p
}

/// The maximum length of the position error over the commanded poses before compensation
/// and after it, in m.
struct Outcome {
    before: f64,
    after: f64,
    /// The largest position difference of the true machine between the servo compensation's
    /// correction (first-order model, `Model::compensator`) and `kin compensate`'s (exact
    /// transforms): what the real-time path gives up.
    servo_gap: f64,
    /// The largest difference of the corrections themselves (m for prismatic axes).
    servo_dq: f64,
}

/// Simulates `src` with coefficients of up to `size` units each (in the model's units, µm or
/// µrad per unit of each term), fits it, compensates 300 fresh poses with the fit and runs them
/// exactly with the true coefficients.
fn closed_loop(src: &str, size: f64, fit_poses: usize, seed: u64) -> Outcome {
    let c = compiled(src);
    let m = &c.machine;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let truth: Vec<f64> = m
        .coefficients
        .iter()
        .map(|co| rng.random_range(-size..size) * co.unit.scale)
        .collect();
    let noise = 0.2e-6;
    let obs = simulate::simulate(
        m,
        &truth,
        &Observations::Points(poses(m, fit_poses, seed)),
        &simulate::Options {
            observe: [true; 6],
            noise,
            noise_tilt: noise,
            seed: seed + 1,
            ..simulate::Options::default()
        },
    )
    .expect("simulate");
    let files = vec![DataSet {
        path: "data.csv".into(),
        observations: obs,
    }];
    let mut it = Interpreter::new(m).expect("interpreter");
    let options = Options::default();
    let result = fit::fit(&c, &mut it, &files, &[], &options, &mut |_, _| {})
        .unwrap_or_else(|e| panic!("{}: fit: {e}", m.name));
    let fitted = report::build(m, src, "interp", &files, &[], &result, &options);
    let n = m.coefficients.len();
    let beta: Vec<f64> = result.solution.beta.iter().take(n).copied().collect();
    // The fitted model: its coefficients, and its non-linear parameters where the fit moved
    // them (the uncertainty's non-linear share is evaluated at both).
    let mut fitted_machine = m.clone();
    fitted_machine.beta = beta.clone();
    if let Some(nl) = &result.nonlinear {
        for (p, v) in fitted_machine.nonlinear.iter_mut().zip(&nl.values) {
            p.value = *v;
        }
    }
    let fm = &fitted_machine;

    let test = poses(m, 300, seed + 7);
    let states = States::new(m, &test.rows, &test.pose, "").expect("states");
    let mut comp = Compensator::new(fm, &beta, CompOptions::pose(fm)).expect("compensator");
    // The same fit in the embedding API's compiled compensation function.
    let mut model = kin_model::Model::compile(src).expect("compiles");
    model.set_beta(&beta).expect("β");
    let values: Vec<f64> = fm.nonlinear.iter().map(|p| p.value).collect();
    model.set_nonlinear(&values).expect("values");
    let servo = model.compensator(CompOptions::pose(fm)).expect("servo");
    let mut servo_dq = vec![0.0; m.axes.len()];
    let mut q_servo = vec![0.0; m.axes.len()];
    let mut uncertainty = Interpreter::new(fm).expect("interpreter");
    let variances = PredictionCovariance::new(fm, &fitted)
        .expect("covariance")
        .point_variances(
            fm,
            &mut uncertainty,
            &mut States::new(fm, &test.rows, &test.pose, "").expect("states"),
            &test.rows,
        )
        .expect("variance");
    let mut truth_it = Interpreter::new(m).expect("interpreter");
    let mut errors = FrameErrors::zeros(m);
    let mut outcome = Outcome {
        before: 0.0,
        after: 0.0,
        servo_gap: 0.0,
        servo_dq: 0.0,
    };
    let mut q = vec![0.0; m.axes.len()];
    for r in 0..states.len() {
        let s = states.get(r);
        let correction = comp.compensate(&s).expect("compensate");
        let pose = Pose {
            q: s.q,
            tool: s.tool,
            tool_offset: s.tool_offset,
        };
        let target = exact::nominal_transform(m, &pose).expect("nominal");
        // Before: the true machine at the commanded pose.
        truth_it
            .frame_errors(&s, &truth, &mut errors)
            .expect("errors");
        let before = exact::location_error(
            &target,
            &exact::actual_transform(m, &pose, &errors).unwrap(),
        );
        // After: the true machine at the corrected pose, against the commanded location.
        for ((slot, q0), d) in q.iter_mut().zip(s.q).zip(&correction.dq) {
            *slot = q0 + d;
        }
        let moved = kin_model::interp::State { q: &q, ..s };
        truth_it
            .frame_errors(&moved, &truth, &mut errors)
            .expect("errors");
        let moved_pose = Pose { q: &q, ..pose };
        let after = exact::location_error(
            &target,
            &exact::actual_transform(m, &moved_pose, &errors).unwrap(),
        );
        let u = variances.get(r).copied().expect("a variance per pose");
        for k in 0..6 {
            // What the machine really does after compensation, against what the fitted model
            // predicts it will do: the model's error at this pose, within its uncertainty.
            let miss = (after[k] - correction.after[k]).abs();
            let bound = 5.0 * u[k].sqrt() + 1e-9;
            assert!(
                miss <= bound,
                "{}: pose {r}, component {k}: after compensation {:.3e}, predicted {:.3e}, \
                 allowed difference {bound:.3e} (before {:.3e})",
                m.name,
                after[k],
                correction.after[k],
                before[k]
            );
        }
        // The servo compensation's correction, run on the true machine.
        let done = servo.compensate(&s, &mut servo_dq).expect("servo");
        assert_eq!(done.rank, correction.rank);
        for ((slot, q0), d) in q_servo.iter_mut().zip(s.q).zip(&servo_dq) {
            *slot = q0 + d;
        }
        truth_it
            .frame_errors(
                &kin_model::interp::State { q: &q_servo, ..s },
                &truth,
                &mut errors,
            )
            .expect("errors");
        let after_servo = exact::location_error(
            &target,
            &exact::actual_transform(
                m,
                &Pose {
                    q: &q_servo,
                    ..pose
                },
                &errors,
            )
            .unwrap(),
        );
        outcome.servo_gap = outcome
            .servo_gap
            .max((after_servo - after).fixed_rows::<3>(0).norm());
        for ((a, b), axis) in servo_dq.iter().zip(&correction.dq).zip(&m.axes) {
            if axis.kind == kin_compiler::ir::JointKind::Prismatic {
                outcome.servo_dq = outcome.servo_dq.max((a - b).abs());
            }
        }
        outcome.before = outcome.before.max(before.fixed_rows::<3>(0).norm());
        outcome.after = outcome.after.max(after.fixed_rows::<3>(0).norm());
    }
    eprintln!(
        "{}: maximum position error over 300 commanded poses: {:.2} µm before compensation, {:.3} µm after; \
         servo compensation (first-order) against the exact one: corrections differ by at most {:.3} nm, \
         the machine's position by {:.3} nm",
        m.name,
        outcome.before * 1e6,
        outcome.after * 1e6,
        outcome.servo_dq * 1e9,
        outcome.servo_gap * 1e9
    );
    outcome
}

#[test]
fn a_three_axis_mill_is_compensated_down_to_the_fit_uncertainty() {
    let o = closed_loop(MILL3, 20.0, 600, 3);
    assert!(o.before > 30e-6, "the errors are not small: {}", o.before);
    assert!(o.after < 1e-6, "{}", o.after);
    // Products of two errors of tens of µm and µrad over half a metre: well under 10 nm.
    assert!(o.servo_gap < 10e-9, "{}", o.servo_gap);
}

#[test]
fn the_five_axis_example_is_compensated_down_to_the_fit_uncertainty() {
    let src = include_str!("../../../examples/milling_5axis.kin");
    let o = closed_loop(src, 20.0, 3000, 11);
    assert!(o.before > 50e-6, "the errors are not small: {}", o.before);
    assert!(o.after < 2e-6, "{}", o.after);
    assert!(o.servo_gap < 10e-9, "{}", o.servo_gap);
}
