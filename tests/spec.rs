//! Keeps the language reference (`spec/*.md`) in step with the compiler and the grammar.
//!
//! 1. Every fenced code block of `spec/*.md` whose info string starts with `kin` is a whole
//!    `.kin` file (a `machine`, optionally followed by `params`) and is compiled with
//!    [`kin_compiler::compile`]:
//!    - ` ```kin ` must compile with no error diagnostic (warnings allowed);
//!    - ` ```kin error=E0xxx ` must report a diagnostic with that code; with `only`, every
//!      error it reports must have that code (no cascade of follow-on errors);
//!    - `E0601` (identifiability) is not a compiler diagnostic: such a block must compile clean,
//!      and `kin check` (the binary) must then report `E0601`;
//!    - ` ```kin check ` additionally runs `kin check` and requires it to pass, identifiability
//!      included; `observe=pose|position|length` and `aligned` are passed to `kin check` as
//!      `--observe …` and `--aligned` (and imply `check` when no error is expected).
//!
//!    Unknown words in a `kin` info string fail, so a misspelt `eror=` cannot silently turn an
//!    error example into an unchecked one.
//! 2. Every rule of `grammar/kin.pest` (its definition line and the lines of its body) appears
//!    verbatim in a ` ```pest ` block of `spec/grammar.md`, in the grammar's order, and nothing
//!    else does. Every rule quoted in a ` ```pest ` block of another spec file is verbatim the
//!    grammar's.
//!
//! Every failure names the spec file and line of its block.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::process::Command;

use kin_compiler::{compile, Diagnostic, Severity};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

/// The spec's Markdown files, sorted, as (path relative to the root, text).
fn spec_files() -> Vec<(String, String)> {
    let dir = root().join("spec");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    paths.sort();
    assert!(!paths.is_empty(), "no spec/*.md");
    paths
        .iter()
        .map(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            (format!("spec/{name}"), read(p))
        })
        .collect()
}

/// One fenced code block.
#[derive(Debug)]
struct Block {
    file: String,
    /// 1-based line of the opening fence.
    line: usize,
    /// The info string after the backticks, trimmed.
    info: String,
    text: String,
}

impl Block {
    fn place(&self) -> String {
        format!("{}:{} (```{})", self.file, self.line, self.info)
    }

    fn language(&self) -> &str {
        self.info.split_whitespace().next().unwrap_or("")
    }
}

/// The fenced blocks of one Markdown file. An unclosed fence is a problem of its own.
fn fenced_blocks(file: &str, text: &str, problems: &mut Vec<String>) -> Vec<Block> {
    let mut blocks = Vec::new();
    let mut open: Option<(usize, String, String)> = None;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        match &mut open {
            None => {
                if let Some(info) = trimmed.strip_prefix("```") {
                    open = Some((i + 1, info.trim().to_string(), String::new()));
                }
            }
            Some((start, info, body)) => {
                if trimmed.trim_end() == "```" {
                    blocks.push(Block {
                        file: file.to_string(),
                        line: *start,
                        info: std::mem::take(info),
                        text: std::mem::take(body),
                    });
                    open = None;
                } else {
                    body.push_str(line);
                    body.push('\n');
                }
            }
        }
    }
    if let Some((start, info, _)) = open {
        problems.push(format!(
            "{file}:{start} (```{info}): the code block is never closed"
        ));
    }
    blocks
}

/// What a ` ```kin … ` info string asks for.
#[derive(Debug, Default)]
struct Expect {
    error: Option<String>,
    only: bool,
    check: bool,
    observe: Option<String>,
    aligned: bool,
}

fn parse_info(info: &str) -> Result<Expect, String> {
    let mut e = Expect::default();
    for word in info.split_whitespace().skip(1) {
        if let Some(code) = word.strip_prefix("error=") {
            let valid = code.len() == 5
                && code.starts_with(['E', 'W'])
                && code.chars().skip(1).all(|c| c.is_ascii_digit());
            if !valid {
                return Err(format!("`{word}`: not a diagnostic code"));
            }
            e.error = Some(code.to_string());
        } else if let Some(o) = word.strip_prefix("observe=") {
            if !["pose", "position", "length"].contains(&o) {
                return Err(format!("`{word}`: observe is pose, position or length"));
            }
            e.observe = Some(o.to_string());
        } else if word == "aligned" {
            e.aligned = true;
        } else if word == "check" {
            e.check = true;
        } else if word == "only" {
            e.only = true;
        } else {
            return Err(format!("unknown word `{word}` in the info string (error=CODE, only, check, observe=…, aligned)"));
        }
    }
    let identifiability = e.error.as_deref() == Some("E0601");
    if e.only && (e.error.is_none() || identifiability) {
        return Err("`only` goes with error=CODE (a compiler diagnostic)".into());
    }
    if e.error.is_some() && !identifiability && (e.check || e.observe.is_some() || e.aligned) {
        return Err(
            "`check`, `observe=` and `aligned` go with no error or with error=E0601".into(),
        );
    }
    if e.error.is_none() && (e.observe.is_some() || e.aligned) {
        e.check = true;
    }
    Ok(e)
}

fn describe(d: &Diagnostic) -> String {
    let severity = match d.severity {
        Severity::Error => "error",
        Severity::Warning => "warning",
    };
    format!("{severity}[{}] {}", d.code, d.message)
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(non-string panic payload)".into())
}

fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kin-spec-{}", std::process::id()));
    std::fs::create_dir_all(&dir)
        .unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    dir
}

/// Runs `kin check --format json` on a block; returns (exit code, diagnostic codes) or why not.
fn kin_check(block: &Block, expect: &Expect, index: usize) -> Result<(i32, Vec<String>), String> {
    let path = scratch().join(format!("block{index}.kin"));
    std::fs::write(&path, &block.text)
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_kin"));
    cmd.arg("check")
        .arg(&path)
        .args(["--format", "json", "--color", "never"]);
    if let Some(o) = &expect.observe {
        cmd.args(["--observe", o]);
    }
    if expect.aligned {
        cmd.arg("--aligned");
    }
    let out = cmd.output().map_err(|e| format!("cannot run kin: {e}"))?;
    let code = out.status.code().unwrap_or(-1);
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).map_err(|e| {
        format!(
            "`kin check` (exit {code}) printed no JSON ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    })?;
    let codes = json["diagnostics"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|d| d["code"].as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    Ok((code, codes))
}

/// Checks one ` ```kin ` block; returns what is wrong with it.
fn check_kin_block(block: &Block, index: usize) -> Option<String> {
    let expect = match parse_info(&block.info) {
        Ok(e) => e,
        Err(e) => return Some(e),
    };
    let out = match catch_unwind(AssertUnwindSafe(|| compile(&block.text))) {
        Ok(out) => out,
        Err(payload) => return Some(format!("compile panicked: {}", panic_message(&*payload))),
    };
    let errors: Vec<String> = out
        .diagnostics
        .iter()
        .filter(|d| d.is_error())
        .map(describe)
        .collect();
    let all: Vec<String> = out.diagnostics.iter().map(describe).collect();
    match expect.error.as_deref() {
        Some("E0601") | None => {
            if !errors.is_empty() {
                return Some(format!(
                    "expected to compile clean, got:\n      {}",
                    errors.join("\n      ")
                ));
            }
        }
        Some(code) => {
            if !out.diagnostics.iter().any(|d| d.code == code) {
                let got = if all.is_empty() {
                    "no diagnostic".to_string()
                } else {
                    all.join("\n      ")
                };
                return Some(format!("expected {code}, got:\n      {got}"));
            }
            let others: Vec<String> = out
                .diagnostics
                .iter()
                .filter(|d| d.is_error() && d.code != code)
                .map(describe)
                .collect();
            if expect.only && !others.is_empty() {
                return Some(format!(
                    "expected only {code}, also got:\n      {}",
                    others.join("\n      ")
                ));
            }
            return None;
        }
    }
    let identifiability = expect.error.as_deref() == Some("E0601");
    if !identifiability && !expect.check {
        return None;
    }
    let (code, codes) = match kin_check(block, &expect, index) {
        Ok(r) => r,
        Err(e) => return Some(e),
    };
    if identifiability {
        if code != 1 || !codes.iter().any(|c| c == "E0601") {
            return Some(format!(
                "expected `kin check` to report E0601 (exit 1), got exit {code} with {codes:?}"
            ));
        }
    } else if code != 0 {
        return Some(format!(
            "expected `kin check` to pass, got exit {code} with {codes:?}"
        ));
    }
    None
}

#[test]
fn every_kin_block_of_the_spec_checks_as_annotated() {
    let mut problems = Vec::new();
    let mut checked = 0;
    let mut errors = 0;
    for (file, text) in spec_files() {
        for block in fenced_blocks(&file, &text, &mut problems) {
            let lang = block.language();
            if lang != "kin" {
                if lang.starts_with("kin") {
                    problems.push(format!(
                        "{}: unknown language `{lang}` (a typo for `kin`?)",
                        block.place()
                    ));
                }
                continue;
            }
            checked += 1;
            if block.info.contains("error=") {
                errors += 1;
            }
            if let Some(p) = check_kin_block(&block, checked) {
                problems.push(format!("{}: {p}", block.place()));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "{} problem(s) in spec code blocks:\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
    assert!(checked >= 10 && errors >= 5, "only {checked} `kin` blocks ({errors} with an error) found: is the fence syntax still ```kin?");
}

/// Whether a line starts a rule definition: `^\s*[a-zA-Z_]+\s*=\s*[_@$!]?\{`.
fn rule_name(line: &str) -> Option<&str> {
    let s = line.trim_start();
    let end = s
        .find(|c: char| !(c.is_ascii_alphabetic() || c == '_'))
        .unwrap_or(s.len());
    if end == 0 {
        return None;
    }
    let (name, rest) = s.split_at(end);
    let rest = rest.trim_start().strip_prefix('=')?.trim_start();
    let rest = rest.strip_prefix(['_', '@', '$', '!']).unwrap_or(rest);
    rest.starts_with('{').then_some(name)
}

/// A rule as written: its name and its lines (definition, then the body lines up to a blank
/// line, a comment at the start of a line, or the next definition).
#[derive(Debug, Clone, PartialEq)]
struct Rule {
    name: String,
    lines: Vec<String>,
}

fn rules(text: &str) -> Vec<Rule> {
    let mut out: Vec<Rule> = Vec::new();
    let mut in_rule = false;
    for line in text.lines() {
        let line = line.trim_end();
        if let Some(name) = rule_name(line) {
            out.push(Rule {
                name: name.to_string(),
                lines: vec![line.to_string()],
            });
            in_rule = true;
        } else if line.is_empty() || line.starts_with("//") {
            in_rule = false;
        } else if in_rule {
            if let Some(r) = out.last_mut() {
                r.lines.push(line.to_string());
            }
        }
    }
    out
}

/// The rules quoted in the ` ```pest ` blocks of a spec file, each with the line of its block.
fn quoted_rules(file: &str, text: &str, problems: &mut Vec<String>) -> Vec<(Rule, usize)> {
    fenced_blocks(file, text, problems)
        .into_iter()
        .filter(|b| b.language() == "pest")
        .flat_map(|b| {
            let line = b.line;
            rules(&b.text).into_iter().map(move |r| (r, line))
        })
        .collect()
}

#[test]
fn the_spec_quotes_every_grammar_rule_verbatim_and_in_order() {
    let grammar = rules(&read(&root().join("grammar/kin.pest")));
    assert!(
        grammar.len() > 50,
        "only {} rules found in grammar/kin.pest",
        grammar.len()
    );
    let mut problems = Vec::new();
    let files = spec_files();
    let Some((_, spec_grammar)) = files.iter().find(|(f, _)| f == "spec/grammar.md") else {
        panic!("spec/grammar.md is missing");
    };
    let quoted = quoted_rules("spec/grammar.md", spec_grammar, &mut problems);

    let missing: Vec<&str> = grammar
        .iter()
        .filter(|g| !quoted.iter().any(|(q, _)| q.name == g.name))
        .map(|g| g.name.as_str())
        .collect();
    if !missing.is_empty() {
        problems.push(format!(
            "spec/grammar.md lacks the rules: {}",
            missing.join(", ")
        ));
    }
    for (q, line) in &quoted {
        match grammar.iter().find(|g| g.name == q.name) {
            None => problems.push(format!("spec/grammar.md:{line}: quotes `{}`, which grammar/kin.pest does not define", q.name)),
            Some(g) if g.lines != q.lines => problems.push(format!(
                "spec/grammar.md:{line}: `{}` differs from grammar/kin.pest:\n      grammar: {}\n      spec:    {}",
                q.name,
                g.lines.join("\n               "),
                q.lines.join("\n               ")
            )),
            Some(_) => {}
        }
    }
    let mut seen = std::collections::HashSet::new();
    for (q, line) in &quoted {
        if !seen.insert(q.name.as_str()) {
            problems.push(format!(
                "spec/grammar.md:{line}: `{}` is quoted twice",
                q.name
            ));
        }
    }
    // Order: the quoted rules that the grammar has, in the spec's order, against the grammar's.
    let spec_order: Vec<&str> = quoted
        .iter()
        .map(|(q, _)| q.name.as_str())
        .filter(|n| grammar.iter().any(|g| g.name == *n))
        .collect();
    let grammar_order: Vec<&str> = grammar
        .iter()
        .map(|g| g.name.as_str())
        .filter(|n| spec_order.contains(n))
        .collect();
    let mut deduped = spec_order.clone();
    let mut once = std::collections::HashSet::new();
    deduped.retain(|n| once.insert(*n));
    if deduped != grammar_order {
        let first = deduped
            .iter()
            .zip(&grammar_order)
            .position(|(a, b)| a != b)
            .unwrap_or(0);
        problems.push(format!(
            "spec/grammar.md quotes the rules out of order: from `{}` on, the grammar has {} but the spec has {}",
            grammar_order.get(first).copied().unwrap_or(""),
            grammar_order.iter().skip(first).take(4).copied().collect::<Vec<_>>().join(", "),
            deduped.iter().skip(first).take(4).copied().collect::<Vec<_>>().join(", ")
        ));
    }

    // Rules quoted elsewhere must be the grammar's too.
    for (file, text) in files.iter().filter(|(f, _)| f != "spec/grammar.md") {
        for (q, line) in quoted_rules(file, text, &mut problems) {
            match grammar.iter().find(|g| g.name == q.name) {
                None => problems.push(format!("{file}:{line}: quotes `{}`, which grammar/kin.pest does not define", q.name)),
                Some(g) if g.lines != q.lines => problems.push(format!(
                    "{file}:{line}: `{}` differs from grammar/kin.pest:\n      grammar: {}\n      spec:    {}",
                    q.name,
                    g.lines.join("\n               "),
                    q.lines.join("\n               ")
                )),
                Some(_) => {}
            }
        }
    }
    assert!(
        problems.is_empty(),
        "{} problem(s):\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
}

#[test]
fn the_rule_splitter_sees_what_the_brief_pattern_sees() {
    // `^\s*[a-zA-Z_]+\s*=\s*[_@$!]?\{`
    assert_eq!(
        rule_name("vector_q = ${ vector ~ (inline_space ~ unit)? }"),
        Some("vector_q")
    );
    assert_eq!(rule_name("  WHITESPACE = _{ \" \" }"), Some("WHITESPACE"));
    assert_eq!(rule_name("unit_name = @{"), Some("unit_name"));
    assert_eq!(rule_name("vector   = !{ lparen }"), Some("vector"));
    assert_eq!(rule_name("// a = { b }"), None);
    assert_eq!(rule_name("    ~ !ident_char"), None);
    assert_eq!(rule_name("a = b"), None);
    let r = rules("x = @{\n    (\"a\"\n     | \"b\")\n}\ny = { x }\n// c = { d }\n");
    assert_eq!(r.len(), 2);
    assert_eq!(r[0].lines.len(), 4);
    assert_eq!(r[1].lines, ["y = { x }"]);
}

/// What a ` ```csv … ` info string asks for.
#[derive(Debug, Default)]
struct CsvExpect {
    poses: bool,
    error: bool,
    kind: Option<&'static str>,
}

fn parse_csv_info(info: &str) -> Result<CsvExpect, String> {
    let mut e = CsvExpect::default();
    for word in info.split_whitespace().skip(1) {
        match word {
            "poses" => e.poses = true,
            "error" => e.error = true,
            "points" => e.kind = Some("points"),
            "lengths" => e.kind = Some("lengths"),
            _ => {
                return Err(format!(
                    "unknown word `{word}` in the info string (poses, error, points, lengths)"
                ))
            }
        }
    }
    Ok(e)
}

/// Checks one ` ```csv ` block against `machine`; `message` is the ` ```text ` block that follows
/// an error example, whose lines (without the CLI's `error: ` prefix and `help:` lines) must be
/// lines of the reader's message.
fn check_csv_block(
    block: &Block,
    machine: &kin_compiler::ir::Machine,
    message: Option<&Block>,
) -> Option<String> {
    use kin_data::data::{read, Observations, ReadOptions};
    let expect = match parse_csv_info(&block.info) {
        Ok(e) => e,
        Err(e) => return Some(e),
    };
    let options = ReadOptions {
        poses: expect.poses,
        ..ReadOptions::default()
    };
    let result = read(
        block.text.as_bytes(),
        Path::new("data.csv"),
        machine,
        &options,
    );
    match (result, expect.error) {
        (Ok(_), true) => Some("is read without a problem, but is marked `error`".into()),
        (Err(e), false) => Some(format!("is refused: {e}")),
        (Err(e), true) => {
            let Some(message) = message.filter(|m| m.language() == "text") else {
                return Some(
                    "an error example must be followed by a ```text block of its message".into(),
                );
            };
            let printed = e.to_string();
            let printed: Vec<&str> = printed.lines().map(str::trim).collect();
            message
                .text
                .lines()
                .map(|l| l.trim())
                .filter(|l| !l.is_empty() && !l.starts_with("help:"))
                .map(|l| l.strip_prefix("error: ").unwrap_or(l))
                .find(|l| !printed.contains(l))
                .map(|l| {
                    format!(
                        "the message lacks the line `{l}`; it is:\n{}",
                        printed.join("\n")
                    )
                })
        }
        (Ok(o), false) => {
            let kind = match o {
                Observations::Points(_) => "points",
                Observations::Lengths(_) => "lengths",
            };
            match expect.kind {
                Some(k) if k != kind => Some(format!("is read as {kind}, not {k}")),
                _ => None,
            }
        }
    }
}

#[test]
fn every_csv_block_of_the_spec_reads_as_annotated() {
    let mut problems = Vec::new();
    let mut checked = 0;
    for (file, text) in spec_files() {
        let blocks = fenced_blocks(&file, &text, &mut problems);
        let mut machine = None;
        for (i, block) in blocks.iter().enumerate() {
            match block.language() {
                "kin" if !block.info.contains("error=") => {
                    machine = compile(&block.text).compiled.map(|c| c.machine);
                }
                "csv" => {
                    checked += 1;
                    let Some(m) = machine.as_ref() else {
                        problems.push(format!("{}: no ```kin machine before it", block.place()));
                        continue;
                    };
                    if let Some(p) = check_csv_block(block, m, blocks.get(i + 1)) {
                        problems.push(format!("{}: {p}", block.place()));
                    }
                }
                _ => {}
            }
        }
    }
    assert!(
        problems.is_empty(),
        "{} problem(s) in spec csv blocks:\n  {}",
        problems.len(),
        problems.join("\n  ")
    );
    assert!(checked >= 10, "only {checked} `csv` blocks found");
}
