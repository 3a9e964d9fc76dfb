//! ISO 230-2 evaluation of a bidirectional positioning run along one axis: per target position
//! the mean deviations and their spread in each direction of approach, the reversal value, and
//! the axis figures E, M, B, R and A (spec/iso230-2.md states the definitions).
//!
//! The run file is a small CSV of its own (`target`, `deviation`, `direction`, `cycle`), read with
//! the same CSV front end as measurement files, so quoting, `;`, decimal commas and inch units
//! work the same way.

use std::fmt;
use std::path::{Path, PathBuf};

use kin_compiler::units::{Dim, Unit};
use serde::Serialize;
use thiserror::Error;

use kin_data::data::csv::{self, Cell, Dialect};

/// At most this many problems are listed per file.
pub(crate) const MAX_PROBLEMS: usize = 20;

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

#[derive(Debug, Error)]
pub enum Iso2302Error {
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

pub(crate) struct Listing<'a> {
    pub(crate) path: &'a Path,
    pub(crate) problems: &'a [RunProblem],
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

/// One approach to a target: where, from which side, in which cycle, and the deviation measured
/// there (actual − target), in m.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub target: f64,
    pub up: bool,
    pub cycle: String,
    pub deviation: f64,
    pub line: usize,
}

/// A run as read: its samples, and the units the file used (for printing in the same units).
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub samples: Vec<Sample>,
    pub target_unit: Unit,
    pub deviation_unit: Unit,
}

/// The figures at one target position, in m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetFigures {
    pub target: f64,
    /// Approaches in the positive (↑) and negative (↓) direction.
    pub n_up: usize,
    pub n_down: usize,
    /// Mean unidirectional positional deviations x̄↑, x̄↓ and the bidirectional mean x̄.
    pub mean_up: f64,
    pub mean_down: f64,
    pub mean: f64,
    /// Estimators of the unidirectional standard uncertainty s↑, s↓ (n − 1 in the denominator).
    pub s_up: f64,
    pub s_down: f64,
    /// Reversal value B_i = x̄↑ − x̄↓.
    pub reversal: f64,
    /// Unidirectional repeatabilities R↑ = 4 s↑, R↓ = 4 s↓, and the bidirectional one
    /// R = max(2 s↑ + 2 s↓ + |B_i|, R↑, R↓).
    pub r_up: f64,
    pub r_down: f64,
    pub r: f64,
}

/// The axis figures, in m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisFigures {
    /// Systematic positioning error: range of x̄↑ (E↑), of x̄↓ (E↓), of both together (E).
    pub e_up: f64,
    pub e_down: f64,
    pub e: f64,
    /// Range of the mean bidirectional positional deviations x̄.
    pub m: f64,
    /// Largest |B_i|, and the mean of the B_i.
    pub b: f64,
    pub b_mean: f64,
    /// Largest R↑_i, R↓_i and R_i.
    pub r_up: f64,
    pub r_down: f64,
    pub r: f64,
    /// Accuracy: range of x̄ ± 2s in one direction (A↑, A↓) or both (A).
    pub a_up: f64,
    pub a_down: f64,
    pub a: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    /// In increasing target order.
    pub targets: Vec<TargetFigures>,
    pub axis: AxisFigures,
    /// The largest number of approaches per target and direction (ISO 230-2 asks for 5).
    pub cycles: usize,
}

/// Reads a run file from disk.
pub fn read_file(path: &Path) -> Result<Run, Iso2302Error> {
    let bytes = read_bytes(path).map_err(|source| Iso2302Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read(&bytes, path)
}

/// A standard test's file from disk (ISO 230-2 and 230-4 alike): whole when it is a regular
/// file, at most `MAX_STREAM_BYTES` otherwise (a pipe or device could be endless).
pub(crate) fn read_bytes(path: &Path) -> Result<Vec<u8>, std::io::Error> {
    use kin_data::bounded_read::{read_unless_regular, BoundedReadError, MAX_STREAM_BYTES};
    read_unless_regular(path, MAX_STREAM_BYTES).map_err(|e| match e {
        BoundedReadError::Io(source) => source,
        BoundedReadError::TooLarge { limit } => std::io::Error::other(format!(
            "not a regular file and longer than {} MiB",
            limit >> 20
        )),
    })
}

/// A test file's text without its byte-order mark, or the line of the first byte that is not
/// UTF-8.
pub(crate) fn text(bytes: &[u8]) -> Result<&str, RunProblem> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let valid = bytes.get(..e.valid_up_to()).unwrap_or_default();
        RunProblem::Line {
            line: 1 + valid.iter().filter(|&&b| b == b'\n').count(),
            what: "not valid UTF-8".into(),
        }
    })?;
    Ok(text.strip_prefix('\u{feff}').unwrap_or(text))
}

/// The lines of a test file that carry something, by role, each with its 1-based line number.
pub(crate) struct Layout<'a> {
    /// `#` comments before the header: where a test states its setup (`# radius: 150 mm`).
    pub setup: Vec<(usize, &'a str)>,
    /// The first line that is neither blank nor a comment.
    pub header: (usize, &'a str),
    /// Every later line that is neither blank nor a comment.
    pub rows: Vec<(usize, &'a str)>,
}

/// Sorts a test file's lines into setup comments, header and rows (CRLF or LF; blank lines and
/// comments after the header skipped); `None` when there is no header. Every ISO test file kin
/// reads shares this layout, so they agree on what a comment or a blank line is.
pub(crate) fn layout(text: &str) -> Option<Layout<'_>> {
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
    Some(Layout {
        setup,
        header: header?,
        rows,
    })
}

/// Splits line `n` of a test file into `cells` (text in `buf`); a quoting problem is reported
/// at its line and column.
pub(crate) fn split_line(
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
pub(crate) fn header_cell(cell: &str) -> Result<(&str, Option<&str>), String> {
    match cell.split_once('[') {
        Some((n, rest)) => match rest.strip_suffix(']') {
            Some(u) => Ok((n.trim(), Some(u.trim()))),
            None => Err(format!("`{cell}`: expected NAME or NAME[UNIT]")),
        },
        None => Ok((cell, None)),
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Role {
    Target,
    Deviation,
    Direction,
    Cycle,
}

const COLUMNS: [(&str, Role); 4] = [
    ("target", Role::Target),
    ("deviation", Role::Deviation),
    ("direction", Role::Direction),
    ("cycle", Role::Cycle),
];

pub(crate) fn column_of(line: &str, byte: usize) -> usize {
    1 + line.get(..byte).map_or(0, |s| s.chars().count())
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

pub(crate) fn push(problems: &mut Vec<RunProblem>, p: RunProblem) {
    if problems.len() < MAX_PROBLEMS {
        problems.push(p);
    }
}

/// Reads a run file from memory; `path` only names it in errors. Targets default to mm and
/// deviations to um when their header gives no unit.
pub fn read(bytes: &[u8], path: &Path) -> Result<Run, Iso2302Error> {
    let invalid = |problems| Iso2302Error::Invalid {
        path: path.to_path_buf(),
        problems,
    };
    let text = text(bytes).map_err(|p| invalid(vec![p]))?;
    let Some(Layout {
        header: (header_line, header),
        rows: lines,
        ..
    }) = layout(text)
    else {
        return Err(invalid(vec![RunProblem::NoHeader]));
    };
    let dialect = Dialect::detect(header);
    let mut problems = Vec::new();
    let mut buf = String::new();
    let mut cells: Vec<Cell> = Vec::new();
    // Header: which column is which, and the units.
    let mut roles: Vec<Option<Role>> = Vec::new();
    let mut target_unit = Unit::atom("mm");
    let mut deviation_unit = Unit::atom("um");
    if let Err(p) = split_line(header, header_line, dialect, &mut buf, &mut cells) {
        push(&mut problems, p);
    }
    for c in &cells {
        let column = column_of(header, c.origin);
        let cell = buf.get(c.start..c.end).unwrap_or("").trim();
        let (name, unit) = match header_cell(cell) {
            Ok(nu) => nu,
            Err(what) => {
                push(
                    &mut problems,
                    RunProblem::At {
                        line: header_line,
                        column,
                        what,
                    },
                );
                roles.push(None);
                continue;
            }
        };
        let Some(&(_, role)) = COLUMNS.iter().find(|(n, _)| *n == name) else {
            push(
                &mut problems,
                RunProblem::At {
                    line: header_line,
                    column,
                    what: format!(
                    "unknown column `{name}`; a run file has target, deviation, direction, cycle"
                ),
                },
            );
            roles.push(None);
            continue;
        };
        if roles.contains(&Some(role)) {
            push(
                &mut problems,
                RunProblem::At {
                    line: header_line,
                    column,
                    what: format!("duplicate column `{name}`"),
                },
            );
            roles.push(None);
            continue;
        }
        match (role, unit) {
            (_, None) => {}
            (Role::Target | Role::Deviation, Some(u)) => match length_unit(u) {
                Ok(unit) if role == Role::Target => target_unit = Some(unit),
                Ok(unit) => deviation_unit = Some(unit),
                Err(e) => push(
                    &mut problems,
                    RunProblem::At {
                        line: header_line,
                        column,
                        what: format!("column `{name}`: {e}"),
                    },
                ),
            },
            (_, Some(_)) => push(
                &mut problems,
                RunProblem::At {
                    line: header_line,
                    column,
                    what: format!("column `{name}` takes no unit"),
                },
            ),
        }
        roles.push(Some(role));
    }
    let missing: Vec<&str> = COLUMNS
        .iter()
        .filter(|(_, r)| !roles.contains(&Some(*r)))
        .map(|(n, _)| *n)
        .collect();
    if !missing.is_empty() {
        push(
            &mut problems,
            RunProblem::File(format!(
                "missing column{}: {}",
                if missing.len() == 1 { "" } else { "s" },
                missing.join(", ")
            )),
        );
    }
    let (Some(target_unit), Some(deviation_unit)) = (target_unit, deviation_unit) else {
        return Err(invalid(vec![RunProblem::File(
            "kin's unit table lacks mm or um".into(),
        )]));
    };
    let mut samples = Vec::new();
    for (n, line) in lines {
        if let Err(p) = split_line(line, n, dialect, &mut buf, &mut cells) {
            push(&mut problems, p);
            continue;
        }
        if cells.len() != roles.len() {
            push(
                &mut problems,
                RunProblem::Line {
                    line: n,
                    what: format!(
                        "{} cells, but the header has {} columns",
                        cells.len(),
                        roles.len()
                    ),
                },
            );
            continue;
        }
        let mut sample = Sample {
            target: f64::NAN,
            up: true,
            cycle: String::new(),
            deviation: f64::NAN,
            line: n,
        };
        let mut ok = true;
        for (c, role) in cells.iter().zip(&roles) {
            let Some(role) = role else { continue };
            let cell = buf.get(c.start..c.end).unwrap_or("").trim();
            let mut bad = |expected: &str| {
                ok = false;
                let shown = if cell.is_empty() {
                    "empty cell".to_string()
                } else {
                    format!("`{cell}`")
                };
                push(
                    &mut problems,
                    RunProblem::At {
                        line: n,
                        column: column_of(line, c.origin),
                        what: format!("{shown}: expected {expected}"),
                    },
                );
            };
            match role {
                Role::Target | Role::Deviation => {
                    let v = number(cell, dialect);
                    let unit = if *role == Role::Target {
                        &target_unit
                    } else {
                        &deviation_unit
                    };
                    match v {
                        // A run covers at most a few metres with deviations of micrometres;
                        // the bound only keeps absurd cells from overflowing the sums.
                        Some(v) if (v * unit.scale).abs() <= 1e4 => {
                            if *role == Role::Target {
                                sample.target = v * unit.scale;
                            } else {
                                sample.deviation = v * unit.scale;
                            }
                        }
                        Some(_) => bad(&format!("a value within ±10 km, in {}", unit.name)),
                        None => bad(&format!("a number in {}", unit.name)),
                    }
                }
                Role::Direction => match direction(cell, dialect) {
                    Some(up) => sample.up = up,
                    None => bad("+1 (approached from below) or -1 (from above)"),
                },
                Role::Cycle => {
                    if cell.is_empty() {
                        bad("a cycle label");
                    } else {
                        sample.cycle = cell.to_string();
                    }
                }
            }
        }
        if ok {
            samples.push(sample);
        }
    }
    if problems.is_empty() && samples.is_empty() {
        push(
            &mut problems,
            RunProblem::File("no data rows after the header".into()),
        );
    }
    if problems.is_empty() {
        Ok(Run {
            samples,
            target_unit,
            deviation_unit,
        })
    } else {
        Err(invalid(problems))
    }
}

pub(crate) fn number(cell: &str, dialect: Dialect) -> Option<f64> {
    match cell.parse::<f64>() {
        Ok(v) if v.is_finite() => Some(v),
        Ok(_) => None,
        Err(_) if dialect.decimal_comma => csv::decimal_comma(cell),
        Err(_) => None,
    }
}

fn direction(cell: &str, dialect: Dialect) -> Option<bool> {
    match cell {
        "+" | "up" => return Some(true),
        "-" | "\u{2212}" | "down" => return Some(false),
        _ => {}
    }
    let v = number(&cell.replace('\u{2212}', "-"), dialect)?;
    if v == 1.0 {
        Some(true)
    } else if v == -1.0 {
        Some(false)
    } else {
        None
    }
}

/// Mean and the estimator of the standard uncertainty (n − 1 in the denominator).
fn mean_and_s(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let ss: f64 = values.iter().map(|v| (v - mean).powi(2)).sum();
    (mean, (ss / (n - 1.0)).sqrt())
}

fn range(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let max = values.clone().fold(f64::NEG_INFINITY, f64::max);
    let min = values.fold(f64::INFINITY, f64::min);
    max - min
}

/// The ISO 230-2 figures of a run. Every target needs at least two approaches from each side
/// (a spread needs two values), and no (target, direction, cycle) may be given twice.
pub fn evaluate(run: &Run, path: &Path) -> Result<Evaluation, Iso2302Error> {
    let invalid = |problems| Iso2302Error::Invalid {
        path: path.to_path_buf(),
        problems,
    };
    let mut targets: Vec<f64> = run.samples.iter().map(|s| s.target).collect();
    targets.sort_by(f64::total_cmp);
    targets.dedup();
    let mut problems = Vec::new();
    let mut seen: std::collections::HashMap<(u64, bool, &str), usize> =
        std::collections::HashMap::new();
    for s in &run.samples {
        let key = (s.target.to_bits(), s.up, s.cycle.as_str());
        if let Some(first) = seen.insert(key, s.line) {
            if problems.len() < MAX_PROBLEMS {
                problems.push(RunProblem::Line {
                    line: s.line,
                    what: format!(
                        "cycle `{}` approaches this target from this side a second time (first at line {first})",
                        s.cycle
                    ),
                });
            }
        }
    }
    let mut figures = Vec::with_capacity(targets.len());
    let mut cycles = 0;
    for &t in &targets {
        let side = |up: bool| -> Vec<f64> {
            run.samples
                .iter()
                .filter(|s| s.target == t && s.up == up)
                .map(|s| s.deviation)
                .collect()
        };
        let (up, down) = (side(true), side(false));
        cycles = cycles.max(up.len()).max(down.len());
        if up.len() < 2 || down.len() < 2 {
            if problems.len() < MAX_PROBLEMS {
                let shown = t / run.target_unit.scale;
                problems.push(RunProblem::File(format!(
                    "target {shown} {}: {} approach(es) from below and {} from above; each side needs at least 2",
                    run.target_unit.name,
                    up.len(),
                    down.len()
                )));
            }
            continue;
        }
        let (mean_up, s_up) = mean_and_s(&up);
        let (mean_down, s_down) = mean_and_s(&down);
        let reversal = mean_up - mean_down;
        let (r_up, r_down) = (4.0 * s_up, 4.0 * s_down);
        figures.push(TargetFigures {
            target: t,
            n_up: up.len(),
            n_down: down.len(),
            mean_up,
            mean_down,
            mean: (mean_up + mean_down) / 2.0,
            s_up,
            s_down,
            reversal,
            r_up,
            r_down,
            r: (2.0 * s_up + 2.0 * s_down + reversal.abs())
                .max(r_up)
                .max(r_down),
        });
    }
    if !problems.is_empty() {
        return Err(invalid(problems));
    }
    let f = &figures;
    let max = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::NEG_INFINITY, f64::max);
    let min = |it: &mut dyn Iterator<Item = f64>| it.fold(f64::INFINITY, f64::min);
    let both_means = f.iter().flat_map(|t| [t.mean_up, t.mean_down]);
    let axis = AxisFigures {
        e_up: range(f.iter().map(|t| t.mean_up)),
        e_down: range(f.iter().map(|t| t.mean_down)),
        e: range(both_means),
        m: range(f.iter().map(|t| t.mean)),
        b: max(&mut f.iter().map(|t| t.reversal.abs())),
        b_mean: f.iter().map(|t| t.reversal).sum::<f64>() / f.len() as f64,
        r_up: max(&mut f.iter().map(|t| t.r_up)),
        r_down: max(&mut f.iter().map(|t| t.r_down)),
        r: max(&mut f.iter().map(|t| t.r)),
        a_up: max(&mut f.iter().map(|t| t.mean_up + 2.0 * t.s_up))
            - min(&mut f.iter().map(|t| t.mean_up - 2.0 * t.s_up)),
        a_down: max(&mut f.iter().map(|t| t.mean_down + 2.0 * t.s_down))
            - min(&mut f.iter().map(|t| t.mean_down - 2.0 * t.s_down)),
        a: max(&mut f
            .iter()
            .flat_map(|t| [t.mean_up + 2.0 * t.s_up, t.mean_down + 2.0 * t.s_down]))
            - min(&mut f
                .iter()
                .flat_map(|t| [t.mean_up - 2.0 * t.s_up, t.mean_down - 2.0 * t.s_down])),
    };
    Ok(Evaluation {
        targets: figures,
        axis,
        cycles,
    })
}

/// The pure-error lack-of-fit test of a model's predicted deviations against the run: every
/// (target, direction) is a group of replicates whose scatter about its own mean is the
/// machine's repeatability (pure error); what remains of the residuals `deviation − predicted`
/// is lack of fit. `predicted` is in the order of `run.samples`; `fitted` is how many degrees of
/// freedom a fit to this run's own deviations took (0 when the prediction comes from other
/// data, which makes the test exact). The F-test is the one `kin diagnose` applies to repeated
/// poses ([`kin_estimate::statistics::lack_of_fit`]).
pub fn lack_of_fit(
    run: &Run,
    predicted: &[f64],
    fitted: f64,
    alpha: f64,
) -> Option<kin_estimate::statistics::LackOfFit> {
    let mut groups: std::collections::BTreeMap<(u64, bool), (usize, f64, f64)> =
        std::collections::BTreeMap::new();
    let mut rss = 0.0;
    for (s, p) in run.samples.iter().zip(predicted) {
        let r = s.deviation - p;
        let g = groups
            .entry((s.target.to_bits(), s.up))
            .or_insert((0, 0.0, 0.0));
        g.0 += 1;
        g.1 += r;
        g.2 += r * r;
        rss += r * r;
    }
    let n = run.samples.len().min(predicted.len()) as f64;
    kin_estimate::statistics::lack_of_fit(groups.into_values(), rss, n - fitted, alpha)
}

#[cfg(test)]
mod tests;
