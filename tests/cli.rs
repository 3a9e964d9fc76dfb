//! End-to-end runs of the `kin` binary: simulate data with a known truth, evaluate the model on
//! it, and the located errors a user sees for bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("kin runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kin-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Data rows of a CSV written by kin, as numbers per named column.
fn column(path: &Path, name: &str) -> Vec<f64> {
    let s = std::fs::read_to_string(path).expect("csv");
    let mut lines = s.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let k = header
        .iter()
        .position(|h| h.split('[').next() == Some(name))
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    lines
        .map(|l| l.split(',').nth(k).expect("cell").parse().expect("number"))
        .collect()
}

const PARAMS: &str = "params {\n    Y.rz = [3, -2, 1, 0.5, 0.2, 4] urad\n    X.ty = [1.5, -0.5, 0.8, 0.3] um\n    X.tx[0] = 2 um\n    Z.tz.tau = 35 min\n}\n";

#[test]
fn check_prints_a_summary_for_every_example() {
    for name in ["bridge_cmm", "milling_5axis", "robot_6axis"] {
        let out = kin(&["check", &format!("examples/{name}.kin")]);
        assert!(out.status.success(), "{name}: {}", text(&out.stderr));
        let stdout = text(&out.stdout);
        assert!(
            stdout.contains("checks clean") && stdout.contains("coefficients"),
            "{stdout}"
        );
    }
    let json = kin(&["check", "examples/milling_5axis.kin", "--format", "json"]);
    let v: serde_json::Value = serde_json::from_slice(&json.stdout).expect("json");
    assert_eq!(v["ok"], true);
    assert!(v["summary"]["coefficients"].as_u64().unwrap() >= 150);
}

#[test]
fn simulate_then_eval_agree_to_second_order() {
    let params = tmp("truth.params");
    std::fs::write(&params, PARAMS).unwrap();
    let sim = tmp("sim.csv");
    let out = kin(&[
        "simulate",
        "examples/bridge_cmm.kin",
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "40",
        "--seed",
        "9",
        "-o",
        sim.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let eval = tmp("eval.csv");
    let out = kin(&[
        "eval",
        "examples/bridge_cmm.kin",
        sim.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--components",
        "position",
        "-o",
        eval.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for c in ["ex", "ey", "ez"] {
        let exact = column(&sim, c);
        let first = column(&eval, c);
        assert_eq!(exact.len(), 40);
        let scale = exact.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(
            scale > 0.5 || c != "ey",
            "the truth produces micrometre errors in y"
        );
        for (a, b) in exact.iter().zip(&first) {
            // Errors of a few µm over a metre: the first-order model is exact to ~1e-5 µm.
            assert!((a - b).abs() < 1e-4, "{c}: exact {a} vs first-order {b}");
        }
    }
}

#[test]
fn simulated_noise_has_the_requested_size() {
    let sim = tmp("noise.csv");
    let zero = tmp("zero.csv");
    for (path, noise) in [(&sim, "0.5um"), (&zero, "0um")] {
        let out = kin(&[
            "simulate",
            "examples/bridge_cmm.kin",
            "--sample",
            "2000",
            "--seed",
            "1",
            "--noise",
            noise,
            "-o",
            path.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
    }
    let a = column(&sim, "ex");
    let b = column(&zero, "ex");
    let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt();
    assert!((sd - 0.5).abs() < 0.05, "noise sd {sd}");
    assert!(mean.abs() < 0.05, "noise mean {mean}");
}

#[test]
fn a_bad_params_file_is_located() {
    let params = tmp("bad.params");
    std::fs::write(&params, "params {\n    Y.rz = [3, -2] urad\n}\n").unwrap();
    let out = kin(&[
        "simulate",
        "examples/bridge_cmm.kin",
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "3",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        err.contains("E0501") && err.contains("`Y.rz` has 6 coefficients, but 2 values are given"),
        "{err}"
    );
    assert!(err.contains("bad.params:2:12"), "points at the list: {err}");
}

#[test]
fn a_bad_measurement_cell_names_file_line_and_column() {
    let csv = tmp("bad.csv");
    std::fs::write(&csv, "# poses\nY,X,Z,ex\n10,20,-30,0.1\n10,2O,-30,0.2\n").unwrap();
    let out = kin(&["eval", "examples/bridge_cmm.kin", csv.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        err.contains("bad.csv") && err.contains("line 4, column 4") && err.contains("2O"),
        "{err}"
    );
}

#[test]
fn a_missing_column_the_model_needs_is_named() {
    // The bridge model uses backlash of Y and a lag of T_room: a poses file without them fails
    // with the column named, not with a wrong number.
    let csv = tmp("nodir.csv");
    std::fs::write(&csv, "Y,X,Z\n10,20,-30\n").unwrap();
    let out = kin(&["eval", "examples/bridge_cmm.kin", csv.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(err.contains("the file has no such column"), "{err}");
}

#[test]
fn fit_recovers_the_truth_and_its_parameters_load_back() {
    let params = tmp("fit-truth.params");
    std::fs::write(&params, PARAMS).unwrap();
    let sim = tmp("fit-data.csv");
    let out = kin(&[
        "simulate",
        "examples/bridge_cmm.kin",
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "1500",
        "--noise",
        "0.2um",
        "--seed",
        "4",
        "-o",
        sim.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report = tmp("fit.json");
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        sim.to_str().unwrap(),
        "-o",
        report.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.contains("σ̂ = ") && stdout.contains("error component"),
        "{stdout}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let sigma = v["sigma"].as_f64().unwrap();
    assert!((sigma - 0.2).abs() < 0.02, "σ̂ {sigma} µm for 0.2 µm noise");
    assert_eq!(v["rank"], v["columns"]);
    let coef = |name: &str| {
        v["coefficients"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["name"] == name)
            .cloned()
            .unwrap()
    };
    let x0 = coef("X.tx[0]");
    assert!(
        ((x0["value"].as_f64().unwrap() - 2.0) / x0["se"].as_f64().unwrap()).abs() < 4.0,
        "{x0}"
    );
    // The fitted parameters (FIT.json or FIT.params) load into eval: predictions match the
    // data to the noise.
    let eval = tmp("fit-eval.csv");
    let out = kin(&[
        "eval",
        "examples/bridge_cmm.kin",
        sim.to_str().unwrap(),
        "--params",
        report.to_str().unwrap(),
        "--components",
        "position",
        "-o",
        eval.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (a, b) = (column(&sim, "ey"), column(&eval, "ey"));
    let rms = (a.iter().zip(&b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
    assert!(rms < 0.25, "residual RMS {rms} µm");
    assert!(report.with_extension("params").exists());
}

#[test]
fn fit_names_a_bad_cell_and_an_invisible_term() {
    let csv = tmp("fit-nan.csv");
    std::fs::write(
        &csv,
        "Y,X,Z,dir_Y,T_scale,T_room,time,ex\n1,2,-3,+1,20,1,0,NaN\n",
    )
    .unwrap();
    let out = kin(&["fit", "examples/bridge_cmm.kin", csv.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("line 2, column 18 (`ex`)"),
        "{}",
        text(&out.stderr)
    );

    // Only ex observed along a line in x: most terms are invisible; the fit says which, at the
    // declarations, instead of returning numbers.
    let line = tmp("fit-line.csv");
    let mut s = String::from("Y,X,Z,dir_Y,T_scale,T_room,time,ex\n");
    for i in 0..50 {
        s.push_str(&format!("100,{},-200,+1,20,1,{i},0.1\n", 10 * i));
    }
    std::fs::write(&line, s).unwrap();
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        line.to_str().unwrap(),
        "--color",
        "never",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        err.contains("E0601")
            && err.contains("examples/bridge_cmm.kin:")
            && err.contains("--min-norm"),
        "{err}"
    );
}

/// The README's first command: the bundled data fit back to their truth.
#[test]
fn the_readme_main_command_fits_the_bundled_data() {
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        "examples/data/bridge_cmm_points.csv",
        "--stepwise",
        "1e-4",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    let sigma: f64 = s
        .split("σ̂ = ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("σ̂ printed");
    assert!(
        (sigma - 0.2).abs() < 0.02,
        "σ̂ {sigma} for 0.2 µm simulated noise"
    );
    // The planted backlash (0.8 µm) survives selection.
    assert!(s.contains("0.800±"), "{s}");
}

/// The README's first command: the loop finds both hidden effects and ends at the noise.
#[test]
fn the_readme_demo_finds_both_hidden_effects() {
    let dir = tmp("demo");
    let out = kin(&["demo", "--dir", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    assert!(
        s.contains("adding candidate 1 to the model: X.tx += backlash(X)"),
        "{s}"
    );
    assert!(s.contains("X.tx += periodic(X, wavelength fit 25."), "{s}");
    assert!(
        s.contains("model revised") && s.contains("no candidate is significant"),
        "{s}"
    );
    let sigma: f64 = s
        .rsplit("σ̂ = ")
        .next()
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("final σ̂");
    assert!(sigma < 1.2 * 0.2, "σ̂ {sigma} within 1.2× the 0.2 µm noise");
    // The model file was changed (the copy, not the bundled one) and the history recorded.
    let model = std::fs::read_to_string(dir.join("bridge_cmm.kin")).unwrap();
    assert!(model.contains("// added by `kin diagnose`"));
    assert!(!std::fs::read_to_string("examples/demo/start.kin")
        .unwrap()
        .contains("added by"));
    assert!(dir.join("bridge_cmm.kin.history.jsonl").exists());
}

/// `kin eval --uncertainty` at the fitted poses: the prediction variances (eq. 4.12) summed over
/// every observed row are σ̂² times the trace of the hat matrix, the number of fitted parameters
/// — an identity, so the check is tight. The file it writes reads back only with its extra columns ignored.
#[test]
fn eval_uncertainties_sum_to_the_rank_and_read_back_with_ignore() {
    let data = "examples/data/bridge_cmm_points.csv";
    let fit = tmp("uncertainty_fit.json");
    let fit_s = fit.to_str().expect("utf-8 path");
    let out = kin(&["fit", "examples/bridge_cmm.kin", data, "-o", fit_s]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("fit.json")).expect("json");
    let sigma = report["sigma"].as_f64().expect("sigma");
    let rank = report["rank"].as_f64().expect("rank");
    assert!(report["nuisance"].as_array().is_some_and(Vec::is_empty));

    let pred = tmp("uncertainty_pred.csv");
    let pred_s = pred.to_str().expect("utf-8 path");
    let args = [
        "eval",
        "examples/bridge_cmm.kin",
        data,
        "--params",
        fit_s,
        "--uncertainty",
        "--components",
        "position",
        "-o",
        pred_s,
    ];
    let out = kin(&args);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let mut total = 0.0;
    for name in ["u_ex", "u_ey", "u_ez"] {
        let u = column(&pred, name);
        assert!(u.iter().all(|x| x.is_finite() && *x > 0.0), "{name}");
        total += u.iter().map(|x| (x / sigma).powi(2)).sum::<f64>();
    }
    // The model fits a time constant (`Z.tz`'s lag), whose share is in every uncertainty: the
    // sum is then the trace of the hat matrix linearised in β and θ, rank + 1. The θ share comes
    // from the fit's covariance of θ (Kaufman's Jacobian) and central differences of the
    // prediction, so the identity holds to about 1e-5 rather than to rounding.
    let fitted = report["nonlinear"].as_array().map_or(0, Vec::len) as f64;
    assert_eq!(fitted, 1.0);
    assert!(
        (total - (rank + fitted)).abs() < 1e-5 * rank,
        "Σ u²/σ̂² = {total}, rank {rank} + {fitted} fitted non-linear parameter"
    );

    let refit = kin(&["fit", "examples/bridge_cmm.kin", pred_s]);
    assert_eq!(refit.status.code(), Some(1));
    let stderr = text(&refit.stderr);
    assert!(
        stderr.contains("unknown column `u_ex`") && stderr.contains("--ignore u_ex,u_ey,u_ez"),
        "{stderr}"
    );
    let refit = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        pred_s,
        "--ignore",
        "u_ex,u_ey,u_ez",
    ]);
    assert!(refit.status.success(), "{}", text(&refit.stderr));

    // A fit made before the model changed cannot give its uncertainties: here the report
    // lists one coefficient fewer than the model has.
    let mut stale = report.clone();
    stale["coefficients"]
        .as_array_mut()
        .expect("coefficients")
        .pop();
    let stale_path = tmp("uncertainty_stale.json");
    std::fs::write(&stale_path, stale.to_string()).expect("write");
    let mut args = args;
    args[4] = stale_path.to_str().expect("utf-8 path");
    let out = kin(&args);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("refit the model"),
        "{}",
        text(&out.stderr)
    );
}

/// `kin diagnose --apply N` and its refit, on a candidate whose plain form the model partly has:
/// the coupling of Y.tz with Z, whose `linear(Z)` is the model's own `Z.tz = linear(Z)` (both
/// translate along z alike). The line applied leaves it out, so the refit is not rank-deficient
/// (E0601) and ends at the noise.
#[test]
fn diagnose_apply_refits_a_candidate_the_model_partly_has() {
    let model = "machine cmm3 {
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
";
    let truth = model.replace(
        "        Z.tz = linear(Z)\n",
        "        Z.tz = linear(Z)\n        Y.tz = linear(Z) * linear(Y)\n",
    );
    let dir = tmp("apply");
    std::fs::create_dir_all(&dir).unwrap();
    let (model_path, truth_path) = (dir.join("cmm3.kin"), dir.join("truth.kin"));
    std::fs::write(&model_path, model).unwrap();
    std::fs::write(&truth_path, truth).unwrap();
    let params = dir.join("truth.params");
    std::fs::write(
        &params,
        "params {\n    X.tx = [3, -2, 1, 0.5] um\n    X.rz[0] = 4 urad\n    Y.ty = [1.5, 0.5] um\n    Z.tz[0] = 2 um\n    Y.tz[0] = 1.5 um\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    let out = kin(&[
        "simulate",
        truth_path.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "600",
        "--noise",
        "0.2um",
        "--seed",
        "3",
        "-o",
        data.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (model_arg, data_arg) = (model_path.to_str().unwrap(), data.to_str().unwrap());
    let out = kin(&["diagnose", model_arg, data_arg]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    // The candidate's number in the ranked list: its rank among equals is not the point.
    let lines: Vec<&str> = s.lines().collect();
    let at = lines
        .iter()
        .position(|l| l.trim() == "add: Y.tz += linear(Z) * linear(Y)")
        .unwrap_or_else(|| panic!("the coupling without its linear part: {s}"));
    let n: String = lines[..at]
        .iter()
        .rev()
        .find_map(|l| l.trim().split_once(". ").map(|(n, _)| n.to_string()))
        .expect("numbered candidate");
    let out = kin(&["diagnose", model_arg, data_arg, "--apply", &n]);
    let s = text(&out.stdout);
    assert!(out.status.success(), "{s}\n{}", text(&out.stderr));
    assert!(s.contains("added to") && s.contains("model revised"), "{s}");
    let sigma: f64 = s
        .rsplit("σ̂ = ")
        .next()
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("σ̂ of the refit");
    assert!(sigma < 1.2 * 0.2, "σ̂ {sigma} after the refit: {s}");
    let revised = std::fs::read_to_string(&model_path).unwrap();
    assert!(
        revised.contains("        Y.tz += linear(Z) * linear(Y)\n"),
        "{revised}"
    );
}

/// Issue 11, point 1 end to end: a periodic error with a strong second harmonic (5 µm at
/// λ = 20 mm, 2 µm at λ/2) is found and fixed by one `--apply 1`, which writes the fitted
/// wavelength; nothing periodic is left significant after it.
#[test]
fn diagnose_apply_fixes_a_two_harmonic_periodic_error_in_one_round() {
    let model = "machine cmm3 {
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
        Y.ty = linear(Y)
        Z.tz = linear(Z)
    }
}
";
    let truth = model.replace(
        "X.tx = spline(X, knots 2)",
        "X.tx = spline(X, knots 2) + fourier(X, harmonics 1..2, wavelength 20 mm)",
    );
    let dir = tmp("harmonics");
    std::fs::create_dir_all(&dir).unwrap();
    let (model_path, truth_path) = (dir.join("cmm3.kin"), dir.join("truth.kin"));
    std::fs::write(&model_path, model).unwrap();
    std::fs::write(&truth_path, truth).unwrap();
    let params = dir.join("truth.params");
    std::fs::write(
        &params,
        "params {\n    X.tx = [3, -2, 1, 0.5, 5, 0, 0, 2] um\n    Y.ty = [1.5] um\n    Z.tz = [2] um\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    let out = kin(&[
        "simulate",
        truth_path.to_str().unwrap(),
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "600",
        "--noise",
        "0.2um",
        "--seed",
        "5",
        "-o",
        data.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (model_arg, data_arg) = (model_path.to_str().unwrap(), data.to_str().unwrap());
    let out = kin(&["diagnose", model_arg, data_arg, "--apply", "1"]);
    let s = text(&out.stdout);
    assert!(out.status.success(), "{s}\n{}", text(&out.stderr));
    assert!(
        s.contains("added to") && s.contains("X.tx += fourier(X, harmonics 1..2, wavelength fit "),
        "{s}"
    );
    let sigma: f64 = s
        .rsplit("σ̂ = ")
        .next()
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("σ̂ of the refit");
    assert!(sigma < 1.1 * 0.2, "σ̂ {sigma} after the refit: {s}");
    // The line written carries the refit's wavelength, close to the truth.
    let revised = std::fs::read_to_string(&model_path).unwrap();
    let lambda: f64 = revised
        .split("wavelength fit ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{revised}"));
    assert!((lambda - 20.0).abs() < 0.01, "{revised}");
    let out = kin(&["diagnose", model_arg, data_arg]);
    let s = text(&out.stdout);
    assert!(out.status.success(), "{s}\n{}", text(&out.stderr));
    assert!(
        !s.lines()
            .any(|l| l.trim().starts_with("add: X.tx += fourier")
                || l.trim().starts_with("add: X.tx += periodic")),
        "a periodic term is still proposed after one round: {s}"
    );
}

/// The verdict follows the test that was made: with the instrument's noise stated and σ̂ ≈ 2.7
/// times it, neither "nowhere" nor "down to the noise" may appear; stated right, the same data
/// are "down to the stated noise"; with nothing stated the words are relative to σ̂.
#[test]
fn diagnose_judges_against_a_stated_noise() {
    let model = "machine cmm3 {
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
";
    let dir = tmp("noise");
    std::fs::create_dir_all(&dir).unwrap();
    let model_path = dir.join("cmm3.kin");
    std::fs::write(&model_path, model).unwrap();
    let params = dir.join("truth.params");
    std::fs::write(
        &params,
        "params {\n    X.tx = [3, -2, 1, 0.5] um\n    X.rz[0] = 4 urad\n    Y.ty[0] = 1.5 um\n    Z.tz[0] = 2 um\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    let (model_arg, data_arg) = (model_path.to_str().unwrap(), data.to_str().unwrap());
    let out = kin(&[
        "simulate",
        model_arg,
        "--params",
        params.to_str().unwrap(),
        "--sample",
        "500",
        "--noise",
        "0.54um",
        "--seed",
        "5",
        "-o",
        data_arg,
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));

    let out = kin(&["diagnose", model_arg, data_arg, "--noise", "0.2um"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    assert!(!s.contains("nowhere") && !s.contains("down to the"), "{s}");
    assert!(s.contains("× the stated noise (χ²"), "{s}");
    let ratio: f64 = s
        .split("σ̂ is ")
        .nth(1)
        .and_then(|t| t.split('×').next())
        .and_then(|v| v.parse().ok())
        .expect("σ̂ over the stated noise");
    assert!((2.4..3.0).contains(&ratio), "{ratio}: {s}");

    let out = kin(&["diagnose", model_arg, data_arg, "--noise", "0.54 um"]);
    let s = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(s.contains("down to the stated noise"), "{s}");

    let out = kin(&["diagnose", model_arg, data_arg]);
    let s = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(!s.contains("down to the") && !s.contains("nowhere"), "{s}");
    assert!(s.contains("model's own residual scatter"), "{s}");

    // A noise that is not a length is a usage error.
    let out = kin(&["diagnose", model_arg, data_arg, "--noise", "2urad"]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
}

/// One artifact label per row: each label adds six placement parameters that one point cannot
/// fix. The fit says so at once, naming the file and labels, instead of factoring a design of
/// 6 × 500 nuisance columns to find the rank deficiency.
#[test]
fn fit_rejects_artifact_labels_too_thin_to_place_before_fitting() {
    let src = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/data/bridge_cmm_points.csv"),
    )
    .expect("bundled data");
    let mut out = String::new();
    let mut row = 0usize;
    for line in src.lines() {
        if line.starts_with('#') {
            out.push_str(line);
        } else if row == 0 {
            out.push_str(&format!("{line},artifact"));
            row += 1;
        } else if row <= 500 {
            out.push_str(&format!("{line},a{row}"));
            row += 1;
        } else {
            break;
        }
        out.push('\n');
    }
    let csv = tmp("thin-artifacts.csv");
    std::fs::write(&csv, out).unwrap();
    let run = kin(&["fit", "examples/bridge_cmm.kin", csv.to_str().unwrap()]);
    let err = text(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(
        err.contains(csv.to_str().unwrap())
            && err.contains("500 artifact labels are observed too thinly to place")
            && err.contains("`a1` (1 row, line")
            && err.contains("and 495 more"),
        "{err}"
    );
}

/// `kin eval --uncertainty --ellipsoid 95`: per pose the semi-axes are the χ²₃(0.95)-scaled
/// square roots of the eigenvalues of the position covariance, so their squares sum to
/// χ²₃(0.95) · (u_ex² + u_ey² + u_ez²) (the trace), with 7.8147279 from the tables; the
/// directions are orthonormal.
#[test]
fn eval_ellipsoids_hold_the_position_uncertainty_at_the_stated_level() {
    let data = "examples/data/bridge_cmm_points.csv";
    let fit = tmp("ellipsoid_fit.json");
    let fit_s = fit.to_str().expect("utf-8 path");
    let out = kin(&["fit", "examples/bridge_cmm.kin", data, "-o", fit_s]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let pred = tmp("ellipsoid_pred.csv");
    let pred_s = pred.to_str().expect("utf-8 path");
    let out = kin(&[
        "eval",
        "examples/bridge_cmm.kin",
        data,
        "--params",
        fit_s,
        "--uncertainty",
        "--ellipsoid",
        "95",
        "--components",
        "position",
        "-o",
        pred_s,
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let u: Vec<Vec<f64>> = ["u_ex", "u_ey", "u_ez"]
        .iter()
        .map(|n| column(&pred, n))
        .collect();
    let a: Vec<Vec<f64>> = ["ell_a1", "ell_a2", "ell_a3"]
        .iter()
        .map(|n| column(&pred, n))
        .collect();
    let dirs: Vec<Vec<Vec<f64>>> = (1..=3)
        .map(|k| {
            ["x", "y", "z"]
                .iter()
                .map(|c| column(&pred, &format!("ell_u{k}{c}")))
                .collect()
        })
        .collect();
    let chi2 = 7.814_727_903;
    for r in 0..u[0].len() {
        let trace: f64 = (0..3).map(|c| u[c][r].powi(2)).sum();
        let sum: f64 = (0..3).map(|k| a[k][r].powi(2)).sum();
        // The file holds a few significant digits per cell.
        assert!(
            (sum - chi2 * trace).abs() < 1e-4 * chi2 * trace,
            "row {r}: Σa² = {sum}, χ²·tr = {}",
            chi2 * trace
        );
        assert!(a[0][r] >= a[1][r] && a[1][r] >= a[2][r]);
        for k in 0..3 {
            for l in 0..3 {
                let dot: f64 = (0..3).map(|c| dirs[k][c][r] * dirs[l][c][r]).sum();
                let want = if k == l { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < 1e-4, "row {r}: u{k}·u{l} = {dot}");
            }
        }
    }
    // Without --uncertainty the option is a usage error; a length file has no ellipsoid.
    let out = kin(&[
        "eval",
        "examples/bridge_cmm.kin",
        data,
        "--params",
        fit_s,
        "--ellipsoid",
        "95",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let out = kin(&[
        "eval",
        "examples/bridge_cmm.kin",
        data,
        "--params",
        fit_s,
        "--uncertainty",
        "--ellipsoid",
        "100",
    ]);
    assert_eq!(out.status.code(), Some(2));
}

/// Two instruments 20× apart (issue #31): `kin fit` with a σ per file prints each file's σ̂
/// near its simulated noise; `--noise FILE=Q` and a `# noise:` header line state one file's σ
/// (fixed, its σ̂/σ reported); a bad header value is located by file, line and column.
#[test]
fn fit_weighs_each_file_by_its_own_noise() {
    let model = "machine cmm3 {
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
        Y.ty = linear(Y)
        Z.tz = linear(Z)
    }
}
";
    let dir = tmp("noise-per-file");
    std::fs::create_dir_all(&dir).unwrap();
    let model_path = dir.join("cmm3.kin");
    std::fs::write(&model_path, model).unwrap();
    let model_arg = model_path.to_str().unwrap();
    let mut paths = Vec::new();
    for (name, noise, seed) in [("laser.csv", "0.1um", "3"), ("tracker.csv", "2um", "4")] {
        let p = dir.join(name);
        let out = kin(&[
            "simulate",
            model_arg,
            "--sample",
            "400",
            "--noise",
            noise,
            "--seed",
            seed,
            "-o",
            p.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        paths.push(p);
    }
    let (laser, tracker) = (paths[0].to_str().unwrap(), paths[1].to_str().unwrap());
    // The σ̂ printed for `file` (estimated or stated).
    let sigma_hat = |s: &str, file: &str| -> f64 {
        let line = s
            .lines()
            .find(|l| l.trim_start().starts_with(file) && l.contains("positions"))
            .unwrap_or_else(|| panic!("no line for {file}: {s}"));
        line.split("σ̂ = ")
            .nth(1)
            .and_then(|t| t.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{line}"))
    };

    let out = kin(&["fit", model_arg, laser, tracker, "--noise-per-file"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    let (a, b) = (sigma_hat(&s, laser), sigma_hat(&s, tracker));
    assert!((0.09..0.11).contains(&a), "laser σ̂ {a}: {s}");
    assert!((1.8..2.2).contains(&b), "tracker σ̂ {b}: {s}");
    assert!(s.contains("estimated"), "{s}");

    // The laser's σ stated by the flag: fixed, its σ̂ against it; the tracker's estimated.
    let flag = format!("{laser}=0.1um");
    let out = kin(&["fit", model_arg, laser, tracker, "--noise", &flag]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    assert!(s.contains("σ = 0.1000 um stated"), "{s}");
    assert!((1.8..2.2).contains(&sigma_hat(&s, tracker)), "{s}");

    // The same by the file's header; a flag naming no data file is a usage error.
    let body = std::fs::read_to_string(&paths[0]).unwrap();
    let headed = dir.join("laser_headed.csv");
    std::fs::write(&headed, format!("# noise: 0.1 um\n{body}")).unwrap();
    let out = kin(&["fit", model_arg, headed.to_str().unwrap(), tracker]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("σ = 0.1000 um stated"));
    let out = kin(&["fit", model_arg, laser, "--noise", "other.csv=1um"]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));

    // The diagnosis weighs each file by its own σ and lists each file's σ̂ against its noise.
    let out = kin(&["diagnose", model_arg, laser, tracker, "--noise", &flag]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = text(&out.stdout);
    assert!(s.contains("its own file's σ"), "{s}");
    assert!(s.contains("its stated σ = 0.1000 um"), "{s}");
    assert!(
        s.contains("estimated by the fit (no noise stated for it)"),
        "{s}"
    );

    let bad = dir.join("laser_bad.csv");
    std::fs::write(&bad, format!("# laser\n# noise: 0.1 urad\n{body}")).unwrap();
    let out = kin(&["fit", model_arg, bad.to_str().unwrap(), tracker]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let e = text(&out.stderr);
    assert!(e.contains("laser_bad.csv, line 2, column 10"), "{e}");
}

/// A truth with no values simulates a perfect machine: said on standard error, not written as
/// zeros without a word; with values bound, nothing is said.
#[test]
fn simulate_says_when_the_truth_has_no_values() {
    let out = tmp("perfect.csv");
    let o = kin(&[
        "simulate",
        "examples/xy_table.kin",
        "--sample",
        "3",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        text(&o.stderr).contains("every coefficient"),
        "{}",
        text(&o.stderr)
    );
    let o = kin(&[
        "simulate",
        "examples/xy_table.kin",
        "--params",
        "examples/data/ballbar_xy_truth.params",
        "--sample",
        "3",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(
        !text(&o.stderr).contains("every coefficient"),
        "{}",
        text(&o.stderr)
    );
}

/// Two rows against a model of 89 coefficients: the one sentence that matters comes first, and
/// the combinations the data cannot see are capped with a count (every one with `-v`).
#[test]
fn too_few_rows_say_so_first_and_briefly() {
    let all = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let few: Vec<&str> = all
        .lines()
        .filter(|l| !l.starts_with('#'))
        .take(3)
        .collect();
    let path = tmp("two-rows.csv");
    std::fs::write(&path, few.join("\n") + "\n").expect("write");
    let o = kin(&["fit", "examples/bridge_cmm.kin", path.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let err = text(&o.stderr);
    assert!(
        err.lines()
            .next()
            .is_some_and(|l| l.contains("the data determine only")),
        "{err}"
    );
    assert!(err.lines().count() < 100, "{} lines", err.lines().count());
    assert!(
        err.contains("more coefficients the data cannot tell apart"),
        "{err}"
    );
    let o = kin(&[
        "fit",
        "-v",
        "examples/bridge_cmm.kin",
        path.to_str().unwrap(),
    ]);
    assert!(text(&o.stderr).lines().count() > 300);
}

/// A component written in two places (`X.tx = spline(…)`, then `X.tx += backlash(X)` after
/// another line) takes two rows of the coefficient table; each says which term it holds.
#[test]
fn a_component_in_two_rows_names_each_row_s_terms() {
    let model = tmp("two_runs.kin");
    std::fs::write(
        &model,
        "machine s {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain { X moving  tool t at (0, 0, -100) mm }
    errors {
        X.tx = spline(X, knots 2)
        X.ry = const
        X.tx += backlash(X)
    }
}
params { X.tx = [2, -1, 0.5, 0.2, 1.0] um  X.ry[0] = 3 urad }
",
    )
    .expect("write");
    let data = tmp("two_runs.csv");
    let (m, d) = (model.to_str().unwrap(), data.to_str().unwrap());
    let o = kin(&[
        "simulate", m, "--sample", "200", "--noise", "0.1um", "-o", d,
    ]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = kin(&["fit", m, d]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains("X.tx EXX         [um] spline(X): "), "{out}");
    assert!(out.contains("X.tx EXX         [um] backlash(X): "), "{out}");
    assert!(
        out.contains("X.ry EBX         [urad] 3."),
        "a one-row component is as before: {out}"
    );
}
