//! End-to-end runs of fits over rounds of a model: weights from a stated noise, the history
//! keyed on the model and the data, fitted non-linear values written back by `--apply`.

mod common;

use common::{cmm3, kin, ok, scratch, simulate, text, CMM3_ERRORS, CMM3_TRUTH};

/// The number after `label` in `s`.
fn after(s: &str, label: &str) -> f64 {
    s.split(label)
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|v| v.trim_end_matches([',', ':']).parse().ok())
        .unwrap_or_else(|| panic!("no number after `{label}` in:\n{s}"))
}

/// Position rows with 0.3 µm of noise and rotation rows with 20 µrad: weighted by what was
/// stated, σ̂/σ is near 1 and the χ² test passes; stated three times too small, it fails; the
/// unweighted fit says that its σ̂ mixes µm and µrad; a missing σ for rotations is refused.
#[test]
fn fit_weights_mixed_rows_by_the_stated_noise() {
    let dir = scratch("weights");
    let model = dir.join("cmm3.kin");
    std::fs::write(&model, cmm3(CMM3_ERRORS)).unwrap();
    let truth = dir.join("truth.params");
    std::fs::write(&truth, CMM3_TRUTH).unwrap();
    let data = dir.join("pose.csv");
    let (m, d) = (model.to_str().unwrap(), data.to_str().unwrap());
    simulate(
        m,
        truth.to_str().unwrap(),
        500,
        4,
        &[
            "--noise",
            "0.3um",
            "--noise-tilt",
            "20urad",
            "--components",
            "pose",
        ],
        d,
    );

    let json = dir.join("fit.json");
    let s = ok(&kin(&[
        "fit",
        m,
        d,
        "--noise",
        "0.3um",
        "--noise-tilt",
        "20urad",
        "-o",
        json.to_str().unwrap(),
    ]));
    let ratio = after(&s, "σ̂/σ =");
    assert!((0.9..1.1).contains(&ratio), "σ̂/σ {ratio}:\n{s}");
    assert!(s.contains("consistent with the stated noise"), "{s}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["weights"]["position"], 0.3);
    assert_eq!(v["weights"]["rotation"], 20.0);
    assert!(
        v["weights"]["p"].as_f64().unwrap() > 0.01,
        "{}",
        v["weights"]
    );
    // The residuals stay in their own units: rotations in µrad, near their 20 µrad noise.
    let erx = v["files"][0]["components"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "erx")
        .expect("erx summary")["rms"]
        .as_f64()
        .unwrap();
    assert!((17.0..23.0).contains(&erx), "erx RMS {erx}");

    // The report holds the residuals against the stated noise, not against σ̂.
    let html = dir.join("report.html");
    ok(&kin(&[
        "report",
        m,
        "--fit",
        json.to_str().unwrap(),
        d,
        "-o",
        html.to_str().unwrap(),
    ]));
    let html = std::fs::read_to_string(&html).unwrap();
    assert!(html.contains("σ̂/σ, against the stated noise"));
    assert!(html.contains(
        "±3σ of the instrument's stated noise (±0.900 um on positions, ±60.0 urad on rotations"
    ));
    let s = ok(&kin(&[
        "fit",
        m,
        d,
        "--noise",
        "0.1um",
        "--noise-tilt",
        "7urad",
    ]));
    assert!(after(&s, "σ̂/σ =") > 2.5, "{s}");
    assert!(s.contains("the residuals exceed the stated noise"), "{s}");

    let s = ok(&kin(&["fit", m, d]));
    assert!(
        !s.contains("σ̂/σ")
            && s.contains("σ̂ mixes um on positions and lengths with urad on rotations"),
        "{s}"
    );

    let s = ok(&kin(&["diagnose", m, d]));
    let second = s.lines().nth(1).unwrap_or("");
    assert!(second.contains("σ̂ mixes um on positions"), "{s}");

    let out = kin(&["fit", m, d, "--noise", "0.3um"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("no noise is stated for them"),
        "{}",
        text(&out.stderr)
    );
}

/// The same model fitted to two data sets is not "improved" by the second; a refit of the same
/// model on the same data is "unchanged"; the same path with other contents is new data; and
/// only a changed model on the same data is "model revised".
#[test]
fn the_history_compares_fits_of_the_same_data_only() {
    let dir = scratch("history");
    let model = dir.join("cmm3.kin");
    std::fs::write(&model, cmm3(CMM3_ERRORS)).unwrap();
    let truth = dir.join("truth.params");
    std::fs::write(&truth, CMM3_TRUTH).unwrap();
    let (a, b) = (dir.join("a.csv"), dir.join("b.csv"));
    let m = model.to_str().unwrap();
    let t = truth.to_str().unwrap();
    simulate(m, t, 300, 1, &["--noise", "0.3um"], a.to_str().unwrap());
    // Three times the noise: a comparison with `a` would read as a worse model.
    simulate(m, t, 300, 2, &["--noise", "0.9um"], b.to_str().unwrap());

    let first = ok(&kin(&["fit", m, a.to_str().unwrap()]));
    assert!(
        !first.contains("model revised") && !first.contains("new data"),
        "{first}"
    );
    let again = ok(&kin(&["fit", m, a.to_str().unwrap()]));
    assert!(
        again.contains("unchanged: the model and the data are those of the fit"),
        "{again}"
    );
    let other = ok(&kin(&["fit", m, b.to_str().unwrap()]));
    assert!(other.contains("new data:"), "{other}");
    assert!(
        !other.contains("model revised") && !other.contains(" %)"),
        "{other}"
    );

    // Same path, other contents.
    simulate(m, t, 300, 3, &["--noise", "0.3um"], a.to_str().unwrap());
    let edited = ok(&kin(&["fit", m, a.to_str().unwrap()]));
    assert!(edited.contains("new data:"), "{edited}");

    // A revised model on data fitted before: the before/after.
    let revised = CMM3_ERRORS.replace(
        "Y.ty = linear(Y)\n",
        "Y.ty = linear(Y)\n        Y.tx = const\n",
    );
    std::fs::write(&model, cmm3(&revised)).unwrap();
    let s = ok(&kin(&["fit", m, b.to_str().unwrap()]));
    assert!(s.contains("model revised: 7 → 8 parameters"), "{s}");

    // Every record keeps its data key and binned residuals; an old record without them reads.
    let history = dir.join("cmm3.kin.history.jsonl");
    let records = std::fs::read_to_string(&history).unwrap();
    for line in records.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(
            v["data_hash"].is_string() && v["binned"].is_array(),
            "{line}"
        );
    }
    let old = r#"{"time":1,"model_hash":"0","parameters":7,"rows":900,"sigma":0.3,"rms":0.3,"error_unit":"um","files":[{"path":"b.csv","rms":0.3}]}"#;
    std::fs::write(&history, format!("{old}\n{records}")).unwrap();
    let out = kin(&["fit", m, b.to_str().unwrap()]);
    let s = ok(&out);
    assert!(s.contains("unchanged"), "{s}");
    assert!(
        !text(&out.stderr).contains("warning"),
        "{}",
        text(&out.stderr)
    );
}

/// `--apply` of a periodic candidate with a fitted wavelength writes the refit's wavelength back
/// as the line's start value; the text before the command stays in MACHINE.previous; the
/// previous round's comparison is not printed again; and the report shows each round's
/// residuals as they were.
#[test]
fn apply_writes_the_fitted_wavelength_back_and_the_report_keeps_every_round() {
    let dir = scratch("apply");
    let model = dir.join("cmm3.kin");
    std::fs::write(&model, cmm3(CMM3_ERRORS)).unwrap();
    let truth_model = dir.join("truth.kin");
    let truth_errors = CMM3_ERRORS.replace(
        "X.tx = spline(X, knots 2)\n",
        "X.tx = spline(X, knots 2)\n        X.tx += periodic(X, wavelength 47 mm, knots 2)\n",
    );
    std::fs::write(&truth_model, cmm3(&truth_errors)).unwrap();
    let truth = dir.join("truth.params");
    std::fs::write(
        &truth,
        "params {\n    X.tx = [3, -2, 1, 0.5, 3.6, 2.4] um\n    X.rz[0] = 4 urad\n    Y.ty[0] = 1.5 um\n    Z.tz[0] = 2 um\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    let (m, d) = (model.to_str().unwrap(), data.to_str().unwrap());
    simulate(
        truth_model.to_str().unwrap(),
        truth.to_str().unwrap(),
        800,
        3,
        &["--noise", "0.2um"],
        d,
    );
    let s = ok(&kin(&["diagnose", m, d]));
    let lines: Vec<&str> = s.lines().collect();
    let at = lines
        .iter()
        .position(|l| {
            // A periodic spline or a Fourier series, whichever the data prefer.
            let l = l.trim();
            l.starts_with("add: X.tx += ") && l.contains("wavelength fit ")
        })
        .unwrap_or_else(|| panic!("a periodic candidate with a fitted wavelength:\n{s}"));
    let scanned = after(lines[at], "wavelength fit");
    let n: String = lines[..at]
        .iter()
        .rev()
        .find_map(|l| l.trim().split_once(". ").map(|(n, _)| n.to_string()))
        .expect("numbered candidate");
    let original = std::fs::read_to_string(&model).unwrap();

    let s = ok(&kin(&["diagnose", m, d, "--apply", &n]));
    // The comparison printed is the one of this round only.
    assert_eq!(s.matches("model revised").count(), 1, "{s}");
    // Written back when the refit of the applied model moved it from what the line states
    // (the line already carries the value its own refit gave, so it may not move).
    let wrote = s
        .lines()
        .find(|l| l.starts_with("wrote the fitted X.tx.wavelength"));
    let revised = std::fs::read_to_string(&model).unwrap();
    let line = revised
        .lines()
        .find(|l| l.contains("X.tx += ") && l.contains("wavelength fit "))
        .expect("the applied line");
    let written = after(line, "wavelength fit");
    // The candidate already states the value a refit with its line gives; the refit of the
    // model as applied lands there again (the written value has the digits its error supports).
    assert!((written - scanned).abs() < 0.5, "{wrote:?}\n{line}");
    assert!((written - 47.0).abs() < 1.0, "{line}");
    assert_eq!(
        std::fs::read_to_string(dir.join("cmm3.kin.previous")).unwrap(),
        original
    );
    // Started at its optimum, the next fit is of the same model: nothing changed.
    let json = dir.join("fit.json");
    let s = ok(&kin(&["fit", m, d, "-o", json.to_str().unwrap()]));
    assert!(s.contains("unchanged"), "{s}");

    let html = dir.join("report.html");
    ok(&kin(&[
        "report",
        m,
        "--fit",
        json.to_str().unwrap(),
        d,
        "-o",
        html.to_str().unwrap(),
    ]));
    let html = std::fs::read_to_string(&html).unwrap();
    for round in ["round 1: ex along X", "round 2: ex along X"] {
        assert!(html.contains(round), "the report lacks `{round}`");
    }
    assert!(!html.contains("larger than the noise allows"));
}

/// A model of `cmm3` whose truth adds a periodic error along X at `tx_mm` in the positioning
/// error (`X.tx`, 5 µm) and at `ry_mm` in the pitch of the carriage (`X.ry`, 10 µrad, seen
/// through the probe's Abbe arm, which Z changes); 0.2 µm of noise. Returns the directory, the
/// model and the data.
fn screw_and_pitch(name: &str, tx_mm: f64, ry_mm: f64) -> (std::path::PathBuf, String, String) {
    let dir = scratch(name);
    let model = dir.join("cmm3.kin");
    std::fs::write(&model, cmm3(CMM3_ERRORS)).unwrap();
    let truth_model = dir.join("truth.kin");
    let truth_errors = format!(
        "{CMM3_ERRORS}        X.tx += fourier(X, harmonics 1, wavelength {tx_mm} mm)\n        X.ry = fourier(X, harmonics 1, wavelength {ry_mm} mm)\n"
    );
    std::fs::write(&truth_model, cmm3(&truth_errors)).unwrap();
    let truth = dir.join("truth.params");
    std::fs::write(
        &truth,
        "params {\n    X.tx = [3, -2, 1, 0.5, 3, 4] um\n    X.rz[0] = 4 urad\n    Y.ty[0] = 1.5 um\n    Z.tz[0] = 2 um\n    X.ry = [6, -8] urad\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    simulate(
        truth_model.to_str().unwrap(),
        truth.to_str().unwrap(),
        1200,
        5,
        &["--noise", "0.2um"],
        data.to_str().unwrap(),
    );
    let (m, d) = (
        model.to_str().unwrap().to_string(),
        data.to_str().unwrap().to_string(),
    );
    (dir, m, d)
}

/// One leadscrew's periodic error in the positioning error and the pitch of its carriage, at
/// one wavelength: `kin diagnose` proposes one line for both components (`X.tx, X.ry += …`)
/// with one fitted wavelength, and one `--apply` brings the residuals to the noise, the
/// wavelength within two standard errors of the truth.
#[test]
fn one_periodic_error_in_two_components_is_one_line_and_one_round() {
    let (dir, m, d) = screw_and_pitch("shared_wavelength", 20.0, 20.0);
    let json = dir.join("diagnose.json");
    let s = ok(&kin(&["diagnose", &m, &d, "-o", json.to_str().unwrap()]));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let top = &v["findings"][0];
    let text = top["candidate"]["text"].as_str().unwrap_or_default();
    assert!(
        text.starts_with("X.tx, X.ry += ") && text.matches("wavelength fit").count() == 1,
        "the first finding is not one line for both components:\n{s}"
    );
    assert_eq!(top["candidate"]["also"], serde_json::json!(["X.ry"]), "{s}");
    assert_eq!(top["fitted"].as_array().map(Vec::len), Some(1), "{s}");

    let s = ok(&kin(&["diagnose", &m, &d, "--apply", "1"]));
    let revised = std::fs::read_to_string(&m).unwrap();
    let added: Vec<&str> = revised
        .lines()
        .filter(|l| l.contains("wavelength fit"))
        .collect();
    assert_eq!(added.len(), 1, "{revised}");
    assert!(added[0].trim().starts_with("X.tx, X.ry += "), "{revised}");

    // One round: the refit is at the noise, its wavelength (one parameter, from both
    // components) within two standard errors of the truth.
    let fit = dir.join("fit.json");
    let s2 = ok(&kin(&["fit", &m, &d, "-o", fit.to_str().unwrap()]));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&fit).unwrap()).unwrap();
    let sigma = v["sigma"].as_f64().unwrap();
    assert!(sigma <= 0.2 * 1.1, "σ̂ {sigma} after one round:\n{s}\n{s2}");
    let nl = v["nonlinear"].as_array().unwrap();
    assert_eq!(nl.len(), 1, "{s2}");
    assert_eq!(nl[0]["name"], "X.tx.wavelength");
    let (lambda, se) = (
        nl[0]["value"].as_f64().unwrap(),
        nl[0]["se"].as_f64().unwrap(),
    );
    assert!(
        (lambda - 20.0).abs() <= 2.0 * se && se < 0.05,
        "λ = {lambda} ± {se} mm"
    );
    let after = ok(&kin(&["diagnose", &m, &d]));
    assert!(
        !after.contains("X.ry += fourier") && !after.contains("X.tx += fourier"),
        "the periodic error is left for another round:\n{after}"
    );
}

/// The control: the positioning error and the pitch at different wavelengths are two effects,
/// never one line.
#[test]
fn periodic_errors_at_different_wavelengths_are_not_merged() {
    let (dir, m, d) = screw_and_pitch("separate_wavelengths", 20.0, 31.0);
    let json = dir.join("diagnose.json");
    let s = ok(&kin(&["diagnose", &m, &d, "-o", json.to_str().unwrap()]));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for f in v["findings"].as_array().unwrap() {
        let text = f["candidate"]["text"].as_str().unwrap_or_default();
        let targets = text.split(" += ").next().unwrap_or_default();
        assert!(!targets.contains(','), "a merged line `{text}`:\n{s}");
        assert_eq!(f["candidate"]["also"], serde_json::json!([]), "{s}");
    }
}

/// A short Z stroke under a long arm: a tilt of the Y carriage (lever 500 mm + Z) and an offset
/// of Z in x are nearly the same column. A small bend along Z that the model lacks is imitated
/// by the two together — a tilt of tens of µrad and an offset of tens of µm that cancel — and
/// the fit says so, naming both; without the bend the same model fits noise and says nothing.
#[test]
fn a_fit_names_coefficients_that_cancel_each_other() {
    let dir = scratch("cancel");
    let model = dir.join("arm.kin");
    std::fs::write(
        &model,
        "machine arm {
    task position
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 500 mm
    axis Z prismatic along z range 0 mm .. 20 mm
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 400) mm
        tool probe at (0, 0, 100) mm
    }
    errors {
        Y.ry = const
        Z.tx = const
    }
}
",
    )
    .unwrap();
    let m = model.to_str().unwrap();
    let fit = |bend: f64, name: &str| {
        let mut csv = String::from("X[mm],Y[mm],Z[mm],ex[um]\n");
        for i in 0..200u32 {
            let (x, y, z) = (
                f64::from(i * 37 % 500),
                f64::from(i * 53 % 500),
                f64::from(i % 21),
            );
            // A deterministic ±0.05 µm of noise.
            let noise = 0.05 * (f64::from(i) * 2.399).sin();
            csv.push_str(&format!("{x},{y},{z},{}\n", bend * z * z + noise));
        }
        let data = dir.join(name);
        std::fs::write(&data, csv).unwrap();
        ok(&kin(&["fit", m, data.to_str().unwrap()]))
    };
    let bent = fit(0.002, "bent.csv");
    let warning = bent
        .lines()
        .find(|l| l.contains("cancel each other"))
        .unwrap_or_else(|| panic!("no warning:\n{bent}"));
    assert!(
        warning.contains("Y.ry[0] = ") && warning.contains("Z.tx[0] = "),
        "{warning}"
    );
    let straight = fit(0.0, "straight.csv");
    assert!(!straight.contains("cancel each other"), "{straight}");
}
