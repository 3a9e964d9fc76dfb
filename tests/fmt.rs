//! `kin fmt`: every `.kin` in the repository is formatted; formatting is idempotent and keeps
//! the meaning (the same compiled IR) on the examples, the diagnostics corpus, the fuzz corpus
//! and whitespace-scrambled variants of them; `--check` and the file handling of the command.

mod common;

use std::path::{Path, PathBuf};

use common::{kin, scratch, text};
use kin_compiler::format::{format_source, FormatError};
use proptest::prelude::*;

fn kin_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            kin_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "kin") {
            out.push(p);
        }
    }
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The compiled machine's full debug form: every axis, frame, term and coefficient, without
/// source positions (those live in the separate source map).
fn ir(source: &str) -> Option<String> {
    kin_compiler::compile(source)
        .compiled
        .map(|c| format!("{:?}", c.machine))
}

/// The diagnostics' codes and messages (positions move when whitespace does).
fn verdict(source: &str) -> Vec<(String, String)> {
    kin_compiler::compile(source)
        .diagnostics
        .iter()
        .map(|d| (d.code.to_string(), d.message.clone()))
        .collect()
}

/// Formatting `source`: idempotent, same IR (or same diagnostics when it does not compile).
fn check_one(name: &str, source: &str) -> Result<Option<String>, String> {
    match format_source(source) {
        Ok(once) => {
            let twice = format_source(&once).map_err(|e| format!("{name}: reformat: {e}"))?;
            if twice != once {
                return Err(format!("{name}: not idempotent:\n{once}\n----\n{twice}"));
            }
            if ir(source) != ir(&once) {
                return Err(format!("{name}: the IR changed"));
            }
            if verdict(source) != verdict(&once) {
                return Err(format!("{name}: the diagnostics changed"));
            }
            Ok(Some(once))
        }
        Err(FormatError::Syntax(d)) => {
            if d.is_empty() {
                return Err(format!("{name}: a syntax failure without a diagnostic"));
            }
            Ok(None)
        }
        Err(e) => Err(format!("{name}: {e}")),
    }
}

#[test]
fn every_example_is_formatted() {
    // The diagnostics corpus is not: its golden files hold line and column numbers, and its
    // files are written to show mistakes (it is checked for idempotence below).
    let mut files = Vec::new();
    kin_files(&root().join("examples"), &mut files);
    assert!(files.len() >= 5, "{files:?}");
    let mut unformatted = Vec::new();
    for f in &files {
        let Ok(src) = std::fs::read_to_string(f) else {
            continue;
        };
        if let Some(formatted) =
            check_one(&f.display().to_string(), &src).unwrap_or_else(|e| panic!("{e}"))
        {
            if formatted != src {
                unformatted.push(f.display().to_string());
            }
        }
    }
    assert!(unformatted.is_empty(), "run `kin fmt` on: {unformatted:?}");
}

#[test]
fn diagnostics_corpus_is_idempotent_and_unparsable_files_are_refused() {
    let mut files = Vec::new();
    kin_files(&root().join("tests/diagnostics"), &mut files);
    let mut refused = 0;
    for f in &files {
        let src = std::fs::read_to_string(f).unwrap_or_default();
        if check_one(&f.display().to_string(), &src)
            .unwrap_or_else(|e| panic!("{e}"))
            .is_none()
        {
            refused += 1;
        }
    }
    // The E0001 files (syntax errors) are refused, the others formatted.
    assert!(
        refused >= 10 && refused < files.len(),
        "{refused} of {}",
        files.len()
    );
}

#[test]
fn fuzz_corpus_is_idempotent_with_the_same_ir() {
    let dir = root().join("fuzz/corpus/kin_source");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        panic!("no fuzz corpus at {}", dir.display());
    };
    let mut formatted = 0;
    for e in entries.filter_map(Result::ok) {
        let Ok(src) = std::fs::read_to_string(e.path()) else {
            continue;
        };
        if check_one(&e.path().display().to_string(), &src)
            .unwrap_or_else(|e| panic!("{e}"))
            .is_some()
        {
            formatted += 1;
        }
    }
    assert!(formatted > 20, "only {formatted} corpus files parse");
}

/// The source with each run of whitespace outside comments replaced by another of the same
/// kind (a run without a newline stays on its line, where units bind to their numbers), and
/// spaces inserted after some commas and brackets.
fn scramble(source: &str, choices: &[u8]) -> String {
    let mut out = String::new();
    let mut k = 0usize;
    let mut pick = |n: u8| {
        let c = choices.get(k % choices.len().max(1)).copied().unwrap_or(0);
        k += 1;
        c % n
    };
    let b = source.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            let end = source[i..].find('\n').map_or(source.len(), |j| i + j);
            out.push_str(&source[i..end]);
            i = end;
        } else if b[i..].starts_with(b"/*") {
            let end = source[i + 2..]
                .find("*/")
                .map_or(source.len(), |j| i + j + 4);
            out.push_str(&source[i..end]);
            i = end;
        } else if matches!(b[i], b' ' | b'\t' | b'\n' | b'\r') {
            let start = i;
            while i < b.len() && matches!(b[i], b' ' | b'\t' | b'\n' | b'\r') {
                i += 1;
            }
            let newlines = source[start..i].matches('\n').count();
            if newlines > 0 {
                for _ in 0..newlines.min(1) + usize::from(pick(3)) {
                    out.push('\n');
                }
                for _ in 0..pick(9) {
                    out.push(' ');
                }
            } else {
                for _ in 0..1 + pick(3) {
                    out.push(if pick(4) == 0 { '\t' } else { ' ' });
                }
            }
        } else {
            let c = source[i..].chars().next().unwrap_or(' ');
            out.push(c);
            i += c.len_utf8();
            if matches!(c, ',' | '(' | '[') && pick(3) == 0 {
                out.push(' ');
            }
        }
    }
    out
}

fn corpus() -> Vec<(String, String)> {
    let mut files = Vec::new();
    kin_files(&root().join("examples"), &mut files);
    kin_files(&root().join("tests/diagnostics"), &mut files);
    files
        .into_iter()
        .filter_map(|f| Some((f.display().to_string(), std::fs::read_to_string(&f).ok()?)))
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Scrambled whitespace: the formatted file is a fixed point and means what the original
    /// meant.
    #[test]
    fn scrambled_whitespace_formats_to_the_same_meaning(
        which in 0usize..1000,
        choices in proptest::collection::vec(any::<u8>(), 1..64),
    ) {
        let files = corpus();
        let (name, src) = &files[which % files.len()];
        let scrambled = scramble(src, &choices);
        let original_parses = format_source(src).is_ok();
        match check_one(name, &scrambled) {
            Err(e) => return Err(TestCaseError::fail(e)),
            Ok(Some(formatted)) => {
                prop_assert!(original_parses, "{name}: only the scrambled text parses");
                prop_assert_eq!(ir(&formatted), ir(src), "{}: not the original's IR", name);
                prop_assert_eq!(format_source(&formatted).ok(), Some(formatted.clone()));
            }
            Ok(None) => prop_assert!(!original_parses, "{name}: scrambling broke the parse:\n{scrambled}"),
        }
    }
}

#[test]
fn check_lists_the_files_that_would_change_with_a_diff() {
    let dir = scratch("fmt_check");
    let good = dir.join("good.kin");
    let bad = dir.join("bad.kin");
    let src = std::fs::read_to_string(root().join("examples/xy_table.kin")).unwrap_or_default();
    std::fs::write(&good, &src).unwrap_or_default();
    let messy = src.replacen("    axis", "axis", 1);
    std::fs::write(&bad, &messy).unwrap_or_default();
    let dir_s = dir.display().to_string();
    let out = kin(&["fmt", "--check", &dir_s]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(
        err.contains("bad.kin") && !err.contains("good.kin"),
        "{err}"
    );
    assert!(err.contains("-axis") && err.contains("+    axis"), "{err}");
    assert_eq!(
        std::fs::read_to_string(&bad).unwrap_or_default(),
        messy,
        "--check writes nothing"
    );
    // Formatting in place, then --check passes.
    let out = kin(&["fmt", &bad.display().to_string()]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert_eq!(std::fs::read_to_string(&bad).unwrap_or_default(), src);
    let out = kin(&["fmt", "--check", &dir_s]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
}

#[test]
fn a_file_with_syntax_errors_is_reported_and_left_alone() {
    let dir = scratch("fmt_syntax");
    let f = dir.join("broken.kin");
    let src = "machine m {\n  axis X prismatic alongg x\n}\n";
    std::fs::write(&f, src).unwrap_or_default();
    let out = kin(&["fmt", &f.display().to_string()]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(err.contains("E0001") && err.contains("broken.kin"), "{err}");
    assert_eq!(std::fs::read_to_string(&f).unwrap_or_default(), src);
    let out = kin(&["fmt", &dir.join("missing.kin").display().to_string()]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn standard_input_to_standard_output() {
    use std::io::Write as _;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_kin"))
        .arg("fmt")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{e}"));
    if let Some(mut stdin) = child.stdin.take() {
        let _ = stdin.write_all(b"machine m{axis X prismatic along x // c\n}");
    }
    let out = child.wait_with_output().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        text(&out.stdout),
        "machine m { axis X prismatic along x // c\n}\n"
    );
}

/// The ` ```kin ` blocks of `spec/*.md` (the ones `tests/spec.rs` compiles), with their file
/// and first line.
fn spec_blocks() -> Vec<(String, String)> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(root().join("spec")) else {
        return out;
    };
    let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    for f in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "md"))
    {
        let text = std::fs::read_to_string(f).unwrap_or_default();
        let mut block: Option<(usize, String)> = None;
        for (i, line) in text.lines().enumerate() {
            match &mut block {
                None if line.starts_with("```kin") => block = Some((i + 1, String::new())),
                Some((start, body)) if line.starts_with("```") => {
                    out.push((format!("{}:{}", f.display(), start), std::mem::take(body)));
                    block = None;
                }
                Some((_, body)) => {
                    body.push_str(line);
                    body.push('\n');
                }
                None => {}
            }
        }
    }
    out
}

#[test]
fn every_spec_block_is_formatted() {
    let blocks = spec_blocks();
    assert!(blocks.len() > 20, "{} blocks", blocks.len());
    let mut unformatted = Vec::new();
    for (name, src) in &blocks {
        if let Some(formatted) = check_one(name, src).unwrap_or_else(|e| panic!("{e}")) {
            if &formatted != src {
                unformatted.push(format!(
                    "{name}\n{}",
                    similar::TextDiff::from_lines(src.as_str(), formatted.as_str()).unified_diff()
                ));
            }
        }
    }
    assert!(
        unformatted.is_empty(),
        "{} spec blocks are not formatted:\n{}",
        unformatted.len(),
        unformatted.join("\n")
    );
}

/// An endless standard input (`kin fmt < /dev/zero`) is refused once it passes the size any
/// source can have, not formatted as if the part read were whole.
#[cfg(unix)]
#[test]
fn an_endless_standard_input_is_refused() {
    let Ok(zero) = std::fs::File::open("/dev/zero") else {
        return;
    };
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_kin"))
        .arg("fmt")
        .stdin(zero)
        .output()
        .expect("kin runs");
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("more than"));
}
