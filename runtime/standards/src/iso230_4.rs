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
use std::path::Path;

use kin_compiler::units::{Dim, Unit};
use kin_data::data::csv::Dialect;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

pub use crate::table::TestFileError as Iso2304Error;
use crate::table::{self, push, RunProblem, Table};

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
    table::read_file(path, read)
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
        table::length_unit(unit)?
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
    // `key = value` too (the 230-3 files take only `key: value`).
    let Some((key, value)) = table::setup_entry(comment, &[':', '=']) else {
        return;
    };
    let key = key.to_ascii_lowercase();
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

/// `ccw`, `+1` or `+` (counter-clockwise), `cw`, `-1` or `-`, in any case.
fn direction(cell: &str, dialect: Dialect) -> Option<bool> {
    match cell.to_ascii_lowercase().as_str() {
        "ccw" | "+" => Some(true),
        "cw" | "-" | "\u{2212}" => Some(false),
        _ => table::unit_sign(cell, dialect),
    }
}

/// Reads a run file from memory; `path` only names it in errors. Angles default to degrees and
/// deviations to um when their header gives no unit.
pub fn read(bytes: &[u8], path: &Path) -> Result<CircularRun, Iso2304Error> {
    let invalid = |p| Iso2304Error::invalid(path, vec![p]);
    let mut file = Table::new(bytes).map_err(invalid)?;
    let mut problems = Vec::new();
    let mut setup = Setup::default();
    // Only the comments before the header describe the test.
    for &(line, comment) in &file.setup {
        setup_line(&mut setup, comment, line, &mut problems);
    }
    let mut angle_unit = Unit::atom("deg");
    let mut deviation_unit = Unit::atom("um");
    let columns = file.header(&mut problems, |cell, columns, problems| {
        let has = "a circular-test file has angle, deviation, direction and optionally run";
        let role = cell.known(&COLUMNS, columns, has)?;
        match (role, cell.unit) {
            (_, None) => {}
            (Role::Deviation, Some(u)) => match table::length_unit(u) {
                Ok(unit) => deviation_unit = Some(unit),
                Err(e) => push(problems, cell.column_problem(e)),
            },
            (Role::Angle, Some(u)) => match Unit::parse(u) {
                Ok(unit) if unit.dim == Dim::ANGLE => angle_unit = Some(unit),
                Ok(_) => push(
                    problems,
                    cell.column_problem(format!("`{u}` is not an angle unit")),
                ),
                Err(e) => push(problems, cell.column_problem(e)),
            },
            (_, Some(_)) => push(problems, cell.takes_no_unit()),
        }
        Ok(Some(role))
    });
    // `run` is optional.
    if let Some(p) = table::missing(&COLUMNS, &columns, |r| r != Role::Run) {
        push(&mut problems, p);
    }
    let (Some(angle_unit), Some(deviation_unit)) = (angle_unit, deviation_unit) else {
        return Err(invalid(RunProblem::File(
            "kin's unit table lacks deg or um".into(),
        )));
    };
    let dialect = file.dialect;
    let new = |line| Sample {
        angle: f64::NAN,
        deviation: f64::NAN,
        ccw: true,
        run: "1".into(),
        line,
    };
    let samples = file.records(&columns, &mut problems, new, |c, sample| {
        let (cell, angle, deviation) = (c.text, &angle_unit, &deviation_unit);
        match c.role {
            // A few turns (an overshoot beyond 360°) at most; the bound only keeps absurd
            // cells out of the trigonometry.
            Role::Angle => {
                let within = "an angle within ±100 rad";
                sample.angle =
                    table::bounded(cell, dialect, angle, |v| angle.to_si(v), 100.0, within)?
            }
            Role::Deviation => {
                let within = "a deviation within ±1 m";
                let si = |v| v * deviation.scale;
                sample.deviation = table::bounded(cell, dialect, deviation, si, 1.0, within)?
            }
            Role::Direction => {
                sample.ccw = direction(cell, dialect).ok_or("ccw (or +1) or cw (or -1)")?
            }
            Role::Run => sample.run = table::label(cell, "a run label")?,
        }
        Ok(())
    });
    table::done(
        path,
        problems,
        CircularRun {
            samples,
            setup,
            deviation_unit,
        },
    )
}

/// The least-squares circle through radial deviations `(θ, d)`: minimises
/// Σ (d − c − a cos θ − b sin θ)² (the least-squares centre of the roundness standards, for a
/// centre offset small against the radius). `None` when the angles do not determine it (fewer
/// than three distinct directions).
pub(crate) fn least_squares_circle(points: &[(f64, f64)]) -> Option<Circle> {
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
                    push(
                        &mut problems,
                        RunProblem::Line {
                            line: first_line.get(&(name, ccw)).copied().unwrap_or(0),
                            what: format!(
                                "run `{name}`, {}: {} sample(s) whose angles do not determine a centre (at least three different directions are needed; ISO 230-4 asks for a full circle)",
                                if ccw { "counter-clockwise" } else { "clockwise" },
                                points.len()
                            ),
                        },
                    );
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
    table::done(
        path,
        problems,
        Evaluation {
            setup: run.setup.clone(),
            runs,
        },
    )
}

/// One axis of the pose a ball bar's pivot was set at: its name, whether a length positions it
/// (else an angle), and its value in SI units (m or rad).
#[derive(Debug, Clone, PartialEq)]
pub struct PoseAxis {
    pub name: String,
    pub length: bool,
    pub value: f64,
}

/// Why a circular test's samples cannot be written as lengths from a centre pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LengthsError {
    /// The centre pose lacks one of the plane's axes.
    PlaneAxisMissing,
    /// One of the plane's axes is positioned by an angle.
    PlaneAxisNotLength,
}

/// A circular test's samples as length observations of one bar per run.
#[derive(Debug, Clone, PartialEq)]
pub struct BarLengths {
    /// The runs in the order they first appear; bar `k` (from 0) is run `runs[k]`'s.
    pub runs: Vec<String>,
    /// One per sample, in the file's order.
    pub rows: Vec<BarLength>,
}

/// One sample as a length: from point 1, the pivot at the centre pose, to point 2.
#[derive(Debug, Clone, PartialEq)]
pub struct BarLength {
    /// Point 2, the nominal circle point: every axis of the centre pose, in its order, the
    /// plane's two moved by the nominal radius along the sample's angle (SI units).
    pub point: Vec<f64>,
    /// Whether each plane axis moved in its positive direction just before reaching point 2.
    pub positive: [bool; 2],
    /// Which bar (index into [`BarLengths::runs`]).
    pub bar: usize,
    /// The reading, actual minus nominal distance (m), its sign flipped for a measuring
    /// machine.
    pub dl: f64,
}

/// The samples of a circular test as length observations for a fit (spec/iso230-4.md, "Ball-bar
/// lengths for a fit"; spec/data.md, length files): point 1 the pivot at the `centre` pose,
/// point 2 the nominal circle point `centre + radius (cos θ, sin θ)` in `plane` (the plane's
/// axes must be lengths of the pose), the direction each plane axis moved in just before
/// reaching it, one bar per run (its length unknown to the fit), and `dL` the reading with the
/// task's sign (flipped when `measure`: a measuring machine, spec/kinematics.md).
pub fn bar_lengths(
    samples: &[Sample],
    plane: &[String; 2],
    radius: f64,
    centre: &[PoseAxis],
    measure: bool,
) -> Result<BarLengths, LengthsError> {
    let position = |n: &str| centre.iter().position(|x| x.name == n);
    let (Some(ip), Some(iq)) = (position(&plane[0]), position(&plane[1])) else {
        return Err(LengthsError::PlaneAxisMissing);
    };
    if !centre[ip].length || !centre[iq].length {
        return Err(LengthsError::PlaneAxisNotLength);
    }
    let sign = if measure { -1.0 } else { 1.0 };
    let mut runs: Vec<String> = Vec::new();
    for s in samples {
        if !runs.contains(&s.run) {
            runs.push(s.run.clone());
        }
    }
    let rows = samples
        .iter()
        .map(|s| {
            let point = centre
                .iter()
                .enumerate()
                .map(|(i, x)| match i {
                    i if i == ip => x.value + radius * s.angle.cos(),
                    i if i == iq => x.value + radius * s.angle.sin(),
                    _ => x.value,
                })
                .collect();
            // The path's tangent a hair earlier, so a point where one axis reverses gets the
            // side it came from.
            let before = if s.ccw {
                s.angle - 1e-9
            } else {
                s.angle + 1e-9
            };
            let turn = if s.ccw { 1.0 } else { -1.0 };
            BarLength {
                point,
                positive: [-turn * before.sin() >= 0.0, turn * before.cos() >= 0.0],
                bar: runs.iter().position(|r| *r == s.run).unwrap_or(0),
                dl: sign * s.deviation,
            }
        })
        .collect();
    Ok(BarLengths { runs, rows })
}

#[cfg(test)]
mod tests;
