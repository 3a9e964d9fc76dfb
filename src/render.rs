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
    for d in diagnostics {
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
    Ok(())
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
