//! Diagnostics as plain data. Every stage reports through this one type; only the CLI renders
//! (with ariadne), so the library never prints and tests can compare diagnostics structurally.

use serde::Serialize;

/// A byte range in the source text. Byte offsets (not characters) because pest produces them;
/// the renderer is configured to index by bytes so labels stay put after a `µ`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize)]
pub struct Span {
    pub start: usize,
    pub end: usize,
}

impl Span {
    pub fn new(start: usize, end: usize) -> Self {
        Span { start, end }
    }
    /// The smallest span covering both.
    pub fn to(self, other: Span) -> Span {
        Span::new(self.start.min(other.start), self.end.max(other.end))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    Error,
    Warning,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Label {
    pub span: Span,
    pub message: String,
}

/// What is wrong (`message`), where (`labels`, the first is primary), why (`notes`) and how
/// to fix it (`help`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnostic {
    pub severity: Severity,
    /// Stable identifier, listed with its meaning in `spec/semantics.md`.
    pub code: &'static str,
    pub message: String,
    pub labels: Vec<Label>,
    pub notes: Vec<String>,
    pub help: Option<String>,
}

impl Diagnostic {
    pub fn error(code: &'static str, message: impl Into<String>, span: Span) -> Self {
        Diagnostic::new(Severity::Error, code, message, span)
    }

    pub fn warning(code: &'static str, message: impl Into<String>, span: Span) -> Self {
        Diagnostic::new(Severity::Warning, code, message, span)
    }

    fn new(severity: Severity, code: &'static str, message: impl Into<String>, span: Span) -> Self {
        Diagnostic {
            severity,
            code,
            message: bounded(message.into()),
            labels: vec![Label {
                span,
                message: String::new(),
            }],
            notes: Vec::new(),
            help: None,
        }
    }

    /// Text for the primary label.
    pub fn with_label(mut self, message: impl Into<String>) -> Self {
        if let Some(first) = self.labels.first_mut() {
            first.message = bounded(message.into());
        }
        self
    }

    /// A secondary label pointing at related text ("first defined here").
    pub fn with_secondary(mut self, span: Span, message: impl Into<String>) -> Self {
        self.labels.push(Label {
            span,
            message: bounded(message.into()),
        });
        self
    }

    pub fn with_note(mut self, note: impl Into<String>) -> Self {
        self.notes.push(bounded(note.into()));
        self
    }

    pub fn with_help(mut self, help: impl Into<String>) -> Self {
        self.help = Some(bounded(help.into()));
        self
    }

    pub fn primary_span(&self) -> Span {
        self.labels.first().map(|l| l.span).unwrap_or_default()
    }

    pub fn is_error(&self) -> bool {
        self.severity == Severity::Error
    }
}

/// Quoted user text longer than this (in characters) is shortened in a message.
const QUOTED: usize = 80;
/// A message, label, note or help longer than this (in bytes) is cut.
const TEXT: usize = 2000;

/// A diagnostic's text as it is shown: a `quoted` stretch of the user's text beyond
/// [`QUOTED`] characters keeps its start and says how long it is, and the whole stays within
/// [`TEXT`] bytes. A 10 MB identifier once came back as 70 MB of messages.
fn bounded(text: String) -> String {
    if text.len() <= QUOTED {
        return text;
    }
    let mut out = String::with_capacity(text.len().min(TEXT + 64));
    // The length of the quoted text just shortened, said after its closing backtick.
    let mut said: Option<usize> = None;
    for (i, piece) in text.split('`').enumerate() {
        if i > 0 {
            out.push('`');
        }
        if let Some(chars) = said.take() {
            out.push_str(&format!(" ({chars} characters)"));
        }
        // Odd pieces lie between backticks: quoted text.
        let chars = piece.chars().count();
        if i % 2 == 1 && chars > QUOTED {
            out.extend(piece.chars().take(QUOTED / 2));
            out.push('…');
            said = Some(chars);
        } else {
            out.push_str(piece);
        }
        if out.len() > TEXT {
            break;
        }
    }
    if out.len() > TEXT {
        let mut cut = TEXT;
        while !out.is_char_boundary(cut) {
            cut -= 1;
        }
        out.truncate(cut);
        out.push('…');
    }
    out
}

/// The closest candidate by edit distance, if it is close enough to be a plausible typo.
pub fn suggest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let lower = name.to_lowercase();
    candidates
        .into_iter()
        .map(|c| (edit_distance(&lower, &c.to_lowercase()), c))
        .filter(|(d, c)| *d <= (c.chars().count().max(name.chars().count()) / 3).max(1))
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != *cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_quoted_text_is_shortened_and_its_length_said() {
        let name = "a".repeat(10_000_000);
        let d = Diagnostic::error("E0101", format!("unknown name `{name}`"), Span::new(0, 1))
            .with_help(format!("did you mean `{}`?", "b".repeat(5000)));
        assert_eq!(
            d.message,
            format!("unknown name `{}…` (10000000 characters)", "a".repeat(40))
        );
        assert!(
            d.help.as_deref().is_some_and(|h| h.len() < 200),
            "{:?}",
            d.help
        );
        // Ordinary text is left alone.
        let d = Diagnostic::error("E0101", "unknown name `Xx`", Span::new(0, 1));
        assert_eq!(d.message, "unknown name `Xx`");
        // Unquoted text beyond the bound is cut on a character boundary.
        let d = Diagnostic::error("E0001", "é".repeat(3000), Span::new(0, 1));
        assert!(d.message.len() <= TEXT + 3 && d.message.ends_with('…'));
    }

    #[test]
    fn suggests_close_names_only() {
        assert_eq!(suggest("Xx", ["X", "Y", "Z"]), Some("X"));
        assert_eq!(suggest("splin", ["spline", "linear"]), Some("spline"));
        assert_eq!(suggest("banana", ["X", "Y"]), None);
    }
}
