//! The writer: the exact format the reader accepts, every numeric column with its unit in the
//! header so the file stays readable if the machine's defaults change. Everything is checked
//! before the first byte is written, so a failed write never leaves half a file behind it.

use std::fmt::Write as _;
use std::io::{BufWriter, Write};
use std::path::Path;

use kin_compiler::ir::{DisplayUnits, JointKind, Machine};
use kin_compiler::units::{Dim, Unit};

use super::{
    ExtraQuantity, LengthData, Observations, PointData, Pose, Rows, WriteError, WriteOptions,
    OBSERVED, TOOL_OFFSET,
};

/// Writes a point file (spec/data.md).
pub fn write_points<W: Write>(
    out: W,
    machine: &Machine,
    data: &PointData,
    options: &WriteOptions,
) -> Result<(), WriteError> {
    let columns = point_columns(machine, data, options)?;
    emit(out, &columns, data.rows.len(), options)
}

/// The columns of a point file, checked: what the reader would refuse is an error here.
fn point_columns<'a>(
    machine: &'a Machine,
    data: &'a PointData,
    options: &'a WriteOptions,
) -> Result<Vec<Column<'a>>, WriteError> {
    let units = units(machine, options)?;
    let n = data.rows.len();
    let mut columns = pose_columns(machine, &units, &data.pose, Kind::Point)?;
    columns.extend(row_columns(machine, &units, &data.rows)?);
    let mut any_observed = false;
    for (k, (name, values)) in OBSERVED.iter().zip(&data.observed).enumerate() {
        let Some(values) = values else { continue };
        any_observed = true;
        let unit = if k < 3 { &units.error } else { &units.tilt };
        columns.push(Column::number(name, unit, values, false));
    }
    if !any_observed {
        return Err(WriteError::NoObservedColumn);
    }
    columns.extend(extra_columns(&units, options));
    check(&columns, n)?;
    for row in 0..n {
        let nothing = data
            .observed
            .iter()
            .flatten()
            .all(|v| v.get(row).is_none_or(|x| x.is_nan()));
        if nothing {
            return Err(WriteError::NothingObserved { row });
        }
    }
    Ok(columns)
}

/// Writes a length file (spec/data.md).
pub fn write_lengths<W: Write>(
    out: W,
    machine: &Machine,
    data: &LengthData,
    options: &WriteOptions,
) -> Result<(), WriteError> {
    let columns = length_columns(machine, data, options)?;
    emit(out, &columns, data.rows.len(), options)
}

/// The columns of a length file, checked.
fn length_columns<'a>(
    machine: &'a Machine,
    data: &'a LengthData,
    options: &'a WriteOptions,
) -> Result<Vec<Column<'a>>, WriteError> {
    let units = units(machine, options)?;
    let n = data.rows.len();
    let [first, second] = &data.poses;
    let mut columns = pose_columns(machine, &units, first, Kind::End(1))?;
    columns.extend(pose_columns(machine, &units, second, Kind::End(2))?);
    columns.extend(row_columns(machine, &units, &data.rows)?);
    columns.push(Column::number("dL", &units.error, &data.dl, true));
    columns.extend(extra_columns(&units, options));
    check(&columns, n)?;
    Ok(columns)
}

fn extra_columns<'a>(
    units: &DisplayUnits,
    options: &'a WriteOptions,
) -> impl Iterator<Item = Column<'a>> + 'a {
    let (error, tilt, length, angle) = (
        units.error.clone(),
        units.tilt.clone(),
        units.length.clone(),
        units.angle.clone(),
    );
    let ratio = Unit::dimensionless();
    options.extra.iter().map(move |c| {
        let unit = match c.quantity {
            ExtraQuantity::Error => &error,
            ExtraQuantity::Tilt => &tilt,
            ExtraQuantity::Length => &length,
            ExtraQuantity::Ratio => &ratio,
            ExtraQuantity::Angle => &angle,
        };
        Column::number(&c.name, unit, &c.values, false)
    })
}

/// Writes either kind of file to `path`, replacing it atomically ([`crate::output::replace`]).
pub fn write_file(
    path: &Path,
    machine: &Machine,
    data: &Observations,
    options: &WriteOptions,
) -> Result<(), WriteError> {
    // Build nothing on disk until the data is known to be writable.
    let mut buffer = Vec::new();
    match data {
        Observations::Points(p) => write_points(&mut buffer, machine, p, options)?,
        Observations::Lengths(l) => write_lengths(&mut buffer, machine, l, options)?,
    }
    crate::output::replace(path, &buffer).map_err(|source| WriteError::Create {
        path: path.to_path_buf(),
        source,
    })
}

/// The file [`write_file`] would write, as the JSON document of spec/json.md ("Measurements"):
/// its comment lines, its columns with their units, and its rows with numbers as numbers (the
/// values the file's digits read back to), labels (tool, run, artifact) as strings and an
/// empty cell as `null`. Built from the same checked columns as the file, so the two agree.
pub fn measurements_json(
    machine: &Machine,
    data: &Observations,
    options: &WriteOptions,
) -> Result<serde_json::Value, WriteError> {
    use serde_json::{json, Value};
    let (columns, n) = match data {
        Observations::Points(p) => (point_columns(machine, p, options)?, p.rows.len()),
        Observations::Lengths(l) => (length_columns(machine, l, options)?, l.rows.len()),
    };
    let comments: Vec<Value> = options
        .comments
        .iter()
        .flat_map(|c| c.split('\n'))
        .map(|line| Value::from(line.trim()))
        .collect();
    let header: Vec<Value> = columns
        .iter()
        .map(|c| match &c.cells {
            Cells::Number { unit, .. } => json!({ "name": c.name, "unit": unit.name }),
            _ => json!({ "name": c.name, "unit": null }),
        })
        .collect();
    let rows: Vec<Value> = (0..n)
        .map(|row| Value::Array(columns.iter().map(|c| c.json_cell(row)).collect()))
        .collect();
    Ok(json!({ "version": 1, "comments": comments, "columns": header, "rows": rows }))
}

#[derive(Clone, Copy)]
enum Kind {
    Point,
    End(u8),
}

enum Cells<'a> {
    Number {
        unit: Unit,
        values: &'a [f64],
        /// An empty cell is refused on reading, so NaN cannot be written here.
        required: bool,
    },
    Dir(&'a [f64]),
    Tool(&'a [usize], Vec<&'a str>),
    Label {
        of_row: LabelIds<'a>,
        labels: &'a [String],
    },
}

enum LabelIds<'a> {
    Run(&'a [u32]),
    Artifact(&'a [Option<u32>]),
}

struct Column<'a> {
    name: String,
    cells: Cells<'a>,
}

impl<'a> Column<'a> {
    fn number(name: &str, unit: &Unit, values: &'a [f64], required: bool) -> Self {
        Column {
            name: name.to_string(),
            cells: Cells::Number {
                unit: unit.as_difference(),
                values,
                required,
            },
        }
    }

    fn header(&self) -> String {
        match &self.cells {
            Cells::Number { unit, .. } => format!("{}[{}]", self.name, unit.name),
            _ => self.name.clone(),
        }
    }

    fn len(&self) -> usize {
        match &self.cells {
            Cells::Number { values, .. } | Cells::Dir(values) => values.len(),
            Cells::Tool(tools, _) => tools.len(),
            Cells::Label { of_row, .. } => match of_row {
                LabelIds::Run(ids) => ids.len(),
                LabelIds::Artifact(ids) => ids.len(),
            },
        }
    }

    /// Appends row `row`'s cell; `check` has already made sure every value is writable.
    fn cell(&self, row: usize, buf: &mut String) {
        match &self.cells {
            Cells::Number { unit, values, .. } => {
                if let Some(v) = values.get(row).filter(|v| !v.is_nan()) {
                    push_number(buf, unit.from_si(*v));
                }
            }
            Cells::Dir(values) => {
                buf.push_str(match values.get(row) {
                    Some(v) if *v < 0.0 => "-1",
                    _ => "+1",
                });
            }
            Cells::Tool(tools, names) => {
                if let Some(name) = tools.get(row).and_then(|&t| names.get(t)) {
                    buf.push_str(name);
                }
            }
            Cells::Label { of_row, labels } => {
                let id = match of_row {
                    LabelIds::Run(ids) => ids.get(row).copied(),
                    LabelIds::Artifact(ids) => ids.get(row).copied().flatten(),
                };
                if let Some(label) = id.and_then(|i| labels.get(i as usize)) {
                    buf.push_str(label);
                }
            }
        }
    }
}

impl Column<'_> {
    /// Row `row`'s cell as a JSON value: what [`Column::cell`] writes, typed.
    fn json_cell(&self, row: usize) -> serde_json::Value {
        use serde_json::Value;
        // −0 as 0, as the file writes it ([`push_number`]).
        let number = |v: f64| {
            let v = if v == 0.0 { 0.0 } else { v };
            serde_json::Number::from_f64(v).map_or(Value::Null, Value::Number)
        };
        match &self.cells {
            Cells::Number { unit, values, .. } => values
                .get(row)
                .filter(|v| !v.is_nan())
                .map_or(Value::Null, |v| number(unit.from_si(*v))),
            Cells::Dir(values) => number(match values.get(row) {
                Some(v) if *v < 0.0 => -1.0,
                _ => 1.0,
            }),
            Cells::Tool(..) | Cells::Label { .. } => {
                let mut text = String::new();
                self.cell(row, &mut text);
                if text.is_empty() {
                    Value::Null
                } else {
                    Value::String(text)
                }
            }
        }
    }
}

/// Shortest text that reads back to the same `f64`; exponent form only where plain digits
/// would run long.
fn push_number(buf: &mut String, v: f64) {
    // −0 (a product of a zero and a negative number) is written `0`: the same value, and a
    // `-0` in a file reads as a sign that means something.
    let v = if v == 0.0 { 0.0 } else { v };
    let a = v.abs();
    // Writing into a `String` cannot fail.
    let _ = if a == 0.0 || (1e-5..1e15).contains(&a) {
        write!(buf, "{v}")
    } else {
        write!(buf, "{v:e}")
    };
}

fn units(machine: &Machine, options: &WriteOptions) -> Result<DisplayUnits, WriteError> {
    let units = options
        .units
        .clone()
        .unwrap_or_else(|| machine.units.clone());
    let expect = [
        ("positions", &units.length, Dim::LENGTH),
        ("angles", &units.angle, Dim::ANGLE),
        ("errors", &units.error, Dim::LENGTH),
        ("tilts", &units.tilt, Dim::ANGLE),
        ("time", &units.time, Dim::TIME),
    ];
    for (quantity, unit, dim) in expect {
        if unit.dim != dim {
            return Err(WriteError::WrongDimension {
                quantity,
                unit: unit.name.clone(),
                found: unit.dim.describe(),
                expected: dim.describe(),
            });
        }
    }
    Ok(units)
}

fn pose_columns<'a>(
    machine: &Machine,
    units: &DisplayUnits,
    pose: &'a Pose,
    kind: Kind,
) -> Result<Vec<Column<'a>>, WriteError> {
    let expected = machine.axes.len();
    if pose.axes.len() != expected {
        return Err(WriteError::AxisCount {
            found: pose.axes.len(),
            expected,
        });
    }
    // An empty `dir` list means no direction columns at all.
    if !pose.dir.is_empty() && pose.dir.len() != expected {
        return Err(WriteError::AxisCount {
            found: pose.dir.len(),
            expected,
        });
    }
    let name = |axis: &str| match kind {
        Kind::Point => axis.to_string(),
        Kind::End(e) => format!("{axis}_{e}"),
    };
    let mut columns = Vec::new();
    for (axis, values) in machine.axes.iter().zip(&pose.axes) {
        let unit = match axis.kind {
            JointKind::Prismatic => &units.length,
            JointKind::Revolute => &units.angle,
        };
        columns.push(Column::number(&name(&axis.name), unit, values, true));
    }
    for (axis, dir) in machine.axes.iter().zip(&pose.dir) {
        if let Some(values) = dir {
            columns.push(Column {
                name: format!("dir_{}", name(&axis.name)),
                cells: Cells::Dir(values),
            });
        }
    }
    Ok(columns)
}

fn row_columns<'a>(
    machine: &'a Machine,
    units: &DisplayUnits,
    rows: &'a Rows,
) -> Result<Vec<Column<'a>>, WriteError> {
    if rows.inputs.len() > machine.inputs.len() {
        return Err(WriteError::InputCount {
            found: rows.inputs.len(),
            expected: machine.inputs.len(),
        });
    }
    let mut columns = Vec::new();
    for (input, values) in machine.inputs.iter().zip(&rows.inputs) {
        let Some(values) = values else { continue };
        // Absolute temperatures go out with their offset, so a `degC` column reads back as such.
        let unit = if input.absolute {
            input.unit.as_absolute()
        } else {
            input.unit.as_difference()
        };
        columns.push(Column {
            name: input.name.clone(),
            cells: Cells::Number {
                unit,
                values,
                required: false,
            },
        });
    }
    if let Some(time) = &rows.time {
        columns.push(Column::number("time", &units.time, time, true));
    }
    if let Some(run) = &rows.run {
        columns.push(Column {
            name: "run".into(),
            cells: Cells::Label {
                of_row: LabelIds::Run(&run.of_row),
                labels: &run.labels,
            },
        });
    }
    // The reader gives tool 0 to every row of a file without the column.
    if rows.tool.iter().any(|&t| t != 0) {
        columns.push(Column {
            name: "tool".into(),
            cells: Cells::Tool(
                &rows.tool,
                machine.tools.iter().map(|t| t.name.as_str()).collect(),
            ),
        });
    }
    if let Some(offsets) = &rows.tool_offset {
        for (name, values) in TOOL_OFFSET.iter().zip(offsets) {
            columns.push(Column::number(name, &units.length, values, false));
        }
    }
    if let Some(artifact) = &rows.artifact {
        columns.push(Column {
            name: "artifact".into(),
            cells: Cells::Label {
                of_row: LabelIds::Artifact(&artifact.of_row),
                labels: &artifact.labels,
            },
        });
    }
    Ok(columns)
}

/// What the reader would refuse, found before anything is written.
fn check(columns: &[Column], n: usize) -> Result<(), WriteError> {
    if n == 0 {
        return Err(WriteError::NoRows);
    }
    for (index, column) in columns.iter().enumerate() {
        if column.len() != n {
            return Err(WriteError::RowCount {
                column: column.name.clone(),
                found: column.len(),
                rows: n,
            });
        }
        let value_error = |row, value, expected| WriteError::Value {
            row,
            column: column.name.clone(),
            value,
            expected,
        };
        match &column.cells {
            Cells::Number {
                unit,
                values,
                required,
            } => {
                for (row, &v) in values.iter().enumerate() {
                    if v.is_nan() && !required {
                        continue;
                    }
                    if !unit.from_si(v).is_finite() {
                        return Err(value_error(row, v, "a finite number"));
                    }
                }
            }
            Cells::Dir(values) => {
                if let Some((row, &v)) = values
                    .iter()
                    .enumerate()
                    .find(|(_, &v)| v != 1.0 && v != -1.0)
                {
                    return Err(value_error(row, v, "+1 or -1"));
                }
            }
            Cells::Tool(tools, names) => {
                if let Some((row, &t)) = tools.iter().enumerate().find(|(_, &t)| t >= names.len()) {
                    return Err(WriteError::Tool {
                        row,
                        index: t,
                        count: names.len(),
                    });
                }
                for name in names {
                    check_label(&column.name, name, index == 0)?;
                }
            }
            Cells::Label { of_row, labels } => {
                let ids: Vec<(usize, u32)> = match of_row {
                    LabelIds::Run(ids) => ids.iter().copied().enumerate().collect(),
                    LabelIds::Artifact(ids) => ids
                        .iter()
                        .enumerate()
                        .filter_map(|(r, id)| id.map(|id| (r, id)))
                        .collect(),
                };
                if let Some(&(row, id)) = ids.iter().find(|(_, id)| *id as usize >= labels.len()) {
                    return Err(WriteError::LabelId {
                        row,
                        column: column.name.clone(),
                        id,
                    });
                }
                for label in labels.iter() {
                    check_label(&column.name, label, index == 0)?;
                }
            }
        }
    }
    let offsets: Vec<&[f64]> = columns
        .iter()
        .filter(|c| TOOL_OFFSET.contains(&c.name.as_str()))
        .filter_map(|c| match &c.cells {
            Cells::Number { values, .. } => Some(*values),
            _ => None,
        })
        .collect();
    if let [x, y, z] = offsets.as_slice() {
        for row in 0..n {
            let nan = [x, y, z].map(|c| c.get(row).is_none_or(|v| v.is_nan()));
            if nan.iter().any(|&b| b) && !nan.iter().all(|&b| b) {
                return Err(WriteError::IncompleteToolOffset { row });
            }
        }
    }
    Ok(())
}

/// A label must read back as itself: the reader splits on commas and lines, trims cells, takes
/// an empty cell for "none" and a line starting with `#` for a comment.
fn check_label(column: &str, label: &str, first_column: bool) -> Result<(), WriteError> {
    let unreadable = label.is_empty()
        || label.trim() != label
        || label.contains([',', '\n', '\r'])
        || (first_column && label.starts_with('#'));
    if !unreadable {
        Ok(())
    } else {
        Err(WriteError::Label {
            column: column.to_string(),
            label: label.to_string(),
        })
    }
}

fn emit<W: Write>(
    out: W,
    columns: &[Column],
    n: usize,
    options: &WriteOptions,
) -> Result<(), WriteError> {
    let mut out = BufWriter::new(out);
    for comment in &options.comments {
        for line in comment.split('\n') {
            writeln!(out, "# {}", line.trim_end_matches('\r'))?;
        }
    }
    let header: Vec<String> = columns.iter().map(Column::header).collect();
    writeln!(out, "{}", header.join(","))?;
    let mut buf = String::new();
    for row in 0..n {
        buf.clear();
        for (i, column) in columns.iter().enumerate() {
            if i > 0 {
                buf.push(',');
            }
            column.cell(row, &mut buf);
        }
        buf.push('\n');
        out.write_all(buf.as_bytes())?;
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests;
