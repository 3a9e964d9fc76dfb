//! The reader. The header is small and read with plain string handling; data rows are the hot
//! path (millions of numeric cells): a logos lexer finds the cells and recognises a plain
//! number in one pass, and a large file's lines are read in pieces, one thread each. Anything
//! the fast path does not recognise falls back to a careful, slow path that produces the
//! diagnostic. Lines with quotes, and files separated by `;` or tabs, are split by the CSV
//! front end ([`csv`]) instead of the lexer; the cells then go through the same checks.

use std::collections::HashMap;
use std::path::Path;

use kin_compiler::ir::{JointKind, Machine};
use kin_compiler::units::{Dim, Unit, UnitError};
use logos::Logos;

pub mod csv;

use csv::{Dialect, SplitError};

use super::{
    Absolute, Groups, LengthData, Observations, PointData, Pose, Problem, ReadError, ReadOptions,
    Rows, MAX_PROBLEMS, MEASURED, MEASURED_ROTATION, OBSERVED, TOOL_OFFSET,
};

/// Reads a point or length file from disk. Any read failure or problem in the file is an error;
/// see [`read`].
pub fn read_file(
    path: &Path,
    machine: &Machine,
    options: &ReadOptions,
) -> Result<Observations, ReadError> {
    use crate::bounded_read::{read_unless_regular, BoundedReadError, MAX_STREAM_BYTES};
    let bytes = read_unless_regular(path, MAX_STREAM_BYTES).map_err(|e| match e {
        BoundedReadError::Io(source) => ReadError::Io {
            path: path.to_path_buf(),
            source,
        },
        BoundedReadError::TooLarge { limit } => ReadError::TooLarge {
            path: path.to_path_buf(),
            limit,
        },
    })?;
    read(&bytes, path, machine, options)
}

/// Reads a point or length file from memory; `path` only names the file in errors.
///
/// The data lines are read on [`ReadOptions::threads`] threads, each a piece of the text cut at
/// line ends, and put together in file order: rows, ids and problems are those of a reading
/// line by line, whatever the number of pieces (`read_in`).
pub fn read(
    bytes: &[u8],
    path: &Path,
    machine: &Machine,
    options: &ReadOptions,
) -> Result<Observations, ReadError> {
    let threads = options.threads.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get)
    });
    // A thread costs tens of microseconds to start; a piece this long takes milliseconds.
    let pieces = threads.min(bytes.len() / MIN_PIECE_BYTES).max(1);
    read_in(bytes, path, machine, options, pieces)
}

/// The shortest piece of text worth a thread of its own.
const MIN_PIECE_BYTES: usize = 256 << 10;

/// As [`read`], the data lines cut into `pieces` pieces (one thread each) whatever the size.
fn read_in(
    bytes: &[u8],
    path: &Path,
    machine: &Machine,
    options: &ReadOptions,
    pieces: usize,
) -> Result<Observations, ReadError> {
    let invalid = |problems: Vec<Problem>, omitted| ReadError::Invalid {
        path: path.to_path_buf(),
        problems,
        omitted,
    };
    let text = match std::str::from_utf8(bytes) {
        Ok(text) => text,
        Err(e) => return Err(invalid(vec![not_utf8(bytes, e.valid_up_to())], 0)),
    };
    // Spreadsheets often start a CSV export with a byte order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // The header is the first line that is not skipped; the data lines follow it.
    let mut rest = text;
    let mut number = 0usize;
    let header = loop {
        number += 1;
        let (line, after) = match rest.split_once('\n') {
            Some((line, after)) => (line, Some(after)),
            None => (rest, None),
        };
        let line = line.strip_suffix('\r').unwrap_or(line);
        if !skipped(line) {
            rest = after.unwrap_or("");
            break Some(line);
        }
        match after {
            Some(after) => rest = after,
            None => break None,
        }
    };
    let Some(header) = header else {
        return Err(invalid(vec![Problem::NoHeader], 0));
    };
    let dialect = dialect_of(options, header);
    let mut reader = Reader::new(machine, options, dialect, number, header);
    let pieces = split_pieces(rest, pieces);
    if let [only] = pieces.as_slice() {
        reader.lines_of(only, number + 1);
    } else {
        // Each piece's first line number: the line ends before it (counted in parallel too).
        let ends: Vec<usize> = std::thread::scope(|s| {
            let counts: Vec<_> = pieces
                .iter()
                .map(|p| s.spawn(|| p.matches('\n').count()))
                .collect();
            counts.into_iter().map(joined).collect()
        });
        let parts: Vec<Reader> = std::thread::scope(|s| {
            let mut first = number + 1;
            let mut handles = Vec::with_capacity(pieces.len());
            for (piece, ends) in pieces.iter().zip(&ends) {
                let mut part = reader.part();
                let start = first;
                handles.push(s.spawn(move || {
                    part.lines_of(piece, start);
                    part
                }));
                first += ends;
            }
            handles.into_iter().map(joined).collect()
        });
        for part in parts {
            reader.absorb(part);
        }
    }
    reader.finish().map_err(|p| invalid(p.list, p.omitted))
}

/// A scoped thread's result; a panic in it goes on in the caller, as if it had run there.
fn joined<T>(handle: std::thread::ScopedJoinHandle<'_, T>) -> T {
    handle
        .join()
        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
}

/// `text` cut into at most `pieces` pieces of about equal length, each ending at a line end
/// (the last at the end of the text); none is empty unless the text is.
fn split_pieces(text: &str, pieces: usize) -> Vec<&str> {
    let mut out = Vec::with_capacity(pieces.max(1));
    let mut start = 0;
    for k in 1..pieces {
        let target = (text.len() / pieces * k).max(start);
        // Past the next line end: a `\n` is a whole character, so the cut is at a boundary
        // (the target itself may fall inside one).
        let after = text.as_bytes().get(target..).unwrap_or_default();
        let end = match after.iter().position(|&b| b == b'\n') {
            Some(at) => target + at + 1,
            None => break,
        };
        if let Some(piece) = text.get(start..end) {
            if !piece.is_empty() {
                out.push(piece);
            }
        }
        start = end;
    }
    if let Some(piece) = text.get(start..) {
        if !piece.is_empty() || out.is_empty() {
            out.push(piece);
        }
    }
    out
}

/// The separator and decimal mark: as the options say, or as the header line shows.
pub(super) fn dialect_of(options: &ReadOptions, header: &str) -> Dialect {
    options
        .delimiter
        .map_or_else(|| Dialect::detect(header), Dialect::with_delimiter)
}

pub(super) fn not_utf8(bytes: &[u8], valid: usize) -> Problem {
    let prefix = bytes.get(..valid).unwrap_or_default();
    let line_start = prefix
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    let line = 1 + prefix.iter().filter(|&&b| b == b'\n').count();
    let column = 1 + std::str::from_utf8(prefix.get(line_start..).unwrap_or_default())
        .map_or(0, |s| s.chars().count());
    Problem::NotUtf8 { line, column }
}

fn split_problem(line_no: usize, line: &str, e: SplitError, dialect: Dialect) -> Problem {
    match e {
        SplitError::Unclosed(at) => Problem::UnclosedQuote {
            line: line_no,
            column: char_column(line, at),
        },
        SplitError::AfterQuote(at) => Problem::AfterQuote {
            line: line_no,
            column: char_column(line, at) + 1,
            separator: dialect.name(),
        },
    }
}

/// Comments and blank lines carry no data; a comment may come before the header.
pub(super) fn skipped(line: &str) -> bool {
    let t = line.trim_start();
    t.is_empty() || t.starts_with('#')
}

#[derive(Logos, Debug, Clone, Copy, PartialEq, Eq)]
#[logos(skip r"[ \t\r]+")]
enum Tok {
    #[token(",")]
    Comma,
    // Every text this matches is also accepted by `f64::from_str`.
    #[regex(r"[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?", priority = 10)]
    Number,
    #[regex(r"[^, \t\r\n]+", priority = 1)]
    Text,
}

/// A cell's span in its line, spaces around it excluded (ASCII ones; the slow path trims the
/// rest). An empty cell has `start == end` at the place it would be.
#[derive(Debug, Clone, Copy)]
pub struct Cell {
    /// Byte range of the cell's text in the line it was split from.
    pub start: usize,
    pub end: usize,
    /// The cell is exactly one number token: the fast path may parse it directly.
    number: bool,
    /// Byte offset of the cell in the line as written, for its column in messages (the span
    /// may index a copy of the line with quotes removed).
    pub origin: usize,
}

fn split_cells(line: &str, cells: &mut Vec<Cell>) {
    cells.clear();
    let mut lex = Tok::lexer(line);
    let mut cell = Cell {
        start: 0,
        end: 0,
        number: false,
        origin: 0,
    };
    let mut tokens = 0usize;
    while let Some(tok) = lex.next() {
        let span = lex.span();
        match tok {
            Ok(Tok::Comma) => {
                cells.push(cell);
                cell = Cell {
                    start: span.end,
                    end: span.end,
                    number: false,
                    origin: span.end,
                };
                tokens = 0;
            }
            other => {
                if tokens == 0 {
                    cell.start = span.start;
                    cell.origin = span.start;
                }
                tokens += 1;
                cell.end = span.end;
                cell.number = tokens == 1 && other == Ok(Tok::Number);
            }
        }
    }
    cells.push(cell);
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Points,
    Lengths,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Axis {
        end: usize,
        axis: usize,
    },
    Dir {
        end: usize,
        axis: usize,
    },
    Input(usize),
    Time,
    Run,
    Tool,
    ToolOffset(usize),
    Artifact,
    Observed(usize),
    /// `px py pz`: a target's position in an instrument's frame.
    Measured(usize),
    /// `prx pry prz`: its orientation there.
    MeasuredRotation(usize),
    Target,
    Dl,
}

enum Store {
    Skip,
    Numbers(Vec<f64>),
    Ids(Vec<u32>),
}

struct Column {
    name: String,
    role: Option<Role>,
    /// Conversion to SI and the unit's name for messages.
    scale: f64,
    offset: f64,
    unit: String,
    store: Store,
}

/// Artifact cells left empty: the row has no artifact.
const NO_ID: u32 = u32::MAX;

#[derive(Default)]
struct Interner {
    ids: HashMap<String, u32>,
    labels: Vec<String>,
    /// Consecutive rows mostly repeat a label: checking the last one first skips the hash.
    last: Option<u32>,
}

impl Interner {
    fn id(&mut self, label: &str) -> u32 {
        if let Some(last) = self.last {
            if self.labels.get(last as usize).is_some_and(|l| l == label) {
                return last;
            }
        }
        let id = match self.ids.get(label) {
            Some(&id) => id,
            None => {
                let id = u32::try_from(self.labels.len()).unwrap_or(NO_ID - 1);
                self.ids.insert(label.to_string(), id);
                self.labels.push(label.to_string());
                id
            }
        };
        self.last = Some(id);
        id
    }
}

#[derive(Default)]
struct Problems {
    list: Vec<Problem>,
    omitted: usize,
}

impl Problems {
    fn push(&mut self, p: Problem) {
        if self.list.len() < MAX_PROBLEMS {
            self.list.push(p);
        } else {
            self.omitted += 1;
        }
    }

    fn is_empty(&self) -> bool {
        self.list.is_empty() && self.omitted == 0
    }
}

pub(super) struct Reader<'m> {
    machine: &'m Machine,
    kind: Kind,
    /// Observations optional: the file only gives poses to evaluate a model at.
    poses: bool,
    columns: Vec<Column>,
    problems: Problems,
    lines: Vec<usize>,
    data_lines: usize,
    runs: Interner,
    artifacts: Interner,
    targets: Interner,
    /// Per run id, the last accepted time (SI) and its line.
    last_time: Vec<Option<(f64, usize)>>,
    has_run: bool,
    dialect: Dialect,
    /// In a piece read on its own thread (`part`): the rows' time-order checks, left for
    /// `absorb`, which knows the times of the pieces before.
    deferred: Option<Vec<TimeCheck>>,
}

/// A row's time, kept for the time-order check (`Reader::check_time`) of the whole file.
struct TimeCheck {
    /// Problems found in the piece before the check (kept and omitted): where its own goes.
    at: usize,
    line: usize,
    time: f64,
    /// The run's id in the piece.
    run: u32,
}

/// 1-based character column of a byte offset in a line.
fn char_column(line: &str, byte: usize) -> usize {
    1 + line.get(..byte).map_or(0, |s| s.chars().count())
}

/// Long garbage is cut so one bad cell cannot flood a message.
fn excerpt(text: &str) -> String {
    const MAX: usize = 40;
    if text.chars().count() <= MAX {
        text.to_string()
    } else {
        let mut s: String = text.chars().take(MAX).collect();
        s.push('…');
        s
    }
}

/// `X[mm]` → (`X`, Some(`mm`)).
fn split_name(text: &str) -> Result<(&str, Option<&str>), &'static str> {
    match text.find('[') {
        None if text.contains(']') => Err("`]` without `[`"),
        None => Ok((text, None)),
        Some(open) => {
            let name = text.get(..open).unwrap_or("").trim_end();
            let rest = text.get(open + 1..).unwrap_or("");
            let close = rest.find(']').ok_or("`[` without `]`")?;
            if !rest.get(close + 1..).unwrap_or("").trim().is_empty() {
                return Err("text after the unit");
            }
            let unit = rest.get(..close).unwrap_or("").trim();
            if unit.contains('[') {
                return Err("nested `[`");
            }
            Ok((name, Some(unit)))
        }
    }
}

impl<'m> Reader<'m> {
    pub(super) fn new(
        machine: &'m Machine,
        options: &ReadOptions,
        dialect: Dialect,
        line_no: usize,
        line: &str,
    ) -> Self {
        let mut problems = Problems::default();
        let mut buf = String::new();
        let mut cells = Vec::new();
        if let Err(e) = csv::split(line, dialect.delimiter, &mut buf, &mut cells) {
            problems.push(split_problem(line_no, line, e, dialect));
            cells.clear();
        }
        let raw: Vec<(usize, &str)> = cells
            .iter()
            .map(|c| {
                let text = buf.get(c.start..c.end).unwrap_or("").trim();
                (char_column(line, c.origin), text)
            })
            .collect();
        let ignored = |name: &str| options.ignore.iter().any(|i| i == name);
        let name_of = |text: &str| split_name(text).map_or(String::new(), |(n, _)| n.to_string());
        let names: Vec<String> = raw.iter().map(|(_, t)| name_of(t)).collect();
        let has_dl = !ignored("dL") && names.iter().any(|n| n == "dL");
        // Without observations a length file is known by its `_1`/`_2` axis columns.
        let has_ends = || {
            machine.axes.iter().any(|a| {
                let ends = [format!("{}_1", a.name), format!("{}_2", a.name)];
                names.iter().any(|n| ends.contains(n) && !ignored(n))
            })
        };
        let kind = if has_dl || (options.poses && has_ends()) {
            Kind::Lengths
        } else {
            Kind::Points
        };
        let known = known_columns(machine, kind);
        let mut columns = Vec::with_capacity(raw.len());
        let mut first_seen: HashMap<String, usize> = HashMap::new();
        // Roles whose column is there, readable or not: a column with a bad unit is reported
        // once, as such, not again as missing.
        let mut present = Vec::new();
        for (index, &(column, text)) in raw.iter().enumerate() {
            let skip = |name: String| Column {
                name,
                role: None,
                scale: 1.0,
                offset: 0.0,
                unit: String::new(),
                store: Store::Skip,
            };
            let (name, unit_text) = match split_name(text) {
                Ok(parts) => parts,
                Err(reason) => {
                    problems.push(Problem::BadName {
                        line: line_no,
                        column,
                        text: excerpt(text),
                        reason,
                    });
                    columns.push(skip(text.to_string()));
                    continue;
                }
            };
            // pandas' `to_csv` writes the row index as a first column with no name.
            if name.is_empty() && index == 0 && unit_text.is_none() && raw.len() > 1 {
                columns.push(skip(String::new()));
                continue;
            }
            if name.is_empty() {
                problems.push(Problem::EmptyName {
                    line: line_no,
                    column,
                });
                columns.push(skip(String::new()));
                continue;
            }
            if ignored(name) {
                columns.push(skip(name.to_string()));
                continue;
            }
            if let Some(&first) = first_seen.get(name) {
                problems.push(Problem::DuplicateColumn {
                    line: line_no,
                    column,
                    name: name.to_string(),
                    first,
                });
                columns.push(skip(name.to_string()));
                continue;
            }
            first_seen.insert(name.to_string(), column);
            let Some(role) = known.get(name).copied() else {
                problems.push(Problem::UnknownColumn {
                    line: line_no,
                    column,
                    name: name.to_string(),
                    hint: hint(name, machine, kind, &known),
                });
                columns.push(skip(name.to_string()));
                continue;
            };
            present.push(role);
            let unit = match column_unit(machine, role, unit_text) {
                Ok(unit) => unit,
                Err(e) => {
                    problems.push(e.at(line_no, column, name));
                    columns.push(skip(name.to_string()));
                    continue;
                }
            };
            let store = match role {
                Role::Run | Role::Tool | Role::Artifact | Role::Target => Store::Ids(Vec::new()),
                _ => Store::Numbers(Vec::new()),
            };
            let (scale, offset, unit) = match unit {
                Some(u) => (u.scale, u.offset, u.name),
                None => (1.0, 0.0, String::new()),
            };
            columns.push(Column {
                name: name.to_string(),
                role: Some(role),
                scale,
                offset,
                unit,
                store,
            });
        }
        let has = |role: Role| present.contains(&role);
        let mut missing = Vec::new();
        let ends = if kind == Kind::Lengths { 2 } else { 1 };
        // A time series may leave out the pose altogether (it is given elsewhere), but not
        // half of it.
        let no_axes = options.series
            && ends == 1
            && !machine
                .axes
                .iter()
                .enumerate()
                .any(|(axis, _)| has(Role::Axis { end: 0, axis }));
        for end in 0..ends {
            for (axis, a) in machine.axes.iter().enumerate() {
                if !has(Role::Axis { end, axis }) && !no_axes {
                    missing.push(axis_column(&a.name, kind, end));
                }
            }
        }
        if options.series && !has(Role::Time) {
            missing.push("time".to_string());
        }
        if kind == Kind::Lengths && !has(Role::Dl) && !options.poses {
            missing.push("dL".to_string());
        }
        if !missing.is_empty() {
            problems.push(Problem::MissingColumns { names: missing });
        }
        let offsets: Vec<bool> = (0..3).map(|k| has(Role::ToolOffset(k))).collect();
        let measured: Vec<bool> = (0..3).map(|k| has(Role::Measured(k))).collect();
        let turned: Vec<bool> = (0..3).map(|k| has(Role::MeasuredRotation(k))).collect();
        if turned.iter().any(|&b| b) && !(turned.iter().all(|&b| b) && measured.iter().all(|&b| b))
        {
            let missing = MEASURED
                .iter()
                .zip(&measured)
                .chain(MEASURED_ROTATION.iter().zip(&turned))
                .filter(|(_, &present)| !present)
                .map(|(n, _)| n.to_string())
                .collect();
            problems.push(Problem::IncompleteOrientationColumns { missing });
        }
        let absolute = measured.iter().any(|&b| b);
        if kind == Kind::Points
            && !options.poses
            && !absolute
            && !(0..OBSERVED.len()).any(|k| has(Role::Observed(k)))
        {
            problems.push(Problem::NoObservedColumn);
        }
        if absolute {
            if !measured.iter().all(|&b| b) {
                let missing = MEASURED
                    .iter()
                    .zip(&measured)
                    .filter(|(_, &present)| !present)
                    .map(|(n, _)| n.to_string())
                    .collect();
                problems.push(Problem::IncompleteMeasuredColumns { missing });
            }
            let errors: Vec<&str> = OBSERVED
                .iter()
                .enumerate()
                .filter(|(k, _)| has(Role::Observed(*k)))
                .map(|(_, n)| *n)
                .collect();
            if !errors.is_empty() {
                problems.push(Problem::ErrorsAndPositions {
                    errors: errors.join(", "),
                });
            }
            if has(Role::Artifact) {
                problems.push(Problem::NotWithPositions {
                    column: "artifact".into(),
                    reason: "the instrument's placement is fitted for the whole file",
                });
            }
            if offsets.iter().any(|&b| b) {
                problems.push(Problem::NotWithPositions {
                    column: "tool_x".into(),
                    reason: "each target's offset on the tool is fitted (`target`)",
                });
            }
        }
        if offsets.iter().any(|&b| b) && !offsets.iter().all(|&b| b) {
            let missing = TOOL_OFFSET
                .iter()
                .zip(&offsets)
                .filter(|(_, &present)| !present)
                .map(|(n, _)| n.to_string())
                .collect();
            problems.push(Problem::IncompleteToolColumns { missing });
        }
        let has_run = columns.iter().any(|c| c.role == Some(Role::Run));
        Reader {
            machine,
            kind,
            poses: options.poses,
            columns,
            problems,
            lines: Vec::new(),
            data_lines: 0,
            runs: Interner::default(),
            artifacts: Interner::default(),
            targets: Interner::default(),
            last_time: Vec::new(),
            has_run,
            dialect,
            deferred: None,
        }
    }

    /// A reader of another piece of the same file: the header's columns, nothing read yet, the
    /// time-order checks deferred (see [`Reader::absorb`]).
    fn part(&self) -> Reader<'m> {
        let columns = self
            .columns
            .iter()
            .map(|c| Column {
                name: c.name.clone(),
                role: c.role,
                scale: c.scale,
                offset: c.offset,
                unit: c.unit.clone(),
                store: match c.store {
                    Store::Skip => Store::Skip,
                    Store::Numbers(_) => Store::Numbers(Vec::new()),
                    Store::Ids(_) => Store::Ids(Vec::new()),
                },
            })
            .collect();
        Reader {
            machine: self.machine,
            kind: self.kind,
            poses: self.poses,
            columns,
            problems: Problems::default(),
            lines: Vec::new(),
            data_lines: 0,
            runs: Interner::default(),
            artifacts: Interner::default(),
            targets: Interner::default(),
            last_time: Vec::new(),
            has_run: self.has_run,
            dialect: self.dialect,
            deferred: Some(Vec::new()),
        }
    }

    /// Reads every data line of `text`, whose first line is line `first` of the file.
    fn lines_of(&mut self, text: &str, first: usize) {
        let mut cells = Vec::with_capacity(self.columns.len());
        let mut buf = String::new();
        for (i, line) in text.split('\n').enumerate() {
            let line = line.strip_suffix('\r').unwrap_or(line);
            if skipped(line) {
                continue;
            }
            self.line(first + i, line, &mut cells, &mut buf);
        }
    }

    /// Appends the rows and problems of `part`, the piece of the file that follows those read
    /// so far, as if its lines had been read here: its labels get this reader's ids (new ones
    /// in the order the piece first used them, which is the file's), its problems go after
    /// these, and its rows' time order is checked against the times before it, each check's
    /// problem in its place among the piece's.
    fn absorb(&mut self, part: Reader<'m>) {
        let ids = |mine: &mut Interner, theirs: &Interner| -> Vec<u32> {
            theirs.labels.iter().map(|l| mine.id(l)).collect()
        };
        let runs = ids(&mut self.runs, &part.runs);
        let artifacts = ids(&mut self.artifacts, &part.artifacts);
        let targets = ids(&mut self.targets, &part.targets);
        // An id with no label is a cell already reported (an empty run or target): any value
        // does, the rows are not handed out.
        let map = |table: &[u32], id: u32| table.get(id as usize).copied().unwrap_or(id);
        for (mine, theirs) in self.columns.iter_mut().zip(part.columns) {
            match (&mut mine.store, theirs.store, mine.role) {
                (Store::Numbers(v), Store::Numbers(more), _) => append(v, more),
                (Store::Ids(v), Store::Ids(more), Some(Role::Run)) => {
                    v.extend(more.into_iter().map(|id| map(&runs, id)));
                }
                (Store::Ids(v), Store::Ids(more), Some(Role::Target)) => {
                    v.extend(more.into_iter().map(|id| map(&targets, id)));
                }
                (Store::Ids(v), Store::Ids(more), Some(Role::Artifact)) => {
                    v.extend(more.into_iter().map(|id| {
                        if id == NO_ID {
                            id
                        } else {
                            map(&artifacts, id)
                        }
                    }));
                }
                // Tools are the machine's, the same in every piece.
                (Store::Ids(v), Store::Ids(more), _) => append(v, more),
                _ => {}
            }
        }
        append(&mut self.lines, part.lines);
        self.data_lines += part.data_lines;
        let mut problems = part.problems.list.into_iter();
        let mut passed = 0;
        for check in part.deferred.unwrap_or_default() {
            // Past the end of the kept list the whole file's list is full (the piece alone
            // filled it): the order of what is only counted does not matter.
            while passed < check.at {
                let Some(p) = problems.next() else { break };
                self.problems.push(p);
                passed += 1;
            }
            let run = if self.has_run {
                map(&runs, check.run)
            } else {
                check.run
            };
            self.check_time(check.line, check.time, run);
        }
        for p in problems {
            self.problems.push(p);
        }
        self.problems.omitted += part.problems.omitted;
    }

    /// One data line (not a comment or blank): split in the file's dialect and read as a row.
    /// `cells` and `buf` are scratch space kept between lines.
    pub(super) fn line(
        &mut self,
        number: usize,
        line: &str,
        cells: &mut Vec<Cell>,
        buf: &mut String,
    ) {
        // The comma lexer is the hot path; quotes and other separators take the general one.
        if self.dialect.delimiter == b',' && !line.contains('"') {
            split_cells(line, cells);
            self.row(number, line, line, cells);
        } else {
            match csv::split(line, self.dialect.delimiter, buf, cells) {
                Ok(()) => self.row(number, line, buf, cells),
                Err(e) => self.unsplittable(number, line, e),
            }
        }
    }

    /// A data line whose quotes do not close or are followed by text.
    fn unsplittable(&mut self, line_no: usize, line: &str, e: SplitError) {
        self.data_lines += 1;
        let p = split_problem(line_no, line, e, self.dialect);
        self.problems.push(p);
    }

    /// One data row: `raw` is the line as written (for columns), `line` the text the cells'
    /// spans index into (the same line, or a copy with quotes removed).
    fn row(&mut self, line_no: usize, raw: &str, line: &str, cells: &[Cell]) {
        self.data_lines += 1;
        if cells.len() != self.columns.len() {
            self.problems.push(Problem::CellCount {
                line: line_no,
                found: cells.len(),
                expected: self.columns.len(),
            });
            return;
        }
        let poses = self.poses;
        let decimal_comma = self.dialect.decimal_comma;
        let Reader {
            machine,
            columns,
            problems,
            runs,
            artifacts,
            targets,
            ..
        } = self;
        let mut observed = false;
        let mut observed_columns = false;
        let mut offsets_empty = [None::<bool>; 3];
        let mut time = None;
        let mut run = if self.has_run { None } else { Some(0) };
        let bad = |problems: &mut Problems, name: &str, cell: &Cell, expected: String| {
            let text = line.get(cell.start..cell.end).unwrap_or("").trim();
            problems.push(Problem::BadCell {
                line: line_no,
                column: char_column(raw, cell.origin),
                name: name.to_string(),
                text: excerpt(text),
                expected,
            });
        };
        for (col, cell) in columns.iter_mut().zip(cells) {
            let Some(role) = col.role else { continue };
            match (&mut col.store, role) {
                (Store::Numbers(values), Role::Dir { .. }) => {
                    let v = direction(line, cell, decimal_comma);
                    if v.is_none() {
                        bad(problems, &col.name, cell, "+1 or -1".into());
                    }
                    values.push(v.unwrap_or(f64::NAN));
                }
                (Store::Numbers(values), _) => {
                    let parsed = number(line, cell, decimal_comma)
                        .map(|v| v.map(|v| v * col.scale + col.offset));
                    let required = match role {
                        Role::Axis { .. }
                        | Role::Time
                        | Role::Measured(_)
                        | Role::MeasuredRotation(_) => true,
                        Role::Dl => !poses,
                        _ => false,
                    };
                    let v = match parsed {
                        Ok(Some(v)) if v.is_finite() => match plausible(machine, role) {
                            // The margin lets the bound itself, written in the column's
                            // unit, read despite the rounding of the conversion to SI.
                            Some((bound, what)) if v.abs() > bound * (1.0 + 1e-12) => {
                                let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                                problems.push(Problem::Implausible {
                                    line: line_no,
                                    column: char_column(raw, cell.origin),
                                    name: col.name.clone(),
                                    text: excerpt(text),
                                    what,
                                    limit: limit_text(bound, col.scale, &col.unit),
                                });
                                f64::NAN
                            }
                            // An error far below any instrument's resolution whose square
                            // underflows: σ̂ would be 0 and every statistic of the fit NaN.
                            _ if matches!(role, Role::Observed(_) | Role::Dl)
                                && v != 0.0
                                && v.abs() < MIN_ERROR * (1.0 - 1e-12) =>
                            {
                                let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                                problems.push(Problem::Negligible {
                                    line: line_no,
                                    column: char_column(raw, cell.origin),
                                    name: col.name.clone(),
                                    text: excerpt(text),
                                    limit: limit_text(MIN_ERROR, col.scale, &col.unit),
                                });
                                f64::NAN
                            }
                            // An absolute temperature is kelvin here: below 0 it is no
                            // temperature (a rise written as absolute, a sign lost).
                            _ if absolute_temperature(machine, role) && v < 0.0 => {
                                let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                                problems.push(Problem::BelowAbsoluteZero {
                                    line: line_no,
                                    column: char_column(raw, cell.origin),
                                    name: col.name.clone(),
                                    text: excerpt(text),
                                });
                                f64::NAN
                            }
                            _ => v,
                        },
                        Ok(None) if !required => f64::NAN,
                        _ => {
                            // `nan`, `inf` and `1e400` are numbers to Rust but not measurements.
                            let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                            let what = if text.parse::<f64>().is_ok() {
                                "a finite number"
                            } else {
                                "a number"
                            };
                            let expected = if col.unit.is_empty() || col.unit == "1" {
                                what.to_string()
                            } else {
                                format!("{what} in {}", col.unit)
                            };
                            bad(problems, &col.name, cell, expected);
                            f64::NAN
                        }
                    };
                    let empty = matches!(parsed, Ok(None));
                    match role {
                        Role::Observed(_) => {
                            observed_columns = true;
                            observed |= !empty;
                        }
                        Role::ToolOffset(k) => {
                            if let Some(slot) = offsets_empty.get_mut(k) {
                                *slot = Some(empty);
                            }
                        }
                        Role::Time if v.is_finite() => time = Some(v),
                        _ => {}
                    }
                    values.push(v);
                }
                (Store::Ids(ids), Role::Tool) => {
                    let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                    let found = machine.tools.iter().position(|t| t.name == text);
                    if found.is_none() {
                        if text.is_empty() {
                            bad(problems, &col.name, cell, "a tool name".into());
                        } else {
                            problems.push(Problem::UnknownTool {
                                line: line_no,
                                column: char_column(raw, cell.origin),
                                name: col.name.clone(),
                                text: excerpt(text),
                                declared: machine.tools.iter().map(|t| t.name.clone()).collect(),
                            });
                        }
                    }
                    ids.push(found.and_then(|i| u32::try_from(i).ok()).unwrap_or(0));
                }
                (Store::Ids(ids), Role::Run) => {
                    let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                    if text.is_empty() {
                        bad(problems, &col.name, cell, "a run label".into());
                        ids.push(0);
                    } else {
                        let id = runs.id(text);
                        run = Some(id);
                        ids.push(id);
                    }
                }
                (Store::Ids(ids), Role::Target) => {
                    let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                    if text.is_empty() {
                        bad(problems, &col.name, cell, "a target label".into());
                        ids.push(0);
                    } else {
                        ids.push(targets.id(text));
                    }
                }
                (Store::Ids(ids), _) => {
                    let text = line.get(cell.start..cell.end).unwrap_or("").trim();
                    ids.push(if text.is_empty() {
                        NO_ID
                    } else {
                        artifacts.id(text)
                    });
                }
                (Store::Skip, _) => {}
            }
        }
        if observed_columns && !observed && self.kind == Kind::Points && !self.poses {
            let columns = self
                .columns
                .iter()
                .filter(|c| matches!(c.role, Some(Role::Observed(_))))
                .map(|c| c.name.clone())
                .collect();
            self.problems.push(Problem::NothingObserved {
                line: line_no,
                columns,
            });
        }
        let given: Vec<bool> = offsets_empty.iter().flatten().copied().collect();
        if given.len() == 3 && given.iter().any(|&e| e) && !given.iter().all(|&e| e) {
            let empty = TOOL_OFFSET
                .iter()
                .zip(offsets_empty)
                .filter(|(_, e)| *e == Some(true))
                .map(|(n, _)| n.to_string())
                .collect();
            self.problems.push(Problem::IncompleteToolOffset {
                line: line_no,
                empty,
            });
        }
        if let (Some(t), Some(run)) = (time, run) {
            self.check_time(line_no, t, run);
        }
        self.lines.push(line_no);
    }

    fn check_time(&mut self, line_no: usize, t: f64, run: u32) {
        if let Some(deferred) = &mut self.deferred {
            deferred.push(TimeCheck {
                at: self.problems.list.len() + self.problems.omitted,
                line: line_no,
                time: t,
                run,
            });
            return;
        }
        let slot = run as usize;
        if self.last_time.len() <= slot {
            self.last_time.resize(slot + 1, None);
        }
        let Some(last) = self.last_time.get_mut(slot) else {
            return;
        };
        match *last {
            Some((previous, previous_line)) if t < previous => {
                let col = self.columns.iter().find(|c| c.role == Some(Role::Time));
                let (scale, offset, unit) = col.map_or((1.0, 0.0, "s".to_string()), |c| {
                    (c.scale, c.offset, c.unit.clone())
                });
                let label = self
                    .has_run
                    .then(|| self.runs.labels.get(slot).cloned())
                    .flatten();
                self.problems.push(Problem::TimeOrder {
                    line: line_no,
                    previous_line,
                    time: (t - offset) / scale,
                    previous: (previous - offset) / scale,
                    unit,
                    run: label,
                });
            }
            _ => *last = Some((t, line_no)),
        }
    }

    fn finish(mut self) -> Result<Observations, Problems> {
        if self.data_lines == 0 {
            self.problems.push(Problem::NoRows);
        }
        if !self.problems.is_empty() {
            return Err(self.problems);
        }
        Ok(self.take())
    }

    /// The problems found so far, at most [`MAX_PROBLEMS`] of them, and how many more.
    pub(super) fn problems(&self) -> (&[Problem], usize) {
        (&self.problems.list, self.problems.omitted)
    }

    /// Data lines read so far (rows and rows with problems).
    pub(super) fn data_lines(&self) -> usize {
        self.data_lines
    }

    /// The rows read since the last call, as observations; the reader goes on with the next
    /// rows. Run and artifact ids stay those of the whole file (the labels are all those seen
    /// so far), so the rows of several calls can be told apart as one file's.
    pub(super) fn take(&mut self) -> Observations {
        let n = self.lines.len();
        let m = self.machine;
        let ends = if self.kind == Kind::Lengths { 2 } else { 1 };
        let mut poses: Vec<Pose> = (0..ends)
            .map(|_| Pose {
                axes: vec![Vec::new(); m.axes.len()],
                dir: vec![None; m.axes.len()],
            })
            .collect();
        let mut rows = Rows {
            line: std::mem::take(&mut self.lines),
            time: None,
            run: None,
            artifact: None,
            tool: vec![0; n],
            tool_offset: None,
            inputs: vec![None; m.inputs.len()],
        };
        let mut offsets: [Option<Vec<f64>>; 3] = Default::default();
        let mut observed: [Option<Vec<f64>>; 6] = Default::default();
        let mut measured: [Option<Vec<f64>>; 3] = Default::default();
        let mut turned: [Option<Vec<f64>>; 3] = Default::default();
        let mut target: Option<Vec<u32>> = None;
        // A poses-only length file may have no `dL`: nothing observed.
        let mut dl = vec![f64::NAN; n];
        for col in &mut self.columns {
            let Some(role) = col.role else { continue };
            let store = match &mut col.store {
                Store::Skip => Store::Skip,
                Store::Numbers(v) => Store::Numbers(std::mem::take(v)),
                Store::Ids(v) => Store::Ids(std::mem::take(v)),
            };
            match (store, role) {
                (Store::Numbers(v), Role::Axis { end, axis }) => {
                    if let Some(slot) = poses.get_mut(end).and_then(|p| p.axes.get_mut(axis)) {
                        *slot = v;
                    }
                }
                (Store::Numbers(v), Role::Dir { end, axis }) => {
                    if let Some(slot) = poses.get_mut(end).and_then(|p| p.dir.get_mut(axis)) {
                        *slot = Some(v);
                    }
                }
                (Store::Numbers(v), Role::Input(i)) => {
                    if let Some(slot) = rows.inputs.get_mut(i) {
                        *slot = Some(v);
                    }
                }
                (Store::Numbers(v), Role::Time) => rows.time = Some(v),
                (Store::Numbers(v), Role::ToolOffset(k)) => {
                    if let Some(slot) = offsets.get_mut(k) {
                        *slot = Some(v);
                    }
                }
                (Store::Numbers(v), Role::Observed(k)) => {
                    if let Some(slot) = observed.get_mut(k) {
                        *slot = Some(v);
                    }
                }
                (Store::Numbers(v), Role::Measured(k)) => {
                    if let Some(slot) = measured.get_mut(k) {
                        *slot = Some(v);
                    }
                }
                (Store::Numbers(v), Role::MeasuredRotation(k)) => {
                    if let Some(slot) = turned.get_mut(k) {
                        *slot = Some(v);
                    }
                }
                (Store::Ids(ids), Role::Target) => target = Some(ids),
                (Store::Numbers(v), Role::Dl) => dl = v,
                (Store::Ids(ids), Role::Tool) => {
                    rows.tool = ids.into_iter().map(|i| i as usize).collect();
                }
                (Store::Ids(ids), Role::Run) => {
                    rows.run = Some(Groups {
                        of_row: ids,
                        labels: self.runs.labels.clone(),
                    });
                }
                (Store::Ids(ids), Role::Artifact) => {
                    rows.artifact = Some(Groups {
                        of_row: ids.into_iter().map(|i| (i != NO_ID).then_some(i)).collect(),
                        labels: self.artifacts.labels.clone(),
                    });
                }
                _ => {}
            }
        }
        if let [Some(x), Some(y), Some(z)] = offsets {
            rows.tool_offset = Some([x, y, z]);
        }
        let mut poses = poses.into_iter();
        let first = poses.next().unwrap_or_default();
        match self.kind {
            Kind::Points => {
                // One unnamed target when the file does not say which.
                let absolute = match measured {
                    [Some(x), Some(y), Some(z)] => Some(Absolute {
                        position: [x, y, z],
                        rotation: match turned {
                            [Some(a), Some(b), Some(c)] => Some([a, b, c]),
                            _ => None,
                        },
                        target: match target {
                            Some(of_row) => Groups {
                                of_row,
                                labels: self.targets.labels.clone(),
                            },
                            None => Groups {
                                of_row: vec![0; n],
                                labels: vec![String::new()],
                            },
                        },
                    }),
                    _ => None,
                };
                Observations::Points(PointData {
                    rows,
                    pose: first,
                    observed,
                    absolute,
                })
            }
            Kind::Lengths => Observations::Lengths(LengthData {
                rows,
                poses: [first, poses.next().unwrap_or_default()],
                dl,
            }),
        }
    }
}

/// `more` after `v`; moved when `v` is empty (the first piece), not copied.
fn append<T: Copy>(v: &mut Vec<T>, more: Vec<T>) {
    if v.is_empty() {
        *v = more;
    } else {
        v.extend_from_slice(&more);
    }
}

/// `Ok(None)` for an empty cell; `Err` for anything that is not a finite number.
fn number(line: &str, cell: &Cell, decimal_comma: bool) -> Result<Option<f64>, ()> {
    let raw = line.get(cell.start..cell.end).unwrap_or("");
    if cell.number {
        // std's parser (Eisel–Lemire) was measured against fast-float2 and lexical-core on the
        // cells of 10⁶ simulated poses: they took 3–5 % less time for the whole read, too
        // little for another dependency.
        let parsed = raw.parse::<f64>().ok();
        if let Some(v) = parsed {
            return Ok(Some(v));
        }
    }
    let text = raw.trim();
    if text.is_empty() {
        return Ok(None);
    }
    // `f64::from_str` also reads `nan` and `inf`, which are not measurements.
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Some(v)),
        Err(_) if decimal_comma => csv::decimal_comma(text).map(Some).ok_or(()),
        _ => Err(()),
    }
}

/// The largest magnitude (SI) a cell of this role may hold, and what the value is, for the
/// message. The bounds are far beyond any machine (spec/cli.md, "Measurement files") yet small
/// enough that the powers of them a model's columns take (polynomials, products of axes) and
/// their sums of squares over 10⁸ rows stay far from overflow, so an absurd cell is reported
/// where it is instead of turning the fit's σ̂ and coefficients into inf or NaN.
/// Whether the column is an input declared as an absolute temperature (read in kelvin).
fn absolute_temperature(machine: &Machine, role: Role) -> bool {
    match role {
        Role::Input(i) => machine.inputs.get(i).is_some_and(|input| {
            input.absolute && input.unit.dim == kin_compiler::units::Dim::TEMPERATURE
        }),
        _ => false,
    }
}

fn plausible(machine: &Machine, role: Role) -> Option<(f64, &'static str)> {
    Some(match role {
        Role::Axis { axis, .. } => match machine.axes.get(axis).map(|a| a.kind) {
            Some(JointKind::Revolute) => (MAX_ANGLE, "axis angle"),
            _ => (MAX_POSITION, "axis position"),
        },
        Role::ToolOffset(_) => (MAX_POSITION, "tool offset"),
        Role::Measured(_) => (MAX_POSITION, "measured position"),
        Role::MeasuredRotation(_) => (MAX_ANGLE, "measured orientation"),
        Role::Observed(k) if k >= 3 => (MAX_TILT, "rotation error"),
        Role::Observed(_) | Role::Dl => (MAX_ERROR, "error"),
        Role::Time => (MAX_TIME, "time"),
        Role::Input(_) => (MAX_INPUT, "input value"),
        Role::Dir { .. } | Role::Run | Role::Tool | Role::Artifact | Role::Target => return None,
    })
}

/// Axis positions and tool offsets: 10 km.
pub(crate) const MAX_POSITION: f64 = 1e4;
/// Revolute axis angles: 10⁶ rad, some 160 000 turns of a continuous axis.
pub(crate) const MAX_ANGLE: f64 = 1e6;
/// Observed position and length errors: 1 m.
pub(crate) const MAX_ERROR: f64 = 1.0;
/// Observed rotation errors: 1 rad.
pub(crate) const MAX_TILT: f64 = 1.0;
/// The smallest non-zero observed error, in SI: 10⁻¹⁰⁰ (no instrument resolves it; squares
/// of smaller values underflow and leave the fit's σ̂ at 0).
pub(crate) const MIN_ERROR: f64 = 1e-100;
/// Time: 10¹⁰ s, about 300 years (a Unix time stamp fits).
pub(crate) const MAX_TIME: f64 = 1e10;
/// Inputs (temperatures, forces, …), in their SI unit: 10⁹.
pub(crate) const MAX_INPUT: f64 = 1e9;

/// A bound in the column's own unit, as the user would write it.
fn limit_text(bound: f64, scale: f64, unit: &str) -> String {
    // Rounded to 12 digits: `1 / 1e-6` is not exactly 10⁶ in binary.
    let v = bound / scale;
    let v = format!("{v:.12e}").parse::<f64>().unwrap_or(v);
    let number = if v.abs() >= 1e6 || v.abs() < 1e-3 {
        format!("{v:e}")
    } else {
        format!("{v}")
    };
    if unit.is_empty() || unit == "1" {
        number
    } else {
        format!("{number} {unit}")
    }
}

fn direction(line: &str, cell: &Cell, decimal_comma: bool) -> Option<f64> {
    let text = line.get(cell.start..cell.end).unwrap_or("").trim();
    match text {
        "+" => return Some(1.0),
        "-" | "\u{2212}" => return Some(-1.0),
        _ => {}
    }
    // Copied only for a minus sign as typesetting writes it: a row holds several of these.
    let text = if text.contains('\u{2212}') {
        std::borrow::Cow::Owned(text.replace('\u{2212}', "-"))
    } else {
        std::borrow::Cow::Borrowed(text)
    };
    let v = match text.parse::<f64>() {
        Err(_) if decimal_comma => csv::decimal_comma(&text),
        parsed => parsed.ok(),
    };
    v.filter(|&v| v == 1.0 || v == -1.0)
}

fn axis_column(axis: &str, kind: Kind, end: usize) -> String {
    match kind {
        Kind::Points => axis.to_string(),
        Kind::Lengths => format!("{axis}_{}", end + 1),
    }
}

/// Every column name a file of this kind may hold, with its meaning. Axis and input names come
/// first so a machine that (against the checker's advice) reuses a reserved name still reads.
fn known_columns(machine: &Machine, kind: Kind) -> HashMap<String, Role> {
    let mut known = HashMap::new();
    let ends = if kind == Kind::Lengths { 2 } else { 1 };
    for end in 0..ends {
        for (axis, a) in machine.axes.iter().enumerate() {
            let name = axis_column(&a.name, kind, end);
            known
                .entry(format!("dir_{name}"))
                .or_insert(Role::Dir { end, axis });
            known.entry(name).or_insert(Role::Axis { end, axis });
        }
    }
    for (i, input) in machine.inputs.iter().enumerate() {
        known.entry(input.name.clone()).or_insert(Role::Input(i));
    }
    let mut fixed = vec![
        ("time", Role::Time),
        ("run", Role::Run),
        ("tool", Role::Tool),
        ("artifact", Role::Artifact),
    ];
    fixed.extend(
        TOOL_OFFSET
            .iter()
            .enumerate()
            .map(|(k, n)| (*n, Role::ToolOffset(k))),
    );
    match kind {
        Kind::Points => {
            fixed.extend(
                OBSERVED
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (*n, Role::Observed(k))),
            );
            fixed.extend(
                MEASURED
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (*n, Role::Measured(k))),
            );
            fixed.extend(
                MEASURED_ROTATION
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (*n, Role::MeasuredRotation(k))),
            );
            fixed.push(("target", Role::Target));
        }
        Kind::Lengths => fixed.push(("dL", Role::Dl)),
    }
    for (name, role) in fixed {
        known.entry(name.to_string()).or_insert(role);
    }
    known
}

/// A likely reason for an unknown column: the other file kind's naming, or a near miss.
fn hint(
    name: &str,
    machine: &Machine,
    kind: Kind,
    known: &HashMap<String, Role>,
) -> Option<String> {
    let axis_named = |n: &str| machine.axes.iter().find(|a| a.name == n);
    match kind {
        Kind::Lengths => {
            let base = name.strip_prefix("dir_").unwrap_or(name);
            if let Some(a) = axis_named(base) {
                return Some(format!(
                    "a length file names each axis twice: `{0}_1` and `{0}_2`",
                    a.name
                ));
            }
            if OBSERVED.contains(&name) {
                return Some("a length file observes `dL`".to_string());
            }
        }
        Kind::Points => {
            let base = name.strip_prefix("dir_").unwrap_or(name);
            let stem = base.strip_suffix("_1").or_else(|| base.strip_suffix("_2"));
            if stem.and_then(axis_named).is_some() {
                return Some(format!(
                    "`{name}` belongs in a length file, which has a `dL` column"
                ));
            }
        }
    }
    let lower = name.to_lowercase();
    let mut best: Option<(usize, &str)> = None;
    for candidate in known.keys() {
        let d = if candidate.to_lowercase() == lower {
            0
        } else {
            edit_distance(name, candidate)
        };
        if d <= 2 && best.is_none_or(|(bd, bn)| d < bd || (d == bd && candidate.as_str() < bn)) {
            best = Some((d, candidate));
        }
    }
    best.map(|(_, n)| format!("did you mean `{n}`?"))
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row.first().copied().unwrap_or(0);
        if let Some(first) = row.first_mut() {
            *first = i + 1;
        }
        for (j, &cb) in b.iter().enumerate() {
            let above = row.get(j + 1).copied().unwrap_or(usize::MAX);
            let left = row.get(j).copied().unwrap_or(usize::MAX);
            let cost = prev + usize::from(ca != cb);
            let value = cost
                .min(above.saturating_add(1))
                .min(left.saturating_add(1));
            prev = above;
            if let Some(slot) = row.get_mut(j + 1) {
                *slot = value;
            }
        }
    }
    row.last().copied().unwrap_or(0)
}

/// A header unit problem before its location is known.
enum UnitProblem {
    Parse(UnitError),
    NotAllowed,
    Dimension {
        unit: String,
        found: Dim,
        expected: Dim,
    },
}

impl UnitProblem {
    fn at(self, line: usize, column: usize, name: &str) -> Problem {
        let name = name.to_string();
        match self {
            UnitProblem::Parse(error) => Problem::BadUnit {
                line,
                column,
                name,
                error,
            },
            UnitProblem::NotAllowed => Problem::UnitNotAllowed { line, column, name },
            UnitProblem::Dimension {
                unit,
                found,
                expected,
            } => Problem::WrongDimension {
                line,
                column,
                name,
                unit,
                found: found.describe(),
                expected: expected.describe(),
            },
        }
    }
}

/// The unit a column's cells are in: the header's, checked against the quantity, or the
/// machine's default. `None` for label columns.
fn column_unit(
    machine: &Machine,
    role: Role,
    header: Option<&str>,
) -> Result<Option<Unit>, UnitProblem> {
    let u = &machine.units;
    let (default, expected, absolute) = match role {
        Role::Run | Role::Tool | Role::Artifact | Role::Target => {
            return match header {
                None => Ok(None),
                Some(_) => Err(UnitProblem::NotAllowed),
            };
        }
        Role::Axis { axis, .. } => match machine.axes.get(axis).map(|a| a.kind) {
            Some(JointKind::Revolute) => (u.angle.clone(), Dim::ANGLE, false),
            _ => (u.length.clone(), Dim::LENGTH, false),
        },
        Role::Dir { .. } => (Unit::dimensionless(), Dim::DIMENSIONLESS, false),
        Role::Input(i) => match machine.inputs.get(i) {
            Some(input) => (input.unit.clone(), input.unit.dim, input.absolute),
            None => (Unit::dimensionless(), Dim::DIMENSIONLESS, false),
        },
        Role::Time => (u.time.clone(), Dim::TIME, false),
        Role::ToolOffset(_) | Role::Measured(_) => (u.length.clone(), Dim::LENGTH, false),
        Role::MeasuredRotation(_) => (u.angle.clone(), Dim::ANGLE, false),
        Role::Observed(k) if k >= 3 => (u.tilt.clone(), Dim::ANGLE, false),
        Role::Observed(_) | Role::Dl => (u.error.clone(), Dim::LENGTH, false),
    };
    let unit = match header {
        None => default,
        Some(text) => {
            let unit = match inch_unit(text) {
                Some(unit) => unit,
                None => Unit::parse(text).map_err(UnitProblem::Parse)?,
            };
            if unit.dim != expected {
                return Err(UnitProblem::Dimension {
                    unit: unit.name,
                    found: unit.dim,
                    expected,
                });
            }
            unit
        }
    };
    // Only an absolute temperature keeps the Celsius offset; everything else is a difference.
    Ok(Some(if absolute {
        unit.as_absolute()
    } else {
        unit.as_difference()
    }))
}

/// Inch-based lengths, which instruments and exports in inch units write in headers. They are
/// units of measurement files only: a `.kin` model states its own units.
pub fn inch_unit(text: &str) -> Option<Unit> {
    const INCH: f64 = 0.0254;
    let (name, scale) = match text {
        "in" => ("in", INCH),
        "mil" => ("mil", INCH * 1e-3),
        "uin" | "\u{b5}in" | "\u{3bc}in" => ("uin", INCH * 1e-6),
        _ => return None,
    };
    Some(Unit {
        name: name.to_string(),
        dim: Dim::LENGTH,
        scale,
        offset: 0.0,
    })
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod dialect_tests;

#[cfg(test)]
mod piece_tests;

#[cfg(test)]
pub(crate) fn read_text(text: &str, machine: &Machine) -> Result<Observations, ReadError> {
    read(
        text.as_bytes(),
        Path::new("test.csv"),
        machine,
        &ReadOptions::default(),
    )
}
