//! No input makes `kin` crash or answer with nonsense: the inputs of an adversarial run that once
//! panicked (exit 101), were silently accepted, or were reported without a usable location, each
//! run through the real binary. Every test checks the exit code, that it is not 101, and the
//! message the user sees.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("kin runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kin-input-safety-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir.join(name)
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 temp path")
}

/// The exit code, with the crash status ruled out and the output shown on failure.
fn code(out: &Output) -> i32 {
    let code = out.status.code();
    assert_ne!(code, Some(101), "kin panicked:\n{}", text(&out.stderr));
    assert!(
        !text(&out.stderr).contains("panicked"),
        "{}",
        text(&out.stderr)
    );
    code.unwrap_or(-1)
}

/// One prismatic axis, 5 coefficients: fits in a moment.
const MODEL: &str = "machine m {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain { X moving tool t at (0, 0, -100) mm }
    errors { X.tx = spline(X, knots 2)  X.ry = const }
}
";

/// A model file and 40 simulated rows of `ex ey ez` (header on line 3, data from line 4), in a
/// folder of the test's own.
fn setup(name: &str) -> (PathBuf, PathBuf) {
    let model = tmp(&format!("{name}.kin"));
    std::fs::write(&model, MODEL).expect("model");
    let data = tmp(&format!("{name}.csv"));
    let out = kin(&[
        "simulate",
        path(&model),
        "--sample",
        "40",
        "--noise",
        "0.1um",
        "-o",
        path(&data),
    ]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    (model, data)
}

/// `data` with the cell at (1-based line, 0-based column) replaced.
fn with_cell(data: &Path, line: usize, column: usize, value: &str, name: &str) -> PathBuf {
    let text = std::fs::read_to_string(data).expect("data");
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut cells: Vec<String> = lines[line - 1].split(',').map(str::to_string).collect();
    cells[column] = value.to_string();
    lines[line - 1] = cells.join(",");
    let out = tmp(name);
    std::fs::write(&out, lines.join("\n") + "\n").expect("write");
    out
}

/// Where a cell starts, 1-based in characters, as the reader reports it.
fn char_column(data: &Path, line: usize, column: usize) -> usize {
    let text = std::fs::read_to_string(data).expect("data");
    let l = text.lines().nth(line - 1).expect("line");
    1 + l
        .split(',')
        .take(column)
        .map(|c| c.chars().count() + 1)
        .sum::<usize>()
}

#[test]
fn absurd_cells_are_reported_at_their_cell() {
    let (model, data) = setup("cells");
    // Once a panic in the solver (1e160 mm) and a fit of ±1e307 coefficients with σ̂ = inf (1e308).
    let cases = [
        (
            5,
            0,
            "1e160",
            "`X`",
            "beyond the largest plausible axis position, ±1e7 mm",
        ),
        (
            6,
            1,
            "1e308",
            "`ex`",
            "beyond the largest plausible error, ±1e6 um",
        ),
        (7, 2, "nan", "`ey`", "`nan`: expected a finite number in um"),
        (
            8,
            3,
            "-inf",
            "`ez`",
            "`-inf`: expected a finite number in um",
        ),
        (
            9,
            1,
            "1e400",
            "`ex`",
            "`1e400`: expected a finite number in um",
        ),
    ];
    for (line, column, value, name, reason) in cases {
        let bad = with_cell(&data, line, column, value, &format!("cell_{line}.csv"));
        let out = kin(&["fit", path(&model), path(&bad)]);
        let stderr = text(&out.stderr);
        assert_eq!(code(&out), 1, "{value}: {stderr}");
        let at = format!(
            "line {line}, column {} ({name}): ",
            char_column(&bad, line, column)
        );
        assert!(stderr.contains(&at), "{value}: expected `{at}` in {stderr}");
        assert!(stderr.contains(reason), "{value}: {stderr}");
        assert!(stderr.contains(&format!("cell_{line}.csv")), "{stderr}");
        assert!(
            out.stdout.is_empty(),
            "nothing fitted: {}",
            text(&out.stdout)
        );
    }
    // The same cells as poses to evaluate the model at: rejected the same way.
    let bad = with_cell(&data, 5, 0, "1e160", "poses.csv");
    let out = kin(&["eval", path(&model), path(&bad)]);
    assert_eq!(code(&out), 1, "{}", text(&out.stderr));
    // An empty observed cell still means "not observed", and the largest plausible value reads.
    let empty = with_cell(&data, 5, 1, "", "empty.csv");
    let out = kin(&["fit", path(&model), path(&empty)]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("119 observations"),
        "{}",
        text(&out.stdout)
    );
}

#[test]
fn bad_option_values_are_usage_errors_naming_the_option() {
    let (model, data) = setup("options");
    let (m, d) = (path(&model), path(&data));
    let cases: Vec<(Vec<&str>, &str, &str)> = vec![
        (
            vec!["fit", m, d, "--holdout", "NaN"],
            "--holdout",
            "0 < F < 1",
        ),
        (
            vec!["fit", m, d, "--holdout", "-0.5"],
            "--holdout",
            "0 < F < 1",
        ),
        (
            vec!["fit", m, d, "--holdout=-0.5"],
            "--holdout",
            "0 < F < 1",
        ),
        (
            vec!["fit", m, d, "--holdout", "1"],
            "--holdout",
            "0 < F < 1",
        ),
        (
            vec!["fit", m, d, "--stepwise", "NaN"],
            "--stepwise",
            "0 < α < 1",
        ),
        (
            vec!["fit", m, d, "--stepwise", "0.1", "--enter", "inf"],
            "--enter",
            "0 < α < 1",
        ),
        (
            vec!["fit", m, d, "--tolerance", "-1e-10"],
            "--tolerance",
            "0 < T < 1",
        ),
        (
            vec!["fit", m, d, "--tolerance", "nan"],
            "--tolerance",
            "0 < T < 1",
        ),
        // At 1 no direction could be determined (it referred to combinations "above" that
        // were never printed).
        (
            vec!["fit", m, d, "--tolerance", "1"],
            "--tolerance",
            "0 < T < 1",
        ),
        (
            vec!["diagnose", m, d, "--alpha", "NaN"],
            "--alpha",
            "0 < α < 1",
        ),
        (
            vec!["diagnose", m, d, "--alpha", "0"],
            "--alpha",
            "0 < α < 1",
        ),
        (
            vec!["simulate", m, "--sample", "18446744073709551615"],
            "--sample",
            "1 ≤ N ≤ 100000000",
        ),
        (
            vec!["simulate", m, "--sample", "0"],
            "--sample",
            "1 ≤ N ≤ 100000000",
        ),
        (
            vec!["simulate", m, "--sample", "3", "--noise", "-1um"],
            "--noise",
            "≥ 0",
        ),
        (
            vec!["simulate", m, "--sample", "3", "--noise", "NaN um"],
            "--noise",
            "number",
        ),
        (
            vec!["simulate", m, "--sample", "3", "--noise", "1e400um"],
            "--noise",
            "not finite",
        ),
        (
            vec!["simulate", m, "--sample", "3", "--noise-tilt", "1um"],
            "--noise-tilt",
            "angle",
        ),
        (
            vec!["simulate", m, "--sample", "3", "--artifact-shift", "inf um"],
            "--artifact-shift",
            "",
        ),
        (vec!["bench", m, "--poses", "0"], "--poses", "1 ≤ N"),
        (
            vec!["bench", m, "--seconds", "1e300"],
            "--seconds",
            "0 < S ≤ 86400",
        ),
        (
            vec!["bench", m, "--seconds", "NaN"],
            "--seconds",
            "0 < S ≤ 86400",
        ),
        (vec!["demo", "--rounds", "1000"], "--rounds", "0 ≤ N ≤ 100"),
        (
            vec!["check", m, "--color", "purple"],
            "--color",
            "auto, always, never",
        ),
    ];
    for (args, option, allowed) in cases {
        let out = kin(&args);
        let stderr = text(&out.stderr);
        assert_eq!(code(&out), 2, "{args:?}: {stderr}");
        assert!(stderr.contains(option), "{args:?}: {stderr}");
        assert!(stderr.contains(allowed), "{args:?}: {stderr}");
    }
    // The values the ranges allow still run.
    let out = kin(&["fit", m, d, "--holdout", "0.25", "--tolerance", "1e-9"]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    let out = kin(&["check", m, "--color", "never"]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
}

/// Unix: a reader that goes away before kin writes. Writing then kills kin with SIGPIPE, as any
/// command-line tool, instead of a panic (exit 101) or an error message.
#[cfg(unix)]
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (model, data) = setup("pipe");
    // Megabytes of output: more than a pipe buffers, so kin is writing when the reader goes.
    let mut child = Command::new(env!("CARGO_BIN_EXE_kin"))
        // `-q`: the model binds no values, which simulate would rightly warn about.
        .args(["simulate", "-q", path(&model), "--sample", "200000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("kin runs");
    let mut stdout = child.stdout.take().expect("stdout");
    let mut first = [0u8; 1];
    stdout.read_exact(&mut first).expect("a first byte");
    drop(stdout);
    let out = child.wait_with_output().expect("kin ends");
    assert_eq!(
        out.status.signal(),
        Some(13),
        "{:?}: {}",
        out.status,
        text(&out.stderr)
    );
    assert!(out.stderr.is_empty(), "quietly: {}", text(&out.stderr));

    // `kin fit … -o FIT.json | head -c1`: the reader closed before the summary is printed. The
    // fit is written all the same.
    for round in 0..3 {
        let fit = tmp(&format!("pipe_fit_{round}.json"));
        let mut child = Command::new(env!("CARGO_BIN_EXE_kin"))
            .args(["fit", path(&model), path(&data), "-o", path(&fit)])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("kin runs");
        drop(child.stdout.take());
        let out = child.wait_with_output().expect("kin ends");
        let status = out.status;
        assert!(
            status.success() || status.signal() == Some(13),
            "{status:?}: {}",
            text(&out.stderr)
        );
        assert!(
            !text(&out.stderr).contains("panicked"),
            "{}",
            text(&out.stderr)
        );
        let written: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&fit).expect("FIT.json written")).expect("json");
        assert_eq!(written["machine"], "m");
    }
}

#[test]
fn invalid_utf8_in_a_model_is_located() {
    let bad = tmp("latin1.kin");
    let mut bytes = MODEL.as_bytes().to_vec();
    // Line 4 (`    tool chain …`), column 5: a Latin-1 `é`.
    let at = MODEL
        .match_indices('\n')
        .nth(2)
        .map(|(i, _)| i + 5)
        .expect("line 4");
    bytes.insert(at, 0xe9);
    std::fs::write(&bad, &bytes).expect("write");
    let out = kin(&["check", path(&bad), "--color", "never"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("E0001") && stderr.contains("not valid UTF-8"),
        "{stderr}"
    );
    assert!(stderr.contains(&format!("byte offset {at}")), "{stderr}");
    assert!(stderr.contains("latin1.kin:4:5"), "{stderr}");

    let out = kin(&["check", path(&bad), "--format", "json"]);
    assert_eq!(code(&out), 1, "{}", text(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: `{}`", text(&out.stdout)));
    assert_eq!(v["ok"], false);
    let d = &v["diagnostics"][0];
    assert_eq!(d["code"], "E0001");
    assert_eq!(
        (d["line"].as_u64(), d["column"].as_u64()),
        (Some(4), Some(5))
    );

    // Every command that reads the model says the same.
    let out = kin(&["simulate", path(&bad), "--sample", "2"]);
    assert_eq!(code(&out), 1);
    assert!(
        text(&out.stderr).contains("latin1.kin:4:5"),
        "{}",
        text(&out.stderr)
    );
}

#[cfg(unix)]
#[test]
fn a_path_that_never_ends_is_read_up_to_a_limit() {
    let zero = Path::new("/dev/zero");
    if !zero.exists() {
        return;
    }
    let out = kin(&["check", "/dev/zero"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 2, "{stderr}");
    assert!(stderr.contains("larger than 64 MiB"), "{stderr}");
    let (model, _) = setup("zero");
    let out = kin(&[
        "simulate",
        path(&model),
        "--sample",
        "2",
        "--params",
        "/dev/zero",
    ]);
    assert_eq!(code(&out), 2, "{}", text(&out.stderr));
    assert!(text(&out.stderr).contains("larger than 64 MiB"));

    // A FIFO fed without end (a writer that keeps writing until kin stops reading).
    let fifo = tmp("endless.kin");
    let _ = std::fs::remove_file(&fifo);
    let made = Command::new("mkfifo").arg(&fifo).status();
    if !made.is_ok_and(|s| s.success()) {
        return;
    }
    let writer_path = fifo.clone();
    let writer = std::thread::spawn(move || {
        use std::io::Write;
        let Ok(mut f) = std::fs::OpenOptions::new().write(true).open(&writer_path) else {
            return;
        };
        let block = vec![b'/'; 1 << 16];
        // Ends when kin closes its end (EPIPE; the test process ignores SIGPIPE).
        while f.write_all(&block).is_ok() {}
    });
    let out = kin(&["check", path(&fifo)]);
    assert_eq!(code(&out), 2, "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("larger than 64 MiB"),
        "{}",
        text(&out.stderr)
    );
    writer.join().expect("writer ends");
}

#[test]
fn a_fit_of_another_model_says_so() {
    let (model, data) = setup("origin");
    let fit = tmp("origin_fit.json");
    let out = kin(&["fit", path(&model), path(&data), "-o", path(&fit)]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));

    // Another machine.
    let other = tmp("other.kin");
    std::fs::write(&other, MODEL.replace("machine m", "machine other")).expect("write");
    let out = kin(&["eval", path(&other), path(&data), "--params", path(&fit)]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("is a fit of machine `m`, but") && stderr.contains("is machine `other`"),
        "{stderr}"
    );

    // The same machine, revised: its coefficients no longer match the fit's.
    let revised = tmp("revised.kin");
    std::fs::write(&revised, MODEL.replace("X.ry = const", "X.rz = const")).expect("write");
    let out = kin(&["eval", path(&revised), path(&data), "--params", path(&fit)]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    // Refused before binding, naming the first coefficient that differs.
    assert!(
        stderr.contains("is a fit of another revision of")
            && stderr.contains("`X.rz[0]` (const) in the model and `X.ry[0]` (const) in the fit"),
        "{stderr}"
    );

    // The model it was fitted to binds it.
    let out = kin(&["eval", path(&model), path(&data), "--params", path(&fit)]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
}

#[test]
fn an_artifact_seen_at_one_row_is_reported_at_that_row() {
    let (model, data) = setup("artifact");
    let text_in = std::fs::read_to_string(&data).expect("data");
    let lines: Vec<&str> = text_in.lines().collect();
    let mut out_lines: Vec<String> = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        out_lines.push(match i {
            0 | 1 => l.to_string(),
            2 => format!("{l},artifact"),
            // The last row alone on `plateB`.
            _ if i + 1 == lines.len() => format!("{l},plateB"),
            _ => format!("{l},plateA"),
        });
    }
    let file = tmp("one_row_artifact.csv");
    std::fs::write(&file, out_lines.join("\n") + "\n").expect("write");
    let out = kin(&["fit", path(&model), path(&file)]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    let last = lines.len();
    assert!(
        stderr.contains(&format!(
            "one_row_artifact.csv, line {last}: artifact `plateB`"
        )),
        "{stderr}"
    );
    assert!(stderr.contains("1 row (3 values)"), "{stderr}");
    assert!(
        !stderr.contains("E0601"),
        "not blamed on the model: {stderr}"
    );
}

#[test]
fn absurd_numbers_in_a_model_are_blamed_on_the_number() {
    let cases = [
        ("params {\n    X.ry[0] = 1e400 urad\n}\n", "8:15", "`1e400`"),
        (
            "params {\n    X.tx = [1, 1e309, 3, 4] um\n}\n",
            "8:16",
            "`1e309`",
        ),
    ];
    for (params, at, number) in cases {
        let model = tmp("absurd.kin");
        std::fs::write(&model, format!("{MODEL}{params}")).expect("write");
        let out = kin(&["check", path(&model), "--color", "never"]);
        let stderr = text(&out.stderr);
        assert_eq!(code(&out), 1, "{stderr}");
        assert!(
            stderr.contains("E0003") && stderr.contains(number),
            "{stderr}"
        );
        assert!(stderr.contains(&format!("absurd.kin:{at}")), "{stderr}");
    }
    let knot = tmp("knot.kin");
    std::fs::write(
        &knot,
        MODEL.replace("knots 2", "knots at (100, 1e309, 300) mm"),
    )
    .expect("write");
    let out = kin(&["check", path(&knot), "--color", "never"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("knot.kin:5:46") && stderr.contains("`1e309`"),
        "{stderr}"
    );
}

/// An absurd offset once made the identifiability analysis report an innocent term (`X.tx`, line
/// 6) as having no effect; the number itself is reported now.
#[test]
fn an_absurd_offset_or_range_is_blamed_on_the_number() {
    let model = tmp("offset.kin");
    let source = "machine m {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 500 mm
    tool chain { X moving Y moving tool t at (0, 0, -1e100) mm }
    errors { X.tx = spline(X, knots 2)  X.ry = const  Y.rz = linear(X) }
}
";
    std::fs::write(&model, source).expect("write");
    let out = kin(&["check", path(&model), "--color", "never"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("E0003") && stderr.contains("beyond any machine"),
        "{stderr}"
    );
    assert!(stderr.contains("offset.kin:5:53"), "{stderr}");
    assert!(!stderr.contains("E0601"), "{stderr}");

    std::fs::write(
        &model,
        source
            .replace("500 mm\n    axis Y", "1e308 m\n    axis Y")
            .replace("-1e100", "-100"),
    )
    .expect("write");
    let out = kin(&["check", path(&model), "--color", "never"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("E0003") && stderr.contains("offset.kin:3:44"),
        "{stderr}"
    );
}

/// Unix: standard output that cannot be written (`> /dev/full`) ends kin with exit 1 and one
/// line on standard error, not a panic (exit 101).
#[cfg(unix)]
#[test]
fn a_full_standard_output_is_an_error_not_a_panic() {
    let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") else {
        return; // no /dev/full on this system
    };
    let out = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["check", "examples/xy_table.kin", "--format", "json"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::from(full))
        .stderr(Stdio::piped())
        .output()
        .expect("kin runs");
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(err.starts_with("error: failed printing to stdout"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// A term whose scale overflows a number (`1e308 * const`) was reported at line 1:1; the error
/// points at the term now.
#[test]
fn an_overflowing_term_is_blamed_on_the_term() {
    let model = tmp("overflow.kin");
    let source = "machine m {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    tool chain { X moving tool t }
    errors { X.tx = 1e308 * const  X.ry = const }
}
";
    std::fs::write(&model, source).expect("write");
    let out = kin(&["check", path(&model), "--color", "never"]);
    let stderr = text(&out.stderr);
    assert_eq!(code(&out), 1, "{stderr}");
    assert!(
        stderr.contains("E0601") && stderr.contains("overflow.kin:5:21"),
        "{stderr}"
    );
}

/// Observations that do not vary (a perfect machine simulated without noise) have no R²: the
/// fit says so instead of printing `R² = NaN`.
#[test]
fn a_fit_of_data_that_do_not_vary_has_no_r2_to_print() {
    let model = tmp("still.kin");
    std::fs::write(&model, MODEL).expect("model");
    let data = tmp("still.csv");
    let out = kin(&[
        "simulate",
        path(&model),
        "--sample",
        "20",
        "-o",
        path(&data),
    ]);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    let out = kin(&["fit", path(&model), path(&data)]);
    let stdout = text(&out.stdout);
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    assert!(
        stdout.contains("R² undefined") && !stdout.contains("NaN"),
        "{stdout}"
    );
}

/// The same data file twice (under two spellings, or fitted and validated) was fitted twice
/// without a word, its standard errors shrunk by √2; it is refused before anything is read.
#[test]
fn a_data_file_given_twice_is_refused() {
    let (model, data) = setup("twice");
    let dir = data.parent().expect("folder");
    let name = data.file_name().expect("name").to_str().expect("utf-8");
    let other = format!("./{name}");
    for args in [
        vec!["fit", path(&model), name, &other],
        vec!["fit", path(&model), name, "--validate", &other],
        vec!["diagnose", path(&model), name, name],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_kin"))
            .args(&args)
            .current_dir(dir)
            .output()
            .expect("kin runs");
        let stderr = text(&out.stderr);
        assert_eq!(code(&out), 2, "{args:?}: {stderr}");
        assert!(stderr.contains("is given twice"), "{stderr}");
    }
}

/// A 10 MB token (an identifier of ten million letters) came back as 70 MB of standard error
/// in 93 s: the message quotes its start and says its length, and the line is not drawn.
#[test]
fn a_huge_token_gives_a_short_error() {
    let model = tmp("token.kin");
    let name = "a".repeat(10_000_000);
    std::fs::write(
        &model,
        format!("machine m {{\n task position\n axis X prismatic along x range 0 mm .. 500 mm\n tool chain {{ X moving tool t }}\n errors {{ X.tx = {name} }}\n}}\n"),
    )
    .expect("write");
    let out = kin(&["check", path(&model), "--color", "never"]);
    assert_eq!(code(&out), 1);
    let stderr = text(&out.stderr);
    assert!(stderr.len() < 2000, "{} bytes", stderr.len());
    assert!(
        stderr.contains("token.kin:5:18: error[E0101]") && stderr.contains("(10000000 characters)"),
        "{stderr}"
    );
    let out = kin(&["check", path(&model), "--format", "json"]);
    assert!(
        out.stdout.len() < 4000,
        "{} bytes of JSON",
        out.stdout.len()
    );
}

/// 10⁵ errors printed 26 MB: the first fifty are drawn and the rest counted.
#[test]
fn many_errors_are_counted_not_all_drawn() {
    let model = tmp("many.kin");
    let mut source = String::from(
        "machine m {\n task position\n axis X prismatic along x range 0 mm .. 500 mm\n tool chain { X moving tool t }\n errors {\n",
    );
    for i in 0..20_000 {
        source.push_str(&format!("  X.tx += u{i}\n"));
    }
    source.push_str(" }\n}\n");
    std::fs::write(&model, source).expect("write");
    let out = kin(&["check", path(&model), "--color", "never"]);
    assert_eq!(code(&out), 1);
    let stderr = text(&out.stderr);
    assert!(stderr.len() < 50_000, "{} bytes", stderr.len());
    assert!(
        stderr.contains("… and 19950 more (19950 errors, 0 warnings) not shown"),
        "{}",
        &stderr[stderr.len().saturating_sub(500)..]
    );
}

/// `-o -` wrote a file named `-`; it is standard output now (and refused by `fit`, whose `-o`
/// names FIT.json with FIT.params beside it).
#[test]
fn dash_is_standard_output() {
    let (model, data) = setup("dash");
    let dir = data.parent().expect("folder");
    let out = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["eval", path(&model), path(&data), "-o", "-"])
        .current_dir(dir)
        .output()
        .expect("kin runs");
    assert_eq!(code(&out), 0, "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("ex[um]"),
        "{}",
        text(&out.stdout)
    );
    assert!(!dir.join("-").exists(), "a file named `-` was written");
    let out = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["fit", path(&model), path(&data), "-o", "-"])
        .current_dir(dir)
        .output()
        .expect("kin runs");
    assert_eq!(code(&out), 2);
    assert!(text(&out.stderr).contains("--format json"));
    assert!(!dir.join("-.params").exists());
}
