//! The diagnosis on data with a hidden effect: the right candidate must rank first.

use kin_compiler::{compile, Compiled};
use kin_runtime::data::Observations;
use kin_runtime::diagnose::{self, Family, Settings};
use kin_runtime::fit::{self, DataSet, Options};
use kin_runtime::interp::Interpreter;
use kin_runtime::simulate::{self, sample_points};

const BASE: &str = r#"
machine cmm3 {
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

fn compiled(src: &str) -> Compiled {
    let out = compile(src);
    out.compiled
        .unwrap_or_else(|| panic!("{:#?}", out.diagnostics))
}

/// Simulates `truth` (the base plus a hidden line), fits `BASE`, diagnoses.
fn case(hidden: &str, values: &[(&str, f64)], seed: u64) -> diagnose::Diagnosis {
    let truth_src = BASE.replace(
        "        Z.tz = linear(Z)\n",
        &format!("        Z.tz = linear(Z)\n        {hidden}\n"),
    );
    let truth = compiled(&truth_src);
    let mut beta = vec![0.0; truth.machine.coefficients.len()];
    for (name, v) in values {
        let j = truth
            .machine
            .coefficients
            .iter()
            .position(|c| c.name == *name)
            .unwrap_or_else(|| panic!("no {name}"));
        beta[j] = v * truth.machine.coefficients[j].unit.scale;
    }
    let base = compiled(BASE);
    let poses = sample_points(&truth.machine, 600, seed);
    let obs = simulate::simulate(
        &truth.machine,
        &beta,
        &Observations::Points(poses),
        &simulate::Options {
            noise: 0.2e-6,
            seed: seed + 1,
            ..simulate::Options::default()
        },
    )
    .unwrap();
    let files = [DataSet {
        path: "data.csv".into(),
        observations: obs,
    }];
    let mut it = Interpreter::new(&base.machine).unwrap();
    let r = fit::fit(
        &base,
        &mut it,
        &files,
        &[],
        &Options::default(),
        &mut |_, _| {},
    )
    .expect("fit");
    diagnose::diagnose(
        &base,
        BASE,
        &files,
        &r,
        &Options::default(),
        &Settings::default(),
    )
    .expect("diagnose")
}

#[test]
fn nothing_hidden_nothing_found() {
    let d = case("", &[("X.tx[0]", 3.0), ("Y.ty[1]", 0.5)], 1);
    let sig: Vec<&str> = d
        .findings
        .iter()
        .filter(|f| f.significant)
        .map(|f| f.candidate.text.as_str())
        .collect();
    assert!(sig.is_empty(), "false alarms: {sig:?}");
    assert!(
        d.regions.is_empty(),
        "{:?}",
        d.regions.iter().map(|r| &r.text).collect::<Vec<_>>()
    );
}

#[test]
fn a_hidden_backlash_of_x_is_found_first() {
    let d = case(
        "X.tx += backlash(X)",
        &[("X.tx[0]", 3.0), ("X.tx[4]", 1.0)],
        2,
    );
    let top = d.findings.first().expect("findings");
    assert!(top.significant, "{top:?}");
    assert_eq!(
        top.candidate.family,
        Family::Backlash,
        "{:?}",
        d.findings
            .iter()
            .take(3)
            .map(|f| (&f.candidate.text, f.explained))
            .collect::<Vec<_>>()
    );
    assert_eq!(top.candidate.target, "X.tx");
}
