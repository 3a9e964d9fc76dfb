//! `spec/tutorial.md` as a user follows it: every ` ```sh ` block is run, in order, in one empty
//! folder, by `sh` with the built `kin` first on the `PATH`. The commands are read from the
//! Markdown itself, so the page and the test cannot drift apart, and the ` ```text ` block that
//! follows a ` ```sh ` block is its output: every line of it must be printed, in that order (a
//! line `…` skips lines, a line ending in `…` is a line's start; numbers may differ in their
//! last printed digit, as the fit's rounding may on another processor). Then what the tutorial
//! promises: the diagnosis names the hidden backlash, the fit after the added line has a smaller
//! residual RMS, the compensation files exist.
#![cfg(unix)]

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fenced block of the page: its 1-based line, info string and text.
struct Block {
    line: usize,
    info: String,
    text: String,
}

fn blocks(markdown: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let mut open: Option<Block> = None;
    for (i, line) in markdown.lines().enumerate() {
        match open.as_mut() {
            None => {
                if let Some(info) = line.strip_prefix("```") {
                    open = Some(Block {
                        line: i + 1,
                        info: info.trim().to_string(),
                        text: String::new(),
                    });
                }
            }
            Some(b) => {
                if line.trim_end() == "```" {
                    out.extend(open.take());
                } else {
                    b.text.push_str(line);
                    b.text.push('\n');
                }
            }
        }
    }
    assert!(
        open.is_none(),
        "spec/tutorial.md: a code block is never closed"
    );
    out
}

/// A piece of a printed line: text compared exactly, a number compared within the last digit
/// printed.
#[derive(Debug)]
enum Token {
    Text(String),
    Number { value: f64, digit: f64 },
}

fn tokens(line: &str) -> Vec<Token> {
    let chars: Vec<char> = line.chars().collect();
    let mut out = Vec::new();
    let mut text = String::new();
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        let after_word = i > 0 && (chars[i - 1].is_alphanumeric() || chars[i - 1] == '_');
        let starts_number = !after_word
            && (c.is_ascii_digit()
                || (c == '-' && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit())));
        if !starts_number {
            text.push(c);
            i += 1;
            continue;
        }
        let start = i;
        i += 1;
        while i < chars.len() && chars[i].is_ascii_digit() {
            i += 1;
        }
        let mut decimals = 0;
        if chars.get(i) == Some(&'.') && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit()) {
            i += 1;
            while i < chars.len() && chars[i].is_ascii_digit() {
                i += 1;
                decimals += 1;
            }
        }
        let mut exponent = 0;
        if matches!(chars.get(i), Some('e' | 'E')) {
            let mut j = i + 1;
            if matches!(chars.get(j), Some('+' | '-')) {
                j += 1;
            }
            if chars.get(j).is_some_and(|d| d.is_ascii_digit()) {
                while j < chars.len() && chars[j].is_ascii_digit() {
                    j += 1;
                }
                exponent = chars[i + 1..j]
                    .iter()
                    .collect::<String>()
                    .parse()
                    .unwrap_or(0);
                i = j;
            }
        }
        // A word that goes on after the digits (`2nd`, `10x`) is text, not a number.
        if chars.get(i).is_some_and(|c| c.is_alphabetic()) {
            text.extend(&chars[start..i]);
            continue;
        }
        let number: String = chars[start..i].iter().collect();
        let Ok(value) = number.parse::<f64>() else {
            text.push_str(&number);
            continue;
        };
        if !text.is_empty() {
            out.push(Token::Text(std::mem::take(&mut text)));
        }
        out.push(Token::Number {
            value,
            digit: 10f64.powi(exponent - decimals),
        });
    }
    if !text.is_empty() {
        out.push(Token::Text(text));
    }
    out
}

fn same_token(expected: &Token, actual: &Token, prefix: bool) -> bool {
    match (expected, actual) {
        (Token::Text(e), Token::Text(a)) => {
            if prefix {
                a.starts_with(e.trim_end())
            } else {
                e.trim_end() == a.trim_end()
            }
        }
        (
            Token::Number {
                value: e,
                digit: de,
            },
            Token::Number {
                value: a,
                digit: da,
            },
        ) => (e - a).abs() <= 1.01 * de.max(*da),
        _ => false,
    }
}

/// Whether `actual` is the line `expected` shows (its start, when `expected` ends in `…`).
fn matches(expected: &str, actual: &str) -> bool {
    let (expected, prefix) = match expected.trim_end().strip_suffix('…') {
        Some(start) => (start, true),
        None => (expected, false),
    };
    let (e, a) = (tokens(expected.trim_end()), tokens(actual.trim_end()));
    if e.len() > a.len() || (!prefix && e.len() != a.len()) {
        return false;
    }
    let last = e.len().saturating_sub(1);
    e.iter()
        .zip(&a)
        .enumerate()
        .all(|(i, (e, a))| same_token(e, a, prefix && i == last))
}

/// The lines of `shown` that `printed` lacks, in order (empty when the page shows the truth).
fn missing_lines(shown: &str, printed: &str) -> Vec<String> {
    let printed: Vec<&str> = printed.lines().collect();
    let mut at = 0;
    let mut missing = Vec::new();
    for line in shown.lines() {
        if line.trim().is_empty() || line.trim() == "…" {
            continue;
        }
        match printed[at..].iter().position(|p| matches(line, p)) {
            Some(k) => at += k + 1,
            None => missing.push(line.to_string()),
        }
    }
    missing
}

/// Runs one block with `sh -e`, standard error merged into standard output as on a terminal.
fn run(script: &str, dir: &Path) -> (bool, String) {
    let kin = PathBuf::from(env!("CARGO_BIN_EXE_kin"));
    let bin = kin.parent().map(Path::to_path_buf).unwrap_or_default();
    let path = std::env::var_os("PATH").unwrap_or_default();
    let mut paths = vec![bin];
    paths.extend(std::env::split_paths(&path));
    let out = Command::new("sh")
        .arg("-e")
        .arg("-c")
        .arg(format!("exec 2>&1\n{script}"))
        .current_dir(dir)
        .env("PATH", std::env::join_paths(paths).expect("PATH"))
        .env("NO_COLOR", "1")
        .output()
        .expect("sh runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

fn rms(fit: &Path) -> f64 {
    let text = std::fs::read_to_string(fit)
        .unwrap_or_else(|e| panic!("{}: {e} (the tutorial writes it)", fit.display()));
    let json: serde_json::Value = serde_json::from_str(&text).expect("FIT.json");
    json["rms"].as_f64().expect("rms in FIT.json")
}

#[test]
fn the_tutorial_runs_as_written_and_prints_what_it_shows() {
    let started = std::time::Instant::now();
    let page = std::fs::read_to_string(root().join("spec/tutorial.md")).expect("spec/tutorial.md");
    let blocks = blocks(&page);
    let dir = tempfile::tempdir().expect("temporary folder");
    let mut problems = Vec::new();
    let mut printed_by = Vec::new();
    for (i, block) in blocks.iter().enumerate() {
        if block.info != "sh" {
            continue;
        }
        let (ok, printed) = run(&block.text, dir.path());
        assert!(
            ok,
            "spec/tutorial.md:{}: the block failed:\n{}\nit printed:\n{printed}",
            block.line, block.text
        );
        if let Some(shown) = blocks.get(i + 1).filter(|b| b.info == "text") {
            let missing = missing_lines(&shown.text, &printed);
            if !missing.is_empty() {
                problems.push(format!(
                    "spec/tutorial.md:{}: the output shown has lines the command does not print (in this order):\n  {}\nit printed:\n{printed}",
                    shown.line,
                    missing.join("\n  ")
                ));
            }
        }
        printed_by.push((block.text.clone(), printed));
    }
    assert!(problems.is_empty(), "{}", problems.join("\n\n"));

    // The steps the tutorial is about are all there, each run above.
    let scripts: String = printed_by.iter().map(|(s, _)| s.as_str()).collect();
    for step in [
        "kin init mill-3axis mill",
        "kin check mill/machine.kin",
        "kin simulate truth.kin",
        "kin fit mill/machine.kin points.csv",
        "--apply 1",
        "-o corrections.csv",
        "--table linuxcnc -o tables/",
    ] {
        assert!(
            scripts.contains(step),
            "the tutorial no longer runs `{step}`"
        );
    }

    // The diagnosis names the effect hidden in truth.kin that the template lacks, first.
    let (_, diagnosis) = printed_by
        .iter()
        .find(|(s, _)| s.contains("kin diagnose") && !s.contains("--apply"))
        .expect("a `kin diagnose` without --apply");
    assert!(
        diagnosis.contains("1. Backlash") && diagnosis.contains("add: X.tx += backlash(X)"),
        "{diagnosis}"
    );
    let model = std::fs::read_to_string(dir.path().join("mill/machine.kin")).expect("model");
    assert!(model.contains("X.tx += backlash(X)"), "{model}");

    // The fit after the added line explains more: its residual RMS is smaller.
    let (before, after) = (
        rms(&dir.path().join("before.json")),
        rms(&dir.path().join("after.json")),
    );
    assert!(after < 0.5 * before, "RMS {before} before, {after} after");

    // What the tutorial writes for the controller.
    let csv = std::fs::read_to_string(dir.path().join("corrections.csv")).expect("corrections");
    assert!(csv.contains("corr_X"), "{csv}");
    for table in ["X.comp", "Y.comp", "Z.comp", "kin-compensation.txt"] {
        let path = dir.path().join("tables").join(table);
        let size = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        assert!(size > 0, "{} is missing or empty", path.display());
    }
    eprintln!("the tutorial ran in {:.1?}", started.elapsed());
}

#[test]
fn printed_lines_are_compared_by_text_and_by_the_digits_shown() {
    assert!(matches("  σ̂/σ = 2.6172   RMS", "  σ̂/σ = 2.6173   RMS"));
    assert!(!matches("  σ̂/σ = 2.6172   RMS", "  σ̂/σ = 2.6175   RMS"));
    assert!(!matches("RMS 2.5 um", "RMS 2.5 urad"));
    assert!(matches("condition 9.640e1)", "condition 9.641e1)"));
    assert!(matches("wrote a …", "wrote a file"));
    assert!(!matches("wrote a", "wrote a file"));
    assert!(matches("X[mm],dir_X,ex[um]", "X[mm],dir_X,ex[um]"));
    assert!(matches("-0.5 and 2nd", "-0.5 and 2nd"));
    let printed = "one\ntwo 2\nthree\n";
    assert!(missing_lines("one\n…\nthree\n", printed).is_empty());
    assert_eq!(missing_lines("three\none\n", printed), ["one"]);
}
