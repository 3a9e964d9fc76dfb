//! `kin export c` end to end: the bundled CMM exported with its parameter file, the file
//! compiled by the system's C compiler with a program that evaluates it at sampled states
//! (β passed as NULL: the exported values), and every number compared with the embedding API's
//! evaluation of the same model and parameters.

use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use kin_model::states::States;
use kin_model::Model;

fn kin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

/// A C array of doubles, each written to read back to its bits.
fn array(name: &str, values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!(
        "static const double {name}[{}] = {{{}}};\n",
        values.len().max(1),
        if items.is_empty() {
            "0.0".to_string()
        } else {
            items.join(", ")
        }
    )
}

#[test]
fn the_exported_c_evaluates_the_fitted_model() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let machine = root.join("examples/bridge_cmm.kin");
    let params = root.join("examples/data/bridge_cmm_truth.params");
    let dir = tempfile::tempdir().expect("a temporary directory");
    let source = dir.path().join("cmm.c");
    let out = kin(&[
        "export",
        "c",
        machine.to_str().expect("utf-8"),
        "--params",
        params.to_str().expect("utf-8"),
        "-o",
        source.to_str().expect("utf-8"),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("exported `bridge_cmm` as C source"),
        "{stdout}"
    );

    let text = std::fs::read_to_string(&machine).expect("machine")
        + &std::fs::read_to_string(&params).expect("params");
    let model = Model::compile(&text).expect("compiles");
    let m = model.machine();
    let n = model.coefficients();
    assert!(
        model.beta().iter().any(|b| *b != 0.0),
        "the parameters bind β"
    );
    let states = States::sample(m, 50, 11);
    // The program: every state's arrays, each function called with β NULL, the results printed
    // with 17 significant digits (enough to read back every double).
    let mut c = String::from("#include <stdio.h>\n#include <stddef.h>\n");
    let (na, ni, nl) = (m.axes.len(), m.inputs.len(), m.lags.len());
    let gather =
        |f: &dyn Fn(usize) -> Vec<f64>| -> Vec<f64> { (0..states.len()).flat_map(f).collect() };
    c += &array("q", &gather(&|r| states.get(r).q.to_vec()));
    c += &array("inputs", &gather(&|r| states.get(r).inputs.to_vec()));
    c += &array("lags", &gather(&|r| states.get(r).lags.to_vec()));
    c += &array("dirs", &gather(&|r| states.get(r).dirs.to_vec()));
    c += &array("times", &gather(&|r| vec![states.get(r).time]));
    let tools: Vec<String> = (0..states.len())
        .map(|r| states.get(r).tool.to_string())
        .collect();
    let _ = writeln!(
        c,
        "static const size_t tools[{}] = {{{}}};",
        tools.len(),
        tools.join(", ")
    );
    let _ = write!(
        c,
        "int bridge_cmm_error(const double *, const double *, const double *, const double *,
    double, size_t, const double *, double *);
int bridge_cmm_jacobian_position(const double *, const double *, const double *,
    const double *, double, size_t, const double *, double *, double *);
int main(void) {{
    static double jac[3 * {n}];
    for (size_t r = 0; r < {rows}; r++) {{
        double err[6], pos[3];
        if (bridge_cmm_error(q + {na} * r, inputs + {ni} * r, lags + {nl} * r, dirs + {na} * r,
                times[r], tools[r], NULL, err) != 0)
            return 1;
        if (bridge_cmm_jacobian_position(q + {na} * r, inputs + {ni} * r, lags + {nl} * r,
                dirs + {na} * r, times[r], tools[r], NULL, pos, jac) != 0)
            return 1;
        for (int k = 0; k < 6; k++) printf(\"%.17g \", err[k]);
        for (int k = 0; k < 3; k++) printf(\"%.17g \", pos[k]);
        for (int k = 0; k < 3 * {n}; k++) printf(\"%.17g \", jac[k]);
        printf(\"\\n\");
    }}
    return 0;
}}
",
        rows = states.len()
    );
    let main = dir.path().join("main.c");
    std::fs::write(&main, c).expect("written");
    let program = dir.path().join("evaluate");
    let status = Command::new("cc")
        .args([
            "-std=c99",
            "-O1",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-ffp-contract=off",
            "-o",
        ])
        .arg(&program)
        .arg(&main)
        .arg(&source)
        .arg("-lm")
        .status()
        .expect("the C compiler runs");
    assert!(status.success(), "the exported C does not compile");
    let run = Command::new(&program).output().expect("the program runs");
    assert!(run.status.success(), "the program failed");
    let printed = String::from_utf8_lossy(&run.stdout).into_owned();
    let lines: Vec<&str> = printed.lines().collect();
    assert_eq!(lines.len(), states.len());
    let mut worst: f64 = 0.0;
    let mut compare = |a: f64, b: f64| {
        let d = (a - b).abs() / (1.0 + b.abs());
        worst = worst.max(if d.is_nan() { f64::INFINITY } else { d });
    };
    for (r, line) in lines.iter().enumerate() {
        let values: Vec<f64> = line
            .split_whitespace()
            .map(|v| v.parse().expect("a number"))
            .collect();
        assert_eq!(values.len(), 9 + 3 * n);
        let st = states.get(r);
        let mut err = [0.0; 6];
        model.eval(&st, model.beta(), &mut err).expect("eval");
        let (mut e6, mut jac) = ([0.0; 6], vec![0.0; 6 * n]);
        model
            .eval_jacobian(&st, model.beta(), &mut e6, &mut jac)
            .expect("eval_jacobian");
        for k in 0..6 {
            compare(values[k], err[k]);
        }
        for k in 0..3 {
            compare(values[6 + k], e6[k]);
        }
        for k in 0..3 * n {
            compare(values[9 + k], jac[k]);
        }
    }
    assert!(worst <= 1e-12, "the C source differs from kin by {worst:e}");
}

#[test]
fn export_c_writes_the_nominal_machine_to_standard_output_and_never_over_an_input() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().expect("a temporary directory");
    let machine = dir.path().join("table.kin");
    std::fs::copy(root.join("examples/xy_table.kin"), &machine).expect("copied");
    let before = std::fs::read(&machine).expect("read");
    let path = machine.to_str().expect("utf-8");
    let out = kin(&["export", "c", path]);
    assert!(out.status.success());
    // Standard output is the file alone; the summary goes to standard error.
    let c = String::from_utf8_lossy(&out.stdout);
    assert!(
        c.starts_with("/* The evaluator of machine `xy_table`"),
        "{c}"
    );
    assert!(c.contains("#define XY_TABLE_COEFFICIENTS 2"), "{c}");
    // No parameter values bound: the nominal machine's β.
    assert!(
        c.contains("static const double xy_table_beta[2] = {\n    0.0, 0.0,\n};"),
        "{c}"
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("exported `xy_table` as C source"),
        "{stderr}"
    );
    let out = kin(&["export", "c", path, "-o", path]);
    assert!(!out.status.success(), "wrote over its input");
    assert_eq!(std::fs::read(&machine).expect("read"), before);
}
