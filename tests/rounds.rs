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
        !s.contains("σ̂/σ") && s.contains("um on positions and lengths, urad on rotations"),
        "{s}"
    );

    let out = kin(&["fit", m, d, "--noise", "0.3um"]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("no noise is stated for them"),
        "{}",
        text(&out.stderr)
    );
}
