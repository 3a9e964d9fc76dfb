//! Candidate measurements of the common artifacts (ball bar, step gauge, ball or hole plate,
//! R-test) for planning a calibration (§4.3): the rows a D-optimal plan is chosen from
//! ([`crate::design::select`]). They are written in the measurement-file format
//! (spec/data.md), so that the file of candidates is read back like any measurement file and a
//! plan chosen from it is a file of the rows to measure (spec/design.md, "Candidates";
//! `kin design --generate`).
//!
//! Every generator keeps the poses inside the declared axis ranges: a candidate that would need
//! an axis outside its range is not written, so a plan chosen from the file can be run as is.
//! The R-test's poses need the inverse kinematics of the prismatic axes: with the rotary axes
//! set, the prismatic positions that put the tool at a sphere.
//!
//! The fields of [`Generate`] are the options of `kin design --generate`, and the errors name
//! a field by its option (`--length`, `--levels`, …).

use kin_compiler::ir::{JointKind, Machine, Var};
use kin_model::exact;
use kin_model::kinematics::{KinematicsError, Pose};
use nalgebra::{DMatrix, DVector, Vector3};
use thiserror::Error;

/// The artifact a candidate file is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// Ball bars in a plane (length file, one row a unit).
    Ballbar,
    /// A step gauge along one prismatic axis (length file, one face distance a unit).
    Stepgauge,
    /// A ball or hole plate in a plane, placed at several positions and orientations (point
    /// file, one placement an `artifact` label).
    Plate,
    /// R-test: a sphere on the workpiece side followed by the tool while the rotary axes turn
    /// (point file, one sweep of one rotary axis around one sphere an `artifact` label).
    Rtest,
}

impl Kind {
    /// The artifact by its name in `kin design --generate`: `ballbar`, `stepgauge`, `plate`,
    /// `rtest`.
    pub fn parse(text: &str) -> Option<Kind> {
        match text {
            "ballbar" => Some(Kind::Ballbar),
            "stepgauge" => Some(Kind::Stepgauge),
            "plate" => Some(Kind::Plate),
            "rtest" => Some(Kind::Rtest),
            _ => None,
        }
    }
}

/// What to generate: the artifact and its grid. Lengths in m, angles in rad.
pub struct Generate {
    pub kind: Kind,
    /// Ball bar: its length; step gauge: the distance from its first face to its last; plate:
    /// the side of its square grid of features.
    pub length: f64,
    /// The grid step of the artifact's placement: the first sphere of a bar, the first face of
    /// a gauge, the first feature (corner) of a plate.
    pub step: f64,
    /// The spacing of a step gauge's faces and of a plate's features.
    pub pitch: f64,
    /// Ball bar: its orientation step; plate: its rotation step in the plane; R-test: the step
    /// of the rotary axes.
    pub angle_step: f64,
    /// Ball bar, plate: the two prismatic axes spanning the plane (the first two when empty).
    pub plane: Vec<String>,
    /// Step gauge: the prismatic axis it lies along (the first when absent).
    pub axis: Option<String>,
    /// The number of evenly spaced positions of each prismatic axis outside the plane (or
    /// across the gauge), ends included; 1 is the middle of its range.
    pub levels: usize,
    /// R-test: the sphere centres in the workpiece reference frame (m).
    pub spheres: Vec<[f64; 3]>,
}

/// The R-test's spheres when none are given: 50 mm above the workpiece origin, and 100 mm out
/// along its x and y axes.
const DEFAULT_SPHERES: [[f64; 3]; 3] = [[0.0, 0.0, 0.05], [0.1, 0.0, 0.05], [0.0, 0.1, 0.05]];

/// At most this many candidate rows are generated: beyond it the exchange algorithm's memory
/// (one unit of p values each) and time grow past what a planning step should take.
const MAX_GENERATED: usize = 1_000_000;

/// Positions within the ranges are accepted this far outside them (m or rad): grid points
/// computed as `lower + k·step` land on the upper end only up to rounding.
const EPS: f64 = 1e-9;

/// Why no candidates were generated. Every case but [`GenerateError::Kinematics`] is a
/// request that cannot be met (a step or size out of bounds, an axis the artifact cannot use).
#[derive(Debug, Error)]
pub enum GenerateError {
    /// A length, step or pitch of [`Generate`] (named by its option) is not above zero.
    #[error("{0} must be above zero")]
    NotPositive(&'static str),
    #[error("--levels must be at least 1")]
    NoLevels,
    #[error("the grid holds more than {MAX_GENERATED} candidates; use a larger --step, --pitch or --angle-step")]
    GridTooFine,
    #[error("no candidate fits inside the axis ranges; use a shorter --length or smaller steps")]
    NoneFits,
    #[error("more than {MAX_GENERATED} candidates; use larger steps or fewer --levels")]
    TooManyCandidates,
    #[error("`{0}` is not a prismatic axis of the machine")]
    NotPrismatic(String),
    /// The plane of a ball bar or plate (named) is not two different prismatic axes.
    #[error("a {0} plane needs two different prismatic axes (--plane X,Y)")]
    Plane(&'static str),
    #[error("a step gauge needs a prismatic axis")]
    NoPrismaticAxis,
    #[error("--pitch is longer than the gauge's --length: the gauge has one face")]
    OneFace,
    #[error("--levels {0} gives more than {MAX_GENERATED} positions of the other axes")]
    TooManyLevels(usize),
    #[error("an R-test needs a revolute axis; the machine has none")]
    NoRevoluteAxis,
    /// The R-test's generator follows the sphere with the prismatic axes only.
    #[error("an R-test follows the sphere with the prismatic axes; the machine has none")]
    RtestWithoutPrismaticAxis,
    #[error("more than {MAX_GENERATED} sweeps; use a larger --angle-step")]
    TooManySweeps,
    /// The nominal kinematics could not place the tool (the R-test's inverse kinematics).
    #[error(transparent)]
    Kinematics(#[from] KinematicsError),
}

/// A file of candidates: its text (comments, header, rows) and the number of its data rows.
pub struct Candidates {
    pub text: String,
    pub rows: usize,
}

/// The candidates `g` describes for machine `m`, with both directions of approach where the
/// model uses them (backlash) and the inputs at their reference values (the middle of a declared
/// range, else 20 °C or 0).
pub fn generate(m: &Machine, g: &Generate) -> Result<Candidates, GenerateError> {
    let positive = [
        (g.length, "--length"),
        (g.step, "--step"),
        (g.pitch, "--pitch"),
        (g.angle_step, "--angle-step"),
    ];
    if let Some((_, name)) = positive.iter().find(|(v, _)| !(*v > 0.0 && v.is_finite())) {
        return Err(GenerateError::NotPositive(name));
    }
    if g.levels == 0 {
        return Err(GenerateError::NoLevels);
    }
    // Grids far finer than any candidate file can hold are refused before they are built.
    let widest = m
        .axes
        .iter()
        .filter(|a| a.kind == JointKind::Prismatic)
        .map(|a| a.range[1] - a.range[0])
        .fold(0.0, f64::max);
    if widest / g.step.min(g.pitch) > MAX_GENERATED as f64
        || std::f64::consts::TAU / g.angle_step > MAX_GENERATED as f64
    {
        return Err(GenerateError::GridTooFine);
    }
    let mut w = Writer::new(m);
    match g.kind {
        Kind::Ballbar => ballbar(m, g, &mut w)?,
        Kind::Stepgauge => stepgauge(m, g, &mut w)?,
        Kind::Plate => plate(m, g, &mut w)?,
        Kind::Rtest => rtest(m, g, &mut w)?,
    }
    if w.rows == 0 {
        return Err(GenerateError::NoneFits);
    }
    Ok(Candidates {
        text: w.out,
        rows: w.rows,
    })
}

/// Collects the rows, refusing to grow past [`MAX_GENERATED`].
struct Writer<'m> {
    m: &'m Machine,
    out: String,
    rows: usize,
    /// The axes whose direction of approach the model uses (backlash): they get `dir_` columns.
    dirs: Vec<usize>,
}

impl<'m> Writer<'m> {
    fn new(m: &'m Machine) -> Self {
        let used = kin_model::states::used_vars(m);
        Writer {
            m,
            out: String::new(),
            rows: 0,
            dirs: (0..m.axes.len())
                .filter(|&a| used.contains(&Var::Direction(a)))
                .collect(),
        }
    }

    /// The directions of approach each candidate is written for: both, when the model uses
    /// one (every such axis approaching from the same side), so that a plan can see backlash.
    fn directions(&self) -> &'static [f64] {
        if self.dirs.is_empty() {
            &[1.0]
        } else {
            &[1.0, -1.0]
        }
    }

    fn comment(&mut self, text: &str) {
        self.out.push_str("# ");
        self.out.push_str(text);
        self.out.push('\n');
    }

    /// The header of a point file (`label`: with an `artifact` column) or a length file.
    fn header(&mut self, lengths: bool, label: bool) {
        let mut names = Vec::new();
        let ends: &[&str] = if lengths { &["_1", "_2"] } else { &[""] };
        for end in ends {
            for a in &self.m.axes {
                names.push(format!("{}{end}[{}]", a.name, unit(a.kind).0));
            }
            for &a in &self.dirs {
                if let Some(axis) = self.m.axes.get(a) {
                    names.push(format!("dir_{}{end}", axis.name));
                }
            }
        }
        for i in &self.m.inputs {
            names.push(format!("{}[{}]", i.name, i.unit.name));
        }
        if !self.m.lags.is_empty() {
            // A lag needs a time; the inputs are constant, so every lag is in steady state.
            names.push("time[s]".into());
        }
        if label {
            names.push("artifact".into());
        }
        if !lengths {
            // Empty observed columns: the plan observes what they name (spec/design.md).
            names.extend(["ex", "ey", "ez"].map(String::from));
        }
        self.out.push_str(&names.join(","));
        self.out.push('\n');
    }

    /// One row: the poses (one or two), then the label, then the empty observed cells.
    fn row(
        &mut self,
        poses: &[&[f64]],
        dir: f64,
        label: Option<&str>,
        observed: usize,
    ) -> Result<(), GenerateError> {
        self.rows += 1;
        if self.rows > MAX_GENERATED {
            return Err(GenerateError::TooManyCandidates);
        }
        let mut cells = Vec::new();
        for q in poses {
            for (a, v) in self.m.axes.iter().zip(q.iter()) {
                cells.push(format!("{}", round9(v * unit(a.kind).1)));
            }
            for _ in &self.dirs {
                cells.push(if dir < 0.0 { "-1" } else { "+1" }.to_string());
            }
        }
        for i in &self.m.inputs {
            cells.push(format!("{}", round9(i.unit.from_si(input_reference(i)))));
        }
        if !self.m.lags.is_empty() {
            cells.push("0".into());
        }
        if let Some(l) = label {
            cells.push(l.to_string());
        }
        cells.extend(std::iter::repeat_n(String::new(), observed));
        self.out.push_str(&cells.join(","));
        self.out.push('\n');
        Ok(())
    }
}

/// The value an input is planned at: the middle of its declared range, else 20 °C for an
/// absolute temperature (the reference temperature of length metrology) and 0 for any other
/// input (a temperature rise, a force, … at its reference).
fn input_reference(i: &kin_compiler::ir::Input) -> f64 {
    match i.range {
        Some([lo, hi]) => 0.5 * (lo + hi),
        None if i.absolute => 293.15,
        None => 0.0,
    }
}

fn unit(kind: JointKind) -> (&'static str, f64) {
    match kind {
        JointKind::Revolute => ("deg", 180.0 / std::f64::consts::PI),
        JointKind::Prismatic => ("mm", 1000.0),
    }
}

/// The indices of the axes of one kind, in their order.
fn axes_of(m: &Machine, kind: JointKind) -> Vec<usize> {
    m.axes
        .iter()
        .enumerate()
        .filter(|(_, a)| a.kind == kind)
        .map(|(i, _)| i)
        .collect()
}

fn prismatic(m: &Machine) -> Vec<usize> {
    axes_of(m, JointKind::Prismatic)
}

/// The prismatic axis called `name`.
fn prismatic_named(m: &Machine, name: &str) -> Result<usize, GenerateError> {
    prismatic(m)
        .into_iter()
        .find(|&i| m.axes.get(i).is_some_and(|a| a.name == name))
        .ok_or_else(|| GenerateError::NotPrismatic(name.to_string()))
}

/// The two prismatic axes of `--plane` (the first two declared when it is empty).
fn plane(m: &Machine, g: &Generate, what: &'static str) -> Result<(usize, usize), GenerateError> {
    let axes: Vec<usize> = if g.plane.is_empty() {
        prismatic(m).into_iter().take(2).collect()
    } else {
        g.plane
            .iter()
            .map(|n| prismatic_named(m, n))
            .collect::<Result<_, _>>()?
    };
    match axes.as_slice() {
        [u, v] if u != v => Ok((*u, *v)),
        _ => Err(GenerateError::Plane(what)),
    }
}

fn range(m: &Machine, i: usize) -> [f64; 2] {
    m.axes.get(i).map_or([0.0, 0.0], |a| a.range)
}

fn inside(x: f64, r: [f64; 2]) -> bool {
    x >= r[0] - EPS && x <= r[1] + EPS
}

/// `lower, lower + step, …` up to the upper end of `r` (the upper end itself when on the grid).
fn grid(r: [f64; 2], step: f64) -> Vec<f64> {
    let n = ((r[1] - r[0]) / step + 1e-9).floor();
    if !(n.is_finite() && n >= 0.0) || n > MAX_GENERATED as f64 {
        return vec![r[0]];
    }
    (0..=n as usize).map(|k| r[0] + step * k as f64).collect()
}

/// The angles of a revolute axis on a grid of `step`: `[0, 2π)` for a continuous axis, its range
/// from the lower end otherwise.
fn angles(m: &Machine, i: usize, step: f64) -> Vec<f64> {
    match m.axes.get(i) {
        Some(a) if a.continuous => {
            let n = (std::f64::consts::TAU / step - 1e-9).ceil().max(1.0) as usize;
            (0..n).map(|k| step * k as f64).collect()
        }
        Some(a) => grid(a.range, step),
        None => Vec::new(),
    }
}

/// Every combination of positions of the axes not in `fixed`: `levels` evenly spaced positions
/// of each prismatic axis (the middle when 1), the middle of each revolute axis's range.
fn others(m: &Machine, fixed: &[usize], levels: usize) -> Result<Vec<Vec<f64>>, GenerateError> {
    let mut out = vec![m
        .axes
        .iter()
        .map(|a| 0.5 * (a.range[0] + a.range[1]))
        .collect::<Vec<f64>>()];
    for (i, a) in m.axes.iter().enumerate() {
        if fixed.contains(&i) || a.kind != JointKind::Prismatic || levels < 2 {
            continue;
        }
        if out.len().saturating_mul(levels) > MAX_GENERATED {
            return Err(GenerateError::TooManyLevels(levels));
        }
        let values: Vec<f64> = (0..levels)
            .map(|k| a.range[0] + (a.range[1] - a.range[0]) * k as f64 / (levels - 1) as f64)
            .collect();
        out = out
            .iter()
            .flat_map(|q| {
                values.iter().map(move |&v| {
                    let mut q = q.clone();
                    if let Some(slot) = q.get_mut(i) {
                        *slot = v;
                    }
                    q
                })
            })
            .collect();
    }
    Ok(out)
}

/// Ball bars in the plane of two prismatic axes: the first sphere on a grid of `step` over both
/// ranges, the bar at every multiple of `angle_step` in [0°, 360°) from the first plane axis
/// towards the second, kept when the second sphere is inside the ranges too.
fn ballbar(m: &Machine, g: &Generate, w: &mut Writer) -> Result<(), GenerateError> {
    let (u, v) = plane(m, g, "ball-bar")?;
    let (ru, rv) = (range(m, u), range(m, v));
    let turns = (std::f64::consts::TAU / g.angle_step).round().max(1.0) as usize;
    w.comment(&format!(
        "ball-bar candidates: length {} mm, grid {} mm, angle step {} deg",
        round9(g.length * 1e3),
        round9(g.step * 1e3),
        round9(g.angle_step.to_degrees())
    ));
    w.header(true, false);
    for base in others(m, &[u, v], g.levels)? {
        for &x in &grid(ru, g.step) {
            for &y in &grid(rv, g.step) {
                for k in 0..turns {
                    let (sn, cs) = (g.angle_step * k as f64).sin_cos();
                    let (x2, y2) = (x + g.length * cs, y + g.length * sn);
                    if !(inside(x2, ru) && inside(y2, rv)) {
                        continue;
                    }
                    let (mut q1, mut q2) = (base.clone(), base.clone());
                    set(&mut q1, u, x);
                    set(&mut q1, v, y);
                    set(&mut q2, u, x2);
                    set(&mut q2, v, y2);
                    for &d in w.directions() {
                        w.row(&[&q1, &q2], d, None, 0)?;
                    }
                }
            }
        }
    }
    Ok(())
}

fn set(q: &mut [f64], i: usize, value: f64) {
    if let Some(slot) = q.get_mut(i) {
        *slot = value;
    }
}

/// A step gauge along one prismatic axis: its first face on a grid of `step` from the lower end
/// of the range, each row the distance from the first face to one of the others (`pitch`
/// apart, up to `length`), the whole gauge inside the range; the other prismatic axes at
/// `levels` positions each (the gauge's lines).
fn stepgauge(m: &Machine, g: &Generate, w: &mut Writer) -> Result<(), GenerateError> {
    let axis = match &g.axis {
        Some(name) => prismatic_named(m, name)?,
        None => *prismatic(m).first().ok_or(GenerateError::NoPrismaticAxis)?,
    };
    let r = range(m, axis);
    let faces = (g.length / g.pitch + 1e-9).floor() as usize;
    if faces == 0 {
        return Err(GenerateError::OneFace);
    }
    let name = m.axes.get(axis).map_or("", |a| a.name.as_str());
    w.comment(&format!(
        "step-gauge candidates along {name}: faces every {} mm up to {} mm, first face every {} mm, {} line(s)",
        round9(g.pitch * 1e3),
        round9(faces as f64 * g.pitch * 1e3),
        round9(g.step * 1e3),
        others(m, &[axis], g.levels)?.len()
    ));
    w.header(true, false);
    for base in others(m, &[axis], g.levels)? {
        for &s in &grid(r, g.step) {
            if !inside(s + faces as f64 * g.pitch, r) {
                continue;
            }
            for k in 1..=faces {
                let (mut q1, mut q2) = (base.clone(), base.clone());
                set(&mut q1, axis, s);
                set(&mut q2, axis, s + g.pitch * k as f64);
                for &d in w.directions() {
                    w.row(&[&q1, &q2], d, None, 0)?;
                }
            }
        }
    }
    Ok(())
}

/// A plate with a square grid of features `pitch` apart over a side of `length`, its first
/// feature on a grid of `step` over the plane, turned by every multiple of `angle_step` in
/// [0°, 90°) (the grid is the same after a quarter turn); a placement is kept when every
/// feature is inside the ranges, and is one `artifact` label (its placement is unknown).
fn plate(m: &Machine, g: &Generate, w: &mut Writer) -> Result<(), GenerateError> {
    let (u, v) = plane(m, g, "plate")?;
    let (ru, rv) = (range(m, u), range(m, v));
    let side = (g.length / g.pitch + 1e-9).floor() as usize;
    let turns = (std::f64::consts::FRAC_PI_2 / g.angle_step - 1e-9)
        .ceil()
        .max(1.0) as usize;
    w.comment(&format!(
        "plate candidates: {n}×{n} features {} mm apart, first feature every {} mm, turned in steps of {} deg; one placement per artifact label",
        round9(g.pitch * 1e3),
        round9(g.step * 1e3),
        round9(g.angle_step.to_degrees()),
        n = side + 1
    ));
    w.header(false, true);
    let mut placement = 0usize;
    for base in others(m, &[u, v], g.levels)? {
        for &x in &grid(ru, g.step) {
            for &y in &grid(rv, g.step) {
                for k in 0..turns {
                    let (sn, cs) = (g.angle_step * k as f64).sin_cos();
                    let features: Vec<(f64, f64)> = (0..=side)
                        .flat_map(|i| (0..=side).map(move |j| (i, j)))
                        .map(|(i, j)| {
                            let (a, b) = (g.pitch * i as f64, g.pitch * j as f64);
                            (x + a * cs - b * sn, y + a * sn + b * cs)
                        })
                        .collect();
                    if !features
                        .iter()
                        .all(|&(fu, fv)| inside(fu, ru) && inside(fv, rv))
                    {
                        continue;
                    }
                    placement += 1;
                    for &d in w.directions() {
                        let label = match (w.dirs.is_empty(), d < 0.0) {
                            (true, _) => format!("plate{placement}"),
                            (false, false) => format!("plate{placement}+"),
                            (false, true) => format!("plate{placement}-"),
                        };
                        for &(fu, fv) in &features {
                            let mut q = base.clone();
                            set(&mut q, u, fu);
                            set(&mut q, v, fv);
                            w.row(&[&q], d, Some(&label), 3)?;
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// R-test: for each sphere, each revolute axis swept over its grid of `angle_step` with the other
/// revolute axes at each of their grid angles; at every angle the prismatic axes place the
/// (first declared) tool's nominal point at the sphere. One sweep is one `artifact` label: the
/// sphere's placement on the table is unknown and taken out per sweep. Angles at which the
/// prismatic axes cannot reach the sphere within their ranges are left out; a sweep needs two
/// angles or more.
fn rtest(m: &Machine, g: &Generate, w: &mut Writer) -> Result<(), GenerateError> {
    let revolute = axes_of(m, JointKind::Revolute);
    if revolute.is_empty() {
        return Err(GenerateError::NoRevoluteAxis);
    }
    let linear = prismatic(m);
    let spheres: Vec<[f64; 3]> = if g.spheres.is_empty() {
        DEFAULT_SPHERES.to_vec()
    } else {
        g.spheres.clone()
    };
    w.comment(&format!(
        "R-test candidates: spheres at {} mm (workpiece frame), rotary axes every {} deg; one sweep of one rotary axis per artifact label",
        spheres
            .iter()
            .map(|s| format!(
                "({}, {}, {})",
                round9(s[0] * 1e3),
                round9(s[1] * 1e3),
                round9(s[2] * 1e3)
            ))
            .collect::<Vec<_>>()
            .join(", "),
        round9(g.angle_step.to_degrees())
    ));
    w.header(false, true);
    let grids: Vec<Vec<f64>> = revolute
        .iter()
        .map(|&i| angles(m, i, g.angle_step))
        .collect();
    let mid: Vec<f64> = m
        .axes
        .iter()
        .map(|a| 0.5 * (a.range[0] + a.range[1]))
        .collect();
    for (s, sphere) in spheres.iter().enumerate() {
        let target = Vector3::from(*sphere);
        for (r, &swept) in revolute.iter().enumerate() {
            // Every combination of the other revolute axes' grid angles.
            let mut settings: Vec<Vec<(usize, f64)>> = vec![Vec::new()];
            for (o, &other) in revolute.iter().enumerate() {
                if o == r {
                    continue;
                }
                let values = grids.get(o).cloned().unwrap_or_default();
                if settings.len().saturating_mul(values.len()) > MAX_GENERATED {
                    return Err(GenerateError::TooManySweeps);
                }
                settings = settings
                    .iter()
                    .flat_map(|set| {
                        values.iter().map(move |&a| {
                            let mut set = set.clone();
                            set.push((other, a));
                            set
                        })
                    })
                    .collect();
            }
            if linear.is_empty() {
                // Nothing to move the tool to the sphere with (and no Jacobian to solve).
                return Err(GenerateError::RtestWithoutPrismaticAxis);
            }
            for setting in settings {
                let mut rows = Vec::new();
                for &angle in grids.get(r).map_or(&[][..], |v| v.as_slice()) {
                    let mut q = mid.clone();
                    for &(i, a) in &setting {
                        set(&mut q, i, a);
                    }
                    set(&mut q, swept, angle);
                    if let Some(q) = reach(m, &linear, q, &target)? {
                        rows.push(q);
                    }
                }
                if rows.len() < 2 {
                    continue;
                }
                let name = |i: usize| m.axes.get(i).map_or("", |a| a.name.as_str());
                let mut label = format!("s{}_{}", s + 1, name(swept));
                for &(i, a) in &setting {
                    label.push_str(&format!("_{}{}", name(i), round9(a.to_degrees())));
                }
                for &d in w.directions() {
                    let label = match (w.dirs.is_empty(), d < 0.0) {
                        (true, _) => label.clone(),
                        (false, false) => format!("{label}+"),
                        (false, true) => format!("{label}-"),
                    };
                    for q in &rows {
                        w.row(&[q], d, Some(&label), 3)?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// The prismatic positions (from `q`'s, the revolute angles kept) that put the first tool's
/// nominal point at `target` in the workpiece frame, or None when they are outside the ranges.
/// With the angles fixed the tool point is affine in the prismatic positions (translations
/// composed with fixed rotations), so one step of least squares solves it exactly.
fn reach(
    m: &Machine,
    linear: &[usize],
    mut q: Vec<f64>,
    target: &Vector3<f64>,
) -> Result<Option<Vec<f64>>, KinematicsError> {
    let point = |q: &[f64]| -> Result<Vector3<f64>, KinematicsError> {
        let pose = Pose {
            q,
            tool: 0,
            tool_offset: None,
        };
        exact::nominal_transform(m, &pose).map(|t| Vector3::new(t[(0, 3)], t[(1, 3)], t[(2, 3)]))
    };
    let p0 = point(&q)?;
    let mut j = DMatrix::zeros(3, linear.len());
    for (c, &i) in linear.iter().enumerate() {
        let mut moved = q.clone();
        if let Some(v) = moved.get_mut(i) {
            *v += 1.0;
        }
        let d = point(&moved)? - p0;
        j.set_column(c, &d);
    }
    let rhs = DVector::from_iterator(3, (target - p0).iter().copied());
    let Ok(step) = j.clone().svd(true, true).solve(&rhs, 1e-12) else {
        return Ok(None);
    };
    if (&j * &step - &rhs).norm() > 1e-9 {
        // The prismatic axes cannot move the tool point there (fewer than three directions).
        return Ok(None);
    }
    for (c, &i) in linear.iter().enumerate() {
        if let Some(v) = q.get_mut(i) {
            *v += step[c];
            if !inside(*v, range(m, i)) {
                return Ok(None);
            }
        }
    }
    Ok(Some(q))
}

/// Nine decimals: nanometres in mm, far below any machine's resolution, and no `1e-14` noise.
fn round9(v: f64) -> f64 {
    let r = (v * 1e9).round() / 1e9;
    if r == 0.0 {
        0.0
    } else {
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kin_compiler::compile;

    /// Three slides carrying the tool over a rotary table C.
    const RTEST: &str = "machine rotary { task position
        units { length mm, angle deg, error um, tilt urad }
        axis X prismatic along x range -300 mm .. 300 mm  axis Y prismatic along y range -300 mm .. 300 mm
        axis Z prismatic along z range -300 mm .. 300 mm  axis C revolute about z range -90 deg .. 90 deg
        tool chain { X moving  Y moving  Z moving  tool t at (0, 0, -100) mm }
        workpiece chain { C fixed  workpiece }  errors { X.tx = const } }";

    fn request(kind: Kind) -> Generate {
        Generate {
            kind,
            length: 0.2,
            step: 0.1,
            pitch: 0.1,
            angle_step: 30f64.to_radians(),
            plane: Vec::new(),
            axis: Some("X".into()),
            levels: 1,
            spheres: Vec::new(),
        }
    }

    /// The data rows of a candidate file, as numbers (an empty cell as NaN, a label skipped).
    fn rows(text: &str) -> Vec<Vec<f64>> {
        text.lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .map(|l| l.split(',').filter_map(|c| c.parse().ok()).collect())
            .collect()
    }

    #[test]
    fn a_step_gauge_stays_inside_its_axis_range() {
        let c = compile(RTEST).compiled.expect("compiles");
        let out = generate(&c.machine, &request(Kind::Stepgauge)).expect("candidates");
        // First faces −300, −200, …, 100 mm (the last face 200 mm further inside the range),
        // each measured to the two faces after it.
        assert_eq!(out.rows, 10);
        let rows = rows(&out.text);
        assert_eq!(rows.len(), 10);
        for r in &rows {
            // X_1 and X_2 (mm), the other axes at the middle of their ranges.
            assert!(r[0] >= -300.0 && r[4] <= 300.0 && r[4] > r[0], "{r:?}");
        }
    }

    #[test]
    fn r_test_poses_put_the_tool_at_the_sphere() {
        let c = compile(RTEST).compiled.expect("compiles");
        let m = &c.machine;
        let out = generate(m, &request(Kind::Rtest)).expect("candidates");
        let rows = rows(&out.text);
        assert_eq!(rows.len(), out.rows);
        // Three spheres, C from −90° to 90° in steps of 30°: seven angles each.
        assert_eq!(out.rows, 21);
        for (r, sphere) in rows.iter().zip(DEFAULT_SPHERES.iter().flat_map(|s| [s; 7])) {
            let q = [r[0] * 1e-3, r[1] * 1e-3, r[2] * 1e-3, r[3].to_radians()];
            let pose = Pose {
                q: &q,
                tool: 0,
                tool_offset: None,
            };
            let t = exact::nominal_transform(m, &pose).expect("transform");
            for k in 0..3 {
                assert!((t[(k, 3)] - sphere[k]).abs() < 1e-9, "{r:?} {sphere:?}");
            }
        }
    }

    #[test]
    fn requests_the_machine_cannot_meet_are_refused() {
        let c = compile(RTEST).compiled.expect("compiles");
        let m = &c.machine;
        let mut g = request(Kind::Ballbar);
        g.length = 0.0;
        assert!(matches!(
            generate(m, &g),
            Err(GenerateError::NotPositive("--length"))
        ));
        let mut g = request(Kind::Plate);
        g.plane = vec!["X".into(), "X".into()];
        assert!(matches!(
            generate(m, &g),
            Err(GenerateError::Plane("plate"))
        ));
        let mut g = request(Kind::Stepgauge);
        g.axis = Some("C".into());
        assert!(matches!(
            generate(m, &g),
            Err(GenerateError::NotPrismatic(axis)) if axis == "C"
        ));
        // A turntable alone: no prismatic axis to follow the sphere with (and no empty
        // Jacobian to solve).
        let c = compile(
            "machine turntable { task position units { length mm, angle deg, error um, tilt urad } \
             axis C revolute about z range -90 deg .. 90 deg \
             tool chain { tool t at (0, 0, 100) mm } workpiece chain { C fixed workpiece } \
             errors { C.rz = const } }",
        )
        .compiled
        .expect("compiles");
        assert!(matches!(
            generate(&c.machine, &request(Kind::Rtest)),
            Err(GenerateError::RtestWithoutPrismaticAxis)
        ));
    }
}
