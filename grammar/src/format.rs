//! The `.kin` formatter behind `kin fmt` and the language server's formatting.
//!
//! It works from pest's parse tree, generically: the tree's leaves (pairs without inner pairs,
//! and whole units such as `um/m/K`, whose parts must stay together) are the tokens, and the
//! text between two tokens holds only whitespace and comments. The formatter rewrites only that
//! whitespace, so a new grammar form formats without code of its own:
//!
//! - line breaks are the author's: a token never moves to another line; runs of blank lines
//!   become one, none after `{` or before `}`;
//! - indentation: four spaces per open `{` for each statement (a child of a braced block), a
//!   closing `}` at its block's level; a continuation line that starts with an operator lines
//!   up under the statement's `=` / `+=`; other continuation lines line up after the open
//!   bracket when something follows it on its line, else go four spaces in per open bracket;
//! - within a line: one space around `=`, `+=`, binary operators and `:`, after `,`, inside
//!   `{ … }`, two between statements that share a line; none after `(`/`[`, before `)`/`]`/`,`, around `.` and in `1..2`, before a call's
//!   `(` and an index's `[`; elsewhere one space where there was space and none where there was
//!   none (`5mm` stays as written, so a unit never leaves its number);
//! - every comment is kept: one on its own line is indented like the line after it (one
//!   indented deeper than that line stays a level deeper: it annotates the line before); one
//!   after code keeps its column (moved with the line's indentation), so aligned comments stay
//!   aligned, with at least one space before it;
//! - trailing whitespace goes, the file ends with one newline.
//!
//! The result is parsed again and its tokens compared with the input's: formatting that would
//! change a token is refused ([`FormatError::Changed`]) rather than written.

use pest::iterators::Pair;
use pest::Parser as _;

use crate::diagnostic::Diagnostic;
use crate::syntax::parse::{KinParser, Rule};

/// Why a source could not be formatted.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    /// The source does not parse: nothing is formatted (the diagnostics say why).
    #[error("the file has syntax errors")]
    Syntax(Vec<Diagnostic>),
    /// Formatting would have changed the tokens (a bug in the formatter): the text is left as
    /// it was.
    #[error("formatting would change the tokens near byte {0}; the file was left as it is")]
    Changed(usize),
}

/// Spaces per indentation level.
const INDENT: usize = 4;

/// The formatted text of a `.kin` source: a machine description (with or without a `params`
/// block) or a parameter file.
pub fn format_source(source: &str) -> Result<String, FormatError> {
    let (rule, tokens) = tokenize(source)?;
    let formatted = render(source, &tokens);
    // The guarantee: the same tokens in the same order, so the same syntax tree.
    let again = tokens_of(&formatted, rule).map_err(|_| FormatError::Changed(0))?;
    if again.len() != tokens.len() {
        return Err(FormatError::Changed(source.len()));
    }
    for (a, b) in tokens.iter().zip(&again) {
        if a.rule != b.rule || source[a.start..a.end] != formatted[b.start..b.end] {
            return Err(FormatError::Changed(a.start));
        }
    }
    if comments(source) != comments(&formatted) {
        return Err(FormatError::Changed(0));
    }
    Ok(formatted)
}

/// One token: a leaf of the parse tree.
#[derive(Debug, Clone)]
struct Tok {
    start: usize,
    end: usize,
    rule: Rule,
    /// The rule of the pair holding it (`call` for a call's `(`).
    parent: Rule,
    /// It begins a statement: a child of a braced block, or a top-level block.
    stmt: bool,
}

/// Parses `source` as a machine file, or else as a parameter file, and returns its tokens.
fn tokenize(source: &str) -> Result<(Rule, Vec<Tok>), FormatError> {
    // The compiler's own parse first: its checks (nesting depth, operand count) keep the
    // recursion below bounded, and its diagnostics are the ones a user knows.
    let rule = match crate::syntax::parse_file_all(source) {
        Ok(_) => Rule::file,
        Err(diagnostics) => match crate::syntax::parse_params(source) {
            Ok(_) => Rule::params_file,
            Err(_) => return Err(FormatError::Syntax(diagnostics)),
        },
    };
    let tokens = tokens_of(source, rule).map_err(|_| FormatError::Changed(0))?;
    Ok((rule, tokens))
}

fn tokens_of(source: &str, rule: Rule) -> Result<Vec<Tok>, ()> {
    let pairs = KinParser::parse(rule, source).map_err(|_| ())?;
    let mut out = Vec::new();
    for pair in pairs {
        leaves(pair, rule, &mut out, source);
    }
    // Text between two leaves that is not whitespace or comments belongs to a rule's literal
    // (a `^` inside a unit): the two leaves are one token.
    let mut merged: Vec<Tok> = Vec::with_capacity(out.len());
    for t in out {
        if let Some(last) = merged.last_mut() {
            if trivia(&source[last.end..t.start]).is_none() {
                last.end = t.end;
                continue;
            }
        }
        merged.push(t);
    }
    Ok(merged)
}

/// Collects the leaves of `pair` in source order. Children of a block (after its `{`) and of a
/// file are statements: their first token is marked.
fn leaves(pair: Pair<Rule>, parent: Rule, out: &mut Vec<Tok>, source: &str) {
    let rule = pair.as_rule();
    let span = pair.as_span();
    let mut inner = pair.into_inner().peekable();
    if inner.peek().is_none() || rule == Rule::unit {
        let text = &source[span.start()..span.end()];
        let end = span.start() + text.trim_end().len();
        // Optional-only rules that matched nothing span whitespace and comments only.
        if end > span.start() && trivia(&source[span.start()..end]).is_none() {
            out.push(Tok {
                start: span.start(),
                end,
                rule,
                parent,
                stmt: false,
            });
        }
        return;
    }
    let top = matches!(rule, Rule::file | Rule::params_file);
    let mut in_block = false;
    for child in inner {
        let child_rule = child.as_rule();
        let first = out.len();
        let is_stmt =
            top || (in_block && !matches!(child_rule, Rule::rbrace | Rule::comma | Rule::EOI));
        if child_rule == Rule::lbrace {
            in_block = true;
        }
        leaves(child, rule, out, source);
        if is_stmt {
            if let Some(t) = out.get_mut(first) {
                t.stmt = true;
            }
        }
    }
}

/// What lies between two tokens.
#[derive(Debug, PartialEq)]
enum Trivia<'a> {
    Newline,
    /// A comment, `//` to the end of the line or `/* … */`.
    Comment(&'a str),
}

/// The newlines and comments of `gap`, or `None` if it holds anything else.
fn trivia(gap: &str) -> Option<Vec<Trivia<'_>>> {
    let mut out = Vec::new();
    let mut i = 0;
    let bytes = gap.as_bytes();
    while i < gap.len() {
        let rest = &gap[i..];
        if rest.starts_with("//") {
            let len = rest.find('\n').unwrap_or(rest.len());
            out.push(Trivia::Comment(rest[..len].trim_end()));
            i += len;
        } else if let Some(body) = rest.strip_prefix("/*") {
            let len = body.find("*/")? + 4;
            out.push(Trivia::Comment(&rest[..len]));
            i += len;
        } else if bytes[i] == b'\n' {
            out.push(Trivia::Newline);
            i += 1;
        } else {
            let c = rest.chars().next()?;
            if !matches!(c, ' ' | '\t' | '\r' | '\u{feff}') {
                return None;
            }
            i += c.len_utf8();
        }
    }
    Some(out)
}

/// Every comment of a parsed source, in order, without trailing whitespace on its lines.
fn comments(source: &str) -> Vec<String> {
    let Ok((_, tokens)) = tokenize(source) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut from = 0;
    for end in tokens
        .iter()
        .map(|t| (t.start, t.end))
        .chain([(source.len(), source.len())])
    {
        for t in trivia(&source[from..end.0]).unwrap_or_default() {
            if let Trivia::Comment(c) = t {
                out.push(trim_lines(c));
            }
        }
        from = end.1;
    }
    out
}

fn trim_lines(text: &str) -> String {
    text.lines()
        .map(str::trim_end)
        .collect::<Vec<_>>()
        .join("\n")
}

/// The column (in characters) of byte `at` in `source`, and the indentation of its line.
fn column(source: &str, at: usize) -> (usize, usize) {
    let line_start = source[..at].rfind('\n').map_or(0, |i| i + 1);
    let line = &source[line_start..at];
    let indent = line
        .chars()
        .take_while(|c| matches!(c, ' ' | '\t' | '\u{feff}'))
        .count();
    (line.chars().count(), indent)
}

/// The output being built, with what the indentation rules need to know.
struct Out {
    text: String,
    depth: usize,
    /// Open `(` and `[` of the current statement: the column after each when what follows it
    /// on its line is lined up there, `None` when a line break follows it (block indent).
    brackets: Vec<Option<usize>>,
    /// The last token written was an opening bracket.
    after_open: bool,
    /// Column of the current statement's first token and of its `=` / `+=`.
    stmt_col: usize,
    assign_col: Option<usize>,
    /// The last thing written was a `{` token (no blank line may follow it).
    after_lbrace: bool,
    /// The last thing written was a comment (a block comment is followed by a space).
    after_comment: bool,
}

impl Out {
    fn col(&self) -> usize {
        let start = self.text.rfind('\n').map_or(0, |i| i + 1);
        self.text[start..].chars().count()
    }

    fn line_indent(&self) -> usize {
        let start = self.text.rfind('\n').map_or(0, |i| i + 1);
        self.text[start..].chars().take_while(|c| *c == ' ').count()
    }

    fn trim_line_end(&mut self) {
        let kept = self.text.trim_end_matches([' ', '\t']).len();
        self.text.truncate(kept);
    }

    /// Ends the current line (with one blank line if `blank`) and indents the next.
    fn new_line(&mut self, blank: bool, indent: usize) {
        if !self.text.is_empty() {
            self.trim_line_end();
            self.text.push('\n');
            if blank && !self.after_lbrace {
                self.text.push('\n');
            }
        }
        self.text.extend(std::iter::repeat_n(' ', indent));
    }

    /// Where `tok` goes when it starts a line.
    fn indent_for(&self, tok: &Tok) -> usize {
        match tok.rule {
            Rule::rbrace => self.depth.saturating_sub(1) * INDENT,
            _ if tok.stmt => self.depth * INDENT,
            Rule::add_op | Rule::mul_op
                if self.brackets.is_empty() && self.assign_col.is_some() =>
            {
                self.assign_col.unwrap_or(self.stmt_col + INDENT)
            }
            // A closing bracket under its opening one, or back at the opening line's level.
            Rule::rparen | Rule::rbrack => match self.brackets.last() {
                Some(Some(col)) => col.saturating_sub(1),
                _ => self.stmt_col + INDENT * self.brackets.len().saturating_sub(1),
            },
            _ => match self.brackets.last() {
                Some(Some(col)) => *col,
                _ => self.stmt_col + INDENT * self.brackets.len().max(1),
            },
        }
    }
}

/// Whether a space separates `a` and `b` on one line; `had_space` is whether one did.
fn space(a: &Tok, b: &Tok, b_text: &str, had_space: bool) -> bool {
    use Rule::*;
    match (a.rule, b.rule) {
        (_, comma | rparen | rbrack | dot) | (dot | lparen | lbrack, _) => false,
        (comma, _) => true,
        // `- 5` must not become the number `-5`, which is another token.
        (neg, _) => {
            had_space && b_text.starts_with(|c: char| c.is_ascii_digit() || "+-.".contains(c))
        }
        (_, lparen | lbrack) if a.parent == b.parent && matches!(b.parent, call | param_ref) => {
            false
        }
        (dotdot, _) | (_, dotdot) => a.parent != int_range,
        (assign | add_op | mul_op | colon | lbrace | rbrace, _)
        | (_, assign | add_op | mul_op | colon | lbrace | rbrace) => true,
        _ => had_space,
    }
}

fn render(source: &str, tokens: &[Tok]) -> String {
    let mut out = Out {
        text: String::with_capacity(source.len() + source.len() / 8),
        depth: 0,
        brackets: Vec::new(),
        after_open: false,
        stmt_col: 0,
        assign_col: None,
        after_lbrace: false,
        after_comment: false,
    };
    let mut from = 0;
    let mut prev: Option<&Tok> = None;
    for tok in tokens {
        gap(&mut out, source, from, tok.start, Some(tok), prev);
        let text = &source[tok.start..tok.end];
        if tok.stmt {
            out.stmt_col = out.line_indent();
            out.brackets.clear();
            out.assign_col = None;
        }
        match tok.rule {
            Rule::assign if out.assign_col.is_none() && out.brackets.is_empty() => {
                out.assign_col = Some(out.col());
            }
            Rule::lparen | Rule::lbrack => {
                let after = out.col() + text.chars().count();
                out.brackets.push(Some(after));
            }
            Rule::rparen | Rule::rbrack => {
                out.brackets.pop();
            }
            Rule::lbrace => out.depth += 1,
            Rule::rbrace => out.depth = out.depth.saturating_sub(1),
            _ => {}
        }
        out.text.push_str(text);
        out.after_lbrace = tok.rule == Rule::lbrace;
        out.after_open = matches!(tok.rule, Rule::lparen | Rule::lbrack);
        out.after_comment = false;
        from = tok.end;
        prev = Some(tok);
    }
    gap(&mut out, source, from, source.len(), None, prev);
    out.trim_line_end();
    let kept = out.text.trim_end().len();
    out.text.truncate(kept);
    if !out.text.is_empty() {
        out.text.push('\n');
    }
    out.text
}

/// Writes the comments and line breaks between `prev` and `next` (source bytes `from..to`),
/// then the line break or space `next` needs.
fn gap(
    out: &mut Out,
    source: &str,
    from: usize,
    to: usize,
    next: Option<&Tok>,
    prev: Option<&Tok>,
) {
    let items = trivia(&source[from..to]).unwrap_or_default();
    if out.after_open && items.contains(&Trivia::Newline) {
        // Nothing follows the bracket on its line: what is inside takes the block indent.
        if let Some(top) = out.brackets.last_mut() {
            *top = None;
        }
    }
    let mut newlines = 0usize;
    let blank_before_next = next.is_some_and(|t| t.rule != Rule::rbrace);
    for item in items {
        match item {
            Trivia::Newline => newlines += 1,
            Trivia::Comment(c) => {
                let at = c.as_ptr() as usize - source.as_ptr() as usize;
                if newlines == 0 && !out.text.is_empty() {
                    if c.starts_with("//") && !out.after_comment {
                        // A comment after code keeps its column, moved with the indentation.
                        let (orig_col, orig_indent) = column(source, at);
                        let wanted = (orig_col + out.line_indent()).saturating_sub(orig_indent);
                        let col = out.col();
                        let pad = wanted.max(col + 1) - col;
                        out.text.extend(std::iter::repeat_n(' ', pad));
                    } else {
                        out.text.push(' ');
                    }
                } else {
                    let (indent, usual) = match next {
                        Some(t) if t.rule == Rule::rbrace => {
                            (out.depth * INDENT, column(source, t.start).1 + INDENT)
                        }
                        Some(t) => (out.indent_for(t), column(source, t.start).1),
                        None => (0, 0),
                    };
                    // A comment indented deeper than the line after it annotates the line
                    // before (`J1 moving …` / `    // joint J1`): it stays one level deeper.
                    let deeper = newlines == 1 && column(source, at).0 > usual;
                    out.new_line(newlines >= 2, indent + if deeper { INDENT } else { 0 });
                }
                out.text.push_str(&trim_lines(c));
                out.after_lbrace = false;
                out.after_comment = true;
                newlines = 0;
            }
        }
    }
    let Some(next) = next else { return };
    if newlines > 0 || out.text.is_empty() {
        let indent = out.indent_for(next);
        out.new_line(newlines >= 2 && blank_before_next, indent);
    } else if out.after_comment {
        out.text.push(' ');
    } else if let Some(prev) = prev {
        let had_space = from < to;
        // `phase -2 mm`: an operator glued to what follows but not to what precedes reads as a
        // sign; it is left as written (spacing it out would change how it reads, not what).
        let sign_like =
            prev.rule == Rule::add_op && !had_space && source[..prev.start].ends_with([' ', '\t']);
        if next.stmt && !matches!(prev.rule, Rule::lbrace | Rule::comma) {
            // Statements sharing a line (`{ Y fixed  X moving }`) stand two spaces apart.
            out.text.push_str("  ");
        } else if !sign_like && space(prev, next, &source[next.start..next.end], had_space) {
            out.text.push(' ');
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fmt(s: &str) -> String {
        match format_source(s) {
            Ok(f) => f,
            Err(e) => panic!("{e}: {e:?}"),
        }
    }

    #[test]
    fn normalises_spacing_and_indentation() {
        let src = "machine m{\n  task measure\naxis X prismatic along x range 0mm..10 mm\n\n\n\n   errors {\nX.tx=spline( X,knots 3 )+const\n   X.ty  =  fourier(X, harmonics 1..2, wavelength fit 20 mm)\n}\n}";
        let want = "machine m {\n    task measure\n    axis X prismatic along x range 0mm .. 10 mm\n\n    errors {\n        X.tx = spline(X, knots 3) + const\n        X.ty = fourier(X, harmonics 1..2, wavelength fit 20 mm)\n    }\n}\n";
        assert_eq!(fmt(src), want);
        assert_eq!(fmt(want), want);
    }

    #[test]
    fn keeps_comments_and_aligns_continuations() {
        let src = "// head\nmachine m { // trailing\n/* block */ axis X prismatic along x\n  errors {\n    // own line\n    X.tx = spline(X, knots 3)   // a\n  + const  /* b */ // c\n\n    // before close\n  }\n}\n";
        let want = "// head\nmachine m { // trailing\n    /* block */ axis X prismatic along x\n    errors {\n        // own line\n        X.tx = spline(X, knots 3)   // a\n             + const /* b */ // c\n\n        // before close\n    }\n}\n";
        let got = fmt(src);
        assert_eq!(got, want);
        assert_eq!(fmt(&got), got);
    }

    #[test]
    fn a_deeper_comment_annotates_the_line_before() {
        let src = "machine m {\n tool chain {\n  X moving\n      // the X carriage\n  tool t\n      // the tool\n }\n}\n";
        let want = "machine m {\n    tool chain {\n        X moving\n            // the X carriage\n        tool t\n            // the tool\n    }\n}\n";
        assert_eq!(fmt(src), want);
        assert_eq!(fmt(want), want);
    }

    #[test]
    fn lines_inside_brackets_line_up() {
        let src = "machine m {\n errors {\n  X.tx = spline(X, knots at (100,\n 250) mm)\n }\n}\nparams {\n X.tx = [\n 1,\n 2\n ] um\n}\n";
        let want = "machine m {\n    errors {\n        X.tx = spline(X, knots at (100,\n                                   250) mm)\n    }\n}\nparams {\n    X.tx = [\n        1,\n        2\n    ] um\n}\n";
        assert_eq!(fmt(src), want);
        assert_eq!(fmt(want), want);
        let signed = "machine m { errors { X.tx = periodic(X, wavelength 10 mm, phase -2 mm) } }\n";
        assert_eq!(fmt(signed), signed);
        let shared = "machine m { workpiece chain { Y fixed X moving  workpiece } }\n";
        let want = "machine m { workpiece chain { Y fixed  X moving  workpiece } }\n";
        assert_eq!(fmt(shared), want);
    }

    #[test]
    fn units_negative_numbers_and_params_stay_tokens() {
        let src = "machine m {\n axis Z prismatic along -z range -450 mm .. 0 mm\n errors { Z.tz = 11.5 um/m/K * Z - -2 um + - 3 um }\n}\nparams {\n Z.tz[0] = 1 um\n Z.tz = [1.2, -0.5] um\n}\n";
        let got = fmt(src);
        assert!(got.contains("11.5 um/m/K * Z - -2 um + - 3 um"), "{got}");
        assert!(got.contains("    Z.tz[0] = 1 um\n"), "{got}");
        assert_eq!(fmt(&got), got);
        let p = "params {\nX.tx = [1, 2] um\n}";
        assert_eq!(fmt(p), "params {\n    X.tx = [1, 2] um\n}\n");
    }

    #[test]
    fn syntax_errors_are_reported_not_formatted() {
        match format_source("machine m { axis X prismatic alongg x }") {
            Err(FormatError::Syntax(d)) => assert_eq!(d[0].code, "E0001"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn examples_are_formatted_and_format_is_idempotent() {
        for src in [
            include_str!("../../examples/bridge_cmm.kin"),
            include_str!("../../examples/milling_5axis.kin"),
            include_str!("../../examples/robot_6axis.kin"),
            include_str!("../../examples/xy_table.kin"),
        ] {
            let once = fmt(src);
            assert_eq!(fmt(&once), once);
        }
    }
}
