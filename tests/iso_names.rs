//! ISO 230-1 names (issue #13): location and squareness aliases mean the error the standard
//! means, measured on the model's own axes; fitted errors are reported at stations along
//! their axis with uncertainties that cover a simulated truth.

use std::process::{Command, Output};

use kin_model::Model;

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs")
}

/// The actual relative displacement of the tool against the workpiece when axis `j` alone
/// moves by `step` from home: the nominal one (from the nominal Jacobian) plus the change of
/// the modelled error.
fn actual_step(m: &Model, j: usize, step: f64) -> [f64; 3] {
    let mut s = m.state();
    let mut jac = vec![0.0; 6 * m.axes()];
    m.nominal_jacobian(&s.get(), &mut jac).expect("nominal");
    let mut e0 = [0.0; 6];
    m.eval(&s.get(), m.beta(), &mut e0).expect("eval");
    s.q[j] = step;
    let mut e1 = [0.0; 6];
    m.eval(&s.get(), m.beta(), &mut e1).expect("eval");
    [0, 1, 2].map(|c| jac[6 * j + c] * step + e1[c] - e0[c])
}

fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
    let dot: f64 = (0..3).map(|i| a[i] * b[i]).sum();
    let n = |v: [f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    (dot / (n(a) * n(b))).acos()
}

/// The three squareness angles (minus 90°) between the actual X, Y, Z of a machine whose axes
/// are `X`, `Y`, `Z` (in any order in its chains).
fn squareness(src: &str) -> (f64, f64, f64) {
    let m = Model::compile(src).expect("compiles");
    let index = |name: &str| {
        m.machine()
            .axes
            .iter()
            .position(|a| a.name == name)
            .expect("axis")
    };
    let step = 0.3;
    let x = actual_step(&m, index("X"), step);
    let y = actual_step(&m, index("Y"), step);
    let z = actual_step(&m, index("Z"), -step);
    let z = z.map(|v| -v);
    let right = std::f64::consts::FRAC_PI_2;
    (
        angle(x, y) - right,
        angle(x, z) - right,
        angle(y, z) - right,
    )
}

const BRIDGE: &str = "machine bridge {
    task position
    units { length mm, error um, tilt urad }
    axis Y prismatic along y range 0 mm .. 700 mm
    axis X prismatic along x range 0 mm .. 600 mm
    axis Z prismatic along z range -450 mm .. 0 mm
    tool chain { Y moving  X moving at (0, 0, 650) mm  Z moving  tool probe at (30, 20, -120) mm }
    errors { ERRORS }
}";

const MILL: &str = "machine mill {
    task position
    units { length mm, error um, tilt urad }
    axis Y prismatic along -y range 0 mm .. 500 mm
    axis X prismatic along -x range 0 mm .. 650 mm
    axis Z prismatic along z range -450 mm .. 0 mm
    workpiece chain { Y fixed at (0, 250, 0) mm  X fixed at (325, 0, 120) mm  workpiece at (0, 0, 50) mm }
    tool chain { Z moving at (0, 0, 760) mm  tool cutter at (0, 0, -100) mm }
    errors { ERRORS }
}";

#[test]
fn squareness_names_open_and_close_the_angles_the_standard_says() {
    // ISO 230-1, right-hand rule: EC0Y > 0 opens X–Y beyond 90°, EB0Z > 0 closes X–Z,
    // EA0Z > 0 opens Y–Z. 100, 200, 300 µrad, each alone, then together.
    for machine in [BRIDGE, MILL] {
        for (errors, expected) in [
            ("EC0Y = 100 urad", (100e-6, 0.0, 0.0)),
            ("EB0Z = 200 urad", (0.0, -200e-6, 0.0)),
            ("EA0Z = 300 urad", (0.0, 0.0, 300e-6)),
            ("EC0X = 100 urad", (-100e-6, 0.0, 0.0)),
            (
                "EC0Y = 100 urad  EB0Z = 200 urad  EA0Z = 300 urad",
                (100e-6, -200e-6, 300e-6),
            ),
        ] {
            let got = squareness(&machine.replace("ERRORS", errors));
            // Alone, each is exact to first order; together they interact at second order
            // (ε² ≈ 3e-8).
            let tolerance = if errors.contains("  ") { 1e-7 } else { 1e-9 };
            let close = |a: f64, b: f64| (a - b).abs() < tolerance;
            assert!(
                close(got.0, expected.0) && close(got.1, expected.1) && close(got.2, expected.2),
                "{errors} on {}: angles − 90° are {got:?}, expected {expected:?}",
                machine.split_whitespace().nth(1).unwrap_or("?")
            );
        }
    }
}

/// A known positioning error (a spline of X with these coefficients), simulated with noise and
/// fitted: the station values must cover the truth within their uncertainties.
#[test]
fn a_fitted_positioning_error_at_stations_covers_the_truth() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("stage.kin");
    std::fs::write(
        &model,
        "machine stage {
            task position
            units { length mm, error um, tilt urad }
            axis X prismatic along x range 0 mm .. 400 mm
            tool chain { X moving  tool t at (0, 0, 0) mm }
            errors { EXX = spline(X, knots 3) }
        }",
    )
    .expect("write");
    let truth = dir.path().join("truth.params");
    let truth_text = "params { EXX = [4.0, -3.0, 2.5, 1.0, -1.5] um }";
    std::fs::write(&truth, truth_text).expect("write");
    let data = dir.path().join("run.csv");
    let fit = dir.path().join("fit.json");
    let (m_s, t_s, d_s, f_s) = (
        model.to_str().expect("utf-8"),
        truth.to_str().expect("utf-8"),
        data.to_str().expect("utf-8"),
        fit.to_str().expect("utf-8"),
    );
    let out = kin(&[
        "simulate",
        m_s,
        "--params",
        t_s,
        "--sample",
        "300",
        "--noise",
        "0.5um",
        "--seed",
        "7",
        "--components",
        "position",
        "-o",
        d_s,
    ]);
    assert!(out.status.success(), "{out:?}");
    let out = kin(&["fit", m_s, d_s, "-o", f_s]);
    assert!(out.status.success(), "{out:?}");
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(printed.contains("X.tx EXX"), "{printed}");
    assert!(printed.contains("errors at stations"), "{printed}");

    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("FIT.json")).expect("json");
    assert!(report["coefficients"]
        .as_array()
        .expect("coefficients")
        .iter()
        .all(|c| c["iso"] == "EXX"));
    let table = report["stations"]
        .as_array()
        .expect("stations")
        .iter()
        .find(|t| t["error"] == "X.tx")
        .expect("X.tx at stations");
    assert_eq!(table["iso"], "EXX");
    assert_eq!(table["partial"], false);
    let positions: Vec<f64> =
        serde_json::from_value(table["positions"].clone()).expect("positions");
    let values: Vec<f64> = serde_json::from_value(table["values"].clone()).expect("values");
    let u: Vec<f64> = serde_json::from_value(table["u"].clone()).expect("u");
    assert_eq!(
        positions,
        vec![0.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 350.0, 400.0]
    );

    // The truth at each station, from the model with the true coefficients.
    let source = std::fs::read_to_string(&model).expect("model");
    let truth_model = Model::compile(&source)
        .expect("compiles")
        .with_params(truth_text)
        .expect("binds");
    let mut worst: f64 = 0.0;
    for ((p, v), u) in positions.iter().zip(&values).zip(&u) {
        let mut s = truth_model.state();
        s.q[0] = p * 1e-3;
        let mut e = [0.0; 6];
        truth_model
            .eval(&s.get(), truth_model.beta(), &mut e)
            .expect("eval");
        let t = e[0] * 1e6;
        // The spline is zero at the start of the axis by construction (a laser run's zero):
        // there the value is exact and carries no uncertainty.
        if *u == 0.0 {
            assert!(
                (v - t).abs() < 1e-9,
                "station {p}: {v} without uncertainty, truth {t}"
            );
            continue;
        }
        assert!(*u < 0.5, "station {p}: u = {u}");
        // 4 standard uncertainties: with 9 stations a false alarm is below 1 in 1000.
        assert!(
            (v - t).abs() < 4.0 * u,
            "station {p} mm: fitted {v} ± {u}, truth {t}"
        );
        worst = worst.max((v - t).abs() / u);
    }
    assert!(worst > 0.0, "the fit is not the truth itself");

    // The report shows the same table under both names.
    let html = dir.path().join("report.html");
    let out = kin(&[
        "report",
        m_s,
        "--fit",
        f_s,
        d_s,
        "-o",
        html.to_str().expect("utf-8"),
    ]);
    assert!(out.status.success(), "{out:?}");
    let page = std::fs::read_to_string(&html).expect("report");
    assert!(
        page.contains("Errors at stations along their axis"),
        "no stations section"
    );
    assert!(
        page.contains("<code>X.tx</code> · <code>EXX</code> along X"),
        "no ISO name"
    );
}

#[test]
fn squareness_constants_are_named_by_iso_in_fit_output() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("mill.kin");
    std::fs::write(
        &model,
        MILL.replace(
            "ERRORS",
            "EXX = spline(X, knots 2)  EYY = spline(Y, knots 2)  EZZ = spline(Z, knots 2)
             EC0Y = const  EB0Z = const  EA0Z = const",
        ),
    )
    .expect("write");
    let truth = dir.path().join("truth.params");
    std::fs::write(
        &truth,
        "params { EXX = [2, -1, 1, 0.5] um  EYY = [1, 1, -1, 0.5] um
                  EZZ = [-2, 1, 0.5, 0.2] um  EC0Y[0] = 40 urad  EB0Z[0] = -25 urad
                  EA0Z[0] = 15 urad }",
    )
    .expect("write");
    let data = dir.path().join("points.csv");
    let fit = dir.path().join("fit.json");
    let s = |p: &std::path::Path| p.to_str().expect("utf-8").to_string();
    let out = kin(&[
        "simulate",
        &s(&model),
        "--params",
        &s(&truth),
        "--sample",
        "400",
        "--noise",
        "0.2um",
        "--seed",
        "3",
        "--components",
        "position",
        "-o",
        &s(&data),
    ]);
    assert!(out.status.success(), "{out:?}");
    let out = kin(&["fit", &s(&model), &s(&data), "-o", &s(&fit)]);
    assert!(out.status.success(), "{out:?}");
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(
        printed.contains("(EC0Y)") || printed.contains("(-EC0Y)"),
        "{printed}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("FIT.json")).expect("json");
    // Each squareness is recovered as the standard defines it: the coefficient times the sign
    // its ISO name carries.
    for (name, truth) in [("EC0Y", 40.0), ("EB0Z", -25.0), ("EA0Z", 15.0)] {
        let c = report["coefficients"]
            .as_array()
            .expect("coefficients")
            .iter()
            .find(|c| {
                c["iso"]
                    .as_str()
                    .is_some_and(|n| n.trim_start_matches('-') == name)
            })
            .unwrap_or_else(|| panic!("{name} named in FIT.json"));
        let sign = if c["iso"].as_str().is_some_and(|n| n.starts_with('-')) {
            -1.0
        } else {
            1.0
        };
        let value = sign * c["value"].as_f64().expect("value");
        let se = c["se"].as_f64().expect("se");
        assert!(
            (value - truth).abs() < 4.0 * se + 1e-9,
            "{name}: {value} ± {se}, truth {truth}"
        );
    }
}

/// A squareness written with its own axis in its scale (`(Y + 250 mm) / 1000 mm * const`, the
/// slope of Y's path in x counted from 250 mm before Y's zero) belongs in Y's table with its
/// straightness: the stations show their sum, as a laser run along Y would.
#[test]
fn a_squareness_written_with_its_axis_is_in_the_station_table() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("column.kin");
    let source = "machine column {
            task position
            units { length mm, error um, tilt urad }
            axis Y prismatic along y range 0 mm .. 500 mm
            tool chain { Y moving  tool t at (0, 0, 0) mm }
            errors { Y.tx = (Y + 250 mm) / 1000 mm * const + straightness(Y, knots 2) }
        }";
    std::fs::write(&model, source).expect("write");
    let truth_text = "params { Y.tx = [12.0, 3.0, -2.0, 1.5] um }";
    let truth = dir.path().join("truth.params");
    std::fs::write(&truth, truth_text).expect("write");
    let data = dir.path().join("run.csv");
    let fit = dir.path().join("fit.json");
    let (m_s, t_s, d_s, f_s) = (
        model.to_str().expect("utf-8"),
        truth.to_str().expect("utf-8"),
        data.to_str().expect("utf-8"),
        fit.to_str().expect("utf-8"),
    );
    let out = kin(&[
        "simulate",
        m_s,
        "--params",
        t_s,
        "--sample",
        "300",
        "--noise",
        "0.5um",
        "--seed",
        "3",
        "--components",
        "position",
        "-o",
        d_s,
    ]);
    assert!(out.status.success(), "{out:?}");
    let out = kin(&["fit", m_s, d_s, "-o", f_s]);
    assert!(out.status.success(), "{out:?}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("FIT.json")).expect("json");
    let table = report["stations"]
        .as_array()
        .expect("stations")
        .iter()
        .find(|t| t["error"] == "Y.tx")
        .expect("Y.tx at stations");
    assert_eq!(table["partial"], false, "{table}");
    let positions: Vec<f64> =
        serde_json::from_value(table["positions"].clone()).expect("positions");
    let values: Vec<f64> = serde_json::from_value(table["values"].clone()).expect("values");
    let u: Vec<f64> = serde_json::from_value(table["u"].clone()).expect("u");
    let truth_model = Model::compile(source)
        .expect("compiles")
        .with_params(truth_text)
        .expect("binds");
    for ((p, v), u) in positions.iter().zip(&values).zip(&u) {
        let mut s = truth_model.state();
        s.q[0] = p * 1e-3;
        let mut e = [0.0; 6];
        truth_model
            .eval(&s.get(), truth_model.beta(), &mut e)
            .expect("eval");
        let t = e[0] * 1e6;
        assert!(
            (v - t).abs() < 4.0 * u.max(1e-9),
            "station {p} mm: fitted {v} ± {u}, truth {t}"
        );
    }
    // The straightness is zero at both ends: there the squareness alone, 12 µm × 500/1000.
    let span = values.last().copied().unwrap_or(f64::NAN) - values[0];
    assert!((span - 6.0).abs() < 3.0, "{values:?}");
}

/// Data along the first quarter of X leave the spline's far coefficients undetermined: a
/// minimum-norm fit states no value there (`null`, printed `undetermined`), never a number the
/// solver's choice made.
#[test]
fn stations_the_data_do_not_reach_are_undetermined() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("stage.kin");
    std::fs::write(
        &model,
        "machine stage {
            task position
            units { length mm, error um, tilt urad }
            axis X prismatic along x range 0 mm .. 400 mm
            tool chain { X moving  tool t at (0, 0, 0) mm }
            errors { X.tx = spline(X, knots 3) }
        }",
    )
    .expect("write");
    let data = dir.path().join("run.csv");
    let mut rows = String::from("X[mm],ex[um]\n");
    for k in 0..=40 {
        let x = 2.5 * f64::from(k);
        rows.push_str(&format!("{x},{}\n", 0.01 * x + 0.1 * f64::from(k % 3)));
    }
    std::fs::write(&data, rows).expect("write");
    let fit = dir.path().join("fit.json");
    let (m_s, d_s, f_s) = (
        model.to_str().expect("utf-8"),
        data.to_str().expect("utf-8"),
        fit.to_str().expect("utf-8"),
    );
    let out = kin(&["fit", m_s, d_s, "--min-norm", "-o", f_s]);
    assert!(out.status.success(), "{out:?}");
    let printed = String::from_utf8_lossy(&out.stdout);
    assert!(printed.contains("400: undetermined"), "{printed}");
    assert!(!printed.contains("±?"), "{printed}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).expect("FIT.json")).expect("json");
    let table = report["stations"]
        .as_array()
        .expect("stations")
        .iter()
        .find(|t| t["error"] == "X.tx")
        .expect("X.tx at stations");
    let values = table["values"].as_array().expect("values");
    assert!(values.first().is_some_and(|v| v.is_number()), "{table}");
    assert!(values.last().is_some_and(|v| v.is_null()), "{table}");
}
