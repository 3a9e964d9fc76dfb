//! Rendering of diagnostics for people (ariadne) and for tools (JSON).

use std::io::Write;

use ariadne::{Color, Config, IndexType, Label, Report, ReportKind, Source};
use kin_compiler::{Diagnostic, Severity};
use serde::Serialize;

/// Renders diagnostics as ariadne reports. Byte indexing, because spans are byte offsets; colour
/// only when asked (the CLI asks when stderr is a terminal).
pub fn human(
    path: &str,
    source: &str,
    diagnostics: &[Diagnostic],
    color: bool,
    out: &mut impl Write,
) -> std::io::Result<()> {
    let src = Source::from(source);
    for d in diagnostics.iter().take(MAX_SHOWN) {
        // A line too long to show (a 10 MB token) is not drawn: the report says where, and
        // what, in a few lines, instead of repeating the line (70 MB in 93 s once).
        if d.labels
            .iter()
            .any(|l| longest_line(source, l.span) > MAX_SHOWN_LINE)
        {
            brief(path, source, d, out)?;
            continue;
        }
        let kind = match d.severity {
            Severity::Error => ReportKind::Error,
            Severity::Warning => ReportKind::Warning,
        };
        let primary = clamp(d.primary_span().start, d.primary_span().end, source.len());
        let mut report = Report::build(kind, (path, primary.clone()))
            .with_config(
                Config::default()
                    .with_index_type(IndexType::Byte)
                    .with_color(color),
            )
            .with_code(d.code)
            .with_message(&d.message);
        for (i, l) in d.labels.iter().enumerate() {
            let range = clamp(l.span.start, l.span.end, source.len());
            let mut label = Label::new((path, range)).with_order(i as i32);
            if !l.message.is_empty() {
                label = label.with_message(&l.message);
            }
            if color {
                label = label.with_color(if i == 0 { Color::Red } else { Color::Blue });
            }
            report = report.with_label(label);
        }
        for n in &d.notes {
            report = report.with_note(n);
        }
        if let Some(h) = &d.help {
            report = report.with_help(h);
        }
        report.finish().write((path, &src), &mut *out)?;
    }
    if let Some(left) = diagnostics.len().checked_sub(MAX_SHOWN).filter(|n| *n > 0) {
        // 10⁵ errors once printed 26 MB: the first ones say what is wrong, a count the rest.
        let errors = diagnostics[MAX_SHOWN..]
            .iter()
            .filter(|d| d.is_error())
            .count();
        writeln!(
            out,
            "… and {left} more ({errors} error{}, {} warning{}) not shown; `kin check {path} --format json` lists every one",
            if errors == 1 { "" } else { "s" },
            left - errors,
            if left - errors == 1 { "" } else { "s" },
        )?;
    }
    Ok(())
}

/// At most this many diagnostics are drawn; the rest are counted.
const MAX_SHOWN: usize = 50;

/// Source lines longer than this (bytes) are not drawn under a diagnostic.
const MAX_SHOWN_LINE: usize = 4096;

/// The longest line the span `span` touches, in bytes.
fn longest_line(source: &str, span: kin_compiler::Span) -> usize {
    let range = clamp(span.start, span.end, source.len());
    let start = source
        .get(..range.start)
        .and_then(|s| s.rfind('\n'))
        .map_or(0, |i| i + 1);
    let end = source
        .get(range.end..)
        .and_then(|s| s.find('\n'))
        .map_or(source.len(), |i| range.end + i);
    source
        .get(start..end)
        .map_or(0, |text| text.split('\n').map(str::len).max().unwrap_or(0))
}

/// A diagnostic without its source lines: `path:line:column: error[CODE]: message`, then its
/// labels, notes and help, one per line.
fn brief(path: &str, source: &str, d: &Diagnostic, out: &mut impl Write) -> std::io::Result<()> {
    let kind = match d.severity {
        Severity::Error => "error",
        Severity::Warning => "warning",
    };
    let (line, column) = line_column(source, d.primary_span().start.min(source.len()));
    writeln!(
        out,
        "{path}:{line}:{column}: {kind}[{}]: {}",
        d.code, d.message
    )?;
    for l in d.labels.iter().filter(|l| !l.message.is_empty()) {
        let (line, column) = line_column(source, l.span.start.min(source.len()));
        writeln!(out, "  {path}:{line}:{column}: {}", l.message)?;
    }
    for n in &d.notes {
        writeln!(out, "  note: {n}")?;
    }
    if let Some(h) = &d.help {
        writeln!(out, "  help: {h}")?;
    }
    writeln!(out, "  (the line is too long to show)")
}

fn clamp(start: usize, end: usize, len: usize) -> std::ops::Range<usize> {
    let s = start.min(len);
    s..end.clamp(s, len)
}

/// A diagnostic with line and column resolved, for `--format json`.
#[derive(Serialize)]
pub struct JsonDiagnostic<'a> {
    #[serde(flatten)]
    pub diagnostic: &'a Diagnostic,
    pub file: &'a str,
    /// 1-based line and column (in characters) of the primary span's start.
    pub line: usize,
    pub column: usize,
}

pub fn json_diagnostics<'a>(
    path: &'a str,
    source: &str,
    diagnostics: &'a [Diagnostic],
) -> Vec<JsonDiagnostic<'a>> {
    diagnostics
        .iter()
        .map(|d| {
            let (line, column) = line_column(source, d.primary_span().start);
            JsonDiagnostic {
                diagnostic: d,
                file: path,
                line,
                column,
            }
        })
        .collect()
}

pub fn line_column(source: &str, offset: usize) -> (usize, usize) {
    let before = source.get(..offset.min(source.len())).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let column = before
        .rsplit('\n')
        .next()
        .map(|l| l.chars().count())
        .unwrap_or(0)
        + 1;
    (line, column)
}
