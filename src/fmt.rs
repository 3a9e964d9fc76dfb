//! `kin fmt`: formats `.kin` files in place, or with `--check` says which would change and how.
//! The formatting itself is `kin_syntax::format` (the syntax layer alone), shared with `kin lsp`.

use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};

use kin_syntax::format::{format_source, FormatError};

use crate::load::Failed;
use crate::render;

/// What became of one text.
enum Outcome {
    Unchanged,
    /// Formatted (written, or with `--check` reported).
    Changed,
    /// Not formatted: syntax errors or an unreadable file, already reported.
    Failed(Failed),
}

/// Formats `paths` (files, or folders searched for `*.kin`), or standard input to standard
/// output when there are none.
pub fn run(paths: &[PathBuf], check: bool, color: bool) -> Result<(), Failed> {
    if paths.is_empty() {
        return stdin(check, color);
    }
    let mut files = Vec::new();
    for p in paths {
        collect(p, &mut files)?;
    }
    let mut worst: Option<Failed> = None;
    let mut changed = Vec::new();
    for file in &files {
        match one(file, check, color) {
            Outcome::Unchanged => {}
            Outcome::Changed => changed.push(file),
            Outcome::Failed(f) => worst = Some(worst.map_or(f, |w| Failed(w.0.max(f.0)))),
        }
    }
    if check && !changed.is_empty() {
        eprintln!(
            "{} file{} would be reformatted (run `kin fmt` on {}):",
            changed.len(),
            if changed.len() == 1 { "" } else { "s" },
            if changed.len() == 1 { "it" } else { "them" }
        );
        for f in &changed {
            eprintln!("  {}", f.display());
        }
        worst = Some(worst.map_or(Failed::INPUT, |w| Failed(w.0.max(1))));
    }
    worst.map_or(Ok(()), Err)
}

/// `path` itself if it is a file, every `*.kin` under it (sorted) if it is a folder.
fn collect(path: &Path, out: &mut Vec<PathBuf>) -> Result<(), Failed> {
    let meta = std::fs::metadata(path).map_err(|e| {
        eprintln!("error: cannot read `{}`: {e}", path.display());
        Failed::USAGE
    })?;
    if !meta.is_dir() {
        out.push(path.to_path_buf());
        return Ok(());
    }
    let mut entries = std::fs::read_dir(path)
        .and_then(|d| {
            d.map(|e| e.map(|e| e.path()))
                .collect::<Result<Vec<_>, _>>()
        })
        .map_err(|e| {
            eprintln!("error: cannot list `{}`: {e}", path.display());
            Failed::USAGE
        })?;
    entries.sort();
    for entry in entries {
        // Links are not followed into folders: a link cycle would never end.
        let is_dir = std::fs::symlink_metadata(&entry).is_ok_and(|m| m.is_dir());
        if is_dir {
            collect(&entry, out)?;
        } else if entry.extension().is_some_and(|e| e == "kin") {
            out.push(entry);
        }
    }
    Ok(())
}

fn one(path: &Path, check: bool, color: bool) -> Outcome {
    let name = path.display().to_string();
    let source = match crate::load::source(path) {
        Ok(s) => s,
        Err(f) => return Outcome::Failed(f),
    };
    if !source.diagnostics.is_empty() {
        let _ = render::human(
            &name,
            &source.text,
            &source.diagnostics,
            color,
            &mut std::io::stderr().lock(),
        );
        return Outcome::Failed(Failed::INPUT);
    }
    let formatted = match formatted(&name, &source.text, color) {
        Ok(f) => f,
        Err(f) => return Outcome::Failed(f),
    };
    if formatted == source.text {
        return Outcome::Unchanged;
    }
    if check {
        eprint!("{}", diff(&name, &source.text, &formatted));
        return Outcome::Changed;
    }
    match kin_data::output::replace(path, formatted.as_bytes()) {
        Ok(()) => Outcome::Changed,
        Err(e) => {
            eprintln!("error: cannot write `{name}`: {e}");
            Outcome::Failed(Failed::USAGE)
        }
    }
}

fn formatted(name: &str, text: &str, color: bool) -> Result<String, Failed> {
    match format_source(text) {
        Ok(f) => Ok(f),
        Err(FormatError::Syntax(diagnostics)) => {
            let _ = render::human(
                name,
                text,
                &diagnostics,
                color,
                &mut std::io::stderr().lock(),
            );
            eprintln!("{name}: not formatted (syntax errors)");
            Err(Failed::INPUT)
        }
        Err(e @ FormatError::Changed(_)) => {
            eprintln!("error: {name}: {e}");
            Err(Failed::INPUT)
        }
    }
}

/// The changes as a unified diff (three lines of context), `--- name` / `+++ name (formatted)`.
fn diff(name: &str, old: &str, new: &str) -> String {
    similar::TextDiff::from_lines(old, new)
        .unified_diff()
        .context_radius(3)
        .header(name, &format!("{name} (formatted)"))
        .to_string()
}

fn stdin(check: bool, color: bool) -> Result<(), Failed> {
    let mut bytes = Vec::new();
    let limit = kin_data::bounded_read::MAX_TEXT_BYTES;
    // One byte past the limit tells a text that fits from one that was cut (`< /dev/zero`):
    // a cut text would be formatted as if it were whole.
    std::io::stdin()
        .take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| {
            eprintln!("error: cannot read standard input: {e}");
            Failed::USAGE
        })?;
    if bytes.len() as u64 > limit {
        eprintln!("error: <stdin>: more than {limit} bytes, larger than any .kin source kin reads");
        return Err(Failed::INPUT);
    }
    let Ok(text) = String::from_utf8(bytes) else {
        eprintln!("error: <stdin>: not UTF-8 text");
        return Err(Failed::INPUT);
    };
    let formatted = formatted("<stdin>", &text, color)?;
    if check {
        if formatted != text {
            eprint!("{}", diff("<stdin>", &text, &formatted));
            return Err(Failed::INPUT);
        }
        return Ok(());
    }
    std::io::stdout()
        .lock()
        .write_all(formatted.as_bytes())
        .map_err(|e| {
            eprintln!("error: cannot write standard output: {e}");
            Failed::USAGE
        })
}
