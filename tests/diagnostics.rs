//! Golden tests of the checker's diagnostics.
//!
//! Every `tests/diagnostics/NAME.kin` is a wrong machine description that starts with comment
//! lines stating what the checker must report, e.g.
//!
//! ```text
//! // Error E0101 at 22:56: unknown name `Xx`
//! // Warning W0101 at 10:11: never used
//! ```
//!
//! (severity, code, line:column of the primary span's start — 1-based, column in characters —
//! and a fragment of the message). For each fixture this harness
//!
//! 1. runs `kin_compiler::compile` and requires the multiset of (severity, code, line, column)
//!    to equal the annotated one, each annotated message fragment to occur in the message,
//!    every span to lie inside the source on character boundaries without blanks at its ends,
//!    every label to have text and every message to be one line (what the renderer needs);
//! 2. runs the CLI exactly as a user would (`kin check tests/diagnostics/NAME.kin --color never`
//!    from the repository root) and compares exit code, standard error and standard output with
//!    the golden file `NAME.expected` (written instead when `KIN_BLESS=1`);
//! 3. requires that nothing panicked (no panic in `compile`, CLI exit code never 101).
//!
//! A fixture with a `// KNOWN-BUG: …` line documents a checker bug: its annotations state the
//! correct behaviour and mismatches in step 1 are reported but tolerated; its golden still
//! records (and guards) the current output. See `tests/diagnostics/README.md`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::process::Command;

use kin_compiler::{compile, Diagnostic, Severity};

const DIR: &str = "tests/diagnostics";

/// One `// Error E0101 at 12:9: fragment` line.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct Expected {
    severity: &'static str,
    code: String,
    line: usize,
    column: usize,
    fragment: String,
}

struct Fixture {
    name: String,
    /// Path relative to the repository root, as the CLI prints it.
    relative: String,
    source: String,
    expected: Vec<Expected>,
    known_bug: bool,
    /// Header lines that look like annotations but do not parse.
    malformed: Vec<String>,
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn bless() -> bool {
    std::env::var_os("KIN_BLESS").is_some_and(|v| v == "1")
}

fn fixtures() -> Vec<Fixture> {
    let dir = root().join(DIR);
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "kin"))
        .collect();
    paths.sort();
    paths.iter().map(|p| load(p)).collect()
}

fn load(path: &Path) -> Fixture {
    let name = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or_default()
        .to_string();
    let source = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut expected = Vec::new();
    let mut malformed = Vec::new();
    let mut known_bug = false;
    for line in source.lines().take_while(|l| l.starts_with("//")) {
        let text = line.trim_start_matches('/').trim();
        if text.starts_with("KNOWN-BUG:") {
            known_bug = true;
        } else if text.starts_with("Error ") || text.starts_with("Warning ") {
            match parse_annotation(text) {
                Some(e) => expected.push(e),
                None => malformed.push(line.to_string()),
            }
        }
    }
    Fixture {
        relative: format!("{DIR}/{name}.kin"),
        name,
        source,
        expected,
        known_bug,
        malformed,
    }
}

/// `Error E0101 at 12:9: unknown name`.
fn parse_annotation(text: &str) -> Option<Expected> {
    let (severity, rest) = text.split_once(' ')?;
    let severity = match severity {
        "Error" => "error",
        "Warning" => "warning",
        _ => return None,
    };
    let (code, rest) = rest.split_once(' ')?;
    let valid_code = code.len() == 5
        && code.starts_with(['E', 'W'])
        && code.chars().skip(1).all(|c| c.is_ascii_digit());
    if !valid_code {
        return None;
    }
    let rest = rest.strip_prefix("at ")?;
    let (position, fragment) = rest.split_once(": ")?;
    let (line, column) = position.split_once(':')?;
    let fragment = fragment.trim().to_string();
    if fragment.is_empty() {
        return None;
    }
    Some(Expected {
        severity,
        code: code.to_string(),
        line: line.parse().ok().filter(|&l| l > 0)?,
        column: column.parse().ok().filter(|&c| c > 0)?,
        fragment,
    })
}

/// 1-based line and column (in characters) of a byte offset, as `kin check --format json` gives.
fn line_column(source: &str, offset: usize) -> (usize, usize) {
    let before = source.get(..offset.min(source.len())).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

fn severity_name(s: Severity) -> &'static str {
    match s {
        Severity::Error => "error",
        Severity::Warning => "warning",
    }
}

fn describe(d: &Diagnostic, source: &str) -> String {
    let (line, column) = line_column(source, d.primary_span().start);
    let severity = if d.is_error() { "Error" } else { "Warning" };
    format!("{severity} {} at {line}:{column}: {}", d.code, d.message)
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(non-string panic payload)".into())
}

/// Checks of the library's diagnostics against the annotations. Returns the problems found.
fn check_library(f: &Fixture) -> (Vec<String>, bool) {
    let mut problems: Vec<String> = f
        .malformed
        .iter()
        .map(|l| format!("malformed annotation: {l}"))
        .collect();
    if f.expected.is_empty() {
        problems.push("no `// Error …` or `// Warning …` annotation".into());
    }
    let out = match catch_unwind(AssertUnwindSafe(|| compile(&f.source))) {
        Ok(out) => out,
        Err(payload) => {
            problems.push(format!("compile panicked: {}", panic_message(&*payload)));
            return (problems, false);
        }
    };
    let source = &f.source;
    for d in &out.diagnostics {
        for (i, label) in d.labels.iter().enumerate() {
            let s = label.span;
            let valid = s.start <= s.end
                && s.end <= source.len()
                && source.is_char_boundary(s.start)
                && source.is_char_boundary(s.end);
            if !valid {
                problems.push(format!(
                    "{}: label {i} has span {}..{}, not a valid range of the {}-byte source",
                    d.code,
                    s.start,
                    s.end,
                    source.len()
                ));
            }
            // Without text, ariadne draws no marker at all under a label.
            if label.message.trim().is_empty() {
                problems.push(format!(
                    "{}: label {i} has no text, so the rendered report shows no marker",
                    d.code
                ));
            }
            // A label covering trailing (or leading) blanks is drawn over the next line.
            let text = source.get(s.start..s.end).unwrap_or("");
            if valid && text.trim() != text {
                problems.push(format!(
                    "{}: label {i} covers {text:?}, with blanks at its ends",
                    d.code
                ));
            }
            if label.message.contains('\n') {
                problems.push(format!(
                    "{}: label {i} text contains a line break: {:?}",
                    d.code, label.message
                ));
            }
        }
        if d.labels.is_empty() {
            problems.push(format!(
                "{}: diagnostic has no label, so no location",
                d.code
            ));
        }
        if d.message.contains('\n') {
            problems.push(format!(
                "{}: message contains a line break: {:?}",
                d.code, d.message
            ));
        }
    }
    if out.compiled.is_some() == out.diagnostics.iter().any(Diagnostic::is_error) {
        problems
            .push("`compiled` is present although there are errors (or absent without any)".into());
    }

    // The multiset of (severity, code, line, column) must match exactly.
    type Key = (&'static str, String, usize, usize);
    let mut actual: BTreeMap<Key, Vec<&Diagnostic>> = BTreeMap::new();
    for d in &out.diagnostics {
        let (line, column) = line_column(source, d.primary_span().start);
        actual
            .entry((severity_name(d.severity), d.code.to_string(), line, column))
            .or_default()
            .push(d);
    }
    let mut wanted: BTreeMap<Key, Vec<&Expected>> = BTreeMap::new();
    for e in &f.expected {
        wanted
            .entry((e.severity, e.code.clone(), e.line, e.column))
            .or_default()
            .push(e);
    }
    for (key, exps) in &wanted {
        let got = actual.get(key).map(Vec::as_slice).unwrap_or(&[]);
        for e in exps.iter().skip(got.len()) {
            problems.push(format!(
                "expected but not reported: {} {} at {}:{}: {}",
                if e.severity == "error" {
                    "Error"
                } else {
                    "Warning"
                },
                e.code,
                e.line,
                e.column,
                e.fragment
            ));
        }
        for e in exps {
            if !got.is_empty() && !got.iter().any(|d| d.message.contains(&e.fragment)) {
                let messages: Vec<&str> = got.iter().map(|d| d.message.as_str()).collect();
                problems.push(format!(
                    "{} at {}:{}: message {:?} does not contain {:?}",
                    e.code, e.line, e.column, messages, e.fragment
                ));
            }
        }
    }
    for (key, ds) in &actual {
        let n = wanted.get(key).map_or(0, Vec::len);
        for d in ds.iter().skip(n) {
            problems.push(format!(
                "reported but not expected: {}",
                describe(d, source)
            ));
        }
    }
    (problems, out.compiled.is_some())
}

/// What the CLI printed, in the golden file's format.
fn run_cli(f: &Fixture) -> Result<(i32, String), String> {
    let output = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["check", &f.relative, "--color", "never"])
        .current_dir(root())
        .env_remove("NO_COLOR")
        .env_remove("CLICOLOR_FORCE")
        .env_remove("RUST_BACKTRACE")
        .output()
        .map_err(|e| format!("cannot run kin: {e}"))?;
    let Some(code) = output.status.code() else {
        return Err(format!(
            "kin was killed by a signal ({:?}): {}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        ));
    };
    let stderr = String::from_utf8_lossy(&output.stderr);
    let stdout = String::from_utf8_lossy(&output.stdout);
    let mut text = format!("exit: {code}\n--- stderr\n{stderr}");
    if !stdout.is_empty() {
        if !text.ends_with('\n') {
            text.push('\n');
        }
        let _ = write!(text, "--- stdout\n{stdout}");
    }
    Ok((code, text))
}

/// A line diff (longest common subsequence), `-` for the golden, `+` for the actual output.
fn diff(expected: &str, actual: &str) -> String {
    let a: Vec<&str> = expected.lines().collect();
    let b: Vec<&str> = actual.lines().collect();
    let mut lcs = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for i in (0..a.len()).rev() {
        for j in (0..b.len()).rev() {
            lcs[i][j] = if a[i] == b[j] {
                lcs[i + 1][j + 1] + 1
            } else {
                lcs[i + 1][j].max(lcs[i][j + 1])
            };
        }
    }
    let (mut i, mut j) = (0, 0);
    let mut out = String::new();
    while i < a.len() || j < b.len() {
        if i < a.len() && j < b.len() && a[i] == b[j] {
            let _ = writeln!(out, "   {}", a[i]);
            i += 1;
            j += 1;
        } else if j < b.len() && (i == a.len() || lcs[i][j + 1] >= lcs[i + 1][j]) {
            let _ = writeln!(out, "  +{}", b[j]);
            j += 1;
        } else {
            let _ = writeln!(out, "  -{}", a[i]);
            i += 1;
        }
    }
    if expected.ends_with('\n') != actual.ends_with('\n') {
        out.push_str("  (the final line break differs)\n");
    }
    out
}

/// Compares (or, with `KIN_BLESS=1`, writes) the golden file. Returns the problem, if any.
fn check_golden(f: &Fixture, actual: &str) -> Option<String> {
    let path = root().join(DIR).join(format!("{}.expected", f.name));
    let golden = std::fs::read_to_string(&path).ok();
    if bless() {
        if golden.as_deref() != Some(actual) {
            if let Err(e) = std::fs::write(&path, actual) {
                return Some(format!("cannot write {}: {e}", path.display()));
            }
        }
        return None;
    }
    match golden {
        None => Some(format!(
            "missing golden {DIR}/{}.expected; the CLI printed:\n{actual}\n(run `KIN_BLESS=1 cargo test --test diagnostics` to write it)",
            f.name
        )),
        Some(g) if g != actual => Some(format!(
            "CLI output differs from {DIR}/{}.expected (- golden, + actual):\n{}(if the new output is right: `KIN_BLESS=1 cargo test --test diagnostics`)",
            f.name,
            diff(&g, actual)
        )),
        Some(_) => None,
    }
}

#[test]
fn diagnostics_match_annotations_and_goldens() {
    let fixtures = fixtures();
    assert!(
        fixtures.len() >= 45,
        "expected at least 45 fixtures in {DIR}, found {}",
        fixtures.len()
    );
    let mut failures = String::new();
    let mut known = String::new();
    for f in &fixtures {
        let (mut problems, compiled) = check_library(f);
        // The CLI: never a panic, exit code 1 exactly when there are errors, output as golden.
        let expect_exit = if f.expected.iter().any(|e| e.severity == "error") {
            1
        } else {
            0
        };
        let mut golden_problem = None;
        match run_cli(f) {
            Err(e) => problems.push(e),
            Ok((code, text)) => {
                if code == 101 {
                    problems.push(format!("kin panicked (exit 101):\n{text}"));
                } else if code != expect_exit {
                    problems.push(format!("kin exited with {code}, expected {expect_exit} (library compiled: {compiled})"));
                }
                golden_problem = check_golden(f, &text);
            }
        }
        if f.known_bug {
            if problems.is_empty() {
                let _ = writeln!(
                    known,
                    "{}: marked KNOWN-BUG but passes every check; is it fixed?",
                    f.name
                );
            }
            for p in &problems {
                let _ = writeln!(known, "{}: {p}", f.name);
            }
        } else if !problems.is_empty() {
            let _ = writeln!(failures, "\n=== {} ({})", f.name, f.relative);
            for p in &problems {
                let _ = writeln!(failures, "  {p}");
            }
        }
        if let Some(p) = golden_problem {
            let _ = writeln!(failures, "\n=== {} ({})\n  {p}", f.name, f.relative);
        }
    }
    // Goldens whose fixture is gone.
    if let Ok(entries) = std::fs::read_dir(root().join(DIR)) {
        for e in entries.flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "expected") && !p.with_extension("kin").exists() {
                if bless() {
                    let _ = std::fs::remove_file(&p);
                } else {
                    let _ = writeln!(
                        failures,
                        "\n=== stale golden {} (no matching .kin)",
                        p.display()
                    );
                }
            }
        }
    }
    if !known.is_empty() {
        eprintln!(
            "known checker bugs (tolerated; see the KNOWN-BUG lines of these fixtures):\n{known}"
        );
    }
    assert!(failures.is_empty(), "diagnostic fixtures failed:{failures}");
}

/// Every diagnostic code the compiler can emit has at least one fixture (E0002, an internal
/// error, cannot be provoked from a file).
#[test]
fn every_compiler_code_has_a_fixture() {
    fn codes_in(dir: &Path, out: &mut Vec<String>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                codes_in(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).unwrap_or_default();
                for (i, _) in text.match_indices('"') {
                    let Some(candidate) = text.get(i + 1..i + 7) else {
                        continue;
                    };
                    let code = &candidate[..5.min(candidate.len())];
                    let shape = candidate.ends_with('"')
                        && code.starts_with(['E', 'W'])
                        && code.chars().skip(1).all(|c| c.is_ascii_digit());
                    if shape && !out.iter().any(|c| c == code) {
                        out.push(code.to_string());
                    }
                }
            }
        }
    }
    let mut codes = Vec::new();
    codes_in(&root().join("compiler/src"), &mut codes);
    codes.sort();
    let covered: Vec<String> = fixtures()
        .iter()
        .flat_map(|f| f.expected.iter().map(|e| e.code.clone()))
        .collect();
    let missing: Vec<&String> = codes
        .iter()
        .filter(|c| *c != "E0002" && !covered.contains(c))
        .collect();
    assert!(
        missing.is_empty(),
        "codes emitted by compiler/src without a fixture in {DIR}: {missing:?}"
    );
}

#[test]
fn annotations_parse() {
    let e = parse_annotation("Error E0101 at 12:9: unknown name `Xx`").expect("parses");
    assert_eq!(
        (e.severity, e.code.as_str(), e.line, e.column),
        ("error", "E0101", 12, 9)
    );
    assert_eq!(e.fragment, "unknown name `Xx`");
    assert!(parse_annotation("Warning W0101 at 3:1: never used").is_some());
    assert!(parse_annotation("Error E101 at 1:1: x").is_none());
    assert!(parse_annotation("Error E0101 at 0:1: x").is_none());
    assert!(parse_annotation("Error E0101 12:9: x").is_none());
    assert_eq!(line_column("a\nµb c", "a\nµb ".len()), (2, 4));
}
