//! Registration of absolute measurements (spec/data.md, "Absolute positions"; spec/robots.md).
//!
//! A tracker, a motion-capture system or a CMM measures a target on the tool (a reflector, a
//! marker) in its own frame, placed somewhere relative to the machine, and the target sits
//! somewhere on the tool. Those placements are finite — a tracker metres away and turned any
//! way, a reflector a hand's width off the flange — so they cannot be first-order error terms.
//! They are fitted as finite transforms, jointly with the error model:
//!
//! `y = R (p(q, o) + e(q, o; β)) + t`
//!
//! where `y` is the measured position, `(R, t)` the instrument's placement (wr → instrument),
//! `p` the nominal tool point with the target at offset `o` in the frame the tool is attached
//! to, and `e` the model's first-order positioning error. With `(R, t, o)` at their current
//! values, `R⊤(y − t) − p` is an ordinary observed error; a change of the placement
//! `R ← R·exp([a]×)`, `t ← t + R b` and of the offset `o ← o + d` adds `b + a × p + A d` to it
//! to first order (`A` the attachment frame's axes in wr), which the fit estimates as nuisance
//! parameters beside β (the design rows of [`crate::fit::for_each_row`]). Each Gauss–Newton
//! step applies the estimated change exactly and recomputes the observed errors, until the
//! change is a negligible fraction of its standard error: the converged fit is the exact least-squares solution of the model
//! above, and the last fit's nuisance standard errors are the placement's.
//!
//! The start is closed-form: the Kabsch (Horn) rotation between the nominal and the measured
//! points with the targets at their declared offsets, then a few Gauss–Newton steps of the
//! placement and the offsets alone with the nominal model.

use std::path::PathBuf;

use kin_compiler::ir::Task;
use kin_compiler::Compiled;
use kin_data::data::{Absolute, Observations, PointData};
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::fit::{
    self, declared_offset, states, DataSet, DesignError, FileStates, FitError, FitResult,
    NuisanceKind, Options,
};
use kin_model::engine::Evaluator;

/// Gauss–Newton steps of the joint fit before giving up.
const MAX_STEPS: usize = 30;
/// Converged when every change is below this fraction of its standard error.
const NEGLIGIBLE: f64 = 1e-4;
/// Steps of the closed-form start's placement-only refinement.
const START_STEPS: usize = 20;

/// Where the instrument of one file sits and where its targets sit on the tool.
#[derive(Debug, Clone, Serialize)]
pub struct Placement {
    pub path: PathBuf,
    /// wr → instrument: a point `p` of wr is at `rotation · p + translation` in the
    /// instrument's frame (rows of the matrix, SI).
    pub rotation: [[f64; 3]; 3],
    pub translation: [f64; 3],
    /// Per target label (as the file names them, `""` for a file without `target`): its
    /// offset in the frame the tool is attached to, m.
    pub targets: Vec<(String, [f64; 3])>,
    /// Per target (as `targets`), its frame's orientation relative to the tool frame (rows),
    /// fitted when the file measures orientations; the identity otherwise.
    pub turns: Vec<[[f64; 3]; 3]>,
}

impl Placement {
    fn r(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.rotation[i][j])
    }

    fn set_r(&mut self, r: &Matrix3<f64>) {
        self.rotation = std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)]));
    }

    /// The instrument → wr transform's rotation as a rotation vector (rad) and its translation
    /// (m): where the instrument sits as seen from the machine.
    pub fn instrument_in_wr(&self) -> ([f64; 3], [f64; 3]) {
        let r = self.r();
        let inverse = r.transpose();
        let t = -(inverse * Vector3::from(self.translation));
        let v = Rotation3::from_matrix_unchecked(inverse).scaled_axis();
        ([v.x, v.y, v.z], [t.x, t.y, t.z])
    }
}

/// The outcome of [`register`].
#[derive(Debug, Clone)]
pub struct Registration {
    pub placements: Vec<Placement>,
    /// The files as observed errors at the final placements, with the targets' offsets per
    /// row: what the final fit (and a diagnosis) reads.
    pub files: Vec<DataSet>,
    /// Gauss–Newton steps of the joint fit.
    pub steps: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum RegisterError {
    #[error("{path}: the measured positions do not fix the instrument's placement: {reason}")]
    Degenerate { path: String, reason: String },
    #[error(
        "the registration does not converge in {MAX_STEPS} steps: the last change of a \
         placement was {ratio:.3} of its standard error (the model and the measured positions \
         may disagree far beyond first order)"
    )]
    NotConverged { ratio: f64 },
    #[error(
        "{path}: absolute positions in a file that is not fitted: its instrument's placement is \
         unknown (hold rows of a fitted file out with --holdout instead)"
    )]
    Unregistered { path: String },
    #[error(transparent)]
    Design(#[from] DesignError),
    #[error(transparent)]
    Fit(#[from] FitError),
}

/// One file's placement as FIT.json and the summary show it (spec/json.md), in the model's
/// display units.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PlacementReport {
    pub file: String,
    pub length_unit: String,
    pub angle_unit: String,
    /// The instrument's origin in wr.
    pub instrument_position: [f64; 3],
    /// The instrument's orientation in wr: the rotation vector of its axes (angle unit).
    pub instrument_rotation: [f64; 3],
    /// Standard uncertainty of the placement as a shift of wr's origin along wr's axes
    /// (length unit) and a rotation about them (angle unit).
    pub shift_u: [f64; 3],
    pub rotation_u: [f64; 3],
    pub targets: Vec<TargetReport>,
}

/// A target's offset on the tool, in the axes of the frame the tool is attached to.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TargetReport {
    /// As the file's `target` column names it; empty without the column.
    pub label: String,
    pub offset: [f64; 3],
    pub offset_u: [f64; 3],
    /// Where orientations are measured: the target frame's turn relative to the tool frame,
    /// a rotation vector (angle unit), and its standard uncertainties about the tool frame's
    /// axes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turn: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turn_u: Option<[f64; 3]>,
}

/// The placements with the standard uncertainties of `result` (the fit at the converged
/// placements), in `m`'s display units.
pub fn report(
    m: &kin_compiler::ir::Machine,
    registration: &Registration,
    result: &FitResult,
) -> Vec<PlacementReport> {
    let n = result.layout.coefficients;
    let var = result.variances();
    let length = &m.units.length;
    let angle = &m.units.angle;
    let files: Vec<usize> = result
        .layout
        .nuisance
        .iter()
        .filter(|nu| matches!(nu.kind, NuisanceKind::InstrumentShift(0)))
        .map(|nu| nu.file)
        .collect();
    let u = |file: usize, kind: NuisanceKind, label: &str| -> f64 {
        result
            .layout
            .nuisance
            .iter()
            .position(|nu| nu.file == file && nu.kind == kind && nu.artifact == label)
            .and_then(|k| var.get(n + k))
            .map_or(f64::NAN, |v| v.max(0.0).sqrt())
    };
    // A target's columns by its place in the file (a named target shared with an earlier file
    // has that file's columns): the first, then three offsets and, where fitted, three turns.
    let target_u = |file: usize, target: usize, k: usize| -> f64 {
        result
            .layout
            .target_columns(file)
            .get(target)
            .and_then(|first| var.get(first + k))
            .map_or(f64::NAN, |v| v.max(0.0).sqrt())
    };
    let turned = |file: usize, target: usize| -> bool {
        result
            .layout
            .target_columns(file)
            .get(target)
            .and_then(|first| result.layout.nuisance.get(first + 3 - n))
            .is_some_and(|nu| nu.kind == NuisanceKind::TargetRotation(0))
    };
    registration
        .placements
        .iter()
        .zip(files)
        .map(|(p, file)| {
            let (rotation, position) = p.instrument_in_wr();
            PlacementReport {
                file: p.path.display().to_string(),
                length_unit: length.name.clone(),
                angle_unit: angle.name.clone(),
                instrument_position: position.map(|v| length.from_si(v)),
                instrument_rotation: rotation.map(|v| angle.from_si(v)),
                shift_u: std::array::from_fn(|k| {
                    u(file, NuisanceKind::InstrumentShift(k), "") / length.scale
                }),
                rotation_u: std::array::from_fn(|k| {
                    u(file, NuisanceKind::InstrumentRotation(k), "") / angle.scale
                }),
                targets: p
                    .targets
                    .iter()
                    .zip(&p.turns)
                    .enumerate()
                    .map(|(t, ((label, o), turn))| {
                        let fitted = turned(file, t);
                        let turn_u: [f64; 3] =
                            std::array::from_fn(|k| target_u(file, t, 3 + k) / angle.scale);
                        let v = Rotation3::from_matrix_unchecked(matrix(turn)).scaled_axis();
                        TargetReport {
                            label: label.clone(),
                            offset: o.map(|v| length.from_si(v)),
                            offset_u: std::array::from_fn(|k| target_u(file, t, k) / length.scale),
                            turn: fitted.then(|| [v.x, v.y, v.z].map(|x| angle.from_si(x))),
                            turn_u: fitted.then_some(turn_u),
                        }
                    })
                    .collect(),
            }
        })
        .collect()
}

/// Whether any file holds absolute positions.
pub fn any_absolute(files: &[DataSet]) -> bool {
    files.iter().any(|f| absolute(f).is_some())
}

fn absolute(f: &DataSet) -> Option<(&PointData, &Absolute)> {
    match &f.observations {
        Observations::Points(p) => p.absolute.as_ref().map(|a| (p, a)),
        Observations::Lengths(_) => None,
    }
}

/// Registers every file of absolute positions jointly with the error model (module docs);
/// other files are fitted alongside unchanged.
pub fn register(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    options: &Options,
    progress: fit::Progress,
) -> Result<Registration, RegisterError> {
    let m = &compiled.machine;
    let mut placements = Vec::new();
    for f in files {
        let Some((p, a)) = absolute(f) else {
            placements.push(None);
            continue;
        };
        placements.push(Some(start(engine, f, p, a)?));
    }
    share_targets(&mut placements);
    let sign = match m.task {
        Task::Position => 1.0,
        Task::Measure => -1.0,
    };
    let mut worst = f64::INFINITY;
    for step in 1..=MAX_STEPS {
        let sets = observed(engine, files, &placements)?;
        let result = fit::fit(compiled, engine, &sets, &[], options, &mut *progress)?;
        worst = apply(&result, &mut placements, sign);
        if worst <= NEGLIGIBLE {
            let files = observed(engine, files, &placements)?;
            return Ok(Registration {
                placements: placements.into_iter().flatten().collect(),
                files,
                steps: step,
            });
        }
    }
    Err(RegisterError::NotConverged { ratio: worst })
}

/// Files of absolute positions (`held`, e.g. held out of a fit) as observed errors at the
/// placements a registration found for the files of the same path, or whose rows they were
/// held out of (a file it did not fit is an error: its instrument's placement is unknown).
/// The placements stay fixed: a fit validated on the result predicts these rows, it does not
/// place their instrument again.
pub fn observe_with(
    engine: &mut dyn Evaluator,
    registration: &Registration,
    held: &[DataSet],
) -> Result<Vec<DataSet>, RegisterError> {
    let mut kept = Vec::new();
    let mut placements = Vec::new();
    for f in held {
        match absolute(f) {
            None => {
                kept.push(f.clone());
                placements.push(None);
            }
            Some(_) => {
                let p = registration
                    .placements
                    .iter()
                    .find(|p| {
                        let mut held = p.path.clone().into_os_string();
                        held.push(fit::HELD_OUT);
                        p.path == f.path || held == f.path.as_os_str()
                    })
                    .ok_or_else(|| RegisterError::Unregistered {
                        path: f.path.display().to_string(),
                    })?;
                kept.push(f.clone());
                placements.push(Some(p.clone()));
            }
        }
    }
    // Their placement is the fitted one, not theirs to refit: without their absolute
    // positions a fit has no nuisance columns for them, and their residuals are predictions.
    let mut out = observed(engine, &kept, &placements)?;
    for f in &mut out {
        if let Observations::Points(p) = &mut f.observations {
            p.absolute = None;
        }
    }
    Ok(out)
}

/// A named target measured in several files is one target: every file starts from the first
/// file's estimate of it (each file's closed-form start found its own).
fn share_targets(placements: &mut [Option<Placement>]) {
    let mut first: Vec<(String, [f64; 3], [[f64; 3]; 3])> = Vec::new();
    for p in placements.iter_mut().flatten() {
        for ((label, o), turn) in p.targets.iter_mut().zip(p.turns.iter_mut()) {
            if label.is_empty() {
                continue;
            }
            match first.iter().find(|(l, _, _)| l == label) {
                Some((_, o0, t0)) => {
                    *o = *o0;
                    *turn = *t0;
                }
                None => first.push((label.clone(), *o, *turn)),
            }
        }
    }
}

/// A step of one placement: the shift b and rotation a of the instrument, and per target the
/// shift d of its offset and the turn ρ of its frame.
type Change = ([f64; 3], [f64; 3], Vec<[f64; 3]>, Vec<[f64; 3]>);

/// The change the fit estimated for each placement, applied exactly; returns the largest
/// change over its standard error.
fn apply(result: &FitResult, placements: &mut [Option<Placement>], sign: f64) -> f64 {
    let n = result.layout.coefficients;
    let beta = &result.solution.beta;
    let var = result.variances();
    let mut worst: f64 = 0.0;
    let mut changes: Vec<Change> = placements
        .iter()
        .map(|p| {
            let targets = p.as_ref().map_or(0, |p| p.targets.len());
            (
                [0.0; 3],
                [0.0; 3],
                vec![[0.0; 3]; targets],
                vec![[0.0; 3]; targets],
            )
        })
        .collect();
    for (k, nu) in result.layout.nuisance.iter().enumerate() {
        let j = n + k;
        let value = sign * beta.get(j).copied().unwrap_or(0.0);
        let se = var.get(j).copied().unwrap_or(0.0).max(0.0).sqrt();
        // A named target shared by several files takes its change in each (one set of
        // columns, those of the first file naming it).
        if !nu.artifact.is_empty()
            && matches!(
                nu.kind,
                NuisanceKind::Target(_) | NuisanceKind::TargetRotation(_)
            )
        {
            for (f, p) in placements.iter().enumerate().skip(nu.file + 1) {
                let Some(t) = p
                    .as_ref()
                    .and_then(|p| p.targets.iter().position(|(l, _)| *l == nu.artifact))
                else {
                    continue;
                };
                let shared = result
                    .layout
                    .target_columns(f)
                    .get(t)
                    .is_some_and(|first| (*first..*first + 6).contains(&j));
                let Some((_, _, d, rho)) = changes.get_mut(f) else {
                    continue;
                };
                let slot = match nu.kind {
                    NuisanceKind::Target(i) => d.get_mut(t).and_then(|d| d.get_mut(i)),
                    NuisanceKind::TargetRotation(i) => rho.get_mut(t).and_then(|r| r.get_mut(i)),
                    _ => None,
                };
                if let (true, Some(slot)) = (shared, slot) {
                    *slot = value;
                }
            }
        }
        let Some((b, a, d, rho)) = changes.get_mut(nu.file) else {
            continue;
        };
        let target = || {
            placements
                .get(nu.file)
                .and_then(Option::as_ref)
                .and_then(|p| p.targets.iter().position(|(l, _)| *l == nu.artifact))
        };
        let slot = match nu.kind {
            NuisanceKind::InstrumentShift(i) => b.get_mut(i),
            NuisanceKind::InstrumentRotation(i) => a.get_mut(i),
            NuisanceKind::Target(i) => target()
                .and_then(|t| d.get_mut(t))
                .and_then(|d| d.get_mut(i)),
            NuisanceKind::TargetRotation(i) => target()
                .and_then(|t| rho.get_mut(t))
                .and_then(|r| r.get_mut(i)),
            _ => None,
        };
        if let Some(slot) = slot {
            *slot = value;
            // A change with no standard error (a fit without residual degrees of freedom)
            // is judged on its size alone.
            let ratio = if se > 0.0 {
                value.abs() / se
            } else {
                value.abs() / 1e-12
            };
            worst = worst.max(ratio);
        }
    }
    for (p, (b, a, d, rho)) in placements.iter_mut().zip(changes) {
        let Some(p) = p else { continue };
        let r = p.r();
        let t = Vector3::from(p.translation) + r * Vector3::from(b);
        p.translation = [t.x, t.y, t.z];
        let turned = r * Rotation3::new(Vector3::from(a)).into_inner();
        p.set_r(&turned);
        for ((_, o), d) in p.targets.iter_mut().zip(d) {
            for (o, d) in o.iter_mut().zip(d) {
                *o += d;
            }
        }
        // ρ turns the target frame about the tool frame's axes: R_o ← exp([ρ]×)·R_o.
        for (turn, rho) in p.turns.iter_mut().zip(rho) {
            let m = Rotation3::new(Vector3::from(rho)).into_inner() * matrix(turn);
            *turn = to_rows(&m);
        }
    }
    worst
}

fn matrix(r: &[[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| r[i][j])
}

fn to_rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// The nominal orientation of the tool frame in wr at every row of `p` (its tool offsets
/// included; the offset moves the point, not the frame's axes).
fn nominal_turns(
    engine: &mut dyn Evaluator,
    f: &DataSet,
    p: &PointData,
) -> Result<Vec<Matrix3<f64>>, RegisterError> {
    let m = engine.machine();
    let mut out = Vec::with_capacity(p.rows.len());
    let mut q = vec![0.0; m.axes.len()];
    for row in 0..p.rows.len() {
        for (slot, column) in q.iter_mut().zip(&p.pose.axes) {
            *slot = column.get(row).copied().unwrap_or(f64::NAN);
        }
        let pose = kin_model::kinematics::Pose {
            q: &q,
            tool: p.rows.tool.get(row).copied().unwrap_or(0),
            tool_offset: None,
        };
        let t = kin_model::exact::nominal_transform(m, &pose).map_err(|e| {
            RegisterError::Degenerate {
                path: f.path.display().to_string(),
                reason: format!("line {}: {e}", p.rows.line.get(row).copied().unwrap_or(0)),
            }
        })?;
        out.push(t.fixed_view::<3, 3>(0, 0).into_owned());
    }
    Ok(out)
}

fn measured_turn(a: &Absolute, row: usize) -> Option<Matrix3<f64>> {
    let r = a.rotation.as_ref()?;
    let v = Vector3::from_fn(|c, _| r[c].get(row).copied().unwrap_or(f64::NAN));
    Some(Rotation3::new(v).into_inner())
}

/// The files with absolute positions turned into observed errors `±(R⊤(y − t) − p)` at their
/// placements (the sign of the machine's task), each row's tool offset its target's.
fn observed(
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    placements: &[Option<Placement>],
) -> Result<Vec<DataSet>, RegisterError> {
    let sign = match engine.machine().task {
        Task::Position => 1.0,
        Task::Measure => -1.0,
    };
    let mut out = Vec::with_capacity(files.len());
    for (f, placement) in files.iter().zip(placements) {
        let (Some((p, a)), Some(placement)) = (absolute(f), placement) else {
            out.push(f.clone());
            continue;
        };
        let with = offsets(p, a, placement);
        let nominal = nominal_points(engine, f, &with)?;
        let r = placement.r();
        let t = Vector3::from(placement.translation);
        let mut columns: [Vec<f64>; 3] = Default::default();
        for (row, p0) in nominal.iter().enumerate() {
            let y = measured(a, row);
            let local = r.transpose() * (y - t);
            for (c, column) in columns.iter_mut().enumerate() {
                column.push(sign * (local[c] - p0[c]));
            }
        }
        let [x, y, z] = columns;
        // Orientations, where measured: the tool frame's actual orientation is
        // R⊤·R_y·R_o⊤, its error the rotation vector of that times the nominal's transpose.
        let turned = match a.rotation {
            Some(_) => {
                let nominal = nominal_turns(engine, f, &with)?;
                let mut turned: [Vec<f64>; 3] = Default::default();
                for (row, r_nom) in nominal.iter().enumerate() {
                    let r_o = target_of(a, placement, row)
                        .and_then(|t| placement.turns.get(t))
                        .map_or_else(Matrix3::identity, matrix);
                    let e = measured_turn(a, row).map_or(Vector3::repeat(f64::NAN), |r_y| {
                        let act = r.transpose() * r_y * r_o.transpose();
                        Rotation3::from_matrix_unchecked(act * r_nom.transpose()).scaled_axis()
                    });
                    for (c, column) in turned.iter_mut().enumerate() {
                        column.push(sign * e[c]);
                    }
                }
                Some(turned)
            }
            None => None,
        };
        let mut data = with;
        data.observed = match turned {
            Some([rx, ry, rz]) => [Some(x), Some(y), Some(z), Some(rx), Some(ry), Some(rz)],
            None => [Some(x), Some(y), Some(z), None, None, None],
        };
        out.push(DataSet {
            path: f.path.clone(),
            observations: Observations::Points(data),
        });
    }
    Ok(out)
}

/// Which of `placement`'s targets row `row` measures (by the file's label).
fn target_of(a: &Absolute, placement: &Placement, row: usize) -> Option<usize> {
    let target = a.target.of_row.get(row).copied().unwrap_or(0) as usize;
    let label = a.target.labels.get(target)?;
    placement.targets.iter().position(|(l, _)| l == label)
}

fn measured(a: &Absolute, row: usize) -> Vector3<f64> {
    Vector3::from_fn(|c, _| a.position[c].get(row).copied().unwrap_or(f64::NAN))
}

/// The point data with every row's tool offset set to its target's.
fn offsets(p: &PointData, a: &Absolute, placement: &Placement) -> PointData {
    let mut data = p.clone();
    let mut columns: [Vec<f64>; 3] = Default::default();
    for row in 0..p.rows.len() {
        let o = target_of(a, placement, row)
            .and_then(|t| placement.targets.get(t))
            .map_or([f64::NAN; 3], |(_, o)| *o);
        for (c, column) in columns.iter_mut().enumerate() {
            column.push(o[c]);
        }
    }
    data.rows.tool_offset = Some(columns);
    data
}

/// The nominal tool point in wr of every row of `p` (its tool offsets included).
fn nominal_points(
    engine: &mut dyn Evaluator,
    f: &DataSet,
    p: &PointData,
) -> Result<Vec<Vector3<f64>>, RegisterError> {
    let set = DataSet {
        path: f.path.clone(),
        observations: Observations::Points(p.clone()),
    };
    let m = engine.machine().clone();
    let st = states(&m, std::slice::from_ref(&set))?;
    let Some(FileStates::Points(s)) = st.first() else {
        return Ok(Vec::new());
    };
    let mut out = Vec::with_capacity(s.len());
    for r in 0..s.len() {
        let v = engine
            .nominal_position(&s.get(r))
            .map_err(|source| DesignError::Eval {
                path: f.path.display().to_string(),
                line: s.line.get(r).copied().unwrap_or(0),
                source,
            })?;
        out.push(Vector3::from(v));
    }
    Ok(out)
}

/// The closed-form start: targets at their tools' declared offsets, the Kabsch rotation and
/// translation between nominal and measured points, then Gauss–Newton steps of the placement
/// and the offsets alone (nominal model).
fn start(
    engine: &mut dyn Evaluator,
    f: &DataSet,
    p: &PointData,
    a: &Absolute,
) -> Result<Placement, RegisterError> {
    let path = f.path.display().to_string();
    let degenerate = |reason: String| RegisterError::Degenerate {
        path: path.clone(),
        reason,
    };
    let m = engine.machine().clone();
    let mut targets = Vec::new();
    for (t, label) in a.target.labels.iter().enumerate() {
        let first = a.target.of_row.iter().position(|&x| x as usize == t);
        let tool = first.and_then(|r| p.rows.tool.get(r)).copied().unwrap_or(0);
        targets.push((label.clone(), declared_offset(&m, tool)));
    }
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let turns = vec![identity; targets.len()];
    let mut placement = Placement {
        path: f.path.clone(),
        rotation: identity,
        translation: [0.0; 3],
        targets,
        turns,
    };
    let rows = p.rows.len();
    let nominal = nominal_points(engine, f, &offsets(p, a, &placement))?;
    let measured_points: Vec<Vector3<f64>> = (0..rows).map(|r| measured(a, r)).collect();
    let (r, t) = kabsch(&nominal, &measured_points).ok_or_else(|| {
        degenerate(
            "the poses must place the target at three points or more, not all on one line".into(),
        )
    })?;
    placement.set_r(&r);
    placement.translation = [t.x, t.y, t.z];
    let labels = placement.targets.len();
    let unknowns = 6 + 3 * labels;
    for _ in 0..START_STEPS {
        let with = offsets(p, a, &placement);
        let p0 = nominal_points(engine, f, &with)?;
        // The attachment frame's axes in wr at each row: the change of the point when the
        // target moves by 1 m along each (exact: the point is affine in the offset).
        let mut along: [Vec<Vector3<f64>>; 3] = Default::default();
        for (k, column) in along.iter_mut().enumerate() {
            let mut moved = with.clone();
            if let Some(c) = moved.rows.tool_offset.as_mut().and_then(|o| o.get_mut(k)) {
                c.iter_mut().for_each(|v| *v += 1.0);
            }
            let p1 = nominal_points(engine, f, &moved)?;
            *column = p1.iter().zip(&p0).map(|(a, b)| a - b).collect();
        }
        let r = placement.r();
        let t = Vector3::from(placement.translation);
        let mut jac = DMatrix::<f64>::zeros(3 * rows, unknowns);
        let mut res = DVector::<f64>::zeros(3 * rows);
        // Every list here has one entry per row (built from the same rows): zipped, a row
        // that lacks one is left out rather than indexed past the end.
        let [a0, a1, a2] = &along;
        let rows_of = measured_points
            .iter()
            .zip(&p0)
            .zip(a0.iter().zip(a1).zip(a2));
        for (row, ((y, p), ((c0, c1), c2))) in rows_of.enumerate() {
            let target = a.target.of_row.get(row).copied().unwrap_or(0) as usize;
            if target >= labels {
                continue;
            }
            let local = r.transpose() * (y - t) - p;
            let axes = [c0, c1, c2];
            for c in 0..3 {
                let i = 3 * row + c;
                res[i] = local[c];
                jac[(i, c)] = 1.0;
                for (k, axis) in axes.iter().enumerate() {
                    let e = Vector3::from_fn(|x, _| if x == k { 1.0 } else { 0.0 });
                    jac[(i, 3 + k)] = e.cross(p)[c];
                    jac[(i, 6 + 3 * target + k)] = axis[c];
                }
            }
        }
        let svd = jac.svd(true, true);
        let step = svd
            .solve(&res, 1e-10 * svd.singular_values.max())
            .map_err(|e| degenerate(e.to_string()))?;
        let rank = svd
            .singular_values
            .iter()
            .filter(|&&s| s > 1e-10 * svd.singular_values.max())
            .count();
        if rank < unknowns {
            return Err(degenerate(format!(
                "the poses determine only {rank} of the {unknowns} unknowns of the instrument's \
                 placement (6) and the targets' offsets (3 each): turn the tool between poses, \
                 so that each target is seen from several orientations"
            )));
        }
        let b = [step[0], step[1], step[2]];
        let w = [step[3], step[4], step[5]];
        let t = t + r * Vector3::from(b);
        placement.translation = [t.x, t.y, t.z];
        placement.set_r(&(r * Rotation3::new(Vector3::from(w)).into_inner()));
        for (t, (_, o)) in placement.targets.iter_mut().enumerate() {
            for (k, o) in o.iter_mut().enumerate() {
                *o += step[6 + 3 * t + k];
            }
        }
        if step.amax() < 1e-12 {
            break;
        }
    }
    // Where orientations are measured, each target frame's turn on the tool: the rotation
    // nearest the mean of R_nom⊤·R⊤·R_y over its rows (the chordal mean, projected on SO(3)).
    if a.rotation.is_some() {
        let nominal = nominal_turns(engine, f, &offsets(p, a, &placement))?;
        let r = placement.r();
        for (t, turn) in placement.turns.iter_mut().enumerate() {
            let mut sum = Matrix3::zeros();
            for (row, r_nom) in nominal.iter().enumerate() {
                if a.target.of_row.get(row).copied().unwrap_or(0) as usize != t {
                    continue;
                }
                if let Some(r_y) = measured_turn(a, row) {
                    sum += r_nom.transpose() * r.transpose() * r_y;
                }
            }
            let svd = sum.svd(true, true);
            if let (Some(u), Some(v_t)) = (svd.u, svd.v_t) {
                let d = (u * v_t).determinant().signum();
                *turn = to_rows(&(u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t));
            }
        }
    }
    Ok(placement)
}

/// The rotation and translation minimising `Σ |b − (R a + t)|²` (Kabsch; Horn 1987 in matrix
/// form), or `None` when the points `a` lie on a line.
fn kabsch(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let n = a.len().min(b.len());
    if n < 3 {
        return None;
    }
    let ca = a.iter().take(n).sum::<Vector3<f64>>() / n as f64;
    let cb = b.iter().take(n).sum::<Vector3<f64>>() / n as f64;
    let mut h = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        h += (p - ca) * (q - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    // Points on a line leave two singular values at zero: no rotation about the line is seen.
    if s[1] <= 1e-9 * s[0].max(f64::MIN_POSITIVE) {
        return None;
    }
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let fix = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    let r = v * fix * u.transpose();
    Some((r, cb - r * ca))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kabsch_recovers_a_finite_rotation() {
        let r = Rotation3::new(Vector3::new(0.3, -1.1, 0.4)).into_inner();
        let t = Vector3::new(0.1, -2.0, 0.5);
        let a: Vec<Vector3<f64>> = (0..7)
            .map(|i| {
                let x = i as f64;
                Vector3::new(x.sin(), (2.0 * x).cos(), 0.3 * x)
            })
            .collect();
        let b: Vec<Vector3<f64>> = a.iter().map(|p| r * p + t).collect();
        let (rr, tt) = kabsch(&a, &b).unwrap_or_else(|| panic!("degenerate"));
        assert!((rr - r).amax() < 1e-12);
        assert!((tt - t).amax() < 1e-12);
        let line: Vec<Vector3<f64>> = (0..5).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        assert!(kabsch(&line, &line).is_none());
    }
}
