//! `--format json` and the documents of spec/json.md: standard output holds the document alone,
//! it equals the file `-o` writes, and every field kin writes is documented (a field added
//! without its line in spec/json.md fails here).

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

use serde_json::Value;

const MODEL: &str = "examples/bridge_cmm.kin";
const DATA: &str = "examples/data/bridge_cmm_points.csv";

fn kin(args: &[&str]) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .output()
        .expect("kin runs");
    let (stdout, stderr) = (
        String::from_utf8(out.stdout).expect("utf-8"),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(out.status.success(), "kin {args:?}: {stderr}");
    (stdout, stderr)
}

/// The fields of one section of spec/json.md: the first cell of each table row, in backticks.
fn documented(section: &str) -> BTreeSet<String> {
    let spec = std::fs::read_to_string("spec/json.md").expect("spec/json.md");
    let start = spec
        .find(&format!("## {section}"))
        .expect("section in spec/json.md");
    let body = &spec[start + 3..];
    let body = &body[..body.find("\n## ").unwrap_or(body.len())];
    body.lines()
        .filter_map(|l| l.strip_prefix("| `"))
        .filter_map(|l| l.split('`').next())
        .map(str::to_string)
        .collect()
}

/// Every field path of `v` (`files[].components[].rms`), each array's elements merged.
fn paths(v: &Value, prefix: &str, out: &mut BTreeSet<String>) {
    match v {
        Value::Object(map) => {
            for (k, x) in map {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                out.insert(p.clone());
                paths(x, &p, out);
            }
        }
        Value::Array(items) => {
            for x in items {
                paths(x, &format!("{prefix}[]"), out);
            }
        }
        _ => {}
    }
}

/// Fields FIT.json holds only for what the data do not determine.
const DEFICIENT_ONLY: [&str; 11] = [
    "nonlinear[].note",
    "coefficients[].note",
    "estimability.groups[].members",
    "estimability.groups[].determined",
    // Written by a fit whose coefficients cancel each other (tests/rounds.rs).
    "cancelling[].members",
    "cancelling[].largest",
    "cancelling[].joint",
    // Written by a fit whose plan barely determines some constants (tests/registration.rs).
    "weak[].members",
    "weak[].inflation",
    // Written by a fit of orientations measured in an instrument's frame
    // (runtime/estimate/tests/registration.rs).
    "registration[].targets[].turn",
    "registration[].targets[].turn_u",
];

/// FIT.json's arrays of one kind share their fields, documented once (spec/json.md says which).
fn fit_alias(path: &str) -> String {
    for (from, to) in [
        ("nonlinear[].note", "nonlinear[].note"),
        ("nuisance[].note", "coefficients[].note"),
        ("nonlinear[]", "coefficients[]"),
        ("nuisance[]", "coefficients[]"),
        ("validation[]", "files[]"),
        ("validation_residuals[]", "residuals[]"),
        ("outliers[]", "residuals[]"),
    ] {
        if let Some(rest) = path.strip_prefix(from) {
            return format!("{to}{rest}");
        }
    }
    path.to_string()
}

fn undocumented(doc: &Value, section: &str, alias: fn(&str) -> String) -> Vec<String> {
    let known = documented(section);
    let mut found = BTreeSet::new();
    paths(doc, "", &mut found);
    found
        .into_iter()
        .map(|p| alias(&p))
        .filter(|p| !known.contains(p))
        .collect()
}

#[test]
fn fit_prints_fit_json_alone_and_every_field_is_documented() {
    let dir = tempfile::tempdir().expect("temp dir");
    // A fitted wavelength, so `nonlinear` is not empty.
    let model = dir.path().join("cmm.kin");
    let text = std::fs::read_to_string(MODEL).expect("model");
    assert!(text.contains("wavelength 25.4 mm"), "the example changed");
    let text = text.replacen("wavelength 25.4 mm", "wavelength fit 25.4 mm", 1);
    std::fs::write(&model, text).expect("write model");
    let model = model.to_str().expect("utf-8");
    let out = dir.path().join("fit.json");
    let out_s = out.to_str().expect("utf-8");
    // Validation data: a copy of the fitted file (the same file twice is refused).
    let again = dir.path().join("again.csv");
    std::fs::copy(DATA, &again).expect("copy");
    let again = again.to_str().expect("utf-8");
    let mut seen = Vec::new();
    for extra in [
        vec!["--noise", "0.2um"],
        vec!["--stepwise", "1e-4"],
        vec!["--validate", again],
        // A σ per file: `noise_per_file`.
        vec!["--noise-per-file"],
    ] {
        let mut args = vec!["fit", model, DATA, "--format", "json", "-o", out_s];
        args.extend(extra.iter().copied());
        let (stdout, _) = kin(&args);
        let printed: Value = serde_json::from_str(&stdout).expect("stdout is one JSON document");
        let written: Value =
            serde_json::from_str(&std::fs::read_to_string(&out).expect("FIT.json"))
                .expect("FIT.json parses");
        assert_eq!(printed, written, "{extra:?}: stdout and -o differ");
        assert!(Path::new(&out.with_extension("params")).exists());
        let missing = undocumented(&printed, "FIT.json", fit_alias);
        assert!(
            missing.is_empty(),
            "{extra:?}: fields not in spec/json.md: {missing:?}"
        );
        seen.push(printed);
    }
    // Absolute positions: `registration`.
    let ur10 = dir.path().join("ur10.kin");
    std::fs::copy("examples/ur10/ur10.kin", &ur10).expect("copy the ur10 model");
    let (stdout, _) = kin(&[
        "fit",
        ur10.to_str().expect("utf-8"),
        "examples/ur10/tracker.csv",
        "--format",
        "json",
        "-o",
        out_s,
    ]);
    let printed: Value = serde_json::from_str(&stdout).expect("stdout is one JSON document");
    let missing = undocumented(&printed, "FIT.json", fit_alias);
    assert!(
        missing.is_empty(),
        "registration: fields not in spec/json.md: {missing:?}"
    );
    assert!(printed["registration"][0]["targets"][0]["offset"].is_array());
    seen.push(printed);
    // And no documented field is stale: each was written by one of the runs (but the fields
    // only a deficient design writes, which these data are not).
    let mut written = BTreeSet::new();
    for doc in &seen {
        let mut found = BTreeSet::new();
        paths(doc, "", &mut found);
        written.extend(found.iter().map(|p| fit_alias(p)));
    }
    let stale: Vec<String> = documented("FIT.json")
        .into_iter()
        .filter(|f| !written.contains(f) && !DEFICIENT_ONLY.contains(&f.as_str()))
        .collect();
    assert!(stale.is_empty(), "documented but never written: {stale:?}");
    // The runs did produce the optional parts the table documents.
    assert!(seen[0]["weights"]["chi2"].is_number());
    assert!(seen[1]["stepwise"]["steps"].is_array());
    assert!(!seen[2]["validation"].as_array().expect("array").is_empty());
    assert!(!seen[0]["nonlinear"].as_array().expect("array").is_empty());
    assert!(seen[3]["noise_per_file"]["files"][0]["sigma_hat"].is_number());
}

#[test]
fn diagnose_prints_diagnose_json_alone_and_every_field_is_documented() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("diagnose.json");
    let (stdout, _) = kin(&[
        "diagnose",
        MODEL,
        DATA,
        "--noise",
        "0.2um",
        "--format",
        "json",
        "-o",
        out.to_str().expect("utf-8"),
    ]);
    let printed: Value = serde_json::from_str(&stdout).expect("stdout is one JSON document");
    let written: Value =
        serde_json::from_str(&std::fs::read_to_string(&out).expect("DIAGNOSE.json"))
            .expect("parses");
    assert_eq!(printed, written);
    assert!(!printed["findings"].as_array().expect("array").is_empty());
    let missing = undocumented(&printed, "DIAGNOSE.json", str::to_string);
    assert!(
        missing.is_empty(),
        "fields not in spec/json.md: {missing:?}"
    );

    // `--apply` edits the model and refits: not a document on standard output.
    let refused = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["diagnose", MODEL, DATA, "--format", "json", "--apply", "1"])
        .output()
        .expect("kin runs");
    assert_eq!(refused.status.code(), Some(2));
}

/// The page's tables are read as this test expects (a changed layout must not pass vacuously).
#[test]
fn every_documented_section_is_found() {
    for section in ["FIT.json", "DIAGNOSE.json"] {
        let fields = documented(section);
        assert!(fields.len() > 40, "{section}: {}", fields.len());
        assert!(fields.iter().all(|f| !f.contains(' ')), "{fields:?}");
    }
}

/// A command asked for JSON that fails prints the error document of spec/json.md ("Errors")
/// on standard output, every field of it documented and every documented field written.
#[test]
fn failures_print_the_documented_error_document() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string(DATA).expect("data");
    let data = dir.path().join("points.csv");
    std::fs::write(
        &data,
        text.replacen("\n276.14629506687504,", "\n27x6.1,", 1),
    )
    .expect("write");
    let mut seen = BTreeSet::new();
    for (args, code) in [
        (vec!["fit", MODEL, data.to_str().expect("utf-8")], 1),
        (vec!["diagnose", MODEL, "no-such-file.csv"], 2),
        (vec!["fit", MODEL, DATA, "--holdout", "NaN"], 2),
    ] {
        let mut args = args;
        args.extend(["--format", "json"]);
        let out = Command::new(env!("CARGO_BIN_EXE_kin"))
            .args(&args)
            .output()
            .expect("kin runs");
        assert_eq!(out.status.code(), Some(code), "{args:?}");
        let doc: Value = serde_json::from_slice(&out.stdout).expect("one JSON document");
        assert_eq!(doc["exit_code"], code);
        let missing = undocumented(&doc, "Errors", str::to_string);
        assert!(
            missing.is_empty(),
            "{args:?}: not in spec/json.md: {missing:?}"
        );
        paths(&doc, "", &mut seen);
    }
    let stale: Vec<String> = documented("Errors")
        .into_iter()
        .filter(|f| !seen.contains(f))
        .collect();
    assert!(stale.is_empty(), "documented but never written: {stale:?}");
}

/// `kin eval` and `kin simulate` with `--format json`: the file `-o` writes, as the document of
/// spec/json.md ("Measurements"), cell for cell (the CSV read here as data.md describes it).
#[test]
fn eval_and_simulate_print_their_measurements_as_the_documented_document() {
    let dir = tempfile::tempdir().expect("temp dir");
    let fit = dir.path().join("fit.json");
    let csv = dir.path().join("out.csv");
    let (f, c) = (fit.to_str().expect("utf-8"), csv.to_str().expect("utf-8"));
    kin(&["fit", MODEL, DATA, "-o", f]);
    let mut seen = BTreeSet::new();
    for args in [
        vec![
            "eval",
            MODEL,
            DATA,
            "--params",
            f,
            "--uncertainty",
            "-o",
            c,
            "--format",
            "json",
        ],
        vec![
            "simulate", MODEL, "--sample", "20", "--seed", "3", "-o", c, "--format", "json",
        ],
    ] {
        let (stdout, _) = kin(&args);
        let doc: Value = serde_json::from_str(&stdout).expect("one JSON document");
        let missing = undocumented(&doc, "Measurements", str::to_string);
        assert!(
            missing.is_empty(),
            "{args:?}: not in spec/json.md: {missing:?}"
        );
        paths(&doc, "", &mut seen);
        // The file: `#` comment lines, a header of NAME[UNIT] cells, rows of cells.
        let text = std::fs::read_to_string(&csv).expect("the -o file");
        let mut lines = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.is_empty());
        let header: Vec<&str> = lines.next().expect("header").split(',').collect();
        let columns = doc["columns"].as_array().expect("columns");
        assert_eq!(columns.len(), header.len());
        for (h, col) in header.iter().zip(columns) {
            let name = h.split('[').next().expect("name");
            assert_eq!(col["name"], name, "{h}");
            match h.split_once('[') {
                Some((_, unit)) => assert_eq!(col["unit"], unit.trim_end_matches(']')),
                None => assert!(col["unit"].is_null(), "{h}"),
            }
        }
        let rows = doc["rows"].as_array().expect("rows");
        let file_rows: Vec<&str> = lines.collect();
        assert_eq!(rows.len(), file_rows.len());
        for (row, line) in rows.iter().zip(&file_rows) {
            for (v, cell) in row.as_array().expect("row").iter().zip(line.split(',')) {
                match cell.parse::<f64>() {
                    Ok(x) => assert_eq!(v.as_f64(), Some(x), "{cell}"),
                    Err(_) => assert_eq!(v.as_str(), Some(cell)),
                }
            }
        }
        assert_eq!(
            doc["comments"].as_array().map(Vec::len),
            Some(text.lines().filter(|l| l.starts_with('#')).count())
        );
    }
    let stale: Vec<String> = documented("Measurements")
        .into_iter()
        .filter(|f| !seen.contains(f))
        .collect();
    assert!(stale.is_empty(), "documented but never written: {stale:?}");
}

/// `kin check --format json`: the report of spec/json.md ("Check report") for a model that
/// compiles and for one that does not.
#[test]
fn check_prints_the_documented_report() {
    let dir = tempfile::tempdir().expect("temp dir");
    let bad = dir.path().join("bad.kin");
    std::fs::write(
        &bad,
        "machine m {\n  axis X prismatic along x range 0..1 m\n  tool chain: Q\n}\n",
    )
    .expect("write");
    // The units map's keys are the model's units: one documented entry stands for them.
    let alias = |p: &str| match p.strip_prefix("summary.units.") {
        Some(_) => "summary.units".to_string(),
        None => p.to_string(),
    };
    let mut seen = BTreeSet::new();
    for (file, code) in [
        ("examples/milling_5axis.kin", 0),
        (bad.to_str().expect("utf-8"), 1),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_kin"))
            .args(["check", "--format", "json", file])
            .output()
            .expect("kin runs");
        assert_eq!(out.status.code(), Some(code), "{file}");
        let doc: Value = serde_json::from_slice(&out.stdout).expect("one JSON document");
        assert_eq!(doc["ok"], code == 0);
        let known = documented("Check report");
        let mut found = BTreeSet::new();
        paths(&doc, "", &mut found);
        let missing: Vec<String> = found
            .iter()
            .map(|p| alias(p))
            .filter(|p| !known.contains(p))
            .collect();
        assert!(
            missing.is_empty(),
            "{file}: not in spec/json.md: {missing:?}"
        );
        seen.extend(found.iter().map(|p| alias(p)));
    }
    let stale: Vec<String> = documented("Check report")
        .into_iter()
        .filter(|f| !seen.contains(f))
        .collect();
    assert!(stale.is_empty(), "documented but never written: {stale:?}");
}
