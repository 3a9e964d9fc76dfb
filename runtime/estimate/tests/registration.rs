//! Absolute measurements of an arm by a tracker in its own frame (spec/data.md, "Absolute
//! positions"): the instrument's placement and the targets' offsets on the flange are finite
//! unknowns fitted jointly with the error model. Truth by the exact simulator (finite
//! transforms everywhere), never by the first-order model being fitted.

use kin_compiler::{compile, Compiled};
use kin_data::data::{Absolute, Groups, Observations, PointData, Pose, Rows};
use kin_estimate::fit::{self, DataSet, FitResult, NuisanceKind, Options};
use kin_estimate::register::{self, Registration};
use kin_model::engine::{self, Engine};
use kin_model::exact;
use kin_model::interp::{Interpreter, State};
use kin_model::kinematics::{FrameErrors, Pose as KPose};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

/// A UR10-class arm measured by a tracker (examples/ur10): J2..J5 zero offsets and two link
/// lengths as the error model.
const ARM: &str = include_str!("../../../examples/ur10/ur10.kin");

const NOISE: f64 = 50e-6;
/// Orientation noise of a 6-DoF reading, rad.
const TURN_NOISE: f64 = 100e-6;

struct Truth {
    beta: Vec<f64>,
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    targets: Vec<[f64; 3]>,
    /// Per target, its frame's turn on the tool when the instrument reads orientations.
    turns: Option<Vec<Matrix3<f64>>>,
}

fn truth(targets: Vec<[f64; 3]>) -> Truth {
    Truth {
        // J2..J5 offsets (rad), J3 and J4 length errors (m).
        beta: vec![4e-4, -3e-4, 5e-4, -2e-4, 3e-4, -2e-4],
        rotation: Rotation3::new(Vector3::new(0.02, -0.05, 0.04)).into_inner(),
        translation: Vector3::new(0.08, -0.05, 0.04),
        targets,
        turns: None,
    }
}

fn compiled() -> Compiled {
    let out = compile(ARM);
    out.compiled
        .unwrap_or_else(|| panic!("{:?}", out.diagnostics))
}

/// `n` poses, each measured at every target: the tracker's reading of the actual target
/// position (exact transforms), with noise.
fn measure(c: &Compiled, truth: &Truth, n: usize, seed: u64) -> DataSet {
    let m = &c.machine;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut it = Interpreter::new(m).unwrap_or_else(|e| panic!("{e}"));
    let mut errors = FrameErrors::zeros(m);
    let mut axes = vec![Vec::new(); 6];
    let mut position: [Vec<f64>; 3] = Default::default();
    let mut turned: [Vec<f64>; 3] = Default::default();
    let mut of_row = Vec::new();
    for _ in 0..n {
        let q: Vec<f64> = (0..6).map(|_| rng.random_range(-2.5..2.5)).collect();
        let dirs = [f64::NAN; 6];
        for (t, o) in truth.targets.iter().enumerate() {
            let state = State {
                q: &q,
                inputs: &[],
                lags: &[],
                time: 0.0,
                dirs: &dirs,
                tool: 0,
                tool_offset: Some(*o),
            };
            it.frame_errors(&state, &truth.beta, &mut errors)
                .unwrap_or_else(|e| panic!("{e}"));
            let pose = KPose {
                q: &q,
                tool: 0,
                tool_offset: Some(*o),
            };
            let actual =
                exact::actual_transform(m, &pose, &errors).unwrap_or_else(|e| panic!("{e}"));
            let p = Vector3::new(actual[(0, 3)], actual[(1, 3)], actual[(2, 3)]);
            let y = truth.rotation * p + truth.translation;
            for (c, column) in position.iter_mut().enumerate() {
                let e: f64 = rng.sample(StandardNormal);
                column.push(y[c] + NOISE * e);
            }
            if let Some(turns) = &truth.turns {
                let r_act = actual.fixed_view::<3, 3>(0, 0).into_owned();
                let noise =
                    Vector3::from_fn(|_, _| TURN_NOISE * rng.sample::<f64, _>(StandardNormal));
                let r_y = Rotation3::new(noise).into_inner() * truth.rotation * r_act * turns[t];
                let v = Rotation3::from_matrix_unchecked(r_y).scaled_axis();
                for (c, column) in turned.iter_mut().enumerate() {
                    column.push(v[c]);
                }
            }
            for (a, column) in axes.iter_mut().enumerate() {
                column.push(q[a]);
            }
            of_row.push(t as u32);
        }
    }
    let rows = of_row.len();
    DataSet {
        path: format!("tracker-{seed}.csv").into(),
        observations: Observations::Points(PointData {
            rows: Rows {
                line: (2..rows + 2).collect(),
                tool: vec![0; rows],
                ..Rows::default()
            },
            pose: Pose {
                axes,
                dir: vec![None; 6],
            },
            observed: Default::default(),
            absolute: Some(Absolute {
                position,
                rotation: truth.turns.as_ref().map(|_| turned),
                target: Groups {
                    of_row,
                    labels: (0..truth.targets.len()).map(|t| format!("T{t}")).collect(),
                },
            }),
        }),
    }
}

fn options() -> Options {
    Options {
        threads: 1,
        ..Options::default()
    }
}

fn fit_registered(c: &Compiled, data: &DataSet) -> (Registration, FitResult) {
    let mut engine = engine::make(&c.machine, Engine::Interp).unwrap_or_else(|e| panic!("{e}"));
    let files = std::slice::from_ref(data);
    let reg = register::register(c, engine.as_mut(), files, &options(), &mut |_, _| {})
        .unwrap_or_else(|e| panic!("{e}"));
    let result = fit::fit(
        c,
        engine.as_mut(),
        &reg.files,
        &[],
        &options(),
        &mut |_, _| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    (reg, result)
}

/// The standard error of the nuisance parameter of `kind` (and target label).
fn se_of(r: &FitResult, kind: NuisanceKind, label: &str) -> f64 {
    let var = r.variances();
    let n = r.layout.coefficients;
    let k = r
        .layout
        .nuisance
        .iter()
        .position(|nu| nu.kind == kind && (nu.artifact == label))
        .unwrap_or_else(|| panic!("no {kind:?} {label}"));
    var[n + k].sqrt()
}

fn check(targets: Vec<[f64; 3]>, seed: u64) {
    let c = compiled();
    let truth = truth(targets);
    let data = measure(&c, &truth, 50, seed);
    let (reg, result) = fit_registered(&c, &data);
    let var = result.variances();
    println!(
        "{} targets: {} Gauss-Newton steps, sigma {:.2e} m, placement t {:?}",
        truth.targets.len(),
        reg.steps,
        result.sigma,
        reg.placements[0].translation
    );
    assert!(reg.steps <= 10, "{} steps", reg.steps);
    // The error model: every coefficient within 3 standard errors of the truth.
    for (j, (b, t)) in result.solution.beta.iter().zip(&truth.beta).enumerate() {
        let se = var[j].sqrt();
        println!(
            "  {}: {b:.4e} (truth {t:.4e}) ± {se:.1e}",
            c.machine.coefficients[j].name
        );
        assert!(
            (b - t).abs() <= 3.0 * se,
            "{}: {b:e} vs {t:e} ± {se:e}",
            c.machine.coefficients[j].name
        );
    }
    // The placement: translation and rotation within 3 standard errors per axis. The fit's
    // rotation change is R ← R·exp([a]×), so the error of the estimate is log(R⊤ R_true).
    let p = &reg.placements[0];
    let r = Matrix3::from_fn(|i, j| p.rotation[i][j]);
    let dr = Rotation3::from_matrix_unchecked(r.transpose() * truth.rotation).scaled_axis();
    // The shift b of t = t + R b, in wr axes.
    let dt = r.transpose() * (truth.translation - Vector3::from(p.translation));
    for k in 0..3 {
        let se_r = se_of(&result, NuisanceKind::InstrumentRotation(k), "");
        let se_t = se_of(&result, NuisanceKind::InstrumentShift(k), "");
        assert!(
            dr[k].abs() <= 3.0 * se_r,
            "rotation {k}: {} ± {se_r}",
            dr[k]
        );
        assert!(dt[k].abs() <= 3.0 * se_t, "shift {k}: {} ± {se_t}", dt[k]);
        assert!(se_t < NOISE, "shift {k} ± {se_t}");
    }
    for (t, truth_o) in truth.targets.iter().enumerate() {
        let label = format!("T{t}");
        let (_, o) = p
            .targets
            .iter()
            .find(|(l, _)| *l == label)
            .unwrap_or_else(|| panic!("no {label}"));
        for k in 0..3 {
            let se = se_of(&result, NuisanceKind::Target(k), &label);
            assert!(
                (o[k] - truth_o[k]).abs() <= 3.0 * se,
                "{label} {k}: {} vs {} ± {se}",
                o[k],
                truth_o[k]
            );
        }
    }
    // Held-out poses, measured the same way, predicted at the noise.
    let held = measure(&c, &truth, 50, seed + 1000);
    let held = DataSet {
        path: data.path.clone(),
        ..held
    };
    let mut engine = engine::make(&c.machine, Engine::Interp).unwrap_or_else(|e| panic!("{e}"));
    let held =
        register::observe_with(engine.as_mut(), &reg, &[held]).unwrap_or_else(|e| panic!("{e}"));
    let checked = fit::fit(
        &c,
        engine.as_mut(),
        &reg.files,
        &held,
        &options(),
        &mut |_, _| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let n = checked.validation.len() as f64;
    let rms = (checked
        .validation
        .iter()
        .map(|r| r.residual.powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    // Position rows weigh 1 without a stated noise: residuals in m.
    let rms_m = rms;
    println!("held-out RMS {rms_m:.3e} m over {n} values (noise {NOISE:e})");
    // Held-out rows are predicted with the fitted placement, not placed again: readings of a
    // tracker that moved by 1 mm since do not fit.
    let mut moved = measure(&c, &truth, 20, seed + 2000);
    moved.path = data.path.clone();
    if let Observations::Points(PointData {
        absolute: Some(a), ..
    }) = &mut moved.observations
    {
        a.position[0].iter_mut().for_each(|x| *x += 1e-3);
    }
    let moved =
        register::observe_with(engine.as_mut(), &reg, &[moved]).unwrap_or_else(|e| panic!("{e}"));
    let off = fit::fit(
        &c,
        engine.as_mut(),
        &reg.files,
        &moved,
        &options(),
        &mut |_, _| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let worst = off
        .validation
        .iter()
        .map(|r| r.residual.abs())
        .fold(0.0, f64::max);
    assert!(
        worst > 5e-4,
        "a moved tracker was placed again: {worst:e} m"
    );
    assert!(
        rms_m < 1.25 * NOISE && rms_m > 0.75 * NOISE,
        "held-out RMS {rms_m:e} m against noise {NOISE:e}"
    );
}

#[test]
fn a_six_dof_probe_registers_its_frame_and_orientation_too() {
    let c = compiled();
    let mut truth = truth(vec![[0.04, 0.06, 0.11]]);
    let turn = Rotation3::new(Vector3::new(0.3, -0.5, 2.0)).into_inner();
    truth.turns = Some(vec![turn]);
    let data = measure(&c, &truth, 50, 3);
    let (reg, result) = fit_registered(&c, &data);
    let var = result.variances();
    assert!(reg.steps <= 10, "{} steps", reg.steps);
    for (j, (b, t)) in result.solution.beta.iter().zip(&truth.beta).enumerate() {
        let se = var[j].sqrt();
        assert!(
            (b - t).abs() <= 3.0 * se,
            "{}: {b:e} vs {t:e} ± {se:e}",
            c.machine.coefficients[j].name
        );
    }
    // The target frame's turn on the tool: the estimate's error log(R_o_est⊤·R_o_true),
    // about the tool frame's axes (the fit's turn ρ acts as exp([ρ]×)·R_o).
    let p = &reg.placements[0];
    let est = Matrix3::from_fn(|i, j| p.turns[0][i][j]);
    let err = Rotation3::from_matrix_unchecked(turn * est.transpose()).scaled_axis();
    for k in 0..3 {
        let se = se_of(&result, NuisanceKind::TargetRotation(k), "T0");
        assert!(err[k].abs() <= 3.0 * se, "turn {k}: {} ± {se}", err[k]);
        assert!(se < 1e-4, "turn {k} ± {se}");
    }
    // The orientation residuals are at the orientation noise (a tilt unit weighs as an error
    // unit, µrad as µm: rows in rad).
    let rot: Vec<f64> = result
        .residuals
        .iter()
        .filter(|r| r.meta.component >= 3)
        .map(|r| r.residual)
        .collect();
    assert_eq!(rot.len(), 150);
    let rms = (rot.iter().map(|r| r * r).sum::<f64>() / rot.len() as f64).sqrt();
    println!("orientation residual RMS {rms:.3e} rad (noise {TURN_NOISE:e})");
    assert!(rms > 0.7 * TURN_NOISE && rms < 1.2 * TURN_NOISE, "{rms}");
}

#[test]
fn a_tracker_with_one_target_per_pose_is_registered_with_the_arm() {
    check(vec![[0.04, 0.06, 0.11]], 1);
}

#[test]
fn three_targets_per_pose_are_registered_each() {
    check(
        vec![[0.1, 0.0, 0.08], [-0.05, 0.09, 0.08], [-0.05, -0.09, 0.08]],
        2,
    );
}

/// A tracker moved between two stations, the same two named reflectors on the flange seen from
/// both: each file gets its own instrument placement, the targets one offset each across the
/// files (what the reflectors are). Both placements and the shared offsets come out within 3
/// standard errors of the truth, every file reports the same offsets, and sharing beats
/// fitting each station's targets apart (the same rows with the second file's labels renamed).
#[test]
fn named_targets_seen_from_two_stations_are_one_target_each() {
    let c = compiled();
    let targets = vec![[0.1, 0.0, 0.08], [-0.05, 0.09, 0.08]];
    let first = truth(targets.clone());
    let mut second = truth(targets.clone());
    second.rotation = Rotation3::new(Vector3::new(-0.03, 0.04, 1.2)).into_inner();
    second.translation = Vector3::new(-1.5, 2.0, 0.3);
    let a = measure(&c, &first, 12, 21);
    let b = measure(&c, &second, 12, 22);
    let mut engine = engine::make(&c.machine, Engine::Interp).unwrap_or_else(|e| panic!("{e}"));
    let run = |engine: &mut dyn kin_model::engine::Evaluator, files: &[DataSet]| {
        let reg = register::register(&c, engine, files, &options(), &mut |_, _| {})
            .unwrap_or_else(|e| panic!("{e}"));
        let result = fit::fit(&c, engine, &reg.files, &[], &options(), &mut |_, _| {})
            .unwrap_or_else(|e| panic!("{e}"));
        (reg, result)
    };
    let files = [a.clone(), b.clone()];
    let (reg, result) = run(engine.as_mut(), &files);
    let report = register::report(&c.machine, &reg, &result);
    assert_eq!(report.len(), 2);
    // One set of columns per named target: 2 instruments × 6 + 2 targets × 3.
    assert_eq!(result.layout.nuisance.len(), 2 * 6 + 2 * 3);
    for (t, truth) in targets.iter().enumerate() {
        let (x, y) = (&report[0].targets[t], &report[1].targets[t]);
        assert_eq!(x.offset, y.offset, "one offset for {}", x.label);
        assert_eq!(x.offset_u, y.offset_u);
        for ((o, u), t) in x.offset.iter().zip(&x.offset_u).zip(truth) {
            // Display unit mm.
            let miss = (o - t * 1e3).abs();
            assert!(miss <= 3.0 * u, "{}: {miss} mm ± {u}", x.label);
        }
    }
    for (p, truth) in reg.placements.iter().zip([&first, &second]) {
        let miss = (Vector3::from(p.translation) - truth.translation).amax();
        assert!(miss < 1e-3, "{}: {miss} m", p.path.display());
    }
    // The same rows, the second station's reflectors named apart: four targets, larger errors.
    let mut apart = b.clone();
    if let Observations::Points(PointData {
        absolute: Some(abs),
        ..
    }) = &mut apart.observations
    {
        abs.target.labels = vec!["U0".into(), "U1".into()];
    }
    let (_, alone) = run(engine.as_mut(), &[a, apart]);
    let shared = se_of(&result, NuisanceKind::Target(0), "T0");
    let separate = se_of(&alone, NuisanceKind::Target(0), "T0");
    println!("T0 offset x: shared ± {shared:.2e} m, per station ± {separate:.2e} m");
    assert!(shared < separate, "{shared} vs {separate}");
}
