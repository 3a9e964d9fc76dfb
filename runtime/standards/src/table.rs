//! The file skeleton the ISO test readers share (230-2 positioning runs, 230-3 thermal tests,
//! 230-4 circular tests): the bytes read with a bound, the text sorted into setup comments,
//! header and rows, the CSV dialect and cells of `kin_data::data::csv`, header cells with their
//! units, numbers, and the problems found, each at its line and column, at most
//! [`MAX_PROBLEMS`] of them. What a file's columns are, what their cells must hold and how a
//! problem is worded stay with each standard's module.

use std::fmt;
use std::path::{Path, PathBuf};

use kin_compiler::units::{Dim, Unit};
use kin_data::data::csv::{self, Cell, Dialect};
use thiserror::Error;

/// At most this many problems are listed per file.
const MAX_PROBLEMS: usize = 20;

/// One thing wrong with a run file; lines and columns are 1-based, columns in characters.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RunProblem {
    #[error("no header row: the file holds only comments and blank lines")]
    NoHeader,
    #[error("line {line}, column {column}: {what}")]
    At {
        line: usize,
        column: usize,
        what: String,
    },
    #[error("line {line}: {what}")]
    Line { line: usize, what: String },
    #[error("{0}")]
    File(String),
}

/// A standard test's file that could not be read, or that holds problems (the error of every
/// ISO reader and evaluation; each module names it after its standard).
#[derive(Debug, Error)]
pub enum TestFileError {
    #[error("cannot read `{}`: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}", Listing { path, problems })]
    Invalid {
        path: PathBuf,
        problems: Vec<RunProblem>,
    },
}

impl TestFileError {
    pub(crate) fn invalid(path: &Path, problems: Vec<RunProblem>) -> Self {
        TestFileError::Invalid {
            path: path.to_path_buf(),
            problems,
        }
    }
}

struct Listing<'a> {
    path: &'a Path,
    problems: &'a [RunProblem],
}

impl fmt::Display for Listing<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.problems.len();
        let s = if n == 1 { "" } else { "s" };
        write!(f, "`{}`: {n} problem{s}", self.path.display())?;
        for p in self.problems {
            write!(f, "\n  {p}")?;
        }
        Ok(())
    }
}

/// A test file from disk, handed to `read` (the standard's reader from memory): whole when it
/// is a regular file, at most `MAX_STREAM_BYTES` otherwise (a pipe or device could be endless).
pub(crate) fn read_file<T>(
    path: &Path,
    read: impl FnOnce(&[u8], &Path) -> Result<T, TestFileError>,
) -> Result<T, TestFileError> {
    use kin_data::bounded_read::{read_unless_regular, BoundedReadError, MAX_STREAM_BYTES};
    let bytes = read_unless_regular(path, MAX_STREAM_BYTES).map_err(|e| TestFileError::Io {
        path: path.to_path_buf(),
        source: match e {
            BoundedReadError::Io(source) => source,
            BoundedReadError::TooLarge { limit } => std::io::Error::other(format!(
                "not a regular file and longer than {} MiB",
                limit >> 20
            )),
        },
    })?;
    read(&bytes, path)
}

/// Adds a problem unless [`MAX_PROBLEMS`] are listed already.
pub(crate) fn push(problems: &mut Vec<RunProblem>, p: RunProblem) {
    if problems.len() < MAX_PROBLEMS {
        problems.push(p);
    }
}

/// `Ok(value)` when nothing was found wrong, else the problems as the file's error.
pub(crate) fn done<T>(
    path: &Path,
    problems: Vec<RunProblem>,
    value: T,
) -> Result<T, TestFileError> {
    if problems.is_empty() {
        Ok(value)
    } else {
        Err(TestFileError::invalid(path, problems))
    }
}

/// A test file's lines by role, in its CSV dialect (detected from the header), with the
/// buffers its cells are split into.
pub(crate) struct Table<'a> {
    /// `#` comments before the header, each with its 1-based line number: where a test states
    /// its setup (`# radius: 150 mm`).
    pub setup: Vec<(usize, &'a str)>,
    /// The first line that is neither blank nor a comment.
    header: (usize, &'a str),
    /// Every later line that is neither blank nor a comment.
    rows: Vec<(usize, &'a str)>,
    pub dialect: Dialect,
    buf: String,
    cells: Vec<Cell>,
}

impl<'a> Table<'a> {
    /// Sorts a test file's lines into setup comments, header and rows (CRLF or LF, a leading
    /// byte-order mark dropped, blank lines and comments after the header skipped). Every ISO
    /// test file kin reads shares this layout, so they agree on what a comment or a blank line
    /// is. The problem is the line of the first byte that is not UTF-8, or that there is no
    /// header.
    pub fn new(bytes: &'a [u8]) -> Result<Self, RunProblem> {
        let text = std::str::from_utf8(bytes).map_err(|e| {
            let valid = bytes.get(..e.valid_up_to()).unwrap_or_default();
            RunProblem::Line {
                line: 1 + valid.iter().filter(|&&b| b == b'\n').count(),
                what: "not valid UTF-8".into(),
            }
        })?;
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut setup = Vec::new();
        let mut header = None;
        let mut rows = Vec::new();
        for (i, l) in text.split('\n').enumerate() {
            let l = l.strip_suffix('\r').unwrap_or(l);
            let t = l.trim_start();
            if t.is_empty() {
                continue;
            }
            if t.starts_with('#') {
                if header.is_none() {
                    setup.push((i + 1, t));
                }
                continue;
            }
            if header.is_none() {
                header = Some((i + 1, l));
            } else {
                rows.push((i + 1, l));
            }
        }
        let header = header.ok_or(RunProblem::NoHeader)?;
        Ok(Table {
            setup,
            header,
            dialect: Dialect::detect(header.1),
            rows,
            buf: String::new(),
            cells: Vec::new(),
        })
    }

    /// The header's columns. Each cell is `NAME` or `NAME[UNIT]`; `classify` gives a well-formed
    /// one its role, seeing the columns before it: `Ok(None)` when it could not (having said why
    /// in `problems`), `Err` to reject the cell. A rejected or malformed cell is a problem here
    /// and a column without a name or role.
    pub fn header<R>(
        &mut self,
        problems: &mut Vec<RunProblem>,
        mut classify: impl FnMut(
            &HeaderCell<'_>,
            &[Column<R>],
            &mut Vec<RunProblem>,
        ) -> Result<Option<R>, RunProblem>,
    ) -> Vec<Column<R>> {
        let (line, header) = self.header;
        if let Err(p) = split_line(header, line, self.dialect, &mut self.buf, &mut self.cells) {
            push(problems, p);
        }
        let mut columns = Vec::with_capacity(self.cells.len());
        for c in &self.cells {
            let column = column_of(header, c.origin);
            let text = self.buf.get(c.start..c.end).unwrap_or("").trim();
            let classified = header_cell(text)
                .map_err(|what| RunProblem::At { line, column, what })
                .and_then(|(name, unit)| {
                    let cell = HeaderCell {
                        text,
                        name,
                        unit,
                        line,
                        column,
                    };
                    Ok((name, classify(&cell, &columns, problems)?))
                });
            let (name, role) = classified.unwrap_or_else(|p| {
                push(problems, p);
                ("", None)
            });
            columns.push(Column {
                name: name.to_string(),
                role,
            });
        }
        columns
    }

    /// Hands every row to `each`, split into one cell per column; a row that cannot be split, or
    /// whose cells do not match the header's columns (`mismatch(cells, columns)` says so), is a
    /// problem instead.
    pub fn rows<R>(
        &mut self,
        columns: &[Column<R>],
        problems: &mut Vec<RunProblem>,
        mismatch: impl Fn(usize, usize) -> String,
        mut each: impl FnMut(&Row<'_, R>, &mut Vec<RunProblem>),
    ) {
        for &(line, text) in &self.rows {
            if let Err(p) = split_line(text, line, self.dialect, &mut self.buf, &mut self.cells) {
                push(problems, p);
                continue;
            }
            if self.cells.len() != columns.len() {
                push(
                    problems,
                    RunProblem::Line {
                        line,
                        what: mismatch(self.cells.len(), columns.len()),
                    },
                );
                continue;
            }
            let row = Row {
                line,
                text,
                buf: &self.buf,
                cells: &self.cells,
                columns,
            };
            each(&row, problems);
        }
    }

    /// One record per row, the 230-2 and 230-4 files' samples: `new(line)` filled by `read`
    /// from every cell with a role. `read` says what it expected of a cell it cannot take (a
    /// problem `VALUE: expected WHAT` at the cell, and the row is left out). No records and no
    /// other problem is itself a problem. (The 230-3 reader, column by column through
    /// [`Table::rows`], words a mismatched row and an empty file its own way.)
    pub fn records<R, S>(
        &mut self,
        columns: &[Column<R>],
        problems: &mut Vec<RunProblem>,
        new: impl Fn(usize) -> S,
        mut read: impl FnMut(&DataCell<'_, R>, &mut S) -> Result<(), String>,
    ) -> Vec<S> {
        let mut records = Vec::new();
        let mismatch =
            |cells, columns| format!("{cells} cells, but the header has {columns} columns");
        self.rows(columns, problems, mismatch, |row, problems| {
            let mut record = new(row.line);
            let mut ok = true;
            for c in row.cells() {
                if let Err(expected) = read(&c, &mut record) {
                    ok = false;
                    push(problems, c.expected(&expected));
                }
            }
            if ok {
                records.push(record);
            }
        });
        if problems.is_empty() && records.is_empty() {
            push(
                problems,
                RunProblem::File("no data rows after the header".into()),
            );
        }
        records
    }
}

/// A column of the header: its name (empty when the cell was malformed or rejected) and its
/// role.
pub(crate) struct Column<R> {
    pub name: String,
    pub role: Option<R>,
}

/// A well-formed header cell, at its line and column.
pub(crate) struct HeaderCell<'c> {
    /// The whole cell, trimmed.
    pub text: &'c str,
    pub name: &'c str,
    pub unit: Option<&'c str>,
    line: usize,
    column: usize,
}

impl HeaderCell<'_> {
    /// A problem at this cell.
    pub fn at(&self, what: String) -> RunProblem {
        RunProblem::At {
            line: self.line,
            column: self.column,
            what,
        }
    }

    /// `column NAME: what`, at this cell.
    pub(crate) fn column_problem(&self, what: impl fmt::Display) -> RunProblem {
        self.at(format!("column `{}`: {what}", self.name))
    }

    /// `column NAME takes no unit`, at this cell.
    pub(crate) fn takes_no_unit(&self) -> RunProblem {
        self.at(format!("column `{}` takes no unit", self.name))
    }

    /// `unknown column NAME; has` (`has` says which columns a file of this test has).
    pub fn unknown(&self, has: &str) -> RunProblem {
        self.at(format!("unknown column `{}`; {has}", self.name))
    }

    pub fn duplicate(&self) -> RunProblem {
        self.at(format!("duplicate column `{}`", self.name))
    }

    /// The role `known` gives this cell's name, or the problem: the name is unknown (`has` says
    /// which columns there are), or an earlier column has that role.
    pub fn known<R: Copy + PartialEq>(
        &self,
        known: &[(&str, R)],
        columns: &[Column<R>],
        has: &str,
    ) -> Result<R, RunProblem> {
        let Some(&(_, role)) = known.iter().find(|(n, _)| *n == self.name) else {
            return Err(self.unknown(has));
        };
        if columns.iter().any(|c| c.role == Some(role)) {
            return Err(self.duplicate());
        }
        Ok(role)
    }
}

/// `missing column(s): …` when the header lacks any `required` role of `known`.
pub(crate) fn missing<R: Copy + PartialEq>(
    known: &[(&str, R)],
    columns: &[Column<R>],
    required: impl Fn(R) -> bool,
) -> Option<RunProblem> {
    let names: Vec<&str> = known
        .iter()
        .filter(|(_, r)| required(*r) && !columns.iter().any(|c| c.role == Some(*r)))
        .map(|(n, _)| *n)
        .collect();
    (!names.is_empty()).then(|| {
        RunProblem::File(format!(
            "missing column{}: {}",
            if names.len() == 1 { "" } else { "s" },
            names.join(", ")
        ))
    })
}

/// A data row, split into cells that match the header's columns.
pub(crate) struct Row<'r, R> {
    pub line: usize,
    text: &'r str,
    buf: &'r str,
    cells: &'r [Cell],
    columns: &'r [Column<R>],
}

impl<'r, R> Row<'r, R> {
    /// The cells of the columns that have a role, in order.
    pub fn cells(&self) -> impl Iterator<Item = DataCell<'r, R>> + 'r {
        let (line, text, buf) = (self.line, self.text, self.buf);
        self.cells
            .iter()
            .zip(self.columns)
            .enumerate()
            .filter_map(move |(index, (c, column))| {
                Some(DataCell {
                    index,
                    role: column.role.as_ref()?,
                    name: &column.name,
                    text: buf.get(c.start..c.end).unwrap_or("").trim(),
                    line,
                    row: text,
                    origin: c.origin,
                })
            })
    }
}

/// One cell of a data row, in a column with a role.
pub(crate) struct DataCell<'r, R> {
    /// Which column, from 0.
    pub index: usize,
    pub role: &'r R,
    /// The column's name.
    pub name: &'r str,
    /// The cell, trimmed.
    pub text: &'r str,
    line: usize,
    row: &'r str,
    origin: usize,
}

impl<R> DataCell<'_, R> {
    /// A problem at this cell.
    pub fn at(&self, what: String) -> RunProblem {
        RunProblem::At {
            line: self.line,
            column: column_of(self.row, self.origin),
            what,
        }
    }

    /// `VALUE: expected WHAT` (or `empty cell: …`) at this cell.
    fn expected(&self, expected: &str) -> RunProblem {
        let shown = if self.text.is_empty() {
            "empty cell".to_string()
        } else {
            format!("`{}`", self.text)
        };
        self.at(format!("{shown}: expected {expected}"))
    }
}

/// Splits line `n` of a test file into `cells` (text in `buf`); a quoting problem is reported
/// at its line and column.
fn split_line(
    line: &str,
    n: usize,
    dialect: Dialect,
    buf: &mut String,
    cells: &mut Vec<Cell>,
) -> Result<(), RunProblem> {
    csv::split(line, dialect.delimiter, buf, cells).map_err(|e| {
        let (at, what) = match e {
            csv::SplitError::Unclosed(at) => (at, "a quote not closed on its line".into()),
            csv::SplitError::AfterQuote(at) => (
                at + 1,
                format!("text after a closing quote; expected {}", dialect.name()),
            ),
        };
        RunProblem::At {
            line: n,
            column: column_of(line, at),
            what,
        }
    })
}

/// A header cell: `NAME` or `NAME[UNIT]`.
fn header_cell(cell: &str) -> Result<(&str, Option<&str>), String> {
    match cell.split_once('[') {
        Some((n, rest)) => match rest.strip_suffix(']') {
            Some(u) => Ok((n.trim(), Some(u.trim()))),
            None => Err(format!("`{cell}`: expected NAME or NAME[UNIT]")),
        },
        None => Ok((cell, None)),
    }
}

fn column_of(line: &str, byte: usize) -> usize {
    1 + line.get(..byte).map_or(0, |s| s.chars().count())
}

/// A `# key: value` setup comment before the header, key and value trimmed; `separators` are
/// the characters a test allows between them.
pub(crate) fn setup_entry<'c>(comment: &'c str, separators: &[char]) -> Option<(&'c str, &'c str)> {
    let body = comment.trim_start().trim_start_matches('#');
    let (key, value) = body.split_once(separators)?;
    Some((key.trim(), value.trim()))
}

/// A length unit of a header: kin's units and the inch units of measurement files.
pub(crate) fn length_unit(text: &str) -> Result<Unit, String> {
    let unit = match kin_data::data::inch_unit(text) {
        Some(u) => u,
        None => Unit::parse(text).map_err(|e| e.to_string())?,
    };
    if unit.dim == Dim::LENGTH {
        Ok(unit)
    } else {
        Err(format!("`{text}` is not a length unit"))
    }
}

/// A finite number, with a decimal comma where the file's dialect has one.
pub(crate) fn number(cell: &str, dialect: Dialect) -> Option<f64> {
    match cell.parse::<f64>() {
        Ok(v) if v.is_finite() => Some(v),
        Ok(_) => None,
        Err(_) if dialect.decimal_comma => csv::decimal_comma(cell),
        Err(_) => None,
    }
}

/// A number in `unit`, `si(v)` in SI, within ±`limit` there (`within` words the bound:
/// `a value within ±10 km`), or what was expected. `si` is the caller's: `v * scale` for
/// lengths, `Unit::to_si` for angles (the two differ in the sign of a zero).
pub(crate) fn bounded(
    cell: &str,
    dialect: Dialect,
    unit: &Unit,
    si: impl Fn(f64) -> f64,
    limit: f64,
    within: &str,
) -> Result<f64, String> {
    match number(cell, dialect) {
        Some(v) if si(v).abs() <= limit => Ok(si(v)),
        Some(_) => Err(format!("{within}, in {}", unit.name)),
        None => Err(format!("a number in {}", unit.name)),
    }
}

/// A label cell (a cycle, a run): any text but none, else `what` was expected.
pub(crate) fn label(cell: &str, what: &str) -> Result<String, String> {
    if cell.is_empty() {
        Err(what.into())
    } else {
        Ok(cell.to_string())
    }
}

/// A direction given as a number: `+1` (`true`) or `-1`, also with a minus sign U+2212.
pub(crate) fn unit_sign(cell: &str, dialect: Dialect) -> Option<bool> {
    let v = number(&cell.replace('\u{2212}', "-"), dialect)?;
    if v == 1.0 {
        Some(true)
    } else if v == -1.0 {
        Some(false)
    } else {
        None
    }
}
