//! The command line's conventions (issue 17): completion scripts and manual pages generated
//! from the same definition as `--help`, and a checked `--color`.

use std::process::Command;

fn kin(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .env_remove("NO_COLOR")
        .output()
        .expect("kin runs")
}

#[test]
fn completion_scripts_name_every_command_for_each_shell() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = kin(&["completions", shell]);
        assert!(out.status.success(), "{shell}: {out:?}");
        let script = String::from_utf8(out.stdout).expect("utf-8");
        for command in ["check", "fit", "diagnose", "compensate", "iso230-2", "man"] {
            assert!(script.contains(command), "{shell} script lacks `{command}`");
        }
        // An option of one command, so the script completes options and not only commands.
        assert!(
            script.contains("noise-tilt"),
            "{shell} script lacks --noise-tilt"
        );
    }
    let out = kin(&["completions", "tcsh"]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn manual_pages_are_roff_with_one_page_per_command() {
    let out = kin(&["man"]);
    assert!(out.status.success());
    let page = String::from_utf8(out.stdout).expect("utf-8");
    assert!(page.contains(".TH kin 1"), "{page}");
    assert!(
        page.contains("kin\\-fit(1)"),
        "the main page lists the command pages"
    );

    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path().to_str().expect("utf-8 path");
    let out = kin(&["man", "-o", d]);
    assert!(out.status.success(), "{out:?}");
    let fit = std::fs::read_to_string(dir.path().join("kin-fit.1")).expect("kin-fit.1");
    assert!(fit.contains(".TH kin-fit 1"), "{fit}");
    // The options' help and the examples reach the page.
    assert!(fit.contains("noise\\-tilt"), "{fit}");
    assert!(fit.contains("Examples:"), "{fit}");
    assert!(!dir.path().join("kin-help.1").exists());

    let missing = dir.path().join("no/such/folder");
    let out = kin(&["man", "-o", missing.to_str().expect("utf-8")]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a folder"));
}

#[test]
fn color_is_a_checked_choice_and_never_colours_a_pipe() {
    let out = kin(&["check", "--color", "purple", "examples/bridge_cmm.kin"]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("auto") && err.contains("never"), "{err}");

    // A model with an error: its diagnostic goes to standard error, a pipe here.
    let dir = tempfile::tempdir().expect("temp dir");
    let bad = dir.path().join("bad.kin");
    std::fs::write(
        &bad,
        "machine m {\n  axis X prismatic along x range 0..1 m\n  tool chain: Q\n}\n",
    )
    .expect("write");
    let bad = bad.to_str().expect("utf-8");
    let plain = kin(&["check", bad]);
    assert_eq!(plain.status.code(), Some(1));
    assert!(!plain.stderr.contains(&0x1b), "auto colours a pipe");
    let forced = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["check", "--color", "always", bad])
        .env("NO_COLOR", "1")
        .output()
        .expect("kin runs");
    assert!(
        forced.stderr.contains(&0x1b),
        "--color always wins over NO_COLOR: {}",
        String::from_utf8_lossy(&forced.stderr)
    );
}

/// A row beyond an axis's declared range is read (the model is extrapolated there) and said
/// once, with the file, the count and the first line; the fit's result is still written.
#[test]
fn rows_outside_an_axis_range_are_warned_about_once_with_their_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    // Line 5 of the file (the second data row): X = 612 mm on an axis declared 0 .. 600 mm.
    let mut cells: Vec<String> = lines[4].split(',').map(str::to_string).collect();
    cells[1] = "612".into();
    lines[4] = cells.join(",");
    let data = dir.path().join("points.csv");
    std::fs::write(&data, lines.join("\n") + "\n").expect("write");
    let fit = dir.path().join("fit.json");
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        data.to_str().expect("utf-8"),
        "-o",
        fit.to_str().expect("utf-8"),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let warning =
        "1 of 1000 rows put X outside its declared range 0 .. 600 mm (first at line 5: 612 mm";
    assert_eq!(err.matches(warning).count(), 1, "{err}");
    assert!(fit.exists());

    // The bundled data are inside every range: no such warning.
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        "examples/data/bridge_cmm_points.csv",
    ]);
    assert!(out.status.success());
    assert!(!String::from_utf8_lossy(&out.stderr).contains("declared range"));
}

/// `--allow CODE` silences one kind of warning, `-q` all of them; errors cannot be allowed.
#[test]
fn warnings_are_silenced_by_code_or_all_at_once() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string("examples/bridge_cmm.kin").expect("model");
    let at = text.find("    axis X").expect("an axis line");
    let model = dir.path().join("m.kin");
    std::fs::write(
        &model,
        format!(
            "{}    input unused : temperature rise\n{}",
            &text[..at],
            &text[at..]
        ),
    )
    .expect("write");
    let m = model.to_str().expect("utf-8");
    let stderr = |args: &[&str]| {
        let out = kin(args);
        assert!(out.status.success(), "{args:?}: {out:?}");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let plain = stderr(&["check", "--no-identify", m]);
    assert_eq!(plain.matches("W0101").count(), 1, "{plain}");
    assert!(!stderr(&["check", "--no-identify", "--allow", "W0101", m]).contains("W0101"));
    assert!(!stderr(&["check", "--no-identify", m, "--allow=w0101,W0801"]).contains("W0101"));
    assert!(!stderr(&["-q", "check", "--no-identify", m]).contains("W0101"));
    // Another code leaves this one alone.
    assert!(stderr(&["check", "--no-identify", "--allow", "W0801", m]).contains("W0101"));
    // The JSON report leaves allowed warnings out too.
    let out = kin(&[
        "check",
        "--no-identify",
        "--format",
        "json",
        "--allow",
        "W0101",
        m,
    ]);
    assert!(!String::from_utf8_lossy(&out.stdout).contains("W0101"));

    for bad in ["E0601", "W01", "nonsense"] {
        let out = kin(&["check", "--allow", bad, m]);
        assert_eq!(out.status.code(), Some(2), "{bad}");
    }

    // The data warning has its code too.
    let text = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let data = dir.path().join("points.csv");
    std::fs::write(&data, text.replacen("\n276.14629506687504,", "\n-20,", 1)).expect("write");
    let d = data.to_str().expect("utf-8");
    let fit = stderr(&["fit", "examples/bridge_cmm.kin", d]);
    assert!(fit.contains("warning[W0801]"), "{fit}");
    assert!(fit.contains("put Y outside its declared range"), "{fit}");
    assert!(!stderr(&["fit", "examples/bridge_cmm.kin", d, "--allow", "W0801"]).contains("W0801"));
}

/// A fit of another revision of the model is an error wherever a fit is read, unless only the
/// text changed and the coefficients are the same (then warning W0802).
#[test]
fn a_fit_of_another_revision_is_refused_everywhere() {
    let dir = tempfile::tempdir().expect("temp dir");
    let model = dir.path().join("m.kin");
    let text = std::fs::read_to_string("examples/bridge_cmm.kin").expect("model");
    std::fs::write(&model, &text).expect("write");
    let (m, fit) = (model.to_str().expect("utf-8"), dir.path().join("fit.json"));
    let f = fit.to_str().expect("utf-8");
    let data = "examples/data/bridge_cmm_points.csv";
    assert!(kin(&["fit", m, data, "-o", f]).status.success());
    let out_of = |name: &str| dir.path().join(name).to_str().expect("utf-8").to_string();
    let (html, csv) = (out_of("r.html"), out_of("e.csv"));
    let commands: [Vec<&str>; 3] = [
        vec!["report", m, "--fit", f, "-o", &html],
        vec!["eval", m, data, "--params", f, "-o", &csv],
        vec!["correct", m, "--fit", f, data, "-o", &csv],
    ];
    // A comment: the same coefficients, a warning.
    std::fs::write(&model, format!("{text}// checked again\n")).expect("write");
    for args in &commands {
        let out = kin(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?}: {err}");
        assert!(err.contains("warning[W0802]"), "{args:?}: {err}");
    }
    // Another knot: other coefficients, an error naming the first that differs.
    assert!(
        text.contains("X.tx = spline(X, knots 4)"),
        "the example changed"
    );
    std::fs::write(
        &model,
        text.replace("X.tx = spline(X, knots 4)", "X.tx = spline(X, knots 5)"),
    )
    .expect("write");
    for args in &commands {
        let out = kin(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("is a fit of another revision"),
            "{args:?}: {err}"
        );
        assert!(err.contains("`X.tx[2]`"), "{args:?}: {err}");
    }
}

/// `--delimiter` fixes the separator every command reads its data files with.
#[test]
fn the_delimiter_option_overrides_detection() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    // The same file with `;` separators and decimal commas, as a spreadsheet saves it.
    let semi: String = text
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                l.to_string()
            } else {
                l.replace(',', ";").replace('.', ",")
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let data = dir.path().join("semi.csv");
    std::fs::write(&data, semi + "\n").expect("write");
    let d = data.to_str().expect("utf-8");
    let m = "examples/bridge_cmm.kin";
    let fit = |extra: &[&str]| {
        let mut args = vec!["fit", m, d, "--format", "json"];
        args.extend(extra);
        kin(&args)
    };
    let json = |o: &std::process::Output| -> serde_json::Value {
        assert!(o.status.success(), "{o:?}");
        serde_json::from_slice(&o.stdout).expect("FIT.json on stdout")
    };
    let detected = json(&fit(&[]));
    let given = json(&fit(&["--delimiter", ";"]));
    assert_eq!(detected["coefficients"], given["coefficients"]);
    assert_eq!(detected["rows"], 3000);
    // Told the wrong separator, the reader says so at the header instead of guessing.
    let wrong = fit(&["--delimiter", ","]);
    assert_eq!(wrong.status.code(), Some(1), "{wrong:?}");
    assert!(String::from_utf8_lossy(&wrong.stderr).contains("semi.csv"));
    let bad = fit(&["--delimiter", "|"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("`,`, `;` or `tab`"));
}

/// `-v` says what each step did (files read with their sizes and rows, the compile time, the
/// engine, the total time); `-q` and `-v` together are a usage error.
#[test]
fn verbose_says_what_each_step_did_and_conflicts_with_quiet() {
    let dir = tempfile::tempdir().expect("temp dir");
    let fit = dir.path().join("fit.json");
    let out = kin(&[
        "-v",
        "fit",
        "examples/bridge_cmm.kin",
        "examples/data/bridge_cmm_points.csv",
        "-o",
        fit.to_str().expect("utf-8"),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    for said in [
        "kin: engine: jit",
        "kin: read `examples/bridge_cmm.kin` (",
        "kin: compiled `examples/bridge_cmm.kin` in ",
        "kin: read 1000 rows of `examples/data/bridge_cmm_points.csv` (",
        "kin: `kin fit` ended with exit code 0 in ",
    ] {
        assert!(err.contains(said), "lacks {said:?}: {err}");
    }
    // Without -v none of it.
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        "examples/data/bridge_cmm_points.csv",
    ]);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("kin: "));

    let both = kin(&["-q", "check", "-v", "examples/bridge_cmm.kin"]);
    assert_eq!(both.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&both.stderr).contains("cannot be used with"));
}

/// `--strict` turns poses outside a declared range into an error (exit 1) naming the file,
/// the axis and the first line; nothing is written.
#[test]
fn strict_refuses_poses_outside_a_declared_range() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let data = dir.path().join("points.csv");
    std::fs::write(&data, text.replacen("\n276.14629506687504,", "\n-20,", 1)).expect("write");
    let d = data.to_str().expect("utf-8");
    let fit = dir.path().join("fit.json");
    let f = fit.to_str().expect("utf-8");
    let out = kin(&["fit", "examples/bridge_cmm.kin", d, "--strict", "-o", f]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("error[W0801]"), "{err}");
    assert!(err.contains("put Y outside its declared range"), "{err}");
    assert!(!fit.exists(), "a refused fit wrote its output");
    // --allow does not make it pass: --strict is asked for explicitly.
    let out = kin(&[
        "--strict",
        "eval",
        "examples/bridge_cmm.kin",
        d,
        "--allow",
        "W0801",
    ]);
    assert_eq!(out.status.code(), Some(1));
    // The same file without --strict: a warning and a result.
    let out = kin(&["fit", "examples/bridge_cmm.kin", d, "-o", f]);
    assert!(out.status.success());
    assert!(fit.exists());
    // Data inside every range pass --strict.
    let out = kin(&[
        "fit",
        "examples/bridge_cmm.kin",
        "examples/data/bridge_cmm_points.csv",
        "--strict",
    ]);
    assert!(out.status.success(), "{out:?}");
}

/// An output in a folder that does not exist is refused at once (exit 2), before anything is
/// read or computed, by every command that writes one.
#[test]
fn outputs_are_checked_before_any_work() {
    let dir = tempfile::tempdir().expect("temp dir");
    let m = "examples/bridge_cmm.kin";
    let data = "examples/data/bridge_cmm_points.csv";
    let fit = dir.path().join("fit.json");
    let f = fit.to_str().expect("utf-8");
    assert!(kin(&["fit", m, data, "-o", f]).status.success());
    let missing = dir.path().join("no/such/folder");
    let at = |name: &str| missing.join(name).to_str().expect("utf-8").to_string();
    let (json, csv, html, kin_file) = (at("out.json"), at("out.csv"), at("out.html"), at("o.kin"));
    // A machine file that does not exist either: had the command started its work, the error
    // would be about the machine, not the output.
    let gone = dir.path().join("gone.kin");
    let g = gone.to_str().expect("utf-8");
    let commands: Vec<Vec<&str>> = vec![
        vec!["fit", g, data, "-o", &json],
        vec!["diagnose", g, data, "-o", &json],
        vec!["simulate", g, "--sample", "10", "-o", &csv],
        vec!["eval", g, data, "-o", &csv],
        vec!["report", g, "--fit", f, "-o", &html],
        vec![
            "compensate",
            g,
            "--fit",
            f,
            "--grid",
            "X=0:500:50",
            "-o",
            &csv,
        ],
        vec!["correct", g, "--fit", f, data, "-o", &csv],
        vec!["design", g, "--generate", "ballbar", "-o", &csv],
        vec!["import", "urdf", "examples/urdf/ur5.urdf", "-o", &kin_file],
    ];
    for args in &commands {
        let out = kin(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("does not exist"), "{args:?}: {err}");
        assert!(
            !err.contains("gone.kin"),
            "{args:?} read its input first: {err}"
        );
    }
}

/// With `--format json` a failure is one JSON document on standard output too: `ok: false`,
/// the exit code, and each error with its code, message, file, line and column (spec/json.md).
#[test]
fn failures_are_json_documents_when_json_is_asked_for() {
    let dir = tempfile::tempdir().expect("temp dir");
    let json = |args: &[&str], code: i32| -> serde_json::Value {
        let out = kin(args);
        assert_eq!(out.status.code(), Some(code), "{args:?}: {out:?}");
        let doc: serde_json::Value =
            serde_json::from_slice(&out.stdout).expect("standard output is one JSON document");
        assert_eq!(doc["ok"], false);
        assert_eq!(doc["exit_code"], code);
        assert!(
            !out.stderr.is_empty(),
            "the human message stays on standard error"
        );
        doc
    };
    // A file that cannot be read: exit 2, code `io`, the file named.
    let gone = dir.path().join("gone.kin");
    let g = gone.to_str().expect("utf-8");
    let doc = json(
        &[
            "fit",
            g,
            "examples/data/bridge_cmm_points.csv",
            "--format",
            "json",
        ],
        2,
    );
    assert_eq!(doc["errors"][0]["code"], "io");
    assert_eq!(doc["errors"][0]["file"], g);

    // A model with an error: its code, line and column.
    let bad = dir.path().join("bad.kin");
    std::fs::write(
        &bad,
        "machine m {\n  axis X prismatic along x range 0..1 m\n  tool chain: Q\n}\n",
    )
    .expect("write");
    let b = bad.to_str().expect("utf-8");
    let doc = json(
        &[
            "diagnose",
            b,
            "examples/data/bridge_cmm_points.csv",
            "--format=json",
        ],
        1,
    );
    let e = &doc["errors"][0];
    assert!(
        e["code"].as_str().is_some_and(|c| c.starts_with('E')),
        "{doc}"
    );
    assert_eq!(e["file"], b);
    assert_eq!(e["line"], 3, "{doc}");
    assert!(e["column"].as_u64().is_some_and(|c| c > 1), "{doc}");

    // A measurement file with bad content: code `data`, located by line and column.
    let text = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let data = dir.path().join("points.csv");
    std::fs::write(
        &data,
        text.replacen("\n276.14629506687504,", "\n27x6.1,", 1),
    )
    .expect("write");
    let d = data.to_str().expect("utf-8");
    let doc = json(
        &["fit", "examples/bridge_cmm.kin", d, "--format", "json"],
        1,
    );
    let e = &doc["errors"][0];
    assert_eq!(e["code"], "data", "{doc}");
    assert_eq!(e["file"], d);
    assert!(e["line"].as_u64().is_some_and(|l| l > 1), "{doc}");
    assert!(e["column"].as_u64().is_some(), "{doc}");

    // A usage error: exit 2, code `usage`.
    let doc = json(
        &[
            "fit",
            "examples/bridge_cmm.kin",
            "--format",
            "json",
            "--holdout",
            "2",
        ],
        2,
    );
    assert_eq!(doc["errors"][0]["code"], "usage");
    assert!(doc["errors"][0]["message"]
        .as_str()
        .is_some_and(|m| m.contains("--holdout")));

    // `kin check --format json` answers with its own report, once, even for a broken model.
    let out = kin(&["check", "--format", "json", b]);
    assert_eq!(out.status.code(), Some(1));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one document");
    assert_eq!(report["ok"], false);
    assert!(report["diagnostics"].is_array());

    // Without --format json, standard output stays empty on a failure.
    let out = kin(&["fit", g, "examples/data/bridge_cmm_points.csv"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(out.stdout.is_empty());
}

/// The new global options reach the completion scripts and the manual pages, with the shared
/// help of `--color` on every command's page.
#[test]
fn completions_and_manual_pages_know_the_global_options() {
    for shell in ["bash", "zsh", "fish"] {
        let out = kin(&["completions", shell]);
        let script = String::from_utf8(out.stdout).expect("utf-8");
        for option in ["--verbose", "--strict", "--quiet", "--allow"] {
            let bare = option.trim_start_matches('-');
            assert!(script.contains(bare), "{shell} script lacks {option}");
        }
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let out = kin(&["man", "-o", dir.path().to_str().expect("utf-8")]);
    assert!(out.status.success());
    let page = std::fs::read_to_string(dir.path().join("kin.1")).expect("kin.1");
    assert!(page.contains("strict"), "{page}");
    assert!(page.contains("verbose"), "{page}");
    let simulate = std::fs::read_to_string(dir.path().join("kin-simulate.1")).expect("page");
    assert!(
        simulate.contains("NO_COLOR"),
        "--color lacks its help: {simulate}"
    );
    // `kin help fit` reads like `cargo help build`: the description, every argument, examples.
    let out = kin(&["help", "fit"]);
    let help = String::from_utf8(out.stdout).expect("utf-8");
    assert!(
        help.contains("<MACHINE>") && help.contains("The `.kin` model file"),
        "{help}"
    );
    assert!(help.contains("Examples:"), "{help}");
    assert!(
        help.contains("--solver") && help.contains("column-pivoted QR"),
        "{help}"
    );
    // File options say what they take.
    let out = kin(&["help", "report"]);
    let help = String::from_utf8(out.stdout).expect("utf-8");
    assert!(
        help.contains("--fit <FIT.json>") && help.contains("-o, --output <OUT>"),
        "{help}"
    );
}

/// A `// kin: allow CODE` comment in the model silences its warnings for every command run on
/// it, as `--allow` does; a code kin does not have is warning W0803 at the code.
#[test]
fn a_model_allows_warnings_with_a_comment() {
    let dir = tempfile::tempdir().expect("temp dir");
    let text = std::fs::read_to_string("examples/bridge_cmm.kin").expect("model");
    let at = text.find("    axis X").expect("an axis line");
    let with = |comment: &str| {
        format!(
            "{}    input unused : temperature rise {comment}\n{}",
            &text[..at],
            &text[at..]
        )
    };
    let model = dir.path().join("m.kin");
    let m = model.to_str().expect("utf-8");
    let stderr = |args: &[&str]| {
        let out = kin(args);
        assert!(out.status.success(), "{args:?}: {out:?}");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    std::fs::write(&model, with("")).expect("write");
    assert!(stderr(&["check", "--no-identify", m]).contains("W0101"));
    std::fs::write(&model, with("// kin: allow W0101 logged for the record")).expect("write");
    let err = stderr(&["check", "--no-identify", m]);
    assert!(!err.contains("W0101") && !err.contains("W0803"), "{err}");
    // The JSON report leaves it out as well.
    let out = kin(&["check", "--no-identify", "--format", "json", m]);
    assert!(!String::from_utf8_lossy(&out.stdout).contains("W0101"));

    // A data warning of a run on this model, allowed in the model.
    let data = std::fs::read_to_string("examples/data/bridge_cmm_points.csv").expect("data");
    let points = dir.path().join("points.csv");
    std::fs::write(&points, data.replacen("\n276.14629506687504,", "\n-20,", 1)).expect("write");
    let p = points.to_str().expect("utf-8");
    std::fs::write(&model, &text).expect("write");
    assert!(stderr(&["fit", m, p]).contains("W0801"));
    std::fs::write(&model, format!("{text}// kin: allow W0801\n")).expect("write");
    assert!(!stderr(&["fit", m, p]).contains("W0801"));

    // A typo is said, located, and allows nothing.
    std::fs::write(&model, with("// kin: allow W0110")).expect("write");
    let err = stderr(&["check", "--no-identify", "--color", "never", m]);
    assert!(
        err.contains("W0803") && err.contains("`W0110` is not a warning kin has"),
        "{err}"
    );
    assert!(err.contains("W0101"), "{err}");
}
