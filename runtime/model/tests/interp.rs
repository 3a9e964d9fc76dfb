//! The interpreter on the bundled examples: linear structure, and agreement with the exact
//! simulator to second order in the size of the errors.

use kin_compiler::compile;
use kin_compiler::ir::Machine;
use kin_model::exact;
use kin_model::interp::Interpreter;
use kin_model::kinematics::{FrameErrors, Pose};
use kin_model::states::States;
use rand::{Rng, SeedableRng};

fn example(name: &str) -> Machine {
    let path = format!("{}/../../examples/{name}.kin", env!("CARGO_MANIFEST_DIR"));
    let src = std::fs::read_to_string(&path).expect("example readable");
    let out = compile(&src);
    out.compiled
        .unwrap_or_else(|| panic!("{name}: {:#?}", out.diagnostics))
        .machine
}

const EXAMPLES: [&str; 3] = ["bridge_cmm", "milling_5axis", "robot_6axis"];

/// Random β giving parametric errors of roughly `size` (m or rad) over the ranges: basis
/// functions are O(1) on the range, so coefficients of that size do.
fn random_beta(m: &Machine, size: f64, seed: u64) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    m.coefficients
        .iter()
        .map(|c| {
            // Coefficients of scaled terms (um/K, urad/N …) are divided by the typical scale.
            let per = if c.unit.dim.temperature != 0 {
                2.0
            } else if c.unit.dim.force != 0 {
                1000.0
            } else {
                1.0
            };
            size * rng.random_range(-1.0..1.0) / per
        })
        .collect()
}

/// Neutralises the known (fixed) terms: absolute temperatures at 20 °C.
fn neutral_states(m: &Machine, n: usize, seed: u64) -> States {
    let mut s = States::sample(m, n, seed);
    for (i, input) in m.inputs.iter().enumerate() {
        if input.absolute {
            s.set_input(i, 293.15);
        }
    }
    s
}

#[test]
fn error_is_fixed_plus_jacobian_times_beta() {
    for name in EXAMPLES {
        let m = example(name);
        let n = m.coefficients.len();
        let beta = random_beta(&m, 1e-5, 1);
        let zero = vec![0.0; n];
        let states = States::sample(&m, 50, 2);
        let mut it = Interpreter::new(&m).expect("interpreter");
        let mut jac = vec![0.0; 6 * n];
        let mut jac0 = vec![0.0; 6 * n];
        for r in 0..states.len() {
            let s = states.get(r);
            let mut e = [0.0; 6];
            let mut e0 = [0.0; 6];
            it.error_and_jacobian(&s, &beta, &mut e, &mut jac)
                .expect("eval");
            it.error_and_jacobian(&s, &zero, &mut e0, &mut jac0)
                .expect("eval");
            assert_eq!(jac, jac0, "{name}: the Jacobian does not depend on β");
            let plain = it.error(&s, &beta).expect("eval");
            for c in 0..6 {
                let row: f64 = (0..n).map(|j| jac[c * n + j] * beta[j]).sum();
                let want = e0[c] + row;
                assert!(
                    (e[c] - want).abs() <= 1e-12 * (1.0 + want.abs()) + 1e-18,
                    "{name} comp {c}: {} vs {want}",
                    e[c]
                );
                assert!(
                    (plain[c] - e[c]).abs() <= 1e-12 * e[c].abs() + 1e-18,
                    "{name}: error() and error_and_jacobian() differ"
                );
            }
        }
    }
}

/// The largest difference, over sampled poses, between the interpreter's first-order error and
/// the exact simulator fed the same parametric errors.
fn gap(m: &Machine, beta: &[f64], states: &States) -> f64 {
    let mut it = Interpreter::new(m).expect("interpreter");
    let mut fe = FrameErrors::zeros(m);
    let mut worst: f64 = 0.0;
    for r in 0..states.len() {
        let s = states.get(r);
        it.frame_errors(&s, beta, &mut fe).expect("frame errors");
        let first = it.error(&s, beta).expect("eval");
        let pose = Pose {
            q: s.q,
            tool: s.tool,
            tool_offset: s.tool_offset,
        };
        let ex = exact::positioning_error(m, &pose, &fe).expect("exact") * m.task.sign();
        for c in 0..6 {
            worst = worst.max((first[c] - ex[c]).abs());
        }
    }
    worst
}

#[test]
fn first_order_agrees_with_exact_to_second_order_on_every_example() {
    for name in EXAMPLES {
        let m = example(name);
        let states = neutral_states(&m, 200, 7);
        for seed in 0..3 {
            let beta = random_beta(&m, 2e-4, 100 + seed);
            let half: Vec<f64> = beta.iter().map(|b| b / 2.0).collect();
            let g1 = gap(&m, &beta, &states);
            let g2 = gap(&m, &half, &states);
            // Errors of 2e-4 on a metre-sized machine: a second-order gap around 1e-8 m, far
            // above rounding (1e-16 × 1 m), so the ratio is clean.
            assert!(g1 > 1e-12, "{name}: gap {g1} too small to test");
            let ratio = g1 / g2;
            assert!(
                (3.6..4.4).contains(&ratio),
                "{name} seed {seed}: gap {g1:e} → {g2:e}, ratio {ratio}"
            );
        }
    }
}

#[test]
fn missing_direction_is_a_named_error() {
    let m = example("bridge_cmm");
    let s = States::sample(&m, 1, 3);
    let st = s.get(0);
    let dirs = vec![f64::NAN; m.axes.len()];
    let state = kin_model::interp::State { dirs: &dirs, ..st };
    let mut it = Interpreter::new(&m).expect("interpreter");
    let beta = vec![0.0; m.coefficients.len()];
    let err = it.error(&state, &beta).unwrap_err();
    assert_eq!(
        err.to_string(),
        "the model uses `dir_Y`, which this observation does not give"
    );
}
