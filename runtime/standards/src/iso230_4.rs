//! ISO 230-4 evaluation of circular tests (a ball bar, or any instrument that gives the radial
//! deviation of a circular path): per direction of contouring the circular deviation G, the
//! radial deviation F (its least and largest value), the least-squares centre offset and radius
//! error; for both directions together the bidirectional G and the circular hysteresis H
//! (spec/iso230-4.md states the definitions and where they come from).
//!
//! The run file is a small CSV of its own (`angle`, `deviation`, `direction`, optionally `run`),
//! read with the same CSV front end as measurement files; the test's radius, plane and feed may
//! be given in `# key: value` comment lines before the header.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use kin_compiler::units::{Dim, Unit};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;
use thiserror::Error;

use crate::iso230_2::{
    column_of, header_cell, layout, length_unit, number, push, read_bytes, split_line, text,
    Layout, Listing, RunProblem, MAX_PROBLEMS,
};
use kin_data::data::csv::{Cell, Dialect};

#[derive(Debug, Error)]
pub enum Iso2304Error {
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

/// One sample of a circular path: the nominal angle (rad, from the plane's first axis towards
/// its second), the radial deviation (m, actual minus nominal radius, measured from the
/// instrument's centre), the direction of contouring and the run it belongs to.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub angle: f64,
    pub deviation: f64,
    pub ccw: bool,
    pub run: String,
    pub line: usize,
}

/// What the comment lines before the header say about the test.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Setup {
    /// Nominal radius of the circle, m.
    pub radius: Option<f64>,
    /// The two axes spanning the plane, first to second being counter-clockwise.
    pub plane: Option<[String; 2]>,
    /// The contouring feed, as written (only reported).
    pub feed: Option<String>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct CircularRun {
    pub samples: Vec<Sample>,
    pub setup: Setup,
    pub deviation_unit: Unit,
}

/// The least-squares circle of a set of radial deviations: `d ≈ c + a cos θ + b sin θ`, the
/// linearisation of the distance from an offset centre that the roundness standards use for the
/// least-squares centre (valid while the offset is small against the radius).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Circle {
    /// Offset of the least-squares centre from the instrument's centre, along the plane's
    /// first and second axis, m.
    pub centre: [f64; 2],
    /// Least-squares radius minus the nominal radius, m.
    pub radius_error: f64,
}

impl Circle {
    /// Deviation from this circle of a sample at `angle` with radial deviation `d`.
    pub fn residual(&self, angle: f64, d: f64) -> f64 {
        d - self.radius_error - self.centre[0] * angle.cos() - self.centre[1] * angle.sin()
    }
}

/// The figures of one direction of one run (or of both directions together), m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Figures {
    pub samples: usize,
    /// The least-squares circle.
    #[serde(flatten)]
    pub circle: Circle,
    /// Circular deviation G: the radial distance between the two circles about the
    /// least-squares centre that just enclose the path.
    pub g: f64,
    /// Radial deviation F: the least and largest deviation from the nominal circle about the
    /// instrument's centre.
    pub f_min: f64,
    pub f_max: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunFigures {
    pub run: String,
    /// Counter-clockwise and clockwise contouring, when the run has them.
    pub ccw: Option<Figures>,
    pub cw: Option<Figures>,
    /// Both directions about one least-squares centre and radius (the bidirectional G), when
    /// the run has both.
    pub both: Option<Figures>,
    /// Circular hysteresis H: the largest radial distance between the two directions' paths at
    /// the same angle (about the common centre), when the run has both directions.
    pub h: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    pub setup: Setup,
    /// In the order the runs first appear in the file.
    pub runs: Vec<RunFigures>,
}

/// Reads a run file from disk.
pub fn read_file(path: &Path) -> Result<CircularRun, Iso2304Error> {
    let bytes = read_bytes(path).map_err(|source| Iso2304Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read(&bytes, path)
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Role {
    Angle,
    Deviation,
    Direction,
    Run,
}

const COLUMNS: [(&str, Role); 4] = [
    ("angle", Role::Angle),
    ("deviation", Role::Deviation),
    ("direction", Role::Direction),
    ("run", Role::Run),
];

/// A quantity such as `150 mm` (a bare number is in `default`).
fn quantity(text: &str, dim: Dim, default: &str) -> Result<f64, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| {
            !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E')
        })
        .unwrap_or(text.len());
    let (num, unit) = text.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("`{text}` does not start with a number"))?;
    let unit = unit.trim();
    let unit = if unit.is_empty() { default } else { unit };
    let unit = if dim == Dim::LENGTH {
        length_unit(unit)?
    } else {
        Unit::parse(unit).map_err(|e| e.to_string())?
    };
    if unit.dim != dim {
        return Err(format!("`{text}` is not {}", dim.describe()));
    }
    let v = unit.as_difference().to_si(value);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("`{text}` is not finite"))
    }
}

/// A `# key: value` (or `key = value`) comment before the header.
fn setup_line(setup: &mut Setup, comment: &str, line: usize, problems: &mut Vec<RunProblem>) {
    let body = comment.trim_start().trim_start_matches('#').trim();
    let Some((key, value)) = body.split_once([':', '=']) else {
        return;
    };
    let (key, value) = (key.trim().to_ascii_lowercase(), value.trim());
    let at = |what: String| RunProblem::Line { line, what };
    match key.as_str() {
        "radius" => match quantity(value, Dim::LENGTH, "mm") {
            Ok(r) if r > 0.0 && r <= 1e4 => setup.radius = Some(r),
            Ok(_) => push(
                problems,
                at("the radius must be above 0 and within 10 km".into()),
            ),
            Err(e) => push(problems, at(format!("radius: {e}"))),
        },
        "plane" => match plane(value) {
            Ok(p) => setup.plane = Some(p),
            Err(e) => push(problems, at(e)),
        },
        "feed" => setup.feed = Some(value.to_string()),
        // Any other comment is the user's own note.
        _ => {}
    }
}

/// `X,Y`: two distinct axis names.
pub fn plane(text: &str) -> Result<[String; 2], String> {
    let names: Vec<&str> = text.split(',').map(str::trim).collect();
    let ok = |n: &str| {
        !n.is_empty()
            && n.chars().all(|c| c.is_alphanumeric() || c == '_')
            && !n.starts_with(|c: char| c.is_ascii_digit())
    };
    match names.as_slice() {
        [a, b] if ok(a) && ok(b) && a != b => Ok([a.to_string(), b.to_string()]),
        _ => Err(format!(
            "plane `{text}`: expected two different axis names, e.g. `X,Y` (first to second is counter-clockwise)"
        )),
    }
}

fn direction(cell: &str, dialect: Dialect) -> Option<bool> {
    match cell.to_ascii_lowercase().as_str() {
        "ccw" | "+" => return Some(true),
        "cw" | "-" | "\u{2212}" => return Some(false),
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

/// Reads a run file from memory; `path` only names it in errors. Angles default to degrees and
/// deviations to um when their header gives no unit.
pub fn read(bytes: &[u8], path: &Path) -> Result<CircularRun, Iso2304Error> {
    let invalid = |problems| Iso2304Error::Invalid {
        path: path.to_path_buf(),
        problems,
    };
    let text = text(bytes).map_err(|p| invalid(vec![p]))?;
    let Some(Layout {
        setup: comments,
        header: (header_line, header),
        rows,
    }) = layout(text)
    else {
        return Err(invalid(vec![RunProblem::NoHeader]));
    };
    let mut problems = Vec::new();
    let mut setup = Setup::default();
    // Only the comments before the header describe the test.
    for (line, comment) in comments {
        setup_line(&mut setup, comment, line, &mut problems);
    }
    let dialect = Dialect::detect(header);
    let mut buf = String::new();
    let mut cells: Vec<Cell> = Vec::new();
    let mut roles: Vec<Option<Role>> = Vec::new();
    let mut angle_unit = Unit::atom("deg");
    let mut deviation_unit = Unit::atom("um");
    if let Err(p) = split_line(header, header_line, dialect, &mut buf, &mut cells) {
        push(&mut problems, p);
    }
    for c in &cells {
        let column = column_of(header, c.origin);
        let at = |what: String| RunProblem::At {
            line: header_line,
            column,
            what,
        };
        let cell = buf.get(c.start..c.end).unwrap_or("").trim();
        let (name, unit) = match header_cell(cell) {
            Ok(nu) => nu,
            Err(what) => {
                push(&mut problems, at(what));
                roles.push(None);
                continue;
            }
        };
        let Some(&(_, role)) = COLUMNS.iter().find(|(n, _)| *n == name) else {
            push(
                &mut problems,
                at(format!(
                    "unknown column `{name}`; a circular-test file has angle, deviation, direction and optionally run"
                )),
            );
            roles.push(None);
            continue;
        };
        if roles.contains(&Some(role)) {
            push(&mut problems, at(format!("duplicate column `{name}`")));
            roles.push(None);
            continue;
        }
        match (role, unit) {
            (_, None) => {}
            (Role::Deviation, Some(u)) => match length_unit(u) {
                Ok(unit) => deviation_unit = Some(unit),
                Err(e) => push(&mut problems, at(format!("column `{name}`: {e}"))),
            },
            (Role::Angle, Some(u)) => match Unit::parse(u) {
                Ok(unit) if unit.dim == Dim::ANGLE => angle_unit = Some(unit),
                Ok(_) => push(
                    &mut problems,
                    at(format!("column `{name}`: `{u}` is not an angle unit")),
                ),
                Err(e) => push(&mut problems, at(format!("column `{name}`: {e}"))),
            },
            (_, Some(_)) => push(&mut problems, at(format!("column `{name}` takes no unit"))),
        }
        roles.push(Some(role));
    }
    let missing: Vec<&str> = COLUMNS
        .iter()
        .filter(|(_, r)| *r != Role::Run && !roles.contains(&Some(*r)))
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
    let (Some(angle_unit), Some(deviation_unit)) = (angle_unit, deviation_unit) else {
        return Err(invalid(vec![RunProblem::File(
            "kin's unit table lacks deg or um".into(),
        )]));
    };
    let mut samples = Vec::new();
    for (n, line) in rows {
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
            angle: f64::NAN,
            deviation: f64::NAN,
            ccw: true,
            run: "1".into(),
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
                Role::Angle => match number(cell, dialect) {
                    // A few turns (an overshoot beyond 360°) at most; the bound only keeps
                    // absurd cells out of the trigonometry.
                    Some(v) if (angle_unit.to_si(v)).abs() <= 100.0 => {
                        sample.angle = angle_unit.to_si(v)
                    }
                    Some(_) => bad(&format!("an angle within ±100 rad, in {}", angle_unit.name)),
                    None => bad(&format!("a number in {}", angle_unit.name)),
                },
                Role::Deviation => match number(cell, dialect) {
                    Some(v) if (v * deviation_unit.scale).abs() <= 1.0 => {
                        sample.deviation = v * deviation_unit.scale
                    }
                    Some(_) => bad(&format!(
                        "a deviation within ±1 m, in {}",
                        deviation_unit.name
                    )),
                    None => bad(&format!("a number in {}", deviation_unit.name)),
                },
                Role::Direction => match direction(cell, dialect) {
                    Some(ccw) => sample.ccw = ccw,
                    None => bad("ccw (or +1) or cw (or -1)"),
                },
                Role::Run => {
                    if cell.is_empty() {
                        bad("a run label");
                    } else {
                        sample.run = cell.to_string();
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
        Ok(CircularRun {
            samples,
            setup,
            deviation_unit,
        })
    } else {
        Err(invalid(problems))
    }
}

/// The least-squares circle through radial deviations `(θ, d)`: minimises
/// Σ (d − c − a cos θ − b sin θ)² (the least-squares centre of the roundness standards, for a
/// centre offset small against the radius). `None` when the angles do not determine it (fewer
/// than three distinct directions).
pub fn least_squares_circle(points: &[(f64, f64)]) -> Option<Circle> {
    let mut n = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    for &(t, d) in points {
        let row = Vector3::new(1.0, t.cos(), t.sin());
        n += row * row.transpose();
        rhs += row * d;
    }
    // The columns are bounded by 1, so a tiny smallest eigenvalue means the angles cluster:
    // the offset along some direction is then not measured.
    let smallest = n.symmetric_eigenvalues().min();
    if !(smallest > 1e-9 * points.len() as f64) {
        return None;
    }
    let x = n.cholesky()?.solve(&rhs);
    Some(Circle {
        centre: [x[1], x[2]],
        radius_error: x[0],
    })
}

fn figures(points: &[(f64, f64)], circle: Circle) -> Figures {
    let residuals = points.iter().map(|&(t, d)| circle.residual(t, d));
    let max = residuals.clone().fold(f64::NEG_INFINITY, f64::max);
    let min = residuals.fold(f64::INFINITY, f64::min);
    Figures {
        samples: points.len(),
        circle,
        g: max - min,
        f_min: points.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
        f_max: points.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
    }
}

/// The angle in [0, 2π).
fn wrap(t: f64) -> f64 {
    t.rem_euclid(std::f64::consts::TAU)
}

/// The circular hysteresis: at every angle of one path, the other path's radius interpolated
/// linearly between its two neighbouring samples (on the circle); the largest difference. A
/// neighbour pair farther apart than four times the other path's median spacing is a gap in it
/// and gives no value there.
pub fn hysteresis(a: &[(f64, f64)], b: &[(f64, f64)], common: Circle) -> Option<f64> {
    let radial = |p: &[(f64, f64)]| -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = p
            .iter()
            .map(|&(t, d)| (wrap(t), common.residual(t, d)))
            .collect();
        v.sort_by(|x, y| x.0.total_cmp(&y.0));
        v
    };
    let (a, b) = (radial(a), radial(b));
    if b.len() < 2 {
        return None;
    }
    let mut steps: Vec<f64> = b.windows(2).map(|w| w[1].0 - w[0].0).collect();
    steps.push(b[0].0 + std::f64::consts::TAU - b[b.len() - 1].0);
    let mut sorted = steps.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let gap = 4.0 * median.max(1e-12);
    let mut h: Option<f64> = None;
    for &(t, r) in &a {
        // The first sample of b at or after t, and the one before it (wrapping round).
        let j = b.partition_point(|p| p.0 < t);
        let (lo, hi) = match j {
            0 => (b[b.len() - 1], b[0]),
            j if j == b.len() => (b[j - 1], b[0]),
            j => (b[j - 1], b[j]),
        };
        // Between neighbours inside the sorted list the span is their difference; the pair
        // across 0 spans the rest of the turn.
        let span = if j == 0 || j == b.len() {
            hi.0 + std::f64::consts::TAU - lo.0
        } else {
            hi.0 - lo.0
        };
        if span > gap {
            continue;
        }
        let along = wrap(t - lo.0).min(span);
        let at = if span > 0.0 {
            lo.1 + (hi.1 - lo.1) * (along / span)
        } else {
            lo.1
        };
        let d = (r - at).abs();
        h = Some(h.map_or(d, |h: f64| h.max(d)));
    }
    h
}

/// The ISO 230-4 figures of every run in the file. Each direction of each run needs at least
/// three samples at angles that determine a centre.
pub fn evaluate(run: &CircularRun, path: &Path) -> Result<Evaluation, Iso2304Error> {
    let mut order: Vec<&str> = Vec::new();
    let mut traces: BTreeMap<(&str, bool), Vec<(f64, f64)>> = BTreeMap::new();
    let mut first_line: BTreeMap<(&str, bool), usize> = BTreeMap::new();
    for s in &run.samples {
        if !order.contains(&s.run.as_str()) {
            order.push(&s.run);
        }
        traces
            .entry((s.run.as_str(), s.ccw))
            .or_default()
            .push((s.angle, s.deviation));
        first_line.entry((s.run.as_str(), s.ccw)).or_insert(s.line);
    }
    let mut problems = Vec::new();
    let mut runs = Vec::new();
    for name in order {
        let mut one = |ccw: bool| -> Option<Figures> {
            let points = traces.get(&(name, ccw))?;
            match least_squares_circle(points) {
                Some(c) if points.len() >= 3 => Some(figures(points, c)),
                _ => {
                    if problems.len() < MAX_PROBLEMS {
                        problems.push(RunProblem::Line {
                            line: first_line.get(&(name, ccw)).copied().unwrap_or(0),
                            what: format!(
                                "run `{name}`, {}: {} sample(s) whose angles do not determine a centre (at least three different directions are needed; ISO 230-4 asks for a full circle)",
                                if ccw { "counter-clockwise" } else { "clockwise" },
                                points.len()
                            ),
                        });
                    }
                    None
                }
            }
        };
        let ccw = one(true);
        let cw = one(false);
        let (mut both, mut h) = (None, None);
        if let (Some(_), Some(_), Some(a), Some(b)) = (
            &ccw,
            &cw,
            traces.get(&(name, true)),
            traces.get(&(name, false)),
        ) {
            let all: Vec<(f64, f64)> = a.iter().chain(b).copied().collect();
            if let Some(c) = least_squares_circle(&all) {
                h = hysteresis(a, b, c);
                both = Some(figures(&all, c));
            }
        }
        runs.push(RunFigures {
            run: name.to_string(),
            ccw,
            cw,
            both,
            h,
        });
    }
    if problems.is_empty() {
        Ok(Evaluation {
            setup: run.setup.clone(),
            runs,
        })
    } else {
        Err(Iso2304Error::Invalid {
            path: path.to_path_buf(),
            problems,
        })
    }
}

#[cfg(test)]
mod tests;
