//! More than the first syntax error.
//!
//! pest stops at the first error. To report the next ones too, the statement holding the error
//! is blanked out — every character replaced by a space, newlines kept, so every later offset,
//! line and column stays what the user sees — and the text is parsed again, up to
//! [`MAX_SYNTAX_ERRORS`] times. A statement is the error's line, the lines after it that
//! continue an expression (they start with an operator or a closing bracket), and, when those
//! lines open a block, the block up to its closing brace.
//!
//! Blanking can itself create an error (an emptied block, a dangling operator). Such an error
//! sits right after the blanked text, so an error with nothing but blanks, spaces and comments
//! between it and a blanked statement ends the search instead of being reported, as does an
//! error that is no further into the file than the one before: a user would rather miss a
//! second error than chase one kin made up.

use pest::Parser as _;

use super::parse::{syntax_error, KinParser, Rule};
use crate::diagnostic::Diagnostic;

/// No more syntax errors are reported for one file than this.
pub(crate) const MAX_SYNTAX_ERRORS: usize = 10;

/// Every syntax error of `source` that can be found, `first` (the parser's own) first.
pub(super) fn syntax_errors(source: &str, first: Diagnostic) -> Vec<Diagnostic> {
    let mut text: Vec<u8> = source.as_bytes().to_vec();
    let mut found = vec![];
    let mut next = Some(first);
    // End offsets of the blanked statements: an error right after one is a cascade.
    let mut blanked_ends: Vec<usize> = vec![];
    while let Some(d) = next.take() {
        let at = d.primary_span().start;
        found.push(d);
        if found.len() >= MAX_SYNTAX_ERRORS {
            break;
        }
        let Some((start, end)) = statement(&text, at) else {
            break;
        };
        for b in text.get_mut(start..end).into_iter().flatten() {
            if *b != b'\n' {
                *b = b' ';
            }
        }
        blanked_ends.push(end);
        // Only ASCII bytes inside whole statements were replaced, by ASCII spaces, so the text
        // is still UTF-8; a failure here would be a bug, and ends the search quietly.
        let Ok(current) = std::str::from_utf8(&text) else {
            break;
        };
        let Err(e) = KinParser::parse(Rule::file, current) else {
            break;
        };
        let d = syntax_error(current, e);
        let pos = d.primary_span().start;
        let cascade = blanked_ends
            .iter()
            .any(|&end| end <= pos && only_blank(current.get(end..pos).unwrap_or("")));
        if pos <= at || cascade || pos >= current.trim_end().len() {
            break;
        }
        next = Some(d);
    }
    found
}

/// The byte range of the statement around offset `at`: see the module docs. `None` when there
/// is nothing to blank (an error at the end of the file).
fn statement(text: &[u8], at: usize) -> Option<(usize, usize)> {
    if at >= text.len() {
        return None;
    }
    let line_start = text
        .get(..at)?
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    let line_end = |from: usize| {
        text.get(from..)
            .and_then(|rest| rest.iter().position(|&b| b == b'\n'))
            .map_or(text.len(), |i| from + i)
    };
    let mut end = line_end(at);
    // Lines that continue the expression belong to the statement.
    while end < text.len() {
        let next_start = end + 1;
        let next_end = line_end(next_start);
        let first = text
            .get(next_start..next_end)?
            .iter()
            .find(|b| !b.is_ascii_whitespace());
        match first {
            Some(b'+' | b'-' | b'*' | b'/' | b')' | b']' | b',') => end = next_end,
            _ => break,
        }
    }
    // A statement that opens a block takes the block with it; one that closes blocks it did
    // not open ends before the first such brace, so the blocks around it stay whole.
    let mut depth = 0usize;
    let mut i = line_start;
    while i < text.len() && (i < end || depth > 0) {
        match (text.get(i), text.get(i + 1)) {
            (Some(b'/'), Some(b'/')) => {
                i = line_end(i);
                continue;
            }
            (Some(b'/'), Some(b'*')) => {
                i = text
                    .get(i + 2..)
                    .and_then(|rest| rest.windows(2).position(|w| w == b"*/"))
                    .map_or(text.len(), |p| i + 2 + p + 2);
                end = end.max(i);
                continue;
            }
            (Some(b'{'), _) => depth += 1,
            (Some(b'}'), _) if depth == 0 => {
                end = i;
                break;
            }
            (Some(b'}'), _) => {
                depth -= 1;
                if depth == 0 {
                    end = end.max(i + 1);
                }
            }
            _ => {}
        }
        i += 1;
    }
    let end = if depth > 0 {
        text.len()
    } else {
        end.min(text.len())
    };
    (line_start < end).then_some((line_start, end))
}

/// Whether `s` holds only spaces, newlines and comments.
fn only_blank(s: &str) -> bool {
    let mut rest = s.trim_start();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("//") {
            rest = r.split_once('\n').map_or("", |(_, after)| after);
        } else if let Some(r) = rest.strip_prefix("/*") {
            rest = r.split_once("*/").map_or("", |(_, after)| after);
        } else {
            return false;
        }
        rest = rest.trim_start();
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::syntax::parse_file_all;

    const GOOD: &str = "machine m {
    task position
    axis X prismatic along x range 0 mm .. 500 mm
    axis Y prismatic along y range 0 mm .. 500 mm
    tool chain { X moving  Y moving  tool t at (0, 0, -100) mm }
    errors {
        X.tx = spline(X, knots 2)
             + const
        Y.ty = const
    }
}
";

    fn errors(src: &str) -> Vec<(usize, usize, String)> {
        match parse_file_all(src) {
            Ok(_) => vec![],
            Err(ds) => ds
                .iter()
                .map(|d| {
                    let at = d.primary_span().start;
                    let line = src[..at].matches('\n').count() + 1;
                    let col = at - src[..at].rfind('\n').map_or(0, |i| i + 1) + 1;
                    (line, col, d.message.clone())
                })
                .collect(),
        }
    }

    #[test]
    fn the_good_file_parses() {
        assert_eq!(errors(GOOD), vec![]);
    }

    #[test]
    fn two_bad_lines_give_two_errors_at_their_places() {
        let src = GOOD
            .replace("prismatic along x", "prismatic alongg x")
            .replace("Y.ty = const", "Y.ty = = const");
        let found = errors(&src);
        assert_eq!(found.len(), 2, "{found:?}");
        assert_eq!((found[0].0, found[0].1), (3, 22));
        assert_eq!((found[1].0, found[1].1), (9, 16));
    }

    #[test]
    fn a_bad_continuation_line_goes_with_its_statement() {
        let src = GOOD
            .replace("+ const", "+ const(1)")
            .replace("Y.ty = const", "Y.ty = const ** 2");
        let found = errors(&src);
        assert_eq!(found.len(), 2, "{found:?}");
        assert_eq!(found[0].0, 8);
        assert_eq!(found[1].0, 9);
    }

    #[test]
    fn a_bad_block_header_takes_its_block_and_makes_up_nothing() {
        let src = GOOD
            .replace("tool chain {", "tool chian {")
            .replace("Y.ty = const", "Y.ty = = const");
        let found = errors(&src);
        assert_eq!(found.len(), 2, "{found:?}");
        assert_eq!(found[0].0, 5);
        assert_eq!(found[1].0, 9);
    }

    #[test]
    fn a_missing_brace_is_one_error() {
        let src = GOOD.trim_end().trim_end_matches('}');
        assert_eq!(errors(src).len(), 1, "{:?}", errors(src));
    }

    #[test]
    fn the_count_is_bounded() {
        let mut src = String::from("machine m {\n");
        for _ in 0..40 {
            src.push_str("    axis X prismatic alongg x\n");
        }
        src.push_str("}\n");
        assert_eq!(errors(&src).len(), MAX_SYNTAX_ERRORS);
    }

    #[test]
    fn blank_means_spaces_and_comments() {
        assert!(only_blank("  \n // c\n /* d */ \n"));
        assert!(!only_blank("  x"));
        assert!(only_blank(""));
    }
}
