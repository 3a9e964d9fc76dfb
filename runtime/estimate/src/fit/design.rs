//! The rows of the least-squares problem: one per observed value of every file.
//!
//! A point row observes one component of the tool-location error (eq. 2.24), a length row the
//! error of a length (eq. 4.5). The unknowns are the model's coefficients β and the nuisance
//! parameters the data asks for: a rigid placement (three shifts, three small rotations about
//! the wr axes) per artifact of a point file, an unknown length error per artifact of a length
//! file (thesis §4.2: "the vector β has to be expanded to include these dimensions").

use std::path::PathBuf;

use kin_compiler::ir::Machine;
use serde::Serialize;

use kin_data::data::{Observations, PointData};
use kin_model::engine::{Evaluator, Observed};
use kin_model::interp::{EvalError, State};
use kin_model::states::{StateError, States};

/// One measurement file, read.
#[derive(Debug, Clone)]
pub struct DataSet {
    pub path: PathBuf,
    pub observations: Observations,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NuisanceKind {
    /// Shift of the artifact along wr axis 0..3.
    Shift(usize),
    /// Small rotation of the artifact about wr axis 0..3.
    Rotation(usize),
    /// Error of the artifact's unknown reference length.
    Length,
    /// Shift of the measuring instrument of a file of absolute positions along wr axis 0..3:
    /// the first-order change of its registration (spec/data.md, "Absolute positions").
    InstrumentShift(usize),
    /// Small rotation of the instrument about wr axis 0..3.
    InstrumentRotation(usize),
    /// Shift of a target's offset on the tool along axis 0..3 of the frame the tool is
    /// attached to.
    Target(usize),
    /// Small rotation of a target's frame about axis 0..3 of the tool frame (files that
    /// measure orientations).
    TargetRotation(usize),
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Nuisance {
    pub file: usize,
    pub artifact: String,
    pub kind: NuisanceKind,
}

impl NuisanceKind {
    /// Whether the parameter belongs to the registration of a file of absolute positions (its
    /// instrument's placement or a target's offset): fitted from all the file's rows together.
    pub fn registers(self) -> bool {
        matches!(
            self,
            NuisanceKind::InstrumentShift(_)
                | NuisanceKind::InstrumentRotation(_)
                | NuisanceKind::Target(_)
                | NuisanceKind::TargetRotation(_)
        )
    }
}

impl Nuisance {
    pub fn name(&self) -> String {
        let axis = |a: usize| ["x", "y", "z"].get(a).copied().unwrap_or("?");
        match self.kind {
            NuisanceKind::Shift(a) => format!("artifact `{}` shift {}", self.artifact, axis(a)),
            NuisanceKind::Rotation(a) => {
                format!("artifact `{}` rotation about {}", self.artifact, axis(a))
            }
            NuisanceKind::Length => format!("artifact `{}` length error", self.artifact),
            NuisanceKind::InstrumentShift(a) => format!("instrument shift {}", axis(a)),
            NuisanceKind::InstrumentRotation(a) => format!("instrument rotation about {}", axis(a)),
            NuisanceKind::Target(a) if self.artifact.is_empty() => {
                format!("target offset {}", axis(a))
            }
            NuisanceKind::Target(a) => format!("target `{}` offset {}", self.artifact, axis(a)),
            NuisanceKind::TargetRotation(a) if self.artifact.is_empty() => {
                format!("target rotation about {}", axis(a))
            }
            NuisanceKind::TargetRotation(a) => {
                format!("target `{}` rotation about {}", self.artifact, axis(a))
            }
        }
    }
}

/// The instrument's stated noise (standard deviations, SI): positions and lengths, rotations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    pub position: Option<f64>,
    pub rotation: Option<f64>,
}

/// What every row of one kind is multiplied by before the fit (rows of SI values).
///
/// Without a stated noise a tilt unit weighs as an error unit (µrad as µm with the default
/// units), so the fit does not depend on SI's choice of metre and radian. With one, every row is
/// divided by its kind's standard deviation (and multiplied by the error unit's scale, so that a
/// weighted residual divided by that scale is `residual / σ`): the weighted least squares that
/// makes µm and µrad rows commensurable, and σ̂ the ratio of the scatter to the stated noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weights {
    /// Position and length rows.
    pub position: f64,
    /// Rotation rows.
    pub rotation: f64,
    /// Whether the weights come from a stated noise (σ̂ is then dimensionless).
    pub stated: bool,
}

impl Weights {
    /// The unit weighting of `m` (no stated noise).
    pub fn unit(m: &Machine) -> Weights {
        Weights {
            position: 1.0,
            rotation: rotation_weight(m),
            stated: false,
        }
    }

    /// The weighting by a stated noise; a kind with no stated σ keeps its unit weight (the fit
    /// refuses data holding such rows, see [`kinds_observed`]).
    pub(crate) fn from_noise(m: &Machine, noise: Option<Noise>) -> Weights {
        let unit = Weights::unit(m);
        let Some(n) = noise else {
            return unit;
        };
        let s = m.units.error.scale;
        let by = |sigma: Option<f64>, fallback: f64| match sigma {
            Some(v) if v > 0.0 && v.is_finite() => s / v,
            _ => fallback,
        };
        Weights {
            position: by(n.position, unit.position),
            rotation: by(n.rotation, unit.rotation),
            stated: true,
        }
    }

    /// The weight of rows of `component` (0..6 = ex..erz, [`LENGTH`]).
    pub fn of(&self, component: u8) -> f64 {
        if (3..6).contains(&component) {
            self.rotation
        } else {
            self.position
        }
    }
}

/// Whether the files observe positions or lengths, and whether they observe rotations.
pub(crate) fn kinds_observed(files: &[DataSet]) -> (bool, bool) {
    let mut kinds = (false, false);
    for f in files {
        match &f.observations {
            Observations::Lengths(_) => kinds.0 = true,
            Observations::Points(p) => {
                for (c, column) in p.observed.iter().enumerate() {
                    let any = column
                        .as_ref()
                        .is_some_and(|v| v.iter().any(|x| !x.is_nan()));
                    if any && c < 3 {
                        kinds.0 = true;
                    } else if any {
                        kinds.1 = true;
                    }
                }
            }
        }
    }
    kinds
}

/// Whether target `label` of file `file` has rotation columns (its file measures orientations).
fn registration_turned(nuisance: &[Nuisance], file: usize, label: &str) -> bool {
    nuisance
        .iter()
        .any(|n| n.file == file && n.artifact == label && n.kind == NuisanceKind::TargetRotation(0))
}

/// The columns: the model's coefficients first, then the nuisance parameters.
#[derive(Debug, Clone)]
pub struct Layout {
    pub coefficients: usize,
    pub nuisance: Vec<Nuisance>,
    /// Per file, per artifact id: the column of its first nuisance parameter.
    first: Vec<Vec<usize>>,
    /// Per file of absolute positions: the column of its instrument's first parameter and,
    /// per target id, of the target's first.
    registration: Vec<Option<(usize, Vec<usize>)>>,
    /// What each row is multiplied by: the one place where rows are weighted.
    pub weights: Weights,
    /// Per file, its own weights when files have σs of their own (stated per file, or
    /// estimated as variance components); empty: every file weighs by `weights`.
    pub file_weights: Vec<Weights>,
}

impl Layout {
    pub fn new(m: &Machine, files: &[DataSet]) -> Layout {
        let coefficients = m.coefficients.len();
        let mut nuisance = Vec::new();
        let mut first = Vec::with_capacity(files.len());
        for (f, file) in files.iter().enumerate() {
            let rows = file.observations.rows();
            let labels = rows
                .artifact
                .as_ref()
                .map(|g| g.labels.clone())
                .unwrap_or_default();
            let mut starts = Vec::with_capacity(labels.len());
            for label in labels {
                starts.push(coefficients + nuisance.len());
                let kinds: Vec<NuisanceKind> = match file.observations {
                    Observations::Points(_) => (0..3)
                        .map(NuisanceKind::Shift)
                        .chain((0..3).map(NuisanceKind::Rotation))
                        .collect(),
                    Observations::Lengths(_) => vec![NuisanceKind::Length],
                };
                nuisance.extend(kinds.into_iter().map(|kind| Nuisance {
                    file: f,
                    artifact: label.clone(),
                    kind,
                }));
            }
            first.push(starts);
        }
        let mut registration = Vec::with_capacity(files.len());
        for (f, file) in files.iter().enumerate() {
            let Observations::Points(PointData {
                absolute: Some(a), ..
            }) = &file.observations
            else {
                registration.push(None);
                continue;
            };
            let instrument = coefficients + nuisance.len();
            nuisance.extend(
                (0..3)
                    .map(NuisanceKind::InstrumentShift)
                    .chain((0..3).map(NuisanceKind::InstrumentRotation))
                    .map(|kind| Nuisance {
                        file: f,
                        artifact: String::new(),
                        kind,
                    }),
            );
            let mut targets = Vec::with_capacity(a.target.labels.len());
            let turned = a.rotation.is_some();
            for label in &a.target.labels {
                // A named target is one physical target across the files (a reflector on the
                // flange seen from two tracker stations): its offset is one set of columns,
                // those of the first file naming it.
                let shared = nuisance.iter().position(|n| {
                    !label.is_empty()
                        && n.artifact == *label
                        && n.kind == NuisanceKind::Target(0)
                        && registration_turned(&nuisance, n.file, label) == turned
                });
                if let Some(k) = shared {
                    targets.push(coefficients + k);
                    continue;
                }
                targets.push(coefficients + nuisance.len());
                let kinds = (0..3)
                    .map(NuisanceKind::Target)
                    .chain((0..3).filter(|_| turned).map(NuisanceKind::TargetRotation));
                nuisance.extend(kinds.map(|kind| Nuisance {
                    file: f,
                    artifact: label.clone(),
                    kind,
                }));
            }
            registration.push(Some((instrument, targets)));
        }
        Layout {
            coefficients,
            nuisance,
            first,
            registration,
            weights: Weights::unit(m),
            file_weights: Vec::new(),
        }
    }

    /// The layout with rows weighted by a stated `noise` (unit weights when `None`) and, when
    /// `per_file` is not empty, each file's rows by its own σs (a kind a file states no σ for
    /// takes `noise`'s).
    pub fn weighted(self, m: &Machine, noise: Option<Noise>, per_file: &[Noise]) -> Layout {
        let file_weights = per_file
            .iter()
            .map(|f| {
                Weights::from_noise(
                    m,
                    Some(Noise {
                        position: f.position.or(noise.and_then(|n| n.position)),
                        rotation: f.rotation.or(noise.and_then(|n| n.rotation)),
                    }),
                )
            })
            .collect();
        let mut weights = Weights::from_noise(m, noise);
        // Per-file σs make every row a multiple of its own σ: σ̂ is then a ratio.
        weights.stated |= !per_file.is_empty();
        Layout {
            weights,
            file_weights,
            ..self
        }
    }

    /// The weights of file `f`'s rows.
    pub fn weights_of(&self, f: usize) -> Weights {
        self.file_weights.get(f).copied().unwrap_or(self.weights)
    }

    pub fn columns(&self) -> usize {
        self.coefficients + self.nuisance.len()
    }

    fn first_of(&self, file: usize, artifact: Option<u32>) -> Option<usize> {
        self.first.get(file)?.get(artifact? as usize).copied()
    }

    /// The first column of each target of file `file` (in the order of its `target` labels),
    /// for a file of absolute positions; a named target measured in several files has one.
    pub fn target_columns(&self, file: usize) -> &[usize] {
        self.registration
            .get(file)
            .and_then(Option::as_ref)
            .map_or(&[], |(_, targets)| targets.as_slice())
    }

    /// The first column of file `file`'s instrument and of its target `target`, for a file of
    /// absolute positions.
    fn registration_of(&self, file: usize, target: u32) -> Option<(usize, usize)> {
        let (instrument, targets) = self.registration.get(file)?.as_ref()?;
        Some((*instrument, *targets.get(target as usize)?))
    }
}

/// Where a row comes from. `component` 0..6 is ex..erz, 6 is a length.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct RowMeta {
    pub file: u32,
    pub line: u32,
    pub component: u8,
}

pub const LENGTH: u8 = 6;

/// The evaluation states of one file (two for a length file: its ends).
// One per data file: the size difference costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum FileStates {
    Points(States),
    Lengths(States, States),
}

#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    #[error("{path}: {source}")]
    State {
        path: String,
        #[source]
        source: StateError,
    },
    #[error("{path}, line {line}: {source}")]
    Eval {
        path: String,
        line: usize,
        #[source]
        source: EvalError,
    },
    #[error(
        "{path}, line {line}: the model's prediction or its derivatives at this row overflow \
         double precision (a value in the row or in the model is far too large to fit)"
    )]
    NotFinite { path: String, line: usize },
    #[error("{}", thin_message(path, labels))]
    ThinArtifacts {
        path: String,
        /// Every label too thin to place, in label order.
        labels: Vec<ThinArtifact>,
    },
}

/// An artifact label of a point file observed too thinly to fix its placement.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ThinArtifact {
    pub label: String,
    /// The label's rows (at most the first 10 line numbers).
    pub lines: Vec<usize>,
    pub rows: usize,
    /// Observed values (non-empty cells of `ex` … `erz`) on those rows.
    pub values: usize,
}

/// The wording of [`DesignError::ThinArtifacts`]: one label at its lines; many as a count and
/// the first few.
fn thin_message(path: &str, labels: &[ThinArtifact]) -> String {
    const RULE: &str = "too few for its placement (3 shifts, 3 rotations): that needs at least 6 \
        observed values, and at least 3 points when its rotations are not observed. Measure it at \
        more points, or leave its `artifact` cells empty to take its placement as nominal";
    let plural = |n: usize, word: &str| format!("{n} {word}{}", if n == 1 { "" } else { "s" });
    match labels {
        [one] => format!(
            "{path}, {} {}: artifact `{}` is observed at {} ({}), {RULE}",
            if one.lines.len() == 1 {
                "line"
            } else {
                "lines"
            },
            one.lines
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", "),
            one.label,
            plural(one.rows, "row"),
            plural(one.values, "value"),
        ),
        _ => {
            const SHOWN: usize = 5;
            let mut list: Vec<String> = labels
                .iter()
                .take(SHOWN)
                .map(|t| {
                    format!(
                        "`{}` ({}, line {})",
                        t.label,
                        plural(t.rows, "row"),
                        t.lines.first().copied().unwrap_or(0)
                    )
                })
                .collect();
            if labels.len() > SHOWN {
                list.push(format!("and {} more", labels.len() - SHOWN));
            }
            format!(
                "{path}: {} are observed too thinly to place: {}. Each is {RULE}",
                plural(labels.len(), "artifact label"),
                list.join(", ")
            )
        }
    }
}

/// Artifacts of a point file observed at too few rows to fix their placement would make the
/// design rank-deficient, found only after factoring a design with six columns per label (cubic
/// in the labels) and then named at the model's terms. They are counted in one pass over the
/// rows and reported at their rows instead, before anything expensive runs.
pub(crate) fn check_artifacts(files: &[DataSet]) -> Result<(), DesignError> {
    for file in files {
        let Observations::Points(p) = &file.observations else {
            // A length file's label adds one length error, fixed by any one row.
            continue;
        };
        let Some(groups) = &p.rows.artifact else {
            continue;
        };
        let mut seen: Vec<(ThinArtifact, bool)> = groups
            .labels
            .iter()
            .map(|label| {
                let t = ThinArtifact {
                    label: label.clone(),
                    lines: Vec::new(),
                    rows: 0,
                    values: 0,
                };
                (t, false)
            })
            .collect();
        for (r, a) in groups.of_row.iter().enumerate() {
            let Some((t, rotations)) = a.and_then(|a| seen.get_mut(a as usize)) else {
                continue;
            };
            t.rows += 1;
            if t.lines.len() < 10 {
                t.lines.push(p.rows.line.get(r).copied().unwrap_or(0));
            }
            for (c, column) in p.observed.iter().enumerate() {
                if column
                    .as_ref()
                    .and_then(|v| v.get(r))
                    .is_some_and(|v| !v.is_nan())
                {
                    t.values += 1;
                    *rotations |= c >= 3;
                }
            }
        }
        judge_artifacts(&file.path.display().to_string(), seen)?;
    }
    Ok(())
}

/// The verdict of [`check_artifacts`] on one file's counts: per label, its rows, values and
/// whether a rotation is observed.
pub(super) fn judge_artifacts(
    path: &str,
    seen: Vec<(ThinArtifact, bool)>,
) -> Result<(), DesignError> {
    let thin: Vec<ThinArtifact> = seen
        .into_iter()
        .filter(|(t, rotations)| t.values < 6 || (!rotations && t.rows < 3))
        .map(|(t, _)| t)
        .collect();
    if thin.is_empty() {
        Ok(())
    } else {
        Err(DesignError::ThinArtifacts {
            path: path.to_string(),
            labels: thin,
        })
    }
}

/// Gives `engine` the non-linear parameters' `values`. A refusal (a wrong count) belongs to no
/// row of any file, so its error names none.
pub(super) fn set_values(engine: &mut dyn Evaluator, values: &[f64]) -> Result<(), DesignError> {
    engine
        .set_nonlinear(values)
        .map_err(|source| DesignError::Eval {
            path: String::new(),
            line: 0,
            source,
        })
}

/// A row with an infinite or NaN entry would turn every sum it enters (the triangle, σ̂, the
/// coefficients) into inf or NaN: it is stopped here, where its file and line are known.
fn finite_row(
    x: &[f64],
    y: f64,
    path: impl Fn() -> String,
    line: usize,
) -> Result<(), DesignError> {
    // A fold without early exit: the compiler checks two values per vector instruction,
    // where `all` branches on each (this runs on every row of every pass).
    if y.is_finite() && !x.iter().fold(false, |bad, v| bad | !v.is_finite()) {
        Ok(())
    } else {
        Err(DesignError::NotFinite { path: path(), line })
    }
}

/// Builds the states of every file once (they change only when a time constant does), with
/// lags integrated for the machine's own non-linear values.
pub fn states(m: &Machine, files: &[DataSet]) -> Result<Vec<FileStates>, DesignError> {
    let values: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    states_with(m, files, &values)
}

/// As [`states`], with lags integrated for the given non-linear parameter values.
pub fn states_with(
    m: &Machine,
    files: &[DataSet],
    values: &[f64],
) -> Result<Vec<FileStates>, DesignError> {
    files
        .iter()
        .map(|f| {
            let path = f.path.display().to_string();
            let err = |source| DesignError::State {
                path: path.clone(),
                source,
            };
            Ok(match &f.observations {
                Observations::Points(p) => {
                    let mut s = States::new(m, &p.rows, &p.pose, "").map_err(err)?;
                    s.integrate_lags(m, &p.rows, values);
                    FileStates::Points(s)
                }
                Observations::Lengths(l) => {
                    let [p1, p2] = &l.poses;
                    let mut a = States::new(m, &l.rows, p1, "_1").map_err(err)?;
                    let mut b = States::new(m, &l.rows, p2, "_2").map_err(err)?;
                    a.integrate_lags(m, &l.rows, values);
                    b.integrate_lags(m, &l.rows, values);
                    FileStates::Lengths(a, b)
                }
            })
        })
        .collect()
}

// The fit weighs rotation rows as the compensator does: one definition, in the model layer.
pub use kin_model::kinematics::rotation_weight;

/// Calls `row(meta, x, y)` for every observed value: `x` the design row (all columns), `y` the
/// observation minus the model's fixed (known) part, both weighted.
pub fn for_each_row(
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    states: &[FileStates],
    layout: &Layout,
    row: impl FnMut(RowMeta, &[f64], f64),
) -> Result<(), DesignError> {
    rows_of(engine, files, states, layout, 0..usize::MAX, row)
}

/// The observations (points or lengths) of every file, counted in file order: what
/// [`for_each_row_parts`] splits.
pub(super) fn observations(states: &[FileStates]) -> usize {
    states
        .iter()
        .map(|s| match s {
            FileStates::Points(p) => p.len(),
            FileStates::Lengths(a, _) => a.len(),
        })
        .sum()
}

/// Rows between two progress reports of [`for_each_row_parts`]'s calling thread.
const TICK: usize = 8192;

/// As [`for_each_row`], on `1 + rest.len()` threads, over the observations `within` of
/// [`observations`]' count (cut at the end): those split into that many contiguous parts of
/// equal size, part 0 evaluated by `lead` on the calling thread and part `t` by
/// `rest[t − 1]`, each part's rows handed to `row` with `parts[t]`, its own accumulator. A
/// part's rows come in the order [`for_each_row`] gives them, so a caller that combines the
/// accumulators in part order gets the same bits for a given number of parts. The calling
/// thread reports the rows done so far by all parts to `progress` now and then. Returns the
/// rows visited; the first error in part order.
#[allow(clippy::too_many_arguments)] // the pass's inputs, its split and its two callbacks
pub(crate) fn for_each_row_parts<A: Send>(
    lead: &mut dyn Evaluator,
    rest: &mut [Box<dyn Evaluator + Send + '_>],
    files: &[DataSet],
    states: &[FileStates],
    layout: &Layout,
    within: std::ops::Range<usize>,
    parts: &mut [A],
    row: impl Fn(&mut A, RowMeta, &[f64], f64) + Sync,
    progress: &mut dyn FnMut(usize),
) -> Result<usize, DesignError> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let Some((mine, others)) = parts.split_first_mut() else {
        return Ok(0);
    };
    let n = 1 + rest.len().min(others.len());
    let from = within.start;
    let total = within.end.min(observations(states)).saturating_sub(from);
    let range = |t: usize| from + t * total / n..from + (t + 1) * total / n;
    let row = &row;
    // Rows the other parts have done, in whole ticks: what the calling thread adds to its own
    // when it reports.
    let others_done = AtomicUsize::new(0);
    let others_done = &others_done;
    let own = std::cell::Cell::new(0usize);
    let own = &own;
    let mut lead_rows = |m: RowMeta, x: &[f64], y: f64| {
        row(mine, m, x, y);
        own.set(own.get() + 1);
        if own.get().is_multiple_of(TICK) {
            progress(own.get() + others_done.load(Ordering::Relaxed));
        }
    };
    if n == 1 {
        rows_of(lead, files, states, layout, range(0), &mut lead_rows)?;
        return Ok(own.get());
    }
    std::thread::scope(|scope| {
        let handles: Vec<_> = rest
            .iter_mut()
            .zip(others.iter_mut())
            .enumerate()
            .map(|(t, (engine, part))| {
                scope.spawn(move || {
                    let mut count = 0usize;
                    rows_of(
                        engine.as_mut(),
                        files,
                        states,
                        layout,
                        range(t + 1),
                        |m, x, y| {
                            row(part, m, x, y);
                            count += 1;
                            if count.is_multiple_of(TICK) {
                                others_done.fetch_add(TICK, Ordering::Relaxed);
                            }
                        },
                    )
                    .map(|()| count)
                })
            })
            .collect();
        let mut out = rows_of(lead, files, states, layout, range(0), &mut lead_rows);
        let mut count = own.get();
        for h in handles {
            let done = match h.join() {
                Ok(done) => done,
                Err(e) => std::panic::resume_unwind(e),
            };
            match (&out, done) {
                (Ok(()), Ok(rows)) => count += rows,
                (Ok(()), Err(e)) => out = Err(e),
                (Err(_), _) => {}
            }
        }
        out.map(|()| count)
    })
}

/// [`for_each_row`] over the observations `part` of [`observations`]' count.
fn rows_of(
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    states: &[FileStates],
    layout: &Layout,
    part: std::ops::Range<usize>,
    mut row: impl FnMut(RowMeta, &[f64], f64),
) -> Result<(), DesignError> {
    let n = layout.coefficients;
    let width = layout.columns();
    let zero = vec![0.0; n];
    let mut jac = vec![0.0; 6 * n];
    let mut x = vec![0.0; width];
    let mut lrow = vec![0.0; n];
    let mut err = [0.0; 6];
    // The first observation of the current file in the count over all files.
    let mut offset = 0usize;
    for (f, (file, st)) in files.iter().zip(states).enumerate() {
        let weights = layout.weights_of(f);
        let path = || file.path.display().to_string();
        let rows = file.observations.rows();
        let count = match st {
            FileStates::Points(s) => s.len(),
            FileStates::Lengths(s, _) => s.len(),
        };
        let local = |at: usize| at.saturating_sub(offset).min(count);
        let mine = local(part.start)..local(part.end);
        offset += count;
        match (&file.observations, st) {
            (Observations::Points(p), FileStates::Points(s)) => {
                // Only the rows of the components the file has a column for are evaluated.
                let observed = Observed::from_flags(std::array::from_fn(|c| {
                    p.observed.get(c).is_some_and(Option::is_some)
                }));
                let k = observed.rows();
                for r in mine {
                    let line = s.line.get(r).copied().unwrap_or(0);
                    let state = s.get(r);
                    engine
                        .observed_error_and_jacobian(
                            &state,
                            &zero,
                            observed,
                            &mut err[..k],
                            &mut jac[..k * n],
                        )
                        .map_err(|source| DesignError::Eval {
                            path: path(),
                            line,
                            source,
                        })?;
                    let artifact = layout.first_of(f, rows.artifact_of(r));
                    let registration = p.absolute.as_ref().and_then(|a| {
                        let target = a.target.of_row.get(r).copied().unwrap_or(0);
                        layout.registration_of(f, target)
                    });
                    let eval = |source| DesignError::Eval {
                        path: path(),
                        line,
                        source,
                    };
                    let position = match (artifact, registration) {
                        (None, None) => None,
                        _ => Some(engine.nominal_position(&state).map_err(eval)?),
                    };
                    // How the tool point moves in wr when the target's offset moves along
                    // each axis of the frame it is attached to: exact differences, as the
                    // point is affine in the offset.
                    let along = match (registration, position) {
                        (Some(_), Some(p0)) => {
                            let base = state
                                .tool_offset
                                .unwrap_or_else(|| declared_offset(engine.machine(), state.tool));
                            let mut along = [[0.0; 3]; 3];
                            for (k, slot) in along.iter_mut().enumerate() {
                                let mut moved = base;
                                moved[k] += 1.0;
                                let shifted = State {
                                    tool_offset: Some(moved),
                                    ..state
                                };
                                let p1 = engine.nominal_position(&shifted).map_err(eval)?;
                                *slot = std::array::from_fn(|c| p1[c] - p0[c]);
                            }
                            Some(along)
                        }
                        _ => None,
                    };
                    for (c, column) in p.observed.iter().enumerate() {
                        let (Some(obs), Some(k)) = (
                            column
                                .as_ref()
                                .and_then(|v| v.get(r))
                                .copied()
                                .filter(|v| !v.is_nan()),
                            observed.row(c),
                        ) else {
                            continue;
                        };
                        let w = weights.of(c as u8);
                        // The coefficients' columns are all written; only the nuisance
                        // columns after them need clearing.
                        let (coefficients, nuisance) = x.split_at_mut(n.min(width));
                        match jac.get(k * n..(k + 1) * n) {
                            Some(jac) => {
                                for (slot, v) in coefficients.iter_mut().zip(jac) {
                                    *slot = v * w;
                                }
                            }
                            None => coefficients.fill(0.0),
                        }
                        nuisance.fill(0.0);
                        if let (Some(first), Some(p)) = (artifact, position) {
                            // A rigid displacement (t, ω) of the artifact changes the observed
                            // error by t + ω × p at a point p, and by ω in orientation.
                            if c < 3 {
                                set(&mut x, first + c, w);
                                for k in 0..3 {
                                    let e_k = unit(k);
                                    let moved = cross(e_k, p);
                                    set(&mut x, first + 3 + k, moved[c] * w);
                                }
                            } else {
                                set(&mut x, first + c, w);
                            }
                        }
                        if let (Some((instrument, target)), Some(p), Some(along)) =
                            (registration, position, along)
                        {
                            // A change (t, ω) of the instrument's placement and a shift d of
                            // the target change the observed error by t + ω × p + A·d at the
                            // point p (A the columns of `along`: the attachment frame's axes in
                            // wr); a turn ρ of the target frame about the tool frame's axes
                            // changes the orientation error by ω + R·ρ (R = A·R_tool, the tool
                            // frame's axes), and ρ moves no point (spec/robots.md).
                            if c < 3 {
                                set(&mut x, instrument + c, w);
                                for (k, a) in along.iter().enumerate() {
                                    let moved = cross(unit(k), p);
                                    set(&mut x, instrument + 3 + k, moved[c] * w);
                                    set(&mut x, target + k, a[c] * w);
                                }
                            } else {
                                let r = c - 3;
                                set(&mut x, instrument + c, w);
                                let turn = declared_rotation(engine.machine(), state.tool);
                                for k in 0..3 {
                                    let axis: f64 =
                                        along.iter().zip(&turn).map(|(a, t)| a[r] * t[k]).sum();
                                    set(&mut x, target + 3 + k, axis * w);
                                }
                            }
                        }
                        let y = (obs - err[k]) * w;
                        finite_row(&x, y, path, line)?;
                        row(
                            RowMeta {
                                file: f as u32,
                                line: line as u32,
                                component: c as u8,
                            },
                            &x,
                            y,
                        );
                    }
                }
            }
            (Observations::Lengths(l), FileStates::Lengths(s1, s2)) => {
                for r in mine {
                    let line = s1.line.get(r).copied().unwrap_or(0);
                    let fixed = engine
                        .length_and_row(&s1.get(r), &s2.get(r), &zero, &mut lrow)
                        .map_err(|source| DesignError::Eval {
                            path: path(),
                            line,
                            source,
                        })?;
                    let Some(obs) = l.dl.get(r).copied().filter(|v| !v.is_nan()) else {
                        continue;
                    };
                    let w = weights.of(LENGTH);
                    x.fill(0.0);
                    for (slot, v) in x.iter_mut().zip(&lrow) {
                        *slot = v * w;
                    }
                    if let Some(first) = layout.first_of(f, rows.artifact_of(r)) {
                        set(&mut x, first, w);
                    }
                    let y = (obs - fixed) * w;
                    finite_row(&x, y, path, line)?;
                    row(
                        RowMeta {
                            file: f as u32,
                            line: line as u32,
                            component: LENGTH,
                        },
                        &x,
                        y,
                    );
                }
            }
            _ => {}
        }
    }
    Ok(())
}

fn set(x: &mut [f64], i: usize, v: f64) {
    if let Some(slot) = x.get_mut(i) {
        *slot = v;
    }
}

fn unit(k: usize) -> [f64; 3] {
    let mut e = [0.0; 3];
    if let Some(s) = e.get_mut(k) {
        *s = 1.0;
    }
    e
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// What a held-out part's path adds to its file's.
pub const HELD_OUT: &str = " (held out)";

/// Splits each file into a fitted part and a held-out part: a fraction `holdout` of the
/// rows, drawn with `seed`. Lag states need whole runs, so a file with lags is split by run.
pub fn holdout(files: &[DataSet], holdout: f64, seed: u64) -> (Vec<DataSet>, Vec<DataSet>) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut fitted = Vec::new();
    let mut held = Vec::new();
    for f in files {
        let rows = f.observations.rows();
        let runs = rows.run.as_ref().map(|g| g.labels.len()).unwrap_or(1);
        let by_run = rows.time.is_some() && runs > 1;
        let draws: Vec<bool> = (0..runs)
            .map(|_| rng.random_bool(holdout.clamp(0.0, 1.0)))
            .collect();
        let (mut keep, mut out) = (Vec::new(), Vec::new());
        for r in 0..rows.len() {
            let hold = if by_run {
                draws.get(rows.run_of(r) as usize).copied().unwrap_or(false)
            } else {
                rng.random_bool(holdout.clamp(0.0, 1.0))
            };
            if hold {
                out.push(r);
            } else {
                keep.push(r);
            }
        }
        fitted.push(DataSet {
            path: f.path.clone(),
            observations: f.observations.select(&keep),
        });
        if !out.is_empty() {
            let mut path = f.path.clone().into_os_string();
            path.push(HELD_OUT);
            held.push(DataSet {
                path: path.into(),
                observations: f.observations.select(&out),
            });
        }
    }
    (fitted, held)
}

/// Number of observed values (rows of the problem) in the files.
pub fn count_rows(files: &[DataSet]) -> usize {
    files
        .iter()
        .map(|f| match &f.observations {
            Observations::Points(p) => p
                .observed
                .iter()
                .flatten()
                .map(|v| v.iter().filter(|x| !x.is_nan()).count())
                .sum(),
            Observations::Lengths(l) => l.dl.iter().filter(|x| !x.is_nan()).count(),
        })
        .sum()
}

/// The rotation of tool `tool`'s declared offset (`Rx·Ry·Rz` of its `rot`), rows.
pub(crate) fn declared_rotation(m: &Machine, tool: usize) -> [[f64; 3]; 3] {
    let r = m
        .tools
        .get(tool)
        .map(|t| t.offset.rotation)
        .unwrap_or_default();
    let t = kin_model::exact::shape_or_error([0.0; 3], r);
    std::array::from_fn(|i| std::array::from_fn(|j| t[(i, j)]))
}

/// The translation of tool `tool`'s declared offset (what a row without `tool_x` … uses).
pub(crate) fn declared_offset(m: &Machine, tool: usize) -> [f64; 3] {
    m.tools
        .get(tool)
        .map(|t| t.offset.translation)
        .unwrap_or_default()
}
