//! Measurement files (spec/data.md): point and length observations as CSV.
//!
//! Reading is strict: every data row becomes an observation or a located [`Problem`]; nothing is
//! dropped or guessed. Values come out columnar and in SI (m, rad, s, K, N), with observed errors
//! in the file's sign, which is the machine's task sign (spec/kinematics.md). Writing produces exactly
//! the format reading accepts, with every unit spelled out in the header.

use std::fmt;
use std::io;
use std::path::PathBuf;

use kin_compiler::ir::Var;
use thiserror::Error;

use kin_compiler::units::UnitError;

mod chunks;
pub mod noise;
pub mod ranges;
mod read;
mod write;

pub use chunks::{chunks, Chunks};
pub use read::{csv, inch_unit};
pub use read::{read, read_file};
pub use write::{measurements_json, write_file, write_lengths, write_points};

/// Names of the observed columns of a point file, in the order of [`PointData::observed`].
pub const OBSERVED: [&str; 6] = ["ex", "ey", "ez", "erx", "ery", "erz"];

/// Names of the columns of a target's position measured in an instrument's own frame, in the
/// order of [`Absolute::position`].
pub const MEASURED: [&str; 3] = ["px", "py", "pz"];

/// Names of the columns of a target frame's orientation measured in an instrument's own frame
/// (a rotation vector), in the order of [`Absolute::rotation`].
pub const MEASURED_ROTATION: [&str; 3] = ["prx", "pry", "prz"];

/// Names of the tool offset columns, in the order of [`Rows::tool_offset`].
pub(crate) const TOOL_OFFSET: [&str; 3] = ["tool_x", "tool_y", "tool_z"];

/// At most this many problems are kept per file: enough to show a pattern, few enough to read.
pub const MAX_PROBLEMS: usize = 20;

#[derive(Debug, Clone, Default)]
pub struct ReadOptions {
    /// Column names (without unit) to skip unread instead of rejecting them as unknown.
    pub ignore: Vec<String>,
    /// Read a file of poses to evaluate a model at: observed columns (`ex` … `erz`, `dL`) become
    /// optional, and a row may observe nothing (all NaN). A length file is then also recognised
    /// by its `_1`/`_2` axis columns.
    pub poses: bool,
    /// The cell separator: `b','`, `b';'` or `b'\t'`. `None` detects it from the header line
    /// (spec/data.md). With a separator other than a comma, numbers may use a decimal comma.
    pub delimiter: Option<u8>,
    /// Read a time series of inputs (a duty cycle for `kin predict`, `kin simulate --cycle`):
    /// as `poses`, and besides axis columns are optional (all or none) and `time` is required.
    pub series: bool,
    /// Threads reading a whole file's data lines ([`read`]); every core when `None`. The rows
    /// and problems are the same for any number.
    pub threads: Option<usize>,
}

// One per data file: the size difference (a point file's absolute positions) costs nothing
// worth a box.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Observations {
    Points(PointData),
    Lengths(LengthData),
}

/// One pose per row: axis positions and, where the file gives them, directions of approach.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Pose {
    /// One column per machine axis (indexed like `Machine::axes`), m or rad.
    pub axes: Vec<Vec<f64>>,
    /// One entry per machine axis: `Some` when the file has the `dir_` column, values ±1.
    pub dir: Vec<Option<Vec<f64>>>,
}

/// Labels grouping rows (`run`, `artifact`): an id per row into `labels`, in order of first
/// appearance.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Groups<I> {
    pub of_row: Vec<I>,
    pub labels: Vec<String>,
}

/// What every row carries besides its pose(s) and its observation.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rows {
    /// 1-based source line of each row, for messages about a row long after reading.
    pub line: Vec<usize>,
    /// Seconds; within one run non-decreasing.
    pub time: Option<Vec<f64>>,
    /// Without a `run` column the whole file is one run.
    pub run: Option<Groups<u32>>,
    /// `None` for a row whose `artifact` cell is empty: its placement is the nominal one.
    pub artifact: Option<Groups<Option<u32>>>,
    /// Index into `Machine::tools` per row; 0 without a `tool` column.
    pub tool: Vec<usize>,
    /// Per-row translation of the tool offset in m; a row of NaN keeps the declared offset.
    pub tool_offset: Option<[Vec<f64>; 3]>,
    /// One entry per machine input: `Some` when the file has the column; NaN where a cell is
    /// empty. Absolute temperatures are in K, temperature rises in K of difference.
    pub inputs: Vec<Option<Vec<f64>>>,
}

/// A point file (spec/data.md).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointData {
    pub rows: Rows,
    pub pose: Pose,
    /// `ex ey ez erx ery erz` (see [`OBSERVED`]), m and rad: `Some` when the file has the
    /// column, NaN where a cell is empty (not observed).
    pub observed: [Option<Vec<f64>>; 6],
    /// Absolute positions in an instrument's frame instead of errors (`px py pz`): the
    /// registration turns them into `observed` errors before a fit.
    pub absolute: Option<Absolute>,
}

/// Positions of targets on the tool (a tracker's reflector, a marker) measured in an
/// instrument's own frame, whose placement relative to the machine is not known (spec/data.md,
/// "Absolute positions"): what `kin fit` registers before it fits.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Absolute {
    /// `px py pz` (see [`MEASURED`]), m, one value per row.
    pub position: [Vec<f64>; 3],
    /// `prx pry prz` (see [`MEASURED_ROTATION`]), rad: the target frame's orientation as a
    /// rotation vector, when the instrument measures it (a 6-DoF probe, a marker cluster).
    pub rotation: Option<[Vec<f64>; 3]>,
    /// Which target each row measures (`target`); one unnamed target without the column.
    pub target: Groups<u32>,
}

/// A length file (spec/data.md).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LengthData {
    pub rows: Rows,
    /// The two ends, `_1` and `_2`.
    pub poses: [Pose; 2],
    /// Length error in m.
    pub dl: Vec<f64>,
}

impl Rows {
    pub fn len(&self) -> usize {
        self.line.len()
    }

    pub fn is_empty(&self) -> bool {
        self.line.is_empty()
    }

    /// The run a row belongs to: 0 when the file has no `run` column.
    pub fn run_of(&self, row: usize) -> u32 {
        self.run
            .as_ref()
            .and_then(|g| g.of_row.get(row).copied())
            .unwrap_or(0)
    }

    pub fn artifact_of(&self, row: usize) -> Option<u32> {
        self.artifact.as_ref()?.of_row.get(row).copied().flatten()
    }

    /// The row's own tool offset translation, when it overrides the declared one.
    pub fn tool_offset_of(&self, row: usize) -> Option<[f64; 3]> {
        let [x, y, z] = self.tool_offset.as_ref()?;
        let v = [*x.get(row)?, *y.get(row)?, *z.get(row)?];
        v.iter().all(|c| c.is_finite()).then_some(v)
    }

    fn value(&self, pose: &Pose, var: Var, row: usize) -> Option<f64> {
        match var {
            Var::Axis(a) => pose.axes.get(a)?.get(row).copied(),
            Var::Direction(a) => pose.dir.get(a)?.as_ref()?.get(row).copied(),
            Var::Input(i) => self.inputs.get(i)?.as_ref()?.get(row).copied(),
            Var::Time => self.time.as_ref()?.get(row).copied(),
            // A lag is a state the interpreter integrates, not something a file holds.
            Var::Lag(_) => None,
        }
    }
}

impl PointData {
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// A state variable of a row in SI; `None` when the file has no such column (or for a lag).
    /// An empty input cell gives `Some(NaN)`.
    pub fn value(&self, var: Var, row: usize) -> Option<f64> {
        self.rows.value(&self.pose, var, row)
    }
}

impl LengthData {
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// As [`PointData::value`], at end 0 (`_1`) or 1 (`_2`); inputs and time are shared.
    pub fn value(&self, var: Var, end: usize, row: usize) -> Option<f64> {
        self.rows.value(self.poses.get(end)?, var, row)
    }
}

fn pick<T: Clone>(v: &[T], rows: &[usize]) -> Vec<T> {
    rows.iter().filter_map(|&r| v.get(r).cloned()).collect()
}

impl Pose {
    fn select(&self, rows: &[usize]) -> Pose {
        Pose {
            axes: self.axes.iter().map(|c| pick(c, rows)).collect(),
            dir: self
                .dir
                .iter()
                .map(|c| c.as_ref().map(|c| pick(c, rows)))
                .collect(),
        }
    }
}

impl Rows {
    /// The rows `rows` (in that order); groups keep their labels so ids stay valid.
    pub fn select(&self, rows: &[usize]) -> Rows {
        Rows {
            line: pick(&self.line, rows),
            time: self.time.as_ref().map(|t| pick(t, rows)),
            run: self.run.as_ref().map(|g| Groups {
                of_row: pick(&g.of_row, rows),
                labels: g.labels.clone(),
            }),
            artifact: self.artifact.as_ref().map(|g| Groups {
                of_row: pick(&g.of_row, rows),
                labels: g.labels.clone(),
            }),
            tool: pick(&self.tool, rows),
            tool_offset: self
                .tool_offset
                .as_ref()
                .map(|[x, y, z]| [pick(x, rows), pick(y, rows), pick(z, rows)]),
            inputs: self
                .inputs
                .iter()
                .map(|c| c.as_ref().map(|c| pick(c, rows)))
                .collect(),
        }
    }
}

impl Observations {
    /// The observations of rows `rows` (indices into this file's rows), e.g. for a held-out
    /// split.
    pub fn select(&self, rows: &[usize]) -> Observations {
        match self {
            Observations::Points(p) => Observations::Points(PointData {
                rows: p.rows.select(rows),
                pose: p.pose.select(rows),
                observed: std::array::from_fn(|k| {
                    p.observed.get(k).cloned().flatten().map(|c| pick(&c, rows))
                }),
                absolute: p.absolute.as_ref().map(|a| Absolute {
                    position: std::array::from_fn(|k| pick(&a.position[k], rows)),
                    rotation: a
                        .rotation
                        .as_ref()
                        .map(|r| std::array::from_fn(|k| pick(&r[k], rows))),
                    target: Groups {
                        of_row: rows
                            .iter()
                            .map(|&r| a.target.of_row.get(r).copied().unwrap_or(0))
                            .collect(),
                        labels: a.target.labels.clone(),
                    },
                }),
            }),
            Observations::Lengths(l) => Observations::Lengths(LengthData {
                rows: l.rows.select(rows),
                poses: [l.poses[0].select(rows), l.poses[1].select(rows)],
                dl: pick(&l.dl, rows),
            }),
        }
    }

    pub fn rows(&self) -> &Rows {
        match self {
            Observations::Points(p) => &p.rows,
            Observations::Lengths(l) => &l.rows,
        }
    }

    pub fn len(&self) -> usize {
        self.rows().len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows().is_empty()
    }
}

/// One thing wrong with a measurement file. Lines and columns are 1-based; columns count
/// characters, not bytes, so they match what an editor shows.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum Problem {
    #[error("line {line}, column {column}: not valid UTF-8")]
    NotUtf8 { line: usize, column: usize },
    #[error("no header row: the file holds only comments and blank lines")]
    NoHeader,
    #[error(
        "line {line}, column {column}: the quote opening this cell is not closed on its line \
         (a quoted cell ends on its line; a quote inside it is written twice, `\"\"`)"
    )]
    UnclosedQuote { line: usize, column: usize },
    #[error(
        "line {line}, column {column}: text after the closing quote of a cell: expected the \
         separator {separator} or the end of the line"
    )]
    AfterQuote {
        line: usize,
        column: usize,
        separator: &'static str,
    },
    #[error("no data rows after the header")]
    NoRows,
    #[error("line {line}, column {column}: empty column name")]
    EmptyName { line: usize, column: usize },
    #[error("line {line}, column {column}: bad column name `{text}`: {reason}")]
    BadName {
        line: usize,
        column: usize,
        text: String,
        reason: &'static str,
    },
    #[error(
        "line {line}, column {column}: unknown column `{name}`{}",
        hint_text(hint)
    )]
    UnknownColumn {
        line: usize,
        column: usize,
        name: String,
        hint: Option<String>,
    },
    #[error("line {line}, column {column}: duplicate column `{name}` (first at column {first})")]
    DuplicateColumn {
        line: usize,
        column: usize,
        name: String,
        first: usize,
    },
    #[error("line {line}, column {column}: column `{name}`: {error}")]
    BadUnit {
        line: usize,
        column: usize,
        name: String,
        error: UnitError,
    },
    #[error("line {line}, column {column}: column `{name}` holds labels and takes no unit")]
    UnitNotAllowed {
        line: usize,
        column: usize,
        name: String,
    },
    #[error(
        "line {line}, column {column}: column `{name}` is given in `{unit}`, a {found}, \
         but `{name}` is a {expected}"
    )]
    WrongDimension {
        line: usize,
        column: usize,
        name: String,
        unit: String,
        found: String,
        expected: String,
    },
    #[error("missing required column{}: {}", plural(names.len()), names.join(", "))]
    MissingColumns { names: Vec<String> },
    #[error(
        "no observed column: a point file needs at least one of ex, ey, ez, erx, ery, erz, or \
         the absolute positions px, py, pz (a length file has dL)"
    )]
    NoObservedColumn,
    #[error("tool offset columns come as all of tool_x, tool_y, tool_z; missing: {}", missing.join(", "))]
    IncompleteToolColumns { missing: Vec<String> },
    #[error("measured position columns come as all of px, py, pz; missing: {}", missing.join(", "))]
    IncompleteMeasuredColumns { missing: Vec<String> },
    #[error("measured orientation columns come as all of prx, pry, prz, with px, py, pz; missing: {}", missing.join(", "))]
    IncompleteOrientationColumns { missing: Vec<String> },
    #[error(
        "the file holds both errors ({errors}) and absolute positions (px, py, pz): a file is \
         one or the other"
    )]
    ErrorsAndPositions { errors: String },
    #[error("`{column}` is not read in a file of absolute positions (px, py, pz): {reason}")]
    NotWithPositions {
        column: String,
        reason: &'static str,
    },
    #[error("line {line}: {found} cell{}, but the header has {expected} column{}", plural(*found), plural(*expected))]
    CellCount {
        line: usize,
        found: usize,
        expected: usize,
    },
    #[error(
        "line {line}, column {column} (`{name}`): {}: expected {expected}",
        quoted(text)
    )]
    BadCell {
        line: usize,
        column: usize,
        name: String,
        text: String,
        expected: String,
    },
    #[error(
        "line {line}, column {column} (`{name}`): `{text}` is beyond the largest plausible \
         {what}, ±{limit}"
    )]
    Implausible {
        line: usize,
        column: usize,
        name: String,
        text: String,
        what: &'static str,
        /// The bound in the column's unit.
        limit: String,
    },
    #[error(
        "line {line}, column {column} (`{name}`): `{text}` is not zero but below the smallest \
         meaningful error, ±{limit} (its square underflows a number)"
    )]
    Negligible {
        line: usize,
        column: usize,
        name: String,
        text: String,
        /// The bound in the column's unit.
        limit: String,
    },
    #[error(
        "line {line}, column {column} (`{name}`): `{text}` is below absolute zero (an absolute temperature is at least −273.15 °C)"
    )]
    BelowAbsoluteZero {
        line: usize,
        column: usize,
        name: String,
        text: String,
    },
    #[error(
        "line {line}, column {column} (`{name}`): unknown tool `{text}`; declared tools: {}",
        declared.join(", ")
    )]
    UnknownTool {
        line: usize,
        column: usize,
        name: String,
        text: String,
        declared: Vec<String>,
    },
    #[error("line {line}: nothing observed: {} all empty", columns.join(", "))]
    NothingObserved { line: usize, columns: Vec<String> },
    #[error(
        "line {line}: tool_x, tool_y, tool_z are given together or all left empty; empty here: {}",
        empty.join(", ")
    )]
    IncompleteToolOffset { line: usize, empty: Vec<String> },
    #[error(
        "line {line}: time {time} {unit} is before {previous} {unit} at line {previous_line}{}: \
         rows of one run must be in time order",
        run.as_ref().map(|r| format!(" (run `{r}`)")).unwrap_or_default()
    )]
    TimeOrder {
        line: usize,
        previous_line: usize,
        time: f64,
        previous: f64,
        unit: String,
        run: Option<String>,
    },
}

impl Problem {
    /// Where in the file the problem is, as data: the 1-based line and, unless the problem is
    /// the whole row's, the column (in characters); `None` for a problem of the whole file. The
    /// message says the same in words (`line 12, column 3: …`).
    pub fn location(&self) -> Option<(usize, Option<usize>)> {
        use Problem::*;
        match self {
            NotUtf8 { line, column }
            | UnclosedQuote { line, column }
            | AfterQuote { line, column, .. }
            | EmptyName { line, column }
            | BadName { line, column, .. }
            | UnknownColumn { line, column, .. }
            | DuplicateColumn { line, column, .. }
            | BadUnit { line, column, .. }
            | UnitNotAllowed { line, column, .. }
            | WrongDimension { line, column, .. }
            | BadCell { line, column, .. }
            | Implausible { line, column, .. }
            | Negligible { line, column, .. }
            | BelowAbsoluteZero { line, column, .. }
            | UnknownTool { line, column, .. } => Some((*line, Some(*column))),
            CellCount { line, .. }
            | NothingObserved { line, .. }
            | IncompleteToolOffset { line, .. }
            | TimeOrder { line, .. } => Some((*line, None)),
            NoHeader
            | NoRows
            | MissingColumns { .. }
            | NoObservedColumn
            | IncompleteToolColumns { .. }
            | IncompleteMeasuredColumns { .. }
            | IncompleteOrientationColumns { .. }
            | ErrorsAndPositions { .. }
            | NotWithPositions { .. } => None,
        }
    }
}

fn quoted(text: &str) -> String {
    if text.is_empty() {
        "empty cell".to_string()
    } else {
        format!("`{text}`")
    }
}

fn hint_text(hint: &Option<String>) -> String {
    hint.as_ref().map(|h| format!(" ({h})")).unwrap_or_default()
}

fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

#[derive(Debug, Error)]
pub enum ReadError {
    #[error("cannot read `{}`: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error(
        "cannot read `{}`: it is not a regular file and holds more than {} MiB, the most kin \
         reads from a pipe or a device",
        path.display(),
        limit >> 20
    )]
    TooLarge { path: PathBuf, limit: u64 },
    #[error("{}", Listing { path, problems, omitted: *omitted })]
    Invalid {
        path: PathBuf,
        /// At most [`MAX_PROBLEMS`], in file order.
        problems: Vec<Problem>,
        /// How many more were found but not kept.
        omitted: usize,
    },
}

struct Listing<'a> {
    path: &'a PathBuf,
    problems: &'a [Problem],
    omitted: usize,
}

impl fmt::Display for Listing<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let total = self.problems.len() + self.omitted;
        write!(
            f,
            "`{}`: {total} problem{}",
            self.path.display(),
            plural(total)
        )?;
        for p in self.problems {
            write!(f, "\n  {p}")?;
        }
        if self.omitted > 0 {
            write!(f, "\n  … and {} more", self.omitted)?;
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Default)]
pub struct WriteOptions {
    /// Written first, each line prefixed with `# `.
    pub comments: Vec<String>,
    /// Units for positions, errors, time and tool offsets; `None` takes the machine's own.
    /// Inputs are always written in their declared unit.
    pub units: Option<kin_compiler::ir::DisplayUnits>,
    /// Written after the observed columns: values that are not observations, such as the
    /// standard uncertainties `kin eval` adds. Reading such a file back needs them ignored.
    pub extra: Vec<ExtraColumn>,
}

/// A column of [`WriteOptions::extra`]: one value per row, SI, written in the unit of the
/// quantity it is (empty cells for NaN).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraColumn {
    pub name: String,
    pub quantity: ExtraQuantity,
    pub values: Vec<f64>,
}

/// What an [`ExtraColumn`] holds, for its unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExtraQuantity {
    /// A position or length error (the error unit).
    Error,
    /// A rotation error (the tilt unit).
    Tilt,
    /// A position or coordinate (the length unit), e.g. the corrected coordinates of
    /// `kin correct`.
    Length,
    /// A plain number (unit `1`), e.g. a direction cosine.
    Ratio,
    /// An angle (the angle unit), e.g. a nominal orientation.
    Angle,
}

#[derive(Debug, Error)]
pub enum WriteError {
    #[error("cannot write: {0}")]
    Io(#[from] io::Error),
    #[error("cannot write `{}`: {source}", path.display())]
    Create {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("nothing to write: no rows")]
    NoRows,
    #[error("a point file needs at least one observed column (ex … erz)")]
    NoObservedColumn,
    #[error("column `{column}` has {found} values for {rows} rows")]
    RowCount {
        column: String,
        found: usize,
        rows: usize,
    },
    #[error("the data has {found} axis columns for a machine with {expected} axes")]
    AxisCount { found: usize, expected: usize },
    #[error("the data has {found} input entries for a machine with {expected} inputs")]
    InputCount { found: usize, expected: usize },
    #[error("row {row}, column `{column}`: {value} cannot be written: expected {expected}")]
    Value {
        row: usize,
        column: String,
        value: f64,
        expected: &'static str,
    },
    #[error(
        "column `{column}`: label `{label}` cannot be written: labels are non-empty, \
         hold no comma or line break, and have no surrounding spaces"
    )]
    Label { column: String, label: String },
    #[error("row {row}: label id {id} of column `{column}` has no label")]
    LabelId { row: usize, column: String, id: u32 },
    #[error("row {row}: tool {index} is not declared (the machine has {count})")]
    Tool {
        row: usize,
        index: usize,
        count: usize,
    },
    #[error("row {row}: nothing observed (every observed value is NaN)")]
    NothingObserved { row: usize },
    #[error("row {row}: tool offset must be given for all of x, y, z or none")]
    IncompleteToolOffset { row: usize },
    #[error("unit `{unit}` for {quantity} is a {found}, expected a {expected}")]
    WrongDimension {
        quantity: &'static str,
        unit: String,
        found: String,
        expected: String,
    },
}

#[cfg(test)]
pub(crate) mod testing {
    use kin_compiler::ir::{
        Axis, DisplayUnits, Element, FrameKind, Input, JointKind, Machine, Shape, Task, Tool,
    };
    use kin_compiler::units::Unit;

    fn unit(text: &str) -> Unit {
        Unit::parse(text).unwrap_or_else(|e| panic!("{text}: {e}"))
    }

    fn axis(name: &str, kind: JointKind, direction: [f64; 3]) -> Axis {
        Axis {
            name: name.into(),
            kind,
            direction,
            range: [-1.0, 1.0],
            continuous: false,
        }
    }

    fn element(axis: usize) -> Element {
        Element {
            axis,
            frame: FrameKind::Moving,
            shape: Shape::default(),
        }
    }

    /// X Y Z prismatic and a revolute C; an absolute and a relative temperature and a load;
    /// two tools. Units mm, deg, um, urad, s.
    pub fn machine() -> Machine {
        Machine {
            name: "test".into(),
            task: Task::Measure,
            gravity: kin_compiler::ir::GRAVITY,
            axes: vec![
                axis("X", JointKind::Prismatic, [1.0, 0.0, 0.0]),
                axis("Y", JointKind::Prismatic, [0.0, 1.0, 0.0]),
                axis("Z", JointKind::Prismatic, [0.0, 0.0, 1.0]),
                axis("C", JointKind::Revolute, [0.0, 0.0, 1.0]),
            ],
            inputs: vec![
                Input {
                    name: "T_spindle".into(),
                    unit: unit("degC"),
                    absolute: true,
                    range: None,
                },
                Input {
                    name: "T_x".into(),
                    unit: unit("degC").as_difference(),
                    absolute: false,
                    range: None,
                },
                Input {
                    name: "load".into(),
                    unit: unit("kN"),
                    absolute: false,
                    range: None,
                },
            ],
            lags: vec![],
            nonlinear: vec![],
            tool_chain: vec![element(1), element(0), element(2)],
            workpiece_chain: vec![element(3)],
            tools: vec![
                Tool {
                    name: "probe".into(),
                    offset: Shape {
                        translation: [0.0, 0.0, -0.15],
                        rotation: [0.0; 3],
                    },
                },
                Tool {
                    name: "star".into(),
                    offset: Shape::default(),
                },
            ],
            workpiece: Shape::default(),
            errors: vec![],
            coefficients: vec![],
            beta: vec![],
            units: DisplayUnits {
                length: unit("mm"),
                angle: unit("deg"),
                error: unit("um"),
                tilt: unit("urad"),
                time: unit("s"),
                temperature: unit("degC"),
                force: unit("N"),
            },
        }
    }
}

#[cfg(test)]
mod location_tests {
    use super::Problem;

    /// The place given as data is the one the message states in words.
    #[test]
    fn a_problems_location_is_what_its_message_says() {
        let cases = [
            Problem::NotUtf8 { line: 4, column: 7 },
            Problem::EmptyName { line: 1, column: 3 },
            Problem::CellCount {
                line: 12,
                found: 3,
                expected: 4,
            },
            Problem::NothingObserved {
                line: 9,
                columns: vec!["ex".into()],
            },
            Problem::NoRows,
            Problem::MissingColumns {
                names: vec!["X".into()],
            },
        ];
        for p in cases {
            let text = p.to_string();
            match p.location() {
                Some((line, Some(column))) => {
                    assert!(
                        text.starts_with(&format!("line {line}, column {column}")),
                        "{text}"
                    )
                }
                Some((line, None)) => {
                    assert!(text.starts_with(&format!("line {line}: ")), "{text}")
                }
                None => assert!(!text.starts_with("line "), "{text}"),
            }
        }
    }
}
