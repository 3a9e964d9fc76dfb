//! The CSV front end: which separator a file uses and how a line splits into cells when the
//! plain comma lexer cannot do it (quoted cells, `;` or tab separators).
//!
//! RFC 4180 quoting is honoured within a line: a cell may be enclosed in double quotes, a quote
//! inside it is written twice, and the separator inside quotes is text. A quoted cell must end
//! on its own line: measurement files have one record per line, and a line break inside a cell
//! would make every later line number wrong in messages.

pub use super::Cell;

/// How a file separates its cells, fixed from the header line (or by the caller).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dialect {
    pub delimiter: u8,
    /// Spreadsheets in many locales write `1,5` for 1.5 when the separator is not a comma.
    pub decimal_comma: bool,
}

impl Dialect {
    pub(crate) fn with_delimiter(delimiter: u8) -> Dialect {
        Dialect {
            delimiter,
            decimal_comma: delimiter != b',',
        }
    }

    /// The separator is the one of `,` `;` tab found most often outside quotes in the header;
    /// a header with none of them (a single column) is comma-separated.
    pub fn detect(header: &str) -> Dialect {
        let mut counts = [0usize; 3];
        let mut quoted = false;
        for b in header.bytes() {
            match b {
                b'"' => quoted = !quoted,
                b',' if !quoted => counts[0] += 1,
                b';' if !quoted => counts[1] += 1,
                b'\t' if !quoted => counts[2] += 1,
                _ => {}
            }
        }
        let mut best = (b',', counts[0]);
        for (delimiter, count) in [(b';', counts[1]), (b'\t', counts[2])] {
            if count > best.1 {
                best = (delimiter, count);
            }
        }
        Dialect::with_delimiter(best.0)
    }

    /// The separator as users type it, for messages.
    pub fn name(self) -> &'static str {
        match self.delimiter {
            b';' => "`;`",
            b'\t' => "a tab",
            _ => "`,`",
        }
    }
}

/// A line that cannot be split: the byte offset in the line and what is wrong there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SplitError {
    /// The quote opening a cell at this offset is not closed on the line.
    Unclosed(usize),
    /// Text follows the quote closing a cell at this offset instead of the separator.
    AfterQuote(usize),
}

fn is_blank(b: u8, delimiter: u8) -> bool {
    (b == b' ' || b == b'\t' || b == b'\r') && b != delimiter
}

/// Splits `line` into `cells` whose spans index into `buf` (cleared first): quotes removed,
/// doubled quotes undone, spaces around unquoted cells dropped. `Cell::origin` is the cell's
/// byte offset in `line`, for columns in messages.
pub fn split(
    line: &str,
    delimiter: u8,
    buf: &mut String,
    cells: &mut Vec<Cell>,
) -> Result<(), SplitError> {
    buf.clear();
    cells.clear();
    let bytes = line.as_bytes();
    let mut pos = 0;
    loop {
        while bytes.get(pos).is_some_and(|&b| is_blank(b, delimiter)) {
            pos += 1;
        }
        let origin = pos;
        let start = buf.len();
        let next = if bytes.get(pos) == Some(&b'"') {
            let mut p = pos + 1;
            loop {
                let rest = line.get(p..).unwrap_or("");
                let Some(q) = rest.find('"') else {
                    return Err(SplitError::Unclosed(origin));
                };
                buf.push_str(rest.get(..q).unwrap_or(""));
                p += q + 1;
                if bytes.get(p) == Some(&b'"') {
                    buf.push('"');
                    p += 1;
                } else {
                    break;
                }
            }
            let closing = p - 1;
            while bytes.get(p).is_some_and(|&b| is_blank(b, delimiter)) {
                p += 1;
            }
            match bytes.get(p) {
                None => None,
                Some(&b) if b == delimiter => Some(p + 1),
                Some(_) => return Err(SplitError::AfterQuote(closing)),
            }
        } else {
            let rest = bytes.get(pos..).unwrap_or_default();
            let end = rest.iter().position(|&b| b == delimiter).map(|i| pos + i);
            let text = line.get(pos..end.unwrap_or(line.len())).unwrap_or("");
            buf.push_str(text.trim_end_matches([' ', '\t', '\r']));
            end.map(|e| e + 1)
        };
        cells.push(Cell {
            start,
            end: buf.len(),
            number: false,
            origin,
        });
        match next {
            Some(p) => pos = p,
            None => return Ok(()),
        }
    }
}

/// A number with a decimal comma (`-1,25e-3`) read as with a point; `None` for anything else,
/// so a thousands separator (`1.234,5`) or two commas are not guessed at.
pub fn decimal_comma(text: &str) -> Option<f64> {
    // Rewritten on the stack: spreadsheet files have millions of such cells.
    const LONGEST: usize = 64;
    let bytes = text.as_bytes();
    if bytes.len() > LONGEST || bytes.contains(&b'.') {
        return None;
    }
    let mut commas = bytes.iter().filter(|&&b| b == b',');
    if commas.next().is_none() || commas.next().is_some() {
        return None;
    }
    let mut copy = [0u8; LONGEST];
    let copy = copy.get_mut(..bytes.len())?;
    for (c, &b) in copy.iter_mut().zip(bytes) {
        *c = if b == b',' { b'.' } else { b };
    }
    std::str::from_utf8(copy)
        .ok()?
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells(line: &str, delimiter: u8) -> Result<Vec<(String, usize)>, SplitError> {
        let mut buf = String::new();
        let mut cells = Vec::new();
        split(line, delimiter, &mut buf, &mut cells)?;
        Ok(cells
            .iter()
            .map(|c| (buf[c.start..c.end].to_string(), c.origin))
            .collect())
    }

    fn texts(line: &str, delimiter: u8) -> Vec<String> {
        cells(line, delimiter)
            .unwrap_or_else(|e| panic!("{line:?}: {e:?}"))
            .into_iter()
            .map(|(t, _)| t)
            .collect()
    }

    #[test]
    fn rfc_4180_quoting() {
        assert_eq!(
            texts(r#""X[mm]","Y [mm]",ex"#, b','),
            ["X[mm]", "Y [mm]", "ex"]
        );
        assert_eq!(
            texts(r#"a,"b,c","say ""hi""""#, b','),
            ["a", "b,c", r#"say "hi""#]
        );
        assert_eq!(texts(r#""","",x"#, b','), ["", "", "x"]);
        assert_eq!(texts("a,,", b','), ["a", "", ""]);
        assert_eq!(texts(" \"q\" ; 2 ", b';'), ["q", "2"]);
        assert_eq!(texts("1\t\t2,5", b'\t'), ["1", "", "2,5"]);
        assert_eq!(texts("", b';'), [""]);
    }

    #[test]
    fn origins_are_byte_offsets_in_the_line() {
        let c = cells(r#"ab; "cd" ;e"#, b';').unwrap();
        assert_eq!(c.iter().map(|(_, o)| *o).collect::<Vec<_>>(), [0, 4, 10]);
    }

    #[test]
    fn bad_quotes_are_located() {
        assert_eq!(cells(r#"a,"bc,d"#, b','), Err(SplitError::Unclosed(2)));
        assert_eq!(cells(r#"a,"bc"x,d"#, b','), Err(SplitError::AfterQuote(5)));
    }

    #[test]
    fn detection_counts_separators_outside_quotes() {
        assert_eq!(Dialect::detect("X;Y;Z;ex").delimiter, b';');
        assert_eq!(Dialect::detect("X\tY\tex").delimiter, b'\t');
        assert_eq!(Dialect::detect(r#""a;b;c",Y,ex"#).delimiter, b',');
        assert_eq!(Dialect::detect("X").delimiter, b',');
        assert!(Dialect::detect("X;ex").decimal_comma);
        assert!(!Dialect::detect("X,ex").decimal_comma);
    }

    #[test]
    fn decimal_commas() {
        assert_eq!(decimal_comma("-1,25e-3"), Some(-1.25e-3));
        assert_eq!(decimal_comma("12,5"), Some(12.5));
        assert_eq!(decimal_comma("1.234,5"), None);
        assert_eq!(decimal_comma("1,2,3"), None);
        assert_eq!(decimal_comma("a,b"), None);
        assert_eq!(decimal_comma("inf,0"), None);
        assert_eq!(decimal_comma(&format!("1,{}", "0".repeat(70))), None);
    }
}
