//! Testing the candidate library against the data, and locating where the model fails.

use std::collections::{BTreeMap, HashMap};

use kin_compiler::ir::{JointKind, Machine};
use kin_compiler::units::Unit;
use kin_compiler::{compile, Compiled, Diagnostic};
use kin_estimate::statistics::{self, lack_of_fit};
use thiserror::Error;

use super::library::{self, Available, Proposal, Sampling};
use super::trend::{self, Timed, Trend};
use super::{evidence, pass, periodic, refit, spectrum};
use super::{
    Bin, Candidate, ChiSquare, Diagnosis, Dropped, Family, FileSigma, Finding, NoiseCheck, Outlier,
    Plausibility, Region, Spectrum,
};
use kin_data::data::Observations;
use kin_estimate::fit::components::RowKind;
use kin_estimate::fit::report::{component_name, model_hash};
use kin_estimate::fit::{self, DataSet, FitResult, Layout, Weights, LENGTH};

#[derive(Debug, Error)]
pub enum DiagnoseError {
    #[error(transparent)]
    Fit(#[from] fit::FitError),
    #[error(transparent)]
    Design(#[from] fit::DesignError),
    #[error("the model with the candidate terms does not compile: {0}")]
    Candidates(String),
    #[error(transparent)]
    Eval(#[from] kin_model::interp::EvalError),
    #[error(transparent)]
    Engine(#[from] kin_model::engine::EngineError),
}

/// Which part of a diagnosis a [`Progress`] report is about: the long ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// The one pass over every measured row with the candidates' columns (`done` of `total`
    /// rows).
    Rows,
    /// The second pass over the rows, with the columns of the candidates that are compared with
    /// one another (`done` of `total` rows).
    Pairs,
    /// The refits of significant findings whose wavelength or time constant is fitted.
    Refits,
}

/// Where a diagnosis is: called with the step, how much of it is done and its total, from the
/// diagnosing thread, at most every few thousand rows. The command line draws it as a bar.
#[derive(Clone, Default)]
pub struct Progress(Option<std::sync::Arc<Report>>);

/// What [`Progress`] calls: the step, how much of it is done, its total.
type Report = dyn Fn(Step, u64, u64) + Send + Sync;

impl Progress {
    pub fn new(report: impl Fn(Step, u64, u64) + Send + Sync + 'static) -> Self {
        Progress(Some(std::sync::Arc::new(report)))
    }

    fn report(&self, step: Step, done: u64, total: u64) {
        if let Some(report) = &self.0 {
            report(step, done, total);
        }
    }
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Progress(reported)"
        } else {
            "Progress(none)"
        })
    }
}

#[derive(Debug, Clone)]
pub struct Settings {
    /// Family-wise significance level over all candidates (Holm–Bonferroni).
    pub alpha: f64,
    /// Time constants scanned for thermal lags, s.
    pub taus: Vec<f64>,
    /// Bins per variable for locating failures.
    pub bins: usize,
    /// What evaluates the model with all its candidates.
    pub engine: kin_model::engine::Engine,
    /// The instrument's stated standard deviation on positions and lengths (m) and on
    /// rotations (rad): the absolute reference of the region tests and of the verdict.
    pub noise: Option<f64>,
    pub noise_tilt: Option<f64>,
    /// Told how far the long steps are (nothing by default).
    pub progress: Progress,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            alpha: 0.01,
            taus: vec![600.0, 1800.0, 5400.0],
            bins: 8,
            engine: kin_model::engine::Engine::default(),
            noise: None,
            noise_tilt: None,
            progress: Progress::default(),
        }
    }
}

/// Diagnoses a fitted model: `base` is the fit of `compiled` (from `source`) to `files`.
pub fn diagnose(
    compiled: &Compiled,
    source: &str,
    files: &[DataSet],
    base: &FitResult,
    options: &fit::Options,
    settings: &Settings,
) -> Result<Diagnosis, DiagnoseError> {
    let m = &compiled.machine;
    let s = m.units.error.scale;
    // With σs per file, every refit of the diagnosis weighs the files by the base fit's σs,
    // held fixed: fits compared by their residual sums of squares must weigh rows alike.
    let fixed;
    let options = match held_sigmas(base, options, files.len()) {
        Some(o) => {
            fixed = o;
            &fixed
        }
        None => options,
    };
    let available = available(m, files);
    // The located residuals are built twice, for the spectra here and for the regions after
    // the candidate pass, so that they and that pass's buffers are never held together: at
    // 10⁶ poses of the 5-axis example they are 190 MB, and building them takes under a second.
    let spectra = spectra(
        m,
        &positions(m, files, base),
        &available.sampled,
        options.threads,
    );
    let peaks: Vec<library::Peak> = spectra
        .iter()
        .filter(|sp| sp.peak_false_alarm < 0.01)
        .filter_map(|sp| {
            let a = m.axes.iter().position(|ax| ax.name == sp.variable)?;
            let (k, _) = sp
                .power
                .iter()
                .enumerate()
                .max_by(|x, y| x.1.total_cmp(y.1))?;
            let unit = &m.units.length;
            let si = |v: f64| unit.to_si(v) - unit.to_si(0.0);
            let shortest = sp.wavelengths.iter().copied().fold(f64::INFINITY, f64::min);
            let range = available.sampled.get(a).copied().flatten()?.span();
            Some(library::Peak {
                axis: a,
                wavelength: si(*sp.wavelengths.get(k)?),
                searched: spectrum::independent(range, si(shortest)),
            })
        })
        .collect();
    let mut proposals = library::propose(m, &available, &peaks, &settings.taus);
    super::beam::propose(
        m,
        &available,
        &super::beam::Beams::of(source),
        &mut proposals,
    );
    library::mark_paths(m, &mut proposals);
    let (findings, dropped) =
        test_candidates(compiled, source, files, base, options, &proposals, settings)?;
    let mut rows = positions(m, files, base);
    let trends = time_trends(m, &mut rows, base, settings);
    let (regions, bins) = regions(m, &rows, base, settings, &trends);
    // σ̂ and the RMS as the fit weighs its rows: with a stated noise, multiples of it.
    let all: Vec<f64> = base.residuals.iter().map(|r| r.residual / s).collect();
    Ok(Diagnosis {
        machine: m.name.clone(),
        model_hash: model_hash(source),
        sigma: base.sigma / s,
        rms: kin_estimate::fit::report::rms(&all),
        error_unit: m.units.error.name.clone(),
        alpha: settings.alpha,
        regions,
        bins,
        spectra,
        findings,
        noise: NoiseCheck {
            per_file: noise_per_file(m, files, base),
            ..noise_check(m, &rows, base, settings)
        },
        outliers: outliers(m, files, base, &rows),
        weighted: base.layout.weights.stated,
        proposed: proposals.len(),
        dropped,
    })
}

/// A residual of the fit in its component's display unit (the error unit; the tilt unit for
/// rotations), whatever the fit weighed its row by: a stated noise weighs every row by
/// `scale/σ` of its kind, the unit weighting a tilt unit as an error unit. Locating failures,
/// the spectra and the noise tests work on the physical residual, each kind against its own σ.
pub(super) fn display(m: &Machine, weights: &Weights, component: u8, residual: f64) -> f64 {
    let w = weights.of(component);
    let unit = Weights::unit(m).of(component);
    if w > 0.0 && w.is_finite() {
        residual / w * unit / m.units.error.scale
    } else {
        residual / m.units.error.scale
    }
}

/// Each file's σ̂ against its noise, when the base fit weighed files by their own σs.
fn noise_per_file(m: &Machine, files: &[DataSet], base: &FitResult) -> Vec<FileSigma> {
    let Some(c) = &base.components else {
        return Vec::new();
    };
    c.groups
        .iter()
        .map(|g| {
            let unit = match g.kind {
                RowKind::Position => &m.units.error,
                RowKind::Rotation => &m.units.tilt,
            };
            let sigma = g.sigma / unit.scale;
            // Σ(r/σ)² over the group's redundancy is χ²-distributed when σ is right.
            // No p-value (rather than 0, a rejection) when the ratio is not a number.
            let p = g
                .stated
                .then(|| {
                    let dof = g.redundancy.max(1.0);
                    statistics::chi_squared_p(g.ratio * g.ratio * dof, dof)
                })
                .flatten();
            FileSigma {
                file: files
                    .get(g.file)
                    .map(|f| f.path.display().to_string())
                    .unwrap_or_default(),
                kind: g.kind,
                unit: unit.name.clone(),
                sigma,
                stated: g.stated,
                sigma_hat: sigma * g.ratio,
                ratio: g.ratio,
                p,
                rows: g.rows,
                outliers: g.outliers,
            }
        })
        .collect()
}

/// The options of the base fit with its σs per file stated (none estimated again), when it
/// had σs per file.
fn held_sigmas(base: &FitResult, options: &fit::Options, files: usize) -> Option<fit::Options> {
    let c = base.components.as_ref()?;
    let mut file_noise = vec![
        fit::Noise {
            position: None,
            rotation: None,
        };
        files
    ];
    for g in &c.groups {
        if let Some(n) = file_noise.get_mut(g.file) {
            match g.kind {
                RowKind::Position => n.position = Some(g.sigma),
                RowKind::Rotation => n.rotation = Some(g.sigma),
            }
        }
    }
    Some(fit::Options {
        file_noise,
        components: true,
        ..options.clone()
    })
}

/// Whether the base fit weighed each file by its own σs: its residuals are then multiples of
/// their rows' σs, and each row is judged against its own file's σ.
fn per_file(base: &FitResult) -> bool {
    base.components.is_some()
}

/// The σ a row is judged against when locating failures, in the unit of its located residual:
/// with σs per file, 1 (the located residuals are multiples of each row's own σ); else the
/// stated σ of its kind.
fn reference(m: &Machine, settings: &Settings, base: &FitResult, component: u8) -> Option<f64> {
    if per_file(base) {
        return Some(1.0);
    }
    stated(m, settings, component)
}

/// The stated σ a row's residual is tested against (χ²), in the unit of its located residual:
/// with σs per file, 1 for the rows of a group whose σ was stated (an estimated σ is the
/// scatter itself, nothing to test it against).
fn stated_for(
    m: &Machine,
    settings: &Settings,
    base: &FitResult,
    file: u32,
    component: u8,
) -> Option<f64> {
    let Some(c) = &base.components else {
        return stated(m, settings, component);
    };
    let kind = if (3..6).contains(&component) {
        RowKind::Rotation
    } else {
        RowKind::Position
    };
    c.groups
        .iter()
        .any(|g| g.file == file as usize && g.kind == kind && g.stated)
        .then_some(1.0)
}

/// The stated σ of a component's rows, in its display unit (error unit; tilt unit for
/// rotations, which is what a weighted rotation residual over the error scale is).
fn stated(m: &Machine, settings: &Settings, component: u8) -> Option<f64> {
    if (3..6).contains(&component) {
        settings.noise_tilt.map(|t| t / m.units.tilt.scale)
    } else {
        settings.noise.map(|n| n / m.units.error.scale)
    }
}

/// The display unit of a component's residuals.
fn unit_of(m: &Machine, component: u8) -> &str {
    if (3..6).contains(&component) {
        &m.units.tilt.name
    } else {
        &m.units.error.name
    }
}

/// The outliers as judged after any trend over time ([`time_trends`]): the rows `located`
/// flags.
fn outliers(m: &Machine, files: &[DataSet], base: &FitResult, located: &Residuals) -> Vec<Outlier> {
    located
        .rows
        .iter()
        .filter(|l| l.outlier)
        .filter_map(|l| base.residuals.get(l.index as usize))
        .map(|r| Outlier {
            file: files
                .get(r.meta.file as usize)
                .map(|f| f.path.display().to_string())
                .unwrap_or_default(),
            line: r.meta.line as usize,
            component: component_name(r.meta.component).to_string(),
            residual: display(
                m,
                &base.layout.weights_of(r.meta.file as usize),
                r.meta.component,
                r.residual,
            ),
            studentized: r.studentized,
        })
        .collect()
}

/// The residuals against the stated noise (χ²) and against the scatter of repeated poses
/// (lack of fit). Outliers are left out of both: they are named on their own.
fn noise_check(
    m: &Machine,
    located: &Residuals,
    base: &FitResult,
    settings: &Settings,
) -> NoiseCheck {
    let used: Vec<&Located> = located.rows.iter().filter(|r| !r.outlier).collect();
    let n = used.len() as f64;
    // The fit's coefficients take their share of the degrees of freedom from every row alike.
    let keep = 1.0 - base.solution.rank as f64 / (base.rows.max(1) as f64);
    let chi2 = {
        let with: Vec<(f64, f64)> = used
            .iter()
            .filter_map(|r| {
                Some((
                    r.residual,
                    stated_for(m, settings, base, r.file, r.component)?,
                ))
            })
            .filter(|(_, s)| *s > 0.0)
            .collect();
        let dof = with.len() as f64 * keep;
        (dof >= 1.0).then(|| {
            let statistic: f64 = with.iter().map(|(r, s)| (r / s).powi(2)).sum();
            let p = statistics::chi_squared_p(statistic, dof).unwrap_or(0.0);
            ChiSquare {
                rows: with.len(),
                dof,
                statistic,
                ratio: (statistic / dof).sqrt(),
                p,
                consistent: p >= settings.alpha,
            }
        })
    };
    // Replicates: one file, one component, the same axis positions, directions and inputs
    // (time is not part of a pose: a drift between repeats counts as pure error, which makes
    // the test conservative, never alarming).
    // Sorted by (file, component, pose bits), stably, each run a group → (rows, Σr, Σr²): the
    // groups and their sums in the order of a map keyed by them, without a key per row.
    let pose = |r: &Located| {
        let values = located.values(r);
        let width = values.len().saturating_sub(1);
        values[..width]
            .iter()
            .chain(located.dirs(r))
            .map(|v| v.to_bits())
    };
    let same = |a: &Located, b: &Located| {
        (a.file, a.component)
            .cmp(&(b.file, b.component))
            .then_with(|| pose(a).cmp(pose(b)))
    };
    let mut sorted = used.clone();
    sorted.sort_by(|a, b| same(a, b));
    let groups = sorted.chunk_by(|a, b| same(a, b).is_eq()).map(|g| {
        g.iter().fold((0, 0.0, 0.0), |(k, s, ss), r| {
            (k + 1, s + r.residual, ss + r.residual * r.residual)
        })
    });
    let rss: f64 = used.iter().map(|r| r.residual * r.residual).sum();
    let lack_of_fit = lack_of_fit(groups, rss, n * keep, settings.alpha);
    NoiseCheck {
        stated: settings.noise.map(|v| v / m.units.error.scale),
        stated_tilt: settings.noise_tilt.map(|v| v / m.units.tilt.scale),
        chi2,
        lack_of_fit,
        per_file: Vec::new(),
    }
}

fn available(m: &Machine, files: &[DataSet]) -> Available {
    let all = |f: &dyn Fn(&DataSet) -> bool| !files.is_empty() && files.iter().all(f);
    let mut available = Available {
        directions: (0..m.axes.len())
            .map(|a| {
                all(&|d: &DataSet| match &d.observations {
                    Observations::Points(p) => p.pose.dir.get(a).is_some_and(|c| c.is_some()),
                    Observations::Lengths(l) => l
                        .poses
                        .iter()
                        .all(|p| p.dir.get(a).is_some_and(|c| c.is_some())),
                })
            })
            .collect(),
        inputs: (0..m.inputs.len())
            .map(|i| {
                all(&|d: &DataSet| {
                    d.observations
                        .rows()
                        .inputs
                        .get(i)
                        .is_some_and(|c| c.as_ref().is_some_and(|v| v.iter().all(|x| !x.is_nan())))
                })
            })
            .collect(),
        time: all(&|d: &DataSet| d.observations.rows().time.is_some()),
        sampled: (0..m.axes.len())
            .map(|a| {
                Sampling::of(files.iter().flat_map(|d| -> Vec<f64> {
                    match &d.observations {
                        Observations::Points(p) => p.pose.axes.get(a).cloned().unwrap_or_default(),
                        Observations::Lengths(l) => l
                            .poses
                            .iter()
                            .flat_map(|p| p.axes.get(a).cloned().unwrap_or_default())
                            .collect(),
                    }
                }))
            })
            .collect(),
        reversals: Vec::new(),
    };
    available.reversals = reversals(m, files, &available.sampled);
    available
}

/// Per pair of axes (a, b): the parts of b's sampled range ([`library::REVERSAL_BINS`]) in which
/// the data hold both directions of motion of a. Point files and both ends of a length.
fn reversals(m: &Machine, files: &[DataSet], sampled: &[Option<Sampling>]) -> Vec<Vec<usize>> {
    let n = m.axes.len();
    let parts = library::REVERSAL_BINS;
    // seen[a][b][part]: bit 0 a moving +, bit 1 a moving −.
    let mut seen = vec![vec![vec![0u8; parts]; n]; n];
    let mut visit = |pose: &kin_data::data::Pose, rows: usize| {
        for (a, seen_a) in seen.iter_mut().enumerate() {
            let Some(Some(dir)) = pose.dir.get(a) else {
                continue;
            };
            for (b, s) in sampled.iter().enumerate() {
                let (Some(s), Some(q)) = (s, pose.axes.get(b)) else {
                    continue;
                };
                if b == a || !(s.span() > 0.0) {
                    continue;
                }
                for r in 0..rows {
                    let (Some(&d), Some(&x)) = (dir.get(r), q.get(r)) else {
                        continue;
                    };
                    if !x.is_finite() {
                        continue;
                    }
                    let bit = if d > 0.0 {
                        1
                    } else if d < 0.0 {
                        2
                    } else {
                        continue;
                    };
                    let part = (((x - s.lo) / s.span() * parts as f64).floor().max(0.0) as usize)
                        .min(parts - 1);
                    seen_a[b][part] |= bit;
                }
            }
        }
    };
    for f in files {
        match &f.observations {
            Observations::Points(p) => visit(&p.pose, p.rows.line.len()),
            Observations::Lengths(l) => {
                for pose in &l.poses {
                    visit(pose, l.rows.line.len());
                }
            }
        }
    }
    seen.iter()
        .map(|row| {
            row.iter()
                .map(|cells| cells.iter().filter(|&&c| c == 3).count())
                .collect()
        })
        .collect()
}

/// One residual, and which of the [`Places`] its pose's state variables are at.
struct Located {
    file: u32,
    component: u8,
    /// Flagged by the fit (studentized residual), or after a trend over time against its own
    /// stretch of time ([`time_trends`]): kept out of the region tests.
    outlier: bool,
    /// Its index in the fit's residuals.
    index: u32,
    residual: f64,
    leverage: f64,
    /// Its pose's place ([`Places`]): the components of one pose share it.
    at: u32,
}

/// The state variables of every observed pose, once per pose (display units): a pose's three
/// or six components share them, and a million-pose diagnosis holds them as one array rather
/// than two small vectors per residual.
struct Places {
    /// Values per place: axis positions, then inputs, then time (NaN where unknown).
    values: usize,
    /// Directions of motion per place, one per axis (±1, NaN where not given).
    axes: usize,
    /// `values + axes` numbers per place, the places one after the other.
    data: Vec<f64>,
}

impl Places {
    /// Numbers per place.
    fn width(&self) -> usize {
        self.values + self.axes
    }
}

/// The residuals with their places.
struct Residuals {
    rows: Vec<Located>,
    places: Places,
}

impl Residuals {
    /// Axis positions, then inputs, then time where `r` was observed.
    fn values(&self, r: &Located) -> &[f64] {
        let at = r.at as usize * self.places.width();
        self.places
            .data
            .get(at..at + self.places.values)
            .unwrap_or(&[])
    }

    /// The direction of motion of each axis where `r` was observed.
    fn dirs(&self, r: &Located) -> &[f64] {
        let at = r.at as usize * self.places.width() + self.places.values;
        self.places
            .data
            .get(at..at + self.places.axes)
            .unwrap_or(&[])
    }
}

/// Names and units of the located variables, in `Located::values` order.
fn variables(m: &Machine) -> Vec<(String, String)> {
    let mut v: Vec<(String, String)> = m
        .axes
        .iter()
        .map(|a| {
            (
                a.name.clone(),
                if a.kind == JointKind::Prismatic {
                    m.units.length.name.clone()
                } else {
                    m.units.angle.name.clone()
                },
            )
        })
        .collect();
    v.extend(
        m.inputs
            .iter()
            .map(|i| (i.name.clone(), i.unit.name.clone())),
    );
    v.push(("time".into(), m.units.time.name.clone()));
    v
}

fn positions(m: &Machine, files: &[DataSet], base: &FitResult) -> Residuals {
    // Each file's rows by line, for a binary search (a hash map costs more per row).
    let index: Vec<Vec<(usize, usize)>> = files
        .iter()
        .map(|f| {
            let mut by_line: Vec<(usize, usize)> = f
                .observations
                .rows()
                .line
                .iter()
                .enumerate()
                .map(|(r, &l)| (l, r))
                .collect();
            by_line.sort_unstable();
            by_line
        })
        .collect();
    let axis_unit = |a: usize| match m.axes.get(a).map(|x| x.kind) {
        Some(JointKind::Revolute) => &m.units.angle,
        _ => &m.units.length,
    };
    let mut places = Places {
        values: m.axes.len() + m.inputs.len() + 1,
        axes: m.axes.len(),
        data: Vec::new(),
    };
    let width = places.width();
    // At most one place per measured row: reserved at once, as growing by doubling would hold
    // up to twice the array at the end.
    let measured: usize = files.iter().map(|f| f.observations.len()).sum();
    places.data.reserve_exact(measured * width);
    // A place is appended for every new (file, row); a pose's components follow one another.
    let mut last: Option<(u32, usize, u32)> = None;
    let mut rows = Vec::with_capacity(base.residuals.len());
    for (k, r) in base.residuals.iter().enumerate() {
        let Some(f) = files.get(r.meta.file as usize) else {
            continue;
        };
        let Some(by_line) = index.get(r.meta.file as usize) else {
            continue;
        };
        let line = r.meta.line as usize;
        // A file's lines are distinct: one row each.
        let Ok(found) = by_line.binary_search_by_key(&line, |&(l, _)| l) else {
            continue;
        };
        let row = by_line[found].1;
        let at = match last {
            Some((file, at_row, at)) if file == r.meta.file && at_row == row => at,
            _ => {
                let at = (places.data.len() / width) as u32;
                push_place(m, f, row, &axis_unit, &mut places.data);
                last = Some((r.meta.file, row, at));
                at
            }
        };
        rows.push(Located {
            file: r.meta.file,
            component: r.meta.component,
            outlier: r.studentized.abs() > base.outlier_threshold,
            index: k as u32,
            // With σs per file, a multiple of the row's own σ: files of unequal precision are
            // then judged alike, each against its own noise.
            residual: if per_file(base) {
                r.residual / m.units.error.scale
            } else {
                display(m, &base.layout.weights, r.meta.component, r.residual)
            },
            leverage: r.leverage,
            at,
        });
    }
    Residuals { rows, places }
}

/// Appends the place of `row` of `f` to `data`: axis positions (a length's at the middle of
/// its two ends), inputs, time, then the axes' directions of motion.
fn push_place<'u>(
    m: &Machine,
    f: &DataSet,
    row: usize,
    axis_unit: &dyn Fn(usize) -> &'u Unit,
    data: &mut Vec<f64>,
) {
    let rows = f.observations.rows();
    match &f.observations {
        Observations::Points(p) => data.extend((0..m.axes.len()).map(|a| {
            p.pose
                .axes
                .get(a)
                .and_then(|c| c.get(row))
                .map(|v| axis_unit(a).from_si(*v))
                .unwrap_or(f64::NAN)
        })),
        Observations::Lengths(l) => data.extend((0..m.axes.len()).map(|a| {
            let end = |e: usize| {
                l.poses[e]
                    .axes
                    .get(a)
                    .and_then(|c| c.get(row))
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            axis_unit(a).from_si((end(0) + end(1)) / 2.0)
        })),
    }
    data.extend(m.inputs.iter().enumerate().map(|(i, input)| {
        rows.inputs
            .get(i)
            .and_then(|c| c.as_ref())
            .and_then(|c| c.get(row))
            .map(|v| input.unit.from_si(*v))
            .unwrap_or(f64::NAN)
    }));
    data.push(
        rows.time
            .as_ref()
            .and_then(|t| t.get(row))
            .map(|t| m.units.time.from_si(*t))
            .unwrap_or(f64::NAN),
    );
    match &f.observations {
        Observations::Points(p) => data.extend((0..m.axes.len()).map(|a| {
            p.pose
                .dir
                .get(a)
                .and_then(|c| c.as_ref())
                .and_then(|c| c.get(row))
                .copied()
                .unwrap_or(f64::NAN)
        })),
        Observations::Lengths(_) => data.extend(std::iter::repeat_n(f64::NAN, m.axes.len())),
    }
}

/// The residual spectra along each prismatic axis, per translation component and length
/// ([`spectrum`]: Lomb–Scargle, for the non-uniform sampling real measurement plans have).
fn spectra(
    m: &Machine,
    located: &Residuals,
    sampled: &[Option<Sampling>],
    threads: usize,
) -> Vec<Spectrum> {
    const COMPONENTS: [u8; 4] = [0, 1, 2, LENGTH];
    let mut out = Vec::new();
    for (a, axis) in m.axes.iter().enumerate() {
        if axis.kind != JointKind::Prismatic {
            continue;
        }
        let Some(sampling) = sampled.get(a).copied().flatten() else {
            continue;
        };
        let unit = &m.units.length;
        let range = unit.from_si(sampling.hi) - unit.from_si(sampling.lo);
        // Nothing shorter than the sampling resolves (Nyquist on the distinct positions).
        let nyquist = unit.from_si(sampling.shortest()) - unit.from_si(0.0);
        let along = located.rows.iter().filter_map(|r| {
            let slot = COMPONENTS.iter().position(|&c| c == r.component)?;
            let x = *located.values(r).get(a)?;
            x.is_finite().then_some((slot, x, r.residual))
        });
        let (positions, moments) = spectrum::Positions::group(COMPONENTS.len(), along);
        for s in spectrum::spectra(&positions, &moments, range, nyquist, threads) {
            out.push(Spectrum {
                component: component_name(COMPONENTS[s.slot]).to_string(),
                variable: axis.name.clone(),
                unit: unit.name.clone(),
                wavelengths: s.wavelengths,
                power: s.power,
                peak_false_alarm: s.false_alarm,
            });
        }
    }
    out
}

/// Per proposal (its index), the super-model's coefficient columns of each of its terms.
type TermColumns = Vec<(usize, Vec<Vec<usize>>)>;

/// Compiles the model with every candidate appended, dropping candidates that do not compile.
/// Returns the super-model and the columns of the kept proposals.
fn super_model(
    compiled: &Compiled,
    source: &str,
    proposals: &[Proposal],
    dropped: &mut Vec<Dropped>,
) -> Result<(Compiled, TermColumns), DiagnoseError> {
    let file = kin_compiler::syntax::parse_file(source)
        .map_err(|d| DiagnoseError::Candidates(d.message))?;
    // Candidate lines go just before the closing brace of the last `errors` block, or into a
    // new block before the machine's closing brace.
    let (at, open, close) = match file.machine.errors_close() {
        Some(at) => (at, String::new(), String::new()),
        None => (
            file.machine.span.end.saturating_sub(1),
            "errors {\n".to_string(),
            "}\n".to_string(),
        ),
    };
    // Each term written on its own (harmonics unmerged), so that its coefficients can be told
    // from its neighbours' by their spans.
    type Ranges = Vec<(usize, Vec<std::ops::Range<usize>>)>;
    let build = |chosen: &[usize]| -> (String, Ranges) {
        let mut text = String::from(source.get(..at).unwrap_or(""));
        text.push('\n');
        text.push_str(&open);
        let mut ranges = Vec::new();
        for &k in chosen {
            let p = &proposals[k];
            text.push_str(&p.candidate.target);
            text.push_str(" += ");
            let mut terms = Vec::new();
            for (i, t) in p.terms.iter().enumerate() {
                if i > 0 {
                    text.push_str(" + ");
                }
                let start = text.len();
                text.push_str(&t.test);
                terms.push(start..text.len());
            }
            ranges.push((k, terms));
            text.push('\n');
        }
        text.push_str(&close);
        text.push_str(source.get(at..).unwrap_or(""));
        (text, ranges)
    };
    // The first error of the model with the chosen candidates, if any.
    let error = |chosen: &[usize]| -> Option<String> {
        compile(&build(chosen).0)
            .diagnostics
            .into_iter()
            .find(Diagnostic::is_error)
            .map(|d| d.message)
    };
    let all: Vec<usize> = (0..proposals.len()).collect();
    let chosen: Vec<usize> = if error(&all).is_none() {
        all
    } else {
        let mut chosen = Vec::new();
        for (k, p) in proposals.iter().enumerate() {
            match error(&[k]) {
                None => chosen.push(k),
                Some(e) => dropped.push(Dropped {
                    text: p.candidate.text.clone(),
                    reason: format!("the model with it does not compile: {e}"),
                }),
            }
        }
        chosen
    };
    let (text, ranges) = build(&chosen);
    let out = compile(&text);
    let Some(mut sup) = out.compiled else {
        return Err(DiagnoseError::Candidates(
            out.diagnostics
                .first()
                .map(|d| d.message.clone())
                .unwrap_or_default(),
        ));
    };
    // The base model's non-linear parameters keep their fitted values.
    for p in &mut sup.machine.nonlinear {
        if let Some(b) = compiled.machine.nonlinear.iter().find(|q| q.name == p.name) {
            p.value = b.value;
        }
    }
    let columns = ranges
        .into_iter()
        .map(|(k, terms)| {
            let cols = terms
                .iter()
                .map(|range| {
                    sup.map
                        .coefficients
                        .iter()
                        .enumerate()
                        .filter(|(_, s)| s.start >= range.start && s.end <= range.end)
                        .map(|(j, _)| j)
                        .collect()
                })
                .collect();
            (k, cols)
        })
        .collect();
    Ok((sup, columns))
}

/// A column that keeps no more than this fraction of its norm once the columns before it are
/// projected out adds no direction: the threshold at which the identifiability analysis names
/// a dependent column (E0601, spec/semantics.md), so that a term kept in a candidate's line is
/// one `kin check` and `kin fit` will also see as new.
const DEPENDENT: f64 = 1e-6;

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Removes from `v` its components along the orthonormal `basis` (Gram–Schmidt, twice, so the
/// result is orthogonal to working precision).
fn project_out(v: &mut [f64], basis: &[Vec<f64>]) {
    for _ in 0..2 {
        for b in basis {
            let d = dot(v, b);
            v.iter_mut().zip(b).for_each(|(x, y)| *x -= d * y);
        }
    }
}

/// Appends `v` (already orthogonal to `basis`) to the basis if it keeps a direction of its own
/// against the norm `norm` of its column of X.
fn extend(basis: &mut Vec<Vec<f64>>, mut v: Vec<f64>, norm: f64) -> bool {
    let n = dot(&v, &v).sqrt();
    // NaN counts as dependent.
    let own = n > DEPENDENT * norm.max(f64::MIN_POSITIVE);
    if !own {
        return false;
    }
    v.iter_mut().for_each(|x| *x /= n);
    basis.push(v);
    true
}

fn test_candidates(
    compiled: &Compiled,
    source: &str,
    files: &[DataSet],
    base: &FitResult,
    options: &fit::Options,
    proposals: &[Proposal],
    settings: &Settings,
) -> Result<(Vec<Finding>, Vec<Dropped>), DiagnoseError> {
    let mut dropped = Vec::new();
    if proposals.is_empty() {
        return Ok((Vec::new(), dropped));
    }
    let m = &compiled.machine;
    let (sup, columns) = super_model(compiled, source, proposals, &mut dropped)?;
    let values: Vec<f64> = match &base.nonlinear {
        Some(n) => sup
            .machine
            .nonlinear
            .iter()
            .map(|p| {
                m.nonlinear
                    .iter()
                    .position(|q| q.name == p.name)
                    .and_then(|i| n.values.get(i).copied())
                    .unwrap_or(p.value)
            })
            .collect(),
        None => sup.machine.nonlinear.iter().map(|p| p.value).collect(),
    };
    let mut engine = kin_model::engine::make(&sup.machine, settings.engine)?;
    engine.set_nonlinear(&values)?;
    // Weighted as the base fit is (by the stated noise, kind by kind): every test below is then
    // on rows of unit variance, and a µrad row counts as much as its σ says, not as a µm.
    // (The base fit's weights, so that the tests and the base fit agree on them.)
    let mut layout = Layout::new(&sup.machine, files);
    layout.weights = base.layout.weights;
    layout.file_weights = base.layout.file_weights.clone();
    let states = fit::states_with(&sup.machine, files, &values)?;
    let n_base = m.coefficients.len();
    let width = layout.columns();
    // The base model's columns (its coefficients, then the nuisance parameters), and every
    // candidate column once, in the order the candidates name them.
    let mut split = pass::Split {
        base: (0..width)
            .filter(|&j| j < n_base || j >= layout.coefficients)
            .collect(),
        candidates: Vec::new(),
        groups: Vec::new(),
    };
    let mut slot_of: HashMap<usize, usize> = HashMap::new();
    for &j in columns.iter().flat_map(|(_, terms)| terms.iter().flatten()) {
        slot_of.entry(j).or_insert_with(|| {
            split.candidates.push(j);
            split.candidates.len() - 1
        });
    }
    // Each candidate's own products: what its test needs. Those between candidates are summed
    // later for the few the diagnosis compares (`compared`).
    split.groups = columns
        .iter()
        .map(|(_, terms)| {
            terms
                .iter()
                .flatten()
                .filter_map(|j| slot_of.get(j).copied())
                .collect()
        })
        .collect();
    let total: u64 = files.iter().map(|f| f.observations.len() as u64).sum();
    // One pass over every row with the columns of `split`, reported as `step`.
    let mut rows_pass = |split: &pass::Split, step: Step| {
        let (mut done, mut last) = (0u64, None);
        let acc = pass::accumulate(split, width, options.block, options.threads, |push| {
            fit::for_each_row(engine.as_mut(), files, &states, &layout, |meta, x, y| {
                // Several rows (components) share a measured row: count the measured rows.
                if last != Some((meta.file, meta.line)) {
                    last = Some((meta.file, meta.line));
                    done += 1;
                    if done % 4096 == 0 {
                        settings.progress.report(step, done, total);
                    }
                }
                push(x, y)
            })
        });
        settings.progress.report(step, total, total);
        acc
    };
    let mut acc = rows_pass(&split, Step::Rows)?;
    let kb = split.base.len();
    // Everything is done on columns of factors whose inner products are those of the columns
    // of X ([`pass`]). An orthonormal basis of the base model's columns first, in the base's
    // coordinates (the first `kb` of every factor); then each candidate's columns with the base
    // projected out. A candidate column the base (or the candidate's own earlier columns)
    // already spans is dropped: a spline with more knots shares its `s`, `s²` with the one in
    // the model. (An unpivoted re-triangularisation of the restricted columns cannot be used
    // here: after a dependent column its triangle is meaningless.)
    let mut base_basis: Vec<Vec<f64>> = Vec::new();
    // The base columns that keep a direction of their own: the refit's columns for the
    // plausibility check.
    let mut base_cols: Vec<usize> = Vec::new();
    for (c, &j) in split.base.iter().enumerate() {
        let mut v: Vec<f64> = (0..kb).map(|i| acc.r[(i, c)]).collect();
        project_out(&mut v, &base_basis);
        if extend(&mut base_basis, v, acc.norms[j]) {
            base_cols.push(j);
        }
    }
    let base_rank = base_basis.len();
    let rss_base = {
        let mut z: Vec<f64> = (0..kb)
            .map(|i| acc.s[(i, split.candidates.len())])
            .collect();
        project_out(&mut z, &base_basis);
        dot(&z, &z) + acc.ee
    };
    let rows = acc.rows as f64;
    let s = m.units.error.scale;
    let space = Space {
        acc: &acc,
        base: &base_basis,
        slot_of: &slot_of,
        rss_base,
    };

    let mut tested: Vec<Tested> = Vec::new();
    let mut drop = |k: usize, reason: &str| {
        dropped.push(Dropped {
            text: proposals[k].candidate.text.clone(),
            reason: reason.to_string(),
        })
    };
    for (k, terms) in &columns {
        let Some(added) = space.added(terms) else {
            drop(*k, "its columns were not in the pass over the rows");
            continue;
        };
        // A candidate the model already contains, or one the data cannot see, adds nothing.
        // Terms the model wholly spans are left out of the line (`restate`), so that what is
        // applied adds exactly `added` coefficients and the refit stays identifiable. A term
        // the model spans in part (the `s` of an Abbe spline that a constant and a coupling
        // elsewhere already make) cannot be: a line adds all of a term's functions or none,
        // and with all of them the refit would be rank-deficient (E0601). Such a candidate is
        // not proposed, nor one whose terms could not be told apart in the super-model.
        if added.basis.is_empty() {
            drop(*k, "the model already spans it on these data (or the data cannot see it): it adds no direction");
            continue;
        }
        if !added.appliable {
            drop(*k, "the model spans part of one of its terms: a line adds all of a term's functions or none, and with all of them the refit would be rank-deficient");
            continue;
        }
        let n_added = added.basis.len();
        let rss = added.rss;
        let dof = rows - (base_rank + n_added) as f64;
        if dof <= 0.0 || rss <= 0.0 {
            drop(
                *k,
                "too few rows to test it: no residual degrees of freedom are left",
            );
            continue;
        }
        let f = ((rss_base - rss) / n_added as f64) / (rss / dof);
        // A candidate placed by a search (a periodic error at the residual spectrum's highest
        // peak) is tested where the data fit it best: Šidák's correction over the independent
        // values searched makes its p-value that of the whole search, as the peak's own
        // false-alarm probability is.
        let p_at = statistics::f_p(f, n_added as f64, dof).unwrap_or(1.0);
        let searched = proposals.get(*k).map_or(1.0, |p| p.searched.max(1.0));
        let p = -(searched * (-p_at).ln_1p()).exp_m1();
        tested.push(Tested {
            proposal: *k,
            finding: Finding {
                candidate: library::restate(&proposals[*k], &added.kept),
                alternatives: Vec::new(),
                separation: None,
                columns: n_added,
                explained: ((rss_base - rss) / rss_base).max(0.0),
                f,
                p,
                p_adjusted: 1.0,
                significant: false,
                rms_after: (rss / rows).sqrt() / s,
                bic: rows * (rss / rss_base).ln() + n_added as f64 * rows.ln(),
                plausibility: None,
                fitted: Vec::new(),
                contradicted: Vec::new(),
                same_effect_as: Vec::new(),
            },
            terms: terms.clone(),
            columns: added.columns,
            rss,
        });
    }
    // Holm–Bonferroni over every candidate tested (ties by text: the order is the data's).
    let n = tested.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        tested[a]
            .finding
            .p
            .total_cmp(&tested[b].finding.p)
            .then_with(|| {
                tested[a]
                    .finding
                    .candidate
                    .text
                    .cmp(&tested[b].finding.candidate.text)
            })
    });
    let mut running: f64 = 0.0;
    for (rank, &i) in order.iter().enumerate() {
        let adj = ((n - rank) as f64 * tested[i].finding.p).min(1.0);
        running = running.max(adj);
        tested[i].finding.p_adjusted = running;
        tested[i].finding.significant = running < settings.alpha;
    }
    // One finding per group (a lag at its best time constant, a constant step or one whose
    // width varies): the lowest BIC, so that a member with more columns wins only when they
    // pay; a BTreeMap and a tie-break on the text keep the choice independent of any
    // iteration order.
    let mut groups: BTreeMap<String, Vec<Tested>> = BTreeMap::new();
    for t in tested {
        groups
            .entry(proposals[t.proposal].group.clone())
            .or_default()
            .push(t);
    }
    let mut all: Vec<Tested> = Vec::with_capacity(groups.len());
    for (g, mut members) in groups {
        // The readings of one periodic error: as many harmonics as the data support.
        if periodic::is_series(&g) {
            let readings: Vec<periodic::Reading> = members
                .iter()
                .map(|t| periodic::Reading {
                    fourier: t.finding.candidate.text.contains("fourier("),
                    columns: t.finding.columns,
                    rss: t.rss,
                    bic: t.finding.bic,
                })
                .collect();
            let chosen = periodic::choose(&readings, rows, base_rank, settings.alpha);
            let kept = chosen.map(|i| members.swap_remove(i));
            let why = match &kept {
                Some(k) => format!(
                    "another reading of the same periodic error is chosen: `{}` (as many harmonics as the data support)",
                    k.finding.candidate.text
                ),
                None => "no reading of this periodic error is supported by the data".to_string(),
            };
            for t in &members {
                drop(t.proposal, &why);
            }
            all.extend(kept);
            continue;
        }
        let mut best: Option<Tested> = None;
        let mut losers = Vec::new();
        for t in members {
            match &best {
                Some(b)
                    if b.finding.bic < t.finding.bic
                        || (b.finding.bic == t.finding.bic
                            && b.finding.candidate.text <= t.finding.candidate.text) =>
                {
                    losers.push(t.proposal)
                }
                _ => {
                    losers.extend(best.take().map(|b| b.proposal));
                    best = Some(t)
                }
            }
        }
        if let Some(b) = &best {
            let why = format!(
                "another member of its group fits at a lower BIC: `{}`",
                b.finding.candidate.text
            );
            for k in losers {
                drop(k, &why);
            }
        }
        all.extend(best);
    }
    all.sort_by(|a, b| rank_order(&a.finding, &b.finding));
    // The products between the candidates the comparisons below can ask about, in a second
    // pass over the rows with their columns alone.
    let compared = compared(&all, rss_base);
    let mut pair_cols: Vec<usize> = compared
        .iter()
        .flat_map(|&i| all[i].terms.iter().flatten().copied())
        .filter(|j| slot_of.contains_key(j))
        .collect();
    pair_cols.sort_unstable();
    pair_cols.dedup();
    if compared.len() > 1 {
        let pairs = pass::Split {
            base: split.base.clone(),
            groups: vec![(0..pair_cols.len()).collect()],
            candidates: pair_cols.clone(),
        };
        let later = rows_pass(&pairs, Step::Pairs)?;
        let slots: Vec<usize> = pair_cols
            .iter()
            .filter_map(|j| slot_of.get(j).copied())
            .collect();
        acc.include(later, &slots);
    }
    let space = Space {
        acc: &acc,
        base: &base_basis,
        slot_of: &slot_of,
        rss_base,
    };
    let mut findings = equivalent_groups(all, rss_base, &space);
    // The plausibility of the refit, for what the user may act on.
    let size = machine_size(m);
    for f in findings.iter_mut().filter(|f| f.finding.significant) {
        // A finding's own columns were summed together (its test needed them).
        let Some(reduced) = space.reduced(&f.columns) else {
            continue;
        };
        let p = plausibility(
            &reduced,
            &base_cols,
            &f.columns,
            &sup.machine,
            size,
            layout.coefficients,
        );
        f.finding.plausibility = Some(p);
    }
    same_effects(&mut findings, &space, rows, base_rank, settings.alpha);
    let mut out: Vec<Finding> = findings.into_iter().map(|t| t.finding).collect();
    // What a line with a fitted wavelength or time constant states comes from its refit.
    let refits = out
        .iter()
        .filter(|f| f.significant && f.candidate.text.contains(" fit "))
        .count() as u64;
    let mut renamed: Vec<(String, String)> = Vec::new();
    for (i, f) in out
        .iter_mut()
        .filter(|f| f.significant && f.candidate.text.contains(" fit "))
        .enumerate()
    {
        settings.progress.report(Step::Refits, i as u64, refits);
        let before = f.candidate.text.clone();
        refit::restate(
            f,
            compiled,
            source,
            files,
            options,
            settings.engine,
            settings.alpha,
        )?;
        if f.candidate.text != before {
            renamed.push((before, f.candidate.text.clone()));
        }
    }
    settings.progress.report(Step::Refits, refits, refits);
    // The lines others are readings of, by their restated text.
    for f in &mut out {
        for name in &mut f.same_effect_as {
            if let Some((_, new)) = renamed.iter().find(|(old, _)| old == name) {
                *name = new.clone();
            }
        }
    }
    for f in refit::one_per_effect(&mut out) {
        dropped.push(Dropped {
            text: f.candidate.text,
            reason:
                "its component is part of a joint line of the same effect, listed as one finding"
                    .into(),
        });
    }
    out.sort_by(rank_order);
    contradictions(&mut out, source, files, base, options, settings)?;
    Ok((out, dropped))
}

/// Significant findings compared pairwise for being readings of one effect.
const SAME_EFFECT_FINDINGS: usize = 10;

/// Whether two tested candidates' residual sums tie for [`equivalent_groups`] (its necessary
/// condition before their spaces are compared).
fn tie(a: &Tested, b: &Tested, rss_base: f64) -> bool {
    (a.rss - b.rss).abs() <= 1e-9 * rss_base.max(f64::MIN_POSITIVE)
        && a.finding.significant == b.finding.significant
        && a.finding.columns == b.finding.columns
}

/// The tested candidates (indices into `all`, in rank order) whose products with others the
/// diagnosis can ask for: every candidate whose residual sum ties another's
/// ([`equivalent_groups`] compares their spaces), and the significant ones [`same_effects`]
/// can reach. That takes the first [`SAME_EFFECT_FINDINGS`] significant findings after the
/// grouping, which only merges tied candidates into the group of the first of them: a finding
/// among those is either tied or one of the first `SAME_EFFECT_FINDINGS + tied` significant
/// candidates here.
fn compared(all: &[Tested], rss_base: f64) -> Vec<usize> {
    let tied: Vec<usize> = (0..all.len())
        .filter(|&i| (0..all.len()).any(|j| j != i && tie(&all[i], &all[j], rss_base)))
        .collect();
    let mut out: Vec<usize> = (0..all.len())
        .filter(|&i| all[i].finding.significant)
        .take(SAME_EFFECT_FINDINGS + tied.len())
        .chain(tied)
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Marks significant findings that are readings of an effect an earlier one (lower BIC)
/// explains: with the earlier line in the model, this one adds nothing significant (its partial
/// F-test given the earlier one, at `alpha`). Backlash of X seen as `X.tx`, as `X.ry` through
/// an arm and as `X.rz`: one effect, one line to add, not three.
fn same_effects(findings: &mut [Tested], space: &Space, rows: f64, base_rank: usize, alpha: f64) {
    let top: Vec<usize> = (0..findings.len())
        .filter(|&i| findings[i].finding.significant)
        .take(SAME_EFFECT_FINDINGS)
        .collect();
    for (a, &i) in top.iter().enumerate() {
        let mut same = Vec::new();
        for &j in &top[..a] {
            let (ti, tj) = (&findings[i], &findings[j]);
            let terms: Vec<Vec<usize>> = tj.terms.iter().chain(&ti.terms).cloned().collect();
            let Some(joint) = space.added(&terms) else {
                continue;
            };
            let own_j = tj.columns.len();
            let more = joint.basis.len().saturating_sub(own_j);
            let dof = rows - (base_rank + joint.basis.len()) as f64;
            let absorbed = if more == 0 {
                true
            } else if dof > 0.0 && joint.rss > 0.0 {
                let f = ((tj.rss - joint.rss) / more as f64) / (joint.rss / dof);
                statistics::f_p(f, more as f64, dof).is_some_and(|p| p >= alpha)
            } else {
                false
            };
            if absorbed {
                same.push(tj.finding.candidate.text.clone());
            }
        }
        findings[i].finding.same_effect_as = same;
    }
}

/// Refits checked for contradicted components at most: each is a fit of the whole data.
const EVIDENCE_CHECKS: usize = 4;

/// Checks the findings that would rank first, in rank order, for measured components their
/// refit makes worse ([`evidence`]) until one is not contradicted: a contradicted one moves
/// after every finding that is not, so the head of the list is one the data do not
/// contradict (as far as [`EVIDENCE_CHECKS`] refits reach).
fn contradictions(
    out: &mut [Finding],
    source: &str,
    files: &[DataSet],
    base: &FitResult,
    options: &fit::Options,
    settings: &Settings,
) -> Result<(), DiagnoseError> {
    let mut checked: Vec<String> = Vec::new();
    for _ in 0..EVIDENCE_CHECKS {
        let Some(head) = out
            .iter_mut()
            .find(|f| f.significant && !doubtful(f) && !checked.contains(&f.candidate.text))
        else {
            break;
        };
        checked.push(head.candidate.text.clone());
        if let Some((c, r)) = refit::with(
            &head.candidate.text,
            source,
            files,
            options,
            settings.engine,
        )? {
            let added = head
                .columns
                .max(r.solution.rank.saturating_sub(base.solution.rank));
            head.contradicted = evidence::worse(&c.machine, base, &r, added, settings.alpha);
        }
        let clean = head.contradicted.is_empty();
        out.sort_by(rank_order);
        if clean {
            break;
        }
    }
    Ok(())
}

/// A candidate as tested: its finding, its terms' super-model columns, the columns that add a
/// direction of their own, and its refit RSS.
struct Tested {
    proposal: usize,
    finding: Finding,
    terms: Vec<Vec<usize>>,
    columns: Vec<usize>,
    rss: f64,
}

/// What a candidate adds to the base: an orthonormal basis of it (base projected out), the
/// super-model columns behind it, per term whether it adds anything, whether the line can be
/// written to add exactly that, and the RSS with it.
struct Added {
    basis: Vec<Vec<f64>>,
    columns: Vec<usize>,
    kept: Vec<bool>,
    appliable: bool,
    rss: f64,
}

/// The pass's products seen as columns of factors ([`pass::Accumulated::factor`]): the base's
/// orthonormal basis in the base's coordinates, and the candidate columns' slots.
struct Space<'a> {
    acc: &'a pass::Accumulated,
    base: &'a [Vec<f64>],
    slot_of: &'a HashMap<usize, usize>,
    rss_base: f64,
}

impl Space<'_> {
    /// The factor of the base with the super-model columns `cols` (each once), and where each
    /// column is in it.
    fn factor(
        &self,
        cols: impl Iterator<Item = usize>,
    ) -> Option<(faer::Mat<f64>, HashMap<usize, usize>)> {
        let kb = self.acc.r.nrows();
        let mut slots = Vec::new();
        let mut at = HashMap::new();
        for j in cols {
            if let (Some(&slot), false) = (self.slot_of.get(&j), at.contains_key(&j)) {
                at.insert(j, kb + slots.len());
                slots.push(slot);
            }
        }
        Some((self.acc.factor(&slots)?, at))
    }

    /// What the terms (super-model columns per term) add to the base; `None` when a column
    /// was not in the pass.
    fn added(&self, terms: &[Vec<usize>]) -> Option<Added> {
        let (f, at) = self.factor(terms.iter().flatten().copied())?;
        self.added_in(&f, &at, terms)
    }

    fn added_in(
        &self,
        f: &faer::Mat<f64>,
        at: &HashMap<usize, usize>,
        terms: &[Vec<usize>],
    ) -> Option<Added> {
        let k = f.nrows();
        let column = |c: usize| -> Vec<f64> { (0..k).map(|i| f[(i, c)]).collect() };
        let base: Vec<Vec<f64>> = self
            .base
            .iter()
            .map(|b| {
                let mut v = b.clone();
                v.resize(k, 0.0);
                v
            })
            .collect();
        let mut y = column(k.checked_sub(1)?);
        project_out(&mut y, &base);
        let mut own: Vec<Vec<f64>> = Vec::new();
        let mut columns = Vec::new();
        let mut kept = Vec::with_capacity(terms.len());
        // Whether the line can be written to add exactly what is new (see the caller).
        let mut appliable = true;
        for cols in terms {
            let before = own.len();
            for &j in cols {
                let mut v = column(*at.get(&j)?);
                project_out(&mut v, &base);
                project_out(&mut v, &own);
                if extend(&mut own, v, self.acc.norms.get(j).copied().unwrap_or(0.0)) {
                    columns.push(j);
                }
            }
            let new = own.len() - before;
            kept.push(new > 0);
            appliable &= !cols.is_empty() && (new == 0 || new == cols.len());
        }
        // The RSS with the candidate, against the base's RSS of the whole pass (this factor's
        // `y` has it up to the rounding of its Gram root).
        let mut e = y.clone();
        project_out(&mut e, &own);
        let rss = dot(&e, &e) + (self.rss_base - dot(&y, &y));
        Some(Added {
            basis: own,
            columns,
            kept,
            appliable,
            rss: rss.max(0.0),
        })
    }

    /// Whether two candidates add the same space: both bases in one factor.
    fn same(&self, a: &Tested, b: &Tested) -> bool {
        // Two candidates the pass did not sum together are not compared (`compared` names
        // every pair this is asked about).
        let Some((f, at)) = self.factor(a.terms.iter().chain(&b.terms).flatten().copied()) else {
            return false;
        };
        match (
            self.added_in(&f, &at, &a.terms),
            self.added_in(&f, &at, &b.terms),
        ) {
            (Some(x), Some(y)) => same_space(&x.basis, &y.basis),
            _ => false,
        }
    }

    /// A reduced problem of the base and the super-model columns `cols`, at their design
    /// positions (y at the last), for [`plausibility`].
    fn reduced(&self, cols: &[usize]) -> Option<fit::Reduced> {
        let (f, at) = self.factor(cols.iter().copied())?;
        let width = self.acc.norms.len();
        let k = f.nrows();
        let mut r = faer::Mat::zeros(k, width + 1);
        let mut place = |from: usize, to: usize| {
            for i in 0..k {
                r[(i, to)] = f[(i, from)];
            }
        };
        for (c, &j) in self.acc.base.iter().enumerate() {
            place(c, j);
        }
        for (&j, &c) in &at {
            place(c, j);
        }
        place(k - 1, width);
        Some(fit::Reduced {
            r,
            rows: self.acc.rows,
            norms: self.acc.norms.clone(),
            y_sum: 0.0,
            y_sumsq: 0.0,
        })
    }
}

/// Whether a finding's refit is implausible (ill-conditioned, a length beyond the machine's).
fn doubtful(f: &Finding) -> bool {
    f.plausibility
        .as_ref()
        .is_some_and(|p| !p.warnings.is_empty())
}

/// The ranking: significant before not; a significant finding the data contradict after the
/// rest, one whose refit is implausible after the plausible ones, a coupling with no physical
/// path after those that have one; then by BIC (a column must pay ln n), the simpler family, the text.
fn rank_order(a: &Finding, b: &Finding) -> std::cmp::Ordering {
    let contradicted = |f: &Finding| !f.contradicted.is_empty();
    let no_path = |f: &Finding| f.candidate.no_path.is_some();
    b.significant
        .cmp(&a.significant)
        .then(contradicted(a).cmp(&contradicted(b)))
        .then(doubtful(a).cmp(&doubtful(b)))
        .then(no_path(a).cmp(&no_path(b)))
        .then(a.bic.total_cmp(&b.bic))
        .then(simplicity(a.candidate.family).cmp(&simplicity(b.candidate.family)))
        .then_with(|| a.candidate.text.cmp(&b.candidate.text))
}

/// Among readings the data cannot tell apart, the simplest physical one is canonical: a
/// constant before an angular error seen through an arm, before a step, before what varies.
fn simplicity(f: Family) -> u8 {
    match f {
        Family::Constant => 0,
        Family::AbbeAngular => 1,
        Family::Backlash => 2,
        Family::Drift => 3,
        Family::Thermal => 4,
        Family::CrossCoupling => 5,
        Family::Periodic => 6,
        Family::RevoluteHarmonics => 7,
        Family::ErrorMotion => 6,
        Family::MoreKnots => 8,
    }
}

/// Two candidates whose added columns span one space (every principal angle below about a
/// milliradian: `a − ‖AᵀB‖²_F` below 10⁻⁶ per column) give the same refit on any weighting of
/// these rows: the data cannot decide between them.
const SAME_SPACE: f64 = 1e-6;

fn same_space(a: &[Vec<f64>], b: &[Vec<f64>]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let captured: f64 = a
        .iter()
        .map(|u| b.iter().map(|v| dot(u, v).powi(2)).sum::<f64>())
        .sum();
    a.len() as f64 - captured < SAME_SPACE * a.len() as f64
}

/// Groups indistinguishable candidates (given in rank order) into one finding each: the
/// canonical line by [`simplicity`] then text, the others as alternatives.
fn equivalent_groups(all: Vec<Tested>, rss_base: f64, space: &Space) -> Vec<Tested> {
    let mut groups: Vec<Vec<Tested>> = Vec::new();
    for t in all {
        // Equal RSS (to rounding) first: a cheap necessary condition.
        let close = |g: &Vec<Tested>| {
            g.first()
                .is_some_and(|h| tie(h, &t, rss_base) && space.same(h, &t))
        };
        match groups.iter_mut().find(|g| close(g)) {
            Some(g) => g.push(t),
            None => groups.push(vec![t]),
        }
    }
    groups
        .into_iter()
        .filter_map(|mut g| {
            g.sort_by(|a, b| {
                simplicity(a.finding.candidate.family)
                    .cmp(&simplicity(b.finding.candidate.family))
                    .then_with(|| a.finding.candidate.text.cmp(&b.finding.candidate.text))
            });
            let mut it = g.into_iter();
            let mut head = it.next()?;
            let alternatives: Vec<Candidate> = it.map(|t| t.finding.candidate).collect();
            if !alternatives.is_empty() {
                head.finding.separation = Some(separation(&head.finding.candidate, &alternatives));
                head.finding.alternatives = alternatives;
            }
            Some(head)
        })
        .collect()
}

/// What measurement would tell equivalent readings apart, from how they differ.
fn separation(head: &Candidate, others: &[Candidate]) -> String {
    let component = |c: &Candidate| c.target.rsplit('.').next().unwrap_or("").to_string();
    let rotation = |c: &Candidate| component(c).starts_with('r');
    let mixed = others.iter().any(|o| rotation(o) != rotation(head));
    let same_component = others.iter().all(|o| component(o) == component(head));
    if mixed {
        "a rotation seen through an Abbe arm that does not change looks like a translation: measuring with a second tool offset (another Abbe arm), or the rotations erx, ery, erz, would separate them".into()
    } else if same_component {
        "the same component on elements that either moved together in these data, or whose frames differ only along the error's own axis (a rotation about the direction a carried slide moves): in the first case poses where those axes move independently would separate them; in the second no measurement can, and either line is the same model".into()
    } else {
        "measuring with another tool offset, at poses or inputs where these lines predict different errors, would separate them".into()
    }
}

/// The machine's size: its prismatic travels and the lengths of its nominal offsets, summed
/// (m). A fitted geometric error comparable with it is not an error of this machine.
fn machine_size(m: &Machine) -> f64 {
    let norm = |t: [f64; 3]| (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    let travels: f64 = m
        .axes
        .iter()
        .filter(|a| a.kind == JointKind::Prismatic)
        .map(|a| (a.range[1] - a.range[0]).abs())
        .sum();
    let offsets: f64 = m
        .tool_chain
        .iter()
        .chain(&m.workpiece_chain)
        .map(|e| norm(e.shape.translation))
        .chain(m.tools.iter().map(|t| norm(t.offset.translation)))
        .sum();
    travels + offsets
}

/// A condition number that grows by this factor, to at least [`ILL_CONDITIONED`], marks a
/// refit whose coefficients trade off against each other rather than describe the machine.
const CONDITION_JUMP: f64 = 1e3;
const ILL_CONDITIONED: f64 = 1e4;
/// A fitted length coefficient beyond this fraction of the machine's size is implausible.
const SIZE_FRACTION: f64 = 0.1;

/// The refit of the base columns with the candidate's, on the unit-scaled triangle: its
/// condition number against the base's, and its largest length coefficient.
#[allow(clippy::too_many_arguments)]
fn plausibility(
    red: &fit::Reduced,
    base_cols: &[usize],
    cand_cols: &[usize],
    sup: &Machine,
    size: f64,
    coefficients: usize,
) -> Plausibility {
    let rows = red.r.nrows();
    let width = red.norms.len();
    let scaled = |j: usize| -> Vec<f64> {
        let n = red
            .norms
            .get(j)
            .copied()
            .unwrap_or(1.0)
            .max(f64::MIN_POSITIVE);
        (0..rows).map(|i| red.r[(i, j)] / n).collect()
    };
    let y: Vec<f64> = (0..rows).map(|i| red.r[(i, width)]).collect();
    let solve = |cols: &[usize]| -> (f64, Vec<f64>) {
        let x: Vec<Vec<f64>> = cols.iter().map(|&j| scaled(j)).collect();
        let k = cols.len();
        let gram = nalgebra::DMatrix::from_fn(k, k, |a, b| dot(&x[a], &x[b]));
        let rhs = nalgebra::DVector::from_fn(k, |a, _| dot(&x[a], &y));
        let eig = gram.symmetric_eigen();
        let (lo, hi) = eig
            .eigenvalues
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
        let condition = if lo > 0.0 {
            (hi / lo).sqrt()
        } else {
            f64::INFINITY
        };
        // β = V Λ⁻¹ Vᵀ b, unscaled back to SI.
        let vt_b = eig.eigenvectors.transpose() * rhs;
        let w = nalgebra::DVector::from_fn(k, |a, _| {
            let l = eig.eigenvalues[a];
            if l > 0.0 {
                vt_b[a] / l
            } else {
                0.0
            }
        });
        let beta = &eig.eigenvectors * w;
        let si = (0..k)
            .map(|a| beta[a] / red.norms[cols[a]].max(f64::MIN_POSITIVE))
            .collect();
        (condition, si)
    };
    let (condition_before, _) = solve(base_cols);
    let mut cols = base_cols.to_vec();
    cols.extend_from_slice(cand_cols);
    let (condition_after, beta) = solve(&cols);
    let length = &sup.units.length;
    let largest = cols
        .iter()
        .zip(&beta)
        .filter(|(j, _)| **j < coefficients)
        .filter(|(j, _)| {
            sup.coefficients
                .get(**j)
                .is_some_and(|c| c.unit.dim == kin_compiler::units::Dim::LENGTH)
        })
        .map(|(_, b)| b.abs())
        .fold(0.0, f64::max);
    let mut warnings = Vec::new();
    if condition_after >= CONDITION_JUMP * condition_before && condition_after >= ILL_CONDITIONED {
        warnings.push(format!(
            "the refit is ill-conditioned: its condition number goes from {} to {} (its coefficients trade off against each other)",
            sci(condition_before),
            sci(condition_after)
        ));
    }
    if largest > SIZE_FRACTION * size {
        warnings.push(format!(
            "the refit has a length coefficient of {} {}, against a machine of {} {}",
            nice(length.from_si(largest)),
            length.name,
            nice(length.from_si(size)),
            length.name
        ));
    }
    Plausibility {
        condition_before,
        condition_after,
        largest_length: length.from_si(largest),
        machine_size: length.from_si(size),
        warnings,
    }
}

fn sci(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1e}")
    } else {
        "∞".into()
    }
}

/// The condition of a region that is a trend over time.
const TREND: &str = "a trend over time";

/// Per component, the trend over time of its residuals ([`trend::trend`]) where it is
/// significant, at the Bonferroni level of the region tests. A row of such a component that
/// the fit flags stays an outlier only if it is one against its own stretch of time too: the
/// trend is tested on every row first (the fit flags the first rows of a warm-up), then again
/// without the rows that stand out from their part; where the second test does not hold, the
/// fit's flags stand.
fn time_trends(
    m: &Machine,
    located: &mut Residuals,
    base: &FitResult,
    settings: &Settings,
) -> Vec<(u8, Trend)> {
    let at = m.axes.len() + m.inputs.len();
    let mut comps: Vec<u8> = located.rows.iter().map(|r| r.component).collect();
    comps.sort_unstable();
    comps.dedup();
    let tests = (comps.len() * variables(m).len() * settings.bins * 2).max(1) as f64;
    let level = settings.alpha / tests;
    let threshold = base.outlier_threshold;
    // Each axis' positions over the data, to normalise the slopes' columns to −1 … 1.
    let axes = m.axes.len();
    let mut span = vec![(f64::INFINITY, f64::NEG_INFINITY); axes];
    for r in &located.rows {
        for (s, v) in span.iter_mut().zip(located.values(r)) {
            if v.is_finite() {
                *s = (s.0.min(*v), s.1.max(*v));
            }
        }
    }
    let timed = |located: &Residuals, k: usize| -> Option<Timed> {
        let r = located.rows.get(k)?;
        let values = located.values(r);
        let time = *values.get(at)?;
        let x = span
            .iter()
            .zip(values)
            .filter(|(s, _)| s.1 > s.0)
            .map(|(s, v)| {
                if v.is_finite() {
                    2.0 * (v - s.0) / (s.1 - s.0) - 1.0
                } else {
                    0.0
                }
            })
            .collect();
        time.is_finite().then_some(Timed {
            time,
            residual: r.residual,
            leverage: r.leverage,
            x,
        })
    };
    let mut out = Vec::new();
    for c in comps {
        let mine: Vec<(usize, Timed)> = (0..located.rows.len())
            .filter(|&k| located.rows.get(k).is_some_and(|r| r.component == c))
            .filter_map(|k| Some((k, timed(located, k)?)))
            .collect();
        let all: Vec<Timed> = mine.iter().map(|(_, t)| t.clone()).collect();
        let Some(first) = trend::trend(&all, settings.bins).filter(|t| t.significant(level)) else {
            continue;
        };
        let kept: Vec<Timed> = all
            .iter()
            .filter(|t| !trend::outlier(&first, t, threshold))
            .cloned()
            .collect();
        let Some(second) = trend::trend(&kept, settings.bins).filter(|t| t.significant(level))
        else {
            continue;
        };
        // The trend clears the fit's flags on its own rows; it never flags a row the fit does
        // not (a shape the parts' levels and slopes cannot follow is the missing effect's).
        for (k, t) in &mine {
            if let Some(r) = located.rows.get_mut(*k) {
                r.outlier = r.outlier && trend::outlier(&second, t, threshold);
            }
        }
        out.push((c, second));
    }
    out
}

/// "Where the model fails" for a trend over time: how the residuals' level and spread change
/// across the time bins.
fn trend_region(m: &Machine, cname: &str, t: &Trend, sigma: f64, unit: &str) -> Region {
    let filled: Vec<(usize, &trend::TimeBin)> = t
        .bins
        .iter()
        .enumerate()
        .filter(|(_, b)| b.rows > 0)
        .collect();
    let pick = |better: fn(f64, f64) -> bool, key: fn(&trend::TimeBin) -> f64| {
        filled
            .iter()
            .copied()
            .reduce(|a, b| if better(key(b.1), key(a.1)) { b } else { a })
    };
    let tu = &m.units.time.name;
    let when = |b: usize| {
        let lo = t.lo + b as f64 * t.width;
        format!("{}–{} {tu}", nice(lo), nice(lo + t.width))
    };
    let (Some(least), Some(most), Some(low), Some(high)) = (
        pick(|a, b| a < b, |b| b.rms),
        pick(|a, b| a > b, |b| b.rms),
        pick(|a, b| a < b, |b| b.mean),
        pick(|a, b| a > b, |b| b.mean),
    ) else {
        return Region {
            component: cname.to_string(),
            conditions: vec![TREND.into()],
            ratio: t.ratio,
            rows: 0,
            p: t.p,
            text: format!("{cname} residuals follow {TREND}"),
        };
    };
    Region {
        component: cname.to_string(),
        conditions: vec![TREND.into()],
        ratio: most.1.rms / sigma.max(f64::MIN_POSITIVE),
        rows: filled.iter().map(|(_, b)| b.rows).sum(),
        p: t.p,
        text: format!(
            "{cname} residuals follow {TREND}: their RMS is {} {unit} at {} and {} {unit} at {}, their mean {} {unit} at {} and {} {unit} at {} ({} equal parts of the time)",
            nice(least.1.rms),
            when(least.0),
            nice(most.1.rms),
            when(most.0),
            nice(low.1.mean),
            when(low.0),
            nice(high.1.mean),
            when(high.0),
            t.bins.len()
        ),
    }
}

/// Residuals binned along every variable, and the regions where they exceed what the noise
/// and the model's uncertainty allow (each residual's variance is σ̂²(1 − h)).
fn regions(
    m: &Machine,
    located: &Residuals,
    base: &FitResult,
    settings: &Settings,
    trends: &[(u8, Trend)],
) -> (Vec<Region>, Vec<Bin>) {
    let vars = variables(m);
    let fitted = base.sigma / m.units.error.scale;
    let comps: Vec<u8> = {
        let mut c: Vec<u8> = located.rows.iter().map(|r| r.component).collect();
        c.sort_unstable();
        c.dedup();
        c
    };
    // The number of tests, for a Bonferroni threshold on the bins.
    let tests = (comps.len() * vars.len() * settings.bins * 2).max(1) as f64;
    let chi = |r: &[&Located], sigma: f64| -> (f64, f64, f64) {
        let n = r.len() as f64;
        let stat: f64 = r
            .iter()
            .map(|x| x.residual.powi(2) / (sigma * sigma * (1.0 - x.leverage).max(1e-9)))
            .sum();
        let p = statistics::chi_squared_p(stat, n.max(1.0)).unwrap_or(1.0);
        let rms = (r.iter().map(|x| x.residual.powi(2)).sum::<f64>() / n.max(1.0)).sqrt();
        let allowed = sigma
            * (r.iter().map(|x| 1.0 - x.leverage).sum::<f64>() / n.max(1.0))
                .max(0.0)
                .sqrt();
        (p, rms, allowed)
    };
    let mut bins = Vec::new();
    let mut found: Vec<Region> = Vec::new();
    for &c in &comps {
        // Outliers are named on their own, not as a region where the model fails.
        let mine: Vec<&Located> = located
            .rows
            .iter()
            .filter(|r| r.component == c && !r.outlier)
            .collect();
        let cname = component_name(c).to_string();
        // The reference: the stated noise when given, else the fit's own σ̂ (and the words
        // say which).
        let (sigma, against) = match reference(m, settings, base, c) {
            Some(v) if v > 0.0 && per_file(base) => (v, "what each file's own σ allows".into()),
            Some(v) if v > 0.0 => (
                v,
                format!(
                    "what the stated noise allows (σ = {} {})",
                    nice(v),
                    unit_of(m, c)
                ),
            ),
            _ => (
                fitted,
                format!(
                    "the model's own residual scatter (σ̂ = {} {})",
                    nice(fitted),
                    m.units.error.name
                ),
            ),
        };
        // A component worse than the noise everywhere is one statement, not one per variable;
        // the bins then look for where it is worse than the component's own level.
        let (p_all, rms_all, allowed_all) = chi(&mine, sigma);
        let throughout = p_all < settings.alpha / tests && rms_all > 1.2 * allowed_all;
        // A trend over time is where such a model fails: named instead of the whole workspace.
        let trend = trends
            .iter()
            .find(|(tc, t)| *tc == c && t.significant(settings.alpha / tests));
        if let Some((_, t)) = trend {
            found.push(trend_region(m, &cname, t, sigma, unit_of(m, c)));
        }
        if throughout && trend.is_none() {
            found.push(Region {
                component: cname.clone(),
                conditions: vec!["throughout the workspace".into()],
                ratio: rms_all / allowed_all.max(f64::MIN_POSITIVE),
                rows: mine.len(),
                p: p_all,
                text: format!(
                    "{cname} residuals are {:.1}× {against} throughout the workspace",
                    rms_all / allowed_all.max(f64::MIN_POSITIVE),
                ),
            });
        }
        let level = if throughout {
            rms_all / allowed_all.max(f64::MIN_POSITIVE)
        } else {
            1.0
        };
        // The direction of motion: a residual that shifts with it is a backlash or hysteresis.
        for (a, axis) in m.axes.iter().enumerate() {
            let side = |d: f64| -> Vec<f64> {
                mine.iter()
                    .filter(|r| located.dirs(r).get(a) == Some(&d))
                    .map(|r| r.residual)
                    .collect()
            };
            let (plus, minus) = (side(1.0), side(-1.0));
            if plus.len() < 10 || minus.len() < 10 {
                continue;
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            let shift = mean(&plus) - mean(&minus);
            let se = sigma * (1.0 / plus.len() as f64 + 1.0 / minus.len() as f64).sqrt();
            let z = shift / se.max(f64::MIN_POSITIVE);
            let p = statistics::normal_two_sided_p(z).unwrap_or(1.0);
            if p < settings.alpha / tests && shift.abs() > 0.5 * sigma {
                found.push(Region {
                    component: cname.clone(),
                    conditions: vec![format!("direction of motion of {}", axis.name)],
                    ratio: shift.abs() / sigma.max(f64::MIN_POSITIVE),
                    rows: plus.len() + minus.len(),
                    p,
                    text: format!(
                        "{cname} residuals shift by {} {} between the two directions of motion of {} ({:.1} σ)",
                        nice(shift),
                        unit_of(m, c),
                        axis.name,
                        shift.abs() / sigma.max(f64::MIN_POSITIVE)
                    ),
                });
            }
        }
        for (v, (vname, unit)) in vars.iter().enumerate() {
            let vals: Vec<f64> = mine
                .iter()
                .filter_map(|r| located.values(r).get(v).copied())
                .filter(|x| x.is_finite())
                .collect();
            if vals.len() < 2 * settings.bins {
                continue;
            }
            let (lo, hi) = vals
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                    (a.min(*x), b.max(*x))
                });
            if !(hi > lo) {
                continue;
            }
            let width = (hi - lo) / settings.bins as f64;
            let mut flagged: Vec<(usize, f64, f64, usize)> = Vec::new();
            for b in 0..settings.bins {
                let (blo, bhi) = (lo + b as f64 * width, lo + (b + 1) as f64 * width);
                let inside: Vec<&Located> = mine
                    .iter()
                    .copied()
                    .filter(|r| {
                        located.values(r).get(v).is_some_and(|x| {
                            *x >= blo && (*x < bhi || (b + 1 == settings.bins && *x <= bhi))
                        })
                    })
                    .collect();
                if inside.is_empty() {
                    continue;
                }
                let (p, rms, allowed) = chi(&inside, sigma);
                let mean = inside.iter().map(|r| r.residual).sum::<f64>() / inside.len() as f64;
                bins.push(Bin {
                    component: cname.clone(),
                    variable: vname.clone(),
                    unit: unit.clone(),
                    lo: blo,
                    hi: bhi,
                    rows: inside.len(),
                    mean,
                    rms,
                    allowed,
                });
                // Against the component's own level when it is raised everywhere: a bin is
                // notable for being worse than the rest, not for sharing the common excess.
                let ratio = rms / (allowed * level).max(f64::MIN_POSITIVE);
                let excess = if throughout {
                    let n = inside.len() as f64;
                    let stat: f64 = inside
                        .iter()
                        .map(|x| x.residual.powi(2) / (rms_all * rms_all))
                        .sum();
                    statistics::chi_squared_p(stat, n.max(1.0)).unwrap_or(1.0)
                } else {
                    p
                };
                // Along time, a named trend already says where (and its bins are in the table).
                let timed = trend.is_some() && v + 1 == vars.len();
                if excess < settings.alpha / tests && ratio > 1.5 && !timed {
                    flagged.push((b, ratio, excess, inside.len()));
                }
            }
            // Adjacent flagged bins form one region.
            let mut i = 0;
            while i < flagged.len() {
                let mut j = i;
                while j + 1 < flagged.len() && flagged[j + 1].0 == flagged[j].0 + 1 {
                    j += 1;
                }
                let (b0, b1) = (flagged[i].0, flagged[j].0);
                let (rlo, rhi) = (lo + b0 as f64 * width, lo + (b1 + 1) as f64 * width);
                let cond = if b0 == 0 && b1 + 1 == settings.bins {
                    format!("all {vname}")
                } else if b0 == 0 {
                    format!("{vname} < {} {unit}", nice(rhi))
                } else if b1 + 1 == settings.bins {
                    format!("{vname} > {} {unit}", nice(rlo))
                } else {
                    format!("{} {unit} < {vname} < {} {unit}", nice(rlo), nice(rhi))
                };
                if b0 == 0 && b1 + 1 == settings.bins {
                    // Every bin: nothing local about it (said once above).
                    i = j + 1;
                    continue;
                }
                let ratio = flagged[i..=j].iter().map(|f| f.1).fold(0.0, f64::max) * level;
                let p = flagged[i..=j].iter().map(|f| f.2).fold(1.0, f64::min);
                let count = flagged[i..=j].iter().map(|f| f.3).sum();
                found.push(Region {
                    component: cname.clone(),
                    conditions: vec![cond.clone()],
                    ratio,
                    rows: count,
                    p,
                    text: format!("{cname} residuals are {ratio:.1}× {against} for {cond}"),
                });
                i = j + 1;
            }
        }
    }
    found.sort_by(|a, b| b.ratio.total_cmp(&a.ratio));
    (combine(found), bins)
}

/// Pairs the strongest one-variable regions of the same component into one statement. Each was
/// tested along its own variable only, so the words do not claim the two hold together ("ez …
/// for Y > 420 mm; also, along another variable, for X < 150 mm").
///
/// Separate ranges of one variable (bins that are not adjacent) are one statement that says
/// they are separate ("in 2 separate ranges of X: X < 120 mm and X > 680 mm"), never a
/// condition that reads as if both had to hold, nor "another variable".
fn combine(found: Vec<Region>) -> Vec<Region> {
    let mut out: Vec<Region> = Vec::new();
    let local = |o: &Region| {
        o.conditions.iter().all(|c| {
            c != "throughout the workspace" && !c.starts_with("direction of motion") && c != TREND
        })
    };
    let variables = |o: &Region| -> Vec<String> {
        o.conditions
            .iter()
            .map(|c| variable_of(c).to_string())
            .collect()
    };
    for r in found {
        let var = r.conditions.first().map(|c| variable_of(c).to_string());
        if let Some(prev) = out.iter_mut().find(|o| {
            local(o) && local(&r) && o.component == r.component && {
                let vs = variables(o);
                vs.iter().all(|v| Some(v) == var.as_ref())
            }
        }) {
            let v = var.unwrap_or_default();
            prev.conditions.extend(r.conditions.clone());
            // Sorted by strength: the first one's ratio is the largest.
            let base = prev
                .text
                .split_once(" for ")
                .or_else(|| prev.text.rsplit_once(" in "))
                .map(|(b, _)| b.to_string())
                .unwrap_or_else(|| prev.text.clone());
            prev.text = format!(
                "{base} in {} separate ranges of {v}: {}",
                prev.conditions.len(),
                prev.conditions.join(" and ")
            );
            prev.rows += r.rows;
            prev.p = prev.p.min(r.p);
            continue;
        }
        if let Some(prev) = out.iter_mut().find(|o| {
            local(o)
                && local(&r)
                && o.component == r.component
                && o.conditions.len() == 1
                && !variables(o).iter().any(|v| Some(v) == var.as_ref())
        }) {
            prev.conditions.extend(r.conditions.clone());
            prev.text = format!(
                "{}; also, along another variable, for {}",
                prev.text,
                r.conditions.join(", ")
            );
            continue;
        }
        out.push(r);
    }
    out
}

/// The variable a region's condition is about: `X` of `X < 120 mm`, `X > 680 mm`,
/// `120 mm < X < 300 mm`.
fn variable_of(condition: &str) -> &str {
    let mut words = condition.split_whitespace();
    let first = words.next().unwrap_or("");
    if first.parse::<f64>().is_ok() {
        // `LO UNIT < VAR < HI UNIT`
        condition
            .split(" < ")
            .nth(1)
            .map(str::trim)
            .unwrap_or(first)
    } else {
        first
    }
}

fn nice(v: f64) -> String {
    let a = v.abs();
    let digits = if a >= 100.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 {
        2
    } else {
        3
    };
    format!("{:.*}", digits, v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use kin_estimate::fit::StreamingQr;

    fn finding(text: &str, bic: f64) -> Finding {
        Finding {
            candidate: Candidate {
                family: Family::CrossCoupling,
                target: "X.tx".into(),
                also: Vec::new(),
                text: text.into(),
                explanation: String::new(),
                no_path: None,
            },
            alternatives: Vec::new(),
            separation: None,
            columns: 1,
            explained: 0.5,
            f: 50.0,
            p: 1e-9,
            p_adjusted: 1e-8,
            significant: true,
            rms_after: 1.0,
            bic,
            plausibility: None,
            fitted: Vec::new(),
            contradicted: Vec::new(),
            same_effect_as: Vec::new(),
        }
    }

    /// The candidates the second pass sums together: every one whose residual sum ties
    /// another's (wherever it ranks, significant or not), and the significant ones the
    /// readings-of-one-effect check can reach once tied ones are merged.
    #[test]
    fn the_compared_candidates_are_the_tied_and_the_first_significant() {
        let tested = |i: usize, rss: f64, significant: bool| Tested {
            proposal: i,
            finding: Finding {
                significant,
                ..finding(&format!("line {i}"), -(i as f64))
            },
            terms: vec![vec![i]],
            columns: vec![i],
            rss,
        };
        // 14 significant with distinct sums, then 3 not significant, the last two tied.
        let mut all: Vec<Tested> = (0..14).map(|i| tested(i, 100.0 + i as f64, true)).collect();
        all.extend((14..17).map(|i| tested(i, 200.0 + (i / 15) as f64, false)));
        let c = compared(&all, 1000.0);
        let want: Vec<usize> = (0..12).chain([15, 16]).collect();
        assert_eq!(c, want);
        // Two significant ones tied far down: they count, and two more of the first.
        all[12].rss = all[13].rss;
        let c = compared(&all, 1000.0);
        assert_eq!(c, (0..14).chain([15, 16]).collect::<Vec<_>>());
        // Sums that differ by more than rounding are not tied.
        all[12].rss = all[13].rss * (1.0 + 1e-6);
        assert_eq!(compared(&all, 1000.0), want);
    }

    /// The evidence and the structure outrank BIC: a contradicted line after every other
    /// significant one, a coupling with no physical path after those with one, and both
    /// still before what is not significant.
    #[test]
    fn contradicted_and_pathless_lines_rank_after_the_rest() {
        let mut contradicted = finding("contradicted", -500.0);
        contradicted.contradicted.push(super::super::Worse {
            component: "erz".into(),
            rms_before: 414.0,
            rms_after: 541.0,
            unit: "urad".into(),
            p: 1e-30,
        });
        let mut pathless = finding("pathless", -400.0);
        pathless.candidate.no_path = Some("no path".into());
        let plain = finding("plain", -10.0);
        let mut weak = finding("weak", 5.0);
        weak.significant = false;
        let mut all = [weak, contradicted, pathless, plain];
        all.sort_by(rank_order);
        let order: Vec<&str> = all.iter().map(|f| f.candidate.text.as_str()).collect();
        assert_eq!(order, ["plain", "pathless", "contradicted", "weak"]);
    }

    fn region(component: &str, cond: &str, ratio: f64) -> Region {
        Region {
            component: component.into(),
            conditions: vec![cond.into()],
            ratio,
            rows: 10,
            p: 1e-6,
            text: format!("{component} residuals are {ratio:.1}× σ̂ for {cond}"),
        }
    }

    #[test]
    fn separate_ranges_of_one_variable_are_said_to_be_separate() {
        assert_eq!(variable_of("X < 120 mm"), "X");
        assert_eq!(variable_of("120 mm < X < 300 mm"), "X");
        assert_eq!(variable_of("-5.5 degC < T_room < 3 degC"), "T_room");
        let out = combine(vec![
            region("ex", "X < 120 mm", 3.1),
            region("ex", "300 mm < X < 420 mm", 2.9),
            region("ex", "X > 680 mm", 2.8),
            region("ex", "Y > 400 mm", 2.5),
            region("ey", "X > 680 mm", 2.0),
        ]);
        assert_eq!(out.len(), 3, "{out:?}");
        assert_eq!(
            out[0].text,
            "ex residuals are 3.1× σ̂ in 3 separate ranges of X: X < 120 mm and 300 mm < X < 420 mm and X > 680 mm"
        );
        assert_eq!(out[1].conditions, vec!["Y > 400 mm"]);
        assert!(!out.iter().any(|r| r.text.contains("another variable")));
    }

    const CMM: &str = r#"
machine cmm3 {
    task measure
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
    }
    errors {
        X.tx = const
        Y.tx = const
    }
}
"#;

    /// Two columns that differ by a millionth: a refit with the second trades one against the
    /// other (condition ~10⁶) and the data's small share along their difference becomes
    /// coefficients of metres.
    #[test]
    fn a_refit_that_trades_columns_off_is_doubtful() {
        let c = compile(CMM).compiled.expect("compiles");
        let m = &c.machine;
        assert!(m
            .coefficients
            .iter()
            .all(|k| k.unit.dim == kin_compiler::units::Dim::LENGTH));
        let mut qr = StreamingQr::new(2, 64);
        for i in 0..200 {
            let x = 1.0 + i as f64 / 200.0;
            let wiggle = (i as f64).sin();
            qr.push(&[x, x + 1e-6 * wiggle], 1e-6 * x + 1e-6 * wiggle);
        }
        let red = qr.finish();
        let size = machine_size(m);
        // 1.8 m of travel and 0.6 m of offsets.
        assert!((size - 2.4).abs() < 1e-9, "{size}");
        let p = plausibility(&red, &[0], &[1], m, size, m.coefficients.len());
        assert!(p.condition_before < 1.0 + 1e-9, "{p:?}");
        assert!(p.condition_after > 1e5, "{p:?}");
        assert_eq!(p.warnings.len(), 2, "{p:?}");
        assert!(p.warnings[0].contains("ill-conditioned"), "{p:?}");
        assert!(p.largest_length > 0.1 * p.machine_size, "{p:?}");

        // Independent columns: nothing to say.
        let mut qr = StreamingQr::new(2, 64);
        for i in 0..200 {
            let x = 1.0 + i as f64 / 200.0;
            qr.push(&[x, (i as f64).sin()], 1e-6 * x);
        }
        let p = plausibility(&qr.finish(), &[0], &[1], m, size, m.coefficients.len());
        assert!(p.warnings.is_empty(), "{p:?}");
    }

    /// The three components of a pose share one place, which holds that pose's positions in
    /// display units; the residuals keep the fit's order.
    #[test]
    fn a_poses_components_share_its_place() {
        let c = compile(&CMM.replace("Y.tx = const", "Y.ty = linear(Y)"))
            .compiled
            .expect("compiles");
        let m = &c.machine;
        let poses = kin_estimate::simulate::sample_points(m, 40, 3);
        let observations = kin_estimate::simulate::simulate(
            m,
            &vec![1e-6; m.coefficients.len()],
            &Observations::Points(poses),
            &kin_estimate::simulate::Options {
                noise: 1e-7,
                seed: 5,
                ..kin_estimate::simulate::Options::default()
            },
        )
        .expect("simulate");
        let files = vec![DataSet {
            path: "data.csv".into(),
            observations,
        }];
        let mut engine = kin_model::interp::Interpreter::new(m).expect("interpreter");
        let base = fit::fit(
            &c,
            &mut engine,
            &files,
            &[],
            &fit::Options::default(),
            &mut |_, _| {},
        )
        .expect("fit");
        let located = positions(m, &files, &base);
        assert_eq!(located.rows.len(), base.residuals.len());
        assert_eq!(base.residuals.len(), 3 * 40);
        let w = located.places.values + located.places.axes;
        assert_eq!(located.places.data.len(), 40 * w, "one place per pose");
        let Observations::Points(p) = &files[0].observations else {
            panic!("points")
        };
        let rows = files[0].observations.rows();
        for (r, l) in base.residuals.iter().zip(&located.rows) {
            let row = rows
                .line
                .iter()
                .position(|&x| x == r.meta.line as usize)
                .expect("a row of the file");
            assert_eq!(l.at as usize, row);
            assert_eq!(l.component, r.meta.component);
            let values = located.values(l);
            for (a, axis) in p.pose.axes.iter().enumerate() {
                assert_eq!(values[a], m.units.length.from_si(axis[row]));
            }
            assert_eq!(located.dirs(l).len(), m.axes.len());
        }
    }

    #[test]
    fn sampling_rules() {
        // 5 positions 10 mm apart: nothing below 20 mm, nothing above 40/3 mm.
        let s = Sampling::of((0..600).map(|r| 0.1 + 0.01 * (r % 5) as f64)).expect("sampled");
        assert_eq!(s.distinct, 5);
        assert!((s.shortest() - 0.02).abs() < 1e-12);
        assert!(!s.resolves(0.0045) && !s.resolves(0.025) && !s.resolves(0.013));
        // ±30°: no harmonic at 2, 3, 4 per revolution; the full circle: all of them; 120°: 3, 4.
        let deg = std::f64::consts::PI / 180.0;
        let range = |a: f64, b: f64| {
            Sampling::of((0..=60).map(|k| (a + (b - a) * k as f64 / 60.0) * deg)).expect("sampled")
        };
        assert!(range(-30.0, 30.0).harmonics(2..=4).is_empty());
        assert_eq!(range(0.0, 360.0).harmonics(2..=4), vec![2, 3, 4]);
        assert_eq!(range(-60.0, 60.0).harmonics(2..=4), vec![3, 4]);
    }
}
